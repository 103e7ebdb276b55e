/* alarm.h: drift alarms of one parameter against a baseline.
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
#include <stdint.h>

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

#endif
