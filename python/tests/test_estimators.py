"""The estimator classes (vibid.LeastSquares, RLS, IV, RecursiveIV, KFRLS, EKF) against
independent numpy computations and the truth. Every number they return is libvibid's; the
references here are numpy's (LAPACK's) solutions of the same problems."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

import vibid
from conftest import EX1_TRUTH, example1_capture

N, P, Q = 1000, 4, 2
NOISE = 1e-3


def rel(a, b):
    """Norm-wise relative difference of b from a."""
    return np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(b)


@pytest.fixture(scope="module")
def lsdata():
    """Random well-conditioned regressor (standard normal: cond(X) about 1.1 for 1000 x 4),
    known theta, small white noise on Y."""
    rng = np.random.default_rng(13)
    X = rng.standard_normal((N, P))
    theta = rng.uniform(-2, 2, (P, Q))
    Y = X @ theta + NOISE * rng.standard_normal((N, Q))
    return X, Y, theta


def numpy_ls_stderr(X, Y, w=None):
    """sqrt(sigma_j^2 (X^T W X)^-1_ii) with sigma_j^2 = sum w r_j^2 / (n - p): the textbook
    standard errors, computed in numpy."""
    w = np.ones(len(X)) if w is None else w
    sw = np.sqrt(w)[:, None]
    th = np.linalg.lstsq(sw * X, sw * Y, rcond=None)[0]
    r = Y - X @ th
    sigma2 = (w[:, None] * r * r).sum(axis=0) / (len(X) - X.shape[1])
    cov = np.linalg.inv(X.T @ (w[:, None] * X))
    return np.sqrt(np.outer(np.diag(cov), sigma2)), cov, sigma2


# ---------------------------------------------------------------- LeastSquares

def test_least_squares_equals_lstsq(lsdata):
    X, Y, theta = lsdata
    ls = vibid.LeastSquares(P, Q)
    ls.add(np.asfortranarray(X), Y)
    th = ls.solve()
    assert th.shape == (P, Q)
    ref = np.linalg.lstsq(X, Y, rcond=None)[0]
    # Householder QR (libvibid) and LAPACK's SVD-based lstsq are both backward stable solutions
    # of the same problem: each is the exact solution for data perturbed by ~eps, so they
    # differ by about eps * (cond(X) + cond(X)^2 |r| / (|X| |theta|)) ~ 1e-15 here
    # (cond 1.08, residual 1e-3 of Y; measured 1.1e-15, printed below). 1e-10 leaves five orders for the
    # accumulation over 1000 rows and still fails on any wrong row, column or output.
    assert rel(th, ref) < 1e-10, rel(th, ref)
    print(f"LeastSquares vs numpy.linalg.lstsq: {rel(th, ref):.2g} relative")  # the figure docs/python.md cites
    # and the truth: noise 1e-3 over 1000 rows gives errors of ~3e-5; within 5 se
    se = ls.standard_errors()
    assert (np.abs(th - theta) < 5 * se).all(), (th - theta) / se

    se_np, cov_np, sigma2 = numpy_ls_stderr(X, Y)
    # sigma^2 (X^T X)^-1 in numpy: X^T X squares the condition number (1.2) and the residual
    # sum of squares loses the digits of Y above the noise (1e3): ~1e-13 (measured 2.0e-13).
    # 1e-8 as asked.
    np.testing.assert_allclose(se, se_np, rtol=1e-8, atol=0)
    np.testing.assert_allclose(ls.covariance(), cov_np, rtol=1e-10, atol=0)
    np.testing.assert_allclose(np.diag(ls.residual_covariance()), sigma2, rtol=1e-8, atol=0)
    assert ls.n_rows == N
    info = ls.info()
    assert info["rank"] == P and info["sum_weights"] == N and 0.5 < info["rcond"] <= 1.0


def test_least_squares_layouts_give_the_same_bits(lsdata):
    # Fortran order goes to vibid_lsq_add_rows as it is; C order and a strided view are
    # gathered into a column-major copy first. The same doubles in the same order reach
    # the library: bit-identical results, or the gather has its strides wrong.
    X, Y, _ = lsdata
    results = []
    wide = np.zeros((N, 2 * P))
    wide[:, ::2] = X
    for Xa in (np.asfortranarray(X), np.ascontiguousarray(X), wide[:, ::2]):
        ls = vibid.LeastSquares(P, Q)
        ls.add(Xa, Y)
        results.append((ls.solve(), ls.standard_errors()))
    for th, se in results[1:]:
        np.testing.assert_array_equal(th, results[0][0])
        np.testing.assert_array_equal(se, results[0][1])
    # several blocks are the same rows: equal to rounding of the rotations' order (1e-13)
    ls = vibid.LeastSquares(P, Q)
    for k in range(0, N, 300):
        ls.add(X[k:k + 300], Y[k:k + 300])
    assert rel(ls.solve(), results[0][0]) < 1e-12


def test_weighted_least_squares_equals_scaled_lstsq(lsdata):
    X, Y, _ = lsdata
    rng = np.random.default_rng(5)
    w = rng.uniform(0.1, 10.0, N)
    w[:10] = 0.0  # weight 0: the row does not count
    ls = vibid.LeastSquares(P, Q)
    ls.add(X, Y, weights=w)
    sw = np.sqrt(w)[:, None]
    ref = np.linalg.lstsq(sw * X, sw * Y, rcond=None)[0]
    # the same problem as above with rows scaled by sqrt(w): cond(sqrt(W) X) about 1.3,
    # the same backward-stability argument, 1e-10
    assert rel(ls.solve(), ref) < 1e-10, rel(ls.solve(), ref)
    se_np, _, _ = numpy_ls_stderr(X, Y, w)
    # weighted residual variance sum w r^2 / (n - p), n counting every row (the library's
    # n_rows counts rows with w > 0: 990)
    info = ls.info()
    assert info["n_rows"] == N - 10
    np.testing.assert_allclose(info["sum_weights"], w.sum(), rtol=1e-14)
    se_np_990 = se_np * np.sqrt((N - P) / (N - 10 - P))
    np.testing.assert_allclose(ls.standard_errors(), se_np_990, rtol=1e-8, atol=0)


def test_least_squares_rank_deficiency_and_reset(lsdata):
    X, Y, _ = lsdata
    Xd = X.copy()
    Xd[:, 3] = 2.0 * Xd[:, 0] - Xd[:, 2]  # collinear: theta cannot be resolved
    ls = vibid.LeastSquares(P, Q)
    with pytest.raises(vibid.VibidError, match="vibid_lsq_solve: .*no rows with weight > 0"):
        ls.solve()
    assert ls.n_rows == 0
    ls.add(Xd, Y)
    with pytest.raises(vibid.VibidError, match=r"numerical rank 3 of 4 parameters"):
        ls.solve()
    ns = ls.null_space()
    v = np.array([2.0, 0.0, -1.0, -1.0]) / np.sqrt(6.0)  # Xd v = 0, largest component positive
    assert ns.shape == (P, 1)
    np.testing.assert_allclose(ns[:, 0], v, atol=1e-12)
    ls.reset()
    assert ls.n_rows == 0
    ls.add(X, Y)
    assert ls.null_space().shape == (P, 0)


def test_least_squares_nan_names_row_and_adds_nothing(lsdata):
    X, Y, _ = lsdata
    ls = vibid.LeastSquares(P, Q)
    ls.add(X[:500], Y[:500])
    before = ls.solve(), ls.covariance(), ls.residual_covariance()
    Xb = X[500:].copy()
    Xb[17, 2] = np.nan
    with pytest.raises(vibid.VibidError, match=r"vibid_lsq_add_rows: .*\(row 17, column 2\) = nan is not finite"):
        ls.add(Xb, Y[500:])
    with pytest.raises(vibid.VibidError, match=r"weights\[3\] = -1 is negative"):
        ls.add(X[500:510], Y[500:510], weights=[1, 1, 1, -1, 1, 1, 1, 1, 1, 1])
    after = ls.solve(), ls.covariance(), ls.residual_covariance()
    for a, b in zip(before, after):
        np.testing.assert_array_equal(a, b)
    assert ls.n_rows == 500


def test_gauss_markov_equals_whitened_lstsq():
    # add_correlated: rows with error covariance Sigma; the estimate is the LS on L^-1 X,
    # L^-1 Y (L the Cholesky factor), whitened here in numpy
    rng = np.random.default_rng(8)
    n = 50
    X = rng.standard_normal((n, 3))
    Y = X @ np.array([1.0, -2.0, 0.5]) + 0.01 * rng.standard_normal(n)
    A = rng.standard_normal((n, n))
    Sigma = A @ A.T / n + np.eye(n)
    ls = vibid.LeastSquares(3)
    ls.add_correlated(X, Y, Sigma)
    L = np.linalg.cholesky(Sigma)
    ref = np.linalg.lstsq(np.linalg.solve(L, X), np.linalg.solve(L, Y), rcond=None)[0]
    # cond(Sigma) about 5: the whitening costs a few digits at most; 1e-10 as above
    assert rel(ls.solve()[:, 0], ref) < 1e-10


# ---------------------------------------------------------------- RLS

def test_rls_with_tiny_prior_equals_batch(lsdata):
    X, Y, _ = lsdata
    alpha = 1e-8
    r = vibid.RLS(P, Q, forgetting=1.0, alpha=alpha)
    r.update(X, Y)
    ls = vibid.LeastSquares(P, Q)
    ls.add(X, Y)
    th_ls = ls.solve()
    # RLS from theta0 = 0, P0 = I / alpha is exactly LS with p extra rows sqrt(alpha) I and
    # target 0 (rls.h): theta_rls = (X^T X + alpha I)^-1 X^T Y. Against plain LS that moves
    # theta by alpha (X^T X + alpha I)^-1 theta_ls, at most alpha |theta| / lambda_min(X^T X)
    # (lambda_min 937 here: 1e-11 relative; measured 9.9e-12). The recursion's own rounding:
    # README, RLS equals batch with the prior rows to 1e-9 relative (measured here against
    # numpy's (X^T X + alpha I)^-1 X^T Y: 1.4e-15). So 1e-9 plus the prior's bound.
    lam_min = np.linalg.eigvalsh(X.T @ X)[0]
    tol = alpha / lam_min + 1e-9
    assert rel(r.theta, th_ls) < tol, (rel(r.theta, th_ls), tol)
    ridge = np.linalg.solve(X.T @ X + alpha * np.eye(P), X.T @ Y)
    assert rel(r.theta, ridge) < 1e-9
    # P = (X^T X + alpha I)^-1, the unscaled covariance: the same bounds
    np.testing.assert_allclose(r.covariance, np.linalg.inv(X.T @ X + alpha * np.eye(P)), rtol=1e-9)
    np.testing.assert_allclose(r.covariance, ls.covariance(), rtol=tol)
    # The residual statistics: with forgetting 1, V is exactly the batch residual sum of
    # squares with the prior rows (rls.h), Sigma_e = V / (N - p): the same 1e-9 (measured
    # 1e-12). Against plain LS the prior rows add alpha theta_j^2 to output j's sum, which
    # is N sigma^2 = 1e-3 here (measured 1.4e-8 / 1e-3 relative to the variance, half of
    # that to the standard errors): that ratio plus 1e-9 is the tolerance.
    res = Y - X @ ridge
    V = res.T @ res + alpha * ridge.T @ ridge
    np.testing.assert_allclose(r.residual_covariance(), V / (N - P), rtol=1e-9)
    rss = (res * res).sum(axis=0)
    tol_se = (alpha * (ridge * ridge).sum(axis=0) / rss).max() + 1e-9
    np.testing.assert_allclose(r.standard_errors(), ls.standard_errors(), rtol=tol_se)
    st = r.stats()
    assert st["n_samples"] == N and st["n_eff"] == N and st["last_forgetting"] == 1.0
    np.testing.assert_allclose(st["trace_p"], np.trace(r.covariance), rtol=1e-12)


def test_rls_block_equals_row_by_row(lsdata):
    X, Y, _ = lsdata
    block = vibid.RLS(P, Q, forgetting=0.995)
    block.update(X, Y)  # C order: each row read in place
    rows = vibid.RLS(P, Q, forgetting=0.995)
    for k in range(N):
        rows.update(X[k:k + 1], Y[k:k + 1])
    fort = vibid.RLS(P, Q, forgetting=0.995)
    fort.update(np.asfortranarray(X), np.asfortranarray(Y))  # strided rows gathered per sample
    # The same per-sample C call with the same doubles in the same order: bit for bit.
    for other in (rows, fort):
        np.testing.assert_array_equal(other.theta, block.theta)
        np.testing.assert_array_equal(other.covariance, block.covariance)
        np.testing.assert_array_equal(other.standard_errors(), block.standard_errors())
        assert other.stats() == block.stats()
    # predict is x^T theta, in the library: equal to numpy's product to rounding
    np.testing.assert_allclose(block.predict(X[:5]), X[:5] @ block.theta, rtol=1e-13, atol=1e-15)


def test_rls_one_output_and_several_equations():
    rng = np.random.default_rng(3)
    n = 400
    X = rng.standard_normal((n, 2))
    y = X @ np.array([3.0, -1.0])
    r = vibid.RLS(2)  # q = 1: Y may be 1-D
    r.update(X, y)
    assert r.theta.shape == (2, 1)
    # noise-free: the prior alpha = 1e-6 moves theta by at most alpha |theta| / lambda_min
    # (lambda_min about 350): 1e-8 relative
    assert rel(r.theta[:, 0], np.array([3.0, -1.0])) < 1e-8
    # m = 2 equations per sample sharing theta equal 2 samples of 1 equation each: the
    # per-equation updates are the same arithmetic, so 1e-13
    m2 = vibid.RLS(2, n_equations=2)
    m2.update(X.reshape(n // 2, 2, 2), y.reshape(n // 2, 2, 1))
    assert m2.stats()["n_samples"] == n // 2
    assert rel(m2.theta, r.theta) < 1e-13


def test_rls_nan_row_raises_and_leaves_state(lsdata):
    X, Y, _ = lsdata
    r = vibid.RLS(P, Q, forgetting=0.999)
    r.update(X[:500], Y[:500])
    before = (r.theta, r.covariance, r.residual_covariance(), r.stats())
    for bad_y in (False, True):
        Xb, Yb = X[500:].copy(), Y[500:].copy()
        if bad_y:
            Yb[17, 1] = np.inf
        else:
            Xb[17, 2] = np.nan
        pat = r"y\[1\] = inf" if bad_y else r"x\[2\] = nan"
        # the row in the block, the library's message for the entry, and that nothing was applied
        with pytest.raises(vibid.VibidError,
                           match=r"vibid_rls_update \(row 17; the block was refused before its first row, "
                                 r"the estimator is unchanged\): NaN or Inf in input data: vibid_rls_update: " + pat):
            r.update(Xb, Yb)
    after = (r.theta, r.covariance, r.residual_covariance(), r.stats())
    for a, b in zip(before[:3], after[:3]):
        np.testing.assert_array_equal(a, b)  # bit-identical, not merely close
    assert before[3] == after[3]
    # and it goes on from there exactly as one that never saw the bad blocks
    ref = vibid.RLS(P, Q, forgetting=0.999)
    ref.update(X[:500], Y[:500])
    r.update(X[500:], Y[500:])
    ref.update(X[500:], Y[500:])
    np.testing.assert_array_equal(r.theta, ref.theta)


def test_rls_prior_reset_and_frozen_adaptation(lsdata):
    X, Y, _ = lsdata
    ls = vibid.LeastSquares(P, Q)
    ls.add(X[:500], Y[:500])
    r = vibid.RLS(P, Q)
    r.set_prior(ls.solve(), ls.covariance())
    np.testing.assert_array_equal(r.theta, ls.solve())
    # Starting from the batch estimate of the first 500 rows with its (X^T X)^-1 as P0 and
    # going on over the rest is LS over all rows (rls.h: P0 from vibid_lsq_covariance); the
    # two orders of rounding agree to 1e-9 (README's RLS/batch figure).
    r.update(X[500:], Y[500:])
    full = vibid.LeastSquares(P, Q)
    full.add(X, Y)
    assert rel(r.theta, full.solve()) < 1e-9
    r.reset()  # back to the prior, not to zeros
    np.testing.assert_array_equal(r.theta, ls.solve())
    r.set_adaptation(False)
    r.update(X[500:], Y[500:])
    np.testing.assert_array_equal(r.theta, ls.solve())  # frozen
    assert r.n_samples == N - 500


# ---------------------------------------------------------------- IV

def ar1(rng, n, a, cols):
    """Smooth signals: AR(1) x_k = a x_{k-1} + sqrt(1 - a^2) e_k, unit variance."""
    x = np.zeros((n, cols))
    e = rng.standard_normal((n, cols)) * np.sqrt(1 - a * a)
    for k in range(1, n):
        x[k] = a * x[k - 1] + e[k]
    return x


def test_iv_consistent_where_ls_is_biased():
    # Errors in variables: Y depends on the true regressors, X measures them with white
    # noise of std 0.5 (variance 0.25 against 1). LS is attenuated by 1 / (1 + 0.25): 20 %
    # low. Instruments: the measured regressors one sample earlier, correlated with the true
    # ones (AR(1), a = 0.95) and not with the noise of this sample (white) nor with e.
    rng = np.random.default_rng(21)
    n = 20000
    truth = np.array([[1.5], [-0.8]])
    S = ar1(rng, n + 1, 0.95, 2)
    Xm = S + 0.5 * rng.standard_normal(S.shape)
    Yall = S @ truth + 0.1 * rng.standard_normal((n + 1, 1))
    X, Z, Y = Xm[1:], Xm[:-1], Yall[1:]
    iv = vibid.IV(2)
    iv.add(X, Z, Y)
    th = iv.solve()
    ref = np.linalg.solve(Z.T @ X, Z.T @ Y)
    # (Z^T X)^-1 Z^T Y formed in numpy from the same cross products (cond(Z^T X) about 1.1
    # here): 1e-10 relative as asked, measured 9.7e-15. The truth within 4 se (measured
    # z 0.12 and 2.0).
    assert rel(th, ref) < 1e-10, rel(th, ref)
    se = iv.standard_errors()
    assert (np.abs(th - truth) < 4 * se).all(), (th - truth) / se
    ls = vibid.LeastSquares(2)
    ls.add(X, Y)
    th_ls = ls.solve()
    # LS: attenuated by 0.8 (expected bias -0.3 and +0.16; measured -0.304 and +0.162, 63
    # and 34 of its standard errors)
    bias = th_ls - truth
    assert (np.abs(bias) > 0.1 * np.abs(truth)).all(), bias
    assert (np.abs(bias) > 20 * ls.standard_errors()).all()
    # the asymptotic IV standard errors, in numpy: sigma^2 diag((Z^T X)^-1 Z^T Z (X^T Z)^-1),
    # sigma^2 the residual variance at the IV estimate over n - p
    r = Y - X @ ref
    sigma2 = float((r * r).sum()) / (n - 2)
    A = np.linalg.inv(Z.T @ X)
    cov = sigma2 * A @ (Z.T @ Z) @ A.T
    np.testing.assert_allclose(se[:, 0], np.sqrt(np.diag(cov)), rtol=1e-8)
    assert iv.n_rows == n and iv.info()["rank"] == 2

    # recursive IV from P0 = I / alpha: (Z^T X + alpha I)^-1 Z^T Y, i.e. the batch estimate
    # moved by alpha |(Z^T X)^-1| (1e-10 / 9000, nothing); the recursion's rounding, README:
    # recursive IV equals batch IV to 1.7e-9 relative. 1e-8 (measured 4.3e-13; P against
    # numpy's (Z^T X)^-1 2.6e-10).
    riv = vibid.RecursiveIV(2, alpha=1e-10)
    riv.update(X, Z, Y[:, 0])
    assert rel(riv.theta, th) < 1e-8, rel(riv.theta, th)
    np.testing.assert_allclose(riv.covariance, np.linalg.inv(Z.T @ X), rtol=1e-8)
    # block equals rows, and a NaN block is refused whole
    riv2 = vibid.RecursiveIV(2, alpha=1e-10)
    for k in range(0, n, 7000):
        riv2.update(X[k:k + 7000], Z[k:k + 7000], Y[k:k + 7000])
    np.testing.assert_array_equal(riv2.theta, riv.theta)
    Zb = Z[:10].copy()
    Zb[4, 1] = np.nan
    before = riv.theta, riv.covariance
    with pytest.raises(vibid.VibidError, match=r"vibid_riv_update \(row 4; .*unchanged\): .*w\[1\] = nan"):
        riv.update(X[:10], Zb, Y[:10])
    np.testing.assert_array_equal(riv.theta, before[0])
    np.testing.assert_array_equal(riv.covariance, before[1])


# ---------------------------------------------------------------- KF+RLS and EKF

EX1_WITH_START = {
    # examples/stands/paper_example1.cfg with start values 17-20 % off: the state-space
    # estimators start from the stand's nominal values and refuse a stand without them
    "name": "paper_example1_start", "sample_rate": 2000.0, "discretization": "central_difference",
    "nodes": [{"name": "m1", "mass": 10.0, "measure": {"displacement": "x1"}},
              {"name": "m2", "mass": 20.0, "measure": {"displacement": "x2"}}],
    "base": {"measure": {"displacement": "s"}},
    "elements": [
        {"name": "c1", "kind": "spring", "between": ["m1", "m2"], "unknown": True, "value": 2.0e5,
         "true_value": 2.5e5},
        {"name": "d", "kind": "damper", "between": ["m1", "m2"], "unknown": True, "value": 250.0,
         "true_value": 300.0},
        {"name": "c2", "kind": "spring", "between": ["m2", "base"], "unknown": True, "value": 1.2e6,
         "true_value": 1.5e6},
    ],
}


@pytest.mark.parametrize("cls,method,tol", [
    # KF+RLS: test_state_space.py's 2 % (README: weaker than the EKF). Measured here
    # -0.02 %, -0.002 %, +0.21 %.
    (vibid.KFRLS, "kf_rls", 2e-2),
    # EKF: test_state_space.py allows a quarter of the inputs' bend within a sample, (w h)^2
    # / 8 (0.2 % for 0.8 %): the filter takes them linear between samples. Example 1's base
    # multisine reaches 160 Hz at 2 kHz, (w h)^2 / 8 = 3.2 %, so 0.8 %. Measured -0.10 %,
    # +0.08 %, +0.22 %.
    (vibid.EKF, "ekf", 8e-3),
])
def test_state_space_on_example1(ex1_clean, cls, method, tol):
    data, _ = ex1_clean  # noise-free, conftest
    stand = vibid.Stand.from_dict(EX1_WITH_START)
    est = cls(stand)
    assert est.push(data) == 0  # no divergence
    theta, se = est.estimate()
    truth = np.array([EX1_TRUTH[p] for p in est.parameters])
    err = theta / truth - 1
    assert (np.abs(err) < tol).all(), err
    assert (se > 0).all()
    # the same library path as identify: equal, not close
    r = vibid.identify(stand, data, method=method, track_every=0)
    np.testing.assert_array_equal(theta, r.parameters["value"].to_numpy())
    np.testing.assert_array_equal(se, r.parameters["se"].to_numpy())
    np.testing.assert_array_equal(est.covariance, r.covariance)
    assert est.flags == r.flags
    if method == "kf_rls":
        assert "U" in est.flags  # the regression's errors on filtered regressors (README)
    # blocks: the filter runs sample by sample, so four pushes are the same samples; an
    # estimate before the 1000th sample is provisional and starts nothing (identify.h)
    chunked = cls(stand)
    n = len(data["x1"])
    for k in range(0, n, 5000):
        chunked.push({c: v[k:k + 5000] for c, v in data.items()})
        chunked.estimate()
    np.testing.assert_array_equal(chunked.estimate().theta, theta)
    assert chunked.n_samples == n


def test_state_space_on_partially_measured_stand():
    # test_state_space.py's stand (m2 without sensor) and capture, with its tolerances:
    # EKF 0.2 %, KF+RLS 2 %; equal to identify's results
    from test_state_space import C1, STAND, capture

    st = vibid.Stand.from_dict(STAND)
    data = capture()
    for cls, method, tol in ((vibid.EKF, "ekf", 2e-3), (vibid.KFRLS, "kf_rls", 2e-2)):
        est = cls(st)
        est.push(np.column_stack([data[c] for c in st.channels]))  # a C-order 2-D array
        theta, se = est.estimate()
        assert abs(theta[0] / C1 - 1) < tol, (method, theta[0] / C1 - 1)
        r = vibid.identify(st, data, method=method, track_every=0)
        assert theta[0] == r.parameters.loc["c1", "value"] and se[0] == r.parameters.loc["c1", "se"]


def test_state_space_errors(ex1_clean, example1_stand):
    with pytest.raises(vibid.VibidError, match=r"vibid_ident_create: .*have none: 'c1', 'd', 'c2'"):
        vibid.EKF(example1_stand)  # no start values in the file
    stand = vibid.Stand.from_dict(EX1_WITH_START)
    with pytest.raises(vibid.VibidError, match=r"forgetting = 1\.5 outside \(0, 1\]"):
        vibid.KFRLS(stand, forgetting=1.5)
    est = vibid.EKF(stand)
    with pytest.raises(ValueError, match="channel 's' missing"):
        est.push({"x1": np.zeros(10), "x2": np.zeros(10)})
    with pytest.raises(vibid.VibidError, match="no estimate yet"):
        est.covariance
    with pytest.raises(vibid.VibidError, match="vibid_ident_estimate after 0 samples"):
        est.estimate()


# ---------------------------------------------------------------- argument errors

def test_bad_arguments_raise_clear_exceptions():
    for make, pat in ((lambda: vibid.LeastSquares(0), r"vibid_lsq_create: n_params = 0, need at least 1"),
                      (lambda: vibid.LeastSquares(2, 0), r"vibid_lsq_create: n_outputs = 0"),
                      (lambda: vibid.RLS(0), r"vibid_rls_create: n_params = 0 outside 1\.\.1024"),
                      (lambda: vibid.IV(0), r"vibid_iv_create: n_params = 0"),
                      (lambda: vibid.RecursiveIV(0), r"vibid_riv_create: n_params = 0"),
                      (lambda: vibid.RLS(2, forgetting=0.0), r"vibid_rls_create: forgetting = 0 outside \(0, 1\]"),
                      (lambda: vibid.RLS(2, forgetting=1.01), r"forgetting = 1\.01 outside \(0, 1\]"),
                      (lambda: vibid.RecursiveIV(2, forgetting=-1), r"vibid_riv_create: forgetting = -1 outside"),
                      (lambda: vibid.RLS(2, alpha=0.0), r"vibid_rls_create: alpha = 0"),
                      (lambda: vibid.LeastSquares(2, rank_tolerance=2.0), r"tol = 2 outside \(0, 1\)")):
        with pytest.raises(vibid.VibidError, match=pat):
            make()
    with pytest.raises(ValueError, match=r"LeastSquares: p = -1"):
        vibid.LeastSquares(-1)
    with pytest.raises(ValueError, match=r"RLS: form 'ud'"):
        vibid.RLS(2, form="ud")

    ls = vibid.LeastSquares(3, 2)
    with pytest.raises(ValueError, match=r"LeastSquares.add: X has shape \(5, 2\), needs \(5, 3\)"):
        ls.add(np.zeros((5, 2)), np.zeros((5, 2)))
    with pytest.raises(ValueError, match=r"Y has shape \(4, 2\), needs \(5, 2\)"):
        ls.add(np.zeros((5, 3)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"Y must be 2-D \(n_rows, 2\)"):
        ls.add(np.zeros((5, 3)), np.zeros(5))  # 1-D only when q = 1
    with pytest.raises(ValueError, match=r"weights has 4 entries for 5 rows"):
        ls.add(np.zeros((5, 3)), np.zeros((5, 2)), weights=np.ones(4))
    with pytest.raises(ValueError, match=r"X must be 2-D"):
        ls.add(np.zeros((5, 3, 1)), np.zeros((5, 2)))
    assert ls.n_rows == 0  # nothing reached the library

    r = vibid.RLS(3)
    with pytest.raises(ValueError, match=r"RLS.update: X has 2 regressors in 1 equations per row, needs p = 3"):
        r.update(np.zeros((5, 2)), np.zeros(5))
    with pytest.raises(ValueError, match=r"RLS.update: Y has 4 rows"):
        r.update(np.zeros((5, 3)), np.zeros(4))
    with pytest.raises(vibid.VibidError, match=r"vibid_rls_residual_covariance: .*"):
        r.residual_covariance()  # no samples yet
    assert r.n_samples == 0
    with pytest.raises(ValueError, match=r"IV.add: Z has shape \(5, 2\), needs \(5, 3\)"):
        vibid.IV(3).add(np.zeros((5, 3)), np.zeros((5, 2)), np.zeros(5))


# ---------------------------------------------------------------- the GIL

def test_block_calls_release_the_gil():
    # As test_gil.py: while one thread runs a long block call, the main thread keeps
    # timestamping; with the GIL held none of its iterations could fall inside the call.
    rng = np.random.default_rng(0)
    X = rng.standard_normal((300_000, 8))
    Y = X @ rng.standard_normal((8, 2))
    r = vibid.RLS(8, 2)
    span = {}

    def work():
        span["t0"] = time.perf_counter()
        r.update(X, Y)
        span["t1"] = time.perf_counter()

    th = threading.Thread(target=work)
    stamps = []
    th.start()
    while th.is_alive():
        stamps.append(time.perf_counter())
    th.join()
    t0, t1 = span["t0"], span["t1"]
    margin = 0.2 * (t1 - t0)
    inside = sum(1 for s in stamps if t0 + margin < s < t1 - margin)
    assert t1 - t0 > 0.02, "too short a call to tell"
    assert inside > 100, (inside, t1 - t0)
    assert r.n_samples == 300_000
