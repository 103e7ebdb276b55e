"""Benchmark of the output-error fit (issue 29): vibid against a careful analyst's scipy fit.

    python python/bench/bench_oe.py            # 10^5 samples; ~2-5 min (the scipy fit)
    python python/bench/bench_oe.py --quick    # 10^4 samples: a smoke run

The 3-DOF chain of the library's tests (examples/stands/chain3.cfg: held force on m3, x and a
of every node, modes 11.5 / 26.4 / 37.5 Hz) simulated by vibid-sim at 2 kHz with 0.5 % noise
on the response channels, no offset; 10^5 samples (50 s). Both fit the same model (six
springs and dampers, the initial state, one offset per response channel: 18 numbers) by
least squares of the simulation error, from the same start (the library's automatic
estimate), to the same data:

- vibid: the library's fit (vibid_oe_fit through _core.Oe.fit: the exact discretisation and
  its Frechet-derivative sensitivities, Levenberg-Marquardt), timed alone; and
  ``identify(method="oe", holdout=0)``, the automatic estimate and the fit together;
- the analyst: scipy.optimize.least_squares (trust region, x_scale="jac", Jacobian by
  finite differences, its default), the model discretised exactly for the held force by
  scipy.signal.cont2discrete (zero-order hold) and run by scipy.signal.dlsim, the residuals
  of all six channels weighted by 1 / their variance.

It prints the times, their ratio (the issue's target: vibid at least 20 times faster and
within 2 s) and both estimates' errors. It never passes or fails on time (the project's
rule)."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

import vibid
from vibid import _core

REPO = Path(__file__).resolve().parents[2]

CHAIN = REPO / "examples" / "stands" / "chain3.cfg"
SIM = """simulation = { seed = 3; excitation = ( { target = "f"; kind = "noise"; amplitude = 20.0; f_high = 150.0; } );
  noise = ( NOISE ); };
"""
RESPONSES = ["x1", "a1", "x2", "a2", "x3", "a3"]
MASSES = np.array([2.0, 1.5, 1.0])


def sim_path() -> Path:
    p = os.environ.get("VIBID_SIM")
    if p:
        return Path(p)
    root = Path(os.environ.get("VIBID_BUILD_ROOT", REPO / "build"))
    return (root if root.is_absolute() else REPO / root) / "werror" / "sim" / "vibid-sim"


def capture(n: int, tmp: Path):
    cfg = tmp / "chain_sim.cfg"
    cfg.write_text(SIM.replace("NOISE", ", ".join(f'{{ channel = "{c}"; snr_db = 46.0; }}' for c in RESPONSES)))
    out = tmp / "chain.csv"
    subprocess.run([str(sim_path()), "-c", str(CHAIN), "-s", str(cfg), "--csv", str(out), "--fast", "-d",
                    repr(n / 2000.0)], check=True, capture_output=True)
    return vibid.Stand.load(CHAIN), pd.read_csv(out, comment="#").rename(columns={"t": "time_s"})


def analyst_fit(df: pd.DataFrame, start: np.ndarray):
    """The analyst's least_squares fit (module docstring); returns theta, seconds, nfev."""
    from scipy.optimize import least_squares
    from scipy.signal import cont2discrete, dlsim

    h = 1.0 / 2000.0
    F = df["F"].to_numpy()[:, None]
    Z = df[RESPONSES].to_numpy()
    w = 1.0 / np.sqrt(Z.var(axis=0))
    Minv = np.diag(1.0 / MASSES)

    def matrices(th):
        k1, d1, k2, d2, k3, d3 = th
        K = np.array([[k1 + k2, -k2, 0], [-k2, k2 + k3, -k3], [0, -k3, k3]])
        D = np.array([[d1 + d2, -d2, 0], [-d2, d2 + d3, -d3], [0, -d3, d3]])
        A = np.block([[np.zeros((3, 3)), np.eye(3)], [-Minv @ K, -Minv @ D]])
        B = np.vstack([np.zeros((3, 1)), Minv @ np.array([[0.0], [0.0], [1.0]])])
        # outputs in RESPONSES' order: x1, a1, x2, a2, x3, a3
        C = np.zeros((6, 6))
        Dd = np.zeros((6, 1))
        for i in range(3):
            C[2 * i, i] = 1.0
            C[2 * i + 1] = A[3 + i]
            Dd[2 * i + 1] = B[3 + i]
        return A, B, C, Dd

    def residuals(p):
        A, B, C, Dd = matrices(p[:6])
        Ad, Bd, Cd, Ddd, _ = cont2discrete((A, B, C, Dd), h, method="zoh")
        _, y, _ = dlsim((Ad, Bd, Cd, Ddd, h), F, x0=p[6:12])
        return ((y + p[12:18] - Z) * w).ravel()

    p0 = np.concatenate([start, np.zeros(6), np.zeros(6)])
    t0 = time.perf_counter()
    sol = least_squares(residuals, p0, x_scale="jac", method="trf")
    return sol.x[:6], time.perf_counter() - t0, sol.nfev


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="10^4 samples: a smoke run")
    a = ap.parse_args(argv)
    n = 10_000 if a.quick else 100_000
    with tempfile.TemporaryDirectory() as d:
        stand, df = capture(n, Path(d))
    truth = np.array(stand.true_values)
    block = np.asfortranarray(df[stand.channels].to_numpy())
    print(f"output-error fit, 3-DOF chain, {n:,} samples at 2 kHz, 0.5 % noise on x and a: 6 parameters, "
          "6 initial states, 6 offsets")
    t0 = time.perf_counter()
    auto = vibid.identify(stand, df, method="auto", holdout=0)
    t_auto = time.perf_counter() - t0
    start = auto.parameters["value"].to_numpy()
    oe = _core.Oe(stand._core, True)
    t0 = time.perf_counter()
    fit = oe.fit(block, start.reshape(-1, 1))
    t_fit = time.perf_counter() - t0
    t0 = time.perf_counter()
    r = vibid.identify(stand, df, method="oe", holdout=0)
    t_oe = time.perf_counter() - t0
    assert fit["status"] == 0, fit["message"]
    print(f"  vibid: automatic estimate (start) {t_auto:.3f} s; the fit alone (vibid_oe_fit) {t_fit:.3f} s, "
          f"{fit['iterations']} iterations; identify(method='oe') {t_oe:.3f} s")
    theta_a, t_a, nfev = analyst_fit(df, start)
    print(f"  analyst (scipy least_squares + cont2discrete + dlsim): {t_a:.2f} s, {nfev} residual evaluations "
          "(+ 18 per Jacobian)")
    print(f"  ratio analyst / vibid fit: {t_a / t_fit:.1f}x (target >= 20x, vibid <= 2 s: {t_fit:.3f} s)")
    for name, th in (("vibid", fit["theta"]), ("analyst", theta_a)):
        err = 100 * (np.asarray(th) / truth - 1)
        print(f"  {name:8s} error %: " + " ".join(f"{p} {e:+.4f}" for p, e in zip(stand.parameters, err)))
    print(f"  vibid se %: " + " ".join(f"{p} {100 * s / v:.4f}" for p, s, v in zip(stand.parameters, fit["se"], fit["theta"])))
    print(f"  identify(method='oe') equals the fit alone: "
          f"{np.allclose(r.parameters['value'], fit['theta'], rtol=1e-6)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
