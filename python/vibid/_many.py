"""vibid.identify_many: :func:`vibid.identify` on many captures, in parallel processes on
this machine or on the workers of a Dask cluster, into one table with a row per capture.

Every capture is identified by the same library call as :func:`vibid.identify` (the worker
processes import the installed vibid), so a row holds exactly what ``identify`` gives for
that capture, wherever it ran. A capture that fails (a missing file, a NaN, a missing
channel, an estimate the library refuses) gets a row with ``status`` "error" and the reason;
the others are not affected.
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
from typing import Any, Mapping, Optional

import numpy as np
import pandas as pd

from ._identify import METHODS, identify
from ._stand import Stand, _stand_from_text

# identify's options that identify_many passes on (the same for every capture). Tracks are
# not part of the table: identify_many asks for none (track_every=0), which gives the same
# final estimate as with tracks (pushes in pieces and in one block are bit-identical).
_OPTIONS = ("forgetting", "prefilter_hz", "iv_lag")
_FIXED = ("capture", "status", "error", "n_samples", "method")

# Stands rebuilt in this (worker) process, by what identifies them: loaded once per process,
# not once per capture. A stand file is keyed with its modification time and size, so a
# long-lived Dask worker reloads an edited file.
_STANDS: dict = {}


def _stand_spec(stand: Stand) -> tuple:
    """What rebuilds the stand in another process: the libconfig text of a stand made from a
    dict, else the absolute path of its file (vibid.Stand wraps a C object, which cannot be
    pickled)."""
    if stand._text is not None:
        return ("text", stand._text)
    return ("path", stand._path)


def _stand_of(spec: tuple) -> Stand:
    kind, value = spec
    if kind == "path":
        st = os.stat(value)
        key = (kind, value, st.st_mtime_ns, st.st_size)
    else:
        key = spec
    stand = _STANDS.get(key)
    if stand is None:
        stand = Stand.load(value) if kind == "path" else _stand_from_text(value)
        if len(_STANDS) >= 16:  # a worker serving many different stands: no unbounded cache
            _STANDS.clear()
        _STANDS[key] = stand
    return stand


def _error_text(e: BaseException) -> str:
    return f"{type(e).__name__}: {e}"


def _error_row(name: Any, error: str) -> dict:
    return {"capture": name, "status": "error", "error": error}


def _identify_one(spec: tuple | Stand, name: Any, data: Any, method: str, options: dict) -> dict:
    """One capture, in a worker process (or in the caller for processes=1, with the caller's
    Stand as ``spec``): the table's row. Never raises for what the capture or the stand does
    wrong: the row says it."""
    try:
        stand = spec if isinstance(spec, Stand) else _stand_of(spec)
    except Exception as e:
        where = spec[1] if spec[0] == "path" else "from a dict"
        return _error_row(name, f"{type(e).__name__}: loading the stand ({where}) in process {os.getpid()}: {e}")
    try:
        r = identify(stand, data, method=method, track_every=0, **options)
    except Exception as e:
        return _error_row(name, _error_text(e))
    row = {"capture": name, "status": "ok", "error": "", "n_samples": r.n_samples, "method": r.method}
    p = r.parameters
    for pname, value, se, flags in zip(p.index, p["value"].to_numpy(), p["se"].to_numpy(), p["flags"]):
        row[pname] = float(value)
        row[pname + "_se"] = float(se)
        row[pname + "_flags"] = flags
    m = r.modes
    for i, f, fse, z, zse in zip(m.index, m["freq_hz"].to_numpy(), m["freq_hz_se"].to_numpy(),
                                 m["zeta"].to_numpy(), m["zeta_se"].to_numpy()):
        row[f"f{i}_hz"] = float(f)
        row[f"f{i}_hz_se"] = float(fse)
        row[f"zeta{i}"] = float(z)
        row[f"zeta{i}_se"] = float(zse)
    row["estimate_flags"] = r.flags
    return row


def _worker_version() -> str:
    import vibid
    return vibid.__version__


def _captures(captures: Any) -> tuple[list, list]:
    """Names and data, in input order."""
    if isinstance(captures, Mapping):
        return list(captures.keys()), list(captures.values())
    if isinstance(captures, (str, os.PathLike, pd.DataFrame, np.ndarray)):
        raise TypeError("captures: a list of capture paths or a dict {name: path, DataFrame or dict of arrays}, "
                        f"not a single {type(captures).__name__} (for one capture call vibid.identify)")
    names, data = [], []
    for i, c in enumerate(captures):
        if not isinstance(c, (str, os.PathLike)):
            raise TypeError(f"captures[{i}] is a {type(c).__name__}: a list holds capture paths; pass data "
                            "(DataFrames, dicts of arrays) as a dict {name: data}")
        names.append(os.fspath(c))
        data.append(c)
    return names, data


def _columns(stand: Stand) -> list[str]:
    cols = list(_FIXED)
    for p in stand.parameters:
        cols += [p, p + "_se", p + "_flags"]
    for i in range(1, stand.n_dof + 1):
        cols += [f"f{i}_hz", f"f{i}_hz_se", f"zeta{i}", f"zeta{i}_se"]
    cols.append("estimate_flags")  # not "flags": DataFrame.flags is pandas' own attribute
    seen = set()
    for c in cols:
        if c in seen:
            raise ValueError(f"the stand {stand.name!r} has a parameter whose name gives the column {c!r} twice "
                             f"in identify_many's table ({cols}); rename the element in the stand")
        seen.add(c)
    return cols


def _table(rows: list, stand: Stand) -> pd.DataFrame:
    cols = _columns(stand)
    params = stand.parameters
    string_cols = {"capture", "status", "error", "method", "estimate_flags", *(p + "_flags" for p in params)}
    for r in rows:
        if r["status"] != "ok":
            # No estimate: the daemon's letter E for the estimate and every parameter.
            r.update({"n_samples": None, "method": "", "estimate_flags": "E", **{p + "_flags": "E" for p in params}})
    df = pd.DataFrame.from_records(rows, columns=cols)
    df["n_samples"] = df["n_samples"].astype("Int64")
    for c in cols:
        if c not in string_cols and c != "n_samples":
            df[c] = df[c].astype(np.float64)  # NaN in the rows of failed captures
    return df


def _run_serial(stand: Stand, names, data, method, options) -> list:
    return [_identify_one(stand, n, d, method, options) for n, d in zip(names, data)]


def _run_processes(spec, names, data, method, options, processes: int) -> list:
    # "spawn": fresh interpreters that import the installed vibid, as Dask's workers do; safe
    # whatever threads the caller runs (fork after threads can deadlock), and the same on
    # Linux, macOS and Windows. A script that calls identify_many needs the usual
    # `if __name__ == "__main__":` guard.
    ctx = multiprocessing.get_context("spawn")
    rows = []
    with concurrent.futures.ProcessPoolExecutor(max_workers=processes, mp_context=ctx) as ex:
        futures = [ex.submit(_identify_one, spec, n, d, method, options) for n, d in zip(names, data)]
        try:
            for n, f in zip(names, futures):
                try:
                    rows.append(f.result())
                except Exception as e:  # the worker died (BrokenProcessPool), the data did not pickle
                    rows.append(_error_row(n, _error_text(e)))
        except BaseException:
            for f in futures:
                f.cancel()
            raise
    return rows


def _run_dask(spec, names, data, method, options, client) -> list:
    from distributed import wait  # only with a client: dask is an optional extra

    try:
        versions = client.run(_worker_version)
    except Exception as e:
        raise RuntimeError(f"the Dask workers cannot import vibid ({type(e).__name__}: {e}); install the same "
                           "vibid on every worker") from e
    import vibid
    other = {w: v for w, v in versions.items() if v != vibid.__version__}
    if other:
        raise RuntimeError(f"Dask workers run another vibid than this process ({vibid.__version__}): {other}; "
                           "install the same version on every worker")
    # Arrays and DataFrames go to the cluster once, scattered (not inside the task graph);
    # paths are sent as they are and read by the worker.
    is_path = [isinstance(d, (str, os.PathLike)) for d in data]
    payload = [os.path.abspath(os.fspath(d)) if p else d for d, p in zip(data, is_path)]
    to_scatter = [d for d, p in zip(payload, is_path) if not p]
    if to_scatter:
        scattered = iter(client.scatter(to_scatter))
        payload = [d if p else next(scattered) for d, p in zip(payload, is_path)]
    futures = [client.submit(_identify_one, spec, n, d, method, options, pure=False)
               for n, d in zip(names, payload)]
    try:
        wait(futures)
        done = [i for i, f in enumerate(futures) if f.status == "finished"]
        results = dict(zip(done, client.gather([futures[i] for i in done])))
        rows = []
        for i, (n, f) in enumerate(zip(names, futures)):
            if i in results:
                rows.append(results[i])
            else:  # a worker lost (KilledWorker), a task that could not run there
                try:
                    exc = f.exception()
                except Exception as e:
                    exc = e
                rows.append(_error_row(n, _error_text(exc) if exc is not None else f"Dask task {f.status}"))
        return rows
    finally:
        client.cancel(futures)


def identify_many(captures: Any, stand: Stand | str | os.PathLike, method: str = "auto", *,
                  client: Any = None, processes: Optional[int] = None, **identify_kwargs) -> pd.DataFrame:
    """:func:`vibid.identify` on many captures at once; one row per capture, in input order.

    captures: a list of capture paths (CSV, MDF4, TDMS: whatever ``identify`` reads), or a
        dict ``{name: path, DataFrame or dict of arrays}``.
    stand: a :class:`Stand` or the path of a stand file; sent to the workers as the file's
        absolute path (a stand loaded from a file) or as its libconfig text (a stand made by
        :meth:`Stand.from_dict`) and rebuilt there once per process.
    method, identify_kwargs (``forgetting``, ``prefilter_hz``, ``iv_lag``): as for
        ``identify``, the same for every capture.
    client: a Dask ``distributed.Client``: the captures run on its workers (which need the
        same vibid installed and, for paths, the files). None: processes on this machine.
    processes: worker processes on this machine (default ``os.cpu_count()``); 1 runs the
        captures one after the other in this process, without a pool.

    Returns a DataFrame with columns ``capture`` (the path or the dict's key), ``status``
    ("ok" or "error"), ``error`` ("Type: message", "" when ok), ``n_samples``, ``method``
    (the estimator used), per parameter ``<p>``, ``<p>_se``, ``<p>_flags``, per mode
    ``f<i>_hz``, ``f<i>_hz_se``, ``zeta<i>``, ``zeta<i>_se``, and ``estimate_flags`` (the
    estimate's letters; "E" and NaN values in the rows of failed captures). Read columns as
    ``table["name"]``: ``table.<name>`` is pandas' attribute where one has that name (as
    ``DataFrame.flags``, which is why the estimate's column is not called ``flags``).
    """
    if method not in METHODS:
        raise ValueError(f"method {method!r}: one of {', '.join(METHODS)}")
    unknown = [k for k in identify_kwargs if k not in _OPTIONS]
    if unknown:
        if "track_every" in unknown:
            raise TypeError("identify_many: track_every: the table holds final estimates only; for tracks call "
                            "vibid.identify on the capture")
        raise TypeError(f"identify_many: unknown option {unknown[0]!r}; identify's options here: {', '.join(_OPTIONS)}")
    if client is not None and processes is not None:
        raise ValueError("identify_many: give either client (a Dask cluster) or processes (this machine), not both")
    if processes is None:
        processes = os.cpu_count() or 1
    if int(processes) != processes or processes < 1:
        raise ValueError(f"processes = {processes!r}: a number of processes >= 1")
    processes = int(processes)
    if not isinstance(stand, Stand):
        stand = Stand.load(stand)  # a bad stand fails here, once, not in every row
    spec = _stand_spec(stand)
    names, data = _captures(captures)
    _columns(stand)  # a clash of column names fails before any work
    options = {k: v for k, v in identify_kwargs.items() if v is not None}
    if not names:
        rows = []
    elif client is not None:
        rows = _run_dask(spec, names, data, method, options, client)
    elif processes == 1 or len(names) == 1:
        rows = _run_serial(stand, names, data, method, options)
    else:
        rows = _run_processes(spec, names, data, method, options, min(processes, len(names)))
    return _table(rows, stand)
