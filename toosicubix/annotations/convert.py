"""The annotation file (v1) to the numpy model of :mod:`toosicubix.model`, and back.

``load_images`` reads, validates and converts a file; ``images_from_schema`` converts a parsed one. The inverse,
``document_json`` (and ``image_json``, ``vehicle_json``, ``part_json`` for pieces of it), writes the model as the
annotation file's JSON for every part kind: reading what it writes gives the same model.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from toosicubix.annotations import schema as schemas
from toosicubix.camera import Camera
from toosicubix.geometry import rot_x, rot_z
from toosicubix.model import LEVEL_NORMAL, GroundBlock, GroundOverride, GroundPlane, Image, Part, Vehicle
from toosicubix.vocabulary import KINDS

# -- file -> model ---------------------------------------------------------------------------------------------------


def part_from_schema(p: Any, json_path: str) -> Part:
    """The :class:`Part` of one parsed annotation (an instance of a class of ``schemas.PART_ANNOTATIONS``); its
    fields are named by the kind's vocabulary entry."""
    kind = KINDS[p.kind]
    uv = np.array([getattr(p, key) for key in kind.clicks], dtype=float)
    known = tuple(float(getattr(p, key)) for key in kind.known) if kind.known else None
    extra = {key: getattr(p, key) for key, _ in kind.fields_extra}
    rows = {key: np.array(extra[key], dtype=float) for key in ("at", "spread") if key in extra}
    return Part(p.kind, getattr(p, kind.name_field), uv, json_path, known,  # type: ignore[arg-type]
                visible=bool(extra.get("visible", True)), **rows)


def ground_from_schema(g: schemas.GroundModel) -> GroundPlane:
    """The :class:`GroundPlane` of an image's ground block."""
    if g.normal is not None:
        normal = np.array(g.normal, dtype=float)
        normal /= np.linalg.norm(normal)
    else:
        pitch = np.deg2rad(g.camera_pitch_deg or 0.0)
        roll = np.deg2rad(g.camera_roll_deg or 0.0)
        normal = rot_z(-roll) @ rot_x(-pitch) @ LEVEL_NORMAL
    return GroundPlane(normal=normal, normal_sigma=float(np.deg2rad(g.normal_sigma_deg)),
                       camera_height=g.camera_height, camera_height_sigma=g.camera_height_sigma,
                       upright_sigma=float(np.deg2rad(g.upright_sigma_deg)))


def block_from_schema(g: schemas.GroundModel) -> GroundBlock:
    """The :class:`GroundBlock` of an image's ground block: its fields as the file states them."""
    fields = g.model_dump()
    if fields["normal"] is not None:
        fields["normal"] = tuple(fields["normal"])
    return GroundBlock(**fields)


def camera_from_schema(cam: schemas.CameraModel, size: tuple[int, int] | None) -> Camera:
    """The :class:`Camera` of an annotation's camera block."""
    distortion = None if cam.distortion is None else np.array(cam.distortion, dtype=float)
    if cam.P is not None:
        return Camera.from_P(np.array(cam.P, dtype=float), image_size=size, distortion=distortion)
    return Camera(K=np.array(cam.K, dtype=float), distortion=distortion, image_size=size)


def images_from_schema(doc: schemas.AnnotationFile) -> list[Image]:
    """Convert a validated annotation file into :class:`Image` objects."""
    return [image_from_schema(im, i) for i, im in enumerate(doc.images)]


def image_from_schema(im: schemas.ImageAnnotation, index: int) -> Image:
    """Convert one validated image, the ``index``-th of its file, into an :class:`Image`."""
    ip = f"$.images[{index}]"
    vehicles = tuple(
        Vehicle(
            id=v.id, prototype=v.prototype,
            box2d=None if v.box2d is None else np.array(v.box2d, dtype=float),
            parts=tuple(part_from_schema(p, f"{ip}.vehicles[{j}].parts[{k}]") for k, p in enumerate(v.parts)),
            json_path=f"{ip}.vehicles[{j}]",
            known_dimensions={axis: (k.metres, k.sigma) for axis, k in (v.known_dimensions or {}).items()},
            track=v.track,
        )
        for j, v in enumerate(im.vehicles)
    )
    return Image(id=im.id, file=im.file, camera=camera_from_schema(im.camera, im.size),
                 vehicles=vehicles, json_path=ip,
                 ground=None if im.ground is None else ground_from_schema(im.ground),
                 ground_block=None if im.ground is None else block_from_schema(im.ground),
                 sequence=im.sequence, frame=im.frame)


def load_images(path: str | Path) -> list[Image]:
    """Read, validate and convert an annotation file.

    Raises
    ------
    toosicubix.errors.InputFileError
    """
    return images_from_schema(schemas.load_annotations(path))


def ground_with(block: GroundBlock | None, override: GroundOverride, source: str = "ground options"
                ) -> tuple[GroundBlock, GroundPlane]:
    """An image's ground ``block`` (None: none) with ``override``'s fields set on it (a normal given drops the
    block's pitch and roll, a pitch or roll its normal), validated, and the plane the solver reads from it.

    Raises
    ------
    toosicubix.errors.InputFileError
        When the resulting block is invalid (e.g. a zero normal), naming ``source`` and the field.
    """
    fields = override.fields()
    if "normal" in fields:
        fields.setdefault("camera_pitch_deg", None)
        fields.setdefault("camera_roll_deg", None)
    if "camera_pitch_deg" in fields or "camera_roll_deg" in fields:
        fields.setdefault("normal", None)
    parsed = schemas.parse_ground_block({**(block.to_json() if block is not None else {}), **fields}, source)
    return block_from_schema(parsed), ground_from_schema(parsed)


def with_ground(images: list[Image], override: GroundOverride | None) -> list[Image]:
    """The images with their ground block's fields replaced by ``override``'s (:func:`ground_with`), for a whole
    file; an image without a block gets one from the override and the defaults.

    Raises
    ------
    toosicubix.errors.InputFileError
        When the resulting block is invalid (e.g. a negative height), naming the field.
    """
    if not override:
        return images
    out = []
    for im in images:
        block, plane = ground_with(im.ground_block, override)
        out.append(replace(im, ground=plane, ground_block=block))
    return out


# -- model -> file ---------------------------------------------------------------------------------------------------


def _pixel(row: np.ndarray, decimals: int | None) -> list[float]:
    if decimals is None:
        return [float(v) for v in row]  # full precision: exact clicks stay exact
    return [round(float(v), decimals) for v in row]


def part_json(part: Part, decimals: int | None = None) -> dict[str, Any]:
    """One annotation as the file has it, e.g. ``{"kind": "point", "part": "wheel-front-left", "xy": [x, y]}``.

    Parameters
    ----------
    decimals : round the pixels to this many decimals; None keeps them exactly
    """
    kind = KINDS[part.kind]
    out: dict[str, Any] = {"kind": part.kind, kind.name_field: part.name}
    out.update({key: _pixel(row, decimals) for key, row in zip(kind.clicks, part.uv, strict=True)})
    if kind.known:
        if part.known is None:
            raise ValueError(f"{part.json_path}: a {part.kind} annotation needs its known size")
        out.update({key: float(value) for key, value in zip(kind.known, part.known, strict=True)})
    for key, _ in kind.fields_extra:  # a keypoint's or plate's typical position; ``visible`` only when False
        if key == "visible":
            if not part.visible:
                out[key] = False
            continue
        row = getattr(part, key)
        if row is None:
            raise ValueError(f"{part.json_path}: a {part.kind} annotation needs its {key!r}")
        out[key] = [float(v) for v in row]
    return out


def vehicle_json(vehicle: Vehicle, decimals: int | None = None) -> dict[str, Any]:
    """One vehicle as the file has it (``box2d`` as stored, the parts' pixels rounded to ``decimals``)."""
    out: dict[str, Any] = {"id": vehicle.id, "prototype": vehicle.prototype}
    if vehicle.track is not None:
        out["track"] = vehicle.track
    if vehicle.box2d is not None:
        out["box2d"] = [float(v) for v in vehicle.box2d]
    out["parts"] = [part_json(p, decimals) for p in vehicle.parts]
    if vehicle.known_dimensions:
        out["known_dimensions"] = {axis: {"metres": float(m), "sigma": float(s)}
                                   for axis, (m, s) in vehicle.known_dimensions.items()}
    return out


def camera_json(camera: Camera) -> dict[str, Any]:
    """The camera block: ``P`` (3x4, KITTI style) when the camera has an offset ``t_cam_rect``, else ``K``;
    ``distortion`` when it has one."""
    if np.any(camera.t_cam_rect != 0):
        out: dict[str, Any] = {"P": np.hstack([camera.K, (camera.K @ camera.t_cam_rect)[:, None]]).tolist()}
    else:
        out = {"K": np.asarray(camera.K, dtype=float).tolist()}
    if camera.distortion is not None:
        out["distortion"] = np.asarray(camera.distortion, dtype=float).tolist()
    return out


def image_json(image: Image, decimals: int | None = None) -> dict[str, Any]:
    """One image as the file has it."""
    out: dict[str, Any] = {"id": image.id}
    if image.file is not None:
        out["file"] = image.file
    if image.sequence is not None:
        out["sequence"], out["frame"] = image.sequence, image.frame
    if image.camera.image_size is not None:
        out["size"] = list(image.camera.image_size)
    out["camera"] = camera_json(image.camera)
    if image.ground_block is not None:
        out["ground"] = image.ground_block.to_json()
    out["vehicles"] = [vehicle_json(v, decimals) for v in image.vehicles]
    return out


def document_json(images: list[Image], decimals: int | None = None) -> dict[str, Any]:
    """The whole annotation file (v1) of ``images``."""
    return {"toosicubix": schemas.SCHEMA_VERSION, "images": [image_json(im, decimals) for im in images]}
