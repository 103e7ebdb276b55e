"""Ambient captures for the OMA tests: a chain of masses (ground - m1 - m2 - ...) under
unmeasured white forces on every mass, held over each sample (exact discretisation), the
displacements measured with sensor noise. The truth: the continuous model's modes."""

import numpy as np


def chain_matrices(m, k, d):
    n = len(m)
    M = np.diag(m)
    K = np.zeros((n, n))
    D = np.zeros((n, n))
    for j in range(n):  # element j joins node j - 1 (ground for j = 0) and node j
        for X, v in ((K, k[j]), (D, d[j])):
            X[j, j] += v
            if j > 0:
                X[j - 1, j - 1] += v
                X[j - 1, j] -= v
                X[j, j - 1] -= v
    return M, D, K


def modes(M, D, K):
    """(f [Hz], zeta) of the continuous model, ascending in frequency."""
    n = M.shape[0]
    Mi = np.linalg.inv(M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Mi @ K, -Mi @ D]])
    lam = np.linalg.eigvals(A)
    lam = lam[lam.imag > 0]
    f = np.abs(lam) / (2 * np.pi)
    z = -lam.real / np.abs(lam)
    o = np.argsort(f)
    return f[o], z[o]


def ambient(M, D, K, fs, n, noise=0.01, seed=0):
    """n samples (n x dof) of the displacements, sensor noise `noise` of each channel's RMS."""
    return ambient_segments(M, D, [(K, n)], fs, noise=noise, seed=seed)


def ambient_segments(M, D, segments, fs, noise=0.01, seed=0):
    """The displacements (sum of n x dof) of a chain whose stiffness matrix is K_i for the
    n_i samples of segment i (segments = [(K_1, n_1), ...]; a step change at each boundary,
    the state continuous across it), sensor noise `noise` of each channel's RMS."""
    rng = np.random.default_rng(seed)
    dof = M.shape[0]
    Mi = np.linalg.inv(M)
    B = np.vstack([np.zeros((dof, dof)), Mi])
    h = 1.0 / fs
    x = np.zeros(2 * dof)
    parts = []
    for i, (K, n) in enumerate(segments):
        A = np.block([[np.zeros((dof, dof)), np.eye(dof)], [-Mi @ K, -Mi @ D]])
        # exact ZOH through the eigen-decomposition (A is diagonalisable: distinct damped modes)
        w, V = np.linalg.eig(A)
        Vi = np.linalg.inv(V)
        G = (V @ np.diag(np.exp(w * h)) @ Vi).real
        Gam = (V @ np.diag((np.exp(w * h) - 1) / w) @ Vi @ B).real
        settle = 2000 if i == 0 else 0  # the first segment starts from rest: let it settle
        out = np.empty((n, dof))
        f = rng.standard_normal((n + settle, dof))
        for t in range(n + settle):
            x = G @ x + Gam @ f[t]
            if t >= settle:
                out[t - settle] = x[:dof]
        parts.append(out)
    out = np.vstack(parts)
    out += noise * out.std(axis=0) * rng.standard_normal(out.shape)
    return out


def chain_stand(name, m, k, d, fs, coloured=(), duration=600.0, seed=1, snr_db=40.0):
    """A stand file (with its simulation group) of the chain: accelerometers a1..an on every
    mass, a disturbance w1..wn on every mass (white, 1 N), those in `coloured` (1-based
    node numbers) driven instead by band-limited noise (2 N, 1..0.4 fs Hz), sensor noise
    snr_db on every channel. The simulation is vibid-sim's exact discretisation."""
    n = len(m)
    lines = [f'stand = {{ name = "{name}"; sample_rate = {fs!r};',
             "  nodes = ( " + ",\n            ".join(
                 f'{{ name = "m{j + 1}"; mass = {m[j]!r}; measure = {{ acceleration = "a{j + 1}"; }}; }}'
                 for j in range(n)) + " );"]
    els = []
    for j in range(n):
        a = "ground" if j == 0 else f"m{j}"
        els.append(f'{{ name = "k{j + 1}"; kind = "spring"; between = ["{a}", "m{j + 1}"]; value = {k[j]!r}; }}')
        els.append(f'{{ name = "d{j + 1}"; kind = "damper"; between = ["{a}", "m{j + 1}"]; value = {d[j]!r}; }}')
    lines.append("  elements = ( " + ",\n               ".join(els) + " );")
    lines.append("  disturbances = ( " + ",\n                   ".join(
        f'{{ name = "w{j + 1}"; node = "m{j + 1}"; std = 1.0; }}' for j in range(n)) + " ); };")
    exc = ",\n    ".join(f'{{ target = "w{j}"; kind = "noise"; amplitude = 2.0; f_low = 1.0; f_high = {0.4 * fs!r}; }}'
                         for j in coloured)
    noise = ",\n    ".join(f'{{ channel = "a{j + 1}"; snr_db = {snr_db!r}; }}' for j in range(n))
    lines.append(f"simulation = {{ seed = {seed}; duration = {duration!r};")
    if coloured:
        lines.append(f"  excitation = (\n    {exc}\n  );")
    lines.append(f"  noise = (\n    {noise}\n  );\n}};")
    return "\n".join(lines) + "\n"


# The shipped ambient examples (examples/oma/*.cfg, written by `python oma_sim.py`): chains
# of 5 and 10 masses, coloured disturbances on every other mass.
EXAMPLES = {
    "chain5": dict(m=[1.0, 1.2, 0.8, 1.0, 0.6], k=[2.0e4, 1.6e4, 1.4e4, 1.2e4, 8.0e3],
                   d=[6.0, 5.0, 4.0, 3.0, 2.0], fs=200.0, coloured=(1, 3, 5)),
    "chain10": dict(m=[1.0] * 10, k=[4.0e4] * 10, d=[4.0] * 10, fs=400.0, coloured=(2, 4, 6, 8, 10)),
}


if __name__ == "__main__":  # writes examples/oma/
    import pathlib

    out = pathlib.Path(__file__).resolve().parents[2] / "examples" / "oma"
    out.mkdir(exist_ok=True)
    for name, p in EXAMPLES.items():
        M, D, K = chain_matrices(p["m"], p["k"], p["d"])
        f, z = modes(M, D, K)
        head = (f"# {name}: an ambient capture for output-only modal analysis (vibid.oma, docs/python.md):\n"
                f"# {len(p['m'])} masses in a chain, an accelerometer on each, unmeasured forces on every mass (white,\n"
                f"# 1 N; band-limited noise 1..{0.4 * p['fs']:g} Hz, 2 N, on masses {', '.join(map(str, p['coloured']))}).\n"
                f"#   vibid-sim -c examples/oma/{name}.cfg --csv {name}.csv\n"
                f"# Written by python/tests/oma_sim.py. The modes (continuous model):\n"
                + "".join(f"#   {j + 1}: {fj:.6f} Hz, zeta {zj:.6f}\n" for j, (fj, zj) in enumerate(zip(f, z))))
        (out / f"{name}.cfg").write_text(head + chain_stand(name, p["m"], p["k"], p["d"], p["fs"], p["coloured"]))
        print(out / f"{name}.cfg")
