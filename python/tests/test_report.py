"""The HTML report of `vibid identify --report` (issue 33, item 4): digits from the standard
error, no column without information, a flag summary that counts what the tracks hold, a
verdict that agrees with the flags, tracks scaled to the converged estimate, the measured
FRF against the identified model's, units on the axes, and a page that headless Chromium
renders without a console error."""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess

import numpy as np
import pandas as pd
import pytest

import vibid
from conftest import EXAMPLE1
from test_cli import capture  # noqa: F401  (the fixture: 10 s of example 1, noise-free)
from vibid import _cli

matplotlib = pytest.importorskip("matplotlib")  # the extra `plot`; pinned in the test venv


def test_digits_follow_the_standard_error():
    f = _cli.fmt_with_se
    assert f(1234.5678, 0.01234) == ("1234.568", "0.012")
    assert f(300.01234, 0.98) == ("300.01", "0.98")
    assert f(300.01234, 0.0999) == ("300.01", "0.10")  # the se rounded before its place is taken
    assert f(2.5e5, 123.0) == ("250000", "120")
    # outside 1e-4..1e6: scientific with one exponent for both
    assert f(1.5000125e6, 6.1) == ("1500012.5", "6.1")
    assert f(1.5e10, 1234.0) == ("1.50000000e+10", "1.2e+03")
    assert f(3.2e-7, 1.1e-9) == ("3.200e-07", "1.1e-09")
    assert f(-7e-9, 2.1e-8) == ("-7e-09", "2.1e-08")
    # no usable se: 4 significant digits of the value
    assert f(1.23456789, math.inf) == ("1.235", "inf")
    assert f(1.23456789, math.nan) == ("1.235", "nan")


def test_html_table_leaves_out_columns_without_information():
    df = pd.DataFrame({"value": [1.0, 2.0], "se": [0.1, 0.2], "true_value": [math.nan, math.nan],
                       "z": [math.nan, math.nan], "flags": ["", ""], "unit": ["N/m", "<b>"]},
                      index=pd.Index(["k", "d"], name="parameter"))
    t = _cli._html_table(df, {"value": "se"})
    heads = re.findall(r"<th>([^<]*)</th>", t)
    assert "true_value" not in heads and "z" not in heads and "flags" not in heads
    assert "value" in heads and "se" in heads and "unit" in heads
    assert "&lt;b&gt;" in t and "<b>" not in t  # text escaped
    assert "<td>1.00</td>" in t and "<td>0.10</td>" in t


def test_track_ylim_holds_the_final_band_and_leaves_out_the_transient():
    from vibid._plot import track_ylim
    n = 400
    t = np.arange(n)
    v = 100.0 + 1e11 * np.exp(-t / 5.0)  # a start transient of 1e11 decaying to 100
    se = np.where(t < 10, 1e11, 0.5)
    lim = track_ylim(v, se, truth=100.2)
    assert lim is not None
    lo, hi = lim
    # the final band (100 +- 1) and the truth inside, the range far narrower than the whole
    assert lo <= 99.0 and hi >= 101.0 and lo <= 100.2 <= hi
    assert hi - lo < 3.0  # band 2 wide, padded by 10 % each side: 2.4
    # a track without transient: matplotlib's own limits
    assert track_ylim(np.full(n, 100.0), np.full(n, 0.5)) is None


@pytest.fixture(scope="module")
def rls_report(capture):
    """An RLS estimate (always U: its textbook error bars) with tracks from the nominal
    start, and its report written in-process."""
    res = vibid.identify(EXAMPLE1, capture, method="rls", track_every=200)
    block, _ = vibid._identify._columns(res.stand, capture)
    path = capture.parent / "rls.html"
    _cli.write_report(res, block, str(capture), str(path))
    return res, block, path.read_text()


def test_plot_scales_tracks_to_the_converged_estimate(rls_report):
    res, _, _ = rls_report
    fig = res.plot()
    tr = res.tracks
    clipped = 0
    for ax, name in zip(fig.axes, res.parameters.index):
        v, se = tr[name].to_numpy(float), tr[name + "_se"].to_numpy(float)
        lo, hi = ax.get_ylim()
        half = slice(len(v) // 2, None)
        ok = np.isfinite(se[half])
        # the second half's band and the truth inside the axis (to rounding)
        assert lo <= np.min((v - 2 * se)[half][ok]) + 1e-9 * abs(lo)
        assert hi >= np.max((v + 2 * se)[half][ok]) - 1e-9 * abs(hi)
        truth = res.parameters.loc[name, "true_value"]
        assert lo <= truth <= hi
        if any(t.get_gid() == f"clipped:{name}" for t in ax.texts):
            clipped += 1
            # narrower than the whole track's values and bands
            fin = np.isfinite(se)
            assert hi - lo < np.max((v + 2 * se)[fin]) - np.min((v - 2 * se)[fin])
    # RLS from the nominal values has a start transient on this capture
    assert clipped >= 1


def test_flag_summary_counts_the_tracks_flags(rls_report):
    res, _, doc = rls_report
    c = _cli.flag_counts(res)
    fl = res.tracks["flags"].astype(str)
    assert c["rows"] == len(res.tracks)
    for k in "EPUIRM":
        assert c[k]["tracks"] == sum(k in f for f in fl)
        assert c[k]["estimate"] == int(k in res.flags)
    title = re.search(r'<section id="flags"><h2>([^<]*)</h2>', doc).group(1)
    assert title == f"Flags and warnings: {_cli.flag_summary(res)}"
    assert "U" in res.flags and title != "Flags and warnings: none"
    for k in "EPUIRM":
        if c[k]["tracks"]:
            assert f"{c[k]['tracks']} {k}" in title
    # the verdict agrees: a flagged estimate is not trusted, and U is explained as RLS's
    verdict = re.search(r'<p id="verdict" class="(\w+)"><b>Verdict: ([^<]*)</b>', doc)
    assert verdict.group(1) == "bad" and verdict.group(2).startswith("not trusted")
    assert "RLS&#x27;s textbook covariance" in doc or "RLS's textbook covariance" in doc
    assert "older and newer halves" not in doc.split('<section id="flags">')[1].split("</section>")[0]


def test_tables_have_no_column_without_information(rls_report):
    _, _, doc = rls_report
    for table in re.findall(r'<table class="t"[^>]*>.*?</table>', doc, flags=re.S):
        rows = re.findall(r"<tr>(.*?)</tr>", table, flags=re.S)
        cells = [re.findall(r"<t[hd]>(.*?)</t[hd]>", r) for r in rows[1:]]
        for j in range(1, len(cells[0]) if cells else 0):
            assert not all(c[j] in ("nan", "") for c in cells), table[:300]
    # the parameters' values to the se's decimal place: at most 2 significant digits of se
    params = doc[doc.index('<section id="parameters">'):doc.index('<section id="modes">')]
    ses = re.findall(r"<tr><th>\w+</th><td>[^<]*</td><td>([^<]*)</td>", params)
    assert ses
    for s_ in ses:
        digits = re.sub(r"e[+-]\d+$", "", s_).replace(".", "").lstrip("0")
        assert len(digits) <= 2, s_


def test_every_axis_has_a_unit(rls_report):
    # The report's figures: every y label names a unit in brackets (or is dimensionless [-]).
    res, block, _ = rls_report
    sim, start = _cli.model_response(res, block)
    figs = [res.plot(), _cli._residual_figure(res, block)[0], _cli._spectrum_figure(res, block)[0],
            _cli._response_figure(res, block, sim, start), _cli._frf_figure(res, block, sim, start)[0]]
    for fig in figs:
        for ax in fig.axes:
            lab = ax.get_ylabel()
            if lab:
                assert re.search(r"\[[^\]]+\]", lab), lab
    res_fig = _cli._residual_figure(res, block)[0]
    assert any(ax.get_ylabel() == "PSD [N\u00b2/Hz]" for ax in res_fig.axes)
    # example 1 is base-excited: its input is the base displacement s, in the stand's m
    spec = _cli._spectrum_figure(res, block)[0]
    assert spec.axes[0].get_ylabel() == "PSD [m\u00b2/Hz]"
    frf = _cli._frf_figure(res, block, sim, start)[0]
    assert frf.axes[0].get_ylabel() == "|H| [m/m]"


def test_identified_frf_matches_the_measured_h1(rls_report, capture):
    # Example 1, noise-free multisine (40 lines, 2-160 Hz: conftest.example1_capture): the
    # IV/OE estimate's FRF from its matrices (vibid_model_frf) against the measured H1 at the
    # FFT bins nearest to the lines (between the lines Welch's H1 of a multisine is the
    # leakage of its neighbours, 0.6-1.04 times the true FRF there). Tolerance 0.5 dB: the
    # estimate is 1e-5 off; what is left is the Hann window's leakage of the neighbouring lines
    # into a line's bin and the bin's offset from the line (at most a quarter of the 3 Hz
    # half-power width at the resonances). Measured max 0.42 dB (x1) and 0.34 dB (x2), medians
    # 0.049 and 0.028 dB.
    res = vibid.identify(EXAMPLE1, capture)
    block, _ = vibid._identify._columns(res.stand, capture)
    sim, start = _cli.model_response(res, block)
    _, f, hm, hs, coh, pairs, source = _cli._frf_figure(res, block, sim, start)
    assert source == "matrices"
    assert pairs == [("s", "x1"), ("s", "x2")]
    lines = np.linspace(2.0, 160.0, 40)
    at = np.unique(np.round(lines / (f[1] - f[0])).astype(int))
    for o in range(hm.shape[1]):
        db = 20 * np.log10(np.abs(hs[at, o, 0]) / np.abs(hm[at, o, 0]))
        print(f"output {o}: model from its matrices - measured H1, at the {len(at)} lines' bins: "
              f"max {np.max(np.abs(db)):.3f} dB, median {np.median(np.abs(db)):.4f} dB")
        assert np.all(coh[at, o] > 0.9)
        assert np.max(np.abs(db)) < 0.5, np.max(np.abs(db))


def _chromium():
    for name in ("chromium", "chromium-browser"):
        p = shutil.which(name)
        if p:
            return p
    return None


def test_report_renders_in_headless_chromium(rls_report, tmp_path):
    # The page as a browser shows it: no console error, a screenshot written and not blank.
    chromium = _chromium()
    if chromium is None:
        pytest.skip("chromium not installed (scripts/install-deps.sh --test)")
    _, _, doc = rls_report
    page = tmp_path / "report.html"
    page.write_text(doc)
    shot = tmp_path / "shot.png"
    env = dict(os.environ, HOME=str(tmp_path))  # chromium's profile under tmp
    proc = subprocess.run([chromium, "--headless", "--disable-gpu", "--no-sandbox", "--enable-logging=stderr",
                           "--v=0", f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}",
                           "--window-size=1200,3000", "--hide-scrollbars", page.as_uri()],
                          capture_output=True, text=True, timeout=180, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    console = [ln for ln in proc.stderr.splitlines() if "CONSOLE" in ln or "Uncaught" in ln]
    assert not console, console
    assert shot.exists()
    from matplotlib.image import imread
    img = imread(str(shot))
    assert img.shape[1] == 1200 and img.shape[0] == 3000
    # not blank: many distinct grey levels, and far from all white
    grey = img[..., :3].mean(axis=2)
    assert grey.std() > 0.05 and (grey < 0.5).mean() > 0.002, (grey.std(), (grey < 0.5).mean())


def test_verdict_agrees_with_the_flags():
    # trusted exactly when neither the estimate nor a parameter or mode is flagged; flagged
    # track rows alone are named but leave it trusted
    from types import SimpleNamespace
    params = pd.DataFrame({"flags": ["", ""]}, index=["k", "d"])
    modes = pd.DataFrame({"flags": [""]}, index=[1])
    tracks = pd.DataFrame({"flags": ["P", "U", "", ""]})
    r = SimpleNamespace(flags="", parameters=params, modes=modes, tracks=tracks, method="auto(iv)")
    ok, why = _cli.verdict(r)
    assert ok and why.startswith("trusted") and "1 P, 1 U of the 4 track rows" in why
    assert _cli.flag_summary(r) == "track rows of 4: 1 P, 1 U"
    r.parameters = pd.DataFrame({"flags": ["", "I"]}, index=["k", "d"])
    ok, why = _cli.verdict(r)
    assert not ok and "flagged I" in why
    r.parameters, r.tracks = params, pd.DataFrame({"flags": ["", ""]})
    assert _cli.flag_summary(r) == "none" and _cli.verdict(r)[0]
    r.method, r.flags = "ekf", "U"
    ok, why = _cli.verdict(r)
    assert not ok and "sandwich variance" in why and "older and newer halves" not in why


def test_report_escapes_hostile_names(rls_report, tmp_path):
    # The loader keeps stand, node and channel names to A-Z a-z 0-9 _ - . (a stand named
    # '<script>' is refused); what reaches the page unchecked is the capture's path: text, never
    # markup.
    res, block, _ = rls_report
    path = tmp_path / "bad.html"
    _cli.write_report(res, block, "<script>alert(1)</script>&<b>.csv", str(path))
    doc = path.read_text()
    assert "<script" not in doc and "<b>.csv" not in doc
    assert "&lt;script&gt;alert(1)&lt;/script&gt;&amp;&lt;b&gt;.csv" in doc


def test_frf_h1_of_a_known_system_and_coherence_of_noise():
    # y = 2 x delayed by one sample: |H1| = 2 at every frequency, coherence 1; an independent
    # y: coherence near 0 (expected 1/K of K averaged segments), also on a capture too short for
    # one 4096-sample segment (one segment would give coherence 1 everywhere)
    rng = np.random.default_rng(5)
    for n in (3377, 40000):
        x = rng.standard_normal(n)
        y = 2.0 * np.concatenate([[0.0], x[:-1]])
        f, h, coh = _cli.frf_h1(x, y, 1000.0)
        k = slice(1, -1)
        np.testing.assert_allclose(np.abs(h[k, 0, 0]), 2.0, rtol=0.05)
        assert np.min(coh[k, 0]) > 0.95
        _, _, coh0 = _cli.frf_h1(x, rng.standard_normal(n), 1000.0)
        assert np.mean(coh0[k, 0]) < 0.25, np.mean(coh0[k, 0])
