// api_guard.hpp: the one place where C++ exceptions become vibid_status codes.
//
// Every extern "C" entry point runs its body through vibid::guard (status-returning
// functions) or vibid::guard_create (constructors returning a handle or NULL). Inside,
// code reports bad input by throwing vibid::Error with a status and a message; the
// guard records "function: message" in the thread-local last-error buffer and returns
// the status. Nothing escapes: std::bad_alloc becomes VIBID_E_NO_MEMORY, anything else
// VIBID_E_INTERNAL.
//
// Real-time paths must not throw (an exception allocates): per-sample functions check
// their arguments with vibid::fail(), which formats into the fixed buffer and returns
// the status without throwing.
#pragma once

#include <vibid/common.h>

#include <cmath>
#include <cstring>
#include <cstddef>
#include <exception>
#include <new>
#include <stdexcept>
#include <string>
#include <type_traits>

namespace vibid {

// The value of an enum argument or configuration field as the int the C caller stored.
// A C caller can store any int there; reading one outside the enum's range as the C++
// enum type is undefined behaviour (UBSan: "load of value 99, which is not a valid value
// for type ..."), so the value is copied out of its bytes. Check it against the
// enumerators before the enum itself is read.
template <class E> int enum_value(const E &e) {
    static_assert(std::is_enum<E>::value && sizeof(E) == sizeof(int), "a C enum, stored as an int");
    int v;
    std::memcpy(&v, &e, sizeof v);
    return v;
}

class Error : public std::runtime_error {
public:
    Error(vibid_status status, const std::string &message) : std::runtime_error(message), status_(status) {}
    vibid_status status() const noexcept { return status_; }

private:
    vibid_status status_;
};

// Records "function: message" (printf-style) as the thread's last error. Never allocates.
void set_last_error(const char *function, const char *format, ...) noexcept __attribute__((format(printf, 2, 3)));

// Records the error and returns status: for non-throwing (real-time) paths.
#define VIBID_FAIL(status, ...) (::vibid::set_last_error(__func__, __VA_ARGS__), (status))

// Throws Error with a printf-style message (for create/solve paths, not real time).
[[noreturn]] void throw_error(vibid_status status, const char *format, ...) __attribute__((format(printf, 2, 3)));

// The entry point a guard is running on this thread (nullptr outside any guard), so
// that VIBID_FAIL inside a guarded lambda names the API function, not "operator()".
const char *&current_entry() noexcept;

struct EntryScope {
    explicit EntryScope(const char *function) noexcept : previous(current_entry()) { current_entry() = function; }
    ~EntryScope() { current_entry() = previous; }
    EntryScope(const EntryScope &) = delete;
    EntryScope &operator=(const EntryScope &) = delete;
    const char *previous;
};

template <class F>
vibid_status guard(const char *function, F &&body) noexcept {
    EntryScope scope(function);
    try {
        return body();
    } catch (const Error &e) {
        set_last_error(function, "%s", e.what());
        return e.status();
    } catch (const std::bad_alloc &) {
        set_last_error(function, "out of memory");
        return VIBID_E_NO_MEMORY;
    } catch (const std::exception &e) {
        set_last_error(function, "internal error: %s", e.what());
        return VIBID_E_INTERNAL;
    } catch (...) {
        set_last_error(function, "internal error: unknown exception");
        return VIBID_E_INTERNAL;
    }
}

template <class T, class F>
T *guard_create(const char *function, F &&body) noexcept {
    T *result = nullptr;
    vibid_status s = guard(function, [&]() -> vibid_status {
        result = body();
        return VIBID_OK;
    });
    return s == VIBID_OK ? result : nullptr;
}

// True if all n values are finite.
inline bool all_finite(const double *v, std::size_t n) noexcept {
    for (std::size_t i = 0; i < n; ++i)
        if (!std::isfinite(v[i])) return false;
    return true;
}

// Non-throwing finiteness check of one column-major rows x cols block (real-time paths):
// the first bad entry becomes the last error of function, as "name[i] = v" for a vector
// (cols == 1), else "name[i] (row r, column c) = v"; returns VIBID_E_NONFINITE, or OK.
inline vibid_status check_block(const char *function, const char *name, const double *A, std::size_t rows,
                                std::size_t cols) noexcept {
    for (std::size_t j = 0; j < cols; ++j)
        for (std::size_t k = 0; k < rows; ++k) {
            const double v = A[k + j * rows];
            if (!std::isfinite(v)) {
                if (cols == 1)
                    set_last_error(function, "%s[%zu] = %g is not finite", name, k, v);
                else
                    set_last_error(function, "%s[%zu] (row %zu, column %zu) = %g is not finite", name, k + j * rows,
                                   k, j, v);
                return VIBID_E_NONFINITE;
            }
        }
    return VIBID_OK;
}

// Throws VIBID_E_DIMENSION unless n_params, n_outputs >= 1 and n_params + n_outputs <= max
// (the batch estimators' create functions).
inline void check_dimensions(std::size_t n_params, std::size_t n_outputs, std::size_t max) {
    if (n_params == 0) throw_error(VIBID_E_DIMENSION, "n_params = 0, need at least 1");
    if (n_outputs == 0) throw_error(VIBID_E_DIMENSION, "n_outputs = 0, need at least 1");
    if (n_params > max || n_outputs > max || n_params + n_outputs > max)
        throw_error(VIBID_E_DIMENSION, "n_params + n_outputs = %zu + %zu exceeds %zu", n_params, n_outputs, max);
}

}  // namespace vibid

// Entry-point helpers: VIBID_GUARD(body) inside a function returning vibid_status.
#define VIBID_GUARD(...) return ::vibid::guard(__func__, [&]() -> vibid_status { __VA_ARGS__ })
