// prediction_error.cpp: maximum-likelihood (prediction-error) estimation of a linear stand
// with disturbances from its steady-state Kalman predictor (vibid/output_error.h, "Stands
// with disturbances", documents the behaviour users see).
//
// The stand over one sample interval (disturbances are held white samples, model.h):
//   x_{k+1} = Phi x_k + G0 e_k + G1 e'_k + Gw w_k,   w_k ~ N(0, Sw), Sw = diag(sigma_w^2)
//   z_k     = Cm x_k + Dm e_k + Hm w_k + o + v_k,     v_k ~ N(0, R),  R = diag(sigma_v^2)
// x = [y; y'] (2n), e the measured inputs (r), e' their slopes (smooth inputs; 0 for held
// ones), [Phi G0 G1 Gw] the top rows of the exponential of the system augmented with e, e'
// and w (output_error.cpp's discretisation, the disturbances as held inputs). An
// accelerometer feels the disturbance on its node directly (Hm), so the process and
// measurement noises correlate: Gw Sw Hm'. The steady-state predictor in innovations form
//   xhat_{k+1} = Phi xhat_k + G0 e_k + G1 e'_k + K eps_k,   eps_k = z_k - Cm xhat_k - Dm e_k - o
//   S = Cm P Cm' + Hm Sw Hm' + R,   K = (Phi P Cm' + Gw Sw Hm') S^-1
// with P the stabilising solution of the filter's Riccati equation (structure-preserving
// doubling), gives the negative log-likelihood (up to a constant) of the counted samples
//   V = 1/2 sum_k (eps_k' S^-1 eps_k + log det S).
// Why not the EKF's estimate: the EKF treats the parameters as states and ignores how its
// gain depends on them, which biases the estimate where the gain matters (Ljung 1979);
// here the gain is a function of the parameters and its derivative is part of the gradient.
//
// Unknowns phi = [theta (p); log sigma of the unknown disturbances and channel noises (q);
// offsets (no)]. The innovations' sensitivities run along with the predictor:
//   d eps_k     = -(dCm xhat_k + Cm dxhat_k + dDm e_k)   (- 1 on its own channel for an offset)
//   dxhat_{k+1} = dPhi xhat_k + Phi dxhat_k + dG0 e_k + dG1 e'_k + dK eps_k + K d eps_k,
// exact given the derivatives of the predictor's matrices (Phi, G0, G1, Cm, Dm, K, S); those
// are central differences of the matrices (2 (p + q) exponentials and Riccati solutions of
// the state's size per iteration, relative step 1e-5: truncation error about 1e-10), not of
// runs over the record. Scoring (Fisher information) with Levenberg-Marquardt
// (gauss_newton.hpp); sandwich error bars over blocks of consecutive samples.
#include "prediction_error.hpp"

#include "api_guard.hpp"
#include "gauss_newton.hpp"
#include "model_internal.hpp"

#include <Eigen/Dense>
#include <unsupported/Eigen/MatrixFunctions>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

namespace vibid {
namespace {

using MatX = Eigen::MatrixXd;
using VecX = Eigen::VectorXd;
using Index = Eigen::Index;

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kRelStep = 1e-5;       // central-difference step of the predictor's matrices
constexpr double kLogSigmaBound = 100;  // |log sigma| (SI units) beyond which nothing is physical
constexpr Index kChunkRows = 256;       // information rows gathered before one rank update
constexpr int kDoublingSteps = 80;      // Riccati and Lyapunov doubling: 2^80 sample steps
constexpr double kBurnDecay = 7.0;      // predictor transients left out of the cost: e^-7 of the start error

struct Resp {
    long channel;
    Index node;
    int q;  // 0 displacement, 1 velocity, 2 acceleration
};

// The predictor's matrices at one phi.
struct Predictor {
    MatX Phi, G0, G1, Gw, Cm, Dm, Hm, K, S, L;  // L: lower Cholesky factor of S
    double logdet = 0.0;
};

struct Pass {
    double cost = 0.0;
    MatX H;       // np x np Fisher information
    VecX g;       // minus the gradient
    MatX scores;  // np x B block scores
};

// X = sum_k A^k Q A'^k by doubling; false when it does not settle (A not stable).
bool stationary_covariance(const MatX &A, const MatX &Q, MatX &X) {
    X = Q;
    MatX Ak = A;
    for (int it = 0; it < kDoublingSteps; ++it) {
        const MatX add = Ak * X * Ak.transpose();
        X += add;
        Ak = (Ak * Ak).eval();
        if (add.norm() <= 1e-15 * X.norm() && Ak.norm() < 1e-8) return X.allFinite();
    }
    return false;
}

}  // namespace

struct PredictionError::Impl {
    Impl(const vibid_model &m, const vibid_oe_config &config) : model(m), cfg(config), bounds(model) {
        require_finalized(&model);
        vibid_model_dims d{};
        if (vibid_model_get_dims(&model, &d) != VIBID_OK) throw_error(VIBID_E_STATE, "%s", vibid_last_error());
        n = static_cast<Index>(d.n_dof);
        r = static_cast<Index>(d.n_inputs);
        p = static_cast<Index>(d.n_params);
        nw = static_cast<Index>(model.disturbances.size());
        if (p == 0) throw_error(VIBID_E_OUT_OF_RANGE, "nothing unknown in the model");
        if (nw == 0) throw_error(VIBID_E_DIMENSION, "no disturbance: the prediction-error fit is for stands with one");
        if (model.nonlinear)
            throw_error(VIBID_E_UNSUPPORTED,
                        "a cubic spring and a disturbance: the prediction-error fit takes linear stands only (use the EKF)");
        if (model.has_base)
            throw_error(VIBID_E_UNSUPPORTED,
                        "an element touches the base and the stand has a disturbance: the prediction-error fit does not "
                        "take a base (use the EKF)");
        for (std::size_t i = 0; i < model.nodes.size(); ++i)
            for (int q = 0; q < 3; ++q) {
                const long c = model.node_channel[i][static_cast<std::size_t>(q)];
                if (c == kNoChannel) continue;
                resp.push_back(Resp{c, static_cast<Index>(i), q});
                channels.push_back(c);
                double sd = -1.0;
                vibid_model_get_noise(&model, i, 1u << q, &sd);
                chan_noise.push_back(sd);
            }
        ny = static_cast<Index>(resp.size());
        if (ny == 0) throw_error(VIBID_E_DIMENSION, "no measured response channel (displacement, velocity or acceleration of a node)");
        for (Index j = 0; j < r; ++j) {
            const long c = model.input_channel[static_cast<std::size_t>(j)];
            if (c == kNoChannel) throw_error(VIBID_E_DIMENSION, "a force input has no channel");
            in_ch.push_back(c);
            in_smooth.push_back(model.inputs[static_cast<std::size_t>(j)].hold != VIBID_HOLD_ZOH);
        }
        // the unknown noise intensities, in phi after theta: disturbances, then channels
        for (Index l = 0; l < nw; ++l)
            if (model.disturbances[static_cast<std::size_t>(l)].std_dev == 0.0) noise_of.push_back(l);
        for (Index j = 0; j < ny; ++j)
            if (chan_noise[static_cast<std::size_t>(j)] < 0.0) noise_of.push_back(nw + j);
        nq = static_cast<Index>(noise_of.size());
        nd = p + nq;
        no = cfg.offsets ? ny : 0;
        np = nd + no;
    }

    // -- the predictor ---------------------------------------------------------------

    double sigma_w(const VecX &phi, Index l) const {
        const double sd = model.disturbances[static_cast<std::size_t>(l)].std_dev;
        if (sd > 0.0) return sd;
        return std::exp(phi(p + noise_index(l)));
    }
    double sigma_v(const VecX &phi, Index j) const {
        const double sd = chan_noise[static_cast<std::size_t>(j)];
        if (sd >= 0.0) return sd;
        return std::exp(phi(p + noise_index(nw + j)));
    }
    Index noise_index(Index what) const {
        return static_cast<Index>(std::find(noise_of.begin(), noise_of.end(), what) - noise_of.begin());
    }

    // The discrete stand at phi (Phi, G0, G1, Gw, Cm, Dm, Hm); false for a singular mass
    // matrix or an exponential that overflows.
    bool discretise(const VecX &phi, Predictor &s) const {
        const Index nx = 2 * n, NA = nx + 2 * r + nw;
        MatX M(n, n), D(n, n), C(n, n), B(n, std::max<Index>(r, 1));
        VecX db(n), cb(n);
        if (vibid_model_assemble(&model, phi.data(), M.data(), D.data(), C.data(), r ? B.data() : nullptr, db.data(),
                                 cb.data()) != VIBID_OK)
            return false;
        Eigen::PartialPivLU<MatX> lu(M);
        if (!(std::fabs(lu.determinant()) > 0.0) || !std::isfinite(lu.determinant())) return false;
        const MatX Mi = lu.inverse();
        MatX F = MatX::Zero(NA, NA);
        F.block(0, n, n, n).setIdentity();
        F.block(n, 0, n, n) = -Mi * C;
        F.block(n, n, n, n) = -Mi * D;
        if (r) {
            F.block(n, nx, n, r) = Mi * B.leftCols(r);
            F.block(nx, nx + r, r, r).setIdentity();
        }
        for (Index l = 0; l < nw; ++l) F.block(n, nx + 2 * r + l, n, 1) = Mi.col(static_cast<Index>(model.disturbances[static_cast<std::size_t>(l)].node));
        const MatX Eh = (F * cfg.sample_time).exp();
        if (!Eh.allFinite()) return false;
        s.Phi = Eh.topLeftCorner(nx, nx);
        s.G0 = Eh.block(0, nx, nx, r);
        s.G1 = Eh.block(0, nx + r, nx, r);
        s.Gw = Eh.block(0, nx + 2 * r, nx, nw);
        s.Cm = MatX::Zero(ny, nx);
        s.Dm = MatX::Zero(ny, r);
        s.Hm = MatX::Zero(ny, nw);
        for (Index j = 0; j < ny; ++j) {
            const Resp &rs = resp[static_cast<std::size_t>(j)];
            if (rs.q < 2) {
                s.Cm(j, rs.q * n + rs.node) = 1.0;
                continue;
            }
            s.Cm.row(j) = F.block(n + rs.node, 0, 1, nx);
            s.Dm.row(j) = F.block(n + rs.node, nx, 1, r);
            s.Hm.row(j) = F.block(n + rs.node, nx + 2 * r, 1, nw);
        }
        return true;
    }

    // The predictor's matrices at phi; false where they do not exist (discretise fails, an
    // innovation covariance that is not positive definite, no stabilising Riccati solution).
    bool build(const VecX &phi, Predictor &s) const {
        if (!discretise(phi, s)) return false;
        const Index nx = 2 * n;
        VecX sw2(nw), sv2(ny);
        for (Index l = 0; l < nw; ++l) sw2(l) = std::pow(sigma_w(phi, l), 2);
        for (Index j = 0; j < ny; ++j) sv2(j) = std::pow(sigma_v(phi, j), 2);
        const MatX Q = s.Gw * sw2.asDiagonal() * s.Gw.transpose();
        const MatX Sx = s.Gw * sw2.asDiagonal() * s.Hm.transpose();
        MatX Rt = s.Hm * sw2.asDiagonal() * s.Hm.transpose();
        Rt.diagonal() += sv2;
        Eigen::LLT<MatX> rl(Rt);
        if (rl.info() != Eigen::Success) return false;
        // decorrelated: Abar = Phi - Sx Rt^-1 Cm, Qbar = Q - Sx Rt^-1 Sx'
        const MatX RiC = rl.solve(s.Cm), RiSx = rl.solve(Sx.transpose());
        // Structure-preserving doubling (Chu, Fan, Lin 2005) on the dual control form
        // X = A' X (I + G X)^-1 A + H with A = Abar', G = Cm' Rt^-1 Cm, H = Qbar.
        MatX A = (s.Phi - Sx * RiC).transpose();
        MatX G = s.Cm.transpose() * RiC;
        MatX Hh = Q - Sx * RiSx;
        G = 0.5 * (G + G.transpose()).eval();
        Hh = 0.5 * (Hh + Hh.transpose()).eval();
        const MatX I = MatX::Identity(nx, nx);
        bool settled = false;
        for (int it = 0; it < kDoublingSteps && !settled; ++it) {
            Eigen::PartialPivLU<MatX> w(I + G * Hh);
            const MatX WA = w.solve(A), WG = w.solve(G);
            const MatX Hn = Hh + A.transpose() * Hh * WA;
            const MatX Gn = G + A * WG * A.transpose();
            A = (A * WA).eval();
            const double change = (Hn - Hh).norm();
            Hh = 0.5 * (Hn + Hn.transpose());
            G = 0.5 * (Gn + Gn.transpose());
            settled = change <= 1e-14 * Hh.norm() || Hh.norm() == 0.0;
        }
        if (!settled || !Hh.allFinite()) return false;
        const MatX &P = Hh;
        s.S = s.Cm * P * s.Cm.transpose() + Rt;
        s.S = 0.5 * (s.S + s.S.transpose()).eval();
        Eigen::LLT<MatX> sl(s.S);
        if (sl.info() != Eigen::Success) return false;
        s.L = sl.matrixL();
        s.K = sl.solve((s.Phi * P * s.Cm.transpose() + Sx).transpose()).transpose();
        s.logdet = 2.0 * s.L.diagonal().array().log().sum();
        return s.K.allFinite() && std::isfinite(s.logdet);
    }

    // -- data ------------------------------------------------------------------------

    void load(std::size_t ns_in, const double *ch) {
        ns = static_cast<Index>(ns_in);
        E.resize(r, ns);
        Ed.resize(r, ns);
        Z.resize(ny, ns);
        finite.assign(ns_in, 1);
        for (Index j = 0; j < r; ++j) {
            const double *col = ch + static_cast<std::size_t>(in_ch[static_cast<std::size_t>(j)]) * ns_in;
            for (Index k = 0; k < ns; ++k) {
                if (!std::isfinite(col[k]))
                    throw_error(VIBID_E_NONFINITE, "input channel '%s', sample %ld: not finite (fit the parts on either side)",
                                model.channels[static_cast<std::size_t>(in_ch[static_cast<std::size_t>(j)])].name.c_str(),
                                static_cast<long>(k));
                E(j, k) = col[k];
            }
            for (Index k = 0; k < ns; ++k) {
                if (!in_smooth[static_cast<std::size_t>(j)]) Ed(j, k) = 0.0;
                else if (k + 1 < ns) Ed(j, k) = (E(j, k + 1) - E(j, k)) / cfg.sample_time;
                else Ed(j, k) = k > 0 ? Ed(j, k - 1) : 0.0;
            }
        }
        for (Index j = 0; j < ny; ++j) {
            const double *col = ch + static_cast<std::size_t>(resp[static_cast<std::size_t>(j)].channel) * ns_in;
            for (Index k = 0; k < ns; ++k) {
                Z(j, k) = col[k];
                if (!std::isfinite(col[k])) finite[static_cast<std::size_t>(k)] = 0;
            }
        }
    }

    // The deterministic response (inputs only) at theta from x0 (2n, may be null): out ny x ns.
    bool deterministic(const VecX &phi, const double *x0, MatX &out) const {
        Predictor s;
        if (!discretise(phi, s)) return false;
        VecX x = x0 ? VecX(Eigen::Map<const VecX>(x0, 2 * n)) : VecX::Zero(2 * n), xn(2 * n);
        out.resize(ny, ns);
        for (Index k = 0; k < ns; ++k) {
            out.col(k).noalias() = s.Cm * x;
            out.col(k).noalias() += s.Dm * E.col(k);
            xn.noalias() = s.Phi * x;
            xn.noalias() += s.G0 * E.col(k);
            xn.noalias() += s.G1 * Ed.col(k);
            x.swap(xn);
            if (!x.allFinite()) return false;
        }
        return true;
    }

    // -- one pass over the samples ---------------------------------------------------

    double step_of(const VecX &phi, Index i) const {
        if (i >= p) return kRelStep;  // log sigma
        const double typ = std::max({std::fabs(phi(i)), std::fabs(typical(i)), 1e-300});
        return kRelStep * typ;
    }

    double pass(const VecX &phi, bool with_sens, Pass &ps) const {
        Predictor s;
        if (!build(phi, s)) return kInf;
        const Index nx = 2 * n;
        // the matrices' derivatives, stacked parameter by parameter
        MatX dPhi, dG0, dG1, dK, dCm, dDm, dS, SidS;  // dS: dS_i side by side (ny x ny nd); SidS: S^-1 dS_i
        VecX trSidS;
        if (with_sens) {
            dPhi.resize(nx * nd, nx);
            dG0.resize(nx * nd, r);
            dG1.resize(nx * nd, r);
            dK.resize(nx * nd, ny);
            dCm.resize(ny * nd, nx);
            dDm.resize(ny * nd, r);
            dS.resize(ny, ny * nd);
            SidS.resize(ny, ny * nd);
            trSidS.resize(nd);
            Eigen::LLT<MatX> sl(s.S);
            for (Index i = 0; i < nd; ++i) {
                const double h = step_of(phi, i);
                VecX a = phi, b = phi;
                a(i) += h;
                b(i) -= h;
                Predictor sa, sb;
                if (!build(a, sa) || !build(b, sb)) return kInf;
                const double c = 1.0 / (2.0 * h);
                dPhi.middleRows(i * nx, nx) = (sa.Phi - sb.Phi) * c;
                dG0.middleRows(i * nx, nx) = (sa.G0 - sb.G0) * c;
                dG1.middleRows(i * nx, nx) = (sa.G1 - sb.G1) * c;
                dK.middleRows(i * nx, nx) = (sa.K - sb.K) * c;
                dCm.middleRows(i * ny, ny) = (sa.Cm - sb.Cm) * c;
                dDm.middleRows(i * ny, ny) = (sa.Dm - sb.Dm) * c;
                dS.middleCols(i * ny, ny) = (sa.S - sb.S) * c;
                SidS.middleCols(i * ny, ny) = sl.solve(dS.middleCols(i * ny, ny));
                trSidS(i) = SidS.middleCols(i * ny, ny).trace();
            }
            ps.H = MatX::Zero(np, np);
            ps.g = VecX::Zero(np);
            ps.scores = MatX::Zero(np, static_cast<Index>(n_blocks));
        }
        const auto Lv = s.L.triangularView<Eigen::Lower>();
        // every buffer sized here: nothing on the per-sample path below allocates
        VecX xh = VecX::Zero(nx), xn(nx), eps(ny), wr(ny), a(ny), dSa(with_sens ? ny * nd : 0);
        VecX stack(with_sens ? std::max(nx, ny) * nd : 0);
        MatX X = MatX::Zero(nx, with_sens ? np : 0), Xn(nx, with_sens ? np : 0), dE(ny, with_sens ? np : 0),
             Jr(ny, np);
        MatX J(kChunkRows, np);
        VecX rr(kChunkRows);
        Index nrow = 0;
        const Index counted = ns - burn;
        const Index block_len = n_blocks ? std::max<Index>(1, counted / static_cast<Index>(n_blocks)) : 1;
        Index block = 0;
        auto flush = [&]() {
            if (!nrow) return;
            auto Jb = J.topRows(nrow);
            ps.H.selfadjointView<Eigen::Lower>().rankUpdate(Jb.transpose());
            const VecX gb = Jb.transpose() * rr.head(nrow);
            ps.g += gb;
            ps.scores.col(block) += gb;
            nrow = 0;
        };
        double quad = 0.0;
        Index used = 0;
        for (Index k = 0; k < ns; ++k) {
            const bool ok = finite[static_cast<std::size_t>(k)] != 0;
            const auto e = E.col(k), ed = Ed.col(k);
            if (ok) {
                eps = Z.col(k);
                eps.noalias() -= s.Cm * xh;
                if (r) eps.noalias() -= s.Dm * e;
                if (no) eps -= phi.tail(no);
            } else {
                eps.setZero();
            }
            if (with_sens) {
                if (ok) {
                    dE.noalias() = -s.Cm * X;
                    auto sy = stack.head(ny * nd);
                    sy.noalias() = dCm * xh;
                    if (r) sy.noalias() += dDm * e;
                    dE.leftCols(nd) -= Eigen::Map<const MatX>(sy.data(), ny, nd);
                    for (Index j = 0; j < no; ++j) dE(j, nd + j) -= 1.0;
                } else {
                    dE.setZero();
                }
            }
            const bool count = ok && k >= burn;
            if (count) {
                wr = eps;
                Lv.solveInPlace(wr);
                quad += wr.squaredNorm();
                ++used;
                if (with_sens) {
                    if (static_cast<Index>(block) < static_cast<Index>(n_blocks) - 1 && (k - burn) >= (block + 1) * block_len) {
                        flush();
                        ++block;
                    }
                    Jr = dE;
                    Lv.solveInPlace(Jr);  // L^-1 d eps: the residual sensitivity is its negative
                    for (Index j = 0; j < ny; ++j) {
                        J.row(nrow) = -Jr.row(j);
                        rr(nrow) = wr(j);
                        if (++nrow == kChunkRows) flush();
                    }
                    // the covariance's part of the score: 1/2 (a' dS_i a - tr S^-1 dS_i), a = S^-1 eps
                    a = wr;
                    s.L.transpose().triangularView<Eigen::Upper>().solveInPlace(a);
                    dSa.noalias() = dS.transpose() * a;  // block i: dS_i a (dS_i symmetric)
                    for (Index i = 0; i < nd; ++i) {
                        const double q = a.dot(dSa.segment(i * ny, ny));
                        const double si = 0.5 * (q - trSidS(i));
                        ps.g(i) += si;
                        ps.scores(i, block) += si;
                    }
                }
            }
            // advance
            xn.noalias() = s.Phi * xh;
            if (r) {
                xn.noalias() += s.G0 * e;
                xn.noalias() += s.G1 * ed;
            }
            if (ok) xn.noalias() += s.K * eps;
            if (with_sens) {
                Xn.noalias() = s.Phi * X;
                if (ok) Xn.noalias() += s.K * dE;
                auto sx = stack.head(nx * nd);
                sx.noalias() = dPhi * xh;
                if (r) {
                    sx.noalias() += dG0 * e;
                    sx.noalias() += dG1 * ed;
                }
                if (ok) sx.noalias() += dK * eps;
                Xn.leftCols(nd) += Eigen::Map<const MatX>(sx.data(), nx, nd);
                X.swap(Xn);
            }
            xh.swap(xn);
            if (!xh.allFinite()) return kInf;
        }
        if (used == 0) return kInf;
        if (with_sens) {
            flush();
            ps.H.triangularView<Eigen::StrictlyUpper>() = ps.H.transpose();
            // the covariance's part of the information: N/2 tr(S^-1 dS_i S^-1 dS_j)
            for (Index i = 0; i < nd; ++i)
                for (Index j = 0; j <= i; ++j) {
                    const double t = 0.5 * static_cast<double>(used) *
                                     (SidS.middleCols(i * ny, ny) * SidS.middleCols(j * ny, ny)).trace();
                    ps.H(i, j) += t;
                    if (i != j) ps.H(j, i) += t;
                }
        }
        ps.cost = 0.5 * (quad + static_cast<double>(used) * s.logdet);
        return ps.cost;
    }

    void project(VecX &phi) const {
        bounds.project(phi, start);
        for (Index i = p; i < nd; ++i) phi(i) = std::min(std::max(phi(i), -kLogSigmaBound), kLogSigmaBound);
    }

    double typical(Index i) const { return i < start.size() ? start(i) : 1.0; }

    // -- the fit -----------------------------------------------------------------------

    using Fit = FitState;

    // Start values of the noise intensities and offsets for theta: the residual of the
    // deterministic response (inputs only) is what the disturbances and the sensor noise
    // must explain. Unknown sensor noise starts at a tenth of its channel's residual; the
    // unknown disturbances share one scale that matches the residuals' variances to the
    // model's stationary response to them (weighted by 1 / variance: channels in different
    // units count alike); offsets start at the residual means.
    bool start_phi(const VecX &theta, VecX &phi) const {
        phi = VecX::Zero(np);
        phi.head(p) = theta;
        for (Index i = p; i < nd; ++i) phi(i) = 0.0;
        MatX det;
        if (!deterministic(phi, nullptr, det)) return false;
        VecX mean = VecX::Zero(ny), var = VecX::Zero(ny);
        Index cnt = 0;
        for (Index k = 0; k < ns; ++k) {
            if (!finite[static_cast<std::size_t>(k)]) continue;
            mean += Z.col(k) - det.col(k);
            ++cnt;
        }
        if (cnt < 2) return false;
        mean /= static_cast<double>(cnt);
        for (Index k = 0; k < ns; ++k)
            if (finite[static_cast<std::size_t>(k)]) var += (Z.col(k) - det.col(k) - mean).cwiseAbs2();
        var /= static_cast<double>(cnt - 1);
        for (Index j = 0; j < ny; ++j)
            if (!(var(j) > 0.0)) var(j) = 1e-30;
        if (no) phi.tail(no) = mean;
        VecX sv0(ny);
        for (Index j = 0; j < ny; ++j) {
            const double declared = chan_noise[static_cast<std::size_t>(j)];
            sv0(j) = declared >= 0.0 ? declared : 0.1 * std::sqrt(var(j));
            if (declared < 0.0) phi(p + noise_index(nw + j)) = std::log(sv0(j));
        }
        Predictor s;
        if (!build(phi, s)) return false;
        VecX unit_w = VecX::Zero(nw), known_w = VecX::Zero(nw);
        for (Index l = 0; l < nw; ++l) {
            const double sd = model.disturbances[static_cast<std::size_t>(l)].std_dev;
            (sd > 0.0 ? known_w(l) : unit_w(l)) = sd > 0.0 ? sd * sd : 1.0;
        }
        auto out_var = [&](const VecX &w2, VecX &y) {
            MatX X;
            if (!stationary_covariance(s.Phi, s.Gw * w2.asDiagonal() * s.Gw.transpose(), X)) return false;
            y = (s.Cm * X * s.Cm.transpose() + s.Hm * w2.asDiagonal() * s.Hm.transpose()).diagonal();
            return true;
        };
        VecX yu, yk;
        if (unit_w.sum() > 0.0) {
            if (!out_var(unit_w, yu) || !out_var(known_w, yk)) return false;
            double num = 0.0, den = 0.0;
            for (Index j = 0; j < ny; ++j) {
                num += std::max(var(j) - yk(j) - sv0(j) * sv0(j), 0.0) / var(j);
                den += yu(j) / var(j);
            }
            const double s2 = num > 0.0 && den > 0.0 ? num / den : 1.0;
            for (Index l = 0; l < nw; ++l)
                if (unit_w(l) > 0.0) phi(p + noise_index(l)) = 0.5 * std::log(s2);
        }
        project(phi);
        return phi.allFinite();
    }

    // Samples the predictor's start-up transient spans: kBurnDecay time constants of its
    // slowest pole at the start values (at most a tenth of the record).
    void choose_burn(const VecX &phi) {
        burn = 0;
        Predictor s;
        if (!build(phi, s)) return;
        const MatX Acl = s.Phi - s.K * s.Cm;
        Eigen::EigenSolver<MatX> es(Acl, false);
        double rho = 0.0;
        for (Index i = 0; i < Acl.rows(); ++i) rho = std::max(rho, std::abs(es.eigenvalues()(i)));
        const Index cap = ns / 10;
        burn = rho < 1.0 && rho > 0.0 ? std::min<Index>(cap, static_cast<Index>(std::ceil(kBurnDecay / -std::log(rho))))
                                      : cap;
    }

    Fit fit_from(const VecX &theta, std::size_t which) {
        Fit f;
        f.start = which;
        start = theta;
        if (!start_phi(theta, f.phi)) return f;
        Pass cur;
        f.cost = pass(f.phi, true, cur);
        if (!std::isfinite(f.cost)) return f;
        const LmOutcome lm = levenberg_marquardt(
            f.phi, f.cost, cur, cfg.max_iterations,
            [this](const VecX &phi, bool with_sens, Pass &ps) { return pass(phi, with_sens, ps); },
            [this](VecX &phi) { project(phi); });
        f.iterations = lm.iterations;
        if (!lm.converged) f.failure |= VIBID_OE_NO_CONVERGENCE;
        return f;
    }

    std::string phi_name(Index i) const {
        if (i < p) return bounds.names[static_cast<std::size_t>(i)];
        if (i < nd) {
            const Index what = noise_of[static_cast<std::size_t>(i - p)];
            if (what < nw) return "intensity of " + model.disturbances[static_cast<std::size_t>(what)].name;
            return "noise of " + model.channels[static_cast<std::size_t>(channels[static_cast<std::size_t>(what - nw)])].name;
        }
        return "offset of " + model.channels[static_cast<std::size_t>(channels[static_cast<std::size_t>(i - nd)])].name;
    }

    void finish(Fit &f) {
        Pass ps;
        f.cost = pass(f.phi, true, ps);
        const Sandwich sw = sandwich(ps.H, ps.scores);
        f.rcond = sw.rcond;
        f.cov = sw.cov;
        f.weak.clear();
        if (sw.singular) {
            // a sensor noise far below what the disturbances put on its channel is not
            // determined and need not be: only the physical unknowns and offsets count
            bool physical = false;
            for (Index i = 0; i < np; ++i)
                if (std::fabs(sw.weakest(i)) > 0.3) {
                    f.weak += (f.weak.empty() ? "'" : ", '") + phi_name(i) + "'";
                    physical = physical || i < p || i >= nd;
                }
            if (physical) f.failure |= VIBID_OE_SINGULAR;
        }
        const std::string bound = bounds.at_bound(f.phi, start);
        if (!bound.empty()) {
            f.failure |= VIBID_OE_BOUND;
            if (!(f.failure & VIBID_OE_SINGULAR)) f.weak = bound;
        }
    }

    vibid_status fit(std::size_t ns_in, const double *ch, std::size_t n_starts, const double *starts) {
        load(ns_in, ch);
        have = false;
        best = Fit{};
        for (std::size_t s = 0; s < n_starts; ++s) {
            VecX theta = Eigen::Map<const VecX>(starts + s * static_cast<std::size_t>(p), p);
            for (Index i = 0; i < p; ++i)
                if (!std::isfinite(theta(i)))
                    throw_error(VIBID_E_NONFINITE, "start %zu: '%s' is not finite", s, bounds.names[static_cast<std::size_t>(i)].c_str());
            if (s == 0) {
                // the transient left out and the blocks: fixed for the whole fit (the cost must
                // compare like with like), from the first start
                VecX phi0;
                start = theta;
                if (start_phi(theta, phi0)) choose_burn(phi0);
                else burn = ns / 10;
                const std::size_t counted = static_cast<std::size_t>(ns - burn);
                n_blocks = cfg.n_blocks ? std::min<std::size_t>(cfg.n_blocks, counted / 50)
                                        : std::min<std::size_t>(32, counted / 50);
                if (n_blocks < 8)
                    throw_error(VIBID_E_INSUFFICIENT_DATA,
                                "%zu samples (%ld after the predictor's start-up): at least 8 blocks of 50 samples are "
                                "needed for error bars",
                                ns_in, static_cast<long>(counted));
            }
            Fit f = fit_from(theta, s);
            if (f.cost < best.cost || s == 0) best = f;
        }
        have = true;
        if (!std::isfinite(best.cost)) {
            best.failure |= VIBID_OE_UNSTABLE;
            throw_error(VIBID_E_NUMERICAL, "no stable predictor from any start (%zu)", n_starts);
        }
        start = Eigen::Map<const VecX>(starts + best.start * static_cast<std::size_t>(p), p);
        finish(best);
        if (best.failure & VIBID_OE_SINGULAR)
            throw_error(VIBID_E_NUMERICAL, "the information matrix is singular (rcond %.3g): %s not determined by the data",
                        best.rcond, best.weak.c_str());
        if (best.failure & VIBID_OE_BOUND) throw_error(VIBID_E_DIVERGED, "%s on its physical bound", best.weak.c_str());
        if (best.failure & VIBID_OE_NO_CONVERGENCE)
            throw_error(VIBID_E_DIVERGED, "no convergence in %u iterations", cfg.max_iterations);
        return VIBID_OK;
    }

    double se_of(Index i) const {
        return best.cov.size() ? std::sqrt(std::max(0.0, best.cov(i, i))) : std::nan("");
    }

    vibid_model model;
    vibid_oe_config cfg;
    Index n = 0, r = 0, p = 0, nw = 0, ny = 0, nq = 0, nd = 0, no = 0, np = 0, ns = 0, burn = 0;
    std::vector<Resp> resp;
    std::vector<long> channels, in_ch;
    std::vector<bool> in_smooth;
    std::vector<double> chan_noise;    // declared sensor noise std per response channel, < 0 unknown
    std::vector<Index> noise_of;       // phi(p + i) is log sigma of: disturbance l (< nw) or channel nw + j
    PhysicalBounds bounds;
    VecX start;
    MatX E, Ed, Z;
    std::vector<char> finite;          // per sample: every response channel finite
    std::size_t n_blocks = 0;
    Fit best;
    bool have = false;
};

PredictionError::PredictionError(const vibid_model &model, const vibid_oe_config &cfg)
    : impl_(std::make_unique<Impl>(model, cfg)) {}
PredictionError::PredictionError(const PredictionError &other) : impl_(std::make_unique<Impl>(*other.impl_)) {}
PredictionError::~PredictionError() = default;

const std::vector<long> &PredictionError::response_channels() const { return impl_->channels; }
std::size_t PredictionError::n_params() const { return static_cast<std::size_t>(impl_->p); }

vibid_status PredictionError::fit(std::size_t n_samples, const double *channels, std::size_t n_starts,
                                  const double *starts) {
    return impl_->fit(n_samples, channels, n_starts, starts);
}

void PredictionError::result(double *theta, double *se, double *cov, double *offsets, double *offsets_se, double *x0,
                             vibid_oe_fit_info *info) const {
    const Impl &m = *impl_;
    if (!m.have) throw_error(VIBID_E_STATE, "no fit yet");
    const auto &f = m.best;
    const Index p = m.p;
    const bool have_cov = f.cov.size() > 0;
    if (theta) Eigen::Map<VecX>(theta, p) = f.phi.head(p);
    if (se)
        for (Index i = 0; i < p; ++i) se[i] = m.se_of(i);
    if (cov) {
        if (have_cov) Eigen::Map<MatX>(cov, p, p) = f.cov.topLeftCorner(p, p);
        else Eigen::Map<MatX>(cov, p, p).setConstant(std::nan(""));
    }
    for (Index j = 0; j < m.ny; ++j) {
        if (offsets) offsets[j] = m.no ? f.phi(m.nd + j) : 0.0;
        if (offsets_se) offsets_se[j] = m.no ? m.se_of(m.nd + j) : 0.0;
    }
    if (x0) Eigen::Map<VecX>(x0, 2 * m.n).setZero();
    if (info) {
        *info = vibid_oe_fit_info{};
        info->failure = f.failure;
        info->iterations = f.iterations;
        info->start = f.start;
        info->n_samples = static_cast<std::size_t>(m.ns);
        info->n_response = static_cast<std::size_t>(m.ny);
        info->n_blocks = m.n_blocks;
        info->cost = f.cost;
        info->rcond = f.rcond;
    }
}

void PredictionError::simulate(const double *theta, const double *x0, const double *offsets, std::size_t n_samples,
                               const double *channels, double *out) {
    Impl &m = *impl_;
    m.load(n_samples, channels);
    VecX phi = VecX::Zero(m.np);
    phi.head(m.p) = Eigen::Map<const VecX>(theta, m.p);
    MatX y;
    if (!m.deterministic(phi, x0, y)) throw_error(VIBID_E_NUMERICAL, "the simulation diverged");
    for (Index j = 0; j < m.ny; ++j)
        for (Index k = 0; k < m.ns; ++k)
            out[static_cast<std::size_t>(k + j * m.ns)] = y(j, k) + (offsets ? offsets[j] : 0.0);
}

void PredictionError::predict(std::size_t n_samples, const double *channels, double *innovations,
                              double *innovation_cov) {
    Impl &m = *impl_;
    if (!m.have) throw_error(VIBID_E_STATE, "no fit yet");
    m.load(n_samples, channels);
    Predictor s;
    if (!m.build(m.best.phi, s)) throw_error(VIBID_E_NUMERICAL, "the fitted predictor does not exist");
    VecX xh = VecX::Zero(2 * m.n), xn(2 * m.n), eps(m.ny);
    for (Index k = 0; k < m.ns; ++k) {
        const bool ok = m.finite[static_cast<std::size_t>(k)] != 0;
        const auto e = m.E.col(k), ed = m.Ed.col(k);
        if (ok) {
            eps = m.Z.col(k);
            eps.noalias() -= s.Cm * xh;
            if (m.r) eps.noalias() -= s.Dm * e;
            if (m.no) eps -= m.best.phi.tail(m.no);
        } else {
            eps.setZero();
        }
        for (Index j = 0; j < m.ny; ++j)
            innovations[static_cast<std::size_t>(k + j * m.ns)] = ok ? eps(j) : std::nan("");
        xn.noalias() = s.Phi * xh;
        xn.noalias() += s.K * eps;
        if (m.r) {
            xn.noalias() += s.G0 * e;
            xn.noalias() += s.G1 * ed;
        }
        xh.swap(xn);
        if (!xh.allFinite()) throw_error(VIBID_E_NUMERICAL, "the predictor diverged at sample %ld", static_cast<long>(k));
    }
    if (innovation_cov) Eigen::Map<MatX>(innovation_cov, m.ny, m.ny) = s.S;
}

void PredictionError::noise(double *dist_std, double *dist_se, double *chan_std, double *chan_se) const {
    const Impl &m = *impl_;
    if (!m.have) throw_error(VIBID_E_STATE, "no fit yet");
    for (Index l = 0; l < m.nw; ++l) {
        const double sd = m.sigma_w(m.best.phi, l);
        if (dist_std) dist_std[l] = sd;
        if (dist_se)
            dist_se[l] = m.model.disturbances[static_cast<std::size_t>(l)].std_dev > 0.0 ? 0.0 : sd * m.se_of(m.p + m.noise_index(l));
    }
    for (Index j = 0; j < m.ny; ++j) {
        const double sd = m.sigma_v(m.best.phi, j);
        if (chan_std) chan_std[j] = sd;
        if (chan_se)
            chan_se[j] = m.chan_noise[static_cast<std::size_t>(j)] >= 0.0 ? 0.0 : sd * m.se_of(m.p + m.noise_index(m.nw + j));
    }
}

}  // namespace vibid
