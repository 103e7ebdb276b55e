/* Internal: byte-parallel ("SWAR") parsing of eight ASCII characters in one 64-bit word,
 * as simdjson and fast_float parse digits, for the capture readers' fast paths.
 * VIBID_SWAR is 1 on little-endian hosts, where byte i of load8(s) is s[i]; elsewhere 0
 * and the callers use their byte-by-byte loops. Every byte-wise range test needs bytes
 * below 0x80 (checked first), so that no sum carries into the next byte. */
#ifndef VIBID_DRIVERS_SWAR_H
#define VIBID_DRIVERS_SWAR_H

#include <stdbool.h>
#include <stdint.h>
#include <string.h>

#define VIBID_BYTES(c) (UINT64_C(0x0101010101010101) * (uint64_t)(c))

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
#define VIBID_SWAR 1
#else
#define VIBID_SWAR 0
#endif

/* The 8 bytes at s (unaligned; all 8 must be readable). */
static inline uint64_t vibid_load8(const char *s)
{
    uint64_t v;
    memcpy(&v, s, sizeof v);
    return v;
}

/* 0x80 in every byte whose value lies in [lo, hi], 0 elsewhere; v's bytes must be < 0x80. */
static inline uint64_t vibid_swar_in_range(uint64_t v, unsigned lo, unsigned hi)
{
    return (v + VIBID_BYTES(0x80 - lo)) & ~(v + VIBID_BYTES(0x7F - hi)) & VIBID_BYTES(0x80);
}

/* true when all eight bytes are '0'..'9'. */
static inline bool vibid_swar_eight_digits(uint64_t v)
{
    return !(v & VIBID_BYTES(0x80)) && vibid_swar_in_range(v, '0', '9') == VIBID_BYTES(0x80);
}

/* Value of eight decimal digits, the first byte (lowest) most significant. */
static inline uint32_t vibid_swar_eight_digits_value(uint64_t v)
{
    v -= VIBID_BYTES('0');
    v = v * 10 + (v >> 8);
    v = (((v & UINT64_C(0x000000FF000000FF)) * UINT64_C(0x000F424000000064)) +
         (((v >> 16) & UINT64_C(0x000000FF000000FF)) * UINT64_C(0x0000271000000001))) >> 32;
    return (uint32_t)v;
}

#endif
