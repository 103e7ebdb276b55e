// lsq.cpp: batch least squares, weighted LS and Gauss-Markov (paper (2.4), (2.11),
// (2.12)) by QR of the augmented matrix [X Y], accumulated block of rows by block of rows.
//
// Why QR of [X Y] instead of normal equations: the condition number of X^T X is the
// square of that of X, so a stiffness of 1e6 beside a damping of 1 would lose twelve
// digits before the solve even starts. Merging rows into the triangular factor R keeps
// the accuracy of an orthogonal factorisation, needs O((p+q)^2) memory independent of N,
// and the last q x q block of R gives the residual cross-product E^T S E for free (it is
// what is left of Y after projecting out X).
//
// Why blocks of rows and Householder reflections (rather than one Givens sweep per row):
// a sweep of Givens rotations costs 6 flops per entry of R and walks all of R for every
// row. Copying b rows into a scratch block A (b x (p+q), sized to stay in the L1 cache)
// and merging [R; A] with one Householder reflection per column costs 4 flops per entry
// of A, in long contiguous vector loops over A's columns, and touches R once per block
// (kernels.hpp, qr_merge). The reflections keep R's diagonal >= 0 as the rotations did;
// nothing of R is visible through the API anyway, only Theta, the covariances and the
// rank, which do not depend on the signs of R's rows.
#include <vibid/lsq.h>

#include "api_guard.hpp"
#include "kernels.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

namespace {

using Eigen::Index;
using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using CMap = Eigen::Map<const Eigen::MatrixXd>;

constexpr std::size_t max_dimension = 4096;
constexpr double default_rank_tolerance = 1e-10;

// Result of the rank analysis of R's regressor block after column scaling.
struct RankAnalysis {
    Index rank = 0;
    double rcond = 0.0;
    Eigen::VectorXd scale;  // column norms of R11 (1 where a column is exactly zero)
    Eigen::MatrixXd V;      // right singular vectors of the scaled R11 (only if asked)
};

// Rows per block merged into R: as many as keep the block (rows x (p + q) doubles) within
// about 24 KiB, so that it stays in a 32 KiB L1 data cache while each column's reflection
// reads it twice; at least 8 rows (large p + q) and at most 256 (small p + q, where more
// rows buy nothing), a multiple of 4 so that every column of the block starts 32-byte
// aligned relative to the first.
Index block_rows(Index n) { return std::clamp<Index>((3072 / n) / 4 * 4, 8, 256); }

}  // namespace

struct vibid_lsq {
    vibid_lsq(std::size_t n_params, std::size_t n_outputs)
        : p(static_cast<Index>(n_params)),
          q(static_cast<Index>(n_outputs)),
          bmax(block_rows(p + q)),
          R(RowMatrix::Zero(p + q, p + q)),
          block(Eigen::VectorXd::Zero(bmax * (p + q))),
          sqrt_w(Eigen::VectorXd::Zero(bmax)),
          kt(&vibid::kern::active()) {}

    // Adds N rows of already validated data: X N x p, Y N x q column-major (leading
    // dimension N), weights NULL for all 1. Block by block: copy (scaled by sqrt(weight))
    // into the scratch block, merge into R. A zero-weight row is a zero row of the block,
    // which the reflections leave without effect; it is not counted.
    void absorb_rows(Index N, const double *X, const double *Y, const double *weights) noexcept {
        const Index n = p + q;
        double *A = block.data();
        for (Index k0 = 0; k0 < N; k0 += bmax) {
            const Index nb = std::min(bmax, N - k0);
            if (!weights) {
                for (Index i = 0; i < p; ++i)
                    std::memcpy(A + i * bmax, X + k0 + i * N, static_cast<std::size_t>(nb) * sizeof(double));
                for (Index j = 0; j < q; ++j)
                    std::memcpy(A + (p + j) * bmax, Y + k0 + j * N, static_cast<std::size_t>(nb) * sizeof(double));
                n_rows += static_cast<std::size_t>(nb);
                sum_weights += static_cast<double>(nb);
            } else {
                double *sw = sqrt_w.data();
                for (Index r = 0; r < nb; ++r) {
                    const double w = weights[k0 + r];
                    sw[r] = std::sqrt(w);
                    if (w > 0.0) {
                        ++n_rows;
                        sum_weights += w;
                    }
                }
                for (Index i = 0; i < p; ++i)
                    for (Index r = 0; r < nb; ++r) A[r + i * bmax] = sw[r] * X[k0 + r + i * N];
                for (Index j = 0; j < q; ++j)
                    for (Index r = 0; r < nb; ++r) A[r + (p + j) * bmax] = sw[r] * Y[k0 + r + j * N];
            }
            kt->qr_merge(n, R.data(), nb, A, bmax);
        }
    }

    Eigen::MatrixXd r11() const { return R.topLeftCorner(p, p); }

    // Numerical rank of the column-scaled regressor block. Scaling each column of
    // R11 to unit norm is the same as scaling the parameters, so that a rank decision
    // does not depend on the units the user chose for each parameter.
    RankAnalysis analyse(bool want_vectors) const {
        RankAnalysis a;
        Eigen::MatrixXd Rs = r11();
        a.scale = Rs.colwise().norm().transpose();
        for (Index i = 0; i < p; ++i) {
            if (a.scale[i] == 0.0) a.scale[i] = 1.0;
            Rs.col(i) /= a.scale[i];
        }
        Eigen::BDCSVD<Eigen::MatrixXd> svd(Rs, want_vectors ? Eigen::ComputeFullV : 0);
        const Eigen::VectorXd &sv = svd.singularValues();
        const double smax = sv.size() ? sv[0] : 0.0;
        for (Index i = 0; i < sv.size(); ++i)
            if (sv[i] > rank_tol * smax) ++a.rank;
        a.rcond = smax > 0.0 ? sv[sv.size() - 1] / smax : 0.0;
        if (want_vectors) a.V = svd.matrixV();
        return a;
    }

    // Checks that a solve is possible; throws otherwise. Fills info if given.
    RankAnalysis require_full_rank(vibid_lsq_info *info, bool want_vectors = false) const {
        if (n_rows == 0) vibid::throw_error(VIBID_E_INSUFFICIENT_DATA, "no rows with weight > 0 added yet");
        if (!R.allFinite())
            vibid::throw_error(VIBID_E_NUMERICAL,
                               "accumulated factor overflowed (data or weights too large)");
        RankAnalysis a = analyse(want_vectors);
        if (info) {
            info->n_rows = n_rows;
            info->rank = static_cast<std::size_t>(a.rank);
            info->rcond = a.rcond;
            info->sum_weights = sum_weights;
        }
        if (a.rank < p)
            vibid::throw_error(
                VIBID_E_NOT_IDENTIFIABLE,
                "regressor has numerical rank %td of %td parameters (rcond %.3g, tolerance %.3g); "
                "see vibid_lsq_null_space",
                static_cast<std::ptrdiff_t>(a.rank), static_cast<std::ptrdiff_t>(p), a.rcond, rank_tol);
        return a;
    }

    // (X^T S X)^-1 = R11^-1 R11^-T, from triangular solves (never an explicit X^T X).
    Eigen::MatrixXd param_cov() const {
        const Eigen::MatrixXd Rinv =
            R.topLeftCorner(p, p).triangularView<Eigen::Upper>().solve(Eigen::MatrixXd::Identity(p, p));
        return Rinv * Rinv.transpose();
    }

    // E^T S E / (n - p) = R22^T R22 / (n - p).
    Eigen::MatrixXd residual_cov() const {
        if (n_rows <= static_cast<std::size_t>(p))
            vibid::throw_error(VIBID_E_INSUFFICIENT_DATA,
                               "residual covariance needs more rows than parameters (n_rows = %zu, p = %td)",
                               n_rows, static_cast<std::ptrdiff_t>(p));
        const Eigen::MatrixXd R22 = R.bottomRightCorner(q, q).triangularView<Eigen::Upper>();
        return R22.transpose() * R22 / static_cast<double>(n_rows - static_cast<std::size_t>(p));
    }

    void reset() noexcept {
        R.setZero();
        n_rows = 0;
        sum_weights = 0.0;
    }

    const Index p;
    const Index q;
    const Index bmax;        // rows per merged block
    RowMatrix R;             // upper-triangular factor of [X Y] (weighted / whitened)
    Eigen::VectorXd block;   // bmax x (p + q) column-major scratch: the rows being merged
    Eigen::VectorXd sqrt_w;  // bmax square roots of the block's weights
    const vibid::kern::Table *kt;  // kernels for this CPU, fixed at create
    std::size_t n_rows = 0;
    double sum_weights = 0.0;
    double rank_tol = default_rank_tolerance;
};

using vibid::check_block;

extern "C" {

VIBID_API vibid_lsq *vibid_lsq_create(size_t n_params, size_t n_outputs) {
    return vibid::guard_create<vibid_lsq>(__func__, [&] {
        vibid::check_dimensions(n_params, n_outputs, max_dimension);
        return new vibid_lsq(n_params, n_outputs);
    });
}

VIBID_API vibid_status vibid_lsq_reset(vibid_lsq *lsq) {
    if (!lsq) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "lsq is NULL");
    lsq->reset();
    return VIBID_OK;
}

VIBID_API void vibid_lsq_destroy(vibid_lsq *lsq) {
    delete lsq;
}

VIBID_API vibid_status vibid_lsq_set_rank_tolerance(vibid_lsq *lsq, double tol) {
    if (!lsq) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "lsq is NULL");
    if (!(tol > 0.0 && tol < 1.0)) return VIBID_FAIL(VIBID_E_OUT_OF_RANGE, "tol = %g outside (0, 1)", tol);
    lsq->rank_tol = tol;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_lsq_add_rows(vibid_lsq *lsq, size_t n_rows, const double *X, const double *Y,
                                          const double *weights) {
    // Real-time path: no exceptions, no allocation. Everything is validated before
    // the first rotation so that a rejected call leaves R exactly as it was.
    if (!lsq) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "lsq is NULL");
    if (!X) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "X is NULL");
    if (!Y) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "Y is NULL");
    if (n_rows == 0) return VIBID_FAIL(VIBID_E_DIMENSION, "n_rows = 0, need at least 1");
    const std::size_t p = static_cast<std::size_t>(lsq->p);
    const std::size_t q = static_cast<std::size_t>(lsq->q);
    if (n_rows > SIZE_MAX / sizeof(double) / (p + q))
        return VIBID_FAIL(VIBID_E_DIMENSION, "n_rows = %zu too large", n_rows);
    vibid_status s = check_block(__func__, "X", X, n_rows, p);
    if (s != VIBID_OK) return s;
    s = check_block(__func__, "Y", Y, n_rows, q);
    if (s != VIBID_OK) return s;
    if (weights)
        for (std::size_t k = 0; k < n_rows; ++k) {
            if (!std::isfinite(weights[k]))
                return VIBID_FAIL(VIBID_E_NONFINITE, "weights[%zu] = %g is not finite", k, weights[k]);
            if (weights[k] < 0.0)
                return VIBID_FAIL(VIBID_E_OUT_OF_RANGE, "weights[%zu] = %g is negative", k, weights[k]);
        }
    const Index n = static_cast<Index>(n_rows);
    lsq->absorb_rows(n, X, Y, weights);
    return VIBID_OK;
}

VIBID_API vibid_status vibid_lsq_add_correlated(vibid_lsq *lsq, size_t n_rows, const double *X,
                                                const double *Y, const double *Sigma) {
    const char *const function = __func__;  // check_block runs inside the guard's lambda
    VIBID_GUARD({
        if (!lsq) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "lsq is NULL");
        if (!X) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "X is NULL");
        if (!Y) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "Y is NULL");
        if (!Sigma) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "Sigma is NULL");
        if (n_rows == 0) vibid::throw_error(VIBID_E_DIMENSION, "n_rows = 0, need at least 1");
        // Sigma is n_rows^2 doubles: keep that product from overflowing.
        if (n_rows > (std::size_t{1} << 26) || n_rows * n_rows > SIZE_MAX / sizeof(double))
            vibid::throw_error(VIBID_E_DIMENSION, "n_rows = %zu too large for a full covariance", n_rows);
        const Index n = static_cast<Index>(n_rows);
        vibid_status s;
        if ((s = check_block(function, "X", X, n_rows, static_cast<std::size_t>(lsq->p))) != VIBID_OK ||
            (s = check_block(function, "Y", Y, n_rows, static_cast<std::size_t>(lsq->q))) != VIBID_OK ||
            (s = check_block(function, "Sigma", Sigma, n_rows, n_rows)) != VIBID_OK)
            return s;
        const CMap S(Sigma, n, n);
        for (Index i = 0; i < n; ++i) {
            if (!(S(i, i) > 0.0))
                vibid::throw_error(VIBID_E_NUMERICAL, "Sigma[%td] (diagonal %td) = %g is not positive",
                                   static_cast<std::ptrdiff_t>(i + i * n), static_cast<std::ptrdiff_t>(i),
                                   S(i, i));
            for (Index j = 0; j < i; ++j) {
                // Relative to the geometric mean of the variances: a covariance only
                // means something at that scale.
                if (std::abs(S(i, j) - S(j, i)) > 1e-10 * std::sqrt(S(i, i) * S(j, j)))
                    vibid::throw_error(
                        VIBID_E_OUT_OF_RANGE,
                        "Sigma is not symmetric: Sigma(%td, %td) = %g but Sigma(%td, %td) = %g",
                        static_cast<std::ptrdiff_t>(i), static_cast<std::ptrdiff_t>(j), S(i, j),
                        static_cast<std::ptrdiff_t>(j), static_cast<std::ptrdiff_t>(i), S(j, i));
            }
        }
        Eigen::LLT<Eigen::MatrixXd> llt(S);
        if (llt.info() != Eigen::Success)
            vibid::throw_error(VIBID_E_NUMERICAL,
                               "Sigma (%zu x %zu) is not positive definite (Cholesky failed)", n_rows,
                               n_rows);
        // A pivot many orders below the largest means Sigma is positive definite only
        // by rounding: whitening would amplify noise by 1 / that pivot.
        const Eigen::VectorXd piv = llt.matrixLLT().diagonal();
        if (piv.minCoeff() <= 1e-7 * piv.maxCoeff())
            vibid::throw_error(VIBID_E_NUMERICAL,
                               "Sigma (%zu x %zu) is numerically singular (Cholesky pivot ratio %.3g)",
                               n_rows, n_rows, piv.minCoeff() / piv.maxCoeff());
        const Eigen::MatrixXd Xw = llt.matrixL().solve(CMap(X, n, lsq->p));
        const Eigen::MatrixXd Yw = llt.matrixL().solve(CMap(Y, n, lsq->q));
        if (!Xw.allFinite() || !Yw.allFinite())
            vibid::throw_error(VIBID_E_NUMERICAL, "whitened rows overflowed");
        lsq->absorb_rows(n, Xw.data(), Yw.data(), nullptr);
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_lsq_solve(const vibid_lsq *lsq, double *theta, vibid_lsq_info *info) {
    VIBID_GUARD({
        if (!lsq) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "lsq is NULL");
        if (!theta) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "theta is NULL");
        lsq->require_full_rank(info);
        const Eigen::MatrixXd T = lsq->R.topLeftCorner(lsq->p, lsq->p)
                                      .triangularView<Eigen::Upper>()
                                      .solve(lsq->R.topRightCorner(lsq->p, lsq->q));
        if (!T.allFinite()) vibid::throw_error(VIBID_E_NUMERICAL, "solution overflowed");
        Eigen::Map<Eigen::MatrixXd>(theta, lsq->p, lsq->q) = T;
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_lsq_covariance(const vibid_lsq *lsq, double *param_cov, double *residual_cov) {
    VIBID_GUARD({
        if (!lsq) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "lsq is NULL");
        if (!param_cov && !residual_cov)
            vibid::throw_error(VIBID_E_NULL_ARGUMENT, "param_cov and residual_cov are both NULL");
        lsq->require_full_rank(nullptr);
        // Compute both before writing either, so a failure writes nothing.
        Eigen::MatrixXd Rc;
        if (residual_cov) Rc = lsq->residual_cov();
        if (param_cov) Eigen::Map<Eigen::MatrixXd>(param_cov, lsq->p, lsq->p) = lsq->param_cov();
        if (residual_cov) Eigen::Map<Eigen::MatrixXd>(residual_cov, lsq->q, lsq->q) = Rc;
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_lsq_stderr(const vibid_lsq *lsq, double *stderr_out) {
    VIBID_GUARD({
        if (!lsq) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "lsq is NULL");
        if (!stderr_out) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "stderr_out is NULL");
        lsq->require_full_rank(nullptr);
        const Eigen::VectorXd rc = lsq->residual_cov().diagonal();
        const Eigen::VectorXd pc = lsq->param_cov().diagonal();
        Eigen::Map<Eigen::MatrixXd>(stderr_out, lsq->p, lsq->q) = (pc * rc.transpose()).cwiseSqrt();
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_lsq_null_space(const vibid_lsq *lsq, double *basis, size_t max_vectors,
                                            size_t *n_vectors) {
    VIBID_GUARD({
        if (!lsq) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "lsq is NULL");
        if (!n_vectors) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "n_vectors is NULL");
        if (!basis && max_vectors > 0)
            vibid::throw_error(VIBID_E_NULL_ARGUMENT, "basis is NULL but max_vectors = %zu", max_vectors);
        if (lsq->n_rows == 0)
            vibid::throw_error(VIBID_E_INSUFFICIENT_DATA, "no rows with weight > 0 added yet");
        const RankAnalysis a = lsq->analyse(true);
        const Index p = lsq->p;
        const Index n_null = p - a.rank;
        const Index n_out =
            std::min<Index>(n_null, static_cast<Index>(std::min<std::size_t>(max_vectors, p)));
        for (Index c = 0; c < n_out; ++c) {
            // Null vector v of R11 D^-1 maps to D^-1 v in the user's parameter units.
            Eigen::VectorXd v = a.V.col(a.rank + c).cwiseQuotient(a.scale);
            v.normalize();
            // Sign convention: the largest component positive, so results are reproducible.
            Index imax;
            v.cwiseAbs().maxCoeff(&imax);
            if (v[imax] < 0.0) v = -v;
            Eigen::Map<Eigen::VectorXd>(basis + c * p, p) = v;
        }
        *n_vectors = static_cast<std::size_t>(n_null);
        return VIBID_OK;
    });
}

}  // extern "C"
