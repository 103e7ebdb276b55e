/* vibid/iv.h: instrumental variables (paper (2.13)-(2.15)), batch and recursive, and
 * the auxiliary-model instruments for difference-equation (ARX) models.
 *
 * Model as in lsq.h: Y = X Theta + E (X N x p, Y N x q, Theta p x q). When E is
 * correlated with X (coloured equation error, or noise on outputs that also appear in
 * the regressor) least squares is biased. The IV estimate
 *     Theta = (W^T X)^-1 W^T Y                                  (2.15)
 * with instruments W (N x p) correlated with X but not with E (2.14) is consistent.
 * Instruments are usually the regressor rebuilt from an auxiliary model driven by the
 * input only (see vibid_arx_iv below).
 *
 * The batch accumulator keeps W^T X, W^T W, W^T Y, X^T X, X^T Y, Y^T Y (the IV estimate
 * is a cross-product estimator by nature; the solve is rank-revealing). Memory
 * O(p^2 + p q + q^2), allocated in create; adding rows allocates nothing.
 */
#ifndef VIBID_IV_H
#define VIBID_IV_H

#include <vibid/common.h>
#include <vibid/lsq.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ---------------- batch IV ---------------- */
typedef struct vibid_iv vibid_iv;

/* p >= 1 parameters, q >= 1 outputs, p + q <= 4096. NULL on bad arguments. */
VIBID_API vibid_iv *vibid_iv_create(size_t n_params, size_t n_outputs);
VIBID_API vibid_status vibid_iv_reset(vibid_iv *iv);
VIBID_API void vibid_iv_destroy(vibid_iv *iv);

/* Adds n_rows rows: X and W n_rows x p, Y n_rows x q, column-major; weights as in
 * vibid_lsq_add_rows (NULL for all 1). Allocates nothing. */
VIBID_API vibid_status vibid_iv_add_rows(vibid_iv *iv, size_t n_rows, const double *X, const double *W,
                                         const double *Y, const double *weights);

/* Theta (p x q). VIBID_E_NOT_IDENTIFIABLE when W^T X is numerically singular (rank in
 * info->rank; rank tolerance 1e-10 relative, after column scaling). */
VIBID_API vibid_status vibid_iv_solve(const vibid_iv *iv, double *theta, vibid_lsq_info *info);

/* Standard errors (p x q) from the asymptotic covariance
 * sigma_j^2 (W^T X)^-1 (W^T W) (X^T W)^-1, sigma_j^2 the residual variance of output j
 * at the current estimate. Needs n_rows > p. */
VIBID_API vibid_status vibid_iv_stderr(const vibid_iv *iv, double *stderr_out);

/* ---------------- recursive IV ---------------- */
/* Recursive form of (2.15), analogous to (2.6)/(2.7):
 *   K = P w / (gamma + x^T P w),  Theta += K (y^T - x^T Theta),  P = (P - K x^T P) / gamma,
 * P = (W^T X)^-1 is not symmetric, so the covariance form is used; the trace bound of
 * rls.h is available against wind-up. One equation per sample (m = 1). */
typedef struct vibid_riv vibid_riv;

typedef struct vibid_riv_config {
    size_t n_params;    /* p, 1..1024 */
    size_t n_outputs;   /* q, 1..1024 */
    double forgetting;  /* (0, 1] */
    double alpha;       /* P0 = alpha^-1 I, > 0 */
    int trace_bound;    /* non-zero: bound |trace(P)| by trace_max as in rls.h */
    double trace_max;   /* > 0; default p / alpha */
} vibid_riv_config;

VIBID_API void vibid_riv_config_init(vibid_riv_config *cfg, size_t n_params, size_t n_outputs);
VIBID_API vibid_riv *vibid_riv_create(const vibid_riv_config *cfg);
VIBID_API vibid_status vibid_riv_reset(vibid_riv *riv);
VIBID_API void vibid_riv_destroy(vibid_riv *riv);
/* Start from theta0 (p x q, NULL = 0) and P0 (p x p, NULL = alpha^-1 I), e.g. from an
 * LS estimate; also what reset returns to. */
VIBID_API vibid_status vibid_riv_set_prior(vibid_riv *riv, const double *theta0, const double *P0);
/* One sample: regressor x (p), instrument w (p), targets y (q). Allocates nothing;
 * non-finite input gives VIBID_E_NONFINITE and leaves the state unchanged. */
VIBID_API vibid_status vibid_riv_update(vibid_riv *riv, const double *x, const double *w, const double *y);
VIBID_API vibid_status vibid_riv_theta(const vibid_riv *riv, double *theta);
/* Current P (p x p, column-major), the recursive counterpart of (W^T X)^-1: for
 * monitoring wind-up and the trace bound. Allocates nothing. */
VIBID_API vibid_status vibid_riv_covariance(const vibid_riv *riv, double *P);

/* ---------------- ARX models and auxiliary-model instruments ---------------- */
/* Single-output difference equation with n_inputs inputs:
 *   y_k + a_1 y_{k-1} + ... + a_na y_{k-na}
 *       = sum_j ( b_j,0 u_j,k-nk + ... + b_j,nb-1 u_j,k-nk-nb+1 ) + e_k
 * Parameter layout: theta = [a_1 .. a_na, b_1,0 .. b_1,nb-1, b_2,0 .. , b_n_inputs,nb-1],
 * p = na + n_inputs * nb. Regressor x_k = [-y_{k-1} .. -y_{k-na}, u terms].
 * The second-order difference form (1.16) of a one-mass oscillator is na = 2. */
typedef struct vibid_arx_spec {
    size_t na;        /* output lags, 0..64 */
    size_t nb;        /* taps per input, 0..64 (na + nb >= 1) */
    size_t nk;        /* input delay in samples, 0..64 */
    size_t n_inputs;  /* 0..64 (0 only with nb = 0) */
} vibid_arx_spec;

/* Number of parameters p of the spec, or 0 if the spec is invalid. */
VIBID_API size_t vibid_arx_n_params(const vibid_arx_spec *spec);

/* Plain LS estimate from y (N) and u (N x n_inputs, column-major; may be NULL when
 * n_inputs = 0). Uses the rows k = max(na, nk + nb - 1) .. N-1. theta (p); stderr_out
 * (p) may be NULL. Allocates O(p^2). */
VIBID_API vibid_status vibid_arx_ls(const vibid_arx_spec *spec, size_t n_samples, const double *y,
                                    const double *u, double *theta, double *stderr_out);

/* IV estimate with instruments from an auxiliary model driven by the input only: start
 * from the LS estimate, simulate the model output y_aux from u with the current
 * estimate, build the instruments from y_aux in place of y, solve (2.15), and repeat
 * n_iterations times (1..100; 3-5 is typical: the estimate stops changing). If an
 * intermediate estimate gives an unstable auxiliary model, its poles are reflected
 * into the unit circle before simulating. theta (p), stderr_out (p, may be NULL).
 * Allocates O(N) scratch. */
VIBID_API vibid_status vibid_arx_iv(const vibid_arx_spec *spec, size_t n_samples, const double *y,
                                    const double *u, size_t n_iterations, double *theta,
                                    double *stderr_out);

/* Simulates the noise-free model output y_sim (N) from u with parameters theta, zero
 * initial conditions (y_k = 0 for k < start row). Useful for validation and for
 * building instruments by hand. Returns VIBID_E_DIVERGED when the output overflows
 * (unstable theta); y_sim then holds the samples before the overflow. */
VIBID_API vibid_status vibid_arx_simulate(const vibid_arx_spec *spec, const double *theta,
                                          size_t n_samples, const double *u, double *y_sim);

#ifdef __cplusplus
}
#endif
#endif
