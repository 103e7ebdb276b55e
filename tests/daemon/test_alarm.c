/* Unit tests of the drift alarm logic (alarm.h): raise only after the hold time, clear
 * after the hold time, relative floor, learned baseline, non-finite input ignored, rows
 * flagged E or P (vd_row_usable) ignored: not learned, never raising or clearing. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>

#include "alarm.h"
#include "estimator.h"

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

/* Rows flagged E (no estimate) or P (physically impossible estimate) are not usable;
 * rows with G or A only are. */
static void test_row_usable(void **state)
{
    (void)state;
    assert_true(vd_row_usable(0));
    assert_true(vd_row_usable(VD_FLAG_GAP | VD_FLAG_ALARM));
    assert_false(vd_row_usable(VD_FLAG_NOEST));
    assert_false(vd_row_usable(VD_FLAG_IMPLAUSIBLE));
    assert_false(vd_row_usable(VD_FLAG_IMPLAUSIBLE | VD_FLAG_GAP | VD_FLAG_ALARM));
}

/* P rows during the learning window are not learned from: the baseline is exactly the
 * mean of the usable rows (1e-12: sums of 10 numbers of order 50, rounding ~1e-14). */
static void test_flagged_rows_not_learned(void **state)
{
    (void)state;
    vd_alarm_config c = base_cfg();
    c.learn = true;
    c.learn_start_s = 0.0;
    c.learn_duration_s = 2.0;
    vd_alarm a;
    vd_alarm_init(&a, &c);
    for (int i = 0; i < 20; i++) {
        bool usable = i % 2 == 0; /* every other row impossible, e.g. a negative stiffness */
        double theta = usable ? 50.0 + (i % 4 == 0 ? 1.0 : -1.0) : -18981.0;
        double se = usable ? 2.0 : 1e6;
        assert_int_equal(vd_alarm_update_row(&a, i * 0.1, theta, se, usable), VD_ALARM_NONE);
    }
    assert_int_equal(a.n_learn, 10);
    assert_int_equal(vd_alarm_update_row(&a, 2.0, 50.0, 2.0, true), VD_ALARM_NONE);
    assert_true(a.have_baseline);
    assert_true(fabs(a.base - 50.0) < 1e-12);
    assert_true(fabs(a.base_se - 2.0) < 1e-12);
    assert_false(a.learn_missed);
}

/* A learning window covered only by unusable rows learns nothing and says so; that alarm
 * then stays off whatever comes. */
static void test_learn_window_all_flagged(void **state)
{
    (void)state;
    vd_alarm_config c = base_cfg();
    c.learn = true;
    c.learn_start_s = 1.0;
    c.learn_duration_s = 1.0;
    c.hold_s = 0.0;
    vd_alarm a;
    vd_alarm_init(&a, &c);
    for (int i = 0; i < 20; i++)
        assert_int_equal(vd_alarm_update_row(&a, i * 0.1, 50.0, 1.0, false), VD_ALARM_NONE);
    assert_false(a.learn_missed); /* t = 1.9 s: the window [1, 2) is not over yet */
    assert_int_equal(vd_alarm_update_row(&a, 2.0, 50.0, 1.0, false), VD_ALARM_NONE);
    assert_true(a.learn_missed);
    assert_false(a.have_baseline);
    for (int i = 0; i < 10; i++)
        assert_int_equal(vd_alarm_update_row(&a, 3.0 + i, 5000.0, 1.0, true), VD_ALARM_NONE);
    assert_false(a.active);
}

/* P rows neither raise nor clear, however far off (or back in) their values are, and do
 * not touch the out/in state; the hold time runs from the last usable row's state change. */
static void test_flagged_rows_neither_raise_nor_clear(void **state)
{
    (void)state;
    vd_alarm_config c = base_cfg(); /* baseline 100, 5 sigma, hold 2 s */
    vd_alarm a;
    vd_alarm_init(&a, &c);
    /* 100 sigma off on P rows only, for 5 s: nothing, the state stays "in" */
    for (int i = 0; i < 50; i++)
        assert_int_equal(vd_alarm_update_row(&a, i * 0.1, 200.0, 1.0, false), VD_ALARM_NONE);
    assert_false(a.out);
    assert_false(a.active);
    /* hold 0: a single P row would raise at once if it counted */
    vd_alarm_config c0 = c;
    c0.hold_s = 0.0;
    vd_alarm b;
    vd_alarm_init(&b, &c0);
    assert_int_equal(vd_alarm_update_row(&b, 0.0, -18981.0, 1.0, false), VD_ALARM_NONE);
    assert_false(b.active);
    assert_int_equal(vd_alarm_update_row(&b, 0.1, 110.0, 1.0, true), VD_ALARM_RAISED);
    /* now active: P rows back at the baseline for 5 s do not clear it */
    for (int i = 2; i < 52; i++)
        assert_int_equal(vd_alarm_update_row(&b, i * 0.1, 100.0, 1.0, false), VD_ALARM_NONE);
    assert_true(b.active);
    assert_true(b.out);
    /* the first usable row back in clears it (hold 0) */
    assert_int_equal(vd_alarm_update_row(&b, 5.3, 100.0, 1.0, true), VD_ALARM_CLEARED);
    /* hold 2 s: out at t = 10 (usable), then P rows "in" up to 11.9, usable out at 12.0:
     * raised at 12.0, the P rows did not interrupt the excursion */
    vd_alarm_event e = vd_alarm_update_row(&a, 10.0, 120.0, 1.0, true);
    assert_int_equal(e, VD_ALARM_NONE);
    for (int i = 101; i < 120; i++)
        assert_int_equal(vd_alarm_update_row(&a, i * 0.1, 100.0, 1.0, false), VD_ALARM_NONE);
    assert_int_equal(vd_alarm_update_row(&a, 12.0, 120.0, 1.0, true), VD_ALARM_RAISED);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_raise_after_hold), cmocka_unit_test(test_interrupted_excursion),
        cmocka_unit_test(test_relative_floor),   cmocka_unit_test(test_learned_baseline),
        cmocka_unit_test(test_nonfinite_ignored),
        cmocka_unit_test(test_row_usable),
        cmocka_unit_test(test_flagged_rows_not_learned),
        cmocka_unit_test(test_learn_window_all_flagged),
        cmocka_unit_test(test_flagged_rows_neither_raise_nor_clear),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
