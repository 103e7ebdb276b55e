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
 *  chain3   3 DOF chain (ground - m1 - m2 - m3), a measured band-limited force on m1,
 *           only x3 measured (1 % noise), masses known, the three springs and dampers
 *           unknown with start values 17-20 % off; 60 s at 1 kHz. Target (the issue's):
 *           each within 2 % and within 3 of its own standard errors. A second damper
 *           from m1 to ground is refused by name. (With the masses unknown too the
 *           measured response admits a second parameter set: the identifiability test
 *           is local; see README.)
 *  ex3      the paper's example 3 as a physical stand: m = 1 kg known, spring k and damper
 *           d unknown, an unmeasured random force (held white samples, std 1 N), only the
 *           position measured, h = 0.05 s. The paper's model is discrete (Euler form,
 *           c = -1.25, d_p = 0.9); the stand is the one with the same sampled poles
 *           (k = 25.63 N/m, d = 0.764 N s/m; see ex3_paper_to_stand), and estimates are
 *           compared in the paper's c, d_p through the same map. Data: the exact
 *           discretisation x_{k+1} = Phi x_k + Gamma w_k (vibid_zoh), 100 realisations per
 *           case, cold start at the paper's c0 = -1.0, d_p0 = 0.8. Targets (the issue's,
 *           mean absolute relative errors of c and d_p): noise-free N = 200: 8 % and 2.5 %;
 *           20 dB N = 5000: 3 % and 1.5 %. The paper's KF+RLS: 11 % and 2.8 % at N = 200;
 *           the library's on its own data (examples/paper_example3): 6.60 % and 2.09 %.
 *  innovations  vibid_ident_innovations on base2 (only the upper spring and damper
 *           unknown, 60 s): none while the start window is collected, at a gap or from
 *           LS; after the tempering the normalised innovations nu / sd of the consistent
 *           model have a mean square of about 1 (lag 1 correlation -0.13); the same capture
 *           identified with the lower spring declared 25 % soft (a model error no
 *           parameter can absorb) gives a mean square over 10 and divergences.
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
/* The same stand with only the upper spring and damper unknown: both act on m1, which
 * carries the sensor (the KF+RLS's case). */
static const char *base_upper_stand =
    "stand = { name = \"base2-upper\"; sample_rate = 1000.0;\n"
    "  nodes = ( { name = \"m1\"; mass = 1.5; measure = { displacement = \"x1\"; }; },\n"
    "            { name = \"m2\"; mass = 3.0; } );\n"
    "  base = { measure = { displacement = \"s\"; }; };\n"
    "  elements = ( { name = \"c1\"; kind = \"spring\"; between = [\"m1\", \"m2\"]; unknown = true; value = 7.2e4; true_value = 6.0e4; },\n"
    "               { name = \"d1\"; kind = \"damper\"; between = [\"m1\", \"m2\"]; unknown = true; value = 12.0; true_value = 15.0; },\n"
    "               { name = \"c2\"; kind = \"spring\"; between = [\"m2\", \"base\"]; value = 1.2e5; },\n"
    "               { name = \"d2\"; kind = \"damper\"; between = [\"m2\", \"base\"]; value = 30.0; } ); };\n"
    "simulation = { seed = 7; excitation = ( { target = \"base\"; kind = \"noise\"; amplitude = 1.0e-4; f_high = 150.0; } ); };\n";
/* ... followed by this (no parameter change) or a change list, and the closing brace. */
static const char *no_change = "; };\n";
static const char *c2_drop = "; changes = ( { parameter = \"c2\"; at = 30.0; factor = 0.9; } ); };\n";

static void print_describe(vibid_ident *id)
{
    char buf[4096];
    vibid_ident_describe(id, buf, sizeof buf, NULL);
    printf("%s", buf);
}

/* Identification of c->noisy with the defaults (est = VIBID_ESTIMATOR_AUTO, which must
 * choose the EKF) or the KF+RLS (VIBID_ESTIMATOR_KF_RLS, whose standard errors are always
 * flagged); theta/se out. */
static void identify_all(const capture *c, vibid_estimator est, double forgetting, double *theta, double *se, int print)
{
    const vibid_model *m = vibid_stand_model(c->stand);
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 1.0 / vibid_stand_sample_rate(c->stand));
    cfg.forgetting = forgetting;
    cfg.estimator = est;
    vibid_ident *id = vibid_ident_create(m, &cfg);
    if (!id) fail_msg("vibid_ident_create: %s", vibid_last_error());
    vibid_ident_config used;
    assert_int_equal(vibid_ident_get_config(id, &used), VIBID_OK);
    assert_int_equal(used.estimator, est == VIBID_ESTIMATOR_KF_RLS ? VIBID_ESTIMATOR_KF_RLS : VIBID_ESTIMATOR_EKF);
    if (print) print_describe(id);
    if (vibid_ident_push_block(id, c->n, c->noisy) != VIBID_OK) fail_msg("push: %s", vibid_last_error());
    assert_int_equal(vibid_ident_estimate(id, theta, se, NULL), VIBID_OK);
    vibid_ident_quality q;
    assert_int_equal(vibid_ident_get_quality(id, &q, NULL), VIBID_OK);
    if (print) printf("  quality flags %u\n", q.flags);
    assert_int_equal(q.flags & VIBID_QUALITY_SE_INVALID, est == VIBID_ESTIMATOR_KF_RLS ? VIBID_QUALITY_SE_INVALID : 0);
    vibid_ident_destroy(id);
}

/* Every estimate within its relative bound (stiffness-like / damping) and, when
 * check_se, within 3 of its own standard errors. */
static void check_within(const capture *c, const double *theta, const double *se, double tol_stiff, double tol_damp,
                         int check_se)
{
    const vibid_model *m = vibid_stand_model(c->stand);
    for (size_t i = 0; i < c->p; i++) {
        vibid_param_info pi;
        vibid_model_param_info(m, i, &pi);
        const double rel = (theta[i] - c->truth[i]) / c->truth[i], z = (theta[i] - c->truth[i]) / se[i];
        const double tol = pi.kind == VIBID_PARAM_DAMPING ? tol_damp : tol_stiff;
        printf("  %-3s %12.6g  truth %-8g  err %+8.4f %%  se %7.4f %%  z %+5.2f  (bound %g %%)\n", pi.name, theta[i],
               c->truth[i], 100 * rel, 100 * se[i] / c->truth[i], z, 100 * tol);
        assert_true(fabs(rel) <= tol);
        if (check_se) assert_true(fabs(z) <= 3.0);
    }
}

/* 60,000 samples (60 s at 1 kHz) of the stand in `text`, sensor noise of `noise` of each
 * channel's RMS, identified with the defaults; every unknown within its bound and within 3
 * standard errors. */
static void identify_and_check(const char *name, const char *text, vibid_estimator est, double noise,
                               double tol_stiff, double tol_damp)
{
    capture c;
    simulate(&c, name, text, 60000);
    add_noise(&c, noise);
    double theta[16], se[16];
    assert_true(c.p <= 16);
    identify_all(&c, est, 1.0, theta, se, 1);
    check_within(&c, theta, se, tol_stiff, tol_damp, est != VIBID_ESTIMATOR_KF_RLS);
    capture_free(&c);
}

static void test_base_partial(void **state)
{
    (void)state;
    char text[4096];
    snprintf(text, sizeof text, "%s%s", base_partial_stand, no_change);
    identify_and_check("ekf_base2.cfg", text, VIBID_ESTIMATOR_AUTO, 0.01, 0.01, 0.05);
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


/* ---- a 3-DOF chain measured at its end ---- */
#define CHAIN3_HEAD \
    "stand = { name = \"chain3-end\"; sample_rate = 1000.0;\n" \
    "  nodes = ( { name = \"m1\"; mass = 2.0; },\n" \
    "            { name = \"m2\"; mass = 1.5; },\n" \
    "            { name = \"m3\"; mass = 1.0; measure = { displacement = \"x3\"; }; } );\n" \
    "  elements = ( { name = \"k1\"; kind = \"spring\"; between = [\"m1\", \"ground\"]; unknown = true; value = 4.8e4; true_value = 4.0e4; },\n" \
    "               { name = \"d1\"; kind = \"damper\"; between = [\"m1\", \"ground\"]; unknown = true; value = 16.0; true_value = 20.0; },\n" \
    "               { name = \"k2\"; kind = \"spring\"; between = [\"m1\", \"m2\"]; unknown = true; value = 2.5e4; true_value = 3.0e4; },\n" \
    "               { name = \"d2\"; kind = \"damper\"; between = [\"m1\", \"m2\"]; unknown = true; value = 18.0; true_value = 15.0; },\n" \
    "               { name = \"k3\"; kind = \"spring\"; between = [\"m2\", \"m3\"]; unknown = true; value = 2.4e4; true_value = 2.0e4; },\n" \
    "               { name = \"d3\"; kind = \"damper\"; between = [\"m2\", \"m3\"]; unknown = true; value = 8.0; true_value = 10.0; }"
#define CHAIN3_TAIL \
    " );\n" \
    "  inputs = ( { name = \"f\"; node = \"m1\"; gain = 1.0; channel = \"F\"; } ); };\n" \
    "simulation = { seed = 11; excitation = ( { target = \"f\"; kind = \"noise\"; amplitude = 20.0; f_high = 150.0; } ); };\n"
static const char *chain3_stand = CHAIN3_HEAD CHAIN3_TAIL;
/* with a second damper from m1 to ground beside d1: only their sum reaches x3 */
static const char *chain3_parallel =
    CHAIN3_HEAD ",\n               { name = \"d1b\"; kind = \"damper\"; between = [\"m1\", \"ground\"]; unknown = true; value = 5.0; }" CHAIN3_TAIL;

static void test_chain3_end(void **state)
{
    (void)state;
    identify_and_check("ekf_chain3.cfg", chain3_stand, VIBID_ESTIMATOR_AUTO, 0.01, 0.02, 0.02);
    const char *path = write_tmp("ekf_chain3_parallel.cfg", chain3_parallel);
    vibid_stand_error serr;
    vibid_stand *st = vibid_stand_load(path, &serr);
    if (!st) fail_msg("%s", serr.text);
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 1e-3);
    assert_null(vibid_ident_create(vibid_stand_model(st), &cfg));
    printf("  refused: %s\n", vibid_last_error());
    assert_non_null(strstr(vibid_last_error(), "not identifiable from the measured channels: 'd1', 'd1b'"));
    vibid_stand_destroy(st);
}

/* ---- the paper's example 3 as a stand ---- */
typedef struct ex3_stats {
    double mare_c, mare_d, mare_k, mare_dd;
    int fails;
} ex3_stats;

/* its own stream, so that its figures do not depend on the cases run before it */
static uint64_t ex3_rng = 0x2545F4914F6CDD1Dull;
static double ex3_normal(void) { return normal_from(&ex3_rng); }

/* The paper's example 3 is a discrete model, x_{k+1} = x_k + h r_k, r_{k+1} = c x_k + d_p r_k
 * + h w_k, with characteristic polynomial l^2 - (1 + d_p) l + (d_p - h c). The stand with
 * the same sampled poles (m = 1 kg): poles r e^(+-i phi) = exp((-d/2 +- i w_d) h), so
 * d = -2 ln(r) / h and k = (ln(r)^2 + phi^2) / h^2. (The explicit Euler reading
 * k = -c / h, d = (1 - d_p) / h would be a different, much more damped stand: Euler adds
 * damping.) Estimates are compared in the paper's coordinates through the same map. */
static void ex3_paper_to_stand(double h, double c, double dp, double *k, double *d)
{
    const double a1 = 1.0 + dp, a0 = dp - h * c, r = sqrt(a0), phi = acos(a1 / (2.0 * r));
    *d = -2.0 * log(r) / h;
    *k = (log(r) * log(r) + phi * phi) / (h * h);
}

static void ex3_stand_to_paper(double h, double k, double d, double *c, double *dp)
{
    const double sigma = -0.5 * d, wd2 = k - 0.25 * d * d;
    /* an overdamped estimate has real poles: cosh instead of cos */
    const double a1 = 2.0 * exp(sigma * h) * (wd2 >= 0.0 ? cos(sqrt(wd2) * h) : cosh(sqrt(-wd2) * h));
    const double a0 = exp(2.0 * sigma * h);
    *dp = a1 - 1.0;
    *c = (*dp - a0) / h;
}

/* runs realisations of length N at snr_db (< 0: noise-free); mean |relative error| of the
 * paper's c and d_p (through the pole map above), and of k and d themselves. */
static ex3_stats ex3_study(vibid_estimator est, size_t N, double snr_db, int runs)
{
    /* R_w = 1 known (the paper's setting); R_v estimated from the data (not declared), as
     * a user of vibidd would run it. Truth c = -1.25, d_p = 0.9; start c = -1.0, d_p = 0.8
     * (the paper's cold start, 80 % and 90 % of the truth). */
    const double h = 0.05, c_true = -1.25, dp_true = 0.9;
    double k_true, d_true, k0, d0;
    ex3_paper_to_stand(h, c_true, dp_true, &k_true, &d_true);
    ex3_paper_to_stand(h, -1.0, 0.8, &k0, &d0);
    vibid_model *m = vibid_model_create();
    size_t node;
    assert_int_equal(vibid_model_add_node(m, "m", 1.0, 0, &node), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "k", VIBID_ELEMENT_SPRING, node, VIBID_GROUND, k0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "d", VIBID_ELEMENT_DAMPER, node, VIBID_GROUND, d0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_disturbance(m, "w", node, 1.0, NULL), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, node, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    /* exact discretisation of the true stand with a held force */
    const double A[4] = {0.0, -k_true, 1.0, -d_true}, B[2] = {0.0, 1.0};
    double G[4], Gam[2];
    assert_int_equal(vibid_zoh(2, 1, A, B, h, G, Gam), VIBID_OK);
    double *z = malloc(N * sizeof(double));
    assert_non_null(z);
    ex3_stats st = {0, 0, 0, 0, 0};
    int ok = 0;
    for (int run = 0; run < runs; run++) {
        double x[2] = {0.0, 0.0};
        for (int k = 0; k < 500; k++) { /* burn-in to the stationary state */
            const double w = ex3_normal(), x0 = x[0];
            x[0] = G[0] * x0 + G[2] * x[1] + Gam[0] * w;
            x[1] = G[1] * x0 + G[3] * x[1] + Gam[1] * w;
        }
        double ss = 0.0;
        for (size_t k = 0; k < N; k++) {
            z[k] = x[0];
            ss += x[0] * x[0];
            const double w = ex3_normal(), x0 = x[0];
            x[0] = G[0] * x0 + G[2] * x[1] + Gam[0] * w;
            x[1] = G[1] * x0 + G[3] * x[1] + Gam[1] * w;
        }
        const double noise_sd = snr_db >= 0.0 ? sqrt(ss / (double)N) * pow(10.0, -snr_db / 20.0) : 0.0;
        for (size_t k = 0; k < N && noise_sd > 0.0; k++) z[k] += noise_sd * ex3_normal();
        vibid_ident_config cfg;
        vibid_ident_config_init(&cfg, h);
        cfg.estimator = est;
        vibid_ident *id = vibid_ident_create(m, &cfg);
        assert_non_null(id);
        double th[2], se[2];
        vibid_status s = VIBID_OK;
        for (size_t k = 0; k < N && s == VIBID_OK; k++) s = vibid_ident_push(id, &z[k]);
        if (s == VIBID_OK) s = vibid_ident_estimate(id, th, se, NULL);
        vibid_ident_destroy(id);
        if (s != VIBID_OK) {
            st.fails++;
            continue;
        }
        ok++;
        double c, dp;
        ex3_stand_to_paper(h, th[0], th[1], &c, &dp);
        st.mare_c += fabs(c / c_true - 1.0);
        st.mare_d += fabs(dp / dp_true - 1.0);
        st.mare_k += fabs(th[0] / k_true - 1.0);
        st.mare_dd += fabs(th[1] / d_true - 1.0);
    }
    st.mare_c /= ok;
    st.mare_d /= ok;
    st.mare_k /= ok;
    st.mare_dd /= ok;
    free(z);
    vibid_model_destroy(m);
    return st;
}

/* Example 3 by estimator est against the targets: noise-free N = 200 and 20 dB
 * N = 5000, 100 realisations each. A mean over 100 realisations with a fixed seed is
 * deterministic, so the margins to the targets are the room the issue allows, not noise
 * allowance. Measured with this seed: EKF (AUTO) 6.42 % / 2.00 % and 1.43 % / 0.31 %;
 * KF+RLS 6.18 % / 1.67 % and 1.57 % / 0.41 %. */
static void ex3_check(vibid_estimator est, const char *label)
{
    ex3_stats a = ex3_study(est, 200, -1.0, 100);
    printf("  %s example 3, noise-free, N = 200, 100 runs: mean |error| c %.2f %%, d %.2f %% (physical k %.2f %%, d "
           "%.2f %%), failures %d\n",
           label, 100 * a.mare_c, 100 * a.mare_d, 100 * a.mare_k, 100 * a.mare_dd, a.fails);
    ex3_stats b = ex3_study(est, 5000, 20.0, 100);
    printf("  %s example 3, 20 dB, N = 5000, 100 runs: mean |error| c %.2f %%, d %.2f %% (physical k %.2f %%, d %.2f "
           "%%), failures %d\n",
           label, 100 * b.mare_c, 100 * b.mare_d, 100 * b.mare_k, 100 * b.mare_dd, b.fails);
    assert_int_equal(a.fails, 0);
    assert_int_equal(b.fails, 0);
    assert_true(a.mare_c <= 0.08 && a.mare_d <= 0.025);
    assert_true(b.mare_c <= 0.03 && b.mare_d <= 0.015);
}

static void test_ex3(void **state)
{
    (void)state;
    ex3_check(VIBID_ESTIMATOR_AUTO, "EKF");
}

/* A cubic spring on the unmeasured node: m1 (1 kg) on ground through k1 and eps (a
 * hardening spring: eps x^2 = k1 at 1 mm), m2 (0.5 kg) on m1, force on m2, only x2
 * measured (1 % noise), 60,000 samples (30 s at 2 kHz); amplitude about 1 mm, so the cubic force is of
 * the order of the linear one. All five unknowns start 15-20 % off. Bounds: the issue's
 * 2-DOF ones (stiffness-like 1 %, which the cubic coefficient shares; dampers 5 %), and
 * 3 standard errors. */
static const char *cubic_partial_stand =
    "stand = { name = \"cubic-partial\"; sample_rate = 2000.0;\n"
    "  nodes = ( { name = \"m1\"; mass = 1.0; },\n"
    "            { name = \"m2\"; mass = 0.5; measure = { displacement = \"x2\"; }; } );\n"
    "  elements = ( { name = \"k1\"; kind = \"spring\"; between = [\"m1\", \"ground\"]; unknown = true; value = 1.2e4; true_value = 1.0e4; },\n"
    "               { name = \"eps\"; kind = \"cubic_spring\"; between = [\"m1\", \"ground\"]; unknown = true; value = 0.8e10; true_value = 1.0e10; },\n"
    "               { name = \"d1\"; kind = \"damper\"; between = [\"m1\", \"ground\"]; unknown = true; value = 6.0; true_value = 5.0; },\n"
    "               { name = \"k2\"; kind = \"spring\"; between = [\"m1\", \"m2\"]; unknown = true; value = 1.7e4; true_value = 2.0e4; },\n"
    "               { name = \"d2\"; kind = \"damper\"; between = [\"m1\", \"m2\"]; unknown = true; value = 2.5; true_value = 3.0; } );\n"
    "  inputs = ( { name = \"f\"; node = \"m2\"; gain = 1.0; channel = \"F\"; } ); };\n"
    "simulation = { seed = 5; excitation = ( { target = \"f\"; kind = \"noise\"; amplitude = 15.0; f_low = 2.0; f_high = 150.0; } ); };\n";

static void test_cubic_partial(void **state)
{
    (void)state;
    identify_and_check("ekf_cubic.cfg", cubic_partial_stand, VIBID_ESTIMATOR_AUTO, 0.01, 0.01, 0.05);
}

/* The drift check (VIBID_QUALITY_SE_INVALID with z_consistency > 4): a stiff, lightly
 * damped 5-DOF chain at 10 kHz (the bench_stand_ekf chain: 70-200 Hz modes, zeta about
 * 2 %), force on m1, only x5 measured (0.1 % noise), 4 s. From 10 % off, the dampers
 * overshoot in the start transient and crawl back under standard errors that shrank
 * first (|z| up to 9 in bench runs): the estimate must be flagged, and the flag must be
 * deserved (some |z| > 3). From the truth the same filter holds: not flagged, every
 * |z| <= 3. */
#define CHAIN5_STAND(k1, d1, k2, d2, k3, d3, k4, d4, k5, d5) \
    "stand = { name = \"chain5\"; sample_rate = 10000.0;\n" \
    "  nodes = ( { name = \"m1\"; mass = 2.0; }, { name = \"m2\"; mass = 1.75; }, { name = \"m3\"; mass = 1.5; },\n" \
    "            { name = \"m4\"; mass = 1.25; }, { name = \"m5\"; mass = 1.0; measure = { displacement = \"x5\"; }; } );\n" \
    "  elements = ( { name = \"k1\"; kind = \"spring\"; between = [\"m1\", \"ground\"]; unknown = true; value = " k1 "; true_value = 4.0e5; },\n" \
    "   { name = \"d1\"; kind = \"damper\"; between = [\"m1\", \"ground\"]; unknown = true; value = " d1 "; true_value = 40.0; },\n" \
    "   { name = \"k2\"; kind = \"spring\"; between = [\"m2\", \"m1\"]; unknown = true; value = " k2 "; true_value = 3.5e5; },\n" \
    "   { name = \"d2\"; kind = \"damper\"; between = [\"m2\", \"m1\"]; unknown = true; value = " d2 "; true_value = 35.0; },\n" \
    "   { name = \"k3\"; kind = \"spring\"; between = [\"m3\", \"m2\"]; unknown = true; value = " k3 "; true_value = 3.0e5; },\n" \
    "   { name = \"d3\"; kind = \"damper\"; between = [\"m3\", \"m2\"]; unknown = true; value = " d3 "; true_value = 30.0; },\n" \
    "   { name = \"k4\"; kind = \"spring\"; between = [\"m4\", \"m3\"]; unknown = true; value = " k4 "; true_value = 2.5e5; },\n" \
    "   { name = \"d4\"; kind = \"damper\"; between = [\"m4\", \"m3\"]; unknown = true; value = " d4 "; true_value = 25.0; },\n" \
    "   { name = \"k5\"; kind = \"spring\"; between = [\"m5\", \"m4\"]; unknown = true; value = " k5 "; true_value = 2.0e5; },\n" \
    "   { name = \"d5\"; kind = \"damper\"; between = [\"m5\", \"m4\"]; unknown = true; value = " d5 "; true_value = 20.0; } );\n" \
    "  inputs = ( { name = \"f\"; node = \"m1\"; gain = 1.0; channel = \"F\"; hold = \"zoh\"; } ); };\n" \
    "simulation = { seed = 21; excitation = ( { target = \"f\"; kind = \"noise\"; amplitude = 100.0; f_high = 4000.0; } ); };\n"

static void chain5_run(const char *name, const char *text, int flagged_expected)
{
    capture c;
    simulate(&c, name, text, 40000);
    add_noise(&c, 0.001);
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 1e-4);
    vibid_ident *id = vibid_ident_create(vibid_stand_model(c.stand), &cfg);
    assert_non_null(id);
    if (vibid_ident_push_block(id, c.n, c.noisy) != VIBID_OK) fail_msg("push: %s", vibid_last_error());
    double theta[10], se[10], zmax = 0.0;
    assert_int_equal(vibid_ident_estimate(id, theta, se, NULL), VIBID_OK);
    vibid_ident_quality q;
    assert_int_equal(vibid_ident_get_quality(id, &q, NULL), VIBID_OK);
    for (size_t i = 0; i < c.p; i++) zmax = fmax(zmax, fabs(theta[i] - c.truth[i]) / se[i]);
    printf("  %s: flags %u, drift z %.2f, largest |estimate - truth| / se %.2f\n", name, q.flags, q.z_consistency, zmax);
    if (flagged_expected) {
        assert_int_equal(q.flags & VIBID_QUALITY_SE_INVALID, VIBID_QUALITY_SE_INVALID);
        assert_true(q.z_consistency > 4.0);
        assert_true(zmax > 3.0);
    } else {
        assert_int_equal(q.flags & VIBID_QUALITY_SE_INVALID, 0);
        assert_true(q.z_consistency <= 4.0);
        assert_true(zmax <= 3.0);
    }
    vibid_ident_destroy(id);
    capture_free(&c);
}

static void test_drift_check(void **state)
{
    (void)state;
    /* springs 10 % high, dampers 10 % low */
    chain5_run("ekf_chain5_off.cfg",
               CHAIN5_STAND("4.4e5", "36.0", "3.85e5", "31.5", "3.3e5", "27.0", "2.75e5", "22.5", "2.2e5", "18.0"), 1);
    chain5_run("ekf_chain5_truth.cfg",
               CHAIN5_STAND("4.0e5", "40.0", "3.5e5", "35.0", "3.0e5", "30.0", "2.5e5", "25.0", "2.0e5", "20.0"), 0);
}

/* The paper's KF+RLS (3.16) on the physical model (VIBID_ESTIMATOR_KF_RLS):
 * - example 3 against the targets (as test_ex3 for the EKF);
 * - the base-excited stand with only the upper spring and damper unknown (both act on
 *   the measured m1), 1 % noise: the 2-DOF bounds of the issue (1 %, 5 %). Its standard
 *   errors are always flagged (identify_all checks the flag), so no z test;
 * - stands where an unknown acts only on unmeasured nodes are refused by name. */
static void test_kf_rls(void **state)
{
    (void)state;
    ex3_check(VIBID_ESTIMATOR_KF_RLS, "KF+RLS");

    identify_and_check("kfrls_base_upper.cfg", base_upper_stand, VIBID_ESTIMATOR_KF_RLS, 0.01, 0.01, 0.05);
    /* The same capture noise-free: the KF+RLS's own bias, which the noise above happens to
     * hide (README, "Stands that are not fully measured"; measured c1 -2.4 %, d1 -2.3 %).
     * Bounded at 4 % so that a change of that bias shows here, not only in the README. */
    identify_and_check("kfrls_base_upper_clean.cfg", base_upper_stand, VIBID_ESTIMATOR_KF_RLS, 0.0, 0.04, 0.04);

    /* refused, naming what acts only on unmeasured nodes */
    static const struct {
        const char *name, *text, *names;
    } refused[] = {
        {"kfrls_base2.cfg", NULL, "KF+RLS cannot estimate 'c2', 'd2'"},
        {"kfrls_chain3.cfg", CHAIN3_HEAD CHAIN3_TAIL, "KF+RLS cannot estimate 'k1', 'd1', 'k2', 'd2'"},
    };
    char text[4096];
    snprintf(text, sizeof text, "%s%s", base_partial_stand, no_change);
    for (size_t i = 0; i < sizeof refused / sizeof refused[0]; i++) {
        capture c;
        simulate(&c, refused[i].name, refused[i].text ? refused[i].text : text, 100);
        vibid_ident_config cfg;
        vibid_ident_config_init(&cfg, 1.0 / 1000.0);
        cfg.estimator = VIBID_ESTIMATOR_KF_RLS;
        vibid_ident *id = vibid_ident_create(vibid_stand_model(c.stand), &cfg);
        assert_null(id);
        printf("  refused: %s\n", vibid_last_error());
        assert_non_null(strstr(vibid_last_error(), refused[i].names));
        assert_non_null(strstr(vibid_last_error(), "use method ekf"));
        capture_free(&c);
    }
}

/* The normalised innovations nu / sd of one channel after the tempering (inflation 1):
 * their mean square and the largest |autocorrelation| over lags 1..20. */
typedef struct innov_stats {
    size_t n, fresh_in_window, fresh_without_update, diverged;
    double mean_square, max_acf;
} innov_stats;

static innov_stats innovations_of(const capture *c, const vibid_model *m, size_t gap_at)
{
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 1.0 / 1000.0);
    cfg.estimator = VIBID_ESTIMATOR_EKF;
    vibid_ident *id = vibid_ident_create(m, &cfg);
    if (!id) fail_msg("vibid_ident_create: %s", vibid_last_error());
    double *z = malloc(c->n * sizeof(double));
    assert_non_null(z);
    innov_stats st = {0};
    double sample[8];
    for (size_t k = 0; k < c->n; k++) {
        for (size_t j = 0; j < c->nch; j++) sample[j] = k == gap_at ? NAN : c->noisy[k + j * c->n];
        const vibid_status s = vibid_ident_push(id, sample);
        if (s == VIBID_E_DIVERGED) ++st.diverged;
        else assert_int_equal(s, k == gap_at ? VIBID_E_NONFINITE : VIBID_OK);
        size_t n_out = 99, ch[4];
        double nu[4], sd[4], infl = 0.0;
        assert_int_equal(vibid_ident_innovations(id, 4, &n_out, ch, nu, sd, &infl), VIBID_OK);
        if (k < 1000 || k == gap_at || s == VIBID_E_DIVERGED) {
            /* the start window (the filter runs over it at its last sample) and a gap */
            if (n_out && k < 1000) ++st.fresh_in_window;
            if (n_out && k >= 1000) ++st.fresh_without_update;
            continue;
        }
        assert_int_equal(n_out, 1);                 /* x1: the only node sensor */
        assert_int_equal(ch[0], 0);                 /* channel order x1, s */
        assert_true(sd[0] > 0.0 && infl >= 1.0);
        if (infl == 1.0) z[st.n++] = nu[0] / sd[0];
    }
    double ms = 0.0, mean = 0.0;
    for (size_t k = 0; k < st.n; k++) {
        ms += z[k] * z[k];
        mean += z[k];
    }
    st.mean_square = ms / (double)st.n;
    mean /= (double)st.n;
    double c0 = 0.0;
    for (size_t k = 0; k < st.n; k++) c0 += (z[k] - mean) * (z[k] - mean);
    for (size_t lag = 1; lag <= 20; lag++) {
        double cl = 0.0;
        for (size_t k = lag; k < st.n; k++) cl += (z[k] - mean) * (z[k - lag] - mean);
        st.max_acf = fmax(st.max_acf, fabs(cl / c0));
    }
    free(z);
    vibid_ident_destroy(id);
    return st;
}

static void test_innovations(void **state)
{
    (void)state;
    capture c;
    simulate(&c, "ekf_innov.cfg", base_upper_stand, 60000);
    add_noise(&c, 0.01);
    const innov_stats ok = innovations_of(&c, vibid_stand_model(c.stand), 20000);
    printf("  consistent model: %zu settled innovations, mean square %.3f, max |acf(1..20)| %.4f "
           "(white: 1.96/sqrt(N) = %.4f)\n", ok.n, ok.mean_square, ok.max_acf, 1.96 / sqrt((double)ok.n));
    assert_int_equal(ok.fresh_in_window, 0);
    assert_int_equal(ok.fresh_without_update, 0);
    /* More than half of the 59,000 samples after the window are past the tempering. */
    assert_true(ok.n > 30000);
    /* The filter's R comes from the channel's differences and each velocity gets a 0.1 %
     * model-error allowance (identify.h), so S is not exact: 0.5..2 is the band of
     * vibid's own NIS check (flag above 2). */
    assert_true(ok.mean_square > 0.5 && ok.mean_square < 2.0);
    /* Not quite white: measured lag 1 -0.134 falling to 0 by lag 7. The base channel's
     * sensor noise drives the model's prediction as if it were motion, and the velocity
     * allowance makes the filter follow the data a little more than the model: both
     * colour the innovations by design. 0.2 bounds that; the 20 lags of white noise
     * would stay within 4/sqrt(N) < 0.023. */
    assert_true(ok.max_acf < 0.2);
    /* White: the 20 lags of N > 30000 samples stay within 4/sqrt(N) < 0.023 for white
     * noise with a probability above 0.99; 0.05 leaves room for the filter's slightly
     * wrong R and process noise without admitting the model error below. */

    /* The same capture with the lower spring declared 25 % soft: a model error. */
    char text[4096];
    snprintf(text, sizeof text, "%s", base_upper_stand);
    char *k2 = strstr(text, "value = 1.2e5;");
    assert_non_null(k2);
    memcpy(k2, "value = 9.0e4;", strlen("value = 9.0e4;"));
    const char *path = write_tmp("ekf_innov_wrong.cfg", text);
    vibid_stand_error serr;
    vibid_stand *wrong = vibid_stand_load(path, &serr);
    if (!wrong) fail_msg("%s", serr.text);
    const innov_stats bad = innovations_of(&c, vibid_stand_model(wrong), (size_t)-1);
    printf("  c2 declared 25 %% soft: %zu divergences, %zu settled innovations, mean square %.3f, "
           "max |acf(1..20)| %.4f\n", bad.diverged, bad.n, bad.mean_square, bad.max_acf);
    /* Measured 118 (and 17 divergences): the NIS check flags above 2 and restarts above 10. */
    assert_true(bad.mean_square > 10.0);
    assert_true(bad.diverged > 0);
    vibid_stand_destroy(wrong);

    /* The other estimators have no innovations. */
    vibid_model *m = vibid_model_create();
    size_t a, u;
    assert_int_equal(vibid_model_add_node(m, "m", 1.0, 0, &a), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "k", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, 10.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_input(m, "f", a, 1.0, 0, &u), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, a, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 0.01);
    cfg.estimator = VIBID_ESTIMATOR_LS;
    vibid_ident *ls = vibid_ident_create(m, &cfg);
    if (!ls) fail_msg("vibid_ident_create: %s", vibid_last_error());
    size_t n_out = 0;
    assert_int_equal(vibid_ident_innovations(ls, 0, &n_out, NULL, NULL, NULL, NULL), VIBID_E_UNSUPPORTED);
    assert_int_equal(vibid_ident_innovations(NULL, 0, &n_out, NULL, NULL, NULL, NULL), VIBID_E_NULL_ARGUMENT);
    vibid_ident_destroy(ls);
    vibid_model_destroy(m);
    capture_free(&c);
}

/* Refused before any sample, naming the parameters: two springs in parallel (only their
 * sum shows in any response). */
static void test_refusals(void **state)
{
    (void)state;
    vibid_model *m = vibid_model_create();
    size_t a;
    assert_int_equal(vibid_model_add_node(m, "m", 1.0, 0, &a), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "ka", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, 10.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "kb", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, 20.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "d", VIBID_ELEMENT_DAMPER, a, VIBID_GROUND, 1.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_disturbance(m, "w", a, 1.0, NULL), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, a, VIBID_MEASURE_ACCELERATION), VIBID_OK);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 0.01);
    assert_null(vibid_ident_create(m, &cfg));
    printf("  refused: %s\n", vibid_last_error());
    assert_non_null(strstr(vibid_last_error(), "not identifiable from the measured channels: 'ka', 'kb'"));
    vibid_model_destroy(m);
    /* no start value for an unknown: named */
    m = vibid_model_create();
    assert_int_equal(vibid_model_add_node(m, "m", 1.0, 0, &a), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "k", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, 0.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_disturbance(m, "w", a, 1.0, NULL), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, a, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    assert_null(vibid_ident_create(m, &cfg));
    printf("  refused: %s\n", vibid_last_error());
    assert_non_null(strstr(vibid_last_error(), "these unknowns have none: 'k'"));
    vibid_model_destroy(m);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_base_partial),
        cmocka_unit_test(test_base_drift),
        cmocka_unit_test(test_chain3_end),
        cmocka_unit_test(test_ex3),
        cmocka_unit_test(test_refusals),
        cmocka_unit_test(test_cubic_partial),
        cmocka_unit_test(test_drift_check),
        cmocka_unit_test(test_kf_rls),
        cmocka_unit_test(test_innovations),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
