/* notify.c: see notify.h. */
#include "notify.h"

#include "log.h"

#include <errno.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

int vd_notify_init(vd_notify *n)
{
    memset(n, 0, sizeof *n);
    n->fd = -1;
    const char *wd = getenv("WATCHDOG_USEC");
    const char *wpid = getenv("WATCHDOG_PID");
    if (wd && *wd) {
        char *end;
        unsigned long long v = strtoull(wd, &end, 10);
        int pid_ok = 1;
        if (wpid && *wpid)
            pid_ok = strtol(wpid, NULL, 10) == (long)getpid();
        if (*end == '\0' && v > 0 && pid_ok)
            n->watchdog_usec = v;
    }
    const char *sock = getenv("NOTIFY_SOCKET");
    if (!sock || !*sock)
        return 0;
    size_t len = strlen(sock);
    if ((sock[0] != '/' && sock[0] != '@') || len >= sizeof n->path) {
        vd_warning("NOTIFY_SOCKET '%s' is neither an absolute path nor an abstract socket '@...' that fits "
                   "sockaddr_un: systemd notifications disabled",
                   sock);
        return -1;
    }
    memcpy(n->path, sock, len);
    if (sock[0] == '@')
        n->path[0] = '\0';
    n->path_len = (unsigned)len;
    n->fd = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    if (n->fd < 0) {
        vd_warning("socket(AF_UNIX, SOCK_DGRAM) for NOTIFY_SOCKET failed: %s: systemd notifications disabled",
                   strerror(errno));
        return -1;
    }
    return 0;
}

int vd_notify_send(vd_notify *n, const char *text)
{
    if (n->fd < 0)
        return 0;
    struct sockaddr_un sa;
    memset(&sa, 0, sizeof sa);
    sa.sun_family = AF_UNIX;
    memcpy(sa.sun_path, n->path, n->path_len);
    socklen_t salen = (socklen_t)(offsetof(struct sockaddr_un, sun_path) + n->path_len);
    ssize_t w = sendto(n->fd, text, strlen(text), MSG_NOSIGNAL, (struct sockaddr *)&sa, salen);
    return w == (ssize_t)strlen(text) ? 0 : -1;
}

uint64_t vd_notify_watchdog_usec(const vd_notify *n) { return n->watchdog_usec; }

void vd_notify_close(vd_notify *n)
{
    if (n->fd >= 0)
        close(n->fd);
    n->fd = -1;
}
