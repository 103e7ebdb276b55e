/* output.h: vibidd's outputs behind one interface (collectd's write plugins; the sources'
 * vibid_source_ops). The daemon (daemon.c) knows no output by name: it opens every output of
 * the registry that is configured and selected, and loops over the open ones.
 *
 * What an output is: something that takes the run's results (samples, track rows, alarm
 * events, the status snapshot) out of the process. The registry (output.c) lists them and
 * says why each is one; the systemd notifications (notify.h) and the log are the service's
 * own protocol, not outputs.
 *
 * Settings: each output reads its own groups of `outputs` (groups, load) with the one
 * configuration reader (config_read.h), while config.c reads the file once, prints them back
 * for --check (print) and checks what they name (check). Its settings struct is a member of
 * vd_config (config.h). An output whose run-time code needs a library the core does not link
 * (MQTT, InfluxDB over HTTP) keeps its settings code in the core (mqtt_settings.c,
 * influx_http_settings.c), so that every program reads the same configuration.
 *
 * Ownership: open allocates the output's state (the void * every other call takes) and
 * close frees it; the configuration and the context passed to open outlive the output (the
 * output keeps pointers into them).
 *
 * Call order (each call optional, NULL in the table when an output has nothing to do):
 *   configuration:           load (every output of the registry, in order, while config.c
 *                            reads the file), print (vibidd --check)
 *   vibidd --check:          check (every output of the registry, configured or not), nothing else
 *   main thread, start-up:   enabled -> open (all outputs, registry order) -> start
 *   estimation thread:       sample, row, alarm (in the samples' order), flush (bounded
 *                            interval and at the end), reopen (after SIGHUP), counters,
 *                            status_lines and status (at its housekeeping: one snapshot
 *                            for all)
 *   main thread, the end:    after the estimation thread is joined: drain (reverse
 *                            registry order), counters, status (VD_OUTPUT_STATUS_AFTER_DRAIN
 *                            outputs: the counters after the drain), failed; close (reverse
 *                            registry order, also after a failed start-up; NULL-safe)
 * sample, row and alarm run on the estimation thread's hot path: they never wait (a full
 * queue drops and counts, a failed write is counted), so that no output can hold up the
 * estimates or another output. An output with a thread of its own starts it in start (the
 * signals are blocked by then) and stops it in drain or close.
 *
 * Adding an output: one file with its ops (docs/vibidd.md, "Adding an output") and one line
 * in the registry (output.c).
 */
#ifndef VIBIDD_OUTPUT_H
#define VIBIDD_OUTPUT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include <vibid_drivers/channel_map.h>
#include <vibid_drivers/source.h>

#include "alarm.h"
#include "config.h"
#include "config_read.h"
#include "estimator.h"
#include "metrics.h"

/* What open gets besides the configuration. */
typedef struct vd_output_ctx {
    const vd_config *cfg;
    const vibid_chanmap *rec_chanmap; /* the source's channels in record order (raw recording) */
    const char *tracks_preamble;      /* "# " lines before the tracks header (the estimator's choices), or NULL */
    const char *stand;                /* the stand's name as a tag: outputs.influx.stand, else the stand's name */
    const char *const *select;        /* names of the outputs (or their parts) to open, NULL-terminated;
                                         NULL: every configured output */
} vd_output_ctx;

/* An alarm event, as every output gets it (alarm.h). */
typedef vd_alarm_report vd_output_alarm;

enum {
    /* status at every status interval (outputs.status.interval; otherwise status_period) */
    VD_OUTPUT_STATUS_TEXT = 1u << 0,       /* status wants the status file's text (key=value lines) */
    VD_OUTPUT_STATUS_AFTER_DRAIN = 1u << 1 /* status once more after the drain, with its counters */
};

typedef struct vd_output_ops {
    const char *name;          /* as the configuration names it: "mqtt" for outputs.mqtt */
    const char *const *parts;  /* names of the parts that can be selected on their own (NULL-terminated), or NULL */
    unsigned flags;            /* VD_OUTPUT_* */
    /* Its groups in `outputs` (NULL-terminated): "tracks" for outputs.tracks; a dotted name,
     * "influx.http", is a group inside another output's group (that output's load accepts
     * the member, vd_output_known_keys, and its print prints it, vd_output_print_nested). */
    const char *const *groups;
    /* Reads its groups from the `outputs` group (NULL when the file has none: every default)
     * into c->cfg with the getters of config_read.h; 0, or -1 with c->r.err. */
    int (*load)(vd_cfg_ctx *c, const config_setting_t *outputs);
    /* Its groups as members of `outputs`, in the file's syntax with every default (vd_config_print). */
    void (*print)(const vd_config *cfg, FILE *out);
    /* Configured in cfg (its group is there and turns it on). */
    bool (*enabled)(const vd_config *cfg);
    /* vibidd --check: the start-up checks that create and connect nothing (directories,
     * secret and TLS files, an address bound and released), configured or not. 0; 1 with a
     * note (a warning, also printed after the configuration); -1 with err. */
    int (*check)(const vd_config *cfg, char *note, size_t note_cap, char *err, size_t cap);
    /* Opens (files, sockets, queues; a thread is not started yet). NULL with err on failure:
     * a configuration error (exit 2). NULL with err empty: this program has no
     * implementation of the output (open warned; the run goes on without it). */
    void *(*open)(const vd_output_ctx *ctx, char *err, size_t cap);
    int (*start)(void *o, char *err, size_t cap);
    /* The raw samples (every record as received; the output picks the samples). */
    void (*sample)(void *o, const vibid_record *rec);
    void (*row)(void *o, const vd_row *row);
    void (*alarm)(void *o, const vd_output_alarm *a);
    /* The status: snapshot s and, with VD_OUTPUT_STATUS_TEXT, its text; final: the last one
     * (the output may wait for its lock). false when the output was busy: offered again at
     * the next housekeeping. */
    bool (*status)(void *o, const vd_snapshot *s, const char *text, size_t len, bool final);
    /* The output's own key=value lines of the status file that are not counters (its
     * counters come with them already: counters), from s, into buf (snprintf's contract: the
     * length of the whole text, written as far as cap allows). */
    size_t (*status_lines)(const vd_snapshot *s, char *buf, size_t cap);
    /* Seconds between status calls when not the status interval (0: the status interval). */
    double (*status_period)(const vd_config *cfg);
    void (*flush)(void *o, bool sync);
    void (*reopen)(void *o);
    /* Adds the output's counters and gauges to s (vd_snapshot_add, metrics.h): the status file
     * and the exposition show them under the names the output gives; s starts zeroed. */
    void (*counters)(void *o, vd_snapshot *s);
    /* Sends what is left (bounded by the output's drain_timeout), stops its thread. */
    void (*drain)(void *o);
    /* A write failed during the run: the exit status is 1. */
    bool (*failed)(void *o);
    void (*close)(void *o);
} vd_output_ops;

/* The registry: every output vibidd has, in the order they are opened (an entry changes
 * only by vd_daemon_use_output, daemon.h, before vd_daemon_init). */
extern const vd_output_ops *vd_outputs[];
extern const size_t vd_n_outputs;

/* The keys of the group `group` of `outputs`: own (the owner's, NULL-terminated), then the last
 * part of every registry output's dotted group inside it ("http" for "influx.http"), into
 * keys (cap entries, NULL-terminated). */
void vd_output_known_keys(const char *group, const char *const *own, const char **keys, size_t cap);
/* Prints the groups that registry outputs keep inside group (their print) into out. */
void vd_output_print_nested(const vd_config *cfg, const char *group, FILE *out);

/* name (an output's or one of its parts') is selected by ctx. */
bool vd_output_selected(const vd_output_ctx *ctx, const char *name);
/* The output or any of its parts is selected by ctx. */
bool vd_output_wanted(const vd_output_ctx *ctx, const vd_output_ops *ops);

/* The outputs of the registry (output.c), for the files that define them. */
extern const vd_output_ops vd_output_files;      /* writers.c */
extern const vd_output_ops vd_output_prometheus; /* metrics.c */

/* The settings of the outputs whose run-time code lives outside the core (output.h,
 * "Settings"): one definition, used by the core's stand-in and by the real output. */
extern const char *const vd_mqtt_groups[];        /* mqtt_settings.c */
int vd_mqtt_load(vd_cfg_ctx *c, const config_setting_t *outputs);
void vd_mqtt_print(const vd_config *cfg, FILE *out);
bool vd_mqtt_enabled(const vd_config *cfg);
extern const char *const vd_influx_http_groups[]; /* influx_http_settings.c */
int vd_influx_http_load(vd_cfg_ctx *c, const config_setting_t *outputs);
void vd_influx_http_print(const vd_config *cfg, FILE *out);
bool vd_influx_http_enabled(const vd_config *cfg);

#endif
