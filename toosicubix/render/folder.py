"""Render a ``toosicubix fit`` output folder: one PNG per image, the overlay with its bird's-eye view beside it.

Inputs: ``OUT/results.json`` (the fits), the annotation file it names (``$.annotations``; the clicks, the
cameras with their lens distortion, and each image's ``file`` relative to the annotation file), the image
files themselves when they can be found (else a blank canvas of the image's size), and optionally ground
truth opened as ``toosicubix eval`` opens it.

Sequences: the bird's-eye view of a frame draws the positions of each of its tracks over every frame of the
sequence that results.json holds (:func:`track_paths`, a few numbers per vehicle per frame, collected once before
the pictures are drawn one at a time), and a tracked vehicle keeps its track's colour in every frame
(:func:`track_colours`).

Every PNG is written atomically (temporary file, then rename); the same inputs give byte-identical files.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import math
import re
import struct
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from toosicubix.annotations.convert import load_images
from toosicubix.camera import Camera
from toosicubix.errors import InputError
from toosicubix.formats.atomic import atomic_write_bytes, remove_stale_temporaries
from toosicubix.formats.results import RESULTS_FILENAME, ImageResult, VehicleResult, read_results
from toosicubix.model import Image
from toosicubix.render.overlay import (
    PALETTE_BGR,
    DrawnCuboid,
    DrawnTrack,
    DrawnVehicle,
    OverlayOptions,
    birds_eye_side,
    blank_canvas,
    compose,
    draw_birds_eye,
    draw_overlay,
    line_thickness,
    text_scale,
)
from toosicubix.render.palette import class_colours

#: ``--only`` choices: images with a failed vehicle, an ambiguous one, one not well determined (yaw or depth
#: sigma beyond ``toosicubix validate``'s default thresholds), or a misfit (``fit --misfit-level``).
ONLY_CHOICES = ("failed", "ambiguous", "uncertain", "misfit")
#: Where ``render`` writes inside the fit folder unless told otherwise.
#: The default picture folder is OUT's sibling ``<OUT>-render``: never inside OUT, which ``fit`` replaces as a
#: whole and which holds only what ``fit`` wrote.
DEFAULT_RENDER_SUFFIX = "-render"
#: PNG compression: 1 is fast and still about half the raw size; the README picture uses 9.
PNG_COMPRESSION = 1
#: The largest image render draws, per side and in all (pixels): a larger image (its annotated size, or a blank
#: canvas of it) is drawn scaled down to fit both, with a warning; an image file beyond them is not decoded (its
#: header says its size). 16,384 px is what a PNG encoder and OpenCV's drawing handle without trouble on any
#: machine; 50 Mpx (an 8,192 x 6,144 photo) keeps a picture's memory (canvas, its fill layer, the bird's-eye panel,
#: the PNG) near 0.6 GB. The annotation file allows sides of 10^6 px: such a canvas, unbounded, needed 4-4.5 GB at
#: 40,000 x 40,000 or 1 x 1,000,000, and 2.7 TiB at 10^6 x 10^6.
MAX_CANVAS_SIDE = 16_384
MAX_CANVAS_PIXELS = 50_000_000
#: The largest image file read (bytes): a 50 Mpx photo as a PNG of noise is 150 MB.
MAX_IMAGE_FILE_BYTES = 256 * 1024 * 1024


class RenderInputError(InputError):
    """An input that cannot be rendered (missing results or annotation file); the message names the file."""

    def __init__(self, message: str):
        super().__init__(None, [(None, message)])


@dataclass(frozen=True)
class RenderOptions:
    """How to render a folder.

    Attributes
    ----------
    overlay : what each overlay shows
    only : one of :data:`ONLY_CHOICES`, or None for every image
    png_compression : zlib level 0-9 of the written PNGs
    video : also write each sequence's rendered frames as ``<sequence>.mp4`` (:mod:`toosicubix.render.video`)
    frame_rate : frames per second of those videos (the sequences' own, as ``fit --frame-rate``)
    """

    overlay: OverlayOptions = field(default_factory=OverlayOptions)
    only: str | None = None
    png_compression: int = PNG_COMPRESSION
    video: bool = False
    frame_rate: float = 10.0


@dataclass
class RenderSummary:
    """What :func:`render_folder` did.

    Attributes
    ----------
    written : the PNG files, in results order
    blank : ids of images drawn on a blank canvas
    refused : ids of images not drawn: too large a canvas even scaled (:func:`canvas_scale`)
    skipped : images left out by ``only``
    warnings : one line each (missing image files, images without ground truth, a changed annotation file)
    out_dir : where the PNGs went
    videos : the sequences' videos (``RenderOptions.video``)
    """

    written: list[Path] = field(default_factory=list)
    blank: list[str] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)
    skipped: int = 0
    warnings: list[str] = field(default_factory=list)
    out_dir: Path | None = None
    videos: list[Path] = field(default_factory=list)


def encode_png(image_bgr: np.ndarray, compression: int = PNG_COMPRESSION) -> bytes:
    """PNG bytes of a (H, W, 3) uint8 BGR image; OpenCV writes no time stamp or other varying metadata.

    Below level 9: zlib's run-length strategy and, where OpenCV offers the choice (``IMWRITE_PNG_FILTER``),
    the single 'sub' row filter: on a KITTI overlay over a photo that encoded in 28 ms instead of 48 ms (level
    1 with the defaults), the file 4 % smaller. Level 9 keeps the defaults (smallest files, for documentation).
    """
    params = [cv2.IMWRITE_PNG_COMPRESSION, int(compression)]
    if compression < 9:
        params += [cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]
        if hasattr(cv2, "IMWRITE_PNG_FILTER"):
            params += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB]
    ok, buffer = cv2.imencode(".png", image_bgr, params)
    if not ok:  # pragma: no cover - OpenCV fails only on invalid arrays
        raise ValueError("OpenCV could not encode the PNG")
    return buffer.tobytes()


#: How a tracked vehicle's label says what determined its pose in a frame (results.json's ``pose_from``).
POSE_FROM_SHORT = {"clicks": "clicks", "box": "box", "interpolated": "interp."}


def vehicle_label(v: VehicleResult) -> str:
    """The short text beside a fitted cuboid: id, prototype, dimensions, depth, yaw sigma, confidence,
    AMBIGUOUS or MISFIT (its residuals failed the chi-square test, ``fit --misfit-level``) when so, IMPLAUSIBLE
    (no person could have clicked that pose) with "LEFT/RIGHT SWAPPED?" when swapping them fits, and for a
    tracked vehicle its track and what determined this frame's pose: ``track 0003-7 (clicks|box|interp.)``."""
    dx, dy, dz = v.dimensions
    parts = [f"{v.id} {v.prototype} {dx:.1f}x{dy:.1f}x{dz:.1f}m z{v.t_cam_vehicle[2]:.1f}m"]
    if v.sigma is not None and math.isfinite(v.sigma.yaw_deg):
        parts.append(f"yaw+-{v.sigma.yaw_deg:.1f}deg")
    if v.confidence is not None:
        parts.append(f"conf {v.confidence:.2f}")
    if v.ambiguous:
        parts.append("AMBIGUOUS")
    if v.residual_test is not None and v.residual_test.misfit:
        parts.append("MISFIT")
    if v.implausible is not None:  # mirrored or turned away (issue 33): the likely cause, in a word
        parts.append("IMPLAUSIBLE: LEFT/RIGHT SWAPPED?" if any(w.startswith("left and right look swapped")
                                                                for w in v.warnings) else "IMPLAUSIBLE")
    if v.track is not None:
        parts.append(f"track {v.track}")
        if v.pose_from is not None:
            parts.append(f"({POSE_FROM_SHORT.get(v.pose_from, v.pose_from)})")
    return " ".join(parts)


#: A track by its sequence (None for an image of no sequence) and name.
TrackKey = tuple[str | None, str]


@dataclass(frozen=True)
class TrackPath:
    """One track's positions over the frames results.json holds, in frame order.

    Attributes
    ----------
    image_ids : (n,) the frames' image ids
    frames : (n,) frame numbers (the image's ``frame``, else its place in the sequence's images)
    xz : (n, 2) ``t_cam_vehicle``'s x and z in each frame's camera frame, metres
    pose_from : (n,) results.json's ``pose_from`` of each frame ('clicks', 'box', 'interpolated' or None)
    first, last : the frame span of the track, failed frames included (what :func:`track_colours` compares)
    """

    image_ids: tuple[str, ...]
    frames: np.ndarray
    xz: np.ndarray
    pose_from: tuple[str | None, ...]
    first: int
    last: int


def track_paths(results: Sequence[ImageResult]) -> dict[TrackKey, TrackPath]:
    """Every track's fitted positions, from one pass over the results (failed frames have none).

    Returns
    -------
    paths : by ``(sequence, track)``, in the order the results first name them
    """
    rows: dict[TrackKey, list[tuple[int, str, float, float, str | None]]] = {}
    spans: dict[TrackKey, list[int]] = {}
    order: dict[str | None, int] = {}
    for result in results:
        place = order[result.sequence] = order.get(result.sequence, -1) + 1
        frame = result.frame if result.frame is not None else place
        for v in result.vehicles:
            if v.track is None:
                continue
            key = (result.sequence, v.track)
            span = spans.setdefault(key, [frame, frame])
            span[0], span[1] = min(span[0], frame), max(span[1], frame)
            if v.ok and v.t_cam_vehicle is not None:
                rows.setdefault(key, []).append((frame, result.id, float(v.t_cam_vehicle[0]),
                                                 float(v.t_cam_vehicle[2]), v.pose_from))
            else:
                rows.setdefault(key, [])
    out = {}
    for key, found in rows.items():
        found.sort(key=lambda row: row[0])
        out[key] = TrackPath(
            image_ids=tuple(row[1] for row in found), frames=np.array([row[0] for row in found], dtype=int),
            xz=np.array([row[2:4] for row in found], dtype=float).reshape(-1, 2),
            pose_from=tuple(row[4] for row in found), first=spans[key][0], last=spans[key][1])
    return out


def track_colours(paths: Mapping[TrackKey, TrackPath]) -> dict[TrackKey, int]:
    """Each track's palette index (into :data:`toosicubix.render.overlay.PALETTE_BGR`), the same in every frame.

    A track takes the colour its name hashes to (CRC-32, the same on every run and machine), unless a track of its
    sequence whose frames overlap its own took that colour first (tracks in order of their first frame, then name);
    then the next colour none of those took, else the one the fewest took. Tracks seen in one picture thus differ
    in colour while a sequence has at most as many tracks at once as the palette has colours.
    """
    n = len(PALETTE_BGR)
    out: dict[TrackKey, int] = {}
    by_sequence: dict[str | None, list[TrackKey]] = {}
    for key in sorted(paths, key=lambda k: (paths[k].first, k[1])):
        by_sequence.setdefault(key[0], []).append(key)
    for keys in by_sequence.values():
        for k, key in enumerate(keys):
            path = paths[key]
            taken = [out[other] for other in keys[:k] if paths[other].last >= path.first]  # they start no later
            wanted = zlib.crc32(key[1].encode("utf-8")) % n
            out[key] = min(((wanted + j) % n for j in range(n)), key=taken.count)  # the first of equal counts
    return out


@dataclass(frozen=True)
class Tracks:
    """What the pictures of a fit's sequences need of all its frames: each track's positions and colour."""

    paths: dict[TrackKey, TrackPath]
    colours: dict[TrackKey, int]

    @classmethod
    def of(cls, results: Sequence[ImageResult]) -> Tracks:
        """:func:`track_paths` and :func:`track_colours` of the results."""
        paths = track_paths(results)
        return cls(paths, track_colours(paths))


def _fitted_uv(camera: Camera, clicks_uv: np.ndarray, residuals: Any) -> np.ndarray | None:
    """Where the fit puts each click, in image pixels (distorted): clicked (undistorted) + residual,
    distorted again. None when the residuals do not line up with the clicks."""
    try:
        r = np.asarray(residuals, dtype=float).reshape(-1, 2)
    except (TypeError, ValueError):
        return None
    if len(r) != len(clicks_uv) or len(r) == 0 or not np.all(np.isfinite(r)):
        return None
    fitted_und = camera.undistort_pixels(clicks_uv) + r
    normalized = np.column_stack([fitted_und, np.ones(len(r))]) @ np.linalg.inv(camera.K).T
    return camera.project(normalized)


def drawn_vehicles(image: Image | None, result: ImageResult, camera: Camera,
                   colours: Mapping[TrackKey, int] | None = None) -> list[DrawnVehicle]:
    """The vehicles of one image as the overlay draws them: fits from results.json, clicks from the annotations.

    With ``colours`` (:func:`track_colours`), a tracked vehicle takes its track's colour and, in an image with
    one, the others take the palette's remaining colours in image order; in an image without a tracked vehicle
    every vehicle takes the colour of its place, as the overlay gives it, and a road user of a class with a palette
    of its own (a pedestrian, a cyclist, ...: :mod:`toosicubix.render.palette`) its class's colour.
    """
    annotated = {v.id: v for v in image.vehicles} if image is not None else {}
    by_class = class_colours([v.prototype for v in result.vehicles])  # road users: their class's own palette
    palette = _palette_indices(result, colours or {}, [own is not None for own in by_class])
    out = []
    for v, colour, own in zip(result.vehicles, palette, by_class, strict=True):
        a = annotated.get(v.id)
        clicks = np.concatenate([p.uv for p in a.parts]) if a is not None and a.parts else np.zeros((0, 2))
        sigma = v.sigma
        next_clicks = tuple((str(s.get("name", "?")), uv) for s in v.next_clicks or ()
                            if isinstance(s, dict) and (uv := _pixel_or_none(s.get("uv"))) is not None)
        box = v.box2d if v.box2d is not None else (a.box2d if a is not None else None)
        out.append(DrawnVehicle(
            id=v.id, ok=v.ok and v.R_cam_vehicle is not None, R_cam_vehicle=v.R_cam_vehicle,
            t_cam_vehicle=v.t_cam_vehicle, dimensions=v.dimensions, clicks_uv=clicks,
            fitted_uv=_fitted_uv(camera, clicks, v.residuals_px) if v.ok and len(clicks) else None,
            downweighted=_click_indices(v.click_labels, v.downweighted), box2d=box,
            label=vehicle_label(v) if v.ok and v.dimensions is not None else "", error=v.error,
            sigma_yaw=np.deg2rad(sigma.yaw_deg) if sigma is not None else None,
            sigma_depth=sigma.depth_m if sigma is not None else None,
            next_clicks=next_clicks, colour=own if colour is None else PALETTE_BGR[colour],
        ))
    return out


def _palette_indices(result: ImageResult, colours: Mapping[TrackKey, int],
                     own_colour: list[bool]) -> list[int | None]:
    """Each vehicle's palette index: its track's, or the next colour no track of the image has; all None (the
    overlay's colours by place) when no vehicle of the image has a track colour. A road user with a colour of its
    class's own (``own_colour``) and no track keeps that colour (None here)."""
    tracked = [colours.get((result.sequence, v.track)) if v.track is not None else None for v in result.vehicles]
    if all(c is None for c in tracked):
        return tracked
    free = [c for c in range(len(PALETTE_BGR)) if c not in tracked] or list(range(len(PALETTE_BGR)))
    others = itertools.cycle(free)  # more vehicles than free colours: they repeat
    return [c if c is not None else (None if own else next(others))
            for c, own in zip(tracked, own_colour, strict=True)]


def _pixel_or_none(value: object) -> np.ndarray | None:
    """A next click's ``uv`` as (2,) finite pixels, or None when results.json holds anything else there (its reader
    keeps suggestions as written; one malformed suggestion must not stop a picture)."""
    try:
        uv = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        return None
    return uv if uv.shape == (2,) and np.all(np.isfinite(uv)) else None


def drawn_tracks(result: ImageResult, tracks: Tracks) -> list[DrawnTrack]:
    """The tracks of one frame's vehicles as the bird's-eye view draws them, over every frame the results hold,
    in the image's vehicle order (a track without a fitted frame is left out)."""
    out = []
    for v in result.vehicles:
        key = (result.sequence, v.track)
        path = tracks.paths.get(key) if v.track is not None else None  # type: ignore[arg-type]
        if path is None or len(path.xz) == 0:
            continue
        current = path.image_ids.index(result.id) if result.id in path.image_ids else None
        out.append(DrawnTrack(v.track, PALETTE_BGR[tracks.colours[key]], path.xz,  # type: ignore[arg-type]
                              np.array([p == "clicks" for p in path.pose_from], dtype=bool), current))
    return out


def render_image(result: ImageResult, image: Image | None, background: np.ndarray | None,
                 ground_truth: list[DrawnCuboid] | None = None, options: OverlayOptions | None = None,
                 note: str | None = None, tracks: Tracks | None = None) -> np.ndarray:
    """One image's picture: the overlay (on ``background`` or a blank canvas) and the bird's-eye view.

    Parameters
    ----------
    result : the image's fits
    image : its annotation (clicks, camera with distortion), or None (then results.json's pinhole ``K``)
    background : (H, W, 3) uint8 BGR photo, or None for a blank canvas of the image's size
    ground_truth : cuboids in the camera frame of the image's ``K``
    note : a line written in the canvas's bottom-left corner (e.g. why it is blank)
    tracks : every track's positions and colour (:meth:`Tracks.of` all the results): the image's tracked
        vehicles take their track's colour, and the bird's-eye view draws their tracks

    Returns
    -------
    (H', W', 3) uint8 BGR
    """
    options = options or OverlayOptions()
    camera = image.camera if image is not None else Camera(K=result.K, image_size=result.image_size)
    size = image_size_of(result, image)
    vehicles = drawn_vehicles(image, result, camera, tracks.colours if tracks is not None else None)
    if background is not None:
        canvas = background.copy()
    else:
        scale = canvas_scale(size)
        if scale is None:
            raise ValueError(f"image {result.id}: a canvas of {size[0]}x{size[1]} pixels cannot be drawn even scaled "
                             f"(at most {MAX_CANVAS_SIDE} px a side and {MAX_CANVAS_PIXELS} pixels, at least 1 px)")
        if scale < 1.0:  # drawn scaled: the camera, and every pixel the vehicles carry
            camera, vehicles = scaled_camera(camera, scale), [scaled_vehicle(v, scale) for v in vehicles]
            size = scaled_size(size, scale)
        canvas = blank_canvas(size)
    gt = ground_truth or []
    draw_overlay(canvas, camera, vehicles, gt, options)
    if note:
        scale = text_scale(canvas.shape[0])
        cv2.putText(canvas, note, (6, canvas.shape[0] - int(20 * scale)), cv2.FONT_HERSHEY_SIMPLEX, scale,
                    (200, 200, 200), line_thickness(canvas.shape[0]), cv2.LINE_AA)
    panel = draw_birds_eye(birds_eye_side(canvas.shape[0]), camera, vehicles, gt, canvas.shape[1],
                           height=canvas.shape[0], tracks=drawn_tracks(result, tracks) if tracks is not None else ()) \
        if options.birds_eye else None
    return compose(canvas, panel)


def canvas_scale(size: tuple[int, int]) -> float | None:
    """The factor an image of ``size = (width, height)`` is drawn at: 1 within :data:`MAX_CANVAS_SIDE` and
    :data:`MAX_CANVAS_PIXELS`, else the largest that brings it within both; None when a side would then be under
    one pixel (an image of 1 x 1,000,000 pixels)."""
    width, height = size
    scale = min(1.0, MAX_CANVAS_SIDE / max(width, height), math.sqrt(MAX_CANVAS_PIXELS / (width * height)))
    return scale if min(width, height) * scale >= 1.0 else None


def scaled_size(size: tuple[int, int], scale: float) -> tuple[int, int]:
    """``size`` drawn at ``scale``, rounded down (within the bounds) and at least one pixel."""
    return max(1, int(size[0] * scale)), max(1, int(size[1] * scale))


def scaled_camera(camera: Camera, scale: float) -> Camera:
    """The camera of an image drawn at ``scale``: ``K`` scaled in x and y (the lens distortion acts on normalized
    coordinates, so it stays), the image size scaled."""
    K = np.diag([scale, scale, 1.0]) @ camera.K
    size = None if camera.image_size is None else scaled_size(camera.image_size, scale)
    return dataclasses.replace(camera, K=K, image_size=size)


def scaled_vehicle(v: DrawnVehicle, scale: float) -> DrawnVehicle:
    """A vehicle's pixels (clicks, where the fit puts them, box, next clicks) in an image drawn at ``scale``."""
    def times(uv: Any) -> Any:
        return None if uv is None else np.asarray(uv, dtype=float) * scale

    return dataclasses.replace(v, clicks_uv=times(v.clicks_uv), fitted_uv=times(v.fitted_uv), box2d=times(v.box2d),
                               next_clicks=tuple((label, times(uv)) for label, uv in v.next_clicks))


def image_size_of(result: ImageResult, image: Image | None) -> tuple[int, int]:
    """``(width, height)``: the annotation's size, else results.json's, else twice the principal point."""
    if image is not None and image.camera.image_size is not None:
        return tuple(int(v) for v in image.camera.image_size)  # type: ignore[return-value]
    if result.image_size is not None:
        return tuple(int(v) for v in result.image_size)  # type: ignore[return-value]
    return round(float(2 * result.K[0, 2])), round(float(2 * result.K[1, 2]))


_TRACKING_ID = re.compile(r"^(\d{4})_(\d{6})$")


def find_image_file(image: Image | None, image_id: str, annotations_path: Path | None,
                    images_dir: Path | None) -> tuple[Path | None, str | None]:
    """The image file of an image, and where it was looked for when it is missing.

    With ``images_dir``: ``DIR/<file>``, ``DIR/<file's name>``, ``DIR/<id>.png|.jpg`` and, for a frame of a
    sequence (its ``sequence`` and ``frame``, or a KITTI tracking id ``SSSS_FFFFFF``), ``DIR/SSSS/FFFFFF.png`` (DIR
    the folder of sequences, as KITTI's ``image_02``) or, when DIR is named as the sequence, ``DIR/FFFFFF.png`` (the
    sequence's own folder of frames). Else the image's ``file`` relative to the annotation file.

    Returns
    -------
    (path or None, None) when found or when nothing names a file; (None, message) when it is missing
    """
    candidates: list[Path] = []
    file = image.file if image is not None else None
    if images_dir is not None:
        if file:
            candidates += [images_dir / file, images_dir / Path(file).name]
        candidates += [images_dir / f"{image_id}{ext}" for ext in (".png", ".jpg", ".jpeg")]
        m = _TRACKING_ID.match(image_id)
        if image is not None and image.sequence is not None and image.frame is not None:
            sequence, frame = image.sequence, f"{image.frame:06d}"
        else:
            sequence, frame = (m.group(1), m.group(2)) if m else (None, None)
        if sequence is not None:
            candidates.append(images_dir / sequence / f"{frame}.png")
            if images_dir.name == sequence:
                candidates.append(images_dir / f"{frame}.png")
    elif file and annotations_path is not None:
        candidates.append(annotations_path.parent / file)
    if not candidates:
        return None, None
    for path in candidates:
        if path.is_file():
            return path, None
    if images_dir is None:
        where = f" ({image.json_path}.file in {annotations_path})" if image is not None else ""
        return None, f"image {image_id}: {candidates[0]} not found{where}; drawn on a blank canvas"
    names = ", ".join(str(c.relative_to(images_dir) if c.is_relative_to(images_dir) else c) for c in candidates)
    return None, f"image {image_id}: no image file in {images_dir} (looked for {names}); drawn on a blank canvas"


def read_image(path: Path) -> tuple[np.ndarray | None, str | None]:
    """The file as (H, W, 3) uint8 BGR, or None and why not: the file is larger than :data:`MAX_IMAGE_FILE_BYTES`,
    its header (:func:`header_size`) says it is beyond :data:`MAX_CANVAS_SIDE` or :data:`MAX_CANVAS_PIXELS` or does
    not say its size (a format not read here), or OpenCV cannot decode it. Nothing is decoded before its size is
    known: a 437 KB PNG that declares 60,000 x 60,000 pixels would need 10 GB."""
    try:
        size = path.stat().st_size
        if size > MAX_IMAGE_FILE_BYTES:
            return None, f"{size} bytes: larger than the {MAX_IMAGE_FILE_BYTES} bytes of an image render reads"
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as exc:
        return None, f"cannot be read ({exc.strerror or exc})"
    if not data.size:
        return None, "an empty file"
    declared = header_size(data[:1 << 16].tobytes(), path)
    if declared is None:
        return None, f"no header of an image render reads ({', '.join(IMAGE_FORMATS)}) gives its size"
    width, height = declared
    if not (0 < width <= MAX_CANVAS_SIDE and 0 < height <= MAX_CANVAS_SIDE and width * height <= MAX_CANVAS_PIXELS):
        return None, (f"its header declares {width}x{height} pixels: beyond the {MAX_CANVAS_SIDE} px a side and "
                      f"{MAX_CANVAS_PIXELS} pixels render decodes")
    try:
        image = cv2.imdecode(data, cv2.IMREAD_COLOR)
    except cv2.error as exc:  # a damaged file OpenCV's decoder asserts on
        return None, f"cannot be decoded ({str(exc).strip().splitlines()[-1][:120]})"
    if image is None or image.ndim != 3 or image.shape[2] != 3:
        return None, "cannot be decoded as an image"
    return image, None


#: The formats whose size :func:`header_size` reads from their header.
IMAGE_FORMATS = ("PNG", "JPEG", "BMP", "GIF", "WebP", "TIFF", "PNM")
_JPEG_FRAMES = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def header_size(head: bytes, path: Path | None = None) -> tuple[int, int] | None:
    """``(width, height)`` an image file declares in its header (``head``: its first bytes, 64 KB suffice for all
    but a JPEG with long metadata, whose segments are then followed in the file at ``path``), or None when it is
    none of :data:`IMAGE_FORMATS` or its header is cut short."""
    try:
        return _header_size(head, path)
    except (struct.error, IndexError, ValueError, OSError):
        return None


def _header_size(head: bytes, path: Path | None) -> tuple[int, int] | None:
    if head.startswith(b"\x89PNG\r\n\x1a\n") and head[12:16] == b"IHDR":
        return struct.unpack(">II", head[16:24])  # type: ignore[return-value]
    if head.startswith(b"\xff\xd8"):
        return _jpeg_size(head, path)
    if head.startswith(b"BM"):
        if struct.unpack("<I", head[14:18])[0] == 12:  # OS/2 BITMAPCOREHEADER
            return struct.unpack("<HH", head[18:22])  # type: ignore[return-value]
        width, height = struct.unpack("<ii", head[18:26])
        return abs(width), abs(height)
    if head[:6] in (b"GIF87a", b"GIF89a"):
        return struct.unpack("<HH", head[6:10])  # type: ignore[return-value]
    if head.startswith(b"RIFF") and head[8:12] == b"WEBP":
        chunk = head[12:16]
        if chunk == b"VP8 ":
            width, height = struct.unpack("<HH", head[26:30])
            return width & 0x3FFF, height & 0x3FFF
        if chunk == b"VP8L":
            bits = struct.unpack("<I", head[21:25])[0]
            return 1 + (bits & 0x3FFF), 1 + ((bits >> 14) & 0x3FFF)
        if chunk == b"VP8X":
            return 1 + int.from_bytes(head[24:27], "little"), 1 + int.from_bytes(head[27:30], "little")
        return None
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        return _tiff_size(head)
    if len(head) > 2 and head[:1] == b"P" and head[1:2] in b"123456" and head[2:3].isspace():
        tokens = re.sub(rb"#[^\n]*", b" ", head[2:256]).split()
        return int(tokens[0]), int(tokens[1])
    return None


def _jpeg_size(head: bytes, path: Path | None) -> tuple[int, int] | None:
    """The size in a JPEG's first frame header (SOFn), following the segments from the file when they run past
    ``head``."""
    data, i = head, 2
    for _ in range(10_000):  # segments before the frame: a handful in any file
        if i + 4 > len(data) and path is not None and len(data) == len(head):
            data = path.read_bytes()[: 16 << 20]  # long metadata (at most 16 MB is searched)
        while i < len(data) and data[i] == 0xFF and i + 1 < len(data) and data[i + 1] == 0xFF:
            i += 1  # fill bytes
        if i + 4 > len(data) or data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            i += 2
            continue
        if marker in (0xD9, 0xDA):  # the end or the scan before any frame header
            return None
        length = struct.unpack(">H", data[i + 2:i + 4])[0]
        if marker in _JPEG_FRAMES:
            height, width = struct.unpack(">HH", data[i + 5:i + 9])
            return width, height
        i += 2 + length
    return None


def _tiff_size(head: bytes) -> tuple[int, int] | None:
    """ImageWidth (tag 256) and ImageLength (257) of a TIFF's first image file directory."""
    order = "<" if head[:2] == b"II" else ">"
    offset = struct.unpack(order + "I", head[4:8])[0]
    count = struct.unpack(order + "H", head[offset:offset + 2])[0]
    found: dict[int, int] = {}
    for k in range(min(count, 1000)):
        entry = head[offset + 2 + 12 * k: offset + 14 + 12 * k]
        tag, kind = struct.unpack(order + "HH", entry[:4])
        if tag in (256, 257):
            found[tag] = struct.unpack(order + ("H" if kind == 3 else "I"), entry[8:10 if kind == 3 else 12])[0]
    return (found[256], found[257]) if 256 in found and 257 in found else None


def selected(result: ImageResult, only: str | None) -> bool:
    """Whether ``--only`` keeps an image."""
    if only is None:
        return True
    if only == "failed":
        return any(not v.ok for v in result.vehicles)
    if only == "ambiguous":
        return any(v.ok and v.ambiguous for v in result.vehicles)
    if only == "uncertain":
        from toosicubix.pipeline.validation import Thresholds, judge

        thresholds = Thresholds(allow_ambiguous=True)
        return any(v.ok and judge(v, thresholds) for v in result.vehicles)
    if only == "misfit":
        return any(v.ok and v.residual_test is not None and v.residual_test.misfit for v in result.vehicles)
    raise ValueError(f"only: expected one of {', '.join(ONLY_CHOICES)}, got {only!r}")


def ground_truth_cuboids(source: Any, result: ImageResult, warnings: list[str]) -> list[DrawnCuboid]:
    """The scored-class ground-truth cuboids of an image in the camera frame of its ``K``.

    ``source`` is a :class:`toosicubix.evaluation.GroundTruthSource`; an image it lacks adds a warning.
    """
    from toosicubix.errors import EvaluationInputError, FormatError

    try:
        gt = source.load(result.id)
    except EvaluationInputError as exc:
        warnings.append(f"image {result.id}: no ground truth ({exc})")
        return []
    except FormatError as exc:  # one malformed label file: that image is drawn without ground truth, the rest go on
        warnings.append(f"image {result.id}: ground truth not drawn: {exc}")
        return []
    offset = gt.t_cam_rect if gt.t_cam_rect is not None else result.t_cam_rect
    wanted = {c.lower() for c in source.default_classes}
    out = []
    for obj in gt.objects:
        if obj.cuboid_rect is not None and obj.cls.lower() in wanted:
            c = obj.cuboid_rect.translated(offset)
            out.append(DrawnCuboid(c.R_cam_vehicle, c.t_cam_vehicle, c.dimensions, ground_truth_note(obj)))
    return out


def ground_truth_note(obj: Any) -> str:
    """What a ground-truth object (:class:`toosicubix.evaluation.GtObject`) says against its own clicks, for its
    note on the overlay, named by its id (ApolloCar3D's car id, which the fitted vehicle's label shows too): that its
    pose hides its labelled keypoints, or puts them more than :data:`toosicubix.parts.learned.CONTRADICTION_M` from
    their rays (:func:`toosicubix.evaluation.report.hides_keypoints`, :func:`~toosicubix.evaluation.report.
    off_keypoint_rays`: as ``eval`` scores them apart); empty otherwise."""
    from toosicubix.evaluation.report import hides_keypoints, off_keypoint_rays

    notes = []
    if hides_keypoints(obj):
        notes.append(f"hides {obj.keypoints_hidden} of its {obj.keypoints} keypoints")
    if off_keypoint_rays(obj):
        notes.append(f"{obj.keypoints_off_rays_m:.1f} m off their rays" if notes else
                     f"{obj.keypoints_off_rays_m:.1f} m off its keypoints' rays")
    if not notes:
        return ""
    name = "GT" if obj.track_id is None else f"GT {obj.track_id}"
    return f"{name}: {'; '.join(notes)}"


def resolve_annotations(results_path: Path, header_value: Any, given: Path | None) -> Path:
    """The annotation file: ``given``, else results.json's ``$.annotations`` (as written by ``fit``, relative to
    the working directory then), also tried relative to the fit folder's parent.

    Raises
    ------
    RenderInputError
        Not found, naming results.json and the JSON path.
    """
    if given is not None:
        if not given.is_file():
            raise RenderInputError(f"{given}: annotation file not found")
        return given
    if not isinstance(header_value, str) or not header_value:
        raise RenderInputError(f"{results_path}: $.annotations: missing; give the annotation file with --annotations")
    for path in (Path(header_value), results_path.parent.parent / header_value):
        if path.is_file():
            return path
    raise RenderInputError(f"{results_path}: $.annotations: annotation file {header_value} not found; give it with "
                           f"--annotations FILE")


def render_folder(fit_dir: str | Path, out_dir: str | Path | None = None, annotations: str | Path | None = None,
                  images_dir: str | Path | None = None, ground_truth: tuple[str, str | Path] | None = None,
                  options: RenderOptions | None = None, progress: Callable[[int], None] | None = None,
                  on_start: Callable[[int], None] | None = None) -> RenderSummary:
    """Render every image of a fit output folder to ``out_dir/<image id>.png``.

    Parameters
    ----------
    fit_dir : a ``toosicubix fit`` output folder (with results.json)
    out_dir : where to write; default ``fit_dir/render``
    annotations : the annotation file; default the one results.json names
    images_dir : a folder of images to use instead of each image's ``file``
    ground_truth : ``(kind, folder)`` as for ``toosicubix eval`` ('kitti', 'kitti-tracking', 'cityscapes'; any
        kind :func:`toosicubix.evaluation.open_ground_truth` knows), drawn dashed in white
    progress : called with the number of images just done; on_start : called once with the total

    Raises
    ------
    RenderInputError, toosicubix.errors.FormatError, toosicubix.errors.InputFileError,
    toosicubix.errors.EvaluationInputError
        Missing or malformed inputs (each names the file and, where there is one, the JSON path).
    """
    from toosicubix.jsonfile import read_json

    options = options or RenderOptions()
    fit_dir = Path(fit_dir)
    results_path = fit_dir / RESULTS_FILENAME
    if not results_path.is_file():
        raise RenderInputError(f"{fit_dir}: no {RESULTS_FILENAME} (the output folder of `toosicubix fit`)")
    header = read_json(results_path)
    results = read_results(results_path)
    annotations_path = resolve_annotations(results_path, header.get("annotations"),
                                           None if annotations is None else Path(annotations))
    summary = RenderSummary()
    expected_sha = header.get("annotations_sha256")
    if isinstance(expected_sha, str) and hashlib.sha256(annotations_path.read_bytes()).hexdigest() != expected_sha:
        summary.warnings.append(f"{annotations_path} changed since the fit ({results_path} $.annotations_sha256): "
                                f"clicks may not match the fits")
    images = {im.id: im for im in load_images(annotations_path)}
    source = None
    if ground_truth is not None:
        from toosicubix.formats.ground_truth import open_ground_truth

        source = open_ground_truth(*ground_truth)
    images_dir = None if images_dir is None else Path(images_dir)
    if images_dir is not None and not images_dir.is_dir():
        raise RenderInputError(f"{images_dir}: image folder not found")
    out = Path(out_dir) if out_dir is not None else fit_dir.with_name(fit_dir.name + DEFAULT_RENDER_SUFFIX)
    out.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(out)  # once here; each picture is then written without scanning the folder again
    summary.out_dir = out
    tracks = Tracks.of(results)  # every frame's, also those --only leaves out: a track's colour and its whole path
    chosen = [r for r in results if selected(r, options.only)]
    summary.skipped = len(results) - len(chosen)
    if on_start is not None:
        on_start(len(chosen))
    frames: dict[str, list[tuple[int, Path]]] = {}  # each sequence's rendered frames, for its video
    for result in chosen:
        image = images.get(result.id)
        if image is None:
            summary.warnings.append(f"image {result.id}: not in {annotations_path}; drawn without clicks")
        path, missing = find_image_file(image, result.id, annotations_path, images_dir)
        background, note = None, "no image file: blank canvas"
        if missing:
            summary.warnings.append(missing)
            note = "image file not found: blank canvas"
        elif path is not None:
            background, why = read_image(path)
            if background is None:
                summary.warnings.append(f"image {result.id}: {path}: {why}; drawn on a blank canvas")
                note = "image file not read: blank canvas"
            else:
                expected = image_size_of(result, image)
                found = (background.shape[1], background.shape[0])
                if found != expected:
                    summary.warnings.append(f"image {result.id}: {path} is {found[0]}x{found[1]} pixels, the "
                                            f"annotation says {expected[0]}x{expected[1]}")
                note = None
        if background is None:
            size = image_size_of(result, image)
            scale = canvas_scale(size)
            if scale is None:
                summary.warnings.append(f"image {result.id}: {size[0]}x{size[1]} pixels cannot be drawn (a side would "
                                        f"be under one pixel once scaled to at most {MAX_CANVAS_SIDE} px a side and "
                                        f"{MAX_CANVAS_PIXELS} pixels): left out")
                summary.refused.append(result.id)
                if progress is not None:
                    progress(1)
                continue
            if scale < 1.0:
                drawn = scaled_size(size, scale)
                summary.warnings.append(f"image {result.id}: {size[0]}x{size[1]} pixels, beyond the {MAX_CANVAS_SIDE} "
                                        f"px a side or {MAX_CANVAS_PIXELS} pixels render draws: drawn scaled by "
                                        f"{scale:.3g} to {drawn[0]}x{drawn[1]}")
            summary.blank.append(result.id)
        gt = ground_truth_cuboids(source, result, summary.warnings) if source is not None else []
        picture = render_image(result, image, background, gt, options.overlay, note, tracks)
        target = out / f"{result.id}.png"
        atomic_write_bytes(target, encode_png(picture, options.png_compression), clean=False)
        summary.written.append(target)
        if options.video and result.sequence is not None and result.frame is not None:
            frames.setdefault(result.sequence, []).append((result.frame, target))
        if progress is not None:
            progress(1)
    if options.video:
        if not frames:
            summary.warnings.insert(0, "--video: no rendered image is a frame of a sequence (its `sequence` and "
                                       "`frame`): no video written")
        else:
            from toosicubix.render.video import write_videos

            videos = write_videos(frames, out, options.frame_rate)
            summary.videos, summary.warnings = videos.written, videos.warnings + summary.warnings  # said first
    return summary


def _click_indices(click_labels: tuple[str, ...], labels: tuple[str, ...]) -> tuple[int, ...]:
    """The indices of the clicks named by ``labels`` (results.json's ``downweighted``) among ``click_labels``."""
    wanted = set(labels)
    return tuple(i for i, label in enumerate(click_labels) if label in wanted)
