/* Modbus source against an independent server (pymodbus, modbus_fifo_server.py, which
 * implements drivers/modbus_fifo_layout.md on its own) on 127.0.0.1:
 *  - FIFO mode at 1 kHz across a server stop/restart: every sample of each server
 *    session arrives exactly once, in order, with the exact values of the known signal;
 *    the outage is LINK faults (retries with a doubling back-off) + one GAP whose
 *    (estimated) length matches the outage the server recorded;
 *  - snapshot mode: consistent samples on an absolute-deadline clock;
 *  - a server that accepts but never answers: timeouts counted, link declared lost,
 *    reconnects with backoff, every failed poll counted, no sample invented;
 *  - hostile peers (issue 12): a FIFO header that does not fit or reads all zeros (a
 *    rebooting device) is retried, never the end of the source; a flapping session id
 *    gives every sample exactly once; a random counter is not believed, and the samples
 *    lost meanwhile are a GAP as long as the elapsed time; a slow or dripping peer cannot
 *    hold a read; a response timeout just under whole seconds is not rounded away.
 * No assertion depends on how fast this machine is: the servers run under the test's
 * command (--control: freeze, stop, start, ... on their stdin, each answered when done)
 * and every loop waits for an event (samples, faults, counters of the source's stats)
 * with HANG_S as the only bound, which only a hung test reaches. Where a property is
 * about time, it is asserted as what the code promises, measured on the server's own
 * timestamps and the test's clocks around each read call, so that a stall of either
 * process widens the bound instead of failing the test. Stalls still change what
 * happens (a FIFO overrun when the source cannot keep up, a missed snapshot tick), and
 * those are checked as exact GAP records, never waved through. Figures that are only
 * speed (snapshot interval jitter, the longest read against a slow peer) are printed
 * here and measured by bench/bench_modbus_peer.c. The peers' driver: support/modbus_peer.h.
 * Needs the venv's Python (VIBID_PYTHON); its absence FAILS the test. */
#include <arpa/inet.h>
#include <math.h>
#include <netinet/in.h>
#include <setjmp.h>
#include <signal.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <cmocka.h>
#include <vibid_drivers/source_modbus.h>

#define MODBUS_PEER_FAIL(...) fail_msg(__VA_ARGS__)
#define MODBUS_PEER_NOTE(...) print_message(__VA_ARGS__)
#include "support/modbus_peer.h"

/* The test's clocks around each read call: what a promise about time is measured on. */
typedef struct call_clock {
    int64_t start, end;       /* CLOCK_MONOTONIC ns around the last call */
    int64_t rt_start, rt_end; /* CLOCK_REALTIME ns around the same call */
    int64_t first_start;      /* of the first call (0: none yet) */
    int64_t max_call;         /* longest call, ns */
    int64_t max_between;      /* longest time between the starts of two calls, ns */
    uint64_t requests;        /* Modbus requests issued by the last call */
    uint64_t max_requests;    /* ... most by one call */
    uint64_t calls;
} call_clock;

/* One vibid_source_read, timed; any status but OK / E_AGAIN fails the test (a peer must
 * never end the source). Returns the number of records. */
static size_t timed_read(vibid_source *s, vibid_record *r, size_t cap, int timeout_ms, call_clock *c)
{
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    const uint64_t req0 = st.requests;
    const int64_t t0 = mono_ns(), rt0 = real_ns();
    if (c->calls++ == 0)
        c->first_start = t0;
    else if (t0 - c->start > c->max_between)
        c->max_between = t0 - c->start;
    size_t n = 0;
    vibid_drv_error err = {0};
    const vibid_drv_status rs = vibid_source_read(s, r, cap, &n, timeout_ms, &err);
    c->rt_end = real_ns();
    c->end = mono_ns();
    c->start = t0;
    c->rt_start = rt0;
    if (c->end - t0 > c->max_call)
        c->max_call = c->end - t0;
    if (rs != VIBID_DRV_OK && rs != VIBID_DRV_E_AGAIN)
        fail_msg("read returned %d: %s (a peer must never end the source)", (int)rs, err.text);
    vibid_source_stats_get(s, &st);
    c->requests = st.requests - req0;
    if (c->requests > c->max_requests)
        c->max_requests = c->requests;
    return n;
}

/* FIFO source on 127.0.0.1:port, h = 1 ms, 20 ms polls; fails the test if it cannot open. */
static vibid_source *open_fifo(const vibid_regmap *rm, int port)
{
    vibid_source_modbus_config cfg = base_cfg(rm, port);
    cfg.mode = VIBID_MODBUS_FIFO;
    cfg.sample_period_s = 1e-3;
    cfg.poll_period_s = 0.02;
    return peer_open(&cfg);
}

/* What a FIFO source delivered, checked record by record: indices contiguous (every k
 * exactly once), values exactly the server's signal, and the server's counter s
 * continuing across each GAP: by exactly its count when the source knows the count (an
 * overrun, the source not keeping up: "exact"), freely only after a GAP estimated from the
 * elapsed time (a restart or a resynchronisation). The source's fault "FIFO server
 * restarted" starts the next server session (at most 2), where s starts again; s going
 * back anywhere else is a duplicate (counted in `backwards`). An exact GAP may come
 * before a session's first sample (an overrun before anything was delivered: the
 * session's stream starts that much earlier). Faults containing `want` are counted in
 * `matched`; the delays of "retry in X s" faults are kept with the times of the call
 * that reported them. */
#define MAX_RETRIES 64
typedef struct read_tally {
    uint64_t samples, faults, matched, backwards, doubled_prefix, link_faults, resyncs;
    uint64_t exact_gap, est_gap, est_gaps; /* GAP samples of each kind; estimated GAP records */
    long first_s, last_s;                  /* -1: none */
    int session;                           /* 0, 1 */
    long sess_first[2], sess_last[2];
    uint64_t sess_lead[2];                 /* exact GAP samples before the session's first sample */
    /* The read calls in which the source dated a stream by its clock (ns, longest): a
     * session's start (session 0: any call up to its first sample; session 1: the call
     * that returned the restart fault, which the poll that restarted queued into an
     * empty queue) and the latest resynchronisation (likewise). */
    int64_t anchor_call[2], resync_call;
    uint64_t sess_samples[2], sess_exact[2];
    uint64_t next_k, pending_exact;
    bool started, pending_est, pending_restart;
    double retry[MAX_RETRIES];
    int64_t retry_start[MAX_RETRIES], retry_end[MAX_RETRIES];
    bool retry_first[MAX_RETRIES]; /* the first retry since the link was lost or made */
    bool retry_fresh;
    size_t n_retry;
    call_clock clk;
} read_tally;

static void tally_init(read_tally *t)
{
    memset(t, 0, sizeof *t);
    t->first_s = t->last_s = -1;
    t->retry_fresh = true;
    t->sess_first[0] = t->sess_first[1] = t->sess_last[0] = t->sess_last[1] = -1;
}

/* The s value the server's stream continues with (after the exact GAPs seen since). */
static long tally_next_s(const read_tally *t) { return t->last_s + 1 + (long)t->pending_exact; }

static void tally_record(read_tally *t, const vibid_record *r, const char *want)
{
    if (r->kind == VIBID_REC_FAULT) {
        t->faults++;
        t->link_faults += r->fault == VIBID_FAULT_LINK;
        if (want && strstr(r->text, want))
            t->matched++;
        const char *p = strstr(r->text, "Modbus ");
        if (p && strstr(p + 7, "Modbus 127.0.0.1"))
            t->doubled_prefix++; /* "Modbus host:port: Modbus host:port: ..." */
        if (strstr(r->text, "FIFO stream resynchronised")) {
            t->resyncs++;
            t->resync_call = t->clk.end - t->clk.start;
        }
        if (strstr(r->text, "FIFO server restarted (session") && t->last_s >= 0) {
            if (t->session == 1)
                fail_msg("a third server session: %s", r->text);
            t->session = 1; /* the server's next session: what follows is counted there */
            t->pending_restart = true;
            t->anchor_call[1] = t->clk.end - t->clk.start;
            t->pending_exact = 0;
        }
        if (strstr(r->text, "link lost") || strstr(r->text, "reconnected"))
            t->retry_fresh = true;
        const char *q = strstr(r->text, "retry in ");
        if (q && t->n_retry < MAX_RETRIES) {
            t->retry[t->n_retry] = strtod(q + 9, NULL);
            t->retry_first[t->n_retry] = t->retry_fresh;
            t->retry_fresh = false;
            t->retry_start[t->n_retry] = t->clk.start;
            t->retry_end[t->n_retry++] = t->clk.end;
        }
        return;
    }
    if (!t->started) {
        t->next_k = r->index;
        t->started = true;
    }
    if (r->index != t->next_k)
        fail_msg("record index %llu, expected %llu (every index exactly once)", (unsigned long long)r->index,
                 (unsigned long long)t->next_k);
    if (r->kind == VIBID_REC_GAP) {
        if (strstr(r->text, "estimated")) {
            print_message("estimated gap: k=%llu count=%llu: %s\n", (unsigned long long)r->index,
                          (unsigned long long)r->count, r->text);
            t->est_gap += r->count;
            t->est_gaps++;
            t->pending_est = true;
        } else {
            print_message("exact gap: k=%llu count=%llu: %s\n", (unsigned long long)r->index,
                          (unsigned long long)r->count, r->text);
            t->exact_gap += r->count;
            t->sess_exact[t->session] += r->count;
            t->pending_exact += r->count;
        }
        t->next_k += r->count;
        return;
    }
    if (r->kind != VIBID_REC_SAMPLE)
        fail_msg("record kind %d at index %llu: %s", r->kind, (unsigned long long)r->index, r->text);
    const long sv = check_values(r);
    if (t->pending_restart) {
        /* the first of the new session: s starts again */
    } else if (t->last_s >= 0 && sv <= t->last_s) {
        t->backwards++; /* a duplicate or a re-read */
    } else if (t->last_s >= 0 && !t->pending_est && sv != tally_next_s(t)) {
        fail_msg("s = %ld after s = %ld and %llu samples of exact GAP: a sample lost or invented", sv, t->last_s,
                 (unsigned long long)t->pending_exact);
    }
    if (t->sess_first[t->session] < 0) {
        t->sess_first[t->session] = sv;
        t->sess_lead[t->session] = t->pending_exact;
        if (t->session == 0)
            t->anchor_call[0] = t->clk.max_call;
    }
    t->pending_exact = 0;
    t->pending_est = t->pending_restart = false;
    if (t->first_s < 0)
        t->first_s = sv;
    t->sess_last[t->session] = sv;
    t->sess_samples[t->session]++;
    t->last_s = sv;
    t->samples++;
    t->next_k++;
}

/* Where a session's stream started: its first sample's s less the exact GAP before it
 * (an overrun before anything was delivered). */
static long tally_start(const read_tally *t, int session)
{
    return t->sess_first[session] - (long)t->sess_lead[session];
}

/* How many s values the (one-session) stream covers, from its start to its last sample
 * and the exact GAP after it. */
static long tally_range(const read_tally *t)
{
    return t->last_s + (long)t->pending_exact - tally_start(t, 0) + 1;
}

/* One read call (timeout_ms), every record tallied. */
static void read_step(vibid_source *s, read_tally *t, const char *want, int timeout_ms)
{
    static vibid_record r[256];
    const size_t n = timed_read(s, r, 256, timeout_ms, &t->clk);
    for (size_t i = 0; i < n; i++)
        tally_record(t, &r[i], want);
}

/* Reads until cond(s, t) holds; only a hung test waits HANG_S. */
#define READ_UNTIL(s, t, want, cond, what)                                                                       \
    do {                                                                                                         \
        const int64_t since_ = mono_ns();                                                                        \
        while (!(cond)) {                                                                                        \
            hang_check(since_, what);                                                                            \
            read_step((s), (t), (want), 50);                                                                     \
        }                                                                                                        \
    } while (0)

static vibid_source_stats stats_of(const vibid_source *s)
{
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    return st;
}

/* FIFO overruns are not a failure here: an overrun GAP is exact (the counter continues by
 * its count, checked record by record) and whether the source keeps up with 1 kHz on a
 * loaded machine is speed (a long stall, or requests slower than the samples come: a
 * sanitizer run at load 17 overran 26 samples with no pause over 85 ms), measured by
 * bench/bench_modbus_peer. What it was is printed. */
static void note_overruns(const read_tally *t, double server_maxgap_s)
{
    if (t->exact_gap == 0)
        return;
    print_message("exact GAP samples %llu: longest time between two reads %.3f s, longest read %.3f s, longest "
                  "server update gap %.3f s\n",
                  (unsigned long long)t->exact_gap, (double)t->clk.max_between * 1e-9,
                  (double)t->clk.max_call * 1e-9, server_maxgap_s);
}

/* The end of a test of one server session that must read as one stream: no sample going
 * back, no restart, no estimated GAP, every s of the range once (delivered or an exact
 * GAP); then the server stopped, everything closed. */
static void one_stream_end(const read_tally *t, peer *srv, vibid_source *s, vibid_regmap *rm)
{
    assert_int_equal(t->backwards, 0);
    assert_int_equal(t->session, 0);
    assert_int_equal(t->est_gap, 0);
    assert_int_equal(t->samples + t->exact_gap, (uint64_t)tally_range(t));
    double t0, maxgap;
    unsigned long served;
    peer_stop(srv, 0, &served, &t0, &maxgap);
    vibid_source_close(s);
    peer_finish(srv);
    note_overruns(t, maxgap);
    vibid_regmap_destroy(rm);
}

/* FIFO across a server stop and restart, each step on the test's command once the event
 * before it has been seen: 1000 samples, the server freezes its counter, we have read up
 * to it, the server stops, we have seen the link lost and 5 failed reconnects (back-off
 * 0.05, 0.1, 0.2, 0.4, 0.4 s: doubled up to its cap; about 1.15 s of outage), the
 * server starts a new session, 1000 samples, freeze, read up to it, stop. */
static void test_fifo_restart(void **state)
{
    (void)state;
    vibid_regmap *rm = load_regmap();
    peer srv;
    peer_start(&srv, VIBID_DRV_SERVER_PY, "");
    vibid_source *s = open_fifo(rm, srv.port);
    read_tally t;
    tally_init(&t);
    char line[256];
    unsigned long served[2] = {0, 0}, frozen;
    double t0[2] = {0, 0}, maxgap[2] = {0, 0};
    size_t retry_from = 0;
    uint64_t failures_at_stop = 0;
    for (int ph = 0; ph < 2; ph++) {
        READ_UNTIL(s, &t, NULL, t.session == ph && t.sess_samples[ph] >= 1000, "1000 samples of the session");
        peer_command(&srv, "freeze", "FROZEN", line, sizeof line);
        assert_int_equal(sscanf(line, "FROZEN %lu", &frozen), 1);
        /* every sample up to the frozen counter, or an exact GAP for it */
        READ_UNTIL(s, &t, NULL, tally_next_s(&t) == (long)frozen, "the session read up to its frozen counter");
        peer_stop(&srv, ph, &served[ph], &t0[ph], &maxgap[ph]);
        assert_int_equal(served[ph], frozen);
        if (ph == 1)
            break;
        /* the link lost, then failed reconnects with their back-off */
        retry_from = t.n_retry;
        failures_at_stop = stats_of(s).connect_failures;
        READ_UNTIL(s, &t, NULL, stats_of(s).link_losses >= 1 && stats_of(s).connect_failures >= failures_at_stop + 5,
                   "the link lost and 5 failed reconnects");
        peer_command(&srv, "start", "STARTED", line, sizeof line);
    }
    vibid_source_stats st = stats_of(s);
    print_message("FIFO: session samples %llu + %llu (s %ld..%ld, %ld..%ld), server served %lu + %lu, exact GAP "
                  "samples %llu + %llu, estimated GAP %llu in %llu record(s); polls %llu, failed polls %llu, requests "
                  "%llu, link losses %llu, connect failures %llu, reconnects %llu; longest read %.3f s, server update "
                  "gap %.3f / %.3f s\n",
                  (unsigned long long)t.sess_samples[0], (unsigned long long)t.sess_samples[1], t.sess_first[0],
                  t.sess_last[0], t.sess_first[1], t.sess_last[1], served[0], served[1],
                  (unsigned long long)t.sess_exact[0], (unsigned long long)t.sess_exact[1],
                  (unsigned long long)t.est_gap, (unsigned long long)t.est_gaps, (unsigned long long)st.polls,
                  (unsigned long long)st.failed_polls, (unsigned long long)st.requests,
                  (unsigned long long)st.link_losses, (unsigned long long)st.connect_failures,
                  (unsigned long long)st.reconnects, (double)t.clk.max_call * 1e-9, maxgap[0], maxgap[1]);
    vibid_source_close(s);
    peer_finish(&srv);
    assert_int_equal(t.backwards, 0);
    assert_int_equal(t.session, 1);
    /* Each session: every sample the server produced from where we started (0, or the
     * start margin if we connected late) to its frozen counter, exactly once: delivered,
     * or an exact GAP (an overrun: the source did not keep up, note_overruns). */
    for (int i = 0; i < 2; i++)
        if (t.sess_samples[i] + t.sess_exact[i] != served[i] - (unsigned long)tally_start(&t, i))
            fail_msg("session %d: %llu samples + %llu exact GAP for s %ld..%ld, server served %lu", i,
                     (unsigned long long)t.sess_samples[i], (unsigned long long)t.sess_exact[i], t.sess_first[i],
                     t.sess_last[i], served[i]);
    note_overruns(&t, fmax(maxgap[0], maxgap[1]));
    /* The outage: one GAP, its length estimated from the elapsed time. The truth, in the
     * server's time: sample s of session i is due at t0_i + (s + 1) h, so the samples
     * between our last of session 0 and our first of session 1 are
     * (t0_1 - t0_0) / h + first_1 - last_0 - 1. The source dates a session's newest sample
     * by its own clock when the counter answer arrives; that is late by at most the read
     * call that polled (the request and the clock reading are inside it) plus the time
     * since the server last updated its registers (its longest update gap), plus up to
     * 2 h of the server's rounding. The estimate compares two such dates, so it is within
     * the later of the two of the truth, + h, + 0.5 for the source's rounding, + 1.5 for
     * the source's CLOCK_REALTIME against the server's CLOCK_MONOTONIC (an NTP slew of at
     * most 500 ppm over these 3 s): + 3 samples. */
    assert_int_equal(t.est_gaps, 1);
    const double h = 1e-3;
    const double truth = (t0[1] - t0[0]) / h + (double)tally_start(&t, 1) - (double)t.sess_last[0] - 1.0;
    const double tol =
        ((double)(t.anchor_call[0] > t.anchor_call[1] ? t.anchor_call[0] : t.anchor_call[1]) * 1e-9 +
         fmax(maxgap[0], maxgap[1])) / h + 3.0;
    print_message("outage: GAP %llu samples, server's timestamps say %.1f, tolerance %.1f\n",
                  (unsigned long long)t.est_gap, truth, tol);
    if (fabs((double)t.est_gap - truth) > tol)
        fail_msg("outage GAP %llu samples, the server's timestamps say %.1f (tolerance %.1f)",
                 (unsigned long long)t.est_gap, truth, tol);
    /* The back-off while the server was away: each failed attempt's retry delay doubles
     * from backoff_initial_s up to backoff_max_s, and the next attempt (reported by a
     * later call) never comes before the delay has passed. */
    const size_t nr = t.n_retry - retry_from;
    assert_true(nr >= 5);
    assert_true(t.retry_first[retry_from]);
    for (size_t i = retry_from; i < t.n_retry; i++) {
        const double want = t.retry_first[i] ? 0.05 : fmin(2 * t.retry[i - 1], 0.4);
        if (fabs(t.retry[i] - want) > 1e-9)
            fail_msg("failed reconnect %zu: retry in %g s, expected %g s", i - retry_from, t.retry[i], want);
        if (!t.retry_first[i] && t.retry_end[i] - t.retry_start[i - 1] < (int64_t)llround(t.retry[i - 1] * 1e9))
            fail_msg("failed reconnect %zu came %.3f s after the one before, its back-off was %g s", i - retry_from,
                     (double)(t.retry_end[i] - t.retry_start[i - 1]) * 1e-9, t.retry[i - 1]);
    }
    assert_true(st.link_losses >= 1 && st.reconnects >= 1 && st.connect_failures >= 5);
    assert_true(st.failed_polls >= 1 && t.link_faults >= 3);
    assert_int_equal(st.samples, t.samples);
    vibid_regmap_destroy(rm);
}

/* Where a FIFO session starts: the server produced 1300 samples into its K = 500 ring and
 * stopped (so the window is fixed). The oldest slot is the next the server overwrites,
 * so the source starts K/8 = 62 records after it: samples 862 .. 1299 (438 of them),
 * index 0 .. 437, and no gap record (nothing was expected before the session began);
 * then nothing more, however many polls follow. */
static void test_fifo_start_margin(void **state)
{
    (void)state;
    vibid_regmap *rm = load_regmap();
    peer srv;
    peer_start(&srv, VIBID_DRV_SERVER_PY, "--stop-after 1300");
    char line[256];
    peer_expect(&srv, "PRODUCED 1300", line, sizeof line);
    vibid_source *s = open_fifo(rm, srv.port);
    read_tally t;
    tally_init(&t);
    READ_UNTIL(s, &t, NULL, t.samples >= 438, "438 samples");
    const uint64_t polls = stats_of(s).polls;
    READ_UNTIL(s, &t, NULL, stats_of(s).polls >= polls + 10, "10 more polls"); /* and no record from them */
    vibid_source_close(s);
    peer_finish(&srv);
    print_message("FIFO start: samples %ld .. %ld (%llu), %llu faults\n", t.first_s, t.last_s,
                  (unsigned long long)t.samples, (unsigned long long)t.faults);
    assert_int_equal(t.first_s, 1300 - 500 + 500 / 8);
    assert_int_equal(t.last_s, 1299);
    assert_int_equal(t.samples, 500 - 500 / 8);
    assert_int_equal(t.exact_gap + t.est_gap, 0);
    /* faults: a request that timed out on a loaded machine is a POLL fault, and the
     * frozen ring is read again at the next poll: allowed, it changes nothing above */
    vibid_regmap_destroy(rm);
}

/* Snapshot mode at 30 ms until 40 samples. Every tick index once: a sample, or part of a
 * GAP when its deadline passed by more than a period (slow answer, a stalled test: correct
 * behaviour, counted, never invented). The clock is absolute (source_modbus.h): tick k is
 * polled at a time p with t0 + k h <= p < t0 + (k + 1) h, t0 taken in the call that gave
 * index 0. A tick's poll runs inside the read call that returns it, so that call ended
 * at or after (first call's start) + k h and started before (end of index 0's call) +
 * (k + 1) h; a sleep relative to the last poll would drift past the second bound, a clock
 * running fast would break the first. The sample time is the answer's receive time,
 * inside the same call. */
static void test_snapshot(void **state)
{
    (void)state;
    vibid_regmap *rm = load_regmap();
    peer srv;
    vibid_source *s = peer_snapshot(&srv, VIBID_DRV_SERVER_PY, rm, 0.03);
    const int64_t h = 30000000;
    vibid_record r[16];
    call_clock clk = {0};
    uint64_t samples = 0, missed = 0, k = 0;
    int64_t end0 = -1; /* end of the call that returned index 0 */
    long last = -1;
    const int64_t since = mono_ns();
    while (samples < 40) {
        hang_check(since, "40 snapshot samples");
        const size_t n = timed_read(s, r, 16, 20, &clk);
        for (size_t i = 0; i < n; i++) {
            if (r[i].kind == VIBID_REC_FAULT)
                continue; /* a failed poll: POLL fault + a one-tick GAP */
            assert_int_equal(r[i].index, k);
            if (end0 < 0)
                end0 = clk.end;
            if (r[i].kind == VIBID_REC_GAP) {
                missed += r[i].count;
                k += r[i].count;
                continue;
            }
            if (r[i].kind != VIBID_REC_SAMPLE)
                fail_msg("unexpected record kind %d: %s", r[i].kind, r[i].text);
            if (clk.end < clk.first_start + (int64_t)k * h)
                fail_msg("tick %llu polled %.3f ms early", (unsigned long long)k,
                         (double)(clk.first_start + (int64_t)k * h - clk.end) * 1e-6);
            if (clk.start >= end0 + (int64_t)(k + 1) * h)
                fail_msg("tick %llu polled more than a period after its deadline (%.3f ms late) without a GAP",
                         (unsigned long long)k, (double)(clk.start - end0 - (int64_t)k * h) * 1e-6);
            if (r[i].t_ns < clk.rt_start || r[i].t_ns > clk.rt_end)
                fail_msg("tick %llu: sample time outside the call that polled it", (unsigned long long)k);
            long sv = check_values(&r[i]); /* one snapshot = one consistent server sample */
            assert_true(sv >= last);
            last = sv;
            samples++;
            k++;
        }
    }
    vibid_source_stats st = stats_of(s);
    print_message("snapshot: %llu samples, %llu ticks missed (GAP), interval mean %.4f ms std %.4f ms max %.4f ms, "
                  "blocks: %llu requests / %llu polls, longest read %.3f ms\n",
                  (unsigned long long)samples, (unsigned long long)missed, st.jitter.mean_s * 1e3,
                  st.jitter.std_s * 1e3, st.jitter.max_s * 1e3, (unsigned long long)st.requests,
                  (unsigned long long)st.polls, (double)clk.max_call * 1e-6);
    /* registers 0..2 and 10..11 fit in one request: 1 request per poll */
    assert_int_equal(st.requests, st.polls);
    assert_int_equal(st.samples, samples);
    assert_int_equal(st.missing_samples, missed);
    vibid_source_close(s);
    peer_finish(&srv);
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
    vibid_source *s = peer_open(&cfg);
    vibid_drv_error err = {0};
    vibid_record r[64];
    size_t n;
    uint64_t samples = 0, missing = 0, faults = 0, k = 0;
    call_clock clk = {0};
    vibid_source_stats st = {0};
    const int64_t since = mono_ns();
    while (!(st.timeouts >= 3 && st.link_losses >= 1 && st.reconnects >= 1 && missing >= 10)) {
        hang_check(since, "timeouts, a lost link, a reconnect and 10 missing ticks");
        n = timed_read(s, r, 64, 50, &clk);
        for (size_t i = 0; i < n; i++) {
            samples += r[i].kind == VIBID_REC_SAMPLE;
            faults += r[i].kind == VIBID_REC_FAULT;
            if (r[i].kind == VIBID_REC_GAP) { /* every tick, once */
                assert_int_equal(r[i].index, k);
                missing += r[i].count;
                k += r[i].count;
            }
        }
        st = stats_of(s);
    }
    print_message("silent server: %llu timeouts, %llu failed polls, %llu link losses, %llu reconnects, %llu missing "
                  "samples as GAP, %llu faults, %llu samples\n",
                  (unsigned long long)st.timeouts, (unsigned long long)st.failed_polls,
                  (unsigned long long)st.link_losses, (unsigned long long)st.reconnects, (unsigned long long)missing,
                  (unsigned long long)faults, (unsigned long long)samples);
    assert_int_equal(samples, 0);
    assert_int_equal(st.failed_polls, st.timeouts); /* each poll is one request, each one timed out */
    /* ticks are missing only as time passes: never more than (first call .. last call) / h + 1 */
    assert_true(missing <= (uint64_t)((clk.end - clk.first_start) / 10000000) + 1);
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

/* A FIFO header that does not fit (wrong base, a device sampling at another rate) is
 * the device's state, not a reason to stop: the source opens, names what it found in a
 * LINK fault per attempt, retries with back-off, and invents no sample (issue 12). */
static void test_fifo_wrong_base(void **state)
{
    (void)state;
    vibid_regmap *rm = load_regmap();
    peer srv;
    peer_start(&srv, VIBID_DRV_SERVER_PY, "");
    vibid_source_modbus_config cfg = base_cfg(rm, srv.port);
    cfg.mode = VIBID_MODBUS_FIFO;
    cfg.fifo_base = 2000;
    vibid_source *s = peer_open(&cfg);
    read_tally t;
    tally_init(&t);
    READ_UNTIL(s, &t, "no vibid FIFO at holding register 2000: magic 0x",
               t.matched >= 2 && stats_of(s).connect_failures >= 2, "2 faults naming the header");
    print_message("wrong base: %llu faults naming the header, %llu connect failures, %llu samples\n",
                  (unsigned long long)t.matched, (unsigned long long)stats_of(s).connect_failures,
                  (unsigned long long)t.samples);
    assert_int_equal(t.doubled_prefix, 0); /* the log line names the device once */
    assert_int_equal(t.samples, 0);
    assert_int_equal(t.exact_gap + t.est_gap, 0);
    vibid_source_close(s);
    cfg.fifo_base = 0;
    cfg.sample_period_s = 0.002;
    s = peer_open(&cfg);
    tally_init(&t);
    READ_UNTIL(s, &t, "device samples every 1000000 ns, configured 0.002 s",
               t.matched >= 2 && stats_of(s).connect_failures >= 2, "2 faults naming the period");
    assert_int_equal(t.samples, 0);
    assert_int_equal(t.exact_gap + t.est_gap, 0);
    vibid_source_close(s);
    peer_finish(&srv);
    vibid_regmap_destroy(rm);
}

/* A device rebooting with cleared registers: the header reads magic 0, capacity 0 until
 * the test has seen two attempts fail on it. The source opens, counts and logs each
 * attempt, retries with back-off, and reads the FIFO once the header is valid (before:
 * exit 2 at start-up, 1 mid-run). */
static void test_fifo_zero_header(void **state)
{
    (void)state;
    vibid_regmap *rm = load_regmap();
    peer srv;
    peer_start(&srv, VIBID_DRV_SERVER_PY, "--zero-header -1");
    vibid_source *s = open_fifo(rm, srv.port);
    read_tally t;
    tally_init(&t);
    READ_UNTIL(s, &t, "magic 0x0000", t.matched >= 2 && stats_of(s).connect_failures >= 2,
               "2 faults naming magic 0");
    assert_int_equal(t.samples, 0);
    char line[256];
    peer_command(&srv, "header", "HEADER", line, sizeof line);
    READ_UNTIL(s, &t, "magic 0x0000", t.samples >= 500, "500 samples after the header appeared");
    vibid_source_stats st = stats_of(s);
    print_message("zero header: %llu faults naming magic 0, %llu connect failures, then %llu samples (s %ld..%ld)\n",
                  (unsigned long long)t.matched, (unsigned long long)st.connect_failures,
                  (unsigned long long)t.samples, t.first_s, t.last_s);
    one_stream_end(&t, &srv, s, rm);
}

/* The session id alternates at every server update while the counter continues: the
 * same stream. Every sample exactly once, in order (before: 18x duplicates), and never
 * taken for a restart. */
static void test_fifo_flapping_session(void **state)
{
    (void)state;
    vibid_regmap *rm = load_regmap();
    peer srv;
    peer_start(&srv, VIBID_DRV_SERVER_PY, "--flap-session");
    vibid_source *s = open_fifo(rm, srv.port);
    read_tally t;
    tally_init(&t);
    READ_UNTIL(s, &t, NULL, t.samples >= 1000, "1000 samples");
    vibid_source_stats st = stats_of(s);
    print_message("flapping session: %llu samples (s %ld..%ld), %llu going back, %llu exact gap samples, %llu "
                  "implausible polls\n",
                  (unsigned long long)t.samples, t.first_s, t.last_s, (unsigned long long)t.backwards,
                  (unsigned long long)t.exact_gap, (unsigned long long)st.implausible);
    one_stream_end(&t, &srv, s, rm);
}

/* The counter registers hold random values from 300 samples on until the source has
 * resynchronised three times (3 x 3 polls not believed, about 0.2 s): polls not believed, no sample invented, no duplicate,
 * and the samples lost meanwhile a GAP as long as the elapsed time (before: 99e9
 * "missing" samples in 6 s). */
static void test_fifo_random_counter(void **state)
{
    (void)state;
    vibid_regmap *rm = load_regmap();
    peer srv;
    peer_start(&srv, VIBID_DRV_SERVER_PY, "");
    const int64_t t_open = mono_ns();
    vibid_source *s = open_fifo(rm, srv.port);
    read_tally t;
    tally_init(&t);
    char line[256];
    READ_UNTIL(s, &t, NULL, t.samples >= 300, "300 samples");
    peer_command(&srv, "random on", "RANDOM on", line, sizeof line);
    READ_UNTIL(s, &t, NULL, t.resyncs >= 3 && stats_of(s).implausible >= 9, "3 resynchronisations");
    const uint64_t before = t.samples;
    peer_command(&srv, "random off", "RANDOM off", line, sizeof line);
    READ_UNTIL(s, &t, NULL, t.samples >= before + 700, "700 samples after the counter came back");
    const double el = (double)(mono_ns() - t_open) * 1e-9;
    double t0, maxgap;
    unsigned long served;
    peer_stop(&srv, 0, &served, &t0, &maxgap);
    vibid_source_stats st = stats_of(s);
    print_message("random counter: %llu samples (s %ld..%ld), %llu estimated gap samples in %llu record(s), %llu "
                  "exact, over %.2f s, %llu going back, %llu implausible polls, %llu resyncs\n",
                  (unsigned long long)t.samples, t.first_s, t.last_s, (unsigned long long)t.est_gap,
                  (unsigned long long)t.est_gaps, (unsigned long long)t.exact_gap, el,
                  (unsigned long long)t.backwards, (unsigned long long)st.implausible,
                  (unsigned long long)t.resyncs);
    assert_true(st.implausible >= 3);
    assert_int_equal(t.backwards, 0);
    assert_int_equal(t.session, 0);
    /* The samples skipped over the bad stretch are GAP records whose lengths are
     * estimated from the elapsed time; together with the samples they cover the s range.
     * Each resynchronisation dates the stream by the source's clock when a counter answer
     * arrives (late by at most its read call + the server's longest update gap + 2 h, as
     * in test_fifo_restart); the estimates chain from one to the next (each rounded:
     * +-0.5), so only the session's start and the last resynchronisation count, and the
     * cover is off by at most the later of the two, + 1. */
    const double h = 1e-3;
    const long covered = (long)(t.samples + t.exact_gap + t.est_gap), range = tally_range(&t);
    const double tol =
        ((double)(t.anchor_call[0] > t.resync_call ? t.anchor_call[0] : t.resync_call) * 1e-9 + maxgap) / h + 3.0 +
        0.5 * (double)t.resyncs;
    print_message("random counter: samples + gap samples %ld, s range %ld, tolerance %.1f\n", covered, range, tol);
    if (fabs((double)(covered - range)) > tol)
        fail_msg("samples + gap samples %ld, s range %ld (tolerance %.1f)", covered, range, tol);
    /* samples + gaps never exceed what 1 kHz produces in the elapsed time (+ the ring at start) */
    assert_true(t.samples + t.exact_gap + t.est_gap <= (uint64_t)(el * 1000.0 * 1.1) + 500);
    vibid_source_close(s);
    peer_finish(&srv);
    note_overruns(&t, maxgap);
    vibid_regmap_destroy(rm);
}

/* A slow peer (modbus_slow_server.py: FIFO at 100 Hz, its ring holds 5 s), FIFO source with
 * 20 ms polls, read with a 100 ms call timeout until done(st) holds. */
static read_tally slow_run(const char *mode, double response_timeout_s, bool (*done)(const vibid_source_stats *))
{
    vibid_regmap *rm = load_regmap();
    peer srv;
    peer_start(&srv, VIBID_DRV_SLOW_SERVER_PY, mode);
    vibid_source_modbus_config cfg = base_cfg(rm, srv.port);
    cfg.mode = VIBID_MODBUS_FIFO;
    cfg.sample_period_s = 0.01;
    cfg.poll_period_s = 0.02;
    cfg.response_timeout_s = response_timeout_s;
    vibid_source *s = peer_open(&cfg);
    read_tally t;
    tally_init(&t);
    vibid_source_stats st = stats_of(s);
    const int64_t since = mono_ns();
    while (!done(&st)) {
        hang_check(since, mode);
        read_step(s, &t, NULL, 100);
        st = stats_of(s);
    }
    vibid_source_close(s);
    peer_finish(&srv);
    vibid_regmap_destroy(rm);
    return t;
}

static bool sixty_samples(const vibid_source_stats *st) { return st->samples >= 60; }
static bool dripped_out(const vibid_source_stats *st) { return st->timeouts >= 3 && st->link_losses >= 1; }
static bool five_requests(const vibid_source_stats *st) { return st->requests >= 5; }

/* A slow peer: every answer 0.45 s late (under the response timeout, 1 s here so that a
 * loaded machine does not turn slow answers into timeouts), or dripped one byte per
 * 0.45 s. A source read with a 100 ms timeout must return after at most one poll's
 * counter and records requests, so that the daemon's acquisition loop sees its stop flag
 * (SIGTERM took 19 s with slow answers: a poll read its whole backlog, dozens of requests
 * in one call): with answers that take longer than the call's timeout, that is at most 2
 * requests per call, whatever the machine's speed. Dripped answers are timeouts (50 ms
 * byte timeout) that end in a link loss and reconnects; before, each took minutes and
 * then succeeded. How long a call takes is measured by bench/bench_modbus_peer.c. */
static void test_slow_peer(void **state)
{
    (void)state;
    read_tally t = slow_run("--delay 0.45", 1.0, sixty_samples);
    print_message("answers 0.45 s late: %llu samples (s %ld..%ld), most requests in one call %llu, longest call "
                  "%.3f s\n",
                  (unsigned long long)t.samples, t.first_s, t.last_s, (unsigned long long)t.clk.max_requests,
                  (double)t.clk.max_call * 1e-9);
    assert_true(t.clk.max_requests <= 2);
    assert_int_equal(t.backwards, 0);
    assert_int_equal(t.est_gap, 0);
    assert_int_equal(t.samples + t.exact_gap, (uint64_t)tally_range(&t));
    t = slow_run("--drip 0.45", 0.5, dripped_out);
    print_message("answers dripped 1 byte / 0.45 s: %llu faults, %llu samples, longest call %.3f s\n",
                  (unsigned long long)t.faults, (unsigned long long)t.samples, (double)t.clk.max_call * 1e-9);
    assert_int_equal(t.samples, 0); /* no dripped answer is ever taken */
}

/* A response timeout just under whole seconds (1.9999996 s) is (2 s, 0 us) for libmodbus.
 * Before, it was passed as (1 s, 1000000 us), which libmodbus refuses (EINVAL), keeping
 * its 0.5 s default: answers 0.7 s late then all timed out (the server cannot answer
 * before its delay, so that failure does not depend on speed); now each has 1.3 s to
 * spare. */
static void test_timeout_rounding(void **state)
{
    (void)state;
    read_tally t = slow_run("--delay 0.7", 1.9999996, five_requests);
    print_message("answers 0.7 s late, response_timeout 1.9999996 s: %llu samples, %llu faults\n",
                  (unsigned long long)t.samples, (unsigned long long)t.faults);
    assert_int_equal(t.faults, 0); /* no timeout, no failed poll */
    assert_true(t.samples > 0);
}

int main(void)
{
    signal(SIGPIPE, SIG_IGN); /* a peer that died is reported by its exit status */
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
