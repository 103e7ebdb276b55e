/* sim/sim_can.c: see sim_can.h. */
#include "sim_can.h"

#include <math.h>
#include <string.h>

static unsigned type_bits(sim_can_type t) { return t == SIM_CAN_INT16 ? 16u : 32u; }

static void sanitize(const char *in, char *out, size_t cap)
{
    size_t i = 0;
    for (; in[i] && i + 1 < cap; i++) {
        char c = in[i];
        int ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_';
        out[i] = ok ? c : '_';
    }
    out[i] = 0;
    if (out[0] >= '0' && out[0] <= '9' && i + 1 < cap) {
        memmove(out + 1, out, i + 1);
        out[0] = '_';
    }
}

static uint8_t fd_len(unsigned bytes)
{
    static const uint8_t lens[] = {0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64};
    for (size_t i = 0; i < sizeof lens; i++)
        if (lens[i] >= bytes) return lens[i];
    return 0;
}

int sim_can_layout_build(const vibid_stand *stand, const sim_config *cfg, sim_can_layout *lay, char *err, size_t errlen)
{
    memset(lay, 0, sizeof *lay);
    const vibid_model *m = vibid_stand_model(stand);
    vibid_model_dims d;
    vibid_model_get_dims(m, &d);
    lay->fd = cfg->can_fd;
    lay->extended = cfg->can_extended;
    lay->n_covariates = cfg->n_covariates;
    sanitize(vibid_stand_name(stand), lay->stand_name, sizeof lay->stand_name);
    size_t n_out = d.n_channels + cfg->n_covariates; /* the covariates' signals follow the channels */
    for (size_t c = 0; c < n_out; c++) {
        const char *nm = c < d.n_channels ? vibid_stand_channel_name(stand, c) : cfg->covariates[c - d.n_channels].name;
        if (c >= d.n_channels)
            snprintf(lay->sig_unit[c], sizeof lay->sig_unit[c], "%s", cfg->covariates[c - d.n_channels].unit);
        sanitize(nm ? nm : "ch", lay->sig_name[c], sizeof lay->sig_name[c]);
        if (strcmp(lay->sig_name[c], "SampleCounter") == 0) {
            snprintf(err, errlen, "channel '%s': the name SampleCounter is reserved for the sample counter", nm);
            return -1;
        }
        for (size_t j = 0; j < c; j++)
            if (strcmp(lay->sig_name[c], lay->sig_name[j]) == 0) {
                snprintf(err, errlen, "channels '%s' and '%s' give the same DBC signal name '%s'",
                         j < d.n_channels ? vibid_stand_channel_name(stand, j) : cfg->covariates[j - d.n_channels].name,
                         nm, lay->sig_name[c]);
                return -1;
            }
    }
    unsigned cap_bits = lay->fd ? 64u * 8u : 64u;
    uint32_t idmax = lay->extended ? 0x1FFFFFFFu : 0x7FFu;
    sim_can_msg *cur = NULL;
    unsigned used = 0;
    for (size_t c = 0; c < n_out; c++) {
        unsigned bits = type_bits(cfg->can_sig[c].type);
        if (!cur || used + bits > cap_bits) {
            if (lay->fd && cur) {
                snprintf(err, errlen, "%zu channels%s do not fit one CAN FD frame of 64 bytes (2 bytes counter); use int16 signals or classic CAN",
                         n_out, cfg->n_covariates ? " (covariates included)" : "");
                return -1;
            }
            cur = &lay->msg[lay->n_msg];
            cur->id = cfg->can_id + (uint32_t)lay->n_msg;
            if (cur->id > idmax) {
                snprintf(err, errlen, "frame id 0x%X beyond 0x%X (simulation.can.id too high for %zu frames)", cur->id, idmax, lay->n_msg + 1);
                return -1;
            }
            lay->n_msg++;
            used = 16;
        }
        sim_can_sig *s = &cur->sig[cur->n_sig++];
        s->channel = c;
        s->start_bit = used;
        s->type = cfg->can_sig[c].type;
        s->scale = cfg->can_sig[c].scale;
        used += bits;
        cur->len = lay->fd ? fd_len((used + 7) / 8) : 8;
    }
    if (lay->n_msg == 0) {
        snprintf(err, errlen, "the stand has no channels to send");
        return -1;
    }
    return 0;
}

static void put_bits(uint8_t *data, unsigned start, unsigned bits, uint64_t v)
{
    for (unsigned b = 0; b < bits; b += 8) data[(start + b) / 8] = (uint8_t)(v >> b);
}

void sim_can_encode(const sim_can_layout *lay, uint64_t k, const double *values, vibid_can_frame *frames, uint64_t *saturated)
{
    for (size_t i = 0; i < lay->n_msg; i++) {
        const sim_can_msg *msg = &lay->msg[i];
        vibid_can_frame *f = &frames[i];
        memset(f->data, 0, sizeof f->data);
        f->id = msg->id;
        f->flags = (uint8_t)((lay->extended ? VIBID_CAN_F_EXT : 0) | (lay->fd ? VIBID_CAN_F_FD : 0));
        f->fd_flags = lay->fd ? VIBID_CANFD_BRS : 0;
        f->len = msg->len;
        put_bits(f->data, 0, 16, k & 0xFFFFu);
        for (size_t j = 0; j < msg->n_sig; j++) {
            const sim_can_sig *s = &msg->sig[j];
            double v = values[s->channel];
            if (s->type == SIM_CAN_FLOAT32) {
                float fv = (float)v;
                uint32_t u;
                memcpy(&u, &fv, 4);
                put_bits(f->data, s->start_bit, 32, u);
                continue;
            }
            double lim = s->type == SIM_CAN_INT16 ? 32767.0 : 2147483647.0;
            double raw = isnan(v) ? 0.0 : nearbyint(v / s->scale);
            if (raw > lim || raw < -lim - 1.0) {
                raw = raw > 0 ? lim : -lim - 1.0;
                if (saturated) (*saturated)++;
            }
            int64_t ir = (int64_t)raw;
            put_bits(f->data, s->start_bit, type_bits(s->type), (uint64_t)ir);
        }
    }
}

int sim_can_write_dbc(const sim_can_layout *lay, FILE *f)
{
    fprintf(f, "VERSION \"\"\n\n\nNS_ :\n    CM_\n    BA_DEF_\n    BA_\n    BA_DEF_DEF_\n    SIG_VALTYPE_\n\nBS_:\n\nBU_: VibidSim\n\n");
    for (size_t i = 0; i < lay->n_msg; i++) {
        const sim_can_msg *m = &lay->msg[i];
        uint32_t id = m->id | (lay->extended ? 0x80000000u : 0u);
        fprintf(f, "BO_ %u %s_%zu: %u VibidSim\n", id, lay->stand_name, i, (unsigned)m->len);
        fprintf(f, " SG_ SampleCounter : 0|16@1+ (1,0) [0|65535] \"\" Vector__XXX\n");
        for (size_t j = 0; j < m->n_sig; j++) {
            const sim_can_sig *s = &m->sig[j];
            if (s->type == SIM_CAN_FLOAT32) {
                fprintf(f, " SG_ %s : %u|32@1- (1,0) [0|0] \"%s\" Vector__XXX\n", lay->sig_name[s->channel], s->start_bit,
                        lay->sig_unit[s->channel]);
            } else {
                unsigned bits = s->type == SIM_CAN_INT16 ? 16u : 32u;
                double lim = s->type == SIM_CAN_INT16 ? 32768.0 : 2147483648.0;
                fprintf(f, " SG_ %s : %u|%u@1- (%.17g,0) [%.17g|%.17g] \"%s\" Vector__XXX\n", lay->sig_name[s->channel],
                        s->start_bit, bits, s->scale, -lim * s->scale, (lim - 1.0) * s->scale, lay->sig_unit[s->channel]);
            }
        }
        fprintf(f, "\n");
    }
    fprintf(f, "\nCM_ \"Frames of vibid-sim (stand %s): SampleCounter = sample index mod 65536 in every frame; "
               "channels in the stand's order%s. Written by vibid-sim --write-dbc.\";\n", lay->stand_name,
            lay->n_covariates ? ", then the covariates (simulation.covariates)" : "");
    if (lay->fd) {
        fprintf(f, "BA_DEF_ BO_ \"VFrameFormat\" ENUM \"StandardCAN\",\"ExtendedCAN\",\"reserved\",\"J1939PG\",\"reserved\","
                   "\"reserved\",\"reserved\",\"reserved\",\"reserved\",\"reserved\",\"reserved\",\"reserved\",\"reserved\","
                   "\"reserved\",\"StandardCAN_FD\",\"ExtendedCAN_FD\";\n");
        fprintf(f, "BA_DEF_DEF_ \"VFrameFormat\" \"StandardCAN\";\n");
        for (size_t i = 0; i < lay->n_msg; i++)
            fprintf(f, "BA_ \"VFrameFormat\" BO_ %u %d;\n", lay->msg[i].id | (lay->extended ? 0x80000000u : 0u),
                    lay->extended ? 15 : 14);
    }
    for (size_t i = 0; i < lay->n_msg; i++)
        for (size_t j = 0; j < lay->msg[i].n_sig; j++)
            if (lay->msg[i].sig[j].type == SIM_CAN_FLOAT32)
                fprintf(f, "SIG_VALTYPE_ %u %s : 1;\n", lay->msg[i].id | (lay->extended ? 0x80000000u : 0u),
                        lay->sig_name[lay->msg[i].sig[j].channel]);
    return ferror(f) ? -1 : 0;
}
