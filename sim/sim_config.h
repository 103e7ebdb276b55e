/* sim/sim_config.h: the `simulation` group of a stand file (docs/sim.md), read by
 * vibid-sim beside the `stand` group that the shared loader reads.
 *
 *   simulation = {
 *     seed = 1; duration = 10.0; hold = "zoh";            # or "smooth"; overrides the stand's
 *                                                          # per-input `hold` (default: the stand's)
 *     integrator = { kind = "auto";          # or "exact" / "arkode" (sim_engine.h)
 *                    rtol = 1e-10; atol = 1e-12; method = "fehlberg8"; };  # ARKODE's; or "dormand_prince5"
 *     excitation = ( { target = "base"; kind = "triangle"; amplitude = 1e-3; frequency = 10.0; } );
 *                    # target: "base", a force input (name or channel) or a disturbance (name),
 *                    # which then replaces the disturbance's default white drive
 *     noise = ( { channel = "x1"; std = 1e-7; resolution = 1e-8; },
 *               { channel = "x2"; snr_db = 60.0; correlation_time = 0.01; offset = 2e-6; } );
 *     changes = ( { parameter = "c2"; at = 60.0; factor = 0.9; ramp = 0.0; } );
 *     covariates = ( { name = "T"; unit = "degC"; mean = 20.0; amplitude = 5.0; period = 600.0;
 *                      phase = 0.0; ramp = 0.0; noise = 0.0; } );   # an operating condition, output
 *                                                                    # as a channel after the stand's
 *     dependence = ( { parameter = "c2"; covariate = "T"; coefficient = -0.004; reference = 20.0; } );
 *     can = { id = 0x100; fd = false; extended = false;
 *             signals = ( { channel = "x1"; type = "int32"; scale = 1e-9; } ); };
 *     modbus = { fifo_base = 1000; capacity = 1000; };
 *   };
 * Everything is optional; without the group the stand is simulated at rest.
 */
#ifndef VIBID_SIM_CONFIG_H
#define VIBID_SIM_CONFIG_H

#include <stddef.h>
#include <stdint.h>

#include <vibid/stand_file.h>

#include "excitation.h"

#define SIM_MAX_CHANNELS 64
#define SIM_MAX_COVARIATES 4
/* Output channels: the stand's model channels 0 .. n_channels-1, then the covariates
 * n_channels .. n_channels + n_covariates - 1 (CSV columns, CAN signals, registers). */
#define SIM_MAX_OUTPUTS (SIM_MAX_CHANNELS + SIM_MAX_COVARIATES)

typedef struct sim_exc_target {
    int is_base;          /* 1: base motion s(t); 0: force input or disturbance */
    int is_disturbance;   /* 1: disturbance `input` (replaces its default white drive, always held) */
    size_t input;         /* input index j (force inputs), disturbance index (disturbances) */
    sim_exc_spec *specs;  /* summed components */
    size_t n;
} sim_exc_target;

typedef struct sim_noise_spec {
    size_t channel;       /* model channel index */
    double std;           /* channel units; NaN if not given (neither given: the stand's declared
                             noise of the quantity applies, vibid_model_get_noise) */
    double snr_db;        /* signal RMS / noise std in dB; NaN if not given */
    double resolution;    /* quantisation step (0 = none) */
    double offset;        /* channel units: a constant sensor zero error added to the output (0 = none) */
    double corr_time;     /* s: the noise's correlation time, first-order (AR(1)) coloured noise of the
                             same std with autocorrelation exp(-|lag| / corr_time); 0 = white */
} sim_noise_spec;

typedef struct sim_change {
    size_t param;         /* unknown parameter index (model parameter order) */
    double at;            /* s: start of the change */
    double ramp;          /* s: duration of the linear ramp (0 = step at the first sample >= at) */
    double value;         /* value after the change (absolute) */
} sim_change;

/* simulation.covariates: an operating condition (a temperature, a speed) that the
 * simulation records as a channel of its own, and that parameters may follow
 * (sim_dependence). True value (no noise):
 *     c(t) = mean + amplitude sin(2 pi t / period + phase) + ramp t
 * the recorded one adds white Gaussian noise of std `noise` from a stream of its own. */
typedef struct sim_covariate {
    char name[64];        /* the channel name (CSV column, CAN signal, register map entry) */
    char unit[32];        /* free text, e.g. "degC"; written into the DBC */
    double mean;          /* covariate units */
    double amplitude;     /* covariate units; 0 = no swing */
    double period;        /* s, > 0 when amplitude != 0 */
    double phase;         /* rad (the formula's; simulation.excitation's `phase` is in degrees) */
    double ramp;          /* covariate units per second: a linear drift from t = 0 */
    double noise;         /* covariate units: std of the measurement noise (0 = none) */
} sim_covariate;

/* simulation.dependence: theta_i(t) = base_i(t) (1 + coefficient (c_true(t) - reference)),
 * base_i(t) the true value after simulation.changes. Several entries multiply. */
typedef struct sim_dependence {
    size_t param;         /* unknown parameter index (model parameter order) */
    size_t covariate;     /* index into sim_config.covariates */
    double coefficient;   /* 1 / covariate unit (e.g. 1/K) */
    double reference;     /* covariate units: where the factor is 1 */
} sim_dependence;

/* simulation.integrator.kind (sim_engine.h says what each does). */
typedef enum sim_integrator {
    SIM_INTEGRATOR_AUTO = 0,   /* exact step on every interval where it is exact, ARKODE elsewhere */
    SIM_INTEGRATOR_EXACT = 1,  /* as AUTO, but a stand or excitation that would keep ARKODE in use on
                                  every interval (cubic springs, smooth sines/sweeps/triangles) is refused */
    SIM_INTEGRATOR_ARKODE = 2  /* ARKODE on every interval (the reference the exact step is checked against) */
} sim_integrator;

typedef enum sim_can_type { SIM_CAN_INT16 = 0, SIM_CAN_INT32 = 1, SIM_CAN_FLOAT32 = 2 } sim_can_type;

typedef struct sim_can_signal {
    sim_can_type type;
    double scale;         /* physical = raw * scale (integer types) */
} sim_can_signal;

typedef struct sim_config {
    char file[256];
    uint64_t seed;
    double duration;      /* s; 0 = not given */
    int smooth;           /* simulation.hold: -1 not given (each input as the stand declares it,
                             vibid_model_get_hold), 0 = "zoh" / 1 = "smooth" for every input
                             (a global override of the stand's declarations) */
    /* Resolved per input from the stand's declarations and the override (1 = smooth,
     * 0 = held over [t_k, t_k + h), (1.10)): what the engine uses. */
    int base_smooth;
    int input_smooth[SIM_MAX_CHANNELS]; /* per force input j (every input is a channel) */
    sim_integrator integrator;
    double rtol, atol;    /* ARKODE's tolerances (relative; absolute in m and m/s) */
    int method;           /* 0 = fehlberg8 (Fehlberg 13-7-8, default), 1 = dormand_prince5 (7-4-5) */
    sim_exc_target *targets;
    size_t n_targets;
    sim_noise_spec *noise;
    size_t n_noise;
    sim_change *changes;
    size_t n_changes;
    sim_covariate covariates[SIM_MAX_COVARIATES];
    size_t n_covariates;
    sim_dependence *dependence;
    size_t n_dependence;
    /* CAN */
    uint32_t can_id;      /* id of the first frame; frames use can_id, can_id+1, ... */
    int can_fd, can_extended;
    sim_can_signal can_sig[SIM_MAX_OUTPUTS]; /* per output channel (model channels, then covariates) */
    /* Modbus */
    unsigned fifo_base, fifo_capacity;
} sim_config;

/* Reads the `simulation` group of path for the loaded stand (names of inputs,
 * channels and parameters are resolved against it). Returns 0, or -1 with err =
 * "file:line: simulation.field: message". */
/* seed: NULL, or a seed that replaces simulation.seed (before streams are derived). */
int sim_config_load(const char *path, const vibid_stand *stand, const uint64_t *seed, sim_config *cfg, char *err,
                    size_t errlen);
void sim_config_free(sim_config *cfg);

/* True value of covariate j at t (s), without measurement noise. */
double sim_covariate_value(const sim_covariate *c, double t);
/* 1 when covariate j changes with time (amplitude or ramp not 0): a parameter that follows
 * it varies within every sample interval. */
int sim_covariate_varies(const sim_covariate *c);

#endif
