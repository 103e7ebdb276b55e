/* test_rls_small_p.c: RLS with few parameters and one output, where the Bierman form
 * updates all equations of a sample in one kernel call with its state in registers
 * (lib/src/kernels.hpp, bierman_small; p <= 4, q = 1, as example 1: p = 3, m = 2).
 *
 * 1. Against a reference in the test: the covariance-form recursion of rls.h in long double
 *    (64-bit mantissa), for p = 1..5 (5 is past the boundary: the per-equation kernel) and
 *    m = 1..3, with forgetting 1, 0.98, and 0.98 with the trace bound (the forgetting
 *    raised per sample, which the reference takes from the library's trace). Theta, P,
 *    Sigma_e, trace(P) and n_eff every 10 of 300 samples. Tolerance 1e-12 relative to each
 *    array's largest entry: the data are well conditioned (independent normal regressors),
 *    the Bierman form's rounding stays below 1e-14 here and the reference's below 1e-16
 *    (its start P = 100 I falls to ~0.02, a cancellation of 1e4 in 64-bit mantissas), while
 *    a slip in the forgetting, the order of the equations or an index shows at 1e-3 or worse.
 *    The test prints the largest difference.
 * 2. A bad sample, whichever of its equations is bad (a NaN or Inf in the second
 *    equation's x or y, an overflow in the first or only in the second), is refused and
 *    leaves the estimator bit-identical: the kernel writes only the uncommitted slot. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <string.h>

#include <vibid/rls.h>

#include "rls_check.h"
#include "test_assert.h"
#include "test_rng.h"

enum { PMAX = 5, MMAX = 3, N = 300 };
static const double kAlpha = 1e-2; /* P0 = I / alpha */
static const double kTol = 1e-12;  /* relative to each array's largest entry: see the top */

static double trace_bound(size_t p, size_t m) { return 0.01 * (double)p / (double)m; }

static vibid_rls *make(size_t p, size_t m, double forgetting, vibid_rls_windup windup) {
    vibid_rls_config cfg;
    vibid_rls_config_init(&cfg, p, 1);
    cfg.n_equations = m;
    cfg.forgetting = forgetting;
    cfg.alpha = kAlpha;
    cfg.windup = windup;
    /* A bound below the trace that forgetting 0.98 settles at (about p / (50 m) with unit
     * regressors), reached after ~100 samples: from there on the forgetting is raised. */
    cfg.trace_max = trace_bound(p, m);
    vibid_rls *rls = vibid_rls_create(&cfg);
    assert_non_null(rls);
    return rls;
}

/* The reference: the covariance-form recursion of rls.h in long double (64-bit mantissa),
 * with the forgetting of each sample chosen as the library does (trace bound). */
typedef struct {
    size_t p;
    long double P[PMAX * PMAX], th[PMAX], V, n_eff;
} ref_rls;

static void ref_init(ref_rls *r, size_t p, double alpha) {
    memset(r, 0, sizeof *r);
    r->p = p;
    for (size_t i = 0; i < p; ++i) r->P[i + i * p] = 1.0L / alpha;
}

static long double ref_trace(const ref_rls *r) {
    long double t = 0.0L;
    for (size_t i = 0; i < r->p; ++i) t += r->P[i + i * r->p];
    return t;
}

/* One sample of m equations: P <- P / g once, then per equation phi = P x,
 * s = 1 + x^T phi, e = y - Theta^T x, Theta += phi e / s, P -= phi phi^T / s (kept exactly
 * symmetric), V <- g V + e^2 / s (g for the first equation only). */
static void ref_update(ref_rls *r, const double *x, const double *y, size_t m, double g) {
    const size_t p = r->p;
    for (size_t k = 0; k < p * p; ++k) r->P[k] /= g;
    r->V *= g;
    for (size_t i = 0; i < m; ++i) {
        const double *xi = x + i * p;
        long double phi[PMAX], s = 1.0L, e = y[i];
        for (size_t a = 0; a < p; ++a) {
            phi[a] = 0.0L;
            for (size_t b = 0; b < p; ++b) phi[a] += r->P[a + b * p] * xi[b];
            s += xi[a] * phi[a];
            e -= r->th[a] * xi[a];
        }
        for (size_t a = 0; a < p; ++a) {
            r->th[a] += phi[a] * e / s;
            for (size_t b = 0; b < p; ++b) r->P[a + b * p] -= phi[a] * phi[b] / s;
        }
        r->V += e * e / s;
    }
    r->n_eff = g * r->n_eff + (long double)m;
}

/* max |a - b| / max |b| over n entries, b in long double. */
static double rel_diff_ld(const double *a, const long double *b, size_t n) {
    long double d = 0.0L, s = 0.0L;
    for (size_t i = 0; i < n; ++i) {
        d = fmaxl(d, fabsl((long double)a[i] - b[i]));
        s = fmaxl(s, fabsl(b[i]));
    }
    return (double)(s > 0.0L ? d / s : d);
}

/* Largest relative difference of the Bierman form against the reference over Theta, P and
 * Sigma_e during N samples of (p, m) (checked every 10 samples and at the end). */
static double compare_reference(size_t p, size_t m, double forgetting, vibid_rls_windup windup) {
    vibid_rls *rls = make(p, m, forgetting, windup);
    ref_rls ref;
    ref_init(&ref, p, kAlpha);
    test_rng rng;
    test_rng_seed(&rng, 500 + 10 * p + m);
    double theta_true[PMAX], x[PMAX * MMAX], y[MMAX], th[PMAX], P[PMAX * PMAX], sigma;
    double worst = 0.0, raised = 0.0; /* largest forgetting applied */
    test_rng_fill_normal(&rng, theta_true, p, 1.0);
    for (int k = 1; k <= N; ++k) {
        test_rng_fill_normal(&rng, x, p * m, 1.0);
        for (size_t i = 0; i < m; ++i) {
            y[i] = 0.1 * test_rng_normal(&rng);
            for (size_t l = 0; l < p; ++l) y[i] += x[l + i * p] * theta_true[l];
        }
        /* The forgetting the library applies (rls.h): from its trace before the sample. */
        vibid_rls_stats st;
        assert_int_equal(vibid_rls_get_stats(rls, &st), VIBID_OK);
        double g = forgetting;
        if (windup == VIBID_RLS_WINDUP_TRACE_BOUND) g = fmin(1.0, fmax(forgetting, st.trace_p / trace_bound(p, m)));
        assert_int_equal(vibid_rls_update(rls, x, y), VIBID_OK);
        ref_update(&ref, x, y, m, g);
        assert_int_equal(vibid_rls_get_stats(rls, &st), VIBID_OK);
        ASSERT_NEAR(st.last_forgetting, g, 0.0);
        raised = fmax(raised, g);
        if (k % 10) continue;
        assert_int_equal(vibid_rls_theta(rls, th), VIBID_OK);
        assert_int_equal(vibid_rls_covariance(rls, P), VIBID_OK);
        worst = fmax(worst, rel_diff_ld(th, ref.th, p));
        worst = fmax(worst, rel_diff_ld(P, ref.P, p * p));
        ASSERT_NEAR(st.trace_p, (double)ref_trace(&ref), kTol * (double)ref_trace(&ref));
        ASSERT_NEAR(st.n_eff, (double)ref.n_eff, kTol * (double)ref.n_eff);
        assert_int_equal(st.n_samples, k);
        assert_true(st.min_d > 0.0);
        if (st.n_eff > (double)p) {
            assert_int_equal(vibid_rls_residual_covariance(rls, &sigma), VIBID_OK);
            const long double sref = ref.V / (ref.n_eff - (long double)p);
            worst = fmax(worst, rel_diff_ld(&sigma, &sref, 1));
        }
        if (!(worst <= kTol))
            print_error("p = %zu, m = %zu, forgetting %g, windup %d, sample %d: relative difference %.3g\n", p, m,
                        forgetting, (int)windup, k, worst);
        assert_true(worst <= kTol);
    }
    /* The estimate is the truth up to the noise (0.1 per equation): it really learnt. */
    for (size_t l = 0; l < p; ++l) ASSERT_NEAR(th[l], theta_true[l], 0.05);
    /* With the bound the forgetting was raised above the nominal on some samples. */
    if (windup == VIBID_RLS_WINDUP_TRACE_BOUND) assert_true(raised > forgetting);
    vibid_rls_destroy(rls);
    return worst;
}

static void test_matches_reference(void **state) {
    (void)state;
    double worst = 0.0;
    for (size_t p = 1; p <= PMAX; ++p)
        for (size_t m = 1; m <= MMAX; ++m) {
            worst = fmax(worst, compare_reference(p, m, 1.0, VIBID_RLS_WINDUP_NONE));
            worst = fmax(worst, compare_reference(p, m, 0.98, VIBID_RLS_WINDUP_NONE));
            worst = fmax(worst, compare_reference(p, m, 0.98, VIBID_RLS_WINDUP_TRACE_BOUND));
        }
    printf("  Bierman vs long double reference, p = 1..5, m = 1..3: largest relative difference %.2g "
           "(tolerance %g)\n",
           worst, kTol);
}

/* The call must return status and leave the estimator bit-identical. */
static void expect_refused(vibid_rls *rls, const double *x, const double *y, vibid_status status) {
    rls_snapshot before, after;
    rls_snapshot_take(&before, rls, 3, 1);
    assert_int_equal(vibid_rls_update(rls, x, y), status);
    rls_snapshot_take(&after, rls, 3, 1);
    assert_true(rls_snapshot_equal(&before, &after));
    rls_snapshot_free(&before);
    rls_snapshot_free(&after);
}

static void test_bad_equation_leaves_state(void **state) {
    (void)state;
    for (int bound = 0; bound < 2; ++bound) {
        vibid_rls *rls =
            make(3, 2, 0.98, bound ? VIBID_RLS_WINDUP_TRACE_BOUND : VIBID_RLS_WINDUP_NONE);
        test_rng rng;
        test_rng_seed(&rng, 77);
        double x[6], y[2];
        for (int k = 0; k < 50; ++k) {
            test_rng_fill_normal(&rng, x, 6, 1.0);
            test_rng_fill_normal(&rng, y, 2, 1.0);
            assert_int_equal(vibid_rls_update(rls, x, y), VIBID_OK);
        }
        const double xg[6] = {0.3, -1.2, 0.8, 1.1, 0.4, -0.7}, yg[2] = {0.5, -0.2};
        memcpy(x, xg, sizeof x);
        memcpy(y, yg, sizeof y);
        x[5] = NAN; /* second equation's regressor */
        expect_refused(rls, x, y, VIBID_E_NONFINITE);
        x[5] = xg[5];
        y[1] = INFINITY; /* second equation's target */
        expect_refused(rls, x, y, VIBID_E_NONFINITE);
        y[1] = yg[1];
        x[3] = 1e200; /* overflow in the second equation only: the first one succeeds */
        expect_refused(rls, x, y, VIBID_E_NUMERICAL);
        x[3] = xg[3];
        x[0] = 1e200; /* overflow in the first equation, the second one fine */
        expect_refused(rls, x, y, VIBID_E_NUMERICAL);
        x[0] = xg[0];
        /* And the good sample is taken afterwards. */
        assert_int_equal(vibid_rls_update(rls, x, y), VIBID_OK);
        vibid_rls_destroy(rls);
    }
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_matches_reference),
        cmocka_unit_test(test_bad_equation_leaves_state),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
