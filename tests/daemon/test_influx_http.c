/* Unit tests of the InfluxDB HTTP output (influx_http.h) without a server: the configuration
 * (defaults, v1/v2, refusals naming the field, the printout read back), the write URL with
 * its query values percent-encoded, what each HTTP status leads to, the dropped_before field
 * added to a line, and the buffer: with no writer thread a 1 MiB buffer takes exactly the
 * lines that fit and drops and counts the rest. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
/* cmocka.h needs the four above first */
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "cfg_fixture.h"
#include "config.h"
#include "estimator.h"
#include "influx_http.h"
#include "writers.h"

static int load(const char *name, const char *outputs, vd_config *c, vd_config_error *err) {
    return vd_test_load_outputs(name, outputs, c, err);
}

static vd_row sample_row(void) {
    vd_row r;
    memset(&r, 0, sizeof r);
    r.t_us = 1700000000123456LL;
    r.index = 42;
    double th[3] = {2.5e5, 300.0, 1.5e6}, se[3] = {12.5, 0.25, NAN};
    for (int k = 0; k < 3; k++) {
        r.theta[k] = th[k];
        r.se[k] = se[k];
    }
    r.freq[0] = 22.7;
    r.freq[1] = 48.3;
    r.zeta[0] = 0.065;
    r.zeta[1] = 0.0435;
    return r;
}

static void test_config(void **state) {
    (void)state;
    vd_config c;
    vd_config_error err;
    /* no group: off; the group alone: database vibid on loopback, API v1 */
    assert_int_equal(load("off", "", &c, &err), 0);
    assert_string_equal(c.influx_http.url, "");
    vd_config_free(&c);
    assert_int_equal(load("def", "outputs = { influx = { http = { }; }; };", &c, &err), 0);
    assert_string_equal(c.influx_http.url, "http://127.0.0.1:8086");
    assert_int_equal(c.influx_http.api, 1);
    assert_string_equal(c.influx_http.database, "vibid");
    assert_int_equal(c.influx_http.batch_lines, 5000);
    assert_true(c.influx_http.batch_interval_s == 1.0);
    assert_int_equal(c.influx_http.buffer_mib, 16);
    assert_true(c.influx_http.timeout_s == 10.0 && c.influx_http.drain_timeout_s == 10.0);
    /* the printout is a configuration that reads back the same */
    char path[256];
    snprintf(path, sizeof path, "/tmp/vd_test_influx_http_%d_print.cfg", (int)getpid());
    FILE *f = fopen(path, "w");
    vd_config_print(&c, f);
    fclose(f);
    vd_config c2;
    int rc = vd_config_load(path, &c2, &err);
    if (rc) fail_msg("printout does not read back: %s", err.text);
    assert_string_equal(c2.influx_http.url, c.influx_http.url);
    assert_string_equal(c2.influx_http.database, "vibid");
    assert_int_equal(c2.influx_http.buffer_mib, 16);
    vd_config_free(&c2);
    unlink(path);
    vd_config_free(&c);
    /* v2 with a base path (the trailing slash dropped), tags site and stand */
    assert_int_equal(load("v2",
                          "outputs = { influx = { site = \"plant1\"; stand = \"rig-7.b\"; http = { url = "
                          "\"https://h.example/influx/\"; api = \"v2\"; org = \"o\"; bucket = \"b\"; token_file = "
                          "\"tok\"; batch_size = 10; buffer_size = 1; }; }; };",
                          &c, &err),
                     0);
    assert_int_equal(c.influx_http.api, 2);
    assert_string_equal(c.influx_http.url, "https://h.example/influx");
    assert_string_equal(c.influx_http.token_file, "/tmp/tok");
    assert_string_equal(c.files.influx_site, "plant1");
    assert_string_equal(c.files.influx_stand, "rig-7.b");
    vd_config_free(&c);
    /* refusals name the field */
    static const struct {
        const char *outputs, *field, *sub;
    } bad[] = {
        {"outputs = { influx = { http = { url = \"ftp://h\"; }; }; };", "outputs.influx.http.url", "expected http"},
        {"outputs = { influx = { http = { url = \"http://u:p@h\"; }; }; };", "outputs.influx.http.url",
         "without a query, fragment or credentials"},
        {"outputs = { influx = { http = { url = \"http://h/?db=x\"; }; }; };", "outputs.influx.http.url", "query"},
        {"outputs = { influx = { http = { api = \"v3\"; }; }; };", "outputs.influx.http.api", "v1"},
        {"outputs = { influx = { http = { username = \"u\"; }; }; };", "outputs.influx.http.username",
         "needs its password_file"},
        {"outputs = { influx = { http = { password_file = \"p\"; }; }; };", "outputs.influx.http.password_file",
         "needs a username"},
        {"outputs = { influx = { http = { bucket = \"b\"; }; }; };", "outputs.influx.http", "belong to api = \"v2\""},
        {"outputs = { influx = { http = { api = \"v2\"; org = \"o\"; }; }; };", "outputs.influx.http",
         "needs org, bucket and token_file"},
        {"outputs = { influx = { http = { api = \"v2\"; org = \"o\"; bucket = \"b\"; token_file = \"t\"; database = "
         "\"d\"; }; }; };",
         "outputs.influx.http", "belong to api = \"v1\""},
        {"outputs = { influx = { http = { ca_file = \"ca.pem\"; }; }; };", "outputs.influx.http.ca_file",
         "https://"},
        {"outputs = { influx = { http = { batch_size = 0; }; }; };", "outputs.influx.http.batch_size", ""},
        {"outputs = { influx = { http = { buffer_size = 5000; }; }; };", "outputs.influx.http.buffer_size", ""},
        {"outputs = { influx = { http = { batchsize = 10; }; }; };", "outputs.influx.http.batchsize",
         "batch_size"},
        {"outputs = { influx = { http = \"http://h\"; }; };", "outputs.influx.http", "must be a group"},
        {"outputs = { influx = { site = \"a\\\\\"; }; };", "outputs.influx.site", "backslash"},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        memset(&err, 0, sizeof err);
        if (load("bad", bad[i].outputs, &c, &err) == 0) {
            vd_config_free(&c);
            fail_msg("accepted: %s", bad[i].outputs);
        }
        if (strcmp(err.field, bad[i].field) || !strstr(err.message, bad[i].sub))
            fail_msg("%s\n  -> field '%s', message '%s'", bad[i].outputs, err.field, err.message);
    }
}

static void test_write_url(void **state) {
    (void)state;
    vd_config c;
    memset(&c, 0, sizeof c);
    char buf[512];
    snprintf(c.influx_http.url, sizeof c.influx_http.url, "http://127.0.0.1:8086");
    c.influx_http.api = 1;
    snprintf(c.influx_http.database, sizeof c.influx_http.database, "vibid");
    int n = vd_influx_http_write_url(buf, sizeof buf, &c);
    assert_int_equal(n, (int)strlen(buf));
    assert_string_equal(buf, "http://127.0.0.1:8086/write?db=vibid&precision=ns");
    /* every reserved character percent-encoded (RFC 3986); the retention policy only when given */
    snprintf(c.influx_http.database, sizeof c.influx_http.database, "my db&x=1/ü");
    snprintf(c.influx_http.rp, sizeof c.influx_http.rp, "30d");
    assert_true(vd_influx_http_write_url(buf, sizeof buf, &c) > 0);
    assert_string_equal(buf, "http://127.0.0.1:8086/write?db=my%20db%26x%3D1%2F%C3%BC&rp=30d&precision=ns");
    c.influx_http.api = 2;
    snprintf(c.influx_http.url, sizeof c.influx_http.url, "https://cloud.example/base");
    snprintf(c.influx_http.org, sizeof c.influx_http.org, "plant 1");
    snprintf(c.influx_http.bucket, sizeof c.influx_http.bucket, "vibid/raw");
    assert_true(vd_influx_http_write_url(buf, sizeof buf, &c) > 0);
    assert_string_equal(buf, "https://cloud.example/base/api/v2/write?org=plant%201&bucket=vibid%2Fraw&precision=ns");
    /* too small: -1, never a cut URL */
    assert_int_equal(vd_influx_http_write_url(buf, 30, &c), -1);
}

static void test_verdicts(void **state) {
    (void)state;
    assert_int_equal(vd_influx_http_verdict_of(204), VD_IH_WRITTEN);
    assert_int_equal(vd_influx_http_verdict_of(200), VD_IH_WRITTEN);
    assert_int_equal(vd_influx_http_verdict_of(0), VD_IH_RETRY); /* no answer */
    long retry[] = {401, 403, 404, 408, 429, 500, 502, 503, 504, 301};
    for (size_t i = 0; i < sizeof retry / sizeof retry[0]; i++)
        assert_int_equal(vd_influx_http_verdict_of(retry[i]), VD_IH_RETRY);
    assert_int_equal(vd_influx_http_verdict_of(413), VD_IH_SPLIT);
    assert_int_equal(vd_influx_http_verdict_of(400), VD_IH_REJECTED);
    assert_int_equal(vd_influx_http_verdict_of(422), VD_IH_REJECTED);
    assert_int_equal(vd_influx_http_verdict_of(405), VD_IH_REJECTED);
}

static void test_add_fields(void **state) {
    (void)state;
    char buf[128] = "vibid,stand=a\\ b c1=1,flags=\"\" 1700000000000000000\n";
    int n = vd_influx_add_fields(buf, sizeof buf, (int)strlen(buf), "dropped_before=7i");
    assert_string_equal(buf, "vibid,stand=a\\ b c1=1,flags=\"\",dropped_before=7i 1700000000000000000");
    assert_int_equal(n, (int)strlen(buf));
    char small[60] = "vibid,stand=a c1=1,flags=\"\" 1700000000000000000\n";
    assert_int_equal(vd_influx_add_fields(small, sizeof small, (int)strlen(small), "dropped_before=7i"), -1);
    char nots[40] = "vibid";
    assert_int_equal(vd_influx_add_fields(nots, sizeof nots, (int)strlen(nots), "x=1i"), -1);
}

/* No thread: the buffer takes the lines that fit (8-byte header + line padded to 8) and
 * drops and counts the rest */
static void test_buffer_full(void **state) {
    (void)state;
    vd_config c;
    vd_config_error err;
    assert_int_equal(load("buf", "outputs = { influx = { http = { buffer_size = 1; }; }; };", &c, &err), 0);
    char e[256];
    const vd_output_ctx ctx = {.cfg = &c, .stand = "paper_example1"};
    vd_influx_http *h = vd_influx_http_curl.open(&ctx, e, sizeof e);
    if (!h) fail_msg("open: %s", e);
    vd_row r = sample_row();
    char line[2048];
    int n = vd_format_influx_row(line, sizeof line, &c, "paper_example1", &r);
    assert_true(n > 100);
    size_t rec = 8 + (((size_t)n + 7) & ~(size_t)7);
    size_t fit = (1u << 20) / rec;
    for (size_t i = 0; i < fit + 25; i++)
        vd_influx_http_curl.row(h, &r); /* the same row: every line the same length */
    vd_snapshot s;
    memset(&s, 0, sizeof s);
    vd_influx_http_curl.counters(h, &s);
    assert_int_equal(s.n_out_counters, 9); /* the output's nine counters and gauges, each once */
    assert_true(vd_snapshot_value(&s, "influx_http_ok") == 0.0);
    assert_true(vd_snapshot_value(&s, "influx_http_waiting") == (double)fit);
    assert_true(vd_snapshot_value(&s, "influx_http_dropped") == 25.0);
    assert_true(vd_snapshot_value(&s, "influx_http_buffer_fill") == (double)(fit * rec));
    assert_true(vd_snapshot_value(&s, "influx_http_buffer_capacity") == (double)(1u << 20));
    assert_true(vd_snapshot_value(&s, "influx_http_written") == 0.0);
    vd_influx_http_curl.close(h); /* never started: nothing to drain */
    vd_config_free(&c);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_config),     cmocka_unit_test(test_write_url),   cmocka_unit_test(test_verdicts),
        cmocka_unit_test(test_add_fields), cmocka_unit_test(test_buffer_full),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
