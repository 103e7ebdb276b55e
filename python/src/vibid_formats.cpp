// vibid._core, the capture-format registry (vibid_drivers/capture_format.h), the one table of
// formats that vibidd and the package share: vibid/_captures.py takes its names, extensions
// and content recognition from here. Compiled into every build: with the drivers it comes
// from their library, without them python/CMakeLists.txt compiles capture_format.c alone
// (plain C, no dependency).
#include <nanobind/nanobind.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <string>
#include <tuple>
#include <vector>

extern "C" {
#include <vibid_drivers/capture_format.h>
}

namespace nb = nanobind;
using namespace nb::literals;

void vibid_register_formats(nb::module_ &m) {
    // [(name, aliases, extensions, title, vibidd_replays, needs_dbc)], the lists space-separated
    m.def("capture_formats", [] {
        size_t n = 0;
        const vibid_capture_format_info *t = vibid_capture_formats(&n);
        std::vector<std::tuple<std::string, std::string, std::string, std::string, bool, bool>> out;
        for (size_t i = 0; i < n; i++)
            out.emplace_back(t[i].name, t[i].aliases, t[i].extensions, t[i].title, t[i].vibidd_replays,
                             t[i].needs_dbc);
        return out;
    });
    // The format's name by the file's content, else its extension; "" when neither says.
    m.def(
        "capture_format_of_file",
        [](const std::string &path) {
            const vibid_capture_format_info *i = vibid_capture_format_info_of(vibid_capture_format_of_file(path.c_str()));
            return std::string(i ? i->name : "");
        },
        "path"_a);
}
