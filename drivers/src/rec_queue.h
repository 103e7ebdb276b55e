/* Internal: a fixed-capacity FIFO of records that a source fills while decoding and
 * drains into the caller's array in read(). Allocated once at open; never grows. */
#ifndef VIBID_DRIVERS_REC_QUEUE_H
#define VIBID_DRIVERS_REC_QUEUE_H

#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <vibid_drivers/sample.h>
#include <vibid_drivers/source.h>

typedef struct rec_queue {
    vibid_record *r;
    size_t cap, head, len;
} rec_queue;

static inline bool rec_queue_init(rec_queue *q, size_t cap)
{
    q->r = calloc(cap, sizeof *q->r);
    q->cap = cap;
    q->head = q->len = 0;
    return q->r != NULL;
}

static inline void rec_queue_free(rec_queue *q)
{
    free(q->r);
    q->r = NULL;
    q->cap = q->len = 0;
}

static inline size_t rec_queue_space(const rec_queue *q) { return q->cap - q->len; }

/* Slot for a new record at the tail (zeroed header); NULL when full: callers check
 * space before producing, so a full queue is a programming error, not data loss. */
static inline vibid_record *rec_queue_push(rec_queue *q, vibid_record_kind kind)
{
    if (q->len == q->cap)
        return NULL;
    /* head < cap and len < cap: one conditional subtraction instead of a division (the
     * capacity is not a constant, and a 64-bit divide per record showed in replay) */
    size_t i = q->head + q->len++;
    if (i >= q->cap)
        i -= q->cap;
    vibid_record *r = &q->r[i];
    r->kind = kind;
    r->fault = VIBID_FAULT_NONE;
    r->index = r->count = 0;
    r->t_ns = 0;
    r->n_values = 0;
    r->text[0] = '\0';
    return r;
}

static inline const vibid_record *rec_queue_peek(const rec_queue *q)
{
    return q->len ? &q->r[q->head] : NULL;
}

static inline void rec_queue_drop_head(rec_queue *q)
{
    if (++q->head == q->cap)
        q->head = 0;
    q->len--;
}

/* Appends a copy of rec (its used part); false when full. */
static inline bool rec_queue_push_copy(rec_queue *q, const vibid_record *rec)
{
    vibid_record *slot = rec_queue_push(q, rec->kind);
    if (slot)
        vibid_record_copy(slot, rec);
    return slot != NULL;
}

/* A source's read(): moves up to cap queued records into recs, each counted in st
 * (vibid_source_stats_count). Returns how many were moved. */
static inline size_t rec_queue_hand_out(rec_queue *q, vibid_record *recs, size_t cap, vibid_source_stats *st,
                                        int64_t *last_sample_t)
{
    size_t k = 0;
    const vibid_record *h;
    while (k < cap && (h = rec_queue_peek(q)) != NULL) {
        vibid_record_copy(&recs[k], h);
        vibid_source_stats_count(st, &recs[k], last_sample_t);
        rec_queue_drop_head(q);
        k++;
    }
    return k;
}

/* Sets a record's text (truncated to fit; texts are for people). */
static inline void rec_text(vibid_record *r, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static inline void rec_text(vibid_record *r, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(r->text, sizeof r->text, fmt, ap);
    va_end(ap);
}

static inline void rec_queue_fault(rec_queue *q, vibid_fault_code code, uint64_t index, uint64_t count,
                                   const char *fmt, ...) __attribute__((format(printf, 5, 6)));
static inline void rec_queue_fault(rec_queue *q, vibid_fault_code code, uint64_t index, uint64_t count,
                                   const char *fmt, ...)
{
    vibid_record *r = rec_queue_push(q, VIBID_REC_FAULT);
    if (!r)
        return;
    r->fault = code;
    r->index = index;
    r->count = count;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(r->text, sizeof r->text, fmt, ap);
    va_end(ap);
}

static inline void rec_queue_gap(rec_queue *q, uint64_t first, uint64_t count, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
static inline void rec_queue_gap(rec_queue *q, uint64_t first, uint64_t count, const char *fmt, ...)
{
    vibid_record *r = rec_queue_push(q, VIBID_REC_GAP);
    if (!r)
        return;
    r->index = first;
    r->count = count;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(r->text, sizeof r->text, fmt, ap);
    va_end(ap);
}

#endif
