// identify.cpp: model + regressor + estimator -> physical parameters with standard
// errors (identify.h). For ZOH models the unstructured difference form (1.16) is
// estimated and taken back to the structured unknowns by the matrix logarithm and a
// small linear least-squares problem.
#include <vibid/identify.h>
#include <vibid/lsq.h>
#include <vibid/output_error.h>
#include <vibid/modal.h>
#include <vibid/regressor.h>
#include <vibid/rls.h>

#include "api_guard.hpp"
#include "block_iv.hpp"
#include "stand_ekf.hpp"
#include "discretize_internal.hpp"
#include "model_internal.hpp"
#include "regressor_internal.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

using Eigen::MatrixXd;
using Eigen::VectorXd;
using vibid::throw_error;

namespace {
struct RegressorFree {
    void operator()(vibid_regressor *r) const noexcept { vibid_regressor_destroy(r); }
};
struct LsqFree {
    void operator()(vibid_lsq *l) const noexcept { vibid_lsq_destroy(l); }
};
struct RlsFree {
    void operator()(vibid_rls *r) const noexcept { vibid_rls_destroy(r); }
};
struct OeFree {
    void operator()(vibid_oe *o) const noexcept { vibid_oe_destroy(o); }
};
}  // namespace

namespace vibid {
struct EstimatorOps;  // one estimator kind's operations (kEstimators, at the end of this file)
}  // namespace vibid

struct vibid_ident {
    vibid_model model;
    vibid_ident_config cfg{};
    // The operations of the estimator that runs (cfg.estimator; AUTO resolved to the
    // state-space estimator is EKF's), set once by create.
    const vibid::EstimatorOps *ops = nullptr;
    std::unique_ptr<vibid_regressor, RegressorFree> reg;
    std::unique_ptr<vibid_lsq, LsqFree> lsq;
    std::unique_ptr<vibid::BlockIV> biv;  // IV and AUTO: sums per block (block_iv.hpp)
    // Constant forces (vibid_ident_config.constant_terms): nb = n constant columns after
    // the p_reg regressors, one per equation (0: none accumulated). biv then has p_reg + nb
    // regressors, and the plain fit is its solve on the leading p_reg; LS keeps a second
    // QR with them (lsq_c). ring_unit: the constant column's value (regressor_unit) of the
    // rows in `ring`. The last estimate's constants (empty: the plain fit stood) and the
    // Wald test's p-value (NaN: none made).
    std::size_t nb = 0;
    std::unique_ptr<vibid_lsq, LsqFree> lsq_c;
    std::vector<double> ring_unit, rows_xc;  // rows_xc: LS's rows with the constant columns
    std::vector<double> const_values, const_se;
    double const_p = std::nan("");
    // IV and AUTO on the structured form, the discretization check: the same estimator
    // on every second sample (step 2h, same pre-filter, the same lag in seconds). Its
    // difference from this estimate measures the discretization error (see estimate).
    std::unique_ptr<vibid_ident> half;
    bool half_take = true;  // the next sample goes to `half` too
    std::unique_ptr<vibid::StandEkf> ekf;  // EKF: the state-space estimator (stand_ekf.hpp)
    std::unique_ptr<vibid_rls, RlsFree> rls;
    // OE (output_error.h): the equation-error estimator that gives the start values (AUTO:
    // IV, or the EKF on a stand that is not fully measured), every sample pushed
    // (sample-major, kept for the fit), the fit, and the last fit's offsets.
    std::unique_ptr<vibid_ident> ee;
    std::unique_ptr<vibid_oe, OeFree> oe;
    std::vector<double> samples;
    std::vector<std::size_t> offset_channels;
    std::vector<double> offsets, offsets_se;
    std::string oe_description;  // what OE is (description = the start estimator's account + this + the fit's outcome)
    std::string ee_trouble;      // the start estimator's first divergence (OE keeps the samples; the fit goes on)
    std::size_t n = 0, p = 0, p_reg = 0, m = 0, q = 0, n_channels = 0;
    bool zoh = false;
    bool has_prior = false;  // RLS started from vibid_ident_set_prior
    // RLS with rls_alpha = 0 (automatic prior): the first prior_len samples' rows are kept,
    // the prior P0 = diag(1 / (1e-6 sum x_i^2)) is formed from them (1e-6 of their
    // information in every direction, whatever the units), then they are replayed.
    bool auto_prior = false, prior_done = false;
    std::size_t prior_len = 0, prior_count = 0;
    std::vector<double> prior_rows, prior_ss, prior_P0, prior_theta;
    // Per-sample scratch (sized in create).
    std::vector<double> x, y, rows_x, rows_w;
    std::vector<double> ring;  // IV: the last iv_lag + 1 regressors x (p_reg * m each)
    unsigned long long n_built = 0, n_samples = 0, n_rows = 0;
    // ZOH way back: structure matrices of each unknown and the known part.
    std::vector<MatrixXd> S_M, S_D, S_C, S_B;  // S_B: n x rz = [B_i, c_base_i]
    MatrixXd K_M, K_D, K_C, K_B;               // known parts (theta = 0)
    // Last estimate
    std::vector<double> cov;
    bool have_cov = false;
    std::vector<double> last_theta;  // IV/AUTO: the last estimate (p_reg x q), kept in unexcited directions
    bool have_theta = false;
    vibid_ident_quality quality{};
    std::vector<unsigned> param_flags;
    // Automatic choices: the highest natural frequency of the nominal model (0 = unknown)
    // and the text of vibid_ident_describe.
    double f_nominal_max = 0.0;
    std::string description;
    // Pre-filter cutoff from the data (IV and AUTO with the automatic cutoff on a stand
    // without nominal natural frequencies): the first pilot_len samples are kept while
    // this estimator runs with f_a / 20; after the last of them their estimate's highest
    // natural frequency sets the cutoff, and an estimator with it replaces this one,
    // replaying them (tune_prefilter). pilot_len = 0: no pilot (or it is over).
    vibid_ident_config requested{};  // the configuration as passed to vibid_ident_create
    std::vector<double> pilot;       // pilot_len samples x n_channels, sample-major
    std::size_t pilot_len = 0, pilot_count = 0;

    // Deferred estimates (vibid_ident_twin_*). Every reset and every replacement by the
    // pilot starts a new generation: the estimate memory above (last_theta) belongs to one.
    unsigned long long generation = 0;
    // A twin: the identification it copies, the generation it copied last, and for RLS
    // the RLS outputs at the copy (p_reg x q, p_reg x p_reg, q x q; sig_ok: the residual
    // covariance existed).
    const vibid_ident *twin_of = nullptr;
    unsigned long long synced_generation = 0;
    std::vector<double> frozen_theta, frozen_P, frozen_sig;
    bool frozen_sig_ok = false;

    vibid_ident() = default;
    vibid_ident(const vibid_ident &) = delete;
    vibid_ident &operator=(const vibid_ident &) = delete;
    vibid_ident &operator=(vibid_ident &&) = default;  // tune_prefilter's replacement
};

namespace vibid {

// Whether an estimator estimates the constant forces (vibid_ident_config.constant_terms).
enum class ConstantForces {
    none,        // never (constant_terms on is refused)
    structured,  // on the structured form (not the ZOH form): extra columns of the regression
    start,       // those of its start estimator (OE), which decides
};

// What create_ident passes on to an estimator's create: with_check = false leaves out the
// discretization check (the check's own estimator) and the pre-filter pilot;
// prefilter_why: the reason for a cutoff the pilot chose (see resolve_config).
struct CreateOptions {
    bool with_check;
    const std::string &prefilter_why;
};

// A regression estimator's fit of the difference form: Theta (p_reg x q), Cov(vec Theta)
// (column-major vec), the solve's rank and condition, the quality so far, the parameters
// the data leave unexcited (empty: none), the measured discretization error per
// parameter (empty: no check) and whether the constant forces stand (with_c).
struct RegressionFit {
    Eigen::MatrixXd Th, cov_reg;
    vibid_lsq_info li{};
    vibid_ident_quality qual{};
    std::vector<int> weak;
    Eigen::VectorXd disc_error;
    bool with_c = false;
};

// One estimator kind, one entry of kEstimators (indexed by vibid_estimator, at the end of
// this file). The rest of this file knows no estimator by name: adding one is writing
// these functions and adding its entry. The regression estimators (LS, IV, AUTO, RLS)
// share the regressor, the pre-filter and the way back from the difference form
// (create_regression, push_regression, estimate_regression) and fill in the four
// regression hooks; the others leave them NULL.
struct EstimatorOps {
    vibid_estimator kind;
    const char *name;  // vibid_estimator_name
    ConstantForces constants;
    // The instrumented estimators: instrument lag, pre-filter pilot, discretization check.
    bool instrumented;
    // The identification for a configuration create_ident has checked (cfg.estimator is
    // this kind). Throws vibid::Error.
    std::unique_ptr<vibid_ident> (*create)(const vibid_model &model, const vibid_ident_config &cfg,
                                           const CreateOptions &opt);
    // One sample (n_channels values): real time, no exceptions, no allocation.
    vibid_status (*push)(vibid_ident &id, const double *channels);
    // vibid_ident_estimate without the argument checks; throws vibid::Error.
    vibid_status (*estimate)(vibid_ident &id, double *theta, double *se, vibid_ident_info *info);
    // vibid_ident_set_prior without the argument checks; throws vibid::Error.
    void (*set_prior)(vibid_ident &id, const double *theta0, const double *P0);
    // Regression hooks: the estimator's line(s) of the description (resolve_config), its
    // solver objects sized for push (create_regression), one ready row x, y into them
    // (real time, no exceptions, no allocation) and the fit (estimate_regression).
    void (*describe)(const vibid_ident_config &cfg, std::string &why);
    void (*make_solver)(vibid_ident &id);
    vibid_status (*push_row)(vibid_ident &id);
    void (*solve)(vibid_ident &id, RegressionFit &fit);
};

}  // namespace vibid

using vibid::ConstantForces;
using vibid::CreateOptions;
using vibid::EstimatorOps;
using vibid::RegressionFit;

namespace {

// The number of estimator kinds (entries of kEstimators).
constexpr int kEstimatorCount = VIBID_ESTIMATOR_OE + 1;

// The entry of estimator kind k, 0 <= k < kEstimatorCount (create_ident checks it).
const EstimatorOps &ops_of(int k);
const EstimatorOps &ops_of(vibid_estimator k) { return ops_of(vibid::enum_value(k)); }


void check_status(vibid_status s, const char *what) {
    if (s != VIBID_OK) throw_error(s, "%s: %s", what, vibid_last_error());
}

// x is p x m column-major; rows is m x p column-major (one regression row per equation).
inline void transpose_into(const double *x, std::size_t p, std::size_t m, double *rows) {
    for (std::size_t e = 0; e < m; ++e)
        for (std::size_t i = 0; i < p; ++i) rows[e + i * m] = x[i + e * p];
}

std::string regressor_name(const vibid_ident &id, std::size_t i) {
    if (!id.zoh) return id.model.terms[id.model.param_term[i]].name;
    const std::size_t n = id.n, rz = (id.p_reg - 2 * n) / 2;
    if (i < 2 * n) return id.model.nodes[i % n].name + (i < n ? "(k-1)" : "(k-2)");
    const std::size_t j = (i - 2 * n) % rz;
    const std::string base = j < id.model.inputs.size() ? id.model.inputs[j].name : std::string("base");
    return base + (i - 2 * n < rz ? "(k-1)" : "(k-2)");
}

[[noreturn]] void refuse_null_space(const vibid_ident &id, const vibid_lsq_info &info) {
    std::string names;
    if (id.lsq) {
        std::vector<double> basis(id.p_reg * id.p_reg);
        std::size_t nv = 0;
        if (vibid_lsq_null_space(id.lsq.get(), basis.data(), id.p_reg, &nv) == VIBID_OK) {
            for (std::size_t v = 0; v < std::min(nv, id.p_reg); ++v) {
                const double *col = basis.data() + v * id.p_reg;
                double vmax = 0;
                for (std::size_t i = 0; i < id.p_reg; ++i) vmax = std::max(vmax, std::fabs(col[i]));
                std::string group;
                for (std::size_t i = 0; i < id.p_reg; ++i)
                    if (std::fabs(col[i]) > 0.1 * vmax) group += (group.empty() ? "" : ", ") + regressor_name(id, i);
                names += (names.empty() ? "{" : "; {") + group + "}";
            }
        }
    }
    throw_error(VIBID_E_NOT_IDENTIFIABLE,
                "the data do not separate the parameters (rank %zu of %zu)%s%s: the excitation is not rich enough",
                info.rank, id.p_reg, names.empty() ? "" : "; cannot separate ", names.c_str());
}

// ZOH way back: Theta (p_reg x n) of (1.16) -> structured unknowns theta (p).
VectorXd zoh_to_theta(const vibid_ident &id, const MatrixXd &Th, vibid_log_info &log_info) {
    const Eigen::Index n = static_cast<Eigen::Index>(id.n);
    const Eigen::Index rz = static_cast<Eigen::Index>((id.p_reg - 2 * id.n) / 2);
    const MatrixXd ThT = Th.transpose();  // [A1 A2 B1 B0]
    const MatrixXd Dt = -ThT.leftCols(n), Ct = -ThT.middleCols(n, n);
    const MatrixXd B1 = ThT.middleCols(2 * n, rz), B0 = ThT.rightCols(rz);
    MatrixXd K, L, J;
    vibid::second_order_to_continuous(Dt, Ct, B1, B0, id.cfg.sample_time, K, L, J, log_info);
    // M(theta) K = C(theta), M(theta) L = D(theta), M(theta) J = [B c_base](theta):
    // linear in theta.
    const Eigen::Index rows = 2 * n * n + n * rz;
    const Eigen::Index p = static_cast<Eigen::Index>(id.p);
    MatrixXd A(rows, p);
    VectorXd b(rows);
    auto stack = [&](const MatrixXd &Mm, const MatrixXd &Dm, const MatrixXd &Cm, const MatrixXd &Bm) {
        VectorXd v(rows);
        MatrixXd e1 = Mm * K - Cm, e2 = Mm * L - Dm, e3 = Mm * J - Bm;
        v << Eigen::Map<VectorXd>(e1.data(), e1.size()), Eigen::Map<VectorXd>(e2.data(), e2.size()),
            Eigen::Map<VectorXd>(e3.data(), e3.size());
        return v;
    };
    for (Eigen::Index i = 0; i < p; ++i)
        A.col(i) = stack(id.S_M[static_cast<std::size_t>(i)], id.S_D[static_cast<std::size_t>(i)],
                         id.S_C[static_cast<std::size_t>(i)], id.S_B[static_cast<std::size_t>(i)]);
    b = -stack(id.K_M, id.K_D, id.K_C, id.K_B);
    VectorXd scale(p);
    for (Eigen::Index i = 0; i < p; ++i) {
        scale(i) = A.col(i).norm();
        if (scale(i) == 0.0) scale(i) = 1.0;
        A.col(i) /= scale(i);
    }
    Eigen::ColPivHouseholderQR<MatrixXd> qr(A);
    qr.setThreshold(1e-10);
    if (qr.rank() < p)
        throw_error(VIBID_E_NOT_IDENTIFIABLE,
                    "ZOH way back: the continuous matrices do not determine all structured unknowns (rank %ld of %ld)",
                    static_cast<long>(qr.rank()), static_cast<long>(p));
    VectorXd th = qr.solve(b);
    return th.cwiseQuotient(scale);
}

// Highest natural frequency (Hz) of the model at its nominal values, 0 when the stand
// does not give a usable nominal value for every unknown (0 = not given) or the modes
// cannot be computed.
double nominal_max_frequency(const vibid_model &m) {
    const std::size_t p = m.param_term.size();
    std::vector<double> th(p);
    if (vibid_model_nominal(&m, th.data()) != VIBID_OK) return 0.0;
    for (std::size_t i = 0; i < p; ++i) {
        const vibid_param_kind k = m.terms[m.param_term[i]].kind;
        if ((k == VIBID_PARAM_MASS || k == VIBID_PARAM_STIFFNESS) && !(th[i] > 0.0)) return 0.0;
        if (k == VIBID_PARAM_GAIN && th[i] == 0.0) return 0.0;
    }
    std::vector<double> f(m.nodes.size()), z(m.nodes.size());
    if (vibid_model_modal(&m, th.data(), nullptr, f.data(), nullptr, z.data(), nullptr, nullptr, nullptr) != VIBID_OK)
        return 0.0;
    double fmax = 0.0;
    for (double v : f)
        if (std::isfinite(v)) fmax = std::max(fmax, v);
    return fmax;
}

std::string strprintf(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
std::string strprintf(const char *fmt, ...) {
    char buf[512];
    va_list ap;
    va_start(ap, fmt);
    std::vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    return buf;
}

// The model's inputs held between samples (VIBID_HOLD_ZOH), the base as "base", comma
// separated; empty when every input is smooth.
std::string held_signals(const vibid_model &m) {
    std::string held;
    for (const auto &u : m.inputs)
        if (u.hold == VIBID_HOLD_ZOH) held += (held.empty() ? "" : ", ") + u.name;
    if (m.has_base && m.base_hold == VIBID_HOLD_ZOH) held += held.empty() ? "base" : ", base";
    return held;
}

// Restarts the difference window, the pre-filter and the instrument ring together, so
// that every later row is again an exact regression (after a gap or an overflowing row).
void restart_window(vibid_ident &id) {
    vibid_regressor_reset(id.reg.get());
    id.n_built = 0;
}

// Length of the pre-filter pilot (vibid_ident::pilot) in samples: 2 s, at least 4096
// samples (34 blocks of the IV statistics at f_a / 20).
std::size_t pilot_length(double h) { return std::max<std::size_t>(4096, static_cast<std::size_t>(std::ceil(2.0 / h))); }

// Whether the estimator for cfg runs the pre-filter pilot: an instrumented one with the
// automatic cutoff on a stand whose nominal model gives no natural frequency.
bool runs_pilot(const vibid_ident_config &cfg, double f_nominal_max) {
    return ops_of(cfg.estimator).instrumented && cfg.prefilter_hz < 0.0 && !(f_nominal_max > 0.0);
}

// The automatic cutoff for a highest natural frequency fmax (Hz) at sample rate fa:
// 4 fmax keeps every mode in the pass band with the filter's phase small there, within
// [f_a / 50, f_a / 8] (below: too few samples per cutoff period for the lag; above: the
// stencils' bias grows as (w h)^4).
double cutoff_for(double fmax, double fa) { return std::min(std::max(4.0 * fmax, fa / 50.0), fa / 8.0); }

// P(chi^2_k > x), the regularized upper incomplete gamma Q(k/2, x/2) for integer k, from
// Q(1/2, y) = erfc(sqrt y), Q(1, y) = e^-y and Q(s + 1, y) = Q(s, y) + y^s e^-y / Gamma(s + 1).
double chi2_survival(double x, std::size_t k) {
    if (!(x > 0.0)) return 1.0;
    const double y = 0.5 * x, top = 0.5 * static_cast<double>(k);
    double s = k % 2 ? 0.5 : 1.0;
    double q = k % 2 ? std::erfc(std::sqrt(y)) : std::exp(-y);
    for (; s + 1.0 <= top + 1e-9; s += 1.0) q += std::exp(s * std::log(y) - y - std::lgamma(s + 1.0));
    return std::min(q, 1.0);
}

// Whether the estimator for cfg on model m accumulates the constant-force columns
// (vibid_ident_config.constant_terms): those that estimate them on the structured form
// (LS, IV and AUTO), on that form, unless OFF.
bool has_constant_columns(const vibid_model &m, const vibid_ident_config &cfg) {
    const bool form =
        m.discretization != VIBID_DISC_ZOH && ops_of(cfg.estimator).constants == ConstantForces::structured;
    return form && cfg.constant_terms != VIBID_CONSTANT_OFF;
}

// Level of the automatic constant-terms test: the constants are kept when the Wald test
// of all of them = 0 rejects at this p-value.
constexpr double kConstantTestLevel = 1e-3;

// Resolves every automatic setting of cfg for the model and writes why into `why`.
// prefilter_why: the reason for a cutoff set by the pilot (tune_prefilter), else empty.
vibid_ident_config resolve_config(const vibid_model &m, const vibid_ident_config &cfg, double f_nominal_max,
                                  const std::string &prefilter_why, std::string &why) {
    vibid_ident_config r = cfg;
    const double h = cfg.sample_time, fa = 1.0 / h;
    const bool zoh = m.discretization == VIBID_DISC_ZOH;
    const EstimatorOps &ops = ops_of(cfg.estimator);
    const bool iv_family = ops.instrumented;
    ops.describe(cfg, why);
    if (zoh) {
        r.difference_order = 2;
        why += "discretization: ZOH difference form (1.16) of the stand (exact for held inputs)\n";
    } else if (cfg.difference_order == 0 && iv_family && cfg.iv_lag != 0 && cfg.iv_lag < 5) {
        r.difference_order = 2;
        why += "differences: central differences (1.17) (automatic: the configured iv_lag is shorter than the "
               "five-point window)\n";
    } else if (cfg.difference_order == 0) {
        r.difference_order = 4;
        why += "differences: five-point stencils (automatic): bias (w h)^4/30 instead of (w h)^2/6 of (1.17)\n";
    } else {
        why += strprintf("differences: order %u (configured)\n", cfg.difference_order);
    }
    const unsigned width = r.difference_order + 1;
    if (cfg.prefilter_hz < 0.0) {
        double fc;
        if (f_nominal_max > 0.0) {
            fc = cutoff_for(f_nominal_max, fa);
            why += strprintf("pre-filter: %.4g Hz (automatic: 4 x the highest natural frequency of the nominal "
                             "model, %.4g Hz, within [f_a/50, f_a/8])\n",
                             fc, f_nominal_max);
        } else {
            // f_a / 20: a stand sampled at 20 or more samples per period of its highest
            // mode (stand-file.md) keeps every mode in the pass band, while the content
            // above, where the stencils' bias grows as (w h)^4 (harmonics of a cubic
            // spring reach far up), is filtered out of the regression.
            fc = fa / 20.0;
            if (runs_pilot(cfg, f_nominal_max))
                why += strprintf("pre-filter: %.4g Hz (automatic: f_a/20) for the first %zu samples (%.4g s), then "
                                 "chosen from the data: of f_a/20, f_a/50, 2 and 4 x the highest natural frequency f_max "
                                 "of their estimate (within [f_a/50, f_a/8], none below 2 f_max) the one whose "
                                 "estimate has the smallest relative variances, and those samples replayed into it "
                                 "(the stand gives no nominal value for "
                                 "every unknown, so no natural frequency is known in advance)\n",
                                 fc, pilot_length(h), static_cast<double>(pilot_length(h)) * h);
            else
                why += strprintf("pre-filter: %.4g Hz (automatic: f_a/20; the stand gives no nominal value for "
                                 "every unknown, so no natural frequency is known in advance)\n",
                                 fc);
        }
        r.prefilter_hz = fc;
    } else if (!prefilter_why.empty()) {
        why += prefilter_why;
    } else if (cfg.prefilter_hz > 0.0) {
        why += strprintf("pre-filter: %.4g Hz (configured)\n", cfg.prefilter_hz);
    } else {
        why += "pre-filter: off (configured)\n";
    }
    if (iv_family) {
        if (cfg.iv_lag == 0) {
            // Short enough that the instruments stay correlated with the regressors at
            // every mode (a lag near a period of some mode makes a weak instrument: 2.9 %
            // damping errors on the test chain at lag 59 against 0.13 % at 19), long
            // enough that the filtered noise has decorrelated: one period of the
            // pre-filter's cutoff beyond the difference window (coverage of the
            // 2-standard-error bars 93.5-96 % on that chain, tests/model/test_auto.c).
            const std::size_t memory =
                r.prefilter_hz > 0.0 ? static_cast<std::size_t>(std::ceil(1.0 / (r.prefilter_hz * h))) : 2;
            r.iv_lag = std::min<std::size_t>(width + memory, 4096);
            why += strprintf("instrument lag: %zu samples (automatic: difference window %u + %s %zu)\n", r.iv_lag,
                             width, r.prefilter_hz > 0.0 ? "one period of the pre-filter cutoff 1/(f_c h) =" : "margin",
                             memory);
        } else {
            why += strprintf("instrument lag: %zu samples (configured)\n", cfg.iv_lag);
        }
    }
    if (cfg.forgetting < 1.0)
        why += strprintf("forgetting: %.6g (memory about %.4g samples = %.4g s)\n", cfg.forgetting,
                         1.0 / (1.0 - cfg.forgetting), h / (1.0 - cfg.forgetting));
    else
        why += "forgetting: none (every sample counts alike)\n";
    if (has_constant_columns(m, cfg))
        why += cfg.constant_terms == VIBID_CONSTANT_ON
                   ? "constant forces: one per node's equation, always estimated (configured)\n"
                   : strprintf("constant forces: one per node's equation (sensor offsets, constant loads), fitted at "
                               "each estimate and kept when a Wald test of all of them = 0 rejects at p < %g "
                               "(automatic)\n",
                               kConstantTestLevel);
    else if (ops.constants != ConstantForces::structured || zoh)
        why += "constant forces: not estimated (not implemented for RLS and the ZOH form)\n";
    else
        why += "constant forces: off (configured)\n";
    const std::string held = held_signals(m);
    if (!held.empty())
        why += "held inputs: " + held +
               (zoh ? " (exact in the ZOH form)\n" : " (entered as their hold equivalents, regressor.h)\n");
    return r;
}

// Automatic RLS prior (see vibid_ident::auto_prior): keeps this sample's rows; at the
// last one of the first prior_len, sets the prior and replays them. Allocation-free.
vibid_status collect_prior_rows(vibid_ident &id) {
    const std::size_t nx = id.p_reg * id.m, ny = id.m * id.q, stride = nx + ny;
    if (!vibid::all_finite(id.x.data(), nx) || !vibid::all_finite(id.y.data(), ny))
        return VIBID_FAIL(VIBID_E_NONFINITE, "regressor overflow (non-finite row)");
    double *slot = id.prior_rows.data() + id.prior_count * stride;
    std::copy(id.x.begin(), id.x.end(), slot);
    std::copy(id.y.begin(), id.y.end(), slot + nx);
    if (id.prior_count == 0) std::fill(id.prior_ss.begin(), id.prior_ss.end(), 0.0);
    for (std::size_t e = 0; e < id.m; ++e)
        for (std::size_t i = 0; i < id.p_reg; ++i) id.prior_ss[i] += id.x[i + e * id.p_reg] * id.x[i + e * id.p_reg];
    if (++id.prior_count < id.prior_len) return VIBID_OK;
    // P0 = diag(1 / (1e-6 S_i)): the prior is worth 1e-6 of these samples' information in
    // each regressor's own units; a column that stayed zero gets the largest variance.
    double smax = 0.0;
    for (double v : id.prior_ss) smax = std::max(smax, v);
    if (!(smax > 0.0)) smax = 1.0;
    std::fill(id.prior_P0.begin(), id.prior_P0.end(), 0.0);
    for (std::size_t i = 0; i < id.p_reg; ++i)
        id.prior_P0[i + i * id.p_reg] = 1.0 / (1e-6 * std::max(id.prior_ss[i], 1e-30 * smax));
    vibid_status s = vibid_rls_set_prior(id.rls.get(), id.prior_theta.data(), id.prior_P0.data());
    if (s != VIBID_OK) return s;
    id.prior_done = true;
    for (std::size_t k = 0; k < id.prior_len && s == VIBID_OK; ++k) {
        const double *r = id.prior_rows.data() + k * stride;
        s = vibid_rls_update(id.rls.get(), r, r + nx);
    }
    return s;
}

}  // namespace

extern "C" {

// The estimator names (identify.h) are those of the entries of kEstimators.
VIBID_API const char *vibid_estimator_name(vibid_estimator kind) {
    const int k = vibid::enum_value(kind);
    return k >= 0 && k < kEstimatorCount ? ops_of(k).name : nullptr;
}

VIBID_API vibid_status vibid_estimator_from_name(const char *name, vibid_estimator *kind) {
    if (!name || !kind) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "name and kind are required");
    for (int k = 0; k < kEstimatorCount; ++k)
        if (std::strcmp(name, ops_of(k).name) == 0) {
            *kind = ops_of(k).kind;
            return VIBID_OK;
        }
    char names[128] = "";
    for (int k = 0; k < kEstimatorCount; ++k) {
        const std::size_t len = std::strlen(names);
        std::snprintf(names + len, sizeof names - len, "%s%s", k ? ", " : "", ops_of(k).name);
    }
    return VIBID_FAIL(VIBID_E_OUT_OF_RANGE, "estimator \"%.64s\" unknown: one of %s", name, names);
}

VIBID_API void vibid_ident_config_init(vibid_ident_config *cfg, double sample_time) {
    if (!cfg) return;
    cfg->estimator = VIBID_ESTIMATOR_AUTO;
    cfg->sample_time = sample_time;
    cfg->prefilter_hz = -1.0;
    cfg->iv_lag = 0;
    cfg->forgetting = 1.0;
    cfg->rls_alpha = 0.0;
    cfg->difference_order = 0;
    cfg->constant_terms = VIBID_CONSTANT_AUTO;
}

}  // extern "C"

namespace {

// The state-space estimator (stand_ekf.hpp): identifiability from the sensitivity of
// the measured responses, then the filter. why_auto is empty when it was configured.
std::unique_ptr<vibid_ident> create_state_space(const vibid_model &model, const vibid_ident_config &cfg,
                                                const std::string &why_auto) {
    std::string ident_report;
    vibid::check_identifiable_state_space(model, cfg.sample_time, ident_report);
    auto id = std::make_unique<vibid_ident>();
    id->model = model;
    id->cfg = cfg;
    const bool kf_rls = cfg.estimator == VIBID_ESTIMATOR_KF_RLS;
    id->cfg.estimator = kf_rls ? VIBID_ESTIMATOR_KF_RLS : VIBID_ESTIMATOR_EKF;
    id->n = model.nodes.size();
    id->p = model.param_term.size();
    id->n_channels = model.channels.size();
    id->f_nominal_max = nominal_max_frequency(model);
    vibid::StandEkfSettings st;
    st.h = cfg.sample_time;
    st.forgetting = cfg.forgetting;
    st.kf_rls = kf_rls;
    id->ekf = std::make_unique<vibid::StandEkf>(id->model, st);
    std::string &why = id->description;
    if (kf_rls)
        why += "estimator: Kalman filter on the stand's states + recursive LS on its physical parameters (the "
               "paper's 3.16, configured); standard errors not valid (the regressors are filtered states)\n";
    else if (why_auto.empty())
        why += "estimator: extended Kalman filter on the stand's states and physical parameters (configured)\n";
    else
        why += "estimator: extended Kalman filter on the stand's states and physical parameters (automatic: " +
               why_auto + ")\n";
    why += "discretization: exact over each sample (matrix exponential; smooth inputs linear between samples, held "
           "inputs constant, cubic springs linearised per step)\n";
    why += ident_report + "\n";
    why += strprintf("start: the stand's nominal values, relative standard deviation %.2g; measurement noise and "
                     "scales from the first %zu samples\n",
                     st.prior_rel, st.window);
    for (const auto &w : model.disturbances)
        why += w.std_dev > 0.0 ? strprintf("disturbance %s: std %.6g N (declared)\n", w.name.c_str(), w.std_dev)
                               : strprintf("disturbance %s: intensity estimated from the first %zu samples (largest "
                                           "innovation likelihood)\n",
                                           w.name.c_str(), st.window);
    if (cfg.forgetting < 1.0)
        why += strprintf("forgetting: %.6g on the parameters' %s (memory about %.4g samples = %.4g s)\n",
                         cfg.forgetting, kf_rls ? "regression" : "covariance", 1.0 / (1.0 - cfg.forgetting),
                         cfg.sample_time / (1.0 - cfg.forgetting));
    else
        why += "forgetting: none (every sample counts alike)\n";
    // Sized here so that an estimate (at the daemon's track-row rate) allocates nothing.
    id->cov.assign(id->p * id->p, 0.0);
    id->param_flags.assign(id->p, 0u);
    return id;
}

// Estimate of the state-space estimator: the filter's parameters and the parameter block
// of its covariance, without forgetting widened where the sandwich covariance of its
// parameter scores is wider (stand_ekf.cpp). An NIS above 2 flags them (the model does not
// explain the data), and so do a sandwich not yet available (fewer than 16 blocks of
// scores) and one far wider than the filter's (below). The KF+RLS's are the regression's
// textbook ones on coloured equation errors: always flagged.
vibid_status estimate_state_space(vibid_ident &id, double *theta, double *se, vibid_ident_info *info) {
    const vibid_status s = id.ekf->estimate(theta, se, id.cov.data());
    if (s != VIBID_OK) return s;
    const vibid::StandEkfStats &st = id.ekf->stats();
    vibid_ident_quality qual{};
    qual.z_consistency = st.drift_z;
    qual.rcond = std::nan("");
    qual.bias_relative = 0.0;
    // The drift check (stand_ekf.hpp) must have passed: before its reference exists the
    // error bars are not yet verified (a 3-DOF chain at 10 kHz 1 s after its start: dampers
    // 40 standard errors off, NIS fine).
    const bool drift_checked = id.cfg.forgetting < 1.0 || !std::isnan(st.drift_z);
    // Scores that spread more than 3 times (in variance) what the filter's noise model
    // gives: the model does not explain the data, and a model error biases the estimate
    // beyond any error bar (an impact test with 2 ms hammer pulses at 5 kHz, which the
    // filter takes as linear between samples: dampers 2 % off at 4-8 sandwich standard
    // errors, variance ratio about 5; consistent stands 0.04-0.6).
    const bool robust_checked = id.cfg.forgetting < 1.0 || (st.robust && !(st.robust_ratio > 3.0));
    if (!(st.nis_avg <= 2.0) || st.n_steps < 2 * id.p || id.cfg.estimator == VIBID_ESTIMATOR_KF_RLS ||
        !drift_checked || st.drift_z > 4.0 || !robust_checked)
        qual.flags |= VIBID_QUALITY_SE_INVALID;
    id.param_flags.assign(id.p, qual.flags);
    id.quality = qual;
    id.have_cov = true;
    if (info) {
        *info = vibid_ident_info{};
        info->n_samples = id.n_samples;
        info->n_rows = st.n_steps;
        info->rank = id.p;
        info->rcond = std::nan("");
    }
    return VIBID_OK;
}

}  // namespace

namespace {

// vibid_ident_create; with_check = false leaves out the discretization check (the
// check's own estimator) and the pre-filter pilot; prefilter_why: see resolve_config.
std::unique_ptr<vibid_ident> create_ident(const vibid_model *model, const vibid_ident_config *cfg, bool with_check,
                                          const std::string &prefilter_why = std::string()) {
    vibid::require_finalized(model);
    if (!cfg) throw_error(VIBID_E_NULL_ARGUMENT, "cfg is NULL");
    const int est = vibid::enum_value(cfg->estimator);
    // the range checked on the int read without an enum load (an out-of-range value passed
    // as vibid_estimator would be undefined behaviour, which lib.test_enum_args catches)
    if (est < 0 || est >= kEstimatorCount) throw_error(VIBID_E_OUT_OF_RANGE, "estimator %d unknown", est);
    if (!(cfg->sample_time > 0.0) || !std::isfinite(cfg->sample_time))
        throw_error(VIBID_E_OUT_OF_RANGE, "sample_time = %g s must be > 0 and finite", cfg->sample_time);
    if (cfg->difference_order != 0 && cfg->difference_order != 2 && cfg->difference_order != 4)
        throw_error(VIBID_E_OUT_OF_RANGE, "difference_order = %u: use 0 (automatic), 2 or 4",
                    cfg->difference_order);
    if (!(cfg->forgetting > 0.0 && cfg->forgetting <= 1.0))
        throw_error(VIBID_E_OUT_OF_RANGE, "forgetting = %g outside (0, 1]", cfg->forgetting);
    if (!(cfg->rls_alpha >= 0.0) || !std::isfinite(cfg->rls_alpha))
        throw_error(VIBID_E_OUT_OF_RANGE, "rls_alpha = %g: > 0, or 0 for the automatic prior", cfg->rls_alpha);
    if (cfg->iv_lag != 0 && (cfg->iv_lag < 3 || cfg->iv_lag > 4096))
        throw_error(VIBID_E_OUT_OF_RANGE, "iv_lag = %zu outside 3..4096 (0 = automatic)", cfg->iv_lag);
    const int ct = vibid::enum_value(cfg->constant_terms);
    if (ct != VIBID_CONSTANT_AUTO && ct != VIBID_CONSTANT_OFF && ct != VIBID_CONSTANT_ON)
        throw_error(VIBID_E_OUT_OF_RANGE, "constant_terms %d unknown (0 auto, 1 off, 2 on)", ct);
    const EstimatorOps &ops = ops_of(est);
    if (ct == VIBID_CONSTANT_ON &&
        (ops.constants == ConstantForces::none ||
         (model->discretization == VIBID_DISC_ZOH && ops.constants == ConstantForces::structured)))
        throw_error(VIBID_E_UNSUPPORTED,
                    "constant_terms on: constant forces are estimated by LS, IV and AUTO on the structured form "
                    "only (not RLS, the state-space estimators or the ZOH form)");
    std::unique_ptr<vibid_ident> id = ops.create(*model, *cfg, CreateOptions{with_check, prefilter_why});
    id->ops = &ops_of(id->cfg.estimator);  // AUTO on the state-space estimator: EKF's
    return id;
}

// The regression estimators' create (LS, IV, AUTO, RLS): the regressor and the difference
// form, the estimator's solver (make_solver), the ZOH way back, the discretization check
// and the pre-filter pilot.
std::unique_ptr<vibid_ident> create_regression(const vibid_model &model, const vibid_ident_config &cfg,
                                               const CreateOptions &opt) {
    // Identifiability before any sample.
    // The check's own message says why (not identifiable, a signal not measured, a
    // discretization that does not support the model): no prefix that would claim
    // "not identifiable" for all of them.
    {
        const vibid_status st = vibid_model_check_identifiable(&model, nullptr);
        if (st != VIBID_OK) throw_error(st, "%s", vibid_last_error());
    }
    auto id = std::make_unique<vibid_ident>();
    id->model = model;
    id->f_nominal_max = nominal_max_frequency(model);
    id->cfg = resolve_config(model, cfg, id->f_nominal_max, opt.prefilter_why, id->description);
    id->requested = cfg;
    const vibid_ident_config &rcfg = id->cfg;
    if (ops_of(rcfg.estimator).instrumented && rcfg.iv_lag < rcfg.difference_order + 1)
        throw_error(VIBID_E_OUT_OF_RANGE, "iv_lag = %zu is shorter than the difference window (%u samples)",
                    rcfg.iv_lag, rcfg.difference_order + 1);
    id->reg.reset(vibid_regressor_create_order(&model, rcfg.sample_time, rcfg.prefilter_hz, rcfg.difference_order));
    if (!id->reg) throw_error(VIBID_E_OUT_OF_RANGE, "%s", vibid_last_error());
    vibid_regressor_dims rd{};
    check_status(vibid_regressor_get_dims(id->reg.get(), &rd), "regressor");
    id->p_reg = rd.n_regressors;
    id->m = rd.n_equations;
    id->q = rd.n_outputs;
    id->n = model.nodes.size();
    id->p = model.param_term.size();
    id->n_channels = model.channels.size();
    id->zoh = model.discretization == VIBID_DISC_ZOH;
    id->x.assign(id->p_reg * id->m, 0.0);
    id->y.assign(id->m * id->q, 0.0);
    id->rows_x.assign(id->p_reg * id->m, 0.0);
    id->rows_w.assign(id->p_reg * id->m, 0.0);
    id->nb = has_constant_columns(model, rcfg) ? id->n : 0;
    if (id->nb) id->rows_xc.assign((id->p_reg + id->nb) * id->m, 0.0);
    ops_of(rcfg.estimator).make_solver(*id);
    if (id->zoh) {
        const Eigen::Index n = static_cast<Eigen::Index>(id->n), r = static_cast<Eigen::Index>(model.inputs.size());
        const Eigen::Index rz = static_cast<Eigen::Index>((id->p_reg - 2 * id->n) / 2);
        auto fetch = [&](long param, MatrixXd &Mm, MatrixXd &Dm, MatrixXd &Cm, MatrixXd &Bz) {
            Mm.resize(n, n);
            Dm.resize(n, n);
            Cm.resize(n, n);
            MatrixXd Bm(n, r);
            VectorXd cb(n);
            vibid_status s;
            if (param < 0) {
                std::vector<double> zero(id->p, 0.0);
                s = vibid_model_assemble(&model, zero.data(), Mm.data(), Dm.data(), Cm.data(), Bm.data(), nullptr,
                                         cb.data());
            } else {
                s = vibid_model_structure(&model, static_cast<std::size_t>(param), Mm.data(), Dm.data(), Cm.data(),
                                          Bm.data(), nullptr, cb.data());
            }
            check_status(s, "structure");
            Bz.resize(n, rz);
            if (r) Bz.leftCols(r) = Bm;
            if (rz > r) Bz.col(r) = cb;
        };
        id->S_M.resize(id->p);
        id->S_D.resize(id->p);
        id->S_C.resize(id->p);
        id->S_B.resize(id->p);
        for (std::size_t i = 0; i < id->p; ++i) fetch(static_cast<long>(i), id->S_M[i], id->S_D[i], id->S_C[i], id->S_B[i]);
        fetch(-1, id->K_M, id->K_D, id->K_C, id->K_B);
    }
    id->cov.assign(id->p * id->p, 0.0);
    // Not with held inputs: their hold equivalents describe a hold of h, which every
    // second sample does not show (on the held-base test stand the check reported 10 to
    // 100 times the actual errors); the a-priori bound stays for them.
    if (opt.with_check && id->biv && !id->zoh && held_signals(model).empty() &&
        rcfg.prefilter_hz < 0.45 / (2.0 * rcfg.sample_time)) {
        vibid_ident_config hc = rcfg;
        hc.estimator = VIBID_ESTIMATOR_IV;
        hc.sample_time = 2.0 * rcfg.sample_time;
        hc.forgetting = rcfg.forgetting * rcfg.forgetting;
        hc.iv_lag = std::max<std::size_t>((rcfg.iv_lag + 1) / 2, rcfg.difference_order + 1);
        id->half = create_ident(&model, &hc, false);
        id->description +=
            "discretization check: the same estimator on every second sample (step 2h); their difference "
            "beyond its noise, / 3, is included in the standard errors as the discretization error (an error "
            "growing as h^2: the aliasing of corners in the excitation)\n";
    }
    if (opt.with_check && runs_pilot(cfg, id->f_nominal_max)) {
        id->pilot_len = pilot_length(rcfg.sample_time);
        id->pilot.assign(id->pilot_len * id->n_channels, 0.0);
    }
    return id;
}

}  // namespace

extern "C" {

VIBID_API vibid_ident *vibid_ident_create(const vibid_model *model, const vibid_ident_config *cfg) {
    return vibid::guard_create<vibid_ident>(__func__, [&] { return create_ident(model, cfg, true).release(); });
}

VIBID_API vibid_status vibid_ident_reset(vibid_ident *ident) {
    VIBID_GUARD(
        if (!ident) throw_error(VIBID_E_NULL_ARGUMENT, "ident is NULL");
        if (ident->ekf) ident->ekf->reset();
        if (ident->ee) {
            check_status(vibid_ident_reset(ident->ee.get()), "equation-error reset");
            ident->samples.clear();
        }
        if (ident->reg) check_status(vibid_regressor_reset(ident->reg.get()), "regressor reset");
        if (ident->lsq) check_status(vibid_lsq_reset(ident->lsq.get()), "lsq reset");
        if (ident->lsq_c) check_status(vibid_lsq_reset(ident->lsq_c.get()), "lsq reset");
        if (ident->biv) ident->biv->reset();
        if (ident->half) check_status(vibid_ident_reset(ident->half.get()), "discretization check reset");
        ident->half_take = true;
        if (ident->rls) check_status(vibid_rls_reset(ident->rls.get()), "rls reset");
        ident->n_built = ident->n_samples = ident->n_rows = 0;
        ident->have_theta = false;
        ident->prior_done = ident->has_prior;
        ident->prior_count = 0;
        ident->pilot_count = 0;  // a pilot not yet over starts again
        ident->have_cov = false;
        ++ident->generation;
        return VIBID_OK;);
}

VIBID_API void vibid_ident_destroy(vibid_ident *ident) { delete ident; }

VIBID_API vibid_status vibid_ident_dims(const vibid_ident *ident, size_t *n_channels, size_t *n_params) {
    if (!ident) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "ident is NULL");
    if (n_channels) *n_channels = ident->n_channels;
    if (n_params) *n_params = ident->p;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_ident_set_prior(vibid_ident *ident, const double *theta0, const double *P0) {
    VIBID_GUARD(
        if (!ident) throw_error(VIBID_E_NULL_ARGUMENT, "ident is NULL");
        ident->ops->set_prior(*ident, theta0, P0);
        return VIBID_OK;);
}

namespace {

vibid_status push_sample(vibid_ident *ident, const double *channels);
vibid_status push_regression(vibid_ident &id, const double *channels);

// A candidate's pre-filter line until the pilot has chosen (replaced by the reason).
constexpr const char *kPilotPlaceholder = "pre-filter: (a pilot candidate)\n";

// vibid_ident_estimate without its traces: an estimate leaves its result behind (the
// block IV keeps the last estimate in weakly informed directions, the covariance is kept
// for vibid_ident_covariance), so the pilot's own estimates would make the run differ from
// one configured with the chosen cutoff from the start. The state is put back afterwards.
// Nor does the pilot read that memory: it estimates as if no estimate had been asked for
// before, so its choice depends on the samples alone, not on how often a caller asked
// for estimates during it (and a caller whose estimates run on a twin chooses alike).
vibid_status estimate_without_trace(vibid_ident &id, double *theta, double *se) {
    const bool have_theta = id.have_theta, have_cov = id.have_cov;
    const std::vector<double> last_theta = id.last_theta, cov = id.cov;
    const vibid_ident_quality quality = id.quality;
    const std::vector<unsigned> param_flags = id.param_flags;
    const std::vector<double> const_values = id.const_values, const_se = id.const_se;
    const double const_p = id.const_p;
    id.have_theta = false;
    const vibid_status s = vibid_ident_estimate(&id, theta, se, nullptr);
    id.const_values = const_values;
    id.const_se = const_se;
    id.const_p = const_p;
    id.have_theta = have_theta;
    id.have_cov = have_cov;
    id.last_theta = last_theta;
    id.cov = cov;
    id.quality = quality;
    id.param_flags = param_flags;
    return s;
}

// The pilot's figure of merit for an estimate: the sum over the parameters of
// (se_i / theta_i)^2, the relative variances (what a track row's error bars add up to).
// HUGE_VAL when a parameter is not excited (infinite se).
double sum_relative_variance(const std::vector<double> &th, const std::vector<double> &se) {
    double sum = 0.0;
    for (std::size_t i = 0; i < th.size(); ++i) {
        if (!std::isfinite(se[i]) || !std::isfinite(th[i])) return HUGE_VAL;
        if (th[i] != 0.0) sum += (se[i] / th[i]) * (se[i] / th[i]);
    }
    return sum;
}

// The same for an estimator's current estimate; HUGE_VAL when it gives none.
double relative_variance(vibid_ident &id) {
    std::vector<double> th(id.p), se(id.p);
    if (estimate_without_trace(id, th.data(), se.data()) != VIBID_OK) return HUGE_VAL;
    return sum_relative_variance(th, se);
}

// The end of the pre-filter pilot (vibid_ident::pilot). Which cutoff is best depends on
// the data: the modes must stay inside the pass band, but where derivatives come from
// displacements the stencils amplify sensor noise as w^2, so every hertz of band beyond
// the response's costs variance (the paper's example 1 at 1 % noise, x only, modes 23 and
// 48 Hz: c2 +0.13 % at f_a/20 = 100 Hz, -0.68 % at 4 x 48 Hz = 193 Hz). So the pilot's
// samples are replayed into candidate cutoffs, f_a/50 and 2 and 4 times the highest natural
// frequency of the pilot's estimate (within [f_a/50, f_a/8]), beside the pilot's own
// f_a/20, and the one whose estimate has the smallest sum of relative variances goes on.
// Allocates (once per run); never fails the push: without a usable estimate f_a/20 stays
// and the description says why.
void tune_prefilter(vibid_ident &id) {
    const double fa = 1.0 / id.cfg.sample_time, fc_now = id.cfg.prefilter_hz;
    const std::size_t n_pilot = id.pilot_len, nc = id.n_channels;
    std::vector<double> pilot = std::move(id.pilot);
    id.pilot_len = id.pilot_count = 0;
    std::string keep_why;
    try {
        std::vector<double> th(id.p), se(id.p), f(id.n), z(id.n);
        if (estimate_without_trace(id, th.data(), se.data()) != VIBID_OK)
            throw_error(VIBID_E_INSUFFICIENT_DATA, "no estimate: %s", vibid_last_error());
        const vibid_status ms =
            vibid_model_modal(&id.model, th.data(), nullptr, f.data(), nullptr, z.data(), nullptr, nullptr, nullptr);
        double fmax = 0.0;
        if (ms == VIBID_OK)  // an unstable estimate's modes are no guide
            for (double v : f)
                if (std::isfinite(v)) fmax = std::max(fmax, v);
        if (!(fmax > 0.0 && fmax < 0.5 * fa))
            throw_error(VIBID_E_NUMERICAL, "their estimate gives no natural frequency between 0 and f_a/2");
        // The candidates, each at least 10 % from the others (the pilot's f_a/20 first),
        // none below 2 f_max (within those 10 %): a cutoff under the highest mode filters
        // out the response that informs its parameters, and there the block error bars
        // over-state the spread (base stand, 45 Hz mode, at f_a/50 = 40 Hz: coverage 98.8 %,
        // rms(error / se) 0.7-0.9, against 95 % at f_a/20).
        const double lowest = 2.0 * fmax / 1.1;
        std::vector<double> cand{fc_now};
        for (double fc : {fa / 50.0, cutoff_for(0.5 * fmax, fa), cutoff_for(fmax, fa)}) {
            bool distinct = fc >= lowest || fc == fa / 8.0;
            for (double c : cand) distinct = distinct && std::fabs(fc / c - 1.0) > 0.1;
            if (distinct) cand.push_back(fc);
        }
        std::vector<double> score{fc_now >= lowest ? sum_relative_variance(th, se) : HUGE_VAL};
        std::unique_ptr<vibid_ident> best;
        std::size_t best_k = 0;
        for (std::size_t k = 1; k < cand.size(); ++k) {
            vibid_ident_config cfg = id.requested;
            cfg.prefilter_hz = cand[k];
            std::unique_ptr<vibid_ident> trial = create_ident(&id.model, &cfg, true, kPilotPlaceholder);
            // Their statuses were returned when they were first pushed.
            for (std::size_t s = 0; s < n_pilot; ++s) (void)push_sample(trial.get(), pilot.data() + s * nc);
            score.push_back(relative_variance(*trial));
            if (score[k] < score[best_k]) {
                best = std::move(trial);
                best_k = k;
            }
        }
        std::string scores;
        for (std::size_t k = 0; k < cand.size(); ++k)
            scores += k == 0 && !(fc_now >= lowest)
                          ? strprintf("%.4g Hz: below 2 x f_max", cand[k])
                          : strprintf("%s%.4g Hz: %.3g", k ? ", " : "", cand[k], score[k]);
        if (!best) {
            if (!(score[0] < HUGE_VAL)) throw_error(VIBID_E_INSUFFICIENT_DATA, "no candidate gave error bars");
            keep_why = strprintf("pre-filter after the first %zu samples: stays %.4g Hz (f_a/20), the smallest sum of "
                                 "relative variances of the candidates (%s; highest natural frequency %.4g Hz)\n",
                                 n_pilot, fc_now, scores.c_str(), fmax);
        } else {
            // The chosen estimator's description: its pre-filter line says why.
            const std::string why =
                strprintf("pre-filter: %.4g Hz (automatic, from the data: of the candidates f_a/20, f_a/50, 2 and 4 x "
                          "the highest natural frequency f_max of the estimate over the first %zu samples (%.4g Hz), within "
                          "[f_a/50, f_a/8] and none below 2 f_max, the smallest sum of relative variances (se/value)^2: "
                          "%s; those samples replayed)\n",
                          cand[best_k], n_pilot, fmax, scores.c_str());
            const std::size_t at = best->description.find(kPilotPlaceholder);
            if (at != std::string::npos) best->description.replace(at, std::strlen(kPilotPlaceholder), why);
            best->generation = id.generation + 1;  // a twin forgets the old estimator's memory
            id = std::move(*best);
            return;
        }
    } catch (const std::exception &e) {
        keep_why = strprintf("pre-filter after the first %zu samples: stays %.4g Hz (f_a/20): %s\n", n_pilot, fc_now,
                             e.what());
    }
    id.description += keep_why;
}

}  // namespace

// Real-time path for every estimator: no exceptions, no allocation (but for the one push
// that ends the pre-filter pilot: tune_prefilter; and OE's, which keeps every sample).
VIBID_API vibid_status vibid_ident_push(vibid_ident *ident, const double *channels) {
    if (!ident || !channels) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "ident and channels are required");
    if (ident->twin_of)
        return VIBID_FAIL(VIBID_E_STATE, "a twin takes no samples: push them into the identification it copies");
    return ident->ops->push(*ident, channels);
}

namespace {

// The regression estimators' push: the pre-filter pilot (its samples kept, and at its last
// one the cutoff chosen), then the sample (push_sample).
vibid_status push_regression(vibid_ident &id, const double *channels) {
    if (id.pilot_count >= id.pilot_len) return push_sample(&id, channels);
    std::copy(channels, channels + id.n_channels, id.pilot.data() + id.pilot_count * id.n_channels);
    ++id.pilot_count;
    const vibid_status s = push_sample(&id, channels);
    if (id.pilot_count == id.pilot_len) tune_prefilter(id);
    return s;
}

}  // namespace

namespace {

// rows (m x p_reg, column-major, one row per equation) and the constant-force columns
// (m x nb: -unit in equation e's own column, the sign of a force input, 0 elsewhere) into
// out (m x (p_reg + nb)). Allocation-free.
void constant_rows(const vibid_ident &id, const double *rows, double unit, double *out) {
    const std::size_t m = id.m, pm = id.p_reg * m;
    std::copy(rows, rows + pm, out);
    std::fill(out + pm, out + pm + id.nb * m, 0.0);
    for (std::size_t e = 0; e < m && e < id.nb; ++e) out[pm + e + e * m] = -unit;
}

// One sample into a regression estimator (and its discretization check): the regressor,
// then a ready row into the estimator (push_row).
vibid_status push_sample(vibid_ident *ident, const double *channels) {
    int ready = 0;
    vibid_status s = vibid_regressor_push(ident->reg.get(), channels, ident->x.data(), ident->y.data(), &ready);
    if (s != VIBID_OK) {
        // A gap: both this estimator and its discretization check start afresh.
        if (s == VIBID_E_NONFINITE) {
            restart_window(*ident);
            if (ident->half) {
                restart_window(*ident->half);
                ident->half_take = true;
            }
        }
        return s;
    }
    ++ident->n_samples;
    if (ident->half) {
        // Advisory: a sample the check's estimator refuses (its own regressor overflow,
        // which restarts its window) leaves this estimate alone.
        if (ident->half_take) (void)push_sample(ident->half.get(), channels);
        ident->half_take = !ident->half_take;
    }
    if (!ready) return VIBID_OK;
    s = ident->ops->push_row(*ident);
    if (s != VIBID_OK) return s;
    ++ident->n_built;
    ident->n_rows += ident->m;
    return VIBID_OK;
}

}  // namespace

VIBID_API vibid_status vibid_ident_push_block(vibid_ident *ident, size_t n_samples, const double *channels) {
    if (!ident || (!channels && n_samples)) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "ident and channels are required");
    const std::size_t nc = ident->n_channels;
    // Gathers one sample (a row of the column-major block) at a time into a stack
    // buffer: no allocation, so this is as real-time safe as vibid_ident_push.
    double sample[256];
    if (nc > 256) return VIBID_FAIL(VIBID_E_DIMENSION, "more than 256 channels: push samples one by one");
    for (std::size_t k = 0; k < n_samples; ++k) {
        for (std::size_t c = 0; c < nc; ++c) sample[c] = channels[k + c * n_samples];
        vibid_status s = vibid_ident_push(ident, sample);
        if (s != VIBID_OK) return s;
    }
    return VIBID_OK;
}

namespace {

// The constants of the fit with them (th: p_reg + nb, cov its covariance): the Wald test of
// all of them = 0 (id.const_p), and whether the estimate keeps them (ON: always; AUTO:
// p-value below kConstantTestLevel; no test without a positive definite covariance: the
// plain fit stands). Sets the last estimate's constants when kept.
bool choose_constants(vibid_ident &id, const VectorXd &th, const MatrixXd &cov) {
    const Eigen::Index pr = static_cast<Eigen::Index>(id.p_reg), nb = static_cast<Eigen::Index>(id.nb);
    const VectorXd b = th.segment(pr, nb);
    const MatrixXd C = cov.block(pr, pr, nb, nb);
    id.const_p = std::nan("");
    if (b.allFinite() && C.allFinite()) {
        const Eigen::LDLT<MatrixXd> ldlt(C);
        if (ldlt.info() == Eigen::Success && (ldlt.vectorD().array() > 0.0).all()) {
            const double w = b.dot(ldlt.solve(b));
            if (std::isfinite(w)) id.const_p = chi2_survival(w, id.nb);
        }
    }
    const bool keep = id.cfg.constant_terms == VIBID_CONSTANT_ON || id.const_p < kConstantTestLevel;
    if (keep) {
        id.const_values.assign(b.data(), b.data() + nb);
        id.const_se.resize(id.nb);
        for (Eigen::Index i = 0; i < nb; ++i) id.const_se[static_cast<std::size_t>(i)] = std::sqrt(std::max(C(i, i), 0.0));
    }
    return keep;
}

}  // namespace

VIBID_API vibid_status vibid_ident_estimate(vibid_ident *ident, double *theta, double *stderr_out,
                                            vibid_ident_info *info) {
    VIBID_GUARD(
        if (!ident || !theta) throw_error(VIBID_E_NULL_ARGUMENT, "ident and theta are required");
        return ident->ops->estimate(*ident, theta, stderr_out, info););
}

}  // extern "C"

namespace {

// The regression estimators' estimate: the estimator's fit of the difference form (solve),
// then the physical parameters (directly, or by the ZOH way back), the discretization
// bound and check in their standard errors, the flags.
vibid_status estimate_regression(vibid_ident &id, double *theta, double *stderr_out, vibid_ident_info *info) {
    const std::size_t pr = id.p_reg, q = id.q, P = pr * q;
    RegressionFit fit;
    MatrixXd &Th = fit.Th;
    Th.resize(static_cast<Eigen::Index>(pr), static_cast<Eigen::Index>(q));
    MatrixXd &cov_reg = fit.cov_reg;  // Cov(vec Theta), vec column-major
    cov_reg = MatrixXd::Zero(static_cast<Eigen::Index>(P), static_cast<Eigen::Index>(P));
    vibid_lsq_info &li = fit.li;
    vibid_ident_info out{};
    if (id.n_rows <= pr && !(id.rls && id.has_prior))
        throw_error(VIBID_E_INSUFFICIENT_DATA, "%llu equations for %zu regressors: push more samples", id.n_rows, pr);
    vibid_ident_quality &qual = fit.qual;
    qual.z_consistency = std::nan("");
    // Constant forces (nb > 0, structured form: q = 1): the fit with them, the test,
    // the choice (choose_constants); the last estimate's constants start empty.
    const std::size_t pa = pr + id.nb;
    id.const_values.clear();
    id.const_se.clear();
    id.const_p = std::nan("");
    id.ops->solve(id, fit);
    const std::vector<int> &weak = fit.weak;
    const VectorXd &disc_error = fit.disc_error;  // measured discretization error per parameter (empty: no check)
    const bool with_c = fit.with_c;
    const std::size_t p = id.p;
    MatrixXd cov(p, p);
    std::vector<unsigned> pflags(p, 0u);
    if (!id.zoh) {
        std::copy(Th.data(), Th.data() + p, theta);
        cov = cov_reg;
        // Discretization bias: the stencils' error at the highest natural frequency
        // of this estimate (of the nominal model when the estimate gives none), as a
        // relative bound on every parameter, added to the variances: (w h)^2 / 6 for
        // (1.17), (w h)^4 / 30 for five-point stencils.
        double fmax = 0.0;
        {
            std::vector<double> f(id.n), z(id.n);
            if (vibid_model_modal(&id.model, theta, nullptr, f.data(), nullptr, z.data(), nullptr, nullptr,
                                  nullptr) == VIBID_OK)
                for (double v : f)
                    if (std::isfinite(v)) fmax = std::max(fmax, v);
            if (!(fmax > 0.0)) fmax = id.f_nominal_max;
        }
        const double wh = 2.0 * M_PI * fmax * id.cfg.sample_time;
        double rel = id.cfg.difference_order == 4 ? std::pow(wh, 4) / 30.0 : wh * wh / 6.0;
        // A held base's jumps reach a damper as impulses, whose images above Nyquist
        // the hold equivalents do not describe: on the held-base test stand
        // (ident.default) the noise-free dampers came out 0.6 (w h)^4 off, the springs
        // 0.08 (w h)^4. Bounds: (w h)^4 on damping, (w h)^4 / 10 on the rest. (Held
        // forces stay within the stencils' bound: 4e-6 on the test chain.)
        const bool impulses = id.model.has_base && id.model.base_hold == VIBID_HOLD_ZOH && id.model.base_damper;
        // Measured discretization error (Richardson): the estimate from every second
        // sample minus this one is (2^a - 1) times this one's error where the error
        // scales as h^a. a = 2 for what the a-priori bound misses, the aliasing of
        // non-smooth signals (a corner of a triangle excitation is a jump in the third
        // derivative of the response; the paper's example 1 came out c1 +0.10 /
        // +0.026 / +0.0063 / +0.0015 % at 1 / 2 / 4 / 8 kHz): the error is the
        // difference / 3. A corner on a sample has error E at h and 4 E or -2 E on
        // either grid of step 2h: / 3 gives |E| for both. Corners halfway between
        // samples are missed (both grids see them at a quarter step, error E too);
        // smooth signals (a = 4) get 5 times their error.
        qual.bias_relative = 0.0;
        for (std::size_t i = 0; i < p; ++i) {
            const Eigen::Index ii = static_cast<Eigen::Index>(i);
            double ri = rel;
            if (impulses) {
                const bool damping = id.model.terms[id.model.param_term[i]].kind == VIBID_PARAM_DAMPING;
                ri = std::max(rel, damping ? std::pow(wh, 4) : std::pow(wh, 4) / 10.0);
            }
            double bias = ri * std::fabs(theta[i]);
            if (disc_error.size() == static_cast<Eigen::Index>(p)) bias = std::max(bias, disc_error(ii));
            cov(ii, ii) += bias * bias;
            if (theta[i] != 0.0) qual.bias_relative = std::max(qual.bias_relative, bias / std::fabs(theta[i]));
        }
        for (std::size_t i = 0; i < p && i < weak.size(); ++i)
            if (weak[i]) pflags[i] |= VIBID_QUALITY_NOT_EXCITED;
    } else {
        VectorXd th = zoh_to_theta(id, Th, out.log_info);
        // Standard errors through the numerical Jacobian of the whole way back.
        MatrixXd J(p, P);
        for (std::size_t k = 0; k < P; ++k) {
            const double step = 1e-6 * std::max(std::fabs(Th.data()[k]), 1e-9);
            MatrixXd tp = Th, tm = Th;
            tp.data()[k] += step;
            tm.data()[k] -= step;
            vibid_log_info dummy{};
            J.col(static_cast<Eigen::Index>(k)) = (zoh_to_theta(id, tp, dummy) - zoh_to_theta(id, tm, dummy)) / (2 * step);
        }
        cov = J * cov_reg * J.transpose();
        std::copy(th.data(), th.data() + p, theta);
    }
    for (std::size_t i = 0; i < p; ++i) {
        if (qual.flags & VIBID_QUALITY_SE_INVALID) pflags[i] |= VIBID_QUALITY_SE_INVALID;
        if (pflags[i] & VIBID_QUALITY_NOT_EXCITED) qual.flags |= VIBID_QUALITY_NOT_EXCITED;
    }
    if (stderr_out)
        for (std::size_t i = 0; i < p; ++i)
            stderr_out[i] = (pflags[i] & VIBID_QUALITY_NOT_EXCITED)
                                ? HUGE_VAL
                                : std::sqrt(std::max(cov(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(i)), 0.0));
    std::copy(cov.data(), cov.data() + p * p, id.cov.begin());
    id.have_cov = true;
    if (id.biv) {
        id.last_theta.assign(Th.data(), Th.data() + Th.size());
        if (id.nb) {
            if (with_c)
                id.last_theta.insert(id.last_theta.end(), id.const_values.begin(), id.const_values.end());
            else
                id.last_theta.resize(pa, 0.0);
        }
        id.have_theta = true;
    }
    qual.rcond = li.rcond;
    id.quality = qual;
    id.param_flags = pflags;
    out.n_samples = id.n_samples;
    out.n_rows = id.n_rows;
    out.rank = li.rank;
    out.rcond = li.rcond;
    if (info) *info = out;
    return VIBID_OK;
}

}  // namespace

extern "C" {

VIBID_API vibid_ident *vibid_ident_twin_create(const vibid_ident *ident) {
    return vibid::guard_create<vibid_ident>(__func__, [&] {
        if (!ident) throw_error(VIBID_E_NULL_ARGUMENT, "ident is NULL");
        if (ident->twin_of) throw_error(VIBID_E_STATE, "ident is itself a twin");
        if (!ident->biv && !ident->rls)
            throw_error(VIBID_E_STATE, "no twin for the %s estimator: deferred estimates need IV, AUTO or RLS "
                                       "(estimate this identification itself)",
                        ident->ekf ? "state-space" : ident->ee ? "output-error" : "batch least-squares");
        // The same form: create makes the same estimator objects (block statistics and
        // their discretization check, or an RLS) with the same shapes. No pilot: a twin
        // takes no samples.
        std::unique_ptr<vibid_ident> t = create_ident(&ident->model, &ident->requested, true);
        t->pilot_len = t->pilot_count = 0;
        std::vector<double>().swap(t->pilot);
        t->twin_of = ident;
        t->synced_generation = ident->generation;
        if (t->rls) {
            t->frozen_theta.assign(t->p_reg * t->q, 0.0);
            t->frozen_P.assign(t->p_reg * t->p_reg, 0.0);
            t->frozen_sig.assign(t->q * t->q, 0.0);
        }
        return t.release();
    });
}

// Real-time path: copies into storage sized at create (same-shape Eigen and vector
// assignments do not allocate); no exceptions.
VIBID_API vibid_status vibid_ident_twin_sync(vibid_ident *twin, const vibid_ident *ident) {
    if (!twin || !ident) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "twin and ident are required");
    if (twin->twin_of != ident)
        return VIBID_FAIL(VIBID_E_STATE, "twin was not made by vibid_ident_twin_create for this identification");
    const vibid_ident &s = *ident;
    vibid_ident &t = *twin;
    if (t.p_reg != s.p_reg || t.q != s.q || t.m != s.m || !t.biv != !s.biv || !t.half != !s.half || !t.rls != !s.rls)
        return VIBID_FAIL(VIBID_E_STATE, "the identification changed its form since the twin was made");
    if (s.generation != t.synced_generation) {
        // reset, or replaced by the pilot: its estimate memory starts afresh
        t.have_theta = t.have_cov = false;
        t.synced_generation = s.generation;
    }
    t.cfg = s.cfg;
    t.n_built = s.n_built;
    t.n_samples = s.n_samples;
    t.n_rows = s.n_rows;
    t.has_prior = s.has_prior;
    t.auto_prior = s.auto_prior;
    t.prior_done = s.prior_done;
    t.prior_count = s.prior_count;
    t.prior_len = s.prior_len;
    if (s.biv) *t.biv = *s.biv;
    if (s.half) {
        *t.half->biv = *s.half->biv;
        t.half->n_samples = s.half->n_samples;
        t.half->n_rows = s.half->n_rows;
    }
    if (s.rls) {
        vibid_status st = vibid_rls_theta(s.rls.get(), t.frozen_theta.data());
        if (st == VIBID_OK) st = vibid_rls_covariance(s.rls.get(), t.frozen_P.data());
        if (st != VIBID_OK) return st;
        t.frozen_sig_ok = vibid_rls_residual_covariance(s.rls.get(), t.frozen_sig.data()) == VIBID_OK;
    }
    return VIBID_OK;
}

VIBID_API vibid_status vibid_ident_get_quality(const vibid_ident *ident, vibid_ident_quality *q, unsigned *param_flags) {
    if (!ident) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "ident is NULL");
    if (!ident->have_cov) return VIBID_FAIL(VIBID_E_STATE, "no estimate yet: call vibid_ident_estimate first");
    if (q) *q = ident->quality;
    if (param_flags) std::copy(ident->param_flags.begin(), ident->param_flags.end(), param_flags);
    return VIBID_OK;
}

VIBID_API vibid_status vibid_ident_get_config(const vibid_ident *ident, vibid_ident_config *cfg) {
    if (!ident || !cfg) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "ident and cfg are required");
    *cfg = ident->cfg;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_ident_describe(const vibid_ident *ident, char *buf, size_t cap, size_t *len) {
    if (!ident || (!buf && cap)) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "ident and buf are required");
    if (len) *len = ident->description.size();
    if (cap) {
        const std::size_t nb = std::min(cap - 1, ident->description.size());
        std::copy(ident->description.begin(), ident->description.begin() + static_cast<long>(nb), buf);
        buf[nb] = '\0';
    }
    return VIBID_OK;
}

VIBID_API vibid_status vibid_ident_offsets(const vibid_ident *ident, size_t cap, size_t *n_out, size_t *channels,
                                           double *values, double *se) {
    if (!ident || !n_out) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "ident and n_out are required");
    if (!ident->have_cov) return VIBID_FAIL(VIBID_E_STATE, "no estimate yet: call vibid_ident_estimate first");
    const std::size_t n = ident->offsets.size();
    *n_out = n;
    for (std::size_t j = 0; j < std::min(n, cap); ++j) {
        if (channels) channels[j] = ident->offset_channels[j];
        if (values) values[j] = ident->offsets[j];
        if (se) se[j] = ident->offsets_se[j];
    }
    return VIBID_OK;
}

VIBID_API vibid_status vibid_ident_innovations(const vibid_ident *ident, size_t cap, size_t *n_out, size_t *channels,
                                               double *nu, double *sd, double *inflation) {
    if (!ident || !n_out) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "ident and n_out are required");
    if (!ident->ekf)
        return VIBID_FAIL(VIBID_E_UNSUPPORTED, "innovations: only the state-space estimators (ekf, kf_rls) have them");
    *n_out = ident->ekf->innovations(cap, channels, nu, sd, inflation);
    return VIBID_OK;
}

VIBID_API vibid_status vibid_ident_constant_forces(const vibid_ident *ident, size_t cap, size_t *n_out,
                                                   size_t *nodes, double *values, double *se, double *p_value) {
    if (!ident || !n_out) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "ident and n_out are required");
    if (!ident->have_cov) return VIBID_FAIL(VIBID_E_STATE, "no estimate yet: call vibid_ident_estimate first");
    // OE: the constants of its equation-error start
    const vibid_ident &id = ident->ee ? *ident->ee : *ident;
    const std::size_t n = id.const_values.size();
    *n_out = n;
    for (std::size_t j = 0; j < std::min(n, cap); ++j) {
        if (nodes) nodes[j] = j;
        if (values) values[j] = id.const_values[j];
        if (se) se[j] = id.const_se[j];
    }
    if (p_value) *p_value = id.const_p;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_ident_covariance(const vibid_ident *ident, double *cov) {
    if (!ident || !cov) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "ident and cov are required");
    if (!ident->have_cov) return VIBID_FAIL(VIBID_E_STATE, "no estimate yet: call vibid_ident_estimate first");
    std::copy(ident->cov.begin(), ident->cov.end(), cov);
    return VIBID_OK;
}

}  // extern "C"

namespace {

// OE: the automatic equation-error estimator runs on the samples as they come and gives
// the fit its start values; the fit itself runs at vibid_ident_estimate on every sample
// kept (output_error.h). Refused here when the fit cannot run on the stand (a disturbance,
// an unmeasured base).
std::unique_ptr<vibid_ident> create_output_error(const vibid_model &model, const vibid_ident_config &cfg) {
    vibid_ident_config ec = cfg;
    ec.estimator = VIBID_ESTIMATOR_AUTO;
    auto id = std::make_unique<vibid_ident>();
    id->ee = create_ident(&model, &ec, true);
    vibid_oe_config oc;
    vibid_oe_config_init(&oc, cfg.sample_time);
    id->oe.reset(vibid_oe_create(&model, &oc));
    if (!id->oe) throw_error(VIBID_E_DIMENSION, "output error: %s", vibid_last_error());
    id->model = model;
    id->cfg = id->ee->cfg;
    id->cfg.estimator = VIBID_ESTIMATOR_OE;
    id->requested = cfg;
    id->n = model.nodes.size();
    id->p = model.param_term.size();
    id->n_channels = model.channels.size();
    id->cov.assign(id->p * id->p, 0.0);
    std::size_t ny = 0;
    check_status(vibid_oe_dims(id->oe.get(), &ny, nullptr), "output error");
    id->offset_channels.resize(ny);
    check_status(vibid_oe_dims(id->oe.get(), &ny, id->offset_channels.data()), "output error");
    id->oe_description =
        model.disturbances.empty()
            ? "estimator: output error on the stand's model (configured), started from the equation-error "
              "estimate above (and from the nominal values where the stand gives them); initial state and "
              "an offset per response channel estimated; sandwich error bars\n"
            : "estimator: prediction error of the stand's Kalman predictor (configured; the stand declares an "
              "unmeasured random force), maximum likelihood, started from the estimate above (and from the "
              "nominal values where the stand gives them); unknown disturbance and sensor noise intensities and "
              "an offset per response channel estimated; sandwich error bars\n";
    id->description = id->ee->description + id->oe_description;
    return id;
}

// The fit's dependence on the smooth inputs' path between samples (output_error.h, "Input
// path"): where the estimate moves by more than one standard error when the inputs follow
// the local parabola instead of the straight line, and the data do not show the straight
// line to be the path (fi.input_path_uncovered), the error bars do not cover that unknown:
// the estimate and the parameters moved are flagged VIBID_QUALITY_SE_INVALID. Returns the
// description's line ("" when no input is smooth).
std::string input_path_check(vibid_ident &id, const vibid_oe_fit_info &fi, const std::vector<double> &se) {
    std::vector<double> shift(id.p);
    check_status(vibid_oe_interp_shift(id.oe.get(), shift.data()), "output error");
    bool smooth = false;
    for (double v : shift) smooth = smooth || v != 0.0;
    if (!smooth) return std::string();
    const char *const what = "the smooth inputs' unknown path between samples (parabola through neighbouring samples "
                             "against the straight line)";
    if (!(fi.interp_z > 1.0))
        return strprintf("input path: %s moves the estimate by at most %.2g of its standard errors\n", what, fi.interp_z);
    std::string moved;
    for (std::size_t i = 0; i < id.p; ++i) {
        const double z = std::fabs(shift[i]) / se[i];
        if (!(z <= 1.0)) {
            if (fi.input_path_uncovered) id.param_flags[i] |= VIBID_QUALITY_SE_INVALID;
            vibid_param_info pi{};
            vibid_model_param_info(&id.model, i, &pi);
            moved += strprintf("%s%s %.3g se", moved.empty() ? "" : ", ", pi.name, z);
        }
    }
    if (!fi.input_path_uncovered)
        return strprintf("input path: %s would move %s, but the data show the straight line to be the path (evidence "
                         "%.3g, decisive below -%g): not flagged\n",
                         what, moved.c_str(), fi.interp_evidence, VIBID_OE_PATH_DECISIVE);
    id.quality.flags |= VIBID_QUALITY_SE_INVALID;
    return strprintf("input path: %s moves %s; %s (evidence %+.3g): the error bars do not cover it\n", what, moved.c_str(),
                     fi.interp_evidence > VIBID_OE_PATH_DECISIVE ? "the data prefer the parabola"
                                                                  : "the data do not tell which path is right",
                     fi.interp_evidence);
}

// The prediction-error fit's noise intensities (vibid_oe_noise) as a description line; ""
// for the output-error fit.
std::string noise_line(const vibid_ident &id) {
    const std::size_t nw = id.model.disturbances.size(), ny = id.offset_channels.size();
    if (nw == 0) return std::string();
    std::vector<double> wsd(nw), wse(nw), vsd(ny), vse(ny);
    check_status(vibid_oe_noise(id.oe.get(), wsd.data(), wse.data(), vsd.data(), vse.data()), "prediction error");
    auto item = [](const std::string &name, double v, double e, const char *unit) {
        return e == 0.0 ? strprintf("%s %.4g %s (declared)", name.c_str(), v, unit)
                        : strprintf("%s %.4g +- %.2g %s", name.c_str(), v, e, unit);
    };
    std::string line = "noise: ";
    for (std::size_t l = 0; l < nw; ++l)
        line += (l ? ", " : "") + item("disturbance " + id.model.disturbances[l].name + " std", wsd[l], wse[l], "N");
    static const char *const kUnit[] = {"m", "m/s", "m/s^2"};
    for (std::size_t j = 0; j < ny; ++j) {
        const auto &ch = id.model.channels[id.offset_channels[j]];
        const int q = ch.kind == VIBID_CHANNEL_VELOCITY ? 1 : ch.kind == VIBID_CHANNEL_ACCELERATION ? 2 : 0;
        line += ", " + item(ch.name + " sensor noise std", vsd[j], vse[j], kUnit[q]);
    }
    return line + "\n";
}

// The fit at vibid_ident_estimate: the equation-error estimate first (its failure is this
// estimate's failure: no start), then the output-error fit from it. A fit that fails leaves
// the equation-error estimate, its quality plus VIBID_QUALITY_REFINE_FAILED, and the reason
// in the description.
vibid_status estimate_output_error(vibid_ident &id, double *theta, double *se, vibid_ident_info *info) {
    const std::size_t p = id.p, nc = id.n_channels, ns = id.samples.size() / std::max<std::size_t>(nc, 1);
    std::vector<double> th_ee(p), se_ee(p);
    const vibid_status st = vibid_ident_estimate(id.ee.get(), th_ee.data(), se_ee.data(), info);
    const std::string ee_why = st == VIBID_OK ? std::string() : vibid_last_error();
    std::vector<double> starts;
    if (st == VIBID_OK) starts = th_ee;
    std::vector<double> nominal(p);
    if (vibid_model_nominal(&id.model, nominal.data()) == VIBID_OK &&
        std::all_of(nominal.begin(), nominal.end(), [](double v) { return v != 0.0 && std::isfinite(v); }))
        starts.insert(starts.end(), nominal.begin(), nominal.end());
    // no start estimate and no nominal values: nothing to start from
    if (starts.empty()) return VIBID_FAIL(st, "%s", ee_why.c_str());
    std::string start_note =
        st == VIBID_OK ? std::string()
                       : strprintf("the start estimator failed (%s): the fit starts from the nominal values\n", ee_why.c_str());
    if (!id.ee_trouble.empty())
        start_note = strprintf("the start estimator diverged (%s) and restarted; every sample stays in the fit\n",
                               id.ee_trouble.c_str()) + start_note;
    std::vector<double> block(ns * nc);
    for (std::size_t k = 0; k < ns; ++k)
        for (std::size_t c = 0; c < nc; ++c) block[k + c * ns] = id.samples[k * nc + c];
    const vibid_status fs = vibid_oe_fit(id.oe.get(), ns, block.data(), starts.size() / p, starts.data());
    const std::string why = fs == VIBID_OK ? std::string() : vibid_last_error();
    vibid_oe_fit_info fi{};
    std::vector<double> th(p), sd(p), cov(p * p);
    const std::size_t ny = id.offset_channels.size();
    id.offsets.assign(ny, 0.0);
    id.offsets_se.assign(ny, 0.0);
    if (fs == VIBID_OK)
        check_status(vibid_oe_result(id.oe.get(), th.data(), sd.data(), cov.data(), id.offsets.data(),
                                     id.offsets_se.data(), nullptr, &fi),
                     "output error");
    const char *const fit_name = id.model.disturbances.empty() ? "output-error" : "prediction-error";
    if (fs != VIBID_OK && st != VIBID_OK) {
        id.description = id.ee->description + id.oe_description + start_note;
        return VIBID_FAIL(fs, "the start estimator failed (%s) and so did the %s fit from the nominal values (%s)",
                          ee_why.c_str(), fit_name, why.c_str());
    }
    if (fs != VIBID_OK) {
        id.offsets.clear();
        id.offsets_se.clear();
        std::copy(th_ee.begin(), th_ee.end(), theta);
        if (se) std::copy(se_ee.begin(), se_ee.end(), se);
        check_status(vibid_ident_covariance(id.ee.get(), id.cov.data()), "equation error");
        id.param_flags.assign(p, 0);
        check_status(vibid_ident_get_quality(id.ee.get(), &id.quality, id.param_flags.data()), "equation error");
        id.quality.flags |= VIBID_QUALITY_REFINE_FAILED;
        for (auto &f : id.param_flags) f |= VIBID_QUALITY_REFINE_FAILED;
        id.description = id.ee->description + id.oe_description +
                         strprintf("%s refinement failed (the %s estimate stands): %s\n", fit_name,
                                   id.model.disturbances.empty() ? "equation-error" : "start", why.c_str());
    } else {
        std::copy(th.begin(), th.end(), theta);
        if (se) std::copy(sd.begin(), sd.end(), se);
        id.cov = cov;
        id.quality = vibid_ident_quality{};
        id.quality.z_consistency = std::nan("");
        id.quality.n_blocks = fi.n_blocks;
        id.quality.rcond = fi.rcond;
        id.param_flags.assign(p, 0);
        const bool from_ee = st == VIBID_OK && fi.start == 0;
        id.description = id.ee->description + id.oe_description + start_note +
                         strprintf("%s fit: %u iterations from start %zu (%s), %zu samples, %zu blocks\n", fit_name,
                                   fi.iterations, fi.start, from_ee ? "the start estimate" : "the nominal values",
                                   fi.n_samples, fi.n_blocks);
        id.description += input_path_check(id, fi, sd);
        id.description += noise_line(id);
    }
    id.have_cov = true;
    if (info) {
        info->n_samples = ns;
        info->n_rows = ns;
    }
    return VIBID_OK;
}

}  // namespace

// ---- The estimators. Each kind's functions, then the table of them (kEstimators). ----

namespace {

// Start values are for the recursive estimators: refused by the batch ones (LS, IV, AUTO).
void refuse_prior(vibid_ident &, const double *, const double *) {
    throw_error(VIBID_E_STATE, "start values are for the RLS and EKF estimators only (LS and IV are batch "
                               "estimators)");
}

// -- LS: batch least squares on the difference form (lsq.h), plus a second QR with the
// constant-force columns (lsq_c).

void describe_ls(const vibid_ident_config &, std::string &why) {
    why += "estimator: batch least squares (configured); biased by noise on the measured channels, standard "
           "errors assume white equation errors (flagged as not valid)\n";
}

void make_solver_ls(vibid_ident &id) {
    const std::size_t pa = id.p_reg + id.nb;
    id.lsq.reset(vibid_lsq_create(id.p_reg, id.q));
    if (!id.lsq) throw_error(VIBID_E_NO_MEMORY, "vibid_lsq_create: %s", vibid_last_error());
    if (id.nb) {
        id.lsq_c.reset(vibid_lsq_create(pa, id.q));
        if (!id.lsq_c) throw_error(VIBID_E_NO_MEMORY, "vibid_lsq_create: %s", vibid_last_error());
    }
}

vibid_status push_row_ls(vibid_ident &id) {
    const std::size_t p = id.p_reg, m = id.m;
    vibid_status s;
    transpose_into(id.x.data(), p, m, id.rows_x.data());
    s = vibid_lsq_add_rows(id.lsq.get(), m, id.rows_x.data(), id.y.data(), nullptr);
    if (s == VIBID_OK && id.nb) {
        constant_rows(id, id.rows_x.data(), vibid::regressor_unit(*id.reg), id.rows_xc.data());
        s = vibid_lsq_add_rows(id.lsq_c.get(), m, id.rows_xc.data(), id.y.data(), nullptr);
    }
    return s;
}

void solve_ls(vibid_ident &id, RegressionFit &fit) {
    const std::size_t pr = id.p_reg, q = id.q, pa = pr + id.nb;
    MatrixXd &Th = fit.Th, &cov_reg = fit.cov_reg;
    vibid_lsq_info &li = fit.li;
    bool &with_c = fit.with_c;
    vibid_status s = vibid_lsq_solve(id.lsq.get(), Th.data(), &li);
    if (s == VIBID_E_NOT_IDENTIFIABLE) refuse_null_space(id, li);
    check_status(s, "least squares");
    MatrixXd Pm(pr, pr), Sig(q, q);
    check_status(vibid_lsq_covariance(id.lsq.get(), Pm.data(), Sig.data()), "least-squares covariance");
    for (std::size_t j = 0; j < q; ++j)
        for (std::size_t l = 0; l < q; ++l)
            cov_reg.block(j * pr, l * pr, pr, pr) = Sig(j, l) * Pm;
    if (id.nb) {
        VectorXd tha(pa);
        MatrixXd Pa(pa, pa), Sa(1, 1);
        vibid_lsq_info lc{};
        vibid_status sc = vibid_lsq_solve(id.lsq_c.get(), tha.data(), &lc);
        if (sc == VIBID_OK) sc = vibid_lsq_covariance(id.lsq_c.get(), Pa.data(), Sa.data());
        if (sc != VIBID_OK && id.cfg.constant_terms == VIBID_CONSTANT_ON)
            check_status(sc, "least squares with constant forces");
        if (sc == VIBID_OK && choose_constants(id, tha, Sa(0, 0) * Pa)) {
            with_c = true;
            Th = tha.head(static_cast<Eigen::Index>(pr));
            cov_reg = Sa(0, 0) * Pa.topLeftCorner(static_cast<Eigen::Index>(pr), static_cast<Eigen::Index>(pr));
            li = lc;
        }
    }
    fit.qual.flags |= VIBID_QUALITY_SE_INVALID;
}

// -- IV and AUTO: instrumental variables with block statistics (block_iv.hpp), the
// instruments the regressors iv_lag samples earlier (ring).

void describe_auto(const vibid_ident_config &, std::string &why) {
    why += "estimator: instrumental variables with block statistics (automatic): consistent where noise on "
           "the measured channels biases LS and RLS, exact on noise-free data; error bars from the spread "
           "over 32..64 blocks, valid for coloured equation errors\n";
}

void describe_iv(const vibid_ident_config &, std::string &why) {
    why += "estimator: instrumental variables with block statistics (configured)\n";
}

void make_solver_iv(vibid_ident &id) {
    const vibid_ident_config &rcfg = id.cfg;
    const std::size_t pa = id.p_reg + id.nb;
    // Blocks much longer than the equation error's correlation (window + filter
    // memory, i.e. about the lag): 4 (lag + window), at least 64 samples. With
    // forgetting, 64 blocks span about 6 memories.
    const std::size_t width = rcfg.difference_order + 1;
    std::size_t block = std::max<std::size_t>(4 * (rcfg.iv_lag + width), 64);
    if (rcfg.forgetting < 1.0)
        block = std::max<std::size_t>(
            static_cast<std::size_t>(std::ceil(6.0 / (1.0 - rcfg.forgetting) / 64.0)), 2 * (rcfg.iv_lag + width));
    id.biv = std::make_unique<vibid::BlockIV>(pa, id.q, rcfg.forgetting, block, 64);
    id.ring.assign((rcfg.iv_lag + 1) * id.p_reg * id.m, 0.0);
    id.ring_unit.assign(rcfg.iv_lag + 1, 0.0);
}

vibid_status push_row_iv(vibid_ident &id) {
    const std::size_t p = id.p_reg, m = id.m;
    // A cubic term of a wild sample can overflow: such a row would poison every sum.
    if (!vibid::all_finite(id.x.data(), p * m) || !vibid::all_finite(id.y.data(), m * id.q)) {
        restart_window(id);
        return VIBID_FAIL(VIBID_E_NONFINITE, "regressor overflow (non-finite row): window restarted");
    }
    const std::size_t L = id.cfg.iv_lag, slots = L + 1, block = p * m;
    double *slot = id.ring.data() + (id.n_built % slots) * block;
    std::copy(id.x.begin(), id.x.end(), slot);
    const double unit = vibid::regressor_unit(*id.reg);
    id.ring_unit[id.n_built % slots] = unit;
    if (id.n_built >= L) {
        const std::size_t old_slot = (id.n_built - L) % slots;
        const double *old = id.ring.data() + old_slot * block;
        transpose_into(id.x.data(), p, m, id.rows_x.data());
        transpose_into(old, p, m, id.rows_w.data());
        if (id.nb) {
            // The constant's instrument is the constant column of the delayed row.
            id.biv->add_constants(m, id.rows_x.data(), id.rows_w.data(), id.y.data(), unit, id.ring_unit[old_slot]);
        } else {
            id.biv->add(m, id.rows_x.data(), id.rows_w.data(), id.y.data());
        }
        id.biv->end_sample();
    }
    return VIBID_OK;
}

void solve_iv(vibid_ident &id, RegressionFit &fit) {
    const std::size_t pr = id.p_reg, pa = pr + id.nb;
    MatrixXd &Th = fit.Th, &cov_reg = fit.cov_reg;
    vibid_lsq_info &li = fit.li;
    vibid_ident_quality &qual = fit.qual;
    std::vector<int> &weak = fit.weak;
    VectorXd &disc_error = fit.disc_error;
    bool &with_c = fit.with_c;
    if (id.biv->samples() * id.m <= pr)
        throw_error(VIBID_E_INSUFFICIENT_DATA, "%llu instrumented samples for %zu regressors: push more samples",
                    id.biv->samples(), pr);
    // In directions the data of this window hardly inform, the last estimate stays
    // (last_theta: p_reg, then the nb constants, 0 where the plain fit stood).
    const double *ref = id.have_theta ? id.last_theta.data() : nullptr;
    vibid::BlockIVResult res;
    if (id.nb) {
        // AUTO: the test needs the fit with the constants, not its consistency
        // check (two more solves), which only the fit kept needs.
        const bool on = id.cfg.constant_terms == VIBID_CONSTANT_ON;
        try {
            res = id.biv->solve(ref, pa, on);
            with_c = choose_constants(id, res.theta.col(0), res.cov);
            if (with_c && !on) res = id.biv->solve(ref, pa);
        } catch (const vibid::Error &) {
            if (on) throw;
        }
    }
    if (with_c) {
        const Eigen::Index np = static_cast<Eigen::Index>(pr);
        res.theta = MatrixXd(res.theta.topRows(np));
        res.cov = MatrixXd(res.cov.topLeftCorner(np, np));
        res.not_excited.resize(pr);
    } else {
        res = id.biv->solve(ref, pr);
    }
    Th = res.theta;
    cov_reg = res.cov;
    li.rank = res.rank;
    li.rcond = res.rcond;
    qual.n_blocks = res.n_blocks;
    qual.z_consistency = res.z_max;
    weak = res.not_excited;
    if (id.half && id.half->biv->samples() * id.m > pr) {
        try {
            const vibid::BlockIVResult rh = id.half->biv->solve(ref, with_c ? pa : pr);
            // Richardson, see below. The difference also carries the two
            // estimates' noise: var(half) - var(this) where this one uses all
            // samples (Hausman), which is taken out of its square.
            disc_error = VectorXd::Zero(static_cast<Eigen::Index>(pr));
            for (Eigen::Index i = 0; i < static_cast<Eigen::Index>(pr); ++i) {
                const double d = rh.theta(i, 0) - Th(i, 0);
                const double vd = std::max(rh.cov(i, i) - cov_reg(i, i), 0.0);
                disc_error(i) = std::sqrt(std::max(d * d - vd, 0.0)) / 3.0;
            }
            if (!disc_error.allFinite()) disc_error.resize(0);
        } catch (const vibid::Error &) {
            disc_error.resize(0);  // no check this time; the a-priori bound stays
        }
    }
    // Too few blocks for a covariance (early in a run), too few that carry the
    // information (n_eff below p_reg + 4: the spread of the scores would rest on fewer
    // than 4 blocks beyond the directions fitted, e.g. excitation only in the newest
    // blocks), or the halves disagree.
    if (!cov_reg.allFinite() || !(res.z_max <= 4.0) ||
        res.n_eff < static_cast<double>(with_c ? pa : pr) + 4.0)
        qual.flags |= VIBID_QUALITY_SE_INVALID;
}

// -- RLS: recursive least squares on the difference form (rls.h), from start values
// (vibid_ident_set_prior) or a prior scaled to the first samples (collect_prior_rows).

void describe_rls(const vibid_ident_config &cfg, std::string &why) {
    why += "estimator: recursive least squares (configured); biased by noise on the measured channels, "
           "standard errors assume white equation errors (flagged as not valid)\n";
    if (cfg.rls_alpha == 0.0)
        why += "RLS prior: scaled to the data (automatic): P0 = diag(1 / (1e-6 sum x_i^2)) over the first "
               "samples, so that no parameter's units make it strong\n";
    else
        why += strprintf("RLS prior: P0 = I / %g (configured)\n", cfg.rls_alpha);
}

void make_solver_rls(vibid_ident &id) {
    const vibid_ident_config &rcfg = id.cfg;
    vibid_rls_config rc;
    vibid_rls_config_init(&rc, id.p_reg, id.q);
    rc.n_equations = id.m;
    rc.forgetting = rcfg.forgetting;
    // Automatic prior (rls_alpha = 0): the RLS starts from a prior scaled to the
    // data (push); until then, and for start values given without P0, 1e-9.
    const double alpha = rcfg.rls_alpha > 0.0 ? rcfg.rls_alpha : 1e-9;
    rc.alpha = alpha;
    rc.trace_max = static_cast<double>(id.p_reg) / alpha;
    if (rcfg.rls_alpha == 0.0) {
        id.auto_prior = true;
        id.prior_len = std::max<std::size_t>(8 * id.p_reg, 100);
        id.prior_rows.assign(id.prior_len * (id.p_reg * id.m + id.m * id.q), 0.0);
        id.prior_ss.assign(id.p_reg, 0.0);
        id.prior_P0.assign(id.p_reg * id.p_reg, 0.0);
        id.prior_theta.assign(id.p_reg * id.q, 0.0);
        if (!id.zoh && vibid_model_nominal(&id.model, id.prior_theta.data()) != VIBID_OK)
            std::fill(id.prior_theta.begin(), id.prior_theta.end(), 0.0);
    }
    id.rls.reset(vibid_rls_create(&rc));
    if (!id.rls) throw_error(VIBID_E_OUT_OF_RANGE, "vibid_rls_create: %s", vibid_last_error());
}

vibid_status push_row_rls(vibid_ident &id) {
    if (id.auto_prior && !id.prior_done) return collect_prior_rows(id);
    return vibid_rls_update(id.rls.get(), id.x.data(), id.y.data());
}

void solve_rls(vibid_ident &id, RegressionFit &fit) {
    if (id.auto_prior && !id.prior_done)
        throw_error(VIBID_E_INSUFFICIENT_DATA,
                    "%zu of the first %zu samples collected to scale the RLS prior: push more samples",
                    id.prior_count, id.prior_len);
    const std::size_t pr = id.p_reg, q = id.q;
    MatrixXd &Th = fit.Th, &cov_reg = fit.cov_reg;
    vibid_lsq_info &li = fit.li;
    MatrixXd Pm(pr, pr), Sig(q, q);
    bool sig_ok;
    if (id.twin_of) {  // the RLS outputs as copied (vibid_ident_twin_sync)
        Th = Eigen::Map<const MatrixXd>(id.frozen_theta.data(), pr, q);
        Pm = Eigen::Map<const MatrixXd>(id.frozen_P.data(), pr, pr);
        Sig = Eigen::Map<const MatrixXd>(id.frozen_sig.data(), q, q);
        sig_ok = id.frozen_sig_ok;
    } else {
        check_status(vibid_rls_theta(id.rls.get(), Th.data()), "recursive least squares");
        check_status(vibid_rls_covariance(id.rls.get(), Pm.data()), "rls covariance");
        sig_ok = vibid_rls_residual_covariance(id.rls.get(), Sig.data()) == VIBID_OK;
    }
    if (sig_ok)
        for (std::size_t j = 0; j < q; ++j)
            for (std::size_t l = 0; l < q; ++l)
                cov_reg.block(j * pr, l * pr, pr, pr) = Sig(j, l) * Pm;
    li.rank = pr;
    li.rcond = 0.0;
    fit.qual.flags |= VIBID_QUALITY_SE_INVALID;
}

void set_prior_rls(vibid_ident &id, const double *theta0, const double *P0) {
    const std::size_t p = id.p;
    if (!id.zoh) {
        // Central differences: the regression parameters are the physical ones.
        if (theta0) {
            std::size_t bad = 0;
            while (bad < p && std::isfinite(theta0[bad])) ++bad;
            if (bad < p) throw_error(VIBID_E_NONFINITE, "theta0[%zu] = %g is not finite", bad, theta0[bad]);
            check_status(vibid_rls_set_prior(id.rls.get(), theta0, P0), "prior");
        } else {
            // Nominal values; p is small for a stand, the stack buffer avoids allocating.
            double nominal[256];
            if (p > 256) throw_error(VIBID_E_DIMENSION, "more than 256 unknowns: pass theta0");
            check_status(vibid_model_nominal(&id.model, nominal), "nominal values");
            check_status(vibid_rls_set_prior(id.rls.get(), nominal, P0), "prior");
        }
        id.has_prior = true;
        id.prior_done = true;  // start values replace the automatic prior
        return;
    }
    if (P0)
        throw_error(VIBID_E_OUT_OF_RANGE,
                    "ZOH: P0 refers to the difference form (1.16), not to the physical parameters: pass NULL");
    std::vector<double> th(p);
    if (theta0)
        std::copy(theta0, theta0 + p, th.begin());
    else
        check_status(vibid_model_nominal(&id.model, th.data()), "nominal values");
    for (std::size_t i = 0; i < p; ++i)
        if (!std::isfinite(th[i])) throw_error(VIBID_E_NONFINITE, "theta0[%zu] = %g is not finite", i, th[i]);
    // Physical parameters -> (1.16): Theta^T = [A1 A2 B1 B0] = [-Dt -Ct B1t B2t]
    // with the base as the last input column (as the regressor builds it).
    const Eigen::Index n = static_cast<Eigen::Index>(id.n), r = static_cast<Eigen::Index>(id.model.inputs.size());
    const Eigen::Index rz = static_cast<Eigen::Index>((id.p_reg - 2 * id.n) / 2);
    MatrixXd M(n, n), D(n, n), C(n, n), B(n, std::max<Eigen::Index>(r, 1)), Bz(n, rz);
    VectorXd cb(n);
    check_status(vibid_model_assemble(&id.model, th.data(), M.data(), D.data(), C.data(), r ? B.data() : nullptr,
                                      nullptr, cb.data()),
                 "assemble");
    if (r) Bz.leftCols(r) = B.leftCols(r);
    if (rz > r) Bz.col(r) = cb;
    MatrixXd Dt(n, n), Ct(n, n), B1(n, rz), B2(n, rz);
    check_status(vibid_second_order_form(id.n, static_cast<std::size_t>(rz), M.data(), D.data(), C.data(),
                                         rz ? Bz.data() : nullptr, id.cfg.sample_time, Dt.data(), Ct.data(),
                                         rz ? B1.data() : nullptr, rz ? B2.data() : nullptr),
                 "ZOH difference form of theta0");
    MatrixXd ThT(n, 2 * n + 2 * rz);
    ThT << -Dt, -Ct, B1, B2;
    const MatrixXd Th = ThT.transpose();
    check_status(vibid_rls_set_prior(id.rls.get(), Th.data(), nullptr), "prior");
    id.has_prior = true;
    id.prior_done = true;
}

// -- EKF and KF_RLS: the state-space estimators (stand_ekf.hpp; create_state_space,
// estimate_state_space above); AUTO chooses the EKF on a stand the regression cannot run on.

std::unique_ptr<vibid_ident> create_ekf(const vibid_model &model, const vibid_ident_config &cfg,
                                        const CreateOptions &) {
    return create_state_space(model, cfg, std::string());
}

vibid_status push_state_space(vibid_ident &id, const double *channels) {
    const vibid_status st = id.ekf->push(channels);
    if (st == VIBID_OK || st == VIBID_E_DIVERGED) ++id.n_samples;
    id.n_rows = id.ekf->stats().n_steps;
    return st;
}

void set_prior_state_space(vibid_ident &id, const double *theta0, const double *P0) {
    // The filter's start values (used at its next start: now, or after a reset).
    if (P0)
        throw_error(VIBID_E_OUT_OF_RANGE, "EKF: the start covariance is relative (50 %% of each start value): "
                                          "pass P0 = NULL");
    std::vector<double> th(id.p);
    if (theta0) {
        for (std::size_t i = 0; i < id.p; ++i)
            if (!std::isfinite(theta0[i]) || theta0[i] == 0.0)
                throw_error(VIBID_E_OUT_OF_RANGE, "theta0[%zu] = %g: EKF start values must be finite and != 0",
                            i, theta0[i]);
        th.assign(theta0, theta0 + id.p);
    } else {
        check_status(vibid_model_nominal(&id.model, th.data()), "nominal values");
    }
    id.ekf->set_start(th.data());
}

// -- AUTO: instrumental variables (as IV) where the regression can run, else the EKF.

// A stand that leaves coordinates unmeasured (some signal of the equations can not be
// formed from the channels) or declares an unmeasured random force gets the state-space
// estimator; the regression estimators cannot run on it.
std::unique_ptr<vibid_ident> create_auto(const vibid_model &model, const vibid_ident_config &cfg,
                                         const CreateOptions &opt) {
    if (!model.disturbances.empty())
        return create_state_space(model, cfg, "the stand declares an unmeasured random force");
    try {
        vibid::check_signals_available(model);
    } catch (const vibid::Error &e) {
        return create_state_space(model, cfg, std::string("the stand is not fully measured (") + e.what() + ")");
    }
    return create_regression(model, cfg, opt);
}

// -- OE: output error (create_output_error, estimate_output_error above).

std::unique_ptr<vibid_ident> create_oe(const vibid_model &model, const vibid_ident_config &cfg,
                                       const CreateOptions &) {
    return create_output_error(model, cfg);
}

// Keeps every sample as received (a gap included: the fit leaves it out) and gives it to
// the start estimator. Allocates (the kept samples grow).
vibid_status push_output_error(vibid_ident &id, const double *channels) {
    id.samples.insert(id.samples.end(), channels, channels + id.n_channels);
    ++id.n_samples;
    const vibid_status st = vibid_ident_push(id.ee.get(), channels);
    // A start estimator that diverged (the EKF restarts itself) costs the fit only its start:
    // every sample is kept, the fit falls back to the nominal values if it must, and the
    // description says so.
    if (st == VIBID_E_DIVERGED) {
        if (id.ee_trouble.empty()) id.ee_trouble = strprintf("sample %zu: %s", static_cast<std::size_t>(id.n_samples - 1), vibid_last_error());
        return VIBID_OK;
    }
    return st;
}

void refuse_prior_oe(vibid_ident &, const double *, const double *) {
    throw_error(VIBID_E_STATE, "output error starts from its equation-error estimate: no prior");
}

// The table, indexed by vibid_estimator.
constexpr EstimatorOps kEstimators[] = {
    {VIBID_ESTIMATOR_LS, "ls", ConstantForces::structured, false, create_regression, push_regression,
     estimate_regression, refuse_prior, describe_ls, make_solver_ls, push_row_ls, solve_ls},
    {VIBID_ESTIMATOR_IV, "iv", ConstantForces::structured, true, create_regression, push_regression,
     estimate_regression, refuse_prior, describe_iv, make_solver_iv, push_row_iv, solve_iv},
    {VIBID_ESTIMATOR_RLS, "rls", ConstantForces::none, false, create_regression, push_regression,
     estimate_regression, set_prior_rls, describe_rls, make_solver_rls, push_row_rls, solve_rls},
    {VIBID_ESTIMATOR_AUTO, "auto", ConstantForces::structured, true, create_auto, push_regression,
     estimate_regression, refuse_prior, describe_auto, make_solver_iv, push_row_iv, solve_iv},
    {VIBID_ESTIMATOR_EKF, "ekf", ConstantForces::none, false, create_ekf, push_state_space, estimate_state_space,
     set_prior_state_space, nullptr, nullptr, nullptr, nullptr},
    {VIBID_ESTIMATOR_KF_RLS, "kf_rls", ConstantForces::none, false, create_ekf, push_state_space,
     estimate_state_space, set_prior_state_space, nullptr, nullptr, nullptr, nullptr},
    {VIBID_ESTIMATOR_OE, "oe", ConstantForces::start, false, create_oe, push_output_error, estimate_output_error,
     refuse_prior_oe, nullptr, nullptr, nullptr, nullptr},
};

constexpr bool table_in_order() {
    for (int k = 0; k < kEstimatorCount; ++k)
        if (kEstimators[k].kind != k) return false;
    return true;
}
static_assert(sizeof kEstimators / sizeof kEstimators[0] == kEstimatorCount, "an entry for every vibid_estimator");
static_assert(table_in_order(), "kEstimators is indexed by vibid_estimator");

const EstimatorOps &ops_of(int k) { return kEstimators[k]; }

}  // namespace
