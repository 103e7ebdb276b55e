/* candump .log reader: the line grammar of can-utils (lib.c parse_canframe and
 * candump.c's log output), plus the variants newer can-utils and python-can write.
 * Every malformed line becomes a BAD_LINE entry with a reason; nothing is fatal. */
#include <vibid_drivers/candump.h>

#include <errno.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

#include "candump_internal.h"
#include "file_util.h"
#include "swar.h"

#define CAN_ERR_FLAG_BIT 0x20000000u
#define CAN_ERR_MASK_BITS 0x1FFFFFFFu

struct vibid_candump_reader {
    FILE *fp;
    char name[256];
    vibid_line_reader lr;
    vibid_candump_stats stats;
};

static vibid_candump_kind bad(vibid_candump_entry *e, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));
static vibid_candump_kind bad(vibid_candump_entry *e, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(e->text, sizeof e->text, fmt, ap);
    va_end(ap);
    e->kind = VIBID_CANDUMP_BAD_LINE;
    return e->kind;
}

/* Hex digit value, -1 for anything else: a table, since this runs ~20 times per line. */
static const signed char hex_table[256] = {
    ['0'] = 1,  ['1'] = 2,  ['2'] = 3,  ['3'] = 4,  ['4'] = 5,  ['5'] = 6,  ['6'] = 7,  ['7'] = 8,
    ['8'] = 9,  ['9'] = 10, ['A'] = 11, ['B'] = 12, ['C'] = 13, ['D'] = 14, ['E'] = 15, ['F'] = 16,
    ['a'] = 11, ['b'] = 12, ['c'] = 13, ['d'] = 14, ['e'] = 15, ['f'] = 16,
}; /* value + 1, so that the zero-initialised rest means "not hex" */

static int hexval(char c) { return hex_table[(unsigned char)c] - 1; }

static bool is_space(char c) { return c == ' ' || c == '\t'; }

/* "DROPCOUNT: dropped N CAN frame[s] on 'IFACE' socket (total drops M)" */
static vibid_candump_kind parse_dropcount(const char *s, const char *end, vibid_candump_entry *e)
{
    static const char head[] = "DROPCOUNT: dropped ";
    const char *p = s + sizeof head - 1;
    unsigned long long n = 0, total = 0;
    const char *d = p;
    while (p < end && *p >= '0' && *p <= '9' && n <= UINT32_MAX)
        n = n * 10 + (unsigned)(*p++ - '0');
    if (p == d || n > UINT32_MAX)
        return bad(e, "DROPCOUNT line without a valid frame count");
    /* The total is the last number in parentheses; the interface name between may
     * hold anything, so search from the end. */
    const char *t = end;
    while (t > p && t[-1] != '(')
        t--;
    static const char tot[] = "total drops ";
    if (t == p || (size_t)(end - t) < sizeof tot || memcmp(t, tot, sizeof tot - 1) != 0) {
        e->dropped = (uint32_t)n;
        e->total_drops = 0; /* older formats omit the total: the count alone is enough */
    } else {
        t += sizeof tot - 1;
        d = t;
        while (t < end && *t >= '0' && *t <= '9' && total <= UINT32_MAX)
            total = total * 10 + (unsigned)(*t++ - '0');
        if (t == d || total > UINT32_MAX || t >= end || *t != ')')
            return bad(e, "DROPCOUNT line with a malformed total");
        e->dropped = (uint32_t)n;
        e->total_drops = (uint32_t)total;
    }
    e->kind = VIBID_CANDUMP_DROPCOUNT;
    return e->kind;
}

/* Parses "ID#..." between s and end into f. */
static vibid_candump_kind parse_frame(const char *s, const char *end, vibid_candump_entry *e)
{
    vibid_can_frame *f = &e->frame;
    size_t idlen = 0;
    while (s + idlen < end && s[idlen] != '#')
        idlen++;
    if (s + idlen >= end)
        return bad(e, "frame without '#' after the identifier");
    if (idlen != 3 && idlen != 8)
        return bad(e, "identifier must have 3 (11-bit) or 8 (29-bit) hex digits, has %zu", idlen);
    uint32_t id = 0;
    for (size_t i = 0; i < idlen; i++) {
        int h = hexval(s[i]);
        if (h < 0)
            return bad(e, "identifier has a non-hex character");
        id = (id << 4) | (uint32_t)h;
    }
    if (idlen == 3) {
        if (id > 0x7FF)
            return bad(e, "11-bit identifier 0x%03X above 0x7FF", (unsigned)id);
        f->id = id;
    } else if (id & CAN_ERR_FLAG_BIT) {
        f->flags |= VIBID_CAN_F_ERR;
        f->id = id & CAN_ERR_MASK_BITS;
    } else if (id > CAN_ERR_MASK_BITS) {
        return bad(e, "29-bit identifier 0x%08X has flag bits set", (unsigned)id);
    } else {
        f->flags |= VIBID_CAN_F_EXT;
        f->id = id;
    }
    const char *p = s + idlen + 1;
    size_t maxlen = VIBID_CAN_MAX_DLEN;
    if (p < end && (*p == 'R' || *p == 'r')) {
        if (f->flags & VIBID_CAN_F_ERR)
            return bad(e, "error frame cannot be a remote request");
        f->flags |= VIBID_CAN_F_RTR;
        p++;
        if (p < end) {
            int h = hexval(*p);
            if (h < 0 || h > 8 || p + 1 != end)
                return bad(e, "remote request length must be one digit 0..8");
            f->len = (uint8_t)h;
        }
        return e->kind = VIBID_CANDUMP_FRAME;
    }
    if (p < end && *p == '#') {
        if (f->flags & VIBID_CAN_F_ERR)
            return bad(e, "error frame cannot be a CAN FD frame");
        p++;
        int h = p < end ? hexval(*p) : -1;
        if (h < 0)
            return bad(e, "CAN FD frame needs a flags nibble after '##'");
        f->flags |= VIBID_CAN_F_FD;
        f->fd_flags = (uint8_t)h;
        memset(f->data + VIBID_CAN_MAX_DLEN, 0, VIBID_CANFD_MAX_DLEN - VIBID_CAN_MAX_DLEN);
        p++;
        maxlen = VIBID_CANFD_MAX_DLEN;
    }
    size_t n = 0;
    while (p < end) {
        if (*p == '.') {
            p++;
            continue;
        }
        if (*p == '_') /* classic len8_dlc suffix "_<dlc>" (9..F): payload stays 8 bytes */
            break;
        if (n == maxlen)
            return bad(e, "more than %zu data bytes", maxlen);
        int hi = hexval(*p), lo = p + 1 < end ? hexval(p[1]) : -1;
        if (hi < 0 || lo < 0)
            return bad(e, "data byte %zu is not two hex digits", n);
        f->data[n++] = (uint8_t)(hi << 4 | lo);
        p += 2;
    }
    if (p < end) { /* "_X" */
        int d = p + 1 < end ? hexval(p[1]) : -1;
        if ((f->flags & VIBID_CAN_F_FD) || n != 8 || d < 9 || p + 2 != end)
            return bad(e, "malformed len8_dlc suffix (only '_9'.. '_F' after 8 classic bytes)");
    }
    if ((f->flags & VIBID_CAN_F_FD) && n > 8) {
        /* CAN FD lengths above 8 come in DLC steps. */
        static const uint8_t ok[] = {12, 16, 20, 24, 32, 48, 64};
        bool valid = false;
        for (size_t i = 0; i < sizeof ok; i++)
            valid |= n == ok[i];
        if (!valid)
            return bad(e, "CAN FD payload of %zu bytes is not a valid FD length", n);
    }
    f->len = (uint8_t)n;
    return e->kind = VIBID_CANDUMP_FRAME;
}

vibid_candump_kind vibid_candump_parse_line_general(const char *line, size_t len, vibid_candump_entry *e)
{
    /* Reset what a parse sets; the 192-byte text only needs its terminator (this runs
     * once per frame on replay, where a full memset was a measurable share). */
    e->kind = VIBID_CANDUMP_EMPTY;
    vibid_can_frame *f = &e->frame; /* field by field: a 96-byte memset was 15 % of the parse */
    f->t_ns = 0;
    f->id = 0;
    f->flags = f->fd_flags = f->len = 0;
    memset(f->data, 0, VIBID_CAN_MAX_DLEN); /* classic payload; a CAN FD frame clears the rest */
    f->iface[0] = '\0';
    e->dropped = e->total_drops = 0;
    e->text[0] = '\0';
    const char *p = line, *end = line + len;
    if (memchr(line, '\0', len))
        return bad(e, "NUL byte in line");
    while (end > p && (end[-1] == ' ' || end[-1] == '\t' || end[-1] == '\r'))
        end--;
    while (p < end && is_space(*p))
        p++;
    if (p == end)
        return e->kind = VIBID_CANDUMP_EMPTY;
    if ((size_t)(end - p) >= 19 && memcmp(p, "DROPCOUNT: dropped ", 19) == 0)
        return parse_dropcount(p, end, e);
    if (*p != '(')
        return bad(e, "expected '(' starting a timestamp");
    p++;
    uint64_t sec = 0;
    const char *d = p;
    while (p < end && *p >= '0' && *p <= '9') {
        if (sec > 9223372035u) /* keeps sec * 1e9 + ns inside int64 */
            return bad(e, "timestamp seconds too large");
        sec = sec * 10 + (unsigned)(*p++ - '0');
    }
    if (p == d || p >= end || *p != '.')
        return bad(e, "timestamp must be (SECONDS.FRACTION)");
    p++;
    d = p;
    uint64_t frac = 0;
    while (p < end && *p >= '0' && *p <= '9' && p - d < 10)
        frac = frac * 10 + (unsigned)(*p++ - '0');
    size_t nd = (size_t)(p - d);
    if (p >= end || *p != ')')
        return bad(e, "timestamp fraction must be digits followed by ')'");
    if (nd != 6 && nd != 9)
        return bad(e, "timestamp fraction has %zu digits, expected 6 (us) or 9 (ns)", nd);
    if (sec > 9223372035u)
        return bad(e, "timestamp seconds too large");
    e->frame.t_ns = (int64_t)(sec * 1000000000u + (nd == 6 ? frac * 1000u : frac));
    p++;
    if (p >= end || !is_space(*p))
        return bad(e, "expected a space after the timestamp");
    while (p < end && is_space(*p))
        p++;
    const char *ifs = p;
    while (p < end && !is_space(*p))
        p++;
    size_t iflen = (size_t)(p - ifs);
    if (iflen == 0 || p == end)
        return bad(e, "expected an interface name and a frame after the timestamp");
    if (iflen >= VIBID_CAN_IFNAMSIZ)
        return bad(e, "interface name longer than %d characters", VIBID_CAN_IFNAMSIZ - 1);
    memcpy(e->frame.iface, ifs, iflen);
    e->frame.iface[iflen] = '\0';
    while (p < end && is_space(*p))
        p++;
    const char *fs = p;
    while (p < end && !is_space(*p))
        p++;
    const char *fe = p;
    while (p < end && is_space(*p))
        p++;
    if (p < end) {
        /* candump -x appends the direction; nothing else may follow the frame. */
        if (p + 1 == end && (*p == 'R' || *p == 'T')) {
            if (*p == 'T')
                e->frame.flags |= VIBID_CAN_F_TX;
        } else {
            return bad(e, "unexpected text after the frame (only ' R' or ' T' may follow)");
        }
    }
    return parse_frame(fs, fe, e);
}

static bool is_digit(char c) { return (unsigned)(c - '0') < 10u; }

#if VIBID_SWAR
#define HAVE_SWAR 1
#define BYTES VIBID_BYTES
#define load8 vibid_load8
#define in_range vibid_swar_in_range
#define eight_digits vibid_swar_eight_digits
#define eight_digits_value vibid_swar_eight_digits_value

/* Eight hex digits (either case) -> four bytes, the first pair in the lowest byte (the
 * payload's byte order on this little-endian host); false if any byte is not a hex digit. */
static bool eight_hex(uint64_t v, uint32_t *out)
{
    if (v & BYTES(0x80))
        return false;
    uint64_t dig = in_range(v, '0', '9');
    uint64_t let = in_range(v, 'A', 'F') | in_range(v, 'a', 'f');
    if ((dig | let) != BYTES(0x80))
        return false;
    uint64_t nib = (v & BYTES(0x0F)) + (let >> 7) * 9;         /* 0..15 per byte */
    uint64_t t = ((nib << 4) | (nib >> 8)) & UINT64_C(0x00FF00FF00FF00FF); /* pairs in even bytes */
    t = (t | (t >> 8)) & UINT64_C(0x0000FFFF0000FFFF);
    t = (t | (t >> 16)) & UINT64_C(0x00000000FFFFFFFF);
    *out = (uint32_t)t;
    return true;
}
#else
#define HAVE_SWAR 0
#endif

/* The canonical line that candump -l, vibid-sim and vibidd's recorder write:
 * "(SECONDS.FFFFFF) IFACE III#HHHH..." with 6 or 9 fraction digits, single spaces, a 3-
 * or 8-hex-digit data frame id (no error flag) and 0..8 data bytes as hex pairs without
 * separators. Everything the general parser does per line (skip blanks, look for
 * DROPCOUNT, tolerate padding and suffixes, check for NUL bytes) is spent on what this
 * form never has; the replay of a candump log is 3 lines per sample, so the saving counts.
 * Fills *e exactly as vibid_candump_parse_line_general does for such a line (the fields it
 * sets, the payload bytes after len zeroed) and returns true; returns false without
 * writing to *e for any other line. Every byte it accepts is checked (a NUL is
 * never a digit, hex digit or interface character), so no separate NUL scan is needed. */
bool vibid_candump_parse_line_fast(const char *line, size_t len, vibid_candump_entry *e)
{
    const char *p = line, *end = line + len;
    if (len < 17 || *p != '(') /* shortest: "(0.000000) a 123#" */
        return false;
    p++;
    uint64_t sec = 0, frac = 0;
    size_t nd;
#if HAVE_SWAR
    /* candump's own "(%010llu.%06llu) ": ten and six digits at fixed places (len >= 24
     * covers the 8-byte loads up to line[17]). bytes 10..17 = "D.DDDDDD": the first two
     * replaced by "00" they are the fraction as eight digits. */
    if (len >= 24 && line[11] == '.' && line[18] == ')' && line[19] == ' ' && is_digit(line[9]) &&
        is_digit(line[10])) {
        uint64_t hi8 = load8(line + 1), fr8 = (load8(line + 10) & ~UINT64_C(0xFFFF)) | 0x3030u;
        if (eight_digits(hi8) && eight_digits(fr8)) {
            sec = (uint64_t)eight_digits_value(hi8) * 100u + (unsigned)(line[9] - '0') * 10u +
                  (unsigned)(line[10] - '0');
            frac = eight_digits_value(fr8);
            nd = 6;
            p = line + 20;
            goto iface; /* the seconds' bound is checked there for both ways in */
        }
    }
#endif
    const char *d = p;
    while (p < end && is_digit(*p)) {
        sec = sec * 10 + (unsigned)(*p++ - '0');
        if (p - d > 10)
            return false; /* more than 10 digits: let the general parser judge */
    }
    if (p == d || p >= end || *p != '.')
        return false;
    p++;
    d = p;
    while (p < end && is_digit(*p) && p - d < 10)
        frac = frac * 10 + (unsigned)(*p++ - '0');
    nd = (size_t)(p - d);
    if ((nd != 6 && nd != 9) || p + 1 >= end || p[0] != ')' || p[1] != ' ')
        return false;
    p += 2;
#if HAVE_SWAR
iface:
#endif
    if (sec > 9223372035u) /* keeps sec * 1e9 + ns inside int64, as the general parser */
        return false;
    const char *ifs = p;
    while (p < end && (unsigned char)*p > ' ') /* no space, tab, control byte or NUL */
        p++;
    size_t iflen = (size_t)(p - ifs);
    if (iflen == 0 || iflen >= VIBID_CAN_IFNAMSIZ || p >= end || *p != ' ')
        return false;
    p++;
    const char *ids = p;
    uint32_t id = 0;
    int h;
    while (p < end && (h = hexval(*p)) >= 0 && p - ids < 9) {
        id = (id << 4) | (uint32_t)h;
        p++;
    }
    size_t idlen = (size_t)(p - ids);
    if (p >= end || *p != '#')
        return false;
    uint8_t flags = 0;
    if (idlen == 3) {
        if (id > 0x7FF)
            return false;
    } else if (idlen == 8) {
        if (id > CAN_ERR_MASK_BITS) /* error frames and flag bits: general parser */
            return false;
        flags = VIBID_CAN_F_EXT;
    } else {
        return false;
    }
    p++;
    size_t ndig = (size_t)(end - p);
    if (ndig > 2 * VIBID_CAN_MAX_DLEN || (ndig & 1u))
        return false; /* RTR, CAN FD, separators, suffixes, odd digits, trailing text */
    uint8_t data[VIBID_CAN_MAX_DLEN] = {0};
#if HAVE_SWAR
    /* The payload is assembled in a register and stored once: bytes written one by one
     * (or four at a time) and then copied as 8 would stall on store forwarding. */
    uint64_t word = 0;
    size_t i = 0;
    for (; 2 * i + 8 <= ndig; i += 4) {
        uint32_t four;
        if (!eight_hex(load8(p + 2 * i), &four))
            return false;
        word |= (uint64_t)four << (8 * i);
    }
    for (; i < ndig / 2; i++) {
        int hi = hexval(p[2 * i]), lo = hexval(p[2 * i + 1]);
        if ((hi | lo) < 0)
            return false;
        word |= (uint64_t)(hi << 4 | lo) << (8 * i);
    }
    memcpy(data, &word, sizeof data);
#else
    for (size_t i = 0; i < ndig / 2; i++) {
        int hi = hexval(p[2 * i]), lo = hexval(p[2 * i + 1]);
        if ((hi | lo) < 0)
            return false;
        data[i] = (uint8_t)(hi << 4 | lo);
    }
#endif
    vibid_can_frame *f = &e->frame;
    f->t_ns = (int64_t)(sec * 1000000000u + (nd == 6 ? frac * 1000u : frac));
    f->id = id;
    f->flags = flags;
    f->fd_flags = 0;
    f->len = (uint8_t)(ndig / 2);
    memcpy(f->data, data, sizeof data);
    /* The id and '#' follow the name, so 16 bytes from ifs lie inside the line when the
     * line is that long: one fixed-size copy instead of a call. The bytes after the NUL
     * are as undefined as the general parser leaves them. */
    if ((size_t)(end - ifs) >= VIBID_CAN_IFNAMSIZ)
        memcpy(f->iface, ifs, VIBID_CAN_IFNAMSIZ);
    else
        memcpy(f->iface, ifs, iflen);
    f->iface[iflen] = '\0';
    e->dropped = e->total_drops = 0;
    e->text[0] = '\0';
    e->kind = VIBID_CANDUMP_FRAME;
    return true;
}

vibid_candump_kind vibid_candump_parse_line(const char *line, size_t len, vibid_candump_entry *e)
{
    if (vibid_candump_parse_line_fast(line, len, e))
        return VIBID_CANDUMP_FRAME;
    return vibid_candump_parse_line_general(line, len, e);
}

static vibid_candump_reader *reader_new(const char *name, vibid_drv_error *err)
{
    vibid_candump_reader *r = calloc(1, sizeof *r);
    if (!r) {
        vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "%s: out of memory", name);
        return NULL;
    }
    snprintf(r->name, sizeof r->name, "%s", name);
    return r;
}

vibid_candump_reader *vibid_candump_reader_open(const char *path, vibid_drv_error *err)
{
    if (!path) {
        vibid_drv_fail(err, VIBID_DRV_E_ARG, "vibid_candump_reader_open: path is NULL");
        return NULL;
    }
    FILE *fp = fopen(path, "rb");
    if (!fp) {
        vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: cannot open: %s", path, strerror(errno));
        return NULL;
    }
    vibid_candump_reader *r = reader_new(path, err);
    if (!r) {
        fclose(fp);
        return NULL;
    }
    r->fp = fp;
    vibid_line_reader_init_file(&r->lr, fp);
    return r;
}

vibid_candump_reader *vibid_candump_reader_open_mem(const char *data, size_t len, const char *name,
                                                    vibid_drv_error *err)
{
    if (!data && len) {
        vibid_drv_fail(err, VIBID_DRV_E_ARG, "vibid_candump_reader_open_mem: data is NULL");
        return NULL;
    }
    vibid_candump_reader *r = reader_new(name ? name : "<memory>", err);
    if (r)
        vibid_line_reader_init_mem(&r->lr, data, len);
    return r;
}

vibid_drv_status vibid_candump_reader_next(vibid_candump_reader *r, vibid_candump_entry *e)
{
    if (!r || !e)
        return VIBID_DRV_E_ARG;
    for (;;) {
        const char *line;
        size_t len;
        bool too_long;
        int rc = vibid_line_reader_next(&r->lr, &line, &len, &too_long);
        if (rc == 0)
            return VIBID_DRV_E_EOF;
        if (rc < 0) {
            memset(e, 0, sizeof *e);
            snprintf(e->text, sizeof e->text, "%.100s:%lu: read error: %.60s", r->name, r->lr.line + 1,
                     strerror(errno));
            return VIBID_DRV_E_IO;
        }
        r->stats.lines++;
        e->line = r->lr.line;
        vibid_candump_kind k;
        if (too_long) {
            memset(e, 0, sizeof *e);
            e->line = r->lr.line;
            k = bad(e, "line longer than %d characters", VIBID_LINE_MAX);
        } else {
            k = vibid_candump_parse_line(line, len, e);
        }
        switch (k) {
        case VIBID_CANDUMP_EMPTY:
            continue;
        case VIBID_CANDUMP_FRAME:
            r->stats.frames++;
            if (e->frame.flags & VIBID_CAN_F_ERR)
                r->stats.error_frames++;
            return VIBID_DRV_OK;
        case VIBID_CANDUMP_DROPCOUNT:
            r->stats.drop_lines++;
            r->stats.dropped += e->dropped;
            return VIBID_DRV_OK;
        case VIBID_CANDUMP_BAD_LINE: {
            char reason[sizeof e->text];
            memcpy(reason, e->text, sizeof reason);
            /* The reason is at most ~100 chars, so name + line + reason fit. */
            snprintf(e->text, sizeof e->text, "%.80s:%lu: %.100s", r->name, e->line, reason);
            r->stats.bad_lines++;
            return VIBID_DRV_OK;
        }
        }
    }
}

void vibid_candump_reader_stats(const vibid_candump_reader *r, vibid_candump_stats *stats)
{
    if (r && stats)
        *stats = r->stats;
}

void vibid_candump_reader_close(vibid_candump_reader *r)
{
    if (!r)
        return;
    if (r->fp)
        fclose(r->fp);
    free(r);
}
