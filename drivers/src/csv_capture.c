/* CSV capture reader: header row + numeric rows; bad rows are reported and skipped. */
#include <vibid_drivers/csv_capture.h>

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "file_util.h"
#include "num_parse.h"

struct vibid_csv_reader {
    FILE *fp;
    char name[256];
    vibid_line_reader lr;
    size_t ncols;
    char *names[VIBID_CSV_MAX_COLUMNS];
    vibid_csv_stats stats;
};

static const char *trim(const char *s, const char **end)
{
    while (s < *end && (*s == ' ' || *s == '\t'))
        s++;
    while (*end > s && ((*end)[-1] == ' ' || (*end)[-1] == '\t'))
        (*end)--;
    return s;
}

/* Next raw line that is not blank or a comment: 1 line, 0 EOF, -1 error. */
static int next_content_line(vibid_csv_reader *r, const char **line, size_t *len, bool *too_long)
{
    for (;;) {
        int rc = vibid_line_reader_next(&r->lr, line, len, too_long);
        if (rc <= 0)
            return rc;
        r->stats.lines++;
        /* a UTF-8 byte order mark before the first line (spreadsheet programs write one) is
         * not part of the first column's name: without this 't' read as "\xEF\xBB\xBFt" and
         * time_column 't' was "not in the header" */
        if (r->lr.line == 1 && *len >= 3 && memcmp(*line, "\xEF\xBB\xBF", 3) == 0) {
            *line += 3;
            *len -= 3;
        }
        const char *e = *line + *len;
        const char *s = trim(*line, &e);
        if (*too_long || (s < e && *s != '#'))
            return 1;
    }
}

static vibid_drv_status read_header(vibid_csv_reader *r, vibid_drv_error *err)
{
    const char *line;
    size_t len;
    bool too_long;
    int rc = next_content_line(r, &line, &len, &too_long);
    if (rc < 0)
        return vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: read error: %s", r->name, strerror(errno));
    if (rc == 0)
        return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s: empty file: no header row", r->name);
    unsigned long ln = r->lr.line;
    if (too_long || memchr(line, '\0', len))
        return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s:%lu: header row too long or holds a NUL byte",
                              r->name, ln);
    const char *p = line, *end = line + len;
    for (;;) {
        const char *c = memchr(p, ',', (size_t)(end - p));
        const char *fe = c ? c : end;
        const char *fs = trim(p, &fe);
        if (fs == fe)
            return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s:%lu: header column %zu has no name",
                                  r->name, ln, r->ncols + 1);
        if (r->ncols == VIBID_CSV_MAX_COLUMNS)
            return vibid_drv_fail(err, VIBID_DRV_E_RANGE, "%s:%lu: more than %d columns", r->name, ln,
                                  VIBID_CSV_MAX_COLUMNS);
        size_t n = (size_t)(fe - fs);
        char *nm = malloc(n + 1);
        if (!nm)
            return vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "%s: out of memory", r->name);
        memcpy(nm, fs, n);
        nm[n] = '\0';
        for (size_t i = 0; i < r->ncols; i++) {
            if (strcmp(r->names[i], nm) == 0) {
                vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%s:%lu: column name '%.60s' appears twice",
                               r->name, ln, nm);
                free(nm);
                return VIBID_DRV_E_SYNTAX;
            }
        }
        r->names[r->ncols++] = nm;
        if (!c)
            break;
        p = c + 1;
    }
    return VIBID_DRV_OK;
}

static vibid_csv_reader *finish_open(vibid_csv_reader *r, vibid_drv_error *err)
{
    if (read_header(r, err) != VIBID_DRV_OK) {
        vibid_csv_close(r);
        return NULL;
    }
    return r;
}

vibid_csv_reader *vibid_csv_open(const char *path, vibid_drv_error *err)
{
    if (!path) {
        vibid_drv_fail(err, VIBID_DRV_E_ARG, "vibid_csv_open: path is NULL");
        return NULL;
    }
    vibid_csv_reader *r = calloc(1, sizeof *r);
    if (!r) {
        vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "%s: out of memory", path);
        return NULL;
    }
    snprintf(r->name, sizeof r->name, "%s", path);
    r->fp = fopen(path, "rb");
    if (!r->fp) {
        vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: cannot open: %s", path, strerror(errno));
        free(r);
        return NULL;
    }
    vibid_line_reader_init_file(&r->lr, r->fp);
    return finish_open(r, err);
}

vibid_csv_reader *vibid_csv_open_mem(const char *data, size_t len, const char *name, vibid_drv_error *err)
{
    if (!data && len) {
        vibid_drv_fail(err, VIBID_DRV_E_ARG, "vibid_csv_open_mem: data is NULL");
        return NULL;
    }
    vibid_csv_reader *r = calloc(1, sizeof *r);
    if (!r) {
        vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "out of memory");
        return NULL;
    }
    snprintf(r->name, sizeof r->name, "%s", name ? name : "<memory>");
    vibid_line_reader_init_mem(&r->lr, data, len);
    return finish_open(r, err);
}

void vibid_csv_close(vibid_csv_reader *r)
{
    if (!r)
        return;
    for (size_t i = 0; i < r->ncols; i++)
        free(r->names[i]);
    if (r->fp)
        fclose(r->fp);
    free(r);
}

size_t vibid_csv_column_count(const vibid_csv_reader *r) { return r ? r->ncols : 0; }

const char *vibid_csv_column_name(const vibid_csv_reader *r, size_t i)
{
    return r && i < r->ncols ? r->names[i] : NULL;
}

int vibid_csv_find_column(const vibid_csv_reader *r, const char *name)
{
    if (!r || !name)
        return -1;
    for (size_t i = 0; i < r->ncols; i++)
        if (strcmp(r->names[i], name) == 0)
            return (int)i;
    return -1;
}

static vibid_drv_status bad_row(vibid_csv_reader *r, vibid_drv_error *err, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static vibid_drv_status bad_row(vibid_csv_reader *r, vibid_drv_error *err, const char *fmt, ...)
{
    char why[160];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(why, sizeof why, fmt, ap);
    va_end(ap);
    r->stats.bad_rows++;
    return vibid_drv_fail(err, VIBID_DRV_E_SYNTAX, "%.100s:%lu: %s", r->name, r->lr.line, why);
}

/* A row with a NUL byte anywhere is reported as such, whatever else is wrong with it.
 * The NUL is looked for only once the row has failed: a row that parses has none (the
 * fast number parser accepts digits, signs, '.' and 'e' only, and a field that goes to
 * strtod is checked before), so good rows are not scanned twice. */
#define BAD_ROW(...)                                                                                              \
    (memchr(text, '\0', len) ? bad_row(r, err, "NUL byte in line") : bad_row(r, err, __VA_ARGS__))

vibid_drv_status vibid_csv_next(vibid_csv_reader *r, double *values, unsigned long *line,
                                vibid_drv_error *err)
{
    if (!r || !values)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "vibid_csv_next: NULL argument");
    const char *text;
    size_t len;
    bool too_long;
    int rc = next_content_line(r, &text, &len, &too_long);
    if (rc < 0)
        return vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: read error: %s", r->name, strerror(errno));
    if (rc == 0)
        return VIBID_DRV_E_EOF;
    if (line)
        *line = r->lr.line;
    if (too_long)
        return bad_row(r, err, "line longer than %d characters", VIBID_LINE_MAX);
    double tmp[VIBID_CSV_MAX_COLUMNS];
    const char *p = text, *end = text + len;
    size_t col = 0;
    for (;;) {
        const char *c = memchr(p, ',', (size_t)(end - p));
        const char *fe = c ? c : end;
        const char *fs = trim(p, &fe);
        if (col == r->ncols)
            return BAD_ROW("more than %zu fields", r->ncols);
        char buf[64];
        size_t n = (size_t)(fe - fs);
        if (n == 0)
            return BAD_ROW("column '%.40s' is empty", r->names[col]);
        if (n >= sizeof buf)
            return BAD_ROW("column '%.40s': number too long", r->names[col]);
        double v;
        /* The exact fast parser answers for plain decimals (bit-identical to strtod,
         * num_parse.h); strtod keeps the last word on everything else. */
        if (!vibid_parse_decimal(fs, fe, &v)) {
            if (memchr(fs, '\0', n))
                return bad_row(r, err, "NUL byte in line");
            memcpy(buf, fs, n);
            buf[n] = '\0';
            char *ep;
            v = strtod(buf, &ep);
            if (*ep != '\0' || ep == buf)
                return BAD_ROW("column '%.40s': '%.40s' is not a number", r->names[col], buf);
            if (!isfinite(v))
                return BAD_ROW("column '%.40s': non-finite value '%.40s'", r->names[col], buf);
        }
        tmp[col++] = v;
        if (!c)
            break;
        p = c + 1;
    }
    if (col != r->ncols)
        return BAD_ROW("%zu fields, the header has %zu", col, r->ncols);
    memcpy(values, tmp, col * sizeof *values);
    r->stats.rows++;
    return VIBID_DRV_OK;
}

#undef BAD_ROW

void vibid_csv_stats_get(const vibid_csv_reader *r, vibid_csv_stats *stats)
{
    if (r && stats)
        *stats = r->stats;
}
