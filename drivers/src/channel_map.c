/* Channel map: which signal/register/column feeds which stand channel. */
#include <vibid_drivers/channel_map.h>

#include <stdio.h>
#include <string.h>

#define N_QUANTITIES 8
static const char *const qnames[N_QUANTITIES] = {"displacement",      "velocity",      "acceleration",
                                                 "force",             "base_displacement", "base_velocity",
                                                 "base_acceleration", "input"};

const char *vibid_quantity_name(vibid_quantity q)
{
    return (unsigned)q < N_QUANTITIES ? qnames[q] : "unknown";
}

bool vibid_quantity_is_base(vibid_quantity q)
{
    return q == VIBID_Q_BASE_DISPLACEMENT || q == VIBID_Q_BASE_VELOCITY || q == VIBID_Q_BASE_ACCELERATION;
}

/* First member of g whose name is not in known (NULL-terminated), or NULL. */
static const config_setting_t *unknown_member(const config_setting_t *g, const char *const *known)
{
    for (int i = 0; i < config_setting_length(g); i++) {
        const config_setting_t *e = config_setting_get_elem(g, (unsigned)i);
        const char *nm = config_setting_name(e);
        bool ok = false;
        for (const char *const *k = known; *k && nm; k++)
            ok = ok || strcmp(*k, nm) == 0;
        if (!ok)
            return e;
    }
    return NULL;
}

/* 0: key absent; 1: copied; -1: longer than cap - 1 (dst left empty: never a silent cut). */
static int copy_opt(const config_setting_t *g, const char *key, char *dst, size_t cap)
{
    const char *s;
    if (!config_setting_lookup_string(g, key, &s))
        return 0;
    if (strlen(s) >= cap) {
        dst[0] = '\0';
        return -1;
    }
    snprintf(dst, cap, "%s", s);
    return 1;
}

static vibid_drv_status too_long(vibid_drv_error *err, const char *file, int line, const char *who,
                                 const char *key, size_t cap)
{
    return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s:%d: %s: %s is longer than %zu characters", file, line, who,
                          key, cap - 1);
}

vibid_drv_status vibid_chanmap_from_setting(const config_setting_t *group, const char *file,
                                            vibid_chanmap *map, vibid_drv_error *err)
{
    if (!file)
        file = "<config>";
    if (!group || !map)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "%s: no channel map", file);
    memset(map, 0, sizeof *map);
    const config_setting_t *list = config_setting_get_member(group, "channels");
    if (!list || !config_setting_is_list(list))
        return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s:%d: needs channels = ( { ... }, ... )", file,
                              config_setting_source_line(group));
    int n = config_setting_length(list);
    if (n < 1 || n > VIBID_DRV_MAX_CHANNELS)
        return vibid_drv_fail(err, VIBID_DRV_E_RANGE, "%s:%d: %d channels, allowed 1..%d", file,
                              config_setting_source_line(list), n, VIBID_DRV_MAX_CHANNELS);
    for (int i = 0; i < n; i++) {
        const config_setting_t *g = config_setting_get_elem(list, (unsigned)i);
        vibid_channel *c = &map->ch[i];
        int line = config_setting_source_line(g);
        c->line = (unsigned)line;
        const char *q;
        char who[160];
        snprintf(who, sizeof who, "channel #%d", i + 1);
        int got = config_setting_is_group(g) ? copy_opt(g, "name", c->name, sizeof c->name) : 0;
        if (got < 0)
            return too_long(err, file, line, who, "name", sizeof c->name);
        if (got == 0 || !c->name[0])
            return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s:%d: channel #%d needs name = \"...\"", file,
                                  line, i + 1);
        static const char *const ch_known[] = {"name",   "quantity", "node",   "unit",
                                               "signal", "register", "column", "message", NULL};
        const config_setting_t *bad = unknown_member(g, ch_known);
        if (bad)
            return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX,
                                  "%s:%d: channel '%s': unknown setting '%s' (name, quantity, node, unit, signal, "
                                  "register, column, message)",
                                  file, config_setting_source_line(bad), c->name, config_setting_name(bad));
        if (!config_setting_lookup_string(g, "quantity", &q))
            return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s:%d: channel '%s' needs quantity", file, line,
                                  c->name);
        int qi = -1;
        for (int k = 0; k < N_QUANTITIES; k++)
            if (strcmp(q, qnames[k]) == 0)
                qi = k;
        if (qi < 0)
            return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX,
                                  "%s:%d: channel '%s': quantity '%s' is not displacement, velocity, "
                                  "acceleration, force, input, base_displacement, base_velocity or base_acceleration",
                                  file, line, c->name, q);
        c->quantity = (vibid_quantity)qi;
        c->is_input = c->quantity == VIBID_Q_FORCE || c->quantity == VIBID_Q_INPUT || vibid_quantity_is_base(c->quantity);
        const config_setting_t *node = config_setting_get_member(g, "node");
        if (vibid_quantity_is_base(c->quantity)) {
            /* The base is not a node; 0 is accepted because earlier maps wrote it. */
            if (node && (config_setting_type(node) != CONFIG_TYPE_INT || config_setting_get_int(node) != 0))
                return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX,
                                      "%s:%d: channel '%s': a %s belongs to the base, not to a node: omit node",
                                      file, config_setting_source_line(node), c->name, q);
            c->node = -1;
        } else if (!config_setting_lookup_int(g, "node", &c->node) || c->node < 0) {
            return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s:%d: channel '%s' needs node = <integer >= 0>",
                                  file, line, c->name);
        }
        snprintf(who, sizeof who, "channel '%s'", c->name);
        if (copy_opt(g, "unit", c->unit, sizeof c->unit) < 0)
            return too_long(err, file, line, who, "unit", sizeof c->unit);
        int sources = 0;
        static const char *const src_keys[] = {"signal", "register", "column"};
        static const vibid_chan_source src_kinds[] = {VIBID_CHAN_SIGNAL, VIBID_CHAN_REGISTER, VIBID_CHAN_COLUMN};
        for (int k = 0; k < 3; k++) {
            int r = copy_opt(g, src_keys[k], c->ref, sizeof c->ref);
            if (r < 0)
                return too_long(err, file, line, who, src_keys[k], sizeof c->ref);
            if (r > 0) {
                c->source = src_kinds[k];
                sources++;
            }
        }
        if (sources != 1 || !c->ref[0])
            return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX,
                                  "%s:%d: channel '%s' needs exactly one of signal, register, column", file,
                                  line, c->name);
        if (copy_opt(g, "message", c->message, sizeof c->message) < 0)
            return too_long(err, file, line, who, "message", sizeof c->message);
        for (int k = 0; k < i; k++)
            if (strcmp(map->ch[k].name, c->name) == 0)
                return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s:%d: channel name '%s' used twice (line %u)",
                                      file, line, c->name, map->ch[k].line);
        map->n++;
    }
    int gl = config_setting_source_line(group);
    if (copy_opt(group, "counter", map->counter, sizeof map->counter) < 0)
        return too_long(err, file, gl, "channel map", "counter", sizeof map->counter);
    if (copy_opt(group, "trigger", map->trigger, sizeof map->trigger) < 0)
        return too_long(err, file, gl, "channel map", "trigger", sizeof map->trigger);
    if (copy_opt(group, "time_column", map->time_column, sizeof map->time_column) < 0)
        return too_long(err, file, gl, "channel map", "time_column", sizeof map->time_column);
    return VIBID_DRV_OK;
}

vibid_drv_status vibid_chanmap_load(const char *path, vibid_chanmap *map, vibid_drv_error *err)
{
    config_t cfg;
    config_init(&cfg);
    vibid_drv_status st;
    if (!config_read_file(&cfg, path)) {
        if (config_error_type(&cfg) == CONFIG_ERR_FILE_IO)
            st = vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: cannot read", path);
        else
            st = vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s:%d: %s", path, config_error_line(&cfg),
                                config_error_text(&cfg));
    } else {
        static const char *const root_known[] = {"channels", "counter", "trigger", "time_column", NULL};
        const config_setting_t *bad = unknown_member(config_root_setting(&cfg), root_known);
        if (bad)
            st = vibid_drv_fail(err, VIBID_DRV_E_SYNTAX,
                                "%s:%d: unknown setting '%s' (channels, counter, trigger, time_column)", path,
                                config_setting_source_line(bad), config_setting_name(bad));
        else
            st = vibid_chanmap_from_setting(config_root_setting(&cfg), path, map, err);
    }
    config_destroy(&cfg);
    return st;
}
