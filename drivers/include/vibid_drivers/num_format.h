/* vibid_drivers/num_format.h: doubles as the shortest decimal text that reads back to the
 * same double, for the capture writers (vibid-sim's CSV).
 *
 * "%.17g" also round-trips, but glibc's printf takes 300-600 ns per value for it, which made
 * vibid-sim's CSV output the bottleneck (a 10-DOF chain at 10 kHz written at 9-18 times real
 * time while its simulation runs at 237-413). The shortest round-trip form (C++17
 * std::to_chars, Ryu in libstdc++) is exact in the same sense - strtod, and the drivers' own
 * reader (num_parse.h), give back the identical bits, -0 and subnormals included - with 17
 * significant digits at most and often fewer (0.0001 as "1e-04" where "%.17g" writes
 * 0.00010000000000000001).
 *
 * Text: the fewest characters of plain or exponent notation that read back exactly, never
 * more than the shortest "%.{p}g" that does ("1e-05", "123.25", "1.2345678901234567e+300",
 * a large integer in plain digits: "5026059737636757504"); "nan", "inf", "-inf" for
 * non-finite values; no locale.
 * Thread-safe, no allocation. */
#ifndef VIBID_DRIVERS_NUM_FORMAT_H
#define VIBID_DRIVERS_NUM_FORMAT_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Room for any double's text plus the terminating NUL (the longest is 24 characters,
 * e.g. "-2.2250738585072014e-308"). */
#define VIBID_NUM_FORMAT_MAX 32

/* Writes v's shortest round-trip text and a NUL to buf (at least VIBID_NUM_FORMAT_MAX
 * bytes); returns the text's length (without the NUL), 1..24. */
size_t vibid_num_format(char *buf, double v);

#ifdef __cplusplus
}
#endif

#endif
