/* Modbus RTU source (ctest drivers.modbus_rtu) against an independent RTU server:
 * pymodbus' serial server (modbus_fifo_server.py --serial, pyserial) on one end of a
 * pseudo-terminal pair, the source (libmodbus RTU client) on the other.
 *
 * The "null-modem cable" is two ptys and a relay thread copying bytes between their
 * masters (what `socat pty pty` does, without the package): the client opens pty A's
 * slave, the server pty B's slave. A pty has no baud rate; the 115200 baud setting are
 * still applied by both ends (8N1) and only change libmodbus' inter-frame delay.
 *
 *  - FIFO mode at 1 kHz, polled every 20 ms for 2 s: every sample index exactly once,
 *    no GAP and no FAULT record, values bit-exact against the known signal, the
 *    server's counter s consecutive; at least 1500 samples (2 s at 1 kHz, less the
 *    server's start-up and the unread last poll period);
 *  - snapshot mode at 20 Hz for 1 s on the same line: 19..21 ticks, of which >= 15
 *    consistent exact samples (missed deadlines under load are GAPs, accounted).
 * Needs the venv's Python with pymodbus 3.6.9 and pyserial (scripts/python-venv.sh):
 * without them the test FAILS. Bounded: the server is killed when done (and exits by
 * itself after 10 s), reading stops after 3 s in all, ctest's TIMEOUT is 60 s. */
#include <errno.h>
#include <math.h>
#include <poll.h>
#include <pthread.h>
#include <pty.h>
#include <setjmp.h>
#include <signal.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <cmocka.h>
#include <vibid_drivers/source_modbus.h>

#include "support/drv_test_util.h"

#define MODBUS_PEER_FAIL(...) fail_msg(__VA_ARGS__)
#define MODBUS_PEER_NOTE(...) print_message(__VA_ARGS__)
#include "support/modbus_peer.h" /* the server's register map and signal */

typedef struct null_modem {
    int master[2], slave[2]; /* slaves stay open here so a closing peer never gives EIO */
    char name[2][64];
    pthread_t relay;
    atomic_int stop;
    atomic_ulong bytes[2];   /* A->B (requests), B->A (answers) */
} null_modem;

static void *relay_main(void *arg)
{
    null_modem *nm = arg;
    char buf[1024];
    while (!atomic_load(&nm->stop)) {
        struct pollfd p[2] = {{.fd = nm->master[0], .events = POLLIN}, {.fd = nm->master[1], .events = POLLIN}};
        if (poll(p, 2, 20) < 0 && errno != EINTR)
            break;
        for (int i = 0; i < 2; i++) {
            if (!(p[i].revents & POLLIN))
                continue;
            ssize_t n = read(nm->master[i], buf, sizeof buf);
            for (ssize_t off = 0; n > 0 && off < n;) {
                ssize_t w = write(nm->master[1 - i], buf + off, (size_t)(n - off));
                if (w < 0 && errno != EINTR && errno != EAGAIN)
                    break;
                off += w > 0 ? w : 0;
            }
            if (n > 0)
                atomic_fetch_add(&nm->bytes[i], (unsigned long)n);
        }
    }
    return NULL;
}

static void null_modem_open(null_modem *nm)
{
    memset(nm, 0, sizeof *nm);
    struct termios raw;
    memset(&raw, 0, sizeof raw);
    cfmakeraw(&raw); /* no echo, no line editing: bytes pass unchanged from the start */
    for (int i = 0; i < 2; i++) {
        if (openpty(&nm->master[i], &nm->slave[i], nm->name[i], &raw, NULL) != 0)
            fail_msg("openpty: %s", strerror(errno));
    }
    assert_int_equal(pthread_create(&nm->relay, NULL, relay_main, nm), 0);
}

static void null_modem_close(null_modem *nm)
{
    atomic_store(&nm->stop, 1);
    pthread_join(nm->relay, NULL);
    for (int i = 0; i < 2; i++) {
        close(nm->master[i]);
        close(nm->slave[i]);
    }
}

/* Starts the pymodbus RTU server on dev (child *pid); returns its stdout after READY. */
static FILE *start_rtu_server(const char *dev, pid_t *pid)
{
    const char *py = getenv("VIBID_PYTHON");
    if (!py || access(py, X_OK) != 0)
        fail_msg("FAIL: VIBID_PYTHON='%s' is not an executable venv interpreter (scripts/python-venv.sh)",
                 py ? py : "");
    int fds[2];
    assert_int_equal(pipe(fds), 0);
    *pid = fork();
    assert_true(*pid >= 0);
    if (*pid == 0) {
        dup2(fds[1], 1);
        close(fds[0]);
        close(fds[1]);
        execl(py, py, VIBID_DRV_SERVER_PY, "--port", "0", "--serial", dev, "--baud", "115200", "--schedule", "10",
              "--max-time", "12", (char *)NULL);
        perror("exec of the venv python");
        _exit(127);
    }
    close(fds[1]);
    FILE *p = fdopen(fds[0], "r");
    assert_non_null(p);
    char line[128];
    if (!fgets(line, sizeof line, p) || strncmp(line, "READY", 5) != 0)
        fail_msg("pymodbus RTU server (%s %s --serial %s) did not start; is pyserial in the venv "
                 "(scripts/python-venv.sh)?", py, VIBID_DRV_SERVER_PY, dev);
    return p;
}

static vibid_source_modbus_config rtu_cfg(const vibid_regmap *rm, const char *dev)
{
    vibid_source_modbus_config c = peer_cfg(rm);
    c.transport = VIBID_MODBUS_RTU;
    c.device = dev;
    c.baud = 115200;
    c.parity = 'N'; /* pyserial cannot set even parity on a pty (tcsetattr EINVAL) */
    c.unit_id = 1;
    c.response_timeout_s = 0.5; /* Python answers within a few ms; 0.5 s only bounds a hang */
    return c;
}

static void test_rtu_fifo_and_snapshot(void **state)
{
    (void)state;
    null_modem nm;
    null_modem_open(&nm);
    vibid_regmap *rm = load_regmap();
    pid_t srv_pid;
    FILE *srv = start_rtu_server(nm.name[1], &srv_pid);

    /* FIFO at 1 kHz */
    vibid_source_modbus_config cfg = rtu_cfg(rm, nm.name[0]);
    cfg.mode = VIBID_MODBUS_FIFO;
    cfg.sample_period_s = 1e-3;
    cfg.poll_period_s = 0.02;
    vibid_drv_error err = {0};
    vibid_source *s = vibid_source_open(&vibid_source_modbus_ops, &cfg, &err);
    if (!s)
        fail_msg("RTU FIFO open: %s", err.text);
    static vibid_record r[256];
    size_t n;
    uint64_t next_k = 0, samples = 0;
    long last_s = -1;
    int64_t end = mono_ns() + (int64_t)2.0e9;
    while (mono_ns() < end) {
        vibid_drv_status st = vibid_source_read(s, r, 256, &n, 50, &err);
        if (st != VIBID_DRV_OK && st != VIBID_DRV_E_AGAIN)
            fail_msg("read: %s", err.text);
        for (size_t i = 0; i < n; i++) {
            if (r[i].kind != VIBID_REC_SAMPLE)
                fail_msg("RTU FIFO: unexpected %s record at k=%llu: %s", r[i].kind == VIBID_REC_GAP ? "GAP" : "FAULT",
                         (unsigned long long)r[i].index, r[i].text);
            assert_int_equal(r[i].index, next_k);
            long sv = check_values(&r[i]);
            if (last_s >= 0 && sv != last_s + 1)
                fail_msg("RTU FIFO: server sample jumped from %ld to %ld", last_s, sv);
            last_s = sv;
            next_k++;
            samples++;
        }
    }
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    print_message("RTU FIFO: %llu samples in 2 s (server s up to %ld), polls %llu, requests %llu, failed polls %llu, "
                  "timeouts %llu; bytes %lu out / %lu in\n",
                  (unsigned long long)samples, last_s, (unsigned long long)st.polls, (unsigned long long)st.requests,
                  (unsigned long long)st.failed_polls, (unsigned long long)st.timeouts,
                  atomic_load(&nm.bytes[0]), atomic_load(&nm.bytes[1]));
    vibid_source_close(s);
    if (samples < 1500)
        fail_msg("RTU FIFO: only %llu samples in 2 s at 1 kHz (want >= 1500)", (unsigned long long)samples);
    assert_int_equal(st.failed_polls, 0);
    assert_int_equal(st.samples, samples);

    /* snapshot at 20 Hz, same line and server. On a loaded machine the Python server can
     * answer late: a missed deadline is a GAP record (as documented), so GAPs are
     * accepted but accounted: indices contiguous, samples + missing = ticks. */
    cfg = rtu_cfg(rm, nm.name[0]);
    cfg.mode = VIBID_MODBUS_SNAPSHOT;
    cfg.sample_period_s = 0.05;
    s = vibid_source_open(&vibid_source_modbus_ops, &cfg, &err);
    if (!s)
        fail_msg("RTU snapshot open: %s", err.text);
    uint64_t snaps = 0, missing = 0, k = 0;
    long last = -1;
    end = mono_ns() + (int64_t)1.0e9;
    while (mono_ns() < end) {
        vibid_drv_status rs = vibid_source_read(s, r, 16, &n, 20, &err);
        if (rs != VIBID_DRV_OK && rs != VIBID_DRV_E_AGAIN)
            fail_msg("read: %s", err.text);
        for (size_t i = 0; i < n; i++) {
            if (r[i].kind == VIBID_REC_FAULT)
                fail_msg("RTU snapshot: fault: %s", r[i].text);
            assert_int_equal(r[i].index, k);
            if (r[i].kind == VIBID_REC_GAP) {
                print_message("RTU snapshot gap: k=%llu count=%llu: %s\n", (unsigned long long)r[i].index,
                              (unsigned long long)r[i].count, r[i].text);
                missing += r[i].count;
                k += r[i].count;
                continue;
            }
            long sv = check_values(&r[i]);
            assert_true(sv >= last); /* the server's counter never goes back */
            last = sv;
            snaps++;
            k++;
        }
    }
    vibid_source_stats_get(s, &st);
    print_message("RTU snapshot: %llu samples + %llu missed in 1 s at 20 Hz, interval mean %.4f ms, std %.4f ms\n",
                  (unsigned long long)snaps, (unsigned long long)missing, st.jitter.mean_s * 1e3,
                  st.jitter.std_s * 1e3);
    vibid_source_close(s);
    /* 1 s / 50 ms = 20 ticks + the first; the last may be unread at the end (-1, and
     * -1 more for a GAP still pending); at least 15 real samples even on a busy machine */
    if (snaps + missing < 19 || snaps + missing > 21 || snaps < 15)
        fail_msg("RTU snapshot: %llu samples + %llu missed in 1 s at 20 Hz (want 19..21 ticks, >= 15 samples)",
                 (unsigned long long)snaps, (unsigned long long)missing);

    kill(srv_pid, SIGTERM); /* done with it; it would serve until its 10 s schedule ends */
    waitpid(srv_pid, NULL, 0);
    fclose(srv);
    null_modem_close(&nm);
    vibid_regmap_destroy(rm);
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(test_rtu_fifo_and_snapshot)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
