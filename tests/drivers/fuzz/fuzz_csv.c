/* libFuzzer target: the CSV capture reader over arbitrary bytes. */
#include <stdint.h>
#include <stdlib.h>
#include <vibid_drivers/csv_capture.h>

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    vibid_csv_reader *r = vibid_csv_open_mem((const char *)data, size, "fuzz.csv", NULL);
    if (!r)
        return 0;
    double v[VIBID_CSV_MAX_COLUMNS];
    vibid_drv_status st;
    unsigned long line;
    while ((st = vibid_csv_next(r, v, &line, NULL)) == VIBID_DRV_OK || st == VIBID_DRV_E_SYNTAX)
        ;
    if (st != VIBID_DRV_E_EOF)
        abort();
    vibid_csv_close(r);
    return 0;
}
