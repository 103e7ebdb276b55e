/* refine.c: see refine.h. */
#include "refine.h"
#include "clock.h"
#include "log.h"

#include <errno.h>
#include <math.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

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
    r->cap = r->window_n + 2 * r->every_n;
    r->ring = malloc(r->cap * nch * sizeof *r->ring);
    r->buf = malloc(r->window_n * nch * sizeof *r->buf);
    r->res.cov = malloc(p * p * sizeof *r->res.cov);
    if (!r->ring || !r->buf || !r->res.cov) {
        snprintf(err, cap, "estimator.refine_window: out of memory for %llu samples of %zu channels",
                 (unsigned long long)(r->cap + r->window_n), nch);
        vd_refine_fini(r);
        return -1;
    }
    vibid_oe_config oc;
    vibid_oe_config_init(&oc, r->sample_time);
    r->oe = vibid_oe_create(vibid_stand_model(cfg->stand), &oc);
    if (!r->oe) {
        snprintf(err, cap, "estimator.refine_every: the output-error fit refuses the stand: %s", vibid_last_error());
        vd_refine_fini(r);
        return -1;
    }
    if (sem_init(&r->wake, 0, 0) != 0) {
        snprintf(err, cap, "refinement: sem_init: %s", strerror(errno));
        vd_refine_fini(r);
        return -1;
    }
    atomic_init(&r->written, 0);
    atomic_init(&r->state, VD_REFINE_IDLE);
    atomic_init(&r->stop, 0);
    r->on = true;
    return 0;
}

/* Copies the requested window out of the ring and fits it. Refine thread. */
static void refine_once(vd_refine *r)
{
    vd_refine_result *res = &r->res;
    const uint64_t start = r->req_start, end = r->req_end, n = end - start;
    res->ok = res->overrun = false;
    res->reason[0] = '\0';
    res->end_index = r->req_end_index;
    res->end_t_us = r->req_end_t_us;
    res->duration_s = 0;
    res->quality = 0;
    res->n_samples = n;
    for (uint64_t k = 0; k < n; k++) {
        const double *slot = r->ring + ((start + k) % r->cap) * r->nch;
        for (size_t i = 0; i < r->nch; i++)
            r->buf[i * n + k] = slot[i];
    }
    /* the copy's reads before the check's: a sample that reused the slot of `start` while
     * it was copied shows in `written` (refine.h, the seqlock) */
    atomic_thread_fence(memory_order_acquire);
    const uint64_t w = atomic_load_explicit(&r->written, memory_order_relaxed);
    if (w >= start + r->cap) {
        res->overrun = true;
        snprintf(res->reason, sizeof res->reason,
                 "the window's samples were overwritten before the refine thread copied them");
        return;
    }
    const double t0 = vd_mono_s();
    vibid_status st = vibid_oe_fit(r->oe, (size_t)n, r->buf, 1, r->req_theta);
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
}

static void *refine_main(void *arg)
{
    vd_refine *r = arg;
    /* low priority: the fit takes whatever CPU the acquisition and estimation threads leave
     * (SCHED_IDLE: a waking thread of the daemon preempts it at once) */
    struct sched_param sp = {.sched_priority = 0};
    int rc = pthread_setschedparam(pthread_self(), SCHED_IDLE, &sp);
    if (rc != 0 && setpriority(PRIO_PROCESS, (id_t)gettid(), 19) != 0)
        vd_warning("refinement thread: neither SCHED_IDLE (%s) nor nice 19 (%s) permitted", strerror(rc),
                   strerror(errno));
    /* named once its priority is set (ps -L, top -H; e2e_refine.sh reads it by this name) */
    pthread_setname_np(pthread_self(), "vibidd-refine");
    for (;;) {
        while (sem_wait(&r->wake) != 0 && errno == EINTR) {
        }
        if (atomic_load_explicit(&r->stop, memory_order_acquire))
            break;
        if (atomic_load_explicit(&r->state, memory_order_acquire) != VD_REFINE_REQUESTED)
            continue;
        refine_once(r);
        atomic_store_explicit(&r->state, VD_REFINE_DONE, memory_order_release);
    }
    return NULL;
}

int vd_refine_start(vd_refine *r, char *err, size_t cap)
{
    if (!r->on)
        return 0;
    int rc = pthread_create(&r->thread, NULL, refine_main, r);
    if (rc != 0) {
        snprintf(err, cap, "cannot start the refinement thread: %s", strerror(rc));
        return -1;
    }
    r->started = true;
    return 0;
}

void vd_refine_fini(vd_refine *r)
{
    if (r->started) {
        atomic_store_explicit(&r->stop, 1, memory_order_release);
        sem_post(&r->wake);
        pthread_join(r->thread, NULL);
        r->started = false;
    }
    if (r->on)
        sem_destroy(&r->wake);
    vibid_oe_destroy(r->oe);
    free(r->ring);
    free(r->buf);
    free(r->res.cov);
    r->oe = NULL;
    r->ring = r->buf = r->res.cov = NULL;
    r->on = false;
}

void vd_refine_gap(vd_refine *r)
{
    if (r->on)
        r->clean_from = atomic_load_explicit(&r->written, memory_order_relaxed);
}

int vd_refine_request(vd_refine *r, const double *theta, uint64_t end_index, int64_t end_t_us)
{
    if (!r->on || !r->started)
        return 0;
    if (atomic_load_explicit(&r->state, memory_order_acquire) != VD_REFINE_IDLE) {
        r->skipped_busy++;
        return 0;
    }
    const uint64_t w = atomic_load_explicit(&r->written, memory_order_relaxed);
    if (w < r->clean_from + r->window_n) { /* the run's start, or a gap, inside the window */
        r->skipped_gap++;
        return 0;
    }
    r->req_start = w - r->window_n;
    r->req_end = w;
    memcpy(r->req_theta, theta, r->p * sizeof *theta);
    r->req_end_index = end_index;
    r->req_end_t_us = end_t_us;
    atomic_store_explicit(&r->state, VD_REFINE_REQUESTED, memory_order_release);
    sem_post(&r->wake); /* never blocks */
    return 1;
}

const vd_refine_result *vd_refine_take(vd_refine *r)
{
    if (!r->on || atomic_load_explicit(&r->state, memory_order_acquire) != VD_REFINE_DONE)
        return NULL;
    return &r->res;
}

void vd_refine_release(vd_refine *r)
{
    atomic_store_explicit(&r->state, VD_REFINE_IDLE, memory_order_release);
}

bool vd_refine_busy(const vd_refine *r)
{
    return r->on && atomic_load_explicit(&r->state, memory_order_acquire) == VD_REFINE_REQUESTED;
}

void vd_refine_wait(vd_refine *r)
{
    while (r->on && r->started && atomic_load_explicit(&r->state, memory_order_acquire) == VD_REFINE_REQUESTED) {
        struct timespec ts = {0, 100000};
        nanosleep(&ts, NULL);
    }
}

int vd_refine_resolve(vd_config *cfg, vibid_estimator resolved, char *err, size_t cap)
{
    if (!(cfg->refine_every_s > 0) || resolved != VIBID_ESTIMATOR_EKF)
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
