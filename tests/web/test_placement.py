"""Names before a fit exists: the prototype's prior cuboid placed by the box and the named clicks
(:func:`toosicubix.web.placement.propose`), on the synthetic car seen from its front left (tests/web/synthetic.py:
10 m away, the camera 1.65 m above its road)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.web.synthetic import CAMERA, DIMENSIONS, R_CAM_VEHICLE, T_CAM_VEHICLE
from toosicubix.annotations.convert import ground_with
from toosicubix.annotations.priors_file import load_priors
from toosicubix.geometry import cuboid_corners_cam
from toosicubix.model import KITTI_GROUND
from toosicubix.parts.synthesis import PartSpec, render_parts
from toosicubix.web.placement import NamingSettings, candidate_names, propose

WHEEL_X = (0.3 * DIMENSIONS[0], -0.3 * DIMENSIONS[0])


@pytest.fixture(scope="module")
def car():
    return load_priors()["Car"]


def _uv(name: str, **aux: float) -> np.ndarray:
    """The pixel of part ``name`` (at its ``aux`` place, fractions of the height or length) on the synthetic car."""
    values = {k: v * DIMENSIONS[2 if k == "Z" else 0] for k, v in aux.items()}
    return render_parts([PartSpec("point", name, values)], R_CAM_VEHICLE, T_CAM_VEHICLE, DIMENSIONS, CAMERA,
                        WHEEL_X)[0].uv


def _named(*names: str) -> list[tuple[str, str, np.ndarray]]:
    return [("point", n, _uv(n)) for n in names]


def test_a_first_click_with_nothing_to_place_the_car_is_not_placed_and_offers_the_wheels(car):
    """One click and no box: nothing places the car, so the page will not name it; with the camera above a level
    road, the parts that can be at a click below the horizon and near the road are the wheels, about equally."""
    proposal = propose(CAMERA, car, [], _uv("wheel-front-left")[0])
    assert not proposal.placed
    top = proposal.choices[:4]
    assert {name for _, name, _ in top} == {f"wheel-{a}-{s}" for a in ("front", "rear") for s in ("left", "right")}
    assert all(abs(p - 0.25) < 0.02 for _, _, p in top)
    assert abs(sum(p for *_, p in proposal.choices) - 1.0) < 1e-12  # probabilities: normalised


def test_a_click_above_the_horizon_is_no_wheel(car):
    """The road is 1.5 m below the camera: a point on it is seen below the horizon (row cy), never above."""
    above = np.array([620.0, 120.0])  # 60 px above the horizon row 180
    wheels = {n for _, n, p in propose(CAMERA, car, [], above).choices if n.startswith("wheel") and p > 1e-6}
    assert wheels == set()


def test_named_clicks_place_the_prior_cuboid_and_name_the_next_clicks(car):
    """With the image's ground block (KITTI's: the camera 1.65 +- 0.1 m above the road, as on the synthetic car),
    after the front left wheel is named the rear left wheel's click is named that, and so on, each surely (exact
    clicks at the parts' typical places: over 0.8 each); no click is an outlier."""
    ground = ground_with(None, KITTI_GROUND)[1]
    named = _named("wheel-front-left")
    for name in ("wheel-rear-left", "wheel-front-right"):
        proposal = propose(CAMERA, car, named, _uv(name)[0], ground=ground)
        assert proposal.placed and not proposal.outlier
        (kind, best, p), *_ = proposal.choices
        assert (kind, best) == ("point", name) and p > 0.8, proposal.choices[:3]  # the page asks below 0.5
        named.append(("point", name, _uv(name)))
    proposal = propose(CAMERA, car, named, _uv("edge-front-left", Z=0.6)[0], ground=ground)
    assert proposal.choices[0][1] == "edge-front-left"


def test_without_a_ground_block_the_assumed_camera_height_ranks_but_is_less_sure(car):
    """Without a ground block the camera is assumed 1.5 +- 1 m above the road: the second wheel's true name still
    comes first, with less of the probability (the page asks below rule 24a's 0.5) than with KITTI's block."""
    (_, best, p), *_ = propose(CAMERA, car, _named("wheel-front-left"), _uv("wheel-rear-left")[0]).choices
    assert best == "wheel-rear-left" and 0.25 < p < 0.9


def test_parts_on_faces_turned_away_are_never_offered(car):
    """Seen from the front left: once the front left wheel and the front badge are named, the rear right wheel and
    edge (on the rear and right faces, both turned away) get no probability wherever the click is."""
    named = _named("wheel-front-left", "wheel-rear-left", "wheel-front-right")
    for uv in (_uv("edge-rear-left", Z=0.5)[0], np.array([700.0, 250.0])):
        offered = {name: p for _, name, p in propose(CAMERA, car, named, uv).choices}
        assert "wheel-rear-right" not in offered and "edge-rear-right" not in offered


def test_a_box_places_the_car_and_sharpens_the_names(car):
    """The box around the projected cuboid places the car without any named click, but a box is the same seen from
    any of four mirror views: the first click is placed, its true name one of four equally likely wheels (the page
    asks). With one wheel named as well, the next click's name is all but certain (without the box: above 0.5)."""
    corners_uv = CAMERA.project(cuboid_corners_cam(R_CAM_VEHICLE, T_CAM_VEHICLE, DIMENSIONS))
    box = np.concatenate([corners_uv.min(axis=0), corners_uv.max(axis=0)])
    proposal = propose(CAMERA, car, [], _uv("wheel-front-left")[0], box2d=box)
    assert proposal.placed
    assert {n for _, n, p in proposal.choices if p > 0.2} == {f"wheel-{a}-{s}" for a in ("front", "rear")
                                                              for s in ("left", "right")}
    (_, best, p), *_ = propose(CAMERA, car, _named("wheel-front-left"), _uv("wheel-rear-left")[0], box2d=box).choices
    assert best == "wheel-rear-left" and p > 0.99


def test_a_click_far_from_every_part_is_an_outlier(car):
    named = _named("wheel-front-left", "wheel-rear-left", "wheel-front-right")
    assert propose(CAMERA, car, named, np.array([20.0, 20.0])).outlier


def test_candidates_suit_the_prototype():
    """Box corners only on box-shaped bodies; hubs (no typical place) never."""
    car = {name for _, name in candidate_names("Car")}
    van = {name for _, name in candidate_names("Van")}
    assert "corner-top-front-left" not in car and "corner-top-front-left" in van
    assert not any(n.startswith("hub") for n in car | van)
    assert car <= van


def test_no_camera_height_assumed_leaves_the_first_click_to_anything():
    """Without a ground block and with no height assumed, nothing keeps a part off a click's place: a first click
    below the horizon may as well be a roof feature."""
    car = load_priors()["Car"]
    proposal = propose(CAMERA, car, [], _uv("wheel-front-left")[0],
                       settings=NamingSettings(camera_height_sigma_m=None))
    offered = {name: p for _, name, p in proposal.choices}
    assert offered["top-center"] > 0.01 and offered["edge-front-left"] > 0.01
