/* Helpers shared by the drivers' source tests: scratch files and a small DBC. */
#ifndef VIBID_DRV_TEST_UTIL_H
#define VIBID_DRV_TEST_UTIL_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

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
