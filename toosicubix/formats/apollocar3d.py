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

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from toosicubix.errors import InputFileError
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


def read_car_models(path: str | Path) -> dict[int, CarModel]:
    """The car models of ``car_models.json`` by id.

    Raises
    ------
    InputFileError
        Naming the file and the JSON path of a missing or non-positive field.
    """
    data = read_json(path, at_root=True)
    if not isinstance(data, dict) or not data:
        raise InputFileError(path, [("$", "expected an object of car models by id")])
    out = {}
    for key, entry in data.items():
        where = f"$.{key}"
        if not key.isdigit() or not isinstance(entry, dict):
            raise InputFileError(path, [(where, "expected a car model id (digits) with an object")])
        values = {}
        for name in ("length", "width_body", "height"):
            v = entry.get(name)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not np.isfinite(v) or v <= 0:
                raise InputFileError(path, [(f"{where}.{name}", f"expected a positive number, got {v!r:.40}")])
            values[name] = float(v)
        out[int(key)] = CarModel(int(key), str(entry.get("name", key)), str(entry.get("type", "")), **values)
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


def read_apollocar3d(path: str | Path, car_models: dict[int, CarModel]) -> list[ApolloImage]:
    """Every image of an ApolloCar3D keypoint file with its cars' ground truth, in file order.

    Raises
    ------
    InputFileError
        Naming the file and the JSON path: a missing or malformed pose, bbox or keypoints, an unknown car model.
    """
    data = read_json(path, at_root=True)
    if not isinstance(data, dict) or not isinstance(data.get("images"), list) \
            or not isinstance(data.get("annotations"), list):
        raise InputFileError(path, [("$", "expected a COCO object with 'images' and 'annotations' lists")])
    names: dict[object, str] = {}
    for i, im in enumerate(data["images"]):
        if not isinstance(im, dict) or "id" not in im or not isinstance(im.get("file_name"), str):
            raise InputFileError(path, [(f"$.images[{i}]", "expected an object with 'id' and 'file_name'")])
        names[im["id"]] = im["file_name"]
    cars: dict[object, list[ApolloCar]] = {k: [] for k in names}
    for i, ann in enumerate(data["annotations"]):
        where = f"$.annotations[{i}]"
        if not isinstance(ann, dict):
            raise InputFileError(path, [(where, "expected an object")])
        if ann.get("image_id") not in names:
            raise InputFileError(path, [(f"{where}.image_id", f"no image has id {ann.get('image_id')!r:.40}")])
        model = car_models.get(ann.get("category_id"))  # type: ignore[arg-type]
        if model is None:
            raise InputFileError(path, [(f"{where}.category_id",
                                         f"car model {ann.get('category_id')!r:.20} is not in the car models file")])
        pose = _numbers(ann, "pose", (6,), path, where)
        box = _numbers(ann, "bbox", (4,), path, where)
        keypoints = _numbers(ann, "keypoints", (-1,), path, where).reshape(-1, 3)
        R, t = pose_to_vehicle(pose, model.dimensions)
        cars[ann["image_id"]].append(ApolloCar(
            id=str(ann.get("id")), model=model, R_cam_vehicle=R, t_cam_vehicle=t,
            box2d=np.array([box[0], box[1], box[0] + box[2], box[1] + box[3]]), keypoints=keypoints,
            source=f"{path} {where}"))
    return [ApolloImage(Path(names[k]).stem, names[k], tuple(cars[k])) for k in names]


def _numbers(obj: dict, key: str, shape: tuple[int, ...], path: str | Path, where: str) -> np.ndarray:
    value = obj.get(key)
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        arr = np.zeros(0)
    ok = arr.ndim == 1 and arr.size > 0 and np.all(np.isfinite(arr)) and (shape[0] < 0 or arr.shape == shape)
    if shape[0] < 0:
        ok = ok and arr.size % 3 == 0
    if not ok:
        expected = f"{shape[0]} numbers" if shape[0] > 0 else "x, y, v triplets"
        raise InputFileError(path, [(f"{where}.{key}", f"expected {expected}, got {value!r:.60}")])
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
