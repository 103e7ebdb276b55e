/* vibid_drivers/status.h: status codes and error text shared by every part of the
 * drivers library (sources, parsers, decoders).
 *
 * Conventions for the whole drivers API:
 *  - Functions return vibid_drv_status; constructors return NULL on failure and, when
 *    the caller passes a vibid_drv_error, write the reason there.
 *  - Error texts name the file, line and field that is wrong ("stand.dbc:12: SG_
 *    'Speed': length 0 outside 1..64"), so that a user can fix the input.
 *  - Destructors are NULL-safe. The caller owns arrays it passes; objects copy what
 *    they keep. Handles are used by one thread at a time.
 */
#ifndef VIBID_DRIVERS_STATUS_H
#define VIBID_DRIVERS_STATUS_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum vibid_drv_status {
    VIBID_DRV_OK = 0,
    VIBID_DRV_E_ARG = 1,         /* NULL pointer or argument outside its documented range */
    VIBID_DRV_E_IO = 2,          /* a system call failed (errno text in the error) */
    VIBID_DRV_E_SYNTAX = 3,      /* malformed input text (file:line in the error) */
    VIBID_DRV_E_NOMEM = 4,       /* allocation failed */
    VIBID_DRV_E_RANGE = 5,       /* a value lies outside its valid range */
    VIBID_DRV_E_EOF = 6,         /* end of a finite stream (replay file fully read) */
    VIBID_DRV_E_AGAIN = 7,       /* nothing available before the timeout; try again */
    VIBID_DRV_E_UNSUPPORTED = 8, /* valid request this version does not implement */
    VIBID_DRV_E_SHORT = 9,       /* frame or register block too short for the signal */
    VIBID_DRV_E_NOT_PRESENT = 10,/* multiplexed signal not present in this frame */
    VIBID_DRV_E_NOT_FOUND = 11,  /* named message/signal/register/channel does not exist */
    VIBID_DRV_E_LINK = 12        /* connection lost or device not answering */
} vibid_drv_status;

/* Short static English description; never NULL. */
const char *vibid_drv_strerror(vibid_drv_status status);

/* Caller-provided holder for a failure's detail. Fixed size so that filling it never
 * allocates; texts longer than the buffer are truncated. */
#define VIBID_DRV_ERROR_LEN 1024
typedef struct vibid_drv_error {
    vibid_drv_status status;
    char text[VIBID_DRV_ERROR_LEN];
} vibid_drv_error;

/* Fills err (if not NULL) with status and printf-style text; returns status so that
 * callers can write `return vibid_drv_fail(err, VIBID_DRV_E_IO, "...")`. */
vibid_drv_status vibid_drv_fail(vibid_drv_error *err, vibid_drv_status status, const char *fmt,
                                ...) __attribute__((format(printf, 3, 4)));

#ifdef __cplusplus
}
#endif
#endif
