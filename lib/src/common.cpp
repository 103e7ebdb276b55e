// common.cpp: status strings, the thread-local last-error buffer, version query.
#include "api_guard.hpp"

#include <cstdarg>
#include <cstdio>
#include <cstring>

namespace {
// 512 bytes hold any message we format; longer ones are truncated, never overflow.
thread_local char last_error_buffer[512];

void vformat_last_error(const char *function, const char *format, va_list args) noexcept {
    int n = std::snprintf(last_error_buffer, sizeof last_error_buffer, "%s: ", function ? function : "vibid");
    if (n < 0) n = 0;
    if (static_cast<size_t>(n) < sizeof last_error_buffer)
        std::vsnprintf(last_error_buffer + n, sizeof last_error_buffer - static_cast<size_t>(n), format, args);
}
}  // namespace

namespace vibid {

const char *&current_entry() noexcept {
    thread_local const char *entry = nullptr;
    return entry;
}

void set_last_error(const char *function, const char *format, ...) noexcept {
    // __func__ inside a guarded lambda is "operator()": name the API entry point instead.
    if (function && current_entry() && std::strcmp(function, "operator()") == 0) function = current_entry();
    va_list args;
    va_start(args, format);
    vformat_last_error(function, format, args);
    va_end(args);
}

void throw_error(vibid_status status, const char *format, ...) {
    char message[448];
    va_list args;
    va_start(args, format);
    std::vsnprintf(message, sizeof message, format, args);
    va_end(args);
    throw Error(status, message);
}

}  // namespace vibid

extern "C" {

VIBID_API const char *vibid_strerror(vibid_status status) {
    switch (status) {
    case VIBID_OK: return "success";
    case VIBID_E_NULL_ARGUMENT: return "required argument is NULL";
    case VIBID_E_DIMENSION: return "dimension is zero, inconsistent or too large";
    case VIBID_E_OUT_OF_RANGE: return "argument outside its valid range";
    case VIBID_E_NONFINITE: return "NaN or Inf in input data";
    case VIBID_E_NOT_IDENTIFIABLE: return "parameters not identifiable (regressor rank-deficient)";
    case VIBID_E_INSUFFICIENT_DATA: return "not enough data";
    case VIBID_E_NUMERICAL: return "numerical breakdown";
    case VIBID_E_NO_MEMORY: return "out of memory";
    case VIBID_E_STATE: return "call not valid in the current state";
    case VIBID_E_DIVERGED: return "estimator diverged";
    case VIBID_E_UNSUPPORTED: return "not supported";
    case VIBID_E_INTERNAL: return "internal error";
    case VIBID_E_UNSTABLE: return "model is unstable";
    }
    return "unknown status";
}

VIBID_API const char *vibid_last_error(void) { return last_error_buffer; }

VIBID_API const char *vibid_version_string(void) { return VIBID_VERSION_STRING; }

VIBID_API int vibid_version(void) { return VIBID_VERSION; }

}  // extern "C"
