// modal.cpp: natural frequencies, damping ratios and mode shapes from M, D, C (the
// quadratic eigenvalue problem, solved through the state matrix of (1.6)), and their
// standard errors propagated from a parameter covariance.
#include <vibid/modal.h>

#include "api_guard.hpp"
#include "model_internal.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <complex>
#include <vector>

using Eigen::MatrixXd;
using vibid::throw_error;

namespace {

struct Mode {
    double freq_hz;
    double zeta;
    Eigen::VectorXcd shape;
    // the eigenvalue(s) of the state matrix behind the mode: root (Im > 0) of an oscillating
    // pair, or the two real roots of an overdamped / rigid-body pair (pair = -1 otherwise)
    Eigen::Index root = -1, pair = -1;
};

// The state matrix of (1.6), A = [0 I; -M^-1 C  -M^-1 D] (2n x 2n).
MatrixXd state_matrix(const MatrixXd &M, const MatrixXd &D, const MatrixXd &C) {
    const Eigen::Index n = M.rows();
    Eigen::FullPivLU<MatrixXd> lu(M);
    if (!lu.isInvertible()) throw_error(VIBID_E_NUMERICAL, "mass matrix is singular");
    MatrixXd A = MatrixXd::Zero(2 * n, 2 * n);
    A.topRightCorner(n, n).setIdentity();
    A.bottomLeftCorner(n, n) = -lu.solve(C);
    A.bottomRightCorner(n, n) = -lu.solve(D);
    return A;
}

// shapes = false skips the eigenvectors (Mode::shape stays empty): the perturbed solves of
// the standard-error propagation need only the eigenvalues, at about half the cost.
// growth (may be null): the largest eigenvalue real part above 1e-12 of the state
// matrix's norm (an unstable model), 0 when there is none.
// es (may be null): the eigen decomposition of the state matrix, for the caller (computed
// with eigenvectors then, whatever shapes says).
std::vector<Mode> modes_of(const MatrixXd &M, const MatrixXd &D, const MatrixXd &C, bool shapes = true,
                           double *growth = nullptr, Eigen::EigenSolver<MatrixXd> *es_out = nullptr) {
    const Eigen::Index n = M.rows();
    const MatrixXd A = state_matrix(M, D, C);
    Eigen::EigenSolver<MatrixXd> es_local;
    Eigen::EigenSolver<MatrixXd> &es = es_out ? *es_out : es_local;
    es.compute(A, shapes || es_out);
    if (es.info() != Eigen::Success) throw_error(VIBID_E_NUMERICAL, "eigen solver did not converge");
    std::vector<Mode> modes;
    std::vector<std::pair<double, Eigen::Index>> real_roots;
    const double scale = std::max(A.norm(), 1e-300);
    if (growth) *growth = 0.0;
    for (Eigen::Index i = 0; i < 2 * n; ++i) {
        const std::complex<double> l = es.eigenvalues()(i);
        // A rigid-body root is 0 up to rounding: only a clearly positive part is growth.
        if (growth && l.real() > 1e-12 * scale) *growth = std::max(*growth, l.real());
        if (std::fabs(l.imag()) > 1e-12 * scale) {
            if (l.imag() < 0) continue;  // the conjugate describes the same mode
            const double w = std::abs(l);
            modes.push_back(Mode{w / (2.0 * M_PI), -l.real() / w,
                                 shapes ? Eigen::VectorXcd(es.eigenvectors().col(i).head(n)) : Eigen::VectorXcd(), i,
                                 -1});
        } else {
            real_roots.emplace_back(l.real(), i);
        }
    }
    // Overdamped (or rigid-body) modes: pair the real roots in ascending order.
    std::sort(real_roots.begin(), real_roots.end());
    for (std::size_t k = 0; k + 1 < real_roots.size(); k += 2) {
        const double l1 = real_roots[k].first, l2 = real_roots[k + 1].first;
        const double prod = l1 * l2;
        Mode md;
        if (prod > 0.0) {
            const double w = std::sqrt(prod);
            md.freq_hz = w / (2.0 * M_PI);
            md.zeta = -(l1 + l2) / (2.0 * w);
        } else {
            md.freq_hz = 0.0;  // a zero root: rigid-body motion
            md.zeta = 1.0;
        }
        if (shapes) md.shape = es.eigenvectors().col(real_roots[k + 1].second).head(n);
        md.root = real_roots[k].second;
        md.pair = real_roots[k + 1].second;
        modes.push_back(md);
    }
    if (static_cast<Eigen::Index>(modes.size()) != n)
        throw_error(VIBID_E_NUMERICAL, "could not pair the %ld eigenvalues into %ld modes", static_cast<long>(2 * n),
                    static_cast<long>(n));
    for (auto &md : modes) {
        if (!shapes) break;
        Eigen::Index imax = 0;
        md.shape.cwiseAbs().maxCoeff(&imax);
        const std::complex<double> pivot = md.shape(imax);
        if (std::abs(pivot) > 0) md.shape /= pivot;
        md.shape(imax) = 1.0;
    }
    std::sort(modes.begin(), modes.end(), [](const Mode &a, const Mode &b) { return a.freq_hz < b.freq_hz; });
    return modes;
}

void write_modes(const std::vector<Mode> &modes, std::size_t n, double *freq_hz, double *zeta, double *shape_re,
                 double *shape_im) {
    for (std::size_t j = 0; j < n; ++j) {
        if (freq_hz) freq_hz[j] = modes[j].freq_hz;
        if (zeta) zeta[j] = modes[j].zeta;
        for (std::size_t i = 0; i < n; ++i) {
            if (shape_re) shape_re[i + j * n] = modes[j].shape(static_cast<Eigen::Index>(i)).real();
            if (shape_im) shape_im[i + j * n] = modes[j].shape(static_cast<Eigen::Index>(i)).imag();
        }
    }
}

void assemble(const vibid_model *model, const double *theta, MatrixXd &M, MatrixXd &D, MatrixXd &C) {
    const Eigen::Index n = static_cast<Eigen::Index>(model->nodes.size());
    M.resize(n, n);
    D.resize(n, n);
    C.resize(n, n);
    if (vibid_model_assemble(model, theta, M.data(), D.data(), C.data(), nullptr, nullptr, nullptr) != VIBID_OK)
        throw_error(VIBID_E_NUMERICAL, "assembling the model failed: %s", vibid_last_error());
}

std::vector<Mode> model_modes(const vibid_model *model, const double *theta, bool shapes = true,
                              double *growth = nullptr, Eigen::EigenSolver<MatrixXd> *es = nullptr) {
    MatrixXd M, D, C;
    assemble(model, theta, M, D, C);
    return modes_of(M, D, C, shapes, growth, es);
}

// The sensitivities of every mode's frequency (rows 0..n-1) and damping ratio (rows
// n..2n-1) to the parameters (p columns) by eigenvalue perturbation: for a simple eigenvalue
// l of the state matrix A with right eigenvector v and left eigenvector w (w^H = the row of
// V^-1), dl = w^H dA v (w^H v = 1 with W^H = V^-1). dA/dtheta_i comes from central
// differences of the assembled M, D, C (exact up to rounding where they are linear in theta,
// as stiffness and damping terms are). One eigen decomposition instead of 2p + 1: this runs
// for every track row. false when V is too ill-conditioned for it (a defective or nearly
// repeated eigenvalue, where the perturbation is not first order): the caller then
// differentiates the eigenvalues numerically.
bool modal_jacobian(const vibid_model *model, const std::vector<double> &th, const std::vector<Mode> &modes,
                    const Eigen::EigenSolver<MatrixXd> &es, MatrixXd &J) {
    const std::size_t n = model->nodes.size(), p = th.size();
    const Eigen::MatrixXcd V = es.eigenvectors();
    Eigen::PartialPivLU<Eigen::MatrixXcd> lu(V);
    // rcond of V: below 1e-10 the eigenvector basis is nearly singular and first-order
    // perturbation loses more digits than the numerical difference would
    if (!(lu.rcond() > 1e-10)) return false;
    const Eigen::MatrixXcd W = lu.inverse();  // row i: w_i^H
    const Eigen::VectorXcd lam = es.eigenvalues();
    J.setZero(static_cast<Eigen::Index>(2 * n), static_cast<Eigen::Index>(p));
    std::vector<double> tp = th, tm = th;
    MatrixXd M, D, C;
    for (std::size_t i = 0; i < p; ++i) {
        const double step = 1e-6 * std::max(std::fabs(th[i]), 1e-12);
        tp[i] = th[i] + step;
        tm[i] = th[i] - step;
        assemble(model, tp.data(), M, D, C);
        MatrixXd dA = state_matrix(M, D, C);
        assemble(model, tm.data(), M, D, C);
        dA -= state_matrix(M, D, C);
        dA /= 2.0 * step;
        tp[i] = tm[i] = th[i];
        const Eigen::MatrixXcd dAV = dA.cast<std::complex<double>>() * V;
        // dl_r = w_r^H dA v_r = sum_k W(r, k) (dA V)(k, r)
        auto dl = [&](Eigen::Index r) { return W.row(r).transpose().cwiseProduct(dAV.col(r)).sum(); };
        for (std::size_t j = 0; j < n; ++j) {
            const Mode &md = modes[j];
            double df = 0.0, dz = 0.0;
            if (md.pair < 0) {
                // f = |l| / 2 pi, zeta = -Re l / |l|
                const std::complex<double> l = lam(md.root), d = dl(md.root);
                const double w = std::abs(l), dw = (l.real() * d.real() + l.imag() * d.imag()) / w;
                df = dw / (2.0 * M_PI);
                dz = -d.real() / w + l.real() * dw / (w * w);
            } else {
                // f = sqrt(l1 l2) / 2 pi, zeta = -(l1 + l2) / (2 sqrt(l1 l2)); f = 0, zeta = 1
                // (rigid body) does not move to first order
                const double l1 = lam(md.root).real(), l2 = lam(md.pair).real();
                if (l1 * l2 > 0.0) {
                    const double d1 = dl(md.root).real(), d2 = dl(md.pair).real();
                    const double w = std::sqrt(l1 * l2), dw = (l2 * d1 + l1 * d2) / (2.0 * w);
                    df = dw / (2.0 * M_PI);
                    dz = -(d1 + d2) / (2.0 * w) + (l1 + l2) * dw / (2.0 * w * w);
                }
            }
            J(static_cast<Eigen::Index>(j), static_cast<Eigen::Index>(i)) = df;
            J(static_cast<Eigen::Index>(n + j), static_cast<Eigen::Index>(i)) = dz;
        }
    }
    return true;
}

// The status of an unstable model, for the API function `fn`: its outputs are written all
// the same.
vibid_status unstable(const char *fn, double growth) {
    vibid::set_last_error(fn,
                      "the model is unstable: an eigenvalue has real part %g 1/s > 0 (negative damping gives "
                      "zeta < 0; a negative stiffness a non-oscillating divergent pair, reported as f = 0, "
                      "zeta = 1)",
                      growth);
    return VIBID_E_UNSTABLE;
}

}  // namespace

extern "C" {

VIBID_API vibid_status vibid_modal(size_t n, const double *M, const double *D, const double *C, double *freq_hz,
                                   double *zeta, double *shape_re, double *shape_im) {
    VIBID_GUARD(
        if (n < 1 || n > 512) throw_error(VIBID_E_DIMENSION, "n = %zu outside 1..512", n);
        if (!M || !C || !freq_hz || !zeta) throw_error(VIBID_E_NULL_ARGUMENT, "M, C, freq_hz and zeta are required");
        if (!vibid::all_finite(M, n * n) || !vibid::all_finite(C, n * n) || (D && !vibid::all_finite(D, n * n)))
            throw_error(VIBID_E_NONFINITE, "matrix with NaN or Inf");
        const Eigen::Index N = static_cast<Eigen::Index>(n);
        MatrixXd Dm = D ? MatrixXd(Eigen::Map<const MatrixXd>(D, N, N)) : MatrixXd::Zero(N, N);
        double growth = 0.0;
        auto modes = modes_of(Eigen::Map<const MatrixXd>(M, N, N), Dm, Eigen::Map<const MatrixXd>(C, N, N),
                              shape_re || shape_im, &growth);
        write_modes(modes, n, freq_hz, zeta, shape_re, shape_im);
        return growth > 0.0 ? unstable("vibid_modal", growth) : VIBID_OK;);
}

VIBID_API vibid_status vibid_model_modal(const vibid_model *model, const double *theta, const double *cov,
                                         double *freq_hz, double *freq_se, double *zeta, double *zeta_se,
                                         double *shape_re, double *shape_im) {
    VIBID_GUARD(
        vibid::require_finalized(model);
        if (!freq_hz || !zeta) throw_error(VIBID_E_NULL_ARGUMENT, "freq_hz and zeta are required");
        const std::size_t n = model->nodes.size(), p = model->param_term.size();
        std::vector<double> th(p);
        if (theta)
            std::copy(theta, theta + p, th.begin());
        else
            vibid_model_nominal(model, th.data());
        if (!vibid::all_finite(th.data(), p)) throw_error(VIBID_E_NONFINITE, "theta has NaN or Inf");
        double growth = 0.0;
        const bool se_wanted = cov && (freq_se || zeta_se);
        Eigen::EigenSolver<MatrixXd> es;
        const auto modes = model_modes(model, th.data(), shape_re || shape_im, &growth, se_wanted ? &es : nullptr);
        write_modes(modes, n, freq_hz, zeta, shape_re, shape_im);
        if (se_wanted) {
            if (!vibid::all_finite(cov, p * p)) throw_error(VIBID_E_NONFINITE, "cov has NaN or Inf");
            // First-order propagation: se^2 = diag(J cov J^T), J (2n x p) by eigenvalue
            // perturbation, or by central differences of the eigenvalues where that fails.
            MatrixXd J(2 * n, p);
            if (!modal_jacobian(model, th, modes, es, J)) {
                for (std::size_t i = 0; i < p; ++i) {
                    const double step = 1e-6 * std::max(std::fabs(th[i]), 1e-12);
                    std::vector<double> tp = th, tm = th;
                    tp[i] += step;
                    tm[i] -= step;
                    const auto mp = model_modes(model, tp.data(), false), mm = model_modes(model, tm.data(), false);
                    for (std::size_t j = 0; j < n; ++j) {
                        J(static_cast<Eigen::Index>(j), static_cast<Eigen::Index>(i)) =
                            (mp[j].freq_hz - mm[j].freq_hz) / (2 * step);
                        J(static_cast<Eigen::Index>(n + j), static_cast<Eigen::Index>(i)) =
                            (mp[j].zeta - mm[j].zeta) / (2 * step);
                    }
                }
            }
            const Eigen::Index P = static_cast<Eigen::Index>(p);
            const MatrixXd V = J * Eigen::Map<const MatrixXd>(cov, P, P) * J.transpose();
            for (std::size_t j = 0; j < n; ++j) {
                const Eigen::Index a = static_cast<Eigen::Index>(j), b = static_cast<Eigen::Index>(n + j);
                if (freq_se) freq_se[j] = std::sqrt(std::max(V(a, a), 0.0));
                if (zeta_se) zeta_se[j] = std::sqrt(std::max(V(b, b), 0.0));
            }
        } else {
            for (std::size_t j = 0; j < n; ++j) {
                if (freq_se) freq_se[j] = 0.0;
                if (zeta_se) zeta_se[j] = 0.0;
            }
        }
        return growth > 0.0 ? unstable("vibid_model_modal", growth) : VIBID_OK;);
}

}  // extern "C"
