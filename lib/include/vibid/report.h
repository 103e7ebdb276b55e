/* vibid/report.h: one estimator state turned into one reported row: the estimate and
 * its standard errors (vibid_ident_estimate), the covariance, the natural frequencies and
 * damping ratios with their standard errors (vibid_model_modal), the physical
 * plausibility (plausibility.h) and the quality flags (vibid_ident_get_quality). The one
 * place where these per-row checks are made: vibidd's track rows and the Python binding's
 * estimates both come from vibid_report_row, so they flag and explain alike.
 *
 * What a row says:
 *  - no estimate (vibid_ident_estimate failed: too few samples, not identifiable, ...):
 *    theta, se, modes NaN, VIBID_ROW_NOEST, est_status and message say why;
 *  - otherwise theta and se as estimated; modes and their standard errors from the
 *    covariance (NaN standard errors when the estimator has no covariance; NaN modes when
 *    the modal analysis fails for another reason than instability);
 *  - VIBID_ROW_IMPLAUSIBLE with the rule bits in `implausible` and the findings in `why`
 *    when the estimate is physically impossible (plausibility.h) or unstable
 *    (vibid_model_modal's VIBID_E_UNSTABLE, which a growth within the rules' 1e-6 zeta
 *    tolerance would otherwise pass: then VIBID_IMPLAUSIBLE_ZETA_NEGATIVE). The unstable
 *    message is appended to the rules' findings ("; " between), never replaces them;
 *  - VIBID_ROW_SE_INVALID, VIBID_ROW_NOT_EXCITED from the estimator's quality
 *    (VIBID_QUALITY_SE_INVALID, VIBID_QUALITY_NOT_EXCITED).
 *
 * Real time: vibid_report_create allocates everything the report itself needs (a copy of
 * the model, the covariance, the plausibility reference with the model's nominal modes,
 * the message buffers, and the scratch of the modal analysis: every matrix and
 * decomposition sized for the model). vibid_report_row and vibid_report_estimate then
 * allocate nothing of their own, the modes included (tests/lib/rt_no_alloc.cpp, with
 * Eigen's allocation check armed); what vibid_report_row calls allocates as documented
 * there: vibid_ident_estimate for the batch estimators (LS, IV, block IV), none for RLS,
 * a twin's RLS, the EKF and KF+RLS. So vibidd's rows from a recursive estimator allocate
 * nothing. vibid_report_no_estimate allocates nothing at all.
 *
 * Threads: one report per thread at a time (it holds the row's buffers); different
 * reports are independent. The model given to create may be destroyed after it.
 */
#ifndef VIBID_REPORT_H
#define VIBID_REPORT_H

#include <vibid/common.h>
#include <vibid/identify.h>
#include <vibid/model.h>
#include <vibid/plausibility.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct vibid_report vibid_report;

/* Row flags: the same bits as vibidd's track flags (docs/vibidd.md: E, P, U, I), so that
 * the daemon ORs them into its own (G, O, A are the daemon's). */
#define VIBID_ROW_NOEST 2u         /* E: no estimate; values NaN */
#define VIBID_ROW_IMPLAUSIBLE 8u   /* P: physically impossible or unstable (above) */
#define VIBID_ROW_SE_INVALID 16u   /* U: VIBID_QUALITY_SE_INVALID */
#define VIBID_ROW_NOT_EXCITED 32u  /* I: VIBID_QUALITY_NOT_EXCITED */

/* The reported row. The arrays are the caller's (p = the model's parameters, n = its
 * nodes = modes); the call writes them and the scalar fields. */
typedef struct vibid_report_row_out {
    double *theta;               /* p, required: estimate, the model's units */
    double *se;                  /* p, required: standard errors (inf: not excited) */
    double *freq, *freq_se;      /* n each, required: natural frequencies (Hz), ascending */
    double *zeta, *zeta_se;      /* n each, required: damping ratios (1) */
    double *cov;                 /* p x p column-major, may be NULL: the covariance (NaN
                                    when the estimator has none) */
    unsigned *param_quality;     /* p, may be NULL: VIBID_QUALITY_* per parameter */
    unsigned *param_implausible; /* p, may be NULL: VIBID_IMPLAUSIBLE_* per parameter */
    unsigned *mode_implausible;  /* n, may be NULL: VIBID_IMPLAUSIBLE_* per mode */

    vibid_status est_status;     /* vibid_ident_estimate's (or the caller's, no_estimate) */
    unsigned flags;              /* VIBID_ROW_* */
    unsigned implausible;        /* VIBID_IMPLAUSIBLE_* found, 0 = plausible */
    unsigned quality;            /* VIBID_QUALITY_* of the whole estimate */
    double z_consistency;        /* vibid_ident_quality's; NaN when not available */
    size_t n_blocks;             /* vibid_ident_quality's */
    unsigned long long n_samples; /* samples behind the estimate (vibid_ident_info) */
    const char *message;         /* est_status != VIBID_OK: the library's message; else "" */
    const char *why;             /* VIBID_ROW_IMPLAUSIBLE: the findings in words; else "" */
    /* message and why are lent by the report: valid until its next row or its destroy */
} vibid_report_row_out;

/* A report for a finalized model (copied), sampled with step sample_time (s, > 0 and
 * finite: the Nyquist rule of the plausibility check). Computes the plausibility
 * reference from the model's nominal values (plausibility.h; a stand without complete
 * nominal values gets no damping-ratio rule). NULL on bad arguments (reason in
 * vibid_last_error()). Allocates. */
VIBID_API vibid_report *vibid_report_create(const vibid_model *model, double sample_time);
VIBID_API void vibid_report_destroy(vibid_report *report);

/* The plausibility reference the report made at create (plausibility.h: its
 * zeta_rule_off says why the damping-ratio rule is off, if it is). Lent: valid until
 * vibid_report_destroy. NULL for a NULL report. */
VIBID_API const vibid_plausibility_ref *vibid_report_reference(const vibid_report *report);

/* The row of ident's current state (an identification of the same model, or its twin:
 * identify.h), into out. Returns VIBID_OK when the row was written, whether or not it has
 * an estimate (est_status says); VIBID_E_NULL_ARGUMENT / VIBID_E_DIMENSION for missing
 * arrays or an ident of another shape (out untouched). Real time: above. */
VIBID_API vibid_status vibid_report_row(vibid_report *report, vibid_ident *ident, vibid_report_row_out *out);

/* The row of an estimate made elsewhere (e.g. an output-error fit: output_error.h), with
 * the same checks as vibid_report_row's: theta and se (p each, copied into out), cov (p x
 * p column-major, NULL: none; then the modes' standard errors are NaN), quality
 * (VIBID_QUALITY_* the caller found for it; VIBID_QUALITY_NOT_EXCITED is added where an se
 * is not finite), n_samples behind it. z_consistency NaN, n_blocks 0. VIBID_OK when written;
 * VIBID_E_NULL_ARGUMENT for missing arrays. Allocates nothing. */
VIBID_API vibid_status vibid_report_estimate(vibid_report *report, const double *theta, const double *se,
                                             const double *cov, unsigned quality, unsigned long long n_samples,
                                             vibid_report_row_out *out);

/* A row without estimate for a reason the caller knows (e.g. a failed
 * vibid_ident_twin_sync): values NaN, VIBID_ROW_NOEST, est_status = status, message =
 * vibid_last_error(). Allocates nothing. */
VIBID_API vibid_status vibid_report_no_estimate(vibid_report *report, vibid_status status, vibid_report_row_out *out);

#ifdef __cplusplus
}
#endif
#endif
