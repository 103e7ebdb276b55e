/* Channel map: a valid map read with every field and default, and each configuration
 * error reported with file:line and the field's name. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>
#include <vibid_drivers/channel_map.h>

#include "support/drv_test_util.h"

static vibid_drv_status load_text(const char *text, vibid_chanmap *map, vibid_drv_error *err, char *path)
{
    assert_non_null(drv_write_tmp("chanmap.cfg", text, strlen(text), path, 512));
    vibid_drv_status st = vibid_chanmap_load(path, map, err);
    unlink(path);
    return st;
}

static void test_valid_map(void **state)
{
    (void)state;
    static const char text[] =
        "# stand channels\n"
        "channels = (\n"
        "  { name = \"F1\"; quantity = \"force\"; node = 0; unit = \"N\"; signal = \"Force1\"; },\n"
        "  { name = \"x1\"; quantity = \"displacement\"; node = 0; unit = \"m\"; signal = \"Pos1\"; message = \"Sample_A\"; },\n"
        "  { name = \"v2\"; quantity = \"velocity\"; node = 1; register = \"v2\"; },\n"
        "  { name = \"a2\"; quantity = \"acceleration\"; node = 1; unit = \"m/s^2\"; column = \"acc\"; },\n"
        "  { name = \"xb\"; quantity = \"base_displacement\"; column = \"xb\"; },\n"
        "  { name = \"T\"; quantity = \"covariate\"; unit = \"degC\"; signal = \"Temp\"; }\n"
        ");\n"
        "counter = \"SampleCounter\";\n"
        "trigger = \"Sample_A\";\n"
        "time_column = \"t\";\n";
    vibid_chanmap map;
    vibid_drv_error err = {0};
    char path[512];
    assert_int_equal(load_text(text, &map, &err, path), VIBID_DRV_OK);
    assert_int_equal(map.n, 6);
    assert_string_equal(map.ch[0].name, "F1");
    assert_int_equal(map.ch[0].quantity, VIBID_Q_FORCE);
    assert_true(map.ch[0].is_input);
    assert_int_equal(map.ch[0].source, VIBID_CHAN_SIGNAL);
    assert_string_equal(map.ch[0].ref, "Force1");
    assert_string_equal(map.ch[0].unit, "N");
    assert_string_equal(map.ch[0].message, "");
    assert_int_equal(map.ch[0].line, 3);
    assert_string_equal(map.ch[1].message, "Sample_A");
    assert_false(map.ch[1].is_input);
    assert_int_equal(map.ch[2].quantity, VIBID_Q_VELOCITY);
    assert_int_equal(map.ch[2].source, VIBID_CHAN_REGISTER);
    assert_int_equal(map.ch[2].node, 1);
    assert_string_equal(map.ch[2].unit, "");
    assert_int_equal(map.ch[3].quantity, VIBID_Q_ACCELERATION);
    assert_int_equal(map.ch[3].source, VIBID_CHAN_COLUMN);
    assert_string_equal(map.ch[3].ref, "acc");
    assert_int_equal(map.ch[4].quantity, VIBID_Q_BASE_DISPLACEMENT);
    assert_true(map.ch[4].is_input);
    assert_int_equal(map.ch[4].node, -1); /* the base is not a node */
    assert_int_equal(map.ch[5].quantity, VIBID_Q_COVARIATE); /* an operating condition: neither ... */
    assert_false(map.ch[5].is_input);                        /* ... input nor (by quantity) output */
    assert_int_equal(map.ch[5].node, -1);
    assert_string_equal(map.ch[5].unit, "degC");             /* any label */
    assert_string_equal(vibid_quantity_name(VIBID_Q_COVARIATE), "covariate");
    assert_string_equal(map.counter, "SampleCounter");
    assert_string_equal(map.trigger, "Sample_A");
    assert_string_equal(map.time_column, "t");
    assert_string_equal(vibid_quantity_name(VIBID_Q_BASE_DISPLACEMENT), "base_displacement");
    assert_string_equal(vibid_quantity_name((vibid_quantity)99), "unknown");
}

/* Each bad map: the error must name the file's line and say what is wrong. */
static void test_errors(void **state)
{
    (void)state;
    static const struct {
        const char *text;
        vibid_drv_status status;
        const char *expect;
    } cases[] = {
        {"counter = \"c\";\n", VIBID_DRV_E_SYNTAX, "chanmap.cfg: channels: missing (a list"},
        /* issue 12, item 9: unknown keys are errors, not "not given" */
        {"foo = 1;\n", VIBID_DRV_E_SYNTAX,
         ":1: foo: unknown setting 'foo' (known: channels, counter, trigger, time_column)"},
        {"channels = (\n { name = \"x\"; quantity = \"displacement\"; node = 0;\n   units = \"mm\"; column = "
         "\"x\"; }\n);\n",
         VIBID_DRV_E_SYNTAX,
         ":3: channels.[0].units: unknown setting 'units' (known: name, quantity, node, unit, signal"},
        {"channels = (\n { name = \"s\"; quantity = \"base_velocity\"; node = 3; column = \"s\"; }\n);\n",
         VIBID_DRV_E_SYNTAX,
         ":2: channels.[0].node: a base_velocity belongs to the base, not to a node: omit node"},
        {"channels = (\n { name = \"T\"; quantity = \"covariate\"; node = 0; column = \"T\"; }\n);\n",
         VIBID_DRV_E_SYNTAX,
         ":2: channels.[0].node: a covariate belongs to the stand, not to a node: omit node"},
        {"channels = ();\n", VIBID_DRV_E_RANGE, ":1: channels: 0 channels, allowed 1..32"},
        {"channels = (\n { quantity = \"force\"; node = 0; signal = \"F\"; }\n);\n", VIBID_DRV_E_SYNTAX,
         ":2: channels.[0].name: missing (the stand's channel name"},
        {"channels = (\n { name = \"F\"; node = 0; signal = \"F\"; }\n);\n", VIBID_DRV_E_SYNTAX,
         ":2: channels.[0].quantity: missing ("},
        {"channels = (\n { name = \"F\"; quantity = \"torque\"; node = 0; signal = \"F\"; }\n);\n",
         VIBID_DRV_E_SYNTAX, ":2: channels.[0].quantity: 'torque' is not one of displacement, velocity"},
        {"channels = (\n { name = \"F\"; quantity = \"force\"; node = -1; signal = \"F\"; }\n);\n",
         VIBID_DRV_E_SYNTAX, ":2: channels.[0].node: -1 outside [0, "},
        {"channels = (\n { name = \"F\"; quantity = \"force\"; signal = \"F\"; }\n);\n", VIBID_DRV_E_SYNTAX,
         ":2: channels.[0].node: missing (the 0-based index"},
        {"channels = (\n { name = \"F\"; quantity = \"force\"; node = 0; signal = \"F\"; column = \"F\"; "
         "}\n);\n",
         VIBID_DRV_E_SYNTAX,
         ":2: channels.[0]: channel 'F' needs exactly one of signal, register, column (has 2)"},
        {"channels = (\n { name = \"F\"; quantity = \"force\"; node = 0; }\n);\n", VIBID_DRV_E_SYNTAX,
         ":2: channels.[0]: channel 'F' needs exactly one of signal, register, column (has 0)"},
        {"channels = (\n { name = \"F\"; quantity = \"force\"; node = 0; signal = \"\"; }\n);\n",
         VIBID_DRV_E_SYNTAX, ":2: channels.[0].signal: must not be empty"},
        {"channels = (\n { name = \"F\"; quantity = \"force\"; node = 0; signal = \"A\"; },\n"
         " { name = \"F\"; quantity = \"displacement\"; node = 0; signal = \"B\"; }\n);\n",
         VIBID_DRV_E_SYNTAX, ":3: channels.[1].name: channel name 'F' used twice (line 2)"},
        {"channels = ( 1, 2 );\n", VIBID_DRV_E_SYNTAX, ":1: channels.[0]: must be a group { name = "},
        {"channels = (\n { name = \"F\"; quantity = ; }\n);\n", VIBID_DRV_E_SYNTAX, ":2: syntax error"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        vibid_chanmap map;
        vibid_drv_error err = {0};
        char path[512];
        vibid_drv_status st = load_text(cases[i].text, &map, &err, path);
        if (st != cases[i].status || !strstr(err.text, cases[i].expect) || !strstr(err.text, path))
            fail_msg("case %zu: status %d, text '%s'; expected %d and '%s' with the path", i, st, err.text,
                     cases[i].status, cases[i].expect);
    }
    vibid_chanmap map;
    vibid_drv_error err = {0};
    assert_int_equal(vibid_chanmap_load("/nonexistent/dir/map.cfg", &map, &err), VIBID_DRV_E_IO);
    assert_non_null(strstr(err.text, "/nonexistent/dir/map.cfg: cannot read"));
    vibid_cfg_error ce = {0};
    vibid_cfg_reader r = {"x.cfg", &ce};
    assert_int_equal(vibid_chanmap_read(&r, NULL, "", &map), VIBID_DRV_E_ARG);
    assert_non_null(strstr(ce.text, "x.cfg: "));
}

/* 33 channels: one more than the fixed-size map holds. */
static void test_too_many_and_too_long(void **state)
{
    (void)state;
    char text[8192];
    size_t n = (size_t)snprintf(text, sizeof text, "channels = (\n");
    for (int i = 0; i < 33; i++)
        n += (size_t)snprintf(text + n, sizeof text - n,
                              "{ name = \"c%d\"; quantity = \"force\"; node = 0; signal = \"s%d\"; }%s\n", i, i,
                              i < 32 ? "," : "");
    snprintf(text + n, sizeof text - n, ");\n");
    vibid_chanmap map;
    vibid_drv_error err = {0};
    char path[512];
    assert_int_equal(load_text(text, &map, &err, path), VIBID_DRV_E_RANGE);
    assert_non_null(strstr(err.text, ":1: channels: 33 channels, allowed 1..32"));
    /* A name longer than the map keeps is an error naming the field, not a silent cut. */
    char longname[300];
    memset(longname, 'n', 200);
    longname[200] = '\0';
    snprintf(text, sizeof text, "channels = (\n { name = \"F\"; quantity = \"force\"; node = 0; signal = \"%s\"; }\n);\n",
             longname);
    assert_int_equal(load_text(text, &map, &err, path), VIBID_DRV_E_SYNTAX);
    if (!strstr(err.text, ":2: channels.[0].signal: longer than 127 characters"))
        fail_msg("got '%s'", err.text);
    snprintf(text, sizeof text, "channels = (\n { name = \"%s\"; quantity = \"force\"; node = 0; signal = \"F\"; }\n);\n",
             longname);
    assert_int_equal(load_text(text, &map, &err, path), VIBID_DRV_E_SYNTAX);
    if (!strstr(err.text, ":2: channels.[0].name: longer than 127 characters"))
        fail_msg("got '%s'", err.text);
    snprintf(text, sizeof text,
             "channels = (\n { name = \"F\"; quantity = \"force\"; node = 0; unit = \"%.40s\"; signal = \"F\"; }\n);\n",
             longname);
    assert_int_equal(load_text(text, &map, &err, path), VIBID_DRV_E_SYNTAX);
    if (!strstr(err.text, ":2: channels.[0].unit: longer than 31 characters")) fail_msg("got '%s'", err.text);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_valid_map),
        cmocka_unit_test(test_errors),
        cmocka_unit_test(test_too_many_and_too_long),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
