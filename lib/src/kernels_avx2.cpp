// kernels_avx2.cpp: the AVX2+FMA variant of the kernels (kernels.hpp), four doubles per
// vector with fused multiply-adds. lib/CMakeLists.txt compiles this file alone with
// -mavx2 -mfma and defines VIBID_HAVE_AVX2_KERNELS when the compiler targets x86-64;
// elsewhere it is empty. It is called only after kernels.cpp has checked that the CPU
// (and the OS, via XSAVE) supports both.
#include "kernels.hpp"

#if defined(VIBID_HAVE_AVX2_KERNELS)
#if !defined(__AVX2__) || !defined(__FMA__)
#error "kernels_avx2.cpp must be compiled with -mavx2 -mfma"
#endif

namespace vibid {
namespace kern {
namespace avx2 {
#define VIBID_KERNEL_VBYTES 32
#include "kernels_impl.hpp"
#undef VIBID_KERNEL_VBYTES
}  // namespace avx2

const Table avx2_table = {"avx2+fma", &avx2::bierman_step, &avx2::bierman_small, &avx2::qr_merge,
                                  &avx2::dot, &avx2::axpy_sum, &avx2::regressor_step};

}  // namespace kern
}  // namespace vibid
#endif
