/* Unit tests of the SPSC ring: order, capacity, overflow counting, the high water against
 * known fills, and a two-thread stress run (bounded: 500,000 records per mode) checking that every record arrives exactly
 * once and in order. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <pthread.h>
#include <stdio.h>
#include <string.h>

#include "ring.h"

static void test_create_bounds(void **state)
{
    (void)state;
    assert_null(vd_ring_create(0));
    assert_null(vd_ring_create(1));
    assert_null(vd_ring_create(1000)); /* not a power of two */
    assert_null(vd_ring_create((size_t)VD_RING_MAX * 2));
    vd_ring *r = vd_ring_create(1024);
    assert_non_null(r);
    assert_int_equal(vd_ring_capacity(r), 1024);
    vd_ring_destroy(r);
    vd_ring_destroy(NULL);
}

static void test_fifo_and_overflow(void **state)
{
    (void)state;
    vd_ring *r = vd_ring_create(8);
    vd_item it, out;
    memset(&it, 0, sizeof it);
    assert_false(vd_ring_pop(r, &out));
    for (unsigned i = 0; i < 8; i++) {
        it.rec.index = i;
        assert_true(vd_ring_push(r, &it));
    }
    it.rec.index = 99;
    assert_false(vd_ring_push(r, &it)); /* full: refused and counted */
    assert_false(vd_ring_push(r, &it));
    assert_int_equal(vd_ring_overflows(r), 2);
    assert_int_equal(vd_ring_fill(r), 8);
    assert_int_equal(vd_ring_high_water(r), 8);
    for (unsigned i = 0; i < 8; i++) {
        assert_true(vd_ring_pop(r, &out));
        assert_int_equal(out.rec.index, i);
    }
    assert_false(vd_ring_pop(r, &out));
    /* wrap-around */
    for (unsigned round = 0; round < 5; round++)
        for (unsigned i = 0; i < 5; i++) {
            it.rec.index = round * 100 + i;
            assert_true(vd_ring_push(r, &it));
            const vd_item *p = vd_ring_peek(r);
            assert_non_null(p);
            assert_int_equal(p->rec.index, round * 100 + i);
            vd_ring_release(r);
        }
    vd_ring_destroy(r);
}

/* The high water is the most records that waited at once, not the records pushed since the
 * producer last looked at the tail (issue 30: a paced replay showed 4096 of 4096 with the
 * ring never more than a read's batch full). Known fills, one thread: exact. */
static void test_high_water(void **state)
{
    (void)state;
    vd_ring *r = vd_ring_create(4096);
    vd_item it, out;
    memset(&it, 0, sizeof it);
    assert_int_equal(vd_ring_high_water(r), 0);
    for (unsigned i = 0; i < 10; i++)
        assert_true(vd_ring_push(r, &it));
    assert_int_equal(vd_ring_high_water(r), 10);
    while (vd_ring_pop(r, &out)) {
    }
    /* a consumer that keeps up: 10000 records through the ring, never more than 1 waiting */
    for (unsigned i = 0; i < 10000; i++) {
        assert_true(vd_ring_push(r, &it));
        assert_true(vd_ring_pop(r, &out));
    }
    assert_int_equal(vd_ring_high_water(r), 10);
    for (unsigned i = 0; i < 7; i++)
        assert_true(vd_ring_push(r, &it));
    assert_int_equal(vd_ring_high_water(r), 10); /* 7 waiting: below the mark */
    for (unsigned i = 0; i < 5; i++)
        assert_true(vd_ring_push(r, &it));
    assert_int_equal(vd_ring_fill(r), 12);
    assert_int_equal(vd_ring_high_water(r), 12);
    /* popping some in between: the fill, not the pushes, sets the mark */
    for (unsigned i = 0; i < 6; i++)
        assert_true(vd_ring_pop(r, &out));
    for (unsigned i = 0; i < 9; i++)
        assert_true(vd_ring_push(r, &it));
    assert_int_equal(vd_ring_high_water(r), 15);
    while (vd_ring_pop(r, &out)) {
    }
    /* full, and a refused push does not count */
    for (unsigned i = 0; i < 4096; i++)
        assert_true(vd_ring_push(r, &it));
    assert_false(vd_ring_push(r, &it));
    assert_int_equal(vd_ring_high_water(r), 4096);
    vd_ring_destroy(r);
}

#define STRESS_N 500000u

typedef struct stress {
    vd_ring *r;
    int drop; /* 1: producer drops on full (live behaviour), 0: retries (replay behaviour) */
    uint64_t pushed;
    uint64_t overflows_before_end;
} stress;

static void *producer(void *arg)
{
    stress *s = arg;
    vd_item it;
    memset(&it, 0, sizeof it);
    it.rec.n_values = VIBID_DRV_MAX_CHANNELS; /* the ring copies only the used values: use all */
    for (uint64_t i = 0; i < STRESS_N; i++) {
        it.rec.index = i;
        it.rec.values[0] = (double)i; /* payload checked too: a torn copy would show */
        it.rec.values[31] = (double)(i * 3);
        if (s->drop) {
            if (vd_ring_push(s->r, &it))
                s->pushed++;
        } else {
            while (!vd_ring_push(s->r, &it)) {
            }
            s->pushed++;
        }
    }
    s->overflows_before_end = vd_ring_overflows(s->r);
    it.rec.index = UINT64_MAX; /* end marker, always delivered */
    while (!vd_ring_push(s->r, &it)) {
    }
    return NULL;
}

static void run_stress(int drop)
{
    stress s = {vd_ring_create(256), drop, 0, 0};
    pthread_t th;
    assert_int_equal(pthread_create(&th, NULL, producer, &s), 0);
    uint64_t got = 0, last = 0;
    int first = 1, bad = 0;
    vd_item out;
    for (;;) {
        if (!vd_ring_pop(s.r, &out))
            continue;
        if (out.rec.index == UINT64_MAX)
            break;
        if (out.rec.values[0] != (double)out.rec.index || out.rec.values[31] != (double)(out.rec.index * 3))
            bad++;
        if (!first && out.rec.index <= last)
            bad++;
        if (!drop && out.rec.index != got)
            bad++;
        first = 0;
        last = out.rec.index;
        got++;
    }
    pthread_join(th, NULL);
    assert_int_equal(bad, 0);
    /* two threads: the mark is a fill that happened, so within the capacity and at least 1 */
    assert_true(vd_ring_high_water(s.r) >= 1 && vd_ring_high_water(s.r) <= 256);
    assert_int_equal(got, s.pushed);
    /* nothing lost silently: every record was either delivered or counted as an overflow */
    if (drop)
        assert_int_equal(got + s.overflows_before_end, (uint64_t)STRESS_N);
    else
        assert_int_equal(got, STRESS_N); /* the retrying producer loses nothing */
    vd_ring_destroy(s.r);
}

/* The ring copies a record's used part only (vibid_record_copy): a sample's n_values
 * values and an empty text, a gap's or fault's text; a slot's earlier content must not
 * leak into these fields. */
static void test_copies_what_a_record_carries(void **state)
{
    (void)state;
    vd_ring *r = vd_ring_create(2);
    vd_item big, out;
    memset(&big, 0, sizeof big);
    big.rec.kind = VIBID_REC_FAULT;
    big.rec.n_values = 0;
    snprintf(big.rec.text, sizeof big.rec.text, "x.log:7: bad line");
    for (int round = 0; round < 2; round++) { /* fill both slots with a fault first */
        assert_true(vd_ring_push(r, &big));
        assert_true(vd_ring_pop(r, &out));
        assert_string_equal(out.rec.text, "x.log:7: bad line");
    }
    vd_item smp;
    memset(&smp, 0, sizeof smp);
    smp.rec.kind = VIBID_REC_SAMPLE;
    smp.rec.index = 42;
    smp.rec.t_ns = 123456789;
    smp.rec.n_values = 3;
    smp.rec.values[0] = 1.5;
    smp.rec.values[1] = -2.25;
    smp.rec.values[2] = 1e-9;
    smp.t_rx_ns = 99;
    assert_true(vd_ring_push(r, &smp));
    assert_true(vd_ring_pop(r, &out));
    assert_int_equal(out.rec.kind, VIBID_REC_SAMPLE);
    assert_int_equal(out.rec.index, 42);
    assert_int_equal(out.rec.t_ns, 123456789);
    assert_int_equal(out.rec.n_values, 3);
    assert_true(out.rec.values[0] == 1.5 && out.rec.values[1] == -2.25 && out.rec.values[2] == 1e-9);
    assert_string_equal(out.rec.text, ""); /* not the fault text the slot held */
    assert_int_equal(out.t_rx_ns, 99);
    vd_ring_destroy(r);
}

static void test_stress_retry(void **state)
{
    (void)state;
    run_stress(0);
}

static void test_stress_drop(void **state)
{
    (void)state;
    run_stress(1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_create_bounds),
        cmocka_unit_test(test_fifo_and_overflow),
        cmocka_unit_test(test_high_water),
        cmocka_unit_test(test_copies_what_a_record_carries),
        cmocka_unit_test(test_stress_retry),
        cmocka_unit_test(test_stress_drop),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
