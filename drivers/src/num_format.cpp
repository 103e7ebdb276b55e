// num_format.cpp: see vibid_drivers/num_format.h. The one C++ file of the drivers: the
// shortest round-trip conversion is libstdc++'s std::to_chars (GCC >= 11), which no C
// library on the target offers.
#include <vibid_drivers/num_format.h>

#include <charconv>
#include <cmath>
#include <cstring>

extern "C" size_t vibid_num_format(char *buf, double v)
{
    // std::to_chars writes "nan"/"-nan" and "inf"/"-inf"; a NaN's sign means nothing in a
    // capture, so it is dropped (as "%g" prints glibc's default NaN).
    if (std::isnan(v)) {
        std::memcpy(buf, "nan", 4);
        return 3;
    }
    const std::to_chars_result r = std::to_chars(buf, buf + VIBID_NUM_FORMAT_MAX - 1, v);
    // cannot fail: VIBID_NUM_FORMAT_MAX - 1 exceeds the longest text (24 characters)
    *r.ptr = '\0';
    return static_cast<size_t>(r.ptr - buf);
}
