"""Fitted cuboids as CVAT 1.1 review shapes, for CVAT to import into the task that holds the clicks.

Each fitted vehicle becomes a ``polyline`` over the 12 edges of its cuboid (label
:data:`~toosicubix.formats.templates.CUBOID_LABEL`) and a ``polygon`` on its front face (``FRONT_LABEL``),
projected with the image's camera including lens distortion (edges are sampled, so they bend as the lens
bends them). Both carry the vehicle id; the polyline also its status. CVAT's own ``cuboid`` shape is a 2D
pseudo-cuboid with no 3D meaning, so it is not used. Images are matched by ``name``: the annotation file's
``file``, which the CVAT importer sets to CVAT's image name. The template's review labels must be in the task
(``toosicubix template cvat`` adds them). In a file of a CVAT video task's frames the shapes are CVAT tracks: a
tracked vehicle one object over its frames.
"""

from __future__ import annotations

import itertools
import math
import re
import xml.etree.ElementTree as ET
from pathlib import PurePosixPath

import numpy as np

from toosicubix.camera import trusted_radius, within_radius
from toosicubix.fields import MAX_PIXEL
from toosicubix.formats.fitted import FittedImage
from toosicubix.formats.templates import CUBOID_LABEL, FRONT_LABEL
from toosicubix.geometry import FRONT_FACE, Z_NEAR, cuboid_corners_cam

#: A walk over all 12 edges of a cuboid (corner indices of :func:`toosicubix.geometry.cuboid_corners_vehicle`:
#: bottom 0-3 front-left, rear-left, rear-right, front-right; top 4-7 the same), each edge at least once.
EDGE_WALK = (0, 1, 2, 3, 0, 4, 5, 6, 7, 4, 5, 1, 2, 6, 7, 3)


def _path_cam(corners_cam: np.ndarray, walk: tuple[int, ...], samples: int, closed: bool) -> np.ndarray:
    """Points along the walk's segments in camera coordinates, ``samples`` per segment: (n, 3)."""
    idx = list(walk) + ([walk[0]] if closed else [])
    out = []
    for a, b in itertools.pairwise(idx):
        s = np.linspace(0.0, 1.0, samples, endpoint=False)[:, None]
        out.append(corners_cam[a] + s * (corners_cam[b] - corners_cam[a]))
    if not closed:
        out.append(corners_cam[idx[-1]][None])
    return np.vstack(out)


#: The largest pixel coordinate written (the annotation file's bound): a cuboid projecting beyond is left out with a
#: warning, like one behind the camera; nothing non-finite or absurd is written.
MAX_WRITTEN_PIXEL = MAX_PIXEL


def projected_shapes(image: FittedImage, samples_per_edge: int = 8) -> tuple[list[dict], list[str]]:
    """Per fitted vehicle its polyline (N, 2) and front polygon (M, 2), pixels; and warnings for the left out
    (a cuboid reaching behind the camera, or projecting beyond +-:data:`MAX_WRITTEN_PIXEL` or to no finite pixel).

    Returns
    -------
    (shapes, warnings) : shapes are ``{"id", "status", "track", "polyline", "front"}``
    """
    samples = samples_per_edge if image.camera.has_distortion else 1
    radius = trusted_radius(image.camera, image.size)
    shapes, warnings = [], []
    for fv in image.vehicles:
        v = fv.result
        if not v.ok:
            continue
        corners_cam = cuboid_corners_cam(v.R_cam_vehicle, v.t_cam_vehicle, v.dimensions)  # (8, 3)
        if not corners_cam[:, 2].min() >= Z_NEAR:
            warnings.append(f"image {image.id!r}, vehicle {v.id!r}: the cuboid reaches behind the camera: left out")
            continue
        path_cam = _path_cam(corners_cam, EDGE_WALK, samples, closed=False)
        front_cam = _path_cam(corners_cam, FRONT_FACE, samples, closed=True)
        if not all(np.all(within_radius(p, radius)) for p in (path_cam, front_cam)):
            warnings.append(f"image {image.id!r}, vehicle {v.id!r}: the cuboid reaches where the lens model is not "
                            "trusted (past the image's corners, or where its distortion folds back): left out")
            continue
        with np.errstate(all="ignore"):  # a far or extreme pose may overflow: checked below
            polyline = image.camera.project(path_cam)
            front = image.camera.project(front_cam)
        if not all(np.all(np.abs(uv) <= MAX_WRITTEN_PIXEL) for uv in (polyline, front)):  # NaN fails too
            warnings.append(f"image {image.id!r}, vehicle {v.id!r}: the cuboid projects beyond "
                            f"+-{MAX_WRITTEN_PIXEL:.0f} pixels (t_cam_vehicle {np.round(v.t_cam_vehicle, 3).tolist()}):"
                            " left out")
            continue
        shapes.append({"id": v.id, "status": v.status, "track": v.track, "polyline": polyline, "front": front})
    return shapes, warnings


#: What XML 1.0 can carry (its ``Char``): no other control characters, no surrogates, no U+FFFE or U+FFFF.
_NOT_XML = re.compile("[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")


def _fmt(uv: np.ndarray) -> str:
    return ";".join(f"{u:.2f},{v:.2f}" for u, v in uv)


def _shape(parent: ET.Element, tag: str, head: dict[str, str], points: np.ndarray, attributes: dict[str, str]) -> None:
    """One review shape: ``head`` is an image's shape's label and source, or a track's shape's frame number,
    keyframe and outside flags."""
    node = ET.SubElement(parent, tag, {**head, "occluded": "0", "points": _fmt(points), "z_order": "0"})
    for name, value in attributes.items():
        ET.SubElement(node, "attribute", {"name": name}).text = value


def _tracks(root: ET.Element, tracked: dict[tuple[str, ...], list[tuple[int, dict]]], frames: list[int]) -> None:
    """Each track (or untracked vehicle) as two CVAT tracks (its cuboid's polyline, its front's polygon), in the
    order of their first frames, a keyframe on every frame that holds it; ``outside`` from the frame after each run
    of frames, within the file's frames (CVAT carries a track's last shape on to later frames, and interpolates
    across a gap, unless told the object left the view).

    The frame after ``f`` is ``f + step``, ``step`` the greatest common divisor of the gaps between the file's
    ``frames``: a task with a frame step (CVAT's ``frame_filter``, e.g. ``step=5``) numbers its frames in the
    video's frames, and CVAT refuses a frame its step skips (``rel_frame_id``); the file's frames are all the
    task's start plus multiples of its step, so this step is a multiple of the task's and ``f + step`` a frame of
    the task. A file of every frame has step 1."""
    step = math.gcd(*(b - a for a, b in itertools.pairwise(sorted(set(frames))))) or 1
    last_frame = max(frames)
    number = 0
    for runs in sorted(tracked.values(), key=lambda runs: min(frame for frame, _ in runs)):
        runs = sorted(runs, key=lambda run: run[0])
        for label, tag, key in ((CUBOID_LABEL, "polyline", "polyline"), (FRONT_LABEL, "polygon", "front")):
            node = ET.SubElement(root, "track", {"id": str(number), "label": label, "source": "auto"})
            number += 1
            for i, (frame, shape) in enumerate(runs):
                attributes = {"vehicle_id": shape["id"]} | ({"status": shape["status"]} if tag == "polyline" else {})
                _shape(node, tag, {"frame": str(frame), "keyframe": "1", "outside": "0"}, shape[key], attributes)
                following = runs[i + 1][0] if i + 1 < len(runs) else None
                if frame < last_frame and following != frame + step:
                    _shape(node, tag, {"frame": str(frame + step), "keyframe": "1", "outside": "1"}, shape[key],
                           attributes)


def review_xml(images: list[FittedImage], samples_per_edge: int = 8) -> tuple[str, list[str]]:
    """The CVAT 1.1 document with every fitted cuboid, and the warnings.

    Images need a ``file`` (CVAT matches by name) and a ``size``; each is an ``<image>`` with its vehicles' shapes,
    its id its order in the file, or its frame number when every image is a frame of one sequence (where CVAT
    cannot match a name, it takes the id as the frame: ``match_dm_item`` in cvat/apps/dataset_manager/bindings.py).

    A file of a CVAT video task's frames (one sequence, every image's file CVAT's name for its frame,
    ``frame_<N:06d>``, as ``import cvat`` names them) has no ``<image>``: every vehicle is in ``<track>`` elements
    (:func:`_tracks`), a tracked one over its frames, any other on its one frame (as CVAT writes a shape in its
    video format), in the video's frame numbers, which is how CVAT exports and reads a track's frames (``load_anno``
    in cvat/apps/dataset_manager/formats/cvat.py; it keeps only keyframes). An image id would be a frame counted
    from the task's start by its frame step, which the file does not know. Frames of other names keep their
    ``<image>``s: an image task matches them by name, and its frame numbers need not be the sequence's.
    """
    root = ET.Element("annotations")
    ET.SubElement(root, "version").text = "1.1"
    warnings: list[str] = []
    one_video = bool(images) and len({image.sequence for image in images}) == 1 and images[0].sequence is not None
    cvat_video = one_video and all(PurePosixPath(image.file or "").stem == f"frame_{image.frame:06d}"
                                   for image in images)
    tracked: dict[tuple[str, ...], list[tuple[int, dict]]] = {}  # track or vehicle -> (frame, shape) of its frames
    for index, image in enumerate(images):
        node = None
        if not cvat_video:
            name = image.file or image.id
            if _NOT_XML.search(name):
                warnings.append(f"image {image.id!r}: its file name {name!r} holds a character XML cannot carry: "
                                "left out")
                continue
            attrs = {"id": str(image.frame if one_video else index), "name": name}
            if image.size is not None:
                attrs.update(width=str(image.size[0]), height=str(image.size[1]))
            node = ET.SubElement(root, "image", attrs)
        shapes, image_warnings = projected_shapes(image, samples_per_edge)
        warnings += image_warnings
        for shape in shapes:
            if _NOT_XML.search(shape["id"]):
                warnings.append(f"image {image.id!r}, vehicle {shape['id']!r}: its id holds a character XML cannot "
                                "carry: left out")
                continue
            if node is None:
                key = ("track", shape["track"]) if shape["track"] is not None else ("vehicle", image.id, shape["id"])
                tracked.setdefault(key, []).append((image.frame, shape))
                continue
            _shape(node, "polyline", {"label": CUBOID_LABEL, "source": "auto"}, shape["polyline"],
                   {"vehicle_id": shape["id"], "status": shape["status"]})
            _shape(node, "polygon", {"label": FRONT_LABEL, "source": "auto"}, shape["front"],
                   {"vehicle_id": shape["id"]})
    if tracked:
        _tracks(root, tracked, [image.frame for image in images])
    ET.indent(root, "  ")
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n", warnings
