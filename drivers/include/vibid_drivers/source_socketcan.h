/* vibid_drivers/source_socketcan.h: live CAN / CAN FD from a SocketCAN interface.
 *
 * Opens a CAN_RAW socket on `iface` with
 *  - CAN_RAW_FD_FRAMES (CAN FD frames arrive as 72-byte canfd_frame, classic frames as
 *    16-byte can_frame; a kernel without FD support keeps classic frames working);
 *  - CAN_RAW_FILTER: one kernel filter per DBC message the channel map uses, so other
 *    traffic never wakes us (unless accept_all_ids);
 *  - CAN_RAW_ERR_FILTER: error frames of the classes in err_mask; bus-off, controller
 *    problems (RX/TX overflow) and restarts are counted (stats) and reported as
 *    BUS_ERROR faults;
 *  - SO_TIMESTAMPING: hardware receive stamps when the interface provides them
 *    (hw_timestamps, enabled with SIOCSHWTSTAMP; needs CAP_NET_ADMIN), kernel software
 *    receive stamps otherwise; a sample's time is its first frame's stamp;
 *  - SO_RXQ_OVFL: frames the kernel dropped because our queue was full become DROPPED
 *    faults with the count (never silent);
 *  - SO_RCVBUF (SO_RCVBUFFORCE when permitted) = rcvbuf_bytes if > 0;
 *  - recvmmsg: up to `batch` frames per system call.
 * Frames become samples in the CAN sample assembler (can_assembler.h).
 *
 * On a kernel without SocketCAN, open fails with VIBID_DRV_E_UNSUPPORTED and a message
 * that says so (socket(PF_CAN) gives EAFNOSUPPORT) and how to fix it.
 */
#ifndef VIBID_DRIVERS_SOURCE_SOCKETCAN_H
#define VIBID_DRIVERS_SOURCE_SOCKETCAN_H

#include <stdbool.h>
#include <stdint.h>

#include <vibid_drivers/channel_map.h>
#include <vibid_drivers/dbc.h>
#include <vibid_drivers/source.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Default error classes (linux/can/error.h): TX_TIMEOUT | CRTL | PROT | TRX | BUSOFF |
 * RESTARTED. Left out by default: LOSTARB, ACK and BUSERROR, which flood on a bus
 * with no other node or a bad termination; add them through err_mask if wanted. */
#define VIBID_SOCKETCAN_DEFAULT_ERR_MASK 0x15Du

typedef struct vibid_source_socketcan_config {
    const char *iface;         /* interface name, e.g. "can0", "vcan0" (< 16 chars) */
    const vibid_dbc *dbc;      /* must outlive the source */
    vibid_chanmap chanmap;     /* signal channels + counter or trigger */
    int rcvbuf_bytes;          /* 0 = kernel default; else requested receive buffer */
    bool hw_timestamps;        /* try hardware receive stamps first */
    bool accept_all_ids;       /* no id filters: other ids arrive as UNKNOWN_ID faults */
    unsigned batch;            /* frames per recvmmsg, 1..256; 0 = 64 */
    uint32_t err_mask;         /* CAN_ERR_* classes; 0 = VIBID_SOCKETCAN_DEFAULT_ERR_MASK */
    double sample_period_s;    /* nominal h in s for the counter plausibility check
                                  (can_assembler.h); 0 = no check */
    /* Tests only: use_fd = true reads from this already-open datagram socket (e.g. one
     * end of an AF_UNIX socketpair carrying can_frame / canfd_frame bytes) instead of
     * opening CAN_RAW; the receive, cmsg and assembly path is the same. */
    bool use_fd;
    int fd;                    /* taken over: closed by the source */
} vibid_source_socketcan_config;

/* What open actually got (for the daemon's status and --check output). */
typedef struct vibid_socketcan_info {
    bool fd_frames;            /* CAN_RAW_FD_FRAMES accepted */
    bool hw_timestamps;        /* hardware stamping enabled on the interface */
    bool so_timestamping;      /* SO_TIMESTAMPING accepted (else SO_TIMESTAMPNS / none) */
    bool rxq_ovfl;             /* SO_RXQ_OVFL accepted */
    int rcvbuf_bytes;          /* effective SO_RCVBUF as the kernel reports it */
    unsigned n_filters;        /* kernel id filters installed (0 = all ids) */
    uint32_t err_mask;
    unsigned batch;
} vibid_socketcan_info;

extern const vibid_source_ops vibid_source_socketcan_ops;

/* VIBID_DRV_E_ARG if src is not a SocketCAN source. */
vibid_drv_status vibid_source_socketcan_info(const vibid_source *src, vibid_socketcan_info *info);

#ifdef __cplusplus
}
#endif
#endif
