/* sim/sim_modbus.c: see sim_modbus.h. */
#include "sim_modbus.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <modbus.h>
#include <netdb.h>
#include <netinet/in.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#define MAX_CLIENTS 32
#define DATA_OFFSET 64u

struct sim_modbus {
    char host[256];
    int port;
    int listen_fd;
    int clients[MAX_CLIENTS];
    uint8_t inbuf[MAX_CLIENTS][MODBUS_TCP_MAX_ADU_LENGTH]; /* per client: bytes of requests not yet answered */
    size_t inlen[MAX_CLIENTS];
    modbus_t *ctx;
    modbus_mapping_t *map;
    vibid_regmap rm;
    size_t *chan;
    unsigned base, K, W, C;
    uint32_t count;
    unsigned ws;
    pthread_t thread;
    int thread_started;
    pthread_mutex_t lock;
    _Atomic int quit;
    int want_serving, serving;
    uint64_t session_seed;
    sim_modbus_stats st;
    uint16_t rec[128];
};

static int open_listen(sim_modbus *m, char *err, size_t errlen)
{
    struct addrinfo hints, *res = NULL;
    memset(&hints, 0, sizeof hints);
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    hints.ai_flags = AI_PASSIVE | AI_NUMERICSERV;
    char ps[16];
    snprintf(ps, sizeof ps, "%d", m->port);
    int rc = getaddrinfo(m->host, ps, &hints, &res);
    if (rc) {
        snprintf(err, errlen, "--modbus %s:%d: cannot resolve '%s': %s", m->host, m->port, m->host, gai_strerror(rc));
        return -1;
    }
    int fd = socket(res->ai_family, res->ai_socktype | SOCK_CLOEXEC, res->ai_protocol);
    if (fd < 0) {
        snprintf(err, errlen, "--modbus %s:%d: socket: %s", m->host, m->port, strerror(errno));
        freeaddrinfo(res);
        return -1;
    }
    int on = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &on, sizeof on);
    if (bind(fd, res->ai_addr, res->ai_addrlen) < 0 || listen(fd, 16) < 0) {
        snprintf(err, errlen, "--modbus %s:%d: bind/listen: %s", m->host, m->port, strerror(errno));
        close(fd);
        freeaddrinfo(res);
        return -1;
    }
    freeaddrinfo(res);
    struct sockaddr_storage ss;
    socklen_t sl = sizeof ss;
    if (getsockname(fd, (struct sockaddr *)&ss, &sl) == 0) {
        if (ss.ss_family == AF_INET) m->port = ntohs(((struct sockaddr_in *)&ss)->sin_port);
        else if (ss.ss_family == AF_INET6) m->port = ntohs(((struct sockaddr_in6 *)&ss)->sin6_port);
    }
    m->listen_fd = fd;
    return 0;
}

/* Drops client slot i (its socket closed, its partial request forgotten). */
static void drop_client(sim_modbus *m, int i)
{
    close(m->clients[i]);
    m->clients[i] = -1;
    m->inlen[i] = 0;
    m->st.closed++;
}

static void close_all(sim_modbus *m)
{
    for (int i = 0; i < MAX_CLIENTS; i++)
        if (m->clients[i] >= 0) drop_client(m, i);
    if (m->listen_fd >= 0) close(m->listen_fd);
    m->listen_fd = -1;
}

/* FIFO (re)start: header, empty ring, count 0, new session. Caller holds the lock. */
static void fifo_restart(sim_modbus *m, double h)
{
    uint16_t *r = m->map->tab_registers;
    unsigned B = m->base;
    uint64_t x = m->session_seed += 0x9E3779B97F4A7C15ull;
    x ^= (uint64_t)time(NULL) ^ ((uint64_t)getpid() << 20);
    x = (x ^ (x >> 31)) * 0xBF58476D1CE4E5B9ull;
    uint16_t session = (uint16_t)(x >> 24);
    if (h > 0) {
        uint32_t pns = (uint32_t)llround(h * 1e9);
        r[B + 6] = (uint16_t)(pns >> 16);
        r[B + 7] = (uint16_t)(pns & 0xFFFF);
    }
    r[B + 0] = 0x5646;
    r[B + 1] = 1;
    r[B + 2] = (uint16_t)m->C;
    r[B + 3] = (uint16_t)m->W;
    r[B + 4] = (uint16_t)m->K;
    r[B + 5] = DATA_OFFSET;
    m->count = 0;
    m->ws = 0;
    r[B + 8] = r[B + 9] = r[B + 10] = 0;
    r[B + 11] = session;
    r[B + 12] = r[B + 13] = r[B + 14] = r[B + 15] = 0;
    for (unsigned i = 0; i < m->C; i++)
        r[B + 16 + i] = (uint16_t)((unsigned)m->rm.entries[i].type | ((unsigned)m->rm.entries[i].order << 8));
    for (unsigned i = 0; i < m->K * m->W; i++) r[B + DATA_OFFSET + i] = 0xFFFF; /* no valid tag yet */
    m->st.sessions++;
}

static int is_write(int fc) { return fc == 0x05 || fc == 0x06 || fc == 0x0F || fc == 0x10 || fc == 0x16 || fc == 0x17; }

/* Answers every complete request in client i's buffer. Requests are framed by their MBAP
 * header here, not by modbus_receive: that call blocks on a partial request (a client
 * dripping bytes stalled every client), and a reply sent on a blocking socket to a client
 * that pipelines requests without reading stalled the thread, with the register lock
 * held, once the socket buffers filled. Sockets are non-blocking: a reply that cannot be
 * sent at once closes that client (counted), the others never wait. 0, or -1 when the
 * client was dropped. */
static int serve_requests(sim_modbus *m, int i)
{
    uint8_t *b = m->inbuf[i];
    for (;;) {
        if (m->inlen[i] < 6) return 0;
        unsigned len = ((unsigned)b[4] << 8) | b[5]; /* unit id + PDU */
        if (len < 2 || len > MODBUS_TCP_MAX_ADU_LENGTH - 6) {
            m->st.bad_frames++;
            drop_client(m, i);
            return -1;
        }
        size_t total = 6 + (size_t)len;
        if (m->inlen[i] < total) return 0;
        uint8_t req[MODBUS_TCP_MAX_ADU_LENGTH] = {0}; /* zeros past a short PDU: never stale bytes */
        memcpy(req, b, total);
        memmove(b, b + total, m->inlen[i] - total);
        m->inlen[i] -= total;
        modbus_set_socket(m->ctx, m->clients[i]);
        pthread_mutex_lock(&m->lock);
        m->st.requests++;
        int fc = req[7], r2;
        if (is_write(fc)) {
            m->st.refused_writes++;
            r2 = modbus_reply_exception(m->ctx, req, MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
        } else if (fc >= 1 && fc <= 4 && len < 6) { /* a read needs address and count */
            r2 = modbus_reply_exception(m->ctx, req, MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE);
        } else {
            r2 = modbus_reply(m->ctx, req, (int)total, m->map);
        }
        pthread_mutex_unlock(&m->lock);
        if (r2 < 0) { /* EAGAIN: its replies pile up unread; or the peer is gone */
            if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EMBBADDATA) m->st.slow_clients++;
            drop_client(m, i);
            return -1;
        }
    }
}

static void *server_thread(void *arg)
{
    sim_modbus *m = arg;
    char err[256];
    while (!m->quit) {
        pthread_mutex_lock(&m->lock);
        int want = m->want_serving;
        pthread_mutex_unlock(&m->lock);
        if (want && m->listen_fd < 0) {
            if (open_listen(m, err, sizeof err) == 0) {
                pthread_mutex_lock(&m->lock);
                m->serving = 1;
                pthread_mutex_unlock(&m->lock);
                fprintf(stderr, "vibid-sim: modbus: serving again on %s:%d (new FIFO session)\n", m->host, m->port);
            } else {
                fprintf(stderr, "vibid-sim: modbus: %s (retrying)\n", err);
                usleep(200000);
                continue;
            }
        } else if (!want && m->listen_fd >= 0) {
            close_all(m);
            pthread_mutex_lock(&m->lock);
            m->serving = 0;
            pthread_mutex_unlock(&m->lock);
            fprintf(stderr, "vibid-sim: modbus: stopped serving (listening socket and clients closed)\n");
        }
        fd_set rd;
        FD_ZERO(&rd);
        int maxfd = -1;
        if (m->listen_fd >= 0) {
            FD_SET(m->listen_fd, &rd);
            maxfd = m->listen_fd;
        }
        for (int i = 0; i < MAX_CLIENTS; i++)
            if (m->clients[i] >= 0) {
                FD_SET(m->clients[i], &rd);
                if (m->clients[i] > maxfd) maxfd = m->clients[i];
            }
        struct timeval tv = {0, 20000};
        int n = select(maxfd + 1, &rd, NULL, NULL, &tv);
        if (n <= 0) continue;
        if (m->listen_fd >= 0 && FD_ISSET(m->listen_fd, &rd)) {
            int fd = accept4(m->listen_fd, NULL, NULL, SOCK_CLOEXEC | SOCK_NONBLOCK);
            if (fd >= 0) {
                int slot = -1;
                for (int i = 0; i < MAX_CLIENTS && slot < 0; i++)
                    if (m->clients[i] < 0) slot = i;
                if (slot < 0) {
                    close(fd); /* too many clients: refuse this one, keep the others */
                } else {
                    m->clients[slot] = fd;
                    m->inlen[slot] = 0;
                    m->st.accepted++;
                }
            }
        }
        for (int i = 0; i < MAX_CLIENTS; i++) {
            int fd = m->clients[i];
            if (fd < 0 || !FD_ISSET(fd, &rd)) continue;
            ssize_t got = recv(fd, m->inbuf[i] + m->inlen[i], sizeof m->inbuf[i] - m->inlen[i], 0);
            if (got == 0 || (got < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) {
                drop_client(m, i); /* disconnected */
                continue;
            }
            if (got > 0) {
                m->inlen[i] += (size_t)got;
                serve_requests(m, i);
            }
        }
    }
    close_all(m);
    return NULL;
}

sim_modbus *sim_modbus_create(const char *host, int port, const vibid_regmap *map, const size_t *chan,
                              unsigned fifo_base, unsigned capacity, double h, char *err, size_t errlen)
{
    sim_modbus *m = calloc(1, sizeof *m);
    if (!m) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    m->listen_fd = -1;
    for (int i = 0; i < MAX_CLIENTS; i++) m->clients[i] = -1;
    pthread_mutex_init(&m->lock, NULL);
    snprintf(m->host, sizeof m->host, "%s", host);
    m->port = port;
    m->base = fifo_base;
    m->K = capacity;
    m->C = (unsigned)map->n;
    if (map->n < 1 || map->n > 32) {
        snprintf(err, errlen, "register map: %zu channels; the FIFO holds 1..32", map->n);
        goto fail;
    }
    m->rm.n = map->n;
    m->rm.entries = calloc(map->n, sizeof *m->rm.entries);
    m->chan = calloc(map->n, sizeof *m->chan);
    if (!m->rm.entries || !m->chan) {
        snprintf(err, errlen, "out of memory");
        goto fail;
    }
    memcpy(m->rm.entries, map->entries, map->n * sizeof *map->entries);
    memcpy(m->chan, chan, map->n * sizeof *chan);
    m->W = 1;
    unsigned hold_max = 0, in_max = 0;
    for (size_t i = 0; i < map->n; i++) {
        const vibid_reg_entry *e = &map->entries[i];
        unsigned w = vibid_reg_type_words(e->type);
        m->W += w;
        if (e->kind == VIBID_REG_HOLDING) {
            if (e->address + w > hold_max) hold_max = e->address + w;
        } else if (e->address + w > in_max) {
            in_max = e->address + w;
        }
    }
    if (m->W > 125) {
        snprintf(err, errlen, "register map: a FIFO record would need %u registers; at most 125 (fewer or smaller channels)", m->W);
        goto fail;
    }
    unsigned long fifo_end = (unsigned long)fifo_base + DATA_OFFSET + (unsigned long)capacity * m->W;
    if (fifo_end > 65536ul) {
        snprintf(err, errlen, "FIFO does not fit: base %u + 64 + capacity %u x %u registers > 65536; lower simulation.modbus.capacity to at most %lu",
                 fifo_base, capacity, m->W, (65536ul - fifo_base - DATA_OFFSET) / m->W);
        goto fail;
    }
    for (size_t i = 0; i < map->n; i++) {
        const vibid_reg_entry *e = &map->entries[i];
        unsigned w = vibid_reg_type_words(e->type);
        if (e->kind == VIBID_REG_HOLDING && e->address + w > fifo_base && e->address < fifo_end) {
            snprintf(err, errlen, "register map entry '%s' (line %u): holding registers %u..%u overlap the FIFO at %u..%lu",
                     e->name, e->line, e->address, e->address + w - 1, fifo_base, fifo_end - 1);
            goto fail;
        }
        for (size_t j = 0; j < i; j++) {
            const vibid_reg_entry *o = &map->entries[j];
            unsigned ow = vibid_reg_type_words(o->type);
            if (o->kind == e->kind && e->address < o->address + ow && o->address < e->address + w) {
                snprintf(err, errlen, "register map entries '%s' and '%s' overlap", o->name, e->name);
                goto fail;
            }
        }
    }
    if (fifo_end > hold_max) hold_max = (unsigned)fifo_end;
    m->map = modbus_mapping_new_start_address(0, 0, 0, 0, 0, hold_max, 0, in_max ? in_max : 1);
    m->ctx = modbus_new_tcp("127.0.0.1", 502); /* only used with modbus_set_socket */
    if (!m->map || !m->ctx) {
        snprintf(err, errlen, "libmodbus: %s", modbus_strerror(errno));
        goto fail;
    }
    modbus_set_byte_timeout(m->ctx, 0, 50000);
    modbus_set_response_timeout(m->ctx, 0, 50000);
    m->session_seed = (uint64_t)time(NULL) * 2654435761u;
    fifo_restart(m, h);
    if (open_listen(m, err, errlen)) goto fail;
    m->serving = m->want_serving = 1;
    if (pthread_create(&m->thread, NULL, server_thread, m)) {
        snprintf(err, errlen, "cannot start the Modbus server thread");
        goto fail;
    }
    m->thread_started = 1;
    return m;
fail:
    sim_modbus_destroy(m);
    return NULL;
}

int sim_modbus_port(const sim_modbus *m) { return m->port; }

void sim_modbus_push(sim_modbus *m, const double *values, sim_faults *faults)
{
    uint16_t words[4];
    uint16_t *rec = m->rec;
    size_t pos = 1;
    pthread_mutex_lock(&m->lock);
    if (!m->serving || !m->want_serving) {
        pthread_mutex_unlock(&m->lock);
        return;
    }
    rec[0] = (uint16_t)(m->count & 0xFFFF);
    for (size_t i = 0; i < m->rm.n; i++) {
        const vibid_reg_entry *e = &m->rm.entries[i];
        unsigned w = vibid_reg_type_words(e->type);
        memset(words, 0, sizeof words);
        if (vibid_reg_encode(e, values[m->chan[i]], words) != VIBID_DRV_OK) m->st.encode_errors++;
        uint16_t *tab = e->kind == VIBID_REG_HOLDING ? m->map->tab_registers : m->map->tab_input_registers;
        memcpy(tab + e->address, words, w * sizeof *words);
        memcpy(rec + pos, words, w * sizeof *words);
        pos += w;
    }
    int keep = faults ? sim_faults_record(faults, rec, m->W) : 1;
    uint16_t *r = m->map->tab_registers;
    if (keep) memcpy(r + m->base + DATA_OFFSET + m->ws * m->W, rec, m->W * sizeof *rec);
    m->count++;
    m->ws = (m->ws + 1) % m->K;
    r[m->base + 8] = (uint16_t)(m->count >> 16);
    r[m->base + 9] = (uint16_t)(m->count & 0xFFFF);
    r[m->base + 10] = (uint16_t)m->ws;
    m->st.records++;
    pthread_mutex_unlock(&m->lock);
}

void sim_modbus_set_serving(sim_modbus *m, int on)
{
    pthread_mutex_lock(&m->lock);
    if (on && !m->want_serving) fifo_restart(m, 0.0);
    m->want_serving = on;
    pthread_mutex_unlock(&m->lock);
}

void sim_modbus_stats_get(sim_modbus *m, sim_modbus_stats *s)
{
    pthread_mutex_lock(&m->lock);
    *s = m->st;
    pthread_mutex_unlock(&m->lock);
}

void sim_modbus_destroy(sim_modbus *m)
{
    if (!m) return;
    if (m->thread_started) {
        m->quit = 1;
        pthread_join(m->thread, NULL);
    } else {
        close_all(m);
    }
    if (m->ctx) {
        modbus_set_socket(m->ctx, -1);
        modbus_free(m->ctx);
    }
    if (m->map) modbus_mapping_free(m->map);
    free(m->rm.entries);
    free(m->chan);
    pthread_mutex_destroy(&m->lock);
    free(m);
}
