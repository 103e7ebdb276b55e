/* estimator.h: the estimation side of the pipeline: source records in, decimated
 * parameter-track rows out.
 *
 * Wraps one vibid_ident (identify.h) built from the stand's model with the configured
 * method. SAMPLE records are re-ordered from the source's channel order into the model's
 * channel layout and pushed (no allocation: vibid_ident_push is real-time safe for
 * every estimator). Every `decimation` samples of sample index a row is due: the
 * current estimate, its standard errors (vibid_ident_estimate), the covariance and
 * from them the natural frequencies and damping ratios with their standard errors
 * (vibid_model_modal). Those calls allocate; they run only at the decimated rate, on
 * the estimation thread, never on the acquisition thread. And they run late: at the
 * row's sample only the estimator's state is copied into a twin (vibid_ident_twin_sync,
 * allocation-free, 0.8 us on example 1), and the row is computed from the twin when the estimation
 * thread has no sample waiting (vd_est_finish_row). A row took 30-100 us on the test
 * machine at 10 kHz (cold caches), and samples that arrived in the same poll waited for
 * it: most of the receipt -> estimate latency's p99. The row's values are the same bit
 * for bit (tests/ident/test_twin.c).
 *
 * Across a gap (a GAP record, or sample indices that jump because the ring overflowed)
 * the regressor's history is restarted by pushing one non-finite sample
 * (vibid_ident_push: the difference window and the pre-filter restart, the estimator's
 * state, theta and P, is kept). So no central difference and no filter output ever spans
 * the gap; the first 2 samples after it (plus the pre-filter's settling) only refill the
 * window. The row that covers a gap carries the missing-sample count and the flag G.
 *
 * Outlier samples (single-sample glitches, vibid/outlier.h; estimator.outlier_threshold):
 * every SAMPLE and GAP record passes through the outlier test before the estimator
 * (vd_est_feed, vd_est_next). A value the test takes out is pushed as NaN, a gap for the
 * estimator, counted (vd_est.outliers), logged and flagged O on the next row; the record
 * itself (the raw recording) is not changed. The test releases a clean sample at once; a
 * suspect waits for the next sample, and the first 16 samples of a run are decided
 * together, so records leave vd_est_next in their order, sometimes one record late.
 *
 * Physically impossible estimates (vibid/plausibility.h: a mass, damper or spring <= 0, a
 * mode at 0 Hz or at/above f_a/2, an unstable mode, or zeta >= 1 where the nominal mode is
 * underdamped) are written as they are but flagged P (VD_FLAG_IMPLAUSIBLE), with the
 * reason in vd_est.why; the alarms ignore such rows as they ignore rows without an
 * estimate (vd_row_usable).
 *
 * Sample index and time: the index of a row is counted from the run's first record
 * (index - first index), so a live run and the replay of its recording number samples
 * alike. Times are kept to the microsecond (round(t_ns / 1000)), the resolution of
 * candump logs, so that a recording replays to identical times.
 */
#ifndef VIBIDD_ESTIMATOR_H
#define VIBIDD_ESTIMATOR_H

#include <stdbool.h>
#include <stdio.h>
#include <stdint.h>

#include <vibid/identify.h>
#include <vibid/outlier.h>
#include <vibid/plausibility.h>
#include <vibid/report.h>
#include <vibid_drivers/sample.h>

#include "config.h"
#include "oma_track.h"

/* E, P, U and I are the library's row flags (vibid/report.h), the same bits. */
enum {
    VD_FLAG_GAP = 1u,       /* samples missing since the previous row */
    VD_FLAG_NOEST = VIBID_ROW_NOEST, /* no estimate yet / estimate failed (values NaN) */
    VD_FLAG_ALARM = 4u,     /* a drift alarm is active */
    VD_FLAG_IMPLAUSIBLE = VIBID_ROW_IMPLAUSIBLE, /* the estimate is physically impossible
                                (vibid/plausibility.h) or unstable: written as it is,
                                flagged P, ignored by the alarms */
    VD_FLAG_SE_INVALID = VIBID_ROW_SE_INVALID, /* U: the standard errors do not hold
                                 (VIBID_QUALITY_SE_INVALID: the older and newer half of the
                                 data disagree, too few blocks yet, or an LS/RLS estimator) */
    VD_FLAG_NOT_EXCITED = VIBID_ROW_NOT_EXCITED, /* I: some parameter is hardly informed by
                                  the data (its standard error is written as inf) */
    VD_FLAG_OUTLIER = 64u,     /* O: a sample since the previous row had a glitch taken out
                                  (vibid/outlier.h): the estimator saw it as a gap */
    VD_FLAG_REFINED = 128u,    /* W: the output-error refinement over the window ending at the
                                  row's sample (refine.h), not the recursive estimate */
    VD_FLAG_COVARIATE = 256u   /* C: the change test met covariates outside the range its
                                  reference saw (vibid/change.h point 6): the row is weighed
                                  down, not judged on an extrapolated dependence */
};

/* The row's flags as letters, in the order G O E P U I A C W (docs/vibidd.md): the one
 * spelling of the tracks, InfluxDB, MQTT and the metrics. out holds at least
 * VD_FLAG_LETTERS_MAX bytes. */
#define VD_FLAG_LETTERS_MAX 12
void vd_flag_letters(unsigned flags, char out[VD_FLAG_LETTERS_MAX]);

/* Parameter k gets the change test's columns in the tracks (alarms.test = "cusum" and k alarmed). */
static inline bool vd_change_columns(const vd_config *cfg, size_t k)
{
    return cfg->alarms_enabled && cfg->alarm_test == VD_ALARM_CUSUM && cfg->alarm_param[k].enabled;
}

/* Rows the alarms may use: an estimate exists (no E) and is physically possible (no P). */
static inline bool vd_row_usable(unsigned flags)
{
    return (flags & (VD_FLAG_NOEST | VD_FLAG_IMPLAUSIBLE)) == 0;
}

typedef struct vd_row {
    int64_t t_us;           /* time of the row's sample, microseconds since the epoch */
    uint64_t index;         /* sample index from the run's start */
    double run_s;           /* index * h: run time used by the alarms */
    unsigned flags;
    uint64_t gap_samples;   /* missing samples since the previous row */
    double theta[VD_MAX_PARAMS], se[VD_MAX_PARAMS];
    double freq[VD_MAX_PARAMS], freq_se[VD_MAX_PARAMS], zeta[VD_MAX_PARAMS], zeta_se[VD_MAX_PARAMS];
    double cov[VD_MAX_COVARIATES]; /* the covariates' means over the samples since the previous
                               row (their channels' units; NaN: none finite; refined rows NaN) */
    /* the change test (alarms.test = "cusum", alarmed parameters once the reference exists;
       NaN otherwise): the statistic over its threshold (>= 1 raises) and the minimum
       detectable change (the parameter's unit) */
    double change_stat[VD_MAX_PARAMS], change_mdc[VD_MAX_PARAMS];
    int est_status;         /* vibid_status of the estimate */
    unsigned implausible;   /* VIBID_IMPLAUSIBLE_* bits found (flag P), 0 = plausible */
} vd_row;

typedef struct vd_est {
    const vd_config *cfg;
    vibid_ident *ident;
    vibid_ident *twin;      /* a row's estimator state, kept at its sample (identify.h,
                               deferred estimates); NULL for LS, EKF and KF+RLS, ... */
    char twin_why[256];     /* ... and why (the library's message) */
    vibid_status sync_status; /* the twin's sync at the due row's sample (one row is
                                 pending at a time: vd_est_record) */
    const vibid_model *model;
    size_t p, nch, nmodes;
    bool started;
    /* the outlier test (NULL: estimator.outlier_threshold = 0) and the records it holds,
     * in order: [0, rel_n) released by the last feed or flush, rel_i of them handed out */
    vibid_outlier *outl;
    vibid_record *held;
    int64_t *held_tag;
    size_t n_held, held_cap, rel_n, rel_i;
    const vibid_record *cur; /* the record of the last feed (the caller's) ... */
    int64_t cur_tag;
    size_t cur_first;        /* ... released as number cur_first, after the held ones */
    unsigned char rel_out[VIBID_DRV_MAX_CHANNELS]; /* the released record: per model
                                                      channel 1 = taken out ... */
    size_t rel_outliers;                           /* ... how many (its values: chan) */
    uint64_t outliers;      /* samples with a value taken out */
    uint64_t outlier_since_row;
    uint64_t first_index, next_index, next_emit;
    uint64_t samples, gaps, missing, push_errors, est_errors, rows;
    uint64_t gap_since_row;
    double cov_sum[VD_MAX_COVARIATES]; /* the covariates' finite values since the last row */
    uint64_t cov_n[VD_MAX_COVARIATES];
    double chan[VIBID_DRV_MAX_CHANNELS];
    vibid_report *report;   /* the row's checks (vibid/report.h) */
    vd_row last;            /* the latest row (for the status) */
    bool have_last;
    int last_push_status;
    /* physical plausibility of each row's estimate (vibid_report_row); the reference
     * (nominal modes: a copy of the report's, made at init) is reported from the first
     * row on (pref_ready) */
    bool pref_ready;
    vibid_plausibility_ref pref;
    uint64_t implausible_rows;
    char why[1024];         /* what the latest flagged row's estimate got wrong (the rules'
                               findings, then an unstable estimate's message) */
    vibid_ident_config resolved;   /* the settings in force (automatic choices resolved) */
    char choices[2048];            /* vibid_ident_describe: one line per choice and why */
    size_t choices_len;            /* its full length (the description grows when the
                                      pre-filter pilot ends, identify.h) */
} vd_est;

/* 0, or -1 with a message in err (cap bytes): the model is not identifiable, ... */
int vd_est_init(vd_est *e, const vd_config *cfg, char *err, size_t cap);
void vd_est_free(vd_est *e);

/* Writes what the estimator chose and why (vibid_ident_describe), one line per choice,
 * each line starting with prefix (e.g. "# " for the tracks header and --check). */
void vd_est_print_choices(const vd_est *e, FILE *out, const char *prefix);
/* The same lines in the log (info level), at start. */
void vd_est_log_choices(const vd_est *e);

/* Line iterator over a '\n'-separated text: 1 with the line starting at the old *text
 * (len characters, no '\n') and *text advanced past it; 0 at the end. */
int vd_next_line(const char **text, int *len);

/* Hands a SAMPLE or GAP record to the outlier test (FAULT records are not fed: the caller
 * handles them at once). tag (e.g. the receive time) comes back with the record from
 * vd_est_next. Allocation-free. */
void vd_est_feed(vd_est *e, const vibid_record *rec, int64_t tag);
/* The end of the data: what the outlier test holds is decided (no successor) and released. */
void vd_est_flush(vd_est *e);
/* The next record released by the test, in feed order, or NULL: pass each to
 * vd_est_record before asking for the next one. *tag = its feed's tag. */
const vibid_record *vd_est_next(vd_est *e, int64_t *tag);

/* Feeds one record released by vd_est_next (allocation-free). Returns 1 when a row is due, else 0: *row then
 * holds the row's time, index and gap fields, and the estimator's state at this sample
 * is kept in the twin. FAULT records are not handled here (the caller logs and counts
 * them). The row's estimate follows with vd_est_finish_row: with a twin at any later time
 * before the next row is due (vd_est_row_due), so that no sample waits for it; without
 * one (LS, EKF, KF+RLS) before the next record. */
int vd_est_record(vd_est *e, const vibid_record *rec, vd_row *row);

/* Completes a due row: vibid_report_row (vibid/report.h) on the twin: the estimate and
 * its standard errors, the modes with theirs, the quality flags and the plausibility
 * check; counts it and keeps it as vd_est.last. Allocates inside the estimate and the
 * modal analysis only (report.h): 30-100 us a row, at the decimated rate. */
void vd_est_finish_row(vd_est *e, vd_row *row);

/* A row of the output-error refinement (refine.h) over the window of n_samples ending at
 * sample index (from the run's start) at time t_us: theta, se, cov (p x p) of the fit,
 * quality (VIBID_QUALITY_* the refinement found); flagged W, its modes, plausibility and
 * flags by vibid_report_estimate as any row's. Counts it and keeps it as vd_est.last.
 * Allocates (the modal analysis). */
void vd_est_refined_row(vd_est *e, vd_row *row, uint64_t index, int64_t t_us, const double *theta, const double *se,
                        const double *cov, unsigned quality, uint64_t n_samples);

/* Output-only: the row of a mode tracker's result (oma_track.h) at its window's end: the
 * tracked modes' f<j>_hz and zeta<j> with their standard errors as the parameters (NaN where a
 * mode was not found), the covariates' means over the window; flagged E when no tracked mode
 * was found, U when a found mode has no standard error, G with missing samples (missing:
 * those since the previous mode row), O when outliers were taken out since then. Counts it
 * and keeps it as vd_est.last. Allocation-free. */
void vd_est_oma_row(vd_est *e, vd_row *row, const vd_omat_result *res, uint64_t missing);

/* 1 when rec may make a row due (or is not a sample): a pending row is finished before
 * such a record, so rows stay in order with everything else the record causes. */
int vd_est_row_due(const vd_est *e, const vibid_record *rec);

/* Microseconds from nanoseconds, rounded to nearest (floor division for negatives). */
int64_t vd_ns_to_us(int64_t t_ns);

#endif
