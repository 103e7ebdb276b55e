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
#include <vibid/stand_file.h>
}

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

    m.attr("QUALITY_SE_INVALID") = VIBID_QUALITY_SE_INVALID;
    m.attr("QUALITY_NOT_EXCITED") = VIBID_QUALITY_NOT_EXCITED;
    m.attr("ESTIMATOR_LS") = static_cast<int>(VIBID_ESTIMATOR_LS);
    m.attr("ESTIMATOR_IV") = static_cast<int>(VIBID_ESTIMATOR_IV);
    m.attr("ESTIMATOR_RLS") = static_cast<int>(VIBID_ESTIMATOR_RLS);
    m.attr("ESTIMATOR_AUTO") = static_cast<int>(VIBID_ESTIMATOR_AUTO);
    m.attr("ESTIMATOR_EKF") = static_cast<int>(VIBID_ESTIMATOR_EKF);
    m.attr("ESTIMATOR_KF_RLS") = static_cast<int>(VIBID_ESTIMATOR_KF_RLS);
}
