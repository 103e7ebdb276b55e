// kernels_impl.hpp: bodies of the kernels declared in kernels.hpp, written once with GCC/Clang
// vector extensions of VIBID_KERNEL_VBYTES bytes (16: SSE2 / NEON, two doubles; 32: AVX2,
// four doubles). Included by kernels_base.cpp and kernels_avx2.cpp only, each inside its
// own namespace, so that the two compilations never share a symbol. No Eigen here (see
// kernels.hpp).
//
// Vector loads and stores go through memcpy: the arrays are only 8-byte aligned in general
// (columns of a p x p matrix), and memcpy of a vector is one unaligned load or store.
// Only compiler builtins are used, no std:: templates or inline functions: an inline
// function instantiated in both compilations would be one symbol, and the linker could
// keep the AVX2 body for the baseline caller. Everything here has internal linkage.

#ifndef VIBID_KERNEL_VBYTES
#error "define VIBID_KERNEL_VBYTES before including kernels_impl.hpp"
#endif

namespace {

// The helpers are forced inline into the kernels that the tables point to: one call per
// equation or block, no calls inside (a call per column would cost as much as the column
// at small p).
#define VIBID_KINLINE inline __attribute__((always_inline))

using vd = double __attribute__((vector_size(VIBID_KERNEL_VBYTES)));
constexpr idx W = VIBID_KERNEL_VBYTES / static_cast<idx>(sizeof(double));

VIBID_KINLINE vd vload(const double *p) {
    vd v;
    __builtin_memcpy(&v, p, sizeof v);
    return v;
}
VIBID_KINLINE void vstore(double *p, vd v) { __builtin_memcpy(p, &v, sizeof v); }
VIBID_KINLINE vd vsplat(double s) {
    vd v;
    for (idx i = 0; i < W; ++i) v[i] = s;
    return v;
}
// *p in every lane, loaded as one broadcast (x - 0 is x exactly, -0 included, and folds
// away; vsplat's lane-by-lane form compiles to two shuffles).
VIBID_KINLINE vd vbroadcast(const double *p) { return *p - vd{}; }
VIBID_KINLINE double hsum(vd v) {
    double s = v[0];
    for (idx i = 1; i < W; ++i) s += v[i];
    return s;
}
VIBID_KINLINE bool pos_finite(double v) { return v > 0.0 && v <= __DBL_MAX__; }

// a . b over n entries; two vector accumulators hide the add latency. Short vectors (the
// first columns of U, all of them at small p) take the scalar loop only.
template <bool Vec = true>
VIBID_KINLINE double dot_i(const double *a, const double *b, idx n) {
    double s = 0.0;
    idx i = 0;
    if (Vec && n >= 2 * W) {
        vd s0 = vsplat(0.0), s1 = vsplat(0.0);
        for (; i + 2 * W <= n; i += 2 * W) {
            s0 += vload(a + i) * vload(b + i);
            s1 += vload(a + i + W) * vload(b + i + W);
        }
        if (i + W <= n) {
            s0 += vload(a + i) * vload(b + i);
            i += W;
        }
        s = hsum(s0 + s1);
    }
#pragma GCC unroll 4
    for (; i < n; ++i) s += a[i] * b[i];
    return s;
}
double dot(const double *a, const double *b, idx n) { return dot_i(a, b, n); }

template <bool Vec = true>
VIBID_KINLINE double axpy_sum_i(idx n, double c, const double *g, const double *x, double *y) {
    double s = 0.0;
    idx i = 0;
    if (Vec && n >= W) {
        const vd cv = vsplat(c);
        vd s0 = vsplat(0.0);
        for (; i + W <= n; i += W) {
            const vd t = vload(x + i) + cv * vload(g + i);
            vstore(y + i, t);
            s0 += t;
        }
        s = hsum(s0);
    }
    for (; i < n; ++i) {
        const double t = x[i] + c * g[i];
        y[i] = t;
        s += t;
    }
    return s;
}
double axpy_sum(idx n, double c, const double *g, const double *x, double *y) { return axpy_sum_i(n, c, g, x, y); }

template <bool Vec = true>
VIBID_KINLINE double bierman_i(idx p, idx ld, const double *us, double *ud, const double *ds, double *dd, double dscale,
               const double *x, double *b, double *work, double &trace, double &ralpha_out, bool &ok) {
    // Pass 1 (scalars): f_j = (U^T x)_j, v_j = D~_j f_j, the running alpha_{j+1} =
    // alpha_j + f_j v_j (alpha_0 = 1), the new D_j = D~_j alpha_j / alpha_{j+1} and the
    // column coefficients pj = -f_j / alpha_j. One division per column, 1 / alpha_{j+1},
    // and nothing on the alpha chain waits for it, so the divisions overlap. (Gathering
    // the alphas first and dividing them as vectors is slower: reloading scalars just
    // stored as a vector defeats store forwarding.) U is only read here and only written
    // in pass 2, D_j is read before D_new,j is stored: the in-place call is safe.
    double *pc = work, *vc = work + p;
    double alpha = 1.0, ralpha = 1.0;
    bool good = true;
#pragma GCC unroll 8
    for (idx j = 0; j < p; ++j) {
        const double f = x[j] + dot_i<Vec>(us + j * ld, x, j);
        const double d = ds[j] * dscale;
        const double v = d * f;
        const double an = alpha + f * v;
        const double ran = 1.0 / an;
        const double dnew = d * alpha * ran;
        dd[j] = dnew;
        good &= (dnew > 0.0) & (dnew <= __DBL_MAX__);  // bitwise: no branch per column
        pc[j] = -f * ralpha;
        vc[j] = v;
        alpha = an;
        ralpha = ran;
    }
    // Pass 2, two columns j, j + 1 per sweep over rows 0..j-1 (the gain b is loaded and
    // stored once for both): U_new(:, j) = U(:, j) + pj b, b += vj U(:, j) (old column),
    // with b the partial gain over the rows above, then the same for column j + 1 with that
    // b. The trace, sum_j D_new,j (1 + |U_new(:, j)|^2), is accumulated as
    // sum_j D_new,j + sum_ij D_new,j U_new(i, j)^2 in one vector accumulator, reduced once.
    vd acc = vsplat(0.0);
    double tr = 0.0;
    const auto pair = [&](idx j) __attribute__((always_inline)) {
        const double *u0 = us + j * ld, *u1 = u0 + ld;
        double *n0 = ud + j * ld, *n1 = n0 + ld;
        const double p0 = pc[j], v0 = vc[j], p1 = pc[j + 1], v1 = vc[j + 1];
        const double d0 = dd[j], d1 = dd[j + 1];
        idx i = 0;
        if (Vec && j >= W) {
            const vd p0v = vsplat(p0), v0v = vsplat(v0), p1v = vsplat(p1), v1v = vsplat(v1);
            const vd d0v = vsplat(d0), d1v = vsplat(d1);
            for (; i + W <= j; i += W) {
                const vd a0 = vload(u0 + i), a1 = vload(u1 + i), bo = vload(b + i);
                const vd m0 = a0 + p0v * bo;
                const vd b1 = bo + v0v * a0;
                const vd m1 = a1 + p1v * b1;
                vstore(n0 + i, m0);
                vstore(n1 + i, m1);
                vstore(b + i, b1 + v1v * a1);
                acc += d0v * (m0 * m0) + d1v * (m1 * m1);
            }
        }
        const auto row = [&](idx r) __attribute__((always_inline)) {
            const double a0 = u0[r], a1 = u1[r], bo = b[r];
            const double m0 = a0 + p0 * bo;
            const double b1 = bo + v0 * a0;
            const double m1 = a1 + p1 * b1;
            n0[r] = m0;
            n1[r] = m1;
            b[r] = b1 + v1 * a1;
            tr += d0 * (m0 * m0) + d1 * (m1 * m1);
        };
        if (!Vec) {
#pragma GCC unroll 8
            for (; i < j; ++i) row(i);
        } else {
            for (; i < j; ++i) row(i);  // the last j mod W rows
        }
        // Row j: column j sets b_j = v0; column j + 1 updates its entry there.
        const double a1 = u1[j];
        const double m1 = a1 + p1 * v0;
        n1[j] = m1;
        b[j] = v0 + v1 * a1;
        b[j + 1] = v1;
        tr += d0 + d1 * (1.0 + m1 * m1);
    };
    idx j = 0;
    if (!Vec) {
        // Constant p (the small-p instantiations): unrolled completely, b stays in registers.
#pragma GCC unroll 8
        for (j = 0; j + 1 < p; j += 2) pair(j);
    } else {
        for (j = 0; j + 1 < p; j += 2) pair(j);
    }
    if (j < p) {  // odd p: the last column alone
        const double *u0 = us + j * ld;
        double *n0 = ud + j * ld;
        const double p0 = pc[j], v0 = vc[j], d0 = dd[j];
        idx i = 0;
        if (Vec && j >= W) {
            const vd p0v = vsplat(p0), v0v = vsplat(v0), d0v = vsplat(d0);
            for (; i + W <= j; i += W) {
                const vd a0 = vload(u0 + i), bo = vload(b + i);
                const vd m0 = a0 + p0v * bo;
                vstore(n0 + i, m0);
                vstore(b + i, bo + v0v * a0);
                acc += d0v * (m0 * m0);
            }
        }
        for (; i < j; ++i) {
            const double a0 = u0[i];
            const double m0 = a0 + p0 * b[i];
            n0[i] = m0;
            b[i] += v0 * a0;
            tr += d0 * (m0 * m0);
        }
        b[j] = v0;
        tr += d0;
    }
    if (Vec) tr += hsum(acc);
    ok = ok && good && pos_finite(alpha) && __builtin_isfinite(tr);
    trace = tr;
    ralpha_out = ralpha;  // 1 / alpha, already computed: no division at the end
    return alpha;
}

// PF > 0: p is the constant PF, so that every loop has a constant trip count and the
// compiler unrolls them (most of an update's cost at small p is loop control otherwise);
// up to p = 8 the code is scalar: vectors of a few entries cost more than they save, and a
// vector load of entries just stored one by one (the gain b, column by column) stalls on
// store forwarding. PF = 0: p from s, vector loops.
template <idx PF>
VIBID_KINLINE void bierman_step_t(RlsStep &s) {
    constexpr bool vec = PF == 0 || PF > 2 * W;
    const idx p = PF > 0 ? PF : s.p, q = s.q;
    for (idx j = 0; j < q; ++j) s.e[j] = s.y[j * s.ystride] - dot_i<vec>(s.ths + j * p, s.x, p);
    bool ok = true;
    double c;  // 1 / alpha
    s.alpha = bierman_i<vec>(p, s.ld, s.us, s.ud, s.ds, s.dd, s.dscale, s.x, s.b, s.work, s.trace, c, ok);
    s.ok = ok;
    double ts = 0.0, vs = 0.0;
    for (idx j = 0; j < q; ++j) ts += axpy_sum_i<vec>(p, s.e[j] * c, s.b, s.ths + j * p, s.thd + j * p);
    for (idx k = 0; k < q; ++k) {
        const double ck = s.e[k] * c;
        const double *vsk = s.Vs + k * q;
        double *vdk = s.Vd + k * q;
        for (idx i = 0; i < q; ++i) {
            const double t = s.vscale * vsk[i] + ck * s.e[i];
            vdk[i] = t;
            vs += t;
        }
    }
    s.theta_sum = ts;
    s.v_sum = vs;
}

void bierman_step(RlsStep &s) {
    switch (s.p) {
    case 2: bierman_step_t<2>(s); return;
    case 3: bierman_step_t<3>(s); return;
    case 4: bierman_step_t<4>(s); return;
    case 5: bierman_step_t<5>(s); return;
    case 6: bierman_step_t<6>(s); return;
    case 7: bierman_step_t<7>(s); return;
    case 8: bierman_step_t<8>(s); return;
    case 9: bierman_step_t<9>(s); return;
    case 10: bierman_step_t<10>(s); return;
    case 11: bierman_step_t<11>(s); return;
    case 12: bierman_step_t<12>(s); return;
    case 13: bierman_step_t<13>(s); return;
    case 14: bierman_step_t<14>(s); return;
    case 15: bierman_step_t<15>(s); return;
    case 16: bierman_step_t<16>(s); return;
    default: bierman_step_t<0>(s); return;
    }
}

// All equations of one sample for p = P <= kSmallP and one output (the structured form's
// case: example 1 has p = 3, m = 2), see Table::bierman_small. U, D, Theta and V are loaded
// once into local arrays, which the compiler keeps in registers through the equations
// (the loops are unrolled completely), and stored once: the per-equation step goes through
// memory, which puts a store and a reload of every entry on the chain from one equation to
// the next, and its setup per equation costs as much as the arithmetic at this size. Same
// arithmetic, in the same order, as bierman_step_t per equation.
template <idx P>
VIBID_KINLINE void bierman_small_t(RlsStep &s) {
    constexpr bool vec = P > 2 * W;  // as bierman_step_t
    double u[P * P], d[P], th[P], b[P], work[2 * P];
#pragma GCC unroll 8
    for (idx j = 0; j < P; ++j) {
#pragma GCC unroll 8
        for (idx i = 0; i < j; ++i) u[j * P + i] = s.us[j * s.ld + i];
        d[j] = s.ds[j];
        th[j] = s.ths[j];
    }
    double v = s.Vs[0], dscale = s.dscale, vscale = s.vscale, tr = 0.0, ts = 0.0;
    bool ok = true;
    for (idx i = 0; i < s.m; ++i) {
        const double *x = s.x + i * P;
        const double e = s.y[i] - dot_i<vec>(th, x, P);
        double c;  // 1 / alpha
        bierman_i<vec>(P, P, u, u, d, d, dscale, x, b, work, tr, c, ok);
        ts = axpy_sum_i<vec>(P, e * c, b, th, th);
        v = vscale * v + (e * c) * e;
        dscale = vscale = 1.0;
    }
#pragma GCC unroll 8
    for (idx j = 0; j < P; ++j) {
#pragma GCC unroll 8
        for (idx i = 0; i < j; ++i) s.ud[j * s.ld + i] = u[j * P + i];
        s.dd[j] = d[j];
        s.thd[j] = th[j];
    }
    s.Vd[0] = v;
    s.trace = tr;
    s.theta_sum = ts;
    s.v_sum = v;
    s.ok = ok;
}

void bierman_small(RlsStep &s) {
    static_assert(kSmallP == 4, "one case per p up to kSmallP");
    switch (s.p) {
    case 1: bierman_small_t<1>(s); return;
    case 2: bierman_small_t<2>(s); return;
    case 3: bierman_small_t<3>(s); return;
    default: bierman_small_t<4>(s); return;
    }
}

// The compiled regressor's sample (kernels.hpp, RegStep). A block's four sums stay in
// registers (one vector of four, or two of two); even and odd columns go to separate sums,
// which halves the chain of dependent adds. The filter runs on whole vectors of entries:
// one biquad's coefficients for all, each entry its own delays.
void regressor_step(const RegStep &s) {
    const idx np = s.n_pad;
    double *out = s.out;
    if (s.linear) {
        const double *A = s.A, *win = s.window;
        const idx *col = s.col;
        static_assert(W == 2 || W == 4, "a block of four entries is two vectors or one");
        constexpr bool two = W == 2;
        for (idx b = 0; b < np / 4; ++b) {
            const idx k1 = s.block[b + 1];
            vd e0 = vsplat(0.0), e1 = e0, o0 = e0, o1 = e0;
            idx k = s.block[b];
            for (; k + 1 < k1; k += 2) {
                const vd v0 = vbroadcast(win + col[k]), v1 = vbroadcast(win + col[k + 1]);
                const double *a = A + 4 * k;
                e0 += vload(a) * v0;
                o0 += vload(a + 4) * v1;
                if constexpr (two) {
                    e1 += vload(a + 2) * v0;
                    o1 += vload(a + 6) * v1;
                }
            }
            if (k < k1) {
                const vd v0 = vbroadcast(win + col[k]);
                e0 += vload(A + 4 * k) * v0;
                if constexpr (two) e1 += vload(A + 4 * k + 2) * v0;
            }
            vstore(out + 4 * b, e0 + o0);
            if constexpr (two) vstore(out + 4 * b + 2, e1 + o1);
        }
        for (idx c = 0; c < s.n_cubic; ++c) {
            const RegCubic &e = s.cubic[c];
            double r = 0.0;
            for (idx t = 0; t < e.n_taps; ++t) r += e.w[t] * win[col[e.tap[t]]];
            out[e.out] += e.coef * (r * r * r);
        }
    }
    if (!s.sec) return;
    const double *c = s.sec;
    double *z = s.z;
    for (idx i = 0; i < np; i += W) {
        vd v = vload(out + i);
#pragma GCC unroll 2
        for (idx q = 0; q < 2; ++q) {
            const double *sq = c + 5 * q;
            double *z0 = z + 2 * q * np + i, *z1 = z0 + np;
            const vd o = vbroadcast(sq) * v + vload(z0);
            vstore(z0, vbroadcast(sq + 1) * v - vbroadcast(sq + 3) * o + vload(z1));
            vstore(z1, vbroadcast(sq + 2) * v - vbroadcast(sq + 4) * o);
            v = o;
        }
        vstore(out + i, v);
    }
}

// Scaled (overflow- and underflow-safe) Householder quantities for [alpha; a]: returns
// false when a is exactly zero (nothing to do), else sets beta = |[alpha; a]| and
// v0 = alpha - beta, computed without cancellation.
inline bool householder_scaled(double alpha, const double *a, idx b, double &beta, double &v0) {
    double m = __builtin_fabs(alpha), am = 0.0;
    for (idx i = 0; i < b; ++i) { const double fa = __builtin_fabs(a[i]); am = fa > am ? fa : am; }
    if (am == 0.0) return false;
    m = am > m ? am : m;
    const double rm = 1.0 / m;
    double ss = 0.0;
    for (idx i = 0; i < b; ++i) ss += (a[i] * rm) * (a[i] * rm);
    const double al = alpha * rm;
    const double nrm = __builtin_sqrt(al * al + ss);
    beta = m * nrm;
    v0 = m * (al <= 0.0 ? al - nrm : -ss / (al + nrm));
    return true;
}

void qr_merge(idx n, double *R, idx b, double *A, idx lda) {
    for (idx j = 0; j < n; ++j) {
        double *a = A + j * lda;
        const double ss = dot_i(a, a, b);
        const double alpha = R[j * n + j];
        const double t = alpha * alpha + ss;
        double beta, v0;
        if (ss != 0.0 && t >= 1e-280 && t <= 1e280) {
            beta = __builtin_sqrt(t);
            // v0 = alpha - beta; for alpha > 0 the same value as -ss / (alpha + beta)
            // without cancellation (LAPACK's dlarfgp): R's diagonal stays >= 0.
            v0 = alpha <= 0.0 ? alpha - beta : -ss / (alpha + beta);
        } else if (!householder_scaled(alpha, a, b, beta, v0)) {
            continue;  // the block is zero in this column: R's row j stays as it is
        }
        if (v0 == 0.0) continue;  // a negligible beside alpha (underflow): nothing to rotate
        // H = I - tau v v^T with v = [1; a / v0] maps [alpha; a] to [beta; 0]. For a column
        // l: w = R(j, l) + v_a . A(:, l); R(j, l) -= tau w; A(:, l) -= tau w v_a. The scale
        // 1 / v0 is folded into the scalars so that a is used as it is.
        // tau = (beta - alpha) / beta, written as -v0 / beta: for alpha > 0 the difference
        // beta - alpha cancels, v0 was computed without it.
        const double tau = -v0 / beta;
        const double s = 1.0 / v0;
        R[j * n + j] = beta;
        double *Rj = R + j * n;
        idx l = j + 1;
        // Two columns per sweep: a is loaded once for both.
        for (; l + 1 < n; l += 2) {
            double *c0 = A + l * lda, *c1 = c0 + lda;
            vd s0 = vsplat(0.0), s1 = vsplat(0.0);
            idx i = 0;
            for (; i + W <= b; i += W) {
                const vd av = vload(a + i);
                s0 += av * vload(c0 + i);
                s1 += av * vload(c1 + i);
            }
            double d0 = hsum(s0), d1 = hsum(s1);
            for (; i < b; ++i) {
                d0 += a[i] * c0[i];
                d1 += a[i] * c1[i];
            }
            const double w0 = Rj[l] + s * d0, w1 = Rj[l + 1] + s * d1;
            Rj[l] -= tau * w0;
            Rj[l + 1] -= tau * w1;
            const double k0 = -tau * w0 * s, k1 = -tau * w1 * s;
            const vd kv0 = vsplat(k0), kv1 = vsplat(k1);
            i = 0;
            for (; i + W <= b; i += W) {
                const vd av = vload(a + i);
                vstore(c0 + i, vload(c0 + i) + kv0 * av);
                vstore(c1 + i, vload(c1 + i) + kv1 * av);
            }
            for (; i < b; ++i) {
                c0[i] += k0 * a[i];
                c1[i] += k1 * a[i];
            }
        }
        if (l < n) {
            double *c0 = A + l * lda;
            const double w0 = Rj[l] + s * dot_i(a, c0, b);
            Rj[l] -= tau * w0;
            const double k0 = -tau * w0 * s;
            const vd kv0 = vsplat(k0);
            idx i = 0;
            for (; i + W <= b; i += W) vstore(c0 + i, vload(c0 + i) + kv0 * vload(a + i));
            for (; i < b; ++i) c0[i] += k0 * a[i];
        }
    }
}

}  // namespace
