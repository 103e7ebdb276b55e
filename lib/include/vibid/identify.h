/* vibid/identify.h: identification of a model's unknown physical parameters from
 * sampled channels: model (model.h) + regressor (regressor.h) + estimator (lsq.h,
 * iv.h, rls.h), returning masses, damping, stiffness, cubic coefficients and input gains
 * with standard errors.
 *
 * Estimators:
 *  LS   batch least squares (2.4) by QR. Consistent for noise-free data; with noise on
 *       measured outputs that also enter the regressor (always the case here) it is
 *       biased, badly so on raw central differences, which amplify the noise.
 *  IV   batch instrumental variables (2.15). Instruments are the regressor rows of the
 *       sample iv_lag samples earlier: smooth signals keep them correlated with the
 *       regressor (2.14 b), while white measurement noise more than the window length
 *       (plus the pre-filter's memory) apart is uncorrelated with the equation error
 *       (2.14 a).
 *  RLS  recursive least squares (2.6)/(2.7), Bierman form, with forgetting: for tracking
 *       and the daemon. The per-sample push is real-time safe in this mode.
 *  AUTO (default) IV with block statistics, settings chosen from the model; below. A
 *       stand that is not fully measured gets the EKF.
 *  EKF  joint estimation of the states [y; y'] and the physical parameters by an extended
 *       Kalman filter on the stand's own model (paper section 3.2, ref. [11]). For stands
 *       where some coordinate is not measured (no sensor on a mass, only an accelerometer
 *       where a spring needs the displacement) or that are excited by unmeasured random
 *       forces (vibid_model_add_disturbance). Details below.
 * LS, IV and AUTO also fit a constant force per node's equation where the data need it
 * (sensor offsets, constant loads: vibid_ident_config.constant_terms, below).
 * With the regressor pre-filter (prefilter_hz > 0) the noise that central differences
 * amplify is removed before it reaches any estimator; for example 1 of the paper at
 * 1 % noise that is what brings every estimator from tens of percent to below 1 %
 * on the springs (README has the figures).
 *
 * Discretization ZOH (model.h): the estimators run on the unstructured difference form
 * (1.16); vibid_ident_estimate maps the estimate back (vibid_second_order_to_continuous)
 * and solves the structured equations M(theta) K = C(theta), M(theta) L = D(theta),
 * M(theta) J = [B(theta) c_base(theta)] for theta by least squares; standard errors
 * come from the covariance of the difference form through the numerical Jacobian of
 * that whole map.
 */
#ifndef VIBID_IDENTIFY_H
#define VIBID_IDENTIFY_H

#include <vibid/common.h>
#include <vibid/model.h>
#include <vibid/discretize.h>
#include <vibid/modal.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct vibid_ident vibid_ident;

typedef enum vibid_estimator {
    VIBID_ESTIMATOR_LS = 0,
    VIBID_ESTIMATOR_IV = 1,
    VIBID_ESTIMATOR_RLS = 2,
    VIBID_ESTIMATOR_AUTO = 3,  /* the default: chosen from the model (see below) */
    VIBID_ESTIMATOR_EKF = 4,   /* extended Kalman filter on the stand's states and physical
                                  parameters, for stands that are not fully measured (below) */
    VIBID_ESTIMATOR_KF_RLS = 5, /* the paper's Kalman filter + recursive LS (3.16) on the stand's
                                  physical parameters (below); never chosen by AUTO */
    VIBID_ESTIMATOR_OE = 6     /* output error on the stand's physical model (output_error.h), started
                                  from the AUTO estimate; batch: every sample is kept (below) */
} vibid_estimator;

/* The estimators' names, one table owned by the library and read by every front end
 * (vibidd's estimator.method, the Python binding's method=): "ls", "iv", "rls", "auto",
 * "ekf", "kf_rls", "oe", in the enum's order.
 * vibid_estimator_name: the name of kind, a static string (valid for the program's life,
 *   never to be freed); NULL for a value that is no estimator, so that
 *   for (k = 0; vibid_estimator_name(k); k++) walks them all.
 * vibid_estimator_from_name: *kind = the estimator called name (exact, lower case);
 *   VIBID_E_NULL_ARGUMENT for NULL arguments, VIBID_E_OUT_OF_RANGE for an unknown name
 *   (the message lists the names; *kind unchanged).
 * Both allocate nothing and are safe from any thread. */
VIBID_API const char *vibid_estimator_name(vibid_estimator kind);
VIBID_API vibid_status vibid_estimator_from_name(const char *name, vibid_estimator *kind);

/* The automatic estimator (VIBID_ESTIMATOR_AUTO, the default of vibid_ident_config_init)
 * and the automatic settings (the "0 / negative = automatic" values below). What it
 * chooses and why, in words: vibid_ident_describe; the settings: vibid_ident_get_config.
 *  - estimator: instrumental variables with block statistics (the IV below). Noise on
 *    any measured channel that enters the regressor biases LS and RLS (badly with
 *    differences: +100 % and more at 1 % noise); IV is consistent with noise and exact
 *    without. Recursive in the sense that matters: the per-sample push is O((p + n)^2 m) and
 *    allocation-free, an estimate is formed from the running sums when asked for; with
 *    forgetting < 1 the sums are exponentially weighted (tracking).
 *  - difference_order 4 (five-point stencils: bias (w h)^4 / 30 instead of (w h)^2 / 6).
 *  - prefilter_hz: 4 times the highest natural frequency of the nominal model (when the
 *    stand gives nominal values for every unknown), else of the data: a pilot over the
 *    first max(4096, ceil(2 / h)) samples runs with f_a / 20 (vibid_ident_get_config says
 *    f_a / 20 until then); at its last sample, with f_max the highest natural frequency
 *    of its estimate, the pilot's samples are replayed into estimators with the candidate
 *    cutoffs f_a / 50, 2 f_max and 4 f_max (each within [f_a / 50, f_a / 8], none below
 *    2 f_max / 1.1 but f_a / 8, each more than 10 % from f_a / 20 and the ones before),
 *    and of these and f_a / 20 (if not below 2 f_max / 1.1) the one whose estimate has the
 *    smallest sum over the parameters of (se / value)^2 goes on, its lag with it (the
 *    stencils amplify displacement noise as w^2, so a wider band than the response needs
 *    costs variance; a narrower one loses the response). The result is bit-identical to
 *    configuring that cutoff from the start. The push that ends the pilot allocates
 *    (the estimates, the candidates; bench_ident prints its time) once per run; every
 *    other push allocates nothing. No usable pilot estimate (too little excitation, an
 *    unstable or mode-less estimate): f_a / 20 stays. vibid_ident_describe grows by the
 *    choice and the candidates' scores. A
 *    reset during the pilot restarts it; after it, the chosen cutoff stays. Within
 *    [f_a / 50, f_a / 8] in every case.
 *  - iv_lag: the difference window plus one period of the pre-filter's cutoff,
 *    1 / (prefilter_hz h): long enough for the filtered noise to decorrelate, short
 *    enough that the instruments stay correlated with the regressors at every mode.
 * Each of these can be set explicitly and then overrides the choice.
 *
 * Error bars (every estimator but plain LS and RLS): the covariance is taken from the
 * spread of the estimating equations over 32..64 blocks of consecutive samples (batch
 * means), which holds for the coloured equation errors that differences and the
 * pre-filter produce; the remaining discretization bias, bounded by
 * |theta_i| (w_max h)^2 / 6 for (1.17) and |theta_i| (w_max h)^4 / 30 for five-point
 * stencils (w_max the highest natural frequency of the estimate), at least
 * |theta_i| (w_max h)^4 on dampers and a tenth of it on the rest with a damper to a
 * held base (its impulses, measured at 0.6 and 0.08 of that), is added to each
 * variance, or, where larger, the measured discretization error: the same estimator runs
 * on every second sample alongside (step 2h, the same pre-filter and lag in seconds), and
 * |difference| / 3, less the two estimates' noise (Hausman: var(half) - var(full) taken
 * out of the squared difference), is the error of an h^2 error term. That is what the
 * bound misses: the aliasing of corners in the excitation (a triangle's corners on
 * samples biased the paper's example 1 by 14 of the former standard errors; now within
 * 1.6). Corners halfway between samples are not seen (both grids see them at a quarter
 * step). Not with held inputs (their hold equivalents assume the hold of step h), nor ZOH.
 * It costs about half the per-sample work again. A consistency check compares the estimates of
 * the older and the newer half of the blocks (vibid_ident_get_quality). LS and RLS report
 * the textbook covariance, which assumes white equation errors: their quality says
 * VIBID_QUALITY_SE_INVALID. */
/* The paper's KF+RLS on the physical model (VIBID_ESTIMATOR_KF_RLS, never chosen by AUTO):
 * the start, the exact discretisation, the divergence handling and the estimates'
 * interface are the EKF's below, but the Kalman filter runs on the states [y; y'] alone,
 * with the parameters at the newest estimate, and a recursive LS (rls.h, forgetting as
 * configured) estimates the parameters from the equation of motion integrated over each
 * sample interval, M dv + D dy - d_b ds + C int(y) - c_b int(s) - B int(u) + int(cubic) =
 * int(w): target the filtered x_{k+1|k+1}, regressors from x_{k|k} and the one-step
 * prediction (paper 3.16). Only the equations of nodes with a sensor are rows:
 * vibid_ident_create refuses (VIBID_E_NOT_IDENTIFIABLE, naming them) unknowns that act
 * only on unmeasured nodes. The velocity model-error allowance is 0.3 % (three times the
 * EKF's). Standard errors: the regression's, on filtered and coloured regressors, always
 * VIBID_QUALITY_SE_INVALID. Weaker than the EKF where states are unmeasured (README). */
/* Output error (VIBID_ESTIMATOR_OE; never chosen by AUTO in the library: the batch front
 * ends choose it by a held-out comparison, docs/python.md): every sample is kept (the push
 * appends it: allocates, not for real-time paths) and fed to the AUTO estimator; at
 * vibid_ident_estimate the output-error fit (output_error.h) runs over all samples kept,
 * started from the AUTO estimate and, where the stand gives a nominal value for every
 * unknown, from those too. Its standard errors are the fit's sandwich ones; its offsets
 * come from vibid_ident_offsets. A fit that fails leaves the AUTO estimate with its own
 * quality plus VIBID_QUALITY_REFINE_FAILED, and the reason in vibid_ident_describe.
 * On a stand with a disturbance the fit is the prediction-error fit of the stand's Kalman
 * predictor (output_error.h, "Stands with disturbances"), started from the EKF's estimate;
 * an EKF that diverges on the way (it restarts itself) does not stop the samples being kept,
 * and where it gives no estimate the fit starts from the nominal values; the description
 * ends with the estimated noise intensities. No prior (vibid_ident_set_prior:
 * VIBID_E_STATE), no twin. Refused at create for a stand with an unmeasured base
 * displacement, or with a disturbance and a cubic spring or a base (output_error.h). */
/* The state-space estimator (VIBID_ESTIMATOR_EKF; AUTO chooses it when some signal the
 * regression needs cannot be formed from the measured channels, or when the stand
 * declares a disturbance):
 *  - model: M y'' + D y' + C y + cubic = B u + c_b s + d_b s' + w over each sample
 *    interval, discretised exactly (matrix exponential of the system augmented with the
 *    inputs and their slopes): smooth inputs linear between samples, held inputs constant
 *    (a held base kicks the velocities through its dampers), disturbances held white
 *    samples (model.h). Cubic springs are linearised about the midpoint of each sample interval.
 *    Filter state [y; y'; theta]; the Jacobian's parameter columns are the Frechet
 *    derivative of the exponential (Boole's rule on quarter steps, relative error about
 *    (w h)^6 / 2e6).
 *  - before any sample (vibid_ident_create): every unknown needs a nominal (start) value;
 *    the base's displacement must be measured when something connects to it; and the
 *    measured channels must determine the unknowns: the sensitivity of the transfer
 *    functions from the measured inputs, and of the output spectra of the disturbances,
 *    to the parameters at the nominal values has full rank on a frequency grid over the
 *    modes. Otherwise VIBID_E_NOT_IDENTIFIABLE names the parameters it cannot determine.
 *    Cubic coefficients are not part of that test (they show only with amplitude).
 *  - start: the first 1000 samples are collected; measurement noise of each measured
 *    channel (vibid_model_set_noise, else from its 2nd..6th differences), the typical
 *    state size, and unknown disturbance intensities (largest innovation likelihood over
 *    those samples) are taken from them; then the filter runs over them from the nominal
 *    values (or vibid_ident_set_prior's theta0), each with a relative standard deviation
 *    of 50 %. For two periods of the slowest nominal mode after a start the measurement
 *    noise is inflated (x 1e4, decaying to x 1), so that start values far off do not
 *    throw the first updates into unstable parameter sets; with a node without sensor
 *    the parameters are held for that long while its states settle. Each velocity gets
 *    a model-error allowance of 0.1 % of its typical size per sample (process noise).
 *    vibid_ident_estimate before the 1000th sample gives a provisional estimate from
 *    the samples so far (at least 10; rerun when they have grown by a quarter) without
 *    starting the filter, so the tracks do not depend on when estimates are asked for.
 *  - per sample O((2n + p)^3 + (2n + 2r)^3), allocation-free. forgetting < 1 divides the
 *    parameter block of the covariance by it each sample (tracking).
 *  - error bars (forgetting 1): the filter's covariance of the parameters, widened by a
 *    sandwich (robust) covariance where that is wider. The filter's parameter update is
 *    a recursive prediction-error step, so each sample has a score u_k = P_thth,k|k-1^-1
 *    (theta update at k) = psi_k S_k^-1 nu_k (psi the derivative of the predicted
 *    measurements with respect to the parameters) and an information psi_k S_k^-1
 *    psi_k'; the filter's P_thth assumes those scores white with that covariance. The
 *    sandwich V = P_thth G P_thth takes G from the spread of the scores' sums over 32-63
 *    blocks of consecutive samples (the blocks double in length as the run grows; each
 *    block's scores moved to the final estimate to first order, so that the start
 *    transient does not count as spread). Each parameter's row and column of P_thth are
 *    scaled by sqrt(V_ii / P_ii) where that exceeds 1. Not the sandwich alone: on two
 *    stands simulated by vibid-sim (ident.ekf_coverage, 4-5 s) the filter's standard
 *    errors were 1.5 to 8 times the spread of the estimates (the velocity allowance and
 *    the base channel's noise, both process noise, discard information), and the
 *    sandwich alone gave 94.2 % coverage of 2-se intervals there, but on 60 s of the
 *    2-DOF base stand of ident.ekf it left the bias of a damper (+0.96 %, which the wide
 *    bars covered) 7 of its standard errors out. Flagged VIBID_QUALITY_SE_INVALID: a
 *    sandwich variance more than 3 times the filter's for some parameter (the scores
 *    spread more than the model's noise explains: a model error, whose bias no error bar
 *    covers; an impact test with 2 ms hammer pulses at 5 kHz, which the filter takes as
 *    linear between samples: dampers 2 % off at 3-12 standard errors, ratio about 5,
 *    every realisation flagged, none before; consistent stands 0.04-0.6), and fewer than
 *    16 blocks of scores. With forgetting < 1 the error bars are the filter's covariance.
 *    The innovations: VIBID_QUALITY_SE_INVALID when
 *    their averaged normalised square (NIS per measurement, memory 100 samples) exceeds 2.
 *    And when the filter is consistent, the change of the estimate since an earlier time
 *    t0 has the variance var(t0) - var(t): a drift check compares the estimate with a
 *    snapshot taken between a quarter and half of the run ago (forgetting 1 only; from ten
 *    tempering time constants after the start) and flags VIBID_QUALITY_SE_INVALID when
 *    some |change| / sqrt(var(t0) - var(t)) exceeds 4 (quality.z_consistency is that
 *    largest ratio, NaN before the second snapshot, and until then the error bars count as
 *    not verified: flagged too). It catches an estimate still leaving
 *    its start transient under error bars that shrank first (a lightly damped 5-DOF
 *    chain at 10 kHz from 10 % off: dampers 9 standard errors off, drift z 9.3; from the
 *    truth 0.06).
 *  - a gap (non-finite sample, VIBID_E_NONFINITE): the state restarts at the next sample,
 *    the parameters carry on. Divergence (non-finite values, a mass <= 0, a state beyond
 *    1e6 typical sizes, or the averaged NIS above 10): vibid_ident_push returns
 *    VIBID_E_DIVERGED for that sample and the filter restarts from its start values;
 *    the next samples are processed normally.
 */
/* Constant forces in the equation-error regression (vibid_ident_config.constant_terms).
 * A constant sensor offset o on a measured channel (measured = true + o: a displacement
 * sensor's zero error, an accelerometer's or a load cell's bias) or a constant force on a
 * mass (gravity on a tilted stand, a preload) enters the structured equations (4.1) of a
 * linear stand as a constant in each node's equation: k o through a spring, d o through a
 * damper whose velocity is measured, m o through a measured acceleration, gain o through a
 * force channel (the differences that form unmeasured velocities and accelerations cancel
 * it). Unmodelled it biases every estimator, IV most (its delayed instruments have a
 * nonzero mean where the regressors do: a gain 10 times off on a real capture, issue 29).
 * With constant terms, each node's equation gets one more unknown, the constant force f0_i
 * on node i in
 *     M y'' + D y' + C y + cubic = B u + c_b s + d_b s' + f0
 * (measured = true + o, so a displacement offset o of a node tied to ground by a spring k
 * shows as f0 = k o, on a chain as f0 = C o with the stiffness matrix C),
 * a regressor that is 1 in every row of that equation, passed through the pre-filter like
 * every column. The n constants are unknowns of the fit only: theta, its standard errors
 * and vibid_ident_covariance keep their p entries (the covariance of theta is the marginal
 * of the fit with the constants, their correlation with theta accounted for); the
 * constants themselves come from vibid_ident_constant_forces. A cubic spring turns an offset
 * into x^2 and x terms too, which a constant does not absorb (the output-error estimator's
 * channel offsets do, VIBID_ESTIMATOR_OE).
 *  AUTO (default): the regression is accumulated with the constants (the same sums serve
 *      both fits); at each estimate the fit with them is formed, and a Wald test of all
 *      constants = 0 (chi-square with n degrees of freedom, on the estimator's own
 *      covariance) decides: p-value below 1e-3 keeps the fit with the constants, otherwise
 *      the plain fit stands, the same as OFF (but for the pre-filter pilot, whose candidate
 *      estimates each choose for themselves: 1 of 100 offset-free realisations differed in
 *      ident.constant_terms). No covariance for the fit with the constants (too few blocks
 *      early in a run, or n_eff <= p + n + 1: block_iv.hpp), no test: the plain fit stands.
 *      With forgetting < 1 the blocks span about 6 memories, n_eff is about 10, so a stand
 *      with p + n >= 9 gets no test (the chain of ident.constant_terms, p 6 + n 3, with
 *      forgetting 0.9997: plain fit kept, d1 +28 % from the offsets; ON gives the fit with
 *      the constants, flagged VIBID_QUALITY_SE_INVALID). LS's test uses its textbook
 *      covariance, too small for coloured equation errors: it keeps the constants in about
 *      half of offset-free captures, which costs it no accuracy. README has the measured
 *      rates and costs. The last estimate's choice and p-value: vibid_ident_constant_forces;
 *      the rule itself: vibid_ident_describe.
 *  ON:  always with the constants.
 *  OFF: never (the regression as before this setting; nothing is accumulated for them).
 * Estimators: LS, IV and AUTO on the structured form (central differences), also with
 * forgetting < 1. Not (yet) RLS and the ZOH form: there AUTO means OFF and ON is refused at
 * vibid_ident_create (VIBID_E_UNSUPPORTED). EKF and KF+RLS: not used. OE: its own offsets
 * per response channel (vibid_ident_offsets); its equation-error start follows this
 * setting. */
typedef enum vibid_constant_terms {
    VIBID_CONSTANT_AUTO = 0, /* tested for at each estimate, kept where the data need them (default) */
    VIBID_CONSTANT_OFF = 1,  /* never */
    VIBID_CONSTANT_ON = 2    /* always */
} vibid_constant_terms;

typedef struct vibid_ident_config {
    vibid_estimator estimator; /* default VIBID_ESTIMATOR_AUTO */
    double sample_time;   /* h in s, > 0 */
    double prefilter_hz;  /* pre-filter cutoff in Hz (regressor.h); 0 = off; < 0 = automatic (default) */
    size_t iv_lag;        /* instrument delay in samples (IV, AUTO), 3..4096; 0 = automatic (default):
                             the difference window plus 1 / (prefilter_hz h) */
    double forgetting;    /* forgetting gamma in (0, 1], default 1 (RLS, and the AUTO/IV sums) */
    double rls_alpha;     /* RLS P0 = alpha^-1 I, > 0; 0 = automatic (default): the first
                             max(8 p, 100) samples are collected, P0 = diag(1 / (1e-6 sum x_i^2))
                             over them (1e-6 of their information in every direction, in each
                             parameter's own units; a fixed alpha is not weak for a cubic
                             coefficient in N/m^3), theta0 the nominal values, then the samples
                             are replayed. Start values without P0 (vibid_ident_set_prior)
                             use alpha 1e-9. */
    unsigned difference_order; /* 2 (1.17) or 4 (five-point), 0 = automatic (default: 4) */
    vibid_constant_terms constant_terms; /* constant forces per equation (above); default
                                            VIBID_CONSTANT_AUTO */
} vibid_ident_config;

typedef struct vibid_ident_info {
    unsigned long long n_samples;   /* samples pushed since create/reset */
    unsigned long long n_rows;      /* regression equations accumulated */
    size_t rank;                    /* numerical rank of the regression (batch estimators) */
    double rcond;                   /* reciprocal condition of the scaled regressor (batch LS) */
    vibid_log_info log_info;        /* ZOH only: the way back's report */
} vibid_ident_info;

/* Quality of the last estimate (vibid_ident_get_quality). */
#define VIBID_QUALITY_SE_INVALID 1u   /* the error bars do not hold: the consistency check failed
                                         (|z| > 4), too few blocks, or an estimator whose standard
                                         errors assume white equation errors (LS, RLS) */
#define VIBID_QUALITY_REFINE_FAILED 4u /* OE: the output-error fit failed (no convergence, a bound, a
                                         singular information matrix, an unstable simulation, an input
                                         gap): the estimate is the equation-error (AUTO) one, the reason
                                         in vibid_ident_describe */
#define VIBID_QUALITY_NOT_EXCITED 2u  /* a parameter lies in a direction the data hardly inform
                                         (scaled information below 1e-7 of the strongest): its
                                         standard error is reported as infinite */

typedef struct vibid_ident_quality {
    unsigned flags;          /* VIBID_QUALITY_* bits for the estimate as a whole */
    double z_consistency;    /* max over parameters of |theta_old - theta_new| / sqrt(var_old + var_new)
                                between the older and the newer half of the blocks; NaN when not
                                available (too few blocks, or LS/RLS) */
    size_t n_blocks;         /* blocks behind the covariance (0 for LS/RLS) */
    double rcond;            /* reciprocal condition of the scaled estimating equations */
    double bias_relative;    /* largest relative discretization error included in the standard errors: the
                                a-priori bound, or the measured one (the check on every second sample) where larger */
} vibid_ident_quality;

/* Defaults for sample time h (s): AUTO estimator, automatic pre-filter, lag and
 * difference order, forgetting 1, automatic RLS prior (rls_alpha 0), constant terms
 * tested for (VIBID_CONSTANT_AUTO). */
VIBID_API void vibid_ident_config_init(vibid_ident_config *cfg, double sample_time);

/* Creates an identification for a finalized model (copied). Runs
 * vibid_model_check_identifiable first: a model that cannot be identified is refused
 * here, before any sample (NULL, reason in vibid_last_error(), naming the parameters). */
VIBID_API vibid_ident *vibid_ident_create(const vibid_model *model, const vibid_ident_config *cfg);
VIBID_API vibid_status vibid_ident_reset(vibid_ident *ident);
VIBID_API void vibid_ident_destroy(vibid_ident *ident);

/* Number of channels per sample and of unknowns (for sizing arrays). */
VIBID_API vibid_status vibid_ident_dims(const vibid_ident *ident, size_t *n_channels, size_t *n_params);

/* Start values for the RLS estimator (cfg.estimator == VIBID_ESTIMATOR_RLS), e.g. the
 * last identification of the stand kept by the daemon. Also the state that
 * vibid_ident_reset returns to from now on. The RLS residual statistics restart; the
 * sample counts, the difference window and the pre-filter keep running. With a prior set,
 * vibid_ident_estimate answers from the first sample on (the prior stands in for the
 * missing equations).
 *   theta0 p physical parameters in the model's parameter order and the model's units
 *          (vibid_model_param_info: N/m, N s/m, kg, N/m^3, gain units, ...), finite.
 *          NULL: the model's nominal values (vibid_model_nominal).
 *   P0     p x p symmetric positive definite start value of the RLS matrix P (column-
 *          major), in the same parameter order; its units are those of theta_i theta_j
 *          divided by the equation error's squared unit (N^2 for force equations): the
 *          covariance of theta0 is sigma_e^2 P0. NULL: alpha^-1 I (cfg.rls_alpha), the
 *          default start. Central differences only: with ZOH the estimator runs on the
 *          difference form (1.16), so theta0 is mapped there (vibid_second_order_form)
 *          and P0 must be NULL (VIBID_E_OUT_OF_RANGE otherwise).
 * VIBID_E_STATE for the batch estimators (LS, IV: they have no start value),
 * VIBID_E_NONFINITE / VIBID_E_OUT_OF_RANGE / VIBID_E_NUMERICAL for bad theta0 or P0 (as
 * vibid_rls_set_prior); on any error the identification is left unchanged. Not a
 * per-sample call: may allocate. */
VIBID_API vibid_status vibid_ident_set_prior(vibid_ident *ident, const double *theta0, const double *P0);

/* One sample: channels in the model's layout (model.h). Allocates nothing (all
 * estimators), but for the one push that ends the pre-filter pilot (above). Non-finite input: VIBID_E_NONFINITE, sample ignored, the difference
 * window restarts (a gap costs the next 2 samples). */
VIBID_API vibid_status vibid_ident_push(vibid_ident *ident, const double *channels);

/* n_samples samples at once: channels n_samples x n_channels, column-major (one column
 * per channel, as in a CSV file). Stops at the first bad sample and reports it. */
VIBID_API vibid_status vibid_ident_push_block(vibid_ident *ident, size_t n_samples, const double *channels);

/* Current estimate of the unknowns theta (p) and their standard errors (p, may be NULL).
 * VIBID_E_INSUFFICIENT_DATA before enough equations (batch: more rows than regressors);
 * VIBID_E_NOT_IDENTIFIABLE when the data do not separate some parameters (message names
 * them, from vibid_lsq_null_space); VIBID_E_NUMERICAL when the ZOH way back fails.
 * info may be NULL. Batch and ZOH: allocates (not for real-time paths). */
VIBID_API vibid_status vibid_ident_estimate(vibid_ident *ident, double *theta, double *stderr_out,
                                            vibid_ident_info *info);

/* Constant offsets of the measured response channels in the last estimate (OE: one per
 * response channel, in the channel's units, measured = true + offset; every other
 * estimator: none; LS, IV and AUTO absorb offsets as constant forces instead:
 * vibid_ident_constant_forces). *n_out receives their number; up to cap of them are written to
 * channels (the channel index in the sample), values and se (each may be NULL).
 * VIBID_E_STATE before an estimate. */
VIBID_API vibid_status vibid_ident_offsets(const vibid_ident *ident, size_t cap, size_t *n_out, size_t *channels,
                                           double *values, double *se);

/* The innovations of the state-space estimators' last measurement update (EKF and
 * KF_RLS; every other estimator: VIBID_E_UNSUPPORTED): the one-step prediction errors
 * whose whiteness says whether the filter's model explains the data. Per measured
 * channel, in the filter's order: channels (its index in the sample), nu (measured -
 * predicted, in the channel's unit) and sd (the filter's predicted standard deviation
 * sqrt(S_kk) of that innovation, S = H P H' + R, measurement noise included). A
 * consistent filter gives nu / sd about N(0, 1) and white; *inflation (may be NULL)
 * receives the factor the measurement noise R was inflated by in that update (1e4
 * decaying to 1 over the tempering after a start, above): while it exceeds 1 the sd are
 * wider than the noise, by design. *n_out receives the number of measured channels, or 0
 * when the last vibid_ident_push made no update (the start window being collected,
 * including the sample that completes it, whose push runs the filter over the whole
 * window; a gap; a divergence); up to cap of them are written (each array may be NULL).
 * Call after each vibid_ident_push to collect them; vibid_ident_push_block keeps only the
 * last. Allocation-free. */
VIBID_API vibid_status vibid_ident_innovations(const vibid_ident *ident, size_t cap, size_t *n_out, size_t *channels,
                                               double *nu, double *sd, double *inflation);

/* Constant forces of the last estimate of the equation-error estimators (LS, IV, AUTO;
 * vibid_ident_config.constant_terms above): f0_i, the constant force on node i in
 * M y'' + D y' + C y + cubic = B u + c_b s + d_b s' + f0, in the force unit of the model's
 * equations (N with SI channels), with its standard error (the estimator's covariance:
 * batch means for IV and AUTO; LS's textbook one, which assumes white equation errors).
 * *n_out receives their number: n (one per node, node order) when the estimate includes
 * them, 0 when the plain fit stands (OFF, AUTO with the test not rejecting, and the other
 * estimators); up to cap of them are written to nodes (node index), values and se (each
 * may be NULL). p_value (may be NULL) receives the Wald test's p-value for all constants
 * = 0 from the fit with them (NaN when no test was made: OFF, other estimators, or a
 * covariance not yet available); under AUTO the constants are kept when it is below 1e-3.
 * VIBID_E_STATE before an estimate. */
VIBID_API vibid_status vibid_ident_constant_forces(const vibid_ident *ident, size_t cap, size_t *n_out,
                                                   size_t *nodes, double *values, double *se, double *p_value);

/* Covariance of the last estimate (p x p), consistent with its standard errors. Valid
 * after a successful vibid_ident_estimate. */
VIBID_API vibid_status vibid_ident_covariance(const vibid_ident *ident, double *cov);

/* Quality of the last successful vibid_ident_estimate: whole-estimate flags and figures
 * (q, may be NULL) and per-parameter flags (param_flags, p entries, may be NULL:
 * VIBID_QUALITY_* bits that concern that parameter). VIBID_E_STATE before an estimate. */
VIBID_API vibid_status vibid_ident_get_quality(const vibid_ident *ident, vibid_ident_quality *q, unsigned *param_flags);

/* The settings in force after the automatic choices (every "automatic" field resolved). */
VIBID_API vibid_status vibid_ident_get_config(const vibid_ident *ident, vibid_ident_config *cfg);

/* What was chosen and why, one line per choice ("estimator: ... because ..."), into buf
 * (cap bytes, always NUL-terminated); the full length is returned in *len (may be NULL).
 * The same text for the same model and configuration. */
VIBID_API vibid_status vibid_ident_describe(const vibid_ident *ident, char *buf, size_t cap, size_t *len);

/* Deferred estimates, for a real-time consumer that must not keep later samples waiting
 * while an estimate is computed (vibidd: 30-100 us per track row against 0.1-0.3 us per
 * sample). A twin is a second identification that takes no samples: at the sample an
 * estimate is due, vibid_ident_twin_sync copies what vibid_ident_estimate reads (the block
 * statistics of the IV family and of its discretization check, or the RLS estimate, P and
 * residual covariance) into the twin, without allocating; the caller goes on pushing
 * samples into the identification and later asks the twin: vibid_ident_estimate,
 * vibid_ident_covariance and vibid_ident_get_quality on the twin answer exactly (bit for
 * bit) what they would have answered on the identification at the sync. Estimates must
 * be asked in the order of their syncs (the IV family's estimate keeps the previous one
 * in weakly informed directions: that memory lives in the twin, and starts afresh when
 * the identification is reset or its pre-filter pilot replaces the estimator). So one
 * twin serves one pending estimate: estimate on it before the next sync.
 * The configuration, the description and samples stay with the identification itself
 * (vibid_ident_push on a twin: VIBID_E_STATE).
 *
 * vibid_ident_twin_create: allocates (not per sample). NULL with VIBID_E_STATE for LS
 * (its estimate is its solve: nothing to save by deferring), EKF and KF+RLS.
 * vibid_ident_twin_sync: O(64 p_a (p_a + q)) copies for the IV family (p_a = p_reg plus the
 * n constant-force columns unless constant_terms is OFF), O(p_reg^3) for
 * RLS; allocation-free. VIBID_E_STATE when twin was not made for ident. Destroy a twin
 * with vibid_ident_destroy, before or after its identification. */
VIBID_API vibid_ident *vibid_ident_twin_create(const vibid_ident *ident);
VIBID_API vibid_status vibid_ident_twin_sync(vibid_ident *twin, const vibid_ident *ident);

#ifdef __cplusplus
}
#endif
#endif
