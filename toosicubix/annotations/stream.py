"""Read a large annotation file one image at a time, so a batch's memory does not grow with its size.

:func:`index_annotations` validates the whole file as :func:`toosicubix.annotations.schema.load_annotations`
does (the same messages and JSON paths), image by image, keeping only the file's text and where each
image's JSON object starts and ends; :func:`iter_images` then decodes, validates and converts one image
at a time. Decoding the whole file at once costs about 5 KB of Python objects per vehicle before any
conversion (540 MB for 100,000 vehicles); this keeps the text (about 0.7 KB per vehicle) and one image.
"""

from __future__ import annotations

import json
import re
from collections.abc import Collection, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from toosicubix.annotations.schema import (
    IMAGE_IDS_IGNORING_CASE,
    AnnotationFile,
    CameraModel,
    ImageAnnotation,
    TrackBook,
    _describe,
    _json_path,
    duplicate_ids_message,
)
from toosicubix.errors import FormatError, InputFileError
from toosicubix.jsonfile import long_integer_error, read_json_text

_WHITESPACE = re.compile(r"[ \t\n\r]*")
#: At most this many problems are listed for one file.
MAX_PROBLEMS = 50


@dataclass(frozen=True)
class AnnotationIndex:
    """A validated annotation file: its text and the span ``(start, end)`` of each image in it.

    Attributes
    ----------
    prototypes : the prototype names the vehicles use
    sequences : per image, its ``(sequence, frame)``, or None for an image of no sequence
    tracked : how many vehicles carry a ``track``
    clicked : how many vehicles carry clicks (the ones a pilot can fit alone; a tracked vehicle may have only a box)
    image_vehicles : per image, how many vehicles it has (what a batch's workers are handed by)
    image_clicked : per image, how many of its vehicles carry clicks
    image_cameras : per image, which of ``cameras`` it was taken with
    cameras : the distinct camera blocks of the file, as validated (a batch's pilot tells them apart without reading
        every image again)
    image_grounded : per image, whether it has a ground block of its own
    """

    path: Path
    text: str
    spans: tuple[tuple[int, int], ...]
    vehicles: int
    prototypes: frozenset[str]
    sequences: tuple[tuple[str, int] | None, ...] = ()
    tracked: int = 0
    clicked: int = 0
    image_vehicles: tuple[int, ...] = ()
    image_clicked: tuple[int, ...] = ()
    image_cameras: tuple[int, ...] = ()
    cameras: tuple[CameraModel, ...] = ()
    image_grounded: tuple[bool, ...] = ()


class _Scanner:
    def __init__(self, text: str, path: Path):
        self.text, self.path, self.pos = text, path, 0
        self.decoder = json.JSONDecoder()

    def fail(self, message: str, pos: int | None = None) -> InputFileError:
        pos = self.pos if pos is None else pos
        line = self.text.count("\n", 0, pos) + 1
        column = pos - (self.text.rfind("\n", 0, pos) + 1) + 1
        return InputFileError(self.path, [("$", f"not valid JSON: {message} at line {line} column {column}")])

    def skip(self) -> None:
        self.pos = _WHITESPACE.match(self.text, self.pos).end()  # type: ignore[union-attr]

    def expect(self, char: str) -> bool:
        """Skip whitespace; consume ``char`` when it comes next."""
        self.skip()
        if self.text.startswith(char, self.pos):
            self.pos += 1
            return True
        return False

    def value(self) -> tuple[Any, int, int]:
        self.skip()
        start = self.pos
        try:
            value, self.pos = self.decoder.raw_decode(self.text, self.pos)
        except json.JSONDecodeError as exc:
            raise self.fail(exc.msg, exc.pos) from None
        except ValueError:  # an integer of more than 4,300 digits, which Python does not read
            raise InputFileError(self.path, [("$", long_integer_error(self.text, self.path, start).message)]) from None
        except RecursionError:
            raise InputFileError(self.path, [("$", "JSON nested too deeply")]) from None
        return value, start, self.pos


def _top_level(scanner: _Scanner) -> Iterator[tuple[str, Any, int, int]]:
    """The top-level object's members ``(key, value, start, end)``; for ``images`` the value is None and
    the scanner is left just inside its ``[``."""
    if not scanner.expect("{"):
        raise InputFileError(scanner.path, [("$", "expected a JSON object (the annotation file format v1)")])
    if scanner.expect("}"):
        return
    while True:
        key, _, _ = scanner.value()
        if not isinstance(key, str):
            raise scanner.fail("Expecting property name enclosed in double quotes")
        if not scanner.expect(":"):
            raise scanner.fail("Expecting ':' delimiter")
        if key == "images":
            scanner.skip()
            if scanner.text.startswith("[", scanner.pos):
                start = scanner.pos
                scanner.pos += 1
                yield key, None, start, -1
            else:
                value, start, end = scanner.value()
                yield key, value, start, end
        else:
            value, start, end = scanner.value()
            yield key, value, start, end
        if scanner.expect("}"):
            break
        if not scanner.expect(","):
            raise scanner.fail("Expecting ',' delimiter")
    scanner.skip()
    if scanner.pos != len(scanner.text):
        raise scanner.fail("Extra data")


def _image_spans(scanner: _Scanner) -> Iterator[tuple[Any, int, int]]:
    """Each element of the ``images`` array the scanner is inside of."""
    if scanner.expect("]"):
        return
    while True:
        yield scanner.value()
        if scanner.expect("]"):
            return
        if not scanner.expect(","):
            raise scanner.fail("Expecting ',' delimiter")


def _problems(exc: ValidationError, prefix: tuple[int | str, ...]) -> list[tuple[str, str]]:
    return [(_json_path(prefix + tuple(err["loc"])), _describe(err)) for err in exc.errors()]


def index_annotations(path: str | Path, known_prototypes: Collection[str] | None = None) -> AnnotationIndex:
    """Validate an annotation file image by image; keep its text and the images' spans.

    ``known_prototypes``: when given, a vehicle whose prototype is not among them is a problem too.

    Raises
    ------
    InputFileError
        As :func:`toosicubix.annotations.schema.load_annotations`, naming the file and each JSON path.
    """
    path = Path(path)
    try:
        text = read_json_text(path)
    except FormatError as exc:
        raise InputFileError(path, [("$", exc.message)]) from None
    scanner = _Scanner(text, path)
    header: dict[str, Any] = {}
    spans: list[tuple[int, int]] = []
    prototypes: set[str] = set()
    known = None if known_prototypes is None else set(known_prototypes)
    problems: list[tuple[str, str]] = []
    first_index: dict[str, int] = {}
    first_lower: dict[str, int] = {}
    vehicles = tracked = clicked = 0
    sequences: list[tuple[str, int] | None] = []
    image_vehicles: list[int] = []
    image_clicked: list[int] = []
    image_cameras: list[int] = []
    image_grounded: list[bool] = []
    cameras: dict[tuple, tuple[int, CameraModel]] = {}  # a camera block's values -> its place, the block
    tracks = TrackBook()
    images_seen = False
    for key, value, _, _ in _top_level(scanner):
        if key != "images":
            header[key] = value
            continue
        if images_seen:
            raise InputFileError(path, [("$.images", "given twice")])
        images_seen = True
        if value is not None:  # not an array: let the model say what it expected
            header["images"] = value
            continue
        for i, (raw, start, end) in enumerate(_image_spans(scanner)):
            spans.append((start, end))
            sequences.append(None)
            image_vehicles.append(0)
            image_clicked.append(0)
            image_cameras.append(-1)
            image_grounded.append(False)
            if len(problems) >= MAX_PROBLEMS:
                continue
            try:
                image = ImageAnnotation.model_validate(raw)
            except ValidationError as exc:
                problems += _problems(exc, ("images", i))
                continue
            if image.sequence is not None and image.frame is not None:
                sequences[-1] = (image.sequence, image.frame)
                tracked += sum(v.track is not None for v in image.vehicles)
                tracks.add(i, image)
            # As the whole-file reader: the same id twice, else two ids that differ only in case (they name files,
            # and some file systems ignore case).
            lower = image.id.lower()
            if image.id in first_index:
                problems.append((f"$.images[{i}].id",
                                 duplicate_ids_message("image", image.id, first_index[image.id], i)))
            elif lower in first_lower:
                problems.append((f"$.images[{i}].id",
                                 duplicate_ids_message(IMAGE_IDS_IGNORING_CASE, lower, first_lower[lower], i)))
            first_index.setdefault(image.id, i)
            first_lower.setdefault(lower, i)
            vehicles += len(image.vehicles)
            image_vehicles[-1] = len(image.vehicles)
            image_clicked[-1] = sum(bool(v.parts) for v in image.vehicles)
            clicked += image_clicked[-1]
            camera = image.camera
            values = (camera.K, camera.P, None if camera.distortion is None else tuple(camera.distortion))
            image_cameras[-1] = cameras.setdefault(values, (len(cameras), camera))[0]
            image_grounded[-1] = image.ground is not None
            prototypes.update(v.prototype for v in image.vehicles)
            if known is not None:
                problems += [(f"$.images[{i}].vehicles[{j}].prototype",
                              f"unknown prototype {v.prototype!r}; known: {', '.join(sorted(known))}")
                             for j, v in enumerate(image.vehicles) if v.prototype not in known]
    try:
        AnnotationFile.model_validate({**header, "images": header.get("images", [])} if images_seen else header)
    except ValidationError as exc:
        problems = _problems(exc, ()) + problems
    problems += tracks.problems
    if problems:
        raise InputFileError(path, problems[:MAX_PROBLEMS])
    return AnnotationIndex(path, text, tuple(spans), vehicles, frozenset(prototypes), tuple(sequences), tracked,
                           clicked, tuple(image_vehicles), tuple(image_clicked), tuple(image_cameras),
                           tuple(camera for _, camera in cameras.values()), tuple(image_grounded))


def iter_image_annotations(index: AnnotationIndex, which: Iterable[int] | None = None
                           ) -> Iterator[tuple[int, ImageAnnotation]]:
    """Each image of an indexed file (``which``: only these, by their positions in the file), validated, with its
    position in the file."""
    for i in range(len(index.spans)) if which is None else which:
        start, end = index.spans[i]
        yield i, image_annotation(index.text[start:end])


def image_texts(index: AnnotationIndex) -> Iterator[str]:
    """Each image's JSON text, as the file has it (what :func:`image_annotation` reads)."""
    for start, end in index.spans:
        yield index.text[start:end]


def image_annotation(text: str) -> ImageAnnotation:
    """One image of an indexed file from its text (:func:`image_texts`), validated (again: the index did)."""
    raw, _ = _DECODER.raw_decode(text)
    return ImageAnnotation.model_validate(raw)


_DECODER = json.JSONDecoder()
