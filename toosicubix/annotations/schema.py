"""The annotation file, version 1: Pydantic models, loading, and errors that name the JSON path.

This module only parses and validates. :mod:`toosicubix.model` turns the parsed file into plain
numpy dataclasses; nothing past that boundary imports pydantic.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

SCHEMA_VERSION = 1

WHEEL_PARTS = tuple(f"wheel-{fr}-{lr}" for fr in ("front", "rear") for lr in ("left", "right"))
CENTER_PARTS = ("front-center", "rear-center", "top-center")
EDGE_PARTS = tuple(f"edge-{fr}-{lr}" for fr in ("front", "rear") for lr in ("left", "right"))
CORNER_PARTS = tuple(
    f"corner-{tb}-{fr}-{lr}" for tb in ("top", "bottom") for fr in ("front", "rear") for lr in ("left", "right")
)
#: Every name a ``point`` annotation may carry.
POINT_PARTS: tuple[str, ...] = WHEEL_PARTS + CENTER_PARTS + EDGE_PARTS + CORNER_PARTS
SYMMETRY_FACES = ("front", "rear", "roof")
DIRECTION_AXES = ("forward", "backward", "leftward", "rightward", "upward", "downward")
#: Features of known size for ``length`` annotations, with what their two clicks ``a`` and ``b`` mark.
LENGTH_FEATURES = {
    "plate-front": "a: left end, b: right end of the front licence plate (its width)",
    "plate-rear": "a: left end, b: right end of the rear licence plate (its width)",
    "wheelbase-left": "a: front, b: rear tyre's contact with the ground, left side (the wheelbase)",
    "wheelbase-right": "a: front, b: rear tyre's contact with the ground, right side (the wheelbase)",
    **{f"tyre-{fr}-{lr}": f"a: contact with the ground, b: top of the {fr}-{lr} tyre (its diameter)"
       for fr in ("front", "rear") for lr in ("left", "right")},
}
LengthFeature = Literal[tuple(LENGTH_FEATURES)]  # type: ignore[valid-type]
DIMENSION_AXES = ("dx", "dy", "dz")
#: The most clicked points one vehicle may have (a point part is one, a pair or an arrow two). The whole
#: part vocabulary clicked once is about 40; the solver's work grows with the square of the clicks and
#: more, so a vehicle past this is refused rather than left to run for minutes.
MAX_CLICKS_PER_VEHICLE = 64

PointPart = Literal[POINT_PARTS]  # type: ignore[valid-type]
SymmetryFace = Literal[SYMMETRY_FACES]  # type: ignore[valid-type]
DirectionAxis = Literal[DIRECTION_AXES]  # type: ignore[valid-type]

Pixel = Annotated[tuple[float, float], Field(description="Pixel position (x, y): x right, y down.")]
Row3 = tuple[float, float, float]
Row4 = tuple[float, float, float, float]


class InputFileError(ValueError):
    """An input file (annotations, priors, settings) that cannot be used, with every problem found.

    Attributes
    ----------
    file : str
        The file, as given.
    problems : list of (json_path, message)
        ``json_path`` is like ``$.images[0].vehicles[2].parts[1].part``.
    """

    def __init__(self, file: str | Path, problems: list[tuple[str, str]]):
        self.file = str(file)
        self.problems = problems
        lines = [f"{self.file}: {path}: {message}" for path, message in problems]
        super().__init__("\n".join(lines))


#: The name used for annotation files.
AnnotationError = InputFileError


class _Model(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


_M = TypeVar("_M", bound=_Model)


class PointAnnotation(_Model):
    """One click on a named vehicle part (see the parts table in the README)."""

    kind: Literal["point"]
    part: PointPart = Field(description="Which part was clicked, e.g. 'wheel-front-left'.")
    xy: Pixel


class SymmetryAnnotation(_Model):
    """Two clicks on laterally symmetric features (lights, mirrors) of the front, rear or roof."""

    kind: Literal["symmetry"]
    face: SymmetryFace
    left: Pixel = Field(description="The feature on the vehicle's own left side (+Y).")
    right: Pixel = Field(description="Its mirror image on the vehicle's right side (-Y).")


class DirectionAnnotation(_Model):
    """An arrow drawn along one of the vehicle's axes, on the vehicle or on the ground beside it."""

    kind: Literal["direction"]
    axis: DirectionAxis
    tail: Pixel
    head: Pixel


class LengthAnnotation(_Model):
    """Two clicks on a feature whose size is known: a licence plate's width, the wheelbase, a tyre's diameter."""

    kind: Literal["length"]
    feature: LengthFeature = Field(description="Which feature; see the README for what a and b mark.")
    a: Pixel
    b: Pixel
    metres: float = Field(gt=0, description="The feature's known size, metres.")
    sigma: float = Field(gt=0, description="Its uncertainty (one standard deviation), metres.")


PartAnnotation = Annotated[
    PointAnnotation | SymmetryAnnotation | DirectionAnnotation | LengthAnnotation, Field(discriminator="kind")
]


class KnownSize(_Model):
    """A known dimension, e.g. from the vehicle's make and model."""

    metres: float = Field(gt=0)
    sigma: float = Field(gt=0, description="One standard deviation, metres.")


class GroundModel(_Model):
    """The road under the vehicles, in camera coordinates: its normal (pointing up, toward the camera side)
    and the camera's height above it. KITTI's cameras sit about 1.65 m above a road whose normal is -y."""

    camera_height: float | None = Field(
        default=None, gt=0, description="Camera height above the road, metres; leave out when unknown.")
    camera_height_sigma: float = Field(default=0.05, gt=0, description="Its uncertainty, metres.")
    normal: Row3 | None = Field(
        default=None, description="Road normal in camera coordinates (x right, y down, z forward), pointing up; "
                                  "default [0, -1, 0] (a level camera).")
    camera_pitch_deg: float | None = Field(
        default=None, description="Instead of the normal: the camera's pitch above the road, degrees (nose up > 0).")
    camera_roll_deg: float | None = Field(
        default=None, description="Instead of the normal: the camera's roll, degrees (clockwise as seen > 0).")
    normal_sigma_deg: float = Field(default=1.0, gt=0, description="Uncertainty of the normal, degrees.")
    upright_sigma_deg: float = Field(
        default=2.0, gt=0, description="How far vehicles lean from the road normal (pitch and roll), degrees.")

    @field_validator("normal")
    @classmethod
    def _ensure_nonzero_normal(cls, normal: Row3 | None) -> Row3 | None:
        if normal is not None and float(np.linalg.norm(normal)) < 1e-9:
            raise ValueError(f"expected a non-zero road normal, got {list(normal)}")
        return normal

    @model_validator(mode="after")
    def _ensure_one_orientation(self) -> GroundModel:
        if self.normal is not None and (self.camera_pitch_deg is not None or self.camera_roll_deg is not None):
            raise ValueError("expected either 'normal' or 'camera_pitch_deg'/'camera_roll_deg', not both")
        return self


class CameraModel(_Model):
    """Intrinsics as ``K`` (3x3, optional OpenCV ``distortion``) or a KITTI-style ``P`` (3x4)."""

    K: tuple[Row3, Row3, Row3] | None = Field(default=None, description="Intrinsics, last row [0, 0, 1].")
    P: tuple[Row4, Row4, Row4] | None = Field(
        default=None, description="KITTI projection matrix K [I | t]; poses come out in the K = P[:, :3] frame."
    )
    distortion: list[float] | None = Field(
        default=None,
        description="OpenCV distortion coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tx, ty]]]]).",
    )

    @field_validator("K")
    @classmethod
    def _ensure_invertible_K(cls, K: tuple[Row3, Row3, Row3] | None) -> tuple[Row3, Row3, Row3] | None:
        if K is not None:
            _check_intrinsics(np.array(K))
        return K

    @field_validator("P")
    @classmethod
    def _ensure_invertible_P(cls, P: tuple[Row4, Row4, Row4] | None) -> tuple[Row4, Row4, Row4] | None:
        if P is not None:
            _check_intrinsics(np.array(P)[:, :3])
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


def _check_intrinsics(K: np.ndarray) -> None:
    if not np.allclose(K[2], [0.0, 0.0, 1.0], atol=1e-9):
        raise ValueError(f"expected the last row of K to be [0, 0, 1], got {K[2].tolist()}")
    scale = max(abs(K[0, 0]), abs(K[1, 1]), 1e-300)
    if abs(np.linalg.det(K)) <= 1e-12 * scale * scale:
        raise ValueError(f"expected an invertible K, got det(K) = {np.linalg.det(K):.3g} for K = {K.tolist()}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"expected positive focal lengths K[0][0] and K[1][1], got {K[0, 0]} and {K[1, 1]}")


class VehicleAnnotation(_Model):
    """One vehicle: its prototype (size class) and the parts clicked on it."""

    id: str = Field(min_length=1, description="Unique within its image.")
    prototype: str = Field(min_length=1, description="Size class in the priors file, e.g. 'Car', 'Mid Size Car'.")
    box2d: Row4 | None = Field(
        default=None, description="Annotated 2D box (x1, y1, x2, y2) in pixels, written to the KITTI file."
    )
    parts: list[PartAnnotation] = Field(default_factory=list)
    known_dimensions: dict[Literal[DIMENSION_AXES], KnownSize] | None = Field(  # type: ignore[valid-type]
        default=None, description="Dimensions known from elsewhere (e.g. the make and model): dx, dy, dz.")

    @field_validator("box2d")
    @classmethod
    def _ensure_box_order(cls, box: Row4 | None) -> Row4 | None:
        if box is not None and not (box[2] > box[0] and box[3] > box[1]):
            raise ValueError(f"expected x1 < x2 and y1 < y2, got {list(box)}")
        return box

    @field_validator("parts")
    @classmethod
    def _ensure_few_clicks(cls, parts: list[PartAnnotation]) -> list[PartAnnotation]:
        clicks = sum(1 if isinstance(part, PointAnnotation) else 2 for part in parts)
        if clicks > MAX_CLICKS_PER_VEHICLE:
            raise ValueError(f"expected at most {MAX_CLICKS_PER_VEHICLE} clicked points per vehicle "
                             f"(MAX_CLICKS_PER_VEHICLE), found {clicks} in {len(parts)} parts")
        return parts


class ImageAnnotation(_Model):
    """One image: its camera and its annotated vehicles."""

    id: str = Field(
        pattern=r"^[A-Za-z0-9][A-Za-z0-9_.\-]*$",
        description="Image id; names the KITTI label file, so letters, digits, '_', '.', '-' only.",
    )
    file: str | None = Field(default=None, description="Image path relative to the annotation file.")
    size: tuple[Annotated[int, Field(gt=0)], Annotated[int, Field(gt=0)]] | None = Field(
        default=None, description="(width, height) in pixels; projected boxes are clipped to it."
    )
    camera: CameraModel
    ground: GroundModel | None = Field(default=None, description="The road plane; enables the ground cues.")
    vehicles: list[VehicleAnnotation] = Field(default_factory=list)

    @field_validator("vehicles")
    @classmethod
    def _ensure_unique_vehicle_ids(cls, vehicles: list[VehicleAnnotation]) -> list[VehicleAnnotation]:
        _ensure_unique([v.id for v in vehicles], "vehicle")
        return vehicles


class AnnotationFile(_Model):
    """A ToosiCubix annotation file, version 1."""

    model_config = ConfigDict(title="ToosiCubix annotation file v1")

    toosicubix: Literal[1] = Field(description="Format version.")
    images: list[ImageAnnotation]

    @field_validator("images")
    @classmethod
    def _ensure_unique_image_ids(cls, images: list[ImageAnnotation]) -> list[ImageAnnotation]:
        _ensure_unique([im.id for im in images], "image")
        return images


def _ensure_unique(ids: list[str], what: str) -> None:
    first: dict[str, int] = {}
    for index, item in enumerate(ids):
        if item in first:
            raise ValueError(f"expected unique {what} ids, got {item!r} at [{first[item]}] and [{index}]")
        first[item] = index


def json_schema() -> dict[str, Any]:
    """The JSON Schema of the annotation file, as committed in ``schemas/annotations.schema.json``."""
    schema = AnnotationFile.model_json_schema()
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema}


_UNION_TAGS = {"point", "symmetry", "direction", "length"}


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


def _describe(error: dict[str, Any]) -> str:
    message = error["msg"].removeprefix("Value error, ")
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


def read_json(path: str | Path) -> Any:
    """Decoded JSON of a file.

    Raises
    ------
    InputFileError
        The file is missing, unreadable or not JSON (with line and column).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputFileError(path, [("$", f"cannot read the file: {exc.strerror or exc}")]) from None
    except UnicodeDecodeError as exc:
        raise InputFileError(path, [("$", f"expected UTF-8 JSON text: {exc.reason}")]) from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        message = f"not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}"
        raise InputFileError(path, [("$", message)]) from None


def parse_annotations(data: Any, source: str | Path = "<annotations>") -> AnnotationFile:
    """Validate already-decoded JSON data.

    Raises
    ------
    InputFileError
        Naming ``source`` and the JSON path of every problem.
    """
    return _validate(AnnotationFile, data, source)


def load_annotations(path: str | Path) -> AnnotationFile:
    """Read and validate an annotation file.

    Raises
    ------
    InputFileError
        The file is missing, not JSON, or not a valid annotation file v1.
    """
    return parse_annotations(read_json(path), path)


class PriorEntry(_Model):
    """The Gaussian size prior of one prototype, dimensions ordered (dx, dy, dz) = (length, width, height)."""

    mean: Row3 = Field(description="Mean (dx, dy, dz) in metres.")
    cov: tuple[Row3, Row3, Row3] = Field(description="Covariance of (dx, dy, dz), m^2; symmetric positive definite.")
    kitti_type: str = Field(pattern=r"^\S+$", description="Type written to KITTI label files, e.g. 'Car'.")
    n: int | None = Field(default=None, ge=0, description="Number of vehicles it was estimated from.")
    approximate: bool = Field(default=False, description="True when not estimated from measured data.")
    source: str = Field(min_length=1, description="Where the figures come from.")

    @field_validator("mean")
    @classmethod
    def _ensure_positive_mean(cls, mean: Row3) -> Row3:
        if min(mean) <= 0:
            raise ValueError(f"expected positive dimensions, got {list(mean)}")
        return mean

    @field_validator("cov")
    @classmethod
    def _ensure_spd(cls, cov: tuple[Row3, Row3, Row3]) -> tuple[Row3, Row3, Row3]:
        C = np.array(cov)
        if not np.allclose(C, C.T, rtol=1e-9, atol=1e-12):
            raise ValueError("expected a symmetric covariance")
        if np.linalg.eigvalsh(C).min() <= 0:
            raise ValueError(f"expected a positive definite covariance, eigenvalues {np.linalg.eigvalsh(C).tolist()}")
        return cov


class PriorsFile(_Model):
    """A table of size priors per prototype."""

    model_config = ConfigDict(title="ToosiCubix size priors v1")

    toosicubix_priors: Literal[1]
    description: str = ""
    prototypes: dict[str, PriorEntry] = Field(min_length=1)


def load_priors_file(path: str | Path) -> PriorsFile:
    """Read and validate a priors file.

    Raises
    ------
    InputFileError
    """
    return _validate(PriorsFile, read_json(path), path)


class SettingsFile(_Model):
    """Solver settings for ``toosicubix fit --config`` (written by ``toosicubix tune``)."""

    model_config = ConfigDict(title="ToosiCubix settings v1")

    toosicubix_settings: Literal[1]
    lambda_3d: float | None = Field(default=None, gt=0, description="Prior weight in the descent's 3D cost.")
    lambda_px: float | None = Field(default=None, gt=0, description="Prior weight in the pixel cost (px^2).")
    tuned: dict[str, Any] | None = Field(default=None, description="How the values were chosen (free form).")


def load_settings_file(path: str | Path) -> SettingsFile:
    """Read and validate a settings file.

    Raises
    ------
    InputFileError
    """
    return _validate(SettingsFile, read_json(path), path)


def parse_ground_block(data: Any, source: str | Path = "command line") -> GroundModel:
    """Validate a ground block given outside a file (e.g. by command-line options).

    Raises
    ------
    InputFileError
        Naming ``source`` and the field of every problem.
    """
    return _validate(GroundModel, data, source)
