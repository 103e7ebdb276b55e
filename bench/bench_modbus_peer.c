/* Benchmark of the Modbus source's timing against the drivers tests' Python peers on
 * 127.0.0.1 (tests/drivers/modbus_fifo_server.py, modbus_slow_server.py, driven through
 * tests/drivers/support/modbus_peer.h). Prints figures, never fails on time: these are
 * what drivers.test_source_modbus used to assert as deadlines and now only prints
 * (issue 31: the test asserts events, the speed is measured here).
 *   1. Snapshot mode at 30 ms for SECONDS: intervals between sample times (mean, std,
 *      max) and ticks missed, beside the yardstick of a bare absolute-deadline loop
 *      (clock_nanosleep TIMER_ABSTIME every 30 ms in this process for as long): what
 *      the machine's scheduler gives any periodic task now.
 *   2. The longest source read with a 100 ms call timeout, FIFO mode with 20 ms polls,
 *      for SECONDS each against: a peer answering at once (yardstick), answers 0.45 s
 *      late, answers dripped one byte per 0.45 s; beside the bound the source promises
 *      (source_modbus.c, mb_read_src: the call timeout + one poll's counter and records
 *      requests, each within the response timeout + the 50 ms byte timeout: 1.2 s at the
 *      default 0.5 s response timeout). The prompt peer's line also says how many samples
 *      the FIFO overran at 1 kHz (the test checks overrun GAPs as exact, not their absence).
 * usage: bench_modbus_peer [SECONDS]   (default 10)
 * Python: VIBID_BENCH_PYTHON, else VIBID_PYTHON, else the test venv of this build. */
#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define MODBUS_PEER_FAIL(...) (fprintf(stderr, __VA_ARGS__), fputc('\n', stderr), exit(1))
#define MODBUS_PEER_NOTE(...) fprintf(stderr, __VA_ARGS__)
#include "support/modbus_peer.h"

typedef struct interval_stats {
    double n, sum, sum2, max;
} interval_stats;

static void interval_add(interval_stats *s, double dt)
{
    s->n++;
    s->sum += dt;
    s->sum2 += dt * dt;
    if (dt > s->max)
        s->max = dt;
}

static void interval_print(const char *what, const interval_stats *s, uint64_t missed)
{
    const double mean = s->sum / s->n, var = s->sum2 / s->n - mean * mean;
    printf("  %-44s mean %8.4f ms  std %7.4f ms  max %8.4f ms  missed %llu\n", what, mean * 1e3,
           sqrt(var > 0 ? var : 0) * 1e3, s->max * 1e3, (unsigned long long)missed);
}

static void snapshot(double secs)
{
    const int64_t h = 30000000, n = (int64_t)(secs * 1e9) / h;
    interval_stats bare = {0};
    int64_t t = mono_ns(), prev = t;
    for (int64_t k = 1; k <= n; k++) {
        sleep_until_mono(t + k * h);
        const int64_t now = mono_ns();
        interval_add(&bare, (double)(now - prev) * 1e-9);
        prev = now;
    }
    vibid_regmap *rm = load_regmap();
    peer srv;
    vibid_source *s = peer_snapshot(&srv, VIBID_DRV_SERVER_PY, rm, 0.03);
    vibid_drv_error err = {0};
    interval_stats src = {0};
    uint64_t ticks = 0, missed = 0;
    int64_t last_t = 0;
    vibid_record r[16];
    while ((int64_t)ticks < n) {
        size_t got = 0;
        if (vibid_source_read(s, r, 16, &got, 100, &err) > VIBID_DRV_E_AGAIN)
            MODBUS_PEER_FAIL("read: %s", err.text);
        for (size_t i = 0; i < got; i++) {
            if (r[i].kind == VIBID_REC_GAP) {
                missed += r[i].count;
                ticks += r[i].count;
                last_t = 0; /* an interval across a GAP is not a sampling interval */
            } else if (r[i].kind == VIBID_REC_SAMPLE) {
                if (last_t)
                    interval_add(&src, (double)(r[i].t_ns - last_t) * 1e-9);
                last_t = r[i].t_ns;
                ticks++;
            }
        }
    }
    vibid_source_close(s);
    peer_finish(&srv);
    vibid_regmap_destroy(rm);
    printf("1. snapshot mode, h = 30 ms, %lld ticks:\n", (long long)n);
    interval_print("yardstick: bare clock_nanosleep loop", &bare, 0);
    interval_print("the source (sample time = answer received)", &src, missed);
}

/* The longest read call (100 ms timeout) against the slow peer in `mode`, or against
 * the plain FIFO server when mode is NULL, for secs. */
static void longest_call(const char *label, const char *mode, double secs)
{
    vibid_regmap *rm = load_regmap();
    peer srv;
    peer_start(&srv, mode ? VIBID_DRV_SLOW_SERVER_PY : VIBID_DRV_SERVER_PY, mode ? mode : "");
    vibid_source_modbus_config cfg = base_cfg(rm, srv.port);
    cfg.mode = VIBID_MODBUS_FIFO;
    cfg.sample_period_s = mode ? 0.01 : 0.001; /* the slow peer samples at 100 Hz */
    cfg.poll_period_s = 0.02;
    cfg.response_timeout_s = 0.5;
    vibid_drv_error err = {0};
    vibid_source *s = peer_open(&cfg);
    static vibid_record r[256];
    double longest = 0, total = 0;
    uint64_t calls = 0;
    const int64_t end = mono_ns() + (int64_t)(secs * 1e9);
    while (mono_ns() < end) {
        size_t got = 0;
        const int64_t t0 = mono_ns();
        if (vibid_source_read(s, r, 256, &got, 100, &err) > VIBID_DRV_E_AGAIN)
            MODBUS_PEER_FAIL("read: %s", err.text);
        const double dt = (double)(mono_ns() - t0) * 1e-9;
        longest = dt > longest ? dt : longest;
        total += dt;
        calls++;
    }
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    vibid_source_close(s);
    peer_finish(&srv);
    vibid_regmap_destroy(rm);
    printf("  %-44s longest %6.3f s  mean %6.3f s  (%llu calls, %llu samples, %llu lost to FIFO overruns, %llu "
           "timeouts)\n",
           label, longest, total / (double)calls, (unsigned long long)calls, (unsigned long long)st.samples,
           (unsigned long long)st.overruns, (unsigned long long)st.timeouts);
}

int main(int argc, char **argv)
{
    const double secs = argc > 1 ? atof(argv[1]) : 10.0;
    if (!(secs > 0)) {
        fprintf(stderr, "usage: %s [SECONDS]\n", argv[0]);
        return 2;
    }
    const char *py = getenv("VIBID_BENCH_PYTHON");
    if (py && *py)
        setenv("VIBID_PYTHON", py, 1);
    else
        setenv("VIBID_PYTHON", VIBID_BENCH_DEFAULT_PYTHON, 0);
    signal(SIGPIPE, SIG_IGN);
    printf("Modbus source timing against the Python peers on 127.0.0.1, %.0f s per figure\n", secs);
    snapshot(secs);
    printf("2. longest read, 100 ms call timeout, 0.5 s response timeout (promised bound: 0.1 + 2 x (0.5 + "
           "0.05) = 1.2 s):\n");
    longest_call("yardstick: a peer answering at once (1 kHz)", NULL, secs);
    longest_call("answers 0.45 s late", "--delay 0.45", secs);
    longest_call("answers dripped 1 byte / 0.45 s", "--drip 0.45", secs);
    return 0;
}
