// io_form.cpp: input-output (characteristic-polynomial) form (3.13)-(3.15): batch LS and
// two-stage IV estimates of the polynomial and U C_i H, modes with delta-method standard
// errors, and recovery of free entries of G from the polynomial. Offline code: it
// allocates freely and reports bad input by throwing (turned into a status by the guard).
#include <vibid/io_form.h>

#include "api_guard.hpp"

#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <Eigen/QR>

#include <algorithm>
#include <cmath>
#include <complex>
#include <vector>

namespace {

using Eigen::Index;
using Mat = Eigen::MatrixXd;
using Vec = Eigen::VectorXd;
using cplx = std::complex<double>;

constexpr size_t kMaxOrder = 64;
constexpr size_t kMaxIo = 64;
constexpr size_t kMaxLags = 256;
constexpr double kPi = 3.14159265358979323846;

void check_config(const vibid_ioform_config *cfg) {
    if (!cfg) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "cfg is NULL");
    if (cfg->order < 1 || cfg->order > kMaxOrder)
        vibid::throw_error(VIBID_E_DIMENSION, "order = %zu outside 1..%zu", cfg->order, kMaxOrder);
    if (cfg->n_outputs < 1 || cfg->n_outputs > kMaxIo)
        vibid::throw_error(VIBID_E_DIMENSION, "n_outputs = %zu outside 1..%zu", cfg->n_outputs, kMaxIo);
    if (cfg->n_inputs > kMaxIo)
        vibid::throw_error(VIBID_E_DIMENSION, "n_inputs = %zu outside 0..%zu", cfg->n_inputs, kMaxIo);
    const int method = vibid::enum_value(cfg->method);
    if (method != VIBID_IOFORM_LS && method != VIBID_IOFORM_IV)
        vibid::throw_error(VIBID_E_OUT_OF_RANGE, "method = %d unknown", method);
    if (cfg->method == VIBID_IOFORM_IV && (cfg->iv_lags < cfg->order || cfg->iv_lags > kMaxLags))
        vibid::throw_error(VIBID_E_OUT_OF_RANGE, "iv_lags = %zu outside order..%zu", cfg->iv_lags, kMaxLags);
}

// Covariance (A^T A)^-1 from a column-pivoted QR of A (full column rank).
Mat inverse_gram(const Eigen::ColPivHouseholderQR<Mat> &qr) {
    const Index p = qr.cols();
    Mat R = qr.matrixQR().topLeftCorner(p, p).triangularView<Eigen::Upper>();
    Mat Rinv = R.triangularView<Eigen::Upper>().solve(Mat::Identity(p, p));
    Mat G = Rinv * Rinv.transpose();
    return qr.colsPermutation() * G * qr.colsPermutation().transpose();
}

// Coefficients c_0..c_{n-1} of det(zI - G) = z^n + c_{n-1} z^{n-1} + ... + c_0
// (Faddeev-LeVerrier).
Vec charpoly(const Mat &G) {
    const Index n = G.rows();
    Vec c(n);
    Mat M = Mat::Zero(n, n);
    double cprev = 1.0;
    for (Index k = 1; k <= n; ++k) {
        M = G * M;
        M.diagonal().array() += cprev;
        const double ck = -(G * M).trace() / static_cast<double>(k);
        c(n - k) = ck;
        cprev = ck;
    }
    return c;
}

}  // namespace

extern "C" {

void vibid_ioform_config_init(vibid_ioform_config *cfg, size_t order, size_t n_outputs, size_t n_inputs) {
    if (!cfg) return;
    cfg->order = order;
    cfg->n_outputs = n_outputs;
    cfg->n_inputs = n_inputs;
    cfg->method = VIBID_IOFORM_LS;
    cfg->iv_lags = order + 2;
}

vibid_status vibid_ioform_estimate(const vibid_ioform_config *cfg, const double *z, const double *u,
                                   size_t n_samples, double *a, double *a_cov, double *ucih, double *sigma2) {
    VIBID_GUARD({
        check_config(cfg);
        if (!z || !a) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "z or a is NULL");
        const size_t m = cfg->order, q = cfg->n_outputs, r = cfg->n_inputs;
        if (r > 0 && !u) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "u is NULL with n_inputs = %zu", r);
        const bool iv = cfg->method == VIBID_IOFORM_IV;
        const size_t lags = iv ? cfg->iv_lags : 0;
        const size_t p = m + m * q * r;
        if (n_samples < m + lags + 1)
            vibid::throw_error(VIBID_E_INSUFFICIENT_DATA, "n_samples = %zu too few for order %zu and %zu lags",
                               n_samples, m, lags);
        const size_t n_k = n_samples - m - lags;
        const size_t n_eq = n_k * q;
        if (n_eq <= p)
            vibid::throw_error(VIBID_E_INSUFFICIENT_DATA, "%zu equations for %zu unknowns", n_eq, p);
        if (!vibid::all_finite(z, q * n_samples)) vibid::throw_error(VIBID_E_NONFINITE, "NaN/Inf in z");
        if (r > 0 && !vibid::all_finite(u, r * n_samples)) vibid::throw_error(VIBID_E_NONFINITE, "NaN/Inf in u");

        const size_t nw = lags + m * q * r;
        Mat X(n_eq, p), W;
        Vec Y(n_eq);
        if (iv) W.resize(n_eq, nw);
        X.setZero();
        if (iv) W.setZero();
        for (size_t kk = 0; kk < n_k; ++kk) {
            const size_t k = kk + lags;  // oldest output of the equation
            for (size_t j = 0; j < q; ++j) {
                const Index row = static_cast<Index>(kk * q + j);
                for (size_t i = 0; i < m; ++i) X(row, static_cast<Index>(i)) = -z[j + (k + i) * q];
                Y(row) = z[j + (k + m) * q];
                for (size_t i = 0; i < m; ++i)
                    for (size_t l = 0; l < r; ++l) {
                        const double b = u[l + (k + i) * r];
                        X(row, static_cast<Index>(m + j + l * q + i * q * r)) = b;
                        if (iv) W(row, static_cast<Index>(lags + j + l * q + i * q * r)) = b;
                    }
                if (iv)
                    for (size_t s = 0; s < lags; ++s) W(row, static_cast<Index>(s)) = z[j + (k - 1 - s) * q];
            }
        }

        Vec theta;
        Mat cov;
        if (!iv) {
            Eigen::ColPivHouseholderQR<Mat> qr(X);
            qr.setThreshold(1e-12);
            if (qr.rank() < static_cast<Index>(p))
                vibid::throw_error(VIBID_E_NOT_IDENTIFIABLE, "regressor rank %ld < %zu unknowns (no excitation?)",
                                   static_cast<long>(qr.rank()), p);
            theta = qr.solve(Y);
            if (a_cov) cov = inverse_gram(qr);
        } else {
            // Two-stage IV: project X and Y onto the instruments' column space.
            Eigen::HouseholderQR<Mat> wqr(W);
            Mat QtX = X;
            QtX.applyOnTheLeft(wqr.householderQ().adjoint());
            Vec QtY = Y;
            QtY.applyOnTheLeft(wqr.householderQ().adjoint());
            Mat A = QtX.topRows(static_cast<Index>(nw));
            Vec b = QtY.head(static_cast<Index>(nw));
            Eigen::ColPivHouseholderQR<Mat> qr(A);
            qr.setThreshold(1e-12);
            if (qr.rank() < static_cast<Index>(p))
                vibid::throw_error(VIBID_E_NOT_IDENTIFIABLE,
                                   "instrumented regressor rank %ld < %zu unknowns (instruments uncorrelated?)",
                                   static_cast<long>(qr.rank()), p);
            theta = qr.solve(b);
            if (a_cov) cov = inverse_gram(qr);
        }
        const Vec e = Y - X * theta;
        const double s2 = e.squaredNorm() / static_cast<double>(n_eq - p);
        if (!theta.allFinite() || !std::isfinite(s2)) vibid::throw_error(VIBID_E_NUMERICAL, "non-finite estimate");
        for (size_t i = 0; i < m; ++i) a[i] = theta(static_cast<Index>(i));
        if (a_cov) {
            for (size_t j = 0; j < m; ++j)
                for (size_t i = 0; i < m; ++i)
                    a_cov[i + j * m] = s2 * cov(static_cast<Index>(i), static_cast<Index>(j));
        }
        if (ucih && r > 0)
            for (size_t i = 0; i < m * q * r; ++i) ucih[i] = theta(static_cast<Index>(m + i));
        if (sigma2) *sigma2 = s2;
        return VIBID_OK;
    });
}

vibid_status vibid_ioform_regressor(const vibid_ioform_config *cfg, const double *z_win, const double *u_win,
                                    double *x, double *y) {
    if (!cfg || !z_win || !x || !y) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "cfg, z_win, x or y is NULL");
    const size_t m = cfg->order, q = cfg->n_outputs, r = cfg->n_inputs;
    if (m < 1 || m > kMaxOrder || q < 1 || q > kMaxIo || r > kMaxIo)
        return VIBID_FAIL(VIBID_E_DIMENSION, "order %zu, n_outputs %zu or n_inputs %zu out of range", m, q, r);
    if (r > 0 && !u_win) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "u_win is NULL with n_inputs = %zu", r);
    if (!vibid::all_finite(z_win, q * (m + 1)) || (r > 0 && !vibid::all_finite(u_win, r * m)))
        return VIBID_FAIL(VIBID_E_NONFINITE, "NaN/Inf in z_win or u_win");
    const size_t p = m + m * q * r;
    for (size_t j = 0; j < q; ++j) {
        double *col = x + j * p;
        for (size_t i = 0; i < p; ++i) col[i] = 0.0;
        for (size_t i = 0; i < m; ++i) col[i] = -z_win[j + i * q];
        for (size_t i = 0; i < m; ++i)
            for (size_t l = 0; l < r; ++l) col[m + j + l * q + i * q * r] = u_win[l + i * r];
        y[j] = z_win[j + m * q];
    }
    return VIBID_OK;
}

vibid_status vibid_ioform_modes(const double *a, const double *a_cov, size_t m, double h, double *freq_hz,
                                double *zeta, double *freq_se, double *zeta_se, size_t *n_modes) {
    VIBID_GUARD({
        if (!a || !freq_hz || !zeta || !n_modes)
            vibid::throw_error(VIBID_E_NULL_ARGUMENT, "a, freq_hz, zeta or n_modes is NULL");
        if (m < 1 || m > kMaxOrder) vibid::throw_error(VIBID_E_DIMENSION, "m = %zu outside 1..%zu", m, kMaxOrder);
        if (!(h > 0.0) || !std::isfinite(h)) vibid::throw_error(VIBID_E_OUT_OF_RANGE, "h = %g not > 0", h);
        if (!vibid::all_finite(a, m)) vibid::throw_error(VIBID_E_NONFINITE, "NaN/Inf in a");
        if (a_cov && !vibid::all_finite(a_cov, m * m)) vibid::throw_error(VIBID_E_NONFINITE, "NaN/Inf in a_cov");
        const Index n = static_cast<Index>(m);
        Mat C = Mat::Zero(n, n);
        for (Index i = 1; i < n; ++i) C(i, i - 1) = 1.0;
        for (Index i = 0; i < n; ++i) C(i, n - 1) = -a[i];
        Eigen::EigenSolver<Mat> es(C, false);
        if (es.info() != Eigen::Success) vibid::throw_error(VIBID_E_NUMERICAL, "eigenvalues did not converge");
        struct Mode {
            double f, zt, fse, zse;
        };
        std::vector<Mode> modes;
        const double nan = std::nan("");
        for (Index i = 0; i < n; ++i) {
            const cplx zr = es.eigenvalues()(i);
            if (zr.imag() < 0.0) continue;
            if (std::abs(zr) == 0.0) vibid::throw_error(VIBID_E_NUMERICAL, "root at z = 0 (no continuous-time mode)");
            const cplx s = std::log(zr) / h;
            const double rs = std::abs(s);
            Mode md{rs / (2.0 * kPi), rs > 0.0 ? -s.real() / rs : nan, nan, nan};
            if (a_cov) {
                cplx dp = static_cast<double>(m) * std::pow(zr, static_cast<int>(m - 1));
                for (size_t l = 1; l < m; ++l) dp += static_cast<double>(l) * a[l] * std::pow(zr, static_cast<int>(l - 1));
                if (std::abs(dp) <= 1e-12 * std::max(1.0, std::abs(zr)))
                    vibid::throw_error(VIBID_E_NUMERICAL, "multiple root at z = %g%+gi: no delta method",
                                       zr.real(), zr.imag());
                Vec jf(n), jz(n);
                for (Index l = 0; l < n; ++l) {
                    const cplx g = -std::pow(zr, static_cast<int>(l)) / dp / (zr * h);
                    const double dr = (s.real() * g.real() + s.imag() * g.imag()) / rs;
                    jf(l) = dr / (2.0 * kPi);
                    jz(l) = -g.real() / rs + s.real() * dr / (rs * rs);
                }
                Eigen::Map<const Mat> S(a_cov, n, n);
                md.fse = std::sqrt(std::max(0.0, jf.dot(S * jf)));
                md.zse = std::sqrt(std::max(0.0, jz.dot(S * jz)));
            }
            modes.push_back(md);
        }
        std::sort(modes.begin(), modes.end(), [](const Mode &x, const Mode &y) { return x.f < y.f; });
        for (size_t i = 0; i < modes.size(); ++i) {
            freq_hz[i] = modes[i].f;
            zeta[i] = modes[i].zt;
            if (freq_se) freq_se[i] = modes[i].fse;
            if (zeta_se) zeta_se[i] = modes[i].zse;
        }
        *n_modes = modes.size();
        return VIBID_OK;
    });
}

vibid_status vibid_ioform_recover_g(const double *a, size_t m, double *G, const unsigned char *free_mask,
                                    const double *a_cov, double *G_cov) {
    VIBID_GUARD({
        if (!a || !G || !free_mask) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "a, G or free_mask is NULL");
        if (m < 1 || m > kMaxOrder) vibid::throw_error(VIBID_E_DIMENSION, "m = %zu outside 1..%zu", m, kMaxOrder);
        if (!vibid::all_finite(a, m) || !vibid::all_finite(G, m * m))
            vibid::throw_error(VIBID_E_NONFINITE, "NaN/Inf in a or G");
        if (a_cov && !vibid::all_finite(a_cov, m * m)) vibid::throw_error(VIBID_E_NONFINITE, "NaN/Inf in a_cov");
        std::vector<Index> idx;
        for (size_t i = 0; i < m * m; ++i)
            if (free_mask[i]) idx.push_back(static_cast<Index>(i));
        const Index nf = static_cast<Index>(idx.size());
        if (nf < 1 || nf > static_cast<Index>(m))
            vibid::throw_error(VIBID_E_DIMENSION, "%ld free entries, need 1..%zu", static_cast<long>(nf), m);
        const Index n = static_cast<Index>(m);
        Mat Gm = Eigen::Map<const Mat>(G, n, n);
        const Vec target = Eigen::Map<const Vec>(a, n);
        const double scale = std::max(1.0, target.cwiseAbs().maxCoeff());
        Mat J(n, nf);
        auto jacobian = [&]() {
            for (Index c = 0; c < nf; ++c) {
                const Index e = idx[static_cast<size_t>(c)];
                const double g0 = Gm.data()[e];
                const double step = 1e-6 * std::max(1.0, std::fabs(g0));
                Gm.data()[e] = g0 + step;
                const Vec cp = charpoly(Gm);
                Gm.data()[e] = g0 - step;
                const Vec cm = charpoly(Gm);
                Gm.data()[e] = g0;
                J.col(c) = (cp - cm) / (2.0 * step);
            }
        };
        bool converged = false;
        for (int it = 0; it < 50 && !converged; ++it) {
            jacobian();
            Eigen::ColPivHouseholderQR<Mat> qr(J);
            qr.setThreshold(1e-9);
            if (qr.rank() < nf)
                vibid::throw_error(VIBID_E_NOT_IDENTIFIABLE,
                                   "the characteristic polynomial does not determine the %ld free entries (rank %ld)",
                                   static_cast<long>(nf), static_cast<long>(qr.rank()));
            const Vec res = target - charpoly(Gm);
            const Vec dx = qr.solve(res);
            for (Index c = 0; c < nf; ++c) Gm.data()[idx[static_cast<size_t>(c)]] += dx(c);
            if (!Gm.allFinite()) break;
            const double gs = std::max(1.0, Gm.cwiseAbs().maxCoeff());
            if (dx.cwiseAbs().maxCoeff() <= 1e-13 * gs && res.cwiseAbs().maxCoeff() <= 1e-10 * scale)
                converged = true;
            else if (dx.cwiseAbs().maxCoeff() <= 1e-14 * gs)
                converged = (target - charpoly(Gm)).cwiseAbs().maxCoeff() <= 1e-8 * scale;
        }
        if (!converged) {
            // One last check: a solution found on the final step counts.
            if (!(Gm.allFinite() && (target - charpoly(Gm)).cwiseAbs().maxCoeff() <= 1e-10 * scale))
                vibid::throw_error(VIBID_E_NUMERICAL, "Gauss-Newton did not converge (no G with this polynomial?)");
        }
        if (G_cov) {
            jacobian();
            if (!a_cov) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "G_cov requested without a_cov");
            Eigen::ColPivHouseholderQR<Mat> qr(J);
            const Mat Jp = qr.solve(Mat::Identity(n, n));  // nf x n pseudo-inverse
            const Mat cv = Jp * Eigen::Map<const Mat>(a_cov, n, n) * Jp.transpose();
            Eigen::Map<Mat>(G_cov, nf, nf) = cv;
        }
        Eigen::Map<Mat>(G, n, n) = Gm;
        return VIBID_OK;
    });
}

}  // extern "C"
