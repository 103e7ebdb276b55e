"""vibid.identify: a capture in, parameters, modes, covariance and tracks out."""

from __future__ import annotations

import html
import math
import os
from typing import Any, Mapping, Optional

import numpy as np
import pandas as pd

from . import _core
from ._stand import Stand

VibidError = _core.VibidError

METHODS = {
    "auto": _core.ESTIMATOR_AUTO,
    "ls": _core.ESTIMATOR_LS,
    "rls": _core.ESTIMATOR_RLS,
    "iv": _core.ESTIMATOR_IV,
    "ekf": _core.ESTIMATOR_EKF,
    "kf_rls": _core.ESTIMATOR_KF_RLS,
}
_METHOD_NAMES = {v: k for k, v in METHODS.items()}
# Estimators whose estimate follows the data sample by sample: identify gives them tracks
# by default. The batch estimators (ls, iv, auto's IV) only with forgetting < 1 or an
# explicit track_every.
_RECURSIVE = {_core.ESTIMATOR_RLS, _core.ESTIMATOR_EKF, _core.ESTIMATOR_KF_RLS}
# Columns a capture may have beside the stand's channels: the sample time.
_TIME_COLUMNS = ("t", "time_s")


def _flags(status_ok: bool, implausible: int, quality: int) -> str:
    """The daemon's flag letters (docs/vibidd.md, order G E P U I A) that apply offline:
    E no estimate, P physically impossible, U error bars do not hold, I hardly informed.
    (G gaps and A alarms belong to a live acquisition.)"""
    if not status_ok:
        return "E"
    s = ""
    if implausible:
        s += "P"
    if quality & _core.QUALITY_SE_INVALID:
        s += "U"
    if quality & _core.QUALITY_NOT_EXCITED:
        s += "I"
    return s


def _columns(stand: Stand, data: Any, dbc: Any = None,
             channel_map: Any = None) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """The capture as an (n_samples x n_channels) float64 array in the stand's channel
    order, and the time column if there is one. Copies only where the layout requires it:
    a 2-D array is used as it is (any strides); a DataFrame whose channels share one float64
    block comes out column-major without a copy; a dict of separate arrays is gathered into
    one column-major block (one copy, the C API takes one block)."""
    channels = stand.channels
    t = None
    if isinstance(data, (str, os.PathLike)):
        # A file (CSV, MDF4, TDMS by its extension): read_capture gives the stand's channels,
        # converted to the stand's units, and time_s (checked below as any time column).
        from ._captures import read_capture
        path = os.fspath(data)
        data = read_capture(path, stand, dbc=dbc, channel_map=channel_map)
        gaps = data.attrs.get("gaps")
        if gaps:
            # A candump log's missing samples (NaN rows): refused, never bridged, naming
            # where; the rows before and after a gap can be identified separately.
            g = gaps[0]
            raise ValueError(f"{path}: {g['count']} sample(s) missing at rows {g['row']}..{g['row'] + g['count'] - 1} "
                             f"(after t = {g['after_time_s']:.6f} s): {g['text']}; vibid never bridges a gap: identify "
                             f"the parts between gaps separately (read_capture(...).attrs['gaps'] lists all "
                             f"{len(gaps)})")
    elif dbc is not None or channel_map is not None:
        raise ValueError("dbc= and channel_map= are for a candump log given by its path")
    if isinstance(data, np.ndarray):
        arr = np.asarray(data, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[1] != len(channels):
            raise ValueError(f"a 2-D array needs shape (n_samples, {len(channels)}) with columns {channels}, "
                             f"got shape {arr.shape}")
        block = arr
    elif isinstance(data, (pd.DataFrame, Mapping)):
        names = [str(c) for c in (data.columns if isinstance(data, pd.DataFrame) else data.keys())]
        unknown = [c for c in names if c not in channels and c not in _TIME_COLUMNS]
        if unknown:
            raise ValueError(f"unknown channel {unknown[0]!r}: the stand {stand.name!r} has channels {channels}"
                             + (f" (and a time column {_TIME_COLUMNS[0]!r})"))
        missing = [c for c in channels if c not in names]
        if missing:
            raise ValueError(f"channel {missing[0]!r} missing: the stand {stand.name!r} needs {channels}")
        tname = next((c for c in _TIME_COLUMNS if c in names), None)
        if isinstance(data, pd.DataFrame):
            block = data[channels].to_numpy(dtype=np.float64)
            if not block.flags.f_contiguous:
                block = np.asfortranarray(block)
            if tname is not None:
                t = data[tname].to_numpy(dtype=np.float64)
        else:
            cols = []
            for c in channels:
                a = np.asarray(data[c], dtype=np.float64)
                if a.ndim != 1:
                    raise ValueError(f"channel {c!r}: a 1-D array is needed, got shape {a.shape}")
                cols.append(a)
            n = len(cols[0])
            for c, a in zip(channels, cols):
                if len(a) != n:
                    raise ValueError(f"channel {c!r} has {len(a)} samples, channel {channels[0]!r} has {n}")
            block = np.empty((n, len(channels)), dtype=np.float64, order="F")
            for i, a in enumerate(cols):
                block[:, i] = a
            if tname is not None:
                t = np.asarray(data[tname], dtype=np.float64)
                if t.shape != (n,):
                    raise ValueError(f"column {tname!r} has shape {t.shape}, the channels have {n} samples")
    else:
        raise TypeError("data must be a pandas DataFrame, a dict of arrays keyed by channel name, "
                        f"a 2-D array or a CSV path, not {type(data).__name__}")
    finite = np.isfinite(block)
    if not finite.all():
        col = int(np.argmin(finite.all(axis=0)))
        row = int(np.argmin(finite[:, col]))
        raise ValueError(f"channel {channels[col]!r}: non-finite value {float(block[row, col])!r} at row {row} "
                         "(the estimators would restart their difference windows there; remove or fill gaps first)")
    # One wild value (1.0 or 1e300 in millimetre motions) enters every sum of the estimators
    # and stays there. vibidd takes such single-sample glitches out (vibid/outlier.h, its
    # flag O); identify takes no gaps, so it names the first one instead of answering wrong.
    bad = _core.outliers(block)
    if bad:
        row, col = bad[0]
        raise ValueError(f"channel {channels[col]!r}: value {float(block[row, col])!r} at row {row} is a "
                         f"single-sample glitch ({len(bad)} in this capture; the outlier test of "
                         "vibid/outlier.h, as vibidd's): remove or repair it (vibid.replay takes such "
                         "glitches out as vibidd does)")
    if t is not None and len(t) > 2:
        # As vibidd: a capture whose rate is more than 1 % off the stand's is refused,
        # naming both rates (the estimates would be off by that much without a word).
        rate = 1.0 / float(np.median(np.diff(t)))
        if not math.isfinite(rate) or abs(rate / stand.sample_rate - 1.0) > 0.01:
            raise ValueError(f"the capture's time column gives {rate:.6g} Hz, the stand {stand.name!r} says "
                             f"{stand.sample_rate:.6g} Hz (more than 1 % apart)")
    return block, t


class Result:
    """What :func:`identify` found.

    Attributes
    ----------
    parameters : DataFrame, one row per unknown: ``value``, ``se`` (standard error),
        ``unit``, ``kind``, ``true_value`` (NaN where the stand gives none), ``z`` =
        (value - true_value) / se, ``flags`` (the daemon's letters for this parameter:
        P impossible, U error bars do not hold, I hardly informed by the data).
    modes : DataFrame, one row per mode in ascending frequency: ``freq_hz``,
        ``freq_hz_se``, ``zeta``, ``zeta_se``, ``flags`` (P). The standard errors come from
        the C library (``vibid_model_modal``: first-order propagation of the parameters'
        covariance through the modal map, i.e. the delta method, done in C).
    covariance : (p x p) ndarray of the parameters, consistent with ``se``.
    tracks : DataFrame of the estimate after every ``track_every`` samples, columns as the
        daemon's tracks file (``time_s``, ``index``, each parameter and ``<p>_se``, per mode
        ``f<i>_hz``, ``f<i>_hz_se``, ``zeta<i>``, ``zeta<i>_se``, then ``flags``); empty
        without tracking. ``time_s`` is the capture's time column where it has one, else
        ``index / sample_rate``.
    flags : the whole estimate's letters (E P U I), as a row of the daemon's tracks.
    why : the plausibility findings in words ("" when plausible).
    description : the estimator's own account of what it chose and why
        (``vibid_ident_describe``).
    config : the settings in force after the automatic choices.
    """

    def __init__(self, stand: Stand, est: Any, description: str, config: dict, tracks: pd.DataFrame,
                 n_samples: int, diverged_samples: int):
        self.stand = stand
        self.description = description
        self.config = config
        self.tracks = tracks
        self.n_samples = n_samples
        self.diverged_samples = diverged_samples
        theta, se = est["theta"], est["se"]
        truth = np.asarray(stand.true_values, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = (theta - truth) / se
        pflags = []
        for i in range(len(theta)):
            f = ""
            if est["param_implausible"][i]:
                f += "P"
            if est["param_quality"][i] & _core.QUALITY_SE_INVALID:
                f += "U"
            if est["param_quality"][i] & _core.QUALITY_NOT_EXCITED:
                f += "I"
            pflags.append(f)
        self.parameters = pd.DataFrame(
            {"value": theta, "se": se, "unit": stand.units, "kind": stand.kinds, "true_value": truth, "z": z,
             "flags": pflags},
            index=pd.Index(stand.parameters, name="parameter"))
        self.modes = pd.DataFrame(
            {"freq_hz": est["freq_hz"], "freq_hz_se": est["freq_hz_se"], "zeta": est["zeta"], "zeta_se": est["zeta_se"],
             "flags": ["P" if f else "" for f in est["mode_implausible"]]},
            index=pd.Index(range(1, len(est["freq_hz"]) + 1), name="mode"))
        self.covariance = np.array(est["covariance"])
        self.flags = _flags(True, est["implausible"], est["quality"])
        self.why = est["why"]
        self.z_consistency = est["z_consistency"]

    @property
    def method(self) -> str:
        return self.config["method"]

    def __repr__(self) -> str:
        with pd.option_context("display.width", 120, "display.max_columns", 20):
            lines = [f"vibid.Result: stand {self.stand.name!r}, method {self.method}, {self.n_samples} samples, "
                     f"flags {self.flags or '-'}"]
            lines.append(self.parameters.to_string(float_format=lambda v: f"{v:.6g}"))
            lines.append(self.modes.to_string(float_format=lambda v: f"{v:.6g}"))
            if self.why:
                lines.append("implausible: " + self.why)
            if len(self.tracks):
                lines.append(f"tracks: {len(self.tracks)} rows")
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        head = (f"<p><b>vibid.Result</b>: stand <code>{html.escape(self.stand.name)}</code>, method "
                f"<code>{html.escape(self.method)}</code>, {self.n_samples} samples, flags "
                f"<code>{html.escape(self.flags or '-')}</code></p>")
        parts = [head, self.parameters.to_html(float_format=lambda v: f"{v:.6g}"),
                 self.modes.to_html(float_format=lambda v: f"{v:.6g}")]
        if self.why:
            parts.append(f"<p>implausible: {html.escape(self.why)}</p>")
        parts.append(f"<details><summary>estimator</summary><pre>{html.escape(self.description)}</pre></details>")
        return "\n".join(parts)

    def plot(self, parameters=None, figsize=None):
        """The tracks with value +- 2 se bands, one axis per parameter, the true value dashed
        (else the nominal start value dash-dotted); for a result without tracks one point
        with its 2-se error bar per axis. Returns a ``matplotlib.figure.Figure`` (no pyplot,
        draws headless). Needs matplotlib (the extra ``plot``); docs/python.md."""
        from ._plot import plot_result  # matplotlib only when asked for a figure

        return plot_result(self, parameters, figsize)


def identify(stand: Stand | str | os.PathLike, data: Any, method: str = "auto",
             forgetting: Optional[float] = None, prefilter_hz: Optional[float] = None,
             iv_lag: Optional[int] = None, track_every: Optional[int] = None, *, dbc: Any = None,
             channel_map: Any = None) -> Result:
    """Identifies the stand's unknowns from a capture.

    stand: a :class:`Stand` or the path of a stand file.
    data: a pandas DataFrame or a dict of 1-D arrays keyed by the stand's channel names
        (``stand.channels``; a time column ``t`` or ``time_s`` is allowed and checked
        against the stand's sample rate), a 2-D array (n_samples x n_channels) in the
        stand's channel order, or the path of a CSV file with a header row of channel names.
    method: "auto" (the library's automatic estimator, README "Right answers by default"),
        "ls", "rls", "iv", "ekf", "kf_rls" (identify.h).
    forgetting: in (0, 1]; None = 1 (no forgetting).
    prefilter_hz: regressor pre-filter cutoff in Hz; 0 = off; None = automatic.
    iv_lag: instrument delay in samples (iv, auto); None = automatic.
    track_every: an estimate every this many samples into ``Result.tracks``. None: every
        0.1 s of samples for recursive settings (rls, ekf, kf_rls, or forgetting < 1),
        no tracks otherwise; 0: no tracks.
    dbc, channel_map: for a candump log given by path (read_capture); a log with missing
        samples is refused, naming the rows, the time and the count.

    Raises ValueError for data that do not fit the stand (naming the channel), VibidError
    for what the library refuses (its message, e.g. the parameters that cannot be separated).
    """
    if not isinstance(stand, Stand):
        stand = Stand.load(stand)
    if method not in METHODS:
        raise ValueError(f"method {method!r}: one of {', '.join(METHODS)}")
    block, t = _columns(stand, data, dbc, channel_map)
    ident = _core.Ident(stand._core, METHODS[method], 1.0 if forgetting is None else float(forgetting),
                        -1.0 if prefilter_hz is None else float(prefilter_hz), 0 if iv_lag is None else int(iv_lag))
    est_code, f_c, lag, gamma, order = ident.config()
    config = {"method": _METHOD_NAMES.get(est_code, str(est_code)), "prefilter_hz": f_c, "iv_lag": lag,
              "forgetting": gamma, "difference_order": order}
    n = block.shape[0]
    if track_every is None:
        recursive = est_code in _RECURSIVE or gamma < 1.0
        track_every = max(1, int(round(stand.sample_rate / 10))) if recursive else 0
    if track_every < 0:
        raise ValueError(f"track_every = {track_every}: a number of samples >= 0")
    diverged = 0
    rows = []
    if track_every:
        names = stand.parameters
        for start in range(0, n, track_every):
            stop = min(n, start + track_every)
            diverged += ident.push(block, start, stop)
            e = ident.estimate()
            idx = stop - 1
            row = {"time_s": t[idx] if t is not None else idx / stand.sample_rate, "index": idx}
            for i, p in enumerate(names):
                row[p] = e["theta"][i]
                row[p + "_se"] = e["se"][i]
            for i in range(len(e["freq_hz"])):
                row[f"f{i + 1}_hz"] = e["freq_hz"][i]
                row[f"f{i + 1}_hz_se"] = e["freq_hz_se"][i]
                row[f"zeta{i + 1}"] = e["zeta"][i]
                row[f"zeta{i + 1}_se"] = e["zeta_se"][i]
            row["flags"] = _flags(e["status"] == 0, e["implausible"], e["quality"])
            rows.append(row)
        final = e if n else ident.estimate()
    else:
        diverged += ident.push(block, 0, n)
        final = ident.estimate()
    if final["status"] != 0:
        raise VibidError(f"vibid_ident_estimate after {n} samples: {final['message']}")
    tracks = pd.DataFrame(rows)
    return Result(stand, final, ident.describe(), config, tracks, n, diverged)
