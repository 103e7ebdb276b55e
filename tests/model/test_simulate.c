/* test_simulate.c: the model's response to its inputs. vibid_model_simulate
 * (vibid/simulate.h), the model at given parameters driven by a capture's measured inputs,
 * against the examples' reference simulator (examples/support/stand_sim.h: RK4 from rest
 * with 20 steps per sample), and its refusals; vibid_model_frf (vibid/modal.h) against the
 * closed form of a single-DOF oscillator.
 * The smooth-input path (cubic Hermite between samples) is checked on a multisine capture
 * by the Python package's tests (python/tests/test_cli.py: NRMSE below 1e-5 at the truth). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <complex.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <vibid/vibid.h>
#include <vibid/stand_file.h>

#include "support/example_common.h"
#include "support/stand_sim.h"

#define N 6000
#define H (1.0 / 2000.0)

/* chain3: three masses, a held force on m3 (hold = "zoh"), displacement and acceleration of
 * every node; the truth from the file */
static vibid_stand *chain3(void) {
    vibid_stand *st = example_load_stand(VIBID_SOURCE_DIR "/examples/stands/chain3.cfg", -1);
    assert_non_null(st);
    return st;
}

/* A held force (a 7 Hz sine held over each sample), the stand at rest for the first 5
 * samples: the state at the start (sample 2) is then exactly the measured one (0, and the
 * five-point velocity of zeros is 0), so what differs from the reference run is RK4 with 8
 * instead of 20 steps per sample: a local error ~ (w h / 8)^5 at w h = 0.12 (37.5 Hz at
 * 2 kHz), ~1e-12 per step, growing to about 1e-10 over 6000 samples. Tolerance 1e-8
 * relative RMS on every simulated channel from the start on, 100 times that (measured
 * 2.6e-11 to 3.9e-11 on the displacements, 1.1e-10 to 2.7e-10 on the accelerations). */
static void test_held_force_follows_the_reference(void **state) {
    (void)state;
    vibid_stand *st = chain3();
    const vibid_model *m = vibid_stand_model(st);
    vibid_model_dims d;
    assert_int_equal(vibid_model_get_dims(m, &d), VIBID_OK);
    assert_int_equal(d.n_channels, 7);
    const size_t nc = d.n_channels, lead = 5;
    const double *truth = vibid_stand_true_values(st);
    double *ref = malloc((N - lead) * nc * sizeof *ref), *rec = calloc(N * nc, sizeof *rec),
           *out = malloc(N * nc * sizeof *out);
    stand_sim_config sc = {H, N - lead, 20, 1, 0.0, 0.0, 10.0, 7.0};
    assert_int_equal(stand_sim_run(m, truth, &sc, ref), 0);
    for (size_t c = 0; c < nc; c++) /* the capture: 5 samples at rest, then the reference run */
        memcpy(rec + lead + c * N, ref + c * (N - lead), (N - lead) * sizeof *rec);
    assert_int_equal(vibid_model_simulate(m, truth, H, N, rec, 8, out), VIBID_OK);
    for (size_t c = 0; c < nc; c++) {
        vibid_channel_info ci;
        assert_int_equal(vibid_model_channel_info(m, c, &ci), VIBID_OK);
        assert_true(isnan(out[0 + c * N]) && isnan(out[1 + c * N])); /* before the start */
        if (ci.kind == VIBID_CHANNEL_INPUT) {                          /* copied as measured */
            for (size_t k = 2; k < N; k++)
                assert_true(out[k + c * N] == rec[k + c * N]);
            continue;
        }
        double e2 = 0.0, s2 = 0.0;
        for (size_t k = 2; k < N; k++) {
            const double e = out[k + c * N] - rec[k + c * N];
            e2 += e * e;
            s2 += rec[k + c * N] * rec[k + c * N];
        }
        const double rel = sqrt(e2 / s2);
        printf("  channel %s: relative RMS error %.2e\n", ci.name, rel);
        assert_true(rel < 1e-8);
    }
    free(ref);
    free(rec);
    free(out);
    vibid_stand_destroy(st);
}

/* Refusals: each names what is wrong. */
static void test_refusals(void **state) {
    (void)state;
    vibid_stand *st = chain3();
    const vibid_model *m = vibid_stand_model(st);
    const double *truth = vibid_stand_true_values(st);
    double rec[7 * 8] = {0}, out[7 * 8];
    assert_int_equal(vibid_model_simulate(m, truth, H, 4, rec, 8, out), VIBID_E_INSUFFICIENT_DATA);
    assert_non_null(strstr(vibid_last_error(), "at least 5"));
    assert_int_equal(vibid_model_simulate(m, truth, H, 8, rec, 0, out), VIBID_E_OUT_OF_RANGE);
    assert_non_null(strstr(vibid_last_error(), "substeps"));
    assert_int_equal(vibid_model_simulate(m, truth, -H, 8, rec, 8, out), VIBID_E_OUT_OF_RANGE);
    assert_int_equal(vibid_model_simulate(m, truth, H, 8, NULL, 8, out), VIBID_E_NULL_ARGUMENT);
    vibid_stand_destroy(st);
}

/* A base that moves but whose displacement is not measured cannot drive the model. */
static void test_unmeasured_base_refused(void **state) {
    (void)state;
    vibid_model *m = vibid_model_create();
    size_t a;
    assert_int_equal(vibid_model_add_node(m, "m", 1.0, 0, &a), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "k", VIBID_ELEMENT_SPRING, a, VIBID_BASE, 1e4, 1), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, a, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    double th[1] = {1e4}, rec[8] = {0}, out[8];
    assert_int_equal(vibid_model_simulate(m, th, H, 8, rec, 4, out), VIBID_E_DIMENSION);
    assert_non_null(strstr(vibid_last_error(), "base"));
    vibid_model_destroy(m);
}

/* m y'' + d y' + k y = b u, u held: H_y(w) = b / (k - w^2 m + j w d), velocity j w H,
 * acceleration -w^2 H, the input channel 1; with the sample time the held input's columns
 * times e^(-j w h / 2) sin(w h / 2) / (w h / 2). Complex arithmetic of C99, to 1e-12. */
static void test_frf_single_dof(void **state) {
    (void)state;
    const double m = 2.0, k = 8.0e3, dmp = 4.0, b = 1.5, h = 1e-3;
    vibid_model *md = vibid_model_create();
    size_t a, u;
    assert_int_equal(vibid_model_add_node(md, "m", m, 0, &a), VIBID_OK);
    assert_int_equal(vibid_model_add_element(md, "k", VIBID_ELEMENT_SPRING, a, VIBID_GROUND, k, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(md, "d", VIBID_ELEMENT_DAMPER, a, VIBID_GROUND, dmp, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_input(md, "u", a, b, 0, &u), VIBID_OK);
    assert_int_equal(vibid_model_set_hold(md, u, VIBID_HOLD_ZOH), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(md, a,
                                              VIBID_MEASURE_DISPLACEMENT | VIBID_MEASURE_VELOCITY |
                                                  VIBID_MEASURE_ACCELERATION),
                     VIBID_OK);
    assert_int_equal(vibid_model_finalize(md), VIBID_OK);
    vibid_model_dims dm;
    assert_int_equal(vibid_model_get_dims(md, &dm), VIBID_OK);
    assert_int_equal(dm.n_channels, 4);
    const double th[2] = {k, dmp}, f[3] = {0.0, 10.07, 250.0};
    double re[3 * 4], im[3 * 4];
    for (int with_hold = 0; with_hold < 2; with_hold++) {
        assert_int_equal(vibid_model_frf(md, th, with_hold ? h : 0.0, 3, f, re, im), VIBID_OK);
        for (size_t q = 0; q < 3; q++) {
            const double w = 2.0 * M_PI * f[q], x = 0.5 * w * h;
            double complex Hy = b / (k - w * w * m + I * w * dmp);
            if (with_hold && w > 0.0)
                Hy *= cexp(-I * x) * sin(x) / x;
            for (size_t c = 0; c < 4; c++) {
                vibid_channel_info ci;
                assert_int_equal(vibid_model_channel_info(md, c, &ci), VIBID_OK);
                const double complex want = ci.kind == VIBID_CHANNEL_INPUT          ? 1.0
                                            : ci.kind == VIBID_CHANNEL_DISPLACEMENT ? Hy
                                            : ci.kind == VIBID_CHANNEL_VELOCITY     ? I * w * Hy
                                                                                    : -w * w * Hy;
                const double complex got = re[q + 3 * c] + I * im[q + 3 * c];
                assert_true(cabs(got - want) <= 1e-12 * cabs(want) + 1e-300);
            }
        }
    }
    const double bad = -1.0;
    assert_int_equal(vibid_model_frf(md, th, 0.0, 1, &bad, re, im), VIBID_E_OUT_OF_RANGE);
    assert_non_null(strstr(vibid_last_error(), "freq_hz[0]"));
    assert_int_equal(vibid_model_frf(md, th, -h, 1, f, re, im), VIBID_E_OUT_OF_RANGE);
    vibid_model_destroy(md);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_held_force_follows_the_reference),
        cmocka_unit_test(test_refusals),
        cmocka_unit_test(test_unmeasured_base_refused),
        cmocka_unit_test(test_frf_single_dof),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
