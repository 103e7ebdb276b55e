// kernels.cpp: chooses the kernel table once per process (kernels.hpp).
#include "kernels.hpp"

#include <cstdlib>
#include <cstring>

namespace vibid {
namespace kern {

namespace {

// VIBID_FORCE_BASELINE set to anything but "" or "0" forces the baseline kernels.
bool force_baseline() {
    const char *v = std::getenv("VIBID_FORCE_BASELINE");
    return v && *v && std::strcmp(v, "0") != 0;
}

const Table &choose() {
#if defined(VIBID_HAVE_AVX2_KERNELS)
    if (!force_baseline()) {
        __builtin_cpu_init();
        if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")) return avx2_table;
    }
#else
    (void)force_baseline;
#endif
    return baseline_table;
}

}  // namespace

const Table &active() {
    // A function-local static: initialised once, thread-safe, before the first use.
    static const Table &chosen = choose();
    return chosen;
}

const Table &baseline() { return baseline_table; }

}  // namespace kern
}  // namespace vibid
