/* Internal: the two halves of vibid_candump_parse_line, exposed for the test that feeds
 * the same lines through both and compares them field by field. Not public API.
 * vibid_candump_parse_line = the fast path when it accepts the line, else the general
 * parser; the general parser alone defines what every line means. */
#ifndef VIBID_DRIVERS_CANDUMP_INTERNAL_H
#define VIBID_DRIVERS_CANDUMP_INTERNAL_H

#include <stdbool.h>
#include <stddef.h>

#include <vibid_drivers/candump.h>

/* The full grammar of candump.h: every kind, every error message. */
vibid_candump_kind vibid_candump_parse_line_general(const char *line, size_t len, vibid_candump_entry *e);
/* Only the canonical data-frame line "(SECONDS.FFFFFF) IFACE III#HH.." (6 or 9 fraction
 * digits, single spaces, 3- or 8-digit id, 0..8 bytes): true with *e filled exactly as the
 * general parser fills it; false for any other line (then *e must be parsed again). */
bool vibid_candump_parse_line_fast(const char *line, size_t len, vibid_candump_entry *e);

#endif
