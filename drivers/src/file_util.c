/* Whole-file reading and the bounded line reader used by the capture readers. */
#include "file_util.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

char *vibid_read_whole_file(const char *path, size_t max, size_t *len, vibid_drv_error *err)
{
    FILE *fp = fopen(path, "rb");
    if (!fp) {
        vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: cannot open: %s", path, strerror(errno));
        return NULL;
    }
    size_t cap = 4096, n = 0;
    char *buf = malloc(cap + 1);
    while (buf) {
        if (n == cap) {
            if (cap >= max) {
                vibid_drv_fail(err, VIBID_DRV_E_RANGE, "%s: larger than %zu bytes", path, max);
                free(buf);
                buf = NULL;
                break;
            }
            cap = cap * 2 > max ? max : cap * 2;
            char *nb = realloc(buf, cap + 1);
            if (!nb) {
                free(buf);
                buf = NULL;
                break;
            }
            buf = nb;
        }
        size_t got = fread(buf + n, 1, cap - n, fp);
        n += got;
        if (got == 0) {
            if (ferror(fp)) {
                vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: read error: %s", path, strerror(errno));
                free(buf);
                buf = NULL;
            }
            break;
        }
    }
    if (!buf && err && err->status == VIBID_DRV_OK)
        vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "%s: out of memory", path);
    fclose(fp);
    if (buf) {
        buf[n] = '\0';
        *len = n;
    }
    return buf;
}

void vibid_line_reader_init_file(vibid_line_reader *lr, FILE *fp)
{
    memset(lr, 0, sizeof *lr);
    lr->fp = fp;
}

void vibid_line_reader_init_mem(vibid_line_reader *lr, const char *data, size_t len)
{
    memset(lr, 0, sizeof *lr);
    lr->mem = data;
    lr->mem_len = len;
}

int vibid_line_reader_next(vibid_line_reader *lr, const char **line, size_t *len, bool *too_long)
{
    size_t n = 0;
    bool any = false;
    *too_long = false;
    for (;;) {
        int c;
        if (lr->fp) {
            c = getc_unlocked(lr->fp); /* one reader per FILE: no locking needed */
            if (c == EOF) {
                if (ferror(lr->fp))
                    return -1;
                break;
            }
        } else {
            if (lr->mem_pos >= lr->mem_len)
                break;
            c = (unsigned char)lr->mem[lr->mem_pos++];
        }
        any = true;
        if (c == '\n')
            break;
        if (n < VIBID_LINE_MAX)
            lr->buf[n++] = (char)c;
        else
            *too_long = true; /* keep consuming to the end of the line */
    }
    if (!any)
        return 0;
    if (n > 0 && lr->buf[n - 1] == '\r' && !*too_long)
        n--;
    lr->buf[n] = '\0';
    lr->line++;
    *line = lr->buf;
    *len = n;
    return 1;
}
