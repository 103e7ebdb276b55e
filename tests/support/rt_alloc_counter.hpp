// rt_alloc_counter.hpp: the allocation counter shared by the real-time tests
// (tests/*/rt_*.cpp). Include it in exactly one translation unit of a program that is
// linked against vibid_rtcheck with -Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc
// (the rt_* registration in the tests' CMakeLists does both).
//
// arm() starts counting every malloc/calloc/realloc made from the library's objects or
// the test (through the --wrap hooks) and every operator new (replaced here, because
// libstdc++'s own malloc calls are invisible to --wrap), and switches Eigen's run-time
// check on (set_is_malloc_allowed(false): an Eigen heap allocation then fails an
// assertion and aborts). disarm() stops and returns the count. Allocations inside the C
// library itself (e.g. printf) are not visible; the library's error paths only format
// into a fixed buffer.
//
// test_counters_fire is a CMocka test that proves both detectors can fire; every rt_*
// program runs it first, so that a broken hook cannot make the real checks pass.
#pragma once

#include <Eigen/Core>

#include <csignal>
#include <cstddef>
#include <cstdlib>
#include <new>

#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>

extern "C" {
#include <setjmp.h>
#include <stdarg.h>
#include <stdint.h>
#include <cmocka.h>
}

namespace {
// Plain globals: the test is single-threaded and the hooks must not allocate.
bool armed = false;
std::size_t n_alloc = 0;

void arm() {
    n_alloc = 0;
    Eigen::internal::set_is_malloc_allowed(false);
    armed = true;
}

std::size_t disarm() {
    armed = false;
    Eigen::internal::set_is_malloc_allowed(true);
    return n_alloc;
}
}  // namespace

extern "C" {
void *__real_malloc(std::size_t size);
void *__real_calloc(std::size_t n, std::size_t size);
void *__real_realloc(void *ptr, std::size_t size);

void *__wrap_malloc(std::size_t size) {
    if (armed) ++n_alloc;
    return __real_malloc(size);
}
void *__wrap_calloc(std::size_t n, std::size_t size) {
    if (armed) ++n_alloc;
    return __real_calloc(n, size);
}
void *__wrap_realloc(void *ptr, std::size_t size) {
    if (armed) ++n_alloc;
    return __real_realloc(ptr, size);
}
}

// operator new lives in libstdc++.so, whose malloc calls --wrap cannot see: replace it.
void *operator new(std::size_t size) {
    if (armed) ++n_alloc;
    if (void *p = __real_malloc(size ? size : 1)) return p;
    throw std::bad_alloc();
}
void *operator new[](std::size_t size) { return ::operator new(size); }
void *operator new(std::size_t size, const std::nothrow_t &) noexcept {
    if (armed) ++n_alloc;
    return __real_malloc(size ? size : 1);
}
void *operator new[](std::size_t size, const std::nothrow_t &tag) noexcept { return ::operator new(size, tag); }
void operator delete(void *p) noexcept { std::free(p); }
void operator delete[](void *p) noexcept { std::free(p); }
void operator delete(void *p, std::size_t) noexcept { std::free(p); }
void operator delete[](void *p, std::size_t) noexcept { std::free(p); }

namespace {

void test_counters_fire(void **state) {
    (void)state;
    // Volatile function pointers keep the compiler from eliding the allocations.
    void *(*volatile do_malloc)(std::size_t) = std::malloc;
    void *(*volatile do_new)(std::size_t) = static_cast<void *(*)(std::size_t)>(&::operator new);
    arm();
    void *a = do_malloc(16);
    void *b = do_new(16);
    const std::size_t n = disarm();
    std::free(a);
    ::operator delete(b);
    assert_int_equal(n, 2);

    // Eigen's check: a child that allocates a matrix while forbidden must abort.
    const pid_t pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        const int devnull = open("/dev/null", O_WRONLY);
        if (devnull >= 0) dup2(devnull, STDERR_FILENO);  // the assertion message is expected
        Eigen::internal::set_is_malloc_allowed(false);
        Eigen::MatrixXd m(64, 64);
        m.setZero();
        _exit(m(0, 0) == 0.0 ? 0 : 1);
    }
    int status = 0;
    assert_int_equal(waitpid(pid, &status, 0), pid);
    assert_true(WIFSIGNALED(status) && WTERMSIG(status) == SIGABRT);
}

}  // namespace
