/* test_rls_windup.c: long run with forgetting 0.98 and an input that excites only now
 * and then (shortened version of bench/bench_rls_longrun.c, 10^6 updates).
 *
 * Schedule, repeated: 1000 exciting samples; 12000 samples with x = 0 (nothing to
 * learn: plain forgetting multiplies P by 0.98^-12000 ~ 1e105); 1000 exciting samples;
 * 11000 samples along one constant direction (P grows in the other three directions).
 * The Bierman form with the trace bound must keep P symmetric positive definite with
 * trace(P) <= trace_max throughout and still estimate Theta; the other variants are
 * run on the same data and what they do is asserted as measured. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <string.h>

#include <vibid/rls.h>

#include "rls_check.h"
#include "test_rng.h"

enum { P_DIM = 4, CYCLE = 25000, CHECK_EVERY = 500 };
static const double theta_true[P_DIM] = {2.0, -1.0, 0.5, 3.0};
static const double direction[P_DIM] = {1.0, 0.5, -0.25, 0.0};

typedef struct windup_result {
    long first_not_pd;   /* first checked update at which P failed Cholesky, -1 if never */
    long first_refused;  /* first update refused with VIBID_E_NUMERICAL, -1 if never */
    long n_refused;
    double max_trace;      /* largest trace(P) seen (stats, every update) */
    double max_trace_settled; /* largest trace(P) once it first was <= trace_max (-1: never) */
    double max_trace_rel;  /* largest |stats trace - trace of the P read back| / trace */
    double max_asym;       /* largest relative asymmetry of P (rls_check_asymmetry) */
    double min_d;          /* smallest min_d seen */
    double theta_err;      /* max |Theta - true| at the end of the last exciting block */
} windup_result;

/* Sample k of the schedule into x, y (noise 0.01 on y). */
static void sample(test_rng *rng, long k, double *x, double *y) {
    const long t = k % CYCLE;
    if (t < 1000 || (t >= 13000 && t < 14000)) {
        for (int i = 0; i < P_DIM; ++i) x[i] = test_rng_normal(rng);
    } else if (t < 13000) {
        memset(x, 0, P_DIM * sizeof *x);
    } else {
        for (int i = 0; i < P_DIM; ++i) x[i] = direction[i];
    }
    *y = 0.01 * test_rng_normal(rng);
    for (int i = 0; i < P_DIM; ++i) *y += x[i] * theta_true[i];
}

static windup_result run(vibid_rls_form form, vibid_rls_windup windup, double trace_max, long n_updates) {
    vibid_rls_config cfg;
    vibid_rls_config_init(&cfg, P_DIM, 1);
    cfg.form = form;
    cfg.forgetting = 0.98;
    cfg.alpha = 1e-3;
    cfg.windup = windup;
    cfg.trace_max = trace_max;
    vibid_rls *rls = vibid_rls_create(&cfg);
    assert_non_null(rls);

    windup_result r = {-1, -1, 0, 0.0, -1.0, 0.0, 0.0, INFINITY, NAN};
    test_rng rng;
    test_rng_seed(&rng, 2024);
    double x[P_DIM], y, P[P_DIM * P_DIM], th[P_DIM];
    vibid_rls_stats st;
    for (long k = 0; k < n_updates; ++k) {
        sample(&rng, k, x, &y);
        const vibid_status s = vibid_rls_update(rls, x, &y);
        if (s == VIBID_E_NUMERICAL) {
            if (r.first_refused < 0) r.first_refused = k;
            ++r.n_refused;
        } else {
            assert_int_equal(s, VIBID_OK);
        }
        assert_int_equal(vibid_rls_get_stats(rls, &st), VIBID_OK);
        if (!(st.trace_p <= r.max_trace)) r.max_trace = st.trace_p;
        if ((r.max_trace_settled >= 0.0 || st.trace_p <= trace_max) && !(st.trace_p <= r.max_trace_settled))
            r.max_trace_settled = st.trace_p;
        if (!(st.min_d >= r.min_d)) r.min_d = st.min_d;
        const long t = k % CYCLE;
        if (k % CHECK_EVERY == 0 || t == 999 || t == 13999) {
            assert_int_equal(vibid_rls_covariance(rls, P), VIBID_OK);
            if (r.first_not_pd < 0 && !rls_check_is_pd(P, P_DIM)) r.first_not_pd = k;
            const double a = rls_check_asymmetry(P, P_DIM);
            if (!(a <= r.max_asym)) r.max_asym = a;
            double tr = 0.0;
            for (int i = 0; i < P_DIM; ++i) tr += P[i + i * P_DIM];
            const double rel = fabs(tr - st.trace_p) / fabs(tr);
            if (!(rel <= r.max_trace_rel)) r.max_trace_rel = rel;
        }
        if (k == n_updates - CYCLE + 13999) {
            assert_int_equal(vibid_rls_theta(rls, th), VIBID_OK);
            r.theta_err = 0.0;
            for (int i = 0; i < P_DIM; ++i) r.theta_err = fmax(r.theta_err, fabs(th[i] - theta_true[i]));
        }
    }
    vibid_rls_destroy(rls);
    print_message("  first not PD %ld, first refused %ld, refused %ld, max trace %.3g (settled %.3g), "
                  "trace mismatch %.2g, "
                  "max asymmetry %.3g, min D %.3g, Theta error %.3g\n",
                  r.first_not_pd, r.first_refused, r.n_refused, r.max_trace, r.max_trace_settled, r.max_trace_rel, r.max_asym, r.min_d,
                  r.theta_err);
    return r;
}

/* The guarded robust form over 10^6 updates (40 cycles): no refusal, P positive definite and exactly symmetric at
 * every check, trace(P) <= trace_max up to rounding (relative 1e-12: the trace is a
 * sum of 4 products, each rounded at 1e-16), the stats trace equals the trace of the P
 * read back (1e-12, same reason), and Theta is still right: noise 0.01 over an
 * effective window of ~50 exciting samples gives stderr ~ 1.5e-3, so 0.01 is a
 * 6-sigma bound. */
static void test_bierman_trace_bound_stays_bounded(void **state) {
    (void)state;
    const double trace_max = P_DIM / 1e-3;
    const windup_result r = run(VIBID_RLS_FORM_BIERMAN_UD, VIBID_RLS_WINDUP_TRACE_BOUND, trace_max, 40 * CYCLE);
    assert_int_equal(r.n_refused, 0);
    assert_int_equal(r.first_not_pd, -1);
    assert_true(r.max_trace <= trace_max * (1.0 + 1e-12));
    assert_true(r.max_trace_rel < 1e-12);
    assert_true(r.max_asym == 0.0);
    assert_true(r.min_d > 0.0);
    assert_true(r.theta_err < 0.01);
}

/* A tighter bound than the prior's trace (4 cycles): forgetting is suspended until the
 * data pull trace(P) under it, and from then on the bound holds. Same tolerances. */
static void test_bierman_tight_trace_bound(void **state) {
    (void)state;
    const double trace_max = 1.0;
    const windup_result r = run(VIBID_RLS_FORM_BIERMAN_UD, VIBID_RLS_WINDUP_TRACE_BOUND, trace_max, 4 * CYCLE);
    assert_int_equal(r.n_refused, 0);
    assert_int_equal(r.first_not_pd, -1);
    /* trace(P0) = 4000 > 1; the first exciting samples bring it below 1, for good. */
    assert_true(r.max_trace <= 4000.0 * (1.0 + 1e-12));
    assert_true(r.max_trace_settled >= 0.0 && r.max_trace_settled <= trace_max * (1.0 + 1e-12));
    assert_true(r.min_d > 0.0);
    assert_true(r.theta_err < 0.01);
}

/* Without the guard (2 cycles) the UD form winds up: measured max trace 1.8e104 after
 * the first 12000-sample gap, i.e. 0.98^-12000 times the trace after excitation. Its
 * factors stay valid (D > 0, no refusal), but the P they represent has a condition
 * number ~1e106 when the next excitation collapses one direction: the explicit P read
 * back fails Cholesky at k = 13000 (measured). Asserted: trace > 1e90, D > 0 always,
 * no refusal, explicit P not numerically PD during the first cycle. */
static void test_bierman_without_guard_winds_up(void **state) {
    (void)state;
    const windup_result r = run(VIBID_RLS_FORM_BIERMAN_UD, VIBID_RLS_WINDUP_NONE, 1.0, 2 * CYCLE);
    assert_true(r.max_trace > 1e90);
    assert_int_equal(r.n_refused, 0);
    assert_true(r.min_d > 0.0);
    assert_true(r.first_not_pd >= 0 && r.first_not_pd < CYCLE);
}

/* The plain covariance form without guard (2 cycles). Measured: trace 1.6e104 after the
 * first gap; at the first exciting sample after it (k = 13000) P collapses from ~1e104 to
 * ~1e-2 by cancellation and is no longer positive definite; from k = 13004 on the
 * innovation variance gamma + x^T P x is not positive and nearly every update is refused
 * (Theta frozen at a wrong value); min diag(P) reaches -5e207, asymmetry 0.1.
 * Asserted: not PD within the first cycle, relative asymmetry >= 1e-3 (or NaN), more
 * than half of the remaining updates refused. */
static void test_covariance_form_fails(void **state) {
    (void)state;
    const windup_result r = run(VIBID_RLS_FORM_COVARIANCE, VIBID_RLS_WINDUP_NONE, 1.0, 2 * CYCLE);
    assert_true(r.first_not_pd >= 0 && r.first_not_pd < CYCLE);
    assert_true(!(r.max_asym < 1e-3)); /* NaN counts as failed too */
    assert_true(r.first_refused >= 0 && r.n_refused > (2 * CYCLE - r.first_refused) / 2);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_bierman_trace_bound_stays_bounded),
        cmocka_unit_test(test_bierman_tight_trace_bound),
        cmocka_unit_test(test_bierman_without_guard_winds_up),
        cmocka_unit_test(test_covariance_form_fails),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
