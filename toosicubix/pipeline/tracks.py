"""A batch's tracks: every tracked vehicle of a file fitted with its track's other frames
(:func:`toosicubix.solver.track.fit_track`), one sequence at a time, and described as results.json describes a
vehicle, with its ``track`` and what its frame's pose came from (``pose_from``: clicks, box, interpolated).

The images are read in file order (:func:`fit_tracks`); a sequence's tracks are fitted once its last image has been
read (the index knows which that is), in ``jobs`` processes, one track a task. What comes back is kept until the
batch writes it: memory grows with the tracked vehicles of the sequences read so far, not with the file's other
vehicles.
"""

from __future__ import annotations

import traceback
from collections.abc import Callable, Iterable, Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np

from toosicubix.formats.results import VehicleResult
from toosicubix.model import Image, Vehicle
from toosicubix.parts.linear import PartsModel, build_parts_model
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.pipeline.vehicle import (
    UnusableFit,
    checked_result,
    describe_fit,
    failed_result,
    settled,
    with_axles_checked,
    with_likely_cause,
)
from toosicubix.size_priors import SizePrior
from toosicubix.solver.fit import FitResult, SolverOptions
from toosicubix.solver.plausibility import implausibility
from toosicubix.solver.track import FrameFit, TrackFit, TrackFrame, TrackOptions, fit_track

#: One track as a worker takes it: (track, its frames as (image, vehicle) pairs, prior, solver settings, track
#: settings, next clicks).
TrackTask = tuple[str, list[tuple[Image, Vehicle]], SizePrior, SolverOptions, TrackOptions, int]

__all__ = ["TrackTask", "fit_tracks", "results_of_track"]


def results_of_track(track: str, frames: list[tuple[Image, Vehicle]], prior: SizePrior, options: SolverOptions,
                     track_options: TrackOptions, next_clicks: int = 0) -> list[VehicleResult]:
    """Fit one track and describe each of its frames as results.json does (``frames``' order); never raises: a track
    that cannot be fitted fails each of its frames with the reason."""
    try:
        models = [build_parts_model(v.parts, v.known_dimensions) for _, v in frames]
        fit = fit_track([TrackFrame(im.frame or 0, m, im.camera, im.ground, v.box2d)
                         for (im, v), m in zip(frames, models, strict=True)], prior, options, track_options)
    except Exception as exc:  # one track must never stop the batch
        where = traceback.extract_tb(exc.__traceback__)[-1]
        reason = (f"internal error in the track fit: {type(exc).__name__}: {exc} "
                  f"(at {Path(where.filename).name}:{where.lineno})")
        return [_tracked(failed_result(v, prior, reason), track, None) for _, v in frames]
    if not fit.ok:
        return [_tracked(failed_result(v, prior, fit.reason or "the track failed"), track, None) for _, v in frames]
    out = []
    for (im, v), model, frame in zip(frames, models, fit.frames, strict=True):
        if frame.pose_from != "clicks" and model.n_clicks:  # its clicks were left out of the track's fit
            model = build_parts_model(())
        try:
            frame_fit = _as_fit(model, frame, fit)
            if frame.pose_from == "clicks":
                frame_fit = _checked_plausible(frame_fit, model, v, im, prior, options)
            result = describe_fit(v, im.camera, prior, model, frame_fit, im.ground, options, next_clicks, tracked=True)
            with np.errstate(all="ignore"):
                out.append(_tracked(settled(checked_result(result)), track, frame.pose_from))
        except UnusableFit as exc:
            out.append(_tracked(failed_result(v, prior, f"in its track's fit: {exc}"), track, frame.pose_from))
    return out


def _checked_plausible(fit: FitResult, model: PartsModel, vehicle: Vehicle, image: Image, prior: SizePrior,
                       options: SolverOptions) -> FitResult:
    """A clicked frame's pose from the track, checked as a vehicle fitted alone is
    (:mod:`toosicubix.solver.plausibility`: upright, every clicked part on a face turned to the camera, a car's axles
    where cars have them): an implausible one gets :attr:`FitResult.implausible` and its likely cause among its
    warnings, as
    :func:`~toosicubix.pipeline.vehicle.fit_one` gives them (its clicks alone, with left and right swapped, fitting a
    plausible pose: the sides look swapped)."""
    up = None if image.ground is None else image.ground.normal
    why = implausibility(model.click_labels, fit.R_cam_vehicle, fit.t_cam_vehicle, fit.p[:3], options.max_tilt, up,
                         model.click_faces)
    if why is None:
        return with_axles_checked(fit, model, prior)  # a car's wheels on the wrong axles (rule 30)
    flagged = replace(fit, implausible=why, warnings=(*fit.warnings, f"the track's pose in this frame is {why}"))
    return with_likely_cause(flagged, vehicle, image.camera, prior, options, image.ground)


def _tracked(result: VehicleResult, track: str, pose_from: str | None) -> VehicleResult:
    return replace(result, track=track, pose_from=pose_from)


def _as_fit(model: PartsModel, frame: FrameFit, track: TrackFit) -> FitResult:
    """A track's frame as one vehicle's fit reads (what :func:`~toosicubix.pipeline.vehicle.describe_fit` takes)."""
    warnings = frame.warnings + (() if frame.uncertainty is not None else (
        "no uncertainty: the track's information matrix is singular (a direction no frame determines)",))
    return FitResult(
        "ok", None, model.constraints, model.n_clicks, model.n_aux, R_cam_vehicle=frame.R_cam_vehicle,
        t_cam_vehicle=frame.t_cam_vehicle, p=frame.p, cost=frame.cost, residuals_px=frame.residuals_px,
        refine_iterations=track.iterations, initial_cost=track.initial_cost, timings=dict(track.timings),
        warnings=warnings, uncertainty=frame.uncertainty, click_weights=frame.click_weights,
        scale_shares={"size prior": 1.0} if frame.uncertainty is not None else {},
    )


def _track_chunk(tasks: list[TrackTask]) -> list[list[VehicleResult]]:
    return [results_of_track(*task) for task in tasks]


def fit_tracks(images: Iterable[Image], last_of_sequence: dict[str, int], settings: BatchSettings,
               progress: Callable[[int], None] | None = None) -> Iterator[tuple[Image, list[VehicleResult]]]:
    """The results of every tracked vehicle, sequence by sequence: ``(image, [result per tracked vehicle of it, in
    its order])`` for each image with tracked vehicles, once its sequence is fitted (the images are read in file
    order; ``last_of_sequence`` gives each sequence's last image's position in the file, from the index).
    """
    from toosicubix.pipeline.fitting import ordered_map  # the batch's pool, one track a task

    waiting: dict[str, list[Image]] = {}
    tracks: dict[str, dict[str, list[tuple[Image, Vehicle]]]] = {}

    def done(sequence: str) -> Iterator[tuple[Image, list[VehicleResult]]]:
        by_track = tracks.pop(sequence, {})
        tasks = ((track, frames, settings.priors[frames[0][1].prototype], settings.options, settings.track_options,
                  settings.next_clicks) for track, frames in by_track.items())
        results: dict[tuple[str, str], VehicleResult] = {}
        for frames, fitted in zip(by_track.values(), ordered_map(tasks, settings.jobs, 1, _track_chunk), strict=True):
            for (im, v), result in zip(frames, fitted, strict=True):
                results[(im.id, v.id)] = result
            if progress is not None:
                progress(len(frames))
        for im in waiting.pop(sequence, []):
            yield im, [results[(im.id, v.id)] for v in im.vehicles if v.track is not None]

    for position, image in enumerate(images):
        if image.sequence is None or not any(v.track is not None for v in image.vehicles):
            if image.sequence is not None and last_of_sequence.get(image.sequence) == position:
                yield from done(image.sequence)
            continue
        waiting.setdefault(image.sequence, []).append(image)
        for v in image.vehicles:
            if v.track is not None:
                tracks.setdefault(image.sequence, {}).setdefault(v.track, []).append((image, v))
        if last_of_sequence.get(image.sequence) == position:
            yield from done(image.sequence)
    for sequence in list(waiting):  # a sequence whose last image the index did not name (not expected)
        yield from done(sequence)
