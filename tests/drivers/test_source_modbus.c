/* Modbus source against an independent server (pymodbus, modbus_fifo_server.py, which
 * implements drivers/modbus_fifo_layout.md on its own) on 127.0.0.1:
 *  - FIFO mode at 1 kHz across a server stop/restart: every sample of each server
 *    session arrives exactly once, in order, with the exact values of the known signal;
 *    the outage is LINK faults + one GAP whose (estimated) length matches the pause;
 *  - snapshot mode at 100 Hz: consistent samples on an absolute-deadline clock;
 *  - a server that accepts but never answers: timeouts counted, link declared lost,
 *    reconnects with backoff, every failed poll counted, no sample invented;
 *  - hostile peers (issue 12): a FIFO header that does not fit or reads all zeros (a
 *    rebooting device) is retried, never the end of the source; a flapping session id
 *    gives every sample exactly once; a random counter is not believed, and the samples
 *    lost meanwhile are a GAP as long as the elapsed time.
 * Needs the venv's Python (VIBID_PYTHON); its absence FAILS the test. */
#include <arpa/inet.h>
#include <math.h>
#include <netinet/in.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <cmocka.h>
#include <vibid_drivers/source_modbus.h>

#include "support/drv_test_util.h"

static const char regmap_text[] =
    "registers = (\n"
    "  { name = \"a\"; address = 0;  register = \"holding\"; type = \"FLOAT32\"; byte_order = \"ABCD\"; },\n"
    "  { name = \"b\"; address = 2;  register = \"holding\"; type = \"INT16\";   scale = 0.001; },\n"
    "  { name = \"c\"; address = 10; register = \"holding\"; type = \"FLOAT32\"; byte_order = \"CDAB\"; }\n"
    ");\n";

static int64_t mono(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

static int free_port(void)
{
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    bind(fd, (struct sockaddr *)&a, sizeof a);
    socklen_t l = sizeof a;
    getsockname(fd, (struct sockaddr *)&a, &l);
    close(fd);
    return ntohs(a.sin_port);
}

/* Starts the pymodbus server; returns its stdout after it printed READY. */
static FILE *start_server_args(int port, const char *schedule, const char *extra)
{
    const char *py = getenv("VIBID_PYTHON");
    if (!py || access(py, X_OK) != 0)
        fail_msg("FAIL: VIBID_PYTHON='%s' is not an executable venv interpreter (scripts/python-venv.sh)",
                 py ? py : "");
    char cmd[1024];
    snprintf(cmd, sizeof cmd, "'%s' '%s' --port %d --schedule %s --max-time 20 %s", py, VIBID_DRV_SERVER_PY, port,
             schedule, extra);
    FILE *p = popen(cmd, "r");
    assert_non_null(p);
    char line[128];
    if (!fgets(line, sizeof line, p) || strncmp(line, "READY", 5) != 0)
        fail_msg("pymodbus server did not start (%s)", cmd);
    return p;
}

static FILE *start_server(int port, const char *schedule) { return start_server_args(port, schedule, ""); }

static vibid_source_modbus_config base_cfg(const vibid_regmap *rm, int port);

/* FIFO source on 127.0.0.1:port, h = 1 ms, 20 ms polls; fails the test if it cannot open. */
static vibid_source *open_fifo(const vibid_regmap *rm, int port)
{
    vibid_source_modbus_config cfg = base_cfg(rm, port);
    cfg.mode = VIBID_MODBUS_FIFO;
    cfg.sample_period_s = 1e-3;
    cfg.poll_period_s = 0.02;
    vibid_drv_error err = {0};
    vibid_source *s = vibid_source_open(&vibid_source_modbus_ops, &cfg, &err);
    if (!s)
        fail_msg("%s", err.text);
    return s;
}

static vibid_regmap *load_regmap(void)
{
    char path[512];
    assert_non_null(drv_write_tmp("regs.cfg", regmap_text, sizeof regmap_text - 1, path, sizeof path));
    vibid_drv_error err = {0};
    vibid_regmap *rm = vibid_regmap_load(path, &err);
    if (!rm)
        fail_msg("%s", err.text);
    unlink(path);
    return rm;
}

static vibid_source_modbus_config base_cfg(const vibid_regmap *rm, int port)
{
    vibid_source_modbus_config c;
    memset(&c, 0, sizeof c);
    c.transport = VIBID_MODBUS_TCP;
    c.host = "127.0.0.1";
    c.port = port;
    c.regmap = rm;
    c.chanmap.n = 3;
    const char *names[] = {"a", "b", "c"};
    for (int i = 0; i < 3; i++) {
        strcpy(c.chanmap.ch[i].name, names[i]);
        strcpy(c.chanmap.ch[i].ref, names[i]);
        c.chanmap.ch[i].source = VIBID_CHAN_REGISTER;
    }
    c.response_timeout_s = 0.2;
    c.backoff_initial_s = 0.05;
    c.backoff_max_s = 0.4;
    return c;
}

/* The server's signal: sample s has c = 0.5 s (exact in float32 below 2^24), a = sin(0.01 s)
 * rounded to float32, b = ((s mod 1000) - 500) * 0.001. Returns s, or fails. */
static long check_values(const vibid_record *r)
{
    double s = r->values[2] * 2.0;
    if (s < 0 || s != floor(s))
        fail_msg("sample %llu: c = %.9g is not 0.5 * integer", (unsigned long long)r->index, r->values[2]);
    long si = (long)s;
    double a = (double)(float)sin(0.01 * s);
    double b = (double)((si % 1000) - 500) * 0.001;
    /* a: float32 bit-exact; b: raw integer * 0.001 computed identically -> exact */
    if (r->values[0] != a || r->values[1] != b)
        fail_msg("sample %llu (s = %ld): a = %.9g (want %.9g), b = %.9g (want %.9g)", (unsigned long long)r->index,
                 si, r->values[0], a, r->values[1], b);
    return si;
}

static void test_fifo_restart(void **state)
{
    (void)state;
    int port = free_port();
    vibid_regmap *rm = load_regmap();
    FILE *srv = start_server(port, "1.2,0.8,1.2"); /* serve, stop 0.8 s, serve (new session) */
    vibid_drv_error err = {0};
    vibid_source *s = open_fifo(rm, port);
    static vibid_record r[256];
    size_t n;
    uint64_t next_k = 0;
    long last_s = -1;
    int session = 0;
    uint64_t samples[2] = {0, 0}, gap_count = 0, gaps = 0, link_faults = 0;
    int64_t end = mono() + (int64_t)3.4e9;
    while (mono() < end) {
        vibid_drv_status st = vibid_source_read(s, r, 256, &n, 50, &err);
        if (st != VIBID_DRV_OK && st != VIBID_DRV_E_AGAIN)
            fail_msg("read: %s", err.text);
        for (size_t i = 0; i < n; i++) {
            if (r[i].kind == VIBID_REC_FAULT) {
                link_faults += r[i].fault == VIBID_FAULT_LINK;
                continue;
            }
            assert_int_equal(r[i].index, next_k); /* every k exactly once */
            if (r[i].kind == VIBID_REC_GAP) {
                print_message("gap: k=%llu count=%llu: %s\n", (unsigned long long)r[i].index,
                              (unsigned long long)r[i].count, r[i].text);
                gaps++;
                gap_count += r[i].count;
                next_k += r[i].count;
                continue;
            }
            long sv = check_values(&r[i]);
            if (sv != last_s + 1) {
                /* only allowed at the start of the second session, which restarts at s = 0 */
                if (!(session == 0 && sv == 0 && last_s > 0))
                    fail_msg("s jumped from %ld to %ld at k=%llu", last_s, sv, (unsigned long long)next_k);
                session = 1;
            }
            samples[session]++;
            last_s = sv;
            next_k++;
        }
    }
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    print_message("FIFO: session samples %llu + %llu, %llu gap(s) of %llu samples, polls %llu, failed polls %llu, "
                  "requests %llu, link losses %llu, connect failures %llu, reconnects %llu\n",
                  (unsigned long long)samples[0], (unsigned long long)samples[1], (unsigned long long)gaps,
                  (unsigned long long)gap_count, (unsigned long long)st.polls, (unsigned long long)st.failed_polls,
                  (unsigned long long)st.requests, (unsigned long long)st.link_losses,
                  (unsigned long long)st.connect_failures, (unsigned long long)st.reconnects);
    vibid_source_close(s);
    char line[128];
    unsigned long served[2] = {0, 0};
    int ph;
    unsigned long cnt;
    while (fgets(line, sizeof line, srv))
        if (sscanf(line, "PHASE %d served %lu", &ph, &cnt) == 2)
            served[ph == 0 ? 0 : 1] = cnt;
    assert_int_equal(pclose(srv), 0);
    /* Each session: every sample the server produced while we were connected; the
     * server's final samples of a session (written after our last poll, < poll period
     * + request time = 20 ms + margin -> at most 60) cannot be read once it stops. */
    for (int i = 0; i < 2; i++)
        if (served[i] < 1000 || samples[i] + 60 < served[i] || samples[i] > served[i])
            fail_msg("session %d: %llu samples received, server wrote %lu", i, (unsigned long long)samples[i],
                     served[i]);
    /* The outage: one GAP (merged), its length estimated from elapsed time: the pause of
     * 0.8 s plus the unread tail of session 1 (<= 60) -> 800 .. 1000 with +-100 slack for
     * scheduling of the Python server. */
    assert_int_equal(gaps, 1);
    if (gap_count < 700 || gap_count > 1100)
        fail_msg("outage gap %llu samples, expected about 800..1000", (unsigned long long)gap_count);
    assert_true(st.link_losses >= 1 && st.reconnects >= 1 && st.connect_failures >= 1);
    assert_true(st.failed_polls >= 1 && link_faults >= 3);
    assert_int_equal(st.samples, samples[0] + samples[1]);
    vibid_regmap_destroy(rm);
}

/* Where a FIFO session starts: the server produced 1300 samples into its K = 500 ring and
 * stopped (so the window is fixed). The oldest slot is the next the server overwrites,
 * so the source starts K/8 = 62 records after it: samples 862 .. 1299 (438 of them),
 * index 0 .. 437, and no gap record (nothing was expected before the session began). */
static void test_fifo_start_margin(void **state)
{
    (void)state;
    int port = free_port();
    vibid_regmap *rm = load_regmap();
    FILE *srv = start_server_args(port, "5", "--stop-after 1300");
    struct timespec ts = {2, 0}; /* 1.3 s to produce the 1300 samples, + margin for a loaded machine */
    nanosleep(&ts, NULL);
    vibid_drv_error err = {0};
    vibid_source *s = open_fifo(rm, port);
    static vibid_record r[256];
    size_t n, got = 0;
    long first = -1, last = -1;
    int64_t end = mono() + (int64_t)1.5e9; /* one poll reads all; the rest shows nothing more comes */
    while (mono() < end) {
        vibid_drv_status st = vibid_source_read(s, r, 256, &n, 50, &err);
        if (st != VIBID_DRV_OK && st != VIBID_DRV_E_AGAIN)
            fail_msg("read: %s", err.text);
        for (size_t i = 0; i < n; i++) {
            if (r[i].kind != VIBID_REC_SAMPLE)
                fail_msg("record kind %d at index %llu: %s", r[i].kind, (unsigned long long)r[i].index, r[i].text);
            assert_int_equal(r[i].index, got);
            long sv = check_values(&r[i]);
            if (first < 0)
                first = sv;
            else
                assert_int_equal(sv, last + 1);
            last = sv;
            got++;
        }
    }
    vibid_source_close(s);
    while (fgets((char[128]){0}, 128, srv)) {
    }
    pclose(srv);
    print_message("FIFO start: samples %ld .. %ld (%zu)\n", first, last, got);
    assert_int_equal(first, 1300 - 500 + 500 / 8);
    assert_int_equal(last, 1299);
    assert_int_equal(got, 500 - 500 / 8);
    vibid_regmap_destroy(rm);
}

static void test_snapshot(void **state)
{
    (void)state;
    int port = free_port();
    vibid_regmap *rm = load_regmap();
    FILE *srv = start_server(port, "1.5");
    vibid_source_modbus_config cfg = base_cfg(rm, port);
    cfg.mode = VIBID_MODBUS_SNAPSHOT;
    /* 30 ms: the Python server answers within ~7 ms here, but this 2-core VM stalls now
     * and then for tens of ms; a tick missed that way is a GAP record (counted, not
     * invented), which is correct behaviour: at most 3 are tolerated below (at 10 ms
     * without tolerance the test failed 2 runs in 3 here) */
    cfg.sample_period_s = 0.03;
    vibid_drv_error err = {0};
    vibid_source *s = vibid_source_open(&vibid_source_modbus_ops, &cfg, &err);
    if (!s)
        fail_msg("%s", err.text);
    vibid_record r[16];
    size_t n, samples = 0, missed = 0;
    int64_t end = mono() + (int64_t)1.2e9; /* the server's schedule serves 1.5 s */
    long last = -1;
    while (mono() < end) {
        vibid_drv_status st = vibid_source_read(s, r, 16, &n, 20, &err);
        assert_true(st == VIBID_DRV_OK || st == VIBID_DRV_E_AGAIN);
        for (size_t i = 0; i < n; i++) {
            if (r[i].kind == VIBID_REC_GAP) { /* ticks missed: indices skip by exactly the count */
                assert_int_equal(r[i].index, samples);
                missed += r[i].count;
                samples += r[i].count;
                continue;
            }
            if (r[i].kind != VIBID_REC_SAMPLE)
                fail_msg("unexpected record kind %d: %s", r[i].kind, r[i].text);
            assert_int_equal(r[i].index, samples);
            long sv = check_values(&r[i]); /* one snapshot = one consistent server sample */
            assert_true(sv >= last);
            last = sv;
            samples++;
        }
    }
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    print_message("snapshot: %zu ticks (%zu missed) in 1.2 s, interval mean %.4f ms std %.4f ms max %.4f ms, "
                  "blocks: %llu requests / %llu polls\n",
                  samples, missed, st.jitter.mean_s * 1e3, st.jitter.std_s * 1e3, st.jitter.max_s * 1e3,
                  (unsigned long long)st.requests, (unsigned long long)st.polls);
    /* 1.2 s / 30 ms = 40 ticks (+1 for the first); registers 0..2 and 10..11 fit in one
     * request (1 request per poll); the mean interval is the period to 1 ms */
    assert_true(samples >= 39 && samples <= 41);
    assert_true(missed <= 3);
    assert_int_equal(st.requests, st.polls);
    /* each missed tick stretches one interval by a period: 0.75 ms on the mean of 40 */
    assert_true(fabs(st.jitter.mean_s - 0.03) < 1e-3 + 0.03 * (double)missed / 40.0);
    vibid_source_close(s);
    while (fgets((char[128]){0}, 128, srv)) {
    }
    pclose(srv);
    vibid_regmap_destroy(rm);
}

/* A listener that completes TCP handshakes (kernel backlog) but never answers. */
static void test_silent_server(void **state)
{
    (void)state;
    int lfd = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    assert_int_equal(bind(lfd, (struct sockaddr *)&a, sizeof a), 0);
    socklen_t l = sizeof a;
    getsockname(lfd, (struct sockaddr *)&a, &l);
    assert_int_equal(listen(lfd, 16), 0);
    vibid_regmap *rm = load_regmap();
    vibid_source_modbus_config cfg = base_cfg(rm, ntohs(a.sin_port));
    cfg.mode = VIBID_MODBUS_SNAPSHOT;
    cfg.sample_period_s = 0.01;
    cfg.response_timeout_s = 0.05;
    vibid_drv_error err = {0};
    vibid_source *s = vibid_source_open(&vibid_source_modbus_ops, &cfg, &err);
    if (!s)
        fail_msg("%s", err.text);
    vibid_record r[64];
    size_t n, samples = 0, missing = 0, faults = 0;
    int64_t end = mono() + (int64_t)0.7e9;
    while (mono() < end) {
        vibid_drv_status st = vibid_source_read(s, r, 64, &n, 50, &err);
        assert_true(st == VIBID_DRV_OK || st == VIBID_DRV_E_AGAIN);
        for (size_t i = 0; i < n; i++) {
            samples += r[i].kind == VIBID_REC_SAMPLE;
            missing += r[i].kind == VIBID_REC_GAP ? r[i].count : 0;
            faults += r[i].kind == VIBID_REC_FAULT;
        }
    }
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    print_message("silent server: %llu timeouts, %llu failed polls, %llu link losses, %llu reconnects, %zu missing "
                  "samples as GAP, %zu faults, 0 samples\n",
                  (unsigned long long)st.timeouts, (unsigned long long)st.failed_polls,
                  (unsigned long long)st.link_losses, (unsigned long long)st.reconnects, missing, faults);
    assert_int_equal(samples, 0);
    assert_true(st.timeouts >= 3 && st.failed_polls == st.timeouts && st.link_losses >= 1 && st.reconnects >= 1);
    assert_true(missing >= 10); /* every elapsed tick accounted as missing */
    vibid_source_close(s);
    close(lfd);
    /* nobody listening at all: open succeeds (device may come later), reads give LINK faults */
    s = vibid_source_open(&vibid_source_modbus_ops, &cfg, &err);
    assert_non_null(s);
    assert_int_equal(vibid_source_read(s, r, 64, &n, 0, &err), VIBID_DRV_OK);
    assert_int_equal(r[0].fault, VIBID_FAULT_LINK);
    assert_non_null(strstr(r[0].text, "connect failed"));
    vibid_source_close(s);
    /* configuration errors */
    strcpy(cfg.chanmap.ch[1].ref, "nope");
    cfg.chanmap.ch[1].line = 4;
    assert_null(vibid_source_open(&vibid_source_modbus_ops, &cfg, &err));
    assert_non_null(strstr(err.text, "channel 'b' (line 4): register 'nope' is not in the register map"));
    vibid_regmap_destroy(rm);
}

/* Reads for `secs`; counts samples (checking the known signal: every s exactly once, in
 * order, gaps only as GAP records), gap samples and faults; fault texts containing `want`
 * counted in *matched. Returns the last s (-1: none). */
typedef struct {
    uint64_t samples, gap_samples, faults, matched, backwards, doubled_prefix;
    long first_s, last_s;
} read_tally;

static read_tally read_for(vibid_source *s, double secs, const char *want)
{
    static vibid_record r[256];
    read_tally t = {0, 0, 0, 0, 0, 0, -1, -1};
    uint64_t next_k = 0;
    vibid_drv_error err = {0};
    int64_t end = mono() + (int64_t)(secs * 1e9);
    while (mono() < end) {
        size_t n;
        vibid_drv_status st = vibid_source_read(s, r, 256, &n, 50, &err);
        if (st != VIBID_DRV_OK && st != VIBID_DRV_E_AGAIN)
            fail_msg("read returned %d: %s (a peer must never end the source)", (int)st, err.text);
        for (size_t i = 0; i < n; i++) {
            if (r[i].kind == VIBID_REC_FAULT) {
                t.faults++;
                if (want && strstr(r[i].text, want))
                    t.matched++;
                const char *p = strstr(r[i].text, "Modbus ");
                if (p && strstr(p + 7, "Modbus 127.0.0.1"))
                    t.doubled_prefix++; /* "Modbus host:port: Modbus host:port: ..." */
                continue;
            }
            if (next_k == 0 && t.samples == 0 && t.gap_samples == 0)
                next_k = r[i].index;
            assert_int_equal(r[i].index, next_k);
            if (r[i].kind == VIBID_REC_GAP) {
                t.gap_samples += r[i].count;
                next_k += r[i].count;
                continue;
            }
            long sv = check_values(&r[i]);
            if (t.last_s >= 0 && sv <= t.last_s)
                t.backwards++; /* a duplicate or a re-read */
            if (t.first_s < 0)
                t.first_s = sv;
            t.last_s = sv;
            t.samples++;
            next_k++;
        }
    }
    return t;
}

static void drain_server(FILE *srv)
{
    while (fgets((char[128]){0}, 128, srv)) {
    }
    pclose(srv);
}

/* A FIFO header that does not fit (wrong base, a device sampling at another rate) is
 * the device's state, not a reason to stop: the source opens, names what it found in a
 * LINK fault per attempt, retries with back-off, and invents no sample (issue 12). */
static void test_fifo_wrong_base(void **state)
{
    (void)state;
    int port = free_port();
    vibid_regmap *rm = load_regmap();
    FILE *srv = start_server(port, "1.5");
    vibid_source_modbus_config cfg = base_cfg(rm, port);
    cfg.mode = VIBID_MODBUS_FIFO;
    cfg.fifo_base = 2000;
    vibid_drv_error err = {0};
    vibid_source *s = vibid_source_open(&vibid_source_modbus_ops, &cfg, &err);
    if (!s)
        fail_msg("open: %s", err.text);
    read_tally t = read_for(s, 0.6, "no vibid FIFO at holding register 2000: magic 0x");
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    print_message("wrong base: %llu faults naming the header, %llu connect failures, %llu samples\n",
                  (unsigned long long)t.matched, (unsigned long long)st.connect_failures,
                  (unsigned long long)t.samples);
    assert_true(t.matched >= 2 && st.connect_failures >= 2); /* retried, not given up */
    assert_int_equal(t.doubled_prefix, 0); /* the log line names the device once */
    assert_int_equal(t.samples, 0);
    vibid_source_close(s);
    cfg.fifo_base = 0;
    cfg.sample_period_s = 0.002;
    s = vibid_source_open(&vibid_source_modbus_ops, &cfg, &err);
    if (!s)
        fail_msg("open: %s", err.text);
    t = read_for(s, 0.4, "device samples every 1000000 ns, configured 0.002 s");
    assert_true(t.matched >= 1);
    assert_int_equal(t.samples, 0);
    vibid_source_close(s);
    drain_server(srv);
    vibid_regmap_destroy(rm);
}

/* A device rebooting with cleared registers: the header reads magic 0, capacity 0 for the
 * first 0.6 s. The source opens, counts and logs each attempt, retries with back-off, and
 * reads the FIFO once the header is valid (before: exit 2 at start-up, 1 mid-run). */
static void test_fifo_zero_header(void **state)
{
    (void)state;
    int port = free_port();
    vibid_regmap *rm = load_regmap();
    FILE *srv = start_server_args(port, "2.0", "--zero-header 0.6");
    vibid_source *s = open_fifo(rm, port);
    read_tally t = read_for(s, 1.6, "magic 0x0000");
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    print_message("zero header: %llu faults naming magic 0, %llu connect failures, then %llu samples (s %ld..%ld)\n",
                  (unsigned long long)t.matched, (unsigned long long)st.connect_failures,
                  (unsigned long long)t.samples, t.first_s, t.last_s);
    assert_true(t.matched >= 1 && st.connect_failures >= 1);
    assert_true(t.samples >= 500); /* about 1 s of the 1 kHz stream after the header appears */
    assert_int_equal(t.backwards, 0);
    vibid_source_close(s);
    drain_server(srv);
    vibid_regmap_destroy(rm);
}

/* The session id alternates at every server update while the counter continues: the
 * same stream. Every sample exactly once, in order (before: 18x duplicates). */
static void test_fifo_flapping_session(void **state)
{
    (void)state;
    int port = free_port();
    vibid_regmap *rm = load_regmap();
    FILE *srv = start_server_args(port, "2.0", "--flap-session");
    vibid_source *s = open_fifo(rm, port);
    read_tally t = read_for(s, 1.5, NULL);
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    print_message("flapping session: %llu samples (s %ld..%ld), %llu going back, %llu gap samples, %llu implausible "
                  "polls\n",
                  (unsigned long long)t.samples, t.first_s, t.last_s, (unsigned long long)t.backwards,
                  (unsigned long long)t.gap_samples, (unsigned long long)st.implausible);
    assert_int_equal(t.backwards, 0);
    /* at most the samples the server produced while we read (1.5 s at 1 kHz, + start) */
    assert_true(t.samples <= (uint64_t)(t.last_s - t.first_s + 1));
    assert_true(t.samples >= 1000);
    vibid_source_close(s);
    drain_server(srv);
    vibid_regmap_destroy(rm);
}

/* The counter registers hold random values from 0.5 s to 1.0 s: polls not believed, no
 * sample invented, no duplicate, and the missing samples bounded by the elapsed time
 * (before: 99e9 "missing" samples in 6 s). */
static void test_fifo_random_counter(void **state)
{
    (void)state;
    int port = free_port();
    vibid_regmap *rm = load_regmap();
    FILE *srv = start_server_args(port, "2.5", "--random-counter 0.5,1.0");
    vibid_source *s = open_fifo(rm, port);
    const int64_t t0 = mono();
    read_tally t = read_for(s, 2.0, NULL);
    const double el = (double)(mono() - t0) * 1e-9;
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    print_message("random counter: %llu samples (s %ld..%ld), %llu gap samples over %.2f s, %llu going back, %llu "
                  "implausible polls\n",
                  (unsigned long long)t.samples, t.first_s, t.last_s, (unsigned long long)t.gap_samples, el,
                  (unsigned long long)t.backwards, (unsigned long long)st.implausible);
    assert_true(st.implausible >= 3);
    assert_int_equal(t.backwards, 0);
    /* the samples skipped over the bad half second are GAP records, their length
     * estimated from the elapsed time: samples + gaps cover the s range to within 10 %
     * of the half second's 500 samples */
    const long covered = (long)(t.samples + t.gap_samples), range = t.last_s - t.first_s + 1;
    if (labs(covered - range) > 50)
        fail_msg("samples + gap samples %ld, s range %ld", covered, range);
    /* samples + gaps never exceed what 1 kHz produces in the elapsed time (+ the ring at start) */
    assert_true(t.samples + t.gap_samples <= (uint64_t)(el * 1000.0 * 1.1) + 500);
    assert_true(t.samples >= 1000); /* the stream goes on around the bad half second */
    vibid_source_close(s);
    drain_server(srv);
    vibid_regmap_destroy(rm);
}

/* A slow peer: every answer 0.45 s late (under the 0.5 s response timeout), or dripped
 * one byte per 0.45 s. One source read with a 100 ms timeout must return within that
 * timeout plus one poll's two requests (each bounded by the response timeout + the 50 ms
 * byte timeout), so that the
 * daemon's acquisition loop sees its stop flag (SIGTERM took 19 s with slow answers and
 * more than 150 s with dripped ones); the dripped answers are counted as timeouts and
 * end in a link loss and reconnects, never in a stall. */
static void slow_run(const char *mode, double secs, double response_timeout_s, double *max_call_s,
                     vibid_source_stats *st)
{
    int port = free_port();
    vibid_regmap *rm = load_regmap();
    const char *py = getenv("VIBID_PYTHON");
    if (!py || access(py, X_OK) != 0)
        fail_msg("FAIL: VIBID_PYTHON='%s' is not an executable venv interpreter", py ? py : "");
    char cmd[1024];
    snprintf(cmd, sizeof cmd, "'%s' '%s' --port %d %s --max-time %g", py, VIBID_DRV_SLOW_SERVER_PY, port, mode,
             secs + 3.0);
    FILE *srv = popen(cmd, "r");
    assert_non_null(srv);
    char line[128];
    if (!fgets(line, sizeof line, srv) || strncmp(line, "READY", 5) != 0)
        fail_msg("slow server did not start (%s)", cmd);
    vibid_source_modbus_config cfg = base_cfg(rm, port);
    cfg.mode = VIBID_MODBUS_FIFO;
    cfg.sample_period_s = 0.01; /* the slow server's 100 Hz: its ring holds 5 s */
    cfg.poll_period_s = 0.02;
    cfg.response_timeout_s = response_timeout_s;
    vibid_drv_error err = {0};
    const int64_t t_open = mono();
    vibid_source *s = vibid_source_open(&vibid_source_modbus_ops, &cfg, &err);
    if (!s)
        fail_msg("open: %s", err.text);
    *max_call_s = (double)(mono() - t_open) * 1e-9;
    static vibid_record r[256];
    const int64_t end = mono() + (int64_t)(secs * 1e9);
    while (mono() < end) {
        size_t n;
        const int64_t t0 = mono();
        vibid_drv_status rs = vibid_source_read(s, r, 256, &n, 100, &err);
        const double dt = (double)(mono() - t0) * 1e-9;
        if (dt > *max_call_s)
            *max_call_s = dt;
        if (rs != VIBID_DRV_OK && rs != VIBID_DRV_E_AGAIN)
            fail_msg("read: %s", err.text);
    }
    vibid_source_stats_get(s, st);
    vibid_source_close(s);
    drain_server(srv);
    vibid_regmap_destroy(rm);
}

static void test_slow_peer(void **state)
{
    (void)state;
    double max_call;
    vibid_source_stats st;
    slow_run("--delay 0.45", 3.0, 0.5, &max_call, &st);
    print_message("answers 0.45 s late: longest call %.3f s, %llu samples, %llu requests, %llu timeouts\n", max_call,
                  (unsigned long long)st.samples, (unsigned long long)st.requests, (unsigned long long)st.timeouts);
    /* 100 ms + the counter and one records request (2 x 0.45 s) + scheduling: 1.2 s;
     * before: a poll read its whole backlog, several seconds */
    assert_true(max_call < 1.2);
    assert_true(st.samples > 0); /* slow but working: data still arrives */
    slow_run("--drip 0.45", 4.0, 0.5, &max_call, &st);
    print_message("answers dripped 1 byte / 0.45 s: longest call %.3f s, %llu timeouts, %llu link losses, %llu "
                  "reconnects\n",
                  max_call, (unsigned long long)st.timeouts, (unsigned long long)st.link_losses,
                  (unsigned long long)st.reconnects);
    /* a request ends 50 ms after the first byte that is not followed in time: 0.5 s +
     * 0.05 s + the 100 ms call timeout + scheduling < 0.9 s; before: minutes */
    assert_true(max_call < 0.9);
    assert_true(st.timeouts >= 3 && st.link_losses >= 1);
}

/* A response timeout just under a whole second (0.9999996 s) is (1 s, 0 us) for libmodbus.
 * Before, it was passed as (0 s, 1000000 us), which libmodbus refuses (EINVAL), keeping
 * its 0.5 s default: answers 0.7 s late then all timed out. */
static void test_timeout_rounding(void **state)
{
    (void)state;
    double max_call;
    vibid_source_stats st;
    slow_run("--delay 0.7", 3.0, 0.9999996, &max_call, &st);
    print_message("answers 0.7 s late, response_timeout 0.9999996 s: %llu samples, %llu requests, %llu timeouts\n",
                  (unsigned long long)st.samples, (unsigned long long)st.requests, (unsigned long long)st.timeouts);
    assert_int_equal(st.timeouts, 0);
    assert_true(st.samples > 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_fifo_restart),
        cmocka_unit_test(test_fifo_start_margin),
        cmocka_unit_test(test_snapshot),
        cmocka_unit_test(test_silent_server),
        cmocka_unit_test(test_fifo_wrong_base),
        cmocka_unit_test(test_fifo_zero_header),
        cmocka_unit_test(test_fifo_flapping_session),
        cmocka_unit_test(test_fifo_random_counter),
        cmocka_unit_test(test_slow_peer),
        cmocka_unit_test(test_timeout_rounding),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
