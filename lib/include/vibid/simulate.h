/* vibid/simulate.h: a stand's model at given parameters driven by a capture's measured
 * inputs, for checking an estimate against the data ("does the model explain the
 * capture?": the Python package's report and `vibid` command compare the simulated
 * response channels with the measured ones).
 *
 * The model (model.h): M y'' = vibid_model_forces(theta, y, y', [s, s'], u), cubic springs
 * included, integrated by the classical Runge-Kutta method with `substeps` steps per
 * sample. The inputs between samples:
 *  - smooth inputs (the default of vibid_model_set_hold) are cubic Hermite between samples
 *    with slopes from five-point central differences (a measured base velocity is used as
 *    the base's slope), so the input path is right to O(h^4) for band-limited signals;
 *  - held inputs (VIBID_HOLD_ZOH) are constant over [t_k, t_k + h), and a held base's jumps
 *    reach the dampers to it as the impulse d_base (s_k - s_{k-1}) (model.h).
 * A disturbance (vibid_model_add_disturbance: an unmeasured force) is zero: what is
 * simulated is the response to the measured inputs alone.
 *
 * Why not the output-error fit's simulation (output_error.h, vibid_oe_simulate): that one
 * takes smooth inputs as straight lines between samples, which its exact discretisation and
 * its sensitivities need, and is off by O((w h)^2) where a real input is not a straight
 * line (a multisine at 10 samples per period: 3 %); a check of an estimate against the
 * data must not add an error of that size. The output-error fit measures its own
 * dependence on the path (vibid_oe_interp_shift).
 *
 * The start: sample 2 (the first with a five-point slope), from the measured state: each
 * node's measured displacement, its measured velocity or else the five-point difference
 * of its displacement, and 0 for a node without displacement sensor (whose start
 * transient then decays with the system's damping: compare after it).
 */
#ifndef VIBID_SIMULATE_H
#define VIBID_SIMULATE_H

#include <vibid/common.h>
#include <vibid/model.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Simulates model (finalized) at parameters theta (p, the model's units) over a capture
 * channels (n_samples x n_channels of the model, column-major, the model's channel order
 * and units) sampled every sample_time s (> 0), with substeps (1..1000) Runge-Kutta steps
 * per sample. out (n_samples x n_channels, column-major) receives the channels in the same
 * layout: a node's displacement, velocity and acceleration channels simulated, input and
 * base channels copied as measured, rows 0 and 1 NaN (before the start).
 * n_samples >= 5. VIBID_E_DIMENSION when a force input has no channel or the base moves
 * and its displacement is not measured (nothing to drive the model with);
 * VIBID_E_NUMERICAL when the mass matrix at theta is singular; a non-finite force stops
 * the run with that status of vibid_model_forces. Allocates (not for real-time paths). */
VIBID_API vibid_status vibid_model_simulate(const vibid_model *model, const double *theta, double sample_time,
                                            size_t n_samples, const double *channels, unsigned substeps,
                                            double *out);

#ifdef __cplusplus
}
#endif
#endif
