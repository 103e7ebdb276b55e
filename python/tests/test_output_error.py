"""Output error in Python (issue 29 items 1 and 3): method "oe", the offsets, the flags R
and M, Result.simulate and Result.validate, auto's validated choice, the first-stage
strength of the instruments, and a careful analyst's scipy fit as the yardstick.

Captures come from vibid-sim (the C build's, conftest.sim_path), seeded, so every figure
below is deterministic; each tolerance says why it is what it is. Measured figures are
printed (pytest -s) and quoted in docs/python.md.
"""

from __future__ import annotations

import math
import subprocess
import time

import numpy as np
import pandas as pd
import pytest

import vibid
from vibid import _adequacy
from conftest import REPO, example1_capture, sim_path  # noqa: F401 (fixtures example1_stand, ex1_clean)

# 1 DOF with a hardening cubic spring, the real capture in kind: its resonance at
# 68 Hz sampled at 610 Hz (9 samples per period), the force band-limited noise, x measured
# with 0.5 % noise (46 dB), the force exactly (the output-error fit takes its inputs as
# exact: noise on the force biases it, see the chain below and docs/python.md). Nominal values 10-25 % off the truth, as a stand file
# gives them (they are the output-error fit's second start). Seed 9 and 10 s: vibid-sim's
# ARKODE fails on this stand for some seeds and durations (e.g. seed 9 over 20 s, at
# 17.2 s), reported to the lead.
SILVER = """stand = { name = "silver"; sample_rate = 610.35;
  nodes = ( { name = "m"; mass = 1.0; measure = { displacement = "x"; }; } );
  elements = ( { name = "k"; kind = "spring"; between = ["m", "ground"]; unknown = true; value = 1.5e5; true_value = 1.8e5; },
               { name = "d"; kind = "damper"; between = ["m", "ground"]; unknown = true; value = 40.0; true_value = 30.0; },
               { name = "eps"; kind = "cubic_spring"; between = ["m", "ground"]; unknown = true; value = 1.5e10; true_value = 2.0e10; } );
  inputs = ( { name = "u"; node = "m"; gain = 1.1; unknown = true; true_value = 1.0; channel = "F"; } ); };
simulation = { seed = 9; excitation = ( { target = "u"; kind = "noise"; amplitude = 20.0; f_low = 5.0; f_high = 150.0; } );
  noise = ( { channel = "x"; snr_db = 46.0; } ); };
"""
# The same stand without nominal values: the output-error fit has only the equation-error
# estimate to start from.
SILVER_BARE = (SILVER.replace(" value = 1.5e5;", "").replace(" value = 40.0;", "").replace(" value = 1.5e10;", "")
               .replace("gain = 1.1;", "gain = 1.0;"))
# Offset of the displacement sensor: 5 % of x's RMS (the issue: a few %).
OFFSET = 0.05

# The 3-DOF chain of the library's tests (examples/stands/chain3.cfg): held force on m3, x
# and a of every node measured; simulated with 0.5 % noise on every channel, the force
# included.
CHAIN = REPO / "examples" / "stands" / "chain3.cfg"
CHAIN_SIM = """simulation = { seed = 3; excitation = ( { target = "f"; kind = "noise"; amplitude = 20.0; f_high = 150.0; } );
  NOISE };
"""
CHAIN_NOISE = ("noise = ( " + ", ".join(f'{{ channel = "{c}"; snr_db = 46.0; }}'
                                       for c in ["x1", "x2", "x3", "a1", "a2", "a3", "F"]) + " );")

# 1 DOF with a cubic spring whose force reaches the linear one at 1 mm (the library's cubic
# stand, damped to zeta 0.2: cubic force 58 % of the linear one at the RMS displacement),
# and the same stand without the cubic spring: a model that cannot explain the data. The
# damping matters for the validation: lightly damped (zeta 0.025) this stand's response
# depends so sensitively on its state that an estimate within 1.5 se of the truth, simulated
# over 8 s, drifts off the measurement (NRMSE 0.55): no simulation-error check can tell a
# right model there (docs/python.md, "Model adequacy").
DUFFING = """stand = { name = "duffing"; sample_rate = 2000.0;
  nodes = ( { name = "m"; mass = 1.0; measure = { displacement = "x"; }; } );
  elements = ( { name = "k"; kind = "spring"; between = ["m", "ground"]; unknown = true; true_value = 1.0e4; },
               { name = "d"; kind = "damper"; between = ["m", "ground"]; unknown = true; true_value = 40.0; }CUBIC );
  inputs = ( { name = "f"; node = "m"; gain = 1.0; channel = "F"; } ); };
simulation = { seed = 4; excitation = ( { target = "f"; kind = "noise"; amplitude = 15.0; f_low = 2.0; f_high = 80.0; } );
  noise = ( { channel = "x"; snr_db = 46.0; } ); };
"""
CUBIC = ',\n { name = "eps"; kind = "cubic_spring"; between = ["m", "ground"]; unknown = true; true_value = 1.0e10; }'


def simulate(tmp, name, text, seconds, stand=None):
    """vibid-sim's capture of a stand file and its simulation group, as a DataFrame with
    time_s, and the stand: text is the whole file, or with stand= (a stand file) the
    simulation group alone (vibid-sim -s)."""
    sim = sim_path()
    assert sim.exists(), f"no vibid-sim at {sim}: build the C tree first (target vibid-sim) or set VIBID_SIM"
    cfg = tmp / f"{name}.cfg"
    cfg.write_text(text)
    out = tmp / f"{name}.csv"
    args = ["-c", str(stand), "-s", str(cfg)] if stand else ["-c", str(cfg)]
    proc = subprocess.run([str(sim), *args, "--csv", str(out), "--fast", "-d", repr(float(seconds))],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    df = pd.read_csv(out, comment="#").rename(columns={"t": "time_s"})
    return vibid.Stand.load(stand or cfg), df


@pytest.fixture(scope="module")
def silver(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("silver")
    stand, df = simulate(tmp, "silver", SILVER, 10)
    offset = OFFSET * float(np.sqrt(np.mean(df["x"] ** 2)))
    df["x"] += offset
    return stand, df, offset


@pytest.fixture(scope="module")
def silver_oe(silver):
    stand, df, _ = silver
    t0 = time.perf_counter()
    r = vibid.identify(stand, df, method="oe")
    print(f"\nsilver, method oe: {time.perf_counter() - t0:.2f} s")
    return r


@pytest.fixture(scope="module")
def silver_auto(silver):
    stand, df, _ = silver
    t0 = time.perf_counter()
    r = vibid.identify(stand, df)
    print(f"\nsilver, auto: {time.perf_counter() - t0:.2f} s")
    return r


def show(r):
    p = r.parameters
    for name, row in p.iterrows():
        print(f"  {name}: {row['value']:.8g} +- {row['se']:.3g} ({100 * (row['value'] / row['true_value'] - 1):+.4f} %, "
              f"z {row['z']:+.2f}) {row['flags']}")
    for name, row in r.offsets.iterrows():
        print(f"  offset({name}): {row['value']:.6g} +- {row['se']:.3g} {row['unit']}")
    print(" ", vibid._identify.adequacy_line(r))


def test_oe_on_the_cubic_stand_with_an_offset(silver, silver_oe):
    # One seeded realisation: every parameter and the offset within 3 of their standard
    # errors (the library's sandwich error bars covered 94.2 % at 2 se on this stand,
    # tests/ident/test_output_error.c), and a few per mille of the truth (se are 0.003-0.03 %).
    _, _, offset = silver
    r = silver_oe
    show(r)
    assert r.method == "oe" and r.config["requested"] == "oe"
    assert r.flags == "", r.flags
    assert (r.parameters["z"].abs() < 3).all(), r.parameters
    assert (np.abs(r.parameters["value"] / r.parameters["true_value"] - 1) < 3e-3).all()
    off = r.offsets
    assert list(off.index) == ["x"] and off.loc["x", "unit"] == "m" and off.loc["x", "quantity"] == "displacement"
    assert abs(off.loc["x", "value"] - offset) < 3 * off.loc["x", "se"], (off, offset)
    # the fit's own account (vibid_ident_describe) and where the tracks would come from
    assert "output-error fit:" in r.description
    # adequacy of the estimate from the first 80 % on the last 20 %: the 0.5 % noise of x and
    # the response to the 0.5 % noise of F are what is left (NRMSE 0.006): far below M's
    # 0.3, and the residuals' predictable part (the F noise seen through the resonance) is
    # 0.003 of the RMS, far below 0.1
    a = r.adequacy
    assert a["segment"] == (len(silver[1]) - round(0.2 * len(silver[1])), len(silver[1]))
    assert 0.004 < a["nrmse"] < 0.02 and a["structured"] < 0.02 and a["flag"] == ""


def test_auto_picks_oe_on_the_cubic_stand_and_says_why(silver_auto, silver_oe):
    r = silver_auto
    show(r)
    print(" ", r.config["choice"])
    assert r.method == "oe" and r.config["requested"] == "auto"
    # the IV's instruments are weak on 9 samples per period (first-stage F 3.1 < 10):
    # IV is not used, and the choice says so with the figures
    assert r.config["choice"] in r.description
    assert "kept output error" in r.config["choice"]
    assert "instruments of the IV are weak" in r.config["choice"] and "IV is not used" in r.config["choice"]
    # the reported estimate is the output-error fit of the whole capture: identify(method="oe")'s
    np.testing.assert_array_equal(r.parameters["value"], silver_oe.parameters["value"])
    np.testing.assert_array_equal(r.offsets["value"], silver_oe.offsets["value"])
    # and the adequacy is the held-out validation of the output-error fit of the first part
    assert r.adequacy["nrmse"] == silver_oe.adequacy["nrmse"]


def test_first_stage_strength(silver, example1_stand):
    # The smallest canonical correlation of first_stage against scipy's principal angles
    # between the regressors' and the instruments' column spaces (cos of the largest angle),
    # on the silver capture at the automatic estimator's settings: equal to 1e-9.
    from scipy.linalg import subspace_angles

    stand, df, _ = silver
    r = vibid.identify(stand, df, method="iv", holdout=0.2)
    block = df[stand.channels].to_numpy()
    c = r.config
    fs = _adequacy.first_stage(stand, block, c["prefilter_hz"], c["difference_order"], c["iv_lag"])
    idx, X, _, m = _adequacy.regression(stand, block, c["prefilter_hz"], c["difference_order"])
    lag = c["iv_lag"]
    rho = math.cos(max(subspace_angles(X[lag * m:], X[:len(idx) * m - lag * m])))
    print(f"\nsilver: lag {lag}, pre-filter {c['prefilter_hz']:.4g} Hz: rho_min {fs['rho_min']:.4g} (scipy {rho:.4g}), "
          f"F {fs['f_stat']:.3g}, N_eff {fs['n_eff']:.0f}")
    assert abs(fs["rho_min"] - rho) < 1e-9
    assert fs["weak"] and fs["f_stat"] < _adequacy.WEAK_F
    # an explicit IV reports it: flagged U, in words in the command's warnings
    assert r.instruments["weak"] and "U" in r.flags and all("U" in f for f in r.parameters["flags"])
    # example 1 (100 Hz pre-filter on its 23 and 48 Hz modes at 2 kHz): strong instruments
    data, _ = example1_capture(noise=0.005, seed=2)
    e = vibid.identify(example1_stand, data, method="iv")
    print(f"example 1: rho_min {e.instruments['rho_min']:.4g}, F {e.instruments['f_stat']:.4g}")
    assert not e.instruments["weak"] and e.instruments["f_stat"] > 10 * _adequacy.WEAK_F


def test_bare_stand_starts_from_the_offset_free_equation_error_estimate(tmp_path, silver):
    # Without nominal values the fit's only start is the equation-error estimate. Before the
    # equation-error estimators carried constant forces (issue 29 item 2) the sensor offset
    # threw it to a negative damper (d -180 % and worse) and the fit failed from there; now
    # the constant absorbs the offset, the start is good, and the fit converges: every
    # parameter within 3 of its standard errors (measured within 0.85), no flag.
    stand, df, _ = silver
    cfg = tmp_path / "bare.cfg"
    cfg.write_text(SILVER_BARE)
    bare = vibid.Stand.load(cfg)
    r = vibid.identify(bare, df, method="oe", holdout=0)
    show(r)
    assert r.flags == "", r.description
    truth = pd.Series(stand.true_values, index=stand.parameters)
    z = (r.parameters["value"] - truth) / r.parameters["se"]
    assert (z.abs() < 3.0).all(), z


def test_refinement_failure_leaves_the_equation_error_estimate(tmp_path, silver):
    # A sensor whose zero drifts (a ramp of one RMS over the capture: neither a constant
    # offset nor anything the model has) throws the equation-error estimate, the bare
    # stand's only start, to an impossible damper: the simulation diverges from it, the fit
    # fails, and the library's automatic estimate stands, flagged R (and P: impossible), with
    # the reason: never a silent garbage row.
    _, df, _ = silver
    cfg = tmp_path / "bare.cfg"
    cfg.write_text(SILVER_BARE)
    bare = vibid.Stand.load(cfg)
    df = df.copy()
    df["x"] += np.linspace(0.0, 1.0, len(df)) * float(np.sqrt(np.mean(df["x"] ** 2)))
    r = vibid.identify(bare, df, method="oe", holdout=0)
    ee = vibid.identify(bare, df, method="auto", holdout=0)
    show(r)
    assert "R" in r.flags and "P" in r.flags
    assert all("R" in f for f in r.parameters["flags"])
    assert "output-error refinement failed (the equation-error estimate stands): " in r.description
    assert "diverged" in r.description
    # the library's automatic estimate, bit for bit (the same samples into the same estimator)
    np.testing.assert_array_equal(r.parameters["value"], ee.parameters["value"])
    np.testing.assert_array_equal(r.parameters["se"], ee.parameters["se"])
    assert len(r.offsets) == 0
    # auto: the fit on the first part fails the same way; the automatic estimate stands and
    # the choice says why
    a = vibid.identify(bare, df)
    print(" ", a.config["choice"])
    assert a.method == "auto(iv)" and "the output-error fit on the first part failed" in a.config["choice"]
    assert "P" in a.flags and "U" in a.flags


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """The chain's capture with 0.5 % noise on every channel, and the same run without
    measurement noise (same seed: the same excitation)."""
    tmp = tmp_path_factory.mktemp("chain")
    stand, df = simulate(tmp, "chain", CHAIN_SIM.replace("NOISE", CHAIN_NOISE), 10, CHAIN)
    _, clean = simulate(tmp, "chain_clean", CHAIN_SIM.replace("NOISE", ""), 10, CHAIN)
    return stand, df, clean


def test_auto_on_the_chain_states_its_choice(chain):
    # Noise on the force too: the output-error fit takes the inputs as exact, so their noise
    # biases it (k1 -3.9 se, d1 +4.2 se measured with method "oe"); its held-out NRMSE is the
    # IV's to 1e-6 (both 0.0048, the noise): no evidence for it, and auto keeps IV, saying so.
    stand, df, _ = chain
    r = vibid.identify(stand, df)
    show(r)
    print(" ", r.config["choice"])
    assert r.method == "auto(iv)"
    choice = r.config["choice"]
    assert "kept iv" in choice and "held-out NRMSE: output error" in choice and "not above 2" in choice
    assert r.adequacy["flag"] == "" and 0.003 < r.adequacy["nrmse"] < 0.01
    assert (r.parameters["z"].abs() < 3).all(), r.parameters
    # the NRMSE the choice quotes for iv is the adequacy's
    assert f"iv {r.adequacy['nrmse']:.4g}" in choice


def test_simulate_is_the_library_simulation(chain):
    # Result.simulate is vibid_oe_simulate at the estimate, bit for bit, whatever form the
    # inputs come in; and against vibid-sim's noise-free run of the same excitation (which
    # steps this linear stand exactly) it differs only by the estimate's error: the chain's
    # estimate is within 0.3 % (dampers) and 0.02 % (springs) of the truth, which moves the
    # lightly damped responses by up to ~1 % of their RMS; measured below.
    stand, df, clean = chain
    r = vibid.identify(stand, df, method="iv")
    out = r.simulate(df[["F"]])
    oe = vibid._core.Oe(stand._core, True)
    block = np.zeros((len(df), len(stand.channels)))
    block[:, stand.channels.index("F")] = df["F"]
    ref = np.asarray(oe.simulate(list(r.parameters["value"]), None, None, block))
    assert list(out.columns) == ["x1", "a1", "x2", "a2", "x3", "a3"]
    np.testing.assert_array_equal(out.to_numpy(), ref)
    np.testing.assert_array_equal(r.simulate({"F": df["F"].to_numpy()}).to_numpy(), ref)
    np.testing.assert_array_equal(r.simulate(df[stand.channels].to_numpy()).to_numpy(), ref)
    # offsets and an initial state: the offsets are added, the state starts the run
    off = {"x1": 1e-3, "a3": -0.5}
    shifted = r.simulate(df[["F"]], offsets=off)
    # added in C as sim + offset: equal to the last bit of the sum
    np.testing.assert_array_equal(shifted["x1"], out["x1"] + 1e-3)
    np.testing.assert_array_equal(shifted["a3"], out["a3"] - 0.5)
    np.testing.assert_array_equal(shifted["x2"], out["x2"])
    x0 = np.zeros(6)
    x0[0] = 1e-3
    moved = r.simulate(df[["F"]], x0=x0)
    assert moved["x1"].iloc[0] == 1e-3 and out["x1"].iloc[0] == 0.0
    # against the clean capture (same seed and excitation, no noise)
    for ch in out.columns:
        err = np.sqrt(np.mean((out[ch] - clean[ch]) ** 2)) / np.sqrt(np.mean(clean[ch] ** 2))
        print(f"  {ch}: simulate vs vibid-sim clean, NRMSE {err:.3g}")
        assert err < 0.02, (ch, err)


def test_validate_against_numpy(chain):
    # validate's figures recomputed from its own fitted simulation with numpy (NRMSE per
    # channel and overall, the residual RMS) and scipy (Ljung-Box's chi-square p-value):
    # equal to rounding (1e-12 relative).
    from scipy.stats import chi2

    stand, df, _ = chain
    r = vibid.identify(stand, df, method="iv", holdout=0)
    v = r.validate(df)
    ch = v["channels"]
    for name in ch.index:
        z = df[name].to_numpy()
        e = z - v["simulated"][name].to_numpy()
        nrmse = np.sqrt(np.mean(e * e)) / np.std(z)
        assert abs(ch.loc[name, "nrmse"] / nrmse - 1) < 1e-12
        assert abs(ch.loc[name, "rms_residual"] / np.sqrt(np.mean(e * e)) - 1) < 1e-12
        ec = e - e.mean()
        n = len(ec)
        r_k = np.array([np.dot(ec[:n - k], ec[k:]) for k in range(1, 21)]) / np.dot(ec, ec)
        q = n * (n + 2) * np.sum(r_k ** 2 / (n - np.arange(1, 21)))
        assert abs(ch.loc[name, "ljung_box_q"] / q - 1) < 1e-9
    assert abs(v["nrmse"] / np.sqrt(np.mean(ch["nrmse"] ** 2)) - 1) < 1e-12
    assert v["ljung_box_dof"] == 20 * len(ch)
    expect_p = chi2.sf(v["ljung_box_q"], v["ljung_box_dof"])
    assert v["ljung_box_p"] == pytest.approx(expect_p, rel=1e-9, abs=1e-300)
    # the noise (0.5 %) is what is left: the model explains the capture
    assert v["flag"] == "" and v["nrmse"] < 0.01
    # the offsets validate fits are the sensor zero errors (none here): within 1e-3 of each RMS
    assert (np.abs(ch["offset"]) < 1e-3 * ch["rms_measured"]).all()


def test_chi2_sf_against_scipy():
    from scipy.stats import chi2

    for k in (1, 2, 7, 20, 120):
        for x in (0.01, 0.5, 1.0, k - 1.0, k, k + 3.0, 3.0 * k, 10.0 * k + 50):
            if x <= 0:
                continue
            assert _adequacy.chi2_sf(x, k) == pytest.approx(chi2.sf(x, k), rel=1e-10, abs=1e-300), (x, k)


@pytest.fixture(scope="module")
def duffing(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("duffing")
    cubic, df = simulate(tmp, "duffing", DUFFING.replace("CUBIC", CUBIC), 8)
    lin_cfg = tmp / "linear.cfg"
    lin_cfg.write_text(DUFFING.replace("CUBIC", ""))
    return cubic, vibid.Stand.load(lin_cfg), df


def test_flag_m_on_a_model_that_cannot_explain_the_data(duffing):
    # Data of a stand with a cubic spring, identified with the stand file that lacks it: the
    # linear model's held-out simulation misses half the response (NRMSE 0.48 measured) and
    # its residuals are structure, not noise (predictable part 0.48): flagged M, with the
    # reason. The matching stand file (IV: the library's output-error fit is slow on cubic
    # stands at 2 kHz, docs) explains the same held-out samples to the 0.5 % noise (NRMSE
    # 0.005, Ljung-Box p 0.9): no M. The same on the whole capture through validate.
    cubic, linear, df = duffing
    wrong = vibid.identify(linear, df)
    show(wrong)
    assert "M" in wrong.flags and wrong.adequacy["flag"] == "M"
    assert wrong.adequacy["nrmse"] > _adequacy.NRMSE_LIMIT and "exceeds" in wrong.adequacy["why"]
    assert wrong.adequacy["structured"] > _adequacy.STRUCTURED_LIMIT
    right = vibid.identify(cubic, df, method="iv")
    show(right)
    assert "M" not in right.flags and right.adequacy["flag"] == ""
    assert right.adequacy["nrmse"] < 0.01
    # validate on the whole capture says the same
    assert wrong.validate(df)["flag"] == "M" and right.validate(df)["flag"] == ""


def _analyst_fit(df, split, start):
    """What a careful analyst writes: the same physical model (k, d, eps, gain u, initial
    state, one constant offset of x) simulated by RK4 with 4 steps per sample, the force
    linear between samples, fitted by scipy.optimize.least_squares (trust region,
    x_scale='jac') to the first `split` samples of x."""
    from scipy.optimize import least_squares

    fs = 610.35
    h = 1.0 / fs
    F = df["F"].to_numpy()[:split]
    z = df["x"].to_numpy()[:split]
    sub = 4
    hs = h / sub

    def sim(p):
        k, d, eps, u, y, v = p[:6]
        out = np.empty(split)
        for i in range(split):
            out[i] = y
            if i + 1 == split:
                break
            f0, f1 = u * F[i], u * F[i + 1]
            for s in range(sub):
                t0 = s / sub
                fa, fm, fb = f0 + (f1 - f0) * t0, f0 + (f1 - f0) * (t0 + 0.5 / sub), f0 + (f1 - f0) * (t0 + 1.0 / sub)
                a1 = fa - k * y - d * v - eps * y ** 3
                y2, v2 = y + 0.5 * hs * v, v + 0.5 * hs * a1
                a2 = fm - k * y2 - d * v2 - eps * y2 ** 3
                y3, v3 = y + 0.5 * hs * v2, v + 0.5 * hs * a2
                a3 = fm - k * y3 - d * v3 - eps * y3 ** 3
                y4, v4 = y + hs * v3, v + hs * a3
                a4 = fb - k * y4 - d * v4 - eps * y4 ** 3
                y += hs / 6 * (v + 2 * v2 + 2 * v3 + v4)
                v += hs / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
            if not abs(y) < 1.0:
                out[i + 1:] = 1.0
                break
        return out

    def res(p):
        return sim(p) + p[6] - z

    x0 = [start[0], start[1], start[2], start[3], z[0], (z[1] - z[0]) / h, 0.0]
    t0 = time.perf_counter()
    sol = least_squares(res, x0, x_scale="jac", method="trf")
    return sol.x, time.perf_counter() - t0, sol.nfev


def test_held_out_error_at_least_as_good_as_the_analysts(silver, silver_auto):
    # The target: on held-out data at least as good as a careful output-error
    # analyst's (scipy least_squares on the same model plus one offset). Both fits use the
    # first 80 % and start from the stand's nominal values; both estimates are validated
    # the same way on the last 20 % (Result.adequacy's convention: initial state and offset
    # fitted). The two minimise the same cost with different integrators (vibid: RK4 with
    # step doubling to 1e-6 of the peak; the analyst: 4 fixed steps per sample); measured:
    # vibid 0.14 % below the analyst, and equal to the truth's to 1e-5.
    stand, df, _ = silver
    n = len(df)
    split = n - round(0.2 * n)
    start = stand.nominal_values
    theta, seconds, nfev = _analyst_fit(df, split, start)
    block = df[stand.channels].to_numpy()
    omega = _adequacy.omega_of(silver_auto.modes["freq_hz"], stand.sample_rate)
    analyst = _adequacy.validate_block(stand, theta[:4], block[split:], omega)
    ours = silver_auto.adequacy
    a_rms = analyst["channels"].loc["x", "rms_residual"]
    o_rms = ours["channels"].loc["x", "rms_residual"]
    print(f"\nheld-out RMS error of x: vibid {o_rms:.6g} m, analyst {a_rms:.6g} m (ratio {o_rms / a_rms:.6f}); "
          f"analyst's fit {seconds:.1f} s, {nfev} simulations; theta {theta[:4]}")
    assert o_rms <= a_rms


def test_command_prints_offsets_and_adequacy(tmp_path, chain):
    # vibid identify --method oe on the chain's capture: the offsets table holds
    # identify(method="oe")'s offsets to the ten printed digits, the adequacy line its figures;
    # the report's held-out section quotes the same line and draws both new figures.
    import re
    import sys
    from pathlib import Path

    stand, df, _ = chain
    cap = tmp_path / "chain.csv"
    df.to_csv(cap, index=False, float_format="%.17g")
    report = tmp_path / "r.html"
    exe = Path(sys.executable).with_name("vibid")
    proc = subprocess.run([str(exe), "identify", str(CHAIN), str(cap), "--method", "oe", "--report", str(report)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    r = vibid.identify(stand, cap, method="oe", track_every=200)
    lines = proc.stdout.splitlines()
    i = next(k for k, line in enumerate(lines) if line.startswith("offset "))
    rows = [re.split(r"\s{2,}", line.strip()) for line in lines[i + 1:i + 1 + len(r.offsets)]]
    assert [row[0] for row in rows] == list(r.offsets.index) == ["x1", "a1", "x2", "a2", "x3", "a3"]
    for row in rows:
        assert row[1] == f"{r.offsets.loc[row[0], 'value']:.10g}" and row[2] == f"{r.offsets.loc[row[0], 'se']:.10g}"
    assert [row[3] for row in rows] == ["m", "m/s^2"] * 3
    line = vibid._identify.adequacy_line(r)
    assert line in proc.stdout and "method oe" in proc.stdout
    doc = report.read_text()
    held = doc[doc.index('<section id="holdout">'):doc.index('<section id="residual-spectrum">')]
    assert "adequacy on held-out samples 16000..19999" in held
    spec = doc[doc.index('<section id="residual-spectrum">'):]
    assert held.count('src="data:image/png;base64,') == 1 and spec.count('src="data:image/png;base64,') == 1


def test_disagreement_with_iv_flags_the_output_error_u(example1_stand, ex1_clean):
    # Paper example 1 noise-free: the base is a smooth multisine, which the fit takes as
    # linear between samples, so its damper comes out 0.068 % low at 51 of its standard errors
    # while the IV holds the truth within its bars. auto keeps the output error (it simulates the
    # held-out part better: the same interpolation is in the validation), and the two
    # estimates disagree far beyond both bars (chi2 950 on 3 degrees of freedom): the
    # output error's bars are flagged U, with the reason, also for method "oe".
    data, _ = ex1_clean
    r = vibid.identify(example1_stand, data)
    print("\n ", r.config["choice"])
    assert r.method == "oe" and "U" in r.flags and all("U" in f for f in r.parameters["flags"])
    assert "disagree beyond their error bars" in r.config["choice"] and r.unsure in r.config["choice"]
    assert abs(r.parameters.loc["d", "z"]) > 10  # the reason for the flag
    o = vibid.identify(example1_stand, data, method="oe")
    assert "U" in o.flags and "disagree beyond their error bars" in o.description
    # the IV estimate of the same capture: no U, truth within 3 se (test_identify.py)
    ee = vibid.identify(example1_stand, data, holdout=0)
    assert "U" not in ee.flags and (ee.parameters["z"].abs() < 3).all()
