// vibid._core: the thin nanobind layer over libvibid's C API (identify.h, report.h, modal.h,
// plausibility.h, output_error.h; lsq.h, rls.h, iv.h for the estimator classes) and the stand loader (stand_file.h). All numerics stay in the C library;
// this file converts arrays and statuses and nothing else. The Pythonic API (channel names,
// DataFrames, tracks) is in vibid/*.py.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/optional.h>

extern "C" {
#include <vibid/identify.h>
#include <vibid/oma.h>
#include <vibid/iv.h>
#include <vibid/lsq.h>
#include <vibid/rls.h>
#include <vibid/modal.h>
#include <vibid/outlier.h>
#include <vibid/output_error.h>
#include <vibid/plausibility.h>
#include <vibid/regressor.h>
#include <vibid/report.h>
#include <vibid/simulate.h>
#include <vibid/stand_file.h>
#include <vibid/units.h>
}

#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>
#include <mutex>
#include <optional>
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
        // OE's start estimator is the EKF on stands that are not fully measured: its
        // divergences are reported and skipped in the same way.
        state_space_ = used.estimator == VIBID_ESTIMATOR_EKF || used.estimator == VIBID_ESTIMATOR_KF_RLS ||
                       used.estimator == VIBID_ESTIMATOR_OE;
        // The row's checks, vibidd's (vibid/report.h); its plausibility reference is made here.
        vibid_report *r = vibid_report_create(model_, h_);
        if (!r) throw VibidError(vibid_last_error());
        report_.reset(r);
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

    // The estimate, its covariance, modes with standard errors and flags: vibid_report_row,
    // the row vibidd writes. A failed vibid_ident_estimate is not raised here (a track row
    // early in a run may have too few samples): status and message say it.
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
        vibid_report_row_out out{};
        out.theta = e.theta.data();
        out.se = e.se.data();
        out.freq = e.freq.data();
        out.freq_se = e.freq_se.data();
        out.zeta = e.zeta.data();
        out.zeta_se = e.zeta_se.data();
        out.cov = e.cov.data();
        out.param_quality = e.param_quality.data();
        out.param_implausible = e.param_implausible.data();
        out.mode_implausible = e.mode_implausible.data();
        vibid_status s;
        {
            nb::gil_scoped_release release;
            s = vibid_report_row(report_.get(), ident_.get(), &out);
        }
        if (s != VIBID_OK) raise_status("vibid_report_row", s);  // a bug: the arrays are sized here
        e.status = out.est_status;
        e.message = out.message;
        e.n_samples = out.n_samples;
        e.quality = out.quality;
        e.implausible = out.implausible;
        e.why = out.why;
        e.z_consistency = out.z_consistency;
        e.n_blocks = out.n_blocks;
        return e;
    }

    // Rows [start, stop) pushed one at a time with each update's innovations
    // (vibid_ident_innovations; EKF and KF_RLS): (channels (the filter's measured channels,
    // index in the sample), nu and sd (rows x channels, NaN where the push made no update:
    // the start window, a gap, a divergence), inflation (rows; NaN likewise)). Divergences
    // are skipped as in push; any other failure is raised naming the row.
    std::tuple<std::vector<size_t>, Array2, Array2, Array1> innovations(
        nb::ndarray<const double, nb::ndim<2>, nb::device::cpu> data, size_t start, size_t stop) {
        const size_t n = data.shape(0), nc = data.shape(1);
        if (nc != dims_.n_channels)
            throw std::invalid_argument("innovations: " + std::to_string(nc) + " columns for " +
                                        std::to_string(dims_.n_channels) + " channels");
        if (start > stop || stop > n) throw std::invalid_argument("innovations: bad row range");
        size_t nz = 0;
        vibid_status s = vibid_ident_innovations(ident_.get(), 0, &nz, nullptr, nullptr, nullptr, nullptr);
        if (s != VIBID_OK) raise_status("vibid_ident_innovations", s);
        nz = dims_.n_channels;  // at most every channel is measured; the true count comes with the first update
        const size_t rows = stop - start;
        std::vector<size_t> channels;
        std::vector<double> nu(rows * nz, NAN), sd(rows * nz, NAN), infl(rows, NAN), sample(nc);  // column-major
        std::vector<size_t> ch(nz);
        std::vector<double> nu_k(nz), sd_k(nz);
        const double *base = data.data();
        const int64_t rs = data.stride(0), cs = data.stride(1);
        size_t bad_row = 0, used = 0;
        {
            nb::gil_scoped_release release;
            for (size_t k = start; k < stop; ++k) {
                for (size_t c = 0; c < nc; ++c) sample[c] = base[k * rs + c * cs];
                vibid_status sk = vibid_ident_push(ident_.get(), sample.data());
                if (sk == VIBID_E_DIVERGED || sk == VIBID_E_NONFINITE) continue;
                if (sk != VIBID_OK) {
                    s = sk;
                    bad_row = k;
                    break;
                }
                size_t m = 0;
                double f = NAN;
                s = vibid_ident_innovations(ident_.get(), nz, &m, ch.data(), nu_k.data(), sd_k.data(), &f);
                if (s != VIBID_OK) {
                    bad_row = k;
                    break;
                }
                if (m == 0) continue;
                if (channels.empty()) channels.assign(ch.begin(), ch.begin() + static_cast<std::ptrdiff_t>(m));
                used = m;
                const size_t r = k - start;
                for (size_t j = 0; j < m; ++j) {
                    nu[j * rows + r] = nu_k[j];
                    sd[j * rows + r] = sd_k[j];
                }
                infl[r] = f;
            }
        }
        if (s != VIBID_OK) raise_status(("vibid_ident_push (row " + std::to_string(bad_row) + ")").c_str(), s);
        // Column-major: the measured channels' columns are the first `used`.
        nu.resize(rows * used);
        sd.resize(rows * used);
        return {channels, to_numpy(std::move(nu), rows, used), to_numpy(std::move(sd), rows, used),
                to_numpy(std::move(infl))};
    }

    // The last estimate's constant offsets (vibid_ident_offsets: OE only, else none):
    // (channel indices in the sample, values, standard errors).
    std::tuple<std::vector<size_t>, std::vector<double>, std::vector<double>> offsets() const {
        size_t n = 0;
        vibid_status s = vibid_ident_offsets(ident_.get(), 0, &n, nullptr, nullptr, nullptr);
        if (s != VIBID_OK) raise_status("vibid_ident_offsets", s);
        std::vector<size_t> ch(n);
        std::vector<double> v(n), se(n);
        s = vibid_ident_offsets(ident_.get(), n, &n, ch.data(), v.data(), se.data());
        if (s != VIBID_OK) raise_status("vibid_ident_offsets", s);
        return {ch, v, se};
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
    struct ReportDeleter {
        void operator()(vibid_report *p) const { vibid_report_destroy(p); }
    };
    std::unique_ptr<vibid_ident, Deleter> ident_;
    std::unique_ptr<vibid_report, ReportDeleter> report_;
};

// ---- Output-only modal identification (vibid/oma.h; issue 34) ----
// Thin: the package's vibid.oma (vibid/_oma.py) sizes the blocks and builds the tables.
class Oma {
public:
    Oma(double sample_rate, size_t n_channels, const std::vector<size_t> &refs, size_t block_rows, size_t max_order,
        size_t block_samples, size_t max_blocks, nb::dict thresholds)
        : nch_(n_channels) {
        vibid_oma_config cfg;
        vibid_oma_config_init(&cfg, sample_rate, n_channels);
        cfg.n_refs = refs.size();
        cfg.refs = refs.empty() ? nullptr : refs.data();
        cfg.block_rows = block_rows;
        cfg.max_order = max_order;
        cfg.block_samples = block_samples;
        cfg.max_blocks = max_blocks;
        for (auto [key, value] : thresholds) {
            const std::string k = nb::cast<std::string>(key);
            const double v = nb::cast<double>(value);
            double *field = k == "stab_freq"           ? &cfg.stab_freq
                            : k == "stab_damping"      ? &cfg.stab_damping
                            : k == "stab_mac"          ? &cfg.stab_mac
                            : k == "max_damping"       ? &cfg.max_damping
                            : k == "cluster_freq"      ? &cfg.cluster_freq
                            : k == "cluster_mac"       ? &cfg.cluster_mac
                            : k == "min_cluster_share" ? &cfg.min_cluster_share
                                                       : nullptr;
            if (!field) throw std::invalid_argument("Oma: unknown threshold '" + k + "'");
            *field = v;
        }
        vibid_oma *o = vibid_oma_create(&cfg);
        if (!o) throw VibidError(vibid_last_error());
        oma_.reset(o);
    }

    // n x n_channels samples of any strides; returns the number of gaps (non-finite samples).
    size_t push(nb::ndarray<const double, nb::ndim<2>, nb::device::cpu> data) {
        const size_t n = data.shape(0);
        if (data.shape(1) != nch_)
            throw std::invalid_argument("Oma.push: " + std::to_string(data.shape(1)) + " columns for " +
                                        std::to_string(nch_) + " channels");
        const double *base = data.data();
        const int64_t rs = data.stride(0), cs = data.stride(1);
        size_t gaps = 0;
        vibid_status s = VIBID_OK;
        {
            nb::gil_scoped_release release;
            if (rs == 1 && cs >= static_cast<int64_t>(n)) {
                s = vibid_oma_push_block(oma_.get(), n, base, static_cast<size_t>(cs), &gaps);
            } else {
                // Column-major chunks of up to 65536 samples.
                const size_t chunk = 65536;
                std::vector<double> buf(std::min(n, chunk) * nch_);
                for (size_t t0 = 0; t0 < n && s == VIBID_OK; t0 += chunk) {
                    const size_t m = std::min(chunk, n - t0);
                    for (size_t c = 0; c < nch_; ++c)
                        for (size_t t = 0; t < m; ++t) buf[t + c * m] = base[(t0 + t) * rs + c * cs];
                    size_t g = 0;
                    s = vibid_oma_push_block(oma_.get(), m, buf.data(), m, &g);
                    gaps += g;
                }
            }
        }
        if (s != VIBID_OK) raise_status("vibid_oma_push_block", s);
        return gaps;
    }

    void identify() {
        vibid_status s;
        {
            nb::gil_scoped_release release;
            s = vibid_oma_identify(oma_.get());
        }
        if (s != VIBID_OK) raise_status("vibid_oma_identify", s);
    }

    nb::dict modes() const {
        size_t n = 0;
        vibid_status s = vibid_oma_get_modes(oma_.get(), 0, &n, nullptr, nullptr, nullptr);
        if (s != VIBID_OK) raise_status("vibid_oma_get_modes", s);
        std::vector<vibid_oma_mode> m(n);
        std::vector<double> re(n * nch_), im(n * nch_);
        s = vibid_oma_get_modes(oma_.get(), n, &n, m.data(), re.data(), im.data());
        if (s != VIBID_OK) raise_status("vibid_oma_get_modes", s);
        std::vector<double> f(n), fse(n), z(n), zse(n), mpc(n), order(n), size(n);
        for (size_t j = 0; j < n; ++j) {
            f[j] = m[j].freq_hz;
            fse[j] = m[j].freq_se;
            z[j] = m[j].zeta;
            zse[j] = m[j].zeta_se;
            mpc[j] = m[j].mpc;
            order[j] = static_cast<double>(m[j].order);
            size[j] = static_cast<double>(m[j].n_poles);
        }
        nb::dict d;
        d["freq_hz"] = to_numpy(std::move(f)).cast();
        d["freq_hz_se"] = to_numpy(std::move(fse)).cast();
        d["zeta"] = to_numpy(std::move(z)).cast();
        d["zeta_se"] = to_numpy(std::move(zse)).cast();
        d["mpc"] = to_numpy(std::move(mpc)).cast();
        d["order"] = to_numpy(std::move(order)).cast();
        d["n_poles"] = to_numpy(std::move(size)).cast();
        d["shape_re"] = to_numpy(std::move(re), n, nch_).cast();
        d["shape_im"] = to_numpy(std::move(im), n, nch_).cast();
        return d;
    }

    nb::dict poles() const {
        size_t n = 0;
        vibid_status s = vibid_oma_get_poles(oma_.get(), 0, &n, nullptr);
        if (s != VIBID_OK) raise_status("vibid_oma_get_poles", s);
        std::vector<vibid_oma_pole> p(n);
        s = vibid_oma_get_poles(oma_.get(), n, &n, p.data());
        if (s != VIBID_OK) raise_status("vibid_oma_get_poles", s);
        std::vector<double> order(n), f(n), fse(n), z(n), zse(n), mpc(n), stable(n), physical(n), mode(n);
        for (size_t j = 0; j < n; ++j) {
            order[j] = static_cast<double>(p[j].order);
            f[j] = p[j].freq_hz;
            fse[j] = p[j].freq_se;
            z[j] = p[j].zeta;
            zse[j] = p[j].zeta_se;
            mpc[j] = p[j].mpc;
            stable[j] = p[j].stable;
            physical[j] = p[j].physical;
            mode[j] = static_cast<double>(p[j].mode);
        }
        nb::dict d;
        d["order"] = to_numpy(std::move(order)).cast();
        d["freq_hz"] = to_numpy(std::move(f)).cast();
        d["freq_hz_se"] = to_numpy(std::move(fse)).cast();
        d["zeta"] = to_numpy(std::move(z)).cast();
        d["zeta_se"] = to_numpy(std::move(zse)).cast();
        d["mpc"] = to_numpy(std::move(mpc)).cast();
        d["stable"] = to_numpy(std::move(stable)).cast();
        d["physical"] = to_numpy(std::move(physical)).cast();
        d["mode"] = to_numpy(std::move(mode)).cast();
        return d;
    }

    Array1 singular_values() const {
        size_t n = 0;
        vibid_status s = vibid_oma_get_singular_values(oma_.get(), 0, &n, nullptr);
        if (s != VIBID_OK) raise_status("vibid_oma_get_singular_values", s);
        std::vector<double> sv(n);
        s = vibid_oma_get_singular_values(oma_.get(), n, &n, sv.data());
        if (s != VIBID_OK) raise_status("vibid_oma_get_singular_values", s);
        return to_numpy(std::move(sv));
    }

    // (block_rows, max_order, block_samples, max_blocks, n_refs) in force
    std::tuple<size_t, size_t, size_t, size_t, size_t> config() const {
        vibid_oma_config c;
        vibid_oma_get_config(oma_.get(), &c);
        return {c.block_rows, c.max_order, c.block_samples, c.max_blocks, c.n_refs};
    }

    // (samples, gaps, complete blocks in the window)
    std::tuple<uint64_t, uint64_t, size_t> stats() const {
        vibid_oma_stats st;
        vibid_oma_get_stats(oma_.get(), &st);
        return {st.n_samples, st.n_gaps, st.blocks_complete};
    }

private:
    struct Deleter {
        void operator()(vibid_oma *p) const { vibid_oma_destroy(p); }
    };
    size_t nch_;
    std::unique_ptr<vibid_oma, Deleter> oma_;
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

// The outlier test of vibid/outlier.h (vibidd's, with its default threshold) over a capture,
// row by row: the values it takes out, as (row, column) pairs in row order.
std::vector<std::tuple<size_t, size_t>> outliers(nb::ndarray<const double, nb::ndim<2>, nb::device::cpu> data) {
    const size_t n = data.shape(0), nc = data.shape(1);
    vibid_outlier_config cfg;
    vibid_outlier_config_init(&cfg, nc);
    std::unique_ptr<vibid_outlier, void (*)(vibid_outlier *)> det(vibid_outlier_create(&cfg), vibid_outlier_destroy);
    if (!det) throw VibidError(vibid_last_error());
    std::vector<std::tuple<size_t, size_t>> out;
    const double *base = data.data();
    const int64_t rs = data.stride(0), cs = data.stride(1);
    {
        nb::gil_scoped_release release;
        std::vector<double> sample(nc);
        std::vector<unsigned char> mark(nc);
        size_t row = 0;  // of the next released sample
        for (size_t k = 0; k <= n; ++k) {
            size_t nr = 0;
            if (k < n) {
                for (size_t c = 0; c < nc; ++c) sample[c] = base[k * rs + c * cs];
                vibid_outlier_push(det.get(), sample.data(), &nr);
            } else {
                vibid_outlier_flush(det.get(), &nr);
            }
            for (size_t i = 0; i < nr; ++i, ++row) {
                size_t no = 0;
                vibid_outlier_released(det.get(), i, nullptr, mark.data(), &no);
                for (size_t c = 0; no && c < nc; ++c)
                    if (mark[c]) out.emplace_back(row, c);
            }
        }
    }
    return out;
}

// The regression the estimators fit (regressor.h: the same differences and pre-filter),
// run over the capture: the sample index each row describes (k - latency), the regressors
// X (rows x m equations, p columns: row r * m + i is equation i of row r, column-major) and
// the targets Y (rows * m). Structured form only: the ZOH form's coefficients are not the
// stand's parameters. For the equation errors of the report (stand_residuals) and the
// first-stage strength of the instrumental variables (vibid/_adequacy.py), which are
// products of these in numpy.
std::tuple<std::vector<long>, Array2, Array1> stand_regression(const Stand &st,
                                                               nb::ndarray<const double, nb::ndim<2>, nb::device::cpu> data,
                                                               double prefilter_hz, unsigned order) {
    const size_t n = data.shape(0), nc = data.shape(1), p = st.dims().n_params;
    if (nc != st.dims().n_channels)
        throw std::invalid_argument("regression: " + std::to_string(nc) + " columns for " +
                                    std::to_string(st.dims().n_channels) + " channels");
    std::unique_ptr<vibid_regressor, void (*)(vibid_regressor *)> reg(
        vibid_regressor_create_order(st.model(), 1.0 / st.sample_rate(), prefilter_hz, order), vibid_regressor_destroy);
    if (!reg) throw VibidError(vibid_last_error());  // it names the function and the argument
    vibid_regressor_dims rd{};
    vibid_status s = vibid_regressor_get_dims(reg.get(), &rd);
    if (s != VIBID_OK) raise_status("vibid_regressor_get_dims", s);
    if (rd.n_outputs != 1 || rd.n_regressors != p)
        throw VibidError("regression: the stand's regression is the ZOH difference form, whose coefficients are not "
                         "the stand's parameters; no equations of the structured form");
    const size_t m = rd.n_equations;
    std::vector<double> x(p * m), y(m), xs, ys;
    std::vector<long> rows;
    xs.reserve(n * m * p);
    ys.reserve(n * m);
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
            xs.insert(xs.end(), x.begin(), x.end());  // x[l + i * p]: equation i, regressor l
            ys.insert(ys.end(), y.begin(), y.end());
        }
    }
    if (s != VIBID_OK) raise_status(("vibid_regressor_push (row " + std::to_string(bad_row) + ")").c_str(), s);
    // xs is row-major ((rows * m) x p); the numpy array is column-major: transpose.
    const size_t nr = ys.size();
    std::vector<double> cm(nr * p);
    for (size_t r = 0; r < nr; ++r)
        for (size_t l = 0; l < p; ++l) cm[r + l * nr] = xs[r * p + l];
    return {rows, to_numpy(std::move(cm), nr, p), to_numpy(std::move(ys))};
}

// The model at theta driven by the capture's measured inputs (vibid_model_simulate,
// vibid/simulate.h: RK4 with `substeps` steps per sample, smooth inputs cubic Hermite between
// samples, held inputs constant, disturbances zero, the start at sample 2 from the measured
// state). Returns the channels in the model's layout: node channels simulated, input
// channels as measured, rows 0 and 1 NaN.
Array2 stand_simulate(const Stand &st, const std::vector<double> &th, nb::ndarray<const double, nb::ndim<2>, nb::device::cpu> data,
                      unsigned substeps) {
    check_theta(st, th, "simulate");
    const vibid_model_dims &dm = st.dims();
    const size_t N = data.shape(0), nc = data.shape(1);
    if (nc != dm.n_channels)
        throw std::invalid_argument("simulate: " + std::to_string(nc) + " columns for " +
                                    std::to_string(dm.n_channels) + " channels");
    if (substeps < 1 || substeps > 1000) throw std::invalid_argument("simulate: substeps in 1..1000");
    if (N < 5) throw std::invalid_argument("simulate: at least 5 samples are needed");
    const int64_t rs = data.stride(0), cs = data.stride(1);
    const double *base = data.data();
    std::vector<double> in(N * nc), out(N * nc);  // column-major, as the library takes them
    for (size_t c = 0; c < nc; ++c)
        for (size_t k = 0; k < N; ++k) in[k + c * N] = base[k * rs + c * cs];
    vibid_status s;
    {
        nb::gil_scoped_release release;
        s = vibid_model_simulate(st.model(), th.data(), 1.0 / st.sample_rate(), N, in.data(), substeps, out.data());
    }
    if (s != VIBID_OK) raise_status("vibid_model_simulate", s);
    return to_numpy(std::move(out), N, nc);
}

// The model's FRFs at theta (vibid_model_frf, vibid/modal.h): (re, im), each n_exc x
// n_channels x n_freq flattened (C order), the sampled zero-order hold's factor applied to
// held excitations when sample_time > 0.
std::tuple<Array1, Array1> stand_frf(const Stand &st, const std::vector<double> &th, const std::vector<double> &freq_hz,
                                     double sample_time) {
    check_theta(st, th, "frf");
    const vibid_model_dims &dm = st.dims();
    const size_t ne = dm.n_inputs + (dm.has_base ? 1 : 0), n = freq_hz.size() * dm.n_channels * ne;
    std::vector<double> re(n), im(n);
    const vibid_status s =
        vibid_model_frf(st.model(), th.data(), sample_time, freq_hz.size(), freq_hz.data(), re.data(), im.data());
    if (s != VIBID_OK) raise_status("vibid_model_frf", s);
    return {to_numpy(std::move(re)), to_numpy(std::move(im))};
}

// ---- Yardstick of python/bench/bench_python.py (issue 13) ----
// identify(stand, data, method) done by a C program: vibid_ident_create with the same
// config, every sample through vibid_ident_push in one loop from an interleaved buffer
// already in memory (as an acquisition loop holds samples), vibid_ident_estimate, destroy.
// The buffer is filled before the clock starts; the clock (steady_clock) runs in C++ with
// the GIL released, so Python time / this time isolates the binding's and the Python
// layer's overhead. Returns (seconds, theta, se) so the benchmark can check that both did
// the same work (push_block is this loop, so the numbers must be identical).
std::tuple<double, std::vector<double>, std::vector<double>> bench_identify_c(
    const Stand &stand, nb::ndarray<const double, nb::ndim<2>, nb::device::cpu> data, int estimator,
    double forgetting, double prefilter_hz, size_t iv_lag) {
    const size_t n = data.shape(0), nc = data.shape(1), p = stand.dims().n_params;
    if (nc != stand.dims().n_channels)
        throw std::invalid_argument("bench_identify_c: " + std::to_string(nc) + " columns for " +
                                    std::to_string(stand.dims().n_channels) + " channels");
    const double *base = data.data();
    const int64_t rs = data.stride(0), cs = data.stride(1);
    std::vector<double> theta(p, NAN), se(p, NAN);
    double seconds = 0;
    vibid_status s = VIBID_OK;
    std::string what, create_error;
    {
        nb::gil_scoped_release release;
        std::vector<double> buf(n * nc);
        for (size_t k = 0; k < n; ++k)
            for (size_t c = 0; c < nc; ++c) buf[k * nc + c] = base[k * rs + c * cs];
        const auto t0 = std::chrono::steady_clock::now();
        vibid_ident_config cfg;
        vibid_ident_config_init(&cfg, 1.0 / stand.sample_rate());
        cfg.estimator = static_cast<vibid_estimator>(estimator);
        cfg.forgetting = forgetting;
        cfg.prefilter_hz = prefilter_hz;
        cfg.iv_lag = iv_lag;
        vibid_ident *id = vibid_ident_create(stand.model(), &cfg);
        if (!id) {
            create_error = vibid_last_error();
        } else {
            for (size_t k = 0; k < n && s == VIBID_OK; ++k) s = vibid_ident_push(id, buf.data() + k * nc);
            what = "vibid_ident_push";
            if (s == VIBID_OK) {
                vibid_ident_info info{};
                s = vibid_ident_estimate(id, theta.data(), se.data(), &info);
                what = "vibid_ident_estimate";
            }
            vibid_ident_destroy(id);
        }
        seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    }
    if (!create_error.empty()) throw VibidError(create_error);
    if (s != VIBID_OK) raise_status(what.c_str(), s);
    return {seconds, std::move(theta), std::move(se)};
}

// ---- Estimator classes (issue 13): vibid.LeastSquares, RLS, IV, RecursiveIV ----
// One C++ class per C handle of lsq.h, rls.h and iv.h, as thin as the rest: shapes are
// checked and arrays handed over; every number is computed by the library. Block calls
// take numpy arrays of any strides. lsq.h and iv.h take whole column-major blocks: an
// array that is column-major already goes to the C call as it is, any other layout is
// gathered once (column_major below). rls.h and riv take one sample at a time: the loop
// over the block's rows runs here, reading each row through the caller's strides.
// Every call into the library releases the GIL and takes the object's own mutex: a handle
// is not thread-safe (common.h), so two Python threads using one object are serialized,
// while threads using different objects run in parallel.

using AnyArray1 = nb::ndarray<const double, nb::ndim<1>, nb::device::cpu>;
using AnyArray2 = nb::ndarray<const double, nb::ndim<2>, nb::device::cpu>;
using AnyArray3 = nb::ndarray<const double, nb::ndim<3>, nb::device::cpu>;

// GIL released first, then the object's mutex: a thread never waits for the mutex while
// holding the GIL (the holder may need the GIL to return). Destroyed in reverse order.
struct Unlocked {
    nb::gil_scoped_release release;
    std::lock_guard<std::mutex> lock;
    explicit Unlocked(std::mutex &m) : lock(m) {}
};

std::string shape_str(size_t a, size_t b) { return "(" + std::to_string(a) + ", " + std::to_string(b) + ")"; }

// ValueError unless a is rows x cols; names the method, the argument and what it needs.
void need_shape(const char *method, const char *name, const AnyArray2 &a, size_t rows, size_t cols,
                const char *rows_says) {
    if (a.shape(0) != rows || a.shape(1) != cols)
        throw std::invalid_argument(std::string(method) + ": " + name + " has shape " +
                                    shape_str(a.shape(0), a.shape(1)) + ", needs " + shape_str(rows, cols) + " (" +
                                    rows_says + ")");
}

// The r x c array a as the C API's column-major block. No copy where a is column-major
// already: numpy order "F", and any array with one column (a 1-D array seen as (n, 1)).
// Copied into buf (once, r x c doubles) for every other layout: numpy's default C order
// with c > 1, slices with a step, other views. Runs without the GIL (reads the buffer only).
const double *column_major(const AnyArray2 &a, std::vector<double> &buf) {
    const size_t r = a.shape(0), c = a.shape(1);
    const int64_t rs = a.stride(0), cs = a.stride(1);
    if ((rs == 1 || r <= 1) && (cs == static_cast<int64_t>(r) || c <= 1)) return a.data();
    buf.resize(r * c);
    const double *base = a.data();
    for (size_t j = 0; j < c; ++j)
        for (size_t k = 0; k < r; ++k)
            buf[k + j * r] = base[static_cast<int64_t>(k) * rs + static_cast<int64_t>(j) * cs];
    return buf.data();
}

const double *contiguous(const AnyArray1 &a, std::vector<double> &buf) {
    if (a.stride(0) == 1 || a.shape(0) <= 1) return a.data();
    buf.resize(a.shape(0));
    for (size_t k = 0; k < a.shape(0); ++k) buf[k] = a.data()[static_cast<int64_t>(k) * a.stride(0)];
    return buf.data();
}

// Row k of an (n x a x b) array as the column-major b x a matrix the recursive C calls take
// (x: p x m from X[k] of shape (m, p); y: m x q from Y[k] of shape (m, q) when transposed
// is false). Points into the array where its strides already are that layout (a C-order
// (n, p) regressor block seen as (n, 1, p): each row is p consecutive doubles), else
// gathers the row into buf (size a * b).
const double *sample_of(const AnyArray3 &A, size_t k, bool transposed, std::vector<double> &buf) {
    const size_t a = A.shape(1), b = A.shape(2);
    const int64_t s1 = A.stride(1), s2 = A.stride(2);
    const double *row = A.data() + static_cast<int64_t>(k) * A.stride(0);
    // transposed (x): element (i, j) of the p x m result is A[k, j, i]: needs s2 == 1, s1 == b.
    // not transposed (y): element (j, l) of the m x q result is A[k, j, l]: needs s1 == 1, s2 == a.
    const bool direct = transposed ? (s2 == 1 || b <= 1) && (s1 == static_cast<int64_t>(b) || a <= 1)
                                   : (s1 == 1 || a <= 1) && (s2 == static_cast<int64_t>(a) || b <= 1);
    if (direct) return row;
    for (size_t j = 0; j < a; ++j)
        for (size_t i = 0; i < b; ++i) {
            const double v = row[static_cast<int64_t>(j) * s1 + static_cast<int64_t>(i) * s2];
            if (transposed) buf[i + j * b] = v;
            else buf[j + i * a] = v;
        }
    return buf.data();
}

// Whether row k of A holds only finite values. The recursive block calls scan the whole
// block first and refuse a block with a NaN or Inf before its first update, so that it
// leaves the estimator as it was (the C calls guarantee that per sample only).
bool row_finite(const AnyArray3 &A, size_t k) {
    const double *row = A.data() + static_cast<int64_t>(k) * A.stride(0);
    for (size_t j = 0; j < A.shape(1); ++j)
        for (size_t i = 0; i < A.shape(2); ++i)
            if (!std::isfinite(row[static_cast<int64_t>(j) * A.stride(1) + static_cast<int64_t>(i) * A.stride(2)]))
                return false;
    return true;
}

// The message of a recursive block call that failed at row k: which rows took effect.
[[noreturn]] void raise_row(const char *function, size_t k, bool prescan, vibid_status s) {
    std::string what = std::string(function) + " (row " + std::to_string(k) +
                       (prescan ? "; the block was refused before its first row, the estimator is unchanged)"
                        : k == 0 ? "; no row of the block applied, the estimator is unchanged)"
                                 : "; rows 0.." + std::to_string(k - 1) +
                                       " of the block applied, the estimator is as after row " +
                                       std::to_string(k - 1) + ")");
    raise_status(what.c_str(), s);
}

// ---- Output error (output_error.h, issue 29) ----
// The stand's model simulated by the output-error fit's own simulator (vibid_oe_simulate:
// linear stands exactly, cubic ones by RK4 with the fit's step doubling), for
// Result.simulate / Result.validate and auto's held-out comparison (vibid/_adequacy.py),
// and the fit itself (vibid_oe_fit; python/bench/bench_oe.py and the analyst comparison of
// the tests). As thin as the rest: shapes are checked, arrays handed over.
class Oe {
public:
    Oe(const Stand &st, bool offsets) : dims_(st.dims()) {
        vibid_oe_config cfg;
        vibid_oe_config_init(&cfg, 1.0 / st.sample_rate());
        cfg.offsets = offsets ? 1 : 0;
        vibid_oe *o = vibid_oe_create(st.model(), &cfg);
        if (!o) throw VibidError(vibid_last_error());  // names the function and the reason
        oe_.reset(o);
        size_t ny = 0;
        vibid_status s = vibid_oe_dims(o, &ny, nullptr);
        if (s != VIBID_OK) raise_status("vibid_oe_dims", s);
        resp_.resize(ny);
        s = vibid_oe_dims(o, &ny, resp_.data());
        if (s != VIBID_OK) raise_status("vibid_oe_dims", s);
    }

    // The response channels' indices in the sample (the offsets' order).
    std::vector<size_t> response_channels() const { return resp_; }

    // n_samples x n_response simulated response channels (offsets added when given).
    Array2 simulate(const std::vector<double> &theta, const std::optional<std::vector<double>> &x0,
                    const std::optional<std::vector<double>> &offsets, const AnyArray2 &data) {
        check_vector("simulate", "theta", theta, dims_.n_params, true);
        if (x0) check_vector("simulate", "x0", *x0, 2 * dims_.n_dof, false);
        if (offsets) check_vector("simulate", "offsets", *offsets, resp_.size(), false);
        const size_t n = data.shape(0), ny = resp_.size();
        if (data.shape(1) != dims_.n_channels)
            throw std::invalid_argument("simulate: data has " + std::to_string(data.shape(1)) + " columns for " +
                                        std::to_string(dims_.n_channels) + " channels");
        std::vector<double> out(n * ny), buf;
        vibid_status s;
        {
            Unlocked u(mutex_);
            s = vibid_oe_simulate(oe_.get(), theta.data(), x0 ? x0->data() : nullptr,
                                  offsets ? offsets->data() : nullptr, n, column_major(data, buf), out.data());
        }
        if (s != VIBID_OK) raise_status("vibid_oe_simulate", s);
        return to_numpy(std::move(out), n, ny);
    }

    // The fit from the start vectors (p x n_starts); a failed fit is not raised: status,
    // message and the best parameters found are in the dict (output_error.h).
    nb::dict fit(const AnyArray2 &data, const AnyArray2 &starts) {
        const size_t n = data.shape(0), p = dims_.n_params, ny = resp_.size(), n2 = 2 * dims_.n_dof;
        if (data.shape(1) != dims_.n_channels)
            throw std::invalid_argument("fit: data has " + std::to_string(data.shape(1)) + " columns for " +
                                        std::to_string(dims_.n_channels) + " channels");
        if (starts.shape(0) != p || starts.shape(1) < 1)
            throw std::invalid_argument("fit: starts has shape " + shape_str(starts.shape(0), starts.shape(1)) +
                                        ", needs (" + std::to_string(p) + ", n_starts >= 1)");
        std::vector<double> th(p), se(p), cov(p * p), off(ny), off_se(ny), x0(n2), b1, b2;
        vibid_oe_fit_info info{};
        vibid_status s, rs;
        std::string message;
        {
            Unlocked u(mutex_);
            s = vibid_oe_fit(oe_.get(), n, column_major(data, b1), starts.shape(1), column_major(starts, b2));
            if (s != VIBID_OK) message = vibid_last_error();
            rs = vibid_oe_result(oe_.get(), th.data(), se.data(), cov.data(), off.data(), off_se.data(), x0.data(),
                                 &info);
        }
        if (rs != VIBID_OK) raise_status(("vibid_oe_fit: " + message + "; vibid_oe_result").c_str(), rs);
        nb::dict d;
        d["status"] = static_cast<int>(s);
        d["message"] = message;
        d["theta"] = to_numpy(std::move(th)).cast();
        d["se"] = to_numpy(std::move(se)).cast();
        d["covariance"] = to_numpy(std::move(cov), p, p).cast();
        d["offsets"] = to_numpy(std::move(off)).cast();
        d["offsets_se"] = to_numpy(std::move(off_se)).cast();
        d["x0"] = to_numpy(std::move(x0)).cast();
        d["failure"] = info.failure;
        d["iterations"] = info.iterations;
        d["start"] = info.start;
        d["n_samples"] = info.n_samples;
        d["n_blocks"] = info.n_blocks;
        d["cost"] = info.cost;
        d["rcond"] = info.rcond;
        if (dims_.n_disturbances) {  // the prediction-error fit's noise intensities
            const size_t nw = dims_.n_disturbances;
            std::vector<double> wsd(nw), wse(nw), vsd(ny), vse(ny);
            rs = vibid_oe_noise(oe_.get(), wsd.data(), wse.data(), vsd.data(), vse.data());
            if (rs != VIBID_OK) raise_status("vibid_oe_noise", rs);
            d["disturbance_std"] = to_numpy(std::move(wsd)).cast();
            d["disturbance_se"] = to_numpy(std::move(wse)).cast();
            d["noise_std"] = to_numpy(std::move(vsd)).cast();
            d["noise_se"] = to_numpy(std::move(vse)).cast();
        }
        return d;
    }

    // The last prediction-error fit's one-step predictor over data (vibid_oe_predict):
    // (innovations n_samples x n_response, their covariance n_response x n_response).
    nb::tuple predict(const AnyArray2 &data) {
        const size_t n = data.shape(0), ny = resp_.size();
        if (data.shape(1) != dims_.n_channels)
            throw std::invalid_argument("predict: data has " + std::to_string(data.shape(1)) + " columns for " +
                                        std::to_string(dims_.n_channels) + " channels");
        std::vector<double> innov(n * ny), S(ny * ny), buf;
        vibid_status s;
        {
            Unlocked u(mutex_);
            s = vibid_oe_predict(oe_.get(), n, column_major(data, buf), innov.data(), S.data());
        }
        if (s != VIBID_OK) raise_status("vibid_oe_predict", s);
        return nb::make_tuple(to_numpy(std::move(innov), n, ny), to_numpy(std::move(S), ny, ny));
    }

private:
    static void check_vector(const char *method, const char *name, const std::vector<double> &v, size_t want,
                             bool finite) {
        if (v.size() != want)
            throw std::invalid_argument(std::string(method) + ": " + name + " has " + std::to_string(v.size()) +
                                        " values, needs " + std::to_string(want));
        if (finite)
            for (double x : v)
                if (!std::isfinite(x)) throw std::invalid_argument(std::string(method) + ": " + name + " is not finite");
    }
    struct Deleter {
        void operator()(vibid_oe *o) const { vibid_oe_destroy(o); }
    };
    vibid_model_dims dims_;
    std::vector<size_t> resp_;
    std::unique_ptr<vibid_oe, Deleter> oe_;
    std::mutex mutex_;
};

class Lsq {
public:
    Lsq(size_t p, size_t q, std::optional<double> rank_tol) {
        vibid_lsq *h = vibid_lsq_create(p, q);
        if (!h) throw VibidError(vibid_last_error());  // names the function and the argument
        h_.reset(h);
        p_ = p;
        q_ = q;
        if (rank_tol) {
            vibid_status s = vibid_lsq_set_rank_tolerance(h, *rank_tol);
            if (s != VIBID_OK) raise_status("vibid_lsq_set_rank_tolerance", s);
        }
    }

    void add(const AnyArray2 &X, const AnyArray2 &Y, const std::optional<AnyArray1> &w) {
        const size_t n = X.shape(0);
        need_shape("LeastSquares.add", "X", X, n, p_, "n_rows x p");
        need_shape("LeastSquares.add", "Y", Y, n, q_, "n_rows x q, the rows of X");
        if (w && w->shape(0) != n)
            throw std::invalid_argument("LeastSquares.add: weights has " + std::to_string(w->shape(0)) +
                                        " entries for " + std::to_string(n) + " rows");
        if (n == 0) return;  // an empty block adds nothing (the C call would refuse n_rows = 0)
        vibid_status s;
        {
            Unlocked u(mu_);
            std::vector<double> xb, yb, wb;
            s = vibid_lsq_add_rows(h_.get(), n, column_major(X, xb), column_major(Y, yb),
                                   w ? contiguous(*w, wb) : nullptr);
        }
        if (s != VIBID_OK) raise_status("vibid_lsq_add_rows", s);
    }

    void add_correlated(const AnyArray2 &X, const AnyArray2 &Y, const AnyArray2 &Sigma) {
        const size_t n = X.shape(0);
        need_shape("LeastSquares.add_correlated", "X", X, n, p_, "n_rows x p");
        need_shape("LeastSquares.add_correlated", "Y", Y, n, q_, "n_rows x q, the rows of X");
        need_shape("LeastSquares.add_correlated", "Sigma", Sigma, n, n, "n_rows x n_rows");
        if (n == 0) return;
        vibid_status s;
        {
            Unlocked u(mu_);
            std::vector<double> xb, yb, sb;
            s = vibid_lsq_add_correlated(h_.get(), n, column_major(X, xb), column_major(Y, yb),
                                         column_major(Sigma, sb));
        }
        if (s != VIBID_OK) raise_status("vibid_lsq_add_correlated", s);
    }

    Array2 solve() {
        std::vector<double> theta(p_ * q_);
        vibid_status s;
        {
            Unlocked u(mu_);
            s = vibid_lsq_solve(h_.get(), theta.data(), nullptr);
        }
        if (s != VIBID_OK) raise_status("vibid_lsq_solve", s);
        return to_numpy(std::move(theta), p_, q_);
    }

    // (n_rows, rank, rcond, sum_weights) of vibid_lsq_info, from a solve (the library's only
    // source of it; O(p^3)). Before any row with weight > 0: (0, 0, nan, 0).
    std::tuple<size_t, size_t, double, double> info() {
        std::vector<double> theta(p_ * q_);
        vibid_lsq_info in{};
        vibid_status s;
        {
            Unlocked u(mu_);
            s = vibid_lsq_solve(h_.get(), theta.data(), &in);
        }
        if (s == VIBID_E_INSUFFICIENT_DATA) return {0, 0, NAN, 0.0};
        if (s != VIBID_OK && s != VIBID_E_NOT_IDENTIFIABLE) raise_status("vibid_lsq_solve", s);
        return {in.n_rows, in.rank, in.rcond, in.sum_weights};
    }

    Array2 covariance() { return cov(true); }
    Array2 residual_covariance() { return cov(false); }

    Array2 stderr_() {
        std::vector<double> se(p_ * q_);
        vibid_status s;
        {
            Unlocked u(mu_);
            s = vibid_lsq_stderr(h_.get(), se.data());
        }
        if (s != VIBID_OK) raise_status("vibid_lsq_stderr", s);
        return to_numpy(std::move(se), p_, q_);
    }

    Array2 null_space() {
        std::vector<double> basis(p_ * p_);
        size_t k = 0;
        vibid_status s;
        {
            Unlocked u(mu_);
            s = vibid_lsq_null_space(h_.get(), basis.data(), p_, &k);
        }
        if (s != VIBID_OK) raise_status("vibid_lsq_null_space", s);
        basis.resize(p_ * k);
        return to_numpy(std::move(basis), p_, k);
    }

    void reset() {
        vibid_status s;
        {
            Unlocked u(mu_);
            s = vibid_lsq_reset(h_.get());
        }
        if (s != VIBID_OK) raise_status("vibid_lsq_reset", s);
    }

    size_t p() const { return p_; }
    size_t q() const { return q_; }

private:
    Array2 cov(bool param) {
        const size_t d = param ? p_ : q_;
        std::vector<double> c(d * d);
        vibid_status s;
        {
            Unlocked u(mu_);
            s = vibid_lsq_covariance(h_.get(), param ? c.data() : nullptr, param ? nullptr : c.data());
        }
        if (s != VIBID_OK) raise_status("vibid_lsq_covariance", s);
        return to_numpy(std::move(c), d, d);
    }
    struct Deleter {
        void operator()(vibid_lsq *p) const { vibid_lsq_destroy(p); }
    };
    std::unique_ptr<vibid_lsq, Deleter> h_;
    size_t p_ = 0, q_ = 0;
    std::mutex mu_;
};

class Iv {
public:
    Iv(size_t p, size_t q) {
        vibid_iv *h = vibid_iv_create(p, q);
        if (!h) throw VibidError(vibid_last_error());
        h_.reset(h);
        p_ = p;
        q_ = q;
    }

    void add(const AnyArray2 &X, const AnyArray2 &W, const AnyArray2 &Y, const std::optional<AnyArray1> &w) {
        const size_t n = X.shape(0);
        need_shape("IV.add", "X", X, n, p_, "n_rows x p");
        need_shape("IV.add", "Z", W, n, p_, "n_rows x p, as X");
        need_shape("IV.add", "Y", Y, n, q_, "n_rows x q, the rows of X");
        if (w && w->shape(0) != n)
            throw std::invalid_argument("IV.add: weights has " + std::to_string(w->shape(0)) + " entries for " +
                                        std::to_string(n) + " rows");
        if (n == 0) return;
        vibid_status s;
        {
            Unlocked u(mu_);
            std::vector<double> xb, zb, yb, wb;
            s = vibid_iv_add_rows(h_.get(), n, column_major(X, xb), column_major(W, zb), column_major(Y, yb),
                                  w ? contiguous(*w, wb) : nullptr);
        }
        if (s != VIBID_OK) raise_status("vibid_iv_add_rows", s);
    }

    Array2 solve() {
        std::vector<double> theta(p_ * q_);
        vibid_status s;
        {
            Unlocked u(mu_);
            s = vibid_iv_solve(h_.get(), theta.data(), nullptr);
        }
        if (s != VIBID_OK) raise_status("vibid_iv_solve", s);
        return to_numpy(std::move(theta), p_, q_);
    }

    std::tuple<size_t, size_t, double, double> info() {
        std::vector<double> theta(p_ * q_);
        vibid_lsq_info in{};
        vibid_status s;
        {
            Unlocked u(mu_);
            s = vibid_iv_solve(h_.get(), theta.data(), &in);
        }
        if (s == VIBID_E_INSUFFICIENT_DATA) return {0, 0, NAN, 0.0};
        if (s != VIBID_OK && s != VIBID_E_NOT_IDENTIFIABLE) raise_status("vibid_iv_solve", s);
        return {in.n_rows, in.rank, in.rcond, in.sum_weights};
    }

    Array2 stderr_() {
        std::vector<double> se(p_ * q_);
        vibid_status s;
        {
            Unlocked u(mu_);
            s = vibid_iv_stderr(h_.get(), se.data());
        }
        if (s != VIBID_OK) raise_status("vibid_iv_stderr", s);
        return to_numpy(std::move(se), p_, q_);
    }

    void reset() {
        vibid_status s;
        {
            Unlocked u(mu_);
            s = vibid_iv_reset(h_.get());
        }
        if (s != VIBID_OK) raise_status("vibid_iv_reset", s);
    }

    size_t p() const { return p_; }
    size_t q() const { return q_; }

private:
    struct Deleter {
        void operator()(vibid_iv *p) const { vibid_iv_destroy(p); }
    };
    std::unique_ptr<vibid_iv, Deleter> h_;
    size_t p_ = 0, q_ = 0;
    std::mutex mu_;
};

class Rls {
public:
    Rls(size_t p, size_t q, size_t m, int form, double forgetting, double alpha, bool trace_bound,
        std::optional<double> trace_max) {
        vibid_rls_config cfg;
        vibid_rls_config_init(&cfg, p, q);
        cfg.n_equations = m;
        cfg.form = static_cast<vibid_rls_form>(form);
        cfg.forgetting = forgetting;
        cfg.alpha = alpha;
        // config_init's default trace_max is p / alpha for its own alpha: recompute for ours.
        cfg.trace_max = trace_max ? *trace_max : static_cast<double>(p) / alpha;
        cfg.windup = trace_bound ? VIBID_RLS_WINDUP_TRACE_BOUND : VIBID_RLS_WINDUP_NONE;
        vibid_rls *h = vibid_rls_create(&cfg);
        if (!h) throw VibidError(vibid_last_error());
        h_.reset(h);
        p_ = p;
        q_ = q;
        m_ = m;
    }

    // X (n, m, p), Y (n, m, q): sample k is x = X[k]^T (p x m), y = Y[k] (m x q).
    void update(const AnyArray3 &X, const AnyArray3 &Y) {
        const size_t n = X.shape(0);
        check3("RLS.update", X, Y, n);
        vibid_status s = VIBID_OK;
        size_t k = 0;
        bool prescan = false;
        {
            Unlocked u(mu_);
            std::vector<double> xb(p_ * m_), yb(m_ * q_);
            while (k < n && row_finite(X, k) && row_finite(Y, k)) ++k;
            if (k < n) {
                // The library refuses the bad row with its own message, on the untouched
                // estimator (rls.h: a refused sample leaves it exactly as it was).
                prescan = true;
                s = vibid_rls_update(h_.get(), sample_of(X, k, true, xb), sample_of(Y, k, false, yb));
                if (s == VIBID_OK) s = VIBID_E_INTERNAL;  // rls.h promises VIBID_E_NONFINITE
            } else {
                for (k = 0; k < n; ++k) {
                    s = vibid_rls_update(h_.get(), sample_of(X, k, true, xb), sample_of(Y, k, false, yb));
                    if (s != VIBID_OK) break;
                }
            }
        }
        if (s != VIBID_OK) raise_row("vibid_rls_update", k, prescan, s);
    }

    // Predictions for X (n, m, p): n * m * q values in C order of (n, m, q).
    Array1 predict(const AnyArray3 &X) {
        const size_t n = X.shape(0);
        if (X.shape(1) != m_ || X.shape(2) != p_)
            throw std::invalid_argument("RLS.predict: X has " + std::to_string(X.shape(2)) + " columns per equation and " +
                                        std::to_string(X.shape(1)) + " equations, needs p = " + std::to_string(p_) +
                                        ", m = " + std::to_string(m_));
        std::vector<double> out(n * m_ * q_);
        vibid_status s = VIBID_OK;
        size_t k = 0;
        {
            Unlocked u(mu_);
            std::vector<double> xb(p_ * m_), y(m_ * q_);
            for (; k < n; ++k) {
                s = vibid_rls_predict(h_.get(), sample_of(X, k, true, xb), y.data());
                if (s != VIBID_OK) break;
                for (size_t j = 0; j < m_; ++j)
                    for (size_t l = 0; l < q_; ++l) out[(k * m_ + j) * q_ + l] = y[j + l * m_];
            }
        }
        if (s != VIBID_OK) raise_status(("vibid_rls_predict (row " + std::to_string(k) + ")").c_str(), s);
        return to_numpy(std::move(out));
    }

    Array2 theta() { return get(p_, q_, vibid_rls_theta, "vibid_rls_theta"); }
    Array2 covariance() { return get(p_, p_, vibid_rls_covariance, "vibid_rls_covariance"); }
    Array2 residual_covariance() {
        return get(q_, q_, vibid_rls_residual_covariance, "vibid_rls_residual_covariance");
    }
    Array2 stderr_() { return get(p_, q_, vibid_rls_stderr, "vibid_rls_stderr"); }

    // (n_samples, n_eff, trace_p, min_d, last_forgetting) of vibid_rls_stats.
    std::tuple<unsigned long long, double, double, double, double> stats() {
        vibid_rls_stats st{};
        vibid_status s;
        {
            Unlocked u(mu_);
            s = vibid_rls_get_stats(h_.get(), &st);
        }
        if (s != VIBID_OK) raise_status("vibid_rls_get_stats", s);
        return {st.n_samples, st.n_eff, st.trace_p, st.min_d, st.last_forgetting};
    }

    void reset() { call(vibid_rls_reset, "vibid_rls_reset"); }

    void set_prior(const std::optional<AnyArray2> &theta0, const std::optional<AnyArray2> &P0) {
        if (theta0) need_shape("RLS.set_prior", "theta0", *theta0, p_, q_, "p x q");
        if (P0) need_shape("RLS.set_prior", "P0", *P0, p_, p_, "p x p");
        vibid_status s;
        {
            Unlocked u(mu_);
            std::vector<double> tb, pb;
            s = vibid_rls_set_prior(h_.get(), theta0 ? column_major(*theta0, tb) : nullptr,
                                    P0 ? column_major(*P0, pb) : nullptr);
        }
        if (s != VIBID_OK) raise_status("vibid_rls_set_prior", s);
    }

    void set_equation_covariance(const std::optional<AnyArray2> &Sigma) {
        if (Sigma) need_shape("RLS.set_equation_covariance", "Sigma", *Sigma, m_, m_, "m x m");
        vibid_status s;
        {
            Unlocked u(mu_);
            std::vector<double> sb;
            s = vibid_rls_set_equation_covariance(h_.get(), Sigma ? column_major(*Sigma, sb) : nullptr);
        }
        if (s != VIBID_OK) raise_status("vibid_rls_set_equation_covariance", s);
    }

    void set_adaptation(bool enabled) {
        vibid_status s;
        {
            Unlocked u(mu_);
            s = vibid_rls_set_adaptation(h_.get(), enabled ? 1 : 0);
        }
        if (s != VIBID_OK) raise_status("vibid_rls_set_adaptation", s);
    }

    size_t p() const { return p_; }
    size_t q() const { return q_; }
    size_t m() const { return m_; }

private:
    void check3(const char *method, const AnyArray3 &X, const AnyArray3 &Y, size_t n) const {
        if (X.shape(1) != m_ || X.shape(2) != p_)
            throw std::invalid_argument(std::string(method) + ": X has " + std::to_string(X.shape(2)) +
                                        " regressors in " + std::to_string(X.shape(1)) +
                                        " equations per row, needs p = " + std::to_string(p_) + " in m = " +
                                        std::to_string(m_));
        if (Y.shape(0) != n || Y.shape(1) != m_ || Y.shape(2) != q_)
            throw std::invalid_argument(std::string(method) + ": Y has " + std::to_string(Y.shape(0)) + " rows of " +
                                        std::to_string(Y.shape(1)) + " x " + std::to_string(Y.shape(2)) +
                                        ", needs " + std::to_string(n) + " rows (as X) of m x q = " +
                                        std::to_string(m_) + " x " + std::to_string(q_));
    }
    Array2 get(size_t r, size_t c, vibid_status (*f)(const vibid_rls *, double *), const char *name) {
        std::vector<double> v(r * c);
        vibid_status s;
        {
            Unlocked u(mu_);
            s = f(h_.get(), v.data());
        }
        if (s != VIBID_OK) raise_status(name, s);
        return to_numpy(std::move(v), r, c);
    }
    void call(vibid_status (*f)(vibid_rls *), const char *name) {
        vibid_status s;
        {
            Unlocked u(mu_);
            s = f(h_.get());
        }
        if (s != VIBID_OK) raise_status(name, s);
    }
    struct Deleter {
        void operator()(vibid_rls *p) const { vibid_rls_destroy(p); }
    };
    std::unique_ptr<vibid_rls, Deleter> h_;
    size_t p_ = 0, q_ = 0, m_ = 0;
    std::mutex mu_;
};

class Riv {
public:
    Riv(size_t p, size_t q, double forgetting, double alpha, bool trace_bound, std::optional<double> trace_max) {
        vibid_riv_config cfg;
        vibid_riv_config_init(&cfg, p, q);
        cfg.forgetting = forgetting;
        cfg.alpha = alpha;
        cfg.trace_bound = trace_bound ? 1 : 0;
        cfg.trace_max = trace_max ? *trace_max : static_cast<double>(p) / alpha;
        vibid_riv *h = vibid_riv_create(&cfg);
        if (!h) throw VibidError(vibid_last_error());
        h_.reset(h);
        p_ = p;
        q_ = q;
    }

    // X, Z (n, 1, p), Y (n, 1, q): one equation per sample (riv has m = 1).
    void update(const AnyArray3 &X, const AnyArray3 &W, const AnyArray3 &Y) {
        const size_t n = X.shape(0);
        if (X.shape(1) != 1 || X.shape(2) != p_ || W.shape(0) != n || W.shape(1) != 1 || W.shape(2) != p_ ||
            Y.shape(0) != n || Y.shape(1) != 1 || Y.shape(2) != q_)
            throw std::invalid_argument("RecursiveIV.update: X " + shape_str(X.shape(0), X.shape(2)) + ", Z " +
                                        shape_str(W.shape(0), W.shape(2)) + ", Y " +
                                        shape_str(Y.shape(0), Y.shape(2)) + ": need (n, p), (n, p), (n, q) with p = " +
                                        std::to_string(p_) + ", q = " + std::to_string(q_));
        vibid_status s = VIBID_OK;
        size_t k = 0;
        bool prescan = false;
        {
            Unlocked u(mu_);
            std::vector<double> xb(p_), wb(p_), yb(q_);
            while (k < n && row_finite(X, k) && row_finite(W, k) && row_finite(Y, k)) ++k;
            if (k < n) {
                prescan = true;
                s = vibid_riv_update(h_.get(), sample_of(X, k, true, xb), sample_of(W, k, true, wb),
                                     sample_of(Y, k, true, yb));
                if (s == VIBID_OK) s = VIBID_E_INTERNAL;  // iv.h promises VIBID_E_NONFINITE
            } else {
                for (k = 0; k < n; ++k) {
                    s = vibid_riv_update(h_.get(), sample_of(X, k, true, xb), sample_of(W, k, true, wb),
                                         sample_of(Y, k, true, yb));
                    if (s != VIBID_OK) break;
                }
            }
        }
        if (s != VIBID_OK) raise_row("vibid_riv_update", k, prescan, s);
    }

    Array2 theta() { return get(p_, q_, vibid_riv_theta, "vibid_riv_theta"); }
    Array2 covariance() { return get(p_, p_, vibid_riv_covariance, "vibid_riv_covariance"); }

    void reset() {
        vibid_status s;
        {
            Unlocked u(mu_);
            s = vibid_riv_reset(h_.get());
        }
        if (s != VIBID_OK) raise_status("vibid_riv_reset", s);
    }

    void set_prior(const std::optional<AnyArray2> &theta0, const std::optional<AnyArray2> &P0) {
        if (theta0) need_shape("RecursiveIV.set_prior", "theta0", *theta0, p_, q_, "p x q");
        if (P0) need_shape("RecursiveIV.set_prior", "P0", *P0, p_, p_, "p x p");
        vibid_status s;
        {
            Unlocked u(mu_);
            std::vector<double> tb, pb;
            s = vibid_riv_set_prior(h_.get(), theta0 ? column_major(*theta0, tb) : nullptr,
                                    P0 ? column_major(*P0, pb) : nullptr);
        }
        if (s != VIBID_OK) raise_status("vibid_riv_set_prior", s);
    }

    size_t p() const { return p_; }
    size_t q() const { return q_; }

private:
    Array2 get(size_t r, size_t c, vibid_status (*f)(const vibid_riv *, double *), const char *name) {
        std::vector<double> v(r * c);
        vibid_status s;
        {
            Unlocked u(mu_);
            s = f(h_.get(), v.data());
        }
        if (s != VIBID_OK) raise_status(name, s);
        return to_numpy(std::move(v), r, c);
    }
    struct Deleter {
        void operator()(vibid_riv *p) const { vibid_riv_destroy(p); }
    };
    std::unique_ptr<vibid_riv, Deleter> h_;
    size_t p_ = 0, q_ = 0;
    std::mutex mu_;
};

}  // namespace

#ifdef VIBID_HAVE_DRIVERS
// vibid_drivers.cpp: candump captures and vibid.replay (built only with the drivers).
void vibid_register_drivers(nb::module_ &m);
#endif
// vibid_formats.cpp: the capture-format registry (every build).
void vibid_register_formats(nb::module_ &m);

NB_MODULE(_core, m) {
    m.doc() = "vibid._core: nanobind binding of libvibid's C API (use the vibid package instead)";
    nb::exception<VibidError>(m, "VibidError", PyExc_RuntimeError);

    m.def("version", [] { return std::string(vibid_version_string()); });
    vibid_register_formats(m);
#ifdef VIBID_HAVE_DRIVERS
    vibid_register_drivers(m);
#endif
    // What this build holds (python/CMakeLists.txt): vibid/_drivers.py says how to get it.
#ifdef VIBID_HAVE_DRIVERS
    m.attr("HAVE_DRIVERS") = true;
#else
    m.attr("HAVE_DRIVERS") = false;
#endif
#ifdef VIBID_HAVE_DAEMON
    m.attr("HAVE_DAEMON") = true;
#else
    m.attr("HAVE_DAEMON") = false;
#endif

    m.def("oma_defaults", [] {
        vibid_oma_config c;
        vibid_oma_config_init(&c, 1.0, 1);
        nb::dict d;
        d["block_rows"] = c.block_rows;
        d["max_blocks"] = c.max_blocks;
        d["stab_freq"] = c.stab_freq;
        d["stab_damping"] = c.stab_damping;
        d["stab_mac"] = c.stab_mac;
        d["max_damping"] = c.max_damping;
        d["cluster_freq"] = c.cluster_freq;
        d["cluster_mac"] = c.cluster_mac;
        d["min_cluster_share"] = c.min_cluster_share;
        return d;
    });
    nb::class_<Oma>(m, "Oma")
        .def(nb::init<double, size_t, const std::vector<size_t> &, size_t, size_t, size_t, size_t, nb::dict>(),
             "sample_rate"_a, "n_channels"_a, "refs"_a, "block_rows"_a, "max_order"_a, "block_samples"_a,
             "max_blocks"_a, "thresholds"_a)
        .def("push", &Oma::push, "data"_a)
        .def("identify", &Oma::identify)
        .def("modes", &Oma::modes)
        .def("poles", &Oma::poles)
        .def("singular_values", &Oma::singular_values)
        .def("config", &Oma::config)
        .def("stats", &Oma::stats);

    nb::class_<Stand>(m, "Stand")
        .def(nb::init<const std::string &>(), "path"_a)
        .def_prop_ro("name", &Stand::name)
        .def_prop_ro("sample_rate", &Stand::sample_rate)
        .def_prop_ro("channels", &Stand::channels)
        .def_prop_ro("params", &Stand::params)
        .def_prop_ro("length_unit", [](const Stand &s) { return std::string(vibid_stand_length_unit(s.raw())); })
        .def_prop_ro("length_si", [](const Stand &s) { return vibid_stand_length_si(s.raw()); })
        .def_prop_ro("n_dof", [](const Stand &s) { return s.dims().n_dof; })
        .def_prop_ro("n_disturbances", [](const Stand &s) { return s.dims().n_disturbances; })
        .def_prop_ro("nonlinear", [](const Stand &s) { return s.dims().nonlinear != 0; });

    nb::class_<Ident>(m, "Ident")
        // keep_alive: the identification reads the stand's model (plausibility, modes).
        .def(nb::init<const Stand &, int, double, double, size_t>(), "stand"_a, "estimator"_a, "forgetting"_a,
             "prefilter_hz"_a, "iv_lag"_a, nb::keep_alive<1, 2>())
        .def("push", &Ident::push, "data"_a, "start"_a, "stop"_a)
        .def("innovations", &Ident::innovations, "data"_a, "start"_a, "stop"_a)
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
        .def("offsets", &Ident::offsets)
        .def("config", &Ident::config);

    // vibid check and the report (issue 13): see stand_identifiability and below.
    m.def("stand_identifiability", &stand_identifiability, "stand"_a);
    m.def("stand_channel_info", &stand_channel_info, "stand"_a);
    m.def("outliers", &outliers, "data"_a);  // vibid/outlier.h over a capture (identify)
    m.def("stand_regression", &stand_regression, "stand"_a, "data"_a, "prefilter_hz"_a, "order"_a);
    m.def("stand_simulate", &stand_simulate, "stand"_a, "theta"_a, "data"_a, "substeps"_a = 8);
    m.def("stand_frf", &stand_frf, "stand"_a, "theta"_a, "freq_hz"_a, "sample_time"_a);
    m.def("bench_identify_c", &bench_identify_c, "stand"_a, "data"_a, "estimator"_a, "forgetting"_a,
          "prefilter_hz"_a, "iv_lag"_a);  // python/bench/bench_python.py

    m.attr("QUALITY_SE_INVALID") = VIBID_QUALITY_SE_INVALID;
    m.attr("QUALITY_NOT_EXCITED") = VIBID_QUALITY_NOT_EXCITED;
    m.attr("QUALITY_REFINE_FAILED") = VIBID_QUALITY_REFINE_FAILED;
    m.attr("ESTIMATOR_LS") = static_cast<int>(VIBID_ESTIMATOR_LS);
    m.attr("ESTIMATOR_IV") = static_cast<int>(VIBID_ESTIMATOR_IV);
    m.attr("ESTIMATOR_RLS") = static_cast<int>(VIBID_ESTIMATOR_RLS);
    m.attr("ESTIMATOR_AUTO") = static_cast<int>(VIBID_ESTIMATOR_AUTO);
    m.attr("ESTIMATOR_EKF") = static_cast<int>(VIBID_ESTIMATOR_EKF);
    m.attr("ESTIMATOR_KF_RLS") = static_cast<int>(VIBID_ESTIMATOR_KF_RLS);
    m.attr("ESTIMATOR_OE") = static_cast<int>(VIBID_ESTIMATOR_OE);
    // The library's estimator names (identify.h), in the enum's order: list index = code.
    m.def("estimator_names", []() {
        std::vector<std::string> names;
        for (int k = 0; const char *name = vibid_estimator_name(static_cast<vibid_estimator>(k)); ++k)
            names.emplace_back(name);
        return names;
    });

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

    // Estimator classes (issue 13): the classes of vibid/_estimators.py wrap these. Arrays
    // arrive as float64 of any strides (the Python layer converts the dtype); see
    // column_major and sample_of for what is copied.
    nb::class_<Lsq>(m, "Lsq")
        .def(nb::init<size_t, size_t, std::optional<double>>(), "p"_a, "q"_a, "rank_tolerance"_a.none())
        .def("add", &Lsq::add, "X"_a, "Y"_a, "weights"_a.none())
        .def("add_correlated", &Lsq::add_correlated, "X"_a, "Y"_a, "Sigma"_a)
        .def("solve", &Lsq::solve)
        .def("info", &Lsq::info)
        .def("covariance", &Lsq::covariance)
        .def("residual_covariance", &Lsq::residual_covariance)
        .def("stderr", &Lsq::stderr_)
        .def("null_space", &Lsq::null_space)
        .def("reset", &Lsq::reset)
        .def_prop_ro("p", &Lsq::p)
        .def_prop_ro("q", &Lsq::q);

    nb::class_<Iv>(m, "Iv")
        .def(nb::init<size_t, size_t>(), "p"_a, "q"_a)
        .def("add", &Iv::add, "X"_a, "Z"_a, "Y"_a, "weights"_a.none())
        .def("solve", &Iv::solve)
        .def("info", &Iv::info)
        .def("stderr", &Iv::stderr_)
        .def("reset", &Iv::reset)
        .def_prop_ro("p", &Iv::p)
        .def_prop_ro("q", &Iv::q);

    nb::class_<Rls>(m, "Rls")
        .def(nb::init<size_t, size_t, size_t, int, double, double, bool, std::optional<double>>(), "p"_a, "q"_a,
             "m"_a, "form"_a, "forgetting"_a, "alpha"_a, "trace_bound"_a, "trace_max"_a.none())
        .def("update", &Rls::update, "X"_a, "Y"_a)
        .def("predict", &Rls::predict, "X"_a)
        .def("theta", &Rls::theta)
        .def("covariance", &Rls::covariance)
        .def("residual_covariance", &Rls::residual_covariance)
        .def("stderr", &Rls::stderr_)
        .def("stats", &Rls::stats)
        .def("reset", &Rls::reset)
        .def("set_prior", &Rls::set_prior, "theta0"_a.none(), "P0"_a.none())
        .def("set_equation_covariance", &Rls::set_equation_covariance, "Sigma"_a.none())
        .def("set_adaptation", &Rls::set_adaptation, "enabled"_a)
        .def_prop_ro("p", &Rls::p)
        .def_prop_ro("q", &Rls::q)
        .def_prop_ro("m", &Rls::m);

    nb::class_<Riv>(m, "Riv")
        .def(nb::init<size_t, size_t, double, double, bool, std::optional<double>>(), "p"_a, "q"_a, "forgetting"_a,
             "alpha"_a, "trace_bound"_a, "trace_max"_a.none())
        .def("update", &Riv::update, "X"_a, "Z"_a, "Y"_a)
        .def("theta", &Riv::theta)
        .def("covariance", &Riv::covariance)
        .def("reset", &Riv::reset)
        .def("set_prior", &Riv::set_prior, "theta0"_a.none(), "P0"_a.none())
        .def_prop_ro("p", &Riv::p)
        .def_prop_ro("q", &Riv::q);
    nb::class_<Oe>(m, "Oe")
        // vibid_oe_create copies the model: the stand may go first
        .def(nb::init<const Stand &, bool>(), "stand"_a, "offsets"_a = true)
        .def("response_channels", &Oe::response_channels)
        .def("simulate", &Oe::simulate, "theta"_a, "x0"_a.none(), "offsets"_a.none(), "data"_a)
        .def("fit", &Oe::fit, "data"_a, "starts"_a)
        .def("predict", &Oe::predict, "data"_a);

    m.attr("RLS_FORM_BIERMAN_UD") = static_cast<int>(VIBID_RLS_FORM_BIERMAN_UD);
    m.attr("RLS_FORM_COVARIANCE") = static_cast<int>(VIBID_RLS_FORM_COVARIANCE);
}
