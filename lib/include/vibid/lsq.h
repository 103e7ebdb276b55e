/* vibid/lsq.h: batch least squares (paper (2.3)/(2.4)), weighted least squares and the
 * Gauss-Markov estimate (2.11)/(2.12), for matrix-valued parameters.
 *
 * Model: Y = X Theta + E, with
 *   X     N x p   regressor rows x_k^T (shared by all outputs),
 *   Y     N x q   one column per output (e.g. one per coordinate, as in (3.3)/(3.4)),
 *   Theta p x q   unknown parameters, estimated by minimising trace(E^T S E) (3.4),
 *   S     weighting: per-row weights (diagonal S) or the inverse of a full row
 *         covariance (Gauss-Markov).
 *
 * The accumulator never stores X: it keeps the upper-triangular factor R of the
 * (weighted) augmented matrix [X Y], (p + q) x (p + q), into which blocks of up to 256
 * rows are merged with Householder reflections (an orthogonal, QR-based method: X^T X
 * is never formed or inverted). The
 * estimate is a triangular solve with R; the numerical rank is read from the singular
 * values of R's regressor block after scaling its columns to unit norm, so that
 * parameters of very different magnitude (a stiffness of 1e6 N/m beside a damping of
 * 300 N s/m) do not look rank-deficient.
 *
 * Memory: (p + q)^2 + b (p + q) + O(p + q) doubles, b = the rows per block (8..256,
 * about 3072 / (p + q)), allocated in vibid_lsq_create.
 * Cost: vibid_lsq_add_rows costs about 2 (p + q)^2 flops per row and allocates nothing;
 * vibid_lsq_solve costs O(p^3 + p^2 q) and may allocate.
 */
#ifndef VIBID_LSQ_H
#define VIBID_LSQ_H

#include <vibid/common.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct vibid_lsq vibid_lsq;

/* Summary of a solve. */
typedef struct vibid_lsq_info {
    size_t n_rows;      /* rows accumulated with weight > 0 */
    size_t rank;        /* numerical rank of the column-scaled regressor, 0..p */
    double rcond;       /* reciprocal condition number of the column-scaled regressor, [0, 1] */
    double sum_weights; /* sum of row weights (equals n_rows when unweighted) */
} vibid_lsq_info;

/* Creates an empty accumulator for n_params (p >= 1) parameters and n_outputs
 * (q >= 1) outputs; p + q <= 4096. Returns NULL (reason in vibid_last_error())
 * on bad arguments or when out of memory. */
VIBID_API vibid_lsq *vibid_lsq_create(size_t n_params, size_t n_outputs);

/* Forgets all rows; the accumulator is as new. */
VIBID_API vibid_status vibid_lsq_reset(vibid_lsq *lsq);

/* Frees the accumulator. NULL is allowed and does nothing. */
VIBID_API void vibid_lsq_destroy(vibid_lsq *lsq);

/* Relative tolerance for the numerical rank: a scaled singular value s_i counts when
 * s_i > tol * s_max. Range (0, 1); default 1e-10 (data with 10 significant digits). */
VIBID_API vibid_status vibid_lsq_set_rank_tolerance(vibid_lsq *lsq, double tol);

/* Adds n_rows rows.
 *   X       n_rows x p, column-major (X[k + i * n_rows] = regressor i of row k)
 *   Y       n_rows x q, column-major
 *   weights n_rows row weights >= 0 (finite), or NULL for all 1. A weight w scales
 *           the row's squared residual, i.e. w = 1 / variance of that row's error.
 * All values must be finite. On any error no row is added. Allocates nothing. */
VIBID_API vibid_status vibid_lsq_add_rows(vibid_lsq *lsq, size_t n_rows, const double *X,
                                          const double *Y, const double *weights);

/* Gauss-Markov (2.12): adds n_rows rows whose errors are correlated with the full
 * covariance Sigma (n_rows x n_rows, symmetric positive definite, column-major; the
 * same Sigma applies to every output column). The rows are whitened with the Cholesky
 * factor L of Sigma (L^-1 X, L^-1 Y) and then accumulated, which minimises
 * trace(E^T Sigma^-1 E). Use it for one block of structured equations per sample or for
 * a whole record at once. Fails with VIBID_E_NUMERICAL if Sigma is not positive
 * definite. Allocates O(n_rows^2) scratch (not for real-time paths). */
VIBID_API vibid_status vibid_lsq_add_correlated(vibid_lsq *lsq, size_t n_rows, const double *X,
                                                const double *Y, const double *Sigma);

/* Solves for Theta (p x q, column-major). Returns VIBID_E_INSUFFICIENT_DATA before any
 * row, VIBID_E_NOT_IDENTIFIABLE when the numerical rank is below p (Theta is then not
 * written; info->rank says how far it is; see vibid_lsq_null_space). info may be NULL;
 * when given it is filled in on success and on VIBID_E_NOT_IDENTIFIABLE. */
VIBID_API vibid_status vibid_lsq_solve(const vibid_lsq *lsq, double *theta, vibid_lsq_info *info);

/* Uncertainty of the last solvable state.
 *   param_cov    p x p: (X^T S X)^-1, the unscaled parameter covariance, or NULL.
 *   residual_cov q x q: E^T S E / (n_rows - p), the residual (co)variance of the
 *                outputs, or NULL. Needs n_rows > p.
 * Cov(Theta_ij, Theta_kl) = param_cov_ik * residual_cov_jl. */
VIBID_API vibid_status vibid_lsq_covariance(const vibid_lsq *lsq, double *param_cov,
                                            double *residual_cov);

/* Standard errors (p x q): sqrt(param_cov_ii * residual_cov_jj). Needs n_rows > p. */
VIBID_API vibid_status vibid_lsq_stderr(const vibid_lsq *lsq, double *stderr_out);

/* Directions in parameter space that the data cannot resolve: a basis of the
 * numerical null space of the regressor in the original, unscaled parameter
 * coordinates, each column of unit Euclidean norm (sign: largest component positive),
 * as the columns of basis (p x max_vectors, column-major). *n_vectors receives
 * p - rank (it may exceed max_vectors; only min(p - rank, max_vectors) columns are
 * written). A component of large magnitude names a parameter involved in the
 * dependency. basis may be NULL when max_vectors is 0. VIBID_E_INSUFFICIENT_DATA
 * before any row. */
VIBID_API vibid_status vibid_lsq_null_space(const vibid_lsq *lsq, double *basis, size_t max_vectors,
                                            size_t *n_vectors);

#ifdef __cplusplus
}
#endif
#endif
