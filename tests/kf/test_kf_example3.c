/* test_kf_example3.c: fast version of the example-3 Monte Carlo study (Bild 4, (4.3)).
 *
 * 100 realisations per cell (the full study, examples/paper_example3, runs 500). Each
 * cell checks
 *  - the target for the best estimator of that parameter, and
 *  - agreement with the 500-run study (docs/kf.md): |MARE_100 - MARE_500| <= 4 SE_100,
 *    SE_100 the Monte Carlo standard error of the 100-run mean computed from the runs
 *    themselves. The 100 runs are the first 100 of the 500 (same seed), so the
 *    difference is a subsample fluctuation of at most ~sqrt(1 - 100/500) SE_100; 4 SE
 *    leaves room for compiler/libm rounding differences while still catching a bias
 *    of a few tenths of a percent (e.g. a wrong Joseph term or a lagged regressor).
 * The runs are deterministic (fixed seeds), so the test cannot flake.
 */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <vibid/vibid.h>

#include "paper_example3_study.h"

#include <math.h>
#include <stdio.h>

enum { RUNS = 100 };

/* Seeds as in examples/paper_example3.c: 1000 + 17 * (index of N) + 7919 * noise. */
static uint64_t seed_for(int n_index, int noisy) { return 1000u + 17u * (unsigned)n_index + 7919u * (unsigned)noisy; }

static void check(const char *what, double got, double se, double ref) {
    printf("  %-34s %7.3f %% (SE %.3f), 500-run study %.3f %%\n", what, 100 * got, 100 * se, 100 * ref);
    assert_true(isfinite(got) && se > 0.0);
    assert_true(fabs(got - ref) <= 4.0 * se);
}

/* Noise-free, N = 200 (index 1). Targets: c <= 8 %, d <= 2.5 % for the best estimator;
 * the paper's KF+RLS had 11 % / 2.8 %. */
static void test_noise_free_n200(void **state) {
    (void)state;
    ex3_setup s;
    ex3_setup_init(&s, -1.0);
    ex3_mc_result r;
    const unsigned mask = (1u << EX3_PLAIN_LS) | (1u << EX3_IO_LS) | (1u << EX3_IO_IV) | (1u << EX3_KFRLS) |
                          (1u << EX3_EKF);
    ex3_monte_carlo(&s, 200, RUNS, seed_for(1, 0), mask, &r);
    for (int e = 0; e < EX3_N_EST; ++e)
        if (mask & (1u << e)) assert_int_equal(r.fails[e], 0);
    check("plain LS c", r.mare_c[EX3_PLAIN_LS], r.se_c[EX3_PLAIN_LS], 0.0660);
    check("plain LS d", r.mare_d[EX3_PLAIN_LS], r.se_d[EX3_PLAIN_LS], 0.0206);
    /* Without measurement noise the I/O-form LS is the same estimator as plain LS on
     * exact differences (an invertible linear map of the regressors). */
    assert_true(fabs(r.mare_c[EX3_IO_LS] - r.mare_c[EX3_PLAIN_LS]) < 1e-9);
    assert_true(fabs(r.mare_d[EX3_IO_LS] - r.mare_d[EX3_PLAIN_LS]) < 1e-9);
    check("I/O IV c", r.mare_c[EX3_IO_IV], r.se_c[EX3_IO_IV], 0.0664);
    check("I/O IV d", r.mare_d[EX3_IO_IV], r.se_d[EX3_IO_IV], 0.0215);
    check("KF+RLS c", r.mare_c[EX3_KFRLS], r.se_c[EX3_KFRLS], 0.0660);
    check("KF+RLS d", r.mare_d[EX3_KFRLS], r.se_d[EX3_KFRLS], 0.0209);
    check("EKF c", r.mare_c[EX3_EKF], r.se_c[EX3_EKF], 0.0622);
    check("EKF d", r.mare_d[EX3_EKF], r.se_d[EX3_EKF], 0.0222);
    /* Targets: best c (EKF) and best d (LS). */
    assert_true(r.mare_c[EX3_EKF] <= 0.08);
    assert_true(r.mare_d[EX3_IO_LS] <= 0.025);
    /* The paper's algorithm, as implemented here, beats the paper's 11 % / 2.8 %. */
    assert_true(r.mare_c[EX3_KFRLS] < 0.11 && r.mare_d[EX3_KFRLS] < 0.028);
}

/* 20 dB SNR, N = 5000 (index 4). Targets: c <= 3 %, d <= 1.5 %; plain LS ~38 % off on d. */
static void test_20db_n5000(void **state) {
    (void)state;
    ex3_setup s;
    ex3_setup_init(&s, 20.0);
    ex3_mc_result r;
    const unsigned mask = (1u << EX3_PLAIN_LS) | (1u << EX3_IO_IV) | (1u << EX3_KFRLS) | (1u << EX3_EKF);
    ex3_monte_carlo(&s, 5000, RUNS, seed_for(4, 1), mask, &r);
    for (int e = 0; e < EX3_N_EST; ++e)
        if (mask & (1u << e)) assert_int_equal(r.fails[e], 0);
    check("plain LS c", r.mare_c[EX3_PLAIN_LS], r.se_c[EX3_PLAIN_LS], 0.0773);
    check("plain LS d", r.mare_d[EX3_PLAIN_LS], r.se_d[EX3_PLAIN_LS], 0.3874);
    check("I/O IV c", r.mare_c[EX3_IO_IV], r.se_c[EX3_IO_IV], 0.0134);
    check("I/O IV d", r.mare_d[EX3_IO_IV], r.se_d[EX3_IO_IV], 0.0040);
    check("KF+RLS c", r.mare_c[EX3_KFRLS], r.se_c[EX3_KFRLS], 0.0154);
    check("KF+RLS d", r.mare_d[EX3_KFRLS], r.se_d[EX3_KFRLS], 0.0039);
    check("EKF c", r.mare_c[EX3_EKF], r.se_c[EX3_EKF], 0.0124);
    check("EKF d", r.mare_d[EX3_EKF], r.se_d[EX3_EKF], 0.0035);
    assert_true(r.mare_c[EX3_EKF] <= 0.03 && r.mare_d[EX3_EKF] <= 0.015);
    assert_true(r.mare_c[EX3_IO_IV] <= 0.03 && r.mare_d[EX3_IO_IV] <= 0.015);
    /* Plain LS is biased, not just noisy: 38 % off on d although N = 5000. */
    assert_true(r.mare_d[EX3_PLAIN_LS] > 0.30);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_noise_free_n200),
        cmocka_unit_test(test_20db_n5000),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
