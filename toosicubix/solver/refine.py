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

from toosicubix.solver.problem import ARROW_ZONE_SIGMA, Problem

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
    problem has a ground plane, then 3 arrow-zone rows per arrow; the cue rows are multiplied by
    ``sqrt(lambda_px)``."""
    K_ = problem.K
    N, _, P = problem.A.shape
    B = len(R)
    m = len(problem.b)
    n_up = 0 if problem.upright_sigma is None else 3
    n_arrow = problem.n_arrow_rows
    X = problem.points_vehicle_batch(p)  # (B, N, 3) vehicle frame
    Y = X @ R.transpose(0, 2, 1) + t[:, None, :]  # (B, N, 3) camera frame
    inv_z = 1.0 / Y[..., 2]
    xn, yn = Y[..., 0] * inv_z, Y[..., 1] * inv_z
    fx, skew, cx, fy, cy = K_[0, 0], K_[0, 1], K_[0, 2], K_[1, 1], K_[1, 2]
    w = np.sqrt(problem.lambda_px)
    r = np.empty((B, 2 * N + m + n_up + n_arrow))
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
        r[:, 2 * N + m:2 * N + m + n_up] = w_up * (R[:, :, 2] - problem.up)
    if n_arrow:
        w_arrow = w / ARROW_ZONE_SIGMA
        outside, arrow_gradient = problem.arrow_zone_residuals(p)
        r[:, 2 * N + m + n_up:] = w_arrow * outside
    if not with_jacobian:
        return r, None
    # D = d(pixel)/dY = [[fx/z, skew/z, -(fx x + skew y)/z], [0, fy/z, -fy y/z]], x, y normalized: (B, N, 2, 3),
    # written straight into the translation columns of J (its Jacobian for t).
    J = np.zeros((B, 2 * N + m + n_up + n_arrow, 6 + P))
    D = J[:, : 2 * N, 3:6].reshape(B, N, 2, 3)
    D[..., 0, 0] = fx * inv_z
    D[..., 0, 1] = skew * inv_z
    D[..., 0, 2] = -(fx * xn + skew * yn) * inv_z
    D[..., 1, 1] = fy * inv_z
    D[..., 1, 2] = -fy * yn * inv_z
    DR = D @ R[:, None, :, :]  # (B, N, 2, 3)
    # Rotation columns: each row b of D R against dY = -R [X - c]x delta gives the row (X - c) x b.
    Xc = (X if pivot is None else X - pivot[:, None, :])[:, :, None, :]
    J_rot = J[:, : 2 * N, 0:3].reshape(B, N, 2, 3)
    J_rot[..., 0] = Xc[..., 1] * DR[..., 2] - Xc[..., 2] * DR[..., 1]
    J_rot[..., 1] = Xc[..., 2] * DR[..., 0] - Xc[..., 0] * DR[..., 2]
    J_rot[..., 2] = Xc[..., 0] * DR[..., 1] - Xc[..., 1] * DR[..., 0]
    J[:, : 2 * N, 6:] = (DR @ problem.A).reshape(B, 2 * N, P)
    # Scale rows: a = G_t t + G_p p; turning about the pivot moves t by R [c]x delta.
    Ga = np.zeros((B, m, 6 + P))
    Gt = problem.G[:, :3]
    if pivot is not None and Gt.any():
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
        J[:, 2 * N + m:2 * N + m + n_up, 0] = -w_up * R[:, :, 1]
        J[:, 2 * N + m:2 * N + m + n_up, 1] = w_up * R[:, :, 0]
    if n_arrow:
        J[:, 2 * N + m + n_up:, 6:] = w_arrow * arrow_gradient
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
    s[~(s > 0)] = 1.0
    s = s[:, None]
    return s * t, s * p


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
    size = np.sqrt(np.einsum("ki,ki->k", t, t)) + np.sqrt(np.einsum("ki,ki->k", p, p)) + 1.0
    # R e_z . up is the cosine of the tilt; starts within the bound are kept within it.
    up = problem.up
    min_up = -np.inf if max_tilt is None else np.cos(max_tilt)
    keep_upright = R[:, :, 2] @ up >= min_up

    # Every array keeps all B starts; the ones that stopped ride along (a few more rows cost less than the
    # gathers to leave them out) but are never updated.
    for _ in range(max_iterations):
        running = status == _RUNNING
        if abandon_factor is not None or abandon_above is not None:
            bar = np.inf if abandon_above is None else abandon_above
            if abandon_factor is not None:
                bar = min(bar, abandon_factor * float(cost.min()) + 1e-6)
            gone = running & (iterations >= abandon_after) & (cost > bar)
            status[gone] = _ABANDONED
            running &= ~gone
        if not running.any():
            break
        g = np.einsum("kmi,km->ki", J, r)
        column_sq = np.einsum("kmi,kmi->ki", J, J)  # squared column norms
        # max_j |g_j| / |J_j| <= gtol |r|, squared
        cosines_sq = (g * g / np.maximum(column_sq, 1e-300)).max(axis=1)
        done = running & ((cost == 0.0) | (cosines_sq <= gradient_tolerance**2 * cost))
        status[done] = _GRADIENT
        running &= ~done
        if not running.any():
            break
        iterations += running
        H = J.transpose(0, 2, 1) @ J
        Dg = np.maximum(column_sq, 1e-12 * column_sq.max(axis=1, keepdims=True) + 1e-300)
        H[:, diagonal, diagonal] += mu[:, None] * Dg
        step = _solve_batch(H, -g, running)
        solved = np.isfinite(step).all(axis=1)  # only running starts are solved
        step[~solved] = 0.0
        R_new = R @ _so3_exp_batch(step[:, :3])
        t_new = t + step[:, 3:6] + np.einsum("kij,kj->ki", R - R_new, pivot)
        p_new = p + step[:, 6:]
        depths = problem.points_vehicle_batch(p_new) @ R_new[:, 2, :, None]
        feasible = (solved & (p_new[:, :3] > 0.0).all(axis=1) & (t_new[:, 2] > MIN_DEPTH)
                    & (depths[..., 0].min(axis=1) + t_new[:, 2] > MIN_DEPTH)
                    & (~keep_upright | (R_new[:, :, 2] @ up >= min_up)))
        rho = np.full(B, -1.0)
        if feasible.any():
            # The trial point goes to its best scale before it is evaluated (the profiled cost does not change
            # with the scale), with its Jacobian: most steps are accepted, and then it is the next iterate's.
            R_try = R_new[feasible]
            t_try, p_try = _at_prior_scale(problem, t_new[feasible], p_new[feasible])
            pivot_try = _pivots(problem, p_try)
            r_try, J_try = residuals_batch(problem, R_try, t_try, p_try, True, pivot_try, True)
            new_cost = np.einsum("km,km->k", r_try, r_try)
            sf = step[feasible]
            predicted = np.einsum("ki,ki->k", sf, mu[feasible, None] * Dg[feasible] * sf - g[feasible])
            with np.errstate(divide="ignore", invalid="ignore"):
                rho[feasible] = np.where(predicted > 0, (cost[feasible] - new_cost) / predicted, -1.0)
        accept = rho > 0  # implies feasible, hence running
        rejected = running & ~accept
        mu[rejected] *= nu[rejected]
        nu[rejected] *= 2.0
        status[rejected & (mu > 1e16)] = _DAMPING
        if not accept.any():
            continue
        sa = step[accept]
        taken = accept[feasible]  # the accepted among the evaluated trials
        small = (np.abs(sa[:, :3]).max(axis=1) <= step_tolerance) & (
            np.sqrt(np.einsum("ki,ki->k", sa[:, 3:], sa[:, 3:])) <= step_tolerance * size[accept])
        R[accept], t[accept], p[accept], pivot[accept] = R_try[taken], t_try[taken], p_try[taken], pivot_try[taken]
        r[accept], J[accept] = r_try[taken], J_try[taken]
        new_cost = new_cost[taken]
        drop = cost[accept] - new_cost
        cost[accept] = new_cost
        mu[accept] = np.maximum(mu[accept] * np.maximum(1.0 / 3.0, 1.0 - (2.0 * rho[accept] - 1.0) ** 3), 1e-15)
        nu[accept] = 2.0
        ka = accept.nonzero()[0]
        status[ka[(drop <= cost_tolerance * new_cost) & ~small]] = _COST
        status[ka[small]] = _STEP
    status[status == _RUNNING] = _MAX_ITERATIONS
    # Re-orthonormalize against drift from many small exp() products.
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    return [RefineResult(R[k], t[k], p[k], float(cost[k]), float(initial_cost[k]), int(iterations[k]),
                         _STATUS_NAMES[status[k]]) for k in range(B)]


def _solve_batch(H: np.ndarray, b: np.ndarray, which: np.ndarray) -> np.ndarray:
    """Solve ``H x = b`` for the rows ``which`` (B,) bool of a batch (B, n, n), (B, n) of symmetric positive
    definite systems (LAPACK dposv, one call each: cheaper than a batched solve for a few starts); rows not
    asked for or not positive definite come back NaN."""
    out = np.full(b.shape, np.nan)
    for k in which.nonzero()[0]:
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
