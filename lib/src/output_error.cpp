// output_error.cpp: output-error estimation on the stand's physical model
// (vibid/output_error.h documents the behaviour users see).
//
// State x = [y; v] (2n). The inputs of an interval [t_k, t_{k+1}] are e(t) = e_k + (t - t_k)
// e'_k, e = [u (r); s (nb)], with e'_k the slope to the next sample for smooth inputs and 0
// for held ones. xi = [x; e; e'] (N = 2n + 2 ne). The velocity rows of the linear part are
//     v' = Av xi,  Av = M^-1 [-C, -D, B, c_b, 0 (u'), d_b (s')],
// so a cubic stand adds -M^-1 g(y, s) (g the cubic forces on the nodes). Everything the
// fit needs follows from two facts:
//   acc = Av xi - M^-1 g,   d acc / d theta_i = M^-1 (X_i xi - M_i acc - dg/dtheta_i)
// with X_i the structure of theta_i laid out like Av's bracket (model.h,
// vibid_model_structure). The fit's unknowns phi = [theta (p); x0 (2n); offsets (ny)];
// the state's sensitivity S = dx/d[theta; x0] (2n x (p + 2n)) starts at [0, I].
#include <vibid/output_error.h>

#include "api_guard.hpp"
#include "gauss_newton.hpp"
#include "model_internal.hpp"
#include "prediction_error.hpp"

#include <Eigen/Dense>
#include <unsupported/Eigen/MatrixFunctions>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <string>
#include <vector>

namespace vibid {
namespace {

using MatX = Eigen::MatrixXd;
using VecX = Eigen::VectorXd;
using Index = Eigen::Index;

constexpr double kRadPerSubstep = 0.08;         // first guess of the RK4 step for cubic stands, rad of the highest mode
constexpr double kSubstepTol = 1e-6;            // doubling the RK4 steps moves the response by less (of its peak)
constexpr Index kChunkRows = 256;               // Jacobian rows gathered before one rank update

struct Response {
    long channel;
    Index node;
    int q;  // 0 displacement, 1 velocity, 2 acceleration
};

struct Cubic {
    Index a;
    std::size_t b;  // node, VIBID_GROUND or VIBID_BASE
    long param;     // -1: known
    double value;
};

// What one pass over the samples produces.
struct Pass {
    double cost = 0.0;
    VecX ms;        // per response channel: mean square residual (weights of the next round)
    VecX count;     // per response channel: finite samples
    MatX H;         // np x np Gauss-Newton information (weighted)
    VecX g;         // np gradient J' W r
    MatX scores;    // np x B block scores (sandwich)
};

class OutputError {
public:
    OutputError(const vibid_model &m, const vibid_oe_config &cfg) : model_(m), cfg_(cfg), bounds_(model_) {
        require_finalized(&model_);
        vibid_model_dims d{};
        if (vibid_model_get_dims(&model_, &d) != VIBID_OK) throw_error(VIBID_E_STATE, "%s", vibid_last_error());
        n_ = static_cast<Index>(d.n_dof);
        r_ = static_cast<Index>(d.n_inputs);
        p_ = static_cast<Index>(d.n_params);
        nch_ = static_cast<Index>(d.n_channels);
        if (p_ == 0) throw_error(VIBID_E_OUT_OF_RANGE, "nothing unknown in the model");
        nb_ = model_.has_base ? 1 : 0;
        if (nb_ && model_.base_channel[0] == kNoChannel)
            throw_error(VIBID_E_DIMENSION, "an element touches the base but the base displacement is not measured");
        ne_ = r_ + nb_;
        N_ = 2 * n_ + 2 * ne_;
        for (std::size_t i = 0; i < model_.nodes.size(); ++i)
            for (int q = 0; q < 3; ++q)
                if (model_.node_channel[i][static_cast<std::size_t>(q)] != kNoChannel)
                    resp_.push_back(Response{model_.node_channel[i][static_cast<std::size_t>(q)], static_cast<Index>(i), q});
        ny_ = static_cast<Index>(resp_.size());
        for (const auto &rs : resp_) has_acc_ = has_acc_ || rs.q == 2;
        if (ny_ == 0) throw_error(VIBID_E_DIMENSION, "no measured response channel (displacement, velocity or acceleration of a node)");
        for (Index j = 0; j < r_; ++j) {
            in_ch_.push_back(model_.input_channel[static_cast<std::size_t>(j)]);
            in_smooth_.push_back(model_.inputs[static_cast<std::size_t>(j)].hold != VIBID_HOLD_ZOH);
        }
        if (nb_) {
            in_ch_.push_back(model_.base_channel[0]);
            in_smooth_.push_back(model_.base_hold != VIBID_HOLD_ZOH);
        }
        for (long c : in_ch_)
            if (c == kNoChannel) throw_error(VIBID_E_DIMENSION, "a force input has no channel");
        kick_ = nb_ && model_.base_hold == VIBID_HOLD_ZOH && model_.base_damper;
        for (const auto &e : model_.elements)
            if (e.kind == VIBID_ELEMENT_CUBIC_SPRING) {
                long param = -1;
                for (const auto &t : model_.terms)
                    if (t.name == e.name) param = t.param;
                cubics_.push_back(Cubic{static_cast<Index>(e.a), e.b, param, e.value});
            }
        nonlinear_ = !cubics_.empty();
        nd_ = p_ + 2 * n_;
        no_ = cfg_.offsets ? ny_ : 0;
        np_ = nd_ + no_;
        load_structure();
    }

    Index n_response() const { return ny_; }
    const std::vector<Response> &responses() const { return resp_; }
    Index p() const { return p_; }
    Index n() const { return n_; }

    vibid_status fit(std::size_t ns, const double *ch, std::size_t n_starts, const double *starts) {
        load_data(ns, ch);
        const std::size_t blocks = choose_blocks(ns);
        if (blocks < 8)
            throw_error(VIBID_E_INSUFFICIENT_DATA, "%zu samples: at least 8 blocks of 50 samples are needed for error bars",
                        ns);
        n_blocks_ = blocks;
        best_ = Fit{};
        best_.cost = kInf;
        for (std::size_t s = 0; s < n_starts; ++s) {
            VecX theta = Eigen::Map<const VecX>(starts + s * static_cast<std::size_t>(p_), p_);
            for (Index i = 0; i < p_; ++i)
                if (!std::isfinite(theta(i))) throw_error(VIBID_E_NONFINITE, "start %zu: '%s' is not finite", s, bounds_.names[static_cast<std::size_t>(i)].c_str());
            Fit f = fit_from(theta, s);
            if (f.cost < best_.cost) best_ = f;
        }
        have_ = true;
        if (!std::isfinite(best_.cost)) {
            best_.failure |= VIBID_OE_UNSTABLE;
            throw_error(VIBID_E_NUMERICAL, "the simulation diverged from every start (%zu)", n_starts);
        }
        if (nonlinear_) {
            // the integration steps for the parameters found (a start far off may have needed fewer)
            const unsigned before = substeps_;
            choose_substeps(best_.phi);
            if (substeps_ != before) {
                Fit f = refine(best_, best_.start, 0);
                if (std::isfinite(f.cost)) best_ = f;
            }
        }
        if (ny_ > 1) {  // second round: weights from the converged residuals
            Fit f = refine(best_, best_.start, 1);
            if (std::isfinite(f.cost)) best_ = f;
        }
        finish(best_);
        if (best_.failure & VIBID_OE_SINGULAR)
            throw_error(VIBID_E_NUMERICAL, "the information matrix is singular (rcond %.3g): %s not determined by the data",
                        best_.rcond, best_.weak.c_str());
        if (best_.failure & VIBID_OE_BOUND)
            throw_error(VIBID_E_DIVERGED, "%s on its physical bound", best_.weak.c_str());
        if (best_.failure & VIBID_OE_NO_CONVERGENCE)
            throw_error(VIBID_E_DIVERGED, "no convergence in %u iterations", cfg_.max_iterations);
        return VIBID_OK;
    }

    void result(double *theta, double *se, double *cov, double *off, double *off_se, double *x0,
                vibid_oe_fit_info *info, double *shift = nullptr) const {
        if (!have_) throw_error(VIBID_E_STATE, "no fit yet");
        const Fit &f = best_;
        if (theta) Eigen::Map<VecX>(theta, p_) = f.phi.head(p_);
        const bool have_cov = f.cov.size() > 0;
        if (se)
            for (Index i = 0; i < p_; ++i) se[i] = have_cov ? std::sqrt(std::max(0.0, f.cov(i, i))) : std::nan("");
        if (cov) {
            if (have_cov) Eigen::Map<MatX>(cov, p_, p_) = f.cov.topLeftCorner(p_, p_);
            else Eigen::Map<MatX>(cov, p_, p_).setConstant(std::nan(""));
        }
        for (Index j = 0; j < ny_; ++j) {
            if (off) off[j] = no_ ? f.phi(nd_ + j) : 0.0;
            if (off_se) off_se[j] = no_ && have_cov ? std::sqrt(std::max(0.0, f.cov(nd_ + j, nd_ + j))) : 0.0;
        }
        if (x0) Eigen::Map<VecX>(x0, 2 * n_) = f.phi.segment(p_, 2 * n_);
        if (info) {
            info->failure = f.failure;
            info->iterations = f.iterations;
            info->start = f.start;
            info->n_samples = static_cast<std::size_t>(ns_);
            info->n_response = static_cast<std::size_t>(ny_);
            info->n_blocks = n_blocks_;
            info->cost = f.cost;
            info->rcond = f.rcond;
            info->interp_z = 0.0;
            for (Index i = 0; i < p_ && f.shift.size() == p_; ++i) {
                const double se_i = have_cov ? std::sqrt(std::max(0.0, f.cov(i, i))) : 0.0;
                const double z = f.shift(i) == 0.0 ? 0.0 : std::fabs(f.shift(i)) / se_i;
                if (!(z <= info->interp_z)) info->interp_z = std::isnan(z) ? kInf : z;
            }
            info->interp_evidence = f.path_evidence;
            info->input_path_uncovered =
                info->interp_z > 1.0 && !(f.path_evidence < -VIBID_OE_PATH_DECISIVE) ? 1 : 0;
        }
        if (shift) {
            for (Index i = 0; i < p_; ++i) shift[i] = f.shift.size() == p_ ? f.shift(i) : 0.0;
        }
    }

    void simulate(const double *theta, const double *x0, const double *off, std::size_t ns, const double *ch,
                  double *out) {
        load_data(ns, ch);
        VecX phi = VecX::Zero(np_);
        phi.head(p_) = Eigen::Map<const VecX>(theta, p_);
        if (x0) phi.segment(p_, 2 * n_) = Eigen::Map<const VecX>(x0, 2 * n_);
        weights_ = VecX::Ones(ny_);
        choose_substeps(phi);
        sim_out_ = out;
        Pass ps;
        weights_ = VecX::Ones(ny_);
        const double c = pass(phi, false, ps);
        sim_out_ = nullptr;
        if (!std::isfinite(c)) throw_error(VIBID_E_NUMERICAL, "the simulation diverged");
        if (off)
            for (Index j = 0; j < ny_; ++j)
                for (std::size_t k = 0; k < ns; ++k) out[k + static_cast<std::size_t>(j) * ns] += off[j];
    }

private:
    static constexpr double kInf = std::numeric_limits<double>::infinity();

    struct Fit : FitState {
        VecX w;  // weights of the round
        VecX shift;  // p: interpolation_shift
        double path_evidence = 0.0;  // interpolation_shift: the data's preference for the parabola
    };

    void load_structure() {
        const Index n = n_, r = r_;
        MatX Mm(n, n), Dm(n, n), Cm(n, n), Bm(n, std::max<Index>(r, 1));
        VecX db(n), cb(n);
        auto into = [&](MatX &X) {
            X.setZero(n, N_);
            X.block(0, 0, n, n) = -Cm;
            X.block(0, n, n, n) = -Dm;
            if (r) X.block(0, 2 * n, n, r) = Bm.leftCols(r);
            if (nb_) {
                X.col(2 * n + r) = cb;
                X.col(2 * n + ne_ + r) = db;
            }
        };
        std::vector<double> zero(static_cast<std::size_t>(p_), 0.0);
        if (vibid_model_assemble(&model_, zero.data(), Mm.data(), Dm.data(), Cm.data(), r ? Bm.data() : nullptr,
                                 db.data(), cb.data()) != VIBID_OK)
            throw_error(VIBID_E_STATE, "%s", vibid_last_error());
        M0_ = Mm;
        into(X0_);
        Mi_.resize(static_cast<std::size_t>(p_));
        Xi_.resize(static_cast<std::size_t>(p_));
        for (Index i = 0; i < p_; ++i) {
            if (vibid_model_structure(&model_, static_cast<std::size_t>(i), Mm.data(), Dm.data(), Cm.data(),
                                      r ? Bm.data() : nullptr, db.data(), cb.data()) != VIBID_OK)
                throw_error(VIBID_E_STATE, "%s", vibid_last_error());
            Mi_[static_cast<std::size_t>(i)] = Mm;
            into(Xi_[static_cast<std::size_t>(i)]);
        }
    }

    std::size_t choose_blocks(std::size_t ns) const {
        if (cfg_.n_blocks) return std::min<std::size_t>(cfg_.n_blocks, ns / 50);
        return std::min<std::size_t>(32, ns / 50);
    }

    void load_data(std::size_t ns, const double *ch) {
        ns_ = static_cast<Index>(ns);
        E_.resize(ne_, ns_);
        Ed_.resize(ne_, ns_);
        Z_.resize(ny_, ns_);
        const double h = cfg_.sample_time;
        for (Index j = 0; j < ne_; ++j) {
            const double *col = ch + static_cast<std::size_t>(in_ch_[static_cast<std::size_t>(j)]) * ns;
            for (Index k = 0; k < ns_; ++k) {
                if (!std::isfinite(col[k]))
                    throw_error(VIBID_E_NONFINITE,
                                "input channel '%s', sample %ld: not finite (an input gap cannot be simulated across: "
                                "fit the parts on either side)",
                                model_.channels[static_cast<std::size_t>(in_ch_[static_cast<std::size_t>(j)])].name.c_str(),
                                static_cast<long>(k));
                E_(j, k) = col[k];
            }
            for (Index k = 0; k < ns_; ++k) {
                if (!in_smooth_[static_cast<std::size_t>(j)]) Ed_(j, k) = 0.0;
                else if (k + 1 < ns_) Ed_(j, k) = (E_(j, k + 1) - E_(j, k)) / h;
                else Ed_(j, k) = k > 0 ? Ed_(j, k - 1) : 0.0;
            }
        }
        scale_ = VecX::Zero(ny_);
        for (Index j = 0; j < ny_; ++j) {
            const double *col = ch + static_cast<std::size_t>(resp_[static_cast<std::size_t>(j)].channel) * ns;
            for (Index k = 0; k < ns_; ++k) {
                Z_(j, k) = col[k];
                if (std::isfinite(col[k])) scale_(j) = std::max(scale_(j), std::fabs(col[k]));
            }
        }
    }

    // Parameters at theta: M^-1, Av, and the stacked derivative pieces.
    void assemble(const VecX &theta) {
        MatX M = M0_;
        MatX X = X0_;
        for (Index i = 0; i < p_; ++i) {
            M.noalias() += theta(i) * Mi_[static_cast<std::size_t>(i)];
            X.noalias() += theta(i) * Xi_[static_cast<std::size_t>(i)];
        }
        Minv_ = M.inverse();
        Av_.noalias() = Minv_ * X;
        MinvX_.resize(n_ * p_, N_);
        MinvM_.resize(n_ * p_, n_);
        for (Index i = 0; i < p_; ++i) {
            MinvX_.middleRows(i * n_, n_).noalias() = Minv_ * Xi_[static_cast<std::size_t>(i)];
            MinvM_.middleRows(i * n_, n_).noalias() = Minv_ * Mi_[static_cast<std::size_t>(i)];
        }
        cubic_eps_.resize(cubics_.size());
        for (std::size_t c = 0; c < cubics_.size(); ++c)
            cubic_eps_[c] = cubics_[c].param >= 0 ? theta(cubics_[c].param) : cubics_[c].value;
    }

    // Linear stands: E = exp(A~ h) top rows and the stacked Frechet derivatives.
    // With quad_ the inputs' second derivatives (constant over the interval) are a third
    // block of the augmented state (N_ + ne_ columns), which the forces do not touch.
    void discretise(bool with_sens) {
        const Index n = n_, Na = augmented();
        MatX A = MatX::Zero(Na, Na);
        for (Index i = 0; i < n; ++i) A(i, n + i) = 1.0;
        A.block(n, 0, n, N_) = Av_;
        for (Index j = 0; j < ne_; ++j) A(2 * n + j, 2 * n + ne_ + j) = 1.0;
        if (quad_)
            for (Index j = 0; j < ne_; ++j) A(2 * n + ne_ + j, 2 * n + 2 * ne_ + j) = 1.0;
        const double h = cfg_.sample_time;
        MatX E = (A * h).exp();
        Etop_ = E.topRows(2 * n);
        if (!with_sens) return;
        dEtop_.resize(2 * n * p_, Na);
        MatX big = MatX::Zero(2 * Na, 2 * Na);
        big.topLeftCorner(Na, Na) = A * h;
        big.bottomRightCorner(Na, Na) = A * h;
        for (Index i = 0; i < p_; ++i) {
            MatX dA = MatX::Zero(Na, Na);
            // d Av / d theta_i = M^-1 (X_i - M_i Av)
            dA.block(n, 0, n, N_) = MinvX_.middleRows(i * n, n) - MinvM_.middleRows(i * n, n) * Av_;
            big.topRightCorner(Na, Na) = dA * h;
            MatX Eb = big.exp();
            dEtop_.middleRows(i * 2 * n, 2 * n) = Eb.topRightCorner(Na, Na).topRows(2 * n);
        }
    }

    // Cubic forces g (n) on the nodes at displacements y and base s; K the tangent
    // stiffness dg/dy (n x n) when wanted; G (n x p) dg/dtheta for the cubic unknowns.
    void cubic_forces(const double *y, double s, VecX &g, MatX *K, MatX *G) const {
        g.setZero(n_);
        if (K) K->setZero(n_, n_);
        if (G) G->setZero(n_, p_);
        for (std::size_t c = 0; c < cubics_.size(); ++c) {
            const Cubic &cu = cubics_[c];
            const double yb = cu.b == VIBID_GROUND ? 0.0 : cu.b == VIBID_BASE ? s : y[cu.b];
            const double rho = y[cu.a] - yb, eps = cubic_eps_[c];
            const double f = eps * rho * rho * rho, k = 3.0 * eps * rho * rho;
            const bool other = cu.b != VIBID_GROUND && cu.b != VIBID_BASE;
            const Index b = other ? static_cast<Index>(cu.b) : 0;
            g(cu.a) += f;
            if (other) g(b) -= f;
            if (K) {
                (*K)(cu.a, cu.a) += k;
                if (other) {
                    (*K)(cu.a, b) -= k;
                    (*K)(b, cu.a) -= k;
                    (*K)(b, b) += k;
                }
            }
            if (G && cu.param >= 0) {
                (*G)(cu.a, cu.param) += rho * rho * rho;
                if (other) (*G)(b, cu.param) -= rho * rho * rho;
            }
        }
    }

    // Time derivative of [x | S] at input vector xi (x part of xi is X.col(0)).
    // dX: 2n x (1 + nd). acc_sens (may be null): n x nd, the acceleration's sensitivity.
    void deriv(const MatX &X, VecX &xi, MatX &dX) {
        const Index n = n_;
        xi.head(2 * n) = X.col(0);
        acc_.noalias() = Av_ * xi.head(N_);
        MatX *K = nullptr;
        MatX *G = nullptr;
        if (nonlinear_) {
            const double s = nb_ ? xi(2 * n + r_) : 0.0;
            cubic_forces(xi.data(), s, gcub_, &Kc_, &Gc_);
            K = &Kc_;
            G = &Gc_;
            acc_.noalias() -= Minv_ * gcub_;
        }
        dX.topRows(n) = X.bottomRows(n);
        dX.block(n, 0, n, 1) = acc_;
        if (X.cols() == 1) return;
        // sensitivity: d acc = Av_x S (+ -M^-1 K S_y) + [M^-1 (X_i xi - M_i acc - dg_i) | 0]
        auto dS = dX.block(n, 1, n, nd_);
        dS.noalias() = Av_.leftCols(2 * n) * X.rightCols(nd_);
        if (K) {
            MK_.noalias() = Minv_ * (*K);
            dS.noalias() -= MK_ * X.block(0, 1, n, nd_);
        }
        stackX_.noalias() = MinvX_ * xi.head(N_);
        stackM_.noalias() = MinvM_ * acc_;
        for (Index i = 0; i < p_; ++i) dS.col(i) += stackX_.segment(i * n, n) - stackM_.segment(i * n, n);
        if (G) dS.leftCols(p_).noalias() -= Minv_ * (*G);
    }

    // One pass over the samples at phi. with_sens: information, gradient and block
    // scores in ps. Returns the cost (inf when the simulation diverges).
    double pass(const VecX &phi, bool with_sens, Pass &ps) {
        const Index n = n_, nx = 2 * n;
        const VecX theta = phi.head(p_);
        assemble(theta);
        if (!nonlinear_) discretise(with_sens);
        const Index cols = with_sens ? 1 + nd_ : 1;
        MatX X = MatX::Zero(nx, cols);
        X.col(0) = phi.segment(p_, nx);
        if (with_sens) X.block(0, 1 + p_, nx, nx).setIdentity();
        MatX dX(nx, cols), K1(nx, cols), K2(nx, cols), K3(nx, cols), K4(nx, cols), Xt(nx, cols);
        VecX xi = VecX::Zero(augmented());
        stackX_.resize(n * p_);
        stackM_.resize(n * p_);
        ps.cost = 0.0;
        ps.ms = VecX::Zero(ny_);
        ps.count = VecX::Zero(ny_);
        if (with_sens) {
            ps.H = MatX::Zero(np_, np_);
            ps.g = VecX::Zero(np_);
            ps.scores = MatX::Zero(np_, static_cast<Index>(n_blocks_));
        }
        MatX J(kChunkRows, np_);
        VecX rr(kChunkRows);
        Index nrow = 0;
        std::size_t block = 0;
        const std::size_t block_len = n_blocks_ ? static_cast<std::size_t>(ns_) / n_blocks_ : 0;
        auto flush = [&]() {
            if (!nrow) return;
            auto Jb = J.topRows(nrow);
            ps.H.selfadjointView<Eigen::Lower>().rankUpdate(Jb.transpose());
            const VecX gb = Jb.transpose() * rr.head(nrow);
            ps.g += gb;
            ps.scores.col(static_cast<Index>(std::min(block, n_blocks_ - 1))) += gb;
            nrow = 0;
        };
        double bound = 0.0;
        for (Index j = 0; j < ny_; ++j) bound = std::max(bound, scale_(j));
        bound = 1e6 * (bound > 0.0 ? bound : 1.0);
        const double h = cfg_.sample_time;
        const unsigned sub = nonlinear_ ? substeps_ : 1;
        const double hs = h / sub;
        for (Index k = 0; k < ns_; ++k) {
            xi.segment(nx, ne_) = E_.col(k);
            xi.segment(nx + ne_, ne_) = Ed_.col(k);
            if (quad_) xi.segment(nx + 2 * ne_, ne_) = Edd_.col(k);
            if (kick_) {
                // held base: the velocities jump by M^-1 d_b (s_k - s_{k-1}) at t_k; before the
                // first sample the base is taken at 0 (as vibid-sim's stand at rest). The
                // estimated initial velocity absorbs that first jump, whatever the base did
                // before the capture.
                const double ds = E_(ne_ - 1, k) - (k > 0 ? E_(ne_ - 1, k - 1) : 0.0);
                const Index cdb = nx + ne_ + r_;
                X.block(n, 0, n, 1) += Av_.col(cdb) * ds;
                if (with_sens)
                    for (Index i = 0; i < p_; ++i)
                        X.block(n, 1 + i, n, 1) += (MinvX_.block(i * n, cdb, n, 1) - MinvM_.middleRows(i * n, n) * Av_.col(cdb)) * ds;
            }
            const bool need_acc = has_acc_ || nonlinear_;
            if (need_acc) deriv(X, xi, dX);
            // outputs
            for (Index j = 0; j < ny_; ++j) {
                const Response &rs = resp_[static_cast<std::size_t>(j)];
                double yhat;
                if (rs.q == 2) yhat = dX(n + rs.node, 0);
                else yhat = X(rs.q * n + rs.node, 0);
                if (sim_out_) sim_out_[k + j * ns_] = yhat;
                const double z = Z_(j, k);
                if (!std::isfinite(z)) continue;
                const double res = z - yhat - (no_ ? phi(nd_ + j) : 0.0);
                const double sw = std::sqrt(weights_(j));
                ps.cost += 0.5 * weights_(j) * res * res;
                ps.ms(j) += res * res;
                ps.count(j) += 1.0;
                if (!with_sens) continue;
                auto row = J.row(nrow);
                row.setZero();
                if (rs.q == 2) row.head(nd_) = dX.block(n + rs.node, 1, 1, nd_) * sw;
                else row.head(nd_) = X.block(rs.q * n + rs.node, 1, 1, nd_) * sw;
                if (no_) row(nd_ + j) = sw;
                rr(nrow) = res * sw;
                if (++nrow == kChunkRows) flush();
            }
            if (!std::isfinite(X(0, 0)) || X.col(0).cwiseAbs().maxCoeff() > bound) return kInf;
            if (with_sens && block_len && static_cast<std::size_t>(k + 1) % block_len == 0) {
                flush();
                ++block;
            }
            if (k + 1 == ns_) break;
            // advance to t_{k+1}
            if (!nonlinear_) {
                xi.head(nx) = X.col(0);  // after the kick (deriv set it only with accelerations)
                Xt.col(0).noalias() = Etop_ * xi;
                if (with_sens) {
                    Xt.rightCols(nd_).noalias() = Etop_.leftCols(nx) * X.rightCols(nd_);
                    stackE_.noalias() = dEtop_ * xi;
                    for (Index i = 0; i < p_; ++i) Xt.col(1 + i) += stackE_.segment(i * nx, nx);
                }
                X.swap(Xt);
                continue;
            }
            const VecX e0 = E_.col(k), ed = Ed_.col(k);
            const VecX edd = quad_ ? VecX(Edd_.col(k)) : VecX::Zero(ne_);
            // the inputs and their slopes at tau into the interval
            auto inputs_at = [&](double tau) {
                xi.segment(nx, ne_) = e0 + tau * ed + (0.5 * tau * tau) * edd;
                if (quad_) xi.segment(nx + ne_, ne_) = ed + tau * edd;
            };
            for (unsigned s = 0; s < sub; ++s) {
                const double tau = s * hs;
                inputs_at(tau);
                deriv(X, xi, K1);
                Xt = X + 0.5 * hs * K1;
                inputs_at(tau + 0.5 * hs);
                deriv(Xt, xi, K2);
                Xt = X + 0.5 * hs * K2;
                deriv(Xt, xi, K3);
                Xt = X + hs * K3;
                inputs_at(tau + hs);
                deriv(Xt, xi, K4);
                X += (hs / 6.0) * (K1 + 2.0 * K2 + 2.0 * K3 + K4);
            }
        }
        if (with_sens) {
            flush();
            ps.H.triangularView<Eigen::StrictlyUpper>() = ps.H.transpose();
        }
        return ps.cost;
    }

    void project(VecX &phi) const { bounds_.project(phi, start_); }

    // Levenberg-Marquardt from fit f (its phi and weights) for one round.
    Fit refine(Fit f, std::size_t start, int round) {
        if (round > 0) {
            Pass ps;
            weights_ = f.w;
            pass(f.phi, false, ps);
            for (Index j = 0; j < ny_; ++j)
                f.w(j) = ps.count(j) > 0 && ps.ms(j) > 0 ? ps.count(j) / ps.ms(j) : 1.0;
        }
        weights_ = f.w;
        f.start = start;
        Pass cur;
        f.cost = pass(f.phi, true, cur);
        if (!std::isfinite(f.cost)) return f;
        const LmOutcome lm = levenberg_marquardt(
            f.phi, f.cost, cur, cfg_.max_iterations,
            [this](const VecX &phi, bool with_sens, Pass &ps) { return pass(phi, with_sens, ps); },
            [this](VecX &phi) { project(phi); });
        f.iterations += lm.iterations;
        if (!lm.converged) f.failure |= VIBID_OE_NO_CONVERGENCE;
        else f.failure &= ~VIBID_OE_NO_CONVERGENCE;
        return f;
    }

    Fit fit_from(const VecX &theta, std::size_t start) {
        start_ = theta;
        Fit f;
        f.phi = VecX::Zero(np_);
        f.phi.head(p_) = theta;
        project(f.phi);
        // start state: measured displacements and their first differences; the rest at rest
        for (const auto &rs : resp_) {
            if (rs.q != 0 || ns_ < 2) continue;
            const Index j = static_cast<Index>(&rs - resp_.data());
            if (std::isfinite(Z_(j, 0)) && std::isfinite(Z_(j, 1))) {
                f.phi(p_ + rs.node) = Z_(j, 0);
                f.phi(p_ + n_ + rs.node) = (Z_(j, 1) - Z_(j, 0)) / cfg_.sample_time;
            }
        }
        choose_substeps(f.phi);
        // weights of the first round: residual level per channel at the start
        weights_ = VecX::Ones(ny_);
        Pass ps;
        const double c0 = pass(f.phi, false, ps);
        f.w = VecX::Ones(ny_);
        if (!std::isfinite(c0)) return f;
        for (Index j = 0; j < ny_; ++j)
            f.w(j) = ps.count(j) > 0 && ps.ms(j) > 0 ? ps.count(j) / ps.ms(j) : 1.0;
        return refine(f, start, 0);
    }

    // Runge-Kutta steps per sample for a cubic stand at phi: a first guess from the highest
    // natural frequency (the cubic springs' tangent at the largest measured displacement),
    // then doubled until the simulated response (first 20,000 samples) moves by less than
    // kSubstepTol of its peak: the error of the kept count is then about 1/16 of that (RK4).
    // A hardening spring's response carries its third harmonic, so the frequency alone
    // underestimates what the integration needs (a 1-DOF cubic stand needed 8x the guess).
    void choose_substeps(const VecX &phi) {
        substeps_ = 1;
        if (!nonlinear_) return;
        if (cfg_.substeps) {
            substeps_ = cfg_.substeps;
            return;
        }
        assemble(phi.head(p_));
        MatX A = -Av_.leftCols(n_);
        std::vector<double> y(static_cast<std::size_t>(n_), 0.0);
        for (Index j = 0; j < ny_; ++j)
            if (resp_[static_cast<std::size_t>(j)].q == 0) y[static_cast<std::size_t>(resp_[static_cast<std::size_t>(j)].node)] = scale_(j);
        VecX g;
        MatX K;
        cubic_forces(y.data(), 0.0, g, &K, nullptr);
        A += Minv_ * K.cwiseAbs();
        Eigen::EigenSolver<MatX> es(A);
        double w2 = 0.0;
        for (Index i = 0; i < n_; ++i) w2 = std::max(w2, std::abs(es.eigenvalues()(i)));
        const double wh = std::sqrt(w2) * cfg_.sample_time;
        unsigned m = static_cast<unsigned>(std::min(500.0, std::max(1.0, std::ceil(wh / kRadPerSubstep))));
        const Index full = ns_, len = std::min<Index>(ns_, 20000);
        ns_ = len;
        std::vector<double> a(static_cast<std::size_t>(len * ny_)), b(a.size());
        const VecX w = weights_;
        weights_ = VecX::Ones(ny_);
        Pass ps;
        substeps_ = m;
        sim_out_ = a.data();
        bool ok = std::isfinite(pass(phi, false, ps));
        double last = kInf;
        while (m < 512) {
            substeps_ = 2 * m;
            sim_out_ = b.data();
            const bool ok2 = std::isfinite(pass(phi, false, ps));
            double peak = 0.0, diff = 0.0;
            for (std::size_t i = 0; i < a.size(); ++i) {
                peak = std::max(peak, std::fabs(b[i]));
                diff = std::max(diff, std::fabs(b[i] - a[i]));
            }
            m *= 2;
            // converged, or no longer converging (rounding, amplified along a trajectory that
            // is sensitive to it, dominates: more steps would not help)
            if (ok && ok2 && (diff <= kSubstepTol * peak || diff > 0.25 * last)) break;
            last = diff;
            ok = ok2;
            a.swap(b);
        }
        sim_out_ = nullptr;
        weights_ = w;
        ns_ = full;
        substeps_ = m;
    }

    // Covariance (sandwich), bounds and rank of the kept fit.
    void finish(Fit &f) {
        weights_ = f.w;
        Pass ps;
        f.cost = pass(f.phi, true, ps);
        const Sandwich sw = sandwich(ps.H, ps.scores);
        f.rcond = sw.rcond;
        f.weak.clear();
        if (sw.singular) {
            f.failure |= VIBID_OE_SINGULAR;
            for (Index i = 0; i < np_; ++i)
                if (std::fabs(sw.weakest(i)) > 0.3) f.weak += (f.weak.empty() ? "'" : ", '") + phi_name(i) + "'";
        }
        f.cov = sw.cov;
        f.shift = interpolation_shift(f, sw.Hinv, f.path_evidence);
        const std::string bound = bounds_.at_bound(f.phi, start_);
        if (!bound.empty()) {
            f.failure |= VIBID_OE_BOUND;
            if (!(f.failure & VIBID_OE_SINGULAR)) f.weak = bound;
        }
    }

    Index augmented() const { return N_ + (quad_ ? ne_ : 0); }

    // How far the estimate moves when the smooth inputs follow, between samples, the local
    // parabola instead of the straight line (output_error.h, "Input path"): one Gauss-Newton
    // step of the cost with parabolic inputs from the fit f (whose linear-input gradient is
    // zero to the convergence tolerance), Hinv its information's (pseudo-)inverse. The
    // parabola on [t_k, t_k+1] passes through both samples with the second derivative
    // (d2_k + d2_k+1) / (2 h^2), d2 the second differences (one-sided at the ends). p values;
    // zero without a smooth input, inf when the simulation with parabolic inputs diverges.
    //
    // evidence: which path the data prefer, 2 (cost of the line at f - cost of the parabola
    // at its Gauss-Newton optimum) / the residual variance, so a log-likelihood ratio in
    // chi-square units for white residuals; divided by the
    // inflation of the sandwich covariance over the Gauss-Newton one (coloured residuals
    // carry less information than their count). > 0: the parabola explains the data better;
    // < 0: the straight line does (as on captures simulated with inputs linear between
    // samples: vibid-sim's noise and PRBS, scipy's lsim).
    static constexpr int kPathSteps = 3;  // Gauss-Newton steps of the parabola's fit (evidence)
    VecX interpolation_shift(const Fit &f, const MatX &Hinv, double &evidence) {
        VecX shift = VecX::Zero(p_);
        evidence = 0.0;
        bool any = false;
        for (bool sm : in_smooth_) any = any || sm;
        if (!any || ns_ < 3) return shift;
        const double h = cfg_.sample_time;
        const MatX Ed_line = Ed_;
        Edd_ = MatX::Zero(ne_, ns_);
        for (Index j = 0; j < ne_; ++j) {
            if (!in_smooth_[static_cast<std::size_t>(j)]) continue;
            auto d2 = [&](Index k) {  // second difference at sample k, 1 <= k <= ns-2
                k = std::min(std::max<Index>(k, 1), ns_ - 2);
                return E_(j, k + 1) - 2.0 * E_(j, k) + E_(j, k - 1);
            };
            for (Index k = 0; k + 1 < ns_; ++k) {
                const double c = (d2(k) + d2(k + 1)) / (2.0 * h * h);
                Edd_(j, k) = c;
                Ed_(j, k) = (E_(j, k + 1) - E_(j, k)) / h - 0.5 * c * h;  // the parabola's slope at t_k
            }
        }
        quad_ = true;
        weights_ = f.w;
        Pass ps;
        const double c = pass(f.phi, true, ps);
        // The parabola's own fit, for the evidence: Gauss-Newton steps on this pass's
        // information (the line fit's Hinv does not bound the decrease: its quadratic model
        // predicted a negative cost on a cubic stand), each kept only where it lowers the
        // cost, so parabola_cost bounds the parabola's optimum from above and the evidence
        // leans to the straight line when the steps fall short.
        double parabola_cost = c;
        if (std::isfinite(c)) {
            VecX phi = f.phi;
            Pass cur = ps;
            for (int it = 0; it < kPathSteps; ++it) {
                const VecX d = cur.H.diagonal().cwiseMax(1e-300).cwiseSqrt().cwiseInverse();
                const MatX Hs = d.asDiagonal() * cur.H * d.asDiagonal();
                const VecX step = d.asDiagonal() * Hs.completeOrthogonalDecomposition().solve(VecX(d.asDiagonal() * cur.g));
                VecX cand = phi + step;
                project(cand);
                Pass next;
                const double cn = pass(cand, true, next);
                if (!(cn < parabola_cost)) break;
                parabola_cost = cn;
                phi = cand;
                cur = next;
            }
        }
        quad_ = false;
        Ed_ = Ed_line;
        Edd_.resize(0, 0);
        if (!std::isfinite(c)) return VecX::Constant(p_, kInf);
        shift = (Hinv * ps.g).head(p_);
        double inflation = 0.0;
        Index counted = 0;
        for (Index i = 0; i < np_; ++i)
            if (Hinv(i, i) > 0.0 && std::isfinite(f.cov(i, i))) {
                inflation += f.cov(i, i) / Hinv(i, i);
                ++counted;
            }
        inflation = counted ? std::max(1.0, inflation / static_cast<double>(counted)) : 1.0;
        // the weights are fixed per round, not 1 / variance: the residual variance in the
        // cost's units is 2 cost / residuals
        const double residuals = ps.count.sum();
        evidence = f.cost > 0.0 && residuals > 0.0 ? (f.cost - parabola_cost) * residuals / f.cost / inflation : 0.0;
        return shift;
    }

    std::string phi_name(Index i) const {
        if (i < p_) return bounds_.names[static_cast<std::size_t>(i)];
        if (i < nd_) {
            const Index k = i - p_;
            return model_.nodes[static_cast<std::size_t>(k % n_)].name + (k < n_ ? " initial displacement" : " initial velocity");
        }
        return "offset of " + model_.channels[static_cast<std::size_t>(resp_[static_cast<std::size_t>(i - nd_)].channel)].name;
    }

    vibid_model model_;
    vibid_oe_config cfg_;
    Index n_ = 0, r_ = 0, p_ = 0, nch_ = 0, nb_ = 0, ne_ = 0, N_ = 0, ny_ = 0, nd_ = 0, no_ = 0, np_ = 0, ns_ = 0;
    std::vector<Response> resp_;
    std::vector<long> in_ch_;
    std::vector<bool> in_smooth_;
    bool kick_ = false, nonlinear_ = false, has_acc_ = false;
    std::vector<Cubic> cubics_;
    std::vector<double> cubic_eps_;
    PhysicalBounds bounds_;
    VecX start_;
    MatX M0_, X0_;
    std::vector<MatX> Mi_, Xi_;
    MatX Minv_, Av_, MinvX_, MinvM_, Etop_, dEtop_, Kc_, Gc_, MK_;
    VecX acc_, gcub_, stackX_, stackM_, stackE_;
    MatX E_, Ed_, Edd_, Z_;  // inputs, their slopes and (quad_) second derivatives per interval; responses
    bool quad_ = false;      // inputs parabolic between samples (interpolation_shift only)
    VecX scale_, weights_;
    unsigned substeps_ = 1;
    std::size_t n_blocks_ = 0;
    double *sim_out_ = nullptr;
    Fit best_;
    bool have_ = false;
};

}  // namespace
}  // namespace vibid

// A stand with a disturbance gets the prediction-error fit (prediction_error.hpp), any
// other the output-error fit; both behind the same calls.
struct vibid_oe {
    vibid_oe(const vibid_model &m, const vibid_oe_config &c) {
        if (m.disturbances.empty()) oe = std::make_unique<vibid::OutputError>(m, c);
        else pe = std::make_unique<vibid::PredictionError>(m, c);
    }
    vibid_oe(const vibid_oe &o)
        : oe(o.oe ? std::make_unique<vibid::OutputError>(*o.oe) : nullptr),
          pe(o.pe ? std::make_unique<vibid::PredictionError>(*o.pe) : nullptr) {}
    std::unique_ptr<vibid::OutputError> oe;
    std::unique_ptr<vibid::PredictionError> pe;
};

extern "C" {

VIBID_API void vibid_oe_config_init(vibid_oe_config *cfg, double sample_time) {
    if (!cfg) return;
    *cfg = vibid_oe_config{};
    cfg->sample_time = sample_time;
    cfg->offsets = 1;
    cfg->max_iterations = 100;
}

VIBID_API vibid_oe *vibid_oe_create(const vibid_model *model, const vibid_oe_config *cfg) {
    return vibid::guard_create<vibid_oe>("vibid_oe_create", [&]() -> vibid_oe * {
        if (!model || !cfg) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "model and cfg are required");
        if (!(cfg->sample_time > 0.0) || !std::isfinite(cfg->sample_time))
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "sample_time = %g, need > 0", cfg->sample_time);
        if (cfg->max_iterations < 1 || cfg->max_iterations > 10000)
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "max_iterations = %u outside 1..10000", cfg->max_iterations);
        if (cfg->substeps > 1000) vibid::throw_error(VIBID_E_OUT_OF_RANGE, "substeps = %u above 1000", cfg->substeps);
        if (cfg->n_blocks && (cfg->n_blocks < 8 || cfg->n_blocks > 1024))
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "n_blocks = %u outside 8..1024 (0 = automatic)", cfg->n_blocks);
        return new vibid_oe(*model, *cfg);
    });
}

VIBID_API void vibid_oe_destroy(vibid_oe *oe) { delete oe; }

VIBID_API vibid_status vibid_oe_dims(const vibid_oe *oe, size_t *n_response, size_t *response_channels) {
    return vibid::guard("vibid_oe_dims", [&]() {
        if (!oe) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "oe is required");
        std::vector<long> ch;
        if (oe->pe) ch = oe->pe->response_channels();
        else
            for (const auto &rs : oe->oe->responses()) ch.push_back(rs.channel);
        if (n_response) *n_response = ch.size();
        if (response_channels)
            for (std::size_t j = 0; j < ch.size(); ++j) response_channels[j] = static_cast<size_t>(ch[j]);
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_oe_fit(vibid_oe *oe, size_t n_samples, const double *channels, size_t n_starts,
                                    const double *theta_starts) {
    return vibid::guard("vibid_oe_fit", [&]() {
        if (!oe || !channels || !theta_starts) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "oe, channels and theta_starts are required");
        if (n_starts < 1) vibid::throw_error(VIBID_E_OUT_OF_RANGE, "n_starts = 0, need at least 1");
        return oe->pe ? oe->pe->fit(n_samples, channels, n_starts, theta_starts)
                      : oe->oe->fit(n_samples, channels, n_starts, theta_starts);
    });
}

VIBID_API vibid_status vibid_oe_result(const vibid_oe *oe, double *theta, double *se, double *cov, double *offsets,
                                       double *offsets_se, double *x0, vibid_oe_fit_info *info) {
    return vibid::guard("vibid_oe_result", [&]() {
        if (!oe) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "oe is required");
        if (oe->pe) oe->pe->result(theta, se, cov, offsets, offsets_se, x0, info);
        else oe->oe->result(theta, se, cov, offsets, offsets_se, x0, info);
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_oe_interp_shift(const vibid_oe *oe, double *shift) {
    return vibid::guard("vibid_oe_interp_shift", [&]() {
        if (!oe || !shift) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "oe and shift are required");
        if (oe->pe) {  // no smooth-input path check for the prediction-error fit (output_error.h)
            oe->pe->result(nullptr, nullptr, nullptr, nullptr, nullptr, nullptr, nullptr);
            std::fill(shift, shift + oe->pe->n_params(), 0.0);
        } else {
            oe->oe->result(nullptr, nullptr, nullptr, nullptr, nullptr, nullptr, nullptr, shift);
        }
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_oe_noise(const vibid_oe *oe, double *disturbance_std, double *disturbance_se,
                                      double *noise_std, double *noise_se) {
    return vibid::guard("vibid_oe_noise", [&]() {
        if (!oe) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "oe is required");
        if (!oe->pe)
            vibid::throw_error(VIBID_E_UNSUPPORTED,
                               "the stand has no disturbance: the output-error fit has no noise model (its residuals "
                               "are the model's misfit)");
        oe->pe->noise(disturbance_std, disturbance_se, noise_std, noise_se);
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_oe_predict(const vibid_oe *oe, size_t n_samples, const double *channels,
                                        double *innovations, double *innovation_cov) {
    return vibid::guard("vibid_oe_predict", [&]() {
        if (!oe || !channels || !innovations)
            vibid::throw_error(VIBID_E_NULL_ARGUMENT, "oe, channels and innovations are required");
        if (!oe->pe)
            vibid::throw_error(VIBID_E_UNSUPPORTED,
                               "the stand has no disturbance: its one-step prediction is the simulation (vibid_oe_simulate)");
        if (n_samples < 1) vibid::throw_error(VIBID_E_INSUFFICIENT_DATA, "no samples");
        vibid_oe copy(*oe);  // the predictor reuses the fit's data buffers: a const handle predicts on a copy
        copy.pe->predict(n_samples, channels, innovations, innovation_cov);
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_oe_simulate(const vibid_oe *oe, const double *theta, const double *x0,
                                         const double *offsets, size_t n_samples, const double *channels,
                                         double *out) {
    return vibid::guard("vibid_oe_simulate", [&]() {
        if (!oe || !theta || !channels || !out) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "oe, theta, channels and out are required");
        if (n_samples < 1) vibid::throw_error(VIBID_E_INSUFFICIENT_DATA, "no samples");
        // simulation reuses the fit's scratch: a const handle is simulated on a copy
        vibid_oe copy(*oe);
        if (copy.pe) copy.pe->simulate(theta, x0, offsets, n_samples, channels, out);
        else copy.oe->simulate(theta, x0, offsets, n_samples, channels, out);
        return VIBID_OK;
    });
}

}  // extern "C"
