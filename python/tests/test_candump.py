"""candump captures with their DBC (issue 13): decoded by the drivers' replay source, the code
`vibidd --replay` runs, and identified like any other capture.

The captures are one vibid-sim run of examples/stands/paper_example1.cfg with
sim/examples/paper_example1_sim.cfg, written both as CSV (17 digits) and as a candump log of
the frames sim/paper_example1.dbc describes (float32 signals). vibid-sim is the suite's own
build (VIBID_SIM, else $VIBID_BUILD_ROOT/werror/sim/vibid-sim); without it these tests are
skipped and say why."""

from __future__ import annotations

import subprocess
import warnings

import numpy as np
import pandas as pd
import pytest

import vibid
from vibid import _core
from conftest import EXAMPLE1, REPO, sim_path

SIMCFG = REPO / "sim" / "examples" / "paper_example1_sim.cfg"
DBC = REPO / "sim" / "paper_example1.dbc"
EPOCH = 1700000000

needs_drivers = pytest.mark.skipif(not _core.HAVE_DRIVERS, reason="vibid built without the drivers")


def sim_capture(out, seconds=10, **_):
    """vibid-sim's CSV and candump log of one run; (csv, log)."""
    sim = sim_path()
    if not sim.exists():
        pytest.skip(f"no vibid-sim at {sim} (build the C suite first, or set VIBID_SIM)")
    csv, log = out / "ex1.csv", out / "ex1.log"
    subprocess.run([str(sim), "-c", str(EXAMPLE1), "-s", str(SIMCFG), "--duration", str(seconds), "--csv", str(csv),
                    "--candump", str(log), "--epoch", str(EPOCH), "--fast", "-q"], check=True, capture_output=True,
                   timeout=120)
    return csv, log


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return sim_capture(tmp_path_factory.mktemp("candump"))


@pytest.fixture(scope="module")
def stand():
    return vibid.Stand.load(EXAMPLE1)


def float32(df, channels):
    out = df.copy()
    for c in channels:
        out[c] = out[c].to_numpy().astype(np.float32).astype(np.float64)
    return out


@needs_drivers
def test_candump_is_the_csv_in_float32(run, stand):
    csv, log = run
    df = vibid.read_capture(log, stand, dbc=DBC)
    ref = vibid.read_capture(csv, stand)
    assert list(df.columns) == ["x1", "x2", "s", "time_s"]
    assert len(df) == len(ref) == 20000  # 10 s at 2 kHz, every sample
    assert df.attrs["counter"] == "SampleCounter"  # found as vibid-sim's DBC names it
    assert df.attrs["gaps"] == [] and df.attrs["faults"] == []
    assert df.attrs["stats"]["frames"] == 60000  # three classic frames per sample
    assert df.attrs["start_time_ns"] == EPOCH * 10**9
    # The frames carry float32 (SIG_VALTYPE_ 1): the CSV's doubles rounded to float32, exactly.
    np.testing.assert_array_equal(df[stand.channels].to_numpy(), float32(ref, stand.channels)[stand.channels].to_numpy())
    # time: from the log's microsecond stamps, seconds since the first sample; the CSV's k h
    # to the rounding of k h in double (k h is exact in microseconds at 2 kHz)
    np.testing.assert_allclose(df["time_s"], ref["time_s"], rtol=0, atol=1e-12)


@needs_drivers
def test_identify_candump_equals_csv(run, stand):
    csv, log = run
    can = vibid.identify(stand, log, dbc=DBC)
    # The same samples as float32 from the CSV: the same estimate, bit for bit.
    ref32 = vibid.identify(stand, float32(vibid.read_capture(csv, stand), stand.channels))
    np.testing.assert_array_equal(can.parameters["value"], ref32.parameters["value"])
    np.testing.assert_array_equal(can.parameters["se"], ref32.parameters["se"])
    np.testing.assert_array_equal(can.covariance, ref32.covariance)
    # Against the double CSV: float32 rounds each sample by at most 2^-24 = 6e-8 relative.
    # The run has 60 dB noise on x1, x2 (sigma = 1e-3 RMS), so the rounding is a perturbation
    # of at most 6e-5 sigma per sample; through the estimator (theta = S y, se = sigma |S|)
    # it moves a parameter by at most se * 6e-5 * sqrt(N) = 8.5e-3 se for N = 20000 (all
    # roundings aligned with S), and by about 6e-5 se when they are random. Asserted 1e-2 se;
    # measured 7.8e-6 se (c1).
    ref = vibid.identify(stand, csv)
    dz = np.abs(can.parameters["value"] - ref.parameters["value"]) / ref.parameters["se"]
    assert dz.max() < 1e-2, dz
    assert can.flags == ref.flags


@needs_drivers
def test_gap_is_nan_rows_and_identify_refuses(run, stand, tmp_path):
    _, log = run
    lines = log.read_text().splitlines(keepends=True)
    assert len(lines) == 60000  # sample k is lines 3k .. 3k+2 (ids 100, 101, 102)
    # samples 5000..5009 cut out whole, and the x2 frame (id 101) of sample 7000
    cut = [ln for i, ln in enumerate(lines) if not (15000 <= i < 15030 or i == 3 * 7000 + 1)]
    gap = tmp_path / "gap.log"
    gap.write_text("".join(cut))
    full = vibid.read_capture(log, stand, dbc=DBC)
    df = vibid.read_capture(gap, stand, dbc=DBC)
    assert len(df) == 20000  # the missing samples are rows, never bridged
    missing = df[stand.channels].isna().all(axis=1)
    assert list(np.flatnonzero(missing)) == [*range(5000, 5010), 7000]
    assert df["time_s"][missing].isna().all()  # no invented times either
    # every other row is the full log's, unchanged
    pd.testing.assert_frame_equal(df[~missing], full[~missing], check_exact=True)
    g = df.attrs["gaps"]
    assert [(x["row"], x["count"]) for x in g] == [(5000, 10), (7000, 1)]
    assert g[0]["after_time_s"] == pytest.approx(2.4995, abs=1e-12)
    assert "counter jump" in g[0]["text"] and "gap.log:15001" in g[0]["text"]
    assert "incomplete sample: missing paper_example1_1" in g[1]["text"]
    with pytest.raises(ValueError, match=r"gap\.log: 10 sample\(s\) missing at rows 5000\.\.5009 "
                                         r"\(after t = 2\.499500 s\): counter jump.*never bridges a gap"):
        vibid.identify(stand, gap, dbc=DBC)
    # the part before the gap is the full log's first 5000 samples: the same estimate
    a = vibid.identify(stand, df.iloc[:5000], track_every=0)
    b = vibid.identify(stand, full.iloc[:5000], track_every=0)
    np.testing.assert_array_equal(a.parameters["value"], b.parameters["value"])


@needs_drivers
def test_faults_are_reported(run, stand, tmp_path):
    _, log = run
    lines = log.read_text().splitlines(keepends=True)
    # a frame repeated (DUPLICATE: the first value kept) and a garbage line (BAD_LINE)
    bad = tmp_path / "faults.log"
    bad.write_text("".join(lines[:300] + [lines[299], "garbage\n"] + lines[300:]))
    with pytest.warns(UserWarning, match=r"faults\.log: 2 fault\(s\) reported.*duplicate 1.*bad_line 1"):
        df = vibid.read_capture(bad, stand, dbc=DBC)
    kinds = [f["kind"] for f in df.attrs["faults"]]
    assert sorted(kinds) == ["bad_line", "duplicate"]
    assert any("faults.log:302" in f["text"] for f in df.attrs["faults"])  # the garbage line
    # neither became a sample: the data are the undisturbed log's
    pd.testing.assert_frame_equal(df, vibid.read_capture(log, stand, dbc=DBC), check_exact=True)


@needs_drivers
def test_channel_map_file(run, stand, tmp_path):
    _, log = run
    full = vibid.read_capture(log, stand, dbc=DBC)
    # A channel-map file (docs/drivers.md) read by vibid_chanmap_read_file: x1 declared in
    # mm (as if the logger had sent mm), so read_capture converts it to the stand's m.
    cmap = tmp_path / "map.cfg"
    cmap.write_text("""counter = "SampleCounter";
channels = (
  { name = "x1"; quantity = "displacement"; node = 0; unit = "mm"; signal = "x1"; message = "paper_example1_0"; },
  { name = "x2"; quantity = "displacement"; node = 1; signal = "x2"; },
  { name = "s";  quantity = "base_displacement"; unit = "m"; signal = "s"; }
);
""")
    df = vibid.read_capture(log, stand, dbc=DBC, channel_map=cmap)
    np.testing.assert_array_equal(df["x1"], full["x1"] * 1e-3)
    np.testing.assert_array_equal(df[["x2", "s"]], full[["x2", "s"]])
    # the reader's own errors: file:line: field: reason
    cmap.write_text('channels = ( { name = "x1"; quantity = "forse"; node = 0; signal = "x1"; } );\n')
    with pytest.raises(ValueError, match=r"map\.cfg:1: channels\.\[0\]\.quantity: 'forse'"):
        vibid.read_capture(log, stand, dbc=DBC, channel_map=cmap)
    cmap.write_text('counter = "SampleCounter";\nchannels = ( { name = "x1"; quantity = "displacement"; node = 0; '
                    'signal = "x1"; } );\n')
    with pytest.raises(ValueError, match=r"map\.cfg: no channel 'x2', which the stand reads"):
        vibid.read_capture(log, stand, dbc=DBC, channel_map=cmap)


@needs_drivers
def test_bad_inputs(run, stand, tmp_path):
    _, log = run
    with pytest.raises(FileNotFoundError, match="DBC file not found.*nowhere.dbc"):
        vibid.read_capture(log, stand, dbc=tmp_path / "nowhere.dbc")
    with pytest.raises(ValueError, match=r"needs its DBC"):
        vibid.read_capture(log, stand)
    # a DBC of another stand: no signal x2 (here renamed y2); the message names the signal
    other = tmp_path / "other.dbc"
    other.write_text(DBC.read_text().replace(" x2 ", " y2 "))
    with pytest.raises(ValueError, match=r"other\.dbc has no signal 'x2' \(its signals: .*paper_example1_1\.y2"):
        vibid.read_capture(log, stand, dbc=other)
    # renamed: channels={stand channel: DBC signal}
    df = vibid.read_capture(log, stand, dbc=other, channels={"x2": "y2"})
    pd.testing.assert_frame_equal(df, vibid.read_capture(log, stand, dbc=DBC), check_exact=True)
    with pytest.raises(ValueError, match=r"other\.dbc has no signal 'y1' \(the stand's channel 'x1'\)"):
        vibid.read_capture(log, stand, dbc=other, channels={"x1": "y1", "x2": "y2"})
    # a malformed DBC: the drivers' file:line: reason
    broken = tmp_path / "broken.dbc"
    broken.write_text(DBC.read_text().replace("SG_ x1 : 16|32@1-", "SG_ x1 : 16|99@1-"))
    with pytest.raises(ValueError, match=r"broken\.dbc:\d+: "):
        vibid.read_capture(log, stand, dbc=broken)
    with pytest.raises(ValueError, match=r"dbc= and channel_map= are for candump logs"):
        vibid.read_capture(run[0], stand, dbc=DBC)


def test_built_without_drivers(monkeypatch, tmp_path, stand):
    # What a plain `pip install ./python` without libmodbus-dev gives (the module has no
    # read_candump / replay_run then): the error says what is missing and how to get it.
    monkeypatch.setattr(_core, "HAVE_DRIVERS", False)
    log = tmp_path / "c.log"
    log.write_text("(1700000000.000000) can0 123#00\n")  # a log line (an empty file is refused first)
    with pytest.raises(ImportError, match=r"reading the candump log .*c\.log: vibid was built without the drivers .*libmodbus-dev"):
        vibid.read_capture(log, stand, dbc=DBC)
    with pytest.raises(ImportError, match=r"vibid\.replay: vibid was built without the drivers"):
        vibid.replay(tmp_path / "v.cfg")
    monkeypatch.setattr(_core, "HAVE_DRIVERS", True)
    monkeypatch.setattr(_core, "HAVE_DAEMON", False)
    with pytest.raises(ImportError, match=r"vibidd's core \(libvibidd_core\).*libvibidd_core\.a"):
        vibid.replay(tmp_path / "v.cfg")
