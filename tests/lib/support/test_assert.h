/* test_assert.h: assertions the libvibid tests share (include after <cmocka.h>).
 * ASSERT_NEAR compares absolutely: |a - b| <= tol. A relative rule such as
 * tol * max(1, |b|) would hide errors on small values, so each test states which
 * comparison it makes and why. ASSERT_MSG_CONTAINS checks vibid_last_error(). */
#ifndef VIBID_TEST_ASSERT_H
#define VIBID_TEST_ASSERT_H

#include <math.h>
#include <string.h>

#include <vibid/common.h>

#define ASSERT_NEAR(a, b, tol)                                                             \
    do {                                                                                   \
        double a_ = (a), b_ = (b), t_ = (tol);                                             \
        if (!(fabs(a_ - b_) <= t_)) {                                                      \
            print_error("%s = %.17g, expected %s = %.17g (tol %g)\n", #a, a_, #b, b_, t_); \
            fail();                                                                        \
        }                                                                                  \
    } while (0)

#define ASSERT_MSG_CONTAINS(needle)                                                                   \
    do {                                                                                              \
        if (!strstr(vibid_last_error(), (needle))) {                                                  \
            print_error("last error \"%s\" does not mention \"%s\"\n", vibid_last_error(), (needle)); \
            fail();                                                                                   \
        }                                                                                             \
    } while (0)

#endif
