// stand_ekf.hpp: joint estimation of the state and the physical parameters of a lumped
// network (model.h) by an extended Kalman filter on [y; y'; theta], for stands that are
// not fully measured (paper section 3.2, example 3; ref. [11]). identify.cpp runs it as
// VIBID_ESTIMATOR_EKF; identify.h documents the behaviour users see.
//
// Model over one sample interval [t_k, t_{k+1}] (exact for these input shapes):
//   M y'' + D y' + C y + cubic(y, s) = B u + c_b s + d_b s' + B_w w,
//   smooth inputs (forces, base) linear between their samples (first-order hold), held
//   inputs constant (zero-order hold; a held base kicks the velocities through its
//   dampers by M^-1 d_b (s_k - s_{k-1}) at t_k), disturbances w held white samples.
// The augmented linear system xi = [y; y'; e; e'] (e the inputs, e' their slopes) has
// the exact one-step map exp(A~ h). Its derivative with respect to each parameter is the
// Frechet derivative of the exponential, integral_0^h exp(A~(h-s)) dA~ exp(A~ s) ds,
// evaluated on the current xi by Boole's rule on quarter steps (relative error about
// (|A~| h)^6 / 2e6, below 1e-9 at 10 samples per period). Cubic springs are linearised
// about the interval's midpoint (predicted from t_k along the velocities), with the
// interval mean of the quadratic remainder as a constant force (linearise_cubics()):
// exact for the linear part, the cubic force's mean error of order (w h)^4.
//
// KF+RLS (settings kf_rls, the paper's (3.16) on the physical model): the same exact
// discretisation drives a Kalman filter on the states [y; y'] alone, with the parameters
// held at the newest estimate; a recursive LS (rls.h) estimates the parameters from the
// filtered states by the equation of motion integrated over each sample interval,
//   M dv + D dy - d_b ds + C int(y) - c_b int(s) - B int(u) + int(cubic) = int(w),
// linear in every mass, spring, damper, cubic coefficient and gain (dv, dy: increments of
// the filtered velocities and displacements, exact; int(y) by the cubic Hermite rule
// through both ends' displacements and velocities, error (w h)^4 / 720 relative;
// inputs as in the filter's model; int(w), the unmeasured force, is the equation error).
// Only the equations of nodes with a sensor are rows: an unmeasured node's filtered
// velocity is the filter's own prediction, so its equation would only confirm the
// current parameters; an unknown that acts on no measured node is therefore refused
// (the EKF estimates it). Rows are weighted by their equation-error level at the start
// values. Cheaper than
// the EKF (no parameter Jacobian, a 2n instead of 2n + p filter), but the regressors
// are filtered states: errors-in-variables, coloured equation errors, so its standard
// errors are the RLS's textbook ones and flagged as not valid (identify.cpp).
//
// Numbers: the covariance is kept in scaled coordinates (states by their typical
// amplitude, parameters by their start values), so that metres and N/m^3 share a
// matrix without a condition number of 1e20.
#pragma once

#include "model_internal.hpp"

#include <vibid/common.h>

#include <vibid/rls.h>

#include <Eigen/Core>

#include <cmath>

#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace vibid {

struct StandEkfSettings {
    double h = 0.0;            // sample time, s
    double forgetting = 1.0;   // (0, 1]: the parameter block of the covariance is divided by it each step
    std::size_t window = 1000;  // start window, samples: noise levels and scales are taken from it
    double prior_rel = 0.5;    // relative standard deviation of the start values
    double nis_limit = 10.0;   // restart when the averaged NIS per measurement exceeds it
    double nis_memory = 0.99;  // averaging factor of the NIS
    bool kf_rls = false;       // false: EKF on [y; y'; theta]; true: KF on [y; y'] + RLS on theta
};

// Before any sample: the unknowns must have nominal (start) values, the base (when
// something connects to it) must have its displacement measured, something must excite
// the stand (a measured input, the base, or a disturbance), and the measured channels
// must determine every unknown: the sensitivity of the transfer functions from the
// measured inputs (and of the output spectra of the disturbances) to the parameters, at
// the nominal values, on a frequency grid spanning the modes, must have full rank.
// Throws vibid::Error naming the parameters that are not determined. Cubic coefficients
// have no linear sensitivity and are not part of the rank test. report receives one line
// saying what was checked.
void check_identifiable_state_space(const vibid_model &m, double h, std::string &report);

struct StandEkfStats {
    unsigned long long n_steps = 0;   // filter steps with a measurement update
    unsigned long long restarts = 0;  // restarts after divergence
    unsigned long long boosts = 0;    // parameter covariance widened after a jump in the innovations
    unsigned long long gaps = 0;      // non-finite samples (state restarted, parameters kept)
    double nis_avg = 1.0;             // averaged NIS per measurement (1 when consistent)
    // Drift check (EKF without forgetting; NaN when not available): the largest
    // |theta_i(t) - theta_i(t0)| / sqrt(var_i(t0) - var_i(t)) over the parameters, t0 a
    // snapshot between t/4 and t/2 after the start. For a consistent filter the increment's
    // variance is exactly var(t0) - var(t); an estimate still crawling out of its start
    // transient under standard errors that shrank first shows as |z| >> 1.
    double drift_z = std::nan("");
    // Error bars: true when the sandwich (robust) covariance was available to widen the
    // filter's own (param_cov()), false when not (forgetting < 1, KF+RLS, or fewer than 16
    // score blocks yet).
    bool robust = false;
    double robust_ratio = std::nan("");  // largest sandwich / filter variance over the parameters
    bool started = false;             // the start window is through
};

class StandEkf {
public:
    // Sizes everything (the only allocations). Call check_identifiable_state_space first.
    StandEkf(const vibid_model &m, const StandEkfSettings &s);

    // One sample in the model's channel layout. Allocation-free. VIBID_E_NONFINITE for a
    // non-finite channel (the state restarts at the next sample, the parameters carry
    // on); VIBID_E_DIVERGED when this sample made the filter diverge (restarted from the
    // start values, reason in vibid_last_error()).
    vibid_status push(const double *channels);

    // Back to the start (the start window is collected again).
    void reset();

    // Start values of the parameters (p; in the model's order); used at the next start.
    void set_start(const double *theta0);

    // Current estimate (p), standard errors (p) and covariance (p x p, may be nullptr).
    // Before the start window is full: a provisional estimate from the samples so far
    // (at least 10; VIBID_E_INSUFFICIENT_DATA before), without starting the filter.
    vibid_status estimate(double *theta, double *se, double *cov);

    // The filter's figures; before the start window is full, those of the last
    // provisional run (estimate()).
    const StandEkfStats &stats() const { return stats_.started ? stats_ : prov_stats_; }

    // The last push's measurement update, when it made one (not while the start window is
    // collected nor at the sample that completes it, not at a gap or a divergence):
    // per measured channel, in the filter's order, its index in the sample, the innovation
    // nu = measured - predicted [the channel's unit] and its predicted standard deviation
    // sqrt(S_kk) (S = H P H' + R, with R inflated by *inflation after a start).
    // Writes min(cap, measured channels) entries (any pointer may be nullptr); returns the
    // number of measured channels, 0 when the last push made no update. Allocation-free.
    std::size_t innovations(std::size_t cap, std::size_t *channel, double *nu, double *sd, double *inflation) const;

private:
    struct Meas {
        long channel;   // index in the sample
        std::size_t node;
        int q;          // 0 displacement, 1 velocity, 2 acceleration
        double declared_std;  // < 0: estimate
    };
    struct Cubic {
        std::size_t a, b;  // b may be VIBID_GROUND or VIBID_BASE
        long param;        // -1 known
        double value;
    };
    using Mat = Eigen::MatrixXd;
    using Vec = Eigen::VectorXd;

    void start_from_window();
    void init_state();
    void assemble();
    void linearise_cubics(const double *y, const double *v, double s, double sd);
    void build_transition();
    double window_misfit();
    double temper() const;
    vibid_status advance(const double *cur);
    vibid_status step(const double *prev, const double *cur);
    vibid_status update(const double *cur);
    void restart_parameters();
    void drift_snapshot();
    double drift_z() const;
    void regression_step(const double *prev, const double *cur);
    void param_cov(Mat &cov);
    void score_reset();
    void score_accumulate();
    bool sandwich(Mat &V);
    double base_disp(const double *ch) const;
    void base_now(const double *ch, const double *prev, double &s, double &sd) const;
    double cubic_rho(std::size_t e, const double *y, double s) const;

    const vibid_model *model_ = nullptr;  // owned by the vibid_ident that owns this
    StandEkfSettings set_;
    // Sizes: n nodes, p unknowns, r force inputs, nb = 1 with a base, nw disturbances,
    // nc = 1 with cubic springs (the constant of their linearisation); ne inputs in xi;
    // nx = 2 n states.
    // nf = na (EKF) or nx (KF+RLS): the dimension the filter's covariance works on.
    Eigen::Index nf_ = 0, n_ = 0, p_ = 0, r_ = 0, nb_ = 0, nw_ = 0, nc_ = 0, ne_ = 0, nx_ = 0, N_ = 0, na_ = 0, nz_ = 0,
                 nch_ = 0;
    Eigen::Index col_s_ = -1, col_sd_ = -1;  // base displacement / velocity column in xi (-1: none)
    unsigned boosts_in_row_ = 0;
    unsigned long long settle_steps_ = 0, release_at_ = 0;  // parameters held while unmeasured states settle
    double temper_tau_ = 50.0;  // samples; see temper()
    static constexpr double kTemperStart = 1e4;
    static constexpr double kModelErrorVelocity = 1e-3;  // scaled (typical velocity) per sample; see step()
    unsigned long long nis_check_from_ = 0;  // n_steps at the last start or release: the NIS check counts from here
    bool held_base_kick_ = false;  // held base with dampers: velocity kicks
    bool base_smooth_ = true;
    std::vector<bool> input_smooth_;
    long base_disp_ch_ = -1, base_vel_ch_ = -1;
    std::vector<long> input_ch_;
    std::vector<Meas> meas_;
    std::vector<Cubic> cubics_;
    std::vector<std::pair<double, double>> cubic_lin_;  // per cubic: spring and force per unit eps (linearise_cubics)
    std::vector<double> dist_declared_;   // std, 0 = estimate
    std::vector<std::size_t> dist_node_;  // node the disturbance acts on
    double base_declared_std_ = -1.0, base_noise_var_ = 0.0;  // base channel noise

    // Structure: X(theta) = X0 + sum_i theta_i X_i, X in {M (diag), D, C, B, c_b, d_b}.
    Vec M0_, cb0_, db0_;
    Mat D0_, C0_, B0_;
    std::vector<Vec> Mi_, cbi_, dbi_;
    std::vector<Mat> Di_, Ci_, Bi_;
    Vec theta_start_;

    // Assembled at the current parameters (and linearisation point for cubics).
    Vec Mv_, Minv_, cb_, db_;   // linear part
    Mat D_, C_, B_;
    Vec cbt_, gconst_;          // with the cubic springs linearised about t_k
    Mat Ct_;
    Mat A_, E4_, E2_, E1_, T1_, T2_, Pow_;  // N x N
    std::vector<Mat> dArows_;                // p of n x N: d(A~)/d theta_i, velocity rows
    Vec xi_[5], acc_, gv_;

    // Filter.
    Vec a_;       // [y; v; theta], physical units
    Vec scale_;   // na: scaled coordinates a_s = a / scale
    Mat P_;       // na x na, scaled
    Mat F_, FP_, Hm_, PHt_, Sz_, K_, IKH_, Rz_;
    double last_nis_ = 0.0;  // nu' S^-1 nu of the last update
    Vec zhat_, nu_, Rv_;
    Vec nu_sd_;                 // sqrt(S_kk) of the last update
    double nu_inflation_ = 1.0;  // the measurement noise's inflation in the last update
    bool innovations_fresh_ = false;  // the last push ran a measurement update
    Vec Rw_;

    // KF+RLS: the regression on the physical parameters in scaled coordinates
    // (theta_i / theta_start_i), p parameters, n equations (one per node) per sample.
    struct RlsFree {
        void operator()(vibid_rls *r) const { vibid_rls_destroy(r); }
    };
    std::unique_ptr<vibid_rls, RlsFree> rls_;
    std::vector<Eigen::Index> rows_;  // nodes with a sensor: their equations are the regression's rows
    Mat phi_;             // p x rows regressor, one column per equation
    Mat rls_P0_;          // p x p prior covariance (prior_rel^2 I)
    std::size_t n_eq_ = 0;  // samples in eq_
    Vec target_, eq_;     // rows: target; equation error at the start values (scale pass)
    Vec dv_, dy_, iy_, iu_;  // n, n, n, r: increments and integrals over the interval
    Vec row_scale_;       // rows: equation-error level per row (rows are divided by it)
    Vec rls_theta_;       // p, scaled
    Vec x_prev_;          // nx: filtered state at t_k (before a held base's kick)
    double kick_ds_ = 0.0;  // base jump at t_k of the interval in step() (held base)
    bool scale_pass_ = false;  // collecting eq_ instead of estimating

    // Sandwich (robust) covariance of the parameters (EKF without forgetting; see
    // score_accumulate()): per block of consecutive samples the sums of the scores u_k,
    // of the informations I_k and of I_k theta_{k-1} (scaled coordinates), so that the
    // scores can be moved to the final estimate. Up to kScoreBlocks blocks; when they are
    // full, neighbours are merged and the block length doubles.
    static constexpr Eigen::Index kScoreBlocks = 64;
    static constexpr unsigned long long kScoreBlockStart = 32;  // samples per block at first
    Mat sc_U_, sc_W_;              // p x kScoreBlocks
    std::vector<Mat> sc_J_;        // kScoreBlocks of p x p
    Eigen::Index sc_blocks_ = 0;   // completed blocks
    unsigned long long sc_len_ = kScoreBlockStart, sc_fill_ = 0;  // block length; samples in the current one
    unsigned long long sc_done_ = 0, sc_skipped_ = 0;  // samples in completed blocks; samples without a score
    Mat sc_L_, sc_psi_, sc_Spsi_, sc_G_, sc_T_;  // scratch: p x p, p x nz, nz x p, p x p, p x p
    Vec sc_u_, sc_th_, sc_w_;      // p

    // Start window and continuity.
    Mat cov_;             // p x p scratch for estimate()
    // Drift check snapshots (EKF): parameters (scaled) and their variances at steps
    // drift_at_[0] < drift_at_[1] since the last start or release (0 = none).
    Vec drift_theta_[2], drift_var_[2];
    unsigned long long drift_at_[2] = {0, 0};
    Vec prov_theta_;      // p: the last provisional estimate (before the window is full)
    Mat prov_cov_;        // p x p, physical units
    StandEkfStats prov_stats_;
    std::size_t prov_at_ = 0;  // window fill at the last provisional run
    std::vector<double> window_;
    std::size_t n_window_ = 0;
    std::vector<double> prev_, prev2_;
    bool have_prev_ = false, have_prev2_ = false;
    double sigma_y_ = 1.0, omega_ref_ = 1.0;
    StandEkfStats stats_;
};

}  // namespace vibid
