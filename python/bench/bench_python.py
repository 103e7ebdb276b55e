"""Benchmark of the Python package (issue 13): prints figures beside a yardstick measured in
the same process; never passes or fails on time (the project's rule for speed).

    python python/bench/bench_python.py            # the figures of docs/python.md "Benchmark"
    python python/bench/bench_python.py --quick    # tiny sizes: a smoke run (python/tests/test_bench.py)

a. vibid.identify on 10^6 samples of the paper's example 1 (0.5 % noise, method auto, holdout 0: the library's automatic estimator) from
   numpy arrays, against the same work done in C in this process (_core.bench_identify_c:
   vibid_ident_create with the same config, every sample through vibid_ident_push in one C
   loop from a buffer already in memory, vibid_ident_estimate; timed in C++ with the GIL
   released). Python / C is the binding's and the Python layer's overhead. Best of the
   repeats, Python and C interleaved so that both see the same machine load.
b. identify_many over CSV files written once: captures/s serially and with 2 processes, and
   the start-up of 2 spawned worker interpreters measured on its own.
c. The analysis by hand in pandas/numpy (central-difference regressors, numpy.linalg.lstsq)
   against vibid.identify on the same DataFrame: time, peak memory (tracemalloc: Python and
   numpy allocations; ru_maxrss of a fresh subprocess per variant: the whole process), and
   each one's error against the truth.

Every figure is one line "  <label>  <value> <unit>  <note>" (labels fixed, for the smoke
test). The captures are conftest.py's exact multisine responses (python/tests), so the
script needs the repository around it and pytest importable (the test venv has both).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import multiprocessing
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pandas as pd

import vibid
from vibid import _core
from vibid._identify import METHODS, _columns
from vibid._many import _identify_one, _stand_spec

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "python" / "tests"))
from conftest import EX1_TRUTH, EXAMPLE1, example1_capture  # noqa: E402

NOISE = 0.005  # 0.5 % of each channel's RMS on x1, x2, s, as in the tests
M1, M2 = 10.0, 20.0  # example 1's known masses (examples/stands/paper_example1.cfg)


def figure(label: str, value: float, unit: str, note: str = "") -> None:
    print(f"  {label:<46s} {value:>12.5g} {unit:<12s} {note}".rstrip(), flush=True)


def spread(times) -> str:
    return f"(repeats {min(times):.3g}-{max(times):.3g} s)"


# ---------------------------------------------------------------- a. Python against C


def bench_identify(stand, n: int, repeats: int) -> None:
    data, _ = example1_capture(n=n, noise=NOISE, seed=11)
    fblock = np.asfortranarray(np.column_stack([data[c] for c in stand.channels]))
    print(f"\na. identify, example 1, {n:,} samples, 0.5 % noise, method auto, holdout 0; best of {repeats}, interleaved")
    t_dict, t_arr, t_c, t_cols = [], [], [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        # holdout=0: the library's automatic estimator alone, what the C loop below runs
        # (auto's validated choice adds the output-error fit: python/bench/bench_oe.py)
        r = vibid.identify(stand, data, holdout=0)
        t_dict.append(time.perf_counter() - t0)
        # The yardstick with identify's settings: auto, forgetting 1, automatic pre-filter and
        # lag (identify passes exactly these for its defaults).
        sec, theta_c, se_c = _core.bench_identify_c(stand._core, fblock, METHODS["auto"], 1.0, -1.0, 0)
        t_c.append(sec)
        t0 = time.perf_counter()
        r_arr = vibid.identify(stand, fblock, holdout=0)
        t_arr.append(time.perf_counter() - t0)
        # What the Python layer does before the C calls: gather the dict into one column-major
        # block and check every value is finite.
        t0 = time.perf_counter()
        _columns(stand, data)
        t_cols.append(time.perf_counter() - t0)
    same = (np.array_equal(r.parameters["value"].to_numpy(), theta_c)
            and np.array_equal(r.parameters["se"].to_numpy(), se_c)
            and np.array_equal(r_arr.parameters["value"].to_numpy(), theta_c))
    bp, ba, bc = min(t_dict), min(t_arr), min(t_c)
    figure("identify, dict of numpy arrays", bp, "s", f"{n / bp / 1e6:.3g} M samples/s {spread(t_dict)}")
    figure("identify, (n, 3) column-major array", ba, "s", f"{n / ba / 1e6:.3g} M samples/s {spread(t_arr)}")
    figure("C yardstick, same calls, timed in C", bc, "s", f"{n / bc / 1e6:.3g} M samples/s {spread(t_c)}")
    # Best over best, and the median of each repeat's own ratio (Python and C run back to
    # back there, so a load that comes and goes on shared cores hits both alike).
    paired = lambda ts: float(np.median(np.array(ts) / np.array(t_c)))  # noqa: E731
    figure("ratio Python / C, dict of arrays", bp / bc, "x",
           f"target <= 1.2; median of the {repeats} paired repeats {paired(t_dict):.3f}")
    figure("ratio Python / C, column-major array", ba / bc, "x",
           f"target <= 1.2; median of the {repeats} paired repeats {paired(t_arr):.3f}")
    figure("of it: gather dict + finiteness check", min(t_cols), "s", f"{spread(t_cols)}")
    figure("same estimate as C (1 = bit-identical)", 1.0 if same else 0.0, "", "theta and se")
    figure("samples per second, C", n / bc, "1/s")


# ---------------------------------------------------------------- b. identify_many


def _probe(_):
    # A worker's first task: vibid imported (the spawned interpreter imported this script as
    # __mp_main__, hence numpy, pandas and vibid, as identify_many's workers do).
    return os.getpid()


def bench_many(n_captures: int, n_samples: int, repeats: int) -> None:
    print(f"\nb. identify_many, {n_captures} CSV captures of {n_samples:,} samples (0.5 % noise), "
          f"{os.cpu_count()} cores; best of {repeats}")
    with tempfile.TemporaryDirectory(prefix="vibid-bench-") as d:
        paths = []
        for i in range(n_captures):
            data, t = example1_capture(n=n_samples, noise=NOISE, seed=100 + i)
            p = os.path.join(d, f"run{i:02d}.csv")
            pd.DataFrame({"time_s": t, **data}).to_csv(p, index=False, float_format="%.17g")
            paths.append(p)
        mb = os.path.getsize(paths[0]) / 1e6
        ctx = multiprocessing.get_context("spawn")
        spec = _stand_spec(vibid.Stand.load(EXAMPLE1))
        t_ser, t_par, t_start, t_warm = [], [], [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            table1 = vibid.identify_many(paths, EXAMPLE1, processes=1)
            t_ser.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            table2 = vibid.identify_many(paths, EXAMPLE1, processes=2)
            t_par.append(time.perf_counter() - t0)
            # The start-up alone: a pool of 2 spawned interpreters, as identify_many makes,
            # each importing numpy, pandas and vibid, one trivial task each, shut down.
            t0 = time.perf_counter()
            with concurrent.futures.ProcessPoolExecutor(max_workers=2, mp_context=ctx) as ex:
                list(ex.map(_probe, range(2)))
            t_start.append(time.perf_counter() - t0)
            # The work alone: the same per-capture function identify_many's pool runs
            # (_identify_one: stand rebuilt once per worker, then identify), on 2 workers
            # started and warmed (stand loaded) before the clock. Subtracting the start-up
            # above from the wall time instead would be the difference of two noisy ~1 s
            # figures for ~0.1 s of work.
            with concurrent.futures.ProcessPoolExecutor(max_workers=2, mp_context=ctx) as ex:
                list(ex.map(_identify_one, [spec] * 2, ["warm"] * 2, paths[:2], ["auto"] * 2, [{}] * 2))
                t0 = time.perf_counter()
                rows = list(ex.map(_identify_one, [spec] * len(paths), paths, paths, ["auto"] * len(paths),
                                   [{}] * len(paths)))
                t_warm.append(time.perf_counter() - t0)
            assert all(r["status"] == "ok" for r in rows), rows
        assert (table1["status"] == "ok").all() and (table2["status"] == "ok").all(), table1["error"]
        ts, tp, st, tw = min(t_ser), min(t_par), min(t_start), min(t_warm)
        figure("serial (processes=1)", n_captures / ts, "captures/s",
               f"{n_captures * n_samples / ts / 1e6:.3g} M samples/s, {mb:.2f} MB CSV each {spread(t_ser)}")
        figure("2 processes, start-up included", n_captures / tp, "captures/s", spread(t_par))
        figure("start-up of 2 spawned workers", st, "s", spread(t_start))
        figure("2 warm processes, start-up excluded", n_captures / tw, "captures/s",
               f"{n_captures * n_samples / tw / 1e6:.3g} M samples/s {spread(t_warm)}")


# ---------------------------------------------------------------- c. by hand


def hand_ls(df: pd.DataFrame, h: float) -> np.ndarray:
    """What an analyst writes: central differences for velocity and acceleration, the two
    equations of motion stacked, plain least squares.
        m1 x1'' = -c1 (x1 - x2) - d (x1' - x2')
        m2 x2'' =  c1 (x1 - x2) + d (x1' - x2') - c2 (x2 - s)
    Returns (c1, d, c2)."""
    x1, x2, s = (df[c].to_numpy() for c in ("x1", "x2", "s"))

    def vel(x):
        return (x[2:] - x[:-2]) / (2 * h)

    def acc(x):
        return (x[2:] - 2 * x[1:-1] + x[:-2]) / (h * h)

    dx = x1[1:-1] - x2[1:-1]
    dv = vel(x1) - vel(x2)
    zero = np.zeros_like(dx)
    X = np.vstack([np.column_stack([-dx, -dv, zero]),
                   np.column_stack([dx, dv, -(x2[1:-1] - s[1:-1])])])
    y = np.concatenate([M1 * acc(x1), M2 * acc(x2)])
    theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    return theta


def vibid_fit(stand, df):
    return vibid.identify(stand, df, holdout=0).parameters["value"].to_numpy()


def _peak_rss_kib() -> tuple[int, int]:
    """(VmHWM, ru_maxrss) of this process in KiB. Linux keeps ru_maxrss across execve as the
    larger of the new image's peak and the peak of the image it replaced (the forked copy of
    the parent, here the benchmark holding 10^6-sample captures), so in a child it can show
    the parent's size; VmHWM (/proc/self/status) is the peak of this image alone. Where
    there is no /proc, ru_maxrss for both."""
    maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]), maxrss
    except OSError:
        pass
    return maxrss, maxrss


def _rss_child(variant: str, npy: str) -> None:
    """A fresh process: imports, the capture as a DataFrame, then one variant; prints its
    peak resident set (VmHWM and ru_maxrss, KiB)."""
    stand = vibid.Stand.load(EXAMPLE1)
    df = pd.DataFrame(np.load(npy), columns=stand.channels)
    if variant == "hand":
        hand_ls(df, 1.0 / stand.sample_rate)
    elif variant == "vibid":
        vibid_fit(stand, df)
    print(*_peak_rss_kib())


def bench_by_hand(stand, n: int, repeats: int) -> None:
    data, _ = example1_capture(n=n, noise=NOISE, seed=23)
    df = pd.DataFrame(data)
    h = 1.0 / stand.sample_rate
    truth = np.array([EX1_TRUTH[p] for p in stand.parameters])
    print(f"\nc. by hand in pandas/numpy (central differences, numpy.linalg.lstsq) against vibid.identify, "
          f"{n:,} samples in a DataFrame, 0.5 % noise; best of {repeats}")
    t_hand, t_vib = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        th_hand = hand_ls(df, h)
        t_hand.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        th_vib = vibid_fit(stand, df)
        t_vib.append(time.perf_counter() - t0)
    figure("by hand: time", min(t_hand), "s", spread(t_hand))
    figure("vibid.identify: time", min(t_vib), "s", spread(t_vib))
    # tracemalloc sees what Python and numpy allocate (numpy reports its buffers to it), not
    # libvibid's own C++ memory: hence also the RSS of a fresh process per variant below.
    for label, fn in (("by hand", lambda: hand_ls(df, h)), ("vibid.identify", lambda: vibid_fit(stand, df))):
        tracemalloc.start()
        fn()
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        figure(f"{label}: tracemalloc peak", peak / 2**20, "MiB")
    with tempfile.TemporaryDirectory(prefix="vibid-bench-") as d:
        npy = os.path.join(d, "capture.npy")
        np.save(npy, np.column_stack([data[c] for c in stand.channels]))
        rss = {}
        for variant in ("load", "hand", "vibid"):
            out = subprocess.run([sys.executable, __file__, "--rss-child", variant, npy], check=True,
                                 capture_output=True, text=True).stdout
            hwm, maxrss = (int(v) / 1024.0 for v in out.split()[-2:])
            rss[variant] = hwm
            rss["maxrss_" + variant] = maxrss
    figure("peak RSS, imports + DataFrame only", rss["load"], "MiB",
           f"(fresh process, VmHWM: the baseline; its ru_maxrss {rss['maxrss_load']:.1f} MiB)")
    for label, v in (("by hand", "hand"), ("vibid.identify", "vibid")):
        figure(f"{label}: peak RSS", rss[v], "MiB", f"(+{rss[v] - rss['load']:.1f} MiB over the baseline)")
    for label, th in (("by hand", th_hand), ("vibid.identify", th_vib)):
        err = 100.0 * (th - truth) / truth
        worst = float(np.max(np.abs(err)))
        figure(f"{label}: largest |error| vs truth", worst, "%",
               ", ".join(f"{p} {e:+.3g} %" for p, e in zip(stand.parameters, err)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes, a smoke run (also VIBID_BENCH_QUICK=1)")
    ap.add_argument("--rss-child", nargs=2, metavar=("VARIANT", "NPY"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.rss_child:
        _rss_child(*args.rss_child)
        return
    quick = args.quick or os.environ.get("VIBID_BENCH_QUICK", "") not in ("", "0")
    # Sizes: 10^6 samples (500 s at 2 kHz) for a and c; 20 captures of 20,000 samples for b.
    n, n_caps, n_cap_samples, repeats = (20_000, 4, 20_000, 2) if quick else (1_000_000, 20, 20_000, 5)
    stand = vibid.Stand.load(EXAMPLE1)
    load = os.getloadavg()
    print(f"vibid {vibid.__version__} Python benchmark: python {platform.python_version()}, numpy {np.__version__}, "
          f"pandas {pd.__version__}; {os.cpu_count()} cores, load average {load[0]:.1f} at the start"
          + (" (--quick: smoke-test sizes, figures meaningless)" if quick else ""))
    bench_identify(stand, n, repeats)
    bench_many(n_caps, n_cap_samples, 2 if quick else 3)
    bench_by_hand(stand, n, 2 if quick else 3)
    print(f"\nload average at the end: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
