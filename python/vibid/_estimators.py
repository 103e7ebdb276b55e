"""The estimators themselves as classes (issue 13): batch and weighted least squares,
recursive least squares, instrumental variables (batch and recursive), and the
state-space estimators KF+RLS and EKF on a stand's physical model.

Thin classes over the C API (lsq.h, rls.h, iv.h, identify.h): every number is computed by
libvibid; this module converts arrays to float64, gives 1-D targets their second axis and
names wrong shapes. Shapes follow the library: a regressor block X is (n_rows, p), targets
Y (n_rows, q) (1-D (n_rows,) when q = 1), parameters theta (p, q). Units are the caller's:
theta_ij is in (unit of Y_j) / (unit of X_i).

What is copied (docs/python.md, "Estimator classes"): arrays of another dtype are converted
to float64 (a copy, by numpy). The batch calls (LeastSquares.add, IV.add) hand a
column-major (Fortran-order) block to the C library as it is; a block in any other layout,
numpy's default C order among them, is gathered once into a column-major copy. The
recursive calls (RLS.update, RecursiveIV.update) read each row through the array's strides
and copy nothing for C-order blocks. Every call into the library releases the GIL.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Optional

import numpy as np

from . import _core
from ._identify import _columns, _flags
from ._stand import Stand

VibidError = _core.VibidError


def _as_float(a: Any, name: str, where: str) -> np.ndarray:
    try:
        return np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise TypeError(f"{where}: {name} must be an array of numbers ({e})") from None


def _block(a: Any, name: str, cols: int, where: str, what: str) -> np.ndarray:
    """a as an (n, cols) float64 array; a 1-D array is taken as one column when cols == 1.
    The 1-D case is a view (no copy)."""
    arr = _as_float(a, name, where)
    if arr.ndim == 1 and cols == 1:
        return arr[:, None]
    if arr.ndim != 2:
        raise ValueError(f"{where}: {name} must be 2-D (n_rows, {cols}) ({what})"
                         + (" or 1-D (n_rows,)" if cols == 1 else "") + f", got shape {arr.shape}")
    return arr


def _weights(w: Any, where: str) -> Optional[np.ndarray]:
    if w is None:
        return None
    arr = _as_float(w, "weights", where)
    if arr.ndim != 1:
        raise ValueError(f"{where}: weights must be 1-D (n_rows,), got shape {arr.shape}")
    return arr


def _dims(p: Any, q: Any, where: str) -> tuple[int, int]:
    # p = 0 goes to the library, which refuses it with its own message; negative numbers
    # cannot reach a size_t, so they are named here.
    for name, v in (("p", p), ("q", q)):
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool):
            raise TypeError(f"{where}: {name} must be an int, got {type(v).__name__}")
        if v < 0:
            raise ValueError(f"{where}: {name} = {v}: the number of {'parameters' if name == 'p' else 'outputs'} "
                             "must be >= 1")
    return int(p), int(q)


class LeastSquares:
    """Batch least squares and weighted least squares, ``Y = X theta + E`` (lsq.h).

    ``LeastSquares(p, q=1, rank_tolerance=None)``: p parameters, q outputs sharing the
    regressor (p, q >= 1, p + q <= 4096). The library keeps the triangular factor R of the
    (weighted) ``[X Y]``, updated by Givens rotations, (p + q)^2 doubles whatever the number
    of rows; ``X^T X`` is never formed. ``rank_tolerance``: the relative singular-value
    threshold of the numerical rank (library default 1e-10).

    Methods: :meth:`add` (a block of rows, optional weights), :meth:`add_correlated`
    (Gauss-Markov: a block with full error covariance), :meth:`solve` -> theta (p, q),
    :meth:`covariance` (p, p), :meth:`residual_covariance` (q, q), :meth:`standard_errors`
    (p, q), :meth:`null_space`, :attr:`n_rows`, :meth:`info`, :meth:`reset`.
    A failed call raises :class:`vibid.VibidError` with the library's message and leaves
    the accumulator as it was; wrong shapes raise ValueError.
    """

    def __init__(self, p: int, q: int = 1, rank_tolerance: Optional[float] = None):
        p, q = _dims(p, q, "LeastSquares")
        self._c = _core.Lsq(p, q, None if rank_tolerance is None else float(rank_tolerance))

    @property
    def p(self) -> int:
        return self._c.p

    @property
    def q(self) -> int:
        return self._c.q

    def add(self, X: Any, Y: Any, weights: Any = None) -> None:
        """Adds the rows of X (n, p) and Y (n, q), or Y (n,) when q = 1, in one C call
        (``vibid_lsq_add_rows``). ``weights`` (n,): w >= 0 scales a row's squared residual,
        i.e. w = 1 / variance of that row's error. All-or-nothing: on a NaN/Inf (the message
        names the row and column) or a negative weight no row is added. An empty block adds
        nothing. No copy for Fortran-order X (and any 1-column or 1-D Y); C-order X is
        gathered once into a column-major copy."""
        w = "LeastSquares.add"
        self._c.add(_block(X, "X", self.p, w, "n_rows x p"), _block(Y, "Y", self.q, w, "n_rows x q"),
                    _weights(weights, w))

    def add_correlated(self, X: Any, Y: Any, Sigma: Any) -> None:
        """Gauss-Markov (paper 2.12): rows whose errors have the full covariance Sigma
        (n, n), whitened by its Cholesky factor in the library (``vibid_lsq_add_correlated``;
        allocates O(n^2))."""
        w = "LeastSquares.add_correlated"
        S = _as_float(Sigma, "Sigma", w)
        if S.ndim != 2:
            raise ValueError(f"{w}: Sigma must be 2-D (n_rows, n_rows), got shape {S.shape}")
        self._c.add_correlated(_block(X, "X", self.p, w, "n_rows x p"), _block(Y, "Y", self.q, w, "n_rows x q"), S)

    def solve(self) -> np.ndarray:
        """theta (p, q). VibidError before any row and when the regressor's numerical rank is
        below p (the message gives the rank; :meth:`null_space` the directions)."""
        return self._c.solve()

    def covariance(self) -> np.ndarray:
        """(X^T S X)^-1 (p, p), the unscaled parameter covariance (S the weights). The
        covariance of theta is Cov(theta_ij, theta_kl) = covariance()_ik *
        residual_covariance()_jl; for one output, covariance() * residual_covariance()[0, 0]."""
        return self._c.covariance()

    def residual_covariance(self) -> np.ndarray:
        """E^T S E / (n_rows - p) (q, q), the outputs' residual (co)variance. Needs n_rows > p."""
        return self._c.residual_covariance()

    def standard_errors(self) -> np.ndarray:
        """sqrt(covariance_ii * residual_covariance_jj) (p, q), in theta's units. Needs n_rows > p."""
        return self._c.stderr()

    def null_space(self) -> np.ndarray:
        """(p, p - rank): unit vectors in parameter space the data cannot resolve (empty
        second axis when theta is identifiable)."""
        return self._c.null_space()

    def info(self) -> dict:
        """``n_rows`` (rows with weight > 0), ``rank``, ``rcond`` (of the column-scaled
        regressor), ``sum_weights``: the library's solve summary (computed by a solve, O(p^3));
        before any row 0, 0, nan, 0."""
        n, rank, rcond, sw = self._c.info()
        return {"n_rows": n, "rank": rank, "rcond": rcond, "sum_weights": sw}

    @property
    def n_rows(self) -> int:
        """Rows accumulated with weight > 0 (from :meth:`info`)."""
        return self.info()["n_rows"]

    def reset(self) -> None:
        """Forgets every row."""
        self._c.reset()

    def __repr__(self) -> str:
        return f"<vibid.LeastSquares p={self.p} q={self.q}>"


_FORMS = {"bierman": _core.RLS_FORM_BIERMAN_UD, "covariance": _core.RLS_FORM_COVARIANCE}


def _forgetting(forgetting: Any, where: str) -> float:
    # The library checks the range (0, 1] and names it; only the type is checked here.
    try:
        return float(forgetting)
    except (TypeError, ValueError):
        raise TypeError(f"{where}: forgetting must be a number in (0, 1], got {forgetting!r}") from None


class RLS:
    """Recursive least squares (rls.h, paper 2.5-2.10): theta (p, q) updated sample by sample.

    ``RLS(p, q=1, forgetting=1.0, alpha=1e-6, form="bierman", n_equations=1,
    trace_max=None)``: ``P0 = I / alpha`` (a small alpha is a weak prior);
    ``forgetting`` gamma in (0, 1]; ``form`` ``"bierman"`` (U D U^T factorisation, the
    default, stays positive definite) or ``"covariance"`` (the plain update, for
    comparison); ``n_equations`` m scalar equations per sample sharing theta; ``trace_max``
    turns on the trace-bound anti-windup (trace(P) <= trace_max).

    :meth:`update` takes a block of samples and runs the library's per-sample update over
    it in one call with the GIL released. A block with a NaN or Inf anywhere is refused
    before its first sample (the message names the row, the library's the entry) and the
    estimator stays bit-identical; a numerical breakdown at row k (rls.h: refused, e.g.
    an overflow) leaves rows 0..k-1 applied, as the message says.

    State: :attr:`theta` (p, q), :attr:`covariance` P (p, p), :meth:`standard_errors`,
    :meth:`residual_covariance` (q, q, from the a-priori errors), :meth:`stats`
    (n_samples, n_eff, trace_p, min_d, last_forgetting), :meth:`predict`, :meth:`reset`,
    :meth:`set_prior`, :meth:`set_adaptation`, :meth:`set_equation_covariance`.
    """

    def __init__(self, p: int, q: int = 1, forgetting: float = 1.0, alpha: float = 1e-6, form: str = "bierman",
                 n_equations: int = 1, trace_max: Optional[float] = None):
        p, q = _dims(p, q, "RLS")
        if form not in _FORMS:
            raise ValueError(f"RLS: form {form!r}: one of {', '.join(_FORMS)}")
        if not isinstance(n_equations, (int, np.integer)) or n_equations < 0:
            raise ValueError(f"RLS: n_equations = {n_equations!r}: an int >= 1")
        self._c = _core.Rls(p, q, int(n_equations), _FORMS[form], _forgetting(forgetting, "RLS"), float(alpha),
                            trace_max is not None, None if trace_max is None else float(trace_max))

    p = property(lambda self: self._c.p, doc="number of parameters")
    q = property(lambda self: self._c.q, doc="number of outputs")
    m = property(lambda self: self._c.m, doc="scalar equations per sample")

    def _samples(self, A: Any, name: str, cols: int, where: str, n: Optional[int] = None) -> np.ndarray:
        """(n, m, cols) view of a block: (n, cols) (or (n,) when cols == 1) for m = 1, else
        (n, m, cols)."""
        arr = _as_float(A, name, where)
        if self.m == 1:
            if arr.ndim == 1 and cols == 1:
                arr = arr[:, None]
            if arr.ndim != 2:
                raise ValueError(f"{where}: {name} must be 2-D (n_rows, {cols})"
                                 + (" or 1-D (n_rows,)" if cols == 1 else "") + f", got shape {arr.shape}")
            return arr[:, None, :]
        if arr.ndim != 3:
            raise ValueError(f"{where}: {name} must be 3-D (n_samples, m={self.m}, {cols}), got shape {arr.shape}")
        return arr

    def update(self, X: Any, Y: Any) -> None:
        """One sample per row: X (n, p), Y (n, q) or (n,) when q = 1; with m > 1 equations
        per sample X (n, m, p) and Y (n, m, q). Equivalent to n single-row updates, bit for
        bit."""
        self._c.update(self._samples(X, "X", self.p, "RLS.update"), self._samples(Y, "Y", self.q, "RLS.update"))

    def predict(self, X: Any) -> np.ndarray:
        """x^T theta for each row: (n, q) for X (n, p), (n, m, q) for X (n, m, p)."""
        Xs = self._samples(X, "X", self.p, "RLS.predict")
        y = self._c.predict(Xs).reshape(Xs.shape[0], self.m, self.q)
        return y[:, 0, :] if self.m == 1 else y

    @property
    def theta(self) -> np.ndarray:
        """Current estimate (p, q)."""
        return self._c.theta()

    @property
    def covariance(self) -> np.ndarray:
        """P (p, p); the covariance of theta is P_ik * residual_covariance_jl."""
        return self._c.covariance()

    def residual_covariance(self) -> np.ndarray:
        """Sigma_e (q, q) from the a-priori errors; VibidError while n_eff <= p."""
        return self._c.residual_covariance()

    def standard_errors(self) -> np.ndarray:
        """sqrt(P_ii Sigma_e,jj) (p, q); VibidError while n_eff <= p."""
        return self._c.stderr()

    def stats(self) -> dict:
        """``n_samples`` (accepted updates), ``n_eff`` (sum of gamma^i), ``trace_p``,
        ``min_d`` (smallest D of U D U^T, or diagonal of P), ``last_forgetting``."""
        keys = ("n_samples", "n_eff", "trace_p", "min_d", "last_forgetting")
        return dict(zip(keys, self._c.stats()))

    @property
    def n_samples(self) -> int:
        return self.stats()["n_samples"]

    def reset(self) -> None:
        """Back to the start state (the prior of :meth:`set_prior`, else theta 0, P0 = I / alpha)."""
        self._c.reset()

    def set_prior(self, theta0: Any = None, P0: Any = None) -> None:
        """Start state and the state :meth:`reset` returns to: theta0 (p, q) (None: zeros),
        P0 (p, p) symmetric positive definite (None: I / alpha), e.g. from a
        :class:`LeastSquares` solve and its covariance()."""
        t = None if theta0 is None else _block(theta0, "theta0", self.q, "RLS.set_prior", "p x q")
        P = None if P0 is None else _as_float(P0, "P0", "RLS.set_prior")
        if P is not None and P.ndim != 2:
            raise ValueError(f"RLS.set_prior: P0 must be 2-D (p, p), got shape {P.shape}")
        self._c.set_prior(t, P)

    def set_adaptation(self, enabled: bool) -> None:
        """False freezes theta and P (updates then only track the residual statistics)."""
        self._c.set_adaptation(bool(enabled))

    def set_equation_covariance(self, Sigma: Any = None) -> None:
        """Covariance (m, m) of one sample's m equation errors (None: uncorrelated)."""
        S = None if Sigma is None else _as_float(Sigma, "Sigma", "RLS.set_equation_covariance")
        if S is not None and S.ndim != 2:
            raise ValueError(f"RLS.set_equation_covariance: Sigma must be 2-D (m, m), got shape {S.shape}")
        self._c.set_equation_covariance(S)

    def __repr__(self) -> str:
        return f"<vibid.RLS p={self.p} q={self.q} m={self.m} n_samples={self.n_samples}>"


class IV:
    """Batch instrumental variables (iv.h, paper 2.13-2.15): theta = (Z^T X)^-1 Z^T Y with
    instruments Z (n, p) correlated with the regressors X but not with the errors
    (consistent where least squares is biased by noise in X).

    ``IV(p, q=1)``. :meth:`add` (X, Z, Y, weights=None) a block in one C call (the same
    copies as :meth:`LeastSquares.add`), :meth:`solve` -> theta (p, q),
    :meth:`standard_errors` (asymptotic, sigma_j^2 (Z^T X)^-1 Z^T Z (X^T Z)^-1), :meth:`info`,
    :attr:`n_rows`, :meth:`reset`.
    """

    def __init__(self, p: int, q: int = 1):
        p, q = _dims(p, q, "IV")
        self._c = _core.Iv(p, q)

    p = property(lambda self: self._c.p, doc="number of parameters")
    q = property(lambda self: self._c.q, doc="number of outputs")

    def add(self, X: Any, Z: Any, Y: Any, weights: Any = None) -> None:
        """Rows of X (n, p), instruments Z (n, p), Y (n, q) or (n,); all-or-nothing."""
        w = "IV.add"
        self._c.add(_block(X, "X", self.p, w, "n_rows x p"), _block(Z, "Z", self.p, w, "n_rows x p"),
                    _block(Y, "Y", self.q, w, "n_rows x q"), _weights(weights, w))

    def solve(self) -> np.ndarray:
        """theta (p, q); VibidError when Z^T X is numerically singular."""
        return self._c.solve()

    def standard_errors(self) -> np.ndarray:
        """(p, q), from the asymptotic covariance; needs n_rows > p."""
        return self._c.stderr()

    def info(self) -> dict:
        """As :meth:`LeastSquares.info` (rank and rcond of the scaled Z^T X)."""
        n, rank, rcond, sw = self._c.info()
        return {"n_rows": n, "rank": rank, "rcond": rcond, "sum_weights": sw}

    @property
    def n_rows(self) -> int:
        return self.info()["n_rows"]

    def reset(self) -> None:
        self._c.reset()

    def __repr__(self) -> str:
        return f"<vibid.IV p={self.p} q={self.q}>"


class RecursiveIV:
    """Recursive instrumental variables (iv.h, ``vibid_riv``): the recursive form of
    (2.15), one equation per sample, covariance form (P = (Z^T X)^-1 is not symmetric).

    ``RecursiveIV(p, q=1, forgetting=1.0, alpha=1e-6, trace_max=None)``; :meth:`update`
    (X (n, p), Z (n, p), Y (n, q) or (n,)) with the same block semantics as
    :meth:`RLS.update`; :attr:`theta` (p, q), :attr:`covariance` P (p, p), :meth:`reset`,
    :meth:`set_prior`. The library gives no standard errors for it (use :class:`IV`).
    """

    def __init__(self, p: int, q: int = 1, forgetting: float = 1.0, alpha: float = 1e-6,
                 trace_max: Optional[float] = None):
        p, q = _dims(p, q, "RecursiveIV")
        self._c = _core.Riv(p, q, _forgetting(forgetting, "RecursiveIV"), float(alpha), trace_max is not None,
                            None if trace_max is None else float(trace_max))

    p = property(lambda self: self._c.p, doc="number of parameters")
    q = property(lambda self: self._c.q, doc="number of outputs")

    def update(self, X: Any, Z: Any, Y: Any) -> None:
        w = "RecursiveIV.update"
        self._c.update(_block(X, "X", self.p, w, "n_rows x p")[:, None, :],
                       _block(Z, "Z", self.p, w, "n_rows x p")[:, None, :],
                       _block(Y, "Y", self.q, w, "n_rows x q")[:, None, :])

    @property
    def theta(self) -> np.ndarray:
        return self._c.theta()

    @property
    def covariance(self) -> np.ndarray:
        return self._c.covariance()

    def reset(self) -> None:
        self._c.reset()

    def set_prior(self, theta0: Any = None, P0: Any = None) -> None:
        t = None if theta0 is None else _block(theta0, "theta0", self.q, "RecursiveIV.set_prior", "p x q")
        P = None if P0 is None else _as_float(P0, "P0", "RecursiveIV.set_prior")
        self._c.set_prior(t, P)

    def __repr__(self) -> str:
        return f"<vibid.RecursiveIV p={self.p} q={self.q}>"


class Estimate(NamedTuple):
    """theta (p,) and its standard errors se (p,), in the stand's parameter order and units."""
    theta: np.ndarray
    se: np.ndarray


class _StandFilter:
    """KF+RLS and EKF on a stand's physical model: ``vibid_ident`` (identify.h) with the
    estimator fixed, the same library path as ``vibid.identify(..., method=...)``."""

    _code = -1  # the vibid_estimator of the subclass

    def __init__(self, stand: Stand | str, forgetting: float = 1.0):
        self.stand = stand if isinstance(stand, Stand) else Stand.load(stand)
        name = type(self).__name__
        # prefilter_hz -1 and iv_lag 0: the automatic values identify passes (unused here).
        self._c = _core.Ident(self.stand._core, self._code, _forgetting(forgetting, name), -1.0, 0)
        self.n_samples = 0
        self.diverged_samples = 0
        self._last: Optional[dict] = None

    @property
    def parameters(self) -> list[str]:
        """Names of theta's entries (the stand's unknowns)."""
        return self.stand.parameters

    def push(self, data: Any) -> int:
        """A block of samples: a DataFrame or dict of 1-D arrays keyed by the stand's
        channels, or an (n, n_channels) array in ``stand.channels`` order (as ``identify``
        takes it; ValueError naming the channel for what does not fit). Pushed sample by
        sample in C with the GIL released, read through the array's strides. Returns the
        number of samples at which the filter diverged and restarted (it goes on)."""
        block, _ = _columns(self.stand, data)  # identify's channel checks, one place
        d = self._c.push(block, 0, block.shape[0])
        self.n_samples += block.shape[0]
        self.diverged_samples += d
        return d

    def estimate(self) -> Estimate:
        """(theta, se) of the unknowns now. VibidError with the library's message when there
        is none yet (too few samples)."""
        e = self._c.estimate()
        if e["status"] != 0:
            raise VibidError(f"vibid_ident_estimate after {self.n_samples} samples: {e['message']}")
        self._last = e
        return Estimate(e["theta"], e["se"])

    @property
    def covariance(self) -> np.ndarray:
        """Covariance (p, p) of the last :meth:`estimate`."""
        if self._last is None:
            raise VibidError(f"{type(self).__name__}.covariance: no estimate yet (call estimate() first)")
        return np.array(self._last["covariance"])

    @property
    def flags(self) -> str:
        """The daemon's letters of the last estimate (P, U, I), as ``Result.flags``."""
        if self._last is None:
            raise VibidError(f"{type(self).__name__}.flags: no estimate yet (call estimate() first)")
        return _flags(True, self._last["implausible"], self._last["quality"])

    def describe(self) -> str:
        """The library's account of the estimator and its settings (vibid_ident_describe)."""
        return self._c.describe()

    def __repr__(self) -> str:
        return f"<vibid.{type(self).__name__} stand {self.stand.name!r}, {self.n_samples} samples>"


class EKF(_StandFilter):
    """Extended Kalman filter on ``[y; y'; theta]`` with the stand's own masses, springs,
    dampers, cubic terms and gains as theta (identify.h, ``VIBID_ESTIMATOR_EKF``; README
    "Incompletely measured systems"). ``EKF(stand, forgetting=1.0)``: the stand (a
    :class:`vibid.Stand` or a path) gives the model, the channels and nominal start values
    for every unknown (refused otherwise, naming them). :meth:`push` blocks of samples,
    :meth:`estimate` -> (theta, se) in the stand's units. Equals
    ``vibid.identify(stand, data, method="ekf", track_every=0)`` on the same samples."""

    _code = _core.ESTIMATOR_EKF


class KFRLS(_StandFilter):
    """The paper's Kalman filter + recursive LS (3.16) on the stand's physical model
    (identify.h, ``VIBID_ESTIMATOR_KF_RLS``): a Kalman filter on ``[y; y']`` with the newest
    parameters and an RLS on the integrated equations of motion of the nodes with a sensor.
    Its standard errors are the regression's on filtered regressors (flagged ``U``).
    Same interface as :class:`EKF`; equals ``identify(..., method="kf_rls", track_every=0)``."""

    _code = _core.ESTIMATOR_KF_RLS
