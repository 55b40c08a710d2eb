"""A simulated annotator: the clicks a person would make on a vehicle whose true cuboid is known.

No human part clicks exist publicly for KITTI, so accuracy is measured by simulating them on real
ground-truth cuboids. The annotator modelled here is a person, not an oracle:

**What a person clicks, in this order of preference** (each only when visible, see below):

1. the tyres' contact points with the ground (``wheel-*``), every visible one;
2. on each end face turned to the camera: a symmetric pair of lights (``symmetry front/rear``), then the
   badge or plate on the centre line (``front-center`` / ``rear-center``);
3. the vertical cuboid edges (``edge-*``) of the visible faces (silhouette edges included);
4. a direction arrow on the ground when the view is nearly straight (within 15 degrees) from the front or
   rear (``forward`` / ``backward`` beside the vehicle) or from the side (``leftward`` / ``rightward``
   ahead of the vehicle, pointing away from the camera side), 30 to 100 % as long as the vehicle along it;
5. when the roof can be seen (camera above it): a symmetric pair on the roof and a roof antenna or light
   (``top-center``);
6. on vans and trucks, whose bodies are boxes: the visible top corners of the body (``corner-top-*``).

Clicking stops before ``max_clicks`` (12) would be exceeded; a symmetric pair or an arrow counts 2. With
``order='random'`` the person takes the same candidates in a random order instead (an annotator whose choice of
parts owes nothing to what the solver likes best).

**What a person can see.** A part is clickable when it lies on a face of the cuboid turned to the camera
(tyres also from their end of the vehicle, below the bumper; vertical edges and box corners when an
adjacent face is turned to the camera; the roof only when the camera is above it), when it projects inside
the image with a 2 px margin, and when the two clicks of a pair are at least 3 px apart. Vehicles labelled partly
occluded (KITTI 1) lose each remaining annotation with probability 0.3, largely occluded (2) with 0.6.
Arrows drawn on the ground need only be inside the image.

**Where the parts really are.** Real vehicles are not cuboids, so by default every part is placed as on a
real car, varying per vehicle: the tyres' outer faces 0 to 5 cm inside the body's sides (as measured on
real cars, see ``TYRE_INSET_MAX``), axles set in from the ends by the vehicle's overhangs; lights 3 to
20 cm behind the end faces; vertical edges (rounded body corners) 5 to 20 cm inside the cuboid's corner;
roof features up to 5 cm below the top; box corners up to 5 cm inside; an arrow on the ground drawn within
a few degrees (sigma 2 degrees) of the vehicle's axis. With ``exact_placement`` every part lies exactly
where the parts model puts it (an arrow along its axis exactly, at its drawn length), which tests the solver
rather than the model.

**Noise.** Every click gets independent Gaussian noise of ``noise_px`` pixels per coordinate.

Randomness is seeded per vehicle from ``seed`` and the vehicle's image and id, so a vehicle's clicks do
not depend on which other vehicles are simulated.

**Tracks** (:func:`select_kitti_tracks`, :func:`simulate_tracks`; ``toosicubix simulate --tracks``). On KITTI
tracking labels each selected track becomes one vehicle across the frames of a contiguous run: the longest run of
consecutive frames in which the object passes the selection's filters (classes, truncation, occlusion, depth, box
height) with one type, the first of equally long ones, cut to its first ``frames_per_track`` frames when that is
set. Every frame of the run is an image ``<sequence>_<frame:06d>`` with ``"sequence"`` and ``"frame"``, and the
object is a vehicle with ``"track": "<sequence>-<track id>"`` (its id is the track id, as without tracks) on each:

- clicks, simulated as above, only on the keyframes: the run's first frame, every ``keyframes``-th frame after it,
  and its last frame; the other frames' vehicles have no parts (a keyframe's clicks are the very clicks the frame
  gets without tracks, from the same per-vehicle stream);
- a 2D box (``box2d``) on every frame, by ``boxes``: 'person' (:mod:`toosicubix.simulate.boxes`: a box around the
  silhouette of a car-shaped solid inside the true cuboid, drawn once per track, with a person's error drawn per
  frame), 'projection' (KITTI's own box from the label line: the projected cuboid clipped to the image) or 'none';
- the ground truth of every frame, written as without tracks (a KITTI object label file per image id).

The faces each part can be seen on and the prototypes it suits (the corners: box-shaped ones) are the part
vocabulary's (:mod:`toosicubix.vocabulary`); the annotation file is written by
:func:`toosicubix.annotations.convert.vehicle_json`.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from toosicubix import vocabulary
from toosicubix.annotations.convert import vehicle_json
from toosicubix.camera import Camera
from toosicubix.errors import FormatError, InputError
from toosicubix.formats.datasets import (
    DEFAULT_IMAGE_SIZE,
    KITTI_VEHICLE_CLASSES,
    KittiObjectFolder,
    KittiTrackingFolder,
    tracking_image_id,
)
from toosicubix.formats.ground_truth import open_ground_truth
from toosicubix.formats.kitti import KittiObject, read_label_file, read_tracking_file
from toosicubix.geometry import R_cam_vehicle_from_ypr, rot_z
from toosicubix.model import GroundOverride, Part, Vehicle
from toosicubix.parts.road_users import keypoint_class
from toosicubix.parts.synthesis import PartSpec, true_parameters
from toosicubix.simulate.boxes import BodyShape, draw_body_shape, simulated_box2d

#: KITTI's vehicle types (defined once, in :mod:`toosicubix.formats.datasets`).
VEHICLE_CLASSES = KITTI_VEHICLE_CLASSES
STRAIGHT_VIEW_DEG = 15.0
#: How long a person draws a direction arrow, as a share of the dimension along it (uniform): along part of the
#: vehicle, never exactly its length (the parts model's gauge is that length; a drawn arrow of any length says the
#: same direction). Fixed by rule 22 of benchmarks/decisions.md, before any fit with it.
ARROW_LENGTH = (0.3, 1.0)
EDGE_MARGIN_PX = 2.0
MIN_PAIR_SEPARATION_PX = 3.0
OCCLUSION_DROP = {0: 0.0, 1: 0.3, 2: 0.6, 3: 0.6}
#: How far, at most, the outer faces of the tyres sit inside the body's sides (metres; uniform from 0, one
#: draw per vehicle). Measured on ApolloCar3D's car meshes (10 models: the sidewall at the ground a median
#: 2.2 cm inside the widest body point, mirrors left out, 10-90 % 0.3-4.3 cm at KITTI's 1.63 m mean width);
#: track, tyre and body widths of common cars agree. Sources: benchmarks/decisions.md, "Scale and ground cues".
TYRE_INSET_MAX = 0.05


@dataclass(frozen=True)
class AnnotatorOptions:
    """How the simulated person works.

    Attributes
    ----------
    noise_px : Gaussian click noise, pixels per coordinate
    exact_placement : every part exactly where the parts model puts it
    max_clicks : stop before exceeding this many clicked points
    seed : base of the per-vehicle random streams
    order : 'preference' (the module's list, in its order) or 'random' (the same candidates shuffled per vehicle,
        from a stream of their own, so that where each part sits and its noise are drawn as in 'preference')
    """

    noise_px: float = 1.0
    exact_placement: bool = False
    max_clicks: int = 12
    seed: int = 0
    order: str = "preference"

    def __post_init__(self) -> None:
        _ensure_range("noise_px", self.noise_px, 0.0, MAX_NOISE_PX, "pixels")
        _ensure_range("max_clicks", self.max_clicks, 1, 10_000, "clicks")
        if self.order not in CLICK_ORDERS:
            raise ValueError(f"option order: expected one of {', '.join(CLICK_ORDERS)}, got {self.order!r}")


#: The orders in which the simulated person takes the parts it can click (:class:`AnnotatorOptions`).
CLICK_ORDERS = ("preference", "random")


@dataclass(frozen=True)
class SelectionOptions:
    """Which ground-truth vehicles to simulate.

    Attributes
    ----------
    classes : KITTI types
    max_truncation : keep truncation <= this (object labels: fraction; tracking: 0, 1, 2)
    max_occlusion : keep occlusion <= this (0 visible, 1 partly, 2 largely occluded)
    min_depth, max_depth : bottom-centre depth range, metres
    min_box_height : 2D box height, pixels
    frames_per_track : tracking labels: at most this many frames per track, evenly spread
    sequences : tracking labels: the sequence names to use, or None for all
    """

    classes: tuple[str, ...] = VEHICLE_CLASSES
    max_truncation: float = 0.0
    max_occlusion: int = 1
    min_depth: float = 3.0
    max_depth: float = 60.0
    min_box_height: float = 25.0
    frames_per_track: int | None = 3
    sequences: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        _ensure_range("max_truncation", self.max_truncation, 0.0, 2.0, "(fraction, or tracking level 0-2)")
        _ensure_range("max_occlusion", self.max_occlusion, 0, 3, "(level)")
        _ensure_range("min_depth", self.min_depth, 0.0, MAX_DEPTH_M, "metres")
        _ensure_range("max_depth", self.max_depth, self.min_depth, MAX_DEPTH_M, "metres (and at least min_depth)")
        _ensure_range("min_box_height", self.min_box_height, 0.0, 1e6, "pixels")
        if self.frames_per_track is not None:
            _ensure_range("frames_per_track", self.frames_per_track, 1, 10**9, "frames")


#: Bounds of the simulation options: click noise beyond 100 px is no click on a vehicle; no KITTI label is
#: 1 km away.
MAX_NOISE_PX = 100.0
MAX_DEPTH_M = 1000.0


def _ensure_range(name: str, value: float, low: float, high: float, unit: str) -> None:
    """Raise ``ValueError`` naming the option unless ``low <= value <= high`` (so never NaN or infinite)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
        raise ValueError(f"option {name}: expected a number from {low:g} to {high:g} {unit}, got {value!r}")


@dataclass(frozen=True)
class TrackOptions:
    """How tracks are simulated (:func:`simulate_tracks`).

    Attributes
    ----------
    keyframes : clicks on a track's first frame, every ``keyframes``-th frame after it, and its last frame
    boxes : the 2D box on every frame: 'person' (a person's box around the silhouette,
        :mod:`toosicubix.simulate.boxes`), 'projection' (KITTI's own box) or 'none'
    """

    keyframes: int = 1
    boxes: str = "person"

    def __post_init__(self) -> None:
        _ensure_range("keyframes", self.keyframes, 1, 10**6, "frames")
        if self.boxes not in TRACK_BOXES:
            raise ValueError(f"option boxes: expected one of {', '.join(TRACK_BOXES)}, got {self.boxes!r}")


#: The 2D boxes a track's frames can get.
TRACK_BOXES = ("person", "projection", "none")
#: The note of a tracked vehicle left without clicks because its frame is not a keyframe.
NOT_A_KEYFRAME = "no clicks: not a keyframe"


@dataclass(frozen=True)
class GroundTruthVehicle:
    """A vehicle to annotate: its label and its image's camera (``P2``); for a track, its sequence, frame and
    track name (``<sequence>-<track id>``)."""

    image_id: str
    vehicle_id: str
    label: KittiObject
    camera: Camera
    sequence: str | None = None
    frame: int | None = None
    track: str | None = None


@dataclass(frozen=True)
class SimulatedVehicle:
    """The simulated annotation of one vehicle and the truth behind it.

    Attributes
    ----------
    parts : the clicks, noise included, in annotation order
    specs : the parts' auxiliary values (vehicle frame) before placement noise was dropped in;
        with ``exact_placement`` they are exactly the model's parameters
    p_true : (P,) the parts model's parameters at the true cuboid: the true dimensions and axles and the
        annotations' auxiliary values (it reproduces the noise-free clicks only with exact placement)
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,) in the camera frame of K; dimensions : (3,)
    wheel_x : X of the front and rear axles, metres
    spare : the parts the person could see and click but left out because of the click budget, clicked as
        the others (placement and noise; the noise from a stream of their own, so that ``parts`` do not
        depend on them): what the person would add when asked for one more
    box2d : (4,) a tracked vehicle's 2D box (:func:`simulate_tracks`), or None (then a vehicle without a track
        gets its label's box, a tracked one none)
    """

    source: GroundTruthVehicle
    parts: list[Part]
    specs: list[PartSpec]
    R_cam_vehicle: np.ndarray
    t_cam_vehicle: np.ndarray
    dimensions: np.ndarray
    wheel_x: tuple[float, float]
    p_true: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    spare: list[Part] = field(default_factory=list)
    box2d: np.ndarray | None = None

    @property
    def n_clicks(self) -> int:
        return sum(len(p.uv) for p in self.parts)


def _keep(obj: KittiObject, camera: Camera, sel: SelectionOptions) -> bool:
    if obj.type not in sel.classes or obj.truncated > sel.max_truncation or obj.occluded > sel.max_occlusion:
        return False
    depth = obj.location_rect[2] + camera.t_cam_rect[2]
    return sel.min_depth <= depth <= sel.max_depth and obj.box2d[3] - obj.box2d[1] >= sel.min_box_height


def _select_kitti_object(folder: KittiObjectFolder, sel: SelectionOptions) -> list[GroundTruthVehicle]:
    out = []
    for path in folder.label_files():
        camera = folder.camera(path.stem)
        for index, obj in enumerate(read_label_file(path)):
            if _keep(obj, camera, sel):
                out.append(GroundTruthVehicle(path.stem, str(index), obj, camera))
    return out


def _sequence_tracks(folder: KittiTrackingFolder, sel: SelectionOptions,
                     keep: Callable[[KittiObject, Camera], bool]
                     ) -> Iterator[tuple[str, Camera, dict[int, list[KittiObject]]]]:
    """Per selected sequence of a KITTI tracking folder: its name, its camera and its tracks (track id -> the objects
    ``keep`` keeps, in frame order)."""
    for path in folder.label_files():
        sequence = path.stem
        if sel.sequences is not None and sequence not in sel.sequences:
            continue
        camera = folder.camera(sequence)
        tracks: dict[int, list[KittiObject]] = {}
        for frame in sorted(frames := read_tracking_file(path)):
            for obj in frames[frame]:
                if keep(obj, camera):
                    tracks.setdefault(int(obj.track_id), []).append(obj)  # type: ignore[arg-type]
        yield sequence, camera, tracks


def _select_kitti_tracking(folder: KittiTrackingFolder, sel: SelectionOptions) -> list[GroundTruthVehicle]:
    """At most ``frames_per_track`` eligible frames per track, evenly spread over its eligible frames."""
    out = []
    for sequence, camera, tracks in _sequence_tracks(folder, sel, lambda obj, camera: _keep(obj, camera, sel)):
        for track_id in sorted(tracks):
            objs = tracks[track_id]
            if sel.frames_per_track is not None and len(objs) > sel.frames_per_track:
                picks = np.linspace(0, len(objs) - 1, sel.frames_per_track).round().astype(int)
                objs = [objs[i] for i in picks]
            for obj in objs:
                out.append(GroundTruthVehicle(tracking_image_id(sequence, int(obj.frame)), str(track_id), obj,
                                              camera))
    out.sort(key=lambda g: (g.image_id, int(g.vehicle_id)))
    return out


#: The ground truths the simulator reads, by kind: KITTI's label rows (with their cameras) are what it clicks on.
_SELECTORS = {"kitti": _select_kitti_object, "kitti-tracking": _select_kitti_tracking}


def select_vehicles(kind: str, root: str | Path, sel: SelectionOptions | None = None) -> list[GroundTruthVehicle]:
    """The vehicles of a ground-truth folder (opened by :func:`toosicubix.formats.ground_truth.open_ground_truth`,
    which must hold ``label_2/`` or ``label_02/`` and ``calib/``) that pass the selection.

    Parameters
    ----------
    kind : 'kitti' (KITTI object labels, every object of an image) or 'kitti-tracking' (at most
        ``frames_per_track`` eligible frames per track, evenly spread over its eligible frames)

    Raises
    ------
    toosicubix.errors.FormatError
        An unknown kind, a missing folder or calibration file, a malformed label line.
    """
    if kind not in _SELECTORS:
        raise FormatError(root, f"cannot simulate from {kind!r} ground truth; expected kitti or kitti-tracking")
    source = open_ground_truth(kind, root, strict=True)
    return _SELECTORS[kind](source.folder, sel or SelectionOptions())  # type: ignore[attr-defined]


def select_kitti_object(root: str | Path, sel: SelectionOptions | None = None) -> list[GroundTruthVehicle]:
    """Vehicles of a KITTI object folder (``label_2/`` and ``calib/``) that pass the selection
    (:func:`select_vehicles` of kind 'kitti')."""
    return select_vehicles("kitti", root, sel)


def select_kitti_tracking(root: str | Path, sel: SelectionOptions | None = None) -> list[GroundTruthVehicle]:
    """Vehicles of a KITTI tracking folder (``label_02/``, ``calib/``) that pass the selection
    (:func:`select_vehicles` of kind 'kitti-tracking')."""
    return select_vehicles("kitti-tracking", root, sel)


def select_kitti_tracks(root: str | Path, sel: SelectionOptions | None = None) -> list[GroundTruthVehicle]:
    """Tracks of a KITTI tracking folder (``label_02/``, ``calib/``): per track, every frame of its longest run of
    consecutive frames that pass the selection with one type (the first of equally long runs), cut to the run's
    first ``frames_per_track`` frames when that is set. Sorted by image id, then track id.

    Raises
    ------
    toosicubix.errors.FormatError
        A missing folder or calibration file, a malformed label line.
    """
    sel = sel or SelectionOptions()
    folder = open_ground_truth("kitti-tracking", root, strict=True).folder  # type: ignore[attr-defined]
    out = []

    def tracked(obj: KittiObject, camera: Camera) -> bool:  # every labelled track; runs are judged below
        return obj.track_id is not None and obj.track_id >= 0

    for sequence, camera, tracks in _sequence_tracks(folder, sel, tracked):
        for track_id in sorted(tracks):
            run = _longest_run(tracks[track_id], camera, sel)
            if sel.frames_per_track is not None:
                run = run[: sel.frames_per_track]
            for obj in run:
                frame = int(obj.frame)  # type: ignore[arg-type]
                out.append(GroundTruthVehicle(tracking_image_id(sequence, frame), str(track_id), obj, camera,
                                              sequence, frame, f"{sequence}-{track_id}"))
    out.sort(key=lambda g: (g.image_id, int(g.vehicle_id)))
    return out


def _longest_run(objs: list[KittiObject], camera: Camera, sel: SelectionOptions) -> list[KittiObject]:
    """The longest run of ``objs`` (one track, by frame) on consecutive frames, each passing the selection, all of
    one type; the first of equally long runs."""
    best: list[KittiObject] = []
    run: list[KittiObject] = []
    for obj in objs:
        if not _keep(obj, camera, sel):
            run = []
            continue
        if run and (obj.frame != run[-1].frame + 1 or obj.type != run[-1].type):  # type: ignore[operator]
            run = []
        run.append(obj)
        if len(run) > len(best):
            best = run
    return list(best)


def keyframe_indices(n_frames: int, keyframes: int) -> list[int]:
    """The positions in a run of ``n_frames`` frames that get clicks: the first, every ``keyframes``-th after it,
    and the last."""
    picks = list(range(0, n_frames, keyframes))
    if n_frames and picks[-1] != n_frames - 1:
        picks.append(n_frames - 1)
    return picks


def vehicle_rng(seed: int, image_id: str, vehicle_id: str) -> np.random.Generator:
    """The random stream of one vehicle: independent of which other vehicles are simulated."""
    digest = hashlib.sha256(f"{seed}/{image_id}/{vehicle_id}".encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:8], "little"))


# Outward normals of the cuboid's faces in the vehicle frame, and a point on each (with d = dx, dy, dz).
def _faces_visible(camera_vehicle: np.ndarray, d: np.ndarray) -> dict[str, bool]:
    x, y, z = camera_vehicle
    return {"front": x > d[0] / 2, "rear": x < -d[0] / 2, "left": y > d[1] / 2, "right": y < -d[1] / 2,
            "top": z > d[2]}


def _axis_view_angle(camera_vehicle: np.ndarray) -> tuple[float, float]:
    """Angles (degrees, in the ground plane) between the line of sight and the vehicle's X and Y axes."""
    x, y, _ = camera_vehicle
    along_x = math.degrees(math.atan2(abs(y), abs(x)))
    return along_x, 90.0 - along_x


def _candidate_specs(gt: GroundTruthVehicle, d: np.ndarray, wheel_x: tuple[float, float],
                     visible: dict[str, bool], camera_vehicle: np.ndarray, rng: np.random.Generator,
                     exact: bool) -> list[PartSpec]:
    """Every annotation the person would consider, in order of preference (:func:`_needs` says which of them
    can be seen)."""
    dx, dy, dz = d
    u = rng.uniform
    boxy = _box_shaped(gt.label.type)

    def inset(lo: float, hi: float) -> float:
        return 0.0 if exact else u(lo, hi)

    out: list[PartSpec] = []
    for axle in ("front", "rear"):
        for side in ("left", "right"):
            out.append(PartSpec("point", f"wheel-{axle}-{side}"))
    for end, sign in (("front", 1.0), ("rear", -1.0)):
        light_z = u(0.2, 0.35) if boxy else (u(0.45, 0.6) if end == "front" else u(0.55, 0.72))
        out.append(PartSpec("symmetry", end, {"Y": u(0.33, 0.44) * dy, "Z": light_z * dz,
                                              "_X": sign * (dx / 2 - inset(0.03, 0.20))}))
        badge_z = u(0.4, 0.55) if end == "front" else u(0.3, 0.5)
        out.append(PartSpec("point", f"{end}-center", {"Z": badge_z * dz, "_X": sign * (dx / 2 - inset(0.02, 0.15))}))
    for end in ("front", "rear"):
        for side in ("left", "right"):
            out.append(PartSpec("point", f"edge-{end}-{side}", {"Z": u(0.3, 0.7) * dz, "_in": inset(0.05, 0.20)}))
    along_x, along_y = _axis_view_angle(camera_vehicle)
    if along_x < STRAIGHT_VIEW_DEG:  # straight from the front or rear: an arrow beside the vehicle
        side = 1.0 if camera_vehicle[1] >= 0 else -1.0
        axis = "forward" if rng.uniform() < 0.5 else "backward"
        start = -dx / 2 if axis == "forward" else dx / 2
        out.append(PartSpec("direction", axis, {"X": start + u(-0.3, 0.3), "Y": side * (dy / 2 + u(0.2, 0.6)),
                                               "Z": 0.0, "_len": u(*ARROW_LENGTH)}))
    elif along_y < STRAIGHT_VIEW_DEG:  # straight from a side: an arrow ahead of the vehicle, away from us
        side = 1.0 if camera_vehicle[1] >= 0 else -1.0
        axis = "rightward" if side > 0 else "leftward"
        out.append(PartSpec("direction", axis, {"X": dx / 2 + u(0.3, 0.8), "Y": side * dy / 2, "Z": 0.0,
                                               "_len": u(*ARROW_LENGTH)}))
    out.append(PartSpec("symmetry", "roof", {"X": u(-0.25, 0.05) * dx, "Y": u(0.3, 0.4) * dy,
                                            "_Z": dz - inset(0.0, 0.05)}))
    out.append(PartSpec("point", "top-center", {"X": u(-0.3, 0.1) * dx, "_Z": dz - inset(0.0, 0.05)}))
    for end in ("front", "rear"):
        for side in ("left", "right"):
            corner = vocabulary.entry("point", f"corner-top-{end}-{side}")
            if vocabulary.suits(corner, (gt.label.type,)):
                out.append(PartSpec("point", corner.name, {"_in": inset(0.0, 0.05)}))
    return out


def _box_shaped(prototype: str) -> bool:
    """A body that is a box (the vocabulary's ``box-shaped`` prototype group): lights set low, long rear
    overhangs, and corners one can click."""
    return prototype in vocabulary.PROTOTYPE_GROUPS["box-shaped"]


def _on_ground(spec: PartSpec) -> bool:
    """Drawn anywhere, the ground included (an arrow): the vocabulary gives it no faces."""
    return vocabulary.entry(spec.kind, spec.name).faces is None


def _needs(spec: PartSpec, visible: dict[str, bool]) -> bool:
    """Whether the person can see the part: any of the faces the vocabulary puts it on is visible; always
    for one drawn on the ground."""
    faces = vocabulary.entry(spec.kind, spec.name).faces
    return faces is None or any(visible[f] for f in faces)


def _real_points(spec: PartSpec, d: np.ndarray, wheel_x: tuple[float, float], tyre_inset: float,
                 arrow_yaw: float) -> np.ndarray:
    """Where the part really is on the vehicle (vehicle frame), (k, 3): the model's point moved by the
    placement offsets recorded in the spec's private ``_`` keys."""
    dx, dy, dz = d
    a = spec.aux
    e = vocabulary.entry(spec.kind, spec.name)
    sx = {"front": 1.0, "rear": -1.0}
    sy = {"left": 1.0, "right": -1.0}
    if spec.kind == "point":
        shape, end, side = e.get("shape"), e.get("end"), e.get("side")
        if shape == "wheel":
            x = wheel_x[0] if e.get("axle") == "front" else wheel_x[1]
            return np.array([[x, sy[side] * (dy / 2 - tyre_inset), 0.0]])
        if shape == "end-center":
            return np.array([[a["_X"], 0.0, a["Z"]]])
        if shape == "top-center":
            return np.array([[a["X"], 0.0, a["_Z"]]])
        if shape == "edge":
            return np.array([[sx[end] * (dx / 2 - a["_in"]), sy[side] * (dy / 2 - a["_in"]), a["Z"]]])
        # a top corner (the person clicks no other)
        return np.array([[sx[end] * (dx / 2 - a["_in"]), sy[side] * (dy / 2 - a["_in"]), dz - a["_in"]]])
    if spec.kind == "symmetry":
        if e.get("end") is None:  # on the roof
            return np.array([[a["X"], a["Y"], a["_Z"]], [a["X"], -a["Y"], a["_Z"]]])
        return np.array([[a["_X"], a["Y"], a["Z"]], [a["_X"], -a["Y"], a["Z"]]])
    tail = np.array([a["X"], a["Y"], a["Z"]])
    axis = ("dx", "dy", "dz").index(e.get("axis"))
    step = np.zeros(3)
    step[axis] = float(e.get("sign")) * d[axis] * a.get("_len", 1.0)
    return np.array([tail, tail + rot_z(arrow_yaw) @ step])


def _model_spec(spec: PartSpec, d: np.ndarray, camera_vehicle: np.ndarray) -> PartSpec:
    """The spec with only the parts model's auxiliary values (private placement keys dropped). An arrow drawn
    ``_len`` times its axis's dimension long is the model's arrow (as long as the dimension) moved along its rays
    from the camera centre ``camera_vehicle`` (3,) by the factor ``1 / _len``: the same clicks, the model's gauge."""
    aux = {k: v for k, v in spec.aux.items() if not k.startswith("_")}
    if spec.kind == "direction" and "_len" in spec.aux:
        tail = np.array([aux["X"], aux["Y"], aux["Z"]])
        moved = camera_vehicle + (tail - camera_vehicle) / spec.aux["_len"]
        aux.update(X=float(moved[0]), Y=float(moved[1]), Z=float(moved[2]))
    return PartSpec(spec.kind, spec.name, aux)


def simulate_vehicle(gt: GroundTruthVehicle, options: AnnotatorOptions) -> SimulatedVehicle:
    """The clicks of the simulated person on one ground-truth vehicle (see the module's description); on a road
    user with a keypoint vocabulary of its own (a Pedestrian, a Cyclist), the keypoints of
    :func:`toosicubix.simulate.road_users.simulate_road_user`."""
    if keypoint_class(gt.label.type) is not None:
        from toosicubix.simulate.road_users import simulate_road_user  # it builds on this module

        return simulate_road_user(gt, options)
    rng = vehicle_rng(options.seed, gt.image_id, gt.vehicle_id)
    obj, camera = gt.label, gt.camera
    d = np.asarray(obj.dimensions, dtype=float)
    R = R_cam_vehicle_from_ypr(obj.rotation_y)
    t = obj.t_cam_vehicle(camera.t_cam_rect)
    boxy = _box_shaped(obj.type)
    front_overhang = rng.uniform(0.10, 0.15) if obj.type == "Truck" else rng.uniform(0.17, 0.24)
    rear_overhang = rng.uniform(0.20, 0.35) if boxy else rng.uniform(0.18, 0.26)
    wheel_x = (d[0] * (0.5 - front_overhang), -d[0] * (0.5 - rear_overhang))
    tyre_inset = 0.0 if options.exact_placement else rng.uniform(0.0, TYRE_INSET_MAX)
    camera_vehicle = R.T @ (-t)
    visible = _faces_visible(camera_vehicle, d)
    size = camera.image_size or DEFAULT_IMAGE_SIZE
    drop = OCCLUSION_DROP.get(obj.occluded, 0.6)

    parts: list[Part] = []
    specs: list[PartSpec] = []
    notes: list[str] = []
    spare: list[Part] = []
    spare_rng = vehicle_rng(options.seed, gt.image_id, gt.vehicle_id + "/spare")
    clicks = 0
    candidates = _candidate_specs(gt, d, wheel_x, visible, camera_vehicle, rng, options.exact_placement)
    if options.order == "random":
        order_rng = vehicle_rng(options.seed, gt.image_id, gt.vehicle_id + "/order")
        candidates = [candidates[i] for i in order_rng.permutation(len(candidates))]
    for spec in candidates:
        if not _needs(spec, visible):
            continue
        arrow_yaw = 0.0 if options.exact_placement else math.radians(rng.normal(0.0, 2.0))
        points_vehicle = _real_points(spec, d, wheel_x, tyre_inset, arrow_yaw)
        points_cam = points_vehicle @ R.T + t
        if np.any(points_cam[:, 2] <= 0.1):
            continue
        uv = camera.project(points_cam)
        inside = np.all((uv >= EDGE_MARGIN_PX) & (uv <= np.array(size) - 1 - EDGE_MARGIN_PX))
        if not inside:
            continue
        if len(uv) == 2 and np.linalg.norm(uv[1] - uv[0]) < MIN_PAIR_SEPARATION_PX:
            continue
        if not _on_ground(spec) and drop > 0 and rng.uniform() < drop:
            notes.append(f"{spec.kind} {spec.name}: lost to occlusion")
            continue
        if clicks + len(uv) > options.max_clicks:
            extra = uv + spare_rng.normal(0.0, options.noise_px, uv.shape) if options.noise_px > 0 else uv
            if len(extra) == 1 or np.linalg.norm(extra[1] - extra[0]) >= MIN_PAIR_SEPARATION_PX:
                spare.append(Part(spec.kind, spec.name, extra, f"spare[{len(spare)}]"))
            continue
        noisy = uv + rng.normal(0.0, options.noise_px, uv.shape) if options.noise_px > 0 else uv
        if len(noisy) == 2 and np.linalg.norm(noisy[1] - noisy[0]) < MIN_PAIR_SEPARATION_PX:
            continue  # the person sees the two clicks land on one spot and leaves the pair out
        k = len(specs)
        parts.append(Part(spec.kind, spec.name, noisy, f"simulated[{k}]"))
        specs.append(_model_spec(spec, d, camera_vehicle))
        clicks += len(uv)
    p_true = true_parameters(specs, d, wheel_x)[1] if specs else np.zeros(3)
    return SimulatedVehicle(gt, parts, specs, R, t, d, wheel_x, p_true, notes, spare)


def annotation_document(simulated: list[SimulatedVehicle],
                        ground: GroundOverride | None = None) -> dict[str, Any]:
    """The annotation file (v1) of simulated vehicles, one image entry per image id (input order). A vehicle
    without a track gets its label's 2D box; a tracked one its ``box2d`` (if any) and its track, its image the
    sequence and frame.

    Parameters
    ----------
    ground : the ground-block fields given to every image (e.g. ``toosicubix.model.KITTI_GROUND``), or None
    """
    images: dict[str, dict[str, Any]] = {}
    for sv in simulated:
        gt = sv.source
        image = images.get(gt.image_id)
        if image is None:
            P2 = np.hstack([gt.camera.K, (gt.camera.K @ gt.camera.t_cam_rect)[:, None]])
            frame = {"sequence": gt.sequence, "frame": gt.frame} if gt.sequence is not None else {}
            image = images[gt.image_id] = {
                "id": gt.image_id, **frame, "size": list(gt.camera.image_size or DEFAULT_IMAGE_SIZE),
                "camera": {"P": P2.tolist()}, **({"ground": ground.to_json()} if ground else {}), "vehicles": [],
            }
        if gt.track is None:
            box2d = np.array([round(float(v), 2) for v in gt.label.box2d])
        else:
            box2d = sv.box2d
        image["vehicles"].append(vehicle_json(Vehicle(gt.vehicle_id, gt.label.type, box2d, tuple(sv.parts), "",
                                                      track=gt.track)))
    return {"toosicubix": 1, "images": list(images.values())}


def simulate(vehicles: list[GroundTruthVehicle], options: AnnotatorOptions) -> list[SimulatedVehicle]:
    """Simulate the annotator on every vehicle."""
    return [simulate_vehicle(gt, options) for gt in vehicles]


def track_body_shape(seed: int, track: str, prototype: str) -> BodyShape:
    """The solid a track's person's boxes are drawn around (:func:`toosicubix.simulate.boxes.draw_body_shape`), from
    the stream ``seed``, ``track/<track>``, ``body``: one per track, whatever else is simulated."""
    return draw_body_shape(prototype, vehicle_rng(seed, f"track/{track}", "body"))


def simulate_tracks(vehicles: list[GroundTruthVehicle], options: AnnotatorOptions,
                    tracks: TrackOptions | None = None) -> list[SimulatedVehicle]:
    """Simulate the annotator on tracked vehicles (:func:`select_kitti_tracks`), in input order: clicks on each
    track's keyframes (:func:`keyframe_indices` of its frames in frame order), none on its other frames, and on
    every frame the 2D box ``tracks.boxes`` asks for (see the module's description).

    The person's solid is drawn once per track (stream ``seed``, ``track/<track>``, ``body``), the person's error
    per frame (stream ``seed``, image id, ``<vehicle id>/box``); the clicks' streams are untouched by both.

    Raises
    ------
    ValueError
        A vehicle without a track.
    """
    tracks = tracks or TrackOptions()
    frames: dict[str, list[int]] = {}
    for i, gt in enumerate(vehicles):
        if gt.track is None or gt.frame is None:
            raise ValueError(f"vehicle {gt.vehicle_id} of image {gt.image_id}: expected a tracked vehicle")
        frames.setdefault(gt.track, []).append(i)
    clicked: set[int] = set()
    for indices in frames.values():
        ordered = sorted(indices, key=lambda i: vehicles[i].frame)  # type: ignore[arg-type, return-value]
        clicked.update(ordered[k] for k in keyframe_indices(len(ordered), tracks.keyframes))
    shapes = {track: track_body_shape(options.seed, track, vehicles[indices[0]].label.type)
              for track, indices in frames.items()}
    out = []
    for i, gt in enumerate(vehicles):
        sv = simulate_vehicle(gt, options)
        if i not in clicked:
            sv = replace(sv, parts=[], specs=[], spare=[], p_true=None, notes=[NOT_A_KEYFRAME])
        box = None
        if tracks.boxes == "projection":
            box = np.array([round(float(v), 2) for v in gt.label.box2d])
        elif tracks.boxes == "person":
            box = simulated_box2d(sv.R_cam_vehicle, sv.t_cam_vehicle, sv.dimensions, gt.label.type, gt.camera,
                                  vehicle_rng(options.seed, gt.image_id, gt.vehicle_id + "/box"),
                                  shape=shapes[gt.track])  # type: ignore[index]
        out.append(replace(sv, box2d=box))
    return out


def _calib_text(camera: Camera) -> str:
    P2 = np.hstack([camera.K, (camera.K @ camera.t_cam_rect)[:, None]])
    P0 = np.hstack([camera.K, np.zeros((3, 1))])
    rows = [f"P{i}: " + " ".join(f"{v:.12e}" for v in P.ravel()) for i, P in enumerate((P0, P0, P2, P2))]
    identity = np.hstack([np.eye(3), np.zeros((3, 1))])
    rows.append("R0_rect: " + " ".join(f"{v:.12e}" for v in np.eye(3).ravel()))
    rows += [f"{key}: " + " ".join(f"{v:.12e}" for v in identity.ravel())
             for key in ("Tr_velo_to_cam", "Tr_imu_to_velo")]
    return "\n".join(rows) + "\n"


#: The file that makes a ground-truth folder one that ``simulate`` wrote (and may write again).
SIMULATION_MARKER = ".toosicubix-simulated.json"


class SimulationOutputError(InputError):
    """``simulate`` was asked to write where it must not: into a dataset or over its own annotation file."""

    def __init__(self, message: str):
        super().__init__(None, [(None, message)])


def check_simulation_targets(annotations: str | Path, gt_dir: str | Path) -> None:
    """Refuse targets that would destroy data; write nothing.

    Raises
    ------
    SimulationOutputError
        ``gt_dir`` is or contains the annotation file, ``gt_dir`` is an existing folder with files that
        ``simulate`` did not write (a dataset: its ground truth would be overwritten), or the annotation
        file is a folder.
    """
    annotations, gt_dir = Path(annotations), Path(gt_dir)
    ann, gt = annotations.resolve(), gt_dir.resolve()
    if ann == gt or ann.is_relative_to(gt):
        raise SimulationOutputError(
            f"--gt-out {gt_dir} is or contains the annotation file {annotations}: they must be apart (one would "
            f"overwrite the other); give them separate places")
    if annotations.is_dir():
        raise SimulationOutputError(f"{annotations}: is a folder; the annotation file must be a file")
    if gt_dir.exists() and not gt_dir.is_dir():
        raise SimulationOutputError(f"--gt-out {gt_dir}: exists and is not a folder")
    if gt_dir.is_dir() and any(gt_dir.iterdir()) and not (gt_dir / SIMULATION_MARKER).is_file():
        entries = sorted(e.name for e in gt_dir.iterdir())
        raise SimulationOutputError(
            f"--gt-out {gt_dir}: an existing folder that toosicubix simulate did not write ({', '.join(entries[:5])}"
            f"{' ...' if len(entries) > 5 else ''}; no {SIMULATION_MARKER}); its files, perhaps a dataset's "
            f"ground truth, are never overwritten. Choose another folder.")


def write_simulation(simulated: list[SimulatedVehicle], annotations: str | Path, gt_dir: str | Path,
                     ground: GroundOverride | None = None) -> None:
    """Write the annotation file and, in ``gt_dir``, the simulated vehicles' ground truth as a KITTI object
    folder (``label_2/<image id>.txt``, ``calib/<image id>.txt`` with ``P2`` in every ``P`` line) that
    ``toosicubix eval --kitti`` reads. Files are written atomically; the marker :data:`SIMULATION_MARKER`
    first, and label and calib files of an earlier simulation into the same folder that this one did not
    write are removed.

    Raises
    ------
    SimulationOutputError
        See :func:`check_simulation_targets`; nothing is written then.
    """
    from toosicubix.formats.atomic import atomic_write_text
    from toosicubix.formats.kitti import format_label_line
    from toosicubix.formats.results import dumps

    gt_dir = Path(gt_dir)
    _check_output_names(simulated, Path(annotations), gt_dir)  # first: a name too long fails every call
    check_simulation_targets(annotations, gt_dir)
    try:
        gt_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_text(gt_dir / SIMULATION_MARKER, json.dumps(
            {"toosicubix_simulated": 1, "annotations": str(annotations)}, indent=1) + "\n")
        (gt_dir / "label_2").mkdir(exist_ok=True)
        (gt_dir / "calib").mkdir(exist_ok=True)
        by_image: dict[str, list[SimulatedVehicle]] = {}
        for sv in simulated:
            by_image.setdefault(sv.source.image_id, []).append(sv)
        for image_id, vehicles in by_image.items():
            lines = [format_label_line(_without_tracking(sv.source.label)) for sv in vehicles]
            atomic_write_text(gt_dir / "label_2" / f"{image_id}.txt", "".join(f"{ln}\n" for ln in lines))
            atomic_write_text(gt_dir / "calib" / f"{image_id}.txt", _calib_text(vehicles[0].source.camera))
        written = {f"{image_id}.txt" for image_id in by_image}
        for folder in ("label_2", "calib"):
            for stale in (gt_dir / folder).glob("*.txt"):
                if stale.name not in written:
                    stale.unlink()
        atomic_write_text(Path(annotations), dumps(annotation_document(simulated, ground)))
    except OSError as exc:
        raise FormatError(exc.filename or gt_dir, f"cannot write: {exc.strerror or exc}") from None


def _check_output_names(simulated: list[SimulatedVehicle], annotations: Path, gt_dir: Path) -> None:
    """Refuse, before anything is written, file names that no file system takes (where the two outputs may go
    is :func:`check_simulation_targets`'s).

    Raises
    ------
    FormatError
        Naming the path: a file name is longer than ``MAX_NAME_BYTES``.
    """
    names = [(annotations, annotations.name), (gt_dir, gt_dir.name)]
    if simulated:
        names.append((gt_dir / "label_2", max((f"{sv.source.image_id}.txt" for sv in simulated), key=len)))
    for where, name in names:
        if len(name.encode("utf-8")) > MAX_NAME_BYTES:
            raise FormatError(where, f"a file name of {len(name.encode('utf-8'))} bytes; at most {MAX_NAME_BYTES} "
                                     f"(file systems allow 255, and a temporary name adds 14)")


#: The longest file name written (255 bytes, the common limit, less the temporary file's 14 more).
MAX_NAME_BYTES = 240


def _without_tracking(obj: KittiObject) -> KittiObject:
    return replace(obj, frame=None, track_id=None, score=None)
