/* cfg_fixture.h: the configuration the output modules' unit tests start from (test_mqtt.c,
 * test_influx_http.c): the paper's example 1 stand, a CSV replay of three channels and the
 * outputs group the test gives. Needs VD_SOURCE_DIR (the source tree, set by CMake). */
#ifndef VD_TEST_CFG_FIXTURE_H
#define VD_TEST_CFG_FIXTURE_H

#include <stdio.h>
#include <unistd.h>

#include "config.h"

/* Writes the configuration with outputs (libconfig text, e.g. "outputs = { ... };") to a
 * file in /tmp named after the process and name, loads it into c and removes the file.
 * 0, or -1 with err filled as vd_config_load fills it. */
static inline int vd_test_load_outputs(const char *name, const char *outputs, vd_config *c, vd_config_error *err) {
    char path[256];
    snprintf(path, sizeof path, "/tmp/vd_test_outputs_%d_%s.cfg", (int)getpid(), name);
    FILE *f = fopen(path, "w");
    if (!f) return -1;
    fprintf(f,
            "stand = \"%s/examples/stands/paper_example1.cfg\";\n"
            "source = { kind = \"replay\"; file = \"x.csv\"; time_column = \"t\";\n"
            " channels = ( { name = \"x1\"; quantity = \"displacement\"; node = 0; column = \"x1\"; },\n"
            "  { name = \"s\"; quantity = \"base_displacement\"; node = 0; column = \"s\"; },\n"
            "  { name = \"x2\"; quantity = \"displacement\"; node = 1; column = \"x2\"; } ); };\n"
            "estimator = { decimation = 10; };\n%s\n",
            VD_SOURCE_DIR, outputs);
    fclose(f);
    int rc = vd_config_load(path, c, err);
    unlink(path);
    return rc;
}

#endif
