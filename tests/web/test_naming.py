"""The candidates an unnamed click is named from (:func:`naming_candidates`), keypoints included."""

from __future__ import annotations

import numpy as np
import pytest

from tests.web.synthetic import CAMERA, DIMENSIONS, R_CAM_VEHICLE, T_CAM_VEHICLE
from toosicubix.formats.results import VehicleResult
from toosicubix.parts.linear import TypicalKeypoint
from toosicubix.web.naming import naming_candidates, nearest_parts

FRONT_LEFT = [0.5, 0.4, 0.5]  # on the front and left faces, both turned to the camera
REAR_RIGHT = [-0.5, -0.4, 0.5]  # on the faces turned away


def _at(at: list[float], seen_from: tuple[str, ...] = ()) -> TypicalKeypoint:
    return TypicalKeypoint(np.array(at), np.full(3, 0.02), seen_from)


def _fit(next_clicks: list[dict]) -> VehicleResult:
    return VehicleResult("1", "ok", None, "Car", R_CAM_VEHICLE, T_CAM_VEHICLE, DIMENSIONS,
                         next_clicks=tuple(next_clicks))


def _pixel(at: list[float]) -> list[float]:
    return CAMERA.project((R_CAM_VEHICLE @ (DIMENSIONS * np.array(at)) + T_CAM_VEHICLE)[None])[0].tolist()


def test_keypoints_projected_at_their_fractions_and_hidden_ones_not_chosen():
    wheel = {"kind": "point", "name": "wheel-front-left", "uv": [[100.0, 300.0]], "visible": True}
    arrow = {"kind": "direction", "name": "forward", "uv": [[1.0, 1.0], [2.0, 2.0]], "visible": True}
    candidates = naming_candidates(_fit([wheel, arrow]), CAMERA, {"fl": _at(FRONT_LEFT), "rr": _at(REAR_RIGHT)})
    by_name = {c["name"]: c for c in candidates}
    assert set(by_name) == {"wheel-front-left", "fl", "rr"}
    assert np.allclose(by_name["fl"]["uv"][0], _pixel(FRONT_LEFT))
    assert by_name["fl"]["visible"] and not by_name["rr"]["visible"]
    near_rr = nearest_parts(_pixel(REAR_RIGHT), candidates)
    assert "rr" not in [c["name"] for c in near_rr]
    best = nearest_parts([p + 1.0 for p in _pixel(FRONT_LEFT)], candidates)[0]
    assert (best["kind"], best["name"]) == ("keypoint", "fl")
    assert best["distance_px"] == round(2 ** 0.5, 2)


def test_point_parts_only_those_asked_for_and_no_keypoints_by_default():
    wheel = {"kind": "point", "name": "wheel-front-left", "uv": [[100.0, 300.0]], "visible": True}
    assert naming_candidates(_fit([wheel]), CAMERA) == [wheel]
    assert naming_candidates(_fit([wheel]), CAMERA, {"fl": _at(FRONT_LEFT)}, points=set())[0]["name"] == "fl"
    failed = VehicleResult("1", "failed", "degenerate clicks", "Car")
    assert naming_candidates(failed, CAMERA, {"fl": _at(FRONT_LEFT)}) == []


def test_a_keypoint_is_named_among_the_visible_by_the_faces_it_was_learned_to_be_seen_from():
    """The faces a keypoint was learned to be seen from decide, not those its position sits near."""
    candidates = naming_candidates(_fit([]), CAMERA, {"rr-seen": _at(REAR_RIGHT, ("front",)),
                                                      "fl-unseen": _at(FRONT_LEFT, ("rear", "right"))})
    visible = {c["name"]: c["visible"] for c in candidates}
    assert visible == {"rr-seen": True, "fl-unseen": False}


def test_with_spreads_and_shares_the_most_probable_keypoint_comes_first():
    """A click 6 px from a narrow keypoint (sigma 2 px) and 8 px from a wide one (sigma 10 px): the wide one is
    the more probable (its cost 0.32 + 4.61 against 4.5 + 1.39, minus the log of equal priors), though farther;
    a prior of 0.01 on it turns that around; without sigmas and priors the nearest comes first."""
    near = {"kind": "keypoint", "name": "plate", "uv": [[106.0, 100.0]], "visible": True}
    wide = {"kind": "keypoint", "name": "handle", "uv": [[92.0, 100.0]], "visible": True}
    click = [100.0, 100.0]
    assert [c["name"] for c in nearest_parts(click, [near, wide])] == ["plate", "handle"]
    ranked = nearest_parts(click, [{**near, "sigma_px": 2.0, "prior": 0.5}, {**wide, "sigma_px": 10.0, "prior": 0.5}])
    assert [c["name"] for c in ranked] == ["handle", "plate"]
    assert [c["distance_px"] for c in ranked] == [8.0, 6.0]
    rare = nearest_parts(click, [{**near, "sigma_px": 2.0, "prior": 0.5}, {**wide, "sigma_px": 10.0, "prior": 0.01}])
    assert [c["name"] for c in rare] == ["plate", "handle"]


def test_a_keypoints_pixel_spread_is_the_click_noise_and_its_spread_projected():
    candidates = naming_candidates(_fit([]), CAMERA, {"fl": TypicalKeypoint(np.array(FRONT_LEFT), np.array(
        [0.01, 0.02, 0.03]), (), 0.4)}, click_sigma=1.5)
    (c,) = candidates
    depth = (R_CAM_VEHICLE @ (DIMENSIONS * np.array(FRONT_LEFT)) + T_CAM_VEHICLE)[2]
    spread_m = np.array([0.01, 0.02, 0.03]) * DIMENSIONS
    f = 0.5 * (CAMERA.K[0, 0] + CAMERA.K[1, 1])
    assert c["sigma_px"] == pytest.approx(np.sqrt(1.5**2 + (f / depth) ** 2 * spread_m @ spread_m / 3), rel=1e-12)
    assert c["prior"] == 0.4
    assert "sigma_px" not in naming_candidates(_fit([]), CAMERA, {"fl": _at(FRONT_LEFT)})[0]
