/* Exact decimal -> double without strtod's multi-precision path; see num_parse.h.
 * glibc's strtod is correctly rounded but takes its slow (multi-precision) route for any
 * input beyond 15-16 significant digits, and the %.17g values that captures hold always
 * are: it was about a third of vibidd's CSV replay time. The Eisel-Lemire algorithm gets
 * the same correctly rounded double from one or two 64x64 -> 128-bit products. */
#include "num_parse.h"

#include <stdint.h>
#include <string.h>

#include "pow5_table.h"
#include "swar.h"

__extension__ typedef unsigned __int128 u128; /* gcc/clang on 64-bit targets */

/* 10^0 .. 10^22: exactly representable as doubles (5^22 < 2^53). */
static const double exact_pow10[23] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,  1e8,  1e9,  1e10, 1e11,
                                       1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};

static double from_bits(uint64_t b)
{
    double d;
    memcpy(&d, &b, sizeof d);
    return d;
}

/* Eisel-Lemire: w * 10^q (w != 0, -342 <= q <= 308) as IEEE double bits without the sign,
 * following fast_float's compute_float for binary64. false: the truncated product cannot
 * decide the rounding (or the value overflows); the caller falls back to strtod. */
static bool eisel_lemire(uint64_t w, int q, uint64_t *bits)
{
    int lz = __builtin_clzll(w);
    w <<= lz;
    const uint64_t *p = vibid_pow5_128[q - VIBID_POW5_MIN_Q];
    u128 first = (u128)w * p[0];
    uint64_t hi = (uint64_t)(first >> 64), lo = (uint64_t)first;
    /* 55 bits are needed (52 + implicit + round + one more); when the bits below them are
     * all ones the low half of the power can still carry into them. */
    const uint64_t precision_mask = UINT64_MAX >> 55;
    if ((hi & precision_mask) == precision_mask) {
        u128 second = (u128)w * p[1];
        uint64_t s_hi = (uint64_t)(second >> 64);
        lo += s_hi;
        if (s_hi > lo)
            hi++;
        /* Still undecided outside the exponents where the 128-bit power is exact enough:
         * give up rather than risk a wrong last bit (fast_float 1.x's conservative test;
         * later proved unnecessary, but the fallback costs nothing in practice). */
        if (lo == UINT64_MAX && (q < -27 || q > 55))
            return false;
    }
    int upperbit = (int)(hi >> 63);
    int shift = upperbit + 64 - 52 - 3;
    uint64_t mant = hi >> shift;
    /* floor(log2(10^q)) + 63 via 217706 / 2^16 ~ log2(10); >> of a negative int is an
     * arithmetic shift on gcc and clang (implementation-defined in C, relied on here). */
    int32_t power2 = (int32_t)((((int64_t)(152170 + 65536) * q) >> 16) + 63) + upperbit - lz + 1023;
    if (power2 <= 0) { /* subnormal or zero */
        if (-power2 + 1 >= 64) {
            *bits = 0;
            return true;
        }
        mant >>= -power2 + 1;
        mant += mant & 1u;
        mant >>= 1;
        power2 = mant < (UINT64_C(1) << 52) ? 0 : 1;
        *bits = (mant & ((UINT64_C(1) << 52) - 1u)) | ((uint64_t)power2 << 52);
        return true;
    }
    /* Exactly halfway (possible only for small |q|): round to even instead of up. */
    if (lo <= 1 && q >= -4 && q <= 23 && (mant & 3u) == 1u && (mant << shift) == hi)
        mant &= ~UINT64_C(1);
    mant += mant & 1u;
    mant >>= 1;
    if (mant >= (UINT64_C(2) << 52)) {
        mant = UINT64_C(1) << 52;
        power2++;
    }
    mant &= ~(UINT64_C(1) << 52);
    if (power2 >= 0x7FF)
        return false; /* infinity: strtod decides (and says ERANGE) */
    *bits = mant | ((uint64_t)power2 << 52);
    return true;
}

bool vibid_parse_decimal(const char *s, const char *end, double *out)
{
    const char *p = s;
    bool neg = false;
    if (p < end && (*p == '-' || *p == '+'))
        neg = *p++ == '-';
    /* All digits go into w, leading zeros included (they add nothing); w wraps only when
     * there are more than 19 significant digits, and then strtod is used. */
    const char *digits = p;
    uint64_t w = 0;
    while (p < end && (unsigned)(*p - '0') < 10u)
        w = w * 10u + (unsigned)(*p++ - '0');
    size_t ndig = (size_t)(p - digits);
    int exp10 = 0; /* w * 10^exp10 is the mantissa's value */
    if (p < end && *p == '.') {
        p++;
        const char *frac = p;
#if VIBID_SWAR
        /* %.17g fractions are long: eight digits per step */
        while (end - p >= 8 && vibid_swar_eight_digits(vibid_load8(p))) {
            w = w * 100000000u + vibid_swar_eight_digits_value(vibid_load8(p));
            p += 8;
        }
#endif
        while (p < end && (unsigned)(*p - '0') < 10u)
            w = w * 10u + (unsigned)(*p++ - '0');
        ndig += (size_t)(p - frac);
        if (p - frac > 100000)
            return false; /* keeps exp10 far from overflow; strtod decides */
        exp10 = -(int)(p - frac);
    }
    if (ndig == 0)
        return false; /* no mantissa digit: ".", "+", "e5", "inf", ... */
    if (ndig > 19) {
        /* leading zeros (and the point between them) are not significant */
        for (const char *z = digits; z < p && (*z == '0' || *z == '.'); z++)
            ndig -= *z == '0';
        if (ndig > 19)
            return false; /* more than 19 significant digits: strtod */
    }
    if (p < end && (*p == 'e' || *p == 'E')) {
        p++;
        bool eneg = false;
        if (p < end && (*p == '-' || *p == '+'))
            eneg = *p++ == '-';
        if (p == end || (unsigned)(*p - '0') >= 10u)
            return false; /* "1e", "1e+": strtod stops before the 'e': not a whole number */
        int e = 0;
        while (p < end && (unsigned)(*p - '0') < 10u) {
            if (e > 100000)
                return false; /* absurd exponent: leave it to strtod */
            e = e * 10 + (*p++ - '0');
        }
        exp10 += eneg ? -e : e;
    }
    if (p != end)
        return false;
    uint64_t sign = neg ? UINT64_C(1) << 63 : 0;
    if (w == 0) {
        *out = from_bits(sign); /* "0", "-0.0", "0e999": signed zero, as strtod */
        return true;
    }
    /* Clinger: w and 10^|q| are exact doubles, so one IEEE operation rounds correctly. */
    if (exp10 >= -22 && exp10 <= 22 && w <= (UINT64_C(1) << 53)) {
        double d = (double)w;
        d = exp10 < 0 ? d / exact_pow10[-exp10] : d * exact_pow10[exp10];
        *out = neg ? -d : d;
        return true;
    }
    if (exp10 < VIBID_POW5_MIN_Q) {
        *out = from_bits(sign); /* below 1e-324 even with 19 digits: rounds to zero */
        return true;
    }
    if (exp10 > VIBID_POW5_MAX_Q)
        return false; /* overflow: strtod */
    uint64_t bits;
    if (!eisel_lemire(w, exp10, &bits))
        return false;
    *out = from_bits(bits | sign);
    return true;
}
