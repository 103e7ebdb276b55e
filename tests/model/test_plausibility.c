/* test_plausibility.c: vibid/plausibility.h, the one rule for physically impossible
 * estimates. Every threshold is the header's own (<= 0, >= f_a / 2, < 0, >= 1), so the
 * boundary cases are tested at the exact boundary value (exactly representable doubles).
 * Tolerances: only where a modal computation is compared with its closed form (single
 * degree of freedom: f = sqrt(k / m) / (2 pi), zeta = d / (2 sqrt(k m))): 1e-12 relative,
 * some hundred times the rounding of the 2 x 2 state-matrix eigenvalue solve. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <vibid/vibid.h>

#include "../support/example1_model.h"

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

#define CONTAINS(hay, needle)                                                                  \
    do {                                                                                       \
        if (!strstr((hay), (needle))) {                                                        \
            print_error("\"%s\" does not contain \"%s\"\n", (hay), (needle));                 \
            fail();                                                                            \
        }                                                                                      \
    } while (0)

/* One degree of freedom, everything unknown: mass m, damper d and spring k to ground, a
 * cubic spring eps and an input of gain b. */
static vibid_model *sdof(double mass, double d, double k) {
    vibid_model *m = vibid_model_create();
    size_t n = 0;
    assert_int_equal(vibid_model_add_node(m, "m", mass, 1, &n), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "d", VIBID_ELEMENT_DAMPER, n, VIBID_GROUND, d, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "k", VIBID_ELEMENT_SPRING, n, VIBID_GROUND, k, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "eps", VIBID_ELEMENT_CUBIC_SPRING, n, VIBID_GROUND, 1e9, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_input(m, "f", n, 1.0, 1, NULL), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, n, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    return m;
}

/* Checks theta with the modes vibid_model_modal gives for it. */
static unsigned check_theta(const vibid_model *m, double h, const double *theta, const vibid_plausibility_ref *ref,
                            unsigned *pf, unsigned *mf, char *why, size_t cap) {
    double f[8], z[8];
    vibid_model_dims dims;
    assert_int_equal(vibid_model_get_dims(m, &dims), VIBID_OK);
    /* impossible values may well give an unstable model (modes written all the same) */
    vibid_status s = vibid_model_modal(m, theta, NULL, f, NULL, z, NULL, NULL, NULL);
    assert_true(s == VIBID_OK || s == VIBID_E_UNSTABLE);
    unsigned flags = 12345;
    assert_int_equal(vibid_plausibility_check(m, h, theta, f, z, dims.n_dof, ref, &flags, pf, mf, why, cap), VIBID_OK);
    return flags;
}

static void test_truth_is_plausible(void **state) {
    (void)state;
    vibid_model *m = example1_model(0);
    vibid_plausibility_ref ref;
    assert_int_equal(vibid_plausibility_ref_init(m, NULL, &ref), VIBID_OK);
    assert_int_equal(ref.zeta_rule, 1);
    assert_string_equal(ref.zeta_rule_off, "");
    assert_int_equal(ref.n_modes, 2);
    assert_int_equal(ref.n_params, 3);
    /* the reference is vibid_model_modal at the nominal values, bit for bit (same code);
     * example 1's modes are 22.78 / 48.15 Hz, zeta 0.0653 / 0.0435 (README: 22.8, 48.2,
     * 0.065, 0.044), checked to the last digit given here */
    double f[2], z[2];
    assert_int_equal(vibid_model_modal(m, NULL, NULL, f, NULL, z, NULL, NULL, NULL), VIBID_OK);
    assert_memory_equal(ref.freq_hz, f, sizeof f);
    assert_memory_equal(ref.zeta, z, sizeof z);
    assert_true(fabs(f[0] - 22.78) < 0.005 && fabs(f[1] - 48.15) < 0.005);
    assert_true(fabs(z[0] - 0.0653) < 5e-5 && fabs(z[1] - 0.0435) < 5e-5);
    const double truth[3] = {2.5e5, 300.0, 1.5e6};
    unsigned pf[3] = {9, 9, 9}, mf[2] = {9, 9};
    char why[256] = "junk";
    assert_int_equal(check_theta(m, 1.0 / 2000.0, truth, &ref, pf, mf, why, sizeof why), 0u);
    assert_int_equal(pf[0] | pf[1] | pf[2] | mf[0] | mf[1], 0u);
    assert_string_equal(why, "");
    vibid_model_destroy(m);
}

/* The row: a negative stiffness gives a mode at 0 Hz with zeta = 1 (modal.h). */
static void test_negative_stiffness(void **state) {
    (void)state;
    vibid_model *m = example1_model(0);
    vibid_plausibility_ref ref;
    assert_int_equal(vibid_plausibility_ref_init(m, NULL, &ref), VIBID_OK);
    const double theta[3] = {2.5e5, 300.0, -18981.0};
    unsigned pf[3], mf[2];
    char why[512];
    unsigned flags = check_theta(m, 1.0 / 2000.0, theta, &ref, pf, mf, why, sizeof why);
    assert_int_equal(pf[0], 0u);
    assert_int_equal(pf[1], 0u);
    assert_int_equal(pf[2], VIBID_IMPLAUSIBLE_STIFFNESS);
    /* mode 1 at 0 Hz, zeta 1, where the nominal mode 1 (22.8 Hz) is underdamped */
    assert_int_equal(mf[0], VIBID_IMPLAUSIBLE_FREQ_ZERO | VIBID_IMPLAUSIBLE_OVERDAMPED);
    assert_int_equal(mf[1], 0u);
    assert_int_equal(flags, VIBID_IMPLAUSIBLE_STIFFNESS | VIBID_IMPLAUSIBLE_FREQ_ZERO | VIBID_IMPLAUSIBLE_OVERDAMPED);
    CONTAINS(why, "c2 = -18981 N/m <= 0 (stiffness must be positive)");
    CONTAINS(why, "; mode 1 at 0 Hz <= 0");
    CONTAINS(why, "mode 1: zeta = 1 >= 1");
    vibid_model_destroy(m);
}

/* Negative damping: the damper is flagged and both modes become unstable (zeta < 0). */
static void test_negative_damping(void **state) {
    (void)state;
    vibid_model *m = example1_model(0);
    const double theta[3] = {2.5e5, -50.0, 1.5e6};
    unsigned pf[3], mf[2];
    char why[512];
    unsigned flags = check_theta(m, 1.0 / 2000.0, theta, NULL, pf, mf, why, sizeof why);
    assert_int_equal(pf[1], VIBID_IMPLAUSIBLE_DAMPING);
    assert_int_equal(pf[0] | pf[2], 0u);
    assert_int_equal(mf[0], VIBID_IMPLAUSIBLE_ZETA_NEGATIVE);
    assert_int_equal(mf[1], VIBID_IMPLAUSIBLE_ZETA_NEGATIVE);
    assert_int_equal(flags, VIBID_IMPLAUSIBLE_DAMPING | VIBID_IMPLAUSIBLE_ZETA_NEGATIVE);
    CONTAINS(why, "d = -50 N s/m <= 0 (damping must be positive)");
    CONTAINS(why, "(unstable)");
    /* zero counts as impossible too (the element exists); no mode is flagged for it:
     * the undamped modes come out at zeta ~ -3.6e-15 / +2.2e-14, inside the 1e-6 margin */
    const double zero[3] = {2.5e5, 0.0, 1.5e6};
    flags = check_theta(m, 1.0 / 2000.0, zero, NULL, pf, mf, why, sizeof why);
    assert_int_equal(flags, VIBID_IMPLAUSIBLE_DAMPING);
    CONTAINS(why, "d = 0 N s/m <= 0");
    vibid_model_destroy(m);
}

/* Masses; cubic coefficients and gains may have any sign; the closed-form reference. */
static void test_sdof_signs_and_reference(void **state) {
    (void)state;
    vibid_model *m = sdof(2.0, 8.0, 800.0); /* f = sqrt(400) / 2 pi, zeta = 8 / (2 * 40) = 0.1 */
    vibid_plausibility_ref ref;
    assert_int_equal(vibid_plausibility_ref_init(m, NULL, &ref), VIBID_OK);
    assert_int_equal(ref.zeta_rule, 1);
    assert_true(fabs(ref.freq_hz[0] / (20.0 / (2.0 * M_PI)) - 1.0) < 1e-12);
    assert_true(fabs(ref.zeta[0] / 0.1 - 1.0) < 1e-12);
    /* theta order: m, d, k, eps, f (masses, elements, gains) */
    unsigned pf[5], mf[1];
    char why[512];
    const double soft[5] = {2.0, 8.0, 800.0, -3e9, -1.5};
    assert_int_equal(check_theta(m, 1e-3, soft, &ref, pf, mf, why, sizeof why), 0u);
    const double neg_mass[5] = {-2.0, 8.0, 800.0, 1e9, 1.0};
    unsigned flags = check_theta(m, 1e-3, neg_mass, &ref, pf, mf, why, sizeof why);
    assert_int_equal(pf[0], VIBID_IMPLAUSIBLE_MASS);
    assert_int_equal(pf[1] | pf[2] | pf[3] | pf[4], 0u);
    assert_true(flags & VIBID_IMPLAUSIBLE_MASS);
    CONTAINS(why, "m = -2 kg <= 0 (mass must be positive)");
    /* A zero mass: the modal computation fails (singular M); the caller passes NaN modes. */
    const double zero_mass[5] = {0.0, 8.0, 800.0, 1e9, 1.0};
    const double nf = NAN, nz = NAN;
    assert_int_equal(vibid_plausibility_check(m, 1e-3, zero_mass, &nf, &nz, 1, &ref, &flags, pf, mf, why, sizeof why),
                     VIBID_OK);
    assert_int_equal(flags, VIBID_IMPLAUSIBLE_MASS | VIBID_IMPLAUSIBLE_NONFINITE);
    assert_int_equal(mf[0], VIBID_IMPLAUSIBLE_NONFINITE);
    CONTAINS(why, "m = 0 kg <= 0");
    CONTAINS(why, "mode 1: f = nan Hz, zeta = nan (not finite)");
    /* a non-finite parameter */
    const double nan_k[5] = {2.0, 8.0, NAN, 1e9, 1.0};
    assert_int_equal(vibid_plausibility_check(m, 1e-3, nan_k, NULL, NULL, 0, &ref, &flags, pf, NULL, why, sizeof why),
                     VIBID_OK);
    assert_int_equal(flags, VIBID_IMPLAUSIBLE_NONFINITE);
    assert_int_equal(pf[2], VIBID_IMPLAUSIBLE_NONFINITE);
    CONTAINS(why, "k = nan is not finite");
    vibid_model_destroy(m);
}

/* Frequency and damping-ratio rules at their exact boundaries (given modes, no theta). */
static void test_mode_boundaries(void **state) {
    (void)state;
    vibid_model *m = example1_model(0);
    vibid_plausibility_ref ref;
    assert_int_equal(vibid_plausibility_ref_init(m, NULL, &ref), VIBID_OK);
    const double h = 1.0 / 64.0; /* Nyquist exactly 32 Hz */
    unsigned flags, mf[2];
    char why[512];
    double f[2] = {31.999999, 32.0}, z[2] = {0.999999, 1.0};
    assert_int_equal(vibid_plausibility_check(m, h, NULL, f, z, 2, &ref, &flags, NULL, mf, why, sizeof why),
                     VIBID_OK);
    assert_int_equal(mf[0], 0u);
    assert_int_equal(mf[1], VIBID_IMPLAUSIBLE_FREQ_NYQUIST | VIBID_IMPLAUSIBLE_OVERDAMPED);
    CONTAINS(why, "mode 2 at 32 Hz >= Nyquist 32 Hz");
    CONTAINS(why, "mode 2: zeta = 1 >= 1 (reference mode 2 at 48.");
    /* f = 0 exactly; zeta just beyond and just within the -1e-6 rounding margin;
     * sample_time 0 skips the Nyquist rule */
    f[0] = 0.0;
    f[1] = 1e9;
    z[0] = -0.99e-6;
    z[1] = -1.01e-6;
    assert_int_equal(vibid_plausibility_check(m, 0.0, NULL, f, z, 2, NULL, &flags, NULL, mf, why, sizeof why),
                     VIBID_OK);
    assert_int_equal(mf[0], VIBID_IMPLAUSIBLE_FREQ_ZERO);
    assert_int_equal(mf[1], VIBID_IMPLAUSIBLE_ZETA_NEGATIVE);
    CONTAINS(why, "mode 2: zeta = -1.01e-06 < 0 (unstable)");
    /* without a reference the zeta >= 1 rule is off */
    z[0] = z[1] = 2.0;
    f[0] = 10.0;
    f[1] = 20.0;
    assert_int_equal(vibid_plausibility_check(m, h, NULL, f, z, 2, NULL, &flags, NULL, mf, why, sizeof why), VIBID_OK);
    assert_int_equal(flags, 0u);
    vibid_model_destroy(m);
}

/* Incomplete nominal values: the reference says why and the zeta rule is skipped; a
 * nominally overdamped mode may stay overdamped. */
static void test_reference_incomplete_or_overdamped(void **state) {
    (void)state;
    vibid_model *m = example1_model(1); /* c1 nominal 0 = not given */
    vibid_plausibility_ref ref;
    assert_int_equal(vibid_plausibility_ref_init(m, NULL, &ref), VIBID_OK);
    assert_int_equal(ref.zeta_rule, 0);
    CONTAINS(ref.zeta_rule_off, "nominal value of c1 is not given (0)");
    assert_true(isnan(ref.zeta[0]));
    unsigned flags;
    double f[2] = {10.0, 20.0}, z[2] = {1.5, 0.1};
    assert_int_equal(vibid_plausibility_check(m, 1e-3, NULL, f, z, 2, &ref, &flags, NULL, NULL, NULL, 0), VIBID_OK);
    assert_int_equal(flags, 0u);
    /* reference values given by the caller complete it */
    const double theta_ref[3] = {2.5e5, 300.0, 1.5e6};
    assert_int_equal(vibid_plausibility_ref_init(m, theta_ref, &ref), VIBID_OK);
    assert_int_equal(ref.zeta_rule, 1);
    assert_int_equal(vibid_plausibility_check(m, 1e-3, NULL, f, z, 2, &ref, &flags, NULL, NULL, NULL, 0), VIBID_OK);
    assert_int_equal(flags, VIBID_IMPLAUSIBLE_OVERDAMPED);
    const double bad_ref[3] = {2.5e5, -1.0, 1.5e6};
    assert_int_equal(vibid_plausibility_ref_init(m, bad_ref, &ref), VIBID_OK);
    assert_int_equal(ref.zeta_rule, 0);
    CONTAINS(ref.zeta_rule_off, "reference value of d is not positive");
    vibid_model_destroy(m);
    /* single degree of freedom with zeta = 100 / (2 sqrt(800 * 2)) = 1.25: overdamped by design */
    m = sdof(2.0, 100.0, 800.0);
    assert_int_equal(vibid_plausibility_ref_init(m, NULL, &ref), VIBID_OK);
    assert_int_equal(ref.zeta_rule, 1);
    assert_true(fabs(ref.zeta[0] / 1.25 - 1.0) < 1e-12);
    double f1 = 3.0, z1 = 1.3;
    assert_int_equal(vibid_plausibility_check(m, 1e-3, NULL, &f1, &z1, 1, &ref, &flags, NULL, NULL, NULL, 0),
                     VIBID_OK);
    assert_int_equal(flags, 0u);
    vibid_model_destroy(m);
}

/* Full-matrix model: only the diagonal entries of M, D, C are sign-constrained. */
static void test_full_matrix_diagonal_only(void **state) {
    (void)state;
    /* M = diag(10, 20), D = [[3, -3], [-3, 3]], C = [[2.5e5, -2.5e5], [-2.5e5, 1.75e6]] */
    const double M[4] = {10, 0, 0, 20}, D[4] = {3, -3, -3, 3}, C[4] = {2.5e5, -2.5e5, -2.5e5, 1.75e6};
    const double B[2] = {1, 0};
    vibid_model *m = vibid_model_create();
    assert_int_equal(vibid_model_set_matrices(m, 2, 1, M, D, C, B, 4u /* C unknown */), VIBID_OK);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    vibid_param_info pi;
    const char *names[3] = {"C1_1", "C1_2", "C2_2"}; /* names of the safe set: CSV columns */
    for (size_t k = 0; k < 3; k++) {
        assert_int_equal(vibid_model_param_info(m, k, &pi), VIBID_OK);
        assert_string_equal(pi.name, names[k]);
    }
    unsigned pf[3], flags;
    char why[256];
    /* the negative coupling C1_2 is fine */
    const double theta[3] = {2.5e5, -2.5e5, 1.75e6};
    assert_int_equal(vibid_plausibility_check(m, 1e-3, theta, NULL, NULL, 0, NULL, &flags, pf, NULL, why, sizeof why),
                     VIBID_OK);
    assert_int_equal(flags, 0u);
    /* a positive coupling is fine too; a negative diagonal entry is not */
    const double bad[3] = {2.5e5, 1e3, -5.0};
    assert_int_equal(vibid_plausibility_check(m, 1e-3, bad, NULL, NULL, 0, NULL, &flags, pf, NULL, why, sizeof why),
                     VIBID_OK);
    assert_int_equal(pf[0] | pf[1], 0u);
    assert_int_equal(pf[2], VIBID_IMPLAUSIBLE_STIFFNESS);
    assert_string_equal(why, "C2_2 = -5 N/m <= 0 (stiffness must be positive)");
    vibid_model_destroy(m);
}

/* Bad arguments: status, the function and argument named, outputs untouched. */
static void test_errors(void **state) {
    (void)state;
    vibid_model *m = example1_model(0), *other = sdof(1.0, 1.0, 1.0), *open = vibid_model_create();
    vibid_plausibility_ref ref, zeroed;
    memset(&zeroed, 0, sizeof zeroed);
    assert_int_equal(vibid_plausibility_ref_init(m, NULL, &ref), VIBID_OK);
    const double theta[3] = {1, 1, 1}, f[2] = {10, 20}, z[2] = {0.1, 0.1};
    unsigned flags = 77, pf[3] = {5, 5, 5};
    char why[32] = "untouched";
#define BAD(call, status, needle)                                                 \
    do {                                                                          \
        assert_int_equal((call), (status));                                       \
        CONTAINS(vibid_last_error(), "vibid_plausibility_check: ");               \
        CONTAINS(vibid_last_error(), (needle));                                   \
        assert_int_equal(flags, 77u);                                             \
        assert_int_equal(pf[0], 5u);                                              \
        assert_string_equal(why, "untouched");                                    \
    } while (0)
    BAD(vibid_plausibility_check(NULL, 1e-3, theta, f, z, 2, &ref, &flags, pf, NULL, why, sizeof why),
        VIBID_E_NULL_ARGUMENT, "model is NULL");
    BAD(vibid_plausibility_check(m, 1e-3, theta, f, z, 2, &ref, NULL, pf, NULL, why, sizeof why),
        VIBID_E_NULL_ARGUMENT, "flags_out is NULL");
    BAD(vibid_plausibility_check(open, 1e-3, theta, f, z, 2, &ref, &flags, pf, NULL, why, sizeof why), VIBID_E_STATE,
        "not finalized");
    BAD(vibid_plausibility_check(m, -1e-3, theta, f, z, 2, &ref, &flags, pf, NULL, why, sizeof why),
        VIBID_E_OUT_OF_RANGE, "sample_time = -0.001");
    BAD(vibid_plausibility_check(m, NAN, theta, f, z, 2, &ref, &flags, pf, NULL, why, sizeof why),
        VIBID_E_OUT_OF_RANGE, "sample_time = nan");
    BAD(vibid_plausibility_check(m, 1e-3, theta, f, z, 1, &ref, &flags, pf, NULL, why, sizeof why),
        VIBID_E_DIMENSION, "n_modes = 1");
    BAD(vibid_plausibility_check(m, 1e-3, theta, NULL, z, 2, &ref, &flags, pf, NULL, why, sizeof why),
        VIBID_E_NULL_ARGUMENT, "freq_hz is NULL");
    BAD(vibid_plausibility_check(m, 1e-3, theta, f, NULL, 2, &ref, &flags, pf, NULL, why, sizeof why),
        VIBID_E_NULL_ARGUMENT, "zeta is NULL");
    BAD(vibid_plausibility_check(m, 1e-3, theta, f, z, 2, &zeroed, &flags, pf, NULL, why, sizeof why),
        VIBID_E_DIMENSION, "ref was made for a model with 0 parameters");
    vibid_plausibility_ref ref_other;
    assert_int_equal(vibid_plausibility_ref_init(other, NULL, &ref_other), VIBID_OK);
    BAD(vibid_plausibility_check(m, 1e-3, theta, f, z, 2, &ref_other, &flags, pf, NULL, why, sizeof why),
        VIBID_E_DIMENSION, "ref was made for a model with 5 parameters and 1 modes");
#undef BAD
    /* ref_init: NULL arguments and an unfinalized model leave ref as it was */
    vibid_plausibility_ref keep = ref;
    assert_int_equal(vibid_plausibility_ref_init(NULL, NULL, &ref), VIBID_E_NULL_ARGUMENT);
    CONTAINS(vibid_last_error(), "vibid_plausibility_ref_init: model is NULL");
    assert_int_equal(vibid_plausibility_ref_init(m, NULL, NULL), VIBID_E_NULL_ARGUMENT);
    CONTAINS(vibid_last_error(), "ref is NULL");
    assert_int_equal(vibid_plausibility_ref_init(open, NULL, &ref), VIBID_E_STATE);
    assert_memory_equal(&keep, &ref, sizeof ref);
    vibid_model_destroy(m);
    vibid_model_destroy(other);
    vibid_model_destroy(open);
}

/* why is cut at why_cap - 1 and always terminated; NULL / 0 is allowed. */
static void test_why_truncation(void **state) {
    (void)state;
    vibid_model *m = example1_model(0);
    const double theta[3] = {-1.0, -2.0, -3.0};
    unsigned flags;
    char why[512];
    assert_int_equal(vibid_plausibility_check(m, 1e-3, theta, NULL, NULL, 0, NULL, &flags, NULL, NULL, why, sizeof why),
                     VIBID_OK);
    assert_string_equal(why, "c1 = -1 N/m <= 0 (stiffness must be positive); d = -2 N s/m <= 0 (damping must be "
                             "positive); c2 = -3 N/m <= 0 (stiffness must be positive)");
    char small[11];
    memset(small, 'x', sizeof small);
    assert_int_equal(vibid_plausibility_check(m, 1e-3, theta, NULL, NULL, 0, NULL, &flags, NULL, NULL, small, 10),
                     VIBID_OK);
    assert_string_equal(small, "c1 = -1 N");
    assert_int_equal(small[10], 'x'); /* nothing written beyond why_cap */
    char one[1] = {'x'};
    assert_int_equal(vibid_plausibility_check(m, 1e-3, theta, NULL, NULL, 0, NULL, &flags, NULL, NULL, one, 1),
                     VIBID_OK);
    assert_int_equal(one[0], '\0');
    assert_int_equal(vibid_plausibility_check(m, 1e-3, theta, NULL, NULL, 0, NULL, &flags, NULL, NULL, NULL, 0),
                     VIBID_OK);
    assert_int_equal(flags, VIBID_IMPLAUSIBLE_STIFFNESS | VIBID_IMPLAUSIBLE_DAMPING);
    vibid_model_destroy(m);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_truth_is_plausible),
        cmocka_unit_test(test_negative_stiffness),
        cmocka_unit_test(test_negative_damping),
        cmocka_unit_test(test_sdof_signs_and_reference),
        cmocka_unit_test(test_mode_boundaries),
        cmocka_unit_test(test_reference_incomplete_or_overdamped),
        cmocka_unit_test(test_full_matrix_diagonal_only),
        cmocka_unit_test(test_errors),
        cmocka_unit_test(test_why_truncation),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
