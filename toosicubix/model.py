"""Plain numpy dataclasses for annotated images and vehicles; built once from the parsed file.

The solver and the formats work on these and never see pydantic: :mod:`toosicubix.annotations.convert` turns the
annotation file into them and back.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from toosicubix.camera import Camera
from toosicubix.vocabulary import click_labels


@dataclass(frozen=True)
class Part:
    """One annotation on a vehicle.

    Attributes
    ----------
    kind : 'point', 'symmetry', 'direction', 'length', 'keypoint' or 'plate'
    name : the point's part name ('wheel-front-left', ...), the symmetry face ('front', 'rear', 'roof'),
        the direction axis ('forward', ...) or the length feature ('plate-rear', ...)
    uv : (k, 2) pixels as clicked: one row for a point, (left, right) for a symmetry,
        (tail, head) for a direction, (a, b) for a length
    json_path : where it stands in the annotation file
    known : ``(metres, sigma)`` of a length (or plate) annotation's feature, else None
    at, spread : (3,) a keypoint's (or a plate centre's) typical position and its spread, fractions of
        ``(dx, dy, dz)``; else None
    visible : False for a keypoint labelled but hidden
    """

    kind: str
    name: str
    uv: np.ndarray
    json_path: str
    known: tuple[float, float] | None = None
    at: np.ndarray | None = None
    spread: np.ndarray | None = None
    visible: bool = True

    @property
    def click_labels(self) -> tuple[str, ...]:
        """A label per clicked pixel, e.g. ('symmetry-rear/left', 'symmetry-rear/right') (the vocabulary's)."""
        return click_labels(self.kind, self.name)


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
    from_batch : the normal was estimated from the batch's own fits (:mod:`toosicubix.pipeline.road_normal`),
        not given
    """

    normal: np.ndarray
    normal_sigma: float
    camera_height: float | None
    camera_height_sigma: float
    upright_sigma: float
    from_batch: bool = False


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


#: The road normal of a level camera (camera y points down).
LEVEL_NORMAL = np.array([0.0, -1.0, 0.0])

#: KITTI's ground, as the annotation block ``{"camera_height": 1.65, "camera_height_sigma": 0.1,
#: "normal": [0, -1, 0], "normal_sigma_deg": 1.0, "upright_sigma_deg": 2.0}``. Measured on KITTI tracking
#: ground truth (sequences 0000-0009): the bottom centres of vehicles within 10 m lie 1.68 m below the
#: camera (standard deviation 0.12 m); farther away the road's slope spreads them by about 0.75 degrees
#: times the distance, which the normal's uncertainty covers.
KITTI_GROUND = {"camera_height": 1.65, "camera_height_sigma": 0.1, "normal": (0.0, -1.0, 0.0),
                "normal_sigma_deg": 1.0, "upright_sigma_deg": 2.0}
