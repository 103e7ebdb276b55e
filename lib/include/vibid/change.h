/* vibid/change.h: has a parameter changed? A sequential test on a recursive estimator's
 * track with a stated false-alarm rate, per parameter, and the smallest change it detects.
 *
 * Condition monitoring asks two things: "alarm at most R times a year when nothing has
 * changed" and "how small a change can you see". A rule like |theta - b| > 5 se answers
 * neither: the rows of a recursive estimator are strongly autocorrelated (with a memory of
 * 1 s and 10 rows/s neighbouring rows share 90 % of their data), so neither the number of
 * false alarms nor the detectable change follows from the per-row standard error.
 *
 * 1. Block estimates (the autocorrelation taken out). A recursive estimator with
 *    forgetting gamma per sample weighs the samples up to sample n by gamma^(n - j); the
 *    total weight of its estimate at row k (sample index n_k, counted from the estimator's
 *    first sample) is W_k = (1 - gamma^(n_k + 1)) / (1 - gamma) (n_k + 1 without
 *    forgetting). With stationary excitation the estimate is the weighted mean of the
 *    information of its samples, so
 *        theta_k = phi_k theta_(k-1) + (1 - phi_k) b_k,  phi_k = gamma^(n_k - n_(k-1)) W_(k-1) / W_k,
 *    where b_k is the estimate from the samples between the two rows alone. This object
 *    computes b_k = (theta_k - phi_k theta_(k-1)) / (1 - phi_k) for every pair of
 *    consecutive rows. The b_k of different rows come from disjoint samples: independent,
 *    with a constant variance sigma_b^2, and each jumps to a new value at once where theta
 *    follows it with the memory's lag. Exact for exponentially weighted least squares and
 *    IV with a constant information matrix; first order for IV with block statistics, the
 *    EKF (forgetting on the parameter covariance) and KF+RLS (tests/lib/test_change.c
 *    measures the false-alarm rate on a simulated recursive estimator).
 * 2. The reference: per parameter the mean m of the block estimates and their standard
 *    deviation sigma_b (the long-run one where neighbouring blocks correlate: from batches of
 *    10 blocks, used when the batches' variance exceeds the 95 % quantile of what independent
 *    blocks give, with the batches' degrees of freedom in n_sd; IV's blocks correlate, 0.3-0.45
 *    at lag 1, because its pre-filter, difference windows and instrument lag straddle the
 *    block boundaries), learned from the rows the caller marks (VIBID_CHANGE_LEARN) or given
 *    (vibid_change_set_reference; e.g. a saved one). A learned reference carries its
 *    uncertainty: m from N blocks has a standard error sigma_b / sqrt(N), sigma_b from
 *    N - 1 degrees of freedom. Both enter the thresholds (3).
 * 3. The test, per parameter: u_k = (b_k - m) / sigma_b, clipped to +-5 (one wild block
 *    cannot raise an alarm alone), drives a two-sided CUSUM (Page): S = max(0, S + u_k - k)
 *    and the same for -u_k. An alarm is RAISED when S reaches the threshold h. The allowance
 *    k is the one with the smallest detectable change within the horizon (4).
 *    Threshold: the false-alarm rate R per year (all parameters together; default 1) is
 *    split equally over the 2 p CUSUMs (Bonferroni: the joint rate is at most R; at the
 *    high thresholds of monitoring the exceedances of correlated parameters are nearly
 *    independent, so nearly R). The average run length of one CUSUM on N(0, 1) increments is
 *    Siegmund's ARL(k, h) = (exp(2 k b) - 2 k b - 1) / (2 k^2), b = h + 1.166 (Basseville &
 *    Nikiforov 1993, 5.2.2). With a learned reference the increments are
 *    (z + a / sqrt(N)) / w, a ~ N(0,1) the mean's error, w^2 ~ chi2(N-1)/(N-1) the scale's
 *    (Wilson-Hilferty). The false-alarm rate depends steeply on both (at 1 a year a mean
 *    0.1 sigma_b off changes it a hundredfold on one side), so h is chosen for the
 *    reference at the edge of its errors: |a| = 1.96 (the mean's 95 % interval) and w at
 *    its 5 % quantile. The rate is then at or below the target for at least 90 % of the
 *    references the learning period could have given; a short reference costs threshold
 *    (tests/lib/test_change.c prints it) and so detectable change. An exact reference
 *    (n_mean = n_sd = INFINITY) gets Siegmund's threshold. The rate is per year of rows
 *    (365.25 d x rows per second).
 * 4. Minimum detectable change (MDC), per parameter: the smallest step delta (in the
 *    parameter's unit) that the test raises with probability >= detection_probability
 *    within horizon_s seconds of sample time, from the random walk the CUSUM dominates:
 *    n (delta/sigma_b - k) - z_p sqrt(n + n^2 / N) >= h, n the rows in the horizon
 *    (conservative: the CUSUM's reset only helps; the n^2 / N
 *    term is the reference mean's error, which a long horizon cannot average away).
 * 5. The event: statistic S and threshold h of the CUSUM that fired, the estimated
 *    change with its standard error and the estimated onset. Among the rows since that CUSUM
 *    last left 0 (as far as a ring of the latest 4 horizons' blocks reaches) the onset is the
 *    maximum-likelihood split of a mean step (the start of the latest n blocks whose summed
 *    deviation S_n maximises S_n^2 / n: the CUSUM's last zero runs early when the change is
 *    large against its allowance); the change is the mean deviation of those n blocks, its
 *    standard error sqrt(max(sigma_b^2, s^2) / n + sigma_b^2 v) with s^2 their own variance
 *    (blocks after a change may scatter more than the reference's: an estimator out of its
 *    stationary regime) and v the reference's error (1 / N without covariates).
 *    With min_relative > 0 the alarm also needs |change| > min_relative |m| (a dead band
 *    for changes too small to matter; 0 by default).
 * 6. Operating conditions (covariates: temperature, speed, load). A stiffness that
 *    follows the temperature is no damage. With n_covariates > 0 each row comes with the
 *    covariates' values over its block (their mean over the samples since the previous
 *    row) and the reference is a regression of the block estimates on them:
 *        b_k = m + slope^T (x(c_k) - xbar) + e_k,   e_k ~ (0, sigma_b^2),
 *    x(c) the terms: the covariates (linear model), and where the data need it their
 *    squares and products (second-order model: a stiffness that follows temperature and
 *    load as k (1 + a dT)(1 + b dL) has the product dT dL; left out, its pattern returns
 *    in every cycle of the two, and a CUSUM sums it into false alarms: 19 raised in 6 h at
 *    a rate of 1 an hour, 6 expected, in the service benchmark). The second-order model is
 *    taken when the batches of 10 blocks (nearly independent, point 2) reject the linear
 *    one: their drop of the residual sum of squares against the second-order residual
 *    variance above the 99.9 % quantile of chi2 with the added terms' degrees of freedom,
 *    and at least 20 batches' degrees of freedom left. Fitted over the learned blocks
 *    (sigma_b from N - 1 - T degrees of freedom, T the terms modelled). The test runs on
 *    the compensated deviation b_k - m - slope^T (x(c_k) - xbar). The prediction's own
 *    error has the variance sigma_b^2 v(c), v(c) = 1 / N + d^T G d, d = x(c) - xbar,
 *    G = (sum_k d_k d_k^T)^-1: it grows with the distance from the reference's conditions.
 *    The thresholds (3) take the prediction at the edge of its 95 % interval where it is
 *    worst (the mean's shift 1.96 sqrt(v_ref), v_ref the largest v over the box of
 *    covariate ranges the reference saw, its corners, edge midpoints and centre:
 *    n_mean = 1 / v_ref in (3)), so inside that box the false-alarm rate holds as in (3). A block
 *    whose covariates lie outside the box is FLAGGED (vibid_change_state.out_of_range) and
 *    its deviation is weighed down by sqrt(v_ref / v(c)) < 1, which keeps the prediction's
 *    error within the thresholds' allowance (a conservative test: less power, never more
 *    false alarms) rather than trusting a fitted curve beyond the data. A covariate that
 *    did not vary over the reference (or duplicates another) is not modelled: a block with
 *    it outside its range is not tested at all (weight 0). The minimum detectable change is
 *    the one inside the box. A block with a non-finite covariate is neither learned nor
 *    tested.
 * 7. Clearing: a raised alarm stays until the data favour the reference again: a CUSUM of
 *    the log-likelihood ratio of "at the reference" against "changed by the estimated
 *    change d" (d in units of sigma_b, at most the clip 5, re-estimated at every block as the
 *    mean clipped increment since the onset over their spread since then (at least 1): the
 *    estimate at the raise is biased away from 0, blocks that scatter beyond the clip show a
 *    smaller mean than their raw one, and an estimator out of its stationary regime after a
 *    change (IV, the EKF) scatters more than sigma_b; a test that expected the raw change
 *    with unit spread cleared changes that persisted (a 1 % crack on a 3-DOF stand, IV:
 *    cleared twice in 90 s); increments are scaled by the same spread; its threshold is at least 3 blocks
 *    of the largest evidence (k + 5): one wild block of an estimator's transient must not
 *    clear a crack; allowance d / 2,
 *    threshold for the same rate) CLEARS it; then the test
 *    restarts at 0. A crack does not heal, so a persistent change stays raised.
 *
 * Rows. Every recursive row is pushed in order with its sample index: rows whose estimate
 * is not finite break the chain (the next row has no predecessor and forms no block);
 * rows pushed with use = 0 (an impossible estimate, a gap, a row not excited) keep the
 * chain but their block, and the next row's (which is computed from theirs), is neither
 * learned from nor tested (nor is a block with a
 * non-finite covariate). Rows of another estimate (an
 * output-error refinement over a window) are not part of the recursion: do not push them.
 *
 * Real time: create allocates (O(p) and the rings, 256 .. 8192 doubles per parameter); push,
 * get_param and reset allocate nothing and never
 * throw. end_learning and set_reference compute the thresholds (bisections, well under
 * 1 ms per parameter) and allocate nothing either.
 */
#ifndef VIBID_CHANGE_H
#define VIBID_CHANGE_H

#include <stddef.h>
#include <stdint.h>

#include <vibid/common.h>

#ifdef __cplusplus
extern "C" {
#endif

#define VIBID_CHANGE_ALARMS_PER_YEAR_DEFAULT 1.0
#define VIBID_CHANGE_HORIZON_DEFAULT 60.0      /* s */
#define VIBID_CHANGE_DETECTION_DEFAULT 0.9
#define VIBID_CHANGE_MIN_BLOCKS 10             /* learned blocks a reference needs per parameter
                                                  (plus one per covariate) */
#define VIBID_CHANGE_MAX_COVARIATES 4
/* terms of the covariate regression (point 6): q linear, and with the second-order model
 * q (q + 1) / 2 products, 14 at q = 4 */
#define VIBID_CHANGE_MAX_TERMS 14

typedef struct vibid_change vibid_change;

typedef struct vibid_change_config {
    size_t n_params;              /* parameters per row, 1 .. 4096 */
    double sample_rate_hz;        /* f_a of the sample indices, > 0 */
    double forgetting;            /* the estimator's gamma per sample, [0, 1] (1: no forgetting;
                                     0: each row's estimate comes from its own samples, disjoint
                                     from the previous row's, so b_k = theta_k: e.g. modes of
                                     non-overlapping windows, vibidd's output-only tracking) */
    double row_interval;          /* samples between rows, >= 1 (rows per year for the rate) */
    double false_alarms_per_year; /* R for all parameters together, > 0 (default 1) */
    double horizon_s;             /* of the minimum detectable change, > 0 (default 60 s) */
    double detection_probability; /* of the minimum detectable change, [0.5, 0.999] (default 0.9) */
    double min_relative;          /* dead band |change| > min_relative |m|, >= 0 (default 0) */
    size_t n_covariates;          /* covariates per row (6 above), 0 .. VIBID_CHANGE_MAX_COVARIATES
                                     (default 0) */
} vibid_change_config;

/* A parameter's reference (vibid_change_get_reference / vibid_change_set_reference). */
typedef struct vibid_change_reference {
    double mean;      /* m: the parameter's value, its unit */
    double block_sd;  /* sigma_b: standard deviation of one row's block estimate, > 0 */
    double n_mean;    /* blocks m was learned from (its standard error sigma_b / sqrt(n_mean));
                         INFINITY: m known exactly */
    double n_sd;      /* sigma_b's degrees of freedom + 1 (n_sd - 1 of them), >= 2; learned:
                         the blocks minus the modelled covariates; INFINITY: known exactly */
    /* With covariates (q = n_covariates; point 6 above). Per covariate (entries 0 .. q - 1): */
    double centre[VIBID_CHANGE_MAX_COVARIATES]; /* c_j's mean over the reference */
    double low[VIBID_CHANGE_MAX_COVARIATES], high[VIBID_CHANGE_MAX_COVARIATES]; /* c_j's range
                                                   over the reference, low <= high */
    double origin[VIBID_CHANGE_MAX_COVARIATES]; /* o_j: where the terms are measured from */
    /* The regression's terms x_t(c), t < n_terms: t < q the linear c_t - o_t; then, when
     * n_terms = q + q (q + 1) / 2 (the second-order model), the products
     * (c_i - o_i)(c_j - o_j) for i <= j in the order (0,0), (0,1) .. (0,q-1), (1,1) ..
     * n_terms 0: the first form of this struct, linear with x_j(c) - term_mean_j = c_j - centre_j
     * (origin and term_mean unused). */
    size_t n_terms;
    double term_mean[VIBID_CHANGE_MAX_TERMS];   /* x_t's mean over the reference */
    double slope[VIBID_CHANGE_MAX_TERMS];       /* d m / d x_t: the parameter's unit per the
                                                   term's */
    double gram_inv[VIBID_CHANGE_MAX_TERMS * VIBID_CHANGE_MAX_TERMS];
                      /* G = (sum_k d_k d_k^T)^-1 over the terms, T x T row-major in the first
                         T^2 entries (T = n_terms, or q for n_terms 0): the slopes' covariance
                         over sigma_b^2, symmetric, positive semi-definite; a term that is not
                         modelled (a covariate that did not vary, a product that duplicates
                         others) has its row and column 0 (and slope 0) */
} vibid_change_reference;

typedef enum vibid_change_phase {
    VIBID_CHANGE_LEARN = 0, /* the row belongs to the reference period */
    VIBID_CHANGE_TEST = 1   /* the row is tested (needs a reference; else only chained) */
} vibid_change_phase;

typedef enum vibid_change_kind { VIBID_CHANGE_RAISED = 1, VIBID_CHANGE_CLEARED = 2 } vibid_change_kind;

typedef struct vibid_change_event {
    size_t param;          /* the parameter's index */
    vibid_change_kind kind;
    uint64_t index;        /* the sample index of the row that raised or cleared it */
    uint64_t onset_index;  /* RAISED: the estimated onset, the sample index of the first row of
                              the run that fired (its block began at the row before) */
    double statistic;      /* the CUSUM that fired (RAISED) or cleared (CLEARED) ... */
    double threshold;      /* ... and its threshold (both in units of sigma_b) */
    double change, change_se; /* RAISED: estimated change from the reference (its unit) and its
                                 standard error; CLEARED: the change that was cleared */
    double reference;      /* m */
} vibid_change_event;

/* The live state of one parameter. */
typedef struct vibid_change_state {
    int have_reference;
    int active;            /* an alarm is raised */
    double statistic;      /* max(S_up, S_down) / h (>= 1 raises); while active the value at
                              the raise */
    double mdc;            /* minimum detectable change, the parameter's unit (NaN without a
                              reference) */
    double mdc_relative;   /* mdc / |m| */
    double last_block;     /* the last block estimate b_k (NaN before one) */
    uint64_t blocks_learned, blocks_tested;
    /* covariates (point 6; 0 / 1.0 without): */
    int out_of_range;      /* the last block's covariates lay outside the reference's range */
    double weight;         /* the last block's weight in the test: 1 inside the range, < 1
                              extrapolated, 0 not tested */
    uint64_t blocks_out_of_range; /* tested or not, since the reference */
} vibid_change_state;

VIBID_API void vibid_change_config_init(vibid_change_config *cfg, size_t n_params);

/* NULL on a bad configuration (vibid_last_error names the field) or out of memory. */
VIBID_API vibid_change *vibid_change_create(const vibid_change_config *cfg);
VIBID_API void vibid_change_destroy(vibid_change *det);
/* Back to the state after create: the reference, the chain and the statistics dropped. */
VIBID_API vibid_status vibid_change_reset(vibid_change *det);

/* One recursive row: its sample index (increasing; from the estimator's first sample),
 * its estimate theta (n_params values, the parameters' units), the covariates' means over
 * its block (n_covariates values; NULL when n_covariates is 0), whether its block may be
 * used, and the phase. Events (at most one per parameter) go to events[0 .. *n_events),
 * *n_events <= cap; events may be NULL when cap is 0. Events beyond cap are lost: pass
 * cap = n_params.
 * VIBID_E_NULL_ARGUMENT, VIBID_E_OUT_OF_RANGE (an index that does not increase: nothing
 * changes). */
VIBID_API vibid_status vibid_change_push(vibid_change *det, uint64_t index, const double *theta,
                                         const double *covariates, int use,
                                         vibid_change_phase phase, vibid_change_event *events, size_t cap,
                                         size_t *n_events);

/* The reference from the blocks learned so far. Every parameter needs
 * VIBID_CHANGE_MIN_BLOCKS blocks (plus one per covariate) with a spread > 0: VIBID_E_INSUFFICIENT_DATA names the
 * first that has not (no parameter gets a reference then; learning may go on). */
VIBID_API vibid_status vibid_change_end_learning(vibid_change *det);

/* A given reference (n_params entries), e.g. a saved one; replaces any other. The covariate
 * fields are checked (finite, low <= high, G's diagonal >= 0, n_terms 0, q or
 * q + q (q + 1) / 2). */
VIBID_API vibid_status vibid_change_set_reference(vibid_change *det, const vibid_change_reference *ref);
/* The reference in use (n_params entries); VIBID_E_STATE without one. */
VIBID_API vibid_status vibid_change_get_reference(const vibid_change *det, vibid_change_reference *ref);

VIBID_API vibid_status vibid_change_get_state(const vibid_change *det, size_t param, vibid_change_state *state);

/* The threshold h of one CUSUM on N(0,1) increments with allowance k > 0 whose average run
 * length is arl rows, with a reference learned from n_mean blocks (mean) and n_sd blocks
 * (scale), INFINITY for exactly known (point 3 above). For tests and tables. */
VIBID_API vibid_status vibid_change_threshold(double k, double arl, double n_mean, double n_sd, double *h);

#ifdef __cplusplus
}
#endif
#endif
