/* libFuzzer target: vibidd's configuration reader (daemon/src/config.c) over arbitrary
 * text, linked with the stand loader, the drivers' map readers and libvibid (all built
 * with clang for this binary) and daemon/src/log.c, the only other daemon file config.c
 * needs (vd_log_level_name).
 *
 * vd_config_load reads a path and resolves the files it names relative to it. At start-up
 * the harness makes a directory of its own ($TMPDIR or /tmp, vibid_fuzz_config.XXXXXX)
 * holding valid files a configuration can name, so that the fuzzer reaches the deep
 * checks (channels against the stand, units, register map, DBC):
 *   stand.cfg          the stand of paper example 1 (channels x1, x2, s)
 *   chan_column.cfg    its channels as CSV columns (time column t)
 *   chan_signal.cfg    ... as DBC signals of example1.dbc (counter "Counter")
 *   chan_register.cfg  ... as registers of registers.cfg
 *   registers.cfg      a Modbus register map
 *   example1.dbc       the DBC of tests/daemon/data
 * Each input is written to fuzz.cfg in that directory (one file, rewritten each time,
 * closed before loading) and loaded; a loaded configuration is printed to /dev/null (one
 * stream opened once), its paths checked and freed. The directory is removed at exit.
 *
 * Inputs are cut at their first NUL (a text file). Refused before loading, because the
 * file system around the configuration is not the reader's to fuzz: `@include` (it opens
 * any path), and a stand, dbc, channel_map or register_map naming something that exists
 * but is no regular file or directory (/dev/zero, a FIFO: they block or never end).
 *
 * Invariants: a refused configuration says why (error text); a loaded one has its stand
 * and a channel of the map for every channel of the stand. */
#include <errno.h>
#include <fcntl.h>
#include <libconfig.h>
#include <limits.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <unistd.h>

#include "config.h"

#define CHECK(c) \
    do { \
        if (!(c)) \
            abort(); \
    } while (0)

static const char k_stand[] =
    "# paper example 1 (examples/stands/paper_example1.cfg)\n"
    "stand = {\n"
    "  name = \"paper_example1\";\n"
    "  sample_rate = 2000.0;\n"
    "  discretization = \"central_difference\";\n"
    "  nodes = (\n"
    "    { name = \"m1\"; mass = 10.0; measure = { displacement = \"x1\"; }; },\n"
    "    { name = \"m2\"; mass = 20.0; measure = { displacement = \"x2\"; }; }\n"
    "  );\n"
    "  base = { measure = { displacement = \"s\"; }; };\n"
    "  elements = (\n"
    "    { name = \"c1\"; kind = \"spring\"; between = [\"m1\", \"m2\"];   unknown = true; true_value = 2.5e5; },\n"
    "    { name = \"d\";  kind = \"damper\"; between = [\"m1\", \"m2\"];   unknown = true; true_value = 300.0; },\n"
    "    { name = \"c2\"; kind = \"spring\"; between = [\"m2\", \"base\"]; unknown = true; true_value = 1.5e6; }\n"
    "  );\n"
    "};\n";

static const char k_chan_column[] =
    "channels = (\n"
    "  { name = \"x1\"; quantity = \"displacement\";      node = 0; unit = \"m\"; column = \"x1\"; },\n"
    "  { name = \"x2\"; quantity = \"displacement\";      node = 1; unit = \"m\"; column = \"x2\"; },\n"
    "  { name = \"s\";  quantity = \"base_displacement\"; node = 0; unit = \"m\"; column = \"s\";  }\n"
    ");\n"
    "time_column = \"t\";\n";

static const char k_chan_signal[] =
    "channels = (\n"
    "  { name = \"x1\"; quantity = \"displacement\";      node = 0; unit = \"m\"; signal = \"X1\"; message = \"Sample_A\"; },\n"
    "  { name = \"x2\"; quantity = \"displacement\";      node = 1; unit = \"m\"; signal = \"X2\"; message = \"Sample_B\"; },\n"
    "  { name = \"s\";  quantity = \"base_displacement\"; node = 0; unit = \"m\"; signal = \"S\";  message = \"Sample_C\"; }\n"
    ");\n"
    "counter = \"Counter\";\n";

static const char k_chan_register[] =
    "channels = (\n"
    "  { name = \"x1\"; quantity = \"displacement\";      node = 0; unit = \"m\"; register = \"x1\"; },\n"
    "  { name = \"x2\"; quantity = \"displacement\";      node = 1; unit = \"m\"; register = \"x2\"; },\n"
    "  { name = \"s\";  quantity = \"base_displacement\"; node = 0; unit = \"m\"; register = \"s\";  }\n"
    ");\n";

static const char k_registers[] =
    "registers = (\n"
    "  { name = \"x1\"; address = 0; register = \"holding\"; type = \"FLOAT32\"; byte_order = \"ABCD\"; },\n"
    "  { name = \"x2\"; address = 2; register = \"holding\"; type = \"FLOAT32\"; byte_order = \"ABCD\"; },\n"
    "  { name = \"s\";  address = 4; register = \"input\";   type = \"INT32\";   byte_order = \"CDAB\"; scale = 1e-6; }\n"
    ");\n";

static const char k_dbc[] =
    "VERSION \"\"\n\nNS_ :\n\nBS_:\n\nBU_: SHAKER VIBIDD\n\n"
    "BO_ 256 Sample_A: 8 SHAKER\n"
    " SG_ Counter : 0|16@1+ (1,0) [0|65535] \"\" VIBIDD\n"
    " SG_ X1 : 16|32@1- (1,0) [0|0] \"m\" VIBIDD\n\n"
    "BO_ 257 Sample_B: 8 SHAKER\n"
    " SG_ Counter : 0|16@1+ (1,0) [0|65535] \"\" VIBIDD\n"
    " SG_ X2 : 16|32@1- (1,0) [0|0] \"m\" VIBIDD\n\n"
    "BO_ 258 Sample_C: 8 SHAKER\n"
    " SG_ Counter : 0|16@1+ (1,0) [0|65535] \"\" VIBIDD\n"
    " SG_ S : 16|32@1- (1,0) [0|0] \"m\" VIBIDD\n\n"
    "SIG_VALTYPE_ 256 X1 : 1;\nSIG_VALTYPE_ 257 X2 : 1;\nSIG_VALTYPE_ 258 S : 1;\n";

static const struct {
    const char *name, *text;
} k_files[] = {
    {"stand.cfg", k_stand},         {"chan_column.cfg", k_chan_column}, {"chan_signal.cfg", k_chan_signal},
    {"chan_register.cfg", k_chan_register}, {"registers.cfg", k_registers}, {"example1.dbc", k_dbc},
};
#define N_FILES (sizeof k_files / sizeof k_files[0])

static int g_trace; /* VIBID_FUZZ_TRACE=1 in the environment: print each result */
static char g_dir[PATH_MAX];
static char g_cfg_path[PATH_MAX + 16];
static FILE *g_null;

static void write_file(const char *path, const char *text, size_t len)
{
    int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    CHECK(fd >= 0);
    while (len > 0) {
        ssize_t w = write(fd, text, len);
        if (w < 0 && errno == EINTR)
            continue;
        CHECK(w > 0);
        text += w;
        len -= (size_t)w;
    }
    CHECK(close(fd) == 0);
}

static void cleanup(void)
{
    char p[PATH_MAX + 64];
    for (size_t i = 0; i < N_FILES; i++) {
        snprintf(p, sizeof p, "%s/%s", g_dir, k_files[i].name);
        unlink(p);
    }
    unlink(g_cfg_path);
    rmdir(g_dir);
    if (g_null && g_null != stderr)
        fclose(g_null);
}

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    (void)argc, (void)argv;
    const char *tmp = getenv("TMPDIR");
    snprintf(g_dir, sizeof g_dir, "%s/vibid_fuzz_config.XXXXXX", tmp && *tmp ? tmp : "/tmp");
    CHECK(mkdtemp(g_dir) != NULL);
    atexit(cleanup);
    char p[PATH_MAX + 64];
    for (size_t i = 0; i < N_FILES; i++) {
        snprintf(p, sizeof p, "%s/%s", g_dir, k_files[i].name);
        write_file(p, k_files[i].text, strlen(k_files[i].text));
    }
    snprintf(g_cfg_path, sizeof g_cfg_path, "%s/fuzz.cfg", g_dir);
    g_null = fopen("/dev/null", "w");
    CHECK(g_null != NULL);
    const char *e = getenv("VIBID_FUZZ_TRACE");
    g_trace = e && *e && *e != '0';
    if (g_trace) { /* the effective configuration instead of /dev/null */
        fclose(g_null);
        g_null = stderr;
    }
    return 0;
}

/* A file the configuration names that exists but is neither a regular file nor a
 * directory (resolved as config.c does: relative to the configuration's directory). */
static int special_file(const config_setting_t *s)
{
    if (!s || config_setting_type(s) != CONFIG_TYPE_STRING)
        return 0;
    const char *v = config_setting_get_string(s);
    char p[2 * PATH_MAX];
    if (v[0] == '/')
        snprintf(p, sizeof p, "%s", v);
    else
        snprintf(p, sizeof p, "%s/%s", g_dir, v);
    struct stat st;
    return stat(p, &st) == 0 && !S_ISREG(st.st_mode) && !S_ISDIR(st.st_mode);
}

static int refused(const char *text)
{
    if (strcasestr(text, "@include"))
        return 1;
    config_t cf;
    config_init(&cf);
    int bad = 0;
    if (config_read_string(&cf, text)) {
        const config_setting_t *src = config_lookup(&cf, "source");
        bad = special_file(config_lookup(&cf, "stand"));
        if (src && config_setting_is_group(src))
            bad |= special_file(config_setting_get_member(src, "dbc")) |
                   special_file(config_setting_get_member(src, "channel_map")) |
                   special_file(config_setting_get_member(src, "register_map"));
    }
    config_destroy(&cf);
    return bad;
}

/* libconfig 1.5 (Debian bookworm) leaks in its scanner when a syntax error interrupts a
 * string or token (allocated in strbuf_append or libconfig_yylex; reproduced with
 * config_read_string + config_destroy alone): not this project's leaks. Leaks of
 * settings (a missing config_destroy) are still reported. */
const char *__lsan_default_suppressions(void);
const char *__lsan_default_suppressions(void) { return "leak:strbuf_append\nleak:libconfig_yylex\n"; }

static vd_config g_cfg;

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char *text = malloc(size + 1);
    CHECK(text);
    memcpy(text, data, size);
    text[size] = '\0';
    size_t len = strlen(text);
    if (refused(text)) {
        free(text);
        return 0;
    }
    write_file(g_cfg_path, text, len);
    free(text);

    vd_config_error err;
    int rc = vd_config_load(g_cfg_path, &g_cfg, &err);
    if (g_trace)
        fprintf(stderr, "%s\n", rc ? err.text : "loaded");
    if (rc != 0) {
        CHECK(err.text[0] != '\0'); /* a refusal says why */
        return 0;
    }
    CHECK(g_cfg.stand != NULL);
    for (size_t i = 0; i < g_cfg.n_channels; i++)
        CHECK(g_cfg.model_to_chan[i] < g_cfg.chanmap.n);
    vd_config_print(&g_cfg, g_null);
    char msg[1024];
    vd_config_check_paths(&g_cfg, NULL, msg, sizeof msg);
    vd_config_free(&g_cfg);
    return 0;
}
