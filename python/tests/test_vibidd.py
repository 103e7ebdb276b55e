"""The same capture through vibidd --replay and through vibid.identify: the same tracks.

vibidd is the suite's own build (build/werror/daemon/vibidd, made by scripts/test.sh before
the Python tests; or VIBID_VIBIDD). Without it this test is skipped, and says why."""

from __future__ import annotations

import subprocess

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
    theirs = pd.read_csv(tracks, comment="#")
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
