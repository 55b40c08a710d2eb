"""The upright term of a vehicle of keypoints weighed against the click noise (``--upright-weight clicks``, rule 23).

Scene: twelve keypoints on the rear and the left side of a car 15-25 m away (:func:`scene`), the road's normal
given exactly (1e-6 degrees) or estimated from a batch (``from_batch``), vehicles leaning 2 degrees about it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tests.parts.test_real_click_kinds import exact_prior, keypoint_parts, scene
from tests.scenes import CAMERA
from tests.solver.test_ground import _numeric_jacobian
from tests.solver.test_robust import TWELVE
from toosicubix.geometry import R_cam_vehicle_from_ypr, geodesic_angle
from toosicubix.model import GroundPlane
from toosicubix.parts.linear import build_parts_model
from toosicubix.solver.fit import SolverOptions, fit_vehicle
from toosicubix.solver.problem import Problem
from toosicubix.solver.refine import residuals_and_jacobian
from toosicubix.solver.robust import soft_weights, with_weights

LEVEL = np.array([0.0, -1.0, 0.0])
UPRIGHT = np.deg2rad(2.0)


def ground(from_batch: bool, normal_sigma_deg: float = 1e-6) -> GroundPlane:
    return GroundPlane(normal=LEVEL, normal_sigma=np.deg2rad(normal_sigma_deg), camera_height=None,
                       camera_height_sigma=0.1, upright_sigma=UPRIGHT, from_batch=from_batch)


def rolled(R: np.ndarray, roll_deg: float) -> np.ndarray:
    """``R`` turned by ``roll_deg`` about the vehicle's own forward axis: its up axis leaves the normal."""
    return R @ R_cam_vehicle_from_ypr(0.0, 0.0, np.deg2rad(roll_deg)) @ R_cam_vehicle_from_ypr(0.0).T


def test_upright_rows_weigh_against_the_click_noise_with_the_stated_sigma(rng):
    d, R, t = scene(rng)
    parts = build_parts_model(keypoint_parts(d, R, t, TWELVE))
    for from_batch, sigma in ((False, np.hypot(UPRIGHT, np.deg2rad(3.0))), (True, UPRIGHT)):
        plain = Problem.build(parts, CAMERA, exact_prior(d), 0.1, 10.0, ground(from_batch, 3.0))
        problem = plain.upright_against_clicks(0.8)
        # about an estimated normal the lean alone (it was measured about such an estimate), else with the
        # normal's own sigma; algebra tier
        assert problem.upright_sigma == pytest.approx(sigma, rel=1e-12)
        R_off, p = rolled(R, 1.5), d * 1.02
        r, _ = residuals_and_jacobian(problem, R_off, t, p)
        n, m = 2 * parts.n_clicks, len(problem.b)
        np.testing.assert_allclose(r[n + m:n + m + 3], 0.8 / sigma * (R_off[:, 2] - LEVEL), rtol=1e-12)
        np.testing.assert_allclose(r[:n + m], residuals_and_jacobian(plain, R_off, t, p)[0][:n + m], rtol=1e-12)
        assert problem.cost_px(R_off, t, p) == pytest.approx(float(r @ r), rel=1e-12)  # the cost is the rows'
        np.testing.assert_allclose(problem.cue_row_lambdas, [10.0] * m + [0.64] * 3, rtol=1e-12)
    # Without a ground there is nothing to weigh.
    bare = Problem.build(parts, CAMERA, exact_prior(d), 0.1, 10.0)
    assert bare.upright_against_clicks(0.8) is bare


@pytest.mark.parametrize("profile", [False, True])
def test_the_upright_rows_jacobian_with_their_own_weight(rng, profile):
    d, R, t = scene(rng)
    parts = build_parts_model(keypoint_parts(d, R, t, TWELVE))
    problem = Problem.build(parts, CAMERA, exact_prior(d), 0.1, 10.0, ground(True)).upright_against_clicks(0.7)
    R_off = rolled(R, 2.0) @ R_cam_vehicle_from_ypr(0.03, 0.01, 0.0) @ R_cam_vehicle_from_ypr(0.0).T
    p = d * 0.98
    J, numeric = _numeric_jacobian(problem, R_off, t * 1.03, p, parts.A.mean(axis=0) @ p, profile)
    # Central differences err by O(h^2) ~ 1e-9 relative to entries up to ~1e3 px per unit.
    np.testing.assert_allclose(J, numeric, rtol=1e-6, atol=1e-5)


def test_with_lambda_the_click_noise_variance_both_weights_are_one_fit(rng):
    """``lambda_px = click_sigma^2`` weighs the upright term as the clicks do under either setting: the same fit and
    the same sigmas (the per-row covariance is the one-weight covariance then)."""
    d, R, t = scene(rng)
    R = rolled(R, 2.5)
    clicks = keypoint_parts(d, R, t, TWELVE)
    noisy = [replace(c, uv=c.uv + rng.normal(0.0, 1.0, c.uv.shape)) for c in clicks]
    model = build_parts_model(noisy)
    g = ground(False, 1.0)
    fits = [fit_vehicle(model, CAMERA, exact_prior(d), SolverOptions(lambda_px=1.21, click_sigma=1.1,
                                                                    upright_weight=w), g)
            for w in ("lambda", "clicks")]
    assert all(f.ok for f in fits)
    # noiseless-solve tier: the two refinements minimise the same cost from the same start
    assert geodesic_angle(fits[0].R_cam_vehicle, fits[1].R_cam_vehicle) < 1e-6
    np.testing.assert_allclose(fits[0].t_cam_vehicle, fits[1].t_cam_vehicle, atol=1e-6)
    a, b = fits[0].uncertainty, fits[1].uncertainty
    np.testing.assert_allclose([a.yaw_deg, a.pitch_deg, a.roll_deg, a.depth_m],
                               [b.yaw_deg, b.pitch_deg, b.roll_deg, b.depth_m], rtol=1e-6)


def test_clicks_that_show_a_lean_keep_more_of_it(rng):
    """A car leaning 3 degrees on its road, twelve noise-free keypoints, click noise 1 px: with lambda_p 10 the
    upright term weighs ten times what the clicks' noise says and pulls the car back toward upright; weighed against
    the click noise it keeps most of the lean."""
    d, R, t = scene(rng)
    R_true = rolled(R, 3.0)
    model = build_parts_model(keypoint_parts(d, R_true, t, TWELVE))
    g = ground(True)
    errors, sigmas = {}, {}
    for w in ("lambda", "clicks"):
        fit = fit_vehicle(model, CAMERA, exact_prior(d), SolverOptions(click_sigma=1.0, upright_weight=w), g)
        assert fit.ok, fit.reason
        errors[w] = np.rad2deg(geodesic_angle(fit.R_cam_vehicle, R_true))
        sigmas[w] = fit.uncertainty.roll_deg
    # Linear-Gaussian shrinkage: the fit keeps I / (I + w) of the lean for the clicks' information I and the prior's
    # weight w; w falls tenfold, so the miss falls by more than half whenever the clicks see the lean at all.
    assert errors["clicks"] < 0.5 * errors["lambda"]
    assert errors["lambda"] > 0.3  # the lambda weighting does pull a 3-degree lean (else the test shows nothing)
    # Both sigmas are the estimator's own spread for a 2-degree lean (the sandwich): weighed as stated, the estimate
    # is the posterior's, the least spread of any weighing; lambda_p 10 makes of the prior 0.6 degrees against 1 px and
    # pulls every car by the lean it does not know, which widens its roll sigma.
    assert sigmas["clicks"] < sigmas["lambda"]


def test_soft_weighted_rows_have_the_click_noise():
    """Why the click noise is the right unit: a keypoint row weighed by the soft term has the click noise alone
    (its spread is in the weight), so ``click_sigma^2 / sigma_up^2`` is the prior's weight in that cost."""
    rng = np.random.default_rng(1)
    d, R, t = scene(rng)
    problem = Problem.build(build_parts_model(keypoint_parts(d, R, t, TWELVE)), CAMERA, exact_prior(d), 0.1, 10.0)
    depth = float(np.linalg.norm(t))
    w = soft_weights(problem, depth, 0.9)
    spread_px = np.sqrt((0.9 / w) ** 2 - 0.9**2)  # what the weight says each click's spread is, pixels
    noise = rng.normal(0.0, 1.0, (20000, len(w))) * np.hypot(0.9, spread_px)
    np.testing.assert_allclose(np.std(noise * w, axis=0), 0.9, rtol=0.03)  # 20,000 draws: 0.5 % sd, 3 % is 6 sd
    assert with_weights(problem, w).upright_noise_px is None  # weights alone leave the upright term as it was
