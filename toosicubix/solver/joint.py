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
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.linalg import lapack

from toosicubix.model import GroundPlane
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


def _hat(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class _Joint:
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
                contact[0, o:o + 3] = w_c * (n @ (R[k] @ _hat(pivot)))
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

    def step(self, R, t, p, n, h, x):
        R2, t2, p2 = [], [], []
        for k, v in enumerate(self.vehicles):
            o = self.offsets[k]
            pivot = v.problem.A_mean @ p[k]
            Rk = R[k] @ cv2.Rodrigues(x[o:o + 3])[0]
            R2.append(Rk)
            t2.append(t[k] + x[o + 3:o + 6] + (R[k] - Rk) @ pivot)
            p2.append(p[k] + x[o + 6:o + self.sizes[k]])
        gh = self.offsets[-1]
        basis = _tangent_basis(n)
        n2 = cv2.Rodrigues(basis @ x[gh + 1:gh + 3])[0] @ n
        return R2, t2, p2, n2 / np.linalg.norm(n2), h + x[gh]

    def feasible(self, R, t, p) -> bool:
        for k, v in enumerate(self.vehicles):
            if np.any(p[k][:3] <= 0) or t[k][2] <= MIN_DEPTH or v.problem.min_depth(R[k], t[k], p[k]) <= MIN_DEPTH:
                return False
        return True


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
    joint = _Joint(vehicles, ground)
    R = [v.R_cam_vehicle.copy() for v in vehicles]
    t = [v.t_cam_vehicle.copy() for v in vehicles]
    p = [v.p.copy() for v in vehicles]
    n = ground.normal.copy()
    h = ground.camera_height if ground.camera_height is not None else float(np.median([-(n @ tk) for tk in t]))
    r, J = joint.evaluate(R, t, p, n, h)
    cost = float(r @ r)
    initial_cost = cost
    mu, nu = 1e-3, 2.0
    stopped, iterations = "max-iterations", 0
    while iterations < max_iterations:
        iterations += 1
        g = J.T @ r
        H = J.T @ J
        D = np.maximum(np.diag(H), 1e-12 * np.max(np.diag(H)))
        Hd = H + mu * np.diag(D)
        _, x, info = lapack.dposv(Hd, -g)
        if info != 0:
            mu *= nu
            nu *= 2.0
            continue
        R2, t2, p2, n2, h2 = joint.step(R, t, p, n, h, x)
        rho = -1.0
        if joint.feasible(R2, t2, p2):
            r2, _ = joint.evaluate(R2, t2, p2, n2, h2, with_jacobian=False)
            new_cost = float(r2 @ r2)
            predicted = -(2.0 * x @ g + x @ H @ x)
            rho = (cost - new_cost) / predicted if predicted > 0 else -1.0
        if rho > 0:
            R, t, p, n, h = R2, t2, p2, n2, h2
            r, J = joint.evaluate(R, t, p, n, h)
            drop = cost - new_cost
            cost = new_cost
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if drop <= cost_tolerance * cost:
                stopped = "cost"
                break
        else:
            mu *= nu
            nu *= 2.0
            if mu > 1e16:
                stopped = "damping"
                break
    return JointResult(R, t, p, n, h, cost, initial_cost, iterations, stopped)
