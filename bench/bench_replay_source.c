/* Benchmark of the replay path below the daemon: how fast a capture becomes samples.
 * Prints figures, never fails on time. Each stage runs over the whole file, best of
 * REPEATS runs, one thread, timed in CPU time of the process (CLOCK_PROCESS_CPUTIME_ID:
 * user + system, so the read() copies count, but time spent descheduled by other work on
 * a shared machine does not). Stages, each including the ones before it:
 *   candump log
 *   0. yardstick: fgets line count (what any line-oriented reader pays for I/O);
 *   1. the drivers' line reader alone (file_util.h);
 *   2. + candump parse into CAN frames (vibid_candump_reader_next);
 *   3. + DBC decoding and sample assembly, gap and fault records, the source's queue
 *      (vibid_source_read, as vibidd's acquisition thread calls it).
 *   CSV capture (CAPTURE.csv, or CAPTURE with .log replaced by .csv when that exists)
 *   0. yardstick: fgets line count;
 *   1. number conversion alone, per value, on the capture's own fields in memory: glibc
 *      strtod (the yardstick) against vibid_parse_decimal (num_parse.h), with the check
 *      that every value it handles is bit-identical to strtod's;
 *   2. the CSV replay source (vibid_source_read).
 * usage: bench_replay_source CAPTURE.log DBC CHANMAP.cfg SAMPLE_RATE_HZ [REPEATS [CAPTURE.csv]]
 * CHANMAP.cfg: a libconfig file whose root holds `channels` (+ `counter`), see
 * drivers/include/vibid_drivers/channel_map.h. The CSV replay uses the same channels as
 * columns of the same names, with time column "t" (what vibid-sim writes). */
#define _POSIX_C_SOURCE 200809L /* clock_gettime under -std=c11 */
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <vibid_drivers/candump.h>
#include <vibid_drivers/channel_map.h>
#include <vibid_drivers/dbc.h>
#include <vibid_drivers/source.h>
#include <vibid_drivers/source_replay.h>

#include "file_util.h" /* drivers/src: the line reader, timed on its own */
#include "num_parse.h" /* drivers/src: the fast exact number parser */

static double cpu_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
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

static long line_reader_lines(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return -1;
    static vibid_line_reader lr; /* 66 KB: not on the stack */
    vibid_line_reader_init_file(&lr, f);
    const char *line;
    size_t len;
    bool too_long;
    long n = 0;
    while (vibid_line_reader_next(&lr, &line, &len, &too_long) == 1)
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

/* The numeric fields of a CSV capture (header and comments skipped), each
 * NUL-terminated in one buffer: field i starts at text + start[i]. */
typedef struct fields {
    char *text;
    size_t *start, n;
} fields;

static bool load_fields(const char *path, size_t max, fields *fl)
{
    FILE *f = fopen(path, "r");
    if (!f)
        return false;
    size_t cap_text = 64 * max, used = 0;
    fl->text = malloc(cap_text);
    fl->start = malloc(max * sizeof *fl->start);
    fl->n = 0;
    char line[1100];
    bool header = true;
    while (fl->text && fl->start && fl->n < max && fgets(line, sizeof line, f)) {
        if (line[0] == '#' || line[0] == '\n')
            continue;
        if (header) {
            header = false;
            continue;
        }
        for (char *p = strtok(line, ",\r\n"); p && fl->n < max; p = strtok(NULL, ",\r\n")) {
            size_t k = strlen(p) + 1;
            if (used + k > cap_text)
                break;
            memcpy(fl->text + used, p, k);
            fl->start[fl->n++] = used;
            used += k;
        }
    }
    fclose(f);
    return fl->text && fl->start && fl->n > 0;
}

int main(int argc, char **argv)
{
    if (argc < 5) {
        fprintf(stderr, "usage: %s CAPTURE.log DBC CHANMAP.cfg SAMPLE_RATE_HZ [REPEATS [CAPTURE.csv]]\n", argv[0]);
        return 2;
    }
    const char *cap = argv[1];
    int repeats = argc > 5 ? atoi(argv[5]) : 3;
    if (repeats < 1)
        repeats = 1;
    char csv_path[4096] = "";
    if (argc > 6) {
        snprintf(csv_path, sizeof csv_path, "%s", argv[6]);
    } else {
        size_t l = strlen(cap);
        if (l > 4 && l < sizeof csv_path && strcmp(cap + l - 4, ".log") == 0) {
            snprintf(csv_path, sizeof csv_path, "%.*s.csv", (int)(l - 4), cap);
            FILE *t = fopen(csv_path, "r");
            if (t)
                fclose(t);
            else
                csv_path[0] = '\0';
        }
    }
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

    double best[4] = {1e30, 1e30, 1e30, 1e30};
    long lines = 0, lines2 = 0, frames = 0, samples = 0, other = 0;
    for (int r = 0; r < repeats; r++) {
        double t0 = cpu_s();
        lines = count_lines(cap);
        double t1 = cpu_s();
        lines2 = line_reader_lines(cap);
        double t2 = cpu_s();
        frames = parse_frames(cap);
        double t3 = cpu_s();
        samples = replay_samples(&rc, &other);
        double t4 = cpu_s();
        if (lines < 0 || lines2 != lines || frames < 0 || samples <= 0)
            return 1;
        double t[4] = {t1 - t0, t2 - t1, t3 - t2, t4 - t3};
        for (int i = 0; i < 4; i++)
            if (t[i] < best[i])
                best[i] = t[i];
    }
    double lps = (double)lines / (double)samples; /* lines per sample */
    double ns_line[4], ns_sample[4];
    for (int i = 0; i < 4; i++) {
        ns_line[i] = 1e9 * best[i] / (double)lines;
        ns_sample[i] = 1e9 * best[i] / (double)samples;
    }
    printf("replay source benchmark: %s, %ld lines, %ld frames, %ld samples (%.2f lines each), %ld gap/fault "
           "records, best of %d, CPU time\n",
           cap, lines, frames, samples, lps, other, repeats);
    printf("  %-40s %7.1f ms %6.1f ns/line %7.1f ns/sample\n", "yardstick: fgets line count", 1e3 * best[0],
           ns_line[0], ns_sample[0]);
    printf("  %-40s %7.1f ms %6.1f ns/line %7.1f ns/sample (%.2fx fgets)\n", "1. line reader", 1e3 * best[1],
           ns_line[1], ns_sample[1], best[1] / best[0]);
    printf("  %-40s %7.1f ms %6.1f ns/line %7.1f ns/sample (%.2fx fgets); parse alone %.1f ns/line\n",
           "2. + candump parse", 1e3 * best[2], ns_line[2], ns_sample[2], best[2] / best[0], ns_line[2] - ns_line[1]);
    printf("  %-40s %7.1f ms %6.1f ns/line %7.1f ns/sample (%.2fx fgets); decode + assembly alone %.1f ns/sample\n",
           "3. + DBC decode, assembly (source read)", 1e3 * best[3], ns_line[3], ns_sample[3], best[3] / best[0],
           ns_sample[3] - ns_sample[2]);
    printf("  candump replay source: %.0f samples/s on one thread\n", (double)samples / best[3]);

    if (csv_path[0]) {
        fields fl = {0};
        if (!load_fields(csv_path, 2000000, &fl)) {
            fprintf(stderr, "%s: cannot read its fields\n", csv_path);
            return 1;
        }
        vibid_source_replay_config cc = rc;
        cc.path = csv_path;
        cc.format = VIBID_REPLAY_CSV;
        cc.dbc = NULL;
        cc.chanmap.counter[0] = '\0';
        snprintf(cc.chanmap.time_column, sizeof cc.chanmap.time_column, "t");
        for (size_t c = 0; c < cc.chanmap.n; c++) {
            cc.chanmap.ch[c].source = VIBID_CHAN_COLUMN;
            snprintf(cc.chanmap.ch[c].ref, sizeof cc.chanmap.ch[c].ref, "%s", cc.chanmap.ch[c].name);
            cc.chanmap.ch[c].message[0] = '\0';
        }
        double cbest[4] = {1e30, 1e30, 1e30, 1e30};
        long clines = 0, csamples = 0, cother = 0;
        size_t handled = 0, mismatches = 0;
        volatile double sink = 0;
        for (int r = 0; r < repeats; r++) {
            double t0 = cpu_s();
            clines = count_lines(csv_path);
            double t1 = cpu_s();
            double acc = 0;
            for (size_t i = 0; i < fl.n; i++)
                acc += strtod(fl.text + fl.start[i], NULL);
            double t2 = cpu_s();
            for (size_t i = 0; i < fl.n; i++) {
                const char *s = fl.text + fl.start[i];
                double v;
                if (vibid_parse_decimal(s, s + strlen(s), &v))
                    acc += v;
                else
                    acc += strtod(s, NULL);
            }
            double t3 = cpu_s();
            csamples = replay_samples(&cc, &cother);
            double t4 = cpu_s();
            sink = acc;
            if (clines < 0 || csamples <= 0)
                return 1;
            double t[4] = {t1 - t0, t2 - t1, t3 - t2, t4 - t3};
            for (int i = 0; i < 4; i++)
                if (t[i] < cbest[i])
                    cbest[i] = t[i];
        }
        (void)sink;
        for (size_t i = 0; i < fl.n; i++) { /* the check, outside the timing */
            const char *s = fl.text + fl.start[i];
            double v, ref = strtod(s, NULL);
            if (vibid_parse_decimal(s, s + strlen(s), &v)) {
                handled++;
                mismatches += memcmp(&v, &ref, sizeof v) != 0;
            }
        }
        printf("CSV: %s, %ld lines, %ld samples, %ld gap/fault records; %zu values timed\n", csv_path, clines,
               csamples, cother, fl.n);
        printf("  %-40s %7.1f ms %6.1f ns/line\n", "yardstick: fgets line count", 1e3 * cbest[0],
               1e9 * cbest[0] / (double)clines);
        printf("  %-40s %7.1f ms %6.1f ns/value\n", "yardstick: glibc strtod", 1e3 * cbest[1],
               1e9 * cbest[1] / (double)fl.n);
        printf("  %-40s %7.1f ms %6.1f ns/value (%.2fx strtod); %zu of %zu handled without strtod, %zu differ "
               "from strtod\n",
               "vibid_parse_decimal (+ strtod fallback)", 1e3 * cbest[2], 1e9 * cbest[2] / (double)fl.n,
               cbest[2] / cbest[1], handled, fl.n, mismatches);
        printf("  %-40s %7.1f ms %6.1f ns/line %7.1f ns/sample (%.2fx fgets)\n", "CSV replay source (source read)",
               1e3 * cbest[3], 1e9 * cbest[3] / (double)clines, 1e9 * cbest[3] / (double)csamples,
               cbest[3] / cbest[0]);
        printf("  CSV replay source: %.0f samples/s on one thread\n", (double)csamples / cbest[3]);
        free(fl.text);
        free(fl.start);
        if (mismatches)
            return 1; /* a wrong value is a bug, not a timing */
    }
    vibid_dbc_destroy(dbc);
    return 0;
}
