"""Many vehicles: fit every vehicle of a stream of images, in one process or several, in input order and with
memory that does not grow with the batch (:func:`iter_fit_images`); refine an image's vehicles together with its
ground plane (:func:`fit_image_jointly`)."""

from __future__ import annotations

import functools
import itertools
import logging
import signal
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import Future, ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from toosicubix.annotations.convert import image_from_schema, with_ground
from toosicubix.annotations.stream import AnnotationIndex, image_annotation, image_texts, iter_image_annotations
from toosicubix.camera import Camera
from toosicubix.errors import InputFileError
from toosicubix.formats.results import ImageResult, RenderedImage, RoadPlane, VehicleResult
from toosicubix.model import GroundOverride, GroundPlane, Image, Vehicle
from toosicubix.parts.linear import build_parts_model
from toosicubix.pipeline import workers
from toosicubix.pipeline.labels import kitti_lines
from toosicubix.pipeline.road_normal import camera_key
from toosicubix.pipeline.settings import BatchSettings, KeypointCatalogue
from toosicubix.pipeline.vehicle import (
    Keypoints,
    SuggestTask,
    UnusableFit,
    checked_result,
    describe_fit,
    failed_result,
    fit_one,
    with_next_clicks,
)
from toosicubix.size_priors import Priors, SizePrior
from toosicubix.solver import compiled
from toosicubix.solver.fit import FitResult, SolverOptions, scale_shares, tested
from toosicubix.solver.joint import JointVehicle, fit_jointly
from toosicubix.solver.misfit import MISFIT_WARNING
from toosicubix.solver.problem import Problem
from toosicubix.solver.robust import with_weights
from toosicubix.solver.uncertainty import analyse

log = logging.getLogger(__name__)

__all__ = ["COMPILED_FROM_VEHICLES", "FitTask", "add_next_clicks", "batch_run", "batch_solver", "check_prototypes",
           "fit_image_jointly", "fit_images", "iter_fit_file", "iter_fit_images", "on_road", "reads_in_workers",
           "shared_workers", "stream_images"]


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


#: What :func:`~toosicubix.pipeline.vehicle.fit_one` takes, as the batch hands it to a worker.
FitTask = tuple[Vehicle, Camera, SizePrior, SolverOptions, GroundPlane | None, int, Keypoints | None, bool]


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
    # Ctrl-C reaches the terminal's whole process group: the main process stops the batch (its running chunks end,
    # the queued ones are cancelled); a worker interrupted inside the compiled solver would otherwise report that
    # solver as broken before it is shut down.
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def fit_images(images: list[Image], settings: BatchSettings | None = None,
               progress: Callable[[int], None] | None = None) -> list[ImageResult]:
    """Fit every vehicle of every image with ``settings``' priors and solver options (the images' own grounds: the
    settings' ground override and estimates are applied where the images are read, :func:`stream_images`).

    Parameters
    ----------
    settings : the batch's settings (default: :class:`BatchSettings`'); its ``jobs`` worker processes give the same
        results for any number (each vehicle is fitted on its own, deterministically, and the results come back in
        input order); with ``joint_ground`` each image's vehicles are then refined together with its ground plane
        (images with a ground block; the camera height may be unknown); ``next_clicks`` suggestions of what to click
        next per vehicle, among ``keypoints`` when given (a keypoint mapping's)
    progress : called with the number of vehicles just finished
    """
    n = sum(len(im.vehicles) for im in images)
    return list(iter_fit_images(images, n, settings, progress))


def iter_fit_images(images: Iterable[Image], n_vehicles: int, settings: BatchSettings | None = None,
                    progress: Callable[[int], None] | None = None,
                    tracked: Iterator[tuple[Image, list[VehicleResult]]] | None = None) -> Iterator[ImageResult]:
    """:func:`fit_images` one image at a time, in input order: the images are read from ``images`` only as
    the workers need them, and each result is handed on as soon as its image is done, so memory does not
    grow with the batch. ``n_vehicles`` (the batch's size) only sets how many vehicles go to a worker at once.

    ``tracked``: the results of the vehicles that carry a ``track``, image by image, a sequence at a time
    (:func:`toosicubix.pipeline.tracks.fit_tracks`), which take their place; None: every vehicle is fitted alone.
    """
    settings = settings or BatchSettings()
    priors, options, next_clicks, jobs = settings.priors, settings.options, settings.next_clicks, settings.jobs
    pending: deque[tuple[Image, dict[int, VehicleResult]]] = deque()  # each with its tracked vehicles' results
    done: list[VehicleResult] = []
    candidates = _candidates_of(settings.keypoints if next_clicks > 0 else None)
    box_cue = settings.box_cue

    # The tracks' results come a sequence at a time, once its last image is read: a file whose sequences are
    # interleaved (or whose images of one sequence enclose another's) gets some before their images come here.
    early: dict[str, list[VehicleResult]] = {}

    def tracked_results(image: Image) -> list[VehicleResult]:
        while image.id not in early:
            same, results = next(tracked)  # type: ignore[arg-type]
            early[same.id] = results
        return early.pop(image.id)

    def tasks() -> Iterator[FitTask]:
        for im in images:
            from_tracks: dict[int, VehicleResult] = {}
            if tracked is not None and any(v.track is not None for v in im.vehicles):
                results = tracked_results(im)
                from_tracks = {j: r for j, r in zip((j for j, v in enumerate(im.vehicles) if v.track is not None),
                                                    results, strict=True)}
            pending.append((im, from_tracks))
            for j, v in enumerate(im.vehicles):
                if j not in from_tracks:
                    yield (v, im.camera, priors[v.prototype], options, im.ground, next_clicks, candidates(v.prototype),
                           box_cue)

    def finished_images() -> Iterator[ImageResult]:
        while pending and len(done) >= len(pending[0][0].vehicles) - len(pending[0][1]):
            im, from_tracks = pending.popleft()
            own = iter(done[:len(im.vehicles) - len(from_tracks)])
            del done[:len(im.vehicles) - len(from_tracks)]
            vehicles = [from_tracks[j] if j in from_tracks else next(own) for j in range(len(im.vehicles))]
            ground = None if im.ground is None else RoadPlane(im.ground.normal, im.ground.camera_height,
                                                              im.ground.from_batch)
            if settings.joint_ground and im.ground is not None:
                vehicles, ground = fit_image_jointly(im, vehicles, priors, options, next_clicks, settings.keypoints)
            yield ImageResult(id=im.id, K=im.camera.K, t_cam_rect=im.camera.t_cam_rect,
                              image_size=im.camera.image_size, vehicles=vehicles, ground=ground, sequence=im.sequence,
                              frame=im.frame)

    for result in ordered_map(tasks(), jobs if n_vehicles > 1 else 1, _chunk(n_vehicles, jobs)):
        done.append(result)
        if progress is not None:
            progress(1)
        yield from finished_images()
    yield from finished_images()  # images without vehicles at the end


#: A batch of fewer vehicles than this is fitted by the numpy path, the compiled solver not loaded: loading it costs
#: about 0.5 s (some 20 s the first time after installing, when numba compiles it), more than it saves on them. It
#: saves 2.3 ms a fit on the KITTI simulated set and 3.2 ms on ApolloCar3D's keypoint cars, and a batch fits each
#: vehicle up to twice (the pilot, then the batch): break-even at about 100 and 80 vehicles in one process, later
#: with more. The results are the same either way (:mod:`toosicubix.solver.compiled`).
COMPILED_FROM_VEHICLES = 64


@contextmanager
def batch_solver(n_vehicles: int, say: Callable[[str], None] | None = None) -> Iterator[None]:
    """The solver path for a batch of ``n_vehicles`` within the block: below :data:`COMPILED_FROM_VEHICLES` the numpy
    path alone (nothing loaded), else the compiled one, loaded now (``say`` is told when numba compiles it first,
    :func:`toosicubix.solver.compiled.warm_up`)."""
    if n_vehicles < COMPILED_FROM_VEHICLES:
        with compiled.numpy_path_only():
            yield
        return
    compiled.warm_up(say)
    yield


@contextmanager
def batch_run(n_vehicles: int, settings: BatchSettings, say: Callable[[str], None] | None = None
              ) -> Iterator[BatchSettings]:
    """What a whole file's batch (``fit``, ``validate``) runs in: the solver path its size takes
    (:func:`batch_solver`) and one pool of workers for its passes (:func:`shared_workers`); yields ``settings`` with
    ``--jobs auto`` resolved for its ``n_vehicles`` (:func:`toosicubix.pipeline.workers.resolved`)."""
    with batch_solver(n_vehicles, say), shared_workers():
        yield replace(settings, jobs=workers.resolved(settings.jobs, n_vehicles))


def _chunk(n_vehicles: int, jobs: int) -> int:
    """How many vehicles go to a worker at once: about sixteen chunks per worker, at most 64 vehicles each. A pass
    (the pilot's, the batch's) ends with its last chunks running while the other workers wait, about half a chunk
    each: a sixteenth of a worker's share loses far less of the pass than a quarter did (benchmarks/decisions.md,
    'What the workers send back')."""
    return max(1, min(64, n_vehicles // (16 * jobs)))


def _share(n_vehicles: int, jobs: int) -> int:
    """A quarter of a worker's share of ``n_vehicles``, at least 1 and at most 64: how many vehicles one image may hold
    for the workers to read the images (:func:`reads_in_workers`)."""
    return max(1, min(64, n_vehicles // (4 * jobs)))


def _fit_chunk(tasks: list[FitTask]) -> list[VehicleResult]:
    return [fit_one(*task) for task in tasks]


def _suggest_chunk(tasks: list[SuggestTask]) -> list[VehicleResult]:
    return [with_next_clicks(*task) for task in tasks]


#: The worker pools of the innermost :func:`shared_workers` block, by number of workers (None: they could not start
#: here, which was said once); None outside any block.
_shared_pools: dict[int, ProcessPoolExecutor | None] | None = None


@contextmanager
def shared_workers() -> Iterator[None]:
    """Within it, every :func:`ordered_map` of the same number of processes takes one pool of workers, started by the
    first of them and shut down when the block ends: a batch's pilot, its fits, its tracks and its next clicks start
    their workers once. Where workers are spawned rather than forked (macOS, Windows, and Linux from Python 3.14),
    each worker imports the package and loads the compiled solver again, about a second a pool."""
    global _shared_pools
    outer, _shared_pools = _shared_pools, {}
    try:
        yield
    finally:
        pools, _shared_pools = _shared_pools, outer
        for pool in pools.values():
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)


def _pool(jobs: int) -> tuple[ProcessPoolExecutor | None, bool]:
    """A pool of ``jobs`` workers and whether the caller owns it (shuts it down) or a :func:`shared_workers` block
    does; None where process pools cannot start (no POSIX semaphores, ...), with a warning: once per block, whose
    later passes (a batch's fits after its pilot) then run in this process without trying again."""
    if _shared_pools is not None and jobs in _shared_pools:
        return _shared_pools[jobs], False
    try:
        pool = _new_pool(jobs)
    except (OSError, NotImplementedError, ImportError) as exc:
        log.warning("cannot start %d worker processes (%s: %s); fitting in this one, with the same results",
                    jobs, type(exc).__name__, exc)
        pool = None
    if _shared_pools is None:
        return pool, True
    _shared_pools[jobs] = pool
    return pool, False


def _new_pool(jobs: int) -> ProcessPoolExecutor:
    # The compiled solver loaded here, before the workers start, is theirs without loading it again (where they are
    # forked: Linux); each would otherwise spend half a second on it, every pool. (Nothing is loaded inside
    # batch_solver's numpy path, which forked workers inherit.)
    compiled.warm_up()
    return ProcessPoolExecutor(max_workers=jobs, initializer=_worker_init)


def ordered_map(tasks: Iterator[tuple], jobs: int, chunk: int,
                work: Callable[[list], list[VehicleResult]] = _fit_chunk) -> Iterator[VehicleResult]:
    """``work`` (:func:`~toosicubix.pipeline.vehicle.fit_one` over a chunk, by default) over ``tasks`` in order,
    in ``jobs`` processes (a :func:`shared_workers` block's, within one), with a bounded number of chunks of ``chunk``
    tasks in flight (the pool's own ``map`` would take every task at once)."""
    pool, owned = _pool(jobs) if jobs > 1 else (None, False)
    if pool is None:
        for task in tasks:
            yield from work([task])
        return
    in_flight: deque[Future[list[VehicleResult]]] = deque()
    try:
        while True:
            while len(in_flight) < 4 * jobs:
                batch = list(itertools.islice(tasks, chunk))
                if not batch:
                    break
                in_flight.append(pool.submit(work, batch))
            if not in_flight:
                return
            yield from in_flight.popleft().result()
    finally:  # left early (an error, or the reader stopped): nothing of this map keeps running
        for future in in_flight:
            future.cancel()
        if owned:
            pool.shutdown(wait=True, cancel_futures=True)


def fit_image_jointly(image: Image, vehicles: list[VehicleResult], priors: Priors, options: SolverOptions,
                      next_clicks: int = 0, keypoints: KeypointCatalogue | None = None
                      ) -> tuple[list[VehicleResult], RoadPlane]:
    """Refine an image's fitted vehicles together with its ground plane (see :mod:`toosicubix.solver.joint`);
    return the updated results and the plane. Failed vehicles stay as they were."""
    ground = image.ground
    assert ground is not None
    # A tracked vehicle keeps its track's pose (the track's other frames hold it there).
    fitted = [(k, v) for k, (v, r) in enumerate(zip(image.vehicles, vehicles, strict=True)) if r.ok and r.track is None]
    if not fitted:
        return vehicles, RoadPlane(ground.normal, ground.camera_height, False)
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
        return vehicles, RoadPlane(ground.normal, ground.camera_height, False,
                                   joint_error=f"{type(exc).__name__}: {exc}")
    plane_fitted = replace(ground, normal=result.normal, camera_height=result.camera_height)
    out = list(vehicles)
    for (k, v), jv, parts, R, t, p in zip(fitted, joint_vehicles, models, result.R, result.t, result.p, strict=True):
        own = with_weights(Problem.build(parts, image.camera, jv.problem.prior, options.lambda_3d, options.lambda_px,
                                         plane_fitted, float(np.linalg.norm(t))), jv.problem.click_weights)
        shares = scale_shares(own, R, t, p)
        u, obs = analyse(own, R, t, p, options.click_sigma, max(shares, key=shares.get) if shares else None,
                         options.part_sigma, soft_noise=options.soft_noise)
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
                describe_fit(v, image.camera, jv.problem.prior, parts, fit, plane_fitted, options, next_clicks,
                             candidates(v.prototype)))
        except UnusableFit as exc:
            out[k] = failed_result(v, jv.problem.prior, f"after the joint refinement: {exc}")
            continue
        out[k] = replace(updated, cues=replace(updated.cues, joint_ground=True),
                         solver=replace(vehicles[k].solver, joint_iterations=result.iterations))
    return out, RoadPlane(result.normal, result.camera_height, True, joint_iterations=result.iterations,
                          vehicles=len(fitted))


def stream_images(index: AnnotationIndex, ground: GroundOverride | None,
                  which: Iterable[int] | None = None) -> Iterator[Image]:
    """The images of an indexed annotation file (:func:`toosicubix.annotations.stream.index_annotations`), one
    at a time, with the ground override set on each; ``which``: only these (their places in the file, in order)."""
    for i, annotation in iter_image_annotations(index, which):
        yield from with_ground([image_from_schema(annotation, i)], ground)


def on_road(image: Image, blocks: Mapping[tuple, GroundOverride]) -> Image:
    """``image`` on its camera's estimated road: without a ground block of its own, it takes the one ``blocks``
    give its camera (:func:`~toosicubix.pipeline.road_normal.camera_key`), marked as the batch's; else as it is."""
    block = blocks.get(camera_key(image.camera)) if image.ground is None and blocks else None
    if block is None:
        return image
    image = with_ground([image], block)[0]
    return replace(image, ground=replace(image.ground, from_batch=True))  # type: ignore[arg-type]


def iter_fit_file(index: AnnotationIndex, settings: BatchSettings, blocks: Mapping[tuple, GroundOverride],
                  progress: Callable[[int], None] | None = None) -> Iterator[ImageResult]:
    """:func:`iter_fit_images` of every image of an indexed file (with the settings' ground override, each on its
    camera's estimated road, ``blocks`` as :func:`on_road` takes them), in ``settings.jobs`` processes, each image
    read by the process that fits it. The results are those of :func:`iter_fit_images` of :func:`stream_images`'
    images as written (:class:`~toosicubix.formats.results.RenderedImage`): each image's results.json entry and
    KITTI label lines, with its vehicles' summaries. The main process only hands out each image's text and takes
    back what it writes, so that it does not limit how many processes a large batch can keep busy (reading an image
    and sending its vehicles to a worker cost the main process about a quarter of what fitting them costs the
    worker, encoding its entry some 0.2 ms a vehicle, and taking back every number of its fits, to write their
    labels, some 0.1 ms).

    The workers get whole images, consecutive ones up to :func:`_chunk`'s number of vehicles at a time: for a file
    whose images are few and crowded, :func:`reads_in_workers` says to read them in the main process instead.
    Not for tracks or ``joint_ground`` (they need the images in the main process): :func:`iter_fit_images`."""
    assert not settings.joint_ground
    jobs = settings.jobs if index.vehicles > 1 else 1
    work = functools.partial(_fit_file_chunk, (replace(settings, jobs=1), dict(blocks)))
    for result in ordered_map(_image_groups(index, _chunk(index.vehicles, jobs)), jobs, 1, work):
        if progress is not None and result.vehicles:
            progress(len(result.vehicles))
        yield result


def reads_in_workers(index: AnnotationIndex, jobs: int) -> bool:
    """Whether :func:`iter_fit_file` keeps ``jobs`` processes about as busy as :func:`iter_fit_images` would: no image
    holds more than half a worker's share of vehicles (twice :func:`_share`; the main process's reading hands out
    vehicles, the workers' whole images)."""
    return jobs > 1 and max(index.image_vehicles, default=0) <= 2 * _share(index.vehicles, jobs)


def _image_groups(index: AnnotationIndex, chunk: int) -> Iterator[list[tuple[int, str]]]:
    """Consecutive images, ``(position, text)`` each, in groups of about ``chunk`` vehicles (at least one image)."""
    group: list[tuple[int, str]] = []
    vehicles = 0
    for i, (text, n) in enumerate(zip(image_texts(index), index.image_vehicles, strict=True)):
        group.append((i, text))
        vehicles += n
        if vehicles >= chunk:
            yield group
            group, vehicles = [], 0
    if group:
        yield group


def _fit_file_chunk(context: tuple[BatchSettings, dict[tuple, GroundOverride]],
                    groups: list[list[tuple[int, str]]]) -> list[ImageResult]:
    """A worker's part of :func:`iter_fit_file`: read, place and fit these images (``(position, text)`` each)."""
    settings, blocks = context
    images = [on_road(image, blocks) for group in groups for i, text in group
              for image in with_ground([image_from_schema(image_annotation(text), i)], settings.ground)]
    # Each image's results.json entry and label lines written here too: the main process only copies them.
    return [RenderedImage.of(r, kitti_lines(r))
            for r in iter_fit_images(images, sum(len(im.vehicles) for im in images), settings)]


def add_next_clicks(images: list[Image], results: list[ImageResult], settings: BatchSettings) -> list[ImageResult]:
    """``results`` (:func:`iter_fit_images`' of ``images``, in order, without next clicks) with ``settings``'
    ``next_clicks`` per vehicle, as if they had been asked for (:func:`~toosicubix.pipeline.vehicle.with_next_clicks`),
    in its ``jobs`` processes."""
    priors, options, n, jobs = settings.priors, settings.options, settings.next_clicks, settings.jobs
    candidates = _candidates_of(settings.keypoints)
    tasks = ((v, im.camera, priors[v.prototype], r, options, im.ground, n, candidates(v.prototype))
             for im, result in zip(images, results, strict=True)
             for v, r in zip(im.vehicles, result.vehicles, strict=True))
    n_vehicles = sum(len(im.vehicles) for im in images)
    done = iter(ordered_map(tasks, jobs if n_vehicles > 1 else 1, _chunk(n_vehicles, jobs), _suggest_chunk))
    return [replace(result, vehicles=[next(done) for _ in result.vehicles]) for result in results]
