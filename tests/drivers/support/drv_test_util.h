/* Helpers shared by the drivers' tests: scratch files, a reproducible random source, the
 * bits of a double. */
#ifndef VIBID_DRV_TEST_UTIL_H
#define VIBID_DRV_TEST_UTIL_H

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* splitmix64: reproducible across runs and platforms; each test keeps its own state (seed) */
static inline uint64_t drv_splitmix64(uint64_t *state)
{
    uint64_t z = (*state += 0x9E3779B97F4A7C15u);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9u;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBu;
    return z ^ (z >> 31);
}

/* A double's 64 bits and back (bit-exact comparisons: -0 vs +0 and the last ulp count) */
static inline uint64_t drv_bits_of(double d)
{
    uint64_t b;
    memcpy(&b, &d, sizeof b);
    return b;
}

static inline double drv_from_bits(uint64_t b)
{
    double d;
    memcpy(&d, &b, sizeof d);
    return d;
}

/* Writes text to "$VIBID_DRV_TMP/<name>.<pid>" (or /tmp) and returns the path (static
 * storage per call site is the caller's: copy it). */
static inline const char *drv_write_tmp(const char *name, const char *text, size_t len, char *path, size_t cap)
{
    const char *dir = getenv("VIBID_DRV_TMP");
    snprintf(path, cap, "%s/%d-%s", dir && dir[0] ? dir : "/tmp", (int)getpid(), name);
    FILE *f = fopen(path, "wb");
    if (!f)
        return NULL;
    fwrite(text, 1, len, f);
    fclose(f);
    return path;
}

#endif
