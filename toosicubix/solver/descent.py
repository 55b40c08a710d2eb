"""Stage (b): coordinate descent on the 3D cost (paper, "Solving the equations").

Alternates two exact minimizations of ``sum |M_i (R A_i p + t)|^2 + lambda_3d |W (d - mu)|^2``:

1. ``(p, t)`` with ``R`` fixed: linear least squares (the prior and the other scale cues make it
   inhomogeneous);
2. ``(R, t)`` with ``p`` fixed: OpenCV's SQPnP, which minimizes exactly this data term in normalized
   coordinates (points kept in metres: its thresholds are absolute).

Each step can only lower the cost, so the descent is monotone. SQPnP raises on clustered or
collinear points and may return no solution: the descent then stops with the last good iterate.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from toosicubix.solver import compiled
from toosicubix.solver.problem import Problem

#: Memory for the normal matrices (and ``M_i R``) of the starts the shape step solves together, bytes.
_SHAPE_CHUNK_BYTES = 65536
#: The camera matrix of normalized coordinates, as SQPnP takes it (never written to).
_IDENTITY = np.eye(3)


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


def solve_shapes(problem: Problem, R_cam_vehicle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimize the 3D cost over ``(p, t)`` for each of several fixed rotations at once.

    Parameters
    ----------
    R_cam_vehicle : (S, 3, 3)

    Returns
    -------
    p : (S, P), t_cam_vehicle : (S, 3)
    """
    A = problem.A
    P = A.shape[2]
    M, prior_normal, rhs = _shape_terms(problem)
    x = compiled.solve_shapes(A, M, R_cam_vehicle, prior_normal, rhs,
                              lambda: _shapes_numpy(A, M, R_cam_vehicle, prior_normal, rhs))
    if x is None:
        x = _shapes_numpy(A, M, R_cam_vehicle, prior_normal, rhs)
    return x[:, :P], x[:, P:]


def _shape_terms(problem: Problem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What every shape step of ``problem`` shares (made once per problem: :meth:`.problem.Problem.kept`): ``M``
    (N, 2, 3), ``M_i = [[1, 0, -x], [0, 1, -y]]`` applied to ``R A_i p + t``; the scale rows' normal matrix
    (P + 3, P + 3) and right-hand side (P + 3,) on ``(p, t)``."""
    return problem.kept("descent shape terms", _make_shape_terms)


def _make_shape_terms(problem: Problem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    # The scale rows (size prior, known sizes, ground contact) act on (t, p); here the unknowns are (p, t).
    w = np.sqrt(problem.lambda_3d)
    prior_rows = w * np.hstack([problem.G[:, 3:], problem.G[:, :3]])
    prior_rhs = w * problem.b
    return _translation_block(problem.u), prior_rows.T @ prior_rows, prior_rows.T @ prior_rhs


def _shapes_numpy(A: np.ndarray, M: np.ndarray, R_cam_vehicle: np.ndarray, prior_normal: np.ndarray,
                  rhs: np.ndarray) -> np.ndarray:
    """:func:`solve_shapes`' solutions (S, P + 3) in numpy."""
    N, _, P = A.shape
    S = len(R_cam_vehicle)
    design = np.empty((N, 2, P + 3))
    design[..., P:] = M
    rows = design.reshape(2 * N, P + 3)  # the design matrix of one start (a view: filled per start below)
    x = np.empty((S, P + 3))
    # One design matrix at a time: that of every start at once, (S, 2N, P + 3), would grow with the starts
    # times the square of the clicks (each symmetric pair or arrow adds two clicks and two unknowns). Their
    # normal matrices, (P + 3, P + 3) each, are solved a chunk of starts at a time.
    chunk = max(1, _SHAPE_CHUNK_BYTES // (8 * ((P + 3) ** 2 + 6 * N)))
    for first in range(0, S, chunk):
        x[first:first + chunk] = _solve_normal_equations(
            M @ R_cam_vehicle[first:first + chunk, None], A, design, rows, prior_normal, rhs)
    return x


def _solve_normal_equations(MR: np.ndarray, A: np.ndarray, design: np.ndarray, rows: np.ndarray,
                            prior_normal: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """The shape step's ``(p, t)``, (C, P + 3), of C starts: ``MR`` (C, N, 2, 3) is ``M_i R`` of each start;
    ``design`` (N, 2, P + 3) holds ``M_i`` in its last 3 columns and ``rows`` is it as (2N, P + 3)."""
    C, _, _, _ = MR.shape
    n = rows.shape[1]
    P = n - 3
    normal = np.empty((C, n, n))
    for s in range(C):
        np.matmul(MR[s], A, out=design[..., :P])  # (N, 2, P): M_i R A_i
        np.matmul(rows.T, rows, out=normal[s])
    normal += prior_normal
    # A ridge of 1e-12 of the mean diagonal keeps an auxiliary unknown that no click constrains at zero
    # instead of making the system singular.
    trace = normal.diagonal(axis1=1, axis2=2).sum(axis=1)  # (C,)
    diagonal = np.arange(n)
    normal[:, diagonal, diagonal] += (1e-12 * trace / n)[:, None]
    # One LAPACK call per system, as one at a time, without the per-call overhead.
    return np.linalg.solve(normal, np.broadcast_to(rhs, (C, n))[..., None])[..., 0]


def _translation_block(u: np.ndarray) -> np.ndarray:
    """``M_i`` for every click: (N, 2, 3)."""
    M = np.zeros((len(u), 2, 3))
    M[:, 0, 0] = 1.0
    M[:, 1, 1] = 1.0
    M[:, :, 2] = -u[:, :2]
    return M


def solve_shape(problem: Problem, R_cam_vehicle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimize the 3D cost over ``(p, t)`` for one fixed rotation (3, 3): ``p`` (P,), ``t`` (3,)."""
    p, t = solve_shapes(problem, R_cam_vehicle[None])
    return p[0], t[0]


def costs_3d(problem: Problem, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The 3D cost of several poses at once: ``R`` (S, 3, 3), ``t`` (S, 3), ``p`` (S, P) -> (S,)."""
    out = compiled.costs_3d(problem, R_cam_vehicle, t_cam_vehicle, p,
                            lambda: _costs_numpy(problem, R_cam_vehicle, t_cam_vehicle, p))
    return _costs_numpy(problem, R_cam_vehicle, t_cam_vehicle, p) if out is None else out


def _costs_numpy(problem: Problem, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray) -> np.ndarray:
    """:func:`costs_3d` in numpy."""
    X = problem.points_vehicle_batch(p)  # (S, N, 3) vehicle frame
    Y = np.einsum("sij,snj->sni", R_cam_vehicle, X) + t_cam_vehicle[:, None, :]
    e = Y[..., :2] - problem.u[None, :, :2] * Y[..., 2:3]
    a, b = problem.scale_terms(t_cam_vehicle, p)
    return np.sum(e * e, axis=(1, 2)) + problem.lambda_3d * np.sum((a - b) ** 2, axis=1)


def solve_pose(problem: Problem, p: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Minimize the 3D cost over ``(R, t)`` for fixed ``p`` with SQPnP; None when it fails.

    Returns
    -------
    R_cam_vehicle : (3, 3), t_cam_vehicle : (3,), or None
    """
    X = np.ascontiguousarray(problem.A @ p, dtype=np.float64).reshape(-1, 1, 3)
    try:  # solvePnP takes SQPnP's first solution as solvePnPGeneric does, without the reprojection errors
        found, rvec, tvec = cv2.solvePnP(X, problem.u_image_points, _IDENTITY, None, flags=cv2.SOLVEPNP_SQPNP)
    except cv2.error:
        return None
    if not found:
        return None
    R, _ = cv2.Rodrigues(rvec)
    return R, tvec.ravel()


def descend_all(problem: Problem, R_start: np.ndarray, max_iterations: int = 30, rel_tolerance: float = 1e-8,
                first_step: tuple[np.ndarray, np.ndarray] | None = None) -> list[DescentResult]:
    """Coordinate descent from several starting rotations, in lockstep (the shape steps are batched).

    Parameters
    ----------
    R_start : (S, 3, 3) starts
    max_iterations : rounds of (R, t) then (p, t) after the first (p, t) step
    rel_tolerance : a start stops when a round lowers its cost by less than this fraction
    first_step : ``(p, t)`` of the first step, (S, P) and (S, 3), when the caller has already solved it

    Returns
    -------
    list of DescentResult, one per start
    """
    R = np.array(R_start, dtype=float)
    S = len(R)
    p, t = solve_shapes(problem, R) if first_step is None else (first_step[0].copy(), first_step[1].copy())
    cost = costs_3d(problem, R, t, p)
    iterations = np.zeros(S, dtype=int)
    stopped = ["max-iterations"] * S
    active = np.ones(S, dtype=bool)
    for _ in range(max_iterations):
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        moved = []
        for k in idx:
            pose = solve_pose(problem, p[k])
            if pose is None:
                stopped[k] = "SQPnP found no pose (clustered or collinear points)"
                active[k] = False
            else:
                moved.append((k, pose[0]))
        if not moved:
            break
        ks = np.array([k for k, _ in moved])
        R_new = np.array([Rk for _, Rk in moved])
        p_new, t_new = solve_shapes(problem, R_new)
        new_cost = costs_3d(problem, R_new, t_new, p_new)
        for j, k in enumerate(ks):
            if new_cost[j] > cost[k]:  # cannot happen in exact arithmetic; guards against SQPnP's local answers
                stopped[k] = "converged"
                active[k] = False
                continue
            old = cost[k]
            R[k], p[k], t[k], cost[k] = R_new[j], p_new[j], t_new[j], new_cost[j]
            iterations[k] += 1
            if old - cost[k] <= rel_tolerance * max(old, 1e-300):
                stopped[k] = "converged"
                active[k] = False
    return [DescentResult(R[k], t[k], p[k], float(cost[k]), int(iterations[k]), stopped[k]) for k in range(S)]


def descend(problem: Problem, R_cam_vehicle: np.ndarray, max_iterations: int = 30,
            rel_tolerance: float = 1e-8) -> DescentResult:
    """Coordinate descent from one starting rotation (3, 3); see :func:`descend_all`."""
    return descend_all(problem, R_cam_vehicle[None], max_iterations, rel_tolerance)[0]
