/* influx_http.c: see influx_http.h. */

#include "influx_http.h"

#include "clock.h"
#include "log.h"
#include "writers.h"

#include <curl/curl.h>
#include <errno.h>
#include <math.h>
#include <poll.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <time.h>
#include <unistd.h>

#define BACKOFF_FIRST_S 0.5
#define BACKOFF_MAX_S 30.0
#define RELOG_S 60.0                  /* a repeated failure is logged again at most this often */
#define BATCH_BYTES_MAX (8u << 20)    /* one request's body at most (InfluxDB 1.x accepts 25 MB) */
#define ANSWER_MAX 1024               /* the part of an answer's body that is read, kept and logged */
#define ANSWER_SHOWN 400              /* of it, in a log line */
#define HEADERS_MAX (64u << 10)       /* an answer's header lines at most (InfluxDB sends < 1 KiB) */
#define RING_WRAP 0xffffffffu         /* record header: the rest of the ring is unused */

/* ------------------------------------------------------------- pure parts ---- */

vd_influx_http_verdict vd_influx_http_verdict_of(long status) {
    if (status >= 200 && status < 300) return VD_IH_WRITTEN;
    if (status == 413) return VD_IH_SPLIT;
    /* credentials, permissions and a missing database can be fixed on the server while vibidd
     * keeps the lines; 408 and 429 ask for a later try */
    if (status == 401 || status == 403 || status == 404 || status == 408 || status == 429) return VD_IH_RETRY;
    if (status >= 400 && status < 500) return VD_IH_REJECTED;
    return VD_IH_RETRY; /* no answer, 5xx, and what a write API never answers (1xx, 3xx) */
}

/* RFC 3986: everything but the unreserved characters percent-encoded */
static int put_query_value(char *buf, size_t cap, size_t *off, const char *v) {
    static const char hex[] = "0123456789ABCDEF";
    for (const unsigned char *p = (const unsigned char *)v; *p; p++) {
        bool plain = (*p >= 'A' && *p <= 'Z') || (*p >= 'a' && *p <= 'z') || (*p >= '0' && *p <= '9') ||
                     *p == '-' || *p == '.' || *p == '_' || *p == '~';
        if (*off + (plain ? 1 : 3) >= cap) return -1;
        if (plain) {
            buf[(*off)++] = (char)*p;
        } else {
            buf[(*off)++] = '%';
            buf[(*off)++] = hex[*p >> 4];
            buf[(*off)++] = hex[*p & 15];
        }
    }
    buf[*off] = '\0';
    return 0;
}

static int put_text(char *buf, size_t cap, size_t *off, const char *s) {
    size_t n = strlen(s);
    if (*off + n >= cap) return -1;
    memcpy(buf + *off, s, n + 1);
    *off += n;
    return 0;
}

int vd_influx_http_write_url(char *buf, size_t cap, const vd_config *cfg) {
    size_t off = 0;
    if (cap == 0) return -1;
    buf[0] = '\0';
    if (cfg->influx_http.api == 2) {
        if (put_text(buf, cap, &off, cfg->influx_http.url) || put_text(buf, cap, &off, "/api/v2/write?org=") ||
            put_query_value(buf, cap, &off, cfg->influx_http.org) || put_text(buf, cap, &off, "&bucket=") ||
            put_query_value(buf, cap, &off, cfg->influx_http.bucket))
            return -1;
    } else {
        if (put_text(buf, cap, &off, cfg->influx_http.url) || put_text(buf, cap, &off, "/write?db=") ||
            put_query_value(buf, cap, &off, cfg->influx_http.database))
            return -1;
        if (cfg->influx_http.rp[0] &&
            (put_text(buf, cap, &off, "&rp=") || put_query_value(buf, cap, &off, cfg->influx_http.rp)))
            return -1;
    }
    if (put_text(buf, cap, &off, "&precision=ns")) return -1;
    return (int)off;
}

/* ----------------------------------------------------------------- module ---- */

/* The ring: records of an 8-byte header (the line's length; RING_WRAP: skip to the ring's
 * start) and the line, padded to 8 bytes. head and tail are byte offsets that only grow
 * (position = offset % cap). One producer (the estimation thread), one consumer (the writer
 * thread). */
typedef struct rec_hdr {
    uint32_t len;
    uint32_t unused;
} rec_hdr;

struct vd_influx_http {
    const vd_config *cfg;
    char stand[64];
    char url[1024];
    char secret[512];    /* the password (v1) or the token (v2) */
    char auth_header[600];
    CURL *curl;
    struct curl_slist *headers;
    bool global_init;
    /* the ring */
    char *ring;
    size_t cap;
    _Atomic size_t head, tail;
    _Atomic uint64_t lines_in, lines_out; /* lines produced / freed */
    /* estimation thread only */
    char fmt[16384 + 64];
    uint64_t pending_drop; /* lines dropped since the last one that got in */
    bool drop_episode;
    uint64_t episode_drops;
    /* wake-up and stop */
    int efd;
    _Atomic int sleeping, stop;
    _Atomic int64_t deadline_ns; /* drain: an unfinished request is aborted after this */
    pthread_t thread;
    bool started;
    /* writer thread */
    char *body;            /* one request's lines */
    size_t body_cap;
    char answer[ANSWER_MAX];
    size_t answer_len;
    bool answer_cut;       /* the body went on past ANSWER_MAX: the rest was not read */
    size_t header_bytes;   /* of the current answer */
    char answer_line[ANSWER_SHOWN + 64];
    char curl_error[CURL_ERROR_SIZE];
    unsigned batch_limit;  /* lines per request (halved by a 413) */
    char last_logged[700];
    double last_log_t;
    bool failing;          /* since the last request that was written */
    uint64_t failed_since; /* requests failed since then */
    /* counters (writer writes, estimation and main thread read) */
    _Atomic uint64_t written, requests, failures, rejected, dropped;
    _Atomic int ok;
};

static void wake(vd_influx_http *h) {
    atomic_thread_fence(memory_order_seq_cst);
    if (atomic_load_explicit(&h->sleeping, memory_order_relaxed)) {
        uint64_t one = 1;
        ssize_t w = write(h->efd, &one, sizeof one);
        (void)w;
    }
}

static size_t rec_size(size_t len) {
    return sizeof(rec_hdr) + ((len + 7) & ~(size_t)7);
}

/* The estimation thread: the line buf[0..n) (ending in '\n') into the ring, or dropped and
 * counted when it does not fit. */
static void push_line(vd_influx_http *h, char *buf, int n) {
    if (n < 0) { /* cannot happen: fmt holds the longest line writers.c formats */
        atomic_fetch_add(&h->dropped, 1);
        return;
    }
    if (h->pending_drop) {
        char f[48];
        snprintf(f, sizeof f, "dropped_before=%llui", (unsigned long long)h->pending_drop);
        n = vd_influx_add_fields(buf, sizeof h->fmt - 1, n, f);
        if (n < 0) {
            atomic_fetch_add(&h->dropped, 1);
            return;
        }
        buf[n++] = '\n';
    }
    size_t need = rec_size((size_t)n);
    size_t head = atomic_load_explicit(&h->head, memory_order_relaxed);
    size_t tail = atomic_load_explicit(&h->tail, memory_order_acquire);
    size_t pos = head % h->cap, skip = h->cap - pos < need ? h->cap - pos : 0;
    if (h->cap - (head - tail) < skip + need) {
        h->pending_drop++;
        h->episode_drops++;
        atomic_fetch_add(&h->dropped, 1);
        if (!h->drop_episode) {
            h->drop_episode = true;
            vd_warning("influx http: the buffer is full (%zu KiB, %llu lines the server has not taken): dropping "
                       "lines until it takes them again (counted in influx_http_dropped; the next line carries "
                       "dropped_before)",
                       h->cap / 1024,
                       (unsigned long long)(atomic_load(&h->lines_in) - atomic_load(&h->lines_out)));
        }
        return;
    }
    if (skip) {
        ((rec_hdr *)(h->ring + pos))->len = RING_WRAP;
        head += skip;
        pos = 0;
    }
    rec_hdr *r = (rec_hdr *)(h->ring + pos);
    r->len = (uint32_t)n;
    memcpy(r + 1, buf, (size_t)n);
    h->pending_drop = 0;
    if (h->drop_episode) {
        h->drop_episode = false;
        vd_notice("influx http: the buffer takes lines again; %llu were dropped", (unsigned long long)h->episode_drops);
        h->episode_drops = 0;
    }
    atomic_store_explicit(&h->head, head + need, memory_order_release);
    uint64_t in = atomic_fetch_add(&h->lines_in, 1) + 1;
    /* a full batch wakes the writer at once; a smaller one waits for batch_interval (the
     * writer's own timer), so a busy stand makes no system call per line */
    if (in - atomic_load(&h->lines_out) >= h->cfg->influx_http.batch_lines) wake(h);
}

static void op_row(void *p, const vd_row *row) {
    vd_influx_http *h = p;
    push_line(h, h->fmt, vd_format_influx_row(h->fmt, sizeof h->fmt - 1, h->cfg, h->stand, row));
}

static void op_alarm(void *p, const vd_output_alarm *a) {
    vd_influx_http *h = p;
    push_line(h, h->fmt, vd_format_influx_alarm(h->fmt, sizeof h->fmt - 1, h->cfg, h->stand, a));
}

static void op_counters(void *p, vd_snapshot *s) {
    vd_influx_http *h = p;
    vd_snapshot_add(s, "influx_http_ok", "vibid_influx_http_ok", NULL,
                    "1 while the last InfluxDB write request was answered 2xx.", true,
                    atomic_load(&h->ok) != 0 ? 1.0 : 0.0);
    vd_snapshot_add(s, "influx_http_written", "vibid_influx_http_written_lines_total", NULL,
                    "Lines InfluxDB accepted.", false, (double)atomic_load(&h->written));
    vd_snapshot_add(s, "influx_http_requests", "vibid_influx_http_requests_total", NULL,
                    "InfluxDB write requests answered 2xx.", false, (double)atomic_load(&h->requests));
    vd_snapshot_add(s, "influx_http_failures", "vibid_influx_http_failures_total", NULL,
                    "InfluxDB write requests that failed and are retried (no answer, 401, 403, 404, 408, 429, 5xx).",
                    false, (double)atomic_load(&h->failures));
    vd_snapshot_add(s, "influx_http_rejected", "vibid_influx_http_rejected_lines_total", NULL,
                    "Lines InfluxDB refused for good (400, 422: e.g. a field type conflict); not sent again.", false,
                    (double)atomic_load(&h->rejected));
    vd_snapshot_add(s, "influx_http_dropped", "vibid_influx_http_dropped_lines_total", NULL,
                    "Lines dropped because the buffer was full.", false, (double)atomic_load(&h->dropped));
    vd_snapshot_add(s, "influx_http_waiting", "vibid_influx_http_waiting_lines", NULL,
                    "Lines in the buffer, not yet written.", true,
                    (double)(atomic_load(&h->lines_in) - atomic_load(&h->lines_out)));
    vd_snapshot_add(s, "influx_http_buffer_fill", "vibid_influx_http_buffer_fill_bytes", NULL,
                    "Bytes of the buffer in use.", true, (double)(atomic_load(&h->head) - atomic_load(&h->tail)));
    vd_snapshot_add(s, "influx_http_buffer_capacity", "vibid_influx_http_buffer_capacity_bytes", NULL,
                    "Bytes the buffer holds (outputs.influx.http.buffer_size).", true, (double)h->cap);
}

/* --------------------------------------------------------- writer thread ---- */

/* The oldest up to max_lines lines (and BATCH_BYTES_MAX bytes) into h->body: their count,
 * *bytes, and *end, the tail after them. */
static unsigned take_batch(vd_influx_http *h, unsigned max_lines, size_t *bytes, size_t *end) {
    size_t t = atomic_load_explicit(&h->tail, memory_order_relaxed);
    const size_t head = atomic_load_explicit(&h->head, memory_order_acquire);
    unsigned n = 0;
    size_t b = 0;
    while (t != head && n < max_lines) {
        size_t pos = t % h->cap;
        const rec_hdr *r = (const rec_hdr *)(h->ring + pos);
        if (r->len == RING_WRAP) {
            t += h->cap - pos;
            continue;
        }
        if (b + r->len > h->body_cap) break;
        memcpy(h->body + b, r + 1, r->len);
        b += r->len;
        t += rec_size(r->len);
        n++;
    }
    *bytes = b;
    *end = t;
    return n;
}

/* curl's body callback. Reads are bounded: the first ANSWER_MAX - 1 bytes are kept (an
 * InfluxDB error is a short JSON object), and once more arrives the transfer is ended
 * (returning less than was handed over makes curl stop with CURLE_WRITE_ERROR and close the
 * connection) instead of reading on: a server streaming a body of 1 GB cost a core for as
 * long as it streamed, and the answer's status line is all the writer needs. */
static size_t on_answer(char *data, size_t size, size_t nmemb, void *obj) {
    vd_influx_http *h = obj;
    size_t n = size * nmemb, room = sizeof h->answer - 1 - h->answer_len;
    memcpy(h->answer + h->answer_len, data, n < room ? n : room);
    h->answer_len += n < room ? n : room;
    h->answer[h->answer_len] = '\0';
    if (n > room) {
        h->answer_cut = true;
        return 0;
    }
    return n;
}

/* curl's header callback: the same bound for the header lines (curl limits one line to
 * 100 KiB, not their number) */
static size_t on_header(char *data, size_t size, size_t nmemb, void *obj) {
    (void)data;
    vd_influx_http *h = obj;
    size_t n = size * nmemb;
    h->header_bytes += n;
    if (h->header_bytes > HEADERS_MAX) {
        snprintf(h->curl_error, sizeof h->curl_error, "the answer's headers are longer than %u KiB: not read on",
                 HEADERS_MAX >> 10);
        return 0;
    }
    return n;
}

/* curl's progress callback: aborts a request that runs past the drain deadline */
static int on_progress(void *obj, curl_off_t a, curl_off_t b, curl_off_t c, curl_off_t d) {
    (void)a, (void)b, (void)c, (void)d;
    vd_influx_http *h = obj;
    return atomic_load(&h->stop) && vd_mono_ns() > atomic_load(&h->deadline_ns);
}

/* The server's answer as one printable line */
static const char *answer_text(vd_influx_http *h) {
    size_t n = h->answer_len;
    while (n && (h->answer[n - 1] == '\n' || h->answer[n - 1] == '\r' || h->answer[n - 1] == ' ')) n--;
    h->answer[n] = '\0';
    for (size_t i = 0; i < n; i++)
        if ((unsigned char)h->answer[i] < 0x20 || (unsigned char)h->answer[i] == 0x7f) h->answer[i] = ' ';
    /* a log line shows the first ANSWER_SHOWN bytes (an InfluxDB error is ~150) */
    const int shown = n > ANSWER_SHOWN ? ANSWER_SHOWN : (int)n;
    snprintf(h->answer_line, sizeof h->answer_line, "%.*s%s", n ? shown : 12, n ? h->answer : "(no message)",
             h->answer_cut ? " [... the rest of the answer was not read]" : (int)n > shown ? " [...]" : "");
    return h->answer_line;
}

/* One POST of h->body[0..bytes): the HTTP status, or 0 with h->curl_error when no answer
 * came (connection, time-out, TLS, abort). *retry_after: the server's Retry-After in s, or 0. */
static long post(vd_influx_http *h, size_t bytes, double *retry_after) {
    h->answer_len = 0;
    h->answer[0] = '\0';
    h->answer_cut = false;
    h->header_bytes = 0;
    h->curl_error[0] = '\0';
    *retry_after = 0;
    curl_easy_setopt(h->curl, CURLOPT_POSTFIELDS, h->body);
    curl_easy_setopt(h->curl, CURLOPT_POSTFIELDSIZE_LARGE, (curl_off_t)bytes);
    CURLcode rc = curl_easy_perform(h->curl);
    if (rc == CURLE_WRITE_ERROR && h->answer_cut) {
        /* the body was cut by on_answer: the status line and headers came; curl has closed
         * the connection, the next request opens a new one */
        rc = CURLE_OK;
        h->curl_error[0] = '\0';
    }
    if (rc != CURLE_OK) {
        if (!h->curl_error[0]) snprintf(h->curl_error, sizeof h->curl_error, "%s", curl_easy_strerror(rc));
        return 0;
    }
    long status = 0;
    curl_easy_getinfo(h->curl, CURLINFO_RESPONSE_CODE, &status);
    curl_off_t ra = 0;
    if (curl_easy_getinfo(h->curl, CURLINFO_RETRY_AFTER, &ra) == CURLE_OK && ra > 0) *retry_after = (double)ra;
    return status;
}

/* A failure: logged when its reason differs from the last one logged or RELOG_S passed
 * (the back-off grows to 30 s, so a long outage logs twice a minute at most) */
static void log_failure(vd_influx_http *h, bool error_level, const char *reason, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
static void log_failure(vd_influx_http *h, bool error_level, const char *reason, const char *fmt, ...) {
    double now = vd_mono_s();
    if (!strncmp(reason, h->last_logged, sizeof h->last_logged - 1) && now - h->last_log_t <= RELOG_S) return;
    char line[CURL_ERROR_SIZE + ANSWER_MAX + 400];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(line, sizeof line, fmt, ap);
    va_end(ap);
    if (error_level)
        vd_error("influx http: %s", line);
    else
        vd_warning("influx http: %s", line);
    snprintf(h->last_logged, sizeof h->last_logged, "%s", reason);
    h->last_log_t = now;
}

static void sleep_on_efd(vd_influx_http *h, double seconds) {
    if (seconds <= 0) return;
    struct pollfd p = {.fd = h->efd, .events = POLLIN};
    atomic_store(&h->sleeping, 1);
    atomic_thread_fence(memory_order_seq_cst);
    if (!atomic_load(&h->stop) || atomic_load(&h->lines_in) != atomic_load(&h->lines_out)) {
        int ms = (int)ceil(fmin(seconds, 1.0) * 1000.0);
        if (poll(&p, 1, ms) > 0 && (p.revents & POLLIN)) {
            uint64_t v;
            ssize_t r = read(h->efd, &v, sizeof v);
            (void)r;
        }
    }
    atomic_store(&h->sleeping, 0);
}

static void *writer_main(void *arg) {
    vd_influx_http *h = arg;
    const vd_config *cfg = h->cfg;
    double backoff = BACKOFF_FIRST_S, next_try = 0, oldest_t = 0;
    bool stopping = false, no_retry = false;
    for (;;) {
        double now = vd_mono_s();
        if (!stopping && atomic_load(&h->stop)) stopping = true;
        uint64_t waiting = atomic_load(&h->lines_in) - atomic_load(&h->lines_out);
        if (stopping && (waiting == 0 || vd_mono_ns() >= atomic_load(&h->deadline_ns))) break;
        if (stopping && next_try > 1e-9 * (double)atomic_load(&h->deadline_ns)) {
            /* the back-off (or the server's Retry-After) puts the next request after the
             * deadline: nothing more can be written, so waiting for the deadline gains nothing */
            no_retry = true;
            break;
        }
        if (waiting == 0) {
            oldest_t = 0;
            sleep_on_efd(h, 1.0);
            continue;
        }
        if (oldest_t == 0) oldest_t = now;
        /* a batch goes when it is full, when its oldest line waited batch_interval, or at the end;
         * never before the back-off of a failure is over (also while draining) */
        double due = (waiting >= h->batch_limit || stopping) ? now : oldest_t + cfg->influx_http.batch_interval_s;
        if (next_try > due) due = next_try;
        if (due > now) {
            double until_deadline = stopping ? 1e-9 * (double)(atomic_load(&h->deadline_ns) - vd_mono_ns()) : 1.0;
            sleep_on_efd(h, fmin(due - now, fmax(until_deadline, 0.001)));
            continue;
        }
        size_t bytes, end;
        unsigned n = take_batch(h, h->batch_limit, &bytes, &end);
        if (n == 0) continue; /* a wrap record only: taken next round */
        double retry_after;
        long status = post(h, bytes, &retry_after);
        vd_influx_http_verdict v = vd_influx_http_verdict_of(status);
        if (v == VD_IH_SPLIT && n == 1) v = VD_IH_REJECTED; /* one line the server will never take */
        now = vd_mono_s();
        switch (v) {
        case VD_IH_WRITTEN:
        case VD_IH_REJECTED:
            if (v == VD_IH_WRITTEN) {
                atomic_fetch_add(&h->written, n);
                atomic_fetch_add(&h->requests, 1);
                atomic_store(&h->ok, 1);
                if (h->failing)
                    vd_notice("influx http: written again after %llu failed requests (%s)",
                              (unsigned long long)h->failed_since, h->url);
                else if (atomic_load(&h->requests) == 1)
                    vd_notice("influx http: the first %u lines written to %s", n, h->url);
                h->failing = false;
                h->failed_since = 0;
                h->last_logged[0] = '\0';
            } else {
                uint64_t r = atomic_fetch_add(&h->rejected, n) + n;
                const char *why = answer_text(h);
                log_failure(h, true, why,
                            "%s refused %u lines for good (HTTP %ld: %s); they are not sent again (%llu rejected "
                            "so far)",
                            h->url, n, status, why, (unsigned long long)r);
            }
            atomic_store_explicit(&h->tail, end, memory_order_release);
            atomic_fetch_add(&h->lines_out, n);
            backoff = BACKOFF_FIRST_S;
            next_try = 0;
            break;
        case VD_IH_SPLIT:
            h->batch_limit = n / 2;
            vd_warning("influx http: %s refused a request of %u lines (%zu bytes) as too large (HTTP 413); "
                       "sending at most %u lines per request from now on",
                       h->url, n, bytes, h->batch_limit);
            break;
        case VD_IH_RETRY: {
            atomic_fetch_add(&h->failures, 1);
            atomic_store(&h->ok, 0);
            h->failing = true;
            h->failed_since++;
            double wait = fmin(fmax(backoff, retry_after), BACKOFF_MAX_S);
            char why[CURL_ERROR_SIZE + ANSWER_MAX + 64];
            if (status == 0)
                snprintf(why, sizeof why, "no answer: %s", h->curl_error);
            else if (status == 401 || status == 403)
                snprintf(why, sizeof why, "HTTP %ld, the credentials are refused (username and password_file, or "
                         "token_file): %s", status, answer_text(h));
            else
                snprintf(why, sizeof why, "HTTP %ld: %s", status, answer_text(h));
            log_failure(h, status == 401 || status == 403 || status == 404, why,
                        "writing to %s failed (%s); %llu lines kept, retrying in %.1f s (back-off doubling to "
                        "%.0f s)",
                        h->url, why, (unsigned long long)waiting, wait, BACKOFF_MAX_S);
            next_try = now + wait;
            backoff = fmin(backoff * 2.0, BACKOFF_MAX_S);
            break;
        }
        }
    }
    uint64_t left = atomic_load(&h->lines_in) - atomic_load(&h->lines_out);
    atomic_store(&h->ok, 0);
    if (left)
        vd_warning("influx http: stopped with %llu lines not written to %s (%s; drain_timeout %g s)",
                   (unsigned long long)left, h->url,
                   no_retry ? "the server did not take them, and its next try was due after the deadline"
                   : h->failing ? "the server did not take them"
                                : "time ran out",
                   cfg->influx_http.drain_timeout_s);
    else
        vd_info("influx http: every line written (%llu in %llu requests)", (unsigned long long)atomic_load(&h->written),
                (unsigned long long)atomic_load(&h->requests));
    return NULL;
}

/* ------------------------------------------------------------ life cycle ---- */

static int read_secret(const vd_config *cfg, char *out, size_t cap, char *err, size_t ecap) {
    out[0] = '\0';
    if (cfg->influx_http.api == 2)
        return vd_read_secret_file("outputs.influx.http.token_file", cfg->influx_http.token_file, out, cap, err, ecap);
    if (cfg->influx_http.password_file[0])
        return vd_read_secret_file("outputs.influx.http.password_file", cfg->influx_http.password_file, out, cap, err,
                                   ecap);
    return 0;
}

int vd_influx_http_check(const vd_config *cfg, char *note, size_t note_cap, char *err, size_t cap) {
    (void)note;
    (void)note_cap;
    if (!cfg->influx_http.url[0]) return 0;
    char s[512];
    int rc = read_secret(cfg, s, sizeof s, err, cap);
    memset(s, 0, sizeof s);
    return rc ? -1 : vd_check_readable_file("outputs.influx.http.ca_file", cfg->influx_http.ca_file, err, cap);
}

static void op_close(void *p);

static void *op_open(const vd_output_ctx *ctx, char *err, size_t cap) {
    const vd_config *cfg = ctx->cfg;
    const char *stand = ctx->stand;
    vd_influx_http *h = calloc(1, sizeof *h);
    if (!h) {
        snprintf(err, cap, "out of memory");
        return NULL;
    }
    h->cfg = cfg;
    h->efd = -1;
    h->batch_limit = cfg->influx_http.batch_lines;
    snprintf(h->stand, sizeof h->stand, "%s", stand);
    if (vd_influx_http_write_url(h->url, sizeof h->url, cfg) < 0) {
        snprintf(err, cap, "outputs.influx.http: the write URL is longer than %zu bytes", sizeof h->url - 1);
        goto fail;
    }
    h->cap = (size_t)cfg->influx_http.buffer_mib << 20;
    h->ring = malloc(h->cap);
    h->body_cap = h->cap < BATCH_BYTES_MAX ? h->cap : BATCH_BYTES_MAX;
    h->body = malloc(h->body_cap);
    if (!h->ring || !h->body) {
        snprintf(err, cap, "outputs.influx.http.buffer_size %u MiB: out of memory", cfg->influx_http.buffer_mib);
        goto fail;
    }
    h->efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    if (h->efd < 0) {
        snprintf(err, cap, "eventfd: %s", strerror(errno));
        goto fail;
    }
    if (read_secret(cfg, h->secret, sizeof h->secret, err, cap)) goto fail;
    if (curl_global_init(CURL_GLOBAL_DEFAULT) != CURLE_OK) {
        snprintf(err, cap, "outputs.influx.http: libcurl cannot be initialised");
        goto fail;
    }
    h->global_init = true;
    h->curl = curl_easy_init();
    if (!h->curl) {
        snprintf(err, cap, "outputs.influx.http: curl_easy_init failed");
        goto fail;
    }
    h->headers = curl_slist_append(NULL, "Content-Type: text/plain; charset=utf-8");
    /* no "Expect: 100-continue" round trip before a large body */
    if (h->headers) h->headers = curl_slist_append(h->headers, "Expect:");
    if (h->headers && cfg->influx_http.api == 2) {
        snprintf(h->auth_header, sizeof h->auth_header, "Authorization: Token %s", h->secret);
        h->headers = curl_slist_append(h->headers, h->auth_header);
        memset(h->auth_header, 0, sizeof h->auth_header); /* curl keeps its own copy */
    }
    if (!h->headers) {
        snprintf(err, cap, "out of memory");
        goto fail;
    }
    CURL *c = h->curl;
    CURLcode rc = curl_easy_setopt(c, CURLOPT_URL, h->url);
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_PROTOCOLS_STR, "http,https");
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_HTTPHEADER, h->headers);
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_POST, 1L);
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_USERAGENT, "vibidd");
    /* threads: no SIGALRM for name resolution time-outs */
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_NOSIGNAL, 1L);
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_TIMEOUT_MS, (long)(cfg->influx_http.timeout_s * 1000.0));
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_CONNECTTIMEOUT_MS, (long)(fmin(cfg->influx_http.timeout_s, 5.0) * 1000.0));
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_TCP_KEEPALIVE, 1L);
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_ERRORBUFFER, h->curl_error);
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, on_answer);
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_WRITEDATA, h);
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_HEADERFUNCTION, on_header);
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_HEADERDATA, h);
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_XFERINFOFUNCTION, on_progress);
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_XFERINFODATA, h);
    if (!rc) rc = curl_easy_setopt(c, CURLOPT_NOPROGRESS, 0L);
    if (!rc && cfg->influx_http.api == 1 && cfg->influx_http.username[0]) {
        rc = curl_easy_setopt(c, CURLOPT_HTTPAUTH, (long)CURLAUTH_BASIC);
        if (!rc) rc = curl_easy_setopt(c, CURLOPT_USERNAME, cfg->influx_http.username);
        if (!rc) rc = curl_easy_setopt(c, CURLOPT_PASSWORD, h->secret);
    }
    if (!rc && cfg->influx_http.ca_file[0]) rc = curl_easy_setopt(c, CURLOPT_CAINFO, cfg->influx_http.ca_file);
    if (rc) {
        snprintf(err, cap, "outputs.influx.http: setting up libcurl: %s", curl_easy_strerror(rc));
        goto fail;
    }
    vd_info("influx http: %s (API v%d%s), batches of up to %u lines every %g s, buffer %u MiB",
            h->url, cfg->influx_http.api,
            cfg->influx_http.api == 2 ? ", token" : cfg->influx_http.username[0] ? ", basic authentication" : "",
            cfg->influx_http.batch_lines, cfg->influx_http.batch_interval_s, cfg->influx_http.buffer_mib);
    return h;
fail:
    op_close(h);
    return NULL;
}

static int op_start(void *p, char *err, size_t cap) {
    vd_influx_http *h = p;
    int rc = pthread_create(&h->thread, NULL, writer_main, h);
    if (rc) {
        snprintf(err, cap, "cannot start the InfluxDB writer thread: %s", strerror(rc));
        return -1;
    }
    h->started = true;
    return 0;
}

static void op_drain(void *p) {
    vd_influx_http *h = p;
    if (!h || !h->started) return;
    atomic_store(&h->deadline_ns, vd_mono_ns() + (int64_t)(h->cfg->influx_http.drain_timeout_s * 1e9));
    atomic_store(&h->stop, 1);
    atomic_store(&h->sleeping, 1);
    wake(h);
    pthread_join(h->thread, NULL);
    h->started = false;
}

static void op_close(void *p) {
    vd_influx_http *h = p;
    if (!h) return;
    op_drain(h);
    if (h->curl) curl_easy_cleanup(h->curl);
    curl_slist_free_all(h->headers);
    if (h->global_init) curl_global_cleanup();
    if (h->efd >= 0) close(h->efd);
    memset(h->secret, 0, sizeof h->secret);
    free(h->ring);
    free(h->body);
    free(h);
}

const vd_output_ops vd_influx_http_curl = {
    .name = "influx.http",
    .groups = vd_influx_http_groups,
    .load = vd_influx_http_load,
    .print = vd_influx_http_print,
    .enabled = vd_influx_http_enabled,
    .check = vd_influx_http_check,
    .open = op_open,
    .start = op_start,
    .row = op_row,
    .alarm = op_alarm,
    .counters = op_counters,
    .drain = op_drain,
    .close = op_close,
};
