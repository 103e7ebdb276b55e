/* Unit tests of the drift alarm logic (alarm.h): raise only after the hold time, clear
 * after the hold time, relative floor, learned baseline, non-finite input ignored. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>

#include "alarm.h"

static vd_alarm_config base_cfg(void)
{
    vd_alarm_config c = {5.0, 0.0, 2.0, false, 100.0, 0.0, 0.0};
    return c;
}

static void test_raise_after_hold(void **state)
{
    (void)state;
    vd_alarm_config c = base_cfg();
    vd_alarm a;
    vd_alarm_init(&a, &c);
    /* steady, within 5 sigma: no alarm ever */
    for (int i = 0; i < 100; i++)
        assert_int_equal(vd_alarm_update(&a, i * 0.1, 100.0 + 4.9 * (i % 2 ? 1 : -1), 1.0), VD_ALARM_NONE);
    /* step at t = 10 s to 110 (10 sigma): raised at t = 12 s exactly, not before */
    int raised_at = -1;
    for (int i = 100; i < 200; i++) {
        vd_alarm_event e = vd_alarm_update(&a, i * 0.1, 110.0, 1.0);
        if (e == VD_ALARM_RAISED) {
            assert_int_equal(raised_at, -1);
            raised_at = i;
        } else {
            assert_int_equal(e, VD_ALARM_NONE);
        }
    }
    assert_int_equal(raised_at, 120);
    assert_true(a.active);
    assert_true(fabs(a.last_z - 10.0) < 1e-12);
    /* back to normal: cleared after 2 s */
    int cleared_at = -1;
    for (int i = 200; i < 300; i++)
        if (vd_alarm_update(&a, i * 0.1, 100.0, 1.0) == VD_ALARM_CLEARED)
            cleared_at = i;
    assert_int_equal(cleared_at, 220);
    assert_false(a.active);
}

static void test_interrupted_excursion(void **state)
{
    (void)state;
    vd_alarm_config c = base_cfg();
    vd_alarm a;
    vd_alarm_init(&a, &c);
    /* out for 1.5 s, in for one estimate, out for 1.5 s: never 2 s in a row */
    for (int rep = 0; rep < 5; rep++) {
        double t0 = rep * 2.0;
        for (int i = 0; i < 15; i++)
            assert_int_equal(vd_alarm_update(&a, t0 + i * 0.1, 120.0, 1.0), VD_ALARM_NONE);
        assert_int_equal(vd_alarm_update(&a, t0 + 1.5, 100.0, 1.0), VD_ALARM_NONE);
    }
    assert_false(a.active);
}

static void test_relative_floor(void **state)
{
    (void)state;
    vd_alarm_config c = base_cfg();
    c.min_relative = 0.05; /* 5 % of 100 = 5 */
    c.hold_s = 0.0;
    vd_alarm a;
    vd_alarm_init(&a, &c);
    /* 4 units off with se 0.01: 400 sigma but under the 5 % floor */
    assert_int_equal(vd_alarm_update(&a, 0.0, 104.0, 0.01), VD_ALARM_NONE);
    assert_int_equal(vd_alarm_update(&a, 0.1, 106.0, 0.01), VD_ALARM_RAISED);
}

static void test_learned_baseline(void **state)
{
    (void)state;
    vd_alarm_config c = base_cfg();
    c.learn = true;
    c.learn_start_s = 1.0;
    c.learn_duration_s = 2.0;
    c.hold_s = 0.5;
    vd_alarm a;
    vd_alarm_init(&a, &c);
    /* before and during learning nothing fires, even far away */
    assert_int_equal(vd_alarm_update(&a, 0.5, 1000.0, 1.0), VD_ALARM_NONE);
    for (int i = 0; i < 20; i++)
        assert_int_equal(vd_alarm_update(&a, 1.0 + i * 0.1, i % 2 ? 49.0 : 51.0, 2.0), VD_ALARM_NONE);
    assert_false(a.have_baseline);
    assert_int_equal(vd_alarm_update(&a, 3.0, 50.0, 2.0), VD_ALARM_NONE);
    assert_true(a.have_baseline);
    assert_true(fabs(a.base - 50.0) < 1e-12);
    assert_true(fabs(a.base_se - 2.0) < 1e-12);
    /* z = 20 / sqrt(2^2 + 2^2) = 7.07 > 5 */
    assert_int_equal(vd_alarm_update(&a, 3.1, 70.0, 2.0), VD_ALARM_NONE);
    assert_int_equal(vd_alarm_update(&a, 3.6, 70.0, 2.0), VD_ALARM_RAISED);
}

static void test_nonfinite_ignored(void **state)
{
    (void)state;
    vd_alarm_config c = base_cfg();
    c.hold_s = 0.0;
    vd_alarm a;
    vd_alarm_init(&a, &c);
    assert_int_equal(vd_alarm_update(&a, 0.0, NAN, 1.0), VD_ALARM_NONE);
    assert_int_equal(vd_alarm_update(&a, 0.0, 200.0, NAN), VD_ALARM_NONE);
    assert_int_equal(vd_alarm_update(&a, 0.0, 200.0, -1.0), VD_ALARM_NONE);
    assert_false(a.active);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_raise_after_hold), cmocka_unit_test(test_interrupted_excursion),
        cmocka_unit_test(test_relative_floor),   cmocka_unit_test(test_learned_baseline),
        cmocka_unit_test(test_nonfinite_ignored),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
