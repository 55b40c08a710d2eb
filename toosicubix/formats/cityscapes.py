"""Cityscapes 3D ground truth: ``<city>_<seq>_<frame>_gtBbox3d.json`` files.

Layout (see ``shared/data/cityscapes3d/CONVENTIONS.md``)::

    {"imgWidth": 2048, "imgHeight": 1024,
     "sensor": {"sensor_T_ISO_8855": [[...], [...], [...]], "fx": ..., "fy": ..., "u0": ..., "v0": ...,
                "baseline": ...},
     "objects": [{"2d": {"modal": [x, y, w, h], "amodal": [x, y, w, h]},
                  "3d": {"center": [x, y, z], "dimensions": [l, w, h], "rotation": [qw, qx, qy, qz],
                         "type": "Mid Size Car", "format": "CRS_ISO8855"},
                  "occlusion": 0.2, "truncation": 0.0, "instanceId": 26014, "label": "car", "score": 1.0}],
     "ignore": [{"2d": [x, y, w, h], "label": "...", "instanceId": ...}]}

Frames: ``ego`` is the ISO 8855 vehicle frame V (x forward, y left, z up) where boxes are given;
``sensor`` is the camera frame C with the same axes; ``cam`` is ours (x right, y down, z forward),
``p_cam = R_CAM_SENSOR @ p_sensor``, where ``K`` applies. ``sensor_T_ISO_8855 = [R | t]`` maps ego to
sensor: ``p_sensor = R p_ego + t``. A box's ``center`` is its geometric centre (not the bottom);
its axes (forward, left, up) are ours, so ``R_cam_vehicle = R_CAM_SENSOR @ R_sensor_ego @ R_ego_vehicle``
with ``R_ego_vehicle`` from the scalar-first quaternion, rotations in full (pitch and roll included).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from toosicubix.annotations.schema import check_intrinsics
from toosicubix.camera import Camera
from toosicubix.errors import FormatError
from toosicubix.formats.kitti import MAX_DISTANCE_M, MAX_PIXEL, MAX_SIZE_M
from toosicubix.jsonfile import json_field, json_numbers, read_json

#: Sensor axes (x forward, y left, z up) to camera axes (x right, y down, z forward); ``get_K_multiplier()``
#: in cityscapesScripts.
R_CAM_SENSOR = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def quaternion_to_matrix(q_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion given scalar first, (4,) -> (3, 3). The input is normalised."""
    w, x, y, z = np.asarray(q_wxyz, dtype=float) / np.linalg.norm(q_wxyz)
    return np.array([
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ])


def xywh_to_xyxy(box_xywh: np.ndarray) -> np.ndarray:
    """``[x, y, w, h]`` (top-left corner and size) to ``(x1, y1, x2, y2)``, (4,)."""
    x, y, w, h = np.asarray(box_xywh, dtype=float)
    return np.array([x, y, x + w, y + h])


@dataclass(frozen=True)
class CityscapesCamera:
    """The ``sensor`` block.

    Attributes
    ----------
    R_sensor_ego : (3, 3) and t_sensor_ego : (3,)
        ``sensor_T_ISO_8855``: ``p_sensor = R_sensor_ego @ p_ego + t_sensor_ego``, metres
    fx, fy, u0, v0 : intrinsics in pixels, applying to ``cam`` coordinates
    baseline : stereo baseline in metres, or None
    """

    R_sensor_ego: np.ndarray
    t_sensor_ego: np.ndarray
    fx: float
    fy: float
    u0: float
    v0: float
    baseline: float | None = None

    @property
    def K(self) -> np.ndarray:
        """(3, 3) ``[[fx, 0, u0], [0, fy, v0], [0, 0, 1]]``."""
        return np.array([[self.fx, 0.0, self.u0], [0.0, self.fy, self.v0], [0.0, 0.0, 1.0]])

    @property
    def R_cam_ego(self) -> np.ndarray:
        """(3, 3) ego axes to camera axes (x right, y down, z forward)."""
        return R_CAM_SENSOR @ self.R_sensor_ego

    @property
    def t_cam_ego(self) -> np.ndarray:
        """(3,) ego origin in camera coordinates, metres."""
        return R_CAM_SENSOR @ self.t_sensor_ego

    def camera(self, image_size: tuple[int, int] | None = None) -> Camera:
        """The pinhole camera of ``K`` (no distortion, ``t_cam_rect`` zero)."""
        return Camera(K=self.K, image_size=image_size)


@dataclass(frozen=True)
class CityscapesBox:
    """One entry of ``objects``.

    Attributes
    ----------
    index : position in the file's ``objects`` list (0-based)
    label : Cityscapes class, e.g. 'car'
    type : the ``3d.type`` sub-type, e.g. 'Mid Size Car' ('' when absent)
    instance_id : ``instanceId`` or None
    center_ego : (3,) geometric centre of the cuboid in the ego frame, metres
    dimensions : (3,) ``(l, w, h)`` = ``(dx, dy, dz)``, metres
    quaternion_ego : (4,) unit quaternion ``(w, x, y, z)`` turning box axes into ego axes
    box2d_amodal : (4,) ``(x1, y1, x2, y2)`` pixels, the full projected box clipped to the image
    box2d_modal : (4,) ``(x1, y1, x2, y2)`` pixels, the visible part (the amodal box when absent)
    occlusion, truncation : fractions in [0, 1], or None when absent
    score : float or None
    """

    index: int
    label: str
    type: str
    instance_id: int | None
    center_ego: np.ndarray
    dimensions: np.ndarray
    quaternion_ego: np.ndarray
    box2d_amodal: np.ndarray
    box2d_modal: np.ndarray
    occlusion: float | None
    truncation: float | None
    score: float | None

    @property
    def R_ego_vehicle(self) -> np.ndarray:
        """(3, 3) box axes (forward, left, up) in ego coordinates."""
        return quaternion_to_matrix(self.quaternion_ego)

    def pose_cam(self, camera: CityscapesCamera) -> tuple[np.ndarray, np.ndarray]:
        """The box as a toosicubix pose in the camera frame of ``camera.K``.

        Returns
        -------
        R_cam_vehicle : (3, 3)
        t_cam_vehicle : (3,) centre of the bottom face, metres
        """
        R_cam_vehicle = camera.R_cam_ego @ self.R_ego_vehicle
        centre_cam = camera.R_cam_ego @ self.center_ego + camera.t_cam_ego
        return R_cam_vehicle, centre_cam - 0.5 * self.dimensions[2] * R_cam_vehicle[:, 2]


@dataclass(frozen=True)
class CityscapesIgnore:
    """One entry of ``ignore``: a 2D region without a 3D box.

    Attributes
    ----------
    index : position in the ``ignore`` list
    box2d : (4,) ``(x1, y1, x2, y2)`` pixels
    """

    index: int
    label: str
    instance_id: int | None
    box2d: np.ndarray


@dataclass(frozen=True)
class CityscapesAnnotation:
    """One gtBbox3d file.

    Attributes
    ----------
    image_size : (width, height) or None
    """

    camera: CityscapesCamera
    objects: list[CityscapesBox]
    ignore: list[CityscapesIgnore]
    image_size: tuple[int, int] | None


def read_gtbbox3d(path: str | Path) -> CityscapesAnnotation:
    """Read a Cityscapes 3D ``*_gtBbox3d.json`` file.

    Raises
    ------
    FormatError
        Not JSON, or a key missing or malformed: the message names the file and the JSON path
        (``$.objects[3].3d.dimensions``).
    """
    path = Path(path)
    doc = read_json(path)
    return parse_gtbbox3d(doc, path)


def parse_gtbbox3d(doc: Any, path: str | Path = "<gtBbox3d>") -> CityscapesAnnotation:
    """Turn the parsed JSON of a gtBbox3d file into a :class:`CityscapesAnnotation` (see :func:`read_gtbbox3d`)."""
    path = Path(path)
    if not isinstance(doc, dict):
        raise FormatError(path, "$: expected a JSON object (a Cityscapes 3D gtBbox3d file)")
    sensor = json_field(doc, "sensor", dict, path, "$")
    T = json_numbers(json_field(sensor, "sensor_T_ISO_8855", list, path, "$.sensor"), (3, 4), path,
                     "$.sensor.sensor_T_ISO_8855")
    intr = {k: float(json_numbers(json_field(sensor, k, (int, float), path, "$.sensor"), (), path, f"$.sensor.{k}"))
            for k in ("fx", "fy", "u0", "v0")}
    baseline = sensor.get("baseline")
    _check_sensor(T, intr, path)
    camera = CityscapesCamera(R_sensor_ego=T[:, :3], t_sensor_ego=T[:, 3], baseline=_optional_float(
        baseline, path, "$.sensor.baseline"), **intr)
    size = None
    if "imgWidth" in doc and "imgHeight" in doc:
        for key in ("imgWidth", "imgHeight"):
            if not 0 < float(json_numbers(doc[key], (), path, f"$.{key}")) <= MAX_PIXEL:
                raise FormatError(path, f"$.{key}: expected a size from 1 to {MAX_PIXEL:g} pixels, got {doc[key]!r}")
        size = (int(doc["imgWidth"]), int(doc["imgHeight"]))
    objects = [_box(obj, i, path) for i, obj in enumerate(json_field(doc, "objects", list, path, "$"))]
    ignore = []
    for i, entry in enumerate(doc.get("ignore") or []):
        where = f"$.ignore[{i}]"
        if not isinstance(entry, dict):
            raise FormatError(path, f"{where}: expected an object")
        box = json_numbers(json_field(entry, "2d", list, path, where), (4,), path, f"{where}.2d")
        ignore.append(CityscapesIgnore(index=i, label=str(entry.get("label", "")),
                                       instance_id=_optional_int(entry.get("instanceId"), path, f"{where}.instanceId"),
                                       box2d=xywh_to_xyxy(box)))
    return CityscapesAnnotation(camera=camera, objects=objects, ignore=ignore, image_size=size)


def _box(obj: Any, i: int, path: Path) -> CityscapesBox:
    where = f"$.objects[{i}]"
    if not isinstance(obj, dict):
        raise FormatError(path, f"{where}: expected an object")
    box3d = json_field(obj, "3d", dict, path, where)
    centre = json_numbers(json_field(box3d, "center", list, path, f"{where}.3d"), (3,), path, f"{where}.3d.center")
    dims = json_numbers(json_field(box3d, "dimensions", list, path, f"{where}.3d"), (3,), path,
                        f"{where}.3d.dimensions")
    if np.any(dims <= 0.0):
        raise FormatError(path, f"{where}.3d.dimensions: expected positive [l, w, h], got {dims.tolist()}")
    if dims.max() > MAX_SIZE_M:
        raise FormatError(path, f"{where}.3d.dimensions: expected at most {MAX_SIZE_M:g} m (no road vehicle is "
                                f"larger), got {dims.tolist()}")
    if np.abs(centre).max() > MAX_DISTANCE_M:
        raise FormatError(path, f"{where}.3d.center: expected within {MAX_DISTANCE_M:g} m, got {centre.tolist()}")
    q = json_numbers(json_field(box3d, "rotation", list, path, f"{where}.3d"), (4,), path, f"{where}.3d.rotation")
    if abs(float(np.linalg.norm(q)) - 1.0) > 1e-3:
        raise FormatError(path, f"{where}.3d.rotation: expected a unit quaternion [w, x, y, z], "
                                f"got norm {np.linalg.norm(q):.6g}")
    fmt = box3d.get("format", "CRS_ISO8855")
    if fmt != "CRS_ISO8855":
        raise FormatError(path, f"{where}.3d.format: expected 'CRS_ISO8855' (boxes in the ego frame), got {fmt!r}")
    box2d = json_field(obj, "2d", dict, path, where)
    # Current files hold "amodal" (and "modal"); older ones "bbox" (amodal) and "bboxVis" (modal).
    amodal_key = "amodal" if "amodal" in box2d else "bbox"
    modal_key = "modal" if "modal" in box2d else ("bboxVis" if "bboxVis" in box2d else amodal_key)
    amodal = json_numbers(json_field(box2d, amodal_key, list, path, f"{where}.2d"), (4,), path,
                          f"{where}.2d.{amodal_key}")
    modal = json_numbers(box2d.get(modal_key), (4,), path, f"{where}.2d.{modal_key}")
    for key, box in ((amodal_key, amodal), (modal_key, modal)):
        if np.abs(box).max() > MAX_PIXEL:
            raise FormatError(path, f"{where}.2d.{key}: expected pixels within +-{MAX_PIXEL:g}, got {box.tolist()}")
    return CityscapesBox(
        index=i, label=str(json_field(obj, "label", str, path, where)), type=str(box3d.get("type", "")),
        instance_id=_optional_int(obj.get("instanceId"), path, f"{where}.instanceId"),
        center_ego=centre, dimensions=dims, quaternion_ego=q / np.linalg.norm(q),
        box2d_amodal=xywh_to_xyxy(amodal), box2d_modal=xywh_to_xyxy(modal),
        occlusion=_optional_float(obj.get("occlusion"), path, f"{where}.occlusion"),
        truncation=_optional_float(obj.get("truncation"), path, f"{where}.truncation"),
        score=_optional_float(obj.get("score"), path, f"{where}.score"),
    )


def _check_sensor(T: np.ndarray, intr: dict[str, float], path: Path) -> None:
    """The camera must be one: a rotation (3, 3) and a bounded translation in ``T`` (3, 4), and intrinsics that
    pass :func:`toosicubix.annotations.schema.check_intrinsics`.

    Raises
    ------
    FormatError
        Naming ``$.sensor`` or ``$.sensor.sensor_T_ISO_8855``.
    """
    R = T[:, :3]
    if not (np.allclose(R @ R.T, np.eye(3), atol=1e-3) and np.linalg.det(R) > 0) or np.abs(T[:, 3]).max() > 100.0:
        raise FormatError(path, f"$.sensor.sensor_T_ISO_8855: expected [R | t] with R a rotation and |t| <= 100 m, "
                                f"got {T.tolist()}")
    K = np.array([[intr["fx"], 0.0, intr["u0"]], [0.0, intr["fy"], intr["v0"]], [0.0, 0.0, 1.0]])
    try:
        check_intrinsics(K)
    except ValueError as exc:
        raise FormatError(path, f"$.sensor: fx, fy, u0, v0 are not a camera: {exc}") from None


def _optional_float(value: Any, path: Path, where: str) -> float | None:
    return None if value is None else float(json_numbers(value, (), path, where))


def _optional_int(value: Any, path: Path, where: str) -> int | None:
    if value is None:
        return None
    number = float(json_numbers(value, (), path, where))
    if number != int(number):
        raise FormatError(path, f"{where}: expected an integer, got {value!r}")
    return int(number)


__all__ = [
    "R_CAM_SENSOR", "CityscapesAnnotation", "CityscapesBox", "CityscapesCamera", "CityscapesIgnore",
    "parse_gtbbox3d", "quaternion_to_matrix", "read_gtbbox3d", "xywh_to_xyxy",
]
