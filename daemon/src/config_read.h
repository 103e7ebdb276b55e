/* config_read.h: the typed getters every part of vibidd's configuration is read with
 * (config.c for the stand, source, estimator, alarms and log; each output for its own
 * groups, output.h), and the helpers that print it back (vd_config_print).
 *
 * Each getter fills in the directive's default first, so that an absent directive (or an
 * absent group: g NULL) reads as its default, checks the value against its range, and
 * returns 0, or -1 with the reader's message ("file:line: section.name: what is wrong")
 * in c->r.err. Unknown directives are errors (vd_cfg_known): a typo must not silently
 * leave a default in place.
 */
#ifndef VIBIDD_CONFIG_READ_H
#define VIBIDD_CONFIG_READ_H

#include <libconfig.h>
#include <stdbool.h>
#include <stddef.h>

#include <vibid/cfgread.h>

#include "config.h"

/* The reader of one vd_config_load: the file and the caller's error (r), and the
 * configuration being filled (cfg). */
typedef struct vd_cfg_ctx {
    vibid_cfg_reader r;
    vd_config *cfg;
} vd_cfg_ctx;

/* group's members are all in known (NULL-terminated); section names the group in messages. */
int vd_cfg_known(vd_cfg_ctx *c, const config_setting_t *group, const char *section, const char *const *known);
/* A number in [lo, hi]. */
int vd_cfg_double(vd_cfg_ctx *c, const config_setting_t *g, const char *section, const char *name, double def,
                  double lo, double hi, double *out);
/* An integer in [lo, hi]. */
int vd_cfg_int(vd_cfg_ctx *c, const config_setting_t *g, const char *section, const char *name, long long def,
               long long lo, long long hi, long long *out);
int vd_cfg_bool(vd_cfg_ctx *c, const config_setting_t *g, const char *section, const char *name, bool def,
                bool *out);
/* A string of at most cap-1 characters ("" allowed: it means "not set" for the outputs). */
int vd_cfg_string(vd_cfg_ctx *c, const config_setting_t *g, const char *section, const char *name,
                  const char *def, char *out, size_t cap);
/* A name (the safe set of vibid/cfgread.h: A-Z a-z 0-9 _ - ., written into outputs
 * unescaped); absent leaves def; "" only where allow_empty (it means "not set"). */
int vd_cfg_name(vd_cfg_ctx *c, const config_setting_t *g, const char *section, const char *name, const char *def,
                bool allow_empty, char *out, size_t cap);
/* One of names (NULL-terminated); *out = its index. */
int vd_cfg_enum(vd_cfg_ctx *c, const config_setting_t *g, const char *section, const char *name, int def,
                const char *const *names, int *out);
/* A file name relative to the file that names it; absent or "" leaves "" (not set). */
int vd_cfg_path(vd_cfg_ctx *c, const config_setting_t *g, const char *section, const char *name, char *out,
                size_t cap);

/* Printing the configuration back (valid libconfig syntax). The returned strings live in
 * rotating static buffers (16 numbers, 12 strings): enough for one fprintf, not thread-safe
 * (vd_config_print runs once, on the main thread). */
const char *vd_cfg_yes(bool b);        /* "true" / "false" */
const char *vd_cfg_num(double v);      /* shortest round-trip float, always with '.' or exponent */
const char *vd_cfg_esc(const char *v); /* the inside of a string literal (quote, backslash escaped) */

#endif
