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

void vd_output_known_keys(const char *group, const char *const *own, const char **keys, size_t cap)
{
    size_t n = 0, len = strlen(group);
    for (; own && own[n] && n + 1 < cap; n++)
        keys[n] = own[n];
    for (size_t i = 0; i < vd_n_outputs; i++)
        for (const char *const *g = vd_outputs[i]->groups; g && *g; g++)
            if (!strncmp(*g, group, len) && (*g)[len] == '.' && n + 1 < cap)
                keys[n++] = *g + len + 1;
    keys[n] = NULL;
}

void vd_output_print_nested(const vd_config *cfg, const char *group, FILE *out)
{
    size_t len = strlen(group);
    for (size_t i = 0; i < vd_n_outputs; i++) {
        const char *g = vd_outputs[i]->groups ? vd_outputs[i]->groups[0] : NULL;
        if (g && vd_outputs[i]->print && !strncmp(g, group, len) && g[len] == '.')
            vd_outputs[i]->print(cfg, out);
    }
}

/* ------------------------------------- stand-ins for outputs.mqtt and .http ---- */

/* What the registry holds for an output the core does not link until main() hands the
 * real one over (vd_daemon_use_output): configured, it is ignored with a warning. */

static void *absent(const char *output, const char *client)
{
    vd_warning("outputs.%s ignored: this program has no %s; vibidd has", output, client);
    return NULL;
}

static void *mqtt_absent(const vd_output_ctx *ctx, char *err, size_t cap)
{
    (void)ctx, (void)err, (void)cap;
    return absent("mqtt", "MQTT client (libmosquitto)");
}

static void *influx_http_absent(const vd_output_ctx *ctx, char *err, size_t cap)
{
    (void)ctx, (void)err, (void)cap;
    return absent("influx.http", "HTTP client (libcurl)");
}

static const vd_output_ops mqtt_standin = {.name = "mqtt",
                                           .groups = vd_mqtt_groups,
                                           .load = vd_mqtt_load,
                                           .print = vd_mqtt_print,
                                           .enabled = vd_mqtt_enabled,
                                           .open = mqtt_absent};
static const vd_output_ops influx_http_standin = {.name = "influx.http",
                                                  .groups = vd_influx_http_groups,
                                                  .load = vd_influx_http_load,
                                                  .print = vd_influx_http_print,
                                                  .enabled = vd_influx_http_enabled,
                                                  .open = influx_http_absent};

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
