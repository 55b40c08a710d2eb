"""From annotations to the linear model ``X_i = A_i p`` of every clicked point (paper, "Method").

``p = (dx, dy, dz, [Xwf], [Xwr], aux...)``: the dimensions, the shared front and rear wheel
positions (only when a front or rear wheel is clicked), then each annotation's own unknowns. Vehicle
frame: origin at the bottom-face centre, X forward, Y left, Z up.

| kind / name                        | 3D point(s)                              | new unknowns   |
|------------------------------------|------------------------------------------|----------------|
| wheel-{front,rear}-{left,right}    | (Xwf or Xwr, +-dy/2, 0)                  | Xwf / Xwr      |
| front-center / rear-center         | (+-dx/2, 0, Z)                           | Z              |
| top-center                         | (X, 0, dz)                               | X              |
| edge-{front,rear}-{left,right}     | (+-dx/2, +-dy/2, Z)                      | Z              |
| corner-{top,bottom}-{fr}-{lr}      | (+-dx/2, +-dy/2, dz or 0)                | none           |
| symmetry front / rear              | (+-dx/2, +Y, Z), (+-dx/2, -Y, Z)         | Y, Z           |
| symmetry roof                      | (X, +Y, dz), (X, -Y, dz)                 | X, Y           |
| direction forward / backward       | (X, Y, Z) -> (X +- dx, Y, Z)             | X, Y, Z        |
| direction leftward / rightward     | (X, Y, Z) -> (X, Y +- dy, Z)             | X, Y, Z        |
| direction upward / downward        | (X, Y, Z) -> (X, Y, Z +- dz)             | X, Y, Z        |
| length plate-{front,rear}          | (+-dx/2, +Y, Z), (+-dx/2, -Y, Z)         | Y, Z           |
| length wheelbase-{left,right}      | (Xwf, +-dy/2, 0), (Xwr, +-dy/2, 0)       | Xwf, Xwr       |
| length tyre-{front,rear}-{lr}      | (Xw, +-dy/2, 0), (Xw, +-dy/2, Zt)        | Xw, Zt         |
| hub-{front,rear}-{left,right}      | (Xwf or Xwr, +-dy/2, Zh)                 | Xwf / Xwr, Zh  |
| keypoint (name, at, spread)        | (at_x dx, at_y dy, at_z dz)              | none           |
| plate front / rear (at, width)     | (at_x dx, +-W/2, at_z dz)                | W (measured)   |

Wheel hubs share the axle unknowns with the tyre contacts and one hub height ``Zh`` among the four. A keypoint
sits at learned fractions ``at`` of the dimensions; ``spread`` (same fractions) says how far real vehicles put it
from there, and enters the pixel cost as a per-click weight (:attr:`PartsModel.click_spread`).

A ``length`` annotation also gives a *measurement*, a linear equation on ``p`` with a known value in metres:
the plate's width ``2 Y``, the wheelbase ``Xwf - Xwr``, the tyre's diameter ``Zt``. Known dimensions of the
vehicle are measurements too. Unlike the clicks, measurements fix the scale.

The names and their attributes come from the part vocabulary (:mod:`toosicubix.vocabulary`); each kind's
linear form is a function here registered with ``@linear_form(kind)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from toosicubix.model import Part
from toosicubix.vocabulary import (
    KINDS,
    ROAD_USER_KEYPOINTS,
    class_keypoint_faces,
    click,
    click_labels,
    entry,
    faces_of_click,
)

DX, DY, DZ = 0, 1, 2
#: Degrees of freedom of a cuboid: rotation 3, translation 3, dimensions 3.
CUBOID_DOF = 9
#: What one image can determine: the cuboid up to scale.
IMAGE_DOF = 8

_SIDE = {"front": 1.0, "rear": -1.0, "left": 1.0, "right": -1.0}
DIM_INDEX = {"dx": DX, "dy": DY, "dz": DZ}


@dataclass(frozen=True)
class Line:
    """Two clicks whose 3D points differ along a vehicle axis: ``X_j - X_i`` is parallel to ``e_axis``.

    Used by the yaw initialisation (``l^T K R D = 0``).
    """

    i: int
    j: int
    axis: int  # 0: X (forward), 1: Y (left)


@dataclass(frozen=True)
class Measurement:
    """A known size: ``coefficients @ p == metres`` within ``sigma``.

    Attributes
    ----------
    coefficients : (P,)
    label : e.g. 'length plate-rear' or 'known dx'
    """

    coefficients: np.ndarray
    metres: float
    sigma: float
    label: str


@dataclass(frozen=True)
class PartsModel:
    """The clicked points of one vehicle as linear functions of ``p``.

    Attributes
    ----------
    A : (N, 3, P) ``X_vehicle_i = A[i] @ p``
    uv : (N, 2) clicked pixels, in click order
    click_labels : (N,) what each click is, e.g. 'wheel-front-left', 'symmetry-rear/left'
    click_part : (N,) index of the annotation each click belongs to
    param_names : (P,) 'dx', 'dy', 'dz', 'Xwf', 'Xwr', then 'parts[k].X' etc.
    lines : pairs of clicks along a known vehicle axis
    measurements : known sizes (length annotations, known dimensions)
    click_spread : (N, 3) for keypoint and plate clicks the spread of their position, fractions of
        ``(dx, dy, dz)``; zeros for every other click; None when the vehicle has none
    """

    A: np.ndarray
    uv: np.ndarray
    click_labels: tuple[str, ...]
    click_part: np.ndarray
    param_names: tuple[str, ...]
    lines: tuple[Line, ...]
    measurements: tuple[Measurement, ...] = ()
    click_spread: np.ndarray | None = None

    @property
    def n_clicks(self) -> int:
        return len(self.uv)

    @property
    def n_params(self) -> int:
        return self.A.shape[2]

    @property
    def n_aux(self) -> int:
        """Unknowns besides the dimensions: wheel positions and per-annotation auxiliaries."""
        return self.n_params - 3

    @property
    def constraints(self) -> int:
        """Equations left for the cuboid: two per click minus one per auxiliary unknown."""
        return 2 * self.n_clicks - self.n_aux

    @property
    def keypoints_only(self) -> bool:
        """Every click is a keypoint or a plate end (at a typical position), none a cuboid part or an arrow."""
        return self.n_clicks > 0 and all(click(label).kind in ("keypoint", "plate") for label in self.click_labels)

    @property
    def road_user(self) -> bool:
        """Every click is a keypoint of a road user's own vocabulary (:data:`~toosicubix.vocabulary.
        ROAD_USER_KEYPOINTS`: a pedestrian's COCO keypoints): a car's wheels and lamps are no advice for it."""
        return self.keypoints_only and all(click(label).name in ROAD_USER_KEYPOINTS for label in self.click_labels)

    @property
    def arrow_tails(self) -> tuple[int, ...]:
        """The click index of each direction arrow's tail; its head is the next click."""
        return tuple(i for i, label in enumerate(self.click_labels) if _is_arrow_tail(label))

    @property
    def click_faces(self) -> tuple[tuple[str, ...] | None, ...]:
        """The faces each click can be seen on, for the plausibility check: the vocabulary's, and for a keypoint
        (an open kind's name) the faces its typical position ``at`` sits near: beyond 0.3 of the length or width
        from the centre, or above 0.85 of the height; None (no check) when near none, and for arrows. A keypoint
        of a road-user class's own vocabulary (a pedestrian's shoulder) has the faces the class gives it: any."""
        at = self.A[:, (0, 1, 2), (DX, DY, DZ)].tolist()  # (N, 3): a keypoint's typical position, fractions
        return tuple(_click_faces(label, *xyz) for label, xyz in zip(self.click_labels, at, strict=True))

    def points_vehicle(self, p: np.ndarray) -> np.ndarray:
        """The clicked points in the vehicle frame for parameters ``p`` (P,): (N, 3)."""
        return self.A @ p


class TypicalKeypoint(NamedTuple):
    """A keypoint as a candidate to click: ``at`` (3,) its typical position and ``spread`` (3,), fractions of the
    dimensions, ``seen_from`` the faces it is seen from (learned, :mod:`toosicubix.parts.learned`; empty: the
    faces its position sits near, :func:`keypoint_faces`), and ``clicked_share`` how often people click it where
    it can be seen (learned; 1 when not)."""

    at: np.ndarray
    spread: np.ndarray
    seen_from: tuple[str, ...] = ()
    clicked_share: float = 1.0

    @property
    def faces(self) -> tuple[str, ...] | None:
        """The faces one of which must be turned to the camera for it to be seen (None: no such face)."""
        return tuple(self.seen_from) or keypoint_faces(self.at)


@lru_cache(maxsize=8192)
def _click_faces(label: str, x: float, y: float, z: float) -> tuple[str, ...] | None:
    """:attr:`PartsModel.click_faces` of one click, at ``(x, y, z)`` when it is a keypoint; kept, as a batch's keypoints
    sit at the few typical positions of its mapping (reading a label costs more than the check)."""
    c = click(label)
    if not KINDS[c.kind].open_names:
        return faces_of_click(label)
    named, faces = class_keypoint_faces(c.name)
    return faces if named else keypoint_faces((x, y, z))


def keypoint_faces(at) -> tuple[str, ...] | None:
    """The faces a keypoint at fractions ``at`` (3,) of the dimensions sits near: beyond 0.3 of the length or
    width from the centre, or above 0.85 of the height; None when near none."""
    faces = tuple(face for face, near in (("front", at[0] > 0.3), ("rear", at[0] < -0.3),
                                          ("left", at[1] > 0.3), ("right", at[1] < -0.3),
                                          ("top", at[2] > 0.85)) if near)
    return faces or None


def _is_arrow_tail(label: str) -> bool:
    """The first click of an annotation not on the body (a direction arrow's tail)."""
    c = click(label)
    return c.index == 0 and not KINDS[c.kind].on_body


class _Builder:
    def __init__(self, parts: tuple[Part, ...]):
        self.names = ["dx", "dy", "dz"]
        axles = {axle for p in parts for axle in _axles(p)}
        self.wheel = {}
        for axle, label in (("front", "Xwf"), ("rear", "Xwr")):
            if axle in axles:
                self.wheel[axle] = len(self.names)
                self.names.append(label)
        self.coeffs: list[list[dict[int, float]]] = []  # per click: the linear forms of X, Y, Z
        self.labels: list[str] = []
        self.owner: list[int] = []
        self.lines: list[Line] = []
        self.measurements: list[tuple[dict[int, float], float, float, str]] = []
        self.wheel_clicks: dict[tuple[str, str], list[int]] = {}  # (axle, side) -> clicks on that tyre's contact
        self.corner_clicks: dict[tuple[str, str, str], list[int]] = {}  # (height, end, side) -> clicks
        self.hub_clicks: dict[tuple[str, str], list[int]] = {}  # (axle, side) -> clicks on that wheel's hub
        self.hub_height: int | None = None  # the index of Zh, shared by all hubs
        self.spread: dict[int, np.ndarray] = {}  # keypoint and plate clicks: their spread (3,)

    def aux(self, k: int, what: str) -> int:
        self.names.append(f"parts[{k}].{what}")
        return len(self.names) - 1

    def point(self, k: int, label: str, x: dict[int, float], y: dict[int, float], z: dict[int, float]) -> int:
        """Add a click whose X, Y, Z are the linear forms ``x``, ``y``, ``z`` ({param: coefficient})."""
        self.coeffs.append([x, y, z])
        self.labels.append(label)
        self.owner.append(k)
        return len(self.labels) - 1

    def build(self, uv: np.ndarray) -> PartsModel:
        P = len(self.names)
        A = np.zeros((len(self.coeffs), 3, P))
        for i, forms in enumerate(self.coeffs):
            for row, form in enumerate(forms):
                for param, c in form.items():
                    A[i, row, param] += c
        measurements = []
        for form, metres, sigma, label in self.measurements:
            c = np.zeros(P)
            for param, coefficient in form.items():
                c[param] += coefficient
            measurements.append(Measurement(c, metres, sigma, label))
        spread = None
        if self.spread:
            spread = np.zeros((len(self.coeffs), 3))
            for i, row in self.spread.items():
                spread[i] = row
        return PartsModel(A=A, uv=uv, click_labels=tuple(self.labels), click_part=np.array(self.owner, dtype=int),
                          param_names=tuple(self.names), lines=tuple(self.lines), measurements=tuple(measurements),
                          click_spread=spread)


def _axles(part: Part) -> tuple[str, ...]:
    """The axles whose positions (``Xwf``, ``Xwr``) an annotation's points use."""
    e = entry(part.kind, part.name)
    shape = e.get("shape")
    if shape == "wheelbase":
        return ("front", "rear")
    if shape in ("wheel", "tyre", "hub"):
        return (e.get("axle"),)
    return ()


#: The linear form of each kind: ``f(builder, k, part)`` adds the clicks of annotation ``k``.
LinearForm = Callable[[_Builder, int, Part], None]
LINEAR_FORMS: dict[str, LinearForm] = {}


def linear_form(kind: str) -> Callable[[LinearForm], LinearForm]:
    """Register the function that adds a ``kind`` annotation's points to the model (see the vocabulary)."""
    def register(f: LinearForm) -> LinearForm:
        LINEAR_FORMS[kind] = f
        return f
    return register


def build_parts_model(parts: tuple[Part, ...] | list[Part],
                      known_dimensions: dict[str, tuple[float, float]] | None = None) -> PartsModel:
    """The linear model of a vehicle's annotations (see the module's table).

    Parameters
    ----------
    parts : the vehicle's annotations, in file order
    known_dimensions : ``{"dx": (metres, sigma), ...}``, dimensions known from elsewhere

    Returns
    -------
    PartsModel
    """
    parts = tuple(parts)
    b = _Builder(parts)
    uv_rows = []
    for k, part in enumerate(parts):
        uv_rows.append(part.uv)
        LINEAR_FORMS[part.kind](b, k, part)
    for axis, (metres, sigma) in (known_dimensions or {}).items():
        b.measurements.append(({DIM_INDEX[axis]: 1.0}, metres, sigma, f"known {axis}"))
    _wheel_lines(b, b.wheel_clicks)
    _wheel_lines(b, b.hub_clicks)
    _corner_lines(b)
    uv = np.concatenate(uv_rows, axis=0) if uv_rows else np.zeros((0, 2))
    return b.build(uv)


@linear_form("point")
def _add_point(b: _Builder, k: int, part: Part) -> None:
    name = part.name
    e = entry("point", name)
    shape = e.get("shape")
    if shape == "wheel":
        axle, side = e.get("axle"), e.get("side")
        i = b.point(k, name, {b.wheel[axle]: 1.0}, {DY: 0.5 * _SIDE[side]}, {})
        b.wheel_clicks.setdefault((axle, side), []).append(i)
    elif shape == "hub":  # on its axle (the tyre contacts' Xwf / Xwr), at the hub height Zh shared by all four
        axle, side = e.get("axle"), e.get("side")
        if b.hub_height is None:
            b.hub_height = len(b.names)
            b.names.append("Zh")
        i = b.point(k, name, {b.wheel[axle]: 1.0}, {DY: 0.5 * _SIDE[side]}, {b.hub_height: 1.0})
        b.hub_clicks.setdefault((axle, side), []).append(i)
    elif shape == "end-center":
        b.point(k, name, {DX: 0.5 * _SIDE[e.get("end")]}, {}, {b.aux(k, "Z"): 1.0})
    elif shape == "top-center":
        b.point(k, name, {b.aux(k, "X"): 1.0}, {}, {DZ: 1.0})
    elif shape == "edge":
        b.point(k, name, {DX: 0.5 * _SIDE[e.get("end")]}, {DY: 0.5 * _SIDE[e.get("side")]}, {b.aux(k, "Z"): 1.0})
    elif shape == "corner":
        height, end, side = e.get("height"), e.get("end"), e.get("side")
        i = b.point(k, name, {DX: 0.5 * _SIDE[end]}, {DY: 0.5 * _SIDE[side]}, {DZ: 1.0} if height == "top" else {})
        b.corner_clicks.setdefault((height, end, side), []).append(i)
    else:
        raise ValueError(f"point part {name!r} has no linear form (shape {shape!r})")


@linear_form("symmetry")
def _add_symmetry(b: _Builder, k: int, part: Part) -> None:
    face = part.name
    end = entry("symmetry", face).get("end")
    left, right = click_labels("symmetry", face)
    if end is not None:  # a front or rear pair
        y, z = b.aux(k, "Y"), b.aux(k, "Z")
        x_form = {DX: 0.5 * _SIDE[end]}
        i = b.point(k, left, x_form, {y: 1.0}, {z: 1.0})
        j = b.point(k, right, x_form, {y: -1.0}, {z: 1.0})
    else:  # on the roof
        x, y = b.aux(k, "X"), b.aux(k, "Y")
        i = b.point(k, left, {x: 1.0}, {y: 1.0}, {DZ: 1.0})
        j = b.point(k, right, {x: 1.0}, {y: -1.0}, {DZ: 1.0})
    b.lines.append(Line(i, j, axis=1))


@linear_form("length")
def _add_length(b: _Builder, k: int, part: Part) -> None:
    """Add a length annotation's two points and its measurement."""
    metres, sigma = part.known  # type: ignore[misc]
    feature = part.name
    e = entry("length", feature)
    shape, side = e.get("shape"), e.get("side")
    label = f"length {feature}"
    a, b_label = click_labels("length", feature)
    if shape == "plate":
        y, z = b.aux(k, "Y"), b.aux(k, "Z")
        x_form = {DX: 0.5 * _SIDE[e.get("end")]}
        i = b.point(k, a, x_form, {y: 1.0}, {z: 1.0})
        j = b.point(k, b_label, x_form, {y: -1.0}, {z: 1.0})
        b.lines.append(Line(i, j, axis=1))
        b.measurements.append(({y: 2.0}, metres, sigma, label))
    elif shape == "wheelbase":
        y_form = {DY: 0.5 * _SIDE[side]}
        i = b.point(k, a, {b.wheel["front"]: 1.0}, y_form, {})
        j = b.point(k, b_label, {b.wheel["rear"]: 1.0}, y_form, {})
        b.measurements.append(({b.wheel["front"]: 1.0, b.wheel["rear"]: -1.0}, metres, sigma, label))
        b.wheel_clicks.setdefault(("front", side), []).append(i)
        b.wheel_clicks.setdefault(("rear", side), []).append(j)
    elif shape == "tyre":
        axle = e.get("axle")
        top = b.aux(k, "Zt")
        x_form, y_form = {b.wheel[axle]: 1.0}, {DY: 0.5 * _SIDE[side]}
        i = b.point(k, a, x_form, y_form, {})
        b.point(k, b_label, x_form, y_form, {top: 1.0})
        b.measurements.append(({top: 1.0}, metres, sigma, label))
        b.wheel_clicks.setdefault((axle, side), []).append(i)
    else:
        raise ValueError(f"length feature {feature!r} has no linear form (shape {shape!r})")


@linear_form("direction")
def _add_direction(b: _Builder, k: int, part: Part) -> None:
    e = entry("direction", part.name)
    axis, sign = DIM_INDEX[e.get("axis")], float(e.get("sign"))
    x, y, z = b.aux(k, "X"), b.aux(k, "Y"), b.aux(k, "Z")
    tail = [{x: 1.0}, {y: 1.0}, {z: 1.0}]
    head = [dict(f) for f in tail]
    head[axis][axis] = sign  # + or - the dimension along that axis (dx, dy, dz have indices 0, 1, 2)
    tail_label, head_label = click_labels("direction", part.name)
    i = b.point(k, tail_label, *tail)
    j = b.point(k, head_label, *head)
    if axis < 2:
        b.lines.append(Line(i, j, axis=axis))


def _wheel_lines(b: _Builder, wheels: dict[tuple[str, str], list[int]]) -> None:
    for side in ("left", "right"):  # same side: front to rear wheel runs along X
        for i in wheels.get(("front", side), []):
            for j in wheels.get(("rear", side), []):
                b.lines.append(Line(i, j, axis=0))
    for axle in ("front", "rear"):  # same axle: left to right wheel runs along Y
        for i in wheels.get((axle, "left"), []):
            for j in wheels.get((axle, "right"), []):
                b.lines.append(Line(i, j, axis=1))


def _corner_lines(b: _Builder) -> None:
    corners = b.corner_clicks
    for (height, end, side), clicks in corners.items():
        if end == "front":  # front-to-rear edge along X
            for i in clicks:
                for j in corners.get((height, "rear", side), []):
                    b.lines.append(Line(i, j, axis=0))
        if side == "left":  # left-to-right edge along Y
            for i in clicks:
                for j in corners.get((height, end, "right"), []):
                    b.lines.append(Line(i, j, axis=1))


@linear_form("keypoint")
def _add_keypoint(b: _Builder, k: int, part: Part) -> None:
    """A keypoint at fractions ``at`` of the dimensions: ``(at_x dx, at_y dy, at_z dz)``, no new unknowns; its
    ``spread`` weighs its click (:mod:`toosicubix.solver.robust`)."""
    at = part.at  # type: ignore[union-attr]
    (label,) = click_labels("keypoint", part.name)
    i = b.point(k, label, {DX: float(at[0])}, {DY: float(at[1])}, {DZ: float(at[2])})
    b.spread[i] = np.asarray(part.spread, dtype=float)


@linear_form("plate")
def _add_plate(b: _Builder, k: int, part: Part) -> None:
    """A licence plate's ends: a centreline point at fractions ``at`` and a measured width ``W``."""
    at, (metres, sigma) = part.at, part.known  # type: ignore[misc]
    w = b.aux(k, "W")
    x_form, z_form = {DX: float(at[0])}, {DZ: float(at[2])}  # type: ignore[index]
    a, b_label = click_labels("plate", part.name)
    i = b.point(k, a, x_form, {w: 0.5}, z_form)
    j = b.point(k, b_label, x_form, {w: -0.5}, z_form)
    b.spread[i] = b.spread[j] = np.asarray(part.spread, dtype=float)
    b.lines.append(Line(i, j, axis=1))
    b.measurements.append(({w: 1.0}, metres, sigma, f"plate {part.name}"))
