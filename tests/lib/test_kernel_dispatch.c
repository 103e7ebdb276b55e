/* test_kernel_dispatch.c: the run-time choice of kernels (lib/src/kernels.hpp). libvibid
 * uses AVX2+FMA kernels for RLS and batch LS where the CPU has them and the baseline
 * (SSE2) kernels elsewhere, or when VIBID_FORCE_BASELINE=1 is set (read once per
 * process). This test runs one RLS and one batch LS scenario in this process (the
 * dispatched kernels) and again in a child process of itself with VIBID_FORCE_BASELINE=1,
 * and compares the results.
 *
 * Tolerance: 1e-10 relative to each array's largest entry. FMA rounds a multiply-add once
 * instead of twice (differences of ~1e-16 per operation), and 4-wide vectors sum in
 * another order; over 3000 recursive updates with forgetting 0.995 and 5000 merged rows
 * the results differ by at most 2e-15 (measured on an AVX2 machine; the test prints the
 * figures), so 1e-10 leaves room for other CPUs and compilers, while a wrong kernel is
 * off by O(1).
 * On a CPU with AVX2 and FMA the two runs must also differ in at least one bit, which
 * shows that two different code paths ran (the whole lib test set also runs once more
 * with VIBID_FORCE_BASELINE=1, the lib.*.baseline tests, so each path is checked against
 * the reference values of the other tests). */
#define _POSIX_C_SOURCE 200809L
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <vibid/lsq.h>
#include <vibid/rls.h>

#include "test_rng.h"

enum { RP = 12, RQ = 2, RN = 3000, LP = 20, LQ = 3, LN = 5000 };
/* Results: RLS Theta (RP x RQ) and P (RP x RP), LS Theta (LP x LQ) and (X^T W X)^-1. */
enum { N_OUT = RP * RQ + RP * RP + LP * LQ + LP * LP };

static const char *self_path;

static void scenario(double *out) {
    test_rng rng;
    test_rng_seed(&rng, 2024);
    double *o = out;

    /* RLS: Bierman with forgetting and the trace bound, a drifting parameter set. */
    vibid_rls_config cfg;
    vibid_rls_config_init(&cfg, RP, RQ);
    cfg.forgetting = 0.995;
    cfg.alpha = 1e-3;
    cfg.windup = VIBID_RLS_WINDUP_TRACE_BOUND;
    cfg.trace_max = 50.0;
    vibid_rls *rls = vibid_rls_create(&cfg);
    assert_non_null(rls);
    for (int k = 0; k < RN; ++k) {
        double x[RP], y[RQ];
        test_rng_fill_normal(&rng, x, RP, 1.0);
        for (int j = 0; j < RQ; ++j) {
            y[j] = 0.01 * test_rng_normal(&rng);
            for (int i = 0; i < RP; ++i) y[j] += (1.0 + 0.1 * i - 0.3 * j + 1e-4 * k) * x[i];
        }
        assert_int_equal(vibid_rls_update(rls, x, y), VIBID_OK);
    }
    assert_int_equal(vibid_rls_theta(rls, o), VIBID_OK);
    o += RP * RQ;
    assert_int_equal(vibid_rls_covariance(rls, o), VIBID_OK);
    o += RP * RP;
    vibid_rls_destroy(rls);

    /* Batch LS: weighted rows in uneven calls (blocks cut at several places). */
    vibid_lsq *lsq = vibid_lsq_create(LP, LQ);
    assert_non_null(lsq);
    static double X[LN * LP], Y[LN * LQ], w[LN];
    test_rng_fill_normal(&rng, X, LN * LP, 1.0);
    for (int k = 0; k < LN; ++k) {
        w[k] = 0.5 + test_rng_uniform(&rng);
        for (int j = 0; j < LQ; ++j) {
            double s = 0.1 * test_rng_normal(&rng);
            for (int i = 0; i < LP; ++i) s += (i - 7.0 * j) * X[k + i * LN];
            Y[k + j * LN] = s;
        }
    }
    /* Rows [0, 1), [1, 1000), [1000, LN) in three calls (a single row, then calls that do
     * not fill the last block): each part copied out as its own column-major matrix. */
    const int cuts[4] = {0, 1, 1000, LN};
    for (int c = 0; c < 3; ++c) {
        const int n = cuts[c + 1] - cuts[c];
        double *Xc = malloc(sizeof(double) * (size_t)(n * LP)), *Yc = malloc(sizeof(double) * (size_t)(n * LQ));
        assert_non_null(Xc);
        assert_non_null(Yc);
        for (int i = 0; i < LP; ++i) memcpy(Xc + i * n, X + cuts[c] + i * LN, sizeof(double) * (size_t)n);
        for (int j = 0; j < LQ; ++j) memcpy(Yc + j * n, Y + cuts[c] + j * LN, sizeof(double) * (size_t)n);
        assert_int_equal(vibid_lsq_add_rows(lsq, (size_t)n, Xc, Yc, w + cuts[c]), VIBID_OK);
        free(Xc);
        free(Yc);
    }
    assert_int_equal(vibid_lsq_solve(lsq, o, NULL), VIBID_OK);
    o += LP * LQ;
    assert_int_equal(vibid_lsq_covariance(lsq, o, NULL), VIBID_OK);
    vibid_lsq_destroy(lsq);
}

/* Largest |a - b| over a block relative to the block's largest |a|. */
static double block_diff(const double *a, const double *b, size_t n) {
    double d = 0.0, m = 0.0;
    for (size_t i = 0; i < n; ++i) {
        d = fmax(d, fabs(a[i] - b[i]));
        m = fmax(m, fabs(a[i]));
    }
    return m > 0.0 ? d / m : d;
}

static int cpu_has_avx2_fma(void) {
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
#else
    return 0;
#endif
}

static void test_dispatched_equals_baseline(void **state) {
    (void)state;
    static double here[N_OUT], base[N_OUT];
    scenario(here);

    char cmd[4096];
    assert_true(snprintf(cmd, sizeof cmd, "VIBID_FORCE_BASELINE=1 '%s' --emit", self_path) < (int)sizeof cmd);
    FILE *f = popen(cmd, "r");
    assert_non_null(f);
    size_t n = 0;
    while (n < N_OUT && fscanf(f, "%la", &base[n]) == 1) ++n;
    assert_int_equal(pclose(f), 0);
    assert_int_equal(n, N_OUT);

    const size_t sizes[4] = {RP * RQ, RP * RP, LP * LQ, LP * LP};
    const char *names[4] = {"RLS theta", "RLS P", "LS theta", "LS param_cov"};
    size_t off = 0;
    for (int b = 0; b < 4; ++b) {
        const double d = block_diff(here + off, base + off, sizes[b]);
        printf("  %-12s dispatched vs baseline: %.3g relative\n", names[b], d);
        assert_true(d <= 1e-10);
        off += sizes[b];
    }
    const char *forced = getenv("VIBID_FORCE_BASELINE");
    const int dispatched_is_avx2 = cpu_has_avx2_fma() && !(forced && *forced && strcmp(forced, "0") != 0);
    const int identical = memcmp(here, base, sizeof here) == 0;
    printf("  CPU has AVX2+FMA: %s; results bit-identical: %s\n", cpu_has_avx2_fma() ? "yes" : "no",
           identical ? "yes" : "no");
    if (dispatched_is_avx2) assert_false(identical); /* two code paths really ran */
}

int main(int argc, char **argv) {
    self_path = argv[0];
    if (argc > 1 && strcmp(argv[1], "--emit") == 0) {
        /* Child: the scenario with whatever kernels this process chose, as exact hex. */
        static double out[N_OUT];
        scenario(out);
        for (size_t i = 0; i < N_OUT; ++i) printf("%a\n", out[i]);
        return 0;
    }
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_dispatched_equals_baseline),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
