/* SocketCAN source without a CAN kernel: (1) opening a real CAN socket here fails with a
 * clear message; (2) the cmsg parser on hand-built control messages (hardware and
 * software stamps, SO_RXQ_OVFL, truncation, FD/EFF/RTR/error flags); (3) the whole
 * receive path (recvmmsg batching, parsing, assembly, drop accounting) on can_frame /
 * canfd_frame bytes sent through an AF_UNIX datagram socketpair. */
#include <errno.h>
#include <time.h> /* before linux/errqueue.h: struct timespec */
#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/errqueue.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <stdlib.h>
#include <unistd.h>

#include <cmocka.h>
#include <vibid_drivers/source_socketcan.h>

#include "socketcan_rx.h"

/* A: classic 11-bit, counter + force; B: CAN FD 29-bit, 12 bytes, counter + two floats */
static const char dbc_text[] =
    "BO_ 256 A: 8 S\n SG_ Cnt : 0|8@1+ (1,0) [0|255] \"\" X\n SG_ F : 8|16@1- (0.01,0) [0|0] \"N\" X\n"
    "BO_ 2566848513 B: 12 S\n SG_ Cnt : 0|8@1+ (1,0) [0|255] \"\" X\n SG_ X : 32|32@1- (1,0) [0|0] \"m\" X\n"
    " SG_ V : 64|32@1- (1,0) [0|0] \"m/s\" X\n"
    "SIG_VALTYPE_ 2566848513 X : 1;\nSIG_VALTYPE_ 2566848513 V : 1;\n";
#define B_ID 0x18FF0001u /* 2566848513 = 0x80000000 | 0x18FF0001 */

static vibid_chanmap map(void)
{
    vibid_chanmap m;
    memset(&m, 0, sizeof m);
    m.n = 3;
    strcpy(m.ch[0].name, "F");
    strcpy(m.ch[0].ref, "F");
    strcpy(m.ch[1].name, "x");
    strcpy(m.ch[1].ref, "X");
    strcpy(m.ch[2].name, "v");
    strcpy(m.ch[2].ref, "V");
    strcpy(m.counter, "Cnt");
    return m;
}

static struct can_frame frame_a(uint8_t cnt, double force)
{
    struct can_frame f;
    memset(&f, 0, sizeof f);
    f.can_id = 0x100;
    f.len = 8;
    f.data[0] = cnt;
    int16_t r = (int16_t)lround(force / 0.01);
    memcpy(f.data + 1, &r, 2); /* x86: little endian, as the DBC's @1 */
    return f;
}

static struct canfd_frame frame_b(uint8_t cnt, float x, float v)
{
    struct canfd_frame f;
    memset(&f, 0, sizeof f);
    f.can_id = B_ID | CAN_EFF_FLAG;
    f.len = 12;
    f.flags = CANFD_BRS;
    f.data[0] = cnt;
    memcpy(f.data + 4, &x, 4);
    memcpy(f.data + 8, &v, 4);
    return f;
}

static void test_real_can_open_fails_clearly(void **state)
{
    (void)state;
    vibid_drv_error err = {0};
    vibid_dbc *dbc = vibid_dbc_parse(dbc_text, sizeof dbc_text - 1, "t.dbc", &err);
    assert_non_null(dbc);
    vibid_source_socketcan_config cfg;
    memset(&cfg, 0, sizeof cfg);
    cfg.iface = "vibidnone0";
    cfg.dbc = dbc;
    cfg.chanmap = map();
    vibid_source *s = vibid_source_open(&vibid_source_socketcan_ops, &cfg, &err);
    assert_null(s);
    int probe = socket(PF_CAN, SOCK_RAW, CAN_RAW);
    if (probe < 0) {
        /* the build hosts: no CAN in the kernel */
        assert_int_equal(err.status, VIBID_DRV_E_UNSUPPORTED);
        assert_non_null(strstr(err.text, "this kernel has no SocketCAN support"));
        assert_non_null(strstr(err.text, "modprobe can-raw"));
    } else {
        close(probe); /* a CAN-capable kernel: the interface does not exist */
        assert_int_equal(err.status, VIBID_DRV_E_NOT_FOUND);
        assert_non_null(strstr(err.text, "no interface 'vibidnone0'"));
    }
    print_message("open on this host: %s\n", err.text);
    cfg.iface = "an-interface-name-too-long";
    assert_null(vibid_source_open(&vibid_source_socketcan_ops, &cfg, &err));
    assert_int_equal(err.status, VIBID_DRV_E_ARG);
    vibid_dbc_destroy(dbc);
}

/* Builds a msghdr with the frame bytes and the given cmsgs. */
typedef struct built {
    struct msghdr mh;
    struct iovec iov;
    struct canfd_frame fr;
    union {
        char buf[256];
        struct cmsghdr align;
    } ctrl;
} built;

static void build(built *b, const void *frame, size_t len, const struct scm_timestamping *ts, const uint32_t *drops)
{
    memset(b, 0, sizeof *b);
    memcpy(&b->fr, frame, len);
    b->iov.iov_base = &b->fr;
    b->iov.iov_len = len;
    b->mh.msg_iov = &b->iov;
    b->mh.msg_iovlen = 1;
    b->mh.msg_control = b->ctrl.buf;
    b->mh.msg_controllen = (ts ? CMSG_SPACE(sizeof *ts) : 0) + (drops ? CMSG_SPACE(sizeof *drops) : 0);
    if (!b->mh.msg_controllen) {
        b->mh.msg_control = NULL;
        return;
    }
    struct cmsghdr *c = CMSG_FIRSTHDR(&b->mh);
    if (ts) {
        c->cmsg_level = SOL_SOCKET;
        c->cmsg_type = SO_TIMESTAMPING;
        c->cmsg_len = CMSG_LEN(sizeof *ts);
        memcpy(CMSG_DATA(c), ts, sizeof *ts);
        c = CMSG_NXTHDR(&b->mh, c);
    }
    if (drops) {
        c->cmsg_level = SOL_SOCKET;
        c->cmsg_type = SO_RXQ_OVFL;
        c->cmsg_len = CMSG_LEN(sizeof *drops);
        memcpy(CMSG_DATA(c), drops, sizeof *drops);
    }
}

static void test_parse_cmsgs(void **state)
{
    (void)state;
    built b;
    vibid_can_frame f;
    socketcan_meta m;
    char why[128];
    struct scm_timestamping ts;
    memset(&ts, 0, sizeof ts);
    ts.ts[0] = (struct timespec){1700000000, 123456789}; /* software */
    ts.ts[2] = (struct timespec){42, 5};                 /* hardware (interface clock) */
    uint32_t drops = 7;
    struct can_frame a = frame_a(9, -1.5);
    build(&b, &a, sizeof a, &ts, &drops);
    assert_int_equal(socketcan_parse_msg(&b.mh, sizeof a, "can0", 111, &f, &m, why, sizeof why), 0);
    assert_true(m.hw_stamp && !m.sw_stamp && m.have_drops && m.drops == 7);
    assert_true(f.t_ns == INT64_C(42000000005)); /* hardware wins */
    assert_true(f.id == 0x100 && f.flags == 0 && f.len == 8 && f.data[0] == 9);
    assert_string_equal(f.iface, "can0");
    /* software only */
    ts.ts[2] = (struct timespec){0, 0};
    build(&b, &a, sizeof a, &ts, NULL);
    assert_int_equal(socketcan_parse_msg(&b.mh, sizeof a, "can0", 111, &f, &m, why, sizeof why), 0);
    assert_true(!m.hw_stamp && m.sw_stamp && !m.have_drops);
    assert_true(f.t_ns == INT64_C(1700000000123456789));
    /* no cmsg: the caller's receive time */
    build(&b, &a, sizeof a, NULL, NULL);
    assert_int_equal(socketcan_parse_msg(&b.mh, sizeof a, "can0", 111, &f, &m, why, sizeof why), 0);
    assert_true(f.t_ns == 111 && !m.hw_stamp && !m.sw_stamp);
    /* FD, 29-bit, flags nibble kept */
    struct canfd_frame bf = frame_b(3, 1.5f, -2.25f);
    build(&b, &bf, sizeof bf, NULL, &drops);
    assert_int_equal(socketcan_parse_msg(&b.mh, sizeof bf, "can0", 1, &f, &m, why, sizeof why), 0);
    assert_true(f.id == B_ID && f.flags == (VIBID_CAN_F_EXT | VIBID_CAN_F_FD) && f.fd_flags == CANFD_BRS);
    assert_int_equal(f.len, 12);
    /* RTR: no payload copied; error frame: class bits in id */
    struct can_frame r = {.can_id = 0x123 | CAN_RTR_FLAG, .len = 4};
    build(&b, &r, sizeof r, NULL, NULL);
    assert_int_equal(socketcan_parse_msg(&b.mh, sizeof r, "can0", 1, &f, &m, why, sizeof why), 0);
    assert_true(f.flags == VIBID_CAN_F_RTR && f.id == 0x123 && f.len == 4);
    struct can_frame e = {.can_id = CAN_ERR_FLAG | CAN_ERR_BUSOFF | CAN_ERR_CRTL, .len = 8};
    e.data[1] = CAN_ERR_CRTL_RX_OVERFLOW;
    build(&b, &e, sizeof e, NULL, NULL);
    assert_int_equal(socketcan_parse_msg(&b.mh, sizeof e, "can0", 1, &f, &m, why, sizeof why), 0);
    assert_true(f.flags == VIBID_CAN_F_ERR && f.id == (CAN_ERR_BUSOFF | CAN_ERR_CRTL) && f.data[1] == 1);
    /* classic DLC 9..15 (len8_dlc): 8 bytes of payload */
    a.len = 15;
    build(&b, &a, sizeof a, NULL, NULL);
    assert_int_equal(socketcan_parse_msg(&b.mh, sizeof a, "can0", 1, &f, &m, why, sizeof why), 0);
    assert_int_equal(f.len, 8);
    /* wrong sizes, FD length > 64, truncated datagram: errors, but drops still read */
    build(&b, &a, 10, NULL, &drops);
    assert_int_equal(socketcan_parse_msg(&b.mh, 10, "can0", 1, &f, &m, why, sizeof why), -1);
    assert_non_null(strstr(why, "datagram of 10 bytes is neither can_frame (16) nor canfd_frame (72)"));
    assert_true(m.have_drops && m.drops == 7);
    bf.len = 65;
    build(&b, &bf, sizeof bf, NULL, NULL);
    assert_int_equal(socketcan_parse_msg(&b.mh, sizeof bf, "can0", 1, &f, &m, why, sizeof why), -1);
    assert_non_null(strstr(why, "length 65 > 64"));
    bf.len = 12;
    build(&b, &bf, sizeof bf, NULL, NULL);
    b.mh.msg_flags = MSG_TRUNC;
    assert_int_equal(socketcan_parse_msg(&b.mh, sizeof bf, "can0", 1, &f, &m, why, sizeof why), -1);
    assert_non_null(strstr(why, "truncated"));
}

static int64_t real_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

/* 200 samples (400 frames, classic + FD) through a socketpair, plus an error frame, an
 * unknown id, a bad datagram and a skipped counter value: exact records, and recvmmsg
 * delivers frames in batches (fewer system calls than frames). */
static void test_socketpair_path(void **state)
{
    (void)state;
    vibid_drv_error err = {0};
    vibid_dbc *dbc = vibid_dbc_parse(dbc_text, sizeof dbc_text - 1, "t.dbc", &err);
    assert_non_null(dbc);
    int sv[2];
    assert_int_equal(socketpair(AF_UNIX, SOCK_DGRAM, 0, sv), 0);
    int big = 1 << 20;
    setsockopt(sv[0], SOL_SOCKET, SO_SNDBUF, &big, sizeof big);
    vibid_source_socketcan_config cfg;
    memset(&cfg, 0, sizeof cfg);
    cfg.iface = "vcan-test";
    cfg.dbc = dbc;
    cfg.chanmap = map();
    cfg.batch = 32;
    cfg.rcvbuf_bytes = 1 << 20;
    cfg.use_fd = true;
    cfg.fd = sv[1];
    vibid_source *s = vibid_source_open(&vibid_source_socketcan_ops, &cfg, &err);
    if (!s)
        fail_msg("%s", err.text);
    vibid_socketcan_info info;
    assert_int_equal(vibid_source_socketcan_info(s, &info), VIBID_DRV_OK);
    assert_int_equal(info.batch, 32);
    assert_true(info.rcvbuf_bytes > 0);
    /* nothing sent yet: a 0 ms and a 20 ms read both time out */
    vibid_record r[64];
    size_t n;
    assert_int_equal(vibid_source_read(s, r, 64, &n, 0, &err), VIBID_DRV_E_AGAIN);
    assert_int_equal(vibid_source_read(s, r, 64, &n, 20, &err), VIBID_DRV_E_AGAIN);
    int64_t t_before = real_now();
    const int N = 200;
    for (int k = 0; k < N; k++) {
        if (k == 150)
            continue; /* sample 150 never sent: a GAP of 1 */
        struct can_frame a = frame_a((uint8_t)k, 0.01 * (k - 100));
        struct canfd_frame b = frame_b((uint8_t)k, (float)k * 0.5f, -(float)k);
        assert_int_equal(send(sv[0], &a, sizeof a, 0), (ssize_t)sizeof a);
        assert_int_equal(send(sv[0], &b, sizeof b, 0), (ssize_t)sizeof b);
        if (k == 50) {
            struct can_frame e = {.can_id = CAN_ERR_FLAG | CAN_ERR_BUSOFF, .len = 8};
            struct can_frame u = {.can_id = 0x555, .len = 2};
            char junk[10] = {0};
            send(sv[0], &e, sizeof e, 0);
            send(sv[0], &u, sizeof u, 0);
            send(sv[0], junk, sizeof junk, 0);
        }
    }
    int64_t t_after = real_now();
    uint64_t next = 0, gaps = 0, faults = 0;
    for (int tries = 0; next < (uint64_t)N && tries < 1000; tries++) {
        vibid_drv_status st = vibid_source_read(s, r, 64, &n, 100, &err);
        assert_true(st == VIBID_DRV_OK || st == VIBID_DRV_E_AGAIN);
        for (size_t i = 0; i < n; i++) {
            if (r[i].kind == VIBID_REC_FAULT) {
                if (getenv("VERBOSE")) print_message("fault: %s\n", r[i].text);
                faults++;
                continue;
            }
            if (r[i].kind == VIBID_REC_GAP) {
                if (!(r[i].index == 150 && r[i].count == 1 && next == 150))
                    fail_msg("gap %llu+%llu at %llu: %s", (unsigned long long)r[i].index, (unsigned long long)r[i].count, (unsigned long long)next, r[i].text);
                gaps++;
                next++;
                continue;
            }
            assert_int_equal(r[i].index, next);
            double k = (double)next;
            if (fabs(r[i].values[0] - 0.01 * (k - 100)) > 0.005 || r[i].values[1] != k * 0.5 || r[i].values[2] != -k)
                fail_msg("sample %llu: %g %g %g", (unsigned long long)next, r[i].values[0], r[i].values[1],
                         r[i].values[2]);
            /* a kernel stamp or the receive time: within the sending window (+ reading) */
            assert_true(r[i].t_ns >= t_before && r[i].t_ns <= real_now());
            next++;
        }
    }
    (void)t_after;
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    print_message("socketpair: %llu frames, %llu recvmmsg batches, %llu samples, %llu sw / %llu hw stamps\n",
                  (unsigned long long)st.frames, (unsigned long long)st.batches, (unsigned long long)st.samples,
                  (unsigned long long)st.sw_timestamps, (unsigned long long)st.hw_timestamps);
    assert_int_equal(next, N);
    assert_int_equal(st.samples, N - 1);
    assert_int_equal(gaps, 1);
    assert_int_equal(faults, 3); /* bus error, unknown id, bad datagram */
    assert_int_equal(st.error_frames, 1);
    assert_int_equal(st.bus_off, 1);
    assert_int_equal(st.unknown_ids, 1);
    assert_int_equal(st.frames, 2 * (N - 1) + 3);
    assert_true(st.batches < st.frames / 4); /* 32 per call when the queue is full */
    vibid_source_close(s);
    close(sv[0]);
    vibid_dbc_destroy(dbc);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_real_can_open_fails_clearly),
        cmocka_unit_test(test_parse_cmsgs),
        cmocka_unit_test(test_socketpair_path),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
