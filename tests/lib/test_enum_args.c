/* test_enum_args.c: out-of-range enum values through the C API. A C caller can put any
 * int where an enum is declared (a cast, a zeroed or stale struct, a binding that passes
 * integers); the library must refuse it with VIBID_E_OUT_OF_RANGE (or NULL from a
 * constructor) and a message naming the value, and must not read it as the enum type
 * first: in C++ a value outside the enum's range is undefined behaviour, which the
 * sanitizer build (scripts/test.sh, UBSan with halt_on_error) turns into a failure of
 * this test. 99 is outside the range of every enum here (they hold 0..3 at most). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>

#include <string.h>

#include <vibid/vibid.h>

#define BAD 99

static void assert_named(const char *what)
{
    const char *msg = vibid_last_error();
    if (!strstr(msg, "99")) fail_msg("%s: the message does not name the value: %s", what, msg);
}

static vibid_model *one_node(size_t *node, size_t *input)
{
    vibid_model *m = vibid_model_create();
    assert_non_null(m);
    assert_int_equal(vibid_model_add_node(m, "m", 1.0, 0, node), VIBID_OK);
    assert_int_equal(vibid_model_add_input(m, "f", *node, 1.0, 0, input), VIBID_OK);
    return m;
}

static void test_model_enums(void **state)
{
    (void)state;
    size_t node, input;
    vibid_model *m = one_node(&node, &input);
    assert_int_equal(vibid_model_add_element(m, "k", (vibid_element_kind)BAD, node, VIBID_GROUND, 1.0, 1),
                     VIBID_E_OUT_OF_RANGE);
    assert_named("vibid_model_add_element");
    assert_int_equal(vibid_model_set_discretization(m, (vibid_discretization)BAD), VIBID_E_OUT_OF_RANGE);
    assert_named("vibid_model_set_discretization");
    assert_int_equal(vibid_model_set_hold(m, input, (vibid_hold)BAD), VIBID_E_OUT_OF_RANGE);
    assert_named("vibid_model_set_hold");
    /* the model is unharmed: a valid element still goes in */
    assert_int_equal(vibid_model_add_element(m, "k", VIBID_ELEMENT_SPRING, node, VIBID_GROUND, 1.0, 1), VIBID_OK);
    vibid_model_destroy(m);
}

static void test_config_enums(void **state)
{
    (void)state;
    size_t node, input;
    vibid_model *m = one_node(&node, &input);
    assert_int_equal(vibid_model_add_element(m, "k", VIBID_ELEMENT_SPRING, node, VIBID_GROUND, 1.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "d", VIBID_ELEMENT_DAMPER, node, VIBID_GROUND, 1.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, node, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    vibid_ident_config ic;
    vibid_ident_config_init(&ic, 1e-3);
    ic.estimator = (vibid_estimator)BAD;
    assert_null(vibid_ident_create(m, &ic));
    assert_named("vibid_ident_create");
    vibid_model_destroy(m);

    vibid_rls_config rc;
    vibid_rls_config_init(&rc, 2, 1);
    rc.form = (vibid_rls_form)BAD;
    assert_null(vibid_rls_create(&rc));
    assert_named("vibid_rls_create (form)");
    vibid_rls_config_init(&rc, 2, 1);
    rc.windup = (vibid_rls_windup)BAD;
    assert_null(vibid_rls_create(&rc));
    assert_named("vibid_rls_create (windup)");

    vibid_ioform_config io;
    vibid_ioform_config_init(&io, 2, 1, 1);
    io.method = (vibid_ioform_method)BAD;
    double z[64] = {0}, u[64] = {0}, a[8], b[8];
    assert_int_equal(vibid_ioform_estimate(&io, z, u, 64, a, b, NULL, NULL), VIBID_E_OUT_OF_RANGE);
    assert_named("vibid_ioform_estimate");

    vibid_kfrls_config kc;
    vibid_kfrls_config_init(&kc, 2, 1, 1);
    kc.method = (vibid_kfrls_method)BAD;
    double U[2] = {1, 0}, Rb[4] = {1, 0, 0, 1}, Rv[1] = {1};
    assert_null(vibid_kfrls_create(&kc, U, Rb, Rv));
    assert_named("vibid_kfrls_create");
}

/* The library's estimator names (identify.h): every kind has one, they read back to the
 * same kind, out-of-range kinds have none, an unknown name is refused with the names. */
static void test_estimator_names(void **state)
{
    (void)state;
    int k = 0;
    for (; vibid_estimator_name((vibid_estimator)k); k++) {
        vibid_estimator back = (vibid_estimator)BAD;
        assert_int_equal(vibid_estimator_from_name(vibid_estimator_name((vibid_estimator)k), &back), VIBID_OK);
        assert_int_equal(back, k);
    }
    assert_int_equal(k, VIBID_ESTIMATOR_OE + 1);
    assert_string_equal(vibid_estimator_name(VIBID_ESTIMATOR_KF_RLS), "kf_rls");
    assert_null(vibid_estimator_name((vibid_estimator)BAD));
    assert_null(vibid_estimator_name((vibid_estimator)-1));
    vibid_estimator e = VIBID_ESTIMATOR_LS;
    assert_int_equal(vibid_estimator_from_name("IV", &e), VIBID_E_OUT_OF_RANGE);
    assert_int_equal(e, VIBID_ESTIMATOR_LS);
    assert_non_null(strstr(vibid_last_error(), "\"IV\" unknown: one of ls, iv"));
    assert_int_equal(vibid_estimator_from_name(NULL, &e), VIBID_E_NULL_ARGUMENT);
    assert_int_equal(vibid_estimator_from_name("ls", NULL), VIBID_E_NULL_ARGUMENT);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_model_enums),
        cmocka_unit_test(test_config_enums),
        cmocka_unit_test(test_estimator_names),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
