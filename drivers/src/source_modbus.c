/* Modbus source (libmodbus client), FIFO and snapshot modes; see source_modbus.h and
 * drivers/modbus_fifo_layout.md. */
#include <vibid_drivers/source_modbus.h>

#include <errno.h>
#include <math.h>
#include <modbus.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "rec_queue.h"
#include "source_util.h"

#define MAX_REQ 125          /* registers per read request (Modbus limit) */
#define POLL_SAMPLES 1024    /* FIFO samples taken per poll step (bounded queue) */
#define HDR_FIXED 16

typedef struct block {
    vibid_reg_kind kind;
    uint16_t start, count;
} block;

typedef struct mb {
    vibid_source_modbus_config cfg;
    char host[256], device[256], where[300];
    modbus_t *ctx;
    bool connected, ever_connected;
    int64_t next_connect;
    double backoff;
    unsigned consec_timeouts;
    char last_error[128];
    vibid_reg_entry ent[VIBID_DRV_MAX_CHANNELS]; /* per channel, from the register map */
    size_t n;
    /* snapshot */
    block blocks[VIBID_DRV_MAX_CHANNELS];
    size_t nblocks;
    int ch_block[VIBID_DRV_MAX_CHANNELS];
    uint16_t regs[VIBID_DRV_MAX_CHANNELS][MAX_REQ];
    int64_t h_ns, t0_mono;
    bool started;
    /* FIFO */
    unsigned B, W, K, D;
    uint32_t period_ns;
    vibid_reg_entry fent[VIBID_DRV_MAX_CHANNELS]; /* address = word offset in a record */
    bool have_session, force_restart;
    uint16_t session;
    int64_t last_good_poll;      /* mono ns of the last counter poll that was believed */
    unsigned implausible_in_row; /* consecutive counter polls not believed */
    bool resync;                 /* restart after counters not believed: skip the ring's backlog */
    uint32_t doubt_S;            /* the counter at the first poll not believed */
    uint32_t s_next32;
    uint64_t s_next64;
    int64_t t_anchor, poll_ns, next_poll;
    uint16_t buf[MAX_REQ];
    /* output */
    uint64_t k_next;
    int64_t last_sample_t;
    bool any_sample;
    rec_queue q;
    vibid_source_stats st;
    int64_t last_count_t;
} mb;

static int64_t sec_ns(double s) { return (int64_t)llround(s * 1e9); }

/* s seconds (>= 0) as libmodbus's (sec, usec < 1000000) pair, rounded to the microsecond
 * with the carry: 0.9999996 s is (1, 0), not (0, 1000000), which libmodbus refuses
 * (EINVAL), silently keeping its 0.5 s default. */
static void split_us(double s, uint32_t *sec, uint32_t *usec)
{
    long long us = llround(s * 1e6);
    *sec = (uint32_t)(us / 1000000);
    *usec = (uint32_t)(us % 1000000);
}

/* n sample periods of hp ns, saturated at +-2^61 ns (73 years) so that the sums around it
 * cannot overflow either: a device's 32-bit counter times its own 32-bit period_ns does
 * not fit in 64 bits (found by drivers.fuzz_modbus_fifo: 4107009791 x 4160749567). */
static int64_t periods_ns(int64_t n, int64_t hp)
{
    const int64_t cap = (int64_t)1 << 61;
    int64_t r;
    if (__builtin_mul_overflow(n, hp, &r) || r > cap || r < -cap)
        return (n < 0) != (hp < 0) ? -cap : cap;
    return r;
}

static void link_lost(mb *m, const char *why)
{
    if (m->ctx) {
        modbus_close(m->ctx);
        modbus_free(m->ctx);
        m->ctx = NULL;
    }
    m->connected = false;
    m->st.link_losses++;
    m->backoff = m->cfg.backoff_initial_s;
    m->next_connect = mono_ns() + sec_ns(m->backoff);
    rec_queue_fault(&m->q, VIBID_FAULT_LINK, m->k_next, 0, "Modbus %s: link lost (%s); reconnecting in %.3g s",
                    m->where, why, m->backoff);
}

/* One read request. 0 on success; -1 on failure (counted, link handling done). */
static int mb_read(mb *m, vibid_reg_kind kind, unsigned addr, unsigned n, uint16_t *dst)
{
    m->st.requests++;
    int rc = kind == VIBID_REG_HOLDING ? modbus_read_registers(m->ctx, (int)addr, (int)n, dst)
                                       : modbus_read_input_registers(m->ctx, (int)addr, (int)n, dst);
    if (rc == (int)n) {
        m->consec_timeouts = 0;
        return 0;
    }
    int e = rc < 0 ? errno : EMBBADDATA;
    snprintf(m->last_error, sizeof m->last_error, "%s %u..%u: %s",
             kind == VIBID_REG_HOLDING ? "holding" : "input", addr, addr + n - 1, modbus_strerror(e));
    if (e == ETIMEDOUT) {
        m->st.timeouts++;
        m->consec_timeouts++;
        modbus_flush(m->ctx); /* a late answer must not be taken for the next one */
        if (m->consec_timeouts >= m->cfg.max_timeouts) {
            char why[200];
            snprintf(why, sizeof why, "%u consecutive timeouts of %.3g s", m->consec_timeouts,
                     m->cfg.response_timeout_s);
            link_lost(m, why);
        }
    } else if (e >= MODBUS_ENOBASE) {
        /* exception answer or malformed answer: the device is there; the link stays */
        modbus_flush(m->ctx);
    } else {
        link_lost(m, m->last_error);
    }
    return -1;
}

static void poll_failed(mb *m, const char *what)
{
    m->st.failed_polls++;
    rec_queue_fault(&m->q, VIBID_FAULT_POLL, m->k_next, 0, "Modbus %s: %s poll failed: %s", m->where, what,
                    m->last_error);
}

/* FIFO header check at connect. OK, E_LINK (retry) or a fatal mismatch. */
static vibid_drv_status fifo_check_header(mb *m, vibid_drv_error *err)
{
    uint16_t h[HDR_FIXED + VIBID_DRV_MAX_CHANNELS];
    unsigned want = HDR_FIXED + (unsigned)m->n;
    if (mb_read(m, VIBID_REG_HOLDING, m->B, want, h) != 0)
        return vibid_drv_fail(err, VIBID_DRV_E_LINK, "cannot read the FIFO header at %u: %s", m->B, m->last_error);
    if (h[0] != VIBID_MODBUS_FIFO_MAGIC || h[1] != VIBID_MODBUS_FIFO_VERSION)
        return vibid_drv_fail(err, VIBID_DRV_E_RANGE,
                              "no vibid FIFO at holding register %u: magic 0x%04X version %u "
                              "(expected 0x%04X version %u; see modbus_fifo_layout.md)",
                              m->B, h[0], h[1], VIBID_MODBUS_FIFO_MAGIC, VIBID_MODBUS_FIFO_VERSION);
    unsigned C = h[2], W = h[3], K = h[4], D = h[5];
    uint32_t period = (uint32_t)h[6] << 16 | h[7];
    unsigned words = 1;
    for (size_t c = 0; c < m->n; c++)
        words += vibid_reg_type_words(m->ent[c].type);
    if (C != m->n)
        return vibid_drv_fail(err, VIBID_DRV_E_RANGE, "FIFO has %u channels, the channel map %zu",
                              C, m->n);
    if (W != words || W < 2 || W > MAX_REQ)
        return vibid_drv_fail(err, VIBID_DRV_E_RANGE,
                              "FIFO records have %u registers, the register map's channel types need %u",
                              W, words);
    if (K < 2 || K > 32767 || D < HDR_FIXED + C || (unsigned long)m->B + D + (unsigned long)K * W > 65536UL)
        return vibid_drv_fail(err, VIBID_DRV_E_RANGE, "FIFO capacity %u / data offset %u invalid",
                              K, D);
    if (period == 0)
        return vibid_drv_fail(err, VIBID_DRV_E_RANGE, "FIFO period_ns is 0");
    if (m->cfg.sample_period_s > 0 && fabs(m->cfg.sample_period_s * 1e9 - period) > 0.5)
        return vibid_drv_fail(err, VIBID_DRV_E_RANGE, "device samples every %u ns, configured %.9g s",
                              period, m->cfg.sample_period_s);
    for (size_t c = 0; c < m->n; c++) {
        unsigned type = h[HDR_FIXED + c] & 0xFF, order = h[HDR_FIXED + c] >> 8;
        if (type != (unsigned)m->ent[c].type || order != (unsigned)m->ent[c].order)
            return vibid_drv_fail(err, VIBID_DRV_E_RANGE,
                                  "FIFO channel %zu ('%s') has type code %u / byte order %u, register "
                                  "'%s' (line %u) says %u / %u",
                                  c, m->cfg.chanmap.ch[c].name, type, order, m->ent[c].name,
                                  m->ent[c].line, (unsigned)m->ent[c].type, (unsigned)m->ent[c].order);
    }
    if (m->have_session && (W != m->W || K != m->K || D != m->D || period != m->period_ns))
        m->force_restart = true;
    m->W = W;
    m->K = K;
    m->D = D;
    m->period_ns = period;
    unsigned off = 1;
    for (size_t c = 0; c < m->n; c++) {
        m->fent[c] = m->ent[c];
        m->fent[c].address = (uint16_t)off;
        off += vibid_reg_type_words(m->ent[c].type);
    }
    m->poll_ns = m->cfg.poll_period_s > 0 ? sec_ns(m->cfg.poll_period_s) : (int64_t)period * K / 4;
    if (m->cfg.poll_period_s <= 0 && m->poll_ns > 50000000)
        m->poll_ns = 50000000;
    return VIBID_DRV_OK;
}

/* One connection attempt. OK, E_LINK (failed, retry later; fault queued), or fatal. */
static vibid_drv_status try_connect(mb *m, vibid_drv_error *err)
{
    const vibid_source_modbus_config *c = &m->cfg;
    m->ctx = c->transport == VIBID_MODBUS_TCP
                 ? modbus_new_tcp(m->host, c->port)
                 : modbus_new_rtu(m->device, c->baud, c->parity, c->data_bits, c->stop_bits);
    if (!m->ctx)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "Modbus %s: cannot create the context: %s", m->where,
                              modbus_strerror(errno));
    modbus_set_slave(m->ctx, c->unit_id);
    uint32_t sec, usec;
    split_us(c->response_timeout_s, &sec, &usec);
    modbus_set_response_timeout(m->ctx, sec, usec);
    /* Between the bytes of one answer libmodbus waits the byte timeout (default 0.5 s),
     * per byte: a peer dripping its answer one byte per 0.45 s held one request for
     * minutes. 50 ms (or 20 character times on a slow serial line) is far above any
     * healthy gap inside an answer and bounds a request by the response timeout plus
     * one such gap per byte that arrives. */
    double byte_s = 0.05;
    if (c->transport == VIBID_MODBUS_RTU && c->baud > 0 && 20.0 * 11.0 / c->baud > byte_s)
        byte_s = 20.0 * 11.0 / c->baud;
    if (byte_s > c->response_timeout_s)
        byte_s = c->response_timeout_s;
    split_us(byte_s, &sec, &usec);
    modbus_set_byte_timeout(m->ctx, sec, usec);
    vibid_drv_status st = VIBID_DRV_OK;
    vibid_drv_error e2 = {0};
    if (modbus_connect(m->ctx) != 0) {
        snprintf(m->last_error, sizeof m->last_error, "%s", modbus_strerror(errno));
        st = vibid_drv_fail(&e2, VIBID_DRV_E_LINK, "connect failed: %s", m->last_error);
    } else {
        m->connected = true;
        if (c->mode == VIBID_MODBUS_FIFO) {
            /* Whatever the header says is the device's state, not the configuration's: a
             * device rebooting with zeroed registers (magic 0, capacity 0), a FIFO not
             * set up yet, a layout that does not fit the register map. A fault and a
             * retry with back-off, never an exit (only the configuration stops vibidd). */
            if (fifo_check_header(m, &e2) != VIBID_DRV_OK)
                st = VIBID_DRV_E_LINK;
        }
    }
    if (st == VIBID_DRV_OK) {
        if (m->ever_connected) {
            m->st.reconnects++;
            rec_queue_fault(&m->q, VIBID_FAULT_LINK, m->k_next, 0, "Modbus %s: reconnected", m->where);
        }
        m->ever_connected = true;
        m->backoff = c->backoff_initial_s;
        m->consec_timeouts = 0;
        m->next_poll = mono_ns();
        return VIBID_DRV_OK;
    }
    if (m->ctx) {
        modbus_close(m->ctx);
        modbus_free(m->ctx);
        m->ctx = NULL;
    }
    m->connected = false;
    if (st != VIBID_DRV_E_LINK)
        return vibid_drv_fail(err, st, "%s", e2.text);
    m->st.connect_failures++;
    m->next_connect = mono_ns() + sec_ns(m->backoff);
    rec_queue_fault(&m->q, VIBID_FAULT_LINK, m->k_next, 0, "Modbus %s: %s; retry in %.3g s", m->where, e2.text,
                    m->backoff);
    m->backoff = m->backoff * 2 > c->backoff_max_s ? c->backoff_max_s : m->backoff * 2;
    return VIBID_DRV_E_LINK;
}

static void emit_sample(mb *m, int64_t t, const double *v)
{
    vibid_record *r = rec_queue_push(&m->q, VIBID_REC_SAMPLE);
    if (!r)
        return;
    r->index = m->k_next++;
    r->t_ns = t;
    r->n_values = (uint32_t)m->n;
    memcpy(r->values, v, m->n * sizeof *v);
    m->last_sample_t = t;
    m->any_sample = true;
}

/* GAP for k_next.. (count samples), merged with a directly preceding GAP record. */
static void gap(mb *m, uint64_t count, const char *why)
{
    if (count == 0)
        return;
    if (m->q.len) {
        vibid_record *last = &m->q.r[(m->q.head + m->q.len - 1) % m->q.cap];
        if (last->kind == VIBID_REC_GAP && last->index + last->count == m->k_next && strstr(last->text, why)) {
            last->count += count;
            m->k_next += count;
            return;
        }
    }
    rec_queue_gap(&m->q, m->k_next, count, "Modbus %s: %s", m->where, why);
    m->k_next += count;
}

/* Decodes entries e[0..n-1] from a register block; false with a fault when unusable. */
static bool decode_all(mb *m, const vibid_reg_entry *e, const uint16_t *const *regs, const size_t *nregs,
                       const uint16_t *first, double *v)
{
    for (size_t c = 0; c < m->n; c++) {
        if (vibid_reg_decode(&e[c], regs[c], nregs[c], first[c], &v[c]) != VIBID_DRV_OK) {
            rec_queue_fault(&m->q, VIBID_FAULT_POLL, m->k_next, 0, "Modbus %s: register '%s' outside the block read",
                            m->where, e[c].name);
            return false;
        }
        if (!isfinite(v[c])) {
            m->st.nonfinite++;
            rec_queue_fault(&m->q, VIBID_FAULT_NONFINITE, m->k_next, 0, "Modbus %s: register '%s' is not finite",
                            m->where, e[c].name);
            return false;
        }
    }
    return true;
}

/* One poll: the counter, then the new records in requests of whole records, until the
 * backlog is read or `deadline` (mono ns) passes (after one records request at least: a
 * slow peer still delivers); the rest is read at the next poll, so a slow peer cannot hold
 * one source read for many requests. */
static void fifo_poll(mb *m, int64_t deadline)
{
    m->st.polls++;
    uint16_t h[4];
    if (mb_read(m, VIBID_REG_HOLDING, m->B + 8, 4, h) != 0) {
        poll_failed(m, "FIFO counter");
        return;
    }
    uint32_t S = (uint32_t)h[0] << 16 | h[1];
    unsigned ws = h[2];
    uint16_t session = h[3];
    const int64_t hp = m->period_ns;
    if (ws >= m->K) {
        snprintf(m->last_error, sizeof m->last_error, "write_slot %u >= capacity %u", ws, m->K);
        poll_failed(m, "FIFO counter");
        return;
    }
    /* What time allows: since the last believed poll the server can have produced at
     * most `possible` samples (10 % clock tolerance, 2 of slack). A session change is a
     * restart only when the new counter fits in that time. Anything else is not believed
     * (nothing read, nothing emitted: the ring keeps the samples for the next believed
     * poll): a new id on a counter that continues ours (a flapping id once multiplied
     * samples 18x; a server that writes its new id before resetting its counter looks
     * like this for one poll), a counter that jumps further than time allows or goes back
     * without a new session (a random counter once made 99e9 "missing" samples in 6 s).
     * Not believed three polls in a row: a new id on a continuing counter is adopted (the
     * same stream, nothing re-read); otherwise the stream is restarted at the newest
     * sample, its gap estimated from the elapsed time: bounded either way. */
    if (m->have_session && !m->force_restart) {
        const int64_t now_m = mono_ns();
        const double el = (double)(now_m - m->last_good_poll);
        const uint64_t possible = (uint64_t)(1.1 * el / (double)hp) + 2;
        const uint32_t ahead = S - m->s_next32; /* mod 2^32 */
        const bool continues = ahead <= possible + m->K;
        const bool fresh = session != m->session && (uint64_t)S <= possible;
        char doubt[160] = "";
        if (session != m->session && !fresh)
            snprintf(doubt, sizeof doubt, "session %u -> %u with counter %u (our next %u, %llu samples possible since "
                     "the last poll)",
                     m->session, session, S, m->s_next32, (unsigned long long)possible);
        else if (session == m->session && !continues)
            snprintf(doubt, sizeof doubt, "counter %u %s our next %u by more than the %llu samples time allows", S,
                     ahead > 0x80000000u ? "behind" : "ahead of", m->s_next32, (unsigned long long)possible);
        if (doubt[0]) {
            m->st.implausible++;
            if (m->implausible_in_row == 0)
                m->doubt_S = S;
            /* A frozen counter (a new server whose counter is not reset yet, or one not
             * producing) is waited for, never escalated: only a moving counter is. */
            if (++m->implausible_in_row < 3 || S == m->doubt_S) {
                if (m->implausible_in_row > 3)
                    m->implausible_in_row = 3;
                rec_queue_fault(&m->q, VIBID_FAULT_LINK, m->k_next, 0, "Modbus %s: FIFO %s: not believed", m->where,
                                doubt);
                return;
            }
            if (session != m->session && continues) {
                rec_queue_fault(&m->q, VIBID_FAULT_LINK, m->k_next, 0,
                                "Modbus %s: FIFO %s, three polls in a row: the same stream, id adopted", m->where,
                                doubt);
                m->session = session;
            } else {
                rec_queue_fault(&m->q, VIBID_FAULT_LINK, m->k_next, 0,
                                "Modbus %s: FIFO %s, three polls in a row: the stream is restarted at its newest "
                                "sample",
                                m->where, doubt);
                m->force_restart = true;
                m->resync = true;
            }
        }
    }
    m->implausible_in_row = 0;
    if (!m->have_session || session != m->session || m->force_restart) {
        if (S == 0)
            return; /* a fresh server with nothing yet: wait for its first sample */
        /* Start margin records after the oldest: the server overwrites the oldest slot
         * next, while this poll is reading (seen at 10 kHz as a 3-sample gap at start). */
        const uint32_t margin = m->K / 8;
        uint32_t first = S + margin > m->K ? S + margin - m->K : 0;
        const bool resync = m->resync;
        m->resync = false;
        if (resync) /* the ring's tags cannot be trusted either: start at the newest */
            first = S;
        int64_t now = real_ns();
        if (m->have_session) {
            /* signed: after a resync first = S, the newest sample is S - 1, the next at now + h */
            int64_t t_first = now - periods_ns((int64_t)S - 1 - (int64_t)first, hp);
            int64_t est = m->any_sample ? llround((double)(t_first - m->last_sample_t) / (double)hp) - 1 : 0;
            char why[128];
            if (resync)
                snprintf(why, sizeof why, "FIFO stream resynchronised at counter %u: about %lld samples lost (estimated "
                         "from the elapsed time)",
                         S, (long long)(est > 0 ? est : 0));
            else
                snprintf(why, sizeof why, "FIFO server restarted (session %u -> %u): about %lld samples lost (estimated)",
                         m->session, session, (long long)(est > 0 ? est : 0));
            rec_queue_fault(&m->q, VIBID_FAULT_LINK, m->k_next, 0, "Modbus %s: %s", m->where, why);
            if (est > 0) {
                gap(m, (uint64_t)est, "FIFO server restarted: gap length estimated from elapsed time");
                /* the gap accounts for the time up to the new stream: a second restart
                 * before any sample (repeated resyncs) must not count it again */
                m->last_sample_t = t_first - hp;
            }
        }
        m->have_session = true;
        m->force_restart = false;
        m->session = session;
        m->s_next32 = first;
        m->s_next64 = first;
        m->t_anchor = now - periods_ns((int64_t)S - 1, hp);
    }
    /* believed and taken (a new session's S == 0 returned above: not yet taken, so the
     * time since the last taken poll keeps growing) */
    m->last_good_poll = mono_ns();
    uint32_t avail = S - m->s_next32;
    if (avail > 0x80000000u) {
        rec_queue_fault(&m->q, VIBID_FAULT_LINK, m->k_next, 0,
                        "Modbus %s: FIFO counter went back from %u to %u without a new session: treated as a restart",
                        m->where, m->s_next32, S);
        m->force_restart = true;
        return;
    }
    const uint32_t keep = m->K - m->K / 8; /* the margin of a session start, for the same reason */
    if (avail > keep) {
        uint32_t lost = avail - keep;
        m->st.overruns += lost;
        gap(m, lost, "FIFO overrun: samples overwritten (or next to be) before they were read");
        m->s_next32 += lost;
        m->s_next64 += lost;
        avail = keep;
    }
    unsigned per_req = MAX_REQ / m->W;
    size_t taken = 0;
    while (avail > 0 && taken < POLL_SAMPLES && rec_queue_space(&m->q) >= 2 * (size_t)per_req + 8 &&
           (taken == 0 || mono_ns() < deadline)) { /* one request at least: a slow peer still delivers */
        unsigned back = S - m->s_next32; /* 1..K */
        unsigned slot = (ws + m->K - back) % m->K;
        unsigned cnt = avail < per_req ? avail : per_req;
        if (cnt > m->K - slot)
            cnt = m->K - slot;
        if (mb_read(m, VIBID_REG_HOLDING, m->B + m->D + slot * m->W, cnt * m->W, m->buf) != 0) {
            poll_failed(m, "FIFO records"); /* the rest is read on the next poll, if still there */
            return;
        }
        for (unsigned i = 0; i < cnt; i++) {
            const uint16_t *rec = m->buf + (size_t)i * m->W;
            if (rec[0] != (uint16_t)(m->s_next32 & 0xFFFF)) {
                gap(m, 1, "FIFO record overwritten while it was read");
            } else {
                double v[VIBID_DRV_MAX_CHANNELS];
                const uint16_t *regs[VIBID_DRV_MAX_CHANNELS];
                size_t nr[VIBID_DRV_MAX_CHANNELS];
                uint16_t first[VIBID_DRV_MAX_CHANNELS];
                for (size_t c = 0; c < m->n; c++) {
                    regs[c] = rec;
                    nr[c] = m->W;
                    first[c] = 0;
                }
                if (decode_all(m, m->fent, regs, nr, first, v))
                    emit_sample(m, m->t_anchor + periods_ns((int64_t)m->s_next64, hp), v);
                else
                    gap(m, 1, "FIFO record not usable (see the fault before)");
            }
            m->s_next32++;
            m->s_next64++;
            avail--;
            taken++;
        }
    }
    if (avail > 0)
        m->next_poll = mono_ns(); /* backlog left: continue at once */
}

static void snapshot_tick(mb *m)
{
    m->st.polls++;
    for (size_t b = 0; b < m->nblocks; b++) {
        if (mb_read(m, m->blocks[b].kind, m->blocks[b].start, m->blocks[b].count, m->regs[b]) != 0) {
            poll_failed(m, "snapshot");
            gap(m, 1, "snapshot poll failed");
            return;
        }
    }
    int64_t t = real_ns();
    double v[VIBID_DRV_MAX_CHANNELS];
    const uint16_t *regs[VIBID_DRV_MAX_CHANNELS];
    size_t nr[VIBID_DRV_MAX_CHANNELS];
    uint16_t first[VIBID_DRV_MAX_CHANNELS];
    for (size_t c = 0; c < m->n; c++) {
        const block *bl = &m->blocks[m->ch_block[c]];
        regs[c] = m->regs[m->ch_block[c]];
        nr[c] = bl->count;
        first[c] = bl->start;
    }
    if (decode_all(m, m->ent, regs, nr, first, v))
        emit_sample(m, t, v);
    else
        gap(m, 1, "snapshot not usable (see the fault before)");
}

/* Groups the channels' registers into read blocks of <= 125 registers per kind. */
static void plan_blocks(mb *m)
{
    size_t order[VIBID_DRV_MAX_CHANNELS];
    for (size_t i = 0; i < m->n; i++)
        order[i] = i;
    for (size_t i = 1; i < m->n; i++) /* insertion sort by (kind, address) */
        for (size_t j = i; j > 0; j--) {
            const vibid_reg_entry *a = &m->ent[order[j - 1]], *b = &m->ent[order[j]];
            if (a->kind < b->kind || (a->kind == b->kind && a->address <= b->address))
                break;
            size_t t = order[j];
            order[j] = order[j - 1];
            order[j - 1] = t;
        }
    m->nblocks = 0;
    for (size_t i = 0; i < m->n; i++) {
        const vibid_reg_entry *e = &m->ent[order[i]];
        unsigned end = e->address + vibid_reg_type_words(e->type); /* exclusive */
        block *cur = m->nblocks ? &m->blocks[m->nblocks - 1] : NULL;
        if (cur && cur->kind == e->kind && end - cur->start <= MAX_REQ) {
            if (end > (unsigned)cur->start + cur->count)
                cur->count = (uint16_t)(end - cur->start);
        } else {
            cur = &m->blocks[m->nblocks++];
            cur->kind = e->kind;
            cur->start = e->address;
            cur->count = (uint16_t)(end - e->address);
        }
        m->ch_block[order[i]] = (int)(m->nblocks - 1);
    }
}

static vibid_drv_status mb_open(vibid_source *src, const void *config, vibid_drv_error *err)
{
    const vibid_source_modbus_config *cfg = config;
    mb *m = calloc(1, sizeof *m);
    if (!m)
        return vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "Modbus source: out of memory");
    src->impl = m;
    m->cfg = *cfg;
    vibid_source_modbus_config *c = &m->cfg;
    if (c->transport == VIBID_MODBUS_TCP) {
        if (!cfg->host || !cfg->host[0] || strlen(cfg->host) >= sizeof m->host)
            return vibid_drv_fail(err, VIBID_DRV_E_ARG, "Modbus TCP: host missing or too long");
        snprintf(m->host, sizeof m->host, "%s", cfg->host);
        if (c->port == 0)
            c->port = 502;
        if (c->port < 1 || c->port > 65535)
            return vibid_drv_fail(err, VIBID_DRV_E_RANGE, "Modbus TCP: port %d outside 1..65535", c->port);
        snprintf(m->where, sizeof m->where, "%s:%d", m->host, c->port);
    } else if (c->transport == VIBID_MODBUS_RTU) {
        if (!cfg->device || !cfg->device[0] || strlen(cfg->device) >= sizeof m->device)
            return vibid_drv_fail(err, VIBID_DRV_E_ARG, "Modbus RTU: serial device missing or too long");
        snprintf(m->device, sizeof m->device, "%s", cfg->device);
        c->baud = c->baud ? c->baud : 19200;
        c->parity = c->parity ? c->parity : 'E';
        c->data_bits = c->data_bits ? c->data_bits : 8;
        c->stop_bits = c->stop_bits ? c->stop_bits : 1;
        if (c->baud < 300 || (c->parity != 'N' && c->parity != 'E' && c->parity != 'O') ||
            (c->data_bits != 7 && c->data_bits != 8) || (c->stop_bits != 1 && c->stop_bits != 2))
            return vibid_drv_fail(err, VIBID_DRV_E_RANGE, "Modbus RTU %s: baud %d parity '%c' %d data / %d stop bits invalid",
                                  m->device, c->baud, c->parity, c->data_bits, c->stop_bits);
        snprintf(m->where, sizeof m->where, "%s@%d", m->device, c->baud);
    } else {
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "Modbus: unknown transport %d", (int)c->transport);
    }
    c->host = m->host;
    c->device = m->device;
    c->unit_id = c->unit_id ? c->unit_id : 1;
    c->response_timeout_s = c->response_timeout_s > 0 ? c->response_timeout_s : 0.5;
    c->backoff_initial_s = c->backoff_initial_s > 0 ? c->backoff_initial_s : 0.1;
    c->backoff_max_s = c->backoff_max_s > 0 ? c->backoff_max_s : 5.0;
    if (c->backoff_max_s < c->backoff_initial_s)
        c->backoff_max_s = c->backoff_initial_s;
    c->max_timeouts = c->max_timeouts ? c->max_timeouts : 3;
    c->fifo_base = c->fifo_base ? c->fifo_base : VIBID_MODBUS_FIFO_DEFAULT_BASE;
    if (c->unit_id < 1 || c->unit_id > 247 || !(c->response_timeout_s < 60) || c->fifo_base > 65535 - HDR_FIXED)
        return vibid_drv_fail(err, VIBID_DRV_E_RANGE, "Modbus %s: unit id %d (1..247), response timeout %g s or FIFO base %u invalid",
                              m->where, c->unit_id, c->response_timeout_s, c->fifo_base);
    if (c->mode == VIBID_MODBUS_SNAPSHOT && !(c->sample_period_s >= 1e-5 && c->sample_period_s <= 3600))
        return vibid_drv_fail(err, VIBID_DRV_E_RANGE, "Modbus %s: snapshot mode needs a sample period in 10 us..1 h, got %g s",
                              m->where, c->sample_period_s);
    if (!cfg->regmap)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "Modbus %s: a register map is required", m->where);
    if (cfg->chanmap.n == 0)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "Modbus %s: empty channel map", m->where);
    src->chanmap = cfg->chanmap;
    m->n = cfg->chanmap.n;
    for (size_t i = 0; i < m->n; i++) {
        const vibid_channel *ch = &cfg->chanmap.ch[i];
        if (ch->source != VIBID_CHAN_REGISTER)
            return vibid_drv_fail(err, VIBID_DRV_E_ARG, "channel '%s' (line %u): a Modbus source needs register = \"...\"",
                                  ch->name, ch->line);
        const vibid_reg_entry *e = vibid_regmap_find(cfg->regmap, ch->ref);
        if (!e)
            return vibid_drv_fail(err, VIBID_DRV_E_NOT_FOUND, "channel '%s' (line %u): register '%s' is not in the register map",
                                  ch->name, ch->line, ch->ref);
        m->ent[i] = *e;
    }
    m->B = c->fifo_base;
    m->h_ns = sec_ns(c->sample_period_s);
    plan_blocks(m);
    if (!rec_queue_init(&m->q, 2 * POLL_SAMPLES + 64))
        return vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "Modbus source: out of memory");
    m->backoff = c->backoff_initial_s;
    /* First connection now: a device that is not there yet, or answers with a FIFO header
     * that does not fit, is retried in read() (faults queued). */
    vibid_drv_status st = try_connect(m, err);
    return st == VIBID_DRV_E_LINK ? VIBID_DRV_OK : st;
}

static vibid_drv_status mb_read_src(vibid_source *src, vibid_record *recs, size_t cap, size_t *n, int timeout_ms,
                                    vibid_drv_error *err)
{
    mb *m = src->impl;
    int64_t limit = wait_limit(timeout_ms);
    size_t k = 0;
    bool acted = false; /* at least one connect attempt, poll or tick per call */
    for (;;) {
        k += rec_queue_hand_out(&m->q, recs + k, cap - k, &m->st, &m->last_count_t);
        if (k > 0) {
            *n = k;
            return VIBID_DRV_OK;
        }
        int64_t now = mono_ns();
        /* The caller's timeout bounds the call, not only its sleeps: a slow peer (every
         * answer just under the response timeout) made one call issue dozens of requests,
         * and SIGTERM waited for all of them. */
        if (acted && now >= limit) {
            *n = 0;
            return VIBID_DRV_E_AGAIN;
        }
        acted = true;
        if (!m->connected) {
            if (now >= m->next_connect) {
                vibid_drv_status st = try_connect(m, err);
                if (st != VIBID_DRV_OK && st != VIBID_DRV_E_LINK)
                    return st;
                continue;
            }
            int64_t until = m->next_connect < limit ? m->next_connect : limit;
            sleep_until_mono(until);
            if (until == limit && mono_ns() >= limit) {
                *n = 0;
                return VIBID_DRV_E_AGAIN;
            }
            continue;
        }
        if (m->cfg.mode == VIBID_MODBUS_FIFO) {
            if (now < m->next_poll) {
                int64_t until = m->next_poll < limit ? m->next_poll : limit;
                sleep_until_mono(until);
                if (mono_ns() < m->next_poll) {
                    *n = 0;
                    return VIBID_DRV_E_AGAIN;
                }
                continue;
            }
            m->next_poll += m->poll_ns;
            if (m->next_poll < now)
                m->next_poll = now + m->poll_ns;
            fifo_poll(m, limit);
            continue;
        }
        /* snapshot: tick k_next is due at t0 + (k_next - k_at_t0) h */
        if (!m->started) {
            m->started = true;
            m->t0_mono = now;
        }
        int64_t deadline = m->t0_mono + (int64_t)m->k_next * m->h_ns;
        if (now < deadline) {
            int64_t until = deadline < limit ? deadline : limit;
            sleep_until_mono(until);
            if (mono_ns() < deadline) {
                *n = 0;
                return VIBID_DRV_E_AGAIN;
            }
            now = mono_ns();
        }
        uint64_t missed = (uint64_t)((now - deadline) / m->h_ns);
        if (missed > 0) {
            m->st.overruns += missed;
            gap(m, missed, "sampling deadlines missed (slow answers or no link)");
        }
        snapshot_tick(m);
    }
}

static void mb_close(vibid_source *src)
{
    mb *m = src->impl;
    if (!m)
        return;
    if (m->ctx) {
        modbus_close(m->ctx);
        modbus_free(m->ctx);
    }
    rec_queue_free(&m->q);
    free(m);
    src->impl = NULL;
}

static void mb_stats(const vibid_source *src, vibid_source_stats *st)
{
    const mb *m = src->impl;
    *st = m->st;
}

const vibid_source_ops vibid_source_modbus_ops = {"modbus", mb_open, mb_read_src, mb_close, mb_stats};
