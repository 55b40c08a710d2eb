"""A vehicle's clicks with its left and right swapped: what they would be had the person taken the vehicle's left for
the image's left (the commonest naming slip: seen from the front, the vehicle's own left is on the image's right).

Swapped: ``-left`` and ``-right`` in point part names, length features and direction axes (``leftward`` and
``rightward``); the two clicks of a symmetric pair (``left``, ``right``) and of a plate (``a`` on the left, ``b`` on
the right); a keypoint's typical position across the vehicle (``at``'s Y). Everything else stays.
"""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np

from toosicubix.model import Part
from toosicubix.vocabulary import KINDS

#: A point or a position across the vehicle mirrored about its midplane: ``at * MIRROR`` (vehicle frame).
MIRROR = np.array([1.0, -1.0, 1.0])
_SIDE = re.compile(r"(?<![A-Za-z0-9])(left|right)(?![A-Za-z0-9])|(left|right)(?=ward$)", re.IGNORECASE)


def swapped_sides(name: str) -> str:
    """``name`` with the vehicle's left and right swapped: the words ``left`` and ``right``, each whole between anything
    but letters and digits (``wheel-front-left``, ``top_left_c_left_front_car_light``; each word's case kept), and a
    direction axis's ``leftward`` / ``rightward``; the name itself when it has neither."""
    def swap(match: re.Match) -> str:
        word = match.group(0)
        other = "right" if word.lower() == "left" else "left"
        return other.upper() if word.isupper() else other.capitalize() if word[0].isupper() else other

    return _SIDE.sub(swap, name)


def mirrored(parts: tuple[Part, ...]) -> tuple[Part, ...]:
    """The parts with the vehicle's left and right swapped (see the module docstring)."""
    out = []
    for part in parts:
        kind = KINDS[part.kind]
        if part.kind in ("symmetry", "plate"):  # two clicks, left then right
            out.append(replace(part, uv=part.uv[::-1].copy(),
                               at=None if part.at is None else part.at * MIRROR))
        elif kind.open_names:  # a keypoint: its place across the vehicle
            out.append(replace(part, at=None if part.at is None else part.at * MIRROR))
        else:
            name = swapped_sides(part.name)
            out.append(replace(part, name=name) if name in kind.names else part)
    return tuple(out)
