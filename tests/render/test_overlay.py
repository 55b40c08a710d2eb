"""Overlays: a known cuboid colours the pixels where its corners project and nothing else; edges behind the
camera are cut, never wrapped; clicks, residuals and down-weighted clicks land where they should."""

from __future__ import annotations

import numpy as np
import pytest

from toosicubix.camera import Camera
from toosicubix.geometry import R_cam_vehicle_from_ypr, cuboid_corners_cam
from toosicubix.render.overlay import (
    BLANK_BGR,
    DOWNWEIGHTED_BGR,
    DrawnVehicle,
    OverlayOptions,
    birds_eye_side,
    blank_canvas,
    clip_segment_to_near_plane,
    colour_of,
    compose,
    draw_birds_eye,
    draw_overlay,
)

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
SIZE = (640, 480)


def changed(canvas: np.ndarray) -> np.ndarray:
    """(H, W) mask of the pixels that differ from the blank canvas."""
    return np.any(canvas != np.array(BLANK_BGR, dtype=np.uint8), axis=2)


def vehicle(R, t, d, **kw) -> DrawnVehicle:
    return DrawnVehicle(id="1", ok=True, R_cam_vehicle=R, t_cam_vehicle=np.asarray(t, float),
                        dimensions=np.asarray(d, float), **kw)


@pytest.mark.parametrize("distortion", [None, np.array([-0.25, 0.08, 0.001, -0.001, 0.0])])
def test_known_cuboid_colours_its_corners_and_nothing_outside_its_box(distortion):
    camera = Camera(K=K, distortion=distortion, image_size=SIZE)
    R = R_cam_vehicle_from_ypr(0.6)
    t, d = np.array([0.5, 1.2, 12.0]), np.array([4.0, 1.7, 1.5])
    canvas = draw_overlay(blank_canvas(SIZE), camera, [vehicle(R, t, d)], options=OverlayOptions(birds_eye=False))
    uv = camera.project(cuboid_corners_cam(R, t, d))  # (8, 2), with the lens distortion
    assert np.all((uv > 0) & (uv < np.array(SIZE) - 1))
    mask = changed(canvas)
    colour = np.array(colour_of(0))
    for u, v in np.round(uv).astype(int):
        patch = canvas[v - 1:v + 2, u - 1:u + 2].reshape(-1, 3).astype(int)
        # An edge passes through every corner: some pixel of its 3x3 neighbourhood is near the vehicle's colour
        # (anti-aliasing and the translucent front face blend it, hence the tolerance of 60 per channel).
        assert np.min(np.max(np.abs(patch - colour), axis=1)) < 60, (u, v)
    # Nothing outside the projected corners' box, widened by the line's half-thickness and anti-aliasing (3 px).
    x1, y1 = np.floor(uv.min(axis=0)).astype(int) - 3
    x2, y2 = np.ceil(uv.max(axis=0)).astype(int) + 3
    outside = mask.copy()
    outside[y1:y2 + 1, x1:x2 + 1] = False
    assert not outside.any()
    assert mask.sum() > 200  # and it did draw the cuboid


def test_cuboid_partly_behind_the_camera_is_cut_not_wrapped():
    camera = Camera(K=K, image_size=SIZE)
    R = R_cam_vehicle_from_ypr(-np.pi / 2)  # forward = camera +z: the cuboid runs from z = -1 to z = 4
    t, d = np.array([3.0, 1.5, 1.5]), np.array([5.0, 1.8, 1.5])
    corners_cam = cuboid_corners_cam(R, t, d)
    assert corners_cam[:, 2].min() < 0 < corners_cam[:, 2].max()
    assert np.all(corners_cam[:, 0] > 0)  # all of it lies right of the camera ...
    z = corners_cam[:, 2:3]
    naive_u = 500.0 * corners_cam[:, 0:1] / z + 320.0
    assert naive_u.min() < 320  # ... but a naive projection sends the corners behind it to the left half
    canvas = draw_overlay(blank_canvas(SIZE), camera, [vehicle(R, t, d)], options=OverlayOptions(birds_eye=False))
    mask = changed(canvas)
    assert mask[:, 323:].any()
    assert not mask[:, :318].any()  # nothing wrapped into the left half


def test_cuboid_wholly_behind_the_camera_draws_nothing():
    camera = Camera(K=K, image_size=SIZE)
    R = R_cam_vehicle_from_ypr(0.3)
    canvas = draw_overlay(blank_canvas(SIZE), camera, [vehicle(R, [0.0, 1.5, -8.0], [4.0, 1.7, 1.5])],
                          options=OverlayOptions(birds_eye=False))
    assert not changed(canvas).any()
    panel = draw_birds_eye(400, camera, [vehicle(R, [0.0, 1.5, -8.0], [4.0, 1.7, 1.5])], image_width=SIZE[0])
    assert panel.shape == (400, 400, 3)


def test_clip_segment_to_near_plane():
    a, b = np.array([1.0, 0.0, -1.0]), np.array([1.0, 2.0, 3.0])
    a2, b2 = clip_segment_to_near_plane(a, b, 0.1)
    np.testing.assert_allclose(a2, [1.0, 1.1 / 2.0, 0.1], atol=1e-12)  # algebra: exact up to rounding
    np.testing.assert_array_equal(b2, b)
    assert clip_segment_to_near_plane(a, a - 1.0, 0.1) is None
    same = clip_segment_to_near_plane(b, b + 1.0, 0.1)
    assert same is not None and np.array_equal(same[0], b)


def test_clicks_residual_lines_and_downweighted_marks():
    camera = Camera(K=K, image_size=SIZE)
    clicks = np.array([[100.0, 100.0], [500.0, 400.0]])
    fitted = clicks + np.array([[30.0, 0.0], [0.0, 0.0]])
    v = DrawnVehicle(id="7", ok=False, clicks_uv=clicks, fitted_uv=fitted, downweighted=(1,), error="x",
                     box2d=np.array([300.0, 300.0, 310.0, 310.0]))  # its failure box away from the clicks
    canvas = draw_overlay(blank_canvas(SIZE), camera, [v], options=OverlayOptions(birds_eye=False))
    # The residual line of click 0 runs to the right of it, 20 px along.
    assert changed(canvas)[100, 120]
    red = np.all(np.abs(canvas.astype(int) - np.array(DOWNWEIGHTED_BGR)) < 40, axis=2)
    assert red[390:411, 490:511].any()  # click 1 is crossed out
    assert not red[90:111, 90:111].any()  # click 0 is not


def test_dashes_of_many_straight_lines_at_once_match_one_by_one(rng):
    from toosicubix.render.overlay import _dashed, _dashed_all

    lines = [rng.uniform(-100.0, 1000.0, (2, 2)) for _ in range(20)] + [np.array([[0.0, 0.0], [3.0, 4.0]])]
    curved = np.array([[0.0, 0.0], [10.0, 5.0], [30.0, 5.0]])
    one_by_one = [d for line in [curved, *lines] for d in _dashed(line)]
    at_once = _dashed_all([curved, *lines])
    assert len(one_by_one) == len(at_once)
    for a, b in zip(one_by_one, at_once, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9)  # the same arithmetic reordered: rounding only


def test_a_tall_image_gets_a_bird_s_eye_panel_as_tall_as_itself():
    K_tall = np.array([[2300.0, 0.0, 1690.0], [0.0, 2300.0, 1350.0], [0.0, 0.0, 1.0]])
    camera = Camera(K=K_tall, image_size=(3384, 2710))
    car = vehicle(np.eye(3), [0.0, 1.5, 30.0], [4.0, 1.7, 1.5])
    side = birds_eye_side(2710)
    panel = draw_birds_eye(side, camera, [car], image_width=3384, height=2710)
    assert panel.shape == (2710, side, 3) and side == 1400
    # Nothing left black: the grey panel reaches the bottom of the composed picture.
    composed = compose(np.zeros((2710, 3384, 3), dtype=np.uint8), panel)
    assert composed.shape == (2710, 3384 + 1400, 3)
    assert composed[2000:, 3384:].max() > 0 and (composed[2000:, 3384:] > 0).mean() > 0.99


def test_labels_asked_for_the_same_place_are_moved_apart():
    from toosicubix.render.overlay import _LabelPlacer

    placer = _LabelPlacer(np.full((400, 400, 3), 40, dtype=np.uint8))
    for text in ("12", "13", "14"):  # three vehicles side by side in the top view: one anchor
        placer.put(text, (200.0, 200.0), (255, 255, 255), 0.5)
    for k, a in enumerate(placer.placed):
        for b in placer.placed[k + 1:]:
            assert min(a[2], b[2]) <= max(a[0], b[0]) or min(a[3], b[3]) <= max(a[1], b[1]), (a, b)
    assert (placer.canvas == 0).any()  # drawn on dark boxes


def test_a_ground_truth_note_is_written_in_white_above_its_cuboid():
    from toosicubix.render.overlay import GROUND_TRUTH_BGR, DrawnCuboid

    camera = Camera(K=K, image_size=SIZE)
    R, t, d = R_cam_vehicle_from_ypr(0.6), np.array([0.5, 1.2, 12.0]), np.array([4.0, 1.7, 1.5])
    options = OverlayOptions(birds_eye=False)
    bare = draw_overlay(blank_canvas(SIZE), camera, [], [DrawnCuboid(R, t, d)], options)
    noted = draw_overlay(blank_canvas(SIZE), camera, [], [DrawnCuboid(R, t, d, "GT 7: hides 4 of its 9 keypoints")],
                         options)
    top = camera.project(cuboid_corners_cam(R, t, d))[:, 1].min()
    differ = np.any(bare != noted, axis=2)
    rows = np.flatnonzero(differ.any(axis=1))
    assert rows.size and rows.max() < top  # the note, and nothing else, is added above the cuboid
    assert np.all(noted[differ] == np.array(GROUND_TRUTH_BGR, dtype=np.uint8), axis=1).any()  # white text
