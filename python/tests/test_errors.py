"""Bad input: clear exceptions naming what is wrong."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

import vibid
from conftest import example1_capture


def test_vibid_error_is_runtime_error():
    assert issubclass(vibid.VibidError, RuntimeError)


def test_unknown_channel_name(example1_stand, ex1_clean):
    data, _ = ex1_clean
    bad = dict(data)
    bad["x3"] = bad.pop("x2")
    with pytest.raises(ValueError, match="unknown channel 'x3'"):
        vibid.identify(example1_stand, bad)


def test_missing_channel(example1_stand, ex1_clean):
    data, _ = ex1_clean
    df = pd.DataFrame({k: v for k, v in data.items() if k != "s"})
    with pytest.raises(ValueError, match="channel 's' missing"):
        vibid.identify(example1_stand, df)


def test_wrong_length(example1_stand, ex1_clean):
    data, _ = ex1_clean
    bad = dict(data)
    bad["x2"] = bad["x2"][:-1]
    with pytest.raises(ValueError, match="channel 'x2' has 19999 samples"):
        vibid.identify(example1_stand, bad)


def test_wrong_shape(example1_stand, ex1_clean):
    data, _ = ex1_clean
    with pytest.raises(ValueError, match=r"shape \(n_samples, 3\)"):
        vibid.identify(example1_stand, np.zeros((100, 2)))
    bad = dict(data)
    bad["x1"] = np.zeros((10, 2))
    with pytest.raises(ValueError, match="channel 'x1': a 1-D array"):
        vibid.identify(example1_stand, bad)


def test_nan_names_channel_and_row(example1_stand, ex1_clean):
    data, _ = ex1_clean
    bad = {k: v.copy() for k, v in data.items()}
    bad["x2"][1234] = np.nan
    with pytest.raises(ValueError, match="channel 'x2': non-finite value nan at row 1234"):
        vibid.identify(example1_stand, bad)


def test_glitch_names_channel_and_row(example1_stand, ex1_clean):
    # Issue 30, item 2: one wild value used to poison every later estimate without a word;
    # identify takes no gaps, so the outlier test vibidd runs (vibid/outlier.h) names it.
    # The clean capture (a multisine, both modes) has none: every other test identifies it.
    data, _ = ex1_clean
    for g in (1.0, 1e3, 1e300):
        bad = {k: v.copy() for k, v in data.items()}
        bad["x1"][8000] = g
        with pytest.raises(ValueError, match=r"channel 'x1': value .* at row 8000 is a single-sample glitch \(1 in"):
            vibid.identify(example1_stand, bad)


def test_time_column_at_another_rate(example1_stand, ex1_clean):
    data, t = ex1_clean
    df = pd.DataFrame({"t": t * 1.02, **data})  # 2 % slower clock
    with pytest.raises(ValueError, match="1960.78 Hz, the stand 'paper_example1' says 2000 Hz"):
        vibid.identify(example1_stand, df)


def test_bad_method(example1_stand, ex1_clean):
    with pytest.raises(ValueError, match="method 'foo'"):
        vibid.identify(example1_stand, ex1_clean[0], method="foo")


def test_library_refuses_bad_forgetting(example1_stand, ex1_clean):
    # checked by the library, not here: its message names the function and the argument
    with pytest.raises(vibid.VibidError, match="forgetting"):
        vibid.identify(example1_stand, ex1_clean[0], forgetting=1.5)


def test_too_few_samples(example1_stand):
    data, _ = example1_capture(n=6)
    with pytest.raises(vibid.VibidError, match="vibid_ident_estimate after 6 samples"):
        vibid.identify(example1_stand, data)


STAND_WITH_TYPO = """stand = {
  name = "typo";
  sample_rate = 1000.0;
  nodes = ( { name = "m1"; mass = 1.0; measure = { displacement = "x1"; }; } );
  elements = (
    { name = "k"; kind = "spring"; between = ["m1", "ground"]; unknown = true; value = 100.0; },
    { name = "d"; kind = "sprung"; between = ["m1", "ground"]; value = 1.0; }
  );
  inputs = ( { name = "f"; node = "m1"; channel = "F"; } );
};
"""


def test_stand_file_error_names_file_and_line(tmp_path):
    path = tmp_path / "typo.cfg"
    path.write_text(STAND_WITH_TYPO)
    with pytest.raises(vibid.VibidError) as ei:
        vibid.Stand.load(path)
    # the loader's "file:line: field: reason"; line 7 is the element with kind "sprung"
    assert re.search(re.escape(str(path)) + r":7: stand\.elements\.\[1\]\.kind: 'sprung' is not one of spring, damper, cubic_spring",
                     str(ei.value)), str(ei.value)


def test_stand_file_syntax_error(tmp_path):
    path = tmp_path / "syntax.cfg"
    path.write_text('stand = {\n  name = "x";\n  sample_rate = = 1.0;\n};\n')  # '= =' on line 3
    with pytest.raises(vibid.VibidError, match=re.escape(str(path)) + r":3: "):
        vibid.Stand.load(path)


def test_missing_stand_file(tmp_path):
    path = tmp_path / "nope.cfg"
    with pytest.raises(vibid.VibidError, match=re.escape(str(path)) + ": cannot read: No such file or directory"):
        vibid.Stand.load(path)


def test_from_dict_error_names_field():
    with pytest.raises(vibid.VibidError, match=r"^stand dict: stand\.nodes\.\[0\]\.mass_unknown: unknown setting"):
        vibid.Stand.from_dict({"sample_rate": 100.0,
                               "nodes": [{"name": "m1", "mass_unknown": True, "measure": {"displacement": "x"}}]})


def test_not_identifiable_names_parameters():
    # Two springs in parallel from m1 to ground, both unknown: only their sum shows in the
    # data. The library refuses before any sample and names both (identify.h).
    st = vibid.Stand.from_dict({
        "sample_rate": 1000.0,
        "nodes": [{"name": "m1", "mass": 1.0, "measure": {"displacement": "x1"}}],
        "elements": [
            {"name": "ka", "kind": "spring", "between": ["m1", "ground"], "unknown": True, "value": 100.0},
            {"name": "kb", "kind": "spring", "between": ["m1", "ground"], "unknown": True, "value": 50.0},
            {"name": "d", "kind": "damper", "between": ["m1", "ground"], "value": 1.0},
        ],
        "inputs": [{"name": "f", "node": "m1", "channel": "F"}],
    })
    data = {"x1": np.sin(np.arange(1000) * 0.05), "F": np.cos(np.arange(1000) * 0.05)}
    with pytest.raises(vibid.VibidError) as ei:
        vibid.identify(st, data)
    msg = str(ei.value)
    assert "ka" in msg and "kb" in msg, msg


def test_binding_reports_push_status(example1_stand):
    # Below identify's own checks: the C status and message reach Python as VibidError,
    # with the row where the row loop stopped (push_block does not say which sample).
    from vibid import _core
    block = np.ones((50, 3))
    block[5, 1] = np.nan
    ident = _core.Ident(example1_stand._core, _core.ESTIMATOR_AUTO, 1.0, -1.0, 0)
    with pytest.raises(vibid.VibidError, match=r"vibid_ident_push \(row 5\): NaN or Inf in input data: vibid_regressor_push"):
        ident.push(block, 0, 50)  # C order: the row loop
    with pytest.raises(vibid.VibidError, match=r"vibid_ident_push_block: NaN or Inf in input data"):
        ident.push(np.asfortranarray(block), 0, 50)  # the whole column-major block
    with pytest.raises(ValueError, match="2 columns for 3 channels"):
        ident.push(np.ones((5, 2)), 0, 5)


# ---- damaged and odd capture files (issue 33 item 3): one line naming the file, where in it
# and the cause; vibid.CaptureError (a VibidError and a ValueError); the command exits 2 with
# that line and no traceback

def _bad_captures(d):
    """{name: (path, expected message regex)} of files as analysts meet them."""
    from test_captures import write_mdf

    data, t = example1_capture(n=4000, noise=0.001, seed=5)
    good = d / "good.csv"
    pd.DataFrame({"t": t, **data}).to_csv(good, index=False)
    lines = good.read_text().splitlines()

    def csv_with(name, lineno, cell):  # line `lineno` (1-based) with x1 replaced by cell
        out = list(lines)
        f = out[lineno - 1].split(",")
        f[1] = cell
        out[lineno - 1] = ",".join(f)
        p = d / name
        p.write_text("\n".join(out) + "\n")
        return p

    mdf = write_mdf(d / "good.mf4", [(t, {c: (data[c], "m") for c in ("x1", "x2", "s")})])
    half = d / "half.mf4"
    half.write_bytes(mdf.read_bytes()[: mdf.stat().st_size // 2])
    (d / "empty.csv").write_text("")
    (d / "empty.mf4").write_bytes(b"")
    (d / "comments.csv").write_text("# a comment only\n")
    (d / "header.csv").write_text("t,x1,x2,s\n")
    pd.DataFrame({"t": 2 * t, **data}).to_csv(d / "rate.csv", index=False)
    return {
        "half": (half, r"half\.mf4: cannot be read as ASAM MDF4 \(\d+ bytes; damaged or cut short\?\): "),
        "empty_csv": (d / "empty.csv", r"empty\.csv: empty file \(0 bytes\)"),
        "empty_mdf": (d / "empty.mf4", r"empty\.mf4: empty file \(0 bytes\)"),
        "comments": (d / "comments.csv", r"comments\.csv: no header line: the file is empty or holds only '#'"),
        "header": (d / "header.csv", r"header\.csv: a header and no data rows"),
        # line 6 of the file is data row 4 (the header is line 1)
        "cell": (csv_with("cell.csv", 6, "1.2.3"), r"cell\.csv:6: channel 'x1': '1\.2\.3' is not a number"),
        "nan": (csv_with("nan.csv", 9, "nan"), r"nan\.csv:9: channel 'x1': non-finite value nan at row 7"),
        "rate": (d / "rate.csv", r"rate\.csv: the capture's time column gives 1000 Hz, the stand 'paper_example1' "
                                 r"says 2000 Hz"),
        "missing": (d / "nope.csv", r"nope\.csv: no such file"),
    }


@pytest.fixture(scope="module")
def bad_captures(tmp_path_factory):
    return _bad_captures(tmp_path_factory.mktemp("bad_captures"))


@pytest.mark.parametrize("case", ["half", "empty_csv", "empty_mdf", "comments", "header", "cell", "nan", "rate",
                                  "missing"])
def test_bad_capture_files_name_file_and_line(bad_captures, example1_stand, case, capfd):
    path, pattern = bad_captures[case]
    with pytest.raises(vibid.CaptureError, match=pattern) as info:
        vibid.identify(example1_stand, path)
    assert isinstance(info.value, vibid.VibidError) and isinstance(info.value, ValueError)
    assert "\n" not in str(info.value)
    assert str(path) in str(info.value)
    # nothing else printed (asammdf's destructor traceback after a damaged file is not)
    err = capfd.readouterr().err
    assert "Traceback" not in err and "Exception ignored" not in err, err


@pytest.mark.parametrize("case", ["half", "empty_mdf", "cell", "nan"])
def test_bad_capture_files_in_the_command(bad_captures, case):
    import subprocess
    import sys
    from pathlib import Path

    from conftest import EXAMPLE1

    path, pattern = bad_captures[case]
    vibid_cmd = Path(sys.executable).with_name("vibid")
    proc = subprocess.run([str(vibid_cmd), "identify", str(EXAMPLE1), str(path)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert re.fullmatch(r"vibid identify: error: /\S*" + pattern + r".*\n", proc.stderr), proc.stderr
