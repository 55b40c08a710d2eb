"""Stage (c): Levenberg-Marquardt on the pixel-domain cost (paper, "Pixel-domain fine-tuning").

Residuals: ``K_:2 pi(R A_i p + t) - x_i`` for every click (pixels), then
``sqrt(lambda_px) W (d - mu)`` for the prior (``W`` the Cholesky factor of the inverse covariance).
Unknowns: a rotation increment ``delta`` (3,), ``t`` (3,) and ``p`` (P,). The rotation is updated on
SO(3) through the exponential map about a pivot ``c`` (the centroid of the clicked points, vehicle frame):
``R <- R exp([delta]x)``, ``t <- t + dt + (R_old - R_new) c``, so the Jacobian of ``Y_i = R X_i + t`` is
``-R [X_i - c]x`` for ``delta``, ``I`` for ``t`` and ``R A_i`` for ``p``.

The refinement is a problem (:class:`RefineProblem`) for the one Levenberg-Marquardt of :mod:`.lm`, which
states the damping and stopping rules. Its state is ``(R, t, p, pivot)``, (B, 3, 3), (B, 3), (B, P),
(B, 3): several starts refined in lockstep (:func:`levenberg_marquardt_batch`). Steps that put a clicked
point or the bottom centre behind the camera, make a dimension non-positive, or tilt an upright start past
the plausible bound, are infeasible. A start still far above the best one after a few iterations is
abandoned.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from toosicubix.geometry import hat, so3_exp
from toosicubix.solver import compiled, lm
from toosicubix.solver.problem import Problem

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
    problem has a ground plane, then 3 arrow rows per arrow (:meth:`Problem.arrow_rows`); the cue rows are
    multiplied by ``sqrt(lambda_px)`` (the upright rows by :attr:`.problem.Problem.upright_weight` times
    ``sigma_up``). Compiled where it can be (:func:`.compiled.residuals`: the same numbers), else numpy's."""
    found = compiled.residuals(problem, R, t, p, with_jacobian, pivot, profile_scale,
                               lambda: _residuals_numpy(problem, R, t, p, with_jacobian, pivot, profile_scale))
    if found is not None:
        return found
    return _residuals_numpy(problem, R, t, p, with_jacobian, pivot, profile_scale)


def _residuals_numpy(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray, with_jacobian: bool,
                     pivot: np.ndarray | None, profile_scale: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`residuals_batch` in numpy."""
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
    u_px = fx * xn + skew * yn  # (B, N): the x pixel less cx; its derivative over Y_z is -u_px / z
    v_px = fy * yn  # (B, N): the y pixel less cy; its derivative over Y_z is -v_px / z
    w = np.sqrt(problem.lambda_px)
    r = np.empty((B, 2 * N + m + n_up + n_arrow))
    r[:, 0:2 * N:2] = u_px + cx - problem.uv[:, 0]
    r[:, 1:2 * N:2] = v_px + cy - problem.uv[:, 1]
    a, b = problem.scale_terms(t, p)  # (B, m), (m,)
    if profile_scale:
        aa = np.einsum("ki,ki->k", a, a)
        s_best = (a @ b) / aa
        r[:, 2 * N:2 * N + m] = w * (s_best[:, None] * a - b)
    else:
        r[:, 2 * N:2 * N + m] = w * (a - b)
    if n_up:
        w_up = problem.upright_weight  # sqrt(lambda_px) / sigma_up, or the clicks' noise over it (keypoints)
        r[:, 2 * N + m:2 * N + m + n_up] = w_up * (R[:, :, 2] - problem.up)
    if n_arrow:
        arrow_r, arrow_gradient = problem.arrow_rows(R, t, p, pivot, with_jacobian)
        r[:, 2 * N + m + n_up:] = w * arrow_r
    row_weights = problem.pixel_row_weights
    if row_weights is not None:  # per-click weights (:mod:`.robust`) on the pixel rows
        r[:, 0:2 * N] *= row_weights
    if not with_jacobian:
        return r, None
    # D = d(pixel)/dY = [[fx/z, skew/z, -(fx x + skew y)/z], [0, fy/z, -fy y/z]], x, y normalized: (B, N, 2, 3),
    # written straight into the translation columns of J (its Jacobian for t).
    J = np.zeros((B, 2 * N + m + n_up + n_arrow, 6 + P))
    D = J[:, : 2 * N, 3:6].reshape(B, N, 2, 3)
    D[..., 0, 0] = fx * inv_z
    D[..., 0, 1] = skew * inv_z
    minus_inv_z = -inv_z
    D[..., 0, 2] = u_px * minus_inv_z
    D[..., 1, 1] = fy * inv_z
    D[..., 1, 2] = v_px * minus_inv_z
    DR = D @ R[:, None, :, :]  # (B, N, 2, 3)
    # Rotation columns: each row b of D R against dY = -R [X - c]x delta gives the row (X - c) x b.
    Xc = (X if pivot is None else X - pivot[:, None, :])[:, :, None, :]
    x0, x1, x2 = Xc[..., 0], Xc[..., 1], Xc[..., 2]
    d0, d1, d2 = DR[..., 0], DR[..., 1], DR[..., 2]
    J_rot = J[:, : 2 * N, 0:3].reshape(B, N, 2, 3)
    J_rot[..., 0] = x1 * d2 - x2 * d1
    J_rot[..., 1] = x2 * d0 - x0 * d2
    J_rot[..., 2] = x0 * d1 - x1 * d0
    J[:, : 2 * N, 6:] = (DR @ problem.A).reshape(B, 2 * N, P)
    if row_weights is not None:
        J[:, : 2 * N] *= row_weights[:, None]
    # Scale rows: a = G_t t + G_p p; turning about the pivot moves t by R [c]x delta.
    Ga = np.empty((B, m, 6 + P))
    Ga[:] = problem.scale_rows_jacobian
    if pivot is not None and problem.scale_rows_see_t:
        Ga[:, :, 0:3] = problem.G[:, :3] @ (R @ hat(pivot))
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
        J[:, 2 * N + m + n_up:] = w * arrow_gradient
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


def _at_prior_scale(problem: Problem, t: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Move each (t, p) of a batch, (B, 3) and (B, P), to the scale the cues prefer (when positive)."""
    a, b = problem.scale_terms(t, p)
    s = (a @ b) / np.einsum("ki,ki->k", a, a)
    s = np.where(s > 0, s, 1.0)[:, None]
    return s * t, s * p


def _pivots(problem: Problem, p: np.ndarray) -> np.ndarray:
    """Centroid of the clicked points in the vehicle frame for each ``p`` of a batch: (B, 3)."""
    return p @ problem.A_mean.T


class RefineProblem:
    """Stage (c) as a problem of :func:`.lm.levenberg_marquardt`: state ``(R, t, p, pivot)``, (B, 3, 3),
    (B, 3), (B, P), (B, 3); step ``(delta, dt, dp)`` (B, 6 + P).

    Update: ``R <- R exp([delta]x)``, ``t <- t + dt + (R_old - R_new) pivot`` (the turn is about the pivot),
    ``p <- p + dp``. The pixel rows do not change with the scale of ``(t, p)``; only the cues fix it, with a
    curvature far below the other directions' that damping would all but freeze. So the cue rows are profiled
    over the scale (their minimum over s), leaving an exact null direction, and every trial point is moved to
    its best scale (:meth:`settle`): the minimum is that of the plain cost.
    """

    def __init__(self, problem: Problem, max_tilt: float | None = None):
        self.problem = problem
        self.up = problem.up
        self.min_up = -np.inf if max_tilt is None else np.cos(max_tilt)
        self.may_tilt: np.ndarray | None = None
        self.size: np.ndarray | None = None

    def start(self, R: np.ndarray, t: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, ...]:
        """The state of B starts, (B, 3, 3), (B, 3), (B, P), at their best scale; fixes the starts' sizes
        (for the step test) and which of them stay upright (``R e_z . up`` no smaller than ``cos(max_tilt)``)."""
        t, p = _at_prior_scale(self.problem, np.array(t, dtype=float), np.array(p, dtype=float))
        self.size = np.sqrt(np.einsum("ki,ki->k", t, t)) + np.sqrt(np.einsum("ki,ki->k", p, p)) + 1.0
        self.may_tilt = ~(R[:, :, 2] @ self.up >= self.min_up)
        return R, t, p, _pivots(self.problem, p)

    def residuals(self, state: tuple[np.ndarray, ...], with_jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        R, t, p, pivot = state
        return residuals_batch(self.problem, R, t, p, with_jacobian, pivot, True)

    def update(self, state: tuple[np.ndarray, ...], step: np.ndarray) -> tuple[np.ndarray, ...]:
        R, t, p, pivot = state
        R_new = R @ so3_exp(step[:, :3])
        t_new = t + step[:, 3:6] + np.einsum("kij,kj->ki", R - R_new, pivot)
        return R_new, t_new, p + step[:, 6:], pivot  # the pivot is set anew by settle()

    def feasible(self, state: tuple[np.ndarray, ...]) -> np.ndarray:
        R, t, p, _ = state
        depths = self.problem.points_vehicle_batch(p) @ R[:, 2, :, None]
        return ((p[:, :3] > 0.0).all(axis=1) & (t[:, 2] > MIN_DEPTH)
                & (depths[..., 0].min(axis=1) + t[:, 2] > MIN_DEPTH)
                & (self.may_tilt | (R[:, :, 2] @ self.up >= self.min_up)))

    def settle(self, state: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
        R, t, p, _ = state
        t, p = _at_prior_scale(self.problem, t, p)
        return R, t, p, _pivots(self.problem, p)

    def step_is_small(self, step: np.ndarray, tolerance: float, starts: np.ndarray) -> np.ndarray:
        """The rotation moves by at most ``tolerance`` radians and ``(t, p)`` by at most that fraction of
        their size ``|t| + |p| + 1`` at the start."""
        return (np.abs(step[:, :3]).max(axis=1) <= tolerance) & (
            np.sqrt(np.einsum("ki,ki->k", step[:, 3:], step[:, 3:])) <= tolerance * self.size[starts])


def levenberg_marquardt_batch(problem: Problem, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray,
                              p: np.ndarray, max_iterations: int = 100, gradient_tolerance: float = 1e-6,
                              step_tolerance: float = 1e-10, cost_tolerance: float = 1e-8,
                              abandon_factor: float | None = None, abandon_after: int = 10,
                              abandon_above: float | None = None,
                              max_tilt: float | None = None) -> list[RefineResult]:
    """Levenberg-Marquardt (:func:`.lm.levenberg_marquardt` on a :class:`RefineProblem`) from several
    feasible starts at once.

    Parameters
    ----------
    R_cam_vehicle : (B, 3, 3); t_cam_vehicle : (B, 3); p : (B, P)
    gradient_tolerance, step_tolerance, cost_tolerance, abandon_factor, abandon_after, abandon_above : see
        :class:`.lm.LMOptions`; a step is small when it changes the rotation by at most ``step_tolerance``
        radians and ``t``, ``p`` by at most that fraction of their size
    max_tilt : radians; a start whose up axis leans less than this from the road normal (else the camera's
        up direction -y) never takes a step that leans it further (see :mod:`.plausibility`)

    Returns
    -------
    list of RefineResult, one per start
    """
    # Rotation increments turn the vehicle about the centroid of its clicked points, not its bottom centre:
    # that keeps rotation and translation nearly uncoupled, so the valley the steps follow is straighter.
    refine = RefineProblem(problem, max_tilt)
    state = refine.start(np.array(R_cam_vehicle, dtype=float), t_cam_vehicle, p)
    options = lm.LMOptions(max_iterations=max_iterations, gradient_tolerance=gradient_tolerance,
                        step_tolerance=step_tolerance, cost_tolerance=cost_tolerance, abandon_factor=abandon_factor,
                        abandon_after=abandon_after, abandon_above=abandon_above)
    result = compiled.levenberg_marquardt(refine, state, options)  # the same numbers, compiled; None: numpy's
    if result is None:
        result = lm.levenberg_marquardt(refine, state, options)
    R, t, p, _ = result.state
    # Re-orthonormalize against drift from many small exp() products.
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    return [RefineResult(R[k], t[k], p[k], float(result.cost[k]), float(result.initial_cost[k]),
                         int(result.iterations[k]), result.stopped[k]) for k in range(len(R))]


def levenberg_marquardt(problem: Problem, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray,
                        max_iterations: int = 100, **tolerances: float) -> RefineResult:
    """Levenberg-Marquardt from one feasible start; see :func:`levenberg_marquardt_batch`.

    Parameters
    ----------
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,); p : (P,)
    """
    return levenberg_marquardt_batch(problem, R_cam_vehicle[None], t_cam_vehicle[None], p[None],
                                     max_iterations, **tolerances)[0]
