/* oma_track.h: output-only tracking of modes (an `oma` configuration, config.h
 * vd_oma_config; docs/vibidd.md "Output-only tracking"; issue 34 item 3).
 *
 * The estimation thread appends every sample (the response channels, outliers already NaN,
 * then the covariates) to a samples ring (worker.h; vd_omat_push, allocation-free; a gap in
 * the source is one all-NaN sample). Every oma.every seconds of sample index it asks the
 * worker thread (vibidd-oma, low priority) for an identification (vd_omat_request). The
 * worker owns the SSI-cov object (vibid/oma.h): it moves the samples that arrived since its
 * last job from the ring into the covariance blocks (vibid_oma_push_block: the per-sample
 * accumulation, as matrix products per block), and once the window (max_blocks complete
 * blocks of oma.block seconds) is full it identifies, matches the modes found to the tracked
 * ones and publishes the result; the estimation thread takes it (vd_omat_take) and writes a
 * track row whose parameters are f<j>_hz and zeta<j> of the tracked modes.
 *
 * Samples the worker could not copy before the ring overwrote them (it fell behind by more
 * than the ring holds: two periods plus a block) are lost to the identification: a gap
 * there (no covariance product spans it), counted (lost_samples) and logged.
 *
 * Tracked modes. With oma.modes = [f_1 .. f_M] each tracked mode j starts at the identified
 * mode nearest to f_j within match_freq (relative); with oma.modes = M they are the M lowest
 * modes of the first identification that finds at least M. Afterwards a mode of a window
 * continues tracked mode j when |f - f_j| <= match_freq f_j and MAC(phi, phi_j) >= match_mac
 * (f_j, phi_j: the last mode it continued), pairs assigned greedily by |f - f_j| / f_j +
 * (1 - MAC), each mode and each tracked mode at most once. A tracked mode without a match is
 * NaN in that row (and keeps its last frequency and shape for the next window); a row in
 * which no tracked mode is found (or before they exist) is flagged E.
 *
 * The change test (alarm.h) takes the rows whose windows do not overlap (one in
 * ceil(window / every)): the modes of disjoint windows are independent estimates.
 */
#ifndef VIBIDD_OMA_TRACK_H
#define VIBIDD_OMA_TRACK_H

#include <math.h>
#include <stdbool.h>
#include <stdint.h>

#include <vibid/oma.h>

#include "config.h"
#include "worker.h"

typedef struct vd_omat_result {
    bool filling;                 /* the window is not full yet: no identification, no row */
    bool identified;              /* an identification ran (the window was full) */
    bool established;             /* the tracked modes exist */
    char reason[512];             /* why no identification or no tracked mode, "" when fine */
    uint64_t end_index;           /* sample index (from the run's start) of the window's last sample */
    int64_t end_t_us;             /* its time */
    double theta[VD_MAX_PARAMS];  /* f_1, zeta_1, f_2, ...: NaN where a tracked mode was not found */
    double se[VD_MAX_PARAMS];
    size_t found;                 /* tracked modes found in this window */
    size_t n_identified;          /* modes the identification selected */
    double cov[VD_MAX_COVARIATES];/* the covariates' means over the window (NaN: none finite) */
    uint64_t window_samples;      /* samples in the window (gaps included) */
    uint64_t lost_samples;        /* samples lost to the ring since the previous result */
    double duration_s;            /* the job's wall time */
} vd_omat_result;

typedef struct vd_omat {
    bool on;
    const vd_config *cfg;
    size_t nch, ncov;             /* a ring sample: nch responses, then ncov covariates */
    uint64_t every_n, block_n;    /* samples */
    size_t max_blocks;
    vd_sample_ring ring;
    vd_worker worker;             /* vibidd-oma */
    /* the request (estimation thread, before vd_worker_request) */
    uint64_t req_end;             /* ring sequence number: the samples before it */
    uint64_t req_end_index;
    int64_t req_end_t_us;
    vd_omat_result res;           /* the worker's, read after vd_worker_done */
    /* the worker's own */
    vibid_oma *oma;
    uint64_t consumed;            /* ring samples moved into the blocks */
    double *buf;                  /* chunk_n x (nch + ncov), column-major */
    uint64_t chunk_n;
    double *cov_sum, *cov_cnt;    /* per block (max_blocks + 1 slots, round robin) x ncov */
    uint64_t pushed;              /* samples pushed into oma (gaps included) */
    uint64_t lost_since;          /* lost samples since the last result */
    size_t modes_cap;
    vibid_oma_mode *modes;
    double *shape_re, *shape_im;  /* modes_cap x nch, column-major (vibid_oma_get_modes) */
    bool established;
    double ref_f[VD_OMA_MAX_MODES];
    double *ref_re, *ref_im;      /* n_modes x nch: the tracked modes' last shapes (row j) */
    /* counters (estimation thread) */
    uint64_t done, skipped_busy, lost_samples, windows_without;
    double last_duration_s;
} vd_omat;

/* Prepares the ring, the SSI object and buffers for cfg's oma group (o->on = false without
 * one). 0, or -1 with err. */
int vd_omat_init(vd_omat *o, const vd_config *cfg, char *err, size_t cap);
int vd_omat_start(vd_omat *o, char *err, size_t cap);
void vd_omat_fini(vd_omat *o);

/* Estimation thread: one sample: the response channels (nch values, the channels' units,
 * NaN where taken out) and the raw record's values (for the covariates). Allocation-free. */
void vd_omat_push(vd_omat *o, const double *responses, const double *record_values);
/* Estimation thread: a gap of the source (one all-NaN sample in the ring). */
void vd_omat_gap(vd_omat *o);
/* Estimation thread, after the push of the sample with index end_index: an identification
 * is due (every every_n samples of sample index). */
static inline bool vd_omat_due(const vd_omat *o, uint64_t end_index)
{
    return o->on && (end_index + 1) % o->every_n == 0;
}
/* Estimation thread: asks for the identification at the ring's current end. false when the
 * worker is busy (counted; the next request covers these samples as well). */
bool vd_omat_request(vd_omat *o, uint64_t end_index, int64_t end_t_us);
/* The same, run in the calling thread (an unpaced replay: worker.h vd_worker_run_here); the
 * result is ready on return (vd_omat_take). */
bool vd_omat_run_here(vd_omat *o, uint64_t end_index, int64_t end_t_us);
/* Estimation thread: a result is ready (nothing else done: vd_omat_take takes it). */
bool vd_omat_ready(const vd_omat *o);
/* Estimation thread: the result when one is ready, counted (then vd_omat_release), else NULL. */
const vd_omat_result *vd_omat_take(vd_omat *o);
void vd_omat_release(vd_omat *o);
bool vd_omat_busy(const vd_omat *o);
void vd_omat_wait(vd_omat *o);

/* Rows whose windows do not overlap: one in this many goes to the change test. */
static inline uint64_t vd_omat_test_stride(const vd_config *cfg)
{
    return (uint64_t)ceil(cfg->oma.window_s / cfg->oma.every_s - 1e-9);
}

#endif
