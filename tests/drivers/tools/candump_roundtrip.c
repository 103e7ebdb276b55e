/* Test helper: reads a candump log with vibid's reader and writes every frame and
 * DROPCOUNT line back with vibid's writer. Bad lines go to stderr as "BAD file:line:
 * reason"; the exit status is 0 when the input was read to its end. */
#include <stdio.h>
#include <vibid_drivers/candump.h>

int main(int argc, char **argv)
{
    if (argc != 3) {
        fprintf(stderr, "usage: %s IN.log OUT.log\n", argv[0]);
        return 2;
    }
    vibid_drv_error err = {0};
    vibid_candump_reader *r = vibid_candump_reader_open(argv[1], &err);
    vibid_candump_writer *w = r ? vibid_candump_writer_open(argv[2], false, &err) : NULL;
    if (!w) {
        fprintf(stderr, "%s\n", err.text);
        vibid_candump_reader_close(r);
        return 1;
    }
    vibid_candump_entry e;
    vibid_drv_status st;
    int rc = 0;
    while ((st = vibid_candump_reader_next(r, &e)) == VIBID_DRV_OK) {
        if (e.kind == VIBID_CANDUMP_BAD_LINE)
            fprintf(stderr, "BAD %s\n", e.text);
        else if (e.kind == VIBID_CANDUMP_DROPCOUNT)
            rc |= vibid_candump_writer_dropcount(w, e.dropped, e.total_drops, "vcan0", &err) != VIBID_DRV_OK;
        else
            rc |= vibid_candump_writer_write(w, &e.frame, NULL, &err) != VIBID_DRV_OK;
    }
    if (vibid_candump_writer_close(w, &err) != VIBID_DRV_OK || rc) {
        fprintf(stderr, "%s\n", err.text);
        rc = 1;
    }
    vibid_candump_reader_close(r);
    return st == VIBID_DRV_E_EOF ? rc : 1;
}
