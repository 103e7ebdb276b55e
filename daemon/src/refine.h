/* refine.h: the output-error refinement of the recursive estimate (docs/vibidd.md
 * "Refinement"; issue 29 item 4).
 *
 * The estimation thread copies every sample it pushes (model layout, outliers already NaN)
 * into a preallocated ring of window + 2 x refine_every seconds (vd_refine_push: one
 * memcpy, no allocation). Every refine_every seconds of sample time, when the refine thread
 * is idle, it hands over the ring range of the last window and the current recursive
 * estimate as the start (vd_refine_request). The refine thread (low priority: SCHED_IDLE,
 * else nice 19; named vibidd-refine)
 * copies the range into its own column-major buffer, checks with the ring's sequence
 * counter that nothing it copied was overwritten meanwhile (else: an overrun, counted),
 * runs vibid_oe_fit and publishes the result; the estimation thread picks it up
 * (vd_refine_take) and writes a row flagged W.
 *
 * The hand-over (one job at a time, no lock the estimation thread could wait on) and the
 * samples ring (a seqlock) are worker.h's.
 */
#ifndef VIBIDD_REFINE_H
#define VIBIDD_REFINE_H

#include <stdbool.h>
#include <stdint.h>

#include <vibid/output_error.h>

#include "config.h"
#include "worker.h"

typedef struct vd_refine_result {
    bool ok;                       /* a sound fit: theta, se, cov hold */
    bool overrun;                  /* the window was overwritten before it was copied */
    double theta[VD_MAX_PARAMS], se[VD_MAX_PARAMS];
    double *cov;                   /* p x p (owned by vd_refine) */
    unsigned quality;              /* VIBID_QUALITY_*: SE_INVALID when interp_z > 1 */
    double interp_z;               /* vibid_oe_fit_info.interp_z: the input path's shift in se */
    uint64_t n_samples;            /* samples of the window */
    char reason[512];              /* why the fit failed (the library's message) */
    uint64_t end_index;            /* sample index (from the run's start) of the window's last sample */
    int64_t end_t_us;              /* its time */
    double duration_s;             /* the fit's wall time */
} vd_refine_result;

typedef struct vd_refine {
    bool on;
    size_t nch, p;
    uint64_t every_n, window_n;    /* samples */
    vd_sample_ring ring;           /* estimation thread writes, refine thread reads */
    uint64_t clean_from;           /* first ring sequence number after the last gap */
    /* the request (written by the estimation thread before vd_worker_request) */
    uint64_t req_start, req_end;   /* ring sequence numbers [start, end) */
    double req_theta[VD_MAX_PARAMS];
    uint64_t req_end_index;
    int64_t req_end_t_us;
    vd_refine_result res;          /* written by the refine thread before it is done */
    vd_worker worker;              /* the refine thread (vibidd-refine) */
    /* the refine thread's own */
    bool disturbed;                /* the stand has a disturbance: the prediction-error fit, more starts */
    bool have_nominal, have_last;  /* nominal: every unknown has a start value in the stand */
    double nominal[VD_MAX_PARAMS], last_theta[VD_MAX_PARAMS];  /* last_theta: the last sound fit's */
    double starts[3 * VD_MAX_PARAMS];                          /* p x n_starts, column-major */
    vibid_oe *oe;
    double *buf;                   /* window_n x nch, column-major */
    double sample_time;
    /* counters (estimation thread) */
    uint64_t done, failed, overruns, skipped_busy, skipped_gap;
    double last_duration_s;
    bool fail_episode;             /* a failure was logged; the next success ends the episode */
} vd_refine;

/* Prepares the ring, buffers and fit when cfg->refine_every_s > 0 (else r->on = false).
 * 0, or -1 with err. */
int vd_refine_init(vd_refine *r, const vd_config *cfg, size_t nch, size_t p, char *err, size_t cap);
/* After the estimator is made (its method resolved): a refinement on by default is turned
 * off (refine_why says so) when `auto` chose the EKF on a stand without disturbance; an
 * explicit one is an error then. A stand with a disturbance keeps it (the prediction-error
 * fit refines the EKF's estimate).
 * 0, or -1 with err. Called by the daemon's start and by --check. */
int vd_refine_resolve(vd_config *cfg, vibid_estimator resolved, char *err, size_t cap);
/* Starts the refine thread (SCHED_IDLE, else nice 19). 0, or -1 with err. */
int vd_refine_start(vd_refine *r, char *err, size_t cap);
/* Stops and joins the thread (a running fit ends first), frees everything. */
void vd_refine_fini(vd_refine *r);

/* Estimation thread: one sample (nch values) into the ring. Allocation-free. */
static inline void vd_refine_push(vd_refine *r, const double *x)
{
    vd_sample_ring_push(&r->ring, x);
}
/* Estimation thread: a gap in the samples: no window may span it. */
void vd_refine_gap(vd_refine *r);
/* Estimation thread, after the push of the sample with index end_index: 1 when a refinement
 * is due at it (every every_n samples of sample index). */
static inline bool vd_refine_due(const vd_refine *r, uint64_t end_index)
{
    return r->on && (end_index + 1) % r->every_n == 0;
}
/* Estimation thread: hands the last window over with start values theta. 1 when handed
 * over; 0 when the thread is busy or the window spans a gap (counted). */
int vd_refine_request(vd_refine *r, const double *theta, uint64_t end_index, int64_t end_t_us);
/* Estimation thread: the result when one is ready (the caller reads it, then calls
 * vd_refine_release), else NULL. */
const vd_refine_result *vd_refine_take(vd_refine *r);
void vd_refine_release(vd_refine *r);
/* Estimation thread: true while a fit is requested or runs (the thread is not idle). */
bool vd_refine_busy(const vd_refine *r);
/* Estimation thread: waits (sleeping 100 us at a time) while a refinement runs (replay:
 * reproducible rows; the end of a run: nothing lost). */
void vd_refine_wait(vd_refine *r);

#endif
