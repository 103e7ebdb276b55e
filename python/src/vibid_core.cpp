// vibid._core: the thin nanobind layer over libvibid's C API (identify.h, modal.h,
// plausibility.h) and the stand loader (stand_file.h). All numerics stay in the C library;
// this file converts arrays and statuses and nothing else. The Pythonic API (channel names,
// DataFrames, tracks) is in vibid/*.py.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>
#include <nanobind/stl/tuple.h>

extern "C" {
#include <vibid/identify.h>
#include <vibid/modal.h>
#include <vibid/plausibility.h>
#include <vibid/regressor.h>
#include <vibid/stand_file.h>
#include <vibid/units.h>
}

#include <algorithm>
#include <cmath>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace nb = nanobind;
using namespace nb::literals;

namespace {

// Becomes vibid.VibidError (a RuntimeError) through nb::exception below.
struct VibidError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// "<what>: <category>: <detail>": the category from vibid_strerror, the detail (function
// and argument) from vibid_last_error, read on the thread that failed (it is thread-local).
[[noreturn]] void raise_status(const char *what, vibid_status s) {
    std::string msg = std::string(what) + ": " + vibid_strerror(s);
    const char *detail = vibid_last_error();
    if (detail && *detail) msg += std::string(": ") + detail;
    throw VibidError(msg);
}

using Array1 = nb::ndarray<nb::numpy, double, nb::ndim<1>>;
using Array2 = nb::ndarray<nb::numpy, double, nb::ndim<2>, nb::f_contig>;

// A numpy array that owns a std::vector's storage (moved, not copied).
Array1 to_numpy(std::vector<double> &&v) {
    auto *heap = new std::vector<double>(std::move(v));
    nb::capsule owner(heap, [](void *p) noexcept { delete static_cast<std::vector<double> *>(p); });
    return Array1(heap->data(), {heap->size()}, owner);
}

Array2 to_numpy(std::vector<double> &&v, size_t rows, size_t cols) {
    auto *heap = new std::vector<double>(std::move(v));
    nb::capsule owner(heap, [](void *p) noexcept { delete static_cast<std::vector<double> *>(p); });
    return Array2(heap->data(), {rows, cols}, owner);
}

const char *param_kind_name(vibid_param_kind k) {
    switch (k) {
    case VIBID_PARAM_MASS: return "mass";
    case VIBID_PARAM_DAMPING: return "damping";
    case VIBID_PARAM_STIFFNESS: return "stiffness";
    case VIBID_PARAM_CUBIC: return "cubic";
    case VIBID_PARAM_GAIN: return "gain";
    }
    return "unknown";
}

class Stand {
public:
    explicit Stand(const std::string &path) {
        vibid_stand_error err;
        vibid_stand *s = vibid_stand_load(path.c_str(), &err);
        // The loader's text is "file:line: field: message", which is what the user needs.
        if (!s) throw VibidError(err.text[0] ? err.text : "vibid_stand_load failed");
        stand_.reset(s);
        vibid_model_get_dims(model(), &dims_);
    }

    const vibid_model *model() const { return vibid_stand_model(stand_.get()); }
    const vibid_stand *raw() const { return stand_.get(); }
    const vibid_model_dims &dims() const { return dims_; }
    std::string name() const { return vibid_stand_name(stand_.get()); }
    double sample_rate() const { return vibid_stand_sample_rate(stand_.get()); }

    std::vector<std::string> channels() const {
        std::vector<std::string> out;
        for (size_t i = 0; i < dims_.n_channels; ++i) out.emplace_back(vibid_stand_channel_name(stand_.get(), i));
        return out;
    }

    // (name, kind, nominal, true value or NaN when the file gives none) per unknown.
    std::vector<std::tuple<std::string, std::string, double, double>> params() const {
        std::vector<std::tuple<std::string, std::string, double, double>> out;
        const double *tv = vibid_stand_true_values(stand_.get());
        for (size_t i = 0; i < dims_.n_params; ++i) {
            vibid_param_info pi;
            vibid_status s = vibid_model_param_info(model(), i, &pi);
            if (s != VIBID_OK) raise_status("vibid_model_param_info", s);
            double truth = vibid_stand_true_value_given(stand_.get(), i) ? tv[i] : NAN;
            out.emplace_back(pi.name, param_kind_name(pi.kind), pi.nominal, truth);
        }
        return out;
    }

private:
    struct Deleter {
        void operator()(vibid_stand *s) const { vibid_stand_destroy(s); }
    };
    std::unique_ptr<vibid_stand, Deleter> stand_;
    vibid_model_dims dims_{};
};

// One estimate with everything a row of the daemon's tracks has.
struct Estimate {
    int status = 0;           // vibid_status of vibid_ident_estimate
    std::string message;      // its vibid_last_error() when status != 0
    std::vector<double> theta, se, cov, freq, freq_se, zeta, zeta_se;
    unsigned quality = 0;     // VIBID_QUALITY_* of the whole estimate
    std::vector<unsigned> param_quality, param_implausible, mode_implausible;
    unsigned implausible = 0; // VIBID_IMPLAUSIBLE_* summary
    std::string why;          // plausibility findings in words
    double z_consistency = NAN;
    size_t n_blocks = 0;
    unsigned long long n_samples = 0;
};

class Ident {
public:
    Ident(const Stand &stand, int estimator, double forgetting, double prefilter_hz, size_t iv_lag)
        : model_(stand.model()), dims_(stand.dims()), h_(1.0 / stand.sample_rate()) {
        vibid_ident_config cfg;
        vibid_ident_config_init(&cfg, h_);
        cfg.estimator = static_cast<vibid_estimator>(estimator);
        cfg.forgetting = forgetting;
        cfg.prefilter_hz = prefilter_hz;
        cfg.iv_lag = iv_lag;
        vibid_ident *id = vibid_ident_create(model_, &cfg);
        // A constructor returns NULL without a status: its message alone is the detail
        // (it names the function and, for a refusal, the parameters).
        if (!id) throw VibidError(vibid_last_error());
        ident_.reset(id);
        vibid_ident_config used;
        vibid_ident_get_config(id, &used);
        state_space_ = used.estimator == VIBID_ESTIMATOR_EKF || used.estimator == VIBID_ESTIMATOR_KF_RLS;
        // The reference for the damping-ratio rule, once (it allocates), as vibidd does.
        if (vibid_plausibility_ref_init(model_, nullptr, &pref_) != VIBID_OK) pref_.n_modes = 0;
    }

    // Rows [start, stop) of a (n_samples x n_channels) float64 array of any strides.
    // Returns the number of samples the state-space estimators reported as diverged (they
    // restart and go on, as in vibidd). The GIL is released: the array is kept alive by
    // the caller's reference for the duration of the call.
    size_t push(nb::ndarray<const double, nb::ndim<2>, nb::device::cpu> data, size_t start, size_t stop) {
        const size_t n = data.shape(0), nc = data.shape(1);
        if (nc != dims_.n_channels)
            throw std::invalid_argument("push: " + std::to_string(nc) + " columns for " +
                                        std::to_string(dims_.n_channels) + " channels");
        if (start > stop || stop > n) throw std::invalid_argument("push: bad row range");
        const double *base = data.data();
        const int64_t rs = data.stride(0), cs = data.stride(1);  // in elements
        vibid_status s = VIBID_OK;
        size_t diverged = 0, bad_row = 0;
        bool whole_block = false;
        {
            nb::gil_scoped_release release;
            whole_block = !state_space_ && start == 0 && stop == n && rs == 1 && cs == static_cast<int64_t>(n);
            if (whole_block) {
                // The whole column-major block: straight to the C API, no copy.
                s = vibid_ident_push_block(ident_.get(), n, base);
            } else {
                // Any other layout or a range of rows (tracks): gather one sample at a time
                // from the caller's strides, still without copying the array. Also the
                // state-space path: a diverged sample is reported and the filter restarts by
                // itself, so the rest of the data must still be pushed (push_block stops).
                std::vector<double> sample(nc);
                for (size_t k = start; k < stop; ++k) {
                    for (size_t c = 0; c < nc; ++c) sample[c] = base[k * rs + c * cs];
                    vibid_status sk = vibid_ident_push(ident_.get(), sample.data());
                    if (sk == VIBID_E_DIVERGED && state_space_) {
                        ++diverged;
                        continue;
                    }
                    if (sk != VIBID_OK) {
                        s = sk;
                        bad_row = k;
                        break;
                    }
                }
            }
        }
        if (s != VIBID_OK) {
            // push_block does not say which sample failed; the row loop does.
            std::string what = whole_block ? std::string("vibid_ident_push_block")
                                           : "vibid_ident_push (row " + std::to_string(bad_row) + ")";
            raise_status(what.c_str(), s);
        }
        return diverged;
    }

    // The estimate, its covariance, modes with standard errors (vibid_model_modal's
    // first-order propagation) and flags. A failed vibid_ident_estimate is not raised
    // here (a track row early in a run may have too few samples): status and message say it.
    Estimate estimate() {
        Estimate e;
        const size_t p = dims_.n_params, n = dims_.n_dof;
        e.theta.assign(p, NAN);
        e.se.assign(p, NAN);
        e.cov.assign(p * p, NAN);
        e.freq.assign(n, NAN);
        e.freq_se.assign(n, NAN);
        e.zeta.assign(n, NAN);
        e.zeta_se.assign(n, NAN);
        e.param_quality.assign(p, 0);
        e.param_implausible.assign(p, 0);
        e.mode_implausible.assign(n, 0);
        vibid_ident_info info{};
        vibid_status s;
        {
            nb::gil_scoped_release release;
            s = vibid_ident_estimate(ident_.get(), e.theta.data(), e.se.data(), &info);
        }
        e.status = s;
        e.n_samples = info.n_samples;
        if (s != VIBID_OK) {
            e.message = vibid_last_error();
            std::fill(e.theta.begin(), e.theta.end(), NAN);
            std::fill(e.se.begin(), e.se.end(), NAN);
            return e;
        }
        const bool have_cov = vibid_ident_covariance(ident_.get(), e.cov.data()) == VIBID_OK;
        // An unstable estimate (VIBID_E_UNSTABLE) keeps its modes: a negative zeta or f = 0
        // is what the plausibility check below flags, and what the analyst needs to see.
        const vibid_status ms = vibid_model_modal(model_, e.theta.data(), have_cov ? e.cov.data() : nullptr,
                                                  e.freq.data(), e.freq_se.data(), e.zeta.data(),
                                                  e.zeta_se.data(), nullptr, nullptr);
        const std::string unstable_why = ms == VIBID_E_UNSTABLE ? vibid_last_error() : "";
        if (ms != VIBID_OK && ms != VIBID_E_UNSTABLE) {
            std::fill(e.freq.begin(), e.freq.end(), NAN);
            std::fill(e.zeta.begin(), e.zeta.end(), NAN);
        }
        if (!have_cov) {
            std::fill(e.freq_se.begin(), e.freq_se.end(), NAN);
            std::fill(e.zeta_se.begin(), e.zeta_se.end(), NAN);
        }
        char why[1024];
        why[0] = '\0';
        vibid_status ps = vibid_plausibility_check(model_, h_, e.theta.data(), e.freq.data(), e.zeta.data(), n,
                                                   pref_.n_modes ? &pref_ : nullptr, &e.implausible,
                                                   e.param_implausible.data(), e.mode_implausible.data(), why,
                                                   sizeof why);
        if (ps != VIBID_OK) {
            // An argument error (a bug): the estimate is not passed as plausible either (vibidd).
            e.implausible = VIBID_IMPLAUSIBLE_NONFINITE;
            e.why = std::string("plausibility check failed: ") + vibid_last_error();
        } else {
            e.why = why;
        }
        if (!unstable_why.empty()) {
            // Impossible for a passive stand whatever the rules say (vibidd flags it P); a
            // growth within the rules' 1e-6 zeta tolerance is a slightly negative zeta.
            if (!e.implausible) e.implausible = VIBID_IMPLAUSIBLE_ZETA_NEGATIVE;
            e.why += (e.why.empty() ? "" : "; ") + unstable_why;
        }
        vibid_ident_quality q;
        if (vibid_ident_get_quality(ident_.get(), &q, e.param_quality.data()) == VIBID_OK) {
            e.quality = q.flags;
            e.z_consistency = q.z_consistency;
            e.n_blocks = q.n_blocks;
        }
        return e;
    }

    std::string describe() const {
        size_t len = 0;
        std::vector<char> buf(4096);
        vibid_status s = vibid_ident_describe(ident_.get(), buf.data(), buf.size(), &len);
        if (s != VIBID_OK) raise_status("vibid_ident_describe", s);
        if (len + 1 > buf.size()) {
            buf.resize(len + 1);
            s = vibid_ident_describe(ident_.get(), buf.data(), buf.size(), &len);
            if (s != VIBID_OK) raise_status("vibid_ident_describe", s);
        }
        return std::string(buf.data());
    }

    // The settings in force after the automatic choices: estimator, prefilter_hz, iv_lag,
    // forgetting, difference_order.
    std::tuple<int, double, size_t, double, unsigned> config() const {
        vibid_ident_config c;
        vibid_status s = vibid_ident_get_config(ident_.get(), &c);
        if (s != VIBID_OK) raise_status("vibid_ident_get_config", s);
        return {static_cast<int>(c.estimator), c.prefilter_hz, c.iv_lag, c.forgetting, c.difference_order};
    }

private:
    struct Deleter {
        void operator()(vibid_ident *p) const { vibid_ident_destroy(p); }
    };
    const vibid_model *model_;
    vibid_model_dims dims_;
    double h_;
    bool state_space_ = false;
    std::unique_ptr<vibid_ident, Deleter> ident_;
    vibid_plausibility_ref pref_{};
};

// ---- Checks, residuals and simulation for `vibid check` and the report (issue 13) ----
// Thin as the rest: the numerics are the library's (vibid_model_check_identifiable,
// vibid_regressor_*, vibid_model_assemble, vibid_model_forces); only the time stepping of
// the simulation lives here, because the library has none outside the EKF.

// (status, message, known_regular, controllable, generic_rank) of
// vibid_model_check_identifiable: the regression's identifiability before any sample.
std::tuple<int, std::string, int, int, size_t> stand_identifiability(const Stand &st) {
    vibid_identifiability rep{};
    vibid_status s = vibid_model_check_identifiable(st.model(), &rep);
    return {static_cast<int>(s), s == VIBID_OK ? std::string() : std::string(vibid_last_error()), rep.known_regular,
            rep.controllable, rep.generic_rank};
}

// Per channel of the model's layout: (kind, node index or -2 for the base or the input
// index for an input, the model's own name such as "m1.displacement").
std::vector<std::tuple<std::string, long, std::string>> stand_channel_info(const Stand &st) {
    std::vector<std::tuple<std::string, long, std::string>> out;
    for (size_t c = 0; c < st.dims().n_channels; ++c) {
        vibid_channel_info ci;
        vibid_status s = vibid_model_channel_info(st.model(), c, &ci);
        if (s != VIBID_OK) raise_status("vibid_model_channel_info", s);
        static const char *const kinds[] = {"displacement", "velocity", "acceleration", "input"};
        const long idx = ci.index == VIBID_BASE ? -2L : static_cast<long>(ci.index);
        out.emplace_back(kinds[ci.kind], idx, ci.name);
    }
    return out;
}

void check_theta(const Stand &st, const std::vector<double> &theta, const char *what) {
    if (theta.size() != st.dims().n_params)
        throw std::invalid_argument(std::string(what) + ": theta has " + std::to_string(theta.size()) +
                                    " values for " + std::to_string(st.dims().n_params) + " unknowns");
    for (double v : theta)
        if (!std::isfinite(v)) throw std::invalid_argument(std::string(what) + ": theta is not finite");
}

// The equation errors e_k = y_k - x_k^T theta of the regression the estimators fit
// (regressor.h: the same differences and pre-filter), one column per equation (node),
// and the sample index each row describes (k - latency). Structured form only: the ZOH
// form's coefficients are not the stand's parameters.
std::tuple<std::vector<long>, Array2> stand_residuals(const Stand &st, const std::vector<double> &th,
                                                      nb::ndarray<const double, nb::ndim<2>, nb::device::cpu> data,
                                                      double prefilter_hz, unsigned order) {
    check_theta(st, th, "residuals");
    const size_t n = data.shape(0), nc = data.shape(1), p = st.dims().n_params;
    if (nc != st.dims().n_channels)
        throw std::invalid_argument("residuals: " + std::to_string(nc) + " columns for " +
                                    std::to_string(st.dims().n_channels) + " channels");
    std::unique_ptr<vibid_regressor, void (*)(vibid_regressor *)> reg(
        vibid_regressor_create_order(st.model(), 1.0 / st.sample_rate(), prefilter_hz, order), vibid_regressor_destroy);
    if (!reg) throw VibidError(vibid_last_error());  // it names the function and the argument
    vibid_regressor_dims rd{};
    vibid_status s = vibid_regressor_get_dims(reg.get(), &rd);
    if (s != VIBID_OK) raise_status("vibid_regressor_get_dims", s);
    if (rd.n_outputs != 1 || rd.n_regressors != p)
        throw VibidError("residuals: the stand's regression is the ZOH difference form, whose coefficients are not "
                         "the stand's parameters; no residuals of the structured equations");
    const size_t m = rd.n_equations;
    std::vector<double> x(p * m), y(m), e;
    std::vector<long> rows;
    e.reserve(n * m);
    const double *base = data.data();
    const int64_t rs = data.stride(0), cs = data.stride(1);
    size_t bad_row = 0;
    {
        nb::gil_scoped_release release;
        std::vector<double> sample(nc);
        for (size_t k = 0; k < n; ++k) {
            for (size_t c = 0; c < nc; ++c) sample[c] = base[k * rs + c * cs];
            int ready = 0;
            s = vibid_regressor_push(reg.get(), sample.data(), x.data(), y.data(), &ready);
            if (s != VIBID_OK) {
                bad_row = k;
                break;
            }
            if (!ready) continue;
            rows.push_back(static_cast<long>(k - rd.latency));
            for (size_t i = 0; i < m; ++i) {
                double r = y[i];
                for (size_t l = 0; l < p; ++l) r -= x[l + i * p] * th[l];
                e.push_back(r);
            }
        }
    }
    if (s != VIBID_OK) raise_status(("vibid_regressor_push (row " + std::to_string(bad_row) + ")").c_str(), s);
    // e is row-major (rows x m); the numpy array is column-major: transpose.
    const size_t nr = rows.size();
    std::vector<double> cm(nr * m);
    for (size_t r = 0; r < nr; ++r)
        for (size_t i = 0; i < m; ++i) cm[r + i * nr] = e[r * m + i];
    return {rows, to_numpy(std::move(cm), nr, m)};
}

// The model at theta driven by the capture's measured inputs (force channels, base
// displacement): M y'' = vibid_model_forces(theta, y, y', [s, s'], u), classical RK4 with
// `substeps` steps per sample. Smooth inputs are cubic Hermite between samples with slopes
// from five-point central differences (a measured base velocity is used as the base's
// slope), so the input is right to O(h^4); held inputs (vibid_model_set_hold) are
// constant over [t_k, t_k + h), and a held base's jumps reach the dampers to it as the
// impulse d_base (s_k - s_{k-1}) (model.h). The run starts at sample 2 from the measured
// displacements and velocities (five-point differences of the displacements where the
// velocity is not measured; 0 for a node without displacement sensor, whose start
// transient then decays with the system's damping). Returns the channels in the model's
// layout: node channels simulated, input channels as measured, rows 0 and 1 NaN.
Array2 stand_simulate(const Stand &st, const std::vector<double> &th, nb::ndarray<const double, nb::ndim<2>, nb::device::cpu> data,
                      unsigned substeps) {
    check_theta(st, th, "simulate");
    const vibid_model_dims &dm = st.dims();
    const size_t N = data.shape(0), nc = data.shape(1), n = dm.n_dof, r = dm.n_inputs;
    if (nc != dm.n_channels)
        throw std::invalid_argument("simulate: " + std::to_string(nc) + " columns for " +
                                    std::to_string(dm.n_channels) + " channels");
    if (substeps < 1) throw std::invalid_argument("simulate: substeps >= 1");
    if (N < 5) throw std::invalid_argument("simulate: at least 5 samples are needed");
    const vibid_model *model = st.model();
    const double h = 1.0 / st.sample_rate();
    const int64_t rs = data.stride(0), cs = data.stride(1);
    const double *base = data.data();
    auto at = [&](size_t k, size_t c) { return base[k * rs + c * cs]; };
    // channel layout
    std::vector<long> disp(n, -1), vel(n, -1);
    long s_ch = -1, sd_ch = -1;
    std::vector<long> u_ch(r, -1);
    std::vector<vibid_channel_info> info(nc);
    for (size_t c = 0; c < nc; ++c) {
        vibid_status s = vibid_model_channel_info(model, c, &info[c]);
        if (s != VIBID_OK) raise_status("vibid_model_channel_info", s);
        const vibid_channel_info &ci = info[c];
        if (ci.kind == VIBID_CHANNEL_INPUT) u_ch[ci.index] = static_cast<long>(c);
        else if (ci.index == VIBID_BASE) {
            if (ci.kind == VIBID_CHANNEL_DISPLACEMENT) s_ch = static_cast<long>(c);
            if (ci.kind == VIBID_CHANNEL_VELOCITY) sd_ch = static_cast<long>(c);
        } else if (ci.kind == VIBID_CHANNEL_DISPLACEMENT) disp[ci.index] = static_cast<long>(c);
        else if (ci.kind == VIBID_CHANNEL_VELOCITY) vel[ci.index] = static_cast<long>(c);
    }
    if (dm.has_base && s_ch < 0)
        throw VibidError("simulate: the stand's base moves but its displacement is not measured: no input to drive "
                         "the model with");
    for (size_t j = 0; j < r; ++j)
        if (u_ch[j] < 0) throw VibidError("simulate: input " + std::to_string(j) + " has no channel");
    // M at theta, inverted once (symmetric positive definite for a plausible estimate;
    // Gauss-Jordan with partial pivoting so that an implausible one is still simulated).
    std::vector<double> M(n * n), Mi(n * n, 0.0), dbase(n, 0.0);
    vibid_status s = vibid_model_assemble(model, th.data(), M.data(), nullptr, nullptr, nullptr, dbase.data(), nullptr);
    if (s != VIBID_OK) raise_status("vibid_model_assemble", s);
    for (size_t i = 0; i < n; ++i) Mi[i + i * n] = 1.0;
    for (size_t col = 0; col < n; ++col) {
        size_t piv = col;
        for (size_t i = col + 1; i < n; ++i)
            if (std::fabs(M[i + col * n]) > std::fabs(M[piv + col * n])) piv = i;
        if (!(std::fabs(M[piv + col * n]) > 0.0))
            throw VibidError("simulate: the mass matrix at these parameters is singular");
        for (size_t j = 0; j < n; ++j) {
            std::swap(M[col + j * n], M[piv + j * n]);
            std::swap(Mi[col + j * n], Mi[piv + j * n]);
        }
        const double d = M[col + col * n];
        for (size_t j = 0; j < n; ++j) {
            M[col + j * n] /= d;
            Mi[col + j * n] /= d;
        }
        for (size_t i = 0; i < n; ++i) {
            if (i == col) continue;
            const double f = M[i + col * n];
            if (f == 0.0) continue;
            for (size_t j = 0; j < n; ++j) {
                M[i + j * n] -= f * M[col + j * n];
                Mi[i + j * n] -= f * Mi[col + j * n];
            }
        }
    }
    // Interpolated inputs: column c's value and slope at t_k + tau h, tau in [0, 1].
    auto slope = [&](size_t c, size_t k) {
        if (k >= 2 && k + 2 < N)
            return (at(k - 2, c) - 8.0 * at(k - 1, c) + 8.0 * at(k + 1, c) - at(k + 2, c)) / (12.0 * h);
        if (k >= 1 && k + 1 < N) return (at(k + 1, c) - at(k - 1, c)) / (2.0 * h);
        return k == 0 ? (at(1, c) - at(0, c)) / h : (at(k, c) - at(k - 1, c)) / h;
    };
    auto hermite = [&](size_t c, size_t k, double tau, double m0, double m1, double *val, double *der) {
        const double p0 = at(k, c), p1 = at(k + 1, c);
        const double t2 = tau * tau, t3 = t2 * tau;
        *val = (2 * t3 - 3 * t2 + 1) * p0 + (t3 - 2 * t2 + tau) * h * m0 + (-2 * t3 + 3 * t2) * p1 + (t3 - t2) * h * m1;
        *der = ((6 * t2 - 6 * tau) * p0 + (3 * t2 - 4 * tau + 1) * h * m0 + (-6 * t2 + 6 * tau) * p1 +
                (3 * t2 - 2 * tau) * h * m1) / h;
    };
    std::vector<int> u_held(r, 0);
    for (size_t j = 0; j < r; ++j) {
        vibid_hold hd;
        if (vibid_model_get_hold(model, j, &hd) == VIBID_OK) u_held[j] = hd == VIBID_HOLD_ZOH;
    }
    int s_held = 0;
    if (dm.has_base) {
        vibid_hold hd;
        if (vibid_model_get_hold(model, VIBID_BASE, &hd) == VIBID_OK) s_held = hd == VIBID_HOLD_ZOH;
    }
    std::vector<double> out(N * nc, NAN);  // column-major N x nc
    std::vector<double> y(n, 0.0), yd(n, 0.0), u(r, 0.0), f(n), acc(n);
    double bs[2] = {0.0, 0.0};
    // accelerations M^-1 f(y, yd) with the inputs at (k, tau)
    auto inputs_at = [&](size_t k, double tau, const std::vector<double> &m0, const std::vector<double> &m1) {
        for (size_t j = 0; j < r; ++j) {
            double d;
            if (u_held[j] || k + 1 >= N) u[j] = at(k, u_ch[j]);
            else hermite(u_ch[j], k, tau, m0[1 + j], m1[1 + j], &u[j], &d);
        }
        if (dm.has_base) {
            if (s_held || k + 1 >= N) {
                bs[0] = at(k, s_ch);
                bs[1] = s_held ? 0.0 : m0[0];
            } else {
                hermite(s_ch, k, tau, m0[0], m1[0], &bs[0], &bs[1]);
            }
        }
    };
    auto accel = [&](const double *yy, const double *vv, double *a) {
        vibid_status fs = vibid_model_forces(model, th.data(), yy, vv, dm.has_base ? bs : nullptr,
                                             r ? u.data() : nullptr, f.data());
        for (size_t i = 0; i < n; ++i) {
            double sum = 0.0;
            for (size_t j = 0; j < n; ++j) sum += Mi[i + j * n] * f[j];
            a[i] = sum;
        }
        return fs;
    };
    // slopes of the inputs at sample k: [base, u_0 .. u_{r-1}]
    auto slopes = [&](size_t k, std::vector<double> &m) {
        m[0] = dm.has_base ? (sd_ch >= 0 ? at(k, sd_ch) : slope(s_ch, k)) : 0.0;
        for (size_t j = 0; j < r; ++j) m[1 + j] = slope(u_ch[j], k);
    };
    s = VIBID_OK;
    {
        nb::gil_scoped_release release;
        const size_t k0 = 2;
        for (size_t i = 0; i < n; ++i) {
            if (disp[i] >= 0) y[i] = at(k0, disp[i]);
            if (vel[i] >= 0) yd[i] = at(k0, vel[i]);
            else if (disp[i] >= 0) yd[i] = slope(disp[i], k0);
        }
        std::vector<double> m0(1 + r), m1(1 + r);
        std::vector<double> k1y(n), k1v(n), k2y(n), k2v(n), k3y(n), k3v(n), k4y(n), k4v(n), ty(n), tv(n);
        const double hs = h / substeps;
        for (size_t k = k0; k < N && s == VIBID_OK; ++k) {
            slopes(k, m0);
            if (k + 1 < N) slopes(k + 1, m1);
            else m1 = m0;
            if (s_held && k > k0) {
                // the held base jumped at t_k: the dampers to it kick the velocities
                const double jump = at(k, s_ch) - at(k - 1, s_ch);
                for (size_t i = 0; i < n; ++i) {
                    double sum = 0.0;
                    for (size_t j = 0; j < n; ++j) sum += Mi[i + j * n] * dbase[j] * jump;
                    yd[i] += sum;
                }
            }
            // this sample's outputs
            inputs_at(k, 0.0, m0, m1);
            s = accel(y.data(), yd.data(), acc.data());
            for (size_t c = 0; c < nc; ++c) {
                const vibid_channel_info &ci = info[c];
                double v;
                if (ci.kind == VIBID_CHANNEL_INPUT || ci.index == VIBID_BASE) v = at(k, c);
                else if (ci.kind == VIBID_CHANNEL_DISPLACEMENT) v = y[ci.index];
                else if (ci.kind == VIBID_CHANNEL_VELOCITY) v = yd[ci.index];
                else v = acc[ci.index];
                out[k + c * N] = v;
            }
            if (k + 1 >= N) break;
            for (unsigned q = 0; q < substeps && s == VIBID_OK; ++q) {
                const double t0 = static_cast<double>(q) / substeps, tm = (q + 0.5) / substeps,
                             t1 = (q + 1.0) / substeps;
                inputs_at(k, t0, m0, m1);
                accel(y.data(), yd.data(), k1v.data());
                for (size_t i = 0; i < n; ++i) {
                    k1y[i] = yd[i];
                    ty[i] = y[i] + 0.5 * hs * k1y[i];
                    tv[i] = yd[i] + 0.5 * hs * k1v[i];
                }
                inputs_at(k, tm, m0, m1);
                accel(ty.data(), tv.data(), k2v.data());
                for (size_t i = 0; i < n; ++i) {
                    k2y[i] = tv[i];
                    ty[i] = y[i] + 0.5 * hs * k2y[i];
                    tv[i] = yd[i] + 0.5 * hs * k2v[i];
                }
                accel(ty.data(), tv.data(), k3v.data());
                for (size_t i = 0; i < n; ++i) {
                    k3y[i] = tv[i];
                    ty[i] = y[i] + hs * k3y[i];
                    tv[i] = yd[i] + hs * k3v[i];
                }
                inputs_at(k, t1, m0, m1);
                s = accel(ty.data(), tv.data(), k4v.data());
                for (size_t i = 0; i < n; ++i) {
                    k4y[i] = tv[i];
                    y[i] += hs / 6.0 * (k1y[i] + 2 * k2y[i] + 2 * k3y[i] + k4y[i]);
                    yd[i] += hs / 6.0 * (k1v[i] + 2 * k2v[i] + 2 * k3v[i] + k4v[i]);
                }
            }
        }
    }
    if (s != VIBID_OK) raise_status("vibid_model_forces", s);
    return to_numpy(std::move(out), N, nc);
}

}  // namespace

NB_MODULE(_core, m) {
    m.doc() = "vibid._core: nanobind binding of libvibid's C API (use the vibid package instead)";
    nb::exception<VibidError>(m, "VibidError", PyExc_RuntimeError);

    m.def("version", [] { return std::string(vibid_version_string()); });

    nb::class_<Stand>(m, "Stand")
        .def(nb::init<const std::string &>(), "path"_a)
        .def_prop_ro("name", &Stand::name)
        .def_prop_ro("sample_rate", &Stand::sample_rate)
        .def_prop_ro("channels", &Stand::channels)
        .def_prop_ro("params", &Stand::params)
        .def_prop_ro("length_unit", [](const Stand &s) { return std::string(vibid_stand_length_unit(s.raw())); })
        .def_prop_ro("length_si", [](const Stand &s) { return vibid_stand_length_si(s.raw()); })
        .def_prop_ro("n_dof", [](const Stand &s) { return s.dims().n_dof; });

    nb::class_<Ident>(m, "Ident")
        // keep_alive: the identification reads the stand's model (plausibility, modes).
        .def(nb::init<const Stand &, int, double, double, size_t>(), "stand"_a, "estimator"_a, "forgetting"_a,
             "prefilter_hz"_a, "iv_lag"_a, nb::keep_alive<1, 2>())
        .def("push", &Ident::push, "data"_a, "start"_a, "stop"_a)
        // A dict of plain values and arrays that own their storage (moved, not copied).
        .def("estimate",
             [](Ident &id) {
                 Estimate e = id.estimate();
                 const size_t p = e.theta.size();
                 nb::dict d;
                 d["status"] = e.status;
                 d["message"] = e.message;
                 d["theta"] = to_numpy(std::move(e.theta)).cast();
                 d["se"] = to_numpy(std::move(e.se)).cast();
                 d["covariance"] = to_numpy(std::move(e.cov), p, p).cast();
                 d["freq_hz"] = to_numpy(std::move(e.freq)).cast();
                 d["freq_hz_se"] = to_numpy(std::move(e.freq_se)).cast();
                 d["zeta"] = to_numpy(std::move(e.zeta)).cast();
                 d["zeta_se"] = to_numpy(std::move(e.zeta_se)).cast();
                 d["quality"] = e.quality;
                 d["param_quality"] = e.param_quality;
                 d["param_implausible"] = e.param_implausible;
                 d["mode_implausible"] = e.mode_implausible;
                 d["implausible"] = e.implausible;
                 d["why"] = e.why;
                 d["z_consistency"] = e.z_consistency;
                 d["n_blocks"] = e.n_blocks;
                 d["n_samples"] = e.n_samples;
                 return d;
             })
        .def("describe", &Ident::describe)
        .def("config", &Ident::config);

    // vibid check and the report (issue 13): see stand_identifiability and below.
    m.def("stand_identifiability", &stand_identifiability, "stand"_a);
    m.def("stand_channel_info", &stand_channel_info, "stand"_a);
    m.def("stand_residuals", &stand_residuals, "stand"_a, "theta"_a, "data"_a, "prefilter_hz"_a, "order"_a);
    m.def("stand_simulate", &stand_simulate, "stand"_a, "theta"_a, "data"_a, "substeps"_a = 8);

    m.attr("QUALITY_SE_INVALID") = VIBID_QUALITY_SE_INVALID;
    m.attr("QUALITY_NOT_EXCITED") = VIBID_QUALITY_NOT_EXCITED;
    m.attr("ESTIMATOR_LS") = static_cast<int>(VIBID_ESTIMATOR_LS);
    m.attr("ESTIMATOR_IV") = static_cast<int>(VIBID_ESTIMATOR_IV);
    m.attr("ESTIMATOR_RLS") = static_cast<int>(VIBID_ESTIMATOR_RLS);
    m.attr("ESTIMATOR_AUTO") = static_cast<int>(VIBID_ESTIMATOR_AUTO);
    m.attr("ESTIMATOR_EKF") = static_cast<int>(VIBID_ESTIMATOR_EKF);
    m.attr("ESTIMATOR_KF_RLS") = static_cast<int>(VIBID_ESTIMATOR_KF_RLS);

    // vibid/units.h, the one unit table of every vibid program, for the capture readers:
    // (value in SI) = factor * (value in unit). ValueError naming the accepted spellings
    // when unit is not one of dim's ("length", "velocity", "acceleration", "force").
    m.def(
        "unit_si_factor",
        [](const std::string &dim, const std::string &unit) {
            static const char *const dims[] = {"length", "velocity", "acceleration", "force"};
            for (int d = 0; d < 4; ++d) {
                if (dim != dims[d]) continue;
                double f = 0;
                if (vibid_unit_si_factor(static_cast<vibid_unit_dim>(d), unit.c_str(), &f))
                    throw nb::value_error(("'" + unit + "' is not a " + dim + " unit (" +
                                           vibid_unit_names(static_cast<vibid_unit_dim>(d)) + ")")
                                              .c_str());
                return f;
            }
            throw nb::value_error(("unit_si_factor: unknown dimension '" + dim +
                                   "' (length, velocity, acceleration, force)")
                                      .c_str());
        },
        "dim"_a, "unit"_a);
}
