/* worker.h: a low-priority background thread fed by the estimation thread, and the samples
 * ring it reads: what the output-error refinement (refine.h) and the output-only mode
 * tracking (oma_track.h) share.
 *
 * The worker: one job at a time. The estimation thread writes the job's fields, then
 * vd_worker_request (IDLE -> REQUESTED, a release store, and a post of the semaphore, which
 * never blocks); the worker thread (SCHED_IDLE, else nice 19; named as given, for ps -L and
 * top -H) runs the job and stores DONE (release); the estimation thread sees it with
 * vd_worker_done (acquire), reads the result and calls vd_worker_release (DONE -> IDLE). So
 * the job's and the result's fields written before each change are seen after it, and the
 * estimation thread never waits on a lock.
 *
 * The samples ring (vd_sample_ring): the estimation thread appends one sample (nch values)
 * at a time, allocation-free; the worker copies a range of sequence numbers out. A seqlock:
 * the writer stores `written` (samples complete) with release after each sample, and a
 * release fence orders that store before the next sample's data; the reader copies, then an
 * acquire fence, then reads `written`: if the slot of the range's first sample may have been
 * reused meanwhile, the copy is discarded (vd_sample_ring_copy returns false).
 */
#ifndef VIBIDD_WORKER_H
#define VIBIDD_WORKER_H

#include <pthread.h>
#include <semaphore.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

enum { VD_WORKER_IDLE = 0, VD_WORKER_REQUESTED = 1, VD_WORKER_DONE = 2 };

typedef struct vd_worker {
    void (*job)(void *ctx); /* runs one requested job (worker thread) */
    void *ctx;
    char name[16];          /* the thread's name (at most 15 characters) */
    _Atomic int state;
    _Atomic int stop;
    sem_t wake;
    bool sem_ok, started;
    pthread_t thread;
} vd_worker;

/* 0, or -1 with err. The thread starts with vd_worker_start (after the signals are blocked). */
int vd_worker_init(vd_worker *w, const char *name, void (*job)(void *ctx), void *ctx, char *err, size_t cap);
int vd_worker_start(vd_worker *w, char *err, size_t cap);
/* Stops and joins the thread (a running job ends first). */
void vd_worker_fini(vd_worker *w);
/* Estimation thread: hands the job over (its fields written before). false when busy. */
bool vd_worker_request(vd_worker *w);
/* Estimation thread: runs the job in the calling thread instead (its fields written before;
 * the worker idle): an unpaced replay waits for every job, and a low-priority thread the
 * caller only waits for would run only when the machine has nothing else to do. The result
 * is then ready (vd_worker_done). false when the worker is not idle. */
bool vd_worker_run_here(vd_worker *w);
/* Estimation thread: a result is ready (read it, then vd_worker_release). */
bool vd_worker_done(const vd_worker *w);
void vd_worker_release(vd_worker *w);
/* Estimation thread: a job is requested or runs. */
bool vd_worker_busy(const vd_worker *w);
/* Estimation thread: waits (sleeping 100 us at a time) while a job runs, the worker moved
 * to SCHED_OTHER for it (a SCHED_IDLE thread starves on a busy machine); it stays there. */
void vd_worker_wait(const vd_worker *w);

typedef struct vd_sample_ring {
    double *v;                /* cap x nch, row-major (one sample a row) */
    uint64_t cap;
    size_t nch;
    _Atomic uint64_t written; /* samples complete */
} vd_sample_ring;

/* 0, or -1 (out of memory). */
int vd_sample_ring_init(vd_sample_ring *r, uint64_t cap, size_t nch);
void vd_sample_ring_fini(vd_sample_ring *r);

/* Estimation thread: one sample (nch values). Allocation-free. */
static inline void vd_sample_ring_push(vd_sample_ring *r, const double *x)
{
    uint64_t s = atomic_load_explicit(&r->written, memory_order_relaxed);
    /* the store of `written` for the previous sample is ordered before these data stores
     * (the reader's overwrite check relies on it) */
    atomic_thread_fence(memory_order_release);
    double *slot = r->v + (s % r->cap) * r->nch;
    for (size_t i = 0; i < r->nch; i++)
        slot[i] = x[i];
    atomic_store_explicit(&r->written, s + 1, memory_order_release);
}

static inline uint64_t vd_sample_ring_written(const vd_sample_ring *r)
{
    return atomic_load_explicit(&r->written, memory_order_acquire);
}

/* Worker: the samples [start, start + n) into dst, column-major (column i of channel i at
 * dst + i ld, ld >= n). false when some of them were overwritten before or while they were
 * copied (dst is then garbage). */
bool vd_sample_ring_copy(const vd_sample_ring *r, uint64_t start, uint64_t n, double *dst, size_t ld);

#endif
