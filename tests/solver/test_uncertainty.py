"""Uncertainty, observability, ambiguity and confidence of a fit (toosicubix.solver.uncertainty)."""

import math

import numpy as np
import pytest

from tests.scenes import CAMERA, VIEW_YAW, _specs, random_scene
from toosicubix.annotations.priors_file import load_priors
from toosicubix.geometry import R_cam_vehicle_from_ypr, wrap_angle, ypr_from_R_cam_vehicle
from toosicubix.model import Part
from toosicubix.parts.linear import build_parts_model
from toosicubix.parts.synthesis import render_parts
from toosicubix.size_priors import SizePrior
from toosicubix.solver.fit import SolverOptions, fit_vehicle
from toosicubix.solver.plausibility import unseen_clicks
from toosicubix.solver.uncertainty import UNDETERMINED_RATIO, Uncertainty, confidence

CAR = load_priors()["Car"]
MEAN = np.array([4.2, 1.75, 1.5])
COV = np.diag([0.4, 0.12, 0.12]) ** 2


@pytest.mark.parametrize("view", ["oblique-front-left", "oblique-rear-right"])
def test_predicted_sigmas_match_a_monte_carlo_spread(view):
    """Vehicles drawn from the size prior, clicks with 1.5 px noise, fitted 400 times with the default weights
    (lambda_p = 10, not the noise variance: the sandwich formula, not a plain inverse Hessian, is needed; the
    plain one predicts about half the spread here). The predicted standard deviations of yaw, pitch, roll,
    depth and the dimensions must match the spread of the errors. A standard deviation from 400 samples is
    off by 3.5 % (1 sigma); the tolerance of 12 % allows 3 of those plus a few % of non-linearity
    (measured: every ratio within 0.94-1.04)."""
    rng = np.random.default_rng(0)
    sigma = 1.5
    prior = SizePrior.from_mean_cov("Car", MEAN, COV)
    options = SolverOptions(click_sigma=sigma, part_sigma=0.0)  # the parts sit exactly where the model says
    R = R_cam_vehicle_from_ypr(VIEW_YAW[view] + 0.2)
    t = np.array([1.5, 1.6, 18.0])
    specs = _specs(view, MEAN, np.random.default_rng(5))
    exact = render_parts(specs, R, t, MEAN, CAMERA, (0.3 * MEAN[0], -0.3 * MEAN[0]))
    u = fit_vehicle(build_parts_model(exact), CAMERA, prior, options).uncertainty
    errors = []
    for _ in range(400):
        d = rng.multivariate_normal(MEAN, COV)
        parts = [Part(p.kind, p.name, p.uv + rng.normal(0.0, sigma, p.uv.shape), p.json_path)
                 for p in render_parts(specs, R, t, d, CAMERA, (0.3 * d[0], -0.3 * d[0]))]
        fit = fit_vehicle(build_parts_model(parts), CAMERA, prior, options)
        assert fit.ok
        ypr_error = np.rad2deg(wrap_angle(np.array(ypr_from_R_cam_vehicle(fit.R_cam_vehicle))
                                          - np.array(ypr_from_R_cam_vehicle(R))))
        errors.append([*ypr_error, (fit.t_cam_vehicle[2] - t[2]) / t[2], *(fit.dimensions - d)])
    spread = np.std(errors, axis=0)
    predicted = np.array([u.yaw_deg, u.pitch_deg, u.roll_deg, u.depth_rel, *u.dimensions])
    np.testing.assert_allclose(spread / predicted, 1.0, atol=0.12)


def _fit(view: str, seed: int, keep=lambda p: p.kind != "direction", options: SolverOptions | None = None):
    scene = random_scene(np.random.default_rng(seed), view)
    parts = tuple(p for p in scene.parts if keep(p))
    # The synthetic parts sit exactly where the cuboid model puts them: no part offsets.
    return scene, parts, fit_vehicle(build_parts_model(parts), CAMERA, CAR, options or SolverOptions(part_sigma=0.0))


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize(("view", "free"), [("rear", "length"), ("front", "length"), ("side", "width")])
def test_observability_names_the_dimension_no_click_fixes(view, free, seed):
    """Parts on the rear (or front) face and the rear wheels say nothing about the length; parts on one side
    nothing about the width. The data Jacobian is blind along that direction, so its variance ratio is about
    the 1e6 by which the cues were scaled down, and the vehicle's sentence names it and what to click."""
    _, _, fit = _fit(view, seed)
    obs = fit.observability
    assert obs.status[free] == "cues only"
    assert obs.ratios[free] > 1e5 > UNDETERMINED_RATIO
    assert f"{free} set by the prior, not by the clicks: " in " ".join(obs.sentences)
    others = [q for q in ("length", "width") if q != free]
    assert all(obs.ratios[q] < UNDETERMINED_RATIO for q in others)


def test_observability_of_a_well_clicked_vehicle_leaves_nothing_to_the_prior():
    """A car 13 m away seen obliquely with both ends, both sides, the roof and the ground clicked: every
    rotation angle and dimension is set by the clicks (only the scale is the prior's, which no click fixes).
    (Further away the same clicks leave yaw and the length-to-width ratio mostly to the prior: the two are
    confounded in a distant oblique view.)"""
    _, _, fit = _fit("oblique-rear-right", 2, keep=lambda p: True)
    assert fit.observability.status == {q: "clicks" for q in ("yaw", "pitch", "roll", "length", "width", "height")}
    assert fit.observability.sentences[-1].startswith("scale set by the size prior (no click fixes it)")


def test_uncertainty_json_has_every_quantity_the_results_promise():
    _, _, fit = _fit("oblique-front-left", 0, keep=lambda p: True)
    sigma = fit.uncertainty.to_json()
    assert set(sigma) == {"yaw_deg", "pitch_deg", "roll_deg", "depth_m", "depth_rel", "dimensions", "position_m",
                          "scale_rel"}
    assert len(sigma["dimensions"]) == 3 and len(sigma["position_m"]) == 2
    assert sigma["depth_rel"] == pytest.approx(sigma["depth_m"] / fit.t_cam_vehicle[2], rel=1e-12)
    assert all(v > 0 for v in (sigma["yaw_deg"], sigma["depth_m"], sigma["scale_rel"], *sigma["dimensions"]))


def test_a_second_plausible_minimum_close_in_cost_makes_the_fit_ambiguous():
    """A rear view with five parts (wheels, lights, badge, roof antenna) admits a second upright answer
    rotated by about 38 degrees that fits the exact clicks nearly as well: flagged, with both costs."""
    scene = random_scene(np.random.default_rng(28), "rear")
    fit = fit_vehicle(build_parts_model(tuple(scene.parts[:5])), CAMERA, CAR, SolverOptions())
    assert fit.ambiguous
    close = [a for a in fit.alternatives if a.close]
    assert close and close[0].implausible is None
    assert close[0].rotation_deg > 15.0
    assert close[0].cost - fit.cost <= SolverOptions().ambiguity_sigmas * SolverOptions().click_sigma ** 2
    assert close[0].to_json()["cost"] == close[0].cost


def test_a_cheaper_answer_with_clicks_on_hidden_faces_is_rejected_not_ambiguous():
    """Same kind of view (seed 15): the lowest cost belongs to an answer that puts the roof antenna on a face
    turned away from the camera. The fit prefers the answer where every clicked part can be seen, records
    the other with its reason, and does not call the fit ambiguous."""
    scene = random_scene(np.random.default_rng(15), "rear")
    parts = tuple(scene.parts[:5])
    fit = fit_vehicle(build_parts_model(parts), CAMERA, CAR, SolverOptions())
    rejected = [a for a in fit.alternatives if a.implausible]
    assert rejected and rejected[0].cost < fit.cost
    assert "faces turned away from the camera: top-center" in rejected[0].implausible
    assert unseen_clicks(build_parts_model(parts).click_labels, fit.R_cam_vehicle, fit.t_cam_vehicle,
                         fit.dimensions) == []
    assert not fit.ambiguous


def test_confidence_is_the_probability_of_both_bands():
    """P(|yaw error| < 10 deg) P(|depth error| < 10 %) for Gaussian errors: at one sigma each band is the
    68.27 % interval; at 5 deg and 5 % the 95.45 % one."""
    def u(yaw, depth):
        return Uncertainty(yaw, 0.0, 0.0, depth * 20.0, depth, np.zeros(3), np.zeros(2), depth, np.zeros((9, 9)))

    assert confidence(u(10.0, 0.10)) == pytest.approx(math.erf(1 / math.sqrt(2)) ** 2, rel=1e-12)
    assert confidence(u(5.0, 0.05)) == pytest.approx(0.954499736 ** 2, rel=1e-8)
    assert confidence(u(1e-3, 1e-5)) == pytest.approx(1.0)
    assert confidence(u(200.0, 0.05)) < 0.05


def test_part_offsets_add_noise_that_shrinks_with_depth_and_spare_the_arrows():
    """A part 0.08 m off its model position, seen from z metres with focal length f, moves by f 0.08 / z
    pixels; it adds in quadrature to the click noise. Arrows (drawn anywhere on the ground) keep the click
    noise alone."""
    from toosicubix.solver.problem import Problem
    from toosicubix.solver.uncertainty import row_sigmas

    scene = random_scene(np.random.default_rng(0), "front")
    problem = Problem.build(scene.model, CAMERA, CAR, 0.1, 10.0)
    sigmas = row_sigmas(problem, scene.R_cam_vehicle, scene.t_cam_vehicle, scene.p_true, 1.5, 0.08)
    z = problem.points_cam(scene.R_cam_vehicle, scene.t_cam_vehicle, scene.p_true)[:, 2]
    arrow = np.array([label.startswith("direction-") for label in scene.model.click_labels])
    assert arrow.any() and not arrow.all()
    expected = np.where(arrow, 1.5, np.sqrt(1.5**2 + (720.0 * 0.08 / z) ** 2))
    np.testing.assert_allclose(sigmas, np.repeat(expected, 2), rtol=1e-12)
    np.testing.assert_array_equal(row_sigmas(problem, scene.R_cam_vehicle, scene.t_cam_vehicle, scene.p_true,
                                             1.5, 0.0), 1.5)


def test_an_undetermined_direction_gives_infinite_sigmas_never_zero_or_negative():
    """A parameter no row sees (a zero Jacobian column) makes H singular: the covariance is infinite, the
    sigmas too, written as null in results.json, and the confidence is 0, never 1."""
    from toosicubix.formats.results import dumps
    from toosicubix.solver.uncertainty import _sandwich, uncertainty_from_covariance

    rng = np.random.default_rng(0)
    J_px = rng.normal(size=(12, 10))
    J_px[:, 7] = 0.0
    J_cue = np.zeros((3, 10))
    cov = _sandwich(J_px, J_cue, 10.0, np.full(12, 1.5))
    u = uncertainty_from_covariance(cov, np.eye(3), np.array([0.0, 1.5, 20.0]))
    assert math.isinf(u.yaw_deg) and math.isinf(u.depth_rel)
    assert u.to_json()["yaw_deg"] is None and u.to_json()["dimensions"] == [None, None, None]
    dumps({"sigma": u.to_json()})  # valid JSON: no infinities
    assert confidence(u) == 0.0


def test_the_sandwich_is_positive_semidefinite_even_when_badly_conditioned():
    rng = np.random.default_rng(1)
    J_px = rng.normal(size=(12, 10)) * np.logspace(-6, 6, 10)  # columns 12 orders of magnitude apart
    J_cue = rng.normal(size=(3, 10))
    from toosicubix.solver.uncertainty import _sandwich

    cov = _sandwich(J_px, J_cue, 10.0, np.full(12, 1.5))
    assert np.all(np.diag(cov) > 0)
    H = J_px.T @ J_px + 10.0 * J_cue.T @ J_cue
    H_inv = np.linalg.inv(H)
    expected = H_inv @ (1.5**2 * J_px.T @ J_px + 100.0 * J_cue.T @ J_cue) @ H_inv
    np.testing.assert_allclose(np.diag(cov), np.diag(expected), rtol=1e-6)


def test_a_vehicle_clicked_in_keypoints_is_advised_in_keypoints():
    """A car seen from behind, clicked on its rear lamps, glass and bumper only (keypoints at typical
    positions, as ApolloCar3D's people click): its length is left to the prior, and the advice names
    keypoints (one toward the front, the far end: issue 36, item 3), never the cuboid vocabulary's arrows or
    ground contacts."""
    from tests.parts.test_real_click_kinds import REAR_LEFT, exact_prior, keypoint_parts

    rear = {name: at for name, at in REAR_LEFT.items() if name.split("-")[0] in ("lamp", "glass", "bumper")}
    d = np.array([4.6, 1.8, 1.5])
    R = R_cam_vehicle_from_ypr(np.deg2rad(-120.0))
    parts = build_parts_model(keypoint_parts(d, R, np.array([0.5, 1.6, 20.0]), rear))
    assert parts.keypoints_only
    fit = fit_vehicle(parts, CAMERA, exact_prior(d))
    assert fit.ok
    sentences = " ".join(fit.observability.sentences)
    assert ("every keypoint is on its rear end, so its yaw and length rest on the size prior: click one more toward "
            "the far end, the front, along its ") in sentences
    assert "length mostly set by the prior" not in sentences  # the one sentence says it
    assert "arrow" not in sentences and "ground" not in sentences.split("scale set by")[0]
    # The same view clicked in the cuboid vocabulary keeps the cuboid advice.
    _, _, cuboid = _fit("rear", 0)
    assert "click a front and a rear part" in " ".join(cuboid.observability.sentences)
    assert "click a keypoint" not in " ".join(cuboid.observability.sentences)


def test_on_a_road_pitch_and_roll_are_the_roads_not_advice():
    """The same keypoint view fitted upright on a road of known normal (no camera height): pitch and roll left to
    the cues are said to be the road's, in one sentence without advice, and the other quantities keep theirs."""
    from tests.parts.test_real_click_kinds import REAR_LEFT, exact_prior, keypoint_parts
    from toosicubix.model import LEVEL_NORMAL, GroundPlane

    rear = {name: at for name, at in REAR_LEFT.items() if name.split("-")[0] in ("lamp", "glass", "bumper")}
    d = np.array([4.6, 1.8, 1.5])
    parts = build_parts_model(keypoint_parts(d, R_cam_vehicle_from_ypr(np.deg2rad(-120.0)),
                                             np.array([0.5, 1.6, 40.0]), rear))
    road = GroundPlane(LEVEL_NORMAL, np.deg2rad(1.0), None, 0.1, np.deg2rad(2.0))
    free = fit_vehicle(parts, CAMERA, exact_prior(d)).observability
    upright = fit_vehicle(parts, CAMERA, exact_prior(d), ground=road).observability
    on_road = [q for q in ("pitch", "roll") if upright.status[q] != "clicks"]
    assert on_road  # seen end-on at 40 m, the clicks leave pitch and roll to the road
    sentences = upright.sentences
    assert f"{' and '.join(on_road)} set by the road (the vehicle stands upright on it)" in sentences
    assert not any(s.startswith(("pitch mostly", "roll mostly", "pitch set by the prior", "roll set by the prior"))
                   for s in sentences)
    assert any(s.startswith("every keypoint is on its rear end, so its yaw and length rest on the size prior")
               for s in sentences)  # the other quantities keep theirs: the one-end sentence for yaw and length
    assert not any("set by the road" in s for s in free.sentences)  # off the road the clicks set them
