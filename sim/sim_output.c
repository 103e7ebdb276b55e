/* sim/sim_output.c: see sim_output.h. */
#include "sim_output.h"

#include <errno.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <vibid_drivers/num_format.h>

int sim_csv_open(sim_csv *c, const char *path, const vibid_stand *stand, char *err, size_t errlen)
{
    memset(c, 0, sizeof *c);
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
    snprintf(c->path, sizeof c->path, "%s", path);
    c->f = fopen(path, "w");
    if (!c->f) {
        snprintf(err, errlen, "--csv %s: cannot create: %s", path, strerror(errno));
        return -1;
    }
    /* 1 MiB of stdio buffer: a 10-DOF row is about 400 bytes, so a write(2) per ~2600 rows */
    setvbuf(c->f, NULL, _IOFBF, 1 << 20);
    fprintf(c->f, "t");
    for (size_t i = 0; i < c->n; i++) fprintf(c->f, ",%s", vibid_stand_channel_name(stand, c->order[i]));
    fprintf(c->f, "\n");
    return 0;
}

int sim_csv_write(sim_csv *c, double t, const double *values)
{
    /* One row as text, then one buffered write: every value in its shortest round-trip form
     * (num_format.h; printf's %.17g was the bottleneck of the CSV output). */
    char row[(64 + 1) * VIBID_NUM_FORMAT_MAX + 1];
    size_t len = vibid_num_format(row, t);
    for (size_t i = 0; i < c->n; i++) {
        row[len++] = ',';
        len += vibid_num_format(row + len, values[c->order[i]]);
    }
    row[len++] = '\n';
    return fwrite(row, 1, len, c->f) == len ? 0 : -1;
}

int sim_csv_close(sim_csv *c, char *err, size_t errlen)
{
    if (!c->f) return 0;
    int bad = ferror(c->f);
    if (fclose(c->f) != 0) bad = 1;
    c->f = NULL;
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
