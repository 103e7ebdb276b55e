/* test_rls.c: recursive least squares (vibid/rls.h) against batch least squares
 * (vibid/lsq.h) and hand-computed cases; prior, reset, frozen adaptation; every
 * bad-input path leaves the estimator bit-identical. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <vibid/lsq.h>
#include <vibid/rls.h>

#include "rls_check.h"
#include "test_rng.h"

static const vibid_rls_form forms[2] = {VIBID_RLS_FORM_BIERMAN_UD, VIBID_RLS_FORM_COVARIANCE};

static double *alloc_doubles(size_t n) {
    double *v = calloc(n, sizeof *v);
    assert_non_null(v);
    return v;
}

static vibid_rls *make(size_t p, size_t q, size_t m, vibid_rls_form form, double forgetting, double alpha) {
    vibid_rls_config cfg;
    vibid_rls_config_init(&cfg, p, q);
    cfg.n_equations = m;
    cfg.form = form;
    cfg.forgetting = forgetting;
    cfg.alpha = alpha;
    vibid_rls *rls = vibid_rls_create(&cfg);
    assert_non_null(rls);
    return rls;
}

/* Compares RLS on N samples of m equations each with batch LS on the same N m rows plus
 * the P0 prior as p extra rows sqrt(alpha) e_i^T with targets sqrt(alpha) theta0(i, :):
 * both then minimise the same quadratic, so Theta, P = (X^T X)^-1 and the residual sum
 * of squares agree up to rounding. With Sigma (m x m) the equations of a sample are
 * correlated: RLS whitens them, LS gets them through vibid_lsq_add_correlated.
 * Tolerance 1e-9 relative: the data are well conditioned (cond(X) ~ 3), so both
 * orthogonal-QR and Bierman/covariance recursions are accurate to ~1e-13; 1e-9 leaves
 * room for the plain covariance form's slower error growth and still catches any
 * algebraic slip (which shows at the 1e-3 level or worse). */
static void check_against_batch(vibid_rls_form form, size_t p, size_t q, size_t m, const double *Sigma) {
    const size_t N = 200;
    const double alpha = 1e-2;
    test_rng rng;
    test_rng_seed(&rng, 1000 + p * 100 + q * 10 + m);

    vibid_rls *rls = make(p, q, m, form, 1.0, alpha);
    vibid_lsq *lsq = vibid_lsq_create(p, q);
    assert_non_null(lsq);

    /* Non-zero theta0 so that the prior rows' targets are exercised too. */
    double *theta0 = alloc_doubles(p * q), *theta_true = alloc_doubles(p * q);
    test_rng_fill_normal(&rng, theta0, p * q, 0.5);
    test_rng_fill_normal(&rng, theta_true, p * q, 1.0);
    assert_int_equal(vibid_rls_set_prior(rls, theta0, NULL), VIBID_OK);
    if (Sigma) assert_int_equal(vibid_rls_set_equation_covariance(rls, Sigma), VIBID_OK);

    double *Xp = alloc_doubles(p * p), *Yp = alloc_doubles(p * q);
    for (size_t i = 0; i < p; ++i) {
        Xp[i + i * p] = sqrt(alpha);
        for (size_t j = 0; j < q; ++j) Yp[i + j * p] = sqrt(alpha) * theta0[i + j * p];
    }
    assert_int_equal(vibid_lsq_add_rows(lsq, p, Xp, Yp, NULL), VIBID_OK);

    double *x = alloc_doubles(p * m), *y = alloc_doubles(m * q);
    double *Xr = alloc_doubles(m * p); /* the sample as m LS rows (m x p) */
    for (size_t k = 0; k < N; ++k) {
        test_rng_fill_normal(&rng, x, p * m, 1.0);
        for (size_t i = 0; i < m; ++i)
            for (size_t j = 0; j < q; ++j) {
                double s = 0.1 * test_rng_normal(&rng);
                for (size_t l = 0; l < p; ++l) s += x[l + i * p] * theta_true[l + j * p];
                y[i + j * m] = s;
            }
        for (size_t i = 0; i < m; ++i)
            for (size_t l = 0; l < p; ++l) Xr[i + l * m] = x[l + i * p];
        assert_int_equal(vibid_rls_update(rls, x, y), VIBID_OK);
        if (Sigma)
            assert_int_equal(vibid_lsq_add_correlated(lsq, m, Xr, y, Sigma), VIBID_OK);
        else
            assert_int_equal(vibid_lsq_add_rows(lsq, m, Xr, y, NULL), VIBID_OK);
    }

    double *th_rls = alloc_doubles(p * q), *th_ls = alloc_doubles(p * q);
    double *P_rls = alloc_doubles(p * p), *P_ls = alloc_doubles(p * p);
    double *S_rls = alloc_doubles(q * q), *S_ls = alloc_doubles(q * q);
    assert_int_equal(vibid_rls_theta(rls, th_rls), VIBID_OK);
    assert_int_equal(vibid_rls_covariance(rls, P_rls), VIBID_OK);
    assert_int_equal(vibid_rls_residual_covariance(rls, S_rls), VIBID_OK);
    assert_int_equal(vibid_lsq_solve(lsq, th_ls, NULL), VIBID_OK);
    assert_int_equal(vibid_lsq_covariance(lsq, P_ls, S_ls), VIBID_OK);

    assert_true(rls_check_rel_diff(th_rls, th_ls, p * q) < 1e-9);
    assert_true(rls_check_rel_diff(P_rls, P_ls, p * p) < 1e-9);
    /* Same residual sum of squares, different divisors: RLS divides by n_eff - p =
     * N m - p, LS (whose n_rows include the p prior rows) by N m + p - p. */
    const double nm = (double)(N * m);
    for (size_t i = 0; i < q * q; ++i) {
        S_rls[i] *= nm - (double)p;
        S_ls[i] *= nm;
    }
    assert_true(rls_check_rel_diff(S_rls, S_ls, q * q) < 1e-9);

    /* Standard errors: sqrt(P_ii Sigma_jj), i.e. the LS ones rescaled by the divisors. */
    double *se_rls = alloc_doubles(p * q), *se_ls = alloc_doubles(p * q);
    assert_int_equal(vibid_rls_stderr(rls, se_rls), VIBID_OK);
    assert_int_equal(vibid_lsq_stderr(lsq, se_ls), VIBID_OK);
    for (size_t i = 0; i < p * q; ++i) se_ls[i] *= sqrt(nm / (nm - (double)p));
    assert_true(rls_check_rel_diff(se_rls, se_ls, p * q) < 1e-9);

    vibid_rls_stats st;
    assert_int_equal(vibid_rls_get_stats(rls, &st), VIBID_OK);
    assert_int_equal(st.n_samples, N);
    assert_true(st.n_eff == nm);
    assert_true(st.min_d > 0.0);

    free(se_rls), free(se_ls), free(S_rls), free(S_ls), free(P_rls), free(P_ls), free(th_rls), free(th_ls);
    free(Xr), free(x), free(y), free(Xp), free(Yp), free(theta0), free(theta_true);
    vibid_lsq_destroy(lsq);
    vibid_rls_destroy(rls);
}

static void test_matches_batch_single_equation(void **state) {
    (void)state;
    for (int f = 0; f < 2; ++f) {
        check_against_batch(forms[f], 5, 1, 1, NULL);
        check_against_batch(forms[f], 6, 3, 1, NULL); /* q > 1: outputs share P */
    }
}

static void test_matches_batch_multi_equation(void **state) {
    (void)state;
    for (int f = 0; f < 2; ++f) {
        check_against_batch(forms[f], 6, 2, 3, NULL); /* m = 3 equations per sample */
        check_against_batch(forms[f], 4, 1, 2, NULL);
    }
}

static void test_matches_gauss_markov_with_equation_covariance(void **state) {
    (void)state;
    /* A strongly correlated, unequal-variance 3 x 3 equation covariance. */
    const double Sigma[9] = {2.0, 0.8, -0.3, 0.8, 1.0, 0.2, -0.3, 0.2, 0.5};
    for (int f = 0; f < 2; ++f) check_against_batch(forms[f], 5, 2, 3, Sigma);
}

/* p = q = m = 1, gamma = 0.5, alpha = 1, two samples (x, y) = (1, 2), (2, 1). By hand
 * from (2.9)/(2.10): P1 = 1 / (0.5 + 1) = 2/3, theta1 = 4/3; P2 = 1 / (0.5 * 1.5 + 4) =
 * 4/19; theta2 minimises 0.25 th^2 + 0.5 (2 - th)^2 + (1 - 2 th)^2: 12/19. Residual
 * statistics: V = 0.5 * 2^2 / 3 + (5/3)^2 / (1 + 4 * 4/3) = 21/19 (the weighted RSS at
 * theta2, prior term included), n_eff = 1.5, Sigma_e = V / (n_eff - 1) = 42/19.
 * Tolerance 1e-14: a dozen roundings of O(1) numbers. */
static void test_forgetting_hand_case(void **state) {
    (void)state;
    for (int f = 0; f < 2; ++f) {
        vibid_rls *rls = make(1, 1, 1, forms[f], 0.5, 1.0);
        double x = 1.0, y = 2.0, th, P, S;
        assert_int_equal(vibid_rls_update(rls, &x, &y), VIBID_OK);
        assert_int_equal(vibid_rls_theta(rls, &th), VIBID_OK);
        assert_int_equal(vibid_rls_covariance(rls, &P), VIBID_OK);
        assert_true(fabs(th - 4.0 / 3.0) < 1e-14);
        assert_true(fabs(P - 2.0 / 3.0) < 1e-14);
        x = 2.0, y = 1.0;
        assert_int_equal(vibid_rls_update(rls, &x, &y), VIBID_OK);
        assert_int_equal(vibid_rls_theta(rls, &th), VIBID_OK);
        assert_int_equal(vibid_rls_covariance(rls, &P), VIBID_OK);
        assert_int_equal(vibid_rls_residual_covariance(rls, &S), VIBID_OK);
        assert_true(fabs(th - 12.0 / 19.0) < 1e-14);
        assert_true(fabs(P - 4.0 / 19.0) < 1e-14);
        assert_true(fabs(S - 42.0 / 19.0) < 1e-14);
        vibid_rls_stats st;
        assert_int_equal(vibid_rls_get_stats(rls, &st), VIBID_OK);
        assert_true(st.n_eff == 1.5);
        assert_true(st.last_forgetting == 0.5);
        assert_true(fabs(st.trace_p - 4.0 / 19.0) < 1e-14);
        vibid_rls_destroy(rls);
    }
}

/* A parameter step at k = 200: with gamma = 0.95 (memory ~ 1 / (1 - gamma) = 20
 * samples) the estimate follows to within 0.02 after 200 more samples (noise 0.01,
 * stderr ~ 0.01 / sqrt(20) ~ 2e-3, so 0.02 is a 10-sigma bound; the old data's weight is
 * 0.95^200 ~ 4e-5). Without forgetting the estimate stays a blend of both regimes,
 * off by about half the step (0.25 / 0.5): forgetting is what makes it track.
 * The run is short on purpose: the plain covariance form is unstable under forgetting
 * (its rounding asymmetry grows like gamma^-k, measured: 1e-15 -> 0.3 in 600 samples at
 * gamma = 0.95, then P is indefinite); test_rls_windup.c covers that. */
static void test_forgetting_tracks_step(void **state) {
    (void)state;
    const double before[2] = {1.0, 2.0}, after[2] = {1.5, 1.0};
    for (int f = 0; f < 2; ++f) {
        vibid_rls *fast = make(2, 1, 1, forms[f], 0.95, 1e-2);
        vibid_rls *slow = make(2, 1, 1, forms[f], 1.0, 1e-2);
        test_rng rng;
        test_rng_seed(&rng, 7);
        for (int k = 0; k < 400; ++k) {
            const double *th = k < 200 ? before : after;
            double x[2] = {test_rng_normal(&rng), test_rng_normal(&rng)};
            double y = th[0] * x[0] + th[1] * x[1] + 0.01 * test_rng_normal(&rng);
            assert_int_equal(vibid_rls_update(fast, x, &y), VIBID_OK);
            assert_int_equal(vibid_rls_update(slow, x, &y), VIBID_OK);
        }
        double tf[2], ts[2];
        assert_int_equal(vibid_rls_theta(fast, tf), VIBID_OK);
        assert_int_equal(vibid_rls_theta(slow, ts), VIBID_OK);
        assert_true(fabs(tf[0] - after[0]) < 0.02 && fabs(tf[1] - after[1]) < 0.02);
        assert_true(fabs(ts[0] - after[0]) > 0.2 || fabs(ts[1] - after[1]) > 0.3);
        vibid_rls_destroy(fast);
        vibid_rls_destroy(slow);
    }
}

/* Batch start: LS on the first half, its estimate and (X1^T X1)^-1 as the prior, then
 * RLS on the second half must equal LS on all data (no alpha prior at all: the batch
 * part carries the information). Same 1e-9 argument as check_against_batch. */
static void test_prior_from_batch_start(void **state) {
    (void)state;
    const size_t p = 5, q = 2, N1 = 40, N2 = 160;
    for (int f = 0; f < 2; ++f) {
        test_rng rng;
        test_rng_seed(&rng, 99);
        vibid_lsq *first = vibid_lsq_create(p, q), *all = vibid_lsq_create(p, q);
        assert_non_null(first);
        assert_non_null(all);
        double theta_true[10];
        test_rng_fill_normal(&rng, theta_true, p * q, 1.0);
        double x[5], y[2];
        vibid_rls *rls = make(p, q, 1, forms[f], 1.0, 1e-6);
        for (size_t k = 0; k < N1 + N2; ++k) {
            test_rng_fill_normal(&rng, x, p, 1.0);
            for (size_t j = 0; j < q; ++j) {
                y[j] = 0.1 * test_rng_normal(&rng);
                for (size_t l = 0; l < p; ++l) y[j] += x[l] * theta_true[l + j * p];
            }
            assert_int_equal(vibid_lsq_add_rows(all, 1, x, y, NULL), VIBID_OK);
            if (k < N1) {
                assert_int_equal(vibid_lsq_add_rows(first, 1, x, y, NULL), VIBID_OK);
                if (k == N1 - 1) {
                    double th0[10], P0[25];
                    assert_int_equal(vibid_lsq_solve(first, th0, NULL), VIBID_OK);
                    assert_int_equal(vibid_lsq_covariance(first, P0, NULL), VIBID_OK);
                    assert_int_equal(vibid_rls_set_prior(rls, th0, P0), VIBID_OK);
                }
            } else {
                assert_int_equal(vibid_rls_update(rls, x, y), VIBID_OK);
            }
        }
        double th_rls[10], th_ls[10], P_rls[25], P_ls[25];
        assert_int_equal(vibid_rls_theta(rls, th_rls), VIBID_OK);
        assert_int_equal(vibid_rls_covariance(rls, P_rls), VIBID_OK);
        assert_int_equal(vibid_lsq_solve(all, th_ls, NULL), VIBID_OK);
        assert_int_equal(vibid_lsq_covariance(all, P_ls, NULL), VIBID_OK);
        assert_true(rls_check_rel_diff(th_rls, th_ls, p * q) < 1e-9);
        assert_true(rls_check_rel_diff(P_rls, P_ls, p * p) < 1e-9);
        vibid_lsq_destroy(first);
        vibid_lsq_destroy(all);
        vibid_rls_destroy(rls);
    }
}

/* reset returns exactly (bit for bit) to the state right after set_prior, and without a
 * prior to Theta = 0, P = alpha^-1 I. */
static void test_reset_returns_to_prior(void **state) {
    (void)state;
    const double theta0[3] = {1.0, -2.0, 0.5};
    const double P0[9] = {2.0, 0.3, 0.1, 0.3, 1.0, -0.2, 0.1, -0.2, 0.5};
    for (int f = 0; f < 2; ++f) {
        vibid_rls *rls = make(3, 1, 1, forms[f], 0.99, 0.25);
        rls_snapshot fresh, start, after;
        rls_snapshot_take(&fresh, rls, 3, 1);
        for (int i = 0; i < 9; ++i) assert_true(fresh.P[i] == (i % 4 == 0 ? 4.0 : 0.0));
        for (int i = 0; i < 3; ++i) assert_true(fresh.theta[i] == 0.0);

        assert_int_equal(vibid_rls_set_prior(rls, theta0, P0), VIBID_OK);
        rls_snapshot_take(&start, rls, 3, 1);
        assert_true(memcmp(start.theta, theta0, sizeof theta0) == 0);
        /* Bierman stores P0 as U D U^T: equal to P0 up to rounding of the factorisation. */
        assert_true(rls_check_rel_diff(start.P, P0, 9) < 1e-15 * 8);

        test_rng rng;
        test_rng_seed(&rng, 3);
        for (int k = 0; k < 50; ++k) {
            double x[3], y = test_rng_normal(&rng);
            test_rng_fill_normal(&rng, x, 3, 1.0);
            assert_int_equal(vibid_rls_update(rls, x, &y), VIBID_OK);
        }
        assert_int_equal(vibid_rls_set_adaptation(rls, 0), VIBID_OK);
        assert_int_equal(vibid_rls_reset(rls), VIBID_OK);
        rls_snapshot_take(&after, rls, 3, 1);
        assert_true(rls_snapshot_equal(&start, &after));
        rls_snapshot_free(&after);

        /* reset re-enables adaptation: the next update moves Theta. */
        double x[3] = {1.0, 1.0, 1.0}, y = 10.0;
        assert_int_equal(vibid_rls_update(rls, x, &y), VIBID_OK);
        rls_snapshot_take(&after, rls, 3, 1);
        assert_true(memcmp(after.theta, start.theta, sizeof theta0) != 0);
        rls_snapshot_free(&after);

        /* set_prior(NULL, NULL) goes back to the alpha prior. */
        assert_int_equal(vibid_rls_set_prior(rls, NULL, NULL), VIBID_OK);
        rls_snapshot_take(&after, rls, 3, 1);
        assert_true(rls_snapshot_equal(&fresh, &after));
        rls_snapshot_free(&after);
        rls_snapshot_free(&fresh);
        rls_snapshot_free(&start);
        vibid_rls_destroy(rls);
    }
}

/* Frozen adaptation: Theta and P stay bit-identical, only the residual statistics move
 * (a-priori errors at the frozen estimate). */
static void test_adaptation_disabled(void **state) {
    (void)state;
    for (int f = 0; f < 2; ++f) {
        vibid_rls *rls = make(2, 1, 1, forms[f], 0.9, 1e-3);
        test_rng rng;
        test_rng_seed(&rng, 5);
        double x[2], y;
        for (int k = 0; k < 20; ++k) {
            test_rng_fill_normal(&rng, x, 2, 1.0);
            y = 3.0 * x[0] - x[1];
            assert_int_equal(vibid_rls_update(rls, x, &y), VIBID_OK);
        }
        rls_snapshot before, after;
        rls_snapshot_take(&before, rls, 2, 1);
        assert_int_equal(vibid_rls_set_adaptation(rls, 0), VIBID_OK);
        for (int k = 0; k < 20; ++k) {
            test_rng_fill_normal(&rng, x, 2, 1.0);
            y = -5.0 * x[0] + x[1]; /* a different system: would move Theta a lot */
            assert_int_equal(vibid_rls_update(rls, x, &y), VIBID_OK);
        }
        rls_snapshot_take(&after, rls, 2, 1);
        assert_true(memcmp(before.theta, after.theta, 2 * sizeof(double)) == 0);
        assert_true(memcmp(before.P, after.P, 4 * sizeof(double)) == 0);
        assert_true(after.stats.n_samples == 40);
        /* n_eff keeps forgetting with gamma: 0.9^20 n_eff + sum 0.9^i. */
        assert_true(after.stats.n_eff > before.stats.n_eff);
        /* The big errors at the frozen estimate show in the residual variance. */
        assert_int_equal(after.sigma_status, VIBID_OK);
        assert_true(after.sigma[0] > 10.0);

        assert_int_equal(vibid_rls_set_adaptation(rls, 1), VIBID_OK);
        assert_int_equal(vibid_rls_update(rls, x, &y), VIBID_OK);
        double th[2];
        assert_int_equal(vibid_rls_theta(rls, th), VIBID_OK);
        assert_true(memcmp(before.theta, th, sizeof th) != 0);
        rls_snapshot_free(&before);
        rls_snapshot_free(&after);
        vibid_rls_destroy(rls);
    }
}

/* predict is x^T Theta for every equation and output. Exact: 2 products and a sum. */
static void test_predict(void **state) {
    (void)state;
    vibid_rls *rls = make(2, 2, 2, VIBID_RLS_FORM_BIERMAN_UD, 1.0, 1.0);
    const double theta0[4] = {1.0, 2.0, -1.0, 0.5};
    assert_int_equal(vibid_rls_set_prior(rls, theta0, NULL), VIBID_OK);
    const double x[4] = {1.0, 1.0, 2.0, -1.0}; /* equation 0: (1, 1), equation 1: (2, -1) */
    double y[4];
    assert_int_equal(vibid_rls_predict(rls, x, y), VIBID_OK);
    assert_true(y[0] == 3.0 && y[1] == 0.0 && y[2] == -0.5 && y[3] == -2.5);
    vibid_rls_destroy(rls);
}

static void expect_error_mentions(const char *what) {
    const char *msg = vibid_last_error();
    if (!strstr(msg, what)) fail_msg("last error \"%s\" does not mention \"%s\"", msg, what);
}

static void expect_create_fails(const vibid_rls_config *cfg, const char *what) {
    assert_null(vibid_rls_create(cfg));
    expect_error_mentions(what);
}

static void test_create_rejects_nonsense(void **state) {
    (void)state;
    vibid_rls_config cfg;
    assert_null(vibid_rls_create(NULL));
    expect_error_mentions("cfg");
#define BAD(field, value, what)            \
    do {                                   \
        vibid_rls_config_init(&cfg, 4, 1); \
        cfg.field = value;                 \
        expect_create_fails(&cfg, what);   \
    } while (0)
    BAD(n_params, 0, "n_params = 0");
    BAD(n_params, 1025, "n_params = 1025");
    BAD(n_outputs, 0, "n_outputs = 0");
    BAD(n_equations, 0, "n_equations = 0");
    BAD(forgetting, 0.0, "forgetting = 0");
    BAD(forgetting, 1.2, "forgetting = 1.2 outside (0, 1]");
    BAD(forgetting, NAN, "forgetting = nan");
    BAD(alpha, 0.0, "alpha = 0");
    BAD(alpha, -1.0, "alpha = -1");
    BAD(alpha, INFINITY, "alpha = inf");
    BAD(alpha, 1e-320, "alpha = "); /* 1 / alpha overflows */
    BAD(form, (vibid_rls_form)7, "form = 7");
    BAD(windup, (vibid_rls_windup)3, "windup = 3");
#undef BAD
    vibid_rls_config_init(&cfg, 4, 1);
    cfg.windup = VIBID_RLS_WINDUP_TRACE_BOUND;
    cfg.trace_max = 0.0;
    expect_create_fails(&cfg, "trace_max = 0");
    /* trace_max is only checked when it is used. */
    cfg.windup = VIBID_RLS_WINDUP_NONE;
    vibid_rls *rls = vibid_rls_create(&cfg);
    assert_non_null(rls);
    vibid_rls_destroy(rls);
    vibid_rls_destroy(NULL);
}

/* An estimator with some history, so that "unchanged" is a non-trivial statement. */
static vibid_rls *seasoned(vibid_rls_form form, size_t m) {
    vibid_rls *rls = make(3, 2, m, form, 0.98, 1e-2);
    test_rng rng;
    test_rng_seed(&rng, 11);
    double x[9], y[6];
    for (int k = 0; k < 30; ++k) {
        test_rng_fill_normal(&rng, x, 3 * m, 1.0);
        test_rng_fill_normal(&rng, y, 2 * m, 1.0);
        assert_int_equal(vibid_rls_update(rls, x, y), VIBID_OK);
    }
    return rls;
}

/* Runs call (an expression returning vibid_status) and checks status, message and
 * that the estimator is bit-identical afterwards. The snapshot after the call is taken
 * only once the message has been checked (a snapshot may overwrite it). */
#define EXPECT_REJECTED(rls, call, status, what)          \
    do {                                                  \
        rls_snapshot before_, after_;                     \
        rls_snapshot_take(&before_, rls, 3, 2);           \
        assert_int_equal((call), (status));               \
        expect_error_mentions(what);                      \
        rls_snapshot_take(&after_, rls, 3, 2);            \
        assert_true(rls_snapshot_equal(&before_, &after_)); \
        rls_snapshot_free(&before_);                      \
        rls_snapshot_free(&after_);                       \
    } while (0)

static void test_bad_update_leaves_state(void **state) {
    (void)state;
    for (int f = 0; f < 2; ++f) {
        for (size_t m = 1; m <= 3; m += 2) {
            vibid_rls *rls = seasoned(forms[f], m);
            double x[9] = {1, 2, 3, 4, 5, 6, 7, 8, 9}, y[6] = {1, 2, 3, 4, 5, 6};
            EXPECT_REJECTED(rls, vibid_rls_update(NULL, x, y), VIBID_E_NULL_ARGUMENT, "rls is NULL");
            EXPECT_REJECTED(rls, vibid_rls_update(rls, NULL, y), VIBID_E_NULL_ARGUMENT, "x is NULL");
            EXPECT_REJECTED(rls, vibid_rls_update(rls, x, NULL), VIBID_E_NULL_ARGUMENT, "y is NULL");
            /* The message starts with the entry point's name. */
            assert_true(strncmp(vibid_last_error(), "vibid_rls_update: y is NULL", 27) == 0);
            /* The last element of each array: validation covers all of it. */
            x[3 * m - 1] = NAN;
            EXPECT_REJECTED(rls, vibid_rls_update(rls, x, y), VIBID_E_NONFINITE, "x[");
            x[3 * m - 1] = 1.0;
            y[2 * m - 1] = -INFINITY;
            EXPECT_REJECTED(rls, vibid_rls_update(rls, x, y), VIBID_E_NONFINITE, "y[");
            y[2 * m - 1] = 1.0;
            /* Finite but so large that x^T P x overflows: a breakdown detected mid-update. */
            x[0] = 1e200;
            EXPECT_REJECTED(rls, vibid_rls_update(rls, x, y), VIBID_E_NUMERICAL, "estimator unchanged");
            x[0] = 1.0;
            /* Frozen adaptation: the residual statistics overflow instead. */
            assert_int_equal(vibid_rls_set_adaptation(rls, 0), VIBID_OK);
            y[0] = 1e200;
            EXPECT_REJECTED(rls, vibid_rls_update(rls, x, y), VIBID_E_NUMERICAL, "estimator unchanged");
            vibid_rls_destroy(rls);
        }
    }
}

/* Breakdown in the middle of a long run: without a wind-up guard and with no
 * excitation, forgetting 0.5 doubles P per sample; after ~1000 samples P would
 * overflow. That update is refused and the state stays the last finite one. */
static void test_windup_overflow_refused(void **state) {
    (void)state;
    for (int f = 0; f < 2; ++f) {
        vibid_rls *rls = make(3, 2, 1, forms[f], 0.5, 1.0);
        const double x[3] = {0, 0, 0}, y[2] = {0, 0};
        int k = 0;
        vibid_status s = VIBID_OK;
        while (k < 2000 && (s = vibid_rls_update(rls, x, y)) == VIBID_OK) ++k;
        assert_int_equal(s, VIBID_E_NUMERICAL);
        assert_true(k > 1000 && k < 1030); /* 3 * 2^k overflows at k = 1023 */
        vibid_rls_stats st;
        assert_int_equal(vibid_rls_get_stats(rls, &st), VIBID_OK);
        assert_true(isfinite(st.trace_p) && st.trace_p > 1e307);
        assert_int_equal(st.n_samples, k);
        EXPECT_REJECTED(rls, vibid_rls_update(rls, x, y), VIBID_E_NUMERICAL, "estimator unchanged");
        vibid_rls_destroy(rls);
    }
}

static void test_bad_prior_and_equation_covariance(void **state) {
    (void)state;
    for (int f = 0; f < 2; ++f) {
        vibid_rls *rls = seasoned(forms[f], 3);
        double theta0[6] = {0}, P0[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
        EXPECT_REJECTED(rls, vibid_rls_set_prior(NULL, theta0, P0), VIBID_E_NULL_ARGUMENT, "rls is NULL");
        theta0[5] = NAN;
        EXPECT_REJECTED(rls, vibid_rls_set_prior(rls, theta0, P0), VIBID_E_NONFINITE, "theta0[5]");
        theta0[5] = 0.0;
        P0[8] = INFINITY;
        EXPECT_REJECTED(rls, vibid_rls_set_prior(rls, theta0, P0), VIBID_E_NONFINITE, "P0(2, 2)");
        P0[8] = 1.0;
        P0[3] = 0.5; /* P0(0, 1) = 0.5 but P0(1, 0) = 0 */
        EXPECT_REJECTED(rls, vibid_rls_set_prior(rls, theta0, P0), VIBID_E_OUT_OF_RANGE, "P0 is not symmetric");
        /* Symmetric, indefinite (eigenvalues 3 and -1 in the leading block). */
        P0[1] = P0[3] = 2.0;
        EXPECT_REJECTED(rls, vibid_rls_set_prior(rls, theta0, P0), VIBID_E_NUMERICAL,
                        "P0 is not positive definite");
        /* Semidefinite: a zero variance. */
        const double Psd[9] = {1, 0, 0, 0, 0, 0, 0, 0, 1};
        EXPECT_REJECTED(rls, vibid_rls_set_prior(rls, NULL, Psd), VIBID_E_NUMERICAL,
                        "P0 is not positive definite");

        double S[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
        EXPECT_REJECTED(rls, vibid_rls_set_equation_covariance(NULL, S), VIBID_E_NULL_ARGUMENT, "rls is NULL");
        S[4] = NAN;
        EXPECT_REJECTED(rls, vibid_rls_set_equation_covariance(rls, S), VIBID_E_NONFINITE, "Sigma(1, 1)");
        S[4] = -1.0;
        EXPECT_REJECTED(rls, vibid_rls_set_equation_covariance(rls, S), VIBID_E_NUMERICAL,
                        "Sigma is not positive definite");
        S[4] = 1.0;
        S[7] = 0.3;
        EXPECT_REJECTED(rls, vibid_rls_set_equation_covariance(rls, S), VIBID_E_OUT_OF_RANGE,
                        "Sigma is not symmetric");
        vibid_rls_destroy(rls);
    }
}

static void test_getters(void **state) {
    (void)state;
    vibid_rls *rls = make(3, 2, 1, VIBID_RLS_FORM_BIERMAN_UD, 1.0, 1.0);
    double buf[9], x[3] = {1, 2, 3};
    vibid_rls_stats st;
    assert_int_equal(vibid_rls_theta(rls, NULL), VIBID_E_NULL_ARGUMENT);
    expect_error_mentions("theta is NULL");
    assert_int_equal(vibid_rls_covariance(rls, NULL), VIBID_E_NULL_ARGUMENT);
    expect_error_mentions("P is NULL");
    assert_int_equal(vibid_rls_stderr(rls, NULL), VIBID_E_NULL_ARGUMENT);
    expect_error_mentions("stderr_out is NULL");
    assert_int_equal(vibid_rls_residual_covariance(rls, NULL), VIBID_E_NULL_ARGUMENT);
    expect_error_mentions("Sigma_e is NULL");
    assert_int_equal(vibid_rls_get_stats(rls, NULL), VIBID_E_NULL_ARGUMENT);
    expect_error_mentions("stats is NULL");
    assert_int_equal(vibid_rls_predict(rls, x, NULL), VIBID_E_NULL_ARGUMENT);
    expect_error_mentions("y is NULL");
    x[2] = NAN;
    assert_int_equal(vibid_rls_predict(rls, x, buf), VIBID_E_NONFINITE);
    expect_error_mentions("x[2]");
    assert_int_equal(vibid_rls_theta(NULL, buf), VIBID_E_NULL_ARGUMENT);
    assert_int_equal(vibid_rls_reset(NULL), VIBID_E_NULL_ARGUMENT);
    assert_int_equal(vibid_rls_set_adaptation(NULL, 1), VIBID_E_NULL_ARGUMENT);
    assert_int_equal(vibid_rls_get_stats(NULL, &st), VIBID_E_NULL_ARGUMENT);
    /* No data yet: n_eff = 0 <= p. */
    assert_int_equal(vibid_rls_residual_covariance(rls, buf), VIBID_E_INSUFFICIENT_DATA);
    expect_error_mentions("n_eff = 0");
    assert_int_equal(vibid_rls_stderr(rls, buf), VIBID_E_INSUFFICIENT_DATA);
    vibid_rls_destroy(rls);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_matches_batch_single_equation),
        cmocka_unit_test(test_matches_batch_multi_equation),
        cmocka_unit_test(test_matches_gauss_markov_with_equation_covariance),
        cmocka_unit_test(test_forgetting_hand_case),
        cmocka_unit_test(test_forgetting_tracks_step),
        cmocka_unit_test(test_prior_from_batch_start),
        cmocka_unit_test(test_reset_returns_to_prior),
        cmocka_unit_test(test_adaptation_disabled),
        cmocka_unit_test(test_predict),
        cmocka_unit_test(test_create_rejects_nonsense),
        cmocka_unit_test(test_bad_update_leaves_state),
        cmocka_unit_test(test_windup_overflow_refused),
        cmocka_unit_test(test_bad_prior_and_equation_covariance),
        cmocka_unit_test(test_getters),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
