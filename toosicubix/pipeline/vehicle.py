"""One vehicle: fit it and describe it as results.json does (:func:`fit_one`), never raising; guard what cannot
be written (:func:`checked_result`); and add what to click next, from the fit or from its result as written
(:func:`with_next_clicks`)."""

from __future__ import annotations

import traceback
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from toosicubix.camera import Camera
from toosicubix.formats.results import (
    Cues,
    SolverStats,
    VehicleResult,
    all_finite,
    non_finite_path,
)
from toosicubix.geometry import box2d_of_points, clip_cuboid_to_near_plane, cuboid_corners_cam, ypr_from_R_cam_vehicle
from toosicubix.model import GroundPlane, Vehicle
from toosicubix.parts.linear import PartsModel, TypicalKeypoint, build_parts_model
from toosicubix.parts.mirror import mirrored
from toosicubix.parts.road_users import class_keypoints, class_notes
from toosicubix.size_priors import SizePrior
from toosicubix.solver.fit import FitResult, SolverOptions, fit_vehicle
from toosicubix.solver.guidance import Fitted, guide, is_box_shaped
from toosicubix.solver.misfit import ResidualTest
from toosicubix.solver.plausibility import axle_implausibility
from toosicubix.solver.track import with_box_cue
from toosicubix.solver.uncertainty import Uncertainty, confidence
from toosicubix.vocabulary import heading_of

__all__ = ["Keypoints", "SuggestTask", "UnusableFit", "active_cues", "checked_result", "describe_fit", "failed_result",
           "fit_as_written", "fit_one", "with_next_clicks"]


#: Keypoints to suggest for one vehicle: name -> where it typically is and the faces it is seen from.
Keypoints = Mapping[str, TypicalKeypoint]


def fit_one(vehicle: Vehicle, camera: Camera, prior: SizePrior, options: SolverOptions,
            ground: GroundPlane | None = None, next_clicks: int = 0,
            keypoints: Keypoints | None = None, box_cue: bool = False) -> VehicleResult:
    """Fit one vehicle and describe it as results.json does; never raises.

    ``next_clicks``: how many suggestions of what to click next to add (:mod:`toosicubix.solver.guidance`), 0:
    none; ``keypoints``: the keypoints to suggest instead of the vocabulary's parts (name ->
    :class:`~toosicubix.parts.linear.TypicalKeypoint`); ``box_cue``: refine the fit with the vehicle's ``box2d``
    as a cue too (:func:`toosicubix.solver.track.with_box_cue`).
    """
    try:
        parts = build_parts_model(vehicle.parts, vehicle.known_dimensions)
        fit = fit_vehicle(parts, camera, prior, options, ground)
        if fit.ok and fit.implausible is not None:
            fit = with_likely_cause(fit, vehicle, camera, prior, options, ground)
        elif fit.ok:
            fit = with_axles_checked(fit, parts, prior)
        if box_cue and vehicle.box2d is not None:
            fit = with_box_cue(fit, parts, camera, prior, options, ground, vehicle.box2d)
        with np.errstate(all="ignore"):  # a non-finite value is caught below, not warned about
            return checked_result(describe_fit(vehicle, camera, prior, parts, fit, ground, options, next_clicks,
                                                  keypoints))
    except UnusableFit as exc:
        return failed_result(vehicle, prior, str(exc))
    except Exception as exc:  # one vehicle must never stop the batch
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return failed_result(vehicle, prior, f"internal error: {type(exc).__name__}: {exc} "
                                       f"(at {Path(where.filename).name}:{where.lineno})")


#: The highest confidence (the KITTI score) of a fit no person could have clicked (:attr:`FitResult.implausible`): below
#: any threshold a KITTI tool would keep a label at, whatever its sigmas say.
IMPLAUSIBLE_CONFIDENCE = 0.2
#: How a fit whose left and right look swapped is described (results.json's warnings, fit's summary, the page).
SWAPPED = ("left and right look swapped: named as the vehicle's own left and right (its driver's: seen from the front, "
           "its left is on the image's right) the clicks fit a plausible pose; rename them, or press s on the page to "
           "swap them")


def with_likely_cause(fit: FitResult, vehicle: Vehicle, camera: Camera, prior: SizePrior, options: SolverOptions,
                      ground: GroundPlane | None) -> FitResult:
    """An implausible fit (:attr:`FitResult.implausible`) with its likely cause among its warnings: when the same
    clicks with the vehicle's left and right swapped (:func:`toosicubix.parts.mirror.mirrored`) fit a plausible pose,
    left and right look swapped (:data:`SWAPPED`); else the clicks contradict the cuboid another way."""
    swapped = fit_vehicle(build_parts_model(mirrored(vehicle.parts), vehicle.known_dimensions), camera, prior, options,
                          ground)
    if swapped.ok and swapped.implausible is None:
        return replace(fit, warnings=(*fit.warnings, SWAPPED))
    return replace(fit, warnings=(*fit.warnings, "the clicks fit no upright cuboid with every clicked part on a face "
                                                 "turned to the camera: check their names (front and rear, left and "
                                                 "right) and that they are on this vehicle"))


def with_axles_checked(fit: FitResult, parts: PartsModel, prior: SizePrior) -> FitResult:
    """A plausible fit whose axles are where no car has them (front and rear wheels swapped, a wheel named on the
    wrong axle: :func:`~toosicubix.solver.plausibility.axle_implausibility`) made implausible, with what to check
    among its warnings; any other fit as it is."""
    why = axle_implausibility(parts.param_names, fit.p, prior.prototype, float(prior.mean[0]))
    if why is None:
        return fit
    return replace(fit, implausible=why, warnings=(*fit.warnings, f"{why}; check the wheels' names (front and rear) "
                                                                 "and that each is clicked where its tyre touches "
                                                                 "the road"))


class UnusableFit(ValueError):
    """A vehicle's fit that cannot be written: behind the camera, or with a non-finite number."""


def failed_result(vehicle: Vehicle, prior: SizePrior, reason: str, detail: str | None = None) -> VehicleResult:
    """A vehicle that failed, why in plain words, and the technical ``detail`` (or None)."""
    return VehicleResult(id=vehicle.id, status="failed", prototype=vehicle.prototype, error=reason,
                         error_detail=detail, kitti_type=prior.kitti_type)


def settled(result: VehicleResult) -> VehicleResult:
    """``result`` with what it makes only when read made now (its observability's sentences,
    :class:`~toosicubix.solver.uncertainty.Observability`), for a result kept a while before it is written: a
    track's, held until its sequence is done, would otherwise hold its fit's Jacobians until then. A result written
    as soon as its image is done needs none (the sentences are made as it is written, or in the worker that pickles
    it); the pilot's, never written, and the page's, never read, never make them."""
    if result.observability is not None:
        result.observability.sentences  # noqa: B018  (made and kept)
    return result


def checked_result(result: VehicleResult) -> VehicleResult:
    """``result`` when it can be written; raises :class:`UnusableFit` when its cuboid (R, t, d) is not in
    front of the camera or any number in it (pose, box, uncertainty, diagnostics) is not finite. A failed
    result keeps its reason and loses any diagnostics with a NaN or infinity.

    Raises
    ------
    UnusableFit
        With the reason, e.g. "the fitted cuboid lies behind the camera (depth -3.2 m)".
    """
    # Every number finite (the usual case) is seen from the fields; the JSON form, to find where one is not.
    finite = all_finite(result)
    if not result.ok:  # keep the reason; drop diagnostics that could not be written
        if finite or non_finite_path(result.to_json()) is None:
            return result
        return VehicleResult(id=result.id, status=result.status, error=result.error, prototype=result.prototype,
                             kitti_type=result.kitti_type, error_detail=result.error_detail)
    for name in ("R_cam_vehicle", "t_cam_vehicle", "dimensions", "box2d"):
        value = getattr(result, name)
        if value is None or not (finite or np.all(np.isfinite(value))):
            raise UnusableFit(f"the fit has a non-finite or missing {name}: {value}")
    if np.any(result.dimensions <= 0):
        raise UnusableFit(f"the fit has non-positive dimensions {result.dimensions.tolist()}")
    corners_cam = cuboid_corners_cam(result.R_cam_vehicle, result.t_cam_vehicle, result.dimensions)
    if corners_cam[:, 2].max() <= 0.0:
        raise UnusableFit(f"the fitted cuboid lies behind the camera (its nearest corner at depth "
                          f"{corners_cam[:, 2].max():.4g} m)")
    if result.t_cam_vehicle[2] <= 0.0:
        raise UnusableFit(f"the fitted cuboid's bottom centre lies behind the camera (depth "
                          f"{result.t_cam_vehicle[2]:.4g} m)")
    bad = None if finite else non_finite_path(result.to_json())
    if bad is not None:
        raise UnusableFit(f"the fit has a non-finite value at {bad}")
    return result


def active_cues(parts: PartsModel, ground: GroundPlane | None) -> Cues:
    """What besides the clicks shapes a vehicle's fit."""
    return Cues(size_prior=True, upright=ground is not None,
                ground_contact=ground is not None and ground.camera_height is not None,
                known_sizes=tuple(m.label for m in parts.measurements))


def describe_fit(vehicle: Vehicle, camera: Camera, prior: SizePrior, parts: PartsModel, fit: FitResult,
                 ground: GroundPlane | None, options: SolverOptions, next_clicks: int = 0,
                 keypoints: Keypoints | None = None, tracked: bool = False) -> VehicleResult:
    """A vehicle's fit as results.json describes it, with ``next_clicks`` suggestions (0: none); not yet checked
    (:func:`checked_result`). ``tracked``: a track's frame (its sigmas the track's; the suggestions' as
    :func:`toosicubix.solver.guidance.guide` adds a click to a track)."""
    common = {"id": vehicle.id, "prototype": vehicle.prototype, "kitti_type": prior.kitti_type,
              "constraints": fit.constraints, "clicks": fit.n_clicks, "aux_unknowns": fit.n_aux,
              "cues": active_cues(parts, ground), "solver": _solver_stats(fit)}
    if not fit.ok:
        return VehicleResult(status="failed", error=fit.reason, error_detail=fit.detail, box2d=vehicle.box2d,
                             **common)
    R, t, d = fit.R_cam_vehicle, fit.t_cam_vehicle, fit.dimensions
    box2d, truncated = _box2d(vehicle, camera, R, t, d)
    ry, pitch, roll = ypr_from_R_cam_vehicle(R)
    suggestions: dict[str, Any] = {}
    if next_clicks > 0:
        suggestions = _next_clicks(vehicle, camera, prior, fit, options, ground, next_clicks, keypoints, tracked)
    return VehicleResult(
        status="ok", error=None, R_cam_vehicle=R, t_cam_vehicle=t, dimensions=d, box2d=box2d, **common,
        box2d_source="annotated" if vehicle.box2d is not None else "projected",
        truncated=truncated,
        yaw_pitch_roll_deg=tuple(np.rad2deg([ry, pitch, roll]).tolist()),
        rms_px=fit.rms_px,
        residuals_px=fit.residuals_px,
        click_labels=tuple(parts.click_labels),
        click_weights=fit.click_weights,
        downweighted=fit.downweighted,
        cost=fit.cost,
        prior_mahalanobis2=fit.cost_prior,
        parameters={name: float(v) for name, v in zip(parts.param_names[3:], fit.p[3:], strict=True)},
        scale_from=fit.scale_from,
        scale_shares=fit.scale_shares,
        sigma=fit.uncertainty,
        confidence=None if fit.uncertainty is None else (
            confidence(fit.uncertainty) if fit.implausible is None
            else min(confidence(fit.uncertainty), IMPLAUSIBLE_CONFIDENCE)),
        implausible=fit.implausible,
        observability=fit.observability,
        ambiguous=fit.ambiguous,
        alternatives=tuple(fit.alternatives),
        residual_test=fit.residual_test,
        warnings=(*fit.warnings, *class_notes(vehicle.prototype, _keypoint_names(vehicle), float(prior.mean[2]))),
        heading=None if heading_of(vehicle.prototype) == "directed" else heading_of(vehicle.prototype),
        **suggestions,
    )


def _keypoint_names(vehicle: Vehicle) -> tuple[str, ...]:
    """The names of a vehicle's keypoint annotations (what :func:`toosicubix.parts.road_users.class_notes` reads)."""
    return tuple(p.name for p in vehicle.parts if p.kind == "keypoint")


def _next_clicks(vehicle: Vehicle, camera: Camera, prior: SizePrior, fit: Fitted, options: SolverOptions,
                 ground: GroundPlane | None, n: int,
                 keypoints: Keypoints | None = None, tracked: bool = False) -> dict[str, Any]:
    """The ``n`` best parts (or ``keypoints``) to click next (``next_clicks``, or ``next_clicks_error`` when
    guidance failed) and what clicking every visible one would reach (``reachable_sigma``); an error here never
    fails the vehicle. A road user with a keypoint vocabulary of its own (a pedestrian) is offered its class's
    keypoints, whatever mapping the batch names."""
    keypoints = class_keypoints(vehicle.prototype) or keypoints
    try:
        guidance = guide(vehicle.parts, camera, prior, fit, options, ground, vehicle.known_dimensions,
                         box_shaped=is_box_shaped(vehicle.prototype, prior.kitti_type), keypoints=keypoints,
                         tracked=tracked)
    except Exception as exc:  # guidance is advice: the fit stands without it
        return {"next_clicks": [], "next_clicks_error": f"{type(exc).__name__}: {exc}"}
    return {"next_clicks": [s.to_json() for s in guidance.suggestions[:n]], "reachable_sigma": guidance.reachable}


@dataclass(frozen=True)
class _FitAsWritten:
    """A fit as results.json keeps it, seen as guidance reads a fit (:class:`toosicubix.solver.guidance.Fitted`)."""

    result: VehicleResult

    @property
    def ok(self) -> bool:
        return self.result.ok

    @property
    def uncertainty(self) -> Uncertainty | None:
        return self.result.sigma

    @property
    def R_cam_vehicle(self) -> np.ndarray:
        return self.result.R_cam_vehicle

    @property
    def t_cam_vehicle(self) -> np.ndarray:
        return self.result.t_cam_vehicle

    @property
    def dimensions(self) -> np.ndarray:
        return self.result.dimensions

    @property
    def p(self) -> np.ndarray:  # (P,): the dimensions, then the auxiliary unknowns in the parts model's order
        return np.concatenate([self.result.dimensions, np.fromiter(self.result.parameters.values(), float)])

    @property
    def click_weights(self) -> np.ndarray | None:
        return self.result.click_weights

    @property
    def residual_test(self) -> ResidualTest | None:
        return self.result.residual_test


def fit_as_written(result: VehicleResult) -> Fitted:
    """A vehicle's result as guidance reads a fit: what :func:`fit_one` would have suggested from the fit itself
    is suggested from its result (the same pose, unknowns, weights and residual test)."""
    return _FitAsWritten(result)


#: What :func:`with_next_clicks` takes, as the batch hands it to a worker.
SuggestTask = tuple[Vehicle, Camera, SizePrior, VehicleResult, SolverOptions, GroundPlane | None, int,
                    Keypoints | None]


def with_next_clicks(vehicle: Vehicle, camera: Camera, prior: SizePrior, result: VehicleResult,
                     options: SolverOptions, ground: GroundPlane | None, n: int,
                     keypoints: Keypoints | None = None) -> VehicleResult:
    """``result`` (:func:`fit_one`'s, without next clicks) with the ``n`` next clicks that :func:`fit_one` would
    have given it with ``next_clicks=n``; a failed vehicle is returned as it is. Never raises."""
    if not result.ok:
        return result
    try:
        with np.errstate(all="ignore"):
            suggestions = _next_clicks(vehicle, camera, prior, fit_as_written(result), options, ground, n, keypoints)
            return checked_result(replace(result, **suggestions))
    except UnusableFit as exc:
        return failed_result(vehicle, prior, str(exc))


def _solver_stats(fit: FitResult) -> SolverStats:
    return SolverStats(starts=fit.starts, starts_from_lines=fit.starts_from_lines,
                       descent_iterations=fit.descent_iterations, refine_iterations=fit.refine_iterations,
                       initial_cost=fit.initial_cost, residual_dof=fit.residual_dof)


def _box2d(vehicle: Vehicle, camera: Camera, R: np.ndarray, t: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, float]:
    """The label's 2D box (annotated, else the projected cuboid clipped to the image) and the
    truncation: the share of the projected cuboid's box outside the image."""
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t)) and np.all(np.isfinite(d))):
        raise UnusableFit(f"the fit has a non-finite pose: t_cam_vehicle {t.tolist()}, dimensions {d.tolist()}")
    points_cam = clip_cuboid_to_near_plane(cuboid_corners_cam(R, t, d))
    if len(points_cam) == 0:
        raise UnusableFit("the fitted cuboid lies wholly behind the camera (no 2D box)")
    uv = camera.project(points_cam)
    if not np.all(np.isfinite(uv)):
        raise UnusableFit("the fitted cuboid projects to non-finite pixels (no 2D box)")
    full = box2d_of_points(uv)
    truncated = 0.0
    clipped = full
    if camera.image_size is not None:
        clipped = box2d_of_points(uv, camera.image_size)
        area = (full[2] - full[0]) * (full[3] - full[1])
        inside = max(clipped[2] - clipped[0], 0.0) * max(clipped[3] - clipped[1], 0.0)
        truncated = float(np.clip(1.0 - inside / area, 0.0, 1.0)) if area > 0 else 0.0
    box = vehicle.box2d if vehicle.box2d is not None else clipped
    return np.asarray(box, dtype=float), truncated
