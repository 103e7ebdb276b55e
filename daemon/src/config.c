/* config.c: reading, checking and printing vibidd's configuration (config.h).
 *
 * Every directive is read through one of the typed getters below, each with an explicit
 * range and default; unknown directives are errors (a typo must not silently leave a
 * default in place). Messages: "file:line: field: what is wrong".
 */
#include "config.h"
#include "config_read.h"

#include <vibid/change.h>
#include <vibid/output_error.h>

#include "log.h"
#include "metrics.h"
#include "output.h"

#include <vibid/outlier.h>

#include <ctype.h>
#include <errno.h>
#include <libconfig.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include <vibid/units.h>
#include <vibid_drivers/source_replay.h>

/* The getters of config_read.h. */

/* Thin adapters over the configuration reader (vibid/cfgread.h): each getter fills in the
 * directive's default first, so that an absent directive reads as its default, and
 * returns 0 or -1 (the reader's message in c->r.err). */

int vd_cfg_known(vd_cfg_ctx *c, const config_setting_t *group, const char *section, const char *const *known)
{
    return vibid_cfg_check_keys(&c->r, group, section, known);
}

int vd_cfg_double(vd_cfg_ctx *c, const config_setting_t *g, const char *section, const char *name, double def, double lo,
                      double hi, double *out)
{
    *out = def;
    return vibid_cfg_number(&c->r, g, section, name, lo, hi, out) < 0 ? -1 : 0;
}

int vd_cfg_int(vd_cfg_ctx *c, const config_setting_t *g, const char *section, const char *name, long long def,
                   long long lo, long long hi, long long *out)
{
    *out = def;
    return vibid_cfg_int(&c->r, g, section, name, lo, hi, out) < 0 ? -1 : 0;
}

int vd_cfg_bool(vd_cfg_ctx *c, const config_setting_t *g, const char *section, const char *name, bool def, bool *out)
{
    *out = def;
    return vibid_cfg_bool(&c->r, g, section, name, out) < 0 ? -1 : 0;
}

/* String of at most cap-1 characters ("" allowed: it means "not set" for the outputs). */
int vd_cfg_string(vd_cfg_ctx *c, const config_setting_t *g, const char *section, const char *name, const char *def,
                      char *out, size_t cap)
{
    snprintf(out, cap, "%s", def);
    return vibid_cfg_string(&c->r, g, section, name, true, out, cap) < 0 ? -1 : 0;
}

/* A name (the safe set of vibid/cfgread.h: A-Z a-z 0-9 _ - ., written into outputs
 * unescaped), copied into out; absent leaves def; "" only where allow_empty (it means
 * "not set"). */
int vd_cfg_name(vd_cfg_ctx *c, const config_setting_t *g, const char *section, const char *name, const char *def,
                    bool allow_empty, char *out, size_t cap)
{
    if (vd_cfg_string(c, g, section, name, def, out, cap))
        return -1;
    const config_setting_t *s = g ? config_setting_get_member(g, name) : NULL;
    if (!s || (allow_empty && !out[0]))
        return 0;
    char f[192];
    vibid_cfg_field(f, sizeof f, section, name);
    return vibid_cfg_check_name(&c->r, s, f, out);
}

/* One of `names` (NULL-terminated); *out = its index. */
int vd_cfg_enum(vd_cfg_ctx *c, const config_setting_t *g, const char *section, const char *name, int def,
                    const char *const *names, int *out)
{
    *out = def;
    return vibid_cfg_enum(&c->r, g, section, name, names, false, out) < 0 ? -1 : 0;
}

/* A file name relative to the file that names it; absent or "" leaves "" (not set). */
int vd_cfg_path(vd_cfg_ctx *c, const config_setting_t *g, const char *section, const char *name, char *out, size_t cap)
{
    out[0] = '\0';
    const config_setting_t *s = g ? config_setting_get_member(g, name) : NULL;
    if (s && config_setting_type(s) == CONFIG_TYPE_STRING && !*config_setting_get_string(s)) return 0;
    return vibid_cfg_path(&c->r, g, section, name, out, cap) < 0 ? -1 : 0;
}

/* ---- sections ---- */

static const char *const oma_known[] = {"name",       "sample_rate", "channels",    "refs",       "modes",
                                        "window",     "every",       "block",       "block_rows", "max_order",
                                        "max_damping", "match_freq", "match_mac",   "outlier_threshold",
                                        "stand",      NULL};

/* oma.stand: a stand file without inputs whose nodes name the response channels (issue 34
 * item 3); its sample rate is the default of oma.sample_rate. 0, or -1 with the error. */
static int load_oma_stand(vd_cfg_ctx *c, config_setting_t *g)
{
    vd_oma_config *o = &c->cfg->oma;
    const config_setting_t *s = config_setting_get_member(g, "stand");
    if (!s)
        return 0;
    if (config_setting_type(s) != CONFIG_TYPE_STRING)
        return vibid_cfg_fail(&c->r, s, "oma.stand", "must be the name of a stand file (a string)");
    if (vibid_cfg_path_of(&c->r, s, "oma.stand", config_setting_get_string(s), o->stand_file, sizeof o->stand_file))
        return -1;
    vibid_stand_error se;
    o->stand = vibid_stand_load(o->stand_file, &se);
    if (!o->stand) {
        *c->r.err = se;
        snprintf(c->r.err->text, sizeof c->r.err->text, "%.1250s (stand file referenced at %.1000s:%d)", se.text,
                 c->r.file, config_setting_source_line(s));
        return -1;
    }
    const vibid_model *m = vibid_stand_model(o->stand);
    vibid_model_dims d;
    vibid_model_get_dims(m, &d);
    for (size_t i = 0; i < d.n_channels; i++) {
        vibid_channel_info ci;
        vibid_model_channel_info(m, i, &ci);
        if (ci.kind == VIBID_CHANNEL_INPUT || ci.index == VIBID_BASE)
            return vibid_cfg_fail(&c->r, s, "oma.stand",
                                  "'%s' measures an input ('%s'): a stand with measured inputs is identified (stand = "
                                  "...;), not tracked output-only",
                                  o->stand_file, vibid_stand_channel_name(o->stand, i));
    }
    return 0;
}

/* The node and quantity of response channel i (model order) in oma.stand, as "m1
 * acceleration"; NULL without oma.stand or where the stand does not measure that channel. */
static const char *oma_node_of(const vd_config *cfg, size_t i, char *buf, size_t cap)
{
    const vibid_stand *st = cfg->oma.stand;
    if (!st)
        return NULL;
    const size_t k = vibid_stand_find_channel(st, cfg->chanmap.ch[cfg->model_to_chan[i]].name);
    vibid_channel_info ci;
    const char *node = NULL;
    if (k == (size_t)-1 || vibid_model_channel_info(vibid_stand_model(st), k, &ci) != VIBID_OK ||
        vibid_model_node_name(vibid_stand_model(st), ci.index, &node) != VIBID_OK)
        return NULL;
    static const char *const q[] = {"displacement", "velocity", "acceleration"};
    snprintf(buf, cap, "%s %s", node, (unsigned)ci.kind < 3 ? q[ci.kind] : "?");
    return buf;
}

const char *vd_param_name(const vd_config *cfg, size_t k)
{
    if (cfg->oma.on)
        return k < cfg->n_params ? cfg->oma.param_name[k] : "?";
    vibid_param_info pi;
    if (vibid_model_param_info(vibid_stand_model(cfg->stand), k, &pi) != VIBID_OK)
        return "?";
    return pi.name; /* points into the model, which the configuration owns */
}

const char *vd_stand_name(const vd_config *cfg)
{
    return cfg->oma.on ? cfg->oma.name : vibid_stand_name(cfg->stand);
}

/* The output-only configuration (config.h vd_oma_config; docs/vibidd.md "Output-only
 * tracking"): everything but its channels, which load_chanmap resolves against the map. */
static int load_oma(vd_cfg_ctx *c, config_setting_t *g)
{
    vd_config *cfg = c->cfg;
    vd_oma_config *o = &cfg->oma;
    if (!config_setting_is_group(g))
        return vibid_cfg_fail(&c->r, g, "oma", "must be a group { sample_rate = ...; modes = ...; }");
    if (vd_cfg_known(c, g, "oma", oma_known))
        return -1;
    o->on = true;
    if (load_oma_stand(c, g))
        return -1;
    if (!o->stand && !config_setting_get_member(g, "sample_rate"))
        return vibid_cfg_fail(&c->r, g, "oma.sample_rate", "missing: the channels' sample rate in Hz");
    if (vd_cfg_name(c, g, "oma", "name", o->stand ? vibid_stand_name(o->stand) : "machine", false, o->name,
                    sizeof o->name) ||
        vd_cfg_double(c, g, "oma", "sample_rate", o->stand ? vibid_stand_sample_rate(o->stand) : 0.0, 1e-3, 1e7,
                      &cfg->sample_rate))
        return -1;
    if (o->stand && fabs(cfg->sample_rate - vibid_stand_sample_rate(o->stand)) > 1e-9 * cfg->sample_rate)
        return vibid_cfg_fail(&c->r, config_setting_get_member(g, "sample_rate"), "oma.sample_rate",
                              "%g Hz, but oma.stand '%s' says %g Hz", cfg->sample_rate, o->stand_file,
                              vibid_stand_sample_rate(o->stand));
    const double fa = cfg->sample_rate;
    /* modes: how many (the lowest of the first identification that finds that many) or their
     * expected frequencies */
    const config_setting_t *m = config_setting_get_member(g, "modes");
    if (!m)
        return vibid_cfg_fail(&c->r, g, "oma.modes",
                              "missing: the number of modes to track (modes = 3;) or their expected frequencies "
                              "in Hz (modes = [12.5, 40.0];)");
    if (config_setting_is_array(m) || config_setting_is_list(m)) {
        const int n = config_setting_length(m);
        if (n < 1 || n > VD_OMA_MAX_MODES)
            return vibid_cfg_fail(&c->r, m, "oma.modes", "%d frequencies: give 1 to %d", n, VD_OMA_MAX_MODES);
        for (int j = 0; j < n; j++) {
            const config_setting_t *e = config_setting_get_elem(m, (unsigned)j);
            const int t = config_setting_type(e);
            const double f = t == CONFIG_TYPE_FLOAT ? config_setting_get_float(e)
                             : t == CONFIG_TYPE_INT  ? (double)config_setting_get_int(e)
                                                     : NAN;
            if (!(f > 0.0 && f < 0.45 * fa))
                return vibid_cfg_fail(&c->r, e, "oma.modes", "[%d]: expected a frequency in (0, %g) Hz (0.45 f_a)",
                                      j, 0.45 * fa);
            if (j && f <= o->nominal_hz[j - 1])
                return vibid_cfg_fail(&c->r, e, "oma.modes", "[%d]: frequencies must increase", j);
            o->nominal_hz[j] = f;
        }
        o->n_modes = (size_t)n;
    } else {
        long long v;
        if (vd_cfg_int(c, g, "oma", "modes", 1, 1, VD_OMA_MAX_MODES, &v))
            return -1;
        o->n_modes = (size_t)v;
    }
    cfg->n_params = 2 * o->n_modes;
    cfg->n_modes = 0; /* the modes are the parameters */
    for (size_t j = 0; j < o->n_modes; j++) {
        const unsigned mode = (unsigned)(j + 1) % 100u; /* <= VD_OMA_MAX_MODES: two digits */
        snprintf(o->param_name[2 * j], sizeof o->param_name[0], "f%u_hz", mode);
        snprintf(o->param_name[2 * j + 1], sizeof o->param_name[0], "zeta%u", mode);
    }
    long long br, mo;
    if (vd_cfg_double(c, g, "oma", "every", 60.0, 1.0 / fa, 86400.0, &o->every_s) ||
        vd_cfg_double(c, g, "oma", "window", fmax(o->every_s, 300.0), o->every_s, 7.0 * 86400.0, &o->window_s) ||
        vd_cfg_int(c, g, "oma", "block_rows", 20, 2, 1024, &br) ||
        vd_cfg_int(c, g, "oma", "max_order", 0, 0, 400, &mo) ||
        vd_cfg_double(c, g, "oma", "max_damping", 0.2, 1e-4, 0.9, &o->max_damping) ||
        vd_cfg_double(c, g, "oma", "match_freq", 0.1, 1e-4, 1.0, &o->match_freq) ||
        vd_cfg_double(c, g, "oma", "match_mac", 0.8, 0.0, 1.0, &o->match_mac) ||
        vd_cfg_double(c, g, "oma", "outlier_threshold", VIBID_OUTLIER_THRESHOLD_DEFAULT, 0.0, 1e6,
                      &cfg->outlier_threshold))
        return -1;
    o->block_rows = (unsigned)br;
    o->max_order = (unsigned)mo;
    if (mo % 2)
        return vibid_cfg_fail(&c->r, config_setting_get_member(g, "max_order"), "oma.max_order",
                              "%lld: model orders are even (0: automatic)", mo);
    if (cfg->outlier_threshold > 0.0 && cfg->outlier_threshold < 2.0)
        return vibid_cfg_fail(&c->r, config_setting_get_member(g, "outlier_threshold"), "oma.outlier_threshold",
                              "%g: use 0 (off) or a value >= 2", cfg->outlier_threshold);
    /* a block long against the correlation time of the response (vibid/oma.h point 4): the
     * window in 32 blocks by default, each at least 4 block_rows samples */
    if (vd_cfg_double(c, g, "oma", "block", o->window_s / 32.0, 4.0 * br / fa, o->window_s / 2.0, &o->block_s))
        return -1;
    if (o->window_s * fa > 2e8)
        return vibid_cfg_fail(&c->r, config_setting_get_member(g, "window"), "oma.window",
                              "%g s are more than 2e8 samples at %g Hz", o->window_s, fa);
    /* what the daemon's settings mean without an estimator: every sample is kept for the
     * identification, no refinement */
    cfg->method = VIBID_ESTIMATOR_AUTO;
    cfg->forgetting = 1.0;
    cfg->decimation = 1;
    cfg->prefilter_hz = -1.0;
    snprintf(cfg->refine_why, sizeof cfg->refine_why, "output-only configuration (oma): no model to refine");
    return 0;
}

/* oma.channels / oma.refs against the channel map (load_oma's rest): the response channels
 * by name (default: every channel that is not a covariate), as the model channels. */
static int resolve_oma_channels(vd_cfg_ctx *c, const config_setting_t *src)
{
    vd_config *cfg = c->cfg;
    vd_oma_config *o = &cfg->oma;
    const config_setting_t *g = config_lookup(src->config, "oma");
    const config_setting_t *ch = config_setting_get_member(g, "channels");
    cfg->n_channels = 0;
    if (!ch && o->stand) { /* the stand's measured channels, in its order */
        vibid_model_dims d;
        vibid_model_get_dims(vibid_stand_model(o->stand), &d);
        for (size_t i = 0; i < d.n_channels; i++) {
            const char *name = vibid_stand_channel_name(o->stand, i);
            size_t k = cfg->chanmap.n;
            for (size_t q = 0; q < cfg->chanmap.n; q++)
                if (!strcmp(cfg->chanmap.ch[q].name, name))
                    k = q;
            if (k == cfg->chanmap.n)
                return vibid_cfg_fail(&c->r, src, "source.channels",
                                      "no channel '%s': oma.stand '%s' measures it (oma.channels may name fewer)",
                                      name, o->stand_file);
            cfg->model_to_chan[cfg->n_channels++] = k;
        }
    } else if (!ch) {
        for (size_t k = 0; k < cfg->chanmap.n; k++)
            if (cfg->chanmap.ch[k].quantity != VIBID_Q_COVARIATE)
                cfg->model_to_chan[cfg->n_channels++] = k;
        if (!cfg->n_channels)
            return vibid_cfg_fail(&c->r, src, "source.channels", "no response channel: every channel is a covariate");
    } else {
        if (!config_setting_is_array(ch) && !config_setting_is_list(ch))
            return vibid_cfg_fail(&c->r, ch, "oma.channels", "must be a list of channel names [\"a1\", \"a2\"]");
        const int n = config_setting_length(ch);
        if (n < 1)
            return vibid_cfg_fail(&c->r, ch, "oma.channels", "empty: name at least one response channel");
        for (int i = 0; i < n; i++) {
            const char *name = config_setting_get_string_elem(ch, i);
            size_t k = cfg->chanmap.n;
            for (size_t q = 0; name && q < cfg->chanmap.n; q++)
                if (!strcmp(cfg->chanmap.ch[q].name, name))
                    k = q;
            if (k == cfg->chanmap.n)
                return vibid_cfg_fail(&c->r, ch, "oma.channels", "[%d]: %s%s%s is not a channel of the channel map",
                                      i, name ? "'" : "", name ? name : "not a string", name ? "'" : "");
            if (cfg->chanmap.ch[k].quantity == VIBID_Q_COVARIATE)
                return vibid_cfg_fail(&c->r, ch, "oma.channels",
                                      "[%d]: '%s' is a covariate (an operating condition), not a response", i, name);
            for (size_t j = 0; j < cfg->n_channels; j++)
                if (cfg->model_to_chan[j] == k)
                    return vibid_cfg_fail(&c->r, ch, "oma.channels", "[%d]: '%s' named twice", i, name);
            cfg->model_to_chan[cfg->n_channels++] = k;
        }
    }
    for (size_t i = 0; i < cfg->n_channels; i++) {
        const vibid_quantity q = cfg->chanmap.ch[cfg->model_to_chan[i]].quantity;
        if (q == VIBID_Q_FORCE || q == VIBID_Q_INPUT)
            return vibid_cfg_fail(&c->r, ch ? ch : src, ch ? "oma.channels" : "source.channels",
                                  "'%s' is a force (an input): output-only identification uses responses; leave it "
                                  "out of oma.channels",
                                  cfg->chanmap.ch[cfg->model_to_chan[i]].name);
        cfg->model_scale[i] = 1.0; /* the channels' own units: the modes do not depend on them */
    }
    const config_setting_t *rf = config_setting_get_member(g, "refs");
    o->n_refs = 0;
    if (rf) {
        if (!config_setting_is_array(rf) && !config_setting_is_list(rf))
            return vibid_cfg_fail(&c->r, rf, "oma.refs", "must be a list of channel names (of oma.channels)");
        const int n = config_setting_length(rf);
        for (int i = 0; i < n; i++) {
            const char *name = config_setting_get_string_elem(rf, i);
            size_t j = cfg->n_channels;
            for (size_t q = 0; name && q < cfg->n_channels; q++)
                if (!strcmp(cfg->chanmap.ch[cfg->model_to_chan[q]].name, name))
                    j = q;
            if (j == cfg->n_channels)
                return vibid_cfg_fail(&c->r, rf, "oma.refs", "[%d]: %s is not one of the response channels", i,
                                      name ? name : "not a string");
            for (size_t q = 0; q < o->n_refs; q++)
                if (o->refs[q] == j)
                    return vibid_cfg_fail(&c->r, rf, "oma.refs", "[%d]: '%s' named twice", i, name);
            o->refs[o->n_refs++] = j;
        }
    }
    return 0;
}

static int load_stand(vd_cfg_ctx *c, config_t *cf)
{
    vd_config *cfg = c->cfg;
    config_setting_t *s = config_lookup(cf, "stand");
    config_setting_t *oma = config_lookup(cf, "oma");
    if (s && oma)
        return vibid_cfg_fail(&c->r, oma, "oma",
                              "give either a stand (identification with measured inputs) or oma (output-only "
                              "tracking of modes), not both");
    if (oma)
        return load_oma(c, oma);
    if (!s)
        return vibid_cfg_fail(
            &c->r, config_root_setting(cf), "stand",
            "missing: give the stand file (stand = \"stand.cfg\";) or the stand group inline (or, for output-only "
            "tracking of modes, an oma group)");
    if (config_setting_type(s) == CONFIG_TYPE_STRING) {
        if (vibid_cfg_path_of(&c->r, s, "stand", config_setting_get_string(s), cfg->stand_file,
                              sizeof cfg->stand_file))
            return -1;
        vibid_stand_error se;
        cfg->stand = vibid_stand_load(cfg->stand_file, &se);
        if (!cfg->stand) {
            /* The loader's error names the stand file's own file:line:field; say where it
             * was referenced from as well. */
            *c->r.err = se;
            /* precisions keep the sum within text's 2304 bytes (a cut path still names the place) */
            snprintf(c->r.err->text, sizeof c->r.err->text, "%.1250s (stand file referenced at %.1000s:%d)",
                     se.text, c->r.file, config_setting_source_line(s));
            return -1;
        }
    } else if (config_setting_is_group(s)) {
        cfg->stand = vibid_stand_from_setting(s, c->r.file, c->r.err);
        if (!cfg->stand) return -1;
    } else {
        return vibid_cfg_fail(&c->r, s, "stand", "must be a file name (string) or a group");
    }
    const vibid_model *m = vibid_stand_model(cfg->stand);
    vibid_model_dims d;
    vibid_model_get_dims(m, &d);
    cfg->sample_rate = vibid_stand_sample_rate(cfg->stand);
    cfg->n_params = d.n_params;
    cfg->n_channels = d.n_channels;
    cfg->n_modes = d.n_dof;
    if (d.n_params == 0)
        return vibid_cfg_fail(&c->r, s, "stand", "the stand has no unknown parameter: nothing to identify");
    if (d.n_params > VD_MAX_PARAMS)
        return vibid_cfg_fail(&c->r, s, "stand", "%zu unknowns, vibidd handles at most %d", d.n_params,
                              VD_MAX_PARAMS);
    if (d.n_channels > VIBID_DRV_MAX_CHANNELS)
        return vibid_cfg_fail(&c->r, s, "stand", "%zu channels, the sources carry at most %d", d.n_channels,
                              VIBID_DRV_MAX_CHANNELS);
    return 0;
}

static const char *const src_kinds[] = {"socketcan", "modbus", "replay", NULL};
static const char *const src_known[] = {
    "kind", "channels", "channel_map", "counter", "trigger", "time_column",
    /* socketcan */ "interface", "dbc", "rcvbuf", "hw_timestamps", "batch",
    /* modbus */ "url", "baud", "parity", "unit_id", "mode", "registers", "register_map", "poll_period",
    "fifo_base", "response_timeout", "backoff_initial", "backoff_max", "max_timeouts",
    /* replay */ "file", "format", "paced", "speed", NULL};

static int parse_url(vd_cfg_ctx *c, const config_setting_t *src)
{
    vd_config *cfg = c->cfg;
    const config_setting_t *s = config_setting_get_member(src, "url");
    const char *u = cfg->url;
    if (strncmp(u, "tcp://", 6) == 0) {
        cfg->transport = VIBID_MODBUS_TCP;
        const char *hp = u + 6;
        const char *colon = strrchr(hp, ':');
        size_t hl = colon ? (size_t)(colon - hp) : strlen(hp);
        if (hl == 0 || hl >= sizeof cfg->host)
            return vibid_cfg_fail(&c->r, s, "source.url", "'%s': no host (tcp://HOST:PORT)", u);
        memcpy(cfg->host, hp, hl);
        cfg->host[hl] = '\0';
        cfg->port = 502;
        if (colon) {
            char *end;
            errno = 0;
            long p = strtol(colon + 1, &end, 10);
            if (*end || p < 1 || p > 65535 || errno)
                return vibid_cfg_fail(&c->r, s, "source.url", "'%s': port '%s' outside 1..65535", u,
                                      colon + 1);
            cfg->port = (int)p;
        }
        return 0;
    }
    if (strncmp(u, "rtu://", 6) == 0) {
        cfg->transport = VIBID_MODBUS_RTU;
        if (u[6] != '/' || strlen(u + 6) >= sizeof cfg->device)
            return vibid_cfg_fail(&c->r, s, "source.url", "'%s': expected rtu:///dev/DEVICE", u);
        snprintf(cfg->device, sizeof cfg->device, "%s", u + 6);
        return 0;
    }
    return vibid_cfg_fail(&c->r, s, "source.url", "'%s': expected tcp://HOST[:PORT] or rtu:///dev/DEVICE", u);
}

static int load_dbc(vd_cfg_ctx *c, const config_setting_t *src)
{
    vd_config *cfg = c->cfg;
    if (vd_cfg_path(c, src, "source", "dbc", cfg->dbc_file, sizeof cfg->dbc_file))
        return -1;
    if (!cfg->dbc_file[0])
        return vibid_cfg_fail(&c->r, src, "source.dbc", "missing: CAN signals need a DBC file");
    vibid_drv_error de = {0};
    cfg->dbc = vibid_dbc_load(cfg->dbc_file, &de);
    if (!cfg->dbc) {
        vibid_cfg_fail(&c->r, config_setting_get_member(src, "dbc"), "source.dbc", "%s", de.text);
        return -1;
    }
    return 0;
}

static int load_chanmap(vd_cfg_ctx *c, const config_setting_t *src)
{
    vd_config *cfg = c->cfg;
    const config_setting_t *inl = config_setting_get_member(src, "channels");
    if (vd_cfg_path(c, src, "source", "channel_map", cfg->chanmap_file, sizeof cfg->chanmap_file))
        return -1;
    if (inl && cfg->chanmap_file[0])
        return vibid_cfg_fail(&c->r, inl, "source.channels",
                              "give either channels (inline) or channel_map (a file), not both");
    vibid_drv_status st;
    if (cfg->chanmap_file[0])
        st = vibid_chanmap_read_file(cfg->chanmap_file, &cfg->chanmap, c->r.err);
    else if (inl)
        st = vibid_chanmap_read(&c->r, src, "source", &cfg->chanmap);
    else
        return vibid_cfg_fail(
            &c->r, src, "source.channels",
            "missing: map the stand's channels to signals/registers/columns (channels = (...); or "
            "channel_map = \"file\";)");
    if (st != VIBID_DRV_OK) return -1;
    /* Embedded counter/trigger/time_column beside an external channel map override it. */
    char tmp[VIBID_CHAN_NAME_LEN];
    const char *const keys[] = {"counter", "trigger", "time_column"};
    char *dst[] = {cfg->chanmap.counter, cfg->chanmap.trigger, cfg->chanmap.time_column};
    for (int i = 0; i < 3; i++) {
        if (!config_setting_get_member(src, keys[i]))
            continue;
        if (vd_cfg_string(c, src, "source", keys[i], "", tmp, sizeof tmp))
            return -1;
        snprintf(dst[i], VIBID_CHAN_NAME_LEN, "%s", tmp);
    }
    /* The covariates: every `covariate` channel of the map, in its order. */
    cfg->n_covariates = 0;
    for (size_t k = 0; k < cfg->chanmap.n; k++) {
        if (cfg->chanmap.ch[k].quantity != VIBID_Q_COVARIATE)
            continue;
        if (cfg->n_covariates == VD_MAX_COVARIATES)
            return vibid_cfg_fail_at(&c->r, cfg->chanmap_file[0] ? cfg->chanmap_file : c->r.file,
                                     (int)cfg->chanmap.ch[k].line, "source.channels",
                                     "covariate '%s': at most %d covariate channels", cfg->chanmap.ch[k].name,
                                     VD_MAX_COVARIATES);
        /* its name heads a column of the tracks: it must not be another column's */
        const char *name = cfg->chanmap.ch[k].name;
        bool clash = !strcmp(name, "time_s") || !strcmp(name, "index") || !strcmp(name, "gap_samples") ||
                     !strcmp(name, "flags");
        for (size_t p = 0; p < cfg->n_params && !clash; p++)
            clash = !strcmp(name, vd_param_name(cfg, p));
        if (clash)
            return vibid_cfg_fail_at(&c->r, cfg->chanmap_file[0] ? cfg->chanmap_file : c->r.file,
                                     (int)cfg->chanmap.ch[k].line, "source.channels",
                                     "covariate '%s' has the name of a column of the tracks (a parameter, time_s, "
                                     "index, gap_samples or flags): rename it",
                                     name);
        cfg->cov_chan[cfg->n_covariates++] = k;
    }
    if (cfg->oma.on)
        return resolve_oma_channels(c, src);
    /* Every model channel must come from the source: map by name. */
    const vibid_model *m = vibid_stand_model(cfg->stand);
    for (size_t i = 0; i < cfg->n_channels; i++) {
        const char *want = vibid_stand_channel_name(cfg->stand, i);
        size_t k;
        for (k = 0; k < cfg->chanmap.n; k++)
            if (strcmp(cfg->chanmap.ch[k].name, want) == 0)
                break;
        if (k == cfg->chanmap.n) {
            vibid_channel_info ci;
            vibid_model_channel_info(m, i, &ci);
            return vibid_cfg_fail(
                &c->r, inl ? inl : src, "source.channels",
                "the stand needs channel '%s' (%s) but the channel map has no channel of that name", want,
                ci.name);
        }
        cfg->model_to_chan[i] = k;
    }
    return 0;
}

/* Dimension of a channel-map quantity; -1 for `input` (its own units, any label). */
static int quantity_dim(vibid_quantity q)
{
    switch (q) {
    case VIBID_Q_DISPLACEMENT:
    case VIBID_Q_BASE_DISPLACEMENT: return VIBID_DIM_LENGTH;
    case VIBID_Q_VELOCITY:
    case VIBID_Q_BASE_VELOCITY: return VIBID_DIM_VELOCITY;
    case VIBID_Q_ACCELERATION:
    case VIBID_Q_BASE_ACCELERATION: return VIBID_DIM_ACCELERATION;
    case VIBID_Q_FORCE: return VIBID_DIM_FORCE;
    case VIBID_Q_INPUT:
    case VIBID_Q_COVARIATE: return -1;
    }
    return -1;
}

/* Factor from channel k's unit to the stand's units, into cfg->chan_scale[k]. The unit is
 * the channel map's `unit`, else the DBC signal's unit, else none (the stand's units, 1).
 * A unit given twice must agree. */
static int channel_scale(vd_cfg_ctx *c, const char *map_file, size_t k)
{
    vd_config *cfg = c->cfg;
    const vibid_channel *ch = &cfg->chanmap.ch[k];
    const vibid_dbc_signal *sig = NULL;
    const vibid_dbc_message *msg = NULL;
    if (ch->source == VIBID_CHAN_SIGNAL && cfg->dbc)
        sig = vibid_dbc_lookup_signal(cfg->dbc, ch->ref, ch->message, &msg, NULL);
    const char *dbc_unit = sig && sig->unit[0] ? sig->unit : NULL;
    const char *unit = ch->unit[0] ? ch->unit : dbc_unit;
    int dim = quantity_dim(ch->quantity);
    cfg->chan_scale[k] = 1.0;
    if (dim < 0 || !unit)
        return 0;
    char f[200];
    snprintf(f, sizeof f, "source.channels.%s.unit", ch->name);
    double si, dbc_si;
    if (vibid_unit_si_factor((vibid_unit_dim)dim, unit, &si)) {
        if (unit == dbc_unit)
            return vibid_cfg_fail_at(
                &c->r, map_file, (int)ch->line, f,
                "channel '%s' (%s) takes the unit '%s' of DBC signal '%s' (%s:%u), which is not a %s "
                "unit (%s): declare the channel's unit, or map a signal of the right quantity",
                ch->name, vibid_quantity_name(ch->quantity), unit, sig->name, cfg->dbc_file, sig->line,
                vibid_unit_dim_name((vibid_unit_dim)dim), vibid_unit_names((vibid_unit_dim)dim));
        return vibid_cfg_fail_at(&c->r, map_file, (int)ch->line, f,
                                 "'%s' is not a %s unit for a %s channel (%s)", unit,
                                 vibid_unit_dim_name((vibid_unit_dim)dim), vibid_quantity_name(ch->quantity),
                                 vibid_unit_names((vibid_unit_dim)dim));
    }
    if (dbc_unit && unit != dbc_unit &&
        (vibid_unit_si_factor((vibid_unit_dim)dim, dbc_unit, &dbc_si) || fabs(dbc_si - si) > 1e-12 * si))
        return vibid_cfg_fail_at(
            &c->r, map_file, (int)ch->line, f,
            "channel '%s' says '%s' but DBC signal '%s' (%s:%u) is in '%s': one of them is wrong", ch->name,
            unit, sig->name, cfg->dbc_file, sig->line, dbc_unit);
    double stand_si = dim == VIBID_DIM_FORCE ? 1.0 : vibid_stand_length_si(cfg->stand);
    cfg->chan_scale[k] = si / stand_si;
    return 0;
}

/* The channel map against the stand: every channel's unit known for its quantity (and
 * converted), and every channel the stand reads declared with the quantity and node the
 * stand gives it. Runs after the source's DBC is loaded (a signal's unit comes from it). */
static int check_channels(vd_cfg_ctx *c)
{
    vd_config *cfg = c->cfg;
    const char *map_file = cfg->chanmap_file[0] ? cfg->chanmap_file : c->r.file;
    /* output-only: the channels' own units (resolve_oma_channels); a stand converts to its own */
    for (size_t k = 0; k < cfg->chanmap.n && !cfg->oma.on; k++)
        if (channel_scale(c, map_file, k))
            return -1;
    for (size_t j = 0; j < cfg->n_covariates; j++) {
        const vibid_channel *ch = &cfg->chanmap.ch[cfg->cov_chan[j]];
        const vibid_dbc_signal *sig = NULL;
        if (ch->source == VIBID_CHAN_SIGNAL && cfg->dbc)
            sig = vibid_dbc_lookup_signal(cfg->dbc, ch->ref, ch->message, NULL, NULL);
        snprintf(cfg->cov_unit[j], sizeof cfg->cov_unit[j], "%s", ch->unit[0] ? ch->unit : sig ? sig->unit : "");
    }
    if (cfg->oma.on)
        return 0;
    const vibid_model *m = vibid_stand_model(cfg->stand);
    for (size_t i = 0; i < cfg->n_channels; i++) {
        const vibid_channel *ch = &cfg->chanmap.ch[cfg->model_to_chan[i]];
        vibid_channel_info ci;
        vibid_model_channel_info(m, i, &ci);
        char f[200], want[160];
        snprintf(f, sizeof f, "source.channels.%s", ch->name);
        bool ok;
        long node = -1;
        if (ci.kind == VIBID_CHANNEL_INPUT) {
            node = vibid_stand_input_node(cfg->stand, ci.index);
            ok = (ch->quantity == VIBID_Q_FORCE || ch->quantity == VIBID_Q_INPUT) && (node < 0 || ch->node == node);
            snprintf(want, sizeof want, "force (or input) on node %ld", node);
            if (node < 0)
                snprintf(want, sizeof want, "force (or input)");
        } else {
            static const vibid_quantity node_q[] = {VIBID_Q_DISPLACEMENT, VIBID_Q_VELOCITY, VIBID_Q_ACCELERATION};
            static const vibid_quantity base_q[] = {VIBID_Q_BASE_DISPLACEMENT, VIBID_Q_BASE_VELOCITY,
                                                    VIBID_Q_BASE_ACCELERATION};
            unsigned kind = (unsigned)ci.kind < 3 ? (unsigned)ci.kind : 0;
            if (ci.index == VIBID_BASE) {
                ok = ch->quantity == base_q[kind];
                snprintf(want, sizeof want, "%s", vibid_quantity_name(base_q[kind]));
            } else {
                node = (long)ci.index;
                ok = ch->quantity == node_q[kind] && ch->node == node;
                snprintf(want, sizeof want, "%s on node %ld", vibid_quantity_name(node_q[kind]), node);
            }
        }
        if (!ok) {
            char have[160];
            if (vibid_quantity_is_base(ch->quantity))
                snprintf(have, sizeof have, "%s", vibid_quantity_name(ch->quantity));
            else
                snprintf(have, sizeof have, "%s on node %d", vibid_quantity_name(ch->quantity), ch->node);
            return vibid_cfg_fail_at(
                &c->r, map_file, (int)ch->line, f,
                "declared as %s, but the stand reads channel '%s' as %s (%s): the channel map and the "
                "stand disagree",
                have, ch->name, ci.name, want);
        }
        cfg->model_scale[i] = cfg->chan_scale[cfg->model_to_chan[i]];
    }
    return 0;
}

static int load_source(vd_cfg_ctx *c, config_t *cf)
{
    vd_config *cfg = c->cfg;
    config_setting_t *src = config_lookup(cf, "source");
    if (!src || !config_setting_is_group(src))
        return vibid_cfg_fail(&c->r, src ? src : config_root_setting(cf), "source",
                              "missing: a group source = { kind = ...; }");
    cfg->source_line = config_setting_source_line(src);
    if (vd_cfg_known(c, src, "source", src_known))
        return -1;
    int kind;
    if (!config_setting_get_member(src, "kind"))
        return vibid_cfg_fail(&c->r, src, "source.kind", "missing: socketcan, modbus or replay");
    if (vd_cfg_enum(c, src, "source", "kind", 0, src_kinds, &kind))
        return -1;
    cfg->source_kind = (vd_source_kind)kind;
    long long v;
    if (load_chanmap(c, src))
        return -1;
    switch (cfg->source_kind) {
    case VD_SRC_SOCKETCAN:
        if (vd_cfg_string(c, src, "source", "interface", "", cfg->iface, 16))
            return -1;
        if (!cfg->iface[0])
            return vibid_cfg_fail(&c->r, src, "source.interface",
                                  "missing: the CAN interface, e.g. \"can0\"");
        if (load_dbc(c, src))
            return -1;
        if (vd_cfg_int(c, src, "source", "rcvbuf", 0, 0, 64LL << 20, &v))
            return -1;
        cfg->rcvbuf_bytes = (int)v;
        if (vd_cfg_bool(c, src, "source", "hw_timestamps", false, &cfg->hw_timestamps))
            return -1;
        if (vd_cfg_int(c, src, "source", "batch", 64, 1, 256, &v))
            return -1;
        cfg->can_batch = (unsigned)v;
        if (!cfg->chanmap.counter[0] && !cfg->chanmap.trigger[0])
            return vibid_cfg_fail(&c->r, src, "source.counter",
                                  "CAN samples need a counter signal or a trigger message");
        break;
    case VD_SRC_MODBUS: {
        if (vd_cfg_string(c, src, "source", "url", "", cfg->url, sizeof cfg->url))
            return -1;
        if (!cfg->url[0])
            return vibid_cfg_fail(&c->r, src, "source.url", "missing: tcp://HOST:PORT or rtu:///dev/DEVICE");
        if (parse_url(c, src))
            return -1;
        if (vd_cfg_int(c, src, "source", "baud", 19200, 1200, 4000000, &v))
            return -1;
        cfg->baud = (int)v;
        static const char *const par[] = {"N", "E", "O", NULL};
        int pi;
        if (vd_cfg_enum(c, src, "source", "parity", 1, par, &pi))
            return -1;
        cfg->parity = par[pi][0];
        if (vd_cfg_int(c, src, "source", "unit_id", 1, 1, 247, &v))
            return -1;
        cfg->unit_id = (int)v;
        static const char *const modes[] = {"fifo", "snapshot", NULL};
        int mi;
        if (vd_cfg_enum(c, src, "source", "mode", 0, modes, &mi))
            return -1;
        cfg->modbus_mode = (vibid_modbus_mode)mi;
        const config_setting_t *inl = config_setting_get_member(src, "registers");
        if (vd_cfg_path(c, src, "source", "register_map", cfg->regmap_file, sizeof cfg->regmap_file)) return -1;
        if (inl && cfg->regmap_file[0])
            return vibid_cfg_fail(&c->r, inl, "source.registers",
                                  "give either registers (inline) or register_map, not both");
        if (cfg->regmap_file[0])
            cfg->regmap = vibid_regmap_read_file(cfg->regmap_file, c->r.err);
        else if (inl)
            cfg->regmap = vibid_regmap_read(&c->r, inl, "source.registers");
        else
            return vibid_cfg_fail(
                &c->r, src, "source.registers",
                "missing: the register map (registers = (...); or register_map = \"file\";)");
        if (!cfg->regmap) return -1;
        for (size_t i = 0; i < cfg->chanmap.n; i++)
            if (cfg->chanmap.ch[i].source != VIBID_CHAN_REGISTER ||
                !vibid_regmap_find(cfg->regmap, cfg->chanmap.ch[i].ref)) {
                char f[64];
                snprintf(f, sizeof f, "source.channels");
                return vibid_cfg_fail(&c->r, src, f,
                                      "channel '%s' (line %u) must name a register of the register map",
                                      cfg->chanmap.ch[i].name, cfg->chanmap.ch[i].line);
            }
        if (vd_cfg_double(c, src, "source", "poll_period", 0.0, 0.0, 10.0, &cfg->poll_period_s) ||
            vd_cfg_int(c, src, "source", "fifo_base", 1000, 0, 65535, &v))
            return -1;
        cfg->fifo_base = (unsigned)v;
        if (vd_cfg_double(c, src, "source", "response_timeout", 0.5, 0.001, 60.0, &cfg->response_timeout_s) ||
            vd_cfg_double(c, src, "source", "backoff_initial", 0.1, 0.001, 60.0, &cfg->backoff_initial_s) ||
            vd_cfg_double(c, src, "source", "backoff_max", 5.0, 0.001, 3600.0, &cfg->backoff_max_s) ||
            vd_cfg_int(c, src, "source", "max_timeouts", 3, 1, 1000, &v))
            return -1;
        cfg->max_timeouts = (unsigned)v;
        if (cfg->backoff_max_s < cfg->backoff_initial_s)
            return vibid_cfg_fail(&c->r, config_setting_get_member(src, "backoff_max"), "source.backoff_max",
                                  "%g s is below backoff_initial %g s", cfg->backoff_max_s,
                                  cfg->backoff_initial_s);
        break;
    }
    case VD_SRC_REPLAY: {
        if (vd_cfg_path(c, src, "source", "file", cfg->replay_file, sizeof cfg->replay_file))
            return -1;
        if (!cfg->replay_file[0])
            return vibid_cfg_fail(&c->r, src, "source.file",
                                  "missing: the capture file (candump .log or .csv)");
        static const char *const fmts[] = {"auto", "candump", "csv", NULL};
        int fi;
        if (vd_cfg_enum(c, src, "source", "format", 0, fmts, &fi))
            return -1;
        cfg->replay_format = fi;
        if (vd_cfg_bool(c, src, "source", "paced", false, &cfg->paced) ||
            vd_cfg_double(c, src, "source", "speed", 1.0, 1e-3, 1e6, &cfg->speed))
            return -1;
        char why[512];
        const vibid_replay_format resolved =
            vibid_replay_format_resolve((vibid_replay_format)fi, cfg->replay_file, why, sizeof why);
        if (resolved == VIBID_REPLAY_AUTO)
            return vibid_cfg_fail(&c->r, config_setting_get_member(src, "file"), "source.file", "%s", why);
        if (resolved == VIBID_REPLAY_CANDUMP) {
            if (load_dbc(c, src))
                return -1;
        } else if (config_setting_get_member(src, "dbc")) {
            if (load_dbc(c, src)) /* allowed: lets --replay read a candump capture too */
                return -1;
        }
        break;
    }
    }
    return check_channels(c);
}

static const char *const acq_known[] = {"ring_size",   "read_batch",   "read_timeout", "realtime_priority",
                                        "lock_memory", "handoff_spin", NULL};
static const char *const est_known[] = {"method",         "forgetting",       "prefilter_hz", "rls_alpha",
                                        "iv_lag",         "difference_order", "decimation",   "warmup_samples",
                                        "start_values",   "outlier_threshold", "refine_every", "refine_window", NULL};
static const char *const alarm_known[] = {"enabled",       "test",           "false_alarms_per_year",
                                          "horizon",       "detection_probability",
                                          "threshold",     "min_relative",   "hold",
                                          "learn_start",   "learn_duration", "parameters",
                                          "reference_file", NULL};
static const char *const log_known[] = {"level", "status_interval", NULL};
static const char *const top_known[] = {"stand",  "oma",    "source", "acquisition", "estimator",
                                        "outputs", "alarms", "log",    NULL};

static int load_acquisition(vd_cfg_ctx *c, config_t *cf)
{
    vd_config *cfg = c->cfg;
    config_setting_t *g = config_lookup(cf, "acquisition");
    if (vd_cfg_known(c, g, "acquisition", acq_known))
        return -1;
    long long v;
    if (vd_cfg_int(c, g, "acquisition", "ring_size", 65536, 16, 1LL << 20, &v))
        return -1;
    if ((v & (v - 1)) != 0)
        return vibid_cfg_fail(&c->r, config_setting_get_member(g, "ring_size"), "acquisition.ring_size",
                              "%lld is not a power of two", v);
    cfg->ring_size = (unsigned)v;
    if (vd_cfg_int(c, g, "acquisition", "read_batch", 64, 1, 1024, &v))
        return -1;
    cfg->read_batch = (unsigned)v;
    if (vd_cfg_int(c, g, "acquisition", "read_timeout", 100, 1, 10000, &v))
        return -1;
    cfg->read_timeout_ms = (int)v;
    if (vd_cfg_int(c, g, "acquisition", "realtime_priority", 0, 0, 99, &v))
        return -1;
    cfg->rt_priority = (int)v;
    if (vd_cfg_int(c, g, "acquisition", "handoff_spin", 0, 0, 10000, &v))
        return -1;
    cfg->handoff_spin_us = (unsigned)v;
    return vd_cfg_bool(c, g, "acquisition", "lock_memory", false, &cfg->lock_memory);
}

/* Index of the stand's unknown named name, or n_params if there is none. */
static size_t param_index(const vd_config *cfg, const char *name)
{
    for (size_t k = 0; k < cfg->n_params; k++)
        if (strcmp(vd_param_name(cfg, k), name) == 0)
            return k;
    return cfg->n_params;
}

/* estimator.start_values = ( { name = "c1"; value = 2.5e5; }, ... ): RLS start values
 * (vibid_ident_set_prior); unlisted parameters start at the stand's nominal value. */
static int load_start_values(vd_cfg_ctx *c, const config_setting_t *sv)
{
    vd_config *cfg = c->cfg;
    if (!sv)
        return 0;
    if (cfg->method != VIBID_ESTIMATOR_RLS && cfg->method != VIBID_ESTIMATOR_EKF &&
        cfg->method != VIBID_ESTIMATOR_KF_RLS)
        return vibid_cfg_fail(&c->r, sv, "estimator.start_values",
                              "only the rls, ekf and kf_rls methods have start values (method is %s)",
                              vd_estimator_name(cfg->method));
    if (!config_setting_is_list(sv))
        return vibid_cfg_fail(&c->r, sv, "estimator.start_values",
                              "must be a list ( { name = \"c1\"; value = ...; }, ... )");
    if (vibid_model_nominal(vibid_stand_model(cfg->stand), cfg->start_theta) != VIBID_OK)
        return vibid_cfg_fail(&c->r, sv, "estimator.start_values", "the stand's nominal values: %s",
                              vibid_last_error());
    int n = config_setting_length(sv);
    for (int i = 0; i < n; i++) {
        const config_setting_t *e = config_setting_get_elem(sv, (unsigned)i);
        char sec[64], f[96];
        snprintf(sec, sizeof sec, "estimator.start_values.[%d]", i);
        static const char *const sk[] = {"name", "value", NULL};
        if (!config_setting_is_group(e))
            return vibid_cfg_fail(&c->r, e, sec, "must be a group { name = \"...\"; value = ...; }");
        char name[64];
        if (vd_cfg_known(c, e, sec, sk) || vd_cfg_name(c, e, sec, "name", "", false, name, sizeof name))
            return -1;
        size_t k = param_index(cfg, name);
        snprintf(f, sizeof f, "%s.name", sec);
        if (k == cfg->n_params)
            return vibid_cfg_fail(&c->r, e, f, "'%s' is not an unknown parameter of the stand", name);
        snprintf(f, sizeof f, "%s.value", sec);
        if (!config_setting_get_member(e, "value")) return vibid_cfg_fail(&c->r, e, f, "missing");
        if (vd_cfg_double(c, e, sec, "value", 0.0, -1e300, 1e300, &cfg->start_theta[k]))
            return -1;
    }
    cfg->has_start = true;
    return 0;
}

/* Whether the output-error fit (output_error.h) can refine this stand's estimates: NULL, or
 * why not (written to why). It refuses an unmeasured base displacement, or a disturbance
 * beside a cubic spring or a base, at create; the KF+RLS and OE methods, and the EKF on a
 * stand without disturbance, are not estimates a refinement starts from. A stand with a
 * disturbance is refined by the prediction-error fit, from the EKF's estimate. */
static const char *refine_refusal(const vd_config *cfg, char *why, size_t cap)
{
    vibid_model_dims dims;
    const bool disturbed = vibid_model_get_dims(vibid_stand_model(cfg->stand), &dims) == VIBID_OK && dims.n_disturbances;
    /* a stand with a disturbance: the prediction-error fit, from the EKF's estimate */
    if (disturbed && cfg->method == VIBID_ESTIMATOR_EKF) {
    } else if (cfg->method != VIBID_ESTIMATOR_LS && cfg->method != VIBID_ESTIMATOR_IV &&
               cfg->method != VIBID_ESTIMATOR_RLS && cfg->method != VIBID_ESTIMATOR_AUTO) {
        snprintf(why, cap, "estimator.method \"%s\" is not an equation-error estimator (ls, iv, rls or auto)",
                 vd_estimator_name(cfg->method));
        return why;
    }
    vibid_oe_config oc;
    vibid_oe_config_init(&oc, 1.0 / cfg->sample_rate);
    vibid_oe *oe = vibid_oe_create(vibid_stand_model(cfg->stand), &oc);
    if (!oe) {
        snprintf(why, cap, "the output-error fit refuses the stand: %s", vibid_last_error());
        return why;
    }
    vibid_oe_destroy(oe);
    return NULL;
}

/* estimator.refine_every / refine_window (docs/vibidd.md "Refinement"). */
static int load_refine(vd_cfg_ctx *c, config_setting_t *g)
{
    vd_config *cfg = c->cfg;
    const double fa = cfg->sample_rate;
    const char *no = refine_refusal(cfg, cfg->refine_why, sizeof cfg->refine_why);
    const config_setting_t *every = g ? config_setting_get_member(g, "refine_every") : NULL;
    cfg->refine_explicit = every != NULL;
    if (vd_cfg_double(c, g, "estimator", "refine_every", no ? 0.0 : 10.0, 0.0, 86400.0, &cfg->refine_every_s))
        return -1;
    if (cfg->refine_every_s > 0 && no)
        return vibid_cfg_fail(&c->r, every, "estimator.refine_every", "%g s: no refinement possible: %s",
                              cfg->refine_every_s, no);
    /* the forgetting memory h / (1 - gamma): the window covers what the recursive estimate
     * still remembers, at least 10 s */
    double memory = cfg->forgetting < 1.0 ? 1.0 / (fa * (1.0 - cfg->forgetting)) : 0.0;
    double min_window = 8.0 * 50.0 / fa; /* the fit's least: 8 blocks of 50 samples */
    if (vd_cfg_double(c, g, "estimator", "refine_window", fmax(10.0, 3.0 * memory), min_window, 86400.0,
                   &cfg->refine_window_s))
        return -1;
    if (cfg->refine_every_s > 0 && cfg->refine_every_s * fa < 1.0)
        return vibid_cfg_fail(&c->r, every, "estimator.refine_every", "%g s is shorter than one sample",
                              cfg->refine_every_s);
    if (cfg->refine_every_s > 0 && (cfg->refine_window_s + 2.0 * cfg->refine_every_s) * fa > 5e7)
        return vibid_cfg_fail(&c->r, every, "estimator.refine_window",
                              "window + 2 x refine_every = %g s are more than 5e7 samples at %g Hz",
                              cfg->refine_window_s + 2.0 * cfg->refine_every_s, fa);
    if (cfg->refine_every_s > 0)
        /* the same whether given or defaulted: the printout reads back to the same text */
        snprintf(cfg->refine_why, sizeof cfg->refine_why, "the output-error fit accepts the stand and the method");
    else if (!no)
        snprintf(cfg->refine_why, sizeof cfg->refine_why, "estimator.refine_every = 0");
    return 0;
}

static int load_estimator(vd_cfg_ctx *c, config_t *cf)
{
    vd_config *cfg = c->cfg;
    config_setting_t *g = config_lookup(cf, "estimator");
    if (cfg->oma.on) /* load_oma set what the daemon needs */
        return g ? vibid_cfg_fail(&c->r, g, "estimator",
                                  "an output-only configuration (oma) has no estimator: its settings are in oma")
                 : 0;
    if (vd_cfg_known(c, g, "estimator", est_known))
        return -1;
    /* The library's names (identify.h), indexed by vibid_estimator, up to the output-error
     * estimator (the last), which vibidd does not run: its push keeps every sample. */
    const char *methods[VIBID_ESTIMATOR_OE + 1];
    for (int k = 0; k < (int)VIBID_ESTIMATOR_OE; k++)
        methods[k] = vibid_estimator_name((vibid_estimator)k);
    methods[VIBID_ESTIMATOR_OE] = NULL;
    int mi;
    if (vd_cfg_enum(c, g, "estimator", "method", (int)VIBID_ESTIMATOR_AUTO, methods, &mi))
        return -1;
    cfg->method = (vibid_estimator)mi;
    double fa = cfg->sample_rate;
    long long v;
    /* Absent prefilter_hz, iv_lag, difference_order: the library chooses (identify.h);
     * a given value overrides the choice. */
    if (vd_cfg_double(c, g, "estimator", "forgetting", 1.0, 0.9, 1.0, &cfg->forgetting) ||
        vd_cfg_double(c, g, "estimator", "prefilter_hz", -1.0, 0.0, 0.45 * fa, &cfg->prefilter_hz) ||
        vd_cfg_double(c, g, "estimator", "rls_alpha", 0.0 /* automatic */, 1e-30, 1e30, &cfg->rls_alpha) ||
        vd_cfg_int(c, g, "estimator", "iv_lag", 0, 3, 4096, &v))
        return -1;
    cfg->iv_lag = (unsigned)v;
    if (vd_cfg_int(c, g, "estimator", "difference_order", 0, 2, 4, &v))
        return -1;
    if (v == 3)
        return vibid_cfg_fail(&c->r, config_setting_get_member(g, "difference_order"),
                              "estimator.difference_order",
                              "3: use 2 (central differences (1.17)) or 4 (five-point stencils)");
    cfg->difference_order = (unsigned)v;
    if (cfg->prefilter_hz > 0 && cfg->prefilter_hz < 1e-3 * fa)
        return vibid_cfg_fail(&c->r, config_setting_get_member(g, "prefilter_hz"), "estimator.prefilter_hz",
                              "%g Hz is below f_a / 1000 = %g Hz (0 turns the pre-filter off)",
                              cfg->prefilter_hz, 1e-3 * fa);
    if (vd_cfg_int(c, g, "estimator", "decimation", (long long)fmax(1.0, round(fa / 10.0)), 1, 10000000, &v))
        return -1;
    cfg->decimation = (unsigned)v;
    if (vd_cfg_int(c, g, "estimator", "warmup_samples", 0, 0, 1000000000, &v))
        return -1;
    cfg->warmup_samples = (unsigned)v;
    /* single-sample glitches taken out before the estimator (vibid/outlier.h); 0 = off */
    if (vd_cfg_double(c, g, "estimator", "outlier_threshold", VIBID_OUTLIER_THRESHOLD_DEFAULT, 0.0, 1e6,
                   &cfg->outlier_threshold))
        return -1;
    if (cfg->outlier_threshold > 0.0 && cfg->outlier_threshold < 2.0)
        return vibid_cfg_fail(&c->r, config_setting_get_member(g, "outlier_threshold"),
                              "estimator.outlier_threshold", "%g: use 0 (off) or a value >= 2",
                              cfg->outlier_threshold);
    if (load_start_values(c, g ? config_setting_get_member(g, "start_values") : NULL))
        return -1;
    return load_refine(c, g);
}

int vd_check_readable_file(const char *setting, const char *path, char *err, size_t cap)
{
    if (!path[0])
        return 0;
    FILE *f = fopen(path, "re");
    if (!f) {
        snprintf(err, cap, "%s %s: %s", setting, path, strerror(errno));
        return -1;
    }
    fclose(f);
    return 0;
}

int vd_read_secret_file(const char *setting, const char *path, char *out, size_t cap, char *err, size_t ecap)
{
    FILE *f = fopen(path, "re");
    if (!f) {
        snprintf(err, ecap, "%s %s: %s", setting, path, strerror(errno));
        return -1;
    }
    struct stat st;
    if (fstat(fileno(f), &st) == 0 && (st.st_mode & S_IROTH))
        vd_warning("%s %s is readable by every user (chmod 0600 or 0640)", setting, path);
    size_t n = fread(out, 1, cap - 1, f);
    bool more = fgetc(f) != EOF;
    fclose(f);
    out[n] = '\0';
    if (more) {
        memset(out, 0, cap);
        snprintf(err, ecap, "%s %s: longer than %zu bytes", setting, path, cap - 2);
        return -1;
    }
    char *nl = strpbrk(out, "\r\n"); /* the first line is the secret */
    if (nl)
        *nl = '\0';
    if (!out[0]) {
        snprintf(err, ecap, "%s %s: empty (the first line is the secret)", setting, path);
        return -1;
    }
    return 0;
}

/* outputs: each output of the registry reads its own groups (output.h); the group's keys are
 * the outputs' top-level groups. */
static int load_outputs(vd_cfg_ctx *c, config_t *cf)
{
    const config_setting_t *g = config_lookup(cf, "outputs");
    const char *known[32];
    size_t n = 0;
    for (size_t i = 0; i < vd_n_outputs; i++)
        for (const char *const *gr = vd_outputs[i]->groups; gr && *gr && n + 1 < 32; gr++)
            if (!strchr(*gr, '.'))
                known[n++] = *gr;
    known[n] = NULL;
    if (vd_cfg_known(c, g, "outputs", known))
        return -1;
    for (size_t i = 0; i < vd_n_outputs; i++)
        if (vd_outputs[i]->load && vd_outputs[i]->load(c, g))
            return -1;
    return 0;
}

static int load_alarms(vd_cfg_ctx *c, config_t *cf)
{
    vd_config *cfg = c->cfg;
    config_setting_t *g = config_lookup(cf, "alarms");
    if (vd_cfg_known(c, g, "alarms", alarm_known))
        return -1;
    static const char *const tests[] = {"cusum", "threshold", NULL};
    int test;
    if (vd_cfg_bool(c, g, "alarms", "enabled", g != NULL, &cfg->alarms_enabled) ||
        vd_cfg_enum(c, g, "alarms", "test", (int)VD_ALARM_CUSUM, tests, &test))
        return -1;
    cfg->alarm_test = (vd_alarm_test)test;
    /* the settings of the other test are errors, not silently ignored */
    static const char *const cusum_only[] = {"false_alarms_per_year", "horizon", "detection_probability",
                                             "reference_file", NULL};
    static const char *const threshold_only[] = {"threshold", "hold", NULL};
    const char *const *wrong = test == VD_ALARM_CUSUM ? threshold_only : cusum_only;
    for (size_t i = 0; g && wrong[i]; i++) {
        const config_setting_t *w = config_setting_get_member(g, wrong[i]);
        if (w) {
            char f[64];
            snprintf(f, sizeof f, "alarms.%s", wrong[i]);
            return vibid_cfg_fail(&c->r, w, f, "belongs to test = \"%s\", and this file's test is \"%s\"%s",
                                  test == VD_ALARM_CUSUM ? "threshold" : "cusum", tests[test],
                                  config_setting_get_member(g, "test") ? "" : " (the default)");
        }
    }
    if (vd_cfg_double(c, g, "alarms", "false_alarms_per_year", VIBID_CHANGE_ALARMS_PER_YEAR_DEFAULT, 1e-6, 1e9,
                   &cfg->alarm_false_per_year) ||
        vd_cfg_double(c, g, "alarms", "horizon", VIBID_CHANGE_HORIZON_DEFAULT, 0.001, 1e9, &cfg->alarm_horizon_s) ||
        vd_cfg_double(c, g, "alarms", "detection_probability", VIBID_CHANGE_DETECTION_DEFAULT, 0.5, 0.999,
                   &cfg->alarm_detection_probability) ||
        vd_cfg_double(c, g, "alarms", "threshold", 5.0, 0.1, 1e6, &cfg->alarm_threshold) ||
        vd_cfg_double(c, g, "alarms", "min_relative", test == VD_ALARM_CUSUM ? 0.0 : 0.02, 0.0, 10.0,
                   &cfg->alarm_min_relative) ||
        vd_cfg_double(c, g, "alarms", "hold", 2.0, 0.0, 86400.0, &cfg->alarm_hold_s) ||
        vd_cfg_double(c, g, "alarms", "learn_start", 5.0, 0.0, 1e9, &cfg->learn_start_s) ||
        vd_cfg_double(c, g, "alarms", "learn_duration", 10.0, 0.001, 1e9, &cfg->learn_duration_s) ||
        vd_cfg_path(c, g, "alarms", "reference_file", cfg->alarm_reference_file, sizeof cfg->alarm_reference_file))
        return -1;
    /* under systemd (StateDirectory=, which sets STATE_DIRECTORY) the reference is kept there
       by default; the first directory of a list */
    const char *state = getenv("STATE_DIRECTORY");
    if (!cfg->alarm_reference_file[0] && state && state[0] == '/' && test == VD_ALARM_CUSUM) {
        size_t n = strcspn(state, ":");
        char stand[64];
        snprintf(stand, sizeof stand, "%s", vd_stand_name(cfg));
        for (char *p = stand; *p; p++) /* a file name whatever the stand is called */
            if (!(isalnum((unsigned char)*p) || *p == '_' || *p == '-' || *p == '.'))
                *p = '_';
        if (n + strlen(stand) + 32 < sizeof cfg->alarm_reference_file)
            snprintf(cfg->alarm_reference_file, sizeof cfg->alarm_reference_file, "%.*s/%s.alarm-reference",
                     (int)n, state, stand);
    }
    const config_setting_t *plist = g ? config_setting_get_member(g, "parameters") : NULL;
    for (size_t k = 0; k < cfg->n_params; k++) {
        snprintf(cfg->alarm_param[k].name, sizeof cfg->alarm_param[k].name, "%s", vd_param_name(cfg, k));
        cfg->alarm_param[k].enabled = plist == NULL; /* no list: every parameter */
    }
    if (!plist)
        return 0;
    if (!config_setting_is_list(plist))
        return vibid_cfg_fail(&c->r, plist, "alarms.parameters",
                              "must be a list ( { name = \"c1\"; baseline = ...; }, ... )");
    int n = config_setting_length(plist);
    for (int i = 0; i < n; i++) {
        const config_setting_t *e = config_setting_get_elem(plist, (unsigned)i);
        char sec[64];
        snprintf(sec, sizeof sec, "alarms.parameters.[%d]", i);
        static const char *const pk[] = {"name", "baseline", NULL};
        if (!config_setting_is_group(e))
            return vibid_cfg_fail(&c->r, e, sec, "must be a group { name = \"...\"; }");
        if (vd_cfg_known(c, e, sec, pk))
            return -1;
        char name[64];
        if (vd_cfg_name(c, e, sec, "name", "", false, name, sizeof name))
            return -1;
        size_t k = param_index(cfg, name);
        if (k == cfg->n_params) {
            char f[96];
            snprintf(f, sizeof f, "%s.name", sec);
            return vibid_cfg_fail(&c->r, e, f, "'%s' is not %s", name,
                                  cfg->oma.on ? "a tracked mode's f<j>_hz or zeta<j>" : "an unknown parameter of the stand");
        }
        cfg->alarm_param[k].enabled = true;
        if (config_setting_get_member(e, "baseline")) {
            if (vd_cfg_double(c, e, sec, "baseline", 0.0, -1e300, 1e300, &cfg->alarm_param[k].baseline))
                return -1;
            cfg->alarm_param[k].has_baseline = true;
        }
    }
    return 0;
}

static int load_log(vd_cfg_ctx *c, config_t *cf)
{
    vd_config *cfg = c->cfg;
    config_setting_t *g = config_lookup(cf, "log");
    if (vd_cfg_known(c, g, "log", log_known))
        return -1;
    static const char *const lv[] = {"error", "warning", "notice", "info", "debug", NULL};
    int li;
    if (vd_cfg_enum(c, g, "log", "level", 3, lv, &li))
        return -1;
    cfg->log_level = VD_LOG_ERROR + li;
    return vd_cfg_double(c, g, "log", "status_interval", 0.0, 0.0, 86400.0, &cfg->log_status_interval_s);
}

void vd_path_dir(const char *path, char *dir, size_t n)
{
    const char *slash = strrchr(path, '/');
    if (slash)
        snprintf(dir, n, "%.*s", slash == path ? 1 : (int)(slash - path), path);
    else
        snprintf(dir, n, ".");
}

int vd_config_load(const char *path, vd_config *cfg, vd_config_error *err)
{
    memset(cfg, 0, sizeof *cfg);
    memset(err, 0, sizeof *err);
    vd_cfg_ctx c = {{path, err}, cfg};
    snprintf(cfg->path, sizeof cfg->path, "%s", path);
    vd_path_dir(path, cfg->dir, sizeof cfg->dir);
    config_t cf;
    if (vibid_cfg_read_file(&cf, path, err)) {
        config_destroy(&cf);
        return -1;
    }
    int rc = vd_cfg_known(&c, config_root_setting(&cf), "", top_known);
    if (!rc)
        rc = load_stand(&c, &cf);
    if (!rc)
        rc = load_source(&c, &cf);
    if (!rc)
        rc = load_acquisition(&c, &cf);
    if (!rc)
        rc = load_estimator(&c, &cf);
    if (!rc)
        rc = load_outputs(&c, &cf);
    if (!rc)
        rc = load_alarms(&c, &cf);
    if (!rc)
        rc = load_log(&c, &cf);
    config_destroy(&cf);
    if (rc)
        vd_config_free(cfg);
    return rc;
}

void vd_config_free(vd_config *cfg)
{
    vibid_stand_destroy(cfg->stand);
    cfg->stand = NULL;
    vibid_stand_destroy(cfg->oma.stand);
    cfg->oma.stand = NULL;
    vibid_dbc_destroy(cfg->dbc);
    cfg->dbc = NULL;
    vibid_regmap_destroy(cfg->regmap);
    cfg->regmap = NULL;
}

/* Identity of a path for vd_config_check_paths: device and inode when it exists, else
 * the canonical directory plus the name. 0 on success. */
typedef struct {
    bool exists;
    dev_t dev;
    ino_t ino;
    char canon[PATH_MAX + VD_PATH_MAX];
} path_id;

static int path_identity(const char *path, path_id *id)
{
    struct stat st;
    memset(id, 0, sizeof *id);
    if (stat(path, &st) == 0) {
        id->exists = true;
        id->dev = st.st_dev;
        id->ino = st.st_ino;
        return 0;
    }
    char dir[PATH_MAX], real[PATH_MAX];
    const char *slash = strrchr(path, '/');
    vd_path_dir(path, dir, sizeof dir);
    if (!realpath(dir, real)) return -1; /* a missing directory: the writers report it */
    snprintf(id->canon, sizeof id->canon, "%s/%s", real, slash ? slash + 1 : path);
    return 0;
}

static bool same_file(const path_id *a, const path_id *b)
{
    if (a->exists != b->exists) return false;
    return a->exists ? a->dev == b->dev && a->ino == b->ino : strcmp(a->canon, b->canon) == 0;
}

/* The path of output part name when outputs selects it (NULL: all), else "". */
static const char *selected_path(const char *const *outputs, const char *name, const char *path)
{
    if (!outputs)
        return path;
    for (const char *const *o = outputs; *o; o++)
        if (!strcmp(*o, name) || !strcmp(*o, "files"))
            return path;
    return "";
}

int vd_config_check_paths(const vd_config *cfg, const char *replay, char *msg, size_t n)
{
    return vd_config_check_paths_for(cfg, replay, NULL, msg, n);
}

int vd_config_check_paths_for(const vd_config *cfg, const char *replay, const char *const *outputs, char *msg,
                              size_t n)
{
    struct named {
        const char *what, *path;
        bool output;
    } f[] = {
        {"outputs.tracks.path", selected_path(outputs, "tracks", cfg->files.tracks_path), true},
        {"outputs.influx.path", selected_path(outputs, "influx", cfg->files.influx_path), true},
        {"outputs.record.path", selected_path(outputs, "record", cfg->files.record_path), true},
        {"outputs.status.path", selected_path(outputs, "status", cfg->files.status_path), true},
        {"the configuration file", cfg->path, false},       {"stand", cfg->stand_file, false},
        {"source.dbc", cfg->dbc_file, false},               {"source.channel_map", cfg->chanmap_file, false},
        {"source.register_map", cfg->regmap_file, false},
        {replay ? "the replayed capture (--replay)" : "source.file", replay ? replay : cfg->replay_file, false},
    };
    const size_t nf = sizeof f / sizeof f[0];
    path_id id[sizeof f / sizeof f[0]];
    bool ok[sizeof f / sizeof f[0]];
    for (size_t i = 0; i < nf; i++) ok[i] = f[i].path && f[i].path[0] && path_identity(f[i].path, &id[i]) == 0;
    for (size_t i = 0; i < nf; i++) {
        if (!ok[i] || !f[i].output) continue;
        for (size_t j = 0; j < nf; j++) {
            if (j == i || !ok[j] || (f[j].output && j < i) || !same_file(&id[i], &id[j])) continue;
            snprintf(msg, n, "%s (%s) and %s (%s) are the same file: %s", f[i].what, f[i].path, f[j].what, f[j].path,
                     f[j].output ? "one output would overwrite the other" : "writing it would destroy an input");
            return -1;
        }
    }
    return 0;
}

const char *vd_source_kind_name(vd_source_kind k) { return (unsigned)k < 3 ? src_kinds[k] : "?"; }

const char *vd_estimator_name(vibid_estimator e)
{
    const char *n = vibid_estimator_name(e);
    return n ? n : "?";
}

const char *vd_cfg_yes(bool b) { return b ? "true" : "false"; }

/* Shortest of %.15g / %.17g that reads back to the same double, as a libconfig float
 * (always with a '.' or exponent, so that it stays a float when read back). */
const char *vd_cfg_num(double v)
{
    static char bufs[16][40];
    static unsigned next;
    char *b = bufs[next++ % 16];
    snprintf(b, 40, "%.15g", v);
    if (strtod(b, NULL) != v)
        snprintf(b, 40, "%.17g", v);
    if (!strpbrk(b, ".eEn"))
        strncat(b, ".0", 39 - strlen(b));
    return b;
}

/* A string as the inside of a libconfig string literal (quote and backslash escaped). */
const char *vd_cfg_esc(const char *v)
{
    static char bufs[12][2 * VD_PATH_MAX + 2];
    static unsigned next;
    char *b = bufs[next++ % 12];
    size_t o = 0;
    for (; *v && o + 2 < sizeof bufs[0]; v++) {
        if (*v == '"' || *v == '\\')
            b[o++] = '\\';
        b[o++] = *v;
    }
    b[o] = '\0';
    return b;
}

/* The estimator group of a stand's configuration (vd_config_print). */
static void print_estimator(const vd_config *cfg, FILE *o)
{
    fprintf(o, "estimator = {\n  method = \"%s\";\n  forgetting = %s;\n", vd_estimator_name(cfg->method),
            vd_cfg_num(cfg->forgetting));
    if (cfg->prefilter_hz >= 0.0)
        fprintf(o, "  prefilter_hz = %s;\n", vd_cfg_num(cfg->prefilter_hz));
    else
        fprintf(o, "  # prefilter_hz: automatic\n");
    if (cfg->rls_alpha > 0.0)
        fprintf(o, "  rls_alpha = %s;\n", vd_cfg_num(cfg->rls_alpha));
    else
        fprintf(o, "  # rls_alpha: automatic\n");
    if (cfg->iv_lag)
        fprintf(o, "  iv_lag = %u;\n", cfg->iv_lag);
    else
        fprintf(o, "  # iv_lag: automatic\n");
    if (cfg->difference_order)
        fprintf(o, "  difference_order = %u;\n", cfg->difference_order);
    else
        fprintf(o, "  # difference_order: automatic\n");
    fprintf(o, "  decimation = %u;\n  warmup_samples = %u;\n", cfg->decimation, cfg->warmup_samples);
    fprintf(o, "  outlier_threshold = %s;  # 0 = off\n", vd_cfg_num(cfg->outlier_threshold));
    fprintf(o, "  refine_every = %s;  # s, 0 = off (refinement %s: %s)\n  refine_window = %s;  # s\n",
            vd_cfg_num(cfg->refine_every_s), cfg->refine_every_s > 0 ? "on" : "off", cfg->refine_why,
            vd_cfg_num(cfg->refine_window_s));
    if (cfg->has_start) {
        fprintf(o, "  start_values = (");
        for (size_t k = 0; k < cfg->n_params; k++) {
            fprintf(o, "%s\n    { name = \"%s\"; value = %s; }", k ? "," : "", vd_param_name(cfg, k),
                    vd_cfg_num(cfg->start_theta[k]));
        }
        fprintf(o, "\n  );\n");
    }
    fprintf(o, "};\n");
}

/* The oma group of an output-only configuration (vd_config_print), with its channels. */
static void print_oma(const vd_config *cfg, FILE *o)
{
    const vd_oma_config *a = &cfg->oma;
    fprintf(o, "oma = {\n  name = \"%s\";\n  sample_rate = %s;  # Hz\n", vd_cfg_esc(a->name),
            vd_cfg_num(cfg->sample_rate));
    if (a->stand)
        fprintf(o, "  stand = \"%s\";  # names the nodes\n", vd_cfg_esc(a->stand_file));
    if (a->nominal_hz[0] > 0.0) {
        fprintf(o, "  modes = [");
        for (size_t j = 0; j < a->n_modes; j++)
            fprintf(o, "%s%s", j ? ", " : "", vd_cfg_num(a->nominal_hz[j]));
        fprintf(o, "];  # Hz, expected\n");
    } else {
        fprintf(o, "  modes = %zu;  # the lowest of the first identification that finds as many\n", a->n_modes);
    }
    fprintf(o, "  channels = [");
    for (size_t i = 0; i < cfg->n_channels; i++)
        fprintf(o, "%s\"%s\"", i ? ", " : "", cfg->chanmap.ch[cfg->model_to_chan[i]].name);
    fprintf(o, "];\n");
    char node[160];
    for (size_t i = 0; i < cfg->n_channels && a->stand; i++) {
        const char *at = oma_node_of(cfg, i, node, sizeof node);
        fprintf(o, "  #   %s: %s\n", cfg->chanmap.ch[cfg->model_to_chan[i]].name,
                at ? at : "not measured by oma.stand");
    }
    if (a->n_refs) {
        fprintf(o, "  refs = [");
        for (size_t i = 0; i < a->n_refs; i++)
            fprintf(o, "%s\"%s\"", i ? ", " : "", cfg->chanmap.ch[cfg->model_to_chan[a->refs[i]]].name);
        fprintf(o, "];\n");
    } else {
        fprintf(o, "  # refs: every channel\n");
    }
    fprintf(o,
            "  window = %s;  # s\n  every = %s;  # s\n  block = %s;  # s\n  block_rows = %u;\n"
            "  max_order = %u;  # 0 = automatic\n  max_damping = %s;\n  match_freq = %s;\n  match_mac = %s;\n"
            "  outlier_threshold = %s;  # 0 = off\n};\n",
            vd_cfg_num(a->window_s), vd_cfg_num(a->every_s), vd_cfg_num(a->block_s), a->block_rows, a->max_order,
            vd_cfg_num(a->max_damping), vd_cfg_num(a->match_freq), vd_cfg_num(a->match_mac),
            vd_cfg_num(cfg->outlier_threshold));
}

void vd_config_print(const vd_config *cfg, FILE *o)
{
    const vibid_model *m = cfg->oma.on ? NULL : vibid_stand_model(cfg->stand);
    fprintf(o, "# vibidd effective configuration of %s (every default filled in)\n", cfg->path);
    if (cfg->oma.on)
        print_oma(cfg, o);
    else if (cfg->stand_file[0])
        fprintf(o, "stand = \"%s\";\n", cfg->stand_file);
    else
        fprintf(o, "# stand: inline group in %s\n", cfg->path);
    if (!cfg->oma.on)
        fprintf(o, "# stand \"%s\": sample_rate %s Hz, %zu unknowns, %zu channels\n", vibid_stand_name(cfg->stand),
                vd_cfg_num(cfg->sample_rate), cfg->n_params, cfg->n_channels);
    for (size_t k = 0; k < cfg->n_params && m; k++) {
        vibid_param_info pi;
        vibid_model_param_info(m, k, &pi);
        static const char *const kinds[] = {"mass", "damping", "stiffness", "cubic", "gain"};
        fprintf(o, "#   unknown %zu: %s (%s)\n", k, pi.name, (unsigned)pi.kind < 5 ? kinds[pi.kind] : "?");
    }
    for (size_t i = 0; i < cfg->n_channels && m; i++) {
        vibid_channel_info ci;
        vibid_model_channel_info(m, i, &ci);
        fprintf(o, "#   channel %zu: %s <- source channel '%s'", i, ci.name, cfg->chanmap.ch[cfg->model_to_chan[i]].name);
        if (cfg->model_scale[i] != 1.0)
            fprintf(o, " x %.12g (its unit to the stand's %s)", cfg->model_scale[i],
                    ci.kind == VIBID_CHANNEL_INPUT ? "N" : vibid_stand_length_unit(cfg->stand));
        fputc('\n', o);
    }
    fprintf(o, "source = {\n  kind = \"%s\";\n", vd_source_kind_name(cfg->source_kind));
    switch (cfg->source_kind) {
    case VD_SRC_SOCKETCAN:
        fprintf(o, "  interface = \"%s\";\n  dbc = \"%s\";\n  rcvbuf = %d;\n  hw_timestamps = %s;\n  batch = %u;\n",
                cfg->iface, cfg->dbc_file, cfg->rcvbuf_bytes, vd_cfg_yes(cfg->hw_timestamps), cfg->can_batch);
        break;
    case VD_SRC_MODBUS:
        fprintf(o, "  url = \"%s\";\n", cfg->url);
        if (cfg->transport == VIBID_MODBUS_RTU)
            fprintf(o, "  baud = %d;\n  parity = \"%c\";\n", cfg->baud, cfg->parity);
        fprintf(o, "  unit_id = %d;\n  mode = \"%s\";\n", cfg->unit_id,
                cfg->modbus_mode == VIBID_MODBUS_FIFO ? "fifo" : "snapshot");
        if (cfg->regmap_file[0])
            fprintf(o, "  register_map = \"%s\";\n", cfg->regmap_file);
        else {
            fprintf(o, "  registers = (\n");
            static const char *const tn[] = {"INT16", "UINT16", "INT32", "UINT32", "FLOAT32", "FLOAT64"};
            static const char *const on[] = {"ABCD", "DCBA", "BADC", "CDAB"};
            for (size_t i = 0; i < cfg->regmap->n; i++) {
                const vibid_reg_entry *e = &cfg->regmap->entries[i];
                fprintf(o,
                        "    { name = \"%s\"; address = %u; register = \"%s\"; type = \"%s\"; byte_order = \"%s\"; "
                        "scale = %s; offset = %s; }%s\n",
                        e->name, e->address, e->kind == VIBID_REG_HOLDING ? "holding" : "input", tn[e->type],
                        on[e->order], vd_cfg_num(e->scale), vd_cfg_num(e->offset), i + 1 < cfg->regmap->n ? "," : "");
            }
            fprintf(o, "  );\n");
        }
        fprintf(o,
                "  poll_period = %s;  # 0 = min(K h / 4, 0.05 s)\n  fifo_base = %u;\n  response_timeout = %s;\n"
                "  backoff_initial = %s;\n  backoff_max = %s;\n  max_timeouts = %u;\n",
                vd_cfg_num(cfg->poll_period_s), cfg->fifo_base, vd_cfg_num(cfg->response_timeout_s), vd_cfg_num(cfg->backoff_initial_s),
                vd_cfg_num(cfg->backoff_max_s), cfg->max_timeouts);
        break;
    case VD_SRC_REPLAY: {
        static const char *const fmts[] = {"auto", "candump", "csv"};
        fprintf(o, "  file = \"%s\";\n  format = \"%s\";\n  paced = %s;\n  speed = %s;\n", cfg->replay_file,
                fmts[cfg->replay_format], vd_cfg_yes(cfg->paced), vd_cfg_num(cfg->speed));
        if (cfg->dbc_file[0])
            fprintf(o, "  dbc = \"%s\";\n", cfg->dbc_file);
        break;
    }
    }
    if (cfg->chanmap_file[0])
        fprintf(o, "  channel_map = \"%s\";\n", cfg->chanmap_file);
    else {
        fprintf(o, "  channels = (\n");
        static const char *const srcn[] = {"signal", "register", "column"};
        for (size_t i = 0; i < cfg->chanmap.n; i++) {
            const vibid_channel *ch = &cfg->chanmap.ch[i];
            fprintf(o, "    { name = \"%s\"; quantity = \"%s\";", ch->name, vibid_quantity_name(ch->quantity));
            if (ch->node >= 0)
                fprintf(o, " node = %d;", ch->node);
            if (ch->unit[0])
                fprintf(o, " unit = \"%s\";", ch->unit);
            fprintf(o, " %s = \"%s\";", srcn[ch->source], ch->ref);
            if (ch->message[0])
                fprintf(o, " message = \"%s\";", ch->message);
            fprintf(o, " }%s\n", i + 1 < cfg->chanmap.n ? "," : "");
        }
        fprintf(o, "  );\n");
    }
    if (cfg->chanmap.counter[0])
        fprintf(o, "  counter = \"%s\";\n", cfg->chanmap.counter);
    if (cfg->chanmap.trigger[0])
        fprintf(o, "  trigger = \"%s\";\n", cfg->chanmap.trigger);
    if (cfg->chanmap.time_column[0])
        fprintf(o, "  time_column = \"%s\";\n", cfg->chanmap.time_column);
    fprintf(o, "};\n");
    fprintf(o,
            "acquisition = {\n  ring_size = %u;\n  read_batch = %u;\n  read_timeout = %d;  # ms\n"
            "  realtime_priority = %d;  # 0 = SCHED_OTHER\n  lock_memory = %s;\n"
            "  handoff_spin = %u;  # us the estimation thread busy-waits before sleeping\n};\n",
            cfg->ring_size, cfg->read_batch, cfg->read_timeout_ms, cfg->rt_priority, vd_cfg_yes(cfg->lock_memory),
            cfg->handoff_spin_us);
    /* Settings left to the automatic choice stay commented out, so that the printout
     * read back chooses again; the choices themselves follow as comments (main.c). */
    if (!cfg->oma.on)
        print_estimator(cfg, o);
    fprintf(o, "outputs = {\n");
    for (size_t i = 0; i < vd_n_outputs; i++) /* each output prints its groups (output.h) */
        if (vd_outputs[i]->print && !strchr(vd_outputs[i]->groups[0], '.'))
            vd_outputs[i]->print(cfg, o);
    fprintf(o, "};\n");
    fprintf(o, "alarms = {\n  enabled = %s;\n", vd_cfg_yes(cfg->alarms_enabled));
    if (cfg->alarm_test == VD_ALARM_CUSUM)
        fprintf(o, "  test = \"cusum\";\n  false_alarms_per_year = %s;\n  horizon = %s;\n  detection_probability = %s;\n",
                vd_cfg_num(cfg->alarm_false_per_year), vd_cfg_num(cfg->alarm_horizon_s), vd_cfg_num(cfg->alarm_detection_probability));
    else
        fprintf(o, "  test = \"threshold\";\n  threshold = %s;\n  hold = %s;\n", vd_cfg_num(cfg->alarm_threshold),
                vd_cfg_num(cfg->alarm_hold_s));
    fprintf(o, "  min_relative = %s;\n  learn_start = %s;\n  learn_duration = %s;\n",
            vd_cfg_num(cfg->alarm_min_relative), vd_cfg_num(cfg->learn_start_s), vd_cfg_num(cfg->learn_duration_s));
    if (cfg->alarm_test == VD_ALARM_CUSUM)
        fprintf(o, "  reference_file = \"%s\";%s\n", vd_cfg_esc(cfg->alarm_reference_file),
                cfg->alarm_reference_file[0] ? "" : "  # not kept: learned at every start");
    fprintf(o, "  parameters = (");
    bool first = true;
    for (size_t k = 0; k < cfg->n_params; k++) {
        const vd_alarm_param *a = &cfg->alarm_param[k];
        if (!a->enabled)
            continue;
        fprintf(o, "%s\n    { name = \"%s\";", first ? "" : ",", a->name);
        if (a->has_baseline)
            fprintf(o, " baseline = %s;", vd_cfg_num(a->baseline));
        fprintf(o, " }");
        first = false;
    }
    fprintf(o, "\n  );\n};\n");
    fprintf(o, "log = {\n  level = \"%s\";\n  status_interval = %s;\n};\n",
            vd_log_level_name((vd_log_level)cfg->log_level), vd_cfg_num(cfg->log_status_interval_s));
}
