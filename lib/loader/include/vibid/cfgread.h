/* vibid/cfgread.h: the one reader of vibid's libconfig files.
 *
 * The stand loader, vibidd's configuration, the drivers' channel and register maps and
 * vibid-sim's simulation group all read their settings through these functions, so that
 * every file has the same strictness and the same messages:
 *   - typed getters with ranges (a number where a string is due, 1e9 where 1..99 is
 *     allowed: an error, never a silent default);
 *   - unknown keys are errors that list the known keys (a typo must not leave a default
 *     in place without a word);
 *   - every message reads "file:line: field: reason", the field being the setting's path
 *     ("stand.nodes.[0].mass"), the file the one that holds the setting (an @include'd
 *     file names itself);
 *   - a path is relative to the directory of the file that names it.
 * A new file format then costs a table of keys and a function per group, not a copy of
 * the getters.
 *
 * Conventions: a getter returns 1 when the setting is given and valid (then *out is set),
 * 0 when it is absent (*out untouched: the caller's default stays), -1 after an error
 * (message in reader->err; *out untouched). Functions that can only fail return 0 or -1.
 * `group` may be NULL (an absent section): every getter then returns 0. `path` is the
 * group's setting path ("" for the root); the field named in messages is path + "." +
 * name. Nothing here allocates; all strings returned by reference point into the
 * config_t and live as long as it.
 */
#ifndef VIBID_CFGREAD_H
#define VIBID_CFGREAD_H

#include <libconfig.h>
#include <stdbool.h>
#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Where and why a file was refused. Fixed size: filling it never allocates; longer texts
 * are truncated. */
typedef struct vibid_cfg_error {
    char file[1024];    /* the file that holds the offending setting */
    int line;           /* 1-based; 0 when unknown (e.g. the file cannot be read) */
    char field[192];    /* setting path, e.g. "stand.nodes.[0].mass"; "" for syntax errors */
    char message[1024]; /* the reason alone */
    char text[2304];    /* "file:line: field: message" (parts that are unknown left out) */
} vibid_cfg_error;

/* The state of one read: the file being read (for settings that carry no file of their
 * own) and where errors go. Both owned by the caller; err must not be NULL. */
typedef struct vibid_cfg_reader {
    const char *file;
    vibid_cfg_error *err;
} vibid_cfg_reader;

/* Size limits of every configuration file (checked before libconfig reads it, whose time
 * grows with the square of a line's length): a line at most VIBID_CFG_LINE_MAX characters,
 * a file together with the files it @includes at most VIBID_CFG_FILE_MAX bytes. Generous
 * for any stand (a stand of 10^5 elements, one per line, is 8 MiB in lines of ~90
 * characters); libconfig reads either limit's worth in well under a second. */
#define VIBID_CFG_LINE_MAX 65536u
#define VIBID_CFG_FILE_MAX (16u << 20)

/* config_init(cf), @include relative to the file's directory, and reads `path`. 0 on
 * success; -1 with err filled ("file:line: syntax error: ...", "file: cannot read: ...",
 * "file:line: line longer than 65536 characters: ..." or "file: larger than 16 MiB with the
 * files it @includes: ..."). The caller calls config_destroy(cf) in both cases. */
int vibid_cfg_read_file(config_t *cf, const char *path, vibid_cfg_error *err);

/* Records an error at setting s (its file and line; the reader's file and line 0 when s
 * is NULL). field may be NULL or "". Always returns -1. */
int vibid_cfg_fail(const vibid_cfg_reader *r, const config_setting_t *s, const char *field, const char *fmt,
                   ...) __attribute__((format(printf, 4, 5)));

/* Records an error at an explicit file and line (line 0: unknown). Returns -1. */
int vibid_cfg_fail_at(const vibid_cfg_reader *r, const char *file, int line, const char *field,
                      const char *fmt, ...) __attribute__((format(printf, 5, 6)));

/* out = parent + "." + name, or name when parent is "" (truncated to cap). */
void vibid_cfg_field(char *out, size_t cap, const char *parent, const char *name);

/* out = the setting path of s from the root, e.g. "registers.[2].type" (truncated). */
void vibid_cfg_setting_path(const config_setting_t *s, char *out, size_t cap);

/* Error for the first member of group whose name is not in known (NULL-terminated):
 * "unknown setting 'x' (known: a, b, c)". 0 when all are known or group is NULL. */
int vibid_cfg_check_keys(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                         const char *const *known);

/* Error "missing (<what>)" unless group has member name; 0 when present. */
int vibid_cfg_require(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                      const char *name, const char *what);

/* A finite number (integer or float) in [lo, hi]. */
int vibid_cfg_number(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                     const char *name, double lo, double hi, double *out);

/* An integer (no float) in [lo, hi]. */
int vibid_cfg_int(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                  const char *name, long long lo, long long hi, long long *out);

/* true or false. */
int vibid_cfg_bool(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                   const char *name, bool *out);

/* A string copied into out (cap bytes); longer than cap - 1 is an error (never cut);
 * allow_empty = false makes "" an error. */
int vibid_cfg_string(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                     const char *name, bool allow_empty, char *out, size_t cap);

/* A non-empty string by reference (valid while the config_t lives). */
int vibid_cfg_string_ref(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                         const char *name, const char **out);

/* One of the strings names (NULL-terminated); *out = its index. case_fold: compare
 * ignoring ASCII case (register types are written INT16 or int16 in the field). */
int vibid_cfg_enum(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                   const char *name, const char *const *names, bool case_fold, int *out);

/* A list ( {...}, {...} ) (an array [ ... ] is refused: its elements cannot be groups);
 * *out = the list setting. */
int vibid_cfg_list(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                   const char *name, const config_setting_t **out);

/* Names. Every name that vibid writes into an output (the stand's name, its nodes,
 * elements, inputs and disturbances, the channel names, vibidd's site and stand tags) is 1
 * to VIBID_CFG_NAME_MAX characters of the safe set
 *     A-Z a-z 0-9 _ - .     (the first one a letter, a digit or '_')
 * so that no output has to escape it and none can be broken by it: CSV headers and rows,
 * InfluxDB line protocol (measurement, tags, field keys), MQTT topic levels and JSON, the
 * status file's key=value lines, Prometheus labels, the log. A name outside the set is an
 * error naming the first offending character and its position, the name itself printed
 * with anything unprintable escaped (a hostile name must not forge a log line through
 * the error either). References to names (an element's `between`, an input's `node`, an
 * alarm's parameter) are checked the same way, so their errors are as clean.
 * docs/stand-file.md, "Names". */
#define VIBID_CFG_NAME_MAX 63

/* NULL when s is a name of the safe set; else why (written into why, cap bytes, and
 * returned), e.g. "'rig,7' contains ',' (character 4): a name is 1..63 of A-Z a-z 0-9 _ - .
 * (the first a letter, digit or '_')". */
const char *vibid_cfg_name_problem(const char *s, char *why, size_t cap);

/* A name setting (a string of the safe set) by reference, like vibid_cfg_string_ref. */
int vibid_cfg_name(const vibid_cfg_reader *r, const config_setting_t *group, const char *path, const char *name,
                   const char **out);

/* The check of a name already read from setting s (a list element, a reference): 0, or -1
 * with the error at s and field. */
int vibid_cfg_check_name(const vibid_cfg_reader *r, const config_setting_t *s, const char *field, const char *value);

/* A file name resolved against the directory of the file that holds the setting (an
 * absolute name stays as it is). "" is an error. */
int vibid_cfg_path(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                   const char *name, char *out, size_t cap);

/* The same resolution for a name held by setting s (e.g. a group member read by the
 * caller, or a string setting that is itself the path): out = dir(file of s) / name. */
int vibid_cfg_path_of(const vibid_cfg_reader *r, const config_setting_t *s, const char *field,
                      const char *name, char *out, size_t cap);

#ifdef __cplusplus
}
#endif
#endif
