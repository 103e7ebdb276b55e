/* Internal helpers shared by the sources: clocks and absolute-deadline sleeping. */
#ifndef VIBID_DRIVERS_SOURCE_UTIL_H
#define VIBID_DRIVERS_SOURCE_UTIL_H

#include <errno.h>
#include <stdint.h>
#include <time.h>

static inline int64_t mono_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

static inline int64_t real_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

/* Sleeps until CLOCK_MONOTONIC reaches deadline_ns (absolute, TIMER_ABSTIME: no drift
 * accumulates over many periods). Returns at once if the deadline has passed. */
static inline void sleep_until_mono(int64_t deadline_ns)
{
    struct timespec ts = {(time_t)(deadline_ns / 1000000000), (long)(deadline_ns % 1000000000)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR) {
    }
}

/* End of a read() call's wait: now + timeout_ms, or "forever" for timeout_ms < 0. */
static inline int64_t wait_limit(int timeout_ms)
{
    return timeout_ms < 0 ? INT64_MAX : mono_ns() + (int64_t)timeout_ms * 1000000;
}

#endif
