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

import json
import re
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from toosicubix import fields
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
from toosicubix.annotations.schema import ImageAnnotation, TrackBook, _describe, _json_path
from toosicubix.errors import FormatError, InputFileError
from toosicubix.fields import shown
from toosicubix.formats.atomic import atomic_write_json_items
from toosicubix.formats.cameras import CameraTable
from toosicubix.formats.tool_import import frame_image_id, sequence_id_for
from toosicubix.jsonfile import read_json, read_json_text, scan_object
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
        names = kinds.__name__ if isinstance(kinds, type) else " or ".join(k.__name__ for k in kinds)
        raise _fail(path, f"{where}.{key}", f"expected {_KIND_NAMES.get(names, names)}, got {shown(value)}")
    return value


#: How a message names a JSON type.
_KIND_NAMES = {"list": "a list", "dict": "an object", "str": "a string"}


def _id(obj: dict[str, Any], key: str, path: str | Path, where: str, what: str) -> str | int:
    """``obj[key]``, an id by the field rules (a string or an integer of sane length)."""
    if key not in obj:
        raise _fail(path, f"{where}.{key}", "missing required field")
    return fields.identifier(obj[key], path, f"{where}.{key}", what=what)


class CocoImport:
    """A COCO keypoint file read for import into an annotation file v1, image by image.

    Reading it (the constructor) checks every field of every entry, in file order, and counts what the import
    makes (:attr:`summary`); :meth:`images` then makes and validates each image's document in turn, so that a large
    file is never held whole: the ``annotations`` array (nearly all of a keypoint file) stays text, each annotation
    decoded when it is checked and again when its image is made. A 101 MB ApolloCar3D-like file (103,400 cars)
    peaked at 4.2 GB held whole; read so, it stays near three times its text (benchmarks/RESULTS.md).

    Parameters
    ----------
    coco_path : the COCO keypoint file
    mapping : from :func:`load_mapping`
    cameras : from :func:`toosicubix.formats.cameras.load_cameras`; None: every image must carry its own ``K``
    options : the mapping's optional parts to use (e.g. ``("plates",)``)

    Raises
    ------
    InputFileError
        Naming the file and the JSON path: a malformed entry (by the field rules of :mod:`toosicubix.fields`), an
        image without a camera, a keypoint the mapping does not know, a bad triplet.
    """

    def __init__(self, coco_path: str | Path, mapping: MappingFile, cameras: CameraTable | None = None,
                 options: tuple[str, ...] = ()):
        self.path = coco_path
        self.mapping = mapping
        self.summary = ImportSummary()
        # Each enabled part with the keypoints it takes (asked of every part of every annotation).
        self._enabled = [(p, keypoints_of(p)) for p in mapping.parts if p.option is None or p.option in options]
        # Per keypoint, the enabled parts (their places in that list) that take it: a vehicle labels a few keypoints
        # of the mapping's many, and only parts whose keypoints are all labelled can be made.
        self._takers: dict[str, list[int]] = {}
        for k, (_, names) in enumerate(self._enabled):
            for name in names:
                self._takers.setdefault(name, []).append(k)
        try:
            self._text = read_json_text(coco_path)
        except FormatError as exc:
            raise _fail(coco_path, "$", exc.message) from None
        scanned = scan_object(self._text, coco_path, spans_of=("annotations",), at_root=True)
        if scanned is None:
            read_json(coco_path, at_root=True)  # names the line of invalid JSON
            raise _fail(coco_path, "$", "expected a COCO object with images, annotations and categories")
        data, spans = scanned
        self._categories = self._read_categories(data)
        self._read_images(data, cameras)
        self.summary.images = len(self._images)
        if "annotations" in spans:
            annotation_spans = spans["annotations"]
        else:
            annotation_spans = []
            _field(data, "annotations", list, coco_path, "$")  # missing, or not a list
        self._spans: dict[Any, list[tuple[int, int]]] = {key: [] for key in self._images}
        decoder = json.JSONDecoder()
        for i, (start, _) in enumerate(annotation_spans):
            ann, _ = decoder.raw_decode(self._text, start)
            image_key, vehicle = self._vehicle(ann, i, self.summary)
            if vehicle is not None:
                self._spans[image_key].append((start, i))

    def _read_categories(self, data: dict[str, Any]) -> dict[Any, tuple[str, list[str] | None]]:
        path, known = self.path, self.mapping.known_keypoints()
        categories: dict[Any, tuple[str, list[str] | None]] = {}
        for i, cat in enumerate(_field(data, "categories", list, path, "$")):
            where = f"$.categories[{i}]"
            if not isinstance(cat, dict):
                raise _fail(path, where, f"expected an object with id, name and keypoints, got {shown(cat)}")
            cat_id = _id(cat, "id", path, where, "a category id")
            names = cat.get("keypoints")
            if isinstance(names, list) and all(n == "" for n in names):
                names = None  # unnamed (ApolloCar3D's file): the mapping's names by index apply
            if names is not None:
                if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
                    raise _fail(path, f"{where}.keypoints", "expected a list of keypoint names")
                for j, name in enumerate(names):
                    if name not in known:
                        raise _fail(path, f"{where}.keypoints[{j}]",
                                    f"keypoint {shown(name)} is not known to the mapping {self.mapping.name!r}")
            name = cat.get("name", cat_id)
            if not isinstance(name, str | int) or isinstance(name, bool):
                raise _fail(path, f"{where}.name", f"expected a category name (a string), got {shown(name)}")
            categories[cat_id] = (str(fields.identifier(name, path, f"{where}.name", what="a category name")),
                                  names)
        return categories

    def _read_images(self, data: dict[str, Any], cameras: CameraTable | None) -> None:
        path = self.path
        self._images: dict[Any, dict[str, Any]] = {}
        ids: dict[str, str] = {}  # the imported image id, folded to lower case -> where
        videos = _video_names(data, path)
        sequences: dict[str, tuple[Any, str]] = {}  # sequence -> (the video it names, where first)
        for i, im in enumerate(_field(data, "images", list, path, "$")):
            where = f"$.images[{i}]"
            if not isinstance(im, dict):
                raise _fail(path, where, f"expected an object with id and file_name, got {shown(im)}")
            image_id = _id(im, "id", path, where, "an image id")
            file_name = _field(im, "file_name", str, path, where)
            camera = _camera_of(im, file_name, cameras, path, where)
            doc: dict[str, Any] = {"id": Path(file_name).stem, "file": file_name}
            frame_of = _video_frame(im, videos, path, where)
            if frame_of is not None:
                video, sequence, frame = frame_of
                first = sequences.setdefault(sequence, (video, where))
                if first[0] != video:
                    raise _fail(path, where, f"videos {shown(first[0][1])} (at {first[1]}) and {shown(video[1])} both "
                                             f"become sequence {sequence!r}: rename one")
                doc.update(id=frame_image_id(sequence, frame), sequence=sequence, frame=frame)
            doc.update(camera=camera, vehicles=[])
            if im.get("width") is not None or im.get("height") is not None:
                doc["size"] = [fields.image_side(im.get("width"), path, f"{where}.width"),
                               fields.image_side(im.get("height"), path, f"{where}.height")]
            if image_id in self._images:
                raise _fail(path, f"{where}.id", f"image id {shown(image_id)} appears twice")
            folded = str(doc["id"]).lower()  # image ids name files, and some file systems ignore case
            if folded in ids:
                raise _fail(path, where, f"this image and the one at {ids[folded]} both get the image id "
                                         f"{shown(doc['id'])} (from file_name{', video and frame' if frame_of else ''}"
                                         f"; ids name files, compared ignoring case): rename one")
            ids[folded] = where
            self._images[image_id] = doc

    def _vehicle(self, ann: Any, i: int, summary: ImportSummary | None) -> tuple[Any, dict[str, Any] | None]:
        """The image key and the vehicle of annotation ``i`` (None: a crowd annotation, skipped); counted in
        ``summary`` when given."""
        path, mapping = self.path, self.mapping
        where = f"$.annotations[{i}]"
        if not isinstance(ann, dict):
            raise _fail(path, where, f"expected an object with id, image_id and keypoints, got {shown(ann)}")
        ann_id = _id(ann, "id", path, where, "an annotation id")
        image_id = _id(ann, "image_id", path, where, "an image id")
        if image_id not in self._images:
            raise _fail(path, f"{where}.image_id", f"no image has id {shown(image_id)}")
        image = self._images[image_id]
        if ann.get("iscrowd") in (1, True):
            if summary is not None:
                summary.crowd_skipped += 1
            return image_id, None
        category = ann.get("category_id")
        if category is not None:
            category = fields.identifier(category, path, f"{where}.category_id", what="a category id")
        cat_name, names = self._categories.get(category, (str(category), None))
        track = _track_of(ann, image, path, where)
        if names is None:
            names = mapping.keypoints
        labelled: dict[str, tuple[float, float, bool]] = {}
        if track is None or "keypoints" in ann:  # a tracked box without keypoints is a frame with a box only
            if names is None:
                raise _fail(path, f"{where}.category_id", f"category {shown(category)} does not name its keypoints, "
                                                          f"nor does the mapping {mapping.name!r}")
            labelled = _triplets(ann, names, path, where, summary)
        prototype = mapping.prototypes.get(str(category), mapping.prototypes.get(cat_name, mapping.prototype))
        candidates = sorted({k for name in labelled for k in self._takers.get(name, ())})
        parts, taken = _make_parts([self._enabled[k] for k in candidates], labelled, prototype)
        vehicle: dict[str, Any] = {"id": str(ann_id), "prototype": prototype}
        if track is not None:
            vehicle["track"] = track
        vehicle["parts"] = parts
        if "bbox" in ann:
            vehicle["box2d"] = _box(ann["bbox"], path, f"{where}.bbox")
        if summary is not None:
            summary.unused.update(name for name in labelled if name not in taken)
            if track is not None:
                summary.tracks.add(track)
                summary.tracked_without_parts += not parts
            summary.vehicles += 1
            summary.vehicles_without_parts += not parts and track is None
            for note in import_notes(prototype, labelled):
                summary.notes[note] += 1
            for part in parts:
                summary.parts[part["kind"]] += 1
                summary.clicks += len(KINDS[part["kind"]].clicks)
        return image_id, vehicle

    def images(self) -> Iterator[dict[str, Any]]:
        """Each image of the annotation file, in the COCO file's order, validated as the annotation file's
        ``$.images[i]``; then the rules across frames (one prototype per track, ...).

        Raises
        ------
        InputFileError
            Naming the file ("as imported") and the JSON path of the first image that breaks a rule of the
            annotation file (with its image id), or of every rule across frames broken.
        """
        decoder = json.JSONDecoder()
        source = f"{self.path} (as imported)"
        book = TrackBook()
        for index, (image_id, header) in enumerate(self._images.items()):
            image = {**header, "vehicles": [self._vehicle(decoder.raw_decode(self._text, start)[0], i, None)[1]
                                            for start, i in self._spans[image_id]]}
            try:
                book.add(index, ImageAnnotation.model_validate(image))
            except ValidationError as exc:
                raise InputFileError(source, [(_json_path(("images", index, *err["loc"])) + f" (image "
                                               f"{image['id']!r})", _describe(err)) for err in exc.errors()]) from None
            yield image
        if book.problems:
            ids = [image["id"] for image in self._images.values()]
            raise InputFileError(source, [(f"{where} (image {ids[_image_index(where)]!r})", message)
                                          for where, message in book.problems])

    def document(self) -> dict[str, Any]:
        """The whole annotation file v1 document (what :meth:`images` gives, in one list)."""
        return {"toosicubix": schemas.SCHEMA_VERSION, "images": list(self.images())}

    def write(self, out_path: str | Path) -> int:
        """Write the annotation file atomically, one image at a time; the number of images.

        Raises
        ------
        InputFileError
            As :meth:`images`; nothing is written then.
        OSError
            The file cannot be written.
        """
        return atomic_write_json_items(out_path, {"toosicubix": schemas.SCHEMA_VERSION}, "images", self.images())


def _image_index(where: str) -> int:
    """The index of the image a JSON path ``$.images[i]...`` is in."""
    return int(re.match(r"\$\.images\[(\d+)\]", where).group(1))  # type: ignore[union-attr]


def coco_to_annotations(coco_path: str | Path, mapping: MappingFile, cameras: CameraTable | None = None,
                        options: tuple[str, ...] = ()) -> tuple[dict[str, Any], ImportSummary]:
    """Turn a COCO keypoint file into an annotation file v1 (a JSON document, already validated): the whole
    document of :class:`CocoImport` (which writes a large one image by image instead).

    Returns
    -------
    (document, summary)

    Raises
    ------
    InputFileError
        As :class:`CocoImport` and :meth:`CocoImport.images`.
    """
    imported = CocoImport(coco_path, mapping, cameras, options)
    return imported.document(), imported.summary


def _box(box: Any, path: str | Path, where: str) -> list[float]:
    """A COCO ``bbox`` ``[x, y, w, h]`` as the annotation file's ``box2d`` ``[x1, y1, x2, y2]``."""
    if not (isinstance(box, list) and len(box) == 4):
        raise _fail(path, where, f"expected [x, y, w, h] with w, h > 0, got {shown(box)}")
    x, y = (fields.pixel(v, path, f"{where}[{k}]") for k, v in enumerate(box[:2]))
    w, h = (fields.number(v, path, f"{where}[{k + 2}]", low=0.0, high=2 * fields.MAX_PIXEL, what="a box side")
            for k, v in enumerate(box[2:]))
    if w <= 0 or h <= 0:
        raise _fail(path, where, f"expected [x, y, w, h] with w, h > 0, got {shown(box)}")
    return [x, y, x + w, y + h]


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
        if not isinstance(video, dict):
            raise _fail(path, f"$.videos[{i}]", f"expected an object with id and name, got {shown(video)}")
        video_id = _id(video, "id", path, f"$.videos[{i}]", "a video id")
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
                                                  f"got {shown(frame, 40)}")
    if video_key == "video_id":
        value = _id(im, video_key, path, where, "a video id")
    else:
        value = _field(im, video_key, str, path, where)
    name = videos.get(value) if video_key == "video_id" else None
    name = name or next((im[k] for k in VIDEO_KEYS[1:] if isinstance(im.get(k), str)), None) or str(value)
    sequence = sequence_id_for(name)
    if not sequence:
        raise _fail(path, f"{where}.{video_key}", f"video {shown(name)} makes no sequence name (letters or digits "
                                                  "needed)")
    return (video_key, value), sequence, frame


def _track_of(ann: dict[str, Any], image: dict[str, Any], path: str | Path, where: str) -> str | None:
    """The track of an annotation, ``<sequence>-<track id>``, or None."""
    key = next((k for k in TRACK_KEYS if ann.get(k) is not None), None)
    if key is None:
        return None
    value = _id(ann, key, path, where, "a track id")
    if "sequence" not in image:
        raise _fail(path, f"{where}.{key}", f"a track needs a frame of a video, but image {image['file']!r} has no "
                                            f"{' or '.join(VIDEO_KEYS)} with {' or '.join(FRAME_KEYS)}")
    return f"{image['sequence']}-{value}"


def _camera_of(im: dict[str, Any], file_name: str, cameras: CameraTable | None, path: str | Path,
               where: str) -> dict[str, Any]:
    if "K" in im:
        K = im["K"]
        if not (isinstance(K, list) and len(K) == 3 and all(isinstance(r, list) and len(r) == 3 for r in K)):
            raise _fail(path, f"{where}.K", f"expected a 3x3 matrix of numbers, got {shown(K)}")
        return {"K": [[fields.number(v, path, f"{where}.K[{r}][{c}]") for c, v in enumerate(row)]
                      for r, row in enumerate(K)]}
    camera = None if cameras is None else cameras.camera_for(file_name)
    if camera is not None:
        return dict(camera)
    how = "no camera in the cameras file matches it" if cameras else "give --cameras CAMERAS.json"
    raise _fail(path, where, f"image {shown(file_name)} has no camera: no 'K' in the image and {how}")


def _triplets(ann: dict[str, Any], names: list[str], path: str | Path, where: str,
              summary: ImportSummary | None) -> dict[str, tuple[float, float, bool]]:
    """The labelled keypoints of an annotation: name -> (x, y, visible); counted in ``summary`` when given."""
    kp = _field(ann, "keypoints", list, path, where)
    if len(kp) != 3 * len(names):
        raise _fail(path, f"{where}.keypoints",
                    f"expected {3 * len(names)} numbers (x, y, v for {len(names)} keypoints), got {len(kp)}")
    out = {}
    unlabelled, hidden = 0, 0
    for j, (name, x, y, v) in enumerate(zip(names, kp[0::3], kp[1::3], kp[2::3], strict=True)):
        if not (fields.is_pixel(x) and fields.is_pixel(y) and v in (0, 1, 2)) or isinstance(v, bool):
            raise _fail(path, f"{where}.keypoints[{3 * j}:{3 * j + 3}]",
                        f"keypoint {j} ({name}): expected x, y pixel coordinates within +-{fields.MAX_PIXEL:.0f} and "
                        f"v in 0, 1, 2, got {shown([x, y, v])}")
        if v == 0:
            unlabelled += 1
            continue
        hidden += v == 1
        out[name] = (float(x), float(y), v == 2)
    if summary is not None:
        summary.unlabelled += unlabelled
        summary.hidden_kept += hidden
    return out


def _make_parts(parts: list[tuple[Any, tuple[str, ...]]], labelled: dict[str, tuple[float, float, bool]],
                prototype: str) -> tuple[list[dict[str, Any]], set[str]]:
    """The annotation parts a vehicle's labelled keypoints make (``parts``: each with the keypoints it takes, in the
    mapping's order; a part listed before takes a keypoint first), and the keypoints they took."""
    out: list[dict[str, Any]] = []
    taken: set[str] = set()
    for part, names in parts:
        if len(names) == 1:  # most parts take one keypoint
            if names[0] not in labelled or names[0] in taken:
                continue
        elif any(n not in labelled or n in taken for n in names):
            continue
        if isinstance(part, MappingLength) and part.metres is None:
            continue  # no size to give it (the toosicubix mapping's wheelbases and tyres)
        taken.update(names)
        xy = [[labelled[n][0], labelled[n][1]] for n in names]
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
