/* vibid/discretize.h: zero-order-hold discretization (1.9)-(1.14), the second-order
 * difference form (1.16), and the way back from discrete to continuous (physical)
 * matrices.
 *
 * Which discretization to identify with (a per-model choice, model.h):
 *  - Central differences (1.17): simple, any model (also nonlinear), parameters directly;
 *    bias O((omega h)^2 / 12) for a signal component at omega (0.2 % at 20 samples per
 *    period), and the differences amplify measurement noise strongly (use the regressor
 *    pre-filter).
 *  - ZOH: exact for a linear model whose input is constant over each sample interval;
 *    needs the matrix logarithm to return to M^-1 C, M^-1 D, M^-1 B, which is real and
 *    unique only when every mode lies well below the Nyquist frequency f_a / 2.
 *
 * All matrices column-major. These functions allocate scratch (not for real-time use).
 */
#ifndef VIBID_DISCRETIZE_H
#define VIBID_DISCRETIZE_H

#include <vibid/common.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Report of the way back from discrete to continuous. */
typedef struct vibid_log_info {
    double max_frequency_hz; /* largest |Im lambda(A)| / (2 pi) found, Hz */
    double nyquist_hz;       /* 1 / (2 h) */
    int ambiguous;           /* non-zero when max_frequency_hz > 0.8 nyquist_hz: a mode
                                near or above Nyquist may have been aliased by the
                                principal logarithm (other real logarithms exist); sample faster */
} vibid_log_info;

/* ZOH (1.12)/(1.13): x_{k+1} = G x_k + Gamma v_k for x' = A x + Bv v, input v held over
 * [t_k, t_k + h). G = e^{A h}, Gamma = int_0^h e^{A t} dt Bv (the paper's H times the
 * input matrix), computed as the exponential of the augmented matrix [A Bv; 0 0] h, so
 * singular A is fine.
 *   n_states 1..512, n_inputs 0..512; A n x n, Bv n x n_inputs (NULL if 0); h > 0 in s;
 *   G n x n, Gamma n x n_inputs (NULL if 0).
 * VIBID_E_NONFINITE for NaN/Inf in A or Bv; VIBID_E_NUMERICAL when e^{A h} overflows (a
 * mode growing by more than 1e308 over one sample); G and Gamma are then left untouched. */
VIBID_API vibid_status vibid_zoh(size_t n_states, size_t n_inputs, const double *A, const double *Bv, double h,
                                 double *G, double *Gamma);

/* Inverse of vibid_zoh: A = log(G) / h, Bv from Gamma, via the logarithm of the
 * augmented matrix [G Gamma; 0 I]. Fails with VIBID_E_NUMERICAL when G has an
 * eigenvalue on the closed negative real axis (no real logarithm: a mode at or beyond
 * Nyquist, or a discrete model that no continuous one produces); info (may be NULL)
 * says how close the highest mode is to Nyquist. */
VIBID_API vibid_status vibid_zoh_inverse(size_t n_states, size_t n_inputs, const double *G, const double *Gamma,
                                         double h, double *A, double *Bv, vibid_log_info *info);

/* Second-order difference form (1.16) of M y'' + D y' + C y = Bv v under ZOH, normalised
 * to M~ = I:
 *     y_{k+2} + Dt y_{k+1} + Ct y_k = B1t v_{k+1} + B2t v_k
 * (Dt = -A1, Ct = -A2 of regressor.h). n 1..256, r 0..256; M regular. Outputs n x n,
 * n x n, n x r, n x r. VIBID_E_NUMERICAL if the upper-right block of G is singular (h
 * at a multiple of a half period). */
VIBID_API vibid_status vibid_second_order_form(size_t n, size_t r, const double *M, const double *D,
                                               const double *C, const double *Bv, double h, double *Dt,
                                               double *Ct, double *B1t, double *B2t);

/* Way back from (1.16) to the continuous mass-normalised matrices
 *     K = M^-1 C, L = M^-1 D, J = M^-1 Bv   (so that y'' + L y' + K y = J v):
 * the observable realisation of (1.16) (state [y_k; y_{k+1} - B1t v_k]) is taken back
 * by vibid_zoh_inverse and transformed to the coordinates [y; y']. K, L n x n, J n x r
 * (NULL if r = 0). With one of M, D, C, Bv known the others follow (M = C K^-1, ...);
 * vibid_ident does this for structured models. */
VIBID_API vibid_status vibid_second_order_to_continuous(size_t n, size_t r, const double *Dt, const double *Ct,
                                                        const double *B1t, const double *B2t, double h,
                                                        double *K, double *L, double *J, vibid_log_info *info);

#ifdef __cplusplus
}
#endif
#endif
