"""Joint fit of all vehicles of one image on one shared ground plane (issue "scale and ground cues").

Each vehicle is first fitted alone; then one Levenberg-Marquardt refinement moves all of them together
with the plane ``{X : n . X = -h}``: the camera height ``h`` and the normal ``n`` (two tangent parameters)
become unknowns shared by every vehicle. Rows, all cue rows weighed by ``sqrt(lambda_px)`` like the prior:

- per vehicle: its pixel residuals, its size prior and known sizes, upright ``(R e_z - n) / sigma_up``,
  ground contact ``(n . t + h) / sigma_c`` (``sigma_c``: the road's roughness, see ``ROAD_SIGMA``);
- for the plane: ``(n - n_0) / sigma_n`` and, when the camera height is given, ``(h - h_0) / sigma_h``.

With the height unknown, the vehicles' size priors fix it together: each vehicle's scale is tied to the
same ``h`` by its contact, so their size errors average out. A vehicle's rotation increment turns it about
the centroid of its clicked points, as in :mod:`.refine`.

The fit is a problem (:class:`JointProblem`) for the one Levenberg-Marquardt of :mod:`.lm`, a batch of one start
whose state is ``(R, t, p, n, h)``: (1, V, 3, 3), (1, V, 3), (1, sum P_k) (the vehicles' ``p`` one after
another), (1, 3), (1,).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from toosicubix.geometry import hat, so3_exp
from toosicubix.model import GroundPlane
from toosicubix.solver import lm
from toosicubix.solver.problem import Problem
from toosicubix.solver.refine import MIN_DEPTH, residuals_batch

#: How far a vehicle's ground may lie off the image's plane once that plane (its normal too) is estimated:
#: the road is not flat. KITTI tracking ground truth (sequences 0000-0009, images with 3 or more vehicles):
#: bottom centres lie 1.6 cm (median), 4 cm (rms) off the plane through the camera's foot fitted per image.
#: Metres, and radians times the distance for the road's bends farther away.
ROAD_SIGMA, ROAD_SLOPE_SIGMA = 0.05, 0.003


@dataclass(frozen=True)
class JointVehicle:
    """One vehicle in a joint fit: its problem (built without a ground plane) and its starting pose."""

    problem: Problem
    R_cam_vehicle: np.ndarray
    t_cam_vehicle: np.ndarray
    p: np.ndarray


@dataclass(frozen=True)
class JointResult:
    """The refined vehicles (poses in input order) and the plane.

    Attributes
    ----------
    R, t, p : lists of (3, 3), (3,), (P_k,)
    normal : (3,) unit; camera_height : metres
    cost : final cost; initial_cost : at the start; iterations; stopped : as in :mod:`.refine`
    """

    R: list[np.ndarray]
    t: list[np.ndarray]
    p: list[np.ndarray]
    normal: np.ndarray
    camera_height: float
    cost: float
    initial_cost: float
    iterations: int
    stopped: str


def _tangent_basis(n: np.ndarray) -> np.ndarray:
    """Two unit vectors orthogonal to ``n`` and to each other: (3, 2)."""
    other = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    b1 = np.cross(n, other)
    b1 /= np.linalg.norm(b1)
    return np.column_stack([b1, np.cross(n, b1)])


class JointProblem:
    """The joint fit as a problem of :func:`.lm.levenberg_marquardt` (see the module docstring): residuals and
    Jacobian (:meth:`evaluate`), update, feasibility (every vehicle's dimensions positive and its clicked
    points and bottom centre in front of the camera)."""

    def __init__(self, vehicles: list[JointVehicle], ground: GroundPlane):
        self.vehicles = vehicles
        self.ground = ground
        self.sizes = [6 + len(v.p) for v in vehicles]
        self.offsets = np.concatenate([[0], np.cumsum(self.sizes)])
        self.n_params = int(self.offsets[-1]) + 3  # + h and the normal's two tangent parameters
        self.w = np.sqrt(vehicles[0].problem.lambda_px)
        self.sigma_up = float(np.hypot(ground.upright_sigma, ground.normal_sigma))

    def contact_sigma(self, t: np.ndarray) -> float:
        # The normal is estimated here, so its own uncertainty does not widen the contact (as it does for one
        # vehicle on a fixed plane); only the road's roughness and bends do.
        return float(np.hypot(ROAD_SIGMA, ROAD_SLOPE_SIGMA * np.linalg.norm(t)))

    def evaluate(self, R, t, p, n, h, with_jacobian: bool = True):
        rows, jac_rows = [], []
        dn = np.column_stack([np.cross(b, n) for b in _tangent_basis(n).T])  # (3, 2): dn / d(tangent)
        gh = self.offsets[-1]  # column of h; then the normal's two
        for k, v in enumerate(self.vehicles):
            pivot = v.problem.A_mean @ p[k]
            r, J = residuals_batch(v.problem, R[k][None], t[k][None], p[k][None], with_jacobian, pivot[None], False)
            rows.append(r[0])
            o, size = self.offsets[k], self.sizes[k]
            if with_jacobian:
                block = np.zeros((len(r[0]), self.n_params))
                block[:, o:o + size] = J[0]
                jac_rows.append(block)
            # Upright: R e_z - n.
            w_up = self.w / self.sigma_up
            rows.append(w_up * (R[k][:, 2] - n))
            # Contact: n . t + h; turning about the pivot moves t by R [c]x delta.
            w_c = self.w / self.contact_sigma(t[k])
            rows.append(np.array([w_c * (n @ t[k] + h)]))
            if with_jacobian:
                up = np.zeros((3, self.n_params))
                up[:, o + 0] = -w_up * R[k][:, 1]
                up[:, o + 1] = w_up * R[k][:, 0]
                up[:, gh + 1:gh + 3] = -w_up * dn
                contact = np.zeros((1, self.n_params))
                contact[0, o:o + 3] = w_c * (n @ (R[k] @ hat(pivot)))
                contact[0, o + 3:o + 6] = w_c * n
                contact[0, gh] = w_c
                contact[0, gh + 1:gh + 3] = w_c * (t[k] @ dn)
                jac_rows += [up, contact]
        w_n = self.w / self.ground.normal_sigma
        rows.append(w_n * (n - self.ground.normal))
        if with_jacobian:
            block = np.zeros((3, self.n_params))
            block[:, gh + 1:gh + 3] = w_n * dn
            jac_rows.append(block)
        if self.ground.camera_height is not None:
            w_h = self.w / self.ground.camera_height_sigma
            rows.append(np.array([w_h * (h - self.ground.camera_height)]))
            if with_jacobian:
                block = np.zeros((1, self.n_params))
                block[0, gh] = w_h
                jac_rows.append(block)
        r = np.concatenate(rows)
        return r, (np.vstack(jac_rows) if with_jacobian else None)

    def split(self, state: tuple[np.ndarray, ...]) -> tuple[list, list, list, np.ndarray, float]:
        """The per-vehicle lists R, t, p and the plane ``n``, ``h`` of a state (a batch of one)."""
        R, t, p, n, h = state
        ends = np.cumsum([size - 6 for size in self.sizes])
        return list(R[0]), list(t[0]), np.split(p[0], ends[:-1]), n[0], float(h[0])

    def residuals(self, state: tuple[np.ndarray, ...], with_jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        r, J = self.evaluate(*self.split(state), with_jacobian=with_jacobian)
        return r[None], None if J is None else J[None]

    def update(self, state: tuple[np.ndarray, ...], step: np.ndarray) -> tuple[np.ndarray, ...]:
        """``R_k <- R_k exp([delta_k]x)`` about vehicle k's pivot, ``t_k``, ``p_k`` and ``h`` additive, and
        ``n <- exp([B s]x) n`` for the normal's tangent step ``s`` (``B`` the tangent basis at ``n``)."""
        R, t, p, n, h = state
        x = step[0]
        columns = [self.offsets[k] + np.arange(6, size) for k, size in enumerate(self.sizes)]
        delta = np.stack([x[o:o + 6] for o in self.offsets[:-1]])  # (V, 6)
        pivots = np.stack([v.problem.A_mean @ pk for v, pk in zip(self.vehicles, self.split(state)[2], strict=True)])
        R2 = R[0] @ so3_exp(delta[:, :3])
        t2 = t[0] + delta[:, 3:6] + np.einsum("kij,kj->ki", R[0] - R2, pivots)
        p2 = p[0] + x[np.concatenate(columns)]
        gh = self.offsets[-1]
        n2 = so3_exp(_tangent_basis(n[0]) @ x[gh + 1:gh + 3]) @ n[0]
        return R2[None], t2[None], p2[None], (n2 / np.linalg.norm(n2))[None], h + x[gh]

    def feasible(self, state: tuple[np.ndarray, ...]) -> np.ndarray:
        R, t, p, _, _ = self.split(state)
        for k, v in enumerate(self.vehicles):
            if np.any(p[k][:3] <= 0) or t[k][2] <= MIN_DEPTH or v.problem.min_depth(R[k], t[k], p[k]) <= MIN_DEPTH:
                return np.array([False])
        return np.array([True])

    def settle(self, state: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
        return state

    def step_is_small(self, step: np.ndarray, tolerance: float, starts: np.ndarray) -> np.ndarray:
        return np.abs(step).max(axis=1) <= tolerance


def fit_jointly(vehicles: list[JointVehicle], ground: GroundPlane, max_iterations: int = 100,
                cost_tolerance: float = 1e-10) -> JointResult:
    """Refine the vehicles of one image and their shared ground plane together.

    Parameters
    ----------
    vehicles : the image's fitted vehicles; their problems must not hold a ground plane (the plane is
        the joint unknown here)
    ground : the starting plane and its priors; ``camera_height`` None means unknown (then the starting
        height is the median of the vehicles' own)

    Returns
    -------
    JointResult
    """
    joint = JointProblem(vehicles, ground)
    n = ground.normal.copy()
    t = np.array([v.t_cam_vehicle for v in vehicles], dtype=float)
    h = ground.camera_height if ground.camera_height is not None else float(np.median([-(n @ tk) for tk in t]))
    state = (np.array([v.R_cam_vehicle for v in vehicles], dtype=float)[None], t[None],
             np.concatenate([v.p for v in vehicles]).astype(float)[None], n[None], np.array([h], dtype=float))
    # No gradient or step test: the joint fit stops on the cost's relative drop (or the damping, or the cap).
    options = lm.LMOptions(max_iterations=max_iterations, gradient_tolerance=0.0, step_tolerance=0.0,
                           cost_tolerance=cost_tolerance)
    result = lm.levenberg_marquardt(joint, state, options)
    R, t, p, n, h = joint.split(result.state)
    return JointResult(R, t, [pk.copy() for pk in p], n, h, float(result.cost[0]), float(result.initial_cost[0]),
                       int(result.iterations[0]), result.stopped[0])
