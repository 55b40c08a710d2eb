"""Each class of road users is drawn in its own palette; the vehicles keep the overlay's (issue 35)."""

import pytest

from toosicubix.render.palette import CLASS_PALETTES_BGR, class_colours, hex_to_bgr
from toosicubix.vocabulary import CLASSES


def test_hex_colours_become_bgr():
    assert hex_to_bgr("#ff4fa3") == (0xa3, 0x4f, 0xff)
    with pytest.raises(ValueError, match="#rrggbb"):
        hex_to_bgr("ff4fa3")


def test_each_class_takes_its_own_colours_in_image_order_and_vehicles_none():
    people = CLASS_PALETTES_BGR["Pedestrian"]
    colours = class_colours(["Car", "Pedestrian", "Cyclist", "Pedestrian", None, "Van"])
    assert colours == [None, people[0], CLASS_PALETTES_BGR["Cyclist"][0], people[1], None, None]
    many = class_colours(["Pedestrian"] * (len(people) + 1))
    assert many[-1] == people[0]  # a class with more objects than colours repeats them


def test_no_two_classes_share_a_colour():
    seen = [c for name in CLASSES for c in CLASS_PALETTES_BGR[name]]
    assert len(seen) == len(set(seen))
