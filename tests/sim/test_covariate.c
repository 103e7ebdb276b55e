/* sim.covariate: simulation.covariates (an operating condition recorded as a channel) and
 * simulation.dependence (a parameter following it): the profile's values, the parameter the
 * engine uses, the free response's frequency under a stiffness that follows the covariate,
 * the covariate as CSV column, DBC signal and register-map entry, and the errors of both
 * groups. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>
#include <sys/wait.h>

#include <vibid_drivers/candump.h>
#include <vibid_drivers/csv_capture.h>
#include <vibid_drivers/dbc.h>

#include "sim_config.h"
#include "sim_engine.h"
#include "sim_test_util.h"

#define STAND1 VIBID_EXAMPLES_DIR "/paper_example1.cfg"

/* One mass on a spring to the base, no damper, a force input: the free response after a
 * short pulse is a sine at sqrt(k / m). m = 1 kg, k = (2 pi 10 Hz)^2 N/m: 10 Hz, 1 kHz
 * sampling (100 samples a period). */
#define STAND_1DOF                                                                                                 \
    "stand = { name = \"one\"; sample_rate = 1000.0;\n"                                                          \
    "  nodes = ( { name = \"m1\"; mass = 1.0; measure = { displacement = \"x1\"; }; } );\n"                      \
    "  elements = ( { name = \"k\"; kind = \"spring\"; between = [\"m1\", \"ground\"]; unknown = true;\n"         \
    "                 true_value = 3947.8417604357433; } );\n"                                                    \
    "  inputs = ( { name = \"f\"; node = \"m1\"; channel = \"F\"; hold = \"zoh\"; } ); };\n"

typedef struct run {
    vibid_stand *stand;
    sim_config cfg;
    sim_engine *eng;
} run;

/* Loads stand file `stand_path` and the simulation group of `sim_path` (may be the same file). */
static void run_open(run *r, const char *stand_path, const char *sim_path)
{
    vibid_stand_error serr;
    r->stand = vibid_stand_load(stand_path, &serr);
    if (!r->stand) fail_msg("%s", serr.text);
    char err[1024];
    if (sim_config_load(sim_path, r->stand, NULL, &r->cfg, err, sizeof err)) fail_msg("%s", err);
    r->eng = sim_engine_create(r->stand, &r->cfg, err, sizeof err);
    if (!r->eng) fail_msg("%s", err);
}

static void run_close(run *r)
{
    sim_engine_destroy(r->eng);
    sim_config_free(&r->cfg);
    vibid_stand_destroy(r->stand);
}

/* The error text sim_config_load gives for the simulation group `group` on the 1-DOF stand. */
static const char *config_error(const char *name, const char *group)
{
    static char err[1024];
    char text[4096];
    snprintf(text, sizeof text, "%ssimulation = {\n%s\n};\n", STAND_1DOF, group);
    const char *path = write_tmp(name, text);
    vibid_stand_error serr;
    vibid_stand *st = vibid_stand_load(path, &serr);
    if (!st) fail_msg("%s", serr.text);
    sim_config cfg;
    err[0] = 0;
    int rc = sim_config_load(path, st, NULL, &cfg, err, sizeof err);
    if (rc == 0) sim_config_free(&cfg);
    vibid_stand_destroy(st);
    return rc ? err : NULL;
}

static void expect_error(const char *name, const char *group, const char *want)
{
    const char *e = config_error(name, group);
    if (!e) fail_msg("%s: accepted, expected an error containing \"%s\"", name, want);
    if (!strstr(e, want)) fail_msg("%s: error \"%s\" does not contain \"%s\"", name, e, want);
    /* every message names the file and the line (file:LINE: simulation....) */
    char prefix[600];
    snprintf(prefix, sizeof prefix, "%s:", tmp_path(name));
    if (strncmp(e, prefix, strlen(prefix)) != 0 || !(e[strlen(prefix)] >= '1' && e[strlen(prefix)] <= '9'))
        fail_msg("%s: error \"%s\" does not start with %sLINE:", name, e, prefix);
}

/* The profile: the recorded value against mean + amplitude sin(2 pi t / period + phase) +
 * ramp t, and the sampled sine's mean, amplitude and period measured from the samples. */
static void test_profile(void **state)
{
    (void)state;
    const char *path = write_tmp("cov_profile.cfg",
        STAND_1DOF
        "simulation = { covariates = (\n"
        "  { name = \"T\"; unit = \"degC\"; mean = 20.0; amplitude = 5.0; period = 2.0; phase = 0.3; },\n"
        "  { name = \"P\"; mean = 1.0; ramp = 0.25; },\n"
        "  { name = \"C\"; mean = -3.0; } ); };\n");
    run r;
    run_open(&r, path, path);
    size_t nch = sim_engine_channels(r.eng);
    assert_int_equal(nch, 2); /* x1, F */
    assert_int_equal(sim_engine_outputs(r.eng), 5);
    const size_t n = 10000; /* 10 s: 5 whole periods of T, 2000 samples each */
    double v[8], c[8], sum = 0.0, vmax = -INFINITY, vmin = INFINITY, maxdev = 0.0, prev = 0.0;
    double cross[16];
    size_t nc = 0;
    for (size_t i = 0; i < n; i++) {
        uint64_t k;
        double t;
        assert_int_equal(sim_engine_next(r.eng, &k, &t, v, c), 0);
        /* without noise the recorded value is the true one, computed here independently;
         * 1e-12 degC: double rounding of sin at arguments below 32 rad is ~1e-15 relative */
        double want = 20.0 + 5.0 * sin(2.0 * M_PI * t / 2.0 + 0.3);
        maxdev = fmax(maxdev, fabs(v[nch] - want));
        assert_true(v[nch] == c[nch]);
        assert_true(fabs(v[nch + 1] - (1.0 + 0.25 * t)) < 1e-12);
        assert_true(v[nch + 2] == -3.0);
        sum += v[nch];
        vmax = fmax(vmax, v[nch]);
        vmin = fmin(vmin, v[nch]);
        /* upward crossings of the mean, linearly interpolated */
        double y = v[nch] - 20.0;
        if (i > 0 && prev < 0.0 && y >= 0.0 && nc < 16) cross[nc++] = t - 1e-3 * y / (y - prev);
        prev = y;
    }
    double mean = sum / (double)n, amp = 0.5 * (vmax - vmin);
    double period = (cross[nc - 1] - cross[0]) / (double)(nc - 1);
    print_message("profile: max |T - formula| %.3g degC; mean %.12g, amplitude %.9g, period %.9g s (%zu crossings)\n",
                  maxdev, mean, amp, period, nc);
    assert_true(maxdev < 1e-12);
    /* the mean over whole periods of a uniformly sampled sine is the mean up to rounding */
    assert_true(fabs(mean - 20.0) < 1e-9);
    /* the largest sample misses the crest by at most a half sample in phase:
     * 5 (1 - cos(pi h / period)) = 6.2e-6 degC */
    assert_true(fabs(amp - 5.0) < 6.2e-6);
    /* linear interpolation of a crossing of a sine at 2000 samples a period errs by
     * ~(pi h / period)^2 / 6 of a sample, far below 1e-6 s */
    assert_true(nc == 5 && fabs(period - 2.0) < 1e-6);
    run_close(&r);
}

/* Measurement noise: std `noise` from a stream of its own, reproducible, leaving the stand's
 * channels bit for bit as they are without it. */
static void test_noise(void **state)
{
    (void)state;
    const char *quiet = write_tmp("cov_noise0.cfg",
        STAND_1DOF
        "simulation = { seed = 3; excitation = ( { target = \"f\"; kind = \"prbs\"; amplitude = 1.0; } );\n"
        "  noise = ( { channel = \"x1\"; std = 1e-6; } );\n"
        "  covariates = ( { name = \"T\"; mean = 20.0; amplitude = 5.0; period = 2.0; } ); };\n");
    const char *noisy = write_tmp("cov_noise1.cfg",
        STAND_1DOF
        "simulation = { seed = 3; excitation = ( { target = \"f\"; kind = \"prbs\"; amplitude = 1.0; } );\n"
        "  noise = ( { channel = \"x1\"; std = 1e-6; } );\n"
        "  covariates = ( { name = \"T\"; mean = 20.0; amplitude = 5.0; period = 2.0; noise = 0.5; } ); };\n");
    run a, b, b2;
    run_open(&a, quiet, quiet);
    run_open(&b, noisy, noisy);
    run_open(&b2, noisy, noisy);
    const size_t n = 20000;
    double s1 = 0.0, s2 = 0.0;
    for (size_t i = 0; i < n; i++) {
        uint64_t k;
        double t, va[4], vb[4], vb2[4], cb[4];
        assert_int_equal(sim_engine_next(a.eng, &k, &t, va, NULL), 0);
        assert_int_equal(sim_engine_next(b.eng, &k, &t, vb, cb), 0);
        assert_int_equal(sim_engine_next(b2.eng, &k, &t, vb2, NULL), 0);
        assert_true(va[0] == vb[0] && va[1] == vb[1]); /* x1 (with its noise) and F unchanged */
        assert_true(vb[2] == vb2[2]);                 /* same seed, same noise */
        assert_true(cb[2] == va[2]);                  /* clean = the quiet run's value */
        double d = vb[2] - va[2];
        s1 += d;
        s2 += d * d;
    }
    double m = s1 / (double)n, sd = sqrt(s2 / (double)n - m * m);
    print_message("covariate noise: mean %.4g, std %.5g over %zu samples (want 0, 0.5)\n", m, sd, n);
    /* 4 standard errors: mean 4 * 0.5 / sqrt(n) = 0.0141; std 4 * 0.5 / sqrt(2 n) = 0.0100 */
    assert_true(fabs(m) < 0.0141);
    assert_true(fabs(sd - 0.5) < 0.0100);
    run_close(&a);
    run_close(&b);
    run_close(&b2);
}

/* The paper's example 1 with both stiffnesses following T and a 1 % step of c2: the values
 * the engine uses at two times, against base (1 + coefficient (T(t) - reference)). */
static void test_dependence_parameters(void **state)
{
    (void)state;
    const char *simf = write_tmp("cov_dep_sim.cfg",
        "simulation = { excitation = ( { target = \"base\"; kind = \"triangle\"; amplitude = 1e-3; frequency = 5.0; } );\n"
        "  covariates = ( { name = \"T\"; unit = \"degC\"; mean = 20.0; amplitude = 8.0; period = 2.0; } );\n"
        "  dependence = ( { parameter = \"c1\"; covariate = \"T\"; coefficient = -0.002; reference = 20.0; },\n"
        "                 { parameter = \"c2\"; covariate = \"T\"; coefficient = -0.002; reference = 18.0; } );\n"
        "  changes = ( { parameter = \"c2\"; at = 1.0; factor = 0.99; } ); };\n");
    run r;
    run_open(&r, STAND1, simf);
    /* parameter order of the stand: c1, d, c2 */
    const double c1 = 2.5e5, d = 300.0, c2 = 1.5e6;
    const uint64_t check_k[] = {1000, 2500}; /* t = 0.5 s (T at its crest, 28 degC), 1.25 s (after the step) */
    size_t ci = 0;
    double v[8];
    for (uint64_t i = 0; i <= check_k[1]; i++) {
        uint64_t k;
        double t;
        assert_int_equal(sim_engine_next(r.eng, &k, &t, v, NULL), 0);
        if (ci < 2 && k == check_k[ci]) {
            double T = 20.0 + 8.0 * sin(2.0 * M_PI * t / 2.0);
            double w1 = c1 * (1.0 - 0.002 * (T - 20.0));
            double w2 = c2 * (t >= 1.0 ? 0.99 : 1.0) * (1.0 - 0.002 * (T - 18.0));
            print_message("t = %g s: T = %.6f degC; c1 %.9g (want %.9g), d %.9g, c2 %.9g (want %.9g)\n", t, T,
                          sim_engine_param(r.eng, 0), w1, sim_engine_param(r.eng, 1), sim_engine_param(r.eng, 2),
                          w2);
            /* the same arithmetic in another order: a few ulps, 1e-12 relative */
            assert_true(fabs(sim_engine_param(r.eng, 0) / w1 - 1.0) < 1e-12);
            assert_true(sim_engine_param(r.eng, 1) == d);
            assert_true(fabs(sim_engine_param(r.eng, 2) / w2 - 1.0) < 1e-12);
            assert_true(fabs(v[3] - T) < 1e-12); /* output 3: after s, x1, x2 (model order x1, x2, s) */
            ci++;
        }
    }
    assert_int_equal(ci, 2);
    /* every interval by ARKODE: the parameters change inside each */
    sim_engine_stats st;
    sim_engine_stats_get(r.eng, &st);
    assert_int_equal(st.exact_intervals, 0);
    run_close(&r);
}

/* Upward zero crossings of x in [t0, t1): *first, *last and their count. */
static size_t crossings(const double *x, size_t n, double h, double t0, double t1, double *first, double *last)
{
    size_t nc = 0;
    for (size_t i = 1; i < n; i++) {
        double t = (double)i * h;
        if (t < t0 || t >= t1) continue;
        if (x[i - 1] < 0.0 && x[i] >= 0.0) {
            double tc = t - h * x[i] / (x[i] - x[i - 1]);
            if (!nc) *first = tc;
            *last = tc;
            nc++;
        }
    }
    return nc;
}

/* The dynamics follow the covariate: a stiffness k (1 + 0.02 (T - 20)) with T = 20 + 10
 * sin(2 pi t / 20 s) swings by +-20 %, the free response's frequency by about +-10 %.
 * Measured from zero crossings over 1 s windows at the crest (t = 5 s) and the trough
 * (15 s) of T, against the window's mean of f(t) = sqrt(k(t) / m) / (2 pi). */
static void test_dependence_frequency(void **state)
{
    (void)state;
    const char *path = write_tmp("cov_freq.cfg",
        STAND_1DOF
        "simulation = { excitation = ( { target = \"f\"; kind = \"constant\"; amplitude = 100.0; t_on = 0.0; t_off = 0.02; } );\n"
        "  covariates = ( { name = \"T\"; unit = \"degC\"; mean = 20.0; amplitude = 10.0; period = 20.0; } );\n"
        "  dependence = ( { parameter = \"k\"; covariate = \"T\"; coefficient = 0.02; } ); };\n");
    run r;
    run_open(&r, path, path);
    const size_t n = 17000;
    const double h = 1e-3;
    double *x = malloc(n * sizeof *x), v[4];
    for (size_t i = 0; i < n; i++) {
        uint64_t k;
        double t;
        assert_int_equal(sim_engine_next(r.eng, &k, &t, v, NULL), 0);
        x[i] = v[0];
    }
    const double centres[2] = {5.0, 15.0};
    for (int w = 0; w < 2; w++) {
        double a = 0.0, b = 0.0;
        size_t nc = crossings(x, n, h, centres[w] - 0.5, centres[w] + 0.5, &a, &b);
        assert_true(nc >= 9);
        double f_meas = (double)(nc - 1) / (b - a);
        /* expected: mean of f(t) over [a, b] (midpoint rule, 1e4 points) */
        double sum = 0.0;
        for (int j = 0; j < 10000; j++) {
            double t = a + (b - a) * (j + 0.5) / 10000.0;
            sum += 10.0 * sqrt(1.0 + 0.02 * 10.0 * sin(2.0 * M_PI * t / 20.0));
        }
        double f_want = sum / 10000.0;
        print_message("free response around t = %g s: %.6f Hz from %zu crossings, expected %.6f Hz "
                      "(%.2e relative; without the dependence 10 Hz)\n",
                      centres[w], f_meas, nc, f_want, f_meas / f_want - 1.0);
        /* Tolerance 2e-5 (measured 4.9e-7 and 9.7e-7): the frequency changes by up to 3 % a
         * second, so the response's frequency differs from the adiabatic sqrt(k(t) / m) by terms
         * of order (k'/k / omega)^2 ~ 2e-6; linear interpolation of the crossings at 100
         * samples a period errs by ~(omega h)^2 / 24 of a sample, ~2e-6 s at each end of a
         * ~1 s span. The effect to detect is +9.5 % / -10.5 %: a dependence ignored, held at
         * the wrong time by more than ~0.1 s, or of the wrong sign fails by orders of magnitude. */
        assert_true(fabs(f_meas / f_want - 1.0) < 2e-5);
    }
    free(x);
    run_close(&r);
}

/* A factor (1 + coefficient (T - reference)) that reaches 0 stops the run, named. */
static void test_dependence_factor_sign(void **state)
{
    (void)state;
    const char *path = write_tmp("cov_sign.cfg",
        STAND_1DOF
        "simulation = { covariates = ( { name = \"T\"; mean = 20.0; amplitude = 10.0; period = 1.0; } );\n"
        "  dependence = ( { parameter = \"k\"; covariate = \"T\"; coefficient = -0.2; } ); };\n");
    run r;
    run_open(&r, path, path);
    int rc = 0;
    double v[4];
    for (size_t i = 0; i < 1000 && !rc; i++) {
        uint64_t k;
        double t;
        rc = sim_engine_next(r.eng, &k, &t, v, NULL);
    }
    assert_int_equal(rc, -1);
    print_message("%s\n", sim_engine_error(r.eng));
    assert_non_null(strstr(sim_engine_error(r.eng), "simulation.dependence.[0]: the factor of 'k' is"));
    assert_non_null(strstr(sim_engine_error(r.eng), "must stay > 0"));
    run_close(&r);
}


/* vibid-sim: T is the CSV's last column with its true values (noise 0); the DBC has signal
 * T in degC and decodes the candump frames to the CSV's values; the default register map
 * puts T after the stand's channels. */
static void test_outputs(void **state)
{
    (void)state;
    const char *simf = write_tmp("cov_out_sim.cfg",
        "simulation = { excitation = ( { target = \"base\"; kind = \"triangle\"; amplitude = 1e-3; frequency = 5.0; } );\n"
        "  covariates = ( { name = \"T\"; unit = \"degC\"; mean = 20.0; amplitude = 8.0; period = 0.5; phase = 1.0; } );\n"
        "  dependence = ( { parameter = \"c2\"; covariate = \"T\"; coefficient = -0.002; } );\n"
        "  can = { signals = ( { channel = \"T\"; type = \"int16\"; scale = 0.01; } ); }; };\n");
    const char *csv = tmp_path("cov.csv"), *log = tmp_path("cov.log"), *dbcp = tmp_path("cov.dbc");
    const char *reg = tmp_path("cov_reg.cfg");
    char e[4096], args[2048];
    snprintf(args, sizeof args, "-c %s -s %s --duration 1 --csv %s --candump %s --write-dbc %s --write-regmap %s -q",
             STAND1, simf, csv, log, dbcp, reg);
    if (run_sim(args, e, sizeof e) != 0) fail_msg("vibid-sim: %s", e);

    vibid_drv_error err;
    vibid_csv_reader *cr = vibid_csv_open(csv, &err);
    if (!cr) fail_msg("%s", err.text);
    assert_int_equal(vibid_csv_column_count(cr), 5);
    assert_string_equal(vibid_csv_column_name(cr, 0), "t");
    assert_string_equal(vibid_csv_column_name(cr, 4), "T");
    double *Tcsv = calloc(4000, sizeof *Tcsv), row[8], maxdev = 0.0;
    size_t rows = 0;
    unsigned long line;
    while (vibid_csv_next(cr, row, &line, &err) == VIBID_DRV_OK && rows < 4000) {
        double want = 20.0 + 8.0 * sin(2.0 * M_PI * row[0] / 0.5 + 1.0);
        maxdev = fmax(maxdev, fabs(row[4] - want));
        Tcsv[rows++] = row[4];
    }
    vibid_csv_close(cr);
    print_message("CSV: %zu rows, max |T - formula| %.3g degC\n", rows, maxdev);
    assert_int_equal(rows, 2000);
    assert_true(maxdev < 1e-12); /* written losslessly (shortest round trip); rounding of sin only */

    vibid_dbc *dbc = vibid_dbc_load(dbcp, &err);
    if (!dbc) fail_msg("%s", err.text);
    /* x1, x2, s float32 one per classic frame (16 + 32 bits each); T's 16 bits fill s's frame */
    assert_int_equal(vibid_dbc_message_count(dbc), 3);
    FILE *df = fopen(dbcp, "r");
    char text[8192];
    size_t tl = fread(text, 1, sizeof text - 1, df);
    text[tl] = 0;
    fclose(df);
    assert_non_null(strstr(text, " SG_ T : 48|16@1- (0.01,0) [-327.68000000000001|327.67000000000002] \"degC\""));
    vibid_candump_reader *lr = vibid_candump_reader_open(log, &err);
    if (!lr) fail_msg("%s", err.text);
    vibid_candump_entry ent;
    size_t nT = 0;
    double dmax = 0.0;
    while (vibid_candump_reader_next(lr, &ent) == VIBID_DRV_OK) {
        const vibid_dbc_message *msg = vibid_dbc_find_message(dbc, ent.frame.id, false);
        assert_non_null(msg);
        double vals[8];
        uint8_t present[8];
        assert_int_equal(vibid_dbc_message_decode(msg, ent.frame.data, ent.frame.len, vals, present), VIBID_DRV_OK);
        size_t k = 0;
        for (size_t i = 0; i < msg->n_signals; i++)
            if (strcmp(msg->signals[i].name, "SampleCounter") == 0) k = (size_t)vals[i];
        for (size_t i = 0; i < msg->n_signals; i++)
            if (strcmp(msg->signals[i].name, "T") == 0) {
                assert_true(k < rows);
                dmax = fmax(dmax, fabs(vals[i] - Tcsv[k]));
                nT++;
            }
    }
    vibid_candump_reader_close(lr);
    vibid_dbc_destroy(dbc);
    print_message("CAN: %zu frames with T, max |decoded - CSV| %.3g degC (int16, step 0.01)\n", nT, dmax);
    assert_int_equal(nT, rows);
    assert_true(dmax <= 0.005 * (1 + 1e-9)); /* rounding to the step: half a step */

    FILE *rf = fopen(reg, "r");
    tl = fread(text, 1, sizeof text - 1, rf);
    text[tl] = 0;
    fclose(rf);
    assert_non_null(strstr(text, "{ name = \"T\"; address = 6; register = \"holding\"; type = \"FLOAT32\";"));
    free(Tcsv);
}

/* The errors of both groups, each with file:line: and the setting's path. */
static void test_config_errors(void **state)
{
    (void)state;
    expect_error("cove1.cfg", "covariates = ( { name = \"T\"; mean = 20.0; periode = 3.0; } );",
                 "simulation.covariates.[0].periode: unknown setting 'periode'");
    expect_error("cove2.cfg", "covariates = ( { name = \"x1\"; mean = 20.0; } );",
                 "simulation.covariates.[0].name: 'x1' is a channel of the stand");
    expect_error("cove3.cfg", "covariates = ( { name = \"F\"; mean = 20.0; } );",
                 "simulation.covariates.[0].name: 'F' is a channel of the stand");
    expect_error("cove4.cfg", "covariates = ( { name = \"T\"; mean = 20.0; amplitude = 5.0; } );",
                 "simulation.covariates.[0]: period = 0 s: must be > 0 when amplitude (5) is not 0");
    expect_error("cove5.cfg", "covariates = ( { name = \"T\"; mean = 20.0; noise = -1.0; } );",
                 "simulation.covariates.[0]: noise = -1 must be >= 0");
    expect_error("cove6.cfg", "covariates = ( { name = \"T\"; amplitude = 1.0; period = 2.0; } );",
                 "simulation.covariates.[0]: mean missing");
    expect_error("cove7.cfg", "covariates = ( { name = \"T\"; mean = 1.0; }, { name = \"T\"; mean = 2.0; } );",
                 "simulation.covariates.[1].name: 'T' names covariate [0] already");
    expect_error("cove8.cfg",
                 "covariates = ( { name = \"A\"; mean = 1.0; }, { name = \"B\"; mean = 1.0; }, { name = \"C\"; mean = 1.0; },\n"
                 "  { name = \"D\"; mean = 1.0; }, { name = \"E\"; mean = 1.0; } );",
                 "simulation.covariates: 5 covariates; at most 4");
    expect_error("cove9.cfg", "covariates = ( { name = \"t\"; mean = 1.0; } );",
                 "simulation.covariates.[0].name: 't' is reserved (the CSV's time column)");
    expect_error("cove10.cfg", "covariates = ( { name = \"T,1\"; mean = 1.0; } );", "simulation.covariates.[0].name:");
    expect_error("cove11.cfg", "covariates = ( { mean = 1.0; } );", "simulation.covariates.[0]: name missing");
    expect_error("cove12.cfg", "covariates = ( { name = \"T\"; mean = \"hot\"; } );", "simulation.covariates.[0].mean");
    const char *cov = "covariates = ( { name = \"T\"; mean = 20.0; amplitude = 5.0; period = 60.0; } );\n";
    char g[1024];
    snprintf(g, sizeof g, "%sdependence = ( { parameter = \"k\"; covariate = \"P\"; coefficient = 0.01; } );", cov);
    expect_error("cove13.cfg", g, "simulation.dependence.[0]: 'P' is not a covariate of simulation.covariates (covariates: T )");
    snprintf(g, sizeof g, "%sdependence = ( { parameter = \"m\"; covariate = \"T\"; coefficient = 0.01; } );", cov);
    expect_error("cove14.cfg", g, "simulation.dependence.[0]: 'm' is not an unknown parameter of the stand");
    snprintf(g, sizeof g, "%sdependence = ( { parameter = \"k\"; covariate = \"T\"; } );", cov);
    expect_error("cove15.cfg", g, "simulation.dependence.[0]: coefficient missing");
    snprintf(g, sizeof g, "%sdependence = ( { parameter = \"k\"; covariate = \"T\"; coefficient = 0.01; ref = 1.0; } );", cov);
    expect_error("cove16.cfg", g, "simulation.dependence.[0].ref: unknown setting 'ref'");
    snprintf(g, sizeof g,
             "%sdependence = ( { parameter = \"k\"; covariate = \"T\"; coefficient = 0.01; },\n"
             "  { parameter = \"k\"; covariate = \"T\"; coefficient = 0.02; } );", cov);
    expect_error("cove17.cfg", g, "simulation.dependence.[1]: 'k' depends on 'T' already (entry [0])");
    snprintf(g, sizeof g, "integrator = { kind = \"exact\"; };\n%sdependence = ( { parameter = \"k\"; covariate = \"T\"; coefficient = 0.01; } );", cov);
    expect_error("cove18.cfg", g, "simulation.dependence.[0]: 'k' follows covariate 'T', which varies");
    expect_error("cove19.cfg", "dependence = ( { parameter = \"k\"; covariate = \"T\"; coefficient = 0.01; } );",
                 "(covariates: none)");
    expect_error("cove20.cfg", "can = { signals = ( { channel = \"T\"; type = \"int16\"; scale = 0.01; } ); };",
                 "simulation.can.signals.[0]: unknown channel 'T'");
    /* accepted: a constant covariate under "exact" (nothing varies), a CAN type for it */
    snprintf(g, sizeof g,
             "integrator = { kind = \"exact\"; };\ncovariates = ( { name = \"T\"; mean = 25.0; } );\n"
             "dependence = ( { parameter = \"k\"; covariate = \"T\"; coefficient = 0.01; reference = 20.0; } );\n"
             "can = { signals = ( { channel = \"T\"; type = \"int16\"; scale = 0.01; } ); };");
    const char *e = config_error("cove_ok.cfg", g);
    if (e) fail_msg("refused: %s", e);
}

/* A constant covariate scales the parameter once: the exact step takes every interval. */
static void test_constant_covariate_exact(void **state)
{
    (void)state;
    const char *path = write_tmp("cov_const.cfg",
        STAND_1DOF
        "simulation = { integrator = { kind = \"exact\"; };\n"
        "  excitation = ( { target = \"f\"; kind = \"prbs\"; amplitude = 1.0; } );\n"
        "  covariates = ( { name = \"T\"; mean = 25.0; } );\n"
        "  dependence = ( { parameter = \"k\"; covariate = \"T\"; coefficient = 0.01; reference = 20.0; } ); };\n");
    run r;
    run_open(&r, path, path);
    double v[4];
    for (int i = 0; i < 100; i++) {
        uint64_t k;
        double t;
        assert_int_equal(sim_engine_next(r.eng, &k, &t, v, NULL), 0);
    }
    assert_true(fabs(sim_engine_param(r.eng, 0) / (3947.8417604357433 * 1.05) - 1.0) < 1e-15);
    sim_engine_stats st;
    sim_engine_stats_get(r.eng, &st);
    assert_int_equal(st.exact_intervals, 100);
    run_close(&r);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_profile),
        cmocka_unit_test(test_noise),
        cmocka_unit_test(test_dependence_parameters),
        cmocka_unit_test(test_dependence_frequency),
        cmocka_unit_test(test_dependence_factor_sign),
        cmocka_unit_test(test_outputs),
        cmocka_unit_test(test_config_errors),
        cmocka_unit_test(test_constant_covariate_exact),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
