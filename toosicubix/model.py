"""Plain numpy dataclasses for annotated images and vehicles; built once from the parsed file.

The solver and the formats work on these and never see pydantic.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import schemas
from .camera import Camera


@dataclass(frozen=True)
class Part:
    """One annotation on a vehicle.

    Attributes
    ----------
    kind : 'point', 'symmetry' or 'direction'
    name : the point's part name ('wheel-front-left', ...), the symmetry face ('front', 'rear', 'roof')
        or the direction axis ('forward', ...)
    uv : (k, 2) pixels as clicked: one row for a point, (left, right) for a symmetry,
        (tail, head) for a direction
    json_path : where it stands in the annotation file
    """

    kind: str
    name: str
    uv: np.ndarray
    json_path: str

    @property
    def click_labels(self) -> tuple[str, ...]:
        """A label per clicked pixel, e.g. ('symmetry-rear/left', 'symmetry-rear/right')."""
        if self.kind == "point":
            return (self.name,)
        if self.kind == "symmetry":
            return (f"symmetry-{self.name}/left", f"symmetry-{self.name}/right")
        return (f"direction-{self.name}/tail", f"direction-{self.name}/head")


@dataclass(frozen=True)
class Vehicle:
    """One annotated vehicle.

    Attributes
    ----------
    box2d : (4,) annotated (x1, y1, x2, y2), or None
    parts : its annotations, in file order
    """

    id: str
    prototype: str
    box2d: np.ndarray | None
    parts: tuple[Part, ...]
    json_path: str


@dataclass(frozen=True)
class Image:
    """One annotated image and its camera."""

    id: str
    file: str | None
    camera: Camera
    vehicles: tuple[Vehicle, ...]
    json_path: str


def _part(p: schemas.PointAnnotation | schemas.SymmetryAnnotation | schemas.DirectionAnnotation,
          json_path: str) -> Part:
    if isinstance(p, schemas.PointAnnotation):
        return Part("point", p.part, np.array([p.xy], dtype=float), json_path)
    if isinstance(p, schemas.SymmetryAnnotation):
        return Part("symmetry", p.face, np.array([p.left, p.right], dtype=float), json_path)
    return Part("direction", p.axis, np.array([p.tail, p.head], dtype=float), json_path)


def camera_from_schema(cam: schemas.CameraModel, size: tuple[int, int] | None) -> Camera:
    """The :class:`Camera` of an annotation's camera block."""
    distortion = None if cam.distortion is None else np.array(cam.distortion, dtype=float)
    if cam.P is not None:
        return Camera.from_P(np.array(cam.P, dtype=float), image_size=size, distortion=distortion)
    return Camera(K=np.array(cam.K, dtype=float), distortion=distortion, image_size=size)


def images_from_schema(doc: schemas.AnnotationFile) -> list[Image]:
    """Convert a validated annotation file into :class:`Image` objects."""
    images = []
    for i, im in enumerate(doc.images):
        ip = f"$.images[{i}]"
        vehicles = tuple(
            Vehicle(
                id=v.id, prototype=v.prototype,
                box2d=None if v.box2d is None else np.array(v.box2d, dtype=float),
                parts=tuple(_part(p, f"{ip}.vehicles[{j}].parts[{k}]") for k, p in enumerate(v.parts)),
                json_path=f"{ip}.vehicles[{j}]",
            )
            for j, v in enumerate(im.vehicles)
        )
        images.append(Image(id=im.id, file=im.file, camera=camera_from_schema(im.camera, im.size),
                            vehicles=vehicles, json_path=ip))
    return images


def load_images(path: str | Path) -> list[Image]:
    """Read, validate and convert an annotation file.

    Raises
    ------
    schemas.AnnotationError
    """
    return images_from_schema(schemas.load_annotations(path))
