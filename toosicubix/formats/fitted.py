"""A fit output folder joined with the annotation file it was fitted from: what the exporters write out.

``results.json`` holds the poses (in the camera frame of each image's ``K``); the annotation file holds the
clicks, the image files and sizes and the lens distortion. ``results.json`` names the annotation file and
its SHA-256; a file that changed since the fit is refused.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from toosicubix.annotations.convert import camera_from_schema
from toosicubix.annotations.schema import load_annotations
from toosicubix.camera import Camera
from toosicubix.errors import FormatError, InputFileError
from toosicubix.formats.results import RESULTS_FILENAME, VehicleResult, read_results
from toosicubix.jsonfile import read_json


@dataclass(frozen=True)
class FittedVehicle:
    """One vehicle: its fit (pose fields None unless ``result.ok``) and its clicks as part objects (JSON)."""

    result: VehicleResult
    parts: list[dict[str, Any]]
    box2d: list[float] | None = None  # the annotated box, if any


@dataclass(frozen=True)
class FittedImage:
    """One image: its file, size and camera (with distortion), its vehicles in file order, and the sequence and frame
    number it is a frame of (None for an image on its own)."""

    id: str
    file: str | None
    size: tuple[int, int] | None
    camera: Camera
    vehicles: list[FittedVehicle] = field(default_factory=list)
    sequence: str | None = None
    frame: int | None = None


def load_fitted(out_dir: str | Path, annotations: str | Path | None = None) -> tuple[list[FittedImage], Path]:
    """Read ``OUT/results.json`` and its annotation file.

    Parameters
    ----------
    out_dir : a ``toosicubix fit`` output folder
    annotations : the annotation file; default: the one ``results.json`` names

    Returns
    -------
    (images, annotation file path)

    Raises
    ------
    FormatError
        No or a malformed results.json, the annotation file missing, changed since the fit, or without an
        image or vehicle of the results.
    """
    results_path = Path(out_dir) / RESULTS_FILENAME
    if not results_path.is_file():
        raise FormatError(results_path, "missing: give a `toosicubix fit` output folder")
    header = read_json(results_path)
    results = read_results(results_path)
    if annotations is None:
        named = header.get("annotations") if isinstance(header, dict) else None
        if not isinstance(named, str):
            raise FormatError(results_path, "$.annotations: missing; give the annotation file with --annotations")
        annotations = Path(named)
    annotations = Path(annotations)
    if not annotations.is_file():
        raise FormatError(results_path, f"$.annotations: the annotation file {str(annotations)!r} is not there; "
                                        "give it with --annotations")
    expected = header.get("annotations_sha256")
    if expected and hashlib.sha256(annotations.read_bytes()).hexdigest() != expected:
        raise FormatError(annotations, f"changed since the fit (its SHA-256 differs from {results_path}'s "
                                       "annotations_sha256): fit it again")
    try:
        doc = load_annotations(annotations)
    except InputFileError as exc:
        raise FormatError(annotations, str(exc)) from None
    by_id = {im.id: im for im in doc.images}
    images = []
    for i, im_result in enumerate(results):
        im = by_id.get(im_result.id)
        if im is None:
            raise FormatError(results_path, f"$.images[{i}]: image {im_result.id!r} is not in {annotations}")
        vehicles_by_id = {v.id: v for v in im.vehicles}
        vehicles = []
        for j, v_result in enumerate(im_result.vehicles):
            v = vehicles_by_id.get(v_result.id)
            if v is None:
                raise FormatError(results_path, f"$.images[{i}].vehicles[{j}]: vehicle {v_result.id!r} is not in "
                                                f"image {im.id!r} of {annotations}")
            parts = [p.model_dump(mode="json") for p in v.parts]
            vehicles.append(FittedVehicle(v_result, parts, None if v.box2d is None else list(v.box2d)))
        images.append(FittedImage(im.id, im.file, None if im.size is None else (im.size[0], im.size[1]),
                                  camera_from_schema(im.camera, im.size), vehicles, im.sequence, im.frame))
    return images, annotations
