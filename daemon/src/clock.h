/* clock.h: the daemon's one monotonic clock, for durations, deadlines and intervals (rate
 * limits, reconnection back-off, drain deadlines, latency). CLOCK_MONOTONIC: not stepped by
 * NTP or an operator setting the date, so a measured interval is never negative; its origin
 * is unspecified (boot on Linux), so values are only compared with each other, never shown
 * as dates. Safe from any thread, no allocation (clock_gettime is a vDSO call on Linux). */
#ifndef VIBIDD_CLOCK_H
#define VIBIDD_CLOCK_H

#include <stdint.h>
#include <time.h>

/* CLOCK_MONOTONIC now, in ns (int64: 292 years of uptime). */
static inline int64_t vd_mono_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

/* CLOCK_MONOTONIC now, in s: the clock's ns to within a double's rounding, i.e. better
 * than 1 us for the first 136 years (2^32 s) of uptime. */
static inline double vd_mono_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

#endif
