"""Monte Carlo coverage of vibid's error bars on five stands (issue 29, item 5).

    python python/bench/bench_coverage.py               # 20 realisations per stand, ~10-30 min
    python python/bench/bench_coverage.py --runs 5      # a smoke run
    python python/bench/bench_coverage.py --stands chain3,cubic1

For each stand, realisations with different seeds are simulated by vibid-sim (the suite's
build, or VIBID_SIM) and identified as a new user would: ``vibid.identify(stand, capture)``
with no options (``auto``: the validated choice for fully measured stands, the library's
EKF for the others). Every stand is sampled at 9 samples per period of its highest mode
(the issue's 8-10), its response channels carry 1 % sensor noise (40 dB SNR), one of them
coloured (correlation time 2 sample periods), displacement sensors a constant offset of
10 % of their RMS, and the linear stands a weak cubic spring in the simulation that the
identified model lacks (0.5 % of the linear force at the RMS deflection).

Per stand and parameter it prints the coverage of the 2-se interval (fraction of
realisations with |value - true| <= 2 se; the target band is 90-98 %), the ratio of the
estimates' spread to their median standard error, the largest |z|, and how many rows were
flagged (a flagged row does not claim its error bars: it is counted apart, its z is not
in the coverage). With 20 realisations a true 95 % coverage reads 85-100 % (binomial 2 sd):
the figures are for the README's table, never a pass/fail test (the project's rule:
Monte Carlo studies are benchmarks)."""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

import vibid
from vibid._stand import to_libconfig

from bench_oe import sim_path  # vibid-sim of the suite's build, or VIBID_SIM (this folder)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from oma_sim import chain_matrices  # noqa: E402  (M, D, C of a chain ground - m1 - m2 - ...)

SAMPLES_PER_PERIOD = 9.0


def f_max(M, C) -> float:
    w2 = np.linalg.eigvals(np.linalg.solve(M, C)).real
    return float(np.sqrt(w2.max()) / (2 * np.pi))


def chain_stand(name, masses, springs, dampers, measure, inputs, nominal_off=0.0, cubic=None):
    """A chain stand dict: node i measured as measure[i] (dict or None); inputs: a list of
    input dicts; unknown springs and dampers with true values, nominal values off by
    nominal_off (needed by the EKF); cubic: (eps, node index) a cubic spring to the ground."""
    M, _, C = chain_matrices(masses, springs, dampers)
    fa = round(SAMPLES_PER_PERIOD * f_max(M, C))
    nodes = []
    for i, m in enumerate(masses):
        node = {"name": f"m{i + 1}", "mass": m}
        if measure[i]:
            node["measure"] = measure[i]
        nodes.append(node)
    elements = []
    for i, (k, d) in enumerate(zip(springs, dampers)):
        lo = "ground" if i == 0 else f"m{i}"
        for kind, nm, v in (("spring", f"k{i + 1}", k), ("damper", f"d{i + 1}", d)):
            e = {"name": nm, "kind": kind, "between": [f"m{i + 1}", lo], "unknown": True, "true_value": v}
            if nominal_off:
                e["value"] = v * (1 + nominal_off * (1 if i % 2 else -1))
            elements.append(e)
    if cubic:
        eps, node = cubic
        elements.append({"name": "eps", "kind": "cubic_spring", "between": [f"m{node + 1}", "ground"],
                         "unknown": True, "true_value": eps})
    return {"name": name, "sample_rate": float(fa), "nodes": nodes, "elements": elements, "inputs": inputs}


def with_unmodelled_cubic(stand: dict, eps: float, node: str) -> dict:
    """The simulation's stand: the identified one plus a known cubic spring node - ground."""
    d = dict(stand)
    d["elements"] = list(stand["elements"]) + [
        {"name": "eps_unmodelled", "kind": "cubic_spring", "between": [node, "ground"], "value": eps}]
    return d


def scenarios():
    """(name, identified stand dict, simulated stand dict, simulation group text)."""
    out = []
    # 1. fully measured 3-DOF chain: displacements, a held force on m3 (its load cell).
    m, k, d = [2.0, 1.5, 1.0], [4.0e4, 3.0e4, 2.0e4], [20.0, 15.0, 10.0]
    meas = [{"displacement": f"x{i}"} for i in (1, 2, 3)]
    st = chain_stand("chain3", m, k, d, meas, [{"name": "f", "node": "m3", "channel": "F", "hold": "zoh"}])
    # RMS deflection of m1 1.16e-3 m (20 N band-limited force, measured): 0.5 % of k1 x there
    x_rms = 1.16e-3
    sim_st = with_unmodelled_cubic(st, 0.005 * k[0] / x_rms ** 2, "m1")
    fa = st["sample_rate"]
    sim = ("simulation = { excitation = ( { target = \"f\"; kind = \"noise\"; amplitude = 20.0; f_high = %g; } );\n"
           "  noise = ( { channel = \"x1\"; snr_db = 40.0; offset = 1.2e-4; },\n"
           "            { channel = \"x2\"; snr_db = 40.0; correlation_time = %g; },\n"
           "            { channel = \"x3\"; snr_db = 40.0; } ); };\n") % (0.4 * fa, 2.0 / fa)
    out.append(("chain3 fully measured (x, force)", st, sim_st, sim, 20.0))

    # 2. 1-DOF cubic oscillator (the real capture's kind): displacement with an offset, force.
    st = chain_stand("cubic1", [1.0], [4.0e4], [8.0], [{"displacement": "x1"}],
                     [{"name": "f", "node": "m1", "channel": "F"}], cubic=(5.0e9, 0))
    fa = st["sample_rate"]
    sim = ("simulation = { excitation = ( { target = \"f\"; kind = \"noise\"; amplitude = 40.0; f_high = %g; } );\n"
           "  noise = ( { channel = \"x1\"; snr_db = 40.0; offset = 1.6e-4; correlation_time = %g; } ); };\n") % (
        0.4 * fa, 2.0 / fa)
    out.append(("cubic 1 DOF (x with offset, force)", st, st, sim, 10.0))

    # 3. four masses, accelerometers and a load cell only (the EKF's case).
    m, k, d = [1.0, 1.0, 1.0, 1.0], [6.0e5, 6.0e5, 6.0e5, 6.0e5], [60.0, 60.0, 60.0, 60.0]
    meas = [{"acceleration": f"a{i}"} for i in (1, 2, 3, 4)]
    st = chain_stand("accel4", m, k, d, meas, [{"name": "f", "node": "m4", "channel": "F"}], nominal_off=0.1)
    fa = st["sample_rate"]
    sim_st = with_unmodelled_cubic(st, 0.005 * k[0] / (2e-5) ** 2, "m1")  # x1 RMS ~ a1 / w^2 = 2e-5 m
    sim = ("simulation = { excitation = ( { target = \"f\"; kind = \"noise\"; amplitude = 20.0; f_high = %g; } );\n"
           "  noise = ( { channel = \"a1\"; snr_db = 40.0; correlation_time = %g; }, { channel = \"a2\"; snr_db = 40.0; },\n"
           "            { channel = \"a3\"; snr_db = 40.0; }, { channel = \"a4\"; snr_db = 40.0; } ); };\n") % (
        0.4 * fa, 2.0 / fa)
    out.append(("4 masses, accelerations + load cell", st, sim_st, sim, 10.0))

    # 4. impact hammer: 2 masses, hammer blows on m1 (force measured), accelerations.
    m, k, d = [0.5, 0.5], [2.0e6, 2.0e6], [40.0, 40.0]
    meas = [{"acceleration": "a1"}, {"acceleration": "a2"}]
    st = chain_stand("hammer2", m, k, d, meas, [{"name": "f", "node": "m2", "channel": "F"}], nominal_off=0.1)
    fa = st["sample_rate"]
    blows = ",\n    ".join(
        "{ target = \"f\"; kind = \"constant\"; amplitude = %g; t_on = %g; t_off = %g; }" % (200.0 * (1 + 0.3 * (i % 3)),
                                                                                        0.05 + 0.25 * i,
                                                                                        0.05 + 0.25 * i + 2.0 / fa)
        for i in range(16))
    sim = ("simulation = { excitation = (\n    %s );\n"
           "  noise = ( { channel = \"a1\"; snr_db = 40.0; correlation_time = %g; }, { channel = \"a2\"; snr_db = 40.0; },\n"
           "            { channel = \"F\"; snr_db = 60.0; } ); };\n") % (blows, 2.0 / fa)
    out.append(("impact hammer, accelerations", st, st, sim, 4.0))

    # 5. two masses on a moving base, the lower one unmeasured (test_ekf.c's base2, scaled).
    st = {"name": "base2", "sample_rate": 0.0,
          "nodes": [{"name": "m1", "mass": 1.5, "measure": {"displacement": "x1"}}, {"name": "m2", "mass": 3.0}],
          "base": {"measure": {"displacement": "s"}},
          "elements": [
              {"name": "c1", "kind": "spring", "between": ["m1", "m2"], "unknown": True, "value": 7.2e4, "true_value": 6.0e4},
              {"name": "d1", "kind": "damper", "between": ["m1", "m2"], "unknown": True, "value": 12.0, "true_value": 15.0},
              {"name": "c2", "kind": "spring", "between": ["m2", "base"], "unknown": True, "value": 1.0e5, "true_value": 1.2e5},
              {"name": "d2", "kind": "damper", "between": ["m2", "base"], "unknown": True, "value": 37.5, "true_value": 30.0}]}
    M, _, C = np.diag([1.5, 3.0]), None, np.array([[6e4, -6e4], [-6e4, 1.8e5]])
    st["sample_rate"] = float(round(SAMPLES_PER_PERIOD * f_max(M, C)))
    fa = st["sample_rate"]
    sim_st = with_unmodelled_cubic(st, 0.005 * 6e4 / (3.65e-4) ** 2, "m1")  # x1 RMS 3.65e-4 m
    sim = ("simulation = { excitation = ( { target = \"base\"; kind = \"noise\"; amplitude = 1.0e-4; f_high = %g; } );\n"
           "  noise = ( { channel = \"x1\"; snr_db = 40.0; offset = 3.6e-5; correlation_time = %g; },\n"
           "            { channel = \"s\"; snr_db = 40.0; } ); };\n") % (0.4 * fa, 2.0 / fa)
    out.append(("2 masses, one unmeasured, base", st, sim_st, sim, 20.0))
    return out


def run_stand(name, st, sim_st, sim, seconds, runs, tmp: Path, simulator: Path):
    stand = vibid.Stand.from_dict(st)
    sim_file = tmp / "stand_sim.cfg"
    sim_file.write_text(to_libconfig(sim_st) + sim)
    rows = []
    t0 = time.perf_counter()
    for seed in range(1, runs + 1):
        out = tmp / f"cap{seed}.csv"
        p = subprocess.run([str(simulator), "-c", str(sim_file), "-s", str(sim_file), "--csv", str(out), "--fast",
                            "-d", str(seconds), "--seed", str(seed)], capture_output=True, text=True)
        if p.returncode != 0:
            print(f"  {name}: seed {seed}: vibid-sim failed: {p.stderr.strip()[-300:]}", flush=True)
            continue
        data = pd.read_csv(out, comment="#")
        try:
            r = vibid.identify(stand, data)
        except Exception as e:  # a refusal is a result too: counted, not a crash of the study
            print(f"  {name}: seed {seed}: {type(e).__name__}: {e}", flush=True)
            continue
        for pname, row in r.parameters.iterrows():
            rows.append({"seed": seed, "parameter": pname, "value": row["value"], "se": row["se"],
                         "true": row["true_value"], "flags": row["flags"] or "", "method": r.config["method"]})
    dt = time.perf_counter() - t0
    return pd.DataFrame(rows), dt


def summarise(name, df: pd.DataFrame, dt: float, runs: int, fa: float):
    if df.empty:
        print(f"| {name} | - | no estimate in {runs} realisations | | | | |")
        return
    method = ",".join(sorted(set(df["method"])))
    for pname, g in df.groupby("parameter", sort=False):
        z = (g["value"] - g["true"]) / g["se"]
        ok = g[g["flags"].str.len() == 0]
        zo = (ok["value"] - ok["true"]) / ok["se"]
        cov = float((zo.abs() <= 2.0).mean()) if len(ok) else float("nan")
        spread = float(g["value"].std(ddof=1) / g["se"].median()) if len(g) > 1 else float("nan")
        bias = float((g["value"].mean() / g["true"].iloc[0] - 1) * 100)
        print(f"| {name} | {method} | {pname} | {len(g)}/{runs} | {len(g) - len(ok)} | "
              f"{cov * 100:.0f} % | {spread:.2f} | {z.abs().max():.1f} | {bias:+.3f} % |", flush=True)
    print(f"|   | ({dt:.0f} s for {runs} realisations at {fa:g} Hz) | | | | | | | |", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--stands", default="", help="comma-separated stand names (default all)")
    a = ap.parse_args(argv)
    simulator = sim_path()
    if not simulator.is_file():
        print(f"bench_coverage: no vibid-sim at {simulator} (build the C suite, or set VIBID_SIM)", file=sys.stderr)
        return 2
    want = set(filter(None, a.stands.split(",")))
    print("| stand | estimator | parameter | estimates | flagged | coverage of 2 se (unflagged) | spread / se | "
          "max abs z | mean error |")
    print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as d:
        for name, st, sim_st, sim, seconds in scenarios():
            if want and st["name"] not in want:
                continue
            df, dt = run_stand(name, st, sim_st, sim, seconds, a.runs, Path(d), simulator)
            summarise(name, df, dt, a.runs, st["sample_rate"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
