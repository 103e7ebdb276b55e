// rt_no_alloc.cpp: the per-sample functions allocate nothing, and a reported row
// (vibid/report.h) of a recursive estimator allocates nothing at all, its modes and their
// standard errors included.
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
#include <cstring>
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

#include <vibid/identify.h>
#include <vibid/iv.h>
#include <vibid/lsq.h>
#include <vibid/modal.h>
#include <vibid/model.h>
#include <vibid/oma.h>
#include <vibid/outlier.h>
#include <vibid/plausibility.h>
#include <vibid/report.h>
#include <vibid/rls.h>

#include "../support/rt_alloc_counter.hpp"
#include "../support/example1_model.h"

namespace {

vibid_rls *make_rls(vibid_rls_form form, std::size_t p, std::size_t q, std::size_t m) {
    vibid_rls_config cfg;
    vibid_rls_config_init(&cfg, p, q);
    cfg.n_equations = m;
    cfg.form = form;
    cfg.forgetting = 0.99;
    cfg.alpha = 1e-3;
    cfg.windup = VIBID_RLS_WINDUP_TRACE_BOUND;
    cfg.trace_max = static_cast<double>(p) / cfg.alpha;
    vibid_rls *rls = vibid_rls_create(&cfg);
    assert_non_null(rls);
    return rls;
}

// Deterministic, well-scaled data (no RNG needed: any finite values do).
double value(std::size_t k, std::size_t i) { return std::sin(0.37 * static_cast<double>(k) + 1.3 * static_cast<double>(i)); }

// Every per-sample RLS function, both forms, trace bound on, equation covariance on,
// the frozen path, the error paths, and the allocation-free configuration calls.
void test_rls_no_alloc(void **state) {
    (void)state;
    const std::size_t p = 12, q = 3, m = 3;
    const double Sigma[9] = {2.0, 0.5, 0.1, 0.5, 1.0, 0.2, 0.1, 0.2, 0.7};
    for (vibid_rls_form form : {VIBID_RLS_FORM_BIERMAN_UD, VIBID_RLS_FORM_COVARIANCE}) {
        vibid_rls *rls = make_rls(form, p, q, m);
        double x[p * m], y[m * q], yhat[m * q], theta[p * q], se[p * q], P[p * p], Se[q * q], P0[p * p];
        for (std::size_t i = 0; i < p * p; ++i) P0[i] = (i % (p + 1) == 0) ? 2.0 : 0.0;
        vibid_rls_stats st;
        std::size_t bad_status = 0;

        arm();
        if (vibid_rls_set_equation_covariance(rls, Sigma) != VIBID_OK) ++bad_status;
        if (vibid_rls_set_prior(rls, nullptr, P0) != VIBID_OK) ++bad_status;
        for (std::size_t k = 0; k < 300; ++k) {
            for (std::size_t i = 0; i < p * m; ++i) x[i] = value(k, i);
            // Long unexcited stretches so that the trace bound is active.
            if (k % 100 > 50)
                for (std::size_t i = 0; i < p * m; ++i) x[i] = 0.0;
            for (std::size_t i = 0; i < m * q; ++i) y[i] = value(k, i + 100);
            if (vibid_rls_set_adaptation(rls, k % 50 < 45) != VIBID_OK) ++bad_status;
            if (vibid_rls_update(rls, x, y) != VIBID_OK) ++bad_status;
            if (vibid_rls_predict(rls, x, yhat) != VIBID_OK) ++bad_status;
            if (vibid_rls_theta(rls, theta) != VIBID_OK) ++bad_status;
            if (vibid_rls_get_stats(rls, &st) != VIBID_OK) ++bad_status;
            if (k > 20) {
                if (vibid_rls_stderr(rls, se) != VIBID_OK) ++bad_status;
                if (vibid_rls_residual_covariance(rls, Se) != VIBID_OK) ++bad_status;
            }
            if (vibid_rls_covariance(rls, P) != VIBID_OK) ++bad_status;
        }
        // Error paths format a message; they must not allocate either.
        if (vibid_rls_set_adaptation(rls, 1) != VIBID_OK) ++bad_status;
        x[0] = NAN;
        if (vibid_rls_update(rls, x, y) != VIBID_E_NONFINITE) ++bad_status;
        x[0] = 1e200;
        if (vibid_rls_update(rls, x, y) != VIBID_E_NUMERICAL) ++bad_status;
        if (vibid_rls_update(rls, nullptr, y) != VIBID_E_NULL_ARGUMENT) ++bad_status;
        P0[0] = -1.0;
        if (vibid_rls_set_prior(rls, nullptr, P0) != VIBID_E_NUMERICAL) ++bad_status;
        if (vibid_rls_reset(rls) != VIBID_OK) ++bad_status;
        if (vibid_rls_set_equation_covariance(rls, nullptr) != VIBID_OK) ++bad_status;
        const std::size_t n = disarm();

        assert_int_equal(bad_status, 0);
        assert_int_equal(n, 0);
        assert_true(st.n_samples == 300);
        vibid_rls_destroy(rls);
    }
}

// The other estimators' per-sample functions: batch LS row accumulation and recursive IV.
void test_lsq_riv_no_alloc(void **state) {
    (void)state;
    const std::size_t p = 8, q = 2, rows = 16;
    vibid_lsq *lsq = vibid_lsq_create(p, q);
    assert_non_null(lsq);
    vibid_riv_config cfg;
    vibid_riv_config_init(&cfg, p, q);
    cfg.forgetting = 0.99;
    cfg.trace_bound = 1;
    vibid_riv *riv = vibid_riv_create(&cfg);
    assert_non_null(riv);
    double X[rows * p], Y[rows * q], w[rows], x[p], wi[p], y[q], theta[p * q];
    std::size_t bad_status = 0;

    arm();
    for (std::size_t k = 0; k < 200; ++k) {
        for (std::size_t i = 0; i < rows * p; ++i) X[i] = value(k, i);
        for (std::size_t i = 0; i < rows * q; ++i) Y[i] = value(k, i + 500);
        for (std::size_t i = 0; i < rows; ++i) w[i] = 1.0 + 0.5 * value(k, i + 900);
        if (vibid_lsq_add_rows(lsq, rows, X, Y, (k % 2) ? w : nullptr) != VIBID_OK) ++bad_status;
        for (std::size_t i = 0; i < p; ++i) {
            x[i] = value(k, i);
            wi[i] = value(k, i + 7);
        }
        for (std::size_t i = 0; i < q; ++i) y[i] = value(k, i + 300);
        if (vibid_riv_update(riv, x, wi, y) != VIBID_OK) ++bad_status;
        if (vibid_riv_theta(riv, theta) != VIBID_OK) ++bad_status;
    }
    X[0] = NAN;
    if (vibid_lsq_add_rows(lsq, rows, X, Y, nullptr) != VIBID_E_NONFINITE) ++bad_status;
    x[0] = NAN;
    if (vibid_riv_update(riv, x, wi, y) != VIBID_E_NONFINITE) ++bad_status;
    const std::size_t n = disarm();

    assert_int_equal(bad_status, 0);
    assert_int_equal(n, 0);
    vibid_lsq_destroy(lsq);
    vibid_riv_destroy(riv);
}

// The outlier test (vibid/outlier.h): pushes through the warm-up, clean samples, suspects
// taken out and accepted, missing values, the flush, the counters, the error paths.
void test_outlier_no_alloc(void **state) {
    (void)state;
    const std::size_t n = 4;
    vibid_outlier_config cfg;
    vibid_outlier_config_init(&cfg, n);
    vibid_outlier *det = vibid_outlier_create(&cfg);
    assert_non_null(det);
    double x[n], out[n];
    unsigned char mark[n];
    vibid_outlier_stats st;
    std::size_t bad_status = 0, released = 0;

    arm();
    for (std::size_t k = 0; k < 2000; ++k) {
        for (std::size_t i = 0; i < n; ++i) x[i] = value(k, i);
        if (k % 97 == 50) x[k % n] = 1e300;  // a glitch
        if (k % 89 == 0) x[1] += 50.0;       // a step that stays (accepted a sample late)
        if (k % 113 == 7) x[2] = NAN;        // a missing value
        std::size_t nr = 0, no = 0;
        if (vibid_outlier_push(det, x, &nr) != VIBID_OK) ++bad_status;
        for (std::size_t i = 0; i < nr; ++i)
            if (vibid_outlier_released(det, i, out, mark, &no) != VIBID_OK) ++bad_status;
        released += nr;
    }
    std::size_t nr = 0;
    if (vibid_outlier_flush(det, &nr) != VIBID_OK) ++bad_status;
    released += nr;
    if (vibid_outlier_get_stats(det, &st) != VIBID_OK) ++bad_status;
    if (vibid_outlier_push(det, nullptr, &nr) != VIBID_E_NULL_ARGUMENT) ++bad_status;
    if (vibid_outlier_released(det, 99, out, mark, nullptr) != VIBID_E_OUT_OF_RANGE) ++bad_status;
    if (vibid_outlier_reset(det) != VIBID_OK) ++bad_status;
    const std::size_t allocs = disarm();

    assert_int_equal(bad_status, 0);
    assert_int_equal(allocs, 0);
    assert_int_equal(released, 2000);
    assert_true(st.outlier_samples > 0);  // the glitches were found: the paths above ran
    vibid_outlier_destroy(det);
}

// Output-only modal identification's per-sample path (vibid/oma.h): samples through
// several block commits, gaps, the stats; the identification itself allocates by design.
void test_oma_push_no_alloc(void **state) {
    (void)state;
    const std::size_t n = 4;
    vibid_oma_config cfg;
    vibid_oma_config_init(&cfg, 100.0, n);
    cfg.block_rows = 6;
    cfg.block_samples = 100;
    cfg.max_blocks = 4;
    vibid_oma *oma = vibid_oma_create(&cfg);
    assert_non_null(oma);
    double x[n];
    std::size_t bad_status = 0;
    vibid_oma_stats st;
    arm();
    for (std::size_t k = 0; k < 1000; ++k) {  // 10 blocks: the window's ring wraps
        for (std::size_t i = 0; i < n; ++i) x[i] = value(k, i);
        if (k % 113 == 7) x[2] = NAN;  // a gap
        const vibid_status s = vibid_oma_push(oma, x);
        if (s != (k % 113 == 7 ? VIBID_E_NONFINITE : VIBID_OK)) ++bad_status;
    }
    if (vibid_oma_get_stats(oma, &st) != VIBID_OK) ++bad_status;
    if (vibid_oma_push(oma, nullptr) != VIBID_E_NULL_ARGUMENT) ++bad_status;
    const std::size_t allocs = disarm();
    assert_int_equal(bad_status, 0);
    assert_int_equal(allocs, 0);
    assert_int_equal(st.n_gaps, 9);
    assert_int_equal(st.blocks_complete, 4);
    assert_int_equal(vibid_oma_identify(oma), VIBID_OK);  // the sums are usable
    vibid_oma_destroy(oma);
}

// Counts allocations without Eigen's abort: for the calls a row makes that allocate by
// design (a regression estimator's estimate).
void count_only() {
    n_alloc = 0;
    armed = true;
}

// A reported row (vibid/report.h) adds no allocation to its estimator's: the report's own
// work (modes and their standard errors on the report's scratch, modal_work.hpp, the
// plausibility, the flags) allocates nothing, with Eigen's check armed
// (vibid_report_estimate); vibid_report_row of an RLS twin (vibidd's way) allocates exactly
// what its estimator's calls (estimate, covariance, quality) allocate when called one by
// one (the regression estimate's own scratch, identify.cpp), and gives the values of its
// parts (vibid_model_modal allocating its own scratch); a row without an estimate
// (vibid_report_no_estimate, and the error paths) allocates nothing at all.
void test_report_row_no_alloc(void **state) {
    (void)state;
    vibid_model *m = example1_model(0);
    const double h = 1e-3;
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, h);
    cfg.estimator = VIBID_ESTIMATOR_RLS;
    vibid_ident *id = vibid_ident_create(m, &cfg);
    assert_non_null(id);
    vibid_report *rep = vibid_report_create(m, h);
    assert_non_null(rep);
    // fixed arrays: example 1 has 3 channels, p = 3, n = 2 (std::vector's inlined delete
    // meets the replaced operator delete in -Wmismatched-new-delete at -O2)
    constexpr std::size_t nc = 3, p = 3, n = 2;
    std::size_t nc_id = 0, p_id = 0;
    assert_int_equal(vibid_ident_dims(id, &nc_id, &p_id), VIBID_OK);
    assert_int_equal(nc_id, nc);
    assert_int_equal(p_id, p);
    double ch[nc];
    for (std::size_t k = 0; k < 3000; ++k) {
        for (std::size_t c = 0; c < nc; ++c) ch[c] = value(k, c);
        assert_int_equal(vibid_ident_push(id, ch), VIBID_OK);
    }
    double theta[p], se[p], cov[p * p], f[n], fse[n], z[n], zse[n];
    vibid_report_row_out out{};
    out.theta = theta;
    out.se = se;
    out.freq = f;
    out.freq_se = fse;
    out.zeta = z;
    out.zeta_se = zse;
    out.cov = cov;

    // the parts, one by one
    double t2[p], s2[p], c2[p * p], f2[n], fse2[n], z2[n], zse2[n];
    unsigned found = 0;
    char why[1024];
    vibid_ident_quality q;
    // vibidd's way: the row of a twin synchronised at the sample the estimate is due
    // (identify.h), whose RLS estimate allocates nothing; a first row first: the twin's
    // lazily made buffers are not the row's
    vibid_ident *tw = vibid_ident_twin_create(id);
    assert_non_null(tw);
    assert_int_equal(vibid_ident_twin_sync(tw, id), VIBID_OK);
    (void)vibid_report_row(rep, tw, &out);
    assert_int_equal(vibid_ident_twin_sync(tw, id), VIBID_OK);
    vibid_ident_info info{};
    count_only();
    const vibid_status es = vibid_ident_estimate(tw, t2, s2, &info);
    const vibid_status cs = vibid_ident_covariance(tw, c2);
    const vibid_status qs = vibid_ident_get_quality(tw, &q, nullptr);
    const std::size_t n_estimator = disarm();
    const vibid_status ms = vibid_model_modal(m, t2, c2, f2, fse2, z2, zse2, nullptr, nullptr);
    const vibid_status ps = vibid_plausibility_check(m, h, t2, f2, z2, n,
                                                     vibid_report_reference(rep), &found, nullptr, nullptr, why,
                                                     sizeof why);
    assert_int_equal(vibid_ident_twin_sync(tw, id), VIBID_OK);
    assert_int_equal(es, VIBID_OK);
    assert_int_equal(ms, VIBID_OK);
    assert_int_equal(cs, VIBID_OK);
    assert_int_equal(ps, VIBID_OK);
    assert_int_equal(qs, VIBID_OK);

    count_only();
    const vibid_status rs = vibid_report_row(rep, tw, &out);
    const std::size_t n_row = disarm();
    assert_int_equal(rs, VIBID_OK);
    assert_int_equal(out.est_status, VIBID_OK);
    assert_int_equal(n_row, n_estimator);
    assert_true(std::isfinite(fse[0]) && fse[0] > 0.0 && std::isfinite(zse[1]));  // the modes' errors ran
    assert_memory_equal(theta, t2, sizeof theta);
    assert_memory_equal(se, s2, sizeof se);
    assert_memory_equal(cov, c2, sizeof cov);
    assert_memory_equal(f, f2, sizeof f);
    assert_memory_equal(fse, fse2, sizeof fse);
    assert_memory_equal(z, z2, sizeof z);
    assert_memory_equal(zse, zse2, sizeof zse);
    assert_int_equal(out.implausible, found);
    assert_int_equal((out.flags & VIBID_ROW_SE_INVALID) != 0, (q.flags & VIBID_QUALITY_SE_INVALID) != 0);

    // an estimate made elsewhere: the report's own work allocates nothing, Eigen's check armed
    double t3[p], s3[p], c3[p * p];
    std::memcpy(t3, t2, sizeof t3);
    std::memcpy(s3, s2, sizeof s3);
    std::memcpy(c3, c2, sizeof c3);
    arm();
    const vibid_status re = vibid_report_estimate(rep, t3, s3, c3, 0u, 3000, &out);
    const std::size_t n_own = disarm();
    assert_int_equal(re, VIBID_OK);
    assert_int_equal(n_own, 0);
    assert_memory_equal(f, f2, sizeof f);
    assert_memory_equal(fse, fse2, sizeof fse);
    assert_memory_equal(zse, zse2, sizeof zse);

    // no estimate: nothing allocated, Eigen's check armed
    std::size_t bad_status = 0;
    arm();
    for (int k = 0; k < 100; ++k)
        if (vibid_report_no_estimate(rep, VIBID_E_INSUFFICIENT_DATA, &out) != VIBID_OK) ++bad_status;
    if (vibid_report_row(rep, nullptr, &out) != VIBID_E_NULL_ARGUMENT) ++bad_status;
    if (vibid_report_row(rep, id, nullptr) != VIBID_E_NULL_ARGUMENT) ++bad_status;
    const std::size_t n_none = disarm();
    assert_int_equal(bad_status, 0);
    assert_int_equal(n_none, 0);
    assert_int_equal(out.flags, VIBID_ROW_NOEST);
    assert_true(std::isnan(theta[0]) && std::isnan(f[1]));
    vibid_report_destroy(rep);
    vibid_ident_destroy(tw);
    vibid_ident_destroy(id);
    vibid_model_destroy(m);
}

}  // namespace

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_counters_fire),
        cmocka_unit_test(test_rls_no_alloc),
        cmocka_unit_test(test_outlier_no_alloc),
        cmocka_unit_test(test_oma_push_no_alloc),
        cmocka_unit_test(test_lsq_riv_no_alloc),
        cmocka_unit_test(test_report_row_no_alloc),
    };
    return cmocka_run_group_tests(tests, nullptr, nullptr);
}
