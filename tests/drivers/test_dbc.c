/* DBC reader: hand-checked decodes and every kind of syntax error reported with file
 * and line. The bulk check against cantools is dbc_vs_cantools.py. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>
#include <vibid_drivers/dbc.h>

static vibid_dbc *parse(const char *text, vibid_drv_error *err)
{
    memset(err, 0, sizeof *err);
    return vibid_dbc_parse(text, strlen(text), "t.dbc", err);
}

static void test_intel_motorola_by_hand(void **state)
{
    (void)state;
    vibid_drv_error err;
    vibid_dbc *d = parse("BO_ 496 M: 8 X\n"
                         " SG_ I : 4|12@1- (0.5,1) [0|0] \"m\" X\n"
                         " SG_ Mo : 23|16@0+ (1,0) [0|0] \"\" X\n",
                         &err);
    assert_non_null(d);
    const vibid_dbc_message *m = vibid_dbc_find_message(d, 496, false);
    assert_non_null(m);
    /* I: bits 4..15 little endian = 0xABC from data[0]=0xC0, data[1]=0xAB; 12-bit signed
     * 0xABC = -1348; phys = -1348*0.5+1 = -673. */
    uint8_t data[8] = {0xC0, 0xAB, 0x12, 0x34, 0x56, 0, 0, 0};
    double v;
    assert_int_equal(vibid_dbc_signal_decode(vibid_dbc_find_signal(m, "I"), data, 8, &v), VIBID_DRV_OK);
    assert_true(v == -673.0); /* exact: small integers times 0.5 */
    /* Mo: Motorola MSB at bit 23 (byte 2 bit 7): bytes 2..3 big endian = 0x1234. */
    assert_int_equal(vibid_dbc_signal_decode(vibid_dbc_find_signal(m, "Mo"), data, 8, &v), VIBID_DRV_OK);
    assert_true(v == 4660.0);
    /* Too short a payload is reported, not read past. */
    assert_int_equal(vibid_dbc_signal_decode(vibid_dbc_find_signal(m, "Mo"), data, 3, &v), VIBID_DRV_E_SHORT);
    vibid_dbc_destroy(d);
}

static void test_float_and_ext(void **state)
{
    (void)state;
    vibid_drv_error err;
    vibid_dbc *d = parse("BO_ 2147483905 F: 12 X\n"
                         " SG_ A : 0|32@1- (1,0) [0|0] \"\" X\n"
                         " SG_ B : 32|64@1- (2,0) [0|0] \"\" X\n"
                         "SIG_VALTYPE_ 2147483905 A : 1;\nSIG_VALTYPE_ 2147483905 B : 2;\n",
                         &err);
    assert_non_null(d);
    const vibid_dbc_message *m = vibid_dbc_find_message(d, 0x101, true);
    assert_non_null(m);
    assert_null(vibid_dbc_find_message(d, 0x101, false));
    uint8_t data[12];
    float f = -1.5f;
    double x = 3.25;
    memcpy(data, &f, 4);
    memcpy(data + 4, &x, 8);
    double vals[2];
    uint8_t pres[2];
    assert_int_equal(vibid_dbc_message_decode(m, data, 12, vals, pres), VIBID_DRV_OK);
    assert_true(pres[0] && pres[1]);
    assert_true(vals[0] == -1.5 && vals[1] == 6.5);
    vibid_dbc_destroy(d);
}

static void test_mux(void **state)
{
    (void)state;
    vibid_drv_error err;
    vibid_dbc *d = parse("BO_ 10 M: 2 X\n SG_ S M : 0|4@1+ (1,0) [0|0] \"\" X\n"
                         " SG_ A m1 : 8|8@1+ (1,0) [0|0] \"\" X\n"
                         " SG_ B m2 : 8|8@1+ (1,0) [0|0] \"\" X\n"
                         "SG_MUL_VAL_ 10 B S 2-3, 7-7;\n",
                         &err);
    assert_non_null(d);
    const vibid_dbc_message *m = vibid_dbc_find_message(d, 10, false);
    double v[3];
    uint8_t p[3];
    uint8_t data[2] = {7, 42};
    vibid_dbc_message_decode(m, data, 2, v, p);
    assert_true(p[0] && !p[1] && p[2]);
    assert_true(v[2] == 42.0 && isnan(v[1]));
    data[0] = 1;
    vibid_dbc_message_decode(m, data, 2, v, p);
    assert_true(p[0] && p[1] && !p[2]);
    vibid_dbc_destroy(d);
}

static void test_skips_unknown_and_multiline(void **state)
{
    (void)state;
    vibid_drv_error err;
    vibid_dbc *d = parse("VERSION \"x\"\nNS_ :\n\tCM_\n\tBA_\nBS_:\nBU_: A B\n"
                         "CM_ BO_ 1 \"two\nlines; with semicolon\";\n"
                         "BA_DEF_ BO_ \"X\" INT 0 1;\nFUTURE_KEYWORD 1 2 3\n"
                         "BO_ 1 M: 1 A\n SG_ S : 0|8@1+ (1,0) [0|0] \"\" B\n",
                         &err);
    assert_non_null(d);
    assert_int_equal(vibid_dbc_message_count(d), 1);
    assert_true(vibid_dbc_skipped_count(d) >= 4);
    assert_int_equal(vibid_dbc_message_at(d, 0)->signals[0].line, 12); /* counted across the 2-line comment */
    vibid_dbc_destroy(d);
}

typedef struct {
    const char *text;
    const char *expect; /* substring of the error, including "t.dbc:<line>:" */
} bad_case;

static void test_syntax_errors_name_line(void **state)
{
    (void)state;
    static const bad_case cases[] = {
        {"BO_ x M: 8 X\n", "t.dbc:1: BO_: expected a decimal message id"},
        {"\nBO_ 1 M 8 X\n", "t.dbc:2: BO_ M: expected ':'"},
        {"BO_ 1 M: 65 X\n", "t.dbc:1: BO_ M: length 65 bytes outside 0..64"},
        {"BO_ 2048 M: 8 X\n", "t.dbc:1: BO_ M: id 0x800 too large"},
        {"BO_ 1 M: 8 X\n SG_ S : 0|0@1+ (1,0) [0|0] \"\" X\n", "t.dbc:2: SG_ S: length 0 bits outside 1..64"},
        {"BO_ 1 M: 8 X\n SG_ S : 0|8@2+ (1,0) [0|0] \"\" X\n", "t.dbc:2: SG_ S: byte order must be"},
        {"BO_ 1 M: 8 X\n SG_ S : 0|8@1+ (1,nan) [0|0] \"\" X\n", "t.dbc:2: SG_ S: expected (factor,offset)"},
        {"BO_ 1 M: 2 X\n SG_ S : 8|16@1+ (1,0) [0|0] \"\" X\n", "t.dbc:2: SG_ S: start bit 8, length 16 (@1) does not fit"},
        {"BO_ 1 M: 8 X\n\n SG_ S : 0|8@1+ (1,0) [0|0] \"unit X\n", "t.dbc:3: SG_ S: expected a \"unit\""},
        {" SG_ S : 0|8@1+ (1,0) [0|0] \"\" X\n", "t.dbc:1: SG_ outside a message"},
        {"BO_ 1 M: 8 X\n SG_ S : 0|8@1+ (1,0) [0|0] \"\" X\nSIG_VALTYPE_ 1 S : 1;\n",
         "t.dbc:3: SIG_VALTYPE_ S: float needs a 32-bit signal"},
        /* a value type or multiplex range naming a signal or message that does not exist:
         * the intended float would be decoded as an integer (issue 12) */
        {"BO_ 1 M: 8 X\n SG_ S : 0|32@1+ (1,0) [0|0] \"\" X\n\nSIG_VALTYPE_ 1 T : 1;\n",
         "t.dbc:4: SIG_VALTYPE_ 1 T: message M has no signal 'T'"},
        {"BO_ 1 M: 8 X\n SG_ S : 0|32@1+ (1,0) [0|0] \"\" X\nSIG_VALTYPE_ 2 S : 1;\n",
         "t.dbc:3: SIG_VALTYPE_ 2 S: no message with this id"},
        {"BO_ 10 M: 8 X\n SG_ S M : 0|8@1+ (1,0) [0|0] \"\" X\n SG_ B m2 : 8|8@1+ (1,0) [0|0] \"\" X\n"
         "SG_MUL_VAL_ 10 C S 2-3;\n",
         "t.dbc:4: SG_MUL_VAL_ 10 C: message M has no signal 'C'"},
        {"BO_ 1 A: 8 X\nBO_ 1 B: 8 X\n", "t.dbc:2: BO_ B: duplicate message id 0x1 (also A at line 1)"},
        {"BO_ 1 M: 8 X\n SG_ S m1 : 0|8@1+ (1,0) [0|0] \"\" X\n", "t.dbc:2: SG_ S: multiplexed signal in message M that has no multiplexor"},
        {"CM_ \"never closed\n\n", "t.dbc:1: unterminated string"},
        {"}}} garbage\n", "t.dbc:1: expected a keyword at the start of the line, found byte 0x7D"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        vibid_drv_error err;
        vibid_dbc *d = parse(cases[i].text, &err);
        if (d || !strstr(err.text, cases[i].expect))
            fail_msg("case %zu: expected error containing '%s', got %s '%s'", i, cases[i].expect,
                     d ? "success" : "error", err.text);
        assert_int_equal(err.status, VIBID_DRV_E_SYNTAX);
    }
}

static void test_load_file_errors(void **state)
{
    (void)state;
    vibid_drv_error err = {0};
    assert_null(vibid_dbc_load("/nonexistent/x.dbc", &err));
    assert_int_equal(err.status, VIBID_DRV_E_IO);
    assert_non_null(strstr(err.text, "/nonexistent/x.dbc"));
    vibid_dbc *d = vibid_dbc_load(VIBID_DRV_TESTDATA "/fd64.dbc", &err);
    assert_non_null(d);
    assert_int_equal(vibid_dbc_message_count(d), 4);
    assert_non_null(vibid_dbc_find_message_by_name(d, "FD64_Std"));
    vibid_dbc_destroy(d);
    vibid_dbc_destroy(NULL);
}

/* Encoding (vibidd's candump recording) against the decoder, which dbc_vs_cantools.py
 * checks bit for bit against cantools: for every non-multiplexed signal of every shared
 * DBC file (written elsewhere) and 200 pseudo-random raw values each, put_raw into a
 * random payload must (1) read back as the same raw and (2) leave every signal that does
 * not overlap it unchanged; and encode(decode(frame)) must reproduce the signal's bits
 * exactly for integer signals and for float signals with factor 1, offset 0. */
static uint64_t rng_next(uint64_t *s)
{
    *s ^= *s << 13;
    *s ^= *s >> 7;
    *s ^= *s << 17;
    return *s;
}

static bool overlaps(const vibid_dbc_message *m, const vibid_dbc_signal *a, const vibid_dbc_signal *b)
{
    uint8_t fa[64] = {0}, fb[64] = {0};
    vibid_dbc_signal_put_raw(a, fa, m->length, ~UINT64_C(0));
    vibid_dbc_signal_put_raw(b, fb, m->length, ~UINT64_C(0));
    for (size_t i = 0; i < m->length; i++)
        if (fa[i] & fb[i])
            return true;
    return false;
}

static void test_encode_inverts_decode(void **state)
{
    (void)state;
    char cmd[600];
    snprintf(cmd, sizeof cmd, "ls %s/*.dbc", VIBID_SHARED_DBC_DIR);
    FILE *ls = popen(cmd, "r");
    assert_non_null(ls);
    char path[512];
    uint64_t seed = 0x9E3779B97F4A7C15ull;
    size_t files = 0, signals = 0, checks = 0;
    while (fgets(path, sizeof path, ls)) {
        path[strcspn(path, "\n")] = '\0';
        vibid_drv_error err = {0};
        vibid_dbc *d = vibid_dbc_load(path, &err);
        if (!d)
            continue; /* files the reader refuses are covered by the cantools cross-check */
        files++;
        for (size_t mi = 0; mi < vibid_dbc_message_count(d); mi++) {
            const vibid_dbc_message *m = vibid_dbc_message_at(d, mi);
            for (size_t si = 0; si < m->n_signals; si++) {
                const vibid_dbc_signal *sg = &m->signals[si];
                if (sg->mux_role == VIBID_DBC_MULTIPLEXED || sg->min_bytes > m->length)
                    continue;
                signals++;
                for (int rep = 0; rep < 200; rep++) {
                    uint8_t data[64], before[64];
                    for (size_t b = 0; b < sizeof data; b++)
                        data[b] = (uint8_t)rng_next(&seed);
                    memcpy(before, data, sizeof data);
                    uint64_t raw = rng_next(&seed), got = 0;
                    uint64_t mask = sg->length >= 64 ? ~UINT64_C(0) : (UINT64_C(1) << sg->length) - 1u;
                    assert_int_equal(vibid_dbc_signal_put_raw(sg, data, m->length, raw), VIBID_DRV_OK);
                    assert_int_equal(vibid_dbc_signal_raw(sg, data, m->length, &got), VIBID_DRV_OK);
                    if (got != (raw & mask))
                        fail_msg("%s: %s.%s: put 0x%llx, read 0x%llx", path, m->name, sg->name,
                                 (unsigned long long)(raw & mask), (unsigned long long)got);
                    for (size_t oi = 0; oi < m->n_signals; oi++) {
                        const vibid_dbc_signal *o = &m->signals[oi];
                        if (oi == si || o->min_bytes > m->length || overlaps(m, sg, o))
                            continue;
                        uint64_t r0, r1;
                        vibid_dbc_signal_raw(o, before, m->length, &r0);
                        vibid_dbc_signal_raw(o, data, m->length, &r1);
                        if (r0 != r1)
                            fail_msg("%s: writing %s.%s changed %s", path, m->name, sg->name, o->name);
                    }
                    /* encode(decode) round trip */
                    bool exact = sg->value_type == VIBID_DBC_INTEGER || (sg->factor == 1.0 && sg->offset == 0.0);
                    double phys;
                    assert_int_equal(vibid_dbc_signal_decode(sg, data, m->length, &phys), VIBID_DRV_OK);
                    bool nan_float = sg->value_type != VIBID_DBC_INTEGER && phys != phys;
                    if (exact && !nan_float) {
                        uint8_t again[64] = {0};
                        vibid_drv_status st = vibid_dbc_signal_encode(sg, phys, again, m->length);
                        if (st != VIBID_DRV_OK)
                            fail_msg("%s: %s.%s: encode(%.17g) failed (%d)", path, m->name, sg->name, phys, st);
                        uint64_t r2;
                        vibid_dbc_signal_raw(sg, again, m->length, &r2);
                        /* integers beyond 2^53 lose bits in the double: compare what a double holds */
                        if (r2 != got && !(sg->value_type == VIBID_DBC_INTEGER && sg->length > 53))
                            fail_msg("%s: %s.%s: raw 0x%llx -> %.17g -> raw 0x%llx", path, m->name, sg->name,
                                     (unsigned long long)got, phys, (unsigned long long)r2);
                    }
                    checks++;
                }
            }
        }
        vibid_dbc_destroy(d);
    }
    pclose(ls);
    print_message("encode vs decode: %zu files, %zu signals, %zu round trips\n", files, signals, checks);
    assert_true(files >= 5 && signals >= 100); /* the shared set has 9 files, hundreds of signals */
    /* out of range and non-finite values are refused, the payload untouched */
    vibid_drv_error err;
    vibid_dbc *d = parse("BO_ 1 M: 8 X\n SG_ U : 0|8@1+ (1,0) [0|0] \"\" X\n SG_ S : 8|8@1- (0.5,0) [0|0] \"\" X\n",
                         &err);
    assert_non_null(d);
    const vibid_dbc_message *m = vibid_dbc_find_message(d, 1, false);
    uint8_t data[8] = {0};
    assert_int_equal(vibid_dbc_signal_encode(vibid_dbc_find_signal(m, "U"), 256.0, data, 8), VIBID_DRV_E_RANGE);
    assert_int_equal(vibid_dbc_signal_encode(vibid_dbc_find_signal(m, "U"), -1.0, data, 8), VIBID_DRV_E_RANGE);
    assert_int_equal(vibid_dbc_signal_encode(vibid_dbc_find_signal(m, "S"), 64.0, data, 8), VIBID_DRV_E_RANGE);
    assert_int_equal(vibid_dbc_signal_encode(vibid_dbc_find_signal(m, "S"), NAN, data, 8), VIBID_DRV_E_RANGE);
    assert_int_equal(vibid_dbc_signal_encode(vibid_dbc_find_signal(m, "S"), -64.0, data, 8), VIBID_DRV_OK);
    assert_int_equal(data[1], 0x80);
    assert_int_equal(data[0], 0);
    vibid_dbc_destroy(d);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_intel_motorola_by_hand),
        cmocka_unit_test(test_float_and_ext),
        cmocka_unit_test(test_mux),
        cmocka_unit_test(test_skips_unknown_and_multiline),
        cmocka_unit_test(test_syntax_errors_name_line),
        cmocka_unit_test(test_load_file_errors),
        cmocka_unit_test(test_encode_inverts_decode),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
