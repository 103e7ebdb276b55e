/* alarm.c: see alarm.h. */
#include "alarm.h"

#include <math.h>
#include <string.h>

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
