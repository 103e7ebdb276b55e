// rt_model_no_alloc.cpp: the per-sample paths of the model layer allocate nothing:
// vibid_model_forces, vibid_regressor_push and vibid_ident_push / vibid_ident_push_block
// (issue 3: "per-sample regressor building allocates nothing").
//
// Same machinery as tests/lib/rt_no_alloc.cpp: linked against vibid_rtcheck (the library
// built with EIGEN_RUNTIME_NO_MALLOC and assertions on) with
// -Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc, so every malloc/calloc/realloc made by
// the library's objects or this file goes through the counters below; operator new is
// replaced too. Inside the armed window Eigen's own check is switched off as well
// (set_is_malloc_allowed(false)): an Eigen heap allocation aborts the test. The first
// test proves that both detectors fire.
//
// Covered: the state-space estimator (EKF) from its start window on (run_ekf);
// central differences (displacement, acceleration, cubic spring, unknown
// input gain; with and without the pre-filter) and ZOH (1.16); the LS, IV and RLS
// estimators; the NaN gap path of every push; the twin's sync (deferred estimates) of the
// IV, RLS and automatic estimators, also across the pilot's replacement of the estimator.
// The estimates are not checked here (tests/model/test_model.c and tests/ident/test_twin.c
// do that), only that the calls succeed and allocate nothing.

// Must see the same Eigen inline functions as the library objects (compiled -UNDEBUG):
// see tests/lib/rt_no_alloc.cpp.
#undef NDEBUG

#include <Eigen/Core>

#include <cmath>
#include <csignal>
#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <new>
#include <initializer_list>
#include <cstring>
#include <vector>

#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>

extern "C" {
#include <setjmp.h>
#include <stdarg.h>
#include <stdint.h>
#include <cmocka.h>
}

#include <vibid/identify.h>
#include <vibid/model.h>
#include <vibid/regressor.h>

#include "../support/rt_alloc_counter.hpp"

namespace {

// Two-mass stand with everything the per-sample paths distinguish. cubic = true: central
// differences with a cubic spring m2-base, an accelerometer on m2 and an input of unknown
// gain on m1. cubic = false: the linear stand (ZOH needs a linear model and displacements).
// nominal = false: the unknowns get value 0 (no nominal value: the pre-filter pilot runs).
vibid_model *make_model(bool cubic, vibid_discretization disc, bool nominal = true) {
    const double v = nominal ? 1.0 : 0.0;
    vibid_model *m = vibid_model_create();
    assert_non_null(m);
    std::size_t n1 = 0, n2 = 0;
    assert_int_equal(vibid_model_add_node(m, "m1", 10.0, 0, &n1), VIBID_OK);
    assert_int_equal(vibid_model_add_node(m, "m2", 20.0, 0, &n2), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "c1", VIBID_ELEMENT_SPRING, n1, n2, v * 2.5e5, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "d", VIBID_ELEMENT_DAMPER, n1, n2, v * 300.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "c2", VIBID_ELEMENT_SPRING, n2, VIBID_BASE, v * 1.5e6, 1), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, n1, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, VIBID_BASE, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    if (cubic) {
        assert_int_equal(vibid_model_add_element(m, "eps", VIBID_ELEMENT_CUBIC_SPRING, n2, VIBID_BASE, 2e9, 1),
                         VIBID_OK);
        assert_int_equal(vibid_model_add_input(m, "u", n1, 3.0, 1, nullptr), VIBID_OK);
        assert_int_equal(vibid_model_set_measured(m, n2, VIBID_MEASURE_DISPLACEMENT | VIBID_MEASURE_ACCELERATION),
                         VIBID_OK);
    } else {
        assert_int_equal(vibid_model_set_measured(m, n2, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    }
    assert_int_equal(vibid_model_set_discretization(m, disc), VIBID_OK);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    return m;
}

// Deterministic, well-scaled channel values (any finite data exercise the same code).
double value(std::size_t k, std::size_t c) {
    return 1e-3 * std::sin(0.037 * static_cast<double>(k) * (1.0 + 0.31 * static_cast<double>(c)) + 0.7 * static_cast<double>(c));
}

void test_forces_no_alloc(void **state) {
    (void)state;
    vibid_model *m = make_model(true, VIBID_DISC_CENTRAL_DIFFERENCE);
    const double theta[5] = {2.5e5, 300.0, 1.5e6, 2e9, 3.0};
    double f[2] = {0, 0}, y[2], yd[2], base[2], u[1];
    double fsum = 0.0;
    std::size_t bad_status = 0;
    arm();
    for (std::size_t k = 0; k < 1000; ++k) {
        y[0] = value(k, 0);
        y[1] = value(k, 1);
        yd[0] = value(k, 2);
        yd[1] = value(k, 3);
        base[0] = value(k, 4);
        base[1] = value(k, 5);
        u[0] = value(k, 6);
        if (vibid_model_forces(m, (k % 2) ? theta : nullptr, y, yd, base, u, f) != VIBID_OK) ++bad_status;
        fsum += std::fabs(f[0]) + std::fabs(f[1]);
    }
    // Error path: the message is formatted into a fixed buffer.
    if (vibid_model_forces(m, theta, y, yd, nullptr, u, f) != VIBID_E_NULL_ARGUMENT) ++bad_status;
    const std::size_t n = disarm();
    assert_int_equal(bad_status, 0);
    assert_int_equal(n, 0);
    assert_true(fsum > 0.0);  // the calls computed something
    vibid_model_destroy(m);
}

void run_regressor(const vibid_model *m, double prefilter_hz) {
    vibid_regressor *g = vibid_regressor_create(m, 5e-4, prefilter_hz);
    assert_non_null(g);
    vibid_regressor_dims d{};
    assert_int_equal(vibid_regressor_get_dims(g, &d), VIBID_OK);
    vibid_model_dims md{};
    assert_int_equal(vibid_model_get_dims(m, &md), VIBID_OK);
    std::vector<double> x(d.n_regressors * d.n_equations), y(d.n_equations * d.n_outputs), ch(md.n_channels);
    std::size_t bad_status = 0, n_ready = 0;
    arm();
    for (std::size_t k = 0; k < 500; ++k) {
        for (std::size_t c = 0; c < ch.size(); ++c) ch[c] = value(k, c);
        if (k == 250) ch[0] = NAN;  // gap: VIBID_E_NONFINITE, then a restart
        int ready = 0;
        const vibid_status s = vibid_regressor_push(g, ch.data(), x.data(), y.data(), &ready);
        if (s != (k == 250 ? VIBID_E_NONFINITE : VIBID_OK)) ++bad_status;
        if (k == 250 && vibid_regressor_reset(g) != VIBID_OK) ++bad_status;
        n_ready += static_cast<std::size_t>(ready);
    }
    const std::size_t n = disarm();
    assert_int_equal(bad_status, 0);
    assert_int_equal(n, 0);
    // 499 good samples in two runs (250 + 249), each run's first 2 fill the window.
    assert_int_equal(n_ready, 499 - 4);
    vibid_regressor_destroy(g);
}

void test_regressor_no_alloc(void **state) {
    (void)state;
    vibid_model *cd = make_model(true, VIBID_DISC_CENTRAL_DIFFERENCE);
    vibid_model *zoh = make_model(false, VIBID_DISC_ZOH);
    run_regressor(cd, 0.0);
    run_regressor(cd, 150.0);
    run_regressor(zoh, 0.0);
    run_regressor(zoh, 150.0);
    vibid_model_destroy(cd);
    vibid_model_destroy(zoh);
}

void run_ident(const vibid_model *m, vibid_estimator est, double prefilter_hz) {
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 5e-4);
    cfg.estimator = est;
    cfg.prefilter_hz = prefilter_hz;
    cfg.forgetting = est == VIBID_ESTIMATOR_RLS || est == VIBID_ESTIMATOR_AUTO ? 0.999 : 1.0;
    if (est == VIBID_ESTIMATOR_IV) cfg.iv_lag = prefilter_hz > 0 ? 30 : 3;
    vibid_ident *id = vibid_ident_create(m, &cfg);
    assert_non_null(id);
    std::size_t nc = 0, p = 0;
    assert_int_equal(vibid_ident_dims(id, &nc, &p), VIBID_OK);
    const std::size_t nk = 400;
    std::vector<double> ch(nc), block(nk * nc);
    for (std::size_t k = 0; k < nk; ++k)
        for (std::size_t c = 0; c < nc; ++c) block[k + c * nk] = value(k + 1000, c);
    std::size_t bad_status = 0;
    // deferred estimates: the twin's sync copies without allocating (LS has no twin)
    vibid_ident *twin = est == VIBID_ESTIMATOR_LS ? nullptr : vibid_ident_twin_create(id);
    if (est != VIBID_ESTIMATOR_LS) assert_non_null(twin);
    arm();
    for (std::size_t k = 0; k < 600; ++k) {
        for (std::size_t c = 0; c < nc; ++c) ch[c] = value(k, c);
        if (k == 300) ch[nc - 1] = INFINITY;
        if (vibid_ident_push(id, ch.data()) != (k == 300 ? VIBID_E_NONFINITE : VIBID_OK)) ++bad_status;
        if (twin && k % 100 == 99 && vibid_ident_twin_sync(twin, id) != VIBID_OK) ++bad_status;
    }
    if (vibid_ident_push_block(id, nk, block.data()) != VIBID_OK) ++bad_status;
    if (vibid_ident_push(id, nullptr) != VIBID_E_NULL_ARGUMENT) ++bad_status;
    const std::size_t n = disarm();
    assert_int_equal(bad_status, 0);
    assert_int_equal(n, 0);
    // The samples arrived: 599 good ones pushed singly plus the block.
    std::vector<double> theta(p);
    vibid_ident_info info{};
    const vibid_status s = vibid_ident_estimate(id, theta.data(), nullptr, &info);
    assert_true(s == VIBID_OK || s == VIBID_E_NOT_IDENTIFIABLE || s == VIBID_E_NUMERICAL);
    if (s == VIBID_OK) assert_true(info.n_samples == 599 + nk);
    if (twin) {  // synced last at sample 599: it answers as the identification did then
        std::vector<double> tt(p);
        const vibid_status ts = vibid_ident_estimate(twin, tt.data(), nullptr, &info);
        assert_true(ts == VIBID_OK || ts == VIBID_E_NOT_IDENTIFIABLE || ts == VIBID_E_NUMERICAL);
        if (ts == VIBID_OK) assert_true(info.n_samples == 599);
    }
    vibid_ident_destroy(twin);
    vibid_ident_destroy(id);
}

// The automatic estimator on a stand without nominal values runs the pre-filter pilot
// (identify.h): every push allocates nothing but the one that ends it (4096 samples at
// 2 kHz), which chooses the cutoff and replays the pilot into the estimator it creates.
void test_ident_pilot_no_alloc(void **state) {
    (void)state;
    // No nominal value, so no natural frequency before the data.
    vibid_model *m = make_model(false, VIBID_DISC_CENTRAL_DIFFERENCE, false);
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 5e-4);
    vibid_ident *id = vibid_ident_create(m, &cfg);
    assert_non_null(id);
    std::size_t nc = 0;
    assert_int_equal(vibid_ident_dims(id, &nc, nullptr), VIBID_OK);
    std::vector<double> ch(nc);
    const std::size_t pilot = 4096;
    std::size_t bad_status = 0, allocs_pilot = 0, allocs_after = 0;
    vibid_ident *twin = vibid_ident_twin_create(id);
    assert_non_null(twin);
    auto push = [&](std::size_t k) {
        for (std::size_t c = 0; c < nc; ++c) ch[c] = value(k, c);
        if (vibid_ident_push(id, ch.data()) != VIBID_OK) ++bad_status;
        // and a twin's sync, before and after the pilot replaced the estimator
        if (k % 200 == 199 && vibid_ident_twin_sync(twin, id) != VIBID_OK) ++bad_status;
    };
    arm();
    for (std::size_t k = 0; k + 1 < pilot; ++k) push(k);
    allocs_pilot = disarm();
    push(pilot - 1);  // ends the pilot: allowed to allocate
    arm();
    for (std::size_t k = pilot; k < pilot + 2000; ++k) push(k);
    allocs_after = disarm();
    assert_int_equal(bad_status, 0);
    assert_int_equal(allocs_pilot, 0);
    assert_int_equal(allocs_after, 0);
    vibid_ident_config used;
    assert_int_equal(vibid_ident_get_config(id, &used), VIBID_OK);
    assert_true(used.prefilter_hz > 0.0);
    // The pilot ended: its choice (a new cutoff, or f_a/20 kept and why) is described.
    char why[4096];
    assert_int_equal(vibid_ident_describe(id, why, sizeof why, nullptr), VIBID_OK);
    assert_true(std::strstr(why, "(automatic, from the data") || std::strstr(why, "pre-filter after the first"));
    vibid_ident_destroy(twin);
    vibid_ident_destroy(id);
    vibid_model_destroy(m);
}

void test_ident_no_alloc(void **state) {
    (void)state;
    vibid_model *cd = make_model(true, VIBID_DISC_CENTRAL_DIFFERENCE);
    vibid_model *zoh = make_model(false, VIBID_DISC_ZOH);
    for (vibid_estimator est : {VIBID_ESTIMATOR_LS, VIBID_ESTIMATOR_IV, VIBID_ESTIMATOR_RLS, VIBID_ESTIMATOR_AUTO})
        for (double pf : {0.0, 150.0, -1.0 /* automatic */}) {
            run_ident(cd, est, pf);
            run_ident(zoh, est, pf);
        }
    vibid_model_destroy(cd);
    vibid_model_destroy(zoh);
}

// Stands for the state-space estimator (VIBID_ESTIMATOR_EKF): m1 displacement only, the
// base displacement measured, m2 without sensor (variant 0: smooth base, a disturbance of
// unknown intensity on m2, so that the start runs the likelihood search) or with only an
// accelerometer (variant 1: held base with a damper to it (velocity kicks), a cubic
// spring, an input of unknown gain on m1, declared sensor noise); variant 2: variant 0 with
// an accelerometer on m2 (for the KF+RLS, which needs every unknown on a measured node).
vibid_model *make_ekf_model(int variant) {
    vibid_model *m = vibid_model_create();
    assert_non_null(m);
    std::size_t n1 = 0, n2 = 0;
    assert_int_equal(vibid_model_add_node(m, "m1", 1.5, 0, &n1), VIBID_OK);
    assert_int_equal(vibid_model_add_node(m, "m2", 3.0, 0, &n2), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "c1", VIBID_ELEMENT_SPRING, n1, n2, 6e4, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "d1", VIBID_ELEMENT_DAMPER, n1, n2, 15.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "c2", VIBID_ELEMENT_SPRING, n2, VIBID_BASE, 1.2e5, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "d2", VIBID_ELEMENT_DAMPER, n2, VIBID_BASE, 30.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, n1, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, VIBID_BASE, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    if (variant != 1) {
        assert_int_equal(vibid_model_add_disturbance(m, "w", n2, 0.0, nullptr), VIBID_OK);
        if (variant == 2)
            assert_int_equal(vibid_model_set_measured(m, n2, VIBID_MEASURE_ACCELERATION), VIBID_OK);
    } else {
        assert_int_equal(vibid_model_set_hold(m, VIBID_BASE, VIBID_HOLD_ZOH), VIBID_OK);
        assert_int_equal(vibid_model_add_element(m, "eps", VIBID_ELEMENT_CUBIC_SPRING, n2, VIBID_BASE, 1e9, 1),
                         VIBID_OK);
        assert_int_equal(vibid_model_add_input(m, "u", n1, 2.0, 1, nullptr), VIBID_OK);
        assert_int_equal(vibid_model_set_measured(m, n2, VIBID_MEASURE_ACCELERATION), VIBID_OK);
        assert_int_equal(vibid_model_set_noise(m, n1, VIBID_MEASURE_DISPLACEMENT, 1e-6), VIBID_OK);
    }
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    return m;
}

// From the first sample: the start window fills and starts the filter (noise levels, the
// likelihood search, the pass over the window) inside the armed region, then filter
// steps, a gap, and estimates with covariance. Synthetic data do not fit the stand, so a
// divergence (restart from the start values, also allocation-free) is an accepted status.
void run_ekf(const vibid_model *m, vibid_estimator est, double forgetting) {
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 1e-3);
    cfg.estimator = est;
    cfg.forgetting = forgetting;
    vibid_ident *id = vibid_ident_create(m, &cfg);
    if (!id) fail_msg("vibid_ident_create: %s", vibid_last_error());
    std::size_t nc = 0, p = 0;
    assert_int_equal(vibid_ident_dims(id, &nc, &p), VIBID_OK);
    std::vector<double> ch(nc), theta(p), se(p), cov(p * p);
    std::size_t bad_status = 0, estimates = 0;
    arm();
    for (std::size_t k = 0; k < 1600; ++k) {
        for (std::size_t c = 0; c < nc; ++c) ch[c] = value(k, c);
        if (k == 1300) ch[0] = NAN;
        const vibid_status s = vibid_ident_push(id, ch.data());
        if (s != (k == 1300 ? VIBID_E_NONFINITE : VIBID_OK) && s != VIBID_E_DIVERGED) ++bad_status;
        if (k % 400 == 399) {
            vibid_ident_info info{};
            if (vibid_ident_estimate(id, theta.data(), se.data(), &info) == VIBID_OK) {
                ++estimates;
                if (vibid_ident_covariance(id, cov.data()) != VIBID_OK) ++bad_status;
            }
        }
    }
    const std::size_t n = disarm();
    assert_int_equal(bad_status, 0);
    assert_int_equal(n, 0);
    assert_int_equal(estimates, 4);
    vibid_ident_destroy(id);
}

// run_ekf on each model variant, without and with forgetting.
void run_variants(vibid_estimator est, std::initializer_list<int> variants) {
    for (int variant : variants) {
        vibid_model *m = make_ekf_model(variant);
        run_ekf(m, est, 1.0);
        run_ekf(m, est, 0.999);
        vibid_model_destroy(m);
    }
}

void test_ekf_no_alloc(void **state) {
    (void)state;
    run_variants(VIBID_ESTIMATOR_EKF, {0, 1});
}

// The KF+RLS (VIBID_ESTIMATOR_KF_RLS): the same path with the regression on the
// parameters (its scale pass at the start, its steps, its covariance in estimates).
void test_kf_rls_no_alloc(void **state) {
    (void)state;
    run_variants(VIBID_ESTIMATOR_KF_RLS, {1, 2});
}

}  // namespace

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_counters_fire),
        cmocka_unit_test(test_forces_no_alloc),
        cmocka_unit_test(test_regressor_no_alloc),
        cmocka_unit_test(test_ident_no_alloc),
        cmocka_unit_test(test_ident_pilot_no_alloc),
        cmocka_unit_test(test_ekf_no_alloc),
        cmocka_unit_test(test_kf_rls_no_alloc),
    };
    return cmocka_run_group_tests(tests, nullptr, nullptr);
}
