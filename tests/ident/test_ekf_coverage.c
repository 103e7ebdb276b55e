/* ident.ekf_coverage: Monte Carlo coverage of the state-space estimator's error bars
 * (VIBID_ESTIMATOR_EKF, chosen by the automatic estimator) on stands that are not fully
 * measured (issue 29, item 5). Each realisation is a new simulation by vibid-sim's engine
 * (its own excitation seed) with its own sensor noise, a few seconds long, identified
 * from start values 10-20 % off; per parameter the share of estimates within 2 of their
 * standard errors of the truth, and the empirical spread over the mean standard error.
 *
 *  unmeasured  2 DOF on a moving base (smooth band-limited noise), the base and the upper
 *              mass measured (displacements, 1 % noise), the lower mass without sensor;
 *              two springs, two dampers unknown; 5 s at 1 kHz.
 *  accel       a 4-DOF chain (ground - m1 - m2 - m3 - m4), a measured force on m4 (the
 *              load cell: an input channel, noise-free here), accelerometers on every
 *              mass (1 % noise), no displacement; four springs, four dampers unknown;
 *              4 s at 2 kHz.
 *
 *  impact      an impact-hammer test (below): 2 ms pulses that the filter, taking the
 *              force as linear between samples, sees with their impulse about 0.8 % off;
 *              a model error, not noise: the dampers come out 2 % off, 3-12 standard
 *              errors from the truth in every realisation (also from the true values, so
 *              not the start transient; with 10 ms pulses 95.8 % coverage, 8 realisations,
 *              measured by hand). Such estimates must be flagged.
 *
 * Bounds. Coverage of at least 88 % over all intervals (unmeasured 30 x 4 = 120, accel
 * 30 x 8 = 240): at a true 95 % the binomial standard deviation is 2.0 % (1.4 %), more
 * as the parameters of one realisation are correlated; 88 % is 3.5 of the former below.
 * No upper bound: the error bars are the filter's own widened by the sandwich where that
 * is wider (identify.h), and the filter's own are too wide here (spread / se 0.12-0.16
 * and 0.44-0.67, coverage 100 %; the sandwich alone gave 94.2 % on both, but left a
 * damper bias 7 standard errors out on a 60 s run of ident.ekf's base stand). No flag
 * on these two stands; the impact test flagged in at least 18 of 20 realisations (none
 * before the sandwich's variance-ratio flag). The seeds are fixed: the figures are
 * reproducible; the bounds are for code changes, not luck.
 *
 * EKF_COV_RUNS (environment) overrides the number of realisations per stand (under the
 * sanitizers 2, unchecked: capture.h);
 * EKF_COV_STAND=unmeasured|accel|impact runs one stand; EKF_COV_TRUTH=1 starts from the
 * truth; EKF_COV_VERBOSE=1 prints each realisation's z. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include <vibid/identify.h>

#include "capture.h"

/* @0, @1, ...: the start value (value = ...) of each unknown, in the order below; @S the seed. */
static const char *unmeasured_fmt =
    "stand = { name = \"cov-unmeasured\"; sample_rate = 1000.0;\n"
    "  nodes = ( { name = \"m1\"; mass = 1.0; measure = { displacement = \"x1\"; }; },\n"
    "            { name = \"m2\"; mass = 2.0; } );\n"
    "  base = { measure = { displacement = \"s\"; }; };\n"
    "  elements = ( { name = \"c1\"; kind = \"spring\"; between = [\"m1\", \"m2\"]; unknown = true; value = @0; true_value = 5.0e4; },\n"
    "               { name = \"d1\"; kind = \"damper\"; between = [\"m1\", \"m2\"]; unknown = true; value = @1; true_value = 10.0; },\n"
    "               { name = \"c2\"; kind = \"spring\"; between = [\"m2\", \"base\"]; unknown = true; value = @2; true_value = 1.0e5; },\n"
    "               { name = \"d2\"; kind = \"damper\"; between = [\"m2\", \"base\"]; unknown = true; value = @3; true_value = 25.0; } ); };\n"
    "simulation = { seed = @S; excitation = ( { target = \"base\"; kind = \"noise\"; amplitude = 1.0e-4; f_high = 150.0; } ); };\n";
static const char *unmeasured_off[] = {"5.8e4", "8.5", "8.5e4", "29.0"};
static const char *unmeasured_truth[] = {"5.0e4", "10.0", "1.0e5", "25.0"};

static const char *accel_fmt =
    "stand = { name = \"cov-accel\"; sample_rate = 2000.0;\n"
    "  nodes = ( { name = \"m1\"; mass = 1.0; measure = { acceleration = \"a1\"; }; },\n"
    "            { name = \"m2\"; mass = 1.0; measure = { acceleration = \"a2\"; }; },\n"
    "            { name = \"m3\"; mass = 0.8; measure = { acceleration = \"a3\"; }; },\n"
    "            { name = \"m4\"; mass = 0.6; measure = { acceleration = \"a4\"; }; } );\n"
    "  elements = ( { name = \"k1\"; kind = \"spring\"; between = [\"m1\", \"ground\"]; unknown = true; value = @0; true_value = 8.0e4; },\n"
    "               { name = \"d1\"; kind = \"damper\"; between = [\"m1\", \"ground\"]; unknown = true; value = @1; true_value = 20.0; },\n"
    "               { name = \"k2\"; kind = \"spring\"; between = [\"m2\", \"m1\"]; unknown = true; value = @2; true_value = 6.0e4; },\n"
    "               { name = \"d2\"; kind = \"damper\"; between = [\"m2\", \"m1\"]; unknown = true; value = @3; true_value = 15.0; },\n"
    "               { name = \"k3\"; kind = \"spring\"; between = [\"m3\", \"m2\"]; unknown = true; value = @4; true_value = 5.0e4; },\n"
    "               { name = \"d3\"; kind = \"damper\"; between = [\"m3\", \"m2\"]; unknown = true; value = @5; true_value = 12.0; },\n"
    "               { name = \"k4\"; kind = \"spring\"; between = [\"m4\", \"m3\"]; unknown = true; value = @6; true_value = 4.0e4; },\n"
    "               { name = \"d4\"; kind = \"damper\"; between = [\"m4\", \"m3\"]; unknown = true; value = @7; true_value = 10.0; } );\n"
    "  inputs = ( { name = \"f\"; node = \"m4\"; gain = 1.0; channel = \"F\"; } ); };\n"
    "simulation = { seed = @S; excitation = ( { target = \"f\"; kind = \"noise\"; amplitude = 20.0; f_high = 250.0; } ); };\n";
static const char *accel_off[] = {"9.2e4", "17.0", "5.1e4", "17.5", "5.8e4", "10.0", "3.4e4", "11.5"};
static const char *accel_truth[] = {"8.0e4", "20.0", "6.0e4", "15.0", "5.0e4", "12.0", "4.0e4", "10.0"};

/* An impact-hammer test: three masses on ground, the hammer's load cell (a measured force,
 * noise-free here) gives half-sine pulses of 200 N and 2 ms (10 samples) every 0.3 s on
 * m1, accelerometers on every mass (1 % noise); three springs and three dampers unknown;
 * 2 s at 5 kHz. (The pulses: a 250 Hz sine switched on for its half periods from t = 0.1 +
 * 0.3 j, where it rises from 0.) */
#define HIT(t, t2) "{ target = \"f\"; kind = \"sine\"; frequency = 250.0; amplitude = 200.0; t_on = " t "; t_off = " t2 "; }"
static const char *impact_fmt =
    "stand = { name = \"cov-impact\"; sample_rate = 5000.0;\n"
    "  nodes = ( { name = \"m1\"; mass = 1.0; measure = { acceleration = \"a1\"; }; },\n"
    "            { name = \"m2\"; mass = 0.7; measure = { acceleration = \"a2\"; }; },\n"
    "            { name = \"m3\"; mass = 0.5; measure = { acceleration = \"a3\"; }; } );\n"
    "  elements = ( { name = \"k1\"; kind = \"spring\"; between = [\"m1\", \"ground\"]; unknown = true; value = @0; true_value = 2.0e5; },\n"
    "               { name = \"d1\"; kind = \"damper\"; between = [\"m1\", \"ground\"]; unknown = true; value = @1; true_value = 30.0; },\n"
    "               { name = \"k2\"; kind = \"spring\"; between = [\"m2\", \"m1\"]; unknown = true; value = @2; true_value = 1.5e5; },\n"
    "               { name = \"d2\"; kind = \"damper\"; between = [\"m2\", \"m1\"]; unknown = true; value = @3; true_value = 20.0; },\n"
    "               { name = \"k3\"; kind = \"spring\"; between = [\"m3\", \"m2\"]; unknown = true; value = @4; true_value = 1.0e5; },\n"
    "               { name = \"d3\"; kind = \"damper\"; between = [\"m3\", \"m2\"]; unknown = true; value = @5; true_value = 15.0; } );\n"
    "  inputs = ( { name = \"f\"; node = \"m1\"; gain = 1.0; channel = \"F\"; } ); };\n"
    "simulation = { seed = @S; excitation = ( " HIT("0.1", "0.102") ", " HIT("0.4", "0.402") ", " HIT("0.7", "0.702") ",\n"
    "  " HIT("1.0", "1.002") ", " HIT("1.3", "1.302") ", " HIT("1.6", "1.602") ", " HIT("1.9", "1.902") ",\n"
    "  { target = \"f\"; kind = \"noise\"; amplitude = 0.5; f_high = 1000.0; } ); };\n";
static const char *impact_off[] = {"2.3e5", "25.0", "1.3e5", "23.0", "1.15e5", "12.5"};
static const char *impact_truth[] = {"2.0e5", "30.0", "1.5e5", "20.0", "1.0e5", "15.0"};

#define MAXP 8

typedef struct cov_stand {
    const char *name, *fmt;
    const char **off, **truth;
    size_t p, n;  /* unknowns, samples per realisation */
    double h;
    int runs;
} cov_stand;

typedef struct cov_result {
    int runs, flagged;
    int covered[MAXP];        /* |z| <= 2, every realisation */
    int covered_unflagged[MAXP];
    double mean_err[MAXP], spread[MAXP], mean_se[MAXP];  /* relative to the truth */
    double worst_z;
} cov_result;

/* The stand text with @0..@7 replaced by the start values and @S by the seed. */
static void format_stand(char *buf, size_t len, const cov_stand *s, const char **vals, int seed)
{
    size_t o = 0;
    for (const char *t = s->fmt; *t && o + 32 < len; t++) {
        if (t[0] == '@' && t[1] == 'S') {
            o += (size_t)snprintf(buf + o, len - o, "%d", seed);
            t++;
        } else if (t[0] == '@' && t[1] >= '0' && t[1] <= '7') {
            o += (size_t)snprintf(buf + o, len - o, "%s", vals[t[1] - '0']);
            t++;
        } else {
            buf[o++] = *t;
        }
    }
    buf[o] = '\0';
}

static cov_result run_stand(const cov_stand *s, int from_truth)
{
    cov_result res;
    memset(&res, 0, sizeof res);
    double sum[MAXP] = {0}, sum2[MAXP] = {0}, sumse[MAXP] = {0};
    char text[8192], name[64];
    for (int run = 0; run < s->runs; run++) {
        format_stand(text, sizeof text, s, from_truth ? s->truth : s->off, 1000 + run);
        snprintf(name, sizeof name, "ekf_cov_%s.cfg", s->name);
        capture c;
        simulate(&c, name, text, s->n);
        add_noise(&c, 0.01);
        vibid_ident_config cfg;
        vibid_ident_config_init(&cfg, s->h);
        vibid_ident *id = vibid_ident_create(vibid_stand_model(c.stand), &cfg);
        if (!id) fail_msg("vibid_ident_create: %s", vibid_last_error());
        vibid_ident_config used;
        assert_int_equal(vibid_ident_get_config(id, &used), VIBID_OK);
        assert_int_equal(used.estimator, VIBID_ESTIMATOR_EKF);
        if (vibid_ident_push_block(id, c.n, c.noisy) != VIBID_OK) fail_msg("push: %s", vibid_last_error());
        double theta[MAXP], se[MAXP];
        assert_int_equal(vibid_ident_estimate(id, theta, se, NULL), VIBID_OK);
        vibid_ident_quality q;
        assert_int_equal(vibid_ident_get_quality(id, &q, NULL), VIBID_OK);
        const int flagged = (q.flags & VIBID_QUALITY_SE_INVALID) != 0;
        res.flagged += flagged;
        for (size_t i = 0; i < s->p; i++) {
            const double t = c.truth[i], z = (theta[i] - t) / se[i];
            res.covered[i] += fabs(z) <= 2.0;
            res.covered_unflagged[i] += !flagged && fabs(z) <= 2.0;
            sum[i] += theta[i] / t - 1.0;
            sum2[i] += (theta[i] / t - 1.0) * (theta[i] / t - 1.0);
            sumse[i] += se[i] / t;
            if (!flagged) res.worst_z = fmax(res.worst_z, fabs(z));
        }
        if (getenv("EKF_COV_VERBOSE")) {
            printf("    run %2d flags %u zc %.2f z:", run, q.flags, q.z_consistency);
            for (size_t i = 0; i < s->p; i++) printf(" %+6.2f", (theta[i] - c.truth[i]) / se[i]);
            printf("\n");
        }
        vibid_ident_destroy(id);
        capture_free(&c);
    }
    res.runs = s->runs;
    for (size_t i = 0; i < s->p; i++) {
        const double m = sum[i] / s->runs;
        res.mean_err[i] = m;
        res.spread[i] = sqrt(fmax(sum2[i] / s->runs - m * m, 0.0) * s->runs / (s->runs - 1));
        res.mean_se[i] = sumse[i] / s->runs;
    }
    return res;
}

static void report(const cov_stand *s, const cov_result *r)
{
    int cov = 0, covu = 0;
    for (size_t i = 0; i < s->p; i++) {
        cov += r->covered[i];
        covu += r->covered_unflagged[i];
    }
    const int unflagged = r->runs - r->flagged;
    printf("  %s: %d realisations, %d flagged; coverage of 2-se intervals %.1f %% (unflagged %.1f %% of %d)\n",
           s->name, r->runs, r->flagged, 100.0 * cov / (r->runs * (double)s->p),
           unflagged ? 100.0 * covu / (unflagged * (double)s->p) : NAN, unflagged * (int)s->p);
    for (size_t i = 0; i < s->p; i++)
        printf("    param %zu: coverage %5.1f %%  mean error %+8.4f %%  spread %7.4f %%  mean se %7.4f %%  "
               "spread / se %5.2f  bias / spread %+5.2f\n",
               i, 100.0 * r->covered[i] / r->runs, 100 * r->mean_err[i], 100 * r->spread[i], 100 * r->mean_se[i],
               r->spread[i] / r->mean_se[i], r->mean_err[i] / r->spread[i]);
}

static int env_runs(int dflt)
{
    const char *e = getenv("EKF_COV_RUNS");
    return e && atoi(e) > 1 ? atoi(e) : SANITIZED ? 2 : dflt;
}

static int wanted(const char *name)
{
    const char *e = getenv("EKF_COV_STAND");
    return !e || !*e || strcmp(e, name) == 0;
}

/* The bounds above, for a stand whose error bars must hold unflagged. */
static void check_coverage(const cov_stand *s, const cov_result *r)
{
    int cov = 0;
    for (size_t i = 0; i < s->p; i++) cov += r->covered[i];
    assert_int_equal(r->flagged, 0);
    assert_true(cov >= 0.88 * r->runs * (double)s->p);
}

/* Runs the stand (unless EKF_COV_STAND names another) and, with the default settings,
 * checks its bounds: error bars that hold unflagged, or (flag_expected) flagged in at
 * least 90 % of the realisations. */
static void run_case(const cov_stand *s, int flag_expected)
{
    if (!wanted(s->name)) skip();
    cov_result r = run_stand(s, getenv("EKF_COV_TRUTH") != NULL);
    report(s, &r);
    /* under the sanitizers two realisations run the code paths, unchecked (capture.h) */
    if (getenv("EKF_COV_RUNS") || getenv("EKF_COV_TRUTH") || SANITIZED) return;
    if (flag_expected)
        assert_true(10 * r.flagged >= 9 * r.runs);
    else
        check_coverage(s, &r);
}

static void test_unmeasured(void **state)
{
    (void)state;
    const cov_stand s = {"unmeasured", unmeasured_fmt, unmeasured_off, unmeasured_truth, 4, 5000, 1e-3, env_runs(30)};
    run_case(&s, 0);
}

static void test_accel(void **state)
{
    (void)state;
    const cov_stand s = {"accel", accel_fmt, accel_off, accel_truth, 8, 8000, 5e-4, env_runs(30)};
    run_case(&s, 0);
}

static void test_impact(void **state)
{
    (void)state;
    const cov_stand s = {"impact", impact_fmt, impact_off, impact_truth, 6, 10000, 2e-4, env_runs(20)};
    run_case(&s, 1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_unmeasured),
        cmocka_unit_test(test_accel),
        cmocka_unit_test(test_impact),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
