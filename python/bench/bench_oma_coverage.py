"""Coverage of vibid.oma's standard errors (issue 34: "coverage of 2-se intervals 90-98 %
over Monte Carlo runs" on simulated ambient captures of 2-, 5- and 10-DOF stands).

    python python/bench/bench_oma_coverage.py              # 100 captures per stand, ~5 min
    python python/bench/bench_oma_coverage.py --runs 20    # a quick look

Each stand is a chain of masses under unmeasured white forces on every mass (held over each
sample: the exact discretisation), displacements measured with 1 % sensor noise
(python/tests/oma_sim.py), 120 s per capture; vibid.oma with its defaults. Per mode: found in
how many captures, 2-se coverage of frequency and damping ratio, mean standard error against
the RMS error (1 when the error bars are right), mean absolute error. A benchmark, not a
test: it asserts nothing (lib.test_oma and test_oma.py are the tests)."""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
import vibid  # noqa: E402
from oma_sim import ambient, chain_matrices, modes  # noqa: E402

STANDS = {
    "2-DOF": dict(m=[1.0, 0.5], k=[1.0e4, 6.0e3], d=[3.0, 2.0], fs=100.0),
    "5-DOF": dict(m=[1.0, 1.2, 0.8, 1.0, 0.6], k=[2.0e4, 1.6e4, 1.4e4, 1.2e4, 8.0e3], d=[6.0, 5.0, 4.0, 3.0, 2.0],
                  fs=200.0),
    "10-DOF": dict(m=[1.0] * 10, k=[4.0e4] * 10, d=[4.0] * 10, fs=400.0),
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--seconds", type=float, default=120.0)
    a = ap.parse_args()
    pooled_hits = pooled_n = 0
    for name, p in STANDS.items():
        M, D, K = chain_matrices(p["m"], p["k"], p["d"])
        f, z = modes(M, D, K)
        n = int(a.seconds * p["fs"])
        nm = len(f)
        found = np.zeros(nm, int)
        hit_f = np.zeros(nm, int)
        hit_z = np.zeros(nm, int)
        se_f, se_z, e_f, e_z, extra = [[[] for _ in range(nm)] for _ in range(4)] + [0]
        for run in range(a.runs):
            y = ambient(M, D, K, p["fs"], n, noise=0.01, seed=1000 + run)
            r = vibid.oma(y, p["fs"])
            used = set()
            for j in range(nm):
                rel = np.abs(r.modes.freq_hz.to_numpy() / f[j] - 1)
                if not len(rel) or rel.min() > 0.05:
                    continue
                k = int(rel.argmin())
                used.add(k)
                m = r.modes.iloc[k]
                found[j] += 1
                hit_f[j] += abs(m.freq_hz - f[j]) <= 2 * m.freq_hz_se
                hit_z[j] += abs(m.zeta - z[j]) <= 2 * m.zeta_se
                se_f[j].append(m.freq_hz_se / f[j])
                se_z[j].append(m.zeta_se / z[j])
                e_f[j].append(m.freq_hz / f[j] - 1)
                e_z[j].append(m.zeta / z[j] - 1)
            extra += len(r.modes) - len(used)
        print(f"{name}: {a.runs} captures of {a.seconds:g} s at {p['fs']:g} Hz; {extra} extra modes selected in all")
        print(f"  {'mode':>4} {'f [Hz]':>8} {'zeta':>7} {'found':>5} {'cov f':>6} {'cov z':>6} {'se/rms f':>8} "
              f"{'se/rms z':>8} {'|err| f %':>9} {'|err| z %':>9}")
        for j in range(nm):
            if not found[j]:
                print(f"  {j + 1:>4} {f[j]:8.3f} {z[j]:7.4f} {0:>5}")
                continue
            rf = np.mean(se_f[j]) / np.sqrt(np.mean(np.square(e_f[j])))
            rz = np.mean(se_z[j]) / np.sqrt(np.mean(np.square(e_z[j])))
            print(f"  {j + 1:>4} {f[j]:8.3f} {z[j]:7.4f} {found[j]:>5} {100 * hit_f[j] / found[j]:5.0f}% "
                  f"{100 * hit_z[j] / found[j]:5.0f}% {rf:8.2f} {rz:8.2f} {100 * np.mean(np.abs(e_f[j])):9.3f} "
                  f"{100 * np.mean(np.abs(e_z[j])):9.2f}")
            pooled_hits += hit_f[j] + hit_z[j]
            pooled_n += 2 * found[j]
    print(f"pooled 2-se coverage: {100 * pooled_hits / pooled_n:.1f} % of {pooled_n} intervals")


if __name__ == "__main__":
    main()
