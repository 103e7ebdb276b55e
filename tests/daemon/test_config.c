/* Unit tests of the configuration reader: every error names file, line and field;
 * defaults are filled in; the printed effective configuration reads back identically. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "config.h"

static char dir[256];

static const char *write_cfg(const char *name, const char *text)
{
    static char path[512];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "w");
    assert_non_null(f);
    fputs(text, f);
    fclose(f);
    return path;
}

#define STAND "stand = \"" VD_SOURCE_DIR "/examples/stands/paper_example1.cfg\";\n"
#define SOURCE                                                                                                         \
    "source = {\n"                                                                                                     \
    "  kind = \"replay\";\n"                                                                                           \
    "  file = \"cap.csv\";\n"                                                                                          \
    "  time_column = \"t\";\n"                                                                                         \
    "  channels = (\n"                                                                                                 \
    "    { name = \"x1\"; quantity = \"displacement\"; node = 0; column = \"x1\"; },\n"                                \
    "    { name = \"x2\"; quantity = \"displacement\"; node = 1; column = \"x2\"; },\n"                                \
    "    { name = \"s\"; quantity = \"base_displacement\"; node = 0; column = \"s\"; }\n"                              \
    "  );\n"                                                                                                           \
    "};\n"
/* STAND is line 1, SOURCE lines 2..11; a directive added after them is on line 12. */

static void expect_error(const char *name, const char *text, const char *want_prefix, const char *want_sub)
{
    const char *path = write_cfg(name, text);
    vd_config cfg;
    vd_config_error err;
    int rc = vd_config_load(path, &cfg, &err);
    if (rc == 0)
        vd_config_free(&cfg);
    assert_int_equal(rc, -1);
    char prefix[600];
    snprintf(prefix, sizeof prefix, "%s%s", path, want_prefix);
    if (strncmp(err.text, prefix, strlen(prefix)) != 0 || !strstr(err.text, want_sub)) {
        print_error("got: %s\nwant prefix: %s\nwant substring: %s\n", err.text, prefix, want_sub);
        fail();
    }
}

/* estimator.refine_every: on by default (10 s, window max(10 s, 3 memories)) where the
 * output-error fit accepts the stand and the method; an explicit value where it cannot run
 * is an error naming why; the window at least 8 blocks of 50 samples. */
static void test_refine(void **state)
{
    (void)state;
    vd_config cfg;
    vd_config_error err;
    assert_int_equal(vd_config_load(write_cfg("refine_default.cfg", STAND SOURCE), &cfg, &err), 0);
    assert_true(cfg.refine_every_s == 10.0 && cfg.refine_window_s == 10.0);
    vd_config_free(&cfg);
    assert_int_equal(
        vd_config_load(write_cfg("refine_mem.cfg", STAND SOURCE "estimator = { forgetting = 0.9999; };\n"), &cfg, &err),
        0);
    assert_true(fabs(cfg.refine_window_s - 3.0 / (cfg.sample_rate * 1e-4)) < 1e-6 * cfg.refine_window_s);
    vd_config_free(&cfg);
    assert_int_equal(
        vd_config_load(write_cfg("refine_ekf.cfg", STAND SOURCE "estimator = { method = \"ekf\"; };\n"), &cfg, &err), 0);
    assert_true(cfg.refine_every_s == 0.0);
    vd_config_free(&cfg);
    expect_error("refine_ekf2.cfg", STAND SOURCE "estimator = { method = \"ekf\"; refine_every = 5.0; };\n",
                 ":12: estimator.refine_every:", "not an equation-error estimator");
    expect_error("refine_win.cfg", STAND SOURCE "estimator = { refine_window = 0.1; };\n", ":12: estimator.refine_window:",
                 "outside");
}

static void test_syntax_error(void **state)
{
    (void)state;
    expect_error("syntax.cfg", STAND "source = {\n kind = \"replay\";\n file = ; };\n", ":4: syntax error", "syntax error");
}

static void test_range_error(void **state)
{
    (void)state;
    expect_error("range.cfg", STAND SOURCE "estimator = { forgetting = 1.5; };\n", ":12: estimator.forgetting:",
                 "1.5 outside [0.9, 1]");
    expect_error("range2.cfg", STAND SOURCE "estimator = {\n  decimation = 0;\n};\n", ":13: estimator.decimation:",
                 "0 outside [1, 10000000]");
    expect_error("range3.cfg", STAND SOURCE "estimator = { prefilter_hz = 2000.0; };\n",
                 ":12: estimator.prefilter_hz:", "outside [0, 900]");
    expect_error("range4.cfg", STAND SOURCE "acquisition = { handoff_spin = 20000; };\n",
                 ":12: acquisition.handoff_spin:", "20000 outside [0, 10000]");
}

static void test_type_error(void **state)
{
    (void)state;
    expect_error("type.cfg", STAND SOURCE "acquisition = { lock_memory = 1; };\n", ":12: acquisition.lock_memory:",
                 "true or false");
    expect_error("type2.cfg", STAND SOURCE "estimator = { method = \"kalman\"; };\n", ":12: estimator.method:",
                 "'kalman' is not one of ls, iv, rls");
    /* a candump recording needs the DBC of a CAN source; this one replays CSV */
    expect_error("rec.cfg", STAND SOURCE "outputs = { record = { path = \"r.log\"; format = \"candump\"; }; };\n",
                 ":12: outputs.record.format:", "needs a CAN source");
}

static void test_unknown_directive(void **state)
{
    (void)state;
    expect_error("unknown.cfg", STAND SOURCE "estimator = { forgeting = 0.99; };\n", ":12: estimator.forgeting:",
                 "unknown setting 'forgeting' (known: method, forgetting, ");
    expect_error("unknown2.cfg", STAND SOURCE "output = { };\n", ":12: output:", "unknown setting 'output' (known: stand, ");
}

/* outputs.prometheus: absent = off, the group alone = loopback on the default port, a
 * given address kept; a host name or a bad port is refused naming the field; the printout
 * carries it (and reads back: test_defaults_and_roundtrip prints the default). */
static void test_prometheus(void **state)
{
    (void)state;
    vd_config cfg;
    vd_config_error err;
    assert_int_equal(vd_config_load(write_cfg("p0.cfg", STAND SOURCE), &cfg, &err), 0);
    assert_string_equal(cfg.prometheus.listen, "");
    vd_config_free(&cfg);
    assert_int_equal(vd_config_load(write_cfg("p1.cfg", STAND SOURCE "outputs = { prometheus = { }; };\n"), &cfg, &err),
                     0);
    assert_string_equal(cfg.prometheus.listen, "127.0.0.1:18813");
    char *p = NULL;
    size_t n = 0;
    FILE *o = open_memstream(&p, &n);
    vd_config_print(&cfg, o);
    fclose(o);
    assert_non_null(strstr(p, "  prometheus = { listen = \"127.0.0.1:18813\"; };"));
    free(p);
    vd_config_free(&cfg);
    assert_int_equal(vd_config_load(write_cfg("p2.cfg", STAND SOURCE
                                              "outputs = { prometheus = { listen = \"[::1]:9999\"; }; };\n"),
                                    &cfg, &err),
                     0);
    assert_string_equal(cfg.prometheus.listen, "[::1]:9999");
    vd_config_free(&cfg);
    expect_error("p3.cfg", STAND SOURCE "outputs = { prometheus = { listen = \"example.org:9100\"; }; };\n",
                 ":12: outputs.prometheus.listen:", "'example.org' is not an IPv4 address");
    expect_error("p4.cfg", STAND SOURCE "outputs = { prometheus = { listen = \"127.0.0.1:70000\"; }; };\n",
                 ":12: outputs.prometheus.listen:", "port '70000' outside 0..65535");
    expect_error("p5.cfg", STAND SOURCE "outputs = { prometheus = { listen = \"::1:9100\"; }; };\n",
                 ":12: outputs.prometheus.listen:", "needs brackets");
    expect_error("p6.cfg", STAND SOURCE "outputs = { prometheus = { port = 9100; }; };\n",
                 ":12: outputs.prometheus.port:", "unknown setting 'port' (known: listen)");
    expect_error("p7.cfg", STAND SOURCE "outputs = { prometheus = \"127.0.0.1:1\"; };\n", ":12: outputs.prometheus:",
                 "must be a group");
}

static void test_ring_power_of_two(void **state)
{
    (void)state;
    expect_error("ring.cfg", STAND SOURCE "acquisition = { ring_size = 1000; };\n", ":12: acquisition.ring_size:",
                 "not a power of two");
}

static void test_missing_parts(void **state)
{
    (void)state;
    /* nothing to point at: file and field, no line */
    expect_error("nosrc.cfg", STAND, ": source:", "missing");
    expect_error("nostand.cfg", SOURCE, ": stand:", "missing");
    expect_error("nokind.cfg", STAND "source = { file = \"x.csv\"; };\n", ":2: source.kind:", "missing");
}

static void test_stand_errors(void **state)
{
    (void)state;
    /* a stand file that does not exist: the message names it and where it was referenced */
    const char *path = write_cfg("badstand.cfg", "stand = \"/nonexistent/stand.cfg\";\n" SOURCE);
    vd_config cfg;
    vd_config_error err;
    assert_int_equal(vd_config_load(path, &cfg, &err), -1);
    assert_non_null(strstr(err.text, "/nonexistent/stand.cfg"));
    assert_non_null(strstr(err.text, "badstand.cfg:1"));
    /* an inline stand with a bad element kind: the loader's file:line:field */
    expect_error("inline.cfg",
                 "stand = {\n sample_rate = 1000.0;\n nodes = ( { name = \"m1\"; mass = 1.0; measure = { displacement "
                 "= \"x1\"; }; } );\n elements = ( { name = \"c\"; kind = \"sprung\"; between = [\"m1\", \"ground\"]; "
                 "unknown = true; } );\n};\n" SOURCE,
                 ":4: stand.elements.[0].kind", "sprung");
}

static void test_channel_missing(void **state)
{
    (void)state;
    expect_error("chan.cfg",
                 STAND "source = {\n  kind = \"replay\";\n  file = \"cap.csv\";\n  time_column = \"t\";\n"
                       "  channels = (\n    { name = \"x1\"; quantity = \"displacement\"; node = 0; column = \"x1\"; }\n"
                       "  );\n};\n",
                 ":6: source.channels:", "needs channel 'x2'");
}

/* SOURCE with channel x2's line (line 8 of the file) replaced. */
#define SOURCE_X2(x2)                                                                                                  \
    "source = {\n"                                                                                                     \
    "  kind = \"replay\";\n"                                                                                           \
    "  file = \"cap.csv\";\n"                                                                                          \
    "  time_column = \"t\";\n"                                                                                         \
    "  channels = (\n"                                                                                                 \
    "    { name = \"x1\"; quantity = \"displacement\"; node = 0; unit = \"mm\"; column = \"x1\"; },\n"                 \
    "    " x2 ",\n"                                                                                                    \
    "    { name = \"s\"; quantity = \"base_displacement\"; unit = \"um\"; column = \"s\"; }\n"                         \
    "  );\n"                                                                                                           \
    "};\n"

static double model_scale_of(const char *name, const char *text, size_t channel)
{
    const char *path = write_cfg(name, text);
    vd_config cfg;
    vd_config_error err;
    if (vd_config_load(path, &cfg, &err) != 0)
        fail_msg("%s", err.text);
    double s = cfg.model_scale[channel];
    vd_config_free(&cfg);
    return s;
}

/* Issue 32, item 3: covariate channels (operating conditions) are collected in map order
 * with their unit label; their names head columns of the tracks, so a parameter's name or a
 * fixed column's is refused, and so is a fifth (the change test models at most 4). */
#define SOURCE_COV(extra)                                                                                              \
    "source = {\n"                                                                                                     \
    "  kind = \"replay\";\n"                                                                                           \
    "  file = \"cap.csv\";\n"                                                                                          \
    "  channels = (\n"                                                                                                 \
    "    { name = \"x1\"; quantity = \"displacement\"; node = 0; column = \"x1\"; },\n"                                \
    "    { name = \"x2\"; quantity = \"displacement\"; node = 1; column = \"x2\"; },\n"                                \
    "    { name = \"s\"; quantity = \"base_displacement\"; column = \"s\"; }" extra "\n"                              \
    "  );\n"                                                                                                           \
    "};\n"
static void test_covariates(void **state)
{
    (void)state;
    const char *path = write_cfg("cov.cfg", STAND SOURCE_COV(",\n    { name = \"T\"; quantity = \"covariate\"; "
                                                              "unit = \"degC\"; column = \"T\"; },\n"
                                                              "    { name = \"speed\"; quantity = \"covariate\"; "
                                                              "column = \"n\"; }"));
    vd_config cfg;
    vd_config_error err;
    if (vd_config_load(path, &cfg, &err) != 0)
        fail_msg("%s", err.text);
    assert_int_equal(cfg.n_covariates, 2);
    assert_int_equal(cfg.cov_chan[0], 3);
    assert_int_equal(cfg.cov_chan[1], 4);
    assert_string_equal(cfg.cov_unit[0], "degC");
    assert_string_equal(cfg.cov_unit[1], "");
    vd_config_free(&cfg);
    expect_error("cov_clash.cfg",
                 STAND SOURCE_COV(",\n    { name = \"c2\"; quantity = \"covariate\"; column = \"T\"; }"),
                 ":9: source.channels:", "covariate 'c2' has the name of a column of the tracks");
    expect_error("cov_node.cfg",
                 STAND SOURCE_COV(",\n    { name = \"T\"; quantity = \"covariate\"; node = 1; column = \"T\"; }"),
                 ":9: source.channels.[3].node:", "a covariate belongs to the stand, not to a node: omit node");
    expect_error("cov_many.cfg",
                 STAND SOURCE_COV(",\n    { name = \"T1\"; quantity = \"covariate\"; column = \"T1\"; },"
                                  " { name = \"T2\"; quantity = \"covariate\"; column = \"T2\"; },"
                                  " { name = \"T3\"; quantity = \"covariate\"; column = \"T3\"; },"
                                  " { name = \"T4\"; quantity = \"covariate\"; column = \"T4\"; },"
                                  " { name = \"T5\"; quantity = \"covariate\"; column = \"T5\"; }"),
                 ":9: source.channels:", "covariate 'T5': at most 4 covariate channels");
}

/* Issue 12, item 9: the channel map's quantity, node and unit are checked against the
 * stand; units are converted to the stand's, or refused. Before, x2 declared a force on
 * node 7 in kN loaded, and every unit was ignored. */
static void test_channel_units(void **state)
{
    (void)state;
    /* the case: the stand reads x2 as m2's displacement (node 1) */
    expect_error("q_node.cfg",
                 STAND SOURCE_X2("{ name = \"x2\"; quantity = \"force\"; node = 7; unit = \"kN\"; column = \"x2\"; }"),
                 ":8: source.channels.x2:", "declared as force on node 7, but the stand reads channel 'x2' as "
                                            "m2.displacement (displacement on node 1)");
    expect_error("node.cfg",
                 STAND SOURCE_X2("{ name = \"x2\"; quantity = \"displacement\"; node = 0; column = \"x2\"; }"),
                 ":8: source.channels.x2:", "declared as displacement on node 0");
    expect_error("base_as_node.cfg",
                 STAND SOURCE_X2("{ name = \"x2\"; quantity = \"base_displacement\"; column = \"x2\"; }"),
                 ":8: source.channels.x2:", "declared as base_displacement");
    /* a unit of another dimension, a unit nobody knows */
    expect_error("unit_dim.cfg",
                 STAND SOURCE_X2("{ name = \"x2\"; quantity = \"displacement\"; node = 1; unit = \"kN\"; column = \"x2\"; }"),
                 ":8: source.channels.x2.unit:", "'kN' is not a length unit for a displacement channel (m, cm, mm");
    expect_error("unit_typo.cfg",
                 STAND SOURCE_X2("{ name = \"x2\"; quantity = \"displacement\"; node = 1; unit = \"mmm\"; column = \"x2\"; }"),
                 ":8: source.channels.x2.unit:", "'mmm' is not a length unit");
    /* a misspelt key is not "not given" */
    expect_error("unit_key.cfg",
                 STAND SOURCE_X2("{ name = \"x2\"; quantity = \"displacement\"; node = 1; units = \"mm\"; column = \"x2\"; }"),
                 ":8: source.channels.[1].units:", "unknown setting 'units' (known: name, quantity, ");
    /* the base has no node */
    expect_error("base_node.cfg",
                 STAND "source = {\n  kind = \"replay\";\n  file = \"cap.csv\";\n  channels = (\n"
                       "    { name = \"x1\"; quantity = \"displacement\"; node = 0; column = \"x1\"; },\n"
                       "    { name = \"x2\"; quantity = \"displacement\"; node = 1; column = \"x2\"; },\n"
                       "    { name = \"s\"; quantity = \"base_displacement\"; node = 2; column = \"s\"; }\n  );\n};\n",
                 ":8: source.channels.[2].node:", "a base_displacement belongs to the base, not to a node: omit node");
    /* conversion factors to the stand's SI units: mm (x1), none (x2: the stand's), um (s).
     * Exact binary values of the table's factors (1e-3, 1e-6), compared exactly. */
    const char *ok = STAND SOURCE_X2("{ name = \"x2\"; quantity = \"displacement\"; node = 1; column = \"x2\"; }");
    assert_true(model_scale_of("scale0.cfg", ok, 0) == 1e-3);
    assert_true(model_scale_of("scale1.cfg", ok, 1) == 1.0);
    assert_true(model_scale_of("scale2.cfg", ok, 2) == 1e-6);
    /* a stand in millimetres (length_unit = "mm", masses in t): a channel in m is scaled by
     * 1000, one in mm by 1, one in um by 1e-3 */
    const char *mm_stand =
        "stand = { sample_rate = 2000.0; length_unit = \"mm\";\n"
        "  nodes = ( { name = \"m1\"; mass = 0.01; measure = { displacement = \"x1\"; }; },\n"
        "            { name = \"m2\"; mass = 0.02; measure = { displacement = \"x2\"; }; } );\n"
        "  base = { measure = { displacement = \"s\"; }; };\n"
        "  elements = ( { name = \"c1\"; kind = \"spring\"; between = [\"m1\", \"m2\"]; unknown = true; value = 250.0; },\n"
        "               { name = \"c2\"; kind = \"spring\"; between = [\"m2\", \"base\"]; unknown = true; value = 1500.0; } );\n"
        "};\n";
    char text[4096];
    snprintf(text, sizeof text, "%s%s", mm_stand,
             SOURCE_X2("{ name = \"x2\"; quantity = \"displacement\"; node = 1; unit = \"m\"; column = \"x2\"; }"));
    assert_true(model_scale_of("mm0.cfg", text, 0) == 1.0);
    assert_true(model_scale_of("mm1.cfg", text, 1) == 1000.0);
    assert_true(model_scale_of("mm2.cfg", text, 2) == 1e-6 / 1e-3);
    /* the printed configuration says what is converted, and reads back */
    const char *path = write_cfg("mm_print.cfg", text);
    vd_config cfg;
    vd_config_error err;
    assert_int_equal(vd_config_load(path, &cfg, &err), 0);
    char *p = NULL;
    size_t n = 0;
    FILE *o = open_memstream(&p, &n);
    vd_config_print(&cfg, o);
    fclose(o);
    vd_config_free(&cfg);
    assert_non_null(strstr(p, "m2.displacement <- source channel 'x2' x 1000 (its unit to the stand's mm)"));
    assert_non_null(strstr(p, "{ name = \"s\"; quantity = \"base_displacement\"; unit = \"um\"; column = \"s\"; }"));
    free(p);
    expect_error("bad_length_unit.cfg", "stand = { sample_rate = 1.0; length_unit = \"furlong\"; };\n" SOURCE,
                 ":1: stand.length_unit:", "'furlong' is not a length unit");
}

/* A DBC signal's unit is the channel's unit when the map gives none, and the two must
 * agree when both are given. */
static void test_channel_units_dbc(void **state)
{
    (void)state;
    write_cfg("u.dbc", "VERSION \"\"\n\nBO_ 256 Sample: 8 Node\n"
                       " SG_ X1 : 0|16@1- (0.001,0) [0|0] \"mm\" Node\n"
                       " SG_ X2 : 16|16@1- (0.001,0) [0|0] \"m\" Node\n"
                       " SG_ S : 32|16@1- (0.001,0) [0|0] \"degK\" Node\n"
                       " SG_ Counter : 48|16@1+ (1,0) [0|0] \"\" Node\n");
#define CAN_SOURCE(x1, s)                                                                                              \
    "source = {\n"                                                                                                     \
    "  kind = \"replay\"; file = \"cap.log\"; dbc = \"u.dbc\"; counter = \"Counter\";\n"                               \
    "  channels = (\n"                                                                                                 \
    "    " x1 ",\n"                                                                                                    \
    "    { name = \"x2\"; quantity = \"displacement\"; node = 1; signal = \"X2\"; },\n"                               \
    "    " s "\n"                                                                                                      \
    "  );\n"                                                                                                           \
    "};\n"
    const char *ok = STAND CAN_SOURCE("{ name = \"x1\"; quantity = \"displacement\"; node = 0; signal = \"X1\"; }",
                                      "{ name = \"s\"; quantity = \"base_displacement\"; unit = \"m\"; signal = \"S\"; }");
    /* S's DBC unit degK contradicts the map's m: refused, naming the DBC line */
    expect_error("dbc_contra.cfg", ok, ":7: source.channels.s.unit:", "u.dbc:6) is in 'degK'");
    const char *ok2 = STAND CAN_SOURCE("{ name = \"x1\"; quantity = \"displacement\"; node = 0; signal = \"X1\"; }",
                                       "{ name = \"s\"; quantity = \"base_displacement\"; signal = \"X2\"; message = \"Sample\"; }");
    assert_true(model_scale_of("dbc_mm.cfg", ok2, 0) == 1e-3); /* X1 in mm, from the DBC */
    assert_true(model_scale_of("dbc_m.cfg", ok2, 1) == 1.0);
    /* no unit in the map, a DBC unit that is not a length */
    expect_error("dbc_degk.cfg",
                 STAND CAN_SOURCE("{ name = \"x1\"; quantity = \"displacement\"; node = 0; signal = \"X1\"; }",
                                  "{ name = \"s\"; quantity = \"base_displacement\"; signal = \"S\"; }"),
                 ":7: source.channels.s.unit:", "takes the unit 'degK' of DBC signal 'S'");
    /* the map says m, the DBC mm: one of them is wrong */
    expect_error("dbc_mm_m.cfg",
                 STAND CAN_SOURCE("{ name = \"x1\"; quantity = \"displacement\"; node = 0; unit = \"m\"; signal = \"X1\"; }",
                                  "{ name = \"s\"; quantity = \"base_displacement\"; signal = \"X2\"; }"),
                 ":5: source.channels.x1.unit:", "channel 'x1' says 'm' but DBC signal 'X1'");
#undef CAN_SOURCE
}

static void test_alarm_param(void **state)
{
    (void)state;
    expect_error("alarm.cfg", STAND SOURCE "alarms = {\n parameters = ( { name = \"c3\"; } );\n};\n",
                 ":13: alarms.parameters.[0].name:", "'c3' is not an unknown parameter");
}

/* alarms.test: the change test by default with its defaults (min_relative 0), the threshold
 * rule on request (min_relative 0.02); the other test's settings are errors naming the test. */
static void test_alarm_test(void **state)
{
    (void)state;
    vd_config cfg;
    vd_config_error err;
    assert_int_equal(vd_config_load(write_cfg("at0.cfg", STAND SOURCE "alarms = { };\n"), &cfg, &err), 0);
    assert_int_equal(cfg.alarm_test, VD_ALARM_CUSUM);
    assert_true(cfg.alarm_false_per_year == 1.0 && cfg.alarm_horizon_s == 60.0 &&
                cfg.alarm_detection_probability == 0.9 && cfg.alarm_min_relative == 0.0);
    vd_config_free(&cfg);
    assert_int_equal(vd_config_load(write_cfg("at1.cfg", STAND SOURCE "alarms = { test = \"threshold\"; hold = 1.0; };\n"),
                                    &cfg, &err),
                     0);
    assert_true(cfg.alarm_test == VD_ALARM_THRESHOLD && cfg.alarm_hold_s == 1.0 && cfg.alarm_min_relative == 0.02);
    vd_config_free(&cfg);
    expect_error("at2.cfg", STAND SOURCE "alarms = {\n threshold = 5.0;\n};\n", ":13: alarms.threshold:",
                 "belongs to test = \"threshold\", and this file's test is \"cusum\" (the default)");
    expect_error("at3.cfg", STAND SOURCE "alarms = { test = \"threshold\";\n horizon = 10.0; };\n", ":13: alarms.horizon:",
                 "belongs to test = \"cusum\"");
    expect_error("at4.cfg", STAND SOURCE "alarms = {\n false_alarms_per_year = 0.0; };\n",
                 ":13: alarms.false_alarms_per_year:", "outside");
}

/* Issue 30, item 3: the names vibidd writes into its outputs unescaped are of the safe set
 * (vibid/cfgread.h), and so are the references to the stand's names; each is refused with
 * file:line: field and the character, in one line. (The stand's own names: model.test_stand_file;
 * MQTT's site, stand, client_id, topic_prefix: daemon.unit.mqtt.) */
static void test_hostile_names(void **state)
{
    (void)state;
    expect_error("hn1.cfg",
                 STAND SOURCE_X2("{ name = \"x2\\nvibidd: error: forged\"; quantity = \"displacement\"; node = 1; "
                                 "column = \"x2\"; }"),
                 ":8: source.channels.[1].name:", "contains a line break (character 3)");
    expect_error("hn2.cfg", STAND SOURCE_X2("{ name = \"x,2\"; quantity = \"displacement\"; node = 1; column = \"x2\"; }"),
                 ":8: source.channels.[1].name:", "'x,2' contains ','");
    expect_error("hn3.cfg", STAND SOURCE "outputs = { influx = { path = \"i.lp\"; site = \"%n%s\"; }; };\n",
                 ":12: outputs.influx.site:", "'%n%s' contains '%' (character 1)");
    expect_error("hn4.cfg", STAND SOURCE "outputs = { influx = { path = \"i.lp\"; stand = \"rig 7\"; }; };\n",
                 ":12: outputs.influx.stand:", "contains a space");
    expect_error("hn5.cfg", STAND SOURCE "outputs = { influx = { path = \"i.lp\"; measurement = \"v,x=1\"; }; };\n",
                 ":12: outputs.influx.measurement:", "contains ','");
    expect_error("hn6.cfg", STAND SOURCE "alarms = {\n parameters = ( { name = \"c1\\n\"; } );\n};\n",
                 ":13: alarms.parameters.[0].name:", "'c1\\x0a' contains a line break");
    expect_error("hn7.cfg",
                 STAND SOURCE "estimator = { method = \"rls\";\n start_values = ( { name = \"c1,d\"; value = 1.0; } ); };\n",
                 ":13: estimator.start_values.[0].name:", "contains ','");
}

static void test_modbus_url(void **state)
{
    (void)state;
    expect_error("url.cfg",
                 STAND "source = {\n kind = \"modbus\";\n url = \"tcp://127.0.0.1:99999\";\n"
                       " registers = ( { name = \"x1\"; address = 0; type = \"FLOAT32\"; } );\n"
                       " channels = ( { name = \"x1\"; quantity = \"displacement\"; node = 0; register = \"x1\"; },\n"
                       "   { name = \"x2\"; quantity = \"displacement\"; node = 1; register = \"x2\"; },\n"
                       "   { name = \"s\"; quantity = \"base_displacement\"; node = 0; register = \"s\"; } );\n};\n",
                 ":4: source.url:", "port '99999' outside 1..65535");
}

static void test_defaults_and_roundtrip(void **state)
{
    (void)state;
    const char *path = write_cfg("ok.cfg", STAND SOURCE);
    vd_config cfg;
    vd_config_error err;
    assert_int_equal(vd_config_load(path, &cfg, &err), 0);
    assert_int_equal(cfg.source_kind, VD_SRC_REPLAY);
    assert_int_equal(cfg.method, VIBID_ESTIMATOR_AUTO); /* the automatic estimator by default (issue 11) */
    assert_true(cfg.prefilter_hz < 0.0 && cfg.iv_lag == 0 && cfg.difference_order == 0); /* chosen by the library */
    assert_int_equal(cfg.decimation, 200); /* f_a / 10 at 2 kHz */
    assert_int_equal(cfg.ring_size, 65536);
    assert_true(cfg.forgetting == 1.0);
    assert_int_equal(cfg.n_params, 3);
    assert_int_equal(cfg.n_modes, 2);
    assert_false(cfg.alarms_enabled); /* no alarms group */
    char expect_file[600];
    snprintf(expect_file, sizeof expect_file, "%s/cap.csv", dir);
    assert_string_equal(cfg.replay_file, expect_file);
    /* the printout is a configuration that loads to the same printout */
    char *p1 = NULL, *p2 = NULL;
    size_t n1 = 0, n2 = 0;
    FILE *o = open_memstream(&p1, &n1);
    vd_config_print(&cfg, o);
    fclose(o);
    vd_config_free(&cfg);
    const char *path2 = write_cfg("printed.cfg", p1);
    assert_int_equal(vd_config_load(path2, &cfg, &err), 0);
    o = open_memstream(&p2, &n2);
    vd_config_print(&cfg, o);
    fclose(o);
    vd_config_free(&cfg);
    /* identical apart from the first comment line, which names the file */
    assert_string_equal(strchr(p1, '\n'), strchr(p2, '\n'));
    free(p1);
    free(p2);
}

/* estimator.start_values: listed parameters take the given value, the others the stand's
 * nominal one; the --check printout lists them and reads back to the same printout;
 * errors name the element and field. */
static void test_start_values(void **state)
{
    (void)state;
    const char *path = write_cfg("start.cfg", STAND SOURCE
                                 "estimator = { method = \"rls\"; start_values = ( { name = \"c1\"; value = 2.0e5; },\n"
                                 "  { name = \"c2\"; value = 1.2e6; } ); };\n");
    vd_config cfg;
    vd_config_error err;
    if (vd_config_load(path, &cfg, &err) != 0)
        fail_msg("%s", err.text);
    assert_true(cfg.has_start);
    double nominal[3];
    assert_int_equal(vibid_model_nominal(vibid_stand_model(cfg.stand), nominal), VIBID_OK);
    assert_true(cfg.start_theta[0] == 2.0e5);      /* c1 */
    assert_true(cfg.start_theta[1] == nominal[1]); /* d: not listed */
    assert_true(cfg.start_theta[2] == 1.2e6);      /* c2 */
    char *p1 = NULL;
    size_t n1 = 0;
    FILE *o = open_memstream(&p1, &n1);
    vd_config_print(&cfg, o);
    fclose(o);
    vd_config_free(&cfg);
    assert_non_null(strstr(p1, "{ name = \"c2\"; value = 1200000.0; }"));
    const char *path2 = write_cfg("start_printed.cfg", p1);
    if (vd_config_load(path2, &cfg, &err) != 0)
        fail_msg("%s", err.text);
    assert_true(cfg.has_start && cfg.start_theta[0] == 2.0e5 && cfg.start_theta[1] == nominal[1]);
    vd_config_free(&cfg);
    free(p1);
    expect_error("start_ls.cfg", STAND SOURCE "estimator = { method = \"ls\"; start_values = ( ); };\n",
                 ":12: estimator.start_values:", "only the rls, ekf and kf_rls methods");
    expect_error("start_name.cfg", STAND SOURCE "estimator = { method = \"rls\"; start_values = ( { name = \"k9\"; value = 1.0; } ); };\n",
                 ":12: estimator.start_values.[0].name:", "'k9' is not an unknown parameter");
    expect_error("start_value.cfg", STAND SOURCE "estimator = { method = \"rls\"; start_values = ( { name = \"d\"; } ); };\n",
                 ":12: estimator.start_values.[0].value:", "missing");
}

int main(void)
{
    snprintf(dir, sizeof dir, "/tmp/vd_test_config_%d", (int)getpid());
    char cmd[300];
    snprintf(cmd, sizeof cmd, "mkdir -p %s", dir);
    if (system(cmd) != 0)
        return 1;
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_syntax_error),      cmocka_unit_test(test_range_error), cmocka_unit_test(test_refine),
        cmocka_unit_test(test_type_error),        cmocka_unit_test(test_unknown_directive),
        cmocka_unit_test(test_ring_power_of_two), cmocka_unit_test(test_missing_parts),
        cmocka_unit_test(test_stand_errors),      cmocka_unit_test(test_channel_missing),
        cmocka_unit_test(test_alarm_param), cmocka_unit_test(test_alarm_test), cmocka_unit_test(test_hostile_names),       cmocka_unit_test(test_modbus_url),
        cmocka_unit_test(test_defaults_and_roundtrip),
        cmocka_unit_test(test_start_values),      cmocka_unit_test(test_prometheus),
        cmocka_unit_test(test_channel_units),     cmocka_unit_test(test_channel_units_dbc),
        cmocka_unit_test(test_covariates),
    };
    int rc = cmocka_run_group_tests(tests, NULL, NULL);
    snprintf(cmd, sizeof cmd, "rm -rf %s", dir);
    if (system(cmd) != 0)
        return 1;
    return rc;
}
