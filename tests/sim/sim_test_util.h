/* tests/sim/sim_test_util.h: helpers shared by the sim tests (temporary stand files,
 * running vibid-sim). */
#ifndef SIM_TEST_UTIL_H
#define SIM_TEST_UTIL_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static inline const char *tmp_dir(void)
{
    const char *d = getenv("VIBID_SIM_TMP");
    return d && *d ? d : "/tmp";
}

/* Writes text to <tmp>/<name>; returns the path (static buffer rotation of 8). */
static inline const char *write_tmp(const char *name, const char *text)
{
    static char bufs[8][512];
    static int idx;
    char *p = bufs[idx++ % 8];
    snprintf(p, 512, "%s/%s", tmp_dir(), name);
    FILE *f = fopen(p, "w");
    if (!f) return NULL;
    fputs(text, f);
    fclose(f);
    return p;
}

static inline const char *tmp_path(const char *name)
{
    static char bufs[8][512];
    static int idx;
    char *p = bufs[idx++ % 8];
    snprintf(p, 512, "%s/%s", tmp_dir(), name);
    return p;
}

#endif
