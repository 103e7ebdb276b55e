/* notify.h: the systemd notification protocol (sd_notify(3)) without libsystemd.
 *
 * The protocol is one datagram with "KEY=VALUE\n..." text sent to the AF_UNIX socket
 * named by $NOTIFY_SOCKET (a path, or a Linux abstract socket when it starts with '@').
 * That is a dozen lines of code; linking libsystemd for it would add a run-time
 * dependency (and its own dependencies) to an industrial PC image that may not run
 * systemd at all, for no gain. Without $NOTIFY_SOCKET every call is a no-op.
 *
 * Watchdog: $WATCHDOG_USEC (and $WATCHDOG_PID, which must be our pid if set) give the
 * interval; vd_notify_watchdog_usec() returns it so that the caller pings at half of it.
 */
#ifndef VIBIDD_NOTIFY_H
#define VIBIDD_NOTIFY_H

#include <stdint.h>

typedef struct vd_notify {
    int fd;                 /* -1 when not under a notify-aware manager */
    char path[108];
    unsigned path_len;      /* bytes of sun_path used (abstract: leading NUL) */
    uint64_t watchdog_usec; /* 0 = no watchdog asked for */
} vd_notify;

/* Reads the environment; returns 0, or -1 with a logged warning when NOTIFY_SOCKET is
 * set but unusable (the daemon then runs on; systemd would time out the start). */
int vd_notify_init(vd_notify *n);
/* Sends text (e.g. "READY=1\nSTATUS=running"). 0 on success or when disabled, -1 on a
 * failed send (errno kept). */
int vd_notify_send(vd_notify *n, const char *text);
uint64_t vd_notify_watchdog_usec(const vd_notify *n);
void vd_notify_close(vd_notify *n);

#endif
