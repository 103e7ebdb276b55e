/* vibid/output_error.h: output-error (simulation-error) estimation of a stand's physical
 * parameters: the parameters, the initial state and constant sensor offsets that make the
 * stand's own model, driven by the measured inputs, reproduce the measured response
 * channels best (weighted least squares of the simulation error, Levenberg-Marquardt).
 *
 * Why: the equation-error estimators (LS, IV, RLS: identify.h) fit the equation of
 * motion sample by sample, with derivatives from differences. On real captures that is
 * fragile: a constant sensor offset enters every equation through the springs, few samples
 * per period make differences poor, and a weak unmodelled effect biases the equations in
 * ways no error bar sees. The output error measures what a user means by "the model
 * explains the data": the simulated response against the measured one. Started from the
 * equation-error estimate it converges in a few iterations.
 *
 * Model (model.h): M y'' + D y' + C y + cubic(y, s) = B u + c_b s + d_b s', driven by the
 * measured force inputs u and the measured base displacement s, which are smooth (linear
 * between samples) or held (constant over [t_k, t_k + h), a held base kicking the
 * velocities through its dampers by M^-1 d_b (s_k - s_{k-1}) at t_k) as the model
 * declares (vibid_model_set_hold). Simulated:
 *  - linear stands exactly: x_{k+1} = E [x_k; e_k; e'_k], E the top rows of the matrix
 *    exponential of the system augmented with the inputs e and their slopes e'. The
 *    sensitivities to the parameters come from the Frechet derivative of that exponential
 *    (the exponential of the block matrix [A dA; 0 A]), exact to rounding;
 *  - stands with cubic springs by the classical Runge-Kutta method with `substeps` steps per
 *    sample (automatic: at most 0.1 rad of the highest natural frequency of the start
 *    values per step, relative frequency error below 1e-6), the sensitivities by the same
 *    steps on the forward sensitivity equations (the exact derivative of the discrete
 *    simulation, not a finite difference).
 * Measured response channels: displacements, velocities and accelerations of nodes (an
 * acceleration is the model's y'' at the sample). A base velocity or acceleration channel
 * is not used (the base enters through its displacement, which must be measured when an
 * element touches the base). A stand with a disturbance gets the prediction-error fit
 * below instead (same calls).
 *
 * Estimated: the p unknowns of the model, the initial state x0 = [y(t_0); y'(t_0)] (2n),
 * and (config.offsets, the default) one constant offset per measured response channel
 * (a sensor's zero error, in the channel's units: measured = true + offset).
 * Cost: sum over channels j and samples k of (z_jk - yhat_jk - o_j)^2 / s_j^2, s_j the
 * residual RMS of channel j (first from the start values; with several response channels
 * a second round re-weights with the converged residuals: the maximum-likelihood weights
 * for white noise of unknown level per channel). Non-finite response samples are left
 * out of the cost; a non-finite input sample is refused (VIBID_E_NONFINITE naming it).
 *
 * Levenberg-Marquardt on the Jacobi-scaled Gauss-Newton information; physical bounds
 * (masses > 0, springs and dampers >= 0) by projection. Converged when the predicted
 * decrease of the cost (in units of the weighted chi^2) is below 1e-8, i.e. the estimate
 * is within 1e-4 of its standard errors of the optimum. Several start vectors can be
 * given; the fit with the smallest cost is kept.
 *
 * Standard errors: sandwich H^-1 G H^-1 with H the Gauss-Newton information and G the
 * covariance of the score (gradient) over n_blocks blocks of consecutive samples (batch
 * means), so that coloured residuals and model error (which make the residuals coloured)
 * widen the error bars instead of being assumed white. With fewer than 8 blocks of 50
 * samples the fit is refused as too short for error bars.
 *
 * Input path: the samples do not say how a smooth input moved between them; the fit
 * takes the straight line (what vibid-sim's noise and PRBS excitations do), a real
 * shaker's continuous force does not. The fit also measures how much that assumption
 * matters: one Gauss-Newton step of the cost with the inputs on the local parabola
 * through neighbouring samples (second derivative from the second differences) gives the
 * estimate's shift (vibid_oe_interp_shift) and its size in standard errors
 * (vibid_oe_fit_info.interp_z), and the same pass tells which path the data prefer
 * (interp_evidence: the drop of the weighted cost from the line's fit to the parabola's
 * Gauss-Newton optimum). Where the shift exceeds 1 se the error bars do not cover the
 * unknown input path (a triangle wave's corners between samples; a sine at 10 samples per
 * period moves a gain by about (2 pi / 10)^2 / 12 = 3 %), unless the data show decisively
 * that the straight line is the path (captures simulated with inputs linear between
 * samples): input_path_uncovered says which, and vibidd and vibid_ident flag such an
 * estimate `U`. Held inputs are exact and have no shift. Costs one more pass with
 * sensitivities.
 *
 * A fit that fails (no convergence within max_iterations, a parameter on its bound, an
 * information matrix that is singular in some direction, an unstable simulation from
 * every start) returns its status and reason (vibid_last_error) and
 * vibid_oe_fit_info.failure; the best parameters found stay readable but are not an
 * estimate to report.
 *
 * Cost per iteration: O(N (4n^2 (p + 2n) + 2n N_a p)) for N samples, N_a = 2n + 2 (r + 1)
 * (linear), times 4 substeps for cubic stands; a fit allocates (not for real-time paths:
 * vibidd runs it in a low-priority thread on a copy of its samples).
 *
 * Stands with disturbances (vibid_model_add_disturbance: unmeasured random forces, e.g. a
 * machine in service): the simulation error is no measure there (the response is mostly
 * the disturbances'), so the fit is the maximum-likelihood prediction-error fit of the
 * stand's steady-state Kalman predictor (lib/src/prediction_error.cpp). The stand is
 * discretised exactly with the disturbances as held white samples (model.h) and the
 * measured inputs smooth or held as declared; an accelerometer on a node a disturbance
 * acts on feels it directly (process and measurement noise correlated, taken into
 * account). Estimated: the p unknowns, the standard deviation of every disturbance whose
 * std is unknown (0) and of every response channel's sensor noise that is not declared
 * (vibid_model_set_noise), and (config.offsets) one offset per response channel. Cost: the
 * innovations' negative log-likelihood 1/2 sum_k (eps_k' S^-1 eps_k + log det S), S their
 * covariance; the predictor starts at the stationary mean (x = 0) and its start-up
 * transient (7 time constants of its slowest pole at the start values, at most a tenth of
 * the record) is left out of the cost. The predictor's gain is a function of the
 * parameters and its derivative is part of the gradient: unlike the EKF, which treats the
 * parameters as states and so ignores it (Ljung 1979), the estimate is consistent. A
 * sample with a non-finite response channel gets no measurement update and is left out
 * of the cost. Fisher scoring with Levenberg-Marquardt and physical bounds; the
 * derivatives of the predictor's matrices (exponential, Riccati solution) are central
 * differences of those small matrices (relative step 1e-5), the sensitivities along the
 * record are propagated exactly. Standard errors: the sandwich over blocks, as above. A
 * sensor noise that the data do not determine (far below what the disturbances put on its
 * channel) is not a failure; its standard error is infinite. Not taken: cubic springs and
 * a moving base (vibid_oe_create refuses them: the EKF takes those). No input-path check
 * (interp_z 0). The initial state is not estimated (x0 reads as zeros). Cost per
 * iteration: O(N (2n)^2 (p + q + ny)) plus 2 (p + q) exponentials and Riccati solutions, q
 * the unknown noise intensities. */
#ifndef VIBID_OUTPUT_ERROR_H
#define VIBID_OUTPUT_ERROR_H

#include <vibid/common.h>
#include <vibid/model.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct vibid_oe vibid_oe;

typedef struct vibid_oe_config {
    double sample_time;       /* h in s, > 0 */
    int offsets;              /* non-zero (default): estimate a constant offset per measured response channel */
    unsigned max_iterations;  /* Levenberg-Marquardt iterations per start and round, 1..10000, default 100 */
    unsigned substeps;        /* Runge-Kutta steps per sample for cubic stands, 0 = automatic (default), <= 1000 */
    unsigned n_blocks;        /* blocks of the sandwich covariance, 0 = automatic (default: 32, fewer
                                 for short records, at least 50 samples each), else 8..1024 */
} vibid_oe_config;

/* Why a fit is not an estimate (vibid_oe_fit_info.failure); 0 = none. */
#define VIBID_OE_NO_CONVERGENCE 1u  /* max_iterations reached */
#define VIBID_OE_BOUND 2u           /* a parameter ended on its physical bound */
#define VIBID_OE_SINGULAR 4u        /* the information matrix is singular in some direction */
#define VIBID_OE_UNSTABLE 8u        /* the simulation diverged from every start */

typedef struct vibid_oe_fit_info {
    unsigned failure;          /* VIBID_OE_* bits, 0 for a sound fit */
    unsigned iterations;       /* accepted and rejected steps, all rounds, of the kept start */
    size_t start;              /* index of the start vector kept */
    size_t n_samples;          /* samples of the fit */
    size_t n_response;         /* measured response channels (= offsets when estimated) */
    size_t n_blocks;           /* blocks behind the covariance */
    double cost;               /* final weighted cost (half the weighted sum of squares) */
    double rcond;              /* reciprocal condition of the Jacobi-scaled information */
    double interp_z;           /* max over the parameters of |shift_i| / se_i (vibid_oe_interp_shift):
                                  > 1 when the estimate depends on the inputs' unknown path between
                                  samples by more than its standard error; 0 without smooth inputs */
    double interp_evidence;    /* which input path the data prefer ("Input path"): > 0 the parabola,
                                  < 0 the straight line; a log-likelihood ratio in chi-square units,
                                  deflated for coloured residuals; 0 without smooth inputs */
    int input_path_uncovered;  /* 1: the error bars do not cover the input path (interp_z > 1 and the
                                  data do not prefer the straight line by VIBID_OE_PATH_DECISIVE);
                                  the estimate is to be flagged VIBID_QUALITY_SE_INVALID */
} vibid_oe_fit_info;

/* The evidence (vibid_oe_fit_info.interp_evidence) beyond which the data decide the input
 * path: 10, a likelihood ratio of e^5 (about 150:1), "very strong" on Jeffreys' scale. */
#define VIBID_OE_PATH_DECISIVE 10.0

/* Defaults for sample time h: offsets on, 100 iterations, automatic substeps and blocks. */
VIBID_API void vibid_oe_config_init(vibid_oe_config *cfg, double sample_time);

/* Creates an output-error fit (a prediction-error fit for a stand with disturbances) for a
 * finalized model (copied). NULL with the reason (vibid_last_error) when the model has
 * nothing unknown, touches the base without a measured base displacement, has a
 * disturbance and a cubic spring or a base, or when the configuration is out of range. */
VIBID_API vibid_oe *vibid_oe_create(const vibid_model *model, const vibid_oe_config *cfg);
VIBID_API void vibid_oe_destroy(vibid_oe *oe);

/* Dimensions: response channels (the offsets' order: the model's channel order, inputs and
 * base channels left out) and, for each, its index in the sample (response_channels,
 * n_response entries, may be NULL). */
VIBID_API vibid_status vibid_oe_dims(const vibid_oe *oe, size_t *n_response, size_t *response_channels);

/* Fits to n_samples samples: channels n_samples x n_channels, column-major (one column per
 * model channel, model.h), from each of n_starts start vectors (p x n_starts, column-major,
 * model units; n_starts >= 1). Keeps the fit with the smallest cost. VIBID_OK for a sound
 * fit; otherwise the status (VIBID_E_NUMERICAL for a singular information matrix or an
 * unstable simulation, VIBID_E_DIVERGED for no convergence or a bound) with the reason,
 * and the best parameters found stay readable. Allocates. */
VIBID_API vibid_status vibid_oe_fit(vibid_oe *oe, size_t n_samples, const double *channels, size_t n_starts,
                                    const double *theta_starts);

/* The last fit: theta (p), standard errors (p, may be NULL), covariance (p x p, may be
 * NULL), offsets and their standard errors (n_response each, may be NULL; zero when not
 * estimated), initial state x0 (2 n: displacements, velocities; may be NULL), info (may be
 * NULL). VIBID_E_STATE before a fit. */
VIBID_API vibid_status vibid_oe_result(const vibid_oe *oe, double *theta, double *se, double *cov, double *offsets,
                                       double *offsets_se, double *x0, vibid_oe_fit_info *info);

/* The last fit's dependence on the inputs' path between samples (above, "Input path"):
 * shift (p) = how far, to first order, the estimate moves when every smooth input
 * follows the local parabola through its neighbouring samples instead of the straight
 * line (model units; 0 without smooth inputs; inf when that simulation diverges).
 * VIBID_E_STATE before a fit. */
VIBID_API vibid_status vibid_oe_interp_shift(const vibid_oe *oe, double *shift);

/* The noise intensities of the last prediction-error fit (a stand with disturbances):
 * each disturbance's standard deviation (n_disturbances, N) and each response channel's
 * sensor noise standard deviation (n_response, the channel's units), with their standard
 * errors (0 for a declared value; inf where the data do not determine it). Any pointer may
 * be NULL. VIBID_E_UNSUPPORTED for a stand without disturbance, VIBID_E_STATE before a fit. */
VIBID_API vibid_status vibid_oe_noise(const vibid_oe *oe, double *disturbance_std, double *disturbance_se,
                                      double *noise_std, double *noise_se);

/* The last prediction-error fit's steady-state predictor (a stand with disturbances: its
 * parameters, noise intensities and offsets) run over other samples (channels: n_samples x
 * n_channels, column-major, model.h), from the stationary mean: innovations receives the
 * one-step prediction errors (n_samples x n_response, column-major; NaN where the sample
 * has a non-finite response channel, which gets no update), innovation_cov (may be NULL)
 * their covariance S (n_response x n_response, column-major). The model adequacy of a
 * stand with disturbances: on a held-out part the innovations are white with covariance S
 * where the model explains the data (docs/python.md). VIBID_E_UNSUPPORTED for a stand
 * without disturbance, VIBID_E_STATE before a fit, VIBID_E_NONFINITE for a non-finite
 * input sample. Allocates. */
VIBID_API vibid_status vibid_oe_predict(const vibid_oe *oe, size_t n_samples, const double *channels,
                                        double *innovations, double *innovation_cov);

/* Simulates the model (with disturbances: its deterministic part, the disturbances zero)
 * with parameters theta (p), initial state x0 (2 n, NULL = at rest)
 * and offsets (n_response, NULL = none) driven by the inputs of channels (n_samples x
 * n_channels, column-major): out receives n_samples x n_response simulated response
 * channels (column-major, offsets added). The response columns are read only for their
 * size: the largest measured displacement sets a cubic stand's first guess of RK4 steps,
 * and a simulation beyond 10^6 times the largest measured value counts as diverged (NaN
 * there is fine). VIBID_E_NUMERICAL when the simulation diverges. Allocates. */
VIBID_API vibid_status vibid_oe_simulate(const vibid_oe *oe, const double *theta, const double *x0,
                                         const double *offsets, size_t n_samples, const double *channels,
                                         double *out);

#ifdef __cplusplus
}
#endif
#endif
