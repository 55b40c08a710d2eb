"""Fitted cuboids as ASAM OpenLABEL 1.0.0 JSON.

Layout::

    {"openlabel": {
      "metadata": {"schema_version": "1.0.0", "annotator": "toosicubix X", ...},
      "coordinate_systems": {"camera1": {"type": "sensor_cs", "parent": "", "children": []}},
      "streams": {"camera1": {"type": "camera", "description": ..., "stream_properties": {"intrinsics_pinhole":
                  {"width_px", "height_px", "camera_matrix_3x4": [12], "distortion_coeffs_1xN": [...]}}}},
      "objects": {"0": {"name": "<image id>/<vehicle id>", "type": "<prototype>", "coordinate_system": "camera1",
                        "frame_intervals": [{"frame_start": f, "frame_end": f}]}},
      "frames": {"0": {"frame_properties": {"streams": {"camera1": {"uri": "<image file>"}}},
                       "objects": {"0": {"object_data": {"cuboid": [...], "point2d": [...], "bbox": [...],
                                                         "text": [...]}}}}}}}

- One frame per image, in file order, one stream (and sensor coordinate system) per distinct camera. A frame of a
  sequence has its ``sequence`` and ``frame`` number among its ``frame_properties``.
- One object per vehicle of an image on its own, named ``<image id>/<vehicle id>``; one per track, named by the
  track, over the frames that hold it (``frame_intervals``, gaps where the track is absent), each frame's
  ``object_data`` with its pose there and the ``text`` entries ``vehicle`` (the frame's vehicle id) and
  ``pose_from`` (``clicks``, ``box`` or ``interpolated``, as in results.json).
- Intrinsics are written as ``camera_matrix_3x4`` and ``distortion_coeffs_1xN``, as the standard's own example
  does (its schema says ``camera_matrix``; see FORMATS.md). For a KITTI ``P`` the matrix is ``[K | 0]``: the
  cuboids are in the frame where ``K`` applies (camera 2), as in results.json.
- ``cuboid.val`` = ``[x, y, z, qx, qy, qz, qw, dx, dy, dz]``: the box **centre** in the camera frame
  (x right, y down, z forward), ``t_cam_vehicle + R_cam_vehicle (0, 0, dz/2)``; the scalar-last unit
  quaternion of ``R_cam_vehicle`` (``qw >= 0``); the dimensions (length, width, height) along the vehicle's
  own axes X forward, Y left, Z up (ISO 8855 like). The uncertainty (``results.json``'s ``sigma`` and
  ``confidence``), ``rms_px`` and ``ambiguous`` are the cuboid's attributes.
- Every click is a ``point2d``, pixels as clicked: the cuboid vocabulary's parts (point, symmetry, direction,
  length) named by their keypoint (:mod:`toosicubix.parts.keypoints`), after them a ``keypoint`` part by its
  name with ``at`` and ``spread`` (``vec``) and ``visible`` (``boolean``) as attributes, and a ``plate`` as
  ``plate-<face>-a`` and ``plate-<face>-b`` (as the flat vocabulary names a plate's ends) with ``metres`` and
  ``sigma`` (``num``), ``at`` and ``spread`` as attributes. A part kind with no such form is left out and said
  once per kind, with how many parts on how many vehicles. The annotated box is a ``bbox`` ``[cx, cy, w, h]``;
  ``status``, ``prototype`` and (for failed vehicles, which get no cuboid) ``error`` are ``text`` entries.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from toosicubix import __version__
from toosicubix.formats.fitted import FittedImage
from toosicubix.formats.results import VehicleResult
from toosicubix.parts.keypoints import KeypointProblem, keypoints_from_parts

SCHEMA_VERSION = "1.0.0"


def cuboid_val(R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, dimensions: np.ndarray) -> list[float]:
    """OpenLABEL's 10-value cuboid of a fitted vehicle.

    Parameters
    ----------
    R_cam_vehicle : (3, 3) rotation, vehicle frame (X forward, Y left, Z up) to camera frame
    t_cam_vehicle : (3,) bottom-face centre in the camera frame, metres
    dimensions : (3,) ``(dx, dy, dz)`` metres

    Returns
    -------
    [x, y, z, qx, qy, qz, qw, dx, dy, dz] : box centre (camera frame), scalar-last quaternion with qw >= 0,
    dimensions
    """
    R = np.asarray(R_cam_vehicle, dtype=float)
    d = np.asarray(dimensions, dtype=float)
    centre_cam = np.asarray(t_cam_vehicle, dtype=float) + R @ np.array([0.0, 0.0, d[2] / 2.0])
    q_xyzw = Rotation.from_matrix(R).as_quat()
    if q_xyzw[3] < 0:
        q_xyzw = -q_xyzw
    return [float(v) for v in (*centre_cam, *q_xyzw, *d)]


def _camera_key(image: FittedImage) -> tuple:
    dist = image.camera.distortion
    return (tuple(np.round(image.camera.K, 9).ravel()), None if dist is None else tuple(dist), image.size)


def _stream(image: FittedImage) -> dict[str, Any]:
    K = image.camera.K
    pinhole: dict[str, Any] = {}
    if image.size is not None:
        pinhole["width_px"], pinhole["height_px"] = int(image.size[0]), int(image.size[1])
    pinhole["camera_matrix_3x4"] = [float(v) for v in np.hstack([K, np.zeros((3, 1))]).ravel()]
    if image.camera.distortion is not None:
        pinhole["distortion_coeffs_1xN"] = [float(v) for v in image.camera.distortion]
    return {"type": "camera", "description": "pinhole camera, x right, y down, z forward; OpenCV distortion order",
            "stream_properties": {"intrinsics_pinhole": pinhole}}


def _cuboid_attributes(v: VehicleResult) -> dict[str, Any]:
    """The cuboid's uncertainty, confidence, rms and ambiguity as OpenLABEL attributes (absent values left out)."""
    num, vec, boolean = [], [], []
    if v.sigma is not None:
        for key, name in (("yaw_deg", "sigma_yaw_deg"), ("pitch_deg", "sigma_pitch_deg"),
                          ("roll_deg", "sigma_roll_deg"), ("depth_m", "sigma_depth_m"),
                          ("depth_rel", "sigma_depth_rel"), ("scale_rel", "sigma_scale_rel")):
            value = getattr(v.sigma, key)
            if math.isfinite(value):
                num.append({"name": name, "val": float(value)})
        for key, name in (("dimensions", "sigma_dimensions_m"), ("position_m", "sigma_position_m")):
            values = getattr(v.sigma, key)
            if values and all(math.isfinite(x) for x in values):
                vec.append({"name": name, "val": [float(x) for x in values]})
    for key in ("confidence", "rms_px"):
        value = getattr(v, key)
        if value is not None:
            num.append({"name": key, "val": float(value)})
    boolean.append({"name": "ambiguous", "val": bool(v.ambiguous)})
    out: dict[str, Any] = {}
    for key, items in (("num", num), ("vec", vec), ("boolean", boolean)):
        if items:
            out[key] = items
    return out


#: The part kinds the flat keypoint vocabulary names click by click (:func:`keypoints_from_parts`).
FLAT_KINDS = ("point", "symmetry", "direction", "length")


def _attributes(num: dict[str, Any], vec: dict[str, Any], boolean: dict[str, Any]) -> dict[str, Any]:
    """OpenLABEL ``attributes`` of the given values (None left out)."""
    out: dict[str, Any] = {}
    for key, values, cast in (("num", num, float), ("vec", vec, lambda v: [float(x) for x in v]),
                              ("boolean", boolean, bool)):
        items = [{"name": name, "val": cast(value)} for name, value in values.items() if value is not None]
        if items:
            out[key] = items
    return out


def _point2d(name: str, xy: Any, cam: str, attributes: dict[str, Any] | None = None) -> dict[str, Any]:
    point: dict[str, Any] = {"name": name, "val": [float(xy[0]), float(xy[1])], "coordinate_system": cam}
    if attributes:
        point["attributes"] = attributes
    return point


def _clicks(parts: list[dict[str, Any]], cam: str, where: str, warnings: list[str],
            formless: Counter) -> list[dict[str, Any]]:
    """The ``point2d`` entries of one vehicle's parts (see the module); counts parts of kinds without one in
    ``formless`` (kind -> parts) and warns of flat-vocabulary parts it cannot name (their clicks left out)."""
    flat = [p for p in parts if p["kind"] in FLAT_KINDS]
    try:
        out = [_point2d(kp, xy, cam) for kp, xy in keypoints_from_parts(flat)]
    except KeypointProblem as exc:
        warnings.append(f"{where}: {exc}: its clicks are left out")
        out = []
    for part in parts:
        kind = part["kind"]
        if kind == "keypoint":
            attributes = _attributes({}, {"at": part.get("at"), "spread": part.get("spread")},
                                     {"visible": part.get("visible", True)})
            out.append(_point2d(part["name"], part["xy"], cam, attributes))
        elif kind == "plate":
            attributes = _attributes({"metres": part.get("metres"), "sigma": part.get("sigma")},
                                     {"at": part.get("at"), "spread": part.get("spread")}, {})
            out += [_point2d(f"plate-{part['face']}-{end}", part[end], cam, attributes) for end in ("a", "b")]
        elif kind not in FLAT_KINDS:
            formless[kind] += 1
    return out


def _extend(intervals: list[dict[str, int]], f: int) -> None:
    """Add frame ``f`` (after every frame in them: a track is in a frame once) to an object's ``frame_intervals``."""
    if intervals[-1]["frame_end"] == f - 1:
        intervals[-1]["frame_end"] = f
    else:
        intervals.append({"frame_start": f, "frame_end": f})


def openlabel_document(images: list[FittedImage], name: str = "") -> tuple[dict[str, Any], list[str]]:
    """The OpenLABEL 1.0.0 document of fitted images, and warnings: clicks the flat vocabulary cannot name (per
    vehicle), part kinds without an OpenLABEL form (once per kind, with counts)."""
    streams: dict[str, Any] = {}
    stream_of: dict[tuple, str] = {}
    objects: dict[str, Any] = {}
    frames: dict[str, Any] = {}
    warnings: list[str] = []
    formless: Counter = Counter()  # kind -> parts left out
    formless_vehicles: Counter = Counter()  # kind -> vehicles with such parts
    track_uid: dict[str, str] = {}  # track -> its object's uid
    for f, image in enumerate(images):
        key = _camera_key(image)
        if key not in stream_of:
            stream_of[key] = f"camera{len(stream_of) + 1}"
            streams[stream_of[key]] = _stream(image)
        cam = stream_of[key]
        frame_objects: dict[str, Any] = {}
        for fv in image.vehicles:
            v = fv.result
            if v.track in track_uid:  # one object for the whole track, its frames added as they come
                uid = track_uid[v.track]
                _extend(objects[uid]["frame_intervals"], f)
            else:
                uid = str(len(objects))
                objects[uid] = {"name": v.track or f"{image.id}/{v.id}", "type": v.prototype,
                                "coordinate_system": cam, "frame_intervals": [{"frame_start": f, "frame_end": f}]}
                if v.track is not None:
                    track_uid[v.track] = uid
            data: dict[str, Any] = {}
            if v.ok:
                cuboid = {"name": "cuboid", "val": cuboid_val(v.R_cam_vehicle, v.t_cam_vehicle, v.dimensions),
                          "coordinate_system": cam}
                attributes = _cuboid_attributes(v)
                if attributes:
                    cuboid["attributes"] = attributes
                data["cuboid"] = [cuboid]
            before = Counter(formless)
            clicks = _clicks(fv.parts, cam, f"image {image.id!r}, vehicle {v.id!r}", warnings, formless)
            formless_vehicles.update(kind for kind in formless if formless[kind] > before[kind])
            if clicks:
                data["point2d"] = clicks
            if fv.box2d is not None:
                x1, y1, x2, y2 = fv.box2d
                data["bbox"] = [{"name": "box2d", "val": [(x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1],
                                 "coordinate_system": cam}]
            text = [{"name": "status", "val": v.status}, {"name": "prototype", "val": v.prototype}]
            if v.track is not None:  # which vehicle of the frame it is, and what set its pose there
                text.append({"name": "vehicle", "val": v.id})
                if v.pose_from is not None:
                    text.append({"name": "pose_from", "val": v.pose_from})
            if v.error:
                text.append({"name": "error", "val": v.error})
            data["text"] = text
            frame_objects[uid] = {"object_data": data}
        properties: dict[str, Any] = {"streams": {cam: {"uri": image.file or image.id}}}
        if image.sequence is not None:  # frame_properties takes further properties (the schema's own words)
            properties.update(sequence=image.sequence, frame=image.frame)
        frame: dict[str, Any] = {"frame_properties": properties}
        if frame_objects:
            frame["objects"] = frame_objects
        frames[str(f)] = frame
    for kind, n in sorted(formless.items()):
        warnings.append(f"part kind {kind!r} has no OpenLABEL form here: {n} parts on {formless_vehicles[kind]} "
                        "vehicles left out")
    metadata = {"schema_version": SCHEMA_VERSION, "annotator": f"toosicubix {__version__}",
                "comment": "cuboid val = [x, y, z, qx, qy, qz, qw, dx, dy, dz]: box centre in the camera frame "
                           "(x right, y down, z forward), scalar-last quaternion of R_cam_vehicle, dimensions along "
                           "the vehicle's X forward, Y left, Z up"}
    if name:
        metadata["name"] = name
    doc = {"openlabel": {
        "metadata": metadata,
        "coordinate_systems": {cam: {"type": "sensor_cs", "parent": "", "children": []} for cam in streams},
        "streams": streams,
        "objects": objects,
        "frames": frames,
        "frame_intervals": [{"frame_start": 0, "frame_end": len(images) - 1}] if images else [],
    }}
    return doc, warnings
