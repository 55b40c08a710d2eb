"""The one part vocabulary: every kind of annotation, every name it may carry, and what each one means.

The table is the data file ``vocabulary.json`` beside this module; this module loads it once and answers
questions about it. Per **kind** (``point``, ``symmetry``, ``direction``, ``length``, and for real clicks
``keypoint`` and ``plate``):

- ``name_field``: the annotation-file key that names it (``part``, ``face``, ``axis``, ``feature``);
- ``clicks``: the keys of its clicked pixels, in click order (``xy``; ``left``, ``right``; ...);
- ``known``: the keys of a known size it states (``metres``, ``sigma``), if any;
- ``labels``: the label of each click, ``{name}`` standing for the name (``symmetry-{name}/left``);
- ``on_body``: whether its clicks lie on the vehicle (a direction arrow may be drawn on the ground);
- ``hint``: how a suggestion names it to a person (``{name} arrow on the ground``; default ``{name}``);
- ``suggest_once``: suggest none of the kind once one of it is clicked (direction arrows);
- ``schema``: its pydantic class in :mod:`toosicubix.annotations.schema` (``class``, ``description``, and
  ``fields``: descriptions of its file keys, where a click's differs from the generic pixel's);
- ``soft``: its clicks sit at typical fractions of the dimensions within a spread (keypoints, plates): the
  spread enters as per-click weights (:mod:`toosicubix.solver.robust`), not as the uncertainty's part sigma;
- ``fields_extra``: further typed keys of its annotations, by type name (``row3``: three numbers,
  ``positive_row3``: three positive numbers, ``bool_default_true``), see :data:`EXTRA_FIELD_TYPES`;
- ``names``: every name, in the order the schema lists them; ``null`` for an open kind (``keypoint``), whose
  names are any non-empty string, with no faces and no typical position.

Per **name**:

- ``faces``: the cuboid faces its clicks can be seen on (``null``: anywhere, e.g. an arrow on the ground);
  :mod:`toosicubix.solver.plausibility` checks clicked parts against them;
- ``typical``: where it usually sits on a cuboid, one point per click, each coordinate a linear form
  ``{term: coefficient}`` over ``dx``, ``dy``, ``dz`` (the dimensions), ``Xwf``, ``Xwr`` (the axles),
  ``side`` (+1 when the camera is on the vehicle's left, else -1), ``side*dy`` and ``one`` (a constant), in
  metres, vehicle frame; ``null``: never suggested (:mod:`toosicubix.solver.guidance`);
- ``suits``: ``"all"`` (the default) or a prototype group of ``prototype_groups`` (the cuboid's corners are
  only suggested on box-shaped vehicles: on a car they are points in the air);
- ``suggest`` (directions): ``always``, ``never``, ``camera-left`` or ``camera-right``;
- attributes the linear form reads: ``shape``, ``end``, ``side``, ``axle``, ``height``, ``axis``, ``sign``;
- ``description`` (length features): what its two clicks mark.

Per **class of road user** (``classes``: Pedestrian, Cyclist, Motorcyclist, Bicycle, Motorcycle, Bus, Articulated bus
section, Traffic cone, Barrier; the vehicles of KITTI and Cityscapes are classes of their own by default, the
cuboid vocabulary's), :class:`RoadUserClass`:

- ``prototypes``: the prototypes (size priors) that are this class; ``family``: which classes an evaluation may pair
  (``person``, ``two-wheeler``, ``vehicle``, ``cone``, ``barrier``); ``kitti_type``: the type its KITTI label gets;
- ``heading``: ``directed`` (it has a front: X points there), ``axial`` (its two ends are alike: the yaw is known
  modulo 180 degrees) or ``none`` (rotationally symmetric: no yaw);
- ``box`` and ``front``: what its box encloses and which way its X axis points, in words;
- ``vocabulary``: ``keypoints`` (its own named keypoints, below) or ``cuboid`` (the parts of ``kinds``);
- ``palette``: the colours (``#rrggbb``) its objects are drawn in, one after another in an image (overlays,
  templates): each class its own hues, apart from the vehicles' palette;
- ``keypoints``: per name (COCO's person keypoint names for a pedestrian) its typical position ``at`` and
  ``spread``, fractions of ``(dx, dy, dz)`` as a ``keypoint`` annotation carries them, and a ``description``;
  ``edges``: pairs of them drawn as a skeleton (templates, overlays); ``about`` and ``sources``: where the
  positions come from.

**Adding a kind** is one entry under ``kinds`` in ``vocabulary.json`` plus its linear form: a function in
:mod:`toosicubix.parts.linear` decorated ``@linear_form("kind")`` that adds the kind's points ``X = A p`` (and
any lines or measurements) to the model. The entry gives its names the attributes the linear form reads, their
faces and typical positions; the annotation file's schema builds the kind's class from the entry (then
regenerate ``schemas/annotations.schema.json`` with ``toosicubix schema``). **Adding a name** to a kind is one
entry under its ``names``. ``tests/test_vocabulary.py`` checks that every kind has its linear form and
that every name's faces and typical positions are well formed.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from typing import Any

import numpy as np

#: Faces of the cuboid a click can be seen on (the bottom never is).
FACES = ("front", "rear", "left", "right", "top")
#: Outward normals of the faces (in :data:`FACES` order), vehicle frame: (5, 3).
_FACE_NORMALS = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])
#: Face centres as fractions of (dx, dy, dz), vehicle frame (origin at the bottom centre): (5, 3).
_FACE_CENTRES = np.array([[0.5, 0.0, 0.5], [-0.5, 0.0, 0.5], [0.0, 0.5, 0.5], [0.0, -0.5, 0.5], [0.0, 0.0, 1.0]])
#: The type names ``fields_extra`` may use.
EXTRA_FIELD_TYPES = ("row3", "positive_row3", "bool_default_true")
#: The terms a typical position's linear forms may use.
TYPICAL_TERMS = ("dx", "dy", "dz", "Xwf", "Xwr", "side", "side*dy", "one")


@dataclass(frozen=True)
class Name:
    """One name of a kind, e.g. point ``wheel-front-left``.

    Attributes
    ----------
    kind, name : as in the annotation file
    faces : faces its clicks can be seen on; None: anywhere (the ground included)
    typical : per click, per coordinate (X, Y, Z), ``{term: coefficient}``; None: never suggested
    suits : 'all' or a prototype group
    attributes : every other field of its entry (``shape``, ``end``, ``side``, ``axle``, ...)
    """

    kind: str
    name: str
    faces: tuple[str, ...] | None
    typical: tuple[tuple[dict[str, float], ...], ...] | None
    suits: str
    attributes: dict[str, Any]

    def get(self, key: str, default: Any = None) -> Any:
        """One of its attributes (``shape``, ``end``, ``side``, ``axle``, ``height``, ``axis``, ``sign``, ...)."""
        return self.attributes.get(key, default)


@dataclass(frozen=True)
class Kind:
    """One kind of annotation (see the module's description)."""

    kind: str
    name_field: str
    clicks: tuple[str, ...]
    known: tuple[str, ...]
    labels: tuple[str, ...]
    on_body: bool
    suggest_once: bool
    hint: str
    schema: dict[str, Any]
    names: dict[str, Name]
    open_names: bool = False
    soft: bool = False
    fields_extra: tuple[tuple[str, str], ...] = ()

    def click_labels(self, name: str) -> tuple[str, ...]:
        """A label per click of the annotation ``name``, e.g. ('symmetry-rear/left', 'symmetry-rear/right')."""
        return tuple(template.replace("{name}", name) for template in self.labels)


@dataclass(frozen=True)
class Click:
    """What one click label stands for: its annotation's kind and name, and which of its clicks it is."""

    kind: str
    name: str
    index: int
    label: str


#: How a class's yaw is determined: it has a front; its two ends are alike (modulo 180 degrees); not at all.
HEADINGS = ("directed", "axial", "none")


@dataclass(frozen=True)
class ClassKeypoint:
    """A keypoint of a class's own vocabulary: where it typically is on the box and how far it strays.

    Attributes
    ----------
    name : its name in annotation files (``keypoint`` annotations), e.g. COCO's ``left_shoulder``
    at : (3,) typical position, fractions of ``(dx, dy, dz)``, vehicle frame (x from -0.5 rear to 0.5 front,
        y from -0.5 right to 0.5 left, z from 0 bottom to 1 top)
    spread : (3,) its standard deviation over objects of the class, same fractions, each > 0
    description : what a person clicks
    """

    name: str
    at: tuple[float, float, float]
    spread: tuple[float, float, float]
    description: str


@dataclass(frozen=True)
class RoadUserClass:
    """A class of road users with its prototypes and click vocabulary (see the module's description)."""

    name: str
    family: str
    heading: str
    kitti_type: str
    prototypes: tuple[str, ...]
    box: str
    front: str
    vocabulary: str
    palette: tuple[str, ...]
    keypoints: dict[str, ClassKeypoint]
    edges: tuple[tuple[str, str], ...]
    about: str
    sources: tuple[str, ...]


def _load() -> tuple[dict[str, Kind], dict[str, frozenset[str]]]:
    text = (resources.files("toosicubix") / "vocabulary.json").read_text(encoding="utf-8")
    doc = json.loads(text)
    kinds = {}
    for kind, k in doc["kinds"].items():
        names = {}
        for name, entry in (k["names"] or {}).items():
            faces = entry.get("faces")
            typical = entry.get("typical")
            attributes = {key: value for key, value in entry.items() if key not in ("faces", "typical", "suits")}
            names[name] = Name(
                kind=kind, name=name, faces=None if faces is None else tuple(faces),
                typical=None if typical is None else tuple(tuple(dict(c) for c in point) for point in typical),
                suits=entry.get("suits", "all"), attributes=attributes,
            )
        kinds[kind] = Kind(kind=kind, name_field=k["name_field"], clicks=tuple(k["clicks"]),
                           known=tuple(k.get("known", ())), labels=tuple(k["labels"]), on_body=bool(k["on_body"]),
                           suggest_once=bool(k.get("suggest_once", False)), hint=k.get("hint", "{name}"),
                           schema=dict(k["schema"]), names=names, open_names=k["names"] is None,
                           soft=bool(k.get("soft", False)), fields_extra=tuple(k.get("fields_extra", {}).items()))
    groups = {group: frozenset(members) for group, members in doc["prototype_groups"].items()}
    return kinds, groups


def _load_classes() -> dict[str, RoadUserClass]:
    doc = json.loads((resources.files("toosicubix") / "vocabulary.json").read_text(encoding="utf-8"))
    out = {}
    for name, c in doc.get("classes", {}).items():
        keypoints = {k: ClassKeypoint(k, tuple(float(v) for v in e["at"]), tuple(float(v) for v in e["spread"]),
                                      str(e.get("description", k)))
                     for k, e in c["keypoints"].items()}
        out[name] = RoadUserClass(
            name=name, family=c["family"], heading=c["heading"], kitti_type=c["kitti_type"],
            prototypes=tuple(c["prototypes"]), box=c["box"], front=c["front"], vocabulary=c["vocabulary"],
            palette=tuple(c["palette"]), keypoints=keypoints, edges=tuple((a, b) for a, b in c.get("edges", ())),
            about=c.get("about", ""), sources=tuple(c.get("sources", ())))
    return out


#: Every kind by its name, in the file's order.
KINDS, PROTOTYPE_GROUPS = _load()
#: Every class of road user with a vocabulary or heading of its own, by name, in the file's order.
CLASSES: dict[str, RoadUserClass] = _load_classes()
_CLASS_OF_PROTOTYPE = {p.casefold(): c for c in CLASSES.values() for p in (c.name, *c.prototypes)}
#: The keypoint names of the classes clicked on keypoints of their own (a pedestrian's COCO keypoints, a cyclist's
#: wheels and rider, a cone's tip and base, a barrier's ends).
ROAD_USER_KEYPOINTS: frozenset[str] = frozenset(k for c in CLASSES.values() if c.vocabulary == "keypoints"
                                                for k in c.keypoints)
#: The family of the ground-truth classes that are no prototype (KITTI's and Cityscapes' type names), lower case.
_FAMILY_OF_TYPE = {"person_sitting": "person", "person": "person", "pedestrian": "person", "cyclist": "two-wheeler",
                   "bicycle": "two-wheeler", "motorcycle": "two-wheeler", "traffic_cone": "cone",
                   "trafficcone": "cone", "barrier": "barrier"}


def class_of(prototype: str | None) -> RoadUserClass | None:
    """The class of road users a prototype (or class name, any case) belongs to; None for a vehicle prototype of
    the cuboid vocabulary with no class entry (Car, Van, Truck, the Cityscapes cars)."""
    return None if prototype is None else _CLASS_OF_PROTOTYPE.get(prototype.casefold())


def family_of(*names: str | None) -> str:
    """The family (``person``, ``two-wheeler``, ``vehicle``, ``cone``, ``barrier``) of the first of ``names`` (a
    prototype, a class or a ground-truth type such as KITTI's ``Person_sitting``) that has one; ``vehicle``
    otherwise. An evaluation pairs predictions and ground truth of one family only."""
    for name in names:
        if not name:
            continue
        c = class_of(name)
        if c is not None:
            return c.family
        if name.casefold() in _FAMILY_OF_TYPE:
            return _FAMILY_OF_TYPE[name.casefold()]
    return "vehicle"


#: How the yaw of a family is determined, for a ground-truth type that names no class of ours (``TrafficCone``).
_HEADING_OF_FAMILY = {"cone": "none", "barrier": "axial"}


def heading_of(prototype: str | None) -> str:
    """How the yaw of a ``prototype`` (or a ground-truth type) is determined (:data:`HEADINGS`): its class's, else its
    family's (a ``traffic_cone`` has none), ``directed`` for vehicles."""
    c = class_of(prototype)
    if c is not None:
        return c.heading
    return _HEADING_OF_FAMILY.get(family_of(prototype), "directed")


def class_keypoint_faces(name: str) -> tuple[bool, tuple[str, ...] | None]:
    """``(named, faces)``: whether ``name`` is a keypoint of some class's own vocabulary, and then the faces it can
    be seen on: None, any (a body is no box: a shoulder shows from behind, an ankle through the legs; the v = 1 flag
    of a hidden one says the rest)."""
    named = any(name in c.keypoints for c in CLASSES.values())
    return named, None


def names(kind: str) -> tuple[str, ...]:
    """Every name a ``kind`` annotation may carry, in the schema's order (empty for an open kind)."""
    return tuple(KINDS[kind].names)


#: Every name a ``point`` annotation may carry, in the schema's order.
POINT_PARTS: tuple[str, ...] = names("point")
#: The faces a ``symmetry`` pair may lie on, and the axes a ``direction`` arrow may follow.
SYMMETRY_FACES: tuple[str, ...] = names("symmetry")
DIRECTION_AXES: tuple[str, ...] = names("direction")
#: Features of known size for ``length`` annotations, with what their two clicks ``a`` and ``b`` mark.
LENGTH_FEATURES: dict[str, str | None] = {name: KINDS["length"].names[name].get("description")
                                          for name in names("length")}
#: The dimensions, in the order of ``(dx, dy, dz)``: length, width, height.
DIMENSION_AXES = ("dx", "dy", "dz")


def entry(kind: str, name: str) -> Name:
    """The vocabulary entry of one annotation.

    An open kind's (``keypoint``) names have no entry of their own: any non-empty name gets one with no faces
    and no typical position.

    Raises
    ------
    KeyError
        An unknown kind or name (the schema admits none).
    """
    k = KINDS[kind]
    if k.open_names and name:
        return k.names.get(name) or Name(kind=kind, name=name, faces=None, typical=None, suits="all", attributes={})
    return k.names[name]


def click_labels(kind: str, name: str) -> tuple[str, ...]:
    """A label per clicked pixel of one annotation, e.g. ('symmetry-rear/left', 'symmetry-rear/right')."""
    return KINDS[kind].click_labels(name)


@lru_cache(maxsize=1)
def _clicks_by_label() -> dict[str, Click]:
    out = {}
    for kind in KINDS.values():
        for name in kind.names:
            for index, label in enumerate(kind.click_labels(name)):
                out[label] = Click(kind.kind, name, index, label)
    return out


@lru_cache(maxsize=65536)  # a batch asks it some 200 times a vehicle; an open kind's label is a scan of templates
def click(label: str) -> Click:
    """What a click label stands for (a frozen :class:`Click`, cached by label).

    Raises
    ------
    KeyError
        A label no annotation gives.
    """
    found = _clicks_by_label().get(label)
    if found is not None:
        return found
    for kind in KINDS.values():  # an open kind's label: its template with any non-empty name
        if not kind.open_names:
            continue
        for index, template in enumerate(kind.labels):
            head, _, tail = template.partition("{name}")
            if label.startswith(head) and label.endswith(tail) and len(label) > len(head) + len(tail):
                return Click(kind.kind, label[len(head):len(label) - len(tail)], index, label)
    raise KeyError(label)


def faces_seen_from(camera_vehicle: np.ndarray, dimensions: np.ndarray, grazing_deg: float = 0.0) -> dict[str, bool]:
    """For each face of :data:`FACES`: is it turned to a camera at ``camera_vehicle`` (3,), vehicle frame, on a
    cuboid of ``dimensions`` (3,)? With ``grazing_deg`` 0, when the camera lies beyond the face's plane; a face
    turned away by up to ``grazing_deg`` counts too (negative: it must be turned toward the camera by that much).

    Each face's ``n . (c - centre)`` and ``|c - centre|`` are summed in the order of numpy's ``einsum('fi,fi->f')``
    (its two-lane loop: the first and last terms, then the middle one), so the answers are those of the array form
    it replaced on the solver's hot path, every number the same."""
    cx, cy, cz = np.asarray(camera_vehicle, dtype=float).tolist()
    dx, dy, dz = np.asarray(dimensions, dtype=float).tolist()
    minus_sin = _minus_grazing_sin(grazing_deg)
    seen = {}
    for face, (nx, ny, nz), (fx, fy, fz) in _FACE_GEOMETRY:
        tx, ty, tz = cx - fx * dx, cy - fy * dy, cz - fz * dz
        along = 0.0 + (((0.0 + nx * tx) + nz * tz) + ((0.0 + ny * ty) + 0.0 * 0.0))
        distance = math.sqrt(0.0 + (((0.0 + tx * tx) + tz * tz) + ((0.0 + ty * ty) + 0.0 * 0.0)))
        seen[face] = along > minus_sin * distance
    return seen


#: Each face's name, outward normal and centre (fractions of the dimensions) as Python numbers.
_FACE_GEOMETRY = tuple(zip(FACES, _FACE_NORMALS.tolist(), _FACE_CENTRES.tolist(), strict=True))


@lru_cache(maxsize=16)
def _minus_grazing_sin(grazing_deg: float) -> float:
    return float(-np.sin(np.deg2rad(grazing_deg)))


def faces_of_click(label: str) -> tuple[str, ...] | None:
    """The faces a clicked part can be seen on; None for arrows (drawn anywhere, the ground included) and for
    an open kind's names (a keypoint's faces follow from its position: :attr:`PartsModel.click_faces`)."""
    c = click(label)
    return entry(c.kind, c.name).faces


def on_body(label: str) -> bool:
    """Whether a click lies on the vehicle's body (a direction arrow may be drawn on the ground)."""
    return KINDS[click(label).kind].on_body


def soft(label: str) -> bool:
    """Whether a click sits at a typical place within a spread that its weight carries (keypoints, plates)."""
    return KINDS[click(label).kind].soft


def suits(name: Name, prototypes: tuple[str, ...] | list[str]) -> bool:
    """Whether a part can be clicked on a vehicle of any of ``prototypes`` (its prototype, its KITTI type)."""
    if name.suits == "all":
        return True
    group = PROTOTYPE_GROUPS[name.suits]
    return any(p in group for p in prototypes)


#: Where an axle sits when the fit has no unknown for it: this fraction of the length ahead of (front) or behind
#: (rear) the middle.
TYPICAL_AXLE_FRACTION = 0.3


def typical_terms(dimensions: Any, params: dict[str, float], camera_side: float) -> dict[str, float]:
    """The values of :data:`TYPICAL_TERMS` on a fitted cuboid: ``dimensions`` (dx, dy, dz), metres; ``params`` its
    named unknowns (the axles ``Xwf``, ``Xwr`` where the fit has them, else :data:`TYPICAL_AXLE_FRACTION` of the
    length); ``camera_side`` +1 when the camera is on the vehicle's left, -1 on its right."""
    dx, dy, dz = (float(v) for v in dimensions)
    return {"dx": dx, "dy": dy, "dz": dz, "Xwf": params.get("Xwf", TYPICAL_AXLE_FRACTION * dx),
            "Xwr": params.get("Xwr", -TYPICAL_AXLE_FRACTION * dx), "side": camera_side, "side*dy": camera_side * dy,
            "one": 1.0}


def typical_points(name: Name, values: dict[str, float]) -> list[list[float]]:
    """Where a part usually sits: per click (X, Y, Z), metres, vehicle frame.

    Parameters
    ----------
    values : the terms' values (``dx``, ``dy``, ``dz``, ``Xwf``, ``Xwr``, ``side``, ``side*dy``, ``one``)

    Raises
    ------
    ValueError
        The part is never suggested (no typical position).
    """
    if name.typical is None:
        raise ValueError(f"{name.kind} {name.name} has no typical position")
    return [[_evaluate(form, values) for form in point] for point in name.typical]


def _evaluate(form: dict[str, float], values: dict[str, float]) -> float:
    out = 0.0
    for term, coefficient in form.items():
        out += coefficient * values[term]
    return out
