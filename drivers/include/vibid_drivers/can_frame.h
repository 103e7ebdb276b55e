/* vibid_drivers/can_frame.h: one received or replayed CAN / CAN FD frame, independent
 * of <linux/can.h> so that replay and decoding build and run on any host.
 */
#ifndef VIBID_DRIVERS_CAN_FRAME_H
#define VIBID_DRIVERS_CAN_FRAME_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define VIBID_CAN_MAX_DLEN 8     /* classic CAN payload bytes */
#define VIBID_CANFD_MAX_DLEN 64  /* CAN FD payload bytes */
#define VIBID_CAN_IFNAMSIZ 16    /* interface name incl. NUL, as IFNAMSIZ */

/* vibid_can_frame.flags */
enum {
    VIBID_CAN_F_EXT = 1u << 0, /* 29-bit identifier */
    VIBID_CAN_F_RTR = 1u << 1, /* remote request (classic only; no payload) */
    VIBID_CAN_F_ERR = 1u << 2, /* error frame: id holds the CAN_ERR_* class bits */
    VIBID_CAN_F_FD = 1u << 3,  /* CAN FD frame; fd_flags is meaningful */
    VIBID_CAN_F_TX = 1u << 4   /* frame sent by this host (candump " T"), else received */
};

/* CAN FD flag nibble as candump writes it after "##" (CANFD_BRS/ESI/FDF). Kept raw
 * (0..15) so that a replayed log can be written back unchanged. */
enum { VIBID_CANFD_BRS = 0x1, VIBID_CANFD_ESI = 0x2, VIBID_CANFD_FDF = 0x4 };

typedef struct vibid_can_frame {
    int64_t t_ns;    /* timestamp, ns since the Unix epoch (receive or log time) */
    uint32_t id;     /* 0..0x7FF, or 0..0x1FFFFFFF with VIBID_CAN_F_EXT; error class
                        bits (CAN_ERR_MASK part) for VIBID_CAN_F_ERR frames */
    uint8_t flags;   /* VIBID_CAN_F_* */
    uint8_t fd_flags;/* 0..15, only with VIBID_CAN_F_FD */
    uint8_t len;     /* payload bytes: 0..8 classic, 0..64 FD; RTR: requested length */
    uint8_t data[VIBID_CANFD_MAX_DLEN];
    char iface[VIBID_CAN_IFNAMSIZ]; /* interface name, NUL-terminated; may be "" */
} vibid_can_frame;

#ifdef __cplusplus
}
#endif
#endif
