"""The one Levenberg-Marquardt (toosicubix.solver.lm), its loss interface, and its two problems.

Tolerances: the toy problems are noise-free, so their minimum is the truth to rounding; LM stops on the
gradient (gtol 1e-10 here) or on a step below 1e-10, with the cost below 1e-16 of its start. Jacobians
against central differences (h = 1e-6) err by O(h^2) ~ 1e-9 relative to entries up to ~1e3 px per unit:
rtol 1e-6, atol 1e-5 as in test_solver.
"""

import itertools

import cv2
import numpy as np
import pytest

from tests.scenes import CAMERA, random_scene
from tests.solver.test_ground import CAR, LEVEL, OBLIQUE_REAR, D
from toosicubix.geometry import R_cam_vehicle_from_ypr, geodesic_angle, hat, so3_exp
from toosicubix.model import GroundPlane
from toosicubix.parts.linear import build_parts_model
from toosicubix.parts.synthesis import render_parts, true_parameters
from toosicubix.solver.joint import JointProblem, JointVehicle
from toosicubix.solver.lm import LMOptions, Loss, TrivialLoss, levenberg_marquardt
from toosicubix.solver.problem import Problem
from toosicubix.solver.refine import RefineProblem


class PointAlignment:
    """Toy problem: rotate and move points ``X`` (N, 3) onto ``Y`` (N, 3). State ``(R, t)``, (B, 3, 3) and
    (B, 3); residuals ``R X_i + t - Y_i`` (B, 3N); update ``R <- R exp([delta]x)``, ``t <- t + dt``."""

    def __init__(self, X, Y):
        self.X, self.Y = X, Y

    def residuals(self, state, with_jacobian):
        R, t = state
        B, N = len(R), len(self.X)
        r = (self.X @ R.transpose(0, 2, 1) + t[:, None, :] - self.Y).reshape(B, 3 * N)
        if not with_jacobian:
            return r, None
        J = np.zeros((B, N, 3, 6))
        J[..., :3] = -R[:, None] @ hat(self.X)[None]  # d(R exp([delta]x) X) / d delta = -R [X]x
        J[..., 3:] = np.eye(3)
        return r, J.reshape(B, 3 * N, 6)

    def update(self, state, delta):
        R, t = state
        return R @ so3_exp(delta[:, :3]), t + delta[:, 3:]

    def feasible(self, state):
        return np.ones(len(state[0]), dtype=bool)

    def settle(self, state):
        return state

    def step_is_small(self, delta, tolerance, starts):
        return np.abs(delta).max(axis=1) <= tolerance


def alignment(rng, n=12):
    R_true = so3_exp(rng.normal(size=3))
    t_true = rng.normal(size=3)
    X = rng.normal(size=(n, 3))
    return PointAlignment(X, X @ R_true.T + t_true), R_true, t_true


def test_lm_solves_a_toy_problem_from_several_starts(rng):
    problem, R_true, t_true = alignment(rng)
    starts = 4
    R0 = R_true @ so3_exp(0.6 * rng.normal(size=(starts, 3)))
    t0 = t_true + rng.normal(size=(starts, 3))
    result = levenberg_marquardt(problem, (R0, t0), LMOptions(gradient_tolerance=1e-10))
    R, t = result.state
    assert set(result.stopped) <= {"gradient", "step"}
    assert np.all(result.iterations >= 1) and np.all(result.iterations < 100)
    assert np.all(result.cost < 1e-16 * result.initial_cost)
    assert result.seconds > 0.0
    for k in range(starts):
        assert geodesic_angle(R[k], R_true) < 1e-8
        np.testing.assert_allclose(t[k], t_true, atol=1e-8)


def test_lm_never_takes_an_infeasible_step(rng):
    """The optimum lies where ``feasible`` says no: the fit stops at the boundary and never crosses it."""
    problem, R_true, t_true = alignment(rng)
    problem.feasible = lambda state: state[1][:, 0] <= t_true[0] - 0.5  # the truth is not allowed
    result = levenberg_marquardt(problem, (R_true[None], t_true[None] - 1.0), LMOptions(max_iterations=50))
    assert result.state[1][0, 0] <= t_true[0] - 0.5
    assert result.cost[0] < result.initial_cost[0]


def test_lm_abandons_a_start_far_above_the_best(rng):
    problem, R_true, t_true = alignment(rng)
    R0 = np.stack([R_true @ so3_exp([0.0, 0.0, 0.1]), R_true @ so3_exp([0.0, 0.0, 3.0])])
    result = levenberg_marquardt(problem, (R0, np.stack([t_true, t_true + 5.0])),
                                 LMOptions(max_iterations=30, abandon_factor=2.0, abandon_after=0))
    assert result.stopped[1] == "abandoned" and result.iterations[1] == 0
    assert result.stopped[0] != "abandoned" and result.cost[0] < 1e-12


def test_trivial_loss_is_the_sum_of_squares():
    s = np.array([[0.0, 0.25, 4.0], [1e6, 3.0, 1e-9]])
    loss = TrivialLoss()
    assert loss.trivial
    np.testing.assert_array_equal(loss.loss(s), s)
    np.testing.assert_array_equal(loss.weight(s), np.ones_like(s))


class Cauchy(Loss):
    """``rho(s) = c^2 log(1 + s / c^2)``, weight ``1 / (1 + s / c^2)``: a robust loss is this small."""

    def __init__(self, c):
        self.c2 = c * c

    def loss(self, s):
        return self.c2 * np.log1p(s / self.c2)

    def weight(self, s):
        return 1.0 / (1.0 + s / self.c2)


class UnitWeights(Loss):
    """The sum of squares through the weighted path (``trivial`` False): must agree with TrivialLoss."""

    def loss(self, s):
        return s

    def weight(self, s):
        return np.ones_like(s)


def test_weighted_path_with_unit_weights_matches_the_trivial_loss(rng):
    problem, R_true, t_true = alignment(rng)
    start = (R_true[None] @ so3_exp([0.3, -0.2, 0.4])[None], t_true[None] + 0.5)
    plain = levenberg_marquardt(problem, start, LMOptions(max_iterations=5))
    weighted = levenberg_marquardt(problem, start, LMOptions(max_iterations=5), UnitWeights())
    assert weighted.iterations[0] == plain.iterations[0] == 5
    np.testing.assert_allclose(weighted.cost, plain.cost, rtol=1e-9)
    np.testing.assert_allclose(weighted.state[1], plain.state[1], rtol=1e-9)


def test_a_robust_loss_reweighs_an_outlier_away(rng):
    """One point moved 5 m: least squares is pulled off the truth, the Cauchy loss (IRLS) is not."""
    problem, R_true, t_true = alignment(rng, n=20)
    problem.Y = problem.Y.copy()
    problem.Y[0] += 5.0
    start = (R_true[None], t_true[None])
    plain = levenberg_marquardt(problem, start, LMOptions(gradient_tolerance=1e-10))
    robust = levenberg_marquardt(problem, start, LMOptions(gradient_tolerance=1e-10, max_iterations=500),
                                 Cauchy(0.1))
    error_plain = np.linalg.norm(plain.state[1][0] - t_true)
    error_robust = np.linalg.norm(robust.state[1][0] - t_true)
    assert error_plain > 0.1
    assert error_robust < 0.01 * error_plain
    assert robust.cost[0] < robust.initial_cost[0]


def numeric_jacobian(problem, state, n, h=1e-6):
    """Central differences of ``problem.residuals`` along ``problem.update``: (B, M, n)."""
    B = len(state[0])
    columns = []
    for j in range(n):
        step = np.zeros((B, n))
        step[:, j] = h
        plus = problem.residuals(problem.update(state, step), False)[0]
        minus = problem.residuals(problem.update(state, -step), False)[0]
        columns.append((plus - minus) / (2 * h))
    return np.stack(columns, axis=2)


def test_toy_problem_jacobian(rng):
    problem, R_true, t_true = alignment(rng)
    state = (R_true[None] @ so3_exp([0.3, -0.2, 0.4])[None], t_true[None] + 0.5)
    _, J = problem.residuals(state, True)
    np.testing.assert_allclose(J, numeric_jacobian(problem, state, 6), rtol=1e-6, atol=1e-8)


def test_refine_problem_jacobian_matches_central_differences_along_its_update(rng):
    scenes = [random_scene(rng, "oblique-front-left") for _ in range(2)]
    model = scenes[0].model
    problem = Problem.build(model, CAMERA, CAR, 1.0, 0.7)
    refine = RefineProblem(problem)
    scene = scenes[0]
    R = np.stack([scene.R_cam_vehicle, scene.R_cam_vehicle @ so3_exp([0.05, -0.1, 0.2])])
    state = refine.start(R, np.stack([scene.t_cam_vehicle + 0.1, scene.t_cam_vehicle * 1.1]),
                         np.stack([scene.p_true * 1.05, scene.p_true * 0.97]))
    r, J = refine.residuals(state, True)
    assert J.shape == (2, r.shape[1], 6 + len(scene.p_true))
    np.testing.assert_allclose(J, numeric_jacobian(refine, state, J.shape[2]), rtol=1e-6, atol=1e-5)


@pytest.mark.parametrize("camera_height", [None, 1.55])
def test_joint_problem_jacobian_matches_central_differences_along_its_update(camera_height):
    rng = np.random.default_rng(3)
    ground = GroundPlane(normal=LEVEL, normal_sigma=np.deg2rad(1.0), camera_height=camera_height,
                         camera_height_sigma=0.1, upright_sigma=np.deg2rad(2.0))
    vehicles = []
    for _ in range(3):
        R = R_cam_vehicle_from_ypr(np.deg2rad(rng.uniform(-120, -30)))
        t = np.array([rng.uniform(-6, 6), 1.55, rng.uniform(10, 35)])
        parts = render_parts(OBLIQUE_REAR, R, t, D, CAMERA, (0.3 * D[0], -0.3 * D[0]))
        model = build_parts_model(parts)
        problem = Problem.build(model, CAMERA, CAR, 0.1, 1e-2)
        _, p = true_parameters(OBLIQUE_REAR, D, (0.3 * D[0], -0.3 * D[0]))
        vehicles.append(JointVehicle(problem, R @ so3_exp(rng.normal(0, 0.05, 3)), t * 1.03, p * 0.98))
    joint = JointProblem(vehicles, ground)
    normal = np.array([0.03, -0.998, 0.02]) / np.linalg.norm([0.03, -0.998, 0.02])
    state = (np.stack([v.R_cam_vehicle for v in vehicles])[None], np.stack([v.t_cam_vehicle for v in vehicles])[None],
             np.concatenate([v.p for v in vehicles])[None], normal[None], np.array([1.6]))
    # The contact's sigma grows with the distance; the Jacobian treats it as a weight fixed at the current
    # ``t`` (as the fit always has), so the differences hold it fixed too.
    sigmas = [joint.contact_sigma(t) for t in state[1][0]]
    order = itertools.cycle(sigmas)  # evaluate() asks vehicle by vehicle, in order
    joint.contact_sigma = lambda t: next(order)
    _, J = joint.residuals(state, True)
    assert J.shape[2] == joint.n_params
    np.testing.assert_allclose(J, numeric_jacobian(joint, state, joint.n_params), rtol=1e-6, atol=1e-5)


@pytest.mark.parametrize("count", [1, 5, 40])  # through cv2.Rodrigues one by one, and the array formula
def test_so3_exp_batch_is_rodrigues_bit_for_bit(rng, count):
    omega = rng.normal(size=(count, 3)) * np.logspace(-17, 0.5, count)[:, None]
    R = so3_exp(omega)
    assert R.shape == (count, 3, 3)
    expected = np.array([cv2.Rodrigues(w)[0] for w in omega])
    np.testing.assert_array_equal(R, expected)
    np.testing.assert_array_equal(so3_exp(omega[0]), expected[0])
    np.testing.assert_array_equal(so3_exp(omega.reshape(count, 1, 3))[:, 0], expected)


def test_so3_exp_of_a_zero_vector_is_the_identity_rodrigues_gives(rng):
    omega = rng.normal(size=(4, 3))
    omega[1], omega[3] = 0.0, (-0.0, 0.0, -0.0)  # the steps of stopped starts
    np.testing.assert_array_equal(so3_exp(omega), np.array([cv2.Rodrigues(w)[0] for w in omega]))
    np.testing.assert_array_equal(so3_exp(omega)[[1, 3]], np.stack([np.eye(3)] * 2))


def test_hat_batch(rng):
    a, b = rng.normal(size=(4, 2, 3)), rng.normal(size=(4, 2, 3))
    np.testing.assert_allclose((hat(a) @ b[..., None])[..., 0], np.cross(a, b), atol=1e-12)
