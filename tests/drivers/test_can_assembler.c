/* CAN sample assembly: complete samples across counter wrap, and every fault kind as
 * an explicit record (gap, duplicate, late, error frame, unknown id, NaN); the
 * assembler's precomputed signal extraction against vibid_dbc_signal_decode. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
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

/* Counter plausibility. One message with a 16-bit counter like vibid-sim's frames,
 * h = 1 ms, default slack (16 samples): a missing count beyond 16 + 2 dt/h is a
 * corrupted counter (FAULT, frame ignored); genuine gaps whose time advanced stay GAPs. */
static const char dbc16_text[] = "BO_ 300 C: 8 S\n SG_ Cnt : 0|16@1+ (1,0) [0|65535] \"\" X\n"
                                 " SG_ Y : 16|32@1- (1,0) [0|0] \"m\" X\nSIG_VALTYPE_ 300 Y : 1;\n";

static vibid_can_frame frame16(uint16_t cnt, float y, int64_t t)
{
    vibid_can_frame f;
    memset(&f, 0, sizeof f);
    f.id = 300;
    f.len = 8;
    f.t_ns = t;
    memcpy(f.data, &cnt, 2); /* little endian host */
    memcpy(f.data + 2, &y, 4);
    return f;
}

static vibid_can_assembler *make16(vibid_dbc **dbc, vibid_chanmap *map)
{
    vibid_drv_error err = {0};
    *dbc = vibid_dbc_parse(dbc16_text, sizeof dbc16_text - 1, "t16.dbc", &err);
    assert_non_null(*dbc);
    memset(map, 0, sizeof *map);
    map->n = 1;
    strcpy(map->ch[0].name, "y");
    strcpy(map->ch[0].ref, "Y");
    strcpy(map->counter, "Cnt");
    vibid_can_assembler *a = vibid_can_assembler_create(*dbc, map, &err);
    assert_non_null(a);
    return a;
}

static void test_counter_plausibility(void **state)
{
    (void)state;
    vibid_dbc *dbc;
    vibid_chanmap map;
    vibid_can_assembler *a = make16(&dbc, &map);
    assert_false(vibid_can_assembler_set_timing(a, -1e-3, 0));
    assert_false(vibid_can_assembler_set_timing(a, NAN, 0));
    assert_true(vibid_can_assembler_set_timing(a, 1e-3, 0));
    const int64_t h = 1000000; /* 1 ms */
    vibid_record r[16];
    vibid_can_frame f;
    for (int k = 0; k < 10; k++) { /* samples 0..9, one per ms */
        f = frame16((uint16_t)k, (float)k, k * h);
        vibid_can_assembler_push(a, &f);
        assert_int_equal(drain(a, r, 16), 1);
        assert_int_equal(r[0].kind, VIBID_REC_SAMPLE);
    }
    /* sample 10's frame with bit 10 of the counter flipped: 10 ^ 0x400 = 1034, a jump of
     * 1025 samples 1 ms after sample 9 (at most 1 + 16 + 2 possible) */
    f = frame16(10 ^ 0x400, 10.0f, 10 * h);
    vibid_can_assembler_push(a, &f);
    size_t n = drain(a, r, 16);
    assert_int_equal(n, 1);
    assert_int_equal(r[0].kind, VIBID_REC_FAULT);
    assert_int_equal(r[0].fault, VIBID_FAULT_CORRUPT);
    assert_int_equal(r[0].index, 9);
    assert_non_null(strstr(r[0].text, "corrupt counter"));
    /* sample 11 arrives correctly: sample 10 (whose frame was corrupt) is a 1-sample GAP */
    f = frame16(11, 11.0f, 11 * h);
    vibid_can_assembler_push(a, &f);
    n = drain(a, r, 16);
    assert_int_equal(n, 2);
    assert_int_equal(r[0].kind, VIBID_REC_GAP);
    assert_int_equal(r[0].index, 10);
    assert_int_equal(r[0].count, 1);
    assert_int_equal(r[1].kind, VIBID_REC_SAMPLE);
    assert_int_equal(r[1].index, 11);
    assert_true(r[1].values[0] == 11.0);
    /* genuine outage: 500 ms later the counter says 511 (499 missing <= 16 + 1000) */
    f = frame16(511, 511.0f, 511 * h);
    vibid_can_assembler_push(a, &f);
    n = drain(a, r, 16);
    assert_int_equal(n, 2);
    assert_int_equal(r[0].kind, VIBID_REC_GAP);
    assert_int_equal(r[0].index, 12);
    assert_int_equal(r[0].count, 499);
    assert_int_equal(r[1].index, 511);
    /* near the bound (16 + 2 * 10 = 36 missing allowed 10 ms after sample 511): 35
     * missing is a GAP, */
    f = frame16(511 + 36, 0.0f, 521 * h);
    vibid_can_assembler_push(a, &f);
    n = drain(a, r, 16);
    assert_int_equal(n, 2);
    assert_int_equal(r[0].kind, VIBID_REC_GAP);
    assert_int_equal(r[0].count, 35);
    assert_int_equal(r[1].index, 547);
    /* ... 37 missing 10 ms later is not */
    f = frame16(547 + 38, 0.0f, 531 * h);
    vibid_can_assembler_push(a, &f);
    n = drain(a, r, 16);
    assert_int_equal(n, 1);
    assert_int_equal(r[0].fault, VIBID_FAULT_CORRUPT);
    /* a frame time going backwards counts as no elapsed time: a jump of 2 is within the
     * slack, a jump of 18 (17 missing) is not */
    f = frame16(547 + 18, 0.0f, 500 * h);
    vibid_can_assembler_push(a, &f);
    n = drain(a, r, 16);
    assert_int_equal(n, 1);
    assert_int_equal(r[0].fault, VIBID_FAULT_CORRUPT);
    f = frame16(547 + 2, 0.0f, 500 * h);
    vibid_can_assembler_push(a, &f);
    n = drain(a, r, 16);
    assert_int_equal(n, 2);
    assert_int_equal(r[0].kind, VIBID_REC_GAP);
    assert_int_equal(r[0].count, 1);
    assert_int_equal(r[1].index, 549);
    /* 20000 ahead after 100 ms: corrupt */
    f = frame16(549 + 20000, 0.0f, 600 * h);
    vibid_can_assembler_push(a, &f);
    n = drain(a, r, 16);
    assert_int_equal(n, 1);
    assert_int_equal(r[0].fault, VIBID_FAULT_CORRUPT);
    vibid_can_assembler_stats st;
    vibid_can_assembler_stats_get(a, &st);
    assert_int_equal(st.corrupt_counters, 4);
    assert_int_equal(st.gaps, 4);
    assert_int_equal(st.missing_samples, 1 + 499 + 35 + 1);
    vibid_can_assembler_destroy(a);
    vibid_dbc_destroy(dbc);

    /* genuine gap across the 16-bit wrap: 65530 -> 5 after 11 ms is 10 missing */
    a = make16(&dbc, &map);
    assert_true(vibid_can_assembler_set_timing(a, 1e-3, 0));
    f = frame16(65530, 0.0f, 0);
    vibid_can_assembler_push(a, &f);
    f = frame16(5, 0.0f, 11 * h);
    vibid_can_assembler_push(a, &f);
    n = drain(a, r, 16);
    assert_int_equal(n, 3);
    assert_int_equal(r[1].kind, VIBID_REC_GAP);
    assert_int_equal(r[1].index, 65531);
    assert_int_equal(r[1].count, 10);
    assert_int_equal(r[2].index, 65541);
    vibid_can_assembler_destroy(a);
    vibid_dbc_destroy(dbc);

    /* without timing (h = 0) the same corrupt frame is still taken as a 1024-sample
     * jump: the check is what turns it into a fault */
    a = make16(&dbc, &map);
    f = frame16(9, 0.0f, 9 * h);
    vibid_can_assembler_push(a, &f);
    f = frame16(10 ^ 0x400, 0.0f, 10 * h);
    vibid_can_assembler_push(a, &f);
    n = drain(a, r, 16);
    assert_int_equal(n, 3);
    assert_int_equal(r[1].kind, VIBID_REC_GAP);
    assert_int_equal(r[1].count, 1024);
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

/* The assembler decodes Intel signals with a precomputed load, shift and mask
 * (can_assembler.c, extractor) and everything else with vibid_dbc_signal_decode. Over
 * random payloads and lengths, every sample value must be bit-identical to
 * vibid_dbc_signal_decode, and a frame too short or holding a non-finite value must give
 * the same fault as before. Signals cover: unsigned/signed integers of 1..64 bits, float32
 * and float64, inside one aligned 64-bit word, across words (loaded from their first byte),
 * too wide for either (general path), Motorola (general path), up to bit 511 of an FD
 * payload, with factors and offsets. No tolerance: the bits of the doubles. */
static const char extract_dbc[] =
    "BO_ 256 A: 8 S\n"
    " SG_ a : 0|7@1+ (0.5,-3) [0|0] \"\" X\n"
    " SG_ b : 7|13@1- (0.001,0) [0|0] \"\" X\n"
    " SG_ c : 20|1@1+ (1,0) [0|0] \"\" X\n"
    " SG_ d : 21|32@1- (2.5,1000) [0|0] \"\" X\n"
    " SG_ e : 53|11@1+ (1,0) [0|0] \"\" X\n"
    "BO_ 300 B: 64 S\n"
    " SG_ m : 23|10@0- (0.25,1) [0|0] \"\" X\n"
    " SG_ o : 32|5@1- (1,0) [0|0] \"\" X\n"
    " SG_ f : 60|16@1+ (1,0) [0|0] \"\" X\n"
    " SG_ g : 76|32@1- (1,0) [0|0] \"\" X\n"
    " SG_ h : 128|64@1- (1,0) [0|0] \"\" X\n"
    " SG_ i : 200|64@1+ (1e-9,0) [0|0] \"\" X\n"
    " SG_ j : 268|64@1- (1,0) [0|0] \"\" X\n"
    " SG_ n : 372|32@1- (3,-1) [0|0] \"\" X\n"
    " SG_ k : 450|40@1- (1,0) [0|0] \"\" X\n"
    " SG_ l : 500|12@1+ (1,0) [0|0] \"\" X\n"
    "SIG_VALTYPE_ 300 g : 1;\n"
    "SIG_VALTYPE_ 300 h : 2;\n"
    "SIG_VALTYPE_ 300 n : 1;\n";

static uint64_t xrng = 0x853C49E6748FEA9Bu;
static uint64_t xrnd(void)
{
    uint64_t z = (xrng += 0x9E3779B97F4A7C15u);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9u;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBu;
    return z ^ (z >> 31);
}

static void check_message_extraction(const vibid_dbc *dbc, const char *msg_name, unsigned long *n_samples,
                                     unsigned long *n_faults)
{
    const vibid_dbc_message *m = vibid_dbc_find_message_by_name(dbc, msg_name);
    assert_non_null(m);
    vibid_chanmap map;
    memset(&map, 0, sizeof map);
    map.n = m->n_signals;
    for (size_t i = 0; i < m->n_signals; i++) {
        snprintf(map.ch[i].name, sizeof map.ch[i].name, "ch_%s", m->signals[i].name);
        snprintf(map.ch[i].ref, sizeof map.ch[i].ref, "%s", m->signals[i].name);
        snprintf(map.ch[i].message, sizeof map.ch[i].message, "%s", msg_name);
    }
    vibid_drv_error err = {0};
    vibid_can_assembler *a = vibid_can_assembler_create(dbc, &map, &err); /* one message: a frame is a sample */
    assert_non_null(a);
    vibid_record rec[8];
    for (int it = 0; it < 20000; it++) {
        vibid_can_frame f;
        memset(&f, 0, sizeof f);
        f.id = m->id;
        f.t_ns = (int64_t)it * 1000000;
        f.len = m->length;
        if (xrnd() % 8 == 0)
            f.len = (uint8_t)(xrnd() % (m->length + 1u)); /* short frames */
        if (m->length > 8)
            f.flags = VIBID_CAN_F_FD;
        for (size_t b = 0; b < VIBID_CANFD_MAX_DLEN; b++)
            f.data[b] = (uint8_t)xrnd(); /* bytes beyond len too: they must not matter */
        /* what the frame must give: the first failing channel's fault, else the values */
        double want[VIBID_DRV_MAX_CHANNELS];
        vibid_fault_code want_fault = VIBID_FAULT_NONE;
        for (size_t i = 0; i < m->n_signals && want_fault == VIBID_FAULT_NONE; i++) {
            if (vibid_dbc_signal_decode(&m->signals[i], f.data, f.len, &want[i]) != VIBID_DRV_OK)
                want_fault = VIBID_FAULT_SHORT_FRAME;
            else if (!isfinite(want[i]))
                want_fault = VIBID_FAULT_NONFINITE;
        }
        vibid_can_assembler_push(a, &f);
        size_t n = drain(a, rec, 8);
        assert_int_equal(n, 1);
        if (want_fault != VIBID_FAULT_NONE) {
            assert_int_equal(rec[0].kind, VIBID_REC_FAULT);
            assert_int_equal(rec[0].fault, want_fault);
            ++*n_faults;
            continue;
        }
        assert_int_equal(rec[0].kind, VIBID_REC_SAMPLE);
        assert_int_equal(rec[0].n_values, m->n_signals);
        for (size_t i = 0; i < m->n_signals; i++) {
            if (memcmp(&rec[0].values[i], &want[i], sizeof want[i]) != 0) {
                fprintf(stderr, "%s.%s: assembler %.17g, vibid_dbc_signal_decode %.17g\n", msg_name,
                        m->signals[i].name, rec[0].values[i], want[i]);
                fail();
            }
        }
        ++*n_samples;
    }
    vibid_can_assembler_destroy(a);
}

static void test_extraction_matches_decode(void **state)
{
    (void)state;
    vibid_drv_error err = {0};
    vibid_dbc *dbc = vibid_dbc_parse(extract_dbc, sizeof extract_dbc - 1, "x.dbc", &err);
    if (!dbc)
        fprintf(stderr, "%s\n", err.text);
    assert_non_null(dbc);
    unsigned long samples = 0, faults = 0;
    check_message_extraction(dbc, "A", &samples, &faults);
    check_message_extraction(dbc, "B", &samples, &faults);
    printf("extraction: %lu samples bit-identical to vibid_dbc_signal_decode, %lu frames with the same fault\n",
           samples, faults);
    assert_true(samples > 10000 && faults > 1000); /* both outcomes well covered */
    vibid_dbc_destroy(dbc);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_counter_mode),
        cmocka_unit_test(test_counter_plausibility),
        cmocka_unit_test(test_config_errors),
        cmocka_unit_test(test_extraction_matches_decode),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
