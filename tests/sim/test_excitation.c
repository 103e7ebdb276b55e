/* sim.excitation: the generators do what docs/sim.md says. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include "excitation.h"

/* every LFSR order 2..22 of the tap table has the maximal period 2^n - 1 */
static void test_prbs_maximal(void **state)
{
    (void)state;
    for (int order = 2; order <= 22; order++) {
        uint32_t s = 1, s0 = 1;
        uint64_t period = 0;
        do {
            sim_lfsr_next(&s, order);
            period++;
        } while (s != s0 && period <= (1ull << order));
        if (period != (1ull << order) - 1) fail_msg("order %d: period %llu, want %llu", order, (unsigned long long)period,
                                                    (unsigned long long)((1ull << order) - 1));
    }
}

/* triangle: 0 at t = 0, +A at a quarter period, -A at three quarters; ZOH holds t_k */
static void test_triangle_zoh(void **state)
{
    (void)state;
    sim_exc_spec s;
    sim_exc_spec_init(&s, SIM_EXC_TRIANGLE);
    s.amplitude = 2.0;
    s.frequency = 10.0;
    char err[256];
    sim_exc *e = sim_exc_create(&s, 1, 1e-3, 0, err, sizeof err);
    assert_non_null(e);
    for (uint64_t k = 0; k < 200; k++) {
        sim_exc_begin_sample(e, k);
        double t = (double)k * 1e-3, p = fmod(t * 10.0, 1.0);
        double want = p < 0.25 ? 8.0 * p : p < 0.75 ? 2.0 * (2.0 - 4.0 * p) : 2.0 * (4.0 * p - 4.0);
        assert_true(fabs(sim_exc_sample_value(e) - want) < 1e-12);
        double v, dv;
        sim_exc_eval(e, t + 0.7e-3, &v, &dv); /* held */
        assert_true(v == sim_exc_sample_value(e) && dv == 0.0);
    }
    sim_exc_destroy(e);
}

/* band-limited noise: sample standard deviation = amplitude within 3 % (200000 samples
 * of a process correlated over ~1/(2 f_high) s: the estimate's relative std is about 0.5 %) */
static void test_noise_std(void **state)
{
    (void)state;
    sim_exc_spec s;
    sim_exc_spec_init(&s, SIM_EXC_NOISE);
    s.amplitude = 3.0;
    s.f_low = 5.0;
    s.f_high = 200.0;
    s.seed = 42;
    char err[256];
    sim_exc *e = sim_exc_create(&s, 1, 1e-3, 0, err, sizeof err);
    assert_non_null(e);
    double sum = 0, sum2 = 0;
    size_t n = 200000;
    for (uint64_t k = 0; k < n; k++) {
        sim_exc_begin_sample(e, k);
        double v = sim_exc_sample_value(e);
        sum += v;
        sum2 += v * v;
    }
    double mean = sum / n, sd = sqrt(sum2 / n - mean * mean);
    print_message("noise: mean %.4f, std %.4f (amplitude 3)\n", mean, sd);
    assert_true(fabs(sd - 3.0) < 0.09);
    assert_true(fabs(mean) < 0.05);
    sim_exc_destroy(e);
}

/* linear sweep: the derivative of the phase is 2 pi f(t); the zero-crossing count over
 * one sweep 10 -> 50 Hz in 2 s is 2 * (mean frequency 30 Hz) * 2 s = 120 */
static void test_sweep(void **state)
{
    (void)state;
    sim_exc_spec s;
    sim_exc_spec_init(&s, SIM_EXC_SWEEP_LINEAR);
    s.f_start = 10.0;
    s.f_stop = 50.0;
    s.sweep_time = 2.0;
    char err[256];
    sim_exc *e = sim_exc_create(&s, 1, 1e-4, 1, err, sizeof err);
    assert_non_null(e);
    int crossings = 0;
    double prev = 0;
    for (uint64_t k = 0; k < 20000; k++) {
        sim_exc_begin_sample(e, k);
        double v = sim_exc_sample_value(e);
        if (k > 0 && ((prev < 0) != (v < 0))) crossings++;
        prev = v;
    }
    assert_true(abs(crossings - 120) <= 1);
    sim_exc_destroy(e);
}

static void test_bad_specs(void **state)
{
    (void)state;
    sim_exc_spec s;
    char err[256];
    sim_exc_spec_init(&s, SIM_EXC_SINE);
    s.frequency = 600.0;
    assert_null(sim_exc_create(&s, 1, 1e-3, 0, err, sizeof err));
    assert_non_null(strstr(err, "Nyquist"));
    sim_exc_spec_init(&s, SIM_EXC_PRBS);
    s.prbs_order = 40;
    assert_null(sim_exc_create(&s, 1, 1e-3, 0, err, sizeof err));
    assert_non_null(strstr(err, "order = 40"));
    sim_exc_spec_init(&s, SIM_EXC_SWEEP_LOG);
    s.f_start = 10;
    s.f_stop = 10;
    s.sweep_time = 1;
    assert_null(sim_exc_create(&s, 1, 1e-3, 0, err, sizeof err));
    assert_null(sim_exc_create(&s, 1, -1.0, 0, err, sizeof err));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_prbs_maximal), cmocka_unit_test(test_triangle_zoh), cmocka_unit_test(test_noise_std),
        cmocka_unit_test(test_sweep),        cmocka_unit_test(test_bad_specs),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
