"""What to click next: for each part a person has not clicked, how much clicking it would shrink the fitted
cuboid's yaw and depth uncertainty.

A candidate part is placed where it typically sits on the fitted cuboid (lights at 38 % of the width from the
centre line and 55 % of the height, badges at 45 % of the height, vertical edges at mid height, roof features
a tenth of the length behind the middle, wheels at the fitted axles or 30 % of the length from the middle, a
forward arrow on the ground beside the vehicle, a sideways one ahead of it), projected into the image, and
checked: on a face turned toward the camera by at least 5 degrees (stricter than
:mod:`toosicubix.solver.plausibility` is with clicks already made), in front of the camera, inside the image. Its
expected effect is the uncertainty (:mod:`toosicubix.solver.uncertainty`) of the same fit with that part
added, exactly where predicted. Candidates are ranked by ``ln(sigma_yaw / sigma_yaw') + ln(sigma_depth /
sigma_depth')``, the log of the factor by which they would shrink the two (primes: with the part clicked), so
halving either counts the same whether it starts at 40 degrees or at 2; a mapping's keypoint's score is weighed by
how often people click it where it can be seen (``clicked_share``), the shrink to expect from suggesting it.

The cuboid's corners are suggested only on box-shaped vehicles (vans, trucks, buses, trailers, caravans) or
when the person has clicked a corner already: on a car they are points in the air that nobody can click.

The candidates, their typical positions, the faces they are seen on and the prototypes they suit are the part
vocabulary's (:mod:`toosicubix.vocabulary`), or, when given, a keypoint mapping's keypoints (at their
typical positions, weighed by their spread as a fit weighs them, seen on the faces they were learned to be seen
from, :attr:`toosicubix.parts.linear.TypicalKeypoint.faces`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

from toosicubix import vocabulary
from toosicubix.camera import Camera
from toosicubix.model import GroundPlane, Part
from toosicubix.parts.linear import TypicalKeypoint, build_parts_model
from toosicubix.size_priors import SizePrior, axle_prior
from toosicubix.solver.clicked import ALREADY_CLICKED_SIGMAS, named_as_clicked, near_a_click
from toosicubix.solver.fit import SolverOptions
from toosicubix.solver.plausibility import faces_turned_to_camera
from toosicubix.solver.problem import Problem
from toosicubix.solver.refine import MIN_DEPTH
from toosicubix.solver.robust import soft_weights, with_weights
from toosicubix.solver.uncertainty import Uncertainty, finite_or_none, one_end, uncertainties_with_added_clicks


class Fitted(Protocol):
    """What :func:`suggest_clicks` reads of a fit: a :class:`~toosicubix.solver.fit.FitResult`, or a fit as
    results.json keeps it (:func:`toosicubix.pipeline.vehicle.fit_as_written`).

    ``R_cam_vehicle`` (3, 3), ``t_cam_vehicle`` (3,), ``dimensions`` (3,), ``p`` (P,) every unknown in the
    parts model's order, ``click_weights`` (N,) or None, ``residual_test`` or None; ``uncertainty`` is only
    asked whether it is there."""

    @property
    def ok(self) -> bool: ...
    @property
    def uncertainty(self) -> Any: ...
    @property
    def R_cam_vehicle(self) -> np.ndarray: ...
    @property
    def t_cam_vehicle(self) -> np.ndarray: ...
    @property
    def dimensions(self) -> np.ndarray: ...
    @property
    def p(self) -> np.ndarray: ...
    @property
    def click_weights(self) -> np.ndarray | None: ...
    @property
    def residual_test(self) -> Any: ...


#: A suggested part must be on a face turned toward the camera by at least this much, degrees.
VISIBLE_MIN_DEG = 5.0
TINY = 1e-12
#: A keypoint is toward the far end of a vehicle clicked on one end when its typical position lies past the middle by
#: at least this fraction of the length (:attr:`Suggestion.far_end`).
FAR_END_FRACTION = 0.05


@dataclass(frozen=True)
class Suggestion:
    """One part to click next.

    Attributes
    ----------
    kind, name : as in the annotation file ('point' 'wheel-rear-left', 'symmetry' 'rear', 'direction' 'forward')
    uv : (k, 2) where it should appear in the image, pixels (lens distortion applied, as clicks are)
    visible : on a face turned to the camera and in front of it; inside : within the image (True if unknown)
    yaw_sigma_deg, depth_sigma_rel : the uncertainty with it clicked
    yaw_gain_deg, depth_gain_rel : the reductions; score : ln of the shrink factor of yaw times depth sigma
    clicked_share : how often people click it where it can be seen (a mapping's keypoint; else 1)
    far_end : a mapping's keypoint past the middle toward the far end of a vehicle whose clicks all sit on one end
        (:func:`.uncertainty.one_end`): such suggestions come first
    """

    kind: str
    name: str
    uv: np.ndarray
    visible: bool
    inside: bool
    yaw_sigma_deg: float
    depth_sigma_rel: float
    yaw_gain_deg: float
    depth_gain_rel: float
    score: float
    clicked_share: float = 1.0
    far_end: bool = False

    @property
    def expected_score(self) -> float:
        """The score to expect from suggesting it: ``clicked_share * score`` (what the ranking uses)."""
        return self.clicked_share * self.score

    @property
    def label(self) -> str:
        """How the vocabulary names the part to a person (its kind's ``hint``), e.g. 'forward arrow on the ground'."""
        return vocabulary.KINDS[self.kind].hint.replace("{name}", self.name)

    def to_json(self) -> dict:
        """As results.json has it (``null`` for an infinite standard deviation or an undefined gain)."""
        return {"kind": self.kind, "name": self.name, "label": self.label, "uv": np.round(self.uv, 1).tolist(),
                "visible": self.visible, "inside_image": self.inside,
                **{key: finite_or_none(getattr(self, key)) for key in (
                    "yaw_sigma_deg", "depth_sigma_rel", "yaw_gain_deg", "depth_gain_rel", "score")},
                **({"clicked_share": self.clicked_share} if self.clicked_share != 1.0 else {}),
                **({"far_end": True} if self.far_end else {})}


def _typical_points(kind: str, name: str, terms: dict[str, float]) -> np.ndarray:
    """Where a part usually is on the fitted cuboid (``terms``: :func:`toosicubix.vocabulary.typical_terms`),
    vehicle frame: (k, 3) (the vocabulary's ``typical``)."""
    return np.array(vocabulary.typical_points(vocabulary.entry(kind, name), terms))


def is_box_shaped(*prototypes: str) -> bool:
    """Whether a vehicle of any of these prototypes (its own, its KITTI type) is a box, so that the cuboid's
    corners are parts one can click (the vocabulary's ``box-shaped`` prototype group)."""
    return any(p in vocabulary.PROTOTYPE_GROUPS["box-shaped"] for p in prototypes)


_SUGGEST = {"always": lambda side: True, "never": lambda side: False,
            "camera-left": lambda side: side > 0, "camera-right": lambda side: side < 0}


def _candidates(parts: tuple[Part, ...], corners: bool, camera_side: float) -> list[tuple[str, str]]:
    """The annotations not made yet, as (kind, name), in the vocabulary's order; a wheelbase counts as its two
    wheels clicked, and a wheel's hub or its contact with the road as that wheel clicked. Parts that suit only
    some prototypes (corners) when ``corners`` or one is clicked already;
    of a kind suggested once (arrows), none when one is clicked, else those its ``suggest`` admits for the
    camera's side (``camera_side`` +1: the camera is on the vehicle's left)."""
    clicked = named_as_clicked((p.kind, p.name) for p in parts)
    corners = corners or any(vocabulary.entry(p.kind, p.name).suits != "all" for p in parts)
    kinds_clicked = {p.kind for p in parts}
    out = []
    for kind in vocabulary.KINDS.values():
        if kind.suggest_once and kind.kind in kinds_clicked:
            continue
        for name, e in kind.names.items():
            if e.typical is None or (kind.kind, name) in clicked or not (corners or e.suits == "all"):
                continue
            if "suggest" in e.attributes and not _SUGGEST[e.get("suggest")](camera_side):
                continue
            out.append((kind.kind, name))
    return out


@dataclass(frozen=True)
class Guidance:
    """What to click next (``suggestions``, best first) and what clicking every visible part inside the image would
    give (``reachable``: the fit's uncertainty with every suggestion that is visible and inside clicked too, where
    predicted, at the same click noise; the fit's own when there is none): how far clicks can take this vehicle at
    its distance, and so what no click can fix."""

    suggestions: list[Suggestion]
    reachable: Uncertainty | None


def suggest_clicks(parts: tuple[Part, ...], camera: Camera, prior: SizePrior, fit: Fitted,
                   options: SolverOptions | None = None, ground: GroundPlane | None = None,
                   known_dimensions: dict[str, tuple[float, float]] | None = None,
                   box_shaped: bool = False,
                   keypoints: Mapping[str, TypicalKeypoint] | None = None) -> list[Suggestion]:
    """Rank the parts not yet clicked by how much they would shrink the yaw and depth uncertainty
    (:func:`guide`'s suggestions)."""
    return guide(parts, camera, prior, fit, options, ground, known_dimensions, box_shaped, keypoints).suggestions


def guide(parts: tuple[Part, ...], camera: Camera, prior: SizePrior, fit: Fitted,
          options: SolverOptions | None = None, ground: GroundPlane | None = None,
          known_dimensions: dict[str, tuple[float, float]] | None = None,
          box_shaped: bool = False,
          keypoints: Mapping[str, TypicalKeypoint] | None = None, tracked: bool = False) -> Guidance:
    """Rank the parts not yet clicked by how much they would shrink the yaw and depth uncertainty, and say what
    clicking all the visible ones would reach. A part is not suggested where the person has clicked already: a
    wheel whose hub is clicked (or the hub of a clicked wheel), or a part of the vocabulary predicted within
    :data:`ALREADY_CLICKED_SIGMAS` click sigmas of a click (a mapping's keypoints may sit closer together than that
    on far cars, and are left to their own ranking).

    Parameters
    ----------
    parts : the vehicle's annotations; fit : its fit (no suggestions when it failed)
    options, ground, known_dimensions : as the fit had them
    box_shaped : suggest the cuboid's corners too (see :func:`is_box_shaped`)
    keypoints : the candidates instead of the vocabulary's parts (a mapping's keypoints, for a person clicking in
        its vocabulary): keypoint name -> its ``at``, ``spread`` (fractions of the dimensions) and ``seen_from``;
        each not clicked yet is placed at ``at`` on the fitted cuboid, weighted by its spread as a fit weighs it,
        and visible when one of the faces it is seen from
        (:attr:`~toosicubix.parts.linear.TypicalKeypoint.faces`) is turned to the camera
    tracked : the fit is a track's frame (:mod:`toosicubix.pipeline.tracks`): its sigmas are the track's, which the
        other frames tighten. A click's gain is worked out on this frame's own rows (the information it adds to
        them) and added to the track's information (:func:`_on_track`): more clicks never widen a sigma.

    Returns
    -------
    Guidance
        The suggestions, best first (by :attr:`Suggestion.expected_score`), visible parts inside the image before
        the others; none, and no reachable uncertainty, for a failed fit.
    """
    options = options or SolverOptions()
    if not fit.ok or fit.uncertainty is None:
        return Guidance([], None)
    R, t, d = fit.R_cam_vehicle, fit.t_cam_vehicle, fit.dimensions
    base = build_parts_model(parts, known_dimensions)
    values = dict(zip(base.param_names, fit.p, strict=True))
    axles = axle_prior(prior.prototype)  # an axle the fit has no unknown for sits where the prior puts it (rule 30)
    where = values if axles is None else {**{k: f * float(d[0]) for k, f in axles.at.items()}, **values}
    camera_side = 1.0 if (R.T @ (-t))[1] >= 0 else -1.0
    terms = vocabulary.typical_terms(d, where, camera_side)
    wheels = {"front": terms["Xwf"], "rear": terms["Xwr"]}
    facing = faces_turned_to_camera(R, t, d, grazing_deg=-VISIBLE_MIN_DEG)

    # Every candidate at its typical place, all in one model: one Jacobian serves them all.
    placed, placed_vehicle = [], []
    if keypoints is None:
        typical = [(Part(kind, name, np.empty((0, 2)), "$"), _typical_points(kind, name, terms))
                   for kind, name in _candidates(parts, box_shaped, camera_side)]
    else:
        clicked = {p.name for p in parts if p.kind == "keypoint"}
        typical = [(Part("keypoint", name, np.empty((0, 2)), "$", at=np.asarray(k.at, dtype=float),
                         spread=np.asarray(k.spread, dtype=float)), (d * np.asarray(k.at, dtype=float))[None])
                   for name, k in keypoints.items() if name not in clicked]
    clicked_uv = np.concatenate([p.uv for p in parts]) if parts else np.empty((0, 2))
    already = ALREADY_CLICKED_SIGMAS * options.click_sigma
    for part, points_vehicle in typical:
        points_cam = points_vehicle @ R.T + t
        if np.all(points_cam[:, 2] > MIN_DEPTH):
            uv = camera.project(points_cam)
            if keypoints is None and near_a_click(uv, clicked_uv, already):
                continue  # the person sees a click there already
            placed.append(replace(part, uv=uv))
            placed_vehicle.append(points_vehicle)
    if not placed:
        return Guidance([], fit.uncertainty)
    combined = build_parts_model((*parts, *placed), known_dimensions)
    index = {name: i for i, name in enumerate(combined.param_names)}
    p = np.full(combined.n_params, np.nan)
    for name, value in values.items():
        p[index[name]] = value
    for axle, name in (("front", "Xwf"), ("rear", "Xwr")):
        if name in index and np.isnan(p[index[name]]):
            p[index[name]] = wheels[axle]
    rows = _click_rows(parts, placed)
    for points_vehicle, (first, last) in zip(placed_vehicle, rows, strict=True):
        _set_own_values(combined.A[first:last], points_vehicle, p)
    problem = Problem.build(combined, camera, prior, options.lambda_3d, options.lambda_px, ground,
                            float(np.linalg.norm(t)))
    # The fit's own weights (keypoints' spread, robust factors); a candidate weighs as its spread makes a fit
    # weigh it (1 for cuboid parts).
    soft = soft_weights(problem, float(np.linalg.norm(t)), options.click_sigma)
    if fit.click_weights is not None or soft is not None:
        own = fit.click_weights if fit.click_weights is not None else np.ones(base.n_clicks)
        added_weights = soft[base.n_clicks:] if soft is not None else np.ones(combined.n_clicks - base.n_clicks)
        problem = with_weights(problem, np.concatenate([own, added_weights]))
    if base.click_spread is not None and options.upright_weight == "clicks":  # as the fit weighed its upright term
        problem = problem.upright_against_clicks(options.click_sigma)
    base_params = np.array([index[name] for name in base.param_names])
    size = camera.image_size
    seen = []
    for part in placed:
        faces = ([keypoints[part.name].faces] if keypoints is not None and part.kind == "keypoint"
                 else map(vocabulary.faces_of_click, part.click_labels))
        visible = all(f is None or any(facing[x] for x in f) for f in faces)
        inside = size is None or bool(np.all((part.uv >= 0) & (part.uv <= np.array(size) - 1)))
        seen.append((visible, inside))
    every = [np.arange(*r) for r, (visible, inside) in zip(rows, seen, strict=True) if visible and inside]
    # Ranked with the rows' noise as the fit weighs them, not the batch's estimate its sigmas take (rule 35): on
    # ApolloCar3D's comparison half that estimate changed the guided order of 75 of 461 cars by their seventh click,
    # 9 of them more than 1 degree worse against 1 better (benchmarks/decisions.md, rule 35's section); the sigmas it
    # reports are rescaled below.
    now, added = uncertainties_with_added_clicks(problem, R, t, p, base_params, base.n_clicks,
                                                 [*rows, np.concatenate(every) if every else np.empty(0, int)],
                                                 options.click_sigma, options.part_sigma)
    test = fit.residual_test
    if test is not None and test.misfit:  # as the fit's own sigmas: widened by its residuals (:mod:`.misfit`)
        now, added = now.widened(test.ratio), [u.widened(test.ratio) for u in added]
    if options.soft_noise is not None and not tracked and fit.uncertainty is not None:
        now, added = fit.uncertainty, [_rescaled(u, now, fit.uncertainty) for u in added]
    if tracked:
        added = [_on_track(u, now, fit.uncertainty) for u in added]
        now = fit.uncertainty
    added, reachable = added[:-1], added[-1]
    # A vehicle clicked in keypoints on one end only: the keypoints toward the far end first. Linearised at a pose
    # the size prior holds, their gain looks small; on ApolloCar3D's comparison half one of them took 268 end-on cars
    # fitted from their near end's keypoints from a mean E_R of 7.52 to 3.38 degrees (benchmarks/apollocar3d.py's
    # far-end diagnostic; benchmarks/decisions.md, rule 23's section).
    end = one_end(base, fit.p) if keypoints is not None else None
    far_sign = 1.0 if end is not None and end[0] == "rear" else -1.0
    out = []
    for part, u, (visible, inside) in zip(placed, added, seen, strict=True):
        score = (math.log(_bounded(now.yaw_deg) / _bounded(u.yaw_deg))
                 + math.log(_bounded(now.depth_rel) / _bounded(u.depth_rel)))
        share = keypoints[part.name].clicked_share if keypoints is not None else 1.0
        far = end is not None and part.at is not None and far_sign * part.at[0] > FAR_END_FRACTION
        out.append(Suggestion(part.kind, part.name, part.uv, visible, inside, u.yaw_deg, u.depth_rel,
                              now.yaw_deg - u.yaw_deg, now.depth_rel - u.depth_rel, score, share, far))
    out.sort(key=lambda s: (not (s.visible and s.inside), not s.far_end, -s.expected_score))
    return Guidance(out, reachable)


def _rescaled(after: Uncertainty, now: Uncertainty, fitted: Uncertainty) -> Uncertainty:
    """A candidate's sigmas ``after`` computed with the rows' noise as the fit weighs them, as the fit's own sigmas
    take them: yaw and depth scaled by the fit's sigma (``fitted``, with the batch's estimated noise) over ``now``
    (the fit's sigma with the weights' noise), each where both are finite and positive, else as they are."""
    def ratio(a: float, b: float) -> float:
        return a / b if math.isfinite(a) and math.isfinite(b) and a > 0.0 and b > 0.0 else 1.0

    r_yaw, r_depth = ratio(fitted.yaw_deg, now.yaw_deg), ratio(fitted.depth_rel, now.depth_rel)
    return replace(after, yaw_deg=after.yaw_deg * r_yaw, depth_rel=after.depth_rel * r_depth,
                   depth_m=after.depth_m * r_depth)


def _on_track(after: Uncertainty, alone: Uncertainty, track: Uncertainty) -> Uncertainty:
    """The track's sigmas (``track``) with the information a click adds to its frame's own rows: per quantity (yaw,
    depth), ``1 / sigma^2 = 1 / track^2 + (1 / after^2 - 1 / alone^2)``, ``alone`` and ``after`` the frame's own
    sigmas without and with the click (the click's information taken as independent of the other frames'); the
    rest of ``track`` as it is."""
    def added(a: float, b: float, c: float) -> float:
        gain = max(0.0, 1.0 / _bounded(a) ** 2 - 1.0 / _bounded(b) ** 2)
        return 1.0 / math.sqrt(1.0 / _bounded(c) ** 2 + gain)

    depth_rel = added(after.depth_rel, alone.depth_rel, track.depth_rel)
    return replace(track, yaw_deg=added(after.yaw_deg, alone.yaw_deg, track.yaw_deg), depth_rel=depth_rel,
                   depth_m=track.depth_m * depth_rel / _bounded(track.depth_rel))


def _bounded(sigma: float) -> float:
    """A standard deviation kept within [1e-12, 1e12], infinities included, for the score's ratios."""
    return min(max(sigma, TINY), 1.0 / TINY)


def _click_rows(parts: tuple[Part, ...], placed: list[Part]) -> list[tuple[int, int]]:
    """The click indices ``[first, last)`` of each placed candidate in the combined model."""
    first = sum(len(p.uv) for p in parts)
    out = []
    for part in placed:
        out.append((first, first + len(part.uv)))
        first += len(part.uv)
    return out


def _set_own_values(A_rows: np.ndarray, points_vehicle: np.ndarray, p: np.ndarray) -> None:
    """Fill in ``p`` the unknowns of a candidate still unset (NaN), from its placed points: ``A_rows``
    (k, 3, P) of its clicks, ``points_vehicle`` (k, 3). Each own unknown is a coordinate of some click
    with coefficient +-1 (the table of :mod:`toosicubix.parts`)."""
    for j in np.flatnonzero(np.isnan(p) & np.any(A_rows != 0, axis=(0, 1))):
        i, axis = np.argwhere(A_rows[:, :, j] != 0)[0]
        rest = A_rows[i, axis] @ np.where(np.isnan(p), 0.0, p)
        p[j] = (points_vehicle[i, axis] - rest) / A_rows[i, axis, j]


__all__ = ["Fitted", "Suggestion", "is_box_shaped", "suggest_clicks"]
