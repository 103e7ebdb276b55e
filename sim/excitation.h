/* sim/excitation.h: excitation generators for vibid-sim: the known input u(t) of (1.7)
 * and the base motion s(t).
 *
 * A generator is the sum of components (triangle, sine, stepped sine, linear and
 * logarithmic sweep, PRBS, band-limited white noise, constant), each with amplitude,
 * offset and an active time window. Continuous components are functions of t;
 * discrete ones (PRBS, noise) produce one value per sample k and are held (zero-order
 * hold) or linearly interpolated (smooth) between samples.
 *
 * Hold (1.10): in ZOH mode the whole sum is evaluated at t_k and held constant over
 * [t_k, t_k + h), derivative 0; in smooth mode continuous components are evaluated at t
 * (with their exact derivative) and discrete ones interpolated linearly between
 * t_k and t_{k+1}.
 */
#ifndef VIBID_SIM_EXCITATION_H
#define VIBID_SIM_EXCITATION_H

#include <stddef.h>
#include <stdint.h>

typedef enum sim_exc_kind {
    SIM_EXC_CONSTANT = 0,  /* amplitude (plus offset) */
    SIM_EXC_TRIANGLE,      /* the paper's: 0 at t = 0 rising, peak +-amplitude, frequency Hz */
    SIM_EXC_SINE,          /* amplitude sin(2 pi f t + phase) */
    SIM_EXC_STEPPED_SINE,  /* `steps` frequencies f_start..f_stop (log spaced), `dwell` s each, phase continuous, repeats */
    SIM_EXC_SWEEP_LINEAR,  /* chirp f_start -> f_stop over sweep_time, repeats */
    SIM_EXC_SWEEP_LOG,     /* exponential chirp f_start -> f_stop over sweep_time, repeats */
    SIM_EXC_PRBS,          /* maximal-length LFSR of order prbs_order, +-amplitude, one bit per prbs_samples samples */
    SIM_EXC_NOISE          /* Gaussian white noise, band-limited to [f_low, f_high] (2nd-order Butterworth
                              high-/low-pass), scaled so that its standard deviation is `amplitude` */
} sim_exc_kind;

typedef struct sim_exc_spec {
    sim_exc_kind kind;
    double amplitude;       /* input units (N per gain unit) or m for the base */
    double offset;          /* added to the component */
    double frequency;       /* Hz: triangle, sine */
    double phase_deg;       /* sine only */
    double f_start, f_stop; /* Hz: sweeps, stepped sine */
    double sweep_time;      /* s: sweeps (period of the repeated sweep) */
    double dwell;           /* s per frequency: stepped sine */
    int steps;              /* stepped sine: number of frequencies >= 1 */
    double f_low, f_high;   /* Hz: noise band (f_low 0 = no high-pass, f_high >= Nyquist = no low-pass) */
    int prbs_order;         /* 2..31 */
    int prbs_samples;       /* samples per PRBS bit >= 1 */
    double t_on, t_off;     /* active window [t_on, t_off); t_off <= t_on means "forever" */
    uint64_t seed;          /* PRBS / noise; 0 = derived from the run's seed and position */
} sim_exc_spec;

/* Default-initialised spec (amplitude 1, everything else neutral). */
void sim_exc_spec_init(sim_exc_spec *s, sim_exc_kind kind);
/* Name <-> kind: "constant", "triangle", "sine", "stepped_sine", "sweep_linear",
 * "sweep_log", "prbs", "noise". Returns -1 for an unknown name. */
int sim_exc_kind_from_name(const char *name);
const char *sim_exc_kind_name(sim_exc_kind kind);

typedef struct sim_exc sim_exc;

/* Checks and copies the specs; h > 0 the sample time, smooth 0 = ZOH. err receives the
 * reason on failure ("component 2: f_stop ... "). n may be 0 (a zero signal). */
sim_exc *sim_exc_create(const sim_exc_spec *specs, size_t n, double h, int smooth, char *err, size_t errlen);
void sim_exc_destroy(sim_exc *e);

/* Prepares sample interval k (sequential: 0, 1, 2, ...; a jump restarts discrete
 * components' state at k). No allocation. */
void sim_exc_begin_sample(sim_exc *e, uint64_t k);
/* Value and time derivative at t in [t_k, t_{k+1}] of the current interval; at the end of
 * the piece (sim_exc_set_piece_end, t_{k+1} by default) the left limit. */
void sim_exc_eval(const sim_exc *e, double t, double *v, double *dv);
/* The first time in (after, t_{k+1}) at which the signal jumps inside the current
 * interval (smooth: a component's window opening or closing; held: never), or INFINITY. */
double sim_exc_next_jump(const sim_exc *e, double after);
/* End of the piece of the interval being integrated (t_{k+1} after sim_exc_begin_sample):
 * sim_exc_eval at t >= t_end gives the left limit there (a jump at t_end belongs to the
 * next piece). */
void sim_exc_set_piece_end(sim_exc *e, double t_end);
/* Value at t_k (the sample recorded for channel output). */
double sim_exc_sample_value(const sim_exc *e);
/* Whether the signal that sim_exc_eval gives over the current interval [t_k, t_{k+1}) is
 * exactly v0 + (v1 - v0) (t - t_k) / h (what the simulator's exact step integrates in
 * closed form, sim_engine.h): returns 1 and sets v0 = value at t_k, v1 = the left limit at
 * t_{k+1}; returns 0 (v0, v1 untouched) when it is not. Held: always 1 with v1 = v0.
 * Smooth: 1 when every component active in the interval is PRBS, noise (interpolated
 * linearly) or constant, and no component's window opens or closes inside (t_k, t_{k+1});
 * 0 with any sine, triangle, sweep or stepped sine. No allocation. */
int sim_exc_linear(const sim_exc *e, double *v0, double *v1);

/* PRBS helper (exposed for tests): next bit of a Fibonacci LFSR of `order` with state
 * *state (non-zero, < 2^order). */
int sim_lfsr_next(uint32_t *state, int order);

/* Deterministic random numbers (xoshiro256**), for noise and faults. */
typedef struct sim_rng { uint64_t s[4]; int have_spare; double spare; } sim_rng;
void sim_rng_seed(sim_rng *r, uint64_t seed);
uint64_t sim_rng_u64(sim_rng *r);
double sim_rng_uniform(sim_rng *r);  /* [0, 1) */
double sim_rng_normal(sim_rng *r);   /* N(0, 1) */

#endif
