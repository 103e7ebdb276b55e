"""Capture files: ASAM MDF4 and NI TDMS (vibid.read_capture, identify on a path).

The files are written by the libraries analysts' tools use (asammdf, npTDMS), never by
hand, from the exact responses of conftest.py; so these tests check that vibid reads what
those libraries write, not what we think the formats are. The extras are installed by
scripts/python-venv.sh: the importorskip below skips only where they are not.
"""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd
import pytest

import vibid

FA = 2000.0  # example 1's sample rate (examples/stands/paper_example1.cfg)


def write_mdf(path, groups, comment="vibid test capture"):
    """An MDF 4.10 file by asammdf: groups is a list of (time stamps, {name: (values, unit)}),
    one data group (one master time channel) each."""
    pytest.importorskip("asammdf")
    from asammdf import MDF, Signal

    mdf = MDF(version="4.10")
    for t, chans in groups:
        mdf.append([Signal(np.asarray(v), np.asarray(t), name=n, unit=u) for n, (v, u) in chans.items()],
                   comment=comment)
    mdf.save(path, overwrite=True)
    mdf.close()
    return path


def write_tdms(path, groups):
    """A TDMS file by npTDMS: groups is {group: {channel: (values, properties)}}."""
    pytest.importorskip("nptdms")
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    objs = [RootObject({"name": "vibid test capture"})]
    for g, chans in groups.items():
        objs.append(GroupObject(g))
        objs += [ChannelObject(g, n, np.asarray(v), properties=p) for n, (v, p) in chans.items()]
    with TdmsWriter(path) as w:
        w.write_segment(objs)
    return path


def waveform(unit, increment=1.0 / FA, offset=0.0):
    """TDMS waveform properties as NI's loggers write them."""
    p = {"wf_increment": increment, "wf_start_offset": offset}
    if unit is not None:
        p["unit_string"] = unit
    return p


def assert_same_result(r, ref):
    # Bit-identical: the same float64 samples reach the same C estimator (float64 is
    # stored as such by both formats, and read_capture does not touch a value whose unit is
    # the stand's), so any difference would be a changed, reordered or shifted sample.
    np.testing.assert_array_equal(r.parameters["value"], ref.parameters["value"])
    np.testing.assert_array_equal(r.parameters["se"], ref.parameters["se"])
    np.testing.assert_array_equal(r.covariance, ref.covariance)


# Relative error of a value written in mm and read back in m: x -> fl(1000 x) ->
# fl(fl(1000 x) * fl(1e-3)): two roundings of half an ulp each (1.1e-16) and fl(1e-3)'s own
# error (2.1e-17), 2.4e-16 at most.
MM_ROUNDTRIP = 2.5e-16
# The estimate from samples each perturbed by up to 2.4e-16 relative. Measured: values
# 8.9e-16 relative apart, standard errors 1.3e-11. The values move like the samples (a few
# ulp: 1e-13 leaves a factor of 100). The automatic estimator's standard errors come from
# the spread of its block estimates, which noise-free is only ~5e-5 of the values, so a
# 1e-15 change of each block's estimate is ~2e-11 of that spread: 1e-9 leaves a factor of
# 75. Both are many orders below a wrong factor (a unit mix-up is 1e3, inches 2.54e-2).
MM_VALUE_RTOL = 1e-13
MM_SE_RTOL = 1e-9


@pytest.fixture(scope="module")
def ref(example1_stand, ex1_clean):
    return vibid.identify(example1_stand, ex1_clean[0])


@pytest.fixture(scope="module")
def ref_ee(example1_stand, ex1_clean):
    # The library's automatic estimator alone (holdout=0) for the unit tests in mm: the
    # tolerances above are its. auto's validated choice keeps the output-error fit here,
    # whose Levenberg-Marquardt stops within 1e-4 of its standard errors of the optimum
    # (output_error.h), so a perturbation of the samples by an ulp can move its estimate by
    # more than an ulp (measured 1.4e-12 relative).
    return vibid.identify(example1_stand, ex1_clean[0], holdout=0)


# ---------------------------------------------------------------------------- MDF4


def test_mdf4_identify_bit_identical(tmp_path, example1_stand, ex1_clean, ref):
    data, t = ex1_clean
    path = write_mdf(tmp_path / "capture.mf4", [(t, {c: (data[c], "m") for c in ("s", "x2", "x1")})])
    df = vibid.read_capture(path, example1_stand)
    # stand order whatever the file's, and the master as time_s, all exactly as written
    assert list(df.columns) == ["x1", "x2", "s", "time_s"]
    for c in ("x1", "x2", "s"):
        np.testing.assert_array_equal(df[c].to_numpy(), data[c])
    np.testing.assert_array_equal(df["time_s"].to_numpy(), t)
    assert_same_result(vibid.identify(example1_stand, path), ref)
    assert_same_result(vibid.identify(example1_stand, str(path)), ref)


def test_mdf4_in_mm_equals_si(tmp_path, example1_stand, ex1_clean, ref_ee):
    data, t = ex1_clean
    path = write_mdf(tmp_path / "mm.mf4", [(t, {c: (1000.0 * data[c], "mm") for c in ("x1", "x2", "s")})])
    df = vibid.read_capture(path, example1_stand)
    for c in ("x1", "x2", "s"):
        np.testing.assert_allclose(df[c].to_numpy(), data[c], rtol=MM_ROUNDTRIP, atol=0)
    r = vibid.identify(example1_stand, path, holdout=0)
    np.testing.assert_allclose(r.parameters["value"], ref_ee.parameters["value"], rtol=MM_VALUE_RTOL, atol=0)
    np.testing.assert_allclose(r.parameters["se"], ref_ee.parameters["se"], rtol=MM_SE_RTOL, atol=0)


def test_mdf4_empty_unit_is_the_stands(tmp_path, example1_stand, ex1_clean, ref):
    # no unit in the file: the values are taken in the stand's units (SI here), unchanged
    data, t = ex1_clean
    path = write_mdf(tmp_path / "nounit.mf4", [(t, {c: (data[c], "") for c in ("x1", "x2", "s")})])
    assert_same_result(vibid.identify(example1_stand, path), ref)


def test_mdf4_wrong_unit_names_channel(tmp_path, example1_stand, ex1_clean):
    data, t = ex1_clean
    path = write_mdf(tmp_path / "wrong.mf4", [(t, {"x1": (data["x1"], "m"), "x2": (data["x2"], "N"),
                                                   "s": (data["s"], "m")})])
    with pytest.raises(ValueError, match=r"channel 'x2' in .*wrong\.mf4 \(m2\.displacement, a displacement\): "
                                         r"'N' is not a length unit \(m, cm, mm, um, nm, in\)"):
        vibid.identify(example1_stand, path)


def test_mdf4_missing_channel_lists_the_files(tmp_path, example1_stand, ex1_clean):
    data, t = ex1_clean
    path = write_mdf(tmp_path / "two.mf4", [(t, {"x1": (data["x1"], "m"), "x2": (data["x2"], "m"),
                                                 "F9": (data["s"], "N")})])
    # the file's channels without the master ('time')
    with pytest.raises(ValueError, match=r"channel 's' missing: .*two\.mf4 has channels \['x1', 'x2', 'F9'\]"):
        vibid.identify(example1_stand, path)


def test_mdf4_renamed_channels(tmp_path, example1_stand, ex1_clean, ref):
    data, t = ex1_clean
    path = write_mdf(tmp_path / "renamed.mf4", [(t, {"Pos1": (data["x1"], "m"), "Pos2": (data["x2"], "m"),
                                                     "Base": (data["s"], "m")})])
    names = {"x1": "Pos1", "x2": "Pos2", "s": "Base"}
    df = vibid.read_capture(path, example1_stand, channels=names)
    assert list(df.columns) == ["x1", "x2", "s", "time_s"]
    assert_same_result(vibid.identify(example1_stand, df), ref)
    # without the mapping, the error says which name was looked for and what is there
    with pytest.raises(ValueError, match=r"channel 'x1' missing: .* has channels \['Pos1', 'Pos2', 'Base'\]"):
        vibid.read_capture(path, example1_stand)
    # a mapping names the file's channel in the error when that one is missing
    with pytest.raises(ValueError, match=r"channel 's' \(as 'Bas' in the file\) missing"):
        vibid.read_capture(path, example1_stand, channels={**names, "s": "Bas"})


def test_mdf4_channel_at_another_rate_refused(tmp_path, example1_stand, ex1_clean):
    # s in its own data group at 1 kHz (every other sample), x1 and x2 at 2 kHz: aligning
    # them would need invented samples; refused naming both channels and rates.
    data, t = ex1_clean
    path = write_mdf(tmp_path / "rates.mf4", [(t, {"x1": (data["x1"], "m"), "x2": (data["x2"], "m")}),
                                              (t[::2], {"s": (data["s"][::2], "m")})])
    with pytest.raises(ValueError, match=r"channels 'x1' \(data group 0: 20000 samples, 2000 Hz from 0 s\) and "
                                         r"'s' \(data group 1: 10000 samples, 1000 Hz from 0 s\) are on different "
                                         r"time bases: vibid .* never resamples"):
        vibid.identify(example1_stand, path)


def test_mdf4_same_rate_other_start_refused(tmp_path, example1_stand, ex1_clean):
    # Same rate and length but started half a sample later: one index would pair samples
    # 0.25 ms apart. Refused too.
    data, t = ex1_clean
    path = write_mdf(tmp_path / "shift.mf4", [(t, {"x1": (data["x1"], "m"), "x2": (data["x2"], "m")}),
                                              (t + 0.5 / FA, {"s": (data["s"], "m")})])
    with pytest.raises(ValueError, match=r"'s' \(data group 1: 20000 samples, 2000 Hz from 0.00025 s\)"):
        vibid.read_capture(path, example1_stand)


def test_mdf4_channels_in_two_groups_on_one_time_base(tmp_path, example1_stand, ex1_clean, ref):
    # Two data groups whose masters are the same time stamps: one time base, accepted.
    data, t = ex1_clean
    path = write_mdf(tmp_path / "groups.mf4", [(t, {"x1": (data["x1"], "m"), "x2": (data["x2"], "m")}),
                                               (t.copy(), {"s": (data["s"], "m")})])
    assert_same_result(vibid.identify(example1_stand, path), ref)


def test_mdf4_time_base_2_percent_off_refused(tmp_path, example1_stand, ex1_clean):
    # The stand says 2 kHz, the recorder's clock 1960.78 Hz: the existing rate check
    # (more than 1 % apart, as vibidd) refuses it, naming both rates.
    data, t = ex1_clean
    path = write_mdf(tmp_path / "slow.mf4", [(t * 1.02, {c: (data[c], "m") for c in ("x1", "x2", "s")})])
    with pytest.raises(ValueError, match=r"1960\.78 Hz, the stand 'paper_example1' says 2000 Hz"):
        vibid.identify(example1_stand, path)


def test_mdf4_invalid_samples_refused_with_row(tmp_path, example1_stand, ex1_clean):
    # Samples the recorder marked invalid (MDF4 invalidation bits) carry no value: they
    # become NaN, which identify refuses naming the channel and the row.
    pytest.importorskip("asammdf")
    from asammdf import MDF, Signal

    data, t = ex1_clean
    inv = np.zeros(len(t), dtype=bool)
    inv[4321] = True
    mdf = MDF(version="4.10")
    mdf.append([Signal(data["x1"], t, name="x1", unit="m"),
                Signal(data["x2"], t, name="x2", unit="m", invalidation_bits=inv),
                Signal(data["s"], t, name="s", unit="m")])
    path = tmp_path / "invalid.mf4"
    mdf.save(path, overwrite=True)
    mdf.close()
    with pytest.raises(ValueError, match="channel 'x2': non-finite value nan at row 4321"):
        vibid.identify(example1_stand, path)


# ---------------------------------------------------------------------------- TDMS


def test_tdms_identify_bit_identical(tmp_path, example1_stand, ex1_clean, ref):
    data, t = ex1_clean
    path = write_tdms(tmp_path / "capture.tdms",
                      {"Measured": {c: (data[c], waveform("m")) for c in ("x2", "s", "x1")}})
    df = vibid.read_capture(path, example1_stand)
    assert list(df.columns) == ["x1", "x2", "s", "time_s"]
    for c in ("x1", "x2", "s"):
        np.testing.assert_array_equal(df[c].to_numpy(), data[c])
    # wf_start_offset + k wf_increment, k / 2000 in conftest: equal to the rounding of a
    # product and a quotient (a few ulp of t; 1e-15 relative bounds it, t >= 1/2000)
    np.testing.assert_allclose(df["time_s"].to_numpy()[1:], t[1:], rtol=1e-15, atol=0)
    assert df["time_s"].iloc[0] == 0.0
    assert_same_result(vibid.identify(example1_stand, path), ref)


def test_tdms_time_channel_and_no_time(tmp_path, example1_stand, ex1_clean, ref):
    data, t = ex1_clean
    # no waveform timing, a time channel in seconds: that is time_s
    t_off = t + 10.0
    path = write_tdms(tmp_path / "timechan.tdms",
                      {"g": {"Time": (t_off, {"unit_string": "s"}),
                             **{c: (data[c], {"unit_string": "m"}) for c in ("x1", "x2", "s")}}})
    df = vibid.read_capture(path, example1_stand)
    np.testing.assert_array_equal(df["time_s"].to_numpy(), t_off)
    assert_same_result(vibid.identify(example1_stand, path), ref)
    # a time channel of TDMS time stamps: seconds from the first sample (microsecond ticks)
    stamps = np.datetime64("2024-05-06T07:08:09", "us") + (np.arange(len(t)) * 500).astype("timedelta64[us]")
    path = write_tdms(tmp_path / "stamps.tdms",
                      {"g": {"Zeit": (stamps, {}), **{c: (data[c], {}) for c in ("x1", "x2", "s")}}})
    df = vibid.read_capture(path, example1_stand, channels={"time_s": "Zeit"})
    # exact to the 2^-64 s fractions (read raw, not as microsecond datetime64) and the
    # rounding of a double below 10 s (1.8e-15)
    np.testing.assert_allclose(df["time_s"].to_numpy(), t, rtol=0, atol=1e-14)
    # nothing: sample index / stand rate, exactly as identify on arrays
    path = write_tdms(tmp_path / "notime.tdms", {"g": {c: (data[c], {}) for c in ("x1", "x2", "s")}})
    df = vibid.read_capture(path, example1_stand)
    np.testing.assert_array_equal(df["time_s"].to_numpy(), np.arange(len(t)) / FA)
    assert_same_result(vibid.identify(example1_stand, path), ref)


def test_tdms_in_mm_equals_si(tmp_path, example1_stand, ex1_clean, ref_ee):
    data, t = ex1_clean
    path = write_tdms(tmp_path / "mm.tdms",
                      {"Measured": {c: (1000.0 * data[c], waveform("mm")) for c in ("x1", "x2", "s")}})
    df = vibid.read_capture(path, example1_stand)
    for c in ("x1", "x2", "s"):
        np.testing.assert_allclose(df[c].to_numpy(), data[c], rtol=MM_ROUNDTRIP, atol=0)
    r = vibid.identify(example1_stand, path, holdout=0)
    np.testing.assert_allclose(r.parameters["value"], ref_ee.parameters["value"], rtol=MM_VALUE_RTOL, atol=0)
    np.testing.assert_allclose(r.parameters["se"], ref_ee.parameters["se"], rtol=MM_SE_RTOL, atol=0)


def test_tdms_wrong_unit_names_channel(tmp_path, example1_stand, ex1_clean):
    data, _ = ex1_clean
    path = write_tdms(tmp_path / "wrong.tdms",
                      {"Measured": {"x1": (data["x1"], waveform("N")), "x2": (data["x2"], waveform("m")),
                                    "s": (data["s"], waveform("m"))}})
    with pytest.raises(ValueError, match=r"channel 'x1' in .*wrong\.tdms \(m1\.displacement, a displacement\): "
                                         r"'N' is not a length unit"):
        vibid.identify(example1_stand, path)


def test_tdms_missing_channel_lists_the_files(tmp_path, example1_stand, ex1_clean):
    data, _ = ex1_clean
    path = write_tdms(tmp_path / "two.tdms",
                      {"Measured": {"x1": (data["x1"], waveform("m")), "s": (data["s"], waveform("m"))}})
    with pytest.raises(ValueError, match=r"channel 'x2' missing: group 'Measured' of .*two\.tdms has channels "
                                         r"\['x1', 's'\]"):
        vibid.identify(example1_stand, path)


def test_tdms_renamed_channels(tmp_path, example1_stand, ex1_clean, ref):
    data, _ = ex1_clean
    path = write_tdms(tmp_path / "renamed.tdms",
                      {"Measured": {"Weg 1": (data["x1"], waveform("m")), "Weg 2": (data["x2"], waveform("m")),
                                    "Sockel": (data["s"], waveform("m"))}})
    df = vibid.read_capture(path, example1_stand, channels={"x1": "Weg 1", "x2": "Weg 2", "s": "Sockel"})
    assert_same_result(vibid.identify(example1_stand, df), ref)


def test_tdms_two_groups_need_group(tmp_path, example1_stand, ex1_clean, ref):
    data, _ = ex1_clean
    chans = {c: (data[c], waveform("m")) for c in ("x1", "x2", "s")}
    path = write_tdms(tmp_path / "groups.tdms", {"Run 1": chans, "Run 2": chans})
    with pytest.raises(ValueError, match=r"groups\.tdms has 2 groups \['Run 1', 'Run 2'\]: choose one with group="):
        vibid.identify(example1_stand, path)
    assert_same_result(vibid.identify(example1_stand, vibid.read_capture(path, example1_stand, group="Run 2")), ref)
    with pytest.raises(ValueError, match=r"group 'Run 3' not in .*groups\.tdms: it has groups \['Run 1', 'Run 2'\]"):
        vibid.read_capture(path, example1_stand, group="Run 3")


def test_tdms_channels_on_different_time_bases_refused(tmp_path, example1_stand, ex1_clean):
    data, _ = ex1_clean
    path = write_tdms(tmp_path / "rates.tdms",
                      {"g": {"x1": (data["x1"], waveform("m")), "x2": (data["x2"], waveform("m")),
                             "s": (data["s"], waveform("m", increment=2.0 / FA))}})
    with pytest.raises(ValueError, match=r"channels 'x1' \(2000 Hz from 0 s\) and 's' \(1000 Hz from 0 s\) are on "
                                         r"different time bases"):
        vibid.read_capture(path, example1_stand)
    path = write_tdms(tmp_path / "lengths.tdms",
                      {"g": {"x1": (data["x1"], {}), "x2": (data["x2"][:-5], {}), "s": (data["s"], {})}})
    with pytest.raises(ValueError, match=r"channel 'x2' has 19995 samples, channel 'x1' 20000"):
        vibid.read_capture(path, example1_stand)


def test_tdms_time_base_2_percent_off_refused(tmp_path, example1_stand, ex1_clean):
    data, _ = ex1_clean
    path = write_tdms(tmp_path / "slow.tdms",
                      {"g": {c: (data[c], waveform("m", increment=1.02 / FA)) for c in ("x1", "x2", "s")}})
    with pytest.raises(ValueError, match=r"1960\.78 Hz, the stand 'paper_example1' says 2000 Hz"):
        vibid.identify(example1_stand, path)


# ---------------------------------------------------------------------------- common


def test_unknown_format_names_path_and_formats(tmp_path, example1_stand):
    path = tmp_path / "capture.h5"
    path.write_bytes(b"\x89HDF\r\n\x1a\n")  # HDF5's signature: neither its content nor its name is a capture format
    # the accepted formats as the drivers' registry lists them (capture_format.h)
    with pytest.raises(ValueError, match=r"capture\.h5: unknown capture format \(extension '\.h5', content not "
                                         r"recognised\); accepted: \.log \(candump -l log, format='candump', with dbc=\), "
                                         r"\.csv \(CSV.*\.mf4 or \.mdf \(ASAM MDF4.*\.tdms \(NI TDMS"):
        vibid.identify(example1_stand, path)
    with pytest.raises(ValueError, match=r"format 'hdf5' for .*capture\.h5: one of 'candump', 'csv', 'mdf', 'tdms'"):
        vibid.read_capture(path, example1_stand, format="hdf5")


def test_format_overrides_extension(tmp_path, example1_stand, ex1_clean, ref):
    # a TDMS file under another name, read with format=
    data, _ = ex1_clean
    path = write_tdms(tmp_path / "capture.dat", {"g": {c: (data[c], waveform("m")) for c in ("x1", "x2", "s")}})
    assert_same_result(vibid.identify(example1_stand, vibid.read_capture(path, example1_stand, format="tdms")), ref)
    # and without format=: recognised by its content ("TDSm"), as vibidd recognises files
    assert vibid._core.capture_format_of_file(str(path)) == "tdms"
    assert_same_result(vibid.identify(example1_stand, vibid.read_capture(path, example1_stand)), ref)


def test_csv_through_read_capture(tmp_path, example1_stand, ex1_clean, ref):
    # CSV: renamed columns and a time column by mapping; extra columns are ignored
    data, t = ex1_clean
    path = tmp_path / "capture.csv"
    pd.DataFrame({"Zeit": t, "A": data["x1"], "B": data["x2"], "C": data["s"], "T_oil": 40.0}).to_csv(
        path, index=False, float_format="%.17g")
    df = vibid.read_capture(path, example1_stand, channels={"x1": "A", "x2": "B", "s": "C", "time_s": "Zeit"})
    np.testing.assert_array_equal(df["time_s"].to_numpy(), t)
    assert_same_result(vibid.identify(example1_stand, df), ref)
    with pytest.raises(ValueError, match=r"channels: 'x3' is not a channel of the stand 'paper_example1'"):
        vibid.read_capture(path, example1_stand, channels={"x3": "A"})
    with pytest.raises(ValueError, match="a CSV file has no groups"):
        vibid.read_capture(path, example1_stand, group="g")


def test_units_by_quantity_and_stand_length_unit(tmp_path):
    # A stand in mm with a force input: a displacement written in m comes out in mm (the
    # stand's units), a force input in kN in N; an input in its own unit (V, the stand's
    # gain is N/V) is taken as it is.
    stand = vibid.Stand.from_dict({
        "name": "one_mass_mm", "sample_rate": 1000.0, "length_unit": "mm",
        "nodes": [{"name": "m1", "mass": 1.0e-3, "measure": {"displacement": "x1"}}],
        "elements": [{"name": "k", "kind": "spring", "between": ["m1", "ground"], "unknown": True, "value": 10.0}],
        "inputs": [{"name": "f", "node": "m1", "channel": "F"}],
    })
    assert stand.channel_quantities == ["displacement", "input"]
    assert stand.length_unit == "mm" and stand.length_si == 1e-3
    x = np.linspace(-1e-3, 1e-3, 50)
    f = np.linspace(-2.0, 2.0, 50)
    path = write_tdms(tmp_path / "units.tdms", {"g": {"x1": (x, {"unit_string": "m"}),
                                                      "F": (f, {"unit_string": "kN"})}})
    df = vibid.read_capture(path, stand)
    # m -> mm multiplies by 1 / fl(1e-3), which rounds to exactly 1000.0, and kN -> N by
    # 1000.0: the same products as here, so equal to the last bit.
    np.testing.assert_array_equal(df["x1"].to_numpy(), x * 1000.0)
    np.testing.assert_array_equal(df["F"].to_numpy(), f * 1000.0)
    path = write_tdms(tmp_path / "volts.tdms", {"g": {"x1": (x, {"unit_string": "mm"}),
                                                      "F": (f, {"unit_string": "V"})}})
    df = vibid.read_capture(path, stand)
    np.testing.assert_array_equal(df["x1"].to_numpy(), x)  # mm on a stand in mm: untouched
    np.testing.assert_array_equal(df["F"].to_numpy(), f)


@pytest.mark.parametrize("module, extra, name", [("asammdf", "mdf", "capture.mf4"), ("nptdms", "tdms", "capture.tdms")])
def test_missing_extra_says_how_to_install(tmp_path, monkeypatch, example1_stand, module, extra, name):
    # As without the extra installed: a None in sys.modules makes the import fail.
    path = tmp_path / name
    path.write_bytes(b"MDF     4.10    " if extra == "mdf" else b"TDSm")  # the formats' first bytes
    monkeypatch.setitem(sys.modules, module, None)
    with pytest.raises(ImportError, match=rf"reading .*{name} needs the package '{module}': "
                                          rf"pip install '\./python\[{extra}\]'"):
        vibid.read_capture(path, example1_stand)
