"""The same capture through vibidd --replay and through vibid.identify: the same tracks.

vibidd is the suite's own build (build/werror/daemon/vibidd, made by scripts/test.sh before
the Python tests; or VIBID_VIBIDD). Without it this test is skipped, and says why."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import vibid
from conftest import EXAMPLE1, vibidd_path

CONFIG = """stand = "{stand}";
source = {{
  kind = "replay"; file = "{capture}"; format = "csv"; paced = false; time_column = "t";
  channels = (
    {{ name = "x1"; quantity = "displacement"; node = 0; unit = "m"; column = "x1"; }},
    {{ name = "x2"; quantity = "displacement"; node = 1; unit = "m"; column = "x2"; }},
    {{ name = "s";  quantity = "base_displacement"; node = 0; unit = "m"; column = "s"; }}
  );
}};
estimator = {{ method = "{method}"; decimation = 500; }};
outputs = {{ tracks = {{ path = "{tracks}"; }}; }};
"""


@pytest.mark.parametrize("method", ["auto", "rls"])
def test_tracks_equal_vibidd_replay(tmp_path, ex1_clean, method):
    vibidd = vibidd_path()
    if not vibidd.exists():
        pytest.skip(f"no vibidd at {vibidd} (build the C suite first, or set VIBID_VIBIDD)")
    data, t = ex1_clean
    capture = tmp_path / "capture.csv"
    pd.DataFrame({"t": t, **data}).to_csv(capture, index=False, float_format="%.17g")
    tracks = tmp_path / "tracks.csv"
    cfg = tmp_path / "vibidd.cfg"
    cfg.write_text(CONFIG.format(stand=EXAMPLE1, capture=capture, method=method, tracks=tracks))
    subprocess.run([str(vibidd), "-c", str(cfg), "--replay", str(capture)], check=True, cwd=tmp_path,
                   capture_output=True, timeout=120)
    every = pd.read_csv(tracks, comment="#")
    # vibidd adds the output-error refinement's row (flag W) of the 10 s window ending at the
    # last sample (estimator.refine_every, docs/vibidd.md "Refinement"); identify has none
    refined = every[every["flags"].fillna("").str.contains("W")]
    theirs = every[~every.index.isin(refined.index)].reset_index(drop=True)
    assert list(refined["index"]) == [19999]
    # the refinement on these noise-free responses: c1, c2 within 1e-4 of the truth, d within
    # 1e-3 (measured: -0.068 %, some 51 of its standard errors: the triangle's corners fall
    # between samples, where the output-error fit takes the base as straight). The fit measures
    # that dependence on the input's path (output_error.h, "Input path") and the row says U:
    # the error bars do not hold, rather than an unflagged row 51 se off.
    for name, truth, rtol in (("c1", 2.5e5, 1e-4), ("d", 300.0, 1e-3), ("c2", 1.5e6, 1e-4)):
        assert abs(refined[name].iloc[0] / truth - 1) < rtol, (name, refined[name].iloc[0])
    assert abs(refined["d"].iloc[0] - 300.0) > 3 * refined["d_se"].iloc[0]
    assert "U" in refined["flags"].iloc[0]
    ours = vibid.identify(EXAMPLE1, capture, method=method, track_every=500).tracks
    assert list(theirs["index"]) == list(ours["index"])
    value_cols = [c for c in ours.columns if c not in ("time_s", "index", "flags")]
    assert list(theirs.columns) == ["time_s", "index", *value_cols, "gap_samples", "flags"]
    # vibidd writes %.10g: equal to 1e-9 relative, or the two paths computed different things
    np.testing.assert_allclose(theirs[value_cols].to_numpy(float), ours[value_cols].to_numpy(float),
                               rtol=1e-9, atol=0)
    assert list(theirs["flags"].fillna("")) == list(ours["flags"])
    # time_s: the capture's t of the row's last sample in both (vibidd: microseconds)
    np.testing.assert_allclose(theirs["time_s"], ours["time_s"], rtol=0, atol=1e-6)


def test_mdf4_refused_then_converted(tmp_path, ex1_clean):
    """vibidd given an MDF4 capture refuses it (exit 2) naming the format, what it replays and
    `vibid convert`; the converted file replays without a channel map (vibidd's recording
    layout) and gives the tracks identify gives on the MDF4 file itself."""
    from test_captures import write_mdf

    vibidd = vibidd_path()
    if not vibidd.exists():
        pytest.skip(f"no vibidd at {vibidd} (build the C suite first, or set VIBID_VIBIDD)")
    data, t = ex1_clean
    mdf = write_mdf(tmp_path / "run.mf4", [(t, {c: (data[c], "m") for c in ("x1", "x2", "s")})])
    tracks = tmp_path / "tracks.csv"
    cfg = tmp_path / "vibidd.cfg"
    cfg.write_text(CONFIG.format(stand=EXAMPLE1, capture=tmp_path / "none.csv", method="auto", tracks=tracks))
    refused = subprocess.run([str(vibidd), "-c", str(cfg), "--replay", str(mdf)], cwd=tmp_path,
                             capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2, refused.stderr
    assert f"{mdf}: an ASAM MDF4 capture, which vibidd does not replay (it replays candump (.log), csv (.csv))" \
        in refused.stderr and "vibid convert" in refused.stderr, refused.stderr
    assert not tracks.exists()

    out = tmp_path / "run.csv"
    conv = subprocess.run([str(Path(sys.executable).with_name("vibid")), "convert", str(EXAMPLE1), str(mdf), str(out)],
                          capture_output=True, text=True, timeout=120)
    assert conv.returncode == 0, conv.stderr
    assert f"{len(t)} samples of 3 channels" in conv.stdout, conv.stdout
    assert out.read_text().startswith("# vibidd raw recording of stand 'paper_example1' at 2000.0 Hz; converted by "
                                      "vibid convert from run.mf4 (mdf)")
    # the values read back bit for bit (shortest round-trip text)
    back = vibid.read_capture(out, EXAMPLE1, channels={"time_s": "t"})
    for c in ("x1", "x2", "s"):
        assert np.array_equal(back[c].to_numpy(), data[c]), c
    subprocess.run([str(vibidd), "-c", str(cfg), "--replay", str(out)], check=True, cwd=tmp_path,
                   capture_output=True, timeout=120)
    theirs = pd.read_csv(tracks, comment="#")
    theirs = theirs[~theirs["flags"].fillna("").str.contains("W")].reset_index(drop=True)  # refinement rows
    ours = vibid.identify(EXAMPLE1, mdf, track_every=500).tracks
    assert list(theirs["index"]) == list(ours["index"])
    value_cols = [c for c in ours.columns if c not in ("time_s", "index", "flags")]
    np.testing.assert_allclose(theirs[value_cols].to_numpy(float), ours[value_cols].to_numpy(float), rtol=1e-9, atol=0)
