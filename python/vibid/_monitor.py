"""vibid.monitor: long captures replayed through vibidd's change test (docs/python.md).

Nothing here tests for a change: every capture goes through vibidd's own pipeline in this
process (:func:`vibid.replay`'s code: configuration reader, replay source, estimator, the
change test of vibid/change.h, the writers), with the alarms' reference kept in a file
across the captures exactly as vibidd keeps it across restarts. So the events are the ones
vibidd raises on the same captures; this module reads them back from the InfluxDB lines the
pipeline writes and draws them.
"""

from __future__ import annotations

import os
import re
import tempfile
from dataclasses import dataclass, field
from typing import Iterable, Optional

import numpy as np
import pandas as pd

from . import _core
from ._drivers import _exists, _need, _read_tracks

EVENT_COLUMNS = ["capture", "time_s", "index", "parameter", "state", "test", "onset_index", "value", "baseline",
                 "z", "statistic", "threshold", "change", "change_se"]


def _unescape(text: str) -> str:
    out, i = [], 0
    while i < len(text):
        if text[i] == "\\" and i + 1 < len(text):
            i += 1
        out.append(text[i])
        i += 1
    return "".join(out)


def _split_unescaped(text: str, sep: str) -> list[str]:
    parts, cur, i = [], [], 0
    while i < len(text):
        c = text[i]
        if c == "\\" and i + 1 < len(text):
            cur.append(text[i:i + 2])
            i += 2
            continue
        if c == sep:
            parts.append("".join(cur))
            cur = []
        else:
            cur.append(c)
        i += 1
    parts.append("".join(cur))
    return parts


def parse_alarm_lines(path: str, capture: str) -> list[dict]:
    """The ``vibid_alarm`` points of an InfluxDB line file that vibidd wrote (docs/vibidd.md,
    "InfluxDB schema"), one dict per event. Field values are numbers, integers (``i``) or
    quoted strings without spaces or commas (vibidd writes no other)."""
    events = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            line = line.rstrip("\n")
            if not line.startswith("vibid_alarm,") and not line.startswith("vibid_alarm "):
                continue
            head, sep, rest = line.partition(" ")
            while head.endswith("\\") and sep:  # an escaped space inside a tag
                more, sep, rest = rest.partition(" ")
                head = head + " " + more
            fields_text, _, ts = rest.rpartition(" ")
            tags = dict(_split_unescaped(t, "=")[:2] for t in _split_unescaped(head, ",")[1:])
            ev: dict = {"capture": capture, "time_s": int(ts) / 1e9,
                        "parameter": _unescape(tags.get("parameter", ""))}
            for item in fields_text.split(","):
                key, _, val = item.partition("=")
                if val.startswith('"'):
                    ev[key] = val.strip('"')
                elif val.endswith("i"):
                    ev[key] = int(val[:-1])
                else:
                    ev[key] = float(val)
            events.append(ev)
    return events


def read_reference(path: str) -> dict:
    """A saved alarm reference (docs/vibidd.md, "The reference across restarts") as
    {parameter: {field: value}} plus the header keys (format, stand, key, learned_index,
    learned_time_s) at the top level."""
    out: dict = {}
    with open(path, encoding="utf-8") as f:
        for line in f:
            line = line.strip()
            if not line or line.startswith("#") or "=" not in line:
                continue
            key, _, val = line.partition("=")
            if key in ("format", "stand", "key", "learned_index", "learned_time_s"):
                out[key] = val
                continue
            param, _, fld = key.rpartition(".")
            out.setdefault(param, {})[fld] = float(val)
    return out


@dataclass
class Monitoring:
    """What :func:`monitor` found. ``tracks``: every capture's rows (vibidd's tracks, a column
    ``capture`` added; ``<p>_change_statistic`` and ``<p>_mdc`` for the alarmed parameters,
    covariates by their channel names). ``events``: the alarm events (columns
    :data:`EVENT_COLUMNS`). ``reference``: the reference the test ran with
    (:func:`read_reference`), ``reference_file`` where it is kept."""
    tracks: pd.DataFrame
    events: pd.DataFrame
    reference: dict
    reference_file: Optional[str]
    covariates: list = field(default_factory=list)

    def parameters(self) -> list[str]:
        """The alarmed parameters (those with a change statistic)."""
        return [c[:-len("_change_statistic")] for c in self.tracks.columns if c.endswith("_change_statistic")]

    def plot(self, parameters: Optional[Iterable[str]] = None, path: Optional[str] = None):
        """Per alarmed parameter the change statistic (the CUSUM over its threshold: the
        alarm raises at 1), the threshold, the events (raised: red, cleared: green, the
        estimated onset dotted), and the covariates below. Returns the matplotlib Figure;
        saved to path when given."""
        from . import _plot

        return _plot.monitoring_figure(self, list(parameters) if parameters is not None else self.parameters(),
                                       path)


def monitor(config: str | os.PathLike, captures: Iterable[str | os.PathLike] | str | os.PathLike, *,
            reference: Optional[str | os.PathLike] = None, log_level: str = "warning",
            rate_check: str = "error") -> Monitoring:
    """Replays long captures in order through vibidd's pipeline and its change test
    (``alarms.test = "cusum"``), as vibidd would run over them with restarts between them.

    config: a vibidd configuration (its stand, channel map, estimator and alarms); its source
        is replaced by each capture (as ``vibidd --replay``).
    captures: one capture or several, in time order (CSV, raw recording, candump log).
    reference: the alarms' reference file. Read when it exists (the test runs against it from
        the first capture on); else learned over the first capture's reference period
        (``alarms.learn_start``, ``learn_duration``) and saved there, then read by the next
        captures, as vibidd does across restarts. None: a temporary file, learned from the
        first capture and kept for the others.
    log_level, rate_check: as :func:`vibid.replay`.

    Returns a :class:`Monitoring`. Raises as :func:`vibid.replay`; ValueError when the
    configuration has no change test (alarms off, or ``test = "threshold"``).
    """
    _need(True, "vibid.monitor")
    config = _exists(os.fspath(config), "vibidd configuration")
    if isinstance(captures, (str, os.PathLike)):
        captures = [captures]
    captures = [_exists(os.fspath(c), "capture") for c in captures]
    if not captures:
        raise ValueError("vibid.monitor: no capture given")
    with tempfile.TemporaryDirectory(prefix="vibid-monitor-") as tmp:
        ref = os.fspath(reference) if reference is not None else os.path.join(tmp, "reference")
        frames, events = [], []
        for i, cap in enumerate(captures):
            tracks = os.path.join(tmp, f"tracks{i}.csv")
            influx = os.path.join(tmp, f"lines{i}.influx")
            rc = _core.replay_run(config, cap, tracks, str(log_level), str(rate_check), influx, ref)
            if rc != 0:
                raise _core.VibidError(f"{config} on {cap}: the pipeline ended with vibidd's exit status {rc} (a "
                                       "run-time failure; the daemon's log lines on stderr say what failed)")
            df = _read_tracks(tracks)
            if i == 0 and not any(c.endswith("_change_statistic") for c in df.columns):
                raise ValueError(f"{config}: no change test (alarms off, no alarmed parameter, or alarms.test = "
                                 "\"threshold\"): vibid.monitor needs alarms = { test = \"cusum\"; ... } (the default)")
            df.insert(0, "capture", cap)
            frames.append(df)
            events.extend(parse_alarm_lines(influx, cap))
        refd = read_reference(ref) if os.path.exists(ref) else {}
    tracks_all = pd.concat(frames, ignore_index=True)
    ev = pd.DataFrame(events)
    for c in EVENT_COLUMNS:
        if c not in ev.columns:
            ev[c] = np.nan if c not in ("capture", "parameter", "state", "test") else ""
    ev = ev[EVENT_COLUMNS]
    return Monitoring(tracks_all, ev, refd, os.fspath(reference) if reference is not None else None,
                      covariate_columns(list(tracks_all.columns)))


_MODE_COLUMN = re.compile(r"^(f\d+_hz|f\d+_hz_se|zeta\d+|zeta\d+_se)$")


def covariate_columns(columns: list[str]) -> list[str]:
    """The covariates of vibidd's tracks (docs/vibidd.md, "Tracks CSV"): the columns between
    the modes' (or the parameters') and the change test's or ``gap_samples``."""
    cols = set(columns)
    params = {c[:-3] for c in cols if c.endswith("_se") and c[:-3] in cols}
    out = []
    for c in columns:
        if c in ("capture", "time_s", "index", "gap_samples", "flags") or c in params or _MODE_COLUMN.match(c):
            continue
        if c.endswith("_se") and c[:-3] in params:
            continue
        if (c.endswith("_change_statistic") and c[:-17] in params) or (c.endswith("_mdc") and c[:-4] in params):
            continue
        out.append(c)
    return out
