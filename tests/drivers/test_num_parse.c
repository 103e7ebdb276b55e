/* The CSV reader's fast number parser (drivers/src/num_parse.h) against glibc's strtod:
 * every string it accepts must give strtod's double bit for bit (the recordings replay
 * bit-identically), and every string it refuses must be one strtod is then asked about.
 * No tolerance: equality of the 64 bits (so -0 vs +0 and the last ulp count).
 * Strings: random doubles as %.17g (what captures hold), %.6g, %e, %.15g, %.16g, %.20g
 * (beyond 19 digits: must be refused or still exact); subnormals and the extremes of the
 * range; exact halfway cases between neighbouring doubles (ties to even); random digit
 * strings with random points and exponents (-400..400); syntax variants. */
#include <float.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "num_parse.h"

#include "support/drv_test_util.h"

static uint64_t rng_state = 0x9E3779B97F4A7C15u;
static uint64_t rnd(void) { return drv_splitmix64(&rng_state); }

typedef struct tally {
    unsigned long checked, handled;
} tally;

/* One string: if the fast parser takes it, it must equal strtod consuming all of it. */
static void check(const char *s, tally *t)
{
    double fast;
    size_t n = strlen(s);
    t->checked++;
    if (!vibid_parse_decimal(s, s + n, &fast))
        return;
    t->handled++;
    char *ep;
    double ref = strtod(s, &ep);
    if (*ep != '\0' || drv_bits_of(fast) != drv_bits_of(ref)) {
        fprintf(stderr, "'%s': fast %.17g (0x%016llx), strtod %.17g (0x%016llx), strtod stopped at '%s'\n", s, fast,
                (unsigned long long)drv_bits_of(fast), ref, (unsigned long long)drv_bits_of(ref), ep);
        fail();
    }
}

static double random_finite(void)
{
    for (;;) {
        double d = drv_from_bits(rnd());
        if (isfinite(d))
            return d;
    }
}

static void test_random_doubles(void **state)
{
    (void)state;
    tally t = {0};
    char buf[512];
    for (int i = 0; i < 400000; i++) {
        double d = random_finite();
        snprintf(buf, sizeof buf, "%.17g", d);
        check(buf, &t);
        snprintf(buf, sizeof buf, "%.6g", d);
        check(buf, &t);
        snprintf(buf, sizeof buf, "%e", d);
        check(buf, &t);
        snprintf(buf, sizeof buf, "%.15g", d);
        check(buf, &t);
        snprintf(buf, sizeof buf, "%.16g", d);
        check(buf, &t);
        snprintf(buf, sizeof buf, "%.20g", d);
        check(buf, &t);
        snprintf(buf, sizeof buf, "%.17e", d);
        check(buf, &t);
        snprintf(buf, sizeof buf, "%.3f", d);
        check(buf, &t);
    }
    /* values of a capture's size: |x| in 1e-12 .. 1e3, as %.17g (nearly all must be handled) */
    tally cap = {0};
    for (int i = 0; i < 1000000; i++) {
        double d = ldexp((double)(rnd() >> 11), -53) * pow(10.0, (double)(int)(rnd() % 16) - 12);
        snprintf(buf, sizeof buf, "%.17g", (rnd() & 1) ? -d : d);
        check(buf, &cap);
    }
    printf("random doubles: %lu strings, %lu handled by the fast parser, all equal to strtod; capture-like "
           "%%.17g: %lu of %lu handled\n",
           t.checked, t.handled, cap.handled, cap.checked);
    assert_true(cap.handled >= cap.checked * 999 / 1000); /* the fast path is really taken */
}

static void test_subnormals_and_extremes(void **state)
{
    (void)state;
    tally t = {0};
    char buf[512];
    for (int i = 0; i < 300000; i++) {
        /* subnormals: exponent field 0, random mantissa */
        double d = drv_from_bits(rnd() & ((UINT64_C(1) << 52) - 1u));
        snprintf(buf, sizeof buf, "%.17g", d);
        check(buf, &t);
        snprintf(buf, sizeof buf, "%.6g", d);
        check(buf, &t);
        /* the top and bottom of the normal range */
        uint64_t e = (rnd() & 1) ? 0x7FE - (rnd() % 4) : 1 + (rnd() % 4);
        d = drv_from_bits((e << 52) | (rnd() & ((UINT64_C(1) << 52) - 1u)));
        snprintf(buf, sizeof buf, "%.17g", d);
        check(buf, &t);
        snprintf(buf, sizeof buf, "%.16e", -d);
        check(buf, &t);
    }
    static const char *const edge[] = {
        "4.9406564584124654e-324", "2.4703282292062327e-324", "2.4703282292062328e-324",
        "2.4703282292062326e-324", "1e-324", "3e-324", "2.2250738585072011e-308", "2.2250738585072014e-308",
        "2.2250738585072012e-308", "1.7976931348623157e308", "1.7976931348623158e308",
        "1.7976931348623159e308", "1e308", "9.9999999999999999e307", "1e-400", "1e-342", "1e-343", "1e309",
        "0", "-0", "+0", "0.0", "-0.0e10", "0e-999", "000000000000000000000000001", "1.000000000000000000000",
        "123456789012345678", "1234567890123456789", "12345678901234567890", "9007199254740993",
        "9007199254740992", "9007199254740995", "18446744073709551615", "1e22", "1e23", "8.589973e9",
        "7.1e-10", "0.1", "0.2", "0.3", ".5", "5.", "+.5e-3", "1E+05", "1e+0005", "00.00100"};
    for (size_t i = 0; i < sizeof edge / sizeof *edge; i++)
        check(edge[i], &t);
    printf("subnormals and extremes: %lu strings, %lu handled, all equal to strtod\n", t.checked, t.handled);
    /* a few the fast path must answer itself (not hand to strtod) */
    double v;
    const char *s = "4.9406564584124654e-324";
    assert_true(vibid_parse_decimal(s, s + strlen(s), &v) && drv_bits_of(v) == 1u);
    s = "-0";
    assert_true(vibid_parse_decimal(s, s + 2, &v) && drv_bits_of(v) == UINT64_C(1) << 63);
}

/* Exact midpoints between neighbouring doubles, written exactly (they have few digits when
 * the doubles are integers or simple binary fractions): ties must go to even, and one
 * digit more or less away from the midpoint must go to the nearer neighbour. */
static void test_halfway(void **state)
{
    (void)state;
    tally t = {0};
    char buf[128];
    for (int i = 0; i < 300000; i++) {
        /* m = 2^53 + odd, an exact midpoint between two doubles of spacing 2, times 2^k */
        uint64_t m = (UINT64_C(1) << 53) + ((rnd() % (UINT64_C(1) << 53)) | 1u);
        int k = (int)(rnd() % 14) - 3; /* -3 .. 10: the exact decimal has at most 19 digits */
        if (k >= 0) {
            __extension__ unsigned __int128 x = (unsigned __int128)m << k;
            if (x >> 64)
                continue;
            snprintf(buf, sizeof buf, "%llu", (unsigned long long)x);
        } else {
            /* m / 2^-k: integer part and an exact fraction of -k digits */
            uint64_t ip = m >> -k, fr = m & ((UINT64_C(1) << -k) - 1u);
            uint64_t scale = 1;
            for (int j = 0; j < -k; j++)
                scale *= 10;
            snprintf(buf, sizeof buf, "%llu.%0*llu", (unsigned long long)ip, -k,
                     (unsigned long long)(fr * scale >> -k));
        }
        check(buf, &t);
        /* the same in scientific notation with the point moved */
        size_t n = strlen(buf);
        char sci[160];
        const char *dot = strchr(buf, '.');
        size_t intdigits = dot ? (size_t)(dot - buf) : n;
        char digits[64];
        size_t nd = 0;
        for (size_t j = 0; j < n; j++)
            if (buf[j] != '.')
                digits[nd++] = buf[j];
        digits[nd] = '\0';
        snprintf(sci, sizeof sci, "%c.%se%d", digits[0], digits + 1, (int)intdigits - 1);
        check(sci, &t);
        /* nudged by one unit in the last place of the decimal, both ways */
        snprintf(sci, sizeof sci, "%s1", dot ? buf : strcat(buf, "."));
        check(sci, &t);
    }
    /* small ones by hand: 2^53 + 1 ties down to 2^53, 2^53 + 3 up to 2^53 + 4 */
    double v;
    const char *s = "9007199254740993";
    assert_true(vibid_parse_decimal(s, s + strlen(s), &v) && v == 9007199254740992.0);
    s = "9007199254740995";
    assert_true(vibid_parse_decimal(s, s + strlen(s), &v) && v == 9007199254740996.0);
    printf("halfway cases: %lu strings, %lu handled, all equal to strtod\n", t.checked, t.handled);
    assert_true(t.handled > t.checked / 2);
}

static void test_random_strings(void **state)
{
    (void)state;
    tally t = {0};
    char buf[128];
    for (int i = 0; i < 1500000; i++) {
        size_t n = 0;
        if (rnd() % 4 == 0)
            buf[n++] = (rnd() & 1) ? '-' : '+';
        int ndig = 1 + (int)(rnd() % 24);
        int dot = (int)(rnd() % (unsigned)(ndig + 2)) - 1; /* -1: no point */
        for (int j = 0; j < ndig; j++) {
            if (j == dot)
                buf[n++] = '.';
            /* many zeros: leading/trailing zero handling */
            buf[n++] = (char)('0' + ((rnd() % 3 == 0) ? 0 : rnd() % 10));
        }
        if (dot == ndig)
            buf[n++] = '.';
        if (rnd() % 3) {
            buf[n++] = (rnd() & 1) ? 'e' : 'E';
            int e = (int)(rnd() % 801) - 400;
            if (rnd() & 1)
                n += (size_t)snprintf(buf + n, sizeof buf - n, "%+d", e);
            else
                n += (size_t)snprintf(buf + n, sizeof buf - n, "%d", e);
        }
        buf[n] = '\0';
        check(buf, &t);
    }
    printf("random digit strings: %lu, %lu handled, all equal to strtod\n", t.checked, t.handled);
}

/* Syntax the fast parser must refuse (strtod then decides, with the reader's messages). */
static void test_refused(void **state)
{
    (void)state;
    static const char *const no[] = {"", "+", "-", ".", "+.", "e5", ".e5", "1e", "1e+", "1e-", "1ee5", "1.2.3",
                                     "--1", "+-1", "inf", "-inf", "nan", "NaN", "infinity", "0x1p3", "0x10",
                                     " 1", "1 ", "\t1", "1\t", "1,", "1a", "1.5f", "1d5", "1e5.5", "1e5e5",
                                     "1e400", "-1e400", "1e99999999999", "12345678901234567890123",
                                     "0.12345678901234567890"};
    for (size_t i = 0; i < sizeof no / sizeof *no; i++) {
        double v = 42.0;
        const char *s = no[i];
        if (vibid_parse_decimal(s, s + strlen(s), &v)) {
            fprintf(stderr, "'%s' accepted as %g\n", s, v);
            fail();
        }
    }
    /* a NUL inside the field is never a digit */
    const char nul[] = "1\0002";
    double v;
    assert_false(vibid_parse_decimal(nul, nul + 3, &v));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_random_doubles), cmocka_unit_test(test_subnormals_and_extremes),
        cmocka_unit_test(test_halfway),        cmocka_unit_test(test_random_strings),
        cmocka_unit_test(test_refused),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
