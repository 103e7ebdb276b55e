/* Channel map: which signal/register/column feeds which stand channel. */
#include <vibid_drivers/channel_map.h>

#include <stdio.h>
#include <string.h>

#define N_QUANTITIES 9
/* In vibid_quantity's order; NULL-terminated for vibid_cfg_enum. */
static const char *const qnames[N_QUANTITIES + 1] = {"displacement",      "velocity",          "acceleration",
                                                     "force",             "base_displacement", "base_velocity",
                                                     "base_acceleration", "input",             "covariate",
                                                     NULL};

const char *vibid_quantity_name(vibid_quantity q)
{
    return (unsigned)q < N_QUANTITIES ? qnames[q] : "unknown";
}

bool vibid_quantity_is_base(vibid_quantity q)
{
    return q == VIBID_Q_BASE_DISPLACEMENT || q == VIBID_Q_BASE_VELOCITY || q == VIBID_Q_BASE_ACCELERATION;
}

/* The configuration reader's error as the drivers' status and error holder. */
static vibid_drv_status to_drv(const vibid_cfg_error *ce, vibid_drv_status st, vibid_drv_error *err) {
    return vibid_drv_fail(err, st, "%s", ce->text);
}

/* The channel's name (read into name) is a name of the safe set (vibid/cfgread.h). */
static int check_name(const vibid_cfg_reader *r, const config_setting_t *g, const char *p, const char *name) {
    char f[192];
    vibid_cfg_field(f, sizeof f, p, "name");
    return vibid_cfg_check_name(r, config_setting_get_member(g, "name"), f, name);
}

vibid_drv_status vibid_chanmap_read(const vibid_cfg_reader *r, const config_setting_t *group,
                                    const char *path, vibid_chanmap *map) {
    if (!r || !r->err) return VIBID_DRV_E_ARG;
    if (!group || !map) return vibid_cfg_fail(r, group, path, "no channel map"), VIBID_DRV_E_ARG;
    memset(map, 0, sizeof *map);
    char lp[192], p[224], f[256]; /* channels, channels.[i], channels.[i].key */
    vibid_cfg_field(lp, sizeof lp, path, "channels");
    const config_setting_t *list = config_setting_get_member(group, "channels");
    if (!list || !config_setting_is_list(list))
        return vibid_cfg_fail(r, list ? list : group, lp,
                              "%s (a list ( { name = ...; quantity = ...; ... }, ... ))",
                              list ? "must be a list" : "missing"),
               VIBID_DRV_E_SYNTAX;
    int n = config_setting_length(list);
    if (n < 1 || n > VIBID_DRV_MAX_CHANNELS)
        return vibid_cfg_fail(r, list, lp, "%d channels, allowed 1..%d", n, VIBID_DRV_MAX_CHANNELS),
               VIBID_DRV_E_RANGE;
    static const char *const ch_known[] = {"name",     "quantity", "node",    "unit", "signal",
                                           "register", "column",   "message", NULL};
    for (int i = 0; i < n; i++) {
        const config_setting_t *g = config_setting_get_elem(list, (unsigned)i);
        vibid_channel *c = &map->ch[i];
        c->line = (unsigned)config_setting_source_line(g);
        snprintf(p, sizeof p, "%s.[%d]", lp, i);
        if (!config_setting_is_group(g))
            return vibid_cfg_fail(r, g, p, "must be a group { name = ...; quantity = ...; ... }"),
                   VIBID_DRV_E_SYNTAX;
        int qi = 0, got;
        long long node = -1;
        if (vibid_cfg_check_keys(r, g, p, ch_known) ||
            vibid_cfg_require(r, g, p, "name", "the stand's channel name, a string") ||
            vibid_cfg_string(r, g, p, "name", false, c->name, sizeof c->name) < 0 ||
            check_name(r, g, p, c->name) || /* written into outputs: the raw recording's header, logs */
            vibid_cfg_require(r, g, p, "quantity", "displacement, velocity, acceleration, force, ...") ||
            vibid_cfg_enum(r, g, p, "quantity", qnames, false, &qi) < 0 ||
            (got = vibid_cfg_int(r, g, p, "node", 0, 1 << 20, &node)) < 0 ||
            vibid_cfg_string(r, g, p, "unit", false, c->unit, sizeof c->unit) < 0 ||
            vibid_cfg_string(r, g, p, "message", false, c->message, sizeof c->message) < 0)
            return VIBID_DRV_E_SYNTAX;
        c->quantity = (vibid_quantity)qi;
        c->is_input = c->quantity == VIBID_Q_FORCE || c->quantity == VIBID_Q_INPUT || vibid_quantity_is_base(c->quantity);
        vibid_cfg_field(f, sizeof f, p, "node");
        if (c->quantity == VIBID_Q_COVARIATE) {
            /* an operating condition of the whole stand (temperature, speed, load) */
            if (got)
                return vibid_cfg_fail(r, config_setting_get_member(g, "node"), f,
                                      "a covariate belongs to the stand, not to a node: omit node"),
                       VIBID_DRV_E_SYNTAX;
            c->node = -1;
        } else if (vibid_quantity_is_base(c->quantity)) {
            /* The base is not a node; 0 is accepted because earlier maps wrote it. */
            if (got && node != 0)
                return vibid_cfg_fail(r, config_setting_get_member(g, "node"), f,
                                      "a %s belongs to the base, not to a node: omit node", qnames[qi]),
                       VIBID_DRV_E_SYNTAX;
            c->node = -1;
        } else if (!got) {
            return vibid_cfg_fail(r, g, f, "missing (the 0-based index of the node in the stand)"),
                   VIBID_DRV_E_SYNTAX;
        } else {
            c->node = (int)node;
        }
        static const char *const src_keys[] = {"signal", "register", "column"};
        static const vibid_chan_source src_kinds[] = {VIBID_CHAN_SIGNAL, VIBID_CHAN_REGISTER, VIBID_CHAN_COLUMN};
        int sources = 0;
        for (int k = 0; k < 3; k++) {
            int rs = vibid_cfg_string(r, g, p, src_keys[k], false, c->ref, sizeof c->ref);
            if (rs < 0) return VIBID_DRV_E_SYNTAX;
            if (rs > 0) {
                c->source = src_kinds[k];
                sources++;
            }
        }
        if (sources != 1)
            return vibid_cfg_fail(r, g, p,
                                  "channel '%s' needs exactly one of signal, register, column (has %d)",
                                  c->name, sources),
                   VIBID_DRV_E_SYNTAX;
        for (int k = 0; k < i; k++)
            if (strcmp(map->ch[k].name, c->name) == 0) {
                vibid_cfg_field(f, sizeof f, p, "name");
                return vibid_cfg_fail(r, config_setting_get_member(g, "name"), f,
                                      "channel name '%s' used twice (line %u)", c->name, map->ch[k].line),
                       VIBID_DRV_E_SYNTAX;
            }
        map->n++;
    }
    if (vibid_cfg_string(r, group, path, "counter", false, map->counter, sizeof map->counter) < 0 ||
        vibid_cfg_string(r, group, path, "trigger", false, map->trigger, sizeof map->trigger) < 0 ||
        vibid_cfg_string(r, group, path, "time_column", false, map->time_column, sizeof map->time_column) < 0)
        return VIBID_DRV_E_SYNTAX;
    return VIBID_DRV_OK;
}

vibid_drv_status vibid_chanmap_read_file(const char *path, vibid_chanmap *map, vibid_cfg_error *err) {
    config_t cfg;
    vibid_drv_status st = VIBID_DRV_E_SYNTAX;
    if (vibid_cfg_read_file(&cfg, path, err)) {
        st = err->line > 0 ? VIBID_DRV_E_SYNTAX : VIBID_DRV_E_IO;
    } else {
        static const char *const root_known[] = {"channels", "counter", "trigger", "time_column", NULL};
        vibid_cfg_reader r = {path, err};
        if (!vibid_cfg_check_keys(&r, config_root_setting(&cfg), "", root_known))
            st = vibid_chanmap_read(&r, config_root_setting(&cfg), "", map);
    }
    config_destroy(&cfg);
    return st;
}

vibid_drv_status vibid_chanmap_load(const char *path, vibid_chanmap *map, vibid_drv_error *err) {
    vibid_cfg_error ce;
    vibid_drv_status st = vibid_chanmap_read_file(path, map, &ce);
    return st == VIBID_DRV_OK ? st : to_drv(&ce, st, err);
}
