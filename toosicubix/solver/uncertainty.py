"""How well a fitted cuboid is determined: covariance, standard deviations, what the clicks fix, confidence.

The fit minimizes ``F = |r_px|^2 + sum_k lambda_k r_cue,k^2`` (pixel residuals; size prior, known sizes, ground
cues as standardized residuals, each weighed by ``lambda_px``, or the upright rows of a vehicle of keypoints by the
click noise squared: :attr:`.problem.Problem.cue_row_lambdas`, ``Lambda`` below). Linearized at the optimum, with
clicks off by independent Gaussian noise of ``click_sigma`` pixels per coordinate and the vehicle off its prior (and
the road off its stated plane) by one standard deviation per standardized residual, the estimate's error has
covariance

    Cov = H^-1 (click_sigma^2 J_px^T J_px + J_cue^T Lambda^2 J_cue) H^-1,  H = J_px^T J_px + J_cue^T Lambda J_cue

over ``theta = (delta, t, p)`` with ``R = R_hat exp([delta]x)``: the estimator's own spread, right whatever
``Lambda`` is (when every ``lambda_k = click_sigma^2`` it is the Laplace posterior ``click_sigma^2 H^-1``).
Reported quantities are functions of ``theta`` whose standard deviations follow by the chain rule.

What the clicks determine: for each quantity, its posterior variance from the clicks' information alone
(``A / click_sigma^2`` with ``A = J_px^T J_px``, the cues' information ``C = J_cue^T J_cue`` scaled by 1e-6 to
keep it invertible) against its variance from both (``(A / click_sigma^2 + C)^-1``). Along a direction no click
fixes, the first is a million times the second. No click ever fixes the scale (the direction ``(0, t, p)`` is
exactly blind to them), but no measured quantity moves along it: the rotations have no part in it, and the
dimensions are measured against the depth of the clicked parts' centroid (:func:`_gradients`). So the scale never
inflates a ratio by itself (pinning it moves them by at most a few times where the clicks leave another direction
free, and not at all where they do not); a large ratio always means a direction the clicks leave free (or nearly).

What sets a quantity the clicks leave to the cues (:func:`_setters`): the cue group (the size prior, the road the
vehicle stands upright on, the camera height, known sizes, arrows' zones) which with the clicks alone restores its
variance, else those without which it widens. The advice for it names only the requirements its clicks do not meet
yet (:func:`_advice`: parts already clicked, by name or within two click sigmas of a click, are never asked for,
:mod:`.clicked`); when they meet them all, what limits it (:func:`_limit`): another quantity it is fixed only
together with (:func:`_follows`), or the view.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

from toosicubix import vocabulary
from toosicubix.geometry import rot_x, ypr_from_R_cam_vehicle
from toosicubix.parts.linear import PartsModel
from toosicubix.solver.clicked import ALREADY_CLICKED_SIGMAS, named_as_clicked, near_clicks
from toosicubix.solver.problem import Problem
from toosicubix.solver.refine import residuals_and_jacobian
from toosicubix.solver.robust import spread_px
from toosicubix.vocabulary import KINDS

#: A vehicle's clicks are all on one end when each sits at least this fraction of its length from the middle, all on
#: one side (:func:`one_end`): a rear view's lamps, plate, boot and rear glass; a door or a wheel is not.
END_FRACTION = 0.15
#: A quantity is "mostly set by the cues" when switching them off multiplies its variance by more than this
#: (its standard deviation by 2).
PRIOR_SET_RATIO = 4.0
#: ... and "not fixed by the clicks at all" above this (standard deviation by 100): in practice a direction
#: the clicks leave free, whose ratio is about 1e6, the inverse of the cues' scaling.
UNDETERMINED_RATIO = 1e4
QUANTITIES = ("yaw", "pitch", "roll", "length", "width", "height")

#: A click pins a dimension when its position along that axis is a fixed fraction of the dimension (no unknown of
#: its own): an end at least END_FRACTION of the length from the middle, a side this fraction of the width, a top or a
#: bottom at least this high or at most this low (fractions of the height; a cuboid's faces are at 0.5, 1 and 0).
SIDE_FRACTION = 0.25
HIGH_FRACTION, LOW_FRACTION = 0.7, 0.35

#: The cue rows' groups as a person knows them (:func:`_cue_groups`), in the order sentences name them.
_CUE_NAMES = {"size prior": "the size prior", "axles": "where cars have their axles", "road": "the road",
              "camera height": "the camera height", "known sizes": "the known sizes",
              "arrows": "where its arrows are drawn"}

# What fixes each quantity, as requirements on the clicks: a fact about where clicks sit (:func:`_clicked`), or
# alternatives of annotations (kind, name) any one of which, all clicked, meets it. A quantity's advice names the
# requirements not met yet: for yaw and roll any one would do ("or"), for the others each is needed ("and").
_WHEELS = {(axle, side): ("point", f"wheel-{axle}-{side}") for axle in ("front", "rear") for side in ("left", "right")}
_ONE_SIDE = tuple((_WHEELS["front", side], _WHEELS["rear", side]) for side in ("left", "right"))
_ONE_AXLE = tuple((_WHEELS[axle, "left"], _WHEELS[axle, "right"]) for axle in ("front", "rear"))
_PAIR = ((("symmetry", "front"),), (("symmetry", "rear"),))
_ARROW = tuple((("direction", axis),) for axis in ("forward", "backward", "leftward", "rightward"))
_ANY = {
    "yaw": (("two wheels of one side", _ONE_SIDE), ("both ends of an axle", _ONE_AXLE), ("a light pair", _PAIR),
            ("a forward or sideways arrow", _ARROW)),
    "roll": (("both wheels of an axle", _ONE_AXLE), ("a light pair", _PAIR)),
}
_ALL = {"pitch": ("ends", "low"), "length": ("ends",), "width": ("sides",), "height": ("high", "low")}
_KEYPOINT_ALL = {"yaw": ("along",), "pitch": ("ends", "low"), "roll": ("across",), "length": ("ends",),
                 "width": ("sides",), "height": ("high", "low")}
#: Requirement -> (phrase when nothing of it is clicked, phrase per fact when only that one is missing).
_PHRASES = {
    "ends": ("a front and a rear part (both ends of the vehicle)", {"front": "a front part", "rear": "a rear part"}),
    "sides": ("parts on both sides at the body's full width (both wheels of an axle, both edges of an end)",
              {"left": "a part on its left side (a left wheel or edge)",
               "right": "a part on its right side (a right wheel or edge)"}),
    "high": ("a roof or top part", {}),
    "low": ("a part on the ground (a wheel)", {}),
}
_KEYPOINT_PHRASES = {
    "ends": ("a keypoint at the front and one at the rear",
             {"front": "a keypoint at the front", "rear": "a keypoint at the rear"}),
    "sides": ("keypoints on both sides, as far apart as they go (both mirrors, both lamps of one end)",
              {"left": "a keypoint far out on its left side (a mirror, a lamp)",
               "right": "a keypoint far out on its right side (a mirror, a lamp)"}),
    "high": ("a high keypoint (a glass top corner)", {}),
    "low": ("a low keypoint (a wheel centre)", {}),
    "along": ("keypoints front to rear along one side (a front and a rear wheel centre, a side's lamps)", {}),
    "across": ("keypoints on both sides of one end (its left and right lamps)", {}),
}
_FACTS = {"ends": ("front", "rear"), "sides": ("left", "right"), "high": ("high",), "low": ("low",),
          "along": ("along",), "across": ("across",)}


@dataclass(frozen=True)
class _Clicked:
    """What a vehicle's clicks already give (:func:`_clicked`): ``names``, the annotations (kind, name) it has or
    that are predicted within two click sigmas of a click (:mod:`.clicked`); ``facts``, where its clicks pin the
    cuboid: 'front', 'rear' (an end), 'left', 'right' (a side at full width), 'high', 'low', and for keypoints
    'along' (front and rear on one side) and 'across' (left and right on one end)."""

    names: frozenset[tuple[str, str]] = frozenset()
    facts: frozenset[str] = frozenset()


def _advice(name: str, clicked: _Clicked, keypoints_only: bool = False) -> str | None:
    """What to click so that the clicks fix ``name``, leaving out what ``clicked`` has; None when they have it all."""
    if not keypoints_only and name in _ANY:
        missing = [text for text, alternatives in _ANY[name]
                   if not any(set(parts) <= clicked.names for parts in alternatives)]
        clicks = [text for text in missing if "arrow" not in text]
        arrow = [f"draw {text}" for text in missing if "arrow" in text]
        # Any one usually fixes it; when one is there and it is still the cues', say so, then what else would.
        there = [text for text, _ in _ANY[name] if text not in missing]
        but = (f"{_and(there)} {'is' if len(there) == 1 else 'are'} not enough from this view; " if there and
               (clicks or arrow) else "")
        if name == "roll":
            return f"{but}click parts on both sides ({_listing(clicks)})" if clicks else None
        if clicks and arrow:
            return f"{but}click {', '.join(clicks)}, or {arrow[0]}"
        return f"{but}click {_listing(clicks)}" if clicks else (f"{but}{arrow[0]}" if arrow else None)
    phrases = _KEYPOINT_PHRASES if keypoints_only else _PHRASES
    needed = []
    for requirement in (_KEYPOINT_ALL if keypoints_only else _ALL)[name]:
        lacking = [f for f in _FACTS[requirement] if f not in clicked.facts]
        if len(lacking) == len(_FACTS[requirement]):
            needed.append(phrases[requirement][0])
        elif lacking:
            needed.append(phrases[requirement][1][lacking[0]])
    return f"click {' and '.join(needed)}" if needed else None


def _listing(items: list[str]) -> str:
    """'a', 'a or b', 'a, b, or c'."""
    if len(items) <= 2:
        return " or ".join(items)
    return f"{', '.join(items[:-1])}, or {items[-1]}"


#: The advice for a vehicle with nothing clicked: every requirement of each quantity, in the cuboid's vocabulary,
#: and for a vehicle clicked only in keypoints (a mapping's, e.g. ApolloCar3D's): no arrows, no ground contacts, no
#: cuboid edges.
_HINTS = {name: _advice(name, _Clicked()) for name in QUANTITIES}
_KEYPOINT_HINTS = {name: _advice(name, _Clicked(), keypoints_only=True) for name in QUANTITIES}


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
    """The pixel rows and the standardized cue rows of the Jacobian w.r.t. ``(delta, t, p)`` (no pivot), each cue
    row divided by the root of its weight (:attr:`.problem.Problem.cue_row_lambdas`); ``J`` is that Jacobian when
    the caller has it already (:func:`.refine.residuals_and_jacobian` at the pose)."""
    if J is None:
        _, J = residuals_and_jacobian(problem, R, t, p)
    n_px = 2 * problem.parts.n_clicks
    if problem.upright_noise_px is None:  # every cue row weighed by lambda_px
        return J[:n_px], J[n_px:] / math.sqrt(problem.lambda_px)
    return J[:n_px], J[n_px:] / np.sqrt(problem.cue_row_lambdas)[:, None]


def row_sigmas(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray, click_sigma: float,
               part_sigma: float = 0.0, soft_noise: tuple[float, float] | None = None) -> np.ndarray:
    """The noise of each pixel row, (2N,): the click noise and, for a part ``part_sigma`` metres off where
    the cuboid model puts it, that offset seen from the camera, ``f part_sigma / z`` pixels at depth ``z``
    (at least 0.5 m). Arrows get the click noise only: where on the ground one is drawn is an unknown of the
    fit, not an error.

    Keypoints and plates carry their own spread in their weights (:mod:`.robust`): their weighted rows have the
    click noise alone, as the fit weighs them. ``soft_noise`` ``(sigma', t)`` says their residuals are rather
    ``sigma'`` pixels on top of ``t`` times the learned spread ``s`` (pixels at the vehicle's distance): their
    weighted rows then have ``click_sigma sqrt(sigma'^2 + t^2 s^2) / sqrt(click_sigma^2 + s^2)``
    (:attr:`.fit.SolverOptions.soft_noise`)."""
    labels = problem.parts.click_labels
    if part_sigma <= 0.0:
        sigmas = np.full(len(labels), float(click_sigma))
    else:
        z = np.maximum(problem.points_cam(R, t, p)[:, 2], 0.5)
        f = 0.5 * (problem.K[0, 0] + problem.K[1, 1])
        on_body = np.array([vocabulary.on_body(label) and not vocabulary.soft(label) for label in labels])
        sigmas = np.sqrt(click_sigma**2 + on_body * (f * part_sigma / z) ** 2)
    if soft_noise is not None:
        s = spread_px(problem, float(np.linalg.norm(t)))
        if s is not None:
            soft = np.array([vocabulary.soft(label) for label in labels])
            sigma, scale = soft_noise
            ratio = np.sqrt((sigma**2 + (scale * s) ** 2) / (click_sigma**2 + s**2))
            sigmas = np.where(soft, click_sigma * ratio, sigmas)
    return np.repeat(sigmas, 2)


def _sandwich(J_px: np.ndarray, J_cue: np.ndarray, lam: float | np.ndarray, sigmas: np.ndarray) -> np.ndarray:
    """``H^-1 (J_px^T S^2 J_px + J_cue^T Lambda^2 J_cue) H^-1`` with ``H = J_px^T J_px + J_cue^T Lambda J_cue``,
    ``S`` the rows' noise (:func:`row_sigmas`) and ``Lambda`` the cue rows' weights: ``lam`` for every row, or
    per row (m,) (:attr:`.problem.Problem.cue_row_lambdas`).

    Computed as ``X X^T`` with ``X = H^-1 [J_px^T S, lam J_cue^T]``, ``H`` scaled to a unit diagonal first, so
    that no variance comes out negative however badly the fit is conditioned; a direction ``H`` does not
    determine at all gets infinite variance (never zero)."""
    if np.ndim(lam) == 0:
        H = J_px.T @ J_px + lam * (J_cue.T @ J_cue)
        weighted_cue_T = lam * J_cue.T
    else:
        weighted_cue = np.asarray(lam)[:, None] * J_cue
        H = J_px.T @ J_px + J_cue.T @ weighted_cue
        weighted_cue_T = weighted_cue.T
    scale = 1.0 / np.sqrt(np.maximum(np.diag(H), 1e-300))
    H_scaled = H * scale[:, None] * scale[None, :]
    L = np.hstack([(J_px * sigmas[:, None]).T, weighted_cue_T]) * scale[:, None]
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


def uncertainty_from_jacobians(J_px: np.ndarray, J_cue: np.ndarray, lambda_px: float | np.ndarray, sigmas: np.ndarray,
                               G: np.ndarray, t: np.ndarray) -> Uncertainty:
    """Standard deviations of a fit from the rows :func:`jacobians` gives (any subset of clicks and of
    parameters, the rotation, translation and dimensions first), their noise ``sigmas`` (:func:`row_sigmas`),
    the cue rows' weights ``lambda_px`` (one, or per row: :attr:`.problem.Problem.cue_row_lambdas`) and
    ``G = ypr_gradient(R)``: what :func:`analyse` reports when the rows are all of them."""
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

    # A scale row on a candidate's own unknowns (the axle prior of an axle only a candidate wheel uses, a candidate's
    # known size) counts only with that candidate: the rows and the unknowns each row sees.
    sees = J_cue[:first_arrow_row, 6:] != 0.0  # (rows, P): the unknowns each scale or upright row sees

    def cue_rows(clicks: np.ndarray, cols: np.ndarray) -> np.ndarray:
        outside = np.ones(sees.shape[1], dtype=bool)
        outside[cols[cols >= 6] - 6] = False
        arrows = np.flatnonzero((tails[:, None] == clicks[None, :]).any(axis=1))  # np.isin's answer, without its sort
        own = (first_arrow_row + per_arrow * arrows[:, None] + np.arange(per_arrow)).ravel()
        shared = np.flatnonzero(~(sees & outside).any(axis=1))
        return np.concatenate([shared, own]).astype(int)

    lam = _cue_lambdas(problem)  # one weight, or one per cue row (the upright rows weighed against the clicks)

    def lam_of(rows: np.ndarray) -> float | np.ndarray:
        return lam if np.ndim(lam) == 0 else np.asarray(lam)[rows]

    base_cues = cue_rows(np.arange(n_base_clicks), cols0)
    now = uncertainty_from_jacobians(J_px[base_rows][:, cols0], J_cue[base_cues][:, cols0], lam_of(base_cues),
                                     sigmas[base_rows], G, t)
    out = []
    not_base = np.ones(A.shape[2], dtype=bool)  # the parameters a candidate may add: those the fit does not have
    not_base[base_cols - 6] = False
    for entry in added:
        clicks = np.arange(*entry) if isinstance(entry, tuple) else np.asarray(entry, dtype=int)
        own = np.any(A[clicks] != 0, axis=(0, 1)) & not_base  # (P,): the candidate's own new unknowns
        cols = np.concatenate([cols0, 6 + np.flatnonzero(own)])
        r = np.concatenate([base_rows, (2 * clicks[:, None] + np.arange(2)).ravel()])
        cues = cue_rows(np.concatenate([np.arange(n_base_clicks), clicks]), cols)
        out.append(uncertainty_from_jacobians(J_px[r][:, cols], J_cue[cues][:, cols], lam_of(cues), sigmas[r],
                                              G, t))
    return now, out


def _cue_lambdas(problem: Problem) -> float | np.ndarray:
    """The cue rows' weights for :func:`_sandwich`: ``lambda_px`` when every row has it, else per row."""
    return problem.lambda_px if problem.upright_noise_px is None else problem.cue_row_lambdas


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
            scale_from: str | None = None, part_sigma: float = 0.0, J: np.ndarray | None = None,
            soft_noise: tuple[float, float] | None = None) -> tuple[Uncertainty, Observability]:
    """Uncertainty and observability of a fit together (one Jacobian, one yaw-pitch-roll gradient); ``J`` as in
    :func:`jacobians`, the rows' noise as :func:`row_sigmas` gives it."""
    J_px, J_c = jacobians(problem, R, t, p, J)
    C = J_c.T @ J_c
    sigmas = row_sigmas(problem, R, t, p, click_sigma, part_sigma, soft_noise)
    G = ypr_gradient(R)
    u = uncertainty_from_covariance(_sandwich(J_px, J_c, _cue_lambdas(problem), sigmas), G, t)
    gradients = _gradients(problem, R, t, p, G)
    whitened = J_px / sigmas[:, None]
    data = whitened.T @ whitened  # the clicks' information
    full, clicks_only = _information_variances(data, C, gradients)
    ratios, status = _status(full, clicks_only)
    keypoints_only, upright = problem.parts.keypoints_only, problem.upright_sigma is not None
    road_user = problem.parts.road_user
    end = None if road_user else one_end(problem.parts, p, R, t)

    def sentences() -> tuple[str, ...]:
        said = _advised(status, keypoints_only, upright, end)
        sources: dict[str, tuple[str, ...]] = {}
        advice: dict[str, str] = {}
        together: dict[str, str] = {}
        if said and road_user:  # what sets them; what to click is its next clicks' (the advice below speaks of a
            # vehicle's wheels, lamps and glass)
            sources = _setters(data, J_c, _cue_groups(problem, len(J_c)), {q: gradients[q] for q in said},
                               {q: full[q] for q in said})
        elif said:  # what sets them and what to click: only for the quantities a sentence advises on
            clicked = _clicked(problem, R, t, p, click_sigma)
            to_click = {name: _advice(name, clicked, keypoints_only) for name in said}
            follows = {name: () if to_click[name] else _follows(name, data, C, gradients, full, status)
                       for name in said}
            needed = list(dict.fromkeys([*said, *(q for name in said for q in follows[name])]))
            sources = _setters(data, J_c, _cue_groups(problem, len(J_c)), {q: gradients[q] for q in needed},
                               {q: full[q] for q in needed})
            for q in _on_road(status, upright):  # as their own sentence says, whatever else would do too
                sources[q] = ("road",)
            together = _together(said, follows)
            for name in said:
                if name in together:
                    continue
                partner = next((q for q, lead in together.items() if lead == name), None)
                advice[name] = to_click[name] or (
                    _jointly(name, partner, sources) if partner else
                    _limit(name, follows[name], sources, float(np.linalg.norm(t))))
            for q, lead in together.items():
                advice[q] = advice[lead]
        return observability_sentences(status, scale_from, keypoints_only, upright, tuple(problem.row_cues), end,
                                       sources, advice, together, road_user)

    return u, Observability(ratios, status, sentences)


def _advised(status: dict[str, str], keypoints_only: bool, upright: bool,
             end: tuple[str, str | None] | None) -> list[str]:
    """The quantities whose sentence names what sets them and advises a click (:func:`observability_sentences`):
    those the clicks leave to the cues, but pitch and roll on a road (the road's job: one sentence, no advice) and
    yaw and length of a vehicle clicked on one end in keypoints (one sentence on the far end)."""
    skip = set(_on_road(status, upright)) | set(_on_one_end(status, keypoints_only, end))
    return [q for q in QUANTITIES if status[q] != "clicks" and q not in skip]


def _on_road(status: dict[str, str], upright: bool) -> list[str]:
    return [q for q in ("pitch", "roll") if upright and status[q] != "clicks"]


def _on_one_end(status: dict[str, str], keypoints_only: bool, end: tuple[str, str | None] | None) -> tuple[str, ...]:
    if keypoints_only and end is not None and (status["yaw"] != "clicks" or status["length"] != "clicks"):
        return ("yaw", "length")
    return ()


def _variances(M: np.ndarray, Gm: np.ndarray) -> np.ndarray:
    """``diag(Gm^T M^-1 Gm)`` (k,) for an information matrix ``M`` (n, n) and gradients ``Gm`` (n, k), solved with ``M``
    scaled to a unit diagonal (a pseudo-inverse when it is singular)."""
    X = _solved(M, Gm)
    return np.array([Gm[:, i] @ X[:, i] for i in range(Gm.shape[1])])


def _solved(M: np.ndarray, Gm: np.ndarray) -> np.ndarray:
    """``M^-1 Gm`` (n, k) with ``M`` (n, n) scaled to a unit diagonal, or its pseudo-inverse's when singular."""
    scale = 1.0 / np.sqrt(np.maximum(np.diag(M), 1e-300))
    try:
        return np.linalg.solve(M * scale[:, None] * scale[None, :], Gm * scale[:, None]) * scale[:, None]
    except np.linalg.LinAlgError:
        return np.linalg.pinv(M, hermitian=True) @ Gm


def _variances_each(Ms: np.ndarray, Gm: np.ndarray) -> np.ndarray:
    """:func:`_variances` of each of a stack of information matrices ``Ms`` (S, n, n): (S, k), in one batched solve
    (the matrices are a dozen unknowns across: a call each would cost more than the arithmetic). Equal to it but in
    the last bits, so only for comparisons (what sets a quantity), never for a figure results.json reports."""
    scale = 1.0 / np.sqrt(np.maximum(np.diagonal(Ms, axis1=1, axis2=2), 1e-300))  # (S, n)
    try:
        X = np.linalg.solve(Ms * scale[:, :, None] * scale[:, None, :], Gm[None] * scale[:, :, None])
        X *= scale[:, :, None]
    except np.linalg.LinAlgError:  # one of them singular: each on its own
        X = np.stack([_solved(M, Gm) for M in Ms])
    return np.einsum("nk,snk->sk", Gm, X)


def _information_variances(data: np.ndarray, C: np.ndarray,
                           gradients: dict[str, np.ndarray]) -> tuple[dict[str, float], dict[str, float]]:
    """Posterior variances of the quantities with the ``gradients``, from clicks and cues, and from the clicks
    alone (cues times 1e-6): ``g^T (J^T W J + c C)^-1 g`` (``data`` the clicks' information ``J^T W J``, ``C`` the
    cues'), solved with the matrix scaled to a unit diagonal."""
    names = list(gradients)
    Gm = np.column_stack([gradients[k] for k in names])
    out = []
    for weight in (1.0, CLICKS_ONLY_WEIGHT):
        v = _variances(data + weight * C, Gm)
        out.append({k: float(v[i]) for i, k in enumerate(names)})
    return out[0], out[1]


#: The cues' weight in "the clicks alone": small enough that a direction no click fixes shows a ratio of about its
#: inverse, large enough to keep the information matrix invertible.
CLICKS_ONLY_WEIGHT = 1e-6


def _status(full: dict[str, float], clicks_only: dict[str, float]) -> tuple[dict[str, float], dict[str, str]]:
    """Each quantity's variance ratio (clicks alone / clicks and cues) and what determines it."""
    ratios, status = {}, {}
    for name, v_full in full.items():
        ratio = clicks_only[name] / v_full if v_full > 0 else math.inf
        ratios[name] = ratio
        status[name] = ("cues only" if ratio > UNDETERMINED_RATIO else
                        "mostly cues" if ratio > PRIOR_SET_RATIO else "clicks")
    return ratios, status


def _cue_groups(problem: Problem, n_rows: int) -> dict[str, np.ndarray]:
    """The cue rows of :func:`jacobians` (``n_rows`` of them: scale rows, upright rows, arrow rows) by what a person
    knows them as (:data:`_CUE_NAMES`' keys): the size prior, where cars have their axles (the axle prior), the known
    sizes, the camera height (the ground contact), the road (the upright rows) and the arrows' zones; groups without
    rows left out."""
    group = {"ground contact": "camera height", "size prior": "size prior", "axle prior": "axles"}
    labels = [group.get(cue, "known sizes") for cue in problem.row_cues]
    labels += ["road"] * (3 if problem.upright_sigma is not None else 0)
    labels += ["arrows"] * (n_rows - len(labels))
    return {g: np.flatnonzero([label == g for label in labels]) for g in _CUE_NAMES if g in labels}


def _setters(data: np.ndarray, J_c: np.ndarray, groups: dict[str, np.ndarray], gradients: dict[str, np.ndarray],
             full: dict[str, float]) -> dict[str, tuple[str, ...]]:
    """For each quantity, the cue groups that set what the clicks leave of it (``data``, the clicks' information;
    ``J_c``, the cue rows; ``full``, the variances with every cue): the one cue that, with the clicks alone, gives
    within :data:`PRIOR_SET_RATIO` of ``full`` (the tightest such), else those whose removal widens the variance by
    more than :data:`PRIOR_SET_RATIO` (or, if none does, the one whose removal widens it most)."""
    names = list(gradients)
    Gm = np.column_stack([gradients[k] for k in names])
    information = {g: J_c[rows].T @ J_c[rows] for g, rows in groups.items()}
    every = sum(information.values(), np.zeros_like(data))
    stack = []
    for C_g in information.values():
        rest = every - C_g
        stack += [data + C_g + CLICKS_ONLY_WEIGHT * rest, data + rest + CLICKS_ONLY_WEIGHT * C_g]
    v_all = _variances_each(np.array(stack), Gm) if stack else np.zeros((0, len(names)))
    only = {g: v_all[2 * j] for j, g in enumerate(information)}
    without = {g: v_all[2 * j + 1] for j, g in enumerate(information)}
    out = {}
    for i, name in enumerate(names):
        v = full[name]
        single = [g for g in groups if only[g][i] <= PRIOR_SET_RATIO * v]
        if single:
            out[name] = (min(single, key=lambda g: only[g][i]),)
            continue
        needed = tuple(g for g in groups if without[g][i] > PRIOR_SET_RATIO * v)
        out[name] = needed or ((max(groups, key=lambda g: without[g][i]),) if groups else ())
    return out


def _follows(name: str, data: np.ndarray, C: np.ndarray, gradients: dict[str, np.ndarray], full: dict[str, float],
             status: dict[str, str]) -> tuple[str, ...]:
    """The fewest other quantities the cues set that ``name`` hangs on: those which, pinned, would leave ``name`` to
    the clicks (its clicks-only variance within :data:`PRIOR_SET_RATIO` of ``full``), in :data:`QUANTITIES`' order;
    empty when no such set does."""
    others = [q for q in QUANTITIES if q != name and status[q] != "clicks"]
    pins = {q: np.outer(gradients[q], gradients[q]) / (CLICKS_ONLY_WEIGHT * full[q]) for q in others}  # known 1000x
    g = gradients[name][:, None]  # better than now
    base = data + CLICKS_ONLY_WEIGHT * C
    for size in range(1, len(others) + 1):
        subsets = list(combinations(others, size))
        v = _variances_each(np.array([base + sum(pins[q] for q in subset) for subset in subsets]), g)[:, 0]
        best = int(np.argmin(v))  # the first of the smallest, as min over the subsets in order
        if v[best] / full[name] <= PRIOR_SET_RATIO:
            return subsets[best]
    return ()


def _together(said: list[str], follows: dict[str, tuple[str, ...]]) -> dict[str, str]:
    """Pairs of quantities the clicks fix only together, each leaving the other to the cues (each one's
    :func:`_follows` is the other): the second of each pair (in :data:`QUANTITIES`' order) -> the first, whose
    sentence says both (two sentences each pointing at the other would tell a person nothing)."""
    out: dict[str, str] = {}
    for a in said:
        f = follows.get(a, ())
        if len(f) == 1 and f[0] in said and follows.get(f[0]) == (a,) and a not in out and f[0] not in out and (
                QUANTITIES.index(a) < QUANTITIES.index(f[0])):
            out[f[0]] = a
    return out


def _setting(quantities: list[str] | tuple[str, ...], sources: dict[str, tuple[str, ...]] | None
             ) -> tuple[str, ...]:
    """The cue groups that set any of ``quantities`` (``sources``: :func:`_setters`; the size prior for one not in
    it), each once, in order."""
    return tuple(dict.fromkeys(g for q in quantities for g in (sources or {}).get(q, ("size prior",))))


def _jointly(name: str, other: str, sources: dict[str, tuple[str, ...]]) -> str:
    """What limits two quantities the clicks fix only together (:func:`_together`)."""
    return (f"the clicks that usually fix them are there, but they fix the {name} and the {other} only together "
            f"(turned and stretched, the cuboid fits them alike), and {_source(_setting((name, other), sources), True)}"
            " picks the pair")


def _limit(name: str, follows: tuple[str, ...], sources: dict[str, tuple[str, ...]], distance: float) -> str:
    """What limits ``name`` when the vehicle has every click that usually fixes it: the quantities it hangs on
    (``follows``, :func:`_follows`) and what sets them, or else the view (``distance`` metres away), and for a
    dimension the cue that would fix it."""
    if follows:
        return (f"the clicks that fix it are there, but they fix the {name} only together with the "
                f"{_and(list(follows))}, which they leave to {_source(_setting(follows, sources), short=True)}")
    known = "; known dimensions would fix it" if name in ("length", "width", "height") else ""
    return (f"the clicks that usually fix it are there, but seen from this view, {distance:.0f} m away, they do not"
            f"{known}")


def _and(items: list[str]) -> str:
    """'a', 'a and b', 'a, b and c'."""
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} and {items[-1]}"


def _source(groups: tuple[str, ...], short: bool = False) -> str:
    """The cue groups that set a quantity, as a person reads them: 'the road (the vehicle stands upright on it)'
    ('the road' when ``short``), 'the road and the size prior'."""
    if groups == ("road",) and not short:
        return "the road (the vehicle stands upright on it)"
    return _and([_CUE_NAMES[g] for g in groups] or ["the cues"])


#: The annotations the advice may ask for (:data:`_ANY`'s alternatives).
_HINTED = frozenset(part for options in _ANY.values() for _, alternatives in options for each in alternatives
                    for part in each)


def _clicked(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray, click_sigma: float) -> _Clicked:
    """What the vehicle's clicks already give the observability's advice (:class:`_Clicked`): the annotations it has
    (:func:`.clicked.named_as_clicked`), those the advice may name that are predicted within
    :data:`.clicked.ALREADY_CLICKED_SIGMAS` click sigmas of a click (the fitted cuboid, its axles and the camera's
    side as :mod:`.guidance` places them), and where its on-body clicks pin the cuboid."""
    parts = problem.parts
    facts = _facts(parts)
    if parts.keypoints_only:  # keypoint advice names no part, only where the clicks sit
        return _Clicked(frozenset(), facts)
    labels = [vocabulary.click(label) for label in parts.click_labels]
    names = named_as_clicked((c.kind, c.name) for c in labels)
    side = 1.0 if (R.T @ -np.asarray(t))[1] >= 0.0 else -1.0
    terms = vocabulary.typical_terms(p[:3], dict(zip(parts.param_names, p, strict=True)), side)
    radius = ALREADY_CLICKED_SIGMAS * click_sigma
    candidates, points, owner = [], [], []  # the advice's parts not clicked, placed on the fit; their points' owner
    for kind, name in sorted(_HINTED - names):
        e = vocabulary.entry(kind, name)
        if e.typical is None or not KINDS[kind].on_body:  # an arrow is drawn anywhere: only one drawn counts
            continue
        xyz = vocabulary.typical_points(e, terms)
        owner += [len(candidates)] * len(xyz)
        candidates.append((kind, name))
        points += xyz
    if candidates:
        points_cam = np.asarray(points, dtype=float) @ R.T + t  # (k, 3)
        owner_of = np.asarray(owner)
        in_front = np.ones(len(candidates), dtype=bool)
        np.logical_and.at(in_front, owner_of, points_cam[:, 2] > 0.0)
        z = np.where(points_cam[:, 2:] > 0.0, points_cam[:, 2:], 1.0)
        uv = points_cam[:, :2] / z @ problem.K[:2, :2].T + problem.K[:2, 2]
        near = np.zeros(len(candidates), dtype=bool)  # any of a part's points near a click (.clicked.near_a_click)
        if len(problem.uv):
            np.logical_or.at(near, owner_of, near_clicks(uv, problem.uv, radius))
        names.update(part for j, part in enumerate(candidates) if in_front[j] and near[j])
    return _Clicked(frozenset(names), facts)


def _facts(parts: PartsModel) -> frozenset[str]:
    """Where a vehicle's on-body clicks pin the cuboid (:attr:`_Clicked.facts`)."""
    facts = set()
    on_body = [i for i, label in enumerate(parts.click_labels) if vocabulary.on_body(label)]
    rows = parts.A[on_body] if on_body else np.zeros((0, 3, 3))  # (M, 3, P)
    own = np.diagonal(rows[:, :, :3], axis1=1, axis2=2)  # (M, 3): each coordinate's term in its own dimension
    alone = np.count_nonzero(rows, axis=2) == (own != 0.0)  # the row has no term but its own dimension's
    # per on-body click: its position as fractions of (dx, dy, dz), NaN along an axis with an unknown
    at = np.where(alone, own, math.nan).reshape(-1, 3)
    with np.errstate(invalid="ignore"):
        x, y, z = at.T
        for fact, hits in (("front", x >= END_FRACTION), ("rear", x <= -END_FRACTION), ("left", y >= SIDE_FRACTION),
                           ("right", y <= -SIDE_FRACTION), ("high", z >= HIGH_FRACTION), ("low", z <= LOW_FRACTION)):
            if np.any(hits):
                facts.add(fact)
        for s in (1.0, -1.0):
            on_side, on_end = s * y >= SIDE_FRACTION, s * x >= END_FRACTION
            if np.any(on_side & (x >= END_FRACTION)) and np.any(on_side & (x <= -END_FRACTION)):
                facts.add("along")
            if np.any(on_end & (y >= SIDE_FRACTION)) and np.any(on_end & (y <= -SIDE_FRACTION)):
                facts.add("across")
    return frozenset(facts)


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


@dataclass(frozen=True, eq=False)
class Observability:
    """For each of yaw, pitch, roll, length, width, height: how much the cues tighten it (results.json's
    ``observability``).

    Attributes
    ----------
    ratios : quantity -> variance from the clicks alone / variance from clicks and cues (>= 1; ``inf``: the clicks
        alone do not determine it); large means the clicks leave it to the cues
    status : quantity -> 'clicks', 'mostly cues' (ratio > PRIOR_SET_RATIO) or 'cues only' (> UNDETERMINED_RATIO)
    sentences : plain sentences, one per quantity the clicks do not fix, and one on the scale
        (:func:`observability_sentences`). Given as a tuple, or as a function that makes it: worked out the first
        time they are read (what sets each quantity and what to click costs several solves a vehicle, and the page's
        refits never read them), and before the object is pickled (a worker's result goes to the parent whole).
    """

    ratios: dict[str, float]
    status: dict[str, str]
    _sentences: tuple[str, ...] | Callable[[], tuple[str, ...]] = field(repr=False)

    @property
    def sentences(self) -> tuple[str, ...]:
        if callable(self._sentences):
            object.__setattr__(self, "_sentences", tuple(self._sentences()))
        return self._sentences

    def __reduce__(self) -> tuple:
        return type(self), (self.ratios, self.status, self.sentences)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Observability):
            return NotImplemented
        return (self.ratios, self.status, self.sentences) == (other.ratios, other.status, other.sentences)

    __hash__ = None  # type: ignore[assignment]  # mutable dicts inside, as the dataclass it was

    def __repr__(self) -> str:
        return f"Observability(ratios={self.ratios!r}, status={self.status!r}, sentences={self.sentences!r})"

    def to_json(self) -> dict:
        return {"determined_by": dict(self.status),
                "variance_ratios": {k: infinite_as_none(v) for k, v in self.ratios.items()},
                "sentences": list(self.sentences)}

    @classmethod
    def from_json(cls, d: dict) -> Observability:
        """The inverse of :meth:`to_json`."""
        return cls({k: none_as_infinite(v) for k, v in d["variance_ratios"].items()}, dict(d["determined_by"]),
                   tuple(d["sentences"]))


def one_end(parts: PartsModel, p: np.ndarray, R: np.ndarray | None = None, t: np.ndarray | None = None
            ) -> tuple[str, str | None] | None:
    """The end every click of a vehicle clicked in keypoints only sits on, 'front' or 'rear' (each click's typical
    position at least :data:`END_FRACTION` of the length from the middle, on that side), and with a pose ``R``
    (3, 3), ``t`` (3,) the side the camera sees, 'left' or 'right' (None without); None when the clicks span the
    length or are not all keypoints. ``p`` (P,): the vehicle's unknowns, its dimensions first.

    ApolloCar3D's end-on cars clicked on one end only (a rear view's lamps, plate, boot and rear glass) leave their
    length and yaw to the size prior: on the comparison half, 268 end-on cars fitted from their near end's keypoints
    had a mean E_R of 7.52 degrees, and one keypoint toward the far end took it to 3.38 (benchmarks/apollocar3d.py's
    far-end diagnostic; benchmarks/decisions.md, rule 23's section)."""
    if not parts.keypoints_only:
        return None
    x = (parts.A @ p)[:, 0] / p[0]  # (N,) each click's position along the length, fractions from the middle
    end = "front" if x.min() > END_FRACTION else "rear" if x.max() < -END_FRACTION else None
    if end is None:
        return None
    side = None if R is None or t is None else ("left" if (R.T @ -np.asarray(t))[1] >= 0.0 else "right")
    return end, side


def observability_sentences(status: dict[str, str], scale_from: str | None, keypoints_only: bool = False,
                            upright: bool = False, scale_cues: tuple[str, ...] = (),
                            end: tuple[str, str | None] | None = None,
                            sources: dict[str, tuple[str, ...]] | None = None,
                            advice: dict[str, str] | None = None,
                            together: dict[str, str] | None = None, road_user: bool = False) -> tuple[str, ...]:
    """Plain sentences, one per quantity the clicks do not fix (``status`` as :attr:`Observability.status`), and
    one on the scale (``scale_from``, the cue that sets it). ``keypoints_only``: every click is a keypoint (or plate)
    at a typical position, and the advice names keypoints. ``upright``: the vehicle stands upright on a road (a
    ground block): pitch and roll left to the cues are one sentence saying the road sets them, with no advice,
    since that is its job. ``scale_cues``: the cues that share the scale (:attr:`~toosicubix.solver.fit.FitResult.
    scale_shares`' keys, or every cue of the problem): the scale's advice names only the cues the vehicle lacks.
    ``end``: the end every keypoint sits on and the side the camera sees (:func:`one_end`): when the clicks leave the
    yaw or the length to the prior, one sentence says so and which click fixes both, in place of their hints.
    ``sources``: per quantity, the cue groups that set it (:func:`_setters`; the size prior when not given), named
    in its sentence. ``advice``: per quantity, what to click that the vehicle lacks, or what limits it when it has
    every such click (:func:`_advice`, :func:`_limit`; every requirement when not given). ``together``: a quantity
    -> the one whose sentence also says it (:func:`_together`: the clicks fix the two only together).
    ``road_user``: every click is a keypoint of a road user's own vocabulary (:attr:`~toosicubix.parts.linear.
    PartsModel.road_user`): the sentences name what sets each quantity, and no vehicle part to click."""
    out = []
    hints = {} if road_user else _KEYPOINT_HINTS if keypoints_only else _HINTS
    on_road = _on_road(status, upright)
    if on_road:
        out.append(f"{' and '.join(on_road)} set by the road (the vehicle stands upright on it)")
    on_one_end = _on_one_end(status, keypoints_only, end)
    if on_one_end:
        out.append(_far_end_sentence(*end))
    together = together or {}
    for name in QUANTITIES:
        if name in on_road or name in on_one_end or name in together:
            continue
        both = [name, *(q for q, lead in together.items() if lead == name)]
        source, what = _source(_setting(both, sources)), (advice or {}).get(name) or hints.get(name)
        said, then = " and ".join(both), f": {what}" if what else ""
        if status[name] == "cues only" or any(status[q] == "cues only" for q in both[1:]):
            out.append(f"{said} set by {source}, not by the clicks{then}")
        elif status[name] == "mostly cues":
            out.append(f"{said} mostly set by {source}{then}")
    if scale_from:
        source = {"size prior": "the size prior", "ground contact": "the camera height"}.get(scale_from, scale_from)
        out.append(f"scale set by {source} (no click fixes it){_scale_hint(scale_from, scale_cues, road_user)}")
    return tuple(out)


def _far_end_sentence(end: str, side: str | None) -> str:
    """What to click on a vehicle whose keypoints all sit on its ``end``, seen from ``side`` (or None)."""
    far = "front" if end == "rear" else "rear"
    along = f"along its {side} side" if side else "along a side it shows"
    example = f"its {side} {far} wheel centre" if side else f"a {far} wheel centre"
    return (f"every keypoint is on its {end} end, so its yaw and length rest on the size prior: click one more "
            f"toward the far end, the {far}, {along} ({example}, or a corner of a {far} door)")


def _scale_hint(scale_from: str, scale_cues: tuple[str, ...], road_user: bool = False) -> str:
    """What would pin a scale the size prior sets: the cues the vehicle lacks (a ground block's camera height, a
    known size: a road user's known dimensions only); when it has them all, that they weigh less than the prior
    here."""
    if scale_from != "size prior":
        return ""
    lacking = []
    if "ground contact" not in scale_cues:
        lacking.append("a ground block (the camera height)")
    if not any(cue.startswith(("length ", "known ", "plate")) for cue in scale_cues):
        lacking.append("known dimensions" if road_user else
                       "a known size (licence plate, wheelbase, tyre, known dimensions)")
    if lacking:
        return f": {' or '.join(lacking)} pins it better"
    return ": the camera height and the known sizes given weigh less than it at this distance"


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
