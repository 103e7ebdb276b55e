/* sim/sim_engine.h: integration of M y'' + G(y, y') + G0(y) = F(t) (1.1) for a stand
 * (vibid_model_forces gives all forces but inertia), sampled at h = 1 / sample_rate.
 *
 * Integrator: SUNDIALS ARKODE, ERKStep (explicit Runge-Kutta, default 8th-order
 * Fehlberg-13-7-8 with embedded error estimate and adaptive steps). Why ARKODE/ERK and not
 * CVODE: the input is held over each sample interval (1.10), so the right-hand side
 * jumps at every sample boundary and the integrator must be restarted there. A
 * one-step method restarts at full order for free; CVODE's multistep BDF/Adams methods
 * restart at order 1 with a tiny step every sample, which costs many steps per sample
 * and gives up accuracy. The systems are not stiff at usable sample rates (every mode
 * below Nyquist), so an explicit method needs no Jacobian or linear solver.
 *
 * Sample k (t_k = k h): state y(t_k), y'(t_k); inputs u_k = u(t_k), base s_k; then the
 * state is integrated over [t_k, t_{k+1}] with each input held (ZOH) or varying
 * (smooth) as sim_config resolved it (the stand's declarations or simulation.hold),
 * stopping exactly at t_{k+1} (ERKStepSetStopTime) and resetting the method there
 * (ERKStepReset), so that no stage ever straddles a jump. A held base jumps by
 * s_k - s_{k-1} at t_k (s_{-1} = 0) and the dampers to the base make that an impulse:
 * y' += M^-1 d_base (s_k - s_{k-1}) before sample k is taken (its velocities are
 * post-impulse, its accelerations those with u_k, s_k, s' = 0) and before the restart.
 *
 * Disturbances (stand.disturbances, vibid_model_add_disturbance): a force w_k on its node,
 * held over [t_k, t_k + h) like a held input (so the same stop and restart at t_k keeps the
 * integration exact), added to vibid_model_forces' f. Default w_k ~ N(0, true_std^2), white,
 * from a stream of its own derived from the run's seed; an excitation that targets the
 * disturbance replaces that. No channel reports it; a measured acceleration at t_k includes
 * w_k (the right-hand limit, as for the inputs).
 *
 * Measurement noise of channel i: simulation.noise's std or snr_db for it if given, else the
 * stand's declared noise of that quantity (vibid_model_get_noise, stand file `noise`), else none.
 *
 * Time-varying parameters (sim_config.changes): a step takes effect at the first sample
 * boundary t_k >= at (so the ZOH solution stays exact); a ramp is linear in continuous
 * time. A change of a mass takes effect at sample boundaries (M^-1 is refreshed there).
 */
#ifndef VIBID_SIM_ENGINE_H
#define VIBID_SIM_ENGINE_H

#include <stddef.h>
#include <stdint.h>

#include <vibid/stand_file.h>

#include "sim_config.h"

typedef struct sim_engine sim_engine;

/* The stand and cfg must outlive the engine. NULL on failure with err. */
sim_engine *sim_engine_create(const vibid_stand *stand, const sim_config *cfg, char *err, size_t errlen);
void sim_engine_destroy(sim_engine *e);

size_t sim_engine_channels(const sim_engine *e);   /* model channel count */
double sim_engine_period(const sim_engine *e);     /* h, s */
/* Noise standard deviation in effect for channel i (after the SNR pilot run). */
double sim_engine_noise_std(const sim_engine *e, size_t channel);

/* Sample k (0, 1, ...): *k, *t = k h, values[n_channels] with noise and quantisation,
 * clean[n_channels] (may be NULL) without; then advances the state to t_{k+1}.
 * Returns 0, or -1 when the integrator fails (sim_engine_error says why). */
int sim_engine_next(sim_engine *e, uint64_t *k, double *t, double *values, double *clean);
const char *sim_engine_error(const sim_engine *e);

/* Current value of unknown parameter i (after changes). */
double sim_engine_param(const sim_engine *e, size_t i);

typedef struct sim_engine_stats {
    long steps, rhs_evals;
} sim_engine_stats;
void sim_engine_stats_get(const sim_engine *e, sim_engine_stats *s);

#endif
