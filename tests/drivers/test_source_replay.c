/* Replay source: CSV and candump captures become exactly the expected records (values,
 * times, indices), every bad line / truncation / time jump is an explicit record with
 * file:line, and recorded-pace replay keeps to the recorded times. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>
#include <time.h>

#include <cmocka.h>
#include <vibid_drivers/candump.h>
#include <vibid_drivers/source_replay.h>

#include "support/drv_test_util.h"

static size_t read_all(vibid_source *s, vibid_record *out, size_t cap)
{
    size_t total = 0, n;
    vibid_drv_error err = {0};
    vibid_drv_status st;
    while ((st = vibid_source_read(s, out + total, cap - total < 7 ? cap - total : 7, &n, 1000, &err)) ==
               VIBID_DRV_OK ||
           st == VIBID_DRV_E_AGAIN) {
        total += n;
        assert_true(total < cap);
    }
    assert_int_equal(st, VIBID_DRV_E_EOF);
    return total;
}

static vibid_chanmap csv_map(bool with_time)
{
    vibid_chanmap m;
    memset(&m, 0, sizeof m);
    m.n = 2;
    strcpy(m.ch[0].name, "F");
    strcpy(m.ch[0].ref, "force");
    m.ch[0].source = VIBID_CHAN_COLUMN;
    m.ch[0].is_input = true;
    strcpy(m.ch[1].name, "x1");
    strcpy(m.ch[1].ref, "y1");
    m.ch[1].source = VIBID_CHAN_COLUMN;
    if (with_time)
        strcpy(m.time_column, "t");
    return m;
}

static void expect_text(const vibid_record *r, const char *needle)
{
    if (!strstr(r->text, needle))
        fail_msg("record text '%s' lacks '%s'", r->text, needle);
}

/* Time column, h = 1 ms: a 3-period jump -> GAP 2; a bad row and a non-increasing time
 * -> faults (the time steps make the gaps); the cut last row -> fault, no sample. */
static void test_csv_time_column(void **state)
{
    (void)state;
    static const char csv[] = "t,y1,force\n"  /* columns in another order than the map */
                              "0.000,1.5,10\n"   /* line 2: k=0 */
                              "0.001,2.5,11\n"   /* 3: k=1 */
                              "0.004,3.5,12\n"   /* 4: k=4, gap k=2..3 */
                              "0.005,x,13\n"     /* 5: bad row */
                              "0.004,9,9\n"      /* 6: time goes back */
                              "0.006,4.5,14\n"   /* 7: k=6, gap k=5 */
                              "0.007,5.5,1";     /* 8: truncated (no newline): not used */
    char path[512];
    assert_non_null(drv_write_tmp("cap.csv", csv, sizeof csv - 1, path, sizeof path));
    vibid_source_replay_config cfg;
    memset(&cfg, 0, sizeof cfg);
    cfg.path = path;
    cfg.chanmap = csv_map(true);
    cfg.sample_period_s = 1e-3;
    vibid_drv_error err = {0};
    vibid_source *s = vibid_source_open(&vibid_source_replay_ops, &cfg, &err);
    if (!s)
        fail_msg("%s", err.text);
    vibid_record r[32];
    size_t n = read_all(s, r, 32);
    assert_int_equal(n, 9);
    /* expected: S0 S1 GAP(2,2) S4 FAULT(line5) FAULT(line6) GAP(5,1) S6 FAULT(line8) */
    const vibid_record_kind kinds[] = {VIBID_REC_SAMPLE, VIBID_REC_SAMPLE, VIBID_REC_GAP, VIBID_REC_SAMPLE,
                                       VIBID_REC_FAULT,  VIBID_REC_FAULT,  VIBID_REC_GAP, VIBID_REC_SAMPLE,
                                       VIBID_REC_FAULT};
    for (size_t i = 0; i < n; i++)
        if (r[i].kind != kinds[i])
            fail_msg("record %zu: kind %d, expected %d (%s)", i, r[i].kind, kinds[i], r[i].text);
    assert_int_equal(r[0].index, 0);
    assert_true(r[0].values[0] == 10 && r[0].values[1] == 1.5 && r[0].t_ns == 0); /* map order: F, x1 */
    assert_true(r[1].values[0] == 11 && r[1].t_ns == 1000000);
    assert_int_equal(r[2].index, 2);
    assert_int_equal(r[2].count, 2);
    expect_text(&r[2], ":4: time step 0.003 s");
    assert_int_equal(r[3].index, 4);
    assert_true(r[3].values[1] == 3.5 && r[3].t_ns == 4000000);
    assert_int_equal(r[4].fault, VIBID_FAULT_BAD_LINE);
    expect_text(&r[4], "cap.csv:5: column 'y1': 'x' is not a number");
    expect_text(&r[5], "cap.csv:6: time 0.004 s does not increase");
    assert_int_equal(r[6].index, 5);
    assert_int_equal(r[6].count, 1);
    assert_int_equal(r[7].index, 6);
    assert_true(r[7].values[0] == 14 && r[7].values[1] == 4.5);
    expect_text(&r[8], "cap.csv:8: last line has no newline: truncated capture, row not used");
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    assert_int_equal(st.samples, 4);
    assert_int_equal(st.gaps, 2);
    assert_int_equal(st.missing_samples, 3);
    assert_int_equal(st.faults, 3);
    assert_int_equal(st.bad_lines, 3);
    assert_int_equal(st.lines, 8);
    vibid_source_close(s);
    unlink(path);
}

/* No time column: t_k = k h; a bad row is sample k missing (GAP 1); a truncated last
 * row that does not parse is a fault naming the truncation. */
static void test_csv_period_only(void **state)
{
    (void)state;
    static const char csv[] = "force,y1\n1,2\n3\n5,6\n7,";
    char path[512];
    assert_non_null(drv_write_tmp("p.CSV", csv, sizeof csv - 1, path, sizeof path));
    vibid_source_replay_config cfg;
    memset(&cfg, 0, sizeof cfg);
    cfg.path = path;
    cfg.chanmap = csv_map(false);
    vibid_drv_error err = {0};
    assert_null(vibid_source_open(&vibid_source_replay_ops, &cfg, &err));
    expect_text(&(vibid_record){.text = {0}}, "");
    assert_non_null(strstr(err.text, "the sample period must be given"));
    cfg.sample_period_s = 0.25;
    vibid_source *s = vibid_source_open(&vibid_source_replay_ops, &cfg, &err);
    assert_non_null(s);
    vibid_record r[16];
    size_t n = read_all(s, r, 16);
    assert_int_equal(n, 6);
    assert_true(r[0].kind == VIBID_REC_SAMPLE && r[0].t_ns == 0 && r[0].values[0] == 1 && r[0].values[1] == 2);
    assert_true(r[1].kind == VIBID_REC_FAULT && r[1].index == 1);
    assert_true(r[2].kind == VIBID_REC_GAP && r[2].index == 1 && r[2].count == 1);
    assert_true(r[3].kind == VIBID_REC_SAMPLE && r[3].index == 2 && r[3].t_ns == 500000000);
    assert_true(r[4].kind == VIBID_REC_FAULT);
    expect_text(&r[4], "p.CSV:5: column 'y1' is empty (truncated capture)");
    assert_true(r[5].kind == VIBID_REC_GAP && r[5].index == 3);
    vibid_source_close(s);
    /* a channel whose column is not in the header */
    cfg.chanmap.ch[1].line = 7;
    strcpy(cfg.chanmap.ch[1].ref, "nope");
    assert_null(vibid_source_open(&vibid_source_replay_ops, &cfg, &err));
    assert_non_null(strstr(err.text, "channel 'x1' (line 7): column 'nope' is not in the header of"));
    unlink(path);
    cfg.path = "/nonexistent/cap.csv";
    assert_null(vibid_source_open(&vibid_source_replay_ops, &cfg, &err));
    assert_non_null(strstr(err.text, "/nonexistent/cap.csv: cannot open"));
}

static const char dbc_text[] =
    "BO_ 256 A: 8 S\n SG_ Cnt : 0|8@1+ (1,0) [0|255] \"\" X\n SG_ F : 8|16@1- (0.01,0) [0|0] \"N\" X\n"
    "BO_ 257 B: 8 S\n SG_ Cnt : 0|8@1+ (1,0) [0|255] \"\" X\n SG_ X : 8|32@1- (1,0) [0|0] \"m\" X\n"
    "SIG_VALTYPE_ 257 X : 1;\n";

static vibid_chanmap can_map(void)
{
    vibid_chanmap m;
    memset(&m, 0, sizeof m);
    m.n = 2;
    strcpy(m.ch[0].name, "F");
    strcpy(m.ch[0].ref, "F");
    m.ch[0].is_input = true;
    strcpy(m.ch[1].name, "x");
    strcpy(m.ch[1].ref, "X");
    strcpy(m.counter, "Cnt");
    return m;
}

static size_t put_frame(char *buf, size_t cap, uint32_t id, uint8_t cnt, double v, int64_t t)
{
    vibid_can_frame f;
    memset(&f, 0, sizeof f);
    f.id = id;
    f.len = 8;
    f.t_ns = t;
    f.data[0] = cnt;
    if (id == 256) {
        int16_t r = (int16_t)lround(v / 0.01);
        f.data[1] = (uint8_t)(r & 0xFF);
        f.data[2] = (uint8_t)((uint16_t)r >> 8);
    } else {
        float x = (float)v;
        uint32_t u;
        memcpy(&u, &x, 4);
        for (int i = 0; i < 4; i++)
            f.data[1 + i] = (uint8_t)(u >> (8 * i));
    }
    int n = vibid_candump_format(buf, cap, &f, "can0");
    assert_true(n > 0 && (size_t)n + 1 < cap);
    buf[n] = '\n';
    return (size_t)n + 1;
}

/* 6 samples over two messages with counter; line 6 is garbage, a DROPCOUNT line, and the
 * last frame's line is cut (no newline): sample 5 becomes a GAP, never a sample with a
 * guessed value. */
static void test_candump(void **state)
{
    (void)state;
    vibid_drv_error err = {0};
    vibid_dbc *dbc = vibid_dbc_parse(dbc_text, sizeof dbc_text - 1, "t.dbc", &err);
    assert_non_null(dbc);
    char log[4096];
    size_t len = 0;
    const int64_t t0 = INT64_C(1700000000) * 1000000000, h = 1000000;
    for (int k = 0; k < 6; k++) {
        if (k == 2)
            len += (size_t)snprintf(log + len, sizeof log - len, "(1700000000.002000) can0 100#zz\n");
        if (k == 4)
            len += (size_t)snprintf(log + len, sizeof log - len,
                                    "DROPCOUNT: dropped 3 CAN frame(s) on 'can0' socket (total drops 3)\n");
        len += put_frame(log + len, sizeof log - len, 256, (uint8_t)k, 0.25 * k, t0 + k * h);
        len += put_frame(log + len, sizeof log - len, 257, (uint8_t)k, -1.5 * k, t0 + k * h + 200000);
    }
    len--; /* cut the final newline: the capture ends mid-write */
    char path[512];
    assert_non_null(drv_write_tmp("cap.log", log, len, path, sizeof path));
    vibid_source_replay_config cfg;
    memset(&cfg, 0, sizeof cfg);
    cfg.path = path;
    cfg.dbc = dbc;
    cfg.chanmap = can_map();
    vibid_source *s = vibid_source_open(&vibid_source_replay_ops, &cfg, &err);
    if (!s)
        fail_msg("%s", err.text);
    vibid_record r[32];
    size_t n = read_all(s, r, 32);
    /* S0 S1 FAULT(bad line 5) S2 S3 FAULT(dropped 3) S4 FAULT(truncated line 14) GAP(5) */
    assert_int_equal(n, 9);
    for (int k = 0; k < 2; k++) {
        assert_true(r[k].kind == VIBID_REC_SAMPLE && r[k].index == (uint64_t)k);
        assert_true(fabs(r[k].values[0] - 0.25 * k) < 1e-12 && r[k].values[1] == -1.5 * k);
        assert_true(r[k].t_ns == t0 + k * h); /* first frame's time, microsecond log */
    }
    assert_true(r[2].kind == VIBID_REC_FAULT && r[2].fault == VIBID_FAULT_BAD_LINE);
    expect_text(&r[2], "cap.log:5:");
    assert_true(r[3].kind == VIBID_REC_SAMPLE && r[3].index == 2);
    assert_true(r[4].kind == VIBID_REC_SAMPLE && r[4].index == 3);
    assert_true(r[5].kind == VIBID_REC_FAULT && r[5].fault == VIBID_FAULT_DROPPED && r[5].count == 3);
    expect_text(&r[5], "DROPCOUNT at");
    expect_text(&r[5], "cap.log:10");
    assert_true(r[6].kind == VIBID_REC_SAMPLE && r[6].index == 4 && r[6].values[1] == -6.0);
    assert_true(r[7].kind == VIBID_REC_FAULT && r[7].fault == VIBID_FAULT_BAD_LINE);
    expect_text(&r[7], "cap.log:14: last line has no newline: truncated capture, frame not used");
    assert_true(r[8].kind == VIBID_REC_GAP && r[8].index == 5 && r[8].count == 1);
    expect_text(&r[8], "missing B");
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    assert_int_equal(st.samples, 5);
    assert_int_equal(st.frames, 11); /* 12 frames, the cut one not pushed */
    assert_int_equal(st.dropped, 3);
    assert_int_equal(st.bad_lines, 2);
    assert_int_equal(st.lines, 14);
    vibid_source_close(s);
    unlink(path);
    vibid_dbc_destroy(dbc);
}

static int64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

/* 21 samples 10 ms apart at recorded pace take 200 ms (speed 1) and 100 ms (speed 2).
 * Lower bound exact (absolute deadlines never release early); upper bound +150 ms for
 * a loaded shared CI machine. At speed 1 a 5 ms read timeout returns AGAIN between samples. */
static void test_paced(void **state)
{
    (void)state;
    char csv[2048];
    size_t len = (size_t)snprintf(csv, sizeof csv, "t,force,y1\n");
    for (int k = 0; k <= 20; k++)
        len += (size_t)snprintf(csv + len, sizeof csv - len, "%.3f,%d,%d\n", 100.0 + 0.01 * k, k, -k);
    char path[512];
    assert_non_null(drv_write_tmp("paced.csv", csv, len, path, sizeof path));
    for (int speed = 1; speed <= 2; speed++) {
        vibid_source_replay_config cfg;
        memset(&cfg, 0, sizeof cfg);
        cfg.path = path;
        cfg.chanmap = csv_map(true);
        cfg.paced = true;
        cfg.speed = speed;
        vibid_drv_error err = {0};
        vibid_source *s = vibid_source_open(&vibid_source_replay_ops, &cfg, &err);
        assert_non_null(s);
        vibid_record r[8];
        size_t n, samples = 0, agains = 0;
        int64_t t0 = now_ns();
        vibid_drv_status st;
        while ((st = vibid_source_read(s, r, 8, &n, 5, &err)) != VIBID_DRV_E_EOF) {
            if (st == VIBID_DRV_E_AGAIN)
                agains++;
            else
                assert_int_equal(st, VIBID_DRV_OK);
            samples += n;
        }
        double el = (double)(now_ns() - t0) * 1e-9;
        double want = 0.2 / speed;
        if (samples != 21 || el < want - 1e-4 || el > want + 0.15 || (speed == 1 && agains < 10))
            fail_msg("speed %d: %zu samples in %.4f s (want 21 in %.3f s), %zu AGAIN", speed, samples, el, want,
                     agains);
        print_message("paced speed %d: 21 samples in %.4f s (recorded %.3f s), %zu timeouts\n", speed, el, want,
                      agains);
        vibid_source_close(s);
    }
    unlink(path);
}

/* As fast as possible: 200,000 samples from a candump log; every one delivered, in
 * order (the figure is printed, not asserted). */
static void test_fast_throughput(void **state)
{
    (void)state;
    vibid_drv_error err = {0};
    vibid_dbc *dbc = vibid_dbc_parse(dbc_text, sizeof dbc_text - 1, "t.dbc", &err);
    char path[512];
    assert_non_null(drv_write_tmp("big.log", "", 0, path, sizeof path));
    FILE *f = fopen(path, "w");
    assert_non_null(f);
    const int N = 200000;
    char line[256];
    for (int k = 0; k < N; k++) {
        size_t n = put_frame(line, sizeof line, 256, (uint8_t)k, 0.01 * (k % 100), INT64_C(1700000000000000000) + k * 1000000LL);
        fwrite(line, 1, n, f);
        n = put_frame(line, sizeof line, 257, (uint8_t)k, k, INT64_C(1700000000000000000) + k * 1000000LL + 1000);
        fwrite(line, 1, n, f);
    }
    fclose(f);
    vibid_source_replay_config cfg;
    memset(&cfg, 0, sizeof cfg);
    cfg.path = path;
    cfg.dbc = dbc;
    cfg.chanmap = can_map();
    vibid_source *s = vibid_source_open(&vibid_source_replay_ops, &cfg, &err);
    assert_non_null(s);
    static vibid_record r[256];
    size_t n;
    uint64_t next = 0;
    int64_t t0 = now_ns();
    while (vibid_source_read(s, r, 256, &n, 0, &err) == VIBID_DRV_OK)
        for (size_t i = 0; i < n; i++) {
            if (r[i].kind != VIBID_REC_SAMPLE || r[i].index != next || r[i].values[1] != (double)(float)next)
                fail_msg("record %llu: kind %d index %llu", (unsigned long long)next, r[i].kind,
                         (unsigned long long)r[i].index);
            next++;
        }
    double el = (double)(now_ns() - t0) * 1e-9;
    assert_int_equal(next, (uint64_t)N);
    print_message("replay: %d samples (%d frames) in %.3f s = %.0f samples/s\n", N, 2 * N, el, N / el);
    vibid_source_close(s);
    vibid_dbc_destroy(dbc);
    unlink(path);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_csv_time_column), cmocka_unit_test(test_csv_period_only),
        cmocka_unit_test(test_candump),         cmocka_unit_test(test_paced),
        cmocka_unit_test(test_fast_throughput),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
