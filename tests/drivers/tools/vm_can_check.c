/* Used inside the SocketCAN VM test (vm_socketcan.sh): runs the SocketCAN source or the
 * replay source and writes every record to a text file, one line per record:
 *   S <k> <t_us> <v0> <v1> ...   sample (time truncated to microseconds, values %.17g)
 *   G <k> <count>                gap
 *   F <code> <text>              fault
 * and prints one summary line "VIBID <tag> key=value ..." to stdout.
 *
 *   vm_can_check live IFACE DBC MAP OUT EXPECT [RCVBUF [DELAY_MS]]
 *       stops when EXPECT sample indices are accounted (samples + gap counts) or after
 *       3 s without records; DELAY_MS: sleep after open before reading (drop test).
 *   vm_can_check replay LOG DBC MAP OUT
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <vibid_drivers/source_replay.h>
#include <vibid_drivers/source_socketcan.h>

static int die(const char *what, const char *text)
{
    fprintf(stderr, "vm_can_check: %s: %s\n", what, text);
    printf("VIBID error %s\n", what);
    return 1;
}

int main(int argc, char **argv)
{
    if (argc < 6)
        return die("usage", "live IFACE DBC MAP OUT EXPECT [RCVBUF [DELAY_MS]] | replay LOG DBC MAP OUT");
    const bool live = strcmp(argv[1], "live") == 0;
    vibid_drv_error err = {0};
    vibid_dbc *dbc = vibid_dbc_load(argv[3], &err);
    if (!dbc)
        return die("dbc", err.text);
    vibid_chanmap map;
    if (vibid_chanmap_load(argv[4], &map, &err) != VIBID_DRV_OK)
        return die("chanmap", err.text);
    vibid_source *s;
    unsigned long expect = 0;
    if (live) {
        if (argc < 7)
            return die("usage", "live needs EXPECT");
        expect = strtoul(argv[6], NULL, 10);
        vibid_source_socketcan_config c;
        memset(&c, 0, sizeof c);
        c.iface = argv[2];
        c.dbc = dbc;
        c.chanmap = map;
        c.rcvbuf_bytes = argc > 7 ? atoi(argv[7]) : 0;
        c.hw_timestamps = true; /* vcan has none: must fall back to software stamps */
        s = vibid_source_open(&vibid_source_socketcan_ops, &c, &err);
        if (!s)
            return die("open", err.text);
        vibid_socketcan_info info;
        vibid_source_socketcan_info(s, &info);
        printf("VIBID info fd_frames=%d hw_ts=%d so_timestamping=%d rxq_ovfl=%d rcvbuf=%d filters=%u\n",
               info.fd_frames, info.hw_timestamps, info.so_timestamping, info.rxq_ovfl, info.rcvbuf_bytes,
               info.n_filters);
        printf("VIBID ready\n");
        fflush(stdout);
        if (argc > 8) {
            int ms = atoi(argv[8]);
            struct timespec ts = {ms / 1000, (ms % 1000) * 1000000L};
            nanosleep(&ts, NULL);
        }
    } else {
        vibid_source_replay_config c;
        memset(&c, 0, sizeof c);
        c.path = argv[2];
        c.format = VIBID_REPLAY_CANDUMP;
        c.dbc = dbc;
        c.chanmap = map;
        s = vibid_source_open(&vibid_source_replay_ops, &c, &err);
        if (!s)
            return die("open", err.text);
    }
    FILE *out = fopen(argv[5], "w");
    if (!out)
        return die("output", argv[5]);
    static vibid_record r[256];
    unsigned long accounted = 0;
    int idle_ms = 0;
    for (;;) {
        size_t n;
        vibid_drv_status st = vibid_source_read(s, r, 256, &n, 100, &err);
        if (st == VIBID_DRV_E_EOF)
            break;
        if (st == VIBID_DRV_E_AGAIN) {
            idle_ms += 100;
            if (live && idle_ms >= 3000)
                break;
            continue;
        }
        if (st != VIBID_DRV_OK)
            return die("read", err.text);
        idle_ms = 0;
        for (size_t i = 0; i < n; i++) {
            const vibid_record *x = &r[i];
            if (x->kind == VIBID_REC_SAMPLE) {
                fprintf(out, "S %llu %lld", (unsigned long long)x->index, (long long)(x->t_ns / 1000));
                for (uint32_t c = 0; c < x->n_values; c++)
                    fprintf(out, " %.17g", x->values[c]);
                fputc('\n', out);
                accounted++;
            } else if (x->kind == VIBID_REC_GAP) {
                fprintf(out, "G %llu %llu\n", (unsigned long long)x->index, (unsigned long long)x->count);
                accounted += x->count;
            } else {
                fprintf(out, "F %d %s\n", (int)x->fault, x->text);
            }
        }
        if (live && expect && accounted >= expect)
            break;
    }
    fclose(out);
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    printf("VIBID %s samples=%llu gaps=%llu missing=%llu faults=%llu frames=%llu dropped=%llu error_frames=%llu "
           "bus_off=%llu sw_ts=%llu hw_ts=%llu batches=%llu unknown=%llu\n",
           live ? "live" : "replay", (unsigned long long)st.samples, (unsigned long long)st.gaps,
           (unsigned long long)st.missing_samples, (unsigned long long)st.faults, (unsigned long long)st.frames,
           (unsigned long long)st.dropped, (unsigned long long)st.error_frames, (unsigned long long)st.bus_off,
           (unsigned long long)st.sw_timestamps, (unsigned long long)st.hw_timestamps,
           (unsigned long long)st.batches, (unsigned long long)st.unknown_ids);
    vibid_source_close(s);
    vibid_dbc_destroy(dbc);
    return 0;
}
