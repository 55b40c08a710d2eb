"""CVAT for images 1.1 and CVAT for video 1.1 XML -> annotation file v1 (the review export is
:mod:`toosicubix.formats.cvat_export`).

Import (as CVAT's ``dump_as_cvat_annotation`` writes it, task, job or project export)::

    <annotations><version>1.1</version><meta><task|project|job>...<labels>...</labels>...</meta>
      <image id="0" name="frames/000001.png" width="1242" height="375" [subset task_id]>
        <skeleton label="vehicle" source="manual" z_order="0">
          <points label="wheel-front-left" source="manual" outside="0" occluded="0" points="401.20,202.00"/>
          <points label="rear-pair1-left" source="manual" outside="1" occluded="0" points="0.00,0.00"/>
          <attribute name="prototype">Car</attribute>
        </skeleton>
        <points label="rear-center" source="manual" occluded="0" points="769.00,243.80" z_order="0" group_id="2"/>
        <box label="Car" source="manual" occluded="0" xtl=".." ytl=".." xbr=".." ybr=".." z_order="0" group_id="2"/>
      </image>

- A ``skeleton`` is one vehicle; its ``points`` children are its keypoints, named by their label
  (:mod:`toosicubix.parts.keypoints`); ``outside="1"`` marks a keypoint not clicked (left out), ``occluded="1"``
  one clicked where it is hidden (kept). The ``prototype`` attribute names the size prior.
- Loose ``points`` shapes are grouped into vehicles by ``group_id``; a ``box`` in the group gives the box
  and the prototype (its ``prototype`` attribute, else its label). In an image without skeletons or groups,
  all loose points are one vehicle.

CVAT for video 1.1 (``dump_as_cvat_interpolation``; a task or job export) has no ``<image>``: its shapes live in
tracks, one child per frame, and the frames of the task become one *sequence*::

    <annotations><version>1.1</version><meta><task><id>7</id><name>drive 3</name>...
        <original_size><width>1242</width><height>375</height></original_size></task></meta>
      <track id="0" label="vehicle" source="manual" group_id="1">
        <skeleton frame="12" keyframe="1" z_order="0">
          <points label="wheel-front-left" keyframe="1" outside="0" occluded="0" points="401.20,202.00"/>
          <attribute name="prototype">Car</attribute>
        </skeleton>
        <skeleton frame="13" keyframe="0" z_order="0">...</skeleton>
      </track>
      <track id="1" label="Car" source="manual" group_id="1">
        <box frame="12" keyframe="1" outside="0" occluded="0" xtl=".." ytl=".." xbr=".." ybr=".." z_order="0"/>
        ...

CVAT writes every frame of a track from its first keyframe on: the keyframes a person set (``keyframe="1"``),
the frames between them as it interpolates them (``keyframe="0"``), and after the last keyframe copies up to the
task's end, unless a keyframe with ``outside="1"`` says the object left the view (nothing is written then until
its next keyframe). The import reads them so:

- *Sequence*: the task's name (:func:`~toosicubix.formats.tool_import.sequence_id_for`), else ``task_<id>``
  (``job_<id>`` for a job export), or the name the caller gives. A frame is the image
  ``<sequence>_<frame:06d>`` with ``"sequence"`` and ``"frame"`` (CVAT's frame number, which counts from the
  video's first frame) and the file :data:`FRAME_FILE` (the name CVAT's export gives a video frame; the XML
  names no frame files). Frames where no vehicle is present are not written.
- *Vehicles*: tracks with the same ``group_id`` are one vehicle (e.g. a skeleton track and a box track); a track
  without one is a vehicle of its own (a box track alone: a vehicle with boxes only). Points tracks without a
  ``group_id`` are one vehicle when the task has no other tracks, else left out with a warning. A vehicle is
  named by its smallest track id: vehicle ``"id"`` that id, ``"track"`` ``<sequence>-<id>``.
- *Outside*: a shape with ``outside="1"`` (a skeleton: all its points outside) means the vehicle is not in that
  frame; a vehicle is in a frame where any of its tracks is.
- *Clicks* come from keyframes only: a skeleton point is a click on a frame where both the skeleton and the
  point are keyframes (a point without its own flag takes its skeleton's), a point shape where it is a
  keyframe. Interpolated positions are CVAT's guess, not a person's click: such a frame gets no parts, only
  its box if there is one, else an empty tracked vehicle whose pose the solver interpolates.
- *Boxes* are taken on every frame where the box track is not outside, interpolated or not (what a tracker or
  CVAT's interpolation gives is what the solver uses a box for). Two boxes of one vehicle on a frame are an
  error.
- *Prototype*: the ``prototype`` attribute of the vehicle's shapes on that frame (skeleton or points first, then
  the box), else the vehicle's first ``prototype`` attribute on any frame, else its box track's label, else the
  default (one warning per vehicle). A prototype that changes along a track is the annotation file's error (one
  prototype per track), naming the JSON path.

Project exports of video tasks are refused (export each task: one sequence each).

Either format is read from the XML or from the zip CVAT downloads (``annotations.xml`` at its root, the images
under ``images/``): a zip needs exactly one ``annotations.xml``; the XML may have at most :data:`MAX_XML_BYTES`
(a zip member's uncompressed size is checked before it is read). The parser refuses a DOCTYPE and any entity
declaration wherever it stands and in any encoding (no entity is expanded or fetched). CVAT for images is read one
``<image>`` at a time (a 100 MB export: 0.2 GB); a video's tracks are held whole (some 10 times the XML's size).

Every number is read by the field rules (:func:`toosicubix.fields.text_number`, :func:`~toosicubix.fields.
text_integer`): decimal notation in ASCII digits, so ``4_01.2`` (Python's ``float`` reads 401.2), ``nan``, ``1e999``
or ``'²'`` are refused; coordinates within the annotation file's pixel bound, image sides and frame numbers within
theirs, group and track ids of at most :data:`~toosicubix.fields.MAX_ID_DIGITS` digits. A refusal names the file,
the line and the element.
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import IO, Any
from xml.parsers import expat

from toosicubix import fields
from toosicubix.errors import FormatError
from toosicubix.fields import MAX_FRAME, MAX_ID_LENGTH, MAX_PIXEL, shown
from toosicubix.formats.cameras import CameraTable
from toosicubix.formats.templates import PROTOTYPE_ATTRIBUTE
from toosicubix.formats.tool_import import (
    DocumentBuilder,
    ImportSummary,
    ToolKeypoint,
    ToolVehicle,
    check_imported,
    check_sequence_name,
    sequence_id_for,
)

#: The file of frame ``frame`` of a video task, as CVAT's export names it (``images/`` beside annotations.xml).
FRAME_FILE = "images/frame_{frame:06d}.PNG"


#: The largest CVAT XML read, in bytes: a file, or the ``annotations.xml`` of an export zip (its uncompressed size,
#: checked before it is read and while it is read, so a zip bomb is refused rather than unpacked). CVAT writes some
#: 150 bytes per keypoint: this holds over 3 million. Images are read one at a time; a video's tree needs some 10
#: times the text's size in memory.
MAX_XML_BYTES = 512 * 1024 * 1024
#: What CVAT names the XML inside the zip it downloads for "CVAT for images 1.1" and "CVAT for video 1.1"
#: (``_export_task`` / ``_export_project`` in cvat/apps/dataset_manager/formats/cvat.py: ``annotations.xml`` at the
#: root, the frames under ``images/``).
ZIP_ANNOTATIONS = "annotations.xml"
_CHUNK = 1 << 16
#: The longest track id: a vehicle's track ``<sequence>-<track id>`` stays within the annotation file's
#: ``MAX_ID_LENGTH`` with a sequence name of half of it.
MAX_TRACK_ID = MAX_ID_LENGTH // 2


class _Element(ET.Element):
    """An element of the parsed XML with the line it starts on (1-based), for messages."""

    line = 0


class _Refused(Exception):
    """A declaration the reader does not take (a DOCTYPE, an entity), at a line."""

    def __init__(self, what: str, line: int):
        super().__init__(what)
        self.what, self.line = what, line


#: Called with each element right under the root once it is complete, the root and the name messages give the file;
#: returns True when it took the element (which is then dropped from the tree).
Taker = Callable[[ET.Element, ET.Element, Path], bool]


def _parse_stream(handle: IO[bytes], source: Path, take: Taker | None = None) -> _Element:
    """Parse CVAT XML from an open binary stream into elements that know their line; refuse any DOCTYPE, entity or
    notation declaration and any external entity, and more than :data:`MAX_XML_BYTES`.

    ``take`` sees each element right under the root as soon as it ends; an element it takes is dropped from the
    tree, so that a file of many ``<image>`` elements is read one image at a time (the tree of a 100 MB export held
    whole needs some 1 GB).

    The refusals are the XML parser's own (expat's declaration handlers, parameter entities never parsed), so they
    hold wherever the declaration stands (after a long comment too) and in any encoding the parser reads (UTF-16
    by its byte order mark, or as the XML declaration names it): no entity is ever expanded or fetched. CVAT writes
    no DOCTYPE. The standard library's parser is enough for this; defusedxml, which sets the same handlers, would
    add a dependency for no further refusal.
    """
    builder = ET.TreeBuilder(element_factory=_Element)
    parser = expat.ParserCreate()
    parser.buffer_text = True
    parser.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)

    def refuse(what: str) -> Any:
        def handler(*_: Any) -> None:
            raise _Refused(what, parser.CurrentLineNumber)
        return handler

    path: list[ET.Element] = []  # the open elements, the root first

    def start(tag: str, attributes: dict[str, str]) -> None:
        element = builder.start(tag, attributes)
        element.line = parser.CurrentLineNumber  # type: ignore[attr-defined]
        path.append(element)

    def end(tag: str) -> None:
        element = builder.end(tag)
        path.pop()
        if take is not None and len(path) == 1 and take(element, path[0], source):
            path[0].remove(element)  # the last child: found at once

    parser.StartDoctypeDeclHandler = refuse("a DOCTYPE")
    parser.EntityDeclHandler = refuse("an entity declaration")
    parser.UnparsedEntityDeclHandler = refuse("an entity declaration")
    parser.NotationDeclHandler = refuse("a notation declaration")
    parser.ExternalEntityRefHandler = refuse("an external entity")
    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = builder.data
    read = 0
    try:
        while chunk := handle.read(_CHUNK):
            read += len(chunk)
            if read > MAX_XML_BYTES:
                raise FormatError(source, f"more than {MAX_XML_BYTES} bytes of XML: larger than a CVAT export this "
                                          "reader takes")
            parser.Parse(chunk, False)
        parser.Parse(b"", True)
        return builder.close()  # type: ignore[return-value]
    except _Refused as exc:
        raise FormatError(source, f"{exc.what} is not allowed in CVAT XML (CVAT writes none; entities are never "
                                  "expanded or fetched)", exc.line) from None
    except expat.ExpatError as exc:
        raise FormatError(source, f"not valid XML: {expat.ErrorString(exc.code)} at line {exc.lineno} column "
                                  f"{exc.offset + 1}", exc.lineno) from None
    except (AssertionError, ET.ParseError) as exc:  # the builder's: a document without a root element
        raise FormatError(source, f"not valid XML: {exc or 'no root element'}") from None


def _parse_zip(path: Path, take: Taker | None) -> tuple[ET.Element, Path]:
    """The root of the one ``annotations.xml`` in a CVAT export zip, and its name for messages (``zip/member``)."""
    expected = (f"expected the zip CVAT downloads for CVAT for images 1.1 or CVAT for video 1.1, with one "
                f"{ZIP_ANNOTATIONS}")
    try:
        with zipfile.ZipFile(path) as archive:
            files = [info for info in archive.infolist() if not info.is_dir()]
            found = [info for info in files if PurePosixPath(info.filename).name == ZIP_ANNOTATIONS]
            if len(found) != 1:
                names = ", ".join(info.filename for info in (found or files)[:5]) or "nothing"
                more = f" and {len(found or files) - 5} more" if len(found or files) > 5 else ""
                what = f"{len(found)} of them" if found else "none"
                hint = ""
                if not found and any(info.filename.endswith(".json") for info in files):
                    hint = " (a COCO or Datumaro export? unzip it: `toosicubix import coco` reads a COCO keypoint file)"
                raise FormatError(path, f"{expected}; found {what} ({names}{more}){hint}")
            info = found[0]
            source = Path(f"{path}/{info.filename}")
            if info.file_size > MAX_XML_BYTES:
                raise FormatError(source, f"{info.file_size} bytes uncompressed: larger than the {MAX_XML_BYTES} "
                                          "bytes of XML this reader takes")
            with archive.open(info) as handle:
                return _parse_stream(handle, source, take), source
    except (zipfile.BadZipFile, zlib.error, EOFError) as exc:
        raise FormatError(path, f"a damaged zip archive ({exc}): {expected}") from None
    except (RuntimeError, NotImplementedError) as exc:  # encrypted, or a compression zipfile cannot read
        raise FormatError(path, f"cannot unpack: {exc}") from None


def _parse(path: Path, take: Taker | None = None) -> tuple[ET.Element, Path]:
    """The root element of a CVAT XML file or of the ``annotations.xml`` in a CVAT export zip (without the elements
    ``take`` took, see :func:`_parse_stream`), and the name messages give it (the file, or ``zip/annotations.xml``)."""
    try:
        with open(path, "rb") as handle:
            if handle.read(4) in (b"PK\x03\x04", b"PK\x05\x06"):  # a zip (or an empty one)
                return _parse_zip(path, take)
            handle.seek(0)
            size = os.fstat(handle.fileno()).st_size
            if size > MAX_XML_BYTES:
                raise FormatError(path, f"{size} bytes: larger than the {MAX_XML_BYTES} bytes of XML this reader takes")
            return _parse_stream(handle, path, take), path
    except OSError as exc:
        raise FormatError(path, f"cannot read: {exc.strerror or exc}") from None


def _line(element: ET.Element) -> int | None:
    """The line an element starts on, for messages."""
    return getattr(element, "line", None) or None


def _coordinate(text: str, path: Path, element: ET.Element, where: str) -> float:
    """A pixel coordinate written in an attribute (surrounding spaces allowed), by the field rules."""
    return fields.text_number(text.strip(), path, _line(element), low=-MAX_PIXEL, high=MAX_PIXEL,
                              what="a pixel coordinate", label=where)


def _xy_list(element: ET.Element, path: Path, where: str) -> list[tuple[float, float]]:
    """The ``points="x,y[;x,y...]"`` of an element, each number by the field rules."""
    text = element.get("points")
    items = [item.split(",") for item in (text or "").split(";") if item.strip()]
    if not items or any(len(item) != 2 for item in items):
        raise FormatError(path, f"{where}: expected points=\"x,y[;x,y...]\", got {shown(text)}", _line(element))
    return [(_coordinate(x, path, element, f"{where} points"), _coordinate(y, path, element, f"{where} points"))
            for x, y in items]


def _box_of(element: ET.Element, path: Path, where: str) -> tuple[float, float, float, float]:
    """The ``xtl ytl xbr ybr`` of a box element, by the field rules."""
    return tuple(_coordinate(element.get(k, ""), path, element, f"{where} {k}")  # type: ignore[return-value]
                 for k in ("xtl", "ytl", "xbr", "ybr"))


def _group_key(group: str) -> int:
    """A ``group_id`` as the number it is (checked by :func:`_group`)."""
    return int(group)


def _attributes(element: ET.Element) -> dict[str, str]:
    return {a.get("name", ""): (a.text or "").strip() for a in element.findall("attribute")}


def read_cvat(path: str | Path, cameras: CameraTable | None, default_prototype: str = "Car",
              lengths: dict[str, tuple[float, float]] | None = None,
              sequence: str | None = None) -> tuple[dict[str, Any], ImportSummary]:
    """Read a CVAT for images 1.1 or CVAT for video 1.1 ``annotations.xml``, or the zip CVAT downloads that holds
    it, into an annotation file v1 document.

    Parameters
    ----------
    path : the XML file or the export zip (from a task, job or project export; a video only from a task or job);
        messages name a zip's XML ``<zip>/annotations.xml``
    cameras : intrinsics by image name (for a video: by :data:`FRAME_FILE`); every image with vehicles needs one
    default_prototype : for vehicles without a prototype attribute or box
    lengths : known sizes of length features, feature -> (metres, sigma)
    sequence : the sequence name of a video export (default: from its task or job); a name
        :func:`~toosicubix.formats.tool_import.check_sequence_name` accepts

    Returns
    -------
    (document, summary)

    Raises
    ------
    FormatError
        Not XML, not CVAT 1.1, malformed shapes or frame numbers, an image without a camera: naming the file
        and the image, track and element; a ``sequence`` for a file without tracks; a zip without exactly one
        ``annotations.xml``, or XML larger than :data:`MAX_XML_BYTES`.
    InputFileError
        A video whose imported document breaks the annotation file's rules (e.g. a prototype that changes
        along a track), naming the file ("as imported") and the JSON path.
    """
    images = _ImageReader(cameras, default_prototype, lengths, sequence)
    root, path = _parse(Path(path), images.take)
    if root.tag != "annotations":
        raise FormatError(path, f"expected <annotations> (CVAT for images 1.1), found <{shown(root.tag)}>")
    version = (root.findtext("version") or "").strip()
    if version and version != "1.1":
        raise FormatError(path, f"<version>: expected 1.1, found {shown(version)}")
    builder = images.builder or DocumentBuilder(str(path), cameras, default_prototype, lengths)
    if root.find("track") is not None:
        if images.read:
            raise FormatError(path, "both <image> and <track> elements: expected CVAT for images 1.1 or CVAT for "
                                    "video 1.1, not both")
        return _read_video(root, path, builder, sequence)
    if sequence is not None:
        raise FormatError(path, f"a sequence name ({sequence!r}) is for CVAT for video exports; this file has no "
                                "<track> (CVAT for images 1.1)")
    return builder.document(), builder.summary


class _ImageReader:
    """Reads each ``<image>`` of CVAT for images 1.1 as soon as the parser has it (:data:`Taker`), so that the
    export's tree is never held whole."""

    def __init__(self, cameras: CameraTable | None, default_prototype: str,
                 lengths: dict[str, tuple[float, float]] | None, sequence: str | None):
        self.cameras, self.default_prototype, self.lengths = cameras, default_prototype, lengths
        self.sequence = sequence
        self.builder: DocumentBuilder | None = None
        self.read = 0

    def take(self, image: ET.Element, root: ET.Element, path: Path) -> bool:
        if image.tag != "image" or root.tag != "annotations":
            return False
        if root.find("track") is not None:
            raise FormatError(path, "both <image> and <track> elements: expected CVAT for images 1.1 or CVAT for "
                                    "video 1.1, not both", _line(image))
        if self.sequence is not None:
            raise FormatError(path, f"a sequence name ({self.sequence!r}) is for CVAT for video exports; this file has "
                                    "no <track> (CVAT for images 1.1)", _line(image))
        if self.builder is None:
            self.builder = DocumentBuilder(str(path), self.cameras, self.default_prototype, self.lengths)
        self.read += 1
        name = image.get("name")
        if not name:
            raise FormatError(path, f"<image id={shown(image.get('id'))}>: missing name", _line(image))
        where = f"<image id={shown(image.get('id'))} name={shown(name)}>"
        size = tuple(fields.text_integer(image.get(side), path, _line(image), low=1, high=int(MAX_PIXEL),
                                         what="an image side in pixels", label=f"{where} {side}")
                     for side in ("width", "height"))
        vehicles = _image_vehicles(image, path, where, self.builder, name)
        if vehicles or image.find("*") is not None:  # else an image nobody labelled
            self.builder.add_image(name, size, vehicles)  # type: ignore[arg-type]
        return True


def _image_vehicles(image: ET.Element, path: Path, where: str, builder: DocumentBuilder,
                    name: str) -> list[ToolVehicle]:
    vehicles: list[ToolVehicle] = []
    for s, skeleton in enumerate(image.findall("skeleton")):
        element = f"skeleton {s + 1} (label {skeleton.get('label')!r})"
        attrs = _attributes(skeleton)
        vehicle = ToolVehicle(id=str(len(vehicles) + 1), element=element, prototype=attrs.get(PROTOTYPE_ATTRIBUTE))
        for point in skeleton.findall("points"):
            label = point.get("label", "")
            pwhere = f"{where} {element}, points {label!r}"
            if point.get("outside", "0") == "1":
                continue
            xy = _xy_list(point, path, pwhere)
            if len(xy) != 1:
                builder.warn(name, f"{element}, points {label!r}", f"{len(xy)} points in one element: left out")
                builder.summary.left_out[label] += 1
                continue
            vehicle.keypoints.append(ToolKeypoint(label, xy[0], f"{element}, points {label!r}"))
        vehicles.append(vehicle)
    groups: dict[str, ToolVehicle] = {}
    loose: list[ToolKeypoint] = []
    for index, shape in enumerate(image):
        if shape.tag not in ("points", "box"):
            continue
        label = shape.get("label", "")
        group = _group(shape, path, f"{where} {shape.tag} {index + 1} (label {label!r})")
        element = f"{shape.tag} {index + 1} (label {label!r}{f', group_id {group}' if group else ''})"
        if group and group != "0" and group not in groups:
            groups[group] = ToolVehicle(id="", element=f"group_id {group}")
        if shape.tag == "box":
            if not group or group == "0":
                continue  # a box on its own is not ours
            groups[group].box2d = _box_of(shape, path, f"{where} {element}")
            groups[group].prototype = _attributes(shape).get(PROTOTYPE_ATTRIBUTE) or label
            continue
        xy = _xy_list(shape, path, f"{where} {element}")
        if len(xy) != 1:
            builder.warn(name, element, f"{len(xy)} points in one shape: left out")
            builder.summary.left_out[label] += 1
            continue
        keypoint = ToolKeypoint(label, xy[0], element)
        if group and group != "0":
            groups[group].keypoints.append(keypoint)
            prototype = _attributes(shape).get(PROTOTYPE_ATTRIBUTE)
            if prototype and not groups[group].prototype:
                groups[group].prototype = prototype
        else:
            loose.append(keypoint)
    for group in sorted(groups, key=_group_key):
        groups[group].id = str(len(vehicles) + 1)
        vehicles.append(groups[group])
    if loose and not vehicles:
        vehicles.append(ToolVehicle(id="1", element="points without group_id", keypoints=loose))
    elif loose:
        for keypoint in loose:
            builder.warn(name, keypoint.element, "cannot be grouped to a vehicle (no group_id, and the image has "
                                                 "skeletons or groups): left out")
            builder.summary.left_out[keypoint.name] += 1
    return vehicles


# --- CVAT for video 1.1 -------------------------------------------------------------------------------------------

_SHAPES = ("box", "points", "skeleton")


@dataclass
class _Shape:
    """One shape of a track on one frame."""

    frame: int
    keyframe: bool
    outside: bool
    element: ET.Element
    where: str  # for errors: "<track id='0' label='Car'> box 3 (frame 12)"
    name: str  # for warnings: "track 0 (label 'Car'), box (frame 12)"


@dataclass
class _Track:
    id: str
    label: str
    kind: str  # box, points or skeleton
    group: str | None
    shapes: dict[int, _Shape] = field(default_factory=dict)


@dataclass
class _Vehicle:
    """The tracks of one vehicle: one track, a group, or the task's loose points tracks."""

    id: str
    element: str
    tracks: list[_Track]


def _number_key(text: str) -> tuple[int, int | str]:
    """Track ids in CVAT's order: numbers (at most :data:`~toosicubix.fields.MAX_ID_DIGITS` ASCII digits, as
    :func:`_tracks` checks) by value, before any other id."""
    return (0, int(text)) if text.isascii() and text.isdigit() else (1, text)


def _group(element: ET.Element, path: Path, where: str) -> str | None:
    """An element's ``group_id``: None for none or ``0``, else the number CVAT wrote (field rules: ASCII digits, at
    most :data:`~toosicubix.fields.MAX_ID_DIGITS`), as text without leading zeros."""
    text = element.get("group_id")
    if text is None:
        return None
    group = fields.text_integer(text.strip(), path, _line(element), low=0, high=10 ** fields.MAX_ID_DIGITS - 1,
                                what="a group id (CVAT numbers groups)", label=f"{where} group_id")
    return str(group) if group else None


def _flag(element: ET.Element, name: str, where: str, path: Path, default: bool | None) -> bool:
    value = element.get(name)
    if value is None and default is not None:
        return default
    if value not in ("0", "1"):
        raise FormatError(path, f'{where}: expected {name}="0" or "1", got {shown(value)}', _line(element))
    return value == "1"


def _video_meta(root: ET.Element, path: Path) -> tuple[str | None, tuple[int, int] | None]:
    """The default sequence name (task name, else task_<id> or job_<id>) and the frame size of a video export."""
    meta = root.find("meta")
    if meta is None:
        return None, None
    if meta.find("project") is not None:
        raise FormatError(path, "CVAT for video from a project export: export each task (or job) as CVAT for video "
                                "1.1, one sequence each")
    owner, kind = meta.find("task"), "task"
    if owner is None:
        owner, kind = meta.find("job"), "job"
    name = None
    if owner is not None:
        task_name = (owner.findtext("name") or "").strip() if kind == "task" else ""  # a job's meta has no name
        number = (owner.findtext("id") or "").strip()
        name = sequence_id_for(task_name) or (sequence_id_for(f"{kind}_{number}") if number else "") or None
    size_element = owner.find("original_size") if owner is not None else None
    if size_element is None:
        size_element = meta.find("original_size")  # where a job export puts it
    if size_element is None:
        return name, None
    size = tuple(fields.text_integer((size_element.findtext(side) or "").strip(), path, _line(size_element), low=1,
                                     high=int(MAX_PIXEL), what="an image side in pixels",
                                     label=f"<original_size> <{side}>")
                 for side in ("width", "height"))
    return name, size  # type: ignore[return-value]


def _tracks(root: ET.Element, path: Path) -> list[_Track]:
    tracks: list[_Track] = []
    ids: set[str] = set()
    for t, element in enumerate(root.findall("track")):
        track_id, label = (element.get("id") or "").strip(), element.get("label", "")
        where = f"<track id={shown(track_id)} label={shown(label)}>"
        if not re.fullmatch(r"[A-Za-z0-9_.\-]+", track_id) or len(track_id) > MAX_TRACK_ID \
                or (track_id.isdigit() and len(track_id) > fields.MAX_ID_DIGITS):
            raise FormatError(path, f"<track> {t + 1} (label {shown(label)}): expected an id of digits (CVAT's track "
                                    f"number, at most {fields.MAX_ID_DIGITS}), got {shown(track_id)}", _line(element))
        if track_id in ids:
            raise FormatError(path, f"{where}: a second track with id {track_id!r}", _line(element))
        ids.add(track_id)
        group = _group(element, path, where)
        kinds = {child.tag for child in element if child.tag != "attribute"}
        if not kinds & set(_SHAPES):
            continue  # an empty track, or polygons, cuboids, ...: not ours
        if len(kinds) > 1:
            raise FormatError(path, f"{where}: expected one kind of shape per track, got {', '.join(sorted(kinds))}",
                              _line(element))
        track = _Track(track_id, label, kinds.pop(), group)
        for index, shape in enumerate(element):
            if shape.tag != track.kind:
                continue
            swhere = f"{where} {shape.tag} {index + 1}"
            frame = fields.text_integer(shape.get("frame"), path, _line(shape), low=0, high=MAX_FRAME,
                                        what="a frame number", label=f"{swhere} frame")
            swhere = f"{swhere} (frame {frame})"
            if frame in track.shapes:
                raise FormatError(path, f"{swhere}: frame {frame} is given twice in one track", _line(shape))
            track.shapes[frame] = _Shape(frame, _flag(shape, "keyframe", swhere, path, None),
                                         _flag(shape, "outside", swhere, path, False), shape, swhere,
                                         f"track {track_id} (label {label!r}), {shape.tag} (frame {frame})")
        tracks.append(track)
    return tracks


def _vehicles(tracks: list[_Track], builder: DocumentBuilder) -> list[_Vehicle]:
    """Link tracks into vehicles: by group_id, else one vehicle per track; loose points tracks (see the module)."""
    groups: dict[str, list[_Track]] = {}
    alone: list[_Track] = []
    loose: list[_Track] = []
    for track in tracks:
        if track.group is not None:
            groups.setdefault(track.group, []).append(track)
        elif track.kind == "points":
            loose.append(track)
        else:
            alone.append(track)
    vehicles = [_Vehicle(track.id, f"track {track.id} (label {track.label!r})", [track]) for track in alone]
    for group, members in groups.items():
        first = min((m.id for m in members), key=_number_key)
        vehicles.append(_Vehicle(first, f"group_id {group} (tracks {', '.join(m.id for m in members)})", members))
    if loose and not vehicles:
        first = min((m.id for m in loose), key=_number_key)
        vehicles.append(_Vehicle(first, "points tracks without group_id", loose))
    else:
        for track in loose:
            clicks = [s for s in track.shapes.values() if s.keyframe and not s.outside]
            builder.summary.warnings.append(
                f"{builder.source}: track {track.id} (label {track.label!r}): a points track without group_id cannot "
                "be linked to a vehicle (the task has other tracks): left out")
            builder.summary.left_out[track.label] += len(clicks)
    return sorted(vehicles, key=lambda v: _number_key(v.id))


def _box(shape: _Shape, path: Path) -> tuple[float, float, float, float]:
    box = _box_of(shape.element, path, shape.where)
    if not (box[0] < box[2] and box[1] < box[3]):
        raise FormatError(path, f"{shape.where}: expected numbers xtl < xbr and ytl < ybr", _line(shape.element))
    return box


def _vehicle_frame(vehicle: _Vehicle, frame: int, path: Path, builder: DocumentBuilder,
                   file_name: str) -> tuple[ToolVehicle, str | None] | None:
    """The vehicle on one frame (None: not in it) and the prototype its shapes there name."""
    out = ToolVehicle(id=vehicle.id, element=vehicle.element)
    present = False
    named: list[str] = []
    box_named: list[str] = []
    box_owner: _Shape | None = None
    for track in vehicle.tracks:
        shape = track.shapes.get(frame)
        if shape is None or shape.outside:
            continue
        prototype = _attributes(shape.element).get(PROTOTYPE_ATTRIBUTE)
        if track.kind == "box":
            if box_owner is not None:
                raise FormatError(path, f"{shape.where}: {vehicle.element} has a second box on frame {frame} "
                                        f"(also {box_owner.where}): one box per vehicle", _line(shape.element))
            present, box_owner, out.box2d = True, shape, _box(shape, path)
            box_named += [prototype] if prototype else []
            continue
        if track.kind == "points":
            present = True
            if shape.keyframe:
                xy = _xy_list(shape.element, path, shape.where)
                if len(xy) != 1:
                    builder.warn(file_name, shape.name, f"{len(xy)} points in one shape: left out")
                    builder.summary.left_out[track.label] += 1
                else:
                    out.keypoints.append(ToolKeypoint(track.label, xy[0], shape.name))
        else:
            points = [p for p in shape.element.findall("points")
                      if not _flag(p, "outside", f"{shape.where}, points {p.get('label', '')!r}", path, False)]
            if not points:
                continue  # every point outside: the skeleton is not in this frame
            present = True
            for point in points:
                label = point.get("label", "")
                pwhere = f"{shape.where}, points {label!r}"
                if not (shape.keyframe and _flag(point, "keyframe", pwhere, path, shape.keyframe)):
                    continue  # CVAT's interpolation, not a click
                xy = _xy_list(point, path, pwhere)
                element = f"{shape.name}, points {label!r}"
                if len(xy) != 1:
                    builder.warn(file_name, element, f"{len(xy)} points in one element: left out")
                    builder.summary.left_out[label] += 1
                    continue
                out.keypoints.append(ToolKeypoint(label, xy[0], element))
        named += [prototype] if prototype else []
    if not present:
        return None
    return out, (named + box_named + [None])[0]


def _read_video(root: ET.Element, path: Path, builder: DocumentBuilder,
                sequence: str | None) -> tuple[dict[str, Any], ImportSummary]:
    if root.find("image") is not None:
        raise FormatError(path, "both <image> and <track> elements: expected CVAT for images 1.1 or CVAT for "
                                "video 1.1, not both")
    default_name, size = _video_meta(root, path)
    if sequence is not None:
        try:
            check_sequence_name(sequence)
        except ValueError as exc:
            raise FormatError(path, f"sequence name: {exc}") from None
    sequence = sequence or default_name
    if sequence is None:
        raise FormatError(path, "CVAT for video 1.1 whose <meta> names no task or job: give the sequence a name "
                                "(--sequence NAME)")
    frames: dict[int, list[ToolVehicle]] = {}
    for vehicle in _vehicles(_tracks(root, path), builder):
        track = f"{sequence}-{vehicle.id}"
        on_frames = []
        for frame in sorted({f for t in vehicle.tracks for f in t.shapes}):
            found = _vehicle_frame(vehicle, frame, path, builder, FRAME_FILE.format(frame=frame))
            if found is not None:
                on_frames.append((frame, *found))
        if not on_frames:
            continue
        fallback = next((named for _, _, named in on_frames if named), None)
        fallback = fallback or next((t.label for t in vehicle.tracks if t.kind == "box" and t.label), None)
        if fallback is None:
            builder.warn(FRAME_FILE.format(frame=on_frames[0][0]), vehicle.element,
                         f"no prototype on any frame: {builder.default_prototype!r} assumed")
            fallback = builder.default_prototype
        for frame, tool_vehicle, named in on_frames:
            tool_vehicle.prototype, tool_vehicle.track = named or fallback, track
            frames.setdefault(frame, []).append(tool_vehicle)
    for frame in sorted(frames):
        builder.add_image(FRAME_FILE.format(frame=frame), size, frames[frame], sequence=sequence, frame=frame)
    document = builder.document()
    check_imported(document, f"{path} (as imported)")
    return document, builder.summary
