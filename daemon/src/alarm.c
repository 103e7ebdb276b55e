/* alarm.c: see alarm.h. */
#include "alarm.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include <vibid/change.h>

void vd_alarm_init(vd_alarm *a, const vd_alarm_config *cfg)
{
    memset(a, 0, sizeof *a);
    a->cfg = *cfg;
    if (!cfg->learn) {
        a->have_baseline = true;
        a->base = cfg->baseline;
        a->base_se = 0.0;
    }
}

static void note_learn_missed(vd_alarm *a, double t_s)
{
    if (!a->have_baseline && a->n_learn == 0 && t_s >= a->cfg.learn_start_s + a->cfg.learn_duration_s)
        a->learn_missed = true;
}

vd_alarm_event vd_alarm_update_row(vd_alarm *a, double t_s, double theta, double se, bool usable)
{
    if (!usable) {
        note_learn_missed(a, t_s);
        return VD_ALARM_NONE;
    }
    return vd_alarm_update(a, t_s, theta, se);
}

vd_alarm_event vd_alarm_update(vd_alarm *a, double t_s, double theta, double se)
{
    note_learn_missed(a, t_s);
    if (!isfinite(theta) || !isfinite(se) || se < 0.0)
        return VD_ALARM_NONE;
    if (!a->have_baseline) {
        double t0 = a->cfg.learn_start_s, t1 = t0 + a->cfg.learn_duration_s;
        if (t_s >= t0 && t_s < t1) {
            a->sum += theta;
            a->sum_se += se;
            a->n_learn++;
        } else if (t_s >= t1 && a->n_learn > 0) {
            a->base = a->sum / (double)a->n_learn;
            a->base_se = a->sum_se / (double)a->n_learn;
            a->have_baseline = true;
        }
        if (!a->have_baseline)
            return VD_ALARM_NONE;
    }
    double dev = fabs(theta - a->base);
    double s = sqrt(se * se + a->base_se * a->base_se);
    a->last_z = s > 0.0 ? dev / s : (dev > 0.0 ? INFINITY : 0.0);
    bool out = a->last_z > a->cfg.threshold && dev > a->cfg.min_relative * fabs(a->base);
    if (out != a->out) {
        a->out = out;
        a->since_s = t_s;
    }
    if (out && !a->active && t_s - a->since_s >= a->cfg.hold_s) {
        a->active = true;
        return VD_ALARM_RAISED;
    }
    if (!out && a->active && t_s - a->since_s >= a->cfg.hold_s) {
        a->active = false;
        return VD_ALARM_CLEARED;
    }
    return VD_ALARM_NONE;
}

/* ---- the change test (vibid/change.h) ---- */

int vd_cusum_init(vd_cusum *c, const vd_cusum_config *cfg, char *err, size_t cap)
{
    memset(c, 0, sizeof *c);
    c->learn_start_s = cfg->learn_start_s;
    c->learn_end_s = cfg->learn_start_s + cfg->learn_duration_s;
    for (size_t k = 0; k < cfg->n_params && k < VD_MAX_PARAMS; k++) {
        if (!cfg->enabled[k])
            continue;
        c->have_given[c->n] = cfg->has_baseline[k];
        c->given[c->n] = cfg->baseline[k];
        c->param[c->n++] = k;
    }
    if (c->n == 0)
        return 0;
    vibid_change_config cc;
    vibid_change_config_init(&cc, c->n);
    cc.sample_rate_hz = cfg->sample_rate_hz;
    cc.forgetting = cfg->forgetting;
    cc.row_interval = cfg->row_interval;
    cc.false_alarms_per_year = cfg->false_alarms_per_year;
    cc.horizon_s = cfg->horizon_s;
    cc.detection_probability = cfg->detection_probability;
    cc.min_relative = cfg->min_relative;
    cc.n_covariates = cfg->n_covariates;
    c->det = vibid_change_create(&cc);
    if (!c->det) {
        snprintf(err, cap, "alarms: %s", vibid_last_error());
        return -1;
    }
    return 0;
}

void vd_cusum_free(vd_cusum *c)
{
    vibid_change_destroy(c->det);
    c->det = NULL;
}

/* The reference from the blocks learned so far, a given baseline in place of the learned mean. */
static bool cusum_end_learning(vd_cusum *c)
{
    if (vibid_change_end_learning(c->det) != VIBID_OK) {
        snprintf(c->why, sizeof c->why, "%s", vibid_last_error());
        return false;
    }
    vibid_change_reference ref[VD_MAX_PARAMS];
    bool given = false;
    if (vibid_change_get_reference(c->det, ref) != VIBID_OK)
        return false;
    for (size_t i = 0; i < c->n; i++)
        if (c->have_given[i]) {
            ref[i].mean = c->given[i];
            ref[i].n_mean = INFINITY;
            given = true;
        }
    if (given && vibid_change_set_reference(c->det, ref) != VIBID_OK) {
        snprintf(c->why, sizeof c->why, "%s", vibid_last_error());
        return false;
    }
    return true;
}

size_t vd_cusum_row(vd_cusum *c, uint64_t index, double t_s, const double *theta, const double *cov, bool usable,
                    vd_cusum_event *ev, bool *reference_now, bool *out_of_range)
{
    *reference_now = false;
    *out_of_range = false;
    if (!c->det)
        return 0;
    double th[VD_MAX_PARAMS];
    for (size_t i = 0; i < c->n; i++)
        th[i] = theta[c->param[i]];
    /* the window, and after it (without a reference yet) more learning */
    const bool learn = !c->have_reference && t_s >= c->learn_start_s;
    if (!c->have_reference && learn && t_s >= c->learn_end_s) {
        if (cusum_end_learning(c)) {
            c->have_reference = true;
            *reference_now = true;
        } else {
            c->learning_extended = true;
        }
    }
    vibid_change_event e[VD_MAX_PARAMS];
    size_t ne = 0;
    const vibid_change_phase phase = c->have_reference ? VIBID_CHANGE_TEST : VIBID_CHANGE_LEARN;
    /* before learn_start: chained only (use = 0): the estimator's start transient is neither
       learned nor tested, also with a reference read from a file */
    const int use = usable && t_s >= c->learn_start_s;
    if (vibid_change_push(c->det, index, th, cov, use, phase, e, c->n, &ne) != VIBID_OK)
        return 0; /* an index that does not increase: the row is not tested */
    for (size_t i = 0; use && phase == VIBID_CHANGE_TEST && i < c->n && !*out_of_range; i++) {
        vibid_change_state st;
        *out_of_range = vibid_change_get_state(c->det, i, &st) == VIBID_OK && st.out_of_range;
    }
    for (size_t j = 0; j < ne; j++) {
        ev[j].param = c->param[e[j].param];
        ev[j].raised = e[j].kind == VIBID_CHANGE_RAISED;
        ev[j].statistic = e[j].statistic;
        ev[j].threshold = e[j].threshold;
        ev[j].change = e[j].change;
        ev[j].change_se = e[j].change_se;
        ev[j].reference = e[j].reference;
        ev[j].onset_index = e[j].onset_index;
    }
    return ne;
}

bool vd_cusum_state(const vd_cusum *c, size_t k, double *statistic, double *mdc, double *mdc_relative, bool *active)
{
    if (!c->det || !c->have_reference)
        return false;
    for (size_t i = 0; i < c->n; i++)
        if (c->param[i] == k) {
            vibid_change_state st;
            if (vibid_change_get_state(c->det, i, &st) != VIBID_OK)
                return false;
            *statistic = st.statistic;
            *mdc = st.mdc;
            *mdc_relative = st.mdc_relative;
            *active = st.active != 0;
            return true;
        }
    return false;
}

bool vd_cusum_reference(const vd_cusum *c, size_t k, vibid_change_reference *ref)
{
    vibid_change_reference all[VD_MAX_PARAMS];
    if (!c->det || !c->have_reference || vibid_change_get_reference(c->det, all) != VIBID_OK)
        return false;
    for (size_t i = 0; i < c->n; i++)
        if (c->param[i] == k) {
            *ref = all[i];
            return true;
        }
    return false;
}

int vd_cusum_set_reference(vd_cusum *c, const vibid_change_reference *ref, char *err, size_t cap)
{
    vibid_change_reference r[VD_MAX_PARAMS];
    for (size_t i = 0; i < c->n; i++) {
        r[i] = ref[i];
        if (c->have_given[i]) {
            r[i].mean = c->given[i];
            r[i].n_mean = INFINITY;
        }
    }
    if (!c->det || vibid_change_set_reference(c->det, r) != VIBID_OK) {
        snprintf(err, cap, "%s", c->det ? vibid_last_error() : "no alarmed parameter");
        return -1;
    }
    c->have_reference = true;
    return 0;
}
