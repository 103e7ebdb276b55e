/* One SocketCAN datagram + cmsgs -> vibid_can_frame; see socketcan_rx.h. */
#include "socketcan_rx.h"

#include <linux/can.h>
#include <linux/errqueue.h>
#include <stdio.h>
#include <string.h>
#include <time.h>

static int64_t ts_ns(const struct timespec *t) { return (int64_t)t->tv_sec * 1000000000 + t->tv_nsec; }

int socketcan_parse_msg(const struct msghdr *mh, size_t len, const char *iface, int64_t fallback_ns,
                        vibid_can_frame *f, socketcan_meta *meta, char *why, size_t why_cap)
{
    memset(meta, 0, sizeof *meta);
    memset(f, 0, sizeof *f);
    f->t_ns = fallback_ns;
    snprintf(f->iface, sizeof f->iface, "%s", iface ? iface : "");
    /* Control messages first: a drop counter is valid even if the frame is not. */
    int64_t sw = 0, hw = 0;
    for (struct cmsghdr *c = CMSG_FIRSTHDR((struct msghdr *)mh); c; c = CMSG_NXTHDR((struct msghdr *)mh, c)) {
        if (c->cmsg_level != SOL_SOCKET)
            continue;
        if (c->cmsg_type == SO_TIMESTAMPING && c->cmsg_len >= CMSG_LEN(sizeof(struct scm_timestamping))) {
            struct scm_timestamping st;
            memcpy(&st, CMSG_DATA(c), sizeof st);
            sw = ts_ns(&st.ts[0]); /* ts[1] is deprecated; ts[2] is the raw hardware stamp */
            hw = ts_ns(&st.ts[2]);
        } else if (c->cmsg_type == SO_TIMESTAMPNS && c->cmsg_len >= CMSG_LEN(sizeof(struct timespec))) {
            struct timespec t;
            memcpy(&t, CMSG_DATA(c), sizeof t);
            sw = ts_ns(&t);
        } else if (c->cmsg_type == SO_RXQ_OVFL && c->cmsg_len >= CMSG_LEN(sizeof(uint32_t))) {
            memcpy(&meta->drops, CMSG_DATA(c), sizeof meta->drops);
            meta->have_drops = true;
        }
    }
    if (hw > 0) {
        f->t_ns = hw;
        meta->hw_stamp = true;
    } else if (sw > 0) {
        f->t_ns = sw;
        meta->sw_stamp = true;
    }
    if (mh->msg_flags & MSG_TRUNC) {
        snprintf(why, why_cap, "%s: datagram longer than a CAN FD frame (truncated)", f->iface);
        return -1;
    }
    if (len != CAN_MTU && len != CANFD_MTU) {
        snprintf(why, why_cap, "%s: datagram of %zu bytes is neither can_frame (%zu) nor canfd_frame (%zu)",
                 f->iface, len, (size_t)CAN_MTU, (size_t)CANFD_MTU);
        return -1;
    }
    struct canfd_frame fr;
    memset(&fr, 0, sizeof fr);
    memcpy(&fr, mh->msg_iov[0].iov_base, len);
    canid_t id = fr.can_id;
    if (id & CAN_EFF_FLAG)
        f->flags |= VIBID_CAN_F_EXT;
    if (id & CAN_RTR_FLAG)
        f->flags |= VIBID_CAN_F_RTR;
    if (id & CAN_ERR_FLAG) {
        f->flags |= VIBID_CAN_F_ERR;
        f->id = id & CAN_ERR_MASK;
    } else {
        f->id = id & ((id & CAN_EFF_FLAG) ? CAN_EFF_MASK : CAN_SFF_MASK);
    }
    if (len == CANFD_MTU) {
        if (fr.len > CANFD_MAX_DLEN) {
            snprintf(why, why_cap, "%s: CAN FD frame 0x%X with length %u > 64", f->iface, (unsigned)f->id, fr.len);
            return -1;
        }
        f->flags |= VIBID_CAN_F_FD;
        f->fd_flags = fr.flags & 0x0F;
        f->len = fr.len;
    } else {
        /* can_frame.can_dlc (len) may be 9..15 for raw DLC values with len8_dlc:
         * the payload is still 8 bytes. */
        f->len = fr.len > CAN_MAX_DLEN ? CAN_MAX_DLEN : fr.len;
    }
    if (!(f->flags & VIBID_CAN_F_RTR))
        memcpy(f->data, fr.data, f->len);
    return 0;
}
