/* rate_check.h: data that do not fit the stand are refused. The sample rate of a capture
 * or of a live source, estimated from the records' own times, is compared with the
 * stand's sample_rate; more than VD_RATE_TOLERANCE (1 %) off is a configuration error
 * naming both rates:
 *
 *   capture.csv: sample rate 1000.0 Hz (from the time column, samples 0..3999) is 50.0 %
 *   off the stand's sample_rate 2000 Hz (stand.cfg): fix stand.sample_rate or the capture
 *
 * The check needs times that do not come from the stand's rate: a CSV time column, candump
 * timestamps, SocketCAN receive stamps. Where a source synthesizes t_k = t_0 + k h from the
 * stand's h (CSV without a time column, Modbus snapshot mode) there is nothing to compare;
 * Modbus FIFO mode compares the device's own period_ns with the stand at every connection
 * (drivers/src/source_modbus.c). docs/vibidd.md has the table.
 *
 * Estimation (vd_rate_estimate), from points (k_i, t_i) = (sample index, time):
 *  1. the series is cut into stretches where a time step is longer than its index step
 *     explains by more than max(0.5 period, split_min_s) (a CSV row missing: the replay
 *     itself makes such a step a gap; a CAN device that paused); each stretch gets its own
 *     intercept, so samples whose loss the index does not show cannot bias the slope, and
 *     samples lost with an index jump (CAN counter, GAP records) simply keep their index;
 *  2. a robust start: the median of the slopes (t_j - t_i) / (k_j - k_i) over pairs at
 *     lags of 1/16, 1/8 and 1/4 of each stretch (receive jitter averages over the lag; a
 *     stall or a burst touches a minority of the pairs); per stretch the median intercept;
 *  3. points further than max(5 sigma, 1 % of the period, 2 us) from that line, sigma from
 *     the median absolute residual, are left out (a receive stall, a late frame), twice;
 *  4. the period is the least-squares slope of t against k over the points kept, with a
 *     common slope and per-stretch intercepts; its standard error comes with it.
 * No estimate (-1) when fewer than VD_RATE_MIN_POINTS points, more than half of them left
 * out, or the times do not advance.
 *
 * Decision (vd_rate_check): windows of consecutive samples of at least VD_RATE_WINDOW_S of
 * their own time and VD_RATE_WINDOW_MIN samples (at most VD_RATE_WINDOW_MAX). A window whose
 * rate is within the tolerance by VD_RATE_SE_FACTOR standard errors passes at once. A window
 * off by more than the tolerance plus those standard errors is only suspect: the next window
 * decides, and the rate is refused when it is clearly off too, in the same direction (then
 * the message gives the fit over both windows); a window that is fine after a suspect one
 * passes (a jittery first second must not kill a daemon). A window between the two (its
 * times scatter too much for a decision at 1 %) decides nothing. After VD_RATE_MAX_WINDOWS
 * windows without a decision the rate is left unchecked (a warning).
 * At the end of a finite stream (a replay) a last suspect window, or a capture shorter than
 * one window but off, is refused: nothing is left that could contradict it.
 */
#ifndef VIBIDD_RATE_CHECK_H
#define VIBIDD_RATE_CHECK_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <vibid_drivers/sample.h>
#include <vibid_drivers/source_replay.h>

#include "config.h"

#define VD_RATE_TOLERANCE 0.01     /* |capture / stand - 1| above this is refused */
#define VD_RATE_WINDOW_S 2.0       /* a window spans at least this much of its own time */
#define VD_RATE_WINDOW_MIN 200     /* and at least this many samples */
#define VD_RATE_WINDOW_MAX 32768   /* at most this many samples (2 s up to 16 kHz) */
#define VD_RATE_MIN_POINTS 20      /* fewer points give no estimate */
#define VD_RATE_MAX_WINDOWS 5      /* windows without a decision before giving up */
#define VD_RATE_SE_FACTOR 3.0      /* a window decides only this many standard errors clear of the tolerance */
#define VD_RATE_SPLIT_RX_S 0.02    /* receive-stamped sources: stretches split at pauses > 20 ms */

/* --rate-check: what a refused rate does. */
typedef enum vd_rate_mode {
    VD_RATE_MODE_ERROR = 0,        /* configuration error, exit 2 (default) */
    VD_RATE_MODE_WARN = 1,         /* a warning, the run goes on */
    VD_RATE_MODE_OFF = 2           /* no check */
} vd_rate_mode;

/* Parses "error", "warn", "off"; -1 if unknown. */
int vd_rate_mode_parse(const char *s);

typedef struct vd_rate_fit {
    double period_s, rate_hz;
    double rel_se;                 /* standard error of the period / period */
    size_t n, used;                /* points given, points kept */
    size_t segments;               /* stretches with their own intercept */
    uint64_t k_first, k_last;      /* sample indices of the first and last point */
} vd_rate_fit;

/* Estimates the sample period of n points: k strictly increasing sample indices, t_ns
 * their times (ns). split_min_s: a time step is cut into a new stretch only beyond
 * max(0.5 period, split_min_s) more than its index step explains (0 for captures whose
 * times are sample times, VD_RATE_SPLIT_RX_S for receive stamps). 0 with *fit, or -1 with
 * *why (static text) when there is no estimate. Allocates its scratch (6 n doubles). */
int vd_rate_estimate(const uint64_t *k, const int64_t *t_ns, size_t n, double split_min_s, vd_rate_fit *fit,
                     const char **why);

typedef enum vd_rate_event {
    VD_RATE_PENDING = 0,           /* nothing new */
    VD_RATE_SUSPECT,               /* a window is off; the next one decides (message) */
    VD_RATE_PASS,                  /* final: the rate fits (message) */
    VD_RATE_FAIL,                  /* final: refused (message names both rates) */
    VD_RATE_UNCHECKED              /* final: no decision possible (message says why) */
} vd_rate_event;

typedef struct vd_rate_check vd_rate_check;

/* who: "capture.csv", "socketcan can0"; basis: "from the time column"; stand: where the
 * stand's rate comes from; fix: the advice after the colon. NULL when out of memory. */
vd_rate_check *vd_rate_check_create(double stand_hz, double split_min_s, const char *who, const char *basis,
                                    const char *stand, const char *fix);
/* The live check of a SocketCAN source of cfg (labels from cfg). */
vd_rate_check *vd_rate_check_create_live(const vd_config *cfg);
void vd_rate_check_destroy(vd_rate_check *c);
/* Feeds a record (SAMPLE: index and time; GAP: only the first index; FAULT: ignored).
 * Returns what happened now; after a final event always VD_RATE_PENDING. */
vd_rate_event vd_rate_check_feed(vd_rate_check *c, const vibid_record *rec);
/* End of a finite stream: decides with what there is (see above). */
vd_rate_event vd_rate_check_finish(vd_rate_check *c);
bool vd_rate_check_done(const vd_rate_check *c);
/* The text of the last event. */
const char *vd_rate_check_message(const vd_rate_check *c);

/* The live hook (estimation thread, every record of a SocketCAN source): feeds rec and logs
 * what happened: a suspect window as a warning, the pass as info, a refusal as an error
 * (mode error) or a warning (mode warn). 1 when the run must stop (refused, mode error). */
int vd_rate_check_live(vd_rate_check *c, const vibid_record *rec, vd_rate_mode mode);

/* The check of a replay, run on the capture before anything else reads it: opens its own
 * replay source with rc (unpaced; for a CSV without gap detection, so that the rows' own
 * spacing is measured, not the stand's), reads until a decision or the end, logs the
 * outcome. Returns 0 (fits, unchecked, or mode warn/off), or -1 with err (the refusal; the
 * capture cannot be read). note != NULL (--check): the outcome other than a refusal goes to
 * note (note_cap bytes; "" when nothing is to be said) instead of the log, and an unreadable
 * capture is no error (the example configurations name captures that do not exist). */
int vd_rate_check_capture(const vd_config *cfg, const vibid_source_replay_config *rc, vd_rate_mode mode,
                          char *note, size_t note_cap, char *err, size_t cap);

#endif
