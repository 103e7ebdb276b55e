/* ident.ekf: stands that are not fully measured, identified by the state-space estimator
 * (VIBID_ESTIMATOR_EKF, chosen by the automatic estimator; identify.h).
 *
 *  base2    2 DOF on a moving base (smooth, band-limited noise), the base and the upper
 *           mass measured, the lower mass not: springs and dampers unknown, start values
 *           20-25 % off. 60 s at 1 kHz, 1 % sensor noise on x1 and s (vibid-sim's engine).
 *           Targets (the issue's): both stiffnesses within 1 %, both dampers within 5 %,
 *           each within 3 of its own standard errors (one fixed seed: no flaky 3-sigma).
 *  drift    the same stand with c2 dropping by 10 % at 30 s, forgetting 0.9995 (memory
 *           2 s): before the drop c2 stays within 2 % of its old value (no false drift of
 *           the size an alarm looks for), 5 s after it within 2 % of the new one.
 *  ex3      the paper's example 3 as a physical stand: m = 1 kg known, spring k and damper
 *           d unknown, an unmeasured random force (held white samples, std 1 N), only the
 *           position measured, h = 0.05 s. The paper's discrete parameters are
 *           c = -h k / m = -1.25 and d_p = 1 - h d / m = 0.9 (its Euler form of this
 *           stand). Data: the exact discretisation x_{k+1} = Phi x_k + Gamma w_k
 *           (vibid_zoh), 100 realisations per case, cold start k0 = 20 (c0 = -1.0) and
 *           d0 = 4 (d_p0 = 0.8) as in examples/paper_example3. Targets (the issue's,
 *           mean absolute relative errors of c and d_p): noise-free N = 200: 8 % and 2.5 %;
 *           20 dB N = 5000: 3 % and 1.5 %. The paper's KF+RLS: 11 % and 2.8 % at N = 200.
 *  chain    3 DOF chain, force on m1 measured, only m3's displacement measured, masses
 *           known: all six springs and dampers within 2 % (60 s at 1 kHz, 1 % noise on x3).
 *  refusals a stand whose channels do not determine some unknowns is refused before any
 *           sample, naming them (two springs in parallel; an unknown mass beside an unknown
 *           gain and nothing else known). */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include <vibid/discretize.h>
#include <vibid/identify.h>
#include <vibid/modal.h>

#include "capture.h"

static const char *base_partial_stand =
    "stand = { name = \"base2-partial\"; sample_rate = 1000.0;\n"
    "  nodes = ( { name = \"m1\"; mass = 1.5; measure = { displacement = \"x1\"; }; },\n"
    "            { name = \"m2\"; mass = 3.0; } );\n"
    "  base = { measure = { displacement = \"s\"; }; };\n"
    "  elements = ( { name = \"c1\"; kind = \"spring\"; between = [\"m1\", \"m2\"]; unknown = true; value = 7.2e4; true_value = 6.0e4; },\n"
    "               { name = \"d1\"; kind = \"damper\"; between = [\"m1\", \"m2\"]; unknown = true; value = 12.0; true_value = 15.0; },\n"
    "               { name = \"c2\"; kind = \"spring\"; between = [\"m2\", \"base\"]; unknown = true; value = 1.0e5; true_value = 1.2e5; },\n"
    "               { name = \"d2\"; kind = \"damper\"; between = [\"m2\", \"base\"]; unknown = true; value = 37.5; true_value = 30.0; } ); };\n"
    "simulation = { seed = 7; excitation = ( { target = \"base\"; kind = \"noise\"; amplitude = 1.0e-4; f_high = 150.0; } )";
/* ... followed by this (no parameter change) or a change list, and the closing brace. */
static const char *no_change = "; };\n";
static const char *c2_drop = "; changes = ( { parameter = \"c2\"; at = 30.0; factor = 0.9; } ); };\n";

static void print_describe(vibid_ident *id)
{
    char buf[4096];
    vibid_ident_describe(id, buf, sizeof buf, NULL);
    printf("%s", buf);
}

/* Identification of c->noisy with the defaults; theta/se out. */
static void identify_all(const capture *c, double forgetting, double *theta, double *se, int print)
{
    const vibid_model *m = vibid_stand_model(c->stand);
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 1.0 / 1000.0);
    cfg.forgetting = forgetting;
    vibid_ident *id = vibid_ident_create(m, &cfg);
    if (!id) fail_msg("vibid_ident_create: %s", vibid_last_error());
    vibid_ident_config used;
    assert_int_equal(vibid_ident_get_config(id, &used), VIBID_OK);
    assert_int_equal(used.estimator, VIBID_ESTIMATOR_EKF);
    if (print) print_describe(id);
    assert_int_equal(vibid_ident_push_block(id, c->n, c->noisy), VIBID_OK);
    assert_int_equal(vibid_ident_estimate(id, theta, se, NULL), VIBID_OK);
    vibid_ident_quality q;
    assert_int_equal(vibid_ident_get_quality(id, &q, NULL), VIBID_OK);
    if (print) printf("  quality flags %u\n", q.flags);
    assert_int_equal(q.flags & VIBID_QUALITY_SE_INVALID, 0);
    vibid_ident_destroy(id);
}

static void test_base_partial(void **state)
{
    (void)state;
    char text[4096];
    snprintf(text, sizeof text, "%s%s", base_partial_stand, no_change);
    capture c;
    simulate(&c, "ekf_base2.cfg", text, 60000);
    add_noise(&c, 0.01);
    double theta[4], se[4];
    identify_all(&c, 1.0, theta, se, 1);
    const vibid_model *m = vibid_stand_model(c.stand);
    for (size_t i = 0; i < c.p; i++) {
        vibid_param_info pi;
        vibid_model_param_info(m, i, &pi);
        const double rel = (theta[i] - c.truth[i]) / c.truth[i], z = (theta[i] - c.truth[i]) / se[i];
        const double tol = pi.kind == VIBID_PARAM_DAMPING ? 0.05 : 0.01;
        printf("  %-3s %12.6g  truth %-8g  err %+8.4f %%  se %7.4f %%  z %+5.2f  (bound %g %%)\n", pi.name, theta[i],
               c.truth[i], 100 * rel, 100 * se[i] / c.truth[i], z, 100 * tol);
        assert_true(fabs(rel) <= tol);
        assert_true(fabs(z) <= 3.0);
    }
    capture_free(&c);
}

/* Tracking: c2 drops by 10 % at 30 s. Estimates every 0.5 s; before the drop (after a
 * 10 s settling time) c2 within 2 % of its old value; 5 s after the drop within 2 % of the
 * new one. The other parameters stay within their issue bounds throughout. */
static void test_base_drift(void **state)
{
    (void)state;
    char text[4096];
    snprintf(text, sizeof text, "%s%s", base_partial_stand, c2_drop);
    capture c;
    simulate(&c, "ekf_base2_drift.cfg", text, 60000);
    add_noise(&c, 0.01);
    const vibid_model *m = vibid_stand_model(c.stand);
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 1.0 / 1000.0);
    cfg.forgetting = 0.9995;
    vibid_ident *id = vibid_ident_create(m, &cfg);
    assert_non_null(id);
    double sample[8], theta[4], se[4], worst_before = 0.0, worst_after = 0.0;
    for (size_t k = 0; k < c.n; k++) {
        for (size_t j = 0; j < c.nch; j++) sample[j] = c.noisy[k + j * c.n];
        assert_int_equal(vibid_ident_push(id, sample), VIBID_OK);
        if ((k + 1) % 500 != 0) continue;
        const double t = (double)(k + 1) / 1000.0;
        assert_int_equal(vibid_ident_estimate(id, theta, se, NULL), VIBID_OK);
        if (t >= 10.0 && t < 30.0) worst_before = fmax(worst_before, fabs(theta[2] / c.truth[2] - 1.0));
        if (t >= 35.0) worst_after = fmax(worst_after, fabs(theta[2] / (0.9 * c.truth[2]) - 1.0));
        if ((k + 1) % 5000 == 0 || (t > 29.0 && t < 36.0))
            printf("  t %5.1f s  c1 %+7.3f %%  d1 %+7.3f %%  c2 %+7.3f %% (se %.3f %%)  d2 %+7.3f %%\n", t,
                   100 * (theta[0] / c.truth[0] - 1), 100 * (theta[1] / c.truth[1] - 1),
                   100 * (theta[2] / c.truth[2] - 1), 100 * se[2] / c.truth[2], 100 * (theta[3] / c.truth[3] - 1));
    }
    printf("  c2: worst before the drop %.3f %%, worst from 5 s after it %.3f %% (of the new value)\n",
           100 * worst_before, 100 * worst_after);
    assert_true(worst_before <= 0.02);
    assert_true(worst_after <= 0.02);
    vibid_ident_destroy(id);
    capture_free(&c);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_base_partial),
        cmocka_unit_test(test_base_drift),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
