"""ApolloCar3D keypoint files with their ground-truth poses, and the car models' extents.

The keypoint file is COCO-like (see :mod:`toosicubix.formats.coco`); each annotation also has ``pose`` =
``[roll, pitch, yaw, x, y, z]`` (radians, metres, camera frame) and ``category_id``, the car model. Frames (as
the data folder's README states them): ``R = Rz(yaw) Ry(pitch) Rx(roll)``, ``X_cam = R X_model + t`` with
``t`` the centre of the car model's box; model axes +z the car's front, +x its left, +y up. In the ToosiCubix
vehicle frame (X forward, Y left, Z up, origin at the bottom-face centre)::

    R_cam_vehicle = [R e_z, R e_x, R e_y]   (columns)
    t_cam_vehicle = t - (H / 2) R e_y
    dimensions    = (length, width_body, height)
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from toosicubix import fields
from toosicubix.errors import InputFileError
from toosicubix.fields import DistinctKeys, shown
from toosicubix.geometry import rot_x, rot_y, rot_z
from toosicubix.jsonfile import read_json


@dataclass(frozen=True)
class CarModel:
    """One ApolloCar3D car model: its name, type ('2x', '3x', 'SUV') and box extents in metres."""

    id: int
    name: str
    type: str
    length: float
    width_body: float
    height: float

    @property
    def dimensions(self) -> np.ndarray:
        """``(dx, dy, dz)`` = (length, width without mirrors, height): (3,)."""
        return np.array([self.length, self.width_body, self.height])


#: The smallest extent (length, width, height) of a car model, metres: no car is 10 cm long, wide or high, and the
#: learned keypoint positions are fractions of the extents (a length of 1e-300 made them infinite).
MIN_EXTENT_M = 0.1


def _key_path(key: str) -> str:
    """The JSON path of a top-level key: ``$.35``, or ``$['...']`` for a key that is not short and plain."""
    return f"$.{key}" if len(key) <= 40 and re.fullmatch(r"\w+", key) else f"$[{shown(key, 40)}]"


def read_car_models(path: str | Path) -> dict[int, CarModel]:
    """The car models of ``car_models.json`` by id.

    Keys are car model numbers by the field rules (:func:`toosicubix.fields.numeric_key`): ``"35"``, ``"035"`` and
    ``"٣٥"`` all mean model 35, and two keys that mean one model are an error naming both (one silently won).

    Raises
    ------
    InputFileError
        Naming the file and the JSON path: a key that is no model number, two keys for one model (or one key given
        twice), an extent that is no size in metres from :data:`MIN_EXTENT_M`, a name or type that is no string.
    """
    data = read_json(path, at_root=True, unique_keys=True)
    if not isinstance(data, dict) or not data:
        raise InputFileError(path, [("$", "expected an object of car models by id")])
    out = {}
    keys = DistinctKeys(path, "car model")
    for key, entry in data.items():
        where = _key_path(key)
        model_id = fields.numeric_key(key, path, where, what="a car model id")
        keys.add(model_id, key, where)
        if not isinstance(entry, dict):
            raise InputFileError(path, [(where, f"expected an object with length, width_body and height, got "
                                                f"{shown(entry)}")])
        values = {name: fields.metres(entry.get(name), path, f"{where}.{name}", low=MIN_EXTENT_M)
                  for name in ("length", "width_body", "height")}
        text = {}
        for name, default in (("name", key), ("type", "")):
            value = entry.get(name, default)
            if value != "" and (not isinstance(value, str) or not fields.passes(fields.identifier, value)):
                raise InputFileError(path, [(f"{where}.{name}", f"expected a string of at most {fields.MAX_ID_LENGTH} "
                                                                f"characters (no control characters), got "
                                                                f"{shown(value)}")])
            text[name] = value
        out[model_id] = CarModel(model_id, text["name"], text["type"], **values)
    return out


def pose_to_vehicle(pose: np.ndarray, dimensions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R_cam_vehicle (3, 3), t_cam_vehicle (3,))`` of an ApolloCar3D ``pose`` (6,) = roll, pitch, yaw, x, y, z
    for a car of ``dimensions`` (3,) (only the height is used: the origin moves to the bottom centre)."""
    roll, pitch, yaw = pose[:3]
    R_cam_model = rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)
    R_cam_vehicle = R_cam_model[:, [2, 0, 1]]
    t_cam_vehicle = np.asarray(pose[3:], dtype=float) - 0.5 * dimensions[2] * R_cam_model[:, 1]
    return R_cam_vehicle, t_cam_vehicle


@dataclass(frozen=True)
class ApolloCar:
    """One labelled car with its ground truth.

    Attributes
    ----------
    id : the annotation id, as a string (the vehicle id an import gives it)
    model : its car model
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,) bottom-face centre, camera frame
    box2d : (4,) x1, y1, x2, y2 pixels (from ``bbox``)
    keypoints : (66, 3) x, y, v
    source : file and JSON path
    """

    id: str
    model: CarModel
    R_cam_vehicle: np.ndarray
    t_cam_vehicle: np.ndarray
    box2d: np.ndarray
    keypoints: np.ndarray
    source: str


@dataclass(frozen=True)
class ApolloImage:
    """One image: its id (the file name's stem), file name and cars."""

    id: str
    file_name: str
    cars: tuple[ApolloCar, ...]


#: The largest pose translation, metres (ApolloCar3D's cars stand within 100 m or so of the camera).
MAX_DISTANCE_M = 10_000.0
#: The largest pose angle, radians (any angle is one within +-pi; a number far beyond is no angle).
MAX_ANGLE = 100.0


def read_apollocar3d(path: str | Path, car_models: dict[int, CarModel]) -> list[ApolloImage]:
    """Every image of an ApolloCar3D keypoint file with its cars' ground truth, in file order.

    Every field goes through the field rules (:mod:`toosicubix.fields`): ids strings or integers of sane length,
    ``category_id`` a car model number (``"35"`` or 35), pixels within the annotation file's bounds, the pose's
    angles within :data:`MAX_ANGLE` radians and its translation within :data:`MAX_DISTANCE_M`.

    Raises
    ------
    InputFileError
        Naming the file and the JSON path: a missing or malformed pose, bbox or keypoints, an unknown car model, an
        image id given twice or two images whose file names give one image id.
    """
    data = read_json(path, at_root=True)
    if not isinstance(data, dict) or not isinstance(data.get("images"), list) \
            or not isinstance(data.get("annotations"), list):
        raise InputFileError(path, [("$", "expected a COCO object with 'images' and 'annotations' lists")])
    names: dict[object, str] = {}
    stems: dict[str, str] = {}  # image id (the file name's stem) -> where
    for i, im in enumerate(data["images"]):
        where = f"$.images[{i}]"
        if not isinstance(im, dict) or "id" not in im or not isinstance(im.get("file_name"), str):
            raise InputFileError(path, [(where, "expected an object with 'id' and 'file_name'")])
        image_id = fields.identifier(im["id"], path, f"{where}.id", what="an image id")
        if image_id in names:
            raise InputFileError(path, [(f"{where}.id", f"image id {shown(image_id)} given twice")])
        stem = Path(im["file_name"]).stem
        if stem in stems:
            raise InputFileError(path, [(f"{where}.file_name", f"this image and the one at {stems[stem]} both get the "
                                                               f"image id {shown(stem)} (the file name's stem)")])
        names[image_id], stems[stem] = im["file_name"], where
    cars: dict[object, list[ApolloCar]] = {k: [] for k in names}
    for i, ann in enumerate(data["annotations"]):
        where = f"$.annotations[{i}]"
        if not isinstance(ann, dict):
            raise InputFileError(path, [(where, "expected an object")])
        image_id = fields.identifier(ann.get("image_id"), path, f"{where}.image_id", what="an image id")
        if image_id not in names:
            raise InputFileError(path, [(f"{where}.image_id", f"no image has id {shown(image_id, 40)}")])
        category = fields.numeric_key(ann.get("category_id"), path, f"{where}.category_id", what="a car model id")
        model = car_models.get(category)
        if model is None:
            raise InputFileError(path, [(f"{where}.category_id",
                                         f"car model {shown(ann.get('category_id'), 20)} is not in the car models "
                                         "file")])
        car_id = fields.identifier(ann.get("id"), path, f"{where}.id", what="an annotation id")
        pose = _numbers(ann, "pose", (6,), path, where)
        if np.abs(pose[:3]).max() > MAX_ANGLE or np.abs(pose[3:]).max() > MAX_DISTANCE_M:
            expected = f"roll, pitch, yaw within +-{MAX_ANGLE:g} rad and x, y, z within +-{MAX_DISTANCE_M:g} m"
            raise InputFileError(path, [(f"{where}.pose", f"expected {expected}, got {pose.tolist()}")])
        box = _numbers(ann, "bbox", (4,), path, where)
        keypoints = _numbers(ann, "keypoints", (-1,), path, where).reshape(-1, 3)
        if not (np.isin(keypoints[:, 2], (0, 1, 2)).all() and np.abs(keypoints[:, :2]).max() <= fields.MAX_PIXEL
                and np.abs(box).max() <= fields.MAX_PIXEL and box[2] > 0 and box[3] > 0):
            raise InputFileError(path, [(where, f"expected bbox [x, y, w, h] (w, h > 0) and keypoints x, y, v (v in 0, "
                                                f"1, 2) within +-{fields.MAX_PIXEL:.0f} pixels")])
        R, t = pose_to_vehicle(pose, model.dimensions)
        cars[image_id].append(ApolloCar(
            id=str(car_id), model=model, R_cam_vehicle=R, t_cam_vehicle=t,
            box2d=np.array([box[0], box[1], box[0] + box[2], box[1] + box[3]]), keypoints=keypoints,
            source=f"{path} {where}"))
    return [ApolloImage(Path(names[k]).stem, names[k], tuple(cars[k])) for k in names]


def _numbers(obj: dict, key: str, shape: tuple[int, ...], path: str | Path, where: str) -> np.ndarray:
    value = obj.get(key)
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError, OverflowError):  # OverflowError: an integer beyond float's range
        arr = np.zeros(0)
    ok = arr.ndim == 1 and arr.size > 0 and np.all(np.isfinite(arr)) and (shape[0] < 0 or arr.shape == shape)
    if shape[0] < 0:
        ok = ok and arr.size % 3 == 0
    if not ok:
        expected = f"{shape[0]} numbers" if shape[0] > 0 else "x, y, v triplets"
        raise InputFileError(path, [(f"{where}.{key}", f"expected {expected}, got {shown(value)}")])
    return arr


#: The prototype (size prior) of each car-model type: the bundled priors nearest to each type's CAD extents.
PROTOTYPE_OF_TYPE = {"2x": "Car", "3x": "Sedan", "SUV": "SUV"}


def prototype_of(car_type: str, prototype_of_type: dict[str, str] | None = None) -> str:
    """The prototype a car of this car-model type gets (``prototype_of_type``, default :data:`PROTOTYPE_OF_TYPE`);
    'Car' for a type it does not name."""
    return (PROTOTYPE_OF_TYPE if prototype_of_type is None else prototype_of_type).get(car_type, "Car")


def keypoints_hidden(car: ApolloCar, seen_from: list[tuple[str, ...]]) -> int | None:
    """How many of ``car``'s labelled keypoints its ground-truth pose turns away from the camera: none of the faces
    it is seen from turned to the camera. ``seen_from``: per keypoint index, those faces (learned, e.g. the bundled
    ``apollocar3d-66`` mapping's); an empty entry never counts. Every keypoint of ApolloCar3D is labelled as seen.
    None when the car has not one keypoint per entry of ``seen_from`` (a file with other keypoints)."""
    from toosicubix.parts.learned import facing_camera, turned_away

    if len(car.keypoints) != len(seen_from):
        return None
    facing = facing_camera(car.R_cam_vehicle, car.t_cam_vehicle, car.model.dimensions)
    return sum(turned_away(seen_from[j], facing) for j in np.flatnonzero(car.keypoints[:, 2] > 0))


def keypoints_off_rays(car: ApolloCar, K: np.ndarray, at: list[np.ndarray | None]) -> float | None:
    """The RMS distance (metres) of ``car``'s labelled keypoints from their pinhole rays through ``K`` (3, 3; lens
    distortion, which ApolloCar3D's cameras do not have, is not undone, as in :func:`keypoint_samples`), each put at
    its typical place on the ground-truth cuboid: ``at`` per keypoint index, fractions of the dimensions (learned,
    e.g. the bundled ``apollocar3d-66`` mapping's), None where unknown. More than
    :data:`toosicubix.parts.learned.CONTRADICTION_M` says the pose contradicts the clicks. None when the car has
    not one keypoint per entry of ``at``, or no labelled keypoint with a place."""
    from toosicubix.parts.learned import KeypointSample, offset_from_ray

    if len(car.keypoints) != len(at):
        return None
    K_inv = np.linalg.inv(K)
    squares = []
    for j in np.flatnonzero(car.keypoints[:, 2] > 0):
        if at[j] is None:
            continue
        ray = K_inv @ np.array([car.keypoints[j, 0], car.keypoints[j, 1], 1.0])
        sample = KeypointSample("", "", car.id, ray, car.R_cam_vehicle, car.t_cam_vehicle, car.model.dimensions)
        squares.append(float(np.sum(offset_from_ray(sample, at[j]) ** 2)))
    return float(np.sqrt(np.mean(squares))) if squares else None


def car_models_file(keypoints: str | Path, car_models: str | Path | None = None) -> Path:
    """``car_models`` if given, else the ``car_models.json`` beside the keypoint file."""
    return Path(car_models) if car_models is not None else Path(keypoints).parent / "car_models.json"


def keypoint_samples(images: list[ApolloImage], names: list[str], K_of: dict[str, np.ndarray],
                     prototype_of_type: dict[str, str] | None = None) -> list:
    """Every labelled keypoint (v > 0) of the images as a :class:`toosicubix.parts.learned.KeypointSample`.

    Parameters
    ----------
    names : the keypoint names by index
    K_of : (3, 3) intrinsics per image id
    prototype_of_type : car-model type -> prototype (default :data:`PROTOTYPE_OF_TYPE`; others 'Car')

    Raises
    ------
    InputFileError
        A car with another number of keypoints than ``names``, naming the file and its JSON path.
    """
    from toosicubix.parts.learned import KeypointSample

    out = []
    for im in images:
        K_inv = np.linalg.inv(K_of[im.id])
        for car in im.cars:
            if len(car.keypoints) != len(names):
                file, _, where = car.source.rpartition(" $")
                expected = f"expected {3 * len(names)} numbers (x, y, v for {len(names)} keypoints)"
                raise InputFileError(file, [(f"${where}.keypoints", f"{expected}, got {car.keypoints.size}")])
            prototype = prototype_of(car.model.type, prototype_of_type)
            for j in np.flatnonzero(car.keypoints[:, 2] > 0):
                ray = K_inv @ np.array([car.keypoints[j, 0], car.keypoints[j, 1], 1.0])
                out.append(KeypointSample(prototype, names[j], f"{im.id}/{car.id}", ray, car.R_cam_vehicle,
                                          car.t_cam_vehicle, car.model.dimensions))
    return out
