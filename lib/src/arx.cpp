// arx.cpp: ARX difference-equation models: LS estimate, simulation, and the IV
// estimate with instruments from an auxiliary model driven by the input only.
//
// Why the auxiliary model: with noise on the measured output, the regressor holds
// past noisy outputs, which are correlated with the (then coloured) equation error,
// so LS is biased however long the record. Past outputs of a model simulated from
// the input alone are correlated with the true past outputs but not with the noise:
// they are valid instruments (2.14). Any instrument model gives a consistent
// estimate; the closer it is to the truth, the smaller the variance, hence the
// iteration LS -> simulate -> IV -> simulate -> IV ...
//
// The estimators are the library's own vibid_lsq / vibid_iv accumulators, fed in
// fixed-size chunks so that memory does not grow with the record length.
#include <vibid/iv.h>

#include "api_guard.hpp"

#include <Eigen/Core>
#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdint>
#include <memory>
#include <vector>

namespace {

using Eigen::Index;

constexpr std::size_t max_order = 64;
constexpr std::size_t chunk_rows = 64;  // rows built and handed to an accumulator at once

struct Arx {
    std::size_t na, nb, nk, n_inputs, p;
    std::size_t start;  // first usable row: max(na, nk + nb - 1)
};

bool spec_ok(const vibid_arx_spec *spec) noexcept {
    return spec && spec->na <= max_order && spec->nb <= max_order && spec->nk <= max_order &&
           spec->n_inputs <= max_order && spec->na + spec->nb >= 1 && !(spec->n_inputs == 0 && spec->nb > 0);
}

Arx parse_spec(const vibid_arx_spec *spec) {
    if (!spec) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "spec is NULL");
    if (spec->na > max_order)
        vibid::throw_error(VIBID_E_OUT_OF_RANGE, "spec->na = %zu outside 0..64", spec->na);
    if (spec->nb > max_order)
        vibid::throw_error(VIBID_E_OUT_OF_RANGE, "spec->nb = %zu outside 0..64", spec->nb);
    if (spec->nk > max_order)
        vibid::throw_error(VIBID_E_OUT_OF_RANGE, "spec->nk = %zu outside 0..64", spec->nk);
    if (spec->n_inputs > max_order)
        vibid::throw_error(VIBID_E_OUT_OF_RANGE, "spec->n_inputs = %zu outside 0..64", spec->n_inputs);
    if (spec->na + spec->nb == 0)
        vibid::throw_error(VIBID_E_OUT_OF_RANGE, "spec->na + spec->nb = 0: no parameters");
    if (spec->n_inputs == 0 && spec->nb > 0)
        vibid::throw_error(VIBID_E_OUT_OF_RANGE, "spec->nb = %zu needs spec->n_inputs >= 1", spec->nb);
    Arx a{spec->na, spec->nb, spec->nk, spec->n_inputs, spec->na + spec->n_inputs * spec->nb, 0};
    a.start = a.nb > 0 ? std::max(a.na, a.nk + a.nb - 1) : a.na;
    if (a.p == 0)
        vibid::throw_error(VIBID_E_OUT_OF_RANGE, "spec has no parameters (na = 0 and n_inputs * nb = 0)");
    return a;
}

void check_signal(const char *name, const double *v, std::size_t n) {
    for (std::size_t k = 0; k < n; ++k)
        if (!std::isfinite(v[k]))
            vibid::throw_error(VIBID_E_NONFINITE, "%s[%zu] = %g is not finite", name, k, v[k]);
}

// Checks y, u and n_samples for the estimators.
void check_record(const Arx &a, std::size_t n_samples, const double *y, const double *u) {
    if (!y) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "y is NULL");
    if (!u && a.n_inputs > 0)
        vibid::throw_error(VIBID_E_NULL_ARGUMENT, "u is NULL but spec->n_inputs = %zu", a.n_inputs);
    if (n_samples == 0) vibid::throw_error(VIBID_E_DIMENSION, "n_samples = 0");
    if (n_samples > SIZE_MAX / sizeof(double) / (a.n_inputs + 1))
        vibid::throw_error(VIBID_E_DIMENSION, "n_samples = %zu too large", n_samples);
    if (n_samples <= a.start + a.p)
        vibid::throw_error(VIBID_E_INSUFFICIENT_DATA,
                           "n_samples = %zu gives %zu equations for %zu parameters (first row %zu)",
                           n_samples, n_samples > a.start ? n_samples - a.start : 0, a.p, a.start);
    check_signal("y", y, n_samples);
    if (a.n_inputs > 0) check_signal("u", u, n_samples * a.n_inputs);
}

// Regressor of row k into column-major block `out` (leading dimension ld) at row r:
// [-yy_{k-1} .. -yy_{k-na}, u_1 terms, u_2 terms, ...].
void fill_row(const Arx &a, std::size_t n_samples, const double *yy, const double *u, std::size_t k,
              double *out, std::size_t r, std::size_t ld) {
    std::size_t col = 0;
    for (std::size_t i = 1; i <= a.na; ++i) out[r + ld * col++] = -yy[k - i];
    for (std::size_t j = 0; j < a.n_inputs; ++j)
        for (std::size_t i = 0; i < a.nb; ++i) out[r + ld * col++] = u[j * n_samples + k - a.nk - i];
}

// Simulates y_sim from u with theta; zero before the start row. Returns the first
// sample that is not finite, or n_samples.
std::size_t simulate(const Arx &a, const double *theta, std::size_t n_samples, const double *u,
                     double *y_sim) {
    for (std::size_t k = 0; k < std::min(a.start, n_samples); ++k) y_sim[k] = 0.0;
    for (std::size_t k = a.start; k < n_samples; ++k) {
        double v = 0.0;
        for (std::size_t i = 1; i <= a.na; ++i) v -= theta[i - 1] * y_sim[k - i];
        for (std::size_t j = 0; j < a.n_inputs; ++j)
            for (std::size_t i = 0; i < a.nb; ++i)
                v += theta[a.na + j * a.nb + i] * u[j * n_samples + k - a.nk - i];
        if (!std::isfinite(v)) return k;
        y_sim[k] = v;
    }
    return n_samples;
}

// Reflects roots of z^na + a_1 z^(na-1) + ... + a_na outside the unit circle to 1/conj.
// The reflected model has the same magnitude-response shape (up to a constant
// factor), which is all an instrument needs, and it can be simulated.
void stabilise(const Arx &a, Eigen::VectorXd &theta) {
    if (a.na == 0) return;
    const Index n = static_cast<Index>(a.na);
    Eigen::MatrixXd C = Eigen::MatrixXd::Zero(n, n);  // companion matrix
    C.row(0) = -theta.head(n).transpose();
    if (n > 1) C.bottomLeftCorner(n - 1, n - 1).setIdentity();
    Eigen::EigenSolver<Eigen::MatrixXd> es(C, false);
    if (es.info() != Eigen::Success)
        vibid::throw_error(VIBID_E_NUMERICAL, "roots of the auxiliary model failed");
    Eigen::VectorXcd roots = es.eigenvalues();
    bool reflected = false;
    for (Index i = 0; i < n; ++i)
        if (std::abs(roots[i]) > 1.0) {
            roots[i] = 1.0 / std::conj(roots[i]);
            reflected = true;
        }
    if (!reflected) return;
    Eigen::VectorXcd c = Eigen::VectorXcd::Zero(n + 1);  // polynomial from its roots
    c[0] = 1.0;
    for (Index i = 0; i < n; ++i)
        for (Index j = i + 1; j > 0; --j) c[j] -= roots[i] * c[j - 1];
    for (Index i = 0; i < n; ++i) theta[i] = c[i + 1].real();  // conjugate pairs: imaginary parts cancel
}

// Owning handles so that an exception between create and destroy leaks nothing.
struct LsqDeleter {
    void operator()(vibid_lsq *l) const noexcept { vibid_lsq_destroy(l); }
};
struct IvDeleter {
    void operator()(vibid_iv *l) const noexcept { vibid_iv_destroy(l); }
};

// Turns a failed inner call into an exception carrying its message.
void check(vibid_status s) {
    if (s != VIBID_OK) vibid::throw_error(s, "%s", vibid_last_error());
}

// Plain LS on rows start..N-1. stderr_out may be NULL.
void arx_ls_impl(const Arx &a, std::size_t n_samples, const double *y, const double *u,
                 Eigen::VectorXd &theta, double *stderr_out) {
    std::unique_ptr<vibid_lsq, LsqDeleter> lsq(vibid_lsq_create(a.p, 1));
    if (!lsq) check(VIBID_E_NO_MEMORY);
    std::vector<double> X(chunk_rows * a.p), Y(chunk_rows);
    for (std::size_t k0 = a.start; k0 < n_samples; k0 += chunk_rows) {
        const std::size_t m = std::min(chunk_rows, n_samples - k0);
        for (std::size_t r = 0; r < m; ++r) {
            fill_row(a, n_samples, y, u, k0 + r, X.data(), r, m);
            Y[r] = y[k0 + r];
        }
        check(vibid_lsq_add_rows(lsq.get(), m, X.data(), Y.data(), nullptr));
    }
    theta.resize(static_cast<Index>(a.p));
    check(vibid_lsq_solve(lsq.get(), theta.data(), nullptr));
    if (stderr_out) check(vibid_lsq_stderr(lsq.get(), stderr_out));
}

}  // namespace

extern "C" {

VIBID_API size_t vibid_arx_n_params(const vibid_arx_spec *spec) {
    return spec_ok(spec) ? spec->na + spec->n_inputs * spec->nb : 0;
}

VIBID_API vibid_status vibid_arx_ls(const vibid_arx_spec *spec, size_t n_samples, const double *y,
                                    const double *u, double *theta, double *stderr_out) {
    VIBID_GUARD({
        const Arx a = parse_spec(spec);
        if (!theta) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "theta is NULL");
        check_record(a, n_samples, y, u);
        Eigen::VectorXd th;
        std::vector<double> se(stderr_out ? a.p : 0);
        arx_ls_impl(a, n_samples, y, u, th, stderr_out ? se.data() : nullptr);
        Eigen::Map<Eigen::VectorXd>(theta, th.size()) = th;
        if (stderr_out) std::copy(se.begin(), se.end(), stderr_out);
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_arx_iv(const vibid_arx_spec *spec, size_t n_samples, const double *y,
                                    const double *u, size_t n_iterations, double *theta, double *stderr_out) {
    VIBID_GUARD({
        const Arx a = parse_spec(spec);
        if (!theta) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "theta is NULL");
        if (n_iterations < 1 || n_iterations > 100)
            vibid::throw_error(VIBID_E_OUT_OF_RANGE, "n_iterations = %zu outside 1..100", n_iterations);
        check_record(a, n_samples, y, u);

        Eigen::VectorXd th;
        arx_ls_impl(a, n_samples, y, u, th, nullptr);  // bootstrap

        std::unique_ptr<vibid_iv, IvDeleter> iv(vibid_iv_create(a.p, 1));
        if (!iv) check(VIBID_E_NO_MEMORY);
        std::vector<double> y_aux(n_samples), X(chunk_rows * a.p), W(chunk_rows * a.p), Y(chunk_rows);
        Eigen::VectorXd aux;
        for (std::size_t it = 0; it < n_iterations; ++it) {
            aux = th;
            stabilise(a, aux);
            const std::size_t bad = simulate(a, aux.data(), n_samples, u, y_aux.data());
            if (bad < n_samples)
                vibid::throw_error(VIBID_E_NUMERICAL,
                                   "auxiliary model output not finite at sample %zu (iteration %zu)", bad,
                                   it + 1);
            check(vibid_iv_reset(iv.get()));
            for (std::size_t k0 = a.start; k0 < n_samples; k0 += chunk_rows) {
                const std::size_t m = std::min(chunk_rows, n_samples - k0);
                for (std::size_t r = 0; r < m; ++r) {
                    fill_row(a, n_samples, y, u, k0 + r, X.data(), r, m);
                    fill_row(a, n_samples, y_aux.data(), u, k0 + r, W.data(), r, m);
                    Y[r] = y[k0 + r];
                }
                check(vibid_iv_add_rows(iv.get(), m, X.data(), W.data(), Y.data(), nullptr));
            }
            check(vibid_iv_solve(iv.get(), th.data(), nullptr));
        }
        std::vector<double> se(stderr_out ? a.p : 0);
        if (stderr_out) check(vibid_iv_stderr(iv.get(), se.data()));
        Eigen::Map<Eigen::VectorXd>(theta, th.size()) = th;
        if (stderr_out) std::copy(se.begin(), se.end(), stderr_out);
        return VIBID_OK;
    });
}

VIBID_API vibid_status vibid_arx_simulate(const vibid_arx_spec *spec, const double *theta, size_t n_samples,
                                          const double *u, double *y_sim) {
    VIBID_GUARD({
        const Arx a = parse_spec(spec);
        if (!theta) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "theta is NULL");
        if (!y_sim) vibid::throw_error(VIBID_E_NULL_ARGUMENT, "y_sim is NULL");
        if (!u && a.n_inputs > 0)
            vibid::throw_error(VIBID_E_NULL_ARGUMENT, "u is NULL but spec->n_inputs = %zu", a.n_inputs);
        if (n_samples == 0) vibid::throw_error(VIBID_E_DIMENSION, "n_samples = 0");
        if (n_samples > SIZE_MAX / sizeof(double) / (a.n_inputs + 1))
            vibid::throw_error(VIBID_E_DIMENSION, "n_samples = %zu too large", n_samples);
        check_signal("theta", theta, a.p);
        if (a.n_inputs > 0) check_signal("u", u, n_samples * a.n_inputs);
        const std::size_t bad = simulate(a, theta, n_samples, u, y_sim);
        if (bad < n_samples)
            vibid::throw_error(VIBID_E_DIVERGED, "simulated output overflows at sample %zu (unstable theta?)",
                               bad);
        return VIBID_OK;
    });
}

}  // extern "C"
