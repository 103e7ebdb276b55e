/* metrics.c: see metrics.h. */

#include "metrics.h"
#include "textbuf.h"

#include "estimator.h"
#include "clock.h"
#include "log.h"
#include "output.h"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <time.h>
#include <unistd.h>

#include <vibid/common.h>

const unsigned vd_metrics_lat_bounds_us[VD_METRICS_LAT_BOUNDS] = {10,  20,   50,   100,  200,
                                                                  500, 1000, 2000, 5000, 10000};

const char *vd_refusal_name(vd_refusal r)
{
    static const char *const n[VD_REFUSED_N] = {"bad_request", "not_found", "method_not_allowed",
                                                "too_large",   "timeout",   "evicted"};
    return (unsigned)r < VD_REFUSED_N ? n[r] : "?";
}

/* ------------------------------------------------------------- rendering ---- */

void vd_metrics_format_double(char *buf, size_t cap, double v)
{
    /* the exposition format's spellings (Go's ParseFloat reads them) */
    if (isnan(v))
        snprintf(buf, cap, "NaN");
    else if (isinf(v))
        snprintf(buf, cap, "%s", v > 0 ? "+Inf" : "-Inf");
    else {
        snprintf(buf, cap, "%.15g", v);
        if (strtod(buf, NULL) != v)
            snprintf(buf, cap, "%.17g", v);
    }
}

void vd_metrics_escape_label(char *dst, size_t cap, const char *src)
{
    size_t o = 0;
    for (; *src; src++) {
        const char *e = *src == '\\' ? "\\\\" : *src == '"' ? "\\\"" : *src == '\n' ? "\\n" : NULL;
        size_t n = e ? 2 : 1;
        if (o + n + 1 > cap)
            break;
        if (e) {
            dst[o++] = e[0];
            dst[o++] = e[1];
        } else {
            dst[o++] = *src;
        }
    }
    if (cap)
        dst[o] = '\0';
}

static void family(vd_text *o, const char *name, const char *type, const char *help)
{
    vd_text_put(o, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
}

static void put_double(vd_text *o, double v)
{
    char b[40];
    vd_metrics_format_double(b, sizeof b, v);
    vd_text_put(o, "%s\n", b);
}

/* name{labels} value, labels "" for none (labels are already escaped) */
static void u64(vd_text *o, const char *name, const char *labels, uint64_t v)
{
    vd_text_put(o, "%s%s%s%s %llu\n", name, labels[0] ? "{" : "", labels, labels[0] ? "}" : "", (unsigned long long)v);
}

static void dbl(vd_text *o, const char *name, const char *labels, double v)
{
    vd_text_put(o, "%s%s%s%s ", name, labels[0] ? "{" : "", labels, labels[0] ? "}" : "");
    put_double(o, v);
}

static void counter(vd_text *o, const char *name, const char *help, uint64_t v)
{
    family(o, name, "counter", help);
    u64(o, name, "", v);
}

static void gauge(vd_text *o, const char *name, const char *help, double v)
{
    family(o, name, "gauge", help);
    dbl(o, name, "", v);
}

/* One series per parameter: name{parameter="<p>"} v[k]. */
static void per_param(vd_text *o, const vd_snapshot *s, const char *name, const char *help, const double *v)
{
    family(o, name, "gauge", help);
    for (size_t k = 0; k < s->n_params; k++) {
        char esc[200], lab[220];
        vd_metrics_escape_label(esc, sizeof esc, s->param[k]);
        snprintf(lab, sizeof lab, "parameter=\"%s\"", esc);
        dbl(o, name, lab, v[k]);
    }
}

static void per_mode(vd_text *o, const vd_snapshot *s, const char *name, const char *help, const double *v)
{
    family(o, name, "gauge", help);
    for (size_t i = 0; i < s->n_modes; i++) {
        char lab[32];
        snprintf(lab, sizeof lab, "mode=\"%zu\"", i + 1);
        dbl(o, name, lab, v[i]);
    }
}

void vd_snapshot_add(vd_snapshot *s, const char *key, const char *metric, const char *label, const char *help,
                     bool gauge, double value)
{
    if (s->n_out_counters < VD_OUTPUT_COUNTERS_MAX)
        s->out_counter[s->n_out_counters++] =
            (vd_output_counter){.key = key, .metric = metric, .label = label, .help = help, .gauge = gauge, .value = value};
}

double vd_snapshot_value(const vd_snapshot *s, const char *key)
{
    for (size_t i = 0; i < s->n_out_counters; i++)
        if (s->out_counter[i].key && !strcmp(s->out_counter[i].key, key))
            return s->out_counter[i].value;
    return NAN;
}

size_t vd_snapshot_status_lines(const vd_snapshot *s, char *buf, size_t cap)
{
    size_t off = 0;
    for (size_t i = 0; i < s->n_out_counters; i++) {
        const vd_output_counter *q = &s->out_counter[i];
        if (!q->key)
            continue;
        int n = q->gauge && q->value != floor(q->value)
                    ? snprintf(buf + (off < cap ? off : cap), off < cap ? cap - off : 0, "%s=%.10g\n", q->key, q->value)
                    : snprintf(buf + (off < cap ? off : cap), off < cap ? cap - off : 0, "%s=%llu\n", q->key,
                               (unsigned long long)q->value);
        if (n > 0)
            off += (size_t)n;
    }
    return off;
}

int vd_metrics_render(char *buf, size_t cap, const vd_snapshot *s)
{
    vd_text o = {buf, cap, 0, cap == 0};
    char a[600], b[200], c[200];
    vd_metrics_escape_label(a, 200, s->stand ? s->stand : "");
    vd_metrics_escape_label(b, sizeof b, s->source ? s->source : "");
    vd_metrics_escape_label(c, sizeof c, s->estimator ? s->estimator : "");
    family(&o, "vibid_info", "gauge",
           "Constant 1; the labels name the stand, the source kind, the configured estimator and the version.");
    vd_text_put(&o, "vibid_info{stand=\"%s\",source=\"%s\",estimator=\"%s\",version=\"%s\"} 1\n", a, b, c,
        VIBID_VERSION_STRING);
    gauge(&o, "vibid_running", "1 while vibidd acquires, 0 once it stopped (end of a replay, SIGTERM).",
          s->state && strcmp(s->state, "running") == 0 ? 1.0 : 0.0);
    gauge(&o, "vibid_uptime_seconds", "Seconds since the threads started.", s->uptime_s);
    gauge(&o, "vibid_stand_sample_rate_hertz", "The stand's configured sample rate.", s->stand_rate_hz);
    gauge(&o, "vibid_sample_rate_hertz", "Samples per second estimated over the last status interval.",
          s->rate_hz);
    counter(&o, "vibid_samples_total", "Samples given to the estimator.", s->samples);
    counter(&o, "vibid_gaps_total", "Gaps (runs of missing samples) seen by the estimator.", s->gaps);
    counter(&o, "vibid_missing_samples_total", "Samples missing in those gaps.", s->missing);
    family(&o, "vibid_faults_total", "counter", "Fault records of the source, by kind.");
    for (unsigned k = 1; k <= s->n_fault_kinds && k < 16; k++) {
        vd_metrics_escape_label(b, sizeof b, s->fault_kind[k] ? s->fault_kind[k] : "?");
        snprintf(a, sizeof a, "kind=\"%s\"", b);
        u64(&o, "vibid_faults_total", a, s->faults_by_kind[k]);
    }
    gauge(&o, "vibid_ring_capacity", "Records the ring between acquisition and estimation holds.",
          (double)s->ring_capacity);
    gauge(&o, "vibid_ring_fill", "Records waiting in the ring now.", (double)s->ring_fill);
    gauge(&o, "vibid_ring_high_water", "Most records ever waiting in the ring.", (double)s->ring_high_water);
    counter(&o, "vibid_ring_overflows_total", "Records dropped because the ring was full (live sources).",
            s->ring_overflows);
    counter(&o, "vibid_replay_waits_total", "Times a replay waited for room in the ring (never a drop).",
            s->replay_waits);
    const vibid_source_stats *ss = &s->src;
    counter(&o, "vibid_source_frames_total", "CAN frames received or read.", ss->frames);
    counter(&o, "vibid_source_dropped_frames_total", "CAN frames lost before vibidd (kernel or logger).",
            ss->dropped);
    counter(&o, "vibid_source_error_frames_total", "CAN error frames.", ss->error_frames);
    counter(&o, "vibid_source_bad_lines_total", "Malformed capture lines.", ss->bad_lines);
    counter(&o, "vibid_source_polls_total", "Modbus poll cycles attempted.", ss->polls);
    counter(&o, "vibid_source_failed_polls_total", "Modbus poll cycles with a failed request.", ss->failed_polls);
    counter(&o, "vibid_source_timeouts_total", "Modbus requests without an answer in time.", ss->timeouts);
    counter(&o, "vibid_source_link_losses_total", "Times the Modbus link was declared lost.", ss->link_losses);
    counter(&o, "vibid_source_reconnects_total", "Modbus reconnections after the first connection.",
            ss->reconnects);
    counter(&o, "vibid_source_connect_failures_total", "Failed Modbus connection attempts.", ss->connect_failures);
    counter(&o, "vibid_source_overruns_total", "Modbus snapshot deadlines missed.", ss->overruns);
    counter(&o, "vibid_source_implausible_total", "Modbus FIFO counter changes the elapsed time cannot explain.",
            ss->implausible);
    gauge(&o, "vibid_source_jitter_mean_seconds", "Mean interval between consecutive sample times.",
          ss->jitter.mean_s);
    gauge(&o, "vibid_source_jitter_stddev_seconds", "Standard deviation of the interval between sample times.",
          ss->jitter.std_s);
    counter(&o, "vibid_rows_total", "Track rows (decimated estimates) written.", s->rows);
    counter(&o, "vibid_estimate_failures_total", "Rows whose estimate failed (flag E after the start).",
            s->est_errors);
    counter(&o, "vibid_implausible_rows_total", "Rows with a physically impossible estimate (flag P).",
            s->implausible_rows);
    counter(&o, "vibid_nonfinite_samples_total", "Samples refused by the estimator (a non-finite value).",
            s->nonfinite_samples);
    counter(&o, "vibid_outlier_samples_total",
            "Samples with a single-sample glitch taken out before the estimator (flag O).", s->outlier_samples);
    if (s->oma_on) {
        counter(&o, "vibid_oma_identifications_total", "Output-only identifications of the window (rows of modes).",
                s->oma_done);
        counter(&o, "vibid_oma_identifications_skipped_total",
                "Identifications not started: the previous one was still running (the next covers the samples).",
                s->oma_skipped);
        counter(&o, "vibid_oma_lost_samples_total",
                "Samples lost to the identification: the low-priority thread fell behind by more than its ring.",
                s->oma_lost);
        counter(&o, "vibid_oma_windows_without_modes_total",
                "Identifications in which no tracked mode was found (rows flagged E).", s->oma_without);
        gauge(&o, "vibid_oma_last_duration_seconds", "Wall time of the last output-only identification.",
              s->oma_last_s);
    }
    if (s->refine_on) {
        counter(&o, "vibid_refinements_total", "Output-error refinements written as rows flagged W.", s->refine_done);
        counter(&o, "vibid_refinements_failed_total",
                "Output-error refinements that failed (no convergence, a bound, singular, a non-finite input).",
                s->refine_failed);
        counter(&o, "vibid_refinement_overruns_total",
                "Refinements given up: the window was overwritten before the refine thread copied it.",
                s->refine_overruns);
        counter(&o, "vibid_refinements_skipped_total",
                "Refinements not started: the refine thread was busy or the window spans a gap.", s->refine_skipped);
        gauge(&o, "vibid_refinement_last_duration_seconds", "Wall time of the last output-error fit.",
              s->refine_last_s);
    }
    /* the daemon's 1 us histogram as a Prometheus histogram with a handful of buckets */
    family(&o, "vibid_latency_seconds", "histogram",
           "Receipt of a sample to its estimate (live and paced sources only).");
    for (unsigned i = 0; i < VD_METRICS_LAT_BOUNDS; i++) {
        char le[40];
        vd_metrics_format_double(le, sizeof le, vd_metrics_lat_bounds_us[i] / 1e6); /* 10 / 1e6 is 1e-05 */
        snprintf(a, sizeof a, "le=\"%s\"", le);
        u64(&o, "vibid_latency_seconds_bucket", a, s->lat_le[i]);
    }
    u64(&o, "vibid_latency_seconds_bucket", "le=\"+Inf\"", s->lat_n);
    dbl(&o, "vibid_latency_seconds_sum", "", s->lat_sum_s);
    u64(&o, "vibid_latency_seconds_count", "", s->lat_n);
    /* the same data as exact quantiles (to 1 us, over the whole run: the status file's
     * latency_us_p50/p99); a summary, because promtool allows a quantile label nowhere else */
    family(&o, "vibid_run_latency_seconds", "summary",
           "Receipt-to-estimate latency quantiles over the whole run, to 1 us (NaN before the first sample).");
    dbl(&o, "vibid_run_latency_seconds", "quantile=\"0.5\"", s->lat_p50_us / 1e6);
    dbl(&o, "vibid_run_latency_seconds", "quantile=\"0.99\"", s->lat_p99_us / 1e6);
    dbl(&o, "vibid_run_latency_seconds_sum", "", s->lat_sum_s);
    u64(&o, "vibid_run_latency_seconds_count", "", s->lat_n);
    /* the outputs' own counters, each family's series one after the other (vd_snapshot_add) */
    for (size_t i = 0; i < s->n_out_counters; i++) {
        const vd_output_counter *q = &s->out_counter[i];
        if (!q->metric)
            continue;
        bool first = true; /* of its family: the HELP and TYPE lines */
        for (size_t j = i; j-- > 0;)
            if (s->out_counter[j].metric) {
                first = strcmp(s->out_counter[j].metric, q->metric) != 0;
                break;
            }
        if (first)
            family(&o, q->metric, q->gauge ? "gauge" : "counter", q->help);
        if (q->gauge)
            dbl(&o, q->metric, q->label ? q->label : "", q->value);
        else
            u64(&o, q->metric, q->label ? q->label : "", (uint64_t)q->value);
    }
    counter(&o, "vibid_alarms_raised_total", "Drift alarms raised.", s->alarms_raised);
    unsigned active = 0;
    for (size_t k = 0; k < s->n_params; k++)
        active += s->alarm_active[k];
    gauge(&o, "vibid_alarms_active", "Drift alarms active now.", active);
    bool any_alarm = false;
    for (size_t k = 0; k < s->n_params; k++)
        any_alarm |= s->alarm_enabled[k];
    if (any_alarm)
        family(&o, "vibid_alarm_active", "gauge", "1 while the drift alarm of the parameter is active.");
    for (size_t k = 0; k < s->n_params; k++) {
        if (!s->alarm_enabled[k])
            continue;
        vd_metrics_escape_label(b, sizeof b, s->param[k]);
        snprintf(a, sizeof a, "parameter=\"%s\"", b);
        u64(&o, "vibid_alarm_active", a, s->alarm_active[k]);
    }
    /* the change test (alarms.test = "cusum"), once its reference exists */
    static const struct {
        const char *name, *help;
    } change_families[] = {
        {"vibid_change_statistic", "The change test's statistic of the parameter: the CUSUM over its threshold (>= 1 raises)."},
        {"vibid_min_detectable_change", "The smallest change of the parameter the test detects within alarms.horizon "
                                        "(alarms.detection_probability, alarms.false_alarms_per_year), its unit."},
        {"vibid_min_detectable_change_ratio", "The minimum detectable change relative to the reference value."}};
    bool any_change = false;
    for (size_t k = 0; k < s->n_params; k++)
        any_change |= s->have_change[k];
    for (size_t f = 0; any_change && f < 3; f++) {
        family(&o, change_families[f].name, "gauge", change_families[f].help);
        for (size_t k = 0; k < s->n_params; k++) {
            if (!s->have_change[k])
                continue;
            vd_metrics_escape_label(b, sizeof b, s->param[k]);
            snprintf(a, sizeof a, "parameter=\"%s\"", b);
            const double v = f == 0 ? s->change_statistic[k] : f == 1 ? s->change_mdc[k] : s->change_mdc_relative[k];
            dbl(&o, change_families[f].name, a, v);
        }
    }
    if (s->n_covariates) {
        counter(&o, "vibid_covariate_out_of_range_rows_total",
                "Rows whose covariates lay outside the range the alarm reference saw (flag C: weighed down in the "
                "change test).",
                s->covariate_rows);
        family(&o, "vibid_covariate", "gauge",
               "The covariate (an operating condition: source.channels with quantity covariate), its mean over the "
               "latest row's samples, in its channel's unit.");
        for (size_t j = 0; j < s->n_covariates; j++) {
            vd_metrics_escape_label(b, sizeof b, s->cov_name[j]);
            snprintf(a, sizeof a, "covariate=\"%s\"", b);
            dbl(&o, "vibid_covariate", a, s->cov_value[j]);
        }
    }
    if (s->have_last) {
        gauge(&o, "vibid_last_row_index", "Sample index (from the run's start) of the latest row.",
              (double)s->last_index);
        gauge(&o, "vibid_last_row_timestamp_seconds", "Sample time of the latest row, seconds since the epoch.",
              (double)s->last_t_us / 1e6);
        /* an output-only configuration's "parameters" are its tracked modes' f<j>_hz and zeta<j> */
        per_param(&o, s, "vibid_estimate",
                  s->oma_on ? "Latest estimate of the tracked mode's quantity: f<j>_hz its natural frequency in Hz, "
                              "zeta<j> its damping ratio (dimensionless); NaN where the mode was not found in the row."
                            : "Latest estimate of the parameter, in the stand's units: kg for masses, N s/m for "
                              "dampers, N/m for springs, N/m^3 for cubic springs, the input's gain for gains (m "
                              "replaced by the stand's length unit).",
                  s->theta);
        per_param(&o, s, "vibid_estimate_standard_error",
                  "Standard error of vibid_estimate, in the parameter's unit (+Inf: the data hardly inform it).",
                  s->se);
        per_mode(&o, s, "vibid_natural_frequency_hertz", "Natural frequency of the mode (ascending order).",
                 s->freq);
        per_mode(&o, s, "vibid_natural_frequency_standard_error_hertz",
                 "Standard error of vibid_natural_frequency_hertz.", s->freq_se);
        per_mode(&o, s, "vibid_damping_ratio", "Damping ratio of the mode (dimensionless).", s->zeta);
        per_mode(&o, s, "vibid_damping_ratio_standard_error", "Standard error of vibid_damping_ratio.",
                 s->zeta_se);
        family(&o, "vibid_row_flag", "gauge",
               "Flags of the latest row as in the tracks, 1 if set: G samples missing since the previous row, O "
               "a single-sample glitch taken out since the previous row, E "
               "no estimate, P physically impossible, U standard errors do not hold, I a parameter hardly "
               "informed, A an alarm active, C covariates outside the alarm reference's range, W an "
               "output-error refinement.");
        static const struct {
            const char *letter;
            unsigned bit;
        } fl[] = {{"G", VD_FLAG_GAP},        {"O", VD_FLAG_OUTLIER},     {"E", VD_FLAG_NOEST},
                  {"P", VD_FLAG_IMPLAUSIBLE}, {"U", VD_FLAG_SE_INVALID}, {"I", VD_FLAG_NOT_EXCITED},
                  {"A", VD_FLAG_ALARM},       {"C", VD_FLAG_COVARIATE},   {"W", VD_FLAG_REFINED}};
        for (size_t i = 0; i < sizeof fl / sizeof fl[0]; i++) {
            snprintf(a, sizeof a, "flag=\"%s\"", fl[i].letter);
            u64(&o, "vibid_row_flag", a, (s->last_flags & fl[i].bit) ? 1 : 0);
        }
    }
    if (s->metrics_on) {
        counter(&o, "vibid_metrics_scrapes_total", "Requests for /metrics answered (as of this text).", s->scrapes);
        family(&o, "vibid_metrics_refused_total", "counter",
               "Connections of the metrics endpoint refused or closed, by reason.");
        for (unsigned r = 0; r < VD_REFUSED_N; r++) {
            snprintf(a, sizeof a, "reason=\"%s\"", vd_refusal_name((vd_refusal)r));
            u64(&o, "vibid_metrics_refused_total", a, s->refused[r]);
        }
    }
    return o.full ? -1 : (int)o.off;
}

/* --------------------------------------------------------------- address ---- */

int vd_metrics_parse_listen(const char *text, struct sockaddr_storage *addr, socklen_t *len, char *err, size_t cap)
{
    memset(addr, 0, sizeof *addr);
    char host[128];
    const char *port_s;
    if (text[0] == '[') {
        const char *close = strchr(text, ']');
        if (!close || close[1] != ':' || (size_t)(close - text - 1) >= sizeof host) {
            snprintf(err, cap, "'%s': expected [IPv6]:PORT, e.g. \"[::1]:18813\"", text);
            return -1;
        }
        snprintf(host, sizeof host, "%.*s", (int)(close - text - 1), text + 1);
        port_s = close + 2;
    } else {
        const char *colon = strrchr(text, ':');
        if (!colon || colon == text || (size_t)(colon - text) >= sizeof host) {
            snprintf(err, cap, "'%s': expected HOST:PORT, e.g. \"127.0.0.1:18813\"", text);
            return -1;
        }
        snprintf(host, sizeof host, "%.*s", (int)(colon - text), text);
        if (strchr(host, ':')) {
            snprintf(err, cap, "'%s': an IPv6 address needs brackets, e.g. \"[::1]:18813\"", text);
            return -1;
        }
        port_s = colon + 1;
    }
    char *end;
    errno = 0;
    long port = strtol(port_s, &end, 10);
    if (!*port_s || *end || errno || port < 0 || port > 65535 || *port_s == '-' || *port_s == '+') {
        snprintf(err, cap, "'%s': port '%s' outside 0..65535", text, port_s);
        return -1;
    }
    if (text[0] == '[') {
        struct sockaddr_in6 *a6 = (struct sockaddr_in6 *)addr;
        if (inet_pton(AF_INET6, host, &a6->sin6_addr) != 1) {
            snprintf(err, cap, "'%s': '%s' is not an IPv6 address", text, host);
            return -1;
        }
        a6->sin6_family = AF_INET6;
        a6->sin6_port = htons((uint16_t)port);
        *len = sizeof *a6;
        return 0;
    }
    struct sockaddr_in *a4 = (struct sockaddr_in *)addr;
    /* no name resolution: "localhost" is the loopback address by definition (RFC 6761),
     * any other name could resolve to an address the operator did not mean to expose */
    if (strcmp(host, "localhost") == 0)
        a4->sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    else if (inet_pton(AF_INET, host, &a4->sin_addr) != 1) {
        snprintf(err, cap, "'%s': '%s' is not an IPv4 address (a host name other than localhost is not accepted)",
                 text, host);
        return -1;
    }
    a4->sin_family = AF_INET;
    a4->sin_port = htons((uint16_t)port);
    *len = sizeof *a4;
    return 0;
}

static bool is_loopback(const struct sockaddr_storage *a)
{
    if (a->ss_family == AF_INET)
        return (ntohl(((const struct sockaddr_in *)a)->sin_addr.s_addr) >> 24) == 127;
    return IN6_IS_ADDR_LOOPBACK(&((const struct sockaddr_in6 *)a)->sin6_addr);
}

static void format_addr(const struct sockaddr_storage *a, char *buf, size_t cap)
{
    char h[INET6_ADDRSTRLEN] = "?";
    if (a->ss_family == AF_INET6) {
        const struct sockaddr_in6 *a6 = (const struct sockaddr_in6 *)a;
        inet_ntop(AF_INET6, &a6->sin6_addr, h, sizeof h);
        snprintf(buf, cap, "[%s]:%u", h, (unsigned)ntohs(a6->sin6_port));
    } else {
        const struct sockaddr_in *a4 = (const struct sockaddr_in *)a;
        inet_ntop(AF_INET, &a4->sin_addr, h, sizeof h);
        snprintf(buf, cap, "%s:%u", h, (unsigned)ntohs(a4->sin_port));
    }
}

/* A listening socket on text; -1 with errno set and err filled. */
static int bind_listen(const char *text, char *err, size_t cap, struct sockaddr_storage *addr)
{
    socklen_t len;
    if (vd_metrics_parse_listen(text, addr, &len, err, cap)) {
        errno = EINVAL;
        return -1;
    }
    int fd = socket(addr->ss_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0) {
        int e = errno;
        snprintf(err, cap, "outputs.prometheus.listen %s: socket: %s", text, strerror(e));
        errno = e;
        return -1;
    }
    int one = 1;
    /* a restarted vibidd binds again at once, despite connections of the old one in TIME_WAIT */
    (void)setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (addr->ss_family == AF_INET6) /* "[::]" means IPv6 only: IPv4 has its own "0.0.0.0" */
        (void)setsockopt(fd, IPPROTO_IPV6, IPV6_V6ONLY, &one, sizeof one);
    if (bind(fd, (struct sockaddr *)addr, len) != 0 || listen(fd, 64) != 0) {
        int e = errno;
        snprintf(err, cap, "outputs.prometheus.listen %s: cannot listen: %s", text, strerror(e));
        close(fd);
        errno = e;
        return -1;
    }
    socklen_t l = sizeof *addr;
    getsockname(fd, (struct sockaddr *)addr, &l); /* the port the kernel chose for port 0 */
    return fd;
}

int vd_metrics_check(const vd_config *cfg, char *note, size_t note_cap, char *err, size_t cap)
{
    if (note_cap)
        note[0] = '\0';
    if (!cfg->prometheus.listen[0])
        return 0;
    struct sockaddr_storage a;
    int fd = bind_listen(cfg->prometheus.listen, err, cap, &a);
    if (fd >= 0) {
        close(fd);
        return 0;
    }
    if (errno == EADDRINUSE) {
        snprintf(note, note_cap,
                 "outputs.prometheus.listen %s is in use now (a running vibidd?): start-up fails unless it is "
                 "free then",
                 cfg->prometheus.listen);
        return 1;
    }
    return -1;
}

/* ---------------------------------------------------------------- server ---- */

typedef struct vd_metrics_slot {
    int fd;          /* -1: free */
    double t0;       /* accept time, monotonic s */
    bool writing;
    size_t in_len, out_len, out_off;
    char in[VD_METRICS_REQUEST_MAX];
    char out[512 + VD_METRICS_TEXT_MAX];
} slot;

int vd_metrics_open(vd_metrics *m, const vd_config *cfg, char *err, size_t cap)
{
    memset(m, 0, sizeof *m);
    m->listen_fd = m->stop_fd = -1;
    pthread_mutex_init(&m->mu, NULL);
    m->opened = true; /* from here on vd_metrics_close releases what was opened */
    m->text = malloc(VD_METRICS_TEXT_MAX);
    m->render = malloc(VD_METRICS_TEXT_MAX);
    m->slots = calloc(VD_METRICS_SLOTS, sizeof *m->slots);
    if (!m->text || !m->render || !m->slots) {
        snprintf(err, cap, "out of memory for the metrics endpoint");
        return -1;
    }
    for (int i = 0; i < VD_METRICS_SLOTS; i++)
        m->slots[i].fd = -1;
    m->stop_fd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    if (m->stop_fd < 0) {
        snprintf(err, cap, "eventfd for the metrics endpoint: %s", strerror(errno));
        return -1;
    }
    struct sockaddr_storage a;
    m->listen_fd = bind_listen(cfg->prometheus.listen, err, cap, &a);
    if (m->listen_fd < 0)
        return -1;
    format_addr(&a, m->where, sizeof m->where);
    if (!is_loopback(&a))
        vd_warning("outputs.prometheus.listen %s is not a loopback address: anyone who can reach it reads the "
                   "stand's estimates and counters (no authentication, plain HTTP)",
                   m->where);
    return 0;
}

static void close_slot(vd_metrics *m, slot *s, int refusal)
{
    if (refusal >= 0)
        atomic_fetch_add_explicit(&m->refused[refusal], 1, memory_order_relaxed);
    close(s->fd);
    s->fd = -1;
}

static void respond(vd_metrics *m, slot *s, int code, const char *reason, const char *ctype, const char *extra,
                    const char *body, size_t body_len, bool head)
{
    int n = snprintf(s->out, 512,
                     "HTTP/1.1 %d %s\r\nContent-Type: %s\r\nContent-Length: %zu\r\nConnection: close\r\n%s\r\n",
                     code, reason, ctype, body_len, extra);
    size_t h = n > 0 && n < 512 ? (size_t)n : 0;
    if (!head && body)
        memcpy(s->out + h, body, body_len);
    s->out_len = h + (head ? 0 : body_len);
    s->out_off = 0;
    s->writing = true;
    (void)m;
}

static void respond_text(vd_metrics *m, slot *s, int code, const char *reason, const char *extra, const char *msg)
{
    respond(m, s, code, reason, "text/plain; charset=utf-8", extra, msg, strlen(msg), false);
}

/* The exposition: copied out of the shared buffer under the lock (a memcpy), so that a
 * peer that reads slowly never holds it. */
static void respond_metrics(vd_metrics *m, slot *s, bool head)
{
    pthread_mutex_lock(&m->mu);
    size_t len = m->text_len;
    int n = snprintf(s->out, 512,
                     "HTTP/1.1 %s\r\nContent-Type: text/plain; version=0.0.4; charset=utf-8\r\nContent-Length: "
                     "%zu\r\nConnection: close\r\nCache-Control: no-store\r\n\r\n",
                     len ? "200 OK" : "503 Service Unavailable", len);
    size_t h = n > 0 && n < 512 ? (size_t)n : 0;
    if (!head)
        memcpy(s->out + h, m->text, len);
    pthread_mutex_unlock(&m->mu);
    s->out_len = h + (head ? 0 : len);
    s->out_off = 0;
    s->writing = true;
    if (len)
        atomic_fetch_add_explicit(&m->scrapes, 1, memory_order_relaxed);
}

/* Bytes of a request line: printable ASCII and the line's \r. */
static bool line_bytes_ok(const char *p, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        unsigned char ch = (unsigned char)p[i];
        if (ch == '\n')
            return true;
        if ((ch < 0x20 && ch != '\r') || ch >= 0x7f)
            return false;
    }
    return true;
}

/* The complete request line of s: "METHOD /target HTTP/1.x" (METHOD upper-case letters,
 * target an origin-form path) into method and target; false if it is anything else. */
static bool request_line(const slot *s, char method[16], char target[2048])
{
    const char *nl = memchr(s->in, '\n', s->in_len);
    char line[VD_METRICS_REQUEST_MAX];
    size_t ll = (size_t)(nl - s->in);
    if (ll && s->in[ll - 1] == '\r')
        ll--;
    memcpy(line, s->in, ll);
    line[ll] = '\0';
    char *sp1 = strchr(line, ' '), *sp2 = sp1 ? strchr(sp1 + 1, ' ') : NULL;
    if (!(sp1 && sp2 && strchr(sp2 + 1, ' ') == NULL && sp1 > line && sp1 - line < 16 && sp2 > sp1 + 1 &&
          sp2 - sp1 - 1 < 2048))
        return false;
    snprintf(method, 16, "%.*s", (int)(sp1 - line), line);
    snprintf(target, 2048, "%.*s", (int)(sp2 - sp1 - 1), sp1 + 1);
    if (strcmp(sp2 + 1, "HTTP/1.1") != 0 && strcmp(sp2 + 1, "HTTP/1.0") != 0)
        return false;
    if (target[0] != '/')
        return false;
    for (const char *p = method; *p; p++)
        if (*p < 'A' || *p > 'Z')
            return false;
    return true;
}

static void bad_request(vd_metrics *m, slot *s)
{
    atomic_fetch_add_explicit(&m->refused[VD_REFUSED_BAD_REQUEST], 1, memory_order_relaxed);
    respond_text(m, s, 400, "Bad Request", "", "400 bad request: expected \"GET /metrics HTTP/1.1\"\n");
}

/* What the request asks for, once its headers are complete. */
static void answer(vd_metrics *m, slot *s)
{
    char method[16], target[2048];
    if (!request_line(s, method, target)) {
        bad_request(m, s);
        return;
    }
    bool head = strcmp(method, "HEAD") == 0;
    if (!head && strcmp(method, "GET") != 0) {
        atomic_fetch_add_explicit(&m->refused[VD_REFUSED_METHOD], 1, memory_order_relaxed);
        respond_text(m, s, 405, "Method Not Allowed", "Allow: GET, HEAD\r\n", "405 method not allowed: GET or HEAD\n");
        return;
    }
    char *q = strchr(target, '?'); /* a query string (Prometheus' params) changes nothing */
    if (q)
        *q = '\0';
    if (strcmp(target, "/metrics") == 0) {
        respond_metrics(m, s, head);
    } else if (strcmp(target, "/") == 0) {
        static const char page[] = "<html><head><title>vibidd</title></head><body><h1>vibidd</h1>"
                                   "<p><a href=\"/metrics\">/metrics</a>: Prometheus metrics of the daemon's "
                                   "health and latest estimates.</p></body></html>\n";
        respond(m, s, 200, "OK", "text/html; charset=utf-8", "", page, sizeof page - 1, head);
    } else {
        atomic_fetch_add_explicit(&m->refused[VD_REFUSED_NOT_FOUND], 1, memory_order_relaxed);
        respond_text(m, s, 404, "Not Found", "", "404 not found: the metrics are at /metrics\n");
    }
}

static bool headers_complete(const slot *s)
{
    for (size_t i = 1; i < s->in_len; i++)
        if (s->in[i] == '\n' && (s->in[i - 1] == '\n' || (i >= 3 && s->in[i - 1] == '\r' && s->in[i - 2] == '\n')))
            return true;
    return false;
}

static void on_readable(vd_metrics *m, slot *s)
{
    for (;;) {
        if (s->in_len == sizeof s->in) {
            atomic_fetch_add_explicit(&m->refused[VD_REFUSED_TOO_LARGE], 1, memory_order_relaxed);
            respond_text(m, s, 431, "Request Header Fields Too Large", "", "431 request larger than 8 KiB\n");
            return;
        }
        ssize_t n = recv(s->fd, s->in + s->in_len, sizeof s->in - s->in_len, 0);
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
            return;
        if (n <= 0) { /* closed (or reset) before a complete request: nothing to answer */
            close_slot(m, s, -1);
            return;
        }
        size_t before = s->in_len;
        s->in_len += (size_t)n;
        /* the request line is judged as soon as its bytes arrive: garbage gets its 400
         * without waiting for a blank line that may never come */
        const bool had_line = memchr(s->in, '\n', before) != NULL;
        if (!had_line && !line_bytes_ok(s->in + before, (size_t)n)) {
            bad_request(m, s);
            return;
        }
        char method[16], target[2048];
        if (!had_line && memchr(s->in + before, '\n', (size_t)n) && !request_line(s, method, target)) {
            bad_request(m, s); /* the line just completed and is not HTTP: no need to wait for headers */
            return;
        }
        if (headers_complete(s)) {
            answer(m, s);
            return;
        }
    }
}

static void on_writable(vd_metrics *m, slot *s)
{
    while (s->out_off < s->out_len) {
        ssize_t n = send(s->fd, s->out + s->out_off, s->out_len - s->out_off, MSG_NOSIGNAL);
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
            return;
        if (n <= 0) {
            close_slot(m, s, -1);
            return;
        }
        s->out_off += (size_t)n;
    }
    /* all sent: FIN after the data (no RST unless the peer sent more than it asked) */
    shutdown(s->fd, SHUT_WR);
    close_slot(m, s, -1);
}

static void accept_all(vd_metrics *m, double now, double *pause_until)
{
    for (int k = 0; k < 4 * VD_METRICS_SLOTS; k++) {
        int fd = accept4(m->listen_fd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (fd < 0) {
            if (errno == EINTR || errno == ECONNABORTED)
                continue;
            if (errno != EAGAIN && errno != EWOULDBLOCK) {
                /* EMFILE, ENFILE, ENOBUFS: the listening socket stays readable; leave it
                 * alone for a moment instead of spinning on it */
                static double last_log;
                if (now - last_log >= 60.0) {
                    vd_warning("metrics endpoint %s: accept: %s (pausing 100 ms)", m->where, strerror(errno));
                    last_log = now;
                }
                *pause_until = now + 0.1;
            }
            return;
        }
        slot *free_s = NULL, *oldest = NULL;
        for (int i = 0; i < VD_METRICS_SLOTS; i++) {
            slot *s = &m->slots[i];
            if (s->fd < 0) {
                free_s = s;
                break;
            }
            if (!oldest || s->t0 < oldest->t0)
                oldest = s;
        }
        if (!free_s) { /* every slot busy: the oldest connection makes room */
            close_slot(m, oldest, VD_REFUSED_EVICTED);
            free_s = oldest;
        }
        free_s->fd = fd;
        free_s->t0 = now;
        free_s->writing = false;
        free_s->in_len = free_s->out_len = free_s->out_off = 0;
    }
}

static void *serve(void *arg)
{
    vd_metrics *m = arg;
    double pause_until = 0;
    for (;;) {
        struct pollfd pfd[2 + VD_METRICS_SLOTS];
        slot *who[2 + VD_METRICS_SLOTS];
        nfds_t n = 0;
        double now = vd_mono_s();
        pfd[n++] = (struct pollfd){.fd = m->stop_fd, .events = POLLIN};
        bool listening = now >= pause_until;
        if (listening)
            pfd[n++] = (struct pollfd){.fd = m->listen_fd, .events = POLLIN};
        double next = listening ? -1.0 : pause_until;
        for (int i = 0; i < VD_METRICS_SLOTS; i++) {
            slot *s = &m->slots[i];
            if (s->fd < 0)
                continue;
            double dl = s->t0 + VD_METRICS_DEADLINE_S;
            if (next < 0 || dl < next)
                next = dl;
            who[n] = s;
            pfd[n++] = (struct pollfd){.fd = s->fd, .events = s->writing ? POLLOUT : POLLIN};
        }
        int timeout = next < 0 ? -1 : (int)ceil(fmax(0.0, next - now) * 1000.0);
        int rc = poll(pfd, n, timeout);
        if (rc < 0 && errno != EINTR) {
            vd_error("metrics endpoint %s: poll: %s; the endpoint stops (acquisition goes on)", m->where,
                     strerror(errno));
            break;
        }
        if (pfd[0].revents)
            break; /* vd_metrics_close */
        now = vd_mono_s();
        for (nfds_t i = listening ? 2 : 1; rc > 0 && i < n; i++) {
            slot *s = who[i];
            if (s->fd < 0 || !pfd[i].revents)
                continue;
            if (s->writing)
                on_writable(m, s);
            else
                on_readable(m, s);
            /* a response is tried at once: it usually fits the socket buffer */
            if (s->fd >= 0 && s->writing)
                on_writable(m, s);
        }
        for (int i = 0; i < VD_METRICS_SLOTS; i++) {
            slot *s = &m->slots[i];
            if (s->fd >= 0 && now >= s->t0 + VD_METRICS_DEADLINE_S)
                close_slot(m, s, VD_REFUSED_TIMEOUT);
        }
        if (listening && rc > 0 && pfd[1].revents)
            accept_all(m, now, &pause_until);
    }
    for (int i = 0; i < VD_METRICS_SLOTS; i++)
        if (m->slots[i].fd >= 0)
            close_slot(m, &m->slots[i], -1);
    return NULL;
}

int vd_metrics_start(vd_metrics *m, char *err, size_t cap)
{
    int rc = pthread_create(&m->thread, NULL, serve, m);
    if (rc) {
        snprintf(err, cap, "cannot start the metrics thread: %s", strerror(rc));
        return -1;
    }
    m->started = true;
    vd_notice("metrics: Prometheus exposition at http://%s/metrics", m->where);
    return 0;
}

bool vd_metrics_publish(vd_metrics *m, const vd_snapshot *s, bool wait)
{
    int n = vd_metrics_render(m->render, VD_METRICS_TEXT_MAX, s);
    if (n < 0) {
        if (!m->too_large_logged)
            vd_error("metrics: the exposition exceeds %d bytes; the last complete one stays served",
                     VD_METRICS_TEXT_MAX);
        m->too_large_logged = true;
        return false;
    }
    if (wait)
        pthread_mutex_lock(&m->mu);
    else if (pthread_mutex_trylock(&m->mu) != 0)
        return false;
    memcpy(m->text, m->render, (size_t)n);
    m->text_len = (size_t)n;
    pthread_mutex_unlock(&m->mu);
    return true;
}

void vd_metrics_counters(vd_metrics *m, vd_snapshot *s)
{
    s->metrics_on = true;
    s->scrapes = atomic_load_explicit(&m->scrapes, memory_order_relaxed);
    for (unsigned r = 0; r < VD_REFUSED_N; r++)
        s->refused[r] = atomic_load_explicit(&m->refused[r], memory_order_relaxed);
}

void vd_metrics_close(vd_metrics *m)
{
    if (!m->opened)
        return;
    m->opened = false;
    if (m->started) {
        uint64_t one = 1;
        ssize_t w = write(m->stop_fd, &one, sizeof one);
        (void)w; /* an eventfd write fails only when the counter would overflow: already set */
        pthread_join(m->thread, NULL);
        m->started = false;
    }
    if (m->listen_fd >= 0)
        close(m->listen_fd);
    if (m->stop_fd >= 0)
        close(m->stop_fd);
    m->listen_fd = m->stop_fd = -1;
    pthread_mutex_destroy(&m->mu);
    free(m->text);
    free(m->render);
    free(m->slots);
    m->text = m->render = NULL;
    m->slots = NULL;
}

/* -------------------------------------------- the output "prometheus" (output.h) ---- */

static bool prometheus_enabled(const vd_config *cfg) { return cfg->prometheus.listen[0] != '\0'; }

/* The socket is bound here, before READY=1: an address that cannot be bound is a
 * configuration error (exit 2), not a run-time surprise. */
static void *prometheus_open(const vd_output_ctx *ctx, char *err, size_t cap)
{
    vd_metrics *m = calloc(1, sizeof *m);
    if (!m) {
        snprintf(err, cap, "outputs.prometheus: out of memory");
        return NULL;
    }
    if (vd_metrics_open(m, ctx->cfg, err, cap)) {
        vd_metrics_close(m);
        free(m);
        return NULL;
    }
    return m;
}

static int prometheus_start(void *o, char *err, size_t cap) { return vd_metrics_start(o, err, cap); }

/* never waits while estimating: a busy server gets the next one */
static bool prometheus_status(void *o, const vd_snapshot *s, const char *text, size_t len, bool final)
{
    (void)text;
    (void)len;
    return vd_metrics_publish(o, s, final);
}

static size_t prometheus_status_lines(const vd_snapshot *sn, char *buf, size_t cap)
{
    unsigned long long refused = 0;
    for (unsigned r = 0; r < VD_REFUSED_N; r++)
        refused += sn->refused[r];
    int n = snprintf(buf, cap, "metrics_listen=%s\nmetrics_scrapes=%llu\nmetrics_refused=%llu\n", sn->metrics_listen,
                     (unsigned long long)sn->scrapes, refused);
    return n > 0 ? (size_t)n : 0;
}

/* at least every second, sooner with a shorter status interval */
static double prometheus_status_period(const vd_config *cfg) { return fmin(cfg->files.status_interval_s, 1.0); }

static void prometheus_counters(void *o, vd_snapshot *s)
{
    vd_metrics *m = o;
    vd_metrics_counters(m, s);
    s->metrics_listen = m->where;
}

/* after the threads: the final state was published */
static void prometheus_close(void *o)
{
    if (!o)
        return;
    vd_metrics_close(o);
    free(o);
}

/* ---------------------------------------------------------- settings ---- */

static const char *const prometheus_groups[] = {"prometheus", NULL};

/* outputs.prometheus: off without the group; the group alone listens on loopback
 * (VD_PROMETHEUS_DEFAULT); another address only when given. Only the syntax here: the bind
 * is tried by --check (vd_metrics_check) and at start-up (vd_metrics_open). */
static int prometheus_load(vd_cfg_ctx *c, const config_setting_t *g)
{
    vd_config *cfg = c->cfg;
    config_setting_t *p = g ? config_setting_get_member(g, "prometheus") : NULL;
    static const char *const pk[] = {"listen", NULL};
    if (p && !config_setting_is_group(p))
        return vibid_cfg_fail(&c->r, p, "outputs.prometheus", "must be a group { listen = \"%s\"; }",
                              VD_PROMETHEUS_DEFAULT);
    if (vd_cfg_known(c, p, "outputs.prometheus", pk) ||
        vd_cfg_string(c, p, "outputs.prometheus", "listen", p ? VD_PROMETHEUS_DEFAULT : "", cfg->prometheus.listen,
                      sizeof cfg->prometheus.listen))
        return -1;
    if (cfg->prometheus.listen[0]) {
        struct sockaddr_storage a;
        socklen_t len;
        char why[300];
        if (vd_metrics_parse_listen(cfg->prometheus.listen, &a, &len, why, sizeof why))
            return vibid_cfg_fail(&c->r, config_setting_get_member(p, "listen"), "outputs.prometheus.listen", "%s",
                                  why);
    }
    return 0;
}

static void prometheus_print(const vd_config *cfg, FILE *o)
{
    fprintf(o, "  prometheus = { listen = \"%s\"; };  # \"\" = off\n", cfg->prometheus.listen);
}

const vd_output_ops vd_output_prometheus = {
    .name = "prometheus",
    .groups = prometheus_groups,
    .load = prometheus_load,
    .print = prometheus_print,
    .enabled = prometheus_enabled,
    .check = vd_metrics_check,
    .open = prometheus_open,
    .start = prometheus_start,
    .status = prometheus_status,
    .status_lines = prometheus_status_lines,
    .status_period = prometheus_status_period,
    .counters = prometheus_counters,
    .close = prometheus_close,
};
