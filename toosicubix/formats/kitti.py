"""KITTI object and tracking labels, and calibration files.

Label line (object benchmark)::

    type truncated occluded alpha x1 y1 x2 y2 h w l x y z ry [score]

Tracking labels put ``frame track_id`` in front. ``(h, w, l)`` are ``(dz, dy, dx)``; ``(x, y, z)`` is the
bottom centre in the rectified camera-0 frame (``rect``); ``ry`` turns about camera y, so
``R_cam_vehicle = R_y(ry) @ R_LEVEL_VEHICLE``. A KITTI file cannot hold pitch or roll: writing one
drops them (results.json keeps the full rotation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from toosicubix.annotations.schema import check_projection
from toosicubix.camera import Camera
from toosicubix.errors import FormatError
from toosicubix.geometry import R_cam_vehicle_from_ypr, wrap_angle, ypr_from_R_cam_vehicle

#: KITTI's code for "occlusion unknown", written for fitted objects.
OCCLUSION_UNKNOWN = 3
#: Bounds a label line must keep, checked before anything is allocated for it: no road vehicle is larger
#: than ``MAX_SIZE_M`` (KITTI's largest is a 16.8 m tram) and none is labelled farther than ``MAX_DISTANCE_M``
#: (KITTI's farthest is under 100 m); boxes lie within ``MAX_PIXEL`` pixels of the image; tracking frames run
#: from 0 to ``MAX_FRAME`` (KITTI's longest sequence has 1,106; 10^5 frames is nearly 3 hours at 10 Hz).
MAX_SIZE_M = 100.0
MAX_DISTANCE_M = 10_000.0
MAX_PIXEL = 1e6
MAX_FRAME = 100_000


@dataclass(frozen=True)
class KittiObject:
    """One label line.

    Attributes
    ----------
    type : str, e.g. 'Car'
    truncated : float in [0, 1] (tracking labels: 0, 1, 2)
    occluded : int, 0 visible, 1 partly, 2 largely occluded, 3 unknown
    alpha : float, observation angle, radians
    box2d : (4,) (x1, y1, x2, y2) pixels
    dimensions : (3,) ``(dx, dy, dz)`` = (l, w, h), metres
    location_rect : (3,) bottom centre in camera-0 coordinates, metres
    rotation_y : float, radians
    score : float or None
    frame, track_id : int or None, tracking labels only
    line : int or None, where it was read (1-based)
    """

    type: str
    truncated: float
    occluded: int
    alpha: float
    box2d: np.ndarray
    dimensions: np.ndarray
    location_rect: np.ndarray
    rotation_y: float
    score: float | None = None
    frame: int | None = None
    track_id: int | None = None
    line: int | None = field(default=None, compare=False)

    @property
    def R_cam_vehicle(self) -> np.ndarray:
        """Rotation implied by ``rotation_y`` (zero pitch and roll), (3, 3)."""
        return R_cam_vehicle_from_ypr(self.rotation_y)

    def t_cam_vehicle(self, t_cam_rect: np.ndarray) -> np.ndarray:
        """Bottom centre in the frame of the camera whose offset from camera 0 is ``t_cam_rect``, (3,)."""
        return self.location_rect + np.asarray(t_cam_rect, dtype=float)


def object_from_pose(
    type_: str,
    R_cam_vehicle: np.ndarray,
    t_cam_vehicle: np.ndarray,
    dimensions: np.ndarray,
    camera: Camera,
    box2d: np.ndarray,
    truncated: float = 0.0,
    occluded: int = OCCLUSION_UNKNOWN,
    score: float | None = 1.0,
    heading: str = "directed",
) -> KittiObject:
    """The KITTI label of a fitted cuboid; pitch and roll are dropped.

    Parameters
    ----------
    R_cam_vehicle : (3, 3), t_cam_vehicle : (3,)
        Pose in the frame where ``camera.K`` applies (camera 2 for ``P2``).
    dimensions : (3,) ``(dx, dy, dz)``
    camera : its ``t_cam_rect`` moves the location to camera 0.
    heading : 'none' for an object without a yaw (a traffic cone): ``rotation_y`` and ``alpha`` are written as
        :data:`ANGLE_NOT_GIVEN`, KITTI's value for an angle not given; else ('directed', 'axial') the fitted yaw
    """
    location_rect = np.asarray(t_cam_vehicle, dtype=float) - camera.t_cam_rect
    ry, _, _ = ypr_from_R_cam_vehicle(np.asarray(R_cam_vehicle, dtype=float))
    ry = float(wrap_angle(ry))
    alpha = float(wrap_angle(ry - math.atan2(location_rect[0], location_rect[2])))
    if heading == "none":
        ry = alpha = ANGLE_NOT_GIVEN
    return KittiObject(
        type=type_, truncated=float(truncated), occluded=int(occluded), alpha=alpha,
        box2d=np.asarray(box2d, dtype=float), dimensions=np.asarray(dimensions, dtype=float),
        location_rect=location_rect, rotation_y=ry, score=score,
    )


#: KITTI's value for an angle not given (its DontCare rows carry it as alpha and rotation_y): what a label of an
#: object without a yaw (a traffic cone) is written with.
ANGLE_NOT_GIVEN = -10.0


def format_label_line(obj: KittiObject) -> str:
    """One label line: 15 fields, 16 with a score; single spaces; no frame or track id.

    Raises
    ------
    ValueError
        A NaN or infinity among the numbers (a label file never holds one).
    """
    numbers = np.concatenate([[obj.truncated, obj.alpha, obj.rotation_y, 0.0 if obj.score is None else obj.score],
                              obj.box2d, obj.dimensions, obj.location_rect]).astype(float)
    if not np.all(np.isfinite(numbers)):
        raise ValueError(f"refusing to write a KITTI label with a NaN or infinity: {obj.type} box {obj.box2d.tolist()} "
                         f"dimensions {obj.dimensions.tolist()} location {obj.location_rect.tolist()} "
                         f"ry {obj.rotation_y} alpha {obj.alpha} score {obj.score}")
    dx, dy, dz = obj.dimensions
    fields = [
        obj.type, f"{obj.truncated:.2f}", f"{obj.occluded:d}", f"{obj.alpha:.6f}",
        *(f"{v:.2f}" for v in obj.box2d),
        f"{dz:.4f}", f"{dy:.4f}", f"{dx:.4f}",
        *(f"{v:.4f}" for v in obj.location_rect),
        f"{obj.rotation_y:.6f}",
    ]
    if obj.score is not None:
        fields.append(f"{obj.score:.4f}")
    return " ".join(fields)


def format_tracking_line(frame: int, track_id: int, obj: KittiObject) -> str:
    """One KITTI tracking label line: the frame, the track id, then :func:`format_label_line`'s fields."""
    return tracking_line(frame, track_id, format_label_line(obj))


def tracking_line(frame: int, track_id: int, label_line: str) -> str:
    """The KITTI tracking label line of an object whose label line (:func:`format_label_line`) is ``label_line``."""
    return f"{int(frame)} {int(track_id)} {label_line}"


def parse_label_line(text: str, file: str | Path = "<label>", line: int | None = None,
                     tracking: bool = False) -> KittiObject:
    """Parse one object (15 or 16 fields) or tracking (17 or 18 fields) label line.

    Raises
    ------
    FormatError
        Wrong field count, a number that does not parse or is not finite, non-positive dimensions.
    """
    tokens = text.split()
    offset = 2 if tracking else 0
    if len(tokens) not in (15 + offset, 16 + offset):
        kind = "tracking" if tracking else "object"
        raise FormatError(file, f"expected {15 + offset} or {16 + offset} fields in a KITTI {kind} label, "
                                f"got {len(tokens)}: {text.strip()[:80]!r}", line)
    try:
        frame = int(tokens[0]) if tracking else None
        track_id = int(tokens[1]) if tracking else None
        values = [float(v) for v in tokens[offset + 1:]]
    except ValueError as exc:
        raise FormatError(file, f"expected numbers after the type: {exc}", line) from None
    if not all(math.isfinite(v) for v in values):
        raise FormatError(file, f"expected finite numbers, got {text.strip()[:80]!r}", line)
    if frame is not None and not 0 <= frame <= MAX_FRAME:
        raise FormatError(file, f"expected a frame number from 0 to {MAX_FRAME}, got {frame}", line)
    truncated, occluded, alpha = values[0], values[1], values[2]
    h, w, l_ = values[7:10]
    obj_type = tokens[offset]
    if obj_type != "DontCare" and min(h, w, l_) <= 0.0:
        raise FormatError(file, f"expected positive h, w, l, got {h}, {w}, {l_}", line)
    if max(abs(h), abs(w), abs(l_)) > (MAX_SIZE_M if obj_type != "DontCare" else MAX_DISTANCE_M):  # DontCare: -1000
        raise FormatError(file, f"expected h, w, l of at most {MAX_SIZE_M:g} m (no road vehicle is larger), "
                                f"got {h:g}, {w:g}, {l_:g}", line)
    if max(abs(v) for v in values[10:13]) > MAX_DISTANCE_M:
        raise FormatError(file, f"expected a location within {MAX_DISTANCE_M:g} m of the camera, got "
                                f"{values[10]:g}, {values[11]:g}, {values[12]:g}", line)
    if max(abs(v) for v in values[3:7]) > MAX_PIXEL or max(abs(alpha), abs(values[13])) > 100.0:
        raise FormatError(file, f"expected a 2D box within +-{MAX_PIXEL:g} pixels and angles in radians, got "
                                f"{text.strip()[:80]!r}", line)
    return KittiObject(
        type=obj_type, truncated=truncated, occluded=int(occluded), alpha=alpha,
        box2d=np.array(values[3:7]), dimensions=np.array([l_, w, h]), location_rect=np.array(values[10:13]),
        rotation_y=values[13], score=values[14] if len(values) == 15 else None,
        frame=frame, track_id=track_id, line=line,
    )


def read_label_file(path: str | Path) -> list[KittiObject]:
    """All objects of a KITTI object label file (blank lines skipped)."""
    path = Path(path)
    text = read_text(path)
    return [parse_label_line(ln, path, i) for i, ln in enumerate(text.splitlines(), 1) if ln.strip()]


def read_tracking_file(path: str | Path) -> dict[int, list[KittiObject]]:
    """A KITTI tracking label file, objects grouped by frame number."""
    path = Path(path)
    frames: dict[int, list[KittiObject]] = {}
    for i, ln in enumerate(read_text(path).splitlines(), 1):
        if ln.strip():
            obj = parse_label_line(ln, path, i, tracking=True)
            frames.setdefault(int(obj.frame), []).append(obj)  # type: ignore[arg-type]
    return frames


@dataclass(frozen=True)
class KittiCalib:
    """A KITTI calibration file: ``P0`` ... ``P3`` (3, 4), ``R0_rect`` (3, 3), and the rest as read."""

    P: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
    R0_rect: np.ndarray
    extra: dict[str, np.ndarray]

    def camera(self, index: int = 2, image_size: tuple[int, int] | None = None) -> Camera:
        """The camera of ``P<index>``."""
        return Camera.from_P(self.P[index], image_size=image_size)


_CALIB_ALIASES = {"R_rect": "R0_rect", "Tr_velo_cam": "Tr_velo_to_cam", "Tr_imu_velo": "Tr_imu_to_velo"}


def read_calib(path: str | Path) -> KittiCalib:
    """Read an object-style (``P2:``, ``R0_rect:``) or tracking-style (``R_rect``) calibration file."""
    path = Path(path)
    entries: dict[str, np.ndarray] = {}
    lines: dict[str, int] = {}
    for i, ln in enumerate(read_text(path).splitlines(), 1):
        if not ln.strip():
            continue
        key, sep, rest = ln.partition(":")
        if not sep:
            key, _, rest = ln.strip().partition(" ")
        key = _CALIB_ALIASES.get(key.strip(), key.strip())
        try:
            entries[key] = np.array([float(v) for v in rest.split()])
        except ValueError:
            raise FormatError(path, f"expected numbers after {key!r}", i) from None
        if not np.all(np.isfinite(entries[key])):
            raise FormatError(path, f"expected finite numbers after {key!r}, got {rest.strip()[:80]!r}", i)
        lines[key] = i
    P = []
    for k in range(4):
        value = entries.get(f"P{k}")
        if value is None or value.size != 12:
            raise FormatError(path, f"expected a line 'P{k}:' with 12 numbers")
        try:
            check_projection(value.reshape(3, 4))
        except ValueError as exc:
            raise FormatError(path, f"P{k} is not a camera: {exc}", lines[f"P{k}"]) from None
        P.append(value.reshape(3, 4))
    R0 = entries.get("R0_rect", np.eye(3).ravel())
    if R0.size != 9:
        raise FormatError(path, f"expected 9 numbers for R0_rect, got {R0.size}")
    extra = {k: v for k, v in entries.items() if k not in {"P0", "P1", "P2", "P3", "R0_rect"}}
    return KittiCalib(P=tuple(P), R0_rect=R0.reshape(3, 3), extra=extra)  # type: ignore[arg-type]


def read_text(path: Path) -> str:
    """The file's text; a UTF-8 byte order mark is dropped.

    Raises
    ------
    FormatError
        Unreadable, or not UTF-8 (naming the line and byte of the first bad byte).
    """
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise FormatError(path, f"cannot read: {exc.strerror or exc}") from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise FormatError(path, f"not UTF-8 text: {exc.reason} at byte {exc.start}", line) from None


__all__ = [
    "OCCLUSION_UNKNOWN", "KittiCalib", "KittiObject", "format_label_line", "object_from_pose",
    "parse_label_line", "read_calib", "read_label_file", "read_text", "read_tracking_file",
]
