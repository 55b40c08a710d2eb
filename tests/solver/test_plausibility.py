"""The seen-faces check names the same clicks, in click order, as its first form did (issue 37 made it cheaper)."""

import numpy as np

from toosicubix.geometry import R_cam_vehicle_from_ypr
from toosicubix.solver.plausibility import faces_turned_to_camera, unseen_clicks
from toosicubix.vocabulary import faces_of_click

LABELS = ("wheel-front-left", "wheel-rear-right", "symmetry-front/left", "symmetry-front/right", "front-center",
          "edge-front-right", "edge-rear-left", "symmetry-roof/left", "corner-bottom-rear-left", "rear-center",
          "direction-forward/tail", "direction-forward/head")


def first_form(labels, R, t, d):
    visible = faces_turned_to_camera(R, t, d)
    return [label for label in labels
            if faces_of_click(label) is not None and not any(visible[f] for f in faces_of_click(label))]


def test_unseen_clicks_are_those_of_the_first_form_in_click_order():
    rng = np.random.default_rng(21)
    labels = tuple(label for label in LABELS if _known(label))
    assert len(labels) >= 8
    named = 0
    for _ in range(3000):
        R = R_cam_vehicle_from_ypr(rng.uniform(-np.pi, np.pi), rng.normal(0.0, 0.5), rng.normal(0.0, 0.5))
        t = np.array([rng.normal(0.0, 5.0), rng.normal(1.5, 1.0), rng.uniform(-5.0, 40.0)])
        d = rng.uniform([3.0, 1.5, 1.3], [5.0, 2.0, 1.9])
        expected = first_form(labels, R, t, d)
        assert unseen_clicks(labels, R, t, d) == expected
        named += bool(expected)
    assert 0 < named < 3000  # both answers are exercised


def _known(label: str) -> bool:
    try:
        faces_of_click(label)
    except KeyError:
        return False
    return True
