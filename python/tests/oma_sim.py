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
    rng = np.random.default_rng(seed)
    dof = M.shape[0]
    Mi = np.linalg.inv(M)
    A = np.block([[np.zeros((dof, dof)), np.eye(dof)], [-Mi @ K, -Mi @ D]])
    B = np.vstack([np.zeros((dof, dof)), Mi])
    h = 1.0 / fs
    # exact ZOH through the eigen-decomposition (A is diagonalisable: distinct damped modes)
    w, V = np.linalg.eig(A)
    Vi = np.linalg.inv(V)
    G = (V @ np.diag(np.exp(w * h)) @ Vi).real
    Gam = (V @ np.diag((np.exp(w * h) - 1) / w) @ Vi @ B).real
    x = np.zeros(2 * dof)
    out = np.empty((n, dof))
    f = rng.standard_normal((n + 2000, dof))
    for t in range(n + 2000):
        x = G @ x + Gam @ f[t]
        if t >= 2000:
            out[t - 2000] = x[:dof]
    out += noise * out.std(axis=0) * rng.standard_normal(out.shape)
    return out
