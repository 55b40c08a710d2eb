"""The annotation file, version 1: Pydantic models, loading, and errors that name the JSON path.

This module only parses and validates. :mod:`toosicubix.annotations.convert` turns the parsed file into the plain
numpy dataclasses of :mod:`toosicubix.model`; nothing past that boundary imports pydantic.
"""

from __future__ import annotations

import functools
import json
import re
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar, Union

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    create_model,
    field_validator,
    model_validator,
)

from toosicubix import vocabulary
from toosicubix.errors import InputFileError
from toosicubix.fields import (
    FILE_NAME_PATTERN,
    MAX_FRAME,
    MAX_ID_LENGTH,
    MAX_METRES,
    MAX_PIXEL,
    MIN_SIGMA_METRES,
)
from toosicubix.jsonfile import read_json
from toosicubix.vocabulary import DIMENSION_AXES

SCHEMA_VERSION = 1

# MAX_PIXEL, MAX_METRES, MIN_SIGMA_METRES, MAX_ID_LENGTH and MAX_FRAME are the bounds every reader applies
# (toosicubix.fields, imported above): what a file may hold is what a reader may pass on.

#: The most clicked points one vehicle may have (a point part is one, a pair or an arrow two). The flat keypoint
#: vocabulary of the labelling tools has 65 and ApolloCar3D's 66; the solver's work grows with the square of
#: the clicks and more, so a vehicle past this is refused rather than left to run for minutes.
MAX_CLICKS_PER_VEHICLE = 128

#: Focal lengths in pixels: below 1 px the clicks cannot be pixels; above 10^6 px no lens gives it.
FOCAL_RANGE_PX = (1.0, 1e6)
#: The largest camera offset ``|K^-1 P[:, 3]|`` (metres) a ``P`` may hold (KITTI's: 0.06 m).
MAX_CAMERA_OFFSET = 100.0



#: A real number as JSON writes it, an integer likewise: strict, so that ``true`` is not read as 1 nor ``"12"`` as 12
#: (pydantic's lax mode would), which no labelling tool means as a pixel, a size or a frame.
Real = Annotated[float, Field(strict=True)]
Integer = Annotated[int, Field(strict=True)]
#: ``true`` or ``false`` (never 1, "yes" or "false").
Flag = Annotated[bool, Field(strict=True)]


def _ensure_pixel(value: float) -> float:
    if not -MAX_PIXEL <= value <= MAX_PIXEL:
        raise ValueError(f"expected a pixel coordinate within +-{MAX_PIXEL:g} (no camera image is that large; "
                         f"the solver's pixel arithmetic loses a click's precision beyond it), got {value:g}")
    return value


def _ensure_metres(value: float) -> float:
    if not 0.0 < value <= MAX_METRES:
        raise ValueError(f"expected a size in metres greater than 0 and at most {MAX_METRES:g} (no road vehicle or "
                         f"camera mount is larger), got {value:g}")
    return value


def _ensure_sigma_metres(value: float) -> float:
    if not MIN_SIGMA_METRES <= value <= MAX_METRES:
        raise ValueError(f"expected a sigma in metres greater than 0, from {MIN_SIGMA_METRES:g} (no vehicle's size "
                         f"is known better; a smaller one swamps every click) to {MAX_METRES:g}, got {value:g}")
    return value


Coordinate = Annotated[Real, AfterValidator(_ensure_pixel),
                       Field(json_schema_extra={"minimum": -MAX_PIXEL, "maximum": MAX_PIXEL})]
Pixel = Annotated[tuple[Coordinate, Coordinate], Field(description="Pixel position (x, y): x right, y down.")]
Row3 = tuple[Real, Real, Real]
Row4 = tuple[Real, Real, Real, Real]
Metres = Annotated[Real, AfterValidator(_ensure_metres),
                   Field(json_schema_extra={"exclusiveMinimum": 0, "maximum": MAX_METRES})]
SigmaMetres = Annotated[Real, AfterValidator(_ensure_sigma_metres),
                        Field(json_schema_extra={"minimum": MIN_SIGMA_METRES, "maximum": MAX_METRES})]
ImageSide = Annotated[Integer, Field(gt=0, le=int(MAX_PIXEL))]




class _Model(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


_M = TypeVar("_M", bound=_Model)


#: The type of each known-size key a part kind may state (``length``: its size and sigma, bounded).
_KNOWN_SIZE_TYPES = {"metres": Metres, "sigma": SigmaMetres}


def _ensure_positive_row(row: Row3) -> Row3:
    if min(row) <= 0:
        raise ValueError(f"expected positive spreads, got {list(row)}")
    return row


#: Three positive numbers (a keypoint's spread).
PositiveRow3 = Annotated[Row3, AfterValidator(_ensure_positive_row)]
#: The pydantic type and default of each ``fields_extra`` type name of the vocabulary.
_EXTRA_FIELD_TYPES: dict[str, tuple[Any, Any]] = {
    "row3": (Row3, ...),
    "positive_row3": (PositiveRow3, ...),
    "bool_default_true": (Flag, True),
}


def _part_annotation(kind: vocabulary.Kind) -> type[_Model]:
    """The pydantic class of one part kind, from its vocabulary entry: ``kind``, the name (one of the kind's
    names; any non-empty string for an open kind), the clicked pixels, the known size's positive numbers when
    the kind states one, and its extra typed fields (``fields_extra``)."""
    described = kind.schema.get("fields", {})

    def field(key: str, **extra: Any) -> Any:
        return Field(description=described[key], **extra) if key in described else (Field(**extra) if extra else ...)

    name_type: Any = (str if kind.open_names else Literal[tuple(kind.names)])  # type: ignore[valid-type]
    name_extra = {"min_length": 1, "max_length": MAX_ID_LENGTH} if kind.open_names else {}
    fields: dict[str, Any] = {
        "kind": (Literal[kind.kind], ...),
        kind.name_field: (name_type, field(kind.name_field, **name_extra)),
        **{key: (Pixel, field(key)) for key in kind.clicks},
        **{key: (_KNOWN_SIZE_TYPES[key], field(key)) for key in kind.known},
    }
    for key, type_name in kind.fields_extra:
        annotation, default = _EXTRA_FIELD_TYPES[type_name]
        fields[key] = (annotation, field(key, default=default) if default is not ... else field(key))
    return create_model(kind.schema["class"], __base__=_Model, __doc__=kind.schema["description"],
                        __module__=__name__, **fields)


#: The pydantic class of every part kind of the vocabulary (``PointAnnotation``, ...), by kind.
PART_ANNOTATIONS: dict[str, type[_Model]] = {k: _part_annotation(kind) for k, kind in vocabulary.KINDS.items()}
PointAnnotation = PART_ANNOTATIONS["point"]
SymmetryAnnotation = PART_ANNOTATIONS["symmetry"]
DirectionAnnotation = PART_ANNOTATIONS["direction"]
LengthAnnotation = PART_ANNOTATIONS["length"]
KeypointAnnotation = PART_ANNOTATIONS["keypoint"]
PlateAnnotation = PART_ANNOTATIONS["plate"]

PartAnnotation = Annotated[Union[tuple(PART_ANNOTATIONS.values())], Field(discriminator="kind")]  # noqa: UP007


class KnownSize(_Model):
    """A known dimension, e.g. from the vehicle's make and model."""

    metres: Metres
    sigma: SigmaMetres = Field(description="One standard deviation, metres.")


class GroundModel(_Model):
    """The road under the vehicles, in camera coordinates: its normal (pointing up, toward the camera side)
    and the camera's height above it. KITTI's cameras sit about 1.65 m above a road whose normal is -y."""

    camera_height: Metres | None = Field(
        default=None, description="Camera height above the road, metres; leave out when unknown.")
    camera_height_sigma: SigmaMetres = Field(default=0.05, description="Its uncertainty, metres.")
    normal: Row3 | None = Field(
        default=None, description="Road normal in camera coordinates (x right, y down, z forward), pointing up; "
                                  "default [0, -1, 0] (a level camera).")
    camera_pitch_deg: Real | None = Field(
        default=None, ge=-90, le=90,
        description="Instead of the normal: the camera's pitch above the road, degrees (nose up > 0).")
    camera_roll_deg: Real | None = Field(
        default=None, ge=-180, le=180,
        description="Instead of the normal: the camera's roll, degrees (clockwise as seen > 0).")
    normal_sigma_deg: Real = Field(default=1.0, ge=1e-6, le=180, description="Uncertainty of the normal, degrees.")
    upright_sigma_deg: Real = Field(
        default=2.0, ge=1e-6, le=180,
        description="How far vehicles lean from the road normal (pitch and roll), degrees.")

    @field_validator("normal")
    @classmethod
    def _ensure_nonzero_normal(cls, normal: Row3 | None) -> Row3 | None:
        if normal is not None and not 1e-9 <= float(np.linalg.norm(normal)) <= 1e9:
            raise ValueError(f"expected a non-zero road normal, of length between 1e-9 and 1e9 (it is normalised), "
                             f"got {list(normal)}")
        return normal

    @model_validator(mode="after")
    def _ensure_one_orientation(self) -> GroundModel:
        if self.normal is not None and (self.camera_pitch_deg is not None or self.camera_roll_deg is not None):
            raise ValueError("expected either 'normal' or 'camera_pitch_deg'/'camera_roll_deg', not both")
        return self


@functools.lru_cache(maxsize=1024)
def _checked_camera(matrix: tuple[tuple[float, ...], ...]) -> None:
    """:func:`check_intrinsics` of a K (3 rows of 3), :func:`check_projection` of a P (3 rows of 4), once per distinct
    matrix: a file's images share a few cameras, and the checks (a determinant, a condition number) cost more than
    the rest of an image's validation. A refused matrix is not kept: each image with it is refused again."""
    if len(matrix[0]) == 3:
        check_intrinsics(np.array(matrix))
    else:
        check_projection(np.array(matrix))


class CameraModel(_Model):
    """Intrinsics as ``K`` (3x3, optional OpenCV ``distortion``) or a KITTI-style ``P`` (3x4)."""

    K: tuple[Row3, Row3, Row3] | None = Field(default=None, description="Intrinsics, last row [0, 0, 1].")
    P: tuple[Row4, Row4, Row4] | None = Field(
        default=None, description="KITTI projection matrix K [I | t]; poses come out in the K = P[:, :3] frame."
    )
    distortion: list[Annotated[Real, Field(ge=-1e6, le=1e6)]] | None = Field(
        default=None,
        description="OpenCV distortion coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tx, ty]]]]).",
    )

    @field_validator("K")
    @classmethod
    def _ensure_invertible_K(cls, K: tuple[Row3, Row3, Row3] | None) -> tuple[Row3, Row3, Row3] | None:
        if K is not None:
            _checked_camera(K)
        return K

    @field_validator("P")
    @classmethod
    def _ensure_invertible_P(cls, P: tuple[Row4, Row4, Row4] | None) -> tuple[Row4, Row4, Row4] | None:
        if P is not None:
            _checked_camera(P)
        return P

    @field_validator("distortion")
    @classmethod
    def _ensure_distortion_length(cls, d: list[float] | None) -> list[float] | None:
        if d is not None and len(d) not in (4, 5, 8, 12, 14):
            raise ValueError(f"expected 4, 5, 8, 12 or 14 OpenCV distortion coefficients, got {len(d)}")
        return d

    @model_validator(mode="after")
    def _ensure_one_matrix(self) -> CameraModel:
        if (self.K is None) == (self.P is None):
            raise ValueError("expected exactly one of 'K' (3x3) and 'P' (3x4)")
        return self


def check_projection(P: np.ndarray) -> None:
    """Raise ``ValueError`` unless ``P`` (3, 4) = K [I | t] with a camera's K (see :func:`check_intrinsics`)
    and an offset ``|t|`` of at most ``MAX_CAMERA_OFFSET`` metres."""
    check_intrinsics(P[:, :3])
    if np.abs(P[:, 3]).max() > MAX_PIXEL * MAX_CAMERA_OFFSET:
        raise ValueError(f"expected P[:, 3] = K t within +-{MAX_PIXEL * MAX_CAMERA_OFFSET:g} (a camera offset "
                         f"t of at most {MAX_CAMERA_OFFSET:g} m), got {P[:, 3].tolist()}")
    offset = np.linalg.solve(P[:, :3], P[:, 3])
    if float(np.linalg.norm(offset)) > MAX_CAMERA_OFFSET:
        raise ValueError(
            f"expected P = K [I | t] with |t| = |K^-1 P[:, 3]| at most {MAX_CAMERA_OFFSET:g} m (a camera's "
            f"offset from the reference camera; KITTI's is 0.06 m), got t = {offset.tolist()} from "
            f"P[:, 3] = {P[:, 3].tolist()}")


def check_intrinsics(K: np.ndarray) -> None:
    """What a pinhole camera's K (3, 3) can be: upper triangular [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with
    focal lengths in ``FOCAL_RANGE_PX``, skew and principal point within ``MAX_PIXEL``, and well conditioned."""
    if not np.allclose(K[2], [0.0, 0.0, 1.0], atol=1e-9, rtol=0.0):
        raise ValueError(f"expected the last row of K to be [0, 0, 1], got {K[2].tolist()}")
    if np.abs(K).max() > MAX_PIXEL:
        raise ValueError(f"expected the entries of K within +-{MAX_PIXEL:g} pixels (focal lengths, skew, principal "
                         f"point), got K = {K.tolist()}")
    scale = max(abs(K[0, 0]), abs(K[1, 1]), 1e-300)
    if abs(np.linalg.det(K)) <= 1e-12 * scale * scale:
        raise ValueError(f"expected an invertible K, got det(K) = {np.linalg.det(K):.3g} for K = {K.tolist()}")
    if abs(K[1, 0]) > 1e-9:
        raise ValueError(f"expected K[1][0] = 0 (K is upper triangular: [[fx, s, cx], [0, fy, cy], [0, 0, 1]]), "
                         f"got {K[1, 0]:g}")
    low, high = FOCAL_RANGE_PX
    for name, f in (("K[0][0]", K[0, 0]), ("K[1][1]", K[1, 1])):
        if not low <= f <= high:
            raise ValueError(f"expected a focal length {name} between {low:g} and {high:g} pixels, got {f:g}")
    f = max(K[0, 0], K[1, 1])
    cond = float(np.linalg.cond(np.diag([1.0 / f, 1.0 / f, 1.0]) @ K))  # in units of the focal length
    if not cond <= 1e8:
        raise ValueError(f"expected a well-conditioned K, got condition number {cond:.3g} for K = {K.tolist()}")


#: The most clicked points a part of any kind has (a symmetry pair's two, an arrow's two ends, ...).
_MOST_CLICKS_PER_PART = max(len(kind.clicks) for kind in vocabulary.KINDS.values())


class VehicleAnnotation(_Model):
    """One vehicle: its prototype (size class) and the parts clicked on it."""

    id: str = Field(min_length=1, max_length=MAX_ID_LENGTH, pattern=r"^[^\x00-\x1f\x7f]*$",
                    description="Unique within its image; no control characters.")
    prototype: str = Field(min_length=1, max_length=MAX_ID_LENGTH,
                           description="Size class in the priors file, e.g. 'Car', 'Mid Size Car'.")
    track: str | None = Field(
        default=None, min_length=1, max_length=MAX_ID_LENGTH, pattern=r"^[^\x00-\x1f\x7f]*$",
        description="The same physical vehicle across the frames of its image's sequence (e.g. '0003-7'): one "
                    "prototype and one size per track. A tracked vehicle may have clicks, only a box2d, or neither "
                    "(its pose is then interpolated from the track's other frames).")
    box2d: tuple[Coordinate, Coordinate, Coordinate, Coordinate] | None = Field(
        default=None, description="Annotated 2D box (x1, y1, x2, y2) in pixels, written to the KITTI file; for a "
                                  "tracked vehicle (or with fit --box-cue) also a cue: the fitted cuboid's projection "
                                  "touches its sides."
    )
    parts: list[PartAnnotation] = Field(default_factory=list)
    known_dimensions: dict[Literal[DIMENSION_AXES], KnownSize] | None = Field(  # type: ignore[valid-type]
        default=None, description="Dimensions known from elsewhere (e.g. the make and model): dx, dy, dz.")

    @field_validator("box2d")
    @classmethod
    def _ensure_box_order(cls, box: tuple[float, ...] | None) -> tuple[float, ...] | None:
        if box is not None and not (box[2] > box[0] and box[3] > box[1]):
            raise ValueError(f"expected x1 < x2 and y1 < y2, got {list(box)}")
        return box

    @field_validator("parts")
    @classmethod
    def _ensure_few_clicks(cls, parts: list[PartAnnotation]) -> list[PartAnnotation]:
        if len(parts) * _MOST_CLICKS_PER_PART <= MAX_CLICKS_PER_VEHICLE:  # every vehicle of a real file
            return parts
        clicks = sum(len(vocabulary.KINDS[part.kind].clicks) for part in parts)
        if clicks > MAX_CLICKS_PER_VEHICLE:
            raise ValueError(f"expected at most {MAX_CLICKS_PER_VEHICLE} clicked points per vehicle "
                             f"(MAX_CLICKS_PER_VEHICLE), found {clicks} in {len(parts)} parts")
        return parts


class ImageAnnotation(_Model):
    """One image: its camera and its annotated vehicles."""

    id: str = Field(
        pattern=FILE_NAME_PATTERN, max_length=MAX_ID_LENGTH,
        description=f"Image id; names the KITTI label file, so letters, digits, '_', '.', '-' only, at most "
                    f"{MAX_ID_LENGTH} characters.",
    )
    file: str | None = Field(default=None, description="Image path relative to the annotation file.")
    sequence: str | None = Field(
        default=None, pattern=FILE_NAME_PATTERN, max_length=MAX_ID_LENGTH,
        description="The video (sequence) the image is a frame of, e.g. '0003'; names the KITTI tracking label file "
                    "label_02/<sequence>.txt. Given with 'frame'.")
    frame: Integer | None = Field(
        default=None, ge=0, le=MAX_FRAME,
        description="The image's frame number in its sequence: orders the frames (each number at most once per "
                    "sequence; gaps are frames not annotated). Given with 'sequence'.")
    size: tuple[ImageSide, ImageSide] | None = Field(
        default=None, description="(width, height) in pixels; projected boxes are clipped to it."
    )
    camera: CameraModel
    ground: GroundModel | None = Field(default=None, description="The road plane; enables the ground cues.")
    vehicles: list[VehicleAnnotation] = Field(default_factory=list)

    @field_validator("vehicles")
    @classmethod
    def _ensure_unique_vehicle_ids(cls, vehicles: list[VehicleAnnotation]) -> list[VehicleAnnotation]:
        _ensure_unique([v.id for v in vehicles], "vehicle")
        tracks: dict[str, int] = {}
        for j, v in enumerate(vehicles):
            if v.track is not None and tracks.setdefault(v.track, j) != j:
                raise ValueError(f"expected one vehicle per track in a frame, got track {v.track!r} at "
                                 f"[{tracks[v.track]}] and [{j}]")
        return vehicles

    @model_validator(mode="after")
    def _ensure_sequence_with_frame(self) -> ImageAnnotation:
        if (self.sequence is None) != (self.frame is None):
            raise ValueError("expected 'sequence' and 'frame' together (a frame of a sequence), or neither")
        if self.sequence is None and any(v.track is not None for v in self.vehicles):
            raise ValueError("expected 'sequence' and 'frame' on an image whose vehicles carry a 'track'")
        return self


class AnnotationFile(_Model):
    """A ToosiCubix annotation file, version 1."""

    model_config = ConfigDict(title="ToosiCubix annotation file v1")

    toosicubix: Literal[1] = Field(description="Format version.")
    images: list[ImageAnnotation]

    @field_validator("images")
    @classmethod
    def _ensure_unique_image_ids(cls, images: list[ImageAnnotation]) -> list[ImageAnnotation]:
        _ensure_unique([im.id for im in images], "image")
        # They name files, and some file systems ignore case: 'A' and 'a' would share one label file.
        _ensure_unique([im.id.lower() for im in images], IMAGE_IDS_IGNORING_CASE)
        return images


class TrackBook:
    """The rules that span images, checked one image at a time (a file's images, or a stream of them): a frame number
    at most once per sequence, a track in one sequence only, one prototype per track. ``problems`` lists each broken
    rule as ``(JSON path, message)``, naming the other place too."""

    def __init__(self) -> None:
        self.problems: list[tuple[str, str]] = []
        self._frames: dict[tuple[str, int], int] = {}  # (sequence, frame) -> image index
        self._tracks: dict[str, tuple[str, str, str]] = {}  # track -> (sequence, prototype, JSON path)
        self._sequences: dict[str, tuple[str, int]] = {}  # lower-cased name -> (name, first image index)

    def add(self, index: int, image: ImageAnnotation) -> None:
        if image.sequence is None or image.frame is None:
            return
        where = f"$.images[{index}]"
        # A sequence names its label_02 file, and some file systems ignore case: 'A' and 'a' would share one.
        name, first_at = self._sequences.setdefault(image.sequence.lower(), (image.sequence, index))
        if name != image.sequence:
            self.problems.append((f"{where}.sequence", f"sequence {image.sequence!r} differs from {name!r} (at "
                                                       f"$.images[{first_at}]) only in case: they name files, and "
                                                       "some file systems ignore case"))
        first = self._frames.setdefault((image.sequence, image.frame), index)
        if first != index:
            self.problems.append((f"{where}.frame", f"frame {image.frame} of sequence {image.sequence!r} is given "
                                                    f"twice: also at $.images[{first}]"))
        for j, v in enumerate(image.vehicles):
            if v.track is None:
                continue
            path = f"{where}.vehicles[{j}].track"
            sequence, prototype, seen = self._tracks.setdefault(v.track, (image.sequence, v.prototype, path))
            if sequence != image.sequence:
                self.problems.append((path, f"track {v.track!r} is in sequence {image.sequence!r} here and in "
                                            f"{sequence!r} at {seen}: a track stays in one sequence"))
            elif prototype != v.prototype:
                self.problems.append((path, f"track {v.track!r} has prototype {v.prototype!r} here and {prototype!r} "
                                            f"at {seen}: one prototype (and one size) per track"))


#: What image ids that differ only in case are called in the message that refuses them.
IMAGE_IDS_IGNORING_CASE = "image (ignoring case: they name files)"


def duplicate_ids_message(what: str, item: str, first: int, index: int) -> str:
    """The message refusing id ``item`` given at ``[first]`` and again at ``[index]`` (the whole-file reader's and the
    streamed index's)."""
    return f"expected unique {what} ids, got {item!r} at [{first}] and [{index}]"


def _ensure_unique(ids: list[str], what: str) -> None:
    first: dict[str, int] = {}
    for index, item in enumerate(ids):
        if item in first:
            raise ValueError(duplicate_ids_message(what, item, first[item], index))
        first[item] = index


def json_schema() -> dict[str, Any]:
    """The JSON Schema of the annotation file, as committed in ``schemas/annotations.schema.json``."""
    schema = AnnotationFile.model_json_schema()
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema}


_UNION_TAGS = set(vocabulary.KINDS)


def _json_path(loc: tuple[int | str, ...]) -> str:
    path = "$"
    for index, item in enumerate(loc):
        if item == "[key]":  # a bad key of a mapping: the path already ends with it
            continue
        # A discriminated union puts the tag into the location: parts[1].point.xy -> parts[1].xy.
        if isinstance(item, str) and item in _UNION_TAGS and index > 0 and isinstance(loc[index - 1], int):
            continue
        path += f"[{item}]" if isinstance(item, int) else f".{item}"
    return path


#: A quoted value in a validator's message longer than this is cut (pydantic quotes the input: a 5,000-character
#: ``kind`` made a 5,000-character message).
_QUOTED = re.compile(r"'([^']{57})[^']{4,}'")


def _describe(error: dict[str, Any]) -> str:
    message = _QUOTED.sub(r"'\1...'", error["msg"].removeprefix("Value error, "))
    if error["loc"] and error["loc"][-1] == "[key]":
        message = f"bad key: {message}"
    if error["type"] == "missing":
        return "missing required field"
    if error["type"] == "extra_forbidden":
        return "unknown field (not in the annotation format v1)"
    found = error.get("input")
    if error["type"] in {"value_error", "assertion_error"} or isinstance(found, dict):
        return message
    text = json.dumps(found, allow_nan=True) if not isinstance(found, tuple) else json.dumps(list(found))
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{message}; got {text}"


def _validate(model: type[_M], data: Any, source: str | Path) -> _M:
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        problems = [(_json_path(err["loc"]), _describe(err)) for err in exc.errors()]
        raise InputFileError(source, problems) from None


def parse_annotations(data: Any, source: str | Path = "<annotations>") -> AnnotationFile:
    """Validate already-decoded JSON data: the model, then the rules that span images (:class:`TrackBook`).

    Raises
    ------
    InputFileError
        Naming ``source`` and the JSON path of every problem.
    """
    doc = _validate(AnnotationFile, data, source)
    book = TrackBook()
    for i, image in enumerate(doc.images):
        book.add(i, image)
    if book.problems:
        raise InputFileError(source, book.problems)
    return doc


def load_annotations(path: str | Path) -> AnnotationFile:
    """Read and validate an annotation file.

    Raises
    ------
    InputFileError
        The file is missing, not JSON, or not a valid annotation file v1.
    """
    return parse_annotations(read_json(path, at_root=True), path)


def parse_ground_block(data: Any, source: str | Path = "command line") -> GroundModel:
    """Validate a ground block given outside a file (e.g. by command-line options).

    Raises
    ------
    InputFileError
        Naming ``source`` and the field of every problem.
    """
    return _validate(GroundModel, data, source)
