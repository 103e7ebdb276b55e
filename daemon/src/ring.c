/* ring.c: see ring.h. */
#include "ring.h"

#include <stdlib.h>
#include <string.h>

vd_ring *vd_ring_create(size_t capacity)
{
    if (capacity < VD_RING_MIN || capacity > VD_RING_MAX || (capacity & (capacity - 1)) != 0)
        return NULL;
    vd_ring *r = aligned_alloc(VD_CACHE_LINE, (sizeof *r + VD_CACHE_LINE - 1) / VD_CACHE_LINE * VD_CACHE_LINE);
    if (!r)
        return NULL;
    memset(r, 0, sizeof *r);
    r->slots = calloc(capacity, sizeof *r->slots);
    if (!r->slots) {
        free(r);
        return NULL;
    }
    r->mask = capacity - 1;
    atomic_init(&r->head, 0);
    atomic_init(&r->tail, 0);
    atomic_init(&r->overflow_pub, 0);
    atomic_init(&r->high_water, 0);
    return r;
}

void vd_ring_destroy(vd_ring *r)
{
    if (!r)
        return;
    free(r->slots);
    free(r);
}

size_t vd_ring_capacity(const vd_ring *r) { return (size_t)r->mask + 1; }

bool vd_ring_full(vd_ring *r)
{
    uint64_t head = atomic_load_explicit(&r->head, memory_order_relaxed);
    if (head - r->tail_cache < r->mask + 1)
        return false;
    r->tail_cache = atomic_load_explicit(&r->tail, memory_order_acquire);
    return head - r->tail_cache >= r->mask + 1;
}

bool vd_ring_push(vd_ring *r, const vd_item *item)
{
    uint64_t head = atomic_load_explicit(&r->head, memory_order_relaxed);
    uint64_t cap = r->mask + 1;
    if (head - r->tail_cache >= cap) {
        r->tail_cache = atomic_load_explicit(&r->tail, memory_order_acquire);
        if (head - r->tail_cache >= cap) {
            r->overflows++;
            atomic_store_explicit(&r->overflow_pub, r->overflows, memory_order_relaxed);
            return false;
        }
    }
    vd_item *slot = &r->slots[head & r->mask];
    vibid_record_copy(&slot->rec, &item->rec); /* only the used part of the ~460-byte record */
    slot->t_rx_ns = item->t_rx_ns;
    atomic_store_explicit(&r->head, head + 1, memory_order_release);
    /* The high water. head + 1 - tail_cache is only an upper bound of the fill: tail_cache
     * is refreshed when the ring looks full, so after the consumer emptied the ring it still
     * counts every record pushed since (the old measure, which equalled the sample count up
     * to the capacity). Only when that bound passes the high water so far is the consumer's
     * tail read (one load of its cache line) and the real fill taken; otherwise the fill
     * cannot have passed it. With a consumer that keeps up and a high water of h this is one
     * load per ~h pushes; once the ring has been full, none. */
    if (head + 1 - r->tail_cache > r->hw_local) {
        r->tail_cache = atomic_load_explicit(&r->tail, memory_order_acquire);
        const uint64_t fill = head + 1 - r->tail_cache;
        if (fill > r->hw_local) {
            r->hw_local = fill;
            atomic_store_explicit(&r->high_water, fill, memory_order_relaxed);
        }
    }
    return true;
}

const vd_item *vd_ring_peek(vd_ring *r)
{
    uint64_t tail = atomic_load_explicit(&r->tail, memory_order_relaxed);
    if (tail == r->head_cache) {
        r->head_cache = atomic_load_explicit(&r->head, memory_order_acquire);
        if (tail == r->head_cache)
            return NULL;
    }
    return &r->slots[tail & r->mask];
}

void vd_ring_release(vd_ring *r)
{
    uint64_t tail = atomic_load_explicit(&r->tail, memory_order_relaxed);
    atomic_store_explicit(&r->tail, tail + 1, memory_order_release);
}

bool vd_ring_pop(vd_ring *r, vd_item *item)
{
    const vd_item *p = vd_ring_peek(r);
    if (!p)
        return false;
    *item = *p;
    vd_ring_release(r);
    return true;
}

size_t vd_ring_fill(vd_ring *r)
{
    uint64_t t = atomic_load_explicit(&r->tail, memory_order_acquire);
    uint64_t h = atomic_load_explicit(&r->head, memory_order_acquire);
    return h >= t ? (size_t)(h - t) : 0;
}

uint64_t vd_ring_overflows(vd_ring *r) { return atomic_load_explicit(&r->overflow_pub, memory_order_relaxed); }
uint64_t vd_ring_high_water(vd_ring *r) { return atomic_load_explicit(&r->high_water, memory_order_relaxed); }
