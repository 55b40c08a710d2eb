"""The heading prior of a road whose traffic heads one way (``fit --heading-prior estimate``, issue 36): its row, its
Jacobian, its cost, its estimate from a batch's headings, and the sigma it reports under its mixture.

Scene: twelve keypoints on the rear and the left side of a car 12-25 m away (:func:`tests.parts.test_real_click_kinds
.scene`), on a level road given exactly, the traffic heading along the camera's axis.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tests.parts.test_real_click_kinds import exact_prior, keypoint_parts, scene
from tests.scenes import CAMERA
from tests.solver.test_ground import _numeric_jacobian
from tests.solver.test_robust import TWELVE
from toosicubix.geometry import R_cam_vehicle_from_ypr
from toosicubix.model import GroundPlane, HeadingPrior
from toosicubix.parts.linear import build_parts_model
from toosicubix.solver import heading
from toosicubix.solver.fit import SolverOptions, fit_vehicle
from toosicubix.solver.problem import Problem
from toosicubix.solver.refine import residuals_and_jacobian

LEVEL = np.array([0.0, -1.0, 0.0])
PRIOR = HeadingPrior(direction=math.radians(2.0), sigma=math.radians(5.0), others=0.2, noise_px=0.8)


def road(prior: HeadingPrior | None = PRIOR) -> GroundPlane:
    return GroundPlane(normal=LEVEL, normal_sigma=1e-8, camera_height=None, camera_height_sigma=0.1,
                       upright_sigma=math.radians(2.0), from_batch=True, heading=prior)


def heading_of(theta_deg: float) -> np.ndarray:
    """A vehicle standing on the level road, its forward axis ``theta_deg`` from the camera's axis toward
    ``l0 = up x f0`` (the heading the prior measures)."""
    f0, l0 = heading.road_axes(LEVEL)
    a = math.radians(theta_deg)
    forward = math.cos(a) * f0 + math.sin(a) * l0
    return np.column_stack([forward, np.cross(LEVEL, forward), LEVEL])


def test_headings_are_measured_on_the_road_from_the_camera_axis():
    for theta in (-170.0, -30.0, 0.0, 12.5, 90.0, 179.0):
        # algebra tier: an angle read back through atan2
        assert math.degrees(float(heading.headings(heading_of(theta), LEVEL))) == pytest.approx(theta, abs=1e-9)
    # Positive toward l0 = up x f0: on a level road (up = -y, f0 = z) that is -x, the camera's left. KITTI's yaw -80
    # deg heads 10 deg to the right of the camera's axis (forward (cos 80, 0, sin 80) in the camera frame).
    R = R_cam_vehicle_from_ypr(math.radians(-80.0), 0.0, 0.0)
    assert math.degrees(float(heading.headings(R, LEVEL))) == pytest.approx(-10.0, abs=1e-9)


def test_the_row_is_zero_on_the_axis_either_way_and_bounded_off_it():
    on = [heading_of(2.0), heading_of(182.0)]
    r, _ = heading.rows(PRIOR, np.array(on), LEVEL, False)
    np.testing.assert_allclose(r, 0.0, atol=1e-12)
    # Near the axis the prior is the peak's Gaussian with (1 - others) of its weight: r ~ sqrt(0.8) d / sigma.
    r, _ = heading.rows(PRIOR, heading_of(2.1)[None], LEVEL, False)
    assert r[0] == pytest.approx(math.sqrt(0.8) * 0.1 / 5.0, rel=1e-3)
    # A heading and its reverse alike (the clicks say which end is the front); sign follows the deviation.
    a, _ = heading.rows(PRIOR, np.array([heading_of(-10.0), heading_of(170.0), heading_of(14.0)]), LEVEL, False)
    assert a[0] == pytest.approx(a[1], rel=1e-12) and a[0] < 0 < a[2]
    # Crossing traffic pays at most -2 ln(others), however far it heads from the axis.
    far, _ = heading.rows(PRIOR, np.array([heading_of(60.0), heading_of(92.0)]), LEVEL, False)
    assert np.all(far**2 <= -2.0 * math.log(PRIOR.others) + 1e-12)
    assert far[1] ** 2 == pytest.approx(-2.0 * math.log(PRIOR.others), rel=1e-6)


@pytest.mark.parametrize("theta", [2.0, 2.0 + 1e-9, -1.0, 9.0, 35.0, 170.0])
def test_the_rows_jacobian_matches_central_differences(theta):
    R = heading_of(theta) @ R_cam_vehicle_from_ypr(0.0, 0.02, -0.03) @ R_cam_vehicle_from_ypr(0.0).T  # leaning a
    _, J = heading.rows(PRIOR, R[None], LEVEL, True)  # little: the gradient's other columns are not zero then
    h = 1e-6
    numeric = np.zeros(3)
    for k in range(3):
        step = np.zeros(3)
        step[k] = h
        plus, _ = heading.rows(PRIOR, (R @ _exp(step))[None], LEVEL, False)
        minus, _ = heading.rows(PRIOR, (R @ _exp(-step))[None], LEVEL, False)
        numeric[k] = (plus[0] - minus[0]) / (2 * h)
    # central differences err by O(h^2) against rows of order 1/sigma = 11 per radian
    np.testing.assert_allclose(J[0], numeric, rtol=1e-6, atol=1e-8)


def _exp(v: np.ndarray) -> np.ndarray:
    from toosicubix.geometry import so3_exp

    return so3_exp(v)


def test_the_problems_heading_row_weighs_against_its_noise_and_is_in_the_cost(rng):
    d, R, t = scene(rng)
    parts = build_parts_model(keypoint_parts(d, R, t, TWELVE))
    with_prior = Problem.build(parts, CAMERA, exact_prior(d), 0.1, 10.0, road())
    plain = Problem.build(parts, CAMERA, exact_prior(d), 0.1, 10.0, road(None))
    assert (with_prior.n_heading_rows, plain.n_heading_rows) == (1, 0)
    R_off, p = heading_of(float(np.degrees(heading.headings(R, LEVEL))) + 3.0), d * 1.02
    r, _ = residuals_and_jacobian(with_prior, R_off, t, p)
    r0, _ = residuals_and_jacobian(plain, R_off, t, p)
    n = 2 * parts.n_clicks + len(plain.b) + 3  # pixels, scale rows, upright rows: then the heading row
    np.testing.assert_allclose(r[:n], r0[:n], rtol=1e-12)
    row, _ = heading.rows(PRIOR, R_off[None], LEVEL, False)
    assert r[n] == pytest.approx(0.8 * row[0], rel=1e-12) and len(r) == len(r0) + 1
    assert with_prior.cost_px(R_off, t, p) == pytest.approx(float(r @ r), rel=1e-12)  # the cost is the rows'
    np.testing.assert_allclose(with_prior.cue_row_lambdas, [10.0] * (len(plain.b) + 3) + [0.64], rtol=1e-12)
    assert plain.cue_rows_uniform and not with_prior.cue_rows_uniform


@pytest.mark.parametrize("profile", [False, True])
def test_the_heading_rows_jacobian_in_the_problem(rng, profile):
    d, R, t = scene(rng)
    parts = build_parts_model(keypoint_parts(d, R, t, TWELVE))
    problem = Problem.build(parts, CAMERA, exact_prior(d), 0.1, 10.0, road())
    R_off = heading_of(float(np.degrees(heading.headings(R, LEVEL))) + 4.0) @ R_cam_vehicle_from_ypr(
        0.0, 0.01, 0.02) @ R_cam_vehicle_from_ypr(0.0).T
    p = d * 0.98
    J, numeric = _numeric_jacobian(problem, R_off, t * 1.03, p, parts.A.mean(axis=0) @ p, profile)
    np.testing.assert_allclose(J, numeric, rtol=1e-6, atol=1e-5)  # as the other cue rows' test


def test_a_loose_heading_turns_toward_the_traffic_and_a_determined_one_stays(rng):
    """Four keypoints on a car's rear leave its heading loose (sigma of degrees); the traffic's prior turns it
    toward the axis. Twelve keypoints on its rear and side fix it; the prior then barely moves it."""
    d = np.array([4.6, 1.8, 1.5])
    R_true = heading_of(6.0)  # six degrees off the traffic's axis (2 deg): within the peak
    t = np.array([0.5, 1.6, 30.0])
    rear = {k: v for k, v in TWELVE.items() if v[0] < -0.4}
    assert 3 <= len(rear) < len(TWELVE)
    options = SolverOptions(click_sigma=1.0)
    moved = {}
    for names in (rear, TWELVE):
        clicks = keypoint_parts(d, R_true, t, names)
        noisy = [replace(c, uv=c.uv + rng.normal(0.0, 1.0, c.uv.shape)) for c in clicks]
        model = build_parts_model(noisy)
        fits = [fit_vehicle(model, CAMERA, exact_prior(d), options, road(prior)) for prior in (None, PRIOR)]
        assert all(f.ok for f in fits), [f.reason for f in fits]
        before, after = (float(np.degrees(heading.headings(f.R_cam_vehicle, LEVEL))) for f in fits)
        sigma_before, sigma_after = (f.uncertainty.yaw_deg for f in fits)
        moved[len(names)] = (before, after, sigma_before, sigma_after)
    before, after, s0, s1 = moved[len(rear)]
    assert abs(heading.axial(np.radians(after - 2.0))) < abs(heading.axial(np.radians(before - 2.0)))
    assert s1 < s0  # the prior adds what the clicks lack
    before, after, s0, s1 = moved[len(TWELVE)]
    assert abs(after - before) < 0.5 * s0  # determined by the clicks: moved by well within its own sigma


def test_the_estimate_recovers_a_batchs_traffic():
    rng = np.random.default_rng(3)
    along = rng.normal(math.radians(3.0), math.radians(4.0), 400) + np.pi * rng.integers(0, 2, 400)  # both ways
    elsewhere = rng.uniform(-np.pi, np.pi, 100)
    found = heading.estimate(np.concatenate([along, elsewhere]), 0.9)
    # 400 draws of the peak: the mean within 4 / sqrt(400) = 0.2 deg (sd), the spread within about 4 %; the uniform
    # share 0.2 within its binomial sd of 0.018 (three of each)
    assert math.degrees(found.direction) == pytest.approx(3.0, abs=0.6)
    assert math.degrees(found.sigma) == pytest.approx(4.0, rel=0.12)
    assert found.others == pytest.approx(0.2, abs=0.055)
    assert (found.noise_px, found.vehicles) == (0.9, 500)


def test_the_mixture_widens_a_heading_the_clicks_put_off_the_axis():
    v_with = math.radians(2.0) ** 2
    # Clicks that leave the heading loose, the fit near the axis: the peak almost surely holds, and the small chance
    # that the vehicle heads elsewhere carries the clicks' own 12 degrees: wider than the peak's, far narrower than
    # the clicks' alone.
    rho, _, near = heading.mixture_variance(PRIOR, math.radians(0.5), v_with, math.radians(12.0) ** 2)
    assert rho > 0.9 and v_with < near < 0.1 * math.radians(12.0) ** 2
    # Clicks that put it well off the axis (the fit sits there too): the uniform share holds, the clicks' variance.
    rho, _, far = heading.mixture_variance(PRIOR, math.radians(40.0), v_with, math.radians(3.0) ** 2)
    assert rho < 0.01 and far == pytest.approx(math.radians(3.0) ** 2, rel=0.05)
    # Clicks that determine the heading far better than the prior: nothing to mix.
    _, _, tight = heading.mixture_variance(PRIOR, math.radians(1.0), v_with, v_with * 1.0001)
    assert tight == pytest.approx(v_with, rel=0.01)
