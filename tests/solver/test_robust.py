"""Per-click weights: the keypoints' soft term and the Cauchy loss that keeps a fit with a mislabelled click."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from tests.parts.test_real_click_kinds import REAR_LEFT, exact_prior, keypoint_parts, scene
from tests.scenes import CAMERA
from toosicubix.geometry import geodesic_angle
from toosicubix.parts.linear import build_parts_model
from toosicubix.solver.fit import SolverOptions, fit_vehicle
from toosicubix.solver.problem import Problem
from toosicubix.solver.refine import residuals_and_jacobian
from toosicubix.solver.robust import CauchyLoss, soft_weights, with_weights

TWELVE = {**REAR_LEFT, "lamp-low-left": (-0.46, 0.36, 0.5), "lamp-low-right": (-0.46, -0.36, 0.5),
          "sill-rear": (-0.3, 0.49, 0.15)}


def test_weights_scale_the_pixel_rows_and_their_jacobian():
    rng = np.random.default_rng(0)
    d, R, t = scene(rng)
    parts = build_parts_model(keypoint_parts(d, R, t))
    problem = Problem.build(parts, CAMERA, exact_prior(d), 0.1, 10.0)
    w = rng.uniform(0.1, 1.0, parts.n_clicks)
    p = d + 0.1
    r0, J0 = residuals_and_jacobian(problem, R, t + 0.05, p)
    r1, J1 = residuals_and_jacobian(with_weights(problem, w), R, t + 0.05, p)
    rows = np.repeat(w, 2)
    n = 2 * parts.n_clicks
    np.testing.assert_allclose(r1[:n], rows * r0[:n], rtol=1e-12)  # algebra tier
    np.testing.assert_allclose(J1[:n], rows[:, None] * J0[:n], rtol=1e-12)
    np.testing.assert_allclose(r1[n:], r0[n:], rtol=1e-12)  # the cue rows are not weighted


def test_soft_weights_trust_tight_keypoints_more():
    rng = np.random.default_rng(0)
    d, R, t = scene(rng)
    parts = keypoint_parts(d, R, t)
    parts[0] = replace(parts[0], spread=np.array([0.2, 0.2, 0.2]))
    problem = Problem.build(build_parts_model(parts), CAMERA, exact_prior(d), 0.1, 10.0)
    w = soft_weights(problem, 20.0, 1.5)
    # spread 0.02 of (4.6, 1.8, 1.5) m is 6 cm RMS, 2 px at 20 m: weight 0.6; spread 0.2 is 20 px: 0.07
    assert 0.5 < w[1] < 0.7 and w[0] < 0.1


def test_cauchy_loss_and_its_derivative():
    loss = CauchyLoss(3.0)
    s = np.array([0.0, 1.0, 9.0, 100.0])
    h = 1e-6
    np.testing.assert_allclose(loss.weight(s), (loss.loss(s + h) - loss.loss(s - h)) / (2 * h), rtol=1e-6)
    np.testing.assert_allclose(loss.loss(np.array([0.0])), 0.0)


def test_robust_loss_keeps_a_fit_with_one_click_swapped_left_for_right():
    rng = np.random.default_rng(3)
    errors = {"none": [], "cauchy": []}
    for _ in range(5):
        d, R, t = scene(rng)
        parts = keypoint_parts(d, R, t, TWELVE)
        assert len(parts) == 12
        parts = [replace(part, uv=part.uv + rng.normal(0.0, 1.0, part.uv.shape)) for part in parts]  # 1 px noise
        left = next(k for k, part in enumerate(parts) if part.name == "lamp-rear-left")
        # The annotator put the left lamp's label on the right lamp (a left-for-right mistake).
        wrong = next(part for part in parts if part.name == "lamp-rear-right").uv.copy()
        parts[left] = replace(parts[left], uv=wrong)
        model = build_parts_model(parts)
        for loss in errors:
            fit = fit_vehicle(model, CAMERA, exact_prior(d), SolverOptions(robust_loss=loss))
            assert fit.ok, fit.reason
            errors[loss].append(np.rad2deg(geodesic_angle(fit.R_cam_vehicle, R)))
            if loss == "cauchy":
                assert "keypoint-lamp-rear-left" in fit.downweighted
                assert len(fit.downweighted) <= 2
    # 1 px noise on 11 good clicks 12-25 m away: within 2 degrees; the swapped click alone pulls the plain
    # least-squares fit further off.
    assert max(errors["cauchy"]) < 2.0
    assert np.median(errors["cauchy"]) < np.median(errors["none"])


def test_symmetry_pairs_alone_leave_the_distance_undetermined_and_say_so():
    """Issue 14's noise-free configuration: two rear light pairs, the rear badge and a roof pair. Every pair
    brings its own Y and Z, so no click ties the clicked shape to the dimensions the prior knows: the distance
    is free. The 3D cost's trivial minimum (every point at the camera centre) used to hide that behind "no
    start led to a cuboid in front of the camera"; now the typical-position starts reach the refinement, which
    names what is undetermined."""
    from toosicubix.model import Part

    rng = np.random.default_rng(0)
    d, R, t = scene(rng)

    def uv(*points):
        from tests.parts.test_real_click_kinds import project
        return project(np.array(points), R, t)

    x = -0.5 * d[0]
    parts = [Part("symmetry", "rear", uv([x, 0.7, 0.9], [x, -0.7, 0.9]), "a"),
             Part("symmetry", "rear", uv([x, 0.6, 0.7], [x, -0.6, 0.7]), "b"),
             Part("point", "rear-center", uv([x, 0.0, 0.6]), "c"),
             Part("symmetry", "roof", uv([-1.0, 0.6, d[2]], [-1.0, -0.6, d[2]]), "d")]
    fit = fit_vehicle(build_parts_model(parts), CAMERA, exact_prior(d))
    assert not fit.ok
    assert "no start led to a cuboid in front of the camera" not in fit.detail
    assert "do not determine" in fit.detail
    assert fit.reason.startswith("seen only from behind, the clicks do not fix ")
