"""The geometric median of points in R^k: Weiszfeld's iteration made safe at the data points (Vardi-Zhang).

The geometric median of points ``x_i`` with weights ``w_i > 0`` minimises ``f(y) = sum_i w_i |x_i - y|``
(Euclidean norm; for flattened matrices the Frobenius norm). Weiszfeld's step is

    T(y) = sum_i (w_i / |x_i - y|) x_i  /  sum_i (w_i / |x_i - y|),

which divides by zero when ``y`` lands on a data point. Vardi and Zhang (2000, PNAS 97(4):1423-1426)
make it safe: when ``y`` coincides with data points of total weight ``eta``, let
``R(y) = sum_{x_i != y} w_i (x_i - y) / |x_i - y|`` (the pull of the other points), ``r = |R(y)|`` and

    y+ = (1 - eta / r) T(y) + min(1, eta / r) y,

with ``T`` over the other points only; when ``r <= eta`` the point ``y`` is itself the median and the
iteration stops there. The iteration decreases ``f`` monotonically and converges to the median.

Nothing here knows about vehicles; :mod:`toosicubix.prior_estimation` uses it for the size priors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Points closer than this fraction of the data's scale to the iterate count as coinciding with it.
COINCIDENCE_RTOL = 1e-12


@dataclass(frozen=True)
class GeometricMedianOptions:
    """Stopping rule of :func:`geometric_median`.

    Attributes
    ----------
    rtol : stop when a step is shorter than ``rtol`` times the data's scale (the weighted mean distance
        of the points from the starting point). Default 1e-12, well above round-off for data whose offset
        from the origin is up to 1e3 times its scale.
    max_iterations : give up (``converged=False``) after this many steps. Default 10,000; Weiszfeld
        converges linearly, slowly only when the median is near a data point, which is tested directly.
    """

    rtol: float = 1e-12
    max_iterations: int = 10_000


@dataclass(frozen=True)
class GeometricMedianResult:
    """What :func:`geometric_median` found.

    Attributes
    ----------
    median : (k,) the minimiser of ``sum_i w_i |x_i - y|``
    objective : ``sum_i w_i |x_i - median|``, in the points' unit
    iterations : steps taken (0 when the start was already optimal, e.g. one point)
    converged : False when ``max_iterations`` ran out before the stopping rule held
    at_data_point : True when the median is a data point, found by the optimality test ``r <= eta``
    """

    median: np.ndarray
    objective: float
    iterations: int
    converged: bool
    at_data_point: bool


def check_points(points: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Cast points to float64 (n, k) and weights to float64 (n,), ones when None.

    Raises
    ------
    ValueError
        Points not a non-empty 2D array, non-finite values, weights of the wrong shape, negative, or
        all zero.
    """
    X = np.asarray(points, dtype=np.float64)
    if X.ndim != 2 or X.shape[0] == 0 or X.shape[1] == 0:
        raise ValueError(f"expected points of shape (n, k) with n, k >= 1, got shape {X.shape}")
    if not np.all(np.isfinite(X)):
        raise ValueError("expected finite points, got NaN or infinity")
    if weights is None:
        return X, np.ones(X.shape[0])
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (X.shape[0],):
        raise ValueError(f"expected weights of shape ({X.shape[0]},), got {w.shape}")
    if not np.all(np.isfinite(w)) or np.any(w < 0.0) or not np.any(w > 0.0):
        raise ValueError("expected finite, non-negative weights, not all zero")
    return X, w


def distance_sum(points: np.ndarray, y: np.ndarray, weights: np.ndarray | None = None) -> float:
    """The objective ``sum_i w_i |x_i - y|`` for points (n, k), y (k,) and weights (n,) (ones when None)."""
    X, w = check_points(points, weights)
    return float(w @ np.linalg.norm(X - np.asarray(y, dtype=np.float64), axis=1))


def geometric_median(points: np.ndarray, weights: np.ndarray | None = None, x0: np.ndarray | None = None,
                     options: GeometricMedianOptions | None = None) -> GeometricMedianResult:
    """The (weighted) geometric median of points in R^k by Weiszfeld's iteration with Vardi-Zhang's step.

    Parameters
    ----------
    points : (n, k) the points ``x_i``; for matrices, their flattened entries (Frobenius norm)
    weights : (n,) multiplicities ``w_i >= 0`` (ones when None); a weight of 2 is the same as the point twice
    x0 : (k,) starting point; the weighted mean when None
    options : stopping rule; :class:`GeometricMedianOptions` defaults when None

    Returns
    -------
    GeometricMedianResult
        With one point, that point. With collinear points of equal total weight on both sides of a
        segment every point of that segment is a median; the one returned depends on ``x0``.

    Raises
    ------
    ValueError
        Malformed points or weights (see :func:`check_points`), or ``x0`` of the wrong shape.

    Notes
    -----
    Coincidence with a data point means a distance below ``COINCIDENCE_RTOL`` times the data's scale.
    When the iterate comes within one step of a data point ``x_j``, the optimality condition
    ``|R(x_j)| < w_j`` (with ``w_j`` the weight of all points at ``x_j``) is tested and, when it holds,
    ``x_j`` is returned: Weiszfeld's iterates approach such a median only linearly, at a rate
    ``|R(x_j)| / w_j`` that can be close to 1.

    Examples
    --------
    >>> geometric_median(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])).median
    array([0., 0.])
    """
    X, w = check_points(points, weights)
    keep = w > 0.0
    X, w = X[keep], w[keep]
    options = options or GeometricMedianOptions()
    y = np.average(X, axis=0, weights=w) if x0 is None else np.asarray(x0, dtype=np.float64).copy()
    if y.shape != X.shape[1:]:
        raise ValueError(f"expected x0 of shape ({X.shape[1]},), got {y.shape}")
    scale = float(np.average(np.linalg.norm(X - y, axis=1), weights=w))
    if scale == 0.0:  # every point sits at the start
        return _result(X, w, y, 0, True, True)
    coincide = COINCIDENCE_RTOL * scale
    step = np.inf
    for iteration in range(1, options.max_iterations + 1):
        diff = X - y
        dist = np.linalg.norm(diff, axis=1)
        near = dist <= coincide
        j = int(np.argmin(np.where(near, np.inf, dist))) if not np.all(near) else -1
        if j >= 0 and not np.any(near) and dist[j] <= step:
            # The iterate is approaching x_j: test whether x_j is the median before creeping towards it.
            # Strictly: on a tie (r = w_j, e.g. two points) x_j is one of many medians; iterate on instead.
            at_j = np.linalg.norm(X - X[j], axis=1) <= coincide
            if _pull(X[~at_j] - X[j], w[~at_j]) < w[at_j].sum():
                return _result(X, w, X[j].copy(), iteration - 1, True, True)
        eta = float(w[near].sum())
        r = _pull(diff[~near], w[~near]) if eta > 0.0 else 0.0
        if eta > 0.0 and r <= eta:  # Vardi-Zhang: y is the median
            return _result(X, w, X[near][0].copy(), iteration - 1, True, True)
        inv = w[~near] / dist[~near]
        T = inv @ X[~near] / inv.sum()
        # Plain Weiszfeld when eta = 0; else Vardi-Zhang's step (r > eta here, so min(1, eta / r) = eta / r).
        y_new = (1.0 - eta / r) * T + min(1.0, eta / r) * y if eta > 0.0 else T
        step = float(np.linalg.norm(y_new - y))
        y = y_new
        if step <= options.rtol * scale:
            return _result(X, w, y, iteration, True, False)
    return _result(X, w, y, options.max_iterations, False, False)


def _pull(diff: np.ndarray, w: np.ndarray) -> float:
    """``|sum_i w_i d_i / |d_i||`` for differences d (m, k) (none coincide) and weights (m,)."""
    if diff.shape[0] == 0:
        return 0.0
    units = diff / np.linalg.norm(diff, axis=1)[:, None]
    return float(np.linalg.norm(w @ units))


def _result(X: np.ndarray, w: np.ndarray, y: np.ndarray, iterations: int, converged: bool,
            at_data_point: bool) -> GeometricMedianResult:
    objective = float(w @ np.linalg.norm(X - y, axis=1))
    return GeometricMedianResult(median=y, objective=objective, iterations=iterations, converged=converged,
                                 at_data_point=at_data_point)


__all__ = [
    "COINCIDENCE_RTOL", "GeometricMedianOptions", "GeometricMedianResult", "check_points", "distance_sum",
    "geometric_median",
]
