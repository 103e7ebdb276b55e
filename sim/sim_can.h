/* sim/sim_can.h: how vibid-sim puts samples into CAN frames, and the DBC that
 * describes them (docs/sim.md, "CAN frames").
 *
 * Every frame of sample k starts with SampleCounter = k mod 65536 (bits 0..15, Intel,
 * unsigned), followed by channel signals (Intel, packed without gaps in the stand's
 * channel order): int16 / int32 (signed, physical = raw * scale) or float32
 * (SIG_VALTYPE_ 1). Classic CAN: as many 8-byte frames per sample as needed (ids id,
 * id+1, ...; a signal never straddles two frames). CAN FD: one frame per sample (id),
 * length rounded up to a valid FD length (<= 64 bytes), BRS set.
 * Signal names are the stand's channel names (characters other than [A-Za-z0-9_]
 * replaced by '_'). The covariates (simulation.covariates) follow the stand's channels as
 * signals of their own (float32 unless simulation.can.signals gives them a type), named by
 * the covariate, their unit in the DBC.
 */
#ifndef VIBID_SIM_CAN_H
#define VIBID_SIM_CAN_H

#include <stdint.h>
#include <stdio.h>

#include <vibid/stand_file.h>
#include <vibid_drivers/can_frame.h>

#include "sim_config.h"

#define SIM_CAN_MAX_FRAMES SIM_MAX_OUTPUTS

typedef struct sim_can_sig {
    size_t channel;     /* output channel (model channel, or n_channels + covariate) */
    unsigned start_bit; /* Intel start bit (LSB) */
    sim_can_type type;
    double scale;
} sim_can_sig;

typedef struct sim_can_msg {
    uint32_t id;
    uint8_t len;        /* payload bytes */
    size_t n_sig;
    sim_can_sig sig[SIM_MAX_OUTPUTS];
} sim_can_msg;

typedef struct sim_can_layout {
    int fd, extended;
    size_t n_covariates;
    size_t n_msg;
    sim_can_msg msg[SIM_CAN_MAX_FRAMES];
    char sig_name[SIM_MAX_OUTPUTS][64];
    char sig_unit[SIM_MAX_OUTPUTS][32]; /* "" for the stand's channels, the covariate's unit */
    char stand_name[64];
} sim_can_layout;

int sim_can_layout_build(const vibid_stand *stand, const sim_config *cfg, sim_can_layout *lay, char *err, size_t errlen);
/* Encodes sample k into frames[0 .. n_msg-1] (t_ns and iface set by the caller).
 * Values outside an integer signal's range saturate; *saturated (may be NULL) is
 * incremented per saturated value. NaN becomes 0 for integers. */
void sim_can_encode(const sim_can_layout *lay, uint64_t k, const double *values, vibid_can_frame *frames,
                    uint64_t *saturated);
/* Writes the DBC text. Returns 0 or -1 (I/O error). */
int sim_can_write_dbc(const sim_can_layout *lay, FILE *f);

#endif
