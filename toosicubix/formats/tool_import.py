"""What the labelling-tool importers share: named keypoints per vehicle -> annotation file v1.

An importer (:mod:`toosicubix.formats.cvat`, :mod:`toosicubix.formats.labelstudio`) reads its tool's export
into :class:`ToolVehicle` objects per image and hands them to :class:`DocumentBuilder`, which checks the
points against the image, turns keypoints into parts (:mod:`toosicubix.parts.keypoints`), attaches the camera
from a cameras file and collects every warning with the image and element it is about.

Videos: an image may be a frame of a sequence (``add_image(..., sequence=, frame=)``) and a vehicle a track
(:attr:`ToolVehicle.track`). A tracked vehicle is kept without parts (a box only, or nothing: the solver
interpolates its pose from the track's other frames); an untracked one without usable keypoints is left out.
:func:`sequence_id_for` makes a sequence name from a tool's video or task name, :func:`check_imported` checks
a finished document, the rules across frames (one prototype per track, ...) first.

:func:`import_hint` recognises a tool's file given where an annotation file belongs (``fit``, ``validate``)
and says which ``toosicubix import`` turns it into one.
"""

from __future__ import annotations

import re
import shlex
import zipfile
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

from pydantic import ValidationError

from toosicubix.annotations.schema import MAX_FRAME, MAX_ID_LENGTH, ImageAnnotation, TrackBook, parse_annotations
from toosicubix.errors import FormatError, InputError, InputFileError
from toosicubix.formats.cameras import CameraTable
from toosicubix.jsonfile import read_json
from toosicubix.parts.keypoints import parts_from_keypoints


@dataclass
class ToolKeypoint:
    """One clicked keypoint as the tool stored it.

    Attributes
    ----------
    name : the keypoint (label) name
    xy : (x, y) pixels
    element : where it is in the export, for messages (e.g. "skeleton 2, points 'wheel-front-left'")
    """

    name: str
    xy: tuple[float, float]
    element: str


@dataclass
class ToolVehicle:
    """One vehicle as the tool stored it: its keypoints and, where the tool has them, prototype and box; on a
    frame of a video, its ``track`` (the same vehicle across the frames of the sequence)."""

    id: str
    element: str
    prototype: str | None = None
    box2d: tuple[float, float, float, float] | None = None
    keypoints: list[ToolKeypoint] = field(default_factory=list)
    track: str | None = None


@dataclass
class ImportSummary:
    """What an import did: counts, and every warning (also printed by the CLI)."""

    images: int = 0
    vehicles: int = 0
    keypoints: int = 0
    warnings: list[str] = field(default_factory=list)
    left_out: Counter = field(default_factory=Counter)  # keypoint name -> how many were left out
    tracks: set[str] = field(default_factory=set)  # the tracks of the tracked vehicles
    tracked: Counter = field(default_factory=Counter)  # tracked vehicle frames: "clicks", "box only", "neither"

    def lines(self) -> list[str]:
        out = [f"{self.images} images, {self.vehicles} vehicles, {self.keypoints} keypoints used"]
        if self.left_out:
            out.append("left out: " + ", ".join(f"{name} x{n}" for name, n in sorted(self.left_out.items())))
        if self.tracks:
            out.append(f"{len(self.tracks)} tracks; their vehicle frames: {self.tracked['clicks']} with clicks, "
                       f"{self.tracked['box only']} with a box only, {self.tracked['neither']} with neither "
                       "(the solver interpolates those)")
        return out


_ID_BAD = re.compile(r"[^A-Za-z0-9_.\-]")


def image_id_for(file_name: str) -> str:
    """The annotation file's image id for a file name: its stem, other characters than ``A-Za-z0-9_.-`` as ``_``."""
    stem = PurePosixPath(file_name.replace("\\", "/")).stem or "image"
    image_id = _ID_BAD.sub("_", stem)
    return image_id if image_id[0].isalnum() else f"i{image_id}"


#: The longest sequence name: a frame's image id ``<sequence>_<frame:06d>`` (up to 7 digits) stays within
#: the schema's ``MAX_ID_LENGTH``.
MAX_SEQUENCE_LENGTH = MAX_ID_LENGTH - len(f"_{MAX_FRAME}")


def sequence_id_for(name: str) -> str:
    """A sequence name from a tool's video or task name: other characters than ``A-Za-z0-9_.-`` as ``_`` (one
    for a run), no ``_``, ``.`` or ``-`` at either end, at most :data:`MAX_SEQUENCE_LENGTH` characters; ``""``
    when nothing is left. ``"Drive 3 (front)"`` gives ``"Drive_3_front"``."""
    text = re.sub(r"_+", "_", _ID_BAD.sub("_", name)).strip("_.-")
    return text[:MAX_SEQUENCE_LENGTH].rstrip("_.-")


def check_sequence_name(name: str) -> str:
    """``name`` if it can name a sequence as it is (what :func:`sequence_id_for` leaves unchanged).

    Raises
    ------
    ValueError
        Naming what a sequence name may hold.
    """
    if not name or sequence_id_for(name) != name:
        raise ValueError(f"expected a sequence name of letters, digits and '_', '.', '-' inside, at most "
                         f"{MAX_SEQUENCE_LENGTH} characters, got {name!r} (e.g. {sequence_id_for(name) or '0003'!r})")
    return name


def frame_image_id(sequence: str, frame: int) -> str:
    """The image id of a frame of a sequence: ``<sequence>_<frame:06d>``, e.g. ``0003_000012``."""
    return f"{sequence}_{frame:06d}"


def check_imported(document: dict[str, Any], source: str) -> None:
    """Validate an imported annotation document: first the rules across frames (:class:`TrackBook`: a frame
    once per sequence, a track in one sequence, one prototype per track), each problem at its JSON path with the
    image id, then the whole file.

    Raises
    ------
    InputFileError
        Naming ``source`` and the JSON path of every problem.
    """
    book = TrackBook()
    for index, image in enumerate(document["images"]):
        try:
            book.add(index, ImageAnnotation.model_validate(image))
        except ValidationError:
            continue  # the whole-file check below names it
    if book.problems:
        ids = [image.get("id") for image in document["images"]]
        problems = []
        for where, message in book.problems:
            index = int(re.match(r"\$\.images\[(\d+)\]", where).group(1))  # type: ignore[union-attr]
            problems.append((f"{where} (image {ids[index]!r})", message))
        raise InputFileError(source, problems)
    parse_annotations(document, source)


class DocumentBuilder:
    """Collects images and builds the annotation file v1 document.

    Parameters
    ----------
    source : the tool's export file, for messages
    cameras : the cameras file; every image needs an entry
    default_prototype : for vehicles the export gives none (a warning says so)
    lengths : feature -> (metres, sigma) of length features (see :mod:`toosicubix.parts.keypoints`)
    """

    def __init__(self, source: str, cameras: CameraTable | None, default_prototype: str = "Car",
                 lengths: dict[str, tuple[float, float]] | None = None):
        self.source = source
        self.cameras = cameras
        self.default_prototype = default_prototype
        self.lengths = lengths or {}
        self.summary = ImportSummary()
        self._images: list[dict[str, Any]] = []
        self._files: dict[str, str] = {}

    def warn(self, image: str, element: str, message: str) -> None:
        self.summary.warnings.append(f"{self.source}: image {image!r}, {element}: {message}")

    def add_image(self, file_name: str, size: tuple[int, int] | None, vehicles: list[ToolVehicle], *,
                  sequence: str | None = None, frame: int | None = None) -> None:
        """Add one image with its vehicles; a frame of a video with its ``sequence`` and ``frame`` (its image id
        is then :func:`frame_image_id`, else :func:`image_id_for` the file name).

        Raises
        ------
        FormatError
            No camera for the image, or two images with the same id.
        """
        image_id = image_id_for(file_name) if sequence is None or frame is None else frame_image_id(sequence, frame)
        if image_id in self._files:
            raise FormatError(self.source, f"images {self._files[image_id]!r} and {file_name!r} get the same "
                                           f"image id {image_id!r}: rename one")
        self._files[image_id] = file_name
        out_vehicles = []
        ids: set[str] = set()
        for vehicle in vehicles:
            converted = self._vehicle(file_name, size, vehicle)
            if converted is None:
                continue
            if converted["id"] in ids:
                raise FormatError(self.source, f"image {file_name!r}: two vehicles with id {converted['id']!r}")
            ids.add(converted["id"])
            out_vehicles.append(converted)
        camera = self.cameras.camera_for(file_name) if self.cameras is not None else None
        if camera is None:
            hint = self.cameras.why_none(file_name) if self.cameras is not None else "give --cameras CAMERAS.json"
            if not out_vehicles:
                self.warn(file_name, "image", f"no vehicles and no camera ({hint}): image left out")
                return
            raise FormatError(self.source, f"image {file_name!r}: no camera ({hint})")
        image: dict[str, Any] = {"id": image_id, "file": file_name}
        if sequence is not None:
            image["sequence"], image["frame"] = sequence, frame
        if size is not None:
            image["size"] = [int(size[0]), int(size[1])]
        image["camera"] = camera
        image["vehicles"] = out_vehicles
        self._images.append(image)
        self.summary.images += 1

    def _vehicle(self, file_name: str, size: tuple[int, int] | None, vehicle: ToolVehicle) -> dict[str, Any] | None:
        named = []
        for kp in vehicle.keypoints:
            x, y = kp.xy
            if size is not None and not (0.0 <= x <= size[0] and 0.0 <= y <= size[1]):
                self.warn(file_name, kp.element, f"({x:.1f}, {y:.1f}) lies outside the {size[0]}x{size[1]} image: "
                                                 "left out")
                self.summary.left_out[kp.name] += 1
                continue
            named.append((kp.name, kp.xy))
        conversion = parts_from_keypoints(named, self.lengths, vehicle.prototype or self.default_prototype)
        elements = {kp.name: kp.element for kp in vehicle.keypoints}
        for name, message in conversion.problems:
            self.warn(file_name, elements.get(name, vehicle.element), f"keypoint {name!r}: {message}: left out")
            self.summary.left_out[name] += 1
        if not conversion.parts and vehicle.track is None:
            self.warn(file_name, vehicle.element, "no usable keypoints: vehicle left out")
            return None
        if not conversion.parts and vehicle.keypoints:
            self.warn(file_name, vehicle.element, "no usable keypoints: kept without parts (a tracked vehicle)")
        prototype = vehicle.prototype
        if not prototype:
            self.warn(file_name, vehicle.element, f"no prototype: {self.default_prototype!r} assumed")
            prototype = self.default_prototype
        out: dict[str, Any] = {"id": vehicle.id, "prototype": prototype}
        if vehicle.track is not None:
            out["track"] = vehicle.track
            self.summary.tracks.add(vehicle.track)
            self.summary.tracked["clicks" if conversion.parts else "box only" if vehicle.box2d else "neither"] += 1
        if vehicle.box2d is not None:
            out["box2d"] = [float(v) for v in vehicle.box2d]
        out["parts"] = conversion.parts
        self.summary.vehicles += 1
        self.summary.keypoints += sum(1 if p["kind"] == "point" else 2 for p in conversion.parts)
        return out

    def document(self) -> dict[str, Any]:
        """The annotation file v1 document (JSON-ready)."""
        return {"toosicubix": 1, "images": self._images}


#: The first bytes :func:`import_hint` looks at for XML, zip and KITTI files.
_HEAD_BYTES = 1 << 16
_XML_ROOT = re.compile(r"<([A-Za-z_][\w.:-]*)")


def _kitti_label_line(line: str) -> str | None:
    """'kitti' for a KITTI object label line (``type`` and 14 or 15 numbers), 'kitti-tracking' for a tracking one
    (``frame track_id`` in front), else None."""
    fields = line.split()
    kind = "kitti"
    if len(fields) in (17, 18) and fields[0].isdigit() and fields[1].lstrip("-").isdigit():
        fields, kind = fields[2:], "kitti-tracking"
    if len(fields) not in (15, 16):
        return None
    try:
        float(fields[0])
        return None  # a number where the type belongs
    except ValueError:
        pass
    try:
        [float(v) for v in fields[1:]]
    except ValueError:
        return None
    return kind


def _tool_of(path: Path) -> str | None:
    """'coco', 'label-studio', 'cvat', 'kitti' or 'kitti-tracking' when ``path`` has that tool's top-level shape,
    else None."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(_HEAD_BYTES)
    except OSError:
        return None
    if head.startswith(b"PK\x03\x04"):
        try:
            with zipfile.ZipFile(path) as archive:
                names = archive.namelist()
        except (zipfile.BadZipFile, OSError):
            return None
        return "cvat" if any(PurePosixPath(n).name == "annotations.xml" for n in names) else None
    text = head.decode("utf-8-sig", errors="replace").lstrip()
    if text.startswith("<"):
        root = _XML_ROOT.search(re.sub(r"<\?.*?\?>|<!--.*?-->", "", text, flags=re.DOTALL))
        return "cvat" if root is not None and root.group(1) == "annotations" else None
    if text.startswith(("{", "[")):
        try:
            doc = read_json(path)
        except InputError:
            return None
        if isinstance(doc, dict) and "toosicubix" not in doc and isinstance(doc.get("images"), list) \
                and isinstance(doc.get("annotations"), list):
            return "coco"
        tasks = doc if isinstance(doc, list) else [doc]
        if tasks and all(isinstance(t, dict) and isinstance(t.get("data"), dict) for t in tasks[:10]) \
                and (isinstance(doc, list) or {"annotations", "completions", "predictions"} & set(doc)):
            return "label-studio"
        return None
    first = next((line for line in text.splitlines() if line.strip()), "")
    return _kitti_label_line(first)


def import_hint(path: str | Path) -> str | None:
    """One line for a labelling tool's file given where an annotation file belongs: what it is and which
    ``toosicubix import`` turns it into an annotation file; None when ``path`` is none of them (an annotation
    file, or anything else).

    Recognised by the top-level shape: a COCO file (``images`` and ``annotations`` lists), a Label Studio
    export (a list of tasks with ``data``), a CVAT XML (root ``<annotations>``) or its export zip (holding
    ``annotations.xml``), a KITTI label file (lines of ``type truncated occluded alpha`` and 11 numbers).
    """
    path = Path(path)
    name = shlex.quote(str(path))
    tool = _tool_of(path)
    if tool == "coco":
        return (f"{path}: a COCO keypoint file, not an annotation file: turn it into one with `toosicubix import coco "
                f"{name} --mapping MAPPING --cameras CAMERAS -o annotations.json` (MAPPING: apollocar3d-66, "
                "toosicubix or a mapping file)")
    if tool == "label-studio":
        return (f"{path}: a Label Studio JSON export, not an annotation file: turn it into one with `toosicubix "
                f"import label-studio {name} --cameras CAMERAS -o annotations.json`")
    if tool == "cvat":
        return (f"{path}: a CVAT for images or video 1.1 export, not an annotation file: turn it into one with "
                f"`toosicubix import cvat {name} --cameras CAMERAS -o annotations.json`")
    if tool in ("kitti", "kitti-tracking"):
        option = f"--{tool}"
        return (f"{path}: a {'KITTI tracking' if tool == 'kitti-tracking' else 'KITTI'} label file (3D boxes, no "
                f"clicks), not an annotation file: no `toosicubix import` reads it; `toosicubix simulate {option} DIR "
                f"-o annotations.json` makes clicks on such labels and `toosicubix eval {option} DIR` scores a fit "
                "against them")
    return None
