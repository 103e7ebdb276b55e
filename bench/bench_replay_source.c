/* Benchmark of the replay path below the daemon: how fast a candump log becomes samples.
 * Prints figures, never fails on time. Three stages, each timed over the whole file
 * (best of REPEATS runs, wall clock, one thread):
 *   1. baseline: read the file line by line with fgets and count lines (the I/O floor:
 *      what any line-oriented reader must pay);
 *   2. candump reader: lines parsed into CAN frames (vibid_candump_reader_next);
 *   3. replay source: frames decoded with the DBC and assembled into samples, with gap and
 *      fault records (vibid_source_read, as vibidd's acquisition thread calls it).
 * usage: bench_replay_source CAPTURE.log DBC CHANMAP.cfg SAMPLE_RATE_HZ [REPEATS]
 * CHANMAP.cfg: a libconfig file whose root holds `channels` (+ `counter`), see
 * drivers/include/vibid_drivers/channel_map.h. */
#define _POSIX_C_SOURCE 200809L /* clock_gettime under -std=c11 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <vibid_drivers/candump.h>
#include <vibid_drivers/channel_map.h>
#include <vibid_drivers/dbc.h>
#include <vibid_drivers/source.h>
#include <vibid_drivers/source_replay.h>

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static long count_lines(const char *path)
{
    FILE *f = fopen(path, "r");
    if (!f)
        return -1;
    char line[1100];
    long n = 0;
    while (fgets(line, sizeof line, f))
        n++;
    fclose(f);
    return n;
}

static long parse_frames(const char *path)
{
    vibid_drv_error err = {0};
    vibid_candump_reader *r = vibid_candump_reader_open(path, &err);
    if (!r) {
        fprintf(stderr, "%s\n", err.text);
        return -1;
    }
    vibid_candump_entry e;
    long n = 0;
    while (vibid_candump_reader_next(r, &e) == VIBID_DRV_OK)
        n += e.kind == VIBID_CANDUMP_FRAME;
    vibid_candump_reader_close(r);
    return n;
}

/* Samples delivered; *other = gap and fault records. */
static long replay_samples(const vibid_source_replay_config *cfg, long *other)
{
    vibid_drv_error err = {0};
    vibid_source *src = vibid_source_open(&vibid_source_replay_ops, cfg, &err);
    if (!src) {
        fprintf(stderr, "%s\n", err.text);
        return -1;
    }
    static vibid_record recs[64];
    long n = 0;
    *other = 0;
    for (;;) {
        size_t got = 0;
        vibid_drv_status st = vibid_source_read(src, recs, 64, &got, 0, &err);
        for (size_t i = 0; i < got; i++) {
            if (recs[i].kind == VIBID_REC_SAMPLE)
                n++;
            else
                ++*other;
        }
        if (st == VIBID_DRV_E_EOF)
            break;
        if (st != VIBID_DRV_OK && st != VIBID_DRV_E_AGAIN) {
            fprintf(stderr, "replay: %s\n", err.text);
            n = -1;
            break;
        }
    }
    vibid_source_close(src);
    return n;
}

int main(int argc, char **argv)
{
    if (argc < 5) {
        fprintf(stderr, "usage: %s CAPTURE.log DBC CHANMAP.cfg SAMPLE_RATE_HZ [REPEATS]\n", argv[0]);
        return 2;
    }
    const char *cap = argv[1];
    int repeats = argc > 5 ? atoi(argv[5]) : 3;
    if (repeats < 1)
        repeats = 1;
    vibid_drv_error err = {0};
    vibid_dbc *dbc = vibid_dbc_load(argv[2], &err);
    if (!dbc) {
        fprintf(stderr, "%s\n", err.text);
        return 1;
    }
    vibid_source_replay_config rc;
    memset(&rc, 0, sizeof rc);
    if (vibid_chanmap_load(argv[3], &rc.chanmap, &err) != VIBID_DRV_OK) {
        fprintf(stderr, "%s\n", err.text);
        return 1;
    }
    rc.path = cap;
    rc.format = VIBID_REPLAY_CANDUMP;
    rc.dbc = dbc;
    rc.speed = 1.0;
    rc.sample_period_s = 1.0 / atof(argv[4]);

    double best[3] = {1e30, 1e30, 1e30};
    long lines = 0, frames = 0, samples = 0, other = 0;
    for (int r = 0; r < repeats; r++) {
        double t0 = now_s();
        lines = count_lines(cap);
        double t1 = now_s();
        frames = parse_frames(cap);
        double t2 = now_s();
        samples = replay_samples(&rc, &other);
        double t3 = now_s();
        if (lines < 0 || frames < 0 || samples < 0)
            return 1;
        double t[3] = {t1 - t0, t2 - t1, t3 - t2};
        for (int i = 0; i < 3; i++)
            if (t[i] < best[i])
                best[i] = t[i];
    }
    printf("replay source benchmark: %s, %ld lines, %ld frames, %ld samples, %ld gap/fault records, best of %d\n",
           cap, lines, frames, samples, other, repeats);
    printf("  %-34s %8.1f ms  %7.1f ns/line  %10.0f lines/s\n", "baseline fgets line count:", 1e3 * best[0],
           1e9 * best[0] / (double)lines, (double)lines / best[0]);
    printf("  %-34s %8.1f ms  %7.1f ns/line  %10.0f frames/s  (%.2fx baseline)\n", "candump reader (parse):",
           1e3 * best[1], 1e9 * best[1] / (double)lines, (double)frames / best[1], best[1] / best[0]);
    printf("  %-34s %8.1f ms  %7.1f ns/sample %9.0f samples/s (%.2fx baseline)\n", "replay source (DBC + assembly):",
           1e3 * best[2], 1e9 * best[2] / (double)samples, (double)samples / best[2], best[2] / best[0]);
    vibid_dbc_destroy(dbc);
    return 0;
}
