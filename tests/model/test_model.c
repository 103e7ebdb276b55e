/* test_model.c: models, discretization, modal parameters and identification of the
 * paper's example 1 (issue 3 targets). The stand: m1 = 10 kg, m2 = 20 kg, c1 = 2.5e5 N/m,
 * d = 300 N s/m (m1-m2), c2 = 1.5e6 N/m (m2-base), 2 kHz, triangle base 5 Hz, 1 mm.
 * It is read from examples/stands/paper_example1.cfg by the shared loader, as the example
 * programs read it. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <vibid/vibid.h>

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

#include "support/example_common.h"
#include "support/stand_sim.h"

#define H (1.0 / 2000.0)
static const double truth[3] = {2.5e5, 300.0, 1.5e6}; /* c1, d, c2 */

/* The example-1 stand file with the given discretization (example_load_stand). */
static vibid_stand *stand_example1(vibid_discretization disc) {
    vibid_stand *st = example_load_stand(VIBID_SOURCE_DIR "/examples/stands/paper_example1.cfg", (int)disc);
    assert_non_null(st);
    for (int i = 0; i < 3; ++i) assert_float_equal(vibid_stand_true_values(st)[i], truth[i], 0.0);
    return st;
}

static double *simulate(const vibid_model *m, size_t n, int hold) {
    vibid_model_dims dims;
    assert_int_equal(vibid_model_get_dims(m, &dims), VIBID_OK);
    double *rec = malloc(n * dims.n_channels * sizeof(double));
    assert_non_null(rec);
    stand_sim_config sc = {H, n, 20, hold, 1e-3, 5.0, 0.0, 0.0};
    assert_int_equal(stand_sim_run(m, truth, &sc, rec), 0);
    return rec;
}

static void estimate(const vibid_model *m, vibid_estimator est, double pf, size_t lag, const double *rec, size_t n,
                     double *theta) {
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, H);
    cfg.estimator = est;
    cfg.prefilter_hz = pf;
    if (lag) cfg.iv_lag = lag;
    vibid_ident *id = vibid_ident_create(m, &cfg);
    if (!id) fail_msg("ident_create: %s", vibid_last_error());
    assert_int_equal(vibid_ident_push_block(id, n, rec), VIBID_OK);
    double se[3];
    vibid_status s = vibid_ident_estimate(id, theta, se, NULL);
    if (s != VIBID_OK) fail_msg("estimate: %s", vibid_last_error());
    vibid_ident_destroy(id);
}

/* Noise-free, base held over each interval: the difference form (1.16) is exact, so
 * ZOH + LS must return the truth up to rounding and the RK4 error (~1e-9); 1e-4 is the
 * issue's target. */
static void test_zoh_noise_free(void **state) {
    (void)state;
    vibid_stand *st = stand_example1(VIBID_DISC_ZOH);
    const vibid_model *m = vibid_stand_model(st);
    double *rec = simulate(m, 4000, 1);
    double th[3];
    estimate(m, VIBID_ESTIMATOR_LS, 0.0, 0, rec, 4000, th);
    for (int i = 0; i < 3; ++i) {
        double rel = fabs(th[i] - truth[i]) / truth[i];
        printf("  zoh noise-free: param %d = %.9g (rel err %.2e)\n", i, th[i], rel);
        assert_true(rel < 1e-4);
    }
    free(rec);
    vibid_stand_destroy(st);
}

/* Noise-free, continuous triangle: central differences carry an O((omega h)^2 / 12)
 * bias, 0.2 % at the 48 Hz mode and 2 kHz; the bound is 1 %. */
static void test_central_difference_noise_free(void **state) {
    (void)state;
    vibid_stand *st = stand_example1(VIBID_DISC_CENTRAL_DIFFERENCE);
    const vibid_model *m = vibid_stand_model(st);
    double *rec = simulate(m, 4000, 0);
    double th[3];
    estimate(m, VIBID_ESTIMATOR_LS, 0.0, 0, rec, 4000, th);
    for (int i = 0; i < 3; ++i) {
        double rel = fabs(th[i] - truth[i]) / truth[i];
        printf("  cd noise-free: param %d = %.9g (rel err %.2e)\n", i, th[i], rel);
        assert_true(rel < 0.01);
    }
    free(rec);
    vibid_stand_destroy(st);
}

/* 1 % of RMS white noise on x1, x2, s; N = 20,000; 50 realisations (one simulation, 50
 * noise draws: the noise is what varies). Best offered estimator: central differences with
 * the 150 Hz pre-filter and LS. Targets (issue 3): mean absolute relative error < 2 % on
 * c1, c2 and < 10 % on d. */
static void test_noisy_monte_carlo(void **state) {
    (void)state;
    const size_t n = 20000, runs = 50;
    vibid_stand *st = stand_example1(VIBID_DISC_CENTRAL_DIFFERENCE);
    const vibid_model *m = vibid_stand_model(st);
    double *clean = simulate(m, n, 0);
    double *rec = malloc(n * 3 * sizeof(double));
    double mare[3] = {0, 0, 0};
    uint64_t seed = 12345;
    for (size_t k = 0; k < runs; ++k) {
        memcpy(rec, clean, n * 3 * sizeof(double));
        stand_sim_add_noise(rec, n, 3, 0.01, &seed);
        double th[3];
        estimate(m, VIBID_ESTIMATOR_LS, 150.0, 0, rec, n, th);
        for (int i = 0; i < 3; ++i) mare[i] += fabs(th[i] - truth[i]) / truth[i] / (double)runs;
    }
    printf("  noisy MC (%zu runs): mean abs rel err c1 %.3f %%, d %.3f %%, c2 %.3f %%\n", runs, 100 * mare[0],
           100 * mare[1], 100 * mare[2]);
    assert_true(mare[0] < 0.02);
    assert_true(mare[2] < 0.02);
    assert_true(mare[1] < 0.10);
    free(rec);
    free(clean);
    vibid_stand_destroy(st);
}

/* ---- RLS start values (vibid_ident_set_prior), for the daemon ---- */
static void expect_error_status(vibid_status got, vibid_status want, const char *needle) {
    assert_int_equal(got, want);
    if (!strstr(vibid_last_error(), needle)) fail_msg("message '%s' lacks '%s'", vibid_last_error(), needle);
}

/* Pushes samples first .. first + count - 1 of a record (n x 3, column-major). */
static void push_samples(vibid_ident *id, const double *rec, size_t n, size_t first, size_t count) {
    for (size_t k = first; k < first + count; ++k) {
        const double sample[3] = {rec[k], rec[k + n], rec[k + 2 * n]};
        assert_int_equal(vibid_ident_push(id, sample), VIBID_OK);
    }
}

static vibid_ident *rls_ident(const vibid_model *m) {
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, H);
    cfg.estimator = VIBID_ESTIMATOR_RLS;
    /* the fixed weak prior and (1.17) without pre-filter, on which the figures below rest */
    cfg.rls_alpha = 1e-9;
    cfg.prefilter_hz = 0.0;
    cfg.difference_order = 2;
    vibid_ident *id = vibid_ident_create(m, &cfg);
    if (!id) fail_msg("ident_create: %s", vibid_last_error());
    return id;
}

static double max_rel_err(const double *th) {
    double e = 0.0;
    for (int i = 0; i < 3; ++i) e = fmax(e, fabs(th[i] - truth[i]) / truth[i]);
    return e;
}

/* Central differences, 1 % noise: from the truth with a tight P0 the first estimates stay
 * at the truth, while the same 20 samples without a prior are far off (raw central
 * differences amplify the noise). P0 = diag((1e-3 theta_i)^2) / (1e3 N)^2: a prior
 * standard deviation of 0.1 % if the equation error is 1 kN (it is of that order here:
 * 1e-5 m of noise through 1 / h^2 on 20 kg); each sample adds ~1e-6 m^2 to P^-1, far
 * below P0^-1 ~ 16, so after 20 samples the estimate may move by well under 1 %. */
static void test_ident_prior_central_difference(void **state) {
    (void)state;
    const size_t n = 2000;
    vibid_stand *st = stand_example1(VIBID_DISC_CENTRAL_DIFFERENCE);
    const vibid_model *m = vibid_stand_model(st);
    double *rec = simulate(m, n, 0);
    uint64_t seed = 777;
    stand_sim_add_noise(rec, n, 3, 0.01, &seed);
    double P0[9] = {0};
    for (int i = 0; i < 3; ++i) P0[i * 4] = pow(1e-3 * truth[i], 2) / 1e6;
    double th[3], th2[3], se[3];

    vibid_ident *id = rls_ident(m);
    assert_int_equal(vibid_ident_set_prior(id, truth, P0), VIBID_OK);
    /* Before any sample the estimate is the prior itself (exact copy). */
    assert_int_equal(vibid_ident_estimate(id, th, se, NULL), VIBID_OK);
    for (int i = 0; i < 3; ++i) assert_float_equal(th[i], truth[i], 1e-12 * truth[i]);
    push_samples(id, rec, n, 0, 20);
    assert_int_equal(vibid_ident_estimate(id, th, se, NULL), VIBID_OK);
    const double err_prior = max_rel_err(th);

    vibid_ident *plain = rls_ident(m);
    push_samples(plain, rec, n, 0, 20);
    assert_int_equal(vibid_ident_estimate(plain, th2, NULL, NULL), VIBID_OK);
    const double err_plain = max_rel_err(th2);
    printf("  prior: after 20 noisy samples max rel err %.2e from the truth, %.2e without prior\n", err_prior,
           err_plain);
    assert_true(err_prior < 0.01);
    assert_true(err_plain > 0.05); /* the prior is what keeps the estimate: it is used */

    /* Bad input: rejected, and the identification is left as it was (same estimate,
     * bit for bit, and it keeps working). */
    double bad[3] = {truth[0], NAN, truth[2]};
    assert_int_equal(vibid_ident_set_prior(id, bad, P0), VIBID_E_NONFINITE);
    double notpd[9] = {0};
    memcpy(notpd, P0, sizeof notpd);
    notpd[4] = -notpd[4];
    assert_int_equal(vibid_ident_set_prior(id, truth, notpd), VIBID_E_NUMERICAL);
    double asym[9];
    memcpy(asym, P0, sizeof asym);
    asym[1] = 1e-3 * P0[0]; /* P0(1,0) != P0(0,1) = 0 */
    assert_int_equal(vibid_ident_set_prior(id, truth, asym), VIBID_E_OUT_OF_RANGE);
    assert_int_equal(vibid_ident_set_prior(NULL, truth, P0), VIBID_E_NULL_ARGUMENT);
    assert_int_equal(vibid_ident_estimate(id, th2, NULL, NULL), VIBID_OK);
    for (int i = 0; i < 3; ++i) assert_true(th2[i] == th[i]);

    /* reset returns to the prior */
    assert_int_equal(vibid_ident_reset(id), VIBID_OK);
    assert_int_equal(vibid_ident_estimate(id, th2, NULL, NULL), VIBID_OK);
    for (int i = 0; i < 3; ++i) assert_float_equal(th2[i], truth[i], 1e-12 * truth[i]);
    vibid_ident_destroy(plain);
    vibid_ident_destroy(id);

    /* Batch estimators have no start value. */
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, H);
    vibid_ident *ls = vibid_ident_create(m, &cfg);
    assert_non_null(ls);
    expect_error_status(vibid_ident_set_prior(ls, truth, NULL), VIBID_E_STATE, "RLS");
    vibid_ident_destroy(ls);
    free(rec);
    vibid_stand_destroy(st);
}

/* ZOH: the physical start values are mapped to the difference form (1.16); the way back
 * (matrix logarithm) must return them, to the round trip's rounding (1e-6 relative:
 * the logarithm of a 2 kHz discretization of a 48 Hz mode loses a few digits). P0 in
 * physical units does not apply there and is refused. */
static void test_ident_prior_zoh(void **state) {
    (void)state;
    vibid_stand *st = stand_example1(VIBID_DISC_ZOH);
    const vibid_model *m = vibid_stand_model(st);
    vibid_ident *id = rls_ident(m);
    const double P0[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    expect_error_status(vibid_ident_set_prior(id, truth, P0), VIBID_E_OUT_OF_RANGE, "P0");
    assert_int_equal(vibid_ident_set_prior(id, truth, NULL), VIBID_OK);
    double th[3];
    assert_int_equal(vibid_ident_estimate(id, th, NULL, NULL), VIBID_OK);
    printf("  zoh prior round trip: max rel err %.2e\n", max_rel_err(th));
    assert_true(max_rel_err(th) < 1e-6);
    vibid_ident_destroy(id);
    vibid_stand_destroy(st);
}

/* ---- rejections: each names the item ---- */
static void expect_error(vibid_status got, vibid_status want, const char *needle) {
    assert_int_equal(got, want);
    if (!strstr(vibid_last_error(), needle)) fail_msg("message '%s' lacks '%s'", vibid_last_error(), needle);
}

static void test_bad_input(void **state) {
    (void)state;
    vibid_model *m = vibid_model_create();
    size_t a, b;
    expect_error(vibid_model_add_node(m, "m1", -1.0, 0, &a), VIBID_E_OUT_OF_RANGE, "m1");
    assert_int_equal(vibid_model_add_node(m, "m1", 1.0, 0, &a), VIBID_OK);
    expect_error(vibid_model_add_element(m, "k9", VIBID_ELEMENT_SPRING, a, 7, 1.0, 1), VIBID_E_OUT_OF_RANGE, "k9");
    expect_error(vibid_model_add_node(m, "m1", 1.0, 0, &b), VIBID_E_OUT_OF_RANGE, "m1");
    assert_int_equal(vibid_model_add_element(m, "k1", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, 100.0, 0), VIBID_OK);
    assert_int_equal(vibid_model_add_input(m, "f", a, 1.0, 0, NULL), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, a, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    /* nothing unknown: fine for simulation, refused for identification */
    expect_error(vibid_model_check_identifiable(m, NULL), VIBID_E_OUT_OF_RANGE, "nothing unknown");
    vibid_model_destroy(m);

    /* channels missing: a damper needs a velocity, only acceleration is measured */
    m = vibid_model_create();
    vibid_model_add_node(m, "m1", 1.0, 0, &a);
    vibid_model_add_element(m, "dd", VIBID_ELEMENT_DAMPER, a, VIBID_GROUND, 1.0, 1);
    vibid_model_add_element(m, "kk", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, 1.0, 1);
    vibid_model_add_input(m, "f", a, 1.0, 0, NULL);
    vibid_model_set_measured(m, a, VIBID_MEASURE_ACCELERATION);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    expect_error(vibid_model_check_identifiable(m, NULL), VIBID_E_DIMENSION, "m1");
    vibid_model_destroy(m);

    /* two unknown springs in parallel cannot be separated: both named */
    m = vibid_model_create();
    vibid_model_add_node(m, "m1", 1.0, 0, &a);
    vibid_model_add_element(m, "ka", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, 1.0, 1);
    vibid_model_add_element(m, "kb", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, 1.0, 1);
    vibid_model_add_input(m, "f", a, 1.0, 0, NULL);
    vibid_model_set_measured(m, a, VIBID_MEASURE_DISPLACEMENT);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    expect_error(vibid_model_check_identifiable(m, NULL), VIBID_E_NOT_IDENTIFIABLE, "ka, kb");
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, H);
    assert_null(vibid_ident_create(m, &cfg)); /* refused before any sample */
    vibid_model_destroy(m);

    /* no excitation at all: not controllable */
    m = vibid_model_create();
    vibid_model_add_node(m, "m1", 1.0, 0, &a);
    vibid_model_add_element(m, "k", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, 1.0, 1);
    vibid_model_set_measured(m, a, VIBID_MEASURE_DISPLACEMENT);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    expect_error(vibid_model_check_identifiable(m, NULL), VIBID_E_NOT_IDENTIFIABLE, "excit");
    vibid_model_destroy(m);

    /* a node nothing touches */
    m = vibid_model_create();
    vibid_model_add_node(m, "m1", 1.0, 0, &a);
    vibid_model_add_node(m, "lonely", 1.0, 0, &b);
    vibid_model_add_element(m, "k", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, 1.0, 1);
    expect_error(vibid_model_finalize(m), VIBID_E_OUT_OF_RANGE, "lonely");
    vibid_model_destroy(m);
}

/* One DOF: f = sqrt(c/m) / 2 pi, zeta = d / (2 sqrt(c m)) exactly; 1e-10 is rounding. */
static void test_modal_analytic(void **state) {
    (void)state;
    double M = 2.0, C = 8.0e4, D = 40.0, f, z;
    assert_int_equal(vibid_modal(1, &M, &D, &C, &f, &z, NULL, NULL), VIBID_OK);
    assert_float_equal(f, sqrt(C / M) / (2 * M_PI), 1e-10 * f);
    assert_float_equal(z, D / (2 * sqrt(C * M)), 1e-10);
    /* two equal masses, springs k-k-k to ground, undamped: sqrt(k/m), sqrt(3k/m) */
    double M2[4] = {1, 0, 0, 1}, C2[4] = {2e4, -1e4, -1e4, 2e4}, f2[2], z2[2], re[4];
    assert_int_equal(vibid_modal(2, M2, NULL, C2, f2, z2, re, NULL), VIBID_OK);
    assert_float_equal(f2[0], 100.0 / (2 * M_PI), 1e-9);
    assert_float_equal(f2[1], sqrt(3e4) / (2 * M_PI), 1e-9);
    assert_float_equal(re[0] * re[1], 1.0, 1e-9);  /* in phase */
    assert_float_equal(re[2] * re[3], -1.0, 1e-9); /* out of phase */
}

/* Unstable models say so (VIBID_E_UNSTABLE) and still write their modes: negative damping
 * (zeta = d / (2 sqrt(c m)) < 0 exactly, 1e-10 rounding), negative stiffness (a divergent
 * real pair: f = 0, zeta = 1 as documented); a rigid-body root (c = 0) is not unstable. */
static void test_modal_unstable(void **state) {
    (void)state;
    double M = 2.0, C = 8.0e4, D = -40.0, f = 0, z = 0;
    assert_int_equal(vibid_modal(1, &M, &D, &C, &f, &z, NULL, NULL), VIBID_E_UNSTABLE);
    assert_non_null(strstr(vibid_last_error(), "unstable"));
    assert_float_equal(f, sqrt(C / M) / (2 * M_PI), 1e-10 * f);
    assert_float_equal(z, D / (2 * sqrt(C * M)), 1e-10);
    double Cn = -8.0e4, Dp = 40.0;
    assert_int_equal(vibid_modal(1, &M, &Dp, &Cn, &f, &z, NULL, NULL), VIBID_E_UNSTABLE);
    assert_float_equal(f, 0.0, 0.0);
    assert_float_equal(z, 1.0, 0.0);
    double C0 = 0.0;
    assert_int_equal(vibid_modal(1, &M, &Dp, &C0, &f, &z, NULL, NULL), VIBID_OK);
    /* the same through a model and its parameters */
    vibid_model *m = vibid_model_create();
    size_t a;
    assert_int_equal(vibid_model_add_node(m, "m1", 2.0, 0, &a), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "k", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, 8.0e4, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "d", VIBID_ELEMENT_DAMPER, a, VIBID_GROUND, 40.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, a, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    const double stable[2] = {8.0e4, 40.0}, neg_d[2] = {8.0e4, -40.0}, cov[4] = {1.0, 0.0, 0.0, 1e-4};
    double fse = 0, zse = 0;
    assert_int_equal(vibid_model_modal(m, stable, cov, &f, &fse, &z, &zse, NULL, NULL), VIBID_OK);
    assert_int_equal(vibid_model_modal(m, neg_d, cov, &f, &fse, &z, &zse, NULL, NULL), VIBID_E_UNSTABLE);
    assert_float_equal(z, -40.0 / (2 * sqrt(8.0e4 * 2.0)), 1e-10);
    assert_true(zse > 0.0); /* the standard errors are written too */
    vibid_model_destroy(m);
}

/* vibid_model_modal's standard errors (delta method, central differences of the modal
 * solution) against the analytic first-order propagation for one mass on a spring and a
 * damper to ground, unknowns d and c (model order: as added):
 *   f = sqrt(c/m) / 2 pi          df/dc = f / (2 c),  df/dd = 0
 *   zeta = d / (2 sqrt(c m))      dzeta/dd = zeta / d, dzeta/dc = -zeta / (2 c)
 * with a full covariance (correlated d, c). Tolerance 1e-6 relative: the central
 * difference with a 1e-6 relative step has truncation error ~1e-12 and rounding error
 * ~1e-10 in the derivatives; 1e-6 leaves room and still catches a wrong term. The
 * frequency and damping values themselves must match to 1e-10. */
static void test_modal_standard_errors(void **state) {
    (void)state;
    const double m = 2.0, d = 40.0, c = 8.0e4;
    vibid_model *mod = vibid_model_create();
    size_t a;
    assert_int_equal(vibid_model_add_node(mod, "m1", m, 0, &a), VIBID_OK);
    assert_int_equal(vibid_model_add_element(mod, "d", VIBID_ELEMENT_DAMPER, a, VIBID_GROUND, d, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(mod, "c", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, c, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_input(mod, "f", a, 1.0, 0, NULL), VIBID_OK);
    assert_int_equal(vibid_model_finalize(mod), VIBID_OK);
    vibid_param_info p0, p1;
    assert_int_equal(vibid_model_param_info(mod, 0, &p0), VIBID_OK);
    assert_int_equal(vibid_model_param_info(mod, 1, &p1), VIBID_OK);
    assert_string_equal(p0.name, "d");
    assert_string_equal(p1.name, "c");
    const double theta[2] = {d, c};
    const double sd = 2.0, sc = 800.0, rho = 0.3;
    const double cov[4] = {sd * sd, rho * sd * sc, rho * sd * sc, sc * sc}; /* symmetric */
    double f, fse, z, zse;
    assert_int_equal(vibid_model_modal(mod, theta, cov, &f, &fse, &z, &zse, NULL, NULL), VIBID_OK);
    const double f_true = sqrt(c / m) / (2 * M_PI), z_true = d / (2 * sqrt(c * m));
    assert_float_equal(f, f_true, 1e-10 * f_true);
    assert_float_equal(z, z_true, 1e-10 * z_true);
    const double Jf[2] = {0.0, f_true / (2 * c)}, Jz[2] = {z_true / d, -z_true / (2 * c)};
    double vf = 0, vz = 0;
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 2; ++j) {
            vf += Jf[i] * cov[i + 2 * j] * Jf[j];
            vz += Jz[i] * cov[i + 2 * j] * Jz[j];
        }
    assert_float_equal(fse, sqrt(vf), 1e-6 * sqrt(vf));
    assert_float_equal(zse, sqrt(vz), 1e-6 * sqrt(vz));
    /* without a covariance the standard errors are 0 (documented) */
    assert_int_equal(vibid_model_modal(mod, theta, NULL, &f, &fse, &z, &zse, NULL, NULL), VIBID_OK);
    assert_true(fse == 0.0 && zse == 0.0);
    vibid_model_destroy(mod);
}

/* The standard errors of a 2-DOF chain with an unknown mass (the state matrix is then not
 * linear in theta) and of an overdamped oscillator (its modes come from a pair of real
 * roots), against the delta method with the Jacobian of the frequencies and damping ratios
 * differentiated numerically here, through vibid_model_modal's own values (central
 * differences, step 1e-5 relative: truncation ~1e-10, rounding ~1e-11 relative in each
 * derivative). vibid_model_modal gets its Jacobian by eigenvalue perturbation (one
 * eigen decomposition per call); the two must agree to 1e-6 relative, far below anything a
 * standard error means and far above their discretisation errors. */
static void check_se_against_numeric(vibid_model *mod, const double *theta, const double *cov, size_t p, size_t n)
{
    double f[4], fse[4], z[4], zse[4];
    assert_int_equal(vibid_model_modal(mod, theta, cov, f, fse, z, zse, NULL, NULL), VIBID_OK);
    double J[8][4]; /* rows: f_0..f_{n-1}, z_0..z_{n-1}; columns: parameters */
    for (size_t i = 0; i < p; ++i) {
        double tp[4], tm[4], fp[4], fm[4], zp[4], zm[4];
        memcpy(tp, theta, p * sizeof *tp);
        memcpy(tm, theta, p * sizeof *tm);
        const double h = 1e-5 * fabs(theta[i]);
        tp[i] += h;
        tm[i] -= h;
        assert_int_equal(vibid_model_modal(mod, tp, NULL, fp, NULL, zp, NULL, NULL, NULL), VIBID_OK);
        assert_int_equal(vibid_model_modal(mod, tm, NULL, fm, NULL, zm, NULL, NULL, NULL), VIBID_OK);
        for (size_t j = 0; j < n; ++j) {
            J[j][i] = (fp[j] - fm[j]) / (2 * h);
            J[n + j][i] = (zp[j] - zm[j]) / (2 * h);
        }
    }
    for (size_t r = 0; r < 2 * n; ++r) {
        double v = 0;
        for (size_t i = 0; i < p; ++i)
            for (size_t k = 0; k < p; ++k)
                v += J[r][i] * cov[i + p * k] * J[r][k];
        const double se = r < n ? fse[r] : zse[r - n];
        if (fabs(se - sqrt(v)) > 1e-6 * sqrt(v))
            fail_msg("%s %zu: se %.12g, numeric delta method %.12g", r < n ? "f" : "zeta", r % n, se, sqrt(v));
    }
}

static void test_modal_standard_errors_mdof(void **state)
{
    (void)state;
    /* 2-DOF chain: m1 (known) - c1, d1 to ground; m2 (unknown) - c2 between the masses */
    vibid_model *mod = vibid_model_create();
    size_t a, b;
    assert_int_equal(vibid_model_add_node(mod, "m1", 2.0, 0, &a), VIBID_OK);
    assert_int_equal(vibid_model_add_node(mod, "m2", 1.5, 1, &b), VIBID_OK);
    assert_int_equal(vibid_model_add_element(mod, "c1", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, 8.0e4, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(mod, "d1", VIBID_ELEMENT_DAMPER, a, VIBID_GROUND, 30.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(mod, "c2", VIBID_ELEMENT_SPRING, a, b, 5.0e4, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_input(mod, "f", a, 1.0, 0, NULL), VIBID_OK);
    assert_int_equal(vibid_model_finalize(mod), VIBID_OK);
    vibid_model_dims dims;
    assert_int_equal(vibid_model_get_dims(mod, &dims), VIBID_OK);
    assert_int_equal(dims.n_params, 4);
    double theta[4];
    assert_int_equal(vibid_model_nominal(mod, theta), VIBID_OK);
    /* a covariance with correlations: 1 % standard errors, rho = 0.2 between neighbours */
    double cov[16];
    for (size_t i = 0; i < 4; ++i)
        for (size_t k = 0; k < 4; ++k) {
            const double si = 0.01 * theta[i], sk = 0.01 * theta[k];
            cov[i + 4 * k] = i == k ? si * sk : (i + 1 == k || k + 1 == i) ? 0.2 * si * sk : 0.0;
        }
    check_se_against_numeric(mod, theta, cov, 4, 2);
    vibid_model_destroy(mod);

    /* overdamped: zeta = 2.5, the mode from two real roots */
    mod = vibid_model_create();
    assert_int_equal(vibid_model_add_node(mod, "m1", 2.0, 0, &a), VIBID_OK);
    assert_int_equal(vibid_model_add_element(mod, "d", VIBID_ELEMENT_DAMPER, a, VIBID_GROUND, 2000.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(mod, "c", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, 8.0e4, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_input(mod, "f", a, 1.0, 0, NULL), VIBID_OK);
    assert_int_equal(vibid_model_finalize(mod), VIBID_OK);
    const double th2[2] = {2000.0, 8.0e4}, cov2[4] = {400.0, 0.3 * 20 * 800, 0.3 * 20 * 800, 640000.0};
    double f, z;
    assert_int_equal(vibid_model_modal(mod, th2, NULL, &f, NULL, &z, NULL, NULL, NULL), VIBID_OK);
    assert_float_equal(z, 2000.0 / (2 * sqrt(8.0e4 * 2.0)), 1e-10);
    check_se_against_numeric(mod, th2, cov2, 2, 1);
    vibid_model_destroy(mod);
}

/* vibid_zoh then vibid_zoh_inverse returns A and B to rounding (1e-9 relative);
 * second_order_form then second_order_to_continuous returns M^-1 C, M^-1 D, M^-1 B. */
static void test_discretization_round_trip(void **state) {
    (void)state;
    double M[4] = {10, 0, 0, 20}, D[4] = {300, -300, -300, 300}, C[4] = {2.5e5, -2.5e5, -2.5e5, 1.75e6},
           B[2] = {0, 1.5e6};
    double Dt[4], Ct[4], B1[2], B2[2], K[4], L[4], J[2];
    vibid_log_info info;
    assert_int_equal(vibid_second_order_form(2, 1, M, D, C, B, H, Dt, Ct, B1, B2), VIBID_OK);
    assert_int_equal(vibid_second_order_to_continuous(2, 1, Dt, Ct, B1, B2, H, K, L, J, &info), VIBID_OK);
    const double Kt[4] = {2.5e4, -1.25e4, -2.5e4, 8.75e4}, Lt[4] = {30, -15, -30, 15}, Jt[2] = {0, 7.5e4};
    for (int i = 0; i < 4; ++i) {
        assert_float_equal(K[i], Kt[i], 1e-7 * 8.75e4);
        assert_float_equal(L[i], Lt[i], 1e-7 * 30);
    }
    for (int i = 0; i < 2; ++i) assert_float_equal(J[i], Jt[i], 1e-7 * 7.5e4);
    assert_false(info.ambiguous);
    /* too slow sampling: a 50 Hz undamped mode at h = 1/100 s sits exactly at Nyquist */
    double m1 = 1.0, d1 = 0.0, c1 = pow(2 * M_PI * 50.0, 2), b1 = 1.0, dt, ct, bb1, bb2, k, l, j;
    assert_int_equal(vibid_second_order_form(1, 1, &m1, &d1, &c1, &b1, 0.009, &dt, &ct, &bb1, &bb2), VIBID_OK);
    vibid_status s = vibid_second_order_to_continuous(1, 1, &dt, &ct, &bb1, &bb2, 0.009, &k, &l, &j, &info);
    /* 50 Hz at 111 Hz sampling: 0.9 of Nyquist -> flagged ambiguous (or refused) */
    assert_true(s != VIBID_OK || info.ambiguous);
}

/* Stand files: the shipped examples load; errors give file:line: field. */
#include <vibid/stand_file.h>
static void write_file(const char *path, const char *text) {
    FILE *f = fopen(path, "w");
    assert_non_null(f);
    fputs(text, f);
    fclose(f);
}

static void test_loader(void **state) {
    (void)state;
    vibid_stand_error err;
    vibid_stand *st = vibid_stand_load(VIBID_SOURCE_DIR "/examples/stands/paper_example1.cfg", &err);
    if (!st) fail_msg("%s", err.text);
    assert_string_equal(vibid_stand_channel_name(st, 2), "s");
    assert_float_equal(vibid_stand_true_values(st)[2], 1.5e6, 0);
    assert_float_equal(vibid_stand_sample_rate(st), 2000.0, 0);
    vibid_stand_destroy(st);

    const char *path = "test_loader_bad.cfg";
    write_file(path, "stand = {\n  sample_rate = 1000.0;\n  nodes = ( { name = \"m1\"; mass = 1.0; } );\n"
                     "  elements = (\n    { name = \"k\"; kind = \"sprung\"; between = [\"m1\", \"ground\"]; value = 1.0; }\n"
                     "  );\n};\n");
    assert_null(vibid_stand_load(path, &err));
    printf("  loader error: %s\n", err.text);
    assert_int_equal(err.line, 5);
    assert_string_equal(err.field, "stand.elements.[0].kind");

    write_file(path, "stand = {\n  sample_rate = 1000.0;\n  nodes = ( { name = \"m1\"; mass = -1.0; } );\n};\n");
    assert_null(vibid_stand_load(path, &err));
    printf("  loader error: %s\n", err.text);
    assert_int_equal(err.line, 3);
    assert_non_null(strstr(err.text, "m1"));

    write_file(path, "stand = {\n  sample_rate = 1000.0;\n  nodes = ( { name = \"m1\"; mass = 1.0;\n"
                     "    measure = { displacement = \"\"; }; } );\n};\n");
    assert_null(vibid_stand_load(path, &err));
    printf("  loader error: %s\n", err.text);
    assert_int_equal(err.line, 4);
    assert_non_null(strstr(err.field, "measure.displacement"));

    write_file(path, "stand = {\n  sample_rate = 1000.0;\n  nodes = ( { name = \"m1\"; mass = 1.0; } );\n"
                     "  elements = ( { name = \"k\"; kind = \"spring\"; between = [\"m1\", \"m7\"]; value = 1.0; } );\n};\n");
    assert_null(vibid_stand_load(path, &err));
    printf("  loader error: %s\n", err.text);
    assert_int_equal(err.line, 4);
    assert_non_null(strstr(err.text, "m7"));
    remove(path);
}

/* `hold` of inputs and the base: declarations reach the model (vibid_model_get_hold);
 * wrong values are errors at their line naming the field. */
static void test_loader_hold(void **state) {
    (void)state;
    vibid_stand_error err;
    const char *path = "test_loader_hold.cfg";
    write_file(path, "stand = {\n  sample_rate = 1000.0;\n  nodes = ( { name = \"m1\"; mass = 1.0; } );\n"
                     "  base = { hold = \"zoh\"; };\n"
                     "  elements = ( { name = \"k\"; kind = \"spring\"; between = [\"m1\", \"base\"]; value = 1.0; } );\n"
                     "  inputs = ( { name = \"f1\"; node = \"m1\"; channel = \"F1\"; hold = \"zoh\"; },\n"
                     "             { name = \"f2\"; node = \"m1\"; channel = \"F2\"; hold = \"smooth\"; },\n"
                     "             { name = \"f3\"; node = \"m1\"; channel = \"F3\"; } );\n};\n");
    vibid_stand *st = vibid_stand_load(path, &err);
    if (!st) fail_msg("%s", err.text);
    vibid_hold hd;
    static const vibid_hold want[3] = {VIBID_HOLD_ZOH, VIBID_HOLD_SMOOTH, VIBID_HOLD_SMOOTH};
    for (size_t j = 0; j < 3; ++j) {
        assert_int_equal(vibid_model_get_hold(vibid_stand_model(st), j, &hd), VIBID_OK);
        assert_int_equal(hd, want[j]);
    }
    assert_int_equal(vibid_model_get_hold(vibid_stand_model(st), VIBID_BASE, &hd), VIBID_OK);
    assert_int_equal(hd, VIBID_HOLD_ZOH);
    vibid_stand_destroy(st);

    write_file(path, "stand = {\n  sample_rate = 1000.0;\n  nodes = ( { name = \"m1\"; mass = 1.0; } );\n"
                     "  inputs = ( { name = \"f1\"; node = \"m1\"; channel = \"F1\";\n"
                     "    hold = \"held\"; } );\n};\n");
    assert_null(vibid_stand_load(path, &err));
    printf("  loader error: %s\n", err.text);
    assert_int_equal(err.line, 5);
    assert_string_equal(err.field, "stand.inputs.[0].hold");
    assert_non_null(strstr(err.text, "test_loader_hold.cfg:5: stand.inputs.[0].hold: 'held' is not one of zoh, smooth"));

    write_file(path, "stand = {\n  sample_rate = 1000.0;\n  nodes = ( { name = \"m1\"; mass = 1.0; } );\n"
                     "  base = {\n    hold = 1;\n  };\n"
                     "  elements = ( { name = \"k\"; kind = \"spring\"; between = [\"m1\", \"base\"]; value = 1.0; } );\n};\n");
    assert_null(vibid_stand_load(path, &err));
    printf("  loader error: %s\n", err.text);
    assert_int_equal(err.line, 5);
    assert_string_equal(err.field, "stand.base.hold");
    assert_non_null(strstr(err.text, "must be one of the strings zoh, smooth"));
    remove(path);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_zoh_noise_free),
        cmocka_unit_test(test_central_difference_noise_free),
        cmocka_unit_test(test_noisy_monte_carlo),
        cmocka_unit_test(test_ident_prior_central_difference),
        cmocka_unit_test(test_ident_prior_zoh),
        cmocka_unit_test(test_bad_input),
        cmocka_unit_test(test_modal_analytic),
        cmocka_unit_test(test_modal_unstable),
        cmocka_unit_test(test_modal_standard_errors),
        cmocka_unit_test(test_modal_standard_errors_mdof),
        cmocka_unit_test(test_discretization_round_trip),
        cmocka_unit_test(test_loader),
        cmocka_unit_test(test_loader_hold),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
