"""`vibid convert ... OUT.log --dbc DBC`: any capture the package reads written as a candump -l
log by the drivers' CAN encoder (vibid_can_assembler_encode, what vibidd's candump recording
uses), read back by the package's candump reader (the drivers' replay source) and decoded
by cantools, the independent peer (never used for vibid's own encoding).

The DBC of the round trip is sim/paper_example1.dbc (the frames vibid-sim writes for example
1: SampleCounter and one signal per message) with its float32 signals made scaled integers,
so that the quantisation is a step: x1 Intel signed 16 bits, factor 1e-6 m, DBC range
[-0.03|0.03]; x2 Motorola signed 16 bits, 1e-6 m, no range; s unsigned 16 bits in mm,
factor 0.001, offset -30 (the stand is in m: converted). The second DBC is cantools'
motohawk.dbc from the shared test data (../shared/testdata/dbc, written elsewhere): one
message, no counter, a Motorola signed signal with an offset."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import vibid
from vibid import _core
from conftest import EXAMPLE1, REPO, example1_capture

VIBID = Path(sys.executable).parent / "vibid"
SHARED_DBC = Path(os.environ.get("VIBID_DBC_TESTDATA_DIR", REPO.parent / "shared" / "testdata" / "dbc"))

needs_drivers = pytest.mark.skipif(not _core.HAVE_DRIVERS, reason="vibid built without the drivers")

INT_DBC = """VERSION ""

NS_ :

BS_:

BU_: VibidSim

BO_ 256 paper_example1_0: 8 VibidSim
 SG_ SampleCounter : 0|16@1+ (1,0) [0|65535] "" Vector__XXX
 SG_ x1 : 16|16@1- (1e-06,0) [-0.03|0.03] "m" Vector__XXX

BO_ 257 paper_example1_1: 8 VibidSim
 SG_ SampleCounter : 0|16@1+ (1,0) [0|65535] "" Vector__XXX
 SG_ x2 : 23|16@0- (1e-06,0) [0|0] "m" Vector__XXX

BO_ 258 paper_example1_2: 8 VibidSim
 SG_ SampleCounter : 0|16@1+ (1,0) [0|65535] "" Vector__XXX
 SG_ s : 16|16@1+ (0.001,-30) [0|0] "mm" Vector__XXX
"""
# Half a step of each channel in the stand's units (m): the tolerance of the round trip.
# raw = round((v - offset) / factor) (vibid_dbc_signal_encode) and the reader's
# raw * factor + offset differ from v by at most factor / 2, plus the double rounding of that
# arithmetic (< 1e-17 m here), which the factor 1 + 1e-9 covers.
HALF_STEP = {"x1": 0.5e-6, "x2": 0.5e-6, "s": 0.5e-3 * 1e-3}
MISSING = range(5000, 5010)


def run(*args):
    return subprocess.run([str(VIBID), *map(str, args)], capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """The DBC and a CSV of example 1 (10 s at 2 kHz, written exactly) with rows 5000..5009
    missing (NaN values, their times kept)."""
    d = tmp_path_factory.mktemp("convert_candump")
    dbc = d / "ex1_int16.dbc"
    dbc.write_text(INT_DBC)
    data, t = example1_capture()
    df = pd.DataFrame({"t": t, **data})
    df.loc[list(MISSING), ["x1", "x2", "s"]] = np.nan
    csv = d / "capture.csv"
    df.to_csv(csv, index=False, float_format="%.17g")
    return dbc, csv, df


def one_line_error(p):
    """Exit 2, one line on stderr, no traceback."""
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1, p.stderr
    return p.stderr.strip()


def cantools_decode(log, dbc):
    """Every frame of a candump -l log decoded by cantools: [(t_s, frame id, {signal: value})]."""
    import cantools

    db = cantools.database.load_file(str(dbc))
    out = []
    pattern = re.compile(r"^\((\d+\.\d{6})\) (\S+) ([0-9A-F]{3})#([0-9A-F]*)$")
    for line in Path(log).read_text().splitlines():
        m = pattern.match(line)
        assert m, line
        out.append((float(m[1]), int(m[3], 16),
                    db.decode_message(int(m[3], 16), bytes.fromhex(m[4]), decode_choices=False, scaling=True)))
    return out


@needs_drivers
def test_csv_to_candump_round_trip(files, tmp_path):
    dbc, csv, df = files
    stand = vibid.Stand.load(EXAMPLE1)
    log = tmp_path / "capture.log"
    p = run("convert", EXAMPLE1, csv, log, "--dbc", dbc)  # candump by the extension .log
    assert p.returncode == 0, p.stderr
    n = len(df) - len(MISSING)
    assert p.stdout.splitlines()[0] == (
        f"{log}: {n} samples of 3 channels (x1, x2, s) as {3 * n} frames of 3 messages of ex1_int16.dbc on can0, "
        "counter SampleCounter (16 bits); 10 missing samples left out (counter jumps: the log's gaps)")
    # The rounded values counted (and none saturated): the values off the signal's grid by more
    # than 1e-9 of a step, counted here independently.
    for c, (factor, offset, k) in {"x1": (1e-6, 0, 1), "x2": (1e-6, 0, 1), "s": (1e-3, -30, 1e-3)}.items():
        v = df[c].dropna().to_numpy() / k
        off_grid = int(np.sum(np.abs(np.rint((v - offset) / factor) * factor + offset - v) > 1e-9 * factor))
        assert off_grid > 0.99 * n
        line = next(ln for ln in p.stdout.splitlines() if ln.startswith(f"  {c}: "))
        assert f": {off_grid} of {n} values rounded to the step {factor:g} " in line and "none saturated" in line, line

    # read back by the package (the drivers' replay source): every row, the missing ones a
    # gap of NaN rows, the others within half a step, the times the CSV's to the microsecond
    back = vibid.read_capture(log, stand, dbc=dbc)
    assert len(back) == len(df)
    missing = back[list(stand.channels)].isna().all(axis=1)
    assert list(np.flatnonzero(missing)) == list(MISSING)
    assert [(g["row"], g["count"]) for g in back.attrs["gaps"]] == [(5000, 10)]
    assert back.attrs["faults"] == [] and back.attrs["counter"] == "SampleCounter"
    ok = ~missing.to_numpy()
    for c in stand.channels:
        err = np.abs(back[c].to_numpy()[ok] - df[c].to_numpy()[ok])
        assert err.max() <= HALF_STEP[c] * (1 + 1e-9), (c, err.max())
        assert err.max() > 0.9 * HALF_STEP[c]  # the data do use the whole step
    np.testing.assert_allclose(back["time_s"].to_numpy()[ok], df["t"].to_numpy()[ok], rtol=0, atol=1e-12)

    # the independent peer: cantools decodes the same values from the same frames
    frames = cantools_decode(log, dbc)
    assert len(frames) == 3 * n
    by_sample = {}
    for t_s, fid, sig in frames:
        by_sample.setdefault(sig["SampleCounter"], {})["t"] = t_s
        by_sample[sig["SampleCounter"]].update({k: v for k, v in sig.items() if k != "SampleCounter"})
    counters = list(by_sample)
    assert counters == [*range(5000), *range(5010, 20000)]  # the counter skips the gap (< 2^16 samples)
    peer = pd.DataFrame([by_sample[k] for k in counters])
    ours = back[ok].reset_index(drop=True)
    np.testing.assert_array_equal(peer["x1"], ours["x1"])
    np.testing.assert_array_equal(peer["x2"], ours["x2"])
    np.testing.assert_array_equal(peer["s"] * 1e-3, ours["s"])  # cantools in the DBC's mm
    np.testing.assert_allclose(peer["t"], df["t"][ok], rtol=0, atol=1e-9)

    # and back to CSV: the same rows as read_capture gave (the missing ones left out)
    out = tmp_path / "back.csv"
    p = run("convert", EXAMPLE1, log, out, "--dbc", dbc)
    assert p.returncode == 0, p.stderr
    assert "10 missing samples left out (gaps in t)" in p.stdout
    again = vibid.read_capture(out, stand, channels={"time_s": "t"})
    np.testing.assert_array_equal(again[list(stand.channels)].to_numpy(), ours[list(stand.channels)].to_numpy())
    # ... and that CSV, whose gap is a time step, to candump again: the same log
    log2 = tmp_path / "again.log"
    p = run("convert", EXAMPLE1, out, log2, "--dbc", dbc)
    assert p.returncode == 0, p.stderr
    assert log2.read_text() == log.read_text()


@needs_drivers
def test_motohawk_no_counter(tmp_path):
    """A DBC written elsewhere (cantools' motohawk.dbc): one message, no counter (each frame a
    sample), Temperature Motorola signed 12 bits with factor 0.01 and offset 250, read as x1 in
    mm through a channel map; AverageRadius 6 bits of 0.1 m; Enable one bit."""
    dbc = SHARED_DBC / "motohawk.dbc"
    if not dbc.exists():
        pytest.skip(f"no {dbc} (the shared DBC test data; VIBID_DBC_TESTDATA_DIR)")
    cmap = tmp_path / "map.cfg"
    cmap.write_text("""channels = (
  { name = "x1"; quantity = "displacement"; node = 0; unit = "mm"; signal = "Temperature"; },
  { name = "x2"; quantity = "displacement"; node = 1; signal = "AverageRadius"; },
  { name = "s";  quantity = "base_displacement"; unit = "m"; signal = "Enable"; }
);
""")
    n = 2000
    t = np.arange(n) / 2000.0
    df = pd.DataFrame({"t": t, "x1": 0.25 + 0.02 * np.sin(2 * np.pi * 7 * t), "x2": 2.5 + 2.4 * np.cos(2 * np.pi * 3 * t),
                       "s": (np.arange(n) % 2).astype(float)})
    csv = tmp_path / "c.csv"
    df.to_csv(csv, index=False, float_format="%.17g")
    log = tmp_path / "c.log"
    p = run("convert", EXAMPLE1, csv, log, "--dbc", dbc, "--channel-map", cmap, "--interface", "vcan0")
    assert p.returncode == 0, p.stderr
    assert f"{n} samples of 3 channels (x1, x2, s) as {n} frames of 1 message of motohawk.dbc on vcan0, no counter" \
        in p.stdout, p.stdout
    assert "  s: signal ExampleMessage.Enable (1-bit unsigned, factor 1, offset 0: 0 .. 1 m): 0 of 2000 values " \
        "rounded" in p.stdout, p.stdout
    stand = vibid.Stand.load(EXAMPLE1)
    back = vibid.read_capture(log, stand, dbc=dbc, channel_map=cmap)
    assert len(back) == n and not back.isna().any().any()
    # half a step: 0.01 mm = 1e-5 m (x1), 0.1 m (x2); Enable exact
    assert np.abs(back["x1"] - df["x1"]).max() <= 0.5e-5 * (1 + 1e-9)
    assert np.abs(back["x2"] - df["x2"]).max() <= 0.05 * (1 + 1e-9)
    np.testing.assert_array_equal(back["s"], df["s"])
    frames = cantools_decode(log, dbc)
    assert all(line.split()[1] == "vcan0" for line in log.read_text().splitlines())
    peer = pd.DataFrame([sig for _, _, sig in frames])
    np.testing.assert_array_equal(peer["Temperature"] * 1e-3, back["x1"])
    np.testing.assert_array_equal(peer["AverageRadius"], back["x2"])
    np.testing.assert_array_equal(peer["Enable"], back["s"])

    # a missing sample cannot be marked in a log without a counter: refused, nothing written
    df.loc[100, "x2"] = np.nan
    df.to_csv(csv, index=False, float_format="%.17g")
    log.unlink()
    e = one_line_error(run("convert", EXAMPLE1, csv, log, "--dbc", dbc, "--channel-map", cmap))
    assert e == (f"vibid convert: error: {csv}:102: 1 missing sample(s), the first here, and the log has no counter "
                 "(trigger message ExampleMessage): it cannot mark a gap (a reader would join the samples around it); "
                 "use a DBC and channel map with a counter signal, or leave the gap out of the capture"), e
    assert not log.exists()
    # Temperature's DBC range [229.52|270.47] (in mm): 0.275 m is outside
    df.loc[100, "x2"] = 1.0
    df.loc[7, "x1"] = 0.275
    df.to_csv(csv, index=False, float_format="%.17g")
    e = one_line_error(run("convert", EXAMPLE1, csv, log, "--dbc", dbc, "--channel-map", cmap))
    assert e.startswith(f"vibid convert: error: {csv}:9: channel 'x1' = 275.0 mm is outside the DBC's range "
                        "[229.52|270.47] of signal ExampleMessage.Temperature (12-bit signed, factor 0.01, offset 250: "
                        "229.52 .. 270.47 mm); 1 such value(s) of 'x1': refused, never saturated"), e
    assert not log.exists()


@needs_drivers
def test_bad_input(files, tmp_path):
    dbc, csv, df = files
    log = tmp_path / "out.log"
    # no DBC
    e = one_line_error(run("convert", EXAMPLE1, csv, log))
    assert e == (f"vibid convert: error: {log}: a candump log is written with a DBC: give --dbc FILE.dbc (and "
                 "--channel-map MAP where the DBC's signals are not named as the stand's channels)")
    e = one_line_error(run("convert", EXAMPLE1, csv, log, "--dbc", tmp_path / "none.dbc"))
    assert e == f"vibid convert: error: DBC file '{tmp_path / 'none.dbc'}': no such file"
    # a channel with no signal in the DBC
    other = tmp_path / "other.dbc"
    other.write_text(INT_DBC.replace(" x2 ", " y2 "))
    e = one_line_error(run("convert", EXAMPLE1, csv, log, "--dbc", other))
    assert e.startswith(f"vibid convert: error: {other} has no signal 'x2' (its signals: ") and \
        "paper_example1_1.y2" in e and e.endswith("give a channel map (--channel-map) naming each channel's signal"), e
    # a format vibid convert does not write
    e = one_line_error(run("convert", EXAMPLE1, csv, tmp_path / "out.mf4", "--dbc", dbc))
    assert e == (f"vibid convert: error: {tmp_path / 'out.mf4'}: vibid convert writes csv or candump, not ASAM MDF4 "
                 "(by its extension); give --to csv or --to candump")
    # values that do not fit: outside the DBC's range of x1, beyond the 16 bits of x2 (no
    # range given); named with the capture's line (row + 2: the header is line 1)
    bad = df.copy()
    bad.loc[7, "x1"] = 0.031
    path = tmp_path / "bad.csv"
    bad.to_csv(path, index=False, float_format="%.17g")
    e = one_line_error(run("convert", EXAMPLE1, path, log, "--dbc", dbc))
    assert e == (f"vibid convert: error: {path}:9: channel 'x1' = 0.031 m is outside the DBC's range [-0.03|0.03] of "
                 "signal paper_example1_0.x1 (16-bit signed, factor 1e-06, offset 0: -0.032768 .. 0.032767 m); 1 "
                 "such value(s) of 'x1': refused, never saturated"), e
    bad = df.copy()
    bad.loc[[300, 301], "x2"] = [0.0327675, -0.04]
    bad.to_csv(path, index=False, float_format="%.17g")
    e = one_line_error(run("convert", EXAMPLE1, path, log, "--dbc", dbc, "--to", "candump"))
    assert e == (f"vibid convert: error: {path}:302: channel 'x2' = 0.0327675 m does not fit signal "
                 "paper_example1_1.x2 (16-bit signed, factor 1e-06, offset 0: -0.032768 .. 0.032767 m): refused, "
                 "never saturated"), e
    assert not log.exists() and not list(tmp_path.glob(".out.log.*"))  # no partial file either
    # not finite: no frame carries it
    bad = df.copy()
    bad.loc[3, "s"] = np.inf
    bad.to_csv(path, index=False, float_format="%.17g")
    e = one_line_error(run("convert", EXAMPLE1, path, log, "--dbc", dbc))
    assert e == f"vibid convert: error: {path}:5: channel 's' = inf: not a finite number, which no frame carries " \
        "(a reader drops it as a fault)", e
    # beyond float32 (vibid-sim's DBC: float32 signals)
    bad = df.copy()
    bad.loc[4, "x2"] = 1e39
    bad.to_csv(path, index=False, float_format="%.17g")
    e = one_line_error(run("convert", EXAMPLE1, path, log, "--dbc", REPO / "sim" / "paper_example1.dbc"))
    assert e == (f"vibid convert: error: {path}:6: channel 'x2' = 1e+39 is beyond float32's range in signal "
                 "paper_example1_1.x2 (float32, factor 1, offset 0); 1 such value(s) of 'x2': refused, never "
                 "saturated"), e
    assert not log.exists()
    # --out-dbc is for a candump output
    e = one_line_error(run("convert", EXAMPLE1, csv, tmp_path / "o.csv", "--out-dbc", dbc))
    assert "--out-dbc and --out-channel-map are for a candump output" in e


@needs_drivers
def test_gap_beyond_the_counter(files, tmp_path):
    """A pause of 20 s at 2 kHz (40000 periods) is more than the 16-bit counter can skip
    (a reader takes a step of 2^15 or more as an older sample): refused, not misplaced."""
    dbc, _, df = files
    short = df.iloc[:3].copy()
    short.loc[2, "t"] = 20.0
    path = tmp_path / "pause.csv"
    short.to_csv(path, index=False, float_format="%.17g")
    log = tmp_path / "pause.log"
    e = one_line_error(run("convert", EXAMPLE1, path, log, "--dbc", dbc))
    assert e == (f"vibid convert: error: {path}:4: 39998 samples missing before this one; the 16-bit counter "
                 "SampleCounter can skip at most 32766 (a reader would misplace the samples after the gap)"), e
    assert not log.exists()
    # a shorter pause (to t = 1 s: 1998 missing) is a gap the log marks and the reader finds
    short.loc[2, "t"] = 1.0
    short.to_csv(path, index=False, float_format="%.17g")
    p = run("convert", EXAMPLE1, path, log, "--dbc", dbc)
    assert p.returncode == 0, p.stderr
    back = vibid.read_capture(log, vibid.Stand.load(EXAMPLE1), dbc=dbc)
    assert [(g["row"], g["count"]) for g in back.attrs["gaps"]] == [(2, 1998)]
    assert len(back) == 2001 and back["time_s"].iloc[-1] == 1.0


REPLAY_CFG = """stand = "{stand}";
source = {{
  kind = "replay"; file = "{log}"; dbc = "{dbc}"; counter = "SampleCounter"; paced = false;
  channels = (
    {{ name = "x1"; quantity = "displacement"; node = 0; signal = "x1"; }},
    {{ name = "x2"; quantity = "displacement"; node = 1; signal = "x2"; }},
    {{ name = "s";  quantity = "base_displacement"; unit = "mm"; signal = "s"; }}
  );
}};
estimator = {{ method = "rls"; decimation = 500; }};
outputs = {{ tracks = {{ path = "tracks.csv"; }}; }};
"""


@pytest.mark.skipif(not getattr(_core, "HAVE_DAEMON", False), reason="vibid built without vibidd's core")
def test_vibidd_replays_the_log_and_a_reencoding(files, tmp_path):
    """vibidd's own pipeline (vibid.replay, in-process) replays the written log and counts its
    gap; the log re-encoded into vibid-sim's float32 DBC (--out-dbc) reads back as the float32
    of the values the first log holds."""
    dbc, csv, df = files
    stand = vibid.Stand.load(EXAMPLE1)
    log = tmp_path / "capture.log"
    assert run("convert", EXAMPLE1, csv, log, "--dbc", dbc).returncode == 0
    cfg = tmp_path / "vibidd.cfg"
    cfg.write_text(REPLAY_CFG.format(stand=EXAMPLE1, log=log, dbc=dbc))
    tracks = vibid.replay(cfg)
    assert tracks["gap_samples"].sum() == len(MISSING)
    assert tracks["flags"].str.contains("G").sum() == 1
    assert tracks["index"].max() == len(df) - 1

    f32 = tmp_path / "f32.log"
    sim_dbc = REPO / "sim" / "paper_example1.dbc"
    p = run("convert", EXAMPLE1, log, f32, "--dbc", dbc, "--out-dbc", sim_dbc)
    assert p.returncode == 0, p.stderr
    assert "  x1: signal paper_example1_0.x1 (float32, factor 1, offset 0): " in p.stdout and "to float32" in p.stdout
    ints = vibid.read_capture(log, stand, dbc=dbc)
    floats = vibid.read_capture(f32, stand, dbc=sim_dbc)
    assert [(g["row"], g["count"]) for g in floats.attrs["gaps"]] == [(5000, 10)]
    for c in stand.channels:
        np.testing.assert_array_equal(floats[c].to_numpy(), ints[c].to_numpy().astype(np.float32).astype(np.float64))
