/* sim/sim_output.c: see sim_output.h. */
#include "sim_output.h"

#include <errno.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <vibid_drivers/num_format.h>

/* Formats rows rows of batch b and writes them, 64 KiB of text at a time (writer thread).
 * 0, or -1 on a write error. */
static int csv_format_batch(sim_csv *c, const double *b, size_t rows)
{
    const size_t stride = 1 + c->n, row_max = stride * (VIBID_NUM_FORMAT_MAX + 1) + 1;
    char text[65536 + (SIM_MAX_OUTPUTS + 1) * (VIBID_NUM_FORMAT_MAX + 1) + 1];
    size_t len = 0;
    for (size_t r = 0; r < rows; r++) {
        const double *v = b + r * stride;
        len += vibid_num_format(text + len, v[0]);
        for (size_t i = 1; i < stride; i++) {
            text[len++] = ',';
            len += vibid_num_format(text + len, v[i]);
        }
        text[len++] = '\n';
        if (len + row_max > sizeof text || r + 1 == rows) {
            if (fwrite(text, 1, len, c->f) != len) return -1;
            len = 0;
        }
    }
    return 0;
}

static void *csv_writer(void *arg)
{
    sim_csv *c = arg;
    pthread_mutex_lock(&c->mu);
    for (;;) {
        while (c->pending < 0 && !c->stop) pthread_cond_wait(&c->cv, &c->mu);
        if (c->pending < 0) break; /* stopped, nothing left */
        const int b = c->pending;
        const size_t rows = c->pending_rows;
        const int failed = c->failed;
        pthread_mutex_unlock(&c->mu);
        const int bad = failed ? 0 : csv_format_batch(c, c->batch[b], rows); /* after a failure: dropped, counted by the caller */
        pthread_mutex_lock(&c->mu);
        if (bad) c->failed = 1;
        c->pending = -1;
        pthread_cond_broadcast(&c->cv);
    }
    pthread_mutex_unlock(&c->mu);
    return NULL;
}

/* Hands batch cur (fill rows) to the writer, waiting while it writes the previous one. */
static int csv_hand_over(sim_csv *c)
{
    pthread_mutex_lock(&c->mu);
    while (c->pending >= 0) pthread_cond_wait(&c->cv, &c->mu);
    c->pending = c->cur;
    c->pending_rows = c->fill;
    const int failed = c->failed;
    pthread_cond_broadcast(&c->cv);
    pthread_mutex_unlock(&c->mu);
    c->cur ^= 1;
    c->fill = 0;
    if (failed) c->failed_seen = 1;
    return failed ? -1 : 0;
}

int sim_csv_open(sim_csv *c, const char *path, const vibid_stand *stand, char *err, size_t errlen)
{
    return sim_csv_open_cfg(c, path, stand, NULL, err, errlen);
}

int sim_csv_open_cfg(sim_csv *c, const char *path, const vibid_stand *stand, const sim_config *cfg, char *err,
                     size_t errlen)
{
    memset(c, 0, sizeof *c);
    c->pending = -1;
    const vibid_model *m = vibid_stand_model(stand);
    vibid_model_dims d;
    vibid_model_get_dims(m, &d);
    if (d.n_channels > 64) {
        snprintf(err, errlen, "--csv %s: %zu channels, at most 64", path, d.n_channels);
        return -1;
    }
    for (int pass = 0; pass < 2; pass++)
        for (size_t i = 0; i < d.n_channels; i++) {
            vibid_channel_info ci;
            vibid_model_channel_info(m, i, &ci);
            int input = ci.kind == VIBID_CHANNEL_INPUT || ci.index == VIBID_BASE;
            if (input == (pass == 0)) c->order[c->n++] = i;
        }
    size_t n_cov = cfg ? cfg->n_covariates : 0;
    for (size_t j = 0; j < n_cov; j++) c->order[c->n++] = d.n_channels + j;
    snprintf(c->path, sizeof c->path, "%s", path);
    for (int b = 0; b < 2; b++)
        if (!(c->batch[b] = malloc(SIM_CSV_BATCH * (1 + c->n) * sizeof(double)))) {
            snprintf(err, errlen, "--csv %s: out of memory for the write batches", path);
            free(c->batch[0]);
            return -1;
        }
    c->f = fopen(path, "w");
    if (!c->f) {
        snprintf(err, errlen, "--csv %s: cannot create: %s", path, strerror(errno));
        free(c->batch[0]);
        free(c->batch[1]);
        return -1;
    }
    /* 1 MiB of stdio buffer: a 10-DOF row is about 400 bytes, so a write(2) per ~2600 rows */
    setvbuf(c->f, NULL, _IOFBF, 1 << 20);
    fprintf(c->f, "t");
    for (size_t i = 0; i < c->n; i++)
        fprintf(c->f, ",%s", c->order[i] < d.n_channels ? vibid_stand_channel_name(stand, c->order[i])
                                                        : cfg->covariates[c->order[i] - d.n_channels].name);
    fprintf(c->f, "\n");
    pthread_mutex_init(&c->mu, NULL);
    pthread_cond_init(&c->cv, NULL);
    int rc = pthread_create(&c->thread, NULL, csv_writer, c);
    if (rc != 0) {
        snprintf(err, errlen, "--csv %s: cannot start the writer thread: %s", path, strerror(rc));
        fclose(c->f);
        c->f = NULL;
        free(c->batch[0]);
        free(c->batch[1]);
        return -1;
    }
    c->started = 1;
    return 0;
}

int sim_csv_write(sim_csv *c, double t, const double *values)
{
    double *row = c->batch[c->cur] + c->fill * (1 + c->n);
    row[0] = t;
    for (size_t i = 0; i < c->n; i++) row[1 + i] = values[c->order[i]];
    if (++c->fill < SIM_CSV_BATCH) return c->failed_seen ? -1 : 0;
    return csv_hand_over(c);
}

int sim_csv_close(sim_csv *c, char *err, size_t errlen)
{
    if (!c->f) return 0;
    if (c->fill) (void)csv_hand_over(c);
    pthread_mutex_lock(&c->mu);
    c->stop = 1;
    pthread_cond_broadcast(&c->cv);
    pthread_mutex_unlock(&c->mu);
    pthread_join(c->thread, NULL);
    pthread_mutex_destroy(&c->mu);
    pthread_cond_destroy(&c->cv);
    int bad = c->failed || ferror(c->f);
    if (fclose(c->f) != 0) bad = 1;
    c->f = NULL;
    free(c->batch[0]);
    free(c->batch[1]);
    c->batch[0] = c->batch[1] = NULL;
    if (bad) {
        snprintf(err, errlen, "--csv %s: write failed (disk full?)", c->path);
        return -1;
    }
    return 0;
}

int sim_socketcan_open(sim_socketcan *s, const char *iface, int fd_frames, char *err, size_t errlen)
{
    memset(s, 0, sizeof *s);
    s->fd = -1;
    s->is_fd = fd_frames;
    snprintf(s->iface, sizeof s->iface, "%s", iface);
    if (strlen(iface) >= IFNAMSIZ) {
        snprintf(err, errlen, "--can %s: interface name longer than %d characters", iface, IFNAMSIZ - 1);
        return -1;
    }
    int fd = socket(PF_CAN, SOCK_RAW, CAN_RAW);
    if (fd < 0) {
        int e = errno;
        if (e == EAFNOSUPPORT || e == EPROTONOSUPPORT)
            snprintf(err, errlen,
                     "--can %s: socket(PF_CAN, SOCK_RAW, CAN_RAW): %s: this kernel has no SocketCAN support "
                     "(load the can and can_raw modules, e.g. modprobe can_raw vcan, or run in a VM with CAN)",
                     iface, strerror(e));
        else
            snprintf(err, errlen, "--can %s: socket(PF_CAN, SOCK_RAW, CAN_RAW): %s", iface, strerror(e));
        return -1;
    }
    struct ifreq ifr;
    memset(&ifr, 0, sizeof ifr);
    snprintf(ifr.ifr_name, sizeof ifr.ifr_name, "%s", iface);
    if (ioctl(fd, SIOCGIFINDEX, &ifr) < 0) {
        snprintf(err, errlen, "--can %s: no such CAN interface (SIOCGIFINDEX: %s); create it, e.g. ip link add dev %s type vcan && ip link set %s up",
                 iface, strerror(errno), iface, iface);
        close(fd);
        return -1;
    }
    if (fd_frames) {
        int on = 1;
        if (setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on) < 0) {
            snprintf(err, errlen, "--can %s: enabling CAN FD frames (CAN_RAW_FD_FRAMES): %s", iface, strerror(errno));
            close(fd);
            return -1;
        }
    }
    /* we only send: receive nothing */
    setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, NULL, 0);
    struct sockaddr_can addr;
    memset(&addr, 0, sizeof addr);
    addr.can_family = AF_CAN;
    addr.can_ifindex = ifr.ifr_ifindex;
    if (bind(fd, (struct sockaddr *)&addr, sizeof addr) < 0) {
        snprintf(err, errlen, "--can %s: bind: %s", iface, strerror(errno));
        close(fd);
        return -1;
    }
    if (fd_frames) {
        struct ifreq mtu;
        memset(&mtu, 0, sizeof mtu);
        snprintf(mtu.ifr_name, sizeof mtu.ifr_name, "%s", iface);
        if (ioctl(fd, SIOCGIFMTU, &mtu) == 0 && mtu.ifr_mtu != CANFD_MTU) {
            snprintf(err, errlen, "--can %s: interface is not CAN FD capable (MTU %d, need %d); e.g. ip link set %s mtu 72",
                     iface, mtu.ifr_mtu, (int)CANFD_MTU, iface);
            close(fd);
            return -1;
        }
    }
    s->fd = fd;
    return 0;
}

int sim_socketcan_send(sim_socketcan *s, const vibid_can_frame *f)
{
    ssize_t want, got;
    if (f->flags & VIBID_CAN_F_FD) {
        struct canfd_frame cf;
        memset(&cf, 0, sizeof cf);
        cf.can_id = f->id | ((f->flags & VIBID_CAN_F_EXT) ? CAN_EFF_FLAG : 0);
        cf.len = f->len;
        cf.flags = (uint8_t)(f->fd_flags & (CANFD_BRS | CANFD_ESI));
        memcpy(cf.data, f->data, f->len);
        want = (ssize_t)sizeof cf;
        got = write(s->fd, &cf, sizeof cf);
    } else {
        struct can_frame cf;
        memset(&cf, 0, sizeof cf);
        cf.can_id = f->id | ((f->flags & VIBID_CAN_F_EXT) ? CAN_EFF_FLAG : 0);
        cf.can_dlc = f->len;
        memcpy(cf.data, f->data, f->len);
        want = (ssize_t)sizeof cf;
        got = write(s->fd, &cf, sizeof cf);
    }
    if (got != want) {
        s->tx_errors++;
        s->last_errno = got < 0 ? errno : EIO;
        return -1;
    }
    s->sent++;
    return 0;
}

void sim_socketcan_close(sim_socketcan *s)
{
    if (s->fd >= 0) close(s->fd);
    s->fd = -1;
}
