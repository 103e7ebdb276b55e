"""candump captures and vibid.replay: the project's C drivers and vibidd's core, in-process.

Nothing here decodes a frame or estimates a parameter: candump logs go through the drivers'
replay source (DBC decoder, candump reader, CAN sample assembler), exactly what
``vibidd --replay`` reads, and :func:`replay` runs vibidd's own pipeline (configuration
reader, replay source, estimator, tracks writer) in this process. Both are compiled into
``vibid._core`` only when the build found the drivers (libmodbus and libconfig,
python/CMakeLists.txt); otherwise they raise ImportError saying how to get them.
"""

from __future__ import annotations

import errno
import math
import os
import tempfile
import warnings
from collections import Counter
from typing import Any, Mapping, Optional

import numpy as np
import pandas as pd

from . import _core
from ._stand import Stand

_HOW = ("vibid was built without {what}: its build found no libmodbus or libconfig (pkg-config libmodbus "
        "libconfig; Debian/Ubuntu: apt install libmodbus-dev libconfig-dev). Install them and reinstall the "
        "package from a clone (python -m pip install --force-reinstall ./python), or link a build tree that "
        "holds drivers/libvibid_drivers.a{daemon} (scripts/python-test.sh BUILD_DIR)")


def _need(daemon: bool, why: str) -> None:
    if not getattr(_core, "HAVE_DRIVERS", False):
        what = "the drivers (DBC decoder, candump reader, CAN sample assembly)"
    elif daemon and not getattr(_core, "HAVE_DAEMON", False):
        what = "vibidd's core (libvibidd_core)"
    else:
        return
    raise ImportError(f"{why}: " + _HOW.format(what=what, daemon=" and daemon/libvibidd_core.a" if daemon else ""))


def _exists(path: str, what: str) -> str:
    if not os.path.isfile(path):
        raise FileNotFoundError(errno.ENOENT, f"{what} not found", path)
    return path


def read_candump(path: str, stand: Stand, names: dict[str, str], group: Any, dbc: Any, channel_map: Any):
    """(cols, units, time_s, attrs) of a candump log for read_capture. names: {stand channel:
    DBC signal} (the default channel map); channel_map: a channel-map file instead."""
    _need(False, f"reading the candump log {path}")
    if group is not None:
        raise ValueError(f"{path}: group= is for MDF4 and TDMS files, a candump log has none")
    if "time_s" in names:
        raise ValueError(f"{path}: a candump log's time is its frames' time stamps; channels={{'time_s': ...}} is "
                         "for CSV and TDMS")
    if dbc is None:
        raise ValueError(f"{path}: a candump log needs its DBC: read_capture(..., dbc='file.dbc')")
    dbc = _exists(os.fspath(dbc), "DBC file")
    _exists(path, "candump log")
    if channel_map is not None:
        channel_map = _exists(os.fspath(channel_map), "channel-map file")
        if any(names[c] != c for c in stand.channels):
            raise ValueError(f"{path}: give the signals either by channels= or by the channel map "
                             f"{channel_map}, not both")
    chans = list(stand.channels)
    out = _core.read_candump(path, dbc, chans, [names[c] for c in chans], channel_map, stand.sample_rate)
    t = np.asarray(out["time_s"])
    gaps = []
    for g in out["gaps"]:
        row, count = int(g["row"]), int(g["count"])
        before = t[:row][~np.isnan(t[:row])]
        gaps.append({"row": row, "count": count, "after_time_s": float(before[-1]) if len(before) else math.nan,
                     "text": g["text"]})
    faults = [dict(f) for f in out["faults"]]
    if faults:
        kinds = Counter(f["kind"] for f in faults)
        warnings.warn(f"{path}: {len(faults)} fault(s) reported by the drivers' replay "
                      f"({', '.join(f'{k} {n}' for k, n in kinds.items())}); the first: {faults[0]['text']} "
                      "(all in DataFrame.attrs['faults']; a fault's frame contributes no value)", stacklevel=3)
    attrs = {"gaps": gaps, "faults": faults, "start_time_ns": int(out["start_time_ns"]), "counter": out["counter"],
             "trigger": out["trigger"], "stats": dict(out["stats"]), "dbc": dbc}
    cols = {c: np.asarray(v) for c, v in zip(chans, out["values"])}
    units = dict(zip(chans, out["units"]))
    return cols, units, t, attrs


def replay(config: str | os.PathLike, capture: Optional[str | os.PathLike] = None, *, log_level: str = "warning",
           rate_check: str = "error") -> pd.DataFrame:
    """vibidd's pipeline on a vibidd configuration file, in this process: the tracks as
    ``vibidd -c config --replay capture`` writes them.

    config: a vibidd configuration (docs/vibidd.md); its source must be a replay unless
        ``capture`` is given. Relative paths in it are relative to the file, as for vibidd.
    capture: replay this capture (CSV, vibidd's raw recording or a candump log with the
        configuration's DBC) instead of ``source.file``, as ``--replay`` does.
    log_level: the daemon's log lines on stderr from this level up ("error", "warning",
        "notice", "info", "debug"); gaps are notices, source faults warnings.
    rate_check: "error" (a capture more than 1 % off the stand's rate is refused), "warn",
        "off": vibidd's ``--rate-check``.

    Returns the tracks file as a DataFrame (columns ``time_s``, ``index``, every unknown and
    ``<p>_se``, per mode ``f<i>_hz``, ``f<i>_hz_se``, ``zeta<i>``, ``zeta<i>_se``,
    ``gap_samples``, ``flags``; the values are the file's ``%.10g`` digits, read back). The
    configuration's outputs are not written: the tracks go to a temporary file that is read
    and removed, influx, record and status are off.

    Raises FileNotFoundError for a missing configuration, ValueError with the daemon's
    message for what it refuses (``file:line: field: reason`` for the configuration, a
    capture whose rate does not fit, a missing DBC, ...), VibidError when the pipeline fails
    while running (its log lines on stderr say why).
    """
    _need(True, "vibid.replay")
    config = _exists(os.fspath(config), "vibidd configuration")
    if capture is not None:
        capture = _exists(os.fspath(capture), "capture")
    with tempfile.TemporaryDirectory(prefix="vibid-replay-") as tmp:
        tracks = os.path.join(tmp, "tracks.csv")
        rc = _core.replay_run(config, capture, tracks, str(log_level), str(rate_check))
        if rc != 0:
            raise _core.VibidError(f"{config}: the pipeline ended with vibidd's exit status {rc} (a run-time "
                                   "failure; the daemon's log lines on stderr say what failed)")
        df = _read_tracks(tracks)
    df.attrs["config"] = config
    return df


def _read_tracks(path: str) -> pd.DataFrame:
    """vibidd's tracks file: flags as text ("" = none), as identify's tracks; "nan"/"inf"
    values as floats."""
    df = pd.read_csv(path, comment="#", dtype={"flags": str}, keep_default_na=False, na_values=["nan"])
    if "flags" in df.columns:
        df["flags"] = df["flags"].astype(str)
    return df


# vibid convert's advice when a stand channel has no signal of its name in the DBC
_CLI_HINT = "give a channel map (--channel-map) naming each channel's signal"


def _signal_range(ch: dict) -> tuple[float, float]:
    """The physical values an integer signal's raw range holds (lowest, highest)."""
    n, f, o = ch["length"], ch["factor"], ch["offset"]
    lo, hi = (-(2.0 ** (n - 1)), 2.0 ** (n - 1) - 1) if ch["signed"] else (0.0, 2.0 ** n - 1)
    a, b = lo * f + o, hi * f + o
    return min(a, b), max(a, b)


def _describe(ch: dict) -> str:
    """"signal Msg.Sig (12-bit signed, factor 0.01, offset 250: 229.52 .. 270.47 degK)"."""
    unit = f" {ch['unit']}" if ch["unit"] else ""
    what = f"signal {ch['message']}.{ch['signal']}"
    if ch["type"] != "integer":
        return f"{what} ({ch['type']}, factor {ch['factor']:g}, offset {ch['offset']:g})"
    lo, hi = _signal_range(ch)
    return (f"{what} ({ch['length']}-bit {'signed' if ch['signed'] else 'unsigned'}, factor {ch['factor']:g}, "
            f"offset {ch['offset']:g}: {lo:.10g} .. {hi:.10g}{unit})")


def write_candump(out: str, stand: Stand, block: np.ndarray, t: np.ndarray, *, dbc: Any, channel_map: Any = None,
                  iface: str = "can0", start_time_ns: int = 0, where=None, hint: str = _CLI_HINT) -> dict:
    """Writes the stand's samples as a candump -l log with the drivers' CAN encoder
    (vibid_can_assembler_encode, what vibidd's candump recording uses): the inverse of
    read_capture(out, stand, dbc=dbc, channel_map=channel_map).

    block: rows x the stand's channels, in the stand's units; a row with a NaN is a missing
        sample: no frame is written for it, and the counter skips its number, so a reader
        sees the gap (without a counter, a log cannot mark one: refused).
    t: each row's time in s (NaN allowed in missing rows), plus start_time_ns: the frames'
        time stamps, to the microsecond. Sample numbers follow the rows and, as vibidd's
        replay of a CSV counts them, time steps over 1.5 periods.
    where(row): the capture's place of a row, for messages.

    Values are converted to each signal's unit (the channel map's, else the DBC's) and
    encoded as raw = round((value - offset) / factor): never saturated (a value outside the
    signal's raw range, or outside its DBC [min|max] where given, is refused with a
    ValueError naming the row, channel and signal), and the values rounded are counted.
    Returns {"samples", "missing", "frames", "plan", "rounded": [per channel],
    "max_error": [per channel, in the stand's units]}.
    """
    from ._captures import _factor

    _need(False, f"writing the candump log {out}")
    dbc = _exists(os.fspath(dbc), "DBC file")
    if channel_map is not None:
        channel_map = _exists(os.fspath(channel_map), "channel-map file")
    where = where or (lambda row: f"row {row}")
    chans = list(stand.channels)
    plan = _core.candump_plan(dbc, chans, chans, channel_map, hint)
    block = np.asarray(block, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    n = len(block)
    missing = np.isnan(block).any(axis=1)
    if plan["counter"]:
        counter_note = f"counter {plan['counter']} ({plan['counter_bits']} bits)"
    else:
        counter_note = f"no counter (trigger message {plan['trigger'] or plan['channels'][0]['message']})"
        if missing.any():
            first = int(np.flatnonzero(missing)[0])
            raise ValueError(f"{where(first)}: {int(missing.sum())} missing sample(s), the first here, and the log "
                             f"has {counter_note}: it cannot mark a gap (a reader would join the samples around it); "
                             "use a DBC and channel map with a counter signal, or leave the gap out of the capture")
    # per channel: the stand's unit -> the signal's (the inverse of read_capture's factor)
    k = np.ones(len(chans))
    for i, (c, ch) in enumerate(zip(chans, plan["channels"])):
        if ch["unit"].strip():
            k[i] = _factor(stand, i, ch["unit"].strip(), f"channel {c!r} ({ch['message']}.{ch['signal']} in {dbc})")
    keep = ~missing
    rows = np.flatnonzero(keep)
    if not len(rows):
        raise ValueError(f"{where(0)}: no sample to write: all {n} rows are missing (NaN)")
    values = np.ascontiguousarray(block[keep] / k)
    inf = ~np.isfinite(values)
    if inf.any():
        j, i = (int(x) for x in np.argwhere(inf)[0])
        raise ValueError(f"{where(int(rows[j]))}: channel {chans[i]!r} = {float(block[rows[j], i])!r}: not a finite "
                         "number, which no frame carries (a reader drops it as a fault)")
    # times, microseconds
    tk = t[keep]
    bad = ~np.isfinite(tk)
    if bad.any():
        r = int(rows[np.flatnonzero(bad)[0]])
        raise ValueError(f"{where(r)}: time {t[r]!r}: a sample's frames need a time")
    t_us = start_time_ns // 1000 + np.rint(tk * 1e6).astype(np.int64)
    if len(t_us) and t_us[0] < 0:
        raise ValueError(f"{where(int(rows[0]))}: time {t[rows[0]]!r} s: a candump log's times start at 0 (the "
                         "Unix epoch)")
    step = np.diff(t_us)
    if (step <= 0).any():
        j = int(np.flatnonzero(step <= 0)[0])
        raise ValueError(f"{where(int(rows[j + 1]))}: time {t[rows[j + 1]]!r} s does not increase (previous "
                         f"{t[rows[j]]!r} s, to the microsecond a candump log holds)")
    # sample numbers: the rows, and time steps over 1.5 periods as vibidd's CSV replay counts
    # them (a CSV converted from a log with gaps has them as time steps)
    h_us = 1e6 / stand.sample_rate
    by_rows = np.diff(rows)
    by_time = np.where(step > 1.5 * h_us, np.rint(step / h_us), 1).astype(np.int64)
    index = np.concatenate([[0], np.cumsum(np.maximum(by_rows, by_time))]).astype(np.uint64) + np.uint64(rows[0])
    if plan["counter"] and len(index) > 1:
        jump = np.diff(index.astype(np.int64))
        half = 2 ** (plan["counter_bits"] - 1)
        # the assembler takes a counter step below half the range as newer (can_assembler.h)
        if (jump >= half).any():
            j = int(np.flatnonzero(jump >= half)[0])
            raise ValueError(f"{where(int(rows[j + 1]))}: {int(jump[j]) - 1} samples missing before this one; the "
                             f"{plan['counter_bits']}-bit counter {plan['counter']} can skip at most {half - 2} "
                             "(a reader would misplace the samples after the gap)")
    # the DBC's [min|max] where given ([0|0]: not given), and float32's range
    for i, (c, ch) in enumerate(zip(chans, plan["channels"])):
        v = values[:, i]
        lo, hi = ch["minimum"], ch["maximum"]
        out_of = np.zeros(len(v), dtype=bool)
        why = ""
        if not (lo == 0 and hi == 0) and lo <= hi:
            out_of = (v < lo) | (v > hi)
            why = f"outside the DBC's range [{lo:g}|{hi:g}] of {_describe(ch)}"
        if ch["type"] == "float32":
            with np.errstate(over="ignore"):
                big = ~np.isfinite(((v - ch["offset"]) / ch["factor"]).astype(np.float32))
            if big.any() and (not out_of.any() or np.flatnonzero(big)[0] < np.flatnonzero(out_of)[0]):
                out_of, why = big, f"beyond float32's range in {_describe(ch)}"
        if out_of.any():
            j = int(np.flatnonzero(out_of)[0])
            unit = f" {ch['unit']}" if ch["unit"] else ""
            raise ValueError(f"{where(int(rows[j]))}: channel {c!r} = {float(v[j])!r}{unit} is {why}; "
                             f"{int(out_of.sum())} such value(s) of {c!r}: refused, never saturated")
    tmp = os.path.join(os.path.dirname(os.path.abspath(out)), f".{os.path.basename(out)}.{os.getpid()}.tmp")
    try:
        res = _core.write_candump(tmp, dbc, chans, chans, channel_map, hint, values, np.ascontiguousarray(index),
                                  np.ascontiguousarray(t_us), str(iface))
        if res["failed_row"] >= 0:
            j, i = int(res["failed_row"]), int(res["failed_channel"])
            if i < 0:
                raise ValueError(f"{where(int(rows[j]))}: {res['failed_text']}")
            ch = plan["channels"][i]
            unit = f" {ch['unit']}" if ch["unit"] else ""
            raise ValueError(f"{where(int(rows[j]))}: channel {chans[i]!r} = {float(values[j, i])!r}{unit} does not "
                             f"fit {_describe(ch)}: refused, never saturated")
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return {"samples": int(keep.sum()), "missing": int(missing.sum()), "frames": int(res["frames"]), "plan": plan,
            "counter_note": counter_note, "rounded": [int(x) for x in res["rounded"]],
            "max_error": [float(e) * float(f) for e, f in zip(res["max_error"], k)]}
