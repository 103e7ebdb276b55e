"""Output-only modal identification, vibid against pyOMA2 (issue 34's speed figure): SSI-cov on
1 h of 16 channels at 1 kHz (3.6 M samples), the same data and settings in both.

Run (one run: about 1.5 min at the full hour, plus 45 s to simulate the data the first time;
18 GiB of memory at the peak, pyOMA2's: its Hankel rows of 320 x 3.6 M values twice):

    python3 -m venv build/bench-venv
    build/bench-venv/bin/pip install pyOMA-2 numpy pandas scikit-build-core==1.1.2 nanobind==3.1.0
    build/bench-venv/bin/pip install --no-build-isolation ./python     # vibid (or -C build-dir=...)
    build/bench-venv/bin/python bench/bench_oma.py [--duration 3600] [--data-dir build/bench-oma]
        [--vibid-python PY] [--pyoma-python PY]

(pyOMA2 is "pyOMA-2" on PyPI.) Both --*-python default to this interpreter; each needs numpy
and its own package (vibid, or pyoma2).

What it does. The data: the ambient response (displacements, sensor noise 1 % of each
channel's RMS) of a 16-mass chain under unmeasured white forces on every mass, simulated once
by python/tests/oma_sim.py (exact discretisation) and kept in an .npy file (samples x
channels, C order, as a user would hold it); the truth: the continuous model's 16 modes,
6-150 Hz, damping 0.1-2.2 %. Each tool then runs in a child process of its own that loads
the file and times one call from the array to the modes:
  vibid    vibid.oma(data, fs, max_order=60, block_rows=20, blocks=32): covariances,
           stabilisation diagram, automatic mode selection, standard errors from the 32
           blocks' spread; libvibid on one thread.
  pyOMA2   SingleSetup(data, fs), SSI(method="cov", br=20, ordmax=60, step=2, calc_unc=True,
           nb=32), run, then mpe(sel_freq=the true frequencies, order_in=60): pyOMA2 has
           no automatic selection in SSI, so it is handed the truth, as a user picking the
           stabilisation diagram's columns would; its BLAS uses every core.
The same block rows (20: lags 1..39), the same orders (2, 4, .., 60) and the same 32 blocks
for the uncertainties. Printed: samples, channels, settings; per tool the wall time, the
process CPU time and the peak resident memory (getrusage ru_maxrss of its process, the
loaded data included); the ratio of the wall times; and each tool's modes beside the truth.
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
FS = 1000.0
N_DOF = 16
BLOCK_ROWS = 20
MAX_ORDER = 60
BLOCKS = 32


def chain():
    """Masses, springs and dampers of the chain: masses 0.6-1.4 kg, springs 2e5 down to
    1.1e5 N/m, dampers 2.5e-5 of the spring plus 4 N s/m (not proportional)."""
    j = np.arange(N_DOF)
    m = 1.0 + 0.4 * np.cos(1.3 * j)
    k = 2.0e5 * (1.0 - 0.03 * j)
    d = 2.5e-5 * k + 4.0
    return m, k, d


def make_data(path, n):
    sys.path.insert(0, os.path.join(ROOT, "python", "tests"))
    import oma_sim

    M, D, K = oma_sim.chain_matrices(*chain())
    t = time.perf_counter()
    y = oma_sim.ambient(M, D, K, FS, n, noise=0.01, seed=34)
    np.save(path, np.ascontiguousarray(y))
    print(f"simulated {n} samples x {N_DOF} channels in {time.perf_counter() - t:.0f} s: {path}", flush=True)


def truth():
    sys.path.insert(0, os.path.join(ROOT, "python", "tests"))
    import oma_sim

    return oma_sim.modes(*oma_sim.chain_matrices(*chain()))


# ---- children: one tool each, the result as one JSON line on stdout ----

def child_vibid(path, sel):
    import vibid

    data = np.load(path)
    t0, c0 = time.perf_counter(), time.process_time()
    r = vibid.oma(data, FS, max_order=MAX_ORDER, block_rows=BLOCK_ROWS, blocks=BLOCKS)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    m = r.modes
    return dict(tool=f"vibid {getattr(vibid, '__version__', '')}".strip(), wall=wall, cpu=cpu,
                f=m.freq_hz.tolist(), f_se=m.freq_hz_se.tolist(), zeta=m.zeta.tolist(),
                zeta_se=m.zeta_se.tolist(), n_samples=r.n_samples)


def child_pyoma(path, sel):
    import logging

    logging.disable(logging.WARNING)  # its progress bars and info lines
    import pyoma2
    from importlib.metadata import version
    from pyoma2.algorithms import SSI
    from pyoma2.setup import SingleSetup

    data = np.load(path)
    t0, c0 = time.perf_counter(), time.process_time()
    setup = SingleSetup(data, fs=FS)
    alg = SSI(name="ssicov", method="cov", br=BLOCK_ROWS, ordmax=MAX_ORDER, step=2, calc_unc=True, nb=BLOCKS)
    setup.add_algorithms(alg)
    setup.run_by_name("ssicov")
    setup.mpe("ssicov", sel_freq=list(sel), order_in=MAX_ORDER, rtol=0.02)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    res = setup["ssicov"].result
    del pyoma2
    return dict(tool=f"pyOMA2 {version('pyOMA-2')}", wall=wall, cpu=cpu, f=np.asarray(res.Fn).tolist(),
                f_se=np.asarray(res.Fn_std).tolist(), zeta=np.asarray(res.Xi).tolist(),
                zeta_se=np.asarray(res.Xi_std).tolist(), n_samples=int(data.shape[0]))


def child(which, path):
    f, _ = truth()
    out = (child_vibid if which == "vibid" else child_pyoma)(path, f)
    out["maxrss_kib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print("RESULT " + json.dumps(out), flush=True)


def run_child(python, which, path):
    cmd = [python, os.path.abspath(__file__), "--child", which, "--data", path]
    t = time.perf_counter()
    p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = next((x for x in p.stdout.splitlines() if x.startswith("RESULT ")), None)
    if p.returncode != 0 or line is None:
        tail = "\n".join(p.stderr.strip().splitlines()[-5:])
        print(f"{which}: failed (exit {p.returncode}, after {time.perf_counter() - t:.0f} s): {tail}", flush=True)
        return None
    return json.loads(line[len("RESULT "):])


def nearest(f, fs_found):
    if len(fs_found) == 0:
        return None
    j = int(np.argmin(np.abs(np.asarray(fs_found) - f)))
    return j if abs(fs_found[j] / f - 1.0) <= 0.02 else None


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=3600.0, help="seconds of data (default 3600)")
    ap.add_argument("--data-dir", default=os.path.join(ROOT, "build", "bench-oma"))
    ap.add_argument("--vibid-python", default=sys.executable)
    ap.add_argument("--pyoma-python", default=sys.executable)
    ap.add_argument("--child", choices=("vibid", "pyoma"), help=argparse.SUPPRESS)
    ap.add_argument("--data", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        child(a.child, a.data)
        return
    n = int(round(a.duration * FS))
    os.makedirs(a.data_dir, exist_ok=True)
    path = os.path.join(a.data_dir, f"chain16_{n}.npy")
    if not os.path.exists(path):
        make_data(path, n)
    f, z = truth()
    print(f"data: {n} samples x {N_DOF} channels at {FS:g} Hz ({n / FS / 3600:.3g} h, {n * N_DOF * 8 / 2**20:.0f} MiB "
          f"float64), {N_DOF}-mass chain, displacements, 1 % sensor noise")
    print(f"settings: SSI-cov, block rows {BLOCK_ROWS} (lags 1..{2 * BLOCK_ROWS - 1}), orders 2..{MAX_ORDER} step 2, "
          f"{BLOCKS} blocks for the standard errors, all channels references; {os.cpu_count()} cores", flush=True)
    results = {}
    for which, py in (("vibid", a.vibid_python), ("pyoma", a.pyoma_python)):
        r = run_child(py, which, path)
        if r is None:
            continue
        results[which] = r
        print(f"{r['tool']:>14}: wall {r['wall']:8.2f} s   cpu {r['cpu']:8.2f} s   peak memory "
              f"{r['maxrss_kib'] / 2**20:6.2f} GiB   ({r['n_samples']} samples used)", flush=True)
    if len(results) == 2:
        v, p = results["vibid"], results["pyoma"]
        print(f"ratio pyOMA2 / vibid: wall {p['wall'] / v['wall']:.1f}x, cpu {p['cpu'] / v['cpu']:.1f}x, "
              f"peak memory {p['maxrss_kib'] / v['maxrss_kib']:.1f}x")
    print(f"\n{'':4}{'truth':>20}  " + "  ".join(f"{results[w]['tool']:>36}" for w in results))
    print(f"{'mode':4}{'f Hz':>10}{'zeta %':>10}  "
          + "  ".join(f"{'f Hz (se)':>22}{'zeta % (se)':>14}" for _ in results))
    for j in range(len(f)):
        row = f"{j + 1:4d}{f[j]:10.4f}{100 * z[j]:10.3f}  "
        cells = []
        for w in results:
            r = results[w]
            q = nearest(f[j], r["f"])
            if q is None:
                cells.append(f"{'-':>22}{'-':>14}")
            else:
                cells.append(f"{r['f'][q]:10.4f} ({r['f_se'][q]:8.4f}){100 * r['zeta'][q]:7.3f} "
                             f"({100 * r['zeta_se'][q]:.3f})")
        print(row + "  ".join(cells))
    for w in results:
        r = results[w]
        extra = [x for x in r["f"] if all(abs(x / fj - 1.0) > 0.02 for fj in f)]
        found = sum(nearest(fj, r["f"]) is not None for fj in f)
        print(f"{r['tool']}: {len(r['f'])} modes reported, {found} of {len(f)} true modes within 2 %"
              + (f"; others at {', '.join(f'{x:.2f}' for x in extra)} Hz" if extra else ""))


if __name__ == "__main__":
    main()
