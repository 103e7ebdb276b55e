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

#ifdef __cplusplus
}
#endif
#endif
