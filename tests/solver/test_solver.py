"""The solver on synthetic vehicles with known answers.

Tolerances: noise-free clicks are fitted with ``lambda_px = 1e-6``: the pixel cost is a MAP objective in
which ``lambda_px`` plays the click-noise variance (px^2), so exact clicks mean a vanishing weight, and the
prior's pull on what the clicks determine is O(lambda_px) (measured about 1e-4 degrees at 1e-6). The
bounds below (0.01 degrees, sIoU 0.999) are the issue's, two orders of magnitude above that.
"""

from dataclasses import replace

import numpy as np
import pytest

import toosicubix.solver.fit as solver_module
from tests.scenes import CAMERA, VIEW_YAW, random_scene
from toosicubix.annotations.priors_file import load_priors
from toosicubix.camera import Camera
from toosicubix.evaluation import iou_3d, scaled_iou
from toosicubix.geometry import Cuboid, R_cam_vehicle_from_ypr, geodesic_angle, so3_exp
from toosicubix.model import Part
from toosicubix.parts.linear import build_parts_model
from toosicubix.size_priors import SizePrior
from toosicubix.solver.descent import DescentResult, descend, solve_pose, solve_shape
from toosicubix.solver.fit import SolverOptions, fit_vehicle
from toosicubix.solver.init import YAW_SWEEP, line_rows, yaw_candidates, yaw_from_lines
from toosicubix.solver.observability import determines_8dof, undetermined_directions
from toosicubix.solver.problem import ARROW_ZONE_SIGMA, Problem
from toosicubix.solver.refine import levenberg_marquardt, residuals_and_jacobian

CAR = load_priors()["Car"]
EXACT = SolverOptions(lambda_px=1e-6)
DETERMINED_VIEWS = ["oblique-front-left", "oblique-rear-right"]
PARTIAL_VIEWS = ["front", "rear", "side"]


def cuboids(fit, scene) -> tuple[Cuboid, Cuboid]:
    return (Cuboid(fit.R_cam_vehicle, fit.t_cam_vehicle, fit.dimensions),
            Cuboid(scene.R_cam_vehicle, scene.t_cam_vehicle, scene.dimensions))


def scaled_errors(fit, scene) -> tuple[float, float, float]:
    """Rotation error (deg), and the largest translation and dimension errors (m) after scaling the fit by
    ``|t_gt| / |t|`` (the sIoU scale)."""
    e_r = np.rad2deg(geodesic_angle(fit.R_cam_vehicle, scene.R_cam_vehicle))
    s = np.linalg.norm(scene.t_cam_vehicle) / np.linalg.norm(fit.t_cam_vehicle)
    e_t = np.abs(s * fit.t_cam_vehicle - scene.t_cam_vehicle).max()
    return e_r, e_t, np.abs(s * fit.dimensions - scene.dimensions).max()


def central_differences(problem, R, t, p, n: int, h: float = 1e-6) -> np.ndarray:
    """The Jacobian of the residuals over ``(delta, t, p)`` (n columns) by central differences."""
    columns = []
    for k in range(n):
        step = np.zeros(n)
        step[k] = h
        plus = residuals_and_jacobian(problem, R @ so3_exp(step[:3]), t + step[3:6], p + step[6:], False)[0]
        minus = residuals_and_jacobian(problem, R @ so3_exp(-step[:3]), t - step[3:6], p - step[6:], False)[0]
        columns.append((plus - minus) / (2 * h))
    return np.column_stack(columns)


def test_jacobian_matches_central_differences(rng):
    scene = random_scene(rng, "oblique-front-left")
    problem = Problem.build(scene.model, CAMERA, CAR, 1.0, 0.7)
    R, t, p = scene.R_cam_vehicle, scene.t_cam_vehicle + 0.1, scene.p_true * 1.05
    _, J = residuals_and_jacobian(problem, R, t, p)
    numeric = central_differences(problem, R, t, p, J.shape[1])
    # Central differences err by O(h^2 f''') ~ 1e-9 relative to entries of size up to ~1e3 px per unit.
    np.testing.assert_allclose(J, numeric, rtol=1e-6, atol=1e-5)


def _moved_arrow(scene, metres_ahead: float) -> tuple[np.ndarray, int]:
    """``p`` with the scene's first arrow moved ``metres_ahead`` along X, and the index of that arrow's tail."""
    model = scene.model
    i = model.arrow_tails[0]
    x_column = int(np.flatnonzero(model.A[i, 0, 3:])[0]) + 3  # the tail's own X unknown (after the dimensions)
    p = scene.p_true.copy()
    p[x_column] += metres_ahead
    return p, i


@pytest.mark.parametrize("view", ["front", "rear"])
def test_arrow_zone_rows_are_zero_near_the_vehicle_and_grow_outside(rng, view):
    """The zone judges the arrow midpoint's ray at the vehicle centre's distance (rule 22): zero for an arrow drawn
    beside the vehicle, and for one moved 30 m ahead, the distance of that ray's point outside the zone."""
    scene = random_scene(rng, view)
    lam = 4.0
    problem = Problem.build(scene.model, CAMERA, CAR, 1.0, lam)
    assert problem.n_arrow_rows == 3
    R, t = scene.R_cam_vehicle, scene.t_cam_vehicle
    r, _ = residuals_and_jacobian(problem, R, t, scene.p_true)
    np.testing.assert_array_equal(r[-3:], 0.0)  # drawn beside the vehicle: inside the zone, no pull at all
    p, i = _moved_arrow(scene, 30.0)
    r, _ = residuals_and_jacobian(problem, R, t, p)
    mid = 0.5 * (scene.model.A[i] + scene.model.A[i + 1]) @ p  # (3,) vehicle frame
    centre = np.array([0.0, 0.0, 0.5 * p[2]])
    camera_centre = -R.T @ t
    on_ray = camera_centre + (mid - camera_centre) * np.linalg.norm(R @ centre + t) / np.linalg.norm(R @ mid + t)
    low, high = np.array([-1.5, -1.5, -0.5]) * p[:3], np.array([1.5, 1.5, 1.5]) * p[:3]
    outside = np.where(on_ray > high, on_ray - high, np.where(on_ray < low, on_ray - low, 0.0))
    assert np.any(outside != 0.0)
    np.testing.assert_allclose(r[-3:], np.sqrt(lam) * outside / ARROW_ZONE_SIGMA, rtol=1e-12, atol=1e-12)


def test_the_arrow_zone_ignores_where_along_its_rays_the_arrow_is_drawn(rng):
    """An arrow drawn shorter or longer than the vehicle is the model's arrow moved along its rays (the paper's
    gauge): the zone sees the midpoint's ray only, so a midpoint anywhere on that ray gives the same rows (issue 36:
    judging the gauge point pulled the yaw of every vehicle whose arrow was not exactly as long as it)."""
    scene = random_scene(rng, "rear")
    problem = Problem.build(scene.model, CAMERA, CAR, 1.0, 1.0)
    R, t = scene.R_cam_vehicle, scene.t_cam_vehicle
    p, i = _moved_arrow(scene, 30.0)
    model = scene.model
    camera_centre = -R.T @ t
    own = np.flatnonzero(np.any(model.A[i, :, 3:] != 0, axis=1)) + 3  # the tail's X, Y, Z unknowns
    mid = 0.5 * (model.A[i] + model.A[i + 1]) @ p
    half_step = mid - model.A[i] @ p  # the tail-to-midpoint vector: half the dimension along the arrow's axis
    r_before, _ = residuals_and_jacobian(problem, R, t, p)
    assert np.any(r_before[-3:] != 0.0)  # outside the zone: the rows are not trivially zero
    for factor in (0.4, 2.5):
        moved = p.copy()
        moved[own] = camera_centre + factor * (mid - camera_centre) - half_step
        assert np.allclose(np.cross(0.5 * (model.A[i] + model.A[i + 1]) @ moved - camera_centre,
                                    mid - camera_centre), 0.0, atol=1e-9)  # the same ray
        r_after, _ = residuals_and_jacobian(problem, R, t, moved)
        np.testing.assert_allclose(r_after[-3:], r_before[-3:], rtol=1e-9, atol=1e-12)


def test_jacobian_matches_central_differences_with_an_arrow_outside_its_zone(rng):
    scene = random_scene(rng, "rear")
    problem = Problem.build(scene.model, CAMERA, CAR, 1.0, 0.7)
    p, _ = _moved_arrow(scene, -25.0)
    R, t = scene.R_cam_vehicle, scene.t_cam_vehicle + 0.1
    _, J = residuals_and_jacobian(problem, R, t, p)
    assert np.any(J[-3:] != 0.0)
    numeric = central_differences(problem, R, t, p, J.shape[1])
    # As above; the zone rows are linear away from the zone's boundary, so their differences are exact.
    np.testing.assert_allclose(J, numeric, rtol=1e-6, atol=1e-5)


def test_zero_residual_at_ground_truth(rng):
    scene = random_scene(rng, "rear")
    problem = Problem.build(scene.model, CAMERA, CAR, 1.0, 1.0)
    r = problem.pixel_residuals(scene.R_cam_vehicle, scene.t_cam_vehicle, scene.p_true)
    np.testing.assert_allclose(r, 0.0, atol=1e-9)


@pytest.mark.parametrize("view", list(VIEW_YAW))
def test_yaw_from_lines_is_exact_for_upright_vehicles(rng, view):
    scene = random_scene(rng, view, max_tilt_deg=0.0)
    problem = Problem.build(scene.model, CAMERA, CAR, 1.0, 1.0)
    ry = yaw_from_lines(line_rows(scene.model, problem.u))
    true_ry = np.arctan2(-scene.R_cam_vehicle[2, 0], scene.R_cam_vehicle[0, 0])
    # Defined up to pi; exact (1e-9 rad) with noise-free clicks and zero pitch and roll.
    diff = np.angle(np.exp(1j * (ry - true_ry)))
    assert min(abs(diff), abs(abs(diff) - np.pi)) < 1e-9


def test_yaw_candidates_try_both_directions_and_offsets(rng):
    scene = random_scene(rng, "front")
    u = CAMERA.normalize(scene.model.uv)
    yaws, from_lines = yaw_candidates(scene.model, u, sweep=0)
    assert from_lines and len(yaws) == 10
    offsets = np.rad2deg(np.angle(np.exp(1j * (yaws - yaws[0]))))
    np.testing.assert_allclose(np.sort(offsets), np.sort([0, -10, 10, -20, 20, 180, 170, -170, 160, -160]), atol=1e-9)
    # The default adds a 30-degree sweep, minus the yaws within 5 degrees of a line-based start.
    with_sweep, _ = yaw_candidates(scene.model, u)
    np.testing.assert_array_equal(with_sweep[:10], yaws)
    extra = with_sweep[10:]
    assert 0 < len(extra) <= 12
    gaps = np.abs(np.angle(np.exp(1j * (extra[:, None] - yaws[None, :]))))
    assert gaps.min() >= np.deg2rad(5.0) - 1e-12


def test_36_angle_sweep_without_lines():
    parts = [Part("point", name, np.array([[100.0 + 10 * i, 50.0 + 7 * i * i]]), "$")
             for i, name in enumerate(["front-center", "top-center", "edge-rear-left", "corner-top-front-right"])]
    model = build_parts_model(parts)
    yaws, from_lines = yaw_candidates(model, CAMERA.normalize(model.uv))
    assert not from_lines
    np.testing.assert_allclose(yaws, YAW_SWEEP)
    assert len(yaws) == 36


def test_shape_step_is_the_least_squares_minimum(rng):
    scene = random_scene(rng, "oblique-rear-right")
    problem = Problem.build(scene.model, CAMERA, CAR, 0.5, 1.0)
    R = scene.R_cam_vehicle @ so3_exp(np.array([0.0, 0.0, 0.05]))
    p, t = solve_shape(problem, R)
    best = problem.cost_3d(R, t, p)
    for _ in range(20):  # any perturbation raises the (convex, quadratic) cost
        dp, dt = 1e-3 * rng.normal(size=p.shape), 1e-3 * rng.normal(size=3)
        assert problem.cost_3d(R, t + dt, p + dp) > best


def test_descent_lowers_the_3d_cost(rng):
    scene = random_scene(rng, "oblique-front-left")
    problem = Problem.build(scene.model, CAMERA, CAR, 1.0, 1.0)
    R0 = R_cam_vehicle_from_ypr(np.arctan2(-scene.R_cam_vehicle[2, 0], scene.R_cam_vehicle[0, 0]) + 0.3)
    p0, t0 = solve_shape(problem, R0)
    result = descend(problem, R0, max_iterations=50)
    assert result.cost < problem.cost_3d(R0, t0, p0)
    assert result.iterations >= 1


def test_sqpnp_failure_gives_none_not_an_exception():
    model = build_parts_model([Part("point", n, np.array([[600.0, 200.0]]), "$")
                               for n in ["front-center", "rear-center", "top-center"]])
    problem = Problem.build(model, CAMERA, CAR, 1.0, 1.0)
    # Three identical clicks: SQPnP asserts on the point spread; we get None.
    assert solve_pose(problem, np.array([4.0, 1.8, 1.5, 0.5, 0.5, 0.1])) is None


def test_mirrored_answer_is_turned_around_by_the_prior_scale(rng):
    scene = random_scene(rng, "rear")
    problem = Problem.build(scene.model, CAMERA, CAR, 1.0, 1.0)
    s = problem.prior_scale(-scene.p_true)
    assert s < 0  # (-p, -t) puts the vehicle behind the camera with negative size; s < 0 turns it back
    r_mirror = problem.pixel_residuals(scene.R_cam_vehicle, -scene.t_cam_vehicle, -scene.p_true)
    np.testing.assert_allclose(r_mirror, 0.0, atol=1e-9)  # the pixel data term cannot tell them apart


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("view", DETERMINED_VIEWS)
def test_noise_free_clicks_determining_8dof_are_fitted_exactly(view, seed):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, view)
    problem = Problem.build(scene.model, CAMERA, CAR, 1.0, 1e-6)
    assert determines_8dof(problem, scene.R_cam_vehicle, scene.t_cam_vehicle, scene.p_true)
    fit = fit_vehicle(scene.model, CAMERA, CAR, EXACT)
    assert fit.ok, fit.reason
    e_r, e_t, e_d = scaled_errors(fit, scene)
    assert e_r < 0.01
    assert scaled_iou(*cuboids(fit, scene)) >= 0.999
    assert e_t < 1e-3 and e_d < 1e-3  # the same, in metres after scaling


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("view", PARTIAL_VIEWS)
def test_views_missing_a_dimension_still_give_the_rotation(view, seed):
    rng = np.random.default_rng(100 + seed)
    scene = random_scene(rng, view)
    problem = Problem.build(scene.model, CAMERA, CAR, 1.0, 1e-6)
    # Scale and one dimension (length from the front or rear, width from the side) are left to the prior.
    assert undetermined_directions(problem, scene.R_cam_vehicle, scene.t_cam_vehicle, scene.p_true) == 2
    fit = fit_vehicle(scene.model, CAMERA, CAR, EXACT)
    assert fit.ok, fit.reason
    assert scaled_errors(fit, scene)[0] < 0.01
    # The only misfit is the prior's pull: cost <= lambda_px * Mahalanobis^2 ~ 1e-6 * 10, so rms ~ 1e-3 px.
    assert fit.rms_px < 1e-3


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("view", list(VIEW_YAW))
def test_prior_centred_on_the_true_size_gives_the_full_cuboid(view, seed):
    rng = np.random.default_rng(200 + seed)
    scene = random_scene(rng, view)
    prior = SizePrior.from_mean_cov("exact", scene.dimensions, CAR.cov)
    fit = fit_vehicle(scene.model, CAMERA, prior, SolverOptions())  # default weights
    assert fit.ok, fit.reason
    assert iou_3d(*cuboids(fit, scene)) >= 0.99
    np.testing.assert_allclose(fit.t_cam_vehicle, scene.t_cam_vehicle, atol=1e-3)
    np.testing.assert_allclose(fit.dimensions, scene.dimensions, atol=1e-3)
    assert np.rad2deg(geodesic_angle(fit.R_cam_vehicle, scene.R_cam_vehicle)) < 0.01


def test_lens_distortion_is_honoured(rng):
    camera = Camera(K=CAMERA.K, distortion=np.array([-0.25, 0.08, 0.001, -0.0005, -0.01]), image_size=(1240, 375))
    scene = random_scene(rng, "oblique-front-left", camera=camera)
    fit = fit_vehicle(scene.model, camera, CAR, EXACT)
    assert fit.ok
    assert scaled_errors(fit, scene)[0] < 0.01
    # Ignoring the distortion gives a rotation 80 times further off (0.8 degrees here): the model really uses it.
    naive = fit_vehicle(scene.model, Camera(K=CAMERA.K), CAR, EXACT)
    assert scaled_errors(naive, scene)[0] > 0.1


def test_too_few_constraints_fail_with_the_count():
    parts = [Part("point", "wheel-rear-left", np.array([[500.0, 250.0]]), "$"),
             Part("point", "wheel-rear-right", np.array([[600.0, 252.0]]), "$")]
    fit = fit_vehicle(build_parts_model(parts), CAMERA, CAR)
    assert fit.status == "failed"
    # The rear axle is the clicks' only unknown of their own, and a car's axle prior holds it (rule 31): 4 of the 6
    # constraints needed, so 1 more click (2 each).
    assert fit.detail.startswith("too few constraints: 2 clicked points give 4 (2 per point minus 1 auxiliary "
                                 "unknowns, 1 of them held by the axle prior)")
    assert fit.reason.startswith("too few clicks: 2 clicked points cannot place a cuboid; click at least 1 more")
    assert fit.R_cam_vehicle is None


def test_degenerate_clicks_fail_without_an_exception():
    same = np.array([[640.0, 200.0]])
    parts = [Part("point", n, same, "$") for n in
             ["corner-top-front-left", "corner-top-rear-left", "corner-bottom-front-left", "corner-top-front-right"]]
    fit = fit_vehicle(build_parts_model(parts), CAMERA, CAR)
    assert fit.status == "failed"
    assert fit.detail.startswith("degenerate clicks: all 4 clicks lie in one cluster")
    assert fit.reason.startswith("all 4 clicks are within a few pixels of each other")


def test_fit_is_deterministic(rng):
    scene = random_scene(rng, "oblique-rear-right")
    a = fit_vehicle(scene.model, CAMERA, CAR)
    b = fit_vehicle(scene.model, CAMERA, CAR)
    np.testing.assert_array_equal(a.R_cam_vehicle, b.R_cam_vehicle)
    np.testing.assert_array_equal(a.p, b.p)
    assert a.cost == b.cost


def test_starts_are_not_compared_by_the_shrinking_3d_cost(rng, monkeypatch):
    """With noise-free clicks and a prior not centred on the true size, a descent result 23 degrees off has
    a lower 3D cost than the true pose: the data term lets it shrink and bend toward the prior. Starts
    must be compared by the pixel cost, which finds the true pose."""
    scene = random_scene(rng, "oblique-front-left")
    problem = Problem.build(scene.model, CAMERA, CAR, 1.0, 1e-6)
    wrong_R = scene.R_cam_vehicle @ so3_exp(np.array([0.0, 0.0, 0.4]))
    wrong_p, wrong_t = solve_shape(problem, wrong_R)
    wrong = DescentResult(wrong_R, wrong_t, wrong_p, problem.cost_3d(wrong_R, wrong_t, wrong_p), 1, "converged")
    true = DescentResult(scene.R_cam_vehicle, scene.t_cam_vehicle, scene.p_true,
                         problem.cost_3d(scene.R_cam_vehicle, scene.t_cam_vehicle, scene.p_true), 1, "converged")
    assert wrong.cost < true.cost  # the trap
    # The true pose comes from the third start.
    monkeypatch.setattr(solver_module, "descend_all",
                        lambda problem, R_start, *args: [wrong, wrong, true] + [wrong] * (len(R_start) - 3))
    fit = fit_vehicle(scene.model, CAMERA, CAR, replace(EXACT, refine_starts=1, refine_iterations=0))
    # No refinement at all: the choice alone must land on the true pose.
    assert np.rad2deg(geodesic_angle(fit.R_cam_vehicle, scene.R_cam_vehicle)) < 1e-9


def test_refine_reaches_zero_residual_from_a_perturbed_start(rng):
    scene = random_scene(rng, "oblique-rear-right")
    problem = Problem.build(scene.model, CAMERA, CAR, 1.0, 1e-6)
    R0 = scene.R_cam_vehicle @ so3_exp(np.deg2rad([2.0, -1.0, 3.0]))
    result = levenberg_marquardt(problem, R0, scene.t_cam_vehicle * 1.02, scene.p_true * 1.02)
    assert result.cost < 1e-6 * result.initial_cost
    assert np.rad2deg(geodesic_angle(result.R_cam_vehicle, scene.R_cam_vehicle)) < 0.01


def test_rotations_from_yaws_match_the_kitti_convention(rng):
    from toosicubix.solver.init import rotations_from_yaws

    yaws = rng.uniform(-np.pi, np.pi, 7)
    np.testing.assert_allclose(rotations_from_yaws(yaws), [R_cam_vehicle_from_ypr(y) for y in yaws], atol=1e-15)


def test_an_arrow_without_length_fails_the_vehicle_not_the_file():
    parts = [Part("point", n, np.array([[400.0 + 60 * i, 250.0 - 5 * i]]), "$")
             for i, n in enumerate(["wheel-front-left", "wheel-rear-left", "wheel-rear-right", "corner-top-rear-left"])]
    parts.append(Part("direction", "forward", np.array([[500.0, 260.0], [500.3, 260.2]]), "$"))
    fit = fit_vehicle(build_parts_model(parts), CAMERA, CAR)
    assert fit.status == "failed"
    assert fit.detail == ("degenerate clicks: the forward arrow of annotation parts[4] is 0.36 px long "
                          "(an arrow needs at least 1 px)")
    assert fit.reason == ("the forward arrow (parts[4]) has no length: draw each arrow from its tail to its head "
                          "along the vehicle, at least 1 px long")
