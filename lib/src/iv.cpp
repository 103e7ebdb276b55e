// iv.cpp: instrumental variables (paper (2.13)-(2.15)), batch and recursive.
//
// The batch estimate (W^T S X)^-1 W^T S Y is a cross-product estimator: unlike LS it
// has no orthogonal-factorisation shortcut over the rows, because the "normal matrix"
// W^T X is not symmetric. What keeps it honest is a rank-revealing solve: W^T X is
// scaled by the column norms of W and X (equivalent to unit-norm instruments and
// regressors, so parameter units do not fake a rank loss) before its SVD.
#include <vibid/iv.h>

#include "api_guard.hpp"

#include <Eigen/Core>
#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace {

using Eigen::Index;
using CMap = Eigen::Map<const Eigen::MatrixXd>;
using CVecMap = Eigen::Map<const Eigen::VectorXd>;

constexpr std::size_t max_batch_dimension = 4096;
constexpr std::size_t max_recursive_dimension = 1024;
constexpr double iv_rank_tolerance = 1e-10;
constexpr double default_alpha = 1e-6;

using vibid::check_block;

// Scaled, rank-revealing factorisation of W^T S X.
struct IvSolve {
    Eigen::BDCSVD<Eigen::MatrixXd> svd;
    Eigen::VectorXd row_scale;  // instrument column norms
    Eigen::VectorXd col_scale;  // regressor column norms
    Index rank = 0;
    double rcond = 0.0;
};

}  // namespace

struct vibid_iv {
    vibid_iv(std::size_t n_params, std::size_t n_outputs)
        : p(static_cast<Index>(n_params)), q(static_cast<Index>(n_outputs)) {
        WtX.setZero(p, p);
        WtW.setZero(p, p);
        WtY.setZero(p, q);
        XtX.setZero(p, p);
        XtY.setZero(p, q);
        YtY.setZero(q, q);
        x.setZero(p);
        w.setZero(p);
        y.setZero(q);
        xs.setZero(p);
        ws.setZero(p);
        ys.setZero(q);
    }

    void reset() noexcept {
        WtX.setZero();
        WtW.setZero();
        WtY.setZero();
        XtX.setZero();
        XtY.setZero();
        YtY.setZero();
        n_rows = 0;
        sum_weights = 0.0;
    }

    IvSolve factor(vibid_lsq_info *info) const {
        if (n_rows == 0) vibid::throw_error(VIBID_E_INSUFFICIENT_DATA, "no rows with weight > 0 added yet");
        IvSolve f;
        f.row_scale = WtW.diagonal().cwiseSqrt();
        f.col_scale = XtX.diagonal().cwiseSqrt();
        for (Index i = 0; i < p; ++i) {
            if (f.row_scale[i] == 0.0) f.row_scale[i] = 1.0;
            if (f.col_scale[i] == 0.0) f.col_scale[i] = 1.0;
        }
        const Eigen::MatrixXd As =
            f.row_scale.cwiseInverse().asDiagonal() * WtX * f.col_scale.cwiseInverse().asDiagonal();
        if (!As.allFinite()) vibid::throw_error(VIBID_E_NUMERICAL, "accumulated cross products overflowed");
        f.svd.compute(As, Eigen::ComputeFullU | Eigen::ComputeFullV);
        const Eigen::VectorXd &sv = f.svd.singularValues();
        const double smax = sv[0];
        for (Index i = 0; i < p; ++i)
            if (sv[i] > iv_rank_tolerance * smax) ++f.rank;
        f.rcond = smax > 0.0 ? sv[p - 1] / smax : 0.0;
        if (info) {
            info->n_rows = n_rows;
            info->rank = static_cast<std::size_t>(f.rank);
            info->rcond = f.rcond;
            info->sum_weights = sum_weights;
        }
        if (f.rank < p)
            vibid::throw_error(
                VIBID_E_NOT_IDENTIFIABLE,
                "W^T X has numerical rank %td of %td (rcond %.3g): instruments do not determine "
                "all parameters",
                static_cast<std::ptrdiff_t>(f.rank), static_cast<std::ptrdiff_t>(p), f.rcond);
        return f;
    }

    // (W^T X)^-1 B = Dc^-1 As^-1 Dr^-1 B with As = Dr^-1 W^T X Dc^-1.
    static Eigen::MatrixXd apply_inverse(const IvSolve &f, const Eigen::MatrixXd &B) {
        return f.col_scale.cwiseInverse().asDiagonal() *
               f.svd.solve(f.row_scale.cwiseInverse().asDiagonal() * B);
    }

    const Index p;
    const Index q;
    // Weighted cross products. X^T X, X^T Y, Y^T Y give the residual variance at any
    // estimate without storing the rows.
    Eigen::MatrixXd WtX, WtW, WtY, XtX, XtY, YtY;
    // Scratch for one row and its weighted copy: outer products of plain vectors
    // need no temporaries, so adding rows allocates nothing.
    Eigen::VectorXd x, w, y, xs, ws, ys;
    std::size_t n_rows = 0;
    double sum_weights = 0.0;
};

struct vibid_riv {
    explicit vibid_riv(const vibid_riv_config &c)
        : cfg(c), p(static_cast<Index>(c.n_params)), q(static_cast<Index>(c.n_outputs)) {
        theta0.setZero(p, q);
        P0 = Eigen::MatrixXd::Identity(p, p) / cfg.alpha;
        theta = theta0;
        P = P0;
        Pw.setZero(p);
        xP.setZero(p);
        err.setZero(q);
    }

    vibid_riv_config cfg;
    const Index p;
    const Index q;
    Eigen::MatrixXd theta0, P0;  // what reset returns to
    Eigen::MatrixXd theta, P;
    Eigen::VectorXd Pw, xP, err;  // scratch, so that update allocates nothing
};

extern "C" {

/* ---------------- batch IV ---------------- */

VIBID_API vibid_iv *vibid_iv_create(size_t n_params, size_t n_outputs) {
    return vibid::guard_create<vibid_iv>(__func__, [&] {
        vibid::check_dimensions(n_params, n_outputs, max_batch_dimension);
        return new vibid_iv(n_params, n_outputs);
    });
}

VIBID_API vibid_status vibid_iv_reset(vibid_iv *iv) {
    if (!iv) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "iv is NULL");
    iv->reset();
    return VIBID_OK;
}

VIBID_API void vibid_iv_destroy(vibid_iv *iv) {
    delete iv;
}

VIBID_API vibid_status vibid_iv_add_rows(vibid_iv *iv, size_t n_rows, const double *X, const double *W,
                                         const double *Y, const double *weights) {
    // Real-time path: validate everything first (state untouched on error), then
    // rank-one updates through preallocated row vectors (no temporaries).
    if (!iv) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "iv is NULL");
    if (!X) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "X is NULL");
    if (!W) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "W is NULL");
    if (!Y) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "Y is NULL");
    if (n_rows == 0) return VIBID_FAIL(VIBID_E_DIMENSION, "n_rows = 0, need at least 1");
    const std::size_t p = static_cast<std::size_t>(iv->p);
    const std::size_t q = static_cast<std::size_t>(iv->q);
    if (n_rows > SIZE_MAX / sizeof(double) / (p + q))
        return VIBID_FAIL(VIBID_E_DIMENSION, "n_rows = %zu too large", n_rows);
    vibid_status s;
    if ((s = check_block(__func__, "X", X, n_rows, p)) != VIBID_OK) return s;
    if ((s = check_block(__func__, "W", W, n_rows, p)) != VIBID_OK) return s;
    if ((s = check_block(__func__, "Y", Y, n_rows, q)) != VIBID_OK) return s;
    if (weights)
        for (std::size_t k = 0; k < n_rows; ++k) {
            if (!std::isfinite(weights[k]))
                return VIBID_FAIL(VIBID_E_NONFINITE, "weights[%zu] = %g is not finite", k, weights[k]);
            if (weights[k] < 0.0)
                return VIBID_FAIL(VIBID_E_OUT_OF_RANGE, "weights[%zu] = %g is negative", k, weights[k]);
        }
    const Index n = static_cast<Index>(n_rows);
    const CMap Xm(X, n, iv->p), Wm(W, n, iv->p), Ym(Y, n, iv->q);
    for (Index k = 0; k < n; ++k) {
        const double wt = weights ? weights[k] : 1.0;
        if (wt == 0.0) continue;
        iv->x.noalias() = Xm.row(k).transpose();
        iv->w.noalias() = Wm.row(k).transpose();
        iv->y.noalias() = Ym.row(k).transpose();
        iv->xs.noalias() = wt * iv->x;
        iv->ws.noalias() = wt * iv->w;
        iv->ys.noalias() = wt * iv->y;
        iv->WtX.noalias() += iv->ws * iv->x.transpose();
        iv->WtW.noalias() += iv->ws * iv->w.transpose();
        iv->WtY.noalias() += iv->ws * iv->y.transpose();
        iv->XtX.noalias() += iv->xs * iv->x.transpose();
        iv->XtY.noalias() += iv->xs * iv->y.transpose();
        iv->YtY.noalias() += iv->ys * iv->y.transpose();
        ++iv->n_rows;
        iv->sum_weights += wt;
    }
    return VIBID_OK;
}

VIBID_API vibid_status vibid_iv_solve(const vibid_iv *iv, double *theta, vibid_lsq_info *info) {
    VIBID_GUARD({
        if (!iv) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "iv is NULL");
        if (!theta) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "theta is NULL");
        const IvSolve f = iv->factor(info);
        const Eigen::MatrixXd T = vibid_iv::apply_inverse(f, iv->WtY);
        if (!T.allFinite()) vibid::throw_error(VIBID_E_NUMERICAL, "solution overflowed");
        Eigen::Map<Eigen::MatrixXd>(theta, iv->p, iv->q) = T;
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_iv_stderr(const vibid_iv *iv, double *stderr_out) {
    VIBID_GUARD({
        if (!iv) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "iv is NULL");
        if (!stderr_out) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "stderr_out is NULL");
        const IvSolve f = iv->factor(nullptr);
        if (iv->n_rows <= static_cast<std::size_t>(iv->p))
            vibid::throw_error(VIBID_E_INSUFFICIENT_DATA,
                               "standard errors need more rows than parameters (n_rows = %zu, p = %td)",
                               iv->n_rows, static_cast<std::ptrdiff_t>(iv->p));
        const Eigen::MatrixXd T = vibid_iv::apply_inverse(f, iv->WtY);
        // E^T S E from the cross products; rounding can push a tiny diagonal below 0.
        const Eigen::MatrixXd XtYT = iv->XtY.transpose() * T;
        const Eigen::VectorXd ss =
            (iv->YtY - XtYT - XtYT.transpose() + T.transpose() * iv->XtX * T).diagonal();
        const Eigen::VectorXd sigma2 =
            ss.cwiseMax(0.0) / static_cast<double>(iv->n_rows - static_cast<std::size_t>(iv->p));
        // (W^T X)^-1 (W^T W) (X^T W)^-1
        const Eigen::MatrixXd M = vibid_iv::apply_inverse(f, Eigen::MatrixXd::Identity(iv->p, iv->p));
        const Eigen::VectorXd c = (M * iv->WtW * M.transpose()).diagonal().cwiseMax(0.0);
        Eigen::Map<Eigen::MatrixXd>(stderr_out, iv->p, iv->q) = (c * sigma2.transpose()).cwiseSqrt();
        return VIBID_OK;
    });
}

/* ---------------- recursive IV ---------------- */

VIBID_API void vibid_riv_config_init(vibid_riv_config *cfg, size_t n_params, size_t n_outputs) {
    if (!cfg) return;
    cfg->n_params = n_params;
    cfg->n_outputs = n_outputs;
    cfg->forgetting = 1.0;
    cfg->alpha = default_alpha;
    cfg->trace_bound = 0;
    cfg->trace_max = static_cast<double>(n_params) / default_alpha;
}

VIBID_API vibid_riv *vibid_riv_create(const vibid_riv_config *cfg) {
    return vibid::guard_create<vibid_riv>(__func__, [&] {
        if (!cfg) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "cfg is NULL");
        if (cfg->n_params == 0 || cfg->n_params > max_recursive_dimension)
            vibid::throw_error(VIBID_E_DIMENSION, "n_params = %zu outside 1..%zu", cfg->n_params,
                               max_recursive_dimension);
        if (cfg->n_outputs == 0 || cfg->n_outputs > max_recursive_dimension)
            vibid::throw_error(VIBID_E_DIMENSION, "n_outputs = %zu outside 1..%zu", cfg->n_outputs,
                               max_recursive_dimension);
        if (!(cfg->forgetting > 0.0 && cfg->forgetting <= 1.0))
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "forgetting = %g outside (0, 1]", cfg->forgetting);
        if (!(cfg->alpha > 0.0 && std::isfinite(cfg->alpha)))
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "alpha = %g must be positive and finite", cfg->alpha);
        if (!std::isfinite(1.0 / cfg->alpha))
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "alpha = %g too small: P0 = alpha^-1 I overflows",
                               cfg->alpha);
        if (cfg->trace_bound && !(cfg->trace_max > 0.0 && std::isfinite(cfg->trace_max)))
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "trace_max = %g must be positive and finite",
                               cfg->trace_max);
        return new vibid_riv(*cfg);
    });
}

VIBID_API vibid_status vibid_riv_reset(vibid_riv *riv) {
    if (!riv) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "riv is NULL");
    riv->theta = riv->theta0;
    riv->P = riv->P0;
    return VIBID_OK;
}

VIBID_API void vibid_riv_destroy(vibid_riv *riv) {
    delete riv;
}

VIBID_API vibid_status vibid_riv_set_prior(vibid_riv *riv, const double *theta0, const double *P0) {
    if (!riv) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "riv is NULL");
    const std::size_t p = static_cast<std::size_t>(riv->p);
    const std::size_t q = static_cast<std::size_t>(riv->q);
    vibid_status s;
    if (theta0 && (s = check_block(__func__, "theta0", theta0, p, q)) != VIBID_OK) return s;
    if (P0 && (s = check_block(__func__, "P0", P0, p, p)) != VIBID_OK) return s;
    if (theta0)
        riv->theta0 = CMap(theta0, riv->p, riv->q);
    else
        riv->theta0.setZero();
    if (P0)
        riv->P0 = CMap(P0, riv->p, riv->p);
    else
        riv->P0.setIdentity() /= riv->cfg.alpha;
    riv->theta = riv->theta0;
    riv->P = riv->P0;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_riv_update(vibid_riv *riv, const double *x, const double *w, const double *y) {
    // Real-time path: no exceptions, no allocation; every quantity that could fail is
    // computed into scratch before theta or P is touched.
    if (!riv) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "riv is NULL");
    if (!x) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "x is NULL");
    if (!w) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "w is NULL");
    if (!y) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "y is NULL");
    const Index p = riv->p;
    const Index q = riv->q;
    vibid_status s;
    if ((s = check_block(__func__, "x", x, static_cast<std::size_t>(p), 1)) != VIBID_OK) return s;
    if ((s = check_block(__func__, "w", w, static_cast<std::size_t>(p), 1)) != VIBID_OK) return s;
    if ((s = check_block(__func__, "y", y, static_cast<std::size_t>(q), 1)) != VIBID_OK) return s;
    const CVecMap xv(x, p), wv(w, p), yv(y, q);

    riv->Pw.noalias() = riv->P * wv;
    riv->xP.noalias() = riv->P.transpose() * xv;  // (x^T P)^T
    const double c = xv.dot(riv->Pw);             // x^T P w
    double gamma = riv->cfg.forgetting;
    if (riv->cfg.trace_bound && gamma < 1.0) {
        // trace(P_new(g)) = (T - t1 / (g + c)) / g with T = trace(P), t1 = x^T P P w.
        // Lower the forgetting (raise g toward 1) just enough that |trace| stays below
        // trace_max: the largest root of tmax g^2 + (tmax c - T) g + (t1 - T c) = 0.
        const double T = riv->P.trace();
        const double t1 = riv->xP.dot(riv->Pw);
        const double tmax = riv->cfg.trace_max;
        const double trace_new = (T - t1 / (gamma + c)) / gamma;
        if (!(std::abs(trace_new) <= tmax)) {
            const double b = tmax * c - T;
            const double disc = b * b - 4.0 * tmax * (t1 - T * c);
            const double g = disc >= 0.0 ? (-b + std::sqrt(disc)) / (2.0 * tmax) : 1.0;
            gamma = std::min(1.0, std::max(gamma, g));
        }
    }
    const double denom = gamma + c;
    // For IV, x^T P w has no sign guarantee; a denominator lost in rounding would
    // blow theta up, so refuse the sample instead.
    if (!std::isfinite(denom) || std::abs(denom) <= 1e-12 * (gamma + std::abs(c)))
        return VIBID_FAIL(VIBID_E_NUMERICAL, "gamma + x^T P w = %g is numerically zero; sample ignored",
                          denom);
    riv->err = yv;
    riv->err.noalias() -= riv->theta.transpose() * xv;
    // K = P w / denom (in place); Theta += K e^T; P = (P - K x^T P) / gamma.
    riv->Pw /= denom;
    riv->theta.noalias() += riv->Pw * riv->err.transpose();
    riv->P.noalias() -= riv->Pw * riv->xP.transpose();
    if (gamma != 1.0) riv->P /= gamma;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_riv_theta(const vibid_riv *riv, double *theta) {
    if (!riv) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "riv is NULL");
    if (!theta) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "theta is NULL");
    Eigen::Map<Eigen::MatrixXd>(theta, riv->p, riv->q) = riv->theta;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_riv_covariance(const vibid_riv *riv, double *P) {
    if (!riv) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "riv is NULL");
    if (!P) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "P is NULL");
    Eigen::Map<Eigen::MatrixXd>(P, riv->p, riv->p) = riv->P;
    return VIBID_OK;
}

}  // extern "C"
