/* output.c: the registry of vibidd's outputs (output.h), with stand-ins for the two outputs
 * whose client library the core does not link (MQTT: libmosquitto, InfluxDB over HTTP:
 * libcurl) until vibidd's main() hands them over (vd_daemon_use_output). */

#include "output.h"

#include <stdio.h>
#include <string.h>

#include "daemon.h"
#include "log.h"

bool vd_output_selected(const vd_output_ctx *ctx, const char *name)
{
    if (!ctx->select)
        return true;
    for (const char *const *s = ctx->select; *s; s++)
        if (!strcmp(*s, name))
            return true;
    return false;
}

bool vd_output_wanted(const vd_output_ctx *ctx, const vd_output_ops *ops)
{
    if (vd_output_selected(ctx, ops->name))
        return true;
    for (const char *const *p = ops->parts; p && *p; p++)
        if (vd_output_selected(ctx, *p))
            return true;
    return false;
}

/* ------------------------------------- stand-ins for outputs.mqtt and .http ---- */

/* What the registry holds for an output the core does not link until main() hands the
 * real one over (vd_daemon_use_output): configured, it is ignored with a warning. */
static bool mqtt_enabled(const vd_config *cfg) { return cfg->mqtt.url[0] != '\0'; }
static bool influx_http_enabled(const vd_config *cfg) { return cfg->influx_http.url[0] != '\0'; }

static void *mqtt_absent(const vd_output_ctx *ctx, char *err, size_t cap)
{
    (void)ctx;
    (void)err;
    (void)cap;
    vd_warning("outputs.mqtt ignored: this program has no MQTT client (libmosquitto); vibidd has");
    return NULL;
}

static void *influx_http_absent(const vd_output_ctx *ctx, char *err, size_t cap)
{
    (void)ctx;
    (void)err;
    (void)cap;
    vd_warning("outputs.influx.http ignored: this program has no HTTP client (libcurl); vibidd has");
    return NULL;
}

static const vd_output_ops mqtt_standin = {.name = "mqtt", .enabled = mqtt_enabled, .open = mqtt_absent};
static const vd_output_ops influx_http_standin = {
    .name = "influx.http", .enabled = influx_http_enabled, .open = influx_http_absent};

/* ---------------------------------------------------------- the registry ---- */

/* The outputs: whatever carries the run's results (raw samples, track rows, alarm events,
 * the status snapshot) out of the process, to files, sockets or brokers:
 *   files        writers.c: the tracks CSV, InfluxDB line protocol to a file and UDP, the raw
 *                recording, and the status file (one output: they share the write-error
 *                accounting, whose total is the exit status, and the SIGHUP reopen; each
 *                part is selected on its own: "tracks", "influx", "record", "status")
 *   prometheus   metrics.c: the /metrics endpoint (the status snapshot, served)
 *   mqtt         mqtt.c: tracks, alarms and status to a broker
 *   influx.http  influx_http.c: tracks and alarms to InfluxDB's HTTP API
 * Not outputs: the systemd notifications (notify.c: the service protocol, READY, WATCHDOG,
 * STOPPING, sent by the main thread whatever the outputs are) and the log (log.c).
 * The order is the order of open and start; drain and close go in reverse (so
 * outputs.influx.http drains before outputs.mqtt, as before the registry). */
const vd_output_ops *vd_outputs[] = {
    &vd_output_files,
    &vd_output_prometheus,
    &mqtt_standin,        /* vd_mqtt_libmosquitto in vibidd */
    &influx_http_standin, /* vd_influx_http_curl in vibidd */
};
const size_t vd_n_outputs = sizeof vd_outputs / sizeof vd_outputs[0];

void vd_daemon_use_output(const vd_output_ops *ops)
{
    for (size_t i = 0; i < vd_n_outputs; i++)
        if (!strcmp(vd_outputs[i]->name, ops->name))
            vd_outputs[i] = ops;
}
