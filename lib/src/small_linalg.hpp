// small_linalg.hpp: allocation-free dense kernels for the Kalman filters (kf_rls.cpp,
// stand_ekf.cpp): Cholesky of a small symmetric matrix, the solve with its factor, and
// symmetrisation. Hand-written because Eigen's LLT of a dynamic matrix may allocate and
// these run per sample on real-time paths.
#pragma once

#include <Eigen/Core>

#include <cmath>

namespace vibid {

// In-place lower Cholesky of the n x n symmetric A (lower triangle read). False if not
// positive definite (or not finite).
inline bool cholesky(Eigen::MatrixXd &A) {
    const Eigen::Index n = A.rows();
    for (Eigen::Index j = 0; j < n; ++j) {
        double d = A(j, j);
        for (Eigen::Index k = 0; k < j; ++k) d -= A(j, k) * A(j, k);
        if (!(d > 0.0) || !std::isfinite(d)) return false;
        d = std::sqrt(d);
        A(j, j) = d;
        for (Eigen::Index i = j + 1; i < n; ++i) {
            double s = A(i, j);
            for (Eigen::Index k = 0; k < j; ++k) s -= A(i, k) * A(j, k);
            A(i, j) = s / d;
        }
    }
    return true;
}

// Solves (L L^T) y = b in place; returns ||L^-1 b||^2 (b^T A^-1 b).
inline double chol_solve(const Eigen::MatrixXd &L, double *b) {
    const Eigen::Index n = L.rows();
    double q = 0.0;
    for (Eigen::Index i = 0; i < n; ++i) {
        double s = b[i];
        for (Eigen::Index k = 0; k < i; ++k) s -= L(i, k) * b[k];
        b[i] = s / L(i, i);
        q += b[i] * b[i];
    }
    for (Eigen::Index i = n - 1; i >= 0; --i) {
        double s = b[i];
        for (Eigen::Index k = i + 1; k < n; ++k) s -= L(k, i) * b[k];
        b[i] = s / L(i, i);
    }
    return q;
}

inline void symmetrise(Eigen::MatrixXd &S) {
    const Eigen::Index n = S.rows();
    for (Eigen::Index j = 0; j < n; ++j)
        for (Eigen::Index i = 0; i < j; ++i) {
            const double m = 0.5 * (S(i, j) + S(j, i));
            S(i, j) = m;
            S(j, i) = m;
        }
}

}  // namespace vibid
