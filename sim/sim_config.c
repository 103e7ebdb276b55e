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

int sim_config_load(const char *path, const vibid_stand *stand, const uint64_t *seed, sim_config *cfg, char *err,
                    size_t errlen)
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
    for (size_t i = 0; i < SIM_MAX_CHANNELS; i++) cfg->can_sig[i] = (sim_can_signal){SIM_CAN_FLOAT32, 1.0};

    vibid_cfg_error cerr = {0};
    ctx c = {path, &cerr};
    const vibid_model *model = vibid_stand_model(stand);
    vibid_model_dims d;
    vibid_model_get_dims(model, &d);
    if (d.n_channels > SIM_MAX_CHANNELS) {
        vibid_cfg_fail(&c, NULL, "stand", "%zu channels; vibid-sim handles at most %d", d.n_channels,
                       SIM_MAX_CHANNELS);
        if (err && errlen) snprintf(err, errlen, "%s", cerr.text);
        return -1;
    }
    /* Each input behaves as the stand declares it unless simulation.hold overrides all. */
    cfg->smooth = -1;
    resolve_holds(cfg, model, d.n_inputs);

    config_t lc;
    int rc = -1;
    if (vibid_cfg_read_file(&lc, path, &cerr)) goto out;
    if (seed) cfg->seed = *seed;
    const config_setting_t *g = config_lookup(&lc, "simulation");
    if (!g) { rc = 0; goto out; }
    const char *gp = "simulation";
    if (!config_setting_is_group(g)) {
        vibid_cfg_fail(&c, g, gp, "must be a group { ... }");
        goto out;
    }
    static const char *const known[] = {"seed", "duration", "hold", "integrator", "excitation", "noise",
                                        "changes", "can", "modbus", NULL};
    if (vibid_cfg_check_keys(&c, g, gp, known)) goto out;

    double v;
    int r;
    if ((r = get_num(&c, g, gp, "seed", &v)) < 0) goto out;
    if (r) {
        if (v < 0) {
            vibid_cfg_fail(&c, config_setting_get_member(g, "seed"), "simulation.seed", "must be >= 0");
            goto out;
        }
        cfg->seed = (uint64_t)v;
    }
    if (seed) cfg->seed = *seed;
    if ((r = get_num(&c, g, gp, "duration", &v)) < 0) goto out;
    if (r) {
        if (!(v > 0)) {
            vibid_cfg_fail(&c, config_setting_get_member(g, "duration"), "simulation.duration",
                           "%g must be > 0 s", v);
            goto out;
        }
        cfg->duration = v;
    }
    static const char *const holds[] = {"zoh", "smooth", NULL}; /* index = cfg->smooth */
    if ((r = vibid_cfg_enum(&c, g, gp, "hold", holds, false, &cfg->smooth)) < 0) goto out;
    if (r) {
        resolve_holds(cfg, model, d.n_inputs);
        unsigned bm = base_rate_measured(model, &d);
        if (!cfg->smooth && bm) {
            vibid_cfg_fail(
                &c, config_setting_get_member(g, "hold"), "simulation.hold",
                "\"zoh\" holds the base, whose %s is measured: a held displacement's derivative is a train "
                "of "
                "impulses that no sensor reports (measure only the base displacement, or use \"smooth\")",
                bm & VIBID_MEASURE_VELOCITY ? "velocity" : "acceleration");
            goto out;
        }
    }

    const config_setting_t *ig = config_setting_get_member(g, "integrator");
    const config_setting_t *kind_setting = NULL; /* where integrator.kind = "exact" was asked for */
    if (ig) {
        static const char *const ik[] = {"kind", "rtol", "atol", "method", NULL};
        if (!config_setting_is_group(ig)) {
            vibid_cfg_fail(&c, ig, "simulation.integrator", "must be a group");
            goto out;
        }
        if (vibid_cfg_check_keys(&c, ig, "simulation.integrator", ik)) goto out;
        static const char *const kinds[] = {"auto", "exact", "arkode", NULL}; /* index = sim_integrator */
        int kind = SIM_INTEGRATOR_AUTO;
        if ((r = vibid_cfg_enum(&c, ig, "simulation.integrator", "kind", kinds, false, &kind)) < 0) goto out;
        cfg->integrator = (sim_integrator)kind;
        if (r) kind_setting = config_setting_get_member(ig, "kind");
        if (cfg->integrator == SIM_INTEGRATOR_EXACT && d.nonlinear) {
            vibid_cfg_fail(&c, kind_setting, "simulation.integrator.kind",
                           "\"exact\" needs a linear stand, and this one has a cubic spring: its motion has no "
                           "closed form between samples (use \"auto\" or \"arkode\", which integrate it with ARKODE)");
            goto out;
        }
        if (get_num(&c, ig, "simulation.integrator", "rtol", &cfg->rtol) < 0) goto out;
        if (get_num(&c, ig, "simulation.integrator", "atol", &cfg->atol) < 0) goto out;
        static const char *const methods[] = {"fehlberg8", "dormand_prince5", NULL}; /* index = cfg->method */
        if (vibid_cfg_enum(&c, ig, "simulation.integrator", "method", methods, false, &cfg->method) < 0)
            goto out;
        if (!(cfg->rtol >= 1e-14 && cfg->rtol <= 1e-2)) {
            vibid_cfg_fail(&c, ig, "simulation.integrator.rtol", "%g outside [1e-14, 1e-2]", cfg->rtol);
            goto out;
        }
        if (!(cfg->atol > 0)) {
            vibid_cfg_fail(&c, ig, "simulation.integrator.atol", "%g must be > 0", cfg->atol);
            goto out;
        }
    }

    int lerr;
    const config_setting_t *ex = get_list(&c, g, gp, "excitation", &lerr);
    if (lerr) goto out;
    for (int i = 0; ex && i < config_setting_length(ex); i++) {
        const config_setting_t *e = config_setting_get_elem(ex, (unsigned)i);
        char p[128];
        snprintf(p, sizeof p, "simulation.excitation.[%d]", i);
        if (!config_setting_is_group(e)) {
            vibid_cfg_fail(&c, e, p, "must be a group { ... }");
            goto out;
        }
        const char *tg = NULL;
        if (vibid_cfg_string_ref(&c, e, p, "target", &tg) < 0) goto out;
        if (!tg) {
            vibid_cfg_fail(&c, e, p,
                           "target missing: \"base\", the name of a force input or of a disturbance");
            goto out;
        }
        int is_base = strcmp(tg, "base") == 0, is_dist = 0;
        size_t input = 0;
        if (is_base && !d.has_base) {
            vibid_cfg_fail(&c, e, p, "target \"base\": no element of the stand connects to the base");
            goto out;
        }
        if (!is_base) {
            int found = 0;
            char names[512] = "", dnames[512] = "";
            for (size_t k = 0; k < d.n_channels && !found; k++) {
                vibid_channel_info ci;
                vibid_model_channel_info(model, k, &ci);
                if (ci.kind != VIBID_CHANNEL_INPUT) continue;
                const char *an = vibid_stand_channel_name(stand, k);
                if (strcmp(ci.name, tg) == 0 || (an && strcmp(an, tg) == 0)) { found = 1; input = ci.index; }
                strncat(names, ci.name, sizeof names - strlen(names) - 1);
                strncat(names, " ", sizeof names - strlen(names) - 1);
            }
            /* A disturbance's name is unique among the model's names, but an input's channel
             * name may equal it: refuse the ambiguity rather than pick one. */
            for (size_t k = 0; k < d.n_disturbances; k++) {
                vibid_disturbance_info wi;
                vibid_model_disturbance_info(model, k, &wi);
                if (strcmp(wi.name, tg) == 0) {
                    if (found) {
                        vibid_cfg_fail(&c, config_setting_get_member(e, "target"), p,
                                       "target '%s' names both a force input's channel and a disturbance",
                                       tg);
                        goto out;
                    }
                    found = is_dist = 1;
                    input = k;
                }
                if (dnames[0]) strncat(dnames, ", ", sizeof dnames - strlen(dnames) - 1);
                strncat(dnames, wi.name, sizeof dnames - strlen(dnames) - 1);
            }
            if (!found) {
                vibid_cfg_fail(&c, config_setting_get_member(e, "target"), p,
                               "target '%s' is neither \"base\" nor a force input nor a disturbance of the "
                               "stand (inputs: %s; "
                               "disturbances: %s)",
                               tg, names[0] ? names : "none", dnames[0] ? dnames : "none");
                goto out;
            }
        }
        sim_exc_target *t = NULL;
        for (size_t k = 0; k < cfg->n_targets; k++)
            if (cfg->targets[k].is_base == is_base && cfg->targets[k].is_disturbance == is_dist &&
                (is_base || cfg->targets[k].input == input))
                t = &cfg->targets[k];
        if (!t) {
            sim_exc_target *nt = realloc(cfg->targets, (cfg->n_targets + 1) * sizeof *nt);
            if (!nt) {
                vibid_cfg_fail(&c, e, p, "out of memory");
                goto out;
            }
            cfg->targets = nt;
            t = &cfg->targets[cfg->n_targets++];
            memset(t, 0, sizeof *t);
            t->is_base = is_base;
            t->is_disturbance = is_dist;
            t->input = input;
        }
        sim_exc_spec *ns = realloc(t->specs, (t->n + 1) * sizeof *ns);
        if (!ns) {
            vibid_cfg_fail(&c, e, p, "out of memory");
            goto out;
        }
        t->specs = ns;
        if (parse_exc(&c, e, p, cfg->seed, (size_t)i, &t->specs[t->n])) goto out;
        t->n++;
    }

    /* "exact" refuses a smooth input with a component that is not piecewise linear between
     * samples: the exact step could not take a single interval of it, and a run asked to be
     * exact must not silently run on ARKODE throughout (sim_engine.h). */
    for (size_t i = 0; cfg->integrator == SIM_INTEGRATOR_EXACT && i < cfg->n_targets; i++) {
        const sim_exc_target *t = &cfg->targets[i];
        int smooth = t->is_base ? cfg->base_smooth
                     : t->is_disturbance ? 0
                     : t->input < SIM_MAX_CHANNELS ? cfg->input_smooth[t->input] : 1;
        for (size_t j = 0; smooth && j < t->n; j++) {
            sim_exc_kind k = t->specs[j].kind;
            if (k == SIM_EXC_CONSTANT || k == SIM_EXC_PRBS || k == SIM_EXC_NOISE) continue;
            vibid_cfg_fail(&c, kind_setting, "simulation.integrator.kind",
                           "\"exact\" is exact for inputs held over each sample or linear between samples, and "
                           "the %s is smooth with a %s component, which is neither (hold it: hold = \"zoh\", or "
                           "use \"auto\", which integrates such intervals with ARKODE)",
                           t->is_base ? "base" : "force input", sim_exc_kind_name(k));
            goto out;
        }
    }

    const config_setting_t *nl = get_list(&c, g, gp, "noise", &lerr);
    if (lerr) goto out;
    for (int i = 0; nl && i < config_setting_length(nl); i++) {
        const config_setting_t *e = config_setting_get_elem(nl, (unsigned)i);
        char p[128];
        snprintf(p, sizeof p, "simulation.noise.[%d]", i);
        static const char *const nk[] = {"channel", "std", "snr_db", "resolution", "offset", "correlation_time", NULL};
        if (!config_setting_is_group(e)) {
            vibid_cfg_fail(&c, e, p, "must be a group { ... }");
            goto out;
        }
        if (vibid_cfg_check_keys(&c, e, p, nk)) goto out;
        const char *ch = NULL;
        if (vibid_cfg_string_ref(&c, e, p, "channel", &ch) < 0) goto out;
        if (!ch) {
            vibid_cfg_fail(&c, e, p, "channel missing");
            goto out;
        }
        size_t idx = find_channel(stand, ch);
        if (idx == (size_t)-1) {
            char names[512];
            channel_list(stand, names, sizeof names);
            vibid_cfg_fail(&c, config_setting_get_member(e, "channel"), p,
                           "unknown channel '%s' (channels: %s)", ch, names);
            goto out;
        }
        sim_noise_spec ns = {idx, NAN, NAN, 0.0, 0.0, 0.0}; /* std NaN: not given (the stand's noise may apply) */
        int hs, hn;
        if ((hs = get_num(&c, e, p, "std", &ns.std)) < 0 || (hn = get_num(&c, e, p, "snr_db", &ns.snr_db)) < 0 ||
            get_num(&c, e, p, "resolution", &ns.resolution) < 0 || get_num(&c, e, p, "offset", &ns.offset) < 0 ||
            get_num(&c, e, p, "correlation_time", &ns.corr_time) < 0)
            goto out;
        if (!isfinite(ns.offset)) {
            vibid_cfg_fail(&c, e, p, "offset = %g must be finite", ns.offset);
            goto out;
        }
        if (!(ns.corr_time >= 0.0) || !isfinite(ns.corr_time)) {
            vibid_cfg_fail(&c, e, p, "correlation_time = %g s must be >= 0 and finite (0: white noise)", ns.corr_time);
            goto out;
        }
        if (hs && hn) {
            vibid_cfg_fail(&c, e, p, "give either std or snr_db, not both");
            goto out;
        }
        if (hs && ns.std < 0) {
            vibid_cfg_fail(&c, e, p, "std = %g must be >= 0", ns.std);
            goto out;
        }
        if (ns.resolution < 0) {
            vibid_cfg_fail(&c, e, p, "resolution = %g must be >= 0", ns.resolution);
            goto out;
        }
        sim_noise_spec *nn = realloc(cfg->noise, (cfg->n_noise + 1) * sizeof *nn);
        if (!nn) {
            vibid_cfg_fail(&c, e, p, "out of memory");
            goto out;
        }
        cfg->noise = nn;
        cfg->noise[cfg->n_noise++] = ns;
    }

    const config_setting_t *cl = get_list(&c, g, gp, "changes", &lerr);
    if (lerr) goto out;
    for (int i = 0; cl && i < config_setting_length(cl); i++) {
        const config_setting_t *e = config_setting_get_elem(cl, (unsigned)i);
        char p[128];
        snprintf(p, sizeof p, "simulation.changes.[%d]", i);
        static const char *const ck[] = {"parameter", "at", "ramp", "factor", "value", NULL};
        if (!config_setting_is_group(e)) {
            vibid_cfg_fail(&c, e, p, "must be a group { ... }");
            goto out;
        }
        if (vibid_cfg_check_keys(&c, e, p, ck)) goto out;
        const char *pn = NULL;
        if (vibid_cfg_string_ref(&c, e, p, "parameter", &pn) < 0) goto out;
        if (!pn) {
            vibid_cfg_fail(&c, e, p, "parameter missing");
            goto out;
        }
        size_t pi = (size_t)-1;
        char names[512] = "";
        for (size_t k = 0; k < d.n_params; k++) {
            vibid_param_info inf;
            vibid_model_param_info(model, k, &inf);
            if (strcmp(inf.name, pn) == 0) pi = k;
            strncat(names, inf.name, sizeof names - strlen(names) - 1);
            strncat(names, " ", sizeof names - strlen(names) - 1);
        }
        if (pi == (size_t)-1) {
            vibid_cfg_fail(&c, config_setting_get_member(e, "parameter"), p,
                           "'%s' is not an unknown parameter of the stand (changeable: %s); only parameters "
                           "marked unknown = true can change",
                           pn, names[0] ? names : "none");
            goto out;
        }
        sim_change ch = {pi, 0.0, 0.0, 0.0};
        double factor = 0.0;
        int ha, hf, hv;
        if ((ha = get_num(&c, e, p, "at", &ch.at)) < 0 || get_num(&c, e, p, "ramp", &ch.ramp) < 0 ||
            (hf = get_num(&c, e, p, "factor", &factor)) < 0 || (hv = get_num(&c, e, p, "value", &ch.value)) < 0)
            goto out;
        if (!ha || ch.at < 0) {
            vibid_cfg_fail(&c, e, p, "at (s, >= 0) missing or negative");
            goto out;
        }
        if (ch.ramp < 0) {
            vibid_cfg_fail(&c, e, p, "ramp = %g must be >= 0 s", ch.ramp);
            goto out;
        }
        if (hf == hv) {
            vibid_cfg_fail(&c, e, p, "give exactly one of factor (times the true value) or value");
            goto out;
        }
        if (hf) ch.value = factor * vibid_stand_true_values(stand)[pi];
        for (size_t k = 0; k < cfg->n_changes; k++)
            if (cfg->changes[k].param == pi && !(ch.at >= cfg->changes[k].at + cfg->changes[k].ramp)) {
                vibid_cfg_fail(&c, e, p, "changes of '%s' must be given in time order without overlap", pn);
                goto out;
            }
        sim_change *nc = realloc(cfg->changes, (cfg->n_changes + 1) * sizeof *nc);
        if (!nc) {
            vibid_cfg_fail(&c, e, p, "out of memory");
            goto out;
        }
        cfg->changes = nc;
        cfg->changes[cfg->n_changes++] = ch;
    }

    const config_setting_t *cg = config_setting_get_member(g, "can");
    if (cg) {
        const char *cp = "simulation.can";
        static const char *const kk[] = {"id", "fd", "extended", "signals", NULL};
        if (!config_setting_is_group(cg)) {
            vibid_cfg_fail(&c, cg, cp, "must be a group");
            goto out;
        }
        if (vibid_cfg_check_keys(&c, cg, cp, kk)) goto out;
        bool fd = false, ext = false;
        if (vibid_cfg_bool(&c, cg, cp, "fd", &fd) < 0 || vibid_cfg_bool(&c, cg, cp, "extended", &ext) < 0)
            goto out;
        cfg->can_fd = fd;
        cfg->can_extended = ext;
        if ((r = get_num(&c, cg, cp, "id", &v)) < 0) goto out;
        if (r) cfg->can_id = (uint32_t)v;
        if (r && (v < 0 || v > (cfg->can_extended ? 0x1FFFFFFF : 0x7FF))) {
            vibid_cfg_fail(&c, config_setting_get_member(cg, "id"), "simulation.can.id", "%g outside 0..0x%X",
                           v, cfg->can_extended ? 0x1FFFFFFF : 0x7FF);
            goto out;
        }
        const config_setting_t *sl = get_list(&c, cg, cp, "signals", &lerr);
        if (lerr) goto out;
        for (int i = 0; sl && i < config_setting_length(sl); i++) {
            const config_setting_t *e = config_setting_get_elem(sl, (unsigned)i);
            char p[128];
            snprintf(p, sizeof p, "simulation.can.signals.[%d]", i);
            static const char *const sk[] = {"channel", "type", "scale", NULL};
            if (!config_setting_is_group(e)) {
                vibid_cfg_fail(&c, e, p, "must be a group");
                goto out;
            }
            if (vibid_cfg_check_keys(&c, e, p, sk)) goto out;
            const char *ch = NULL;
            static const char *const types[] = {"int16", "int32", "float32", NULL};
            static const sim_can_type type_values[] = {SIM_CAN_INT16, SIM_CAN_INT32, SIM_CAN_FLOAT32};
            int ty = 2;
            if (vibid_cfg_string_ref(&c, e, p, "channel", &ch) < 0 ||
                vibid_cfg_enum(&c, e, p, "type", types, false, &ty) < 0)
                goto out;
            if (!ch) {
                vibid_cfg_fail(&c, e, p, "channel missing");
                goto out;
            }
            size_t idx = find_channel(stand, ch);
            if (idx == (size_t)-1) {
                char names[512];
                channel_list(stand, names, sizeof names);
                vibid_cfg_fail(&c, config_setting_get_member(e, "channel"), p,
                               "unknown channel '%s' (channels: %s)", ch, names);
                goto out;
            }
            sim_can_signal sg = {type_values[ty], 1.0};
            if (get_num(&c, e, p, "scale", &sg.scale) < 0) goto out;
            if (!(sg.scale > 0)) {
                vibid_cfg_fail(&c, e, p, "scale = %g must be > 0", sg.scale);
                goto out;
            }
            if (sg.type == SIM_CAN_FLOAT32 && sg.scale != 1.0) {
                vibid_cfg_fail(&c, e, p, "float32 signals are not scaled (scale must be 1)");
                goto out;
            }
            cfg->can_sig[idx] = sg;
        }
    }

    const config_setting_t *mg = config_setting_get_member(g, "modbus");
    if (mg) {
        const char *mp = "simulation.modbus";
        static const char *const mk[] = {"fifo_base", "capacity", NULL};
        if (!config_setting_is_group(mg)) {
            vibid_cfg_fail(&c, mg, mp, "must be a group");
            goto out;
        }
        if (vibid_cfg_check_keys(&c, mg, mp, mk)) goto out;
        if ((r = get_num(&c, mg, mp, "fifo_base", &v)) < 0) goto out;
        if (r) {
            if (v < 0 || v > 65535) {
                vibid_cfg_fail(&c, mg, "simulation.modbus.fifo_base", "%g outside 0..65535", v);
                goto out;
            }
            cfg->fifo_base = (unsigned)v;
        }
        if ((r = get_num(&c, mg, mp, "capacity", &v)) < 0) goto out;
        if (r) {
            if (v < 2 || v > 32767) {
                vibid_cfg_fail(&c, mg, "simulation.modbus.capacity", "%g outside 2..32767", v);
                goto out;
            }
            cfg->fifo_capacity = (unsigned)v;
        }
    }
    rc = 0;
out:
    config_destroy(&lc);
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
    cfg->targets = NULL;
    cfg->noise = NULL;
    cfg->changes = NULL;
    cfg->n_targets = cfg->n_noise = cfg->n_changes = 0;
}
