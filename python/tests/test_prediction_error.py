"""Stands with disturbances through identify (issue 34 item 4, issue 29 items 1 and 3): the
prediction-error fit of the stand's Kalman predictor, chosen by auto, against the EKF, and
its validation by the held-out one-step prediction, on captures written by vibid-sim (an
independent simulator: SUNDIALS-free exact steps of its own, docs/sim.md).

The stand: a 3-DOF chain to ground (modes 10.9, 25.4, 36.6 Hz, damping 0.7-2.3 %) in
service, white held forces of 1 N on every mass (unmeasured, intensity unknown),
accelerometers on every mass with 40 dB SNR (noise level unknown); 120 s at 300 Hz; three
springs and three dampers unknown, started 15 % off. ident.prediction_error has the Monte
Carlo coverage (93.9 % over 180 intervals); here one seeded capture each, so tolerances of
3 standard errors (a 0.3 % chance per parameter for a true 1-sigma bar, fixed seeds)."""

from __future__ import annotations

import re
import subprocess

import numpy as np
import pandas as pd
import pytest

import vibid
from conftest import sim_path

TRUTH = {"k1": 2.0e4, "d1": 4.0, "k2": 1.5e4, "d2": 3.0, "k3": 1.0e4, "d3": 2.0}
START = {"k1": 2.3e4, "d1": 3.4, "k2": 1.725e4, "d2": 3.45, "k3": 0.85e4, "d3": 2.3}


def stand_text(extra_excitation: str = "") -> str:
    el = []
    for name, a, b in (("1", "m1", "ground"), ("2", "m2", "m1"), ("3", "m3", "m2")):
        for kind, p in (("spring", "k"), ("damper", "d")):
            el.append(f'{{ name = "{p}{name}"; kind = "{kind}"; between = ["{a}", "{b}"]; unknown = true; '
                      f'value = {START[p + name]!r}; true_value = {TRUTH[p + name]!r}; }}')
    noise = ", ".join(f'{{ channel = "a{j}"; snr_db = 40.0; }}' for j in (1, 2, 3))
    return (
        'stand = { name = "pe-chain3"; sample_rate = 300.0;\n'
        '  nodes = ( { name = "m1"; mass = 1.0; measure = { acceleration = "a1"; }; },\n'
        '            { name = "m2"; mass = 0.8; measure = { acceleration = "a2"; }; },\n'
        '            { name = "m3"; mass = 0.6; measure = { acceleration = "a3"; }; } );\n'
        f'  elements = ( {", ".join(el)} );\n'
        '  disturbances = ( { name = "w1"; node = "m1"; true_std = 1.0; },\n'
        '                   { name = "w2"; node = "m2"; true_std = 1.0; },\n'
        '                   { name = "w3"; node = "m3"; true_std = 1.0; } ); };\n'
        f'simulation = {{ seed = 7; duration = 120.0; noise = ( {noise} );\n'
        f'  {extra_excitation} }};\n')


def capture(tmp_path, text: str, name: str):
    cfg = tmp_path / f"{name}.cfg"
    cfg.write_text(text)
    csv = tmp_path / f"{name}.csv"
    subprocess.run([str(sim_path()), "-c", str(cfg), "--csv", str(csv), "-q"], check=True, timeout=300)
    return vibid.Stand.load(cfg), pd.read_csv(csv)


@pytest.fixture(scope="module")
def white(tmp_path_factory):
    return capture(tmp_path_factory.mktemp("pe"), stand_text(), "white")


def test_auto_keeps_the_prediction_error_fit(white):
    st, data = white
    r = vibid.identify(st, data)
    assert r.config["method"] == "oe"
    assert "kept the prediction-error fit" in r.config["choice"]
    assert "prediction-error fit:" in r.description
    z = (r.parameters["value"] - pd.Series(TRUTH)) / r.parameters["se"]
    assert (z.abs() < 3).all(), z
    # the springs within 1 % (measured -0.07, +0.05, +0.32 %; their se 0.1-0.25 %: the spread
    # over ident.prediction_error's 30 realisations of 60 s is 0.17-0.26 %)
    rel = r.parameters["value"] / pd.Series(TRUTH) - 1
    assert (rel[["k1", "k2", "k3"]].abs() < 1e-2).all(), rel
    assert r.flags == ""
    # held-out one-step prediction (2160 samples): white innovations with the variance the
    # predictor expects; the ratio's sd is sqrt(2 / 2160) = 0.03 per channel, so +-0.1 is
    # 3.3 sd
    a = r.adequacy
    assert a["flag"] == "", a["why"]
    assert a.get("kind") == "one-step prediction"
    assert a["ljung_box_p"] > 1e-3
    assert ((a["channels"]["variance_ratio"] - 1).abs() < 0.1).all(), a["channels"]
    # the unknown intensities: each disturbance's std within 3 of its se of the 1 N simulated
    found = re.findall(r"disturbance (w\d) std ([0-9.e+-]+) \+- ([0-9.e+-]+) N", r.description)
    assert len(found) == 3, r.description
    for name, v, se in found:
        assert abs(float(v) - 1.0) < 3 * float(se), (name, v, se)


def test_ekf_on_the_same_capture(white):
    """Why auto does not keep the EKF here: on this chain it is far off (or flagged)."""
    st, data = white
    r = vibid.identify(st, data, method="ekf")
    z = (r.parameters["value"] - pd.Series(TRUTH)) / r.parameters["se"]
    rel = r.parameters["value"] / pd.Series(TRUTH) - 1
    # measured: flagged U (its error bars do not hold), dampers off by tens of percent
    assert "U" in r.flags or (z.abs() > 3).any() or (rel.abs() > 0.05).any(), (r.flags, rel)
    # the EKF's estimate is not validated by a simulation (it would mean nothing here)
    assert r.adequacy.get("unavailable", "").startswith("a stand with disturbances")


@pytest.mark.parametrize("amplitude", [1.0, 2.0])
def test_coloured_excitation_is_flagged(tmp_path, amplitude):
    """A band-limited force (1..80 Hz) on m1 beside the white ones: the model's white held
    disturbances do not explain it, and the result is never a plain row. Measured: 1 N, the fit
    succeeds with d1 pulled to 1.28 (truth 4, 7 se) and the held-out innovations are not white
    (23 % of their variance predictable): flag M; 2 N, the fit of the first part drives d1 to its
    bound and fails, the EKF's estimate stands, flagged (P, U: k3 = 134 +- 2.8e5)."""
    st, data = capture(tmp_path, stand_text(
        f'excitation = ( {{ target = "w1"; kind = "noise"; amplitude = {amplitude}; f_low = 1.0; f_high = 80.0; }} );'),
        "coloured")
    r = vibid.identify(st, data)
    if amplitude == 1.0:
        assert r.config["method"] == "oe"
        assert r.adequacy["flag"] == "M", r.adequacy["why"]
        assert "M" in r.flags
    else:
        assert "failed" in r.config["choice"]
        assert r.flags != "", r.parameters


def test_method_oe_and_noise_given(white, tmp_path):
    """method="oe" runs the same fit; a declared disturbance std and sensor noise are used,
    not estimated (the description says declared)."""
    st, data = white
    text = stand_text().replace('true_std = 1.0;', 'std = 1.0;')
    cfg = tmp_path / "declared.cfg"
    cfg.write_text(text)
    st2 = vibid.Stand.load(cfg)
    r = vibid.identify(st2, data, method="oe")
    assert r.config["method"] == "oe"
    assert "disturbance w1 std 1 N (declared)" in r.description
    z = (r.parameters["value"] - pd.Series(TRUTH)) / r.parameters["se"]
    assert (z.abs() < 3).all(), z
    assert np.isfinite(r.parameters["se"]).all()
