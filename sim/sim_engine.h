/* sim/sim_engine.h: integration of M y'' + G(y, y') + G0(y) = F(t) (1.1) for a stand
 * (vibid_model_forces gives all forces but inertia), sampled at h = 1 / sample_rate.
 *
 * Two paths, chosen per sample interval (simulation.integrator.kind, sim_config.h):
 *
 * Exact step (linear stands, kind "auto" (default) or "exact"): with x = [y; y'],
 * x' = A x + Bv v(t), A = [0 I; -M^-1 C  -M^-1 D], Bv = [0; M^-1 [B c_base d_base E_w]],
 * input columns v = [u_1..u_r, s, s', w_1..w_nw]. When every input is linear over
 * [t_k, t_{k+1}), v = v0 + dv (t - t_k) / h, the solution is closed-form:
 *     x_{k+1} = Ad x_k + Gamma0 v0 + Gamma1 dv = Phi [x_k; v0; dv]
 * (Ad = e^{A h}, Gamma0 = int_0^h e^{A (h - tau)} Bv dtau, Gamma1 the same weighted by
 * tau / h), one matrix-vector product per sample, Phi from one vibid_zoh of the system
 * augmented by the input (computed at creation and after each parameter change). Exact to
 * rounding for held inputs (dv = 0: ZOH, (1.12)) and for PRBS / noise / constants under
 * "smooth" (interpolated linearly: a first-order hold), with the held base's impulse and
 * the held disturbances as below. Not exact, so integrated by ARKODE instead, are intervals
 * with a smooth sine, triangle, sweep or stepped sine (a continuous function of t that no
 * polynomial over the interval reproduces: holding or interpolating it would simulate a
 * different system), a parameter ramp, or a component window opening or closing inside
 * the interval; with kind "exact" the first of these (and a nonlinear stand) is refused at
 * start (sim_config_load), the other two fall back per interval. sim_engine_stats counts
 * the intervals of each path.
 *
 * ARKODE (nonlinear stands, the intervals above, and everything with kind "arkode"):
 * SUNDIALS ARKODE, ERKStep (explicit Runge-Kutta, default 8th-order
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
 *
 * Covariates (sim_config.covariates) are output channels after the model channels; the
 * dependence (sim_config.dependence) multiplies a parameter's value after the changes by
 * (1 + coefficient (c_true(t) - reference)), evaluated at every right-hand-side evaluation
 * like a ramp (continuous in time, no hold; a mass, again, at sample boundaries). A
 * dependence on a covariate that varies therefore sends every interval to ARKODE.
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
/* Output channels: the model channels, then the covariates (sim_config.covariates). */
size_t sim_engine_outputs(const sim_engine *e);
double sim_engine_period(const sim_engine *e);     /* h, s */
/* Noise standard deviation in effect for channel i (after the SNR pilot run). */
double sim_engine_noise_std(const sim_engine *e, size_t channel);

/* Sample k (0, 1, ...): *k, *t = k h, values[sim_engine_outputs] with noise and quantisation
 * (the model channels, then each covariate: its true value at t_k plus its noise),
 * clean[sim_engine_outputs] (may be NULL) without; then advances the state to t_{k+1}.
 * Returns 0, or -1 when the integrator fails (sim_engine_error says why). */
int sim_engine_next(sim_engine *e, uint64_t *k, double *t, double *values, double *clean);
const char *sim_engine_error(const sim_engine *e);

/* Value of unknown parameter i at the last sample's t_k (after changes and dependence). */
double sim_engine_param(const sim_engine *e, size_t i);

typedef struct sim_engine_stats {
    long steps, rhs_evals;           /* ARKODE's Runge-Kutta steps and right-hand-side evaluations */
    long exact_intervals;            /* sample intervals taken by the exact step */
    long arkode_intervals;           /* sample intervals integrated by ARKODE */
    long retried_pieces;             /* pieces the configured method failed on (ARK_ERR_FAILURE) and
                                        Dormand-Prince 5(4) integrated again from their start */
} sim_engine_stats;
void sim_engine_stats_get(const sim_engine *e, sim_engine_stats *s);

#endif
