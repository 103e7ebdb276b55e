/* test_wls.c: weighted least squares and Gauss-Markov (vibid/lsq.h, (2.11)/(2.12)):
 * a hand-computed weighted fit, weights versus repeated rows, the full-covariance
 * path against diagonal weights and against explicit whitening, a Monte Carlo check
 * of the weighted standard errors, and the rejection of bad covariances. */
/* cmocka.h needs these first. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include <math.h>
#include <string.h>

#include <vibid/lsq.h>

#include "rls_check.h" /* rls_check_rel_diff: max |a - b| / max |b| */
#include "test_assert.h"
#include "test_rng.h"


/* ---- hand-computed WLS ----
 * Line y = c0 + c1 t through (t, y, w) = (0, 1, 1), (1, 3, 2), (2, 4, 1), plus a
 * fourth row (3, 100, 0): an outlier with weight 0, which must have no effect.
 *   X^T S X = [sum w, sum w t; sum w t, sum w t^2] = [4 4; 4 6], det 8,
 *   (X^T S X)^-1 = [6 -4; -4 4] / 8 = [0.75 -0.5; -0.5 0.5],
 *   X^T S y = [sum w y, sum w t y] = [1 + 6 + 4, 0 + 6 + 8] = [11, 14],
 *   c0 = (6 * 11 - 4 * 14) / 8 = 1.25,  c1 = (-4 * 11 + 4 * 14) / 8 = 1.5.
 * Residuals 1 - 1.25 = -0.25, 3 - 2.75 = 0.25, 4 - 4.25 = -0.25; weighted sum of
 * squares 0.0625 (1 + 2 + 1) = 0.25; residual variance 0.25 / (3 - 2) = 0.25.
 * Standard errors sqrt(0.75 * 0.25) = sqrt(3)/4 and sqrt(0.5 * 0.25) = sqrt(2)/4. */
static void test_wls_hand_computed(void **state) {
    (void)state;
    const double X[] = {1, 1, 1, 1, 0, 1, 2, 3};
    const double Y[] = {1, 3, 4, 100};
    const double w[] = {1, 2, 1, 0};
    double est[2], pc[4], rc[1], se[2];
    vibid_lsq *lsq = vibid_lsq_create(2, 1);
    assert_int_equal(vibid_lsq_add_rows(lsq, 4, X, Y, w), VIBID_OK);
    vibid_lsq_info info;
    assert_int_equal(vibid_lsq_solve(lsq, est, &info), VIBID_OK);
    assert_int_equal(info.n_rows, 3); /* the zero-weight row is not counted */
    ASSERT_NEAR(info.sum_weights, 4.0, 0.0);
    assert_int_equal(vibid_lsq_covariance(lsq, pc, rc), VIBID_OK);
    assert_int_equal(vibid_lsq_stderr(lsq, se), VIBID_OK);
    /* Order-1 numbers from 3 rows: a few eps. */
    const double tol = 1e-14;
    ASSERT_NEAR(est[0], 1.25, tol);
    ASSERT_NEAR(est[1], 1.5, tol);
    ASSERT_NEAR(pc[0], 0.75, tol);
    ASSERT_NEAR(pc[1], -0.5, tol);
    ASSERT_NEAR(pc[3], 0.5, tol);
    ASSERT_NEAR(rc[0], 0.25, tol);
    ASSERT_NEAR(se[0], sqrt(3.0) / 4.0, tol);
    ASSERT_NEAR(se[1], sqrt(2.0) / 4.0, tol);
    vibid_lsq_destroy(lsq);
}

/* An integer weight w is the same as adding the row w times. */
static void test_weight_equals_repeated_rows(void **state) {
    (void)state;
    enum { N = 20, P = 3, Q = 2 };
    test_rng rng;
    test_rng_seed(&rng, 11);
    double X[N * P], Y[N * Q], w[N], a[P * Q], b[P * Q];
    for (size_t i = 0; i < N * P; ++i) X[i] = test_rng_normal(&rng);
    for (size_t i = 0; i < N * Q; ++i) Y[i] = test_rng_normal(&rng);
    vibid_lsq *weighted = vibid_lsq_create(P, Q), *repeated = vibid_lsq_create(P, Q);
    for (size_t k = 0; k < N; ++k) w[k] = (double)(1 + k % 3);
    assert_int_equal(vibid_lsq_add_rows(weighted, N, X, Y, w), VIBID_OK);
    for (size_t k = 0; k < N; ++k) {
        double x[P], y[Q];
        for (size_t i = 0; i < P; ++i) x[i] = X[k + i * N];
        for (size_t j = 0; j < Q; ++j) y[j] = Y[k + j * N];
        for (size_t r = 0; r < (size_t)w[k]; ++r)
            assert_int_equal(vibid_lsq_add_rows(repeated, 1, x, y, NULL), VIBID_OK);
    }
    assert_int_equal(vibid_lsq_solve(weighted, a, NULL), VIBID_OK);
    assert_int_equal(vibid_lsq_solve(repeated, b, NULL), VIBID_OK);
    /* Same minimiser, different rotation order: agreement to rounding (cond ~ 3). */
    assert_true(rls_check_rel_diff(a, b, P * Q) < 1e-13);
    vibid_lsq_destroy(weighted);
    vibid_lsq_destroy(repeated);
}

/* Lower Cholesky factor of an SPD n x n column-major matrix (test reference). */
static void cholesky(const double *S, double *L, size_t n) {
    memset(L, 0, n * n * sizeof *L);
    for (size_t j = 0; j < n; ++j) {
        double d = S[j + j * n];
        for (size_t k = 0; k < j; ++k) d -= L[j + k * n] * L[j + k * n];
        assert_true(d > 0.0);
        L[j + j * n] = sqrt(d);
        for (size_t i = j + 1; i < n; ++i) {
            double s = S[i + j * n];
            for (size_t k = 0; k < j; ++k) s -= L[i + k * n] * L[j + k * n];
            L[i + j * n] = s / L[j + j * n];
        }
    }
}

/* Solves L Z = B in place for the m columns of B (n x m). */
static void forward_solve(const double *L, double *B, size_t n, size_t m) {
    for (size_t c = 0; c < m; ++c)
        for (size_t i = 0; i < n; ++i) {
            double s = B[i + c * n];
            for (size_t k = 0; k < i; ++k) s -= L[i + k * n] * B[k + c * n];
            B[i + c * n] = s / L[i + i * n];
        }
}

/* Gauss-Markov with a diagonal Sigma is WLS with weights 1 / Sigma_kk. */
static void test_gauss_markov_diagonal_is_wls(void **state) {
    (void)state;
    enum { N = 12, P = 3, Q = 2 };
    test_rng rng;
    test_rng_seed(&rng, 12);
    double X[N * P], Y[N * Q], w[N], S[N * N] = {0}, a[P * Q], b[P * Q], ra[Q * Q], rb[Q * Q];
    for (size_t i = 0; i < N * P; ++i) X[i] = test_rng_normal(&rng);
    for (size_t i = 0; i < N * Q; ++i) Y[i] = test_rng_normal(&rng);
    for (size_t k = 0; k < N; ++k) {
        S[k + k * N] = 0.1 + 10.0 * test_rng_uniform(&rng);
        w[k] = 1.0 / S[k + k * N];
    }
    vibid_lsq *gm = vibid_lsq_create(P, Q), *wls = vibid_lsq_create(P, Q);
    assert_int_equal(vibid_lsq_add_correlated(gm, N, X, Y, S), VIBID_OK);
    assert_int_equal(vibid_lsq_add_rows(wls, N, X, Y, w), VIBID_OK);
    assert_int_equal(vibid_lsq_solve(gm, a, NULL), VIBID_OK);
    assert_int_equal(vibid_lsq_solve(wls, b, NULL), VIBID_OK);
    assert_int_equal(vibid_lsq_covariance(gm, NULL, ra), VIBID_OK);
    assert_int_equal(vibid_lsq_covariance(wls, NULL, rb), VIBID_OK);
    /* Row k scaled by 1/sqrt(S_kk) either way; only rounding differs (cond ~ 10). */
    assert_true(rls_check_rel_diff(a, b, P * Q) < 1e-13);
    assert_true(rls_check_rel_diff(ra, rb, Q * Q) < 1e-13);
    vibid_lsq_destroy(gm);
    vibid_lsq_destroy(wls);
}

/* With a full Sigma, add_correlated equals whitening by hand (L^-1 X, L^-1 Y) and
 * plain add_rows; two blocks of 8 rows with different Sigma. */
static void test_gauss_markov_full_is_whitening(void **state) {
    (void)state;
    enum { N = 8, P = 3, Q = 2, BLOCKS = 2 };
    test_rng rng;
    test_rng_seed(&rng, 13);
    vibid_lsq *gm = vibid_lsq_create(P, Q), *ref = vibid_lsq_create(P, Q);
    for (int blk = 0; blk < BLOCKS; ++blk) {
        double X[N * P], Y[N * Q], A[N * N], S[N * N], L[N * N];
        for (size_t i = 0; i < N * P; ++i) X[i] = test_rng_normal(&rng);
        for (size_t i = 0; i < N * Q; ++i) Y[i] = test_rng_normal(&rng);
        /* S = A A^T + 0.5 I: symmetric positive definite with strong correlations. */
        for (size_t i = 0; i < N * N; ++i) A[i] = test_rng_normal(&rng);
        for (size_t i = 0; i < N; ++i)
            for (size_t j = 0; j < N; ++j) {
                double s = i == j ? 0.5 : 0.0;
                for (size_t k = 0; k < N; ++k) s += A[i + k * N] * A[j + k * N];
                S[i + j * N] = s;
            }
        assert_int_equal(vibid_lsq_add_correlated(gm, N, X, Y, S), VIBID_OK);
        cholesky(S, L, N);
        forward_solve(L, X, N, P);
        forward_solve(L, Y, N, Q);
        assert_int_equal(vibid_lsq_add_rows(ref, N, X, Y, NULL), VIBID_OK);
    }
    double a[P * Q], b[P * Q], ra[Q * Q], rb[Q * Q];
    vibid_lsq_info info;
    assert_int_equal(vibid_lsq_solve(gm, a, &info), VIBID_OK);
    assert_int_equal(info.n_rows, N * BLOCKS);
    assert_int_equal(vibid_lsq_solve(ref, b, NULL), VIBID_OK);
    assert_int_equal(vibid_lsq_covariance(gm, NULL, ra), VIBID_OK);
    assert_int_equal(vibid_lsq_covariance(ref, NULL, rb), VIBID_OK);
    /* Two Cholesky implementations of an SPD matrix with cond ~ 1e3 agree to ~1e-13;
     * the fit is well conditioned, so 1e-11 is a comfortable bound. */
    assert_true(rls_check_rel_diff(a, b, P * Q) < 1e-11);
    assert_true(rls_check_rel_diff(ra, rb, Q * Q) < 1e-11);
    vibid_lsq_destroy(gm);
    vibid_lsq_destroy(ref);
}

/* ---- Monte Carlo: weighted standard errors ----
 * Heteroscedastic noise: row k has standard deviation sigma_k in [0.2, 5]; weights
 * w_k = 1 / sigma_k^2 make the weighted residual variance 1, and the reported
 * standard errors must match the empirical spread over R = 400 runs. The sample sd of
 * 400 values has relative sd 1/sqrt(798) = 3.5 %, so 10 % is a ~3-sigma band. */
static void test_weighted_standard_errors(void **state) {
    (void)state;
    enum { N = 30, P = 2, R = 400 };
    test_rng rng;
    test_rng_seed(&rng, 14);
    double X[N * P], Y[N], w[N], sigma[N], est[P], se[P], rc;
    const double T[P] = {0.7, -1.3};
    for (size_t i = 0; i < N * P; ++i) X[i] = test_rng_normal(&rng);
    for (size_t k = 0; k < N; ++k) {
        sigma[k] = 0.2 + 4.8 * test_rng_uniform(&rng);
        w[k] = 1.0 / (sigma[k] * sigma[k]);
    }
    double sum[P] = {0}, sum2[P] = {0}, se2[P] = {0}, rc_mean = 0.0;
    vibid_lsq *lsq = vibid_lsq_create(P, 1);
    for (int r = 0; r < R; ++r) {
        for (size_t k = 0; k < N; ++k)
            Y[k] = X[k] * T[0] + X[k + N] * T[1] + sigma[k] * test_rng_normal(&rng);
        vibid_lsq_reset(lsq);
        assert_int_equal(vibid_lsq_add_rows(lsq, N, X, Y, w), VIBID_OK);
        assert_int_equal(vibid_lsq_solve(lsq, est, NULL), VIBID_OK);
        assert_int_equal(vibid_lsq_stderr(lsq, se), VIBID_OK);
        assert_int_equal(vibid_lsq_covariance(lsq, NULL, &rc), VIBID_OK);
        for (size_t i = 0; i < P; ++i) {
            sum[i] += est[i];
            sum2[i] += est[i] * est[i];
            se2[i] += se[i] * se[i];
        }
        rc_mean += rc / R;
    }
    for (size_t i = 0; i < P; ++i) {
        const double mean = sum[i] / R;
        const double sd = sqrt((sum2[i] - R * mean * mean) / (R - 1));
        const double ratio = sd / sqrt(se2[i] / R);
        print_message("  WLS parameter %zu: empirical sd / rms stderr = %.3f\n", i, ratio);
        ASSERT_NEAR(ratio, 1.0, 0.10);
    }
    /* Unit weighted variance; relative sd of the mean sqrt(2/28)/sqrt(400) = 1.3 %. */
    ASSERT_NEAR(rc_mean, 1.0, 0.05);
    vibid_lsq_destroy(lsq);
}

/* ---- bad covariances and other bad input; state untouched ---- */
static void test_add_correlated_rejects(void **state) {
    (void)state;
    enum { P = 2 };
    const double X[] = {1, 0, 1, 0, 1, 1};
    const double Y[] = {1, 2, 3};
    const double I3[] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    vibid_lsq *lsq = vibid_lsq_create(P, 1);
    assert_int_equal(vibid_lsq_add_correlated(lsq, 3, X, Y, I3), VIBID_OK);
    double before[P], after[P];
    assert_int_equal(vibid_lsq_solve(lsq, before, NULL), VIBID_OK);

    /* Symmetric but indefinite: eigenvalues 3, -1 (and 1). */
    const double indefinite[] = {1, 2, 0, 2, 1, 0, 0, 0, 1};
    assert_int_equal(vibid_lsq_add_correlated(lsq, 3, X, Y, indefinite), VIBID_E_NUMERICAL);
    ASSERT_MSG_CONTAINS("Sigma (3 x 3) is not positive definite");
    /* Singular (rank 1): positive semidefinite only. */
    const double singular[] = {1, 1, 1, 1, 1, 1, 1, 1, 1};
    assert_int_equal(vibid_lsq_add_correlated(lsq, 3, X, Y, singular), VIBID_E_NUMERICAL);
    ASSERT_MSG_CONTAINS("Sigma");
    const double zero_diag[] = {1, 0, 0, 0, 0, 0, 0, 0, 1};
    assert_int_equal(vibid_lsq_add_correlated(lsq, 3, X, Y, zero_diag), VIBID_E_NUMERICAL);
    ASSERT_MSG_CONTAINS("Sigma[4] (diagonal 1) = 0 is not positive");
    const double asym[] = {2, 0.5, 0, 0, 2, 0, 0, 0, 2};
    assert_int_equal(vibid_lsq_add_correlated(lsq, 3, X, Y, asym), VIBID_E_OUT_OF_RANGE);
    ASSERT_MSG_CONTAINS("Sigma is not symmetric");
    double nan_sigma[9];
    memcpy(nan_sigma, I3, sizeof I3);
    nan_sigma[5] = NAN;
    assert_int_equal(vibid_lsq_add_correlated(lsq, 3, X, Y, nan_sigma), VIBID_E_NONFINITE);
    ASSERT_MSG_CONTAINS("vibid_lsq_add_correlated: Sigma[5] (row 2, column 1) = nan");
    double Xbad[6];
    memcpy(Xbad, X, sizeof X);
    Xbad[3] = INFINITY;
    assert_int_equal(vibid_lsq_add_correlated(lsq, 3, Xbad, Y, I3), VIBID_E_NONFINITE);
    ASSERT_MSG_CONTAINS("X[3]");
    assert_int_equal(vibid_lsq_add_correlated(lsq, 3, X, Y, NULL), VIBID_E_NULL_ARGUMENT);
    ASSERT_MSG_CONTAINS("Sigma is NULL");
    assert_int_equal(vibid_lsq_add_correlated(lsq, 3, NULL, Y, I3), VIBID_E_NULL_ARGUMENT);
    ASSERT_MSG_CONTAINS("X is NULL");
    assert_int_equal(vibid_lsq_add_correlated(lsq, 3, X, NULL, I3), VIBID_E_NULL_ARGUMENT);
    ASSERT_MSG_CONTAINS("Y is NULL");
    assert_int_equal(vibid_lsq_add_correlated(NULL, 3, X, Y, I3), VIBID_E_NULL_ARGUMENT);
    ASSERT_MSG_CONTAINS("lsq is NULL");
    assert_int_equal(vibid_lsq_add_correlated(lsq, 0, X, Y, I3), VIBID_E_DIMENSION);
    ASSERT_MSG_CONTAINS("n_rows = 0");

    assert_int_equal(vibid_lsq_solve(lsq, after, NULL), VIBID_OK);
    assert_memory_equal(before, after, sizeof before); /* bit-identical */
    vibid_lsq_destroy(lsq);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_wls_hand_computed),
        cmocka_unit_test(test_weight_equals_repeated_rows),
        cmocka_unit_test(test_gauss_markov_diagonal_is_wls),
        cmocka_unit_test(test_gauss_markov_full_is_whitening),
        cmocka_unit_test(test_weighted_standard_errors),
        cmocka_unit_test(test_add_correlated_rejects),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
