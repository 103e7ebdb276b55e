"""Model adequacy (issue 29 item 3): does the identified model explain the data?

Every figure here is computed from the library's own simulation of the stand
(``vibid_oe_simulate`` through ``_core.Oe``: linear stands exactly, cubic ones by RK4) and
its own regression (``vibid_regressor_*`` through ``_core.stand_regression``); this module
only fits the nuisance quantities of a validation segment and computes the statistics in
numpy. docs/python.md, "Model adequacy", says why each threshold is what it is.

Validation of parameters theta on a segment of a capture (``validate``):
  the model at theta is driven by the segment's measured inputs; its initial state x0 at
  the segment's first sample and one constant offset per response channel are fitted with
  theta fixed (weighted least squares, each channel weighted by 1 / its variance about the
  mean, i.e. the sum of the squared per-channel NRMSEs is minimised; Gauss-Newton over x0
  with finite-difference sensitivities, the offsets in closed form). That is MATLAB's
  ``compare`` convention (initial condition estimated): the segment's start state is not
  known to any estimator that did not see the segment, and a sensor's zero error is not
  the model's business. It costs 2 n + ny numbers against thousands of samples.
A stand with disturbances (``validate_predictor``): the response is mostly the
  disturbances', which no simulation reproduces; the model is judged by its steady-state
  Kalman predictor instead (the prediction-error fit on the first part, run over the
  held-out part): the innovations must be white, with the variance the predictor expects.
Figures per response channel: NRMSE = RMS(residual) / RMS(measured - its mean) (1 is the
  model that predicts the mean), the residual RMS, the Ljung-Box statistic of the residual's
  autocorrelation over LJUNG_BOX_LAGS lags with its p-value (chi-square, one degree of
  freedom per lag), and the predictable fraction of the residual (1 - the prediction-error
  variance of an autoregression of order LJUNG_BOX_LAGS / the residual variance; about
  lags / N for white residuals, near 1 for the smooth error of a wrong model).
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
import pandas as pd

from . import _core

# Lags of the Ljung-Box test: Ljung and Box's 20, at least 10 samples per lag needed.
LJUNG_BOX_LAGS = 20
# The flag M ("the model cannot explain the data"), docs/python.md "Model adequacy":
NRMSE_LIMIT = 0.3        # held-out NRMSE above which the model misses > 9 % of the output's variance
STRUCTURED_LIMIT = 0.1   # NRMSE x sqrt(predictable fraction): structure the model misses, > 1 % of the variance
WHITENESS_P = 1e-3       # and the Ljung-Box test must reject whiteness at this level for that
# Fewest samples of a validation segment (20 lags need 200 for the Ljung-Box test).
MIN_SEGMENT = 200
# Weak instruments: the Cragg-Donald statistic below this (Staiger and Stock's rule of thumb).
WEAK_F = 10.0


def chi2_sf(x: float, k: int) -> float:
    """P(X > x) for X chi-square with k degrees of freedom: the regularised upper incomplete
    gamma function Q(k/2, x/2), by its series below a + 1 and Lentz's continued fraction
    above (Numerical Recipes 6.2); relative accuracy ~1e-14."""
    if not x > 0:
        return 1.0
    if math.isinf(x):
        return 0.0
    a, z = 0.5 * k, 0.5 * x
    lead = math.exp(-z + a * math.log(z) - math.lgamma(a))
    if z < a + 1.0:
        term = total = 1.0 / a
        ap = a
        for _ in range(10000):
            ap += 1.0
            term *= z / ap
            total += term
            if abs(term) < abs(total) * 1e-16:
                break
        return max(0.0, 1.0 - total * lead)
    tiny = 1e-300
    b = z + 1.0 - a
    c, d = 1.0 / tiny, 1.0 / b
    h = d
    for i in range(1, 10000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-16:
            break
    return lead * h


def ljung_box(e: np.ndarray, lags: int = LJUNG_BOX_LAGS) -> tuple[float, float, float]:
    """(Q, p-value, predictable fraction) of a residual series: Q = N (N + 2) sum_k r_k^2 /
    (N - k) over lags 1..lags (r the sample autocorrelation, mean removed), p = P(chi2_lags
    > Q); the predictable fraction 1 - prod(1 - kappa_i^2) from the reflection coefficients
    kappa of the Levinson-Durbin recursion on the same r (the share of the variance an
    autoregression of that order predicts from the past)."""
    from ._plot import autocorrelation

    e = np.asarray(e, dtype=float)
    n = len(e)
    r = autocorrelation(e, lags)
    if not np.isfinite(r).all():
        return math.nan, math.nan, math.nan
    k = np.arange(1, lags + 1)
    q = float(n * (n + 2) * np.sum(r[1:] ** 2 / (n - k)))
    # Levinson-Durbin: prediction-error variance (relative to r0) of orders 1..lags
    a = np.zeros(lags + 1)
    err = 1.0
    for m in range(1, lags + 1):
        kappa = (r[m] - np.dot(a[1:m], r[m - 1:0:-1])) / err
        a_new = a.copy()
        a_new[m] = kappa
        a_new[1:m] = a[1:m] - kappa * a[m - 1:0:-1]
        a = a_new
        err *= max(0.0, 1.0 - kappa * kappa)
    return q, chi2_sf(q, lags), float(1.0 - err)


def regression(stand, block: np.ndarray, prefilter_hz: float, order: int):
    """The estimators' regression over the capture (regressor.h): sample index per row,
    X ((rows * m) x p, equation i of row r at r * m + i), Y (rows * m), and m."""
    idx, X, Y = _core.stand_regression(stand._core, block, float(prefilter_hz), int(order))
    idx = np.asarray(idx)
    m = len(Y) // len(idx) if len(idx) else 1
    return idx, np.asarray(X), np.asarray(Y), m


def equation_errors(stand, theta, block: np.ndarray, prefilter_hz: float, order: int):
    """The equation errors y - x^T theta of the regression at theta (the estimators'
    differences and pre-filter), rows x m (one column per node's equation), and the sample
    index of each row."""
    idx, X, Y, m = regression(stand, block, prefilter_hz, order)
    e = Y - X @ np.asarray(theta, dtype=float)
    return idx, e.reshape(len(idx), m)


def first_stage(stand, block: np.ndarray, prefilter_hz: float, order: int, lag: int) -> dict:
    """Strength of the instruments of the IV estimators (identify.h: the regressor rows
    `lag` samples earlier, same equation) for the regressors: the smallest canonical
    correlation rho between X and Z (uncentred, as the estimator has no intercept), and
    the Cragg-Donald statistic F = (N_eff - p) / p * rho^2 / (1 - rho^2) with N_eff the
    degrees of freedom of the pre-filtered rows, 2 f_c T per equation (a signal band-limited
    to f_c over T seconds has that many independent values; the samples are not
    independent), or the rows themselves without a pre-filter. Weak when F < WEAK_F."""
    idx, X, _, m = regression(stand, block, prefilter_hz, order)
    rows, p = len(idx), X.shape[1]
    if rows <= lag + p:
        return {"rho_min": math.nan, "f_stat": math.nan, "n_eff": 0.0, "weak": False,
                "why": f"{rows} regression rows, {lag + p + 1} needed"}
    Xc = X[lag * m:]
    Zc = X[:(rows - lag) * m]
    qx = np.linalg.qr(Xc / np.linalg.norm(Xc, axis=0).clip(1e-300))[0]
    qz = np.linalg.qr(Zc / np.linalg.norm(Zc, axis=0).clip(1e-300))[0]
    rho = float(min(1.0, np.linalg.svd(qx.T @ qz, compute_uv=False).min()))
    fs = stand.sample_rate
    n_eff = float(len(Xc))
    if prefilter_hz > 0:
        n_eff = min(n_eff, 2.0 * prefilter_hz * (rows - lag) / fs * m)
    f = (n_eff - p) / p * rho * rho / max(1e-300, 1.0 - rho * rho)
    return {"rho_min": rho, "f_stat": float(f), "n_eff": n_eff, "weak": bool(f < WEAK_F), "why": ""}


def input_block(stand, inputs) -> np.ndarray:
    """The stand's channels as a block for the simulator from what the caller gives: a
    DataFrame or a dict with the input channels (force inputs and the base displacement;
    response channels may be there and are ignored), or a 2-D array with all channels in
    the stand's order. The response columns the simulator does not drive are zero."""
    from ._identify import _columns

    chans = stand.channels
    if isinstance(inputs, np.ndarray):
        return _columns(stand, inputs)[0]
    names = list(inputs.columns if isinstance(inputs, pd.DataFrame) else inputs.keys())
    need = simulator_inputs(stand)
    missing = [c for c in need if c not in names]
    if missing:
        raise ValueError(f"input channel {missing[0]!r} missing: the stand {stand.name!r} is driven by {need}")
    n = len(inputs[need[0]]) if need else len(inputs[names[0]])
    full = {c: (inputs[c] if c in need else np.zeros(n)) for c in chans}
    return _columns(stand, full)[0]


def simulator_inputs(stand) -> list[str]:
    """The channels that drive the simulation: force inputs and the base displacement."""
    out = []
    for ch, (kind, idx, _) in zip(stand.channels, _core.stand_channel_info(stand._core)):
        if kind == "input" or (idx == -2 and kind == "displacement"):
            out.append(ch)
    return out


def simulator(stand):
    """The stand's output-error simulator (_core.Oe), made once per stand. Raises VibidError
    with the library's reason where the stand cannot be simulated (a moving base whose
    displacement is not measured; a disturbance beside a cubic spring or a base)."""
    oe = getattr(stand, "_oe", None)
    if oe is None:
        oe = _core.Oe(stand._core, True)
        stand._oe = oe
    return oe


def _state_start(stand, block: np.ndarray, omega: float) -> tuple[np.ndarray, np.ndarray]:
    """A start value for the initial state [y; y'] at the block's first sample and a scale
    per state for the finite differences: measured displacements (and velocities, else
    one-sided differences of the displacements); nodes without a sensor start at rest, with
    the scale of the measured ones (displacements from velocities / omega and accelerations
    / omega^2 where no displacement is measured)."""
    n = stand.n_dof
    h = 1.0 / stand.sample_rate
    y0, v0 = np.zeros(n), np.zeros(n)
    ys, vs = np.full(n, np.nan), np.full(n, np.nan)
    scale_d = []
    for c, (kind, idx, _) in enumerate(_core.stand_channel_info(stand._core)):
        if idx < 0 or kind == "input":
            continue
        col = block[:, c]
        rms = float(np.sqrt(np.mean((col - col.mean()) ** 2)))
        if kind == "displacement":
            y0[idx] = col[0]
            ys[idx] = rms
            if len(col) > 2:  # one-sided second-order slope at the first sample
                v0[idx] = (-3 * col[0] + 4 * col[1] - col[2]) / (2 * h)
            scale_d.append(rms)
        elif kind == "velocity":
            v0[idx] = col[0]
            vs[idx] = rms
            scale_d.append(rms / omega)
        else:
            scale_d.append(rms / (omega * omega))
    d = max(scale_d) if scale_d else 1.0
    ys = np.where(np.isfinite(ys), ys, d)
    vs = np.where(np.isfinite(vs), vs, ys * omega)
    scale = np.concatenate([ys, vs])
    scale = np.where(scale > 0, scale, d if d > 0 else 1.0)
    return np.concatenate([y0, v0]), scale


def fitted_simulation(stand, theta, block: np.ndarray, omega: float, iterations: int = 8):
    """The model at theta on the block with the initial state and the offsets fitted (module
    docstring): (simulated response channels with offsets, n x ny; x0; offsets; response
    channel indices). Gauss-Newton over x0 from two starts, the measured state at the first
    sample and rest, the better kept: a linear stand needs one step from either (its response
    is affine in x0), a stand with cubic springs can be so sensitive to its initial state
    that a start velocity from differences of noisy displacements throws the whole segment
    off (the duffing stand of test_output_error.py: NRMSE 0.95 from it, 0.005 from rest)."""
    oe = simulator(stand)
    resp = list(oe.response_channels())
    theta = [float(v) for v in theta]
    z = block[:, resp]
    w = 1.0 / np.maximum(z.var(axis=0), 1e-300)
    measured, scale = _state_start(stand, block, omega)

    def sim(x):
        return np.asarray(oe.simulate(theta, list(x), None, block))

    def cost_of(s):
        r = z - s
        r = r - r.mean(axis=0)
        return float(np.sum(w * np.mean(r * r, axis=0))), r

    def gauss_newton(x0):
        s0 = sim(x0)
        cost, r = cost_of(s0)
        for _ in range(iterations):
            # sensitivities of the centred response to each state, by finite differences
            J = np.empty((z.shape[0], z.shape[1], len(x0)))
            for i in range(len(x0)):
                d = 1e-3 * scale[i]
                x = x0.copy()
                x[i] += d
                J[:, :, i] = (sim(x) - s0) / d
            J -= J.mean(axis=0)
            sw = np.sqrt(w)
            A = (J * sw[None, :, None]).reshape(-1, len(x0))
            b = (r * sw[None, :]).reshape(-1)
            step = np.linalg.lstsq(A, b, rcond=None)[0]
            improved = False
            for _ in range(6):
                xt = x0 + step
                try:
                    st = sim(xt)
                except _core.VibidError:
                    step *= 0.5
                    continue
                ct, rt = cost_of(st)
                if ct < cost:
                    improved = True
                    break
                step *= 0.5
            if not improved:
                break
            rel = (cost - ct) / max(cost, 1e-300)
            x0, s0, cost, r = xt, st, ct, rt
            if rel < 1e-9:
                break
        return cost, x0, s0

    best = None
    for start in (measured, np.zeros_like(measured)):
        try:
            fit = gauss_newton(start)
        except _core.VibidError:
            continue
        if best is None or fit[0] < best[0]:
            best = fit
    if best is None:
        raise _core.VibidError("vibid_oe_simulate: the simulation diverged from the measured state and from rest")
    _, x0, s0 = best
    offsets = (z - s0).mean(axis=0)
    return s0 + offsets, x0, offsets, resp


def validate_block(stand, theta, block: np.ndarray, omega: float) -> dict:
    """Validation figures of theta on block (module docstring): a dict with ``nrmse`` (RMS
    over the response channels of their NRMSEs), ``ljung_box_q``, ``ljung_box_dof``,
    ``ljung_box_p`` (all channels' Q summed, their lags as degrees of freedom), ``structured``
    (RMS over channels of NRMSE x sqrt(predictable fraction)), ``flag`` ("M" or ""), ``why``,
    ``channels`` (DataFrame per response channel: rms_measured, rms_residual, nrmse, offset,
    ljung_box_q, ljung_box_p, predictable), ``simulated`` (DataFrame of the fitted
    simulation) and ``x0``."""
    n = block.shape[0]
    if n < MIN_SEGMENT:
        raise ValueError(f"{n} samples to validate on: at least {MIN_SEGMENT} are needed (Ljung-Box over "
                         f"{LJUNG_BOX_LAGS} lags)")
    sim, x0, offsets, resp = fitted_simulation(stand, theta, block, omega)
    names = [stand.channels[c] for c in resp]
    rows = []
    for j, c in enumerate(resp):
        z = block[:, c]
        e = z - sim[:, j]
        rms_z = float(np.sqrt(np.mean((z - z.mean()) ** 2)))
        rms_e = float(np.sqrt(np.mean(e * e)))
        q, p, pred = ljung_box(e)
        rows.append({"channel": names[j], "rms_measured": rms_z, "rms_residual": rms_e,
                     "nrmse": rms_e / rms_z if rms_z > 0 else math.nan, "offset": float(offsets[j]),
                     "ljung_box_q": q, "ljung_box_p": p, "predictable": pred})
    ch = pd.DataFrame(rows).set_index("channel")
    nrmse = float(np.sqrt(np.mean(ch["nrmse"] ** 2)))
    q = float(ch["ljung_box_q"].sum())
    dof = LJUNG_BOX_LAGS * len(ch)
    p = chi2_sf(q, dof)
    structured = float(np.sqrt(np.mean(ch["nrmse"] ** 2 * ch["predictable"].clip(lower=0.0))))
    why = []
    if nrmse > NRMSE_LIMIT:
        why.append(f"the held-out NRMSE {nrmse:.3g} exceeds {NRMSE_LIMIT:g}: the model leaves "
                   f"{100 * min(1.0, nrmse * nrmse):.0f} % of the outputs' variance unexplained")
    if p < WHITENESS_P and structured > STRUCTURED_LIMIT:
        why.append(f"the residuals are not white (Ljung-Box p = {p:.2g} < {WHITENESS_P:g}) and their predictable "
                   f"part is {structured:.3g} of the outputs' RMS (above {STRUCTURED_LIMIT:g}): structure the "
                   "model does not have")
    return {"nrmse": nrmse, "ljung_box_q": q, "ljung_box_dof": dof, "ljung_box_p": p, "structured": structured,
            "flag": "M" if why else "", "why": "; ".join(why), "channels": ch,
            "simulated": pd.DataFrame(sim, columns=names), "x0": x0}


# A stand with disturbances (docs/python.md "Stands with disturbances"): its held-out
# innovations must be white with the covariance the predictor expects. Above this ratio of
# their mean square to that variance, the predictor is over-confident.
VARIANCE_RATIO_LIMIT = 1.5


def validate_predictor(stand, theta, first: np.ndarray, held: np.ndarray) -> dict:
    """Validation figures of a stand with disturbances (module docstring, second part): the
    prediction-error fit on ``first`` started at theta (it converges at once from its own
    estimate) gives the steady-state Kalman predictor (parameters, noise intensities and
    offsets), which runs over ``first`` and on over ``held`` (``vibid_oe_predict``). Per
    response channel: the one-step prediction's NRMSE (innovation RMS over the measured RMS
    about the mean; not flagged by size: an accelerometer on a node a disturbance acts on
    sees that force directly, which no predictor can know), the Ljung-Box statistic and
    predictable fraction of the innovations, and their mean square over the variance the
    predictor expects (``variance_ratio``, 1 where the model explains the data). Flag "M"
    where the innovations are not white and more than STRUCTURED_LIMIT^2 of their variance
    is predictable from their past, or where a variance ratio exceeds VARIANCE_RATIO_LIMIT.
    The same keys as :func:`validate_block`, ``simulated`` holding the one-step predictions."""
    n = held.shape[0]
    if n < MIN_SEGMENT:
        raise ValueError(f"{n} samples to validate on: at least {MIN_SEGMENT} are needed (Ljung-Box over "
                         f"{LJUNG_BOX_LAGS} lags)")
    oe = _core.Oe(stand._core, True)
    fit = oe.fit(first, np.asarray(theta, dtype=float).reshape(-1, 1))
    if fit["status"] != 0:
        raise ValueError(f"the prediction-error fit on the first part failed: {fit['message']}")
    # through the first part into the held-out one: a one-step prediction knows the past, and
    # the predictor's start-up transient (from the stationary mean) stays out of the figures
    innov, S = oe.predict(np.vstack([first, held]))
    innov, S = np.asarray(innov)[first.shape[0]:], np.asarray(S)
    resp = list(oe.response_channels())
    names = [stand.channels[c] for c in resp]
    rows = []
    for j, c in enumerate(resp):
        z = held[:, c]
        e = innov[:, j]
        ok = np.isfinite(e)
        z, e = z[ok], e[ok]
        rms_z = float(np.sqrt(np.mean((z - z.mean()) ** 2)))
        rms_e = float(np.sqrt(np.mean(e * e)))
        q, p, pred = ljung_box(e)
        rows.append({"channel": names[j], "rms_measured": rms_z, "rms_residual": rms_e,
                     "nrmse": rms_e / rms_z if rms_z > 0 else math.nan, "offset": float(fit["offsets"][j]),
                     "ljung_box_q": q, "ljung_box_p": p, "predictable": pred,
                     "variance_ratio": rms_e * rms_e / S[j, j] if S[j, j] > 0 else math.nan})
    ch = pd.DataFrame(rows).set_index("channel")
    nrmse = float(np.sqrt(np.mean(ch["nrmse"] ** 2)))
    q = float(ch["ljung_box_q"].sum())
    dof = LJUNG_BOX_LAGS * len(ch)
    p = chi2_sf(q, dof)
    structured = float(np.sqrt(np.mean(ch["predictable"].clip(lower=0.0))))
    worst = float(ch["variance_ratio"].max())
    why = []
    if p < WHITENESS_P and structured > STRUCTURED_LIMIT:
        why.append(f"the held-out innovations are not white (Ljung-Box p = {p:.2g} < {WHITENESS_P:g}) and "
                   f"{100 * structured ** 2:.2g} % of their variance is predictable from their past (above "
                   f"{100 * STRUCTURED_LIMIT ** 2:g} %): structure the model does not have")
    if not worst <= VARIANCE_RATIO_LIMIT:
        why.append(f"the held-out innovations' mean square is {worst:.3g} times what the predictor expects "
                   f"(above {VARIANCE_RATIO_LIMIT:g}): the model or its noise intensities do not explain the data")
    predicted = held[:, resp] - np.where(np.isfinite(innov), innov, np.nan)
    return {"nrmse": nrmse, "ljung_box_q": q, "ljung_box_dof": dof, "ljung_box_p": p, "structured": structured,
            "flag": "M" if why else "", "why": "; ".join(why), "channels": ch,
            "simulated": pd.DataFrame(predicted, columns=names), "x0": np.array([]),
            "kind": "one-step prediction"}


def omega_of(freq_hz, sample_rate: float) -> float:
    """A representative angular frequency for the state scales: the highest finite mode,
    else a tenth of the sample rate."""
    f = [float(v) for v in freq_hz if math.isfinite(v) and v > 0]
    return 2 * math.pi * (max(f) if f else sample_rate / 10)


def unavailable(why: str, segment: Optional[tuple[int, int]] = None) -> dict:
    """The adequacy of a result whose model cannot be validated, with the reason."""
    return {"nrmse": math.nan, "ljung_box_q": math.nan, "ljung_box_dof": 0, "ljung_box_p": math.nan,
            "structured": math.nan, "flag": "", "why": "", "channels": pd.DataFrame(), "simulated": pd.DataFrame(),
            "x0": np.array([]), "unavailable": why, "segment": segment}


# Blocks of the held-out part for the standard error of a difference of squared errors
# (batch means: the residuals are correlated over a mode's decay time, blocks of a
# twentieth of the part hold several of them), and the t it must exceed.
COMPARE_BLOCKS = 20
COMPARE_T = 2.0


def compare(stand, a: dict, b: dict, block: np.ndarray) -> tuple[float, float]:
    """Whether validation b fits the same segment better than a: (mean over the segment of
    d_k = sum_j (e_a,jk^2 - e_b,jk^2) / (ny var z_j), whose mean is NRMSE_a^2 - NRMSE_b^2,
    and its standard error by batch means over COMPARE_BLOCKS blocks)."""
    oe = simulator(stand)
    resp = list(oe.response_channels())
    z = block[:, resp]
    w = 1.0 / (len(resp) * np.maximum(z.var(axis=0), 1e-300))
    ea = z - a["simulated"].to_numpy()
    eb = z - b["simulated"].to_numpy()
    d = np.sum(w * (ea * ea - eb * eb), axis=1)
    nb = min(COMPARE_BLOCKS, len(d) // 10)
    means = np.array([c.mean() for c in np.array_split(d, nb)])
    return float(d.mean()), float(means.std(ddof=1) / math.sqrt(nb))
