// bench_lsq.cpp: cost of batch least squares per row (ns) for p = 4..64 parameters and
// q = 1, 4 outputs, in one run, beside two yardsticks on the same rows:
//   - vibid_lsq_add_rows: N rows in one call into a fresh accumulator (R of [X Y]);
//   - Eigen's HouseholderQR of the stacked N x (p + q) matrix [X Y] (the same factor R,
//     computed from all rows at once; compiled here with the library's flags, -O2 without
//     -march, so SSE2 only);
//   - numpy's lstsq(X, Y) (LAPACK gelsd through OpenBLAS, which picks AVX2/AVX-512
//     kernels at run time and may use several threads), timed by bench_lsq_numpy.py in
//     the Python given by VIBID_BENCH_PYTHON or else the test venv
//     (<source>/build/venv/bin/python), skipped when there is no numpy.
// N = 8192 rows (a few seconds of a stand at kHz rates; large enough that a per-call cost
// does not count). Usage: bench_lsq [scale]  (scale multiplies the repetitions, default 1).
// Each figure is the best of kRepeats interleaved rounds of thread CPU time (numpy's: best
// of its own rounds of process CPU time, as it may use threads). VIBID_FORCE_BASELINE=1
// in the environment forces libvibid's baseline SSE2 kernels. Prints a table; never fails
// on time.
#include <vibid/lsq.h>

#include <Eigen/Core>
#include <Eigen/QR>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <random>
#include <string>
#include <time.h>
#include <utility>
#include <vector>

#ifndef VIBID_SOURCE_DIR
#define VIBID_SOURCE_DIR "."
#endif

namespace {

constexpr long kRows = 8192;
constexpr int kRepeats = 5;

double thread_ns() {
    timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return 1e9 * static_cast<double>(ts.tv_sec) + static_cast<double>(ts.tv_nsec);
}

template <class F>
double ns_per_row(int reps, const F &call) {
    const double t0 = thread_ns();
    for (int r = 0; r < reps; ++r) call();
    return (thread_ns() - t0) / (static_cast<double>(reps) * static_cast<double>(kRows));
}

// numpy's figures, ns per row keyed by (p, q), from one run of the Python script; empty
// when there is no Python with numpy.
std::map<std::pair<int, int>, double> numpy_figures(double scale, std::string &how) {
    std::map<std::pair<int, int>, double> out;
    const char *env = std::getenv("VIBID_BENCH_PYTHON");
    const std::string python = env && *env ? env : VIBID_SOURCE_DIR "/build/venv/bin/python";
    const std::string cmd = "'" + python + "' '" VIBID_SOURCE_DIR "/bench/bench_lsq_numpy.py' " +
                            std::to_string(kRows) + " " + std::to_string(scale) + " 2>&1";
    FILE *f = popen(cmd.c_str(), "r");
    if (!f) {
        how = "numpy: could not run " + python;
        return out;
    }
    char line[512];
    while (std::fgets(line, sizeof line, f)) {
        int p = 0, q = 0;
        double ns = 0.0;
        if (std::sscanf(line, "lstsq %d %d %lf", &p, &q, &ns) == 3)
            out[{p, q}] = ns;
        else if (std::string(line).rfind("numpy ", 0) == 0)
            how = std::string(line, std::strlen(line) - (line[std::strlen(line) - 1] == '\n'));
    }
    if (pclose(f) != 0 || out.empty()) {
        out.clear();
        how = "numpy: not available (" + python + "); set VIBID_BENCH_PYTHON to a Python with numpy";
    }
    return out;
}

}  // namespace

int main(int argc, char **argv) {
    const double scale = argc > 1 ? std::atof(argv[1]) : 1.0;
    if (!(scale > 0.0)) {
        std::fprintf(stderr, "usage: %s [scale > 0]\n", argv[0]);
        return 2;
    }
    std::string how;
    const auto numpy = numpy_figures(scale, how);
    const char *force = std::getenv("VIBID_FORCE_BASELINE");
    std::printf("Batch LS, ns per row, N = %ld rows per call (best of %d interleaved rounds); "
                "VIBID_FORCE_BASELINE=%s\n%s\n",
                kRows, kRepeats, force ? force : "(unset)", how.c_str());
    std::printf("%4s %3s | %9s | %9s %9s | %9s %9s\n", "p", "q", "vibid", "Eigen QR", "v/QR", "numpy", "v/numpy");
    for (int p : {4, 8, 16, 32, 64}) {
        for (int q : {1, 4}) {
            const int n = p + q;
            std::mt19937_64 gen(42);
            std::normal_distribution<double> n01;
            Eigen::MatrixXd A(kRows, n);  // [X Y], column-major: X is its first p columns
            for (Eigen::Index k = 0; k < A.size(); ++k) A.data()[k] = n01(gen);
            vibid_lsq *lsq = vibid_lsq_create(static_cast<size_t>(p), static_cast<size_t>(q));
            if (!lsq) {
                std::fprintf(stderr, "vibid_lsq_create: %s\n", vibid_last_error());
                return 1;
            }
            Eigen::HouseholderQR<Eigen::MatrixXd> qr(kRows, n);
            // About 10 ms per measurement: the work per row grows like n^2.
            const int reps = std::max(1, static_cast<int>(scale * 1e7 / (kRows * 4.0 * n * n)));
            long bad = 0;
            double best_v = 1e300, best_qr = 1e300;
            for (int r = 0; r < kRepeats; ++r) {
                best_v = std::min(best_v, ns_per_row(reps, [&] {
                                      bad += vibid_lsq_reset(lsq) != VIBID_OK;
                                      bad += vibid_lsq_add_rows(lsq, kRows, A.data(), A.data() + kRows * p,
                                                                nullptr) != VIBID_OK;
                                  }));
                best_qr = std::min(best_qr, ns_per_row(reps, [&] { qr.compute(A); }));
            }
            if (bad) std::fprintf(stderr, "vibid_lsq_add_rows failed %ld times: %s\n", bad, vibid_last_error());
            // Keep both results observable.
            std::vector<double> theta(static_cast<size_t>(p * q));
            if (vibid_lsq_solve(lsq, theta.data(), nullptr) != VIBID_OK || !qr.matrixQR().allFinite())
                std::fprintf(stderr, "solve failed: %s\n", vibid_last_error());
            vibid_lsq_destroy(lsq);
            const auto it = numpy.find({p, q});
            if (it != numpy.end())
                std::printf("%4d %3d | %9.1f | %9.1f %9.2f | %9.1f %9.2f\n", p, q, best_v, best_qr, best_v / best_qr,
                            it->second, best_v / it->second);
            else
                std::printf("%4d %3d | %9.1f | %9.1f %9.2f | %9s %9s\n", p, q, best_v, best_qr, best_v / best_qr, "-",
                            "-");
            std::fflush(stdout);
        }
    }
    return 0;
}
