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
