/* vibid/regressor.h: per-sample regressor builder for a finalized model: turns the
 * channel vector of each sample into the rows of a linear regression
 *     y_k = x_k^T Theta + e_k        (2.2), (3.2)
 * in the layout of rls.h: x_k is p_reg x m, y_k is m x q, Theta is p_reg x q.
 *
 * Two forms, chosen by the model's discretization (model.h):
 *  CENTRAL_DIFFERENCE, structured (4.1), (3.5)-(3.7), (4.2): one equation per node
 *    (m = n), one output (q = 1), p_reg = p (the model's unknowns). Equation i at the
 *    centre sample k-1 of the window {k-2, k-1, k}:
 *        sum_l theta_l phi_l,i  =  -(known terms)_i
 *    phi_l,i is the structure of unknown l applied to the signals: r, r' or r^3 of an
 *    element, y_i'' of a node's mass, -u_j of an input gain. Velocities and
 *    accelerations that are measured are used directly (accelerometers); the others are
 *    central differences (1.17) of the displacement or of the measured velocity.
 *  ZOH, second-order difference form (1.16)/(3.1): one equation (m = 1), q = n outputs,
 *    p_reg = 2 n + 2 r_z, with r_z = r force inputs plus 1 for the base displacement
 *    if a spring touches the base (a damper or cubic spring on the base is refused in
 *    ZOH mode: a held s has no derivative):
 *        y_{k}^T = [y_{k-1}^T, y_{k-2}^T, v_{k-1}^T, v_{k-2}^T] Theta
 *    (v the ZOH input vector [u; s]), i.e. Theta^T = [A1 A2 B1 B0] with
 *    y_{k+2} = A1 y_{k+1} + A2 y_k + B1 v_{k+1} + B0 v_k (M~ = I normalisation).
 *
 * Optional pre-filter: every column of x_k and y_k passes through the same 4th-order
 * Butterworth low-pass (two biquads, bilinear transform, cutoff prefilter_hz). A linear
 * time-invariant filter applied to every column preserves the regression exactly (also
 * for the cubic columns, which are formed before filtering), while it removes the
 * measurement noise above the cutoff that central differences amplify by up to
 * (2 / h)^4 in power. Choose the cutoff above the highest natural frequency and the
 * excitation band (2-4 times the highest mode is a good start), below f_a / 4.
 *
 * Real time: vibid_regressor_push allocates nothing, takes no lock and costs one
 * multiply-add per window value that an entry of x or y reads (the stencils, hold
 * equivalents and coefficients are folded together at create; entries are taken four at a
 * time, so about (p_reg m + m q) times the taps of one stencil), plus the cubic entries and
 * 20 flops per entry with the pre-filter. Paper example 1 (p_reg = 3, m = 2) with the
 * pre-filter: about 20 ns per sample on an x86-64 core with AVX2.
 */
#ifndef VIBID_REGRESSOR_H
#define VIBID_REGRESSOR_H

#include <vibid/common.h>
#include <vibid/model.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct vibid_regressor vibid_regressor;

typedef struct vibid_regressor_dims {
    size_t n_regressors; /* p_reg */
    size_t n_equations;  /* m */
    size_t n_outputs;    /* q */
    size_t latency;      /* samples between the newest sample and the one the rows describe (0 for ZOH,
                            1 for central differences, 2 for five-point stencils) */
} vibid_regressor_dims;

/* Creates a builder for a finalized model (copied; the model may be destroyed).
 *   sample_time   h in s, > 0 and finite.
 *   prefilter_hz  cutoff of the pre-filter in Hz, 0 = off, else in (0, 0.45 / h).
 * Checks that the needed signals are measured (as vibid_model_check_identifiable does,
 * without the identifiability part). NULL on failure, reason in vibid_last_error(). */
VIBID_API vibid_regressor *vibid_regressor_create(const vibid_model *model, double sample_time,
                                                  double prefilter_hz);
/* As vibid_regressor_create, with the order of the differences that replace unmeasured
 * derivatives (structured form only; ZOH always uses three samples):
 *   2  central differences (1.17), window of 3 samples, latency 1, bias (w h)^2 / 6 on
 *      a first and (w h)^2 / 12 on a second derivative of a component at w (rad/s);
 *   4  five-point stencils, window of 5 samples, latency 2, bias (w h)^4 / 30 and
 *      (w h)^4 / 90 (2e-5 and 7e-6 at 40 samples per period). They amplify white noise
 *      near Nyquist a little more (by 4/3 in amplitude); the pre-filter removes it.
 * Held inputs (vibid_model_set_hold) enter as their hold equivalents of the same order:
 *   value   order 2: (s_{c-1} + s_c) / 2; order 4: (13 (s_{c-1} + s_c) - (s_{c-2} + s_{c+1})) / 24
 *   rate    (s_c - s_{c-1}) / h (exact: the impulse of the jump at t_c, spread over h)
 * where c is the centre sample; a held force in the equation of a node whose acceleration
 * is measured enters as sampled (the accelerometer at t_k sees the force held from t_k).
 * vibid_regressor_create is this function with order 2. */
VIBID_API vibid_regressor *vibid_regressor_create_order(const vibid_model *model, double sample_time,
                                                        double prefilter_hz, unsigned difference_order);

/* Forgets the sample history and the filter state. */
VIBID_API vibid_status vibid_regressor_reset(vibid_regressor *reg);
VIBID_API void vibid_regressor_destroy(vibid_regressor *reg);
VIBID_API vibid_status vibid_regressor_get_dims(const vibid_regressor *reg, vibid_regressor_dims *dims);

/* Pushes one sample.
 *   channels  n_channels values in the model's channel layout (model.h), finite.
 *   x         out: p_reg x m (column-major), written when *ready != 0.
 *   y         out: m x q (column-major), written when *ready != 0.
 *   ready     out: 0 while the window is filling (the first 2, or 4 with order 4), 1 after.
 * Non-finite input gives VIBID_E_NONFINITE and leaves the builder unchanged (a gap:
 * call vibid_regressor_reset to restart the window). Allocates nothing. */
VIBID_API vibid_status vibid_regressor_push(vibid_regressor *reg, const double *channels, double *x, double *y,
                                            int *ready);

#ifdef __cplusplus
}
#endif
#endif
