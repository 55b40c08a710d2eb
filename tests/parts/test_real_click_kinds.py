"""The parts people click on real cars: wheel hubs, licence plates, keypoints at learned positions; and learned
positions from a synthetic fleet."""

from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import CAMERA
from toosicubix.geometry import R_cam_vehicle_from_ypr, geodesic_angle
from toosicubix.model import Part
from toosicubix.parts.learned import (
    KeypointSample,
    LearnedPosition,
    faces_toward,
    halves,
    hidden_by_ground_truth,
    learn_positions,
    learned_mapping,
    mirrored_positions,
    seen_from,
)
from toosicubix.parts.linear import build_parts_model
from toosicubix.parts.mirror import swapped_sides
from toosicubix.size_priors import SizePrior
from toosicubix.solver.fit import SolverOptions, fit_vehicle

#: Keypoints on the rear and the left side of a car (fractions of dx, dy, dz), as real ones sit.
REAR_LEFT = {"lamp-rear-left": (-0.45, 0.38, 0.62), "lamp-rear-right": (-0.45, -0.38, 0.62),
             "glass-rear-left": (-0.25, 0.3, 0.92), "glass-rear-right": (-0.25, -0.3, 0.92),
             "bumper-left": (-0.48, 0.35, 0.25), "handle-front": (0.05, 0.47, 0.56), "handle-rear": (-0.2, 0.47, 0.58),
             "door-bottom": (0.2, 0.48, 0.18), "mirror": (0.18, 0.5, 0.65)}


def project(X_vehicle: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    Y = X_vehicle @ R.T + t
    return Y[:, :2] / Y[:, 2:] @ CAMERA.K[:2, :2].T + CAMERA.K[:2, 2]


def scene(rng: np.random.Generator):
    d = np.array([4.6, 1.8, 1.5])
    R = R_cam_vehicle_from_ypr(np.deg2rad(rng.uniform(-140, -100)), 0.0, 0.0)  # rear and left side in view
    t = np.array([rng.uniform(-3, 3), 1.6, rng.uniform(12, 25)])
    return d, R, t


def keypoint_parts(d, R, t, names=REAR_LEFT):
    parts = []
    for k, (name, at) in enumerate(names.items()):
        uv = project((np.array(at) * d)[None], R, t)
        parts.append(Part("keypoint", name, uv, f"parts[{k}]", None, np.array(at), np.full(3, 0.02)))
    return parts


def exact_prior(d):
    return SizePrior.from_mean_cov("test", d, np.diag([0.3, 0.1, 0.1]) ** 2)


def test_keypoints_recover_a_known_cuboid_noise_free(rng):
    for _ in range(3):
        d, R, t = scene(rng)
        fit = fit_vehicle(build_parts_model(keypoint_parts(d, R, t)), CAMERA, exact_prior(d))
        assert fit.ok, fit.reason
        # Noise-free clicks at the true fractions and a prior centred on the truth: exact up to the solver's
        # tolerance (1e-6 noiseless tier).
        assert geodesic_angle(fit.R_cam_vehicle, R) < 1e-6
        np.testing.assert_allclose(fit.t_cam_vehicle, t, atol=1e-5)
        np.testing.assert_allclose(fit.dimensions, d, atol=1e-5)


def test_hubs_share_the_axles_and_one_height(rng):
    d, R, t = scene(rng)
    wheel_x, hub_z = (1.4, -1.3), 0.33
    parts = keypoint_parts(d, R, t, {k: v for k, v in REAR_LEFT.items() if "handle" not in k})
    for k, (fr, x) in enumerate(zip(("front", "rear"), wheel_x, strict=True)):
        uv = project(np.array([[x, 0.5 * d[1], hub_z]]), R, t)
        parts.append(Part("point", f"hub-{fr}-left", uv, f"hub[{k}]"))
    model = build_parts_model(parts)
    assert model.param_names[3:] == ("Xwf", "Xwr", "Zh")
    fit = fit_vehicle(model, CAMERA, exact_prior(d))
    assert fit.ok, fit.reason
    np.testing.assert_allclose(fit.p[3:], [*wheel_x, hub_z], atol=1e-5)
    assert geodesic_angle(fit.R_cam_vehicle, R) < 1e-6


def test_plate_width_fixes_the_scale(rng):
    d, R, t = scene(rng)
    parts = keypoint_parts(d, R, t)
    at = np.array([-0.47, 0.0, 0.4])
    ends = project(np.array([[at[0] * d[0], 0.22, at[2] * d[2]], [at[0] * d[0], -0.22, at[2] * d[2]]]), R, t)
    parts.append(Part("plate", "rear", ends, "plate", (0.44, 0.001), at, np.full(3, 0.02)))
    # A prior 10 % too small, the truth within about one of its sigmas: alone it puts the car about 10 % too
    # close. The plate's clicks pull the scale back; how far depends on the plate's size in pixels (about 30 px
    # here) against the prior's weight lambda_px: at the default (10 px^2, clicks worth about 3 px) a little,
    # with exact clicks trusted (lambda_px = 1e-4) nearly all the way.
    prior = SizePrior.from_mean_cov("small", 0.9 * d, np.diag([0.45, 0.18, 0.15]) ** 2)
    without = fit_vehicle(build_parts_model(parts[:-1]), CAMERA, prior)
    with_plate = fit_vehicle(build_parts_model(parts), CAMERA, prior)
    trusted = fit_vehicle(build_parts_model(parts), CAMERA, prior, SolverOptions(lambda_px=1e-4))
    assert without.ok and with_plate.ok and trusted.ok
    error = lambda fit: abs(np.linalg.norm(fit.t_cam_vehicle) / np.linalg.norm(t) - 1.0)  # noqa: E731
    assert error(without) > 0.05
    assert error(with_plate) < error(without) - 0.002
    assert error(trusted) < 1e-3
    assert with_plate.scale_from == "plate rear"


def test_learned_positions_of_a_synthetic_fleet_come_back():
    rng = np.random.default_rng(0)
    truth = {"lamp": np.array([-0.45, 0.38, 0.62]), "handle": np.array([0.05, 0.47, 0.56])}
    spread = 0.01
    samples = []
    for v in range(200):
        d = np.array([4.6, 1.8, 1.5]) * rng.uniform(0.9, 1.1, 3)
        R = R_cam_vehicle_from_ypr(rng.uniform(-np.pi, np.pi), 0.0, 0.0)
        t = np.array([rng.uniform(-5, 5), 1.6, rng.uniform(10, 40)])
        for name, at in truth.items():
            X = (at + rng.normal(0.0, spread, 3)) * d
            ray = R @ X + t  # an exact click's ray (camera frame), any length
            samples.append(KeypointSample("Car", name, str(v), ray / ray[2], R, t, d))
    learned = learn_positions(samples)["Car"]
    for name, at in truth.items():
        # 200 vehicles, 1 % spread per axis, each ray seeing two of three axes: about 0.01 / sqrt(130) ~ 0.001
        # per axis; 0.004 is a 4-sigma bound
        np.testing.assert_allclose(learned[name].at, at, atol=0.01)
        assert learned[name].n == 200
        assert np.all(learned[name].spread < 3 * spread) and np.all(learned[name].spread > 0.3 * spread)


def test_mirror_names_swap_left_and_right_as_whole_words():
    assert swapped_sides("top_left_c_left_front_car_light") == "top_right_c_right_front_car_light"
    assert swapped_sides("top_right_c_front_glass") == "top_left_c_front_glass"
    assert swapped_sides("lamp-rear-left") == "lamp-rear-right"
    assert swapped_sides("Left mirror") == "Right mirror"
    assert swapped_sides("LEFT_DOOR") == "RIGHT_DOOR"
    assert swapped_sides("leftover_badge") == "leftover_badge"  # not a whole word: no partner
    assert swapped_sides("upright_post") == "upright_post"
    assert swapped_sides("roof") == "roof"


def test_mirror_pairs_put_each_pair_at_its_mean_mirrored():
    """``learn-parts --mirror-pairs``: a left lamp clicked 2 % of the length farther forward than the right one ends up
    1 % forward, its partner the same mirrored; spreads, counts and faces stay each one's own; a keypoint without a
    partner, or named without a side, is left as it is."""
    left = LearnedPosition(np.array([-0.43, 0.38, 0.62]), np.array([0.01, 0.02, 0.03]), 60, ("rear", "left"), 0.8)
    right = LearnedPosition(np.array([-0.45, -0.36, 0.60]), np.array([0.02, 0.02, 0.02]), 40, ("rear", "right"), 0.6)
    badge = LearnedPosition(np.array([-0.5, 0.01, 0.5]), np.array([0.01, 0.01, 0.01]), 30)
    door = LearnedPosition(np.array([0.1, 0.5, 0.4]), np.array([0.05, 0.01, 0.05]), 20)
    out = mirrored_positions({"lamp_rear_left": left, "lamp_rear_right": right, "badge": badge, "door_left": door})
    np.testing.assert_allclose(out["lamp_rear_left"].at, [-0.44, 0.37, 0.61], rtol=0, atol=1e-15)
    np.testing.assert_allclose(out["lamp_rear_right"].at, [-0.44, -0.37, 0.61], rtol=0, atol=1e-15)
    assert out["lamp_rear_left"].spread is left.spread and out["lamp_rear_right"].n == 40
    assert out["lamp_rear_right"].seen_from == ("rear", "right") and out["lamp_rear_left"].clicked_share == 0.8
    assert out["badge"] is badge and out["door_left"] is door


def test_the_faces_a_keypoint_is_seen_from_are_learned_from_where_it_was_labelled():
    """A fleet seen from every side by a camera below the roof (1.2 m; the cars are 1.5 m tall). People label a
    rear window's top corner when the rear is turned to the camera, and a headlight's outer corner when the front
    or the left is: those are the faces learned, although the window's position sits near the top face only. The
    lamp is clicked on every vehicle it could be seen on, the window on every other one (share 1/2); a badge on
    every vehicle, so that each one counts (a vehicle without any labelled keypoint is not in the data)."""
    rng = np.random.default_rng(2)
    window, lamp = np.array([-0.3, 0.3, 0.92]), np.array([0.45, 0.38, 0.55])
    samples = []
    for v in range(300):
        d = np.array([4.6, 1.8, 1.5])
        R = R_cam_vehicle_from_ypr(rng.uniform(-np.pi, np.pi), 0.0, 0.0)
        t = np.array([rng.uniform(-5, 5), 1.2, rng.uniform(10, 40)])
        facing = faces_toward(KeypointSample("Car", "-", str(v), np.zeros(3), R, t, d))
        assert "top" not in facing
        for name, at, seen in (("window", window, {"rear"}), ("lamp", lamp, {"front", "left"}),
                               ("badge", np.array([0.0, 0.0, 0.95]), set(facing))):
            if (facing & seen or name == "badge") and (name != "window" or v % 2 == 0):
                samples.append(KeypointSample("Car", name, str(v), R @ (at * d) + t, R, t, d))
    learned = learn_positions(samples)["Car"]
    assert learned["window"].seen_from == ("rear",)
    assert learned["lamp"].seen_from == ("front", "left")
    # Of the vehicles with the rear turned to the camera, the window was labelled on the even ones.
    assert learned["lamp"].clicked_share == 1.0
    rear_seen = {s.vehicle for s in samples if "rear" in faces_toward(s)}
    assert learned["window"].clicked_share == pytest.approx(
        sum(int(v) % 2 == 0 for v in rear_seen) / len(rear_seen), abs=1e-12)
    assert abs(learned["window"].clicked_share - 0.5) < 0.15  # 141 vehicles show their rear: 3.6 sigmas


def test_seen_from_takes_the_fewest_faces_on_the_keypoints_half():
    """Greedy: the face turned to the camera on most vehicles first, until 95 % are covered. A face on the other
    half of the vehicle is never taken: 10 % of ground truths turned around do not make a rear lamp seen from
    the front."""
    rear_lamp = np.array([-0.45, 0.38, 0.62])
    assert halves(rear_lamp) == ("rear", "left", "top")
    facing = [frozenset({"rear"})] * 80 + [frozenset({"rear", "left"})] * 6 + [frozenset({"left"})] * 4 \
        + [frozenset({"front"})] * 10
    assert seen_from(facing) == ("front", "rear")  # 90 % by the rear, then the front covers the 10 %
    # On its half: the rear, then the left for the 4 seen from the left only; the 10 turned around stay uncovered.
    assert seen_from(facing, halves(rear_lamp)) == ("rear", "left")
    assert seen_from([frozenset({"rear"})] * 90 + [frozenset({"front"})] * 10, halves(rear_lamp)) == ("rear",)
    assert seen_from([frozenset({"rear"})] * 96 + [frozenset({"left"})] * 4, halves(rear_lamp)) == ("rear",)
    assert seen_from([]) == ()


def test_second_pass_leaves_out_a_contradicting_pose():
    rng = np.random.default_rng(1)
    at = np.array([-0.45, 0.38, 0.62])
    samples = []
    for v in range(30):
        d = np.array([4.6, 1.8, 1.5])
        R = R_cam_vehicle_from_ypr(rng.uniform(-np.pi, np.pi), 0.0, 0.0)
        t = np.array([rng.uniform(-5, 5), 1.6, rng.uniform(10, 40)])
        ray = R @ (at * d) + t
        R_gt = R @ R_cam_vehicle_from_ypr(np.pi, 0.0, 0.0) @ np.linalg.inv(R_cam_vehicle_from_ypr(0, 0, 0)) \
            if v == 0 else R  # vehicle 0: its ground truth turned around
        samples.append(KeypointSample("Car", "lamp", str(v), ray, R_gt, t, d))
    one_pass = learn_positions(samples)["Car"]["lamp"].at
    two_pass = learn_positions(samples, max_offset=0.5)["Car"]["lamp"].at
    assert np.abs(one_pass - at).max() > 0.01
    np.testing.assert_allclose(two_pass, at, atol=1e-9)  # the 29 exact vehicles alone: algebra tier


def test_ground_truth_that_hides_its_own_clicks_is_counted():
    """A rear lamp labelled as seen on a car whose ground truth shows the camera its front is hidden there; on the
    same car seen from behind it is not. Keypoints without learned faces, or not learned, are not counted."""
    d, t = np.array([4.6, 1.8, 1.5]), np.array([1.0, 1.6, 25.0])
    lamp, mirror = np.array([-0.45, 0.38, 0.62]), np.array([0.2, 0.55, 0.7])
    learned = {"Car": {"lamp": LearnedPosition(lamp, np.full(3, 0.02), 50, seen_from=("rear",)),
                       "mirror": LearnedPosition(mirror, np.full(3, 0.02), 50)}}
    R_away = R_cam_vehicle_from_ypr(-np.pi / 2, 0.0, 0.0)  # its front away from the camera
    R_toward = R_away @ R_cam_vehicle_from_ypr(np.pi, 0.0, 0.0)  # turned end for end about its up axis
    samples = []
    for vehicle, R in (("away", R_away), ("toward", R_toward)):
        for name, at in (("lamp", lamp), ("mirror", mirror), ("unknown", lamp)):
            samples.append(KeypointSample("Car", name, vehicle, R @ (at * d) + t, R, t, d))
    assert "rear" in faces_toward(samples[0]) and "rear" not in faces_toward(samples[3])  # the scene is as meant
    assert hidden_by_ground_truth(samples, learned) == {"away": (1, 0), "toward": (1, 1)}

def test_learning_a_mapping_reports_the_poses_it_left_out_and_those_that_hide_their_clicks():
    """30 cars driving away, three rear keypoints labelled on each; car 0's ground truth is turned end for end, so
    its keypoints lie off their rays (left out by the second pass) and on its far side (its pose hides them)."""
    rng = np.random.default_rng(2)
    names = {"lamp-l": (-0.48, 0.35, 0.6), "lamp-r": (-0.48, -0.35, 0.6), "badge": (-0.5, 0.0, 0.45)}
    base = {"toosicubix_mapping": 1, "name": "t", "keypoints": list(names), "unused": [],
            "parts": [{"kind": "keypoint", "keypoint": n, "position": {"at": [0, 0, 0.5], "spread": [0.1] * 3}}
                      for n in names]}
    samples = []
    for v in range(30):
        d = np.array([4.6, 1.8, 1.5])
        R = R_cam_vehicle_from_ypr(-np.pi / 2 + rng.uniform(-0.8, 0.8), 0.0, 0.0)  # its front away from the camera
        t = np.array([rng.uniform(-4, 4), 1.6, rng.uniform(10, 40)])
        R_gt = R @ R_cam_vehicle_from_ypr(np.pi, 0.0, 0.0) if v == 0 else R
        for name, at in names.items():
            samples.append(KeypointSample("Car", name, str(v), R @ (np.array(at) * d) + t, R_gt, t, d))
    document, report = learned_mapping(base, samples, 5, "test", max_offset=0.5)
    assert report.vehicles == 30 and report.left_out == {"0"} and report.hiding == {"0": (3, 3)}
    lamp = next(p for p in document["parts"] if p["keypoint"] == "lamp-l")["position"]
    np.testing.assert_allclose(lamp["at"], names["lamp-l"], atol=1e-4)  # the 29 exact cars: rounded to 4 places
    assert lamp["seen_from"] == ["rear"]

@pytest.fixture
def rng():
    return np.random.default_rng(0)
