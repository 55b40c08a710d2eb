"""Names for clicks before a fit exists: the prototype's size-prior cuboid, stood upright on the road and placed from
the vehicle's 2D box and the clicks named so far, proposes the few names that fit where a new click is.

For every yaw of a sweep (:attr:`NamingSettings.yaw_steps` about the road's normal) and every candidate name of the
new click, the prior cuboid (the prototype's mean dimensions) is placed by Gauss-Newton on its translation: each named
click against its part's typical place (the vocabulary's ``typical``) within that part's spread (:data:`SPREADS`:
where on the body people click it, plus the size prior's uncertainty, projected into the image at its depth, plus the
click noise), the box's sides against the cuboid's extremes (:func:`toosicubix.solver.track.box_residuals`' sigmas),
and the camera's height above the road (the image's ground block, else :attr:`NamingSettings.camera_height_m`, a
car-mounted camera's). A placement that would put a clicked part on a face turned away from the camera, or the
cuboid behind it, is ruled out. A candidate's probability is its placements' likelihood (with each click's Gaussian
normalisation, so that a part clicked anywhere on a long edge weighs less than a wheel's point) summed over the
yaws, the yaws and names equally likely beforehand.

Only the vocabulary's point parts are proposed (each click of a symmetric pair or an arrow needs its partner, and a
keypoint mapping's keypoints are named once a fit exists, :mod:`toosicubix.web.naming`); symmetric pairs count as
evidence, arrows, hubs and keypoints do not (they have no typical place of their own).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from toosicubix import vocabulary
from toosicubix.camera import Camera
from toosicubix.geometry import R_cam_vehicle_from_ypr, rotation_between
from toosicubix.model import GroundPlane
from toosicubix.size_priors import SizePrior
from toosicubix.solver.track import TrackOptions

__all__ = ["NAMING_SETTINGS", "OUTLIER_MAHALANOBIS2", "SPREADS", "NamingSettings", "Proposal", "candidate_names",
           "propose"]


@dataclass(frozen=True)
class NamingSettings:
    """How the page names a click before a fit exists (benchmarks/decisions.md, rule 24a).

    Attributes
    ----------
    camera_height_m, camera_height_sigma_m : the camera's height above the road assumed for an image without a
        ground block of its own (a car-mounted camera's), metres; sigma None: no height assumed
    confidence : the page names a click when its most probable name has at least this probability, else it asks
        (offering the most probable few)
    after_fit : once the vehicle's named clicks fit a cuboid, 'prior': name by the same placement with the fit's
        dimensions (and their sigmas) for the prior's; 'fit': the nearest part not clicked yet at its typical place
        on the fit (:func:`toosicubix.web.naming.nearest_parts`, the page's rule before issue 33; always sure)
    yaw_steps : the yaws tried, evenly over the full turn
    """

    camera_height_m: float = 1.5
    camera_height_sigma_m: float | None = 1.0
    confidence: float = 0.5
    after_fit: str = "prior"
    yaw_steps: int = 72

    def __post_init__(self) -> None:
        if self.after_fit not in ("prior", "fit"):
            raise ValueError(f"after_fit: expected 'prior' or 'fit', got {self.after_fit!r}")

    def to_json(self) -> dict:
        return asdict(self)


#: The page's naming settings.
NAMING_SETTINGS = NamingSettings()

#: Where people click each kind of part around its typical place, standard deviations along the vehicle's X, Y, Z:
#: ``(fraction of dx, fraction of dy, fraction of dz, metres)`` per axis, added in quadrature. Wheels: the axle's
#: place along the body (overhangs vary) and the tyre's outer face a few cm inside the body; edges: anywhere along
#: the vertical edge (uniform over its height, dz / sqrt(12)), a rounded corner 5-20 cm inside; badges and plates:
#: on the centre line at 30-55 % of the height, set back a little; the roof's centre: anywhere along its length;
#: corners: within a few cm; a light pair: set back, across and up by what lamps vary.
SPREADS: dict[str, tuple[tuple[float, float, float, float], ...]] = {
    "wheel": ((0.04, 0, 0, 0), (0, 0, 0, 0.03), (0, 0, 0, 0.02)),
    "edge": ((0, 0, 0, 0.06), (0, 0, 0, 0.06), (0, 0, 1 / math.sqrt(12), 0)),
    "end-center": ((0, 0, 0, 0.08), (0, 0, 0, 0.03), (0, 0, 0.15, 0)),
    "top-center": ((0.2, 0, 0, 0), (0, 0, 0, 0.03), (0, 0, 0, 0.03)),
    "corner": ((0, 0, 0, 0.04), (0, 0, 0, 0.04), (0, 0, 0, 0.04)),
    "lights": ((0, 0, 0, 0.08), (0, 0.06, 0, 0), (0, 0, 0.1, 0)),
    "roof": ((0.15, 0, 0, 0), (0, 0.06, 0, 0), (0, 0, 0, 0.03)),
}
#: Where the axles typically are, as a fraction of the length from the centre (the guidance's own default).
WHEEL_X = 0.3
#: A placement nearer than this (metres) is ruled out.
MIN_DEPTH_M = 0.5
#: A weak prior on the depth that keeps a placement from a single click defined: metres and its sigma.
DEPTH_PRIOR_M = (20.0, 200.0)
#: A click whose squared Mahalanobis distance to its most probable part's place exceeds this (chi-square, 2 degrees of
#: freedom, 99.9 %) is not named.
OUTLIER_MAHALANOBIS2 = 13.82
#: Linear solves that start each placement, and Gauss-Newton iterations after them.
LINEAR_PASSES = 2
ITERATIONS = 5


@dataclass(frozen=True)
class Proposal:
    """What the prior cuboid says a click is.

    Attributes
    ----------
    choices : ``(kind, name, probability)``, the most probable first (every candidate that can be seen there)
    placed : whether anything but the click itself placed the cuboid (a named click or a box); without, the
        probabilities say only where on a vehicle the click could be, and the page does not name the click
    outlier : the click lies farther from the most probable part's place than a click of it would
        (:data:`OUTLIER_MAHALANOBIS2`), at that part's best placement: it is on no part the cuboid has there (another
        vehicle, or a slip), and the page does not name it
    """

    choices: tuple[tuple[str, str, float], ...]
    placed: bool
    outlier: bool = False


def _shape(kind: str, name: str) -> str | None:
    if kind == "symmetry":
        return "roof" if name == "roof" else "lights"
    if kind == "point":
        shape = vocabulary.entry(kind, name).get("shape")
        return shape if shape in SPREADS else None
    return None


def candidate_names(prototype: str, kitti_type: str | None = None) -> list[tuple[str, str]]:
    """The point parts a click on a vehicle of ``prototype`` may be named before a fit exists: those with a typical
    place and a spread that suit the prototype (corners only on box-shaped bodies)."""
    out = []
    for name, entry in vocabulary.KINDS["point"].names.items():
        if entry.typical is not None and _shape("point", name) is not None and vocabulary.suits(
                entry, (prototype, kitti_type or prototype)):
            out.append(("point", name))
    return out


def _typical(kind: str, name: str, d: np.ndarray, cov_d: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each click of part (kind, name) on the prior cuboid of dimensions ``d`` (3,): its typical place (3,), vehicle
    frame, and the covariance (3, 3) of where it is clicked (:data:`SPREADS` and the dimensions' ``cov_d``)."""
    entry = vocabulary.entry(kind, name)
    values = {"dx": d[0], "dy": d[1], "dz": d[2], "Xwf": WHEEL_X * d[0], "Xwr": -WHEEL_X * d[0], "side": 0.0,
              "side*dy": 0.0, "one": 0.0}
    unit = {"dx": 1.0, "dy": 1.0, "dz": 1.0, "Xwf": WHEEL_X, "Xwr": -WHEEL_X, "side": 0.0, "side*dy": 0.0,
            "one": 0.0}
    spread = SPREADS[_shape(kind, name)]
    sigma = np.array([math.sqrt((fx * d[0]) ** 2 + (fy * d[1]) ** 2 + (fz * d[2]) ** 2 + m ** 2)
                      for fx, fy, fz, m in spread])
    out = []
    for point, per_dim in zip(vocabulary.typical_points(entry, values), vocabulary.typical_points(entry, unit),
                              strict=True):
        scale = np.diag(per_dim)  # each coordinate is its dimension times this
        out.append((np.array(point), np.diag(sigma**2) + scale @ cov_d @ scale))
    return out


@dataclass(frozen=True)
class _Click:
    point_vehicle: np.ndarray  # (3,)
    cov_vehicle: np.ndarray  # (3, 3)
    m: np.ndarray  # (2,) normalized image coordinates
    faces: tuple[str, ...] | None


def _clicks(kind: str, name: str, uv: np.ndarray, camera: Camera, d: np.ndarray, cov_d: np.ndarray) -> list[_Click]:
    m = camera.normalize(np.asarray(uv, dtype=float).reshape(-1, 2))[:, :2]
    faces = vocabulary.entry(kind, name).faces
    return [_Click(p, c, m[k], faces) for k, (p, c) in enumerate(_typical(kind, name, d, cov_d))]


def _rotations(ground: GroundPlane | None, steps: int) -> np.ndarray:
    """Upright rotations ``R_cam_vehicle`` (steps, 3, 3), evenly over the yaw, on the road's normal (level: -y)."""
    tilt = np.eye(3) if ground is None else rotation_between(np.array([0.0, -1.0, 0.0]), ground.normal)
    return np.stack([tilt @ R_cam_vehicle_from_ypr(2 * math.pi * k / steps) for k in range(steps)])


def _height(ground: GroundPlane | None, settings: NamingSettings) -> tuple[np.ndarray, float, float] | None:
    """The road's normal, the camera's height above it and its sigma, or None when no height is known or assumed."""
    if ground is not None and ground.camera_height is not None:
        return ground.normal, ground.camera_height, max(ground.camera_height_sigma, 1e-3)
    if settings.camera_height_sigma_m is None:
        return None
    normal = np.array([0.0, -1.0, 0.0]) if ground is None else ground.normal
    return normal, settings.camera_height_m, settings.camera_height_sigma_m


def _place(R: np.ndarray, clicks: list[_Click], f: float, click_sigma: float, height, box: np.ndarray | None,
           d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cost (Y,) of the prior cuboid at each rotation of ``R`` (Y, 3, 3), its translation the best for
    ``clicks``, the road ``height`` and the ``box`` (normalized image coordinates, or None): the clicks' Mahalanobis
    distances and log determinants, the height's and the box's squared residuals; infinite where a click's part
    lies on a face turned away or the cuboid is not in front of the camera; and the last click's squared Mahalanobis
    distance (Y,) at each."""
    Y = len(R)
    points = np.stack([c.point_vehicle for c in clicks])  # (N, 3)
    covs = np.stack([c.cov_vehicle for c in clicks])  # (N, 3, 3)
    m = np.stack([c.m for c in clicks])  # (N, 2)
    P_rot = np.einsum("yij,nj->yni", R, points)  # (Y, N, 3)
    cov_cam = np.einsum("yij,njk,ylk->ynil", R, covs, R)  # (Y, N, 3, 3)
    corners = _corner_signs() * np.array([d[0] / 2, d[1] / 2, d[2]])
    C_rot = np.einsum("yij,cj->yci", R, corners)  # (Y, 8, 3)
    # A start: the linear (algebraic) least squares of the same terms, each click's two rows scaled to pixels at the
    # depth of the previous solution (first: the weak prior's), then Gauss-Newton on the pixel residuals.
    t = np.zeros((Y, 3))
    t[:, 2] = DEPTH_PRIOR_M[0]
    if box is not None:
        centre = np.array([(box[0] + box[2]) / 2, (box[1] + box[3]) / 2, 1.0])
        t[:] = centre * d[2] / max(box[3] - box[1], 1e-6)
    for _ in range(LINEAR_PASSES):
        t = _linear_start(t, P_rot, m, f, click_sigma, height)
    for _ in range(ITERATIONS):
        t = _gauss_newton_step(t, P_rot, cov_cam, m, f, click_sigma, height, box, C_rot)
    return _cost(t, P_rot, cov_cam, m, f, click_sigma, height, box, C_rot, R, clicks, d)


def _linear_start(t, P_rot, m, f, click_sigma, height):
    """The translations (Y, 3) that solve the clicks' projection equations linearly: for each click
    ``(e1 - m_x e3) . (R X + t) = 0`` and ``(e2 - m_y e3) . (R X + t) = 0``, scaled by ``f / z`` at the depth ``z``
    of the clicked point under ``t`` (pixels, over the click noise), with the road's height and the weak depth prior."""
    Y, N = P_rot.shape[:2]
    z = np.maximum((P_rot + t[:, None, :])[..., 2], MIN_DEPTH_M)  # (Y, N)
    rows = np.zeros((Y, N, 2, 3))
    rows[..., 0, 0] = rows[..., 1, 1] = 1.0
    rows[..., 0, 2], rows[..., 1, 2] = -m[:, 0], -m[:, 1]
    scale = (f / z / click_sigma)[..., None, None]
    A = (rows * scale).reshape(Y, 2 * N, 3)
    b = -(np.einsum("ynkj,ynj->ynk", rows, P_rot) * scale[..., 0]).reshape(Y, 2 * N)
    extra_A, extra_b = [], []
    if height is not None:
        normal, h, sigma = height
        extra_A.append(np.broadcast_to(normal / sigma, (Y, 1, 3)))
        extra_b.append(np.full((Y, 1), -h / sigma))
    mean, sigma = DEPTH_PRIOR_M
    extra_A.append(np.broadcast_to(np.array([0.0, 0.0, 1.0 / sigma]), (Y, 1, 3)))
    extra_b.append(np.full((Y, 1), mean / sigma))
    A = np.concatenate([A, *extra_A], axis=1)
    b = np.concatenate([b, *extra_b], axis=1)
    H = np.einsum("yri,yrj->yij", A, A) + 1e-9 * np.eye(3)
    out = np.linalg.solve(H, np.einsum("yri,yr->yi", A, b)[..., None])[..., 0]
    out[:, 2] = np.maximum(out[:, 2], MIN_DEPTH_M)
    return out


def _corner_signs() -> np.ndarray:
    return np.array([[sx, sy, top] for top in (0, 1) for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))], float)


def _residuals(t, P_rot, cov_cam, m, f, click_sigma, height, box, C_rot):
    """Whitened residuals (Y, R) and their Jacobians (Y, R, 3) with respect to t, plus the clicks' log
    determinants (Y,)."""
    P = P_rot + t[:, None, :]  # (Y, N, 3)
    z = np.maximum(P[..., 2], 1e-3)
    proj = P[..., :2] / z[..., None]
    J = np.zeros((*P.shape[:2], 2, 3))  # d(f * proj) / dP
    J[..., 0, 0] = J[..., 1, 1] = f / z
    J[..., :, 2] = -f * proj / z[..., None]
    S = np.einsum("ynai,ynij,ynbj->ynab", J, cov_cam, J) + click_sigma**2 * np.eye(2)
    L = np.linalg.cholesky(S)  # S = L L^T; whiten by L^-1
    r = f * (proj - m)  # (Y, N, 2)
    rw = np.linalg.solve(L, r[..., None])[..., 0]
    Jw = np.linalg.solve(L, J)  # dP/dt = I
    logdet = 2 * np.log(np.diagonal(L, axis1=-2, axis2=-1)).sum(axis=(-1, -2))
    rows, jacs = [rw.reshape(len(t), -1)], [Jw.reshape(len(t), -1, 3)]
    if height is not None:
        normal, h, sigma = height
        rows.append(((t @ normal + h) / sigma)[:, None])
        jacs.append(np.broadcast_to(normal / sigma, (len(t), 1, 3)))
    mean, sigma = DEPTH_PRIOR_M
    rows.append(((t[:, 2] - mean) / sigma)[:, None])
    jacs.append(np.broadcast_to(np.array([0.0, 0.0, 1.0 / sigma]), (len(t), 1, 3)))
    if box is not None:
        r_box, J_box = _box_rows(t, C_rot, f, box)
        rows.append(r_box)
        jacs.append(J_box)
    return np.concatenate(rows, axis=1), np.concatenate(jacs, axis=1), logdet


def _box_rows(t, C_rot, f, box):
    """The box's four sides against the projected cuboid's extremes: whitened residuals (Y, 4), Jacobians
    (Y, 4, 3)."""
    options = TrackOptions()
    C = C_rot + t[:, None, :]  # (Y, 8, 3)
    z = np.maximum(C[..., 2], 1e-3)
    proj = C[..., :2] / z[..., None]
    size = np.array([box[2] - box[0], box[3] - box[1]]) * f
    rows, jacs = [], []
    for axis, pick, side in ((0, np.argmin, box[0]), (0, np.argmax, box[2]), (1, np.argmin, box[1]),
                             (1, np.argmax, box[3])):
        k = pick(proj[..., axis], axis=1)
        at = np.arange(len(t))
        sigma = math.hypot(options.box_sigma_px, options.box_sigma_rel * size[axis])
        rows.append(f * (proj[at, k, axis] - side) / sigma)
        jac = np.zeros((len(t), 3))
        jac[:, axis] = f / z[at, k] / sigma
        jac[:, 2] = -f * proj[at, k, axis] / z[at, k] / sigma
        jacs.append(jac)
    return np.stack(rows, axis=1), np.stack(jacs, axis=1)


def _gauss_newton_step(t, P_rot, cov_cam, m, f, click_sigma, height, box, C_rot):
    r, J, _ = _residuals(t, P_rot, cov_cam, m, f, click_sigma, height, box, C_rot)
    H = np.einsum("yri,yrj->yij", J, J) + 1e-9 * np.eye(3)
    g = np.einsum("yri,yr->yi", J, r)
    step = -np.linalg.solve(H, g[..., None])[..., 0]
    t = t + step
    t[:, 2] = np.maximum(t[:, 2], MIN_DEPTH_M)
    return t


def _cost(t, P_rot, cov_cam, m, f, click_sigma, height, box, C_rot, R, clicks, d):
    """The placements' costs (Y,), infinite where ruled out, and the last click's own squared Mahalanobis distance
    (Y,) at each."""
    r, _, logdet = _residuals(t, P_rot, cov_cam, m, f, click_sigma, height, box, C_rot)
    cost = np.einsum("yr,yr->y", r, r) + logdet
    last = (r[:, 2 * (len(clicks) - 1):2 * len(clicks)] ** 2).sum(axis=1)
    camera_vehicle = np.einsum("yji,yj->yi", R, -t)  # R^T (-t)
    seen = [vocabulary.faces_seen_from(c, d) for c in camera_vehicle]
    bad = (P_rot + t[:, None, :])[..., 2].min(axis=1) <= MIN_DEPTH_M
    for y, visible in enumerate(seen):
        if any(c.faces is not None and not any(visible[face] for face in c.faces) for c in clicks):
            bad[y] = True
    return np.where(bad, np.inf, cost), last


def propose(camera: Camera, prior: SizePrior, named: list[tuple[str, str, np.ndarray]], uv: np.ndarray,
            box2d: np.ndarray | None = None, ground: GroundPlane | None = None, click_sigma: float = 1.5,
            settings: NamingSettings = NAMING_SETTINGS,
            dimensions: tuple[np.ndarray, np.ndarray] | None = None) -> Proposal:
    """The names a click at pixel ``uv`` (2,) may have on a vehicle of ``prior``'s prototype, each with its
    probability, from the prior cuboid placed by the vehicle's ``named`` clicks (kind, name, uv (k, 2); those of
    kinds without a typical place are left out), its ``box2d`` (4,) pixels or None, and the road (``ground``, else
    the level road :attr:`NamingSettings.camera_height_m` below the camera).

    Returns
    -------
    Proposal
        The candidates (:func:`candidate_names` not among ``named``) by probability; none when no placement
        admits any.
    """
    d, cov_d = np.asarray(prior.mean, dtype=float), np.asarray(prior.cov, dtype=float)
    if dimensions is not None:
        d, cov_d = (np.asarray(x, dtype=float) for x in dimensions)
    taken = {(kind, name) for kind, name, _ in named}
    evidence: list[_Click] = []
    for kind, name, clicked in named:
        if _shape(kind, name) is not None and vocabulary.entry(kind, name).typical is not None:
            evidence.extend(_clicks(kind, name, clicked, camera, d, cov_d))
    box = None
    if box2d is not None:
        corners = camera.normalize(np.asarray(box2d, dtype=float).reshape(2, 2))[:, :2]
        box = np.array([corners[0, 0], corners[0, 1], corners[1, 0], corners[1, 1]])
    f = 0.5 * float(camera.K[0, 0] + camera.K[1, 1])
    R = _rotations(ground, settings.yaw_steps)
    height = _height(ground, settings)
    scores, outlying = [], []
    names = [c for c in candidate_names(prior.prototype, prior.kitti_type) if c not in taken]
    for kind, name in names:
        clicks = evidence + _clicks(kind, name, uv, camera, d, cov_d)
        cost, last = _place(R, clicks, f, click_sigma, height, box, d)
        finite = np.isfinite(cost)
        if not finite.any():
            scores.append(-np.inf)
            outlying.append(True)
            continue
        low = cost[finite].min()
        scores.append(float(np.log(np.exp(-(cost[finite] - low) / 2).sum()) - low / 2))
        outlying.append(bool(last[np.argmin(np.where(finite, cost, np.inf))] > OUTLIER_MAHALANOBIS2))
    placed = bool(evidence) or box is not None
    scores_arr = np.array(scores)
    if not len(scores_arr) or not np.isfinite(scores_arr).any():
        return Proposal((), placed, True)
    p = np.exp(scores_arr - scores_arr[np.isfinite(scores_arr)].max())
    p /= p.sum()
    order = np.argsort(-p, kind="stable")
    return Proposal(tuple((names[i][0], names[i][1], float(p[i])) for i in order if p[i] > 0), placed,
                    outlying[int(order[0])])
