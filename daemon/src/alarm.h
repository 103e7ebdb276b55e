/* alarm.h: drift alarms of the parameters against a reference: the change test (test =
 * "cusum", the default: vibid/change.h, vd_cusum below) or the threshold rule (test =
 * "threshold", vd_alarm below), and the event both report to the log and the outputs.
 *
 * The threshold rule, per parameter:
 *
 * The deviation of an estimate theta with standard error se from the baseline b (with
 * its own standard error se_b, 0 when the baseline was given as a number) is
 *     z = |theta - b| / sqrt(se^2 + se_b^2)
 * A parameter is "out" when z > threshold AND |theta - b| > min_relative * |b|: the
 * relative floor keeps an alarm from firing on a change too small to matter, as
 * happens when the standard errors become tiny on clean data over long runs.
 * The alarm RAISES when the parameter has been out continuously for hold_s seconds of
 * sample time, and CLEARS when it has been back in continuously for hold_s. Time is the
 * samples' time, so a replay raises the same alarms at the same samples as the live run.
 *
 * Baseline: given (value, se_b = 0), or learned as the mean of the estimates (and the
 * mean of their standard errors) over the sample-time window
 * [learn_start_s, learn_start_s + learn_duration_s) from the start of the run; no
 * alarm is evaluated before the baseline exists. If the window passes without a single
 * usable estimate, no baseline is ever learned and learn_missed says so (the alarm of
 * that parameter stays off for the run).
 *
 * Unusable rows (vd_alarm_update_row with usable = false: vibidd's rows flagged E, no
 * estimate, or P, a physically impossible estimate) are ignored like non-finite values:
 * they are not learned from, they neither raise nor clear, and they do not change the
 * out/in state or when it began. The sample time they cover is not evidence either way;
 * the next usable row judges the state as if they were absent (an excursion that is out
 * before and after a run of unusable rows counts as continuously out).
 */
#ifndef VIBIDD_ALARM_H
#define VIBIDD_ALARM_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <vibid/change.h>

#include "config.h" /* VD_MAX_PARAMS */

typedef struct vd_alarm_config {
    double threshold;     /* in standard errors, > 0 */
    double min_relative;  /* >= 0 */
    double hold_s;        /* >= 0 */
    bool learn;           /* true: learn the baseline; false: use `baseline` */
    double baseline;      /* when !learn */
    double learn_start_s, learn_duration_s;
} vd_alarm_config;

typedef enum vd_alarm_event { VD_ALARM_NONE = 0, VD_ALARM_RAISED = 1, VD_ALARM_CLEARED = 2 } vd_alarm_event;

typedef struct vd_alarm {
    vd_alarm_config cfg;
    bool have_baseline;
    double base, base_se;
    double sum, sum_se;   /* learning */
    uint64_t n_learn;
    bool out;             /* currently beyond the threshold */
    double since_s;       /* time the current out/in state began */
    bool active;          /* alarm raised */
    double last_z;
    bool learn_missed;    /* the learning window passed without a usable estimate */
} vd_alarm;

void vd_alarm_init(vd_alarm *a, const vd_alarm_config *cfg);
/* One estimate at run time t_s (s since the first sample). se <= 0 or non-finite
 * values are ignored for the alarm (nothing can be said). Returns the event. */
vd_alarm_event vd_alarm_update(vd_alarm *a, double t_s, double theta, double se);
/* One track row: vd_alarm_update when usable, else nothing but the learn_missed
 * bookkeeping (VD_ALARM_NONE). */
vd_alarm_event vd_alarm_update_row(vd_alarm *a, double t_s, double theta, double se, bool usable);

/* An alarm event as the log and every output get it (output.h: vd_output_alarm). */
struct vd_row;
typedef struct vd_alarm_report {
    const char *param;        /* the parameter's name */
    int raised;               /* 1 raised, 0 cleared */
    const struct vd_row *row; /* the row that raised or cleared it */
    const char *test;         /* "cusum" or "threshold" */
    double value;             /* the row's estimate */
    double baseline;          /* the reference value m (cusum) or baseline b (threshold) */
    double z;                 /* cusum: change / change_se; threshold: the row's z */
    double statistic, threshold; /* cusum: the CUSUM and its threshold (units of the block
                                    estimates' standard deviation); threshold: z and the
                                    configured threshold */
    double change, change_se; /* cusum: the estimated change from the reference and its
                                 standard error; threshold: value - baseline and NaN */
    uint64_t onset_index;     /* cusum: the estimated onset's sample index; threshold: the
                                 row's index */
} vd_alarm_report;

/* The change test over the alarmed parameters (vibid/change.h): one detector, rows pushed in
 * order, the reference learned over [learn_start, learn_start + learn_duration) of sample
 * time (extended until every parameter has VIBID_CHANGE_MIN_BLOCKS blocks), a given
 * baseline replacing the learned mean (then known exactly). */
typedef struct vd_cusum {
    vibid_change *det;
    size_t n;                 /* alarmed parameters */
    size_t param[VD_MAX_PARAMS]; /* their indices in the stand's parameter order */
    double learn_start_s, learn_end_s;
    bool have_given[VD_MAX_PARAMS];
    double given[VD_MAX_PARAMS];
    bool have_reference;
    bool learning_extended;   /* the window passed without enough blocks: learning goes on */
    char why[256];            /* why it goes on (the library's message) */
} vd_cusum;

typedef struct vd_cusum_config {
    double sample_rate_hz, forgetting, row_interval;
    double false_alarms_per_year, horizon_s, detection_probability, min_relative;
    double learn_start_s, learn_duration_s;
    size_t n_params;                            /* the stand's */
    size_t n_covariates;                        /* per row (vd_row.cov), 0 .. VD_MAX_COVARIATES */
    const bool *enabled;                        /* [n_params] */
    const bool *has_baseline;                   /* [n_params] */
    const double *baseline;                     /* [n_params] */
} vd_cusum_config;

/* 0, or -1 with err (a configuration the library refuses). No alarmed parameter: det NULL. */
int vd_cusum_init(vd_cusum *c, const vd_cusum_config *cfg, char *err, size_t cap);
void vd_cusum_free(vd_cusum *c);
/* One recursive row: theta of the stand's parameters at sample index, the covariates' means
 * over its block (n_covariates values; may be NULL without), its block usable or not, at run
 * time t_s. Events into ev[0 .. return value), param = the stand's index, at most n events (ev
 * holds VD_MAX_PARAMS). *reference_now: this row completed the reference. *out_of_range: the
 * row was tested with covariates outside the reference's range (vibid/change.h point 6: it
 * is weighed down, the row is flagged C). */
typedef struct vd_cusum_event {
    size_t param;
    int raised;
    double statistic, threshold, change, change_se, reference;
    uint64_t onset_index;
} vd_cusum_event;
size_t vd_cusum_row(vd_cusum *c, uint64_t index, double t_s, const double *theta, const double *cov, bool usable,
                    vd_cusum_event *ev, bool *reference_now, bool *out_of_range);
/* A reference from elsewhere (a saved one, reference.h), ref[0 .. c->n) in the alarmed
 * parameters' order; a given baseline still replaces its mean. 0, or -1 with err. */
int vd_cusum_set_reference(vd_cusum *c, const vibid_change_reference *ref, char *err, size_t cap);
/* The reference of the stand's parameter k (false when k is not alarmed or no reference). */
bool vd_cusum_reference(const vd_cusum *c, size_t k, vibid_change_reference *ref);
/* The live state of the stand's parameter k (NULL when k is not alarmed or no reference). */
bool vd_cusum_state(const vd_cusum *c, size_t k, double *statistic, double *mdc, double *mdc_relative,
                    bool *active);

#endif
