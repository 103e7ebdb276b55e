/* CAN frames -> samples, with every gap and fault made explicit; see can_assembler.h. */
#include <vibid_drivers/can_assembler.h>

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAX_MSGS 32      /* messages carrying channels */
#define QUEUE_LEN 16     /* records one frame can produce is at most 3 */
#define MAX_UNKNOWN 64   /* distinct unknown ids reported individually */

/* How one signal is taken out of a payload, worked out once at create time instead of
 * per frame. For a little-endian (Intel) signal whose bits lie within the 8 bytes from
 * its first byte, the raw value is one 64-bit load, a shift and a mask; the
 * conversions below repeat vibid_dbc_signal_decode's arithmetic expression for
 * expression, so the values are bit-identical (test_can_assembler checks it against
 * vibid_dbc_signal_decode over random payloads). Every other signal (Motorola, wider
 * spans, big-endian hosts) and every frame shorter than the signal needs takes
 * vibid_dbc_signal_raw / _decode as before (the short-frame fault included). */
typedef enum { X_GENERAL = 0, X_UNSIGNED, X_SIGNED, X_FLOAT32, X_FLOAT64 } extract_kind;
typedef struct extractor {
    const vibid_dbc_signal *sig;
    uint8_t kind;       /* extract_kind */
    uint8_t byte;       /* first byte of the 8 loaded; byte + 8 <= VIBID_CANFD_MAX_DLEN */
    uint8_t shift;      /* start_bit - 8 * byte, < 64 */
    uint8_t min_bytes;  /* sig->min_bytes: shorter frames take the general path */
    uint64_t mask;      /* low `length` bits */
    uint64_t sign_bit;  /* X_SIGNED, length < 64: the sign bit of the raw value, else 0 */
    double factor, offset;
} extractor;

typedef struct involved {
    const vibid_dbc_message *msg;
    int counter_sig;                       /* index in msg->signals, -1 in trigger mode */
    size_t n_ch;
    uint8_t ch_index[VIBID_DRV_MAX_CHANNELS];   /* channel map index */
    uint8_t sig_index[VIBID_DRV_MAX_CHANNELS];  /* signal index in msg */
    extractor x[VIBID_DRV_MAX_CHANNELS];        /* for sig_index[i] */
    extractor counter_x;                        /* for counter_sig (counter mode) */
} involved;

/* 11-bit ids -> index into inv (+1; 0 = not involved): the per-frame lookup is one load. */
#define STD_IDS 2048

struct vibid_can_assembler {
    const vibid_chanmap *map;
    involved inv[MAX_MSGS];
    size_t n_inv;
    uint8_t std_inv[STD_IDS];
    int trigger; /* index into inv of the trigger message, or -1 */
    const vibid_dbc_message *trigger_msg;
    bool counter_mode;
    unsigned counter_bits;
    double period_s;     /* nominal h; 0 = no plausibility check */
    uint32_t slack;      /* missing samples tolerated beyond 2 dt / h */
    /* open sample */
    bool have_current, current_done;
    uint64_t k, cur_raw;
    uint32_t filled; /* bit per involved message */
    uint32_t all_mask;
    int64_t t_ns;
    double values[VIBID_DRV_MAX_CHANNELS];
    /* output queue */
    vibid_record q[QUEUE_LEN];
    size_t q_head, q_len;
    /* unknown ids reported */
    uint32_t unknown[MAX_UNKNOWN];
    size_t n_unknown;
    /* stats */
    vibid_can_assembler_stats st;
    int64_t last_sample_t;
    bool have_last_t;
};

static vibid_record *push_rec(vibid_can_assembler *a, vibid_record_kind kind)
{
    if (a->q_len == QUEUE_LEN) { /* cannot happen when the caller pops after every push */
        a->q_head = (a->q_head + 1) % QUEUE_LEN;
        a->q_len--;
    }
    vibid_record *r = &a->q[(a->q_head + a->q_len++) % QUEUE_LEN];
    r->kind = kind;
    r->fault = VIBID_FAULT_NONE;
    r->index = r->count = 0;
    r->t_ns = 0;
    r->n_values = 0;
    r->text[0] = '\0';
    return r;
}

static void fault(vibid_can_assembler *a, vibid_fault_code code, uint64_t index, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
static void fault(vibid_can_assembler *a, vibid_fault_code code, uint64_t index, const char *fmt, ...)
{
    vibid_record *r = push_rec(a, VIBID_REC_FAULT);
    r->fault = code;
    r->index = index;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(r->text, sizeof r->text, fmt, ap);
    va_end(ap);
}

static void gap(vibid_can_assembler *a, uint64_t first, uint64_t count, const char *why)
{
    vibid_record *r = push_rec(a, VIBID_REC_GAP);
    r->index = first;
    r->count = count;
    snprintf(r->text, sizeof r->text, "%s", why);
    a->st.gaps++;
    a->st.missing_samples += count;
}

static void make_extractor(extractor *x, const vibid_dbc_signal *s)
{
    memset(x, 0, sizeof *x);
    x->sig = s;
    x->factor = s->factor;
    x->offset = s->offset;
    x->min_bytes = s->min_bytes;
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    if (s->byte_order != VIBID_DBC_INTEL)
        return;
    /* Prefer the aligned 64-bit word holding the signal: the parser stores a classic
     * payload as one 8-byte word, and a load that straddles two stores cannot be served
     * from the store buffer (a stall per frame). Else the 8 bytes from its first byte. */
    unsigned byte = 8u * (s->start_bit / 64u), shift = s->start_bit % 64u;
    if (shift + s->length > 64u) {
        byte = s->start_bit / 8u;
        shift = s->start_bit % 8u;
    }
    if (shift + s->length > 64u || byte + 8u > VIBID_CANFD_MAX_DLEN)
        return;
    x->byte = (uint8_t)byte;
    x->shift = (uint8_t)shift;
    x->mask = s->length < 64 ? (UINT64_C(1) << s->length) - 1u : UINT64_MAX;
    if (s->value_type == VIBID_DBC_FLOAT32)
        x->kind = s->length == 32 ? X_FLOAT32 : X_GENERAL;
    else if (s->value_type == VIBID_DBC_FLOAT64)
        x->kind = s->length == 64 ? X_FLOAT64 : X_GENERAL;
    else if (s->is_signed) {
        x->kind = X_SIGNED;
        x->sign_bit = s->length < 64 ? UINT64_C(1) << (s->length - 1) : 0;
    } else
        x->kind = X_UNSIGNED;
#endif
}

/* Raw bits of x's signal; the caller has checked x->kind != X_GENERAL and that the frame
 * holds x->min_bytes bytes (data is the frame's 64-byte array, so the load stays inside). */
static inline uint64_t extract_raw(const extractor *x, const uint8_t *data)
{
    uint64_t v;
    memcpy(&v, data + x->byte, sizeof v);
    return (v >> x->shift) & x->mask;
}

/* vibid_dbc_signal_decode's conversion, expression for expression. */
static inline double extract_value(const extractor *x, const uint8_t *data)
{
    uint64_t raw = extract_raw(x, data);
    double v;
    switch (x->kind) {
    case X_FLOAT32: {
        uint32_t b = (uint32_t)raw;
        float f;
        memcpy(&f, &b, sizeof f);
        v = (double)f;
        break;
    }
    case X_FLOAT64:
        memcpy(&v, &raw, sizeof v);
        break;
    case X_SIGNED: {
        int64_t sv;
        if (raw & x->sign_bit)
            raw |= ~x->mask; /* sign-extend */
        memcpy(&sv, &raw, sizeof sv);
        v = (double)sv;
        break;
    }
    default:
        v = (double)raw;
        break;
    }
    return v * x->factor + x->offset;
}

static int find_inv(vibid_can_assembler *a, const vibid_dbc_message *m)
{
    for (size_t i = 0; i < a->n_inv; i++)
        if (a->inv[i].msg == m)
            return (int)i;
    return -1;
}

vibid_can_assembler *vibid_can_assembler_create(const vibid_dbc *dbc, const vibid_chanmap *map,
                                                vibid_drv_error *err)
{
    if (!dbc || !map || map->n == 0) {
        vibid_drv_fail(err, VIBID_DRV_E_ARG, "can assembler: DBC and a non-empty channel map are needed");
        return NULL;
    }
    vibid_can_assembler *a = calloc(1, sizeof *a);
    if (!a) {
        vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "can assembler: out of memory");
        return NULL;
    }
    a->map = map;
    a->trigger = -1;
    for (size_t c = 0; c < map->n; c++) {
        const vibid_channel *ch = &map->ch[c];
        if (ch->source != VIBID_CHAN_SIGNAL) {
            vibid_drv_fail(err, VIBID_DRV_E_ARG, "channel '%s' (line %u): a CAN source needs signal = \"...\"",
                           ch->name, ch->line);
            goto fail;
        }
        const vibid_dbc_message *found = NULL, *second = NULL;
        const vibid_dbc_signal *sig = vibid_dbc_lookup_signal(dbc, ch->ref, ch->message, &found, &second);
        if (second) {
            vibid_drv_fail(err, VIBID_DRV_E_ARG,
                           "channel '%s' (line %u): signal '%s' is in messages %s and %s; add message = \"...\"",
                           ch->name, ch->line, ch->ref, found->name, second->name);
            goto fail;
        }
        if (!sig) {
            vibid_drv_fail(err, VIBID_DRV_E_NOT_FOUND, "channel '%s' (line %u): no signal '%s'%s%s in the DBC",
                           ch->name, ch->line, ch->ref, ch->message[0] ? " in message " : "", ch->message);
            goto fail;
        }
        if (sig->mux_role == VIBID_DBC_MULTIPLEXED) {
            vibid_drv_fail(err, VIBID_DRV_E_UNSUPPORTED, "channel '%s': multiplexed signal '%s' cannot be a channel",
                           ch->name, sig->name);
            goto fail;
        }
        int ii = find_inv(a, found);
        if (ii < 0) {
            if (a->n_inv == MAX_MSGS) {
                vibid_drv_fail(err, VIBID_DRV_E_RANGE, "channels spread over more than %d messages", MAX_MSGS);
                goto fail;
            }
            ii = (int)a->n_inv++;
            a->inv[ii].msg = found;
            a->inv[ii].counter_sig = -1;
        }
        involved *v = &a->inv[ii];
        v->ch_index[v->n_ch] = (uint8_t)c;
        v->sig_index[v->n_ch] = (uint8_t)(sig - found->signals);
        make_extractor(&v->x[v->n_ch], sig);
        v->n_ch++;
    }
    a->all_mask = a->n_inv == 32 ? 0xFFFFFFFFu : ((1u << a->n_inv) - 1u);
    if (map->counter[0]) {
        a->counter_mode = true;
        for (size_t i = 0; i < a->n_inv; i++) {
            const vibid_dbc_signal *s = vibid_dbc_find_signal(a->inv[i].msg, map->counter);
            if (!s || s->is_signed || s->value_type != VIBID_DBC_INTEGER || s->length > 63) {
                vibid_drv_fail(err, VIBID_DRV_E_NOT_FOUND,
                               "counter '%s': message %s carries channels but no unsigned integer counter of that name",
                               map->counter, a->inv[i].msg->name);
                goto fail;
            }
            if (i > 0 && s->length != a->counter_bits) {
                vibid_drv_fail(err, VIBID_DRV_E_ARG, "counter '%s' has different lengths in different messages",
                               map->counter);
                goto fail;
            }
            a->counter_bits = s->length;
            a->inv[i].counter_sig = (int)(s - a->inv[i].msg->signals);
            make_extractor(&a->inv[i].counter_x, s);
        }
    } else if (map->trigger[0]) {
        a->trigger_msg = vibid_dbc_find_message_by_name(dbc, map->trigger);
        if (!a->trigger_msg) {
            vibid_drv_fail(err, VIBID_DRV_E_NOT_FOUND, "trigger message '%s' is not in the DBC", map->trigger);
            goto fail;
        }
        a->trigger = find_inv(a, a->trigger_msg);
    } else if (a->n_inv == 1) {
        /* One message carries everything: each frame is one sample. */
        a->trigger_msg = a->inv[0].msg;
        a->trigger = 0;
    } else {
        vibid_drv_fail(err, VIBID_DRV_E_ARG,
                       "channels come from %zu messages: set counter = \"<signal>\" or trigger = \"<message>\"",
                       a->n_inv);
        goto fail;
    }
    for (size_t i = 0; i < a->n_inv; i++)
        if (!a->inv[i].msg->extended && a->inv[i].msg->id < STD_IDS)
            a->std_inv[a->inv[i].msg->id] = (uint8_t)(i + 1);
    return a;
fail:
    free(a);
    return NULL;
}

void vibid_can_assembler_destroy(vibid_can_assembler *a) { free(a); }

bool vibid_can_assembler_set_timing(vibid_can_assembler *a, double period_s, uint32_t slack_samples)
{
    if (!a || !(period_s >= 0.0) || !isfinite(period_s))
        return false;
    a->period_s = period_s;
    a->slack = slack_samples ? slack_samples : VIBID_CAN_ASSEMBLER_DEFAULT_SLACK;
    return true;
}

/* true when skipping delta - 1 samples is possible in the time since the open sample
 * began (see can_assembler.h). Frame times going backwards count as no time. */
static bool jump_plausible(const vibid_can_assembler *a, uint64_t delta, int64_t t_ns)
{
    if (!(a->period_s > 0.0) || delta <= 1)
        return true;
    double dt = t_ns > a->t_ns ? (double)(t_ns - a->t_ns) * 1e-9 : 0.0;
    double allowed = (double)a->slack + 2.0 * dt / a->period_s;
    return (double)(delta - 1) <= allowed;
}

static void emit_sample(vibid_can_assembler *a)
{
    vibid_record *r = push_rec(a, VIBID_REC_SAMPLE);
    r->index = a->k;
    r->t_ns = a->t_ns;
    r->n_values = (uint32_t)a->map->n;
    memcpy(r->values, a->values, a->map->n * sizeof(double));
    a->st.samples++;
    a->current_done = true;
    if (a->have_last_t)
        vibid_jitter_add(&a->st.jitter, (double)(a->t_ns - a->last_sample_t) * 1e-9);
    a->last_sample_t = a->t_ns;
    a->have_last_t = true;
}

/* Closes the open sample: nothing if it was emitted, else a one-sample GAP. */
static void close_current(vibid_can_assembler *a)
{
    if (!a->have_current || a->current_done)
        return;
    char why[160];
    int n = snprintf(why, sizeof why, "incomplete sample: missing");
    for (size_t i = 0; i < a->n_inv && n > 0 && (size_t)n < sizeof why; i++)
        if (!(a->filled & (1u << i)))
            n += snprintf(why + n, sizeof why - (size_t)n, " %s", a->inv[i].msg->name);
    a->st.incomplete_samples++;
    gap(a, a->k, 1, why);
    a->current_done = true;
}

static void open_sample(vibid_can_assembler *a, uint64_t k, uint64_t raw, int64_t t)
{
    a->have_current = true;
    a->current_done = false;
    a->k = k;
    a->cur_raw = raw;
    a->filled = 0;
    a->t_ns = t;
}

/* Decodes the channels of one frame into a scratch array; false (with a fault) if
 * any value cannot be used. */
static bool decode_channels(vibid_can_assembler *a, const involved *v, const vibid_can_frame *f,
                            double *out)
{
    for (size_t i = 0; i < v->n_ch; i++) {
        const extractor *x = &v->x[i];
        const vibid_dbc_signal *s = x->sig;
        if (x->kind != X_GENERAL && f->len >= x->min_bytes)
            out[i] = extract_value(x, f->data);
        else if (vibid_dbc_signal_decode(s, f->data, f->len, &out[i]) != VIBID_DRV_OK) {
            a->st.short_frames++;
            fault(a, VIBID_FAULT_SHORT_FRAME, a->k, "%s: %u bytes, signal %s needs %u", v->msg->name,
                  f->len, s->name, s->min_bytes);
            return false;
        }
        if (!isfinite(out[i])) {
            a->st.nonfinite++;
            fault(a, VIBID_FAULT_NONFINITE, a->k, "%s.%s: non-finite value", v->msg->name, s->name);
            return false;
        }
    }
    return true;
}

static void fill(vibid_can_assembler *a, int ii, const double *vals)
{
    const involved *v = &a->inv[ii];
    if (a->filled & (1u << ii)) {
        a->st.duplicates++;
        fault(a, VIBID_FAULT_DUPLICATE, a->k, "duplicate %s for sample %llu (first value kept)", v->msg->name,
              (unsigned long long)a->k);
        return;
    }
    if (a->current_done) {
        a->st.late++;
        fault(a, VIBID_FAULT_LATE, a->k, "%s for sample %llu arrived after the sample was closed",
              v->msg->name, (unsigned long long)a->k);
        return;
    }
    for (size_t i = 0; i < v->n_ch; i++)
        a->values[v->ch_index[i]] = vals[i];
    a->filled |= 1u << ii;
    if (a->filled == a->all_mask)
        emit_sample(a);
}

static void error_frame(vibid_can_assembler *a, const vibid_can_frame *f)
{
    a->st.error_frames++;
    /* Classes from linux/can/error.h: CRTL 0x04 (data[1]: RX/TX overflow 0x01/0x02),
     * BUSOFF 0x40, RESTARTED 0x100. */
    if (f->id & 0x40u)
        a->st.bus_off++;
    if ((f->id & 0x04u) && f->len > 1 && (f->data[1] & 0x03u))
        a->st.ctrl_overflow++;
    if (f->id & 0x100u)
        a->st.restarts++;
    fault(a, VIBID_FAULT_BUS_ERROR, a->k, "CAN error frame class 0x%X%s%s%s on %s", (unsigned)f->id,
          (f->id & 0x40u) ? " bus-off" : "", (f->id & 0x04u) ? " controller" : "",
          (f->id & 0x100u) ? " restarted" : "", f->iface[0] ? f->iface : "bus");
}

void vibid_can_assembler_push(vibid_can_assembler *a, const vibid_can_frame *f)
{
    if (!a || !f)
        return;
    a->st.frames++;
    if (f->flags & VIBID_CAN_F_ERR) {
        error_frame(a, f);
        return;
    }
    if (f->flags & VIBID_CAN_F_RTR)
        return; /* remote requests carry no data; not a fault */
    bool ext = (f->flags & VIBID_CAN_F_EXT) != 0;
    int ii = -1;
    if (!ext && f->id < STD_IDS) {
        ii = (int)a->std_inv[f->id] - 1;
    } else {
        for (size_t i = 0; i < a->n_inv; i++)
            if (a->inv[i].msg->id == f->id && a->inv[i].msg->extended == ext)
                ii = (int)i;
    }
    bool is_trigger = a->trigger_msg && a->trigger_msg->id == f->id && a->trigger_msg->extended == ext;
    if (ii < 0 && !is_trigger) {
        a->st.unknown_ids++;
        uint32_t key = f->id | (ext ? 0x80000000u : 0);
        for (size_t i = 0; i < a->n_unknown; i++)
            if (a->unknown[i] == key)
                return;
        if (a->n_unknown < MAX_UNKNOWN)
            a->unknown[a->n_unknown++] = key;
        fault(a, VIBID_FAULT_UNKNOWN_ID, a->k, "frame id 0x%X%s is not a channel message (reported once)",
              (unsigned)f->id, ext ? " (29-bit)" : "");
        return;
    }
    double vals[VIBID_DRV_MAX_CHANNELS];
    if (a->counter_mode) {
        const involved *v = &a->inv[ii];
        uint64_t raw;
        if (v->counter_x.kind != X_GENERAL && f->len >= v->counter_x.min_bytes)
            raw = extract_raw(&v->counter_x, f->data);
        else if (vibid_dbc_signal_raw(&v->msg->signals[v->counter_sig], f->data, f->len, &raw) != VIBID_DRV_OK) {
            a->st.short_frames++;
            fault(a, VIBID_FAULT_SHORT_FRAME, a->k, "%s: %u bytes, too short for the counter", v->msg->name, f->len);
            return;
        }
        if (!decode_channels(a, v, f, vals))
            return;
        if (!a->have_current) {
            open_sample(a, raw, raw, f->t_ns);
        } else {
            uint64_t mod_mask = (UINT64_C(1) << a->counter_bits) - 1u;
            uint64_t delta = (raw - a->cur_raw) & mod_mask;
            uint64_t half = UINT64_C(1) << (a->counter_bits - 1);
            if (delta != 0 && delta < half && !jump_plausible(a, delta, f->t_ns)) {
                a->st.corrupt_counters++;
                fault(a, VIBID_FAULT_CORRUPT, a->k,
                      "%s: counter %llu jumps %llu samples after %.6f s (at most %.0f possible): corrupt "
                      "counter, frame ignored",
                      v->msg->name, (unsigned long long)raw, (unsigned long long)delta,
                      (double)(f->t_ns > a->t_ns ? f->t_ns - a->t_ns : 0) * 1e-9,
                      1.0 + (double)a->slack +
                          2.0 * (double)(f->t_ns > a->t_ns ? f->t_ns - a->t_ns : 0) * 1e-9 / a->period_s);
                return;
            }
            if (delta != 0 && delta < half) {
                close_current(a);
                if (delta > 1)
                    gap(a, a->k + 1, delta - 1, "counter jump: samples missing");
                open_sample(a, a->k + delta, raw, f->t_ns);
            } else if (delta != 0) {
                a->st.late++;
                fault(a, VIBID_FAULT_LATE, a->k, "%s with counter %llu is older than sample %llu: ignored",
                      v->msg->name, (unsigned long long)raw, (unsigned long long)a->k);
                return;
            }
        }
        fill(a, ii, vals);
        return;
    }
    /* trigger mode */
    if (ii >= 0 && !decode_channels(a, &a->inv[ii], f, vals))
        return;
    if (is_trigger) {
        close_current(a);
        open_sample(a, a->have_current ? a->k + 1 : 0, 0, f->t_ns);
    } else if (!a->have_current) {
        fault(a, VIBID_FAULT_LATE, 0, "%s before the first trigger %s: ignored", a->inv[ii].msg->name,
              a->trigger_msg->name);
        a->st.late++;
        return;
    }
    if (ii >= 0)
        fill(a, ii, vals);
}

void vibid_can_assembler_note_drops(vibid_can_assembler *a, uint64_t dropped, const char *where)
{
    if (!a || dropped == 0)
        return;
    a->st.dropped += dropped;
    vibid_record *r = push_rec(a, VIBID_REC_FAULT);
    r->fault = VIBID_FAULT_DROPPED;
    r->index = a->k;
    r->count = dropped;
    snprintf(r->text, sizeof r->text, "%llu frame(s) dropped before reaching us (%s)",
             (unsigned long long)dropped, where ? where : "kernel");
}

void vibid_can_assembler_finish(vibid_can_assembler *a)
{
    if (a)
        close_current(a);
}

bool vibid_can_assembler_pop(vibid_can_assembler *a, vibid_record *rec)
{
    if (!a || !rec || a->q_len == 0)
        return false;
    vibid_record_copy(rec, &a->q[a->q_head]);
    a->q_head = (a->q_head + 1) % QUEUE_LEN;
    a->q_len--;
    return true;
}

static uint8_t fd_length(uint8_t len)
{
    static const uint8_t ok[] = {8, 12, 16, 20, 24, 32, 48, 64};
    for (size_t i = 0; i < sizeof ok; i++)
        if (len <= ok[i])
            return ok[i];
    return 64;
}

vibid_drv_status vibid_can_assembler_encode(const vibid_can_assembler *a, const vibid_record *rec,
                                            vibid_can_frame *frames, size_t cap, size_t *n, vibid_drv_error *err)
{
    if (!a || !rec || !frames || !n)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "can assembler encode: NULL argument");
    *n = 0;
    if (rec->kind != VIBID_REC_SAMPLE || rec->n_values != a->map->n)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "can assembler encode: not a sample of %zu channels",
                              a->map->n);
    if (cap < a->n_inv)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "can assembler encode: room for %zu frames, %zu needed", cap,
                              a->n_inv);
    for (size_t j = 0; j < a->n_inv; j++) {
        /* the trigger message first: the assembler starts a sample with it */
        size_t i = a->trigger <= 0 ? j : (j == 0 ? (size_t)a->trigger : (j <= (size_t)a->trigger ? j - 1 : j));
        const involved *v = &a->inv[i];
        vibid_can_frame *f = &frames[j];
        memset(f, 0, sizeof *f);
        f->t_ns = rec->t_ns;
        f->id = v->msg->id;
        if (v->msg->extended)
            f->flags |= VIBID_CAN_F_EXT;
        f->len = v->msg->length;
        if (f->len > VIBID_CAN_MAX_DLEN) {
            f->flags |= VIBID_CAN_F_FD;
            f->len = fd_length(f->len);
        }
        if (v->counter_sig >= 0) {
            uint64_t c = a->counter_bits >= 64 ? rec->index : rec->index & ((UINT64_C(1) << a->counter_bits) - 1u);
            vibid_dbc_signal_put_raw(&v->msg->signals[v->counter_sig], f->data, f->len, c);
        }
        for (size_t k = 0; k < v->n_ch; k++) {
            const vibid_dbc_signal *s = &v->msg->signals[v->sig_index[k]];
            double x = rec->values[v->ch_index[k]];
            if (vibid_dbc_signal_encode(s, x, f->data, f->len) != VIBID_DRV_OK)
                return vibid_drv_fail(err, VIBID_DRV_E_RANGE,
                                      "sample %llu: channel '%s' = %.17g does not fit signal %s.%s",
                                      (unsigned long long)rec->index, a->map->ch[v->ch_index[k]].name, x,
                                      v->msg->name, s->name);
        }
    }
    *n = a->n_inv;
    return VIBID_DRV_OK;
}

size_t vibid_can_assembler_ids(const vibid_can_assembler *a, uint32_t *ids, size_t cap)
{
    if (!a)
        return 0;
    size_t n = 0;
    for (size_t i = 0; i < a->n_inv; i++, n++)
        if (ids && n < cap)
            ids[n] = a->inv[i].msg->id | (a->inv[i].msg->extended ? 0x80000000u : 0);
    if (a->trigger_msg && a->trigger < 0) {
        if (ids && n < cap)
            ids[n] = a->trigger_msg->id | (a->trigger_msg->extended ? 0x80000000u : 0);
        n++;
    }
    return n;
}

void vibid_can_assembler_stats_get(const vibid_can_assembler *a, vibid_can_assembler_stats *s)
{
    if (a && s) {
        *s = a->st;
        vibid_jitter_finish(&s->jitter);
    }
}

size_t vibid_can_assembler_pending(const vibid_can_assembler *a) { return a ? a->q_len : 0; }
