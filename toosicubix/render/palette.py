"""Each class of road users in its own palette (:attr:`toosicubix.vocabulary.RoadUserClass.palette`): pedestrians in
pinks, cyclists in greens, buses in oranges, ..., the vehicles of the cuboid vocabulary (Car, Van, Truck) in the
overlay's own palette (:data:`toosicubix.render.overlay.PALETTE_BGR`), as before.

Colours are BGR (OpenCV's order). Within one image the objects of a class take its palette's colours in image order;
a class with more objects than colours repeats them.
"""

from __future__ import annotations

from collections.abc import Sequence

from toosicubix.vocabulary import CLASSES, class_of


def hex_to_bgr(colour: str) -> tuple[int, int, int]:
    """``#rrggbb`` -> (b, g, r).

    Raises
    ------
    ValueError
        Not a ``#rrggbb`` colour.
    """
    if len(colour) != 7 or colour[0] != "#":
        raise ValueError(f"expected a colour #rrggbb, got {colour!r}")
    r, g, b = (int(colour[i:i + 2], 16) for i in (1, 3, 5))
    return b, g, r


#: Each class's palette, BGR, by class name.
CLASS_PALETTES_BGR: dict[str, tuple[tuple[int, int, int], ...]] = {
    name: tuple(hex_to_bgr(c) for c in cls.palette) for name, cls in CLASSES.items()}


def class_colours_hex(prototypes: Sequence[str | None]) -> list[str | None]:
    """The colour of each object of an image (``prototypes`` in image order) as ``#rrggbb``: its class's palette in
    the order the class's objects come, or None for a vehicle of the cuboid vocabulary (drawn in the overlay's
    palette, or on the page in its track's colour)."""
    seen: dict[str, int] = {}
    out: list[str | None] = []
    for prototype in prototypes:
        cls = class_of(prototype)  # a class of road users beyond the box-shaped vehicles, or None
        if cls is None:
            out.append(None)
            continue
        k = seen.get(cls.name, 0)
        seen[cls.name] = k + 1
        out.append(cls.palette[k % len(cls.palette)])
    return out


def class_colours(prototypes: Sequence[str | None]) -> list[tuple[int, int, int] | None]:
    """As :func:`class_colours_hex`, BGR (what the overlay draws with)."""
    return [None if colour is None else hex_to_bgr(colour) for colour in class_colours_hex(prototypes)]
