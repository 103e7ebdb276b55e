// kernels_base.cpp: the baseline variant of the kernels (kernels.hpp), two doubles per
// vector: SSE2 on x86-64, which every x86-64 CPU has; NEON or scalar code elsewhere.
#include "kernels.hpp"

namespace vibid {
namespace kern {
namespace base {
#define VIBID_KERNEL_VBYTES 16
#include "kernels_impl.hpp"
#undef VIBID_KERNEL_VBYTES
}  // namespace base

const Table baseline_table = {"baseline", &base::bierman_step, &base::bierman_small, &base::qr_merge,
                                  &base::dot, &base::axpy_sum, &base::regressor_step};

}  // namespace kern
}  // namespace vibid
