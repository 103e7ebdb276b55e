"""The long C calls release the GIL: Python code runs in another thread meanwhile."""

from __future__ import annotations

import threading
import time

import numpy as np

import vibid
from vibid import _core


def test_push_releases_the_gil(example1_stand):
    # 400,000 samples take tenths of a second in vibid_ident_push_block (README: ~300 ns
    # per sample). While they run, the main thread timestamps its own loop iterations.
    # Holding the GIL, no iteration could run strictly inside the call; released, thousands do.
    rng = np.random.default_rng(0)
    block = np.asfortranarray(rng.standard_normal((400_000, 3)) * 1e-3)
    ident = _core.Ident(example1_stand._core, _core.ESTIMATOR_AUTO, 1.0, -1.0, 0)
    span = {}

    def work():
        span["t0"] = time.perf_counter()
        ident.push(block, 0, block.shape[0])
        span["t1"] = time.perf_counter()

    th = threading.Thread(target=work)
    stamps = []
    th.start()
    while th.is_alive():
        stamps.append(time.perf_counter())
    th.join()
    t0, t1 = span["t0"], span["t1"]
    margin = 0.2 * (t1 - t0)  # away from the call's edges, where the GIL changes hands
    inside = sum(1 for s in stamps if t0 + margin < s < t1 - margin)
    assert t1 - t0 > 0.02, "too short a call to tell"
    assert inside > 100, (inside, t1 - t0)
