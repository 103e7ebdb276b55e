/* The capture writers' number formatter (vibid_drivers/num_format.h): every double's text
 * reads back to the same 64 bits through glibc's strtod and through the drivers' own fast
 * parser (num_parse.h) where that takes it, and it is no longer than the shortest "%.{p}g"
 * text that round-trips. No tolerance anywhere: bits are compared.
 * Values: random bit patterns (every exponent, subnormals included), random doubles of the
 * sizes captures hold (1e-9..1e3, both signs), the extremes (DBL_MIN, DBL_MAX, the least
 * subnormal, -0, 0.1, 1/3), and values on a sampling-time grid k / f_s (vibid-sim's t). */
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
#include <vibid_drivers/num_format.h>

#include "num_parse.h"

#include "support/drv_test_util.h"

static uint64_t rng_state = 0x2545F4914F6CDD1Du;
static uint64_t rnd(void) { return drv_splitmix64(&rng_state); }

/* The length of "%.{p}g" for the least precision p that gives v back (p <= 17 always does) */
static size_t shortest_printf_length(double v)
{
    char buf[64];
    for (int p = 1; p <= 17; p++) {
        snprintf(buf, sizeof buf, "%.*g", p, v);
        if (drv_bits_of(strtod(buf, NULL)) == drv_bits_of(v)) return strlen(buf);
    }
    return 0; /* never reached */
}

static unsigned long n_checked, n_fast_parsed;

static void check(double v)
{
    char buf[VIBID_NUM_FORMAT_MAX + 8];
    memset(buf, 'x', sizeof buf);
    const size_t len = vibid_num_format(buf, v);
    n_checked++;
    if (len == 0 || len > 24 || buf[len] != '\0' || strlen(buf) != len) {
        fprintf(stderr, "%.17g: length %zu, text '%.*s'\n", v, len, (int)sizeof buf, buf);
        fail();
    }
    char *end;
    const double back = strtod(buf, &end);
    if (*end != '\0' || drv_bits_of(back) != drv_bits_of(v)) {
        fprintf(stderr, "%.17g (0x%016llx): '%s' reads back as %.17g\n", v, (unsigned long long)drv_bits_of(v), buf, back);
        fail();
    }
    double fast;
    if (vibid_parse_decimal(buf, buf + len, &fast)) {
        n_fast_parsed++;
        if (drv_bits_of(fast) != drv_bits_of(v)) {
            fprintf(stderr, "%.17g: '%s' reads back through num_parse as %.17g\n", v, buf, fast);
            fail();
        }
    }
    /* shortest: never longer than the shortest %g text that round-trips (often shorter: a
     * large integer as "5026059737636757504", not "5.026059737636757e+18") */
    const size_t printf_len = shortest_printf_length(v);
    if (len > printf_len) {
        fprintf(stderr, "%.17g: '%s' is longer than %%g's shortest round trip (%zu characters)\n", v, buf, printf_len);
        fail();
    }
}

static void test_random_bit_patterns(void **state)
{
    (void)state;
    for (int i = 0; i < 200000; i++) {
        uint64_t b = rnd();
        double v;
        memcpy(&v, &b, sizeof v);
        if (isfinite(v)) check(v);
    }
}

static void test_capture_sized_values(void **state)
{
    (void)state;
    for (int i = 0; i < 200000; i++) {
        const double mag = pow(10.0, -9.0 + 12.0 * (double)(rnd() >> 11) * 0x1.0p-53);
        check((rnd() & 1 ? -1.0 : 1.0) * mag * (double)(rnd() >> 11) * 0x1.0p-53);
    }
    /* vibid-sim's time column: t = k / f_s */
    for (int k = 0; k < 100000; k++) check((double)k / 10000.0);
    for (int k = 0; k < 100000; k++) check((double)k / 3000.0);
}

static void test_special_values(void **state)
{
    (void)state;
    const double v[] = {0.0, -0.0, 1.0, -1.0, 0.1, 1.0 / 3.0, 100.0, 1e-5, 123.25, 1e21, 1e22, 5e-324, -5e-324,
                        DBL_MIN, DBL_MAX, -DBL_MAX, DBL_EPSILON, 9007199254740993.0, 2.2250738585072009e-308};
    for (size_t i = 0; i < sizeof v / sizeof v[0]; i++) check(v[i]);
    char buf[VIBID_NUM_FORMAT_MAX];
    assert_int_equal(vibid_num_format(buf, -0.0), 2);
    assert_string_equal(buf, "-0");
    assert_int_equal(vibid_num_format(buf, 0.0001), 5);
    assert_string_equal(buf, "1e-04"); /* %.17g: 0.00010000000000000001 */
    vibid_num_format(buf, NAN);
    assert_string_equal(buf, "nan");
    vibid_num_format(buf, -NAN);
    assert_string_equal(buf, "nan");
    vibid_num_format(buf, INFINITY);
    assert_string_equal(buf, "inf");
    vibid_num_format(buf, -INFINITY);
    assert_string_equal(buf, "-inf");
    /* the longest text of all */
    assert_int_equal(vibid_num_format(buf, -2.2250738585072014e-308), 24);
}

static int report(void **state)
{
    (void)state;
    printf("num_format: %lu values round-trip through strtod, none longer than %%g's shortest; %lu of them also "
           "through num_parse's fast path\n",
           n_checked, n_fast_parsed);
    return 0;
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_special_values),
        cmocka_unit_test(test_random_bit_patterns),
        cmocka_unit_test(test_capture_sized_values),
    };
    return cmocka_run_group_tests(tests, NULL, report);
}
