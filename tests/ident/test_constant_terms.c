/* ident.constant_terms: constant forces in the equation-error estimators
 * (vibid_ident_config.constant_terms, identify.h) on the 3-DOF chain of chain_stand.h
 * simulated by vibid-sim's engine (sim_core), 4 s at 2 kHz, white noise of 0.5 % of each
 * measured channel's RMS, and a constant offset of 0.2 x RMS on every displacement channel
 * (a sensor zero error; the accelerometers and the force are offset-free).
 *
 * What is checked and why the tolerances are what they are:
 *  - exactness: the offsets are constant forces f0 = C o in the node equations, which the
 *    constant columns (pre-filtered like every column) absorb exactly, so with constant
 *    terms on, the estimates with and without the offsets agree to rounding (1e-6 relative),
 *    for LS and IV;
 *  - one seeded realisation with offsets: IV and AUTO keep the constants by default (Wald
 *    p < 1e-3), every parameter within 3 of its standard errors of the truth, and each f0
 *    within 3 of its standard errors of C o; without constant terms the same data are more
 *    than 3.5 se off (IV, AUTO) and LS more than 10 of its se from its own offset-free
 *    estimate. LS itself is biased by the noise and its textbook se (flagged not valid)
 *    are too small for coloured equation errors, so against the truth it is checked at
 *    0.05 % noise by relative error: with constants every parameter and f0 within 0.1 %
 *    (measured 0.014 %; 2.4 of its se in this realisation, in another realisation more than 3), without
 *    some parameter more than 1 % off (k1 -1.8 %);
 *  - without offsets (100 noise realisations) the automatic rule keeps the plain estimate
 *    (AUTO) in at least 90 of them (measured 100 of 100; 99 bit-identical to OFF, one differs
 *    through the pre-filter pilot, whose candidate estimates make their own choice), and
 *    the constants cost no accuracy: rms error with / without them 1.0000-1.0021, standard
 *    errors 1.037-1.038 times wider (the batch-means correction n_eff / (n_eff - rank) for
 *    three more fitted directions), asserted below 1.05;
 *  - Monte Carlo coverage of the 2-se intervals with offsets (100 realisations x 6
 *    parameters, AUTO default; measured 98.3 %) in [88 %, 99.5 %] and within 2 % of the
 *    coverage of the plain estimator on the same noise without offsets (measured 98.0 %: the
 *    estimator is conservative on this short capture with or without constants; binomial sd
 *    0.6-0.9 % at 600), and that of the constants (300; measured 98.3 %) in [88 %, 99.5 %];
 *  - the cubic stand at 9 samples per period (the real capture in kind) with the same
 *    offset: without constants the automatic estimate is useless (gain -35 %, d -15549 %,
 *    no valid error bars); with them k, d and the gain within 1.4 se and 1.6 % (asserted: 3 se,
 *    3 %); the cubic coefficient stays 29 % off (the offset's x^2 term), not asserted;
 *  - settings: OFF gives no constants and no test; ON with RLS is refused. */
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
#include <vibid/stand_file.h>

#include "capture.h"
#include "chain_stand.h"
#include "silver_stand.h"

#define N_SAMPLES 8000
#define OFFSET 0.2 /* x RMS of each displacement channel */

typedef struct run {
    double theta[8], se[8], f0[4], f0_se[4], p_value;
    size_t n_const;
    unsigned flags;
} run;

static run identify(const capture *c, const double *data, vibid_estimator est, vibid_constant_terms ct)
{
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 1.0 / vibid_stand_sample_rate(c->stand));
    cfg.estimator = est;
    cfg.constant_terms = ct;
    vibid_ident *id = vibid_ident_create(vibid_stand_model(c->stand), &cfg);
    if (!id) fail_msg("vibid_ident_create: %s", vibid_last_error());
    assert_int_equal(vibid_ident_push_block(id, c->n, data), VIBID_OK);
    run r;
    memset(&r, 0, sizeof r);
    assert_int_equal(vibid_ident_estimate(id, r.theta, r.se, NULL), VIBID_OK);
    size_t nodes[4];
    assert_int_equal(vibid_ident_constant_forces(id, 4, &r.n_const, nodes, r.f0, r.f0_se, &r.p_value), VIBID_OK);
    for (size_t j = 0; j < r.n_const; j++) assert_int_equal(nodes[j], j);
    vibid_ident_quality q;
    assert_int_equal(vibid_ident_get_quality(id, &q, NULL), VIBID_OK);
    r.flags = q.flags;
    vibid_ident_destroy(id);
    return r;
}

/* largest |theta - ref| / se over the parameters */
static double max_z(const capture *c, const run *r, const double *ref)
{
    double z = 0.0;
    for (size_t i = 0; i < c->p; i++) z = fmax(z, fabs(r->theta[i] - ref[i]) / r->se[i]);
    return z;
}

static void print_run(const char *what, const capture *c, const run *r)
{
    printf("%-16s max|z| %6.2f, %zu constants, Wald p %.3g, flags %u:", what, max_z(c, r, c->truth), r->n_const,
           r->p_value, r->flags);
    for (size_t i = 0; i < c->p; i++)
        printf(" %+.3f%%(%+.1f)", 100.0 * (r->theta[i] / c->truth[i] - 1.0), (r->theta[i] - c->truth[i]) / r->se[i]);
    printf("\n");
    for (size_t j = 0; j < r->n_const; j++) printf("    f0[%zu] = %.5g +- %.3g\n", j, r->f0[j], r->f0_se[j]);
}

/* The estimator est on c->noisy with constant terms automatic (*a) and off (*b), printed. */
static void with_and_without(const capture *c, vibid_estimator est, const char *what, run *a, run *b)
{
    *a = identify(c, c->noisy, est, VIBID_CONSTANT_AUTO);
    *b = identify(c, c->noisy, est, VIBID_CONSTANT_OFF);
    print_run(what, c, a);
    print_run("  without", c, b);
}

/* Adds frac x RMS to every displacement channel of c->noisy; o[node] receives the offsets. */
static void add_offsets(capture *c, double frac, double o[3])
{
    const vibid_model *m = vibid_stand_model(c->stand);
    for (size_t j = 0; j < c->nch; j++) {
        vibid_channel_info ci;
        assert_int_equal(vibid_model_channel_info(m, j, &ci), VIBID_OK);
        if (ci.kind != VIBID_CHANNEL_DISPLACEMENT) continue;
        o[ci.index] = frac * c->rms[j];
        for (size_t k = 0; k < c->n; k++) c->noisy[k + j * c->n] += o[ci.index];
    }
}

/* The constant forces the offsets make: f0 = C o (k1 k2 k3 at truth[0], [2], [4]). */
static void expected_f0(const capture *c, const double o[3], double f0[3])
{
    const double k1 = c->truth[0], k2 = c->truth[2], k3 = c->truth[4];
    f0[0] = k1 * o[0] + k2 * (o[0] - o[1]);
    f0[1] = k2 * (o[1] - o[0]) + k3 * (o[1] - o[2]);
    f0[2] = k3 * (o[2] - o[1]);
}

static capture chain(void)
{
    capture c;
    simulate(&c, "ct_chain.cfg", chain_stand, N_SAMPLES);
    assert_int_equal(c.p, 6);
    return c;
}

static void test_exact(void **state)
{
    (void)state;
    capture c = chain();
    add_noise(&c, 0.005);
    double *plain = malloc(c.n * c.nch * sizeof(double)), o[3];
    assert_non_null(plain);
    memcpy(plain, c.noisy, c.n * c.nch * sizeof(double));
    add_offsets(&c, OFFSET, o);
    const vibid_estimator est[] = {VIBID_ESTIMATOR_LS, VIBID_ESTIMATOR_IV, VIBID_ESTIMATOR_AUTO};
    for (size_t e = 0; e < 3; e++) {
        const run a = identify(&c, c.noisy, est[e], VIBID_CONSTANT_ON), b = identify(&c, plain, est[e], VIBID_CONSTANT_ON);
        double worst = 0.0;
        for (size_t i = 0; i < c.p; i++) worst = fmax(worst, fabs(a.theta[i] / b.theta[i] - 1.0));
        printf("estimator %d, constants on: with and without offsets %.3g apart (relative)\n", (int)est[e], worst);
        assert_true(worst < 1e-6);
    }
    free(plain);
    capture_free(&c);
}

static void test_offsets(void **state)
{
    (void)state;
    capture c = chain();
    add_noise(&c, 0.005);
    double *plain = malloc(c.n * c.nch * sizeof(double)), o[3], f0[3];
    assert_non_null(plain);
    memcpy(plain, c.noisy, c.n * c.nch * sizeof(double));
    add_offsets(&c, OFFSET, o);
    expected_f0(&c, o, f0);
    printf("offsets %.4g %.4g %.4g m: f0 = C o = %.5g %.5g %.5g N\n", o[0], o[1], o[2], f0[0], f0[1], f0[2]);
    const vibid_estimator est[] = {VIBID_ESTIMATOR_IV, VIBID_ESTIMATOR_AUTO};
    for (size_t e = 0; e < 2; e++) {
        run a, b;
        with_and_without(&c, est[e], est[e] == VIBID_ESTIMATOR_IV ? "IV" : "AUTO", &a, &b);
        assert_int_equal(a.n_const, 3);
        assert_true(a.p_value < 1e-3);
        assert_true(max_z(&c, &a, c.truth) < 3.0);
        for (size_t j = 0; j < 3; j++) assert_true(fabs(a.f0[j] - f0[j]) < 3.0 * a.f0_se[j]);
        assert_int_equal(b.n_const, 0);
        assert_true(isnan(b.p_value));
        assert_true(max_z(&c, &b, c.truth) > 3.5);
    }
    /* LS: the offsets' bias against its own offset-free estimate */
    const run ref = identify(&c, plain, VIBID_ESTIMATOR_LS, VIBID_CONSTANT_OFF);
    print_run("LS no offsets", &c, &ref);
    run a, b;
    with_and_without(&c, VIBID_ESTIMATOR_LS, "LS", &a, &b);
    printf("LS from its offset-free estimate: with constants %.2f se, without %.2f se\n", max_z(&c, &a, ref.theta),
           max_z(&c, &b, ref.theta));
    assert_int_equal(a.n_const, 3);
    assert_true(max_z(&c, &a, ref.theta) < 1.0);
    assert_true(max_z(&c, &b, ref.theta) > 10.0);
    /* LS against the truth where its noise bias is small: 0.05 % noise */
    add_noise(&c, 0.0005);
    add_offsets(&c, OFFSET, o);
    run l, m;
    with_and_without(&c, VIBID_ESTIMATOR_LS, "LS 0.05 %", &l, &m);
    assert_int_equal(l.n_const, 3);
    double worst_l = 0.0, worst_m = 0.0;
    for (size_t i = 0; i < c.p; i++) {
        worst_l = fmax(worst_l, fabs(l.theta[i] / c.truth[i] - 1.0));
        worst_m = fmax(worst_m, fabs(m.theta[i] / c.truth[i] - 1.0));
    }
    assert_true(worst_l < 1e-3);
    for (size_t j = 0; j < 3; j++) assert_true(fabs(l.f0[j] / f0[j] - 1.0) < 1e-3);
    assert_true(worst_m > 1e-2);
    free(plain);
    capture_free(&c);
}

#define RUNS 100

static void test_no_offsets(void **state)
{
    (void)state;
    capture c = chain();
    int plain = 0, plain_ls = 0, identical = 0;
    double ratio[6] = {0}, err_on[6] = {0}, err_off[6] = {0};
    for (int r = 0; r < RUNS; r++) {
        add_noise(&c, 0.005);
        const run a = identify(&c, c.noisy, VIBID_ESTIMATOR_AUTO, VIBID_CONSTANT_AUTO);
        const run on = identify(&c, c.noisy, VIBID_ESTIMATOR_AUTO, VIBID_CONSTANT_ON);
        const run off = identify(&c, c.noisy, VIBID_ESTIMATOR_AUTO, VIBID_CONSTANT_OFF);
        const run ls = identify(&c, c.noisy, VIBID_ESTIMATOR_LS, VIBID_CONSTANT_AUTO);
        plain += a.n_const == 0;
        plain_ls += ls.n_const == 0;
        if (a.n_const == 0) {
            int same = 1;
            for (size_t i = 0; i < c.p; i++) same &= a.theta[i] == off.theta[i] && a.se[i] == off.se[i];
            identical += same;
        }
        for (size_t i = 0; i < c.p; i++) {
            ratio[i] += on.se[i] / off.se[i] / RUNS;
            err_on[i] += pow(on.theta[i] / c.truth[i] - 1.0, 2) / RUNS;
            err_off[i] += pow(off.theta[i] / c.truth[i] - 1.0, 2) / RUNS;
        }
    }
    printf("no offsets: AUTO kept the plain estimate in %d of %d realisations (%d of them identical to OFF), LS in "
           "%d\n",
           plain, RUNS, identical, plain_ls);
    printf("se with / without constants (AUTO), mean:");
    for (size_t i = 0; i < c.p; i++) printf(" %.4f", ratio[i]);
    printf("\nrms error with / without constants:");
    for (size_t i = 0; i < c.p; i++) printf(" %.4f", sqrt(err_on[i] / err_off[i]));
    printf("\n");
    assert_true(plain >= RUNS * 9 / 10);
    for (size_t i = 0; i < c.p; i++) assert_true(ratio[i] < 1.05);
    capture_free(&c);
}

static void test_coverage(void **state)
{
    (void)state;
    capture c = chain();
    int in = 0, total = 0, in_f = 0, total_f = 0, kept = 0, in_ref = 0;
    for (int r = 0; r < RUNS; r++) {
        double o[3], f0[3];
        add_noise(&c, 0.005);
        const run ref = identify(&c, c.noisy, VIBID_ESTIMATOR_AUTO, VIBID_CONSTANT_OFF);
        for (size_t i = 0; i < c.p; i++) in_ref += fabs(ref.theta[i] - c.truth[i]) <= 2.0 * ref.se[i];
        add_offsets(&c, OFFSET, o);
        expected_f0(&c, o, f0);
        const run a = identify(&c, c.noisy, VIBID_ESTIMATOR_AUTO, VIBID_CONSTANT_AUTO);
        kept += a.n_const == 3;
        for (size_t i = 0; i < c.p; i++, total++) in += fabs(a.theta[i] - c.truth[i]) <= 2.0 * a.se[i];
        for (size_t j = 0; j < a.n_const; j++, total_f++) in_f += fabs(a.f0[j] - f0[j]) <= 2.0 * a.f0_se[j];
    }
    const double cov = (double)in / total, cov_f = (double)in_f / total_f;
    printf("offsets 0.2 RMS: constants kept in %d of %d; coverage of 2 se: parameters %.1f %% (%d of %d), constants "
           "%.1f %% (%d of %d)\n",
           kept, RUNS, 100.0 * cov, in, total, 100.0 * cov_f, in_f, total_f);
    printf("the same noise without offsets and without constants: coverage %.1f %% (%d of %d)\n",
           100.0 * in_ref / total, in_ref, total);
    assert_int_equal(kept, RUNS);
    assert_true(cov >= 0.88 && cov <= 0.995);
    assert_true(fabs(cov - (double)in_ref / total) <= 0.02);
    assert_true(cov_f >= 0.88 && cov_f <= 0.995);
    capture_free(&c);
}

static void test_settings(void **state)
{
    (void)state;
    capture c = chain();
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 1.0 / vibid_stand_sample_rate(c.stand));
    assert_int_equal(cfg.constant_terms, VIBID_CONSTANT_AUTO);
    cfg.estimator = VIBID_ESTIMATOR_RLS;
    cfg.constant_terms = VIBID_CONSTANT_ON;
    assert_null(vibid_ident_create(vibid_stand_model(c.stand), &cfg));
    printf("RLS with constants on: %s\n", vibid_last_error());
    cfg.constant_terms = (vibid_constant_terms)7;
    cfg.estimator = VIBID_ESTIMATOR_AUTO;
    assert_null(vibid_ident_create(vibid_stand_model(c.stand), &cfg));
    /* RLS under AUTO: no constants, no test */
    add_noise(&c, 0.005);
    const run r = identify(&c, c.noisy, VIBID_ESTIMATOR_RLS, VIBID_CONSTANT_AUTO);
    assert_int_equal(r.n_const, 0);
    assert_true(isnan(r.p_value));
    capture_free(&c);
}

/* The cubic stand with the offset: without constants the automatic estimate is useless (the
 * issue's failure in kind); with them k, d and the gain are within 3 se and 3 %. The cubic
 * coefficient is not checked: the offset also makes 3 eps o x^2 and 3 eps o^2 x, which a
 * constant does not absorb (eps +29 %, 4 se, identify.h). */
static void test_cubic_offset(void **state)
{
    (void)state;
    capture c;
    simulate(&c, "ct_silver.cfg", silver_stand, 8000);
    double o[3];
    add_noise(&c, 0.005);
    add_offsets(&c, OFFSET, o);
    run a, b;
    with_and_without(&c, VIBID_ESTIMATOR_AUTO, "cubic, offset", &a, &b);
    assert_int_equal(a.n_const, 1);
    const size_t checked[3] = {0, 1, 3}; /* k, d, gain */
    for (size_t i = 0; i < 3; i++) {
        const size_t j = checked[i];
        assert_true(fabs(a.theta[j] - c.truth[j]) < 3.0 * a.se[j]);
        assert_true(fabs(a.theta[j] / c.truth[j] - 1.0) < 0.03);
    }
    assert_true(fabs(b.theta[3] / c.truth[3] - 1.0) > 0.2); /* the gain */
    capture_free(&c);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_exact),    cmocka_unit_test(test_offsets),  cmocka_unit_test(test_no_offsets),
        cmocka_unit_test(test_coverage), cmocka_unit_test(test_settings), cmocka_unit_test(test_cubic_offset),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
