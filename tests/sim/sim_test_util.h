/* tests/sim/sim_test_util.h: helpers shared by the sim tests (temporary stand files,
 * running vibid-sim). */
#ifndef SIM_TEST_UTIL_H
#define SIM_TEST_UTIL_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "sim_config.h"

/* The integrator the tests run (sim.accuracy and sim.hold run twice, ctest names
 * sim.accuracy / sim.accuracy_arkode): VIBID_SIM_TEST_INTEGRATOR=arkode forces ARKODE on
 * every interval; otherwise the configuration's choice stays (default "auto": the exact
 * step wherever it is exact). Call after sim_config_load. */
static inline void apply_test_integrator(sim_config *cfg)
{
    const char *s = getenv("VIBID_SIM_TEST_INTEGRATOR");
    if (s && strcmp(s, "arkode") == 0) cfg->integrator = SIM_INTEGRATOR_ARKODE;
}

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

#ifdef VIBID_SIM_EXE
#include <sys/wait.h>
/* Runs vibid-sim with args; returns its exit status (-1 if it did not exit); its stderr
 * text in errbuf (NULL: not kept). */
static inline int run_sim(const char *args, char *errbuf, size_t cap)
{
    char cmd[4096];
    const char *errf = tmp_path("sim_stderr.txt");
    snprintf(cmd, sizeof cmd, "%s %s 2>%s", VIBID_SIM_EXE, args, errf);
    int st = system(cmd);
    if (errbuf) {
        errbuf[0] = 0;
        FILE *f = fopen(errf, "r");
        if (f) {
            size_t n = fread(errbuf, 1, cap - 1, f);
            errbuf[n] = 0;
            fclose(f);
        }
    }
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}
#endif

#endif
