"""Stage (c): Levenberg-Marquardt on the pixel-domain cost (paper, "Pixel-domain fine-tuning").

Residuals: ``K_:2 pi(R A_i p + t) - x_i`` for every click (pixels), then
``sqrt(lambda_px) W (d - mu)`` for the prior (``W`` the Cholesky factor of the inverse covariance).
Unknowns: a rotation increment ``delta`` (3,), ``t`` (3,) and ``p`` (P,). The rotation is updated on
SO(3) through the exponential map about a pivot ``c`` (the centroid of the clicked points, vehicle frame):
``R <- R exp([delta]x)``, ``t <- t + dt + (R_old - R_new) c``, so the Jacobian of ``Y_i = R X_i + t`` is
``-R [X_i - c]x`` for ``delta``, ``I`` for ``t`` and ``R A_i`` for ``p``.

Damping: ``(J^T J + mu D) step = -J^T r`` with ``D`` the (floored) diagonal of ``J^T J``; ``mu`` follows
Nielsen's rule: after a step with gain ratio ``rho`` it is multiplied by ``max(1/3, 1 - (2 rho - 1)^3)``,
after a rejected step by ``nu``, which doubles with each rejection in a row. Steps that put a
clicked point or the bottom centre behind the camera, make a dimension non-positive, or tilt an upright start
past the plausible bound, are rejected.

Several starts are refined in lockstep (:func:`levenberg_marquardt_batch`): residuals, Jacobians and the
damped normal equations of all of them are computed in one pass of batched array operations, each start
keeping its own damping, acceptance and stopping. A start still far above the best one after a few
iterations is abandoned.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.linalg import lapack

from .problem import Problem

#: Points closer than this (metres) to the camera plane count as behind it.
MIN_DEPTH = 1e-3

_RUNNING, _GRADIENT, _STEP, _COST, _MAX_ITERATIONS, _DAMPING, _ABANDONED = range(7)
_STATUS_NAMES = ("running", "gradient", "step", "cost", "max-iterations", "damping", "abandoned")


@dataclass(frozen=True)
class RefineResult:
    """Where a refinement ended.

    Attributes
    ----------
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,); p : (P,)
    cost : final pixel-domain cost (px^2 + lambda_px Mahalanobis^2)
    initial_cost : the cost at the start
    iterations : accepted and rejected steps
    stopped : 'gradient', 'step', 'cost', 'max-iterations', 'damping' or 'abandoned'
    """

    R_cam_vehicle: np.ndarray
    t_cam_vehicle: np.ndarray
    p: np.ndarray
    cost: float
    initial_cost: float
    iterations: int
    stopped: str


def residuals_batch(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray, with_jacobian: bool,
                    pivot: np.ndarray | None, profile_scale: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """Residuals (B, M) and Jacobians (B, M, 6 + P) of B poses: ``R`` (B, 3, 3), ``t`` (B, 3), ``p`` (B, P),
    ``pivot`` (B, 3) or None. Rows: 2 per click (pixels), then the scale rows, then 3 upright rows when the
    problem has a ground plane; the cue rows are multiplied by ``sqrt(lambda_px)``."""
    K_ = problem.K
    N, _, P = problem.A.shape
    B = len(R)
    m = len(problem.b)
    n_up = 0 if problem.upright_sigma is None else 3
    X = problem.points_vehicle_batch(p)  # (B, N, 3) vehicle frame
    Y = X @ R.transpose(0, 2, 1) + t[:, None, :]  # (B, N, 3) camera frame
    inv_z = 1.0 / Y[..., 2]
    xn, yn = Y[..., 0] * inv_z, Y[..., 1] * inv_z
    fx, skew, cx, fy, cy = K_[0, 0], K_[0, 1], K_[0, 2], K_[1, 1], K_[1, 2]
    w = np.sqrt(problem.lambda_px)
    r = np.empty((B, 2 * N + m + n_up))
    r[:, 0:2 * N:2] = fx * xn + skew * yn + cx - problem.uv[:, 0]
    r[:, 1:2 * N:2] = fy * yn + cy - problem.uv[:, 1]
    a, b = problem.scale_terms(t, p)  # (B, m), (m,)
    if profile_scale:
        aa = np.einsum("ki,ki->k", a, a)
        s_best = (a @ b) / aa
        r[:, 2 * N:2 * N + m] = w * (s_best[:, None] * a - b)
    else:
        r[:, 2 * N:2 * N + m] = w * (a - b)
    if n_up:
        w_up = w / problem.upright_sigma
        r[:, 2 * N + m:] = w_up * (R[:, :, 2] - problem.up)
    if not with_jacobian:
        return r, None
    # D = d(pixel)/dY = [[fx/z, skew/z, -(fx x + skew y)/z], [0, fy/z, -fy y/z]], x, y normalized: (B, N, 2, 3)
    D = np.zeros((B, N, 2, 3))
    D[..., 0, 0] = fx * inv_z
    D[..., 0, 1] = skew * inv_z
    D[..., 0, 2] = -(fx * xn + skew * yn) * inv_z
    D[..., 1, 1] = fy * inv_z
    D[..., 1, 2] = -fy * yn * inv_z
    DR = D @ R[:, None, :, :]  # (B, N, 2, 3)
    # Rotation columns: each row b of D R against dY = -R [X - c]x delta gives the row (X - c) x b.
    Xc = (X if pivot is None else X - pivot[:, None, :])[:, :, None, :]
    J = np.zeros((B, 2 * N + m + n_up, 6 + P))
    J_rot = J[:, : 2 * N, 0:3].reshape(B, N, 2, 3)
    J_rot[..., 0] = Xc[..., 1] * DR[..., 2] - Xc[..., 2] * DR[..., 1]
    J_rot[..., 1] = Xc[..., 2] * DR[..., 0] - Xc[..., 0] * DR[..., 2]
    J_rot[..., 2] = Xc[..., 0] * DR[..., 1] - Xc[..., 1] * DR[..., 0]
    J[:, : 2 * N, 3:6] = D.reshape(B, 2 * N, 3)
    J[:, : 2 * N, 6:] = (DR @ problem.A).reshape(B, 2 * N, P)
    # Scale rows: a = G_t t + G_p p; turning about the pivot moves t by R [c]x delta.
    Ga = np.zeros((B, m, 6 + P))
    Gt = problem.G[:, :3]
    if pivot is not None and np.any(Gt):
        c_hat = np.zeros((B, 3, 3))
        c_hat[:, 0, 1], c_hat[:, 0, 2] = -pivot[:, 2], pivot[:, 1]
        c_hat[:, 1, 0], c_hat[:, 1, 2] = pivot[:, 2], -pivot[:, 0]
        c_hat[:, 2, 0], c_hat[:, 2, 1] = -pivot[:, 1], pivot[:, 0]
        Ga[:, :, 0:3] = Gt @ (R @ c_hat)
    Ga[:, :, 3:6] = Gt
    Ga[:, :, 6:] = problem.G[:, 3:]
    if profile_scale:
        ds = np.einsum("kmi,km->ki", Ga, b - 2.0 * s_best[:, None] * a) / aa[:, None]  # (B, 6 + P)
        J[:, 2 * N:2 * N + m] = w * (s_best[:, None, None] * Ga + a[:, :, None] * ds[:, None, :])
    else:
        J[:, 2 * N:2 * N + m] = w * Ga
    if n_up:
        # R exp([delta]x) e_z ~ R (e_z + delta x e_z) = R e_z + delta_y R e_x - delta_x R e_y.
        J[:, 2 * N + m:, 0] = -w_up * R[:, :, 1]
        J[:, 2 * N + m:, 1] = w_up * R[:, :, 0]
    return r, J


def residuals_and_jacobian(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray,
                           with_jacobian: bool = True, pivot: np.ndarray | None = None,
                           profile_scale: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Stacked residuals (2N + 3,) and their Jacobian (2N + 3, 6 + P) w.r.t. ``(delta, t, p)``.

    Click ``i`` owns rows ``2i`` (x) and ``2i + 1`` (y); the last 3 rows are the prior. With ``pivot``
    (3,), vehicle frame, the rotation increment turns the vehicle about that point instead of its origin
    (``t`` moves along, see :func:`levenberg_marquardt_batch`). With ``profile_scale`` the prior rows are
    ``sqrt(lambda_px) (s* W d - W mu)`` with the best scale ``s* = (W d . W mu) / |W d|^2``: the prior's
    minimum over the scale, which the pixel rows cannot see. Equal to the plain rows where ``s* = 1``.
    """
    r, J = residuals_batch(problem, R[None], t[None], p[None], with_jacobian,
                            None if pivot is None else pivot[None], profile_scale)
    return r[0], None if J is None else J[0]


def _so3_exp_batch(omega: np.ndarray) -> np.ndarray:
    """The exponential map of (B, 3) rotation vectors: (B, 3, 3). OpenCV's Rodrigues in a loop: for the few
    starts of a batch this beats the vectorized formula (about 1 microsecond each)."""
    return np.array([cv2.Rodrigues(w)[0] for w in omega])


def _at_prior_scale(problem: Problem, t: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Move each (t, p) of a batch, (B, 3) and (B, P), to the scale the cues prefer (when positive)."""
    a, b = problem.scale_terms(t, p)
    s = (a @ b) / np.einsum("ki,ki->k", a, a)
    s = np.where(s > 0, s, 1.0)
    return s[:, None] * t, s[:, None] * p


def _pivots(problem: Problem, p: np.ndarray) -> np.ndarray:
    """Centroid of the clicked points in the vehicle frame for each ``p`` of a batch: (B, 3)."""
    return p @ problem.A_mean.T


def levenberg_marquardt_batch(problem: Problem, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray,
                              p: np.ndarray, max_iterations: int = 100, gradient_tolerance: float = 1e-6,
                              step_tolerance: float = 1e-10, cost_tolerance: float = 1e-8,
                              abandon_factor: float | None = None, abandon_after: int = 10,
                              abandon_above: float | None = None,
                              max_tilt: float | None = None) -> list[RefineResult]:
    """Levenberg-Marquardt from several feasible starts at once.

    Parameters
    ----------
    R_cam_vehicle : (B, 3, 3); t_cam_vehicle : (B, 3); p : (B, P)
    gradient_tolerance : stop when the residual is this close to orthogonal to every Jacobian column
        (the largest ``|J_j^T r| / (|J_j| |r|)``, MINPACK's gtol)
    step_tolerance : stop when an accepted step changes the rotation by less than this many radians and
        ``t``, ``p`` by less than this fraction of their size
    cost_tolerance : stop when an accepted step lowers the cost by less than this fraction
    abandon_factor, abandon_after, abandon_above : a start is stopped ('abandoned') when after
        ``abandon_after`` iterations its cost is still above ``abandon_factor`` times the lowest cost in the
        batch, or above ``abandon_above`` (an answer already in hand)
    max_tilt : radians; a start whose up axis leans less than this from the road normal (else the camera's
        up direction -y) never takes a step that leans it further (see :mod:`.plausibility`)

    Returns
    -------
    list of RefineResult, one per start
    """
    B = len(p)
    R = np.array(R_cam_vehicle, dtype=float)
    # Rotation increments turn the vehicle about the centroid of its clicked points, not its bottom centre:
    # that keeps rotation and translation nearly uncoupled, so the valley the steps follow is straighter.
    # The pixel rows do not change with the scale of (t, p); only the prior fixes it, with a curvature far
    # below the other directions' that damping would all but freeze. So the prior is profiled over the
    # scale (its minimum over s), leaving an exact null direction, and every accepted iterate is moved to
    # its best scale: the minimum is that of the plain cost.
    t, p = _at_prior_scale(problem, np.array(t_cam_vehicle, dtype=float), np.array(p, dtype=float))
    pivot = _pivots(problem, p)
    r, J = residuals_batch(problem, R, t, p, True, pivot, True)
    cost = np.einsum("km,km->k", r, r)
    initial_cost = cost.copy()
    n = J.shape[2]
    diagonal = np.arange(n)
    mu = np.full(B, 1e-3)
    nu = np.full(B, 2.0)
    iterations = np.zeros(B, dtype=int)
    status = np.full(B, _RUNNING)
    size = np.linalg.norm(t, axis=1) + np.linalg.norm(p, axis=1) + 1.0
    # R e_z . up is the cosine of the tilt; starts within the bound are kept within it.
    up = problem.up
    min_up = -np.inf if max_tilt is None else np.cos(max_tilt)
    keep_upright = R[:, :, 2] @ up >= min_up

    for _ in range(max_iterations):
        if abandon_factor is not None or abandon_above is not None:
            bar = np.inf if abandon_above is None else abandon_above
            if abandon_factor is not None:
                bar = min(bar, abandon_factor * float(cost.min()) + 1e-6)
            status[(status == _RUNNING) & (iterations >= abandon_after) & (cost > bar)] = _ABANDONED
        idx = np.flatnonzero(status == _RUNNING)
        if len(idx) == 0:
            break
        Ji, ri = J[idx], r[idx]
        g = np.einsum("kmi,km->ki", Ji, ri)
        column_norms = np.sqrt(np.einsum("kmi,kmi->ki", Ji, Ji))
        cosines = np.max(np.abs(g) / np.maximum(column_norms, 1e-300), axis=1)
        done = (cost[idx] == 0.0) | (cosines <= gradient_tolerance * np.sqrt(cost[idx]))
        status[idx[done]] = _GRADIENT
        if done.all():
            break
        keep = ~done
        idx, Ji, g, column_norms = idx[keep], Ji[keep], g[keep], column_norms[keep]
        iterations[idx] += 1
        H = Ji.transpose(0, 2, 1) @ Ji
        Dg = np.maximum(column_norms**2, 1e-12 * np.max(column_norms, axis=1, keepdims=True) ** 2 + 1e-300)
        H[:, diagonal, diagonal] += mu[idx, None] * Dg
        step = _solve_batch(H, -g)
        solved = np.all(np.isfinite(step), axis=1)
        step[~solved] = 0.0
        R_new = R[idx] @ _so3_exp_batch(step[:, :3])
        t_new = t[idx] + step[:, 3:6] + np.einsum("kij,kj->ki", R[idx] - R_new, pivot[idx])
        p_new = p[idx] + step[:, 6:]
        depths = problem.points_vehicle_batch(p_new) @ R_new[:, 2, :, None]
        feasible = (solved & np.all(p_new[:, :3] > 0.0, axis=1) & (t_new[:, 2] > MIN_DEPTH)
                    & (depths[..., 0].min(axis=1) + t_new[:, 2] > MIN_DEPTH)
                    & (~keep_upright[idx] | (R_new[:, :, 2] @ up >= min_up)))
        rho = np.full(len(idx), -1.0)
        new_cost = np.full(len(idx), np.inf)
        if feasible.any():
            r_try, _ = residuals_batch(problem, R_new[feasible], t_new[feasible], p_new[feasible], False, None, True)
            new_cost[feasible] = np.einsum("km,km->k", r_try, r_try)
            sf = step[feasible]
            predicted = np.einsum("ki,ki->k", sf, mu[idx[feasible], None] * Dg[feasible] * sf - g[feasible])
            with np.errstate(divide="ignore", invalid="ignore"):
                rho[feasible] = np.where(predicted > 0, (cost[idx[feasible]] - new_cost[feasible]) / predicted, -1.0)
        accept = rho > 0
        rejected = idx[~accept]
        mu[rejected] *= nu[rejected]
        nu[rejected] *= 2.0
        status[rejected[mu[rejected] > 1e16]] = _DAMPING
        if not accept.any():
            continue
        ka = idx[accept]
        sa = step[accept]
        small = (np.max(np.abs(sa[:, :3]), axis=1) <= step_tolerance) & (
            np.linalg.norm(sa[:, 3:], axis=1) <= step_tolerance * size[ka])
        R[ka] = R_new[accept]
        t[ka], p[ka] = _at_prior_scale(problem, t_new[accept], p_new[accept])
        pivot[ka] = _pivots(problem, p[ka])
        r[ka], J[ka] = residuals_batch(problem, R[ka], t[ka], p[ka], True, pivot[ka], True)
        drop = cost[ka] - new_cost[accept]
        cost[ka] = new_cost[accept]
        ra = rho[accept]
        mu[ka] = np.maximum(mu[ka] * np.maximum(1.0 / 3.0, 1.0 - (2.0 * ra - 1.0) ** 3), 1e-15)
        nu[ka] = 2.0
        status[ka[(drop <= cost_tolerance * cost[ka]) & ~small]] = _COST
        status[ka[small]] = _STEP
    status[status == _RUNNING] = _MAX_ITERATIONS
    # Re-orthonormalize against drift from many small exp() products.
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    return [RefineResult(R[k], t[k], p[k], float(cost[k]), float(initial_cost[k]), int(iterations[k]),
                         _STATUS_NAMES[status[k]]) for k in range(B)]


def _solve_batch(H: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``H x = b`` for a batch (B, n, n), (B, n) of symmetric positive definite systems (LAPACK dposv,
    one call each: cheaper than a batched solve for a few starts); rows that are not come back NaN."""
    out = np.full(b.shape, np.nan)
    for k in range(len(H)):
        _, x, info = lapack.dposv(H[k], b[k])
        if info == 0:
            out[k] = x
    return out


def levenberg_marquardt(problem: Problem, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray,
                        max_iterations: int = 100, **tolerances: float) -> RefineResult:
    """Levenberg-Marquardt from one feasible start; see :func:`levenberg_marquardt_batch`.

    Parameters
    ----------
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,); p : (P,)
    """
    return levenberg_marquardt_batch(problem, R_cam_vehicle[None], t_cam_vehicle[None], p[None],
                                     max_iterations, **tolerances)[0]
