/* vibid_drivers/can_assembler.h: turns CAN frames into samples.
 *
 * Counter mode (chanmap.counter set): every message that carries a channel must also
 * carry the counter signal (an unsigned integer of n bits; raw value, wraps modulo
 * 2^n). A sample is complete when every such message has arrived with the same
 * counter value; it is emitted at once. A frame with a newer counter closes the
 * current sample: if incomplete it becomes a GAP record (1 sample, naming the missing
 * messages); skipped counter values become one GAP record. A frame whose counter is
 * older than the current sample is LATE; a second frame for a message already in the
 * current sample is a DUPLICATE; both are reported and ignored (the first value wins).
 * "Older/newer" is decided modulo 2^n by half the range, so wrap-around is handled.
 *
 * Counter plausibility (after vibid_can_assembler_set_timing with period h > 0): a
 * forward jump of d samples that arrives only dt after the open sample's first frame
 * is accepted as a genuine gap only if d - 1 <= slack + 2 dt / h, i.e. the sender
 * cannot have skipped more samples than twice the elapsed time holds (factor 2 and
 * slack absorb receive jitter and bursty senders). A larger jump is a corrupted
 * counter (one flipped bit of a 16-bit counter jumps by up to 32768): a FAULT record
 * VIBID_FAULT_CORRUPT for that frame, which contributes nothing and moves nothing.
 * Without timing (h = 0, the default) every forward jump is a GAP as before.
 *
 * Trigger mode (chanmap.trigger set, no counter): the trigger message opens sample
 * k+1 (closing sample k as above); other messages fill the open sample.
 *
 * Sample time = receive (or log) time of the sample's first frame.
 * Error frames, short frames, non-finite values, unknown ids and drop reports become
 * FAULT records; the affected frame never contributes a value.
 */
#ifndef VIBID_DRIVERS_CAN_ASSEMBLER_H
#define VIBID_DRIVERS_CAN_ASSEMBLER_H

#include <stdbool.h>
#include <stdint.h>

#include <vibid_drivers/can_frame.h>
#include <vibid_drivers/channel_map.h>
#include <vibid_drivers/dbc.h>
#include <vibid_drivers/sample.h>
#include <vibid_drivers/status.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct vibid_can_assembler vibid_can_assembler;

typedef struct vibid_can_assembler_stats {
    uint64_t frames, samples, gaps, missing_samples, incomplete_samples;
    uint64_t duplicates, late, unknown_ids, short_frames, nonfinite;
    uint64_t error_frames, bus_off, ctrl_overflow, restarts, dropped;
    uint64_t corrupt_counters; /* implausible counter jumps (FAULT, frame ignored) */
    vibid_jitter_stats jitter;
} vibid_can_assembler_stats;

/* dbc and map must outlive the assembler (it keeps pointers into dbc). NULL on a
 * configuration error (unknown signal/message, counter missing from a message, ...). */
vibid_can_assembler *vibid_can_assembler_create(const vibid_dbc *dbc, const vibid_chanmap *map,
                                                vibid_drv_error *err);
void vibid_can_assembler_destroy(vibid_can_assembler *a);
/* Enables the counter plausibility check (counter mode only). period_s: nominal
 * sample period h in s (> 0, finite; 0 disables the check); slack_samples: extra
 * missing samples tolerated beyond 2 dt / h (0 selects the default,
 * VIBID_CAN_ASSEMBLER_DEFAULT_SLACK). Returns false on an invalid period. */
#define VIBID_CAN_ASSEMBLER_DEFAULT_SLACK 16u
bool vibid_can_assembler_set_timing(vibid_can_assembler *a, double period_s, uint32_t slack_samples);
/* Feeds one frame. Produced records are queued; read them with _pop. No allocation. */
void vibid_can_assembler_push(vibid_can_assembler *a, const vibid_can_frame *frame);
/* Reports frames lost before they reached us (SO_RXQ_OVFL, candump DROPCOUNT). */
void vibid_can_assembler_note_drops(vibid_can_assembler *a, uint64_t dropped, const char *where);
/* At end of stream: an open incomplete sample becomes a GAP record. */
void vibid_can_assembler_finish(vibid_can_assembler *a);
/* true and *rec filled while records are queued. */
bool vibid_can_assembler_pop(vibid_can_assembler *a, vibid_record *rec);
/* Records queued (what _pop would return before it returns false); 0 for NULL. Lets a
 * caller pop straight into its own queue's slots instead of through a copy. */
size_t vibid_can_assembler_pending(const vibid_can_assembler *a);
/* The inverse of push, for recording samples as CAN frames (vibidd's candump recording):
 * the frames that carry sample rec (a SAMPLE record in this assembler's channel order),
 * one per DBC message holding channels, in the order the assembler rebuilds them (the
 * trigger message first); the counter signal (counter mode) = rec->index mod 2^bits,
 * signals that are not channels 0; payload = the message's DBC length (CAN FD above 8
 * bytes, rounded up to a valid FD length); t_ns = rec->t_ns, iface "". Pushing the frames
 * back gives the same sample (same index in counter mode). *n = frames written.
 * VIBID_DRV_E_RANGE (err names channel and signal) if a value does not fit its signal,
 * VIBID_DRV_E_ARG if rec is not a sample of this map or cap is too small. No allocation. */
vibid_drv_status vibid_can_assembler_encode(const vibid_can_assembler *a, const vibid_record *rec,
                                            vibid_can_frame *frames, size_t cap, size_t *n, vibid_drv_error *err);
/* The channel ids of the DBC messages involved (for kernel filters): up to cap
 * entries (ids with bit 31 set for extended ids); returns how many exist. */
size_t vibid_can_assembler_ids(const vibid_can_assembler *a, uint32_t *ids, size_t cap);
void vibid_can_assembler_stats_get(const vibid_can_assembler *a, vibid_can_assembler_stats *s);

#ifdef __cplusplus
}
#endif
#endif
