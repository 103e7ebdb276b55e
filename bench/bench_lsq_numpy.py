"""numpy's yardstick for bench_lsq: ns per row of numpy.linalg.lstsq(X, Y) on N random rows,
for the (p, q) cells bench_lsq prints. One line per cell: "lstsq p q ns_per_row", and a line
"numpy ..." naming the version and BLAS threads.

Usage: bench_lsq_numpy.py N [scale]. OpenBLAS is held to one thread (set before numpy is
imported), as libvibid runs on one: the figure is the cost of the arithmetic on one core,
and the machine is shared. Each figure is the best of 5 rounds of process CPU time.
"""
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402


def main():
    n_rows = int(sys.argv[1])
    scale = float(sys.argv[2]) if len(sys.argv) > 2 else 1.0
    print(f"numpy {np.__version__} lstsq (LAPACK gelsd, includes its solve), "
          f"OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}", flush=True)
    rng = np.random.default_rng(42)
    for p in (4, 8, 16, 32, 64):
        for q in (1, 4):
            n = p + q
            X = np.asfortranarray(rng.standard_normal((n_rows, p)))
            Y = np.asfortranarray(rng.standard_normal((n_rows, q)))
            reps = max(1, int(scale * 1e7 / (n_rows * 4.0 * n * n)))
            np.linalg.lstsq(X, Y, rcond=None)  # warm-up
            best = float("inf")
            for _ in range(5):
                t0 = time.process_time_ns()
                for _ in range(reps):
                    np.linalg.lstsq(X, Y, rcond=None)
                best = min(best, (time.process_time_ns() - t0) / (reps * n_rows))
            print(f"lstsq {p} {q} {best:.2f}", flush=True)


if __name__ == "__main__":
    main()
