"""Stage (b): coordinate descent on the 3D cost (paper, "Solving the equations").

Alternates two exact minimizations of ``sum |M_i (R A_i p + t)|^2 + lambda_3d |W (d - mu)|^2``:

1. ``(p, t)`` with ``R`` fixed: linear least squares (the prior makes it inhomogeneous);
2. ``(R, t)`` with ``p`` fixed: OpenCV's SQPnP, which minimizes exactly this data term in normalized
   coordinates (points kept in metres: its thresholds are absolute).

Each step can only lower the cost, so the descent is monotone. SQPnP raises on clustered or
collinear points and may return no solution: the descent then stops with the last good iterate.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .problem import Problem


@dataclass(frozen=True)
class DescentResult:
    """Where a descent ended.

    Attributes
    ----------
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,); p : (P,)
    cost : final 3D cost
    iterations : completed (p, t) + (R, t) rounds
    stopped : why it stopped: 'converged', 'max-iterations', or the SQPnP problem
    """

    R_cam_vehicle: np.ndarray
    t_cam_vehicle: np.ndarray
    p: np.ndarray
    cost: float
    iterations: int
    stopped: str


def solve_shape(problem: Problem, R_cam_vehicle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimize the 3D cost over ``(p, t)`` for a fixed rotation.

    Parameters
    ----------
    R_cam_vehicle : (3, 3)

    Returns
    -------
    p : (P,), t_cam_vehicle : (3,)
    """
    A, u = problem.A, problem.u
    N, _, P = A.shape
    RA = np.einsum("ij,njk->nik", R_cam_vehicle, A)  # (N, 3, P): R A_i
    # M_i = [[1, 0, -x], [0, 1, -y]] applied to R A_i p + t.
    B = RA[:, :2, :] - u[:, :2, None] * RA[:, 2:3, :]  # (N, 2, P)
    Mt = np.zeros((N, 2, 3))
    Mt[:, 0, 0] = 1.0
    Mt[:, 1, 1] = 1.0
    Mt[:, :, 2] = -u[:, :2]
    design = np.concatenate([B, Mt], axis=2).reshape(2 * N, P + 3)
    w = np.sqrt(problem.lambda_3d)
    prior_rows = np.zeros((3, P + 3))
    prior_rows[:, :3] = w * problem.prior.sqrt_information
    prior_rhs = w * problem.prior.sqrt_information @ problem.prior.mean
    lhs = np.vstack([design, prior_rows])
    rhs = np.concatenate([np.zeros(2 * N), prior_rhs])
    x, *_ = np.linalg.lstsq(lhs, rhs, rcond=None)
    return x[:P], x[P:]


def solve_pose(problem: Problem, p: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Minimize the 3D cost over ``(R, t)`` for fixed ``p`` with SQPnP; None when it fails.

    Returns
    -------
    R_cam_vehicle : (3, 3), t_cam_vehicle : (3,), or None
    """
    X = np.ascontiguousarray(problem.A @ p, dtype=np.float64).reshape(-1, 1, 3)
    x = np.ascontiguousarray(problem.u[:, :2], dtype=np.float64).reshape(-1, 1, 2)
    try:
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(X, x, np.eye(3), None, flags=cv2.SOLVEPNP_SQPNP)
    except cv2.error:
        return None
    if n < 1:
        return None
    R, _ = cv2.Rodrigues(rvecs[0])
    return R, np.asarray(tvecs[0], dtype=float).ravel()


def descend(problem: Problem, R_cam_vehicle: np.ndarray, max_iterations: int = 30,
            rel_tolerance: float = 1e-8) -> DescentResult:
    """Coordinate descent from a starting rotation.

    Parameters
    ----------
    R_cam_vehicle : (3, 3) start
    max_iterations : rounds of (p, t) then (R, t)
    rel_tolerance : stop when a round lowers the cost by less than this fraction

    Returns
    -------
    DescentResult
    """
    R = R_cam_vehicle
    p, t = solve_shape(problem, R)
    cost = problem.cost_3d(R, t, p)
    stopped = "max-iterations"
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        pose = solve_pose(problem, p)
        if pose is None:
            stopped = "SQPnP found no pose (clustered or collinear points)"
            iterations -= 1
            break
        R_new, _ = pose
        p_new, t_new = solve_shape(problem, R_new)
        new_cost = problem.cost_3d(R_new, t_new, p_new)
        if new_cost > cost:  # cannot happen in exact arithmetic; guards against SQPnP's local answers
            stopped = "converged"
            break
        R, p, t, old, cost = R_new, p_new, t_new, cost, new_cost
        if old - cost <= rel_tolerance * max(old, 1e-300):
            stopped = "converged"
            break
    return DescentResult(R, t, p, cost, iterations, stopped)
