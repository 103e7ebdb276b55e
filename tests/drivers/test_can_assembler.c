/* CAN sample assembly: complete samples across counter wrap, and every fault kind as
 * an explicit record (gap, duplicate, late, error frame, unknown id, NaN). */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>
#include <vibid_drivers/can_assembler.h>

static const char dbc_text[] =
    "BO_ 256 A: 8 S\n SG_ Cnt : 0|8@1+ (1,0) [0|255] \"\" X\n SG_ F : 8|16@1- (0.01,0) [0|0] \"N\" X\n"
    "BO_ 257 B: 8 S\n SG_ Cnt : 0|8@1+ (1,0) [0|255] \"\" X\n SG_ X : 8|32@1- (1,0) [0|0] \"m\" X\n"
    "SIG_VALTYPE_ 257 X : 1;\n";

static vibid_can_frame frame(uint32_t id, uint8_t cnt, double v, int64_t t)
{
    vibid_can_frame f;
    memset(&f, 0, sizeof f);
    f.id = id;
    f.len = 8;
    f.t_ns = t;
    f.data[0] = cnt;
    if (id == 256) {
        int16_t r = (int16_t)lround(v / 0.01);
        memcpy(f.data + 1, &r, 2); /* little endian host */
    } else {
        float x = (float)v;
        memcpy(f.data + 1, &x, 4);
    }
    return f;
}

static size_t drain(vibid_can_assembler *a, vibid_record *out, size_t cap)
{
    size_t n = 0;
    while (n < cap && vibid_can_assembler_pop(a, &out[n]))
        n++;
    return n;
}

static void test_counter_mode(void **state)
{
    (void)state;
    vibid_drv_error err = {0};
    vibid_dbc *dbc = vibid_dbc_parse(dbc_text, sizeof dbc_text - 1, "t.dbc", &err);
    assert_non_null(dbc);
    vibid_chanmap map;
    memset(&map, 0, sizeof map);
    map.n = 2;
    strcpy(map.ch[0].name, "F");
    map.ch[0].quantity = VIBID_Q_FORCE;
    map.ch[0].is_input = true;
    strcpy(map.ch[0].ref, "F");
    strcpy(map.ch[1].name, "x");
    strcpy(map.ch[1].ref, "X");
    strcpy(map.counter, "Cnt");
    vibid_can_assembler *a = vibid_can_assembler_create(dbc, &map, &err);
    assert_non_null(a);
    uint32_t ids[4];
    assert_int_equal(vibid_can_assembler_ids(a, ids, 4), 2);

    vibid_record r[16];
    vibid_can_frame f;
    const int64_t h = 1000000; /* 1 ms */
    /* samples with counter 254, 255, 0 (wrap), each complete */
    for (int k = 0; k < 3; k++) {
        uint8_t c = (uint8_t)(254 + k);
        f = frame(256, c, 1.25 * k, k * h);
        vibid_can_assembler_push(a, &f);
        f = frame(257, c, -0.5 * k, k * h + 1000);
        vibid_can_assembler_push(a, &f);
        assert_int_equal(drain(a, r, 16), 1);
        assert_int_equal(r[0].kind, VIBID_REC_SAMPLE);
        assert_int_equal(r[0].index, 254 + k); /* unwrapped: 256 after the wrap */
        assert_true(fabs(r[0].values[0] - 1.25 * k) < 1e-12); /* 0.01 quantum, exact at these values */
        assert_true(r[0].values[1] == -0.5 * k);              /* float32 exact */
        assert_true(r[0].t_ns == k * h);
    }
    /* counter 1: only A arrives; then counter 4 arrives: sample 257 incomplete (gap 1),
     * 258..259 missing (gap 2) */
    f = frame(256, 1, 0, 3 * h);
    vibid_can_assembler_push(a, &f);
    f = frame(256, 4, 0, 6 * h);
    vibid_can_assembler_push(a, &f);
    size_t n = drain(a, r, 16);
    assert_int_equal(n, 2);
    assert_int_equal(r[0].kind, VIBID_REC_GAP);
    assert_int_equal(r[0].index, 257);
    assert_int_equal(r[0].count, 1);
    assert_non_null(strstr(r[0].text, "missing B"));
    assert_int_equal(r[1].kind, VIBID_REC_GAP);
    assert_int_equal(r[1].index, 258);
    assert_int_equal(r[1].count, 2);
    /* duplicate A for counter 4, then late B for counter 3 */
    vibid_can_assembler_push(a, &f);
    f = frame(257, 3, 0, 6 * h);
    vibid_can_assembler_push(a, &f);
    n = drain(a, r, 16);
    assert_int_equal(n, 2);
    assert_int_equal(r[0].fault, VIBID_FAULT_DUPLICATE);
    assert_int_equal(r[1].fault, VIBID_FAULT_LATE);
    /* NaN in B: fault, and the sample stays incomplete */
    f = frame(257, 4, NAN, 6 * h);
    vibid_can_assembler_push(a, &f);
    n = drain(a, r, 16);
    assert_int_equal(n, 1);
    assert_int_equal(r[0].fault, VIBID_FAULT_NONFINITE);
    /* error frame (bus-off), unknown id twice (reported once), short frame */
    vibid_can_frame e;
    memset(&e, 0, sizeof e);
    e.flags = VIBID_CAN_F_ERR;
    e.id = 0x40;
    e.len = 8;
    vibid_can_assembler_push(a, &e);
    f = frame(0x300, 0, 0, 0);
    vibid_can_assembler_push(a, &f);
    vibid_can_assembler_push(a, &f);
    f = frame(257, 4, 1, 6 * h);
    f.len = 3;
    vibid_can_assembler_push(a, &f);
    n = drain(a, r, 16);
    assert_int_equal(n, 3);
    assert_int_equal(r[0].fault, VIBID_FAULT_BUS_ERROR);
    assert_int_equal(r[1].fault, VIBID_FAULT_UNKNOWN_ID);
    assert_int_equal(r[2].fault, VIBID_FAULT_SHORT_FRAME);
    /* finally B for counter 4 completes sample 260 */
    f = frame(257, 4, 2.0, 6 * h);
    vibid_can_assembler_push(a, &f);
    assert_int_equal(drain(a, r, 16), 1);
    assert_int_equal(r[0].kind, VIBID_REC_SAMPLE);
    assert_int_equal(r[0].index, 260);
    vibid_can_assembler_note_drops(a, 5, "DROPCOUNT");
    assert_int_equal(drain(a, r, 16), 1);
    assert_int_equal(r[0].fault, VIBID_FAULT_DROPPED);
    assert_int_equal(r[0].count, 5);
    vibid_can_assembler_finish(a);
    assert_int_equal(drain(a, r, 16), 0);

    vibid_can_assembler_stats st;
    vibid_can_assembler_stats_get(a, &st);
    assert_int_equal(st.samples, 4);
    assert_int_equal(st.missing_samples, 3);
    assert_int_equal(st.incomplete_samples, 1);
    assert_int_equal(st.duplicates, 1);
    assert_int_equal(st.late, 1);
    assert_int_equal(st.unknown_ids, 2);
    assert_int_equal(st.bus_off, 1);
    assert_int_equal(st.dropped, 5);
    /* intervals between emitted samples: 1, 1, 4 ms */
    assert_int_equal(st.jitter.n, 3);
    assert_true(fabs(st.jitter.mean_s - 0.002) < 1e-12);
    assert_true(fabs(st.jitter.min_s - 0.001) < 1e-12 && fabs(st.jitter.max_s - 0.004) < 1e-12);
    vibid_can_assembler_destroy(a);
    vibid_dbc_destroy(dbc);
}

static void test_config_errors(void **state)
{
    (void)state;
    vibid_drv_error err = {0};
    vibid_dbc *dbc = vibid_dbc_parse(dbc_text, sizeof dbc_text - 1, "t.dbc", &err);
    vibid_chanmap map;
    memset(&map, 0, sizeof map);
    map.n = 2;
    strcpy(map.ch[0].name, "F");
    strcpy(map.ch[0].ref, "F");
    strcpy(map.ch[1].name, "x");
    strcpy(map.ch[1].ref, "X");
    assert_null(vibid_can_assembler_create(dbc, &map, &err)); /* two messages, no counter/trigger */
    assert_non_null(strstr(err.text, "set counter"));
    strcpy(map.ch[1].ref, "Nope");
    strcpy(map.counter, "Cnt");
    assert_null(vibid_can_assembler_create(dbc, &map, &err));
    assert_non_null(strstr(err.text, "no signal 'Nope'"));
    vibid_dbc_destroy(dbc);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_counter_mode),
        cmocka_unit_test(test_config_errors),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
