"""Fit every vehicle of an annotation file and write the outputs: the job behind ``toosicubix fit``.

Outputs in the output folder:

- ``label_2/<image id>.txt``: KITTI labels (camera-0 frame when the camera is a KITTI ``P``), one file per
  image, vehicles that failed left out. KITTI stores yaw only: pitch and roll are dropped there.
- ``results.json``: every vehicle, with its full rotation, or its status "failed" and the reason.

The folder is written as a whole (:mod:`toosicubix.pipeline.output_folder`): a staging folder beside it
takes every file, with a marker that makes it ours, and then replaces it in one rename; a killed run
leaves the previous output. The annotation file is read one image at a time and each image's results
are written as soon as it is done, so memory does not grow with the batch. One vehicle that fails, even
by an unexpected error, never stops the batch.
"""

from __future__ import annotations

import hashlib
import itertools
import os
import traceback
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from toosicubix import __version__
from toosicubix.annotations.convert import image_from_schema, with_ground
from toosicubix.annotations.schema import InputFileError
from toosicubix.annotations.stream import AnnotationIndex, index_annotations, iter_image_annotations
from toosicubix.camera import Camera
from toosicubix.formats import kitti
from toosicubix.formats.results import (
    RESULTS_FILENAME,
    Cues,
    ImageResult,
    Observability,
    Sigma,
    SolverStats,
    VehicleResult,
    all_finite,
    non_finite_path,
    write_results_stream,
)
from toosicubix.geometry import box2d_of_points, clip_cuboid_to_near_plane, cuboid_corners_cam, ypr_from_R_cam_vehicle
from toosicubix.model import GroundPlane, Image, Vehicle
from toosicubix.parts.linear import PartsModel, build_parts_model
from toosicubix.pipeline.click_noise import ClickNoise, estimate_from_pilot, pilot_images, telling
from toosicubix.pipeline.output_folder import (
    LABEL_DIR,
    OutputFolderError,
    check_output_dir,
    pause_after_file,
    staged_output,
)
from toosicubix.pipeline.road_normal import (
    MIN_VEHICLES,
    RoadNormal,
    camera_key,
    describe_without_pilot,
    estimate_road_normals,
    ground_block,
    refuse_with_ground,
    without_pilot,
)
from toosicubix.priors.table import Priors, SizePrior, load_priors
from toosicubix.solver import (
    MISFIT_WARNING,
    FitResult,
    JointVehicle,
    Problem,
    SolverOptions,
    analyse,
    confidence,
    fit_jointly,
    fit_vehicle,
    scale_shares,
    tested,
)
from toosicubix.solver.guidance import Fitted, is_box_shaped, suggest_clicks
from toosicubix.solver.misfit import ResidualTest
from toosicubix.solver.robust import with_weights

__all__ = ["LABEL_DIR", "BatchSummary", "OutputFolderError", "PilotFindings", "fit_as_written", "fit_file",
           "fit_images", "fit_one", "fitted_batch", "run_pilot", "with_next_clicks"]


#: How many failed vehicles a :class:`BatchSummary` lists (a batch's memory must not grow with its size).
FAILED_KEPT = 1000


@dataclass(frozen=True)
class BatchSummary:
    """What a batch did."""

    images: int
    vehicles: int
    ok: int
    failed: list[tuple[str, str, str]]  # (image id, vehicle id, reason), the first FAILED_KEPT in file order
    out_dir: Path
    scale_from: dict[str, int] = field(default_factory=dict)  # cue -> vehicles whose scale it set
    pilot: PilotFindings | None = None  # the click noise and road normals the batch was fitted with, and whence
    misfits: int | None = None  # fitted vehicles whose residuals failed the chi-square test; None: not tested

    @property
    def n_failed(self) -> int:
        """How many vehicles failed (``failed`` lists only the first :data:`FAILED_KEPT`; all are in
        results.json)."""
        return self.vehicles - self.ok


def check_prototypes(images: list[Image], priors: Priors, source: str | Path) -> None:
    """Every vehicle's prototype must be in the priors table.

    Raises
    ------
    InputFileError
        Naming each vehicle's JSON path and listing the known prototypes.
    """
    known = sorted(priors)
    problems = [
        (f"{v.json_path}.prototype", f"unknown prototype {v.prototype!r}; known: {', '.join(known)}")
        for im in images for v in im.vehicles if v.prototype not in priors
    ]
    if problems:
        raise InputFileError(source, problems)


#: Keypoints to suggest for one vehicle: name -> ``(at, spread)``, (3,) fractions of the dimensions.
Keypoints = Mapping[str, tuple[np.ndarray, np.ndarray]]


class KeypointCatalogue(Protocol):
    """Keypoints to suggest as next clicks, per prototype (a keypoint mapping,
    :class:`toosicubix.formats.coco.MappingFile`)."""

    def keypoint_candidates(self, prototype: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Name -> ``(at, spread)``, (3,) fractions of the dimensions, on a vehicle of ``prototype``."""
        ...


def fit_one(vehicle: Vehicle, camera: Camera, prior: SizePrior, options: SolverOptions,
            ground: GroundPlane | None = None, next_clicks: int = 0,
            keypoints: Keypoints | None = None) -> VehicleResult:
    """Fit one vehicle and describe it as results.json does; never raises.

    ``next_clicks``: how many suggestions of what to click next to add (:mod:`toosicubix.solver.guidance`), 0:
    none; ``keypoints``: the keypoints to suggest instead of the vocabulary's parts (name -> ``(at, spread)``).
    """
    try:
        parts = build_parts_model(vehicle.parts, vehicle.known_dimensions)
        fit = fit_vehicle(parts, camera, prior, options, ground)
        with np.errstate(all="ignore"):  # a non-finite value is caught below, not warned about
            return checked_result(_vehicle_result(vehicle, camera, prior, parts, fit, ground, options, next_clicks,
                                                  keypoints))
    except UnusableFit as exc:
        return _failed(vehicle, prior, str(exc))
    except Exception as exc:  # one vehicle must never stop the batch
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return _failed(vehicle, prior, f"internal error: {type(exc).__name__}: {exc} "
                                       f"(at {Path(where.filename).name}:{where.lineno})")


class UnusableFit(ValueError):
    """A vehicle's fit that cannot be written: behind the camera, or with a non-finite number."""


def _failed(vehicle: Vehicle, prior: SizePrior, reason: str) -> VehicleResult:
    return VehicleResult(id=vehicle.id, status="failed", prototype=vehicle.prototype, error=reason,
                         kitti_type=prior.kitti_type)


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
                             kitti_type=result.kitti_type)
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


def _vehicle_result(vehicle: Vehicle, camera: Camera, prior: SizePrior, parts: PartsModel, fit: FitResult,
                    ground: GroundPlane | None, options: SolverOptions, next_clicks: int = 0,
                    keypoints: Keypoints | None = None) -> VehicleResult:
    common = {"id": vehicle.id, "prototype": vehicle.prototype, "kitti_type": prior.kitti_type,
              "constraints": fit.constraints, "clicks": fit.n_clicks, "aux_unknowns": fit.n_aux,
              "cues": active_cues(parts, ground), "solver": _solver_stats(fit)}
    if not fit.ok:
        return VehicleResult(status="failed", error=fit.reason, box2d=vehicle.box2d, **common)
    R, t, d = fit.R_cam_vehicle, fit.t_cam_vehicle, fit.dimensions
    box2d, truncated = _box2d(vehicle, camera, R, t, d)
    ry, pitch, roll = ypr_from_R_cam_vehicle(R)
    suggestions: dict[str, Any] = {}
    if next_clicks > 0:
        suggestions = _next_clicks(vehicle, camera, prior, fit, options, ground, next_clicks, keypoints)
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
        sigma=Sigma.from_json(fit.uncertainty.to_json()) if fit.uncertainty is not None else None,
        confidence=confidence(fit.uncertainty) if fit.uncertainty is not None else None,
        observability=Observability.from_json(fit.observability.to_json()) if fit.observability is not None else None,
        ambiguous=fit.ambiguous,
        alternatives=tuple(fit.alternatives),
        residual_test=fit.residual_test,
        warnings=tuple(fit.warnings),
        **suggestions,
    )


def _next_clicks(vehicle: Vehicle, camera: Camera, prior: SizePrior, fit: Fitted, options: SolverOptions,
                 ground: GroundPlane | None, n: int,
                 keypoints: Keypoints | None = None) -> dict[str, Any]:
    """The ``n`` best parts (or ``keypoints``) to click next (``next_clicks``, or ``next_clicks_error`` when
    guidance failed); an error here never fails the vehicle."""
    try:
        suggestions = suggest_clicks(vehicle.parts, camera, prior, fit, options, ground, vehicle.known_dimensions,
                                     box_shaped=is_box_shaped(vehicle.prototype, prior.kitti_type),
                                     keypoints=keypoints)
    except Exception as exc:  # guidance is advice: the fit stands without it
        return {"next_clicks": [], "next_clicks_error": f"{type(exc).__name__}: {exc}"}
    return {"next_clicks": [s.to_json() for s in suggestions[:n]]}


@dataclass(frozen=True)
class _FitAsWritten:
    """A fit as results.json keeps it, seen as guidance reads a fit (:class:`toosicubix.solver.guidance.Fitted`)."""

    result: VehicleResult

    @property
    def ok(self) -> bool:
        return self.result.ok

    @property
    def uncertainty(self) -> Sigma | None:
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
        return _failed(vehicle, prior, str(exc))


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


def kitti_lines(image_result: ImageResult, camera: Camera) -> list[str]:
    """The KITTI label lines of an image's successful fits (pitch and roll dropped)."""
    lines = []
    for v in image_result.vehicles:
        if not v.ok:
            continue
        obj = kitti.object_from_pose(
            v.kitti_type, v.R_cam_vehicle, v.t_cam_vehicle, v.dimensions, camera, v.box2d,
            truncated=0.0 if v.truncated is None else v.truncated, occluded=kitti.OCCLUSION_UNKNOWN,
            score=1.0 if v.confidence is None else v.confidence,
        )
        lines.append(kitti.format_label_line(obj))
    return lines


#: What :func:`fit_one` takes, as the batch hands it to a worker.
FitTask = tuple[Vehicle, Camera, SizePrior, SolverOptions, GroundPlane | None, int, Keypoints | None]


def _candidates_of(keypoints: KeypointCatalogue | None
                   ) -> Callable[[str], Keypoints | None]:
    """Per prototype, the keypoints to suggest (None: the vocabulary's parts), each prototype's made once."""
    made: dict[str, Keypoints] = {}

    def of(prototype: str) -> Keypoints | None:
        if keypoints is None:
            return None
        if prototype not in made:
            made[prototype] = keypoints.keypoint_candidates(prototype)
        return made[prototype]

    return of


def _worker_init() -> None:
    cv2.setNumThreads(1)  # one process per core; no threads on top


def fit_images(images: list[Image], priors: Priors, options: SolverOptions,
               progress: Callable[[int], None] | None = None, jobs: int = 1,
               joint_ground: bool = False, next_clicks: int = 0,
               keypoints: KeypointCatalogue | None = None) -> list[ImageResult]:
    """Fit every vehicle of every image.

    Parameters
    ----------
    progress : called with the number of vehicles just finished
    jobs : worker processes; the results are the same for any number (each vehicle is fitted on its own,
        deterministically, and the results come back in input order)
    joint_ground : then refine each image's vehicles together with its ground plane (images with a
        ground block); the camera height may be unknown
    next_clicks : per vehicle, how many suggestions of what to click next to add (0: none)
    keypoints : suggest these keypoints instead of the vocabulary's parts (a keypoint mapping,
        :class:`toosicubix.formats.coco.MappingFile`: its keypoints at their positions for each prototype)
    """
    n = sum(len(im.vehicles) for im in images)
    return list(iter_fit_images(images, n, priors, options, progress, jobs, joint_ground, next_clicks, keypoints))


def iter_fit_images(images: Iterable[Image], n_vehicles: int, priors: Priors, options: SolverOptions,
                    progress: Callable[[int], None] | None = None, jobs: int = 1,
                    joint_ground: bool = False, next_clicks: int = 0,
                    keypoints: KeypointCatalogue | None = None) -> Iterator[ImageResult]:
    """:func:`fit_images` one image at a time, in input order: the images are read from ``images`` only as
    the workers need them, and each result is handed on as soon as its image is done, so memory does not
    grow with the batch. ``n_vehicles`` (the batch's size) only sets how many vehicles go to a worker at once.
    """
    pending: deque[Image] = deque()
    done: list[VehicleResult] = []
    candidates = _candidates_of(keypoints if next_clicks > 0 else None)

    def tasks() -> Iterator[FitTask]:
        for im in images:
            pending.append(im)
            for v in im.vehicles:
                yield v, im.camera, priors[v.prototype], options, im.ground, next_clicks, candidates(v.prototype)

    def finished_images() -> Iterator[ImageResult]:
        while pending and len(done) >= len(pending[0].vehicles):
            im = pending.popleft()
            vehicles = done[:len(im.vehicles)]
            del done[:len(im.vehicles)]
            ground = _ground_json(im.ground, estimated=im.ground.from_batch) if im.ground is not None else None
            if joint_ground and im.ground is not None:
                vehicles, ground = fit_image_jointly(im, vehicles, priors, options, next_clicks, keypoints)
            yield ImageResult(id=im.id, K=im.camera.K, t_cam_rect=im.camera.t_cam_rect,
                              image_size=im.camera.image_size, vehicles=vehicles, ground=ground)

    chunk = max(1, min(64, n_vehicles // (4 * jobs)))
    for result in _ordered_map(tasks(), jobs if n_vehicles > 1 else 1, chunk):
        done.append(result)
        if progress is not None:
            progress(1)
        yield from finished_images()
    yield from finished_images()  # images without vehicles at the end


def _fit_chunk(tasks: list[FitTask]) -> list[VehicleResult]:
    return [fit_one(*task) for task in tasks]


def _suggest_chunk(tasks: list[SuggestTask]) -> list[VehicleResult]:
    return [with_next_clicks(*task) for task in tasks]


def _ordered_map(tasks: Iterator[tuple], jobs: int, chunk: int,
                 work: Callable[[list], list[VehicleResult]] = _fit_chunk) -> Iterator[VehicleResult]:
    """``work`` (:func:`fit_one` over a chunk, by default) over ``tasks`` in order, in ``jobs`` processes, with a
    bounded number of chunks of ``chunk`` tasks in flight (the pool's own ``map`` would take every task at
    once)."""
    if jobs <= 1:
        for task in tasks:
            yield from work([task])
        return
    in_flight: deque[Future[list[VehicleResult]]] = deque()
    with ProcessPoolExecutor(max_workers=jobs, initializer=_worker_init) as pool:
        while True:
            while len(in_flight) < 4 * jobs:
                batch = list(itertools.islice(tasks, chunk))
                if not batch:
                    break
                in_flight.append(pool.submit(work, batch))
            if not in_flight:
                return
            yield from in_flight.popleft().result()


def _ground_json(ground: GroundPlane, estimated: bool, camera_height: float | None = None,
                 normal: np.ndarray | None = None) -> dict[str, Any]:
    return {
        "normal": (ground.normal if normal is None else normal).tolist(),
        "camera_height": ground.camera_height if camera_height is None else camera_height,
        "estimated": estimated,
    }


def fit_image_jointly(image: Image, vehicles: list[VehicleResult], priors: Priors, options: SolverOptions,
                      next_clicks: int = 0, keypoints: KeypointCatalogue | None = None
                      ) -> tuple[list[VehicleResult], dict[str, Any]]:
    """Refine an image's fitted vehicles together with its ground plane (see :mod:`toosicubix.solver.joint`);
    return the updated results and the plane. Failed vehicles stay as they were."""
    ground = image.ground
    assert ground is not None
    fitted = [(k, v) for k, (v, r) in enumerate(zip(image.vehicles, vehicles, strict=True)) if r.ok]
    if not fitted:
        return vehicles, _ground_json(ground, estimated=False)
    joint_vehicles, models = [], []
    candidates = _candidates_of(keypoints if next_clicks > 0 else None)
    for k, v in fitted:
        parts = build_parts_model(v.parts, v.known_dimensions)
        r = vehicles[k]  # its clicks keep the weights of its own fit (keypoints' soft term, robust factors)
        problem = with_weights(Problem.build(parts, image.camera, priors[v.prototype], options.lambda_3d,
                                             options.lambda_px), r.click_weights)
        p = np.concatenate([r.dimensions, [r.parameters[name] for name in parts.param_names[3:]]])
        joint_vehicles.append(JointVehicle(problem, r.R_cam_vehicle, r.t_cam_vehicle, p))
        models.append(parts)
    try:
        result = fit_jointly(joint_vehicles, ground)
    except Exception as exc:  # the vehicles keep their own fits
        plane = _ground_json(ground, estimated=False)
        plane["joint_error"] = f"{type(exc).__name__}: {exc}"
        return vehicles, plane
    plane_fitted = replace(ground, normal=result.normal, camera_height=result.camera_height)
    out = list(vehicles)
    for (k, v), jv, parts, R, t, p in zip(fitted, joint_vehicles, models, result.R, result.t, result.p, strict=True):
        own = with_weights(Problem.build(parts, image.camera, jv.problem.prior, options.lambda_3d, options.lambda_px,
                                         plane_fitted, float(np.linalg.norm(t))), jv.problem.click_weights)
        shares = scale_shares(own, R, t, p)
        u, obs = analyse(own, R, t, p, options.click_sigma, max(shares, key=shares.get) if shares else None,
                         options.part_sigma)
        u, test = tested(own, R, t, p, u, options)
        warnings = tuple(w for w in vehicles[k].warnings if not w.startswith(MISFIT_WARNING))
        fit = FitResult(
            "ok", None, vehicles[k].constraints, parts.n_clicks, parts.n_aux, R_cam_vehicle=R,
            t_cam_vehicle=t, p=p, cost=own.cost_px(R, t, p), cost_prior=float(np.sum(own.prior_residual(p) ** 2)),
            residuals_px=own.pixel_residuals(R, t, p), scale_shares=shares, uncertainty=u, observability=obs,
            warnings=(*warnings, test.sentence()) if test is not None and test.misfit else warnings,
            click_weights=own.click_weights, downweighted=vehicles[k].downweighted, residual_test=test,
        )
        try:
            updated = checked_result(
                _vehicle_result(v, image.camera, jv.problem.prior, parts, fit, plane_fitted, options, next_clicks,
                                candidates(v.prototype)))
        except UnusableFit as exc:
            out[k] = _failed(v, jv.problem.prior, f"after the joint refinement: {exc}")
            continue
        out[k] = replace(updated, cues=replace(updated.cues, joint_ground=True),
                         solver=replace(vehicles[k].solver, joint_iterations=result.iterations))
    return out, {**_ground_json(ground, True, result.camera_height, result.normal),
                 "joint_iterations": result.iterations, "vehicles": len(fitted)}


def prepare_output_dir(out_dir: Path) -> None:
    """Check that ``out_dir`` may be replaced by this run's output; write nothing.

    Raises
    ------
    OutputFolderError
        See :func:`toosicubix.pipeline.output_folder.check_output_dir`: a dataset, ground truth, any folder
        with files toosicubix did not write (the marker file decides, not ``results.json``).
    """
    check_output_dir(out_dir)


def write_outputs(out_dir: Path, images: Iterable[Image], results: Iterable[ImageResult],
                  header: dict[str, Any], on_image: Callable[[ImageResult], None] | None = None) -> dict[str, int]:
    """Write the KITTI label files and results.json into a staging folder, one image at a time as the
    results come, then swap it in for ``out_dir`` as a whole (:mod:`.output_folder`); return the summary.
    ``images`` and ``results`` are consumed together, in step."""

    def write_label(path: Path, text: str) -> None:
        with open(path, "w", encoding="utf-8", newline="\n") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        pause_after_file()

    try:
        with staged_output(out_dir, {"generator": header.get("generator")}) as staging:
            label_dir = staging / LABEL_DIR
            label_dir.mkdir()

            def labelled() -> Iterator[ImageResult]:
                for im, res in zip(images, results, strict=True):
                    lines = "".join(f"{ln}\n" for ln in kitti_lines(res, im.camera))
                    write_label(label_dir / f"{im.id}.txt", lines)
                    yield res

            with open(staging / RESULTS_FILENAME, "w", encoding="utf-8", newline="\n") as handle:
                summary = write_results_stream(handle, labelled(), header, on_image)
                handle.flush()
                os.fsync(handle.fileno())
            pause_after_file()
    except OSError as exc:  # a full disk, a name the file system refuses: nothing of this run is left
        where = Path(exc.filename).name if exc.filename else out_dir
        raise OutputFolderError(f"{out_dir}: cannot write {where}: {exc.strerror or exc}; the folder is "
                                f"unchanged") from None
    return summary


@dataclass(frozen=True)
class PilotFindings:
    """What a batch's pilot fit found (:func:`run_pilot`).

    Attributes
    ----------
    options : the solver settings to fit the batch with (the estimated click noise in them)
    click_noise : the click noise and where it came from ('given' when it was not estimated)
    road_normals : per camera (:func:`toosicubix.pipeline.road_normal.camera_key`), the estimated road
        normal or why there is none; None when not estimated
    without_pilot : cameras (and their images) the pilot had no vehicle of; empty when not estimated
    results : the pilot's results, image by image in file order, when they are the batch's own: the pilot fitted
        every vehicle with the settings the batch is fitted with and estimated no road normal (a small batch with
        nothing to change); None otherwise. :func:`fitted_batch` then writes them instead of fitting again.
    next_clicks : how many next clicks per vehicle those results have
    """

    options: SolverOptions
    click_noise: ClickNoise
    road_normals: dict[tuple, RoadNormal] | None = None
    without_pilot: dict[str, int] = field(default_factory=dict)
    results: list[ImageResult] | None = None
    next_clicks: int = 0

    def header(self) -> dict[str, Any]:
        """What results.json's header (and validate's report) say about the pilot's estimates."""
        out: dict[str, Any] = {}
        if self.click_noise.source != "given":
            out["click_noise"] = self.click_noise.to_json()
        if self.road_normals is not None:
            out["road_normal"] = [n.to_json() for n in self.road_normals.values()]
        if self.without_pilot.get("cameras"):
            out["road_normal_without_pilot"] = self.without_pilot
        return out

    def describe(self) -> list[str]:
        """Summary lines for ``fit`` and ``validate``: the click noise; each camera with a road normal (or one
        refused for scattered up axes), at most five; one line for the cameras with too few pilot vehicles."""
        lines = [self.click_noise.describe()]
        cameras = list((self.road_normals or {}).values())
        listed = [n for n in cameras if n.spread_deg is not None]
        few = [n for n in cameras if n.spread_deg is None]
        lines += [n.describe() for n in listed[:5]]
        if len(listed) > 5:
            lines.append(f"  ... and {len(listed) - 5} more cameras (results.json: road_normal)")
        if few:
            lines.append(f"road normal: not estimated for {len(few)} camera(s) ({sum(n.images for n in few)} images): "
                         f"the pilot fitted at most {max(n.vehicles for n in few)} vehicles of each, "
                         f"{MIN_VEHICLES} needed; their vehicles only kept within 45 deg of upright (--road-normal "
                         "sets it)")
        if self.without_pilot:
            lines.append(describe_without_pilot(self.without_pilot))
        return [line for line in lines if line]


def run_pilot(index: AnnotationIndex, ground: dict[str, object] | None, priors: Priors, options: SolverOptions,
              jobs: int = 1, progress: Callable[[int], None] | None = None,
              on_start: Callable[[int], None] | None = None, estimate_click_sigma: bool = False,
              estimate_road_normal: bool = False, next_clicks: int = 0,
              keypoints: KeypointCatalogue | None = None) -> PilotFindings:
    """Fit every k-th vehicle of an indexed file (at most :data:`toosicubix.pipeline.click_noise.PILOT_VEHICLES`,
    held in memory) and estimate from them what was asked: the click noise
    (:mod:`toosicubix.pipeline.click_noise`; its vehicles only) and each camera's road normal
    (:mod:`toosicubix.pipeline.road_normal`; any vehicle). Nothing asked: no pilot. When the pilot fits every
    vehicle of the file with the batch's settings, its fits are the batch's (:attr:`PilotFindings.results`), and it
    then adds the ``next_clicks`` the batch asks for to them (``jobs`` processes). Fits it does not hand on get
    none: guidance costs about as much as a fit, and would be thrown away.

    ``on_start`` is called once with the vehicles the whole batch fits, the pilot's and the file's;
    ``progress`` with each vehicle the pilot finishes.
    """
    cameras: Counter = Counter()  # images without their own ground block, per camera

    def counted(images: Iterable[Image]) -> Iterator[Image]:
        for im in images:
            if im.ground is None:
                cameras[camera_key(im.camera)] += 1
            yield im

    pilot: list[Image] = []
    if estimate_click_sigma or estimate_road_normal:
        pilot = list(pilot_images(counted(stream_images(index, ground)), index.vehicles,
                                  keep=None if estimate_road_normal else telling))
    n_pilot = sum(len(im.vehicles) for im in pilot)
    if on_start is not None:
        on_start(index.vehicles + n_pilot)
    pilot_options = replace(options, robust_loss="none")
    every = n_pilot == index.vehicles
    results = list(iter_fit_images(iter(pilot), n_pilot, priors, pilot_options, progress, jobs)) if pilot else []
    noise = ClickNoise(options.click_sigma, "given")
    if estimate_click_sigma:
        noise = estimate_from_pilot(results, options.click_sigma)
        options = replace(options, click_sigma=noise.sigma_px)
    normals = estimate_road_normals(pilot, results, cameras) if estimate_road_normal else None
    # The pilot's fits are the batch's when it fitted every vehicle as the batch will: same settings, and no
    # road normal that would give some images a ground block.
    own = bool(pilot and every and options == pilot_options
           and not any(n.normal is not None for n in (normals or {}).values()))
    pilot_next = next_clicks if own else 0
    if own and next_clicks > 0:
        results = _with_next_clicks(pilot, results, priors, options, next_clicks, keypoints, jobs)
    if normals is None:
        return PilotFindings(options, noise, results=results if own else None, next_clicks=pilot_next)
    return PilotFindings(options, noise, normals, without_pilot(cameras, normals), results if own else None,
                         pilot_next)


def _with_next_clicks(images: list[Image], results: list[ImageResult], priors: Priors, options: SolverOptions,
                      n: int, keypoints: KeypointCatalogue | None, jobs: int) -> list[ImageResult]:
    """The pilot's results (``images``' fits, in order), ``n`` next clicks per vehicle (:func:`with_next_clicks`)."""
    candidates = _candidates_of(keypoints)
    tasks = ((v, im.camera, priors[v.prototype], r, options, im.ground, n, candidates(v.prototype))
             for im, result in zip(images, results, strict=True)
             for v, r in zip(im.vehicles, result.vehicles, strict=True))
    n_vehicles = sum(len(im.vehicles) for im in images)
    done = iter(_ordered_map(tasks, jobs if n_vehicles > 1 else 1, max(1, min(64, n_vehicles // (4 * jobs))),
                             _suggest_chunk))
    return [replace(result, vehicles=[next(done) for _ in result.vehicles]) for result in results]


def file_estimates(annotations: str | Path, priors: Priors, options: SolverOptions, estimate_click_sigma: bool = True,
                   estimate_road_normal: bool = True, progress: Callable[[int], None] | None = None) -> PilotFindings:
    """What ``toosicubix fit ANNOTATIONS`` would estimate before fitting, with its default ground settings: the
    click noise (unless ``estimate_click_sigma`` is False: ``options.click_sigma`` was given) and each camera's
    road normal (unless ``estimate_road_normal`` is False), by :func:`run_pilot`. For fitting single vehicles of
    the file as that batch fits them (the annotate page); :func:`estimated_grounds` gives the normals as ground
    blocks.

    Raises
    ------
    InputFileError
        Bad annotation file, unknown prototype.
    """
    index = index_annotations(Path(annotations), known_prototypes=list(priors))
    return run_pilot(index, None, priors, options, progress=progress, estimate_click_sigma=estimate_click_sigma,
                     estimate_road_normal=estimate_road_normal)


def estimated_grounds(normals: dict[tuple, RoadNormal] | None) -> dict[tuple, dict[str, object]]:
    """Per camera (:func:`toosicubix.pipeline.road_normal.camera_key`), the ground block its estimated road normal
    gives the camera's images without one of their own; cameras without an estimate are left out."""
    return {key: ground_block(n) for key, n in (normals or {}).items() if n.normal is not None}


def fitted_batch(images: Iterable[Image], n_vehicles: int, priors: Priors, pilot: PilotFindings,
                 progress: Callable[[int], None] | None = None, jobs: int = 1, joint_ground: bool = False,
                 next_clicks: int = 0, keypoints: KeypointCatalogue | None = None) -> Iterator[ImageResult]:
    """The batch's results, image by image in file order (:func:`iter_fit_images` with the pilot's settings),
    reusing the pilot's own fits when they are the batch's (:attr:`PilotFindings.results`) and the batch asks
    nothing the pilot did not do (no joint ground, as many next clicks): a small batch is then fitted once."""
    if pilot.results is None or joint_ground or next_clicks != pilot.next_clicks:
        yield from iter_fit_images(images, n_vehicles, priors, pilot.options, progress, jobs, joint_ground,
                                   next_clicks, keypoints)
        return
    done = iter(pilot.results)  # the images with vehicles, in file order
    for im in images:
        if not im.vehicles:  # the pilot skipped it: nothing to fit
            yield from iter_fit_images([im], 0, priors, pilot.options)
            continue
        result = next(done)
        assert result.id == im.id and len(result.vehicles) == len(im.vehicles)
        if progress is not None:
            progress(len(result.vehicles))
        yield result


def pilot_and_fits(index: AnnotationIndex, ground: dict[str, object] | None, priors: Priors, options: SolverOptions,
                   jobs: int, progress: Callable[[int], None] | None, on_start: Callable[[int], None] | None,
                   estimate_click_sigma: bool, estimate_road_normal: bool, joint_ground: bool, next_clicks: int,
                   keypoints: KeypointCatalogue | None = None
                   ) -> tuple[PilotFindings, Iterator[Image], Iterator[ImageResult]]:
    """A batch as ``fit`` fits it (``fit`` and ``validate``): the pilot (:func:`run_pilot`), then, lazily, every
    image of the file on its camera's estimated road (a second reader of the stream, for the labels or the
    checks) and its fit (:func:`fitted_batch`), in file order."""
    pilot = run_pilot(index, ground, priors, options, jobs, progress, on_start, estimate_click_sigma,
                      estimate_road_normal, 0 if joint_ground else next_clicks, keypoints)
    images, second = itertools.tee(on_estimated_roads(stream_images(index, ground), pilot.road_normals))
    return pilot, second, fitted_batch(images, index.vehicles, priors, pilot, progress, jobs, joint_ground,
                                       next_clicks, keypoints)


def fit_file(annotations: str | Path, out_dir: str | Path, priors_path: str | Path | None = None,
             options: SolverOptions | None = None,
             progress: Callable[[int], None] | None = None,
             on_start: Callable[[int], None] | None = None, jobs: int = 1,
             ground: dict[str, object] | None = None, joint_ground: bool = False,
             next_clicks: int = 0, estimate_click_sigma: bool = False,
             estimate_road_normal: bool = False, keypoints: KeypointCatalogue | None = None) -> BatchSummary:
    """Read an annotation file, fit every vehicle, write ``label_2/`` and ``results.json``.

    Parameters
    ----------
    annotations : the annotation file (v1)
    out_dir : output folder, created when missing
    priors_path : a priors file; the bundled one when None
    options : solver settings
    progress : called with the number of vehicles just finished
    on_start : called once with the number of vehicles to fit
    jobs : worker processes (the output does not depend on it)
    ground : ground-block fields (schema names) set for every image of the file
    joint_ground : refine each image's vehicles together with its ground plane
    next_clicks : per vehicle, how many suggestions of what to click next results.json gets (0: none)
    keypoints : suggest a keypoint mapping's keypoints instead of the vocabulary's parts (:func:`fit_images`)
    estimate_click_sigma : first estimate the click noise from a pilot fit's residuals
        (:mod:`toosicubix.pipeline.click_noise`) and fit with it; ``options.click_sigma`` is the pilot's
        assumption and stays when the batch's clicks are too few to estimate it (``toosicubix fit`` does this
        unless given ``--click-sigma``)
    estimate_road_normal : estimate each camera's road normal from the same pilot fit's vehicles
        (:mod:`toosicubix.pipeline.road_normal`) and fit that camera's images without a ground block of their
        own upright on it (``toosicubix fit`` does this unless given a ground); not with ``ground`` or
        ``joint_ground``

    Raises
    ------
    InputFileError
        Bad annotation or priors file, unknown prototype: nothing is written.
    OutputFolderError
        The output folder holds label files toosicubix did not write.
    """
    refuse_with_ground(estimate_road_normal, ground, joint_ground)
    annotations, out_dir = Path(annotations), Path(out_dir)
    options = options or SolverOptions()
    priors = load_priors(priors_path)
    index = index_annotations(annotations, known_prototypes=list(priors))
    prepare_output_dir(out_dir)  # fail before the work, not after
    # Two readers of the same stream: the fitter and the label writer (which needs each image's camera).
    pilot, for_labels, results = pilot_and_fits(index, ground, priors, options, jobs, progress, on_start,
                                                estimate_click_sigma, estimate_road_normal, joint_ground, next_clicks,
                                                keypoints)
    options = pilot.options
    header = {
        "generator": f"toosicubix {__version__}",
        "annotations": str(annotations),
        "annotations_sha256": _sha256(annotations),
        "priors": priors.source if priors_path is not None else "bundled",
        "settings": {"lambda_3d": options.lambda_3d, "lambda_px": options.lambda_px, "click_sigma": options.click_sigma,
                     "part_sigma": options.part_sigma,
                     **({"misfit_level": options.misfit_level} if options.misfit_level is not None else {}),
                     **({"ground": ground} if ground else {}), **({"joint_ground": True} if joint_ground else {})},
        **pilot.header(),
        "notes": "t_cam_vehicle is in the frame where the image's K applies (camera 2 for KITTI P2); "
                 "X_rect = X_cam - t_cam_rect. KITTI label files drop pitch and roll; R_cam_vehicle keeps them.",
    }
    failed: list[tuple[str, str, str]] = []
    scale_from: dict[str, int] = {}
    misfits = [0]

    def tally(im: ImageResult) -> None:
        for v in im.vehicles:
            if not v.ok:
                if len(failed) < FAILED_KEPT:
                    failed.append((im.id, v.id, v.error or ""))
            else:
                if v.scale_from:
                    scale_from[v.scale_from] = scale_from.get(v.scale_from, 0) + 1
                misfits[0] += bool(v.residual_test is not None and v.residual_test.misfit)

    summary = write_outputs(out_dir, for_labels, results, header, tally)
    return BatchSummary(images=summary["images"], vehicles=summary["vehicles"], ok=summary["ok"], failed=failed,
                        out_dir=out_dir, scale_from=scale_from, pilot=pilot,
                        misfits=misfits[0] if options.misfit_level is not None else None)


def stream_images(index: AnnotationIndex, ground: dict[str, object] | None) -> Iterator[Image]:
    """The images of an indexed annotation file (:func:`toosicubix.annotations.stream.index_annotations`), one
    at a time, with the options' ground block applied."""
    for i, annotation in iter_image_annotations(index):
        yield from with_ground([image_from_schema(annotation, i)], ground or {})


def on_estimated_roads(images: Iterable[Image], normals: dict[tuple, RoadNormal] | None) -> Iterator[Image]:
    """The images, each without a ground block of its own given its camera's estimated road normal
    (:func:`toosicubix.pipeline.road_normal.ground_block`) when there is one."""
    blocks = estimated_grounds(normals)
    for im in images:
        block = blocks.get(camera_key(im.camera)) if im.ground is None and blocks else None
        if block is None:
            yield im
        else:
            im = with_ground([im], block)[0]
            yield replace(im, ground=replace(im.ground, from_batch=True))


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
