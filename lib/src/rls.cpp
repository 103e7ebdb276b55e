// rls.cpp: recursive least squares (paper (2.5)-(2.10)) in Bierman's UD form and in
// the plain covariance form, behind the C API of vibid/rls.h.
//
// State and roll-back. The state that an update changes (U or P, D, Theta, trace) lives
// in two preallocated slots. An update reads the current slot and writes the other one
// (the first equation of a sample out of place, the others in place), checks the
// result, and commits by flipping the slot index. A numerical breakdown (a D entry or
// innovation variance that is not positive and finite, an overflow anywhere in the new
// state) is therefore undone for free: the current slot was never touched. This costs
// one extra copy of the state in memory but no copy per update, and keeps the
// operation count fixed. set_prior and set_equation_covariance likewise build their
// result in scratch and copy it in only once it is known to be valid.
//
// Everything the per-sample functions touch is allocated in create; they use Eigen
// maps over the caller's arrays, column-wise vector kernels and explicit loops, never a
// matrix-matrix product (whose blocking workspace may come from the heap).
//
// Cost. The Bierman update's inner loops are the kernels of kernels.hpp (one pass for
// U^T x, one fused pass that updates U, the gain and the trace), chosen once for the CPU.
// For small p with one output (the structured form; example 1 has p = 3, m = 2) one call
// does all equations of a sample with the state in registers between them (bierman_small).
// The per-call checks cost nothing on the accepted path: the input is not scanned before
// the update, because every non-finite x or y entry makes the update itself fail (x
// reaches alpha, or the innovation variance in the covariance form, y reaches the a-priori
// error and hence Theta and V), and the result is checked anyway. Only a failed update
// scans x and y, to report VIBID_E_NONFINITE with the offending entry rather than
// VIBID_E_NUMERICAL; the committed state is untouched either way.
#include <vibid/rls.h>

#include "api_guard.hpp"
#include "kernels.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

// VIBID_FAIL for use inside VIBID_GUARD's lambda, where __func__ would name the lambda:
// each entry point captures its own name as fn first.
#define RLS_FAIL(status, ...) (::vibid::set_last_error(fn, __VA_ARGS__), (status))

namespace {

using Eigen::Index;
using Mat = Eigen::MatrixXd;
using Vec = Eigen::VectorXd;
using CMapV = Eigen::Map<const Vec>;
using MapV = Eigen::Map<Vec>;
using CMapM = Eigen::Map<const Mat>;
using MapM = Eigen::Map<Mat>;

constexpr size_t kMaxDim = 1024;
// Relative asymmetry |A_ij - A_ji| <= kSymTol sqrt(|A_ii A_jj|) accepted in a matrix the
// caller declares symmetric: covers rounding in e.g. (R^T R)^-1 from a batch solve,
// rejects a matrix that is simply not symmetric. The mean of both triangles is used.
constexpr double kSymTol = 1e-9;

inline bool pos_finite(double v) { return v > 0.0 && v <= std::numeric_limits<double>::max(); }

// Index of the first non-finite value of v[0..n), or n if all are finite.
size_t first_nonfinite(const double *v, size_t n) {
    for (size_t i = 0; i < n; ++i)
        if (!std::isfinite(v[i])) return i;
    return n;
}

// Checks that the n x n column-major A is finite and symmetric (kSymTol). On failure
// returns the status and writes the message for argument `name` via VIBID_FAIL in the
// calling entry point; here it only reports what is wrong through (i, j).
enum class SymCheck { ok, nonfinite, asymmetric };
SymCheck check_symmetric(const double *a, Index n, Index &bad_i, Index &bad_j) {
    for (Index j = 0; j < n; ++j)
        for (Index i = 0; i < n; ++i)
            if (!std::isfinite(a[i + j * n])) {
                bad_i = i;
                bad_j = j;
                return SymCheck::nonfinite;
            }
    for (Index j = 0; j < n; ++j)
        for (Index i = 0; i < j; ++i) {
            const double tol = kSymTol * std::sqrt(std::fabs(a[i + i * n] * a[j + j * n]));
            if (std::fabs(a[i + j * n] - a[j + i * n]) > tol) {
                bad_i = i;
                bad_j = j;
                return SymCheck::asymmetric;
            }
        }
    return SymCheck::ok;
}

// x^T P x for P = U D U^T (the innovation variance minus 1 when nothing adapts).
double ud_quadratic(Index p, const double *u, const double *d, const double *x) {
    double s = 0.0;
    for (Index j = 0; j < p; ++j) {
        const double fj = x[j] + CMapV(u + j * p, j).dot(CMapV(x, j));
        s += d[j] * fj * fj;
    }
    return s;
}

// One covariance-form update P <- (I - K x^T) P / g, K = P x / (g + x^T P x), reading
// ps and writing pd (may be the same array). x^T P is taken as (P x)^T, exact for the
// symmetric P of exact arithmetic; nothing is symmetrised, so rounding asymmetry stays
// (this is the textbook form kept for comparison). Writes phi = P x and the gain K;
// returns 1 + x^T (P / g) x. ok is cleared on a non-positive or non-finite innovation
// variance or a non-finite new P.
double covariance_update(Index p, const double *ps, double *pd, double g, const double *x, double *phi,
                         double *gain, double &trace, bool &ok) {
    CMapM P(ps, p, p);
    CMapV xv(x, p);
    MapV ph(phi, p);
    MapV K(gain, p);
    ph.noalias() = P * xv;
    const double den = g + xv.dot(ph);
    const double c = 1.0 / g;
    K = ph / den;
    double check = 0.0;
    for (Index j = 0; j < p; ++j) {
        MapV col(pd + j * p, p);
        col = c * (CMapV(ps + j * p, p) - ph[j] * K);
        // A sum over the column is NaN/Inf iff an entry is (or the column overflows).
        check += col.sum();
    }
    trace = MapM(pd, p, p).diagonal().sum();
    ok = ok && pos_finite(den) && std::isfinite(check) && std::isfinite(trace);
    return den * c;
}

}  // namespace

// The estimator. Slots hold the state an update changes; see the file comment.
struct vibid_rls {
    struct Slot {
        Mat M;      // Bierman: U (unit upper triangular, strict upper part used); covariance form: P
        Vec D;      // Bierman: D; covariance form: scratch for the positive-definiteness check
        Mat theta;  // p x q
        Mat V;      // q x q residual sum of squares (forgotten)
        double trace = 0.0;
    };

    Index p, q, m;
    vibid_rls_form form;
    double gamma, alpha;
    double inv_gamma;  // 1 / gamma, the D scale of the forgetting step
    bool trace_bound;
    double trace_max;

    Slot slot[2];
    int cur = 0;
    Slot prior;

    Mat V_work;  // q x q scratch: the residual sum of squares being built
    double n_eff = 0.0;
    unsigned long long n_samples = 0;
    double last_forgetting;
    bool adapt = true;

    bool whiten = false;
    Mat L, L_work;  // m x m lower Cholesky factor of the equation covariance
    Mat xw, yw;     // whitened sample, p x m and m x q

    Vec b, K, work, e;  // p, p, 2p, q scratch
    // Kernel arguments, built once (the slots never reallocate): step_out[c] reads slot c
    // and writes slot 1 - c (first equation of a sample), step_in[c] works in place on
    // slot c (later equations). A call sets only the forgetting, x and y.
    vibid::kern::RlsStep step_out[2], step_in[2];
    const vibid::kern::Table *kt;  // kernels for this CPU, fixed at create
    bool small;                    // whole samples through kt->bierman_small (set in create)

    explicit vibid_rls(const vibid_rls_config &c)
        : p(static_cast<Index>(c.n_params)),
          q(static_cast<Index>(c.n_outputs)),
          m(static_cast<Index>(c.n_equations)),
          form(c.form),
          gamma(c.forgetting),
          alpha(c.alpha),
          inv_gamma(1.0 / c.forgetting),
          trace_bound(c.windup == VIBID_RLS_WINDUP_TRACE_BOUND),
          trace_max(c.trace_max),
          last_forgetting(c.forgetting) {
        for (Slot *s : {&slot[0], &slot[1], &prior}) {
            s->M.setIdentity(p, p);
            s->D.setZero(p);
            s->theta.setZero(p, q);
            s->V.setZero(q, q);
        }
        // Default prior: Theta = 0, P = alpha^-1 I, i.e. U = I, D = alpha^-1 (or P itself).
        if (form == VIBID_RLS_FORM_BIERMAN_UD)
            prior.D.setConstant(1.0 / alpha);
        else
            prior.M *= 1.0 / alpha;
        prior.trace = static_cast<double>(p) / alpha;
        V_work.setZero(q, q);
        L.setIdentity(m, m);
        L_work.setIdentity(m, m);
        xw.setZero(p, m);
        yw.setZero(m, q);
        b.setZero(p);
        K.setZero(p);
        work.setZero(2 * p);
        e.setZero(q);
        kt = &vibid::kern::active();
        // At p = kSmallP with one equation nothing stays in registers between equations,
        // and the copies in and out made the baseline kernels 5 % slower there.
        small = form == VIBID_RLS_FORM_BIERMAN_UD && q == 1 &&
                (p < vibid::kern::kSmallP || (p == vibid::kern::kSmallP && m > 1));
        for (int k = 0; k < 2; ++k) {
            build_step(step_out[k], slot[k], slot[1 - k]);
            build_step(step_in[k], slot[k], slot[k]);
        }
        reset();
    }

    void build_step(vibid::kern::RlsStep &st, Slot &from, Slot &to) {
        st = vibid::kern::RlsStep{};
        st.p = p;
        st.q = q;
        st.ld = p;
        st.ystride = m;
        st.m = m;
        st.us = from.M.data();
        st.ud = to.M.data();
        st.ds = from.D.data();
        st.dd = to.D.data();
        st.ths = from.theta.data();
        st.thd = to.theta.data();
        st.Vs = from.V.data();
        st.Vd = to.V.data();
        st.b = b.data();
        st.e = e.data();
        st.work = work.data();
    }

    bool bierman() const { return form == VIBID_RLS_FORM_BIERMAN_UD; }
    const Slot &state() const { return slot[cur]; }

    void reset() {
        Slot &s = slot[cur];
        s.M = prior.M;
        s.D = prior.D;
        s.theta = prior.theta;
        s.trace = prior.trace;
        s.V.setZero();
        n_eff = 0.0;
        n_samples = 0;
        last_forgetting = gamma;
        adapt = true;
    }

    // Whitens one sample with L (forward substitution), writing xw and yw.
    void whiten_sample(const double *x, const double *y) {
        CMapM X(x, p, m), Y(y, m, q);
        for (Index i = 0; i < m; ++i) {
            xw.col(i) = X.col(i);
            yw.row(i) = Y.row(i);
            for (Index k = 0; k < i; ++k) {
                xw.col(i) -= L(i, k) * xw.col(k);
                yw.row(i) -= L(i, k) * yw.row(k);
            }
            xw.col(i) /= L(i, i);
            yw.row(i) /= L(i, i);
        }
    }

    // e = y(i, :)^T - theta^T x_i (the a-priori error of equation i), q dot products.
    void prior_error(const Mat &theta, const double *xi, const double *y, Index i) {
        for (Index j = 0; j < q; ++j) e[j] = y[i + j * m] - kt->dot(theta.data() + j * p, xi, p);
    }

    // Vacc += e e^T / s, column by column (an outer product could need a temporary);
    // returns the sum of the new entries (finiteness check, as for Theta).
    double accumulate_residual(Mat &Vacc, double s) {
        const double inv = 1.0 / s;
        double sum = 0.0;
        for (Index k = 0; k < q; ++k)
            sum += kt->axpy_sum(q, e[k] * inv, e.data(), Vacc.data() + k * q, Vacc.data() + k * q);
        return sum;
    }

    // Adaptation frozen: only the residual statistics move, with the nominal forgetting.
    bool observe(const double *xe, const double *ye) {
        const Slot &s = slot[cur];
        V_work = gamma * s.V;
        for (Index i = 0; i < m; ++i) {
            const double *xi = xe + i * p;
            prior_error(s.theta, xi, ye, i);
            double quad;
            if (bierman()) {
                quad = ud_quadratic(p, s.M.data(), s.D.data(), xi);
            } else {
                MapV phi(b.data(), p);
                phi.noalias() = s.M * CMapV(xi, p);
                quad = CMapV(xi, p).dot(phi);
            }
            if (!pos_finite(1.0 + quad)) return false;
            accumulate_residual(V_work, 1.0 + quad);
        }
        if (!V_work.allFinite()) return false;
        slot[cur].V = V_work;
        n_eff = gamma * n_eff + static_cast<double>(m);
        last_forgetting = gamma;
        ++n_samples;
        return true;
    }

    // Forgetting for this sample: the nominal gamma, raised (less forgetting) just enough
    // that the forgetting step P / gamma_eff keeps trace(P) <= trace_max. The measurement
    // step only lowers P, so the bound then holds after the whole update. Never above 1:
    // a start state above the bound only suspends forgetting until data lower it.
    double forgetting_now() const {
        if (!trace_bound) return gamma;
        return std::min(1.0, std::max(gamma, slot[cur].trace / trace_max));
    }

    // The D scale of the forgetting step, 1 / g: no division per sample at the nominal g.
    double forgetting_scale(double g) const { return g == gamma ? inv_gamma : 1.0 / g; }

    bool adapt_sample(const double *xe, const double *ye) {
        const Slot &src = slot[cur];
        Slot &dst = slot[1 - cur];
        const double g = forgetting_now();
        bool ok = true;
        // Sums of every new Theta and V entry: finite unless an entry is not (or the sum
        // alone overflows, which the exact scan below tells apart).
        double theta_sum = 0.0, v_sum = 0.0;
        for (Index i = 0; i < m && ok; ++i) {
            const double *xi = xe + i * p;
            const bool first = (i == 0);
            const Slot &from = first ? src : dst;
            if (bierman()) {
                // The first equation reads the committed slot and writes the other; later
                // equations of the sample work in place on the uncommitted slot.
                vibid::kern::RlsStep &st = first ? step_out[cur] : step_in[1 - cur];
                st.dscale = first ? forgetting_scale(g) : 1.0;
                st.vscale = first ? g : 1.0;
                st.x = xi;
                st.y = ye + i;
                kt->bierman_step(st);
                ok = ok && st.ok;
                dst.trace = st.trace;
                theta_sum = st.theta_sum;
                v_sum = st.v_sum;
            } else {
                prior_error(from.theta, xi, ye, i);
                if (first) dst.V = g * src.V;
                const double s = covariance_update(p, from.M.data(), dst.M.data(), first ? g : 1.0, xi, b.data(),
                                                   K.data(), dst.trace, ok);
                theta_sum = 0.0;
                for (Index j = 0; j < q; ++j)
                    theta_sum += kt->axpy_sum(p, e[j], K.data(), from.theta.data() + j * p, dst.theta.data() + j * p);
                v_sum = accumulate_residual(dst.V, s);
            }
        }
        return ok && commit(g, theta_sum, v_sum);
    }

    // adapt_sample for the small Bierman case (`small`): the whole sample in one kernel call,
    // from the committed slot into the other.
    bool adapt_small(const double *xe, const double *ye) {
        const double g = forgetting_now();
        vibid::kern::RlsStep &st = step_out[cur];
        st.dscale = forgetting_scale(g);
        st.vscale = g;
        st.x = xe;
        st.y = ye;
        kt->bierman_small(st);
        slot[1 - cur].trace = st.trace;
        return st.ok && commit(g, st.theta_sum, st.v_sum);
    }

    // Makes the uncommitted slot, just written with forgetting g, the state, unless an
    // entry of its Theta or V is not finite (told by the sums of the new entries, confirmed
    // by a scan: a sum alone may overflow).
    bool commit(double g, double theta_sum, double v_sum) {
        const Slot &dst = slot[1 - cur];
        if (!std::isfinite(theta_sum) && !dst.theta.allFinite()) return false;
        if (!std::isfinite(v_sum) && !dst.V.allFinite()) return false;
        cur = 1 - cur;
        n_eff = g * n_eff + static_cast<double>(m);
        last_forgetting = g;
        ++n_samples;
        return true;
    }
};

namespace {

vibid_rls *make_rls(const vibid_rls_config *cfg) {
    using vibid::throw_error;
    if (!cfg) throw_error(VIBID_E_NULL_ARGUMENT, "cfg is NULL");
    if (cfg->n_params < 1 || cfg->n_params > kMaxDim)
        throw_error(VIBID_E_DIMENSION, "n_params = %zu outside 1..%zu", cfg->n_params, kMaxDim);
    if (cfg->n_outputs < 1 || cfg->n_outputs > kMaxDim)
        throw_error(VIBID_E_DIMENSION, "n_outputs = %zu outside 1..%zu", cfg->n_outputs, kMaxDim);
    if (cfg->n_equations < 1 || cfg->n_equations > kMaxDim)
        throw_error(VIBID_E_DIMENSION, "n_equations = %zu outside 1..%zu", cfg->n_equations, kMaxDim);
    const int form = vibid::enum_value(cfg->form), windup = vibid::enum_value(cfg->windup);
    if (form != VIBID_RLS_FORM_BIERMAN_UD && form != VIBID_RLS_FORM_COVARIANCE)
        throw_error(VIBID_E_OUT_OF_RANGE, "form = %d is not a vibid_rls_form", form);
    if (!(cfg->forgetting > 0.0 && cfg->forgetting <= 1.0))
        throw_error(VIBID_E_OUT_OF_RANGE, "forgetting = %g outside (0, 1]", cfg->forgetting);
    if (!(pos_finite(cfg->alpha) && pos_finite(1.0 / cfg->alpha) &&
          pos_finite(static_cast<double>(cfg->n_params) / cfg->alpha)))
        throw_error(VIBID_E_OUT_OF_RANGE, "alpha = %g: needs alpha > 0 with n_params / alpha finite",
                    cfg->alpha);
    if (windup != VIBID_RLS_WINDUP_NONE && windup != VIBID_RLS_WINDUP_TRACE_BOUND)
        throw_error(VIBID_E_OUT_OF_RANGE, "windup = %d is not a vibid_rls_windup", windup);
    if (windup == VIBID_RLS_WINDUP_TRACE_BOUND && !pos_finite(cfg->trace_max))
        throw_error(VIBID_E_OUT_OF_RANGE, "trace_max = %g: must be > 0 and finite", cfg->trace_max);
    return new vibid_rls(*cfg);
}

}  // namespace

extern "C" {

VIBID_API void vibid_rls_config_init(vibid_rls_config *cfg, size_t n_params, size_t n_outputs) {
    if (!cfg) return;
    std::memset(cfg, 0, sizeof *cfg);
    cfg->n_params = n_params;
    cfg->n_outputs = n_outputs;
    cfg->n_equations = 1;
    cfg->form = VIBID_RLS_FORM_BIERMAN_UD;
    cfg->forgetting = 1.0;
    cfg->alpha = 1e-6;
    cfg->windup = VIBID_RLS_WINDUP_NONE;
    cfg->trace_max = static_cast<double>(n_params) / cfg->alpha;
}

VIBID_API vibid_rls *vibid_rls_create(const vibid_rls_config *cfg) {
    return vibid::guard_create<vibid_rls>(__func__, [&] { return make_rls(cfg); });
}

VIBID_API vibid_status vibid_rls_reset(vibid_rls *rls) {
    const char *const fn = __func__;
    VIBID_GUARD({
        if (!rls) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "rls is NULL");
        rls->reset();
        return VIBID_OK;
    });
}

VIBID_API void vibid_rls_destroy(vibid_rls *rls) { delete rls; }

VIBID_API vibid_status vibid_rls_set_prior(vibid_rls *rls, const double *theta0, const double *P0) {
    const char *const fn = __func__;
    VIBID_GUARD({
        if (!rls) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "rls is NULL");
        const Index p = rls->p, q = rls->q;
        if (theta0) {
            const size_t bad = first_nonfinite(theta0, static_cast<size_t>(p * q));
            if (bad < static_cast<size_t>(p * q))
                return RLS_FAIL(VIBID_E_NONFINITE, "theta0[%zu] = %g is not finite", bad, theta0[bad]);
        }
        // Build the new start state in the spare slot; nothing visible changes on failure.
        vibid_rls::Slot &w = rls->slot[1 - rls->cur];
        if (P0) {
            Index bi = 0, bj = 0;
            switch (check_symmetric(P0, p, bi, bj)) {
            case SymCheck::nonfinite:
                return RLS_FAIL(VIBID_E_NONFINITE, "P0(%td, %td) = %g is not finite", bi, bj, P0[bi + bj * p]);
            case SymCheck::asymmetric:
                return RLS_FAIL(VIBID_E_OUT_OF_RANGE, "P0 is not symmetric: P0(%td, %td) = %g, P0(%td, %td) = %g",
                                  bi, bj, P0[bi + bj * p], bj, bi, P0[bj + bi * p]);
            case SymCheck::ok: break;
            }
            // UD factorisation of the symmetrised P0, last column first; it is the state
            // of the Bierman form and the positive-definiteness test of both forms.
            CMapM A(P0, p, p);
            Mat &U = w.M;
            Vec &D = w.D;
            U.setIdentity();
            for (Index j = p - 1; j >= 0; --j) {
                double dj = A(j, j);
                for (Index k = j + 1; k < p; ++k) dj -= D[k] * U(j, k) * U(j, k);
                if (!pos_finite(dj))
                    return RLS_FAIL(VIBID_E_NUMERICAL,
                                      "P0 is not positive definite (UD pivot %td = %g)", j, dj);
                D[j] = dj;
                for (Index i = 0; i < j; ++i) {
                    double s = 0.5 * (A(i, j) + A(j, i));
                    for (Index k = j + 1; k < p; ++k) s -= D[k] * U(i, k) * U(j, k);
                    U(i, j) = s / dj;
                }
            }
            if (rls->bierman()) {
                w.trace = 0.0;
                for (Index j = 0; j < p; ++j) w.trace += D[j] * (1.0 + U.col(j).head(j).squaredNorm());
            } else {
                U = 0.5 * (A + A.transpose());
                w.trace = U.trace();
            }
        } else {
            w.M.setIdentity();
            w.D.setConstant(1.0 / rls->alpha);
            if (!rls->bierman()) w.M *= 1.0 / rls->alpha;
            w.trace = static_cast<double>(p) / rls->alpha;
        }
        if (theta0)
            w.theta = CMapM(theta0, p, q);
        else
            w.theta.setZero();
        rls->prior.M = w.M;
        rls->prior.D = w.D;
        rls->prior.theta = w.theta;
        rls->prior.trace = w.trace;
        rls->reset();
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_rls_set_equation_covariance(vibid_rls *rls, const double *Sigma) {
    const char *const fn = __func__;
    VIBID_GUARD({
        if (!rls) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "rls is NULL");
        const Index m = rls->m;
        if (!Sigma) {
            rls->whiten = false;
            rls->L.setIdentity();
            return VIBID_OK;
        }
        Index bi = 0, bj = 0;
        switch (check_symmetric(Sigma, m, bi, bj)) {
        case SymCheck::nonfinite:
            return RLS_FAIL(VIBID_E_NONFINITE, "Sigma(%td, %td) = %g is not finite", bi, bj, Sigma[bi + bj * m]);
        case SymCheck::asymmetric:
            return RLS_FAIL(VIBID_E_OUT_OF_RANGE, "Sigma is not symmetric: Sigma(%td, %td) = %g, Sigma(%td, %td) = %g",
                              bi, bj, Sigma[bi + bj * m], bj, bi, Sigma[bj + bi * m]);
        case SymCheck::ok: break;
        }
        // Cholesky Sigma = L L^T (lower triangle of the symmetrised Sigma) into scratch.
        CMapM S(Sigma, m, m);
        Mat &L = rls->L_work;
        L.setZero();
        for (Index j = 0; j < m; ++j) {
            double d = S(j, j) - L.row(j).head(j).squaredNorm();
            if (!pos_finite(d))
                return RLS_FAIL(VIBID_E_NUMERICAL, "Sigma is not positive definite (Cholesky pivot %td = %g)", j, d);
            L(j, j) = std::sqrt(d);
            for (Index i = j + 1; i < m; ++i)
                L(i, j) = (0.5 * (S(i, j) + S(j, i)) - L.row(i).head(j).dot(L.row(j).head(j))) / L(j, j);
        }
        rls->L = L;
        rls->whiten = true;
        return VIBID_OK;
    });
}

// Real-time path: nothing here throws or allocates, so there is no exception guard (its
// entry bookkeeping is a thread-local store and restore per call).
VIBID_API vibid_status vibid_rls_update(vibid_rls *rls, const double *x, const double *y) {
    const char *const fn = __func__;
    if (!rls) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "rls is NULL");
    if (!x) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "x is NULL");
    if (!y) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "y is NULL");
    const double *xe = x, *ye = y;
    if (rls->whiten) {
        rls->whiten_sample(x, y);
        xe = rls->xw.data();
        ye = rls->yw.data();
    }
    // Optimistic: update first, classify a failure after (see the file comment). A
    // failed update has not touched the committed state.
    if (!rls->adapt ? rls->observe(xe, ye) : rls->small ? rls->adapt_small(xe, ye) : rls->adapt_sample(xe, ye))
        return VIBID_OK;
    const size_t nx = static_cast<size_t>(rls->p * rls->m), ny = static_cast<size_t>(rls->m * rls->q);
    size_t bad = first_nonfinite(x, nx);
    if (bad < nx) return RLS_FAIL(VIBID_E_NONFINITE, "x[%zu] = %g is not finite", bad, x[bad]);
    bad = first_nonfinite(y, ny);
    if (bad < ny) return RLS_FAIL(VIBID_E_NONFINITE, "y[%zu] = %g is not finite", bad, y[bad]);
    if (rls->adapt)
        return RLS_FAIL(VIBID_E_NUMERICAL,
                        "sample rejected: the update would leave P not positive definite or not "
                        "finite (trace(P) = %g now); estimator unchanged",
                        rls->state().trace);
    return RLS_FAIL(VIBID_E_NUMERICAL, "sample rejected: residual statistics overflow; estimator unchanged");
}

VIBID_API vibid_status vibid_rls_set_adaptation(vibid_rls *rls, int enabled) {
    const char *const fn = __func__;
    VIBID_GUARD({
        if (!rls) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "rls is NULL");
        rls->adapt = (enabled != 0);
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_rls_predict(const vibid_rls *rls, const double *x, double *y) {
    const char *const fn = __func__;
    VIBID_GUARD({
        if (!rls) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "rls is NULL");
        if (!x) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "x is NULL");
        if (!y) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "y is NULL");
        const size_t nx = static_cast<size_t>(rls->p * rls->m);
        const size_t bad = first_nonfinite(x, nx);
        if (bad < nx) return RLS_FAIL(VIBID_E_NONFINITE, "x[%zu] = %g is not finite", bad, x[bad]);
        const Mat &theta = rls->state().theta;
        CMapM X(x, rls->p, rls->m);
        MapM Y(y, rls->m, rls->q);
        for (Index j = 0; j < rls->q; ++j)
            for (Index i = 0; i < rls->m; ++i) Y(i, j) = X.col(i).dot(theta.col(j));
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_rls_theta(const vibid_rls *rls, double *theta) {
    const char *const fn = __func__;
    VIBID_GUARD({
        if (!rls) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "rls is NULL");
        if (!theta) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "theta is NULL");
        MapM(theta, rls->p, rls->q) = rls->state().theta;
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_rls_covariance(const vibid_rls *rls, double *P) {
    const char *const fn = __func__;
    VIBID_GUARD({
        if (!rls) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "rls is NULL");
        if (!P) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "P is NULL");
        const Index p = rls->p;
        const vibid_rls::Slot &s = rls->state();
        MapM out(P, p, p);
        if (!rls->bierman()) {
            out = s.M;
            return VIBID_OK;
        }
        // P = sum_j D_j u_j u_j^T, u_j = column j of U (nonzero in rows 0..j); the upper
        // triangle column by column, then mirrored so that P is exactly symmetric.
        // p^3 / 6 multiply-adds, no temporaries.
        out.setZero();
        for (Index j = 0; j < p; ++j) {
            const double *uj = s.M.data() + j * p;
            for (Index k = 0; k <= j; ++k) {
                const double ukj = (k == j) ? 1.0 : uj[k];  // unit diagonal is implicit
                const double c = s.D[j] * ukj;
                out.col(k).head(k) += c * CMapV(uj, k);
                out(k, k) += c * ukj;
            }
        }
        for (Index k = 0; k < p; ++k) out.row(k).head(k) = out.col(k).head(k).transpose();
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_rls_residual_covariance(const vibid_rls *rls, double *Sigma_e) {
    const char *const fn = __func__;
    VIBID_GUARD({
        if (!rls) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "rls is NULL");
        if (!Sigma_e) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "Sigma_e is NULL");
        const double dof = rls->n_eff - static_cast<double>(rls->p);
        if (!(dof > 0.0))
            return RLS_FAIL(VIBID_E_INSUFFICIENT_DATA, "n_eff = %g not above n_params = %td", rls->n_eff, rls->p);
        MapM(Sigma_e, rls->q, rls->q) = rls->state().V / dof;
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_rls_stderr(const vibid_rls *rls, double *stderr_out) {
    const char *const fn = __func__;
    VIBID_GUARD({
        if (!rls) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "rls is NULL");
        if (!stderr_out) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "stderr_out is NULL");
        const Index p = rls->p, q = rls->q;
        const double dof = rls->n_eff - static_cast<double>(p);
        if (!(dof > 0.0))
            return RLS_FAIL(VIBID_E_INSUFFICIENT_DATA, "n_eff = %g not above n_params = %td", rls->n_eff, p);
        const vibid_rls::Slot &s = rls->state();
        MapM out(stderr_out, p, q);
        for (Index i = 0; i < p; ++i) {
            // P_ii: D_i + sum_{j > i} D_j U_ij^2 (Bierman), or the stored diagonal.
            double pii;
            if (rls->bierman()) {
                pii = s.D[i];
                for (Index j = i + 1; j < p; ++j) pii += s.D[j] * s.M(i, j) * s.M(i, j);
            } else {
                pii = s.M(i, i);
            }
            // A covariance-form P that lost definiteness has no standard error: NaN says so.
            for (Index j = 0; j < q; ++j) out(i, j) = std::sqrt(pii * s.V(j, j) / dof);
        }
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_rls_get_stats(const vibid_rls *rls, vibid_rls_stats *stats) {
    const char *const fn = __func__;
    VIBID_GUARD({
        if (!rls) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "rls is NULL");
        if (!stats) return RLS_FAIL(VIBID_E_NULL_ARGUMENT, "stats is NULL");
        const vibid_rls::Slot &s = rls->state();
        stats->n_samples = rls->n_samples;
        stats->n_eff = rls->n_eff;
        stats->trace_p = s.trace;
        stats->min_d = rls->bierman() ? s.D.minCoeff() : s.M.diagonal().minCoeff();
        stats->last_forgetting = rls->last_forgetting;
        return VIBID_OK;
    });
}

}  // extern "C"
