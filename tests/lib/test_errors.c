/* test_errors.c: the error-reporting conventions of the whole C API: status strings,
 * the thread-local last-error text naming the entry point, and the version query. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>

#include <math.h>
#include <string.h>

#include <vibid/vibid.h>

static void test_strerror_covers_every_status(void **state) {
    (void)state;
    for (int s = VIBID_OK; s <= VIBID_E_INTERNAL; ++s) {
        const char *text = vibid_strerror((vibid_status)s);
        assert_non_null(text);
        assert_string_not_equal(text, "unknown status");
    }
    assert_string_equal(vibid_strerror((vibid_status)999), "unknown status");
}

/* A failure detected inside a guarded entry point must be reported under the API
 * function's name (the guard's lambda would otherwise give "operator()"). */
static void test_last_error_names_entry_point(void **state) {
    (void)state;
    vibid_lsq *lsq = vibid_lsq_create(2, 1);
    assert_non_null(lsq);
    double X[2] = {1.0, NAN}, Y[1] = {1.0};
    assert_int_equal(vibid_lsq_add_rows(lsq, 1, X, Y, NULL), VIBID_E_NONFINITE);
    const char *msg = vibid_last_error();
    assert_true(strncmp(msg, "vibid_lsq_add_rows: ", 20) == 0);
    assert_null(strstr(msg, "operator()"));
    vibid_lsq_destroy(lsq);

    /* Constructors: NULL and the reason under the constructor's name. */
    assert_null(vibid_lsq_create(0, 1));
    assert_true(strncmp(vibid_last_error(), "vibid_lsq_create: ", 18) == 0);
}

/* vibid_zoh: non-finite input and an overflowing exponential are errors, and the outputs
 * stay as they were (issue 12, item 10: it returned OK with Inf in G). */
static void test_zoh_refuses_overflow(void **state) {
    (void)state;
    double A[1] = {NAN}, B[1] = {1.0}, G[1] = {-7.0}, Gam[1] = {-7.0};
    assert_int_equal(vibid_zoh(1, 1, A, B, 1e-3, G, Gam), VIBID_E_NONFINITE);
    A[0] = 1e3; /* e^{1000 * 1 s} overflows */
    assert_int_equal(vibid_zoh(1, 1, A, B, 1.0, G, Gam), VIBID_E_NUMERICAL);
    assert_non_null(strstr(vibid_last_error(), "overflows"));
    assert_true(G[0] == -7.0 && Gam[0] == -7.0);
    assert_int_equal(vibid_zoh(1, 1, A, B, 1e-3, G, Gam), VIBID_OK); /* e^1: fine */
    assert_true(fabs(G[0] - exp(1.0)) < 1e-12 * exp(1.0));
}

static void test_version(void **state) {
    (void)state;
    assert_string_equal(vibid_version_string(), VIBID_VERSION_STRING);
    assert_int_equal(vibid_version(), VIBID_VERSION);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_strerror_covers_every_status),
        cmocka_unit_test(test_last_error_names_entry_point),
        cmocka_unit_test(test_zoh_refuses_overflow),
        cmocka_unit_test(test_version),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
