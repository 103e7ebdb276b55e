"""vibidd's output-only mode tracking (issue 34 item 3): an `oma` configuration (no stand)
replayed through vibidd's pipeline (vibid.replay runs the daemon's own C code in-process).

The capture: the 3-DOF chain of test_oma.py under unmeasured white forces (oma_sim.py),
displacements with 1 % sensor noise, 100 Hz; its middle spring loses 8 % at t = T_CHANGE (the
state continuous across the step). Truth: the continuous model's modes before and after."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import vibid
from vibid import _core
from oma_sim import ambient_segments, chain_matrices, modes

pytestmark = pytest.mark.skipif(not _core.HAVE_DAEMON, reason="vibid built without vibidd's core")

FS = 100.0
MASS, STIFF, DAMP = [1.0, 1.5, 1.0], [1e4, 8e3, 6e3], [4.0, 3.0, 2.0]
M, D, K0 = chain_matrices(MASS, STIFF, DAMP)
K1 = chain_matrices(MASS, [STIFF[0], 0.92 * STIFF[1], STIFF[2]], DAMP)[2]
F0, Z0 = modes(M, D, K0)
F1, Z1 = modes(M, D, K1)
# 40 s windows every 20 s: the change test takes every other row (disjoint windows) and
# learns its reference from the first 1640 s (40 blocks: a reference from 10 costs the
# thresholds a factor of several, vibid/change.h point 3)
T_CHANGE, T_END = 2000.0, 3000.0
WINDOW, EVERY, LEARN = 40.0, 20.0, 1640.0

CONFIG = """oma = {{
  name = "chain3";
  sample_rate = {fs};
  modes = {modes};
  window = {window};
  every = {every};
  {extra}
}};
source = {{
  kind = "replay"; file = "{capture}"; format = "csv"; time_column = "t";
  channels = (
    {{ name = "x1"; quantity = "displacement"; node = 0; unit = "m"; column = "x1"; }},
    {{ name = "x2"; quantity = "displacement"; node = 1; unit = "m"; column = "x2"; }},
    {{ name = "x3"; quantity = "displacement"; node = 2; unit = "m"; column = "x3"; }},
    {{ name = "temp"; quantity = "covariate"; unit = "degC"; column = "temp"; }}
  );
}};
alarms = {{ learn_start = 0.0; learn_duration = {learn}; }};
"""


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    n0, n1 = int(T_CHANGE * FS), int((T_END - T_CHANGE) * FS)
    y = ambient_segments(M, D, [(K0, n0), (K1, n1)], FS, noise=0.01, seed=11)
    t = np.arange(n0 + n1) / FS
    path = tmp_path_factory.mktemp("vibidd_oma") / "ambient.csv"
    # a covariate that does not act on the chain: written through to the rows (window means)
    temp = 20.0 + 2.0 * np.sin(2 * np.pi * t / 600.0)
    pd.DataFrame({"t": t, "x1": y[:, 0], "x2": y[:, 1], "x3": y[:, 2], "temp": temp}).to_csv(
        path, index=False, float_format="%.9g")
    return path


def write_config(dir_, capture, modes="3", extra="", learn=LEARN):
    path = dir_ / "oma.cfg"
    path.write_text(CONFIG.format(fs=FS, modes=modes, window=WINDOW, every=EVERY, capture=capture, extra=extra,
                                  learn=learn))
    return path


@pytest.fixture(scope="module")
def tracks(capture):
    return vibid.replay(write_config(capture.parent, capture))


def test_rows_and_columns(tracks):
    cols = ["time_s", "index"] + [c for j in (1, 2, 3) for c in (f"f{j}_hz", f"f{j}_hz_se", f"zeta{j}",
                                                                   f"zeta{j}_se")]
    assert list(tracks.columns[:len(cols)]) == cols
    assert "temp" in tracks.columns and tracks.columns[-1] == "flags"
    # the first row once the window (60 s, 32 blocks) is full, then one every 20 s
    assert tracks["time_s"].iloc[0] == pytest.approx(WINDOW, abs=EVERY)
    assert np.allclose(np.diff(tracks["index"]), EVERY * FS)
    assert len(tracks) == pytest.approx((T_END - WINDOW) / EVERY + 1, abs=1)
    # the covariate: the window's mean of 20 + 2 sin(2 pi t / 600) (within the sine's change
    # over one block of 1.9 s, which the window's edge may hold or not: 0.05 degC)
    tc = tracks["time_s"].to_numpy()
    expect = np.array([np.mean(20.0 + 2.0 * np.sin(2 * np.pi * np.arange(t - WINDOW, t, 0.01) / 600.0)) for t in tc])
    assert np.max(np.abs(tracks["temp"].to_numpy() - expect)) < 0.05


def test_tracked_modes_follow_the_truth(tracks):
    """Windows wholly before the change against the healthy modes, wholly after it against the
    damaged ones: every tracked mode found in at least 90 % of them, within 1 % and
    the pooled 2-se coverage of frequency and damping at least 80 %."""
    t = tracks["time_s"].to_numpy()
    before = t <= T_CHANGE
    after = t - WINDOW >= T_CHANGE
    assert before.sum() >= 95 and after.sum() >= 45
    zs = []
    for sel, F, Z in ((before, F0, Z0), (after, F1, Z1)):
        rows = tracks[sel]
        assert not rows["flags"].astype(str).str.contains("E").any()
        for j in range(3):
            f, fse = rows[f"f{j + 1}_hz"].to_numpy(), rows[f"f{j + 1}_hz_se"].to_numpy()
            z, zse = rows[f"zeta{j + 1}"].to_numpy(), rows[f"zeta{j + 1}_se"].to_numpy()
            found = np.isfinite(f)
            # the automatic selection (vibid/oma.h point 6) misses a mode in 2-4 % of the 40 s
            # windows (a cluster short of min_cluster_share); 10 % would be a failing selection
            assert found.mean() >= 0.9 and np.all(fse[found] > 0)
            f, fse, z, zse = f[found], fse[found], z[found], zse[found]
            print(f"mode {j + 1}: f {F[j]:.4f} Hz, found in {found.sum()} of {len(found)}, mean error "
                  f"{np.mean(f / F[j] - 1) * 100:+.3f} %, |z| f {np.mean(np.abs(f - F[j]) / fse):.2f}, zeta {Z[j]:.4f} "
                  f"mean {np.mean(z):.4f} |z| {np.mean(np.abs(z - Z[j]) / zse):.2f}")
            # 40 s windows: the frequencies' standard errors are 0.1-0.5 %; the mean error
            # within 0.3 % (the 8 % spring loss moves modes 1 and 3 by 1.8 and 2.3 %) and no
            # row beyond 5 of its standard errors (p = 6e-7 each for a correct Gaussian one)
            assert abs(np.mean(f / F[j] - 1)) < 3e-3
            assert np.max(np.abs(f - F[j]) / fse) < 5.0
            zs += list(np.abs(f - F[j]) / fse) + list(np.abs(z - Z[j]) / zse)
    zs = np.array(zs)
    cover = np.mean(zs <= 2.0)
    print(f"pooled 2-se coverage {100 * cover:.1f} % over {len(zs)} intervals")
    # overlapping windows (2 rows share each sample) make the rows' errors correlated: about
    # 70 independent windows per quantity; 80 % is below the 95 % binomial floor of a true
    # 90 % coverage with that many (lib.test_oma and bench_oma_coverage.py measure the
    # coverage with independent captures: 90-99 % per mode)
    assert cover >= 0.80


def test_change_test_on_modal_frequencies(tracks):
    """The change test (alarms, cusum: vibid/change.h) on the disjoint windows' modes: no alarm
    before the spring loses 8 %, an alarm on the frequencies it moves (modes 1 and 3, by 1.8 %
    and 2.3 %: 10-20 of their block standard deviations) within 4 disjoint windows (160 s)."""
    flags = tracks["flags"].astype(str)
    t = tracks["time_s"].to_numpy()
    assert not flags[t <= T_CHANGE].str.contains("A").any()
    raised = t[flags.str.contains("A").to_numpy()]
    assert len(raised) and raised[0] > T_CHANGE
    delay = raised[0] - T_CHANGE
    print(f"alarm {delay:.0f} s after the change")
    assert delay <= 4 * 2 * WINDOW
    after = t > T_CHANGE
    for j in (0, 2):
        stat = tracks[f"f{j + 1}_hz_change_statistic"].to_numpy()
        assert np.nanmax(stat[after]) >= 1.0 and np.nanmax(stat[~after]) < 1.0
    # mode 2 does not move (the middle spring is at its node): its statistic stays under 1
    assert np.nanmax(tracks["f2_hz_change_statistic"].to_numpy()) < 1.0


def test_expected_frequencies(capture):
    """modes = [f...]: only the modes near the given frequencies are tracked, in their order."""
    df = vibid.replay(write_config(capture.parent, capture, modes=f"[{F0[1]:.2f}, {F0[2]:.2f}]"))
    rows = df[df["time_s"] <= T_CHANGE]
    assert [c for c in df.columns if c.endswith("_hz")] == ["f1_hz", "f2_hz"]
    for j, F in ((1, F0[1]), (2, F0[2])):  # within 5 standard errors, as above
        f, fse = rows[f"f{j}_hz"].dropna(), rows[f"f{j}_hz_se"].dropna()
        assert len(f) >= 0.9 * len(rows) and np.max(np.abs(f - F) / fse) < 5.0


@pytest.mark.parametrize("body, message", [
    ('modes = 3;', "oma.sample_rate: missing"),
    ('sample_rate = 100.0;', "oma.modes: missing"),
    ('sample_rate = 100.0; modes = 3; channels = ["x1", "nope"];', "'nope' is not a channel"),
    ('sample_rate = 100.0; modes = 3; channels = ["x1", "temp"];', "is a covariate"),
    ('sample_rate = 100.0; modes = [20.0, 10.0];', "frequencies must increase"),
    ('sample_rate = 100.0; modes = 3; max_order = 7;', "model orders are even"),
    ('sample_rate = 100.0; modes = 3; window = 10.0; every = 20.0;', "oma.window"),
    ('sample_rate = 100.0; modes = 3; refs = ["x9"];', "oma.refs"),
])
def test_configuration_errors(capture, tmp_path, body, message):
    cfg = tmp_path / "bad.cfg"
    text = CONFIG.format(fs=FS, modes=3, window=WINDOW, every=EVERY, capture=capture, extra="", learn=LEARN)
    start = text.index("oma = {")
    end = text.index("};", start) + 2
    cfg.write_text(text[:start] + "oma = { " + body + " };" + text[end:])
    with pytest.raises(ValueError, match=message):
        vibid.replay(cfg)


def test_stand_and_oma_together(capture, tmp_path):
    cfg = tmp_path / "both.cfg"
    cfg.write_text('stand = "x.cfg";\n' + CONFIG.format(fs=FS, modes=3, window=WINDOW, every=EVERY, capture=capture,
                                                        extra="", learn=LEARN))
    with pytest.raises(ValueError, match="either a stand .* or oma"):
        vibid.replay(cfg)


def test_check_prints_a_configuration_that_reads_back(capture, tmp_path):
    """vibidd --check on an oma configuration: the printout (every default filled in) is a
    configuration that --check accepts and prints identically."""
    import subprocess

    from conftest import vibidd_path
    vibidd = vibidd_path()
    if not vibidd.exists():
        pytest.skip(f"no vibidd at {vibidd} (build the C suite first, or set VIBID_VIBIDD)")
    cfg = write_config(tmp_path, capture)
    first = subprocess.run([str(vibidd), "-c", str(cfg), "--check"], capture_output=True, text=True, timeout=60)
    assert first.returncode == 0, first.stderr
    out = first.stdout
    assert 'oma = {' in out and 'channels = ["x1", "x2", "x3"];' in out and "block_rows = 20;" in out
    assert "estimator = {" not in out
    assert "# output-only: SSI-cov" in out
    again = tmp_path / "again.cfg"
    again.write_text(out)
    second = subprocess.run([str(vibidd), "-c", str(again), "--check"], capture_output=True, text=True, timeout=60)
    assert second.returncode == 0, second.stderr
    # the lines that name the file read: the header and the sample-rate check's outcome
    strip = lambda s: [ln for ln in s.splitlines()
                       if not ln.startswith("# vibidd effective configuration") and "oma.sample_rate in" not in ln]
    assert sum("oma.sample_rate in" in ln for ln in out.splitlines()) == 1
    assert strip(second.stdout) == strip(out)


STAND_NAMES = """stand = {{ name = "chain3-named"; sample_rate = {fs};
  nodes = ( {{ name = "base_plate"; mass = 1.0; measure = {{ displacement = "x1"; }}; }},
            {{ name = "column"; mass = 1.5; measure = {{ displacement = "x2"; }}; }},
            {{ name = "top"; mass = 1.0; measure = {{ displacement = "x3"; }}; }} );
  elements = ( {{ name = "k1"; kind = "spring"; between = ["base_plate", "ground"]; value = 1.0e4; }},
               {{ name = "k2"; kind = "spring"; between = ["column", "base_plate"]; value = 8.0e3; }},
               {{ name = "k3"; kind = "spring"; between = ["top", "column"]; value = 6.0e3; }} ){inputs} }};
"""


@pytest.mark.parametrize("case", ["names", "input", "rate"])
def test_stand_names_the_nodes(capture, tmp_path, case):
    """oma.stand (issue 34 item 3): a stand without inputs names the nodes of the response
    channels; its sample rate is the default and must agree; its measured channels are the
    default response channels; a stand that measures an input is refused."""
    import subprocess

    from conftest import vibidd_path
    inputs = ';\n  inputs = ( { name = "f"; node = "top"; gain = 1.0; channel = "x3"; } )' if case == "input" else ""
    (tmp_path / "named.cfg").write_text(STAND_NAMES.format(fs=FS, inputs=inputs))
    text = CONFIG.format(fs=FS, modes=3, window=WINDOW, every=EVERY, capture=capture, extra="", learn=LEARN)
    rate = "sample_rate = 200.0; " if case == "rate" else ""
    text = text.replace(f"  sample_rate = {FS};\n", f'  stand = "named.cfg"; {rate}\n')
    cfg = tmp_path / "oma.cfg"
    cfg.write_text(text)
    if case == "input":
        with pytest.raises(ValueError, match="measures an input .* not tracked output-only"):
            vibid.replay(cfg)
        return
    if case == "rate":
        with pytest.raises(ValueError, match="oma.sample_rate: 200 Hz, but oma.stand .* says 100 Hz"):
            vibid.replay(cfg)
        return
    out = subprocess.run([str(vibidd_path()), "-c", str(cfg), "--check"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert "  sample_rate = 100.0;  # Hz" in lines
    assert any(ln.startswith('  stand = "') and ln.endswith('named.cfg";  # names the nodes') for ln in lines)
    # the stand's measured channels are the response channels (the covariate is not one)
    assert '  channels = ["x1", "x2", "x3"];' in lines
    for ch, node in (("x1", "base_plate"), ("x2", "column"), ("x3", "top")):
        assert f"  #   {ch}: {node} displacement" in lines
    again = tmp_path / "again.cfg"
    again.write_text(out.stdout)
    second = subprocess.run([str(vibidd_path()), "-c", str(again), "--check"], capture_output=True, text=True,
                            timeout=60)
    assert second.returncode == 0, second.stderr
    strip = lambda s: [ln for ln in s.splitlines()
                       if not ln.startswith("# vibidd effective configuration") and "oma.sample_rate in" not in ln]
    assert strip(second.stdout) == strip(out.stdout)


def run_vibidd(args, timeout=120):
    import subprocess

    from conftest import vibidd_path
    vibidd = vibidd_path()
    if not vibidd.exists():
        pytest.skip(f"no vibidd at {vibidd} (build the C suite first, or set VIBID_VIBIDD)")
    return subprocess.run([str(vibidd)] + args, capture_output=True, text=True, timeout=timeout)


def test_outputs_and_status_of_the_daemon(tmp_path):
    """The vibidd program on an oma configuration, its outputs: tracks, InfluxDB line protocol
    (the modes as fields, the machine's name as the stand tag) and the status file with the
    mode tracker's counters; paced at 40 times the recorded rate, so the identifications run
    in the low-priority oma thread as in a live run (an unpaced replay runs them inline)."""
    n = int(240 * FS)
    y = ambient_segments(M, D, [(K0, n)], FS, noise=0.01, seed=5)
    t = np.arange(n) / FS
    cap = tmp_path / "short.csv"
    pd.DataFrame({"t": t, "x1": y[:, 0], "x2": y[:, 1], "x3": y[:, 2], "temp": 20.0 + 0 * t}).to_csv(
        cap, index=False, float_format="%.9g")
    cfg = tmp_path / "live.cfg"
    text = CONFIG.format(fs=FS, modes=3, window=30.0, every=10.0, capture=cap, extra="", learn=LEARN)
    cfg.write_text(text + f'outputs = {{ tracks = {{ path = "{tmp_path / "tracks.csv"}"; }};\n'
                          f'  influx = {{ path = "{tmp_path / "lines.txt"}"; }};\n'
                          f'  status = {{ path = "{tmp_path / "status"}"; interval = 0.5; }}; }};\n')
    r = run_vibidd(["-c", str(cfg), "--pace", "--speed", "40"])
    assert r.returncode == 0, r.stderr
    tracks = pd.read_csv(tmp_path / "tracks.csv", comment="#")
    # 24 requests (every 10 s), at most 2 while the window (30 s) fills: 22 identified, or
    # skipped because the thread was still busy (counted; the SCHED_IDLE thread gets almost
    # no CPU while the machine is busy with other work); the last one is waited for
    status = dict(ln.split("=", 1) for ln in (tmp_path / "status").read_text().splitlines() if "=" in ln)
    done, skipped = int(status["oma_identifications"]), int(status["oma_skipped"])
    print(f"{len(tracks)} rows, {done} identifications, {skipped} skipped, last took "
          f"{status['oma_last_duration_s']} s")
    assert done + skipped >= 22 and len(tracks) == done and done >= 1
    assert int(status["oma_lost_samples"]) == 0
    for j in range(3):
        f = tracks[f"f{j + 1}_hz"].dropna()
        assert len(f) >= 0.8 * len(tracks) and np.all(np.abs(f / F0[j] - 1) < 0.02)
    lines = (tmp_path / "lines.txt").read_text().splitlines()
    assert len(lines) == len(tracks)  # a line per row (a row without any mode has no field: none here)
    assert all(ln.startswith("vibid,stand=chain3 ") and " f1_hz=" in ln and ",f1_hz_se=" in ln for ln in lines
               if "f1_hz" in ln)
    assert sum(",zeta3=" in ln for ln in lines) >= 0.8 * len(lines)


def test_monitor_events(capture):
    """vibid.monitor on the oma configuration: vibidd's change test on the modes, its events:
    f1 and f3 raised, the onset at the first disjoint window wholly after the change, the
    estimated change within 3 of its standard errors of the true one (1.8 and 0.4 measured)."""
    m = vibid.monitor(write_config(capture.parent, capture), [capture], log_level="error")
    ev = m.events
    print(ev.to_string())
    assert list(ev["state"]) == ["raised", "raised"] and set(ev["parameter"]) == {"f1_hz", "f3_hz"}
    for _, e in ev.iterrows():
        j = int(e["parameter"][1]) - 1
        assert T_CHANGE * FS <= e["onset_index"] <= (T_CHANGE + 2 * WINDOW) * FS
        assert abs(e["change"] - (F1[j] - F0[j])) <= 3 * e["change_se"]
