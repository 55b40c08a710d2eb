"""Why a vehicle's clicks cannot give a cuboid: too few constraints, clicks in one blob or on one line, arrows
without a length (all judged before solving), a direction of the unknowns the answer leaves undetermined, or an
answer at an absurd depth (judged after).

Each refusal has two sentences (:class:`Refusal`): ``reason``, in plain words for the person who clicked (what is
missing and which click or cue would fix it; no parameter names), and ``detail``, the technical account for experts
(results.json's ``error_detail``: the unknowns involved, the numbers and thresholds)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from toosicubix.camera import Camera
from toosicubix.parts.linear import PartsModel
from toosicubix.solver.problem import Problem
from toosicubix.vocabulary import click

_BLOCKS = ("rotation", "rotation", "rotation", "position", "position", "position")


class Refusal(NamedTuple):
    """Why no cuboid: ``reason`` in plain words (what to click or add), ``detail`` the technical account.
    ``cuboid`` False: the undetermined direction moves only parts' own unknowns (where a part sits on the body, where
    an arrow was drawn), not the cuboid, which is then fitted with ``reason`` as a warning (rule 30)."""

    reason: str
    detail: str
    cuboid: bool = True


def degeneracy(problem: Problem, J: np.ndarray, tolerance: float) -> Refusal | None:
    """A refusal when the clicks and the prior leave a direction of the unknowns undetermined, else None.
    ``J`` : (M, 6 + P) the Jacobian at the answer (:func:`.refine.residuals_and_jacobian`). A direction that involves
    only parts' own unknowns (rule 30 of benchmarks/decisions.md: a roof pair seen from exactly behind slides along the
    line of sight) leaves the cuboid where it is: its refusal has ``cuboid`` False and says so."""
    names = _unknown_names(problem)
    norms = np.linalg.norm(J, axis=0)
    if np.any(norms == 0.0):
        missing = [names[i] for i in np.flatnonzero(norms == 0.0)]
        return _refusal(problem.parts, missing, f"degenerate clicks: nothing constrains {', '.join(missing)}")
    _, s, Vt = np.linalg.svd(J / norms, full_matrices=False)
    if s[-1] >= tolerance * s[0]:
        return None
    null = np.abs(Vt[-1])
    involved = sorted({names[i] for i in np.flatnonzero(null > 0.3 * null.max())})
    return _refusal(problem.parts, involved,
                    f"degenerate clicks: they do not determine {', '.join(involved)} (Jacobian rank deficient)")


def _refusal(parts: PartsModel, unknowns: list[str], detail: str) -> Refusal:
    """The refusal for ``unknowns`` left undetermined; a warning instead (``cuboid`` False) when all are parts' own."""
    if all(name.startswith("parts[") for name in unknowns):
        return Refusal(f"the clicks do not fix {_loose(_phrases(parts, unknowns))}; the cuboid does not depend on "
                       "it, so it is fitted without it", detail, cuboid=False)
    return Refusal(_undetermined(parts, unknowns), detail)


def _unknown_names(problem: Problem) -> list[str]:
    return [*_BLOCKS, *problem.parts.param_names]


#: An arrow shorter than this (pixels) has no direction.
MIN_ARROW_PX = 1.0


def short_arrows(parts: PartsModel) -> Refusal | None:
    """A refusal naming the direction arrows whose tail and head are less than MIN_ARROW_PX apart, else None."""
    found, plain = [], []
    for i in parts.arrow_tails:
        length = float(np.linalg.norm(parts.uv[i + 1] - parts.uv[i]))
        if length < MIN_ARROW_PX:
            axis = click(parts.click_labels[i]).name
            found.append(f"the {axis} arrow of annotation parts[{parts.click_part[i]}] is {length:.2f} px long")
            plain.append(f"the {axis} arrow (parts[{parts.click_part[i]}])")
    if not found:
        return None
    return Refusal(f"{_join(plain)} {'has' if len(plain) == 1 else 'have'} no length: draw each arrow from its "
                   f"tail to its head along the vehicle, at least {MIN_ARROW_PX:g} px long",
                   "degenerate clicks: " + "; ".join(found) + f" (an arrow needs at least {MIN_ARROW_PX:g} px)")


#: Clicks whose spread (root mean square distance from their centroid along their main direction) is below
#: this many pixels are one blob: a vehicle that small in the image cannot be annotated part by part.
MIN_CLICK_SPREAD_PX = 4.0
#: Clicks whose root mean square distance from their best-fitting line is below this many pixels lie on one
#: line (clicks on a real vehicle's wheels, lights and edges span an area).
MIN_CLICK_THICKNESS_PX = 0.5
#: A fit this far away (metres) is absurd for a vehicle whose parts were clicked.
MAX_DEPTH_M = 1000.0


def degenerate_spread(uv: np.ndarray) -> Refusal | None:
    """Why the clicks ``uv`` (N, 2), pixels, cannot determine a cuboid (clustered or collinear), else None."""
    if len(uv) < 3:
        return None
    spread = np.linalg.svd(uv - uv.mean(axis=0), compute_uv=False) / np.sqrt(len(uv))  # RMS along the axes
    if spread[0] < MIN_CLICK_SPREAD_PX:
        return Refusal(f"all {len(uv)} clicks are within a few pixels of each other: the vehicle is too small to "
                       f"click part by part; zoom in and click parts spread over the whole vehicle",
                       f"degenerate clicks: all {len(uv)} clicks lie in one cluster ({spread[0]:.2f} px RMS "
                       f"spread; at least {MIN_CLICK_SPREAD_PX:g} px needed)")
    if spread[1] < MIN_CLICK_THICKNESS_PX:
        return Refusal(f"all {len(uv)} clicks lie on one straight line in the image, which no cuboid's parts do "
                       f"from a real view; click parts off that line (a top corner, a wheel at the other end)",
                       f"degenerate clicks: all {len(uv)} clicks lie on one line ({spread[1]:.2f} px RMS off it; "
                       f"at least {MIN_CLICK_THICKNESS_PX:g} px needed)")
    return None


def absurd_depth(camera: Camera, t_cam_vehicle: np.ndarray, dimensions: np.ndarray) -> str | None:
    """Why a fit at ``t_cam_vehicle`` (3,), metres, with ``dimensions`` (3,) is too far to be believed, else None:
    beyond ``MAX_DEPTH_M``, or so far that the vehicle spans fewer than ``MIN_CLICK_SPREAD_PX`` pixels."""
    depth = float(t_cam_vehicle[2])
    focal = float(max(camera.K[0, 0], camera.K[1, 1]))
    extent_px = focal * float(np.max(dimensions)) / depth if depth > 0 else np.inf
    if not (np.isfinite(depth) and depth <= MAX_DEPTH_M and extent_px >= MIN_CLICK_SPREAD_PX):
        return (f"degenerate clicks: the fit is at an absurd depth ({depth:.4g} m, where the vehicle spans "
                f"{extent_px:.3g} px; at most {MAX_DEPTH_M:g} m and {MIN_CLICK_SPREAD_PX:g} px)")
    return None


def too_far(detail: str) -> Refusal:
    """The refusal of an answer :func:`absurd_depth` rejects (``detail`` its sentence)."""
    return Refusal("the only cuboid these clicks fit is absurdly far away, so they cannot all be on one vehicle as "
                   "named: " + _CHECK_NAMES, detail)


def too_few(parts: PartsModel, needed: int, held: int = 0) -> Refusal:
    """The refusal of clicks that give fewer than ``needed`` constraints; ``held``: the auxiliary unknowns a prior
    holds (a car's axles, rule 31 of benchmarks/decisions.md), not counted against the clicks."""
    constraints = parts.constraints + held
    short = max(needed - constraints, 0)
    more = max(-(-short // 2), 3 - parts.n_clicks, 1)
    held_words = f", {held} of them held by the axle prior" if held else ""
    return Refusal(f"too few clicks: {parts.n_clicks} clicked point{'s' if parts.n_clicks != 1 else ''} cannot "
                   f"place a cuboid; click at least {more} more named part{'s' if more != 1 else ''} (the wheels "
                   f"where they touch the road and the body's corners and edges work best)",
                   f"too few constraints: {parts.n_clicks} clicked points give {constraints} "
                   f"(2 per point minus {parts.n_aux} auxiliary unknowns{held_words}); at least {needed} are needed "
                   f"to place the cuboid with its size prior, 8 to fix its shape from the clicks alone")


def no_start(parts: PartsModel) -> Refusal:
    """The refusal when no start led to a cuboid in front of the camera."""
    return Refusal("no cuboid in front of the camera fits these clicks: " + _CHECK_NAMES,
                   "degenerate clicks: no start led to a cuboid in front of the camera")


def starts_collapsed(depth: str) -> Refusal:
    """The refusal when every start collapsed onto the camera and the typical parts' start leaves the distance
    ``depth`` ('not determined' or 'uncertain by N %')."""
    return Refusal("these clicks hardly tie the vehicle to its size, so its distance is " + depth + ": click "
                   "both wheels on a side you can see, a licence plate's two ends, or give the road (a ground "
                   "block)",
                   f"degenerate clicks: every start collapsed onto the camera, and from typical part positions the "
                   f"distance is {depth}: the clicks hardly tie the vehicle to its size")


_CHECK_NAMES = ("check each click's name (left and right are the vehicle's own, as its driver sees them) and the "
                "camera's intrinsics")

_VIEWS = {"rear": "from behind", "front": "from the front", "left": "from its left side",
          "right": "from its right side"}
#: What would fix a view, best first: (the words, the click kind and names that already give it).
_ARROW_ALONG = ("a forward arrow along its side", "direction", ("forward", "backward"))
_ARROW_ACROSS = ("a leftward arrow across it", "direction", ("leftward", "rightward"))
_SIDE_WHEEL = ("a wheel or an edge on a side you can see", "point", ())
_END_PART = ("a part on its front or rear (a light pair, the plate, an edge)", "point", ())
_VIEW_FIX = {"rear": (_ARROW_ALONG, _SIDE_WHEEL), "front": (_ARROW_ALONG, _SIDE_WHEEL),
             "left": (_END_PART, _ARROW_ACROSS), "right": (_END_PART, _ARROW_ACROSS)}
_QUANTITY_FIX = {
    "heading": _ARROW_ALONG,
    "position": ("a wheel where it touches the road", "point", ()),
    "length": ("both wheels on one side", "point", ()),
    "width": ("a left-right pair (two lights, two wheels, the plate's ends)", "point", ()),
    "height": ("a top corner, or an upward arrow", "point", ()),
    "arrow": ("a longer arrow along the vehicle in its place", "point", ()),
}


def _missing(parts: PartsModel, fixes) -> list[str]:
    """The words of the fixes the vehicle does not already have (an arrow of that axis already drawn)."""
    given = {(click(label).kind, click(label).name) for label in parts.click_labels}
    return [words for words, kind, names in fixes if not any((kind, name) in given for name in names)]


def seen_only_from(parts: PartsModel) -> str | None:
    """The one face ('front', 'rear', 'left', 'right') every clicked part can be seen on, or None: the view the
    clicks give when they are all on one face (the roof and arrows, seen from anywhere, aside)."""
    common: set[str] | None = None
    for faces in parts.click_faces:
        sides = set(faces or ()) - {"top"}
        if sides:
            common = sides if common is None else common & sides
    return next(iter(common)) if common is not None and len(common) == 1 else None


def _undetermined(parts: PartsModel, unknowns: list[str]) -> str:
    """Plain words for unknowns the clicks leave undetermined: the view, what is loose, and what would fix it."""
    phrases = _phrases(parts, unknowns)
    loose = _loose(phrases)
    view = seen_only_from(parts)
    fixes = _missing(parts, _VIEW_FIX[view] if view is not None else [_QUANTITY_FIX[q] for q in phrases])
    advice = "; add " + ", or ".join(fixes[:2]) if fixes else ""
    if view is not None:
        return f"seen only {_VIEWS[view]}, the clicks do not fix {loose}{advice}"
    return f"the clicks do not fix {loose}{advice}"


def _phrases(parts: PartsModel, unknowns: list[str]) -> dict[str, list[str]]:
    """Each quantity ('heading', 'length', ...) the unknowns belong to, with their plain words, in order first met."""
    phrases: dict[str, list[str]] = {}
    for name in unknowns:
        words, quantity = _quantity(parts, name)
        if words not in phrases.setdefault(quantity, []):
            phrases[quantity].append(words)
    return phrases


def _loose(phrases: dict[str, list[str]]) -> str:
    """What the unknowns of :func:`_phrases` leave loose, in plain words ('where the roof pair sits along it and how
    wide the roof pair is')."""
    return _join([words[0] if len(words) == 1 else _GROUPED[quantity] for quantity, words in phrases.items()])


_GROUPED = {"arrow": "where the arrows lie", "length": "where the clicked parts sit along it",
            "width": "how wide the clicked parts are",
            "height": "how high the clicked parts sit"}


def _quantity(parts: PartsModel, name: str) -> tuple[str, str]:
    """Plain words for one unknown, and the quantity ('heading', 'position', 'length', 'width', 'height') it is."""
    if name == "rotation":
        return "which way it faces", "heading"
    if name == "position":
        return "where it stands", "position"
    if name in ("dx", "Xwf", "Xwr"):
        return "its length", "length"
    if name == "dy":
        return "its width", "width"
    if name in ("dz", "Zh"):
        return "its height", "height"
    k, _, axis = name.removeprefix("parts[").partition("].")
    part = _part_words(parts, int(k))
    if click(parts.click_labels[int(np.flatnonzero(parts.click_part == int(k))[0])]).kind == "direction":
        return f"where {part} lies", "arrow"  # an arrow's own unknowns: where along its rays it was drawn
    return {"X": (f"where {part} sits along it", "length"), "Y": (f"how wide {part} is", "width"),
            "Z": (f"how high {part} sits", "height")}[axis]


def _part_words(parts: PartsModel, k: int) -> str:
    """An annotation's part in plain words: 'the rear pair', 'the forward arrow', 'rear center'."""
    label = parts.click_labels[int(np.flatnonzero(parts.click_part == k)[0])]
    c = click(label)
    name = c.name.replace("-", " ")
    return {"symmetry": f"the {name} pair", "direction": f"the {name} arrow", "length": f"the {name}'s ends",
            "plate": f"the {name} plate", "keypoint": f"keypoint {c.name}"}.get(c.kind, f"the {name}")


def _join(words: list[str]) -> str:
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} and {words[-1]}"
