"""vibid.oma: output-only modal identification (SSI-cov with standard errors, libvibid's
vibid/oma.h) of response channels whose excitation is not measured (docs/python.md,
"Output-only modal analysis")."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Mapping, Optional, Sequence

import numpy as np
import pandas as pd

from . import _core
from ._captures import CaptureError, _format_of, _numeric, _rate, _reading, _same_length

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

# Blocks of the covariance estimate (vibid/oma.h, 4.): the standard errors come from their
# spread; 32 gave 2-se coverage of 92-95 % on lib.test_oma's simulated chain.
DEFAULT_BLOCKS = 32
# The largest model order by default: min(this, what the Hankel matrix allows).
DEFAULT_MAX_ORDER = 60
_TIME_COLUMNS = ("time_s", "t", "time", "Time")


@dataclass
class OmaResult:
    """The result of :func:`oma`.

    modes: one row per selected mode (index ``mode`` 1, 2, ... by frequency): ``freq_hz``,
        ``freq_hz_se``, ``zeta`` (fraction of critical), ``zeta_se``, ``mpc`` (modal phase
        collinearity, 1 for a real shape), ``order`` (the model order it is taken from) and
        ``n_poles`` (stable poles in its cluster).
    shapes: the mode shapes (complex, normalised to 1 at the largest component), one row
        per mode, one column per channel.
    poles: the stabilisation diagram: every pole of every order (``order``, ``freq_hz``,
        ``freq_hz_se``, ``zeta``, ``zeta_se``, ``mpc``, ``stable``, ``physical``, ``mode``:
        the mode whose cluster holds it, or 0).
    singular_values: of the Hankel matrix of output covariances (descending).
    """

    modes: pd.DataFrame
    shapes: pd.DataFrame
    poles: pd.DataFrame
    singular_values: np.ndarray
    channels: list
    refs: list
    sample_rate: float
    config: dict
    n_samples: int
    n_gaps: int
    _data: np.ndarray = field(repr=False, default=None)

    def __repr__(self) -> str:
        lines = [f"OmaResult: {len(self.modes)} modes from {self.n_samples} samples of {len(self.channels)} channels "
                 f"at {self.sample_rate:g} Hz (block_rows {self.config['block_rows']}, max_order "
                 f"{self.config['max_order']}, {self.config['blocks']} blocks)"]
        for k, r in self.modes.iterrows():
            lines.append(f"  mode {k}: f {r.freq_hz:.6g} +- {r.freq_hz_se:.2g} Hz, zeta {r.zeta:.4g} +- "
                         f"{r.zeta_se:.2g}, mpc {r.mpc:.3f}")
        return "\n".join(lines)

    def spectrum(self, nperseg: int = 4096) -> tuple[np.ndarray, np.ndarray]:
        """The singular values of the outputs' cross-spectral density matrix per frequency
        (Welch: Hann, 50 % overlap, mean removed per segment): (f [Hz], sv (nf x
        min(channels, 3)) in channel units^2/Hz)."""
        x = self._data
        n, nch = x.shape
        nperseg = int(min(nperseg, 1 << max(4, int(math.floor(math.log2(max(n, 64) / 8))))))
        step = nperseg // 2
        w = np.hanning(nperseg)
        scale = 1.0 / (self.sample_rate * np.sum(w * w))
        G = np.zeros((nperseg // 2 + 1, nch, nch), complex)
        count = 0
        for start in range(0, n - nperseg + 1, step):
            seg = x[start:start + nperseg]
            if not np.isfinite(seg).all():
                continue
            X = np.fft.rfft((seg - seg.mean(axis=0)) * w[:, None], axis=0)
            G += X[:, :, None] * X[:, None, :].conj()
            count += 1
        G *= scale / max(count, 1)
        sv = np.linalg.svd(G, compute_uv=False)[:, :min(nch, 3)]
        return np.fft.rfftfreq(nperseg, 1.0 / self.sample_rate), sv

    def report(self, path: str | os.PathLike, capture: Optional[str] = None) -> None:
        """A self-contained HTML report (modes with standard errors, shapes, the
        stabilisation diagram, the settings), as ``vibid oma --report`` writes it."""
        _report(self, path, capture)

    def plot(self, path: Optional[str | os.PathLike] = None) -> "Figure":
        """The stabilisation diagram (model order against frequency: stable physical poles
        filled, the selected modes' poles coloured, the rest grey) over the singular values
        of the output spectrum (right axis, dB), the selected modes marked. Saved to
        ``path`` when given."""
        from ._plot import _figure

        fig = _figure(figsize=(9.0, 5.0), layout="constrained")
        ax = fig.subplots()
        p = self.poles
        other = p[~((p.stable > 0) & (p.physical > 0))]
        ax.plot(other.freq_hz, other.order, "x", color="0.7", markersize=3, label="pole")
        st = p[(p.stable > 0) & (p.physical > 0) & (p["mode"] == 0)]
        ax.plot(st.freq_hz, st.order, "o", color="0.35", markersize=3, label="stable pole")
        for k, r in self.modes.iterrows():
            mine = p[p["mode"] == k]
            ax.plot(mine.freq_hz, mine.order, "o", markersize=4, color=f"C{(k - 1) % 10}",
                    label=f"mode {k}: {r.freq_hz:.4g} Hz, \u03b6 {100 * r.zeta:.3g} %")
            ax.axvline(r.freq_hz, color=f"C{(k - 1) % 10}", linewidth=0.8, linestyle=":")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("model order [-]")
        ax.set_xlim(0, self.sample_rate / 2)
        ax.grid(True, alpha=0.3)
        f, sv = self.spectrum()
        ax2 = ax.twinx()
        for j in range(sv.shape[1]):
            ax2.plot(f[1:], 10 * np.log10(np.maximum(sv[1:, j], 1e-300)), linewidth=0.8, color="k",
                     alpha=1.0 - 0.3 * j)
        ax2.set_ylabel("singular values of the output spectrum [dB re 1 unit\u00b2/Hz]")
        ax.legend(fontsize="small", loc="upper left")
        ax.set_title(f"stabilisation diagram: {len(self.modes)} modes ({len(self.channels)} channels, "
                     f"{self.n_samples} samples at {self.sample_rate:g} Hz)", fontsize="small")
        if path is not None:
            from matplotlib.backends.backend_agg import FigureCanvasAgg

            FigureCanvasAgg(fig)
            fig.savefig(path, dpi=96)
        return fig


def _report(r: OmaResult, path: str | os.PathLike, capture: Optional[str]) -> None:
    import datetime
    import html

    from ._cli import _html_table, write_html
    from ._plot import figure_png_data_uri

    esc = html.escape
    c = r.config
    sec = []
    if len(r.modes):
        modes = r.modes.copy()
        modes.insert(0, "freq_hz", modes.pop("freq_hz"))
        sec.append('<section id="modes"><h2>Modes</h2><p>Values to the decimal place of the second significant '
                   "digit of their standard error (first order, from the spread of the "
                   f"{c['blocks']} blocks' covariances; vibid/oma.h). zeta: fraction of critical damping; mpc: modal "
                   "phase collinearity (1: a real, classically damped shape); order: the model order the values are "
                   "taken from; poles: the stable poles of the mode's cluster.</p>"
                   + _html_table(modes, {"freq_hz": "freq_hz_se", "zeta": "zeta_se"}) + "</section>")
        mag = r.shapes.abs().round(4)
        mag.index.name = "mode"
        ph = pd.DataFrame(np.degrees(np.angle(r.shapes.to_numpy())).round(1) + 0.0, index=r.shapes.index,  # no -0
                          columns=r.shapes.columns)
        sec.append('<section id="shapes"><h2>Mode shapes</h2><p>Magnitude, normalised to 1 at the largest '
                   "component, in the channels' own units:</p>" + _html_table(mag)
                   + "<p>Phase [degrees] against that component:</p>" + _html_table(ph) + "</section>")
    else:
        sec.append('<section id="modes"><h2>Modes</h2><p>No mode selected: no cluster of stable physical poles '
                   f"holds {100 * c['min_cluster_share']:g} % of the orders. The diagram below shows what the data "
                   "give; a longer capture, more channels or other block rows may.</p></section>")
    fig = r.plot()
    sec.append('<section id="stabilisation"><h2>Stabilisation diagram</h2><p>Every pole of orders 2..'
               f"{c['max_order']} (x: not stable or not physical; dots: stable against the order below: frequency "
               f"within {100 * c['stab_freq']:g} %, damping within {100 * c['stab_damping']:g} %, MAC at least "
               f"{c['stab_mac']:g}), the selected modes coloured, over the first singular values of the outputs' "
               "cross-spectral density matrix (Welch, Hann, 50 % overlap): a mode shows as a column of stable "
               f'poles at a spectral peak.</p><img alt="stabilisation diagram" src="{figure_png_data_uri(fig)}">'
               "</section>")
    sv = r.singular_values
    sec.append('<section id="settings"><h2>Settings</h2><p>'
               f"{len(r.channels)} channels ({esc(', '.join(r.channels))}), references {esc(', '.join(r.refs))}; "
               f"{r.n_samples} samples at {r.sample_rate:g} Hz, {r.n_gaps} gaps; block rows {c['block_rows']} "
               f"(lags 1..{2 * c['block_rows'] - 1}, {(2 * c['block_rows'] - 1) / r.sample_rate:.4g} s); "
               f"{c['blocks']} blocks of {c['block_samples']} samples; thresholds: "
               + esc(", ".join(f"{k} {c[k]:g}" for k in ("stab_freq", "stab_damping", "stab_mac", "max_damping",
                                                          "cluster_freq", "cluster_mac", "min_cluster_share")))
               + f". Singular values of the Hankel matrix (first 12, relative to the first): "
               + esc(", ".join(f"{v / sv[0]:.3g}" for v in sv[:12])) + "</p></section>")
    head = (f"<h1>vibid oma: {esc(os.path.basename(str(capture)) if capture else 'data')}</h1><p>"
            + (f"capture <code>{esc(str(capture))}</code>, " if capture else "")
            + f"{len(r.modes)} modes from {r.n_samples} samples ({r.n_samples / r.sample_rate:.6g} s); vibid "
            f"{esc(_core.version())}, {datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M:%S UTC')}"
            "</p>")
    write_html(os.fspath(path), f"vibid oma: {os.path.basename(str(capture)) if capture else 'data'}", head, sec)


def _read_file(path: str, channels: Optional[Sequence[str]], format: Optional[str],
               group: Any) -> tuple[pd.DataFrame, Optional[float]]:
    """The named channels (all numeric ones when None) of a CSV, MDF4 or TDMS capture, in
    the file's own units, and the sample rate its time base gives (None without one)."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise CaptureError(f"{path}: no such file" if not os.path.exists(path) else f"{path}: not a file")
    fmt = _format_of(path, format)
    if fmt not in ("csv", "mdf", "tdms"):
        raise ValueError(f"{path}: vibid.oma reads CSV, MDF4 and TDMS captures, not {fmt}")
    with _reading(path, fmt):
        if fmt == "csv":
            try:
                df = pd.read_csv(path, comment="#", skipinitialspace=True)
            except pd.errors.EmptyDataError:
                raise CaptureError(f"{path}: no header line: the file is empty or holds only '#' comments") from None
            cols = {str(c): df[c].to_numpy() for c in df.columns}
            t_name = next((c for c in _TIME_COLUMNS if c in cols), None)
        elif fmt == "mdf":
            from asammdf import MDF

            with MDF(path) as mdf:
                frame = mdf.to_dataframe(time_from_zero=False)
            cols = {str(c): frame[c].to_numpy() for c in frame.columns}
            cols["time_s"] = frame.index.to_numpy(float)
            t_name = "time_s"
        else:
            from nptdms import TdmsFile

            tf = TdmsFile.read(path)
            groups = tf.groups()
            g = groups[0] if group is None and len(groups) == 1 else (tf[group] if group is not None else None)
            if g is None:
                raise ValueError(f"{path}: {len(groups)} groups ({', '.join(x.name for x in groups)}): say which "
                                 "with group=")
            cols = {ch.name: ch[:] for ch in g.channels()}
            first = g.channels()[0]
            inc = first.properties.get("wf_increment")
            t_name = None
            if inc:
                cols["time_s"] = first.properties.get("wf_start_offset", 0.0) + np.arange(len(first)) * float(inc)
                t_name = "time_s"
    names = list(channels) if channels is not None else [c for c in cols if c not in _TIME_COLUMNS]
    out = {}
    for c in names:
        if c not in cols:
            raise ValueError(f"channel {c!r} missing: {path} has channels {list(cols)}")
        out[c] = _numeric(cols[c], f"channel {c!r} in {path}", csv_path=path if fmt == "csv" else None)
    _same_length(out, path)
    rate = None
    if t_name is not None:
        rate = _rate(_numeric(cols[t_name], f"time {t_name!r} in {path}", csv_path=path if fmt == "csv" else None))
    return pd.DataFrame(out), rate


def oma(data: Any, sample_rate: Optional[float] = None, channels: Optional[Sequence[str]] = None,
        refs: Optional[Sequence[str]] = None, max_order: Optional[int] = None, *, block_rows: Optional[int] = None,
        blocks: int = DEFAULT_BLOCKS, format: Optional[str] = None, group: Any = None,
        thresholds: Optional[Mapping[str, float]] = None) -> OmaResult:
    """Output-only modal identification: the modes of a structure excited by unmeasured
    broadband forces, from its response channels alone (covariance-driven SSI, libvibid's
    vibid/oma.h: method, thresholds and the standard errors' derivation in its header).

    data: a DataFrame (one column per channel, a ``time_s``/``t`` column for the time), a
        2-D array (samples x channels) or the path of a CSV, MDF4 or TDMS capture (values
        in the file's units; the shapes are relative).
    sample_rate: Hz; from the time column or the file's time base when not given.
    channels: the response channels (default: every numeric column but the time).
    refs: the reference channels (default: all).
    max_order: the largest model order (even; default min(60, what block_rows allows)).
    block_rows: i, the Hankel matrix's block rows (lags 1..2i-1); default
        max(20, max_order / n_refs + 1), so that the default order fits.
    blocks: the number of blocks whose spread gives the standard errors (default 32).
    thresholds: stabilisation and selection settings by name (stab_freq, stab_damping,
        stab_mac, max_damping, cluster_freq, cluster_mac, min_cluster_share; defaults in
        vibid/oma.h).

    Non-finite samples are gaps (no lag product spans them; counted in ``n_gaps``).
    Raises ValueError (a CaptureError for a file) naming what is wrong; VibidError from
    the library (e.g. a capture too short for the blocks).
    """
    rate = None
    if isinstance(data, (str, os.PathLike)):
        frame, rate = _read_file(data, channels, format, group)
        names = list(frame.columns)
        x = frame.to_numpy(np.float64)
    elif isinstance(data, pd.DataFrame):
        tcol = next((c for c in _TIME_COLUMNS if c in data.columns), None)
        if tcol is not None:
            rate = _rate(np.asarray(data[tcol], float))
        names = list(channels) if channels is not None else [str(c) for c in data.columns if c != tcol]
        missing = [c for c in names if c not in data.columns]
        if missing:
            raise ValueError(f"channels {missing} missing: the data have {list(map(str, data.columns))}")
        x = np.column_stack([_numeric(data[c].to_numpy(), f"channel {c!r}") for c in names]) if names else None
    else:
        x = np.asarray(data, dtype=np.float64)
        if x.ndim == 1:
            x = x[:, None]
        if x.ndim != 2:
            raise ValueError(f"data: a 2-D array (samples x channels) expected, not shape {x.shape}")
        names = list(channels) if channels is not None else [f"y{j}" for j in range(x.shape[1])]
        if len(names) != x.shape[1]:
            raise ValueError(f"channels: {len(names)} names for {x.shape[1]} columns")
    if x is None or x.shape[1] == 0:
        raise ValueError("no response channel to identify from")
    fs = float(sample_rate) if sample_rate is not None else rate
    if fs is None or not math.isfinite(fs) or fs <= 0:
        raise ValueError("sample_rate: give it (Hz, > 0); the data have no time column to take it from")
    ref_idx = list(range(len(names))) if refs is None else []
    for r in refs or []:
        if r not in names:
            raise ValueError(f"refs: {r!r} is not one of the channels {names}")
        ref_idx.append(names.index(r))
    nref = len(ref_idx)
    order = int(max_order) if max_order is not None else None
    if block_rows is None:
        block_rows = max(20, (order if order is not None else DEFAULT_MAX_ORDER) // nref + 1)
    if order is None:
        bound = min((block_rows - 1) * len(names), block_rows * nref)
        order = min(DEFAULT_MAX_ORDER, bound - bound % 2)
    n = x.shape[0]
    blocks = int(blocks)
    if blocks < 2:
        raise ValueError(f"blocks = {blocks}: at least 2 (the standard errors come from their spread)")
    block_samples = n // blocks
    if block_samples < 4 * block_rows:
        raise ValueError(f"{n} samples are too few: {blocks} blocks of at least 4 x block_rows = {4 * block_rows} "
                         f"samples need {blocks * 4 * block_rows}")
    defaults = _core.oma_defaults()
    th = {k: defaults[k] for k in ("stab_freq", "stab_damping", "stab_mac", "max_damping", "cluster_freq",
                                   "cluster_mac", "min_cluster_share")}
    for k, v in (thresholds or {}).items():
        if k not in th:
            raise ValueError(f"thresholds: unknown {k!r} (known: {', '.join(th)})")
        th[k] = float(v)
    core = _core.Oma(fs, len(names), ref_idx, int(block_rows), order, block_samples, blocks, th)
    # whole blocks only: the samples after the last complete block are not used
    used = x[:block_samples * blocks]
    # any layout: the binding gathers other strides in column-major chunks itself (copying the
    # whole capture first cost 1.6 s of 7.2 s on an hour of 16 channels: bench/bench_oma.py)
    gaps = core.push(used)
    core.identify()
    m = core.modes()
    k = len(m["freq_hz"])
    idx = pd.Index(range(1, k + 1), name="mode")
    modes = pd.DataFrame({c: m[c] for c in ("freq_hz", "freq_hz_se", "zeta", "zeta_se", "mpc")}, index=idx)
    modes["order"] = m["order"].astype(int)
    modes["n_poles"] = m["n_poles"].astype(int)
    shapes = pd.DataFrame(m["shape_re"] + 1j * m["shape_im"], index=idx, columns=names)
    p = core.poles()
    poles = pd.DataFrame({c: p[c] for c in ("order", "freq_hz", "freq_hz_se", "zeta", "zeta_se", "mpc")})
    poles["order"] = poles["order"].astype(int)
    poles["stable"] = p["stable"].astype(bool)
    poles["physical"] = p["physical"].astype(bool)
    poles["mode"] = (p["mode"] + 1).astype(int)
    i, mo, bs, mb, _ = core.config()
    samples, ngaps, _ = core.stats()
    return OmaResult(modes=modes, shapes=shapes, poles=poles, singular_values=core.singular_values(),
                     channels=names, refs=[names[j] for j in ref_idx], sample_rate=fs,
                     config={"block_rows": i, "max_order": mo, "block_samples": bs, "blocks": mb, **th},
                     n_samples=int(samples), n_gaps=int(ngaps), _data=used)
