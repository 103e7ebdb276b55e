/* metrics.h: the daemon's health as Prometheus metrics (text exposition format 0.0.4) on a
 * small HTTP endpoint (outputs.prometheus.listen; docs/vibidd.md, "Prometheus metrics").
 *
 * Data flow and ownership:
 *   vd_snapshot  one copy of every counter the status file and the metrics show. Filled by
 *                the estimation thread (daemon.c, at its housekeeping), which owns the
 *                counters; the status file and the exposition are both formatted from it,
 *                so the two cannot disagree about what a counter is.
 *   vd_metrics_render  snapshot -> exposition text (pure; the unit test calls it).
 *   vd_metrics   the endpoint. vd_metrics_open binds the socket (start-up: a bind failure
 *                is a configuration error); vd_metrics_start starts its own thread, which
 *                owns the socket and every connection; vd_metrics_publish (estimation
 *                thread) hands it the latest text; vd_metrics_stop stops and joins it.
 *
 * Threads: publish never blocks the estimation thread. It renders into a buffer of its own
 * and copies it into the shared one under a mutex taken with trylock; while the server
 * thread holds the mutex (a memcpy of at most VD_METRICS_TEXT_MAX bytes) the copy is left
 * for the next housekeeping call (vd_metrics_publish returns false). The server thread
 * copies the shared text out under the same mutex before it sends anything, so a slow
 * peer never holds the lock.
 *
 * The server: a single thread, poll() over the listening socket, a stop eventfd and at
 * most VD_METRICS_SLOTS connections, each non-blocking with a hard deadline of
 * VD_METRICS_DEADLINE_S from accept to the last byte sent; a request (line and headers)
 * of more than VD_METRICS_REQUEST_MAX bytes is refused (431), a connection that has not
 * sent a complete request by the deadline is closed (counted "timeout"), and when every
 * slot is busy a new connection evicts the oldest one (counted "evicted"), so idle
 * connections cannot lock a scraper out. GET (and HEAD) /metrics: 200 with the text,
 * GET /: a short pointer page, other paths 404, other methods 405, anything that is not
 * an HTTP/1.x request line 400; the connection is closed after every response (no
 * keep-alive). Nothing a peer does can block or stop the acquisition or estimation.
 *
 * Units: every time in seconds, rates in hertz, latencies in seconds (the daemon's
 * histogram is kept in microseconds and converted here), estimates in the stand's units.
 */
#ifndef VIBIDD_METRICS_H
#define VIBIDD_METRICS_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <netinet/in.h>
#include <pthread.h>
#include <sys/socket.h>

#include <vibid_drivers/source.h>

#include "config.h"

/* outputs.prometheus.listen when the group is given without it: loopback only. 18813 lies
 * outside 9100-9999, the range of the Prometheus wiki's "Default port allocations" (fully
 * allocated to exporters), and below Linux's ephemeral ports (32768-60999). */
#define VD_PROMETHEUS_DEFAULT "127.0.0.1:18813"

#define VD_METRICS_TEXT_MAX (64 * 1024)  /* the exposition's size limit (a 64-parameter stand
                                            with 64 modes needs about 40 KiB) */
#define VD_METRICS_SLOTS 8               /* connections served at once */
#define VD_METRICS_DEADLINE_S 2.0        /* per connection, accept to last byte */
#define VD_METRICS_REQUEST_MAX 8192      /* request line and headers */
#define VD_METRICS_LAT_BOUNDS 10         /* finite buckets of the latency histogram */

/* Upper bounds (le) of the latency histogram's finite buckets, microseconds: all below the
 * daemon's last 1 us bucket (VD_LAT_BUCKETS - 1 = 19999 us, which collects the rest). */
extern const unsigned vd_metrics_lat_bounds_us[VD_METRICS_LAT_BOUNDS];

/* Why a request was refused (the label reason of vibid_metrics_refused_total). */
typedef enum vd_refusal {
    VD_REFUSED_BAD_REQUEST = 0, /* 400: not an HTTP/1.x request line */
    VD_REFUSED_NOT_FOUND,       /* 404 */
    VD_REFUSED_METHOD,          /* 405: not GET or HEAD */
    VD_REFUSED_TOO_LARGE,       /* 431: request longer than VD_METRICS_REQUEST_MAX */
    VD_REFUSED_TIMEOUT,         /* no complete request (or response not taken) by the deadline */
    VD_REFUSED_EVICTED,         /* closed for a newer connection: every slot was busy */
    VD_REFUSED_N
} vd_refusal;

const char *vd_refusal_name(vd_refusal r);

/* One counter or gauge of an output (output.h, counters), as the status file and the
 * exposition show it. The output names it; neither the status file's code nor the
 * exposition's knows any output's counters. */
#define VD_OUTPUT_COUNTERS_MAX 64
typedef struct vd_output_counter {
    const char *key;    /* status-file key ("mqtt_published"); NULL: the exposition only */
    const char *metric; /* exposition family ("vibid_mqtt_published_total"); NULL: the status file only */
    const char *label;  /* the series' labels ("output=\"tracks\""); NULL: none. The series of a
                           family are added one after the other. */
    const char *help;   /* the family's HELP (its first series gives it) */
    bool gauge;         /* a gauge (goes up and down); else a counter (a whole number) */
    double value;       /* counters: whole numbers, exact up to 2^53 */
} vd_output_counter;

/* Everything the status file and the exposition show, at one instant. Strings point to
 * storage that lives as long as the daemon (stand name, source kind, fault names). */
typedef struct vd_snapshot {
    const char *state;     /* "running" or "stopped" */
    const char *stand;     /* the stand's name (any characters: escaped where printed) */
    const char *source;    /* the source kind (vibid_source_kind) */
    const char *estimator; /* configured method (vd_estimator_name) */
    double uptime_s;
    double stand_rate_hz;  /* the stand's sample_rate */
    /* acquisition and estimation */
    uint64_t samples, gaps, missing, faults;
    double rate_hz;        /* samples per second over the last status interval */
    size_t ring_capacity, ring_fill;
    uint64_t ring_high_water, ring_overflows, replay_waits;
    vibid_source_stats src;
    unsigned n_fault_kinds;          /* faults_by_kind[1 .. n_fault_kinds] are used */
    const char *fault_kind[16];
    uint64_t faults_by_kind[16];
    uint64_t rows, est_errors, implausible_rows, nonfinite_samples;
    uint64_t outlier_samples;        /* samples with a glitch taken out (vibid/outlier.h) */
    /* the output-error refinement (refine.h); refine_on false: off, not shown */
    bool refine_on;
    uint64_t refine_done, refine_failed, refine_overruns, refine_skipped;
    double refine_last_s;            /* the last fit's wall time, s (NaN before one) */
    /* output-only mode tracking (oma_track.h); oma_on false: not shown */
    bool oma_on;
    uint64_t oma_done, oma_skipped, oma_lost, oma_without;
    double oma_last_s;               /* the last identification's wall time, s (NaN before one) */
    /* receipt -> estimate latency (live or paced sources; lat_n == 0 otherwise) */
    double lat_p50_us, lat_p99_us;   /* NaN when no sample was measured */
    uint64_t lat_n;
    uint64_t lat_le[VD_METRICS_LAT_BOUNDS]; /* cumulative counts at vd_metrics_lat_bounds_us */
    double lat_sum_s;
    /* the outputs' counters (each output's counters call adds its own, output.h) */
    size_t n_out_counters;
    vd_output_counter out_counter[VD_OUTPUT_COUNTERS_MAX];
    uint64_t alarms_raised;
    /* parameters and modes (names in stand order; modes numbered 1..n_modes) */
    size_t n_params, n_modes;
    const char *param[VD_MAX_PARAMS];
    bool alarm_enabled[VD_MAX_PARAMS], alarm_active[VD_MAX_PARAMS];
    /* alarms.test = "cusum" once the reference exists (have_change): the statistic (>= 1 raises)
       and the minimum detectable change (the parameter's unit, and relative to the reference) */
    bool have_change[VD_MAX_PARAMS];
    double change_statistic[VD_MAX_PARAMS], change_mdc[VD_MAX_PARAMS], change_mdc_relative[VD_MAX_PARAMS];
    /* covariates (source.channels with quantity covariate): names, the latest row's values
       (their block means; NaN none), rows flagged C (outside the alarm reference's range) */
    size_t n_covariates;
    const char *cov_name[VD_MAX_COVARIATES];
    double cov_value[VD_MAX_COVARIATES];
    uint64_t covariate_rows;
    /* the latest row (when have_last) */
    bool have_last;
    uint64_t last_index;
    int64_t last_t_us;
    unsigned last_flags;   /* VD_FLAG_* of estimator.h */
    double theta[VD_MAX_PARAMS], se[VD_MAX_PARAMS];
    double freq[VD_MAX_PARAMS], freq_se[VD_MAX_PARAMS], zeta[VD_MAX_PARAMS], zeta_se[VD_MAX_PARAMS];
    /* the endpoint itself (when it runs) */
    bool metrics_on;
    const char *metrics_listen;      /* the bound address, "127.0.0.1:18813" */
    uint64_t scrapes, refused[VD_REFUSED_N];
} vd_snapshot;

/* Adds an output's counter (gauge false) or gauge to s (vd_output_counter says what each
 * argument is); the strings must outlive s (literals). More than VD_OUTPUT_COUNTERS_MAX are
 * not kept (the unit test of every output's counters checks the room). */
void vd_snapshot_add(vd_snapshot *s, const char *key, const char *metric, const char *label, const char *help,
                     bool gauge, double value);
/* The value of the output counter with status-file key key, NaN when s has none. */
double vd_snapshot_value(const vd_snapshot *s, const char *key);
/* The status file's key=value lines of s's output counters (snprintf's contract). */
size_t vd_snapshot_status_lines(const vd_snapshot *s, char *buf, size_t cap);

/* The exposition text of s into buf. Returns its length, or -1 if cap is too small (the
 * text is then incomplete and must not be served). */
int vd_metrics_render(char *buf, size_t cap, const vd_snapshot *s);

/* One sample value as the exposition writes it: NaN, +Inf, -Inf, else the shortest of
 * %.15g / %.17g that reads back to the same double. */
void vd_metrics_format_double(char *buf, size_t cap, double v);

/* A label value escaped for the exposition (backslash, double quote, newline); cut (never
 * in the middle of an escape) to fit cap. */
void vd_metrics_escape_label(char *dst, size_t cap, const char *src);

/* outputs.prometheus.listen parsed: "HOST:PORT" with HOST an IPv4 literal, "localhost" or
 * a bracketed IPv6 literal ("[::1]:18813"); PORT 0..65535 (0: the kernel picks a free
 * one, logged). 0, or -1 with err saying what is wrong. */
int vd_metrics_parse_listen(const char *text, struct sockaddr_storage *addr, socklen_t *len, char *err, size_t cap);

typedef struct vd_metrics {
    int listen_fd, stop_fd;
    char where[80];            /* "127.0.0.1:18813" as bound (the actual port) */
    bool too_large_logged;
    pthread_t thread;
    bool opened, started;
    pthread_mutex_t mu;        /* guards text/text_len */
    char *text;                /* VD_METRICS_TEXT_MAX, shared: the latest exposition */
    size_t text_len;
    char *render;              /* VD_METRICS_TEXT_MAX, estimation thread only */
    struct vd_metrics_slot *slots; /* VD_METRICS_SLOTS connections, server thread only */
    _Atomic uint64_t scrapes, refused[VD_REFUSED_N];
} vd_metrics;

/* Binds and listens on cfg->prometheus.listen (SO_REUSEADDR, non-blocking, close-on-exec) and
 * allocates the buffers; no thread yet. 0, or -1 with err naming the address and the
 * errno text. */
int vd_metrics_open(vd_metrics *m, const vd_config *cfg, char *err, size_t cap);
/* Starts the server thread (call with the signals blocked: it must not take them). */
int vd_metrics_start(vd_metrics *m, char *err, size_t cap);
/* Renders s and hands it to the server. Without wait, false when the server was busy
 * copying the last text out: call again later (the estimation thread does at its next
 * housekeeping); with wait (the final state, when nothing is left to estimate) it takes
 * the lock. Also false if the text does not fit VD_METRICS_TEXT_MAX (the last complete
 * text stays served, and the failure is logged once). */
bool vd_metrics_publish(vd_metrics *m, const vd_snapshot *s, bool wait);
/* The endpoint's own counters into s (metrics_on, scrapes, refused). */
void vd_metrics_counters(vd_metrics *m, vd_snapshot *s);
/* Stops the thread (at once: it polls the stop eventfd) and closes every socket. Safe on
 * a zeroed or half-opened m. */
void vd_metrics_close(vd_metrics *m);

/* --check: the address parses and can be bound now (the socket is closed at once).
 * 0; 1 when the address is in use (by a running vibidd?): *note says so, start-up would
 * fail unless it is free by then; -1 with err for every other failure. */
int vd_metrics_check(const vd_config *cfg, char *note, size_t note_cap, char *err, size_t cap);

#endif
