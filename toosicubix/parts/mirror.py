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

_SIDE = re.compile(r"\b(left|right)\b|(left|right)(?=ward$)")
_OTHER = {"left": "right", "right": "left"}


def _swapped_name(name: str) -> str:
    return _SIDE.sub(lambda m: _OTHER[m.group(0)], name)


def mirrored(parts: tuple[Part, ...]) -> tuple[Part, ...]:
    """The parts with the vehicle's left and right swapped (see the module docstring)."""
    out = []
    for part in parts:
        kind = KINDS[part.kind]
        if part.kind in ("symmetry", "plate"):  # two clicks, left then right
            out.append(replace(part, uv=part.uv[::-1].copy(),
                               at=None if part.at is None else part.at * np.array([1.0, -1.0, 1.0])))
        elif kind.open_names:  # a keypoint: its place across the vehicle
            out.append(replace(part, at=None if part.at is None else part.at * np.array([1.0, -1.0, 1.0])))
        else:
            name = _swapped_name(part.name)
            out.append(replace(part, name=name) if name in kind.names else part)
    return tuple(out)
