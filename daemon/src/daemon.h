/* daemon.h: the run time of vibidd: threads, ring, signals, status, service protocol.
 *
 *   acquisition thread: vibid_source_read -> vd_ring_push. Never blocks on the
 *     estimator or on disk: a full ring refuses the record, which is counted
 *     (ring_overflows) and reported once the ring has room again (a FAULT record and a
 *     log line); the estimator sees the jump in sample indices and treats it as a gap.
 *     File sources (replay) have no deadline, so for them a full ring makes the reader
 *     wait instead (no record is ever dropped in a replay).
 *     Optional SCHED_FIFO priority for this thread (acquisition.realtime_priority).
 *   estimation thread: vd_ring_peek -> estimator -> writers, alarms, status file,
 *     bounded-interval flushes; sleeps on an eventfd when the ring is empty (the producer
 *     wakes it only when it said it sleeps, so a busy pipeline makes no system calls).
 *   main thread: signals (sigtimedwait on a blocked set: no asynchronous handler at all),
 *     the systemd notifications and watchdog pings (only while both threads make
 *     progress).
 * The outputs (output.h) are opened from the registry and reached only through their ops:
 * the estimation thread hands each open output the samples, rows, alarms and status; some
 * have a thread of their own:
 *   metrics thread (outputs.prometheus only): the HTTP endpoint (metrics.h); it reads the
 *     text the estimation thread renders at its housekeeping and nothing else.
 *   MQTT thread (outputs.mqtt only): the broker connection (mqtt.h); it takes the messages the
 *     estimation thread queues (never waiting for them) and the status text it hands over.
 *   InfluxDB thread (outputs.influx.http only): the HTTP writes (influx_http.h); it takes the
 *     lines the estimation thread buffers (never waiting for them).
 * Start order: config -> log -> memory lock -> ring -> estimator -> writers -> source ->
 * metrics socket -> threads -> READY=1; torn down in reverse.
 */
#ifndef VIBIDD_DAEMON_H
#define VIBIDD_DAEMON_H

#include <pthread.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include <vibid_drivers/source.h>

#include "alarm.h"
#include "config.h"
#include "estimator.h"
#include "influx_http.h"
#include "metrics.h"
#include "mqtt.h"
#include "notify.h"
#include "oma_track.h"
#include "output.h"
#include "rate_check.h"
#include "refine.h"
#include "ring.h"
#include "writers.h"

typedef struct vd_options {
    const char *replay;        /* --replay CAPTURE (NULL: the configured source) */
    bool pace;                 /* --pace: replay at the recorded pace */
    double speed;              /* --speed (with --pace) */
    vd_rate_mode rate_check;   /* --rate-check (default error): capture/stand rate mismatch */
    const char *const *outputs;/* the outputs (or parts, output.h) to open by name, NULL-terminated;
                                  NULL: every configured output */
} vd_options;

#define VD_MAX_OUTPUTS 16 /* open outputs at most (the registry has fewer) */

/* One open output (output.h). */
typedef struct vd_output_slot {
    const vd_output_ops *ops;
    void *o;
    bool pending; /* the last status found it busy: offered again at the next housekeeping */
    bool due;     /* status due at this housekeeping */
    double t_last;/* its last status (status_period outputs), monotonic s */
} vd_output_slot;

/* An output whose client library the core does not link (vibidd: vd_mqtt_libmosquitto,
 * mqtt.h; vd_influx_http_curl, influx_http.h), given before vd_daemon_init: it takes the
 * place of the registry's stand-in of the same name (output.c). Without it (a program that
 * links vibidd_core alone, e.g. the Python module's vibid.replay) a configured outputs.mqtt
 * or outputs.influx.http is ignored with a warning. */
void vd_daemon_use_output(const vd_output_ops *ops);

#define VD_LAT_BUCKETS 20000   /* 1 us buckets up to 20 ms; the last one collects the rest */

typedef struct vd_daemon {
    vd_config *cfg;
    vd_options opt;
    vibid_source *src;
    vibid_chanmap rec_chanmap; /* the source's channels (replay of a recording: columns) */
    bool file_source;          /* replay: wait on a full ring instead of dropping */
    bool measure_latency;      /* live or paced: receipt -> estimate histogram; an unpaced
                                  replay has no receipt time worth measuring (records wait
                                  in a full ring by design) */
    vd_ring *ring;
    vd_est est;
    vd_row row;                /* the due row, until finished (finish_row in daemon.c) */
    vd_refine refine;          /* the output-error refinement (refine.h) */
    vd_row refined_row;
    bool unpaced_replay;       /* waits for each refinement and runs each identification inline
                                  (reproducible rows) */
    uint64_t refine_gaps_seen; /* est.gaps at the last look: a new gap ends the clean window */
    vd_omat omat;              /* output-only: the mode tracker (oma_track.h) */
    vd_row oma_row;
    uint64_t omat_gaps_seen;   /* est.gaps at the last look: a new gap is a gap in its ring */
    uint64_t omat_missing_seen;/* est.missing at the last mode row: its gap_samples */
    bool omat_fail_episode;    /* rows without a tracked mode are logged once per episode */
    bool omat_tested_any;      /* the change test took a mode row ... */
    uint64_t omat_tested_index;/* ... at this sample index (the next must not share its window) */
    bool row_pending;
    vd_alarm alarm[VD_MAX_PARAMS];       /* alarms.test = "threshold" */
    vd_cusum cusum;                      /* alarms.test = "cusum" */
    bool cusum_extended_reported;
    uint64_t covariate_rows;      /* rows flagged C (covariates outside the reference's range) */
    bool base_reported[VD_MAX_PARAMS];
    vd_notify notify;
    vd_rate_check *rate;       /* live SocketCAN: the sample-rate check until it decided */
    bool rate_refused;         /* the rate was refused: nothing more is processed */
    int efd;
    pthread_t acq_thread, est_thread;
    pthread_t main_thread;          /* runs vd_daemon_run; woken with VD_WAKE_SIGNAL when done */
    bool acq_started, est_started;

    _Atomic int stop_acq, acq_done, est_done, reopen, fatal;
    _Atomic int consumer_sleeping;
    _Atomic uint64_t acq_beat, est_beat;
    /* acquisition counters, written by the acquisition thread only */
    _Atomic uint64_t acq_records, acq_reads, acq_read_errors, acq_wait_full;
    pthread_mutex_t stats_mu;  /* guards src_stats; the acquisition side only trylocks */
    vibid_source_stats src_stats;

    /* estimation thread state */
    uint64_t faults_by_code[16];
    uint64_t faults, gap_records;
    uint64_t alarms_raised;
    bool pref_reported;        /* the plausibility reference was logged (when its zeta rule is off) */
    bool implausible_episode;  /* rows are flagged P since sample episode_first */
    uint64_t episode_first, episode_rows;
    uint32_t *lat_hist;        /* receipt -> estimate pushed, 1 us buckets */
    uint64_t lat_n;
    uint64_t lat_sum_us;       /* sum of the measured latencies (not clipped), us */
    double t_start, t_last_flush, t_last_status, t_last_logstatus;
    uint64_t samples_at_last_status;
    double rate_hz;
    /* the counters at one instant, for the status file and the metrics alike (metrics.h);
     * filled by the estimation thread at its housekeeping */
    vd_snapshot snap;
    /* the open outputs (output.h), in registry order; out_ctx is what they were opened with */
    vd_output_ctx out_ctx;
    vd_output_slot out[VD_MAX_OUTPUTS];
    size_t n_out;
    char status_text[8192];    /* the status file's text, also the MQTT status */
    size_t status_len;
} vd_daemon;

/* Opens everything (see the start order). 0, or -1 with err. */
int vd_daemon_init(vd_daemon *d, vd_config *cfg, const vd_options *opt, char *err, size_t cap);
/* Runs until SIGTERM/SIGINT or the end of a replay; returns the exit status (0 ok, 1 a
 * fatal run-time error, 2 the live source's sample rate was refused: rate_check.h). */
int vd_daemon_run(vd_daemon *d);
void vd_daemon_fini(vd_daemon *d);

/* --check: the sample-rate check of the capture when the source is a replay (or --replay
 * is given); 0 with the outcome in note ("" if none), or -1 with err (refused, or the
 * capture's configuration is wrong). */
int vd_daemon_check_capture(const vd_config *cfg, const vd_options *opt, char *note, size_t note_cap, char *err,
                            size_t cap);

/* Latency percentile (0..1) in microseconds from the histogram, NAN when empty. */
double vd_daemon_latency_us(const vd_daemon *d, double q);

#endif
