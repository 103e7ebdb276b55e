/* libFuzzer target: the stand-file loader (lib/loader/src/stand_file.c) over arbitrary
 * libconfig text, through libvibid's model API (built with clang for this binary).
 *
 * Input -> NUL-terminated copy -> config_read_string -> the group `stand` (or, if there is
 * none, the root group, so that a bare stand body is loaded too) -> vibid_stand_from_setting.
 * A loaded stand has its accessors checked against what stand_file.h promises, then is
 * destroyed. A refused one must say why (the error text is never empty). */
#include <libconfig.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <vibid/model.h>
#include <vibid/stand_file.h>

#define CHECK(c) \
    do { \
        if (!(c)) \
            abort(); \
    } while (0)

static void exercise(const vibid_stand *st)
{
    const vibid_model *m = vibid_stand_model(st);
    CHECK(m != NULL);
    CHECK(vibid_stand_name(st) != NULL);
    CHECK(vibid_stand_sample_rate(st) > 0); /* "Sample rate f_a in Hz, > 0" */
    vibid_model_dims d;
    CHECK(vibid_model_get_dims(m, &d) == VIBID_OK);

    /* Every model channel has an acquisition name, which finds a channel of that name. */
    for (size_t i = 0; i < d.n_channels; i++) {
        const char *name = vibid_stand_channel_name(st, i);
        CHECK(name != NULL);
        size_t k = vibid_stand_find_channel(st, name);
        CHECK(k <= i && strcmp(vibid_stand_channel_name(st, k), name) == 0);
        vibid_channel_info ci;
        CHECK(vibid_model_channel_info(m, i, &ci) == VIBID_OK && ci.name != NULL);
    }
    CHECK(vibid_stand_channel_name(st, d.n_channels) == NULL); /* out of range */
    CHECK(vibid_stand_find_channel(st, NULL) == (size_t)-1);

    /* True values of the p unknowns (read all: ASan checks the length). */
    const double *tv = vibid_stand_true_values(st);
    CHECK(tv != NULL);
    volatile double sum = 0;
    for (size_t k = 0; k < d.n_params; k++) {
        sum += tv[k];
        int given = vibid_stand_true_value_given(st, k);
        CHECK(given == 0 || given == 1);
        vibid_param_info pi;
        CHECK(vibid_model_param_info(m, k, &pi) == VIBID_OK && pi.name != NULL);
    }
    CHECK(vibid_stand_true_value_given(st, d.n_params) == 0);

    /* Disturbances: never NULL for a loaded stand; std and true_std are >= 0. */
    const double *ts = vibid_stand_disturbance_true_std(st);
    CHECK(ts != NULL);
    for (size_t k = 0; k < d.n_disturbances; k++) {
        CHECK(!(ts[k] < 0));
        vibid_disturbance_info di;
        CHECK(vibid_model_disturbance_info(m, k, &di) == VIBID_OK);
    }

    /* Nominal values and the assembled matrices at them. */
    size_t n = d.n_dof, r = d.n_inputs;
    double *theta = calloc(d.n_params ? d.n_params : 1, sizeof *theta);
    double *mats = calloc(3 * n * n + n * (r ? r : 1) + 2 * n + 1, sizeof *mats);
    CHECK(theta && mats);
    CHECK(vibid_model_nominal(m, theta) == VIBID_OK);
    vibid_model_assemble(m, theta, mats, mats + n * n, mats + 2 * n * n, mats + 3 * n * n,
                         mats + 3 * n * n + n * (r ? r : 1), mats + 3 * n * n + n * (r ? r : 1) + n);
    free(theta);
    free(mats);
    (void)sum;
}

/* libconfig 1.5 (Debian bookworm) leaks in its scanner when a syntax error interrupts a
 * string or token (allocated in strbuf_append or libconfig_yylex; reproduced with
 * config_read_string + config_destroy alone): not this project's leaks. Leaks of
 * settings (a missing config_destroy) are still reported. */
const char *__lsan_default_suppressions(void);
const char *__lsan_default_suppressions(void) { return "leak:strbuf_append\nleak:libconfig_yylex\n"; }

/* VIBID_FUZZ_TRACE=1 in the environment: print each result. */
static int trace(void)
{
    static int t = -1;
    if (t < 0) {
        const char *e = getenv("VIBID_FUZZ_TRACE");
        t = e && *e && *e != '0';
    }
    return t;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char *text = malloc(size + 1);
    if (!text)
        return 0;
    memcpy(text, data, size);
    text[size] = '\0';
    /* @include would make libconfig open files named by the input (relative to the
     * working directory): not the loader's business, and /dev/stdin would block. */
    if (strcasestr(text, "@include")) {
        free(text);
        return 0;
    }
    config_t cfg;
    config_init(&cfg);
    if (config_read_string(&cfg, text)) {
        const config_setting_t *g = config_lookup(&cfg, "stand");
        if (!g)
            g = config_root_setting(&cfg);
        vibid_stand_error err;
        vibid_stand *st = vibid_stand_from_setting(g, "fuzz.cfg", &err);
        if (trace())
            fprintf(stderr, "%s\n", st ? "loaded" : err.text);
        if (st) {
            exercise(st);
            vibid_stand_destroy(st);
        } else {
            CHECK(err.text[0] != '\0' && err.message[0] != '\0'); /* a refusal says why */
        }
    }
    config_destroy(&cfg);
    free(text);
    return 0;
}
