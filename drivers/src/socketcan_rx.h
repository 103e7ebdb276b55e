/* Internal: turning one received SocketCAN datagram (can_frame or canfd_frame bytes plus
 * its control messages) into a vibid_can_frame. Separate from the socket code so that
 * tests can feed hand-built messages and cmsgs (the build host has no CAN). */
#ifndef VIBID_DRIVERS_SOCKETCAN_RX_H
#define VIBID_DRIVERS_SOCKETCAN_RX_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <sys/socket.h>

#include <vibid_drivers/can_frame.h>

typedef struct socketcan_meta {
    bool hw_stamp;     /* t_ns came from the interface's hardware stamp */
    bool sw_stamp;     /* t_ns came from the kernel's software receive stamp */
    bool have_drops;   /* drops holds the socket's SO_RXQ_OVFL counter */
    uint32_t drops;    /* cumulative frames the kernel dropped on this socket */
} socketcan_meta;

/* mh: the received message (msg_iov[0] holds the frame bytes), len: bytes received.
 * fallback_ns: receive time to use without a kernel stamp. Returns 0 and fills *f and
 * *meta; -1 when the datagram is not a CAN frame (why says what). */
int socketcan_parse_msg(const struct msghdr *mh, size_t len, const char *iface, int64_t fallback_ns,
                        vibid_can_frame *f, socketcan_meta *meta, char *why, size_t why_cap);

#endif
