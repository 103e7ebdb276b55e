// modal.cpp: natural frequencies, damping ratios and mode shapes from M, D, C (the
// quadratic eigenvalue problem, solved through the state matrix of (1.6)), and their
// standard errors propagated from a parameter covariance.
#include <vibid/modal.h>

#include "api_guard.hpp"
#include "model_internal.hpp"
#include "modal_work.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <complex>
#include <vector>

using Eigen::MatrixXd;
using vibid::throw_error;

namespace {

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

namespace vibid {

ModalWork::ModalWork(const vibid_model *model) : ModalWork(model->nodes.size()) {
    model_ = model;
    p_ = static_cast<Eigen::Index>(model->param_term.size());
    th_.resize(static_cast<std::size_t>(p_));
    tp_.resize(static_cast<std::size_t>(p_));
    tm_.resize(static_cast<std::size_t>(p_));
    J_.resize(2 * n_, p_);
    JC_.resize(2 * n_, p_);
}

ModalWork::ModalWork(std::size_t n)
    : n_(static_cast<Eigen::Index>(n)), lu_(static_cast<Eigen::Index>(n)), es_(2 * static_cast<Eigen::Index>(n)),
      luV_(2 * static_cast<Eigen::Index>(n)) {
    const Eigen::Index N = 2 * n_;
    M_.setZero(n_, n_);
    D_.setZero(n_, n_);
    C_.setZero(n_, n_);
    A_.setZero(N, N);
    Ap_.setZero(N, N);
    S_.setZero(n_, n_);
    V_.setZero(N, N);
    W_.setZero(N, N);
    I_.setIdentity(N, N);
    shape_.setZero(n_);
    Cv_.setZero(N, N);
    modes_.resize(n);
    modes_p_.resize(n);
    modes_m_.resize(n);
    real_roots_.reserve(static_cast<std::size_t>(N));
}

void ModalWork::assemble(const double *theta) {
    if (vibid_model_assemble(model_, theta, M_.data(), D_.data(), C_.data(), nullptr, nullptr, nullptr) != VIBID_OK)
        throw_error(VIBID_E_NUMERICAL, "assembling the model failed: %s", vibid_last_error());
}

// The state matrix of (1.6), A = [0 I; -M^-1 C  -M^-1 D] (2n x 2n), of M_, D_, C_.
void ModalWork::state_matrix(Eigen::MatrixXd &A) {
    const Eigen::Index n = n_;
    lu_.compute(M_);
    // singular: a pivot below the rank threshold of a full-pivoting LU (n eps of the largest)
    const auto piv = lu_.matrixLU().diagonal().cwiseAbs();
    if (!(piv.minCoeff() > piv.maxCoeff() * static_cast<double>(n) * Eigen::NumTraits<double>::epsilon()))
        throw_error(VIBID_E_NUMERICAL, "mass matrix is singular");
    A.setZero();
    A.topRightCorner(n, n).setIdentity();
    S_ = lu_.solve(C_);
    A.bottomLeftCorner(n, n) = -S_;
    S_ = lu_.solve(D_);
    A.bottomRightCorner(n, n) = -S_;
}

// The eigenvectors of es_ as complex columns into V_ (EigenSolver::eigenvectors(), which
// returns a new matrix: the same arithmetic, into the preallocated one).
void ModalWork::complex_vectors() {
    const Eigen::MatrixXd &E = es_.pseudoEigenvectors();
    const auto &lam = es_.eigenvalues();
    const Eigen::Index N = 2 * n_;
    for (Eigen::Index j = 0; j < N; ++j) {
        if (Eigen::internal::isMuchSmallerThan(lam(j).imag(), lam(j).real()) || j + 1 == N) {
            V_.col(j) = E.col(j).cast<std::complex<double>>();
            V_.col(j).normalize();
        } else {
            for (Eigen::Index i = 0; i < N; ++i) {
                V_(i, j) = std::complex<double>(E(i, j), E(i, j + 1));
                V_(i, j + 1) = std::complex<double>(E(i, j), -E(i, j + 1));
            }
            V_.col(j).normalize();
            V_.col(j + 1).normalize();
            ++j;
        }
    }
}

// The modes of A_ (state_matrix done) into modes, sorted by frequency. vectors: the
// eigenvectors too (V_), for shapes or the Jacobian. growth (may be null): the largest
// eigenvalue real part above 1e-12 of the state matrix's norm (an unstable model), 0 when
// there is none.
void ModalWork::analyse(bool vectors, std::vector<Mode> &modes, double *growth) {
    const Eigen::Index n = n_;
    es_.compute(A_, vectors);
    if (es_.info() != Eigen::Success) throw_error(VIBID_E_NUMERICAL, "eigen solver did not converge");
    if (vectors) complex_vectors();
    std::size_t nm = 0;
    real_roots_.clear();
    const double scale = std::max(A_.norm(), 1e-300);
    if (growth) *growth = 0.0;
    for (Eigen::Index i = 0; i < 2 * n; ++i) {
        const std::complex<double> l = es_.eigenvalues()(i);
        // A rigid-body root is 0 up to rounding: only a clearly positive part is growth.
        if (growth && l.real() > 1e-12 * scale) *growth = std::max(*growth, l.real());
        if (std::fabs(l.imag()) > 1e-12 * scale) {
            if (l.imag() < 0) continue;  // the conjugate describes the same mode
            const double w = std::abs(l);
            if (nm < modes.size()) modes[nm] = Mode{w / (2.0 * M_PI), -l.real() / w, i, -1, i};
            ++nm;
        } else {
            real_roots_.emplace_back(l.real(), i);  // reserved: no allocation
        }
    }
    // Overdamped (or rigid-body) modes: pair the real roots in ascending order.
    std::sort(real_roots_.begin(), real_roots_.end());
    for (std::size_t k = 0; k + 1 < real_roots_.size(); k += 2, ++nm) {
        const double l1 = real_roots_[k].first, l2 = real_roots_[k + 1].first;
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
        md.root = real_roots_[k].second;
        md.pair = real_roots_[k + 1].second;
        md.vec = md.pair;
        if (nm < modes.size()) modes[nm] = md;
    }
    if (static_cast<Eigen::Index>(nm) != n)
        throw_error(VIBID_E_NUMERICAL, "could not pair the %ld eigenvalues into %ld modes", static_cast<long>(2 * n),
                    static_cast<long>(n));
    std::sort(modes.begin(), modes.end(), [](const Mode &a, const Mode &b) { return a.freq_hz < b.freq_hz; });
}

void ModalWork::write(const std::vector<Mode> &modes, double *freq_hz, double *zeta, double *shape_re,
                      double *shape_im) {
    const std::size_t n = static_cast<std::size_t>(n_);
    for (std::size_t j = 0; j < n; ++j) {
        if (freq_hz) freq_hz[j] = modes[j].freq_hz;
        if (zeta) zeta[j] = modes[j].zeta;
        if (!shape_re && !shape_im) continue;
        // the first n components of the eigenvector, the largest one exactly 1 (real)
        shape_ = V_.col(modes[j].vec).head(n_);
        Eigen::Index imax = 0;
        shape_.cwiseAbs().maxCoeff(&imax);
        const std::complex<double> pivot = shape_(imax);
        if (std::abs(pivot) > 0) shape_ /= pivot;
        shape_(imax) = 1.0;
        for (std::size_t i = 0; i < n; ++i) {
            if (shape_re) shape_re[i + j * n] = shape_(static_cast<Eigen::Index>(i)).real();
            if (shape_im) shape_im[i + j * n] = shape_(static_cast<Eigen::Index>(i)).imag();
        }
    }
}

// The sensitivities of every mode's frequency (rows 0..n-1) and damping ratio (rows
// n..2n-1) to the parameters (p columns) into J_, by eigenvalue perturbation: for a simple
// eigenvalue l of the state matrix A with right eigenvector v and left eigenvector w (w^H =
// the row of V^-1), dl = w^H dA v. dA/dtheta_i comes from central differences of the
// assembled M, D, C (exact up to rounding where they are linear in theta, as stiffness and
// damping terms are). One eigen decomposition instead of 2p + 1: this runs for every track
// row. false when V is too ill-conditioned for it (a defective or nearly repeated
// eigenvalue, where the perturbation is not first order): the caller then differentiates
// the eigenvalues numerically. Needs analyse(vectors) of th_ into modes_ first.
bool ModalWork::jacobian() {
    const Eigen::Index n = n_, N = 2 * n_;
    luV_.compute(V_);
    W_ = luV_.solve(I_);  // V^-1, row i: w_i^H (inverse() would copy the decomposition)
    // the reciprocal 1-norm condition of V, exact from V and its inverse: below 1e-10 the
    // eigenvector basis is nearly singular and first-order perturbation loses more digits
    // than the numerical difference would
    double nv = 0.0, nw = 0.0;
    for (Eigen::Index j = 0; j < N; ++j) {
        double sv = 0.0, sw = 0.0;
        for (Eigen::Index i = 0; i < N; ++i) {
            sv += std::abs(V_(i, j));
            sw += std::abs(W_(i, j));
        }
        nv = std::max(nv, sv);
        nw = std::max(nw, sw);
    }
    if (!(1.0 / (nv * nw) > 1e-10)) return false;
    const auto &lam = es_.eigenvalues();
    J_.setZero();
    const std::size_t p = static_cast<std::size_t>(p_);
    for (std::size_t i = 0; i < p; ++i) {
        const double step = 1e-6 * std::max(std::fabs(th_[i]), 1e-12);
        tp_ = th_;
        tm_ = th_;
        tp_[i] = th_[i] + step;
        tm_[i] = th_[i] - step;
        assemble(tp_.data());
        state_matrix(Ap_);
        assemble(tm_.data());
        state_matrix(A_);
        Ap_ -= A_;
        Ap_ /= 2.0 * step;  // dA
        // dl_r = w_r^H dA v_r = sum_k W(r, k) (dA V)(k, r), for the roots the modes use
        auto dl = [&](Eigen::Index r) {
            std::complex<double> sum = 0.0;
            for (Eigen::Index k = 0; k < N; ++k) {
                std::complex<double> av = 0.0;
                for (Eigen::Index m = 0; m < N; ++m) av += Ap_(k, m) * V_(m, r);
                sum += W_(r, k) * av;
            }
            return sum;
        };
        for (Eigen::Index j = 0; j < n; ++j) {
            const Mode &md = modes_[static_cast<std::size_t>(j)];
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
            J_(j, static_cast<Eigen::Index>(i)) = df;
            J_(n + j, static_cast<Eigen::Index>(i)) = dz;
        }
    }
    return true;
}

// J_ by central differences of the eigenvalues (2p decompositions): where jacobian() cannot.
void ModalWork::numeric_jacobian() {
    const std::size_t p = static_cast<std::size_t>(p_);
    for (std::size_t i = 0; i < p; ++i) {
        const double step = 1e-6 * std::max(std::fabs(th_[i]), 1e-12);
        tp_ = th_;
        tm_ = th_;
        tp_[i] += step;
        tm_[i] -= step;
        assemble(tp_.data());
        state_matrix(A_);
        analyse(false, modes_p_, nullptr);
        assemble(tm_.data());
        state_matrix(A_);
        analyse(false, modes_m_, nullptr);
        for (Eigen::Index j = 0; j < n_; ++j) {
            const std::size_t jj = static_cast<std::size_t>(j);
            J_(j, static_cast<Eigen::Index>(i)) = (modes_p_[jj].freq_hz - modes_m_[jj].freq_hz) / (2 * step);
            J_(n_ + j, static_cast<Eigen::Index>(i)) = (modes_p_[jj].zeta - modes_m_[jj].zeta) / (2 * step);
        }
    }
}

vibid_status ModalWork::model_modal(const double *theta, const double *cov, double *freq_hz, double *freq_se,
                                    double *zeta, double *zeta_se, double *shape_re, double *shape_im, const char *fn) {
    if (!freq_hz || !zeta) throw_error(VIBID_E_NULL_ARGUMENT, "freq_hz and zeta are required");
    const std::size_t n = static_cast<std::size_t>(n_), p = static_cast<std::size_t>(p_);
    if (theta)
        std::copy(theta, theta + p, th_.begin());
    else
        vibid_model_nominal(model_, th_.data());
    if (!vibid::all_finite(th_.data(), p)) throw_error(VIBID_E_NONFINITE, "theta has NaN or Inf");
    const bool se_wanted = cov && (freq_se || zeta_se);
    if (se_wanted && !vibid::all_finite(cov, p * p)) throw_error(VIBID_E_NONFINITE, "cov has NaN or Inf");
    double growth = 0.0;
    assemble(th_.data());
    state_matrix(A_);
    analyse(shape_re || shape_im || se_wanted, modes_, &growth);
    write(modes_, freq_hz, zeta, shape_re, shape_im);
    if (se_wanted) {
        // First-order propagation: se^2 = diag(J cov J^T), J (2n x p) by eigenvalue
        // perturbation, or by central differences of the eigenvalues where that fails.
        if (!jacobian()) numeric_jacobian();
        const Eigen::Map<const Eigen::MatrixXd> Cm(cov, p_, p_);
        JC_.noalias() = J_ * Cm;
        for (std::size_t j = 0; j < n; ++j) {
            const Eigen::Index a = static_cast<Eigen::Index>(j), b = static_cast<Eigen::Index>(n + j);
            if (freq_se) freq_se[j] = std::sqrt(std::max(JC_.row(a).dot(J_.row(a)), 0.0));
            if (zeta_se) zeta_se[j] = std::sqrt(std::max(JC_.row(b).dot(J_.row(b)), 0.0));
        }
    } else {
        for (std::size_t j = 0; j < n; ++j) {
            if (freq_se) freq_se[j] = 0.0;
            if (zeta_se) zeta_se[j] = 0.0;
        }
    }
    return growth > 0.0 ? unstable(fn, growth) : VIBID_OK;
}

vibid_status ModalWork::matrices_modal(const double *M, const double *D, const double *C, double *freq_hz,
                                       double *zeta, double *shape_re, double *shape_im, const char *fn) {
    M_ = Eigen::Map<const Eigen::MatrixXd>(M, n_, n_);
    if (D)
        D_ = Eigen::Map<const Eigen::MatrixXd>(D, n_, n_);
    else
        D_.setZero();
    C_ = Eigen::Map<const Eigen::MatrixXd>(C, n_, n_);
    double growth = 0.0;
    state_matrix(A_);
    analyse(shape_re || shape_im, modes_, &growth);
    write(modes_, freq_hz, zeta, shape_re, shape_im);
    return growth > 0.0 ? unstable(fn, growth) : VIBID_OK;
}

}  // namespace vibid

extern "C" {

VIBID_API vibid_status vibid_modal(size_t n, const double *M, const double *D, const double *C, double *freq_hz,
                                   double *zeta, double *shape_re, double *shape_im) {
    VIBID_GUARD(
        if (n < 1 || n > 512) throw_error(VIBID_E_DIMENSION, "n = %zu outside 1..512", n);
        if (!M || !C || !freq_hz || !zeta) throw_error(VIBID_E_NULL_ARGUMENT, "M, C, freq_hz and zeta are required");
        if (!vibid::all_finite(M, n * n) || !vibid::all_finite(C, n * n) || (D && !vibid::all_finite(D, n * n)))
            throw_error(VIBID_E_NONFINITE, "matrix with NaN or Inf");
        vibid::ModalWork w(n);
        return w.matrices_modal(M, D, C, freq_hz, zeta, shape_re, shape_im, "vibid_modal"););
}

VIBID_API vibid_status vibid_model_modal(const vibid_model *model, const double *theta, const double *cov,
                                         double *freq_hz, double *freq_se, double *zeta, double *zeta_se,
                                         double *shape_re, double *shape_im) {
    VIBID_GUARD(
        vibid::require_finalized(model);
        vibid::ModalWork w(model);  // model_modal checks the outputs
        return w.model_modal(theta, cov, freq_hz, freq_se, zeta, zeta_se, shape_re, shape_im, "vibid_model_modal"););
}

VIBID_API vibid_status vibid_model_frf(const vibid_model *model, const double *theta, double sample_time,
                                       size_t n_freq, const double *freq_hz, double *re, double *im) {
    VIBID_GUARD(
        vibid::require_finalized(model);
        if (!freq_hz || !re || !im) throw_error(VIBID_E_NULL_ARGUMENT, "freq_hz, re and im are required");
        if (!(sample_time >= 0.0) || !std::isfinite(sample_time))
            throw_error(VIBID_E_OUT_OF_RANGE, "sample_time = %g s must be >= 0 and finite", sample_time);
        for (size_t k = 0; k < n_freq; ++k)
            if (!(freq_hz[k] >= 0.0) || !std::isfinite(freq_hz[k]))
                throw_error(VIBID_E_OUT_OF_RANGE, "freq_hz[%zu] = %g must be >= 0 and finite", k, freq_hz[k]);
        vibid_model_dims dm{};
        if (vibid_model_get_dims(model, &dm) != VIBID_OK) throw_error(VIBID_E_STATE, "%s", vibid_last_error());
        const std::size_t p = dm.n_params, n = dm.n_dof, r = dm.n_inputs, nc = dm.n_channels;
        const std::size_t ne = r + (dm.has_base ? 1 : 0);
        std::vector<double> th(p);
        if (theta)
            std::copy(theta, theta + p, th.begin());
        else
            vibid_model_nominal(model, th.data());
        if (!vibid::all_finite(th.data(), p)) throw_error(VIBID_E_NONFINITE, "theta has NaN or Inf");
        const Eigen::Index N = static_cast<Eigen::Index>(n);
        MatrixXd M(N, N), D(N, N), C(N, N), B(N, std::max<Eigen::Index>(static_cast<Eigen::Index>(r), 1));
        Eigen::VectorXd db(N), cb(N);
        if (vibid_model_assemble(model, th.data(), M.data(), D.data(), C.data(), r ? B.data() : nullptr, db.data(),
                                 cb.data()) != VIBID_OK)
            throw_error(VIBID_E_STATE, "%s", vibid_last_error());
        std::vector<bool> held(ne, false);
        for (std::size_t e = 0; e < ne; ++e) {
            vibid_hold hd;
            if (vibid_model_get_hold(model, e < r ? e : VIBID_BASE, &hd) == VIBID_OK) held[e] = hd == VIBID_HOLD_ZOH;
        }
        std::vector<vibid_channel_info> info(nc);
        for (std::size_t c = 0; c < nc; ++c)
            if (vibid_model_channel_info(model, c, &info[c]) != VIBID_OK)
                throw_error(VIBID_E_STATE, "%s", vibid_last_error());
        using cd = std::complex<double>;
        Eigen::MatrixXcd Z(N, N), R(N, static_cast<Eigen::Index>(std::max<std::size_t>(ne, 1))), X;
        for (std::size_t k = 0; k < n_freq; ++k) {
            const double w = 2.0 * M_PI * freq_hz[k];
            const cd jw(0.0, w);
            Z = C.cast<cd>() - w * w * M.cast<cd>() + jw * D.cast<cd>();
            for (std::size_t e = 0; e < ne; ++e) {
                const Eigen::Index ei = static_cast<Eigen::Index>(e);
                if (e < r)
                    R.col(ei) = B.col(ei).cast<cd>();
                else
                    R.col(ei) = cb.cast<cd>() + jw * db.cast<cd>();
            }
            X = Z.partialPivLu().solve(R);
            for (std::size_t e = 0; e < ne; ++e) {
                // the zero-order hold's factor for a held excitation, sampled
                cd hold = 1.0;
                if (held[e] && sample_time > 0.0 && w > 0.0) {
                    const double x = 0.5 * w * sample_time;
                    hold = std::polar(std::sin(x) / x, -x);
                }
                for (std::size_t c = 0; c < nc; ++c) {
                    const vibid_channel_info &ci = info[c];
                    const cd q = ci.kind == VIBID_CHANNEL_DISPLACEMENT ? cd(1.0)
                                 : ci.kind == VIBID_CHANNEL_VELOCITY   ? jw
                                                                       : cd(-w * w);
                    cd h = 0.0;
                    if (ci.kind == VIBID_CHANNEL_INPUT)
                        h = ci.index == e ? 1.0 : 0.0;
                    else if (ci.index == VIBID_BASE)
                        h = e == r && dm.has_base ? q : cd(0.0);
                    else
                        h = q * X(static_cast<Eigen::Index>(ci.index), static_cast<Eigen::Index>(e)) * hold;
                    const std::size_t at = k + n_freq * (c + nc * e);
                    re[at] = h.real();
                    im[at] = h.imag();
                }
            }
        }
        return VIBID_OK;);
}

}  // extern "C"
