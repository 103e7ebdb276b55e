/* SocketCAN source: CAN_RAW + FD, filters, error frames, timestamps, drop counter,
 * recvmmsg batching; see source_socketcan.h. */
#include <vibid_drivers/source_socketcan.h>

#include <errno.h>
#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <linux/net_tstamp.h>
#include <linux/sockios.h>
#include <net/if.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <vibid_drivers/can_assembler.h>

#include "rec_queue.h"
#include "socketcan_rx.h"
#include "source_util.h"

#define MAX_BATCH 256
#define CTRL_LEN 256 /* room for SO_TIMESTAMPING (48 bytes) + SO_RXQ_OVFL + padding */

typedef struct socketcan {
    vibid_source_socketcan_config cfg;
    char iface[IFNAMSIZ];
    int fd;
    vibid_can_assembler *as;
    vibid_socketcan_info info;
    /* recvmmsg buffers, allocated at open */
    struct mmsghdr *msgs;
    struct iovec *iov;
    struct canfd_frame *frames;
    unsigned char *ctrl;
    uint32_t last_drops;
    bool have_drops;
    rec_queue q;
    vibid_source_stats st;
    int64_t last_sample_t;
    uint64_t bad_datagrams;
} socketcan;

static vibid_drv_status sys_fail(vibid_drv_error *err, const char *iface, const char *what)
{
    return vibid_drv_fail(err, VIBID_DRV_E_IO, "SocketCAN %s: %s: %s", iface, what, strerror(errno));
}

static vibid_drv_status setup_can_socket(socketcan *s, vibid_drv_error *err)
{
    s->fd = socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
    if (s->fd < 0) {
        if (errno == EAFNOSUPPORT || errno == EPROTONOSUPPORT)
            return vibid_drv_fail(err, VIBID_DRV_E_UNSUPPORTED,
                                  "SocketCAN %s: socket(PF_CAN, SOCK_RAW, CAN_RAW) failed: %s: this kernel has "
                                  "no SocketCAN support (needs the can and can-raw modules: modprobe can-raw)",
                                  s->iface, strerror(errno));
        return sys_fail(err, s->iface, "socket(PF_CAN, SOCK_RAW, CAN_RAW)");
    }
    unsigned ifindex = if_nametoindex(s->iface);
    if (ifindex == 0)
        return vibid_drv_fail(err, VIBID_DRV_E_NOT_FOUND, "SocketCAN: no interface '%s' (%s)", s->iface,
                              strerror(errno));
    int on = 1;
    s->info.fd_frames = setsockopt(s->fd, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on) == 0;
    if (!s->info.fd_frames && errno != ENOPROTOOPT)
        return sys_fail(err, s->iface, "setsockopt(CAN_RAW_FD_FRAMES)");
    if (!s->cfg.accept_all_ids) {
        uint32_t ids[64];
        size_t n = vibid_can_assembler_ids(s->as, ids, 64);
        if (n > 64)
            return vibid_drv_fail(err, VIBID_DRV_E_RANGE, "SocketCAN %s: %zu messages, at most 64 filters", s->iface, n);
        struct can_filter flt[64];
        for (size_t i = 0; i < n; i++) {
            if (ids[i] & 0x80000000u) {
                flt[i].can_id = (ids[i] & CAN_EFF_MASK) | CAN_EFF_FLAG;
                flt[i].can_mask = CAN_EFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG;
            } else {
                flt[i].can_id = ids[i] & CAN_SFF_MASK;
                flt[i].can_mask = CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG;
            }
        }
        if (setsockopt(s->fd, SOL_CAN_RAW, CAN_RAW_FILTER, flt, (socklen_t)(n * sizeof flt[0])) != 0)
            return sys_fail(err, s->iface, "setsockopt(CAN_RAW_FILTER)");
        s->info.n_filters = (unsigned)n;
    }
    can_err_mask_t em = s->info.err_mask;
    if (setsockopt(s->fd, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &em, sizeof em) != 0)
        return sys_fail(err, s->iface, "setsockopt(CAN_RAW_ERR_FILTER)");
    if (s->cfg.hw_timestamps) {
        struct hwtstamp_config hc = {.flags = 0, .tx_type = HWTSTAMP_TX_OFF, .rx_filter = HWTSTAMP_FILTER_ALL};
        struct ifreq ifr;
        memset(&ifr, 0, sizeof ifr);
        snprintf(ifr.ifr_name, sizeof ifr.ifr_name, "%s", s->iface);
        ifr.ifr_data = (char *)&hc;
        /* Fails with EPERM without CAP_NET_ADMIN, EOPNOTSUPP/EINVAL without hardware
         * support: software stamps are used then (info.hw_timestamps = false). */
        s->info.hw_timestamps = ioctl(s->fd, SIOCSHWTSTAMP, &ifr) == 0 && hc.rx_filter != HWTSTAMP_FILTER_NONE;
    }
    if (bind(s->fd, (struct sockaddr *)&(struct sockaddr_can){.can_family = AF_CAN, .can_ifindex = (int)ifindex},
             sizeof(struct sockaddr_can)) != 0)
        return sys_fail(err, s->iface, "bind");
    return VIBID_DRV_OK;
}

/* Options that also work on the test's AF_UNIX socket. */
static vibid_drv_status setup_common(socketcan *s, vibid_drv_error *err)
{
    int on = 1;
    int tsflags = SOF_TIMESTAMPING_RX_SOFTWARE | SOF_TIMESTAMPING_SOFTWARE;
    if (s->info.hw_timestamps)
        tsflags |= SOF_TIMESTAMPING_RX_HARDWARE | SOF_TIMESTAMPING_RAW_HARDWARE;
    s->info.so_timestamping = setsockopt(s->fd, SOL_SOCKET, SO_TIMESTAMPING, &tsflags, sizeof tsflags) == 0;
    if (!s->info.so_timestamping)
        (void)setsockopt(s->fd, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on); /* receive time then */
    s->info.rxq_ovfl = setsockopt(s->fd, SOL_SOCKET, SO_RXQ_OVFL, &on, sizeof on) == 0;
    if (s->cfg.rcvbuf_bytes > 0) {
        int b = s->cfg.rcvbuf_bytes;
        if (setsockopt(s->fd, SOL_SOCKET, SO_RCVBUFFORCE, &b, sizeof b) != 0 &&
            setsockopt(s->fd, SOL_SOCKET, SO_RCVBUF, &b, sizeof b) != 0)
            return sys_fail(err, s->iface, "setsockopt(SO_RCVBUF)");
    }
    socklen_t sl = sizeof s->info.rcvbuf_bytes;
    if (getsockopt(s->fd, SOL_SOCKET, SO_RCVBUF, &s->info.rcvbuf_bytes, &sl) != 0)
        return sys_fail(err, s->iface, "getsockopt(SO_RCVBUF)");
    return VIBID_DRV_OK;
}

static vibid_drv_status sc_open(vibid_source *src, const void *config, vibid_drv_error *err)
{
    const vibid_source_socketcan_config *cfg = config;
    socketcan *s = calloc(1, sizeof *s);
    if (!s) {
        if (cfg->use_fd)
            close(cfg->fd);
        return vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "SocketCAN: out of memory");
    }
    src->impl = s;
    s->fd = cfg->use_fd ? cfg->fd : -1;
    s->cfg = *cfg;
    if (!cfg->iface || !cfg->iface[0] || strlen(cfg->iface) >= IFNAMSIZ)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "SocketCAN: interface name '%s' empty or longer than %d",
                              cfg->iface ? cfg->iface : "", IFNAMSIZ - 1);
    snprintf(s->iface, sizeof s->iface, "%s", cfg->iface);
    s->cfg.iface = s->iface;
    if (!cfg->dbc)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "SocketCAN %s: a DBC is required", s->iface);
    if (cfg->batch > MAX_BATCH || cfg->rcvbuf_bytes < 0)
        return vibid_drv_fail(err, VIBID_DRV_E_RANGE, "SocketCAN %s: batch %u (1..%d) or rcvbuf %d invalid", s->iface,
                              cfg->batch, MAX_BATCH, cfg->rcvbuf_bytes);
    s->info.batch = cfg->batch ? cfg->batch : 64;
    s->info.err_mask = cfg->err_mask ? (cfg->err_mask & CAN_ERR_MASK) : VIBID_SOCKETCAN_DEFAULT_ERR_MASK;
    src->chanmap = cfg->chanmap;
    s->as = vibid_can_assembler_create(cfg->dbc, &src->chanmap, err);
    if (!s->as)
        return err ? err->status : VIBID_DRV_E_ARG;
    if (!vibid_can_assembler_set_timing(s->as, cfg->sample_period_s, 0))
        return vibid_drv_fail(err, VIBID_DRV_E_RANGE, "SocketCAN %s: sample period %g s invalid", s->iface,
                              cfg->sample_period_s);
    unsigned b = s->info.batch;
    s->msgs = calloc(b, sizeof *s->msgs);
    s->iov = calloc(b, sizeof *s->iov);
    s->frames = calloc(b, sizeof *s->frames);
    s->ctrl = calloc(b, CTRL_LEN);
    /* per frame: at most 3 assembler records + 1 drop or bad-datagram fault */
    if (!s->msgs || !s->iov || !s->frames || !s->ctrl || !rec_queue_init(&s->q, 4 * (size_t)b + 16))
        return vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "SocketCAN %s: out of memory", s->iface);
    if (!cfg->use_fd) {
        vibid_drv_status st = setup_can_socket(s, err);
        if (st != VIBID_DRV_OK)
            return st;
    }
    return setup_common(s, err);
}

static void drain_assembler(socketcan *s)
{
    vibid_record rec;
    while (rec_queue_space(&s->q) > 0 && vibid_can_assembler_pop(s->as, &rec))
        rec_queue_push_copy(&s->q, &rec);
}

/* One recvmmsg batch into the queue. OK, E_AGAIN (nothing), or fatal. */
static vibid_drv_status receive_batch(socketcan *s, vibid_drv_error *err)
{
    unsigned b = s->info.batch;
    for (unsigned i = 0; i < b; i++) {
        s->iov[i].iov_base = &s->frames[i];
        s->iov[i].iov_len = sizeof s->frames[i];
        struct msghdr *mh = &s->msgs[i].msg_hdr;
        memset(mh, 0, sizeof *mh);
        mh->msg_iov = &s->iov[i];
        mh->msg_iovlen = 1;
        mh->msg_control = s->ctrl + (size_t)i * CTRL_LEN;
        mh->msg_controllen = CTRL_LEN;
    }
    int n = recvmmsg(s->fd, s->msgs, b, MSG_DONTWAIT, NULL);
    if (n < 0) {
        if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)
            return VIBID_DRV_E_AGAIN;
        if (errno == ENETDOWN) {
            /* The interface went down (ip link set down, bus-off with restart-ms 0):
             * reported, and we keep listening for it to come back. */
            s->st.link_losses++;
            rec_queue_fault(&s->q, VIBID_FAULT_LINK, 0, 0, "SocketCAN %s: interface is down", s->iface);
            return VIBID_DRV_OK;
        }
        return sys_fail(err, s->iface, "recvmmsg");
    }
    if (n == 0)
        return VIBID_DRV_E_AGAIN;
    s->st.batches++;
    int64_t now = real_ns();
    for (int i = 0; i < n; i++) {
        vibid_can_frame f;
        socketcan_meta m;
        char why[128];
        int rc = socketcan_parse_msg(&s->msgs[i].msg_hdr, s->msgs[i].msg_len, s->iface, now, &f, &m, why, sizeof why);
        if (m.have_drops) {
            uint32_t delta = m.drops - (s->have_drops ? s->last_drops : 0); /* wraps mod 2^32 */
            s->last_drops = m.drops;
            s->have_drops = true;
            if (delta) {
                char where[48];
                snprintf(where, sizeof where, "SO_RXQ_OVFL on %s", s->iface);
                vibid_can_assembler_note_drops(s->as, delta, where);
            }
        }
        if (rc != 0) {
            s->bad_datagrams++;
            drain_assembler(s);
            rec_queue_fault(&s->q, VIBID_FAULT_SHORT_FRAME, 0, 0, "%s", why);
            continue;
        }
        if (m.hw_stamp)
            s->st.hw_timestamps++;
        else if (m.sw_stamp)
            s->st.sw_timestamps++;
        vibid_can_assembler_push(s->as, &f);
        drain_assembler(s);
    }
    return VIBID_DRV_OK;
}

static vibid_drv_status sc_read(vibid_source *src, vibid_record *recs, size_t cap, size_t *n, int timeout_ms,
                                vibid_drv_error *err)
{
    socketcan *s = src->impl;
    int64_t limit = wait_limit(timeout_ms);
    size_t k = 0;
    for (;;) {
        k += rec_queue_hand_out(&s->q, recs + k, cap - k, &s->st, &s->last_sample_t);
        if (k > 0 || rec_queue_peek(&s->q)) {
            *n = k;
            return VIBID_DRV_OK;
        }
        vibid_drv_status st = receive_batch(s, err);
        if (st == VIBID_DRV_OK)
            continue;
        if (st != VIBID_DRV_E_AGAIN)
            return st;
        int64_t left = limit == INT64_MAX ? -1 : limit - mono_ns();
        if (left == 0 || (left < 0 && limit != INT64_MAX)) {
            *n = 0;
            return VIBID_DRV_E_AGAIN;
        }
        struct pollfd p = {.fd = s->fd, .events = POLLIN};
        int ms = left < 0 ? -1 : (int)((left + 999999) / 1000000);
        int pr = poll(&p, 1, ms);
        if (pr < 0 && errno != EINTR)
            return sys_fail(err, s->iface, "poll");
        if (pr == 0 && limit != INT64_MAX && mono_ns() >= limit) {
            *n = 0;
            return VIBID_DRV_E_AGAIN;
        }
        if (pr > 0 && (p.revents & (POLLERR | POLLHUP | POLLNVAL)) && !(p.revents & POLLIN)) {
            if (p.revents & POLLHUP) {
                *n = 0;
                return vibid_drv_fail(err, VIBID_DRV_E_LINK, "SocketCAN %s: socket hung up", s->iface);
            }
            return vibid_drv_fail(err, VIBID_DRV_E_IO, "SocketCAN %s: socket error (poll revents 0x%x)", s->iface,
                                  (unsigned)p.revents);
        }
    }
}

static void sc_close(vibid_source *src)
{
    socketcan *s = src->impl;
    if (!s)
        return;
    if (s->fd >= 0)
        close(s->fd);
    vibid_can_assembler_destroy(s->as);
    free(s->msgs);
    free(s->iov);
    free(s->frames);
    free(s->ctrl);
    rec_queue_free(&s->q);
    free(s);
    src->impl = NULL;
}

static void sc_stats(const vibid_source *src, vibid_source_stats *st)
{
    const socketcan *s = src->impl;
    *st = s->st;
    vibid_can_assembler_stats as;
    vibid_can_assembler_stats_get(s->as, &as);
    st->frames = as.frames + s->bad_datagrams;
    st->error_frames = as.error_frames;
    st->bus_off = as.bus_off;
    st->ctrl_overflow = as.ctrl_overflow;
    st->restarts = as.restarts;
    st->dropped = as.dropped;
    st->unknown_ids = as.unknown_ids;
    st->short_frames = as.short_frames + s->bad_datagrams;
    st->nonfinite = as.nonfinite;
    st->duplicates = as.duplicates;
    st->late = as.late;
}

const vibid_source_ops vibid_source_socketcan_ops = {"socketcan", sc_open, sc_read, sc_close, sc_stats};

vibid_drv_status vibid_source_socketcan_info(const vibid_source *src, vibid_socketcan_info *info)
{
    if (!src || src->ops != &vibid_source_socketcan_ops || !info || !src->impl)
        return VIBID_DRV_E_ARG;
    *info = ((const socketcan *)src->impl)->info;
    return VIBID_DRV_OK;
}
