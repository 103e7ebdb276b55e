/* worker.c: see worker.h. */
#include "worker.h"
#include "log.h"

#include <errno.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

int vd_worker_init(vd_worker *w, const char *name, void (*job)(void *ctx), void *ctx, char *err, size_t cap)
{
    memset(w, 0, sizeof *w);
    w->job = job;
    w->ctx = ctx;
    snprintf(w->name, sizeof w->name, "%s", name);
    atomic_init(&w->state, VD_WORKER_IDLE);
    atomic_init(&w->stop, 0);
    if (sem_init(&w->wake, 0, 0) != 0) {
        snprintf(err, cap, "%s: sem_init: %s", name, strerror(errno));
        return -1;
    }
    w->sem_ok = true;
    return 0;
}

static void *worker_main(void *arg)
{
    vd_worker *w = arg;
    /* low priority: the job takes whatever CPU the acquisition and estimation threads leave
     * (SCHED_IDLE: a waking thread of the daemon preempts it at once) */
    struct sched_param sp = {.sched_priority = 0};
    int rc = pthread_setschedparam(pthread_self(), SCHED_IDLE, &sp);
    if (rc != 0 && setpriority(PRIO_PROCESS, (id_t)gettid(), 19) != 0)
        vd_warning("%s thread: neither SCHED_IDLE (%s) nor nice 19 (%s) permitted", w->name, strerror(rc),
                   strerror(errno));
    /* named once its priority is set (ps -L, top -H; e2e_refine.sh reads it by this name) */
    pthread_setname_np(pthread_self(), w->name);
    for (;;) {
        while (sem_wait(&w->wake) != 0 && errno == EINTR) {
        }
        if (atomic_load_explicit(&w->stop, memory_order_acquire))
            break;
        if (atomic_load_explicit(&w->state, memory_order_acquire) != VD_WORKER_REQUESTED)
            continue;
        w->job(w->ctx);
        atomic_store_explicit(&w->state, VD_WORKER_DONE, memory_order_release);
    }
    return NULL;
}

int vd_worker_start(vd_worker *w, char *err, size_t cap)
{
    int rc = pthread_create(&w->thread, NULL, worker_main, w);
    if (rc != 0) {
        snprintf(err, cap, "cannot start the %s thread: %s", w->name, strerror(rc));
        return -1;
    }
    w->started = true;
    return 0;
}

void vd_worker_fini(vd_worker *w)
{
    if (w->started) {
        atomic_store_explicit(&w->stop, 1, memory_order_release);
        sem_post(&w->wake);
        pthread_join(w->thread, NULL);
        w->started = false;
    }
    if (w->sem_ok)
        sem_destroy(&w->wake);
    w->sem_ok = false;
}

bool vd_worker_request(vd_worker *w)
{
    if (!w->started || atomic_load_explicit(&w->state, memory_order_acquire) != VD_WORKER_IDLE)
        return false;
    atomic_store_explicit(&w->state, VD_WORKER_REQUESTED, memory_order_release);
    sem_post(&w->wake); /* never blocks */
    return true;
}

bool vd_worker_run_here(vd_worker *w)
{
    if (atomic_load_explicit(&w->state, memory_order_acquire) != VD_WORKER_IDLE)
        return false;
    w->job(w->ctx);
    atomic_store_explicit(&w->state, VD_WORKER_DONE, memory_order_release);
    return true;
}

bool vd_worker_done(const vd_worker *w)
{
    return atomic_load_explicit(&w->state, memory_order_acquire) == VD_WORKER_DONE;
}

void vd_worker_release(vd_worker *w)
{
    atomic_store_explicit(&w->state, VD_WORKER_IDLE, memory_order_release);
}

bool vd_worker_busy(const vd_worker *w)
{
    return atomic_load_explicit(&w->state, memory_order_acquire) == VD_WORKER_REQUESTED;
}

void vd_worker_wait(const vd_worker *w)
{
    /* the caller waits for the job: it is no longer work for idle time. On a busy machine a
     * SCHED_IDLE thread gets almost no CPU (the end of a run would wait for it without end),
     * so it runs at the normal policy from here (permitted to lower the priority it raised
     * from; if refused it stays) */
    if (w->started && vd_worker_busy(w)) {
        struct sched_param sp = {.sched_priority = 0};
        (void)pthread_setschedparam(w->thread, SCHED_OTHER, &sp);
    }
    while (w->started && vd_worker_busy(w)) {
        struct timespec ts = {0, 100000};
        nanosleep(&ts, NULL);
    }
}

int vd_sample_ring_init(vd_sample_ring *r, uint64_t cap, size_t nch)
{
    r->cap = cap;
    r->nch = nch;
    atomic_init(&r->written, 0);
    r->v = malloc(cap * nch * sizeof *r->v);
    return r->v ? 0 : -1;
}

void vd_sample_ring_fini(vd_sample_ring *r)
{
    free(r->v);
    r->v = NULL;
}

bool vd_sample_ring_copy(const vd_sample_ring *r, uint64_t start, uint64_t n, double *dst, size_t ld)
{
    if (atomic_load_explicit(&r->written, memory_order_acquire) > start + r->cap)
        return false; /* already gone */
    for (uint64_t k = 0; k < n; k++) {
        const double *slot = r->v + ((start + k) % r->cap) * r->nch;
        for (size_t i = 0; i < r->nch; i++)
            dst[i * ld + k] = slot[i];
    }
    /* the copy's reads before the check's: a sample that reused the slot of `start` while
     * it was copied shows in `written` */
    atomic_thread_fence(memory_order_acquire);
    return atomic_load_explicit(&r->written, memory_order_relaxed) < start + r->cap;
}
