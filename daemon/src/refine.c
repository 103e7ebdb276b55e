/* refine.c: see refine.h. */
#include "refine.h"
#include "clock.h"
#include "log.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void refine_once(void *arg);

int vd_refine_init(vd_refine *r, const vd_config *cfg, size_t nch, size_t p, char *err, size_t cap)
{
    memset(r, 0, sizeof *r);
    if (!(cfg->refine_every_s > 0))
        return 0;
    const double fa = cfg->sample_rate;
    r->nch = nch;
    r->p = p;
    r->sample_time = 1.0 / fa;
    r->every_n = (uint64_t)fmax(1.0, round(cfg->refine_every_s * fa));
    r->window_n = (uint64_t)fmax(400.0, round(cfg->refine_window_s * fa));
    /* the window plus two periods: the refine thread has two periods to copy its window
     * before the estimation thread reaches it again */
    const uint64_t ring_n = r->window_n + 2 * r->every_n;
    const int ring_rc = vd_sample_ring_init(&r->ring, ring_n, nch);
    r->buf = malloc(r->window_n * nch * sizeof *r->buf);
    r->res.cov = malloc(p * p * sizeof *r->res.cov);
    if (ring_rc || !r->buf || !r->res.cov) {
        snprintf(err, cap, "estimator.refine_window: out of memory for %llu samples of %zu channels",
                 (unsigned long long)(ring_n + r->window_n), nch);
        vd_refine_fini(r);
        return -1;
    }
    vibid_oe_config oc;
    vibid_oe_config_init(&oc, r->sample_time);
    const vibid_model *model = vibid_stand_model(cfg->stand);
    vibid_model_dims dims;
    r->disturbed = vibid_model_get_dims(model, &dims) == VIBID_OK && dims.n_disturbances;
    r->have_nominal = vibid_model_nominal(model, r->nominal) == VIBID_OK;
    for (size_t i = 0; r->have_nominal && i < p; i++)
        r->have_nominal = r->nominal[i] != 0.0 && isfinite(r->nominal[i]);
    r->oe = vibid_oe_create(model, &oc);
    if (!r->oe) {
        snprintf(err, cap, "estimator.refine_every: the output-error fit refuses the stand: %s", vibid_last_error());
        vd_refine_fini(r);
        return -1;
    }
    if (vd_worker_init(&r->worker, "vibidd-refine", refine_once, r, err, cap)) {
        vd_refine_fini(r);
        return -1;
    }
    r->on = true;
    return 0;
}

/* Copies the requested window out of the ring and fits it. Refine thread. */
static void refine_once(void *arg)
{
    vd_refine *r = arg;
    vd_refine_result *res = &r->res;
    const uint64_t start = r->req_start, end = r->req_end, n = end - start;
    res->ok = res->overrun = false;
    res->reason[0] = '\0';
    res->end_index = r->req_end_index;
    res->end_t_us = r->req_end_t_us;
    res->duration_s = 0;
    res->quality = 0;
    res->n_samples = n;
    if (!vd_sample_ring_copy(&r->ring, start, n, r->buf, (size_t)n)) {
        res->overrun = true;
        snprintf(res->reason, sizeof res->reason,
                 "the window's samples were overwritten before the refine thread copied them");
        return;
    }
    const double t0 = vd_mono_s();
    /* Starts: the recursive estimate; on a stand with a disturbance also the last refined
     * estimate and the stand's nominal values (the EKF's estimate may be far off there:
     * README "Stands with disturbances"). The fit keeps the best. */
    size_t n_starts = 1;
    memcpy(r->starts, r->req_theta, r->p * sizeof *r->starts);
    if (r->disturbed) {
        if (r->have_last) {
            memcpy(r->starts + n_starts * r->p, r->last_theta, r->p * sizeof *r->starts);
            n_starts++;
        }
        if (r->have_nominal) {
            memcpy(r->starts + n_starts * r->p, r->nominal, r->p * sizeof *r->starts);
            n_starts++;
        }
    }
    vibid_status st = vibid_oe_fit(r->oe, (size_t)n, r->buf, n_starts, r->starts);
    vibid_oe_fit_info info = {0};
    if (st == VIBID_OK)
        st = vibid_oe_result(r->oe, res->theta, res->se, res->cov, NULL, NULL, NULL, &info);
    /* The standard errors cover the noise, not the inputs' unknown path between samples
     * (output_error.h, "Input path"): where that moves the estimate by more than one of
     * them and the data do not show the straight line to be the path, the row says U. */
    res->interp_z = info.interp_z;
    if (st == VIBID_OK && info.input_path_uncovered)
        res->quality |= VIBID_QUALITY_SE_INVALID;
    res->duration_s = vd_mono_s() - t0;
    if (st != VIBID_OK) {
        snprintf(res->reason, sizeof res->reason, "%s", vibid_last_error());
        return;
    }
    res->ok = true;
    memcpy(r->last_theta, res->theta, r->p * sizeof *res->theta);
    r->have_last = true;
}

int vd_refine_start(vd_refine *r, char *err, size_t cap)
{
    return r->on ? vd_worker_start(&r->worker, err, cap) : 0;
}

void vd_refine_fini(vd_refine *r)
{
    vd_worker_fini(&r->worker);
    vibid_oe_destroy(r->oe);
    vd_sample_ring_fini(&r->ring);
    free(r->buf);
    free(r->res.cov);
    r->oe = NULL;
    r->buf = r->res.cov = NULL;
    r->on = false;
}

void vd_refine_gap(vd_refine *r)
{
    if (r->on)
        r->clean_from = vd_sample_ring_written(&r->ring);
}

int vd_refine_request(vd_refine *r, const double *theta, uint64_t end_index, int64_t end_t_us)
{
    if (!r->on || !r->worker.started)
        return 0;
    if (vd_worker_busy(&r->worker) || vd_worker_done(&r->worker)) {
        r->skipped_busy++;
        return 0;
    }
    const uint64_t w = vd_sample_ring_written(&r->ring);
    if (w < r->clean_from + r->window_n) { /* the run's start, or a gap, inside the window */
        r->skipped_gap++;
        return 0;
    }
    r->req_start = w - r->window_n;
    r->req_end = w;
    memcpy(r->req_theta, theta, r->p * sizeof *theta);
    r->req_end_index = end_index;
    r->req_end_t_us = end_t_us;
    return vd_worker_request(&r->worker) ? 1 : 0;
}

const vd_refine_result *vd_refine_take(vd_refine *r)
{
    return r->on && vd_worker_done(&r->worker) ? &r->res : NULL;
}

void vd_refine_release(vd_refine *r)
{
    vd_worker_release(&r->worker);
}

bool vd_refine_busy(const vd_refine *r)
{
    return r->on && vd_worker_busy(&r->worker);
}

void vd_refine_wait(vd_refine *r)
{
    if (r->on)
        vd_worker_wait(&r->worker);
}

int vd_refine_resolve(vd_config *cfg, vibid_estimator resolved, char *err, size_t cap)
{
    vibid_model_dims dims;
    if (!(cfg->refine_every_s > 0) || resolved != VIBID_ESTIMATOR_EKF)
        return 0;
    /* a stand with a disturbance: the prediction-error fit refines the EKF's estimate */
    if (vibid_model_get_dims(vibid_stand_model(cfg->stand), &dims) == VIBID_OK && dims.n_disturbances)
        return 0;
    /* auto chose the EKF: not an equation-error estimate to refine */
    if (cfg->refine_explicit) {
        snprintf(err, cap,
                 "%s: estimator.refine_every: the automatic estimator chose the EKF for this stand; refinement "
                 "needs an equation-error estimator (ls, iv, rls)",
                 cfg->path);
        return -1;
    }
    cfg->refine_every_s = 0;
    snprintf(cfg->refine_why, sizeof cfg->refine_why, "the automatic estimator chose the EKF");
    return 0;
}
