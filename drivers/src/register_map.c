/* Modbus register maps (libconfig) and register decoding. */
#include <vibid_drivers/register_map.h>

#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

unsigned vibid_reg_type_words(vibid_reg_type type)
{
    switch (type) {
    case VIBID_REG_INT16:
    case VIBID_REG_UINT16: return 1;
    case VIBID_REG_INT32:
    case VIBID_REG_UINT32:
    case VIBID_REG_FLOAT32: return 2;
    case VIBID_REG_FLOAT64: return 4;
    }
    return 0;
}

static const char *const type_names[] = {"INT16", "UINT16", "INT32", "UINT32", "FLOAT32", "FLOAT64", NULL};
static const char *const order_names[] = {"ABCD", "DCBA", "BADC", "CDAB", NULL};

vibid_regmap *vibid_regmap_read(const vibid_cfg_reader *r, const config_setting_t *list, const char *path) {
    if (!r || !r->err) return NULL;
    if (!list || !(config_setting_is_list(list) || config_setting_is_array(list))) {
        vibid_cfg_fail(r, list, path, "must be a list ( { name = ...; address = ...; type = ...; }, ... )");
        return NULL;
    }
    int n = config_setting_length(list);
    vibid_regmap *map = calloc(1, sizeof *map);
    if (map && n > 0)
        map->entries = calloc((size_t)n, sizeof *map->entries);
    if (!map || (n > 0 && !map->entries)) {
        vibid_regmap_destroy(map);
        vibid_cfg_fail(r, list, path, "out of memory");
        return NULL;
    }
    static const char *const known[] = {"name",       "address", "register", "kind", "type",
                                        "byte_order", "scale",   "offset",   NULL};
    /* "register" as Telegraf spells it; "kind" accepted too. */
    static const char *const kinds[] = {"holding", "input", NULL};
    for (int i = 0; i < n; i++) {
        const config_setting_t *g = config_setting_get_elem(list, (unsigned)i);
        vibid_reg_entry *e = &map->entries[i];
        char p[192], f[224];
        snprintf(p, sizeof p, "%s.[%d]", path, i);
        long long addr = 0;
        int t = 0, o = 0, k = 0;
        e->scale = 1.0;
        e->offset = 0.0;
        e->line = (unsigned)config_setting_source_line(g);
        if (!config_setting_is_group(g)) {
            vibid_cfg_fail(r, g, p, "must be a group { name = ...; address = ...; type = ...; }");
            goto fail;
        }
        if (vibid_cfg_check_keys(r, g, p, known) || vibid_cfg_require(r, g, p, "name", "a string") ||
            vibid_cfg_string(r, g, p, "name", false, e->name, sizeof e->name) < 0 ||
            vibid_cfg_require(r, g, p, "address", "0..65535, 0-based") ||
            vibid_cfg_int(r, g, p, "address", 0, 65535, &addr) < 0 ||
            vibid_cfg_require(r, g, p, "type", "INT16, UINT16, INT32, UINT32, FLOAT32 or FLOAT64") ||
            vibid_cfg_enum(r, g, p, "type", type_names, true, &t) < 0 ||
            vibid_cfg_enum(r, g, p, "byte_order", order_names, true, &o) < 0 ||
            vibid_cfg_enum(r, g, p, "register", kinds, true, &k) < 0 ||
            vibid_cfg_enum(r, g, p, "kind", kinds, true, &k) < 0 ||
            vibid_cfg_number(r, g, p, "scale", -HUGE_VAL, HUGE_VAL, &e->scale) < 0 ||
            vibid_cfg_number(r, g, p, "offset", -HUGE_VAL, HUGE_VAL, &e->offset) < 0)
            goto fail;
        if (config_setting_get_member(g, "register") && config_setting_get_member(g, "kind")) {
            vibid_cfg_field(f, sizeof f, p, "kind");
            vibid_cfg_fail(r, config_setting_get_member(g, "kind"), f, "give register or kind, not both");
            goto fail;
        }
        if (e->scale == 0.0) {
            vibid_cfg_field(f, sizeof f, p, "scale");
            vibid_cfg_fail(r, config_setting_get_member(g, "scale"), f, "must not be 0");
            goto fail;
        }
        if (addr + (long long)vibid_reg_type_words((vibid_reg_type)t) - 1 > 65535) {
            vibid_cfg_field(f, sizeof f, p, "address");
            vibid_cfg_fail(r, config_setting_get_member(g, "address"), f,
                           "%lld + %u registers of %s runs past register 65535", addr,
                           vibid_reg_type_words((vibid_reg_type)t), type_names[t]);
            goto fail;
        }
        for (size_t j = 0; j < map->n; j++)
            if (strcmp(map->entries[j].name, e->name) == 0) {
                vibid_cfg_field(f, sizeof f, p, "name");
                vibid_cfg_fail(r, config_setting_get_member(g, "name"), f, "'%s' used twice (line %u)",
                               e->name, map->entries[j].line);
                goto fail;
            }
        e->address = (uint16_t)addr;
        e->type = (vibid_reg_type)t;
        e->order = (vibid_reg_order)o;
        e->kind = k == 1 ? VIBID_REG_INPUT : VIBID_REG_HOLDING;
        map->n++;
    }
    return map;
fail:
    vibid_regmap_destroy(map);
    return NULL;
}

vibid_regmap *vibid_regmap_read_file(const char *path, vibid_cfg_error *err) {
    config_t cfg;
    vibid_regmap *map = NULL;
    if (!vibid_cfg_read_file(&cfg, path, err)) {
        static const char *const root_known[] = {"registers", NULL};
        vibid_cfg_reader r = {path, err};
        const config_setting_t *list = config_lookup(&cfg, "registers");
        if (vibid_cfg_check_keys(&r, config_root_setting(&cfg), "", root_known))
            ;
        else if (!list)
            vibid_cfg_fail(&r, config_root_setting(&cfg), "registers",
                           "missing (a list registers = ( ... );)");
        else
            map = vibid_regmap_read(&r, list, "registers");
    }
    config_destroy(&cfg);
    return map;
}

vibid_regmap *vibid_regmap_load(const char *path, vibid_drv_error *err) {
    vibid_cfg_error ce;
    vibid_regmap *map = vibid_regmap_read_file(path, &ce);
    if (!map) vibid_drv_fail(err, ce.line > 0 ? VIBID_DRV_E_SYNTAX : VIBID_DRV_E_IO, "%s", ce.text);
    return map;
}

void vibid_regmap_destroy(vibid_regmap *map)
{
    if (!map)
        return;
    free(map->entries);
    free(map);
}

const vibid_reg_entry *vibid_regmap_find(const vibid_regmap *map, const char *name)
{
    if (!map || !name)
        return NULL;
    for (size_t i = 0; i < map->n; i++)
        if (strcmp(map->entries[i].name, name) == 0)
            return &map->entries[i];
    return NULL;
}

/* Puts the words into canonical big-endian order (ABCD...) and returns them as one
 * integer, most significant word first. */
static uint64_t canonical(const vibid_reg_entry *e, const uint16_t *w)
{
    unsigned n = vibid_reg_type_words(e->type);
    uint16_t t[4];
    bool swap_bytes = e->order == VIBID_REG_BADC || e->order == VIBID_REG_DCBA;
    bool swap_words = e->order == VIBID_REG_CDAB || e->order == VIBID_REG_DCBA;
    for (unsigned i = 0; i < n; i++) {
        uint16_t x = w[swap_words ? n - 1 - i : i];
        t[i] = swap_bytes ? (uint16_t)((x >> 8) | (x << 8)) : x;
    }
    uint64_t v = 0;
    for (unsigned i = 0; i < n; i++)
        v = (v << 16) | t[i];
    return v;
}

vibid_drv_status vibid_reg_decode(const vibid_reg_entry *e, const uint16_t *regs, size_t n_regs,
                                  uint16_t first_address, double *value)
{
    if (!e || !regs || !value)
        return VIBID_DRV_E_ARG;
    unsigned n = vibid_reg_type_words(e->type);
    if (e->address < first_address || (size_t)(e->address - first_address) + n > n_regs)
        return VIBID_DRV_E_RANGE;
    uint64_t v = canonical(e, regs + (e->address - first_address));
    double x;
    switch (e->type) {
    case VIBID_REG_INT16: x = (int16_t)(uint16_t)v; break;
    case VIBID_REG_UINT16: x = (uint16_t)v; break;
    case VIBID_REG_INT32: x = (int32_t)(uint32_t)v; break;
    case VIBID_REG_UINT32: x = (uint32_t)v; break;
    case VIBID_REG_FLOAT32: {
        uint32_t b = (uint32_t)v;
        float f;
        memcpy(&f, &b, sizeof f);
        x = f;
        break;
    }
    default: memcpy(&x, &v, sizeof x); break;
    }
    *value = x * e->scale + e->offset;
    return VIBID_DRV_OK;
}

vibid_drv_status vibid_reg_encode(const vibid_reg_entry *e, double value, uint16_t *words)
{
    if (!e || !words || !isfinite(value))
        return VIBID_DRV_E_ARG;
    double raw = (value - e->offset) / e->scale;
    uint64_t v;
    static const double lo[] = {-32768.0, 0.0, -2147483648.0, 0.0};
    static const double hi[] = {32767.0, 65535.0, 2147483647.0, 4294967295.0};
    if (e->type <= VIBID_REG_UINT32) {
        double r = nearbyint(raw);
        if (!(r >= lo[e->type] && r <= hi[e->type]))
            return VIBID_DRV_E_RANGE;
        int64_t iv = (int64_t)r;
        v = (uint64_t)iv & (e->type <= VIBID_REG_UINT16 ? 0xFFFFu : 0xFFFFFFFFu);
    } else if (e->type == VIBID_REG_FLOAT32) {
        float f = (float)raw;
        uint32_t b;
        memcpy(&b, &f, sizeof b);
        v = b;
    } else {
        memcpy(&v, &raw, sizeof v);
    }
    unsigned n = vibid_reg_type_words(e->type);
    uint16_t t[4];
    for (unsigned i = 0; i < n; i++)
        t[i] = (uint16_t)(v >> (16 * (n - 1 - i)));
    bool swap_bytes = e->order == VIBID_REG_BADC || e->order == VIBID_REG_DCBA;
    bool swap_words = e->order == VIBID_REG_CDAB || e->order == VIBID_REG_DCBA;
    for (unsigned i = 0; i < n; i++) {
        uint16_t x = t[i];
        words[swap_words ? n - 1 - i : i] = swap_bytes ? (uint16_t)((x >> 8) | (x << 8)) : x;
    }
    return VIBID_DRV_OK;
}
