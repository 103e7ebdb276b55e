/* vibid_drivers/source.h: one interface for every source of samples.
 *
 * A source turns a bus, a device or a capture file into a stream of vibid_record
 * (sample.h): SAMPLE records (t_k, u_k, y_k in channel-map order), GAP records for
 * samples that are known to be missing (never invented), and FAULT records for
 * everything else that went wrong (bad line, error frame, failed poll, lost link, ...),
 * each with a text naming what and where (file:line for files).
 *
 * Each source kind is a `const vibid_source_ops` table (SocketCAN, Modbus, replay, the
 * test double), as libmodbus does for its backends. The daemon holds a vibid_source and
 * calls only the generic functions below, so it treats every source alike:
 *
 *     vibid_source *s = vibid_source_open(&vibid_source_replay_ops, &replay_cfg, &err);
 *     while (running) {
 *         size_t n;
 *         st = vibid_source_read(s, recs, 64, &n, 100, &err);   // up to 64 records, 100 ms
 *         ... n records in recs; st == VIBID_DRV_E_EOF: finite stream ended ...
 *     }
 *     vibid_source_stats_get(s, &stats);
 *     vibid_source_close(s);
 *
 * Sample indices k are consecutive across SAMPLE and GAP records: the first record
 * concerns k = first index, and every k appears in exactly one SAMPLE or GAP record
 * (a source never emits a k twice and never skips one without a GAP).
 *
 * Threading: a source is used by one thread at a time (the acquisition thread).
 * read() never allocates; open() allocates everything the source needs.
 */
#ifndef VIBID_DRIVERS_SOURCE_H
#define VIBID_DRIVERS_SOURCE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <vibid_drivers/channel_map.h>
#include <vibid_drivers/sample.h>
#include <vibid_drivers/status.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Counters every source fills (fields that do not apply to a kind stay 0). */
typedef struct vibid_source_stats {
    /* records delivered */
    uint64_t samples;          /* SAMPLE records */
    uint64_t gaps;             /* GAP records */
    uint64_t missing_samples;  /* sum of GAP counts */
    uint64_t faults;           /* FAULT records */
    /* CAN (live and candump replay) */
    uint64_t frames;           /* frames received / read */
    uint64_t error_frames, bus_off, ctrl_overflow, restarts;
    uint64_t dropped;          /* frames lost before us (SO_RXQ_OVFL, DROPCOUNT) */
    uint64_t unknown_ids, short_frames, nonfinite, duplicates, late;
    uint64_t hw_timestamps;    /* frames stamped by the interface's clock */
    uint64_t sw_timestamps;    /* frames stamped by the kernel on receipt */
    uint64_t batches;          /* recvmmsg calls that returned frames */
    /* files */
    uint64_t lines;            /* capture lines read */
    uint64_t bad_lines;        /* malformed lines / rows (incl. a truncated last line) */
    /* Modbus */
    uint64_t polls;            /* poll cycles attempted */
    uint64_t failed_polls;     /* poll cycles with at least one failed request */
    uint64_t timeouts;         /* requests that got no answer in the response timeout */
    uint64_t link_losses;      /* times the link was declared lost */
    uint64_t reconnects;       /* successful (re)connections after the first */
    uint64_t connect_failures; /* failed connection attempts (a FIFO header that does not
                                  fit counts here too: the device is retried) */
    uint64_t implausible;      /* FIFO counter or session changes that the elapsed time
                                  cannot explain: ignored, not turned into samples or gaps */
    uint64_t overruns;         /* snapshot deadlines missed (samples given up as GAP) */
    uint64_t requests;         /* Modbus read requests sent */
    /* timing of emitted samples (intervals between consecutive SAMPLE times) */
    vibid_jitter_stats jitter;
} vibid_source_stats;

typedef struct vibid_source vibid_source;

/* The ops table of a source kind. Implementations keep their state in `impl`.
 * open:  parses/validates `config` (the kind's own config struct, see below), opens
 *        files/sockets/connections, allocates; returns VIBID_DRV_OK or fills err.
 * read:  writes up to cap records into recs, *n = how many. Blocks at most timeout_ms
 *        (0 = do not block, < 0 = block until something happens).
 *        OK (*n >= 1), E_AGAIN (*n == 0, nothing yet), E_EOF (finite stream ended,
 *        *n == 0, every record delivered), or a fatal status with err filled.
 * close: releases everything; NULL-safe impl.
 * stats: fills *st (may be called at any time from the reading thread). */
typedef struct vibid_source_ops {
    const char *kind; /* "socketcan", "modbus", "replay", "double" */
    vibid_drv_status (*open)(vibid_source *src, const void *config, vibid_drv_error *err);
    vibid_drv_status (*read)(vibid_source *src, vibid_record *recs, size_t cap, size_t *n,
                             int timeout_ms, vibid_drv_error *err);
    void (*close)(vibid_source *src);
    void (*stats)(const vibid_source *src, vibid_source_stats *st);
} vibid_source_ops;

struct vibid_source {
    const vibid_source_ops *ops;
    void *impl;               /* owned by the kind */
    vibid_chanmap chanmap;    /* copy of the channels the records' values follow */
};

/* Opens a source of kind `ops` with that kind's config. NULL on failure (err says why,
 * naming file:line or system call). */
vibid_source *vibid_source_open(const vibid_source_ops *ops, const void *config, vibid_drv_error *err);
/* See vibid_source_ops.read. recs: caller array of cap >= 1 records. */
vibid_drv_status vibid_source_read(vibid_source *src, vibid_record *recs, size_t cap, size_t *n,
                                   int timeout_ms, vibid_drv_error *err);
void vibid_source_stats_get(const vibid_source *src, vibid_source_stats *st);
/* Channels of the records (lives as long as the source). */
const vibid_chanmap *vibid_source_channels(const vibid_source *src);
const char *vibid_source_kind(const vibid_source *src);
/* NULL-safe. */
void vibid_source_close(vibid_source *src);

/* Adds the record to the stats' record counters and jitter (for implementations). */
void vibid_source_stats_count(vibid_source_stats *st, const vibid_record *rec, int64_t *last_t_ns);

/* ------------------------------------------------------------------------------------
 * Test double: delivers a scripted list of records, then EOF (or AGAIN forever), and
 * can be told to fail. Lets daemon tests run the whole pipeline without any I/O. */
typedef struct vibid_source_double_config {
    vibid_chanmap chanmap;          /* channels of the scripted samples */
    const vibid_record *records;    /* copied at open */
    size_t n_records;
    size_t max_batch;               /* at most this many records per read (0 = cap) */
    bool endless;                   /* after the script: E_AGAIN instead of E_EOF */
    size_t fail_after_reads;        /* if > 0: that read call fails with fail_status */
    vibid_drv_status fail_status;   /* e.g. VIBID_DRV_E_IO */
} vibid_source_double_config;
extern const vibid_source_ops vibid_source_double_ops;

#ifdef __cplusplus
}
#endif
#endif
