/* textbuf.h: appending printf-formatted text to a caller's fixed buffer, for the texts
 * vibidd renders on its estimation thread (Prometheus exposition, MQTT payloads): no
 * allocation, and an overflow is remembered (full) instead of cutting a text silently.
 * The buffer is the caller's; nothing here owns memory. */
#ifndef VIBIDD_TEXTBUF_H
#define VIBIDD_TEXTBUF_H

#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdio.h>

typedef struct vd_text {
    char *buf;   /* caller's buffer of cap bytes; NUL-terminated while !full */
    size_t cap;
    size_t off;  /* bytes written so far */
    bool full;   /* a piece did not fit: the text is incomplete and must not be used */
} vd_text;

static inline void vd_text_put(vd_text *t, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static inline void vd_text_put(vd_text *t, const char *fmt, ...)
{
    if (t->full || t->off >= t->cap) {
        t->full = true;
        return;
    }
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(t->buf + t->off, t->cap - t->off, fmt, ap);
    va_end(ap);
    if (n < 0 || (size_t)n >= t->cap - t->off) {
        t->full = true;
        return;
    }
    t->off += (size_t)n;
}

#endif
