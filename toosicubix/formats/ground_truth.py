"""Ground truth from KITTI object labels, KITTI tracking labels, Cityscapes 3D or ApolloCar3D, in one per-image form:
the one dispatch from a dataset's kind to its reader (:func:`open_ground_truth`), for evaluation, size-prior
estimation and simulation alike.

Every source turns one image id into a :class:`GtImage`: its objects as cuboids in the ground
truth's own frame ``rect`` plus ``t_cam_rect``, the offset of the camera whose ``K`` applies
(``X_cam = X_rect + t_cam_rect``):

- KITTI: ``rect`` is camera 0; ``t_cam_rect = K^-1 P2[:, 3]`` from the frame's (or sequence's) calib
  file, about 6 cm; None when there is no calib file, so the caller must supply it.
- Cityscapes 3D: boxes are converted from the ego frame straight into the camera frame of ``K``, so
  ``rect`` is that frame and ``t_cam_rect`` is zero.

Image ids: KITTI object ``000123`` (``label_2/000123.txt``); KITTI tracking ``<seq>_<frame as 6
digits>``, e.g. ``0010_000123`` (``label_02/0010.txt``, frame 123); Cityscapes the file stem without
``_gtBbox3d``, e.g. ``aachen_000000_000019`` (a trailing ``_leftImg8bit`` on the asked id is ignored).
Only images that are asked for are read.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from toosicubix.errors import EvaluationInputError, FormatError
from toosicubix.formats import kitti
from toosicubix.formats.cityscapes import read_gtbbox3d
from toosicubix.formats.datasets import (
    GTBBOX3D_SUFFIX,
    KITTI_VEHICLE_CLASSES,
    CityscapesFolder,
    KittiObjectFolder,
    KittiTrackingFolder,
    parse_tracking_image_id,
    tracking_image_id,
)
from toosicubix.geometry import Cuboid

#: Classes scored by default, compared case-insensitively.
KITTI_DEFAULT_CLASSES = KITTI_VEHICLE_CLASSES
CITYSCAPES_DEFAULT_CLASSES = ("car", "truck", "bus", "caravan", "trailer", "train")
#: Class of a Cityscapes ``ignore`` region (it has no 3D box and is never scored).
CITYSCAPES_IGNORE_CLASS = "ignore"
#: Cityscapes labels whose boxes are vehicles; their ``type`` names are the prototypes priors are estimated for.
CITYSCAPES_VEHICLE_LABELS = ("car", "truck", "bus", "train", "motorcycle", "bicycle", "caravan", "trailer")


@dataclass(frozen=True)
class GtObject:
    """One ground-truth object.

    Attributes
    ----------
    index : position among the image's objects as read (0-based, all classes)
    cls : KITTI type ('Car', 'DontCare', ...) or Cityscapes label ('car', ...)
    cuboid_rect : the cuboid in the ground truth's ``rect`` frame, or None (KITTI DontCare, Cityscapes ignore)
    box2d : (4,) ``(x1, y1, x2, y2)`` pixels (Cityscapes: the amodal box)
    truncation : KITTI truncation (fraction; tracking labels 0, 1, 2) or Cityscapes fraction; None if absent
    occlusion : KITTI occlusion level 0-3, else None
    occlusion_fraction : Cityscapes occlusion in [0, 1], else None
    track_id : KITTI tracking track id, Cityscapes instanceId, else None
    source : where it was read: ``file:line`` or ``file $.objects[i]``
    subtype : Cityscapes ``3d.type`` (e.g. 'Mid Size Car'), else ''
    keypoints : how many keypoints people labelled on it (ApolloCar3D), else None
    keypoints_hidden : how many of those its pose turns away from the camera (ApolloCar3D: none of the faces the
        bundled ``apollocar3d-66`` mapping learned each keypoint is seen from turned to it), else None
    keypoints_off_rays_m : the RMS distance (metres) of those from their rays, each at its learned place on the
        ground-truth cuboid (ApolloCar3D with its cameras, :func:`toosicubix.formats.apollocar3d.keypoints_off_rays`),
        else None
    """

    index: int
    cls: str
    cuboid_rect: Cuboid | None
    box2d: np.ndarray
    truncation: float | None
    occlusion: int | None
    occlusion_fraction: float | None
    track_id: int | None
    source: str
    subtype: str = ""
    keypoints: int | None = None
    keypoints_hidden: int | None = None
    keypoints_off_rays_m: float | None = None


@dataclass(frozen=True)
class GtImage:
    """The ground truth of one image.

    Attributes
    ----------
    id : image id
    objects : every object read, all classes
    t_cam_rect : (3,) ``X_cam = X_rect + t_cam_rect`` for the camera whose ``K`` applies; None when
        unknown (KITTI without a calib file)
    K : (3, 3) intrinsics of that camera, or None when unknown
    source : the label file read (tracking: ``file`` plus ``frame N``)
    calib_source : the calibration read, or None
    """

    id: str
    objects: tuple[GtObject, ...]
    t_cam_rect: np.ndarray | None
    K: np.ndarray | None
    source: str
    calib_source: str | None = None


class GroundTruthSource:
    """A ground-truth dataset opened for reading, image by image.

    Attributes
    ----------
    kind : 'kitti', 'kitti-tracking', 'cityscapes' or 'apollocar3d'
    root : the folder given
    default_classes : classes scored when none are asked for
    occlusion_kind : 'level' (KITTI 0-3), 'fraction' (Cityscapes), or None (no occlusion in this ground truth)
    """

    kind: str = ""
    default_classes: tuple[str, ...] = ()
    occlusion_kind: str | None = "level"
    #: Objects carry track ids that name one physical object across images (a size prior counts it once).
    per_track: bool = False

    def __init__(self, root: str | Path):
        self.root = Path(root)
        if not self.root.is_dir():
            raise EvaluationInputError(f"ground-truth folder not found ({self.kind})", self.root)

    def size_class(self, obj: GtObject) -> str | None:
        """The class a size prior is estimated for from ``obj`` (None: none, e.g. KITTI's DontCare)."""
        return obj.cls if obj.cuboid_rect is not None else None

    def image_ids(self) -> list[str]:
        """Every image id that has ground truth, sorted."""
        raise NotImplementedError

    def resolve_id(self, image_id: str, sequence: str | None = None, frame: int | None = None) -> str:
        """The ground-truth id a prediction's image pairs with (its id, or its ``sequence`` and ``frame`` where the
        source names frames so: the same id unless a source says otherwise)."""
        return image_id

    def load(self, image_id: str) -> GtImage:
        """The ground truth of one image.

        Raises
        ------
        EvaluationInputError
            No ground truth for that id; the message names the path that was expected.
        FormatError
            A malformed file (file and line, or JSON path).
        """
        raise NotImplementedError

    def describe(self) -> str:
        """One line saying what is read, for reports."""
        return f"{self.kind} ground truth in {self.root}"


def _walk(walker: type[KittiObjectFolder | KittiTrackingFolder | CityscapesFolder], root: Path):
    """The dataset's folder walker; a folder without its files is an :class:`EvaluationInputError`."""
    try:
        return walker(root)
    except FormatError as exc:
        raise EvaluationInputError(exc.message, exc.file) from None


def _kitti_gt_object(obj: kitti.KittiObject, index: int, source: Path) -> GtObject:
    cuboid = None
    if obj.type != "DontCare":
        cuboid = Cuboid(obj.R_cam_vehicle, obj.location_rect, obj.dimensions)
    return GtObject(
        index=index, cls=obj.type, cuboid_rect=cuboid, box2d=np.asarray(obj.box2d, dtype=float),
        truncation=float(obj.truncated), occlusion=int(obj.occluded), occlusion_fraction=None,
        track_id=obj.track_id, source=f"{source}:{obj.line}",
    )


def _calib_offset(calib_path: Path | None) -> tuple[np.ndarray | None, np.ndarray | None, str | None]:
    """``(t_cam_rect, K, source)`` of camera 2 from a calib file, or Nones when there is none."""
    if calib_path is None or not calib_path.is_file():
        return None, None, None
    camera = kitti.read_calib(calib_path).camera(2)
    return camera.t_cam_rect, camera.K, str(calib_path)


class _KittiGroundTruth(GroundTruthSource):
    """KITTI labels in the folder its walker (:attr:`walker`) finds; ``strict``: ``label_2/`` (or ``label_02/``) and
    ``calib/`` both required (the simulator's need), named as the walker names them."""

    default_classes = KITTI_DEFAULT_CLASSES
    walker: type[KittiObjectFolder] | type[KittiTrackingFolder]

    def __init__(self, root: str | Path, strict: bool = False):
        if strict:
            self.root, self.folder = Path(root), self.walker(root, strict=True)
        else:
            super().__init__(root)
            self.folder = _walk(self.walker, self.root)
        self.label_dir, self.calib_dir = self.folder.label_dir, self.folder.calib_dir


class KittiObjectGroundTruth(_KittiGroundTruth):
    """KITTI object-benchmark labels: ``DIR/label_2/<id>.txt`` with ``DIR/calib/<id>.txt``, or ``DIR/<id>.txt``
    with the calib folder at ``DIR/../calib``."""

    kind = "kitti"
    walker = KittiObjectFolder
    folder: KittiObjectFolder

    def image_ids(self) -> list[str]:
        return self.folder.image_ids()

    def load(self, image_id: str) -> GtImage:
        path = self.folder.label_file(image_id)
        if not path.is_file():
            raise EvaluationInputError(f"no ground truth for image {image_id!r}: expected {path}")
        objects = tuple(_kitti_gt_object(obj, i, path) for i, obj in enumerate(kitti.read_label_file(path)))
        t_cam_rect, K, calib_source = _calib_offset(self.folder.calib_file(image_id))
        return GtImage(id=image_id, objects=objects, t_cam_rect=t_cam_rect, K=K, source=str(path),
                       calib_source=calib_source)

    def describe(self) -> str:
        calib = self.calib_dir if self.calib_dir is not None else "none found"
        return f"KITTI object labels in {self.label_dir} (calib: {calib})"


class KittiTrackingGroundTruth(_KittiGroundTruth):
    """KITTI tracking labels: ``DIR/label_02/<seq>.txt`` with ``DIR/calib/<seq>.txt``; image ids
    ``<seq>_<frame as 6 digits>``."""

    kind = "kitti-tracking"
    walker = KittiTrackingFolder
    folder: KittiTrackingFolder
    per_track = True

    def __init__(self, root: str | Path, strict: bool = False):
        super().__init__(root, strict)
        self._sequences: dict[str, dict[int, list[kitti.KittiObject]]] = {}

    def image_ids(self) -> list[str]:
        """Frames 0 to the last labelled frame of every sequence (a frame without rows has no objects)."""
        return self.folder.image_ids()

    def resolve_id(self, image_id: str, sequence: str | None = None, frame: int | None = None) -> str:
        """A frame's id ``<sequence>_<frame as 6 digits>``: the image id's when it is one (``0001_5`` is
        ``0001_000005``: one frame, one id), else made from the image's ``sequence`` and ``frame`` (an annotation file
        whose frames carry other ids)."""
        parsed = parse_tracking_image_id(image_id)
        if parsed is not None:
            return tracking_image_id(*parsed)
        if sequence is not None and frame is not None:
            return tracking_image_id(sequence, frame)
        return image_id

    def sequence_ids(self, sequence: str) -> list[str]:
        """The image ids of one sequence's frames, 0 to its last labelled one (its label file must exist)."""
        return [tracking_image_id(sequence, f) for f in range(self.folder.last_frame(sequence) + 1)]

    def _sequence(self, sequence: str) -> dict[int, list[kitti.KittiObject]]:
        if sequence not in self._sequences:
            self._sequences[sequence] = kitti.read_tracking_file(self.folder.label_file(sequence))
        return self._sequences[sequence]

    def load(self, image_id: str) -> GtImage:
        parsed = parse_tracking_image_id(image_id)
        if parsed is None:
            raise EvaluationInputError(
                f"image id {image_id!r} is not a KITTI tracking id: expected <sequence>_<frame>, e.g. 0010_000123")
        sequence, frame = parsed
        path = self.folder.label_file(sequence)
        if not path.is_file():
            raise EvaluationInputError(f"no ground truth for image {image_id!r}: expected {path} (sequence {sequence})")
        # A frame without rows has no labelled objects.
        rows = self._sequence(sequence).get(frame, [])
        objects = tuple(_kitti_gt_object(obj, i, path) for i, obj in enumerate(rows))
        t_cam_rect, K, calib_source = _calib_offset(self.folder.calib_file(sequence))
        return GtImage(id=image_id, objects=objects, t_cam_rect=t_cam_rect, K=K, source=f"{path} frame {frame}",
                       calib_source=calib_source)

    def describe(self) -> str:
        calib = self.calib_dir if self.calib_dir is not None else "none found"
        return f"KITTI tracking labels in {self.label_dir} (calib: {calib})"


class CityscapesGroundTruth(GroundTruthSource):
    """Cityscapes 3D ``*_gtBbox3d.json`` files anywhere under ``DIR`` (other ``*.json`` files are read too);
    image id = file stem without ``_gtBbox3d``."""

    kind = "cityscapes"
    default_classes = CITYSCAPES_DEFAULT_CLASSES
    occlusion_kind = "fraction"

    def size_class(self, obj: GtObject) -> str | None:
        """A vehicle box's prototype (its ``3d.type``, e.g. 'Mid Size Car')."""
        return obj.subtype if obj.cls in CITYSCAPES_VEHICLE_LABELS and obj.subtype else None

    def __init__(self, root: str | Path):
        super().__init__(root)
        self.folder: CityscapesFolder = _walk(CityscapesFolder, self.root)

    def image_ids(self) -> list[str]:
        return self.folder.image_ids()

    def resolve_id(self, image_id: str, sequence: str | None = None, frame: int | None = None) -> str:
        return self.folder.resolve_id(image_id)

    def load(self, image_id: str) -> GtImage:
        gt_id = self.resolve_id(image_id)
        if gt_id in self.folder.clashes:
            files = ", ".join(str(p) for p in self.folder.clashes[gt_id])
            raise EvaluationInputError(f"image {image_id!r}: several ground-truth files have that name: {files}")
        path = self.folder.files.get(gt_id)
        if path is None:
            raise EvaluationInputError(
                f"no ground truth for image {image_id!r}: "
                f"expected a file {gt_id}{GTBBOX3D_SUFFIX}.json under {self.root}")
        ann = read_gtbbox3d(path)
        objects = []
        for box in ann.objects:
            R_cam_vehicle, t_cam_vehicle = box.pose_cam(ann.camera)
            objects.append(GtObject(
                index=box.index, cls=box.label, cuboid_rect=Cuboid(R_cam_vehicle, t_cam_vehicle, box.dimensions),
                box2d=box.box2d_amodal, truncation=box.truncation, occlusion=None, occlusion_fraction=box.occlusion,
                track_id=box.instance_id, source=f"{path} $.objects[{box.index}]", subtype=box.type,
            ))
        for region in ann.ignore:
            objects.append(GtObject(
                index=len(ann.objects) + region.index, cls=CITYSCAPES_IGNORE_CLASS, cuboid_rect=None,
                box2d=region.box2d, truncation=None, occlusion=None, occlusion_fraction=None,
                track_id=region.instance_id, source=f"{path} $.ignore[{region.index}]",
            ))
        return GtImage(id=gt_id, objects=tuple(objects), t_cam_rect=np.zeros(3), K=ann.camera.K, source=str(path),
                       calib_source=str(path))

    def describe(self) -> str:
        return f"Cityscapes 3D gtBbox3d files under {self.root} ({len(self.folder.files)} images)"


class ApolloCar3DGroundTruth(GroundTruthSource):
    """ApolloCar3D: a keypoint file (COCO with a 6-DoF ``pose`` per car) and ``car_models.json`` (by default
    beside it); image id = the file name's stem, every car of class 'Car', frames as
    :mod:`toosicubix.formats.apollocar3d` says. Poses are in the camera frame of ``K`` (``t_cam_rect`` zero).
    Each car also counts the labelled keypoints its pose turns away from the camera
    (:func:`toosicubix.formats.apollocar3d.keypoints_hidden`, with the faces the bundled ``apollocar3d-66``
    mapping learned): a pose that hides its own clicks contradicts them. With a cameras file (``cameras``, by
    default the ``cameras.json`` beside the keypoint file when there is one) each car also gets how far its labelled
    keypoints lie from their rays at its pose (:func:`toosicubix.formats.apollocar3d.keypoints_off_rays`): a pose
    far off them contradicts them too. An image its cameras file has no camera for gets no such distance."""

    kind = "apollocar3d"
    default_classes = ("Car",)
    occlusion_kind = None

    def size_class(self, obj: GtObject) -> str | None:
        """The prototype its car model's type gets on import (hatchback ``Car``, saloon ``Sedan``, ``SUV``)."""
        from toosicubix.formats.apollocar3d import prototype_of

        return prototype_of(obj.subtype)

    def __init__(self, root: str | Path, car_models: str | Path | None = None, cameras: str | Path | None = None,
                 keypoint_checks: bool = True):
        from toosicubix.errors import FormatError, InputFileError
        from toosicubix.formats.apollocar3d import car_models_file, read_apollocar3d, read_car_models
        from toosicubix.formats.cameras import load_cameras

        self.root = Path(root)
        if not self.root.is_file():
            raise EvaluationInputError(f"{self.root}: ApolloCar3D keypoint file not found")
        self.car_models = car_models_file(self.root, car_models)
        self.keypoint_checks = keypoint_checks
        beside = self.root.parent / "cameras.json"
        found = beside if beside.is_file() and keypoint_checks else None
        self.cameras = Path(cameras) if cameras is not None else found
        if self.cameras is not None and not self.cameras.exists():
            raise EvaluationInputError(f"{self.cameras}: cameras file not found")
        try:
            images = read_apollocar3d(self.root, read_car_models(self.car_models))
        except InputFileError as exc:
            raise FormatError(exc.file, "; ".join(f"{p}: {m}" for p, m in exc.problems)) from None
        self._images = {im.id: im for im in images}
        try:
            self._camera_table = None if self.cameras is None else load_cameras(self.cameras)
        except FormatError as exc:
            if cameras is not None:
                raise
            raise FormatError(exc.file, f"{exc.message} (read as the cameras of {self.root.name}'s images because it "
                                        "lies beside it; --cameras names another)", exc.line) from None
        self._candidates: dict[str, list] = {}

    def _keypoints_of(self, prototype: str) -> list:
        """Per keypoint index, the bundled ``apollocar3d-66`` mapping's keypoint on a car of ``prototype``
        (:class:`toosicubix.parts.linear.TypicalKeypoint`: its place and the faces it is seen from), or None."""
        if prototype not in self._candidates:
            from toosicubix.annotations.mapping import load_mapping

            mapping, _ = load_mapping("apollocar3d-66")
            candidates = mapping.keypoint_candidates(prototype)
            self._candidates[prototype] = [candidates.get(name) for name in mapping.keypoints or ()]
        return self._candidates[prototype]

    def _K(self, file_name: str) -> np.ndarray | None:
        from toosicubix.formats.cameras import intrinsics

        camera = None if self._camera_table is None else self._camera_table.camera_for(file_name)
        return None if camera is None else intrinsics(camera)  # a K, or a KITTI calib's P[:, :3]

    def image_ids(self) -> list[str]:
        return sorted(self._images)

    def load(self, image_id: str) -> GtImage:
        from toosicubix.formats.apollocar3d import keypoints_hidden, keypoints_off_rays, prototype_of

        im = self._images.get(image_id)
        if im is None:
            raise EvaluationInputError(f"no ground truth for image {image_id!r}: not in {self.root}")
        K = self._K(im.file_name)
        objects = []
        for k, car in enumerate(im.cars):
            typical = self._keypoints_of(prototype_of(car.model.type)) if self.keypoint_checks else None
            seen_from = None if typical is None else [() if t is None else tuple(t.seen_from) for t in typical]
            objects.append(GtObject(
                index=k, cls="Car", cuboid_rect=Cuboid(car.R_cam_vehicle, car.t_cam_vehicle, car.model.dimensions),
                box2d=car.box2d, truncation=None, occlusion=None, occlusion_fraction=None,
                track_id=int(car.id) if car.id.isascii() and car.id.isdigit() else None, source=car.source,
                subtype=car.model.type,
                keypoints=int(np.count_nonzero(car.keypoints[:, 2] > 0)),
                keypoints_hidden=None if seen_from is None else keypoints_hidden(car, seen_from),
                keypoints_off_rays_m=None if K is None or typical is None else keypoints_off_rays(
                    car, K, [None if t is None else t.at for t in typical])))
        return GtImage(id=image_id, objects=tuple(objects), t_cam_rect=np.zeros(3), K=K, source=str(self.root))

    def describe(self) -> str:
        cameras = "" if self.cameras is None else f" and cameras {self.cameras}"
        return (f"ApolloCar3D keypoints {self.root} with car models {self.car_models}{cameras} "
                f"({len(self._images)} images)")


#: The ``--kitti``, ``--kitti-tracking``, ``--cityscapes`` and ``--apollocar3d`` sources by kind.
SOURCES: dict[str, type[GroundTruthSource]] = {
    "kitti": KittiObjectGroundTruth,
    "kitti-tracking": KittiTrackingGroundTruth,
    "cityscapes": CityscapesGroundTruth,
    "apollocar3d": ApolloCar3DGroundTruth,
}


def open_ground_truth(kind: str, root: str | Path, **source_options: Any) -> GroundTruthSource:
    """Open a ground-truth folder (or ApolloCar3D's keypoint file): the one place a dataset's kind chooses its reader
    (``eval``, ``priors``, ``simulate`` and ``tune`` all open theirs here).

    Parameters
    ----------
    kind : 'kitti', 'kitti-tracking', 'cityscapes' or 'apollocar3d'
    root : the folder, or the file
    source_options : further arguments of the source (``strict`` for KITTI: ``label_2/`` or ``label_02/`` and
        ``calib/`` both required; ``car_models``, ``cameras`` and ``keypoint_checks`` for 'apollocar3d')

    Raises
    ------
    EvaluationInputError
        Unknown kind, missing folder, or a folder without the expected files.
    """
    if kind not in SOURCES:
        raise EvaluationInputError(f"unknown ground-truth kind {kind!r}; expected one of {', '.join(SOURCES)}")
    return SOURCES[kind](root, **source_options)
