/* libFuzzer target: the DBC parser over arbitrary text, then decoding of a fixed and
 * of a short payload with every message it accepted. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <vibid_drivers/dbc.h>

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    vibid_drv_error err;
    vibid_dbc *d = vibid_dbc_parse((const char *)data, size, "fuzz.dbc", &err);
    if (!d) {
        if (strncmp(err.text, "fuzz.dbc", 8) != 0) /* every error names the file */
            abort();
        return 0;
    }
    uint8_t payload[64];
    for (size_t i = 0; i < sizeof payload; i++)
        payload[i] = (uint8_t)(i * 37u + 11u);
    double values[256];
    uint8_t present[256];
    for (size_t i = 0; i < vibid_dbc_message_count(d); i++) {
        const vibid_dbc_message *m = vibid_dbc_message_at(d, i);
        if (m->n_signals > 256)
            continue;
        if (vibid_dbc_message_decode(m, payload, m->length, values, present) != VIBID_DRV_OK)
            abort(); /* the reader guarantees every signal fits the declared length */
        vibid_dbc_message_decode(m, payload, m->length / 2, values, present);
    }
    vibid_dbc_destroy(d);
    return 0;
}
