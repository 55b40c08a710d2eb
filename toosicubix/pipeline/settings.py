"""How a batch is fitted, as one object (:class:`BatchSettings`), and how the commands assemble it: solver defaults, a
settings file, explicit values (:func:`solver_options`); a ground override (:func:`ground_overrides`).

``toosicubix tune`` writes a settings file (:func:`write_settings_file`); ``fit --config`` and ``validate
--config`` read it back (:func:`solver_options`), and options given on the command line win over it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

from toosicubix.annotations.priors_file import load_priors
from toosicubix.formats.atomic import atomic_write_text
from toosicubix.model import KITTI_GROUND, GroundOverride
from toosicubix.parts.linear import TypicalKeypoint
from toosicubix.size_priors import Priors
from toosicubix.solver.fit import SolverOptions
from toosicubix.solver.track import TrackOptions

#: The settings a file may set (the rest of :class:`SolverOptions` keeps its defaults).
SETTINGS_FIELDS = ("lambda_3d", "lambda_px")


class KeypointCatalogue(Protocol):
    """Keypoints to suggest as next clicks, per prototype (a keypoint mapping,
    :class:`toosicubix.annotations.mapping.MappingFile`)."""

    def keypoint_candidates(self, prototype: str) -> dict[str, TypicalKeypoint]:
        """Name -> where it typically is on a vehicle of ``prototype`` and the faces it is seen from."""
        ...


@dataclass(frozen=True)
class BatchSettings:
    """How every vehicle of a batch is fitted: what ``fit_file``, ``validate_file``, the pilot and the image iterator
    take (:mod:`toosicubix.pipeline.batch`, :mod:`.validation`, :mod:`.pilot`, :mod:`.fitting`).

    Attributes
    ----------
    priors : the size priors (default: the bundled table)
    options : the solver settings
    ground : ground-block fields set on every image over its own block, or None
    joint_ground : refine each image's vehicles together with its ground plane
    jobs : worker processes (the output does not depend on it); 0 (:data:`toosicubix.pipeline.workers.AUTO`): as
        many as the batch repays, :func:`toosicubix.pipeline.workers.workers_for` its vehicles (``--jobs auto``)
    next_clicks : per vehicle, how many suggestions of what to click next the results get (0: none)
    keypoints : suggest a keypoint mapping's keypoints instead of the vocabulary's parts, or None
    estimate_click_sigma : first estimate the click noise from a pilot fit's residuals
        (:mod:`toosicubix.pipeline.click_noise`) and fit with it; ``options.click_sigma`` is the pilot's assumption and
        stays when the batch's clicks are too few to estimate it (``toosicubix fit`` does this unless given
        ``--click-sigma``)
    estimate_part_sigma : with ``estimate_click_sigma``, where no keypoints or plates tell the click noise, estimate
        it and how far the parts sit from the cuboid model from the same pilot fit's cuboid parts
        (:mod:`toosicubix.pipeline.part_placement`) and fit with both (``toosicubix fit`` does this unless given
        ``--click-sigma`` or ``--part-sigma``)
    estimate_road_normal : estimate each camera's road normal from the same pilot fit's vehicles
        (:mod:`toosicubix.pipeline.road_normal`) and fit that camera's images without a ground block of their own
        upright on it (``toosicubix fit`` does this unless given a ground); not with ``ground`` or ``joint_ground``
    tracks : fit the vehicles that carry a ``track`` together with the track's other frames
        (:mod:`toosicubix.pipeline.tracks`); False fits every frame alone (``fit --tracks off``)
    track_options : the tracks' motion model and box cue (:class:`toosicubix.solver.track.TrackOptions`)
    box_cue : a vehicle fitted alone with a ``box2d`` takes the box as a cue too (``fit --box-cue``): the projected
        cuboid's extremes touch its sides (the sides the image border cuts left out)
    """

    priors: Priors = field(default_factory=load_priors)
    options: SolverOptions = field(default_factory=SolverOptions)
    ground: GroundOverride | None = None
    joint_ground: bool = False
    jobs: int = 1
    next_clicks: int = 0
    keypoints: KeypointCatalogue | None = None
    estimate_click_sigma: bool = False
    estimate_part_sigma: bool = False
    estimate_road_normal: bool = False
    tracks: bool = True
    track_options: TrackOptions = field(default_factory=TrackOptions)
    box_cue: bool = False

    def __post_init__(self) -> None:
        if self.estimate_road_normal and (self.ground or self.joint_ground):
            raise ValueError("estimate_road_normal goes without a ground or joint_ground: they say what the road is")


def solver_options(config_path: str | Path | None = None, **explicit: Any) -> SolverOptions:
    """The defaults, then the settings file's values, then ``explicit`` (any :class:`SolverOptions` field).

    Raises
    ------
    toosicubix.errors.InputFileError
        The settings file cannot be read or is not a settings file v1 (file and JSON path).
    """
    options = SolverOptions()
    if config_path is not None:
        from toosicubix.annotations.settings_file import load_settings_file

        settings = load_settings_file(config_path)
        from_file = {k: getattr(settings, k) for k in SETTINGS_FIELDS if getattr(settings, k) is not None}
        options = replace(options, **from_file)
    return replace(options, **explicit)


def ground_overrides(kitti_ground: bool = False, normal: tuple[float, float, float] | None = None,
                     **fields: float | None) -> GroundOverride | None:
    """The ground-block fields to set on every image, or None when none are.

    Parameters
    ----------
    kitti_ground : start from KITTI's nominal block (:data:`toosicubix.model.KITTI_GROUND`)
    normal : (3,) road normal in camera coordinates, or None
    fields : ``camera_height``, ``camera_height_sigma``, ``camera_pitch_deg``, ``camera_roll_deg``,
        ``normal_sigma_deg``, ``upright_sigma_deg``; None leaves a field as it is

    Returns
    -------
    GroundOverride or None
        A camera pitch or roll replaces the normal (the caller refuses both being given).
    """
    override = GroundOverride(normal=normal, **fields).over(KITTI_GROUND if kitti_ground else None)
    return override or None


def settings_document(lambda_3d: float, lambda_px: float, tuned: dict[str, Any]) -> dict[str, Any]:
    """A settings file v1 (``toosicubix_settings: 1``) with the chosen weights and how they were chosen."""
    return {"toosicubix_settings": 1, "lambda_3d": lambda_3d, "lambda_px": lambda_px, "tuned": tuned}


def write_settings_file(path: str | Path, document: dict[str, Any]) -> None:
    """Write a settings file atomically (JSON, one-space indent).

    Raises
    ------
    OSError
        The folder does not exist or is not writable.
    """
    atomic_write_text(path, json.dumps(document, indent=1) + "\n")


__all__ = ["SETTINGS_FIELDS", "BatchSettings", "KeypointCatalogue", "ground_overrides", "settings_document",
           "solver_options", "write_settings_file"]
