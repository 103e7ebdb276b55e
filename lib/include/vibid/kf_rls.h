/* vibid/kf_rls.h: joint state and parameter estimation for incompletely measured linear
 * systems, paper (3.16) and the extended Kalman filter of ref. [11].
 *
 * Model (1.14)/(3.11):  x_{k+1} = G x_k + H u_k + n_k,   z_{k+1} = U x_{k+1} + v_{k+1},
 *   x n states, u r known inputs (r may be 0), z nz measurements, n_k ~ (0, R_b) the
 *   process noise (e.g. H_w R_w H_w^T for an unmeasured white excitation w),
 *   v ~ (0, R_v) white measurement noise. Rows first_free_row..n-1 of [G H] are
 *   unknown ("free"); the rows above are known (e.g. the kinematic rows
 *   x_{k+1} = x_k + h r_k of (4.3)) and stay at their start values.
 *
 * Methods:
 *  - VIBID_KFRLS_PAPER: the algorithm after (3.16). Per step: Kalman prediction with the
 *    newest G, H (x* = G x + H u, S* = G S G^T + R_b), correction with z (gain
 *    L = S* U^T (U S* U^T + R_v)^-1, Joseph form S = (I - L U) S* (I - L U)^T + L R_v L^T,
 *    symmetrised), then one recursive-LS step (vibid_rls, Bierman UD form) of the free
 *    rows of [G H] on the regressor [x_{k|k}; u_k] with target x_{k+1|k+1}; the next
 *    prediction uses the new [G H]. Cheap (O(n^3) per step), but the regressor is a
 *    filtered state, so the estimate carries an errors-in-variables bias. Limitation
 *    (measured, docs/kf.md): an input acting on an unmeasured state (a force on the
 *    velocity row with only positions measured) reaches z one step after the RLS step
 *    that could learn it, so its column of H is not learnt (the regression confirms the
 *    start value); the filter then becomes inconsistent and the NIS check reports
 *    VIBID_E_DIVERGED. Use the EKF for such inputs.
 *  - VIBID_KFRLS_EKF: extended Kalman filter on the augmented state [x; theta], theta the
 *    free rows of [G H] stacked row by row (row i: G(i, 0..n-1), H(i, 0..r-1)), constant
 *    up to a random walk of variance param_noise per step. Same Joseph-form update on
 *    dimension n_a = n + n_free (n + r). Costs O(n_a^3) per step; takes the coupling
 *    between state and parameter errors into account.
 * S (the state covariance; for the EKF the augmented one) stays symmetric and, if R_v is
 * positive definite, positive definite (Joseph form). With R_v = 0 (noise-free
 * measurement) S is only positive semi-definite: singular along the measured directions.
 *
 * Start procedure (start values matter, as the paper says). vibid_kfrls_start sets
 * G0, H0, x0, S0 and P_theta0, the prior covariance of each free row of [G H]. A good
 * start comes from the input-output form (vibid/io_form.h): vibid_ioform_estimate on the
 * first samples, vibid_ioform_recover_g for the free entries of G (G_cov gives P_theta0,
 * inflated by a factor ~10 so that the filter does not count those samples twice),
 * x0 = the first measured values with the unmeasured states 0, S0 = diag of the expected
 * state variance. In the PAPER method the RLS prior is theta0 = the free rows and
 * P0 = P_theta0 / sigma_e^2, sigma_e^2 the mean of R_b's diagonal over the free rows (the
 * regression's equation-error variance when the states are exact).
 *
 * Bad input and divergence (defined behaviour, each tested):
 *  - z_next == NULL: missing sample. Time update only (prediction; S grows); in the
 *    PAPER method the RLS is not updated. Returns VIBID_OK.
 *  - NaN/Inf in z_next or u: VIBID_E_NONFINITE, the object is left unchanged (the sample
 *    is rejected; pass NULL for a time update instead).
 *  - The innovation covariance U S* U^T + R_v not positive definite: VIBID_E_NUMERICAL,
 *    unchanged.
 *  - Divergence: a non-finite new state or covariance, a state or covariance entry
 *    beyond state_limit (resp. state_limit^2), a negative diagonal of S, or the
 *    exponentially averaged normalised innovation squared (NIS, nu^T (U S* U^T + R_v)^-1 nu
 *    per measurement, memory nis_memory, expected value 1) above nis_limit: returns
 *    VIBID_E_DIVERGED, keeps the last good state and marks the estimator diverged: every
 *    later step returns VIBID_E_DIVERGED until vibid_kfrls_start or vibid_kfrls_reset.
 *    The getters keep returning the last good values.
 *
 * Real time: vibid_kfrls_step and the getters allocate nothing and take no lock. Cost per
 * step about 4 n_a^3 + 2 n_a^2 nz + nz^3 / 6 multiply-adds (+ the RLS step,
 * ~2 p^2 + 2 p n_free, p = n + r, in the PAPER method); n_a = n for PAPER.
 */
#ifndef VIBID_KF_RLS_H
#define VIBID_KF_RLS_H

#include <vibid/common.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct vibid_kfrls vibid_kfrls;

typedef enum vibid_kfrls_method {
    VIBID_KFRLS_PAPER = 0,
    VIBID_KFRLS_EKF = 1
} vibid_kfrls_method;

typedef struct vibid_kfrls_config {
    size_t n_states;          /* n, 1..32 */
    size_t n_meas;            /* nz, 1..n */
    size_t n_inputs;          /* r, 0..32 */
    size_t first_free_row;    /* rows first_free_row..n-1 of [G H] are estimated, 0..n-1 */
    vibid_kfrls_method method;
    double forgetting;        /* PAPER: RLS forgetting factor, (0, 1]; default 1 */
    double param_noise;       /* EKF: random-walk variance of each parameter per step, >= 0;
                                 default 0 (constant parameters) */
    double nis_limit;         /* divergence when the averaged NIS per measurement exceeds
                                 this, > 1; default 10 */
    double nis_memory;        /* NIS averaging factor lambda, (0, 1); default 0.98 (~50 steps) */
    double state_limit;       /* divergence when |x_i| > state_limit, > 0; default 1e12 */
} vibid_kfrls_config;

/* Defaults for n states, nz measurements and r inputs: first_free_row = 0, PAPER,
 * forgetting 1, param_noise 0, nis_limit 10, nis_memory 0.98, state_limit 1e12. */
VIBID_API void vibid_kfrls_config_init(vibid_kfrls_config *cfg, size_t n_states, size_t n_meas, size_t n_inputs);

/* Creates an estimator. All memory is allocated here. NULL on bad arguments (reason in
 * vibid_last_error()).
 *   U    nz x n measurement matrix, finite
 *   R_b  n x n process-noise covariance, symmetric positive semi-definite (it may be
 *        singular, e.g. zero on the kinematic rows)
 *   R_v  nz x nz measurement-noise covariance, symmetric positive semi-definite (0 allowed)
 * The estimator must be started (vibid_kfrls_start) before the first step. */
VIBID_API vibid_kfrls *vibid_kfrls_create(const vibid_kfrls_config *cfg, const double *U, const double *R_b,
                                          const double *R_v);

/* Frees the estimator. NULL is allowed. */
VIBID_API void vibid_kfrls_destroy(vibid_kfrls *kf);

/* Sets the start state (see "Start procedure") and makes it the state vibid_kfrls_reset
 * returns to. Clears the divergence mark and the statistics.
 *   G0        n x n, finite
 *   H0        n x r, or NULL for zeros (ignored when r = 0)
 *   x0        n, or NULL for zeros
 *   S0        n x n symmetric positive semi-definite, finite
 *   P_theta0  p x p (p = n + r) symmetric positive definite: prior covariance of each
 *             free row of [G H] (the same for every free row)
 * VIBID_E_NONFINITE, VIBID_E_OUT_OF_RANGE (not symmetric), VIBID_E_NUMERICAL (P_theta0
 * not positive definite); the object is unchanged on failure. Allocates nothing. */
VIBID_API vibid_status vibid_kfrls_start(vibid_kfrls *kf, const double *G0, const double *H0, const double *x0,
                                         const double *S0, const double *P_theta0);

/* Returns to the last start state. VIBID_E_STATE if never started. */
VIBID_API vibid_status vibid_kfrls_reset(vibid_kfrls *kf);

/* One step k -> k+1: input u_k (r values; NULL allowed when r = 0) and measurement
 * z_{k+1} (nz values, or NULL when the sample is missing). See above for the statuses;
 * on any failure the estimator is unchanged. VIBID_E_STATE before vibid_kfrls_start. */
VIBID_API vibid_status vibid_kfrls_step(vibid_kfrls *kf, const double *u, const double *z_next);

/* Filtered state x_{k|k} (n) and its covariance S (n x n; the state block for the EKF).
 * Either pointer may be NULL. */
VIBID_API vibid_status vibid_kfrls_state(const vibid_kfrls *kf, double *x, double *S);

/* Current model: G (n x n) and H (n x r). Either may be NULL. */
VIBID_API vibid_status vibid_kfrls_model(const vibid_kfrls *kf, double *G, double *H);

/* Standard errors of the free rows of [G H]: se is n_free x (n + r) column-major,
 * n_free = n - first_free_row, se[i + j n_free] for free row i and column j of [G H]. EKF: sqrt of the augmented covariance diagonal. PAPER: from the
 * RLS (vibid_rls_stderr); VIBID_E_INSUFFICIENT_DATA while it has too few samples. */
VIBID_API vibid_status vibid_kfrls_param_stderr(const vibid_kfrls *kf, double *se);

typedef struct vibid_kfrls_stats {
    unsigned long long n_steps;   /* accepted steps (with and without measurement) */
    unsigned long long n_missing; /* of which time updates only */
    double nis_avg;               /* averaged NIS per measurement (1 when consistent) */
    int diverged;                 /* 1 once divergence was detected */
} vibid_kfrls_stats;

VIBID_API vibid_status vibid_kfrls_get_stats(const vibid_kfrls *kf, vibid_kfrls_stats *stats);

#ifdef __cplusplus
}
#endif
#endif
