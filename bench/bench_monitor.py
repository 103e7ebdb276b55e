#!/usr/bin/env python3
"""Benchmarks of vibidd's change test (issue 32, docs/vibidd.md "alarms"): simulated service
under swinging operating conditions on three stands. Prints figures; never passes or fails on
them (the long Monte Carlo studies are benchmarks, not tests). Exit status 1 only if a tool
fails.

usage: bench/bench_monitor.py BUILD_DIR service [HOURS] [OUT_DIR]
       bench/bench_monitor.py BUILD_DIR delay [OUT_DIR]
       (VIBID_BENCH_STANDS=base2,chain3: only those stands)

service: HOURS (default 24) of stationary service per stand after a reference learned over one
  whole temperature cycle (4 h), the temperature swinging 20 +- 8 degC with a 4 h period plus a
  faster +-2 degC load cycle (23 min), the stiffnesses following it (-0.2 %/K to -0.3 %/K:
  +-2..3 %, far more than the changes the test is to see). Each capture is replayed twice by
  vibidd: at the default rate (1 false alarm a year: expect none) and at 1 an hour
  (false_alarms_per_year = 8766: expect HOURS per stand; the two-sided 95 % Poisson interval
  is printed beside the count). One vibid-sim run per stand writes the capture once
  (~1.4 GB per stand for 24 h at 500 Hz, deleted afterwards).
delay: per stand and change size (0.25, 0.5, 1, 2, 5 % of a stiffness, a step at 30 min after
  a 20 min reference), with and without a temperature swing larger than the change (+-8 degC
  x -0.25 %/K: +-2 %, the temperature mapped as a covariate), at the default rate: the
  detection delay (the first raise of that stiffness after the step) and any other alarm.
  A step not raised within 30 min is "not within 30 min". Prints the README's table.

The stands (500 Hz; their modes between 6 and 60 Hz):
  base2   examples/stands/base2.cfg at 500 Hz (4 unknowns), band-limited random
          base motion, 60 dB noise on x1, x2, s; c1 and c2 follow T
  chain3  examples/stands/chain3.cfg at 500 Hz (6 unknowns), band-limited random force on m3,
          60 dB noise; k1, k2, k3 follow T
  paper1  the paper's example 1 (examples/stands/paper_example1.cfg, 3 unknowns) at 500 Hz,
          random base motion; c1 and c2 follow T, and a second covariate (a speed that moves
          nothing) is mapped too
"""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
RATE = 500.0
# every duration times this (VIBID_BENCH_SCALE=0.01: a smoke run of the script itself)
SCALE = float(os.environ.get("VIBID_BENCH_SCALE", "1"))
# the stands to run (VIBID_BENCH_STANDS=base2,paper1; default all three)
ONLY = [s for s in os.environ.get("VIBID_BENCH_STANDS", "").split(",") if s]
PER_HOUR = 365.25 * 24.0  # false_alarms_per_year for one an hour

STANDS = {
    "base2": {
        "stand": (REPO / "examples" / "stands" / "base2.cfg").read_text().replace("sample_rate = 1000.0",
                                                                                "sample_rate = 500.0"),
        "excitation": '{ target = "base"; kind = "noise"; amplitude = 1.0e-4; f_high = 80.0; }',
        "noise": ["x1", "x2", "s"],
        "channels": [("x1", "displacement", 0), ("x2", "displacement", 1), ("s", "base_displacement", None)],
        "follow": {"c1": -0.003, "c2": -0.003},
        "crack": "c2",
    },
    "chain3": {
        "stand": (REPO / "examples" / "stands" / "chain3.cfg").read_text().replace("sample_rate = 2000.0",
                                                                                 "sample_rate = 500.0"),
        "excitation": '{ target = "f"; kind = "noise"; amplitude = 5.0; f_high = 80.0; }',
        "noise": ["x1", "x2", "x3", "a1", "a2", "a3"],
        "channels": [("F", "force", 2), ("x1", "displacement", 0), ("x2", "displacement", 1),
                     ("x3", "displacement", 2), ("a1", "acceleration", 0), ("a2", "acceleration", 1),
                     ("a3", "acceleration", 2)],
        "follow": {"k1": -0.002, "k2": -0.002, "k3": -0.002},
        "crack": "k2",
    },
    "paper1": {
        "stand": (REPO / "examples" / "stands" / "paper_example1.cfg").read_text().replace(
            "sample_rate = 2000.0", "sample_rate = 500.0"),
        "excitation": '{ target = "base"; kind = "noise"; amplitude = 1.0e-3; f_high = 80.0; }',
        "noise": ["x1", "x2"],
        "channels": [("x1", "displacement", 0), ("x2", "displacement", 1), ("s", "base_displacement", None)],
        "follow": {"c1": -0.0025, "c2": -0.0025},
        "crack": "c2",
        "speed": True,
    },
}


def sim_group(spec: dict, seed: int, duration: float, temp: tuple[float, float, float], changes: str) -> str:
    """The simulation group: excitation, 60 dB noise, T = 20 + a sin(2 pi t / period) + the
    load cycle, the dependence, the changes."""
    amp, period, load = temp
    noise = ", ".join(f'{{ channel = "{c}"; snr_db = 60.0; }}' for c in spec["noise"])
    cov = [f'{{ name = "T"; unit = "degC"; mean = 20.0; amplitude = {amp}; period = {period}; noise = 0.05; }}']
    if load:
        cov.append(f'{{ name = "Tload"; unit = "degC"; mean = 0.0; amplitude = {load}; period = 1380.0; }}')
    if spec.get("speed"):
        cov.append('{ name = "speed"; unit = "rpm"; mean = 1500.0; amplitude = 300.0; period = 5000.0; noise = 1.0; }')
    dep = []
    for p, a in spec["follow"].items():
        dep.append(f'{{ parameter = "{p}"; covariate = "T"; coefficient = {a}; reference = 20.0; }}')
        if load:
            dep.append(f'{{ parameter = "{p}"; covariate = "Tload"; coefficient = {a}; reference = 0.0; }}')
    return f"""simulation = {{ seed = {seed}; duration = {duration};
  excitation = ( {spec["excitation"]} );
  noise = ( {noise} );
  covariates = ( {", ".join(cov)} );
  dependence = ( {", ".join(dep)} );
  {changes} }};
"""


def vibidd_cfg(spec: dict, capture: str, covariates: list[str], alarms: str) -> str:
    ch = []
    for name, q, node in spec["channels"]:
        n = f" node = {node};" if node is not None else ""
        ch.append(f'    {{ name = "{name}"; quantity = "{q}";{n} column = "{name}"; }}')
    for c in covariates:
        ch.append(f'    {{ name = "{c}"; quantity = "covariate"; column = "{c}"; }}')
    channels = ",\n".join(ch)
    return f"""stand = "stand.cfg";
source = {{ kind = "replay"; file = "{capture}"; time_column = "t";
  channels = (
{channels}
  ); }};
estimator = {{ forgetting = 0.999; }};
alarms = {{ {alarms} }};
outputs = {{ influx = {{ path = "lines.influx"; }}; }};
"""


def run(cmd: list[str], cwd: Path, what: str) -> float:
    t0 = time.monotonic()
    r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"{what} failed ({r.returncode}): {r.stderr[-2000:]}")
    (cwd / f"{what}.log").write_text(r.stderr)
    return time.monotonic() - t0


def alarms(path: Path) -> list[tuple[str, str, int]]:
    """(parameter, state, sample index) of every alarm line."""
    out = []
    for line in path.read_text().splitlines():
        m = re.match(r'vibid_alarm,parameter=([^,]*),.*state="([a-z]*)".*,index=(\d+)i', line)
        if m:
            out.append((m.group(1), m.group(2), int(m.group(3))))
    return out


def poisson_interval(mu: float) -> tuple[float, float]:
    """The two-sided 95 % interval of a Poisson count with mean mu: the quantiles 2.5 % and
    97.5 % (summed exactly)."""
    def cdf(k):
        s, term = 0.0, math.exp(-mu)
        for i in range(k + 1):
            s += term
            term *= mu / (i + 1)
        return s
    lo = next(k for k in range(10 * int(mu) + 20) if cdf(k) >= 0.025)
    hi = next(k for k in range(10 * int(mu) + 20) if cdf(k) >= 0.975)
    return lo, hi


def service(build: Path, hours: float, out: Path) -> None:
    sim, vibidd = build / "sim" / "vibid-sim", build / "daemon" / "vibidd"
    learn_s, warm_s = 4 * 3600.0 * SCALE, 60.0
    hours *= SCALE
    total = warm_s + learn_s + hours * 3600.0
    print(f"service: {hours:g} h tested per stand after a {learn_s / 3600:g} h reference, {RATE:g} Hz, "
          f"T 20 +- 8 degC (4 h) + 2 degC (23 min)")
    print("| stand | samples | sim s | vibidd s (default, 1/h) | alarms at 1/year | raised at 1/h | "
          "95 % Poisson interval of the expected count | rows C |")
    print("|---|---|---|---|---|---|---|---|")
    for name, spec in STANDS.items():
        if ONLY and name not in ONLY:
            continue
        d = out / name
        d.mkdir(parents=True, exist_ok=True)
        (d / "stand.cfg").write_text(spec["stand"] + sim_group(spec, 7, total, (8.0, 14400.0 * SCALE, 2.0), ""))
        t_sim = run([str(sim), "-c", "stand.cfg", "--csv", "cap.csv", "-q"], d, "sim")
        covs = ["T", "Tload"] + (["speed"] if spec.get("speed") else [])
        common = f"learn_start = {warm_s}; learn_duration = {learn_s};"
        counts, times, rows_c = [], [], 0
        for rate in (None, PER_HOUR):
            a = common + (f" false_alarms_per_year = {rate};" if rate else "")
            (d / "v.cfg").write_text(vibidd_cfg(spec, "cap.csv", covs, a))
            (d / "lines.influx").unlink(missing_ok=True)
            times.append(run([str(vibidd), "-c", "v.cfg", "--log-level", "info"], d, "vibidd"))
            ev = alarms(d / "lines.influx")
            counts.append(sum(1 for e in ev if e[1] == "raised"))
            if rate:
                rows_c = sum(1 for line in (d / "lines.influx").read_text().splitlines()
                             if line.startswith("vibid,") and re.search(r'flags="[A-Z]*C', line))
        lo, hi = poisson_interval(hours)
        print(f"| {name} | {int(total * RATE)} | {t_sim:.0f} | {times[0]:.0f}, {times[1]:.0f} | {counts[0]} | "
              f"{counts[1]} | [{lo}, {hi}] (expected {hours:g}) | {rows_c} |", flush=True)
        (d / "cap.csv").unlink()


def delay(build: Path, out: Path) -> None:
    sim, vibidd = build / "sim" / "vibid-sim", build / "daemon" / "vibidd"
    sizes = [0.25, 0.5, 1.0, 2.0, 5.0]
    step_s, learn_s, total = 1800.0 * SCALE, 1200.0 * SCALE, 3600.0 * SCALE
    print(f"delay: a step of one stiffness at {step_s / 60:g} min after a {learn_s / 60:g} min reference, "
          f"default rate (1 false alarm a year), {RATE:g} Hz")
    print("| stand (stiffness) | conditions | " + " | ".join(f"{s:g} %" for s in sizes) + " | other alarms | MDC |")
    print("|---|---|" + "---|" * len(sizes) + "---|---|")
    for name, spec in STANDS.items():
        if ONLY and name not in ONLY:
            continue
        p = spec["crack"]
        for swing in (False, True):
            cells, other, mdc = [], 0, ""
            for i, size in enumerate(sizes):
                d = out / f"{name}_{'swing' if swing else 'steady'}_{size:g}"
                d.mkdir(parents=True, exist_ok=True)
                change = f'changes = ( {{ parameter = "{p}"; at = {step_s}; factor = {1 - size / 100:.6f}; }} );'
                temp = (8.0, 2400.0 * SCALE, 0.0) if swing else (0.0, 1.0, 0.0)
                (d / "stand.cfg").write_text(spec["stand"] + sim_group(spec, 100 + i, total, temp, change))
                run([str(sim), "-c", "stand.cfg", "--csv", "cap.csv", "-q"], d, "sim")
                covs = ["T"] + (["speed"] if spec.get("speed") else [])
                (d / "v.cfg").write_text(vibidd_cfg(spec, "cap.csv", covs if swing else [],
                                                    f"learn_duration = {learn_s};"))
                (d / "lines.influx").unlink(missing_ok=True)
                run([str(vibidd), "-c", "v.cfg", "--log-level", "info"], d, "vibidd")
                ev = [e for e in alarms(d / "lines.influx") if e[1] == "raised"]
                hit = [e for e in ev if e[0] == p and e[2] >= step_s * RATE]
                other += len([e for e in ev if e not in hit[:1]])
                cells.append(f"{(hit[0][2] / RATE - step_s):.1f} s" if hit else "not within 30 min")
                if not mdc:
                    m = re.search(rf"alarm reference of {p}: .*detectable change [^ ]* \(([^ ]*) %\)",
                                  (d / "vibidd.log").read_text())
                    mdc = f"{m.group(1)} %" if m else "?"
                (d / "cap.csv").unlink()
            print(f"| {name} ({p}) | {'T +-8 degC: +-2 %, mapped' if swing else 'steady'} | " + " | ".join(cells)
                  + f" | {other} | {mdc} |", flush=True)


def main() -> None:
    if len(sys.argv) < 3 or sys.argv[2] not in ("service", "delay"):
        sys.exit(__doc__)
    build = Path(sys.argv[1]).resolve()
    if sys.argv[2] == "service":
        hours = float(sys.argv[3]) if len(sys.argv) > 3 else 24.0
        out = Path(sys.argv[4] if len(sys.argv) > 4 else "out/monitor_service").resolve()
        service(build, hours, out)
    else:
        out = Path(sys.argv[3] if len(sys.argv) > 3 else "out/monitor_delay").resolve()
        delay(build, out)


if __name__ == "__main__":
    main()
