/* sim/sim_config.c: reads the `simulation` group (see sim_config.h, docs/sim.md). */
#include "sim_config.h"

#include <libconfig.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <vibid/cfgread.h>

typedef vibid_cfg_reader ctx; /* the configuration reader (vibid/cfgread.h) */

/* A finite number of any size (ranges are checked where the value is used, with the
 * reason): 1 given, 0 absent, -1 error. */
static int get_num(const ctx *c, const config_setting_t *g, const char *gpath, const char *name,
                   double *out) {
    return vibid_cfg_number(c, g, gpath, name, -HUGE_VAL, HUGE_VAL, out);
}

/* A list member: NULL when absent; *err = -1 when it is not a list. */
static const config_setting_t *get_list(const ctx *c, const config_setting_t *g, const char *gpath,
                                        const char *name, int *err) {
    const config_setting_t *l = NULL;
    *err = vibid_cfg_list(c, g, gpath, name, &l) < 0 ? -1 : 0;
    return l;
}

/* model channel index from an acquisition name or a model channel name */
static size_t find_channel(const vibid_stand *st, const char *name)
{
    size_t i = vibid_stand_find_channel(st, name);
    if (i != (size_t)-1) return i;
    const vibid_model *m = vibid_stand_model(st);
    vibid_model_dims d;
    vibid_model_get_dims(m, &d);
    for (size_t k = 0; k < d.n_channels; k++) {
        vibid_channel_info ci;
        if (vibid_model_channel_info(m, k, &ci) == VIBID_OK && strcmp(ci.name, name) == 0) return k;
    }
    return (size_t)-1;
}

static void channel_list(const vibid_stand *st, char *buf, size_t cap)
{
    vibid_model_dims d;
    vibid_model_get_dims(vibid_stand_model(st), &d);
    buf[0] = 0;
    for (size_t k = 0; k < d.n_channels; k++) {
        const char *nm = vibid_stand_channel_name(st, k);
        strncat(buf, nm ? nm : "?", cap - strlen(buf) - 1);
        if (k + 1 < d.n_channels) strncat(buf, ", ", cap - strlen(buf) - 1);
    }
}

/* cfg->base_smooth / input_smooth from the override cfg->smooth (-1: the stand's declarations). */
static void resolve_holds(sim_config *cfg, const vibid_model *model, size_t n_inputs)
{
    vibid_hold hd = VIBID_HOLD_SMOOTH;
    if (cfg->smooth >= 0) cfg->base_smooth = cfg->smooth;
    else cfg->base_smooth = vibid_model_get_hold(model, VIBID_BASE, &hd) != VIBID_OK || hd != VIBID_HOLD_ZOH;
    for (size_t j = 0; j < n_inputs && j < SIM_MAX_CHANNELS; j++) {
        if (cfg->smooth >= 0) cfg->input_smooth[j] = cfg->smooth;
        else cfg->input_smooth[j] = vibid_model_get_hold(model, j, &hd) != VIBID_OK || hd != VIBID_HOLD_ZOH;
    }
}

/* VIBID_MEASURE_VELOCITY / _ACCELERATION bits of the base channels that are measured. */
static unsigned base_rate_measured(const vibid_model *model, const vibid_model_dims *d)
{
    unsigned bits = 0;
    for (size_t k = 0; k < d->n_channels; k++) {
        vibid_channel_info ci;
        if (vibid_model_channel_info(model, k, &ci) != VIBID_OK || ci.index != VIBID_BASE) continue;
        if (ci.kind == VIBID_CHANNEL_VELOCITY) bits |= VIBID_MEASURE_VELOCITY;
        if (ci.kind == VIBID_CHANNEL_ACCELERATION) bits |= VIBID_MEASURE_ACCELERATION;
    }
    return bits;
}

static int parse_exc(const ctx *c, const config_setting_t *e, const char *path, uint64_t seed, size_t index,
                     sim_exc_spec *s) {
    static const char *const known[] = {"target", "kind", "amplitude", "offset", "frequency", "phase",
                                        "f_start", "f_stop", "sweep_time", "dwell", "steps", "f_low",
                                        "f_high", "order", "samples_per_bit", "t_on", "t_off", "seed", NULL};
    if (vibid_cfg_check_keys(c, e, path, known)) return -1;
    const char *kind = NULL;
    if (vibid_cfg_string_ref(c, e, path, "kind", &kind) < 0) return -1;
    if (!kind)
        return vibid_cfg_fail(
            c, e, path,
            "kind missing (constant, triangle, sine, stepped_sine, sweep_linear, sweep_log, prbs, noise)");
    int k = sim_exc_kind_from_name(kind);
    if (k < 0) {
        char p2[256];
        snprintf(p2, sizeof p2, "%s.kind", path);
        return vibid_cfg_fail(c, config_setting_get_member(e, "kind"), p2,
                              "unknown kind '%s' (constant, triangle, sine, stepped_sine, sweep_linear, "
                              "sweep_log, prbs, noise)",
                              kind);
    }
    sim_exc_spec_init(s, (sim_exc_kind)k);
    double v;
    struct { const char *name; double *dst; } nums[] = {
        {"amplitude", &s->amplitude}, {"offset", &s->offset}, {"frequency", &s->frequency},
        {"phase", &s->phase_deg}, {"f_start", &s->f_start}, {"f_stop", &s->f_stop},
        {"sweep_time", &s->sweep_time}, {"dwell", &s->dwell}, {"f_low", &s->f_low},
        {"f_high", &s->f_high}, {"t_on", &s->t_on}, {"t_off", &s->t_off}};
    for (size_t i = 0; i < sizeof nums / sizeof nums[0]; i++)
        if (get_num(c, e, path, nums[i].name, nums[i].dst) < 0) return -1;
    int r;
    if ((r = get_num(c, e, path, "steps", &v)) < 0) return -1;
    if (r) s->steps = (int)v;
    if ((r = get_num(c, e, path, "order", &v)) < 0) return -1;
    if (r) s->prbs_order = (int)v;
    if ((r = get_num(c, e, path, "samples_per_bit", &v)) < 0) return -1;
    if (r) s->prbs_samples = (int)v;
    if ((r = get_num(c, e, path, "seed", &v)) < 0) return -1;
    /* each random component gets its own stream: run seed and position, unless given */
    s->seed = r ? (uint64_t)v : seed * 1000003ull + index + 1;
    if (s->kind == SIM_EXC_NOISE && !config_setting_get_member(e, "f_high"))
        s->f_high = INFINITY; /* full band: no low-pass */
    return 0;
}

/* What every parser of the simulation group needs: the reader (file, errors), the stand
 * whose names the settings refer to, its model and dimensions, and the configuration being
 * filled. One argument instead of five for each group's parser. */
typedef struct sim_reader {
    const ctx *c;
    const vibid_stand *stand;
    const vibid_model *model;
    vibid_model_dims d;
    sim_config *cfg;
} sim_reader;

/* arr (n elements of size bytes) grown by one element, or NULL with "out of memory" at `e`
 * (arr then unchanged). Kept apart because the excitation targets, their components, the
 * noise and the changes all append one parsed entry at a time. */
static void *grow_by_one(const sim_reader *r, const config_setting_t *e, const char *p, void *arr, size_t n,
                         size_t size)
{
    void *na = realloc(arr, (n + 1) * size);
    if (!na) vibid_cfg_fail(r->c, e, p, "out of memory");
    return na;
}

/* The i-th element of a list setting, which must be a group; its path ("simulation.noise.[2]")
 * into p. Every list of the simulation group is a list of groups: one check, one message
 * (not_group: "must be a group" or "must be a group { ... }", as each list has always said).
 * NULL after an error. */
static const config_setting_t *list_group_elem(const sim_reader *r, const config_setting_t *list,
                                               const char *lpath, int i, char *p, size_t cap,
                                               const char *not_group)
{
    const config_setting_t *e = config_setting_get_elem(list, (unsigned)i);
    snprintf(p, cap, "%s.[%d]", lpath, i);
    if (!config_setting_is_group(e)) {
        vibid_cfg_fail(r->c, e, p, "%s", not_group);
        return NULL;
    }
    return e;
}

/* The optional sub-group `name` of g (integrator, can, modbus): absent 0, a group with
 * known keys only 1 (*out set), otherwise -1. Apart so that the three share one check. */
static int open_subgroup(const sim_reader *r, const config_setting_t *g, const char *name, const char *path,
                         const char *const *known, const config_setting_t **out)
{
    const config_setting_t *s = config_setting_get_member(g, name);
    *out = s;
    if (!s) return 0;
    if (!config_setting_is_group(s)) return vibid_cfg_fail(r->c, s, path, "must be a group");
    return vibid_cfg_check_keys(r->c, s, path, known) ? -1 : 1;
}

/* The model channel named `name` (an acquisition or model channel name) into *idx, or
 * "unknown channel" listing the stand's channels. Shared by the noise and CAN signal
 * entries, which both name a channel. */
static int resolve_channel(const sim_reader *r, const config_setting_t *e, const char *p, const char *name,
                           size_t *idx)
{
    *idx = find_channel(r->stand, name);
    if (*idx != (size_t)-1) return 0;
    char names[512];
    channel_list(r->stand, names, sizeof names);
    return vibid_cfg_fail(r->c, config_setting_get_member(e, "channel"), p,
                          "unknown channel '%s' (channels: %s)", name, names);
}

/* The output channel named `name` for a CAN signal: a stand channel as resolve_channel, or
 * a covariate (output channel n_channels + j; they are read before simulation.can). The
 * noise entries stay with resolve_channel: a covariate has its own `noise`. */
static int resolve_output_channel(const sim_reader *r, const config_setting_t *e, const char *p, const char *name,
                                  size_t *idx)
{
    for (size_t j = 0; j < r->cfg->n_covariates; j++)
        if (strcmp(r->cfg->covariates[j].name, name) == 0) {
            *idx = r->d.n_channels + j;
            return 0;
        }
    *idx = find_channel(r->stand, name);
    if (*idx != (size_t)-1) return 0;
    char names[512], *end;
    channel_list(r->stand, names, sizeof names);
    for (size_t j = 0; j < r->cfg->n_covariates; j++) {
        end = names + strlen(names);
        snprintf(end, sizeof names - (size_t)(end - names), "%s%s", j ? ", " : "; covariates: ",
                 r->cfg->covariates[j].name);
    }
    return vibid_cfg_fail(r->c, config_setting_get_member(e, "channel"), p,
                          "unknown channel '%s' (channels: %s)", name, names);
}

/* Appends `name` and a space to a fixed buffer (the lists of names in messages). */
static void append_name(char *buf, size_t cap, const char *name)
{
    strncat(buf, name, cap - strlen(buf) - 1);
    strncat(buf, " ", cap - strlen(buf) - 1);
}

/* simulation.seed: the file's seed (>= 0). The command line's seed replaces it afterwards
 * (sim_config_load), before any stream is derived from it. */
static int parse_seed(const sim_reader *r, const config_setting_t *g, const char *gp)
{
    double v;
    int got = get_num(r->c, g, gp, "seed", &v);
    if (got <= 0) return got;
    if (v < 0)
        return vibid_cfg_fail(r->c, config_setting_get_member(g, "seed"), "simulation.seed", "must be >= 0");
    r->cfg->seed = (uint64_t)v;
    return 0;
}

/* simulation.duration (> 0 s) and simulation.hold, which overrides every input's hold but
 * may not hold a base whose velocity or acceleration is measured. */
static int parse_duration_and_hold(const sim_reader *r, const config_setting_t *g, const char *gp)
{
    sim_config *cfg = r->cfg;
    double v;
    int got = get_num(r->c, g, gp, "duration", &v);
    if (got < 0) return -1;
    if (got) {
        if (!(v > 0))
            return vibid_cfg_fail(r->c, config_setting_get_member(g, "duration"), "simulation.duration",
                                  "%g must be > 0 s", v);
        cfg->duration = v;
    }
    static const char *const holds[] = {"zoh", "smooth", NULL}; /* index = cfg->smooth */
    if ((got = vibid_cfg_enum(r->c, g, gp, "hold", holds, false, &cfg->smooth)) <= 0) return got;
    resolve_holds(cfg, r->model, r->d.n_inputs);
    unsigned bm = base_rate_measured(r->model, &r->d);
    if (!cfg->smooth && bm)
        return vibid_cfg_fail(
            r->c, config_setting_get_member(g, "hold"), "simulation.hold",
            "\"zoh\" holds the base, whose %s is measured: a held displacement's derivative is a train "
            "of "
            "impulses that no sensor reports (measure only the base displacement, or use \"smooth\")",
            bm & VIBID_MEASURE_VELOCITY ? "velocity" : "acceleration");
    return 0;
}

/* simulation.integrator { kind, rtol, atol, method }. *kind_setting: where kind was given
 * (NULL otherwise), for the later check of "exact" against the excitations. */
static int parse_integrator(const sim_reader *r, const config_setting_t *g,
                            const config_setting_t **kind_setting)
{
    static const char *const ik[] = {"kind", "rtol", "atol", "method", NULL};
    const char *ip = "simulation.integrator";
    sim_config *cfg = r->cfg;
    const config_setting_t *ig;
    int got = open_subgroup(r, g, "integrator", ip, ik, &ig);
    if (got <= 0) return got;
    static const char *const kinds[] = {"auto", "exact", "arkode", NULL}; /* index = sim_integrator */
    int kind = SIM_INTEGRATOR_AUTO;
    if ((got = vibid_cfg_enum(r->c, ig, ip, "kind", kinds, false, &kind)) < 0) return -1;
    cfg->integrator = (sim_integrator)kind;
    if (got) *kind_setting = config_setting_get_member(ig, "kind");
    if (cfg->integrator == SIM_INTEGRATOR_EXACT && r->d.nonlinear)
        return vibid_cfg_fail(r->c, *kind_setting, "simulation.integrator.kind",
                              "\"exact\" needs a linear stand, and this one has a cubic spring: its motion has no "
                              "closed form between samples (use \"auto\" or \"arkode\", which integrate it with "
                              "ARKODE)");
    if (get_num(r->c, ig, ip, "rtol", &cfg->rtol) < 0) return -1;
    if (get_num(r->c, ig, ip, "atol", &cfg->atol) < 0) return -1;
    static const char *const methods[] = {"fehlberg8", "dormand_prince5", NULL}; /* index = cfg->method */
    if (vibid_cfg_enum(r->c, ig, ip, "method", methods, false, &cfg->method) < 0) return -1;
    if (!(cfg->rtol >= 1e-14 && cfg->rtol <= 1e-2))
        return vibid_cfg_fail(r->c, ig, "simulation.integrator.rtol", "%g outside [1e-14, 1e-2]", cfg->rtol);
    if (!(cfg->atol > 0))
        return vibid_cfg_fail(r->c, ig, "simulation.integrator.atol", "%g must be > 0", cfg->atol);
    return 0;
}

/* What an excitation's `target` names: the base, a force input or a disturbance (index in
 * *input). Resolving names is apart from reading the excitation's signal (parse_exc):
 * it needs the stand's names and refuses the ambiguous ones. */
static int resolve_excitation_target(const sim_reader *r, const config_setting_t *e, const char *p,
                                     int *is_base, int *is_dist, size_t *input)
{
    const char *tg = NULL;
    if (vibid_cfg_string_ref(r->c, e, p, "target", &tg) < 0) return -1;
    if (!tg)
        return vibid_cfg_fail(r->c, e, p,
                              "target missing: \"base\", the name of a force input or of a disturbance");
    *is_base = strcmp(tg, "base") == 0;
    *is_dist = 0;
    *input = 0;
    if (*is_base) {
        if (!r->d.has_base)
            return vibid_cfg_fail(r->c, e, p,
                                  "target \"base\": no element of the stand connects to the base");
        return 0;
    }
    int found = 0;
    char names[512] = "", dnames[512] = "";
    for (size_t k = 0; k < r->d.n_channels && !found; k++) {
        vibid_channel_info ci;
        vibid_model_channel_info(r->model, k, &ci);
        if (ci.kind != VIBID_CHANNEL_INPUT) continue;
        const char *an = vibid_stand_channel_name(r->stand, k);
        if (strcmp(ci.name, tg) == 0 || (an && strcmp(an, tg) == 0)) {
            found = 1;
            *input = ci.index;
        }
        append_name(names, sizeof names, ci.name);
    }
    /* A disturbance's name is unique among the model's names, but an input's channel
     * name may equal it: refuse the ambiguity rather than pick one. */
    for (size_t k = 0; k < r->d.n_disturbances; k++) {
        vibid_disturbance_info wi;
        vibid_model_disturbance_info(r->model, k, &wi);
        if (strcmp(wi.name, tg) == 0) {
            if (found)
                return vibid_cfg_fail(r->c, config_setting_get_member(e, "target"), p,
                                      "target '%s' names both a force input's channel and a disturbance", tg);
            found = *is_dist = 1;
            *input = k;
        }
        if (dnames[0]) strncat(dnames, ", ", sizeof dnames - strlen(dnames) - 1);
        strncat(dnames, wi.name, sizeof dnames - strlen(dnames) - 1);
    }
    if (!found)
        return vibid_cfg_fail(r->c, config_setting_get_member(e, "target"), p,
                              "target '%s' is neither \"base\" nor a force input nor a disturbance of the "
                              "stand (inputs: %s; "
                              "disturbances: %s)",
                              tg, names[0] ? names : "none", dnames[0] ? dnames : "none");
    return 0;
}

/* The target entry for (is_base, is_dist, input), made when it is the first excitation of
 * that target: components of one target add up, so they are collected per target. NULL
 * after an error. */
static sim_exc_target *target_entry(const sim_reader *r, const config_setting_t *e, const char *p,
                                    int is_base, int is_dist, size_t input)
{
    sim_config *cfg = r->cfg;
    sim_exc_target *t = NULL;
    for (size_t k = 0; k < cfg->n_targets; k++)
        if (cfg->targets[k].is_base == is_base && cfg->targets[k].is_disturbance == is_dist &&
            (is_base || cfg->targets[k].input == input))
            t = &cfg->targets[k];
    if (t) return t;
    sim_exc_target *nt = grow_by_one(r, e, p, cfg->targets, cfg->n_targets, sizeof *nt);
    if (!nt) return NULL;
    cfg->targets = nt;
    t = &cfg->targets[cfg->n_targets++];
    memset(t, 0, sizeof *t);
    t->is_base = is_base;
    t->is_disturbance = is_dist;
    t->input = input;
    return t;
}

/* simulation.excitation ( { target, kind, ... }, ... ): each entry adds one component to
 * its target's signal. Its seed is derived from cfg->seed, which is final by now. */
static int parse_excitations(const sim_reader *r, const config_setting_t *g, const char *gp)
{
    int lerr;
    const config_setting_t *ex = get_list(r->c, g, gp, "excitation", &lerr);
    if (lerr) return -1;
    for (int i = 0; ex && i < config_setting_length(ex); i++) {
        char p[128];
        const config_setting_t *e =
            list_group_elem(r, ex, "simulation.excitation", i, p, sizeof p, "must be a group { ... }");
        if (!e) return -1;
        int is_base = 0, is_dist = 0;
        size_t input = 0;
        if (resolve_excitation_target(r, e, p, &is_base, &is_dist, &input)) return -1;
        sim_exc_target *t = target_entry(r, e, p, is_base, is_dist, input);
        if (!t) return -1;
        sim_exc_spec *ns = grow_by_one(r, e, p, t->specs, t->n, sizeof *ns);
        if (!ns) return -1;
        t->specs = ns;
        if (parse_exc(r->c, e, p, r->cfg->seed, (size_t)i, &t->specs[t->n])) return -1;
        t->n++;
    }
    return 0;
}

/* "exact" refuses a smooth input with a component that is not piecewise linear between
 * samples: the exact step could not take a single interval of it, and a run asked to be
 * exact must not silently run on ARKODE throughout (sim_engine.h). A check across the
 * integrator and the excitations, hence apart from parsing either. */
static int check_exact_integrable(const sim_reader *r, const config_setting_t *kind_setting)
{
    const sim_config *cfg = r->cfg;
    for (size_t i = 0; cfg->integrator == SIM_INTEGRATOR_EXACT && i < cfg->n_targets; i++) {
        const sim_exc_target *t = &cfg->targets[i];
        int smooth = t->is_base ? cfg->base_smooth
                     : t->is_disturbance ? 0
                     : t->input < SIM_MAX_CHANNELS ? cfg->input_smooth[t->input] : 1;
        for (size_t j = 0; smooth && j < t->n; j++) {
            sim_exc_kind k = t->specs[j].kind;
            if (k == SIM_EXC_CONSTANT || k == SIM_EXC_PRBS || k == SIM_EXC_NOISE) continue;
            return vibid_cfg_fail(r->c, kind_setting, "simulation.integrator.kind",
                                  "\"exact\" is exact for inputs held over each sample or linear between samples, "
                                  "and the %s is smooth with a %s component, which is neither (hold it: hold = "
                                  "\"zoh\", or use \"auto\", which integrates such intervals with ARKODE)",
                                  t->is_base ? "base" : "force input", sim_exc_kind_name(k));
        }
    }
    return 0;
}

/* The ranges of one noise entry, checked after all its numbers are read. */
static int check_noise_entry(const sim_reader *r, const config_setting_t *e, const char *p,
                             const sim_noise_spec *ns, int has_std, int has_snr)
{
    if (!isfinite(ns->offset)) return vibid_cfg_fail(r->c, e, p, "offset = %g must be finite", ns->offset);
    if (!(ns->corr_time >= 0.0) || !isfinite(ns->corr_time))
        return vibid_cfg_fail(r->c, e, p, "correlation_time = %g s must be >= 0 and finite (0: white noise)",
                              ns->corr_time);
    if (has_std && has_snr) return vibid_cfg_fail(r->c, e, p, "give either std or snr_db, not both");
    if (has_std && ns->std < 0) return vibid_cfg_fail(r->c, e, p, "std = %g must be >= 0", ns->std);
    if (ns->resolution < 0) return vibid_cfg_fail(r->c, e, p, "resolution = %g must be >= 0", ns->resolution);
    return 0;
}

/* simulation.noise ( { channel, std | snr_db, resolution, offset, correlation_time }, ... ). */
static int parse_noise(const sim_reader *r, const config_setting_t *g, const char *gp)
{
    static const char *const nk[] = {"channel", "std",    "snr_db", "resolution",
                                     "offset",  "correlation_time", NULL};
    sim_config *cfg = r->cfg;
    int lerr;
    const config_setting_t *nl = get_list(r->c, g, gp, "noise", &lerr);
    if (lerr) return -1;
    for (int i = 0; nl && i < config_setting_length(nl); i++) {
        char p[128];
        const config_setting_t *e =
            list_group_elem(r, nl, "simulation.noise", i, p, sizeof p, "must be a group { ... }");
        if (!e || vibid_cfg_check_keys(r->c, e, p, nk)) return -1;
        const char *ch = NULL;
        if (vibid_cfg_string_ref(r->c, e, p, "channel", &ch) < 0) return -1;
        if (!ch) return vibid_cfg_fail(r->c, e, p, "channel missing");
        size_t idx;
        if (resolve_channel(r, e, p, ch, &idx)) return -1;
        /* std NaN: not given (the stand's noise may apply) */
        sim_noise_spec ns = {idx, NAN, NAN, 0.0, 0.0, 0.0};
        int hs, hn;
        if ((hs = get_num(r->c, e, p, "std", &ns.std)) < 0 ||
            (hn = get_num(r->c, e, p, "snr_db", &ns.snr_db)) < 0 ||
            get_num(r->c, e, p, "resolution", &ns.resolution) < 0 ||
            get_num(r->c, e, p, "offset", &ns.offset) < 0 ||
            get_num(r->c, e, p, "correlation_time", &ns.corr_time) < 0)
            return -1;
        if (check_noise_entry(r, e, p, &ns, hs, hn)) return -1;
        sim_noise_spec *nn = grow_by_one(r, e, p, cfg->noise, cfg->n_noise, sizeof *nn);
        if (!nn) return -1;
        cfg->noise = nn;
        cfg->noise[cfg->n_noise++] = ns;
    }
    return 0;
}

/* The unknown parameter named by a change's `parameter` into *pi, or an error listing the
 * parameters that may change. */
static int resolve_changed_parameter(const sim_reader *r, const config_setting_t *e, const char *p,
                                     const char *pn, size_t *pi)
{
    *pi = (size_t)-1;
    char names[512] = "";
    for (size_t k = 0; k < r->d.n_params; k++) {
        vibid_param_info inf;
        vibid_model_param_info(r->model, k, &inf);
        if (strcmp(inf.name, pn) == 0) *pi = k;
        append_name(names, sizeof names, inf.name);
    }
    if (*pi != (size_t)-1) return 0;
    return vibid_cfg_fail(r->c, config_setting_get_member(e, "parameter"), p,
                          "'%s' is not an unknown parameter of the stand (changeable: %s); only parameters "
                          "marked unknown = true can change",
                          pn, names[0] ? names : "none");
}

/* The time range of one change: it starts at or after 0 s and ramps over >= 0 s. */
static int check_change_times(const sim_reader *r, const config_setting_t *e, const char *p,
                              const sim_change *ch, int has_at)
{
    if (!has_at || ch->at < 0) return vibid_cfg_fail(r->c, e, p, "at (s, >= 0) missing or negative");
    if (ch->ramp < 0) return vibid_cfg_fail(r->c, e, p, "ramp = %g must be >= 0 s", ch->ramp);
    return 0;
}

/* simulation.changes ( { parameter, at, ramp, factor | value }, ... ). */
static int parse_changes(const sim_reader *r, const config_setting_t *g, const char *gp)
{
    static const char *const ck[] = {"parameter", "at", "ramp", "factor", "value", NULL};
    sim_config *cfg = r->cfg;
    int lerr;
    const config_setting_t *cl = get_list(r->c, g, gp, "changes", &lerr);
    if (lerr) return -1;
    for (int i = 0; cl && i < config_setting_length(cl); i++) {
        char p[128];
        const config_setting_t *e =
            list_group_elem(r, cl, "simulation.changes", i, p, sizeof p, "must be a group { ... }");
        if (!e || vibid_cfg_check_keys(r->c, e, p, ck)) return -1;
        const char *pn = NULL;
        if (vibid_cfg_string_ref(r->c, e, p, "parameter", &pn) < 0) return -1;
        if (!pn) return vibid_cfg_fail(r->c, e, p, "parameter missing");
        size_t pi;
        if (resolve_changed_parameter(r, e, p, pn, &pi)) return -1;
        sim_change ch = {pi, 0.0, 0.0, 0.0};
        double factor = 0.0;
        int ha, hf, hv;
        if ((ha = get_num(r->c, e, p, "at", &ch.at)) < 0 || get_num(r->c, e, p, "ramp", &ch.ramp) < 0 ||
            (hf = get_num(r->c, e, p, "factor", &factor)) < 0 ||
            (hv = get_num(r->c, e, p, "value", &ch.value)) < 0)
            return -1;
        if (check_change_times(r, e, p, &ch, ha)) return -1;
        if (hf == hv)
            return vibid_cfg_fail(r->c, e, p, "give exactly one of factor (times the true value) or value");
        if (hf) ch.value = factor * vibid_stand_true_values(r->stand)[pi];
        for (size_t k = 0; k < cfg->n_changes; k++)
            if (cfg->changes[k].param == pi && !(ch.at >= cfg->changes[k].at + cfg->changes[k].ramp))
                return vibid_cfg_fail(r->c, e, p,
                                      "changes of '%s' must be given in time order without overlap", pn);
        sim_change *nc = grow_by_one(r, e, p, cfg->changes, cfg->n_changes, sizeof *nc);
        if (!nc) return -1;
        cfg->changes = nc;
        cfg->changes[cfg->n_changes++] = ch;
    }
    return 0;
}

double sim_covariate_value(const sim_covariate *c, double t)
{
    double v = c->mean + c->ramp * t;
    if (c->amplitude != 0.0) v += c->amplitude * sin(2.0 * M_PI * t / c->period + c->phase);
    return v;
}

int sim_covariate_varies(const sim_covariate *c) { return c->amplitude != 0.0 || c->ramp != 0.0; }

/* A covariate's name becomes a CSV column, a DBC signal and a register-map entry beside the
 * stand's channels, so it must differ from every channel name (acquisition and model
 * names), from the CSV's time column "t", from the CAN frames' SampleCounter, and from the
 * covariates before it. */
static int check_covariate_name(const sim_reader *r, const config_setting_t *e, const char *p, const char *name,
                                size_t j)
{
    const config_setting_t *ns = config_setting_get_member(e, "name");
    char field[160];
    snprintf(field, sizeof field, "%s.name", p);
    if (vibid_cfg_check_name(r->c, ns, field, name)) return -1;
    if (find_channel(r->stand, name) != (size_t)-1) {
        char names[512];
        channel_list(r->stand, names, sizeof names);
        return vibid_cfg_fail(r->c, ns, field, "'%s' is a channel of the stand (channels: %s); a covariate is a "
                              "channel of its own and needs another name", name, names);
    }
    if (strcmp(name, "t") == 0 || strcmp(name, "SampleCounter") == 0)
        return vibid_cfg_fail(r->c, ns, field, "'%s' is reserved (%s)", name,
                              name[0] == 't' ? "the CSV's time column" : "the CAN frames' sample counter");
    for (size_t k = 0; k < j; k++)
        if (strcmp(r->cfg->covariates[k].name, name) == 0)
            return vibid_cfg_fail(r->c, ns, field, "'%s' names covariate [%zu] already", name, k);
    return 0;
}

/* The numbers of one covariate and their ranges. The unit goes into the DBC between
 * quotes, so it is printable ASCII without '"'. */
static int parse_covariate_numbers(const sim_reader *r, const config_setting_t *e, const char *p, sim_covariate *cv)
{
    int hm = 0;
    if ((hm = get_num(r->c, e, p, "mean", &cv->mean)) < 0 || get_num(r->c, e, p, "amplitude", &cv->amplitude) < 0 ||
        get_num(r->c, e, p, "period", &cv->period) < 0 || get_num(r->c, e, p, "phase", &cv->phase) < 0 ||
        get_num(r->c, e, p, "ramp", &cv->ramp) < 0 || get_num(r->c, e, p, "noise", &cv->noise) < 0)
        return -1;
    if (!hm) return vibid_cfg_fail(r->c, e, p, "mean missing (the covariate's value without swing, its unit)");
    if (cv->amplitude != 0.0 && !(cv->period > 0.0))
        return vibid_cfg_fail(r->c, e, p, "period = %g s: must be > 0 when amplitude (%g) is not 0", cv->period,
                              cv->amplitude);
    if (cv->period < 0.0) return vibid_cfg_fail(r->c, e, p, "period = %g s must be > 0", cv->period);
    if (cv->noise < 0.0) return vibid_cfg_fail(r->c, e, p, "noise = %g must be >= 0 (a standard deviation)", cv->noise);
    for (const char *u = cv->unit; *u; u++)
        if (*u < 0x20 || *u > 0x7E || *u == '"')
            return vibid_cfg_fail(r->c, e, p, "unit '%s': printable ASCII without '\"' (it is quoted in the DBC)",
                                  cv->unit);
    return 0;
}

/* simulation.covariates ( { name, unit, mean, amplitude, period, phase, ramp, noise }, ... ):
 * at most SIM_MAX_COVARIATES. Read before the dependence (which names them) and the CAN
 * signals (which may give them a wire type). */
static int parse_covariates(const sim_reader *r, const config_setting_t *g, const char *gp)
{
    static const char *const ck[] = {"name", "unit", "mean", "amplitude", "period", "phase", "ramp", "noise", NULL};
    sim_config *cfg = r->cfg;
    int lerr;
    const config_setting_t *cl = get_list(r->c, g, gp, "covariates", &lerr);
    if (lerr) return -1;
    if (cl && config_setting_length(cl) > SIM_MAX_COVARIATES)
        return vibid_cfg_fail(r->c, cl, "simulation.covariates", "%d covariates; at most %d",
                              config_setting_length(cl), SIM_MAX_COVARIATES);
    for (int i = 0; cl && i < config_setting_length(cl); i++) {
        char p[128];
        const config_setting_t *e =
            list_group_elem(r, cl, "simulation.covariates", i, p, sizeof p, "must be a group { ... }");
        if (!e || vibid_cfg_check_keys(r->c, e, p, ck)) return -1;
        sim_covariate cv;
        memset(&cv, 0, sizeof cv);
        const char *name = NULL;
        if (vibid_cfg_string_ref(r->c, e, p, "name", &name) < 0) return -1;
        if (!name) return vibid_cfg_fail(r->c, e, p, "name missing (the covariate's channel name, e.g. \"T\")");
        if (check_covariate_name(r, e, p, name, (size_t)i)) return -1;
        snprintf(cv.name, sizeof cv.name, "%s", name);
        if (vibid_cfg_string(r->c, e, p, "unit", true, cv.unit, sizeof cv.unit) < 0) return -1;
        if (parse_covariate_numbers(r, e, p, &cv)) return -1;
        cfg->covariates[cfg->n_covariates++] = cv;
    }
    return 0;
}

/* simulation.dependence ( { parameter, covariate, coefficient, reference }, ... ). A pair
 * (parameter, covariate) at most once; several covariates of one parameter multiply. A
 * dependence on a covariate that varies keeps every interval on ARKODE (the parameter
 * changes inside it, as during a ramp), which integrator.kind = "exact" refuses. */
static int parse_dependence(const sim_reader *r, const config_setting_t *g, const char *gp)
{
    static const char *const dk[] = {"parameter", "covariate", "coefficient", "reference", NULL};
    sim_config *cfg = r->cfg;
    int lerr;
    const config_setting_t *dl = get_list(r->c, g, gp, "dependence", &lerr);
    if (lerr) return -1;
    for (int i = 0; dl && i < config_setting_length(dl); i++) {
        char p[128];
        const config_setting_t *e =
            list_group_elem(r, dl, "simulation.dependence", i, p, sizeof p, "must be a group { ... }");
        if (!e || vibid_cfg_check_keys(r->c, e, p, dk)) return -1;
        const char *pn = NULL, *cn = NULL;
        if (vibid_cfg_string_ref(r->c, e, p, "parameter", &pn) < 0 ||
            vibid_cfg_string_ref(r->c, e, p, "covariate", &cn) < 0)
            return -1;
        if (!pn) return vibid_cfg_fail(r->c, e, p, "parameter missing");
        if (!cn) return vibid_cfg_fail(r->c, e, p, "covariate missing");
        sim_dependence dp = {0, (size_t)-1, 0.0, 0.0};
        if (resolve_changed_parameter(r, e, p, pn, &dp.param)) return -1;
        char names[512] = "";
        for (size_t j = 0; j < cfg->n_covariates; j++) {
            if (strcmp(cfg->covariates[j].name, cn) == 0) dp.covariate = j;
            append_name(names, sizeof names, cfg->covariates[j].name);
        }
        if (dp.covariate == (size_t)-1)
            return vibid_cfg_fail(r->c, config_setting_get_member(e, "covariate"), p,
                                  "'%s' is not a covariate of simulation.covariates (covariates: %s)", cn,
                                  names[0] ? names : "none");
        const sim_covariate *cv = &cfg->covariates[dp.covariate];
        int hc, hr;
        if ((hc = get_num(r->c, e, p, "coefficient", &dp.coefficient)) < 0 ||
            (hr = get_num(r->c, e, p, "reference", &dp.reference)) < 0)
            return -1;
        if (!hc) return vibid_cfg_fail(r->c, e, p, "coefficient missing (relative change per covariate unit)");
        if (!hr) dp.reference = cv->mean;
        for (size_t k = 0; k < cfg->n_dependence; k++)
            if (cfg->dependence[k].param == dp.param && cfg->dependence[k].covariate == dp.covariate)
                return vibid_cfg_fail(r->c, e, p, "'%s' depends on '%s' already (entry [%zu])", pn, cn, k);
        if (cfg->integrator == SIM_INTEGRATOR_EXACT && dp.coefficient != 0.0 && sim_covariate_varies(cv))
            return vibid_cfg_fail(r->c, e, p,
                                  "'%s' follows covariate '%s', which varies: the parameter changes inside every "
                                  "sample interval, which the exact step cannot take, and integrator.kind = "
                                  "\"exact\" refuses runs that keep ARKODE on every interval (use \"auto\")",
                                  pn, cn);
        sim_dependence *nd = grow_by_one(r, e, p, cfg->dependence, cfg->n_dependence, sizeof *nd);
        if (!nd) return -1;
        cfg->dependence = nd;
        cfg->dependence[cfg->n_dependence++] = dp;
    }
    return 0;
}

/* One entry of simulation.can.signals: the channel's wire type and scale. */
static int parse_can_signal(const sim_reader *r, const config_setting_t *e, const char *p)
{
    static const char *const sk[] = {"channel", "type", "scale", NULL};
    static const char *const types[] = {"int16", "int32", "float32", NULL};
    static const sim_can_type type_values[] = {SIM_CAN_INT16, SIM_CAN_INT32, SIM_CAN_FLOAT32};
    if (vibid_cfg_check_keys(r->c, e, p, sk)) return -1;
    const char *ch = NULL;
    int ty = 2;
    if (vibid_cfg_string_ref(r->c, e, p, "channel", &ch) < 0 ||
        vibid_cfg_enum(r->c, e, p, "type", types, false, &ty) < 0)
        return -1;
    if (!ch) return vibid_cfg_fail(r->c, e, p, "channel missing");
    size_t idx;
    if (resolve_output_channel(r, e, p, ch, &idx)) return -1;
    sim_can_signal sg = {type_values[ty], 1.0};
    if (get_num(r->c, e, p, "scale", &sg.scale) < 0) return -1;
    if (!(sg.scale > 0)) return vibid_cfg_fail(r->c, e, p, "scale = %g must be > 0", sg.scale);
    if (sg.type == SIM_CAN_FLOAT32 && sg.scale != 1.0)
        return vibid_cfg_fail(r->c, e, p, "float32 signals are not scaled (scale must be 1)");
    r->cfg->can_sig[idx] = sg;
    return 0;
}

/* simulation.can { id, fd, extended, signals }: the frame the CAN server sends. */
static int parse_can(const sim_reader *r, const config_setting_t *g)
{
    static const char *const kk[] = {"id", "fd", "extended", "signals", NULL};
    const char *cp = "simulation.can";
    sim_config *cfg = r->cfg;
    const config_setting_t *cg;
    int got = open_subgroup(r, g, "can", cp, kk, &cg);
    if (got <= 0) return got;
    bool fd = false, ext = false;
    if (vibid_cfg_bool(r->c, cg, cp, "fd", &fd) < 0 || vibid_cfg_bool(r->c, cg, cp, "extended", &ext) < 0)
        return -1;
    cfg->can_fd = fd;
    cfg->can_extended = ext;
    double v;
    if ((got = get_num(r->c, cg, cp, "id", &v)) < 0) return -1;
    if (got) cfg->can_id = (uint32_t)v;
    if (got && (v < 0 || v > (cfg->can_extended ? 0x1FFFFFFF : 0x7FF)))
        return vibid_cfg_fail(r->c, config_setting_get_member(cg, "id"), "simulation.can.id",
                              "%g outside 0..0x%X", v, cfg->can_extended ? 0x1FFFFFFF : 0x7FF);
    int lerr;
    const config_setting_t *sl = get_list(r->c, cg, cp, "signals", &lerr);
    if (lerr) return -1;
    for (int i = 0; sl && i < config_setting_length(sl); i++) {
        char p[128];
        const config_setting_t *e =
            list_group_elem(r, sl, "simulation.can.signals", i, p, sizeof p, "must be a group");
        if (!e || parse_can_signal(r, e, p)) return -1;
    }
    return 0;
}

/* A whole number setting of group `s` in [lo, hi] into *out (absent: *out untouched);
 * the Modbus FIFO's base and capacity. The message names the group's line, as it always has. */
static int parse_modbus_range(const sim_reader *r, const config_setting_t *s, const char *name, double lo,
                              double hi, unsigned *out)
{
    char field[64];
    double v;
    int got = get_num(r->c, s, "simulation.modbus", name, &v);
    if (got <= 0) return got;
    if (v < lo || v > hi) {
        snprintf(field, sizeof field, "simulation.modbus.%s", name);
        return vibid_cfg_fail(r->c, s, field, "%g outside %g..%g", v, lo, hi);
    }
    *out = (unsigned)v;
    return 0;
}

/* simulation.modbus { fifo_base, capacity }: where the Modbus server's sample FIFO lives. */
static int parse_modbus(const sim_reader *r, const config_setting_t *g)
{
    static const char *const mk[] = {"fifo_base", "capacity", NULL};
    const config_setting_t *mg;
    int got = open_subgroup(r, g, "modbus", "simulation.modbus", mk, &mg);
    if (got <= 0) return got;
    if (parse_modbus_range(r, mg, "fifo_base", 0, 65535, &r->cfg->fifo_base) < 0) return -1;
    return parse_modbus_range(r, mg, "capacity", 2, 32767, &r->cfg->fifo_capacity) < 0 ? -1 : 0;
}

/* The defaults of every setting the simulation group may leave out. */
static void set_defaults(sim_config *cfg, const char *path)
{
    memset(cfg, 0, sizeof *cfg);
    snprintf(cfg->file, sizeof cfg->file, "%s", path);
    cfg->seed = 1;
    cfg->rtol = 1e-10;
    cfg->atol = 1e-12; /* m, m/s: far below any sensor resolution; 1e-15 made the error test fail
                          (e.g. example 1 at 1 kHz with the smooth triangle, t = 7.79 s) */
    cfg->can_id = 0x100;
    cfg->fifo_base = 1000;
    cfg->fifo_capacity = 1000;
    for (size_t i = 0; i < SIM_MAX_OUTPUTS; i++) cfg->can_sig[i] = (sim_can_signal){SIM_CAN_FLOAT32, 1.0};
}

/* The `simulation` group of the file read into lc (absent: the defaults), each of its
 * settings by the parser of its concern, in the order in which they depend on each other:
 * the seed before the excitations' streams, the hold and the integrator before the check
 * of "exact" against the excitations and the dependence, the covariates before the
 * dependence and the CAN signals that name them. `seed` (the command line's) replaces the file's. */
static int parse_simulation_group(const sim_reader *r, const config_t *lc, const uint64_t *seed)
{
    static const char *const known[] = {"seed", "duration", "hold", "integrator", "excitation", "noise",
                                        "changes", "covariates", "dependence", "can", "modbus", NULL};
    const char *gp = "simulation";
    const config_setting_t *g = config_lookup(lc, gp);
    if (g && !config_setting_is_group(g)) return vibid_cfg_fail(r->c, g, gp, "must be a group { ... }");
    if (g && (vibid_cfg_check_keys(r->c, g, gp, known) || parse_seed(r, g, gp))) return -1;
    if (seed) r->cfg->seed = *seed;
    if (!g) return 0;
    const config_setting_t *kind_setting = NULL; /* where integrator.kind = "exact" was asked for */
    if (parse_duration_and_hold(r, g, gp) || parse_integrator(r, g, &kind_setting) < 0 ||
        parse_excitations(r, g, gp) || check_exact_integrable(r, kind_setting) || parse_noise(r, g, gp) ||
        parse_changes(r, g, gp) || parse_covariates(r, g, gp) || parse_dependence(r, g, gp) || parse_can(r, g) < 0 ||
        parse_modbus(r, g) < 0)
        return -1;
    return 0;
}

int sim_config_load(const char *path, const vibid_stand *stand, const uint64_t *seed, sim_config *cfg, char *err,
                    size_t errlen)
{
    set_defaults(cfg, path);
    vibid_cfg_error cerr = {0};
    ctx c = {path, &cerr};
    sim_reader r = {&c, stand, vibid_stand_model(stand), {0}, cfg};
    vibid_model_get_dims(r.model, &r.d);
    int rc = -1;
    if (r.d.n_channels > SIM_MAX_CHANNELS) {
        vibid_cfg_fail(&c, NULL, "stand", "%zu channels; vibid-sim handles at most %d", r.d.n_channels,
                       SIM_MAX_CHANNELS);
    } else {
        /* Each input behaves as the stand declares it unless simulation.hold overrides all. */
        cfg->smooth = -1;
        resolve_holds(cfg, r.model, r.d.n_inputs);
        config_t lc;
        if (vibid_cfg_read_file(&lc, path, &cerr) == 0) rc = parse_simulation_group(&r, &lc, seed);
        config_destroy(&lc);
    }
    if (rc) {
        sim_config_free(cfg);
        if (err && errlen) snprintf(err, errlen, "%s", cerr.text);
    }
    return rc;
}

void sim_config_free(sim_config *cfg)
{
    if (!cfg) return;
    for (size_t i = 0; i < cfg->n_targets; i++) free(cfg->targets[i].specs);
    free(cfg->targets);
    free(cfg->noise);
    free(cfg->changes);
    free(cfg->dependence);
    cfg->targets = NULL;
    cfg->noise = NULL;
    cfg->changes = NULL;
    cfg->dependence = NULL;
    cfg->n_targets = cfg->n_noise = cfg->n_changes = cfg->n_dependence = cfg->n_covariates = 0;
}
