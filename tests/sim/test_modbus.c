/* sim.modbus: vibid-sim's Modbus TCP server (127.0.0.1, ephemeral port) answered by a
 * libmodbus client following drivers/modbus_fifo_layout.md, while another client sends
 * garbage and a third disconnects; every sample read from the FIFO equals the CSV row
 * of the same run (float32). Then stop/resume: the server closes, refuses connections,
 * and comes back with a new session and count 0. Then a client pipelining requests
 * without reading and one stopping mid-request beside a polling one. Bounded: each run
 * lasts <= 4 s. */
#include <arpa/inet.h>
#include <errno.h>
#include <math.h>
#include <modbus.h>
#include <netinet/in.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>
#include <sys/socket.h>
#include <time.h>

#include <vibid_drivers/csv_capture.h>

#include "sim_test_util.h"

#define STAND1 VIBID_EXAMPLES_DIR "/paper_example1.cfg"
#define SIM1 VIBID_SIM_SOURCE_DIR "/examples/paper_example1_sim.cfg"
#define REGMAP1 VIBID_SIM_SOURCE_DIR "/paper_example1_registers.cfg"
#define B 1000

static FILE *start_sim(const char *extra, int *port)
{
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "%s -c %s -s %s --modbus 127.0.0.1:0 --regmap %s %s", VIBID_SIM_EXE, STAND1, SIM1, REGMAP1, extra);
    FILE *p = popen(cmd, "r");
    assert_non_null(p);
    char line[512];
    assert_non_null(fgets(line, sizeof line, p));
    const char *c = strstr(line, "127.0.0.1:");
    assert_non_null(c);
    *port = atoi(c + 10);
    assert_true(*port > 0);
    return p;
}

static double now_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static float f32(const uint16_t *w)
{
    uint32_t u = ((uint32_t)w[0] << 16) | w[1];
    float f;
    memcpy(&f, &u, 4);
    return f;
}

static modbus_t *client(int port)
{
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", port);
    assert_non_null(ctx);
    modbus_set_response_timeout(ctx, 0, 500000);
    if (modbus_connect(ctx) != 0) {
        modbus_free(ctx);
        return NULL;
    }
    return ctx;
}

static void test_fifo_against_csv(void **state)
{
    (void)state;
    const char *csv = tmp_path("mb.csv");
    char extra[1024];
    snprintf(extra, sizeof extra, "--duration 2.5 --csv %s", csv);
    int port;
    FILE *p = start_sim(extra, &port);
    modbus_t *ctx = client(port);
    assert_non_null(ctx);
    uint16_t hdr[19];
    assert_int_equal(modbus_read_registers(ctx, B, 19, hdr), 19);
    assert_int_equal(hdr[0], 0x5646);
    assert_int_equal(hdr[1], 1);
    assert_int_equal(hdr[2], 3);  /* x1, x2, s */
    assert_int_equal(hdr[3], 7);  /* tag + 3 FLOAT32 */
    assert_int_equal(hdr[4], 1000);
    assert_int_equal(hdr[5], 64);
    assert_int_equal(((uint32_t)hdr[6] << 16) | hdr[7], 500000); /* 2 kHz */
    for (int i = 0; i < 3; i++) assert_int_equal(hdr[16 + i], 4); /* FLOAT32, ABCD */
    unsigned W = hdr[3], K = hdr[4];

    /* a garbage client (kept open) and one that connects and leaves */
    int g = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_port = htons((uint16_t)port)};
    inet_pton(AF_INET, "127.0.0.1", &a.sin_addr);
    assert_int_equal(connect(g, (struct sockaddr *)&a, sizeof a), 0);
    const char junk[] = "\x01\x02\x00\x07\xff\xff\x09garbage garbage garbage\r\n";
    assert_true(send(g, junk, sizeof junk, 0) > 0);
    modbus_t *quitter = client(port);
    assert_non_null(quitter);
    modbus_close(quitter);
    modbus_free(quitter);

    /* writes are refused */
    assert_int_equal(modbus_write_register(ctx, B + 8, 1), -1);
    assert_int_equal(errno, EMBXILFUN);

    /* poll the FIFO for 1.5 s */
    size_t cap = 20000, got = 0, gaps = 0;
    uint32_t *idx = calloc(cap, sizeof *idx);
    float (*val)[3] = calloc(cap, sizeof *val);
    uint32_t next = 0;
    int first = 1;
    double t_end = now_s() + 1.5;
    uint16_t regs[125];
    while (now_s() < t_end) {
        uint16_t c[4];
        assert_int_equal(modbus_read_registers(ctx, B + 8, 4, c), 4);
        uint32_t S = ((uint32_t)c[0] << 16) | c[1];
        unsigned ws = c[2];
        if (first) {
            next = S > K ? S - K : 0;
            first = 0;
        }
        if (S - next > K) {
            gaps += S - K - next;
            next = S - K;
        }
        while (next < S) {
            unsigned slot = (ws + K - (S - next)) % K;
            unsigned nrec = 125 / W;
            if (nrec > S - next) nrec = S - next;
            if (slot + nrec > K) nrec = K - slot;
            assert_int_equal(modbus_read_registers(ctx, (int)(B + 64 + slot * W), (int)(nrec * W), regs), (int)(nrec * W));
            for (unsigned r = 0; r < nrec; r++) {
                const uint16_t *rec = regs + r * W;
                uint32_t s = next + r;
                if (rec[0] != (s & 0xFFFF)) { gaps++; continue; }
                assert_true(got < cap);
                idx[got] = s;
                for (int ch = 0; ch < 3; ch++) val[got][ch] = f32(rec + 1 + 2 * ch);
                got++;
            }
            next += nrec;
        }
        usleep(20000);
    }
    /* current-value registers: a recent sample, decodable */
    uint16_t cur[6];
    assert_int_equal(modbus_read_registers(ctx, 0, 6, cur), 6);
    assert_true(isfinite(f32(cur)) && isfinite(f32(cur + 2)) && isfinite(f32(cur + 4)));
    modbus_close(ctx);
    modbus_free(ctx);
    close(g);
    assert_int_equal(pclose(p), 0);

    /* compare with the CSV (all samples of the run) */
    vibid_drv_error err;
    vibid_csv_reader *r = vibid_csv_open(csv, &err);
    if (!r) fail_msg("%s", err.text);
    double row[4];
    unsigned long line;
    size_t k = 0, j = 0, matched = 0;
    while (vibid_csv_next(r, row, &line, &err) == VIBID_DRV_OK && j < got) {
        if (idx[j] == k) {
            /* FIFO order x1, x2, s (register map); CSV t, s, x1, x2 */
            assert_true(val[j][0] == (float)row[2]);
            assert_true(val[j][1] == (float)row[3]);
            assert_true(val[j][2] == (float)row[1]);
            matched++;
            j++;
        }
        k++;
    }
    vibid_csv_close(r);
    print_message("FIFO: %zu samples read over 1.5 s from sample %u, %zu gap samples, %zu matched the CSV\n", got,
                  got ? idx[0] : 0, gaps, matched);
    assert_int_equal(matched, got);
    assert_true(got >= 2500);   /* 1.5 s at 2 kHz = 3000, less start-up */
    assert_int_equal(gaps, 0);  /* polled every 20 ms, the FIFO spans 0.5 s */
    for (size_t i = 1; i < got; i++) assert_int_equal(idx[i], idx[i - 1] + 1);
    free(idx);
    free(val);
}

static void test_stop_resume(void **state)
{
    (void)state;
    int port;
    FILE *p = start_sim("--duration 2.5 --stop-at 0.6 --resume-at 1.2", &port);
    modbus_t *ctx = client(port);
    assert_non_null(ctx);
    uint16_t c[4];
    assert_int_equal(modbus_read_registers(ctx, B + 8, 4, c), 4);
    uint16_t session1 = c[3];
    usleep(900000); /* now t ~ 0.9 s: stopped */
    assert_int_equal(modbus_read_registers(ctx, B + 8, 4, c), -1); /* our connection was closed */
    modbus_close(ctx);
    modbus_free(ctx);
    modbus_t *refused = client(port);
    assert_null(refused); /* nobody listening while stopped */
    usleep(700000); /* t ~ 1.6 s: serving again */
    ctx = client(port);
    assert_non_null(ctx);
    assert_int_equal(modbus_read_registers(ctx, B + 8, 4, c), 4);
    uint32_t S = ((uint32_t)c[0] << 16) | c[1];
    print_message("after resume: session %u -> %u, count %u (restarted at t = 1.2 s)\n", session1, c[3], S);
    assert_true(c[3] != session1 || S < 1500);
    assert_true(S < 2000); /* restarted about 0.4 s ago at 2 kHz: ~800, certainly < 1 s worth */
    modbus_close(ctx);
    modbus_free(ctx);
    assert_int_equal(pclose(p), 0);
}

static int raw_connect(int port)
{
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    assert_true(fd >= 0);
    struct sockaddr_in sa = {.sin_family = AF_INET, .sin_port = htons((uint16_t)port)};
    sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    assert_int_equal(connect(fd, (struct sockaddr *)&sa, sizeof sa), 0);
    return fd;
}

/* Issue 12, item 10: a client that pipelines requests without reading its replies, and
 * one that sends half a request and stops, must not stall the server for the others.
 * Before, the server thread blocked in send() to the first (holding the register lock)
 * and in modbus_receive on the second: the polling client's reads timed out. Now the
 * polling client gets every reply, and the non-reading client is closed by the server
 * (its replies are read back up to end of file). */
static void test_hostile_clients(void **state)
{
    (void)state;
    int port;
    FILE *p = start_sim("--duration 4", &port);
    int hog = raw_connect(port), drip = raw_connect(port);
    /* half an MBAP header: the rest never comes */
    const uint8_t half[3] = {0x00, 0x01, 0x00};
    assert_int_equal(send(drip, half, sizeof half, 0), 3);
    /* read 125 holding registers at B, pipelined without reading: 259-byte replies */
    uint8_t req[12] = {0, 0, 0, 0, 0, 6, 1, 3, (uint8_t)(B >> 8), (uint8_t)(B & 0xFF), 0, 125};
    long sent = 0;
    double t0 = now_s();
    while (sent < 400000 && now_s() - t0 < 1.0) {
        req[0] = (uint8_t)(sent >> 8);
        req[1] = (uint8_t)sent;
        ssize_t w = send(hog, req, sizeof req, MSG_DONTWAIT | MSG_NOSIGNAL);
        if (w < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
            usleep(1000);
            continue;
        }
        if (w < 0) break; /* the server closed it already */
        assert_int_equal(w, (ssize_t)sizeof req);
        sent++;
    }
    print_message("pipelined %ld requests without reading\n", sent);
    /* a well-behaved client polls the FIFO's count for 1 s: every read answered */
    modbus_t *ctx = client(port);
    assert_non_null(ctx);
    double worst = 0;
    int reads = 0;
    for (double t1 = now_s(); now_s() - t1 < 1.0; reads++) {
        uint16_t c[4];
        double a = now_s();
        if (modbus_read_registers(ctx, B + 8, 4, c) != 4)
            fail_msg("read %d of the polling client failed: %s (the server stalled)", reads, modbus_strerror(errno));
        if (now_s() - a > worst) worst = now_s() - a;
        usleep(10000);
    }
    print_message("%d reads by a polling client, slowest %.1f ms\n", reads, worst * 1e3);
    modbus_close(ctx);
    modbus_free(ctx);
    /* the hog was closed by the server: its unread replies, then end of file */
    struct timeval tv = {3, 0};
    setsockopt(hog, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    static uint8_t buf[1 << 16];
    long bytes = 0;
    ssize_t r;
    while ((r = recv(hog, buf, sizeof buf, 0)) > 0) bytes += r;
    if (r != 0 && !(r < 0 && errno == ECONNRESET))
        fail_msg("the non-reading client was not closed by the server (recv: %s)", strerror(errno));
    print_message("non-reading client closed by the server after %ld reply bytes (%ld replies of %ld requests)\n",
                  bytes, bytes / 259, sent);
    close(hog);
    close(drip);
    assert_int_equal(pclose(p), 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_fifo_against_csv),
        cmocka_unit_test(test_stop_resume),
        cmocka_unit_test(test_hostile_clients),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
