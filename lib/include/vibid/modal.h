/* vibid/modal.h: modal parameters from M, D, C (quadratic eigenvalue problem
 *     (lambda^2 M + lambda D + C) phi = 0 ),
 * solved as the eigenvalue problem of the state matrix A of (1.6). Its 2n eigenvalues
 * come in conjugate pairs for underdamped modes; each pair lambda, conj(lambda) is one
 * mode with
 *     natural (undamped) frequency f = |lambda| / (2 pi)        Hz
 *     damping ratio               zeta = -Re(lambda) / |lambda|   (0 < zeta < 1)
 * Overdamped modes (two real eigenvalues l1, l2 < 0) are paired in ascending order and
 * reported as f = sqrt(l1 l2) / (2 pi), zeta = -(l1 + l2) / (2 sqrt(l1 l2)) >= 1.
 * Modes are sorted by ascending f. Mode shapes are the complex vectors phi (the first n
 * components of the state eigenvector of the eigenvalue with Im >= 0), scaled so that
 * the component of largest modulus is exactly 1 (real).
 *
 * Both functions allocate their scratch at every call (not for real-time use); a reported
 * row (report.h) runs the same analysis on scratch its report made once and allocates
 * nothing.
 */
#ifndef VIBID_MODAL_H
#define VIBID_MODAL_H

#include <vibid/common.h>
#include <vibid/model.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Modal parameters of M y'' + D y' + C y = 0.
 *   n 1..512; M n x n regular, D, C n x n (D may be NULL for undamped).
 *   freq_hz, zeta: n each. shape_re, shape_im: n x n, column j = mode j (either may be
 *   NULL). VIBID_E_NUMERICAL if M is singular or the eigen solver fails; a rigid-body
 *   mode (lambda = 0) gives f = 0, zeta = 1. */
/* An unstable model (an eigenvalue with real part > 1e-12 of the state matrix's norm:
 * negative damping or stiffness) returns VIBID_E_UNSTABLE with every output written:
 * oscillating modes with zeta < 0, a divergent real pair as f = 0, zeta = 1. A rigid-body
 * root (0) is not unstable. Both functions below. */
VIBID_API vibid_status vibid_modal(size_t n, const double *M, const double *D, const double *C, double *freq_hz,
                                   double *zeta, double *shape_re, double *shape_im);

/* Modal parameters of a model at parameter values theta (p, NULL = nominal), cubic terms
 * ignored (linearisation at rest), with standard errors propagated to first order from
 * the covariance of theta (p x p, e.g. vibid_ident_covariance; NULL = no errors):
 * se = sqrt(J cov J^T) with J the central-difference Jacobian of (f, zeta) with respect
 * to theta (relative step 1e-6). Modes are matched by order, so errors are meaningful
 * when neighbouring frequencies differ by more than their errors.
 *   freq_hz, zeta n each; freq_se, zeta_se n each (may be NULL; set to 0 when cov is
 *   NULL); shape_re, shape_im n x n (may be NULL). */
VIBID_API vibid_status vibid_model_modal(const vibid_model *model, const double *theta, const double *cov,
                                         double *freq_hz, double *freq_se, double *zeta, double *zeta_se,
                                         double *shape_re, double *shape_im);

/* The model's frequency response functions at parameter values theta (p, NULL = nominal),
 * cubic terms ignored (linearisation at rest): from each excitation e (the force inputs
 * u_0 .. u_(r-1), then the base displacement s when the base moves: n_exc = r + has_base)
 * to each of the model's channels c (vibid_model_channel_info), at n_freq frequencies
 * freq_hz (>= 0, Hz):
 *     X(w) = (C - w^2 M + j w D)^-1 [B, c_base + j w d_base],  w = 2 pi f;
 * a node's displacement channel is the row of X, its velocity j w X, its acceleration
 * -w^2 X; an input channel or the base displacement channel is 1 for its own excitation
 * (j w, -w^2 for base velocity and acceleration channels), 0 otherwise. Units: the
 * channel's per the excitation's (m/N, m/m, ...).
 * sample_time h > 0: what sampled data show where an excitation is held between samples
 * (vibid_model_set_hold, VIBID_HOLD_ZOH): the held excitation's columns of the response
 * channels times the zero-order hold's e^(-j w h / 2) sin(w h / 2) / (w h / 2) (the
 * staircase the system sees, to first order in the aliases: exact below Nyquist where the
 * response above it is small). h = 0: the continuous FRF for every excitation.
 * re, im: n_freq x n_channels x n_exc, index f + n_freq (c + n_channels e). A frequency at
 * which C - w^2 M + j w D is singular (an undamped mode hit exactly) gives inf/NaN there.
 * Allocates (not for real-time use). */
VIBID_API vibid_status vibid_model_frf(const vibid_model *model, const double *theta, double sample_time,
                                       size_t n_freq, const double *freq_hz, double *re, double *im);

#ifdef __cplusplus
}
#endif
#endif
