"""A batch's pilot: fit a sample of its vehicles first and estimate from them what ``fit`` estimates (the click
noise, each camera's road normal), then put the images on their camera's estimated road
(:func:`run_pilot`, :func:`on_estimated_roads`). A small batch the pilot fitted whole with nothing changed is
written from the pilot's own fits."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from toosicubix.annotations.convert import camera_from_schema
from toosicubix.annotations.stream import AnnotationIndex, index_annotations
from toosicubix.formats.results import ImageResult
from toosicubix.model import GroundOverride, Image
from toosicubix.pipeline.click_noise import ClickNoise, estimate_from_pilot, pilot_images, pilot_positions, telling
from toosicubix.pipeline.fitting import add_next_clicks, iter_fit_images, on_road, stream_images
from toosicubix.pipeline.part_placement import PartPlacement, estimate_placement, evidence, evidence_dof, too_few
from toosicubix.pipeline.road_normal import (
    MIN_VEHICLES,
    RoadNormal,
    camera_key,
    describe_without_pilot,
    estimate_road_normals,
    ground_block,
    without_pilot,
)
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.size_priors import Priors
from toosicubix.solver.fit import SolverOptions
from toosicubix.vocabulary import KINDS

__all__ = ["PilotFindings", "estimated_grounds", "file_estimates", "on_estimated_roads", "run_pilot"]


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
        nothing to change); None otherwise. :func:`~toosicubix.pipeline.batch.fitted_batch` then writes them
        instead of fitting again.
    next_clicks : how many next clicks per vehicle those results have
    part_placement : the click noise and how far the parts sit from the cuboid model, estimated from the residuals
        of a batch of cuboid parts (:mod:`toosicubix.pipeline.part_placement`), when it was; None otherwise
    part_placement_dof : the degrees of freedom the pilot's cuboid parts gave when too few for that estimate (the
        batch keeps its settings); None when it was made or not asked for
    """

    options: SolverOptions
    click_noise: ClickNoise
    road_normals: dict[tuple, RoadNormal] | None = None
    without_pilot: dict[str, int] = field(default_factory=dict)
    results: list[ImageResult] | None = None
    next_clicks: int = 0
    part_placement: PartPlacement | None = None
    part_placement_dof: float | None = None

    def header(self) -> dict[str, Any]:
        """What results.json's header (and validate's report) say about the pilot's estimates."""
        out: dict[str, Any] = {}
        if self.part_placement is not None:
            out["part_placement"] = self.part_placement.to_json()
        elif self.click_noise.source != "given":
            out["click_noise"] = self.click_noise.to_json()
        if self.road_normals is not None:
            out["road_normal"] = [n.to_json() for n in self.road_normals.values()]
        if self.without_pilot.get("cameras"):
            out["road_normal_without_pilot"] = self.without_pilot
        return out

    def describe(self) -> list[str]:
        """Summary lines for ``fit`` and ``validate``: the click noise; each camera with a road normal (or one
        refused for scattered up axes), at most five; one line for the cameras with too few pilot vehicles."""
        if self.part_placement is not None:
            lines = [self.part_placement.describe()]
        elif self.part_placement_dof is not None and self.click_noise.source == "default":
            lines = [too_few(self.part_placement_dof, self.options.part_sigma, self.click_noise.sigma_px)]
        else:
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


def run_pilot(index: AnnotationIndex, settings: BatchSettings, progress: Callable[[int], None] | None = None,
              on_start: Callable[[int], None] | None = None) -> PilotFindings:
    """Fit every k-th vehicle of an indexed file (at most :data:`toosicubix.pipeline.click_noise.PILOT_VEHICLES`,
    held in memory) and estimate from them what ``settings`` ask: the click noise
    (:mod:`toosicubix.pipeline.click_noise`; its vehicles only) and each camera's road normal
    (:mod:`toosicubix.pipeline.road_normal`; any vehicle). Nothing asked: no pilot. When the pilot fits every
    vehicle of the file with the batch's settings, its fits are the batch's (:attr:`PilotFindings.results`), and it
    then adds the ``next_clicks`` the batch asks for to them (``jobs`` processes; none with ``joint_ground``, whose
    refinement changes the fits). Fits it does not hand on get none: their guidance (a quarter to a half of a fit's
    time with a mapping's keypoints) would be thrown away.

    ``on_start`` is called once with the vehicles the whole batch fits, the pilot's and the file's;
    ``progress`` with each vehicle the pilot finishes.
    """
    options = settings.options
    estimate_click_sigma, estimate_road_normal = settings.estimate_click_sigma, settings.estimate_road_normal
    next_clicks = 0 if settings.joint_ground else settings.next_clicks
    cameras: Counter = Counter()  # images without their own ground block, per camera
    estimate_parts = estimate_click_sigma and settings.estimate_part_sigma
    pilot: list[Image] = []
    if estimate_click_sigma or estimate_road_normal:
        cameras = _without_ground(index, settings.ground)
        # Only the images that hold a pilot vehicle are read: a batch of 100,000 vehicles read them all here,
        # some 9 s in the main process before its first fit, for the pilot's 400.
        positions = pilot_positions(index.image_clicked, index.clicked)
        pilot = list(pilot_images(stream_images(index, settings.ground, [i for i, _ in positions]), index.clicked,
                                  keep=None if estimate_road_normal or estimate_parts else telling,
                                  clicked_before=[before for _, before in positions]))
    n_pilot = sum(len(im.vehicles) for im in pilot)
    if on_start is not None:
        on_start(index.vehicles + n_pilot)
    pilot_options = replace(options, robust_loss="none")
    every = n_pilot == index.vehicles
    pilot_settings = replace(settings, options=pilot_options, joint_ground=False, next_clicks=0, keypoints=None,
                             estimate_click_sigma=False, estimate_part_sigma=False, estimate_road_normal=False,
                             ground=None)
    results = list(iter_fit_images(iter(pilot), n_pilot, pilot_settings, progress)) if pilot else []
    noise = ClickNoise(options.click_sigma, "given")
    placement, placement_dof = None, None
    if estimate_click_sigma:
        noise = estimate_from_pilot(results, options.click_sigma)
        options = replace(options, click_sigma=noise.sigma_px, soft_noise=noise.sigmas_noise)
        if estimate_parts and noise.source != "estimated":  # no keypoints tell the noise: the cuboid parts may
            items = evidence((im.camera for im in pilot), results)
            placement = estimate_placement(items)
            if placement is not None:
                options = replace(options, click_sigma=placement.sigma_px, part_sigma=placement.part_sigma_m)
            else:
                placement_dof = evidence_dof(items)
    normals = estimate_road_normals(pilot, results, cameras) if estimate_road_normal else None
    # The pilot's fits are the batch's when it fitted every vehicle as the batch will: same settings, and no
    # road normal that would give some images a ground block.
    own = bool(pilot and every and _fitted_alike(pilot, options, pilot_options)
           and not any(n.normal is not None for n in (normals or {}).values()))
    pilot_next = next_clicks if own else 0
    if own and next_clicks > 0:
        results = add_next_clicks(pilot, results, replace(settings, options=options, next_clicks=next_clicks))
    if normals is None:
        return PilotFindings(options, noise, results=results if own else None, next_clicks=pilot_next,
                             part_placement=placement, part_placement_dof=placement_dof)
    return PilotFindings(options, noise, normals, without_pilot(cameras, normals), results if own else None,
                         pilot_next, placement, placement_dof)


def _without_ground(index: AnnotationIndex, ground: GroundOverride | None) -> Counter:
    """Per camera (:func:`~toosicubix.pipeline.road_normal.camera_key`), how many images of an indexed file are
    without a ground block once ``ground`` is set on them (none when it is: it gives every image one)."""
    if ground:
        return Counter()
    keys = [camera_key(camera_from_schema(camera, None)) for camera in index.cameras]
    return Counter(keys[c] for c, grounded in zip(index.image_cameras, index.image_grounded, strict=True)
                   if not grounded)


def _fitted_alike(pilot: list[Image], options: SolverOptions, pilot_options: SolverOptions) -> bool:
    """Whether the pilot's settings fit its vehicles as ``options`` do: the same settings, or ``options``' robust
    loss is 'auto' and no pilot vehicle has a keypoint or plate click (which 'auto' alone would reweight)."""
    if options == pilot_options:
        return True
    return replace(options, robust_loss="none") == pilot_options and options.robust_loss == "auto" and not any(
        KINDS[part.kind].soft for im in pilot for v in im.vehicles for part in v.parts)


def file_estimates(annotations: str | Path, priors: Priors, options: SolverOptions, estimate_click_sigma: bool = True,
                   estimate_road_normal: bool = True, progress: Callable[[int], None] | None = None,
                   ground: GroundOverride | None = None, estimate_part_sigma: bool = False) -> PilotFindings:
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
    settings = BatchSettings(priors, options, ground, estimate_click_sigma=estimate_click_sigma,
                             estimate_road_normal=estimate_road_normal, estimate_part_sigma=estimate_part_sigma)
    return run_pilot(index, settings, progress=progress)


def estimated_grounds(normals: dict[tuple, RoadNormal] | None) -> dict[tuple, GroundOverride]:
    """Per camera (:func:`toosicubix.pipeline.road_normal.camera_key`), the ground block its estimated road normal
    gives the camera's images without one of their own; cameras without an estimate are left out."""
    return {key: ground_block(n) for key, n in (normals or {}).items() if n.normal is not None}


def on_estimated_roads(images: Iterable[Image], normals: dict[tuple, RoadNormal] | None) -> Iterator[Image]:
    """The images, each without a ground block of its own given its camera's estimated road normal
    (:func:`toosicubix.pipeline.road_normal.ground_block`) when there is one."""
    blocks = estimated_grounds(normals)
    for im in images:
        yield on_road(im, blocks)
