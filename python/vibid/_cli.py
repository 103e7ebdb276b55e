"""The `vibid` command: identify a capture, check a stand, simulate one (docs/python.md).

    vibid identify STAND CAPTURE [--method M] [--forgetting G] [--prefilter-hz F]
                   [--iv-lag L] [--holdout H] [--track-every N] [--tracks OUT.csv] [--report OUT.html]
    vibid check STAND
    vibid simulate STAND OUT.csv [--sim SIM.cfg] [--duration S] [--seed N]

Exit status: 0 success (check: identifiable); 1 what the library refuses, bad input, a
stand that cannot be identified, a file that cannot be read or written (the message on
stderr, no traceback); 2 a bad command line (argparse)."""

from __future__ import annotations

import argparse
import datetime
import html
import math
import os
import shutil
import subprocess
import sys
from typing import Optional, Sequence

import numpy as np
import pandas as pd

from . import _adequacy, _core
from ._identify import HOLDOUT, METHODS, Result, _columns, adequacy_line, identify
from ._stand import Stand

PROG = "vibid"

# The letters of vibidd's tracks (docs/vibidd.md, "Outputs") that identify reports.
FLAG_MEANING = {
    "E": "no estimate (too few samples, or the estimate failed)",
    "P": "physically impossible (plausibility.h: a mass, damper or spring <= 0, a mode at <= 0 Hz or at/above "
         "Nyquist, a negative damping ratio, or an overdamped mode the nominal model has underdamped)",
    "U": "the standard errors do not hold (ls/rls always; auto/iv: the older and newer halves of the blocks "
         "disagree, or too few blocks)",
    "I": "hardly informed by the data (its se is inf)",
    "R": "the output-error refinement failed (no convergence, a bound, a singular information matrix, a diverged "
         "simulation): the equation-error estimate stands, the reason in the estimator's description",
    "M": "the model cannot explain the data: on the held-out part its simulation leaves more than "
         f"{_adequacy.NRMSE_LIMIT:g} NRMSE, or residuals that are not white with a predictable part above "
         f"{_adequacy.STRUCTURED_LIMIT:g} of the outputs' RMS (docs/python.md, \"Model adequacy\")",
}


# What U means for each estimator (lib/include/vibid/identify.h, VIBID_QUALITY_SE_INVALID and
# the package's own U of _identify.py): the letter is one, its cause is the estimator's.
U_MEANING = {
    "ls": "the standard errors do not hold: LS's textbook covariance assumes white equation errors, which "
          "differences and the pre-filter never give (always flagged)",
    "rls": "the standard errors do not hold: RLS's textbook covariance assumes white equation errors "
           "(always flagged)",
    "iv": "the standard errors do not hold: the older and newer halves of the blocks disagree (|z| > 4) or "
          "there are too few blocks, or the instruments are weak",
    "ekf": "the standard errors do not hold: the EKF's sandwich variance exceeds 3 times the filter's for some "
           "parameter (a model error), fewer than 16 blocks of scores, the averaged normalised innovation "
           "square exceeds 2, or the drift check (estimate against a snapshot a quarter to half of the run "
           "ago) exceeds |z| = 4 or has not run yet",
    "kf_rls": "the standard errors do not hold: KF-RLS's are the regression's on filtered, coloured regressors "
              "(always flagged)",
    "oe": "the standard errors do not hold: the output-error estimate disagrees with the IV one beyond both "
          "error bars, or the equation-error estimate it started from is flagged",
}


def flag_meaning(letter: str, method: str) -> str:
    """FLAG_MEANING, with U's cause for this estimator (method as Result.method:
    'auto(ekf)' is the EKF's)."""
    if letter == "U":
        m = method[5:-1] if method.startswith("auto(") else method
        return U_MEANING.get(m, FLAG_MEANING["U"])
    return FLAG_MEANING[letter]


def flag_counts(result: Result) -> dict:
    """Per letter: 'estimate' (1 where the whole estimate carries it), 'parameters' and
    'modes' (how many carry it) and 'tracks' (how many track rows carry it), and 'rows'
    (the number of track rows)."""
    out = {}
    fl = result.tracks["flags"].astype(str) if len(result.tracks) else pd.Series([], dtype=str)
    for letter in "EPUIRM":
        out[letter] = {"estimate": int(letter in result.flags),
                       "parameters": int(sum(letter in f for f in result.parameters["flags"])),
                       "modes": int(sum(letter in f for f in result.modes["flags"])),
                       "tracks": int(fl.str.contains(letter, regex=False).sum())}
    out["rows"] = len(fl)
    return out


def flag_summary(result: Result) -> str:
    """One line: the whole estimate's letters, then per letter the track rows carrying it
    ('none' only where neither the estimate, a parameter, a mode nor a track row is flagged)."""
    c = flag_counts(result)
    est = sorted({k for k in "EPUIRM" if c[k]["estimate"] or c[k]["parameters"] or c[k]["modes"]},
                 key="EPUIRM".index)
    parts = []
    if est:
        parts.append("estimate " + "".join(est))
    rows = [f"{c[k]['tracks']} {k}" for k in "EPUIRM" if c[k]["tracks"]]
    if rows:
        parts.append(f"track rows of {c['rows']}: " + ", ".join(rows))
    return "; ".join(parts) if parts else "none"


def verdict(result: Result) -> tuple[bool, str]:
    """(trusted, why) of the final estimate, from its flags: trusted where neither the
    estimate nor a parameter or mode carries a letter; flagged track rows alone (a start
    transient) leave it trusted, and the reason says so."""
    c = flag_counts(result)
    bad = [k for k in "EPUIRM" if c[k]["estimate"] or c[k]["parameters"] or c[k]["modes"]]
    if bad:
        why = "; ".join(f"{k}: {flag_meaning(k, result.method)}" for k in bad)
        return False, f"not trusted: the final estimate is flagged {''.join(bad)} ({why})"
    rows = [f"{c[k]['tracks']} {k}" for k in "EPUIRM" if c[k]["tracks"]]
    extra = (f"; {', '.join(rows)} of the {c['rows']} track rows are flagged (the estimate on the way, "
             "not the final one)") if rows else ""
    return True, ("trusted: the final estimate carries no flag (plausible, its standard errors hold, "
                  "the model explains the held-out data where checked)" + extra)


# Exit status, as vibidd's and vibid-sim's: 0 success; 1 a failure while running on good input
# (an output that cannot be written; `check`'s "cannot be identified"); 2 a bad command line,
# input or configuration (a stand or capture that is missing, unreadable or refused, vibid-sim
# not found, an extra not installed). The message on stderr, no traceback.
EXIT_RUN_FAILURE = 1
EXIT_BAD_INPUT = 2


class CliError(Exception):
    """A refusal of the command line, an input or the configuration: its message on stderr,
    no traceback, exit status 2."""
    status = EXIT_BAD_INPUT


class RunFailure(CliError):
    """A failure while running on good input (an output that cannot be written): exit status 1."""
    status = EXIT_RUN_FAILURE


def _fmt(v: float, digits: int = 10) -> str:
    # %.10g as vibidd's tracks: the printed digits are the estimate's to 1e-10.
    return "nan" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}g}"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """Columns separated by at least two spaces (units such as 'N s/m' hold single ones),
    numbers right-aligned, text left-aligned."""
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(header)]

    def line(cells, align):
        return "  ".join(c.rjust(w) if a == "r" else c.ljust(w) for c, w, a in zip(cells, widths, align)).rstrip()

    align = ["l"] + ["r" if h not in ("unit", "flags", "kind") else "l" for h in header[1:]]
    return "\n".join([line(header, align)] + [line(r, align) for r in rows])


def parameter_table(result: Result) -> str:
    p = result.parameters
    truth = p["true_value"].notna().any()
    header = ["parameter", "value", "se", "unit", "flags"] + (["true_value", "z"] if truth else [])
    rows = []
    for name, r in p.iterrows():
        row = [str(name), _fmt(r["value"]), _fmt(r["se"]), r["unit"], r["flags"] or "-"]
        if truth:
            row += [_fmt(r["true_value"]), _fmt(r["z"], 3)]
        rows.append(row)
    return _table(header, rows)


def offset_table(result: Result) -> str:
    """The output-error estimate's sensor offsets (measured = true + offset)."""
    rows = [[str(name), _fmt(r["value"]), _fmt(r["se"]), r["unit"], r["quantity"]]
            for name, r in result.offsets.iterrows()]
    return _table(["offset", "value", "se", "unit", "quantity"], rows)


def mode_table(result: Result) -> str:
    rows = [[str(i), _fmt(r["freq_hz"]), _fmt(r["freq_hz_se"]), _fmt(r["zeta"]), _fmt(r["zeta_se"]), r["flags"] or "-"]
            for i, r in result.modes.iterrows()]
    return _table(["mode", "f_hz", "f_se", "zeta", "zeta_se", "flags"], rows)


def warnings_of(result: Result) -> list[str]:
    """Every flag and warning of the estimate, in words: the whole estimate's letters, each
    parameter's and mode's, the plausibility findings, the consistency check, the
    state-space estimators' restarts and the track rows without estimate."""
    out = []
    for letter in result.flags:
        out.append(f"estimate flagged {letter}: {flag_meaning(letter, result.method)}")
    for name, f in result.parameters["flags"].items():
        for letter in f:
            out.append(f"parameter {name} flagged {letter}: {flag_meaning(letter, result.method)}")
    for i, f in result.modes["flags"].items():
        if f:
            out.append(f"mode {i} flagged P: {FLAG_MEANING['P']}")
    if result.why:
        out.append("implausible: " + result.why)
    if result.adequacy.get("flag"):
        out.append("the model cannot explain the data: " + result.adequacy["why"])
    if result.unsure:
        out.append(result.unsure)
    ins = result.instruments
    if ins and ins.get("weak"):
        out.append(f"the instruments of the IV are weak: first-stage F {ins['f_stat']:.3g} < {_adequacy.WEAK_F:g} "
                   f"(smallest canonical correlation {ins['rho_min']:.3g}): its estimate and error bars are unreliable")
    if math.isfinite(result.z_consistency):
        if result.method in ("ekf", "auto(ekf)"):
            # the EKF's figure is its drift check (identify.h), not LS/IV's block halves
            out.append(f"drift check of the EKF (the estimate against a snapshot a quarter to half of the run "
                       f"ago): largest |change| / sqrt(var(t0) - var(t)) = {result.z_consistency:.3g} (U above 4)")
        else:
            out.append(f"consistency of the older and newer halves of the blocks: largest |z| = "
                       f"{result.z_consistency:.3g} (U above 4)")
    if result.diverged_samples:
        out.append(f"the state-space filter diverged at {result.diverged_samples} samples and restarted")
    if len(result.tracks):
        fl = result.tracks["flags"].astype(str)
        for letter in "EPUIRM":
            k = int(fl.str.contains(letter, regex=False).sum())
            if k:
                out.append(f"{k} of {len(fl)} track rows flagged {letter}")
    return out


def config_line(result: Result) -> str:
    c = result.config
    return (f"settings in force: method {c['method']}, prefilter_hz {c['prefilter_hz']:g}, iv_lag {c['iv_lag']}, "
            f"forgetting {c['forgetting']:g}, difference_order {c['difference_order']}")


def write_tracks(result: Result, path: str) -> None:
    """The tracks as vibidd writes them (docs/vibidd.md, "Outputs"): '#' lines saying what
    the estimator chose, then the columns of Result.tracks. Overwritten, not appended (one
    capture, one file). %.17g: read back, the values are the Result's exactly."""
    with open(path, "w", newline="") as f:
        f.write(f"# vibid identify: stand '{result.stand.name}' ({result.stand.source}), "
                f"{result.n_samples} samples, {config_line(result)}\n")
        for line in result.description.splitlines():
            f.write(f"# {line}\n")
        result.tracks.to_csv(f, index=False, float_format="%.17g", lineterminator="\n")


# ---- the report ----

SE_DIGITS = 2  # significant digits of a standard error in the report; the value to the same place


def fmt_with_se(v: float, se: float) -> tuple[str, str]:
    """(value, se) as text: the se to SE_DIGITS significant digits and the value to the
    same decimal place (1234.5678 +- 0.01234 -> '1234.568', '0.012'); outside 1e-4..1e9 (or
    beyond 8 decimals) scientific, the value's mantissa to that place and the se with its
    own exponent (3.2e-07 +- 1.1e-09 -> '3.200e-07', '1.1e-09'). Where se is not finite or
    not positive the value gets 4 significant digits and the se its own text ('inf', 'nan')."""
    if v is None or not math.isfinite(v):
        return _fmt(v), _fmt(se, SE_DIGITS)
    if se is None or not math.isfinite(se) or se <= 0:
        return f"{v:.4g}", ("nan" if se is None or math.isnan(se) else f"{se:.{SE_DIGITS}g}")
    se = float(f"{se:.{SE_DIGITS - 1}e}")  # rounded first: 0.0999 is 0.10, not 0.100
    place = math.floor(math.log10(se)) - (SE_DIGITS - 1)  # the last printed decimal: 10**place
    big = max(abs(v), se)
    if 1e-4 <= big < 1e9 and place >= -8:
        dec = max(0, -place)
        return f"{round(v, -place):.{dec}f}", f"{round(se, -place):.{dec}f}"
    # scientific: the value's mantissa to the se's place, the se with its own exponent
    e = math.floor(math.log10(abs(v))) if v != 0 else place
    return f"{v:.{max(0, e - place)}e}", f"{se:.{SE_DIGITS - 1}e}"


def _cell(v) -> str:
    if isinstance(v, (float, np.floating)):
        return _fmt(float(v), 4)
    return html.escape(str(v))


def _html_table(df: pd.DataFrame, pairs: Optional[dict] = None) -> str:
    """df as an HTML table: columns with no information (every value NaN or empty) left
    out; each column named in `pairs` (value column -> its se column) printed with its se's
    significant digits (fmt_with_se), other numbers with 4 significant digits; every text
    escaped."""
    pairs = pairs or {}
    cols = [c for c in df.columns if not (df[c].isna().all() or (df[c].astype(str) == "").all())]
    head = "<tr><th>" + html.escape(str(df.index.name or "")) + "</th>" + "".join(
        f"<th>{html.escape(str(c))}</th>" for c in cols) + "</tr>"
    body = []
    for idx, r in df.iterrows():
        cells = []
        for c in cols:
            if c in pairs and pairs[c] in df.columns:
                txt = fmt_with_se(float(r[c]), float(r[pairs[c]]))[0]
            elif c in pairs.values():
                val = next(k for k, s in pairs.items() if s == c)
                txt = fmt_with_se(float(r[val]), float(r[c]))[1]
            else:
                txt = _cell(r[c])
            cells.append(f"<td>{html.escape(txt) if c in pairs or c in pairs.values() else txt}</td>")
        body.append(f"<tr><th>{html.escape(str(idx))}</th>" + "".join(cells) + "</tr>")
    return '<table class="t">' + head + "".join(body) + "</table>"


def channel_roles(stand: Stand) -> list[tuple[str, str, int, str]]:
    """(acquisition channel, quantity, node index / -2 base / input index, model name) in the
    model's channel order."""
    return [(ch, kind, idx, name) for ch, (kind, idx, name) in zip(stand.channels, _core.stand_channel_info(stand._core))]


def _excitation_channels(stand: Stand) -> list[str]:
    return [ch for ch, kind, idx, _ in channel_roles(stand) if kind == "input" or idx == -2]


def _settle_samples(result: Result, n: int) -> int:
    """Samples after which a start transient of the simulation has decayed to e^-5: five
    time constants 1 / (zeta 2 pi f) of the slowest-decaying identified mode, at most half
    the capture (for a stand whose every node is measured the start is the measured state
    and there is hardly a transient to wait for)."""
    m = result.modes
    tau = [1.0 / (z * 2 * math.pi * f) for f, z in zip(m["freq_hz"], m["zeta"])
           if math.isfinite(f) and math.isfinite(z) and z > 0 and f > 0]
    if not tau:
        return n // 2
    return int(min(n // 2, math.ceil(5 * max(tau) * result.stand.sample_rate)))


def model_response(result: Result, block: np.ndarray, theta: Optional[np.ndarray] = None) -> tuple[np.ndarray, int]:
    """The stand's model at theta (default: the estimate) driven by the capture's measured
    inputs (_core.stand_simulate: vibid_model_simulate, vibid/simulate.h), channels in stand order, and
    the first sample after the start transient (see _settle_samples)."""
    th = result.parameters["value"].to_numpy(float) if theta is None else np.asarray(theta, float)
    sim = _core.stand_simulate(result.stand._core, list(th), block)
    return sim, max(2, _settle_samples(result, block.shape[0]))


def response_fit(result: Result, block: np.ndarray, sim: np.ndarray, start: int) -> pd.DataFrame:
    """Per simulated (node) channel: RMS of the measured signal and of measured - model
    from `start` on, and NRMSE = their ratio."""
    rows = []
    for i, (ch, kind, idx, _) in enumerate(channel_roles(result.stand)):
        if kind == "input" or idx == -2:
            continue
        meas, model = block[start:, i], sim[start:, i]
        rms = float(np.sqrt(np.mean(meas * meas)))
        err = float(np.sqrt(np.mean((meas - model) ** 2)))
        rows.append({"channel": ch, "quantity": kind, "rms_measured": rms, "rms_error": err,
                     "nrmse": err / rms if rms > 0 else math.nan})
    return pd.DataFrame(rows).set_index("channel") if rows else pd.DataFrame()


def residuals(result: Result, block: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The equation errors of the fitted regression (regressor.h, with the estimate's
    pre-filter and differences), one column per node's equation, and the sample index of
    each row."""
    c = result.config
    return _adequacy.equation_errors(result.stand, result.parameters["value"].to_numpy(float), block,
                                     float(c["prefilter_hz"]), int(c["difference_order"]))


def channel_unit(stand: Stand, ch: str) -> str:
    """The unit of a channel in the stand's units: the length unit per s^k for a
    displacement, velocity or acceleration (of a node or the base); a force input's own
    unit ('input unit': N where its gain is 1, the default)."""
    lu = stand.length_unit
    kind = dict((c, k) for c, k, _, _ in channel_roles(stand))[ch]
    return {"displacement": lu, "velocity": f"{lu}/s", "acceleration": f"{lu}/s\u00b2"}.get(kind, "input unit")


ACF_LAGS = 50  # lags of the residuals' autocorrelation shown (the whiteness tests use 20)


def _residual_panels(fig, series, fs: float, unit: str, titles: Sequence[str]):
    """Per column of series: its Welch PSD [unit^2/Hz; 1/Hz for unit "1"] and the autocorrelation of its first
    ACF_LAGS lags with the +-1.96/sqrt(N) band. Returns (band, share of lags outside)."""
    from ._plot import autocorrelation, welch_psd

    n = series.shape[0]
    max_lag = int(min(n - 1, ACF_LAGS))
    axes = fig.subplots(series.shape[1], 2, squeeze=False)
    band = 1.96 / math.sqrt(n)
    outside = []
    for j in range(series.shape[1]):
        ax = axes[j, 0]
        f, pe = welch_psd(series[:, j], fs)
        ax.semilogy(f[1:], pe[1:], linewidth=0.8)
        ax.set_ylabel("PSD [1/Hz]" if unit == "1" else f"PSD [{unit}\u00b2/Hz]")  # "1": dimensionless
        ax.set_title(titles[j], fontsize="small")
        ax.set_xlim(0, fs / 2)
        ax.grid(True, alpha=0.3, which="both")
        r = autocorrelation(series[:, j], max_lag)
        ax = axes[j, 1]
        lags = np.arange(max_lag + 1)
        ax.vlines(lags, 0, r, linewidth=1.0)
        ax.plot(lags, r, "o", markersize=2.5, color="C0")
        ax.axhline(band, color="C3", linestyle="--", linewidth=0.8, label="\u00b11.96/\u221aN")
        ax.axhline(-band, color="C3", linestyle="--", linewidth=0.8)
        ax.set_xlim(-0.5, max_lag + 0.5)
        ax.set_ylabel("autocorrelation [-]")
        ax.set_title(f"autocorrelation, lags 0..{max_lag}", fontsize="small")
        ax.legend(fontsize="small")
        ax.grid(True, alpha=0.3)
        outside.append(float(np.mean(np.abs(r[1:]) > band)))
    axes[-1, 0].set_xlabel("frequency [Hz]")
    axes[-1, 1].set_xlabel("lag [samples]")
    return band, outside, max_lag


def _residual_figure(result: Result, block: np.ndarray):
    """The regression's equation errors (forces in N, docs/stand-file.md) per node: their
    spectrum and the first ACF_LAGS lags of their autocorrelation."""
    from ._plot import _figure

    idx, e = residuals(result, block)
    fs = result.stand.sample_rate
    # Skip the pre-filter's start (its transient from rest): 4 time constants of a 4th-order
    # Butterworth at f_c are about 2 / f_c s; nothing to skip without a pre-filter.
    f_c = float(result.config["prefilter_hz"])
    skip = int(math.ceil(2.0 / f_c * fs)) if f_c > 0 else 0
    skip = min(skip, len(idx) // 4)
    idx, e = idx[skip:], e[skip:]
    fig = _figure(figsize=(8.0, 2.2 * e.shape[1] + 0.5), layout="constrained")
    nodes = _node_names(result.stand)
    titles = [f"equation error of {nodes[j] if j < len(nodes) else j} (force)" for j in range(e.shape[1])]
    band, outside, max_lag = _residual_panels(fig, e, fs, "N", titles)
    return fig, len(idx), band, outside, max_lag


def _innovation_figure(result: Result, block: np.ndarray):
    """For the state-space estimators: the filter's normalised innovations nu / sd per
    measured channel, their spectrum and the first ACF_LAGS lags of their autocorrelation."""
    from ._plot import _figure

    z, settled = innovations(result, block)
    if len(z) < 4 * ACF_LAGS:
        raise ValueError(f"only {len(z)} filter updates after the start tempering")
    fig = _figure(figsize=(8.0, 2.2 * z.shape[1] + 0.5), layout="constrained")
    band, outside, max_lag = _residual_panels(fig, z.to_numpy(), result.stand.sample_rate, "1",
                                              [f"{ch}: innovation / its predicted sd" for ch in z.columns])
    return fig, z, band, outside, max_lag


def innovations(result: Result, block: np.ndarray) -> tuple[pd.DataFrame, np.ndarray]:
    """The state-space estimator's one-step innovations over the capture (the filter of
    `result.config`, run again on `block`: vibid_ident_innovations after each sample), per
    measured channel the normalised innovation nu / sd (sd the filter's predicted standard
    deviation; about N(0, 1) and white when the model explains the data). Rows are the
    samples with an update after the filter's noise tempering (inflation 1); returns
    (DataFrame indexed by sample, one column per channel, the sample indices)."""
    code = {"ekf": _core.ESTIMATOR_EKF, "auto(ekf)": _core.ESTIMATOR_EKF,
            "kf_rls": _core.ESTIMATOR_KF_RLS}.get(result.method)
    if code is None:
        raise ValueError(f"the estimator {result.method} has no filter innovations")
    ident = _core.Ident(result.stand._core, code, float(result.config["forgetting"]), -1.0, 0)
    channels, nu, sd, inflation = ident.innovations(block, 0, block.shape[0])
    settled = np.flatnonzero(inflation == 1.0)
    names = [result.stand.channels[c] for c in channels]
    z = pd.DataFrame(nu[settled] / sd[settled], index=pd.Index(settled, name="sample"), columns=names)
    return z, settled


def frf_segment(n: int, nperseg: int = 4096) -> int:
    """Welch segment length of the FRF: at most nperseg, and a power of two of at most n/4, so
    that at least 7 segments (50 % overlap) are averaged: a coherence of one segment is 1 at
    every frequency, whatever the noise."""
    return int(max(16, min(nperseg, 1 << max(4, int(math.floor(math.log2(max(n, 64) / 4)))))))


def frf_h1(x: np.ndarray, y: np.ndarray, fs: float, nperseg: int = 4096):
    """H1 = Gyx Gxx^-1 per frequency of inputs x (n x i) to outputs y (n x o) by Welch's
    method (Hann window, 50 % overlap, mean removed per segment), and the coherence of each
    output with the inputs (the ordinary coherence |Gxy|^2 / (Gxx Gyy) for one input, the
    multiple coherence for several). Returns (f, H (nf x o x i), coherence (nf x o))."""
    x = np.asarray(x, float).reshape(len(x), -1)
    y = np.asarray(y, float).reshape(len(y), -1)
    nperseg = frf_segment(len(x), nperseg)
    step = max(1, nperseg // 2)
    w = np.hanning(nperseg)
    nf = nperseg // 2 + 1
    gxx = np.zeros((nf, x.shape[1], x.shape[1]), complex)
    gyx = np.zeros((nf, y.shape[1], x.shape[1]), complex)
    gyy = np.zeros((nf, y.shape[1]))
    for s0 in range(0, len(x) - nperseg + 1, step):
        X = np.fft.rfft((x[s0:s0 + nperseg] - x[s0:s0 + nperseg].mean(0)) * w[:, None], axis=0)
        Y = np.fft.rfft((y[s0:s0 + nperseg] - y[s0:s0 + nperseg].mean(0)) * w[:, None], axis=0)
        gxx += X[:, :, None] * np.conj(X[:, None, :])
        gyx += Y[:, :, None] * np.conj(X[:, None, :])
        gyy += np.abs(Y) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.linalg.pinv(gxx)
        h = gyx @ inv
        # multiple coherence: (Gyx Gxx^-1 Gxy) / Gyy per output
        num = np.einsum("foi,fij,foj->fo", gyx, inv, np.conj(gyx)).real
        coh = np.clip(num / gyy, 0.0, 1.0)
    return np.fft.rfftfreq(nperseg, 1.0 / fs), h, coh


def model_frf(result: Result, f: np.ndarray, ins: list[int], outs: list[int]) -> Optional[np.ndarray]:
    """The identified model's FRF from its matrices (``vibid_model_frf``: (C - w^2 M + j w D)^-1
    [B, c_base + j w d_base], held inputs with the sampled zero-order hold's factor) at the
    frequencies f, from the excitation channels ins to the response channels outs (channel
    indices): nf x len(outs) x len(ins). None for a stand with cubic springs (the matrices are
    its linearisation at rest, not the response at the capture's amplitude) or an excitation
    channel that is neither a force input nor the base displacement (a base velocity or
    acceleration channel)."""
    st = result.stand
    if st._core.nonlinear:
        return None
    roles = channel_roles(st)
    n_inputs = sum(1 for _, kind, _, _ in roles if kind == "input")
    exc = []
    for i in ins:
        _, kind, idx, name = roles[i]
        if kind == "input":
            exc.append(idx)
        elif idx == -2 and kind == "displacement":
            exc.append(n_inputs)
        else:
            return None
    th = result.parameters["value"].to_numpy(float)
    re, im = _core.stand_frf(st._core, list(th), list(np.asarray(f, float)), 1.0 / st.sample_rate)
    n_exc = len(re) // (len(f) * len(st.channels))
    h = (np.asarray(re) + 1j * np.asarray(im)).reshape(n_exc, len(st.channels), len(f))
    return np.transpose(h[np.ix_(exc, outs)], (2, 1, 0))


def _frf_figure(result: Result, block: np.ndarray, sim: np.ndarray, start: int):
    """Measured H1 (input channels -> each response channel) with its coherence, against
    the identified model's FRF: from its matrices (model_frf) for a linear stand; for a stand
    with cubic springs estimated the same way as the measured one from the model's simulation
    driven by the same measured inputs (noise-free, so its H1 is the model's response at the
    capture's amplitude wherever the inputs excite). Returns the figure, the frequencies, the
    measured and model FRFs, the coherence, the (input, output) channel pairs, and which
    model FRF it is ("matrices" or "simulation")."""
    from ._plot import _figure

    st = result.stand
    fs = st.sample_rate
    ins = [st.channels.index(ch) for ch in _excitation_channels(st)]
    outs = [i for i, (ch, kind, idx, _) in enumerate(channel_roles(st)) if kind != "input" and idx != -2]
    f, hm, coh = frf_h1(block[start:, ins], block[start:, outs], fs)
    hs = model_frf(result, f, ins, outs)
    source = "matrices"
    if hs is None:
        _, hs, _ = frf_h1(block[start:, ins], sim[start:, outs], fs)
        source = "simulation"
    pairs = [(o, i) for o in range(len(outs)) for i in range(len(ins))]
    fig = _figure(figsize=(8.0, 3.6 * len(pairs) + 0.5), layout="constrained")
    axes = fig.subplots(3 * len(pairs), 1, squeeze=False, sharex=True,
                        gridspec_kw={"height_ratios": [3, 2, 1.2] * len(pairs)})[:, 0]
    k = slice(1, None)
    for n, (o, i) in enumerate(pairs):
        oc, ic = st.channels[outs[o]], st.channels[ins[i]]
        unit = f"{channel_unit(st, oc)}/{channel_unit(st, ic)}"
        am, ap, ac = axes[3 * n], axes[3 * n + 1], axes[3 * n + 2]
        am.semilogy(f[k], np.abs(hm[k, o, i]), color="k", linewidth=1.0, label="measured H1")
        am.semilogy(f[k], np.abs(hs[k, o, i]), color="C1", linewidth=1.0, linestyle="--", label="identified model")
        am.set_ylabel(f"|H| [{unit}]")
        am.set_title(f"{ic} \u2192 {oc}", fontsize="small")
        am.legend(fontsize="small")
        ap.plot(f[k], np.degrees(np.angle(hm[k, o, i])), color="k", linewidth=0.8)
        ap.plot(f[k], np.degrees(np.angle(hs[k, o, i])), color="C1", linewidth=0.8, linestyle="--")
        ap.set_ylabel("phase [\u00b0]")
        ap.set_ylim(-180, 180)
        ap.set_yticks([-180, -90, 0, 90, 180])
        ac.plot(f[k], coh[k, o], color="C2", linewidth=0.8)
        ac.set_ylabel("coherence [-]")
        ac.set_ylim(0, 1.05)
        for ax in (am, ap, ac):
            ax.grid(True, alpha=0.3, which="both")
            for fm in result.modes["freq_hz"]:
                if math.isfinite(fm):
                    ax.axvline(fm, color="0.5", linestyle=":", linewidth=0.8)
    axes[-1].set_xlabel("frequency [Hz]")
    axes[-1].set_xlim(0, fs / 2)
    return fig, f, hm, hs, coh, [(st.channels[ins[i]], st.channels[outs[o]]) for o, i in pairs], source


def _node_names(stand: Stand) -> list[str]:
    names = {}
    for _, kind, idx, model_name in channel_roles(stand):
        if kind != "input" and idx >= 0:
            names[idx] = model_name.split(".")[0]
    return [names.get(i, f"node {i}") for i in range(stand.n_dof)]


def _spectrum_figure(result: Result, block: np.ndarray):
    from ._plot import _figure, welch_psd

    chans = _excitation_channels(result.stand)
    fig = _figure(figsize=(8.0, 3.2), layout="constrained")
    ax = fig.subplots()
    fs = result.stand.sample_rate
    for ch in chans:
        f, p = welch_psd(block[:, result.stand.channels.index(ch)], fs)
        ax.semilogy(f[1:], p[1:], linewidth=0.8, label=ch)
    for i, fm in result.modes["freq_hz"].items():
        if math.isfinite(fm):
            ax.axvline(fm, color="k", linestyle=":", linewidth=0.8)
            ax.text(fm, 1.0, f" {i}", transform=ax.get_xaxis_transform(), fontsize="small", va="top")
    ax.set_xlabel("frequency [Hz]")
    units = sorted({channel_unit(result.stand, ch) for ch in chans})
    ax.set_ylabel(f"PSD [{units[0]}\u00b2/Hz]" if len(units) == 1 else "PSD [(channel unit)\u00b2/Hz]")
    ax.set_xlim(0, fs / 2)
    ax.grid(True, alpha=0.3, which="both")
    ax.legend(fontsize="small")
    return fig, chans


def _last_periods(result: Result, first: int, stop: int) -> np.ndarray:
    """Sample indices of a window of five periods of the lowest identified mode (at least
    0.2 s) at the end of [first, stop): the whole capture would be a solid band at this scale."""
    fs = result.stand.sample_rate
    fmin = min([f for f in result.modes["freq_hz"] if math.isfinite(f) and f > 0] or [fs / 100])
    w = int(min(stop - first, max(0.2 * fs, 5 * fs / fmin)))
    return np.arange(stop - w, stop)


def _overlay_figure(result: Result, k: np.ndarray, rows, label: str):
    """One axis per (channel, measured, model) of rows, both over the samples k."""
    from ._plot import _figure

    t = k / result.stand.sample_rate
    fig = _figure(figsize=(8.0, 2.0 * len(rows) + 0.5), layout="constrained")
    axes = fig.subplots(len(rows), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (ch, measured, model) in zip(axes, rows):
        ax.plot(t, measured, color="k", linewidth=1.0, label="measured")
        ax.plot(t, model, color="C1", linewidth=1.0, linestyle="--", label=label)
        ax.set_ylabel(f"{ch} [{channel_unit(result.stand, ch)}]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small", loc="upper right")
    axes[-1].set_xlabel("time [s]")
    return fig


def _response_figure(result: Result, block: np.ndarray, sim: np.ndarray, start: int):
    k = _last_periods(result, start, block.shape[0])
    rows = [(ch, block[k, i], sim[k, i]) for i, (ch, kind, idx, _) in enumerate(channel_roles(result.stand))
            if kind != "input" and idx != -2]
    return _overlay_figure(result, k, rows, "model (identified)")


def _holdout_figure(result: Result, block: np.ndarray):
    """Measured against simulated response channels on the held-out part (the adequacy's
    fitted simulation), over its last five periods of the lowest mode (at least 0.2 s)."""
    start, stop = result.adequacy["segment"]
    sim = result.adequacy["simulated"]
    k = _last_periods(result, start, stop)
    rows = [(ch, block[k, result.stand.channels.index(ch)], sim[ch].to_numpy()[k - start]) for ch in sim.columns]
    return _overlay_figure(result, k, rows, "simulated (estimate of the first part)")


def _residual_spectrum_figure(result: Result, block: np.ndarray):
    """Welch PSD of the held-out simulation residuals per response channel, beside the
    measured channel's, the identified natural frequencies dotted."""
    from ._plot import _figure, welch_psd

    a = result.adequacy
    start, stop = a["segment"]
    sim = a["simulated"]
    fs = result.stand.sample_rate
    fig = _figure(figsize=(8.0, 2.2 * sim.shape[1] + 0.5), layout="constrained")
    axes = fig.subplots(sim.shape[1], 1, sharex=True, squeeze=False)[:, 0]
    for ax, ch in zip(axes, sim.columns):
        z = block[start:stop, result.stand.channels.index(ch)]
        f, pz = welch_psd(z, fs)
        _, pe = welch_psd(z - sim[ch].to_numpy(), fs)
        ax.semilogy(f[1:], pz[1:], color="0.5", linewidth=0.8, label=f"{ch} measured")
        ax.semilogy(f[1:], pe[1:], color="C3", linewidth=0.8, label="residual (measured - simulated)")
        for fm in result.modes["freq_hz"]:
            if math.isfinite(fm):
                ax.axvline(fm, color="k", linestyle=":", linewidth=0.8)
        ax.set_ylabel(f"PSD [{channel_unit(result.stand, ch)}\u00b2/Hz]")
        ax.grid(True, alpha=0.3, which="both")
        ax.legend(fontsize="small")
    axes[-1].set_xlabel("frequency [Hz]")
    axes[-1].set_xlim(0, fs / 2)
    return fig


def write_report(result: Result, block: np.ndarray, capture: str, path: str) -> None:
    """A self-contained HTML report: every figure a data: URI PNG, no external file, script,
    style sheet or network access. A section that cannot be drawn for this stand or
    estimator (e.g. no residuals of a state-space estimate) says why instead."""
    from ._plot import figure_png_data_uri

    esc = html.escape
    sec = []

    def figure(fig, alt):
        uri = figure_png_data_uri(fig)
        return f'<img alt="{esc(alt)}" src="{uri}">'

    def section(id_, title, body):
        sec.append(f'<section id="{id_}"><h2>{esc(title)}</h2>\n{body}\n</section>')

    memo = {}

    def response():  # the model's simulation, once for the residual, response and FRF sections
        if "sim" not in memo:
            memo["sim"] = model_response(result, block)
        return memo["sim"]

    st = result.stand
    trusted, why = verdict(result)
    section("parameters", "Parameters",
            "<p>Values to the decimal place of the second significant digit of their standard error; columns "
            "without information (no true value given by the stand) left out.</p>"
            + _html_table(result.parameters, {"value": "se"})
            + ("<p>Sensor offsets of the output-error estimate (measured = true + offset):</p>"
               + _html_table(result.offsets, {"value": "se"}) if len(result.offsets) else ""))
    section("modes", "Modes", _html_table(result.modes, {"freq_hz": "freq_hz_se", "zeta": "zeta_se"}))
    warns = warnings_of(result)
    body = ("<ul>" + "".join(f"<li>{esc(w)}</li>" for w in warns) + "</ul>") if warns else \
        "<p>No flag and no warning: the estimate is plausible and its standard errors hold.</p>"
    c = flag_counts(result)
    rows = "".join(f"<tr><th>{k}</th><td>{'yes' if c[k]['estimate'] else '-'}</td><td>{c[k]['parameters']}</td>"
                   f"<td>{c[k]['modes']}</td><td>{c[k]['tracks']} of {c['rows']}</td>"
                   f"<td>{esc(flag_meaning(k, result.method))}</td></tr>" for k in "EPUIRM" if any(c[k].values()))
    if rows:
        body = ('<table class="t" id="flag-counts"><tr><th>flag</th><th>estimate</th><th>parameters</th><th>modes</th>'
                f'<th>track rows</th><th>meaning ({esc(result.method)})</th></tr>{rows}</table>') + body
    section("flags", f"Flags and warnings: {flag_summary(result)}", body)
    section("estimator", "Estimator", f"<p>{esc(config_line(result))}</p><details><summary>what the estimator "
            f"chose and why</summary><pre>{esc(result.description)}</pre></details>")
    if len(result.tracks):
        fig = result.plot()
        clipped = [ax.get_ylabel().split(" [")[0] for ax in fig.axes
                   if any(t.get_gid() and t.get_gid().startswith("clipped:") for t in ax.texts)]
        note = (f"<p>The y axes of {esc(', '.join(clipped))} are scaled to the converged estimate: the range of "
                "value &plusmn; 2 se over the second half of the rows (and the true value where the stand gives "
                "one); the start transient before it runs off the axis. The other axes show the whole track.</p>"
                if clipped else "<p>Each axis shows the whole track (no start transient beyond the final band).</p>")
        section("tracks", "Tracks (value \u00b1 2 se)", note + figure(fig, "parameter tracks"))
    else:
        section("tracks", "Tracks (value \u00b1 2 se)",
                "<p>No tracks (--track-every 0): the final estimate with its 2-se error bar per parameter.</p>"
                + figure(result.plot(), "parameters with 2-se error bars"))
    state_space = result.method in ("ekf", "kf_rls", "auto(ekf)")
    try:
        if state_space:
            fig, z, band, outside, max_lag = _innovation_figure(result, block)
            n, names = len(z), list(z.columns)
            ms = (z ** 2).mean()
            within = (z.abs() <= 1.96).mean()
            what = (f"<p>The state-space estimator {esc(result.method)} fits no regression: its check is the "
                    f"filter's one-step innovations nu (measured - predicted) of each measured channel, divided by "
                    f"their predicted standard deviation sd (the filter's innovation covariance, sensor noise "
                    f"included; the filter run again over the capture, vibid_ident_innovations), from sample "
                    f"{int(z.index[0])} on, after the start window and the start's noise tempering, N = {n}. A "
                    f"model that explains the data gives nu/sd about standard normal (mean square 1, 95 % within "
                    f"&plusmn;1.96) and white. The filter's velocity allowance and a measured base's sensor "
                    f"noise colour them a little by design (lag 1 about -0.1 on a consistent simulated stand); "
                    f"a mean square well above 2, a spectral peak at a mode, or correlation over many lags "
                    f"mean a model error. Their Welch spectrum [1/Hz] and the autocorrelation of lags "
                    f"0..{max_lag} with &plusmn;1.96/&radic;N = {band:.3g}:</p>"
                    + "<ul>" + "".join(f"<li>{esc(ch)}: mean square {ms[ch]:.3g}, {100 * within[ch]:.1f} % within "
                                       f"&plusmn;1.96</li>" for ch in names) + "</ul>")
        else:
            fig, n, band, outside, max_lag = _residual_figure(result, block)
            names = _node_names(st)
            what = (f"<p>Equation errors y - x<sup>T</sup>&theta; of the regression at the estimate (forces in N; the "
                    f"estimator's differences and pre-filter), N = {n}: their Welch spectrum and the autocorrelation "
                    f"of lags 0..{max_lag}; white residuals stay within &plusmn;1.96/&radic;N = {band:.3g} at 95 % of "
                    f"the lags. Differences and the pre-filter colour them by design (which is why auto's error bars "
                    f"come from block statistics), so lags outside the band are no fault by themselves; peaks in "
                    f"the spectrum at the modes are.</p>")
        lines = "".join(f"<li>{esc(node)}: {100 * o:.1f} % of the lags 1..{max_lag} outside "
                        "the band</li>" for node, o in zip(names, outside))
        section("residuals", "Residuals of the fit" if not state_space else "Innovations of the filter",
                what + f"<ul>{lines}</ul>" + figure(fig, "residual spectra and autocorrelations"))
    except (_core.VibidError, ValueError) as e:
        section("residuals", "Residuals of the fit", f"<p>Not available for this stand or estimator: {esc(str(e))}</p>")
    chans = _excitation_channels(st)
    if chans:
        fig, chans = _spectrum_figure(result, block)
        section("excitation", "Excitation spectrum",
                f"<p>Welch PSD (Hann, 4096-sample segments, 50 % overlap) of the input channels "
                f"{esc(', '.join(chans))}; the identified natural frequencies dotted and numbered. A mode outside the "
                f"excited band is determined by little.</p>" + figure(fig, "excitation spectrum"))
    else:
        section("excitation", "Excitation spectrum", "<p>The stand has no measured input channel.</p>")
    try:
        sim, start = response()
        fit = response_fit(result, block, sim, start)
        section("response", "Measured against model response",
                f"<p>The identified model driven by the measured inputs (RK4 over the library's equations of "
                f"motion, from the measured state at sample 2). Errors from sample {start} "
                f"({start / st.sample_rate:.3g} s: five time constants of the slowest mode, at most half the "
                f"capture) on; NRMSE = RMS(measured - model) / RMS(measured).</p>" + _html_table(fit)
                + figure(_response_figure(result, block, sim, start), "measured against model response"))
    except (_core.VibidError, ValueError) as e:
        section("response", "Measured against model response", f"<p>Not available: {esc(str(e))}</p>")
    try:
        if not chans:
            raise ValueError("the stand has no measured input channel")
        sim, start = response()
        fig, f, hm, hs, coh, pairs, source = _frf_figure(result, block, sim, start)
        model_text = (
            "FRF from its matrices, (C - &omega;<sup>2</sup> M + j&omega; D)<sup>-1</sup> times the inputs' "
            "coefficients (held inputs with the sampled zero-order hold's factor)" if source == "matrices" else
            "response at the capture's amplitude (the stand has cubic springs: its matrices are only the "
            "linearisation at rest), estimated the same way from the model's noise-free simulation driven by the "
            "same measured inputs")
        section("frf", "Frequency response and coherence",
                f"<p>Measured H<sub>1</sub> = G<sub>yx</sub> G<sub>xx</sub><sup>-1</sup> (Welch, Hann, "
                f"{frf_segment(block.shape[0] - start)}-sample segments, 50 % overlap, samples {start} on) from the "
                f"input channels {esc(', '.join(_excitation_channels(st)))} to each response channel, with its "
                f"coherence (multiple coherence where there are several inputs), against the identified model's "
                f"{model_text} (both in the measured quantities' units: output channel unit per input channel "
                f"unit; a force input's unit is N where its gain is 1). The identified natural frequencies "
                f"dotted. Where the coherence is low the measured H<sub>1</sub> is noise, not a fault of the "
                f"model.</p>" + figure(fig, "frequency response functions"))
    except (_core.VibidError, ValueError) as e:
        section("frf", "Frequency response and coherence", f"<p>Not available: {esc(str(e))}</p>")
    a = result.adequacy
    if a.get("unavailable"):
        section("holdout", "Held-out part: measured against simulated", f"<p>Not available: {esc(a['unavailable'])}</p>")
    else:
        start, stop = a["segment"]
        section("holdout", "Held-out part: measured against simulated",
                f"<p>The estimate from samples 0..{start - 1} simulated on the held-out samples {start}..{stop - 1} "
                f"(the library's output-error simulator, its initial state and one offset per channel fitted with "
                f"the parameters fixed; docs/python.md \"Model adequacy\"). {esc(adequacy_line(result))}.</p>"
                + _html_table(a["channels"]) + figure(_holdout_figure(result, block), "held-out measured and simulated"))
        section("residual-spectrum", "Residual spectrum (held-out part)",
                "<p>Welch PSD (Hann, 4096-sample segments, 50 % overlap) of the held-out simulation residuals beside "
                "the measured channels'; the identified natural frequencies dotted. Residuals of a model that explains "
                "the data are flat (white sensor noise); peaks at or between the modes are dynamics the model does not "
                "have.</p>" + figure(_residual_spectrum_figure(result, block), "residual spectrum"))
    head = (f"<h1>vibid identify: {esc(st.name)}</h1><p>stand <code>{esc(st.source)}</code>, capture "
            f"<code>{esc(capture)}</code>, {result.n_samples} samples at {st.sample_rate:g} Hz "
            f"({result.n_samples / st.sample_rate:.6g} s), method {esc(result.method)}, flags "
            f"<b>{esc(result.flags or '-')}</b>; vibid {esc(_core.version())}, "
            f"{datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M:%S UTC')}</p>"
            + f'<p id="verdict" class="{"ok" if trusted else "bad"}"><b>Verdict: {esc(why)}</b></p>')
    write_html(path, f"vibid: {st.name}", head, sec)


# The reports' one style sheet (identify's and oma's).
REPORT_STYLE = ("body{font-family:sans-serif;max-width:60em;margin:1em auto;padding:0 1em}"
                "table.t{border-collapse:collapse}table.t td,table.t th{padding:2px 8px;border-bottom:1px solid #ccc;"
                "text-align:right}img{max-width:100%}p.ok{background:#e6f4e6;padding:.4em}"
                "#flag-counts td:last-child{text-align:left}p.bad{background:#fbe4e4;padding:.4em}"
                "pre{background:#f4f4f4;padding:.5em;white-space:pre-wrap}")


def write_html(path: str, title: str, head: str, sections: Sequence[str]) -> None:
    """A self-contained report page: the title (escaped here), the head and the sections (HTML)."""
    doc = (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
           f"<style>{REPORT_STYLE}</style></head><body>\n{head}\n" + "\n".join(sections) + "\n</body></html>\n")
    with open(path, "w", encoding="utf-8") as f:
        f.write(doc)


# ---- commands ----

def _load_stand(path: str) -> Stand:
    if not os.path.exists(path):
        raise CliError(f"stand file {path!r}: no such file")
    return Stand.load(path)


def _check_capture_and_report(a: argparse.Namespace) -> None:
    """Before any work: the capture exists, and matplotlib is there when a report is asked for."""
    if not os.path.exists(a.capture):
        raise CliError(f"capture {a.capture!r}: no such file")
    if a.report:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise CliError("--report needs matplotlib: pip install 'vibid[plot]'") from None


def cmd_identify(a: argparse.Namespace) -> int:
    stand = _load_stand(a.stand)
    _check_capture_and_report(a)
    block, t = _columns(stand, a.capture)
    data = {ch: block[:, i] for i, ch in enumerate(stand.channels)}
    if t is not None:
        data["time_s"] = t
    track_every = a.track_every
    if track_every is None and (a.tracks or a.report):
        # Tracks asked for: a row every 0.1 s, also for the batch estimators (as vibidd
        # with decimation = f_a / 10), so that the report shows how the estimate settled.
        track_every = max(1, int(round(stand.sample_rate / 10)))
    result = identify(stand, data, method=a.method, forgetting=a.forgetting, prefilter_hz=a.prefilter_hz,
                      iv_lag=a.iv_lag, track_every=track_every, holdout=a.holdout)
    out = [f"stand {stand.name} ({stand.source}), capture {a.capture}: {result.n_samples} samples at "
           f"{stand.sample_rate:g} Hz, method {result.method}, flags {result.flags or '-'}", "",
           parameter_table(result), ""]
    if len(result.offsets):
        out += [offset_table(result), ""]
    out += [mode_table(result), "", adequacy_line(result), ""]
    warns = warnings_of(result)
    out += ["warnings:"] + [f"  {w}" for w in warns] if warns else ["warnings: none"]
    out += ["", config_line(result), "estimator:"] + [f"  {line}" for line in result.description.splitlines()]
    print("\n".join(out), flush=True)
    try:
        if a.tracks:
            write_tracks(result, a.tracks)
            print(f"tracks: {len(result.tracks)} rows written to {a.tracks}")
        if a.report:
            write_report(result, block, a.capture, a.report)
            print(f"report: {a.report}")
    except OSError as e:
        raise RunFailure(f"cannot write the output: {e}") from None
    return 0


def cmd_check(a: argparse.Namespace) -> int:
    stand = _load_stand(a.stand)
    print(f"stand {stand.name} ({stand.source}): {stand.n_dof} degree{'s' if stand.n_dof != 1 else ''} of "
          f"freedom, {stand.sample_rate:g} Hz")
    print("\nchannels:")
    print(_table(["channel", "quantity", "model"],
                 [[ch, kind, name] for ch, kind, _, name in channel_roles(stand)]))
    print("\nunknowns:")
    print(_table(["parameter", "kind", "unit", "nominal", "true_value"],
                 [[n, k, u, _fmt(v), _fmt(tv)] for n, k, u, v, tv in
                  zip(stand.parameters, stand.kinds, stand.units, stand.nominal_values, stand.true_values)]))
    # The regression's structural check (model.h), then what identify itself does: create
    # the automatic estimator, which also covers the state-space estimators' own check.
    status, msg, known, controllable, rank = _core.stand_identifiability(stand._core)
    mats = [m for bit, m in ((1, "M"), (2, "D"), (4, "C"), (8, "B")) if known & bit]
    print("\nidentifiability:")
    if status == 0:
        print(f"  regression: identifiable (generic rank {rank} of {len(stand.parameters)}, "
              f"{'controllable' if controllable else 'not controllable'} from the inputs, known and regular: "
              f"{', '.join(mats) or 'none'})")
    else:
        print(f"  regression: {msg}")
    try:
        ident = _core.Ident(stand._core, METHODS["auto"], 1.0, -1.0, 0)
    except _core.VibidError as e:
        print(f"  automatic estimator: refused: {e}")
        print(f"{PROG} check: {stand.source}: cannot be identified: {e}", file=sys.stderr)
        return EXIT_RUN_FAILURE
    first = ident.describe().splitlines()
    print(f"  automatic estimator: accepted: {first[0] if first else ''}")
    print("identifiable")
    return 0


# vibidd recognises its own raw recordings by this first line (daemon/src/writers.h,
# VD_RECORDING_MAGIC) and then reads the columns by the stand's channel names, time in t.
RECORDING_MAGIC = "# vibidd raw recording"


def _output_format(a: argparse.Namespace) -> str:
    """csv or candump: --to, else OUT's extension by the capture-format registry (.log:
    candump), else csv."""
    from ._captures import _FORMATS, FORMATS

    titles = {n: t for n, _, _, t, _, _ in FORMATS}
    if a.to is not None:
        fmt = _FORMATS.get(a.to.lower())
        if fmt is None:
            raise CliError(f"--to {a.to!r}: one of csv, candump")
    else:
        ext = os.path.splitext(a.out)[1].lower()
        fmt = next((n for n, _, exts, *_ in FORMATS if ext and ext in exts.split()), "csv")
    if fmt not in ("csv", "candump"):
        raise CliError(f"{a.out}: vibid convert writes csv or candump, not {titles.get(fmt, fmt)} "
                       f"({'--to ' + a.to if a.to else 'by its extension'}); give --to csv or --to candump")
    return fmt


def _write_csv(a: argparse.Namespace, stand: Stand, df: pd.DataFrame, fmt: str) -> None:
    block = df[list(stand.channels)]
    t = df["time_s"].to_numpy() if "time_s" in df else np.arange(len(df)) / stand.sample_rate
    # A candump log's missing samples are NaN rows: left out, never written as numbers, so
    # that vibidd's replay sees the gap in the time column (and counts it) as in the log.
    keep = ~block.isna().any(axis=1).to_numpy()
    out = pd.DataFrame({"t": t[keep], **{c: block[c].to_numpy()[keep] for c in stand.channels}})
    try:
        with open(a.out, "w", encoding="utf-8", newline="") as f:
            f.write(f"{RECORDING_MAGIC} of stand '{stand.name}' at {stand.sample_rate!r} Hz; converted by "
                    f"vibid convert from {os.path.basename(a.capture)} ({fmt}); replay: vibidd -c CONFIG "
                    "--replay FILE\n")
            # float_format None: each value's shortest round-trip text (repr), so the doubles
            # read back bit for bit
            out.to_csv(f, index=False, lineterminator="\n")
    except OSError as e:
        raise RunFailure(f"cannot write {a.out}: {e}") from None
    dropped = int((~keep).sum())
    print(f"{a.out}: {int(keep.sum())} samples of {len(stand.channels)} channels ({', '.join(stand.channels)}) "
          f"in {stand.name}'s units, time column t"
          + (f"; {dropped} missing samples left out (gaps in t)" if dropped else ""))


def _write_candump(a: argparse.Namespace, stand: Stand, df: pd.DataFrame, fmt: str) -> None:
    from ._captures import location
    from ._drivers import _describe, write_candump

    dbc = a.out_dbc or a.dbc
    cmap = a.out_channel_map or (a.channel_map if not a.out_dbc else None)
    if dbc is None:
        raise CliError(f"{a.out}: a candump log is written with a DBC: give --dbc FILE.dbc (and --channel-map MAP "
                       "where the DBC's signals are not named as the stand's channels)")
    for path, what in ((dbc, "DBC file"), (cmap, "channel-map file")):
        if path is not None and not os.path.isfile(path):
            raise CliError(f"{what} {path!r}: no such file")
    t = df["time_s"].to_numpy() if "time_s" in df else np.arange(len(df)) / stand.sample_rate
    where = lambda row: location(a.capture, fmt, row)  # noqa: E731
    try:
        res = write_candump(a.out, stand, df[list(stand.channels)].to_numpy(), t, dbc=dbc, channel_map=cmap,
                            iface=a.interface, start_time_ns=int(df.attrs.get("start_time_ns", 0)), where=where)
    except OSError as e:
        raise RunFailure(f"cannot write {a.out}: {e}") from None
    plan = res["plan"]
    print(f"{a.out}: {res['samples']} samples of {len(stand.channels)} channels ({', '.join(stand.channels)}) as "
          f"{res['frames']} frames of {plan['messages']} message{'s' if plan['messages'] != 1 else ''} of "
          f"{os.path.basename(dbc)} on {a.interface}, {res['counter_note']}"
          + (f"; {res['missing']} missing samples left out (counter jumps: the log's gaps)" if res["missing"] else ""))
    for c, ch, n, err in zip(stand.channels, plan["channels"], res["rounded"], res["max_error"]):
        step = (f"to float32" if ch["type"] == "float32" else "to float64" if ch["type"] == "float64"
                else f"to the step {abs(ch['factor']):g} {ch['unit'] or ''}".rstrip())
        print(f"  {c}: {_describe(ch)}: {n} of {res['samples']} values rounded {step}"
              + (f" (at most {err:.3g} in {stand.name}'s units)" if n else "") + "; none saturated")


def cmd_convert(a: argparse.Namespace) -> int:
    from ._captures import read_capture

    stand = _load_stand(a.stand)
    if not os.path.exists(a.capture):
        raise CliError(f"capture {a.capture!r}: no such file")
    if os.path.exists(a.out) and os.path.samefile(a.capture, a.out):
        raise CliError(f"{a.out!r} is the capture itself: give another output file")
    to = _output_format(a)
    # --dbc and --channel-map are the capture's when it is a candump log (named so, or by
    # its content; with a DBC, a file neither places), else the output's alone.
    if a.format is not None:
        in_candump = a.format.lower() == "candump"
    else:
        known = _core.capture_format_of_file(a.capture)
        in_candump = known == "candump" or (not known and a.dbc is not None)
    read_dbc = (a.dbc, a.channel_map) if in_candump or to != "candump" else (None, None)
    df = read_capture(a.capture, stand, format=a.format, group=a.group, dbc=read_dbc[0], channel_map=read_dbc[1])
    fmt = df.attrs["source"]["format"]  # as read_capture resolved it
    if to == "candump":
        _write_candump(a, stand, df, fmt)
    else:
        if a.out_dbc or a.out_channel_map:
            raise CliError("--out-dbc and --out-channel-map are for a candump output (--to candump, or OUT.log)")
        _write_csv(a, stand, df, fmt)
    return 0


# vibid-sim as the package's build installs it (python/CMakeLists.txt) where SUNDIALS is there
PACKAGED_SIM = os.path.join(os.path.dirname(os.path.abspath(__file__)), "bin", "vibid-sim")


def _vibid_sim() -> str:
    """VIBID_SIM, else the package's own vibid-sim, else the one on PATH."""
    p = os.environ.get("VIBID_SIM")
    if p:
        if not (os.path.isfile(p) and os.access(p, os.X_OK)):
            raise CliError(f"VIBID_SIM={p!r} is not an executable file")
        return p
    if os.access(PACKAGED_SIM, os.X_OK):
        return PACKAGED_SIM
    p = shutil.which("vibid-sim")
    if not p:
        raise CliError("vibid-sim not found: the package was built without it (it needs SUNDIALS: apt install "
                       "libsundials-dev, then reinstall), none is on PATH and VIBID_SIM is not set (the C tree "
                       "builds it: <build>/sim/vibid-sim)")
    return p


def mode_table_oma(r) -> str:
    """The selected modes of an OmaResult as text, values to their se's digits."""
    lines = [f"{'mode':>4}  {'f [Hz]':>22}  {'zeta [-]':>24}  {'mpc':>5}  {'order':>5}  {'poles':>5}"]
    for k, m in r.modes.iterrows():
        f, fse = fmt_with_se(float(m.freq_hz), float(m.freq_hz_se))
        z, zse = fmt_with_se(float(m.zeta), float(m.zeta_se))
        lines.append(f"{k:>4}  {f + ' +- ' + fse:>22}  {z + ' +- ' + zse:>24}  {m.mpc:5.3f}  {int(m.order):>5}  "
                     f"{int(m.n_poles):>5}")
    return "\n".join(lines)


def cmd_oma(a: argparse.Namespace) -> int:
    from ._oma import oma

    _check_capture_and_report(a)
    split = (lambda v: [x.strip() for x in v.split(",") if x.strip()] if v else None)  # noqa: E731
    r = oma(a.capture, a.sample_rate, channels=split(a.channels), refs=split(a.refs), max_order=a.max_order,
            block_rows=a.block_rows, blocks=a.blocks, format=a.format, group=a.group)
    c = r.config
    print(f"capture {a.capture}: {r.n_samples} samples of {len(r.channels)} channels ({', '.join(r.channels)}) at "
          f"{r.sample_rate:g} Hz, {r.n_gaps} gaps; SSI-cov: references {', '.join(r.refs)}, block rows "
          f"{c['block_rows']}, orders 2..{c['max_order']}, {c['blocks']} blocks of {c['block_samples']} samples\n",
          flush=True)
    print(mode_table_oma(r) if len(r.modes) else "no mode selected: no cluster of stable poles holds "
          f"{100 * c['min_cluster_share']:g} % of the orders (see the stabilisation diagram: --report)", flush=True)
    try:
        if a.modes:
            r.modes.to_csv(a.modes)
            print(f"modes: written to {a.modes}")
        if a.report:
            r.report(a.report, capture=a.capture)
            print(f"report: {a.report}")
    except OSError as e:
        raise RunFailure(f"cannot write the output: {e}") from None
    return 0


def cmd_simulate(a: argparse.Namespace) -> int:
    if not os.path.exists(a.stand):
        raise CliError(f"stand file {a.stand!r}: no such file")
    cmd = [_vibid_sim(), "-c", a.stand, "--csv", a.out, "--fast"]
    if a.sim:
        cmd += ["-s", a.sim]
    if a.duration is not None:
        cmd += ["-d", repr(a.duration)]
    if a.seed is not None:
        cmd += ["--seed", str(a.seed)]
    # vibid-sim's own exit status (0, 1 run-time failure, 2 bad input) and messages.
    return subprocess.run(cmd).returncode


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog=PROG, description="Identification of mechanical vibration systems "
                                 "(masses, damping, stiffness) by least squares: docs/python.md.",
                                 epilog="Exit status: 0 success, 1 a failure while running (an output that "
                                 "cannot be written; check: the stand cannot be identified), 2 a bad command "
                                 "line, input or configuration.")
    ap.add_argument("--version", action="version", version=f"{PROG} {_core.version()}")
    sub = ap.add_subparsers(dest="command", required=True, metavar="{identify,oma,convert,check,simulate}")
    p = sub.add_parser("identify", help="identify a stand's unknowns from a capture",
                       description="Prints the parameters and modes with standard errors and flags; "
                       "optionally writes the tracks and an HTML report.")
    p.add_argument("stand", metavar="STAND", help="stand file (docs/stand-file.md)")
    p.add_argument("capture", metavar="CAPTURE", help="capture file (CSV with a header of channel names; "
                   "MDF4/TDMS where the extras are installed)")
    p.add_argument("--method", choices=list(METHODS), default="auto", help="estimator (default auto)")
    p.add_argument("--forgetting", type=float, metavar="G", help="forgetting factor in (0, 1]")
    p.add_argument("--prefilter-hz", type=float, metavar="F", help="pre-filter cutoff in Hz, 0 = off")
    p.add_argument("--iv-lag", type=int, metavar="L", help="instrument delay in samples")
    p.add_argument("--holdout", type=float, metavar="H", default=HOLDOUT,
                   help=f"held-out fraction at the capture's end for auto's choice and the adequacy figures "
                   f"(default {HOLDOUT:g}; 0: none, auto is the library's automatic estimator alone)")
    p.add_argument("--track-every", type=int, metavar="N", help="a track row every N samples (default with "
                   "--tracks/--report: 0.1 s of samples; else identify's default)")
    p.add_argument("--tracks", metavar="OUT.csv", help="write the tracks here (overwritten)")
    p.add_argument("--report", metavar="OUT.html", help="write a self-contained HTML report here (needs matplotlib)")
    p.set_defaults(func=cmd_identify)
    p = sub.add_parser("oma", help="output-only modal analysis of response channels (no stand, no input)",
                       description="Covariance-driven SSI (vibid.oma, docs/python.md): prints the selected modes "
                       "with standard errors; optionally writes them as CSV and an HTML report with the "
                       "stabilisation diagram.")
    p.add_argument("capture", metavar="CAPTURE", help="CSV (header of channel names; a time_s or t column gives the "
                   "rate), MDF4 or TDMS capture")
    p.add_argument("--sample-rate", type=float, metavar="HZ", help="sample rate (default: from the capture's time)")
    p.add_argument("--channels", metavar="A,B,...", help="response channels (default: every numeric column but "
                   "the time)")
    p.add_argument("--refs", metavar="A,B,...", help="reference channels (default: all)")
    p.add_argument("--max-order", type=int, metavar="N", help="largest model order (even)")
    p.add_argument("--block-rows", type=int, metavar="I", help="block rows of the Hankel matrix (lags 1..2I-1)")
    p.add_argument("--blocks", type=int, default=32, metavar="B", help="blocks for the standard errors (default 32)")
    p.add_argument("--format", help="the capture's format when its name does not tell (csv, mdf, tdms)")
    p.add_argument("--group", help="TDMS group or MDF4 data group")
    p.add_argument("--modes", metavar="OUT.csv", help="write the modes here (overwritten)")
    p.add_argument("--report", metavar="OUT.html", help="write a self-contained HTML report here (needs matplotlib)")
    p.set_defaults(func=cmd_oma)
    p = sub.add_parser("convert", help="write any capture the package reads as CSV that vibidd replays, or as "
                       "a candump log", description="Reads CAPTURE (CSV, candump with --dbc, MDF4, TDMS: the drivers' "
                       "format registry) as identify does (the stand's channels, in its units) and writes OUT: as CSV "
                       "(default), vibid's raw-recording layout (a '# vibidd raw recording' line, then t and the "
                       "stand's channels by name, every value in its shortest round-trip form), which `vibidd "
                       "--replay OUT.csv` reads without a channel map; as a candump -l log (--to candump, or OUT.log), "
                       "each sample encoded into the frames of the DBC (--dbc, signals named as the stand's "
                       "channels, or --channel-map) by the drivers' encoder, as vibidd's candump recording writes "
                       "them. Missing samples are left out (a candump log's counter skips them). Values are never "
                       "saturated: one that does not fit its signal is refused (exit 2); rounded values are counted.")
    p.add_argument("stand", metavar="STAND")
    p.add_argument("capture", metavar="CAPTURE")
    p.add_argument("out", metavar="OUT")
    p.add_argument("--to", metavar="FORMAT", help="the output's format: csv or candump (default: by OUT's "
                   "extension, .log candump; else csv)")
    p.add_argument("--format", help="the capture's format when neither its content nor its name tells "
                   "(csv, candump, mdf, tdms)")
    p.add_argument("--group", help="TDMS group or MDF4 data group")
    p.add_argument("--dbc", help="DBC of a candump capture, and of a candump output (unless --out-dbc)")
    p.add_argument("--channel-map", dest="channel_map", help="channel map of a candump capture, and of a candump "
                   "output (unless --out-dbc or --out-channel-map)")
    p.add_argument("--out-dbc", dest="out_dbc", metavar="DBC", help="DBC of the candump output when it is not "
                   "the capture's")
    p.add_argument("--out-channel-map", dest="out_channel_map", metavar="MAP", help="channel map of the candump "
                   "output when it is not the capture's")
    p.add_argument("--interface", default="can0", metavar="NAME", help="CAN interface named in a candump "
                   "output's lines (default can0)")
    p.set_defaults(func=cmd_convert)
    p = sub.add_parser("check", help="channels, unknowns and identifiability of a stand",
                       description="Exit status 0 when the stand can be identified, 1 when not (the reason on "
                       "stdout and stderr).")
    p.add_argument("stand", metavar="STAND")
    p.set_defaults(func=cmd_check)
    p = sub.add_parser("simulate", help="write a simulated CSV capture with vibid-sim",
                       description="Runs vibid-sim (VIBID_SIM, else PATH) on the stand: vibid-sim -c STAND "
                       "--csv OUT --fast [-s SIM] [-d S] [--seed N] (docs/sim.md).")
    p.add_argument("stand", metavar="STAND")
    p.add_argument("out", metavar="OUT.csv")
    p.add_argument("--sim", metavar="SIM.cfg", help="file with the simulation group")
    p.add_argument("--duration", type=float, metavar="S", help="simulated seconds")
    p.add_argument("--seed", type=int, metavar="N")
    p.set_defaults(func=cmd_simulate)
    return ap


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = _parser()
    a = ap.parse_args(argv)  # exits 2 on a usage error, with the usage on stderr
    try:
        return a.func(a)
    except BrokenPipeError:
        # The reader went away (`vibid identify ... | head`): stop quietly, as a C tool
        # killed by SIGPIPE does (status 128 + 13), and keep the interpreter's final flush
        # of stdout from raising again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except CliError as e:
        print(f"{PROG} {a.command}: error: {e}", file=sys.stderr)
        return e.status
    except (_core.VibidError, ValueError, OSError, ImportError) as e:
        # What the library, the loaders or the data refuse (outputs are written inside a
        # RunFailure guard, so these come from the inputs): the message alone (it names the
        # file, field, channel or parameter), no traceback.
        print(f"{PROG} {a.command}: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":  # python -m vibid._cli
    sys.exit(main())
