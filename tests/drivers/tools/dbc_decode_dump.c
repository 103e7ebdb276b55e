/* Test helper: decodes every frame of a candump log with a DBC and prints one line per
 * present signal: "<log line> <message> <signal> <value %.17g>", so that a script can
 * compare with an independent decoder (cantools). Frames whose id the DBC lacks print
 * "<log line> UNKNOWN"; bad lines print "<log line> BAD <reason>". Exit 1 on a DBC or
 * file error. */
#include <stdio.h>
#include <vibid_drivers/candump.h>
#include <vibid_drivers/dbc.h>

int main(int argc, char **argv)
{
    if (argc != 3) {
        fprintf(stderr, "usage: %s FILE.dbc FILE.log\n", argv[0]);
        return 2;
    }
    vibid_drv_error err = {0};
    vibid_dbc *dbc = vibid_dbc_load(argv[1], &err);
    if (!dbc) {
        fprintf(stderr, "%s\n", err.text);
        return 1;
    }
    /* First the definitions, so that the script can compare them too. */
    for (size_t i = 0; i < vibid_dbc_message_count(dbc); i++) {
        const vibid_dbc_message *m = vibid_dbc_message_at(dbc, i);
        for (size_t j = 0; j < m->n_signals; j++) {
            const vibid_dbc_signal *s = &m->signals[j];
            printf("META %s %s %u %u %d %d %d %.17g %.17g %.17g %.17g \"%s\"\n", m->name, s->name,
                   s->start_bit, s->length, (int)s->byte_order, (int)s->is_signed,
                   (int)s->value_type, s->factor, s->offset, s->minimum, s->maximum, s->unit);
        }
    }
    vibid_candump_reader *r = vibid_candump_reader_open(argv[2], &err);
    if (!r) {
        fprintf(stderr, "%s\n", err.text);
        vibid_dbc_destroy(dbc);
        return 1;
    }
    vibid_candump_entry e;
    vibid_drv_status st;
    double values[512];
    uint8_t present[512];
    while ((st = vibid_candump_reader_next(r, &e)) == VIBID_DRV_OK) {
        if (e.kind == VIBID_CANDUMP_BAD_LINE) {
            printf("%lu BAD %s\n", e.line, e.text);
            continue;
        }
        if (e.kind != VIBID_CANDUMP_FRAME)
            continue;
        const vibid_dbc_message *m =
            vibid_dbc_find_message(dbc, e.frame.id, (e.frame.flags & VIBID_CAN_F_EXT) != 0);
        if (!m || m->n_signals > 512) {
            printf("%lu UNKNOWN\n", e.line);
            continue;
        }
        vibid_dbc_message_decode(m, e.frame.data, e.frame.len, values, present);
        for (size_t i = 0; i < m->n_signals; i++)
            if (present[i])
                printf("%lu %s %s %.17g\n", e.line, m->name, m->signals[i].name, values[i]);
    }
    vibid_candump_reader_close(r);
    vibid_dbc_destroy(dbc);
    return st == VIBID_DRV_E_EOF ? 0 : 1;
}
