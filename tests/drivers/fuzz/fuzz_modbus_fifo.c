/* libFuzzer target: the Modbus source's FIFO reader (drivers/src/source_modbus.c, layout
 * drivers/modbus_fifo_layout.md) driven by crafted register images.
 *
 * This file is the device and the clock of the source:
 *  - it defines the libmodbus functions the source calls (this binary links them instead
 *    of libmodbus) over a fake modbus_t that answers reads from a 65536-register image;
 *  - the drivers sources of this binary are compiled with -Dclock_gettime=vibid_fuzz_clock_gettime
 *    -Dclock_nanosleep=vibid_fuzz_clock_nanosleep (tests/drivers/CMakeLists.txt), so the
 *    source's clocks are a virtual clock that only this harness (and a simulated request
 *    latency or timeout) advances: the source never sleeps for real, a run is
 *    deterministic, and time is one more input. libFuzzer's own clock is untouched.
 *
 * Input: setup bytes (channels and their register types, the source's configuration, the
 * device's FIFO layout, counter, session and record contents), then a script of
 * operations: source reads (timeout 0), clock advances, the device producing samples,
 * restarting (new session, counter 0), flapping its session id, jumping its counter,
 * moving its write slot, zeroing its header (a rebooting device), changing its layout,
 * poking any register, failing requests (timeouts, exceptions, resets, short or torn
 * answers) and connections. Bytes past the end read as 0, which means "valid, default".
 *
 * Invariants (source.h, sample.h, docs/drivers.md, modbus_fifo_layout.md):
 *  - a read returns OK with 1 <= n <= cap, or E_AGAIN with n == 0, or a fatal status with
 *    its text; never E_EOF (a device is no finite stream); with timeout 0 it never sleeps;
 *  - SAMPLE and GAP indices are consecutive from k = 0: every k in exactly one SAMPLE or
 *    GAP record (so strictly increasing, never repeated, never skipped); a GAP has count >= 1;
 *  - a SAMPLE has one value per channel, all finite (NaN/Inf registers are FAULTs:
 *    VIBID_FAULT_NONFINITE, sample.h; docs/drivers.md); a FAULT has a code and a text;
 *  - the source's record counters (samples, gaps, missing_samples, faults) equal what
 *    was delivered;
 *  - requests ask for 1..125 registers inside 0..65535 on a connected context; every
 *    context is freed (none left after close; LeakSanitizer checks the rest). */
#include <errno.h>
#include <math.h>
#include <modbus.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <vibid_drivers/source_modbus.h>

#define CHECK(c) \
    do { \
        if (!(c)) \
            abort(); \
    } while (0)

/* ---- virtual clock ---------------------------------------------------------------- */

static int64_t g_now;                                /* CLOCK_MONOTONIC, ns */
static const int64_t g_epoch = 1700000000000000000LL; /* CLOCK_REALTIME - CLOCK_MONOTONIC */

int vibid_fuzz_clock_gettime(clockid_t id, struct timespec *ts);
int vibid_fuzz_clock_nanosleep(clockid_t id, int flags, const struct timespec *req, struct timespec *rem);

int vibid_fuzz_clock_gettime(clockid_t id, struct timespec *ts)
{
    int64_t t = g_now + (id == CLOCK_REALTIME ? g_epoch : 0);
    ts->tv_sec = (time_t)(t / 1000000000);
    ts->tv_nsec = (long)(t % 1000000000);
    return 0;
}

/* Every read is made with timeout 0: the source may "sleep" only until a time that has
 * already passed. A sleep that would wait is a read blocking longer than its timeout. */
int vibid_fuzz_clock_nanosleep(clockid_t id, int flags, const struct timespec *req, struct timespec *rem)
{
    (void)rem;
    int64_t t = (int64_t)req->tv_sec * 1000000000 + req->tv_nsec;
    int64_t target = flags & TIMER_ABSTIME ? t - (id == CLOCK_REALTIME ? g_epoch : 0) : g_now + t;
    CHECK(target <= g_now);
    return 0;
}

/* ---- input ------------------------------------------------------------------------ */

typedef struct rd {
    const uint8_t *p;
    size_t n;
} rd;

static unsigned u8(rd *r)
{
    if (!r->n)
        return 0;
    r->n--;
    return *r->p++;
}
static unsigned u16(rd *r)
{
    unsigned a = u8(r);
    return a << 8 | u8(r);
}
static uint32_t u32(rd *r)
{
    uint32_t a = u16(r);
    return a << 16 | u16(r);
}

/* ---- the device ------------------------------------------------------------------- */

#define NREG 65536u

static struct dev {
    uint16_t hold[NREG], input[NREG];
    bool snapshot;             /* the client polls current values, not the FIFO */
    unsigned B, C, W, K, D;    /* the layout the device writes with */
    uint32_t period, S, ws;
    uint16_t session;
    unsigned value_mode;
    uint32_t seed;
} dev;

static vibid_reg_entry g_ent[VIBID_DRV_MAX_CHANNELS];
static size_t g_nch;

static void put(uint64_t addr, uint16_t v)
{
    if (addr < NREG)
        dev.hold[addr] = v;
}

static void write_header(void)
{
    put(dev.B + 0, VIBID_MODBUS_FIFO_MAGIC);
    put(dev.B + 1, VIBID_MODBUS_FIFO_VERSION);
    put(dev.B + 2, (uint16_t)dev.C);
    put(dev.B + 3, (uint16_t)dev.W);
    put(dev.B + 4, (uint16_t)dev.K);
    put(dev.B + 5, (uint16_t)dev.D);
    put(dev.B + 6, (uint16_t)(dev.period >> 16));
    put(dev.B + 7, (uint16_t)dev.period);
    put(dev.B + 8, (uint16_t)(dev.S >> 16));
    put(dev.B + 9, (uint16_t)dev.S);
    put(dev.B + 10, (uint16_t)dev.ws);
    put(dev.B + 11, dev.session);
    for (unsigned i = 12; i < 16; i++)
        put(dev.B + i, 0);
    for (size_t c = 0; c < g_nch; c++)
        put(dev.B + 16 + c, (uint16_t)((unsigned)g_ent[c].order << 8 | (unsigned)g_ent[c].type));
}

static void write_counter(void)
{
    put(dev.B + 8, (uint16_t)(dev.S >> 16));
    put(dev.B + 9, (uint16_t)dev.S);
    put(dev.B + 10, (uint16_t)dev.ws);
    put(dev.B + 11, dev.session);
}

static uint32_t mix(uint32_t x)
{
    x ^= x >> 16;
    x *= 0x7feb352dU;
    x ^= x >> 15;
    x *= 0x846ca68bU;
    x ^= x >> 16;
    return x;
}

/* Registers of channel c for sample s, in its type and byte order. */
static void encode_value(size_t c, uint32_t s, uint16_t *w)
{
    unsigned nw = vibid_reg_type_words(g_ent[c].type);
    switch (dev.value_mode) {
    case 0: { /* a plausible signal, encoded as the register map says */
        double v = (double)((int)((s * 7u + (uint32_t)c * 13u) % 2001u) - 1000) * 0.25;
        if (vibid_reg_encode(&g_ent[c], v, w) != VIBID_DRV_OK)
            memset(w, 0, nw * sizeof *w);
        break;
    }
    case 1: /* any bit pattern: NaN, Inf, huge, denormal, ... */
        for (unsigned i = 0; i < nw; i++)
            w[i] = (uint16_t)mix(dev.seed ^ (s * 0x9E3779B9u) ^ (uint32_t)(c * 4 + i) * 0x85EBCA6Bu);
        break;
    case 2:
        for (unsigned i = 0; i < nw; i++)
            w[i] = 0xFFFF; /* NaN for the float types */
        break;
    default:
        for (unsigned i = 0; i < nw; i++)
            w[i] = i == 0 ? 0x7F80 : 0x0000; /* +Inf as FLOAT32 ABCD */
        break;
    }
}

/* The device writes n new samples (server rule 1). Only the last K can still be in the
 * ring, so older ones are counted without being written. */
static void produce(uint64_t n)
{
    if (dev.K == 0)
        return;
    if (n > dev.K) {
        uint64_t skip = n - dev.K;
        dev.S += (uint32_t)skip;
        dev.ws = (uint32_t)((dev.ws + skip % dev.K) % dev.K);
        n = dev.K;
    }
    for (uint64_t i = 0; i < n; i++) {
        uint64_t base = (uint64_t)dev.B + dev.D + (uint64_t)(dev.ws % dev.K) * dev.W;
        put(base, (uint16_t)dev.S);
        unsigned off = 1;
        for (size_t c = 0; c < g_nch; c++) {
            uint16_t w[4];
            encode_value(c, dev.S, w);
            unsigned nw = vibid_reg_type_words(g_ent[c].type);
            for (unsigned j = 0; j < nw; j++)
                put(base + off + j, w[j]);
            off += nw;
        }
        dev.S++;
        dev.ws = (dev.ws + 1) % dev.K;
    }
    if (dev.snapshot) /* current values at the register map's addresses */
        for (size_t c = 0; c < g_nch; c++) {
            uint16_t w[4];
            encode_value(c, dev.S, w);
            uint16_t *img = g_ent[c].kind == VIBID_REG_INPUT ? dev.input : dev.hold;
            for (unsigned j = 0; j < vibid_reg_type_words(g_ent[c].type); j++)
                img[(g_ent[c].address + j) % NREG] = w[j];
        }
    write_counter();
}

/* ---- libmodbus, as far as the source uses it --------------------------------------- */

struct _modbus {
    bool connected;
    int64_t response_ns;
};

enum { B_OK, B_TIMEOUT, B_EXCEPTION, B_RESET, B_BADDATA, B_SHORT, B_TORN, B_KINDS };
static struct {
    unsigned char kind, arg;
} g_behav[64];
static unsigned g_nbehav, g_behav_head;
static unsigned g_fail_new, g_fail_connect;
static int64_t g_latency;
static int g_live_ctx;

static modbus_t *new_ctx(void)
{
    if (g_fail_new) {
        g_fail_new--;
        errno = ENOMEM;
        return NULL;
    }
    modbus_t *ctx = calloc(1, sizeof *ctx);
    CHECK(ctx);
    ctx->response_ns = 500000000; /* libmodbus' default */
    g_live_ctx++;
    return ctx;
}

modbus_t *modbus_new_tcp(const char *ip, int port)
{
    CHECK(ip && ip[0] && port >= 1 && port <= 65535);
    return new_ctx();
}

modbus_t *modbus_new_rtu(const char *device, int baud, char parity, int data_bit, int stop_bit)
{
    CHECK(device && device[0] && baud > 0);
    (void)parity, (void)data_bit, (void)stop_bit;
    return new_ctx();
}

int modbus_set_slave(modbus_t *ctx, int slave)
{
    CHECK(ctx);
    (void)slave;
    return 0;
}

/* libmodbus 3.1 refuses 0 s 0 us and more than 999999 us (EINVAL) and keeps the old value. */
int modbus_set_response_timeout(modbus_t *ctx, uint32_t to_sec, uint32_t to_usec)
{
    CHECK(ctx);
    if ((to_sec == 0 && to_usec == 0) || to_usec > 999999) {
        errno = EINVAL;
        return -1;
    }
    ctx->response_ns = (int64_t)to_sec * 1000000000 + (int64_t)to_usec * 1000;
    return 0;
}

int modbus_set_byte_timeout(modbus_t *ctx, uint32_t to_sec, uint32_t to_usec)
{
    CHECK(ctx);
    (void)to_sec;
    if (to_usec > 999999) {
        errno = EINVAL;
        return -1;
    }
    return 0;
}

int modbus_connect(modbus_t *ctx)
{
    CHECK(ctx && !ctx->connected);
    g_now += g_latency;
    if (g_fail_connect) {
        g_fail_connect--;
        errno = ECONNREFUSED;
        return -1;
    }
    ctx->connected = true;
    return 0;
}

void modbus_close(modbus_t *ctx)
{
    CHECK(ctx);
    ctx->connected = false;
}

void modbus_free(modbus_t *ctx)
{
    if (!ctx)
        return;
    g_live_ctx--;
    free(ctx);
}

int modbus_flush(modbus_t *ctx)
{
    CHECK(ctx);
    return 0;
}

const char *modbus_strerror(int errnum)
{
    switch (errnum) {
    case EMBXILADD: return "Illegal data address";
    case EMBXSBUSY: return "Slave device or server is busy";
    case EMBBADDATA: return "Invalid data";
    default: return strerror(errnum);
    }
}

static int fake_read(modbus_t *ctx, int addr, int nb, uint16_t *dest, const uint16_t *img)
{
    CHECK(ctx && ctx->connected && dest);
    CHECK(nb >= 1 && nb <= MODBUS_MAX_READ_REGISTERS); /* one Modbus request */
    CHECK(addr >= 0 && (unsigned)addr + (unsigned)nb <= NREG);
    g_now += g_latency;
    unsigned kind = B_OK, arg = 0;
    if (g_nbehav) {
        kind = g_behav[g_behav_head].kind;
        arg = g_behav[g_behav_head].arg;
        g_behav_head = (g_behav_head + 1) % 64;
        g_nbehav--;
    }
    switch (kind) {
    case B_TIMEOUT:
        g_now += ctx->response_ns;
        errno = ETIMEDOUT;
        return -1;
    case B_EXCEPTION:
        errno = arg & 1 ? EMBXSBUSY : EMBXILADD;
        return -1;
    case B_RESET:
        errno = arg & 1 ? EPIPE : ECONNRESET;
        return -1;
    case B_BADDATA:
        errno = EMBBADDATA;
        return -1;
    case B_SHORT:
        memcpy(dest, img + addr, (size_t)(nb - 1) * sizeof *dest);
        return nb - 1 - (int)(arg % (unsigned)nb);
    case B_TORN: /* the device writes while it answers: part old, part new */
        memcpy(dest, img + addr, (size_t)nb * sizeof *dest);
        produce(1 + arg);
        memcpy(dest + nb / 2, img + addr + nb / 2, (size_t)(nb - nb / 2) * sizeof *dest);
        return nb;
    default:
        memcpy(dest, img + addr, (size_t)nb * sizeof *dest);
        return nb;
    }
}

int modbus_read_registers(modbus_t *ctx, int addr, int nb, uint16_t *dest)
{
    return fake_read(ctx, addr, nb, dest, dev.hold);
}

int modbus_read_input_registers(modbus_t *ctx, int addr, int nb, uint16_t *dest)
{
    return fake_read(ctx, addr, nb, dest, dev.input);
}

/* ---- the client side: reads and their invariants ---------------------------------- */

static vibid_record g_recs[256];
static int g_trace = -1; /* VIBID_FUZZ_TRACE=1 in the environment: print every record */

typedef struct tally {
    uint64_t next_k, samples, gaps, missing, faults;
    bool dead; /* a fatal status was returned */
} tally;

static void read_once(vibid_source *src, size_t cap, tally *t)
{
    size_t n = 12345;
    vibid_drv_error err;
    memset(&err, 0, sizeof err);
    vibid_drv_status st = vibid_source_read(src, g_recs, cap, &n, 0, &err);
    if (st == VIBID_DRV_E_AGAIN) {
        CHECK(n == 0);
    } else if (st == VIBID_DRV_OK) {
        CHECK(n >= 1 && n <= cap);
    } else {
        CHECK(st != VIBID_DRV_E_EOF && err.text[0] != '\0');
        t->dead = true;
        return;
    }
    for (size_t i = 0; i < n; i++) {
        const vibid_record *r = &g_recs[i];
        if (g_trace)
            fprintf(stderr, "t=%.6f s %s k=%llu count=%llu %s%s%.9g\n", (double)g_now * 1e-9,
                    r->kind == VIBID_REC_SAMPLE ? "SAMPLE" : r->kind == VIBID_REC_GAP ? "GAP" : "FAULT",
                    (unsigned long long)r->index, (unsigned long long)r->count, r->text,
                    r->kind == VIBID_REC_SAMPLE ? "v0=" : "", r->kind == VIBID_REC_SAMPLE ? r->values[0] : 0.0);
        switch (r->kind) {
        case VIBID_REC_SAMPLE:
            CHECK(r->index == t->next_k);
            CHECK(r->n_values == g_nch);
            for (size_t c = 0; c < g_nch; c++)
                CHECK(isfinite(r->values[c]));
            t->next_k++;
            t->samples++;
            break;
        case VIBID_REC_GAP:
            CHECK(r->index == t->next_k && r->count >= 1);
            CHECK(t->next_k + r->count > t->next_k); /* no wrap-around of k */
            t->next_k += r->count;
            t->gaps++;
            t->missing += r->count;
            break;
        case VIBID_REC_FAULT:
            CHECK(r->fault != VIBID_FAULT_NONE && r->text[0] != '\0');
            t->faults++;
            break;
        default:
            abort();
        }
    }
    vibid_source_stats s;
    vibid_source_stats_get(src, &s);
    CHECK(s.samples == t->samples && s.gaps == t->gaps && s.missing_samples == t->missing &&
          s.faults == t->faults);
}

/* ---- setup and script ------------------------------------------------------------- */

static const double k_scales[8] = {1.0, 0.001, -2.5, 1e300, 1e-300, 0.5, 100.0, -1.0};
static const double k_offsets[4] = {0.0, 1.5, -1e300, 1e300};
static const double k_polls[6] = {0.0, 1e-9, 1e-3, 0.02, 1.0, 10.0};
static const double k_resp[4] = {0.0, 0.001, 0.2, 5.0};
static const double k_back_init[4] = {0.0, 0.001, 0.1, 2.0};
static const double k_back_max[4] = {0.0, 0.001, 1.0, 3600.0};
static const double k_snap_h[4] = {1e-3, 1e-5, 0.5, 3600.0};
static const uint32_t k_periods[7] = {1000000, 100000, 1, 0xFFFFFFFFu, 20000000, 1000, 50000};
static const int64_t k_dt[8] = {0, 1000, 100000, 1000000, 10000000, 100000000, 1000000000, 100000000000};
static const int64_t k_latency[4] = {0, 10000, 5000000, 300000000};

static int64_t delta_t(rd *in)
{
    unsigned b = u8(in);
    return k_dt[b & 7] * (int64_t)(1 + (b >> 3));
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    rd in = {data, size};
    if (g_trace < 0) {
        const char *e = getenv("VIBID_FUZZ_TRACE");
        g_trace = e && *e && *e != '0';
    }
    memset(&dev, 0, sizeof dev);
    memset(g_ent, 0, sizeof g_ent);
    g_now = 1000000000000LL; /* 1000 s after boot */
    g_nbehav = g_behav_head = 0;
    g_fail_new = g_fail_connect = 0;
    g_latency = 0;
    g_live_ctx = 0;

    /* source configuration */
    unsigned flags = u8(&in);
    vibid_source_modbus_config cfg;
    memset(&cfg, 0, sizeof cfg);
    cfg.transport = flags & 1 ? VIBID_MODBUS_RTU : VIBID_MODBUS_TCP;
    cfg.host = "192.0.2.1";
    cfg.port = 1502;
    cfg.device = "/dev/ttyFUZZ0";
    cfg.baud = flags & 1 ? 115200 : 0;
    dev.snapshot = (flags & 0x0E) == 0x0E;
    cfg.mode = dev.snapshot ? VIBID_MODBUS_SNAPSHOT : VIBID_MODBUS_FIFO;
    g_nch = 1 + u8(&in) % VIBID_DRV_MAX_CHANNELS;
    static vibid_regmap map;
    map.n = g_nch;
    map.entries = g_ent;
    cfg.chanmap.n = g_nch;
    for (size_t c = 0; c < g_nch; c++) {
        unsigned t = u8(&in), s = u8(&in), a = u16(&in);
        vibid_reg_entry *e = &g_ent[c];
        snprintf(e->name, sizeof e->name, "r%zu", c);
        e->type = (vibid_reg_type)((t + 4) % 6); /* 0: FLOAT32 */
        e->order = (vibid_reg_order)((t / 6) % 4);
        e->kind = s & 0x20 ? VIBID_REG_INPUT : VIBID_REG_HOLDING;
        e->scale = k_scales[s & 7];
        e->offset = k_offsets[(s >> 3) & 3];
        unsigned nw = vibid_reg_type_words(e->type);
        e->address = (uint16_t)(a > NREG - nw ? NREG - nw : a);
        e->line = (unsigned)c + 1;
        vibid_channel *ch = &cfg.chanmap.ch[c];
        snprintf(ch->name, sizeof ch->name, "ch%zu", c);
        snprintf(ch->ref, sizeof ch->ref, "%s", e->name);
        ch->source = VIBID_CHAN_REGISTER;
        ch->line = (unsigned)c + 1;
    }
    cfg.regmap = &map;
    if (flags & 0x10)
        cfg.fifo_base = u16(&in); /* may be invalid: open refuses it */
    if (flags & 0x20)
        cfg.poll_period_s = k_polls[u8(&in) % 6];
    if (flags & 0x80) {
        unsigned l = u8(&in);
        cfg.response_timeout_s = k_resp[l & 3];
        cfg.backoff_initial_s = k_back_init[(l >> 2) & 3];
        cfg.backoff_max_s = k_back_max[(l >> 4) & 3];
        cfg.max_timeouts = l >> 6;
    }
    size_t cap = 1 + u8(&in);

    /* the device: layout, counter, session, history */
    dev.B = cfg.fifo_base ? cfg.fifo_base : VIBID_MODBUS_FIFO_DEFAULT_BASE;
    dev.C = (unsigned)g_nch;
    dev.W = 1;
    for (size_t c = 0; c < g_nch; c++)
        dev.W += vibid_reg_type_words(g_ent[c].type);
    unsigned k16 = u16(&in);
    dev.K = k16 ? 2 + k16 % 32766 : 1000;
    unsigned p = u8(&in) % 8;
    dev.period = p < 7 ? k_periods[p] : u32(&in);
    unsigned d = u8(&in);
    unsigned dmin = 16 + dev.C > 64 ? 16 + dev.C : 64;
    dev.D = d < 250 ? dmin + d : 16 + dev.C - (d - 249); /* the last ones too small */
    uint32_t S0 = u32(&in);
    dev.session = (uint16_t)u16(&in);
    dev.value_mode = u8(&in) % 4;
    dev.seed = u32(&in);
    unsigned h = u8(&in);
    if (dev.snapshot)
        cfg.sample_period_s = k_snap_h[h & 3];
    else if (flags & 0x40) /* the expected period: the device's, or not quite */
        cfg.sample_period_s = (double)dev.period * 1e-9 * (h & 1 ? 1.0 + 1e-6 : 1.0);
    uint32_t hist = S0 < dev.K ? S0 : dev.K;
    dev.S = S0 - hist;
    dev.ws = (uint32_t)(((uint64_t)S0 % dev.K + dev.K - hist % dev.K) % dev.K);
    write_header();
    produce(hist);

    vibid_drv_error err;
    memset(&err, 0, sizeof err);
    vibid_source *src = vibid_source_open(&vibid_source_modbus_ops, &cfg, &err);
    if (!src) {
        CHECK(err.text[0] != '\0');
        CHECK(g_live_ctx == 0);
        return 0;
    }
    CHECK(vibid_source_channels(src)->n == g_nch);

    tally t;
    memset(&t, 0, sizeof t);
    for (unsigned step = 0; step < 256 && in.n > 0 && !t.dead; step++) {
        unsigned op = u8(&in) % 20;
        switch (op) {
        case 6:
        case 7: /* time passes, the device does not write (stalled, or snapshot only) */
            g_now += delta_t(&in);
            break;
        case 8:
        case 9: { /* time passes and the device writes a sample every period */
            int64_t dt = delta_t(&in);
            g_now += dt;
            produce(dev.period ? (uint64_t)dt / dev.period : 0);
            break;
        }
        case 10:
            produce(u16(&in));
            break;
        case 11: /* restart: new session, counter and write slot 0 (server rule 3) */
            dev.session = (uint16_t)u16(&in);
            dev.S = 0;
            dev.ws = 0;
            write_header();
            break;
        case 12: /* the session id alone changes (flapping) */
            dev.session = (uint16_t)u16(&in);
            write_counter();
            break;
        case 13: { /* the counter jumps, with or without the write slot */
            unsigned m = u8(&in);
            uint32_t v = u32(&in);
            uint32_t old = dev.S;
            dev.S = m & 1 ? dev.S + v : v;
            if ((m & 2) && dev.K)
                dev.ws = (uint32_t)((dev.ws + (uint64_t)(uint32_t)(dev.S - old)) % dev.K);
            write_counter();
            break;
        }
        case 14: /* write_slot register alone (may be >= K) */
            put(dev.B + 10, (uint16_t)u16(&in));
            break;
        case 15: /* a rebooting device reads zeros; or the header comes back */
            if (u8(&in) & 1) {
                write_header();
            } else {
                for (unsigned i = 0; i < 16 + dev.C; i++)
                    put(dev.B + i, 0);
            }
            break;
        case 16: { /* any register of the header or ring, or anywhere */
            unsigned m = u8(&in);
            unsigned a = u16(&in);
            uint16_t v = (uint16_t)u16(&in);
            uint64_t span = 16u + dev.D + (uint64_t)dev.K * dev.W;
            uint64_t addr = m & 1 ? a : dev.B + a % span;
            if (m & 2)
                dev.input[addr % NREG] = v;
            else
                put(addr, v);
            break;
        }
        case 17: { /* the device is reconfigured: capacity, data offset or period */
            unsigned m = u8(&in);
            unsigned v = u16(&in);
            if ((m & 3) == 0)
                dev.K = v;
            else if ((m & 3) == 1)
                dev.D = v;
            else
                dev.period = (m & 3) == 2 ? (uint32_t)v : (uint32_t)v << 16 | v;
            if (dev.K)
                dev.ws %= dev.K;
            else
                dev.ws = 0;
            write_header();
            break;
        }
        case 18: { /* the next requests fail, or are torn */
            unsigned m = u8(&in);
            unsigned cnt = 1 + (m >> 5);
            for (unsigned i = 0; i < cnt && g_nbehav < 64; i++) {
                unsigned slot = (g_behav_head + g_nbehav++) % 64;
                g_behav[slot].kind = (unsigned char)(1 + (m & 31) % (B_KINDS - 1));
                g_behav[slot].arg = (unsigned char)u8(&in);
            }
            break;
        }
        case 19: { /* connections fail; requests take time */
            unsigned m = u8(&in);
            g_fail_connect += m & 3;
            g_fail_new += (m >> 2) & 1;
            g_latency = k_latency[(m >> 3) & 3];
            break;
        }
        default: /* 0..5 */
            read_once(src, cap, &t);
            break;
        }
    }
    for (int i = 0; i < 2 && !t.dead; i++)
        read_once(src, cap, &t);
    vibid_source_close(src);
    CHECK(g_live_ctx == 0);
    return 0;
}
