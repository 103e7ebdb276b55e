// discretize.cpp: zero-order hold (1.9)-(1.14) by the augmented matrix exponential, the
// second-order difference form (1.16), and the way back by the matrix logarithm.
#include <vibid/discretize.h>

#include "api_guard.hpp"
#include "discretize_internal.hpp"

#include <unsupported/Eigen/MatrixFunctions>

#include <cmath>
#include <complex>

using Eigen::MatrixXd;
using vibid::throw_error;

namespace vibid {

void zoh(const MatrixXd &A, const MatrixXd &Bv, double h, MatrixXd &G, MatrixXd &Gamma) {
    const Eigen::Index n = A.rows(), r = Bv.cols();
    // exp([A Bv; 0 0] h) = [e^{Ah}  int_0^h e^{At} dt Bv; 0 I]: no inverse of A needed.
    MatrixXd aug = MatrixXd::Zero(n + r, n + r);
    aug.topLeftCorner(n, n) = A * h;
    if (r) aug.topRightCorner(n, r) = Bv * h;
    const MatrixXd e = aug.exp();
    G = e.topLeftCorner(n, n);
    Gamma = e.topRightCorner(n, r);
}

void zoh_inverse(const MatrixXd &G, const MatrixXd &Gamma, double h, MatrixXd &A, MatrixXd &Bv,
                 vibid_log_info &info) {
    const Eigen::Index n = G.rows(), r = Gamma.cols();
    Eigen::EigenSolver<MatrixXd> es(G, false);
    if (es.info() != Eigen::Success) throw_error(VIBID_E_NUMERICAL, "eigenvalues of G did not converge");
    double max_arg = 0.0;
    for (Eigen::Index i = 0; i < n; ++i) {
        const std::complex<double> l = es.eigenvalues()(i);
        const double mag = std::abs(l);
        if (mag < 1e-300)
            throw_error(VIBID_E_NUMERICAL, "G is singular (eigenvalue 0): no logarithm; not a sampled continuous system");
        // A real eigenvalue <= 0 has no real logarithm: in a sampled system it means a mode
        // exactly at Nyquist (or beyond, folded), i.e. sampling too slow.
        if (l.real() < 0.0 && std::fabs(l.imag()) <= 1e-12 * mag)
            throw_error(VIBID_E_NUMERICAL,
                        "G has the negative real eigenvalue %.6g: no real matrix logarithm (a mode at the Nyquist "
                        "frequency %.6g Hz or an aliased one); sample faster",
                        l.real(), 0.5 / h);
        max_arg = std::max(max_arg, std::fabs(std::arg(l)));
    }
    info.nyquist_hz = 0.5 / h;
    info.max_frequency_hz = max_arg / (2.0 * M_PI * h);
    info.ambiguous = info.max_frequency_hz > 0.8 * info.nyquist_hz ? 1 : 0;
    MatrixXd aug = MatrixXd::Identity(n + r, n + r);
    aug.topLeftCorner(n, n) = G;
    if (r) aug.topRightCorner(n, r) = Gamma;
    const MatrixXd l = aug.log() / h;
    if (!l.allFinite()) throw_error(VIBID_E_NUMERICAL, "matrix logarithm failed (non-finite result)");
    A = l.topLeftCorner(n, n);
    Bv = l.topRightCorner(n, r);
}

void second_order_form(const MatrixXd &M, const MatrixXd &D, const MatrixXd &C, const MatrixXd &Bv, double h,
                       MatrixXd &Dt, MatrixXd &Ct, MatrixXd &B1t, MatrixXd &B2t) {
    const Eigen::Index n = M.rows(), r = Bv.cols();
    Eigen::FullPivLU<MatrixXd> lu(M);
    if (!lu.isInvertible()) throw_error(VIBID_E_NUMERICAL, "M is singular");
    MatrixXd A = MatrixXd::Zero(2 * n, 2 * n), Bc = MatrixXd::Zero(2 * n, r);
    A.topRightCorner(n, n).setIdentity();
    A.bottomLeftCorner(n, n) = -lu.solve(C);
    A.bottomRightCorner(n, n) = -lu.solve(D);
    if (r) Bc.bottomRows(n) = lu.solve(Bv);
    MatrixXd G, Gamma;
    zoh(A, Bc, h, G, Gamma);
    // Observability matrix of y = [I 0] x over two steps: O = [I 0; G11 G12]. The state
    // xi_k = O x_k = [y_k; y_{k+1} - CH v_k] turns (1.14) into the companion form
    // [0 I; A2 A1] (see second_order_to_continuous).
    const MatrixXd G12 = G.topRightCorner(n, n);
    Eigen::FullPivLU<MatrixXd> lu12(G12);
    if (!lu12.isInvertible())
        throw_error(VIBID_E_NUMERICAL, "upper-right block of e^{Ah} is singular: h is at a multiple of a half period");
    MatrixXd O(2 * n, 2 * n);
    O << MatrixXd::Identity(n, n), MatrixXd::Zero(n, n), G.topRows(n);
    const MatrixXd CG2 = (G * G).topRows(n);
    const MatrixXd A21 = O.transpose().fullPivLu().solve(CG2.transpose()).transpose();  // C G^2 O^-1 = [A2 A1]
    const MatrixXd A2 = A21.leftCols(n), A1 = A21.rightCols(n);
    Dt = -A1;
    Ct = -A2;
    B1t = Gamma.topRows(n);                          // C H
    B2t = (G * Gamma).topRows(n) - A1 * B1t;         // C G H - A1 C H
}

void second_order_to_continuous(const MatrixXd &Dt, const MatrixXd &Ct, const MatrixXd &B1t, const MatrixXd &B2t,
                                double h, MatrixXd &K, MatrixXd &L, MatrixXd &J, vibid_log_info &info) {
    const Eigen::Index n = Dt.rows(), r = B1t.cols();
    // Observable realisation of y_{k+2} = A1 y_{k+1} + A2 y_k + B1 v_{k+1} + B0 v_k:
    //   Gc = [0 I; A2 A1], Hc = [B1; B0 + A1 B1], output [I 0].
    MatrixXd Gc = MatrixXd::Zero(2 * n, 2 * n), Hc(2 * n, r);
    Gc.topRightCorner(n, n).setIdentity();
    Gc.bottomLeftCorner(n, n) = -Ct;
    Gc.bottomRightCorner(n, n) = -Dt;
    if (r) {
        Hc.topRows(n) = B1t;
        Hc.bottomRows(n) = B2t - Dt * B1t;
    }
    MatrixXd Ac, Bc;
    zoh_inverse(Gc, Hc, h, Ac, Bc, info);
    // Continuous system in the coordinates [y; y']: T = [I 0; Ac11 Ac12] (the continuous
    // observability matrix); T Ac T^-1 = [0 I; -K -L], T Bc = [0; J].
    MatrixXd T = MatrixXd::Zero(2 * n, 2 * n);
    T.topLeftCorner(n, n).setIdentity();
    T.bottomRows(n) = Ac.topRows(n);
    Eigen::FullPivLU<MatrixXd> lut(T);
    if (!lut.isInvertible())
        throw_error(VIBID_E_NUMERICAL, "the estimated difference form has no second-order continuous equivalent");
    const MatrixXd Aw = T * Ac * lut.inverse();
    K = -Aw.bottomLeftCorner(n, n);
    L = -Aw.bottomRightCorner(n, n);
    J = r ? MatrixXd(Ac.topRows(n) * Bc) : MatrixXd(n, 0);
}

}  // namespace vibid

namespace {

Eigen::Map<const MatrixXd> cmap(const double *p, std::size_t rows, std::size_t cols) {
    return Eigen::Map<const MatrixXd>(p, static_cast<Eigen::Index>(rows), static_cast<Eigen::Index>(cols));
}

void check_in(const double *p, std::size_t count, const char *name) {
    if (!p) throw_error(VIBID_E_NULL_ARGUMENT, "%s is NULL", name);
    if (!vibid::all_finite(p, count)) throw_error(VIBID_E_NONFINITE, "%s has NaN or Inf", name);
}

void check_state_dims(std::size_t n_states, std::size_t n_inputs) {
    if (n_states < 1 || n_states > 512 || n_inputs > 512)
        throw_error(VIBID_E_DIMENSION, "n_states = %zu (1..512), n_inputs = %zu (0..512)", n_states, n_inputs);
}

void check_h(double h) {
    if (!(h > 0.0) || !std::isfinite(h)) throw_error(VIBID_E_OUT_OF_RANGE, "h = %g s must be > 0 and finite", h);
}

void store(double *dst, const MatrixXd &m) {
    if (dst && m.size()) Eigen::Map<MatrixXd>(dst, m.rows(), m.cols()) = m;
}

}  // namespace

extern "C" {

VIBID_API vibid_status vibid_zoh(size_t n_states, size_t n_inputs, const double *A, const double *Bv, double h,
                                 double *G, double *Gamma) {
    VIBID_GUARD(
        check_state_dims(n_states, n_inputs);
        check_in(A, n_states * n_states, "A");
        if (n_inputs) check_in(Bv, n_states * n_inputs, "Bv");
        check_h(h);
        if (!G || (n_inputs && !Gamma)) throw_error(VIBID_E_NULL_ARGUMENT, "G (and Gamma) required");
        MatrixXd Gm, Gam;
        vibid::zoh(cmap(A, n_states, n_states), n_inputs ? MatrixXd(cmap(Bv, n_states, n_inputs)) : MatrixXd(n_states, 0),
                   h, Gm, Gam);
        // Finite A can still overflow e^{A h} (a growth rate of 1000/s over 1 s): that is
        // no discretization, and the outputs are left untouched.
        if (!Gm.allFinite() || !Gam.allFinite())
            throw_error(VIBID_E_NUMERICAL, "e^{A h} overflows (h = %g s): some mode grows by more than 1e308 over one "
                                           "sample", h);
        store(G, Gm);
        store(Gamma, Gam);
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_zoh_inverse(size_t n_states, size_t n_inputs, const double *G, const double *Gamma,
                                         double h, double *A, double *Bv, vibid_log_info *info) {
    VIBID_GUARD(
        check_state_dims(n_states, n_inputs);
        check_in(G, n_states * n_states, "G");
        if (n_inputs) check_in(Gamma, n_states * n_inputs, "Gamma");
        check_h(h);
        if (!A || (n_inputs && !Bv)) throw_error(VIBID_E_NULL_ARGUMENT, "A (and Bv) required");
        vibid_log_info local{};
        MatrixXd Am, Bm;
        vibid::zoh_inverse(cmap(G, n_states, n_states),
                           n_inputs ? MatrixXd(cmap(Gamma, n_states, n_inputs)) : MatrixXd(n_states, 0), h, Am, Bm,
                           local);
        store(A, Am);
        store(Bv, Bm);
        if (info) *info = local;
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_second_order_form(size_t n, size_t r, const double *M, const double *D,
                                               const double *C, const double *Bv, double h, double *Dt,
                                               double *Ct, double *B1t, double *B2t) {
    VIBID_GUARD(
        if (n < 1 || n > 256 || r > 256) throw_error(VIBID_E_DIMENSION, "n = %zu (1..256), r = %zu (0..256)", n, r);
        check_in(M, n * n, "M");
        check_in(D, n * n, "D");
        check_in(C, n * n, "C");
        if (r) check_in(Bv, n * r, "Bv");
        check_h(h);
        if (!Dt || !Ct || (r && (!B1t || !B2t))) throw_error(VIBID_E_NULL_ARGUMENT, "outputs required");
        MatrixXd a, b, c, d;
        vibid::second_order_form(cmap(M, n, n), cmap(D, n, n), cmap(C, n, n),
                                 r ? MatrixXd(cmap(Bv, n, r)) : MatrixXd(n, 0), h, a, b, c, d);
        store(Dt, a);
        store(Ct, b);
        store(B1t, c);
        store(B2t, d);
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_second_order_to_continuous(size_t n, size_t r, const double *Dt, const double *Ct,
                                                        const double *B1t, const double *B2t, double h,
                                                        double *K, double *L, double *J, vibid_log_info *info) {
    VIBID_GUARD(
        if (n < 1 || n > 256 || r > 256) throw_error(VIBID_E_DIMENSION, "n = %zu (1..256), r = %zu (0..256)", n, r);
        check_in(Dt, n * n, "Dt");
        check_in(Ct, n * n, "Ct");
        if (r) {
            check_in(B1t, n * r, "B1t");
            check_in(B2t, n * r, "B2t");
        }
        check_h(h);
        if (!K || !L || (r && !J)) throw_error(VIBID_E_NULL_ARGUMENT, "outputs required");
        vibid_log_info local{};
        MatrixXd k, l, j;
        const MatrixXd b1 = r ? MatrixXd(cmap(B1t, n, r)) : MatrixXd(n, 0);
        const MatrixXd b2 = r ? MatrixXd(cmap(B2t, n, r)) : MatrixXd(n, 0);
        vibid::second_order_to_continuous(cmap(Dt, n, n), cmap(Ct, n, n), b1, b2, h, k, l, j, local);
        store(K, k);
        store(L, l);
        store(J, j);
        if (info) *info = local;
        return VIBID_OK;);
}

}  // extern "C"
