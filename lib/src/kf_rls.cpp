// kf_rls.cpp: joint state and parameter estimation (paper (3.16): Kalman filter + RLS)
// and the extended Kalman filter on the augmented state (ref. [11]), behind the C API of
// vibid/kf_rls.h.
//
// Both methods share one Kalman core on dimension n_a (n for PAPER, n + n_free p for the
// EKF). A step computes the new state and covariance into scratch (xn_, Sn_), checks
// them (NIS, finiteness, limits), then runs the RLS step (PAPER; vibid_rls leaves itself
// unchanged when it fails) and only then commits by copying scratch into the state. A
// failing step therefore leaves the object unchanged.
//
// Per-step code allocates nothing: every matrix is sized in create, products are written
// as noalias() lazyProduct into preallocated storage (coefficient-based, no GEMM blocking
// workspace), and the small nz x nz innovation covariance is factored by a hand-written
// Cholesky.
#include <vibid/kf_rls.h>
#include <vibid/rls.h>

#include "api_guard.hpp"
#include "small_linalg.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>

namespace {

using Eigen::Index;
using vibid::chol_solve;
using vibid::cholesky;
using vibid::symmetrise;
using Mat = Eigen::MatrixXd;
using Vec = Eigen::VectorXd;
using CMapM = Eigen::Map<const Mat>;
using CMapV = Eigen::Map<const Vec>;

constexpr size_t kMaxStates = 32;
constexpr size_t kMaxInputs = 32;
constexpr double kSymTol = 1e-9;

#define KF_FAIL(status, ...) (::vibid::set_last_error(fn, __VA_ARGS__), (status))

bool symmetric(const double *a, Index n) {
    for (Index j = 0; j < n; ++j)
        for (Index i = 0; i < j; ++i) {
            const double tol = kSymTol * std::sqrt(std::fabs(a[i + i * n] * a[j + j * n])) + 1e-300;
            if (std::fabs(a[i + j * n] - a[j + i * n]) > tol) return false;
        }
    return true;
}

}  // namespace

struct vibid_kfrls {
    vibid_kfrls_config cfg;
    Index n, nz, r, ff, nf, p, na;
    Mat U, Rb, Rv;
    // state
    Mat G, H, S;
    Vec x;  // n_a
    bool started = false, have_start = false, diverged = false;
    double nis_avg = 1.0;
    unsigned long long n_steps = 0, n_missing = 0;
    // start copies
    Mat G0, H0, S0a, Pth0, Prls;
    Vec x0a;
    // scratch
    Mat F, T1, Sp, A, Sn, PUt, Lg, LRv, Sy;
    Vec xp, xn, nu, phi, yfree, theta;
    mutable Vec rls_se;  // scratch of the const getter vibid_kfrls_param_stderr
    vibid_rls *rls = nullptr;

    ~vibid_kfrls() { vibid_rls_destroy(rls); }

    // Writes the free rows of [G H] from theta (p x nf column-major, the RLS layout) or
    // from the augmented state (EKF layout: row by row).
    void model_from_rls() {
        for (Index i = 0; i < nf; ++i) {
            for (Index j = 0; j < n; ++j) G(ff + i, j) = theta(j + i * p);
            for (Index l = 0; l < r; ++l) H(ff + i, l) = theta(n + l + i * p);
        }
    }
    void model_from_state() {
        for (Index i = 0; i < nf; ++i) {
            for (Index j = 0; j < n; ++j) G(ff + i, j) = x(n + i * p + j);
            for (Index l = 0; l < r; ++l) H(ff + i, l) = x(n + i * p + n + l);
        }
    }

    vibid_status restart() {
        G = G0;
        H = H0;
        S = S0a;
        x = x0a;
        diverged = false;
        nis_avg = 1.0;
        n_steps = n_missing = 0;
        if (cfg.method == VIBID_KFRLS_PAPER) {
            for (Index i = 0; i < nf; ++i) {
                for (Index j = 0; j < n; ++j) theta(j + i * p) = G0(ff + i, j);
                for (Index l = 0; l < r; ++l) theta(n + l + i * p) = H0(ff + i, l);
            }
            double se2 = 0.0;
            for (Index i = ff; i < n; ++i) se2 += Rb(i, i);
            se2 /= static_cast<double>(nf);
            if (!(se2 > 0.0)) se2 = 1.0;
            Prls = Pth0 / se2;
            const vibid_status s = vibid_rls_set_prior(rls, theta.data(), Prls.data());
            if (s != VIBID_OK) return s;
        }
        started = true;
        return VIBID_OK;
    }
};

extern "C" {

void vibid_kfrls_config_init(vibid_kfrls_config *cfg, size_t n_states, size_t n_meas, size_t n_inputs) {
    if (!cfg) return;
    cfg->n_states = n_states;
    cfg->n_meas = n_meas;
    cfg->n_inputs = n_inputs;
    cfg->first_free_row = 0;
    cfg->method = VIBID_KFRLS_PAPER;
    cfg->forgetting = 1.0;
    cfg->param_noise = 0.0;
    cfg->nis_limit = 10.0;
    cfg->nis_memory = 0.98;
    cfg->state_limit = 1e12;
}

vibid_kfrls *vibid_kfrls_create(const vibid_kfrls_config *cfg, const double *U, const double *R_b,
                                const double *R_v) {
    return vibid::guard_create<vibid_kfrls>(__func__, [&]() -> vibid_kfrls * {
        if (!cfg || !U || !R_b || !R_v) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "cfg, U, R_b or R_v is NULL");
        const size_t n = cfg->n_states, nz = cfg->n_meas, r = cfg->n_inputs;
        if (n < 1 || n > kMaxStates) vibid::throw_error(VIBID_E_DIMENSION, "n_states = %zu outside 1..%zu", n, kMaxStates);
        if (nz < 1 || nz > n) vibid::throw_error(VIBID_E_DIMENSION, "n_meas = %zu outside 1..n_states", nz);
        if (r > kMaxInputs) vibid::throw_error(VIBID_E_DIMENSION, "n_inputs = %zu outside 0..%zu", r, kMaxInputs);
        if (cfg->first_free_row >= n)
            vibid::throw_error(VIBID_E_DIMENSION, "first_free_row = %zu not below n_states", cfg->first_free_row);
        const int method = vibid::enum_value(cfg->method);
        if (method != VIBID_KFRLS_PAPER && method != VIBID_KFRLS_EKF)
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "method = %d unknown", method);
        if (!(cfg->forgetting > 0.0 && cfg->forgetting <= 1.0))
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "forgetting = %g outside (0, 1]", cfg->forgetting);
        if (!(cfg->param_noise >= 0.0) || !std::isfinite(cfg->param_noise))
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "param_noise = %g not >= 0", cfg->param_noise);
        if (!(cfg->nis_limit > 1.0)) vibid::throw_error(VIBID_E_OUT_OF_RANGE, "nis_limit = %g not > 1", cfg->nis_limit);
        if (!(cfg->nis_memory > 0.0 && cfg->nis_memory < 1.0))
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "nis_memory = %g outside (0, 1)", cfg->nis_memory);
        if (!(cfg->state_limit > 0.0))
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "state_limit = %g not > 0", cfg->state_limit);
        if (!vibid::all_finite(U, nz * n) || !vibid::all_finite(R_b, n * n) || !vibid::all_finite(R_v, nz * nz))
            vibid::throw_error(VIBID_E_NONFINITE, "NaN/Inf in U, R_b or R_v");
        if (!symmetric(R_b, static_cast<Index>(n)) || !symmetric(R_v, static_cast<Index>(nz)))
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "R_b or R_v not symmetric");
        for (size_t i = 0; i < n; ++i)
            if (R_b[i + i * n] < 0.0) vibid::throw_error(VIBID_E_OUT_OF_RANGE, "R_b(%zu,%zu) < 0", i, i);
        for (size_t i = 0; i < nz; ++i)
            if (R_v[i + i * nz] < 0.0) vibid::throw_error(VIBID_E_OUT_OF_RANGE, "R_v(%zu,%zu) < 0", i, i);

        auto *k = new vibid_kfrls;
        k->cfg = *cfg;
        k->n = static_cast<Index>(n);
        k->nz = static_cast<Index>(nz);
        k->r = static_cast<Index>(r);
        k->ff = static_cast<Index>(cfg->first_free_row);
        k->nf = k->n - k->ff;
        k->p = k->n + k->r;
        k->na = cfg->method == VIBID_KFRLS_EKF ? k->n + k->nf * k->p : k->n;
        const Index na = k->na;
        k->U = CMapM(U, k->nz, k->n);
        k->Rb = CMapM(R_b, k->n, k->n);
        k->Rv = CMapM(R_v, k->nz, k->nz);
        k->G = Mat::Zero(k->n, k->n);
        k->H = Mat::Zero(k->n, k->r);
        k->S = Mat::Zero(na, na);
        k->x = Vec::Zero(na);
        k->G0 = k->G;
        k->H0 = k->H;
        k->S0a = k->S;
        k->x0a = k->x;
        k->Pth0 = Mat::Identity(k->p, k->p);
        k->Prls = k->Pth0;
        for (Mat *m : {&k->F, &k->T1, &k->Sp, &k->A, &k->Sn}) m->setZero(na, na);
        for (Mat *m : {&k->PUt, &k->Lg, &k->LRv}) m->setZero(na, k->nz);
        k->Sy.setZero(k->nz, k->nz);
        for (Vec *v : {&k->xp, &k->xn}) v->setZero(na);
        k->nu.setZero(k->nz);
        k->phi.setZero(k->p);
        k->yfree.setZero(k->nf);
        k->theta.setZero(k->p * k->nf);
        k->rls_se.setZero(k->p * k->nf);
        if (cfg->method == VIBID_KFRLS_PAPER) {
            vibid_rls_config rc;
            vibid_rls_config_init(&rc, static_cast<size_t>(k->p), static_cast<size_t>(k->nf));
            rc.forgetting = cfg->forgetting;
            k->rls = vibid_rls_create(&rc);
            if (!k->rls) {
                delete k;
                vibid::throw_error(VIBID_E_NO_MEMORY, "RLS: %s", vibid_last_error());
            }
        }
        return k;
    });
}

void vibid_kfrls_destroy(vibid_kfrls *kf) { delete kf; }

vibid_status vibid_kfrls_start(vibid_kfrls *kf, const double *G0, const double *H0, const double *x0,
                               const double *S0, const double *P_theta0) {
    VIBID_GUARD({
        if (!kf || !G0 || !S0 || !P_theta0)
            vibid::throw_error(VIBID_E_NULL_ARGUMENT, "kf, G0, S0 or P_theta0 is NULL");
        const Index n = kf->n, r = kf->r, p = kf->p;
        const size_t un = static_cast<size_t>(n), ur = static_cast<size_t>(r), up = static_cast<size_t>(p);
        if (!vibid::all_finite(G0, un * un) || !vibid::all_finite(S0, un * un) ||
            !vibid::all_finite(P_theta0, up * up) || (H0 && r > 0 && !vibid::all_finite(H0, un * ur)) ||
            (x0 && !vibid::all_finite(x0, un)))
            vibid::throw_error(VIBID_E_NONFINITE, "NaN/Inf in the start values");
        if (!symmetric(S0, n) || !symmetric(P_theta0, p))
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "S0 or P_theta0 not symmetric");
        for (Index i = 0; i < n; ++i)
            if (S0[i + i * n] < 0.0) vibid::throw_error(VIBID_E_OUT_OF_RANGE, "S0(%ld,%ld) < 0", long(i), long(i));
        Mat Pc = CMapM(P_theta0, p, p);
        if (!cholesky(Pc)) vibid::throw_error(VIBID_E_NUMERICAL, "P_theta0 not positive definite");
        // Validated: build the start state.
        kf->G0 = CMapM(G0, n, n);
        if (H0 && r > 0)
            kf->H0 = CMapM(H0, n, r);
        else
            kf->H0.setZero();
        kf->Pth0 = CMapM(P_theta0, p, p);
        symmetrise(kf->Pth0);
        kf->S0a.setZero();
        kf->S0a.topLeftCorner(n, n) = CMapM(S0, n, n);
        symmetrise(kf->S0a);
        kf->x0a.setZero();
        if (x0) kf->x0a.head(n) = CMapV(x0, n);
        if (kf->cfg.method == VIBID_KFRLS_EKF) {
            for (Index i = 0; i < kf->nf; ++i) {
                kf->S0a.block(n + i * p, n + i * p, p, p) = kf->Pth0;
                for (Index j = 0; j < n; ++j) kf->x0a(n + i * p + j) = kf->G0(kf->ff + i, j);
                for (Index l = 0; l < r; ++l) kf->x0a(n + i * p + n + l) = kf->H0(kf->ff + i, l);
            }
        }
        const vibid_status s = kf->restart();
        kf->have_start = s == VIBID_OK;
        if (s != VIBID_OK) {
            kf->started = false;
            vibid::throw_error(s, "RLS prior: %s", vibid_last_error());
        }
        return VIBID_OK;
    });
}

vibid_status vibid_kfrls_reset(vibid_kfrls *kf) {
    const char *fn = __func__;
    if (!kf) return KF_FAIL(VIBID_E_NULL_ARGUMENT, "kf is NULL");
    if (!kf->have_start)
        return KF_FAIL(VIBID_E_STATE, "never started");
    return kf->restart();
}

vibid_status vibid_kfrls_step(vibid_kfrls *kf, const double *u, const double *z_next) {
    const char *fn = __func__;
    if (!kf) return KF_FAIL(VIBID_E_NULL_ARGUMENT, "kf is NULL");
    vibid_kfrls &k = *kf;
    if (!k.started) return KF_FAIL(VIBID_E_STATE, "not started (call vibid_kfrls_start)");
    if (k.diverged) return KF_FAIL(VIBID_E_DIVERGED, "diverged earlier; restart with vibid_kfrls_start/reset");
    const Index n = k.n, nz = k.nz, r = k.r, na = k.na, p = k.p, nf = k.nf, ff = k.ff;
    if (r > 0 && !u) return KF_FAIL(VIBID_E_NULL_ARGUMENT, "u is NULL with n_inputs = %ld", long(r));
    if (r > 0 && !vibid::all_finite(u, static_cast<size_t>(r))) return KF_FAIL(VIBID_E_NONFINITE, "NaN/Inf in u");
    if (z_next && !vibid::all_finite(z_next, static_cast<size_t>(nz)))
        return KF_FAIL(VIBID_E_NONFINITE, "NaN/Inf in z (sample rejected; pass NULL for a missing sample)");
    const bool ekf = k.cfg.method == VIBID_KFRLS_EKF;

    // Regressor phi = [x_{k|k}; u_k].
    k.phi.head(n) = k.x.head(n);
    for (Index l = 0; l < r; ++l) k.phi(n + l) = u[l];

    // Prediction x* = G x + H u (parameters constant), F = d x* / d [x; theta].
    k.xp.head(n).noalias() = k.G.lazyProduct(k.x.head(n));
    if (r > 0) k.xp.head(n).noalias() += k.H.lazyProduct(k.phi.tail(r));
    if (ekf) k.xp.tail(na - n) = k.x.tail(na - n);
    k.F.setZero();
    k.F.topLeftCorner(n, n) = k.G;
    if (ekf) {
        for (Index i = 0; i < nf; ++i)
            for (Index j = 0; j < p; ++j) k.F(ff + i, n + i * p + j) = k.phi(j);
        for (Index i = n; i < na; ++i) k.F(i, i) = 1.0;
    }
    k.T1.noalias() = k.F.lazyProduct(k.S);
    k.Sp.noalias() = k.T1.lazyProduct(k.F.transpose());
    k.Sp.topLeftCorner(n, n) += k.Rb;
    if (ekf)
        for (Index i = n; i < na; ++i) k.Sp(i, i) += k.cfg.param_noise;
    symmetrise(k.Sp);

    double nis_avg = k.nis_avg;
    if (z_next) {
        // Innovation and its covariance Sy = U S*_xx U^T + R_v.
        for (Index i = 0; i < nz; ++i) k.nu(i) = z_next[i];
        k.nu.noalias() -= k.U.lazyProduct(k.xp.head(n));
        k.PUt.noalias() = k.Sp.leftCols(n).lazyProduct(k.U.transpose());
        k.Sy.noalias() = k.U.lazyProduct(k.PUt.topRows(n));
        k.Sy += k.Rv;
        if (!cholesky(k.Sy)) return KF_FAIL(VIBID_E_NUMERICAL, "innovation covariance not positive definite");
        // Gain L = PUt Sy^-1, row by row (Lg is column-major: copy each row through xn).
        for (Index i = 0; i < na; ++i) {
            for (Index j = 0; j < nz; ++j) k.xn(j) = k.PUt(i, j);
            chol_solve(k.Sy, k.xn.data());
            for (Index j = 0; j < nz; ++j) k.Lg(i, j) = k.xn(j);
        }
        // NIS = nu^T Sy^-1 nu per measurement.
        for (Index j = 0; j < nz; ++j) k.xn(j) = k.nu(j);
        const double nis = chol_solve(k.Sy, k.xn.data()) / static_cast<double>(nz);
        nis_avg = k.cfg.nis_memory * nis_avg + (1.0 - k.cfg.nis_memory) * nis;
        // x+ = x* + L nu; Joseph form S = A S* A^T + L R_v L^T with A = I - L [U 0].
        k.xn = k.xp;
        k.xn.noalias() += k.Lg.lazyProduct(k.nu);
        k.A.setIdentity();
        k.A.leftCols(n).noalias() -= k.Lg.lazyProduct(k.U);
        k.T1.noalias() = k.A.lazyProduct(k.Sp);
        k.Sn.noalias() = k.T1.lazyProduct(k.A.transpose());
        k.LRv.noalias() = k.Lg.lazyProduct(k.Rv);
        k.Sn.noalias() += k.LRv.lazyProduct(k.Lg.transpose());
        symmetrise(k.Sn);
    } else {
        k.xn = k.xp;
        k.Sn = k.Sp;
    }

    // Divergence checks on the candidate state.
    const double lim = k.cfg.state_limit;
    bool bad = !(nis_avg <= k.cfg.nis_limit);
    const char *why = "averaged NIS above nis_limit";
    if (!bad) {
        for (Index i = 0; i < na && !bad; ++i)
            if (!(std::fabs(k.xn(i)) <= lim) || !(k.Sn(i, i) >= 0.0) || !(k.Sn(i, i) <= lim * lim)) bad = true;
        if (!bad && !k.Sn.allFinite()) bad = true;
        why = "state or covariance non-finite, negative or beyond state_limit";
    }
    if (bad) {
        k.diverged = true;
        return KF_FAIL(VIBID_E_DIVERGED, "diverged after %llu steps: %s (NIS avg %g)", k.n_steps, why, nis_avg);
    }

    if (!ekf && z_next) {
        // RLS on [G H]: regressor [x_{k|k}; u_k], target the free rows of x_{k+1|k+1}.
        k.yfree = k.xn.segment(ff, nf);
        const vibid_status s = vibid_rls_update(k.rls, k.phi.data(), k.yfree.data());
        if (s != VIBID_OK) return s;  // RLS unchanged, its message already recorded
        vibid_rls_theta(k.rls, k.theta.data());
    }
    // Commit.
    k.x = k.xn;
    k.S = k.Sn;
    k.nis_avg = nis_avg;
    ++k.n_steps;
    if (!z_next) ++k.n_missing;
    if (ekf)
        k.model_from_state();
    else if (z_next)
        k.model_from_rls();
    return VIBID_OK;
}

vibid_status vibid_kfrls_state(const vibid_kfrls *kf, double *x, double *S) {
    const char *fn = __func__;
    if (!kf) return KF_FAIL(VIBID_E_NULL_ARGUMENT, "kf is NULL");
    const Index n = kf->n;
    if (x)
        for (Index i = 0; i < n; ++i) x[i] = kf->x(i);
    if (S)
        for (Index j = 0; j < n; ++j)
            for (Index i = 0; i < n; ++i) S[i + j * n] = kf->S(i, j);
    return VIBID_OK;
}

vibid_status vibid_kfrls_model(const vibid_kfrls *kf, double *G, double *H) {
    const char *fn = __func__;
    if (!kf) return KF_FAIL(VIBID_E_NULL_ARGUMENT, "kf is NULL");
    const Index n = kf->n, r = kf->r;
    if (G)
        for (Index j = 0; j < n; ++j)
            for (Index i = 0; i < n; ++i) G[i + j * n] = kf->G(i, j);
    if (H)
        for (Index j = 0; j < r; ++j)
            for (Index i = 0; i < n; ++i) H[i + j * n] = kf->H(i, j);
    return VIBID_OK;
}

vibid_status vibid_kfrls_param_stderr(const vibid_kfrls *kf, double *se) {
    const char *fn = __func__;
    if (!kf || !se) return KF_FAIL(VIBID_E_NULL_ARGUMENT, "kf or se is NULL");
    const Index nf = kf->nf, p = kf->p, n = kf->n;
    if (kf->cfg.method == VIBID_KFRLS_EKF) {
        for (Index i = 0; i < nf; ++i)
            for (Index j = 0; j < p; ++j) {
                const Index a = n + i * p + j;
                se[i + j * nf] = std::sqrt(std::max(0.0, kf->S(a, a)));
            }
        return VIBID_OK;
    }
    const vibid_status s = vibid_rls_stderr(kf->rls, kf->rls_se.data());
    if (s != VIBID_OK) return s;
    for (Index i = 0; i < nf; ++i)
        for (Index j = 0; j < p; ++j) se[i + j * nf] = kf->rls_se(j + i * p);
    return VIBID_OK;
}

vibid_status vibid_kfrls_get_stats(const vibid_kfrls *kf, vibid_kfrls_stats *stats) {
    const char *fn = __func__;
    if (!kf || !stats) return KF_FAIL(VIBID_E_NULL_ARGUMENT, "kf or stats is NULL");
    stats->n_steps = kf->n_steps;
    stats->n_missing = kf->n_missing;
    stats->nis_avg = kf->nis_avg;
    stats->diverged = kf->diverged ? 1 : 0;
    return VIBID_OK;
}

}  // extern "C"
