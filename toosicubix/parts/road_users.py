"""Road users beyond vehicles: the click vocabularies of the vocabulary's classes
(:data:`toosicubix.vocabulary.CLASSES`) as the rest of the package takes them.

A pedestrian, a cyclist or a traffic cone is a box like a vehicle (vehicle frame: origin at the bottom-face centre,
X forward = the way it faces or points, Y left, Z up) in the annotation file's ``vehicles`` list, with a prototype
of its class and ``keypoint`` annotations named by its class's vocabulary (COCO's 17 person keypoints for a
pedestrian), each at its class's typical place ``at`` within ``spread`` (fractions of ``(dx, dy, dz)``). This module:

- gives a class's keypoints as candidates to click (:func:`class_keypoints`: guidance, the page's naming);
- makes the keypoint annotations of named clicks (:func:`keypoint_parts`);
- builds the bundled mappings ``coco-person`` and ``two-wheeler`` from the vocabulary (:func:`mapping_document`),
  so that the two never disagree;
- says what a fit of a class cannot measure (:func:`class_notes`): a pedestrian without an ankle stands where the
  height prior puts the feet; a traffic cone has no yaw, a barrier's yaw is known modulo 180 degrees.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from toosicubix.parts.linear import TypicalKeypoint
from toosicubix.vocabulary import CLASSES, RoadUserClass, class_of

#: COCO's person keypoints in COCO's order (``categories[].keypoints`` of ``person_keypoints_*.json``).
COCO_PERSON_KEYPOINTS = ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
                         "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip",
                         "left_knee", "right_knee", "left_ankle", "right_ankle")
#: The classes of the bundled ``two-wheeler`` mapping, and the COCO category names that become each.
TWO_WHEELER_CATEGORIES = {"cyclist": "Cyclist", "bicyclist": "Cyclist", "rider": "Cyclist",
                          "motorcyclist": "Motorcyclist", "bicycle": "Bicycle", "motorcycle": "Motorcycle",
                          "motorbike": "Motorcycle"}
#: The mappings this module builds, by name (read by :func:`toosicubix.annotations.mapping.load_mapping`).
ROAD_USER_MAPPINGS = ("coco-person", "two-wheeler")
#: The keypoints that place a pedestrian's feet: without one, the height prior does.
ANKLES = ("left_ankle", "right_ankle")


def keypoint_class(prototype: str | None) -> RoadUserClass | None:
    """The class of ``prototype`` when it has a keypoint vocabulary of its own, else None."""
    c = class_of(prototype)
    return c if c is not None and c.vocabulary == "keypoints" else None


def class_keypoints(prototype: str | None) -> dict[str, TypicalKeypoint]:
    """The keypoints of ``prototype``'s class as candidates to click (name -> typical position and spread); empty
    for a prototype of the cuboid vocabulary. No face is named: every one may be seen from any side."""
    c = keypoint_class(prototype)
    if c is None:
        return {}
    return {k.name: TypicalKeypoint(np.array(k.at), np.array(k.spread)) for k in c.keypoints.values()}


def keypoint_parts(prototype: str, clicks: Mapping[str, tuple[float, float, bool]] | Iterable[
        tuple[str, tuple[float, float, bool]]]) -> tuple[list[dict[str, Any]], list[str]]:
    """Keypoint annotations (annotation file v1 part objects) of one object of ``prototype``'s class from its named
    clicks ``name -> (x, y, visible)``, in the class vocabulary's order; and the names the vocabulary does not know
    (left out). A hidden click (``visible`` False, COCO's v = 1) is kept with ``"visible": false``.

    Raises
    ------
    ValueError
        ``prototype`` has no keypoint vocabulary of its own.
    """
    c = keypoint_class(prototype)
    if c is None:
        raise ValueError(f"prototype {prototype!r} has no keypoint vocabulary of its own; classes with one: "
                         f"{', '.join(n for n, k in CLASSES.items() if k.vocabulary == 'keypoints')}")
    given = dict(clicks.items() if isinstance(clicks, Mapping) else clicks)
    parts = []
    for name, k in c.keypoints.items():
        if name not in given:
            continue
        x, y, visible = given[name]
        part: dict[str, Any] = {"kind": "keypoint", "name": name, "xy": [float(x), float(y)], "at": list(k.at),
                                "spread": list(k.spread)}
        if not visible:
            part["visible"] = False
        parts.append(part)
    return parts, [name for name in given if name not in c.keypoints]


def mapping_document(name: str) -> dict[str, Any]:
    """A bundled road-user mapping (:data:`ROAD_USER_MAPPINGS`) as a mapping file's JSON document.

    - ``coco-person``: COCO's person keypoint files (category ``person``) -> ``Pedestrian`` objects, one keypoint
      annotation per labelled COCO keypoint at the vocabulary's place for a pedestrian.
    - ``two-wheeler``: the two-wheeler vocabulary (wheel contacts and hubs, handlebar ends, saddle, the rider's head
      and shoulders); categories ``cyclist``, ``motorcyclist``, ``bicycle``, ``motorcycle`` (and the spellings of
      :data:`TWO_WHEELER_CATEGORIES`) -> those classes, each keypoint at its class's place.

    Raises
    ------
    KeyError
        Not one of :data:`ROAD_USER_MAPPINGS`.
    """
    if name == "coco-person":
        person = CLASSES["Pedestrian"]
        return {
            "toosicubix_mapping": 1, "name": name,
            "description": "COCO's 17 person keypoints (person_keypoints_*.json) as a Pedestrian's keypoints at the "
                           "places the vocabulary gives them (toosicubix/vocabulary.json, class Pedestrian: "
                           + person.about + ")",
            "keypoints": list(COCO_PERSON_KEYPOINTS), "prototype": "Pedestrian",
            "prototypes": {"person": "Pedestrian", "pedestrian": "Pedestrian"},
            "parts": [_keypoint_part(person.keypoints[k].at, person.keypoints[k].spread, k, {})
                      for k in COCO_PERSON_KEYPOINTS],
        }
    if name == "two-wheeler":
        classes = [CLASSES[c] for c in ("Cyclist", "Motorcyclist", "Bicycle", "Motorcycle")]
        names = list(dict.fromkeys(k for c in classes for k in c.keypoints))
        parts = []
        for k in names:
            owners = [c for c in classes if k in c.keypoints]
            base = owners[0].keypoints[k]
            by = {c.name: {"at": list(c.keypoints[k].at), "spread": list(c.keypoints[k].spread)} for c in owners}
            parts.append(_keypoint_part(base.at, base.spread, k, by))
        return {
            "toosicubix_mapping": 1, "name": name,
            "description": "Two-wheelers with and without a rider (the box of a Cyclist or Motorcyclist holds rider "
                           "and machine, as KITTI and nuScenes box them): wheel contacts and hubs, handlebar ends, "
                           "saddle, the rider's head and shoulders, each at its class's place "
                           "(toosicubix/vocabulary.json). "
                           "Categories by name: " + ", ".join(f"{k} -> {v}" for k, v in TWO_WHEELER_CATEGORIES.items()),
            "keypoints": names, "prototype": "Cyclist",
            "prototypes": dict(TWO_WHEELER_CATEGORIES),
            "parts": parts,
        }
    raise KeyError(name)


def _keypoint_part(at: tuple[float, ...], spread: tuple[float, ...], name: str,
                   by_prototype: dict[str, Any]) -> dict[str, Any]:
    part: dict[str, Any] = {"kind": "keypoint", "keypoint": name, "position": {"at": list(at), "spread": list(spread)}}
    if by_prototype:
        part["by_prototype"] = by_prototype
    return part


def class_notes(prototype: str | None, click_names: Iterable[str],
                prior_height: float | None = None) -> tuple[str, ...]:
    """What a fit of an object of ``prototype`` with keypoint clicks ``click_names`` cannot measure, in plain words
    (results.json's warnings); empty for vehicles.

    - a Pedestrian with no ankle clicked: where the feet stand comes from the height prior (``prior_height``
      metres), not from a click;
    - a Traffic cone: no yaw (rotationally symmetric; the box's X axis along the line of sight is a convention);
    - a Barrier: its yaw is known modulo 180 degrees (its two ends are alike).
    """
    c = class_of(prototype)
    if c is None:
        return ()
    names = set(click_names)
    out = []
    if c.name == "Pedestrian" and names and not names & set(ANKLES):
        height = f" ({prior_height:.2f} m)" if prior_height is not None else ""
        out.append(f"no ankle clicked: the feet, the box's bottom, are placed by the {c.name} height prior{height}, "
                   "not by a click; the depth rests on that prior")
    if c.heading == "none":
        out.append(f"yaw undetermined: a {c.name.lower()} is rotationally symmetric; the box's X axis is put along the "
                   "line of sight away from the camera by convention, and its KITTI rotation_y and alpha are written "
                   "as -10 (KITTI's value for an angle not given)")
    elif c.heading == "axial":
        out.append(f"yaw known modulo 180 degrees: a {c.name.lower()}'s two ends are alike; the box's +X end is the "
                   "end clicked on the image's right")
    return tuple(out)


def import_notes(prototype: str | None, click_names: Iterable[str]) -> tuple[str, ...]:
    """What an importer says of an object of ``prototype`` made with keypoints ``click_names`` (counted per
    sentence in its summary): a Pedestrian with keypoints but no ankle is still fitted, its feet placed by the
    height prior."""
    c = class_of(prototype)
    names = set(click_names)
    if c is not None and c.name == "Pedestrian" and names and not names & set(ANKLES):
        return ("persons without a labelled ankle: fitted all the same, the feet placed by the Pedestrian height "
                "prior (results.json says so per person)",)
    return ()

