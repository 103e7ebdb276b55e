#!/usr/bin/env python3
"""Track the first bending mode of the DROPBEAR cantilever over sliding windows with
vibid.oma (output-only SSI-cov) and plot its frequency against the measured roller
position PinLoc.

Data: DROPBEAR Dataset-8 (A. Vereen, A. Downey, J. Dodson, A. G. Moura, "Dataset-8
DROPBEAR Acceleration vs Roller Displacement", 2023; testbed: Downey et al., Mech. Syst.
Signal Process. 138 (2020) 106551), CC BY-SA 4.0: shared/realdata/dropbear/ (README.md,
LICENSE_header.txt). The figure this script writes is an adaptation of that data and
carries the same licence and attribution.

The captures ramp10_test{0,1,2}: a steel cantilever whose roller support steps 5 times
away from its start (PinLoc 1.23 V -> 3.37 V) and 5 times back, 1 s dwell each, 0.2 s
moves; the first bending mode rises from about 26 Hz to about 42 Hz. Nothing measures the
excitation (the roller's motion and whatever the rig passes on), so the identification is
output-only.

Usage (from the repository root, in an environment with vibid, scipy and matplotlib):

    python python/examples/dropbear/track_first_mode.py
    python python/examples/dropbear/track_first_mode.py --captures 0 --window 1.0 --hop 0.5
    python python/examples/dropbear/track_first_mode.py --stab-damping 1.0

How the first mode is picked in a window: among the modes vibid.oma selects, those in the
band --band (15-80 Hz: the first mode lies in 26-42 Hz over the roller's whole travel, the
second bending mode at 160-270 Hz, so the band holds only the first mode and spurious
poles) with MPC > 0.5; of these the one with the smallest frequency standard error (the
first mode dominates the response in this band, so it is the best determined pole there;
noise modes come with standard errors of Hz). Windows without such a mode count as lost.
"""

from __future__ import annotations

import argparse
import gzip
import os
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parents[3]
COLUMNS = ["Low G Accel", "Accel", "PinLoc", "Time"]
FS_RAW = 5000.0  # Hz, the captures' rate (checked against their Time column)


def load_capture(path: Path) -> pd.DataFrame:
    """One ramp10 capture: 9 header lines, then tab-separated Low G Accel, Accel, PinLoc, Time."""
    with gzip.open(path, "rt") as fh:
        a = np.loadtxt(fh, skiprows=9)
    if a.ndim != 2 or a.shape[1] != len(COLUMNS):
        raise SystemExit(f"{path}: expected {len(COLUMNS)} columns {COLUMNS}, got shape {a.shape}")
    df = pd.DataFrame(a, columns=COLUMNS)
    dt = np.diff(df["Time"].to_numpy())
    if not np.allclose(dt, 1.0 / FS_RAW, rtol=1e-6, atol=1e-9):
        raise SystemExit(f"{path}: time step {dt.min():g}..{dt.max():g} s, expected {1 / FS_RAW:g} s")
    return df


def preprocess(df: pd.DataFrame, channels: list[str], q: int) -> tuple[np.ndarray, float]:
    """The response channels, mean removed, decimated by q over the whole capture.

    scipy.signal.decimate (order-8 Chebyshev I low-pass at 0.8 of the new Nyquist, run
    forwards and backwards, so no phase shift and no filter transient inside the windows)
    then keeps every q-th sample. At q = 10 (500 Hz) the band left is 0-200 Hz: the first
    mode (26-42 Hz) has 12-19 samples per period, and the model order is no longer spent on
    the modes and noise up to 2.5 kHz that the raw 5 kHz data hold."""
    from scipy import signal

    x = df[channels].to_numpy(float)
    x = x - x.mean(axis=0)
    if q > 1:
        x = signal.decimate(x, q, ftype="iir", zero_phase=True, axis=0)
    return np.ascontiguousarray(x), FS_RAW / q


def roller_moving(pin: np.ndarray, fs: float, tol: float) -> bool:
    """True when the roller moves within the window: PinLoc, smoothed over 20 ms (its
    noise is about 4 mV rms at rest), spans more than tol volts."""
    k = max(1, int(round(0.02 * fs)))
    sm = np.convolve(pin, np.ones(k) / k, mode="valid")
    return bool(sm.max() - sm.min() > tol)


def band_diagnostics(poles: pd.DataFrame, band: tuple[float, float], stab_freq: float) -> dict:
    """What the stabilisation diagram holds in the band, whatever the selection made of it:
    the poles (physical or not) that have a pole of the order below within stab_freq in
    frequency (stable by frequency alone), how many of them the library marks stable and
    physical, how many have zeta <= 0 (not physical: oma.h 5. needs 0 < zeta), and the
    median of |zeta| / zeta_se over them (below 2: the damping is zero within 2 se)."""
    p = poles[(poles.freq_hz >= band[0]) & (poles.freq_hz <= band[1])]
    n_f = n_ok = n_neg = 0
    zr = []
    for _, r in p.iterrows():
        below = poles[poles.order == r.order - 2]
        if len(below) and np.min(np.abs(below.freq_hz - r.freq_hz)) <= stab_freq * r.freq_hz:
            n_f += 1
            n_ok += int(r.stable and r.physical)
            n_neg += int(r.zeta <= 0)
            zr.append(abs(r.zeta) / r.zeta_se if r.zeta_se > 0 else np.inf)
    return {"band_fstable": n_f, "band_stable_phys": n_ok, "band_zeta_le0": n_neg,
            "band_zeta_over_se": float(np.median(zr)) if zr else float("nan")}


def track(x: np.ndarray, pin: np.ndarray, fs: float, args, thresholds: dict) -> pd.DataFrame:
    import vibid

    n = int(round(args.window * fs))
    hop = int(round(args.hop * fs))
    q = args.decimate
    i = args.block_rows
    # As many covariance blocks as the library allows (each >= 4 block_rows samples), at
    # most its default 32: the standard errors come from the blocks' spread, so more is
    # better; 0.5 s at 500 Hz with block_rows 10 gives 6 blocks of 80 ms.
    blocks = min(32, n // (4 * i))
    if blocks < 2:
        raise SystemExit(f"window {args.window} s at {fs:g} Hz is {n} samples: fewer than 2 blocks of "
                         f"4 x block_rows = {4 * i}; lengthen the window or lower --block-rows")
    rows = []
    for s in range(0, x.shape[0] - n + 1, hop):
        w = x[s:s + n] - x[s:s + n].mean(axis=0)
        p = pin[s * q:(s + n) * q]  # PinLoc at the raw rate over the same span
        r = vibid.oma(w, fs, channels=args.channels, block_rows=i, max_order=args.max_order, blocks=blocks,
                      thresholds=thresholds)
        m = r.modes
        cand = m[(m.freq_hz >= args.band[0]) & (m.freq_hz <= args.band[1]) & (m.mpc > 0.5)]
        row = {"t0_s": s / fs, "t1_s": (s + n) / fs, "pin_mean_v": p.mean(), "pin_span_v": np.ptp(p),
               "moving": roller_moving(p, FS_RAW, args.rest_tol), "n_candidates": len(cand),
               "f_hz": np.nan, "f_se_hz": np.nan, "zeta": np.nan, "zeta_se": np.nan, "order": 0, "n_poles": 0}
        if len(cand):
            best = cand.sort_values(["freq_hz_se", "freq_hz"]).iloc[0]
            row.update(f_hz=best.freq_hz, f_se_hz=best.freq_hz_se, zeta=best.zeta, zeta_se=best.zeta_se,
                       order=int(best.order), n_poles=int(best.n_poles))
        row.update(band_diagnostics(r.poles, tuple(args.band), thresholds["stab_freq"]))
        rows.append(row)
    out = pd.DataFrame(rows)
    out.attrs.update(blocks=blocks, block_samples=n // blocks, max_order=r.config["max_order"])
    return out


def fit_quadratic(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """An empirical monotone description f(PinLoc): least-squares quadratic, unweighted (the
    standard errors from 6 blocks are themselves uncertain by +-30 %, so they weigh badly)."""
    return np.polyfit(v, f, 2)


def dwell_levels(v: np.ndarray, gap: float = 0.15) -> np.ndarray:
    """Group PinLoc means into the dwell positions (positions are 0.42 V apart)."""
    order = np.argsort(v)
    lab = np.zeros(len(v), int)
    k = 0
    for a, b in zip(order[:-1], order[1:]):
        if v[b] - v[a] > gap:
            k += 1
        lab[b] = k
    return lab


def plot(results: dict, traces: dict, coef, args, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10.0, 4.2), layout="constrained")
    ax1, ax2 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.35, 1.0]})
    ax1b = ax1.twinx()
    for k, (name, df) in enumerate(results.items()):
        c = f"C{k}"
        tm = 0.5 * (df.t0_s + df.t1_s)
        ok = df.f_hz.notna()
        ax1.errorbar(tm[ok], df.f_hz[ok], yerr=2 * df.f_se_hz[ok], fmt="o", ms=3, color=c, elinewidth=0.8,
                     capsize=0, label=f"{name}: {ok.sum()} of {len(df)} windows")
        # lost windows as ticks along the bottom, one row per capture
        ax1.plot(tm[~ok], np.full((~ok).sum(), 20.6 + 0.6 * k), "|", color=c, ms=5)
        ax1b.plot(*traces[name], color="0.55", lw=0.7)
        for moving, mfc in ((False, c), (True, "white")):
            sel = ok & (df.moving == moving)
            ax2.errorbar(df.pin_mean_v[sel], df.f_hz[sel], yerr=2 * df.f_se_hz[sel], fmt="o", ms=3.5, color=c,
                         mfc=mfc, elinewidth=0.8, capsize=0, label=name if not moving else None)
    ax2.plot([], [], "o", color="0.3", mfc="white", ms=3.5, label="hollow: roller moved in the window")
    ax1.set_xlabel("window centre [s]")
    ax1.set_ylabel("first mode frequency [Hz] (2-se bars)")
    ax1b.set_ylabel("PinLoc (roller position) [V], grey lines")
    ax1.set_ylim(20, 46)
    ax1b.set_ylim(0.6, 3.6)
    ax1.grid(True, alpha=0.3)
    ax1.legend(fontsize="x-small", loc="upper left")
    ax1.set_title(f"vibid.oma over {args.window:g} s windows every {args.hop:g} s (ticks at the bottom: mode lost)",
                  fontsize="small")
    if coef is not None:
        vv = np.linspace(1.15, 3.45, 100)
        ax2.plot(vv, np.polyval(coef, vv), "k-", lw=0.8, label="quadratic fit to the filled points")
    ax2.set_xlabel("PinLoc, mean over the window [V]")
    ax2.set_ylabel("first mode frequency [Hz]")
    ax2.set_ylim(20, 46)
    ax2.grid(True, alpha=0.3)
    ax2.legend(fontsize="x-small", loc="upper left")
    ax2.set_title("frequency against roller position (2-se bars)", fontsize="small")
    fig.text(0.5, -0.01, "Data: DROPBEAR Dataset-8, A. Vereen, A. Downey, J. Dodson, A. G. Moura (2023), CC BY-SA 4.0; "
             "figure CC BY-SA 4.0", ha="center", va="top", fontsize="x-small", color="0.3")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=args.dpi, bbox_inches="tight")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-dir", type=Path, default=REPO.parent / "shared" / "realdata" / "dropbear",
                    help="folder with ramp10_test*.txt.gz (default: ../shared/realdata/dropbear beside the repository)")
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "img" / "dropbear_first_mode.png", help="PNG to write")
    ap.add_argument("--csv", type=Path, default=None, help="also write the per-window table here")
    ap.add_argument("--captures", type=int, nargs="+", default=[0, 1, 2], help="ramp10_test numbers (default 0 1 2)")
    # 0.5 s: fits inside a 1 s dwell, so about half the windows see the roller at rest (a
    # 1 s window almost always straddles a 0.2 s move and holds two frequencies).
    ap.add_argument("--window", type=float, default=0.5, help="window length [s] (default 0.5)")
    ap.add_argument("--hop", type=float, default=0.25, help="window step [s] (default 0.25)")
    # 10: 5 kHz -> 500 Hz, the band 0-200 Hz, about 5x the highest first-mode frequency (42 Hz).
    ap.add_argument("--decimate", type=int, default=10, help="decimation factor (default 10: 500 Hz)")
    # block_rows i: lags 1..2i-1. At 500 Hz, i = 10 spans 19 lags = 38 ms, one period of the
    # lowest first-mode frequency (26 Hz: 38.5 ms), 1.6 periods at 42 Hz (docs/python.md: the
    # lag window 2i/fs should span at least a period of the lowest mode). Larger i costs
    # blocks: each block needs >= 4 i samples, so a 0.5 s window gives 250 / 40 = 6 blocks.
    ap.add_argument("--block-rows", type=int, default=10, help="Hankel block rows i (default 10)")
    ap.add_argument("--max-order", type=int, default=None,
                    help="largest model order (default: what block_rows allows, 18 with 2 channels and i = 10)")
    # Both accelerometers: with 2 channels the same lag span allows twice the model order
    # (the bound is (i - 1) x channels: 18 instead of 8, and with 8 a mode needs stable poles
    # at each of orders 4, 6 and 8), and the MAC criteria have a shape to check; the poles
    # do not depend on the channels' scaling (both are in volts of similar size).
    ap.add_argument("--channels", default="Low G Accel,Accel", help="comma-separated response channels")
    ap.add_argument("--band", type=float, nargs=2, default=[15.0, 80.0], help="first-mode search band [Hz]")
    ap.add_argument("--rest-tol", type=float, default=0.05,
                    help="PinLoc span [V] (20 ms smoothed) above which the roller counts as moving (default 0.05)")
    # The library's thresholds as shipped. The first mode is lightly damped (zeta 0.01-1 %)
    # and 0.5 s hold only 13-21 of its cycles, so its damping is determined to no better than
    # +-100 % (|zeta| / zeta_se below 1: the last column of the table); the library's
    # stabilisation test then takes the damping as stable within twice the poles' combined
    # standard errors where their frequencies are sharp (oma.h point 5; with the relative 5 %
    # test alone only 21 of the 165 windows found the mode). What no threshold admits: poles
    # whose damping estimate is <= 0 are not physical (oma.h 5.), and in the dwells, where the
    # mode rings on with an apparent damping near zero, that is many of them: those windows
    # are lost (the summary counts them).
    ap.add_argument("--stab-damping", type=float, default=None,
                    help="override the relative damping criterion of the stabilisation diagram (library: 0.05)")
    ap.add_argument("--dpi", type=int, default=100)
    ap.add_argument("--quiet", action="store_true", help="no per-window table")
    args = ap.parse_args(argv)
    args.channels = [c.strip() for c in args.channels.split(",") if c.strip()]

    from vibid import _core

    defaults = _core.oma_defaults()
    thresholds = {k: defaults[k] for k in ("stab_freq", "stab_damping", "stab_mac", "max_damping", "cluster_freq",
                                           "cluster_mac", "min_cluster_share")}
    if args.stab_damping is not None:
        thresholds["stab_damping"] = args.stab_damping

    t_start = time.perf_counter()
    results, traces = {}, {}
    for k in args.captures:
        path = args.data_dir / f"ramp10_test{k}.txt.gz"
        if not path.is_file():
            raise SystemExit(f"{path}: not found (--data-dir)")
        df = load_capture(path)
        x, fs = preprocess(df, args.channels, args.decimate)
        pin = df["PinLoc"].to_numpy(float)
        res = track(x, pin, fs, args, thresholds)
        res.attrs["fs"] = fs
        results[f"test{k}"] = res
        traces[f"test{k}"] = (df["Time"].to_numpy()[::50], pin[::50])  # PinLoc for panel 1, every 10 ms
    elapsed = time.perf_counter() - t_start

    any_res = next(iter(results.values()))
    print(f"vibid {_core.version()}; channels "
          f"{args.channels}; decimate {args.decimate} -> {any_res.attrs['fs']:g} Hz; window {args.window:g} s, hop "
          f"{args.hop:g} s; block_rows {args.block_rows} (lags {(2 * args.block_rows - 1) / any_res.attrs['fs'] * 1e3:.0f} ms); "
          f"max_order {any_res.attrs['max_order']}; {any_res.attrs['blocks']} blocks of {any_res.attrs['block_samples']} "
          f"samples; thresholds {thresholds}; band {args.band[0]:g}-{args.band[1]:g} Hz")
    for name, res in results.items():
        if not args.quiet:
            print(f"\n{name}: window start [s], PinLoc mean [V], roller moving, f +- se [Hz], zeta +- se, order, "
                  f"poles, candidates; band poles stable by frequency: n / stable+physical / zeta<=0, median |zeta|/se")
            for _, r in res.iterrows():
                fs_txt = (f"{r.f_hz:7.3f} +- {r.f_se_hz:6.3f}  {r.zeta:8.5f} +- {r.zeta_se:8.5f}  {r.order:3d} {r.n_poles:3d}"
                          if np.isfinite(r.f_hz) else f"{'lost':>16}  {'':21}  {'':7}")
                print(f"  {r.t0_s:6.2f}  {r.pin_mean_v:5.3f}  {'moving' if r.moving else 'rest  '}  {fs_txt}  "
                      f"{r.n_candidates:2d}  {r.band_fstable:3d}/{r.band_stable_phys:2d}/{r.band_zeta_le0:<2d} "
                      f"{r.band_zeta_over_se:6.2f}")

    # Summary
    all_rows = pd.concat([r.assign(capture=n) for n, r in results.items()], ignore_index=True)
    print("\nSummary")
    for name, res in results.items():
        ok = res.f_hz.notna()
        rest = ~res.moving
        print(f"  {name}: first mode in {ok.sum()} of {len(res)} windows ({(ok & rest).sum()} of {rest.sum()} at rest, "
              f"{(ok & ~rest).sum()} of {(~rest).sum()} moving); f {res.f_hz.min():.2f}..{res.f_hz.max():.2f} Hz")
    lost = all_rows[all_rows.f_hz.isna()]
    if len(lost):
        col = lost.band_fstable >= 3
        print(f"  lost windows: {len(lost)} ({int((lost.t1_s <= 1.0).sum())} end before 1.0 s: nothing excites the beam "
              f"before the first move at 0.7 s). {int(col.sum())} of them hold a column of >= 3 poles in the band "
              f"stable by frequency alone ({int(lost.band_fstable[col].sum())} poles: "
              f"{int(lost.band_stable_phys[col].sum())} stable and physical, {int(lost.band_zeta_le0[col].sum())} with "
              f"zeta <= 0; median |zeta|/se {np.nanmedian(lost.band_zeta_over_se[col]):.2f})")
    fit = all_rows[all_rows.f_hz.notna() & ~all_rows.moving]
    coef = None
    if len(fit) and dwell_levels(fit.pin_mean_v.to_numpy()).max() < 2:
        print("  no fit: the windows at rest cover fewer than 3 roller positions (1 s windows rarely fit in a dwell)")
    if len(fit) >= 4 and dwell_levels(fit.pin_mean_v.to_numpy()).max() >= 2:  # 3 positions at least
        coef = fit_quadratic(fit.pin_mean_v.to_numpy(), fit.f_hz.to_numpy())
        res_hz = fit.f_hz - np.polyval(coef, fit.pin_mean_v)
        z = res_hz / fit.f_se_hz
        vmin, vmax = fit.pin_mean_v.min(), fit.pin_mean_v.max()
        slope = np.polyval(np.polyder(coef), np.linspace(vmin, vmax, 50))
        print(f"  fit over {len(fit)} windows at rest: f = {coef[0]:.3f} V^-2 PinLoc^2 + {coef[1]:.3f} V^-1 PinLoc + "
              f"{coef[2]:.3f} Hz; slope {slope.min():.2f}..{slope.max():.2f} Hz/V over {vmin:.2f}..{vmax:.2f} V "
              f"({'monotone' if slope.min() > 0 else 'NOT monotone'})")
        print(f"  scatter about it: rms {np.sqrt(np.mean(res_hz ** 2)):.3f} Hz, median |res| {np.median(np.abs(res_hz)):.3f} Hz, "
              f"max |res| {np.abs(res_hz).max():.3f} Hz; in se units: rms {np.sqrt(np.mean(z ** 2)):.1f}, median |z| "
              f"{np.median(np.abs(z)):.1f}, |z| <= 2 for {np.mean(np.abs(z) <= 2) * 100:.0f} %; median se "
              f"{fit.f_se_hz.median():.3f} Hz")
        lab = dwell_levels(fit.pin_mean_v.to_numpy())
        fit = fit.assign(level=lab, out=fit.t0_s < 6.6)
        print("  per dwell position (windows at rest): PinLoc [V], n, f mean, sd between windows, median se [Hz]; "
              "out (t < 6.6 s) / back")
        for lv, g in fit.groupby("level"):
            parts = []
            for d, gg in g.groupby("out"):
                parts.append(f"{'out ' if d else 'back'} n {len(gg):2d} f {gg.f_hz.mean():7.3f}")
            print(f"    {g.pin_mean_v.mean():.3f}  n {len(g):2d}  f {g.f_hz.mean():7.3f}  sd {g.f_hz.std(ddof=1) if len(g) > 1 else np.nan:6.3f}"
                  f"  se {g.f_se_hz.median():6.3f}   " + " | ".join(sorted(parts, reverse=True)))
    print(f"  run time {elapsed:.1f} s (loading, filtering and {len(all_rows)} vibid.oma calls)")
    if args.csv:
        all_rows.to_csv(args.csv, index=False)
    plot(results, traces, coef, args, args.out)
    print(f"  wrote {args.out} ({os.path.getsize(args.out) / 1024:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
