// oma.cpp: covariance-driven stochastic subspace identification with first-order
// uncertainty (vibid/oma.h has the method and the contract).
#include <vibid/oma.h>

#include <Eigen/Dense>
#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdint>
#include <cstring>
#include <memory>
#include <numeric>
#include <vector>

#include "api_guard.hpp"

namespace {

using Eigen::Index;
using Eigen::MatrixXd;
using Eigen::VectorXd;
using cplx = std::complex<double>;
using MatrixXc = Eigen::MatrixXcd;
using VectorXc = Eigen::VectorXcd;

// One block's lagged products: lag k (1..n_lags) at [(k - 1) * nch * nref], an
// n_channels x n_refs column-major matrix each, and the number of products per lag.
struct BlockSums {
    std::vector<double> sum;
    std::vector<double> count;
    void zero() {
        std::fill(sum.begin(), sum.end(), 0.0);
        std::fill(count.begin(), count.end(), 0.0);
    }
};

struct Pole {
    std::size_t order;
    double f, f_se, zeta, zeta_se, mpc;
    bool stable = false, physical = false;
    long mode = -1;
    VectorXc shape;  // normalised to 1 at its largest component
};

double mac(const VectorXc &a, const VectorXc &b) {
    const double num = std::norm(a.dot(b));  // a^H b
    const double den = a.squaredNorm() * b.squaredNorm();
    return den > 0.0 ? num / den : 0.0;
}

// Pappa's modal phase collinearity of a complex shape: 1 for a real (classically damped)
// shape, near 0 for a travelling wave or noise.
double mpc(const VectorXc &phi) {
    const VectorXd re = phi.real(), im = phi.imag();
    const double sxx = re.squaredNorm(), syy = im.squaredNorm(), sxy = re.dot(im);
    const double den = (sxx + syy) * (sxx + syy);
    return den > 0.0 ? ((sxx - syy) * (sxx - syy) + 4.0 * sxy * sxy) / den : 0.0;
}

}  // namespace

struct vibid_oma {
    vibid_oma_config cfg{};
    std::vector<std::size_t> refs;
    std::size_t i = 0, nch = 0, nref = 0, n_lags = 0, lag_size = 0;
    // The last n_lags reference samples (ring; row j holds the refs of one sample).
    std::vector<double> ring;
    std::size_t ring_pos = 0, ring_fill = 0;
    // vibid_oma_push_block's scratch: the references of up to n_lags earlier samples and of
    // a run of up to kRunChunk samples, column-major with n_lags + kRunChunk rows; and the
    // longest product one GEMM call may take (run_depth; see accumulate_run).
    std::vector<double> run_refs;
    std::size_t run_depth = 0;
    BlockSums current;
    std::size_t current_samples = 0;
    std::vector<BlockSums> window;  // max_blocks slots
    std::size_t next_slot = 0, slots_filled = 0;
    uint64_t n_samples = 0, n_gaps = 0;
    // Results of the last identification.
    bool have_result = false;
    std::vector<Pole> poles;
    std::vector<std::size_t> modes;  // indices into poles (the medoids)
    std::vector<std::size_t> mode_sizes;
    VectorXd sv;
};

namespace {

void commit_block(vibid_oma &o) {
    std::swap(o.window[o.next_slot].sum, o.current.sum);
    std::swap(o.window[o.next_slot].count, o.current.count);
    o.current.zero();
    o.next_slot = (o.next_slot + 1) % o.window.size();
    o.slots_filled = std::min(o.slots_filled + 1, o.window.size());
    o.current_samples = 0;
}

void gap(vibid_oma &o) {
    o.ring_fill = 0;
    ++o.n_gaps;
}

void end_sample(vibid_oma &o) {
    ++o.n_samples;
    if (++o.current_samples == o.cfg.block_samples) commit_block(o);
}

// The products of sample y with the last ring_fill reference samples, then y's references
// into the ring. Allocation-free.
void accumulate(vibid_oma &o, const double *y, std::size_t stride) {
    const std::size_t nch = o.nch, nref = o.nref, L = o.n_lags;
    const std::size_t have = std::min(o.ring_fill, L);
    for (std::size_t k = 1; k <= have; ++k) {
        const double *past = &o.ring[((o.ring_pos + L - k) % L) * nref];
        double *S = &o.current.sum[(k - 1) * o.lag_size];
        for (std::size_t r = 0; r < nref; ++r) {
            const double pr = past[r];
            double *col = S + r * nch;
            for (std::size_t c = 0; c < nch; ++c) col[c] += y[c * stride] * pr;
        }
        o.current.count[k - 1] += 1.0;
    }
    double *slot = &o.ring[o.ring_pos * nref];
    for (std::size_t r = 0; r < nref; ++r) slot[r] = y[o.refs[r] * stride];
    o.ring_pos = (o.ring_pos + 1) % L;
    o.ring_fill = std::min(o.ring_fill + 1, L);
}

// vibid_oma_push_block's runs: samples per pass (the scratch's size; 32 kB of references per
// channel). Runs shorter than kMinRun go through accumulate: a few samples cost less than
// the n_lags product calls.
constexpr std::size_t kRunChunk = 4096, kMinRun = 4;

// The products of the finite samples t0 .. t0 + len - 1 of data (column-major, column
// stride ld; all in the current block) with the earlier references, the same sums as len
// calls of accumulate (to rounding), as one matrix product per lag:
// S_k += Y[t0 + s0 .. t0 + len)^T Ref[t0 + s0 - k .. t0 + len - k), where s0 = max(0, k - have)
// skips the later samples whose partner lies before the ring's oldest sample (a gap or the
// start). The earlier references come from the ring (samples before this run) and from the
// run itself, gathered into run_refs; the ring is left as len pushes would leave it.
// Allocation-free: Eigen's GEMM packs its operands into blocks of at most
// depth x max(n_channels, n_refs) values, taken from the stack (alloca) up to
// EIGEN_STACK_ALLOCATION_LIMIT bytes and from the heap above; run_depth keeps every call
// below that limit.
void accumulate_run(vibid_oma &o, const double *data, std::size_t ld, std::size_t t0, std::size_t len) {
    const std::size_t nch = o.nch, nref = o.nref, L = o.n_lags, lr = L + kRunChunk;
    const std::size_t have = std::min(o.ring_fill, L);
    double *R = o.run_refs.data();
    // Rows L - have .. L - 1: the ring's samples, oldest first (row L - k is k samples back).
    for (std::size_t k = 1; k <= have; ++k) {
        const double *past = &o.ring[((o.ring_pos + L - k) % L) * nref];
        for (std::size_t r = 0; r < nref; ++r) R[(L - k) + r * lr] = past[r];
    }
    for (std::size_t r = 0; r < nref; ++r)
        std::memcpy(R + L + r * lr, data + t0 + o.refs[r] * ld, len * sizeof(double));
    using CMap = Eigen::Map<const MatrixXd, 0, Eigen::OuterStride<>>;
    for (std::size_t k = 1; k <= L; ++k) {
        const std::size_t s0 = k > have ? k - have : 0;
        if (s0 >= len) break;  // and for every longer lag
        Eigen::Map<MatrixXd> S(&o.current.sum[(k - 1) * o.lag_size], static_cast<Index>(nch),
                               static_cast<Index>(nref));
        for (std::size_t s = s0; s < len; s += o.run_depth) {
            const Index m = static_cast<Index>(std::min(o.run_depth, len - s));
            const CMap Y(data + t0 + s, m, static_cast<Index>(nch), Eigen::OuterStride<>(static_cast<Index>(ld)));
            const CMap P(R + L + s - k, m, static_cast<Index>(nref), Eigen::OuterStride<>(static_cast<Index>(lr)));
            S.noalias() += Y.transpose() * P;
        }
        o.current.count[k - 1] += static_cast<double>(len - s0);
    }
    // The ring as len pushes leave it: the last min(len, L) references, ending before
    // ring_pos + len (mod L).
    const std::size_t w = std::min(len, L);
    o.ring_pos = (o.ring_pos + (len - w)) % L;
    for (std::size_t s = len - w; s < len; ++s) {
        double *slot = &o.ring[o.ring_pos * nref];
        for (std::size_t r = 0; r < nref; ++r) slot[r] = R[L + s + r * lr];
        o.ring_pos = (o.ring_pos + 1) % L;
    }
    o.ring_fill = std::min(o.ring_fill + len, L);
}

// The block Hankel matrix of covariances R_k = sum_k / count_k.
void hankel(const vibid_oma &o, const std::vector<double> &sum, const std::vector<double> &count, MatrixXd &H) {
    const Index nch = static_cast<Index>(o.nch), nref = static_cast<Index>(o.nref), i = static_cast<Index>(o.i);
    H.resize(i * nch, i * nref);
    for (Index a = 0; a < i; ++a)
        for (Index b = 0; b < i; ++b) {
            const std::size_t k = static_cast<std::size_t>(a + b + 1);
            const Eigen::Map<const MatrixXd> S(&sum[(k - 1) * o.lag_size], nch, nref);
            H.block(a * nch, b * nref, nch, nref) = S / count[k - 1];
        }
}

std::size_t max_order_bound(std::size_t i, std::size_t nch, std::size_t nref) {
    const std::size_t b = std::min((i - 1) * nch, i * nref);
    return b - b % 2;
}

// Each selected mode's values from one of its poles (oma.h, 6.): the one at the lowest
// order at or above n* (the lowest order at which the most modes have a pole, stable or
// not) whose frequency and damping standard errors are within kSeSlack of the smallest
// the mode's poles at or above n* have. Why: the first-order standard errors hold at
// orders where the truncation falls between well-separated singular values, and
// overstate the spread many times where it cuts into the noise floor (3-DOF chain, 60
// captures of 120 s, se / RMS error: order 6 0.99-1.1, order 10 up to 5, order 24 up to
// 45): the cluster's medoid, at a middle order, gave 2-se coverage of 99-100 % with se 2-4
// times the RMS error; the pole with the smallest se, 86 % on one mode of one set of
// captures (chosen for being small). Below n* the model lacks modes the data have, which
// biases the others; and at n* itself a mode may still be poorly determined where the
// excitation's own dynamics need more states (examples/oma/chain10.cfg, band-limited
// forces: the first mode at n* = 20 had zeta +76 % with standard errors 1.5 times those
// from order 26 on, where it is right). Coverage with this choice: tests/lib/test_oma.c.
constexpr double kSeSlack = 1.2;
// Stability of the damping ratio against the order below (step 5): within this many of the
// two poles' combined standard errors passes too (oma.h point 5).
constexpr double kStabDampingSe = 2.0;

void choose_representatives(vibid_oma &o, Eigen::Index nmax) {
    const std::size_t nm = o.modes.size();
    if (nm == 0) return;
    // A mode's poles at each order: physical poles, stable or not, within its cluster's
    // frequency span (widened by cluster_freq) and with MAC >= cluster_mac to its medoid.
    // (A mode that first appears at order n is stable only from n + 2 on.)
    std::vector<double> lo(nm, INFINITY), hi(nm, -INFINITY);
    for (const Pole &p : o.poles)
        if (p.mode >= 0) {
            const std::size_t m = static_cast<std::size_t>(p.mode);
            lo[m] = std::min(lo[m], p.f);
            hi[m] = std::max(hi[m], p.f);
        }
    auto of_mode = [&](const Pole &p, std::size_t m) {
        return p.physical && p.f >= lo[m] * (1.0 - o.cfg.cluster_freq) && p.f <= hi[m] * (1.0 + o.cfg.cluster_freq) &&
               mac(p.shape, o.poles[o.modes[m]].shape) >= o.cfg.cluster_mac;
    };
    std::size_t best_order = 0, best_count = 0;
    for (std::size_t n = 2; n <= static_cast<std::size_t>(nmax); n += 2) {
        std::size_t count = 0;
        for (std::size_t m = 0; m < nm; ++m)
            for (const Pole &p : o.poles)
                if (p.order == n && of_mode(p, m)) {
                    ++count;
                    break;
                }
        if (count > best_count) {
            best_count = count;
            best_order = n;
        }
    }
    for (std::size_t m = 0; m < nm; ++m) {
        const double fm = o.poles[o.modes[m]].f;
        // the smallest standard errors of the mode's poles at or above n*
        double f_se_min = INFINITY, z_se_min = INFINITY;
        for (const Pole &p : o.poles)
            if (p.order >= best_order && of_mode(p, m)) {
                f_se_min = std::min(f_se_min, p.f_se);
                z_se_min = std::min(z_se_min, p.zeta_se);
            }
        std::size_t rep = SIZE_MAX;
        for (std::size_t j = 0; j < o.poles.size(); ++j) {
            const Pole &p = o.poles[j];
            if (p.order < best_order || !of_mode(p, m)) continue;
            // as well determined as at any order (NaN se with one block: every pole passes)
            if (p.f_se > kSeSlack * f_se_min || p.zeta_se > kSeSlack * z_se_min) continue;
            if (rep == SIZE_MAX || p.order < o.poles[rep].order ||
                (p.order == o.poles[rep].order && std::abs(p.f - fm) < std::abs(o.poles[rep].f - fm)))
                rep = j;
        }
        if (rep != SIZE_MAX) o.modes[m] = rep;  // else the medoid
    }
}

// Identification proper (oma.h, 2.-6.).
void identify(vibid_oma &o) {
    using vibid::throw_error;
    const std::size_t nb = o.slots_filled;
    if (nb == 0)
        throw_error(VIBID_E_INSUFFICIENT_DATA, "no complete block of %zu samples yet (%llu samples pushed)",
                    o.cfg.block_samples, static_cast<unsigned long long>(o.n_samples));
    const Index nch = static_cast<Index>(o.nch), i = static_cast<Index>(o.i);
    const double fs = o.cfg.sample_rate;
    // Window sums and the block Hankel matrices.
    std::vector<double> sum(o.window[0].sum.size(), 0.0), count(o.n_lags, 0.0);
    for (std::size_t b = 0; b < nb; ++b) {
        for (std::size_t j = 0; j < sum.size(); ++j) sum[j] += o.window[b].sum[j];
        for (std::size_t k = 0; k < o.n_lags; ++k) {
            if (o.window[b].count[k] <= 0.0)
                throw_error(VIBID_E_INSUFFICIENT_DATA, "a block has no products at lag %zu (gaps)", k + 1);
            count[k] += o.window[b].count[k];
        }
    }
    MatrixXd H;
    hankel(o, sum, count, H);
    if (!H.allFinite()) throw_error(VIBID_E_NONFINITE, "the covariances are not finite (overflow)");
    const Index rows = H.rows(), cols = H.cols(), nd = std::min(rows, cols);
    Eigen::BDCSVD<MatrixXd> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
    const MatrixXd &U = svd.matrixU(), &V = svd.matrixV();
    o.sv = svd.singularValues();
    if (!(o.sv(0) > 0.0)) throw_error(VIBID_E_NUMERICAL, "the Hankel matrix of the output covariances is zero");
    const Index nmax = static_cast<Index>(o.cfg.max_order);

    // 4. Perturbation coefficients of the first nmax left singular vectors along each
    // block's direction D_b = (H_b - Hbar) / sqrt(nb (nb - 1)):
    // du_k = sum_l u_l c_lk, c_lk = (s_k G_lk + s_l G_kl) / (s_k^2 - s_l^2) for l < nd,
    // G_lk / s_k for l >= nd (rows > cols), G = U^T D V.
    std::vector<MatrixXd> coef;
    if (nb >= 2) {
        std::vector<MatrixXd> Hb(nb);
        MatrixXd Hbar = MatrixXd::Zero(rows, cols);
        for (std::size_t b = 0; b < nb; ++b) {
            hankel(o, o.window[b].sum, o.window[b].count, Hb[b]);
            Hbar += Hb[b];
        }
        Hbar /= static_cast<double>(nb);
        const double scale = 1.0 / std::sqrt(static_cast<double>(nb) * static_cast<double>(nb - 1));
        const double tiny = 1e-13 * o.sv(0) * o.sv(0);
        coef.resize(nb);
        for (std::size_t b = 0; b < nb; ++b) {
            const MatrixXd D = (Hb[b] - Hbar) * scale;
            const MatrixXd GL = U.transpose() * (D * V.leftCols(nmax));  // rows x nmax: G_lk
            const MatrixXd GR = (U.leftCols(nmax).transpose() * D) * V;  // nmax x cols: G_kl
            MatrixXd &Cb = coef[b];
            Cb.setZero(rows, nmax);
            for (Index k = 0; k < nmax; ++k) {
                const double sk = o.sv(k);
                for (Index l = 0; l < rows; ++l) {
                    if (l == k) continue;
                    if (l < nd) {
                        const double sl = o.sv(l), den = sk * sk - sl * sl;
                        Cb(l, k) = std::abs(den) > tiny ? (sk * GL(l, k) + sl * GR(k, l)) / den : 0.0;
                    } else {
                        Cb(l, k) = GL(l, k) / sk;
                    }
                }
            }
        }
    }

    // 3. Poles per order, with their standard errors.
    o.poles.clear();
    const Index nup = (i - 1) * nch;
    for (Index n = 2; n <= nmax; n += 2) {
        const VectorXd sq = o.sv.head(n).cwiseSqrt();
        const MatrixXd O = U.leftCols(n) * sq.asDiagonal();
        const MatrixXd X = O.topRows(nup), Y = O.bottomRows(nup);
        const Eigen::LDLT<MatrixXd> XtX(X.transpose() * X);
        const MatrixXd A = XtX.solve(X.transpose() * Y);
        const MatrixXd Cm = O.topRows(nch);
        Eigen::EigenSolver<MatrixXd> es(A);
        if (es.info() != Eigen::Success) continue;  // no poles at this order
        const MatrixXc Vc = es.eigenvectors();
        const VectorXc lam = es.eigenvalues();
        const MatrixXc W = Vc.inverse();  // rows: left eigenvectors with W V = I
        const MatrixXd Res = Y - X * A;
        std::vector<Index> keep;
        for (Index j = 0; j < n; ++j)
            if (lam(j).imag() > 0.0 && std::abs(lam(j)) > 0.0) keep.push_back(j);
        std::vector<double> vf(keep.size(), 0.0), vz(keep.size(), 0.0);
        std::vector<cplx> mu(keep.size());
        for (std::size_t q = 0; q < keep.size(); ++q) mu[q] = fs * std::log(lam(keep[q]));
        for (std::size_t b = 0; b < coef.size(); ++b) {
            const MatrixXd dO = (U.rightCols(rows - n) * coef[b].block(n, 0, rows - n, n)) * sq.asDiagonal();
            const MatrixXd dX = dO.topRows(nup), dY = dO.bottomRows(nup);
            const MatrixXd dA = XtX.solve(X.transpose() * (dY - dX * A) + dX.transpose() * Res);
            for (std::size_t q = 0; q < keep.size(); ++q) {
                const Index j = keep[q];
                const cplx dlam = (W.row(j) * dA.cast<cplx>() * Vc.col(j))(0, 0);
                const cplx dmu = fs * dlam / lam(j);
                const double am = std::abs(mu[q]);
                const double df = std::real(std::conj(mu[q]) * dmu) / (2.0 * M_PI * am);
                const double dz =
                    -dmu.real() / am + mu[q].real() * std::real(std::conj(mu[q]) * dmu) / (am * am * am);
                vf[q] += df * df;
                vz[q] += dz * dz;
            }
        }
        std::vector<Pole> at;
        for (std::size_t q = 0; q < keep.size(); ++q) {
            Pole p;
            p.order = static_cast<std::size_t>(n);
            const double am = std::abs(mu[q]);
            p.f = am / (2.0 * M_PI);
            p.zeta = -mu[q].real() / am;
            p.f_se = nb >= 2 ? std::sqrt(vf[q]) : NAN;
            p.zeta_se = nb >= 2 ? std::sqrt(vz[q]) : NAN;
            VectorXc phi = Cm.cast<cplx>() * Vc.col(keep[q]);
            Index big = 0;
            phi.cwiseAbs().maxCoeff(&big);
            if (std::abs(phi(big)) > 0.0) phi /= phi(big);
            p.mpc = mpc(phi);
            p.shape = phi;
            p.physical = p.zeta > 0.0 && p.zeta <= o.cfg.max_damping && p.f < 0.45 * fs;
            at.push_back(std::move(p));
        }
        std::sort(at.begin(), at.end(), [](const Pole &a, const Pole &b) { return a.f < b.f; });
        for (Pole &p : at) o.poles.push_back(std::move(p));
    }

    // 5. Stability against the order below.
    for (Pole &p : o.poles) {
        if (p.order < 4) continue;
        for (const Pole &q : o.poles) {
            if (q.order + 2 != p.order) continue;
            // damping: within stab_damping of its value, or, for poles whose frequency is
            // determined within stab_freq (standard error) but whose damping is not (a
            // lightly damped mode over a short window: +-100 % and more), within
            // kStabDampingSe of the two poles' combined standard errors, so that the relative
            // test does not reject them (oma.h point 5; the DROPBEAR beam's first mode in
            // 0.5 s windows: found in 21 of 165 without, 134 with). Noise poles, whose
            // frequencies scatter by several percent, stay under the relative test (with it
            // for every pole the 2-DOF chain of bench_oma_coverage.py got 129 extra modes in
            // 100 captures, and the modes' orders rose into the noise floor)
            const bool f_sharp = p.f_se <= o.cfg.stab_freq * p.f && q.f_se <= o.cfg.stab_freq * q.f;
            const double dz_tol =
                std::max(o.cfg.stab_damping * std::abs(p.zeta),
                         f_sharp ? kStabDampingSe * std::hypot(p.zeta_se, q.zeta_se) : 0.0);
            if (std::abs(p.f - q.f) <= o.cfg.stab_freq * p.f && std::abs(p.zeta - q.zeta) <= dz_tol &&
                mac(p.shape, q.shape) >= o.cfg.stab_mac) {
                p.stable = true;
                break;
            }
        }
    }

    // 6. Clusters of stable physical poles.
    std::vector<std::size_t> cand;
    for (std::size_t j = 0; j < o.poles.size(); ++j)
        if (o.poles[j].stable && o.poles[j].physical) cand.push_back(j);
    std::sort(cand.begin(), cand.end(), [&](std::size_t a, std::size_t b) { return o.poles[a].f < o.poles[b].f; });
    const std::size_t n_orders = static_cast<std::size_t>(nmax / 2);
    const std::size_t min_size =
        std::max<std::size_t>(3, static_cast<std::size_t>(std::ceil(o.cfg.min_cluster_share * n_orders)));
    o.modes.clear();
    o.mode_sizes.clear();
    std::size_t start = 0;
    while (start < cand.size()) {
        std::size_t end = start + 1;
        while (end < cand.size() &&
               o.poles[cand[end]].f - o.poles[cand[end - 1]].f <= o.cfg.cluster_freq * o.poles[cand[end - 1]].f)
            ++end;
        const std::size_t medoid = cand[start + (end - start) / 2];
        std::vector<std::size_t> members;
        for (std::size_t j = start; j < end; ++j)
            if (mac(o.poles[cand[j]].shape, o.poles[medoid].shape) >= o.cfg.cluster_mac) members.push_back(cand[j]);
        if (members.size() >= min_size) {
            const long id = static_cast<long>(o.modes.size());
            for (std::size_t m : members) o.poles[m].mode = id;
            o.modes.push_back(medoid);
            o.mode_sizes.push_back(members.size());
        }
        start = end;
    }
    choose_representatives(o, nmax);
    o.have_result = true;
}

}  // namespace

extern "C" {

VIBID_API void vibid_oma_config_init(vibid_oma_config *cfg, double sample_rate, size_t n_channels) {
    if (!cfg) return;
    std::memset(cfg, 0, sizeof *cfg);
    cfg->sample_rate = sample_rate;
    cfg->n_channels = n_channels;
    cfg->block_rows = 20;
    cfg->max_blocks = 32;
    cfg->stab_freq = 0.01;
    cfg->stab_damping = 0.05;
    cfg->stab_mac = 0.98;
    cfg->max_damping = 0.2;
    cfg->cluster_freq = 0.01;
    cfg->cluster_mac = 0.9;
    cfg->min_cluster_share = 0.3;
}

VIBID_API vibid_oma *vibid_oma_create(const vibid_oma_config *cfg) {
    return vibid::guard_create<vibid_oma>(__func__, [&]() -> vibid_oma * {
        using vibid::throw_error;
        if (!cfg) throw_error(VIBID_E_NULL_ARGUMENT, "cfg is NULL");
        if (!std::isfinite(cfg->sample_rate) || cfg->sample_rate <= 0.0)
            throw_error(VIBID_E_OUT_OF_RANGE, "sample_rate = %g must be finite and > 0", cfg->sample_rate);
        if (cfg->n_channels < 1 || cfg->n_channels > 256)
            throw_error(VIBID_E_DIMENSION, "n_channels = %zu outside 1..256", cfg->n_channels);
        const std::size_t nref = cfg->n_refs ? cfg->n_refs : cfg->n_channels;
        if (nref > cfg->n_channels)
            throw_error(VIBID_E_DIMENSION, "n_refs = %zu exceeds n_channels = %zu", nref, cfg->n_channels);
        if (cfg->block_rows < 2 || cfg->block_rows > 1024)
            throw_error(VIBID_E_OUT_OF_RANGE, "block_rows = %zu outside 2..1024", cfg->block_rows);
        const std::size_t bound = max_order_bound(cfg->block_rows, cfg->n_channels, nref);
        if (bound < 2)
            throw_error(VIBID_E_DIMENSION,
                        "block_rows = %zu with %zu channels allows no model order of 2 or more (raise block_rows)",
                        cfg->block_rows, cfg->n_channels);
        std::size_t order = cfg->max_order ? cfg->max_order : std::min<std::size_t>(bound, 100);
        if (order < 2 || order % 2 || order > bound)
            throw_error(VIBID_E_OUT_OF_RANGE, "max_order = %zu must be even and in 2..%zu (block_rows %zu)",
                        cfg->max_order, bound, cfg->block_rows);
        if (cfg->block_samples < 4 * cfg->block_rows)
            throw_error(VIBID_E_OUT_OF_RANGE, "block_samples = %zu must be at least 4 block_rows = %zu",
                        cfg->block_samples, 4 * cfg->block_rows);
        if (cfg->max_blocks < 2 || cfg->max_blocks > 65536)
            throw_error(VIBID_E_OUT_OF_RANGE, "max_blocks = %zu outside 2..65536", cfg->max_blocks);
        auto frac = [](double v) { return std::isfinite(v) && v > 0.0 && v <= 1.0; };
        if (!frac(cfg->stab_freq) || !frac(cfg->stab_damping) || !frac(cfg->stab_mac) || !frac(cfg->max_damping) ||
            !frac(cfg->cluster_freq) || !frac(cfg->cluster_mac) || !frac(cfg->min_cluster_share))
            throw_error(VIBID_E_OUT_OF_RANGE,
                        "stab_freq, stab_damping, stab_mac, max_damping, cluster_freq, cluster_mac and "
                        "min_cluster_share must lie in (0, 1] (vibid_oma_config_init sets them)");
        auto o = std::make_unique<vibid_oma>();
        o->cfg = *cfg;
        o->cfg.n_refs = nref;
        o->cfg.refs = nullptr;
        o->cfg.max_order = order;
        o->refs.resize(nref);
        for (std::size_t r = 0; r < nref; ++r) {
            o->refs[r] = cfg->refs ? cfg->refs[r] : r;
            if (o->refs[r] >= cfg->n_channels)
                throw_error(VIBID_E_OUT_OF_RANGE, "refs[%zu] = %zu is not a channel (0..%zu)", r, o->refs[r],
                            cfg->n_channels - 1);
            for (std::size_t q = 0; q < r; ++q)
                if (o->refs[q] == o->refs[r]) throw_error(VIBID_E_OUT_OF_RANGE, "refs[%zu] repeats channel %zu", r, o->refs[r]);
        }
        o->i = cfg->block_rows;
        o->nch = cfg->n_channels;
        o->nref = nref;
        o->n_lags = 2 * o->i - 1;
        o->lag_size = o->nch * o->nref;
        o->ring.assign(o->n_lags * nref, 0.0);
        o->current.sum.assign(o->n_lags * o->lag_size, 0.0);
        o->current.count.assign(o->n_lags, 0.0);
        o->window.assign(cfg->max_blocks, o->current);
        o->run_refs.assign((o->n_lags + kRunChunk) * nref, 0.0);
        o->run_depth = std::max<std::size_t>(
            1, EIGEN_STACK_ALLOCATION_LIMIT / (sizeof(double) * std::max(o->nch, o->nref)));
        return o.release();
    });
}

VIBID_API void vibid_oma_destroy(vibid_oma *oma) { delete oma; }

VIBID_API vibid_status vibid_oma_get_config(const vibid_oma *oma, vibid_oma_config *cfg) {
    if (!oma || !cfg) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "oma and cfg are required");
    *cfg = oma->cfg;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_oma_push(vibid_oma *oma, const double *sample) {
    if (!oma || !sample) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "oma and sample are required");
    for (std::size_t c = 0; c < oma->nch; ++c)
        if (!std::isfinite(sample[c])) {
            gap(*oma);
            end_sample(*oma);
            return VIBID_FAIL(VIBID_E_NONFINITE, "channel %zu is not finite (a gap: no product spans it)", c);
        }
    accumulate(*oma, sample, 1);
    end_sample(*oma);
    return VIBID_OK;
}

VIBID_API vibid_status vibid_oma_push_block(vibid_oma *oma, size_t n, const double *data, size_t ld,
                                            size_t *n_gaps) {
    if (!oma || (n > 0 && !data)) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "oma and data are required");
    if (ld < n) return VIBID_FAIL(VIBID_E_DIMENSION, "ld = %zu < n = %zu", ld, n);
    vibid_oma &o = *oma;
    std::size_t gaps = 0, t = 0;
    while (t < n) {
        // The next run of finite samples from t, cut at the end of the current block (a
        // product belongs to the block of its later sample) and at the scratch's size.
        std::size_t end = std::min({n, t + kRunChunk, t + (o.cfg.block_samples - o.current_samples)});
        for (std::size_t c = 0; c < o.nch; ++c) {
            const double *col = data + c * ld;
            for (std::size_t s = t; s < end; ++s)
                if (!std::isfinite(col[s])) {
                    end = s;
                    break;
                }
        }
        if (end == t) {  // sample t is a gap
            gap(o);
            ++gaps;
            end_sample(o);
            ++t;
            continue;
        }
        const std::size_t len = end - t;
        if (len < kMinRun) {
            for (; t < end; ++t) {
                accumulate(o, data + t, ld);
                end_sample(o);
            }
            continue;
        }
        accumulate_run(o, data, ld, t, len);
        // end_sample len times: the run ends at or before the block's end
        o.n_samples += len;
        o.current_samples += len;
        if (o.current_samples == o.cfg.block_samples) commit_block(o);
        t = end;
    }
    if (n_gaps) *n_gaps = gaps;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_oma_reset(vibid_oma *oma) {
    if (!oma) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "oma is NULL");
    oma->ring_pos = oma->ring_fill = 0;
    oma->current.zero();
    oma->current_samples = 0;
    for (BlockSums &b : oma->window) b.zero();
    oma->next_slot = oma->slots_filled = 0;
    oma->n_samples = oma->n_gaps = 0;
    oma->have_result = false;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_oma_get_stats(const vibid_oma *oma, vibid_oma_stats *stats) {
    if (!oma || !stats) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "oma and stats are required");
    stats->n_samples = oma->n_samples;
    stats->n_gaps = oma->n_gaps;
    stats->blocks_complete = oma->slots_filled;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_oma_identify(vibid_oma *oma) {
    return vibid::guard(__func__, [&]() -> vibid_status {
        if (!oma) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "oma is NULL");
        oma->have_result = false;
        identify(*oma);
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_oma_get_modes(const vibid_oma *oma, size_t cap, size_t *n_out, vibid_oma_mode *modes,
                                           double *shape_re, double *shape_im) {
    if (!oma || !n_out) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "oma and n_out are required");
    if (!oma->have_result) return VIBID_FAIL(VIBID_E_STATE, "no identification yet: call vibid_oma_identify");
    *n_out = oma->modes.size();
    for (std::size_t j = 0; j < std::min(cap, oma->modes.size()); ++j) {
        const Pole &p = oma->poles[oma->modes[j]];
        if (modes) modes[j] = vibid_oma_mode{p.f, p.f_se, p.zeta, p.zeta_se, p.mpc, p.order, oma->mode_sizes[j]};
        for (std::size_t c = 0; c < oma->nch; ++c) {
            if (shape_re) shape_re[j + c * cap] = p.shape(static_cast<Index>(c)).real();
            if (shape_im) shape_im[j + c * cap] = p.shape(static_cast<Index>(c)).imag();
        }
    }
    return VIBID_OK;
}

VIBID_API vibid_status vibid_oma_get_poles(const vibid_oma *oma, size_t cap, size_t *n_out, vibid_oma_pole *poles) {
    if (!oma || !n_out || (cap > 0 && !poles))
        return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "oma, n_out (and poles when cap > 0) are required");
    if (!oma->have_result) return VIBID_FAIL(VIBID_E_STATE, "no identification yet: call vibid_oma_identify");
    *n_out = oma->poles.size();
    for (std::size_t j = 0; j < std::min(cap, oma->poles.size()); ++j) {
        const Pole &p = oma->poles[j];
        poles[j] = vibid_oma_pole{p.order, p.f, p.f_se, p.zeta, p.zeta_se, p.mpc, p.stable, p.physical, p.mode};
    }
    return VIBID_OK;
}

VIBID_API vibid_status vibid_oma_get_singular_values(const vibid_oma *oma, size_t cap, size_t *n_out, double *sv) {
    if (!oma || !n_out || (cap > 0 && !sv))
        return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "oma, n_out (and sv when cap > 0) are required");
    if (!oma->have_result) return VIBID_FAIL(VIBID_E_STATE, "no identification yet: call vibid_oma_identify");
    *n_out = static_cast<std::size_t>(oma->sv.size());
    for (std::size_t j = 0; j < std::min(cap, *n_out); ++j) sv[j] = oma->sv(static_cast<Index>(j));
    return VIBID_OK;
}

}  // extern "C"
