/* Modbus register maps (libconfig) and register decoding. */
#include <vibid_drivers/register_map.h>

#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

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

static const char *const type_names[] = {"INT16", "UINT16", "INT32", "UINT32", "FLOAT32", "FLOAT64"};
static const char *const order_names[] = {"ABCD", "DCBA", "BADC", "CDAB"};

static vibid_drv_status bad(vibid_drv_error *err, const char *file, const config_setting_t *s,
                            const char *what, const char *name)
{
    return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s:%d: register '%s': %s", file,
                          s ? config_setting_source_line(s) : 0, name, what);
}

vibid_regmap *vibid_regmap_from_setting(const config_setting_t *list, const char *file,
                                        vibid_drv_error *err)
{
    if (!file)
        file = "<config>";
    if (!list || !(config_setting_is_list(list) || config_setting_is_array(list))) {
        vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s:%d: 'registers' must be a list ( {...}, ... )", file,
                       list ? config_setting_source_line(list) : 0);
        return NULL;
    }
    int n = config_setting_length(list);
    vibid_regmap *map = calloc(1, sizeof *map);
    if (map && n > 0)
        map->entries = calloc((size_t)n, sizeof *map->entries);
    if (!map || (n > 0 && !map->entries)) {
        vibid_regmap_destroy(map);
        vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "%s: out of memory", file);
        return NULL;
    }
    for (int i = 0; i < n; i++) {
        config_setting_t *g = config_setting_get_elem(list, (unsigned)i);
        vibid_reg_entry *e = &map->entries[i];
        const char *name = NULL, *kind = "holding", *type = NULL, *order = "ABCD";
        int addr;
        char label[16];
        snprintf(label, sizeof label, "#%d", i + 1);
        vibid_drv_status st = VIBID_DRV_OK;
        if (!config_setting_is_group(g))
            st = bad(err, file, g, "each entry must be a group { ... }", label);
        else if (!config_setting_lookup_string(g, "name", &name) || !name[0] ||
                 strlen(name) >= VIBID_REG_NAME_LEN)
            st = bad(err, file, g, "needs name = \"...\" (1..63 characters)", label);
        else if (!config_setting_lookup_int(g, "address", &addr) || addr < 0 || addr > 65535)
            st = bad(err, file, config_setting_get_member(g, "address") ? config_setting_get_member(g, "address") : g,
                     "needs address = 0..65535 (0-based, integer)", name);
        else if (!config_setting_lookup_string(g, "type", &type))
            st = bad(err, file, g, "needs type = INT16|UINT16|INT32|UINT32|FLOAT32|FLOAT64", name);
        if (st != VIBID_DRV_OK) {
            vibid_regmap_destroy(map);
            return NULL;
        }
        /* "register" as Telegraf spells it; "kind" accepted too. */
        if (!config_setting_lookup_string(g, "register", &kind))
            config_setting_lookup_string(g, "kind", &kind);
        config_setting_lookup_string(g, "byte_order", &order);
        snprintf(e->name, sizeof e->name, "%s", name);
        e->address = (uint16_t)addr;
        e->line = (unsigned)config_setting_source_line(g);
        int t = -1, o = -1;
        for (int k = 0; k < 6; k++)
            if (strcasecmp(type, type_names[k]) == 0)
                t = k;
        for (int k = 0; k < 4; k++)
            if (strcasecmp(order, order_names[k]) == 0)
                o = k;
        e->scale = 1.0;
        e->offset = 0.0;
        double d;
        int iv;
        if (config_setting_lookup_float(g, "scale", &d))
            e->scale = d;
        else if (config_setting_lookup_int(g, "scale", &iv))
            e->scale = iv;
        if (config_setting_lookup_float(g, "offset", &d))
            e->offset = d;
        else if (config_setting_lookup_int(g, "offset", &iv))
            e->offset = iv;
        if (t < 0)
            st = bad(err, file, g, "type must be INT16, UINT16, INT32, UINT32, FLOAT32 or FLOAT64", name);
        else if (o < 0)
            st = bad(err, file, g, "byte_order must be ABCD, DCBA, BADC or CDAB", name);
        else if (strcasecmp(kind, "holding") != 0 && strcasecmp(kind, "input") != 0)
            st = bad(err, file, g, "register must be \"holding\" or \"input\"", name);
        else if (!isfinite(e->scale) || e->scale == 0.0 || !isfinite(e->offset))
            st = bad(err, file, g, "scale must be finite and non-zero, offset finite", name);
        else if (addr + (int)vibid_reg_type_words((vibid_reg_type)t) - 1 > 65535)
            st = bad(err, file, g, "address + size runs past register 65535", name);
        for (int k = 0; st == VIBID_DRV_OK && k < i; k++)
            if (strcmp(map->entries[k].name, name) == 0)
                st = bad(err, file, g, "name used twice", name);
        if (st != VIBID_DRV_OK) {
            vibid_regmap_destroy(map);
            return NULL;
        }
        e->type = (vibid_reg_type)t;
        e->order = (vibid_reg_order)o;
        e->kind = strcasecmp(kind, "input") == 0 ? VIBID_REG_INPUT : VIBID_REG_HOLDING;
        map->n++;
    }
    return map;
}

vibid_regmap *vibid_regmap_load(const char *path, vibid_drv_error *err)
{
    config_t cfg;
    config_init(&cfg);
    if (!config_read_file(&cfg, path)) {
        if (config_error_type(&cfg) == CONFIG_ERR_FILE_IO)
            vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: cannot read", path);
        else
            vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s:%d: %s",
                           config_error_file(&cfg) ? config_error_file(&cfg) : path,
                           config_error_line(&cfg), config_error_text(&cfg));
        config_destroy(&cfg);
        return NULL;
    }
    config_setting_t *list = config_lookup(&cfg, "registers");
    vibid_regmap *map = NULL;
    if (!list)
        vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s: no 'registers' list", path);
    else
        map = vibid_regmap_from_setting(list, path, err);
    config_destroy(&cfg);
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
