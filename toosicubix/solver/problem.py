"""One vehicle's fitting problem and its costs (paper, "Solving the equations" and "Pixel-domain
fine-tuning"), with the scale and ground cues.

With ``X_i = A_i p`` and ``Y_i = R_cam_vehicle X_i + t_cam_vehicle``:

- 3D cost (coordinate descent): ``sum |M_i Y_i|^2 + lambda_3d |G [t; p] - b|^2`` with
  ``M_i = [[1, 0, -x_i], [0, 1, -y_i]]`` in normalized coordinates: the SQPnP cost, a depth-weighted
  error that shrinks with the vehicle's scale.
- Pixel cost (refinement, and the comparison of starts): ``sum |K_:2 pi(Y_i) - x_i|^2 +
  lambda_px (|G [t; p] - b|^2 + |R e_z - n|^2 / sigma_up^2)``.

``G [t; p] - b`` stacks every term that fixes the scale, each a linear function of ``(t, p)`` divided by
its standard deviation: the size prior ``W (d - mu)`` (``W`` the upper Cholesky factor of the inverse
covariance) and, for a car, where its clicked axles sit (``(Xwf - a_f dx) / sigma``, ``(Xwr + a_r dx) / sigma``:
:func:`toosicubix.size_priors.axle_prior`, rules 29-30 of benchmarks/decisions.md; cue 'axle prior'), known sizes
``(c . p - metres) / sigma`` (plates, wheelbases, tyres, known dimensions) and, with a ground plane of known
height, the ground contact ``(n . t + h) / sigma_c`` (the bottom face on the
road). The upright term ``(R e_z - n) / sigma_up`` keeps the vehicle's up axis near the road normal; it
does not depend on scale. Every cue is weighed like the prior: ``lambda_px`` plays the click-noise variance.

The upright term of a vehicle whose clicks carry their own noise (keypoints and plates: the soft term of
:mod:`.robust` weighs each pixel row to the click noise ``sigma_c``) may instead be weighed as the prior it states,
``sigma_c^2 |R e_z - n|^2 / sigma_up^2`` (:meth:`Problem.upright_against_clicks`, ``SolverOptions.upright_weight``
'clicks'; rule 23 of benchmarks/decisions.md): weighed by ``lambda_px`` (10 px^2) against ApolloCar3D's 0.95 px
clicks it stands vehicles upright within about 1 degree where the ground block says 3.6.

Arrow rows: a direction arrow's two points are a gauge (the paper moves them along their rays until the segment is
as long as the dimension it runs along), so only the rays say where the arrow was drawn. The arrow is drawn on the
vehicle or on the ground beside it, so the midpoint's ray, taken at the distance of the vehicle's centre, passes
through a zone around the cuboid, ``|c_x| <= 1.5 dx``, ``|c_y| <= 1.5 dy``, ``-0.5 dz <= c_z <= 1.5 dz``: a row
``(distance outside the zone) / ARROW_ZONE_SIGMA`` per coordinate, zero inside (no pull on an arrow drawn anywhere
near the vehicle). The gauge needs no pin: a segment as long as the dimension between the two rays, along the
vehicle's axis, is one segment (its two points are determined). Without the zone an arrow seen nearly end-on
(front and rear views) can slide along its rays tens of metres at almost no cost: a flat valley with spurious
minima that the starts cannot all reach. Judging the gauge point itself (as this zone once did) pulls the pose
whenever an arrow is drawn shorter or longer than the vehicle (rule 22 of benchmarks/decisions.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cached_property
from typing import TypeVar

import numpy as np

from toosicubix.camera import Camera
from toosicubix.model import GroundPlane
from toosicubix.parts.linear import PartsModel
from toosicubix.size_priors import SizePrior, axle_prior

T = TypeVar("T")

#: Metres: how fast the arrow-zone cost grows outside the zone (a standard deviation, weighed like a cue).
ARROW_ZONE_SIGMA = 0.5
#: Rows per arrow: the zone's three.
ARROW_ROWS = 3
#: The arrow zone, as multiples of (dx, dy, dz) per coordinate: (low, high).
_ARROW_ZONE = ((-1.5, 1.5), (-1.5, 1.5), (-0.5, 1.5))


def _hat_batch(x: np.ndarray) -> np.ndarray:
    """The cross-product matrices of vectors ``x`` (..., 3): (..., 3, 3)."""
    out = np.zeros((*x.shape, 3))
    out[..., 0, 1], out[..., 0, 2] = -x[..., 2], x[..., 1]
    out[..., 1, 0], out[..., 1, 2] = x[..., 2], -x[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -x[..., 1], x[..., 0]
    return out


@dataclass(frozen=True)
class Problem:
    """Everything the solver stages need, as arrays.

    Attributes
    ----------
    parts : the linear model ``X_i = A_i p``; ``A`` (N, 3, P)
    u : (N, 3) normalized, undistorted clicks ``K^-1 (x, y, 1)``
    uv : (N, 2) the clicks as an ideal pinhole ``K`` sees them (undistorted pixels)
    K : (3, 3)
    prior : size prior of the vehicle's prototype
    lambda_3d, lambda_px : weights of the cues in the 3D and the pixel cost
    G : (m, 3 + P) the scale rows' linear map on ``(t, p)``, already divided by their sigmas
    b : (m,) their targets
    row_cues : (m,) what each row is
    ground : the road plane, or None
    upright_sigma : radians, the spread of the vehicle's up axis about the normal (None without ground)
    upright_noise_px : the pixel noise the upright rows are weighed against, each row
        ``upright_noise_px (R e_z - n)_k / upright_sigma``; None: ``sqrt(lambda_px)``, like every other cue
        (:meth:`upright_against_clicks`)
    A_rows : (3N, P) ``A`` stacked; A_mean : (3, P) the clicked points' centroid is ``A_mean @ p``
    arrow_mid, arrow_low, arrow_high : (3 n_arrows, P) each arrow's midpoint coordinates and the zone's
        bounds on them, linear in ``p`` (empty without arrows)
    click_weights : (N,) weights of each click's two pixel rows (keypoints' soft term, robust loss; see
        :mod:`.robust`), or None for all ones
    """

    parts: PartsModel
    u: np.ndarray
    uv: np.ndarray
    K: np.ndarray
    prior: SizePrior
    lambda_3d: float
    lambda_px: float
    G: np.ndarray
    b: np.ndarray
    row_cues: tuple[str, ...]
    ground: GroundPlane | None
    upright_sigma: float | None
    A_rows: np.ndarray
    A_mean: np.ndarray
    arrow_mid: np.ndarray
    arrow_low: np.ndarray
    arrow_high: np.ndarray
    click_weights: np.ndarray | None = None
    upright_noise_px: float | None = None

    @classmethod
    def build(cls, parts: PartsModel, camera: Camera, prior: SizePrior, lambda_3d: float,
              lambda_px: float, ground: GroundPlane | None = None, contact_distance: float = 0.0) -> Problem:
        """Assemble a vehicle's problem.

        Parameters
        ----------
        ground : the image's road plane; adds the upright term, and the ground contact when the camera
            height is known
        contact_distance : metres from the camera to the vehicle along the road; a normal off by
            ``normal_sigma`` moves the road under the vehicle by about ``normal_sigma * contact_distance``,
            which adds to the contact's uncertainty (see :meth:`with_contact_distance`)
        """
        u = camera.normalize(parts.uv)
        uv = u[:, :2] @ camera.K[:2, :2].T + camera.K[:2, 2]
        P = parts.n_params
        rows, targets, cues = [], [], []
        W = prior.sqrt_information
        for k in range(3):
            row = np.zeros(3 + P)
            row[3:6] = W[k]
            rows.append(row)
            targets.append(W[k] @ prior.mean)
            cues.append("size prior")
        axles = axle_prior(prior.prototype)
        if axles is not None:  # rule 30: a car's axles where real cars have them, weighed as the size prior
            sigma = axles.sigma(float(prior.mean[0]))
            for name, fraction in axles.at.items():
                if name in parts.param_names:
                    row = np.zeros(3 + P)
                    row[3 + parts.param_names.index(name)] = 1.0 / sigma
                    row[3] = -fraction / sigma
                    rows.append(row)
                    targets.append(0.0)
                    cues.append("axle prior")
        for m in parts.measurements:
            row = np.zeros(3 + P)
            row[3:] = m.coefficients / m.sigma
            rows.append(row)
            targets.append(m.metres / m.sigma)
            cues.append(m.label)
        upright_sigma = None
        if ground is not None:
            upright_sigma = float(np.hypot(ground.upright_sigma, ground.normal_sigma))
            if ground.camera_height is not None:
                sigma = float(np.hypot(ground.camera_height_sigma, ground.normal_sigma * contact_distance))
                row = np.zeros(3 + P)
                row[:3] = ground.normal / sigma
                rows.append(row)
                targets.append(-ground.camera_height / sigma)
                cues.append("ground contact")
        A = parts.A
        A_mean = A.mean(axis=0) if len(A) else np.zeros((3, P))  # no clicks (a track's frame with a box only)
        return cls(parts, u, uv, camera.K, prior, lambda_3d, lambda_px, np.array(rows), np.array(targets),
                   tuple(cues), ground, upright_sigma, A.reshape(-1, P), A_mean, *_arrow_zone(parts))

    @property
    def upright_weight(self) -> float:
        """The factor of the upright rows ``(R e_z - n)`` in the pixel cost: ``upright_noise_px / upright_sigma``
        (``sqrt(lambda_px)`` for the noise when None). Only for a problem with a ground."""
        assert self.upright_sigma is not None
        noise = math.sqrt(self.lambda_px) if self.upright_noise_px is None else self.upright_noise_px
        return noise / self.upright_sigma

    @property
    def cue_row_lambdas(self) -> np.ndarray:
        """(m,) the weight, px^2, of each cue row's squared standardized residual in the pixel cost, in the order
        of :func:`.refine.residuals_batch`'s cue rows (scale rows, upright rows, arrow rows): ``lambda_px``, but
        ``upright_noise_px^2`` for the upright rows when set."""
        n_up = 0 if self.upright_sigma is None else 3
        out = np.full(len(self.b) + n_up + self.n_arrow_rows, float(self.lambda_px))
        if n_up and self.upright_noise_px is not None:
            out[len(self.b):len(self.b) + n_up] = self.upright_noise_px**2
        return out

    def upright_against_clicks(self, click_sigma: float) -> Problem:
        """The problem with its upright term weighed against the click noise ``click_sigma`` (px), as the prior it
        states: for a vehicle whose pixel rows are weighed to that noise (keypoints, plates:
        :func:`.robust.soft_weights`).

        The spread is the ground's ``upright_sigma`` about a normal the batch estimated (rule 7 measured its 2 degrees
        about the median of ground-truth up axes, the estimator of :mod:`toosicubix.pipeline.road_normal`: the
        estimate's own error is in it; it is 0.16 degrees, the standard error of the median of 231 vehicles, on
        ApolloCar3D's comparison half), else ``hypot(upright_sigma, normal_sigma)`` as for every vehicle. Without a
        ground, the problem as it is."""
        if self.ground is None:
            return self
        sigma = (self.ground.upright_sigma if self.ground.from_batch
                 else float(np.hypot(self.ground.upright_sigma, self.ground.normal_sigma)))
        return replace(self, upright_sigma=float(sigma), upright_noise_px=float(click_sigma))

    @property
    def n_arrow_rows(self) -> int:
        return ARROW_ROWS * (len(self.arrow_mid) // 3)

    @cached_property
    def scale_rows_jacobian(self) -> np.ndarray:
        """(m, 6 + P): the scale rows' Jacobian for the refinement's step ``(delta, dt, dp)`` when rotations
        turn about the origin: zero, ``G``'s t columns, ``G``'s p columns."""
        G = np.zeros((len(self.b), 6 + self.parts.n_params))
        G[:, 3:6] = self.G[:, :3]
        G[:, 6:] = self.G[:, 3:]
        return G

    @cached_property
    def scale_rows_see_t(self) -> bool:
        """Whether any scale row depends on ``t`` (the ground contact)."""
        return bool(self.G[:, :3].any())

    def with_click_weights(self, weights: np.ndarray | None) -> Problem:
        """The problem with its pixel rows weighted by ``weights`` (N,) (None: unweighted): the same problem when
        neither is weighted; else a new one that keeps what this one derived and the weights do not change
        (:data:`UNWEIGHTED_KEPT`), as the robust loss's rounds reweigh a vehicle's clicks again and again."""
        if weights is None and self.click_weights is None:
            return self
        new = replace(self, click_weights=None if weights is None else np.asarray(weights, dtype=float))
        for key in UNWEIGHTED_KEPT:
            if key in self.__dict__:
                new.__dict__[key] = self.__dict__[key]
        return new

    def kept(self, key: str, make: Callable[[Problem], T]) -> T:
        """``make(self)``, made once per problem and kept on it under ``key``, as ``functools.cached_property`` keeps
        its values (a problem never changes; ``dataclasses.replace`` makes a new one): for what a stage derives from a
        problem on every call (the descent's shape-step terms, the compiled kernel's arrays)."""
        found = self.__dict__.get(key)
        if found is None:
            found = self.__dict__[key] = make(self)
        return found

    @cached_property
    def u_image_points(self) -> np.ndarray:
        """(N, 1, 2) the normalized clicks as OpenCV's PnP solvers take image points (contiguous float64)."""
        return np.ascontiguousarray(self.u[:, :2], dtype=np.float64).reshape(-1, 1, 2)

    @cached_property
    def pixel_row_weights(self) -> np.ndarray | None:
        """(2N,) the click weights repeated for each click's two pixel rows, or None for all ones."""
        return None if self.click_weights is None else np.repeat(self.click_weights, 2)

    def arrow_rows(self, R: np.ndarray, t: np.ndarray, p: np.ndarray, pivot: np.ndarray | None = None,
                   with_jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """The arrows' standardized rows (see the module docstring) and their Jacobian over ``(delta, t, p)`` (the
        refinement's step, rotations about ``pivot``): (B, k) and (B, k, 6 + P) for ``R`` (B, 3, 3), ``t`` (B, 3),
        ``p`` (B, P) and ``pivot`` (B, 3) or None, with ``k = n_arrow_rows``: per arrow, how far its midpoint, moved
        along its ray to the vehicle centre's distance from the camera, lies outside its zone (three rows, metres
        over ``ARROW_ZONE_SIGMA``, 0 inside).

        The arrow's own points are a gauge (the paper fixes the length of its 3D segment to the dimension, so a
        drawn arrow of another length sits farther along its rays); the ray is not, so the zone judges the point
        of the midpoint's ray at the distance of the vehicle's centre: ``c' = C + rho (c - C)`` with ``C`` the
        camera centre (vehicle frame) and ``rho = |v_cam| / |c_cam|``, ``v`` the centre ``(0, 0, dz / 2)``. Without
        ``with_jacobian`` the Jacobian is None (the rows are the same)."""
        B, P = p.shape
        n = self.n_arrow_rows // ARROW_ROWS
        mid = self.arrow_mid.reshape(n, 3, P)
        c = np.einsum("kip,bp->bki", mid, p)  # (B, n, 3) the gauge midpoints, vehicle frame
        v = np.zeros((B, 3))
        v[:, 2] = 0.5 * p[:, 2]
        a = np.einsum("bij,bkj->bki", R, c) + t[:, None, :]  # (B, n, 3) camera frame
        b = np.einsum("bij,bj->bi", R, v) + t  # (B, 3)
        # |a|, |b|: np.linalg.norm's own arithmetic (the root of the summed squares), without its dispatch.
        na, nb = np.sqrt(np.add.reduce(a * a, axis=2)), np.sqrt(np.add.reduce(b * b, axis=1))  # (B, n), (B,)
        rho = nb[:, None] / na  # (B, n)
        w = rho[..., None] * a - t[:, None, :]  # (B, n, 3)
        c_ray = np.einsum("bji,bkj->bki", R, w)  # R^T w: (B, n, 3)
        low = (p @ self.arrow_low.T).reshape(B, n, 3)
        high = (p @ self.arrow_high.T).reshape(B, n, 3)
        above, below = c_ray - high, c_ray - low
        is_above, is_below = above > 0.0, below < 0.0
        outside = np.where(is_above, above, np.where(is_below, below, 0.0))
        if not with_jacobian:
            return (outside / ARROW_ZONE_SIGMA).reshape(B, 3 * n), None
        if not (is_above | is_below).any():  # every midpoint in its zone (the usual case): a zero gradient
            return (outside / ARROW_ZONE_SIGMA).reshape(B, 3 * n), np.zeros((B, 3 * n, 6 + P))
        # Jacobians (B, n, 3, 6 + P) of a, b, w and c_ray; d(R^T w) = [c_ray]x delta + R^T dw.
        q = np.zeros((B, 3)) if pivot is None else pivot
        eye = np.eye(3)

        def d_point(x_minus_q: np.ndarray, A_p: np.ndarray) -> np.ndarray:  # d(R x + t) for x (B, ..., 3)
            out = np.zeros((*x_minus_q.shape, 6 + P))
            out[..., 0:3] = -np.einsum("bij,b...jk->b...ik", R, _hat_batch(x_minus_q))
            out[..., 3:6] = eye
            out[..., 6:] = A_p
            return out

        Rm = np.einsum("bij,kjp->bkip", R, mid)  # R (d c / d p): (B, n, 3, P)
        da = d_point(c - q[:, None, :], Rm)
        V = np.zeros((3, P))
        V[2, 2] = 0.5
        db = d_point(v - q, np.einsum("bij,jp->bip", R, V))  # (B, 3, 6 + P)
        d_rho = rho[..., None] * (np.einsum("bi,bip->bp", b, db)[:, None, :] / (nb**2)[:, None, None]
                                  - np.einsum("bki,bkip->bkp", a, da) / (na**2)[..., None])  # (B, n, 6 + P)
        dt_total = np.zeros((B, 3, 6 + P))  # t's own change: dt + R [q]x delta
        dt_total[:, :, 0:3] = np.einsum("bij,bjk->bik", R, _hat_batch(q))
        dt_total[:, :, 3:6] = eye
        dw = a[..., None] * d_rho[:, :, None, :] + rho[..., None, None] * da - dt_total[:, None]
        d_ray = np.einsum("bji,bkjp->bkip", R, dw)
        d_ray[..., 0:3] += _hat_batch(c_ray)
        bounds = np.where(is_above[..., None], self.arrow_high.reshape(n, 3, P)[None],
                          np.where(is_below[..., None], self.arrow_low.reshape(n, 3, P)[None], 0.0))
        zone_gradient = np.where((is_above | is_below)[..., None], d_ray, 0.0)
        zone_gradient[..., 6:] -= bounds
        return ((outside / ARROW_ZONE_SIGMA).reshape(B, 3 * n),
                (zone_gradient / ARROW_ZONE_SIGMA).reshape(B, 3 * n, 6 + P))

    def with_contact_distance(self, distance: float) -> Problem:
        """The same problem with the ground contact's sigma widened for a vehicle ``distance`` metres away."""
        if self.ground is None or self.ground.camera_height is None:
            return self
        sigma = float(np.hypot(self.ground.camera_height_sigma, self.ground.normal_sigma * distance))
        k = self.row_cues.index("ground contact")
        G, b = self.G.copy(), self.b.copy()
        G[k] = 0.0
        G[k, :3] = self.ground.normal / sigma
        b[k] = -self.ground.camera_height / sigma
        return replace(self, G=G, b=b)

    @property
    def A(self) -> np.ndarray:
        return self.parts.A

    @property
    def up(self) -> np.ndarray:
        """The direction vehicles stand along, camera frame: the road normal, else the camera's up (-y)."""
        return self.ground.normal if self.ground is not None else np.array([0.0, -1.0, 0.0])

    def points_vehicle_batch(self, p: np.ndarray) -> np.ndarray:
        """The clicked points for each ``p`` of a batch (B, P): (B, N, 3), vehicle frame."""
        return (p @ self.A_rows.T).reshape(len(p), -1, 3)

    def points_cam(self, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray) -> np.ndarray:
        """``Y_i = R X_i + t`` for every click: (N, 3)."""
        return (self.A @ p) @ R_cam_vehicle.T + t_cam_vehicle

    def scale_terms(self, t_cam_vehicle: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``a = G [t; p]`` and ``b``: the scale rows are ``s a - b`` when ``(t, p)`` is scaled by ``s``.

        Parameters
        ----------
        t_cam_vehicle : (B, 3) or (3,); p : (B, P) or (P,)
        """
        return t_cam_vehicle @ self.G[:, :3].T + p @ self.G[:, 3:].T, self.b

    def prior_residual(self, p: np.ndarray) -> np.ndarray:
        """``W (d - mu)``: (3,), unweighted by lambda."""
        return self.prior.sqrt_information @ (p[:3] - self.prior.mean)

    def cost_3d(self, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray) -> float:
        """The coordinate-descent (SQPnP) cost with the scale rows: metres^2 plus lambda_3d times theirs."""
        Y = self.points_cam(R_cam_vehicle, t_cam_vehicle, p)
        e = Y[:, :2] - self.u[:, :2] * Y[:, 2:3]
        a, b = self.scale_terms(t_cam_vehicle, p)
        return float(np.sum(e * e) + self.lambda_3d * np.sum((a - b) ** 2))

    def pixel_residuals(self, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Projected minus clicked (undistorted) pixels: (N, 2)."""
        Y = self.points_cam(R_cam_vehicle, t_cam_vehicle, p)
        return Y[:, :2] / Y[:, 2:3] @ self.K[:2, :2].T + self.K[:2, 2] - self.uv

    def cost_px(self, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray) -> float:
        """The pixel-domain cost: px^2 plus lambda_px times the cues' squared standardized residuals (the upright
        term's weight :attr:`upright_weight` squared)."""
        e = self.pixel_residuals(R_cam_vehicle, t_cam_vehicle, p)
        if self.click_weights is not None:
            e = e * self.click_weights[:, None]
        a, b = self.scale_terms(t_cam_vehicle, p)
        cues = float(np.sum((a - b) ** 2))
        upright = 0.0
        if self.upright_sigma is not None and self.upright_noise_px is None:
            cues += float(np.sum((R_cam_vehicle[:, 2] - self.up) ** 2)) / self.upright_sigma**2
        elif self.upright_sigma is not None:
            upright = self.upright_weight**2 * float(np.sum((R_cam_vehicle[:, 2] - self.up) ** 2))
        if self.n_arrow_rows:
            arrows, _ = self.arrow_rows(R_cam_vehicle[None], t_cam_vehicle[None], p[None], None, False)
            cues += float(np.sum(arrows[0] ** 2))
        return float(np.sum(e * e) + self.lambda_px * cues + upright)

    def min_depth(self, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray) -> float:
        """Smallest depth (camera z) of the clicked points and the cuboid's bottom centre, metres."""
        Y = self.points_cam(R_cam_vehicle, t_cam_vehicle, p)
        return float(min(Y[:, 2].min(), t_cam_vehicle[2]))

    def prior_scale(self, p: np.ndarray, t_cam_vehicle: np.ndarray | None = None) -> float:
        """The scale ``s`` minimizing the scale rows ``|s a - b|^2``: where the cues put a cuboid of this shape.

        May be negative: ``(s p, s t)`` then turns a mirrored, behind-the-camera answer around (the
        pixel data term is the same for both). 0 when ``a`` is zero.
        """
        t = np.zeros(3) if t_cam_vehicle is None else t_cam_vehicle
        a, b = self.scale_terms(t, p)
        denom = float(a @ a)
        return float(a @ b) / denom if denom > 0.0 else 0.0


#: The :meth:`Problem.kept` key of the compiled kernel's arrays (:func:`toosicubix.solver.compiled._problem_arrays`),
#: which leave the click weights out.
KERNEL_ARRAYS = "compiled kernel arrays"
#: What a problem derives (its cached properties, and :meth:`Problem.kept`'s keys) that does not depend on its click
#: weights: :meth:`Problem.with_click_weights` hands them on. Anything derived from the weights must stay out.
UNWEIGHTED_KEPT = ("scale_rows_jacobian", "scale_rows_see_t", "u_image_points", KERNEL_ARRAYS)


def _arrow_zone(parts: PartsModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each arrow's midpoint coordinates and the zone's low and high bounds on them: 3 rows (P,) per arrow."""
    tails = parts.arrow_tails
    if not tails:  # most vehicles
        return np.zeros((0, parts.n_params)), np.zeros((0, parts.n_params)), np.zeros((0, parts.n_params))
    unit = np.eye(parts.n_params)[:3]  # rows picking dx, dy, dz out of p
    low = np.array([lo for lo, _ in _ARROW_ZONE])[:, None] * unit  # (3, P)
    high = np.array([hi for _, hi in _ARROW_ZONE])[:, None] * unit
    mid = [0.5 * (parts.A[i] + parts.A[i + 1]) for i in tails]  # (3, P) each: tail and head, vehicle frame
    shape = (3 * len(tails), parts.n_params)
    return np.reshape(mid, shape), np.tile(low, (len(tails), 1)), np.tile(high, (len(tails), 1))
