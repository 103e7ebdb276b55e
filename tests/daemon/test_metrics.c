/* Unit tests of the Prometheus metrics (metrics.h): exact exposition lines for given
 * counters, NaN/+Inf/-Inf and number formatting, label escaping of a stand name with
 * quotes, backslashes and a newline, HELP and TYPE before every family, the histogram's
 * cumulative buckets; the listen address parser; and the endpoint on a loopback port:
 * 200/404/405/400/431, a peer that sends nothing closed at the deadline while others are
 * served, and the counters of both. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <arpa/inet.h>
#include <math.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <vibid/common.h>

#include "config.h"
#include "estimator.h"
#include "metrics.h"
#include "output.h"
#include "writers.h"

static vd_snapshot snap;

static void fill_snapshot(vd_snapshot *s)
{
    memset(s, 0, sizeof *s);
    s->state = "running";
    s->stand = "rig \"A\\7\"\nnew";
    s->source = "socketcan";
    s->estimator = "auto";
    s->uptime_s = 12.5;
    s->stand_rate_hz = 2000.0;
    s->samples = 123456789012ULL;
    s->rate_hz = 1999.5;
    s->gaps = 3;
    s->missing = 17;
    s->n_fault_kinds = 2;
    s->fault_kind[1] = "bad_line";
    s->fault_kind[2] = "unknown_id";
    s->faults_by_kind[1] = 4;
    s->faults_by_kind[2] = 0;
    s->ring_capacity = 65536;
    s->ring_fill = 12;
    s->ring_overflows = 2;
    /* the file outputs' counters as their output gives them (writers.c): tracks and record
     * configured, no influx file; the tracks closed after 3 failed reopens */
    static vd_writers w;
    memset(&w, 0, sizeof w);
    w.write_errors = 5;
    w.torn_lines = 1;
    w.out[0].path = "tracks.csv";
    w.out[1].path = "";
    w.out[2].path = "raw.csv";
    w.out[0].open_failures = 3;
    w.out[0].closed = true;
    w.out[0].lost = 401;
    w.out[2].lost = 8017;
    vd_output_files.counters(&w, s);
    /* 5 counters, the open-failure sum, 2 labelled open-failure series, 3 losses, 2 labelled
     * loss series; with every file output 15 at most, MQTT's 10 and InfluxDB's 9 (their
     * tests): 34 of the VD_OUTPUT_COUNTERS_MAX a snapshot holds */
    assert_int_equal(s->n_out_counters, 13);
    s->rows = 617;
    s->est_errors = 1;
    s->implausible_rows = 2;
    s->outlier_samples = 5;
    s->alarms_raised = 1;
    s->lat_n = 10;
    for (unsigned i = 0; i < VD_METRICS_LAT_BOUNDS; i++)
        s->lat_le[i] = i < 2 ? 0 : i < 4 ? 6 : 9; /* cumulative, the tenth above 10 ms */
    s->lat_sum_s = 0.25;
    s->lat_p50_us = 57.5;
    s->lat_p99_us = NAN;
    s->n_params = 3;
    s->n_modes = 2;
    static const char *const names[] = {"c1", "d", "c2"};
    for (size_t k = 0; k < 3; k++) {
        s->param[k] = names[k];
        s->alarm_enabled[k] = k != 1;
    }
    s->alarm_active[2] = true;
    s->have_last = true;
    s->last_index = 4000;
    s->last_t_us = 1700000001500000LL;
    s->last_flags = VD_FLAG_GAP | VD_FLAG_OUTLIER | VD_FLAG_ALARM;
    s->theta[0] = 250000.0;
    s->theta[1] = NAN;
    s->theta[2] = 0.1;
    s->se[0] = 12.5;
    s->se[1] = INFINITY;
    s->se[2] = -INFINITY;
    s->freq[0] = 22.78;
    s->freq[1] = 48.15;
    s->zeta[0] = 0.0653;
    s->zeta[1] = 0.0435;
    s->metrics_on = true;
    s->scrapes = 7;
    s->refused[VD_REFUSED_TIMEOUT] = 2;
}

static char text[VD_METRICS_TEXT_MAX];

static void render(void)
{
    int n = vd_metrics_render(text, sizeof text, &snap);
    assert_true(n > 0);
    assert_int_equal((size_t)n, strlen(text));
}

/* The exposition has this exact line. */
static void has_line(const char *line)
{
    char want[600];
    snprintf(want, sizeof want, "\n%s\n", line);
    if (!strstr(text, want) && strncmp(text, want + 1, strlen(want + 1)) != 0) {
        print_error("line not in the exposition: %s\n--- exposition:\n%s", line, text);
        fail();
    }
}

static void test_render_lines(void **state)
{
    (void)state;
    fill_snapshot(&snap);
    render();
    char info[400];
    /* the stand's quote, backslash and newline escaped as the exposition format says */
    snprintf(info, sizeof info,
             "vibid_info{stand=\"rig \\\"A\\\\7\\\"\\nnew\",source=\"socketcan\",estimator=\"auto\",version=\"%s\"} 1",
             VIBID_VERSION_STRING);
    has_line(info);
    has_line("# HELP vibid_samples_total Samples given to the estimator.");
    has_line("# TYPE vibid_samples_total counter");
    has_line("vibid_samples_total 123456789012");
    has_line("vibid_running 1");
    has_line("vibid_uptime_seconds 12.5");
    has_line("vibid_stand_sample_rate_hertz 2000");
    has_line("vibid_sample_rate_hertz 1999.5");
    has_line("vibid_gaps_total 3");
    has_line("vibid_missing_samples_total 17");
    has_line("vibid_faults_total{kind=\"bad_line\"} 4");
    has_line("vibid_faults_total{kind=\"unknown_id\"} 0");
    has_line("vibid_ring_capacity 65536");
    has_line("vibid_ring_fill 12");
    has_line("vibid_ring_overflows_total 2");
    has_line("vibid_write_errors_total 5");
    has_line("vibid_torn_lines_total 1");
    has_line("vibid_outputs_closed 1");
    has_line("vibid_output_open_failures_total{output=\"tracks\"} 3");
    has_line("vibid_output_open_failures_total{output=\"record\"} 0");
    has_line("vibid_output_lost_records_total{output=\"tracks\"} 401");
    has_line("vibid_output_lost_records_total{output=\"record\"} 8017");
    assert_null(strstr(text, "output=\"influx\"")); /* not configured */
    has_line("vibid_rows_total 617");
    has_line("vibid_estimate_failures_total 1");
    has_line("vibid_implausible_rows_total 2");
    has_line("# TYPE vibid_outlier_samples_total counter");
    has_line("vibid_outlier_samples_total 5");
    has_line("vibid_alarms_raised_total 1");
    has_line("vibid_alarms_active 1");
    has_line("vibid_alarm_active{parameter=\"c1\"} 0");
    has_line("vibid_alarm_active{parameter=\"c2\"} 1");
    assert_null(strstr(text, "vibid_alarm_active{parameter=\"d\"}")); /* its alarm is off */
    /* the histogram: cumulative buckets in seconds, +Inf = count */
    has_line("# TYPE vibid_latency_seconds histogram");
    has_line("vibid_latency_seconds_bucket{le=\"1e-05\"} 0");
    has_line("vibid_latency_seconds_bucket{le=\"5e-05\"} 6");
    has_line("vibid_latency_seconds_bucket{le=\"0.0002\"} 9");
    has_line("vibid_latency_seconds_bucket{le=\"0.01\"} 9");
    has_line("vibid_latency_seconds_bucket{le=\"+Inf\"} 10");
    has_line("vibid_latency_seconds_sum 0.25");
    has_line("vibid_latency_seconds_count 10");
    has_line("# TYPE vibid_run_latency_seconds summary");
    has_line("vibid_run_latency_seconds{quantile=\"0.5\"} 5.75e-05");
    has_line("vibid_run_latency_seconds{quantile=\"0.99\"} NaN");
    /* the latest row: NaN, +Inf, -Inf as Prometheus spells them */
    has_line("vibid_last_row_index 4000");
    has_line("vibid_last_row_timestamp_seconds 1700000001.5");
    has_line("vibid_estimate{parameter=\"c1\"} 250000");
    has_line("vibid_estimate{parameter=\"d\"} NaN");
    has_line("vibid_estimate{parameter=\"c2\"} 0.1");
    has_line("vibid_estimate_standard_error{parameter=\"c1\"} 12.5");
    has_line("vibid_estimate_standard_error{parameter=\"d\"} +Inf");
    has_line("vibid_estimate_standard_error{parameter=\"c2\"} -Inf");
    has_line("vibid_natural_frequency_hertz{mode=\"1\"} 22.78");
    has_line("vibid_natural_frequency_hertz{mode=\"2\"} 48.15");
    has_line("vibid_damping_ratio{mode=\"1\"} 0.0653");
    has_line("vibid_row_flag{flag=\"G\"} 1");
    has_line("vibid_row_flag{flag=\"O\"} 1");
    has_line("vibid_row_flag{flag=\"E\"} 0");
    has_line("vibid_row_flag{flag=\"A\"} 1");
    has_line("vibid_metrics_scrapes_total 7");
    has_line("vibid_metrics_refused_total{reason=\"timeout\"} 2");
    has_line("vibid_metrics_refused_total{reason=\"bad_request\"} 0");
    /* every sample's family has HELP and TYPE before its first sample */
    char *copy = strdup(text), *save = NULL;
    char declared[200][80];
    size_t nd = 0, samples = 0;
    for (char *l = strtok_r(copy, "\n", &save); l; l = strtok_r(NULL, "\n", &save)) {
        char name[80];
        if (sscanf(l, "# TYPE %79s", name) == 1) {
            assert_true(nd < 200);
            snprintf(declared[nd++], sizeof declared[0], "%s", name);
            continue;
        }
        if (l[0] == '#')
            continue;
        size_t len = strcspn(l, "{ ");
        snprintf(name, sizeof name, "%.*s", (int)len, l);
        bool found = false;
        for (size_t i = 0; i < nd && !found; i++) {
            size_t fl = strlen(declared[i]);
            found = strncmp(name, declared[i], fl) == 0 &&
                    (name[fl] == '\0' || !strcmp(name + fl, "_bucket") || !strcmp(name + fl, "_sum") ||
                     !strcmp(name + fl, "_count"));
        }
        if (!found) {
            print_error("sample %s without a TYPE line before it\n", l);
            fail();
        }
        samples++;
    }
    free(copy);
    assert_true(samples > 80);
    /* the estimates' units: the stand's, or for an output-only configuration (oma) the
     * tracked modes' frequency in Hz and dimensionless damping ratio */
    assert_non_null(strstr(text, "# HELP vibid_estimate Latest estimate of the parameter, in the stand's units"));
    snap.oma_on = true;
    render();
    assert_non_null(strstr(text, "# HELP vibid_estimate Latest estimate of the tracked mode's quantity: f<j>_hz its "
                                 "natural frequency in Hz, zeta<j> its damping ratio (dimensionless)"));
    assert_null(strstr(text, "in the stand's units"));
    snap.oma_on = false;
    /* no row yet: no estimate families at all (not NaN series) */
    snap.have_last = false;
    snap.metrics_on = false;
    render();
    assert_null(strstr(text, "vibid_estimate{"));
    assert_null(strstr(text, "vibid_damping_ratio"));
    assert_null(strstr(text, "vibid_row_flag"));
    assert_null(strstr(text, "vibid_metrics_"));
    /* too small a buffer: refused, not cut */
    assert_int_equal(vd_metrics_render(text, 100, &snap), -1);
}

static void test_format(void **state)
{
    (void)state;
    char b[40];
    const struct {
        double v;
        const char *want;
    } cases[] = {{NAN, "NaN"},   {INFINITY, "+Inf"}, {-INFINITY, "-Inf"},      {0.0, "0"},
                 {0.1, "0.1"},   {-2.5e-7, "-2.5e-07"}, {1e300, "1e+300"}, {1.0 / 3.0, "0.33333333333333331"},
                 {2000.0, "2000"}};
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        vd_metrics_format_double(b, sizeof b, cases[i].v);
        assert_string_equal(b, cases[i].want);
    }
    char e[64];
    vd_metrics_escape_label(e, sizeof e, "a\\b\"c\nd");
    assert_string_equal(e, "a\\\\b\\\"c\\nd");
    /* cut to fit, never inside an escape: "ab" + "\\" does not fit 4 bytes */
    vd_metrics_escape_label(e, 4, "ab\\c");
    assert_string_equal(e, "ab");
}

static void test_parse_listen(void **state)
{
    (void)state;
    struct sockaddr_storage a;
    socklen_t len;
    char err[300];
    assert_int_equal(vd_metrics_parse_listen("127.0.0.1:18813", &a, &len, err, sizeof err), 0);
    assert_int_equal(a.ss_family, AF_INET);
    assert_int_equal(ntohs(((struct sockaddr_in *)&a)->sin_port), 18813);
    assert_int_equal(vd_metrics_parse_listen("localhost:0", &a, &len, err, sizeof err), 0);
    assert_int_equal(ntohl(((struct sockaddr_in *)&a)->sin_addr.s_addr), INADDR_LOOPBACK);
    assert_int_equal(vd_metrics_parse_listen("[::1]:9", &a, &len, err, sizeof err), 0);
    assert_int_equal(a.ss_family, AF_INET6);
    assert_int_equal(vd_metrics_parse_listen("0.0.0.0:80", &a, &len, err, sizeof err), 0);
    const struct {
        const char *text, *why;
    } bad[] = {{"127.0.0.1", "expected HOST:PORT"},          {":80", "expected HOST:PORT"},
               {"127.0.0.1:", "port '' outside"},            {"127.0.0.1:-1", "port '-1' outside"},
               {"127.0.0.1:8x", "port '8x' outside"},        {"host.example:80", "not an IPv4 address"},
               {"::1:80", "needs brackets"},                 {"[::1]80", "expected [IPv6]:PORT"},
               {"[fe80::zz]:80", "not an IPv6 address"},     {"256.1.1.1:80", "not an IPv4 address"}};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        assert_int_equal(vd_metrics_parse_listen(bad[i].text, &a, &len, err, sizeof err), -1);
        if (!strstr(err, bad[i].why) || !strstr(err, bad[i].text)) {
            print_error("'%s': got '%s', want '%s'\n", bad[i].text, err, bad[i].why);
            fail();
        }
    }
}

/* ------------------------------------------------------------ the endpoint ---- */

static int connect_to(const char *where)
{
    struct sockaddr_storage a;
    socklen_t len;
    char err[200];
    assert_int_equal(vd_metrics_parse_listen(where, &a, &len, err, sizeof err), 0);
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    assert_true(fd >= 0);
    assert_int_equal(connect(fd, (struct sockaddr *)&a, len), 0);
    return fd;
}

/* Sends req on a new connection and reads the answer until the server closes (bounded
 * by 5 s); the response into out. */
static void exchange(const char *where, const char *req, size_t req_len, char *out, size_t cap)
{
    int fd = connect_to(where);
    if (req_len)
        assert_int_equal(send(fd, req, req_len, MSG_NOSIGNAL), (ssize_t)req_len);
    size_t off = 0;
    for (;;) {
        struct pollfd p = {fd, POLLIN, 0};
        assert_int_equal(poll(&p, 1, 5000), 1);
        ssize_t n = recv(fd, out + off, cap - 1 - off, 0);
        if (n <= 0)
            break;
        off += (size_t)n;
    }
    out[off] = '\0';
    close(fd);
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void test_endpoint(void **state)
{
    (void)state;
    static vd_config cfg; /* only prometheus.listen is read */
    snprintf(cfg.prometheus.listen, sizeof cfg.prometheus.listen, "127.0.0.1:0");
    static vd_metrics m;
    char err[300];
    assert_int_equal(vd_metrics_open(&m, &cfg, err, sizeof err), 0);
    assert_int_equal(vd_metrics_start(&m, err, sizeof err), 0);
    static char resp[VD_METRICS_TEXT_MAX + 1024];
    /* before the first publish: 503, not an empty exposition */
    exchange(m.where, "GET /metrics HTTP/1.1\r\n\r\n", 25, resp, sizeof resp);
    assert_true(strncmp(resp, "HTTP/1.1 503 ", 13) == 0);
    fill_snapshot(&snap);
    assert_true(vd_metrics_publish(&m, &snap, false));
    render();
    const char *get = "GET /metrics HTTP/1.1\r\nHost: x\r\nAccept: */*\r\n\r\n";
    exchange(m.where, get, strlen(get), resp, sizeof resp);
    char head[300];
    snprintf(head, sizeof head,
             "HTTP/1.1 200 OK\r\nContent-Type: text/plain; version=0.0.4; charset=utf-8\r\nContent-Length: %zu\r\n",
             strlen(text));
    assert_true(strncmp(resp, head, strlen(head)) == 0);
    const char *body = strstr(resp, "\r\n\r\n");
    assert_non_null(body);
    assert_string_equal(body + 4, text); /* the published text, byte for byte */
    exchange(m.where, "GET /metrics?x=1 HTTP/1.0\n\n", 27, resp, sizeof resp); /* bare LF, a query */
    assert_true(strncmp(resp, "HTTP/1.1 200 ", 13) == 0);
    exchange(m.where, "GET / HTTP/1.1\r\n\r\n", 18, resp, sizeof resp);
    assert_true(strncmp(resp, "HTTP/1.1 200 ", 13) == 0 && strstr(resp, "href=\"/metrics\""));
    exchange(m.where, "GET /other HTTP/1.1\r\n\r\n", 23, resp, sizeof resp);
    assert_true(strncmp(resp, "HTTP/1.1 404 ", 13) == 0);
    exchange(m.where, "POST /metrics HTTP/1.1\r\n\r\n", 26, resp, sizeof resp);
    assert_true(strncmp(resp, "HTTP/1.1 405 ", 13) == 0 && strstr(resp, "Allow: GET, HEAD\r\n"));
    exchange(m.where, "HEAD /metrics HTTP/1.1\r\n\r\n", 26, resp, sizeof resp);
    assert_true(strncmp(resp, "HTTP/1.1 200 ", 13) == 0);
    assert_string_equal(strstr(resp, "\r\n\r\n"), "\r\n\r\n"); /* no body */
    /* garbage: 400 at once, without waiting for a blank line that never comes */
    double t0 = now_s();
    exchange(m.where, "\x16\x03\x01\x02\x00", 5, resp, sizeof resp); /* a TLS hello */
    assert_true(strncmp(resp, "HTTP/1.1 400 ", 13) == 0);
    exchange(m.where, "hello there\r\n", 13, resp, sizeof resp);
    assert_true(strncmp(resp, "HTTP/1.1 400 ", 13) == 0);
    assert_true(now_s() - t0 < 1.0);
    /* a request line longer than 8 KiB: 431 */
    static char big[VD_METRICS_REQUEST_MAX + 100];
    memset(big, 'a', sizeof big);
    memcpy(big, "GET /", 5);
    exchange(m.where, big, VD_METRICS_REQUEST_MAX, resp, sizeof resp);
    assert_true(strncmp(resp, "HTTP/1.1 431 ", 13) == 0);
    /* a peer that sends nothing: others are served meanwhile, it is closed at the deadline */
    int idle = connect_to(m.where);
    t0 = now_s();
    exchange(m.where, get, strlen(get), resp, sizeof resp);
    assert_true(strncmp(resp, "HTTP/1.1 200 ", 13) == 0);
    assert_true(now_s() - t0 < 0.5);
    struct pollfd p = {idle, POLLIN, 0};
    assert_int_equal(poll(&p, 1, 4000), 1);
    char c;
    assert_int_equal(recv(idle, &c, 1, 0), 0); /* closed, without a response */
    double dt = now_s() - t0;
    assert_true(dt > VD_METRICS_DEADLINE_S - 0.6 && dt < VD_METRICS_DEADLINE_S + 0.5);
    close(idle);
    /* more connections than slots: the oldest are evicted, a later scrape works */
    int many[3 * VD_METRICS_SLOTS];
    for (int i = 0; i < 3 * VD_METRICS_SLOTS; i++)
        many[i] = connect_to(m.where);
    usleep(200000);
    exchange(m.where, get, strlen(get), resp, sizeof resp);
    assert_true(strncmp(resp, "HTTP/1.1 200 ", 13) == 0);
    for (int i = 0; i < 3 * VD_METRICS_SLOTS; i++)
        close(many[i]);
    vd_snapshot counted;
    memset(&counted, 0, sizeof counted);
    vd_metrics_counters(&m, &counted);
    assert_true(counted.metrics_on);
    assert_int_equal(counted.scrapes, 5); /* the 200s of /metrics (GET and HEAD), not the 503 */
    assert_int_equal(counted.refused[VD_REFUSED_NOT_FOUND], 1);
    assert_int_equal(counted.refused[VD_REFUSED_METHOD], 1);
    assert_int_equal(counted.refused[VD_REFUSED_BAD_REQUEST], 2);
    assert_int_equal(counted.refused[VD_REFUSED_TOO_LARGE], 1);
    assert_int_equal(counted.refused[VD_REFUSED_TIMEOUT], 1);
    assert_true(counted.refused[VD_REFUSED_EVICTED] >= 2 * VD_METRICS_SLOTS);
    /* stopping is immediate even with connections open */
    int open_conn = connect_to(m.where);
    t0 = now_s();
    vd_metrics_close(&m);
    assert_true(now_s() - t0 < 0.2);
    close(open_conn);
    /* a second open of the same port works at once (SO_REUSEADDR), and the port is busy
     * while it is open: the error names the address and the errno text */
    static vd_metrics m2, m3;
    assert_int_equal(vd_metrics_open(&m2, &cfg, err, sizeof err), 0);
    snprintf(cfg.prometheus.listen, sizeof cfg.prometheus.listen, "%s", m2.where);
    assert_int_equal(vd_metrics_open(&m3, &cfg, err, sizeof err), -1);
    char want[200];
    snprintf(want, sizeof want, "outputs.prometheus.listen %s: cannot listen: Address already in use", m2.where);
    assert_string_equal(err, want);
    char note[300];
    assert_int_equal(vd_metrics_check(&cfg, note, sizeof note, err, sizeof err), 1);
    assert_non_null(strstr(note, "is in use now"));
    vd_metrics_close(&m3);
    vd_metrics_close(&m2);
    assert_int_equal(vd_metrics_check(&cfg, note, sizeof note, err, sizeof err), 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_render_lines),
        cmocka_unit_test(test_format),
        cmocka_unit_test(test_parse_listen),
        cmocka_unit_test(test_endpoint),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
