/* candump .log writer: byte-for-byte the format of `candump -l` (can-utils candump.c
 * log output with lib.c's sprint_canframe, no separators), so that canplayer, log2asc
 * and python-can read what we record. */
#include <vibid_drivers/candump.h>

#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

struct vibid_candump_writer {
    FILE *fp;
    char path[256];
    vibid_drv_status first_error;
};

static const char hexdig[] = "0123456789ABCDEF";

int vibid_candump_format(char *buf, size_t cap, const vibid_can_frame *f, const char *iface)
{
    if (!buf || !f || f->t_ns < 0)
        return -1;
    if (!iface)
        iface = f->iface;
    size_t maxlen = (f->flags & VIBID_CAN_F_FD) ? VIBID_CANFD_MAX_DLEN : VIBID_CAN_MAX_DLEN;
    if (f->len > maxlen || !iface[0] || strlen(iface) >= VIBID_CAN_IFNAMSIZ || cap < 256)
        return -1;
    unsigned long long sec = (unsigned long long)(f->t_ns / 1000000000);
    unsigned long long usec = (unsigned long long)(f->t_ns % 1000000000) / 1000u;
    int n = snprintf(buf, cap, "(%010llu.%06llu) %s ", sec, usec, iface);
    if (n < 0)
        return -1;
    size_t o = (size_t)n;
    if (f->flags & VIBID_CAN_F_ERR)
        o += (size_t)snprintf(buf + o, cap - o, "%08X#", (unsigned)((f->id & 0x1FFFFFFFu) | 0x20000000u));
    else if (f->flags & VIBID_CAN_F_EXT)
        o += (size_t)snprintf(buf + o, cap - o, "%08X#", (unsigned)(f->id & 0x1FFFFFFFu));
    else
        o += (size_t)snprintf(buf + o, cap - o, "%03X#", (unsigned)(f->id & 0x7FFu));
    if ((f->flags & VIBID_CAN_F_RTR) && !(f->flags & VIBID_CAN_F_FD)) {
        buf[o++] = 'R';
        if (f->len > 0 && f->len <= 8)
            buf[o++] = (char)('0' + f->len);
        buf[o] = '\0';
        return (int)o;
    }
    if (f->flags & VIBID_CAN_F_FD) {
        buf[o++] = '#';
        buf[o++] = hexdig[f->fd_flags & 0xF];
    }
    for (unsigned i = 0; i < f->len; i++) {
        buf[o++] = hexdig[f->data[i] >> 4];
        buf[o++] = hexdig[f->data[i] & 0xF];
    }
    buf[o] = '\0';
    return (int)o;
}

vibid_candump_writer *vibid_candump_writer_open(const char *path, bool append, vibid_drv_error *err)
{
    if (!path) {
        vibid_drv_fail(err, VIBID_DRV_E_ARG, "vibid_candump_writer_open: path is NULL");
        return NULL;
    }
    vibid_candump_writer *w = calloc(1, sizeof *w);
    if (!w) {
        vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "%s: out of memory", path);
        return NULL;
    }
    w->fp = fopen(path, append ? "ab" : "wb");
    if (!w->fp) {
        vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: cannot open for writing: %s", path, strerror(errno));
        free(w);
        return NULL;
    }
    snprintf(w->path, sizeof w->path, "%s", path);
    return w;
}

static vibid_drv_status put_line(vibid_candump_writer *w, const char *buf, size_t n,
                                 vibid_drv_error *err)
{
    if (fwrite(buf, 1, n, w->fp) != n || putc('\n', w->fp) == EOF) {
        if (!w->first_error)
            w->first_error = VIBID_DRV_E_IO;
        return vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: write failed: %s", w->path, strerror(errno));
    }
    return VIBID_DRV_OK;
}

vibid_drv_status vibid_candump_writer_write(vibid_candump_writer *w, const vibid_can_frame *frame,
                                            const char *iface, vibid_drv_error *err)
{
    if (!w || !frame)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "vibid_candump_writer_write: NULL argument");
    char buf[256];
    int n = vibid_candump_format(buf, sizeof buf, frame, iface);
    if (n < 0)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG,
                              "%s: frame cannot be logged (negative time, length %u, or interface name empty or too long)",
                              w->path, frame->len);
    return put_line(w, buf, (size_t)n, err);
}

vibid_drv_status vibid_candump_writer_dropcount(vibid_candump_writer *w, uint32_t dropped,
                                                uint32_t total, const char *iface,
                                                vibid_drv_error *err)
{
    if (!w || !iface)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "vibid_candump_writer_dropcount: NULL argument");
    char buf[256];
    int n = snprintf(buf, sizeof buf, "DROPCOUNT: dropped %u CAN frame%s on '%.15s' socket (total drops %u)",
                     (unsigned)dropped, dropped > 1 ? "s" : "", iface, (unsigned)total);
    return put_line(w, buf, (size_t)n, err);
}

vibid_drv_status vibid_candump_writer_flush(vibid_candump_writer *w, bool sync, vibid_drv_error *err)
{
    if (!w)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "vibid_candump_writer_flush: NULL writer");
    if (fflush(w->fp) != 0 || (sync && fdatasync(fileno(w->fp)) != 0)) {
        if (!w->first_error)
            w->first_error = VIBID_DRV_E_IO;
        return vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: flush failed: %s", w->path, strerror(errno));
    }
    return VIBID_DRV_OK;
}

vibid_drv_status vibid_candump_writer_close(vibid_candump_writer *w, vibid_drv_error *err)
{
    if (!w)
        return VIBID_DRV_OK;
    vibid_drv_status st = w->first_error;
    if (fclose(w->fp) != 0 && st == VIBID_DRV_OK)
        st = vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: close failed: %s", w->path, strerror(errno));
    else if (st != VIBID_DRV_OK)
        vibid_drv_fail(err, st, "%s: an earlier write failed", w->path);
    free(w);
    return st;
}
