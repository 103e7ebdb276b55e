/* vibid_drivers/sample.h: what every source delivers: samples (t_k, u_k, y_k) and
 * explicit gap / fault records, so that nothing is invented or dropped silently.
 * Fixed size (no pointers) so that records can be copied through a lock-free ring. */
#ifndef VIBID_DRIVERS_SAMPLE_H
#define VIBID_DRIVERS_SAMPLE_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <vibid_drivers/channel_map.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum vibid_record_kind {
    VIBID_REC_SAMPLE = 0, /* values[] holds one complete sample */
    VIBID_REC_GAP = 1,    /* samples index .. index+count-1 are missing (not invented) */
    VIBID_REC_FAULT = 2   /* something went wrong; text says what and where; no sample */
} vibid_record_kind;

typedef enum vibid_fault_code {
    VIBID_FAULT_NONE = 0,
    VIBID_FAULT_BAD_LINE,     /* malformed capture line/row */
    VIBID_FAULT_UNKNOWN_ID,   /* frame id not in the DBC (reported once per id, all counted) */
    VIBID_FAULT_SHORT_FRAME,  /* payload shorter than a signal needs */
    VIBID_FAULT_NONFINITE,    /* NaN/Inf value */
    VIBID_FAULT_DUPLICATE,    /* second frame for a sample already holding it */
    VIBID_FAULT_LATE,         /* frame for a sample already emitted or declared missing */
    VIBID_FAULT_BUS_ERROR,    /* CAN error frame */
    VIBID_FAULT_DROPPED,      /* frames dropped by the kernel/logger (count in `count`) */
    VIBID_FAULT_POLL,         /* failed Modbus poll */
    VIBID_FAULT_LINK,         /* connection lost / re-established */
    VIBID_FAULT_CORRUPT,      /* implausible content, e.g. a CAN sample counter jumping further than
                                 the elapsed time allows (frame not used) */
    VIBID_FAULT_CLOCK         /* a capture's timestamps step backwards or implausibly far forward:
                                 the replay's timeline is re-based (frame used, times shifted) */
} vibid_fault_code;
#define VIBID_FAULT_LAST VIBID_FAULT_CLOCK

/* The fault's kind as a short lower-case name: "none", "bad_line", "unknown_id",
 * "short_frame", "nonfinite", "duplicate", "late", "bus_error", "dropped", "poll", "link",
 * "corrupt", "clock" (in enum order). These are the names vibidd's status file
 * (faults_<name>), its metrics (vibid_faults_total{kind}) and log lines use, and the "kind"
 * column of the Python package's fault tables: outside tools match them, so they do not
 * change. A code outside NONE..VIBID_FAULT_LAST gives "fault". The string is static (never
 * freed by the caller); safe from any thread. */
const char *vibid_fault_name(vibid_fault_code c);

typedef struct vibid_record {
    vibid_record_kind kind;
    vibid_fault_code fault;   /* FAULT only */
    uint64_t index;           /* SAMPLE: k; GAP: first missing k; FAULT: sample k it concerns (or 0) */
    uint64_t count;           /* GAP: missing samples; FAULT DROPPED: frames dropped */
    int64_t t_ns;             /* SAMPLE: sample time, ns (device time if available, else receive time) */
    uint32_t n_values;        /* SAMPLE: = channel count */
    double values[VIBID_DRV_MAX_CHANNELS]; /* in channel-map order, physical units */
    char text[160];           /* GAP/FAULT: reason, with file:line when from a file */
} vibid_record;

/* Copies what a record of its kind carries: the header, the n_values used values and, for
 * a GAP or FAULT, the text (a SAMPLE's text is set empty). values[n_values..] of *dst are
 * left as they were. A record is ~460 bytes of which a 3-channel sample uses ~60; the
 * replay path copies each record about five times, so whole-struct copies cost more than
 * the parsing. n_values must be <= VIBID_DRV_MAX_CHANNELS (it is clamped). */
static inline void vibid_record_copy(vibid_record *dst, const vibid_record *src)
{
    size_t nv = src->n_values <= VIBID_DRV_MAX_CHANNELS ? src->n_values : VIBID_DRV_MAX_CHANNELS;
    /* Copies of a constant size are inlined as a few moves; a size known only at run time
     * is a call to memcpy, which for the usual handful of channels cost more than the copy. */
    memcpy(dst, src, offsetof(vibid_record, values));
    switch (nv) {
    case 0: break;
    case 1: memcpy(dst->values, src->values, 1 * sizeof(double)); break;
    case 2: memcpy(dst->values, src->values, 2 * sizeof(double)); break;
    case 3: memcpy(dst->values, src->values, 3 * sizeof(double)); break;
    case 4: memcpy(dst->values, src->values, 4 * sizeof(double)); break;
    default: memcpy(dst->values, src->values, nv * sizeof(double)); break;
    }
    dst->n_values = (uint32_t)nv;
    if (src->kind == VIBID_REC_SAMPLE)
        dst->text[0] = '\0';
    else
        memcpy(dst->text, src->text, sizeof dst->text);
}

/* Jitter statistics of the intervals between consecutive emitted samples. */
typedef struct vibid_jitter_stats {
    uint64_t n;               /* intervals seen */
    double mean_s, std_s;     /* mean and standard deviation of the interval, s */
    double min_s, max_s;
    double m2_s2;             /* sum of squared deviations from the running mean (Welford's
                                 M2), s^2: std_s is derived from it where the statistics are
                                 read (vibid_jitter_finish), not per sample */
} vibid_jitter_stats;

/* Adds one interval dt (s): Welford's update, no square root (a sqrt per sample was a
 * measurable share of replay). */
static inline void vibid_jitter_add(vibid_jitter_stats *j, double dt)
{
    j->n++;
    const double d = dt - j->mean_s;
    j->mean_s += d / (double)j->n;
    j->m2_s2 += d * (dt - j->mean_s);
    if (j->n == 1 || dt < j->min_s)
        j->min_s = dt;
    if (j->n == 1 || dt > j->max_s)
        j->max_s = dt;
}

/* Sets std_s from m2_s2 (sample standard deviation; 0 below two intervals). */
void vibid_jitter_finish(vibid_jitter_stats *j);

#ifdef __cplusplus
}
#endif
#endif
