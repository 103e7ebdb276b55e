/* stand_file.c: libconfig stand files -> vibid_model (public C API only) plus what the
 * programs need beside the model. Format: docs/stand-file.md. */
#include <vibid/stand_file.h>
#include <vibid/units.h>

#include <libconfig.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct vibid_stand {
    vibid_model *model;
    char *name;
    double sample_rate;
    size_t n_channels;
    char **channel_names; /* per model channel */
    double *true_values;  /* per unknown */
    unsigned char *true_given; /* per unknown: 1 if the file gives its true_value */
    size_t n_unknowns;         /* length of true_values and true_given */
    double *true_std;     /* per disturbance, N (vibid_stand_disturbance_true_std) */
    char length_unit[8];  /* `length_unit`, "m" unless given */
    double length_si;     /* metres per length unit */
    long *input_nodes;    /* per input: node index, -1 for a full-matrix stand */
    size_t n_inputs;
};

/* A number that must be there ("missing (a number is required)" otherwise). */
static int require_number(const vibid_cfg_reader *c, const config_setting_t *g, const char *path,
                          const char *name, double *out) {
    return vibid_cfg_require(c, g, path, name, "a number is required") ||
                   vibid_cfg_number(c, g, path, name, -HUGE_VAL, HUGE_VAL, out) < 0
               ? -1
               : 0;
}

/* A name that must be there (the safe set of vibid/cfgread.h: names reach every output). */
static int require_name(const vibid_cfg_reader *c, const config_setting_t *g, const char *path,
                        const char *name, const char **out) {
    return vibid_cfg_require(c, g, path, name, "a name is required") ||
                   vibid_cfg_name(c, g, path, name, out) < 0
               ? -1
               : 0;
}

/* An optional finite number of any size: 1 given, 0 absent, -1 error. */
static int get_number(const vibid_cfg_reader *c, const config_setting_t *g, const char *path,
                      const char *name, double *out) {
    return vibid_cfg_number(c, g, path, name, -HUGE_VAL, HUGE_VAL, out);
}

/* Reports a library failure against the setting that caused it. */
static int lib_fail(const vibid_cfg_reader *c, const config_setting_t *s, const char *field,
                    vibid_status st) {
    return vibid_cfg_fail(c, s, field, "%s (%s)", vibid_last_error(), vibid_strerror(st));
}

/* Index 0..2 of a measured quantity's name (bit 1 << index is its VIBID_MEASURE_*), -1 if
 * name is none of them. */
static int quantity_index(const char *name) {
    static const char *const q[3] = {"displacement", "velocity", "acceleration"};
    for (int j = 0; j < 3; ++j)
        if (name && !strcmp(name, q[j])) return j;
    return -1;
}

/* Group `name` of g keyed by measured quantity (`measure`, `noise`): NULL when absent or
 * after an error (then *bad = -1). gpath receives its field path. */
static const config_setting_t *quantity_group(const vibid_cfg_reader *c, const config_setting_t *g,
                                              const char *path, const char *name, const char *shape,
                                              char gpath[160], int *bad) {
    const config_setting_t *q = config_setting_get_member(g, name);
    *bad = 0;
    vibid_cfg_field(gpath, 160, path, name);
    if (q && !config_setting_is_group(q)) {
        *bad = vibid_cfg_fail(c, q, gpath, "must be a group %s", shape);
        return NULL;
    }
    return q;
}

/* Member i of a quantity group: its setting *e, field path f and quantity index 0..2, or
 * -1 after an error (a key that is no quantity). */
static int quantity_member(const vibid_cfg_reader *c, const config_setting_t *q, const char *gpath, int i,
                           const config_setting_t **e, char f[200]) {
    *e = config_setting_get_elem(q, (unsigned)i);
    const char *nm = config_setting_name(*e);
    snprintf(f, 200, "%s.%s", gpath, nm ? nm : "?");
    int k = quantity_index(nm);
    return k >= 0 ? k : vibid_cfg_fail(c, *e, f, "unknown quantity (displacement, velocity, acceleration)");
}

/* Per node or base: `measure = { displacement = "x1"; velocity = "v1"; acceleration = "a1"; }`.
 * Fills mask and the channel names in quantity order. */
static int read_measure(const vibid_cfg_reader *c, const config_setting_t *g, const char *path,
                        unsigned *mask, const char *names[3]) {
    *mask = 0;
    names[0] = names[1] = names[2] = NULL;
    char mp[160], f[200];
    int bad;
    const config_setting_t *m = quantity_group(c, g, path, "measure", "{ displacement = \"channel\"; ... }", mp, &bad);
    for (int i = 0; m && i < config_setting_length(m); ++i) {
        const config_setting_t *e;
        int k = quantity_member(c, m, mp, i, &e, f);
        if (k < 0) return -1;
        if (config_setting_type(e) != CONFIG_TYPE_STRING || !config_setting_get_string(e)[0])
            return vibid_cfg_fail(c, e, f,
                                  "channel name missing: a measured quantity needs the name of its channel");
        if (vibid_cfg_check_name(c, e, f, config_setting_get_string(e))) return -1;
        *mask |= 1u << k;
        names[k] = config_setting_get_string(e);
    }
    return bad;
}

/* Optional `noise = { displacement = 1e-6; acceleration = 0.02; }` of a node or the base:
 * the declared white measurement-noise std of measured quantities (channel units, >= 0;
 * vibid_model_set_noise). Only quantities that `measure` names (mask) may have one: noise
 * of an unmeasured quantity is a mistake, not something to ignore. 0, or -1 after an error. */
static int read_noise(const vibid_cfg_reader *c, vibid_model *m, const config_setting_t *g, const char *path,
                      size_t node, unsigned mask) {
    static const unsigned bits[3] = {VIBID_MEASURE_DISPLACEMENT, VIBID_MEASURE_VELOCITY, VIBID_MEASURE_ACCELERATION};
    char np[160], f[200];
    int bad;
    const config_setting_t *ng =
        quantity_group(c, g, path, "noise", "{ displacement = std; ... } (std in channel units)", np, &bad);
    for (int i = 0; ng && i < config_setting_length(ng); ++i) {
        const config_setting_t *e;
        int k = quantity_member(c, ng, np, i, &e, f);
        if (k < 0) return -1;
        const char *nm = config_setting_name(e);
        double v;
        if (get_number(c, ng, np, nm, &v) < 0) return -1;
        if (v < 0) return vibid_cfg_fail(c, e, f, "%g must be >= 0 (standard deviation in channel units)", v);
        if (!(mask & bits[k]))
            return vibid_cfg_fail(
                c, e, f, "the %s is not measured (no measure.%s): noise applies to a measured quantity", nm,
                nm);
        vibid_status st = vibid_model_set_noise(m, node, bits[k], v);
        if (st != VIBID_OK) return lib_fail(c, e, f, st);
    }
    return bad;
}

/* Optional `hold = "zoh" | "smooth"` of an input or the base (vibid_hold: how the signal
 * behaves between samples; the simulator produces it, the identification accounts for
 * it). Sets it on the model; absent = the model's default (smooth). 0, or -1 after an
 * error. */
static int read_hold(const vibid_cfg_reader *c, vibid_model *m, const config_setting_t *g, const char *path,
                     size_t input) {
    static const char *const holds[] = {"zoh", "smooth", NULL};
    int h;
    int r = vibid_cfg_enum(c, g, path, "hold", holds, false, &h);
    if (r <= 0) return r;
    char f[160];
    vibid_cfg_field(f, sizeof f, path, "hold");
    const config_setting_t *s = config_setting_get_member(g, "hold");
    vibid_hold hold = h == 0 ? VIBID_HOLD_ZOH : VIBID_HOLD_SMOOTH;
    vibid_status st = vibid_model_set_hold(m, input, hold);
    return st == VIBID_OK ? 0 : lib_fail(c, s, f, st);
}

static char *dup_string(const char *s) {
    size_t n = strlen(s) + 1;
    char *d = malloc(n);
    if (d) memcpy(d, s, n);
    return d;
}

void vibid_stand_destroy(vibid_stand *stand) {
    if (!stand) return;
    vibid_model_destroy(stand->model);
    free(stand->name);
    if (stand->channel_names)
        for (size_t i = 0; i < stand->n_channels; ++i) free(stand->channel_names[i]);
    free(stand->channel_names);
    free(stand->true_values);
    free(stand->true_given);
    free(stand->true_std);
    free(stand->input_nodes);
    free(stand);
}

/* Resolves an end name: a node, "ground" or "base". */
static int resolve_end(const vibid_cfg_reader *c, const vibid_model *m, const config_setting_t *s,
                       const char *f, const char *name, size_t *out) {
    if (vibid_cfg_check_name(c, s, f, name)) return -1; /* a clean message for any reference */
    if (!strcmp(name, "ground")) {
        *out = VIBID_GROUND;
        return 0;
    }
    if (!strcmp(name, "base")) {
        *out = VIBID_BASE;
        return 0;
    }
    if (vibid_model_find_node(m, name, out) != VIBID_OK)
        return vibid_cfg_fail(c, s, f, "'%s' is not a declared node (nor ground or base)", name);
    return 0;
}

/* Channel names and true values collected while reading, in declaration order. */
typedef struct pending {
    const char *node_names[4096][3];
    size_t n_nodes;
    const char *base_names[3];
    const char *input_names[256];
    long input_nodes[256];
    size_t n_inputs;
    double true_values[8192];
    int has_true[8192];
    size_t n_unknown;
} pending;

/* For an unknown parameter: its optional true_value (else the nominal value) appended to
 * pd's list. 0, or -1 after an error. */
static int note_true_value(const vibid_cfg_reader *c, const config_setting_t *e, const char *path,
                           double nominal, pending *pd) {
    double tv;
    int r = get_number(c, e, path, "true_value", &tv);
    if (r < 0) return -1;
    if (pd->n_unknown >= sizeof pd->true_values / sizeof pd->true_values[0])
        return vibid_cfg_fail(c, e, path, "more than %zu unknowns",
                              sizeof pd->true_values / sizeof pd->true_values[0]);
    pd->has_true[pd->n_unknown] = r;
    pd->true_values[pd->n_unknown++] = r ? tv : nominal;
    return 0;
}

/* `disturbances = ( { name = "w1"; node = "m1"; std = 2.0; true_std = 2.0; }, ... )`:
 * unmeasured random forces (vibid_model_add_disturbance). std (N, >= 0): omitted or 0 =
 * unknown, estimated. true_std (N): what vibid-sim simulates, default std; when std is
 * unknown only vibid-sim needs it, so it is optional here (stored as 0: the simulator
 * names the field if it lacks it); if given, > 0 then (0 would read as "missing"), else
 * >= 0 (0: the stand has no such force, the estimator's model does). Fills st->true_std. */
static int read_disturbances(const vibid_cfg_reader *c, vibid_model *m, const config_setting_t *list,
                             vibid_stand *st) {
    static const char *const known[] = {"name", "node", "std", "true_std", NULL};
    const char *path = "stand.disturbances";
    if (!config_setting_is_list(list))
        return vibid_cfg_fail(c, list, path,
                              "must be a list ( { name = ...; node = ...; std = ...; }, ... )");
    int n = config_setting_length(list);
    free(st->true_std);
    if (!(st->true_std = calloc(n ? (size_t)n : 1, sizeof(double))))
        return vibid_cfg_fail(c, list, path, "out of memory");
    for (int i = 0; i < n; ++i) {
        const config_setting_t *e = config_setting_get_elem(list, (unsigned)i);
        char p[64], f[160];
        snprintf(p, sizeof p, "%s.[%d]", path, i);
        if (!config_setting_is_group(e))
            return vibid_cfg_fail(c, e, p, "must be a group { name = \"w1\"; node = \"m1\"; std = 1.0; }");
        if (vibid_cfg_check_keys(c, e, p, known)) return -1;
        const char *nm, *node;
        double sd = 0.0, tsd = 0.0;
        int has_true;
        if (require_name(c, e, p, "name", &nm) || require_name(c, e, p, "node", &node)) return -1;
        if (get_number(c, e, p, "std", &sd) < 0 || (has_true = get_number(c, e, p, "true_std", &tsd)) < 0) return -1;
        size_t idx;
        if (vibid_model_find_node(m, node, &idx) != VIBID_OK) {
            vibid_cfg_field(f, sizeof f, p, "node");
            return vibid_cfg_fail(c, config_setting_get_member(e, "node"), f, "unknown node '%s'", node);
        }
        if (sd < 0) {
            vibid_cfg_field(f, sizeof f, p, "std");
            return vibid_cfg_fail(c, config_setting_get_member(e, "std"), f,
                                  "%g must be >= 0 N (omitted or 0: unknown, estimated)", sd);
        }
        if (has_true && (tsd < 0 || (tsd == 0 && sd == 0))) {
            vibid_cfg_field(f, sizeof f, p, "true_std");
            return vibid_cfg_fail(c, config_setting_get_member(e, "true_std"), f,
                                  "%g must be %s (N, the standard deviation vibid-sim simulates)", tsd,
                                  sd == 0 ? "> 0 when std is unknown" : ">= 0");
        }
        vibid_status s = vibid_model_add_disturbance(m, nm, idx, sd, NULL);
        if (s != VIBID_OK) {
            vibid_cfg_field(f, sizeof f, p, "name");
            return lib_fail(c, e, strstr(vibid_last_error(), "name") ? f : p, s);
        }
        st->true_std[i] = has_true ? tsd : sd;
    }
    return 0;
}

static int read_matrices(const vibid_cfg_reader *c, vibid_model *m, const config_setting_t *g,
                         const char *path, pending *pd) {
    double nd = 0, nr = 0;
    static const char *const known[] = {"n_dof", "n_inputs", "M", "D", "C", "B", "unknown", "channels", NULL};
    if (vibid_cfg_check_keys(c, g, path, known)) return -1;
    if (require_number(c, g, path, "n_dof", &nd) || (get_number(c, g, path, "n_inputs", &nr) < 0)) return -1;
    char f[160];
    vibid_cfg_field(f, sizeof f, path, "n_dof");
    if (nd < 1 || nd > 256 || nd != floor(nd)) return vibid_cfg_fail(c, g, f, "must be an integer in 1..256");
    if (nr < 0 || nr > 256 || nr != floor(nr)) {
        vibid_cfg_field(f, sizeof f, path, "n_inputs");
        return vibid_cfg_fail(c, g, f, "must be an integer in 0..256");
    }
    /* cast only after the range checks: (size_t)-1.0 is undefined (found by fuzz_stand) */
    size_t n = (size_t)nd, r = (size_t)nr;
    double *mats[4] = {calloc(n * n, sizeof(double)), calloc(n * n, sizeof(double)), calloc(n * n, sizeof(double)),
                       calloc(n * (r ? r : 1), sizeof(double))};
    static const char *const names[4] = {"M", "D", "C", "B"};
    unsigned unknown = 0;
    int rc = -1;
    for (int k = 0; k < 4; ++k)
        if (!mats[k]) goto out;
    for (int k = 0; k < 4; ++k) {
        size_t cols = k == 3 ? r : n;
        const config_setting_t *a = config_setting_get_member(g, names[k]);
        vibid_cfg_field(f, sizeof f, path, names[k]);
        if (!a) {
            if (k == 3 && r == 0) continue;
            if (k == 1) continue; /* D may be omitted: undamped */
            vibid_cfg_fail(c, g, f, "missing (matrix given row by row as a list of numbers)");
            goto out;
        }
        if (!config_setting_is_array(a) && !config_setting_is_list(a)) {
            vibid_cfg_fail(c, a, f, "must be an array of %zu numbers (row by row)", n * cols);
            goto out;
        }
        if ((size_t)config_setting_length(a) != n * cols) {
            vibid_cfg_fail(c, a, f, "has %d numbers, expected %zu (%zu x %zu, row by row)",
                           config_setting_length(a), n * cols, n, cols);
            goto out;
        }
        for (size_t i = 0; i < n; ++i)
            for (size_t j = 0; j < cols; ++j) {
                const config_setting_t *e = config_setting_get_elem(a, (unsigned)(i * cols + j));
                int t = config_setting_type(e);
                if (t != CONFIG_TYPE_FLOAT && t != CONFIG_TYPE_INT && t != CONFIG_TYPE_INT64) {
                    vibid_cfg_fail(c, e, f, "element %zu is not a number", i * cols + j);
                    goto out;
                }
                mats[k][i + j * n] = t == CONFIG_TYPE_FLOAT ? config_setting_get_float(e)
                                                              : (double)config_setting_get_int64(e);
            }
    }
    const config_setting_t *u = config_setting_get_member(g, "unknown");
    if (u) {
        vibid_cfg_field(f, sizeof f, path, "unknown");
        if (!config_setting_is_array(u) && !config_setting_is_list(u)) {
            vibid_cfg_fail(c, u, f, "must be a list of matrix names, e.g. [\"D\", \"C\"]");
            goto out;
        }
        for (int i = 0; i < config_setting_length(u); ++i) {
            const char *s = config_setting_get_string_elem(u, (unsigned)i);
            int k = -1;
            for (int j = 0; j < 4; ++j)
                if (s && !strcmp(s, names[j])) k = j;
            if (k < 0) {
                vibid_cfg_fail(c, u, f, "'%s' is not one of M, D, C, B", s ? s : "?");
                goto out;
            }
            unknown |= 1u << k;
        }
    }
    vibid_status st = vibid_model_set_matrices(m, n, r, mats[0], mats[1], mats[2], r ? mats[3] : NULL, unknown);
    if (st != VIBID_OK) {
        lib_fail(c, g, path, st);
        goto out;
    }
    pd->n_nodes = n;
    for (size_t i = 0; i < n; ++i) {
        /* channels "q1".."qn" unless named in `channels` */
        pd->node_names[i][0] = NULL;
    }
    const config_setting_t *ch = config_setting_get_member(g, "channels");
    if (ch) {
        vibid_cfg_field(f, sizeof f, path, "channels");
        if ((size_t)config_setting_length(ch) != n + r) {
            vibid_cfg_fail(c, ch, f, "must name %zu channels: the n displacements, then the inputs", n + r);
            goto out;
        }
        for (size_t i = 0; i < n + r; ++i) {
            const char *s = config_setting_get_string_elem(ch, (unsigned)i);
            if (!s) {
                vibid_cfg_fail(c, ch, f, "element %zu is not a channel name", i);
                goto out;
            }
            if (vibid_cfg_check_name(c, config_setting_get_elem(ch, (unsigned)i), f, s)) goto out;
            if (i < n)
                pd->node_names[i][0] = s;
            else
                pd->input_names[i - n] = s;
        }
    }
    pd->n_inputs = r;
    rc = 0;
out:
    for (int k = 0; k < 4; ++k) free(mats[k]);
    return rc;
}

/* The stand's own settings: known keys, length_unit, name, sample_rate, discretization.
 * Apart from the model's description (nodes ... or matrices), which they do not depend on.
 * *name points into the configuration. 0, or -1 after an error. */
static int read_stand_settings(const vibid_cfg_reader *c, const config_setting_t *g, vibid_stand *st,
                               const char **name) {
    const char *path = "stand";
    static const char *const known[] = {"name",   "sample_rate", "discretization", "length_unit",  "matrices",
                                        "nodes",  "base",        "elements",       "inputs", "disturbances", NULL};
    if (vibid_cfg_check_keys(c, g, path, known)) return -1;
    const char *lu = "m";
    if (vibid_cfg_string_ref(c, g, path, "length_unit", &lu) < 0) return -1;
    if (vibid_unit_si_factor(VIBID_DIM_LENGTH, lu, &st->length_si) || strlen(lu) >= sizeof st->length_unit)
        return vibid_cfg_fail(c, config_setting_get_member(g, "length_unit"), "stand.length_unit",
                              "'%s' is not a length unit (%s)", lu, vibid_unit_names(VIBID_DIM_LENGTH));
    snprintf(st->length_unit, sizeof st->length_unit, "%s", lu);
    if (vibid_cfg_name(c, g, path, "name", name) < 0) return -1;
    if (require_number(c, g, path, "sample_rate", &st->sample_rate)) return -1;
    if (!(st->sample_rate > 0))
        return vibid_cfg_fail(c, config_setting_get_member(g, "sample_rate"), "stand.sample_rate",
                              "must be > 0 (Hz)");
    static const char *const discs[] = {"central_difference", "zoh", NULL};
    static const vibid_discretization disc_values[] = {VIBID_DISC_CENTRAL_DIFFERENCE, VIBID_DISC_ZOH};
    int d;
    int r = vibid_cfg_enum(c, g, path, "discretization", discs, false, &d);
    if (r < 0) return -1;
    if (r) vibid_model_set_discretization(st->model, disc_values[d]);
    return 0;
}

/* What every entry of nodes and elements begins with: only known keys, a name, and the
 * optional flag `unknown`. One check for both lists. */
static int read_entry_head(const vibid_cfg_reader *c, const config_setting_t *e, const char *p,
                           const char *const *keys, const char **nm, bool *unknown) {
    return vibid_cfg_check_keys(c, e, p, keys) || require_name(c, e, p, "name", nm) ||
                   vibid_cfg_bool(c, e, p, "unknown", unknown) < 0
               ? -1
               : 0;
}

/* One entry of stand.nodes: a mass (known, or unknown with its true value), what of it is
 * measured under which channel names, the sensors' noise. */
static int read_node(const vibid_cfg_reader *c, vibid_model *m, const config_setting_t *e, const char *p,
                     pending *pd) {
    static const char *const node_keys[] = {"name", "mass", "unknown", "true_value", "measure", "noise", NULL};
    const char *nm;
    double mass = 0;
    bool unknown = false;
    char f[200];
    if (read_entry_head(c, e, p, node_keys, &nm, &unknown)) return -1;
    int has_mass = get_number(c, e, p, "mass", &mass);
    if (has_mass < 0) return -1;
    if (!has_mass && !unknown) {
        vibid_cfg_field(f, sizeof f, p, "mass");
        return vibid_cfg_fail(c, e, f, "missing: a known mass needs its value in kg");
    }
    size_t idx;
    vibid_status s = vibid_model_add_node(m, nm, mass, unknown, &idx);
    if (s != VIBID_OK) {
        vibid_cfg_field(f, sizeof f, p, "mass");
        return lib_fail(c, config_setting_get_member(e, "mass") ? config_setting_get_member(e, "mass") : e,
                        strstr(vibid_last_error(), "name") ? p : f, s);
    }
    if (unknown && note_true_value(c, e, p, mass, pd)) return -1;
    unsigned mask;
    if (read_measure(c, e, p, &mask, pd->node_names[idx])) return -1;
    vibid_model_set_measured(m, idx, mask);
    if (read_noise(c, m, e, p, idx, mask)) return -1;
    pd->n_nodes = idx + 1;
    return 0;
}

/* stand.base { measure, noise, hold }: the moving base's sensors and its hold. */
static int read_base(const vibid_cfg_reader *c, vibid_model *m, const config_setting_t *base, pending *pd) {
    static const char *const base_keys[] = {"measure", "noise", "hold", NULL};
    const char *path = "stand.base";
    unsigned mask;
    if (vibid_cfg_check_keys(c, base, path, base_keys)) return -1;
    if (read_measure(c, base, path, &mask, pd->base_names)) return -1;
    vibid_model_set_measured(m, VIBID_BASE, mask);
    if (read_noise(c, m, base, path, VIBID_BASE, mask)) return -1;
    return read_hold(c, m, base, path, VIBID_BASE);
}

/* One entry of stand.elements: a spring, damper or cubic spring between a node and a node,
 * the ground or the base (the node first), known or unknown. */
static int read_element(const vibid_cfg_reader *c, vibid_model *m, const config_setting_t *e, const char *p,
                        pending *pd) {
    static const char *const element_keys[] = {"name", "kind", "between", "value", "unknown", "true_value", NULL};
    static const char *const kinds[] = {"spring", "damper", "cubic_spring", NULL};
    static const vibid_element_kind kind_values[] = {VIBID_ELEMENT_SPRING, VIBID_ELEMENT_DAMPER,
                                                     VIBID_ELEMENT_CUBIC_SPRING};
    const char *nm;
    double value = 0;
    bool unknown = false;
    char f[200];
    int ki;
    if (read_entry_head(c, e, p, element_keys, &nm, &unknown)) return -1;
    if (vibid_cfg_require(c, e, p, "kind", "a string is required: spring, damper, cubic_spring") ||
        vibid_cfg_enum(c, e, p, "kind", kinds, false, &ki) < 0)
        return -1;
    int hv = get_number(c, e, p, "value", &value);
    if (hv < 0) return -1;
    if (!hv && !unknown) {
        vibid_cfg_field(f, sizeof f, p, "value");
        return vibid_cfg_fail(c, e, f, "missing: a known element needs its value");
    }
    const config_setting_t *btw = config_setting_get_member(e, "between");
    vibid_cfg_field(f, sizeof f, p, "between");
    if (!btw || config_setting_length(btw) != 2 || !config_setting_get_string_elem(btw, 0) ||
        !config_setting_get_string_elem(btw, 1))
        return vibid_cfg_fail(c, btw ? btw : e, f, "must be two names [\"node\", \"node|ground|base\"]");
    size_t a, b;
    if (resolve_end(c, m, btw, f, config_setting_get_string_elem(btw, 0), &a) ||
        resolve_end(c, m, btw, f, config_setting_get_string_elem(btw, 1), &b))
        return -1;
    if (a == VIBID_GROUND || a == VIBID_BASE) { /* put the node first */
        size_t t = a;
        a = b;
        b = t;
    }
    vibid_status s = vibid_model_add_element(m, nm, kind_values[ki], a, b, value, unknown);
    if (s != VIBID_OK) return lib_fail(c, e, p, s);
    return unknown ? note_true_value(c, e, p, value, pd) : 0;
}

/* One entry of stand.inputs: a force on a node with its gain (known or unknown), the
 * channel that carries it, its hold. */
static int read_input(const vibid_cfg_reader *c, vibid_model *m, const config_setting_t *e, const char *p,
                      pending *pd) {
    static const char *const input_keys[] = {"name", "node", "gain", "unknown", "true_value", "channel", "hold",
                                             NULL};
    const char *nm, *node, *chan;
    double gain = 1.0;
    bool unknown = false;
    char f[200];
    /* not read_entry_head: node is required before unknown is read, as the messages have always had it */
    if (vibid_cfg_check_keys(c, e, p, input_keys) || require_name(c, e, p, "name", &nm) ||
        require_name(c, e, p, "node", &node) || vibid_cfg_bool(c, e, p, "unknown", &unknown) < 0 ||
        get_number(c, e, p, "gain", &gain) < 0)
        return -1;
    if (require_name(c, e, p, "channel", &chan)) return -1;
    size_t idx;
    vibid_cfg_field(f, sizeof f, p, "node");
    if (vibid_model_find_node(m, node, &idx) != VIBID_OK)
        return vibid_cfg_fail(c, config_setting_get_member(e, "node"), f, "'%s' is not a declared node", node);
    size_t in_idx;
    vibid_status s = vibid_model_add_input(m, nm, idx, gain, unknown, &in_idx);
    if (s != VIBID_OK) return lib_fail(c, e, p, s);
    if (unknown && note_true_value(c, e, p, gain, pd)) return -1;
    if (read_hold(c, m, e, p, in_idx)) return -1;
    pd->input_nodes[pd->n_inputs] = (long)idx;
    pd->input_names[pd->n_inputs++] = chan;
    return 0;
}

typedef int (*entry_reader)(const vibid_cfg_reader *c, vibid_model *m, const config_setting_t *e, const char *p,
                            pending *pd);

/* Each entry of the list `name` ("stand.<name>.[i]") through `read`; an absent list has
 * none. The one loop of nodes, elements and inputs. */
static int read_entries(const vibid_cfg_reader *c, vibid_model *m, const config_setting_t *list, const char *name,
                        entry_reader read, pending *pd) {
    for (int i = 0; list && i < config_setting_length(list); ++i) {
        char p[64];
        snprintf(p, sizeof p, "stand.%s.[%d]", name, i);
        if (read(c, m, config_setting_get_elem(list, (unsigned)i), p, pd)) return -1;
    }
    return 0;
}

/* A stand described as a lumped network: nodes (required, non-empty), base, elements,
 * inputs, disturbances, in the order in which the later refer to the earlier. */
static int read_network(const vibid_cfg_reader *c, const config_setting_t *g, vibid_stand *st, pending *pd) {
    vibid_model *m = st->model;
    const config_setting_t *nodes = config_setting_get_member(g, "nodes");
    if (!nodes || !config_setting_is_list(nodes) || config_setting_length(nodes) == 0)
        return vibid_cfg_fail(c, nodes ? nodes : g, "stand.nodes",
                              "must be a non-empty list ( { name = ...; mass = ...; }, ... )");
    if (read_entries(c, m, nodes, "nodes", read_node, pd)) return -1;
    const config_setting_t *base = config_setting_get_member(g, "base");
    if (base && read_base(c, m, base, pd)) return -1;
    if (read_entries(c, m, config_setting_get_member(g, "elements"), "elements", read_element, pd) ||
        read_entries(c, m, config_setting_get_member(g, "inputs"), "inputs", read_input, pd))
        return -1;
    const config_setting_t *dist = config_setting_get_member(g, "disturbances");
    return dist ? read_disturbances(c, m, dist, st) : 0;
}

/* The model's description: a network (nodes, elements, ...) or full matrices, not both;
 * a full-matrix stand has no disturbances. *from_matrices says which. */
static int read_model(const vibid_cfg_reader *c, const config_setting_t *g, vibid_stand *st, pending *pd,
                      int *from_matrices) {
    const config_setting_t *mats = config_setting_get_member(g, "matrices");
    const config_setting_t *dist = config_setting_get_member(g, "disturbances");
    *from_matrices = mats != NULL;
    if (mats && config_setting_get_member(g, "nodes"))
        return vibid_cfg_fail(c, mats, "stand.matrices", "give either nodes/elements or matrices, not both");
    if (mats && dist)
        /* vibid_model_add_disturbance needs a node: a full-matrix model has only coordinates */
        return vibid_cfg_fail(c, dist, "stand.disturbances",
                              "a full-matrix stand (matrices) has no disturbances: describe it by "
                              "nodes and elements to declare one");
    return mats ? read_matrices(c, st->model, mats, "stand.matrices", pd) : read_network(c, g, st, pd);
}

/* The acquisition name of model channel ci: the name the file gives it (measure, inputs'
 * channel, matrices' channels), NULL if none (the model's name then serves). */
static const char *acquisition_name(const pending *pd, const vibid_channel_info *ci) {
    int q = ci->kind == VIBID_CHANNEL_DISPLACEMENT ? 0 : ci->kind == VIBID_CHANNEL_VELOCITY ? 1 : 2;
    if (ci->kind == VIBID_CHANNEL_INPUT) return ci->index < pd->n_inputs ? pd->input_names[ci->index] : NULL;
    if (ci->index == VIBID_BASE) return pd->base_names[q];
    return ci->index < pd->n_nodes ? pd->node_names[ci->index][q] : NULL;
}

/* The tables the programs need beside the finalized model, from what reading collected:
 * name, channel names, true values (a full-matrix stand: nominal = true), input nodes.
 * Apart from reading: it needs the model's final dimensions. 0, or -1 when out of memory
 * (no message: the caller reports it). */
static int fill_stand_tables(vibid_stand *st, const pending *pd, const char *name, int from_matrices) {
    const vibid_model *m = st->model;
    vibid_model_dims dims;
    vibid_model_get_dims(m, &dims);
    st->name = dup_string(name);
    st->n_channels = dims.n_channels;
    st->channel_names = calloc(dims.n_channels ? dims.n_channels : 1, sizeof(char *));
    st->true_values = calloc(dims.n_params ? dims.n_params : 1, sizeof(double));
    st->true_given = calloc(dims.n_params ? dims.n_params : 1, 1);
    st->n_unknowns = dims.n_params;
    if (!st->true_std) st->true_std = calloc(1, sizeof(double)); /* no disturbances: never NULL */
    st->n_inputs = dims.n_inputs;
    st->input_nodes = calloc(dims.n_inputs ? dims.n_inputs : 1, sizeof(long));
    if (!st->name || !st->channel_names || !st->true_values || !st->true_given || !st->true_std || !st->input_nodes)
        return -1;
    for (size_t i = 0; i < dims.n_inputs; ++i) st->input_nodes[i] = from_matrices ? -1 : pd->input_nodes[i];
    if (from_matrices) {
        vibid_model_nominal(m, st->true_values);
    } else {
        for (size_t i = 0; i < dims.n_params; ++i) {
            st->true_values[i] = pd->true_values[i];
            st->true_given[i] = pd->has_true[i] ? 1 : 0;
        }
    }
    for (size_t i = 0; i < dims.n_channels; ++i) {
        vibid_channel_info ci;
        vibid_model_channel_info(m, i, &ci);
        const char *acq = acquisition_name(pd, &ci);
        st->channel_names[i] = dup_string(acq ? acq : ci.name);
        if (!st->channel_names[i]) return -1;
    }
    return 0;
}

vibid_stand *vibid_stand_from_setting(const config_setting_t *g, const char *file, vibid_stand_error *err) {
    vibid_stand_error local; /* err may be NULL: the reader always needs somewhere to write */
    vibid_cfg_reader c = {file, err ? err : &local};
    memset(c.err, 0, sizeof *c.err);
    if (!g || !config_setting_is_group(g)) {
        vibid_cfg_fail(&c, g, "stand", "must be a group { ... }");
        return NULL;
    }
    vibid_stand *st = calloc(1, sizeof *st);
    pending *pd = calloc(1, sizeof *pd); /* large: on the heap */
    const char *name = "stand";
    int from_matrices = 0, rc = -1;
    vibid_status s;
    if (!st || !pd || !(st->model = vibid_model_create())) {
        vibid_cfg_fail(&c, g, "stand", "out of memory");
    } else if (!read_stand_settings(&c, g, st, &name) && !read_model(&c, g, st, pd, &from_matrices)) {
        /* Unknowns of a full-matrix model have no true_value fields: nominal = true. */
        if ((s = vibid_model_finalize(st->model)) != VIBID_OK)
            lib_fail(&c, g, "stand", s);
        else if (fill_stand_tables(st, pd, name, from_matrices))
            vibid_cfg_fail(&c, g, "stand", "out of memory");
        else
            rc = 0;
    }
    free(pd);
    if (rc) {
        vibid_stand_destroy(st);
        return NULL;
    }
    return st;
}

vibid_stand *vibid_stand_load(const char *path, vibid_stand_error *err) {
    vibid_stand_error local;
    vibid_cfg_reader c = {path, err ? err : &local};
    memset(c.err, 0, sizeof *c.err);
    config_t cfg;
    if (vibid_cfg_read_file(&cfg, path, c.err)) {
        config_destroy(&cfg);
        return NULL;
    }
    const config_setting_t *g = config_lookup(&cfg, "stand");
    vibid_stand *st = NULL;
    if (!g)
        vibid_cfg_fail(&c, config_root_setting(&cfg), "stand",
                       "missing: the file must contain a group stand = { ... };");
    else
        st = vibid_stand_from_setting(g, path, c.err);
    config_destroy(&cfg);
    return st;
}

const vibid_model *vibid_stand_model(const vibid_stand *stand) { return stand ? stand->model : NULL; }
const char *vibid_stand_name(const vibid_stand *stand) { return stand ? stand->name : NULL; }
double vibid_stand_sample_rate(const vibid_stand *stand) { return stand ? stand->sample_rate : 0.0; }
const double *vibid_stand_true_values(const vibid_stand *stand) { return stand ? stand->true_values : NULL; }
const double *vibid_stand_disturbance_true_std(const vibid_stand *stand) { return stand ? stand->true_std : NULL; }
int vibid_stand_true_value_given(const vibid_stand *stand, size_t index) {
    if (!stand || index >= stand->n_unknowns) return 0;
    return stand->true_given[index];
}

const char *vibid_stand_channel_name(const vibid_stand *stand, size_t channel) {
    if (!stand || channel >= stand->n_channels) return NULL;
    return stand->channel_names[channel];
}

size_t vibid_stand_find_channel(const vibid_stand *stand, const char *name) {
    if (!stand || !name) return (size_t)-1;
    for (size_t i = 0; i < stand->n_channels; ++i)
        if (!strcmp(stand->channel_names[i], name)) return i;
    return (size_t)-1;
}
const char *vibid_stand_length_unit(const vibid_stand *stand) { return stand ? stand->length_unit : NULL; }
double vibid_stand_length_si(const vibid_stand *stand) { return stand ? stand->length_si : 0.0; }
long vibid_stand_input_node(const vibid_stand *stand, size_t input) {
    return stand && input < stand->n_inputs ? stand->input_nodes[input] : -1;
}
