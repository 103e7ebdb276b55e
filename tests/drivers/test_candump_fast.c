/* The candump parser's fast path (canonical lines, candump_internal.h) against the general
 * parser: for generated lines, valid and subtly invalid, vibid_candump_parse_line must
 * give exactly what the general parser gives (kind, every frame field, the error text),
 * and whenever the fast path accepts a line the general parser must accept it with the
 * same fields. No tolerances: the fields are integers and strings.
 * Lines: the canonical form with random timestamps (10 digits and other widths, 6 and 9
 * fraction digits, and wrong ones), interface names (1..17 bytes, with tabs, control
 * bytes, NUL, bytes >= 0x80), ids of 3 and 8 hex digits (above 0x7FF, error flag, flag
 * bits), 0..9 data bytes in either case, and single-character damage anywhere (odd
 * digit counts, 'g', '.', '_9', 'R', '##', extra spaces, " R"/" T", a CR, a NUL). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>

#include "candump_internal.h"

#include "support/drv_test_util.h"

static uint64_t rng_state = 0x2545F4914F6CDD1Du;
static uint64_t rnd(void) { return drv_splitmix64(&rng_state); }

static const char hexu[] = "0123456789ABCDEF", hexl[] = "0123456789abcdef";

/* Appends a generated line to buf; returns its length (it may contain NUL bytes). */
static size_t make_line(char *buf, size_t cap)
{
    size_t n = 0;
#define PUT(c)                                                                                                    \
    do {                                                                                                          \
        if (n < cap)                                                                                              \
            buf[n++] = (char)(c);                                                                                 \
    } while (0)
    PUT('(');
    int secd = (rnd() % 8) ? 10 : (int)(rnd() % 13); /* mostly candump's 10 digits */
    uint64_t sec = (rnd() % 4) ? 1700000000u + rnd() % 100000000u : rnd();
    char tmp[32];
    int tl = snprintf(tmp, sizeof tmp, "%020llu", (unsigned long long)sec);
    for (int i = 0; i < secd; i++)
        PUT(tmp[tl - secd + i]);
    PUT('.');
    int fracd = (rnd() % 6) ? 6 : ((rnd() & 1) ? 9 : (int)(rnd() % 11));
    for (int i = 0; i < fracd; i++)
        PUT('0' + rnd() % 10);
    PUT(')');
    PUT(' ');
    int ifl = (rnd() % 6) ? 4 : 1 + (int)(rnd() % 17);
    for (int i = 0; i < ifl; i++) {
        unsigned r = (unsigned)(rnd() % 64);
        if (r == 0)
            PUT('\t');
        else if (r == 1)
            PUT(0x01);
        else if (r == 2)
            PUT(0xC3);
        else if (r == 3)
            PUT('\0');
        else
            PUT("can0vxyz_-.1"[r % 12]);
    }
    PUT(' ');
    int idl = (rnd() % 4) ? 3 : ((rnd() & 1) ? 8 : (int)(rnd() % 10));
    bool lower = rnd() % 4 == 0;
    for (int i = 0; i < idl; i++) {
        unsigned d = (unsigned)(rnd() % 16);
        if (i == 0 && idl == 3 && rnd() % 4)
            d &= 7u; /* mostly <= 0x7FF */
        if (i == 0 && idl == 8 && rnd() % 3)
            d &= 1u; /* mostly without the error flag and flag bits */
        PUT(lower ? hexl[d] : hexu[d]);
    }
    PUT('#');
    int nb = (int)(rnd() % 10);
    for (int i = 0; i < 2 * nb; i++) {
        unsigned d = (unsigned)(rnd() % 16);
        PUT((lower || rnd() % 8 == 0) ? hexl[d] : hexu[d]);
    }
    /* damage: one change in a third of the lines */
    if (rnd() % 3 == 0 && n > 0) {
        static const char junk[] = "g.R#_9 \t\r\0GxX:/()e-+";
        size_t at = (size_t)(rnd() % n);
        switch (rnd() % 4) {
        case 0: /* replace */
            buf[at] = junk[rnd() % (sizeof junk - 1)];
            break;
        case 1: /* insert */
            if (n < cap) {
                memmove(buf + at + 1, buf + at, n - at);
                buf[at] = junk[rnd() % (sizeof junk - 1)];
                n++;
            }
            break;
        case 2: /* delete */
            memmove(buf + at, buf + at + 1, n - at - 1);
            n--;
            break;
        default: { /* a suffix */
            static const char *const suf[] = {" R", " T", " ", "\r", "_9", "R", "R5", "#", "##1", " X", ".", "_"};
            const char *s = suf[rnd() % (sizeof suf / sizeof *suf)];
            while (*s)
                PUT(*s++);
        }
        }
    }
#undef PUT
    return n;
}

static void expect_same(const char *line, size_t len, const vibid_candump_entry *a, const vibid_candump_entry *b)
{
    bool same = a->kind == b->kind && strcmp(a->text, b->text) == 0 && a->dropped == b->dropped &&
                a->total_drops == b->total_drops;
    if (same && a->kind == VIBID_CANDUMP_FRAME) {
        const vibid_can_frame *f = &a->frame, *g = &b->frame;
        same = f->t_ns == g->t_ns && f->id == g->id && f->flags == g->flags && f->fd_flags == g->fd_flags &&
               f->len == g->len && memcmp(f->data, g->data, VIBID_CAN_MAX_DLEN) == 0 &&
               strcmp(f->iface, g->iface) == 0;
        if (same && (f->flags & VIBID_CAN_F_FD))
            same = memcmp(f->data, g->data, VIBID_CANFD_MAX_DLEN) == 0;
    }
    if (!same) {
        fprintf(stderr, "line '%.*s' (%zu bytes): kinds %d / %d, texts '%s' / '%s'\n", (int)len, line, len, a->kind,
                b->kind, a->text, b->text);
        fail();
    }
}

static void test_fast_equals_general(void **state)
{
    (void)state;
    char line[256];
    unsigned long n_lines = 0, n_fast = 0, n_frames = 0, n_bad = 0;
    for (int i = 0; i < 1000000; i++) {
        size_t len = make_line(line, sizeof line - 1);
        line[len] = '\0'; /* as the line reader hands lines out */
        vibid_candump_entry g, p, f;
        /* the same garbage everywhere: whatever a parser leaves unset compares equal */
        memset(&g, 0xA5, sizeof g);
        memset(&p, 0xA5, sizeof p);
        memset(&f, 0xA5, sizeof f);
        vibid_candump_parse_line_general(line, len, &g);
        vibid_candump_parse_line(line, len, &p);
        expect_same(line, len, &p, &g);
        if (vibid_candump_parse_line_fast(line, len, &f)) {
            n_fast++;
            expect_same(line, len, &f, &g);
        }
        n_lines++;
        n_frames += g.kind == VIBID_CANDUMP_FRAME;
        n_bad += g.kind == VIBID_CANDUMP_BAD_LINE;
    }
    printf("%lu generated lines: %lu frames, %lu bad lines (general parser); %lu taken by the fast path, all "
           "identical\n",
           n_lines, n_frames, n_bad, n_fast);
    /* both sides of the comparison must be well populated */
    assert_true(n_fast > n_lines / 4);
    assert_true(n_bad > n_lines / 10);
    assert_true(n_frames > n_fast); /* frames the fast path leaves to the general parser */
}

/* Lines the fast path must take, and what they give (values worked out by hand). */
static void test_fast_known(void **state)
{
    (void)state;
    vibid_candump_entry e;
    const char *l = "(1700000000.000500) can0 101#010003FD0EAF0000";
    assert_true(vibid_candump_parse_line_fast(l, strlen(l), &e));
    assert_int_equal(e.frame.t_ns, INT64_C(1700000000000500000));
    assert_int_equal(e.frame.id, 0x101);
    assert_int_equal(e.frame.len, 8);
    assert_int_equal(e.frame.flags, 0);
    static const uint8_t want[8] = {0x01, 0x00, 0x03, 0xFD, 0x0E, 0xAF, 0x00, 0x00};
    assert_memory_equal(e.frame.data, want, 8);
    assert_string_equal(e.frame.iface, "can0");
    l = "(0000000001.123456789) vcan12 1FFFFFFF#abcd";
    assert_true(vibid_candump_parse_line_fast(l, strlen(l), &e));
    assert_int_equal(e.frame.t_ns, INT64_C(1123456789));
    assert_int_equal(e.frame.id, 0x1FFFFFFF);
    assert_int_equal(e.frame.flags, VIBID_CAN_F_EXT);
    assert_int_equal(e.frame.len, 2);
    assert_int_equal(e.frame.data[0], 0xAB);
    assert_int_equal(e.frame.data[1], 0xCD);
    assert_int_equal(e.frame.data[2], 0);
    /* left to the general parser */
    static const char *const not_fast[] = {
        "(1700000000.000500) can0 20000080#0000000000000000", /* error frame */
        "(1700000000.000500) can0 123#R",  "(1700000000.000500) can0 123##1AA",
        "(1700000000.000500) can0 123#11.22", "(1700000000.000500)  can0 123#11",
        "(1700000000.000500) can0 123#11 R", "(1700000000.00050) can0 123#11",
        "(1700000000.000500) can0 800#11", "DROPCOUNT: dropped 3 CAN frames on 'can0' socket (total drops 7)",
        "(9223372036.000000) can0 123#11"};
    for (size_t i = 0; i < sizeof not_fast / sizeof *not_fast; i++)
        assert_false(vibid_candump_parse_line_fast(not_fast[i], strlen(not_fast[i]), &e));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_fast_equals_general),
        cmocka_unit_test(test_fast_known),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
