"""COCO keypoint files to annotation file v1, through a keypoint mapping.

A COCO keypoint file has ``images[]`` (``id``, ``file_name``, optional per-image ``K`` as Omni3D writes it),
``categories[]`` (``id``, ``name``, optional ``keypoints``: the names by index) and ``annotations[]``
(``id``, ``image_id``, ``category_id``, ``keypoints``: x, y, v triplets, ``bbox``: x, y, w, h). The image id
becomes the file name's stem, the vehicle id the annotation id (as a string), ``box2d`` the ``bbox``.
``v = 0`` (not labelled) is skipped, ``v = 1`` (labelled, not visible) is kept and counted, ``v = 2`` kept.
Crowd annotations (``iscrowd`` 1: a region of many people, with no keypoints) are skipped and counted.

A *mapping* (:class:`MappingFile`, JSON Schema in ``schemas/mapping.schema.json``) says which keypoints make
which parts, and which category gets which prototype. Its parts are tried in file order: a part is made when
every keypoint it names is labelled and none was taken by an earlier part (each click is used once). Parts
with an ``option`` are used only when the import asks for it (e.g. ``plates``: plate corners as a
known-width feature rather than as keypoints). Labelled keypoints no part used are counted per name.

Cameras: a cameras file (:mod:`toosicubix.formats.cameras`: the first glob on ``file_name`` that matches wins),
or the image's own ``K``.

The bundled ``toosicubix`` mapping is not a file: it is :func:`toosicubix.parts.keypoints.mapping_document`, the
labelling tools' flat keypoint names, so the two cannot disagree. Its length features without a default size
(wheelbases, tyres) are not made on a COCO import (no size to give them); their keypoints are counted unused.

Videos (COCO-style tracking files, TAO and BDD100K's ``to_coco``): an image that names its video and its frame is a
frame of a sequence, an annotation with a track id a tracked vehicle.

- Video: ``video_id`` (TAO, BDD100K), named by ``videos[]`` (``{"id", "name"}``) when it lists the id, else by the
  image's ``video_name`` or ``video`` (TAO), else by the id itself; or only ``video_name`` / ``video``. The name,
  made a file name (:func:`~toosicubix.formats.tool_import.sequence_id_for`), is the image's ``"sequence"``.
- Frame: ``frame_index`` (TAO), else ``frame_id`` (BDD100K): an integer from 0, the image's ``"frame"``. A video
  without a frame, or a frame without a video, is an error naming the JSON path.
- Track: ``track_id`` (TAO), else ``instance_id`` (BDD100K, numbered per video): the vehicle's ``"track"`` is
  ``<sequence>-<track id>``. A track id on an annotation whose image is not a frame of a video is an error naming
  its JSON path: a track only means something within one sequence, and guessing one (the whole file) would tie
  unrelated images together. A tracked annotation may have no ``keypoints`` (TAO's and BDD100K's have none):
  a frame with its box only.

Such an image's id is ``<sequence>_<frame:06d>`` (TAO's file names repeat across videos); the file stays its
``file_name``. A tracked vehicle without parts is kept (its box, or nothing: the solver interpolates it); the rules
across frames (one prototype per track, a frame once per sequence) are checked on the imported document, naming
the JSON path. Files without these fields import as before.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from toosicubix.annotations import schema as schemas
from toosicubix.annotations.mapping import (
    MappingDirection,
    MappingFile,
    MappingKeypoint,
    MappingLength,
    MappingPlate,
    MappingPoint,
    MappingSymmetry,
    keypoints_of,
)
from toosicubix.errors import InputFileError
from toosicubix.formats.cameras import CameraTable
from toosicubix.formats.tool_import import check_imported, frame_image_id, sequence_id_for
from toosicubix.jsonfile import read_json
from toosicubix.parts.road_users import import_notes
from toosicubix.vocabulary import KINDS


@dataclass
class ImportSummary:
    """What an import made and what it left."""

    images: int = 0
    vehicles: int = 0
    parts: Counter = field(default_factory=Counter)
    clicks: int = 0
    hidden_kept: int = 0
    unlabelled: int = 0
    unused: Counter = field(default_factory=Counter)
    vehicles_without_parts: int = 0
    tracks: set[str] = field(default_factory=set)
    tracked_without_parts: int = 0
    crowd_skipped: int = 0
    notes: Counter = field(default_factory=Counter)

    def lines(self) -> list[str]:
        kinds = ", ".join(f"{n} {k}" for k, n in sorted(self.parts.items())) or "none"
        out = [f"{self.images} images, {self.vehicles} vehicles, {self.clicks} clicks in parts ({kinds})",
               f"{self.hidden_kept} labelled keypoints marked not visible (v = 1) kept; "
               f"{self.unlabelled} unlabelled (v = 0) skipped"]
        if self.vehicles_without_parts:
            out.append(f"{self.vehicles_without_parts} vehicles got no part (they will fail to fit)")
        if self.tracks:
            out.append(f"{len(self.tracks)} tracks; {self.tracked_without_parts} of their vehicle frames have no part "
                       "(a box only, or the solver interpolates them)")
        if self.crowd_skipped:
            out.append(f"{self.crowd_skipped} crowd annotations (iscrowd 1) skipped")
        out += [f"{n} {note}" for note, n in sorted(self.notes.items())]
        if self.unused:
            out.append(f"{sum(self.unused.values())} labelled keypoints no part used, by name: "
                       + ", ".join(f"{name} {n}" for name, n in sorted(self.unused.items())))
        return out


def _fail(path: str | Path, where: str, message: str) -> InputFileError:
    return InputFileError(path, [(where, message)])


def _field(obj: Any, key: str, kinds: type | tuple[type, ...], path: str | Path, where: str) -> Any:
    if not isinstance(obj, dict) or key not in obj:
        raise _fail(path, f"{where}.{key}", "missing required field")
    value = obj[key]
    if not isinstance(value, kinds) or isinstance(value, bool):
        raise _fail(path, f"{where}.{key}", f"expected {getattr(kinds, '__name__', kinds)}, got {value!r:.60}")
    return value


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def coco_to_annotations(coco_path: str | Path, mapping: MappingFile, cameras: CameraTable | None = None,
                        options: tuple[str, ...] = ()) -> tuple[dict[str, Any], ImportSummary]:
    """Turn a COCO keypoint file into an annotation file v1 (a JSON document, already validated).

    Parameters
    ----------
    coco_path : the COCO keypoint file
    mapping : from :func:`load_mapping`
    cameras : from :func:`toosicubix.formats.cameras.load_cameras`; None: every image must carry its own ``K``
    options : the mapping's optional parts to use (e.g. ``("plates",)``)

    Returns
    -------
    (document, summary)

    Raises
    ------
    InputFileError
        Naming the file and the JSON path: a malformed entry, an image without a camera, a keypoint the
        mapping does not know, a bad triplet.
    """
    data = read_json(coco_path, at_root=True)
    if not isinstance(data, dict):
        raise _fail(coco_path, "$", "expected a COCO object with images, annotations and categories")
    known = mapping.known_keypoints()
    categories: dict[Any, tuple[str, list[str] | None]] = {}
    for i, cat in enumerate(_field(data, "categories", list, coco_path, "$")):
        where = f"$.categories[{i}]"
        cat_id = _field(cat, "id", (int, str), coco_path, where)
        names = cat.get("keypoints") if isinstance(cat, dict) else None
        if isinstance(names, list) and all(n == "" for n in names):
            names = None  # unnamed (ApolloCar3D's file): the mapping's names by index apply
        if names is not None:
            if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
                raise _fail(coco_path, f"{where}.keypoints", "expected a list of keypoint names")
            for j, name in enumerate(names):
                if name not in known:
                    raise _fail(coco_path, f"{where}.keypoints[{j}]",
                                f"keypoint {name!r} is not known to the mapping {mapping.name!r}")
        categories[cat_id] = (str(cat.get("name", cat_id)), names)

    images: dict[Any, dict[str, Any]] = {}
    order: list[Any] = []
    videos = _video_names(data, coco_path)
    sequences: dict[str, tuple[Any, str]] = {}  # sequence -> (the video it names, where first)
    for i, im in enumerate(_field(data, "images", list, coco_path, "$")):
        where = f"$.images[{i}]"
        image_id = _field(im, "id", (int, str), coco_path, where)
        file_name = _field(im, "file_name", str, coco_path, where)
        camera = _camera_of(im, file_name, cameras, coco_path, where)
        doc: dict[str, Any] = {"id": Path(file_name).stem, "file": file_name}
        frame_of = _video_frame(im, videos, coco_path, where)
        if frame_of is not None:
            video, sequence, frame = frame_of
            first = sequences.setdefault(sequence, (video, where))
            if first[0] != video:
                raise _fail(coco_path, where, f"videos {first[0][1]!r} (at {first[1]}) and {video[1]!r} both become "
                                              f"sequence {sequence!r}: rename one")
            doc.update(id=frame_image_id(sequence, frame), sequence=sequence, frame=frame)
        doc.update(camera=camera, vehicles=[])
        if _number(im.get("width")) and _number(im.get("height")):
            doc["size"] = [int(im["width"]), int(im["height"])]
        if image_id in images:
            raise _fail(coco_path, f"{where}.id", f"image id {image_id!r} appears twice")
        images[image_id] = doc
        order.append(image_id)

    summary = ImportSummary(images=len(images))
    enabled = [p for p in mapping.parts if p.option is None or p.option in options]
    for i, ann in enumerate(_field(data, "annotations", list, coco_path, "$")):
        where = f"$.annotations[{i}]"
        ann_id = _field(ann, "id", (int, str), coco_path, where)
        image_id = _field(ann, "image_id", (int, str), coco_path, where)
        if image_id not in images:
            raise _fail(coco_path, f"{where}.image_id", f"no image has id {image_id!r}")
        if ann.get("iscrowd") in (1, True):
            summary.crowd_skipped += 1
            continue
        category = ann.get("category_id")
        cat_name, names = categories.get(category, (str(category), None))
        track = _track_of(ann, images[image_id], coco_path, where)
        if names is None:
            names = mapping.keypoints
        labelled: dict[str, tuple[float, float, bool]] = {}
        if track is None or "keypoints" in ann:  # a tracked box without keypoints is a frame with a box only
            if names is None:
                raise _fail(coco_path, f"{where}.category_id", f"category {category!r} does not name its keypoints, "
                                                               f"nor does the mapping {mapping.name!r}")
            labelled = _triplets(ann, names, coco_path, where, summary)
        prototype = mapping.prototypes.get(str(category), mapping.prototypes.get(cat_name, mapping.prototype))
        parts, taken = _make_parts(enabled, labelled, prototype)
        for name in labelled:
            if name not in taken:
                summary.unused[name] += 1
        vehicle: dict[str, Any] = {"id": str(ann_id), "prototype": prototype}
        if track is not None:
            vehicle["track"] = track
            summary.tracks.add(track)
            summary.tracked_without_parts += not parts
        vehicle["parts"] = parts
        if "bbox" in ann:
            box = ann["bbox"]
            if not (isinstance(box, list) and len(box) == 4 and all(_number(v) for v in box)) or box[2] <= 0 \
                    or box[3] <= 0:
                raise _fail(coco_path, f"{where}.bbox", f"expected [x, y, w, h] with w, h > 0, got {box!r:.60}")
            vehicle["box2d"] = [box[0], box[1], box[0] + box[2], box[1] + box[3]]
        images[image_id]["vehicles"].append(vehicle)
        summary.vehicles += 1
        summary.vehicles_without_parts += not parts and track is None
        for note in import_notes(prototype, labelled):
            summary.notes[note] += 1
        for part in parts:
            summary.parts[part["kind"]] += 1
            summary.clicks += len(KINDS[part["kind"]].clicks)
    document = {"toosicubix": schemas.SCHEMA_VERSION, "images": [images[k] for k in order]}
    if sequences:
        check_imported(document, f"{coco_path} (as imported)")  # the rules across frames name the image too
    else:
        schemas.parse_annotations(document, f"{coco_path} (as imported)")
    return document, summary


#: The spellings of a frame's video (identity first, then names), its frame number and an annotation's track.
VIDEO_KEYS = ("video_id", "video_name", "video")
FRAME_KEYS = ("frame_index", "frame_id")
TRACK_KEYS = ("track_id", "instance_id")


def _video_names(data: dict[str, Any], path: str | Path) -> dict[Any, str]:
    """The ``videos[]`` table: id -> name (empty when the file has none)."""
    if "videos" not in data:
        return {}
    names: dict[Any, str] = {}
    for i, video in enumerate(_field(data, "videos", list, path, "$")):
        video_id = _field(video, "id", (int, str), path, f"$.videos[{i}]")
        name = video.get("name")
        if name is not None:
            names[video_id] = str(_field(video, "name", str, path, f"$.videos[{i}]"))
    return names


def _video_frame(im: dict[str, Any], videos: dict[Any, str], path: str | Path,
                 where: str) -> tuple[tuple[str, Any], str, int] | None:
    """((key, value) naming the video, sequence, frame) of an image that is a frame of a video, else None."""
    video_key = next((k for k in VIDEO_KEYS if im.get(k) is not None), None)
    frame_key = next((k for k in FRAME_KEYS if im.get(k) is not None), None)
    if video_key is None and frame_key is None:
        return None
    if video_key is None or frame_key is None:
        found = video_key or frame_key
        raise _fail(path, f"{where}.{found}", f"expected a video ({', '.join(VIDEO_KEYS)}) and a frame number "
                                              f"({', '.join(FRAME_KEYS)}) together, found only {found!r}")
    frame = im[frame_key]
    if not isinstance(frame, int) or isinstance(frame, bool) or not 0 <= frame <= schemas.MAX_FRAME:
        raise _fail(path, f"{where}.{frame_key}", f"expected an integer frame number from 0 to {schemas.MAX_FRAME}, "
                                                  f"got {frame!r:.40}")
    value = _field(im, video_key, (int, str) if video_key == "video_id" else str, path, where)
    name = videos.get(value) if video_key == "video_id" else None
    name = name or next((im[k] for k in VIDEO_KEYS[1:] if isinstance(im.get(k), str)), None) or str(value)
    sequence = sequence_id_for(name)
    if not sequence:
        raise _fail(path, f"{where}.{video_key}", f"video {name!r} makes no sequence name (letters or digits needed)")
    return (video_key, value), sequence, frame


def _track_of(ann: dict[str, Any], image: dict[str, Any], path: str | Path, where: str) -> str | None:
    """The track of an annotation, ``<sequence>-<track id>``, or None."""
    key = next((k for k in TRACK_KEYS if ann.get(k) is not None), None)
    if key is None:
        return None
    value = _field(ann, key, (int, str), path, where)
    if "sequence" not in image:
        raise _fail(path, f"{where}.{key}", f"a track needs a frame of a video, but image {image['file']!r} has no "
                                            f"{' or '.join(VIDEO_KEYS)} with {' or '.join(FRAME_KEYS)}")
    return f"{image['sequence']}-{value}"


def _camera_of(im: dict[str, Any], file_name: str, cameras: CameraTable | None, path: str | Path,
               where: str) -> dict[str, Any]:
    if "K" in im:
        K = im["K"]
        if not (isinstance(K, list) and len(K) == 3 and all(isinstance(r, list) and len(r) == 3
                                                             and all(_number(v) for v in r) for r in K)):
            raise _fail(path, f"{where}.K", f"expected a 3x3 matrix of numbers, got {K!r:.60}")
        return {"K": K}
    camera = None if cameras is None else cameras.camera_for(file_name)
    if camera is not None:
        return dict(camera)
    how = "no camera in the cameras file matches it" if cameras else "give --cameras CAMERAS.json"
    raise _fail(path, where, f"image {file_name!r} has no camera: no 'K' in the image and {how}")


def _triplets(ann: dict[str, Any], names: list[str], path: str | Path, where: str,
              summary: ImportSummary) -> dict[str, tuple[float, float, bool]]:
    """The labelled keypoints of an annotation: name -> (x, y, visible)."""
    kp = _field(ann, "keypoints", list, path, where)
    if len(kp) != 3 * len(names):
        raise _fail(path, f"{where}.keypoints",
                    f"expected {3 * len(names)} numbers (x, y, v for {len(names)} keypoints), got {len(kp)}")
    out = {}
    for j, name in enumerate(names):
        x, y, v = kp[3 * j: 3 * j + 3]
        if not (_number(x) and _number(y) and v in (0, 1, 2)) or isinstance(v, bool):
            raise _fail(path, f"{where}.keypoints[{3 * j}:{3 * j + 3}]",
                        f"keypoint {j} ({name}): expected x, y finite and v in 0, 1, 2, got {[x, y, v]!r:.60}")
        if v == 0:
            summary.unlabelled += 1
            continue
        summary.hidden_kept += v == 1
        out[name] = (float(x), float(y), v == 2)
    return out


def _make_parts(parts: list[Any], labelled: dict[str, tuple[float, float, bool]],
                prototype: str) -> tuple[list[dict[str, Any]], set[str]]:
    """The annotation parts a vehicle's labelled keypoints make, and the keypoints they took."""
    out: list[dict[str, Any]] = []
    taken: set[str] = set()
    for part in parts:
        names = keypoints_of(part)
        if any(n not in labelled or n in taken for n in names):
            continue
        if isinstance(part, MappingLength) and part.metres is None:
            continue  # no size to give it (the toosicubix mapping's wheelbases and tyres)
        taken |= set(names)
        xy = [list(labelled[n][:2]) for n in names]
        if isinstance(part, MappingKeypoint):
            pos = part.position_for(prototype)
            entry: dict[str, Any] = {"kind": "keypoint", "name": part.keypoint, "xy": xy[0], "at": list(pos.at),
                                     "spread": list(pos.spread)}
            if not labelled[part.keypoint][2]:
                entry["visible"] = False
            out.append(entry)
        elif isinstance(part, MappingPoint):
            out.append({"kind": "point", "part": part.part, "xy": xy[0]})
        elif isinstance(part, MappingSymmetry):
            out.append({"kind": "symmetry", "face": part.face, "left": xy[0], "right": xy[1]})
        elif isinstance(part, MappingDirection):
            out.append({"kind": "direction", "axis": part.axis, "tail": xy[0], "head": xy[1]})
        elif isinstance(part, MappingPlate):
            pos = part.position_for(prototype)
            out.append({"kind": "plate", "face": part.face, "a": xy[0], "b": xy[1], "at": list(pos.at),
                        "spread": list(pos.spread), "metres": part.metres, "sigma": part.sigma})
        else:
            out.append({"kind": "length", "feature": part.feature, "a": xy[0], "b": xy[1], "metres": part.metres,
                        "sigma": part.sigma})
    return out, taken
