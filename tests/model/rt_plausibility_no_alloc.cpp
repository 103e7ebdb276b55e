// rt_plausibility_no_alloc.cpp: vibid_plausibility_check allocates nothing (it runs at
// the track-row rate in vibidd's estimation thread), on plausible and implausible
// estimates, with every output requested, and on its error paths. The reference
// (vibid_plausibility_ref_init) is made before the armed window: it allocates by design.
// Machinery: tests/support/rt_alloc_counter.hpp (see tests/model/rt_model_no_alloc.cpp).
#undef NDEBUG

#include <Eigen/Core>

#include <cmath>
#include <cstddef>
#include <cstring>

extern "C" {
#include <setjmp.h>
#include <stdarg.h>
#include <stdint.h>
#include <cmocka.h>
}

#include <vibid/modal.h>
#include <vibid/model.h>
#include <vibid/plausibility.h>

#include "../support/rt_alloc_counter.hpp"
#include "../support/example1_model.h"

namespace {

void test_check_no_alloc(void **state) {
    (void)state;
    vibid_model *m = example1_model(0);
    static vibid_plausibility_ref ref;
    assert_int_equal(vibid_plausibility_ref_init(m, nullptr, &ref), VIBID_OK);
    const double good[3] = {2.5e5, 300.0, 1.5e6}, bad[3] = {2.5e5, -3.0, -18981.0};
    double fg[2], zg[2], fb[2], zb[2];
    assert_int_equal(vibid_model_modal(m, good, nullptr, fg, nullptr, zg, nullptr, nullptr, nullptr), VIBID_OK);
    assert_int_equal(vibid_model_modal(m, bad, nullptr, fb, nullptr, zb, nullptr, nullptr, nullptr), VIBID_E_UNSTABLE);
    unsigned flags = 0, pf[3], mf[2];
    char why[512];
    std::size_t bad_status = 0, n_flagged = 0;
    arm();
    for (int k = 0; k < 1000; ++k) {
        const bool b = (k % 2) != 0;
        if (vibid_plausibility_check(m, 5e-4, b ? bad : good, b ? fb : fg, b ? zb : zg, 2, &ref, &flags, pf, mf, why,
                                     sizeof why) != VIBID_OK)
            ++bad_status;
        if (flags) ++n_flagged;
    }
    // error paths format into the fixed last-error buffer
    if (vibid_plausibility_check(m, -1.0, good, fg, zg, 2, &ref, &flags, pf, mf, why, sizeof why) !=
        VIBID_E_OUT_OF_RANGE)
        ++bad_status;
    if (vibid_plausibility_check(m, 5e-4, good, fg, zg, 1, &ref, &flags, pf, mf, why, sizeof why) != VIBID_E_DIMENSION)
        ++bad_status;
    const std::size_t n = disarm();
    assert_int_equal(bad_status, 0);
    assert_int_equal(n, 0);
    assert_int_equal(n_flagged, 500);   // every "bad" call found something
    assert_true(std::strstr(why, "c2 = -18981 N/m") != nullptr);
    vibid_model_destroy(m);
}

}  // namespace

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_counters_fire),
        cmocka_unit_test(test_check_no_alloc),
    };
    return cmocka_run_group_tests(tests, nullptr, nullptr);
}
