/* vibid_drivers/dbc.h: the subset of the DBC format that acquisition needs, and
 * decoding of CAN / CAN FD payloads into physical values.
 *
 * Read: BO_ (11-bit ids, and 29-bit ids written with bit 31 set), SG_ (Intel @1 and
 * Motorola @0 bit numbering, + unsigned / - signed, (factor,offset), [min|max],
 * "unit"), SIG_VALTYPE_ (1 = IEEE float32, 2 = IEEE float64), simple multiplexing
 * (one multiplexor "M" per message, signals "m<value>") and SG_MUL_VAL_ value ranges
 * for that one multiplexor. Every other statement (CM_, BA_*, VAL_, NS_ block, ...) is
 * skipped, not rejected; multi-line strings inside skipped statements are handled.
 * The pseudo message VECTOR__INDEPENDENT_SIG_MSG (id 0xC0000000) is skipped too.
 * Rejected, with "file:line: reason": malformed BO_/SG_/SIG_VALTYPE_/SG_MUL_VAL_,
 * lengths outside 1..64 bits, signals that do not fit the message length, standard
 * ids above 0x7FF, duplicate message ids, non-finite numbers, unterminated strings.
 *
 * Physical value = raw * factor + offset, computed in double (as cantools does), where
 * raw is the signed/unsigned integer, or the float32/float64 value for SIG_VALTYPE_
 * signals. Multiplexing follows cantools: a multiplexed signal is present when the
 * multiplexor's raw value lies in one of its ranges.
 *
 * Numbers are parsed with strtod: the process must use the "C" numeric locale.
 */
#ifndef VIBID_DRIVERS_DBC_H
#define VIBID_DRIVERS_DBC_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <vibid_drivers/status.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum vibid_dbc_byte_order {
    VIBID_DBC_MOTOROLA = 0, /* @0: big endian, start bit is the MSB (sawtooth numbering) */
    VIBID_DBC_INTEL = 1     /* @1: little endian, start bit is the LSB */
} vibid_dbc_byte_order;

typedef enum vibid_dbc_value_type {
    VIBID_DBC_INTEGER = 0, /* signed or unsigned integer of `length` bits */
    VIBID_DBC_FLOAT32 = 1, /* SIG_VALTYPE_ 1; length must be 32 */
    VIBID_DBC_FLOAT64 = 2  /* SIG_VALTYPE_ 2; length must be 64 */
} vibid_dbc_value_type;

typedef enum vibid_dbc_mux_role {
    VIBID_DBC_PLAIN = 0,       /* always present */
    VIBID_DBC_MULTIPLEXOR = 1, /* "M": selects which multiplexed signals are present */
    VIBID_DBC_MULTIPLEXED = 2  /* "m<v>": present when the multiplexor's raw value is in mux_ranges */
} vibid_dbc_mux_role;

typedef struct vibid_dbc_mux_range {
    uint64_t lo, hi; /* inclusive raw multiplexor values */
} vibid_dbc_mux_range;

typedef struct vibid_dbc_signal {
    const char *name;        /* as in the file; unique within its message */
    const char *unit;        /* "" when none */
    uint16_t start_bit;      /* 0 .. 8*length-1 of the message */
    uint8_t length;          /* bits, 1..64 */
    uint8_t min_bytes;       /* payload bytes needed to decode it (derived) */
    vibid_dbc_byte_order byte_order;
    bool is_signed;
    vibid_dbc_value_type value_type;
    double factor, offset;   /* physical = raw * factor + offset; both finite */
    double minimum, maximum; /* as written; [0|0] means "not given" in DBC practice */
    vibid_dbc_mux_role mux_role;
    const vibid_dbc_mux_range *mux_ranges; /* MULTIPLEXED only */
    size_t n_mux_ranges;
    unsigned line;           /* line of its SG_ in the file */
} vibid_dbc_signal;

typedef struct vibid_dbc_message {
    uint32_t id;             /* without the extended flag bit */
    bool extended;           /* 29-bit id */
    const char *name;
    uint8_t length;          /* declared payload bytes, 0..64 */
    const vibid_dbc_signal *signals;
    size_t n_signals;
    int multiplexor;         /* index into signals of the "M" signal, -1 if none */
    unsigned line;           /* line of its BO_ */
} vibid_dbc_message;

typedef struct vibid_dbc vibid_dbc;

/* Reads a DBC file. NULL on failure with err->text "path:line: reason". The returned
 * object owns all messages, signals and strings; pointers into it live until
 * vibid_dbc_destroy. */
vibid_dbc *vibid_dbc_load(const char *path, vibid_drv_error *err);
/* Same from memory (text need not be NUL-terminated); `name` is used in messages. */
vibid_dbc *vibid_dbc_parse(const char *text, size_t len, const char *name, vibid_drv_error *err);
void vibid_dbc_destroy(vibid_dbc *dbc);

size_t vibid_dbc_message_count(const vibid_dbc *dbc);
/* Messages sorted by (extended, id); i < count. */
const vibid_dbc_message *vibid_dbc_message_at(const vibid_dbc *dbc, size_t i);
/* O(log n) lookup by id; NULL when the DBC has no such message. */
const vibid_dbc_message *vibid_dbc_find_message(const vibid_dbc *dbc, uint32_t id, bool extended);
const vibid_dbc_message *vibid_dbc_find_message_by_name(const vibid_dbc *dbc, const char *name);
const vibid_dbc_signal *vibid_dbc_find_signal(const vibid_dbc_message *msg, const char *name);
/* The signal `name` in any message of the DBC, or only in the message named `message`
 * (NULL or "" = any). Returns it and sets *msg_out (may be NULL) to its message; NULL when
 * no message holds it. When several messages hold it, returns NULL and sets *second_out
 * (may be NULL) to the second of them (*msg_out to the first): the caller must name the
 * message. *second_out is NULL otherwise. */
const vibid_dbc_signal *vibid_dbc_lookup_signal(const vibid_dbc *dbc, const char *name, const char *message,
                                                const vibid_dbc_message **msg_out,
                                                const vibid_dbc_message **second_out);
/* Number of statements that were skipped (not understood, but well-formed enough). */
size_t vibid_dbc_skipped_count(const vibid_dbc *dbc);

/* Raw bits of a signal (not sign-extended, not scaled). len = payload bytes present.
 * VIBID_DRV_E_SHORT when len < sig->min_bytes. Ignores multiplexing. */
vibid_drv_status vibid_dbc_signal_raw(const vibid_dbc_signal *sig, const uint8_t *data, size_t len,
                                      uint64_t *raw);
/* Physical value of one signal; ignores multiplexing. Float signals may yield NaN or
 * Inf (the caller decides what a non-finite sample means). */
vibid_drv_status vibid_dbc_signal_decode(const vibid_dbc_signal *sig, const uint8_t *data,
                                         size_t len, double *phys);
/* The inverse, for writing frames (vibidd's candump recording): sets the signal's bits in
 * data[0 .. len) to raw (its low sig->length bits), leaving all other bits as they are. */
vibid_drv_status vibid_dbc_signal_put_raw(const vibid_dbc_signal *sig, uint8_t *data, size_t len, uint64_t raw);
/* Encodes the physical value phys: raw = round((phys - offset) / factor) for integer
 * signals (VIBID_DRV_E_RANGE when it does not fit the signal's length and signedness, or
 * phys is not finite), the float32/float64 of (phys - offset) / factor for float signals.
 * A value decoded from a frame with the same signal encodes back to the same bits
 * (exactly for integers, and for floats with factor 1 and offset 0). */
vibid_drv_status vibid_dbc_signal_encode(const vibid_dbc_signal *sig, double phys, uint8_t *data, size_t len);
/* Decodes every signal of msg: values[i], present[i] for i < msg->n_signals (caller
 * arrays). Multiplexed signals not selected, and signals beyond a short payload, get
 * present = 0 and value NaN. Returns VIBID_DRV_E_SHORT if any signal that should be
 * present did not fit in len, else OK. No allocation. */
vibid_drv_status vibid_dbc_message_decode(const vibid_dbc_message *msg, const uint8_t *data,
                                          size_t len, double *values, uint8_t *present);

#ifdef __cplusplus
}
#endif
#endif
