"""vibid.identify: a capture in, parameters, modes, covariance and tracks out."""

from __future__ import annotations

import html
import math
import os
from typing import Any, Mapping, Optional, Sequence

import numpy as np
import pandas as pd

from . import _adequacy, _core
from ._captures import CaptureError, location
from ._stand import Stand

VibidError = _core.VibidError

# method name -> the library's estimator code: the library's own name table (identify.h,
# vibid_estimator_name), "auto" (the default) first.
_NAMES = _core.estimator_names()
METHODS = {name: _NAMES.index(name) for name in ["auto"] + [n for n in _NAMES if n != "auto"]}
# The held-out part of a capture (its last fraction): auto's choice and every result's
# adequacy figures are computed on it (docs/python.md, "The automatic choice").
HOLDOUT = 0.2
_METHOD_NAMES = {v: k for k, v in METHODS.items()}
# Estimators whose estimate follows the data sample by sample: identify gives them tracks
# by default. The batch estimators (ls, iv, auto's IV) only with forgetting < 1 or an
# explicit track_every.
_RECURSIVE = {_core.ESTIMATOR_RLS, _core.ESTIMATOR_EKF, _core.ESTIMATOR_KF_RLS}
# Columns a capture may have beside the stand's channels: the sample time.
_TIME_COLUMNS = ("t", "time_s")


def _flags(status_ok: bool, implausible: int, quality: int) -> str:
    """The daemon's flag letters (docs/vibidd.md, order G E P U I A) that apply offline:
    E no estimate, P physically impossible, U error bars do not hold, I hardly informed,
    and the batch letters R the output-error refinement failed (the equation-error estimate
    stands). (G gaps and A alarms belong to a live acquisition; M, the model cannot explain
    the data, is added by the adequacy check.)"""
    if not status_ok:
        return "E"
    s = ""
    if implausible:
        s += "P"
    if quality & _core.QUALITY_SE_INVALID:
        s += "U"
    if quality & _core.QUALITY_NOT_EXCITED:
        s += "I"
    if quality & _core.QUALITY_REFINE_FAILED:
        s += "R"
    return s


def _add_flag(flags: str, letter: str) -> str:
    """flags with letter added in the order E P U I R M (once)."""
    if letter in flags:
        return flags
    order = "EPUIRM"
    return "".join(c for c in order if c in flags or c == letter)


def _columns(stand: Stand, data: Any, dbc: Any = None,
             channel_map: Any = None) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """The capture as an (n_samples x n_channels) float64 array in the stand's channel
    order, and the time column if there is one. Copies only where the layout requires it:
    a 2-D array is used as it is (any strides); a DataFrame whose channels share one float64
    block comes out column-major without a copy; a dict of separate arrays is gathered into
    one column-major block (one copy, the C API takes one block)."""
    channels = stand.channels
    t = None
    source = None  # {"path", "format"} of a capture file: bad samples are named by file and line
    if isinstance(data, (str, os.PathLike)):
        # A file (CSV, MDF4, TDMS by its extension): read_capture gives the stand's channels,
        # converted to the stand's units, and time_s (checked below as any time column).
        from ._captures import read_capture
        path = os.fspath(data)
        data = read_capture(path, stand, dbc=dbc, channel_map=channel_map)
        source = data.attrs.get("source")
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
    def at(row: int) -> str:  # "file.csv:123: " for a capture file, "" for data in memory
        return f"{location(source['path'], source['format'], row)}: " if source else ""

    bad_input = CaptureError if source else ValueError
    finite = np.isfinite(block)
    if not finite.all():
        col = int(np.argmin(finite.all(axis=0)))
        row = int(np.argmin(finite[:, col]))
        raise bad_input(f"{at(row)}channel {channels[col]!r}: non-finite value {float(block[row, col])!r} at row {row} "
                        "(the estimators would restart their difference windows there; remove or fill gaps first)")
    # One wild value (1.0 or 1e300 in millimetre motions) enters every sum of the estimators
    # and stays there. vibidd takes such single-sample glitches out (vibid/outlier.h, its
    # flag O); identify takes no gaps, so it names the first one instead of answering wrong.
    bad = _core.outliers(block)
    if bad:
        row, col = bad[0]
        raise bad_input(f"{at(row)}channel {channels[col]!r}: value {float(block[row, col])!r} at row {row} is a "
                         f"single-sample glitch ({len(bad)} in this capture; the outlier test of "
                         "vibid/outlier.h, as vibidd's): remove or repair it (vibid.replay takes such "
                         "glitches out as vibidd does)")
    if t is not None and len(t) > 2:
        # As vibidd: a capture whose rate is more than 1 % off the stand's is refused,
        # naming both rates (the estimates would be off by that much without a word).
        rate = 1.0 / float(np.median(np.diff(t)))
        if not math.isfinite(rate) or abs(rate / stand.sample_rate - 1.0) > 0.01:
            raise bad_input(f"{source['path'] + ': ' if source else ''}the capture's time column gives {rate:.6g} Hz, "
                            f"the stand {stand.name!r} says {stand.sample_rate:.6g} Hz (more than 1 % apart)")
    return block, t


class Result:
    """What :func:`identify` found.

    Attributes
    ----------
    parameters : DataFrame, one row per unknown: ``value``, ``se`` (standard error),
        ``unit``, ``kind``, ``true_value`` (NaN where the stand gives none), ``z`` =
        (value - true_value) / se, ``flags`` (the daemon's letters for this parameter:
        P impossible, U error bars do not hold, I hardly informed by the data, R the
        output-error refinement failed).
    offsets : DataFrame, one row per measured response channel of an output-error estimate
        (index: the channel): ``value``, ``se``, ``unit``, ``quantity``; the constant sensor
        offsets, measured = true + offset. Empty for the other estimators.
    modes : DataFrame, one row per mode in ascending frequency: ``freq_hz``,
        ``freq_hz_se``, ``zeta``, ``zeta_se``, ``flags`` (P). The standard errors come from
        the C library (``vibid_model_modal``: first-order propagation of the parameters'
        covariance through the modal map, i.e. the delta method, done in C).
    covariance : (p x p) ndarray of the parameters, consistent with ``se``.
    tracks : DataFrame of the estimate after every ``track_every`` samples, columns as the
        daemon's tracks file (``time_s``, ``index``, each parameter and ``<p>_se``, per mode
        ``f<i>_hz``, ``f<i>_hz_se``, ``zeta<i>``, ``zeta<i>_se``, then ``flags``); empty
        without tracking. ``time_s`` is the capture's time column where it has one, else
        ``index / sample_rate``. Always the recursive or equation-error estimator's (for
        ``oe`` and an output-error winner of ``auto``: the automatic estimator's).
    adequacy : dict, the held-out validation (docs/python.md "Model adequacy"): the
        estimate from the first part of the capture simulated on the held-out last part:
        ``nrmse``, ``ljung_box_q``, ``ljung_box_dof``, ``ljung_box_p``, ``structured``,
        ``flag`` ("M" or ""), ``why``, ``channels`` (DataFrame per response channel),
        ``simulated``, ``x0``, ``segment`` (first and end sample of the held-out part);
        ``unavailable`` (the reason) where no validation could be made.
    instruments : dict or None: the first-stage strength of the instrumental variables
        where the reported estimate is IV's (``rho_min``, ``f_stat``, ``n_eff``, ``weak``).
    flags : the whole estimate's letters (E P U I R M), as a row of the daemon's tracks plus
        R and M.
    why : the plausibility findings in words ("" when plausible).
    description : what was chosen and why: the automatic choice's account, then the
        estimator's own (``vibid_ident_describe``).
    config : the settings in force after the automatic choices; ``method`` is the estimator
        whose estimate is reported (``auto`` resolves to ``oe``, ``auto(iv)`` or
        ``auto(ekf)``), ``requested`` the method asked for, ``choice`` auto's reason.
    """

    def __init__(self, stand: Stand, est: Any, description: str, config: dict, tracks: pd.DataFrame,
                 n_samples: int, diverged_samples: int, offsets: Any = None, adequacy: Optional[dict] = None,
                 instruments: Optional[dict] = None, unsure: str = ""):
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
        # U beyond the library's: weak instruments of an IV estimate, or an output-error
        # estimate that disagrees with the IV one beyond both error bars (unsure: the reason)
        weak = bool(instruments and instruments.get("weak")) or bool(unsure)
        self.unsure = unsure
        pflags = []
        for i in range(len(theta)):
            f = _flags(True, est["param_implausible"][i], est["param_quality"][i])
            pflags.append(_add_flag(f, "U") if weak else f)
        self.parameters = pd.DataFrame(
            {"value": theta, "se": se, "unit": stand.units, "kind": stand.kinds, "true_value": truth, "z": z,
             "flags": pflags},
            index=pd.Index(stand.parameters, name="parameter"))
        self.offsets = _offsets_frame(stand, offsets)
        self.modes = pd.DataFrame(
            {"freq_hz": est["freq_hz"], "freq_hz_se": est["freq_hz_se"], "zeta": est["zeta"], "zeta_se": est["zeta_se"],
             "flags": ["P" if f else "" for f in est["mode_implausible"]]},
            index=pd.Index(range(1, len(est["freq_hz"]) + 1), name="mode"))
        self.covariance = np.array(est["covariance"])
        self.adequacy = adequacy if adequacy is not None else _adequacy.unavailable("not computed")
        self.instruments = instruments
        self.flags = _flags(True, est["implausible"], est["quality"])
        if weak:
            self.flags = _add_flag(self.flags, "U")
        if self.adequacy.get("flag"):
            self.flags = _add_flag(self.flags, "M")
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
            if len(self.offsets):
                lines.append(self.offsets.to_string(float_format=lambda v: f"{v:.6g}"))
            lines.append(self.modes.to_string(float_format=lambda v: f"{v:.6g}"))
            if self.why:
                lines.append("implausible: " + self.why)
            lines.append(adequacy_line(self))
            if len(self.tracks):
                lines.append(f"tracks: {len(self.tracks)} rows")
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        head = (f"<p><b>vibid.Result</b>: stand <code>{html.escape(self.stand.name)}</code>, method "
                f"<code>{html.escape(self.method)}</code>, {self.n_samples} samples, flags "
                f"<code>{html.escape(self.flags or '-')}</code></p>")
        parts = [head, self.parameters.to_html(float_format=lambda v: f"{v:.6g}")]
        if len(self.offsets):
            parts.append(self.offsets.to_html(float_format=lambda v: f"{v:.6g}"))
        parts.append(self.modes.to_html(float_format=lambda v: f"{v:.6g}"))
        if self.why:
            parts.append(f"<p>implausible: {html.escape(self.why)}</p>")
        parts.append(f"<p>{html.escape(adequacy_line(self))}</p>")
        parts.append(f"<details><summary>estimator</summary><pre>{html.escape(self.description)}</pre></details>")
        return "\n".join(parts)

    def plot(self, parameters=None, figsize=None):
        """The tracks with value +- 2 se bands, one axis per parameter, the true value dashed
        (else the nominal start value dash-dotted); for a result without tracks one point
        with its 2-se error bar per axis. Returns a ``matplotlib.figure.Figure`` (no pyplot,
        draws headless). Needs matplotlib (the extra ``plot``); docs/python.md."""
        from ._plot import plot_result  # matplotlib only when asked for a figure

        return plot_result(self, parameters, figsize)

    def simulate(self, inputs: Any, x0: Any = None, offsets: Any = None) -> pd.DataFrame:
        """The identified model driven by ``inputs``: a DataFrame or dict with the stand's
        input channels (force inputs and the base displacement, :func:`simulator_inputs`;
        other channels are ignored) or a 2-D array with every channel in the stand's order.
        ``x0``: the initial state [displacements; velocities] of the nodes (2 n values), None
        = at rest. ``offsets``: None = none (the model's response), else per response
        channel a sequence in the columns' order or a mapping channel -> offset (e.g.
        ``result.offsets["value"]``). Returns the simulated response channels (the stand's
        measured displacements, velocities and accelerations of nodes), one column each, by
        the library's output-error simulator (``vibid_oe_simulate``: linear stands exactly,
        cubic springs by RK4; a stand with disturbances: its deterministic part, the
        disturbances zero). Raises VibidError where the stand cannot be simulated (a moving
        base whose displacement is not measured; a disturbance beside a cubic spring or a
        base) or the simulation diverges."""
        block = _adequacy.input_block(self.stand, inputs)
        oe = _adequacy.simulator(self.stand)
        resp = list(oe.response_channels())
        names = [self.stand.channels[c] for c in resp]
        th = [float(v) for v in self.parameters["value"]]
        if x0 is not None:
            x0 = [float(v) for v in np.asarray(x0, dtype=float).ravel()]
        if offsets is not None:
            if isinstance(offsets, (Mapping, pd.Series)):
                offsets = [float(offsets.get(c, 0.0)) for c in names]
            else:
                offsets = [float(v) for v in np.asarray(offsets, dtype=float).ravel()]
        out = oe.simulate(th, x0, offsets, block)
        return pd.DataFrame(np.asarray(out), columns=names)

    def validate(self, capture: Any) -> dict:
        """The estimate's simulation error on a capture (any that :func:`identify` takes):
        the model at this estimate driven by the capture's measured inputs, its initial state
        and one offset per response channel fitted with the parameters fixed (docs/python.md
        "Model adequacy"). Returns the dict of ``Result.adequacy`` for that capture:
        ``nrmse`` (overall), ``channels`` (per response channel: rms_measured, rms_residual,
        nrmse, offset, ljung_box_q, ljung_box_p, predictable), ``ljung_box_q``,
        ``ljung_box_dof``, ``ljung_box_p``, ``structured``, ``flag`` ("M" when the model
        cannot explain the capture), ``why``, ``simulated``, ``x0``."""
        block, _ = _columns(self.stand, capture)
        return _adequacy.validate_block(self.stand, self.parameters["value"].to_numpy(float), block,
                                        _adequacy.omega_of(self.modes["freq_hz"], self.stand.sample_rate))


def _offsets_frame(stand: Stand, offsets: Any) -> pd.DataFrame:
    """Result.offsets from vibid_ident_offsets' (channels, values, se)."""
    cols = {"value": [], "se": [], "unit": [], "quantity": []}
    names = []
    if offsets is not None:
        chans, values, ses = offsets
        quantities = stand.channel_quantities
        lu = stand.length_unit
        unit = {"displacement": lu, "velocity": lu + "/s", "acceleration": lu + "/s^2"}
        for c, v, s in zip(chans, values, ses):
            names.append(stand.channels[c])
            cols["value"].append(float(v))
            cols["se"].append(float(s))
            cols["quantity"].append(quantities[c])
            cols["unit"].append(unit.get(quantities[c], ""))
    return pd.DataFrame(cols, index=pd.Index(names, name="channel")).astype(
        {"value": float, "se": float, "unit": object, "quantity": object})


def adequacy_line(result: Result) -> str:
    """The adequacy figures in one line (the command, repr)."""
    a = result.adequacy
    if a.get("unavailable"):
        return f"adequacy: not available: {a['unavailable']}"
    seg = a.get("segment")
    where = f"held-out samples {seg[0]}..{seg[1] - 1}" if seg else "the capture"
    return (f"adequacy on {where}: NRMSE {a['nrmse']:.4g}, Ljung-Box Q {a['ljung_box_q']:.4g} on {a['ljung_box_dof']} "
            f"lags, p {a['ljung_box_p']:.3g}, predictable part {a['structured']:.3g} of the RMS"
            + (f"; flag M: {a['why']}" if a.get("flag") else ""))


class _Run:
    """One identification's pass over the capture: samples pushed in chunks that end at the
    track rows (every track_every samples) and at the snapshots asked for, an estimate at
    each. Not for OE (its estimate is a fit over every sample so far)."""

    def __init__(self, stand: Stand, code: int, settings: tuple):
        self.stand = stand
        self.ident = _core.Ident(stand._core, code, *settings)
        self.diverged = 0
        self.rows: list = []
        self.snapshots: dict = {}

    def run(self, block: np.ndarray, t: Optional[np.ndarray], track_every: int, snapshots: Sequence[int]) -> dict:
        n = block.shape[0]
        stops = set(snapshots)
        if track_every:
            stops.update(range(track_every, n, track_every))
        stops.add(n)
        start, e = 0, None
        names = self.stand.parameters
        for stop in sorted(s for s in stops if 0 < s <= n):
            self.diverged += self.ident.push(block, start, stop)
            start = stop
            track_row = track_every and (stop % track_every == 0 or stop == n)
            if not (track_row or stop in snapshots):
                continue
            e = self.ident.estimate()
            if stop in snapshots:
                self.snapshots[stop] = e
            if track_row:
                idx = stop - 1
                row = {"time_s": t[idx] if t is not None else idx / self.stand.sample_rate, "index": idx}
                for i, p in enumerate(names):
                    row[p] = e["theta"][i]
                    row[p + "_se"] = e["se"][i]
                for i in range(len(e["freq_hz"])):
                    row[f"f{i + 1}_hz"] = e["freq_hz"][i]
                    row[f"f{i + 1}_hz_se"] = e["freq_hz_se"][i]
                    row[f"zeta{i + 1}"] = e["zeta"][i]
                    row[f"zeta{i + 1}_se"] = e["zeta_se"][i]
                row["flags"] = _flags(e["status"] == 0, e["implausible"], e["quality"])
                self.rows.append(row)
        final = e if (e is not None and start == n and (track_every or n in snapshots)) else self.ident.estimate()
        if final["status"] != 0:
            raise VibidError(f"vibid_ident_estimate after {n} samples: {final['message']}")
        return final


def _config(ident: Any, requested: str) -> dict:
    est_code, f_c, lag, gamma, order = ident.config()
    return {"method": _METHOD_NAMES.get(est_code, str(est_code)), "requested": requested, "prefilter_hz": f_c,
            "iv_lag": lag, "forgetting": gamma, "difference_order": order}


def _validate(stand: Stand, est: dict, block: np.ndarray, segment: tuple[int, int],
              predictor: bool = False) -> dict:
    """The held-out figures of an estimate (the adequacy), or why there are none. A stand
    with disturbances is validated by the prediction-error fit's predictor (predictor: the
    estimate is that fit's), never by a simulation."""
    if est["status"] != 0:
        return _adequacy.unavailable(f"no estimate on the first part: {est['message']}", segment)
    if stand._core.n_disturbances:
        if not predictor:
            return _adequacy.unavailable("a stand with disturbances is validated by the one-step prediction of the "
                                         "prediction-error fit (method 'oe' or 'auto'), not by a simulation", segment)
        try:
            v = _adequacy.validate_predictor(stand, est["theta"], block[:segment[0]], block[segment[0]:segment[1]])
        except (VibidError, ValueError, np.linalg.LinAlgError) as e:
            return _adequacy.unavailable(f"the predictor cannot be validated on the held-out part: {e}", segment)
        v["segment"] = segment
        v["unavailable"] = ""
        return v
    try:
        v = _adequacy.validate_block(stand, est["theta"], block[segment[0]:segment[1]],
                                     _adequacy.omega_of(est["freq_hz"], stand.sample_rate))
    except (VibidError, ValueError, np.linalg.LinAlgError) as e:
        return _adequacy.unavailable(f"the model cannot be simulated on the held-out part: {e}", segment)
    v["segment"] = segment
    v["unavailable"] = ""
    return v


def _first_stage(stand: Stand, block: np.ndarray, config: dict) -> Optional[dict]:
    """The instruments' strength for an IV estimate (None where the regression is not the
    structured form the IV ran on)."""
    try:
        return _adequacy.first_stage(stand, block, float(config["prefilter_hz"]), int(config["difference_order"]),
                                     int(config["iv_lag"]))
    except (VibidError, ValueError, np.linalg.LinAlgError):
        return None


# Agreement of the output-error and the equation-error (IV) estimates of the same capture:
# below this p-value they disagree beyond their error bars.
AGREEMENT_P = 1e-3


def _agreement(oe: dict, ee: dict) -> Optional[tuple[float, int, float]]:
    """A Hausman-type test of the output-error estimate against the IV one: chi2 =
    d' (V_oe + V_ee)^-1 d with d their difference (the two are positively correlated, so the
    sum over-states the variance of d and the test errs towards agreement), p-value with p
    degrees of freedom. None where either has no usable covariance."""
    d = np.asarray(oe["theta"]) - np.asarray(ee["theta"])
    V = np.asarray(oe["covariance"]) + np.asarray(ee["covariance"])
    if not (np.isfinite(d).all() and np.isfinite(V).all()):
        return None
    try:
        c = float(d @ np.linalg.solve(V, d))
    except np.linalg.LinAlgError:
        return None
    return c, len(d), _adequacy.chi2_sf(c, len(d))


def _disagrees(est: dict, ee: dict, lib: str, instruments: Optional[dict]) -> str:
    """Why the output-error estimate's error bars do not hold ("" when they may): it and the
    library's IV estimate of the same samples disagree beyond both error bars, so an assumption
    of one fails (exact and piecewise-linear inputs for the output error, no sensor offset for
    the IV); the IV's bars are the tested ones (coverage, README), so the output error's row
    is flagged U. Not where the IV is not used (weak instruments) or is the EKF."""
    if lib != "iv" or (instruments and instruments.get("weak")) or est["quality"] & _core.QUALITY_REFINE_FAILED:
        return ""
    a = _agreement(est, ee)
    if a is None or a[2] >= AGREEMENT_P:
        return ""
    return (f"the output-error and IV estimates disagree beyond their error bars (chi2 {a[0]:.3g} on {a[1]} "
            f"degrees of freedom, p {a[2]:.2g} < {AGREEMENT_P:g}): an assumption of one fails (noise on an input "
            "or a smooth input for the output error, a sensor offset for the IV); the output error's standard "
            "errors do not hold (U)")


def _oe_failure(ident: Any) -> str:
    """The reason of a failed output-error refinement (vibid_ident_describe's line)."""
    for line in ident.describe().splitlines():
        if line.startswith(("output-error refinement failed", "prediction-error refinement failed")):
            return line.split(": ", 1)[-1]
    return "the output-error refinement failed"


def identify(stand: Stand | str | os.PathLike, data: Any, method: str = "auto",
             forgetting: Optional[float] = None, prefilter_hz: Optional[float] = None,
             iv_lag: Optional[int] = None, track_every: Optional[int] = None, *, dbc: Any = None,
             channel_map: Any = None, holdout: float = HOLDOUT) -> Result:
    """Identifies the stand's unknowns from a capture.

    stand: a :class:`Stand` or the path of a stand file.
    data: a pandas DataFrame or a dict of 1-D arrays keyed by the stand's channel names
        (``stand.channels``; a time column ``t`` or ``time_s`` is allowed and checked
        against the stand's sample rate), a 2-D array (n_samples x n_channels) in the
        stand's channel order, or the path of a CSV file with a header row of channel names.
    method: "auto" (the validated automatic choice: the library's automatic estimator and,
        where the stand can be simulated, the output-error fit, the one with the smaller
        simulation error on the held-out part kept; docs/python.md), "oe" (output error on
        the stand's model, started from the automatic estimate), "ls", "rls", "iv", "ekf",
        "kf_rls" (identify.h).
    forgetting: in (0, 1]; None = 1 (no forgetting).
    prefilter_hz: regressor pre-filter cutoff in Hz; 0 = off; None = automatic.
    iv_lag: instrument delay in samples (iv, auto); None = automatic.
    track_every: an estimate every this many samples into ``Result.tracks``. None: every
        0.1 s of samples for recursive settings (rls, ekf, kf_rls, or forgetting < 1),
        no tracks otherwise; 0: no tracks.
    dbc, channel_map: for a candump log given by path (read_capture); a log with missing
        samples is refused, naming the rows, the time and the count.
    holdout: the fraction at the end of the capture held out (default 0.2): the estimate
        from the samples before it is simulated on it (``Result.adequacy``) and auto
        chooses by it; the reported estimate uses the whole capture. 0: no held-out part,
        no adequacy figures, and "auto" is the library's automatic estimator alone (as
        vibidd runs it).

    Raises ValueError for data that do not fit the stand (naming the channel), VibidError
    for what the library refuses (its message, e.g. the parameters that cannot be separated).
    """
    if not isinstance(stand, Stand):
        stand = Stand.load(stand)
    if method not in METHODS:
        raise ValueError(f"method {method!r}: one of {', '.join(METHODS)}")
    if not (0.0 <= float(holdout) <= 0.5):
        raise ValueError(f"holdout = {holdout}: a fraction of the capture in [0, 0.5]")
    block, t = _columns(stand, data, dbc, channel_map)
    n = block.shape[0]
    settings = (1.0 if forgetting is None else float(forgetting), -1.0 if prefilter_hz is None else float(prefilter_hz),
                0 if iv_lag is None else int(iv_lag))
    split = n - int(round(float(holdout) * n))
    segment = (split, n)
    if holdout == 0:
        no_segment = "holdout = 0: no held-out part"
    elif n - split < _adequacy.MIN_SEGMENT or split < _adequacy.MIN_SEGMENT:
        no_segment = (f"{n} samples: too short for a held-out part of {holdout:g} (at least "
                      f"{_adequacy.MIN_SEGMENT} samples on each side)")
    else:
        no_segment = ""
    snaps = [] if no_segment else [split]
    # The pass that gives the tracks: the method's own, the automatic estimator's for oe.
    run = _Run(stand, _core.ESTIMATOR_AUTO if method == "oe" else METHODS[method], settings)
    config = _config(run.ident, method)
    if track_every is None:
        recursive = METHODS.get(config["method"], -1) in _RECURSIVE or config["forgetting"] < 1.0
        track_every = max(1, int(round(stand.sample_rate / 10))) if recursive else 0
    if track_every < 0:
        raise ValueError(f"track_every = {track_every}: a number of samples >= 0")
    final = run.run(block, t, track_every, snaps)
    # after the samples: the automatic pre-filter is chosen at the end of its pilot
    config = _config(run.ident, method)
    tracks = pd.DataFrame(run.rows)
    ee_code = _core.ESTIMATOR_EKF if config["method"] == "ekf" else _core.ESTIMATOR_IV
    lib = "ekf" if ee_code == _core.ESTIMATOR_EKF else "iv"

    def result(est, description, cfg, offsets=None, adequacy=None, instruments=None, unsure=""):
        return Result(stand, est, description, cfg, tracks, n, run.diverged, offsets, adequacy, instruments, unsure)

    def held(est, predictor=False):
        return (_adequacy.unavailable(no_segment, None) if no_segment
                else _validate(stand, est, block, segment, predictor))

    disturbed = stand._core.n_disturbances > 0

    if method == "oe":
        oe = _core.Ident(stand._core, _core.ESTIMATOR_OE, *settings)
        cfg = _config(oe, method)
        adequacy = None
        if not no_segment:
            oe.push(block, 0, split)
            adequacy = held(oe.estimate(), predictor=True)
            oe.push(block, split, n)
        else:
            oe.push(block, 0, n)
            adequacy = held(None)
        est = oe.estimate()
        if est["status"] != 0:
            raise VibidError(f"vibid_ident_estimate after {n} samples: {est['message']}")
        tr = ("\ntracks: the automatic estimator's (the output-error fit runs once, on the whole capture)"
              if len(tracks) else "")
        # the automatic estimate's instruments: checked where it is reported (a failed
        # refinement) and before it is compared with the output error's
        ins = _first_stage(stand, block, config) if lib == "iv" else None
        unsure = _disagrees(est, final, lib, ins)
        failed = est["quality"] & _core.QUALITY_REFINE_FAILED
        return result(est, oe.describe() + tr + (f"\n{unsure}" if unsure else ""), cfg, oe.offsets(), adequacy,
                      ins if failed else None, unsure)

    if method != "auto" or no_segment:
        cfg = config
        if method == "auto":
            cfg = dict(config, method=f"auto({lib})", choice=f"the library's automatic estimator alone ({no_segment})")
        instruments = None
        if not no_segment and cfg["method"] in ("iv", "auto"):
            instruments = _first_stage(stand, block, cfg)
        return result(final, run.ident.describe(), cfg, None, held(run.snapshots.get(split)) if not no_segment
                      else held(None), instruments)

    # auto, validated (docs/python.md "The automatic choice"): the library's automatic
    # estimate and the output-error fit, each from the first part, simulated on the held-out part.
    ee80 = run.snapshots[split]
    v_ee = held(ee80)
    instruments = _first_stage(stand, block, config) if lib == "iv" else None
    weak = bool(instruments and instruments["weak"])
    ee_cfg = dict(config, method=f"auto({lib})")
    fig = f"held-out NRMSE {v_ee['nrmse']:.4g}" if not v_ee.get("unavailable") else "not validated"
    head = (f"choice: the estimates of samples 0..{split - 1} simulated on the held-out samples {split}..{n - 1} "
            f"(the last {holdout:g} of the capture); the reported estimate uses all {n} samples")
    try:
        oe = _core.Ident(stand._core, _core.ESTIMATOR_OE, *settings)
    except VibidError as e:
        why = f"output error cannot run on this stand ({e}): the library's automatic estimator ({lib}) stands"
        ee_cfg["choice"] = why
        return result(final, why + "\n" + run.ident.describe(), ee_cfg, None, v_ee, instruments)
    oe.push(block, 0, split)
    oe80 = oe.estimate()
    if oe80["status"] != 0 or oe80["quality"] & _core.QUALITY_REFINE_FAILED:
        reason = oe80["message"] if oe80["status"] != 0 else _oe_failure(oe)
        why = (f"{head}; the output-error fit on the first part failed ({reason}): the library's automatic "
               f"estimator ({lib}) stands, {fig}")
        ee_cfg["choice"] = why
        return result(final, why + "\n" + run.ident.describe(), ee_cfg, None, v_ee, instruments)
    v_oe = held(oe80, predictor=True)
    nr_ee, nr_oe = v_ee["nrmse"], v_oe["nrmse"]
    if disturbed:
        # no simulation compares them (the response is mostly the disturbances'); the
        # prediction-error fit is the maximum-likelihood estimate, the EKF is biased where its
        # gain's dependence on the parameters matters (docs/python.md "Stands with disturbances")
        oe_wins = True
        because = ("the stand declares a disturbance: the prediction-error fit is the maximum-likelihood estimate "
                   f"(the EKF ignores how its gain depends on the parameters); held-out one-step prediction NRMSE "
                   f"{nr_oe:.4g}" + (f", flagged {v_oe['flag']}" if v_oe.get("flag") else "")
                   if not v_oe.get("unavailable") else
                   "the stand declares a disturbance: the prediction-error fit is the maximum-likelihood estimate "
                   f"(the EKF ignores how its gain depends on the parameters); not validated ({v_oe['unavailable']})")
    elif v_oe.get("unavailable"):
        oe_wins, because = False, f"the output-error estimate could not be validated ({v_oe['unavailable']})"
    elif weak:
        oe_wins, because = True, (f"the instruments of the IV are weak (first-stage F {instruments['f_stat']:.3g} "
                                  f"< {_adequacy.WEAK_F:g}, smallest canonical correlation "
                                  f"{instruments['rho_min']:.3g}): IV is not used")
    elif not math.isfinite(nr_ee):
        oe_wins, because = True, f"held-out NRMSE: output error {nr_oe:.4g}, {lib} {nr_ee:.4g}"
    else:
        # better by more than the held-out noise of the comparison (docs/python.md): a
        # difference within it is no evidence, and the equation-error estimate is consistent
        # with noisy inputs, which bias the output error
        diff, se = _adequacy.compare(stand, v_ee, v_oe, block[split:n])
        tval = diff / se if se > 0 else (math.inf if diff > 0 else 0.0)
        oe_wins = tval > _adequacy.COMPARE_T
        because = (f"held-out NRMSE: output error {nr_oe:.4g}, {lib} {nr_ee:.4g} (difference of the squares "
                   f"{tval:.3g} standard errors, {'above' if oe_wins else 'not above'} {_adequacy.COMPARE_T:g})")
    if not oe_wins:
        why = f"{head}; kept {lib}: {because}"
        ee_cfg["choice"] = why
        return result(final, why + "\n" + run.ident.describe(), ee_cfg, None, v_ee, instruments)
    oe.push(block, split, n)
    est = oe.estimate()
    if est["status"] != 0:
        raise VibidError(f"vibid_ident_estimate after {n} samples: {est['message']}")
    cfg = dict(_config(oe, "auto"), method="oe")
    why = f"{head}; kept {'the prediction-error fit' if disturbed else 'output error'}: {because}"
    if est["quality"] & _core.QUALITY_REFINE_FAILED:
        why += (f"; but its fit on the whole capture failed ({_oe_failure(oe)}): the equation-error estimate "
                "stands, flagged R")
        cfg["method"] = f"auto({lib})"
    unsure = _disagrees(est, final, lib, instruments)
    if unsure:
        why += "; " + unsure
    cfg["choice"] = why
    tr = "\ntracks: the automatic estimator's (the output-error fit runs on the whole capture once)" if len(tracks) else ""
    return result(est, why + "\n" + oe.describe() + tr, cfg, oe.offsets(), v_oe,
                  instruments if cfg["method"] != "oe" else None, unsure)
