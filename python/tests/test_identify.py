"""vibid.identify against the truth of exactly simulated stands (conftest.py)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

import vibid
from conftest import EX1_TRUTH, EXAMPLE1, example1_capture, example1_modes


def rel_err(result):
    p = result.parameters
    return (p["value"] / p["true_value"] - 1.0).to_dict()


def test_auto_noise_free_example1(example1_stand, ex1_clean):
    data, _ = ex1_clean
    # holdout=0: the library's automatic estimator alone (what vibidd runs); auto's validated
    # choice with the output-error fit is test_output_error.py's
    r = vibid.identify(example1_stand, data, holdout=0)
    assert r.method == "auto(iv)" and r.config["requested"] == "auto"
    # what auto chose, in the library's words (identify.h: IV with block statistics)
    assert r.description.startswith("estimator: instrumental variables with block statistics")
    assert r.config["prefilter_hz"] == 100.0  # f_a / 20: the stand gives no nominal values
    assert list(r.parameters.index) == ["c1", "d", "c2"]
    assert list(r.parameters["unit"]) == ["N/m", "N s/m", "N/m"]
    err = rel_err(r)
    # Noise-free exact samples: what is left is the five-point stencils' bias,
    # (w h)^4 / 30 = 1.2e-5 at the 48 Hz mode (w h = 0.15), and the pre-filter's
    # discretization; 1e-3 relative leaves a factor of ~80 and still catches any mix-up of
    # channels or units (those give tens of percent).
    for name, e in err.items():
        assert abs(e) < 1e-3, (name, e)
    # The library's error bars include that bias bound: the truth lies within 3 of them
    # (README "Right answers by default": noise-free, every estimate within 3 se).
    assert (r.parameters["z"].abs() < 3).all(), r.parameters
    assert (r.parameters["se"] > 0).all()
    # covariance consistent with the standard errors
    np.testing.assert_allclose(np.sqrt(np.diag(r.covariance)), r.parameters["se"], rtol=1e-12)
    assert r.covariance.shape == (3, 3)
    np.testing.assert_allclose(r.covariance, r.covariance.T, rtol=1e-12, atol=0)


def test_modes_against_numpy_eigenvalues(example1_stand, ex1_clean):
    data, _ = ex1_clean
    r = vibid.identify(example1_stand, data, holdout=0)
    f, zeta = example1_modes()  # numpy's eigenvalues at the truth, not the C modal code
    # The modes inherit the parameters' 1e-3 (frequencies go with sqrt(c): half of it);
    # the damping ratios go with d, which is the least accurate parameter: 2e-3.
    np.testing.assert_allclose(r.modes["freq_hz"], f, rtol=1e-3)
    np.testing.assert_allclose(r.modes["zeta"], zeta, rtol=2e-3)
    assert (r.modes["freq_hz_se"] > 0).all() and (r.modes["zeta_se"] > 0).all()
    # and the truth within 3 of the propagated standard errors, as for the parameters
    assert (np.abs(r.modes["freq_hz"] - f) < 3 * r.modes["freq_hz_se"]).all(), r.modes
    assert list(r.modes["flags"]) == ["", ""]


def test_auto_with_noise_truth_within_3_se(example1_stand):
    # 0.5 % white noise on every channel (as README's ident.default table). The automatic
    # estimator's 2-se bars covered 95 % over 200 realisations on three stands; 3 se is the
    # 99.7 % bound, and the seed is fixed, so this test is deterministic.
    data, _ = example1_capture(noise=0.005, seed=2)
    r = vibid.identify(example1_stand, data, holdout=0)
    assert (r.parameters["z"].abs() < 3).all(), r.parameters
    # and the estimate is still useful: within 1 % (README: automatic, 0.5 % noise, errors
    # of 0.01-0.4 % on the test stands)
    for name, e in rel_err(r).items():
        assert abs(e) < 1e-2, (name, e)
    # 20,000 samples give enough blocks and the halves agree: the bars count as valid
    assert "U" not in r.flags, (r.flags, r.z_consistency)


def test_ls_is_flagged_U(example1_stand, ex1_clean):
    # LS reports textbook errors that assume white equation errors: every row is flagged U
    # (identify.h, VIBID_QUALITY_SE_INVALID), in the whole flags and per parameter.
    data, _ = ex1_clean
    r = vibid.identify(example1_stand, data, method="ls", prefilter_hz=0)
    assert r.method == "ls"
    assert "U" in r.flags
    assert all("U" in f for f in r.parameters["flags"])
    assert r.config["difference_order"] == 4  # five-point stencils stay automatic
    # Noise-free, no pre-filter: the stencils' bias (w h)^4 / 30 = 1.2e-5 at 48 Hz is all
    # there is (measured 6.6e-5 on every parameter); 1e-3 as for auto. The textbook errors
    # miss that bias (measured |z| 3.6-3.75): why LS rows are flagged U.
    for name, e in rel_err(r).items():
        assert abs(e) < 1e-3, (name, e)


def test_rls_tracks_converge(example1_stand, ex1_clean):
    data, _ = ex1_clean
    r = vibid.identify(example1_stand, data, method="rls", track_every=2000)
    tr = r.tracks
    n = len(data["x1"])
    assert len(tr) == n // 2000
    expected = ["time_s", "index", "c1", "c1_se", "d", "d_se", "c2", "c2_se",
                "f1_hz", "f1_hz_se", "zeta1", "zeta1_se", "f2_hz", "f2_hz_se", "zeta2", "zeta2_se", "flags"]
    assert list(tr.columns) == expected  # the daemon's tracks columns (docs/vibidd.md)
    assert list(tr["index"]) == list(range(1999, n, 2000))
    np.testing.assert_allclose(tr["time_s"], tr["index"] / 2000.0)
    # the last row is the result itself (same estimate, same samples)
    last = tr.iloc[-1]
    for p in ["c1", "d", "c2"]:
        assert last[p] == r.parameters.loc[p, "value"]
    # RLS on the automatic pre-filter and stencils, noise-free: within 1e-3 from the first
    # second on (README: RLS noise-free with the automatic prior, errors of 1e-5..1e-3 relative)
    for p in ["c1", "d", "c2"]:
        err = np.abs(tr[p] / EX1_TRUTH[p] - 1)
        assert (err < 1e-3).all(), (p, err.max())
    # measured: largest |error| over all rows 1.9e-5 (c2)
    assert all("U" in f for f in tr["flags"])  # RLS: textbook errors, flagged


def test_rls_tracks_with_noise(example1_stand):
    # 0.5 % noise: the standard errors shrink as the samples come (about as 1/sqrt(N): ten
    # times the samples, a third; measured c1 119.6 -> 22.9 N/m, 0.19), and the estimates
    # stay within 1 % all along (measured: largest 0.28 %, d after the first second).
    data, _ = example1_capture(noise=0.005, seed=2)
    tr = vibid.identify(example1_stand, data, method="rls", track_every=2000).tracks
    for p in ["c1", "d", "c2"]:
        assert tr[p + "_se"].iloc[-1] < 0.5 * tr[p + "_se"].iloc[0], (p, tr[p + "_se"].iloc[[0, -1]])
        assert (np.abs(tr[p] / EX1_TRUTH[p] - 1) < 1e-2).all(), (p, tr[p])


def test_default_tracks_for_recursive_settings(example1_stand, ex1_clean):
    data, _ = ex1_clean
    assert len(vibid.identify(example1_stand, data).tracks) == 0  # batch: no tracks
    r = vibid.identify(example1_stand, data, forgetting=0.9995)
    assert len(r.tracks) == 20000 // 200  # every 0.1 s at 2 kHz
    assert r.config["forgetting"] == 0.9995


def test_block_and_strided_paths_agree(example1_stand, ex1_clean):
    # The dict is gathered into one column-major block and pushed by vibid_ident_push_block;
    # a C-order 2-D array goes through the strided row loop. Same samples, same estimator:
    # bit-identical results, or the strides are wrong.
    data, _ = ex1_clean
    r_block = vibid.identify(example1_stand, data)
    arr = np.column_stack([data[c] for c in example1_stand.channels])  # C order
    assert arr.flags.c_contiguous and not arr.flags.f_contiguous
    r_rows = vibid.identify(example1_stand, arr)
    np.testing.assert_array_equal(r_rows.parameters["value"], r_block.parameters["value"])
    np.testing.assert_array_equal(r_rows.parameters["se"], r_block.parameters["se"])
    np.testing.assert_array_equal(r_rows.covariance, r_block.covariance)
    # Tracks push ranges of rows and estimate in between; an estimate in between rounds the
    # estimator's running sums differently (measured: 1.8e-15 relative), so 1e-12 here; a
    # row range off by one sample would move the estimate by far more.
    r_tracked = vibid.identify(example1_stand, data, track_every=777)
    np.testing.assert_allclose(r_tracked.parameters["value"], r_block.parameters["value"], rtol=1e-12, atol=0)
    np.testing.assert_allclose(r_tracked.parameters["se"], r_block.parameters["se"], rtol=1e-9, atol=0)


def test_dataframe_csv_and_dict_stand(tmp_path, example1_stand, ex1_clean):
    data, t = ex1_clean
    ref = vibid.identify(example1_stand, data)
    df = pd.DataFrame({"t": t, **data})
    r_df = vibid.identify(example1_stand, df)
    np.testing.assert_array_equal(r_df.parameters["value"], ref.parameters["value"])
    csv = tmp_path / "capture.csv"
    df.to_csv(csv, index=False, float_format="%.17g")  # round-trips doubles exactly
    r_csv = vibid.identify(str(EXAMPLE1), csv)  # stand given as a path too
    np.testing.assert_array_equal(r_csv.parameters["value"], ref.parameters["value"])
    # the same stand as a dict: one reader (the C loader), so the same model
    stand_dict = {
        "name": "paper_example1", "sample_rate": 2000.0, "discretization": "central_difference",
        "nodes": [{"name": "m1", "mass": 10.0, "measure": {"displacement": "x1"}},
                  {"name": "m2", "mass": 20.0, "measure": {"displacement": "x2"}}],
        "base": {"measure": {"displacement": "s"}},
        "elements": [
            {"name": "c1", "kind": "spring", "between": ["m1", "m2"], "unknown": True, "true_value": 2.5e5},
            {"name": "d", "kind": "damper", "between": ["m1", "m2"], "unknown": True, "true_value": 300.0},
            {"name": "c2", "kind": "spring", "between": ["m2", "base"], "unknown": True, "true_value": 1.5e6},
        ],
    }
    st = vibid.Stand.from_dict(stand_dict)
    assert st.channels == ["x1", "x2", "s"] and st.parameters == ["c1", "d", "c2"]
    assert st.true_values == [2.5e5, 300.0, 1.5e6]
    r_dict = vibid.identify(st, data)
    np.testing.assert_array_equal(r_dict.parameters["value"], ref.parameters["value"])


def test_repr_and_description(example1_stand, ex1_clean):
    data, _ = ex1_clean
    r = vibid.identify(example1_stand, data)
    text = repr(r)
    assert "paper_example1" in text and "c1" in text and "freq_hz" in text
    html = r._repr_html_()
    assert "<table" in html and "c2" in html
    # the estimator's own account (vibid_ident_describe), one line per choice
    assert "estimator" in r.description
    assert r.description.count("\n") >= 2


def test_stand_properties(example1_stand):
    s = example1_stand
    assert s.name == "paper_example1"
    assert s.sample_rate == 2000.0
    assert s.channels == ["x1", "x2", "s"]
    assert s.parameters == ["c1", "d", "c2"]
    assert s.kinds == ["stiffness", "damping", "stiffness"]
    assert s.true_values == [2.5e5, 300.0, 1.5e6]
    assert all(math.isnan(v) for v in s.nominal_values)  # the file gives no start values
    assert s.n_dof == 2
    # one version: the C library's (top-level CMakeLists.txt) is the package's (pyproject.toml)
    from importlib.metadata import version
    assert vibid.__version__ == version("vibid")


def test_explicit_iv_settings(example1_stand):
    # The README's hand-tuned choice for example 1 (IV, 150 Hz pre-filter, lag 30): the
    # settings reach the library as given, and with 0.5 % noise the truth is within 3 se.
    data, _ = example1_capture(noise=0.005, seed=2)
    r = vibid.identify(example1_stand, data, method="iv", prefilter_hz=150.0, iv_lag=30)
    assert r.config["method"] == "iv"
    assert r.config["prefilter_hz"] == 150.0 and r.config["iv_lag"] == 30
    assert "150 Hz" in r.description
    assert (r.parameters["z"].abs() < 3).all(), r.parameters


def test_dataframe_block_is_not_copied(example1_stand, ex1_clean):
    # A DataFrame built from float64 columns holds them in one block; the channels come out
    # as a column-major view of it, which goes to vibid_ident_push_block as it is.
    from vibid._identify import _columns
    data, _ = ex1_clean
    df = pd.DataFrame(data)
    block, t = _columns(example1_stand, df)
    assert t is None
    assert block.flags.f_contiguous
    assert np.shares_memory(block, df["x1"].to_numpy())
    # a dict of separate arrays needs the one gather copy
    block2, _ = _columns(example1_stand, data)
    assert block2.flags.f_contiguous and not np.shares_memory(block2, data["x1"])
    np.testing.assert_array_equal(block, block2)


def test_methods_are_the_librarys_names():
    """vibid.METHODS is the library's name table (identify.h, vibid_estimator_name), "auto"
    first: each name maps to the code the library gives it, and no name is spelled here."""
    from vibid import _core
    names = _core.estimator_names()
    assert names == ["ls", "iv", "rls", "auto", "ekf", "kf_rls", "oe"]
    assert list(vibid.METHODS)[0] == "auto"
    assert sorted(vibid.METHODS) == sorted(names)
    assert all(names[code] == name for name, code in vibid.METHODS.items())
    assert vibid.METHODS["kf_rls"] == _core.ESTIMATOR_KF_RLS
