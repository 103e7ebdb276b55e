"""vibid.read_capture: a capture file (CSV, ASAM MDF4, NI TDMS) as the DataFrame that
:func:`vibid.identify` takes: the stand's channels in the stand's order and units, and
``time_s``.

Samples are taken as the file holds them: never resampled, interpolated or aligned. A
file whose channels were not sampled together (different time bases or rates) is refused,
because an estimate from samples that were invented or shifted would look as good as a
real one and be wrong. MDF4 needs the extra ``mdf`` (asammdf), TDMS the extra ``tdms``
(npTDMS): ``pip install './python[mdf,tdms]'``.
"""

from __future__ import annotations

import contextlib
import gc
import math
import os
import sys
import traceback
from typing import Any, Mapping, Optional

import numpy as np
import pandas as pd

from . import _core
from ._stand import Stand

# The capture formats: the drivers' registry (vibid_drivers/capture_format.h), which vibidd
# reads too: names, aliases, extensions, recognition by content. ".mdf" is also MDF version 3,
# which asammdf reads as well.
FORMATS = _core.capture_formats()  # [(name, aliases, extensions, title, vibidd_replays, needs_dbc)]
_FORMATS = {alias: name for name, aliases, *_ in FORMATS for alias in [name, *aliases.split()]}
_ACCEPTED = ", ".join(f"{' or '.join(ext.split())} ({title}, format={name!r}{', with dbc=' if dbc else ''})"
                      for name, _, ext, title, _, dbc in FORMATS)
# Time columns/channels looked for when the file has no time base of its own (CSV: the
# columns identify has always accepted; TDMS: also the names NI's loggers use).
_CSV_TIME = ("time_s", "t")
_TDMS_TIME = ("time_s", "t", "time", "Time")
# Units of a stand channel's quantity (vibid/units.h dimensions). Inputs have their own
# units ("input units", the stand's gain is N per input unit): a force unit on an input is
# converted to N, any other label (V, A, ...) is the input's own and taken as it is, as
# vibidd's channel-map quantity "input".
_DIMENSION = {"displacement": "length", "velocity": "velocity", "acceleration": "acceleration", "input": "force"}
# Relative agreement of two channels' sample intervals (and start offsets, in intervals)
# for them to count as one time base: far below any real clock difference (1e-9 of an
# interval is 0.5 ps at 2 kHz), far above the rounding of a time stamp written as a double.
_SAME_TIME = 1e-9


class CaptureError(_core.VibidError, ValueError):
    """A capture that cannot be read as asked: the message names the file, where in it (the
    line of a CSV, the sample of other formats) and the cause, in one line. A VibidError (the
    package's own type) and a ValueError (what bad input raised before)."""


def csv_line(path: str, row: int) -> int:
    """The 1-based line of the file holding data row `row` (0-based) of a CSV read as
    read_capture reads it: '#' comment lines and blank lines skipped, the header first.
    Scans the file; called only to name where an error is."""
    seen = -1  # the header is row -1
    with open(path, "rb") as f:
        for number, line in enumerate(f, start=1):
            s = line.strip()
            if not s or s.startswith(b"#"):
                continue
            if seen == row:
                return number
            seen += 1
    return 0


def location(path: str, fmt: str, row: int) -> str:
    """Where data row `row` of a capture is, for a message: "file.csv:123" or "file.mf4,
    sample 122"."""
    if fmt == "csv":
        line = csv_line(path, row)
        if line:
            return f"{path}:{line}"
    return f"{path}, sample {row}"


@contextlib.contextmanager
def _reading(path: str, fmt: str):
    """Errors while a reader runs become one-line CaptureErrors naming the file: ours keep
    their message (they name the file and where already); a library's (asammdf, npTDMS,
    pandas on a damaged file: "seek out of range") get the file, its format and size, and the
    library's words. A missing extra (ImportError) passes as it is. While the reader runs, a
    destructor's error of a half-built library object (asammdf's MDF4.__del__ after a failed
    open prints a second traceback) is not printed: the error reported is the first."""
    old_hook = sys.unraisablehook
    sys.unraisablehook = lambda unraisable: None
    try:
        yield
    except (CaptureError, ImportError):
        raise
    except Exception as e:
        tb = e.__traceback__
        while tb is not None and tb.tb_next is not None:
            tb = tb.tb_next
        ours = tb is not None and os.path.samefile(tb.tb_frame.f_code.co_filename, __file__)
        if ours and isinstance(e, ValueError):
            message = str(e)
        else:
            title = next((t for n, _, _, t, _, _ in FORMATS if n == fmt), fmt)
            message = (f"{path}: cannot be read as {title} ({os.path.getsize(path)} bytes; damaged or cut short?): "
                       f"{type(e).__name__}: {str(e).strip() or 'no message'}")
        # The failed reader's objects die now, under the quiet hook: the finished frames of
        # the traceback hold them (a half-built asammdf MDF4 whose __del__ fails), and the
        # traceback itself lives on in the with statement until after this hook is restored.
        traceback.clear_frames(e.__traceback__)
        gc.collect()
        raise CaptureError(message) from None
    finally:
        sys.unraisablehook = old_hook


def _require(module: str, extra: str, path: str):
    try:
        return __import__(module)
    except ImportError as e:
        raise ImportError(f"reading {path} needs the package {module!r}: pip install './python[{extra}]' "
                          f"from a clone of vibid (the extra '{extra}')") from e


def _format_of(path: str, format: Optional[str]) -> str:
    if format is not None:
        f = _FORMATS.get(str(format).lower())
        if f is None:
            raise ValueError(f"format {format!r} for {path}: one of {', '.join(repr(n) for n, *_ in FORMATS)}")
        return f
    # the file's content first (MDF4, TDMS, candump and CSV are told apart by their first
    # bytes), its extension when the content says nothing
    f = _core.capture_format_of_file(str(path))
    if not f:
        ext = os.path.splitext(path)[1].lower()
        raise ValueError(f"{path}: unknown capture format (extension {ext or '(none)'!r}, content not "
                         f"recognised); accepted: {_ACCEPTED}; or give format=")
    return f


def _mapping(stand: Stand, channels: Optional[Mapping[str, str]]) -> dict[str, str]:
    """{stand channel or 'time_s': name in the file}; the same names by default."""
    m = {c: c for c in stand.channels}
    if channels is None:
        return m
    for k, v in channels.items():
        if k not in m and k != "time_s":
            raise ValueError(f"channels: {k!r} is not a channel of the stand {stand.name!r} "
                             f"({', '.join(stand.channels)}; or 'time_s' for the time)")
        if not isinstance(v, str):
            raise TypeError(f"channels: the file's name for {k!r} must be a string, not {type(v).__name__}")
        m[k] = v
    return m


def _missing(stand_name: str, file_name: str, where: str, have: list[str]) -> ValueError:
    called = repr(stand_name) + ("" if stand_name == file_name else f" (as {file_name!r} in the file)")
    return ValueError(f"channel {called} missing: {where} has channels {have}")


def _numeric(values: Any, what: str, csv_path: Optional[str] = None) -> np.ndarray:
    a = np.asarray(values)
    if a.ndim == 1 and a.dtype.kind == "O" and csv_path is not None:
        # A CSV column pandas could not read as numbers: name the first cell that is not one.
        for row, v in enumerate(a):
            try:
                float(v)
            except (TypeError, ValueError):
                raise CaptureError(f"{csv_path}:{csv_line(csv_path, row)}: {what.split(' in ')[0]}: {str(v)!r} is "
                                   "not a number") from None
    if a.ndim != 1 or a.dtype.kind not in "biuf":
        raise CaptureError(f"{what}: holds {a.dtype} values of shape {a.shape}, not one number per sample")
    return a.astype(np.float64, copy=False)


def _rate(t: np.ndarray) -> float:
    return 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else math.nan


def _same_length(cols: dict[str, np.ndarray], where: str) -> None:
    names = list(cols)
    for c in names[1:]:
        if len(cols[c]) != len(cols[names[0]]):
            raise ValueError(f"{where}: channel {c!r} has {len(cols[c])} samples, channel {names[0]!r} "
                             f"{len(cols[names[0]])}: they were not sampled together (vibid never resamples)")


def _read_csv(path: str, stand: Stand, names: dict[str, str], group: Any):
    if group is not None:
        raise ValueError(f"{path}: group= is for MDF4 and TDMS files, a CSV file has no groups")
    # The daemon's tracks and vibid-sim's captures head their files with '#' lines.
    try:
        df = pd.read_csv(path, comment="#", skipinitialspace=True)
    except pd.errors.EmptyDataError:
        raise CaptureError(f"{path}: no header line: the file is empty or holds only '#' comments") from None
    except (pd.errors.ParserError, UnicodeDecodeError) as e:
        raise CaptureError(f"{path}: not a CSV file vibid can read: {str(e).strip()}") from None
    if len(df) == 0:
        raise CaptureError(f"{path}: a header and no data rows")
    have = [str(c) for c in df.columns]
    cols = {}
    for c in stand.channels:
        if names[c] not in have:
            raise _missing(c, names[c], path, have)
        cols[c] = _numeric(df[names[c]].to_numpy(), f"channel {c!r} in {path}", csv_path=path)
    if "time_s" in names:
        if names["time_s"] not in have:
            raise _missing("time_s", names["time_s"], path, have)
        tname = names["time_s"]
    else:
        tname = next((c for c in _CSV_TIME if c in have), None)
    t = _numeric(df[tname].to_numpy(), f"time column {tname!r} in {path}", csv_path=path) if tname is not None else None
    # A CSV file has no units: its values are in the stand's units.
    return cols, {}, t


def _read_mdf(path: str, stand: Stand, names: dict[str, str], group: Any):
    _require("asammdf", "mdf", path)
    from asammdf import MDF

    if "time_s" in names:
        raise ValueError(f"{path}: an MDF file's time is each channel's master (time) channel; "
                         "channels={'time_s': ...} is for CSV and TDMS")
    cols, units, times = {}, {}, {}
    with MDF(path) as mdf:
        masters = mdf.masters_db  # data group -> index of its master (time) channel
        have = []
        for gi, grp in enumerate(mdf.groups):
            for ci, ch in enumerate(grp.channels):
                if masters.get(gi) != ci and ch.name not in have:
                    have.append(ch.name)
        for c in stand.channels:
            fname = names[c]
            where = [(g, i) for g, i in mdf.channels_db.get(fname, ()) if masters.get(g) != i
                     and (group is None or g == group)]
            if not where:
                raise _missing(c, fname, path + ("" if group is None else f" (data group {group})"), have)
            if len(where) > 1:
                raise ValueError(f"channel {fname!r} is in data groups {sorted({g for g, _ in where})} of {path}: "
                                 "choose one with group=<data group index>")
            g, i = where[0]
            mi = masters.get(g)
            if mi is None:
                raise ValueError(f"channel {fname!r} in {path}: its data group {g} has no master channel, "
                                 "so its samples have no time")
            master = mdf.groups[g].channels[mi]
            # MDF4 masters may count angle or distance (crank shaft, track): not a time base.
            if getattr(master, "sync_type", 1) not in (1,):
                raise ValueError(f"channel {fname!r} in {path}: the master {master.name!r} of data group {g} is not "
                                 f"a time (sync type {master.sync_type}); vibid needs samples in time")
            # ignore_invalidation_bits=True: all samples, with the bits beside them; asammdf's
            # default drops the invalid samples, which would shift this channel against the
            # others without a word.
            sig = mdf.get(fname, group=g, index=i, ignore_invalidation_bits=True)
            what = f"channel {c!r}" + ("" if fname == c else f" ({fname!r} in the file)") + f" in {path}"
            v = _numeric(sig.samples, what)
            inv = getattr(sig, "invalidation_bits", None)
            if inv is not None and np.any(inv):
                # Samples the recorder marked invalid carry no value: NaN, which identify
                # refuses naming the channel and the row (rather than use a meaningless number).
                v = v.copy()
                v[np.asarray(inv, dtype=bool)] = np.nan
            cols[c] = v
            units[c] = sig.unit or ""
            times[c] = (g, np.asarray(sig.timestamps, dtype=np.float64))
    # One time base: the same data group, or masters that agree sample by sample.
    first = stand.channels[0]
    g0, t0 = times[first]
    for c in stand.channels[1:]:
        g, t = times[c]
        if g == g0:
            continue
        dt = abs(float(np.median(np.diff(t0)))) if len(t0) > 1 else 0.0
        if len(t) != len(t0) or (len(t) and np.max(np.abs(t - t0)) > _SAME_TIME * max(dt, 1e-300)):
            raise ValueError(
                f"{path}: channels {first!r} (data group {g0}: {len(t0)} samples, {_rate(t0):.6g} Hz from "
                f"{t0[0] if len(t0) else math.nan:.6g} s) and {c!r} (data group {g}: {len(t)} samples, "
                f"{_rate(t):.6g} Hz from {t[0] if len(t) else math.nan:.6g} s) are on different time bases: "
                "vibid takes samples as they were taken and never resamples; record or export them on one "
                "time base")
    return cols, units, t0


def _read_tdms(path: str, stand: Stand, names: dict[str, str], group: Any):
    _require("nptdms", "tdms", path)
    from nptdms import TdmsFile

    # raw_timestamps: TDMS time stamps as seconds and 2^-64 fractions; as datetime64 they
    # would be cut to microseconds (0.5005 s read as 0.500499 s).
    f = TdmsFile.read(path, raw_timestamps=True)
    groups = [g.name for g in f.groups()]
    if group is None:
        if len(groups) != 1:
            raise ValueError(f"{path} has {len(groups)} groups {groups}: choose one with group=")
        grp = f.groups()[0]
    else:
        if group not in groups:
            raise ValueError(f"group {group!r} not in {path}: it has groups {groups}")
        grp = f[group]
    where = f"group {grp.name!r} of {path}"
    have = [ch.name for ch in grp.channels()]
    chans, cols, units = {}, {}, {}
    for c in stand.channels:
        if names[c] not in have:
            raise _missing(c, names[c], where, have)
        ch = grp[names[c]]
        chans[c] = ch
        cols[c] = _numeric(ch[:], f"channel {c!r}" + ("" if names[c] == c else f" ({names[c]!r})") + f" in {where}")
        units[c] = str(ch.properties.get("unit_string", ""))
    _same_length(cols, where)
    n = len(cols[stand.channels[0]])
    wf = [c for c in stand.channels if "wf_increment" in chans[c].properties]
    if wf:
        # NI waveform timing: t_k = wf_start_offset + k wf_increment (seconds).
        if len(wf) != len(stand.channels):
            none = [c for c in stand.channels if c not in wf]
            raise ValueError(f"{where}: channel {wf[0]!r} has waveform timing (wf_increment) and channel "
                             f"{none[0]!r} none: not one time base")
        def timing(c):
            p = chans[c].properties
            return float(p["wf_increment"]), float(p.get("wf_start_offset", 0.0))
        inc0, off0 = timing(wf[0])
        if not (math.isfinite(inc0) and inc0 > 0):
            raise ValueError(f"{where}: channel {wf[0]!r} has wf_increment {inc0!r}, not a sample interval")
        for c in wf[1:]:
            inc, off = timing(c)
            if abs(inc / inc0 - 1.0) > _SAME_TIME or abs(off - off0) > _SAME_TIME * inc0:
                raise ValueError(f"{where}: channels {wf[0]!r} ({1 / inc0:.6g} Hz from {off0:.6g} s) and {c!r} "
                                 f"({1 / inc:.6g} Hz from {off:.6g} s) are on different time bases: vibid takes "
                                 "samples as they were taken and never resamples")
        return cols, units, off0 + np.arange(n) * inc0
    if "time_s" in names:
        if names["time_s"] not in have:
            raise _missing("time_s", names["time_s"], where, have)
        tname = names["time_s"]
    else:
        tname = next((c for c in _TDMS_TIME if c in have), None)
    if tname is None:
        return cols, units, None
    tch = grp[tname]
    tv = np.asarray(tch[:])
    if tv.dtype.names and {"seconds", "second_fractions"} <= set(tv.dtype.names):
        # TDMS time stamps (absolute): seconds from the first sample. Whole seconds as
        # integers, the fractions (units of 2^-64 s) as doubles: exact to ~1e-16 s each.
        sec = tv["seconds"].astype(np.int64)
        frac = tv["second_fractions"].astype(np.float64) * 2.0**-64
        t = (sec - sec[0]).astype(np.float64) + (frac - frac[0]) if len(tv) else np.zeros(0)
    else:
        tunit = str(tch.properties.get("unit_string", ""))
        if tunit not in ("", "s"):
            raise ValueError(f"time channel {tname!r} in {where}: unit {tunit!r}; seconds ('s') are needed")
        t = _numeric(tv, f"time channel {tname!r} in {where}")
    if len(t) != n:
        raise ValueError(f"{where}: time channel {tname!r} has {len(t)} samples, the channels {n}")
    return cols, units, np.asarray(t, dtype=np.float64)


def _factor(stand: Stand, index: int, unit: str, what: str) -> float:
    """Factor from the file's unit of channel `index` to the stand's units."""
    quantity = stand.channel_quantities[index]
    dim = _DIMENSION[quantity]
    if quantity == "input":
        try:
            return _core.unit_si_factor("force", unit)  # forces in N, as the stand's
        except ValueError:
            return 1.0  # the input's own unit (e.g. V): the stand's gain converts it
    try:
        si = _core.unit_si_factor(dim, unit)
    except ValueError as e:
        raise ValueError(f"{what} ({stand.channel_models[index]}, a {quantity}): {e}") from None
    # The stand's length unit (stand.length_unit): values in mm for a stand in mm.
    return si / stand.length_si


def read_capture(path: str | os.PathLike, stand: Stand | str | os.PathLike, *, format: Optional[str] = None,
                 channels: Optional[Mapping[str, str]] = None, group: Any = None, dbc: Any = None,
                 channel_map: Any = None) -> pd.DataFrame:
    """Reads the stand's channels from a capture file.

    path: a CSV (header row of names, ``#`` lines skipped), ASAM MDF4 (``.mf4``, ``.mdf``;
        extra ``mdf``) or NI TDMS (``.tdms``; extra ``tdms``) file; the format from the
        extension unless ``format`` ('csv', 'mdf', 'tdms') is given.
    stand: a :class:`Stand` or the path of a stand file.
    channels: {stand channel: name in the file} where they differ (and ``'time_s'``: the
        time column or channel of a CSV or TDMS file); other channels are looked up by
        their own names. Channels of the file that the stand does not read are ignored.
    group: TDMS: the group's name (needed when the file has several); MDF4: the data group
        index, where a channel name occurs in several.
    dbc, channel_map: a candump log (``.log``, or any name with ``format='candump'`` or a
        ``dbc``) is decoded by the drivers with its DBC ``dbc``; its channels are the DBC
        signals of the stand's channel names (``channels`` renames them) numbered by the
        ``SampleCounter`` signal, or what the channel-map file ``channel_map`` says
        (docs/drivers.md). Missing samples are NaN rows (time NaN), listed in
        ``attrs['gaps']``; source faults in ``attrs['faults']`` (docs/python.md).

    Returns a DataFrame with the stand's channels in stand order, in the stand's units (a
    channel's unit in the file, MDF ``unit`` or TDMS ``unit_string``, is converted by
    vibid's unit table; none: the stand's units), and ``time_s``: the MDF master, the TDMS
    waveform timing (``wf_start_offset + k wf_increment``) or time channel, the CSV
    ``time_s``/``t`` column, else ``index / stand.sample_rate``.

    Raises ValueError naming the file and the channel: a channel that is not there (listing
    the file's), a unit that is not one of the channel's quantity, channels on different
    time bases (never resampled), a TDMS file with several groups and no ``group``, an
    unknown format.
    """
    if not isinstance(stand, Stand):
        stand = Stand.load(stand)
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise CaptureError(f"{path}: no such file" if not os.path.exists(path) else f"{path}: not a file")
    if os.path.getsize(path) == 0:
        raise CaptureError(f"{path}: empty file (0 bytes)")
    # With a DBC, a file that neither content nor name place is candump, as for vibidd's
    # replay (source_replay.h).
    unplaced = format is None and dbc is not None and not _core.capture_format_of_file(path)
    fmt = "candump" if unplaced else _format_of(path, format)
    names = _mapping(stand, channels)
    attrs = {}
    if fmt == "candump":
        from ._drivers import read_candump  # the C drivers' replay source

        cols, units, t, attrs = read_candump(path, stand, names, group, dbc, channel_map)
    else:
        if dbc is not None or channel_map is not None:
            raise ValueError(f"{path}: dbc= and channel_map= are for candump logs, not {fmt} files")
        reader = {"csv": _read_csv, "mdf": _read_mdf, "tdms": _read_tdms}[fmt]
        with _reading(path, fmt):
            cols, units, t = reader(path, stand, names, group)
    _same_length(cols, path)
    n = len(cols[stand.channels[0]]) if stand.channels else 0
    out = {}
    for i, c in enumerate(stand.channels):
        v = cols[c]
        unit = units.get(c, "").strip()
        if unit:
            what = f"channel {c!r}" + ("" if names[c] == c else f" ({names[c]!r} in the file)") + f" in {path}"
            k = _factor(stand, i, unit, what)
            if k != 1.0:
                v = v * k
        out[c] = v
    out["time_s"] = t if t is not None else np.arange(n) / stand.sample_rate
    df = pd.DataFrame(out, columns=[*stand.channels, "time_s"])
    df.attrs.update(attrs)
    # where the samples came from, so that identify can name the file and line of a bad one
    df.attrs["source"] = {"path": path, "format": fmt}
    return df
