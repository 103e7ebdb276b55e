/* writers.h: the daemon's outputs.
 *
 *  tracks   CSV with a header row, one row per decimated estimate:
 *             time_s, index, <p>, <p>_se for every unknown p (stand order),
 *             f<i>_hz, f<i>_hz_se, zeta<i>, zeta<i>_se for every mode i (ascending f),
 *             gap_samples, flags
 *           time_s: sample time, s since the Unix epoch, to the microsecond; index:
 *           sample index from the run's start; a value that could not be computed is
 *           "nan"; flags: G (gap since the previous row), E (no estimate), P (the
 *           estimate is physically impossible, vibid/plausibility.h: values written as
 *           they are), A (alarm active), "" otherwise.
 *  influx   InfluxDB line protocol, to a file and/or UDP datagrams (Telegraf's
 *           socket_listener / InfluxDB's UDP service):
 *             <measurement>,stand=<name> c1=..,c1_se=..,f1_hz=..,..,index=..i,gap_samples=0i,flags="P" <ns>
 *           (flags as in the tracks: filter on it, e.g. flags !~ /P/, to drop impossible estimates)
 *           non-finite fields are left out (line protocol has no NaN); alarm events as
 *             <measurement>_alarm,stand=<name>,parameter=<p> state="raised",value=..,baseline=..,z=.. <ns>
 *  record   raw samples as CSV: a comment line "# vibidd raw recording ...", a header
 *           "t,<channel>...", rows "t,values" with t in s to the microsecond and values
 *           as %.17g (exact round trip). --replay reads it back; missing samples show as
 *           time steps, which the replay turns into the same gaps.
 *           Or (format candump, CAN sources) as a candump -l log: each sample encoded
 *           into its DBC messages with the sample counter, all frames at the sample time
 *           to the microsecond; missing samples show as counter jumps.
 * Writes are buffered (stdio) and flushed by the caller on a bounded interval
 * (outputs.tracks.flush_interval) and at exit; every failed write is counted and
 * logged (first failure per file, then once a minute). Each file output is opened and
 * reopened on its own (vd_output): one that fails to reopen is retried while the others go
 * on, and what it misses meanwhile is counted (vd_output.lost), never lost silently.
 */
#ifndef VIBIDD_WRITERS_H
#define VIBIDD_WRITERS_H

#include <stdint.h>
#include <stdio.h>

#include <netinet/in.h>

#include <vibid_drivers/can_assembler.h>

#include "config.h"
#include "estimator.h"
#include "output.h"

#define VD_RECORDING_MAGIC "# vibidd raw recording"

/* The file outputs (vd_writers.out[]) and, for the per-output error counts, the status file. */
enum { VD_OUT_TRACKS = 0, VD_OUT_INFLUX, VD_OUT_RECORD, VD_OUT_FILES, VD_OUT_STATUS = VD_OUT_FILES };

/* The parts of the output "files" (output.h) that can be selected on their own (the replay
 * of the Python package opens the tracks alone): bit 1 << i is part i of "tracks",
 * "influx" (file and UDP), "record", "status". */
enum {
    VD_PART_TRACKS = 1u << 0,
    VD_PART_INFLUX = 1u << 1,
    VD_PART_RECORD = 1u << 2,
    VD_PART_STATUS = 1u << 3,
    VD_PARTS_ALL = 15u
};

/* One file output. Each is opened, reopened (SIGHUP), failed and retried on its own: a
 * reopen that fails leaves that output closed (closed = true) and never the others; what
 * would have gone to it meanwhile is counted in lost, and it is tried again after a
 * back-off (vd_writers_flush) and at every SIGHUP. */
typedef struct vd_output {
    FILE *f;
    const char *path;         /* the configuration's path; "" = off */
    const char *what;         /* for messages: "tracks", "influx", "raw recording" */
    bool closed;              /* configured, but the last (re)open failed */
    uint64_t lost;            /* records (rows, lines, samples) not written while closed */
    uint64_t open_failures;   /* failed (re)opens, retries included */
    uint64_t failed_attempts; /* of the current closed episode */
    double retry_at, backoff; /* monotonic s */
} vd_output;

typedef struct vd_writers {
    const vd_config *cfg;
    const vibid_chanmap *chanmap; /* channels of the raw recording, in record order */
    const char *stand_name;
    const char *tracks_preamble;  /* "# " lines before the tracks header, or NULL */
    const char *status_path;      /* outputs.status.path, "" = off (or not selected) */
    vd_output out[VD_OUT_FILES];
    vibid_can_assembler *record_encoder; /* candump recording: samples -> frames (source DBC) */
    int udp_fd;
    struct sockaddr_in udp_addr;
    uint64_t write_errors, udp_errors, udp_sent;
    uint64_t torn_lines;   /* torn last lines cut off outputs at open (a run killed mid-write) */
    /* per output (VD_OUT_TRACKS .. VD_OUT_STATUS): failed writes and the last time they were
     * logged (monotonic s); vd_writers_failed */
    uint64_t output_errors[VD_OUT_FILES + 1];
    double output_report[VD_OUT_FILES + 1];
    char linebuf[16384];
} vd_writers;

/* Opens every configured output (append mode for tracks/influx/record; a header is
 * written when the file is empty). tracks_preamble (may be NULL): lines written before
 * the tracks' column header, each prefixed "# " (what the estimator chose and why);
 * must live as long as w. 0, or -1 with err naming the file and errno. */
int vd_writers_open(vd_writers *w, const vd_config *cfg, const vibid_chanmap *chanmap, const char *tracks_preamble,
                    char *err, size_t cap);
/* The same for the parts (VD_PART_*) only: the others stay off as if their paths were "". */
int vd_writers_open_parts(vd_writers *w, const vd_config *cfg, const vibid_chanmap *chanmap,
                          const char *tracks_preamble, unsigned parts, char *err, size_t cap);
/* Replaces the status file (outputs.status.path; nothing when off) with buf[0..len). */
void vd_writers_status(vd_writers *w, const char *buf, size_t len);
/* The start-up checks of every output, without creating anything: each output's
 * (tracks, InfluxDB file, record, status) directory exists and is writable, an existing
 * output file is a writable regular file, and outputs.influx.udp names a host that
 * resolves to an IPv4 address. vd_writers_open runs them first and `vibidd --check`
 * runs them, so both refuse the same configurations. 0, or -1 with err naming the
 * setting and the path. */
int vd_writers_check(const vd_config *cfg, char *err, size_t cap);
/* A failed write of output path (one of the configuration's output paths; what says
 * which step): counted in write_errors and per output; each output's first failure is
 * logged at once (so a second output failing later is not hidden behind the first), then
 * at most once a minute with its count. Uses errno. */
void vd_writers_failed(vd_writers *w, const char *what, const char *path);
/* SIGHUP: closes and reopens each file (logrotate moved them away), each on its own: one
 * that cannot be opened (logged, counted in write_errors and its open_failures) stays closed
 * and is retried by vd_writers_flush, the others are open again. The number of outputs
 * left closed (0: all reopened). */
int vd_writers_reopen(vd_writers *w);
/* File outputs configured but closed now (a failed reopen, being retried). */
unsigned vd_writers_closed(const vd_writers *w);
void vd_writers_row(vd_writers *w, const vd_row *row);
void vd_writers_sample(vd_writers *w, const vibid_record *rec);
void vd_writers_alarm(vd_writers *w, const vd_output_alarm *a);
/* fflush (and fdatasync when sync) every open file; first, every closed output whose retry
 * is due is opened again (back-off 1 s doubling to 30 s; logged when it fails, at most once
 * a minute, and when it succeeds, with the records lost meanwhile). */
void vd_writers_flush(vd_writers *w, int sync);
void vd_writers_close(vd_writers *w);

/* Formatters (also used by the tests). Return the length written, or -1 if cap is too
 * small. */
int vd_format_tracks_header(char *buf, size_t cap, const vd_config *cfg);
int vd_format_track_row(char *buf, size_t cap, const vd_config *cfg, const vd_row *row);
int vd_format_influx_row(char *buf, size_t cap, const vd_config *cfg, const char *stand, const vd_row *row);
/* The alarm event a (docs/vibidd.md, InfluxDB schema). */
int vd_format_influx_alarm(char *buf, size_t cap, const vd_config *cfg, const char *stand, const vd_output_alarm *a);
int vd_format_recording_header(char *buf, size_t cap, const char *stand, double rate, const vibid_chanmap *map);
int vd_format_recording_row(char *buf, size_t cap, const vibid_record *rec);
/* candump recording: the frames of one sample (vibid_can_assembler_encode), one candump -l
 * line each; -1 if cap is too small or a value does not fit its signal. */
int vd_format_recording_frames(char *buf, size_t cap, const vibid_can_assembler *enc, const char *iface,
                               const vibid_record *rec);
/* Adds fields ("a=1i,b=2i") to the end of the field set of the line buf[0..n) (a line of
 * vd_format_influx_row or _alarm, its newline dropped): written before the timestamp, the
 * result NUL-terminated without a newline. The new length, or -1 if cap is too small or the
 * line has no timestamp. */
int vd_influx_add_fields(char *buf, size_t cap, int n, const char *fields);
/* Influx tag value escaping (commas, spaces, equals signs). */
void vd_influx_escape_tag(char *dst, size_t cap, const char *src);

#endif
