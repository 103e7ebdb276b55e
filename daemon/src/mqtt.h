/* mqtt.h: tracks, alarms and status published to an MQTT broker (outputs.mqtt; docs/vibidd.md,
 * "MQTT"), with libmosquitto.
 *
 * Topics (one topic level each for site and stand):
 *   <topic_prefix>/<site>/<stand>/tracks              one message per track row, not retained
 *   <topic_prefix>/<site>/<stand>/alarms/<parameter>  alarm raised/cleared, retained (so a new
 *                                                     subscriber sees each parameter's state)
 *   <topic_prefix>/<site>/<stand>/status              the status snapshot, retained; the last
 *                                                     will puts {"state":"offline"} there
 * Payloads: JSON (format "json", the schema in docs/vibidd.md) or the InfluxDB line of
 * writers.h with the fields seq and dropped_before added (format "line"; the status is JSON
 * in both). Every message carries the stand, a sequence number and the sample index. seq
 * counts per kind (tracks, alarms, status) from 1 in each run.
 *
 * Threads and data flow: the estimation thread formats each message into a slot of a
 * bounded single-producer single-consumer queue (queue_size slots, each as long as the
 * longest message the stand can produce, allocated at start) and never waits: when the
 * queue is full the message is dropped and counted (mqtt_dropped), its seq stays used, and
 * the next message of that kind that gets in carries dropped_before = the number dropped just
 * before it, so a consumer sees a seq gap and knows vibidd dropped it. The status is not
 * queued: the estimation thread hands the status file's text over under a mutex it only
 * tries to take (as the metrics do); only the latest status matters (it is state, not an
 * event), the publisher converts it to JSON. The publisher thread owns the libmosquitto
 * handle: it connects (non-blocking) with back-off (0.5 s doubling to 30 s), sets the last
 * will before connecting, publishes the latest status retained at every connection, and
 * takes a message out of the queue only once mosquitto_publish accepted it, while at most
 * VD_MQTT_WINDOW messages wait for their acknowledgement; after a lost connection
 * libmosquitto resends those on the next one (QoS 1: at least once, so a consumer may see a
 * seq twice). A CONNACK must come within 5 s of an attempt's start (a peer that never answers
 * is a failed attempt with its reason, not libmosquitto's "Unknown error." after the
 * keep-alive). It polls the broker's socket and an eventfd (new message, stop), so SIGTERM
 * stops it at once; at the end it publishes what is queued and the final status for at most
 * drain_timeout, reconnecting meanwhile when the connection is down and can come back (the
 * broker down or restarting: not a refusal, a TLS failure or an unanswered CONNECT), then
 * disconnects cleanly (no will; a connection lost before the DISCONNECT is reconnected to put
 * the final status over the will). It ends as soon as nothing more can be sent (the next
 * attempt would come after the deadline) and counts what is left (mqtt_unsent).
 *
 * The daemon's core (vibidd_core) does not link libmosquitto (the Python module links the
 * core without it): vibidd's main() hands its output ops over with vd_daemon_use_output, in
 * place of the registry's stand-in (output.c).
 */
#ifndef VIBIDD_MQTT_H
#define VIBIDD_MQTT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "config.h"
#include "estimator.h"
#include "metrics.h"
#include "output.h"

#define VD_MQTT_WINDOW 100 /* messages handed to libmosquitto and not yet acknowledged */
#define VD_MQTT_STATUS_MAX 16384

typedef enum vd_mqtt_kind { VD_MQTT_TRACKS = 0, VD_MQTT_ALARMS = 1, VD_MQTT_STATUS = 2 } vd_mqtt_kind;

typedef struct vd_mqtt vd_mqtt;

/* The output "mqtt" (output.h), the state a vd_mqtt: open reads the password file, builds
 * the topics and the queue and sets up libmosquitto (no connection yet; NULL with err on
 * failure: a configuration error); start starts the publisher thread; row (one message per
 * track row) and alarm queue and never wait (a full queue drops and counts); status hands
 * over the status file's text (key=value lines; the snapshot is not used): without final,
 * false when the publisher was copying the previous one just then; counters: the mqtt_*
 * counters; drain publishes what is left (at most drain_timeout, reconnecting if it can),
 * disconnects and joins the thread, the counters stay readable (mqtt_unsent: what was
 * left); close drains, then frees (NULL-safe). */
extern const vd_output_ops vd_mqtt_libmosquitto;

/* --check: the password file and the TLS files can be read (nothing is connected). 0 (no
 * note: the output's check, output.h), or -1 with err naming the setting and the file. */
int vd_mqtt_check(const vd_config *cfg, char *note, size_t note_cap, char *err, size_t cap);

/* Formatters (pure; the unit test calls them). stand: the topic's stand name. Return the
 * length, or -1 if cap is too small. JSON numbers as the tracks CSV writes them (%.10g);
 * NaN and infinities are not JSON: null. */
int vd_mqtt_format_track(char *buf, size_t cap, const vd_config *cfg, const char *stand, uint64_t seq,
                         uint64_t dropped_before, const vd_row *row);
int vd_mqtt_format_alarm(char *buf, size_t cap, const vd_config *cfg, const char *stand, uint64_t seq,
                         uint64_t dropped_before, const vd_output_alarm *a);
/* The status file's text (key=value lines) as a JSON object: "stand", "site", "seq",
 * "index" (last_index, or null before the first row) first, then every key in the file's
 * order; a value that is a JSON number stays a number, nan/inf become null, anything else
 * is a string. */
int vd_mqtt_format_status(char *buf, size_t cap, const vd_config *cfg, const char *stand, uint64_t seq,
                          const char *text, size_t len);
/* A string as a JSON string literal (quotes included). */
int vd_mqtt_json_string(char *buf, size_t cap, const char *s);

#endif
