"""vibid.replay (issue 13): vibidd's pipeline in-process on a vibidd configuration gives the
tracks `vibidd --replay` writes: the same columns and the same values to the printed digits.

Both sides run the same C code (vibidd_core linked into vibid._core), so the DataFrame is
compared with the daemon's tracks file read back by pandas exactly: any difference, even in
the last printed digit, would mean the two ran different things. vibidd and vibid-sim are
the suite's own builds (VIBID_VIBIDD, VIBID_SIM, else $VIBID_BUILD_ROOT/werror); without them
these tests are skipped and say why."""

from __future__ import annotations

import subprocess

import pandas as pd
import pytest

import vibid
from vibid import _core
from conftest import EXAMPLE1, REPO, vibidd_path
from test_candump import DBC, sim_capture

pytestmark = pytest.mark.skipif(not _core.HAVE_DAEMON, reason="vibid built without vibidd's core")

CSV_SOURCE = """kind = "replay"; file = "{capture}"; format = "csv"; paced = false; time_column = "t";
  channels = (
    {{ name = "x1"; quantity = "displacement"; node = 0; unit = "m"; column = "x1"; }},
    {{ name = "x2"; quantity = "displacement"; node = 1; unit = "m"; column = "x2"; }},
    {{ name = "s";  quantity = "base_displacement"; node = 0; unit = "m"; column = "s"; }}
  );"""
CAN_SOURCE = """kind = "replay"; file = "{capture}"; dbc = "{dbc}"; counter = "SampleCounter";
  channels = (
    {{ name = "x1"; quantity = "displacement"; node = 0; unit = "m"; signal = "x1"; }},
    {{ name = "x2"; quantity = "displacement"; node = 1; unit = "m"; signal = "x2"; }},
    {{ name = "s";  quantity = "base_displacement"; node = 0; unit = "m"; signal = "s"; }}
  );"""
CONFIG = """stand = "{stand}";
source = {{
  {source}
}};
estimator = {{ {estimator} decimation = 500; }};
outputs = {{ tracks = {{ path = "{tracks}"; }}; status = {{ path = "{status}"; }}; }};
"""


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return sim_capture(tmp_path_factory.mktemp("replay"))


def vibidd():
    p = vibidd_path()
    if not p.exists():
        pytest.skip(f"no vibidd at {p} (build the C suite first, or set VIBID_VIBIDD)")
    return p


def write_config(path, capture, kind="csv", estimator=""):
    source = (CSV_SOURCE if kind == "csv" else CAN_SOURCE).format(capture=capture, dbc=DBC)
    path.write_text(CONFIG.format(stand=EXAMPLE1, source=source, estimator=estimator,
                                  tracks=path.parent / "tracks.csv", status=path.parent / "status"))
    return path


def daemon_tracks(cfg, capture=None):
    """What `vibidd -c cfg [--replay capture]` writes to the configuration's tracks file."""
    tracks = cfg.parent / "tracks.csv"
    tracks.unlink(missing_ok=True)
    subprocess.run([str(vibidd()), "-c", str(cfg), *(["--replay", str(capture)] if capture else [])], check=True,
                   cwd=cfg.parent, capture_output=True, timeout=120)
    df = pd.read_csv(tracks, comment="#")
    df["flags"] = df["flags"].fillna("").astype(str)
    return df


@pytest.mark.parametrize("kind,estimator", [("csv", 'method = "rls";'), ("candump", ""), ("candump", 'method = "iv";')])
def test_replay_equals_vibidd(run, tmp_path, kind, estimator):
    csv, log = run
    cfg = write_config(tmp_path / "v.cfg", csv if kind == "csv" else log, kind, estimator)
    ours = vibid.replay(cfg)
    # only the tracks, into a temporary file: the configuration's outputs stay unwritten
    assert not (tmp_path / "tracks.csv").exists() and not (tmp_path / "status").exists()
    theirs = daemon_tracks(cfg)
    assert list(ours.columns) == ["time_s", "index", "c1", "c1_se", "d", "d_se", "c2", "c2_se", "f1_hz", "f1_hz_se",
                                  "zeta1", "zeta1_se", "f2_hz", "f2_hz_se", "zeta2", "zeta2_se", "gap_samples", "flags"]
    # 20000 samples, a row every 500, and the refinement's row (flag W) of the 10 s window
    # ending at the last sample (estimator.refine_every, docs/vibidd.md "Refinement")
    assert (~ours["flags"].str.contains("W")).sum() == 40
    pd.testing.assert_frame_equal(ours, theirs, check_exact=True)
    # sample times: the log's stamps (epoch 1700000000) or the CSV's t
    t0 = 1700000000.0 if kind == "candump" else 0.0
    assert ours["time_s"].iloc[0] == pytest.approx(t0 + 499 / 2000, abs=1e-6)


def test_replay_capture_override_and_gaps(run, tmp_path):
    csv, log = run
    # The configuration names the full log; capture= replays another one, as --replay does:
    # here the log with samples 5000..5009 cut out. The row covering them says so (G, 10).
    lines = log.read_text().splitlines(keepends=True)
    gap = tmp_path / "gap.log"
    gap.write_text("".join(ln for i, ln in enumerate(lines) if not 15000 <= i < 15030))
    cfg = write_config(tmp_path / "v.cfg", log, "candump", 'method = "rls";')
    ours = vibid.replay(cfg, capture=gap)
    theirs = daemon_tracks(cfg, gap)
    pd.testing.assert_frame_equal(ours, theirs, check_exact=True)
    row = ours[ours["gap_samples"] > 0]
    assert list(row["index"]) == [5499] and list(row["gap_samples"]) == [10]
    assert "G" in row["flags"].iloc[0]
    # and the full log through the same configuration is a different run
    assert not ours.equals(vibid.replay(cfg))


def test_replay_errors(run, tmp_path):
    csv, log = run
    # the configuration reader's file:line: field: reason
    cfg = write_config(tmp_path / "bad.cfg", csv, "csv", 'method = "rls"; forgetting = 1.5;')
    with pytest.raises(ValueError, match=r"bad\.cfg:10: estimator\.forgetting: 1\.5 outside \[0\.9, 1\]"):
        vibid.replay(cfg)
    with pytest.raises(FileNotFoundError, match="vibidd configuration not found"):
        vibid.replay(tmp_path / "none.cfg")
    # a candump configuration given a CSV capture: the daemon's refusal, naming file and channel
    cfg = write_config(tmp_path / "can.cfg", log, "candump")
    with pytest.raises(ValueError, match=r"ex1\.csv: not a vibidd recording, and channel 'x1' of .*can\.cfg:5 "
                                         r"names no CSV column"):
        vibid.replay(cfg, capture=csv)
    # a DBC that is not there: the configuration reader names it
    cfg.write_text(cfg.read_text().replace(str(DBC), str(tmp_path / "missing.dbc")))
    with pytest.raises(ValueError, match=r"can\.cfg:\d+: source\.dbc: .*missing\.dbc"):
        vibid.replay(cfg)
    # a capture at another rate than the stand's: refused before anything runs (rate_check.h)
    fast = tmp_path / "fast.csv"
    df = pd.read_csv(csv)
    df["t"] = df["t"] / 2  # 4 kHz
    df.to_csv(fast, index=False, float_format="%.17g")
    cfg = write_config(tmp_path / "v.cfg", fast, "csv")
    with pytest.raises(ValueError, match=r"fast\.csv: sample rate 4000"):
        vibid.replay(cfg)
    with pytest.raises(ValueError, match=r"rate_check 'maybe': error, warn or off"):
        vibid.replay(cfg, rate_check="maybe")
