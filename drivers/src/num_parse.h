/* Internal: a fast, exact decimal -> double conversion for the capture readers.
 *
 * vibid_parse_decimal handles only the plain decimal form that makes up nearly every
 * field of a capture, [+-]digits[.digits][(e|E)[+-]digits] (at least one mantissa
 * digit, at most 19 significant ones), and returns exactly what glibc's strtod returns
 * for it, bit for bit (round to nearest, ties to even; subnormals; -0). It returns false
 * ("not handled": the caller must use strtod) for everything else: other syntax (hex
 * floats, inf, nan, leading whitespace, stray characters, a NUL), more than 19
 * significant digits, results that overflow to infinity, and the rare products the
 * 128-bit approximation cannot round with certainty. So strtod stays the definition of
 * what a field means; this only answers early where the answer is known to be the same.
 * Algorithms: Clinger's fast path (both operands exact doubles, one rounding) and the
 * Eisel-Lemire algorithm with a 128-bit table of powers of five (pow5_table.h).
 * Requires round-to-nearest (the default floating-point environment) and IEEE doubles. */
#ifndef VIBID_DRIVERS_NUM_PARSE_H
#define VIBID_DRIVERS_NUM_PARSE_H

#include <stdbool.h>

/* Parses s[0, end - s) as a whole: true with *out set, or false (use strtod). */
bool vibid_parse_decimal(const char *s, const char *end, double *out);

#endif
