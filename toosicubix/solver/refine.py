"""Stage (c): Levenberg-Marquardt on the pixel-domain cost (paper, "Pixel-domain fine-tuning").

Residuals: ``K_:2 pi(R A_i p + t) - x_i`` for every click (pixels), then
``sqrt(lambda_px) W (d - mu)`` for the prior (``W`` the Cholesky factor of the inverse covariance).
Unknowns: a rotation increment ``delta`` (3,), ``t`` (3,) and ``p`` (P,). The rotation is updated on
SO(3) through the exponential map, ``R <- R exp([delta]x)``, so the Jacobian of ``Y_i = R X_i + t`` is
``-R [X_i]x`` for ``delta``, ``I`` for ``t`` and ``R A_i`` for ``p``.

Damping: ``(J^T J + mu D) step = -J^T r`` with ``D`` the (floored) diagonal of ``J^T J``; ``mu`` shrinks
fivefold after a step the linear model predicted well, grows tenfold after a rejected one. Steps that put a
clicked point or the bottom centre behind the camera, or make a dimension non-positive, are rejected.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import so3_exp
from .problem import Problem

#: Points closer than this (metres) to the camera plane count as behind it.
MIN_DEPTH = 1e-3


@dataclass(frozen=True)
class RefineResult:
    """Where a refinement ended.

    Attributes
    ----------
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,); p : (P,)
    cost : final pixel-domain cost (px^2 + lambda_px Mahalanobis^2)
    initial_cost : the cost at the start
    iterations : accepted and rejected steps
    stopped : 'gradient', 'step', 'cost', 'max-iterations' or 'damping'
    """

    R_cam_vehicle: np.ndarray
    t_cam_vehicle: np.ndarray
    p: np.ndarray
    cost: float
    initial_cost: float
    iterations: int
    stopped: str


def residuals_and_jacobian(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray,
                           with_jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Stacked residuals (2N + 3,) and their Jacobian (2N + 3, 6 + P) w.r.t. ``(delta, t, p)``.

    Click ``i`` owns rows ``2i`` (x) and ``2i + 1`` (y); the last 3 rows are the prior.
    """
    A, K = problem.A, problem.K
    N, _, P = A.shape
    X = A @ p  # (N, 3) vehicle frame
    Y = X @ R.T + t  # (N, 3) camera frame
    inv_z = 1.0 / Y[:, 2]
    xy = Y[:, :2] * inv_z[:, None]
    K2 = K[:2, :2]
    w = np.sqrt(problem.lambda_px)
    r = np.empty(2 * N + 3)
    r[: 2 * N] = (xy @ K2.T + K[:2, 2] - problem.uv).ravel()
    r[2 * N:] = w * problem.prior_residual(p)
    if not with_jacobian:
        return r, None
    # d(pixel)/dY = K2 @ [[1/z, 0, -x/z], [0, 1/z, -y/z]]   (N, 2, 3)
    dproj = np.zeros((N, 2, 3))
    dproj[:, 0, 0] = inv_z
    dproj[:, 1, 1] = inv_z
    dproj[:, :, 2] = -xy * inv_z[:, None]
    dpix_dY = np.einsum("ab,nbc->nac", K2, dproj)
    dY_ddelta = -np.einsum("ij,njk->nik", R, _hats(X))  # (N, 3, 3)
    dY_dp = np.einsum("ij,njk->nik", R, A)  # (N, 3, P)
    J = np.zeros((2 * N + 3, 6 + P))
    J[: 2 * N, 0:3] = np.einsum("nab,nbc->nac", dpix_dY, dY_ddelta).reshape(2 * N, 3)
    J[: 2 * N, 3:6] = dpix_dY.reshape(2 * N, 3)
    J[: 2 * N, 6:] = np.einsum("nab,nbc->nac", dpix_dY, dY_dp).reshape(2 * N, P)
    J[2 * N:, 6:9] = w * problem.prior.sqrt_information
    return r, J


def _hats(X: np.ndarray) -> np.ndarray:
    """Skew matrices of the rows of X (N, 3): (N, 3, 3)."""
    H = np.zeros((len(X), 3, 3))
    H[:, 0, 1], H[:, 0, 2] = -X[:, 2], X[:, 1]
    H[:, 1, 0], H[:, 1, 2] = X[:, 2], -X[:, 0]
    H[:, 2, 0], H[:, 2, 1] = -X[:, 1], X[:, 0]
    return H


def _feasible(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray) -> bool:
    return bool(np.all(p[:3] > 0.0)) and problem.min_depth(R, t, p) > MIN_DEPTH


def levenberg_marquardt(problem: Problem, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray,
           max_iterations: int = 100, gradient_tolerance: float = 1e-8, step_tolerance: float = 1e-10,
           cost_tolerance: float = 1e-10) -> RefineResult:
    """Levenberg-Marquardt from a feasible start.

    Parameters
    ----------
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,); p : (P,)
    gradient_tolerance : stop when the residual is this close to orthogonal to every Jacobian column
        (the largest ``|J_j^T r| / (|J_j| |r|)``, MINPACK's gtol)
    step_tolerance : stop when an accepted step changes the rotation by less than this many radians and
        ``t``, ``p`` by less than this fraction of their size
    cost_tolerance : stop when an accepted step lowers the cost by less than this fraction

    Returns
    -------
    RefineResult
    """
    R, t, p = R_cam_vehicle.copy(), t_cam_vehicle.copy(), p.copy()
    n_p = len(p)
    r, J = residuals_and_jacobian(problem, R, t, p)
    cost = float(r @ r)
    initial_cost = cost
    mu = 1e-3
    stopped = "max-iterations"
    iterations = 0
    while iterations < max_iterations:
        iterations += 1
        g = J.T @ r
        column_norms = np.sqrt(np.einsum("ij,ij->j", J, J))
        if cost == 0.0 or np.max(np.abs(g) / np.maximum(column_norms, 1e-300)) <= gradient_tolerance * np.sqrt(cost):
            stopped = "gradient"
            break
        H = J.T @ J
        D = np.maximum(column_norms**2, 1e-12 * max(float(np.max(column_norms)) ** 2, 1e-300))
        H_damped = H.copy()
        H_damped[np.diag_indices_from(H)] += mu * D
        try:
            step = np.linalg.solve(H_damped, -g)
        except np.linalg.LinAlgError:
            mu *= 10.0
            continue
        R_new = R @ so3_exp(step[:3])
        t_new = t + step[3:6]
        p_new = p + step[6:6 + n_p]
        rho = -1.0
        if _feasible(problem, R_new, t_new, p_new):
            r_new, _ = residuals_and_jacobian(problem, R_new, t_new, p_new, with_jacobian=False)
            new_cost = float(r_new @ r_new)
            predicted = float(step @ (mu * D * step - g))  # cost drop predicted by the linear model
            rho = (cost - new_cost) / predicted if predicted > 0 else -1.0
        if rho > 0:
            size = np.linalg.norm(t) + np.linalg.norm(p) + 1.0
            small_step = (np.max(np.abs(step[:3])) <= step_tolerance
                          and np.linalg.norm(step[3:]) <= step_tolerance * size)
            R, t, p = R_new, t_new, p_new
            r, J = residuals_and_jacobian(problem, R, t, p)
            drop = cost - new_cost
            cost = new_cost
            mu = max(mu * (0.2 if rho > 0.75 else 1.0 if rho > 0.25 else 2.0), 1e-15)
            if small_step:
                stopped = "step"
                break
            if drop <= cost_tolerance * cost:
                stopped = "cost"
                break
        else:
            mu *= 10.0
            if mu > 1e16:
                stopped = "damping"
                break
    # Re-orthonormalize against drift from many small exp() products.
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    return RefineResult(R, t, p, cost, initial_cost, iterations, stopped)
