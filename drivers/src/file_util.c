/* Whole-file reading and the bounded line reader used by the capture readers. */
#include "file_util.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

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

/* Hands out the line s[0, n) (its '\n' already consumed): cut to VIBID_LINE_MAX and
 * flagged when longer, CR before the end dropped, NUL-terminated. s[n] must be writable
 * (it is the '\n' or the spare byte after the data) unless the line is copied. */
static int emit(vibid_line_reader *lr, char *s, size_t n, bool cut, const char **line, size_t *len, bool *too_long)
{
    if (n > VIBID_LINE_MAX) {
        memcpy(lr->buf, s, VIBID_LINE_MAX);
        s = lr->buf;
        n = VIBID_LINE_MAX;
        cut = true;
    }
    if (n > 0 && s[n - 1] == '\r' && !cut)
        n--;
    s[n] = '\0';
    lr->line++;
    *line = s;
    *len = n;
    *too_long = cut;
    return 1;
}

/* Moves the unread tail to the front of the chunk and reads more behind it.
 * Returns the bytes read (0 at end of file) or -1 on a read error. */
static long refill(vibid_line_reader *lr)
{
    size_t keep = lr->end - lr->pos;
    if (lr->pos > 0 && keep > 0)
        memmove(lr->chunk, lr->chunk + lr->pos, keep);
    lr->pos = 0;
    lr->end = keep;
    size_t got = fread(lr->chunk + keep, 1, VIBID_LINE_CHUNK - keep, lr->fp);
    if (got == 0 && ferror(lr->fp))
        return -1;
    lr->end += got;
    return (long)got;
}

/* First '\n' in [p, end) of the chunk, or NULL. Capture lines are short (~46 bytes for
 * candump), where a call to memchr costs more than the search: 16 bytes per step with
 * SSE2 (part of every x86-64), inline. The loads may pass `end` by up to 15 bytes, which
 * the chunk's padding holds (zeroed at init, stale later: a match there is ignored). */
static inline char *find_newline(char *p, const char *end)
{
#ifdef __SSE2__
    const __m128i nl = _mm_set1_epi8('\n');
    for (; p < end; p += 16) {
        unsigned m = (unsigned)_mm_movemask_epi8(_mm_cmpeq_epi8(_mm_loadu_si128((const __m128i *)(const void *)p), nl));
        if (m) {
            char *q = p + __builtin_ctz(m);
            return q < end ? q : NULL;
        }
    }
    return NULL;
#else
    return memchr(p, '\n', (size_t)(end - p));
#endif
}

static int next_from_file(vibid_line_reader *lr, const char **line, size_t *len, bool *too_long)
{
    size_t scanned = 0; /* bytes after pos already known to hold no '\n' */
    for (;;) {
        char *s = lr->chunk + lr->pos;
        char *nl = find_newline(s + scanned, lr->chunk + lr->end);
        if (nl) {
            lr->pos += (size_t)(nl - s) + 1;
            return emit(lr, s, (size_t)(nl - s), false, line, len, too_long);
        }
        scanned = lr->end - lr->pos;
        if (scanned > VIBID_LINE_MAX) {
            /* Over-long line: keep its head, skip the rest up to and including '\n'. */
            memcpy(lr->buf, s, VIBID_LINE_MAX);
            lr->pos = lr->end;
            for (;;) {
                long got = refill(lr);
                if (got < 0)
                    return -1;
                if (got == 0)
                    break;
                nl = memchr(lr->chunk, '\n', lr->end);
                if (nl) {
                    lr->pos = (size_t)(nl - lr->chunk) + 1;
                    break;
                }
                lr->pos = lr->end;
            }
            return emit(lr, lr->buf, VIBID_LINE_MAX, true, line, len, too_long);
        }
        long got = refill(lr);
        if (got < 0)
            return -1;
        if (got == 0) {
            if (lr->end == lr->pos)
                return 0;
            /* last line without '\n': chunk has a spare byte for its NUL */
            size_t n = lr->end - lr->pos;
            s = lr->chunk + lr->pos;
            lr->pos = lr->end;
            return emit(lr, s, n, false, line, len, too_long);
        }
    }
}

int vibid_line_reader_next(vibid_line_reader *lr, const char **line, size_t *len, bool *too_long)
{
    *too_long = false;
    if (lr->fp)
        return next_from_file(lr, line, len, too_long);
    if (lr->mem_pos >= lr->mem_len)
        return 0;
    const char *s = lr->mem + lr->mem_pos;
    size_t left = lr->mem_len - lr->mem_pos;
    const char *nl = memchr(s, '\n', left);
    size_t n = nl ? (size_t)(nl - s) : left;
    lr->mem_pos += nl ? n + 1 : n;
    size_t keep = n < VIBID_LINE_MAX ? n : VIBID_LINE_MAX;
    memcpy(lr->buf, s, keep); /* the input is const: NUL-terminate a copy */
    return emit(lr, lr->buf, n > VIBID_LINE_MAX ? VIBID_LINE_MAX : n, n > VIBID_LINE_MAX, line, len, too_long);
}
