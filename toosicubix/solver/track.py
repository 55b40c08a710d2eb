"""One cuboid per track: a vehicle's pose in every frame of a video and one size, from clicks on some frames, 2D boxes
on others and nothing on the rest (issue 32; the paper's first future work).

Unknowns: the vehicle's size and the parameters every frame shares (``dx``, ``dy``, ``dz``, the axles ``Xwf``,
``Xwr`` and the hub height ``Zh``: :data:`SHARED`), and per frame its pose (``R_cam_vehicle``, ``t_cam_vehicle``) and
its clicks' own unknowns (a light pair's height, an arrow's place). Rows, all in the pixel cost's units (a cue's
standardized residual times ``sqrt(lambda_px)``, as :mod:`.problem` weighs the size prior):

- per frame with clicks: its pixel residuals and cues as one vehicle's (:func:`.refine.residuals_batch`: weighted
  clicks, known sizes, the ground contact and the upright term with a ground, the arrow zone), but the size prior,
  which the track has once;
- per frame with a 2D box (:class:`TrackFrame`): each side of the box the image border does not cut is where the
  projected cuboid's extreme corner lies (:func:`box_residuals`), within :attr:`TrackOptions.box_sigma`; on a road,
  the cuboid stood upright on it, so that a box sets the heading, position and size but not the lean (rule 28);
- per frame without clicks: the ground contact and the upright term when its image has a ground;
- the size prior, once, weighed as in each clicked frame fitted alone (its information times the number of clicked
  frames): real parts sit off the cuboid model by the same offsets in every frame (a tyre is as far inside the body
  in each), so the frames' clicks are not independent evidence on the shape, and the prior must keep the weight
  against them that it has against one frame's (rule 19b of benchmarks/decisions.md);
- the motion: a white-noise acceleration model at the frame rate (:class:`TrackOptions`). Between frames ``i - 1``,
  ``i``, ``i + 1`` at times ``tau`` (frame numbers over the frame rate; gaps allowed), the change of velocity
  ``(t_i+1 - t_i) / h_2 - (t_i - t_i-1) / h_1`` has the variance ``q (h_1 + h_2) / 2`` per camera axis, and the
  change of the rotation rate ``log(R_i^T R_i+1) / h_2 - log(R_i-1^T R_i) / h_1`` likewise per vehicle axis (a
  constant-velocity vehicle, turning at a constant rate, costs nothing: the poses between two clicked frames of such
  a vehicle are interpolated exactly); a weak prior on the velocity itself (:attr:`TrackOptions.speed_sigma`) keeps
  a track seen in one frame only defined.

The poses start where each clicked frame's own fit (:func:`toosicubix.solver.fit.fit_vehicle`) puts them, at the
track's size, the clicked frames' answers chosen among their minima to turn least from frame to frame (a
flipped keyframe would otherwise pull its neighbours round); frames between are interpolated (positions linearly,
rotations along the geodesic), frames before the first and after the last keep the nearest one's pose. Then one
Levenberg-Marquardt (Nielsen's damping, as :mod:`.lm`) on all of it, whose normal equations are a chain with a
border (:mod:`.blocks`): time and memory linear in the frames.

Uncertainty: the Laplace approximation, the marginal covariance of each frame's pose and the shared size from the
information matrix of the whitened rows (pixel rows over their noise, :func:`.uncertainty.row_sigmas`; cue, box and
motion rows standardized). Far from the clicked frames the motion model is all there is, and the sigmas grow.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from toosicubix.camera import Camera
from toosicubix.geometry import Z_NEAR, geodesic_angle, so3_exp, so3_log
from toosicubix.model import GroundPlane
from toosicubix.parts.linear import PartsModel, build_parts_model
from toosicubix.size_priors import SizePrior
from toosicubix.solver import lm
from toosicubix.solver.blocks import BlockArrow, NotPositiveDefinite
from toosicubix.solver.fallback import typical_p
from toosicubix.solver.fit import FitResult, SolverOptions, fit_vehicle
from toosicubix.solver.problem import Problem
from toosicubix.solver.refine import MIN_DEPTH, residuals_batch
from toosicubix.solver.robust import soft_weights, with_weights
from toosicubix.solver.uncertainty import Uncertainty, row_sigmas, uncertainty_from_covariance, ypr_gradient

#: The parameters one vehicle has in every frame: its size, its axles and its hub height.
SHARED = ("dx", "dy", "dz", "Xwf", "Xwr", "Zh")
#: Box sides within this many pixels of the image border are cut by it: they say nothing of the vehicle.
BORDER_PX = 1.0
#: A clicked frame too poorly clicked to be fitted alone is fitted with these settings for the track's start: a
#: direction its clicks leave free is the size prior's, three clicked points are enough.
RELAXED = {"min_constraints": 1, "rank_tolerance": 0.0}
#: The corners of the unit cuboid, as multiples of (dx, dy, dz) from the bottom centre: (8, 3).
_CORNERS = np.array([[sx * 0.5, sy * 0.5, sz] for sz in (0.0, 1.0) for sx in (1.0, -1.0) for sy in (1.0, -1.0)])


@dataclass(frozen=True)
class TrackOptions:
    """The track's motion model and box cue.

    Attributes
    ----------
    frame_rate : frames per second (frame numbers over it are the times the motion model runs on); KITTI's 10
    accel_sigma : (3,) the root of the white-noise acceleration's spectral density per camera axis (x right,
        y down, z forward), m s^-3/2
    angular_accel_sigma : (3,) the same for the rotation rate, per vehicle axis (roll about X, pitch about Y,
        yaw about Z), rad s^-3/2
    speed_sigma : m/s, a weak prior on the velocity relative to the camera (oncoming traffic is within it)
    angular_speed_sigma : rad/s, a weak prior on the rotation rate
    box_sigma_px, box_sigma_rel : a box side lies where the projected cuboid's extreme does within
        ``hypot(box_sigma_px, box_sigma_rel * size)`` pixels, ``size`` the box's width (for its left and right
        sides) or height (top, bottom): a person's box hugs the silhouette, inside the cuboid's corners
    max_iterations : of the Levenberg-Marquardt

    The defaults are rules 19 and 19a of benchmarks/decisions.md, fixed from the tuning sequences 0000-0009 of KITTI
    tracking before any track was fitted (``python benchmarks/tracks.py --motion-model``): the motion sigmas the root
    mean square of the ground truth's changes of velocity and of yaw rate over the root of the frame interval (9,357
    triples; pitch and roll take the yaw's), the speed priors their tracks' 99th percentiles; the box sigmas the
    simulated person's boxes against the projected cuboids (40,304 sides, offset^2 = a^2 + b^2 size^2 by least
    squares).
    """

    frame_rate: float = 10.0
    accel_sigma: tuple[float, float, float] = (1.45, 1.77, 2.07)
    angular_accel_sigma: tuple[float, float, float] = (0.177, 0.177, 0.177)
    speed_sigma: float = 30.5
    angular_speed_sigma: float = 0.525
    box_sigma_px: float = 1.71
    box_sigma_rel: float = 0.047
    max_iterations: int = 100


@dataclass(frozen=True)
class TrackFrame:
    """One frame of a track.

    Attributes
    ----------
    frame : its frame number (order and time: ``frame / frame_rate`` seconds)
    parts : the clicks on it (may be none)
    camera : its image's camera
    ground : its image's road plane, or None
    box2d : (4,) the 2D box drawn around the vehicle, distorted image pixels ``(x1, y1, x2, y2)``, or None
    """

    frame: int
    parts: PartsModel
    camera: Camera
    ground: GroundPlane | None = None
    box2d: np.ndarray | None = None


@dataclass(frozen=True)
class FrameFit:
    """The track's answer in one frame (the order of :func:`fit_track`'s ``frames``).

    Attributes
    ----------
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,); p : (P_f,) the frame's parameters, in its parts model's order
    pose_from : 'clicks' (clicked here), 'box' (only a 2D box here) or 'interpolated' (nothing here)
    residuals_px : (N, 2) projected minus clicked (undistorted) pixels; click_weights : (N,) or None
    box_residuals_px : (4,) the projected cuboid's extreme minus the box side, left, top, right, bottom (NaN for a
        side left out), or None without a box; the rows the fit used (on a road, the cuboid stood upright on it)
    uncertainty : its sigmas, from the track's marginal covariance, or None when it could not be computed
    cost : its share of the track's cost (its pixel and cue rows, not the motion's)
    single : the frame's own fit from its clicks alone, or None (no clicks, or too few)
    warnings : what the track's fit says of this frame (e.g. its clicks left out)
    """

    R_cam_vehicle: np.ndarray
    t_cam_vehicle: np.ndarray
    p: np.ndarray
    pose_from: str
    residuals_px: np.ndarray
    click_weights: np.ndarray | None
    box_residuals_px: np.ndarray | None
    uncertainty: Uncertainty | None
    cost: float
    single: FitResult | None = None
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class TrackFit:
    """A track's fit; ``frames`` is empty when ``status == 'failed'``.

    Attributes
    ----------
    dimensions : (3,) the track's one size; shared : the values of :data:`SHARED` present, by name
    cost, initial_cost : the joint cost at the end and at the start; iterations; stopped : as in :mod:`.lm`
    timings : seconds per stage
    """

    status: str
    reason: str | None
    frames: tuple[FrameFit, ...] = ()
    dimensions: np.ndarray | None = None
    shared: dict[str, float] = field(default_factory=dict)
    cost: float | None = None
    initial_cost: float | None = None
    iterations: int = 0
    stopped: str = ""
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == "ok"


# -- the 2D box as a cue ------------------------------------------------------------------------------------------


def box_sides_used(camera: Camera, box2d: np.ndarray) -> np.ndarray:
    """Which sides of a drawn box (left, top, right, bottom) are the vehicle's, not the image border's: (4,) bool.
    Without an image size every side is."""
    if camera.image_size is None:
        return np.ones(4, dtype=bool)
    w, h = camera.image_size
    x1, y1, x2, y2 = np.asarray(box2d, dtype=float)
    return np.array([x1 > BORDER_PX, y1 > BORDER_PX, x2 < w - 1.0 - BORDER_PX, y2 < h - 1.0 - BORDER_PX])


def undistorted_box(camera: Camera, box2d: np.ndarray) -> np.ndarray:
    """The box in the ideal pinhole camera's pixels, where the solver works: its four corners and four side midpoints
    undistorted, their extent (the box itself for a camera without distortion): (4,)."""
    x1, y1, x2, y2 = np.asarray(box2d, dtype=float)
    if not camera.has_distortion:
        return np.array([x1, y1, x2, y2])
    xm, ym = 0.5 * (x1 + x2), 0.5 * (y1 + y2)
    points = np.array([[x1, y1], [x2, y1], [x1, y2], [x2, y2], [xm, y1], [xm, y2], [x1, ym], [x2, ym]])
    u = camera.normalize(points)
    uv = u[:, :2] @ camera.K[:2, :2].T + camera.K[:2, 2]
    return np.array([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()])


def upright_on(R: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``R_cam_vehicle`` (3, 3) stood upright on a road whose normal is ``up`` (3,), camera frame: the rotation whose
    forward axis is ``R``'s projected onto the road plane and whose up axis is ``up`` (the heading kept, the lean
    dropped); and ``g`` (3,), the derivative of its heading about ``up`` on ``R``'s increment ``delta``
    (``R <- R exp([delta]x)``; its first component is 0: a roll leaves the forward axis where it is).

    ``R``'s forward axis must not be along ``up`` (a vehicle on its nose); the fits keep vehicles within 45 degrees of
    upright, far from it."""
    up = np.asarray(up, dtype=float)
    forward_on_road = R[:, 0] - (R[:, 0] @ up) * up
    length = float(np.linalg.norm(forward_on_road))
    h = forward_on_road / length
    left = np.cross(up, h)
    # d(forward) = delta_z R e_y - delta_y R e_z; its component along ``left`` over ``length`` turns the heading.
    g = np.array([0.0, -(left @ R[:, 2]), left @ R[:, 1]]) / length
    return np.column_stack([h, left, up]), g


def box_residuals(K: np.ndarray, box: np.ndarray, R: np.ndarray, t: np.ndarray, d: np.ndarray,
                  with_jacobian: bool = True, up: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The projected cuboid's extremes minus the box's sides: left, top, right, bottom (4,) pixels, and their
    Jacobian (4, 9) on ``(delta, t, d)`` (``R <- R exp([delta]x)``). ``box`` (4,) in the pinhole's pixels; every
    corner must lie in front of the camera.

    ``up`` (3,): the road's normal in the camera frame, when the image has a road. The cuboid is then projected
    standing upright on it (:func:`upright_on`): the box speaks to the heading, the position and the size, not to the
    lean (rule 28 of benchmarks/decisions.md). A box's sides move with the lean less than with the errors every side
    carries (the cuboid is not the silhouette, a person's box sits inside its corners, the size is a few per cent
    off), and least squares would spend the lean absorbing them; the clicks and the road's upright term set it."""
    g = None
    if up is not None:
        R, g = upright_on(R, up)
    X = _CORNERS * d  # (8, 3) vehicle frame
    Y = X @ R.T + t
    inv_z = 1.0 / Y[:, 2]
    u = K[0, 0] * Y[:, 0] * inv_z + K[0, 1] * Y[:, 1] * inv_z + K[0, 2]
    v = K[1, 1] * Y[:, 1] * inv_z + K[1, 2]
    corner = (int(np.argmin(u)), int(np.argmin(v)), int(np.argmax(u)), int(np.argmax(v)))
    value = np.array([u[corner[0]], v[corner[1]], u[corner[2]], v[corner[3]]])
    r = value - np.asarray(box, dtype=float)
    if not with_jacobian:
        return r, None
    J = np.zeros((4, 9))
    for side, (k, axis) in enumerate(zip(corner, (0, 1, 0, 1), strict=True)):
        z = Y[k, 2]
        if axis == 0:
            dY = np.array([K[0, 0] / z, K[0, 1] / z, -(u[k] - K[0, 2]) / z])
        else:
            dY = np.array([0.0, K[1, 1] / z, -(v[k] - K[1, 2]) / z])
        b = dY @ R  # the row of d(pixel)/dY R
        rotation = np.cross(X[k], b)  # dY = -R [X]x delta: the row (X x b)
        J[side, 0:3] = rotation if g is None else rotation[2] * g  # upright: only the heading turns it
        J[side, 3:6] = dY
        J[side, 6:9] = b * _CORNERS[k]
    return r, J


# -- the layout of the unknowns -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Layout:
    """Where each frame's parameters live: shared (:data:`SHARED`, the border) or the frame's own (after its pose in
    its block)."""

    shared: tuple[str, ...]
    to_shared: tuple[np.ndarray, ...]  # per frame (P_f,) the border index of each parameter, -1 when its own
    to_own: tuple[np.ndarray, ...]  # per frame (P_f,) the index in the frame's own unknowns, -1 when shared

    @classmethod
    def of(cls, models: list[PartsModel]) -> _Layout:
        present = {name for m in models for name in m.param_names}
        shared = tuple(name for name in SHARED if name in present or name in ("dx", "dy", "dz"))
        to_shared, to_own = [], []
        for m in models:
            s = np.array([shared.index(n) if n in shared else -1 for n in m.param_names])
            own = np.cumsum(s < 0) - 1
            to_shared.append(s)
            to_own.append(np.where(s < 0, own, -1))
        return cls(shared, tuple(to_shared), tuple(to_own))

    def n_own(self, f: int) -> int:
        return int(np.count_nonzero(self.to_shared[f] < 0))

    def p(self, f: int, shared: np.ndarray, own: np.ndarray) -> np.ndarray:
        """Frame ``f``'s parameter vector (P_f,) from the shared values and its own."""
        s, o = self.to_shared[f], self.to_own[f]
        out = np.empty(len(s))
        out[s >= 0] = shared[s[s >= 0]]
        out[o >= 0] = own[o[o >= 0]]
        return out

    def split(self, f: int, J_p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A Jacobian on frame ``f``'s parameters (m, P_f) as (m, n_own) on its own and (m, n_shared) on the border."""
        s = self.to_shared[f]
        own = J_p[:, s < 0]
        border = np.zeros((len(J_p), len(self.shared)))
        np.add.at(border.T, s[s >= 0], J_p[:, s >= 0].T)
        return own, border


# -- the track's least squares ------------------------------------------------------------------------------------


class _TrackProblem:
    """Residuals and normal equations of a track (see the module docstring). Frame ``f`` is unknown block ``f // 2``
    (two frames a block, so that the second differences, which tie three frames, tie neighbouring blocks only)."""

    def __init__(self, frames: list[TrackFrame], problems: list[Problem], layout: _Layout, prior: SizePrior,
                 lambda_px: float, options: TrackOptions, boxes: list[np.ndarray | None],
                 sides: list[np.ndarray | None]):
        self.frames, self.problems, self.layout, self.prior = frames, problems, layout, prior
        self.w = math.sqrt(lambda_px)
        # The size prior weighs as in each clicked frame fitted alone (see the module docstring).
        self.prior_sqrt_information = math.sqrt(max(1, sum(p.parts.n_clicks > 0 for p in problems))) * (
            prior.sqrt_information)
        self.options = options
        self.boxes, self.sides = boxes, sides
        self.F = len(frames)
        self.times = np.array([f.frame for f in frames], dtype=float) / options.frame_rate
        self.frame_sizes = [6 + layout.n_own(f) for f in range(self.F)]
        self.block_of = [f // 2 for f in range(self.F)]
        self.offset_in_block = [0 if f % 2 == 0 else self.frame_sizes[f - 1] for f in range(self.F)]
        self.block_sizes = [sum(self.frame_sizes[2 * k:2 * k + 2]) for k in range((self.F + 1) // 2)]
        self.n_shared = len(layout.shared)
        self.box_sigmas = [None if b is None else self._box_sigma(b) for b in boxes]
        # The road each frame's box rows stand the cuboid upright on (rule 28), None without a road.
        self.ups = [None if f.ground is None else np.asarray(f.ground.normal, dtype=float) for f in frames]

    def _box_sigma(self, box: np.ndarray) -> np.ndarray:
        width, height = box[2] - box[0], box[3] - box[1]
        size = np.array([width, height, width, height])
        return np.hypot(self.options.box_sigma_px, self.options.box_sigma_rel * size)

    # -- residual blocks, each with its frames and border Jacobians --------------------------------------------

    def _frame_rows(self, f: int, R: np.ndarray, t: np.ndarray, p: np.ndarray, jacobian: bool
                    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, int]:
        """Frame ``f``'s own rows (pixels and cues but the size prior, then its box's sides): residuals (m,), the
        Jacobian on its block (m, 6 + n_own) and on the border (m, n_shared), and how many are pixel rows."""
        problem = self.problems[f]
        r, J = residuals_batch(problem, R[None], t[None], p[None], jacobian, None, False)
        N2 = 2 * problem.parts.n_clicks
        keep = np.r_[0:N2, N2 + 3:r.shape[1]]  # the size prior's 3 rows are the track's, once
        r = r[0, keep]
        J = None if J is None else J[0][keep]
        box = self.boxes[f]
        if box is not None:
            rb, Jb = box_residuals(problem.K, box, R, t, p[:3], jacobian, self.ups[f])
            used = self.sides[f]
            scale = self.w / self.box_sigmas[f][used]
            r = np.concatenate([r, scale * rb[used]])
            if jacobian:
                Jbox = np.zeros((int(used.sum()), J.shape[1]))
                Jbox[:, :9] = scale[:, None] * Jb[used]  # (delta, t, d): d is p's first three
                J = np.concatenate([J, Jbox])
        if not jacobian:
            return r, None, None, N2
        own, border = self.layout.split(f, J[:, 6:])
        return r, np.concatenate([J[:, :6], own], axis=1), border, N2

    def _motion_rows(self, R: np.ndarray, t: np.ndarray) -> list[tuple[int, np.ndarray, list[tuple[int, np.ndarray]]]]:
        """The motion rows: ``(first frame, residuals (m,), [(frame, Jacobian (m, 6) on its pose), ...])``."""
        o = self.options
        out = []
        phi = [so3_log(R[i - 1].T @ R[i]) for i in range(1, self.F)]  # phi[i - 1]: from frame i - 1 to i
        h = np.diff(self.times)
        w_v = self.w / (o.speed_sigma * h)
        w_w = self.w / (o.angular_speed_sigma * h)
        for i in range(1, self.F):
            rel = R[i - 1].T @ R[i]
            r = np.concatenate([w_v[i - 1] * (t[i] - t[i - 1]), w_w[i - 1] * phi[i - 1]])
            J_prev, J_this = np.zeros((6, 6)), np.zeros((6, 6))
            J_prev[0:3, 3:6] = -w_v[i - 1] * np.eye(3)
            J_this[0:3, 3:6] = w_v[i - 1] * np.eye(3)
            J_prev[3:6, 0:3] = -w_w[i - 1] * rel.T
            J_this[3:6, 0:3] = w_w[i - 1] * np.eye(3)
            out.append((i - 1, r, [(i - 1, J_prev), (i, J_this)]))
        acc = np.asarray(o.accel_sigma, dtype=float)
        ang = np.asarray(o.angular_accel_sigma, dtype=float)
        for i in range(1, self.F - 1):
            h1, h2 = h[i - 1], h[i]
            root = np.sqrt(0.5 * (h1 + h2))
            w_t, w_r = self.w / (acc * root), self.w / (ang * root)
            r_t = w_t * ((t[i + 1] - t[i]) / h2 - (t[i] - t[i - 1]) / h1)
            r_r = w_r * (phi[i] / h2 - phi[i - 1] / h1)
            J = {i - 1: np.zeros((6, 6)), i: np.zeros((6, 6)), i + 1: np.zeros((6, 6))}
            J[i + 1][0:3, 3:6] = np.diag(w_t / h2)
            J[i][0:3, 3:6] = -np.diag(w_t * (1.0 / h2 + 1.0 / h1))
            J[i - 1][0:3, 3:6] = np.diag(w_t / h1)
            # phi_i (i -> i+1) moves by delta_i+1 - rel_i^T delta_i, phi_i-1 by delta_i - rel_i-1^T delta_i-1.
            rel_next, rel_prev = R[i].T @ R[i + 1], R[i - 1].T @ R[i]
            J[i + 1][3:6, 0:3] = w_r[:, None] * np.eye(3) / h2
            J[i][3:6, 0:3] = w_r[:, None] * (-rel_next.T / h2 - np.eye(3) / h1)
            J[i - 1][3:6, 0:3] = w_r[:, None] * rel_prev.T / h1
            out.append((i - 1, np.concatenate([r_t, r_r]), sorted(J.items())))
        return out

    def evaluate(self, state: tuple, jacobian: bool) -> tuple[float, BlockArrow | None, list[float]]:
        """The cost, the normal equations (when ``jacobian``) and each frame's share of the cost."""
        R, t, shared, own = state
        system = BlockArrow(self.block_sizes, self.n_shared) if jacobian else None
        cost, shares = 0.0, []
        for f in range(self.F):
            p = self.layout.p(f, shared, own[f])
            r, J_frame, J_border, _ = self._frame_rows(f, R[f], t[f], p, jacobian)
            shares.append(float(r @ r))
            cost += shares[-1]
            if system is not None:
                self._add(system, r, [(f, J_frame)], J_border)
        prior_r = self.w * (self.prior_sqrt_information @ (shared[:3] - self.prior.mean))
        cost += float(prior_r @ prior_r)
        if system is not None:
            J_border = np.zeros((3, self.n_shared))
            J_border[:, :3] = self.w * self.prior_sqrt_information
            system.C += J_border.T @ J_border
            system.g_border += J_border.T @ prior_r
        for _, r, pieces in self._motion_rows(R, t):
            cost += float(r @ r)
            if system is not None:
                self._add(system, r, [(f, np.concatenate([J, np.zeros((len(J), self.frame_sizes[f] - 6))], axis=1))
                                      for f, J in pieces], None)
        return cost, system, shares

    def _add(self, system: BlockArrow, r: np.ndarray, pieces: list[tuple[int, np.ndarray]],
             J_border: np.ndarray | None) -> None:
        """Place frame Jacobians (m, frame size) into their blocks (at most two neighbouring blocks) and add."""
        blocks = sorted({self.block_of[f] for f, _ in pieces})
        first = blocks[0]
        J_blocks = {k: np.zeros((len(r), self.block_sizes[k])) for k in blocks}
        for f, J in pieces:
            o = self.offset_in_block[f]
            J_blocks[self.block_of[f]][:, o:o + self.frame_sizes[f]] += J
        system.add(r, first, J_blocks[first], J_blocks.get(first + 1), J_border)

    # -- the step ---------------------------------------------------------------------------------------------

    def update(self, state: tuple, chain: list[np.ndarray], border: np.ndarray) -> tuple:
        R, t, shared, own = state
        R_new, t_new, own_new = R.copy(), t.copy(), [o.copy() for o in own]
        for f in range(self.F):
            o = self.offset_in_block[f]
            step = chain[self.block_of[f]][o:o + self.frame_sizes[f]]
            R_new[f] = R[f] @ so3_exp(step[:3])
            t_new[f] = t[f] + step[3:6]
            own_new[f] = own[f] + step[6:]
        return R_new, t_new, shared + border, own_new

    def feasible(self, state: tuple) -> bool:
        R, t, shared, own = state
        if not np.all(shared[:3] > 0.0) or not np.all(np.isfinite(shared)):
            return False
        for f in range(self.F):
            if t[f][2] <= MIN_DEPTH:
                return False
            problem = self.problems[f]
            if problem.parts.n_clicks:
                z = problem.points_cam(R[f], t[f], self.layout.p(f, shared, own[f]))[:, 2]
                if z.min() <= MIN_DEPTH:
                    return False
            if self.boxes[f] is not None and ((_CORNERS * shared[:3]) @ R[f][2] + t[f][2]).min() <= Z_NEAR:
                return False
        return True

    def whitened(self, state: tuple, click_sigma: float, part_sigma: float,
                 soft_noise: tuple[float, float] | None = None) -> BlockArrow:
        """The information matrix: the rows' Jacobians over their noise (pixel rows over
        :func:`.uncertainty.row_sigmas`, every other row standardized)."""
        R, t, shared, own = state
        system = BlockArrow(self.block_sizes, self.n_shared)
        for f in range(self.F):
            p = self.layout.p(f, shared, own[f])
            r, J_frame, J_border, N2 = self._frame_rows(f, R[f], t[f], p, True)
            scale = np.full(len(r), 1.0 / self.w)
            if N2:  # weighted pixel rows over their noise (a keypoint's weight already carries its spread)
                scale[:N2] = 1.0 / row_sigmas(self.problems[f], R[f], t[f], p, click_sigma, part_sigma, soft_noise)
            self._add(system, scale * r, [(f, scale[:, None] * J_frame)], scale[:, None] * J_border)
        J_border = np.zeros((3, self.n_shared))
        J_border[:, :3] = self.prior_sqrt_information
        system.C += J_border.T @ J_border
        for _, r, pieces in self._motion_rows(R, t):
            self._add(system, r / self.w, [(f, np.concatenate([J / self.w, np.zeros((len(J), self.frame_sizes[f] - 6))],
                                                             axis=1)) for f, J in pieces], None)
        return system


def _levenberg_marquardt(problem: _TrackProblem, state: tuple, max_iterations: int,
                         tolerance: float = 1e-10) -> tuple[tuple, float, float, int, str]:
    """Levenberg-Marquardt on the track (one start; Nielsen's damping, :func:`.lm.gain_ratio` and
    :func:`.lm.damping_after_success`): the final state, its cost, the initial cost, iterations, why it stopped."""
    cost, system, _ = problem.evaluate(state, True)
    initial = cost
    mu, nu = 1e-3, 2.0
    for iteration in range(1, max_iterations + 1):
        diag_chain, diag_border = system.diagonal()
        g = np.concatenate([*system.g, system.g_border])
        scale = np.sqrt(np.maximum(np.concatenate([*diag_chain, diag_border]), 1e-300))
        if np.max(np.abs(g) / scale) <= 1e-9 * math.sqrt(max(cost, 1e-300)):
            return state, cost, initial, iteration - 1, "gradient"
        try:
            chain, border = system.solve(mu)
        except NotPositiveDefinite:
            chain = None
        if chain is not None:
            step = np.concatenate([*chain, border])
            trial = problem.update(state, chain, border)
            if problem.feasible(trial):
                new_cost, new_system, _ = problem.evaluate(trial, True)
                damped = np.concatenate([mu * np.maximum(d, 1e-12) for d in (*diag_chain, diag_border)]) * step - g
                rho = float(lm.gain_ratio(step[None], damped[None], np.array([cost]), np.array([new_cost]))[0])
                if rho > 0:
                    drop = cost - new_cost
                    state, cost, system = trial, new_cost, new_system
                    mu = float(lm.damping_after_success(np.array([mu]), np.array([rho]))[0])
                    nu = 2.0
                    if np.max(np.abs(step)) <= tolerance * (1.0 + np.max(np.abs(np.concatenate(
                            [state[1].ravel(), state[2]])))):
                        return state, cost, initial, iteration, "step"
                    if drop <= 1e-10 * new_cost:
                        return state, cost, initial, iteration, "cost"
                    continue
        mu *= nu
        nu *= 2.0
        if mu > 1e16:
            return state, cost, initial, iteration, "damping"
    return state, cost, initial, max_iterations, "max-iterations"


# -- starts ---------------------------------------------------------------------------------------------------------


def _consistent_rotations(fits: dict[int, FitResult], times: np.ndarray, lambda_px: float
                          ) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per fitted frame, the pose ``(R, t, dimensions)`` among its own answer and its close, plausible alternatives
    that turns least between consecutive fitted frames (a Viterbi pass): a cost of ``(angle / (0.3 rad per second
    between them, at least 0.1 rad))^2`` per pair, plus each alternative's extra cost over ``lambda_px``."""
    order = sorted(fits)
    options = []
    for f in order:
        fit = fits[f]
        own = [(fit.R_cam_vehicle, fit.t_cam_vehicle, fit.dimensions, 0.0)]
        size, distance = float(np.linalg.norm(fit.dimensions)), float(np.linalg.norm(fit.t_cam_vehicle))
        own += [(a.R_cam_vehicle, a.t_cam_vehicle, a.dimensions, max(a.cost - fit.cost, 0.0) / lambda_px)
                for a in fit.alternatives if a.close and a.implausible is None and np.all(a.dimensions > 0)
                and 0.5 <= float(np.linalg.norm(a.dimensions)) / size <= 2.0  # the turn, not another size ...
                and 0.5 <= float(np.linalg.norm(a.t_cam_vehicle)) / distance <= 2.0]  # ... or another distance
        options.append(own)
    best = [np.array([c for *_, c in options[0]])]
    back: list[np.ndarray] = []
    for j in range(1, len(order)):
        gap = max(abs(times[order[j]] - times[order[j - 1]]), 1e-3)
        sigma = max(0.3 * gap, 0.1)
        step = np.array([[geodesic_angle(a[0], b[0]) ** 2 / sigma**2 for a in options[j - 1]] for b in options[j]])
        total = best[-1][None, :] + step  # (now, before)
        back.append(np.argmin(total, axis=1))
        best.append(total.min(axis=1) + np.array([c for *_, c in options[j]]))
    pick = [int(np.argmin(best[-1]))]
    for j in range(len(order) - 1, 0, -1):
        pick.append(int(back[j - 1][pick[-1]]))
    pick.reverse()
    return {f: options[j][pick[j]][:3] for j, f in enumerate(order)}


#: A frame's own fit lying farther than this share of its distance (or of the predicted one, the smaller) from where
#: the track's other starts put it (by
#: :func:`_interpolated`) is not a start: one vehicle's fit from poor clicks can be off in depth several times over
#: (its scale is the prior's alone), where its neighbours' are within some 10 %.
OUTLYING_START = 0.25


def _without_outlying_starts(known: dict[int, tuple[np.ndarray, np.ndarray]], times: np.ndarray
                             ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """The starts without those that lie far from the others (:data:`OUTLYING_START`), dropped one at a time, worst
    first, while at least three are left: each compared with the others' positions linearly inter- or extrapolated
    to its time (a start poisoned by one gross outlier interpolates it into its neighbours' frames)."""
    known = dict(known)
    while len(known) >= 3:
        worst, worst_off = None, OUTLYING_START
        for f in known:
            others = {k: v for k, v in known.items() if k != f}
            predicted = _linear_position(times, others, f)
            off = np.linalg.norm(known[f][1] - predicted) / min(np.linalg.norm(known[f][1]), np.linalg.norm(predicted))
            if off > worst_off:
                worst, worst_off = f, off
        if worst is None:
            break
        del known[worst]
    return known


def _linear_position(times: np.ndarray, known: dict[int, tuple[np.ndarray, np.ndarray]], f: int) -> np.ndarray:
    """The position at frame ``f`` on the least-squares line (position against time) through the four known frames
    nearest to it in time (as many as there are, at least two)."""
    nearest = sorted(known, key=lambda k: abs(times[k] - times[f]))[:4]
    tau = times[nearest] - times[f]
    positions = np.array([known[k][1] for k in nearest])
    A = np.column_stack([np.ones(len(tau)), tau])
    coefficients, *_ = np.linalg.lstsq(A, positions, rcond=None)
    return coefficients[0]  # the line's value at tau = 0


def _interpolated(times: np.ndarray, known: dict[int, tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Poses (F, 3, 3), (F, 3) for every frame: the known ones, linear positions and geodesic rotations between
    them, the nearest one's outside them."""
    F = len(times)
    order = sorted(known)
    R, t = np.zeros((F, 3, 3)), np.zeros((F, 3))
    for f in range(F):
        after = [k for k in order if k >= f]
        before = [k for k in order if k <= f]
        if not before or not after:
            k = after[0] if not before else before[-1]
            R[f], t[f] = known[k]
            continue
        a, b = before[-1], after[0]
        if a == b:
            R[f], t[f] = known[a]
            continue
        s = (times[f] - times[a]) / (times[b] - times[a])
        Ra, ta = known[a]
        Rb, tb = known[b]
        R[f] = Ra @ so3_exp(s * so3_log(Ra.T @ Rb))
        t[f] = (1.0 - s) * ta + s * tb
    return R, t


# -- the fit --------------------------------------------------------------------------------------------------------


def fit_track(frames: list[TrackFrame], prior: SizePrior, options: SolverOptions | None = None,
              track_options: TrackOptions | None = None, singles: dict[int, FitResult] | None = None) -> TrackFit:
    """Fit one track: a pose per frame and one size (see the module docstring).

    Parameters
    ----------
    frames : the track's frames, in any order (the results follow it)
    prior : the size prior of its prototype
    options : the solver's settings (each clicked frame's own fit, the weights, the click noise)
    track_options : the motion model and the box cue
    singles : frames' own fits already made, by their position in ``frames`` (the others with clicks are fitted)

    Returns
    -------
    TrackFit
        ``status='failed'`` with a reason when no frame's clicks fix a cuboid on their own (the track needs one
        such frame to start from); never raises for bad geometry.
    """
    options = options or SolverOptions()
    track_options = track_options or TrackOptions()
    started = time.perf_counter()
    order = sorted(range(len(frames)), key=lambda i: frames[i].frame)
    given = singles or {}
    frames = [frames[i] for i in order]
    times = np.array([f.frame for f in frames], dtype=float) / track_options.frame_rate
    singles, relaxed = {}, {}
    for f, frame in enumerate(frames):
        if frame.parts.n_clicks:
            fit = given.get(order[f]) or fit_vehicle(frame.parts, frame.camera, prior, options, frame.ground)
            if fit.ok:
                singles[f] = fit
            elif frame.parts.n_clicks >= 3:
                # Clicks too few or too poor to place a vehicle on their own (a rear view leaves its length to the
                # prior) still place it with the track's other frames: such a frame's own answer, with the prior
                # filling what its clicks leave free, is a start (and its unknowns' start), never an answer alone.
                fit = fit_vehicle(frame.parts, frame.camera, prior, replace(options, **RELAXED), frame.ground)
                if fit.ok:
                    relaxed[f] = fit
    t_single = time.perf_counter()
    if not singles:
        singles = relaxed
    if not singles:
        clicked = sum(1 for frame in frames if frame.parts.n_clicks)
        why = ("no frame has clicks" if not clicked else
               f"none of its {clicked} clicked frame(s) places a cuboid from its own clicks, even with the size prior "
               "filling what they leave free")
        return TrackFit("failed", f"the track cannot be placed: {why}; click one frame as fully as a vehicle fitted "
                                  "alone (its other frames may keep a box only, or nothing)",
                        timings={"single": t_single - started})
    starts = {**relaxed, **singles}  # every frame's own answer, for its own unknowns' start
    chosen = _consistent_rotations(singles, times, options.lambda_px)
    dims = np.median(np.array([d for _, _, d in chosen.values()]), axis=0)
    known = {}
    for f, (R, t, d) in chosen.items():
        known[f] = (R, t * float(np.linalg.norm(dims) / np.linalg.norm(d)))  # at the track's one size
    known = _without_outlying_starts(known, times)
    R0, t0 = _interpolated(times, known)

    # Each clicked frame's unknowns start at its own fit's values, else at their typical places on the track's cuboid;
    # a frame whose clicks would then lie behind the camera at the track's start is not clicked, for the track.
    track_prior = SizePrior.from_mean_cov(prior.prototype, dims, prior.cov)
    start_p, dropped = [], set()
    for f, frame in enumerate(frames):
        if not frame.parts.n_clicks:
            start_p.append(dims.copy())
            continue
        probe = Problem.build(frame.parts, frame.camera, track_prior, options.lambda_3d, options.lambda_px)
        fit = starts.get(f)
        p = fit.p.copy() if fit is not None else typical_p(probe)
        p[:3] = dims
        if probe.min_depth(R0[f], t0[f], p) <= MIN_DEPTH:
            dropped.add(f)
            frames[f] = TrackFrame(frame.frame, build_parts_model(()), frame.camera, frame.ground, frame.box2d)
            p = dims.copy()
        start_p.append(p)
    models = [frame.parts for frame in frames]
    layout = _Layout.of(models)
    shared = np.zeros(len(layout.shared))
    shared[:3] = dims
    for j, name in enumerate(layout.shared[3:], start=3):
        values = [singles[f].p[list(models[f].param_names).index(name)] for f in singles
                  if name in models[f].param_names]
        shared[j] = float(np.median(values)) if values else (
            {"Xwf": 0.3, "Xwr": -0.3}.get(name, 0.0) * dims[0] if name != "Zh" else 0.35)
    own = []
    problems = []
    for f, frame in enumerate(frames):
        problem = Problem.build(frame.parts, frame.camera, prior, options.lambda_3d, options.lambda_px, frame.ground,
                                float(np.linalg.norm(t0[f])))
        fit = starts.get(f)
        mine = layout.to_own[f] >= 0
        values = np.zeros(layout.n_own(f))
        values[layout.to_own[f][mine]] = start_p[f][mine]
        if frame.parts.n_clicks:
            weights = fit.click_weights if fit is not None else soft_weights(problem, float(np.linalg.norm(t0[f])),
                                                                             options.click_sigma)
            problem = with_weights(problem, weights)
            if frame.parts.click_spread is not None and options.upright_weight == "clicks":  # as a frame alone
                problem = problem.upright_against_clicks(options.click_sigma)
        problems.append(problem)
        own.append(values)
    boxes, sides = [], []
    for f, frame in enumerate(frames):
        if frame.box2d is None:
            boxes.append(None)
            sides.append(None)
            continue
        used = box_sides_used(frame.camera, frame.box2d)
        corners_z = (_CORNERS * dims) @ R0[f][2] + t0[f][2]
        if not used.any() or corners_z.min() <= Z_NEAR:
            boxes.append(None)
            sides.append(None)
            continue
        boxes.append(undistorted_box(frame.camera, frame.box2d))
        sides.append(used)
    problem = _TrackProblem(frames, problems, layout, prior, options.lambda_px, track_options, boxes, sides)
    state = (R0, t0, shared, own)
    if not problem.feasible(state):  # not expected: the clicks and boxes that would be are left out above
        why = ("the track's frames cannot be joined into one motion in front of the camera: check that every "
               "frame's clicks are on the same vehicle, named as its driver sees it")
        return TrackFit("failed", why,
                        timings={"single": t_single - started})
    state, cost, initial, iterations, stopped = _levenberg_marquardt(problem, state, track_options.max_iterations)
    t_joint = time.perf_counter()
    R, t, shared, own = state
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    state = (R, t, shared, own)
    _, _, shares = problem.evaluate(state, False)
    marginals = None
    try:
        marginals = problem.whitened(state, options.click_sigma, options.part_sigma, options.soft_noise).marginals()
    except NotPositiveDefinite:
        pass
    out = []
    for f, frame in enumerate(frames):
        p = layout.p(f, shared, own[f])
        pixel = problems[f].pixel_residuals(R[f], t[f], p) if frame.parts.n_clicks else np.zeros((0, 2))
        box_r = None
        if boxes[f] is not None:
            rb, _ = box_residuals(problems[f].K, boxes[f], R[f], t[f], p[:3], False, problem.ups[f])
            box_r = np.where(sides[f], rb, np.nan)
        uncertainty = None if marginals is None else _frame_uncertainty(marginals, problem, f, R[f], t[f])
        pose_from = "clicks" if frame.parts.n_clicks else "box" if boxes[f] is not None else "interpolated"
        warnings = ("its clicks are left out of the track's fit: at the track's start (interpolated from the frames "
                    "its clicks fixed) they would lie behind the camera",) if f in dropped else ()
        out.append(FrameFit(R[f], t[f], p, pose_from, pixel, problems[f].click_weights, box_r, uncertainty,
                            shares[f], singles.get(f), warnings))
    inverse = np.argsort(order)
    named = {name: float(v) for name, v in zip(layout.shared, shared, strict=True)}
    return TrackFit("ok", None, tuple(out[i] for i in inverse), shared[:3].copy(), named, cost, initial, iterations,
                    stopped, {"single": t_single - started, "joint": t_joint - t_single,
                              "total": time.perf_counter() - started})


def _frame_uncertainty(marginals: tuple, problem: _TrackProblem, f: int, R: np.ndarray, t: np.ndarray
                       ) -> Uncertainty:
    """Frame ``f``'s :class:`.uncertainty.Uncertainty` from the track's marginals: the covariance of its rotation
    increment, translation and size (the shared ``dx, dy, dz``) assembled from its block, the border and their
    cross block."""
    chain, cross, border = marginals
    k, o = problem.block_of[f], problem.offset_in_block[f]
    pose = chain[k][o:o + 6, o:o + 6]
    pose_size = cross[k][o:o + 6, :3]
    cov = np.zeros((9, 9))
    cov[:6, :6] = pose
    cov[:6, 6:] = pose_size
    cov[6:, :6] = pose_size.T
    cov[6:, 6:] = border[:3, :3]
    return uncertainty_from_covariance(cov, ypr_gradient(R), t)


def with_box_cue(fit: FitResult, parts: PartsModel, camera: Camera, prior: SizePrior, options: SolverOptions,
                 ground: GroundPlane | None, box2d: np.ndarray, track_options: TrackOptions | None = None) -> FitResult:
    """One vehicle's fit refined with its 2D box as a cue (``fit --box-cue``): a track of one frame, started at
    ``fit`` (its own answer from the clicks). The pose, size, residuals and sigmas are the refined ones; the rest
    (alternatives, observability, the solver's statistics) stay ``fit``'s. ``fit`` itself when it failed, or when the
    box adds nothing (every side on the image border, or the cuboid reaching behind the camera)."""
    if not fit.ok:
        return fit
    track = fit_track([TrackFrame(0, parts, camera, ground, np.asarray(box2d, dtype=float))], prior, options,
                      track_options, singles={0: fit})
    if not track.ok or track.frames[0].box_residuals_px is None:
        return fit
    frame = track.frames[0]
    return replace(fit, R_cam_vehicle=frame.R_cam_vehicle, t_cam_vehicle=frame.t_cam_vehicle, p=frame.p,
                   cost=track.cost, residuals_px=frame.residuals_px,
                   uncertainty=frame.uncertainty if frame.uncertainty is not None else fit.uncertainty,
                   refine_iterations=fit.refine_iterations + track.iterations)

