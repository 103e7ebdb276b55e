/* The Modbus source's tests and benchmark against the Python peers of tests/drivers
 * (modbus_fifo_server.py, modbus_slow_server.py) run with --control: the peer serves
 * until its stdin ends, takes commands there and answers each on its stdout once done,
 * so that a test waits for events, never for a schedule. Also the register map of the
 * peers' signal, configurations reading it and the check of its values (also used by
 * modbus_rtu.c against the same server over a serial line).
 * The includer defines MODBUS_PEER_FAIL(fmt, ...) (does not return) and
 * MODBUS_PEER_NOTE(fmt, ...) (a message) first; needs _GNU_SOURCE (pipe2). */
#ifndef VIBID_TEST_MODBUS_PEER_H
#define VIBID_TEST_MODBUS_PEER_H

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <vibid_drivers/source_modbus.h>

#include "source_util.h" /* drivers/src: the source's own clocks, mono_ns and real_ns */
#include "drv_test_util.h"

extern char **environ;

/* Only a hung test waits this long for an event (a count of samples, a fault, a peer's
 * answer to a command); on an idle machine each of them comes within a second. */
#define HANG_S 60

static const char regmap_text[] =
    "registers = (\n"
    "  { name = \"a\"; address = 0;  register = \"holding\"; type = \"FLOAT32\"; byte_order = \"ABCD\"; },\n"
    "  { name = \"b\"; address = 2;  register = \"holding\"; type = \"INT16\";   scale = 0.001; },\n"
    "  { name = \"c\"; address = 10; register = \"holding\"; type = \"FLOAT32\"; byte_order = \"CDAB\"; }\n"
    ");\n";

static inline void hang_check(int64_t since, const char *what)
{
    if (mono_ns() - since > (int64_t)HANG_S * 1000000000)
        MODBUS_PEER_FAIL("still waiting for %s after %d s: hung", what, HANG_S);
}

static inline int free_port(void)
{
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    bind(fd, (struct sockaddr *)&a, sizeof a);
    socklen_t l = sizeof a;
    getsockname(fd, (struct sockaddr *)&a, &l);
    close(fd);
    return ntohs(a.sin_port);
}

/* A Python server run with --control: commands go to its stdin, answers come back as
 * lines on its stdout. It exits when its stdin ends (also when this program dies). */
typedef struct peer {
    int port; /* 127.0.0.1:port */
    pid_t pid;
    int in, out;
    char buf[4096];
    size_t len;
} peer;

/* The next line of the peer's output (without its newline), waiting up to timeout_ms:
 * 1 a line, 0 none yet, -1 the output ended. */
static inline int peer_line(peer *p, int timeout_ms, char *line, size_t cap)
{
    for (;;) {
        char *nl = memchr(p->buf, '\n', p->len);
        if (nl) {
            const size_t l = (size_t)(nl - p->buf);
            snprintf(line, cap, "%.*s", (int)l, p->buf);
            memmove(p->buf, nl + 1, p->len - l - 1);
            p->len -= l + 1;
            return 1;
        }
        struct pollfd pf = {.fd = p->out, .events = POLLIN};
        const int r = poll(&pf, 1, timeout_ms);
        if (r < 0 && errno == EINTR)
            continue;
        if (r <= 0)
            return 0;
        if (p->len == sizeof p->buf)
            MODBUS_PEER_FAIL("peer: line longer than %zu bytes", sizeof p->buf);
        const ssize_t k = read(p->out, p->buf + p->len, sizeof p->buf - p->len);
        if (k < 0 && errno == EINTR)
            continue;
        if (k <= 0)
            return -1;
        p->len += (size_t)k;
    }
}

/* Waits for the peer's line starting with prefix (earlier lines are printed). */
static inline void peer_expect(peer *p, const char *prefix, char *line, size_t cap)
{
    const int64_t since = mono_ns();
    for (;;) {
        const int r = peer_line(p, 1000, line, cap);
        if (r < 0)
            MODBUS_PEER_FAIL("peer ended before printing '%s'", prefix);
        if (r > 0 && strncmp(line, prefix, strlen(prefix)) == 0)
            return;
        if (r > 0)
            MODBUS_PEER_NOTE("peer: %s\n", line);
        hang_check(since, prefix);
    }
}

/* Sends one command and waits for its answer (the line starting with `answer`). */
static inline void peer_command(peer *p, const char *cmd, const char *answer, char *line, size_t cap)
{
    if (dprintf(p->in, "%s\n", cmd) < 0)
        MODBUS_PEER_FAIL("peer: cannot send '%s': %s", cmd, strerror(errno));
    peer_expect(p, answer, line, cap);
}

/* Starts `script --port P --control args` with the venv's Python on a free port P
 * (p->port); returns once it printed READY. */
static inline void peer_start(peer *p, const char *script, const char *args)
{
    const int port = p->port = free_port();
    const char *py = getenv("VIBID_PYTHON");
    if (!py || access(py, X_OK) != 0)
        MODBUS_PEER_FAIL("FAIL: VIBID_PYTHON='%s' is not an executable venv interpreter (scripts/python-venv.sh)",
                 py ? py : "");
    char cmd[1024];
    snprintf(cmd, sizeof cmd, "exec '%s' '%s' --port %d --control %s", py, script, port, args);
    int in[2], out[2];
    if (pipe2(in, O_CLOEXEC) != 0 || pipe2(out, O_CLOEXEC) != 0)
        MODBUS_PEER_FAIL("pipe: %s", strerror(errno));
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_adddup2(&fa, in[0], 0);
    posix_spawn_file_actions_adddup2(&fa, out[1], 1);
    char *argv[] = {"/bin/sh", "-c", cmd, NULL};
    const int rc = posix_spawn(&p->pid, "/bin/sh", &fa, NULL, argv, environ);
    posix_spawn_file_actions_destroy(&fa);
    close(in[0]);
    close(out[1]);
    if (rc != 0)
        MODBUS_PEER_FAIL("cannot start %s: %s", cmd, strerror(rc));
    p->in = in[1];
    p->out = out[0];
    p->len = 0;
    char line[256];
    peer_expect(p, "READY", line, sizeof line);
}

/* Ends the peer's input; it stops serving and exits, which must be with status 0. */
static inline void peer_finish(peer *p)
{
    close(p->in);
    char line[256];
    const int64_t since = mono_ns();
    int r;
    while ((r = peer_line(p, 1000, line, sizeof line)) >= 0)
        if (r == 0 && mono_ns() - since > (int64_t)HANG_S * 1000000000) {
            kill(p->pid, SIGKILL);
            MODBUS_PEER_FAIL("peer did not exit within %d s of the end of its input", HANG_S);
        }
    close(p->out);
    int status = 0;
    waitpid(p->pid, &status, 0);
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0)
        MODBUS_PEER_FAIL("peer exited with wait status 0x%x", status);
}

/* Stops the peer's session `phase`: what it served, when the session started (its
 * CLOCK_MONOTONIC, s) and its longest gap between two register updates (s). */
static inline void peer_stop(peer *p, int phase, unsigned long *served, double *t0, double *maxgap)
{
    char line[256];
    int ph = -1;
    peer_command(p, "stop", "PHASE", line, sizeof line);
    if (sscanf(line, "PHASE %d served %lu samples t0 %lf maxgap %lf", &ph, served, t0, maxgap) != 4 || ph != phase)
        MODBUS_PEER_FAIL("peer: '%s' (expected PHASE %d ...)", line, phase);
}

static inline vibid_regmap *load_regmap(void)
{
    char path[512];
    if (!drv_write_tmp("regs.cfg", regmap_text, sizeof regmap_text - 1, path, sizeof path))
        MODBUS_PEER_FAIL("cannot write %s: %s", path, strerror(errno));
    vibid_drv_error err = {0};
    vibid_regmap *rm = vibid_regmap_load(path, &err);
    if (!rm)
        MODBUS_PEER_FAIL("%s", err.text);
    unlink(path);
    return rm;
}

/* The channels a, b, c of the peers' register map, back-off 0.05 .. 0.4 s; no transport. */
static inline vibid_source_modbus_config peer_cfg(const vibid_regmap *rm)
{
    vibid_source_modbus_config c;
    memset(&c, 0, sizeof c);
    c.regmap = rm;
    c.chanmap.n = 3;
    const char *names[] = {"a", "b", "c"};
    for (int i = 0; i < 3; i++) {
        strcpy(c.chanmap.ch[i].name, names[i]);
        strcpy(c.chanmap.ch[i].ref, names[i]);
        c.chanmap.ch[i].source = VIBID_CHAN_REGISTER;
    }
    c.backoff_initial_s = 0.05;
    c.backoff_max_s = 0.4;
    return c;
}

/* peer_cfg over Modbus TCP to 127.0.0.1:port, response timeout 0.2 s. */
static inline vibid_source_modbus_config base_cfg(const vibid_regmap *rm, int port)
{
    vibid_source_modbus_config c = peer_cfg(rm);
    c.transport = VIBID_MODBUS_TCP;
    c.host = "127.0.0.1";
    c.port = port;
    c.response_timeout_s = 0.2;
    return c;
}

/* Opens a Modbus source, or fails. */
static inline vibid_source *peer_open(const vibid_source_modbus_config *cfg)
{
    vibid_drv_error err = {0};
    vibid_source *s = vibid_source_open(&vibid_source_modbus_ops, cfg, &err);
    if (!s)
        MODBUS_PEER_FAIL("open: %s", err.text);
    return s;
}

/* Starts modbus_fifo_server.py (script) and opens a snapshot-mode source on it sampling
 * every h_s seconds. */
static inline vibid_source *peer_snapshot(peer *p, const char *script, const vibid_regmap *rm, double h_s)
{
    peer_start(p, script, "");
    vibid_source_modbus_config cfg = base_cfg(rm, p->port);
    cfg.mode = VIBID_MODBUS_SNAPSHOT;
    cfg.sample_period_s = h_s;
    return peer_open(&cfg);
}

/* The peers' signal: sample s has c = 0.5 s (exact in float32 below 2^24), a = sin(0.01 s)
 * rounded to float32, b = ((s mod 1000) - 500) * 0.001. Returns s, or fails. */
static inline long check_values(const vibid_record *r)
{
    double s = r->values[2] * 2.0;
    if (s < 0 || s != floor(s))
        MODBUS_PEER_FAIL("sample %llu: c = %.9g is not 0.5 * integer", (unsigned long long)r->index, r->values[2]);
    long si = (long)s;
    double a = (double)(float)sin(0.01 * s);
    double b = (double)((si % 1000) - 500) * 0.001;
    /* a: float32 bit-exact; b: raw integer * 0.001 computed identically -> exact */
    if (r->values[0] != a || r->values[1] != b)
        MODBUS_PEER_FAIL("sample %llu (s = %ld): a = %.9g (want %.9g), b = %.9g (want %.9g)",
                         (unsigned long long)r->index, si, r->values[0], a, r->values[1], b);
    return si;
}

#endif
