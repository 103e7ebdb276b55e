/* Modbus register maps: libconfig parsing with file:line errors, and decoding of every
 * type in every byte order against hand-computed register patterns. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>
#include <vibid_drivers/register_map.h>

static vibid_regmap *from_text(const char *text, vibid_drv_error *err)
{
    config_t cfg;
    config_init(&cfg);
    memset(err, 0, sizeof *err);
    if (!config_read_string(&cfg, text)) {
        fail_msg("libconfig: %s at line %d", config_error_text(&cfg), config_error_line(&cfg));
    }
    vibid_cfg_error ce = {0};
    vibid_cfg_reader r = {"map.cfg", &ce};
    vibid_regmap *m = vibid_regmap_read(&r, config_lookup(&cfg, "registers"), "registers");
    if (!m) vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s", ce.text);
    config_destroy(&cfg);
    return m;
}

static void test_orders(void **state)
{
    (void)state;
    vibid_drv_error err;
    vibid_regmap *m = from_text(
        "registers = (\n"
        " { name = \"f_abcd\"; address = 0; type = \"FLOAT32\"; byte_order = \"ABCD\"; },\n"
        " { name = \"f_cdab\"; address = 2; type = \"FLOAT32\"; byte_order = \"CDAB\"; },\n"
        " { name = \"f_badc\"; address = 4; type = \"FLOAT32\"; byte_order = \"BADC\"; },\n"
        " { name = \"f_dcba\"; address = 6; type = \"FLOAT32\"; byte_order = \"DCBA\"; },\n"
        " { name = \"i16\"; address = 8; type = \"INT16\"; scale = 0.5; register = \"input\"; },\n"
        " { name = \"i16s\"; address = 9; type = \"INT16\"; byte_order = \"BADC\"; },\n"
        " { name = \"u32\"; address = 10; type = \"UINT32\"; byte_order = \"CDAB\"; offset = -1; },\n"
        " { name = \"d\"; address = 12; type = \"FLOAT64\"; byte_order = \"CDAB\"; }\n"
        ");\n",
        &err);
    assert_non_null(m);
    assert_int_equal(m->n, 8);
    /* 1.5f = 0x3FC00000: A=3F B=C0 C=00 D=00 */
    uint16_t regs[16] = {0x3FC0, 0x0000, 0x0000, 0x3FC0, 0xC03F, 0x0000, 0x0000, 0xC03F,
                         0xFFFE, /* INT16 -2 */ 0xFEFF /* -2 byte-swapped */,
                         0x5678, 0x1234, /* UINT32 0x12345678 word-swapped */
                         /* 2.5 = 0x4004000000000000, CDAB: GH EF CD AB */
                         0x0000, 0x0000, 0x0000, 0x4004};
    const char *names[] = {"f_abcd", "f_cdab", "f_badc", "f_dcba"};
    double v;
    for (int i = 0; i < 4; i++) {
        assert_int_equal(vibid_reg_decode(vibid_regmap_find(m, names[i]), regs, 16, 0, &v), VIBID_DRV_OK);
        assert_true(v == 1.5);
    }
    const vibid_reg_entry *e = vibid_regmap_find(m, "i16");
    assert_int_equal(e->kind, VIBID_REG_INPUT);
    assert_int_equal(vibid_reg_decode(e, regs, 16, 0, &v), VIBID_DRV_OK);
    assert_true(v == -1.0);
    assert_int_equal(vibid_reg_decode(vibid_regmap_find(m, "i16s"), regs, 16, 0, &v), VIBID_DRV_OK);
    assert_true(v == -2.0);
    assert_int_equal(vibid_reg_decode(vibid_regmap_find(m, "u32"), regs, 16, 0, &v), VIBID_DRV_OK);
    assert_true(v == 305419896.0 - 1.0);
    assert_int_equal(vibid_reg_decode(vibid_regmap_find(m, "d"), regs, 16, 0, &v), VIBID_DRV_OK);
    assert_true(v == 2.5);
    /* outside the block that was read */
    assert_int_equal(vibid_reg_decode(vibid_regmap_find(m, "d"), regs, 15, 0, &v), VIBID_DRV_E_RANGE);
    assert_int_equal(vibid_reg_decode(vibid_regmap_find(m, "f_abcd"), regs, 16, 1, &v), VIBID_DRV_E_RANGE);
    /* encode is the exact inverse for every entry */
    for (size_t i = 0; i < m->n; i++) {
        uint16_t w[4];
        double x;
        vibid_reg_decode(&m->entries[i], regs, 16, 0, &x);
        assert_int_equal(vibid_reg_encode(&m->entries[i], x, w), VIBID_DRV_OK);
        assert_memory_equal(w, regs + m->entries[i].address, 2 * vibid_reg_type_words(m->entries[i].type));
    }
    uint16_t w[4];
    assert_int_equal(vibid_reg_encode(vibid_regmap_find(m, "i16s"), 40000.0, w), VIBID_DRV_E_RANGE);
    vibid_regmap_destroy(m);
}

static void test_errors(void **state)
{
    (void)state;
    /* Each error names the file, the entry's line and field (the configuration reader's
     * "file:line: field: reason"). */
    static const char *cases[][2] = {
        {"registers = (\n{ name = \"a\"; address = 70000; type = \"INT16\"; });",
         "map.cfg:2: registers.[0].address: 70000 outside [0, 65535]"},
        {"registers = (\n{ name = \"a\"; address = 1; type = \"INT64\"; });",
         "map.cfg:2: registers.[0].type: 'INT64' is not one of INT16, UINT16, INT32, UINT32, FLOAT32, "
         "FLOAT64"},
        {"registers = (\n{ name = \"a\"; address = 1; type = \"INT16\"; byte_order = \"AB\"; });",
         "registers.[0].byte_order: 'AB' is not one of ABCD, DCBA, BADC, CDAB"},
        {"registers = (\n{ name = \"a\"; address = 1; type = \"INT16\"; register = \"coil\"; });",
         "registers.[0].register: 'coil' is not one of holding, input"},
        {"registers = (\n{ name = \"a\"; address = 65535; type = \"FLOAT32\"; });",
         "registers.[0].address: 65535 + 2 registers of FLOAT32 runs past register 65535"},
        {"registers = (\n{ name = \"a\"; address = 1; type = \"INT16\"; },\n{ name = \"a\"; address = 2; "
         "type = \"INT16\"; });",
         "map.cfg:3: registers.[1].name: 'a' used twice (line 2)"},
        {"registers = (\n{ address = 1; type = \"INT16\"; });",
         "map.cfg:2: registers.[0].name: missing (a string)"},
        {"registers = (\n{ name = \"a\"; address = 1; type = \"INT16\"; scale = 0.0; });",
         "registers.[0].scale: must not be 0"},
        /* a misspelt key is an error, not "not given" (issue 12: one configuration reader) */
        {"registers = (\n{ name = \"a\"; address = 1; type = \"INT16\"; byteorder = \"DCBA\"; });",
         "map.cfg:2: registers.[0].byteorder: unknown setting 'byteorder' (known: name, address, register, "
         "kind, "
         "type, byte_order, scale, offset)"},
        {"registers = (\n{ name = \"a\"; address = 1.5; type = \"INT16\"; });",
         "registers.[0].address: must be an integer"},
        {"registers = (\n{ name = \"a\"; address = 1; type = \"INT16\"; register = \"input\"; kind = "
         "\"input\"; });",
         "registers.[0].kind: give register or kind, not both"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        vibid_drv_error err;
        vibid_regmap *m = from_text(cases[i][0], &err);
        if (m || !strstr(err.text, cases[i][1]))
            fail_msg("case %zu: expected '%s', got '%s'", i, cases[i][1], err.text);
    }
    vibid_drv_error err = {0};
    assert_null(vibid_regmap_load("/nonexistent.cfg", &err));
    assert_int_equal(err.status, VIBID_DRV_E_IO);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_orders),
        cmocka_unit_test(test_errors),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
