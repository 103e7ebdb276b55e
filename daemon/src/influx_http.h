/* influx_http.h: track rows and alarm events written to InfluxDB over HTTP
 * (outputs.influx.http; docs/vibidd.md, "InfluxDB over HTTP"), with libcurl.
 *
 * What is sent: the lines of writers.h's influx output (measurement, tags site and stand,
 * the fields of a track row; <measurement>_alarm for alarm events), byte for byte, except
 * that a line written after lines were dropped carries the integer field dropped_before =
 * the number dropped just before it. API v1: POST <url>/write?db=&rp=&precision=ns with
 * HTTP basic authentication (InfluxDB 1.x; also 2.x's compatibility API). API v2: POST
 * <url>/api/v2/write?org=&bucket=&precision=ns with "Authorization: Token ..." (InfluxDB
 * 2.x, 3.x).
 *
 * Threads and data flow: the estimation thread formats each line into a byte ring (the
 * retry buffer, buffer_size MiB, allocated at start) and never waits: when the ring is full
 * the line is dropped and counted (influx_http_dropped) and the next line that gets in
 * carries dropped_before. The writer thread owns the curl handle (one kept-alive
 * connection): it takes up to batch_size lines from the oldest end of the ring, once the
 * oldest has waited batch_interval or batch_size lines are waiting, and POSTs them. Only a
 * 2xx answer frees them; otherwise:
 *   connection failure, time-out, 408, 429, 5xx: the same lines again after a back-off
 *     (0.5 s doubling to 30 s; a Retry-After of the server is honoured up to 30 s);
 *   401, 403, 404 (credentials, permissions, a database not yet created): logged with the
 *     server's message and retried the same way; an administrator can fix it while vibidd
 *     keeps the lines;
 *   413 (request too large): the batch is halved and sent again;
 *   400, 422 and other 4xx: the server refused the lines themselves (a field type
 *     conflict, a point outside the retention policy); they would be refused forever, so
 *     they are counted (influx_http_rejected) and logged with the server's message and the
 *     writer goes on (InfluxDB 1.x has written the valid points of such a "partial write").
 * A batch that reached the server but whose answer was lost is sent again; InfluxDB keeps
 * one point per series and timestamp, so the repetition overwrites the point with itself
 * (idempotent: no duplicate rows).
 * An answer is read up to its first KiB of body (and 64 KiB of headers): the transfer then
 * ends and the connection is closed, so a server that streams a long body costs nothing.
 * SIGTERM: the writer sends what is buffered for at most drain_timeout (an unfinished
 * request is aborted at the deadline), and ends at once when the back-off or the server's
 * Retry-After puts the next request after the deadline; then it says how many lines were
 * left (influx_http_waiting).
 *
 * The daemon's core (vibidd_core) does not link libcurl (the Python module links the core
 * without it): vibidd's main() hands its output ops over with vd_daemon_use_output.
 */
#ifndef VIBIDD_INFLUX_HTTP_H
#define VIBIDD_INFLUX_HTTP_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "config.h"
#include "estimator.h"
#include "metrics.h"
#include "output.h"

typedef struct vd_influx_http vd_influx_http;

/* The output "influx.http" (output.h), the state a vd_influx_http: open reads the password
 * or token file, allocates the ring and sets up libcurl (nothing is connected; the stand tag
 * is the context's stand; NULL with err on failure: a configuration error); start starts the
 * writer thread; row and alarm buffer a line and never wait (a full ring drops and counts);
 * counters: the influx_http_* counters (also from the main thread after drain); drain sends
 * what is buffered (at most drain_timeout) and joins the thread, the counters stay readable;
 * close drains, then frees (NULL-safe). */
extern const vd_output_ops vd_influx_http_curl;

/* --check: the password or token file and the CA file can be read (nothing is
 * connected). 0 (no note: the output's check, output.h), or -1 with err naming the setting
 * and the file. */
int vd_influx_http_check(const vd_config *cfg, char *note, size_t note_cap, char *err, size_t cap);

/* The write endpoint of cfg (url, API, database or org and bucket, precision=ns) with the
 * query values percent-encoded, into buf. The length, or -1 if cap is too small. */
int vd_influx_http_write_url(char *buf, size_t cap, const vd_config *cfg);

/* What the writer does with an HTTP answer (status 0: no answer: a transport failure). */
typedef enum vd_influx_http_verdict {
    VD_IH_WRITTEN = 0,  /* 2xx: the lines are freed */
    VD_IH_RETRY,        /* the same lines again after the back-off */
    VD_IH_SPLIT,        /* 413: halve the batch */
    VD_IH_REJECTED,     /* the lines are refused for good: counted, freed */
} vd_influx_http_verdict;
vd_influx_http_verdict vd_influx_http_verdict_of(long status);

#endif
