/* DBC subset reader and payload decoder; see vibid_drivers/dbc.h for what is read. */
#include <vibid_drivers/dbc.h>

#include <errno.h>
#include <stdarg.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "file_util.h"

#define DBC_EXT_FLAG 0x80000000u
#define DBC_INDEPENDENT_ID 0xC0000000u /* VECTOR__INDEPENDENT_SIG_MSG pseudo message */
#define DBC_MAX_NAME 128
#define VIBID_DBC_MAX_LEN_BYTES 64

typedef struct msg_build {
    vibid_dbc_message pub;
    vibid_dbc_signal *sigs;
    size_t n_sigs, cap_sigs;
} msg_build;

struct vibid_dbc {
    vibid_dbc_message *messages; /* sorted by (extended, id) */
    size_t n_messages;
    size_t skipped;
};

/* Parsing state: a cursor over the whole text. Only spaces, tabs and CR are
 * whitespace inside a statement; '\n' ends a line. */
typedef struct parser {
    const char *p, *end;
    unsigned line;
    const char *name;
    vibid_drv_error *err;
    msg_build *msgs;
    size_t n_msgs, cap_msgs;
    msg_build *current; /* message whose SG_ lines follow; NULL when none */
    bool skip_current;  /* current BO_ is the pseudo message: drop its signals */
    bool have_pseudo;   /* a pseudo message was declared, with this raw id */
    uint32_t pseudo_id;
    size_t skipped;
    /* deferred statements (they may name messages defined later) */
    struct deferred {
        unsigned line;
        uint32_t raw_id;
        char signal[DBC_MAX_NAME];
        int valtype; /* SIG_VALTYPE_: 0/1/2; SG_MUL_VAL_: -1 */
        char muxor[DBC_MAX_NAME];
        vibid_dbc_mux_range *ranges;
        size_t n_ranges;
    } *defs;
    size_t n_defs, cap_defs;
} parser;

static vibid_drv_status perr(parser *ps, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static vibid_drv_status perr(parser *ps, const char *fmt, ...)
{
    char buf[VIBID_DRV_ERROR_LEN];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    return vibid_drv_fail(ps->err, VIBID_DRV_E_SYNTAX, "%s:%u: %s", ps->name, ps->line, buf);
}

static bool is_hspace(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f'; }
static bool is_ident_start(char c)
{
    return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || c == '_';
}
static bool is_ident(char c) { return is_ident_start(c) || (c >= '0' && c <= '9'); }

static void skip_hspace(parser *ps)
{
    while (ps->p < ps->end && is_hspace(*ps->p))
        ps->p++;
}

static bool at_eol(parser *ps) { return ps->p >= ps->end || *ps->p == '\n'; }

/* Skips to the start of the next line (past '\n'). */
static void skip_line(parser *ps)
{
    while (ps->p < ps->end && *ps->p != '\n')
        ps->p++;
    if (ps->p < ps->end) {
        ps->p++;
        ps->line++;
    }
}

/* Skips a statement we do not interpret: up to ';' or end of line, whichever comes
 * first outside a string. Strings may span lines (CM_ comments do). */
static vibid_drv_status skip_statement(parser *ps)
{
    unsigned start = ps->line;
    bool in_str = false;
    while (ps->p < ps->end) {
        char c = *ps->p++;
        if (c == '\n') {
            ps->line++;
            if (!in_str)
                return VIBID_DRV_OK;
        } else if (in_str) {
            if (c == '\\' && ps->p < ps->end && ps->p[0] != '\n')
                ps->p++;
            else if (c == '"')
                in_str = false;
        } else if (c == '"') {
            in_str = true;
        } else if (c == ';') {
            skip_hspace(ps);
            return VIBID_DRV_OK;
        }
    }
    if (in_str) {
        ps->line = start;
        return perr(ps, "unterminated string (statement starts here)");
    }
    return VIBID_DRV_OK;
}

static bool read_ident(parser *ps, char *out, size_t cap)
{
    skip_hspace(ps);
    const char *s = ps->p;
    if (s >= ps->end || !is_ident_start(*s))
        return false;
    while (ps->p < ps->end && is_ident(*ps->p))
        ps->p++;
    size_t n = (size_t)(ps->p - s);
    if (n >= cap)
        return false;
    memcpy(out, s, n);
    out[n] = '\0';
    return true;
}

static bool expect(parser *ps, char c)
{
    skip_hspace(ps);
    if (ps->p < ps->end && *ps->p == c) {
        ps->p++;
        return true;
    }
    return false;
}

/* Unsigned decimal integer up to max. */
static bool read_uint(parser *ps, uint64_t max, uint64_t *out)
{
    skip_hspace(ps);
    const char *s = ps->p;
    uint64_t v = 0;
    while (ps->p < ps->end && *ps->p >= '0' && *ps->p <= '9') {
        unsigned d = (unsigned)(*ps->p - '0');
        if (v > (max - d) / 10)
            return false;
        v = v * 10 + d;
        ps->p++;
    }
    if (ps->p == s)
        return false;
    *out = v;
    return true;
}

/* A decimal floating-point number (strtod syntax, but no hex, inf or nan). */
static bool read_double(parser *ps, double *out)
{
    skip_hspace(ps);
    char buf[64];
    size_t n = 0;
    while (ps->p + n < ps->end && n < sizeof buf - 1) {
        char c = ps->p[n];
        if (!((c >= '0' && c <= '9') || c == '.' || c == '-' || c == '+' || c == 'e' || c == 'E'))
            break;
        buf[n] = c;
        n++;
    }
    if (n == 0 || n == sizeof buf - 1)
        return false;
    buf[n] = '\0';
    char *endp;
    errno = 0;
    double v = strtod(buf, &endp);
    /* ERANGE on underflow (1e-400) still gives a usable 0 or denormal; overflow gives
     * Inf, which isfinite rejects. */
    if (endp == buf || !isfinite(v))
        return false;
    ps->p += endp - buf;
    *out = v;
    return true;
}

/* A "string" on the current line (units never span lines); escapes kept verbatim. */
static bool read_string(parser *ps, char **out)
{
    skip_hspace(ps);
    if (ps->p >= ps->end || *ps->p != '"')
        return false;
    const char *s = ++ps->p;
    while (ps->p < ps->end && *ps->p != '"' && *ps->p != '\n') {
        if (*ps->p == '\\' && ps->p + 1 < ps->end && ps->p[1] != '\n')
            ps->p++;
        ps->p++;
    }
    if (ps->p >= ps->end || *ps->p != '"')
        return false;
    size_t n = (size_t)(ps->p - s);
    ps->p++;
    *out = malloc(n + 1);
    if (!*out)
        return false;
    memcpy(*out, s, n);
    (*out)[n] = '\0';
    return true;
}

static char *dup_str(const char *s)
{
    size_t n = strlen(s) + 1;
    char *d = malloc(n);
    if (d)
        memcpy(d, s, n);
    return d;
}

/* Payload bytes a signal needs. Intel: bits start..start+len-1 counting up.
 * Motorola: from the MSB at start_bit downwards in its byte, then whole following
 * bytes MSB first (the DBC "sawtooth" numbering). */
static unsigned needed_bytes(unsigned start, unsigned len, vibid_dbc_byte_order order)
{
    if (order == VIBID_DBC_INTEL)
        return (start + len - 1) / 8 + 1;
    unsigned first = start % 8 + 1; /* bits available in the first byte */
    unsigned bytes = start / 8 + 1;
    if (len > first)
        bytes += (len - first + 7) / 8;
    return bytes;
}

static void free_signal(vibid_dbc_signal *s)
{
    free((char *)s->name);
    free((char *)s->unit);
    free((vibid_dbc_mux_range *)s->mux_ranges);
}

static vibid_drv_status parse_bo(parser *ps)
{
    uint64_t raw_id, dlc;
    char name[DBC_MAX_NAME];
    if (!read_uint(ps, UINT32_MAX, &raw_id))
        return perr(ps, "BO_: expected a decimal message id");
    if (!read_ident(ps, name, sizeof name))
        return perr(ps, "BO_ %llu: expected a message name", (unsigned long long)raw_id);
    if (!expect(ps, ':'))
        return perr(ps, "BO_ %s: expected ':' after the name", name);
    if (!read_uint(ps, 255, &dlc))
        return perr(ps, "BO_ %s: expected the length in bytes", name);

    if (raw_id == DBC_INDEPENDENT_ID || strcmp(name, "VECTOR__INDEPENDENT_SIG_MSG") == 0) {
        ps->current = NULL;
        ps->skip_current = true;
        ps->have_pseudo = true;
        ps->pseudo_id = (uint32_t)raw_id;
        ps->skipped++;
        skip_line(ps);
        return VIBID_DRV_OK;
    }
    if (dlc > VIBID_DBC_MAX_LEN_BYTES)
        return perr(ps, "BO_ %s: length %llu bytes outside 0..64", name, (unsigned long long)dlc);
    bool ext = (raw_id & DBC_EXT_FLAG) != 0;
    uint32_t id = (uint32_t)raw_id & ~DBC_EXT_FLAG;
    if (ext ? id > 0x1FFFFFFFu : id > 0x7FFu)
        return perr(ps, "BO_ %s: id 0x%X too large for a %s identifier", name, (unsigned)id,
                    ext ? "29-bit" : "11-bit");
    if (ps->n_msgs == ps->cap_msgs) {
        size_t cap = ps->cap_msgs ? 2 * ps->cap_msgs : 16;
        msg_build *m = realloc(ps->msgs, cap * sizeof *m);
        if (!m)
            return vibid_drv_fail(ps->err, VIBID_DRV_E_NOMEM, "%s: out of memory", ps->name);
        ps->msgs = m;
        ps->cap_msgs = cap;
    }
    msg_build *mb = &ps->msgs[ps->n_msgs];
    memset(mb, 0, sizeof *mb);
    mb->pub.name = dup_str(name);
    if (!mb->pub.name)
        return vibid_drv_fail(ps->err, VIBID_DRV_E_NOMEM, "%s: out of memory", ps->name);
    ps->n_msgs++;
    mb->pub.id = id;
    mb->pub.extended = ext;
    mb->pub.length = (uint8_t)dlc;
    mb->pub.multiplexor = -1;
    mb->pub.line = ps->line;
    ps->current = mb;
    ps->skip_current = false;
    skip_line(ps); /* transmitter: not needed */
    return VIBID_DRV_OK;
}

static vibid_drv_status parse_sg(parser *ps)
{
    char name[DBC_MAX_NAME];
    if (!ps->current && !ps->skip_current)
        return perr(ps, "SG_ outside a message (no BO_ before it)");
    if (!read_ident(ps, name, sizeof name))
        return perr(ps, "SG_: expected a signal name");

    vibid_dbc_signal s;
    memset(&s, 0, sizeof s);
    s.line = ps->line;
    skip_hspace(ps);
    if (ps->p < ps->end && *ps->p == 'M') {
        ps->p++;
        s.mux_role = VIBID_DBC_MULTIPLEXOR;
    } else if (ps->p < ps->end && *ps->p == 'm') {
        ps->p++;
        uint64_t v;
        if (!read_uint(ps, UINT64_MAX, &v))
            return perr(ps, "SG_ %s: expected a multiplexer value after 'm'", name);
        if (ps->p < ps->end && *ps->p == 'M')
            return perr(ps, "SG_ %s: extended multiplexing (m<n>M) is not supported", name);
        s.mux_role = VIBID_DBC_MULTIPLEXED;
        vibid_dbc_mux_range *r = malloc(sizeof *r);
        if (!r)
            return vibid_drv_fail(ps->err, VIBID_DRV_E_NOMEM, "%s: out of memory", ps->name);
        r->lo = r->hi = v;
        s.mux_ranges = r;
        s.n_mux_ranges = 1;
    }
    vibid_drv_status st = VIBID_DRV_E_SYNTAX;
    uint64_t start = 0, len = 0; /* set by the parser before use; initialised for -O3 -Wmaybe-uninitialized */
    double factor, offset, mn, mx;
    char *unit = NULL;
    if (!expect(ps, ':')) {
        st = perr(ps, "SG_ %s: expected ':'", name);
    } else if (!read_uint(ps, 65535, &start) || !expect(ps, '|')) {
        st = perr(ps, "SG_ %s: expected <start bit>|<length>", name);
    } else if (!read_uint(ps, 255, &len) || !expect(ps, '@')) {
        st = perr(ps, "SG_ %s: expected <length>@<byte order>", name);
    } else if (ps->p >= ps->end || (*ps->p != '0' && *ps->p != '1')) {
        st = perr(ps, "SG_ %s: byte order must be @0 (Motorola) or @1 (Intel)", name);
    } else {
        s.byte_order = *ps->p++ == '1' ? VIBID_DBC_INTEL : VIBID_DBC_MOTOROLA;
        if (ps->p >= ps->end || (*ps->p != '+' && *ps->p != '-')) {
            st = perr(ps, "SG_ %s: expected '+' (unsigned) or '-' (signed) after @%d", name,
                      (int)s.byte_order);
        } else {
            s.is_signed = *ps->p++ == '-';
            if (!expect(ps, '(') || !read_double(ps, &factor) || !expect(ps, ',') ||
                !read_double(ps, &offset) || !expect(ps, ')'))
                st = perr(ps, "SG_ %s: expected (factor,offset) with finite numbers", name);
            else if (!expect(ps, '[') || !read_double(ps, &mn) || !expect(ps, '|') ||
                     !read_double(ps, &mx) || !expect(ps, ']'))
                st = perr(ps, "SG_ %s: expected [minimum|maximum] with finite numbers", name);
            else if (!read_string(ps, &unit))
                st = perr(ps, "SG_ %s: expected a \"unit\" string on the same line", name);
            else if (len < 1 || len > 64)
                st = perr(ps, "SG_ %s: length %llu bits outside 1..64", name, (unsigned long long)len);
            else
                st = VIBID_DRV_OK;
        }
    }
    if (st != VIBID_DRV_OK) {
        free(unit);
        free((vibid_dbc_mux_range *)s.mux_ranges);
        return st;
    }
    if (ps->skip_current) {
        free(unit);
        free((vibid_dbc_mux_range *)s.mux_ranges);
        ps->skipped++;
        skip_line(ps);
        return VIBID_DRV_OK;
    }
    s.start_bit = (uint16_t)start;
    s.length = (uint8_t)len;
    s.factor = factor;
    s.offset = offset;
    s.minimum = mn;
    s.maximum = mx;
    s.unit = unit;
    s.value_type = VIBID_DBC_INTEGER;
    msg_build *mb = ps->current;
    unsigned need = needed_bytes(s.start_bit, s.length, s.byte_order);
    if (s.start_bit >= 8u * VIBID_DBC_MAX_LEN_BYTES || need > mb->pub.length) {
        free(unit);
        free((vibid_dbc_mux_range *)s.mux_ranges);
        return perr(ps, "SG_ %s: start bit %u, length %u (@%d) does not fit message %s of %u bytes",
                    name, s.start_bit, s.length, (int)s.byte_order, mb->pub.name, mb->pub.length);
    }
    s.min_bytes = (uint8_t)need;
    for (size_t i = 0; i < mb->n_sigs; i++) {
        if (strcmp(mb->sigs[i].name, name) == 0) {
            free(unit);
            free((vibid_dbc_mux_range *)s.mux_ranges);
            return perr(ps, "SG_ %s: duplicate signal name in message %s (first at line %u)", name,
                        mb->pub.name, mb->sigs[i].line);
        }
    }
    if (s.mux_role == VIBID_DBC_MULTIPLEXOR) {
        if (mb->pub.multiplexor >= 0) {
            free(unit);
            return perr(ps, "SG_ %s: second multiplexor in message %s (extended multiplexing is not supported)",
                        name, mb->pub.name);
        }
        mb->pub.multiplexor = (int)mb->n_sigs;
    }
    if (mb->n_sigs == mb->cap_sigs) {
        size_t cap = mb->cap_sigs ? 2 * mb->cap_sigs : 8;
        vibid_dbc_signal *n = realloc(mb->sigs, cap * sizeof *n);
        if (!n) {
            free(unit);
            free((vibid_dbc_mux_range *)s.mux_ranges);
            return vibid_drv_fail(ps->err, VIBID_DRV_E_NOMEM, "%s: out of memory", ps->name);
        }
        mb->sigs = n;
        mb->cap_sigs = cap;
    }
    s.name = dup_str(name);
    if (!s.name) {
        free(unit);
        free((vibid_dbc_mux_range *)s.mux_ranges);
        return vibid_drv_fail(ps->err, VIBID_DRV_E_NOMEM, "%s: out of memory", ps->name);
    }
    mb->sigs[mb->n_sigs++] = s;
    skip_line(ps); /* receivers: not needed */
    return VIBID_DRV_OK;
}

static struct deferred *new_deferred(parser *ps)
{
    if (ps->n_defs == ps->cap_defs) {
        size_t cap = ps->cap_defs ? 2 * ps->cap_defs : 8;
        struct deferred *d = realloc(ps->defs, cap * sizeof *d);
        if (!d)
            return NULL;
        ps->defs = d;
        ps->cap_defs = cap;
    }
    struct deferred *d = &ps->defs[ps->n_defs++];
    memset(d, 0, sizeof *d);
    d->line = ps->line;
    return d;
}

/* SIG_VALTYPE_ <id> <signal> : <0|1|2> ; */
static vibid_drv_status parse_valtype(parser *ps)
{
    uint64_t id, vt;
    char name[DBC_MAX_NAME];
    if (!read_uint(ps, UINT32_MAX, &id) || !read_ident(ps, name, sizeof name) || !expect(ps, ':') ||
        !read_uint(ps, 9, &vt) || !expect(ps, ';'))
        return perr(ps, "SIG_VALTYPE_: expected <message id> <signal> : <0|1|2> ;");
    if (vt > 2)
        return perr(ps, "SIG_VALTYPE_ %s: value type %llu is not 0, 1 (float) or 2 (double)", name,
                    (unsigned long long)vt);
    struct deferred *d = new_deferred(ps);
    if (!d)
        return vibid_drv_fail(ps->err, VIBID_DRV_E_NOMEM, "%s: out of memory", ps->name);
    d->raw_id = (uint32_t)id;
    memcpy(d->signal, name, sizeof name);
    d->valtype = (int)vt;
    skip_line(ps);
    return VIBID_DRV_OK;
}

/* SG_MUL_VAL_ <id> <signal> <multiplexor> <lo>-<hi>[, <lo>-<hi>]* ; */
static vibid_drv_status parse_mul_val(parser *ps)
{
    uint64_t id;
    char name[DBC_MAX_NAME], muxor[DBC_MAX_NAME];
    if (!read_uint(ps, UINT32_MAX, &id) || !read_ident(ps, name, sizeof name) ||
        !read_ident(ps, muxor, sizeof muxor))
        return perr(ps, "SG_MUL_VAL_: expected <message id> <signal> <multiplexor> <ranges> ;");
    struct deferred *d = new_deferred(ps);
    if (!d)
        return vibid_drv_fail(ps->err, VIBID_DRV_E_NOMEM, "%s: out of memory", ps->name);
    d->raw_id = (uint32_t)id;
    memcpy(d->signal, name, sizeof name);
    memcpy(d->muxor, muxor, sizeof muxor);
    d->valtype = -1;
    size_t cap = 0;
    for (;;) {
        uint64_t lo, hi;
        if (!read_uint(ps, UINT64_MAX, &lo) || !expect(ps, '-') || !read_uint(ps, UINT64_MAX, &hi))
            return perr(ps, "SG_MUL_VAL_ %s: expected a range <lo>-<hi>", name);
        if (lo > hi)
            return perr(ps, "SG_MUL_VAL_ %s: range %llu-%llu is empty", name, (unsigned long long)lo,
                        (unsigned long long)hi);
        if (d->n_ranges == cap) {
            cap = cap ? 2 * cap : 4;
            vibid_dbc_mux_range *r = realloc(d->ranges, cap * sizeof *r);
            if (!r)
                return vibid_drv_fail(ps->err, VIBID_DRV_E_NOMEM, "%s: out of memory", ps->name);
            d->ranges = r;
        }
        d->ranges[d->n_ranges].lo = lo;
        d->ranges[d->n_ranges].hi = hi;
        d->n_ranges++;
        if (expect(ps, ';'))
            break;
        if (!expect(ps, ','))
            return perr(ps, "SG_MUL_VAL_ %s: expected ',' or ';' after a range", name);
    }
    skip_line(ps);
    return VIBID_DRV_OK;
}

static int cmp_msg(const void *a, const void *b)
{
    const msg_build *x = a, *y = b;
    if (x->pub.extended != y->pub.extended)
        return x->pub.extended ? 1 : -1;
    return x->pub.id < y->pub.id ? -1 : x->pub.id > y->pub.id;
}

static msg_build *find_build(parser *ps, uint32_t raw_id)
{
    bool ext = (raw_id & DBC_EXT_FLAG) != 0;
    uint32_t id = raw_id & ~DBC_EXT_FLAG;
    for (size_t i = 0; i < ps->n_msgs; i++)
        if (ps->msgs[i].pub.id == id && ps->msgs[i].pub.extended == ext)
            return &ps->msgs[i];
    return NULL;
}

static vibid_dbc_signal *find_sig_build(msg_build *mb, const char *name)
{
    for (size_t i = 0; i < mb->n_sigs; i++)
        if (strcmp(mb->sigs[i].name, name) == 0)
            return &mb->sigs[i];
    return NULL;
}

static vibid_drv_status apply_deferred(parser *ps)
{
    for (size_t i = 0; i < ps->n_defs; i++) {
        struct deferred *d = &ps->defs[i];
        ps->line = d->line;
        msg_build *mb = find_build(ps, d->raw_id);
        vibid_dbc_signal *s = mb ? find_sig_build(mb, d->signal) : NULL;
        if (!s && (d->raw_id == DBC_INDEPENDENT_ID || (ps->have_pseudo && d->raw_id == ps->pseudo_id))) {
            /* the pseudo message's signals are not decoded: nothing to apply */
            ps->skipped++;
            continue;
        }
        if (!s) {
            /* A value type or multiplex range for a signal that does not exist is a typo
             * that would silently decode the intended signal wrongly (a float read as an
             * integer): refused, as the file is inconsistent. */
            const char *what = d->valtype >= 0 ? "SIG_VALTYPE_" : "SG_MUL_VAL_";
            if (!mb)
                return perr(ps, "%s %lu %s: no message with this id", what, (unsigned long)d->raw_id, d->signal);
            return perr(ps, "%s %lu %s: message %s has no signal '%s'", what, (unsigned long)d->raw_id, d->signal,
                        mb->pub.name, d->signal);
        }
        if (d->valtype >= 0) {
            if (d->valtype == 1 && s->length != 32)
                return perr(ps, "SIG_VALTYPE_ %s: float needs a 32-bit signal, it has %u bits",
                            s->name, s->length);
            if (d->valtype == 2 && s->length != 64)
                return perr(ps, "SIG_VALTYPE_ %s: double needs a 64-bit signal, it has %u bits",
                            s->name, s->length);
            s->value_type = (vibid_dbc_value_type)d->valtype;
        } else {
            if (mb->pub.multiplexor < 0 || strcmp(mb->sigs[mb->pub.multiplexor].name, d->muxor) != 0)
                return perr(ps, "SG_MUL_VAL_ %s: '%s' is not the multiplexor of message %s "
                                "(only one multiplexor per message is supported)",
                            s->name, d->muxor, mb->pub.name);
            if (s->mux_role != VIBID_DBC_MULTIPLEXED)
                return perr(ps, "SG_MUL_VAL_ %s: signal is not multiplexed (no m<n>)", s->name);
            free((vibid_dbc_mux_range *)s->mux_ranges);
            s->mux_ranges = d->ranges;
            s->n_mux_ranges = d->n_ranges;
            d->ranges = NULL;
        }
    }
    for (size_t i = 0; i < ps->n_msgs; i++) {
        msg_build *mb = &ps->msgs[i];
        for (size_t j = 0; j < mb->n_sigs; j++) {
            if (mb->sigs[j].mux_role == VIBID_DBC_MULTIPLEXED && mb->pub.multiplexor < 0) {
                ps->line = mb->sigs[j].line;
                return perr(ps, "SG_ %s: multiplexed signal in message %s that has no multiplexor (M)",
                            mb->sigs[j].name, mb->pub.name);
            }
        }
    }
    if (ps->n_msgs > 1) /* qsort(NULL, 0, ...) is undefined: found by fuzz_dbc */
        qsort(ps->msgs, ps->n_msgs, sizeof *ps->msgs, cmp_msg);
    for (size_t i = 1; i < ps->n_msgs; i++) {
        if (cmp_msg(&ps->msgs[i - 1], &ps->msgs[i]) == 0) {
            const msg_build *a = &ps->msgs[i - 1], *b = &ps->msgs[i];
            ps->line = a->pub.line > b->pub.line ? a->pub.line : b->pub.line;
            return perr(ps, "BO_ %s: duplicate message id 0x%X (also %s at line %u)",
                        a->pub.line > b->pub.line ? a->pub.name : b->pub.name, (unsigned)a->pub.id,
                        a->pub.line > b->pub.line ? b->pub.name : a->pub.name,
                        a->pub.line > b->pub.line ? b->pub.line : a->pub.line);
        }
    }
    return VIBID_DRV_OK;
}

static void free_parser(parser *ps)
{
    for (size_t i = 0; i < ps->n_defs; i++)
        free(ps->defs[i].ranges);
    free(ps->defs);
    ps->defs = NULL;
}

static void free_builds(msg_build *msgs, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        for (size_t j = 0; j < msgs[i].n_sigs; j++)
            free_signal(&msgs[i].sigs[j]);
        free(msgs[i].sigs);
        free((char *)msgs[i].pub.name);
    }
    free(msgs);
}

static vibid_drv_status parse_all(parser *ps)
{
    bool in_ns = false;
    while (ps->p < ps->end) {
        const char *line_start = ps->p;
        skip_hspace(ps);
        if (at_eol(ps)) {
            skip_line(ps);
            continue;
        }
        bool indented = ps->p != line_start;
        if (in_ns) {
            if (indented) {
                skip_line(ps);
                continue;
            }
            in_ns = false;
        }
        char kw[DBC_MAX_NAME];
        unsigned char first = (unsigned char)*ps->p; /* not at EOL: checked above */
        if (!read_ident(ps, kw, sizeof kw)) {
            if (is_ident_start((char)first))
                return perr(ps, "keyword longer than %d characters", DBC_MAX_NAME - 1);
            return perr(ps, "expected a keyword at the start of the line, found byte 0x%02X", first);
        }
        vibid_drv_status st;
        if (strcmp(kw, "SG_") == 0) {
            st = parse_sg(ps);
        } else {
            /* Any other statement ends the BO_ block its SG_ lines belong to. */
            ps->current = NULL;
            ps->skip_current = false;
            if (strcmp(kw, "BO_") == 0) {
                st = parse_bo(ps);
            } else if (strcmp(kw, "SIG_VALTYPE_") == 0) {
                st = parse_valtype(ps);
            } else if (strcmp(kw, "SG_MUL_VAL_") == 0) {
                st = parse_mul_val(ps);
            } else if (strcmp(kw, "NS_") == 0) {
                in_ns = true;
                skip_line(ps);
                st = VIBID_DRV_OK;
            } else {
                ps->skipped++;
                st = skip_statement(ps);
            }
        }
        if (st != VIBID_DRV_OK)
            return st;
    }
    return VIBID_DRV_OK;
}

vibid_dbc *vibid_dbc_parse(const char *text, size_t len, const char *name, vibid_drv_error *err)
{
    if (!text && len) {
        vibid_drv_fail(err, VIBID_DRV_E_ARG, "vibid_dbc_parse: text is NULL");
        return NULL;
    }
    parser ps;
    memset(&ps, 0, sizeof ps);
    ps.p = text;
    ps.end = text + len;
    ps.line = 1;
    ps.name = name ? name : "<dbc>";
    ps.err = err;
    vibid_drv_status st = parse_all(&ps);
    if (st == VIBID_DRV_OK)
        st = apply_deferred(&ps);
    free_parser(&ps);
    vibid_dbc *dbc = NULL;
    if (st == VIBID_DRV_OK) {
        dbc = calloc(1, sizeof *dbc);
        if (dbc && ps.n_msgs)
            dbc->messages = calloc(ps.n_msgs, sizeof *dbc->messages);
        if (!dbc || (ps.n_msgs && !dbc->messages)) {
            free(dbc);
            dbc = NULL;
            vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "%s: out of memory", ps.name);
        }
    }
    if (!dbc) {
        free_builds(ps.msgs, ps.n_msgs);
        return NULL;
    }
    /* Hand the signal arrays over to the public messages. */
    for (size_t i = 0; i < ps.n_msgs; i++) {
        dbc->messages[i] = ps.msgs[i].pub;
        dbc->messages[i].signals = ps.msgs[i].sigs;
        dbc->messages[i].n_signals = ps.msgs[i].n_sigs;
    }
    dbc->n_messages = ps.n_msgs;
    dbc->skipped = ps.skipped;
    free(ps.msgs);
    return dbc;
}

vibid_dbc *vibid_dbc_load(const char *path, vibid_drv_error *err)
{
    if (!path) {
        vibid_drv_fail(err, VIBID_DRV_E_ARG, "vibid_dbc_load: path is NULL");
        return NULL;
    }
    size_t len;
    char *text = vibid_read_whole_file(path, 64u << 20, &len, err);
    if (!text)
        return NULL;
    vibid_dbc *dbc = vibid_dbc_parse(text, len, path, err);
    free(text);
    return dbc;
}

void vibid_dbc_destroy(vibid_dbc *dbc)
{
    if (!dbc)
        return;
    for (size_t i = 0; i < dbc->n_messages; i++) {
        vibid_dbc_message *m = &dbc->messages[i];
        for (size_t j = 0; j < m->n_signals; j++)
            free_signal((vibid_dbc_signal *)&m->signals[j]);
        free((vibid_dbc_signal *)m->signals);
        free((char *)m->name);
    }
    free(dbc->messages);
    free(dbc);
}

size_t vibid_dbc_message_count(const vibid_dbc *dbc) { return dbc ? dbc->n_messages : 0; }
size_t vibid_dbc_skipped_count(const vibid_dbc *dbc) { return dbc ? dbc->skipped : 0; }

const vibid_dbc_message *vibid_dbc_message_at(const vibid_dbc *dbc, size_t i)
{
    return dbc && i < dbc->n_messages ? &dbc->messages[i] : NULL;
}

const vibid_dbc_message *vibid_dbc_find_message(const vibid_dbc *dbc, uint32_t id, bool extended)
{
    if (!dbc)
        return NULL;
    size_t lo = 0, hi = dbc->n_messages;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        const vibid_dbc_message *m = &dbc->messages[mid];
        int c = m->extended != extended ? (m->extended ? 1 : -1) : (m->id < id ? -1 : m->id > id);
        if (c == 0)
            return m;
        if (c < 0)
            lo = mid + 1;
        else
            hi = mid;
    }
    return NULL;
}

const vibid_dbc_message *vibid_dbc_find_message_by_name(const vibid_dbc *dbc, const char *name)
{
    if (!dbc || !name)
        return NULL;
    for (size_t i = 0; i < dbc->n_messages; i++)
        if (strcmp(dbc->messages[i].name, name) == 0)
            return &dbc->messages[i];
    return NULL;
}

const vibid_dbc_signal *vibid_dbc_find_signal(const vibid_dbc_message *msg, const char *name)
{
    if (!msg || !name)
        return NULL;
    for (size_t i = 0; i < msg->n_signals; i++)
        if (strcmp(msg->signals[i].name, name) == 0)
            return &msg->signals[i];
    return NULL;
}

const vibid_dbc_signal *vibid_dbc_lookup_signal(const vibid_dbc *dbc, const char *name, const char *message,
                                                const vibid_dbc_message **msg_out,
                                                const vibid_dbc_message **second_out)
{
    const vibid_dbc_message *found = NULL;
    const vibid_dbc_signal *sig = NULL;
    if (msg_out)
        *msg_out = NULL;
    if (second_out)
        *second_out = NULL;
    for (size_t i = 0; dbc && name && i < vibid_dbc_message_count(dbc); i++) {
        const vibid_dbc_message *m = vibid_dbc_message_at(dbc, i);
        if (message && message[0] && strcmp(m->name, message) != 0)
            continue;
        const vibid_dbc_signal *s = vibid_dbc_find_signal(m, name);
        if (!s)
            continue;
        if (found) {
            if (second_out)
                *second_out = m;
            return NULL;
        }
        found = m;
        sig = s;
        if (msg_out)
            *msg_out = m;
    }
    return sig;
}

vibid_drv_status vibid_dbc_signal_raw(const vibid_dbc_signal *sig, const uint8_t *data, size_t len,
                                      uint64_t *raw)
{
    if (!sig || !raw || (!data && len))
        return VIBID_DRV_E_ARG;
    if (len < sig->min_bytes)
        return VIBID_DRV_E_SHORT;
    unsigned n = sig->length;
    size_t byte = sig->start_bit / 8u;
    uint64_t v;
    if (sig->byte_order == VIBID_DBC_INTEL) {
        unsigned shift = sig->start_bit % 8u;
        unsigned got = 8u - shift;
        v = (uint64_t)(data[byte++] >> shift);
        /* got < n <= 64 inside the loop, so every shift is below 64. */
        while (got < n) {
            v |= (uint64_t)data[byte++] << got;
            got += 8;
        }
    } else {
        unsigned avail = sig->start_bit % 8u + 1u; /* bits from the MSB at start_bit down */
        unsigned take = avail < n ? avail : n;
        v = (uint64_t)((data[byte++] >> (avail - take)) & ((1u << take) - 1u));
        unsigned rem = n - take;
        while (rem >= 8) {
            v = (v << 8) | data[byte++];
            rem -= 8;
        }
        if (rem)
            v = (v << rem) | (uint64_t)(data[byte] >> (8u - rem));
    }
    if (n < 64)
        v &= (UINT64_C(1) << n) - 1u;
    *raw = v;
    return VIBID_DRV_OK;
}

vibid_drv_status vibid_dbc_signal_decode(const vibid_dbc_signal *sig, const uint8_t *data,
                                         size_t len, double *phys)
{
    uint64_t raw;
    vibid_drv_status st = vibid_dbc_signal_raw(sig, data, len, &raw);
    if (st != VIBID_DRV_OK || !phys)
        return st ? st : VIBID_DRV_E_ARG;
    double x;
    if (sig->value_type == VIBID_DBC_FLOAT32) {
        uint32_t b = (uint32_t)raw;
        float f;
        memcpy(&f, &b, sizeof f);
        x = (double)f;
    } else if (sig->value_type == VIBID_DBC_FLOAT64) {
        memcpy(&x, &raw, sizeof x);
    } else if (sig->is_signed) {
        int64_t s;
        if (sig->length < 64 && (raw >> (sig->length - 1)) & 1u)
            raw |= ~((UINT64_C(1) << sig->length) - 1u); /* sign-extend */
        memcpy(&s, &raw, sizeof s);
        x = (double)s;
    } else {
        x = (double)raw;
    }
    *phys = x * sig->factor + sig->offset;
    return VIBID_DRV_OK;
}

/* Frame bit (byte * 8 + bit-in-byte) of the signal's bit i, counted from its LSB.
 * Intel: consecutive from start_bit upwards. Motorola: start_bit is the MSB; going
 * towards the LSB the bit number falls within a byte and continues at bit 7 of the next
 * byte (the DBC "sawtooth"), so the LSB is n-1 such steps after start_bit. */
static unsigned frame_bit(const vibid_dbc_signal *sig, unsigned i)
{
    if (sig->byte_order == VIBID_DBC_INTEL)
        return sig->start_bit + i;
    unsigned pos = sig->start_bit;
    for (unsigned j = sig->length - 1u; j > i; j--)
        pos = (pos % 8u == 0u) ? pos + 15u : pos - 1u;
    return pos;
}

vibid_drv_status vibid_dbc_signal_put_raw(const vibid_dbc_signal *sig, uint8_t *data, size_t len, uint64_t raw)
{
    if (!sig || (!data && len))
        return VIBID_DRV_E_ARG;
    if (len < sig->min_bytes)
        return VIBID_DRV_E_SHORT;
    /* Bit by bit: recording runs at the sample rate (a few 10^4 signals per second), and
     * this form is the plainest inverse of vibid_dbc_signal_raw. */
    for (unsigned i = 0; i < sig->length; i++) {
        unsigned pos = frame_bit(sig, i);
        uint8_t mask = (uint8_t)(1u << (pos % 8u));
        if ((raw >> i) & 1u)
            data[pos / 8u] |= mask;
        else
            data[pos / 8u] &= (uint8_t)~mask;
    }
    return VIBID_DRV_OK;
}

vibid_drv_status vibid_dbc_signal_encode(const vibid_dbc_signal *sig, double phys, uint8_t *data, size_t len)
{
    if (!sig)
        return VIBID_DRV_E_ARG;
    double x = (phys - sig->offset) / sig->factor;
    uint64_t raw;
    if (sig->value_type == VIBID_DBC_FLOAT32) {
        float f = (float)x;
        uint32_t b;
        memcpy(&b, &f, sizeof b);
        raw = b;
    } else if (sig->value_type == VIBID_DBC_FLOAT64) {
        memcpy(&raw, &x, sizeof raw);
    } else {
        unsigned n = sig->length;
        double r = nearbyint(x);
        if (!isfinite(r))
            return VIBID_DRV_E_RANGE;
        if (sig->is_signed) {
            double lo = -ldexp(1.0, (int)n - 1), hi = ldexp(1.0, (int)n - 1); /* [lo, hi) */
            if (!(r >= lo && r < hi))
                return VIBID_DRV_E_RANGE;
            int64_t s = (int64_t)r;
            memcpy(&raw, &s, sizeof raw);
        } else {
            if (!(r >= 0.0 && r < ldexp(1.0, (int)n)))
                return VIBID_DRV_E_RANGE;
            raw = (uint64_t)r;
        }
        if (n < 64)
            raw &= (UINT64_C(1) << n) - 1u;
    }
    return vibid_dbc_signal_put_raw(sig, data, len, raw);
}

static bool mux_selected(const vibid_dbc_signal *s, uint64_t muxval)
{
    for (size_t i = 0; i < s->n_mux_ranges; i++)
        if (muxval >= s->mux_ranges[i].lo && muxval <= s->mux_ranges[i].hi)
            return true;
    return false;
}

vibid_drv_status vibid_dbc_message_decode(const vibid_dbc_message *msg, const uint8_t *data,
                                          size_t len, double *values, uint8_t *present)
{
    if (!msg || !values || !present || (!data && len))
        return VIBID_DRV_E_ARG;
    vibid_drv_status result = VIBID_DRV_OK;
    bool have_mux = false;
    uint64_t muxval = 0;
    if (msg->multiplexor >= 0)
        have_mux = vibid_dbc_signal_raw(&msg->signals[msg->multiplexor], data, len, &muxval) ==
                   VIBID_DRV_OK;
    for (size_t i = 0; i < msg->n_signals; i++) {
        const vibid_dbc_signal *s = &msg->signals[i];
        present[i] = 0;
        values[i] = NAN;
        if (s->mux_role == VIBID_DBC_MULTIPLEXED && (!have_mux || !mux_selected(s, muxval)))
            continue;
        if (vibid_dbc_signal_decode(s, data, len, &values[i]) == VIBID_DRV_OK)
            present[i] = 1;
        else
            result = VIBID_DRV_E_SHORT;
    }
    return result;
}
