/* lib.test_outlier: vibid/outlier.h, the single-sample glitch test.
 *
 * What is asserted and why (tolerances are exact: the test passes values through or
 * replaces them by NaN, it computes nothing):
 *  - false outliers on white Gaussian noise: none in 10^7 samples (two channels, one with
 *    an offset of 1e4 standard deviations, where the relative floor matters). A false
 *    outlier needs a value K S (S ~ 5 sigma, the peak increment) off both neighbours;
 *  - signals that jump legitimately pass, bit for bit: a held step and a ramp starting
 *    from exact rest, a sine starting from rest, a triangle with its corners on samples,
 *    PRBS with one sample per bit (runs of up to 20 equal bits), a quantised channel at
 *    rest that flickers by one step;
 *  - glitches (1.0 in millimetre motions, 1e3, 1e300, -1e300, on any channel, also in the
 *    warm-up and at the first sample) are taken out, exactly those values, and the rest of
 *    each sample passes; every sample comes out once, in order;
 *  - a suspect followed by a missing value or the end is taken out as unverified;
 *  - bad configurations are refused naming the field. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include <vibid/outlier.h>

#include "test_rng.h"

#define TWO_PI 6.283185307179586476925286766559

/* Feeds x[k * nch + c], k < n, through a default detector (flushed at the end) and
 * collects what comes out: y (values, NaN where taken out) and mark (1 = taken out). */
static vibid_outlier_stats pass(const double *x, size_t n, size_t nch, double *y, unsigned char *mark)
{
    vibid_outlier_config cfg;
    vibid_outlier_config_init(&cfg, nch);
    vibid_outlier *det = vibid_outlier_create(&cfg);
    assert_non_null(det);
    size_t out = 0;
    for (size_t k = 0; k <= n; k++) {
        size_t nr = 0;
        if (k < n)
            assert_int_equal(vibid_outlier_push(det, x + k * nch, &nr), VIBID_OK);
        else
            assert_int_equal(vibid_outlier_flush(det, &nr), VIBID_OK);
        for (size_t i = 0; i < nr; i++, out++) {
            assert_true(out < n);
            size_t no = 99;
            assert_int_equal(vibid_outlier_released(det, i, y + out * nch, mark + out * nch, &no), VIBID_OK);
            size_t t = 0;
            for (size_t c = 0; c < nch; c++) t += mark[out * nch + c];
            assert_int_equal(no, t);
        }
    }
    assert_int_equal(out, n); /* every sample once */
    vibid_outlier_stats st;
    assert_int_equal(vibid_outlier_get_stats(det, &st), VIBID_OK);
    assert_int_equal(st.samples, n);
    vibid_outlier_destroy(det);
    return st;
}

/* Every value passed unchanged (bit for bit, NaN as NaN), none taken out. */
static void assert_untouched(const double *x, const double *y, const unsigned char *mark, size_t m)
{
    for (size_t i = 0; i < m; i++) {
        assert_int_equal(mark[i], 0);
        if (isnan(x[i]))
            assert_true(isnan(y[i]));
        else
            assert_memory_equal(&x[i], &y[i], sizeof(double));
    }
}

static void test_gaussian(void **state)
{
    (void)state;
    const size_t n = 10000000, nch = 2;
    double *x = malloc(n * nch * sizeof *x), *y = malloc(n * nch * sizeof *y);
    unsigned char *mark = malloc(n * nch);
    assert_true(x && y && mark);
    test_rng rng;
    test_rng_seed(&rng, 30);
    for (size_t k = 0; k < n; k++) {
        x[k * nch] = test_rng_normal(&rng);
        x[k * nch + 1] = 1e4 + test_rng_normal(&rng);
    }
    vibid_outlier_stats st = pass(x, n, nch, y, mark);
    printf("  white Gaussian noise, 2 x 10^7 values: %llu held for their successors, %llu outliers\n",
           (unsigned long long)st.held, (unsigned long long)st.outlier_values);
    assert_int_equal(st.outlier_values, 0);
    assert_untouched(x, y, mark, n * nch);
    free(x);
    free(y);
    free(mark);
}

/* Legitimate jumps, noise-free (the hardest case: nothing but the signal sets the scale). */
static void test_legitimate(void **state)
{
    (void)state;
    enum { N = 6000, C = 4 };
    static double x[N * C], y[N * C];
    static unsigned char mark[N * C];
    /* c0: rest, a held step at 1000, a ramp from 3000; c1: rest, then a sine from 2000;
     * c2: a triangle with corners on samples (period 40); c3: PRBS, one sample per bit,
     * with runs of 1..20 equal bits */
    uint32_t lfsr = 0xACE1u;
    double level = 1.0;
    int run = 0, run_len = 1;
    for (size_t k = 0; k < N; k++) {
        double *r = x + k * C;
        r[0] = k < 1000 ? 0.0 : k < 3000 ? 2.5 : 2.5 + 1e-3 * (double)(k - 3000);
        r[1] = k < 2000 ? 0.0 : 1e-3 * sin(0.05 * (double)(k - 2000));
        size_t ph = k % 40;
        r[2] = 1e-3 * (ph < 20 ? (double)ph : (double)(40 - ph));
        if (++run >= run_len) {
            run = 0;
            lfsr = (lfsr >> 1) ^ (-(lfsr & 1u) & 0xB400u);
            run_len = 1 + (int)(lfsr % 20u);
            level = -level;
        }
        r[3] = 10.0 * level;
    }
    vibid_outlier_stats st = pass(x, N, C, y, mark);
    assert_int_equal(st.outlier_values, 0);
    assert_untouched(x, y, mark, N * C);
    /* the step at 1000 waited for its successors and was accepted, as were the sine's start
     * and the PRBS's first jumps after the warm-up */
    assert_true(st.held >= 1);
}

/* A quantised channel at rest (exactly 0) that flickers by one step now and then: the
 * first flicker teaches the step; none is taken out. */
static void test_quantised_rest(void **state)
{
    (void)state;
    enum { N = 20000 };
    static double x[N], y[N];
    static unsigned char mark[N];
    for (size_t k = 0; k < N; k++) x[k] = (k % 997 == 500) ? 1e-3 : (k % 1409 == 700) ? -1e-3 : 0.0;
    vibid_outlier_stats st = pass(x, N, 1, y, mark);
    assert_int_equal(st.outlier_values, 1); /* the very first flicker: no step known yet */
    assert_int_equal(mark[500], 1);
    assert_true(isnan(y[500]));
    /* and with the step seen in the warm-up, none */
    x[3] = 1e-3;
    x[4] = 1e-3;
    st = pass(x, N, 1, y, mark);
    assert_int_equal(st.outlier_values, 0);
}

static void test_glitches(void **state)
{
    (void)state;
    enum { N = 8000, C = 3 };
    static double x[N * C], y[N * C];
    static unsigned char mark[N * C];
    test_rng rng;
    test_rng_seed(&rng, 7);
    for (size_t k = 0; k < N; k++) { /* millimetre motions in m, 60 dB of noise */
        double t = (double)k / 2000.0;
        x[k * C] = 1e-3 * sin(TWO_PI * 5 * t) + 1e-6 * test_rng_normal(&rng);
        x[k * C + 1] = 0.5e-3 * sin(TWO_PI * 23 * t + 1) + 1e-6 * test_rng_normal(&rng);
        x[k * C + 2] = 10.0 * cos(TWO_PI * 40 * t) + 1e-2 * test_rng_normal(&rng);
    }
    static const struct {
        size_t k, c;
        double v;
    } g[] = {{0, 1, 1.0},      {3, 0, 1e3},     {100, 0, 1.0},     {1000, 0, 1e3}, {2000, 0, 1e300},
             {3000, 0, -1e300}, {4000, 1, 1.0}, {5000, 2, 1e6},    {5001, 0, 1.0}, {7999, 1, 5.0}};
    const size_t ng = sizeof g / sizeof g[0];
    for (size_t i = 0; i < ng; i++) x[g[i].k * C + g[i].c] = g[i].v;
    vibid_outlier_stats st = pass(x, N, C, y, mark);
    assert_int_equal(st.outlier_values, ng);
    assert_int_equal(st.outlier_samples, ng);
    assert_int_equal(st.unverified, 1); /* the last sample's: no successor */
    for (size_t i = 0; i < ng; i++) {
        size_t at = g[i].k * C + g[i].c;
        assert_int_equal(mark[at], 1);
        assert_true(isnan(y[at]));
        x[at] = NAN; /* for the comparison below: taken out exactly there */
    }
    assert_true(isnan(x[3 * C]));
    for (size_t i = 0; i < N * C; i++) {
        if (isnan(x[i])) continue;
        assert_int_equal(mark[i], 0);
        assert_memory_equal(&x[i], &y[i], sizeof(double));
    }
}

/* A suspect whose successor is missing cannot be checked: taken out, counted unverified.
 * A missing value itself is passed through as it is, never counted. */
static void test_unverified(void **state)
{
    (void)state;
    enum { N = 400 };
    static double x[N], y[N];
    static unsigned char mark[N];
    for (size_t k = 0; k < N; k++) x[k] = sin(0.1 * (double)k);
    x[200] = 1e3;
    x[201] = NAN;
    x[300] = NAN;
    vibid_outlier_stats st = pass(x, N, 1, y, mark);
    assert_int_equal(st.outlier_values, 1);
    assert_int_equal(st.unverified, 1);
    assert_int_equal(mark[200], 1);
    assert_int_equal(mark[201], 0);
    assert_true(isnan(y[201]) && isnan(y[300]));
}

static void test_config(void **state)
{
    (void)state;
    vibid_outlier_config cfg;
    vibid_outlier_config_init(&cfg, 3);
    assert_true(cfg.threshold == VIBID_OUTLIER_THRESHOLD_DEFAULT && cfg.memory == VIBID_OUTLIER_MEMORY_DEFAULT &&
                cfg.warmup == VIBID_OUTLIER_WARMUP_DEFAULT);
    assert_null(vibid_outlier_create(NULL));
    cfg.threshold = 1.5;
    assert_null(vibid_outlier_create(&cfg));
    assert_non_null(strstr(vibid_last_error(), "threshold = 1.5"));
    cfg.threshold = 8;
    cfg.memory = 0.5;
    assert_null(vibid_outlier_create(&cfg));
    assert_non_null(strstr(vibid_last_error(), "memory"));
    cfg.memory = 100;
    cfg.warmup = 2;
    assert_null(vibid_outlier_create(&cfg));
    assert_non_null(strstr(vibid_last_error(), "warmup"));
    cfg.warmup = 16;
    cfg.n_channels = 0;
    assert_null(vibid_outlier_create(&cfg));
    assert_non_null(strstr(vibid_last_error(), "n_channels"));
    cfg.n_channels = 2;
    vibid_outlier *det = vibid_outlier_create(&cfg);
    assert_non_null(det);
    size_t nr;
    double v[2] = {0, 0};
    assert_int_equal(vibid_outlier_push(NULL, v, &nr), VIBID_E_NULL_ARGUMENT);
    assert_int_equal(vibid_outlier_released(det, 0, v, NULL, NULL), VIBID_E_OUT_OF_RANGE);
    vibid_outlier_destroy(det);
    vibid_outlier_destroy(NULL);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_gaussian),   cmocka_unit_test(test_legitimate), cmocka_unit_test(test_quantised_rest),
        cmocka_unit_test(test_glitches),   cmocka_unit_test(test_unverified), cmocka_unit_test(test_config),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
