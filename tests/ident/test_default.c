/* ident.default: identification with no estimator settings at all (vibid_ident_config_init:
 * the automatic estimator, identify.h) on data simulated by vibid-sim's engine, for the
 * three stand types of the issue "right answers by default":
 *   chain  3 DOF (ground - m1 - m2 - m3), springs and dampers unknown, a held force on m3
 *          (band-limited noise), displacement and acceleration measured on every mass;
 *   cubic  1 DOF with a strong cubic spring (cubic force = linear force at 1 mm), force
 *          smooth, only the displacement measured;
 *   base   2 DOF on a moving base whose displacement is held between samples, a damper to
 *          the base (its impulses are simulated, docs/sim.md), x1, x2 and s measured.
 * The stands give no nominal values: the automatic choice cannot lean on them.
 *
 * Targets and why they are what they are:
 *  - accuracy (one seeded realisation, 20 s at 2 kHz): chain with 0.5 % noise: every
 *    stiffness within 0.05 %, every damping and damping ratio within 1 % (the issue's
 *    targets); noise-free chain: stiffness 0.01 %, damping 0.5 %; noise-free cubic: linear
 *    and cubic stiffness within 0.05 %. Each estimate also within 3 of its own standard
 *    errors, noise-free too (there the error bar is the discretization-bias bound and the
 *    batch-means spread of the deterministic residuals); a fixed seed: no chance of a
 *    flaky 3-sigma miss.
 *  - coverage (Monte Carlo, 200 noise realisations per stand on one simulated response):
 *    the fraction of |theta - truth| <= 2 se, pooled over the stand's parameters (200 p
 *    trials, binomial standard deviation about 0.6 %), must lie in [90 %, 98 %] (the
 *    issue's band around the nominal 95.4 %). Per-parameter figures are printed.
 * Noise: white Gaussian, standard deviation = level x RMS of the clean channel, on every
 * measured displacement, acceleration and base channel (not on the force: a force sensor's
 * noise is not in the cases), from a fixed xorshift seed. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <cmocka.h>

#include <vibid/identify.h>
#include <vibid/modal.h>
#include <vibid/stand_file.h>

#include "sim_config.h"
#include "sim_engine.h"
#include "sim_test_util.h"
#include "capture.h"
#include "chain_stand.h"
#include "cubic_stand.h"
#include "two_stands.h"

#define FS 2000.0
#define SECONDS 20.0
#define MC_RUNS 200


static double fmax3(const double *f)
{
    double v = 0.0;
    for (int i = 0; i < 4 && f[i] == f[i]; i++)
        if (f[i] > v) v = f[i];
    return v;
}

typedef struct result {
    double theta[8], se[8];
    double zeta[4], zeta_se[4];
    unsigned flags;
} result;

/* Identification of c->noisy: the defaults, or (est != NULL) explicit settings. */
static result identify_with(const capture *c, int print, const vibid_ident_config *est);
static result identify(const capture *c, int print) { return identify_with(c, print, NULL); }

static result identify_with(const capture *c, int print, const vibid_ident_config *est)
{
    const vibid_model *m = vibid_stand_model(c->stand);
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 1.0 / FS);
    if (est) cfg = *est;
    vibid_ident *id = vibid_ident_create(m, &cfg);
    if (!id) fail_msg("vibid_ident_create: %s", vibid_last_error());
    if (vibid_ident_push_block(id, c->n, c->noisy) != VIBID_OK) fail_msg("push: %s", vibid_last_error());
    if (print) {
        /* After the samples: with the pre-filter the pilot chose (identify.h). */
        char buf[4096];
        vibid_ident_describe(id, buf, sizeof buf, NULL);
        printf("%s", buf);
    }
    result r;
    double cov[64];
    if (vibid_ident_estimate(id, r.theta, r.se, NULL) != VIBID_OK) fail_msg("estimate: %s", vibid_last_error());
    assert_int_equal(vibid_ident_covariance(id, cov), VIBID_OK);
    vibid_ident_quality q;
    assert_int_equal(vibid_ident_get_quality(id, &q, NULL), VIBID_OK);
    r.flags = q.flags;
    vibid_model_dims d;
    vibid_model_get_dims(m, &d);
    double f[4], fse[4];
    assert_int_equal(vibid_model_modal(m, r.theta, cov, f, fse, r.zeta, r.zeta_se, NULL, NULL), VIBID_OK);
    if (print)
        printf("  quality: flags %u, consistency z %.2f, %zu blocks, bias bound %.2g\n", q.flags, q.z_consistency,
               q.n_blocks, q.bias_relative);
    vibid_ident_destroy(id);
    return r;
}

static void true_zeta(const capture *c, double *zeta)
{
    double f[4];
    assert_int_equal(vibid_model_modal(vibid_stand_model(c->stand), c->truth, NULL, f, NULL, zeta, NULL, NULL, NULL),
                     VIBID_OK);
}

/* One realisation against per-kind bounds (relative): stiffness/cubic, damping/zeta. */
static void check_accuracy(capture *c, double level, double tol_stiff, double tol_damp, int check_3se)
{
    add_noise(c, level);
    result r = identify(c, 1);
    const vibid_model *m = vibid_stand_model(c->stand);
    for (size_t i = 0; i < c->p; i++) {
        vibid_param_info pi;
        vibid_model_param_info(m, i, &pi);
        double rel = (r.theta[i] - c->truth[i]) / c->truth[i];
        double z = (r.theta[i] - c->truth[i]) / r.se[i];
        double tol = pi.kind == VIBID_PARAM_DAMPING ? tol_damp : tol_stiff;
        printf("  %-4s %14.8g  truth %-10g  err %+9.5f %%  se %8.5f %%  z %+5.2f  (bound %g %%)\n", pi.name, r.theta[i],
               c->truth[i], 100 * rel, 100 * r.se[i] / fabs(c->truth[i]), z, 100 * tol);
        assert_true(fabs(rel) <= tol);
        if (check_3se) assert_true(fabs(z) <= 3.0);
    }
    vibid_model_dims d;
    vibid_model_get_dims(m, &d);
    double zt[4];
    true_zeta(c, zt);
    for (size_t i = 0; i < d.n_dof; i++) {
        double rel = (r.zeta[i] - zt[i]) / zt[i];
        printf("  zeta%zu %.6f  truth %.6f  err %+8.4f %%  se %.4f %%\n", i + 1, r.zeta[i], zt[i], 100 * rel,
               100 * r.zeta_se[i] / zt[i]);
        assert_true(fabs(rel) <= tol_damp);
    }
    assert_int_equal(r.flags & VIBID_QUALITY_SE_INVALID, 0);
}

/* For the README: one realisation (the next noise draw) with plain LS on central
 * differences (1.17), RLS on (1.17) without pre-filter (the former default, now with the hold equivalents) and the automatic
 * estimator; relative errors in % and |error| / se. Prints only. */
static void compare(capture *c, double level)
{
    add_noise(c, level);
    const vibid_model *m = vibid_stand_model(c->stand);
    vibid_ident_config ls, rls, aut;
    vibid_ident_config_init(&ls, 1.0 / FS);
    ls.estimator = VIBID_ESTIMATOR_LS;
    ls.prefilter_hz = 0.0;
    ls.difference_order = 2;
    rls = ls;
    rls.estimator = VIBID_ESTIMATOR_RLS;
    vibid_ident_config_init(&aut, 1.0 / FS);
    const char *names[3] = {"plain LS, (1.17)", "RLS, (1.17), no filter", "automatic (default)"};
    const vibid_ident_config *cfgs[3] = {&ls, &rls, &aut};
    printf("comparison at %.1f %% noise (one realisation): error %% [|error| / se]\n", 100 * level);
    for (int k = 0; k < 3; k++) {
        result r = identify_with(c, 0, cfgs[k]);
        printf("  %-22s", names[k]);
        for (size_t i = 0; i < c->p; i++) {
            vibid_param_info pi;
            vibid_model_param_info(m, i, &pi);
            printf("  %s %+.3f [%.1f]", pi.name, 100 * (r.theta[i] - c->truth[i]) / c->truth[i],
                   fabs(r.theta[i] - c->truth[i]) / r.se[i]);
        }
        printf("\n");
    }
}

/* Monte Carlo: MC_RUNS noise realisations on the same clean response. */
static void check_coverage(capture *c, const char *what, double level)
{
    const vibid_model *m = vibid_stand_model(c->stand);
    size_t in2[8] = {0}, total = 0, inside = 0, flagged = 0;
    double sum_z2[8] = {0};
    for (int run = 0; run < MC_RUNS; run++) {
        add_noise(c, level);
        result r = identify(c, 0);
        if (r.flags & VIBID_QUALITY_SE_INVALID) flagged++;
        for (size_t i = 0; i < c->p; i++) {
            double z = (r.theta[i] - c->truth[i]) / r.se[i];
            sum_z2[i] += z * z;
            if (fabs(z) <= 2.0) {
                in2[i]++;
                inside++;
            }
            total++;
        }
    }
    double cov = (double)inside / (double)total;
    printf("%s, %.1f %% noise, %d realisations: 2-se coverage %.1f %% pooled over %zu parameters; rows flagged "
           "SE-invalid: %zu\n",
           what, 100 * level, MC_RUNS, 100 * cov, c->p, flagged);
    for (size_t i = 0; i < c->p; i++) {
        vibid_param_info pi;
        vibid_model_param_info(m, i, &pi);
        printf("  %-4s coverage %5.1f %%  rms(z) %.2f\n", pi.name, 100.0 * (double)in2[i] / MC_RUNS,
               sqrt(sum_z2[i] / MC_RUNS));
    }
    assert_true(cov >= 0.90 && cov <= 0.98);
}

static void test_chain(void **state)
{
    (void)state;
    capture c;
    simulate(&c, "ident_chain.cfg", chain_stand, (size_t)(SECONDS * FS));
    printf("chain, noise-free:\n");
    check_accuracy(&c, 0.0, 1e-4, 5e-3, 1);
    printf("chain, 0.5 %% noise:\n");
    check_accuracy(&c, 0.005, 5e-4, 1e-2, 1);
    compare(&c, 0.005);
    check_coverage(&c, "chain", 0.005);
    capture_free(&c);
}

/* RLS with the automatic prior (rls_alpha 0, scaled to the data) on the noise-free cubic
 * oscillator: the cubic coefficient (N/m^3, ~1e10) must come out like batch LS on the same
 * data, within 0.05 % as the automatic estimator; with the fixed alpha = 1e-9 (the former
 * default) the prior outweighs the x^3 column (sum of squares ~1e-14) and eps is lost. */
static void check_rls_prior(capture *c)
{
    add_noise(c, 0.0);
    vibid_ident_config rls;
    vibid_ident_config_init(&rls, 1.0 / FS);
    rls.estimator = VIBID_ESTIMATOR_RLS;
    result r = identify_with(c, 0, &rls);
    rls.rls_alpha = 1e-9;
    result fixed = identify_with(c, 0, &rls);
    const vibid_model *m = vibid_stand_model(c->stand);
    for (size_t i = 0; i < c->p; i++) {
        vibid_param_info pi;
        vibid_model_param_info(m, i, &pi);
        double rel = (r.theta[i] - c->truth[i]) / c->truth[i];
        printf("  RLS, automatic prior: %s err %+.5f %%  (alpha 1e-9: %+.3f %%)\n", pi.name, 100 * rel,
               100 * (fixed.theta[i] - c->truth[i]) / c->truth[i]);
        assert_true(fabs(rel) <= (pi.kind == VIBID_PARAM_DAMPING ? 5e-3 : 5e-4));
    }
}

static void test_cubic(void **state)
{
    (void)state;
    capture c;
    simulate(&c, "ident_cubic.cfg", cubic_stand, (size_t)(SECONDS * FS));
    printf("cubic, noise-free:\n");
    check_accuracy(&c, 0.0, 5e-4, 5e-3, 1);
    check_rls_prior(&c);
    compare(&c, 0.0);
    compare(&c, 0.005);
    check_coverage(&c, "cubic", 0.005);
    capture_free(&c);
}

static void test_base(void **state)
{
    (void)state;
    capture c;
    simulate(&c, "ident_base.cfg", base_stand, (size_t)(SECONDS * FS));
    printf("base-excited, held base, noise-free:\n");
    check_accuracy(&c, 0.0, 1e-4, 5e-3, 1);
    printf("base-excited, held base, 0.5 %% noise:\n");
    check_accuracy(&c, 0.005, 5e-3, 5e-2, 1);
    compare(&c, 0.005);
    check_coverage(&c, "base-excited", 0.005);
    capture_free(&c);
}

/* Corners: the paper's example 1 (two masses, c1 and d between them, c2 to a base moving
 * as a 5 Hz triangle of 1 mm, continuous), the demo's stand. The corners of the triangle
 * fall on samples (every 200th at 2 kHz), as they do where the excitation is generated on
 * the sampling clock; the response's third derivative jumps there, and its aliasing
 * biases every stencil the same way, h^2 (c1 +0.026 % noise-free, 14 of the former
 * standard errors, which bounded only the smooth (w h)^4 / 30 bias). The discretization
 * check on every second sample measures it (identify.h). Expected: noise-free, every
 * estimate within 3 of its standard errors and the measured bias at least half c1's actual
 * error (the check is exact for corners on samples: 1/2 leaves room for the few samples'
 * phase of the pre-filter); at 0.1 % noise (the demo's 60 dB) the pooled 2-se coverage of
 * 200 realisations within [90 %, 98 %] (before the check: c1 was at 2 to 4 se). 12 s, as
 * the demo's printed run. */
static const char *corner_stand =
    "stand = { name = \"corners\"; sample_rate = 2000.0; discretization = \"central_difference\";\n"
    "  nodes = ( { name = \"m1\"; mass = 10.0; measure = { displacement = \"x1\"; }; },\n"
    "            { name = \"m2\"; mass = 20.0; measure = { displacement = \"x2\"; }; } );\n"
    "  base = { measure = { displacement = \"s\"; }; };\n"
    "  elements = ( { name = \"c1\"; kind = \"spring\"; between = [\"m1\", \"m2\"]; unknown = true; true_value = 2.5e5; },\n"
    "    { name = \"d\"; kind = \"damper\"; between = [\"m1\", \"m2\"]; unknown = true; true_value = 300.0; },\n"
    "    { name = \"c2\"; kind = \"spring\"; between = [\"m2\", \"base\"]; unknown = true; true_value = 1.5e6; } ); };\n"
    "simulation = { seed = 7; hold = \"smooth\";\n"
    "  excitation = ( { target = \"base\"; kind = \"triangle\"; amplitude = 1.0e-3; frequency = 5.0; } ); };\n";

static void test_corners(void **state)
{
    (void)state;
    capture c;
    simulate(&c, "ident_corners.cfg", corner_stand, (size_t)(12.0 * FS));
    printf("corners (paper example 1, triangle base), noise-free:\n");
    add_noise(&c, 0.0);
    result r = identify(&c, 1);
    double c1_err = fabs(r.theta[0] - c.truth[0]) / c.truth[0];
    for (size_t i = 0; i < c.p; i++) {
        double z = (r.theta[i] - c.truth[i]) / r.se[i];
        printf("  %zu: err %+9.5f %%  se %8.5f %%  z %+5.2f\n", i, 100 * (r.theta[i] - c.truth[i]) / c.truth[i],
               100 * r.se[i] / c.truth[i], z);
        assert_true(fabs(z) <= 3.0);
    }
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 1.0 / FS);
    vibid_ident *id = vibid_ident_create(vibid_stand_model(c.stand), &cfg);
    assert_non_null(id);
    assert_int_equal(vibid_ident_push_block(id, c.n, c.noisy), VIBID_OK);
    double th[3], se[3];
    assert_int_equal(vibid_ident_estimate(id, th, se, NULL), VIBID_OK);
    vibid_ident_quality q;
    assert_int_equal(vibid_ident_get_quality(id, &q, NULL), VIBID_OK);
    printf("  measured discretization error %.3g, c1's actual error %.3g\n", q.bias_relative, c1_err);
    assert_true(q.bias_relative >= 0.5 * c1_err);
    vibid_ident_destroy(id);
    check_coverage(&c, "corners", 0.001);
    capture_free(&c);
}

/* A stretch that does not excite some parameters: 1 DOF with unknown mass, spring and
 * damper, tracked with forgetting 0.999 (memory 1000 samples). 10 s of two sines (7 and
 * 20 Hz) separate all three; then 10 s of the 20 Hz sine alone, at which mass and spring
 * act only as k - m w^2 while the damper stays determined. The response is the exact
 * steady state (noise-free). Expected: all three estimates unflagged and within 1e-4 at the
 * end of the first stretch; at the end of the second, m and k flagged not excited with
 * infinite standard errors, d unflagged and within 1e-4 (the stencils' bias at 20 Hz is
 * 5e-7; 1e-4 is still far below the 4-12 % by which m and k drift in the unexcited
 * direction). */
static void test_not_excited(void **state)
{
    (void)state;
    const double h = 1.0 / 2000.0, M = 2.0, K = 1.0e4, Dd = 10.0, truth[3] = {M, K, Dd};
    vibid_model *m = vibid_model_create();
    size_t a, in;
    assert_int_equal(vibid_model_add_node(m, "m", M, 1, &a), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, a, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "k", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, K, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "d", VIBID_ELEMENT_DAMPER, a, VIBID_GROUND, Dd, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_input(m, "f", a, 1.0, 0, &in), VIBID_OK);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, h);
    cfg.forgetting = 0.999;
    vibid_ident *id = vibid_ident_create(m, &cfg);
    if (!id) fail_msg("%s", vibid_last_error());
    const double w[2] = {2 * M_PI * 20.0, 2 * M_PI * 7.0}, amp[2] = {1.0, 0.5}, phase[2] = {0.0, 1.0};
    for (int k = 0; k < 40000; k++) {
        double t = k * h, u = 0.0, x = 0.0;
        for (int j = 0; j < (k < 20000 ? 2 : 1); j++) {
            double re = K - M * w[j] * w[j], im = Dd * w[j];
            u += amp[j] * sin(w[j] * t + phase[j]);
            x += amp[j] * sin(w[j] * t + phase[j] - atan2(im, re)) / sqrt(re * re + im * im);
        }
        double ch[2] = {x, u};
        assert_int_equal(vibid_ident_push(id, ch), VIBID_OK);
        if (k == 19999 || k == 39999) {
            double th[3], se[3];
            unsigned pf[3];
            vibid_ident_quality q;
            assert_int_equal(vibid_ident_estimate(id, th, se, NULL), VIBID_OK);
            assert_int_equal(vibid_ident_get_quality(id, &q, pf), VIBID_OK);
            printf("  %s: m %.6g k %.6g d %.6g, se %.3g %.3g %.3g, flags %u (per parameter %u %u %u)\n",
                   k < 20000 ? "two sines" : "one sine", th[0], th[1], th[2], se[0], se[1], se[2], q.flags, pf[0], pf[1],
                   pf[2]);
            if (k < 20000) {
                assert_int_equal(q.flags & VIBID_QUALITY_NOT_EXCITED, 0);
                for (int i = 0; i < 3; i++) assert_true(fabs(th[i] - truth[i]) <= 1e-4 * truth[i]);
            } else {
                assert_true(q.flags & VIBID_QUALITY_NOT_EXCITED);
                assert_true((pf[0] & VIBID_QUALITY_NOT_EXCITED) && isinf(se[0]));
                assert_true((pf[1] & VIBID_QUALITY_NOT_EXCITED) && isinf(se[1]));
                assert_int_equal(pf[2] & VIBID_QUALITY_NOT_EXCITED, 0);
                assert_true(fabs(th[2] - Dd) <= 1e-4 * Dd);
            }
        }
    }
    vibid_ident_destroy(id);
    vibid_model_destroy(m);
}

/* Pushes samples [from, to) of c->noisy, one by one; sample `gap` (if in range) as NaN. */
static void push_range(vibid_ident *id, const capture *c, size_t from, size_t to, size_t gap)
{
    double ch[16];
    assert_true(c->nch <= 16);
    for (size_t k = from; k < to; k++) {
        for (size_t j = 0; j < c->nch; j++) ch[j] = k == gap ? NAN : c->noisy[k + j * c->n];
        vibid_status s = vibid_ident_push(id, ch);
        assert_int_equal(s, k == gap ? VIBID_E_NONFINITE : VIBID_OK);
    }
}

/* Auto (the pilot chooses the cutoff) against an estimator configured from the start with
 * the cutoff it chose, on the same samples (sample `gap` NaN): the estimates and their
 * standard errors must be bit-identical, i.e. the replay of the pilot's samples loses
 * nothing and adds nothing. Returns the chosen cutoff. */
static double pilot_against_explicit(const capture *c, size_t gap, double *theta, double *se)
{
    const vibid_model *m = vibid_stand_model(c->stand);
    vibid_ident_config cfg, used;
    vibid_ident_config_init(&cfg, 1.0 / FS);
    vibid_ident *id = vibid_ident_create(m, &cfg);
    assert_non_null(id);
    const size_t pilot = 4096;  /* max(4096, 2 s) at 2 kHz (identify.h) */
    push_range(id, c, 0, pilot - 1, gap);
    assert_int_equal(vibid_ident_get_config(id, &used), VIBID_OK);
    assert_true(used.prefilter_hz == FS / 20.0);  /* still the pilot's f_a / 20 */
    push_range(id, c, pilot - 1, c->n, gap);
    assert_int_equal(vibid_ident_get_config(id, &used), VIBID_OK);
    const double fc = used.prefilter_hz;
    assert_int_equal(vibid_ident_estimate(id, theta, se, NULL), VIBID_OK);
    vibid_ident_config ecfg = cfg;
    ecfg.prefilter_hz = fc;
    vibid_ident *ex = vibid_ident_create(m, &ecfg);
    assert_non_null(ex);
    push_range(ex, c, 0, c->n, gap);
    double th2[8], se2[8];
    assert_int_equal(vibid_ident_estimate(ex, th2, se2, NULL), VIBID_OK);
    for (size_t i = 0; i < c->p; i++) {
        assert_true(theta[i] == th2[i]);
        assert_true(se[i] == se2[i]);
    }
    assert_int_equal(vibid_ident_get_config(ex, &ecfg), VIBID_OK);
    assert_int_equal(used.iv_lag, ecfg.iv_lag);
    vibid_ident_destroy(ex);
    vibid_ident_destroy(id);
    return fc;
}

/* The pilot's figure of merit for an explicit cutoff, computed outside the library: an
 * estimator configured with that cutoff from the start, fed the pilot's samples [0, n),
 * sum over the parameters of (se / theta)^2. Also returns the highest natural frequency of
 * its estimate in *fmax (when fmax != NULL). */
static double pilot_score(const capture *c, size_t n, double fc, double *fmax)
{
    const vibid_model *m = vibid_stand_model(c->stand);
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 1.0 / FS);
    cfg.prefilter_hz = fc;
    vibid_ident *id = vibid_ident_create(m, &cfg);
    assert_non_null(id);
    push_range(id, c, 0, n, (size_t)-1);
    double th[8], se[8], f[4] = {NAN, NAN, NAN, NAN}, z[4];
    assert_int_equal(vibid_ident_estimate(id, th, se, NULL), VIBID_OK);
    double sum = 0.0;
    for (size_t i = 0; i < c->p; i++) sum += (se[i] / th[i]) * (se[i] / th[i]);
    if (fmax) {
        assert_int_equal(vibid_model_modal(m, th, NULL, f, NULL, z, NULL, NULL, NULL), VIBID_OK);
        *fmax = fmax3(f);
    }
    vibid_ident_destroy(id);
    return sum;
}

/* The cutoff the pilot's rule (identify.h) must choose, re-derived here from explicit
 * estimators on the pilot's samples: f_max from the estimate at f_a/20; candidates f_a/20,
 * f_a/50, 2 and 4 x f_max (each within [f_a/50, f_a/8]; none below 2 f_max / 1.1 unless
 * it is f_a/8; each more than 10 % from the ones before); the smallest score wins. */
static double pilot_rule(const capture *c, size_t n)
{
    double f_hi;
    const double base = pilot_score(c, n, FS / 20.0, &f_hi);
    const double lowest = 2.0 * f_hi / 1.1;
    const double cand[3] = {FS / 50.0, fmin(fmax(2.0 * f_hi, FS / 50.0), FS / 8.0),
                            fmin(fmax(4.0 * f_hi, FS / 50.0), FS / 8.0)};
    double taken[4] = {FS / 20.0};
    size_t n_taken = 1;
    double best = FS / 20.0, best_score = FS / 20.0 >= lowest ? base : HUGE_VAL;
    printf("  candidate %.4g Hz (f_a/20): score %.3g; highest mode of the pilot's estimate %.4g Hz\n", FS / 20.0,
           base, f_hi);
    for (size_t k = 0; k < 3; k++) {
        int distinct = cand[k] >= lowest || cand[k] == FS / 8.0;
        for (size_t l = 0; l < n_taken; l++) distinct = distinct && fabs(cand[k] / taken[l] - 1.0) > 0.1;
        if (!distinct) continue;
        taken[n_taken++] = cand[k];
        const double sc = pilot_score(c, n, cand[k], NULL);
        printf("  candidate %.4g Hz: score %.3g\n", cand[k], sc);
        if (sc < best_score) {
            best_score = sc;
            best = cand[k];
        }
    }
    return best;
}

/* The pre-filter cutoff from the data (the stands give no nominal values): after the
 * pilot (the first 4096 samples at 2 kHz), the candidate cutoff whose estimate over the
 * pilot has the smallest sum of relative variances.
 *  - chain, 0.5 % noise, highest mode 37.5 Hz: the cutoff equals (exactly) the one the
 *    rule gives when re-derived here from explicit estimators (pilot_rule) and is not below
 *    2 x the true highest mode / 1.1; the run is bit-identical to the explicit setting,
 *    with and without a gap inside the pilot.
 *  - a 1-DOF stand with its mode at 120 Hz, above f_a/40 = 50 Hz, where f_a/20 (100 Hz)
 *    would filter out its resonance: the pilot raises the cutoff to at least 2 x 120 Hz.
 *    Printed against the fixed f_a/20; asserted: auto within 3 of its standard errors. */
static void test_pilot(void **state)
{
    (void)state;
    capture c;
    simulate(&c, "ident_pilot_chain.cfg", chain_stand, (size_t)(SECONDS * FS));
    add_noise(&c, 0.005);
    double f[4] = {NAN, NAN, NAN, NAN}, z[4], th[8], se[8];
    assert_int_equal(vibid_model_modal(vibid_stand_model(c.stand), c.truth, NULL, f, NULL, z, NULL, NULL, NULL),
                     VIBID_OK);
    const double fmax_true = fmax3(f);
    double fc = pilot_against_explicit(&c, (size_t)-1, th, se);
    printf("pilot, chain: cutoff %.4g Hz for a highest mode of %.4g Hz\n", fc, fmax_true);
    assert_true(fc == pilot_rule(&c, 4096));
    assert_true(fc >= 2.0 * fmax_true / 1.1 * 0.99);  /* 1 %: the pilot's f_max, not the true one */
    pilot_against_explicit(&c, 1000, th, se);
    capture_free(&c);

    simulate(&c, "ident_pilot_high.cfg", high_stand, (size_t)(SECONDS * FS));
    add_noise(&c, 0.005);
    fc = pilot_against_explicit(&c, (size_t)-1, th, se);
    printf("pilot, 1 DOF at 120 Hz: cutoff %.4g Hz\n", fc);
    assert_true(fc == pilot_rule(&c, 4096));
    assert_true(fc >= 240.0 * 0.99 && fc <= FS / 8.0);
    vibid_ident_config fixed;
    vibid_ident_config_init(&fixed, 1.0 / FS);
    fixed.prefilter_hz = FS / 20.0;
    const result r = identify_with(&c, 0, &fixed);
    for (size_t i = 0; i < c.p; i++) {
        printf("  %-3s auto %+.4f %% (se %.4f %%), f_a/20 %+.4f %% (se %.4f %%)\n", i ? "d" : "k",
               100.0 * (th[i] / c.truth[i] - 1.0), 100.0 * se[i] / c.truth[i],
               100.0 * (r.theta[i] / c.truth[i] - 1.0), 100.0 * r.se[i] / c.truth[i]);
        assert_true(fabs(th[i] - c.truth[i]) <= 3.0 * se[i]);
    }
    capture_free(&c);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_chain),
        cmocka_unit_test(test_cubic),
        cmocka_unit_test(test_base),
        cmocka_unit_test(test_not_excited),
        cmocka_unit_test(test_corners),
        cmocka_unit_test(test_pilot),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
