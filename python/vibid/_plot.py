"""Figures of a Result (Result.plot) and of the `vibid identify --report` (matplotlib, the
extra ``plot``). Every figure is a bare ``matplotlib.figure.Figure``, not a pyplot one: no
global figure registry and no GUI backend, so they draw headless (Agg) in a server, a
test or a batch job, and are garbage-collected like any object; Jupyter shows them all
the same."""

from __future__ import annotations

import base64
import io
import math
from typing import TYPE_CHECKING, Optional, Sequence

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from ._identify import Result

# The half-width of the bands, in standard errors: the 95 % interval of a normal estimate,
# the figure README's coverage tests are made of (2-se bars covered 95 %).
BAND_SE = 2.0


def _figure(**kw) -> "Figure":
    try:
        from matplotlib.figure import Figure
    except ImportError as e:  # the extra is optional; say how to get it
        raise ImportError("vibid's figures need matplotlib: pip install 'vibid[plot]' "
                          f"(or pip install matplotlib) [{e}]") from None
    return Figure(**kw)


def _truth_lines(ax, truth: float, nominal: float) -> None:
    """The stand's true value as a dashed line; where it gives none, the nominal (start)
    value dash-dotted: a start value is not a truth and must not look like one."""
    if math.isfinite(truth):
        ax.axhline(truth, color="k", linestyle="--", linewidth=1.0, label="true value")
    elif math.isfinite(nominal):
        ax.axhline(nominal, color="0.4", linestyle="-.", linewidth=1.0, label="nominal (start value)")


def track_ylim(v: np.ndarray, se: np.ndarray, truth: float = math.nan,
               pad: float = 0.1) -> Optional[tuple[float, float]]:
    """y limits of a parameter track scaled to the converged estimate: the range of
    value +- BAND_SE se over the second half of the rows (the finite ones; the value alone
    where se is not finite), the true value included where finite, padded by `pad` of the
    range on each side. None where the second half holds no finite value, or where these
    limits would not be narrower than the whole track's (no start transient to leave out):
    then the axis keeps matplotlib's own limits."""
    v = np.asarray(v, float)
    se = np.asarray(se, float)
    half = slice(len(v) // 2, None)
    vh, sh = v[half], se[half]
    lo = np.where(np.isfinite(sh), vh - BAND_SE * sh, vh)
    hi = np.where(np.isfinite(sh), vh + BAND_SE * sh, vh)
    keep = np.isfinite(lo) & np.isfinite(hi)
    if not keep.any():
        return None
    a, b = float(lo[keep].min()), float(hi[keep].max())
    if math.isfinite(truth):
        a, b = min(a, truth), max(b, truth)
    width = b - a if b > a else max(abs(a), 1e-300) * 1e-3
    a, b = a - pad * width, b + pad * width
    # the whole track: its values and the finite bands
    flo = np.where(np.isfinite(se), v - BAND_SE * se, v)
    fhi = np.where(np.isfinite(se), v + BAND_SE * se, v)
    fk = np.isfinite(flo) & np.isfinite(fhi)
    if float(flo[fk].min()) >= a and float(fhi[fk].max()) <= b:
        return None
    return a, b


def plot_result(result: "Result", parameters: Optional[Sequence[str]] = None,
                figsize: Optional[tuple[float, float]] = None) -> "Figure":
    """The parameter tracks with value +- 2 se bands, one axis per parameter (shared time
    axis); the stand's true value dashed (else its nominal value dash-dotted). Rows flagged E
    (no estimate) and bands whose se is not finite (flag I) leave gaps. A result without
    tracks (a batch estimate) gets the same layout with one point and its 2-se error bar per
    axis.

    Each track's y axis is scaled to the converged estimate (:func:`track_ylim`): the
    range of value +- 2 se over the second half of the rows, with the true value where the
    stand gives one; the start transient (and a nominal start value far off) runs off the
    axis, and the axis says so ("start transient clipped"). Where the whole track already
    lies in that range the axis is matplotlib's own."""
    p = result.parameters
    names = list(p.index) if parameters is None else list(parameters)
    for name in names:
        if name not in p.index:
            raise ValueError(f"parameter {name!r}: the stand {result.stand.name!r} has {list(p.index)}")
    if not names:
        raise ValueError("no parameter to plot")
    nominal = dict(zip(result.stand.parameters, result.stand.nominal_values))
    fig = _figure(figsize=figsize or (8.0, 1.0 + 2.0 * len(names)), layout="constrained")
    axes = fig.subplots(len(names), 1, sharex=True, squeeze=False)[:, 0]
    tracks = result.tracks
    have_tracks = len(tracks) > 0
    for ax, name in zip(axes, names):
        unit = p.loc[name, "unit"]
        if have_tracks:
            t = tracks["time_s"].to_numpy(float)
            v = tracks[name].to_numpy(float)
            se = tracks[name + "_se"].to_numpy(float)
            lo, hi = v - BAND_SE * se, v + BAND_SE * se
            ok = np.isfinite(lo) & np.isfinite(hi)
            ax.fill_between(t, lo, hi, where=ok, color="C0", alpha=0.25, linewidth=0,
                            label=f"value \u00b1 {BAND_SE:g} se", gid=f"band:{name}")
            ax.plot(t, v, color="C0", linewidth=1.2, label="estimate", gid=f"track:{name}")
            lim = track_ylim(v, se, float(p.loc[name, "true_value"]))
            if lim is not None:
                ax.set_ylim(*lim)
                ax.text(1.0, 1.01, "start transient clipped: y scaled to the second half of the rows",
                        transform=ax.transAxes, ha="right", va="bottom", fontsize="x-small", color="0.35",
                        gid=f"clipped:{name}")
            bad = tracks["flags"].astype(str).str.contains("[PU]", regex=True).to_numpy()
            if bad.any():
                # Rows whose value is impossible (P) or whose band does not hold (U): marked,
                # so that a band is not read as a confidence interval where it is none.
                ax.plot(t[bad], v[bad], linestyle="none", marker=".", markersize=3, color="C3",
                        label="row flagged P or U")
        else:
            v, se = float(p.loc[name, "value"]), float(p.loc[name, "se"])
            ax.errorbar([0.0], [v], yerr=[BAND_SE * se] if math.isfinite(se) else None, fmt="o", color="C0",
                        capsize=6, label=f"value \u00b1 {BAND_SE:g} se", gid=f"point:{name}")
            ax.set_xticks([])
        _truth_lines(ax, float(p.loc[name, "true_value"]), float(nominal.get(name, math.nan)))
        flags = p.loc[name, "flags"]
        ax.set_ylabel(f"{name} [{unit}]" + (f"\nflags {flags}" if flags else ""))
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    if have_tracks:
        axes[-1].set_xlabel("time [s]")
    fig.suptitle(f"{result.stand.name}: {result.method}, {result.n_samples} samples"
                 + (f", flags {result.flags}" if result.flags else ""))
    return fig


def figure_png_data_uri(fig: "Figure", dpi: int = 96) -> str:
    """The figure as a data: URI of a PNG (for a self-contained HTML report). Rendered by
    the Agg canvas explicitly, whatever backend the process has."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def autocorrelation(e: np.ndarray, max_lag: int) -> np.ndarray:
    """Sample autocorrelation r(0..max_lag) of a series (mean removed, biased estimator
    normalised by r(0), as the +-1.96/sqrt(N) whiteness band assumes)."""
    e = np.asarray(e, dtype=float) - np.mean(e)
    n = len(e)
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(e, nfft)
    r = np.fft.irfft(f * np.conj(f), nfft)[:max_lag + 1]
    return r / r[0] if r[0] > 0 else np.full(max_lag + 1, np.nan)


def welch_psd(x: np.ndarray, fs: float, nperseg: int = 4096) -> tuple[np.ndarray, np.ndarray]:
    """One-sided power spectral density by Welch's method (Hann window, 50 % overlap, mean
    removed per segment), in units^2/Hz. Shorter captures get one segment of their length."""
    x = np.asarray(x, dtype=float)
    nperseg = int(min(nperseg, len(x)))
    step = max(1, nperseg // 2)
    w = np.hanning(nperseg)
    scale = 1.0 / (fs * np.sum(w * w))
    acc = np.zeros(nperseg // 2 + 1)
    count = 0
    for start in range(0, len(x) - nperseg + 1, step):
        seg = x[start:start + nperseg]
        X = np.fft.rfft((seg - seg.mean()) * w)
        acc += np.abs(X) ** 2
        count += 1
    psd = acc * scale / max(count, 1)
    psd[1:-1 if nperseg % 2 == 0 else None] *= 2.0  # one-sided: fold the negative frequencies
    return np.fft.rfftfreq(nperseg, 1.0 / fs), psd


def monitoring_figure(mon, parameters: Sequence[str], path: Optional[str] = None) -> "Figure":
    """vibid.Monitoring.plot: per parameter the change statistic against the sample time
    (its threshold is 1: the CUSUM over its threshold), the threshold line, raised events
    (red) with their estimated onset (dotted), cleared events (green), and the rows flagged C
    (covariates outside the reference's range) shaded; the covariates in a last panel."""
    tr = mon.tracks
    t = tr["time_s"].to_numpy(dtype=float)
    t0 = t[np.isfinite(t)].min() if np.isfinite(t).any() else 0.0
    panels = len(parameters) + (1 if mon.covariates else 0)
    if panels == 0:
        raise ValueError("vibid.Monitoring.plot: no alarmed parameter and no covariate to draw")
    fig = _figure(figsize=(9.0, 2.2 * panels + 0.6))
    axes = fig.subplots(panels, 1, sharex=True, squeeze=False)[:, 0]
    recursive = ~tr["flags"].str.contains("W", regex=False)
    flagged_c = tr["flags"].str.contains("C", regex=False).to_numpy()
    for ax, p in zip(axes, parameters):
        col = f"{p}_change_statistic"
        if col not in tr.columns:
            raise ValueError(f"vibid.Monitoring.plot: '{p}' has no change statistic (not an alarmed parameter; "
                             f"those are {mon.parameters()})")
        ax.plot(t[recursive] - t0, tr.loc[recursive, col].to_numpy(dtype=float), linewidth=0.8,
                label="statistic / threshold")
        ax.axhline(1.0, color="k", linestyle="--", linewidth=1.0, label="threshold")
        if flagged_c.any():
            ax.fill_between(t - t0, 0, 1, where=flagged_c, color="0.85", step="mid",
                            transform=ax.get_xaxis_transform(), label="covariate outside reference (C)")
        ev = mon.events[mon.events["parameter"] == p]
        for _, e in ev.iterrows():
            raised = e["state"] == "raised"
            ax.axvline(e["time_s"] - t0, color="tab:red" if raised else "tab:green", linewidth=1.2)
            if raised and np.isfinite(e["onset_index"]):
                # the onset's time from the row of that capture with the onset's index
                rows = tr[(tr["capture"] == e["capture"]) & (tr["index"] >= e["onset_index"])]
                if len(rows):
                    ax.axvline(rows["time_s"].iloc[0] - t0, color="tab:red", linestyle=":", linewidth=1.0)
        mdc = tr[f"{p}_mdc"].to_numpy(dtype=float) if f"{p}_mdc" in tr.columns else np.array([np.nan])
        last_mdc = mdc[np.isfinite(mdc)][-1] if np.isfinite(mdc).any() else math.nan
        ax.set_ylabel(f"{p}\nCUSUM / h")
        ax.set_title(f"{p}: {len(ev[ev['state'] == 'raised'])} alarm(s); minimum detectable change "
                     f"{last_mdc:.4g}", fontsize=9, loc="left")
        ax.legend(fontsize=7, loc="upper left")
    if mon.covariates:
        ax = axes[-1]
        for c in mon.covariates:
            ax.plot(t - t0, tr[c].to_numpy(dtype=float), linewidth=0.8, label=c)
        ax.set_ylabel("covariates")
        ax.legend(fontsize=7, loc="upper left")
    axes[-1].set_xlabel("time from the first row, s")
    fig.tight_layout()
    if path:
        fig.savefig(path)
    return fig
