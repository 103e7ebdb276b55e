/* vibid/io_form.h: input-output (characteristic-polynomial) form of an incompletely
 * measured linear system, paper (3.13)-(3.15).
 *
 * With x_{k+1} = G x_k + H b_k, z_k = U x_k + v_k and m = dim G, each measured output
 * j = 0..q-1 obeys
 *   z_{k+m}(j) + a_{m-1} z_{k+m-1}(j) + ... + a_0 z_k(j)
 *        = sum_{i=0}^{m-1} (U C_i H)(j, :) b_{k+i} + e_k(j),
 * with a_0..a_{m-1} the coefficients of det(zI - G) = z^m + a_{m-1} z^{m-1} + ... + a_0
 * (shared by all outputs) and C_i the coefficient matrices of adj(zI - G).
 * vibid_ioform_estimate stacks the equations of all outputs into one regression with
 * p = m + m q r unknowns and solves it by QR (never via normal equations).
 *
 * Methods:
 *  - VIBID_IOFORM_LS: least squares. Consistent when the equation error is white, e.g.
 *    no measurement noise and white (unmeasured) excitation. With measurement noise the
 *    equation error is a moving average of v and LS is biased.
 *  - VIBID_IOFORM_IV: instrumental variables (2.13)-(2.15), two-stage form: for the
 *    equation whose oldest output is z_k the instruments are z_{k-1} .. z_{k-iv_lags}
 *    of the same output (uncorrelated with a white v and with the excitation inside the
 *    equation) and the measured inputs themselves; with more instruments than unknowns the estimate is
 *    (X^T P_W X)^-1 X^T P_W Y, P_W the projector onto the instruments. Consistent with
 *    white measurement noise; needs a coloured (e.g. resonant) output so that delayed
 *    outputs correlate with the regressor. Unmeasured white excitation is allowed.
 *
 * Data layout: z is q x N (z[j + k q] = output j at sample k), u is r x N or NULL if
 * r = 0 (b_k = u_k). Units are the caller's; a_i are dimensionless.
 *
 * Except vibid_ioform_regressor, nothing here is real-time: the functions may allocate
 * (batch, offline or at start).
 */
#ifndef VIBID_IO_FORM_H
#define VIBID_IO_FORM_H

#include <vibid/common.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum vibid_ioform_method {
    VIBID_IOFORM_LS = 0,
    VIBID_IOFORM_IV = 1
} vibid_ioform_method;

typedef struct vibid_ioform_config {
    size_t order;              /* m = dim G, 1..64 */
    size_t n_outputs;          /* q, 1..64 */
    size_t n_inputs;           /* r, 0..64 (0: excitation not measured) */
    vibid_ioform_method method;
    size_t iv_lags;            /* IV: delayed outputs per output used as instruments,
                                  order..256; default order + 2 */
} vibid_ioform_config;

/* Defaults: LS, iv_lags = order + 2. */
VIBID_API void vibid_ioform_config_init(vibid_ioform_config *cfg, size_t order, size_t n_outputs,
                                        size_t n_inputs);

/* Batch estimate from N samples.
 *   z       q x N outputs; u r x N inputs (NULL allowed when r = 0). Finite.
 *   a       out, m: a_0..a_{m-1}
 *   a_cov   out, m x m covariance of a (sigma2 (A^T A)^-1 of the final LS stage), or NULL.
 *           For IV with coloured equation error this is the white-error approximation.
 *   ucih    out, q x r x m: ucih[j + l q + i q r] = (U C_i H)(j, l), or NULL (ignored
 *           when r = 0)
 *   sigma2  out, residual variance of the equations (RSS / (N_eq - p)), or NULL
 * Needs N_eq = q (N - m - s) > p equations, s = iv_lags for IV and 0 for LS, else
 * VIBID_E_INSUFFICIENT_DATA. VIBID_E_NOT_IDENTIFIABLE if the (instrumented) regressor is
 * rank deficient (e.g. no excitation), VIBID_E_NONFINITE for NaN/Inf in the data. */
VIBID_API vibid_status vibid_ioform_estimate(const vibid_ioform_config *cfg, const double *z,
                                             const double *u, size_t n_samples, double *a,
                                             double *a_cov, double *ucih, double *sigma2);

/* Per-sample regressor of the I/O form for recursive LS with vibid_rls (configure it
 * with n_params = p = m + m q r, n_outputs = 1, n_equations = q; Theta has the layout
 * [a_0..a_{m-1}, ucih as above]). From the m + 1 newest samples:
 *   z_win  q x (m + 1): z_k .. z_{k+m}, oldest first
 *   u_win  r x m: u_k .. u_{k+m-1}, oldest first (NULL allowed when r = 0)
 *   x      out, p x q: column j is the regressor of output j's equation
 *   y      out, q: z_{k+m}
 * cfg->method is ignored (a recursive IV is vibid/iv.h's business). Real time: allocates
 * nothing, never throws, O(p q). VIBID_E_NONFINITE for NaN/Inf (outputs not written). */
VIBID_API vibid_status vibid_ioform_regressor(const vibid_ioform_config *cfg, const double *z_win,
                                              const double *u_win, double *x, double *y);

/* Modes from the characteristic polynomial: roots z_i of z^m + a_{m-1} z^{m-1} + ... + a_0,
 * s_i = log(z_i) / h, natural frequency f = |s| / (2 pi) in Hz, damping ratio
 * zeta = -Re(s) / |s|. One entry per complex-conjugate pair (Im z > 0) and per real root
 * (zeta = +-1 for a real positive root; a negative real root lies at the Nyquist
 * frequency, Im s = pi / h). Sorted by ascending frequency.
 *   a        m coefficients; a_cov m x m or NULL (then the *_se outputs are NaN)
 *   h        sample time in s, > 0 and finite
 *   freq_hz, zeta, freq_se, zeta_se   out, m entries each (only *n_modes written);
 *            freq_se / zeta_se may be NULL. Standard errors by the delta method:
 *            dz_i/da_l = -z_i^l / p'(z_i), linearised through log and |.|.
 *   n_modes  out, number of modes written (<= m)
 * VIBID_E_NUMERICAL for a root at 0 or a multiple root (p'(z_i) = 0: no delta method). */
VIBID_API vibid_status vibid_ioform_modes(const double *a, const double *a_cov, size_t m, double h,
                                          double *freq_hz, double *zeta, double *freq_se,
                                          double *zeta_se, size_t *n_modes);

/* Recovers unknown entries of G (n x n, n = m) from the characteristic polynomial: finds
 * the free entries such that det(zI - G) has coefficients a, by Gauss-Newton on the
 * coefficient map (Faddeev-LeVerrier), starting from the values in G.
 *   a     m coefficients
 *   G     in/out, m x m: known entries are kept, free entries are start values on input
 *         and estimates on output (only written on success)
 *   free_mask  m x m column-major, non-zero marks a free entry
 *   a_cov      m x m or NULL; G_cov out (n_free x n_free, free entries in column-major
 *              order) or NULL: delta-method covariance J^-1 a_cov J^-T (square case only)
 * The number of free entries must be 1..m. VIBID_E_NOT_IDENTIFIABLE if the Jacobian of
 * the coefficients w.r.t. the free entries is rank deficient (the polynomial does not
 * determine them), VIBID_E_NUMERICAL if Gauss-Newton does not converge in 50 steps.
 * Example (4.3): G = [1 h; c d], free = {c, d}: det(zI - G) = z^2 - (1 + d) z + d - h c,
 * so d = -a_1 - 1, c = (d - a_0) / h. What U C_i H adds (parts of H given G) is not used. */
VIBID_API vibid_status vibid_ioform_recover_g(const double *a, size_t m, double *G,
                                              const unsigned char *free_mask, const double *a_cov,
                                              double *G_cov);

#ifdef __cplusplus
}
#endif
#endif
