/* mqtt.c: see mqtt.h. */

#include "mqtt.h"

#include "clock.h"
#include "log.h"
#include "textbuf.h"
#include "writers.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <mosquitto.h>
#include <poll.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#define BACKOFF_FIRST_S 0.5
#define BACKOFF_MAX_S 30.0
#define RELOG_S 60.0 /* a repeated failure is logged again at most this often */
/* A connection attempt's CONNACK must come within this (from the attempt's start: TCP, TLS and
 * CONNECT together). A broker answers CONNECT at once (mosquitto: about a millisecond on a
 * LAN; TLS and a password check add round trips, not seconds); without this bound a peer
 * that never answers was only given up by libmosquitto's keep-alive check, after 30 s and as
 * "Unknown error.". */
#define CONNECT_TIMEOUT_S 5.0

/* How the last connection attempt failed, for the drain (pub_main): only a failure that can
 * heal within seconds (the broker down or restarting, a lost connection) is retried while
 * draining; a broker that refused vibidd (credentials, client id), TLS that failed, or a peer
 * that did not answer CONNECT will not change before the deadline. */
typedef enum fail_kind { FAIL_NONE = 0, FAIL_NET, FAIL_REFUSED, FAIL_TLS, FAIL_SILENT } fail_kind;

/* ------------------------------------------------------------ formatting ---- */

static void put_str(vd_text *o, const char *s) {
    vd_text_put(o, "\"");
    for (const unsigned char *p = (const unsigned char *)s; *p && !o->full; p++) {
        if (*p == '"' || *p == '\\')
            vd_text_put(o, "\\%c", *p);
        else if (*p < 0x20)
            vd_text_put(o, "\\u%04x", *p);
        else
            vd_text_put(o, "%c", *p);
    }
    vd_text_put(o, "\"");
}

int vd_mqtt_json_string(char *buf, size_t cap, const char *s) {
    vd_text o = {buf, cap, 0, cap == 0};
    put_str(&o, s);
    return o.full ? -1 : (int)o.off;
}

/* a number as the tracks CSV writes it; NaN and infinities are not JSON: null */
static void put_num(vd_text *o, double v) {
    if (isfinite(v))
        vd_text_put(o, "%.10g", v);
    else
        vd_text_put(o, "null");
}

static void put_time(vd_text *o, int64_t t_us) {
    const char *sign = "";
    uint64_t a = (uint64_t)t_us;
    if (t_us < 0) {
        sign = "-";
        a = (uint64_t)(-(t_us + 1)) + 1u;
    }
    vd_text_put(o, "%s%llu.%06llu", sign, (unsigned long long)(a / 1000000u), (unsigned long long)(a % 1000000u));
}

static void put_header(vd_text *o, const vd_config *cfg, const char *stand, uint64_t seq) {
    vd_text_put(o, "{\"stand\":");
    put_str(o, stand);
    vd_text_put(o, ",\"site\":");
    put_str(o, cfg->mqtt.site);
    vd_text_put(o, ",\"seq\":%llu", (unsigned long long)seq);
}

int vd_mqtt_format_track(char *buf, size_t cap, const vd_config *cfg, const char *stand, uint64_t seq,
                         uint64_t dropped_before, const vd_row *row) {
    vd_text o = {buf, cap, 0, cap == 0};
    put_header(&o, cfg, stand, seq);
    vd_text_put(&o, ",\"index\":%llu,\"time_s\":", (unsigned long long)row->index);
    put_time(&o, row->t_us);
    vd_text_put(&o, ",\"params\":{");
    for (size_t k = 0; k < cfg->n_params; k++) {
        if (k) vd_text_put(&o, ",");
        put_str(&o, vd_param_name(cfg, k));
        vd_text_put(&o, ":{\"value\":");
        put_num(&o, row->theta[k]);
        vd_text_put(&o, ",\"se\":");
        put_num(&o, row->se[k]);
        if (vd_change_columns(cfg, k)) { /* the change test's, null before its reference */
            vd_text_put(&o, ",\"change_statistic\":");
            put_num(&o, row->change_stat[k]);
            vd_text_put(&o, ",\"mdc\":");
            put_num(&o, row->change_mdc[k]);
        }
        vd_text_put(&o, "}");
    }
    vd_text_put(&o, "},\"modes\":[");
    for (size_t i = 0; i < cfg->n_modes; i++) {
        vd_text_put(&o, "%s{\"f_hz\":", i ? "," : "");
        put_num(&o, row->freq[i]);
        vd_text_put(&o, ",\"f_hz_se\":");
        put_num(&o, row->freq_se[i]);
        vd_text_put(&o, ",\"zeta\":");
        put_num(&o, row->zeta[i]);
        vd_text_put(&o, ",\"zeta_se\":");
        put_num(&o, row->zeta_se[i]);
        vd_text_put(&o, "}");
    }
    vd_text_put(&o, "]");
    if (cfg->n_covariates) {
        vd_text_put(&o, ",\"covariates\":{");
        for (size_t j = 0; j < cfg->n_covariates; j++) {
            if (j) vd_text_put(&o, ",");
            put_str(&o, cfg->chanmap.ch[cfg->cov_chan[j]].name);
            vd_text_put(&o, ":");
            put_num(&o, row->cov[j]);
        }
        vd_text_put(&o, "}");
    }
    char fl[VD_FLAG_LETTERS_MAX];
    vd_flag_letters(row->flags, fl);
    vd_text_put(&o, ",\"gap_samples\":%llu,\"flags\":\"%s\",\"dropped_before\":%llu}",
        (unsigned long long)row->gap_samples, fl, (unsigned long long)dropped_before);
    return o.full ? -1 : (int)o.off;
}

int vd_mqtt_format_alarm(char *buf, size_t cap, const vd_config *cfg, const char *stand, uint64_t seq,
                         uint64_t dropped_before, const vd_output_alarm *a) {
    vd_text o = {buf, cap, 0, cap == 0};
    put_header(&o, cfg, stand, seq);
    vd_text_put(&o, ",\"index\":%llu,\"time_s\":", (unsigned long long)a->row->index);
    put_time(&o, a->row->t_us);
    vd_text_put(&o, ",\"parameter\":");
    put_str(&o, a->param);
    vd_text_put(&o, ",\"state\":\"%s\",\"test\":\"%s\",\"onset_index\":%llu", a->raised ? "raised" : "cleared",
                a->test, (unsigned long long)a->onset_index);
    static const char *const names[] = {"value", "baseline", "z", "statistic", "threshold", "change", "change_se"};
    const double values[] = {a->value, a->baseline, a->z, a->statistic, a->threshold, a->change, a->change_se};
    for (size_t i = 0; i < sizeof values / sizeof values[0]; i++) {
        vd_text_put(&o, ",\"%s\":", names[i]);
        put_num(&o, values[i]);
    }
    vd_text_put(&o, ",\"dropped_before\":%llu}", (unsigned long long)dropped_before);
    return o.full ? -1 : (int)o.off;
}

/* RFC 8259's number: -? (0 | [1-9][0-9]*) (. [0-9]+)? ([eE] [+-]? [0-9]+)? */
static bool is_json_number(const char *s, size_t n) {
    size_t i = 0;
    if (i < n && s[i] == '-') i++;
    if (i >= n) return false;
    if (s[i] == '0')
        i++;
    else if (s[i] >= '1' && s[i] <= '9')
        while (i < n && s[i] >= '0' && s[i] <= '9') i++;
    else
        return false;
    if (i < n && s[i] == '.') {
        size_t d = ++i;
        while (i < n && s[i] >= '0' && s[i] <= '9') i++;
        if (i == d) return false;
    }
    if (i < n && (s[i] == 'e' || s[i] == 'E')) {
        i++;
        if (i < n && (s[i] == '+' || s[i] == '-')) i++;
        size_t d = i;
        while (i < n && s[i] >= '0' && s[i] <= '9') i++;
        if (i == d) return false;
    }
    return i == n;
}

static bool is_nonfinite_word(const char *s, size_t n) {
    if (n && (*s == '-' || *s == '+')) s++, n--;
    return (n == 3 && (!strncasecmp(s, "nan", 3) || !strncasecmp(s, "inf", 3))) ||
           (n == 8 && !strncasecmp(s, "infinity", 8));
}

int vd_mqtt_format_status(char *buf, size_t cap, const vd_config *cfg, const char *stand, uint64_t seq,
                          const char *text, size_t len) {
    vd_text o = {buf, cap, 0, cap == 0};
    put_header(&o, cfg, stand, seq);
    /* the index of the latest row, for the schema's common header */
    const char *li = NULL;
    size_t lin = 0;
    for (size_t p = 0; p < len;) {
        const char *line = text + p, *nl = memchr(line, '\n', len - p);
        size_t ll = nl ? (size_t)(nl - line) : len - p;
        if (ll > 11 && !strncmp(line, "last_index=", 11)) {
            li = line + 11;
            lin = ll - 11;
        }
        p += ll + 1;
    }
    if (li && is_json_number(li, lin))
        vd_text_put(&o, ",\"index\":%.*s", (int)lin, li);
    else
        vd_text_put(&o, ",\"index\":null");
    char key[256], val[1024];
    for (size_t p = 0; p < len && !o.full;) {
        const char *line = text + p, *nl = memchr(line, '\n', len - p);
        size_t ll = nl ? (size_t)(nl - line) : len - p;
        p += ll + 1;
        const char *eq = memchr(line, '=', ll);
        if (!eq || eq == line) continue;
        size_t kl = (size_t)(eq - line), vl = ll - kl - 1;
        if (kl >= sizeof key || vl >= sizeof val) continue;
        memcpy(key, line, kl);
        key[kl] = '\0';
        memcpy(val, eq + 1, vl);
        val[vl] = '\0';
        if (!strcmp(key, "stand")) continue; /* in the header (the topic's stand name) */
        vd_text_put(&o, ",");
        put_str(&o, key);
        vd_text_put(&o, ":");
        if (is_json_number(val, vl))
            vd_text_put(&o, "%s", val);
        else if (is_nonfinite_word(val, vl))
            vd_text_put(&o, "null");
        else
            put_str(&o, val);
    }
    vd_text_put(&o, "}");
    return o.full ? -1 : (int)o.off;
}

/* format "line": the InfluxDB line of writers.c with seq and dropped_before added */
static int splice_seq(char *buf, size_t cap, int n, uint64_t seq, uint64_t dropped) {
    char ins[80];
    snprintf(ins, sizeof ins, "seq=%llui,dropped_before=%llui", (unsigned long long)seq, (unsigned long long)dropped);
    return vd_influx_add_fields(buf, cap, n, ins);
}

/* ----------------------------------------------------------------- module ---- */

typedef struct slot_hdr {
    uint32_t len;
    uint16_t kind;  /* VD_MQTT_TRACKS or VD_MQTT_ALARMS */
    uint16_t param; /* alarms: the parameter (its topic) */
} slot_hdr;

struct vd_mqtt {
    const vd_config *cfg;
    char stand[64];
    char client_id[160];
    char topic_tracks[400], topic_status[400];
    char (*topic_alarm)[400]; /* n_params */
    char password[512];
    struct mosquitto *mosq;
    bool lib_init;
    /* the queue: n_slots slots of stride bytes (slot_hdr + payload) */
    char *slots;
    size_t n_slots, stride, payload_max;
    _Atomic size_t head, tail; /* produced (estimation thread), consumed (publisher) */
    /* estimation thread only */
    uint64_t seq[2], pending_drop[2];
    bool drop_episode;
    uint64_t episode_drops;
    char fmt[VD_MQTT_STATUS_MAX];
    /* status hand-over */
    pthread_mutex_t st_mu;
    char *st_text; /* VD_MQTT_STATUS_MAX */
    size_t st_len;
    bool st_new;
    /* wake-up and stop */
    int efd;
    _Atomic int sleeping, stop;
    pthread_t thread;
    bool started;
    /* publisher thread */
    char *st_local; /* the latest status text the publisher has */
    size_t st_local_len;
    char *st_json;
    uint64_t status_seq;
    bool sock_active; /* a connection attempt or a connection */
    bool connected_local, just_connected, ever_connected;
    bool final_will; /* the drain's last connection: its will is the final status (see pub_main) */
    bool final_up;   /* that connection was made */
    double attempt_t;    /* when the current attempt began (vd_mono_s) */
    fail_kind last_fail; /* of the last failed attempt or lost connection; FAIL_NONE once connected */
    int refused_rc;      /* CONNACK reason of the current attempt (0 = none) */
    char lib_error[300]; /* the last error libmosquitto logged (OpenSSL's reasons) */
    char last_logged[600];
    double last_log_t;
    /* counters (publisher writes, estimation thread reads) */
    _Atomic uint64_t published, refused, reconnects, connect_failures, dropped, inflight, errors;
    _Atomic uint64_t unsent; /* at the end of the drain: queued or unacknowledged messages left */
    _Atomic int connected;
};

static void wake(vd_mqtt *m) {
    atomic_thread_fence(memory_order_seq_cst);
    if (atomic_load_explicit(&m->sleeping, memory_order_relaxed)) {
        uint64_t one = 1;
        ssize_t w = write(m->efd, &one, sizeof one);
        (void)w;
    }
}

static slot_hdr *slot_at(vd_mqtt *m, size_t i) {
    return (slot_hdr *)(m->slots + (i % m->n_slots) * m->stride);
}

/* The estimation thread: a free slot, or NULL (the message is dropped and counted). */
static slot_hdr *claim(vd_mqtt *m, int kind) {
    size_t head = atomic_load_explicit(&m->head, memory_order_relaxed);
    size_t tail = atomic_load_explicit(&m->tail, memory_order_acquire);
    if (head - tail < m->n_slots) return slot_at(m, head);
    m->pending_drop[kind]++;
    atomic_fetch_add(&m->dropped, 1);
    m->episode_drops++;
    if (!m->drop_episode) {
        m->drop_episode = true;
        vd_warning(
            "mqtt: the queue is full (%zu messages, %llu waiting for the broker's acknowledgement): dropping "
            "messages until the broker takes them again (counted in mqtt_dropped; the next message carries "
            "dropped_before)",
            m->n_slots, (unsigned long long)atomic_load(&m->inflight));
    }
    return NULL;
}

static void commit(vd_mqtt *m, slot_hdr *s, int kind, uint16_t param, int n) {
    if (n < 0) { /* cannot happen: the slots fit the longest message (vd_mqtt open) */
        atomic_fetch_add(&m->errors, 1);
        return;
    }
    s->len = (uint32_t)n;
    s->kind = (uint16_t)kind;
    s->param = param;
    m->pending_drop[kind] = 0;
    if (m->drop_episode) {
        m->drop_episode = false;
        vd_notice("mqtt: the queue takes messages again; %llu were dropped",
                  (unsigned long long)m->episode_drops);
        m->episode_drops = 0;
    }
    atomic_store_explicit(&m->head, atomic_load_explicit(&m->head, memory_order_relaxed) + 1,
                          memory_order_release);
    wake(m);
}

static int format_track(vd_mqtt *m, char *buf, size_t cap, uint64_t seq, uint64_t dropped,
                        const vd_row *row) {
    if (m->cfg->mqtt.format == 0) return vd_mqtt_format_track(buf, cap, m->cfg, m->stand, seq, dropped, row);
    int n = vd_format_influx_row(buf, cap, m->cfg, m->stand, row);
    return n < 0 ? -1 : splice_seq(buf, cap, n, seq, dropped);
}

static int format_alarm(vd_mqtt *m, char *buf, size_t cap, uint64_t seq, uint64_t dropped, const vd_output_alarm *a) {
    if (m->cfg->mqtt.format == 0) return vd_mqtt_format_alarm(buf, cap, m->cfg, m->stand, seq, dropped, a);
    int n = vd_format_influx_alarm(buf, cap, m->cfg, m->stand, a);
    return n < 0 ? -1 : splice_seq(buf, cap, n, seq, dropped);
}

static void op_track(void *p, const vd_row *row) {
    vd_mqtt *m = p;
    uint64_t seq = ++m->seq[VD_MQTT_TRACKS];
    slot_hdr *s = claim(m, VD_MQTT_TRACKS);
    if (!s) return;
    int n = format_track(m, (char *)(s + 1), m->payload_max, seq, m->pending_drop[VD_MQTT_TRACKS], row);
    commit(m, s, VD_MQTT_TRACKS, 0, n);
}

static void op_alarm(void *p, const vd_output_alarm *a) {
    vd_mqtt *m = p;
    uint64_t seq = ++m->seq[VD_MQTT_ALARMS];
    uint16_t k = 0;
    for (size_t i = 0; i < m->cfg->n_params; i++)
        if (!strcmp(vd_param_name(m->cfg, i), a->param)) k = (uint16_t)i;
    slot_hdr *s = claim(m, VD_MQTT_ALARMS);
    if (!s) return;
    int n = format_alarm(m, (char *)(s + 1), m->payload_max, seq, m->pending_drop[VD_MQTT_ALARMS], a);
    commit(m, s, VD_MQTT_ALARMS, k, n);
}

static bool op_status(void *p, const vd_snapshot *snap, const char *text, size_t len, bool wait) {
    (void)snap; /* the status file's text is what is published */
    vd_mqtt *m = p;
    if (len >= VD_MQTT_STATUS_MAX) len = VD_MQTT_STATUS_MAX - 1;
    if (wait ? pthread_mutex_lock(&m->st_mu) != 0 : pthread_mutex_trylock(&m->st_mu) != 0) return false;
    memcpy(m->st_text, text, len);
    m->st_len = len;
    m->st_new = true;
    pthread_mutex_unlock(&m->st_mu);
    atomic_store(&m->sleeping, 1); /* a status is rare: always wake the publisher */
    wake(m);
    return true;
}

static void op_counters(void *p, vd_snapshot *s) {
    vd_mqtt *m = p;
    vd_snapshot_add(s, "mqtt_connected", "vibid_mqtt_connected", NULL, "1 while connected to the MQTT broker.", true,
                    atomic_load(&m->connected) != 0 ? 1.0 : 0.0);
    vd_snapshot_add(s, "mqtt_published", "vibid_mqtt_published_total", NULL,
                    "MQTT messages acknowledged by the broker.", false, (double)atomic_load(&m->published));
    vd_snapshot_add(s, "mqtt_refused", "vibid_mqtt_refused_total", NULL,
                    "MQTT messages the broker refused (MQTT 5 reason codes, e.g. an ACL; always 0 with MQTT 3.1.1).",
                    false, (double)atomic_load(&m->refused));
    vd_snapshot_add(s, "mqtt_dropped", "vibid_mqtt_dropped_total", NULL,
                    "MQTT messages dropped because the queue was full.", false, (double)atomic_load(&m->dropped));
    vd_snapshot_add(s, "mqtt_queue_fill", "vibid_mqtt_queue_fill", NULL,
                    "MQTT messages waiting in the queue for the broker.", true,
                    (double)(atomic_load(&m->head) - atomic_load(&m->tail)));
    vd_snapshot_add(s, "mqtt_queue_capacity", "vibid_mqtt_queue_capacity", NULL,
                    "MQTT messages the queue holds (outputs.mqtt.queue_size).", true, (double)m->n_slots);
    vd_snapshot_add(s, "mqtt_inflight", "vibid_mqtt_inflight", NULL,
                    "MQTT messages sent and not yet acknowledged (resent after a reconnection).", true,
                    (double)atomic_load(&m->inflight));
    vd_snapshot_add(s, "mqtt_reconnects", "vibid_mqtt_reconnects_total", NULL, "MQTT connections after the first one.",
                    false, (double)atomic_load(&m->reconnects));
    vd_snapshot_add(s, "mqtt_connect_failures", "vibid_mqtt_connect_failures_total", NULL,
                    "Failed MQTT connection attempts (unreachable, TLS, refused by the broker, CONNECT unanswered).",
                    false, (double)atomic_load(&m->connect_failures));
    vd_snapshot_add(s, "mqtt_unsent", "vibid_mqtt_unsent_total", NULL,
                    "MQTT messages not acknowledged by the broker when vibidd stopped (queued or sent; 0 until the "
                    "end).",
                    false, (double)atomic_load(&m->unsent));
}

/* ------------------------------------------------------ publisher thread ---- */

static const char *url_of(const vd_mqtt *m) {
    return m->cfg->mqtt.url;
}

static void on_log(struct mosquitto *mosq, void *obj, int level, const char *str) {
    (void)mosq;
    vd_mqtt *m = obj;
    size_t n = strlen(m->lib_error);
    if ((level & MOSQ_LOG_ERR) && n + 3 < sizeof m->lib_error)
        snprintf(m->lib_error + n, sizeof m->lib_error - n, "%s%s", n ? "; " : "", str);
}

static const char *reason_text(int rc) {
    /* CONNACK codes of MQTT 3.1.1 are 1..5; MQTT 5 reason codes are >= 128 */
    return rc < 128 ? mosquitto_connack_string(rc) : mosquitto_reason_string(rc);
}

static void on_connect(struct mosquitto *mosq, void *obj, int rc, int flags,
                       const mosquitto_property *props) {
    (void)mosq, (void)flags, (void)props;
    vd_mqtt *m = obj;
    if (rc != 0) {
        m->refused_rc = rc;
        return;
    }
    m->connected_local = true;
    m->just_connected = true;
    m->last_fail = FAIL_NONE;
    atomic_store(&m->connected, 1);
    if (m->ever_connected && !m->final_will) atomic_fetch_add(&m->reconnects, 1);
    if (m->final_will) m->final_up = true;
}

static void on_publish(struct mosquitto *mosq, void *obj, int mid, int reason,
                       const mosquitto_property *props) {
    (void)mosq, (void)props;
    vd_mqtt *m = obj;
    if (atomic_load(&m->inflight) > 0) atomic_fetch_sub(&m->inflight, 1);
    if (reason >= 128) {
        /* MQTT 5 only: the broker refused the message (an ACL: "not authorized"). MQTT 3.1.1
         * acknowledges a refused message like any other: nothing to see there. */
        uint64_t n = atomic_fetch_add(&m->refused, 1) + 1;
        if (n == 1 || n % 1000 == 0)
            vd_warning(
                "mqtt: the broker refused a message (mid %d): %s (%llu refused so far; an ACL that does not "
                "allow this client to publish under %s/%s/%s/?)",
                mid, mosquitto_reason_string(reason), (unsigned long long)n, m->cfg->mqtt.prefix,
                m->cfg->mqtt.site, m->stand);
    } else {
        atomic_fetch_add(&m->published, 1);
    }
}

/* One failed attempt or a lost connection: logged when the reason differs from the last
 * one logged or RELOG_S passed, counted, the next attempt after the back-off. */
static void failed(vd_mqtt *m, bool was_connected, const char *why, double *backoff, double *next_try) {
    double now = vd_mono_s();
    char line[600];
    if (was_connected)
        snprintf(line, sizeof line, "connection to %s lost: %s", url_of(m), why);
    else
        snprintf(line, sizeof line, "cannot connect to %s: %s", url_of(m), why);
    if (!was_connected) atomic_fetch_add(&m->connect_failures, 1);
    if (was_connected || strcmp(line, m->last_logged) || now - m->last_log_t > RELOG_S) {
        vd_warning(
            "mqtt: %s; retrying in %.1f s (back-off doubling to %.0f s; %llu messages queued, %llu waiting "
            "for an acknowledgement, resent after reconnecting)",
            line, *backoff, BACKOFF_MAX_S,
            (unsigned long long)(atomic_load(&m->head) - atomic_load(&m->tail)),
            (unsigned long long)atomic_load(&m->inflight));
        snprintf(m->last_logged, sizeof m->last_logged, "%s", line);
        m->last_log_t = now;
    }
    *next_try = now + *backoff;
    *backoff = fmin(*backoff * 2.0, BACKOFF_MAX_S);
}

static const char *why_of(vd_mqtt *m, int rc, int err, char *buf, size_t cap) {
    if (m->refused_rc) /* MOSQ_ERR_CONN_REFUSED, or MOSQ_ERR_PROTOCOL for MQTT 5's reason codes */
        snprintf(buf, cap, "the broker refused the connection: %s", reason_text(m->refused_rc));
    else if (rc == MOSQ_ERR_ERRNO)
        snprintf(buf, cap, "%s", err ? strerror(err) : "a system call failed");
    else if (m->lib_error[0])
        snprintf(buf, cap, "%s (%s)", mosquitto_strerror(rc), m->lib_error);
    else
        snprintf(buf, cap, "%s", mosquitto_strerror(rc));
    return buf;
}

/* the latest status, retained; a minimal one before the first snapshot */
static void publish_status(vd_mqtt *m) {
    int n;
    uint64_t seq = ++m->status_seq;
    if (m->st_local_len)
        n = vd_mqtt_format_status(m->st_json, VD_MQTT_STATUS_MAX * 2, m->cfg, m->stand, seq, m->st_local,
                                  m->st_local_len);
    else
        n = vd_mqtt_format_status(m->st_json, VD_MQTT_STATUS_MAX * 2, m->cfg, m->stand, seq,
                                  "state=running\n", 14);
    if (n < 0) return;
    int rc = mosquitto_publish(m->mosq, NULL, m->topic_status, n, m->st_json, m->cfg->mqtt.qos, true);
    if (rc == MOSQ_ERR_SUCCESS || rc == MOSQ_ERR_NO_CONN || rc == MOSQ_ERR_CONN_LOST || rc == MOSQ_ERR_ERRNO)
        atomic_fetch_add(&m->inflight, 1);
}

/* mosquitto_publish's errors before the message was queued inside libmosquitto; any other
 * error comes after (the connection), and the message is resent after reconnecting */
static bool refused_locally(int rc) {
    return rc == MOSQ_ERR_INVAL || rc == MOSQ_ERR_NOMEM || rc == MOSQ_ERR_PAYLOAD_SIZE ||
           rc == MOSQ_ERR_MALFORMED_UTF8 || rc == MOSQ_ERR_OVERSIZE_PACKET ||
           rc == MOSQ_ERR_QOS_NOT_SUPPORTED || rc == MOSQ_ERR_NOT_SUPPORTED;
}

static void publish_pending(vd_mqtt *m) {
    if (m->just_connected) {
        m->just_connected = false;
        if (!m->final_will)
            vd_notice("mqtt: connected to %s as '%s'%s; publishing under %s/%s/%s/", url_of(m), m->client_id,
                  m->ever_connected ? " again" : "", m->cfg->mqtt.prefix, m->cfg->mqtt.site, m->stand);
        m->ever_connected = true;
        m->last_logged[0] = '\0';
        pthread_mutex_lock(&m->st_mu); /* the publisher may wait: the estimation thread only trylocks */
        if (m->st_new) {
            memcpy(m->st_local, m->st_text, m->st_len);
            m->st_local_len = m->st_len;
            m->st_new = false;
        }
        pthread_mutex_unlock(&m->st_mu);
        publish_status(m); /* "running" over the will's "offline" */
    }
    pthread_mutex_lock(&m->st_mu);
    bool fresh = m->st_new;
    if (fresh) {
        memcpy(m->st_local, m->st_text, m->st_len);
        m->st_local_len = m->st_len;
        m->st_new = false;
    }
    pthread_mutex_unlock(&m->st_mu);
    if (fresh) publish_status(m);
    while (atomic_load(&m->inflight) < VD_MQTT_WINDOW) {
        size_t tail = atomic_load_explicit(&m->tail, memory_order_relaxed);
        size_t head = atomic_load_explicit(&m->head, memory_order_acquire);
        if (tail == head) break;
        slot_hdr *s = slot_at(m, tail);
        const char *topic = s->kind == VD_MQTT_TRACKS ? m->topic_tracks : m->topic_alarm[s->param];
        int rc = mosquitto_publish(m->mosq, NULL, topic, (int)s->len, s + 1, m->cfg->mqtt.qos,
                                   s->kind == VD_MQTT_ALARMS);
        if (refused_locally(rc)) {
            uint64_t e = atomic_fetch_add(&m->errors, 1) + 1;
            if (e == 1 || e % 1000 == 0)
                vd_error("mqtt: a message to %s could not be published: %s (%llu so far; dropped)", topic,
                         mosquitto_strerror(rc), (unsigned long long)e);
            atomic_fetch_add(&m->dropped, 1);
        } else {
            atomic_fetch_add(&m->inflight, 1);
        }
        atomic_store_explicit(&m->tail, tail + 1, memory_order_release);
        if (rc != MOSQ_ERR_SUCCESS && !refused_locally(rc))
            break; /* the connection: mosquitto_loop reports it */
    }
}

static bool idle(vd_mqtt *m) {
    pthread_mutex_lock(&m->st_mu);
    bool st = m->st_new;
    pthread_mutex_unlock(&m->st_mu);
    return !st && atomic_load(&m->head) == atomic_load(&m->tail) && atomic_load(&m->inflight) == 0;
}

/* A CONNACK that did not come within CONNECT_TIMEOUT_S: why, as precisely as the socket tells */
static const char *silent_reason(vd_mqtt *m, char *buf, size_t cap) {
    struct sockaddr_storage peer;
    socklen_t len = sizeof peer;
    int sock = mosquitto_socket(m->mosq);
    if (sock >= 0 && getpeername(sock, (struct sockaddr *)&peer, &len) != 0 && errno == ENOTCONN)
        snprintf(buf, cap, "no TCP connection within %.0f s (the host does not answer: down, or its packets are "
                 "dropped)", CONNECT_TIMEOUT_S);
    else
        snprintf(buf, cap, "the peer accepted the connection but did not answer CONNECT within %.0f s (not an MQTT "
                 "broker? %s)", CONNECT_TIMEOUT_S,
                 m->cfg->mqtt.tls ? "a listener without TLS for mqtts://?" : "a TLS listener for mqtt://?");
    return buf;
}

/* The failure of rc (from connecting or mosquitto_loop) as the drain sees it (fail_kind) */
static fail_kind kind_of(const vd_mqtt *m, int rc) {
    if (m->refused_rc) return FAIL_REFUSED;
    if (rc == MOSQ_ERR_TLS || strstr(m->lib_error, "SSL")) return FAIL_TLS; /* OpenSSL's reason was logged */
    return FAIL_NET;
}

/* Sends DISCONNECT (a clean end: the broker drops the will). true once it is written to the
 * socket; false when the connection broke first, so that the broker publishes the will and the
 * final status must be published again on a new connection. */
static bool disconnect_cleanly(vd_mqtt *m) {
    if (mosquitto_disconnect(m->mosq) != MOSQ_ERR_SUCCESS) return false;
    for (int i = 0; i < 10 && mosquitto_want_write(m->mosq); i++)
        if (mosquitto_loop(m->mosq, 10, 1) != MOSQ_ERR_SUCCESS) break;
    if (mosquitto_want_write(m->mosq)) return false;
    for (int i = 0; i < 5; i++) /* the broker closes the connection after DISCONNECT */
        if (mosquitto_loop(m->mosq, 10, 1) != MOSQ_ERR_SUCCESS) break;
    return true;
}

/* The final status (the latest the daemon gave) as the will of the next connection; false
 * when it cannot be set (then the drain ends as before, on a connection whose will is
 * "offline") */
static bool set_final_will(vd_mqtt *m) {
    if (!m->st_local_len) return false;
    int n = vd_mqtt_format_status(m->st_json, VD_MQTT_STATUS_MAX * 2, m->cfg, m->stand, m->status_seq + 1,
                                  m->st_local, m->st_local_len);
    if (n < 0 || mosquitto_will_set(m->mosq, m->topic_status, n, m->st_json, m->cfg->mqtt.qos, true) !=
                     MOSQ_ERR_SUCCESS)
        return false;
    m->final_will = true;
    return true;
}

static void lost(vd_mqtt *m, int rc, int e, double *backoff, double *next_try) {
    bool was = m->connected_local;
    char why[400];
    why_of(m, rc, e, why, sizeof why);
    /* a connection that was up and broke can come back (OpenSSL may log why it broke: not a
     * TLS failure); an attempt that failed is judged by its reason */
    m->last_fail = was ? FAIL_NET : kind_of(m, rc);
    m->sock_active = false;
    m->connected_local = false;
    atomic_store(&m->connected, 0);
    if (was) *backoff = BACKOFF_FIRST_S;
    failed(m, was, why, backoff, next_try);
    m->lib_error[0] = '\0';
}

/* The publisher thread. The drain (after stop): publishes what is queued and the final status
 * and ends with a clean DISCONNECT, for at most drain_timeout. While disconnected it goes on
 * connecting (the back-off as before) as long as an attempt can begin before the deadline and
 * the last failure can heal (the broker down or restarting, a lost connection: FAIL_NET); every
 * lost connection let the broker publish the will ("offline"), so the drain reconnects even
 * with nothing queued, to put the final status over it; and it ends on a last connection
 * whose will is the final status (set_final_will). It ends at once when nothing more can
 * be sent: the next attempt is due after the deadline, or the broker refused vibidd, TLS
 * failed or the peer did not answer CONNECT (those do not heal within seconds). What is left
 * is counted (unsent) and logged. */
static void *pub_main(void *arg) {
    vd_mqtt *m = arg;
    double backoff = BACKOFF_FIRST_S, next_try = 0, drain_until = 0;
    bool stopping = false, first = true, clean = false;
    const char *why_end = NULL; /* why the drain ended before a clean DISCONNECT */
    for (;;) {
        double now = vd_mono_s();
        if (!stopping && atomic_load(&m->stop)) {
            stopping = true;
            drain_until = now + m->cfg->mqtt.drain_timeout_s;
        }
        if (m->sock_active && !m->connected_local && now - m->attempt_t >= CONNECT_TIMEOUT_S) {
            /* the socket stays open until the next attempt (mosquitto_reconnect_async closes it) */
            char why[400];
            m->sock_active = false;
            m->last_fail = FAIL_SILENT;
            failed(m, false, silent_reason(m, why, sizeof why), &backoff, &next_try);
        }
        if (stopping) {
            if (m->connected_local && idle(m)) {
                if (!m->final_will && set_final_will(m)) {
                    /* this connection's will says "offline", and DISCONNECT is never
                     * acknowledged: a cut between the final status and DISCONNECT (a proxy, a
                     * flaky link; e2e_mqtt flaps met it) lets the broker put "offline" over
                     * "stopped". So the last connection carries the final status as its will:
                     * however it ends, the retained status is the final one. It costs one more
                     * connection at each stop, not counted as a reconnection. */
                    disconnect_cleanly(m);
                    m->sock_active = m->connected_local = false;
                    atomic_store(&m->connected, 0);
                    next_try = now;
                    continue;
                }
                if ((clean = disconnect_cleanly(m))) break;
                lost(m, MOSQ_ERR_CONN_LOST, 0, &backoff, &next_try); /* the will is out: again */
                continue;
            }
            if (now >= drain_until) {
                why_end = m->connected_local ? "the broker was too slow" : "not connected";
                break;
            }
            if (!m->connected_local && m->last_fail != FAIL_NONE && m->last_fail != FAIL_NET) {
                why_end = m->last_fail == FAIL_REFUSED ? "the broker refuses the connection"
                          : m->last_fail == FAIL_TLS   ? "TLS fails"
                                                       : "the broker does not answer CONNECT";
                break;
            }
            if (!m->sock_active && next_try >= drain_until) {
                why_end = "not connected, and the next connection attempt is due after drain_timeout";
                break;
            }
        }
        if (!m->sock_active && now >= next_try) {
            m->lib_error[0] = '\0';
            m->refused_rc = 0;
            errno = 0;
            int rc = first ? mosquitto_connect_async(m->mosq, m->cfg->mqtt.host, m->cfg->mqtt.port,
                                                     m->cfg->mqtt.keepalive)
                           : mosquitto_reconnect_async(m->mosq);
            int e = errno;
            if (rc == MOSQ_ERR_SUCCESS) {
                m->sock_active = true;
                m->attempt_t = now;
                first = false;
            } else {
                char why[400];
                m->last_fail = kind_of(m, rc);
                failed(m, false, why_of(m, rc, e, why, sizeof why), &backoff, &next_try);
                if (rc != MOSQ_ERR_EAI && rc != MOSQ_ERR_ERRNO && rc != MOSQ_ERR_TLS) first = false;
            }
        }
        if (m->connected_local) publish_pending(m);
        struct pollfd p[2] = {{.fd = m->efd, .events = POLLIN}, {.fd = -1}};
        int np = 1;
        int sock = m->sock_active ? mosquitto_socket(m->mosq) : -1;
        if (sock >= 0) {
            p[1].fd = sock;
            p[1].events = (short)(POLLIN | (mosquitto_want_write(m->mosq) ? POLLOUT : 0));
            np = 2;
        }
        int timeout = 100; /* keepalive, back-off, CONNACK and drain deadlines are checked at least this often */
        if (!m->sock_active && next_try > now)
            timeout = (int)fmin(100.0, ceil((next_try - now) * 1000.0));
        atomic_store(&m->sleeping, 1);
        atomic_thread_fence(memory_order_seq_cst);
        if ((atomic_load(&m->stop) && !stopping) ||
            (m->connected_local && atomic_load(&m->inflight) < VD_MQTT_WINDOW &&
             atomic_load(&m->head) != atomic_load(&m->tail)))
            timeout = 0;
        if (poll(p, (nfds_t)np, timeout) > 0 && (p[0].revents & POLLIN)) {
            uint64_t v;
            ssize_t r = read(m->efd, &v, sizeof v);
            (void)r;
        }
        atomic_store(&m->sleeping, 0);
        if (m->sock_active) {
            errno = 0;
            int rc = mosquitto_loop(m->mosq, 0, 1);
            int e = errno;
            if (rc != MOSQ_ERR_SUCCESS)
                lost(m, rc, e, &backoff, &next_try);
            else if (m->connected_local)
                backoff = BACKOFF_FIRST_S;
        }
    }
    if (m->connected_local && !clean) clean = disconnect_cleanly(m); /* drain_timeout while connected */
    size_t left = atomic_load(&m->head) - atomic_load(&m->tail);
    uint64_t unacked = atomic_load(&m->inflight);
    atomic_store(&m->unsent, left + unacked);
    atomic_store(&m->connected, 0);
    if (left || unacked || !clean)
        vd_warning("mqtt: stopped with %zu messages unsent and %llu unacknowledged (%s; drain_timeout %g s)%s",
                   left, (unsigned long long)unacked, why_end ? why_end : "disconnected", m->cfg->mqtt.drain_timeout_s,
                   clean || !m->ever_connected || m->final_up ? ""
                                                                 : "; the broker has published the will (offline), not the final status");
    else
        vd_info("mqtt: every message acknowledged by the broker (%llu), disconnected",
                (unsigned long long)atomic_load(&m->published));
    return NULL;
}

/* ------------------------------------------------------------ life cycle ---- */

int vd_mqtt_check(const vd_config *cfg, char *note, size_t note_cap, char *err, size_t cap) {
    (void)note;
    (void)note_cap;
    if (!cfg->mqtt.url[0]) return 0;
    char pw[512];
    if (cfg->mqtt.password_file[0] &&
        vd_read_secret_file("outputs.mqtt.password_file", cfg->mqtt.password_file, pw, sizeof pw, err, cap))
        return -1;
    memset(pw, 0, sizeof pw);
    return vd_check_readable_file("outputs.mqtt.ca_file", cfg->mqtt.ca_file, err, cap) ||
                   vd_check_readable_file("outputs.mqtt.cert_file", cfg->mqtt.cert_file, err, cap) ||
                   vd_check_readable_file("outputs.mqtt.key_file", cfg->mqtt.key_file, err, cap)
               ? -1
               : 0;
}

static void op_close(void *p);

static void *op_open(const vd_output_ctx *ctx, char *err, size_t cap) {
    const vd_config *cfg = ctx->cfg;
    vd_mqtt *m = calloc(1, sizeof *m);
    if (!m) {
        snprintf(err, cap, "out of memory");
        return NULL;
    }
    m->cfg = cfg;
    m->efd = -1;
    pthread_mutex_init(&m->st_mu, NULL);
    snprintf(m->stand, sizeof m->stand, "%s",
             cfg->mqtt.stand[0] ? cfg->mqtt.stand : vd_stand_name(cfg));
    if (cfg->mqtt.client_id[0])
        snprintf(m->client_id, sizeof m->client_id, "%s", cfg->mqtt.client_id);
    else
        snprintf(m->client_id, sizeof m->client_id, "vibidd-%s-%s", cfg->mqtt.site, m->stand);
    snprintf(m->topic_tracks, sizeof m->topic_tracks, "%s/%s/%s/tracks", cfg->mqtt.prefix, cfg->mqtt.site,
             m->stand);
    snprintf(m->topic_status, sizeof m->topic_status, "%s/%s/%s/status", cfg->mqtt.prefix, cfg->mqtt.site,
             m->stand);
    m->topic_alarm = calloc(cfg->n_params ? cfg->n_params : 1, sizeof *m->topic_alarm);
    m->st_text = malloc(VD_MQTT_STATUS_MAX);
    m->st_local = malloc(VD_MQTT_STATUS_MAX);
    m->st_json = malloc(VD_MQTT_STATUS_MAX * 2);
    if (!m->topic_alarm || !m->st_text || !m->st_local || !m->st_json) {
        snprintf(err, cap, "out of memory");
        goto fail;
    }
    size_t longest_name = 0;
    for (size_t k = 0; k < cfg->n_params; k++) {
        const char *pname = vd_param_name(cfg, k);
        snprintf(m->topic_alarm[k], sizeof m->topic_alarm[k], "%s/%s/%s/alarms/%s", cfg->mqtt.prefix,
                 cfg->mqtt.site, m->stand, pname);
        if (strlen(pname) > longest_name) longest_name = strlen(pname);
        if (mosquitto_pub_topic_check(m->topic_alarm[k]) != MOSQ_ERR_SUCCESS) {
            snprintf(err, cap, "outputs.mqtt: '%s' is not a valid MQTT topic (the parameter's name)",
                     m->topic_alarm[k]);
            goto fail;
        }
    }
    if (mosquitto_pub_topic_check(m->topic_tracks) != MOSQ_ERR_SUCCESS ||
        mosquitto_validate_utf8(m->topic_tracks, (int)strlen(m->topic_tracks)) != MOSQ_ERR_SUCCESS) {
        snprintf(err, cap, "outputs.mqtt: '%s' is not a valid MQTT topic (UTF-8 without wildcards)",
                 m->topic_tracks);
        goto fail;
    }
    /* the slots: as long as the longest message this stand can produce (every number at its
     * longest, every counter at 2^64 - 1, every flag) */
    {
        vd_row w;
        memset(&w, 0, sizeof w);
        w.t_us = INT64_MIN;
        w.index = UINT64_MAX;
        w.gap_samples = UINT64_MAX;
        w.flags = 0x1ffu;
        for (size_t k = 0; k < VD_MAX_PARAMS; k++)
            w.theta[k] = w.se[k] = w.freq[k] = w.freq_se[k] = w.zeta[k] = w.zeta_se[k] = w.change_stat[k] =
                w.change_mdc[k] = -2.225073859e-308;
        for (size_t j = 0; j < VD_MAX_COVARIATES; j++)
            w.cov[j] = -2.225073859e-308;
        char pname[256];
        if (longest_name > sizeof pname - 1) longest_name = sizeof pname - 1;
        memset(pname, '"', longest_name); /* escaped: twice as long */
        pname[longest_name] = '\0';
        static char probe[1 << 20];
        int a = format_track(m, probe, sizeof probe, UINT64_MAX, UINT64_MAX, &w);
        const double x = -2.225073859e-308; /* the longest %.17g */
        const vd_output_alarm probe_alarm = {pname, 0, &w, "threshold", x, x, x, x, x, x, x, UINT64_MAX};
        int b = format_alarm(m, probe, sizeof probe, UINT64_MAX, UINT64_MAX, &probe_alarm);
        if (a < 0 || b < 0) {
            snprintf(err, cap, "outputs.mqtt: the stand's messages do not fit 1 MiB");
            goto fail;
        }
        m->payload_max = (size_t)(a > b ? a : b) + 64;
    }
    m->stride = (sizeof(slot_hdr) + m->payload_max + 7) & ~(size_t)7;
    m->n_slots = cfg->mqtt.queue_size;
    m->slots = calloc(m->n_slots, m->stride);
    if (!m->slots) {
        snprintf(err, cap, "outputs.mqtt.queue_size %zu: out of memory for %zu messages of %zu bytes",
                 m->n_slots, m->n_slots, m->stride);
        goto fail;
    }
    m->efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    if (m->efd < 0) {
        snprintf(err, cap, "eventfd: %s", strerror(errno));
        goto fail;
    }
    if (cfg->mqtt.password_file[0] && vd_read_secret_file("outputs.mqtt.password_file", cfg->mqtt.password_file,
                                                          m->password, sizeof m->password, err, cap))
        goto fail;
    mosquitto_lib_init();
    m->lib_init = true;
    m->mosq = mosquitto_new(m->client_id, true, m);
    if (!m->mosq) {
        snprintf(err, cap, "outputs.mqtt: mosquitto_new: %s", strerror(errno));
        goto fail;
    }
    int rc = mosquitto_int_option(m->mosq, MOSQ_OPT_PROTOCOL_VERSION,
                                  cfg->mqtt.protocol == 5 ? MQTT_PROTOCOL_V5 : MQTT_PROTOCOL_V311);
    /* the last will: the stand offline, retained, until the next status replaces it */
    char will[600];
    size_t wl = 0;
    {
        vd_text o = {will, sizeof will, 0, false};
        vd_text_put(&o, "{\"stand\":");
        put_str(&o, m->stand);
        vd_text_put(&o, ",\"site\":");
        put_str(&o, cfg->mqtt.site);
        vd_text_put(&o, ",\"seq\":null,\"index\":null,\"state\":\"offline\"}");
        wl = o.off;
    }
    if (!rc) rc = mosquitto_will_set(m->mosq, m->topic_status, (int)wl, will, cfg->mqtt.qos, true);
    if (!rc && cfg->mqtt.username[0])
        rc = mosquitto_username_pw_set(m->mosq, cfg->mqtt.username, m->password[0] ? m->password : NULL);
    if (!rc && cfg->mqtt.tls) {
        /* no ca_file: the system's CA store (Debian's ca-certificates) */
        rc = mosquitto_tls_set(m->mosq, cfg->mqtt.ca_file[0] ? cfg->mqtt.ca_file : NULL,
                               cfg->mqtt.ca_file[0] ? NULL : "/etc/ssl/certs",
                               cfg->mqtt.cert_file[0] ? cfg->mqtt.cert_file : NULL,
                               cfg->mqtt.key_file[0] ? cfg->mqtt.key_file : NULL, NULL);
        if (!rc) rc = mosquitto_tls_opts_set(m->mosq, 1 /* SSL_VERIFY_PEER */, NULL, NULL);
    }
    if (rc) {
        snprintf(err, cap, "outputs.mqtt: setting up libmosquitto: %s%s", mosquitto_strerror(rc),
                 cfg->mqtt.tls ? " (are ca_file, cert_file and key_file readable PEM files?)" : "");
        goto fail;
    }
    mosquitto_log_callback_set(m->mosq, on_log);
    mosquitto_connect_v5_callback_set(m->mosq, on_connect);
    mosquitto_publish_v5_callback_set(m->mosq, on_publish);
    vd_info(
        "mqtt: %s as '%s' (MQTT %s, QoS %d, %s), topics %s/%s/%s/{tracks,alarms/<parameter>,status}; queue "
        "of "
        "%zu messages (%zu KiB)",
        cfg->mqtt.url, m->client_id, cfg->mqtt.protocol == 5 ? "5" : "3.1.1", cfg->mqtt.qos,
        cfg->mqtt.format ? "line protocol" : "JSON", cfg->mqtt.prefix, cfg->mqtt.site, m->stand, m->n_slots,
        m->n_slots * m->stride / 1024);
    return m;
fail:
    op_close(m);
    return NULL;
}

static int op_start(void *p, char *err, size_t cap) {
    vd_mqtt *m = p;
    int rc = pthread_create(&m->thread, NULL, pub_main, m);
    if (rc) {
        snprintf(err, cap, "cannot start the MQTT thread: %s", strerror(rc));
        return -1;
    }
    m->started = true;
    return 0;
}

static void op_drain(void *p) {
    vd_mqtt *m = p;
    if (!m || !m->started) return;
    atomic_store(&m->stop, 1);
    atomic_store(&m->sleeping, 1);
    wake(m);
    pthread_join(m->thread, NULL);
    m->started = false;
}

static void op_close(void *p) {
    vd_mqtt *m = p;
    if (!m) return;
    op_drain(m);
    if (m->mosq) mosquitto_destroy(m->mosq);
    if (m->lib_init) mosquitto_lib_cleanup();
    if (m->efd >= 0) close(m->efd);
    memset(m->password, 0, sizeof m->password);
    pthread_mutex_destroy(&m->st_mu);
    free(m->slots);
    free(m->topic_alarm);
    free(m->st_text);
    free(m->st_local);
    free(m->st_json);
    free(m);
}

const vd_output_ops vd_mqtt_libmosquitto = {
    .name = "mqtt",
    .flags = VD_OUTPUT_STATUS_TEXT,
    .groups = vd_mqtt_groups,
    .load = vd_mqtt_load,
    .print = vd_mqtt_print,
    .enabled = vd_mqtt_enabled,
    .check = vd_mqtt_check,
    .open = op_open,
    .start = op_start,
    .row = op_track,
    .alarm = op_alarm,
    .status = op_status,
    .counters = op_counters,
    .drain = op_drain,
    .close = op_close,
};
