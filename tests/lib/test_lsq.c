/* test_lsq.c: batch least squares (vibid/lsq.h): exact recovery, agreement with
 * independent references, bad scaling, rank deficiency and its null space,
 * uncertainty (residual covariance, standard errors) by Monte Carlo, and every
 * bad-input path with the state left untouched. */
/* cmocka.h needs these first. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <string.h>

#include <vibid/lsq.h>

#include "rls_check.h" /* rls_check_rel_diff: max |a - b| / max |b| */
#include "test_assert.h"
#include "test_rng.h"


/* Y = X Theta, column-major (N x p) (p x q). */
static void matmul(const double *X, const double *T, double *Y, size_t n, size_t p, size_t q) {
    for (size_t j = 0; j < q; ++j)
        for (size_t k = 0; k < n; ++k) {
            double s = 0.0;
            for (size_t i = 0; i < p; ++i) s += X[k + i * n] * T[i + j * p];
            Y[k + j * n] = s;
        }
}

/* Normal equations solved by Cholesky, written out here as an independent reference
 * (fine for a well-conditioned X, which is exactly why the library does not use it). */
static void normal_equations(const double *X, const double *Y, size_t n, size_t p, size_t q, double *theta) {
    double A[16 * 16], B[16 * 4];
    assert_true(p <= 16 && q <= 4);
    for (size_t i = 0; i < p; ++i) {
        for (size_t j = 0; j < p; ++j) {
            double s = 0.0;
            for (size_t k = 0; k < n; ++k) s += X[k + i * n] * X[k + j * n];
            A[i + j * p] = s;
        }
        for (size_t j = 0; j < q; ++j) {
            double s = 0.0;
            for (size_t k = 0; k < n; ++k) s += X[k + i * n] * Y[k + j * n];
            B[i + j * p] = s;
        }
    }
    /* A = L L^T in place (lower triangle). */
    for (size_t j = 0; j < p; ++j) {
        double d = A[j + j * p];
        for (size_t k = 0; k < j; ++k) d -= A[j + k * p] * A[j + k * p];
        assert_true(d > 0.0);
        A[j + j * p] = sqrt(d);
        for (size_t i = j + 1; i < p; ++i) {
            double s = A[i + j * p];
            for (size_t k = 0; k < j; ++k) s -= A[i + k * p] * A[j + k * p];
            A[i + j * p] = s / A[j + j * p];
        }
    }
    for (size_t c = 0; c < q; ++c) {
        double *b = B + c * p;
        for (size_t i = 0; i < p; ++i) { /* L z = b */
            for (size_t k = 0; k < i; ++k) b[i] -= A[i + k * p] * b[k];
            b[i] /= A[i + i * p];
        }
        for (size_t ii = p; ii-- > 0;) { /* L^T t = z */
            for (size_t k = ii + 1; k < p; ++k) b[ii] -= A[k + ii * p] * b[k];
            b[ii] /= A[ii + ii * p];
        }
        memcpy(theta + c * p, b, p * sizeof *b);
    }
}

/* ---- exact recovery, p x q with q > 1 ---- */
static void test_exact_system_recovers_theta(void **state) {
    (void)state;
    enum { N = 60, P = 5, Q = 3 };
    test_rng rng;
    test_rng_seed(&rng, 1);
    double X[N * P], T[P * Q], Y[N * Q], est[P * Q];
    test_rng_fill_normal(&rng, X, N * P, 1.0);
    test_rng_fill_normal(&rng, T, P * Q, 3.0);
    matmul(X, T, Y, N, P, Q);

    vibid_lsq *lsq = vibid_lsq_create(P, Q);
    assert_non_null(lsq);
    /* In two calls (rows 0..24 and 25..59), to exercise accumulation across calls. */
    double X1[25 * P], Y1[25 * Q], X2[35 * P], Y2[35 * Q];
    for (size_t i = 0; i < P; ++i) {
        memcpy(X1 + i * 25, X + i * N, 25 * sizeof(double));
        memcpy(X2 + i * 35, X + i * N + 25, 35 * sizeof(double));
    }
    for (size_t j = 0; j < Q; ++j) {
        memcpy(Y1 + j * 25, Y + j * N, 25 * sizeof(double));
        memcpy(Y2 + j * 35, Y + j * N + 25, 35 * sizeof(double));
    }
    assert_int_equal(vibid_lsq_add_rows(lsq, 25, X1, Y1, NULL), VIBID_OK);
    assert_int_equal(vibid_lsq_add_rows(lsq, 35, X2, Y2, NULL), VIBID_OK);
    vibid_lsq_info info;
    assert_int_equal(vibid_lsq_solve(lsq, est, &info), VIBID_OK);
    assert_int_equal(info.n_rows, N);
    assert_int_equal(info.rank, P);
    ASSERT_NEAR(info.sum_weights, (double)N, 0.0);
    /* Backward-stable QR on a random (cond ~ 3) 60 x 5 system: error ~ 10 eps. */
    double err = rls_check_rel_diff(est, T, P * Q);
    assert_true(err < 1e-12);

    /* Residual covariance of an exact system is zero up to rounding of Y (|Y| ~ 10). */
    double rc[Q * Q];
    assert_int_equal(vibid_lsq_covariance(lsq, NULL, rc), VIBID_OK);
    for (size_t i = 0; i < Q * Q; ++i) ASSERT_NEAR(rc[i], 0.0, 1e-24);
    vibid_lsq_destroy(lsq);
}

/* ---- independent reference: normal equations on a well-conditioned noisy case ---- */
static void test_matches_normal_equations(void **state) {
    (void)state;
    enum { N = 200, P = 6, Q = 2 };
    test_rng rng;
    test_rng_seed(&rng, 2);
    double X[N * P], T[P * Q], Y[N * Q], est[P * Q], ref[P * Q];
    test_rng_fill_normal(&rng, X, N * P, 1.0);
    test_rng_fill_normal(&rng, T, P * Q, 1.0);
    matmul(X, T, Y, N, P, Q);
    for (size_t i = 0; i < N * Q; ++i) Y[i] += 0.3 * test_rng_normal(&rng);
    normal_equations(X, Y, N, P, Q, ref);

    vibid_lsq *lsq = vibid_lsq_create(P, Q);
    assert_int_equal(vibid_lsq_add_rows(lsq, N, X, Y, NULL), VIBID_OK);
    assert_int_equal(vibid_lsq_solve(lsq, est, NULL), VIBID_OK);
    /* cond(X^T X) ~ 2 here, so the normal equations are accurate to ~1e-15 as well;
     * 1e-12 leaves room for summation order. */
    assert_true(rls_check_rel_diff(est, ref, P * Q) < 1e-12);
    vibid_lsq_destroy(lsq);
}

/* ---- hand-computed: straight line through (0,1), (1,3), (2,4) ----
 * x_k = [1, t_k]. Mean t = 1, mean y = 8/3; slope = sum (t-1)(y-8/3) / sum (t-1)^2
 * = (5/3 + 4/3) / 2 = 3/2; intercept = 8/3 - 3/2 = 7/6. Residuals -1/6, 1/3, -1/6,
 * sum of squares 1/6, residual variance (1/6) / (3 - 2) = 1/6.
 * X^T X = [3 3; 3 5], det 6, inverse [5/6 -1/2; -1/2 1/2].
 * Standard errors sqrt(5/6 * 1/6) = sqrt(5)/6 and sqrt(1/2 * 1/6) = 1/sqrt(12). */
static void test_hand_computed_line(void **state) {
    (void)state;
    const double X[] = {1, 1, 1, 0, 1, 2};
    const double Y[] = {1, 3, 4};
    double est[2], pc[4], rc[1], se[2];
    vibid_lsq *lsq = vibid_lsq_create(2, 1);
    assert_int_equal(vibid_lsq_add_rows(lsq, 3, X, Y, NULL), VIBID_OK);
    assert_int_equal(vibid_lsq_solve(lsq, est, NULL), VIBID_OK);
    assert_int_equal(vibid_lsq_covariance(lsq, pc, rc), VIBID_OK);
    assert_int_equal(vibid_lsq_stderr(lsq, se), VIBID_OK);
    /* Numbers of order 1 from 3 rows: a few eps. */
    const double tol = 1e-14;
    ASSERT_NEAR(est[0], 7.0 / 6.0, tol);
    ASSERT_NEAR(est[1], 1.5, tol);
    ASSERT_NEAR(rc[0], 1.0 / 6.0, tol);
    ASSERT_NEAR(pc[0], 5.0 / 6.0, tol);
    ASSERT_NEAR(pc[1], -0.5, tol);
    ASSERT_NEAR(pc[2], -0.5, tol);
    ASSERT_NEAR(pc[3], 0.5, tol);
    ASSERT_NEAR(se[0], sqrt(5.0) / 6.0, tol);
    ASSERT_NEAR(se[1], 1.0 / sqrt(12.0), tol);
    vibid_lsq_destroy(lsq);
}

/* ---- badly scaled columns: a stiffness of 1e6 beside a damping of 1 ---- */
static void test_badly_scaled_columns(void **state) {
    (void)state;
    enum { N = 100, P = 3, Q = 2 };
    test_rng rng;
    test_rng_seed(&rng, 3);
    const double scale[P] = {1e6, 1.0, 1e-3};
    double X[N * P], Y[N * Q], est[P * Q];
    /* Parameters scaled inversely, so every column contributes equally to Y. */
    const double T[P * Q] = {2e-6, -1.5, 4e3, 7e-6, 0.25, -1e3};
    for (size_t i = 0; i < P; ++i)
        for (size_t k = 0; k < N; ++k) X[k + i * N] = scale[i] * test_rng_normal(&rng);
    matmul(X, T, Y, N, P, Q);
    vibid_lsq *lsq = vibid_lsq_create(P, Q);
    assert_int_equal(vibid_lsq_add_rows(lsq, N, X, Y, NULL), VIBID_OK);
    vibid_lsq_info info;
    assert_int_equal(vibid_lsq_solve(lsq, est, &info), VIBID_OK);
    assert_int_equal(info.rank, P);
    /* Column scaling removes the 1e9 spread: the scaled rcond is that of a random
     * Gaussian 100 x 3 matrix, well above 0.1. */
    assert_true(info.rcond > 0.1);
    /* Each parameter relative to itself (not to the largest): QR is column-scaling
     * invariant, so each is good to ~1e-14; 1e-11 leaves margin. */
    for (size_t i = 0; i < P * Q; ++i) ASSERT_NEAR(est[i] / T[i], 1.0, 1e-11);
    vibid_lsq_destroy(lsq);
}

/* ---- rank deficiency: column 2 = 2 * column 0 ---- */
static void test_rank_deficient(void **state) {
    (void)state;
    enum { N = 40, P = 4, Q = 2 };
    test_rng rng;
    test_rng_seed(&rng, 4);
    double X[N * P], Y[N * Q];
    test_rng_fill_normal(&rng, X, N * P, 1.0);
    for (size_t k = 0; k < N; ++k) X[k + 2 * N] = 2.0 * X[k + 0 * N];
    test_rng_fill_normal(&rng, Y, N * Q, 1.0);
    vibid_lsq *lsq = vibid_lsq_create(P, Q);
    assert_int_equal(vibid_lsq_add_rows(lsq, N, X, Y, NULL), VIBID_OK);

    double theta[P * Q];
    for (size_t i = 0; i < P * Q; ++i) theta[i] = 12345.0 + (double)i;
    vibid_lsq_info info;
    memset(&info, 0, sizeof info);
    assert_int_equal(vibid_lsq_solve(lsq, theta, &info), VIBID_E_NOT_IDENTIFIABLE);
    ASSERT_MSG_CONTAINS("rank 3 of 4");
    assert_int_equal(info.rank, P - 1);
    assert_int_equal(info.n_rows, N);
    assert_true(info.rcond < 1e-14);
    for (size_t i = 0; i < P * Q; ++i) ASSERT_NEAR(theta[i], 12345.0 + (double)i, 0.0);

    /* X (2, 0, -1, 0)^T = 0: the null vector is (2, 0, -1, 0) / sqrt(5). The SVD gap
     * is O(1) after column scaling, so the vector is accurate to ~1e-15; 1e-12. */
    double basis[P * 2];
    size_t nv = 99;
    assert_int_equal(vibid_lsq_null_space(lsq, basis, 2, &nv), VIBID_OK);
    assert_int_equal(nv, 1);
    const double expect[P] = {2.0 / sqrt(5.0), 0.0, -1.0 / sqrt(5.0), 0.0};
    for (size_t i = 0; i < P; ++i) ASSERT_NEAR(basis[i], expect[i], 1e-12);
    /* Asking for the count only. */
    nv = 0;
    assert_int_equal(vibid_lsq_null_space(lsq, NULL, 0, &nv), VIBID_OK);
    assert_int_equal(nv, 1);

    /* Covariance and standard errors refuse as well. */
    double se[P * Q];
    assert_int_equal(vibid_lsq_stderr(lsq, se), VIBID_E_NOT_IDENTIFIABLE);
    vibid_lsq_destroy(lsq);
}

/* Collinearity between columns of very different scale (1e6 and 1) is still found,
 * and the null vector is given in the user's units. */
static void test_rank_deficient_scaled(void **state) {
    (void)state;
    enum { N = 30, P = 3 };
    test_rng rng;
    test_rng_seed(&rng, 5);
    double X[N * P], Y[N], theta[P];
    test_rng_fill_normal(&rng, X, N * P, 1.0);
    for (size_t k = 0; k < N; ++k) {
        X[k] *= 1e6;
        X[k + 1 * N] = -3e-6 * X[k]; /* column 1 = -3e-6 column 0 */
    }
    test_rng_fill_normal(&rng, Y, N, 1.0);
    vibid_lsq *lsq = vibid_lsq_create(P, 1);
    assert_int_equal(vibid_lsq_add_rows(lsq, N, X, Y, NULL), VIBID_OK);
    vibid_lsq_info info;
    assert_int_equal(vibid_lsq_solve(lsq, theta, &info), VIBID_E_NOT_IDENTIFIABLE);
    assert_int_equal(info.rank, 2);
    double v[P];
    size_t nv;
    assert_int_equal(vibid_lsq_null_space(lsq, v, 1, &nv), VIBID_OK);
    assert_int_equal(nv, 1);
    /* X (3e-6, 1, 0) = 0 -> normalised (3e-6, 1, 0) / |.|; relative accuracy as above. */
    const double nrm = sqrt(1.0 + 9e-12);
    ASSERT_NEAR(v[0], 3e-6 / nrm, 1e-15);
    ASSERT_NEAR(v[1], 1.0 / nrm, 1e-12);
    ASSERT_NEAR(v[2], 0.0, 1e-12);
    vibid_lsq_destroy(lsq);
}

/* Fewer rows than parameters is a rank question (rank = rows); no rows at all is
 * "insufficient data". */
static void test_too_few_rows(void **state) {
    (void)state;
    const double X[] = {1, 2, 3, 4, 5, 6}; /* 2 x 3 */
    const double Y[] = {1, 2};
    double theta[3];
    vibid_lsq_info info;
    vibid_lsq *lsq = vibid_lsq_create(3, 1);
    assert_int_equal(vibid_lsq_solve(lsq, theta, &info), VIBID_E_INSUFFICIENT_DATA);
    ASSERT_MSG_CONTAINS("no rows");
    size_t nv;
    assert_int_equal(vibid_lsq_null_space(lsq, NULL, 0, &nv), VIBID_E_INSUFFICIENT_DATA);
    assert_int_equal(vibid_lsq_add_rows(lsq, 2, X, Y, NULL), VIBID_OK);
    assert_int_equal(vibid_lsq_solve(lsq, theta, &info), VIBID_E_NOT_IDENTIFIABLE);
    assert_int_equal(info.rank, 2);
    assert_int_equal(vibid_lsq_null_space(lsq, NULL, 0, &nv), VIBID_OK);
    assert_int_equal(nv, 1);
    vibid_lsq_destroy(lsq);

    /* Exactly p rows: solvable, but no residual covariance (n_rows - p = 0). */
    lsq = vibid_lsq_create(2, 1);
    const double X2[] = {1, 0, 0, 1};
    assert_int_equal(vibid_lsq_add_rows(lsq, 2, X2, Y, NULL), VIBID_OK);
    assert_int_equal(vibid_lsq_solve(lsq, theta, NULL), VIBID_OK);
    double pc[4], rc[1];
    assert_int_equal(vibid_lsq_covariance(lsq, pc, NULL), VIBID_OK);
    assert_int_equal(vibid_lsq_covariance(lsq, pc, rc), VIBID_E_INSUFFICIENT_DATA);
    ASSERT_MSG_CONTAINS("n_rows = 2, p = 2");
    assert_int_equal(vibid_lsq_stderr(lsq, pc), VIBID_E_INSUFFICIENT_DATA);
    vibid_lsq_destroy(lsq);
}

/* ---- Monte Carlo: standard errors and residual covariance ----
 * Fixed X (N = 40, p = 3), two outputs with correlated noise of covariance
 * Sv = [0.25 0.3; 0.3 4] (std 0.5 and 2, correlation 0.3). Over R = 500 runs the
 * empirical standard deviation of each estimate is compared with the root mean square
 * of the reported standard errors. The sample standard deviation of 500 normal values
 * has relative standard deviation 1/sqrt(2 * 499) = 3.2 %, so a 10 % band is a
 * 3-sigma test; the RMS stderr itself fluctuates far less (each is from 37 dof, averaged
 * over 500). The mean residual covariance is unbiased; each entry has relative sd
 * ~ sqrt(2/37) / sqrt(500) = 1 %, so 5 % is again a wide band. */
static void test_monte_carlo_standard_errors(void **state) {
    (void)state;
    enum { N = 40, P = 3, Q = 2, R = 500 };
    test_rng rng;
    test_rng_seed(&rng, 6);
    double X[N * P], Y[N * Q], est[P * Q], se[P * Q], rc[Q * Q];
    const double T[P * Q] = {1.0, -2.0, 0.5, 3.0, 0.0, -1.0};
    test_rng_fill_normal(&rng, X, N * P, 1.0);
    const double s1 = 0.5, s2 = 2.0, rho = 0.3;
    double sum[P * Q] = {0}, sum2[P * Q] = {0}, se2[P * Q] = {0}, rc_mean[Q * Q] = {0};
    vibid_lsq *lsq = vibid_lsq_create(P, Q);
    for (int r = 0; r < R; ++r) {
        matmul(X, T, Y, N, P, Q);
        for (size_t k = 0; k < N; ++k) {
            const double z1 = test_rng_normal(&rng), z2 = test_rng_normal(&rng);
            Y[k] += s1 * z1;
            Y[k + N] += s2 * (rho * z1 + sqrt(1.0 - rho * rho) * z2);
        }
        vibid_lsq_reset(lsq);
        assert_int_equal(vibid_lsq_add_rows(lsq, N, X, Y, NULL), VIBID_OK);
        assert_int_equal(vibid_lsq_solve(lsq, est, NULL), VIBID_OK);
        assert_int_equal(vibid_lsq_stderr(lsq, se), VIBID_OK);
        assert_int_equal(vibid_lsq_covariance(lsq, NULL, rc), VIBID_OK);
        for (size_t i = 0; i < P * Q; ++i) {
            sum[i] += est[i];
            sum2[i] += est[i] * est[i];
            se2[i] += se[i] * se[i];
        }
        for (size_t i = 0; i < Q * Q; ++i) rc_mean[i] += rc[i] / R;
    }
    double worst = 1.0;
    for (size_t i = 0; i < P * Q; ++i) {
        const double mean = sum[i] / R;
        const double sd = sqrt((sum2[i] - R * mean * mean) / (R - 1));
        const double rms_se = sqrt(se2[i] / R);
        const double ratio = sd / rms_se;
        if (fabs(ratio - 1.0) > fabs(worst - 1.0)) worst = ratio;
        ASSERT_NEAR(ratio, 1.0, 0.10);
        /* Unbiased: mean within 4 standard errors of the mean. */
        ASSERT_NEAR(mean, T[i], 4.0 * sd / sqrt((double)R));
    }
    print_message("  stderr Monte Carlo: worst empirical sd / rms stderr = %.3f\n", worst);
    ASSERT_NEAR(rc_mean[0] / (s1 * s1), 1.0, 0.05);
    ASSERT_NEAR(rc_mean[3] / (s2 * s2), 1.0, 0.05);
    ASSERT_NEAR(rc_mean[1] / (rho * s1 * s2), 1.0, 0.10); /* off-diagonal: sd ~ 2.5 % */
    ASSERT_NEAR(rc_mean[1], rc_mean[2], 0.0);
    print_message("  residual covariance mean = [%.4f %.4f; %.4f %.4f], true [0.25 0.3; 0.3 4]\n", rc_mean[0],
                  rc_mean[2], rc_mean[1], rc_mean[3]);
    vibid_lsq_destroy(lsq);
}

/* ---- bad input: status, message naming the argument, state untouched ---- */
static void test_create_rejects(void **state) {
    (void)state;
    assert_null(vibid_lsq_create(0, 1));
    ASSERT_MSG_CONTAINS("n_params = 0");
    assert_null(vibid_lsq_create(1, 0));
    ASSERT_MSG_CONTAINS("n_outputs = 0");
    assert_null(vibid_lsq_create(4000, 100));
    ASSERT_MSG_CONTAINS("4096");
    assert_null(vibid_lsq_create(SIZE_MAX, 1));
    ASSERT_MSG_CONTAINS("vibid_lsq_create");
    vibid_lsq_destroy(NULL);
}

/* Solves and returns theta bytes for comparison. */
static void snapshot(const vibid_lsq *lsq, double *theta, size_t n_rows_expected) {
    vibid_lsq_info info;
    assert_int_equal(vibid_lsq_solve(lsq, theta, &info), VIBID_OK);
    assert_int_equal(info.n_rows, n_rows_expected);
}

static void test_add_rows_rejects_and_keeps_state(void **state) {
    (void)state;
    enum { N = 10, P = 2, Q = 2 };
    test_rng rng;
    test_rng_seed(&rng, 7);
    double X[N * P], Y[N * Q], w[N];
    test_rng_fill_normal(&rng, X, N * P, 1.0);
    test_rng_fill_normal(&rng, Y, N * Q, 1.0);
    for (size_t k = 0; k < N; ++k) w[k] = 1.0 + test_rng_uniform(&rng);
    vibid_lsq *lsq = vibid_lsq_create(P, Q);
    assert_int_equal(vibid_lsq_add_rows(lsq, N, X, Y, w), VIBID_OK);
    double before[P * Q], after[P * Q];
    snapshot(lsq, before, N);

    assert_int_equal(vibid_lsq_add_rows(NULL, N, X, Y, NULL), VIBID_E_NULL_ARGUMENT);
    ASSERT_MSG_CONTAINS("lsq is NULL");
    assert_int_equal(vibid_lsq_add_rows(lsq, N, NULL, Y, NULL), VIBID_E_NULL_ARGUMENT);
    ASSERT_MSG_CONTAINS("X is NULL");
    assert_int_equal(vibid_lsq_add_rows(lsq, N, X, NULL, NULL), VIBID_E_NULL_ARGUMENT);
    ASSERT_MSG_CONTAINS("Y is NULL");
    assert_int_equal(vibid_lsq_add_rows(lsq, 0, X, Y, NULL), VIBID_E_DIMENSION);
    ASSERT_MSG_CONTAINS("n_rows = 0");
    assert_int_equal(vibid_lsq_add_rows(lsq, SIZE_MAX / 2, X, Y, NULL), VIBID_E_DIMENSION);
    ASSERT_MSG_CONTAINS("n_rows");

    /* A bad value in the LAST row: the rows before it must not have been added. */
    double Xbad[N * P];
    memcpy(Xbad, X, sizeof X);
    Xbad[(N - 1) + 1 * N] = NAN;
    assert_int_equal(vibid_lsq_add_rows(lsq, N, Xbad, Y, NULL), VIBID_E_NONFINITE);
    ASSERT_MSG_CONTAINS("X[19] (row 9, column 1)");
    double Ybad[N * Q];
    memcpy(Ybad, Y, sizeof Y);
    Ybad[N + 4] = -INFINITY;
    assert_int_equal(vibid_lsq_add_rows(lsq, N, X, Ybad, NULL), VIBID_E_NONFINITE);
    ASSERT_MSG_CONTAINS("Y[14] (row 4, column 1) = -inf");
    double wbad[N];
    memcpy(wbad, w, sizeof w);
    wbad[7] = -1.0;
    assert_int_equal(vibid_lsq_add_rows(lsq, N, X, Y, wbad), VIBID_E_OUT_OF_RANGE);
    ASSERT_MSG_CONTAINS("weights[7] = -1 is negative");
    wbad[7] = NAN;
    assert_int_equal(vibid_lsq_add_rows(lsq, N, X, Y, wbad), VIBID_E_NONFINITE);
    ASSERT_MSG_CONTAINS("weights[7] = nan");

    snapshot(lsq, after, N);
    assert_memory_equal(before, after, sizeof before); /* bit-identical */

    /* Other entry points. */
    assert_int_equal(vibid_lsq_set_rank_tolerance(lsq, 0.0), VIBID_E_OUT_OF_RANGE);
    ASSERT_MSG_CONTAINS("tol = 0");
    assert_int_equal(vibid_lsq_set_rank_tolerance(lsq, 1.0), VIBID_E_OUT_OF_RANGE);
    assert_int_equal(vibid_lsq_set_rank_tolerance(lsq, NAN), VIBID_E_OUT_OF_RANGE);
    assert_int_equal(vibid_lsq_set_rank_tolerance(NULL, 1e-8), VIBID_E_NULL_ARGUMENT);
    assert_int_equal(vibid_lsq_solve(NULL, after, NULL), VIBID_E_NULL_ARGUMENT);
    ASSERT_MSG_CONTAINS("lsq is NULL");
    assert_int_equal(vibid_lsq_solve(lsq, NULL, NULL), VIBID_E_NULL_ARGUMENT);
    ASSERT_MSG_CONTAINS("theta is NULL");
    assert_int_equal(vibid_lsq_covariance(lsq, NULL, NULL), VIBID_E_NULL_ARGUMENT);
    ASSERT_MSG_CONTAINS("param_cov and residual_cov");
    assert_int_equal(vibid_lsq_covariance(NULL, after, NULL), VIBID_E_NULL_ARGUMENT);
    assert_int_equal(vibid_lsq_stderr(lsq, NULL), VIBID_E_NULL_ARGUMENT);
    ASSERT_MSG_CONTAINS("stderr_out is NULL");
    assert_int_equal(vibid_lsq_stderr(NULL, after), VIBID_E_NULL_ARGUMENT);
    size_t nv;
    assert_int_equal(vibid_lsq_null_space(lsq, NULL, 1, &nv), VIBID_E_NULL_ARGUMENT);
    ASSERT_MSG_CONTAINS("basis is NULL but max_vectors = 1");
    assert_int_equal(vibid_lsq_null_space(lsq, after, 1, NULL), VIBID_E_NULL_ARGUMENT);
    ASSERT_MSG_CONTAINS("n_vectors is NULL");
    assert_int_equal(vibid_lsq_null_space(NULL, after, 1, &nv), VIBID_E_NULL_ARGUMENT);
    assert_int_equal(vibid_lsq_reset(NULL), VIBID_E_NULL_ARGUMENT);

    snapshot(lsq, after, N);
    assert_memory_equal(before, after, sizeof before);

    /* Reset really forgets; re-adding the same rows gives the same bits. */
    assert_int_equal(vibid_lsq_reset(lsq), VIBID_OK);
    assert_int_equal(vibid_lsq_solve(lsq, after, NULL), VIBID_E_INSUFFICIENT_DATA);
    assert_int_equal(vibid_lsq_add_rows(lsq, N, X, Y, w), VIBID_OK);
    snapshot(lsq, after, N);
    assert_memory_equal(before, after, sizeof before);
    vibid_lsq_destroy(lsq);
}

/* The rank tolerance is honoured: a column that is collinear up to 1e-8 relative
 * counts as independent at the default 1e-10 and as dependent at 1e-6. */
static void test_rank_tolerance(void **state) {
    (void)state;
    enum { N = 50, P = 2 };
    test_rng rng;
    test_rng_seed(&rng, 8);
    double X[N * P], Y[N], theta[P];
    test_rng_fill_normal(&rng, X, N * P, 1.0);
    for (size_t k = 0; k < N; ++k) X[k + N] = X[k] + 1e-8 * X[k + N];
    test_rng_fill_normal(&rng, Y, N, 1.0);
    vibid_lsq *lsq = vibid_lsq_create(P, 1);
    assert_int_equal(vibid_lsq_add_rows(lsq, N, X, Y, NULL), VIBID_OK);
    vibid_lsq_info info;
    assert_int_equal(vibid_lsq_solve(lsq, theta, &info), VIBID_OK);
    assert_true(info.rcond > 1e-10 && info.rcond < 1e-7);
    assert_int_equal(vibid_lsq_set_rank_tolerance(lsq, 1e-6), VIBID_OK);
    assert_int_equal(vibid_lsq_solve(lsq, theta, &info), VIBID_E_NOT_IDENTIFIABLE);
    assert_int_equal(info.rank, 1);
    vibid_lsq_destroy(lsq);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_exact_system_recovers_theta),
        cmocka_unit_test(test_matches_normal_equations),
        cmocka_unit_test(test_hand_computed_line),
        cmocka_unit_test(test_badly_scaled_columns),
        cmocka_unit_test(test_rank_deficient),
        cmocka_unit_test(test_rank_deficient_scaled),
        cmocka_unit_test(test_too_few_rows),
        cmocka_unit_test(test_monte_carlo_standard_errors),
        cmocka_unit_test(test_create_rejects),
        cmocka_unit_test(test_add_rows_rejects_and_keeps_state),
        cmocka_unit_test(test_rank_tolerance),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
