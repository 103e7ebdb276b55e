// change.cpp: see vibid/change.h.
#include <vibid/change.h>

#include "api_guard.hpp"

#include <Eigen/Core>
#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <vector>

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kClip = 5.0;               // |u_k| beyond this is taken as 5 (one wild block)
constexpr double kMaxAllowance = 3.0;
constexpr double kSiegmund = 1.166;         // the overshoot correction of b = h + 1.166
constexpr double kSecondsPerYear = 365.25 * 86400.0;

// Siegmund's average run length of a one-sided CUSUM whose increments have mean -kappa
// (allowance minus drift) and unit variance, threshold h.
double siegmund_arl(double kappa, double h) {
    const double b = h + kSiegmund;
    if (std::fabs(kappa) < 1e-9) return b * b;
    const double x = 2.0 * kappa * b;
    if (x > 700.0) return kInf;
    return (std::exp(x) - x - 1.0) / (2.0 * kappa * kappa);
}

// Standard normal quantile (Acklam's rational approximation, relative error < 1.2e-9).
double normal_quantile(double p) {
    static const double a[] = {-3.969683028665376e+01, 2.209460984245205e+02, -2.759285104469687e+02,
                               1.383577518672690e+02,  -3.066479806614716e+01, 2.506628277459239e+00};
    static const double b[] = {-5.447609879822406e+01, 1.615858368580409e+02, -1.556989798598866e+02,
                               6.680131188771972e+01,  -1.328068155288572e+01};
    static const double c[] = {-7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e+00,
                               -2.549671010349356e+00, 4.374664141464968e+00,  2.938163982698783e+00};
    static const double d[] = {7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e+00,
                               3.754408661907416e+00};
    const double lo = 0.02425;
    if (p < lo) {
        const double q = std::sqrt(-2.0 * std::log(p));
        return (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
               ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0);
    }
    if (p > 1.0 - lo) return -normal_quantile(1.0 - p);
    const double q = p - 0.5, r = q * q;
    return (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q /
           (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0);
}

// The false-alarm rate per row of one two-sided CUSUM pair (allowance k, threshold h) for
// a reference whose errors lie at the edge of their confidence regions: the mean off by
// kMeanZ / sqrt(n_mean) standard deviations (one side faster, the other slower), the scale
// underestimated to its kScaleZ quantile (chi2(n_sd - 1), Wilson-Hilferty). Half the
// pair's rate, so that it compares with one CUSUM's 1 / ARL.
constexpr double kMeanZ = 1.96;    // the mean's 95 % interval
constexpr double kScaleZ = -1.645; // the scale's 5 % quantile
// The reference at the edge of its errors: the mean's shift (units of sigma_b) and the
// scale's factor w.
void reference_edge(double n_mean, double n_sd, double *shift, double *w) {
    *shift = std::isfinite(n_mean) ? kMeanZ / std::sqrt(n_mean) : 0.0;
    *w = 1.0;
    if (std::isfinite(n_sd)) {
        const double nu = n_sd - 1.0;
        const double c = std::max(0.05, 1.0 - 2.0 / (9.0 * nu) + kScaleZ * std::sqrt(2.0 / (9.0 * nu)));
        *w = std::sqrt(c * c * c);
    }
}

double pair_rate(double k, double h, double n_mean, double n_sd) {
    double shift, w;
    reference_edge(n_mean, n_sd, &shift, &w);
    // increments (z +- shift) / w against allowance k: in units of z the allowance is
    // k w -+ shift and the threshold h w
    auto rate = [&](double kappa) { return std::min(1.0, 1.0 / std::max(1.0, siegmund_arl(kappa, h * w))); };
    return 0.5 * (rate(k * w - shift) + rate(k * w + shift));
}

// h with the rate 1 / arl (bisection on h; the rate falls with h).
double threshold_for(double k, double arl, double n_mean, double n_sd) {
    const double target = 1.0 / arl;
    double lo = 0.0, hi = 1.0;
    while (pair_rate(k, hi, n_mean, n_sd) > target && hi < 1e7) hi *= 2.0;
    for (int it = 0; it < 60 && hi - lo > 1e-9 * hi; ++it) {
        const double mid = 0.5 * (lo + hi);
        if (pair_rate(k, mid, n_mean, n_sd) > target)
            lo = mid;
        else
            hi = mid;
    }
    return hi;
}

constexpr size_t kMaxCov = VIBID_CHANGE_MAX_COVARIATES;
constexpr size_t kMaxTerms = VIBID_CHANGE_MAX_TERMS;
constexpr unsigned kBatch = 10;  // blocks per batch of the long-run variance (Learn)

// Terms of q covariates: q linear, then the second-order model's q (q + 1) / 2 products.
size_t full_terms(size_t q) { return q + q * (q + 1) / 2; }
// The terms a reference uses: n_terms, or q for the first (linear) form of the struct.
size_t terms_of(const vibid_change_reference &r, size_t q) { return r.n_terms ? r.n_terms : q; }

// x(c) of n_t terms measured from origin o (change.h point 6).
void terms(size_t q, size_t n_t, const double *c, const double *o, double *x) {
    double e[kMaxCov];
    for (size_t j = 0; j < q; ++j) e[j] = c[j] - o[j];
    for (size_t j = 0; j < q && j < n_t; ++j) x[j] = e[j];
    size_t t = q;
    for (size_t i = 0; i < q; ++i)
        for (size_t j = i; j < q; ++j, ++t)
            if (t < n_t) x[t] = e[i] * e[j];
}

// d = x(c) - xbar of a reference: its deviation from the reference's conditions; the term count.
size_t deviation(const vibid_change_reference &r, size_t q, const double *c, double *d) {
    if (!r.n_terms) {  // the first form: linear, from the centre
        for (size_t j = 0; j < q; ++j) d[j] = c[j] - r.centre[j];
        return q;
    }
    terms(q, r.n_terms, c, r.origin, d);
    for (size_t t = 0; t < r.n_terms; ++t) d[t] -= r.term_mean[t];
    return r.n_terms;
}

// v(c) = 1 / n_mean + d^T G d of a reference (point 6 of change.h); INFINITY when c lies
// outside the range of a covariate that is not modelled (G's diagonal 0).
double prediction_v(const vibid_change_reference &r, size_t q, const double *c) {
    double v = std::isfinite(r.n_mean) ? 1.0 / r.n_mean : 0.0;
    double d[kMaxTerms];
    const size_t T = deviation(r, q, c, d);
    for (size_t j = 0; j < q; ++j) {
        const double tol = 1e-9 * std::max(r.high[j] - r.low[j], std::fabs(c[j]));
        if (!(r.gram_inv[j * T + j] > 0.0) && (c[j] < r.low[j] - tol || c[j] > r.high[j] + tol)) return kInf;
    }
    for (size_t i = 0; i < T; ++i)
        for (size_t j = 0; j < T; ++j) v += d[i] * r.gram_inv[i * T + j] * d[j];
    return std::max(v, 0.0);
}

using SmallMat = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMaxTerms, kMaxTerms>;
using SmallVec = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, kMaxTerms, 1>;

// A regression of the last column of co-moments m2 (m x m, m = T + 1) on the first n_t of its
// T terms: which terms are kept (greedy by the pivots of a Cholesky: a term whose variance
// left after the kept ones is below 1e-10 of its own, or 0, is not modelled), their slopes,
// G, and the residual sum of squares.
struct Fit {
    size_t keep[kMaxTerms] = {}, nk = 0;
    SmallMat G;
    SmallVec beta;
    double rss = 0.0;
};

Fit regress(const double *m2, size_t m, size_t n_t, const bool *varies) {
    const size_t yi = m - 1;
    Fit f;
    for (size_t j = 0; j < n_t; ++j) {
        const double own = m2[j * m + j];
        bool ok = varies[j] && own > 0.0 && std::isfinite(own);
        if (ok && f.nk > 0) {
            SmallMat A(f.nk, f.nk);
            SmallVec sv(f.nk);
            for (size_t a = 0; a < f.nk; ++a) {
                sv(a) = m2[f.keep[a] * m + j];
                for (size_t b = 0; b < f.nk; ++b) A(a, b) = m2[f.keep[a] * m + f.keep[b]];
            }
            const double left = own - sv.dot(A.inverse() * sv);
            ok = left > 1e-10 * own;
        }
        if (ok) f.keep[f.nk++] = j;
    }
    f.rss = m2[yi * m + yi];
    if (f.nk > 0) {
        SmallMat A(f.nk, f.nk);
        SmallVec sv(f.nk);
        for (size_t a = 0; a < f.nk; ++a) {
            sv(a) = m2[f.keep[a] * m + yi];
            for (size_t b = 0; b < f.nk; ++b) A(a, b) = m2[f.keep[a] * m + f.keep[b]];
        }
        f.G = A.inverse();
        f.beta = f.G * sv;
        f.rss -= sv.dot(f.beta);
    }
    f.rss = std::max(f.rss, 0.0);
    return f;
}

// The co-moments of the first n_t terms and the parameter (the last of m) out of m x m ones.
void sub_moments(const double *m2, size_t m, size_t n_t, double *out) {
    const size_t k = n_t + 1;
    for (size_t a = 0; a < k; ++a)
        for (size_t b = 0; b < k; ++b) {
            const size_t ia = a < n_t ? a : m - 1, ib = b < n_t ? b : m - 1;
            out[a * k + b] = m2[ia * m + ib];
        }
}

// The (1 - alpha) quantile of chi2(dof) (Wilson-Hilferty), z its normal quantile.
double chi2_quantile(double dof, double z) {
    const double a = 2.0 / (9.0 * dof);
    return dof * std::pow(1.0 - a + z * std::sqrt(a), 3.0);
}

// Per-parameter learning sums (Welford on x = (terms of c, b), the terms measured from the
// first learned block's covariates): mean and co-moment, over the blocks and over batches of
// kBatch consecutive blocks.
struct Learn {
    static constexpr size_t kM = kMaxTerms + 1;
    uint64_t n = 0;
    double origin[kMaxCov] = {};
    double mean[kM] = {};
    double m2[kM * kM] = {};
    double low[kMaxCov] = {}, high[kMaxCov] = {};
    // the same over batches of kBatch consecutive learned blocks (their means): the long-run
    // variance of the blocks, which neighbouring blocks' correlation raises above theirs
    uint64_t nb = 0;
    double bmean[kM] = {};
    double bm2[kM * kM] = {};
    double cur[kM] = {};
    unsigned in_batch = 0;

    static void welford(uint64_t n, size_t m, const double *x, double *mean, double *m2) {
        double dx[kM];
        for (size_t j = 0; j < m; ++j) {
            dx[j] = x[j] - mean[j];
            mean[j] += dx[j] / (double)n;
        }
        for (size_t i = 0; i < m; ++i)
            for (size_t j = 0; j < m; ++j) m2[i * m + j] += dx[i] * (x[j] - mean[j]);
    }

    void add(size_t q, const double *c, double b) {
        const size_t T = full_terms(q), m = T + 1;
        if (n == 0)
            for (size_t j = 0; j < q; ++j) origin[j] = c[j];
        double x[kM];
        terms(q, T, c, origin, x);
        x[T] = b;
        ++n;
        for (size_t j = 0; j < m; ++j) cur[j] += x[j];
        if (++in_batch == kBatch) {
            for (size_t j = 0; j < m; ++j) cur[j] /= (double)kBatch;
            welford(++nb, m, cur, bmean, bm2);
            std::fill(cur, cur + m, 0.0);
            in_batch = 0;
        }
        welford(n, m, x, mean, m2);
        for (size_t j = 0; j < q; ++j) {
            if (n == 1 || c[j] < low[j]) low[j] = c[j];
            if (n == 1 || c[j] > high[j]) high[j] = c[j];
        }
    }

    // The regression of b on the covariates' terms (change.h point 6): the linear model, or
    // the second-order one where the batches reject the linear one.
    vibid_change_reference reference(size_t q) const {
        const size_t Tf = full_terms(q), m = Tf + 1;
        vibid_change_reference r{};
        const double N = (double)n;
        // a term varies when its covariates do (a product of a constant covariate is not modelled)
        bool varies[kMaxTerms] = {};
        for (size_t j = 0; j < q; ++j) varies[j] = high[j] > low[j];
        for (size_t i = 0, t = q; i < q; ++i)
            for (size_t j = i; j < q; ++j, ++t) varies[t] = varies[i] && varies[j];
        // the model: linear unless the batches reject it (change.h point 6)
        size_t T = q;
        if (q > 0 && nb > 0) {
            double lin[kM * kM];
            sub_moments(bm2, m, q, lin);
            const Fit bl = regress(lin, q + 1, q, varies), bf = regress(bm2, m, Tf, varies);
            const double added = (double)bf.nk - (double)bl.nk, dof = (double)nb - 1.0 - (double)bf.nk;
            if (added > 0.0 && dof >= 20.0 && bf.rss > 0.0) {
                const double drop = (bl.rss - bf.rss) / (bf.rss / dof);
                if (drop > chi2_quantile(added, 3.090)) T = Tf;  // 99.9 %
            }
        }
        double mm[kM * kM];
        sub_moments(m2, m, T, mm);
        const Fit f = regress(mm, T + 1, T, varies);
        r.n_terms = T;
        for (size_t a = 0; a < f.nk; ++a) {
            r.slope[f.keep[a]] = f.beta(a);
            for (size_t b = 0; b < f.nk; ++b) r.gram_inv[f.keep[a] * T + f.keep[b]] = f.G(a, b);
        }
        for (size_t t = 0; t < T; ++t) r.term_mean[t] = mean[t];
        for (size_t j = 0; j < q; ++j) {
            r.origin[j] = origin[j];
            r.centre[j] = origin[j] + mean[j];
            r.low[j] = low[j];
            r.high[j] = high[j];
        }
        const double dof = N - 1.0 - (double)f.nk;
        r.mean = mean[Tf];
        r.block_sd = dof > 0.0 && f.rss > 0.0 ? std::sqrt(f.rss / dof) : 0.0;
        r.n_mean = N;
        r.n_sd = N - (double)f.nk;
        // The long-run standard deviation: kBatch x the variance of the batch means' residuals
        // (the blocks' slopes). The rows of IV with a pre-filter, difference windows and an
        // instrument lag straddle the block boundaries: neighbouring blocks correlate (0.3-0.45
        // at lag 1 on a 2-DOF stand, the long-run variance 2-2.5 times the blocks'), a CUSUM's
        // sums grow with the long-run variance, and a threshold for independent blocks gave
        // false alarms at 1 a year within an hour. Used when larger than the blocks' own, with
        // the batches' degrees of freedom for its uncertainty.
        const double bdof = (double)nb - 1.0 - (double)f.nk;
        if (bdof >= 2.0) {
            double vb = bm2[Tf * m + Tf];
            for (size_t a = 0; a < T; ++a) {
                vb -= 2.0 * r.slope[a] * bm2[a * m + Tf];
                for (size_t b = 0; b < T; ++b) vb += r.slope[a] * r.slope[b] * bm2[a * m + b];
            }
            const double lr = std::sqrt(std::max(0.0, (double)kBatch * vb / bdof));
            // only when the data show it: the batches' variance above the 95 % quantile of
            // what independent blocks give (chi2(bdof) / bdof, Wilson-Hilferty), so that
            // independent blocks keep their own (more precise) spread
            const double q95 = chi2_quantile(bdof, 1.645) / bdof;
            if (lr * lr > q95 * r.block_sd * r.block_sd) {
                r.block_sd = lr;
                r.n_sd = bdof + 1.0;
            }
        }
        return r;
    }
};

struct Param {
    // chain
    double prev = kNaN;
    uint64_t prev_index = 0;
    bool have_prev = false;
    bool prev_use = false;  // the previous row was usable: a block spans two rows and is used
                            // only when both are (an impossible estimate poisons the next block)
    Learn learn;
    vibid_change_reference learned{};  // end_learning's regression, before it is taken
    // reference
    bool have_ref = false;
    vibid_change_reference ref{};
    double n_eff = kInf;      // the n_mean whose edge shift 1.96 / sqrt(n_eff) is the
                              // prediction's at the edge of its region (change.h point 6)
    double v_ref = 0.0;       // the largest v(c) over the reference's covariate box
    double h = 0.0, k = 0.0;  // the CUSUMs' threshold and allowance (units of sigma_b)
    double mdc = kNaN;
    // the CUSUMs: side 0 up, 1 down. sum/n: b_k - m over the current run, which began at onset
    double S[2] = {}, sum[2] = {};
    uint64_t n[2] = {}, onset[2] = {};
    // a raised alarm and its recovery CUSUM
    bool active = false;
    double change = 0.0, stat_at_raise = 0.0, T = 0.0, k_clear = 0.0, h_clear = 0.0;
    double act_sum = 0.0, act_u = 0.0, act_u2 = 0.0, act_n = 0.0;  // the deviations since the
                                  // onset (while raised): raw, as clipped increments, their squares
    // the latest tested blocks' deviations from the reference (a ring of the detector's
    // ring_size): the change point of a raised alarm (test)
    std::vector<double> dev;
    std::vector<uint64_t> dev_index;
    size_t dev_pos = 0, dev_n = 0;
    double last_block = kNaN;
    uint64_t tested = 0, out_of_range = 0;
    bool last_out = false;
    double last_weight = 1.0;

    void restart_cusums() {
        std::memset(S, 0, sizeof S);
        std::memset(sum, 0, sizeof sum);
        std::memset(n, 0, sizeof n);
    }
};

}  // namespace

struct vibid_change {
    vibid_change_config cfg{};
    double arl = 0.0;       // rows per CUSUM per false alarm
    double rows_horizon = 0.0;
    double z_p = 0.0;
    std::vector<Param> par;
    bool have_last = false;  // a row was pushed; its sample index:
    uint64_t last_index = 0;
    size_t ring_size = 256;  // Param::dev's size

    void init_ring(Param &p) const {
        p.dev.assign(ring_size, 0.0);
        p.dev_index.assign(ring_size, 0);
        p.dev_pos = p.dev_n = 0;
    }

    // W of a row at sample index n (weight of the samples 0..n)
    double weight(uint64_t n) const {
        const double g = cfg.forgetting, m = (double)n + 1.0;
        return g >= 1.0 ? m : -std::expm1(m * std::log(g)) / (1.0 - g);
    }

    // The allowance, threshold and MDC of one parameter from its reference.
    void design(Param &p) const {
        // the prediction's uncertainty at the worst corner of the covariate box, as an
        // equivalent n_mean (point 6)
        const size_t q = cfg.n_covariates;
        double vmax = std::isfinite(p.ref.n_mean) ? 1.0 / p.ref.n_mean : 0.0;
        // over the box's corners, edge midpoints and centre (3^q points: v of the second-order
        // terms is a quartic, whose largest value need not lie at a corner)
        size_t points = q > 0 ? 1 : 0;
        for (size_t j = 0; j < q; ++j) points *= 3;
        for (size_t pt = 0; pt < points; ++pt) {
            double c[kMaxCov];
            for (size_t j = 0, code = pt; j < q; ++j, code /= 3) {
                const double lo = p.ref.low[j], hi = p.ref.high[j];
                c[j] = code % 3 == 0 ? lo : code % 3 == 1 ? hi : 0.5 * (lo + hi);
            }
            vmax = std::max(vmax, prediction_v(p.ref, q, c));
        }
        p.v_ref = vmax;
        p.n_eff = vmax > 0.0 ? 1.0 / vmax : kInf;
        if (p.n_eff < 1.0) p.n_eff = 1.0;
        const double nm = p.n_eff, ns = p.ref.n_sd, n = rows_horizon;
        const double spread = std::sqrt(n + (std::isfinite(nm) ? n * n / nm : 0.0));
        auto mdc_of = [&](double k, double h) { return k + (h + z_p * spread) / n; };
        // k: the allowance with the smallest MDC at the horizon (golden section in log k),
        // above the one at which the edge reference's CUSUM would drift up (k w <= shift:
        // alarms at any threshold)
        double shift, w;
        reference_edge(nm, ns, &shift, &w);
        const double k_lo = std::max(1e-3, 1.25 * shift / w);
        double a = std::log(k_lo), b = std::log(std::max(kMaxAllowance, 2.0 * k_lo));
        const double gr = 0.5 * (std::sqrt(5.0) - 1.0);
        auto f = [&](double lk) {
            const double k = std::exp(lk);
            return mdc_of(k, threshold_for(k, arl, nm, ns));
        };
        double c = b - gr * (b - a), d = a + gr * (b - a), fc = f(c), fd = f(d);
        for (int it = 0; it < 16; ++it) {
            if (fc < fd) {
                b = d, d = c, fd = fc, c = b - gr * (b - a), fc = f(c);
            } else {
                a = c, c = d, fc = fd, d = a + gr * (b - a), fd = f(d);
            }
        }
        p.k = std::exp(0.5 * (a + b));
        p.h = threshold_for(p.k, arl, nm, ns);
        p.mdc = mdc_of(p.k, p.h) * p.ref.block_sd;
        p.restart_cusums();
        p.active = false;
    }

    // h of the recovery CUSUM for allowance k (reference taken as exact: a clearing
    // decision, not a false alarm of the service)
    // At least 3 blocks of the largest evidence (k + the clip): Siegmund's threshold assumes
    // Gaussian increments, and an estimator's wild block (an IV transient) is not; with a
    // large change the threshold is below one wild block's increment, and single blocks
    // cleared persisting cracks (base2 at 500 Hz: every 100-300 s).
    double clear_threshold(double k) const {
        double lo = 0.0, hi = 1.0;
        while (siegmund_arl(k, hi) < arl && hi < 1e7) hi *= 2.0;
        for (int it = 0; it < 60; ++it) {
            const double mid = 0.5 * (lo + hi);
            (siegmund_arl(k, mid) < arl ? lo : hi) = mid;
        }
        return std::max(hi, 3.0 * (k + kClip));
    }

    // One block of parameter i; returns true with *ev filled on an event.
    bool test(size_t i, uint64_t index, double blk, const double *cov, vibid_change_event *ev) {
        Param &p = par[i];
        const size_t q = cfg.n_covariates;
        double m = p.ref.mean, weight = 1.0;
        bool out = false;
        if (q) {
            double d[kMaxTerms];
            const size_t T = deviation(p.ref, q, cov, d);
            for (size_t t = 0; t < T; ++t) m += p.ref.slope[t] * d[t];
        }
        for (size_t j = 0; j < q; ++j) {
            // outside by more than rounding (1e-9 of the range, or of the value without one)
            const double tol = 1e-9 * std::max(p.ref.high[j] - p.ref.low[j], std::fabs(cov[j]));
            out = out || cov[j] < p.ref.low[j] - tol || cov[j] > p.ref.high[j] + tol;
        }
        const double v = q ? prediction_v(p.ref, q, cov) : p.v_ref;
        if (v > p.v_ref) weight = std::isfinite(v) ? std::sqrt(p.v_ref / v) : 0.0;
        p.last_out = out;
        p.last_weight = weight;
        p.out_of_range += out;
        if (weight <= 0.0) return false;
        const double sb = p.ref.block_sd;
        const double u_raw = std::clamp((blk - m) / sb, -kClip, kClip), u = u_raw * weight;
        ++p.tested;
        p.dev[p.dev_pos] = blk - m;
        p.dev_index[p.dev_pos] = index;
        p.dev_pos = (p.dev_pos + 1) % p.dev.size();
        p.dev_n = std::min(p.dev_n + 1, p.dev.size());
        if (p.active) {
            // the change as the blocks since its onset show it: the estimate at the raise is
            // biased away from 0 (the CUSUM fires when the noise adds to the change), and a
            // recovery test against an overestimated change clears a change that persists
            p.act_sum += blk - m;
            p.act_u += u_raw;
            p.act_u2 += u_raw * u_raw;
            p.act_n += 1.0;
            // The recovery test in the clipped increments' own scale and spread since the
            // onset: blocks that scatter beyond the clip show a smaller mean than their raw
            // one, and blocks of an estimator out of its stationary regime (IV, the EKF after
            // a change) scatter more than sigma_b: a test that expected the raw mean with unit
            // spread would read a change that persists as "back at the reference".
            const double n = p.act_n;
            const double var = n >= 2.0 ? std::max(0.0, (p.act_u2 - p.act_u * p.act_u / n) / (n - 1.0)) : 1.0;
            const double scale = std::max(1.0, std::sqrt(var));
            const double d_now = std::clamp(std::fabs(p.act_u / n) / scale, 1e-3, kClip);
            if (std::fabs(0.5 * d_now - p.k_clear) > 0.05 * p.k_clear) {
                p.k_clear = 0.5 * d_now;
                p.h_clear = clear_threshold(p.k_clear);
            }
            p.change = p.act_sum / n;
            const double s = p.change >= 0.0 ? 1.0 : -1.0;
            // a block weighed down (covariates outside the reference's range) is weaker
            // evidence either way: its whole increment is weighed, so that it cannot clear
            // an alarm by looking like the reference
            p.T = std::max(0.0, p.T + weight * (p.k_clear - s * u_raw / scale));
            if (p.T < p.h_clear) return false;
            *ev = vibid_change_event{i, VIBID_CHANGE_CLEARED, index, index, p.T, p.h_clear, p.change, kNaN, m};
            p.active = false;
            p.T = 0.0;
            p.restart_cusums();
            return true;
        }
        int fired = -1;
        double best = 0.0;
        for (int side = 0; side < 2; ++side) {
            const double x = side == 0 ? u : -u;
            double &S = p.S[side];
            if (S == 0.0) {  // a new run begins with this row
                p.sum[side] = 0.0;
                p.n[side] = 0;
                p.onset[side] = index;
            }
            S = std::max(0.0, S + x - p.k);
            if (S > 0.0) {
                p.sum[side] += blk - m;
                ++p.n[side];
            }
            S = std::min(S, 10.0 * p.h);  // bounded while a dead band holds it back
            const double r = S / p.h;
            if (r >= 1.0 && r > best) best = r, fired = side;
        }
        if (fired < 0) return false;
        // The change point: the CUSUM's last zero runs early when the change is large against
        // the allowance, and the mean since then mixes in unchanged blocks. Within the run (as
        // far as the ring reaches) the maximum-likelihood split of a mean step: the start j of
        // the latest blocks whose sum S_j (on the side that fired) maximises S_j^2 / n_j.
        const double sgn = fired == 0 ? 1.0 : -1.0;
        double best_score = -1.0, change = p.sum[fired] / (double)p.n[fired], nrun = (double)p.n[fired];
        double spread = 0.0;  // the variance of the blocks after the change point
        uint64_t onset = p.onset[fired];
        double S = 0.0, SS = 0.0;
        for (size_t back = 1; back <= p.dev_n; ++back) {
            const size_t at = (p.dev_pos + p.dev.size() - back) % p.dev.size();
            if (p.dev_index[at] < p.onset[fired]) break;
            S += p.dev[at];
            SS += p.dev[at] * p.dev[at];
            const double score = sgn * S > 0.0 ? S * S / (double)back : 0.0;
            if (score > best_score) {
                best_score = score, change = S / (double)back, nrun = (double)back, onset = p.dev_index[at];
                spread = back > 1 ? std::max(0.0, (SS - S * S / (double)back) / (double)(back - 1)) : 0.0;
            }
        }
        if (!(std::fabs(change) > cfg.min_relative * std::fabs(m))) return false;
        // its standard error: the blocks after a change can scatter far more than the
        // reference's (an estimator out of its stationary regime: IV, the EKF), so the larger
        // of sigma_b and their own spread, plus the reference's error
        const double se = std::sqrt(std::max(sb * sb, spread) / nrun + sb * sb * v);
        *ev = vibid_change_event{i, VIBID_CHANGE_RAISED, index, onset, p.S[fired], p.h, change, se, m};
        p.active = true;
        p.change = change;
        p.act_sum = change * nrun;
        p.act_u = std::clamp(change / sb, -kClip, kClip) * nrun;
        // the run's spread as the raise saw it (the blocks' own variance, at least sigma_b's)
        p.act_u2 = p.act_u * p.act_u / nrun + std::max(1.0, spread / (sb * sb)) * std::max(0.0, nrun - 1.0);
        p.act_n = nrun;
        p.stat_at_raise = best;
        // the change as the clipped increments see it: beyond the clip they show at most kClip
        const double d = std::clamp(std::fabs(change) / sb, 1e-3, kClip);
        p.k_clear = 0.5 * d;
        p.h_clear = clear_threshold(p.k_clear);
        p.T = 0.0;
        return true;
    }
};

VIBID_API void vibid_change_config_init(vibid_change_config *cfg, size_t n_params) {
    if (!cfg) return;
    std::memset(cfg, 0, sizeof *cfg);
    cfg->n_params = n_params;
    cfg->sample_rate_hz = 1.0;
    cfg->forgetting = 1.0;
    cfg->row_interval = 1.0;
    cfg->false_alarms_per_year = VIBID_CHANGE_ALARMS_PER_YEAR_DEFAULT;
    cfg->horizon_s = VIBID_CHANGE_HORIZON_DEFAULT;
    cfg->detection_probability = VIBID_CHANGE_DETECTION_DEFAULT;
    cfg->min_relative = 0.0;
    cfg->n_covariates = 0;
}

VIBID_API vibid_change *vibid_change_create(const vibid_change_config *cfg) {
    return vibid::guard_create<vibid_change>(__func__, [&]() -> vibid_change * {
        using vibid::throw_error;
        if (!cfg) throw_error(VIBID_E_NULL_ARGUMENT, "cfg is NULL");
        if (cfg->n_params < 1 || cfg->n_params > 4096)
            throw_error(VIBID_E_DIMENSION, "n_params = %zu outside [1, 4096]", cfg->n_params);
        auto in = [](double v, double lo, double hi) { return std::isfinite(v) && v >= lo && v <= hi; };
        if (!in(cfg->sample_rate_hz, 1e-9, 1e12) || cfg->sample_rate_hz <= 0.0)
            throw_error(VIBID_E_OUT_OF_RANGE, "sample_rate_hz = %g must be finite and > 0", cfg->sample_rate_hz);
        if (!in(cfg->forgetting, 0.0, 1.0))
            throw_error(VIBID_E_OUT_OF_RANGE, "forgetting = %g outside [0, 1]", cfg->forgetting);
        if (!in(cfg->row_interval, 1.0, 1e12))
            throw_error(VIBID_E_OUT_OF_RANGE, "row_interval = %g samples outside [1, 1e12]", cfg->row_interval);
        if (!in(cfg->false_alarms_per_year, 1e-9, 1e12) )
            throw_error(VIBID_E_OUT_OF_RANGE, "false_alarms_per_year = %g outside [1e-9, 1e12]",
                        cfg->false_alarms_per_year);
        if (!in(cfg->horizon_s, 1e-9, 1e12))
            throw_error(VIBID_E_OUT_OF_RANGE, "horizon_s = %g must be finite and > 0", cfg->horizon_s);
        if (!in(cfg->detection_probability, 0.5, 0.999))
            throw_error(VIBID_E_OUT_OF_RANGE, "detection_probability = %g outside [0.5, 0.999]",
                        cfg->detection_probability);
        if (!in(cfg->min_relative, 0.0, 1e6))
            throw_error(VIBID_E_OUT_OF_RANGE, "min_relative = %g outside [0, 1e6]", cfg->min_relative);
        if (cfg->n_covariates > VIBID_CHANGE_MAX_COVARIATES)
            throw_error(VIBID_E_DIMENSION, "n_covariates = %zu outside [0, %d]", cfg->n_covariates,
                        VIBID_CHANGE_MAX_COVARIATES);
        auto *d = new vibid_change;
        d->cfg = *cfg;
        const double rows_per_year = kSecondsPerYear * cfg->sample_rate_hz / cfg->row_interval;
        const double cusums = 2.0 * (double)cfg->n_params;
        d->arl = std::max(2.0, rows_per_year * cusums / cfg->false_alarms_per_year);
        d->rows_horizon = std::max(1.0, cfg->horizon_s * cfg->sample_rate_hz / cfg->row_interval);
        d->z_p = normal_quantile(cfg->detection_probability);
        // the ring of recent deviations: 4 horizons (a change at the MDC is raised within one),
        // 256 .. 8192 blocks
        d->ring_size = (size_t)std::clamp(4.0 * d->rows_horizon, 256.0, 8192.0);
        try {
            d->par.assign(cfg->n_params, Param{});
            for (Param &p : d->par) d->init_ring(p);
        } catch (...) {
            delete d;
            throw;
        }
        return d;
    });
}

VIBID_API void vibid_change_destroy(vibid_change *det) { delete det; }

VIBID_API vibid_status vibid_change_reset(vibid_change *det) {
    if (!det) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "det is NULL");
    for (Param &p : det->par) {  // back to Param{}, keeping the rings' storage (no allocation)
        std::vector<double> dev = std::move(p.dev);
        std::vector<uint64_t> dev_index = std::move(p.dev_index);
        p = Param{};
        p.dev = std::move(dev);
        p.dev_index = std::move(dev_index);
        p.dev_pos = p.dev_n = 0;
    }
    det->have_last = false;
    det->last_index = 0;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_change_push(vibid_change *det, uint64_t index, const double *theta,
                                         const double *covariates, int use, vibid_change_phase phase,
                                         vibid_change_event *events, size_t cap, size_t *n_events) {
    if (!det || !theta || !n_events || (cap > 0 && !events) || (det->cfg.n_covariates > 0 && !covariates))
        return VIBID_FAIL(VIBID_E_NULL_ARGUMENT,
                          "det, theta, n_events (and events when cap > 0, covariates when n_covariates > 0) "
                          "are required");
    const int ph = vibid::enum_value(phase);
    if (ph != VIBID_CHANGE_LEARN && ph != VIBID_CHANGE_TEST)
        return VIBID_FAIL(VIBID_E_OUT_OF_RANGE, "phase = %d is neither VIBID_CHANGE_LEARN nor VIBID_CHANGE_TEST", ph);
    *n_events = 0;
    if (det->have_last && index <= det->last_index)
        return VIBID_FAIL(VIBID_E_OUT_OF_RANGE, "index %llu does not follow the previous row's %llu",
                          (unsigned long long)index, (unsigned long long)det->last_index);
    det->have_last = true;
    det->last_index = index;
    const double wk = det->weight(index);
    const size_t q = det->cfg.n_covariates;
    for (size_t j = 0; j < q; ++j)
        if (!std::isfinite(covariates[j])) use = 0;  // neither learned nor tested
    for (size_t i = 0; i < det->par.size(); ++i) {
        Param &p = det->par[i];
        const double th = theta[i];
        if (!std::isfinite(th)) {  // the chain breaks
            p.have_prev = false;
            p.prev_index = index;
            continue;
        }
        double blk = kNaN;
        if (p.have_prev) {
            const double g = det->cfg.forgetting;
            const double dn = (double)(index - p.prev_index);
            const double decay = g >= 1.0 ? 1.0 : std::exp(dn * std::log(g));
            const double phi = decay * det->weight(p.prev_index) / wk;
            if (phi < 1.0) blk = (th - phi * p.prev) / (1.0 - phi);
        }
        p.prev = th;
        p.prev_index = index;
        p.have_prev = true;
        const bool both = use && p.prev_use;
        p.prev_use = use != 0;
        if (!both || !std::isfinite(blk)) continue;
        p.last_block = blk;
        if (ph == VIBID_CHANGE_LEARN) {
            p.learn.add(q, covariates, blk);
        } else if (p.have_ref) {
            vibid_change_event ev;
            if (det->test(i, index, blk, covariates, &ev)) {
                if (*n_events < cap) events[*n_events] = ev;
                ++*n_events;
            }
        }
    }
    if (*n_events > cap) *n_events = cap;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_change_end_learning(vibid_change *det) {
    if (!det) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "det is NULL");
    const size_t q = det->cfg.n_covariates;
    const uint64_t need = VIBID_CHANGE_MIN_BLOCKS + q;
    for (size_t i = 0; i < det->par.size(); ++i) {  // every parameter's first: all or none
        Param &p = det->par[i];
        const Learn &l = p.learn;
        if (l.n >= need) p.learned = l.reference(q);
        if (l.n < need || !(p.learned.block_sd > 0.0))
            return VIBID_FAIL(VIBID_E_INSUFFICIENT_DATA,
                              "parameter %zu: %llu blocks learned%s; a reference needs %llu with a spread > 0", i,
                              (unsigned long long)l.n, l.n >= need ? " (no spread left)" : "",
                              (unsigned long long)need);
    }
    for (Param &p : det->par) {
        p.ref = p.learned;
        p.have_ref = true;
        det->design(p);
    }
    return VIBID_OK;
}

VIBID_API vibid_status vibid_change_set_reference(vibid_change *det, const vibid_change_reference *ref) {
    if (!det || !ref) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "det and ref are required");
    for (size_t i = 0; i < det->par.size(); ++i) {
        const vibid_change_reference &r = ref[i];
        if (!std::isfinite(r.mean) || !std::isfinite(r.block_sd) || !(r.block_sd > 0.0) || !(r.n_mean >= 1.0) ||
            !(r.n_sd >= 2.0))
            return VIBID_FAIL(VIBID_E_OUT_OF_RANGE,
                              "ref[%zu]: mean %g, block_sd %g, n_mean %g, n_sd %g (need finite mean, "
                              "block_sd > 0, n_mean >= 1, n_sd >= 2)",
                              i, r.mean, r.block_sd, r.n_mean, r.n_sd);
        const size_t q = det->cfg.n_covariates, T = terms_of(r, q);
        if (r.n_terms && r.n_terms != q && r.n_terms != full_terms(q))
            return VIBID_FAIL(VIBID_E_OUT_OF_RANGE, "ref[%zu]: n_terms %zu (need 0, %zu or %zu for %zu covariates)", i,
                              r.n_terms, q, full_terms(q), q);
        for (size_t j = 0; j < q; ++j) {
            const bool ok = std::isfinite(r.centre[j]) && std::isfinite(r.low[j]) && std::isfinite(r.high[j]) &&
                            r.low[j] <= r.high[j] && (!r.n_terms || std::isfinite(r.origin[j]));
            if (!ok)
                return VIBID_FAIL(VIBID_E_OUT_OF_RANGE,
                                  "ref[%zu], covariate %zu: centre %g, range [%g, %g], origin %g (need finite "
                                  "values, low <= high)",
                                  i, j, r.centre[j], r.low[j], r.high[j], r.origin[j]);
        }
        for (size_t t = 0; t < T; ++t) {
            bool ok = std::isfinite(r.slope[t]) && r.gram_inv[t * T + t] >= 0.0 &&
                      (!r.n_terms || std::isfinite(r.term_mean[t]));
            for (size_t l = 0; l < T; ++l) ok = ok && std::isfinite(r.gram_inv[t * T + l]);
            if (!ok)
                return VIBID_FAIL(VIBID_E_OUT_OF_RANGE,
                                  "ref[%zu], term %zu: slope %g, mean %g, G_tt %g (need finite values, G_tt >= 0)", i,
                                  t, r.slope[t], r.term_mean[t], r.gram_inv[t * T + t]);
        }
    }
    for (size_t i = 0; i < det->par.size(); ++i) {
        Param &p = det->par[i];
        p.ref = ref[i];
        p.have_ref = true;
        det->design(p);
    }
    return VIBID_OK;
}

VIBID_API vibid_status vibid_change_get_reference(const vibid_change *det, vibid_change_reference *ref) {
    if (!det || !ref) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "det and ref are required");
    for (const Param &p : det->par)
        if (!p.have_ref) return VIBID_FAIL(VIBID_E_STATE, "no reference yet");
    for (size_t i = 0; i < det->par.size(); ++i) ref[i] = det->par[i].ref;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_change_get_state(const vibid_change *det, size_t param, vibid_change_state *state) {
    if (!det || !state) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "det and state are required");
    if (param >= det->par.size())
        return VIBID_FAIL(VIBID_E_OUT_OF_RANGE, "param = %zu, the detector has %zu", param, det->par.size());
    const Param &p = det->par[param];
    vibid_change_state s{};
    s.have_reference = p.have_ref;
    s.active = p.active;
    double r = 0.0;
    if (p.have_ref) r = std::max(p.S[0], p.S[1]) / p.h;
    s.statistic = p.active ? p.stat_at_raise : r;
    s.mdc = p.have_ref ? p.mdc : kNaN;
    s.mdc_relative = p.have_ref && p.ref.mean != 0.0 ? p.mdc / std::fabs(p.ref.mean) : kNaN;
    s.last_block = p.last_block;
    s.blocks_learned = p.learn.n;
    s.blocks_tested = p.tested;
    s.out_of_range = p.last_out;
    s.weight = p.last_weight;
    s.blocks_out_of_range = p.out_of_range;
    *state = s;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_change_threshold(double k, double arl, double n_mean, double n_sd, double *h) {
    if (!h) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "h is NULL");
    if (!(k > 0.0) || !std::isfinite(k) || !(arl >= 2.0) || !std::isfinite(arl) || !(n_mean >= 1.0) ||
        !(n_sd >= 2.0))
        return VIBID_FAIL(VIBID_E_OUT_OF_RANGE, "k = %g, arl = %g, n_mean = %g, n_sd = %g (need k > 0, arl >= 2, "
                                                "n_mean >= 1, n_sd >= 2)",
                          k, arl, n_mean, n_sd);
    *h = threshold_for(k, arl, n_mean, n_sd);
    return VIBID_OK;
}
