"""Plain numpy dataclasses for annotated images and vehicles; built once from the parsed file.

The solver and the formats work on these and never see pydantic.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from toosicubix.annotations import schema as schemas
from toosicubix.camera import Camera
from toosicubix.geometry import rot_x, rot_z


@dataclass(frozen=True)
class Part:
    """One annotation on a vehicle.

    Attributes
    ----------
    kind : 'point', 'symmetry', 'direction' or 'length'
    name : the point's part name ('wheel-front-left', ...), the symmetry face ('front', 'rear', 'roof'),
        the direction axis ('forward', ...) or the length feature ('plate-rear', ...)
    uv : (k, 2) pixels as clicked: one row for a point, (left, right) for a symmetry,
        (tail, head) for a direction, (a, b) for a length
    json_path : where it stands in the annotation file
    known : ``(metres, sigma)`` of a length annotation's feature, else None
    """

    kind: str
    name: str
    uv: np.ndarray
    json_path: str
    known: tuple[float, float] | None = None

    @property
    def click_labels(self) -> tuple[str, ...]:
        """A label per clicked pixel, e.g. ('symmetry-rear/left', 'symmetry-rear/right')."""
        if self.kind == "point":
            return (self.name,)
        if self.kind == "symmetry":
            return (f"symmetry-{self.name}/left", f"symmetry-{self.name}/right")
        if self.kind == "length":
            return (f"length-{self.name}/a", f"length-{self.name}/b")
        return (f"direction-{self.name}/tail", f"direction-{self.name}/head")


@dataclass(frozen=True)
class Vehicle:
    """One annotated vehicle.

    Attributes
    ----------
    box2d : (4,) annotated (x1, y1, x2, y2), or None
    parts : its annotations, in file order
    known_dimensions : ``{"dx": (metres, sigma), ...}`` for the dimensions known from elsewhere
    """

    id: str
    prototype: str
    box2d: np.ndarray | None
    parts: tuple[Part, ...]
    json_path: str
    known_dimensions: dict[str, tuple[float, float]] = field(default_factory=dict)


@dataclass(frozen=True)
class GroundPlane:
    """The road in camera coordinates: ``{X : normal . X = -camera_height}``.

    Attributes
    ----------
    normal : (3,) unit normal pointing up from the road (toward the camera side)
    normal_sigma : its uncertainty, radians
    camera_height : metres above the road, or None when unknown
    camera_height_sigma : metres
    upright_sigma : how far vehicles lean from the normal (their pitch and roll on the road), radians
    """

    normal: np.ndarray
    normal_sigma: float
    camera_height: float | None
    camera_height_sigma: float
    upright_sigma: float


@dataclass(frozen=True)
class Image:
    """One annotated image and its camera."""

    id: str
    file: str | None
    camera: Camera
    vehicles: tuple[Vehicle, ...]
    json_path: str
    ground: GroundPlane | None = None
    ground_block: dict | None = None  # the ground block as the file gave it (schema field names)


def _part(p: schemas.PointAnnotation | schemas.SymmetryAnnotation | schemas.DirectionAnnotation
          | schemas.LengthAnnotation, json_path: str) -> Part:
    if isinstance(p, schemas.PointAnnotation):
        return Part("point", p.part, np.array([p.xy], dtype=float), json_path)
    if isinstance(p, schemas.SymmetryAnnotation):
        return Part("symmetry", p.face, np.array([p.left, p.right], dtype=float), json_path)
    if isinstance(p, schemas.LengthAnnotation):
        return Part("length", p.feature, np.array([p.a, p.b], dtype=float), json_path, (p.metres, p.sigma))
    return Part("direction", p.axis, np.array([p.tail, p.head], dtype=float), json_path)


#: The road normal of a level camera (camera y points down).
LEVEL_NORMAL = np.array([0.0, -1.0, 0.0])

#: KITTI's ground, as the annotation block ``{"camera_height": 1.65, "camera_height_sigma": 0.1,
#: "normal": [0, -1, 0], "normal_sigma_deg": 1.0, "upright_sigma_deg": 2.0}``. Measured on KITTI tracking
#: ground truth (sequences 0000-0009): the bottom centres of vehicles within 10 m lie 1.68 m below the
#: camera (standard deviation 0.12 m); farther away the road's slope spreads them by about 0.75 degrees
#: times the distance, which the normal's uncertainty covers.
KITTI_GROUND = {"camera_height": 1.65, "camera_height_sigma": 0.1, "normal": (0.0, -1.0, 0.0),
                "normal_sigma_deg": 1.0, "upright_sigma_deg": 2.0}


def with_ground(images: list[Image], overrides: dict[str, object]) -> list[Image]:
    """The images with their ground block's fields replaced by ``overrides`` (schema field names), for a
    whole file; an image without a block gets one from the overrides and the defaults.

    Raises
    ------
    schemas.InputFileError
        When the resulting block is invalid (e.g. a negative height), naming the field.
    """
    if not overrides:
        return images
    out = []
    for im in images:
        fields = dict(overrides)
        if "normal" in fields:
            fields.setdefault("camera_pitch_deg", None)
            fields.setdefault("camera_roll_deg", None)
        if "camera_pitch_deg" in fields or "camera_roll_deg" in fields:
            fields.setdefault("normal", None)
        block = schemas.parse_ground_block({**(im.ground_block or {}), **fields}, "ground options")
        out.append(replace(im, ground=ground_from_schema(block), ground_block=block.model_dump()))
    return out


def ground_from_schema(g: schemas.GroundModel) -> GroundPlane:
    """The :class:`GroundPlane` of an image's ground block."""
    if g.normal is not None:
        normal = np.array(g.normal, dtype=float)
        normal /= np.linalg.norm(normal)
    else:
        pitch = np.deg2rad(g.camera_pitch_deg or 0.0)
        roll = np.deg2rad(g.camera_roll_deg or 0.0)
        normal = rot_z(-roll) @ rot_x(-pitch) @ LEVEL_NORMAL
    return GroundPlane(normal=normal, normal_sigma=float(np.deg2rad(g.normal_sigma_deg)),
                       camera_height=g.camera_height, camera_height_sigma=g.camera_height_sigma,
                       upright_sigma=float(np.deg2rad(g.upright_sigma_deg)))


def camera_from_schema(cam: schemas.CameraModel, size: tuple[int, int] | None) -> Camera:
    """The :class:`Camera` of an annotation's camera block."""
    distortion = None if cam.distortion is None else np.array(cam.distortion, dtype=float)
    if cam.P is not None:
        return Camera.from_P(np.array(cam.P, dtype=float), image_size=size, distortion=distortion)
    return Camera(K=np.array(cam.K, dtype=float), distortion=distortion, image_size=size)


def images_from_schema(doc: schemas.AnnotationFile) -> list[Image]:
    """Convert a validated annotation file into :class:`Image` objects."""
    return [image_from_schema(im, i) for i, im in enumerate(doc.images)]


def image_from_schema(im: schemas.ImageAnnotation, index: int) -> Image:
    """Convert one validated image, the ``index``-th of its file, into an :class:`Image`."""
    ip = f"$.images[{index}]"
    vehicles = tuple(
        Vehicle(
            id=v.id, prototype=v.prototype,
            box2d=None if v.box2d is None else np.array(v.box2d, dtype=float),
            parts=tuple(_part(p, f"{ip}.vehicles[{j}].parts[{k}]") for k, p in enumerate(v.parts)),
            json_path=f"{ip}.vehicles[{j}]",
            known_dimensions={axis: (k.metres, k.sigma) for axis, k in (v.known_dimensions or {}).items()},
        )
        for j, v in enumerate(im.vehicles)
    )
    return Image(id=im.id, file=im.file, camera=camera_from_schema(im.camera, im.size),
                 vehicles=vehicles, json_path=ip,
                 ground=None if im.ground is None else ground_from_schema(im.ground),
                 ground_block=None if im.ground is None else im.ground.model_dump())


def load_images(path: str | Path) -> list[Image]:
    """Read, validate and convert an annotation file.

    Raises
    ------
    schemas.AnnotationError
    """
    return images_from_schema(schemas.load_annotations(path))
