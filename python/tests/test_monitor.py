"""vibid.monitor (issue 32, item 5): long captures replayed through vibidd's change test with
the reference kept across them, the events read back, drawn.

The events must be vibidd's own: the same captures replayed by the vibidd binary, one run per
capture with the same reference file (a restart between them), give the same alarm lines,
compared field by field to the printed digits. The stand is the base-excited 2-DOF stand of
tests/daemon/e2e_auto.sh; the second capture is the machine after a restart, its lower
spring c2 cracked by 10 % from 6 s on (another noise seed). Expected: nothing in the healthy
capture (the rate is 1 false alarm a year over 4 parameters and 50 s of rows: a false alarm
has a probability of about 2e-6), a c2 alarm after 6 s in the cracked one, on c2 only."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

import vibid
from vibid import _core
from vibid._monitor import covariate_columns, parse_alarm_lines
from conftest import REPO, sim_path, vibidd_path

pytestmark = pytest.mark.skipif(not _core.HAVE_DAEMON, reason="vibid built without vibidd's core")

STAND = (REPO / "examples" / "stands" / "base2.cfg").read_text()
SIM = """simulation = {{ seed = {seed};
  excitation = ( {{ target = "base"; kind = "noise"; amplitude = 1.0e-4; f_high = 100.0; }} );
  noise = ( {{ channel = "x1"; snr_db = 60.0; }}, {{ channel = "x2"; snr_db = 60.0; }}, {{ channel = "s"; snr_db = 60.0; }} );
  {changes} }};
"""
CONFIG = """stand = "stand.cfg";
source = {{
  kind = "replay"; file = "healthy.csv"; time_column = "t";
  channels = (
    {{ name = "x1"; quantity = "displacement"; node = 0; unit = "m"; column = "x1"; }},
    {{ name = "x2"; quantity = "displacement"; node = 1; unit = "m"; column = "x2"; }},
    {{ name = "s";  quantity = "base_displacement"; node = 0; unit = "m"; column = "s"; }}
  );
}};
estimator = {{ forgetting = 0.999; }};
alarms = {{ reference_file = "{ref}"; }};
outputs = {{ tracks = {{ path = "tracks.csv"; }}; influx = {{ path = "lines.influx"; }}; }};
"""


def _tool(p):
    if not p.exists():
        pytest.skip(f"no {p.name} at {p} (build the C suite first)")
    return str(p)


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    d = tmp_path_factory.mktemp("monitor")
    (d / "stand.cfg").write_text(STAND + SIM.format(seed=7, changes=""))
    (d / "cracked.sim").write_text(SIM.format(seed=8, changes='changes = ( { parameter = "c2"; at = 6.0; '
                                                             'factor = 0.9; } );'))
    sim = _tool(sim_path())
    subprocess.run([sim, "-c", "stand.cfg", "--duration", "25", "--csv", "healthy.csv", "-q"], cwd=d, check=True,
                   capture_output=True, timeout=300)
    subprocess.run([sim, "-c", "stand.cfg", "-s", "cracked.sim", "--duration", "25", "--csv", "cracked.csv", "-q"],
                   cwd=d, check=True, capture_output=True, timeout=300)
    (d / "v.cfg").write_text(CONFIG.format(ref="daemon.ref"))
    return d


def test_monitor_events_are_vibidds(captures):
    d = captures
    mon = vibid.monitor(d / "v.cfg", [d / "healthy.csv", d / "cracked.csv"], reference=d / "monitor.ref")
    ev = mon.events
    raised = ev[ev["state"] == "raised"]
    # nothing in the healthy capture; c2 alone in the cracked one, after the crack at 6 s
    assert (ev["capture"] == str(d / "healthy.csv")).sum() == 0, ev
    assert len(raised) == 1 and raised["parameter"].iloc[0] == "c2", ev
    assert raised["capture"].iloc[0] == str(d / "cracked.csv")
    assert 6000 <= raised["index"].iloc[0] <= 11000, raised  # within 5 s of the crack
    # the estimated change: -10 % of 1.2e5, within 4 of its standard errors
    assert abs(raised["change"].iloc[0] + 1.2e4) < 4 * raised["change_se"].iloc[0], raised
    assert raised["statistic"].iloc[0] >= raised["threshold"].iloc[0]
    # the reference was learned from the healthy capture and kept
    assert mon.reference["stand"] == "base2" and abs(mon.reference["c2"]["mean"] / 1.2e5 - 1) < 0.01
    # the tracks carry the statistic and the MDC; the statistic crosses 1 at the raising row
    cr = mon.tracks[(mon.tracks["capture"] == str(d / "cracked.csv")) & ~mon.tracks["flags"].str.contains("W")]
    at = cr[cr["index"] == raised["index"].iloc[0]]
    assert len(at) == 1 and at["c2_change_statistic"].iloc[0] >= 1.0
    assert np.isfinite(cr["c2_mdc"]).all()  # a reference read from the file: the MDC from the first row
    assert mon.covariates == []

    # vibidd itself, restarted between the captures with the same reference file
    vibidd = _tool(vibidd_path())
    lines = []
    for cap in ("healthy.csv", "cracked.csv"):
        (d / "lines.influx").unlink(missing_ok=True)
        subprocess.run([vibidd, "-c", "v.cfg", "--replay", cap], cwd=d, check=True, capture_output=True,
                       timeout=300)
        lines += parse_alarm_lines(str(d / "lines.influx"), str(d / cap))
    assert len(lines) == len(ev)
    for a, (_, b) in zip(lines, ev.iterrows()):
        for k in ("capture", "time_s", "index", "parameter", "state", "test", "onset_index", "value", "baseline",
                  "statistic", "threshold", "change", "change_se"):
            assert a[k] == b[k], (k, a[k], b[k])
    # the reference files of both: the same numbers
    assert (d / "daemon.ref").read_text().split("learned_index")[1] == \
        (d / "monitor.ref").read_text().split("learned_index")[1]

    fig = mon.plot(path=str(d / "monitor.png"))
    axes = fig.get_axes()
    assert len(axes) == 4  # c1, d1, c2, d2; no covariate panel
    assert "c2: 1 alarm(s)" in axes[2].get_title(loc="left")
    assert (d / "monitor.png").stat().st_size > 10000


def test_monitor_errors(captures, tmp_path):
    d = captures
    with pytest.raises(FileNotFoundError):
        vibid.monitor(d / "v.cfg", [d / "missing.csv"])
    (tmp_path / "stand.cfg").write_text((d / "stand.cfg").read_text())
    (tmp_path / "t.cfg").write_text(CONFIG.format(ref="r.ref").replace('alarms = { reference_file = "r.ref"; };',
                                                                       "alarms = { test = \"threshold\"; };"))
    with pytest.raises(ValueError, match="no change test"):
        vibid.monitor(tmp_path / "t.cfg", d / "healthy.csv")


def test_covariate_columns():
    cols = ["time_s", "index", "c1", "c1_se", "c2", "c2_se", "f1_hz", "f1_hz_se", "zeta1", "zeta1_se", "T", "flow",
            "c2_change_statistic", "c2_mdc", "gap_samples", "flags"]
    assert covariate_columns(cols) == ["T", "flow"]
