// plausibility.cpp: physically impossible estimates (negative masses, stiffnesses or
// damping, modes at 0 Hz or beyond Nyquist, unstable or newly overdamped modes); see
// vibid/plausibility.h for the rules.
//
// The check reads the model's terms directly (model_internal.hpp) rather than through
// vibid_model_param_info: it must not throw or allocate, and the sign constraint of a
// full-matrix entry depends on whether it is a diagonal entry, which the term's structure
// says without parsing its name ("C1_2" is built in vibid_model_set_matrices from the
// same (i, j): a diagonal entry has one equation entry, an off-diagonal one two).
#include <vibid/modal.h>
#include <vibid/plausibility.h>

#include "api_guard.hpp"
#include "model_internal.hpp"

#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <vector>

using vibid::throw_error;

namespace {

// The rule bit of a parameter of this term whose value is <= 0, or 0 if the term may have
// any sign.
unsigned sign_rule(const vibid_model &m, const vibid::Term &t) {
    unsigned bit = 0;
    switch (t.kind) {
    case VIBID_PARAM_MASS: bit = VIBID_IMPLAUSIBLE_MASS; break;
    case VIBID_PARAM_DAMPING: bit = VIBID_IMPLAUSIBLE_DAMPING; break;
    case VIBID_PARAM_STIFFNESS: bit = VIBID_IMPLAUSIBLE_STIFFNESS; break;
    default: return 0;  // cubic coefficients and gains: any sign
    }
    if (m.full_matrix) {
        // Entry (i, j) of a symmetric matrix: one equation entry (row i, signal of
        // coordinate i) on the diagonal, two (rows i and j) off it.
        const bool diagonal = t.entries.size() == 1 && t.entries[0].row == t.entries[0].signal.a;
        if (!diagonal) return 0;
    }
    return bit;
}

const char *unit_of(vibid_param_kind k) {
    switch (k) {
    case VIBID_PARAM_MASS: return "kg";
    case VIBID_PARAM_DAMPING: return "N s/m";
    case VIBID_PARAM_STIFFNESS: return "N/m";
    case VIBID_PARAM_CUBIC: return "N/m^3";
    default: return "";
    }
}

const char *kind_word(vibid_param_kind k) {
    switch (k) {
    case VIBID_PARAM_MASS: return "mass";
    case VIBID_PARAM_DAMPING: return "damping";
    case VIBID_PARAM_STIFFNESS: return "stiffness";
    default: return "parameter";
    }
}

// Appends one "; "-separated clause to why (cut at cap - 1, always terminated).
struct Why {
    char *buf;
    std::size_t cap;
    std::size_t len = 0;
    void add(const char *fmt, ...) __attribute__((format(printf, 2, 3))) {
        if (!buf || cap == 0 || len + 1 >= cap) return;
        if (len > 0) {
            const int n = std::snprintf(buf + len, cap - len, "; ");
            len = std::min(cap - 1, len + static_cast<std::size_t>(n > 0 ? n : 0));
            if (len + 1 >= cap) return;
        }
        va_list ap;
        va_start(ap, fmt);
        const int n = std::vsnprintf(buf + len, cap - len, fmt, ap);
        va_end(ap);
        len = std::min(cap - 1, len + static_cast<std::size_t>(n > 0 ? n : 0));
    }
};

}  // namespace

extern "C" {

VIBID_API vibid_status vibid_plausibility_ref_init(const vibid_model *model, const double *theta_ref,
                                                   vibid_plausibility_ref *ref) {
    VIBID_GUARD(
        if (!model) throw_error(VIBID_E_NULL_ARGUMENT, "model is NULL");
        if (!ref) throw_error(VIBID_E_NULL_ARGUMENT, "ref is NULL");
        vibid::require_finalized(model);
        const std::size_t p = model->param_term.size(), n = model->nodes.size();
        std::vector<double> th(p);
        if (theta_ref)
            std::copy(theta_ref, theta_ref + p, th.begin());
        else if (p)
            vibid_model_nominal(model, th.data());
        // Built in a local copy: a failure leaves *ref as it was.
        vibid_plausibility_ref r;
        std::memset(&r, 0, sizeof r);
        r.n_params = p;
        r.n_modes = n;
        for (std::size_t i = 0; i < VIBID_PLAUSIBILITY_MAX_MODES; ++i) r.freq_hz[i] = r.zeta[i] = NAN;
        const char *what = theta_ref ? "reference" : "nominal";
        for (std::size_t k = 0; k < p && !r.zeta_rule_off[0]; ++k) {
            const vibid::Term &t = model->terms[model->param_term[k]];
            if (!std::isfinite(th[k]))
                std::snprintf(r.zeta_rule_off, sizeof r.zeta_rule_off, "the %s value of %s is %g", what,
                              t.name.c_str(), th[k]);
            else if (sign_rule(*model, t) && th[k] <= 0.0)
                std::snprintf(r.zeta_rule_off, sizeof r.zeta_rule_off, "the %s value of %s is %s", what,
                              t.name.c_str(), th[k] == 0.0 ? "not given (0)" : "not positive");
        }
        if (!r.zeta_rule_off[0] && n > VIBID_PLAUSIBILITY_MAX_MODES)
            std::snprintf(r.zeta_rule_off, sizeof r.zeta_rule_off, "the model has %zu modes, more than %d", n,
                          VIBID_PLAUSIBILITY_MAX_MODES);
        if (!r.zeta_rule_off[0]) {
            if (vibid_model_modal(model, th.data(), nullptr, r.freq_hz, nullptr, r.zeta, nullptr, nullptr, nullptr) !=
                VIBID_OK) {
                std::snprintf(r.zeta_rule_off, sizeof r.zeta_rule_off, "the %s modes cannot be computed: %s", what,
                              vibid_last_error());
                for (std::size_t i = 0; i < n; ++i) r.freq_hz[i] = r.zeta[i] = NAN;
            }
        }
        r.zeta_rule = r.zeta_rule_off[0] ? 0 : 1;
        *ref = r;
        return VIBID_OK;);
}

// Not guarded: nothing here throws or allocates (real-time use at the row rate).
VIBID_API vibid_status vibid_plausibility_check(const vibid_model *model, double sample_time, const double *theta,
                                                const double *freq_hz, const double *zeta, size_t n_modes,
                                                const vibid_plausibility_ref *ref, unsigned *flags_out,
                                                unsigned *param_flags, unsigned *mode_flags, char *why,
                                                size_t why_cap) {
    if (!model) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "model is NULL");
    if (!flags_out) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "flags_out is NULL");
    if (!model->frozen) return VIBID_FAIL(VIBID_E_STATE, "model is not finalized (call vibid_model_finalize)");
    const std::size_t p = model->param_term.size(), n = model->nodes.size();
    if (!(sample_time >= 0.0) || !std::isfinite(sample_time))
        return VIBID_FAIL(VIBID_E_OUT_OF_RANGE, "sample_time = %g, need > 0 (or 0 to skip the Nyquist rule)",
                          sample_time);
    if (n_modes != 0 && n_modes != n)
        return VIBID_FAIL(VIBID_E_DIMENSION, "n_modes = %zu, need 0 or the model's %zu degrees of freedom", n_modes,
                          n);
    if (n_modes && (!freq_hz || !zeta))
        return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "%s is NULL with n_modes = %zu", freq_hz ? "zeta" : "freq_hz",
                          n_modes);
    if (ref && (ref->n_params != p || ref->n_modes != n))
        return VIBID_FAIL(VIBID_E_DIMENSION,
                          "ref was made for a model with %zu parameters and %zu modes, this one has %zu and %zu "
                          "(initialize it with vibid_plausibility_ref_init)",
                          ref->n_params, ref->n_modes, p, n);

    Why w{why, why_cap};
    if (why && why_cap) why[0] = '\0';
    unsigned all = 0;
    if (param_flags)
        for (std::size_t k = 0; k < p; ++k) param_flags[k] = 0;
    if (mode_flags)
        for (std::size_t i = 0; i < n_modes; ++i) mode_flags[i] = 0;

    if (theta) {
        for (std::size_t k = 0; k < p; ++k) {
            const vibid::Term &t = model->terms[model->param_term[k]];
            const double v = theta[k];
            unsigned bit = 0;
            if (!std::isfinite(v)) {
                bit = VIBID_IMPLAUSIBLE_NONFINITE;
                w.add("%s = %g is not finite", t.name.c_str(), v);
            } else if (v <= 0.0 && (bit = sign_rule(*model, t)) != 0) {
                w.add("%s = %.6g %s <= 0 (%s must be positive)", t.name.c_str(), v, unit_of(t.kind),
                      kind_word(t.kind));
            }
            if (param_flags) param_flags[k] = bit;
            all |= bit;
        }
    }

    const double nyquist = sample_time > 0.0 ? 0.5 / sample_time : INFINITY;
    const bool zeta_rule = ref && ref->zeta_rule && n <= VIBID_PLAUSIBILITY_MAX_MODES;
    for (std::size_t i = 0; i < n_modes; ++i) {
        const double f = freq_hz[i], z = zeta[i];
        unsigned bits = 0;
        if (!std::isfinite(f) || !std::isfinite(z)) {
            bits |= VIBID_IMPLAUSIBLE_NONFINITE;
            w.add("mode %zu: f = %g Hz, zeta = %g (not finite)", i + 1, f, z);
        } else {
            if (f <= 0.0) {
                bits |= VIBID_IMPLAUSIBLE_FREQ_ZERO;
                w.add("mode %zu at %.6g Hz <= 0", i + 1, f);
            } else if (f >= nyquist) {
                bits |= VIBID_IMPLAUSIBLE_FREQ_NYQUIST;
                w.add("mode %zu at %.6g Hz >= Nyquist %.6g Hz", i + 1, f, nyquist);
            }
            if (z < -VIBID_PLAUSIBILITY_ZETA_TOL) {
                bits |= VIBID_IMPLAUSIBLE_ZETA_NEGATIVE;
                w.add("mode %zu: zeta = %.6g < 0 (unstable)", i + 1, z);
            } else if (zeta_rule && z >= 1.0 && ref->zeta[i] < 1.0) {
                bits |= VIBID_IMPLAUSIBLE_OVERDAMPED;
                w.add("mode %zu: zeta = %.6g >= 1 (reference mode %zu at %.6g Hz is underdamped, zeta %.3g)", i + 1, z,
                      i + 1, ref->freq_hz[i], ref->zeta[i]);
            }
        }
        if (mode_flags) mode_flags[i] = bits;
        all |= bits;
    }
    *flags_out = all;
    return VIBID_OK;
}

}  // extern "C"
