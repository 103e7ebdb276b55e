/* vibid/rls.h: recursive least squares (paper (2.5)-(2.10)).
 *
 * Model per sample k: m scalar equations sharing one parameter matrix,
 *   y_k(i, :) = x_k(:, i)^T Theta + e_k(i, :),   i = 0..m-1,
 *   x_k   p x m  regressor, one column per equation (m = n_equations, e.g. one equation
 *                per degree of freedom of a structured multi-DOF model),
 *   y_k   m x q  targets, one column per output (q = n_outputs, several outputs
 *                sharing the regressor and hence P, as in (3.3)),
 *   Theta p x q.
 * With m = q = 1 this is the textbook RLS (2.6)/(2.7).
 *
 * Forms (selectable, same results in exact arithmetic):
 *  - VIBID_RLS_FORM_BIERMAN_UD (default): P = U D U^T with U unit upper triangular and
 *    D > 0 diagonal, updated by Bierman's algorithm. P stays symmetric positive definite
 *    by construction; this is the form to run for months.
 *  - VIBID_RLS_FORM_COVARIANCE: the plain update P <- (I - K x^T) P / gamma of (2.7),
 *    with x^T P taken as (P x)^T and no symmetrisation, kept for comparison; it loses
 *    symmetry and definiteness under rounding (with gamma < 1 the antisymmetric
 *    rounding error grows like gamma^-k) and winds up without excitation.
 *
 * Forgetting (2.9)/(2.10): P^-1 <- gamma P^-1 + x x^T once per sample (not per
 * equation), gamma in (0, 1]. Without excitation plain forgetting makes P grow like
 * gamma^-k ("wind-up"); VIBID_RLS_WINDUP_TRACE_BOUND guards against it by lowering the
 * forgetting of a sample just enough that trace(P) never exceeds trace_max (up to
 * rounding, relative ~p 1e-16): the forgetting applied is min(1, max(gamma,
 * trace(P) / trace_max)). A start state whose trace is above trace_max (e.g. alpha
 * smaller than p / trace_max) only suspends forgetting until the data lower trace(P)
 * below the bound; P is never inflated.
 *
 * Breakdown: an update that would leave P not positive definite or not finite (a D
 * entry not positive and finite, an innovation variance gamma + x^T P x <= 0 in the
 * covariance form, an overflow anywhere in the new state, e.g. after ~35000 unexcited
 * samples at gamma = 0.98 without the trace bound) is refused with VIBID_E_NUMERICAL
 * and the estimator is left exactly as it was.
 *
 * Equations within one sample are treated as uncorrelated unless an equation
 * covariance is set (vibid_rls_set_equation_covariance), in which case each sample's
 * x_k and y_k are whitened with its Cholesky factor first (the residual statistics below
 * are then those of the whitened equations).
 *
 * Uncertainty: the residual covariance of the outputs is estimated recursively from the
 * a-priori errors, Sigma_e = V / (n_eff - p) with V <- gamma V + e e^T / (1 + x^T P x /
 * gamma) and n_eff <- gamma n_eff + 1 per equation (gamma applied once per sample: for
 * the second and later equations of a sample the gamma terms are 1 and P, e are those
 * after the previous equation); Cov(Theta_ij, Theta_kl) = P_ik * Sigma_e,jl. With
 * forgetting 1 and the alpha prior, V is exactly the residual sum of squares of batch
 * LS with the prior rows, so Sigma_e = that / (N m - p). Standard errors are meaningful once n_eff > p and the prior is small
 * against the data (small alpha).
 *
 * Real time: vibid_rls_update, vibid_rls_predict and the getters allocate nothing, take
 * no lock and cost a fixed number of operations. An update costs about
 * (2 p^2 + 2 p q + 6 p) m multiply-adds (Bierman; 0.5 p^2 of it computes trace(P),
 * which also checks every new entry for overflow) or (3 p^2 + 2 p q + 2 p) m (covariance
 * form), plus O(q^2 m) for the residual statistics and O(m^2 (p + q)) for whitening when
 * enabled; the trace bound itself is O(1). vibid_rls_covariance costs p^3 / 6 in the
 * Bierman form (it rebuilds P from U and D), the other getters O(p q) or less.
 */
#ifndef VIBID_RLS_H
#define VIBID_RLS_H

#include <vibid/common.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct vibid_rls vibid_rls;

typedef enum vibid_rls_form {
    VIBID_RLS_FORM_BIERMAN_UD = 0,
    VIBID_RLS_FORM_COVARIANCE = 1
} vibid_rls_form;

typedef enum vibid_rls_windup {
    VIBID_RLS_WINDUP_NONE = 0,
    VIBID_RLS_WINDUP_TRACE_BOUND = 1
} vibid_rls_windup;

typedef struct vibid_rls_config {
    size_t n_params;         /* p, 1..1024 */
    size_t n_outputs;        /* q, 1..1024 */
    size_t n_equations;      /* m, scalar equations per sample, 1..1024 */
    vibid_rls_form form;
    double forgetting;       /* gamma, (0, 1]; 1 = no forgetting */
    double alpha;            /* P0 = alpha^-1 I (2.8), alpha > 0 and finite */
    vibid_rls_windup windup;
    double trace_max;        /* bound on trace(P) for TRACE_BOUND, > 0; default p / alpha */
} vibid_rls_config;

/* Fills cfg with defaults for p parameters and q outputs: m = 1, Bierman form,
 * forgetting 1, alpha 1e-6, windup none, trace_max p / alpha. */
VIBID_API void vibid_rls_config_init(vibid_rls_config *cfg, size_t n_params, size_t n_outputs);

/* Creates an estimator with Theta = 0 and P = alpha^-1 I. Returns NULL (reason in
 * vibid_last_error()) on bad configuration or when out of memory. All memory the
 * estimator will ever use is allocated here. */
VIBID_API vibid_rls *vibid_rls_create(const vibid_rls_config *cfg);

/* Returns to the start state: the prior set with vibid_rls_set_prior, else Theta = 0,
 * P = alpha^-1 I; clears the residual statistics and n_samples; adaptation enabled. The
 * equation covariance stays as set. */
VIBID_API vibid_status vibid_rls_reset(vibid_rls *rls);

/* Frees the estimator. NULL is allowed and does nothing. */
VIBID_API void vibid_rls_destroy(vibid_rls *rls);

/* Sets the start state and makes it the state that vibid_rls_reset returns to, e.g.
 * from a batch estimate (vibid_lsq_solve and the param_cov of vibid_lsq_covariance).
 *   theta0 p x q, or NULL for zeros
 *   P0     p x p symmetric positive definite, or NULL for alpha^-1 I. Asymmetry up to
 *          |P0_ij - P0_ji| <= 1e-9 sqrt(|P0_ii P0_jj|) (rounding in a computed
 *          covariance) is accepted and the mean of both triangles used; more gives
 *          VIBID_E_OUT_OF_RANGE.
 * Also resets the residual statistics (as vibid_rls_reset). VIBID_E_NONFINITE for
 * NaN/Inf, VIBID_E_NUMERICAL if P0 is not positive definite. Allocates nothing;
 * O(p^3 / 6) for the UD factorisation. */
VIBID_API vibid_status vibid_rls_set_prior(vibid_rls *rls, const double *theta0, const double *P0);

/* Covariance of the m equations' errors within one sample (m x m, symmetric positive
 * definite, same symmetry tolerance and status codes as P0 in vibid_rls_set_prior), or
 * NULL to go back to uncorrelated, equally weighted equations. Its Cholesky factor is
 * computed here (O(m^3 / 3)); allocates nothing. */
VIBID_API vibid_status vibid_rls_set_equation_covariance(vibid_rls *rls, const double *Sigma);

/* One sample: x is p x m, y is m x q (column-major). Non-finite input gives
 * VIBID_E_NONFINITE, a breakdown (see above) VIBID_E_NUMERICAL; either way the estimator
 * is left unchanged. With adaptation disabled the call only updates the residual
 * statistics (the a-priori errors at the frozen Theta, normalised by 1 + x^T P x, and
 * forgotten with the configured gamma) and n_samples; Theta and P stay as they are. */
VIBID_API vibid_status vibid_rls_update(vibid_rls *rls, const double *x, const double *y);

/* Enables (non-zero) or freezes (0) adaptation of Theta and P. */
VIBID_API vibid_status vibid_rls_set_adaptation(vibid_rls *rls, int enabled);

/* Prediction y = x^T Theta for x p x m; y is m x q. VIBID_E_NONFINITE for NaN/Inf in x. */
VIBID_API vibid_status vibid_rls_predict(const vibid_rls *rls, const double *x, double *y);

/* Current estimate, p x q. */
VIBID_API vibid_status vibid_rls_theta(const vibid_rls *rls, double *theta);

/* Current P (p x p, symmetric for the Bierman form; for the covariance form exactly the
 * stored matrix, asymmetry included). */
VIBID_API vibid_status vibid_rls_covariance(const vibid_rls *rls, double *P);

/* Residual covariance estimate Sigma_e (q x q); VIBID_E_INSUFFICIENT_DATA while
 * n_eff <= p. */
VIBID_API vibid_status vibid_rls_residual_covariance(const vibid_rls *rls, double *Sigma_e);

/* Standard errors of Theta (p x q): sqrt(P_ii Sigma_e,jj). Same condition as above. NaN
 * where a covariance-form P has lost definiteness (P_ii < 0). */
VIBID_API vibid_status vibid_rls_stderr(const vibid_rls *rls, double *stderr_out);

typedef struct vibid_rls_stats {
    unsigned long long n_samples; /* accepted calls to vibid_rls_update */
    double n_eff;                 /* effective number of equations, sum of gamma^i */
    double trace_p;               /* trace(P) now */
    double min_d;                 /* smallest diagonal of D (Bierman) or of P (covariance form) */
    double last_forgetting;       /* forgetting factor applied at the last sample (the
                                     configured one before the first sample) */
} vibid_rls_stats;

VIBID_API vibid_status vibid_rls_get_stats(const vibid_rls *rls, vibid_rls_stats *stats);

#ifdef __cplusplus
}
#endif
#endif
