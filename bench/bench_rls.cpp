// bench_rls.cpp: cost of one RLS update (ns) for p = 4..64 parameters and q = 1, 2, 4
// outputs, in one run: libvibid's Bierman UD form (without and with the trace bound),
// libvibid's plain covariance form, and a plain Eigen covariance-form RLS written here
// as the baseline; plus batch LS rows per second (vibid_lsq_add_rows).
//
// Usage: bench_rls [scale]   scale multiplies the number of updates timed (default 1).
// Each figure is the best of 3 repetitions (the machine is shared: the minimum is the
// least disturbed run). Forgetting is 1 in the timed runs: the plain covariance form
// is numerically unstable under forgetting (see test_rls_windup.c) and a refused update
// would be timed on a different path; the update's cost does not depend on gamma.
// Prints a table; never fails on time.
#include <vibid/lsq.h>
#include <vibid/rls.h>

#include <Eigen/Core>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <vector>

namespace {

constexpr int kSamples = 256;  // distinct samples, cycled (kept in cache, no RNG in the loop)
constexpr int kRepeats = 3;

struct Data {
    int p, q;
    std::vector<double> x, y;  // kSamples x p, kSamples x q
    Data(int p_, int q_) : p(p_), q(q_), x(static_cast<size_t>(kSamples * p_)), y(static_cast<size_t>(kSamples * q_)) {
        std::mt19937_64 gen(42);
        std::normal_distribution<double> n01;
        for (double &v : x) v = n01(gen);
        for (double &v : y) v = n01(gen);
    }
    const double *xs(long k) const { return x.data() + (k % kSamples) * p; }
    const double *ys(long k) const { return y.data() + (k % kSamples) * q; }
};

// Plain Eigen covariance-form RLS (2.6)/(2.7), the usual way to write it.
struct EigenRls {
    Eigen::MatrixXd P, theta;
    Eigen::VectorXd phi, K, e;
    double gamma;
    EigenRls(int p, int q, double alpha, double g)
        : P(Eigen::MatrixXd::Identity(p, p) / alpha), theta(Eigen::MatrixXd::Zero(p, q)), phi(p), K(p), e(q),
          gamma(g) {}
    void update(const double *xp, const double *yp) {
        Eigen::Map<const Eigen::VectorXd> x(xp, P.rows());
        Eigen::Map<const Eigen::VectorXd> y(yp, theta.cols());
        phi.noalias() = P * x;
        K = phi / (gamma + x.dot(phi));
        e = y;
        e.noalias() -= theta.transpose() * x;
        theta.noalias() += K * e.transpose();
        P.noalias() -= K * phi.transpose();
        P /= gamma;
    }
};

template <class F>
double best_ns_per_call(long n, F &&call) {
    double best = 1e300;
    for (int r = 0; r < kRepeats; ++r) {
        const auto t0 = std::chrono::steady_clock::now();
        for (long k = 0; k < n; ++k) call(k);
        const auto t1 = std::chrono::steady_clock::now();
        best = std::min(best, std::chrono::duration<double, std::nano>(t1 - t0).count() / static_cast<double>(n));
    }
    return best;
}

// Times vibid_rls_update; counts non-OK returns (must be 0 for the figure to mean anything).
double time_vibid(const Data &d, vibid_rls_form form, vibid_rls_windup windup, long n, long &failures) {
    vibid_rls_config cfg;
    vibid_rls_config_init(&cfg, static_cast<size_t>(d.p), static_cast<size_t>(d.q));
    cfg.form = form;
    cfg.alpha = 1e-2;
    cfg.windup = windup;
    cfg.trace_max = d.p / cfg.alpha;
    vibid_rls *rls = vibid_rls_create(&cfg);
    if (!rls) {
        std::fprintf(stderr, "vibid_rls_create: %s\n", vibid_last_error());
        std::exit(1);
    }
    for (long k = 0; k < kSamples; ++k) vibid_rls_update(rls, d.xs(k), d.ys(k));  // warm-up
    long bad = 0;
    const double ns = best_ns_per_call(n, [&](long k) { bad += vibid_rls_update(rls, d.xs(k), d.ys(k)) != VIBID_OK; });
    failures += bad;
    vibid_rls_destroy(rls);
    return ns;
}

double time_eigen(const Data &d, long n) {
    EigenRls rls(d.p, d.q, 1e-2, 1.0);
    for (long k = 0; k < kSamples; ++k) rls.update(d.xs(k), d.ys(k));
    const double ns = best_ns_per_call(n, [&](long k) { rls.update(d.xs(k), d.ys(k)); });
    // Keep the result observable so the loop cannot be optimised away.
    if (!rls.theta.allFinite()) std::fprintf(stderr, "baseline diverged\n");
    return ns;
}

// Batch LS: rows per second through vibid_lsq_add_rows in blocks of kSamples rows.
double lsq_rows_per_second(int p, int q, long rows) {
    Data d(p, q);
    // Column-major kSamples x p and kSamples x q blocks, as the API wants.
    std::vector<double> X(static_cast<size_t>(kSamples * p)), Y(static_cast<size_t>(kSamples * q));
    for (int k = 0; k < kSamples; ++k) {
        for (int i = 0; i < p; ++i) X[static_cast<size_t>(k + i * kSamples)] = d.xs(k)[i];
        for (int j = 0; j < q; ++j) Y[static_cast<size_t>(k + j * kSamples)] = d.ys(k)[j];
    }
    vibid_lsq *lsq = vibid_lsq_create(static_cast<size_t>(p), static_cast<size_t>(q));
    if (!lsq) {
        std::fprintf(stderr, "vibid_lsq_create: %s\n", vibid_last_error());
        std::exit(1);
    }
    const long blocks = std::max(1L, rows / kSamples);
    long bad = 0;
    const double ns = best_ns_per_call(blocks, [&](long) {
        bad += vibid_lsq_add_rows(lsq, kSamples, X.data(), Y.data(), nullptr) != VIBID_OK;
    });
    vibid_lsq_destroy(lsq);
    if (bad) std::fprintf(stderr, "vibid_lsq_add_rows failed %ld times: %s\n", bad, vibid_last_error());
    return 1e9 * kSamples / ns;
}

}  // namespace

int main(int argc, char **argv) {
    const double scale = argc > 1 ? std::atof(argv[1]) : 1.0;
    if (!(scale > 0.0)) {
        std::fprintf(stderr, "usage: %s [scale > 0]\n", argv[0]);
        return 2;
    }
    std::printf("RLS update cost, ns per update (best of %d); forgetting 1, m = 1 equation per sample\n", kRepeats);
    std::printf("%4s %3s | %9s %9s %11s %7s | %9s | %12s\n", "p", "q", "Bierman", "+bound", "covariance",
                "B/cov", "Eigen", "LS rows/s");
    long failures = 0;
    for (int p : {4, 8, 16, 32, 64}) {
        for (int q : {1, 2, 4}) {
            const Data d(p, q);
            // About 40 ms per measurement: the work per update grows like p^2.
            const long n = std::clamp(static_cast<long>(scale * 4e7 / (p * p + 8 * p + 4 * p * q)), 10000L, 5000000L);
            const double bier = time_vibid(d, VIBID_RLS_FORM_BIERMAN_UD, VIBID_RLS_WINDUP_NONE, n, failures);
            const double bound = time_vibid(d, VIBID_RLS_FORM_BIERMAN_UD, VIBID_RLS_WINDUP_TRACE_BOUND, n, failures);
            const double cov = time_vibid(d, VIBID_RLS_FORM_COVARIANCE, VIBID_RLS_WINDUP_NONE, n, failures);
            const double eig = time_eigen(d, n);
            const double ls = lsq_rows_per_second(p, q, static_cast<long>(scale * 4e7 / ((p + q) * (p + q))));
            std::printf("%4d %3d | %9.1f %9.1f %11.1f %7.2f | %9.1f | %12.3g\n", p, q, bier, bound, cov, bier / cov,
                        eig, ls);
            std::fflush(stdout);
        }
    }
    if (failures) std::printf("WARNING: %ld updates returned an error; their figures are not meaningful\n", failures);
    return 0;
}
