/* libFuzzer target: the candump log reader over arbitrary bytes must never crash,
 * hang or read out of bounds, and must account for every line. */
#include <stdint.h>
#include <stdlib.h>
#include <vibid_drivers/candump.h>

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    vibid_candump_reader *r = vibid_candump_reader_open_mem((const char *)data, size, "fuzz.log", NULL);
    if (!r)
        return 0;
    vibid_candump_entry e;
    uint64_t n = 0;
    while (vibid_candump_reader_next(r, &e) == VIBID_DRV_OK) {
        if (e.kind == VIBID_CANDUMP_FRAME) {
            char buf[256];
            /* what we read must be writable again */
            if ((e.frame.t_ns >= 0 && e.frame.iface[0]) && vibid_candump_format(buf, sizeof buf, &e.frame, NULL) < 0)
                abort();
        }
        n++;
    }
    vibid_candump_stats st;
    vibid_candump_reader_stats(r, &st);
    if (st.frames + st.bad_lines + st.drop_lines != n)
        abort();
    vibid_candump_reader_close(r);
    return 0;
}
