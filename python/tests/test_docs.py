"""The examples of docs/python.md run, in order, in one namespace, as a notebook would run
them (issue 13): an example that no longer works with the package fails here.

Every ```python block runs, except those fenced as ```python no-run (a Dask scheduler
address, say), which are counted and reported. ```sh blocks are commands for a shell, not
Python, and are not run. The blocks run in a temporary directory holding the files they name,
written by the test from conftest's exact responses of example 1 (0.5 % noise) with the
libraries analysts' tools use (pandas for CSV, asammdf for MDF4, npTDMS for TDMS):

    examples/stands/paper_example1.cfg   a copy of the repository's
    capture.csv                          10 s at 2 kHz, time_s, x1, x2, s
    run7.mf4                             the same channels, 4 s
    run7.tdms                            group "Run 7", channels "Weg 1", "Weg 2", "Sockel"
    runs/run0.csv .. runs/run2.csv       three captures of 2 s
    run1.mf4                             another 2 s
    stand.dbc, run7.log, map.cfg         sim/paper_example1.dbc, a candump log of it written
                                         by vibid-sim (4 s), a channel map of its signals
    vibidd.cfg                           vibidd replaying a candump log with stand.dbc
    day1.csv, day2.csv, monitor.cfg      60 s each of sim/examples/service_temperature_sim.cfg
                                         (vibid-sim, seeds 1 and 2) and vibidd with T a covariate
    daemon/examples/replay_csv.cfg       the repository's, beside the capture.csv it names
    ambient.csv                          120 s of a 3-DOF chain's response to unmeasured forces
                                         (oma_sim.py): time_s, a1, a2, a3 at 200 Hz

Blocks that need what an optional part of the build provides (the drivers for candump logs,
vibidd's core for vibid.replay, vibid-sim to write the log) are skipped, counted and named
when it is missing, as the suites of those parts skip (test_candump.py, test_replay.py);
scripts/test.sh builds all of them, so there every block runs.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import traceback
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from vibid import _core
from conftest import EX1_TRUTH, EXAMPLE1, REPO, example1_capture, no_skip, sim_path
from test_captures import waveform, write_mdf, write_tdms

DOC = REPO / "docs" / "python.md"
NOISE = 0.005
# The ```python blocks of docs/python.md that must run (Example, from_dict, plot, Capture
# formats, Estimator classes, Many captures): an extractor that finds nothing, or a marker
# put on a block that should run, must not pass.
MIN_BLOCKS_RUN = 6

# A fence: three backticks and an info string without backticks (CommonMark), so that prose
# quoting a fence in inline code is not taken for one.
FENCE = re.compile(r"^\s*```([^`]*)$")

SIM_CFG = REPO / "sim" / "examples" / "paper_example1_sim.cfg"
SIM_DBC = REPO / "sim" / "paper_example1.dbc"


def missing_parts(code: str) -> list[str]:
    """What a block needs that this build or machine lacks (empty: it can run)."""
    out = []
    candump = "dbc=" in code or ".log\"" in code
    if candump and not getattr(_core, "HAVE_DRIVERS", False):
        out.append("vibid built without the drivers (candump)")
    if "vibid.replay(" in code and not getattr(_core, "HAVE_DAEMON", False):
        out.append("vibid built without vibidd's core (vibid.replay)")
    if candump and not sim_path().exists():
        out.append(f"no vibid-sim at {sim_path()} to write run7.log (set VIBID_SIM)")
    if "vibid.monitor(" in code and not getattr(_core, "HAVE_DAEMON", False):
        out.append("vibid built without vibidd's core (vibid.monitor)")
    if "vibid.monitor(" in code and not sim_path().exists():
        out.append(f"no vibid-sim at {sim_path()} to write day1.csv, day2.csv (set VIBID_SIM)")
    return out


def doc_blocks(text: str) -> list[tuple[int, str, str]]:
    """(line of the block's first code line, info string of the fence, code) for every fenced
    block of the Markdown text, in order. The info string is what follows the backticks:
    "python", "python no-run", "sh"."""
    blocks, info, start, lines = [], None, 0, []
    for i, line in enumerate(text.splitlines(), start=1):
        m = FENCE.match(line)
        if m and info is None:
            info, start, lines = m.group(1).strip(), i + 1, []
        elif m and not m.group(1).strip():
            blocks.append((start, info, "\n".join(lines) + "\n"))
            info = None
        elif info is not None:
            lines.append(line)
    assert info is None, f"{DOC}: the block opened at line {start - 1} is never closed"
    return blocks


def write_files(d: Path) -> None:
    (d / "examples" / "stands").mkdir(parents=True)
    shutil.copy(EXAMPLE1, d / "examples" / "stands" / "paper_example1.cfg")

    def csv(path, n, seed):
        data, t = example1_capture(n=n, noise=NOISE, seed=seed)
        pd.DataFrame({"time_s": t, **data}).to_csv(path, index=False, float_format="%.17g")

    csv(d / "capture.csv", 20_000, 1)
    (d / "runs").mkdir()
    for i in range(3):
        csv(d / "runs" / f"run{i}.csv", 4000, 30 + i)
    for name, n, seed in (("run7.mf4", 8000, 7), ("run1.mf4", 4000, 8)):
        data, t = example1_capture(n=n, noise=NOISE, seed=seed)
        write_mdf(d / name, [(t, {c: (data[c], "m") for c in ("x1", "x2", "s")})])
    data, t = example1_capture(n=8000, noise=NOISE, seed=9)
    write_tdms(d / "run7.tdms", {"Run 7": {name: (data[c], waveform("m"))
                                           for c, name in (("x1", "Weg 1"), ("x2", "Weg 2"), ("s", "Sockel"))}})
    # vibidd's example configuration, with its relative paths intact: the stand two levels up
    # (written above) and a CSV capture beside it with the time column it names, t.
    (d / "daemon" / "examples").mkdir(parents=True)
    shutil.copy(REPO / "daemon" / "examples" / "replay_csv.cfg", d / "daemon" / "examples" / "replay_csv.cfg")
    data, t = example1_capture(n=8000, noise=NOISE, seed=10)
    pd.DataFrame({"t": t, **data}).to_csv(d / "daemon" / "examples" / "capture.csv", index=False,
                                          float_format="%.17g")
    # output-only modal analysis: 120 s of the 3-DOF chain's displacements under unmeasured
    # white forces (oma_sim.py), 200 Hz
    from oma_sim import ambient, chain_matrices

    y = ambient(*chain_matrices([1.0, 1.5, 1.0], [1e4, 8e3, 6e3], [4.0, 3.0, 2.0]), 200.0, 24000, seed=5)
    pd.DataFrame({"time_s": np.arange(len(y)) / 200.0, "a1": y[:, 0], "a2": y[:, 1], "a3": y[:, 2]}).to_csv(
        d / "ambient.csv", index=False, float_format="%.17g")
    # candump: vibid-sim's frames as sim/paper_example1.dbc describes them (test_candump.py).
    shutil.copy(SIM_DBC, d / "stand.dbc")
    if sim_path().exists():
        subprocess.run([str(sim_path()), "-c", str(EXAMPLE1), "-s", str(SIM_CFG), "--duration", "4",
                        "--candump", str(d / "run7.log"), "--fast", "-q"], check=True, capture_output=True,
                       timeout=120)
    # monitoring: two days of the temperature example (sim/examples/service_temperature_sim.cfg,
    # 60 s each, other seeds) and vibidd's configuration with T as a covariate
    if sim_path().exists():
        for day, seed in (("day1.csv", "1"), ("day2.csv", "2")):
            subprocess.run([str(sim_path()), "-c", str(EXAMPLE1), "-s",
                            str(REPO / "sim" / "examples" / "service_temperature_sim.cfg"), "--duration", "60",
                            "--seed", seed, "--csv", str(d / day), "-q"], check=True, capture_output=True,
                           timeout=120)
    (d / "monitor.cfg").write_text("""stand = "examples/stands/paper_example1.cfg";
source = {
  kind = "replay"; file = "day1.csv"; time_column = "t";
  channels = (
    { name = "x1"; quantity = "displacement"; node = 0; unit = "m"; column = "x1"; },
    { name = "x2"; quantity = "displacement"; node = 1; unit = "m"; column = "x2"; },
    { name = "s";  quantity = "base_displacement"; unit = "m"; column = "s"; },
    { name = "T";  quantity = "covariate"; unit = "degC"; column = "T"; }
  );
};
estimator = { forgetting = 0.999; decimation = 200; };
alarms = { learn_duration = 40.0; };
outputs = { tracks = { path = "tracks.csv"; }; };
""")
    (d / "map.cfg").write_text("""counter = "SampleCounter";
channels = (
  { name = "x1"; quantity = "displacement"; node = 0; unit = "m"; signal = "x1"; },
  { name = "x2"; quantity = "displacement"; node = 1; unit = "m"; signal = "x2"; },
  { name = "s";  quantity = "base_displacement"; unit = "m"; signal = "s"; }
);
""")
    (d / "vibidd.cfg").write_text("""stand = "examples/stands/paper_example1.cfg";
source = {
  kind = "replay"; file = "run7.log"; dbc = "stand.dbc"; counter = "SampleCounter";
  channels = (
    { name = "x1"; quantity = "displacement"; node = 0; unit = "m"; signal = "x1"; },
    { name = "x2"; quantity = "displacement"; node = 1; unit = "m"; signal = "x2"; },
    { name = "s";  quantity = "base_displacement"; node = 0; unit = "m"; signal = "s"; }
  );
};
estimator = { decimation = 200; };
outputs = { tracks = { path = "tracks.csv"; }; };
""")


def test_docs_python_examples_run(tmp_path, monkeypatch, capsys):
    pytest.importorskip("matplotlib")  # the plot example (extra plot; in the test venv)
    pytest.importorskip("asammdf")
    pytest.importorskip("nptdms")
    blocks = doc_blocks(DOC.read_text())
    python = [b for b in blocks if b[1].split()[:1] == ["python"]]
    skipped = [b for b in python if "no-run" in b[1].split()[1:]]
    other = len(blocks) - len(python)
    write_files(tmp_path)
    monkeypatch.chdir(tmp_path)
    ns: dict = {"__name__": "__docs__"}
    ran, unavailable = 0, []
    for line, info, code in python:
        if "no-run" in info.split()[1:]:
            continue
        why = missing_parts(code)
        if why:
            unavailable.append(f"line {line - 1}: {'; '.join(why)}")
            continue
        first = code.strip().splitlines()[0] if code.strip() else ""
        # Padded to the block's place in the file, so that a traceback names docs/python.md
        # and the line of the failing statement.
        compiled = compile("\n" * (line - 1) + code, str(DOC), "exec")
        failure = None
        try:
            exec(compiled, ns)
        except Exception as e:
            failure = (f"docs/python.md, block at line {line} ({first!r}): {type(e).__name__}: {e}\n"
                       + "".join(traceback.format_exception(e)[-4:]))
        if failure:  # outside the except: the report is the block's, not pytest's own chain
            pytest.fail(failure, pytrace=False)
        ran += 1
    with capsys.disabled():
        print(f"\ndocs/python.md: {len(python)} python blocks, {ran} ran, {len(skipped)} skipped by the "
              f"no-run marker (lines {', '.join(str(b[0] - 1) for b in skipped) or '-'}); "
              f"{len(unavailable)} skipped for a missing part of the build; {other} blocks of other languages "
              "(sh) not run")
        for u in unavailable:
            print(f"  skipped, a part of the build is missing: {u}")
    if unavailable and no_skip():
        pytest.fail("docs/python.md blocks not run for a missing part of the build (in CI a missing "
                    "install): " + "; ".join(unavailable), pytrace=False)
    assert ran >= MIN_BLOCKS_RUN, f"only {ran} python blocks ran"

    # What the examples computed is right, not only free of exceptions. Example 1, 10 s with
    # 0.5 % noise: the automatic estimator within 1 % of the truth (the tests' tolerance for
    # this case, test_identify.py; measured there 0.008 %).
    truth = np.array([EX1_TRUTH[p] for p in ns["stand"].parameters])
    np.testing.assert_allclose(ns["result"].parameters["value"].to_numpy(), truth, rtol=1e-2)
    assert ns["stand"].channels == ["x1", "x2", "s"]  # as the example's comment says
    assert len(ns["tracked"].tracks) == 100  # 20,000 samples, a row per 200
    assert (tmp_path / "tracks.png").stat().st_size > 0
    # The EKF from start values 17-20 % off: within 1 % (test_estimators.py allows 0.8 % on the
    # noise-free capture, from the inputs' bend within a sample; 0.5 % noise adds its spread).
    np.testing.assert_allclose(ns["ekf"].estimate().theta, truth, rtol=1e-2)
    # LeastSquares and RLS on the doc's regression: theta within 5 of its standard errors of
    # the truth (a chance of ~6e-7 per entry for a right estimate).
    for est in (ns["ls"], ns["rls"]):
        theta = est.solve() if est is ns["ls"] else est.theta
        assert (np.abs(theta - ns["theta_true"]) < 5 * est.standard_errors()).all(), (theta, ns["theta_true"])
    # identify_many: every capture of both tables identified.
    assert (ns["table"]["status"] == "ok").all(), ns["table"]
    assert len(ns["table"]) == 2
