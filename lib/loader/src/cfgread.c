/* cfgread.c: the one reader of vibid's libconfig files (vibid/cfgread.h). */
#include <vibid/cfgread.h>

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>

/* The directory part of path ("." when it has none; "/" for a file in the root). */
static void dir_of(const char *path, char *dir, size_t cap) {
    const char *slash = strrchr(path, '/');
    if (!slash)
        snprintf(dir, cap, ".");
    else
        snprintf(dir, cap, "%.*s", slash == path ? 1 : (int)(slash - path), path);
}

static int vfail_at(const vibid_cfg_reader *r, const char *file, int line, const char *field, const char *fmt,
                    va_list ap) {
    vibid_cfg_error *e = r->err;
    snprintf(e->file, sizeof e->file, "%s", file ? file : "");
    e->line = line;
    snprintf(e->field, sizeof e->field, "%s", field ? field : "");
    vsnprintf(e->message, sizeof e->message, fmt, ap);
    char where[1040]; /* file (< 1024) + ":" + line: text (2304) holds where + field + message */
    if (line > 0)
        snprintf(where, sizeof where, "%s:%d", e->file, line);
    else
        snprintf(where, sizeof where, "%s", e->file);
    snprintf(e->text, sizeof e->text, "%s: %s%s%s", where, e->field, e->field[0] ? ": " : "", e->message);
    return -1;
}

int vibid_cfg_fail_at(const vibid_cfg_reader *r, const char *file, int line, const char *field,
                      const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vfail_at(r, file, line, field, fmt, ap);
    va_end(ap);
    return -1;
}

int vibid_cfg_fail(const vibid_cfg_reader *r, const config_setting_t *s, const char *field, const char *fmt,
                   ...) {
    const char *file = r->file;
    int line = 0;
    if (s) {
        const char *sf = config_setting_source_file(s);
        if (sf && *sf) file = sf;
        line = (int)config_setting_source_line(s);
    }
    va_list ap;
    va_start(ap, fmt);
    vfail_at(r, file, line, field, fmt, ap);
    va_end(ap);
    return -1;
}

/* The limits of vibid/cfgread.h, checked before libconfig reads a byte: its scanner takes
 * time quadratic in a line's length (a 1 MiB line 0.95 s, 4 MiB 15 s on the test machine;
 * 64 KiB 4 ms), and nothing bounded a file. One pass over the file and every file it
 * @includes (libconfig's own rule: "@include" at the start of a line, the name relative to
 * the include directory, at most 10 deep). */
typedef struct prescan {
    const vibid_cfg_reader *r;
    const char *dir;   /* the include directory */
    size_t total;      /* bytes of all files so far */
} prescan;

/* The file name of an @include line (text, len bytes: the line's first bytes), or 0. */
static int include_name(const char *text, size_t len, char *name, size_t cap) {
    size_t i = 0;
    while (i < len && (text[i] == ' ' || text[i] == '\t')) i++;
    if (len - i < 8 || strncmp(text + i, "@include", 8)) return 0;
    i += 8;
    while (i < len && (text[i] == ' ' || text[i] == '\t')) i++;
    if (i >= len || text[i] != '"') return 0;
    size_t n = 0;
    for (i++; i < len && text[i] != '"' && n + 1 < cap; i++) name[n++] = text[i];
    name[n] = '\0';
    return n > 0;
}

static int prescan_file(prescan *ps, const char *path, int depth) {
    FILE *f = fopen(path, "r");
    if (!f) return 0; /* libconfig says why, in its words */
    char buf[16384], head[1100], name[1024];
    size_t line = 1, len = 0, hn = 0;
    int rc = 0;
    for (size_t got; rc == 0 && (got = fread(buf, 1, sizeof buf, f)) > 0;) {
        ps->total += got;
        if (ps->total > VIBID_CFG_FILE_MAX) {
            rc = vibid_cfg_fail_at(ps->r, path, 0, "",
                                   "larger than %u MiB with the files it @includes: the limit of a configuration file",
                                   VIBID_CFG_FILE_MAX >> 20);
            break;
        }
        for (size_t i = 0; i < got && rc == 0; i++) {
            if (buf[i] != '\n') {
                if (hn < sizeof head) head[hn++] = buf[i];
                if (++len > VIBID_CFG_LINE_MAX)
                    rc = vibid_cfg_fail_at(ps->r, path, (int)line, "",
                                           "line longer than %u characters: the limit of a line of a configuration file",
                                           VIBID_CFG_LINE_MAX);
                continue;
            }
            if (include_name(head, hn, name, sizeof name)) {
                char inc[2048];
                if (depth >= 10)
                    rc = vibid_cfg_fail_at(ps->r, path, (int)line, "", "@include nested more than 10 deep");
                else if (snprintf(inc, sizeof inc, "%s%s%s", name[0] == '/' ? "" : ps->dir, name[0] == '/' ? "" : "/",
                                  name) < (int)sizeof inc)
                    rc = prescan_file(ps, inc, depth + 1);
            }
            line++;
            len = hn = 0;
        }
    }
    fclose(f);
    return rc;
}

int vibid_cfg_read_file(config_t *cf, const char *path, vibid_cfg_error *err) {
    config_init(cf);
    vibid_cfg_reader r = {path, err};
    if (!path || !*path) return vibid_cfg_fail_at(&r, "", 0, "", "no file name");
    char dir[1024];
    dir_of(path, dir, sizeof dir);
    config_set_include_dir(cf, dir);
    /* libconfig opens a directory like a file and reports the read that fails as an I/O error
     * without errno: it showed as "No such file or directory" */
    struct stat st;
    if (stat(path, &st) == 0 && S_ISDIR(st.st_mode))
        return vibid_cfg_fail_at(&r, path, 0, "", "cannot read: %s", strerror(EISDIR));
    prescan ps = {&r, dir, 0};
    if (prescan_file(&ps, path, 0)) return -1;
    errno = 0;
    if (config_read_file(cf, path)) return 0;
    if (config_error_type(cf) == CONFIG_ERR_FILE_IO)
        return vibid_cfg_fail_at(&r, path, 0, "", "cannot read: %s", strerror(errno ? errno : ENOENT));
    const char *ef = config_error_file(cf);
    return vibid_cfg_fail_at(&r, ef && *ef ? ef : path, config_error_line(cf), "", "syntax error: %s",
                             config_error_text(cf));
}

void vibid_cfg_field(char *out, size_t cap, const char *parent, const char *name) {
    snprintf(out, cap, "%s%s%s", parent ? parent : "", parent && *parent ? "." : "", name ? name : "?");
}

void vibid_cfg_setting_path(const config_setting_t *s, char *out, size_t cap) {
    /* Walk up to the root, then write the parts from the root down. */
    const config_setting_t *chain[64];
    int n = 0;
    for (const config_setting_t *p = s; p && !config_setting_is_root(p) && n < 64;
         p = config_setting_parent(p))
        chain[n++] = p;
    size_t len = 0;
    out[0] = '\0';
    for (int i = n - 1; i >= 0 && len + 1 < cap; i--) {
        const char *nm = config_setting_name(chain[i]);
        int w = nm ? snprintf(out + len, cap - len, "%s%s", len ? "." : "", nm)
                   : snprintf(out + len, cap - len, "%s[%d]", len ? "." : "", config_setting_index(chain[i]));
        if (w < 0) break;
        len += (size_t)w;
    }
}

int vibid_cfg_check_keys(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                         const char *const *known) {
    if (!group || !config_setting_is_group(group)) return 0;
    int n = config_setting_length(group);
    for (int i = 0; i < n; i++) {
        const config_setting_t *m = config_setting_get_elem(group, (unsigned)i);
        const char *name = config_setting_name(m);
        bool ok = false;
        for (const char *const *k = known; *k && name && !ok; k++) ok = strcmp(*k, name) == 0;
        if (ok) continue;
        char list[800] = "", f[192];
        for (const char *const *k = known; *k; k++) {
            strncat(list, *k, sizeof list - strlen(list) - 1);
            if (k[1]) strncat(list, ", ", sizeof list - strlen(list) - 1);
        }
        vibid_cfg_field(f, sizeof f, path, name);
        return vibid_cfg_fail(r, m, f, "unknown setting '%s' (known: %s)", name ? name : "?", list);
    }
    return 0;
}

/* The member `name` of group and its field path; NULL when group or the member is absent. */
static const config_setting_t *member(const config_setting_t *group, const char *path, const char *name,
                                      char *f, size_t cap) {
    vibid_cfg_field(f, cap, path, name);
    return group ? config_setting_get_member(group, name) : NULL;
}

int vibid_cfg_require(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                      const char *name, const char *what) {
    char f[192];
    if (member(group, path, name, f, sizeof f)) return 0;
    return vibid_cfg_fail(r, group, f, "missing (%s)", what);
}

int vibid_cfg_number(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                     const char *name, double lo, double hi, double *out) {
    char f[192];
    const config_setting_t *s = member(group, path, name, f, sizeof f);
    if (!s) return 0;
    int t = config_setting_type(s);
    double v;
    if (t == CONFIG_TYPE_FLOAT)
        v = config_setting_get_float(s);
    else if (t == CONFIG_TYPE_INT || t == CONFIG_TYPE_INT64)
        v = (double)config_setting_get_int64(s);
    else
        return vibid_cfg_fail(r, s, f, "must be a number");
    if (!isfinite(v)) return vibid_cfg_fail(r, s, f, "must be finite");
    if (v < lo || v > hi) return vibid_cfg_fail(r, s, f, "%g outside [%g, %g]", v, lo, hi);
    *out = v;
    return 1;
}

int vibid_cfg_int(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                  const char *name, long long lo, long long hi, long long *out) {
    char f[192];
    const config_setting_t *s = member(group, path, name, f, sizeof f);
    if (!s) return 0;
    int t = config_setting_type(s);
    if (t != CONFIG_TYPE_INT && t != CONFIG_TYPE_INT64) return vibid_cfg_fail(r, s, f, "must be an integer");
    long long v = config_setting_get_int64(s);
    if (v < lo || v > hi) return vibid_cfg_fail(r, s, f, "%lld outside [%lld, %lld]", v, lo, hi);
    *out = v;
    return 1;
}

int vibid_cfg_bool(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                   const char *name, bool *out) {
    char f[192];
    const config_setting_t *s = member(group, path, name, f, sizeof f);
    if (!s) return 0;
    if (config_setting_type(s) != CONFIG_TYPE_BOOL) return vibid_cfg_fail(r, s, f, "must be true or false");
    *out = config_setting_get_bool(s) != 0;
    return 1;
}

int vibid_cfg_string_ref(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                         const char *name, const char **out) {
    char f[192];
    const config_setting_t *s = member(group, path, name, f, sizeof f);
    if (!s) return 0;
    if (config_setting_type(s) != CONFIG_TYPE_STRING) return vibid_cfg_fail(r, s, f, "must be a string");
    const char *v = config_setting_get_string(s);
    if (!v || !*v) return vibid_cfg_fail(r, s, f, "must not be empty");
    *out = v;
    return 1;
}

int vibid_cfg_string(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                     const char *name, bool allow_empty, char *out, size_t cap) {
    char f[192];
    const config_setting_t *s = member(group, path, name, f, sizeof f);
    if (!s) return 0;
    if (config_setting_type(s) != CONFIG_TYPE_STRING) return vibid_cfg_fail(r, s, f, "must be a string");
    const char *v = config_setting_get_string(s);
    if (!allow_empty && !*v) return vibid_cfg_fail(r, s, f, "must not be empty");
    if (strlen(v) >= cap) return vibid_cfg_fail(r, s, f, "longer than %zu characters", cap - 1);
    snprintf(out, cap, "%s", v);
    return 1;
}

int vibid_cfg_enum(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                   const char *name, const char *const *names, bool case_fold, int *out) {
    char f[192];
    const config_setting_t *s = member(group, path, name, f, sizeof f);
    if (!s) return 0;
    char list[400] = "";
    for (const char *const *k = names; *k; k++) {
        strncat(list, *k, sizeof list - strlen(list) - 1);
        if (k[1]) strncat(list, ", ", sizeof list - strlen(list) - 1);
    }
    if (config_setting_type(s) != CONFIG_TYPE_STRING)
        return vibid_cfg_fail(r, s, f, "must be one of the strings %s", list);
    const char *v = config_setting_get_string(s);
    for (int i = 0; names[i]; i++)
        if (case_fold ? strcasecmp(names[i], v) == 0 : strcmp(names[i], v) == 0) {
            *out = i;
            return 1;
        }
    return vibid_cfg_fail(r, s, f, "'%s' is not one of %s", v, list);
}

int vibid_cfg_list(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                   const char *name, const config_setting_t **out) {
    char f[192];
    const config_setting_t *s = member(group, path, name, f, sizeof f);
    if (!s) return 0;
    if (!config_setting_is_list(s)) return vibid_cfg_fail(r, s, f, "must be a list ( {...}, {...} )");
    *out = s;
    return 1;
}

int vibid_cfg_path_of(const vibid_cfg_reader *r, const config_setting_t *s, const char *field,
                      const char *name, char *out, size_t cap) {
    if (!name || !*name) return vibid_cfg_fail(r, s, field, "must not be empty (a file name)");
    int n;
    if (name[0] == '/') {
        n = snprintf(out, cap, "%s", name);
    } else {
        const char *file = s && config_setting_source_file(s) ? config_setting_source_file(s) : r->file;
        char dir[1024];
        dir_of(file ? file : "", dir, sizeof dir);
        n = snprintf(out, cap, "%s/%s", dir, name); /* "./x" for a file in the working directory */
    }
    if (n < 0 || (size_t)n >= cap)
        return vibid_cfg_fail(r, s, field, "path longer than %zu characters", cap - 1);
    return 0;
}

int vibid_cfg_path(const vibid_cfg_reader *r, const config_setting_t *group, const char *path,
                   const char *name, char *out, size_t cap) {
    char f[192];
    const config_setting_t *s = member(group, path, name, f, sizeof f);
    if (!s) return 0;
    if (config_setting_type(s) != CONFIG_TYPE_STRING)
        return vibid_cfg_fail(r, s, f, "must be a string (a file name)");
    return vibid_cfg_path_of(r, s, f, config_setting_get_string(s), out, cap) ? -1 : 1;
}

/* The name as text that cannot break a line: printable ASCII as it is, anything else as
 * \xNN, at most 48 characters of it (then "..."). */
static void printable(char *out, size_t cap, const char *s)
{
    size_t o = 0;
    for (size_t i = 0; s[i] && o + 8 < cap; i++) {
        unsigned char ch = (unsigned char)s[i];
        if (i == 48) {
            o += (size_t)snprintf(out + o, cap - o, "...");
            break;
        }
        if (ch >= 0x20 && ch < 0x7f && ch != '\\')
            out[o++] = (char)ch;
        else
            o += (size_t)snprintf(out + o, cap - o, "\\x%02x", ch);
    }
    out[o < cap ? o : cap - 1] = '\0';
}

static bool name_char(char ch, bool first)
{
    return (ch >= 'A' && ch <= 'Z') || (ch >= 'a' && ch <= 'z') || (ch >= '0' && ch <= '9') || ch == '_' ||
           (!first && (ch == '-' || ch == '.'));
}

const char *vibid_cfg_name_problem(const char *s, char *why, size_t cap)
{
    static const char rule[] = "a name is 1..63 of A-Z a-z 0-9 _ - . (the first a letter, digit or '_')";
    char shown[256];
    size_t n = 0;
    while (s[n] && n <= VIBID_CFG_NAME_MAX) n++;
    if (n == 0) {
        snprintf(why, cap, "is empty: %s", rule);
        return why;
    }
    for (size_t i = 0; i < n; i++) {
        if (name_char(s[i], i == 0)) continue;
        unsigned char ch = (unsigned char)s[i];
        char what[16];
        if (ch >= 0x21 && ch < 0x7f && ch != '\\')
            snprintf(what, sizeof what, "'%c'", ch);
        else if (ch == ' ')
            snprintf(what, sizeof what, "a space");
        else if (ch == '\n' || ch == '\r')
            snprintf(what, sizeof what, "a line break");
        else if (ch == '\\')
            snprintf(what, sizeof what, "a backslash");
        else
            snprintf(what, sizeof what, "\\x%02x", ch);
        printable(shown, sizeof shown, s);
        snprintf(why, cap, "'%s' %s %s (character %zu): %s", shown, i == 0 && name_char(s[i], false) ? "begins with" : "contains",
                 what, i + 1, rule);
        return why;
    }
    if (n > VIBID_CFG_NAME_MAX) {
        printable(shown, sizeof shown, s);
        snprintf(why, cap, "'%s' is longer than %d characters: %s", shown, VIBID_CFG_NAME_MAX, rule);
        return why;
    }
    return NULL;
}

int vibid_cfg_check_name(const vibid_cfg_reader *r, const config_setting_t *s, const char *field, const char *value)
{
    char why[512];
    if (!value) return vibid_cfg_fail(r, s, field, "must be a string (a name)");
    return vibid_cfg_name_problem(value, why, sizeof why) ? vibid_cfg_fail(r, s, field, "%s", why) : 0;
}

int vibid_cfg_name(const vibid_cfg_reader *r, const config_setting_t *group, const char *path, const char *name,
                   const char **out)
{
    char f[192];
    const config_setting_t *s = member(group, path, name, f, sizeof f);
    if (!s) return 0;
    if (config_setting_type(s) != CONFIG_TYPE_STRING) return vibid_cfg_fail(r, s, f, "must be a string (a name)");
    const char *v = config_setting_get_string(s);
    if (vibid_cfg_check_name(r, s, f, v)) return -1;
    *out = v;
    return 1;
}
