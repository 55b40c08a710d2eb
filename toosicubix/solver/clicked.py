"""What a vehicle has clicked already: the one rule that next-click guidance (:mod:`.guidance`) and the
observability's advice (:mod:`.uncertainty`) share, so that neither ever asks for a click the person has made.

A part counts as clicked when an annotation names it (a wheel's contact with the road and its hub are one wheel; a
wheelbase is its two wheels), or when the part is predicted within :data:`ALREADY_CLICKED_SIGMAS` click sigmas of a
click: no click could tell it from the one already there.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from toosicubix import vocabulary

#: A part predicted closer to a click than this many click sigmas is not suggested: no click could tell it from the
#: one already there (2 sigmas: 3 px at the default 1.5 px, whatever the vehicle's size in the image).
ALREADY_CLICKED_SIGMAS = 2.0


def named_as_clicked(annotations: Iterable[tuple[str, str]]) -> set[tuple[str, str]]:
    """The annotations ``(kind, name)`` a vehicle has, with a wheelbase counted as its two wheels clicked and a
    wheel's hub or its contact with the road as that wheel (both of its points) clicked."""
    clicked = set(annotations)
    for kind, name in list(clicked):
        e = vocabulary.entry(kind, name)
        if e.get("shape") == "wheelbase":
            clicked |= {("point", f"wheel-{axle}-{e.get('side')}") for axle in ("front", "rear")}
        elif e.get("shape") in ("wheel", "hub"):  # one wheel, whichever of its two points was clicked
            clicked |= {("point", f"{shape}-{e.get('axle')}-{e.get('side')}") for shape in ("wheel", "hub")}
    return clicked


def near_a_click(uv: np.ndarray, clicked_uv: np.ndarray, radius: float) -> bool:
    """Whether any of a part's predicted pixels ``uv`` (k, 2) lies within ``radius`` pixels of a click
    (``clicked_uv`` (N, 2), the same image coordinates)."""
    if not len(uv) or not len(clicked_uv):
        return False
    return bool(np.any(near_clicks(uv, clicked_uv, radius)))


def near_clicks(uv: np.ndarray, clicked_uv: np.ndarray, radius: float) -> np.ndarray:
    """For each predicted pixel ``uv`` (k, 2), whether it lies within ``radius`` pixels of a click (``clicked_uv``
    (N, 2), N >= 1): (k,) bool."""
    gaps = np.linalg.norm(np.asarray(uv)[:, None] - np.asarray(clicked_uv)[None], axis=2)
    return gaps.min(axis=1) < radius
