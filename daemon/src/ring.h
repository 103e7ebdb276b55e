/* ring.h: lock-free single-producer / single-consumer ring of vd_item (a vibid_record
 * and its receipt time).
 *
 * The acquisition thread is the only producer, the estimation thread the only consumer.
 * Capacity is a power of two so that a slot is `index & mask`; the indices count up
 * without wrapping in practice (64 bits). `head` (written by the producer) and `tail`
 * (written by the consumer) sit on separate cache lines, with each side's cached copy of
 * the other's index beside its own, so that the two cores do not fight over one line
 * (false sharing) and each side reads the other's index only when its cached copy says
 * the ring is full/empty.
 *
 * Memory order: the producer writes the slot, then publishes head with release; the
 * consumer loads head with acquire before reading the slot, and publishes tail with
 * release after it has copied the slot out; the producer loads tail with acquire before
 * reusing a slot.
 *
 * Push never blocks: on a full ring it returns false and the caller counts an overflow.
 * Storage is allocated once in vd_ring_create; push/pop never allocate.
 */
#ifndef VIBIDD_RING_H
#define VIBIDD_RING_H

#include <stdalign.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <vibid_drivers/sample.h>

#define VD_CACHE_LINE 64

/* One ring entry: a source record plus the CLOCK_MONOTONIC time (ns) at which the
 * acquisition thread got it from the source (for the receipt -> estimate latency). */
typedef struct vd_item {
    vibid_record rec;
    int64_t t_rx_ns;
} vd_item;
#define VD_RING_MIN 2u
#define VD_RING_MAX (1u << 20)

typedef struct vd_ring {
    alignas(VD_CACHE_LINE) _Atomic uint64_t head; /* next slot to write (producer) */
    uint64_t tail_cache;                          /* producer's copy of tail */
    uint64_t overflows;                           /* pushes refused (producer) */
    uint64_t hw_local;                            /* producer's copy of high_water */
    alignas(VD_CACHE_LINE) _Atomic uint64_t tail; /* next slot to read (consumer) */
    uint64_t head_cache;                          /* consumer's copy of head */
    alignas(VD_CACHE_LINE) uint64_t mask;         /* read-only after create */
    vd_item *slots;
    _Atomic uint64_t overflow_pub;                /* overflows, published for the status */
    _Atomic uint64_t high_water;                  /* highest fill right after a push (ring.c) */
} vd_ring;

/* capacity: power of two in VD_RING_MIN..VD_RING_MAX. NULL on bad capacity or no memory. */
vd_ring *vd_ring_create(size_t capacity);
void vd_ring_destroy(vd_ring *r);
size_t vd_ring_capacity(const vd_ring *r);

/* Producer: copies *rec into the ring. false if full (counted in overflows). */
bool vd_ring_push(vd_ring *r, const vd_item *item);
/* Producer: true if a push now would be refused (nothing counted). A replay waits on it
 * instead of pushing into a full ring, so its status shows no overflows (it drops none). */
bool vd_ring_full(vd_ring *r);
/* Consumer: copies the oldest record to *rec. false if empty. */
bool vd_ring_pop(vd_ring *r, vd_item *item);
/* Consumer: pointer to the oldest record without copying, NULL if empty; release it
 * with vd_ring_release once done. */
const vd_item *vd_ring_peek(vd_ring *r);
void vd_ring_release(vd_ring *r);

/* Any thread: records currently queued (approximate while both sides run). */
size_t vd_ring_fill(vd_ring *r);
uint64_t vd_ring_overflows(vd_ring *r);
/* Any thread: the most records that waited in the ring at once, measured by the producer
 * right after each push against the consumer's tail as it was then (exact when the two do
 * not run at the same instant; while they do, a pop that lands between the push and the
 * producer's look at the tail can make it one or a few records low, never high). */
uint64_t vd_ring_high_water(vd_ring *r);

#endif
