// report.cpp: an estimator's state as one reported row (vibid/report.h): the per-row
// checks that vibidd and the Python binding used to make each in its own way.
#include <vibid/report.h>

#include <vibid/modal.h>

#include "api_guard.hpp"
#include "modal_work.hpp"
#include "model_internal.hpp"

#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <vector>

using vibid::throw_error;

struct vibid_report {
    vibid_model *model = nullptr;  // the caller's model, cloned
    std::unique_ptr<vibid::ModalWork> modal;  // of model: the rows' modal analysis, allocated once
    double h = 0.0;
    std::size_t p = 0, n = 0;
    std::vector<double> cov;        // p x p, when the caller wants none
    vibid_plausibility_ref pref{};  // n_modes 0: no reference (the rules without it)
    char message[512] = "";
    char why[1024] = "";
    char unstable[256] = "";
    ~vibid_report() { vibid_model_destroy(model); }
};

namespace {

void fill_nan(double *v, std::size_t k) {
    for (std::size_t i = 0; i < k; ++i) v[i] = NAN;
}

vibid_status check_out(const vibid_report *r, const vibid_report_row_out *out) {
    if (!r || !out) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "report and out are required");
    if (!out->theta || !out->se || !out->freq || !out->freq_se || !out->zeta || !out->zeta_se)
        return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "out: theta, se, freq, freq_se, zeta and zeta_se are required");
    return VIBID_OK;
}

// Every output of a row without estimate (the scalars and the NaN values).
void no_estimate(vibid_report *r, vibid_status status, vibid_report_row_out *out) {
    std::snprintf(r->message, sizeof r->message, "%s", status == VIBID_OK ? "" : vibid_last_error());
    r->why[0] = '\0';
    fill_nan(out->theta, r->p);
    fill_nan(out->se, r->p);
    fill_nan(out->freq, r->n);
    fill_nan(out->freq_se, r->n);
    fill_nan(out->zeta, r->n);
    fill_nan(out->zeta_se, r->n);
    if (out->cov) fill_nan(out->cov, r->p * r->p);
    for (std::size_t i = 0; i < r->p; ++i) {
        if (out->param_quality) out->param_quality[i] = 0;
        if (out->param_implausible) out->param_implausible[i] = 0;
    }
    if (out->mode_implausible)
        for (std::size_t j = 0; j < r->n; ++j) out->mode_implausible[j] = 0;
    out->est_status = status;
    out->flags = VIBID_ROW_NOEST;
    out->implausible = 0;
    out->quality = 0;
    out->z_consistency = NAN;
    out->n_blocks = 0;
    out->n_samples = 0;
    out->message = r->message;
    out->why = r->why;
}

// The modes of out->theta with their standard errors from cov (have_cov), and the
// plausibility of both: the checks every row makes, whoever estimated it.
void describe(vibid_report *r, const double *cov, bool have_cov, vibid_report_row_out *out) {
    // A covariance with a non-finite entry (the estimator's standard errors do not exist yet:
    // IV with too few blocks) is no covariance: the modes are still those of theta. Before,
    // the modal analysis refused it and the row's modes were NaN, so the row was flagged P
    // ("not finite") although its estimate was plausible (a third of a 3-DOF stand's rows).
    for (std::size_t i = 0; have_cov && i < r->p * r->p; ++i) have_cov = std::isfinite(cov[i]);
    // An unstable estimate (VIBID_E_UNSTABLE) keeps its modes: a negative zeta or f = 0 is
    // what the plausibility check flags, and what the reader needs to see. Without a
    // covariance the modes' standard errors stay NaN (not modal.h's 0).
    // vibid_model_modal on the report's scratch (modal_work.hpp): nothing allocated
    const vibid_status ms = vibid::guard("vibid_model_modal", [&]() {
        return r->modal->model_modal(out->theta, have_cov ? cov : nullptr, out->freq, have_cov ? out->freq_se : nullptr,
                                     out->zeta, have_cov ? out->zeta_se : nullptr, nullptr, nullptr,
                                     "vibid_model_modal");
    });
    // copied now: the plausibility check may replace the last error
    if (ms == VIBID_E_UNSTABLE) std::snprintf(r->unstable, sizeof r->unstable, "%s", vibid_last_error());
    if (ms != VIBID_OK && ms != VIBID_E_UNSTABLE) {
        fill_nan(out->freq, r->n);
        fill_nan(out->zeta, r->n);
    }
    if (!have_cov || (ms != VIBID_OK && ms != VIBID_E_UNSTABLE)) {
        fill_nan(out->freq_se, r->n);
        fill_nan(out->zeta_se, r->n);
    }

    unsigned found = 0;
    if (vibid_plausibility_check(r->model, r->h, out->theta, out->freq, out->zeta, r->n,
                                 r->pref.n_modes ? &r->pref : nullptr, &found, out->param_implausible,
                                 out->mode_implausible, r->why, sizeof r->why) != VIBID_OK) {
        // an argument error (a bug): nothing can be said for the estimate, so it is not
        // passed as plausible either
        std::snprintf(r->why, sizeof r->why, "plausibility check failed: %s", vibid_last_error());
        found = VIBID_IMPLAUSIBLE_NONFINITE;
    }
    if (r->unstable[0]) {
        // Impossible for a passive stand whatever the rules say; a growth within the
        // rules' 1e-6 zeta tolerance is a slightly negative zeta. Appended: the rules'
        // findings stay.
        if (!found) found = VIBID_IMPLAUSIBLE_ZETA_NEGATIVE;
        const std::size_t len = std::strlen(r->why);
        std::snprintf(r->why + len, sizeof r->why - len, "%s%s", len ? "; " : "", r->unstable);
    }
    out->implausible = found;
    if (found) out->flags |= VIBID_ROW_IMPLAUSIBLE;

}

// The scalar fields of a row with an estimate, before its checks.
void start_row(vibid_report *r, vibid_report_row_out *out, unsigned long long n_samples) {
    r->message[0] = r->why[0] = r->unstable[0] = '\0';
    out->est_status = VIBID_OK;
    out->flags = 0;
    out->n_samples = n_samples;
    out->message = r->message;
    out->why = r->why;
}

}  // namespace

extern "C" {

VIBID_API vibid_report *vibid_report_create(const vibid_model *model, double sample_time) {
    return vibid::guard_create<vibid_report>(__func__, [&]() -> vibid_report * {
        vibid::require_finalized(model);
        if (!(sample_time > 0.0) || !std::isfinite(sample_time))
            throw_error(VIBID_E_OUT_OF_RANGE, "sample_time = %g s must be > 0 and finite", sample_time);
        std::unique_ptr<vibid_report> r(new vibid_report);
        r->model = vibid_model_clone(model);
        if (!r->model) throw_error(VIBID_E_NO_MEMORY, "copying the model: %s", vibid_last_error());
        r->modal = std::make_unique<vibid::ModalWork>(r->model);
        r->h = sample_time;
        r->p = model->param_term.size();
        r->n = model->nodes.size();
        r->cov.assign(r->p * r->p, NAN);
        // The reference for the damping-ratio rule, once (it allocates). It cannot fail
        // for a finalized model; if it did, the rules that need no reference still run.
        if (vibid_plausibility_ref_init(r->model, nullptr, &r->pref) != VIBID_OK) {
            r->pref = vibid_plausibility_ref{};
            std::snprintf(r->pref.zeta_rule_off, sizeof r->pref.zeta_rule_off, "%s", vibid_last_error());
        }
        return r.release();
    });
}

VIBID_API void vibid_report_destroy(vibid_report *report) { delete report; }

VIBID_API const vibid_plausibility_ref *vibid_report_reference(const vibid_report *report) {
    return report ? &report->pref : nullptr;
}

VIBID_API vibid_status vibid_report_no_estimate(vibid_report *report, vibid_status status,
                                                vibid_report_row_out *out) {
    const vibid_status s = check_out(report, out);
    if (s != VIBID_OK) return s;
    no_estimate(report, status, out);
    return VIBID_OK;
}

VIBID_API vibid_status vibid_report_row(vibid_report *report, vibid_ident *ident, vibid_report_row_out *out) {
    vibid_status s = check_out(report, out);
    if (s != VIBID_OK) return s;
    if (!ident) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "ident is NULL");
    vibid_report *r = report;
    std::size_t nc = 0, np = 0;
    if (vibid_ident_dims(ident, &nc, &np) != VIBID_OK || np != r->p)
        return VIBID_FAIL(VIBID_E_DIMENSION, "ident has %zu parameters, the report's model %zu", np, r->p);

    vibid_ident_info info{};
    s = vibid_ident_estimate(ident, out->theta, out->se, &info);
    if (s != VIBID_OK) {
        no_estimate(r, s, out);
        out->n_samples = info.n_samples;
        return VIBID_OK;
    }
    start_row(r, out, info.n_samples);

    double *cov = out->cov ? out->cov : r->cov.data();
    const bool have_cov = vibid_ident_covariance(ident, cov) == VIBID_OK;
    if (!have_cov) fill_nan(cov, r->p * r->p);
    describe(r, cov, have_cov, out);

    vibid_ident_quality q;
    if (vibid_ident_get_quality(ident, &q, out->param_quality) == VIBID_OK) {
        out->quality = q.flags;
        out->z_consistency = q.z_consistency;
        out->n_blocks = q.n_blocks;
        if (q.flags & VIBID_QUALITY_SE_INVALID) out->flags |= VIBID_ROW_SE_INVALID;
        if (q.flags & VIBID_QUALITY_NOT_EXCITED) out->flags |= VIBID_ROW_NOT_EXCITED;
    } else {
        out->quality = 0;
        out->z_consistency = NAN;
        out->n_blocks = 0;
        if (out->param_quality)
            for (std::size_t i = 0; i < r->p; ++i) out->param_quality[i] = 0;
    }
    return VIBID_OK;
}

VIBID_API vibid_status vibid_report_estimate(vibid_report *report, const double *theta, const double *se,
                                             const double *cov, unsigned quality, unsigned long long n_samples,
                                             vibid_report_row_out *out) {
    const vibid_status s = check_out(report, out);
    if (s != VIBID_OK) return s;
    if (!theta || !se) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "theta and se are required");
    vibid_report *r = report;
    start_row(r, out, n_samples);
    for (std::size_t i = 0; i < r->p; ++i) {
        out->theta[i] = theta[i];
        out->se[i] = se[i];
        if (!std::isfinite(se[i])) quality |= VIBID_QUALITY_NOT_EXCITED;
        if (out->param_quality) out->param_quality[i] = std::isfinite(se[i]) ? 0u : VIBID_QUALITY_NOT_EXCITED;
    }
    double *row_cov = out->cov ? out->cov : r->cov.data();
    if (cov)
        std::memcpy(row_cov, cov, r->p * r->p * sizeof *row_cov);
    else
        fill_nan(row_cov, r->p * r->p);
    describe(r, row_cov, cov != nullptr, out);
    out->quality = quality;
    out->z_consistency = NAN;
    out->n_blocks = 0;
    if (quality & VIBID_QUALITY_SE_INVALID) out->flags |= VIBID_ROW_SE_INVALID;
    if (quality & VIBID_QUALITY_NOT_EXCITED) out->flags |= VIBID_ROW_NOT_EXCITED;
    return VIBID_OK;
}

}  // extern "C"
