/* Unit tests of the output formats (writers.h): tracks CSV header and rows, InfluxDB
 * line protocol (escaping, no NaN fields, ns timestamps), raw recording rows (exact
 * round trip), microsecond rounding of times, and the estimator's gap handling; the file
 * outputs reopened each on its own (a failed reopen counted and retried). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <sys/stat.h>

#include "cfg_fixture.h"
#include "config.h"
#include "estimator.h"
#include "writers.h"

static vd_config cfg;

static int setup(void **state)
{
    (void)state;
    char path[256];
    snprintf(path, sizeof path, "/tmp/vd_test_writers_%d.cfg", (int)getpid());
    FILE *f = fopen(path, "w");
    fprintf(f, "stand = \"%s/examples/stands/paper_example1.cfg\";\n"
               "source = { kind = \"replay\"; file = \"x.csv\"; time_column = \"t\";\n"
               " channels = ( { name = \"x1\"; quantity = \"displacement\"; node = 0; column = \"x1\"; },\n"
               "  { name = \"s\"; quantity = \"base_displacement\"; node = 0; column = \"s\"; },\n"
               "  { name = \"x2\"; quantity = \"displacement\"; node = 1; column = \"x2\"; } ); };\n"
               "estimator = { decimation = 10; };\n",
            VD_SOURCE_DIR);
    fclose(f);
    vd_config_error err;
    int rc = vd_config_load(path, &cfg, &err);
    unlink(path);
    if (rc)
        fprintf(stderr, "%s\n", err.text);
    return rc;
}

static int teardown(void **state)
{
    (void)state;
    vd_config_free(&cfg);
    return 0;
}

static void test_tracks_header(void **state)
{
    (void)state;
    char buf[1024];
    int n = vd_format_tracks_header(buf, sizeof buf, &cfg);
    assert_true(n > 0);
    assert_string_equal(buf, "time_s,index,c1,c1_se,d,d_se,c2,c2_se,f1_hz,f1_hz_se,zeta1,zeta1_se,f2_hz,f2_hz_se,"
                             "zeta2,zeta2_se,gap_samples,flags\n");
    assert_int_equal(vd_format_tracks_header(buf, 20, &cfg), -1); /* too small: refused, not cut */
}

static vd_row sample_row(void)
{
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
    r.freq_se[0] = r.freq_se[1] = 0.01;
    r.zeta[0] = 0.065;
    r.zeta[1] = 0.0435;
    r.zeta_se[0] = r.zeta_se[1] = 1e-4;
    r.gap_samples = 3;
    r.flags = VD_FLAG_GAP | VD_FLAG_ALARM;
    return r;
}

static void test_track_row(void **state)
{
    (void)state;
    vd_row r = sample_row();
    char buf[1024];
    assert_true(vd_format_track_row(buf, sizeof buf, &cfg, &r) > 0);
    assert_string_equal(buf, "1700000000.123456,42,250000,12.5,300,0.25,1500000,nan,22.7,0.01,0.065,0.0001,48.3,0.01,"
                             "0.0435,0.0001,3,GA\n");
    r.t_us = -1500000; /* before the epoch: -1.500000 */
    r.flags = VD_FLAG_NOEST;
    assert_true(vd_format_track_row(buf, sizeof buf, &cfg, &r) > 0);
    assert_true(strncmp(buf, "-1.500000,42,", 13) == 0);
    assert_non_null(strstr(buf, ",3,E\n"));
    /* a physically impossible estimate: P, between E's place and A */
    r.flags = VD_FLAG_GAP | VD_FLAG_IMPLAUSIBLE | VD_FLAG_ALARM;
    assert_true(vd_format_track_row(buf, sizeof buf, &cfg, &r) > 0);
    assert_non_null(strstr(buf, ",3,GPA\n"));
    r.flags = VD_FLAG_IMPLAUSIBLE;
    assert_true(vd_format_influx_row(buf, sizeof buf, &cfg, "s", &r) > 0);
    assert_non_null(strstr(buf, ",flags=\"P\" "));
}

static void test_influx(void **state)
{
    (void)state;
    vd_row r = sample_row();
    char buf[2048];
    assert_true(vd_format_influx_row(buf, sizeof buf, &cfg, "stand one,a=b", &r) > 0);
    /* tag escaping; c2_se (NaN) left out; integer fields with i; ns timestamp */
    assert_string_equal(buf, "vibid,stand=stand\\ one\\,a\\=b c1=250000,c1_se=12.5,d=300,d_se=0.25,c2=1500000,"
                             "f1_hz=22.7,f1_hz_se=0.01,zeta1=0.065,zeta1_se=0.0001,f2_hz=48.3,f2_hz_se=0.01,"
                             "zeta2=0.0435,zeta2_se=0.0001,index=42i,gap_samples=3i,flags=\"GA\" "
                             "1700000000123456000\n");
    /* a change-test event: every field; a threshold-rule event leaves change_se (NaN) out */
    const vd_output_alarm raised = {"c2", 1, &r, "cusum", 1.35e6, 1.5e6, -12.0, 31.5, 30.25, -1.5e5, 1.25e4, 40};
    assert_true(vd_format_influx_alarm(buf, sizeof buf, &cfg, "s", &raised) > 0);
    assert_string_equal(buf, "vibid_alarm,parameter=c2,stand=s state=\"raised\",test=\"cusum\",onset_index=40i,"
                             "index=42i,value=1350000,baseline=1500000,z=-12,statistic=31.5,threshold=30.25,"
                             "change=-150000,change_se=12500 1700000000123456000\n");
    /* outputs.influx.site: a tag of its own, escaped, tags in key order */
    vd_config with_site = cfg;
    snprintf(with_site.files.influx_site, sizeof with_site.files.influx_site, "plant 1");
    assert_true(vd_format_influx_row(buf, sizeof buf, &with_site, "s", &r) > 0);
    assert_true(!strncmp(buf, "vibid,site=plant\\ 1,stand=s c1=250000,", 38));
    const vd_output_alarm cleared = {"c2", 0, &r, "threshold", 1.35e6, 1.5e6, 12.0, 12.0, 5.0, -1.5e5, NAN, 42};
    assert_true(vd_format_influx_alarm(buf, sizeof buf, &with_site, "s", &cleared) > 0);
    assert_non_null(strstr(buf, "z=12,statistic=12,threshold=5,change=-150000 1700000000123456000"));
    assert_true(!strncmp(buf, "vibid_alarm,parameter=c2,site=plant\\ 1,stand=s state=\"cleared\",", 63));
    /* a refinement's row: a series of its own (estimate=refined, tags in key order), so that it
     * does not overwrite a recursive row of the same sample */
    r.flags = VD_FLAG_REFINED;
    assert_true(vd_format_influx_row(buf, sizeof buf, &with_site, "s", &r) > 0);
    assert_true(!strncmp(buf, "vibid,estimate=refined,site=plant\\ 1,stand=s c1=250000,", 55));
    assert_non_null(strstr(buf, ",flags=\"W\" "));
}

static void test_recording_roundtrip(void **state)
{
    (void)state;
    vibid_record rec;
    memset(&rec, 0, sizeof rec);
    rec.kind = VIBID_REC_SAMPLE;
    rec.t_ns = 1700000000123456789LL; /* rounds to ...123457 us */
    rec.n_values = 3;
    rec.values[0] = 0.1;
    rec.values[1] = -1.2345678901234567e-7;
    rec.values[2] = 1.0 / 3.0;
    char buf[512];
    assert_true(vd_format_recording_row(buf, sizeof buf, &rec) > 0);
    assert_true(strncmp(buf, "1700000000.123457,", 18) == 0);
    /* every value reads back to the same double */
    char *p = strchr(buf, ',') + 1;
    for (int i = 0; i < 3; i++) {
        char *end;
        double v = strtod(p, &end);
        assert_true(v == rec.values[i]);
        p = end + 1;
    }
    char hdr[256];
    assert_true(vd_format_recording_header(hdr, sizeof hdr, "st", 2000.0, &cfg.chanmap) > 0);
    assert_true(strncmp(hdr, VD_RECORDING_MAGIC, strlen(VD_RECORDING_MAGIC)) == 0);
    assert_non_null(strstr(hdr, "\nt,x1,s,x2\n"));
}

static void test_ns_to_us(void **state)
{
    (void)state;
    assert_int_equal(vd_ns_to_us(1499), 1);
    assert_int_equal(vd_ns_to_us(1500), 2);
    assert_int_equal(vd_ns_to_us(-1499), -1);
    assert_int_equal(vd_ns_to_us(-1501), -2);
    assert_int_equal(vd_ns_to_us(0), 0);
}

/* Feeds rec through the outlier test and the estimator (as vibidd's process does);
 * finishes every row that comes due at once. Appends the rows to idx/flags/gaps. */
static void est_feed(vd_est *e, const vibid_record *rec, int *rows, uint64_t *idx, unsigned *flags, uint64_t *gaps)
{
    if (rec)
        vd_est_feed(e, rec, 0);
    else
        vd_est_flush(e);
    const vibid_record *r;
    int64_t tag;
    vd_row row;
    while ((r = vd_est_next(e, &tag))) {
        if (vd_est_record(e, r, &row)) {
            vd_est_finish_row(e, &row);
            idx[*rows] = row.index;
            flags[*rows] = row.flags;
            gaps[*rows] = row.gap_samples;
            (*rows)++;
        }
    }
}

/* Estimator: a gap restarts the difference window, is counted and flagged in the next
 * row; rows are due every `decimation` indices, also across a gap. A glitch is taken out
 * (counted, flagged O), not counted as a non-finite sample. */
static void test_estimator_gap(void **state)
{
    (void)state;
    vd_est e;
    char err[512];
    assert_int_equal(vd_est_init(&e, &cfg, err, sizeof err), 0);
    assert_non_null(e.outl); /* the default: the outlier test on */
    vibid_record rec;
    memset(&rec, 0, sizeof rec);
    rec.n_values = 3;
    int rows = 0;
    uint64_t idx[16];
    unsigned flags[16];
    uint64_t gaps[16];
    for (uint64_t k = 100; k < 160; k++) {
        if (k >= 125 && k < 128) { /* 3 samples missing */
            if (k == 125) {
                rec.kind = VIBID_REC_GAP;
                rec.index = 125;
                rec.count = 3;
                est_feed(&e, &rec, &rows, idx, flags, gaps);
            }
            continue;
        }
        rec.kind = VIBID_REC_SAMPLE;
        rec.index = k;
        rec.t_ns = (int64_t)k * 500000;
        double t = (double)k * 5e-4;
        rec.values[0] = 1e-3 * sin(140 * t);
        rec.values[1] = 1e-3 * sin(31 * t);
        rec.values[2] = 1e-3 * sin(300 * t);
        if (k == 145)
            rec.values[1] = 1e300; /* a glitch */
        est_feed(&e, &rec, &rows, idx, flags, gaps);
    }
    est_feed(&e, NULL, &rows, idx, flags, gaps);
    /* index relative to the first record (100): rows at 9, 19 (in time), 29 (after the gap) ... */
    assert_int_equal(rows, 6);
    assert_int_equal(idx[0], 9);
    assert_int_equal(idx[1], 19);
    assert_int_equal(idx[2], 29);
    assert_int_equal(gaps[2], 3);
    assert_true(flags[2] & VD_FLAG_GAP);
    assert_int_equal(gaps[3], 0);
    assert_false(flags[3] & VD_FLAG_GAP);
    assert_false(flags[3] & VD_FLAG_OUTLIER);
    assert_true(flags[4] & VD_FLAG_OUTLIER); /* row 49 covers sample 45 */
    assert_false(flags[5] & VD_FLAG_OUTLIER);
    assert_int_equal(e.outliers, 1);
    assert_int_equal(e.push_errors, 0);
    assert_int_equal(e.gaps, 1);
    assert_int_equal(e.missing, 3);
    /* an index jump without a GAP record (ring overflow) is a gap too */
    rec.kind = VIBID_REC_SAMPLE;
    rec.index = 170;
    est_feed(&e, &rec, &rows, idx, flags, gaps);
    est_feed(&e, NULL, &rows, idx, flags, gaps);
    assert_int_equal(e.gaps, 2);
    assert_int_equal(e.missing, 13);
    vd_est_free(&e);
}

/* Lines of a file (0 if it is not there) */
static int file_lines(const char *dir, const char *name)
{
    char p[512];
    snprintf(p, sizeof p, "%s/%s", dir, name);
    FILE *f = fopen(p, "r");
    if (!f)
        return 0;
    int n = 0, ch;
    while ((ch = fgetc(f)) != EOF)
        n += ch == '\n';
    fclose(f);
    return n;
}

/* Issue 30 item 1: logrotate moved the three files away and left a directory where the
 * tracks were. The SIGHUP reopen leaves the tracks closed (counted, retried) and reopens the
 * others; the rows the tracks miss are counted; the retry opens them once the path is free. */
static void test_reopen_each_on_its_own(void **state)
{
    (void)state;
    char dir[] = "/tmp/vd_test_reopen_XXXXXX", outs[1024], p[600], q[600];
    assert_non_null(mkdtemp(dir));
    snprintf(outs, sizeof outs,
             "outputs = { tracks = { path = \"%s/t.csv\"; }; influx = { path = \"%s/i.lp\"; };\n"
             " record = { path = \"%s/r.csv\"; }; };",
             dir, dir, dir);
    vd_config c;
    vd_config_error ce;
    assert_int_equal(vd_test_load_outputs("reopen", outs, &c, &ce), 0);
    static vd_writers w;
    char err[1200];
    assert_int_equal(vd_writers_open(&w, &c, &c.chanmap, NULL, err, sizeof err), 0);
    vd_row row;
    memset(&row, 0, sizeof row);
    row.index = 10;
    vibid_record rec;
    memset(&rec, 0, sizeof rec);
    rec.kind = VIBID_REC_SAMPLE;
    rec.n_values = 3;
    vd_writers_row(&w, &row);
    vd_writers_sample(&w, &rec);
    const char *const names[3] = {"t.csv", "i.lp", "r.csv"};
    for (int k = 0; k < 3; k++) {
        snprintf(p, sizeof p, "%s/%s", dir, names[k]);
        snprintf(q, sizeof q, "%s/%s.1", dir, names[k]);
        assert_int_equal(rename(p, q), 0);
    }
    snprintf(p, sizeof p, "%s/t.csv", dir);
    assert_int_equal(mkdir(p, 0700), 0);
    assert_int_equal(vd_writers_reopen(&w), 1); /* one output left closed */
    assert_int_equal(vd_writers_closed(&w), 1);
    assert_true(w.out[VD_OUT_TRACKS].closed && !w.out[VD_OUT_TRACKS].f);
    assert_non_null(w.out[VD_OUT_INFLUX].f);
    assert_non_null(w.out[VD_OUT_RECORD].f);
    assert_int_equal(w.out[VD_OUT_TRACKS].open_failures, 1);
    assert_int_equal(w.write_errors, 1);
    for (int i = 0; i < 5; i++) {
        vd_writers_row(&w, &row);
        vd_writers_sample(&w, &rec);
    }
    assert_int_equal(w.out[VD_OUT_TRACKS].lost, 5);
    assert_int_equal(w.out[VD_OUT_INFLUX].lost, 0);
    assert_int_equal(w.out[VD_OUT_RECORD].lost, 0);
    vd_writers_flush(&w, 0); /* its retry is not due yet (1 s): still closed, nothing counted */
    assert_true(w.out[VD_OUT_TRACKS].closed);
    assert_int_equal(w.out[VD_OUT_TRACKS].open_failures, 1);
    /* the retry when due (the test sets the time instead of waiting the second) and the path is
     * a directory still: a second failure, the back-off doubled */
    w.out[VD_OUT_TRACKS].retry_at = 0;
    vd_writers_flush(&w, 0);
    assert_int_equal(w.out[VD_OUT_TRACKS].open_failures, 2);
    assert_true(w.out[VD_OUT_TRACKS].backoff == 2.0);
    assert_int_equal(rmdir(p), 0);
    w.out[VD_OUT_TRACKS].retry_at = 0;
    vd_writers_flush(&w, 0);
    assert_false(w.out[VD_OUT_TRACKS].closed);
    assert_int_equal(vd_writers_closed(&w), 0);
    vd_writers_row(&w, &row);
    vd_writers_close(&w);
    assert_int_equal(w.write_errors, 2);
    assert_int_equal(w.out[VD_OUT_TRACKS].lost, 5);
    /* header line + 1 row before, header + 1 row after; every InfluxDB line and sample kept */
    assert_int_equal(file_lines(dir, "t.csv.1"), 2);
    assert_int_equal(file_lines(dir, "t.csv"), 2);
    assert_int_equal(file_lines(dir, "i.lp.1") + file_lines(dir, "i.lp"), 7);
    assert_int_equal(file_lines(dir, "r.csv.1") + file_lines(dir, "r.csv"), 2 * 2 + 6); /* 2 headers each */
    for (int k = 0; k < 3; k++) {
        snprintf(p, sizeof p, "%s/%s", dir, names[k]);
        snprintf(q, sizeof q, "%s/%s.1", dir, names[k]);
        unlink(p);
        unlink(q);
    }
    rmdir(dir);
    vd_config_free(&c);
}

/* The flag letters: one spelling for every output, in the documented order. */
static void test_flag_letters(void **state)
{
    (void)state;
    char l[VD_FLAG_LETTERS_MAX];
    vd_flag_letters(VD_FLAG_GAP | VD_FLAG_OUTLIER | VD_FLAG_IMPLAUSIBLE | VD_FLAG_SE_INVALID | VD_FLAG_NOT_EXCITED |
                        VD_FLAG_ALARM,
                    l);
    assert_string_equal(l, "GOPUIA");
    /* every letter at once: W (a refinement) last */
    vd_flag_letters(VD_FLAG_GAP | VD_FLAG_OUTLIER | VD_FLAG_NOEST | VD_FLAG_IMPLAUSIBLE | VD_FLAG_SE_INVALID |
                        VD_FLAG_NOT_EXCITED | VD_FLAG_ALARM | VD_FLAG_COVARIATE | VD_FLAG_REFINED,
                    l);
    assert_string_equal(l, "GOEPUIACW");
    vd_flag_letters(VD_FLAG_NOEST | VD_FLAG_OUTLIER, l);
    assert_string_equal(l, "OE");
    vd_flag_letters(0, l);
    assert_string_equal(l, "");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_tracks_header), cmocka_unit_test(test_track_row),
        cmocka_unit_test(test_influx),        cmocka_unit_test(test_recording_roundtrip),
        cmocka_unit_test(test_ns_to_us),      cmocka_unit_test(test_estimator_gap),
        cmocka_unit_test(test_reopen_each_on_its_own),
        cmocka_unit_test(test_flag_letters),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
