// bench_rls.cpp: cost of one RLS update (ns) for p = 4..64 parameters and q = 1, 2, 4
// outputs, in one run, beside a yardstick: libvibid's Bierman UD form (the default;
// without and with the trace bound), libvibid's plain covariance form, and a lean Eigen
// covariance-form RLS written here in a dozen lines (the cheapest correct way to write
// RLS with Eigen: one matrix-vector product, one rank-1 update of P, no checks, no
// roll-back, no residual statistics). The ratio Bierman / lean is the figure of issue 15
// (target: at most 1.2).
//
// A second table times whole samples of m equations with one output (the structured form:
// example 1 has p = 3, m = 2), Bierman against the lean RLS doing its m updates.
//
// Usage: bench_rls [scale [p]]   scale multiplies the number of updates timed (default 1);
// p, if given, restricts the tables to that number of parameters.
// The variants of one cell are timed in turn, kRepeats rounds; each figure is the best
// round of the thread's CPU time (the machine is shared: CPU time leaves out the time other
// processes hold the core, the minimum is the least disturbed round, and interleaving the
// variants keeps a burst of load from favouring one of them). The library's kernels
// are the ones the CPU gets (VIBID_FORCE_BASELINE=1 in the environment forces the
// baseline SSE2 kernels; the yardstick is compiled with the same flags as the library,
// -O2 without -march, and never uses AVX2). Forgetting is 1: the plain covariance form is
// numerically unstable under forgetting (see test_rls_windup.c) and a refused update
// would be timed on a different path; vibid's update costs the same for any gamma (it is
// folded into D), the yardstick would need one more pass over P. Prints a table; never
// fails on time.
#include <vibid/rls.h>

#include <Eigen/Core>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <time.h>
#include <utility>
#include <vector>

namespace {

constexpr int kSamples = 256;  // distinct samples, cycled (kept in cache, no RNG in the loop)
constexpr int kRepeats = 5;

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

// The yardstick: lean covariance-form RLS (2.6)/(2.7) with forgetting 1, P = alpha^-1 I.
struct LeanRls {
    Eigen::MatrixXd P, theta;
    Eigen::VectorXd phi, K, e;
    LeanRls(int p, int q, double alpha)
        : P(Eigen::MatrixXd::Identity(p, p) / alpha), theta(Eigen::MatrixXd::Zero(p, q)), phi(p), K(p), e(q) {}
    void update(const double *xp, const double *yp) {
        Eigen::Map<const Eigen::VectorXd> x(xp, P.rows()), y(yp, theta.cols());
        phi.noalias() = P * x;
        K = phi / (1.0 + x.dot(phi));
        e = y;
        e.noalias() -= theta.transpose() * x;
        theta.noalias() += K * e.transpose();
        P.noalias() -= K * phi.transpose();
    }
};

// CPU time of this thread, ns: time while other processes hold the core is not counted
// (the machine is shared), only what they leave behind in the caches.
double thread_ns() {
    timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return 1e9 * static_cast<double>(ts.tv_sec) + static_cast<double>(ts.tv_nsec);
}

template <class F>
double ns_per_call(long n, const F &call) {
    const double t0 = thread_ns();
    for (long k = 0; k < n; ++k) call(k);
    return (thread_ns() - t0) / static_cast<double>(n);
}

// d holds p x m regressors and m targets per sample when m > 1 (q = 1).
vibid_rls *make(const Data &d, vibid_rls_form form, vibid_rls_windup windup, int m = 1) {
    vibid_rls_config cfg;
    vibid_rls_config_init(&cfg, static_cast<size_t>(d.p / m), static_cast<size_t>(d.q / m));
    cfg.n_equations = static_cast<size_t>(m);
    cfg.form = form;
    cfg.alpha = 1e-2;
    cfg.windup = windup;
    cfg.trace_max = d.p / m / cfg.alpha;
    vibid_rls *rls = vibid_rls_create(&cfg);
    if (!rls) {
        std::fprintf(stderr, "vibid_rls_create: %s\n", vibid_last_error());
        std::exit(1);
    }
    return rls;
}

}  // namespace

int main(int argc, char **argv) {
    const double scale = argc > 1 ? std::atof(argv[1]) : 1.0;
    if (!(scale > 0.0)) {
        std::fprintf(stderr, "usage: %s [scale > 0]\n", argv[0]);
        return 2;
    }
    const int only_p = argc > 2 ? std::atoi(argv[2]) : 0;
    const char *force = std::getenv("VIBID_FORCE_BASELINE");
    std::printf("RLS update cost, ns per update (best of %d interleaved rounds); forgetting 1, m = 1; "
                "VIBID_FORCE_BASELINE=%s\n",
                kRepeats, force ? force : "(unset)");
    std::printf("%4s %3s | %9s %9s %11s | %9s | %8s %8s\n", "p", "q", "Bierman", "+bound", "covariance", "lean Eigen",
                "B/lean", "cov/lean");
    long failures = 0;
    for (int p : {4, 8, 16, 32, 64}) {
        if (only_p && p != only_p) continue;
        for (int q : {1, 2, 4}) {
            const Data d(p, q);
            // About 10 ms per measurement: the work per update grows like p^2.
            const long n = std::clamp(static_cast<long>(scale * 1e7 / (p * p + 8 * p + 4 * p * q)), 5000L, 2000000L);
            vibid_rls *bier = make(d, VIBID_RLS_FORM_BIERMAN_UD, VIBID_RLS_WINDUP_NONE);
            vibid_rls *bound = make(d, VIBID_RLS_FORM_BIERMAN_UD, VIBID_RLS_WINDUP_TRACE_BOUND);
            vibid_rls *cov = make(d, VIBID_RLS_FORM_COVARIANCE, VIBID_RLS_WINDUP_NONE);
            LeanRls lean(p, q, 1e-2);
            for (long k = 0; k < kSamples; ++k) {  // warm-up, and the state away from the prior
                for (vibid_rls *r : {bier, bound, cov}) failures += vibid_rls_update(r, d.xs(k), d.ys(k)) != VIBID_OK;
                lean.update(d.xs(k), d.ys(k));
            }
            double best[4] = {1e300, 1e300, 1e300, 1e300};
            for (int r = 0; r < kRepeats; ++r) {
                int v = 0;
                for (vibid_rls *e : {bier, bound, cov}) {
                    long bad = 0;
                    best[v] = std::min(best[v], ns_per_call(n, [&](long k) {
                                           bad += vibid_rls_update(e, d.xs(k), d.ys(k)) != VIBID_OK;
                                       }));
                    failures += bad;
                    ++v;
                }
                best[3] = std::min(best[3], ns_per_call(n, [&](long k) { lean.update(d.xs(k), d.ys(k)); }));
            }
            // Keep the yardstick's result observable so that its loop cannot be optimised away.
            if (!lean.theta.allFinite()) std::fprintf(stderr, "lean yardstick diverged\n");
            std::printf("%4d %3d | %9.1f %9.1f %11.1f | %9.1f | %8.2f %8.2f\n", p, q, best[0], best[1], best[2],
                        best[3], best[0] / best[3], best[2] / best[3]);
            std::fflush(stdout);
            for (vibid_rls *e : {bier, bound, cov}) vibid_rls_destroy(e);
        }
    }
    // The structured form's shapes: m equations per sample with one output (example 1:
    // p = 3, m = 2; a 3-DOF chain: p = 6, m = 3). The yardstick does its m updates.
    std::printf("\nseveral equations per sample, q = 1: ns per sample (m equations)\n");
    std::printf("%4s %3s | %9s | %9s | %8s\n", "p", "m", "Bierman", "lean Eigen", "B/lean");
    for (const auto &[p, m] : {std::pair<int, int>{3, 2}, {4, 2}, {6, 3}}) {
        if (only_p && p != only_p) continue;
        const Data d(p * m, m);
        const long n = std::clamp(static_cast<long>(scale * 1e7 / (m * (p * p + 8 * p + 4 * p))), 5000L, 2000000L);
        vibid_rls *bier = make(d, VIBID_RLS_FORM_BIERMAN_UD, VIBID_RLS_WINDUP_NONE, m);
        LeanRls lean(p, 1, 1e-2);
        const auto lean_sample = [&](long k) {
            for (int i = 0; i < m; ++i) lean.update(d.xs(k) + i * p, d.ys(k) + i);
        };
        for (long k = 0; k < kSamples; ++k) {
            failures += vibid_rls_update(bier, d.xs(k), d.ys(k)) != VIBID_OK;
            lean_sample(k);
        }
        double best[2] = {1e300, 1e300};
        for (int r = 0; r < kRepeats; ++r) {
            long bad = 0;
            best[0] = std::min(best[0], ns_per_call(n, [&](long k) {
                                   bad += vibid_rls_update(bier, d.xs(k), d.ys(k)) != VIBID_OK;
                               }));
            failures += bad;
            best[1] = std::min(best[1], ns_per_call(n, lean_sample));
        }
        if (!lean.theta.allFinite()) std::fprintf(stderr, "lean yardstick diverged\n");
        std::printf("%4d %3d | %9.1f | %9.1f | %8.2f\n", p, m, best[0], best[1], best[0] / best[1]);
        vibid_rls_destroy(bier);
    }
    if (failures) std::printf("WARNING: %ld updates returned an error; their figures are not meaningful\n", failures);
    return 0;
}
