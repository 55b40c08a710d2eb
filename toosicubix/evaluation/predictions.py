"""The predictions to score: a ``toosicubix fit`` output folder.

``OUT/results.json`` is read when present: full rotations, poses in the frame where each image's
``K`` applies (``frame == "cam"``). Otherwise KITTI label files are read, from ``OUT/label_2/*.txt``
or ``OUT/*.txt``: yaw only (``R = R_cam_vehicle_from_ypr(ry)``), locations in KITTI's camera 0
(``frame == "rect"``); the evaluation moves them by the ground truth's ``t_cam_rect``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from toosicubix.errors import EvaluationInputError
from toosicubix.formats import kitti
from toosicubix.formats.results import RESULTS_FILENAME, ImageResult, VehicleResult, read_results
from toosicubix.geometry import Cuboid, box2d_of_points, clip_cuboid_to_near_plane, project_pinhole
from toosicubix.vocabulary import family_of

LABEL_DIR = "label_2"


@dataclass(frozen=True)
class PredObject:
    """One predicted vehicle.

    Attributes
    ----------
    id : vehicle id (results.json) or 0-based line index among the label file's objects (KITTI labels)
    cls : KITTI type when known ('Car'), else the prototype
    status : 'ok' or 'failed' (results.json); KITTI labels are always 'ok'
    error : the failure reason, or None
    cuboid : the pose, in the image's ``frame``; None when failed
    box2d : (4,) ``(x1, y1, x2, y2)`` pixels, or None (a failed vehicle without an annotated box)
    source : where it was read: ``file $.images[i].vehicles[j]`` or ``file:line``
    prototype : its prototype (results.json), or None (KITTI labels): with ``cls`` it gives the family of road users
        it may be paired within (:func:`toosicubix.vocabulary.family_of`)
    """

    id: str
    cls: str
    status: str
    error: str | None
    cuboid: Cuboid | None
    box2d: np.ndarray | None
    source: str
    prototype: str | None = None

    @property
    def family(self) -> str:
        """The family of road users it belongs to: a pedestrian is paired with pedestrians only."""
        return family_of(self.prototype, self.cls)

    @property
    def ok(self) -> bool:
        return self.status == "ok" and self.cuboid is not None and self.box2d is not None


@dataclass(frozen=True)
class PredImage:
    """One image's predictions.

    Attributes
    ----------
    id : image id
    frame : 'cam' (poses in the frame of ``K``, results.json) or 'rect' (KITTI camera 0, label files)
    K : (3, 3) or None (label files)
    t_cam_rect : (3,) ``X_cam = X_rect + t_cam_rect`` as results.json states it, or None (label files)
    objects : the vehicles, in file order
    source : the file read
    sequence, frame_number : the video the image is a frame of and its frame number (results.json), or None
    """

    id: str
    frame: str
    K: np.ndarray | None
    t_cam_rect: np.ndarray | None
    objects: tuple[PredObject, ...]
    source: str
    sequence: str | None = None
    frame_number: int | None = None


@dataclass(frozen=True)
class Predictions:
    """Everything read from an output folder.

    Attributes
    ----------
    kind : 'results.json' (full rotations) or 'label_2' (KITTI labels, yaw only)
    source : the file or folder read
    """

    images: tuple[PredImage, ...]
    kind: str
    source: Path

    @property
    def yaw_only(self) -> bool:
        return self.kind == LABEL_DIR


def load_predictions(out_dir: str | Path) -> Predictions:
    """Read a fit output folder: ``results.json`` if present, else KITTI label files (yaw only).

    Raises
    ------
    EvaluationInputError
        The folder is missing, holds neither, or repeats an image id.
    FormatError
        A malformed results.json or label line (file and line or JSON path).
    """
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise EvaluationInputError(f"{out_dir}: prediction folder not found (the output folder of toosicubix fit)")
    results_path = out_dir / RESULTS_FILENAME
    if results_path.is_file():
        return predictions_from_results(read_results(results_path), results_path)
    label_dir = out_dir / LABEL_DIR if (out_dir / LABEL_DIR).is_dir() else out_dir
    paths = sorted(label_dir.glob("*.txt"))
    if not paths:
        raise EvaluationInputError(
            f"{out_dir}: found neither {RESULTS_FILENAME} nor KITTI label files ({LABEL_DIR}/*.txt or *.txt)")
    return Predictions(images=tuple(_image_from_labels(p) for p in paths), kind=LABEL_DIR, source=label_dir)


def predictions_from_results(results: list[ImageResult], source: str | Path = "<results>") -> Predictions:
    """Predictions from fit results held in memory (as ``results.json`` would give them).

    Raises
    ------
    EvaluationInputError
        An image id appears more than once.
    """
    source = Path(source)
    images = tuple(_image_from_result(im, i, source) for i, im in enumerate(results))
    _check_unique(images, source)
    return Predictions(images=images, kind=RESULTS_FILENAME, source=source)


def _image_from_result(im: ImageResult, i: int, path: Path) -> PredImage:
    objects = tuple(_object_from_vehicle(v, im, f"{path} $.images[{i}].vehicles[{j}]")
                    for j, v in enumerate(im.vehicles))
    return PredImage(id=im.id, frame="cam", K=im.K, t_cam_rect=im.t_cam_rect, objects=objects, source=str(path),
                     sequence=im.sequence, frame_number=im.frame)


def _object_from_vehicle(v: VehicleResult, im: ImageResult, source: str) -> PredObject:
    cls = str(v.kitti_type or v.prototype)
    if not v.ok:
        return PredObject(id=v.id, cls=cls, status=v.status, error=v.error, cuboid=None, box2d=v.box2d, source=source,
                          prototype=v.prototype or None)
    cuboid = Cuboid(v.R_cam_vehicle, v.t_cam_vehicle, v.dimensions)  # type: ignore[arg-type]
    box2d = v.box2d if v.box2d is not None else projected_box2d(cuboid, im.K, im.image_size)
    return PredObject(id=v.id, cls=cls, status=v.status, error=v.error, cuboid=cuboid, box2d=box2d, source=source,
                      prototype=v.prototype or None)


def projected_box2d(cuboid: Cuboid, K: np.ndarray, image_size: tuple[int, int] | None) -> np.ndarray | None:
    """The 2D box ``(x1, y1, x2, y2)`` of a cuboid's projection by ``K``, clipped to the image when its size
    is known; None when the cuboid lies wholly behind the camera."""
    points_cam = clip_cuboid_to_near_plane(cuboid.corners())
    if len(points_cam) == 0:
        return None
    return box2d_of_points(project_pinhole(K, points_cam), image_size)


def _image_from_labels(path: Path) -> PredImage:
    objects = []
    for i, obj in enumerate(kitti.read_label_file(path)):
        cuboid = Cuboid(obj.R_cam_vehicle, obj.location_rect, obj.dimensions) if obj.type != "DontCare" else None
        objects.append(PredObject(
            id=str(i), cls=obj.type, status="ok" if cuboid is not None else "failed",
            error=None if cuboid is not None else "DontCare line in a prediction file",
            cuboid=cuboid, box2d=np.asarray(obj.box2d, dtype=float), source=f"{path}:{obj.line}",
        ))
    return PredImage(id=path.stem, frame="rect", K=None, t_cam_rect=None, objects=tuple(objects), source=str(path))


def _check_unique(images: tuple[PredImage, ...], path: Path) -> None:
    seen: set[str] = set()
    for im in images:
        if im.id in seen:
            raise EvaluationInputError(f"{path}: image id {im.id!r} appears more than once")
        seen.add(im.id)
