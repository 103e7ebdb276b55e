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
        # flags as text ("" = none), as identify's tracks; "nan"/"inf" values as floats
        df = pd.read_csv(tracks, comment="#", dtype={"flags": str}, keep_default_na=False, na_values=["nan"])
    if "flags" in df.columns:
        df["flags"] = df["flags"].astype(str)
    df.attrs["config"] = config
    return df
