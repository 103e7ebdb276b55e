/* vibid/common.h: status codes, error reporting and version query shared by every
 * part of the libvibid C API.
 *
 * Conventions that hold for the whole API:
 *  - Every function returns vibid_status, except constructors (NULL on failure, the
 *    reason in vibid_last_error()) and destructors (void, NULL-safe).
 *  - Matrices cross the API column-major and dense, with their dimensions given
 *    explicitly; element (i, j) of an r x c matrix A is A[i + j * r].
 *  - The caller owns every array it passes; the library copies what it keeps and
 *    never keeps a caller's pointer after the call returns.
 *  - When a call fails, the object it was given is left exactly as it was before.
 *  - Handles are not thread-safe: one handle is used by one thread at a time.
 *    Different handles may be used from different threads concurrently.
 */
#ifndef VIBID_COMMON_H
#define VIBID_COMMON_H

#include <stddef.h>
#include <vibid/version.h>

#ifdef __cplusplus
extern "C" {
#endif

#if defined(VIBID_BUILDING_LIBRARY)
#define VIBID_API __attribute__((visibility("default")))
#else
#define VIBID_API
#endif

typedef enum vibid_status {
    VIBID_OK = 0,
    VIBID_E_NULL_ARGUMENT = 1,    /* a required pointer argument is NULL */
    VIBID_E_DIMENSION = 2,        /* a dimension is zero, inconsistent or too large */
    VIBID_E_OUT_OF_RANGE = 3,     /* a scalar argument lies outside its documented range */
    VIBID_E_NONFINITE = 4,        /* NaN or Inf in input data */
    VIBID_E_NOT_IDENTIFIABLE = 5, /* regressor rank-deficient: parameters cannot be separated */
    VIBID_E_INSUFFICIENT_DATA = 6,/* fewer (effective) samples than the computation needs */
    VIBID_E_NUMERICAL = 7,        /* numerical breakdown (matrix not positive definite, overflow) */
    VIBID_E_NO_MEMORY = 8,        /* allocation failed (only in create/solve-type calls) */
    VIBID_E_STATE = 9,            /* call not valid in the object's current state */
    VIBID_E_DIVERGED = 10,        /* an iterative or recursive estimator diverged */
    VIBID_E_UNSUPPORTED = 11,     /* valid request that this version does not implement */
    VIBID_E_INTERNAL = 12,        /* unexpected internal error (a bug: please report) */
    VIBID_E_UNSTABLE = 13         /* the model is unstable (modal.h): the outputs are written, but
                                     describe no decaying vibration */
} vibid_status;

/* Short, static, English description of a status code. Never NULL; unknown codes
 * give "unknown status". The string lives for the life of the program. */
VIBID_API const char *vibid_strerror(vibid_status status);

/* Detail of the most recent failure on the calling thread, naming the function and
 * the offending argument, e.g. "vibid_rls_create: forgetting = 1.2 outside (0, 1]".
 * Empty string if no call on this thread has failed yet. The text is overwritten by
 * the next failing call on the same thread; copy it if you need it longer. Setting it
 * never allocates (fixed thread-local buffer), so it is safe on real-time paths. */
VIBID_API const char *vibid_last_error(void);

/* Run-time version of the library actually loaded, e.g. "0.1.0"; compare with
 * VIBID_VERSION_STRING to detect a header/library mismatch. */
VIBID_API const char *vibid_version_string(void);
/* Same as VIBID_VERSION of the loaded library. */
VIBID_API int vibid_version(void);

#ifdef __cplusplus
}
#endif
#endif
