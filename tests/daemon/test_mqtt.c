/* Unit tests of the MQTT output (mqtt.h) without a broker: the JSON of a track row (exact
 * text; NaN and infinities as null; names and the site escaped), of an alarm event, of the
 * status (numbers stay numbers, nan becomes null, text becomes strings, the index from
 * last_index), the line-protocol payload with seq and dropped_before; the configuration
 * (defaults, URL forms, refusals naming the field); and the queue: with no broker a queue of
 * 5 takes 5 messages, drops and counts the rest, never waiting. */
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
#include <time.h>
#include <unistd.h>

#include "cfg_fixture.h"
#include "config.h"
#include "estimator.h"
#include "mqtt.h"

static vd_config cfg;

static int load(const char *name, const char *outputs, vd_config *c, vd_config_error *err) {
    return vd_test_load_outputs(name, outputs, c, err);
}

static int setup(void **state) {
    (void)state;
    vd_config_error err;
    int rc = load("base",
                  "outputs = { mqtt = { site = \"plant1\"; stand = \"rig1\"; queue_size = 5; "
                  "drain_timeout = 0.0; }; };",
                  &cfg, &err);
    if (rc) fprintf(stderr, "%s\n", err.text);
    /* a site with quotes: the configuration refuses it (names are of the safe set,
     * vibid/cfgread.h), the JSON writer escapes it all the same (defence in depth) */
    snprintf(cfg.mqtt.site, sizeof cfg.mqtt.site, "plant \"1\"");
    return rc;
}

static int teardown(void **state) {
    (void)state;
    vd_config_free(&cfg);
    return 0;
}

static vd_row sample_row(void) {
    vd_row r;
    memset(&r, 0, sizeof r);
    r.t_us = 1700000000123456LL;
    r.index = 42;
    double th[3] = {2.5e5, 300.0, 1.5e6}, se[3] = {12.5, INFINITY, NAN};
    for (int k = 0; k < 3; k++) {
        r.theta[k] = th[k];
        r.se[k] = se[k];
    }
    r.freq[0] = 22.7;
    r.freq[1] = 48.3;
    r.freq_se[0] = r.freq_se[1] = 0.01;
    r.zeta[0] = 0.065;
    r.zeta[1] = 0.0435;
    r.zeta_se[0] = r.zeta_se[1] = 1e-4;
    r.gap_samples = 3;
    r.flags = VD_FLAG_GAP | VD_FLAG_NOT_EXCITED;
    return r;
}

static void test_config(void **state) {
    (void)state;
    /* the defaults of the group */
    assert_string_equal(cfg.mqtt.url, "mqtt://127.0.0.1:1883");
    assert_string_equal(cfg.mqtt.host, "127.0.0.1");
    assert_int_equal(cfg.mqtt.port, 1883);
    assert_false(cfg.mqtt.tls);
    assert_string_equal(cfg.mqtt.prefix, "vibid/v1");
    assert_int_equal(cfg.mqtt.qos, 1);
    assert_int_equal(cfg.mqtt.keepalive, 30);
    assert_int_equal(cfg.mqtt.protocol, 5);
    assert_int_equal(cfg.mqtt.format, 0);
    vd_config c;
    vd_config_error err;
    /* no group: off */
    assert_int_equal(load("off", "", &c, &err), 0);
    assert_string_equal(c.mqtt.url, "");
    vd_config_free(&c);
    /* mqtts with an IPv6 literal and a port; relative files next to the configuration */
    assert_int_equal(
        load("tls",
             "outputs = { mqtt = { url = \"mqtts://[::1]:8884\"; site = \"p\"; username = \"u\"; "
             "password_file = \"pw\"; ca_file = \"ca.pem\"; protocol = \"3.1.1\"; format = \"line\"; }; };",
             &c, &err),
        0);
    assert_true(c.mqtt.tls);
    assert_string_equal(c.mqtt.host, "::1");
    assert_int_equal(c.mqtt.port, 8884);
    assert_int_equal(c.mqtt.protocol, 4);
    assert_int_equal(c.mqtt.format, 1);
    assert_string_equal(c.mqtt.password_file, "/tmp/pw");
    vd_config_free(&c);
    assert_int_equal(
        load("tlsdef", "outputs = { mqtt = { url = \"mqtts://broker.plant\"; site = \"p\"; }; };", &c, &err),
        0);
    assert_int_equal(c.mqtt.port, 8883);
    assert_string_equal(c.mqtt.host, "broker.plant");
    vd_config_free(&c);
    /* refusals name the field */
    static const struct {
        const char *outputs, *field, *sub;
    } bad[] = {
        {"outputs = { mqtt = { url = \"tcp://h:1883\"; site = \"p\"; }; };", "outputs.mqtt.url",
         "expected mqtt://"},
        {"outputs = { mqtt = { url = \"mqtt://h:0\"; site = \"p\"; }; };", "outputs.mqtt.url",
         "outside 1..65535"},
        {"outputs = { mqtt = { url = \"mqtt://h/x\"; site = \"p\"; }; };", "outputs.mqtt.url",
         "after the host"},
        {"outputs = { mqtt = { url = \"mqtt://\"; site = \"p\"; }; };", "outputs.mqtt.url", "no host"},
        {"outputs = { mqtt = { }; };", "outputs.mqtt.site", "missing"},
        {"outputs = { mqtt = { site = \"a/b\"; }; };", "outputs.mqtt.site", "contains '/'"},
        {"outputs = { mqtt = { site = \"a+\"; }; };", "outputs.mqtt.site", "contains '+'"},
        {"outputs = { mqtt = { site = \"p\"; stand = \"#\"; }; };", "outputs.mqtt.stand", "contains '#'"},
        {"outputs = { mqtt = { site = \"p\"; topic_prefix = \"/v1\"; }; };", "outputs.mqtt.topic_prefix",
         "e.g."},
        {"outputs = { mqtt = { site = \"p\"; topic_prefix = \"v1/a b\"; }; };", "outputs.mqtt.topic_prefix",
         "contains a space"},
        {"outputs = { mqtt = { site = \"p\"; client_id = \"id\\n2\"; }; };", "outputs.mqtt.client_id",
         "contains a line break"},
        {"outputs = { mqtt = { site = \"p\"; password_file = \"pw\"; }; };", "outputs.mqtt.password_file",
         "needs a username"},
        {"outputs = { mqtt = { site = \"p\"; ca_file = \"ca.pem\"; }; };", "outputs.mqtt", "mqtts://"},
        {"outputs = { mqtt = { url = \"mqtts://h\"; site = \"p\"; cert_file = \"c.pem\"; }; };",
         "outputs.mqtt", "both cert_file and key_file"},
        {"outputs = { mqtt = { site = \"p\"; qos = 0; }; };", "outputs.mqtt.qos", ""},
        {"outputs = { mqtt = { site = \"p\"; password = \"x\"; }; };", "outputs.mqtt.password",
         "unknown setting 'password'"},
        {"outputs = { mqtt = { site = \"p\"; format = \"xml\"; }; };", "outputs.mqtt.format", ""},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        int rc = load("bad", bad[i].outputs, &c, &err);
        if (rc == 0 || !strstr(err.text, bad[i].field) || !strstr(err.text, bad[i].sub))
            fail_msg("%s: rc %d, error '%s' (want %s ... %s)", bad[i].outputs, rc, err.text, bad[i].field,
                     bad[i].sub);
    }
    /* the printout reads back to the same configuration */
    char *p = NULL;
    size_t pn = 0;
    FILE *o = open_memstream(&p, &pn);
    /* as loaded (setup gives the site a quote only after loading: a configuration cannot) */
    static vd_config loaded;
    loaded = cfg;
    snprintf(loaded.mqtt.site, sizeof loaded.mqtt.site, "plant1");
    vd_config_print(&loaded, o);
    fclose(o);
    assert_non_null(strstr(p, "    url = \"mqtt://127.0.0.1:1883\";\n"));
    assert_non_null(strstr(p, "    queue_size = 5;\n"));
    char path[256];
    snprintf(path, sizeof path, "/tmp/vd_test_mqtt_%d_printed.cfg", (int)getpid());
    FILE *f = fopen(path, "w");
    fputs(p, f);
    fclose(f);
    vd_config c2;
    int rc = vd_config_load(path, &c2, &err);
    unlink(path);
    if (rc) fail_msg("printout does not read back: %s\n%s", err.text, p);
    assert_string_equal(c2.mqtt.site, "plant1");
    assert_int_equal(c2.mqtt.queue_size, 5);
    vd_config_free(&c2);
    free(p);
}

static void test_track_json(void **state) {
    (void)state;
    char buf[4096];
    vd_row r = sample_row();
    int n = vd_mqtt_format_track(buf, sizeof buf, &cfg, "rig1", 7, 2, &r);
    assert_true(n > 0);
    assert_string_equal(buf,
                        "{\"stand\":\"rig1\",\"site\":\"plant \\\"1\\\"\",\"seq\":7,\"index\":42,"
                        "\"time_s\":1700000000.123456,\"params\":{\"c1\":{\"value\":250000,\"se\":12.5},"
                        "\"d\":{\"value\":300,\"se\":null},\"c2\":{\"value\":1500000,\"se\":null}},"
                        "\"modes\":[{\"f_hz\":22.7,\"f_hz_se\":0.01,\"zeta\":0.065,\"zeta_se\":0.0001},"
                        "{\"f_hz\":48.3,\"f_hz_se\":0.01,\"zeta\":0.0435,\"zeta_se\":0.0001}],"
                        "\"gap_samples\":3,\"flags\":\"GI\",\"dropped_before\":2}");
    assert_int_equal(n, (int)strlen(buf));
    assert_int_equal(vd_mqtt_format_track(buf, 50, &cfg, "rig1", 7, 2, &r), -1); /* refused, not cut */
    /* a negative time */
    r.t_us = -1500000;
    assert_true(vd_mqtt_format_track(buf, sizeof buf, &cfg, "rig1", 1, 0, &r) > 0);
    assert_non_null(strstr(buf, "\"time_s\":-1.500000,"));
}

/* Issue 32: with covariate channels a "covariates" object follows the modes; an alarmed
 * parameter of the change test carries its statistic and minimum detectable change. */
static void test_track_json_monitoring(void **state) {
    (void)state;
    static vd_config c;
    c = cfg; /* a shallow copy: the same stand, not freed here */
    c.n_covariates = 1;
    c.cov_chan[0] = 1; /* the channel map's "s", as a covariate's name */
    c.alarms_enabled = true;
    c.alarm_test = VD_ALARM_CUSUM;
    for (size_t k = 0; k < c.n_params; k++)
        c.alarm_param[k].enabled = k == 2;
    vd_row r = sample_row();
    r.cov[0] = 21.5;
    r.change_stat[2] = 0.5;
    r.change_mdc[2] = 1200.0;
    char buf[4096];
    assert_true(vd_mqtt_format_track(buf, sizeof buf, &c, "rig1", 7, 2, &r) > 0);
    assert_non_null(strstr(buf, "\"c2\":{\"value\":1500000,\"se\":null,\"change_statistic\":0.5,\"mdc\":1200}}"));
    assert_non_null(strstr(buf, "\"d\":{\"value\":300,\"se\":null},")); /* not alarmed: no change fields */
    assert_non_null(strstr(buf, "}],\"covariates\":{\"s\":21.5},\"gap_samples\":3,"));
    r.cov[0] = NAN; /* no finite value in the row's block */
    assert_true(vd_mqtt_format_track(buf, sizeof buf, &c, "rig1", 7, 2, &r) > 0);
    assert_non_null(strstr(buf, "\"covariates\":{\"s\":null}"));
}

static void test_alarm_json(void **state) {
    (void)state;
    char buf[1024];
    vd_row r = sample_row();
    const vd_output_alarm a = {"c2", 1, &r, "cusum", 1.35e6, 1.5e6, NAN, 31.5, 30.25, -1.5e5, 1.25e4, 40};
    int n = vd_mqtt_format_alarm(buf, sizeof buf, &cfg, "rig1", 3, 0, &a);
    assert_true(n > 0);
    assert_string_equal(buf,
                        "{\"stand\":\"rig1\",\"site\":\"plant \\\"1\\\"\",\"seq\":3,\"index\":42,"
                        "\"time_s\":1700000000.123456,\"parameter\":\"c2\",\"state\":\"raised\","
                        "\"test\":\"cusum\",\"onset_index\":40,\"value\":1350000,\"baseline\":1500000,"
                        "\"z\":null,\"statistic\":31.5,\"threshold\":30.25,\"change\":-150000,"
                        "\"change_se\":12500,\"dropped_before\":0}");
    char s[64];
    assert_int_equal(vd_mqtt_json_string(s, sizeof s, "a\"b\\c\nd\x01"), 22);
    assert_string_equal(s, "\"a\\\"b\\\\c\\u000ad\\u0001\"");
}

static void test_status_json(void **state) {
    (void)state;
    const char *text =
        "state=running\nstand=paper_example1\nsamples=123\nsample_rate_hz=1999.5\n"
        "latency_us_p50=nan\nalarms_active=c1,c2\nlast_index=4000\nlast_time_s=1700000000.500000\n"
        "estimate.c1=2.5e+05\nweird=007\nminus=-0.5\nneg_inf=-inf\nempty=\n";
    char buf[2048];
    int n = vd_mqtt_format_status(buf, sizeof buf, &cfg, "rig1", 9, text, strlen(text));
    assert_true(n > 0);
    assert_string_equal(buf,
                        "{\"stand\":\"rig1\",\"site\":\"plant \\\"1\\\"\",\"seq\":9,\"index\":4000,"
                        "\"state\":\"running\",\"samples\":123,\"sample_rate_hz\":1999.5,"
                        "\"latency_us_p50\":null,\"alarms_active\":\"c1,c2\",\"last_index\":4000,"
                        "\"last_time_s\":1700000000.500000,\"estimate.c1\":2.5e+05,\"weird\":\"007\","
                        "\"minus\":-0.5,\"neg_inf\":null,\"empty\":\"\"}");
    /* before the first row: index null */
    n = vd_mqtt_format_status(buf, sizeof buf, &cfg, "rig1", 1, "state=running\n", 14);
    assert_string_equal(buf,
                        "{\"stand\":\"rig1\",\"site\":\"plant \\\"1\\\"\",\"seq\":1,\"index\":null,"
                        "\"state\":\"running\"}");
}

static uint64_t dropped(vd_mqtt *m, vd_snapshot *s) {
    memset(s, 0, sizeof *s);
    vd_mqtt_libmosquitto.counters(m, s);
    return (uint64_t)vd_snapshot_value(s, "mqtt_dropped");
}

/* No broker, no thread: the queue of 5 takes 5 rows; the others are dropped and counted, each
 * in microseconds (never a wait). */
static void test_queue_drops(void **state) {
    (void)state;
    char err[512];
    const vd_output_ctx ctx = {.cfg = &cfg};
    vd_mqtt *m = vd_mqtt_libmosquitto.open(&ctx, err, sizeof err);
    if (!m) fail_msg("open: %s", err);
    vd_row r = sample_row();
    vd_snapshot s;
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (int i = 0; i < 12; i++) {
        r.index = (uint64_t)i * 10;
        vd_mqtt_libmosquitto.row(m, &r);
    }
    vd_mqtt_libmosquitto.alarm(m, &(vd_output_alarm){"c2", 1, &r, "threshold", 1.0, 2.0, 3.0, 3.0, 5.0, -1.0, NAN, 42});
    clock_gettime(CLOCK_MONOTONIC, &t1);
    double dt = (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0.tv_nsec);
    assert_int_equal(dropped(m, &s), 8); /* 7 rows and the alarm */
    assert_int_equal(s.n_out_counters, 10); /* the output's ten counters and gauges, each once */
    assert_true(vd_snapshot_value(&s, "mqtt_connected") == 0.0);
    assert_true(vd_snapshot_value(&s, "mqtt_queue_fill") == 5.0);
    assert_true(vd_snapshot_value(&s, "mqtt_queue_capacity") == 5.0);
    assert_true(dt < 0.5);
    assert_true(vd_mqtt_libmosquitto.status(m, NULL, "state=running\n", 14, false));
    vd_mqtt_libmosquitto.close(m); /* never started: nothing to drain */
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_config),      cmocka_unit_test(test_track_json),
        cmocka_unit_test(test_track_json_monitoring),
        cmocka_unit_test(test_alarm_json),  cmocka_unit_test(test_status_json),
        cmocka_unit_test(test_queue_drops),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
