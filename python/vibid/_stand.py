"""Stands: the stand file (docs/stand-file.md) read by the C loader, from a file or a dict."""

from __future__ import annotations

import math
import os
import re
import tempfile
from typing import Any, Mapping

from . import _core

# The model's parameter kinds in SI units (model.h). The library never converts: a stand
# written in mm, N, s, t has its parameters in those units instead.
def parameter_unit(kind: str, length_unit: str) -> str:
    """The unit of a parameter of this kind on a stand whose lengths are in length_unit
    (docs/stand-file.md: forces in N, time in s, so a mass is in N s^2 per length unit: kg
    with m, t with mm). A gain maps the input's own unit to N."""
    lu = length_unit
    if kind == "mass":
        return {"m": "kg", "mm": "t"}.get(lu, f"N s^2/{lu}")
    return {"damping": f"N s/{lu}", "stiffness": f"N/{lu}", "cubic": f"N/{lu}^3",
            "gain": "N/input unit"}[kind]


def _libconfig_value(v: Any, path: str) -> str:
    if isinstance(v, bool):  # before int: bool is an int in Python
        return "true" if v else "false"
    if isinstance(v, int):
        # The loader accepts an int wherever a number is expected, and some fields must be
        # ints (n_dof): ints stay ints. Beyond 32 bits libconfig needs the L suffix.
        return str(v) + ("L" if not -2**31 <= v < 2**31 else "")
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"{path}: {v!r} is not a finite number")
        return repr(v) if ("e" in repr(v) or "." in repr(v)) else repr(v) + ".0"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, Mapping):
        return _libconfig_group(v, path)
    if isinstance(v, (list, tuple)):
        items = list(v)
        # libconfig: [scalars] is an array, (groups) is a list.
        if all(isinstance(x, Mapping) for x in items) and items:
            return "(" + ", ".join(_libconfig_value(x, f"{path}.[{i}]") for i, x in enumerate(items)) + ")"
        return "[" + ", ".join(_libconfig_value(x, f"{path}.[{i}]") for i, x in enumerate(items)) + "]"
    if hasattr(v, "item"):  # numpy scalar
        return _libconfig_value(v.item(), path)
    raise TypeError(f"{path}: cannot write a {type(v).__name__} to a stand file")


def _libconfig_group(d: Mapping, path: str) -> str:
    parts = []
    for k, v in d.items():
        if not isinstance(k, str):
            raise TypeError(f"{path}: key {k!r} is not a string")
        parts.append(f"{k} = {_libconfig_value(v, f'{path}.{k}' if path else k)};")
    return "{ " + " ".join(parts) + " }"


def to_libconfig(d: Mapping) -> str:
    """The libconfig text of a stand dict (the ``stand`` group's content, or a dict with a
    ``stand`` key). One line per top-level field, so that the loader's line numbers point
    at the field in error."""
    if "stand" in d and len(d) == 1:
        d = d["stand"]
    lines = ["stand = {"]
    for k, v in d.items():
        lines.append(f"  {k} = {_libconfig_value(v, 'stand.' + k)};")
    lines.append("};")
    return "\n".join(lines) + "\n"


class Stand:
    """A test stand: the lumped model, its channels and sample rate.

    Read by the one C loader every vibid program uses, so a stand accepted here is accepted
    by vibidd and vibid-sim and the errors are the same (``file:line: field: reason``,
    raised as :class:`vibid.VibidError`)."""

    def __init__(self, core: _core.Stand, source: str, text: str | None = None):
        self._core = core
        self.source = source
        # What rebuilds the stand in another process (pickling, vibid.identify_many's
        # workers): the libconfig text of a stand made from a dict, else the absolute path
        # of its file (the C object itself cannot be pickled).
        self._text = text
        self._path = os.path.abspath(source) if text is None else None

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Stand":
        """Loads the ``stand`` group of a libconfig stand file (docs/stand-file.md)."""
        path = os.fspath(path)
        return cls(_core.Stand(path), path)

    @classmethod
    def from_dict(cls, d: Mapping) -> "Stand":
        """The same schema as a stand file, as nested dicts and lists: e.g.
        ``{"name": "s", "sample_rate": 1000.0, "nodes": [{"name": "m1", ...}], ...}``.
        Written to a temporary libconfig file and read by the C loader, so the checks are
        the stand file's; an error names the field (``stand dict: stand.nodes.[0].mass: ...``),
        not the temporary file, whose name and line mean nothing to the caller."""
        return _stand_from_text(to_libconfig(d))

    @property
    def name(self) -> str:
        return self._core.name

    @property
    def sample_rate(self) -> float:
        """f_a in Hz."""
        return self._core.sample_rate

    @property
    def channels(self) -> list[str]:
        """Acquisition channel names, in the model's channel order (the columns identify needs)."""
        return list(self._core.channels)

    @property
    def channel_quantities(self) -> list[str]:
        """What each channel of :attr:`channels` measures: ``"displacement"``,
        ``"velocity"``, ``"acceleration"`` (of a node or the base) or ``"input"`` (a force
        input, in the input's own units; the stand's ``gain`` is N per input unit)."""
        return [q for q, _, _ in _core.stand_channel_info(self._core)]

    @property
    def channel_models(self) -> list[str]:
        """The model's name of each channel: ``"m2.displacement"``, ``"base.velocity"``,
        or the input's name."""
        return [n for _, _, n in _core.stand_channel_info(self._core)]

    @property
    def length_unit(self) -> str:
        """The stand's length unit (``length_unit``, default ``"m"``): displacements,
        velocities and accelerations are in it, forces in N, time in s."""
        return self._core.length_unit

    @property
    def length_si(self) -> float:
        """Metres per :attr:`length_unit` (1 for m, 1e-3 for mm)."""
        return self._core.length_si

    @property
    def parameters(self) -> list[str]:
        """Names of the unknowns, in the model's parameter order."""
        return [p[0] for p in self._core.params]

    @property
    def kinds(self) -> list[str]:
        return [p[1] for p in self._core.params]

    @property
    def units(self) -> list[str]:
        """The unit of each unknown, in the stand's length unit (``N/mm`` on a stand in mm)."""
        lu = self.length_unit
        return [parameter_unit(p[1], lu) for p in self._core.params]

    @property
    def nominal_values(self) -> list[float]:
        """Start values of the unknowns (``mass``/``value``/``gain`` of an unknown); NaN
        where the file gives none (the library's 0 = not given)."""
        return [p[2] if p[2] != 0 else math.nan for p in self._core.params]

    @property
    def true_values(self) -> list[float]:
        """The ``true_value`` of each unknown where the file gives one, else NaN."""
        return [p[3] for p in self._core.params]

    @property
    def n_dof(self) -> int:
        return self._core.n_dof

    def __reduce__(self):
        # Pickled as what rebuilds it: a dict's libconfig text, or the file's absolute path
        # (which must then be readable where it is unpickled).
        if self._text is not None:
            return (_stand_from_text, (self._text,))
        return (Stand.load, (self._path,))

    def __repr__(self) -> str:
        return (f"<vibid.Stand {self.name!r}: {self.sample_rate:g} Hz, channels {self.channels}, "
                f"unknowns {self.parameters}>")


def _stand_from_text(text: str) -> Stand:
    """A stand from the libconfig text :meth:`Stand.from_dict` wrote (unpickling)."""
    fd, path = tempfile.mkstemp(prefix="vibid-stand-", suffix=".cfg")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        try:
            return Stand(_core.Stand(path), "<dict>", text)
        except _core.VibidError as e:
            raise _core.VibidError(re.sub(re.escape(path) + r":\d+: ", "stand dict: ", str(e))) from None
    finally:
        os.unlink(path)
