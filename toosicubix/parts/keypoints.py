"""The flat keypoint vocabulary: one named keypoint per click, for labelling tools and keypoint files.

Labelling tools (CVAT skeletons, Label Studio ``KeyPointLabels``, COCO ``categories[].keypoints``) know
single named points, not our two-click parts. This module names every click of every part kind of the
annotation file v1 and turns the named keypoints of one vehicle into part objects, and back:

=====================================  ===========================================================
keypoint                               part object (annotation file v1)
=====================================  ===========================================================
``wheel-front-left``, ``rear-center``  ``{"kind": "point", "part": NAME, "xy": ...}``
(every point part, by its part name)
``{face}-pair{k}-{left|right}``        ``{"kind": "symmetry", "face": face, "left": ..., "right": ...}``;
(face front, rear, roof; k = 1..3)     k numbers up to three symmetric pairs on one face
``arrow-{axis}-{tail|head}``           ``{"kind": "direction", "axis": axis, "tail": ..., "head": ...}``
``{feature}-{a|b}``                    ``{"kind": "length", "feature": feature, "a": ..., "b": ...,
(plate-rear-a, wheelbase-left-b, ...)  "metres": m, "sigma": s}``: the size from the caller or :data:`DEFAULT_LENGTHS`
=====================================  ===========================================================

A two-click part needs both of its keypoints; a lone one is reported, never guessed. The names are the
bundled ``toosicubix`` keypoint mapping (:func:`mapping_document`), which the COCO importer reads.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from toosicubix import vocabulary
from toosicubix.parts.road_users import keypoint_class, keypoint_parts
from toosicubix.vocabulary import DIRECTION_AXES, LENGTH_FEATURES, POINT_PARTS, SYMMETRY_FACES

#: How many symmetric pairs a face may carry (``rear-pair1-left`` .. ``rear-pair3-right``).
PAIRS_PER_FACE = 3
#: Known sizes ``(metres, sigma)`` of length features used when the caller gives none: an EU licence plate's width.
#: Wheelbases and tyre diameters differ per vehicle and have no default.
DEFAULT_LENGTHS: dict[str, tuple[float, float]] = {"plate-front": (0.52, 0.01), "plate-rear": (0.52, 0.01)}


@dataclass(frozen=True)
class PartSlot:
    """One part object the vocabulary can produce, and which keypoint fills which of its click fields.

    Attributes
    ----------
    kind : 'point', 'symmetry', 'direction' or 'length'
    name : the part name, face, axis or feature
    fields : ((field, keypoint name), ...), e.g. (('left', 'rear-pair1-left'), ('right', 'rear-pair1-right'))
    """

    kind: str
    name: str
    fields: tuple[tuple[str, str], ...]

    @property
    def keypoints(self) -> tuple[str, ...]:
        return tuple(keypoint for _, keypoint in self.fields)


#: The point parts of the flat vocabulary: every one but the wheel hubs (ApolloCar3D's wheel centres, reached
#: through its own mappings; the labelling tools' 65 keypoints stay as they were).
TOOL_POINT_PARTS = tuple(part for part in POINT_PARTS if vocabulary.entry("point", part).get("shape") != "hub")


def _slots() -> tuple[PartSlot, ...]:
    slots = [PartSlot("point", part, (("xy", part),)) for part in TOOL_POINT_PARTS]
    slots += [PartSlot("symmetry", face, (("left", f"{face}-pair{k}-left"), ("right", f"{face}-pair{k}-right")))
              for face in SYMMETRY_FACES for k in range(1, PAIRS_PER_FACE + 1)]
    slots += [PartSlot("direction", axis, (("tail", f"arrow-{axis}-tail"), ("head", f"arrow-{axis}-head")))
              for axis in DIRECTION_AXES]
    slots += [PartSlot("length", feature, (("a", f"{feature}-a"), ("b", f"{feature}-b")))
              for feature in LENGTH_FEATURES]
    return tuple(slots)


#: Every part slot, in vocabulary order.
SLOTS: tuple[PartSlot, ...] = _slots()
#: Every keypoint name, in a fixed order (templates and COCO keypoint indices use it).
KEYPOINTS: tuple[str, ...] = tuple(keypoint for slot in SLOTS for keypoint in slot.keypoints)
_SLOT_OF: dict[str, PartSlot] = {keypoint: slot for slot in SLOTS for keypoint in slot.keypoints}


def describe(keypoint: str) -> str:
    """A short description of what a keypoint marks, for templates and help texts."""
    slot = _SLOT_OF[keypoint]
    field = next(f for f, k in slot.fields if k == keypoint)
    if slot.kind == "point":
        return f"point part {slot.name}"
    if slot.kind == "symmetry":
        return f"symmetric pair on the {slot.name} face, the feature on the vehicle's own {field} side"
    if slot.kind == "direction":
        return f"{field} of an arrow pointing {slot.name} along the vehicle"
    return f"click {field} of {slot.name}: {LENGTH_FEATURES[slot.name]}"


def skeleton_edges() -> list[tuple[str, str]]:
    """Edges for skeleton templates: each two-click part's pair, and the wheels along each side and axle."""
    edges = [slot.keypoints for slot in SLOTS if len(slot.fields) == 2]
    edges += [("wheel-front-left", "wheel-rear-left"), ("wheel-front-right", "wheel-rear-right"),
              ("wheel-front-left", "wheel-front-right"), ("wheel-rear-left", "wheel-rear-right")]
    return [(a, b) for a, b in edges]


class KeypointProblem(ValueError):
    """Keypoints that do not make a part: unknown name, a lone half of a pair, a repeated name."""


@dataclass(frozen=True)
class Conversion:
    """Part objects made from one vehicle's keypoints, and what could not be used.

    Attributes
    ----------
    parts : annotation file v1 part objects (JSON-ready dicts), in vocabulary order
    problems : (keypoint name, message) for every keypoint left out
    """

    parts: list[dict[str, Any]]
    problems: list[tuple[str, str]]


def parts_from_keypoints(keypoints: Mapping[str, tuple[float, float]] | Iterable[tuple[str, tuple[float, float]]],
                         lengths: Mapping[str, tuple[float, float]] | None = None,
                         prototype: str | None = None) -> Conversion:
    """Part objects of one vehicle from its named keypoints.

    Parameters
    ----------
    keypoints : name -> (x, y) pixels, or (name, (x, y)) pairs; a name given twice is a problem
    lengths : feature -> (metres, sigma) of length features; :data:`DEFAULT_LENGTHS` fills the others
    prototype : the object's prototype; when its class of road users has a keypoint vocabulary of its own (a
        Pedestrian's COCO keypoints, :mod:`toosicubix.parts.road_users`), its names become ``keypoint`` annotations
        at the class's places, before the flat vocabulary's names are read

    Returns
    -------
    Conversion
        Unknown names, repeated names, lone halves of two-click parts and length features of unknown size
        are listed in ``problems`` and left out; everything else is in ``parts``.
    """
    items = list(keypoints.items()) if isinstance(keypoints, Mapping) else list(keypoints)
    known_lengths = {**DEFAULT_LENGTHS, **(lengths or {})}
    problems: list[tuple[str, str]] = []
    own = keypoint_class(prototype)
    class_parts: list[dict[str, Any]] = []
    if own is not None:  # the class's own names first (a name given twice is left to the loop below to report)
        counts = Counter(name for name, _ in items)
        named = [(n, (float(p[0]), float(p[1]), True)) for n, p in items if n in own.keypoints and counts[n] == 1]
        class_parts = keypoint_parts(own.name, named)[0]
        items = [(n, p) for n, p in items if n not in own.keypoints or counts[n] > 1]
    xy: dict[str, tuple[float, float]] = {}
    for name, point in items:
        if name not in _SLOT_OF:
            problems.append((name, "not a toosicubix keypoint name"))
        elif name in xy:
            problems.append((name, "given more than once"))
        else:
            xy[name] = (float(point[0]), float(point[1]))
    parts: list[dict[str, Any]] = []
    for slot in SLOTS:
        present = [k for k in slot.keypoints if k in xy]
        if not present:
            continue
        if len(present) < len(slot.fields):
            missing = [k for k in slot.keypoints if k not in xy]
            problems += [(k, f"needs {' and '.join(missing)} too") for k in present]
            continue
        if slot.kind == "length" and slot.name not in known_lengths:
            problems += [(k, f"the size of {slot.name} is not known: give it (metres, sigma)") for k in present]
            continue
        key = {"point": "part", "symmetry": "face", "direction": "axis", "length": "feature"}[slot.kind]
        part: dict[str, Any] = {"kind": slot.kind, key: slot.name}
        part.update({field: list(xy[k]) for field, k in slot.fields})
        if slot.kind == "length":
            part["metres"], part["sigma"] = known_lengths[slot.name]
        parts.append(part)
    return Conversion(class_parts + parts, problems)


def keypoints_from_parts(parts: Iterable[Mapping[str, Any]]) -> list[tuple[str, tuple[float, float]]]:
    """Named keypoints of one vehicle's part objects (annotation file v1), the inverse of :func:`parts_from_keypoints`.

    Symmetric pairs of one face are numbered pair1, pair2, pair3 in the order given.

    Raises
    ------
    KeypointProblem
        More than :data:`PAIRS_PER_FACE` pairs on a face, or a part (point, arrow axis, length feature) given
        twice: the flat vocabulary has one keypoint per click and cannot hold them.
    """
    out: list[tuple[str, tuple[float, float]]] = []
    pairs: dict[str, int] = {}
    seen: set[str] = set()
    for index, part in enumerate(parts):
        kind = part["kind"]
        if kind == "point":
            names = [(part["part"], part["xy"])]
        elif kind == "symmetry":
            k = pairs[part["face"]] = pairs.get(part["face"], 0) + 1
            if k > PAIRS_PER_FACE:
                raise KeypointProblem(f"parts[{index}]: more than {PAIRS_PER_FACE} symmetric pairs on the "
                                      f"{part['face']} face")
            names = [(f"{part['face']}-pair{k}-{side}", part[side]) for side in ("left", "right")]
        elif kind == "direction":
            names = [(f"arrow-{part['axis']}-{end}", part[end]) for end in ("tail", "head")]
        elif kind == "length":
            names = [(f"{part['feature']}-{end}", part[end]) for end in ("a", "b")]
        else:
            raise KeypointProblem(f"parts[{index}]: unknown part kind {kind!r}")
        for name, point in names:
            if name in seen:
                raise KeypointProblem(f"parts[{index}]: keypoint {name} given twice (one keypoint per click)")
            seen.add(name)
            out.append((name, (float(point[0]), float(point[1]))))
    return out


def lengths_of_parts(parts: Iterable[Mapping[str, Any]]) -> dict[str, tuple[float, float]]:
    """feature -> (metres, sigma) of the length parts among ``parts``: what :func:`keypoints_from_parts` drops."""
    return {p["feature"]: (float(p["metres"]), float(p["sigma"])) for p in parts if p["kind"] == "length"}


def mapping_document() -> dict[str, Any]:
    """The bundled ``toosicubix`` keypoint mapping: keypoint names that are our own part names.

    Every entry of ``parts`` is a part object of the annotation file v1 in which each click field holds the
    name of the keypoint that fills it (length features also give their default size where one exists).
    """
    parts = []
    for slot in SLOTS:
        key = {"point": "part", "symmetry": "face", "direction": "axis", "length": "feature"}[slot.kind]
        entry: dict[str, Any] = {"kind": slot.kind, key: slot.name, **dict(slot.fields)}
        if slot.kind == "length" and slot.name in DEFAULT_LENGTHS:
            entry["metres"], entry["sigma"] = DEFAULT_LENGTHS[slot.name]
        parts.append(entry)
    return {
        "toosicubix_mapping": 1,
        "name": "toosicubix",
        "description": "One keypoint per click, named after the part it belongs to (toosicubix.parts.keypoints).",
        "keypoints": list(KEYPOINTS),
        "parts": parts,
    }
