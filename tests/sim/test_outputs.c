/* sim.outputs: vibid-sim's files read back with the drivers' readers (CSV reader,
 * candump reader, DBC decoder, CAN sample assembler), fault options measured, the
 * live-CAN failure message, and command-line / stand-file errors. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>
#include <sys/wait.h>

#include <vibid_drivers/can_assembler.h>
#include <vibid_drivers/candump.h>
#include <vibid_drivers/csv_capture.h>
#include <vibid_drivers/dbc.h>

#include "sim_config.h"
#include "sim_engine.h"
#include "sim_test_util.h"

#define STAND1 VIBID_EXAMPLES_DIR "/paper_example1.cfg"
#define SIM1 VIBID_SIM_SOURCE_DIR "/examples/paper_example1_sim.cfg"
#define H1 5e-4


/* All CSV rows: rows x cols into *out (malloc). Returns rows. */
static size_t read_csv(const char *path, double **out, size_t *cols, char names[][64])
{
    vibid_drv_error err;
    vibid_csv_reader *r = vibid_csv_open(path, &err);
    if (!r) fail_msg("%s", err.text);
    *cols = vibid_csv_column_count(r);
    for (size_t i = 0; i < *cols; i++) snprintf(names[i], 64, "%s", vibid_csv_column_name(r, i));
    size_t cap = 1024, n = 0;
    double *v = malloc(cap * *cols * sizeof *v);
    unsigned long line;
    vibid_drv_status st;
    double row[64];
    while ((st = vibid_csv_next(r, row, &line, &err)) != VIBID_DRV_E_EOF) {
        if (st != VIBID_DRV_OK) fail_msg("csv: %s", err.text);
        if (n == cap) v = realloc(v, (cap *= 2) * *cols * sizeof *v);
        memcpy(v + n * *cols, row, *cols * sizeof *row);
        n++;
    }
    vibid_csv_stats s;
    vibid_csv_stats_get(r, &s);
    assert_int_equal(s.bad_rows, 0);
    vibid_csv_close(r);
    *out = v;
    return n;
}

/* CSV holds exactly (17 digits) the values the engine produces in-process. */
static void test_csv_matches_engine(void **state)
{
    (void)state;
    char e[4096], args[2048];
    const char *csv = tmp_path("out1.csv");
    snprintf(args, sizeof args, "-c %s -s %s --duration 1 --csv %s -q", STAND1, SIM1, csv);
    assert_int_equal(run_sim(args, e, sizeof e), 0);
    double *v;
    size_t cols;
    char names[64][64];
    size_t rows = read_csv(csv, &v, &cols, names);
    assert_int_equal(rows, 2000);
    assert_int_equal(cols, 4);
    assert_string_equal(names[0], "t");
    assert_string_equal(names[1], "s"); /* inputs (base) first, then measured */
    assert_string_equal(names[2], "x1");
    assert_string_equal(names[3], "x2");

    vibid_stand_error serr;
    vibid_stand *st = vibid_stand_load(STAND1, &serr);
    assert_non_null(st);
    sim_config cfg;
    char err[1024];
    assert_int_equal(sim_config_load(SIM1, st, NULL, &cfg, err, sizeof err), 0);
    sim_engine *en = sim_engine_create(st, &cfg, err, sizeof err);
    assert_non_null(en);
    double vals[8];
    for (size_t k = 0; k < rows; k++) {
        uint64_t kk;
        double t;
        assert_int_equal(sim_engine_next(en, &kk, &t, vals, NULL), 0);
        /* model order x1, x2, s; CSV order t, s, x1, x2: lossless, so equal */
        assert_true(v[k * 4 + 0] == t);
        assert_true(v[k * 4 + 1] == vals[2]);
        assert_true(v[k * 4 + 2] == vals[0]);
        assert_true(v[k * 4 + 3] == vals[1]);
    }
    /* the configured 60 dB SNR: noise std = RMS / 1000, not zero */
    assert_true(sim_engine_noise_std(en, 0) > 0 && sim_engine_noise_std(en, 2) == 0.0);
    sim_engine_destroy(en);
    sim_config_free(&cfg);
    vibid_stand_destroy(st);
    free(v);
}

/* candump log read back with the drivers' reader; frames decoded with the DBC that
 * vibid-sim wrote; samples assembled by the daemon's CAN assembler; values equal the
 * CSV's rounded to float32. */
static void check_candump(int fd)
{
    char e[4096], args[2048];
    const char *csv = tmp_path(fd ? "c_fd.csv" : "c_cl.csv");
    const char *log = tmp_path(fd ? "c_fd.log" : "c_cl.log");
    const char *dbcp = tmp_path(fd ? "c_fd.dbc" : "c_cl.dbc");
    snprintf(args, sizeof args, "-c %s -s %s --duration 1 --csv %s --candump %s --write-dbc %s --epoch 1000 %s -q",
             STAND1, SIM1, csv, log, dbcp, fd ? "--fd" : "--classic");
    assert_int_equal(run_sim(args, e, sizeof e), 0);
    double *v;
    size_t cols;
    char names[64][64];
    size_t rows = read_csv(csv, &v, &cols, names);
    assert_int_equal(rows, 2000);

    vibid_drv_error err;
    vibid_dbc *dbc = vibid_dbc_load(dbcp, &err);
    if (!dbc) fail_msg("%s", err.text);
    assert_int_equal(vibid_dbc_message_count(dbc), fd ? 1 : 3);
    vibid_chanmap map;
    memset(&map, 0, sizeof map);
    const char *cn[3] = {"x1", "x2", "s"};
    for (int i = 0; i < 3; i++) {
        vibid_channel *c = &map.ch[map.n++];
        snprintf(c->name, sizeof c->name, "%s", cn[i]);
        c->quantity = i < 2 ? VIBID_Q_DISPLACEMENT : VIBID_Q_BASE_DISPLACEMENT;
        c->is_input = i == 2;
        c->node = i < 2 ? i : 0;
        c->source = VIBID_CHAN_SIGNAL;
        snprintf(c->ref, sizeof c->ref, "%s", cn[i]);
    }
    snprintf(map.counter, sizeof map.counter, "SampleCounter");
    vibid_can_assembler *as = vibid_can_assembler_create(dbc, &map, &err);
    if (!as) fail_msg("%s", err.text);

    vibid_candump_reader *r = vibid_candump_reader_open(log, &err);
    if (!r) fail_msg("%s", err.text);
    vibid_candump_entry ent;
    size_t frames = 0, samples = 0;
    vibid_record rec;
    while (vibid_candump_reader_next(r, &ent) == VIBID_DRV_OK) {
        assert_int_equal(ent.kind, VIBID_CANDUMP_FRAME);
        size_t k = frames / (fd ? 1 : 3);
        /* device time: epoch + k h, written with 6 digits (microseconds) */
        assert_int_equal(ent.frame.t_ns, 1000000000000LL + (int64_t)k * 500000);
        assert_int_equal(!!(ent.frame.flags & VIBID_CAN_F_FD), fd);
        assert_int_equal(ent.frame.len, fd ? 16 : 8);
        const vibid_dbc_message *msg = vibid_dbc_find_message(dbc, ent.frame.id, false);
        assert_non_null(msg);
        double vals[8];
        uint8_t present[8];
        assert_int_equal(vibid_dbc_message_decode(msg, ent.frame.data, ent.frame.len, vals, present), VIBID_DRV_OK);
        for (size_t i = 0; i < msg->n_signals; i++) {
            const char *sn = msg->signals[i].name;
            if (strcmp(sn, "SampleCounter") == 0) {
                assert_true(vals[i] == (double)(k & 0xFFFF));
                continue;
            }
            size_t col = strcmp(sn, "s") == 0 ? 1 : strcmp(sn, "x1") == 0 ? 2 : 3;
            assert_true(vals[i] == (double)(float)v[k * 4 + col]); /* float32 signal: exact float32 of the CSV value */
        }
        vibid_can_assembler_push(as, &ent.frame);
        while (vibid_can_assembler_pop(as, &rec)) {
            assert_int_equal(rec.kind, VIBID_REC_SAMPLE);
            assert_int_equal(rec.n_values, 3);
            assert_true(rec.values[0] == (double)(float)v[samples * 4 + 2]);
            assert_true(rec.values[2] == (double)(float)v[samples * 4 + 1]);
            samples++;
        }
        frames++;
    }
    vibid_can_assembler_finish(as);
    while (vibid_can_assembler_pop(as, &rec)) {
        assert_int_equal(rec.kind, VIBID_REC_SAMPLE);
        samples++;
    }
    assert_int_equal(frames, fd ? 2000 : 6000);
    assert_int_equal(samples, 2000);
    vibid_candump_reader_close(r);
    vibid_can_assembler_destroy(as);
    vibid_dbc_destroy(dbc);
    free(v);
}

static void test_candump_classic(void **state) { (void)state; check_candump(0); }
static void test_candump_fd(void **state) { (void)state; check_candump(1); }

/* the shipped DBC files are what --write-dbc produces for the example stand now */
static void test_shipped_dbc_current(void **state)
{
    (void)state;
    char e[4096], args[2048];
    for (int fd = 0; fd < 2; fd++) {
        const char *out = tmp_path("shipped_check.dbc");
        snprintf(args, sizeof args, "-c %s --write-dbc %s %s", STAND1, out, fd ? "--fd" : "--classic");
        assert_int_equal(run_sim(args, e, sizeof e), 0);
        char cmd[2048];
        snprintf(cmd, sizeof cmd, "cmp -s %s %s/%s", out, VIBID_SIM_SOURCE_DIR, fd ? "paper_example1_fd.dbc" : "paper_example1.dbc");
        if (system(cmd) != 0) fail_msg("sim/%s is out of date: regenerate it with vibid-sim --write-dbc", fd ? "paper_example1_fd.dbc" : "paper_example1.dbc");
    }
}

/* Integer signals: int32 with scale 1e-9 m and int16 with 1e-5 m: decoded values within
 * half a step of the CSV value. */
static void test_integer_signals(void **state)
{
    (void)state;
    const char *simf = write_tmp("int_sim.cfg",
        "simulation = { excitation = ( { target = \"base\"; kind = \"triangle\"; amplitude = 1e-3; frequency = 5.0; } );\n"
        "  can = { id = 0x200; signals = ( { channel = \"x1\"; type = \"int32\"; scale = 1e-9; },\n"
        "                                  { channel = \"x2\"; type = \"int32\"; scale = 1e-9; },\n"
        "                                  { channel = \"s\"; type = \"int16\"; scale = 1e-7; } ); }; };\n");
    char e[4096], args[2048];
    const char *csv = tmp_path("int.csv"), *log = tmp_path("int.log"), *dbcp = tmp_path("int.dbc");
    snprintf(args, sizeof args, "-c %s -s %s --duration 0.5 --csv %s --candump %s --write-dbc %s -q", STAND1, simf, csv, log, dbcp);
    assert_int_equal(run_sim(args, e, sizeof e), 0);
    double *v;
    size_t cols;
    char names[64][64];
    size_t rows = read_csv(csv, &v, &cols, names);
    vibid_drv_error err;
    vibid_dbc *dbc = vibid_dbc_load(dbcp, &err);
    if (!dbc) fail_msg("%s", err.text);
    /* x1 int32 + x2 int32 do not fit with the counter in 8 bytes: 2 frames (x1 | x2 + s) */
    assert_int_equal(vibid_dbc_message_count(dbc), 2);
    vibid_candump_reader *r = vibid_candump_reader_open(log, &err);
    vibid_candump_entry ent;
    size_t frames = 0;
    double maxdev[4] = {0};
    while (vibid_candump_reader_next(r, &ent) == VIBID_DRV_OK) {
        size_t k = frames / 2;
        const vibid_dbc_message *msg = vibid_dbc_find_message(dbc, ent.frame.id, false);
        assert_non_null(msg);
        assert_true(msg->id == 0x200 || msg->id == 0x201);
        double vals[8];
        uint8_t present[8];
        assert_int_equal(vibid_dbc_message_decode(msg, ent.frame.data, ent.frame.len, vals, present), VIBID_DRV_OK);
        for (size_t i = 0; i < msg->n_signals; i++) {
            const char *sn = msg->signals[i].name;
            if (strcmp(sn, "SampleCounter") == 0) continue;
            size_t col = strcmp(sn, "s") == 0 ? 1 : strcmp(sn, "x1") == 0 ? 2 : 3;
            double dev = fabs(vals[i] - v[k * 4 + col]);
            if (dev > maxdev[col]) maxdev[col] = dev;
        }
        frames++;
    }
    assert_int_equal(frames, 2 * rows);
    print_message("integer signals: max |decoded - csv|: s %.3g (step 1e-7), x1 %.3g, x2 %.3g (step 1e-9)\n", maxdev[1], maxdev[2], maxdev[3]);
    assert_true(maxdev[1] <= 0.5e-7 * (1 + 1e-6));
    assert_true(maxdev[2] <= 0.5e-9 * (1 + 1e-6) && maxdev[3] <= 0.5e-9 * (1 + 1e-6));
    vibid_candump_reader_close(r);
    vibid_dbc_destroy(dbc);
    free(v);
}

/* reads a log into arrays keyed by (sample k from the time stamp, frame index) */
typedef struct logent { int count; uint8_t data[64]; uint8_t len; } logent;

static void read_keyed(const char *path, logent *tab, size_t nk, size_t nf, double epoch)
{
    vibid_drv_error err;
    vibid_candump_reader *r = vibid_candump_reader_open(path, &err);
    if (!r) fail_msg("%s", err.text);
    vibid_candump_entry ent;
    while (vibid_candump_reader_next(r, &ent) == VIBID_DRV_OK) {
        int64_t rel = ent.frame.t_ns - (int64_t)(epoch * 1e9);
        size_t k = (size_t)llround((double)rel / (H1 * 1e9));
        size_t fi = ent.frame.id - 0x100;
        assert_true(k < nk && fi < nf);
        logent *le = &tab[k * nf + fi];
        if (le->count == 0) {
            memcpy(le->data, ent.frame.data, ent.frame.len);
            le->len = ent.frame.len;
        } else {
            assert_memory_equal(le->data, ent.frame.data, ent.frame.len); /* a duplicate is an exact copy */
        }
        le->count++;
    }
    vibid_candump_reader_close(r);
}

/* --drop 0.1 --duplicate 0.05 --corrupt 0.05 on 30000 frames: measured fractions
 * within 5 binomial standard deviations of the requested ones (a false failure has
 * probability < 1e-6; the seed is fixed, so the run is reproducible anyway). */
static void test_fault_fractions(void **state)
{
    (void)state;
    char e[4096], args[2048];
    const char *clean = tmp_path("f_clean.log"), *faulty = tmp_path("f_faulty.log");
    snprintf(args, sizeof args, "-c %s -s %s --duration 5 --candump %s --epoch 2000 -q", STAND1, SIM1, clean);
    assert_int_equal(run_sim(args, e, sizeof e), 0);
    snprintf(args, sizeof args, "-c %s -s %s --duration 5 --candump %s --epoch 2000 --drop 0.1 --duplicate 0.05 --corrupt 0.05 --fault-seed 7",
             STAND1, SIM1, faulty);
    assert_int_equal(run_sim(args, e, sizeof e), 0);
    size_t nk = 10000, nf = 3, N = nk * nf;
    logent *a = calloc(N, sizeof *a), *b = calloc(N, sizeof *b);
    read_keyed(clean, a, nk, nf, 2000);
    read_keyed(faulty, b, nk, nf, 2000);
    size_t dropped = 0, dup = 0, corrupt = 0, kept = 0;
    for (size_t i = 0; i < N; i++) {
        assert_int_equal(a[i].count, 1);
        if (b[i].count == 0) { dropped++; continue; }
        kept++;
        assert_true(b[i].count <= 2);
        if (b[i].count == 2) dup++;
        if (memcmp(a[i].data, b[i].data, a[i].len) != 0) corrupt++;
    }
    double fd = (double)dropped / N, fu = (double)dup / kept, fc = (double)corrupt / kept;
    double sd = 5 * sqrt(0.1 * 0.9 / N), su = 5 * sqrt(0.05 * 0.95 / kept);
    print_message("faults over %zu frames: dropped %.4f (0.1 +- %.4f), duplicated %.4f, corrupted %.4f of the sent (0.05 +- %.4f)\n",
                  N, fd, sd, fu, fc, su);
    assert_true(fabs(fd - 0.1) < sd);
    assert_true(fabs(fu - 0.05) < su);
    assert_true(fabs(fc - 0.05) < su);
    /* the summary on stderr counts the same frames */
    char want[256];
    snprintf(want, sizeof want, "%zu generated, %zu dropped, %zu duplicated, %zu corrupted", N, dropped, dup, corrupt);
    if (!strstr(e, want)) fail_msg("summary '%s' not in stderr:\n%s", want, e);
    free(a);
    free(b);
}

/* --stop-at 1 --resume-at 2: no frame stamped in [1, 2) s, frames before and after;
 * the CSV still holds every sample */
static void test_stop_resume_candump(void **state)
{
    (void)state;
    char e[4096], args[2048];
    const char *log = tmp_path("sr.log"), *csv = tmp_path("sr.csv");
    snprintf(args, sizeof args, "-c %s -s %s --duration 3 --candump %s --csv %s --epoch 0 --stop-at 1 --resume-at 2", STAND1, SIM1, log, csv);
    assert_int_equal(run_sim(args, e, sizeof e), 0);
    vibid_drv_error err;
    vibid_candump_reader *r = vibid_candump_reader_open(log, &err);
    vibid_candump_entry ent;
    size_t before = 0, inside = 0, after = 0;
    while (vibid_candump_reader_next(r, &ent) == VIBID_DRV_OK) {
        double t = (double)ent.frame.t_ns * 1e-9;
        if (t < 1.0 - 1e-9) before++;
        else if (t < 2.0 - 1e-9) inside++;
        else after++;
    }
    vibid_candump_reader_close(r);
    assert_int_equal(before, 2000 * 3);
    assert_int_equal(inside, 0);
    assert_int_equal(after, 2000 * 3);
    double *v;
    size_t cols;
    char names[64][64];
    assert_int_equal(read_csv(csv, &v, &cols, names), 6000);
    free(v);
    assert_non_null(strstr(e, "stopped serving"));
    assert_non_null(strstr(e, "resumed serving"));
}

/* This build host has no SocketCAN: --can must fail with a message that says so (or,
 * on a host with CAN but no such interface, that names the interface). */
static void test_can_live_error(void **state)
{
    (void)state;
    char e[4096], args[2048];
    snprintf(args, sizeof args, "-c %s -s %s --duration 0.01 --can vibidtest0", STAND1, SIM1);
    int rc = run_sim(args, e, sizeof e);
    print_message("--can vibidtest0: exit %d: %s", rc, e);
    assert_int_equal(rc, 1);
    assert_true(strstr(e, "no SocketCAN support") || strstr(e, "vibidtest0: no such CAN interface"));
}

static void expect_error(const char *args, int code, const char *needle)
{
    char e[4096];
    int rc = run_sim(args, e, sizeof e);
    if (rc != code || !strstr(e, needle)) fail_msg("vibid-sim %s: exit %d, stderr '%s'; expected exit %d and '%s'", args, rc, e, code, needle);
}

static void test_bad_input(void **state)
{
    (void)state;
    char args[2048];
    const char *bad = write_tmp("bad_kind.cfg",
        "simulation = {\n  excitation = (\n    { target = \"base\"; kind = \"triangel\"; amplitude = 1e-3; }\n  );\n};\n");
    snprintf(args, sizeof args, "-c %s -s %s --csv /dev/null", STAND1, bad);
    expect_error(args, 2, "bad_kind.cfg:3: simulation.excitation.[0].kind: unknown kind 'triangel'");
    const char *bad2 = write_tmp("bad_target.cfg",
        "simulation = { excitation = ( { target = \"f9\"; kind = \"sine\"; frequency = 5.0; } ); };\n");
    snprintf(args, sizeof args, "-c %s -s %s --csv /dev/null", STAND1, bad2);
    expect_error(args, 2, "target 'f9' is neither \"base\" nor a force input");
    const char *bad3 = write_tmp("bad_param.cfg",
        "simulation = {\n changes = ( { parameter = \"m1\"; at = 1.0; factor = 0.9; } ); };\n");
    snprintf(args, sizeof args, "-c %s -s %s --csv /dev/null", STAND1, bad3);
    expect_error(args, 2, "bad_param.cfg:2: simulation.changes.[0]: 'm1' is not an unknown parameter");
    const char *bad4 = write_tmp("bad_nyq.cfg",
        "simulation = { excitation = ( { target = \"base\"; kind = \"sine\"; frequency = 1500.0; } ); };\n");
    snprintf(args, sizeof args, "-c %s -s %s --csv /dev/null", STAND1, bad4);
    expect_error(args, 2, "not below the Nyquist frequency 1000 Hz");
    const char *bad5 = write_tmp("bad_typo.cfg", "simulation = { durration = 3.0; };\n");
    snprintf(args, sizeof args, "-c %s -s %s --csv /dev/null", STAND1, bad5);
    expect_error(args, 2, "bad_typo.cfg:1: simulation.durration: unknown setting");
    const char *bad6 = write_tmp("bad_syntax.cfg", "simulation = { duration = ; };\n");
    snprintf(args, sizeof args, "-c %s -s %s --csv /dev/null", STAND1, bad6);
    expect_error(args, 2, "bad_syntax.cfg:1:");
    snprintf(args, sizeof args, "-c %s --csv /dev/null --drop 1.5", STAND1);
    expect_error(args, 2, "--drop '1.5': expected a number in [0, 1]");
    expect_error("--csv /dev/null", 2, "no stand file");
    snprintf(args, sizeof args, "-c %s", STAND1);
    expect_error(args, 2, "nothing to do");
    snprintf(args, sizeof args, "-c %s --modbus nohostport", STAND1);
    expect_error(args, 2, "--modbus 'nohostport': expected HOST:PORT");
    snprintf(args, sizeof args, "-c %s/does_not_exist.cfg --csv /dev/null", tmp_dir());
    expect_error(args, 2, "does_not_exist.cfg");
    snprintf(args, sizeof args, "-c %s --bogus", STAND1);
    expect_error(args, 2, "unknown option '--bogus'");
    /* a CSV that cannot be written (the writer thread's error reaches the exit status):
     * 2 s at 2 kHz are several batches of SIM_CSV_BATCH rows and stdio buffers */
    snprintf(args, sizeof args, "-c %s -s %s --duration 2 --csv /dev/full -q", STAND1, SIM1);
    expect_error(args, 1, "--csv /dev/full: write failed (disk full?)");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_csv_matches_engine), cmocka_unit_test(test_candump_classic),
        cmocka_unit_test(test_candump_fd),         cmocka_unit_test(test_shipped_dbc_current),
        cmocka_unit_test(test_integer_signals),    cmocka_unit_test(test_fault_fractions),
        cmocka_unit_test(test_stop_resume_candump), cmocka_unit_test(test_can_live_error),
        cmocka_unit_test(test_bad_input),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
