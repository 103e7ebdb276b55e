// rt_kf_no_alloc.cpp: vibid_kfrls_step and its getters allocate nothing (both methods,
// with and without inputs, on every path: measurement, missing sample, NaN rejection,
// divergence). Same detectors as tests/lib/rt_no_alloc.cpp (copied from there).
//
// Linked against vibid_rtcheck (the library built with EIGEN_RUNTIME_NO_MALLOC and
// assertions on) with -Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc, so that every
// malloc/calloc/realloc call made from the library's objects or this file goes through
// the counters below; operator new is replaced too. Inside the armed window Eigen's own
// check is also switched off (set_is_malloc_allowed(false)): any Eigen heap allocation
// then fails an assertion and aborts the test. Allocations made inside the C library
// itself (e.g. by printf) are not visible to --wrap; the library's error paths only
// format into a fixed buffer.
//
// The test proves both detectors can fire: a deliberate malloc and operator new inside
// the armed window are counted, and a forked child that allocates an Eigen matrix with
// allocation forbidden dies of the assertion.

// This file must see the same Eigen inline functions as the library objects, which
// are compiled with assertions on (-UNDEBUG): with NDEBUG here, the linker could keep
// this file's copy of Eigen's aligned_malloc, without the check, for the whole program.
#undef NDEBUG

#include <Eigen/Core>

#include <cmath>
#include <csignal>
#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <new>

#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>

extern "C" {
#include <setjmp.h>
#include <stdarg.h>
#include <stdint.h>
#include <cmocka.h>
}

#include <vibid/io_form.h>
#include <vibid/kf_rls.h>

#include "../support/rt_alloc_counter.hpp"

namespace {

double value(std::size_t k, std::size_t i) { return std::sin(0.37 * static_cast<double>(k) + 1.3 * static_cast<double>(i)); }

// n = 4 states, 2 measurements, 1 input, rows 2..3 free: EKF dimension 4 + 2 * 5 = 14.
void run(vibid_kfrls_method method) {
    vibid_kfrls_config cfg;
    vibid_kfrls_config_init(&cfg, 4, 2, 1);
    cfg.first_free_row = 2;
    cfg.method = method;
    cfg.nis_limit = 1e30;  // any data; the divergence path is exercised by state_limit below
    cfg.state_limit = 1e3;
    double U[8] = {1, 0, 0, 1, 0, 0, 0, 0};
    double Rb[16] = {0};
    Rb[10] = Rb[15] = 1e-2;
    double Rv[4] = {1e-2, 0, 0, 1e-2};
    vibid_kfrls *kf = vibid_kfrls_create(&cfg, U, Rb, Rv);
    assert_non_null(kf);
    double G0[16] = {1, 0, -0.1, 0, 0, 1, 0, -0.1, 0.05, 0, 0.9, 0, 0, 0.05, 0, 0.9};
    double H0[4] = {0, 0, 0.05, 0.05};
    double S0[16] = {0};
    for (int i = 0; i < 4; ++i) S0[i * 5] = 1.0;
    double P[25] = {0};
    for (int i = 0; i < 5; ++i) P[i * 6] = 0.1;
    assert_int_equal(vibid_kfrls_start(kf, G0, H0, nullptr, S0, P), VIBID_OK);
    double x[4], S[16], G[16], H[4], se[10], z[2], u[1];
    vibid_kfrls_stats st;
    arm();
    int n_ok = 0;
    for (std::size_t k = 0; k < 500; ++k) {
        u[0] = value(k, 0);
        z[0] = 0.1 * value(k, 1);
        z[1] = 0.1 * value(k, 2);
        const bool missing = k % 7 == 3;
        if (vibid_kfrls_step(kf, u, missing ? nullptr : z) == VIBID_OK) ++n_ok;
        vibid_kfrls_state(kf, x, S);
        vibid_kfrls_model(kf, G, H);
        vibid_kfrls_param_stderr(kf, se);
        vibid_kfrls_get_stats(kf, &st);
    }
    z[0] = NAN;
    const vibid_status s_nan = vibid_kfrls_step(kf, u, z);
    // Divergence path: a wild measurement drives the state beyond state_limit.
    z[0] = 1e9;
    z[1] = 1e9;
    vibid_status s_div = VIBID_OK;
    for (int i = 0; i < 10 && s_div == VIBID_OK; ++i) s_div = vibid_kfrls_step(kf, u, z);
    const vibid_status s_after = vibid_kfrls_step(kf, u, z);
    const vibid_status s_reset = vibid_kfrls_reset(kf);
    // The I/O-form regressor (the per-sample part of the recursive I/O form).
    vibid_ioform_config ic;
    vibid_ioform_config_init(&ic, 2, 2, 1);
    double zw[6] = {1, 2, 3, 4, 5, 6}, uw[2] = {0.5, -0.5}, xr[12], yr[2];
    const vibid_status s_reg = vibid_ioform_regressor(&ic, zw, uw, xr, yr);
    zw[2] = NAN;
    const vibid_status s_reg_nan = vibid_ioform_regressor(&ic, zw, uw, xr, yr);
    const std::size_t n = disarm();
    assert_int_equal(s_reg, VIBID_OK);
    assert_int_equal(s_reg_nan, VIBID_E_NONFINITE);
    assert_true(xr[0] == -1.0 && xr[1] == -3.0 && yr[0] == 5.0 && yr[1] == 6.0);
    assert_int_equal(n_ok, 500);
    assert_int_equal(s_nan, VIBID_E_NONFINITE);
    assert_int_equal(s_div, VIBID_E_DIVERGED);
    assert_int_equal(s_after, VIBID_E_DIVERGED);
    assert_int_equal(s_reset, VIBID_OK);
    assert_int_equal(n, 0);
    vibid_kfrls_destroy(kf);
}

void test_paper_no_alloc(void **state) {
    (void)state;
    run(VIBID_KFRLS_PAPER);
}
void test_ekf_no_alloc(void **state) {
    (void)state;
    run(VIBID_KFRLS_EKF);
}

}  // namespace

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_counters_fire),
        cmocka_unit_test(test_paper_no_alloc),
        cmocka_unit_test(test_ekf_no_alloc),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
