"""How well a fitted cuboid is determined: covariance, standard deviations, what the clicks fix, confidence.

The fit minimizes ``F = |r_px|^2 + lambda_px |r_cue|^2`` (pixel residuals; size prior, known sizes, ground
cues as standardized residuals). Linearized at the optimum, with clicks off by independent Gaussian noise of
``click_sigma`` pixels per coordinate and the vehicle off its prior (and the road off its stated plane) by
one standard deviation per standardized residual, the estimate's error has covariance

    Cov = H^-1 (click_sigma^2 J_px^T J_px + lambda_px^2 J_cue^T J_cue) H^-1,  H = J_px^T J_px + lambda_px J_cue^T J_cue

over ``theta = (delta, t, p)`` with ``R = R_hat exp([delta]x)``: the estimator's own spread, right whatever
``lambda_px`` is (when ``lambda_px = click_sigma^2`` it is the Laplace posterior ``click_sigma^2 H^-1``).
Reported quantities are functions of ``theta`` whose standard deviations follow by the chain rule.

What the clicks determine: for each quantity, its posterior variance from the clicks' information alone
(``A / click_sigma^2`` with ``A = J_px^T J_px``, the cues' information ``C = J_cue^T J_cue`` scaled by 1e-6 to
keep it invertible) against its variance from both (``(A / click_sigma^2 + C)^-1``). Along a direction no click
fixes, the first is a million times the second. Both have the scale pinned (a huge weight along the
direction ``(0, t, p)``), since no click ever fixes it: the scale is always the cues' (or the prior's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from toosicubix import vocabulary
from toosicubix.geometry import rot_x, ypr_from_R_cam_vehicle
from toosicubix.solver.problem import Problem
from toosicubix.solver.refine import residuals_and_jacobian

#: A quantity is "mostly set by the cues" when switching them off multiplies its variance by more than this
#: (its standard deviation by 2).
PRIOR_SET_RATIO = 4.0
#: ... and "not fixed by the clicks at all" above this (standard deviation by 100): in practice a direction
#: the clicks leave free, whose ratio is about 1e6, the inverse of the cues' scaling.
UNDETERMINED_RATIO = 1e4
QUANTITIES = ("yaw", "pitch", "roll", "length", "width", "height")

_HINTS = {
    "yaw": "click two wheels of one side, both ends of an axle, a light pair, or draw a forward arrow",
    "pitch": "click parts at both ends (front and rear) and on the ground (wheels)",
    "roll": "click parts on both sides (both wheels of an axle, a light pair)",
    "length": "click a front and a rear part (both ends of the vehicle)",
    "width": "click parts on both sides (both wheels of an axle, a light pair, both edges of an end)",
    "height": "click a roof or top part and one on the ground (a wheel)",
}
#: The same advice for a vehicle clicked only in keypoints (a mapping's, e.g. ApolloCar3D's): no arrows,
#: no ground contacts, no cuboid edges.
_KEYPOINT_HINTS = {
    "yaw": "click keypoints front to rear along one side (a front and a rear wheel centre, a side's lamps)",
    "pitch": "click keypoints at both ends (front and rear) and low on the body (wheel centres)",
    "roll": "click keypoints on both sides of one end (its left and right lamps)",
    "length": "click a keypoint at the front and one at the rear",
    "width": "click keypoints on both sides, as far apart as they go (both mirrors, both lamps of one end)",
    "height": "click a high keypoint (a glass top corner) and a low one (a wheel centre)",
}


@dataclass(frozen=True)
class Uncertainty:
    """Standard deviations of a fitted cuboid for a stated click noise (results.json's ``sigma``); ``inf`` where the
    fit does not determine a quantity at all (``null`` in the JSON).

    Attributes
    ----------
    yaw_deg, pitch_deg, roll_deg : KITTI yaw (about camera y) and the vehicle's pitch and roll, degrees
    depth_m : of the bottom centre's camera z; depth_rel : relative to it
    dimensions : (3,) of (dx, dy, dz), metres
    position_m : (2,) of the bottom centre's lateral and forward position (camera x and z), metres
    scale_rel : of the vehicle's scale (its distance), relative
    covariance : (6 + P, 6 + P) of ``(delta, t, p)``; None when read from results.json (it is not written)
    """

    yaw_deg: float
    pitch_deg: float
    roll_deg: float
    depth_m: float
    depth_rel: float
    dimensions: tuple[float, float, float]
    position_m: tuple[float, float]
    scale_rel: float
    covariance: np.ndarray | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        for key in ("dimensions", "position_m"):  # plain floats: values compare, whatever the caller gave
            object.__setattr__(self, key, tuple(float(v) for v in getattr(self, key)))

    def widened(self, variance_factor: float) -> Uncertainty:
        """The same with every variance multiplied by ``variance_factor`` (standard deviations by its root): a
        misfit's (:mod:`toosicubix.solver.misfit`)."""
        k = math.sqrt(variance_factor)
        return Uncertainty(self.yaw_deg * k, self.pitch_deg * k, self.roll_deg * k, self.depth_m * k,
                           self.depth_rel * k, tuple(v * k for v in self.dimensions),
                           tuple(v * k for v in self.position_m), self.scale_rel * k,
                           None if self.covariance is None else self.covariance * variance_factor)

    def to_json(self) -> dict:
        """As results.json has it; ``null`` for a quantity the fit does not determine at all (infinite). A NaN stays
        (the writer refuses it, naming its path)."""
        scalars = ("yaw_deg", "pitch_deg", "roll_deg", "depth_m", "depth_rel")
        return {
            **{key: infinite_as_none(getattr(self, key)) for key in scalars},
            "dimensions": [infinite_as_none(v) for v in self.dimensions],
            "position_m": [infinite_as_none(v) for v in self.position_m],
            "scale_rel": infinite_as_none(self.scale_rel),
        }

    @classmethod
    def from_json(cls, d: dict) -> Uncertainty:
        """The inverse of :meth:`to_json` (without the covariance)."""
        return cls(yaw_deg=none_as_infinite(d["yaw_deg"]), pitch_deg=none_as_infinite(d["pitch_deg"]),
                   roll_deg=none_as_infinite(d["roll_deg"]), depth_m=none_as_infinite(d["depth_m"]),
                   depth_rel=none_as_infinite(d["depth_rel"]),
                   dimensions=tuple(none_as_infinite(v) for v in d["dimensions"]),
                   position_m=tuple(none_as_infinite(v) for v in d["position_m"]),
                   scale_rel=none_as_infinite(d["scale_rel"]))


def infinite_as_none(value: float) -> float | None:
    """JSON has no infinity: None stands for it. A NaN is kept (it is not a value; writers refuse it)."""
    value = float(value)
    return None if math.isinf(value) else value


def none_as_infinite(value: float | None) -> float:
    """The inverse of :func:`infinite_as_none`."""
    return math.inf if value is None else float(value)


def finite_or_none(value: float) -> float | None:
    """JSON has no infinity: None stands for it."""
    value = float(value)
    return value if math.isfinite(value) else None


def jacobians(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray,
              J: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The pixel rows and the standardized cue rows of the Jacobian w.r.t. ``(delta, t, p)`` (no pivot); ``J``
    is that Jacobian when the caller has it already (:func:`.refine.residuals_and_jacobian` at the pose)."""
    if J is None:
        _, J = residuals_and_jacobian(problem, R, t, p)
    n_px = 2 * problem.parts.n_clicks
    return J[:n_px], J[n_px:] / math.sqrt(problem.lambda_px)


def row_sigmas(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray, click_sigma: float,
               part_sigma: float = 0.0) -> np.ndarray:
    """The noise of each pixel row, (2N,): the click noise and, for a part ``part_sigma`` metres off where
    the cuboid model puts it, that offset seen from the camera, ``f part_sigma / z`` pixels at depth ``z``
    (at least 0.5 m). Arrows get the click noise only: where on the ground one is drawn is an unknown of the
    fit, not an error."""
    if part_sigma <= 0.0:
        return np.full(2 * problem.parts.n_clicks, float(click_sigma))
    z = np.maximum(problem.points_cam(R, t, p)[:, 2], 0.5)
    f = 0.5 * (problem.K[0, 0] + problem.K[1, 1])
    # Keypoints and plates carry their own spread in their weights (:mod:`.robust`): their weighted rows have the
    # click noise alone.
    on_body = np.array([vocabulary.on_body(label) and not vocabulary.soft(label)
                        for label in problem.parts.click_labels])
    return np.repeat(np.sqrt(click_sigma**2 + on_body * (f * part_sigma / z) ** 2), 2)


def _sandwich(J_px: np.ndarray, J_cue: np.ndarray, lam: float, sigmas: np.ndarray) -> np.ndarray:
    """``H^-1 (J_px^T S^2 J_px + lam^2 J_cue^T J_cue) H^-1`` with ``H = J_px^T J_px + lam J_cue^T J_cue`` and
    ``S`` the rows' noise (:func:`row_sigmas`).

    Computed as ``X X^T`` with ``X = H^-1 [J_px^T S, lam J_cue^T]``, ``H`` scaled to a unit diagonal first, so
    that no variance comes out negative however badly the fit is conditioned; a direction ``H`` does not
    determine at all gets infinite variance (never zero)."""
    H = J_px.T @ J_px + lam * (J_cue.T @ J_cue)
    scale = 1.0 / np.sqrt(np.maximum(np.diag(H), 1e-300))
    H_scaled = H * scale[:, None] * scale[None, :]
    L = np.hstack([(J_px * sigmas[:, None]).T, lam * J_cue.T]) * scale[:, None]
    try:
        X = np.linalg.solve(H_scaled, L) * scale[:, None]
    except np.linalg.LinAlgError:
        return np.full_like(H, np.inf)
    if not np.all(np.isfinite(X)):
        return np.full_like(H, np.inf)
    return X @ X.T


def ypr_gradient(R: np.ndarray) -> np.ndarray:
    """d(ry, pitch, roll) / d delta at ``R = R_hat exp([delta]x)``: (3, 3).

    With ``R = R_y(ry) R_level R_Y(pitch) R_X(roll)`` (:func:`toosicubix.geometry.R_cam_vehicle_from_ypr`),
    the rates of the three angles turn the vehicle about, in its own frame, ``R^T e_y`` (camera y),
    ``R_X(roll)^T e_y`` and ``e_x``: ``delta = M (d ry, d pitch, d roll)`` with those columns, so the
    gradient is ``M^-1`` (singular only with the nose straight up or down).
    """
    roll = ypr_from_R_cam_vehicle(R)[2]
    e_x, e_y = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    return np.linalg.inv(np.column_stack([R.T @ e_y, rot_x(roll).T @ e_y, e_x]))


def uncertainty_from_jacobians(J_px: np.ndarray, J_cue: np.ndarray, lambda_px: float, sigmas: np.ndarray,
                               G: np.ndarray, t: np.ndarray) -> Uncertainty:
    """Standard deviations of a fit from the rows :func:`jacobians` gives (any subset of clicks and of
    parameters, the rotation, translation and dimensions first), their noise ``sigmas`` (:func:`row_sigmas`)
    and ``G = ypr_gradient(R)``: what :func:`analyse` reports when the rows are all of them."""
    return uncertainty_from_covariance(_sandwich(J_px, J_cue, lambda_px, sigmas), G, t)


def uncertainties_with_added_clicks(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray,
                                    base_params: np.ndarray, n_base_clicks: int,
                                    added: list[tuple[int, int] | np.ndarray], click_sigma: float,
                                    part_sigma: float = 0.0) -> tuple[Uncertainty, list[Uncertainty]]:
    """The uncertainty of a fit, and of the same fit with each of some candidate annotations added, from one
    Jacobian of a model that holds them all (:mod:`toosicubix.solver.guidance`).

    Parameters
    ----------
    problem : its parts model holds the fit's clicks first (``n_base_clicks``), then every candidate's
    R, t, p : the pose (3, 3), (3,) and every parameter (P,) of that model
    base_params : (P0,) indices in ``p`` of the fit's own parameters, in its own order
    added : per candidate, its click indices ``[first, last)``, or an array of them (several candidates at once)
    click_sigma, part_sigma : as :func:`row_sigmas`

    Returns
    -------
    now : the fit's uncertainty; with : per candidate, with it clicked (its own new unknowns included)
    """
    J_px, J_cue = jacobians(problem, R, t, p)
    sigmas = row_sigmas(problem, R, t, p, click_sigma, part_sigma)
    G = ypr_gradient(R)
    A = problem.parts.A
    base_rows = np.arange(2 * n_base_clicks)
    base_cols = 6 + np.asarray(base_params)
    cols0 = np.concatenate([np.arange(6), base_cols])
    # The cue rows: the scale and upright rows, then each arrow's rows (:meth:`Problem.arrow_rows`), which see the
    # pose: a candidate arrow's rows count only with that candidate.
    tails = np.asarray(problem.parts.arrow_tails, dtype=int)
    per_arrow = problem.n_arrow_rows // max(len(tails), 1)
    first_arrow_row = len(J_cue) - problem.n_arrow_rows

    def cue_rows(clicks: np.ndarray) -> np.ndarray:
        arrows = np.flatnonzero(np.isin(tails, clicks))
        own = (first_arrow_row + per_arrow * arrows[:, None] + np.arange(per_arrow)).ravel()
        return np.concatenate([np.arange(first_arrow_row), own]).astype(int)

    base_cues = cue_rows(np.arange(n_base_clicks))
    now = uncertainty_from_jacobians(J_px[base_rows][:, cols0], J_cue[base_cues][:, cols0], problem.lambda_px,
                                     sigmas[base_rows], G, t)
    out = []
    for entry in added:
        clicks = np.arange(*entry) if isinstance(entry, tuple) else np.asarray(entry, dtype=int)
        own = np.flatnonzero(np.any(A[clicks] != 0, axis=(0, 1)))
        cols = np.concatenate([cols0, 6 + np.setdiff1d(own, base_cols - 6)])
        r = np.concatenate([base_rows, (2 * clicks[:, None] + np.arange(2)).ravel()])
        cues = cue_rows(np.concatenate([np.arange(n_base_clicks), clicks]))
        out.append(uncertainty_from_jacobians(J_px[r][:, cols], J_cue[cues][:, cols], problem.lambda_px, sigmas[r],
                                              G, t))
    return now, out


def uncertainty_from_covariance(cov: np.ndarray, G: np.ndarray, t: np.ndarray) -> Uncertainty:
    """The standard deviations of a fit from the covariance ``cov`` (6 + P, 6 + P) of ``(delta, t, p)`` (``p``'s
    first three the dimensions), the yaw-pitch-roll gradient ``G`` (3, 3) (:func:`ypr_gradient`) and ``t`` (3,);
    every one infinite when ``cov`` is not finite."""
    if not np.all(np.isfinite(cov)):  # nothing determined: every standard deviation infinite
        inf = math.inf
        return Uncertainty(inf, inf, inf, inf, inf, np.full(3, inf), np.full(2, inf), inf, cov)
    cov_ypr = G @ cov[:3, :3] @ G.T
    std_ypr = np.rad2deg(np.sqrt(np.clip(np.diag(cov_ypr), 0.0, None)))
    cov_t = cov[3:6, 3:6]
    depth = float(np.sqrt(max(cov_t[2, 2], 0.0)))
    distance = float(np.linalg.norm(t))
    g_scale = t / distance**2  # d log|t| / dt
    return Uncertainty(
        yaw_deg=float(std_ypr[0]), pitch_deg=float(std_ypr[1]), roll_deg=float(std_ypr[2]),
        depth_m=depth, depth_rel=depth / abs(float(t[2])),
        dimensions=np.sqrt(np.clip(np.diag(cov[6:9, 6:9]), 0.0, None)),
        position_m=np.sqrt(np.clip(np.array([cov_t[0, 0], cov_t[2, 2]]), 0.0, None)),
        scale_rel=float(np.sqrt(max(g_scale @ cov_t @ g_scale, 0.0))), covariance=cov,
    )


def analyse(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray, click_sigma: float,
            scale_from: str | None = None, part_sigma: float = 0.0,
            J: np.ndarray | None = None) -> tuple[Uncertainty, Observability]:
    """Uncertainty and observability of a fit together (one Jacobian, one yaw-pitch-roll gradient); ``J`` as in
    :func:`jacobians`."""
    J_px, J_c = jacobians(problem, R, t, p, J)
    C = J_c.T @ J_c
    sigmas = row_sigmas(problem, R, t, p, click_sigma, part_sigma)
    G = ypr_gradient(R)
    u = uncertainty_from_covariance(_sandwich(J_px, J_c, problem.lambda_px, sigmas), G, t)
    full, clicks_only = _information_variances(J_px, C, sigmas, _gradients(problem, R, t, p, G))
    return u, _observability(full, clicks_only, scale_from, problem.parts.keypoints_only,
                             problem.upright_sigma is not None, tuple(problem.row_cues))


def _information_variances(J_px: np.ndarray, C: np.ndarray, sigmas: np.ndarray,
                           gradients: dict[str, np.ndarray]) -> tuple[dict[str, float], dict[str, float]]:
    """Posterior variances of the quantities with the ``gradients``, from clicks and cues, and from the clicks
    alone (cues times 1e-6): ``g^T (J^T W J + c C)^-1 g``, solved with the matrix scaled to a unit diagonal."""
    whitened = J_px / sigmas[:, None]
    data = whitened.T @ whitened
    names = list(gradients)
    Gm = np.column_stack([gradients[k] for k in names])
    out = []
    for weight in (1.0, 1e-6):
        M = data + weight * C
        scale = 1.0 / np.sqrt(np.maximum(np.diag(M), 1e-300))
        try:
            X = np.linalg.solve(M * scale[:, None] * scale[None, :], Gm * scale[:, None]) * scale[:, None]
        except np.linalg.LinAlgError:
            X = np.linalg.pinv(M, hermitian=True) @ Gm
        out.append({k: float(Gm[:, i] @ X[:, i]) for i, k in enumerate(names)})
    return out[0], out[1]


def _gradients(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray,
               G: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Gradients over ``(delta, t, p)`` of yaw, pitch, roll, and of each dimension against the scale:
    ``log d_k - log z_c`` with ``z_c`` the depth of the centroid of the clicked parts (arrows left out). Their
    points are fixed by their rays up to the common scale, so ``z_c`` changes with the scale and with nothing
    else. An arrow's ends are not: they may slide along their rays when the dimension along the arrow is free."""
    n = 6 + len(p)
    G = ypr_gradient(R) if G is None else G
    out = {}
    for k, name in enumerate(("yaw", "pitch", "roll")):
        g = np.zeros(n)
        g[:3] = G[k]
        out[name] = g
    rigid = [i for i, label in enumerate(problem.parts.click_labels) if vocabulary.on_body(label)]
    A_mean = problem.A[rigid].mean(axis=0) if rigid else problem.A_mean
    c = A_mean @ p  # centroid, vehicle frame
    z_c = float(R[2] @ c + t[2])
    d_log_zc = np.zeros(n)
    d_log_zc[0:3] = -(R @ np.array([[0.0, -c[2], c[1]], [c[2], 0.0, -c[0]], [-c[1], c[0], 0.0]]))[2] / z_c
    d_log_zc[5] = 1.0 / z_c
    d_log_zc[6:] = (R @ A_mean)[2] / z_c
    for k, name in enumerate(("length", "width", "height")):
        g = -d_log_zc.copy()
        g[6 + k] += 1.0 / p[k]
        out[name] = g
    return out


@dataclass(frozen=True)
class Observability:
    """For each of yaw, pitch, roll, length, width, height: how much the cues tighten it (results.json's
    ``observability``).

    Attributes
    ----------
    ratios : quantity -> variance from the clicks alone / variance from clicks and cues (>= 1; ``inf``: the clicks
        alone do not determine it); large means the clicks leave it to the cues
    status : quantity -> 'clicks', 'mostly cues' (ratio > PRIOR_SET_RATIO) or 'cues only' (> UNDETERMINED_RATIO)
    sentences : plain sentences, one per quantity the clicks do not fix, and one on the scale
        (:func:`observability_sentences`)
    """

    ratios: dict[str, float]
    status: dict[str, str]
    sentences: tuple[str, ...]

    def to_json(self) -> dict:
        return {"determined_by": dict(self.status),
                "variance_ratios": {k: infinite_as_none(v) for k, v in self.ratios.items()},
                "sentences": list(self.sentences)}

    @classmethod
    def from_json(cls, d: dict) -> Observability:
        """The inverse of :meth:`to_json`."""
        return cls({k: none_as_infinite(v) for k, v in d["variance_ratios"].items()}, dict(d["determined_by"]),
                   tuple(d["sentences"]))


def observability_sentences(status: dict[str, str], scale_from: str | None, keypoints_only: bool = False,
                            upright: bool = False, scale_cues: tuple[str, ...] = ()) -> tuple[str, ...]:
    """Plain sentences, one per quantity the clicks do not fix (``status`` as :attr:`Observability.status`), and
    one on the scale (``scale_from``, the cue that sets it). ``keypoints_only``: every click is a keypoint (or plate)
    at a typical position, and the advice names keypoints. ``upright``: the vehicle stands upright on a road (a
    ground block): pitch and roll left to the cues are one sentence saying the road sets them, with no advice,
    since that is its job. ``scale_cues``: the cues that share the scale (:attr:`~toosicubix.solver.fit.FitResult.
    scale_shares`' keys, or every cue of the problem): the scale's advice names only the cues the vehicle lacks."""
    out = []
    hints = _KEYPOINT_HINTS if keypoints_only else _HINTS
    on_road = [q for q in ("pitch", "roll") if upright and status[q] != "clicks"]
    if on_road:
        out.append(f"{' and '.join(on_road)} set by the road (the vehicle stands upright on it)")
    for name in QUANTITIES:
        if name in on_road:
            continue
        if status[name] == "cues only":
            out.append(f"{name} set by the prior, not by the clicks: {hints[name]}")
        elif status[name] == "mostly cues":
            out.append(f"{name} mostly set by the prior: {hints[name]}")
    if scale_from:
        source = {"size prior": "the size prior", "ground contact": "the camera height"}.get(scale_from, scale_from)
        out.append(f"scale set by {source} (no click fixes it){_scale_hint(scale_from, scale_cues)}")
    return tuple(out)


def _scale_hint(scale_from: str, scale_cues: tuple[str, ...]) -> str:
    """What would pin a scale the size prior sets: the cues the vehicle lacks (a ground block's camera height, a
    known size); when it has them all, that they weigh less than the prior here."""
    if scale_from != "size prior":
        return ""
    lacking = []
    if "ground contact" not in scale_cues:
        lacking.append("a ground block (the camera height)")
    if not any(cue.startswith(("length ", "known ", "plate")) for cue in scale_cues):
        lacking.append("a known size (licence plate, wheelbase, tyre, known dimensions)")
    if lacking:
        return f": {' or '.join(lacking)} pins it better"
    return ": the camera height and the known sizes given weigh less than it at this distance"


def _observability(full: dict[str, float], clicks_only: dict[str, float], scale_from: str | None,
                   keypoints_only: bool, upright: bool, scale_cues: tuple[str, ...] = ()) -> Observability:
    ratios, status = {}, {}
    for name, v_full in full.items():
        v_clicks = clicks_only[name]
        ratio = v_clicks / v_full if v_full > 0 else math.inf
        ratios[name] = ratio
        status[name] = ("cues only" if ratio > UNDETERMINED_RATIO else
                        "mostly cues" if ratio > PRIOR_SET_RATIO else "clicks")
    return Observability(ratios, status,
                         observability_sentences(status, scale_from, keypoints_only, upright, scale_cues))


def residual_dof(J: np.ndarray, n_pixel_rows: int) -> float:
    """The effective degrees of freedom of a fit's pixel residuals: ``n - 2 tr(H) + tr(H^2)``, with ``H`` the
    pixel rows' block of the hat matrix ``J (J^T J)^+ J^T`` at the optimum (``J`` (M, 6 + P), every row
    weighted, the pixel rows first). Noise of variance ``sigma^2`` per row leaves ``E |r_px|^2 = sigma^2`` times
    this (linearised). Without cues it is ``n`` minus the unknowns the clicks fix; where the prior or another
    cue holds a direction the clicks barely see, that direction soaks up less noise, and it is larger."""
    J_px = J[:n_pixel_rows]
    H = J_px @ np.linalg.pinv(J.T @ J) @ J_px.T  # (n, n), symmetric
    return float(n_pixel_rows - 2.0 * np.trace(H) + np.sum(H * H))


def confidence(u: Uncertainty, yaw_within_deg: float = 10.0, depth_within_rel: float = 0.1) -> float:
    """The probability, under the Gaussian uncertainty, that the yaw is within ``yaw_within_deg`` and the depth
    within ``depth_within_rel`` of the truth (taken as independent): the KITTI score of a fit."""
    p_yaw = math.erf(yaw_within_deg / (math.sqrt(2.0) * max(u.yaw_deg, 1e-12)))
    p_depth = math.erf(depth_within_rel / (math.sqrt(2.0) * max(u.depth_rel, 1e-12)))
    return p_yaw * p_depth
