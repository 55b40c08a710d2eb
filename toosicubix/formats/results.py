"""``results.json``: what ``toosicubix fit`` found for every vehicle, with full rotations.

Layout (keys may be added; these keep their names and meanings)::

    {"toosicubix_results": 1, "generator": "toosicubix 0.1.0", "annotations": "...", "settings": {...},
     "images": [{"id": "000123", "camera": {"K": [[...]], "t_cam_rect": [...], "image_size": [w, h]},
                 "vehicles": [{"id": "3", "status": "ok", "error": null, "prototype": "Car",
                               "R_cam_vehicle": [[...]], "t_cam_vehicle": [...], "dimensions": [...], ...}]}],
     "summary": {...}}

``t_cam_vehicle`` is in the frame where the image's ``K`` applies; ``X_rect = X_cam - t_cam_rect``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from toosicubix.formats import FormatError, json_field, json_numbers, read_json

RESULTS_VERSION = 1
RESULTS_FILENAME = "results.json"
#: Where ``fit`` writes and ``eval`` reads when no folder is given (relative to the working directory).
DEFAULT_OUTPUT_DIR = "toosicubix-out"


@dataclass(frozen=True)
class VehicleResult:
    """One vehicle's fit. Pose fields are None when ``status == "failed"``.

    Attributes
    ----------
    R_cam_vehicle : (3, 3) or None
    t_cam_vehicle : (3,) or None, bottom-face centre in the camera frame of ``K``
    dimensions : (3,) or None, ``(dx, dy, dz)`` metres
    box2d : (4,) or None, ``(x1, y1, x2, y2)`` pixels
    details : every other key of the vehicle's JSON object, as read or to be written
    """

    id: str
    status: str
    error: str | None
    prototype: str
    R_cam_vehicle: np.ndarray | None = None
    t_cam_vehicle: np.ndarray | None = None
    dimensions: np.ndarray | None = None
    box2d: np.ndarray | None = None
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == "ok"


@dataclass(frozen=True)
class ImageResult:
    """One image's fits and the camera they are expressed in.

    Attributes
    ----------
    K : (3, 3)
    t_cam_rect : (3,) zero unless the camera came from a KITTI ``P``
    image_size : (width, height) or None
    ground : the road plane used or estimated (``{"normal": [...], "camera_height": h, ...}``), or None
    """

    id: str
    K: np.ndarray
    t_cam_rect: np.ndarray
    image_size: tuple[int, int] | None
    vehicles: list[VehicleResult]
    ground: dict[str, Any] | None = None


def _array(value: np.ndarray | None) -> Any:
    return None if value is None else np.asarray(value, dtype=float).tolist()


def vehicle_to_json(v: VehicleResult) -> dict[str, Any]:
    """The JSON object of one vehicle, fixed keys first."""
    out: dict[str, Any] = {
        "id": v.id, "status": v.status, "error": v.error, "prototype": v.prototype,
        "R_cam_vehicle": _array(v.R_cam_vehicle), "t_cam_vehicle": _array(v.t_cam_vehicle),
        "dimensions": _array(v.dimensions), "box2d": _array(v.box2d),
    }
    out.update(v.details)
    return out


def image_to_json(im: ImageResult) -> dict[str, Any]:
    """The JSON object of one image."""
    return {
        "id": im.id,
        "camera": {"K": _array(im.K), "t_cam_rect": _array(im.t_cam_rect),
                   "image_size": list(im.image_size) if im.image_size else None},
        **({"ground": im.ground} if im.ground is not None else {}),
        "vehicles": [vehicle_to_json(v) for v in im.vehicles],
    }


def results_to_json(images: list[ImageResult], header: dict[str, Any] | None = None) -> dict[str, Any]:
    """The whole document: ``header`` keys, then ``images`` and a ``summary`` of counts."""
    n_ok = sum(v.ok for im in images for v in im.vehicles)
    n_all = sum(len(im.vehicles) for im in images)
    doc: dict[str, Any] = {"toosicubix_results": RESULTS_VERSION, **(header or {})}
    doc["images"] = [image_to_json(im) for im in images]
    doc["summary"] = {"images": len(images), "vehicles": n_all, "ok": n_ok, "failed": n_all - n_ok}
    return doc


def write_results_stream(handle: IO[str], images: Iterable[ImageResult], header: dict[str, Any] | None = None,
                         on_image: Callable[[ImageResult], None] | None = None) -> dict[str, int]:
    """Write the document of :func:`results_to_json` to ``handle`` one image at a time, byte for byte as
    :func:`dumps` would (so a batch never holds every image's results); return its summary.
    ``on_image`` is called with each image after it is written.

    Raises
    ------
    ValueError
        A NaN or an infinity (not JSON); what was written is then incomplete.
    """
    head = json.dumps({"toosicubix_results": RESULTS_VERSION, **(header or {})}, indent=1, allow_nan=False)
    handle.write(head[:-2] + ',\n "images": [')
    summary = {"images": 0, "vehicles": 0, "ok": 0, "failed": 0}
    for im in images:
        text = json.dumps(image_to_json(im), indent=1, allow_nan=False)  # strings hold no raw newline
        handle.write(("\n  " if summary["images"] == 0 else ",\n  ") + text.replace("\n", "\n  "))
        summary["images"] += 1
        summary["vehicles"] += len(im.vehicles)
        summary["ok"] += sum(v.ok for v in im.vehicles)
        if on_image is not None:
            on_image(im)
    summary["failed"] = summary["vehicles"] - summary["ok"]
    handle.write(("\n ]" if summary["images"] else "]") + ',\n "summary": '
                 + json.dumps(summary, indent=1).replace("\n", "\n ") + "\n}\n")
    return summary


def dumps(doc: dict[str, Any]) -> str:
    """JSON text with NaN and infinities refused (they are not JSON)."""
    return json.dumps(doc, indent=1, allow_nan=False) + "\n"


def read_results(path: str | Path) -> list[ImageResult]:
    """Read a ``results.json`` written by ``toosicubix fit``.

    Raises
    ------
    FormatError
        Not JSON, or a required key missing or malformed (the message gives its JSON path).
    """
    path = Path(path)
    doc = read_json(path)
    if not isinstance(doc, dict) or doc.get("toosicubix_results") != RESULTS_VERSION:
        raise FormatError(path, f"$.toosicubix_results: expected {RESULTS_VERSION} (a toosicubix results file)")
    images = []
    for i, im in enumerate(json_field(doc, "images", list, path, "$")):
        where = f"$.images[{i}]"
        camera = json_field(im, "camera", dict, path, where)
        K = json_numbers(camera.get("K"), (3, 3), path, f"{where}.camera.K")
        t_cam_rect = json_numbers(camera.get("t_cam_rect", [0.0, 0.0, 0.0]), (3,), path, f"{where}.camera.t_cam_rect")
        size = camera.get("image_size")
        vehicles = []
        for j, v in enumerate(json_field(im, "vehicles", list, path, where)):
            vw = f"{where}.vehicles[{j}]"
            status = json_field(v, "status", str, path, vw)
            posed = status == "ok"
            details = {k: val for k, val in v.items() if k not in _FIXED_KEYS}
            vehicles.append(VehicleResult(
                id=str(json_field(v, "id", str, path, vw)), status=status, error=v.get("error"),
                prototype=str(v.get("prototype", "")),
                R_cam_vehicle=json_numbers(v.get("R_cam_vehicle"), (3, 3), path, f"{vw}.R_cam_vehicle")
                if posed else None,
                t_cam_vehicle=json_numbers(v.get("t_cam_vehicle"), (3,), path, f"{vw}.t_cam_vehicle")
                if posed else None,
                dimensions=json_numbers(v.get("dimensions"), (3,), path, f"{vw}.dimensions") if posed else None,
                box2d=json_numbers(v["box2d"], (4,), path, f"{vw}.box2d") if v.get("box2d") is not None else None,
                details=details,
            ))
        images.append(ImageResult(
            id=str(json_field(im, "id", str, path, where)), K=K, t_cam_rect=t_cam_rect,
            image_size=tuple(size) if size else None, vehicles=vehicles,  # type: ignore[arg-type]
            ground=im.get("ground"),
        ))
    return images


_FIXED_KEYS = {"id", "status", "error", "prototype", "R_cam_vehicle", "t_cam_vehicle", "dimensions", "box2d"}


