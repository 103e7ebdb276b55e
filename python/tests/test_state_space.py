"""A stand that is not fully measured: the state-space estimators (EKF, KF+RLS) through
identify. Two masses in a chain on the ground, a force and a displacement sensor on the
upper one, no sensor on the lower one (docs/stand-file.md, "A partially measured stand",
without its disturbance); c1 unknown, started 17 % low."""

from __future__ import annotations

import numpy as np

import vibid
from conftest import multisine, steady_state

C1 = 1.2e5
STAND = {
    "name": "partially_measured", "sample_rate": 1000.0,
    "nodes": [{"name": "m1", "mass": 5.0, "measure": {"displacement": "x1"}, "noise": {"displacement": 1e-6}},
              {"name": "m2", "mass": 20.0}],
    "elements": [
        {"name": "c1", "kind": "spring", "between": ["m1", "m2"], "unknown": True, "value": 1.0e5, "true_value": C1},
        {"name": "d1", "kind": "damper", "between": ["m1", "m2"], "value": 50.0},
        {"name": "c2", "kind": "spring", "between": ["m2", "ground"], "value": 4.0e5},
        {"name": "d2", "kind": "damper", "between": ["m2", "ground"], "value": 200.0}],
    "inputs": [{"name": "f1", "node": "m1", "channel": "F1"}],
}


def capture(n=30000, seed=3):
    """30 s at 1 kHz of a 40-line multisine force (1..40 Hz, modes at 18.1 and 30.7 Hz),
    x1 with the declared 1e-6 m noise (x1 RMS 1.5e-3 m)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 1000.0
    d1, c2, d2 = 50.0, 4.0e5, 200.0
    M = np.diag([5.0, 20.0])
    D = np.array([[d1, -d1], [-d1, d1 + d2]])
    C = np.array([[C1, -C1], [-C1, C1 + c2]])
    freqs = np.linspace(1.0, 40.0, 40)
    amps, phases = multisine(rng, freqs, 10.0)
    y = steady_state(M, D, C, [[1.0], [0.0]], freqs, amps, phases, t)
    F = sum(amps[0][i] * np.sin(2 * np.pi * f * t + phases[0][i]) for i, f in enumerate(freqs))
    return {"x1": y[:, 0] + 1e-6 * rng.standard_normal(n), "F1": F}


def test_auto_chooses_ekf_and_finds_c1():
    st = vibid.Stand.from_dict(STAND)
    # holdout=0: the library's automatic estimator alone (auto's validated choice between it
    # and the output-error fit is test_output_error.py's)
    r = vibid.identify(st, capture(), holdout=0)
    assert r.config["method"] == "auto(ekf)"  # m2 has no sensor: the regression cannot be formed
    assert r.description.startswith("estimator: extended Kalman filter")
    err = r.parameters.loc["c1", "value"] / C1 - 1
    # Measured +0.043 %. The filter takes the force as linear between samples; the
    # multisine's lines up to 40 Hz at 1 kHz bend by up to (w h)^2 / 8 = 0.8 % of their
    # amplitude within a sample, which is what is left at this low noise: 0.2 %.
    assert abs(err) < 2e-3, err
    assert len(r.tracks) == 300  # recursive: a row every 0.1 s by default
    assert r.diverged_samples == 0
    # the start, 17 % low, is left behind within the first quarter of the run
    early = r.tracks["c1"].iloc[75:]
    assert (np.abs(early / C1 - 1) < 1e-2).all(), early.describe()


def test_kf_rls_is_flagged_and_close():
    st = vibid.Stand.from_dict(STAND)
    r = vibid.identify(st, capture(), method="kf_rls")
    assert r.config["method"] == "kf_rls"
    # README: the KF+RLS's standard errors are the regression's on filtered regressors,
    # every row flagged U; and weaker than the EKF with an unmeasured node (measured
    # -0.94 % here; 2 %).
    assert "U" in r.flags and all("U" in f for f in r.tracks["flags"])
    err = r.parameters.loc["c1", "value"] / C1 - 1
    assert abs(err) < 2e-2, err


def test_no_true_value_no_z():
    # Without true_value the nominal value is a start value, not a truth: no z.
    d = dict(STAND)
    d["elements"] = [dict(e) for e in STAND["elements"]]
    del d["elements"][0]["true_value"]
    st = vibid.Stand.from_dict(d)
    assert st.nominal_values == [1.0e5]
    assert np.isnan(st.true_values[0])
    r = vibid.identify(st, capture(n=5000), method="ekf", track_every=0)
    assert np.isnan(r.parameters.loc["c1", "true_value"]) and np.isnan(r.parameters.loc["c1", "z"])
    assert np.isfinite(r.parameters.loc["c1", "value"])
    assert len(r.tracks) == 0  # track_every=0: none, even for a recursive estimator
