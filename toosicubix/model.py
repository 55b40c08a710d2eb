"""Plain numpy dataclasses for annotated images and vehicles; built once from the parsed file.

The solver and the formats work on these and never see pydantic: :mod:`toosicubix.annotations.convert` turns the
annotation file into them and back.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

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

    def __reduce__(self) -> tuple[Any, tuple]:
        """Pickled with its float arrays as lists: a batch sends every part to a worker process, and numpy's
        pickling of three small arrays cost more than the part's numbers. They come back the same: float64, the
        same shape, C order (any other value, an array of another kind included, is pickled as it is)."""
        return _part, (self.kind, self.name, *_as_rows(self.uv), self.json_path, self.known, *_as_rows(self.at),
                       *_as_rows(self.spread), self.visible)


def _as_rows(a: Any) -> tuple[Any, tuple[int, ...] | None]:
    """``(nested lists, shape)`` of a C-ordered float64 array, for :meth:`Part.__reduce__`; anything else
    ``(itself, None)``."""
    if type(a) is np.ndarray and a.dtype == np.float64 and a.flags.c_contiguous:
        return a.tolist(), a.shape
    return a, None


def _from_rows(value: Any, shape: tuple[int, ...] | None) -> Any:
    """The array :func:`_as_rows` took apart (``shape`` not None); else the value as it was."""
    return value if shape is None else np.array(value, dtype=np.float64).reshape(shape)


def _part(kind: str, name: str, uv: Any, uv_shape: tuple[int, ...] | None, json_path: str,
          known: tuple[float, float] | None, at: Any, at_shape: tuple[int, ...] | None, spread: Any,
          spread_shape: tuple[int, ...] | None, visible: bool) -> Part:
    """A :class:`Part` from its pickled fields (:meth:`Part.__reduce__`)."""
    return Part(kind, name, _from_rows(uv, uv_shape), json_path, known, _from_rows(at, at_shape),
                _from_rows(spread, spread_shape), visible)


@dataclass(frozen=True)
class Vehicle:
    """One annotated vehicle.

    Attributes
    ----------
    box2d : (4,) annotated (x1, y1, x2, y2), or None
    parts : its annotations, in file order
    known_dimensions : ``{"dx": (metres, sigma), ...}`` for the dimensions known from elsewhere
    track : the physical vehicle it is across the frames of its image's sequence, or None
    """

    id: str
    prototype: str
    box2d: np.ndarray | None
    parts: tuple[Part, ...]
    json_path: str
    known_dimensions: dict[str, tuple[float, float]] = field(default_factory=dict)
    track: str | None = None


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
class GroundBlock:
    """An image's ground block as the annotation file states it (its field names and units; see
    :class:`toosicubix.annotations.schema.GroundModel`): what a file written back keeps. The solver reads the
    :class:`GroundPlane` made from it.

    Attributes
    ----------
    camera_height : metres above the road, or None when unknown; camera_height_sigma : metres
    normal : (3,) road normal in camera coordinates, pointing up (not necessarily unit), or None
    camera_pitch_deg, camera_roll_deg : instead of the normal, or None
    normal_sigma_deg, upright_sigma_deg : degrees
    """

    camera_height: float | None = None
    camera_height_sigma: float = 0.05
    normal: tuple[float, float, float] | None = None
    camera_pitch_deg: float | None = None
    camera_roll_deg: float | None = None
    normal_sigma_deg: float = 1.0
    upright_sigma_deg: float = 2.0

    def to_json(self) -> dict[str, Any]:
        """The block as the annotation file has it: every field, None ones as null."""
        return {f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v for f in fields(self)}


@dataclass(frozen=True)
class GroundOverride:
    """Ground-block fields set on every image of a batch, over each image's own block (``fit --kitti-ground``,
    ``--camera-height``, ``--road-normal x,y,z``, ..., or a camera's road normal estimated from the batch). None
    leaves a field as the image's block has it; a normal replaces a block's pitch and roll, a pitch or roll its
    normal. Merged by :func:`toosicubix.annotations.convert.with_ground`, which validates the result.

    Attributes: those of :class:`GroundBlock`, each None when not set.
    """

    camera_height: float | None = None
    camera_height_sigma: float | None = None
    normal: tuple[float, float, float] | None = None
    camera_pitch_deg: float | None = None
    camera_roll_deg: float | None = None
    normal_sigma_deg: float | None = None
    upright_sigma_deg: float | None = None

    def __post_init__(self) -> None:
        if self.normal is not None:
            object.__setattr__(self, "normal", tuple(float(v) for v in self.normal))

    def __bool__(self) -> bool:
        return bool(self.fields())

    def fields(self) -> dict[str, Any]:
        """The fields it sets, by name (schema names), in the block's order."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}

    def over(self, other: GroundOverride | None) -> GroundOverride:
        """This override's fields set over ``other``'s (a normal given here drops ``other``'s pitch and roll, a pitch
        or roll given here its normal)."""
        if other is None:
            return self
        base = other.fields()
        if self.normal is not None:
            base.pop("camera_pitch_deg", None)
            base.pop("camera_roll_deg", None)
        if self.camera_pitch_deg is not None or self.camera_roll_deg is not None:
            base.pop("normal", None)
        return GroundOverride(**{**base, **self.fields()})

    def to_json(self) -> dict[str, Any]:
        """The fields it sets (results.json's ``settings.ground``)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in self.fields().items()}


@dataclass(frozen=True)
class Image:
    """One annotated image and its camera.

    Attributes
    ----------
    ground : the road plane the solver reads, or None
    ground_block : the ground block it was made from, as the file states it (or as an override set it), or None
    sequence, frame : the video it is a frame of and its frame number there, or None
    """

    id: str
    file: str | None
    camera: Camera
    vehicles: tuple[Vehicle, ...]
    json_path: str
    ground: GroundPlane | None = None
    ground_block: GroundBlock | None = None
    sequence: str | None = None
    frame: int | None = None


#: The road normal of a level camera (camera y points down).
LEVEL_NORMAL = np.array([0.0, -1.0, 0.0])

#: KITTI's ground, as the annotation block ``{"camera_height": 1.65, "camera_height_sigma": 0.1,
#: "normal": [0, -1, 0], "normal_sigma_deg": 1.0, "upright_sigma_deg": 2.0}``. Measured on KITTI tracking
#: ground truth (sequences 0000-0009): the bottom centres of vehicles within 10 m lie 1.68 m below the
#: camera (standard deviation 0.12 m); farther away the road's slope spreads them by about 0.75 degrees
#: times the distance, which the normal's uncertainty covers.
KITTI_GROUND = GroundOverride(camera_height=1.65, camera_height_sigma=0.1, normal=(0.0, -1.0, 0.0),
                              normal_sigma_deg=1.0, upright_sigma_deg=2.0)
