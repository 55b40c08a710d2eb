"""The compiled refinement (toosicubix/solver/compiled.py) computes every number as the numpy path does.

Each comparison is bit for bit: the compiled path exists only because it changes no result (issue 37). Skipped where
the compiled path cannot run (no numba, or a numpy not built on OpenBLAS): there the numpy path runs anyway.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tests.parts.test_real_click_kinds import exact_prior, keypoint_parts, scene
from tests.scenes import CAMERA, VIEW_YAW, random_scene
from toosicubix.annotations.priors_file import load_priors
from toosicubix.model import GroundPlane
from toosicubix.parts.linear import build_parts_model
from toosicubix.solver import compiled, lm
from toosicubix.solver.fit import SolverOptions, fit_vehicle
from toosicubix.solver.problem import KERNEL_ARRAYS, Problem
from toosicubix.solver.refine import RefineProblem
from toosicubix.solver.robust import soft_weights, with_weights

pytestmark = pytest.mark.skipif(not compiled.available(),
                                reason="the compiled refinement cannot run here (numba or numpy's OpenBLAS missing)")

GROUND = GroundPlane(np.array([0.0, -1.0, 0.0]), math.radians(1.0), 1.65, 0.1, math.radians(2.0))
CAR = load_priors()["Car"]


def _bits(x) -> bytes:
    return np.ascontiguousarray(np.asarray(x, dtype=float)).tobytes()


def _assert_same_fit(a, b):
    assert (a.status, a.reason, a.refine_iterations, a.descent_iterations) == (
        b.status, b.reason, b.refine_iterations, b.descent_iterations)
    for name in ("R_cam_vehicle", "t_cam_vehicle", "p", "cost", "initial_cost", "residuals_px"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert _bits(x) == _bits(y), name


def _both(fit):
    """The fit as the compiled path gives it, and as the numpy path does."""
    compiled_fit = fit()
    with compiled.numpy_path_only():
        numpy_fit = fit()
    return compiled_fit, numpy_fit


@pytest.mark.parametrize("view", sorted(VIEW_YAW))
@pytest.mark.parametrize("ground", [None, GROUND], ids=["no ground", "ground"])
def test_fits_of_the_paper_parts_are_the_same_to_the_last_bit(view, ground):
    # Every part kind, direction arrows (their zone rows) included, with and without the upright and contact rows.
    rng = np.random.default_rng(7)
    for _ in range(4):
        s = random_scene(rng, view)
        noisy = build_parts_model([replace(p, uv=p.uv + rng.normal(0.0, 1.5, p.uv.shape)) for p in s.parts])
        a, b = _both(lambda: fit_vehicle(noisy, CAMERA, CAR, SolverOptions(), ground))  # noqa: B023
        assert a.ok == b.ok
        _assert_same_fit(a, b)


def test_fits_of_keypoints_with_the_robust_loss_are_the_same_to_the_last_bit():
    # Keypoints: per-click weights (their soft term), the Cauchy rounds, one mislabelled click.
    rng = np.random.default_rng(3)
    for _ in range(6):
        d, R, t = scene(rng)
        parts = keypoint_parts(d, R, t)
        parts[0] = replace(parts[0], uv=parts[0].uv + np.array([[25.0, -10.0]]))
        model = build_parts_model([replace(p, uv=p.uv + rng.normal(0.0, 1.0, p.uv.shape)) for p in parts])
        a, b = _both(lambda: fit_vehicle(model, CAMERA, exact_prior(d), SolverOptions(), GROUND))  # noqa: B023
        assert a.ok and b.ok
        _assert_same_fit(a, b)


def _refine_problem(rng, weighted: bool):
    s = random_scene(rng, "oblique-front-left")
    problem = Problem.build(s.model, CAMERA, CAR, 0.1, 10.0, GROUND, 20.0)
    if weighted:
        problem = with_weights(problem, rng.uniform(0.2, 1.0, s.model.n_clicks))
    return s, problem


@pytest.mark.parametrize("starts", [1, 2, 4, 8])
def test_a_batch_of_starts_ends_where_the_numpy_loop_ends(starts):
    # Starts off the answer by up to 25 degrees: rejected steps, infeasible trials and starts that stop early.
    rng = np.random.default_rng(starts)
    for weighted in (False, True):
        s, problem = _refine_problem(rng, weighted)
        turns = rng.normal(0.0, 0.25, (starts, 3))
        R = np.array([s.R_cam_vehicle @ _rotation(w) for w in turns])
        t = s.t_cam_vehicle + rng.normal(0.0, 1.0, (starts, 3))
        p = s.p_true * rng.uniform(0.8, 1.2, (starts, len(s.p_true)))
        refine = RefineProblem(problem, math.radians(30.0))
        state = refine.start(R, t, p)
        options = lm.LMOptions(abandon_factor=4.0, abandon_after=5)
        mine = compiled._run(refine, state, options)
        theirs = _numpy_lm(refine, state, options)
        assert compiled._same(mine, theirs), (mine.stopped, theirs.stopped, mine.iterations, theirs.iterations)
        assert set(theirs.stopped) <= set(lm.STATUS_NAMES[1:])


def _numpy_lm(refine, state, options):
    """The numpy loop with numpy's residuals (the compiled residuals, the same numbers, would run inside it)."""
    with compiled.numpy_path_only():
        return lm.levenberg_marquardt(refine, state, options)


def _rotation(w):
    from toosicubix.geometry import so3_exp

    return so3_exp(w)


def test_the_first_refinement_falls_back_when_the_numbers_differ(monkeypatch):
    # A machine whose libraries round otherwise: the first comparison finds it, and from then on the numpy path runs.
    rng = np.random.default_rng(0)
    s, problem = _refine_problem(rng, False)
    refine = RefineProblem(problem, None)
    state = refine.start(s.R_cam_vehicle[None], s.t_cam_vehicle[None], s.p_true[None])
    options = lm.LMOptions()
    real_run = compiled._run

    def off_by_one_bit(*args):
        result = real_run(*args)
        return replace(result, cost=np.nextafter(result.cost, np.inf))

    monkeypatch.setattr(compiled, "_run", off_by_one_bit)
    monkeypatch.setattr(compiled, "_agrees", {})
    first = compiled.levenberg_marquardt(refine, state, options)
    assert first is not None and compiled._same(first, _numpy_lm(refine, state, options))
    assert compiled._agrees["refine"] is False
    assert compiled.levenberg_marquardt(refine, state, options) is None  # the numpy path from now on


def test_numpy_path_only_and_the_environment_switch_turn_it_off(monkeypatch):
    rng = np.random.default_rng(1)
    s, problem = _refine_problem(rng, False)
    refine = RefineProblem(problem, None)
    state = refine.start(s.R_cam_vehicle[None], s.t_cam_vehicle[None], s.p_true[None])
    monkeypatch.setattr(compiled, "_agrees", {"refine": True})
    assert compiled.levenberg_marquardt(refine, state, lm.LMOptions()) is not None
    with compiled.numpy_path_only():
        assert compiled.levenberg_marquardt(refine, state, lm.LMOptions()) is None
    monkeypatch.setattr(compiled, "_kernel", None)
    monkeypatch.setenv(compiled.ENVIRONMENT_SWITCH, "0")
    assert not compiled.available()
    assert compiled.levenberg_marquardt(refine, state, lm.LMOptions()) is None


def test_keypoint_weights_from_the_soft_term_are_the_same_to_the_last_bit():
    rng = np.random.default_rng(11)
    d, R, t = scene(rng)
    model = build_parts_model(keypoint_parts(d, R, t))
    problem = Problem.build(model, CAMERA, exact_prior(d), 0.1, 10.0)
    problem = with_weights(problem, soft_weights(problem, float(np.linalg.norm(t)), 1.0))
    refine = RefineProblem(problem, None)
    state = refine.start(R[None], (t + 0.3)[None], (d * 1.1)[None])
    mine = compiled._run(refine, state, lm.LMOptions())
    assert compiled._same(mine, _numpy_lm(refine, state, lm.LMOptions()))


def test_reweighing_hands_on_the_kernel_arrays_and_only_the_weights_change():
    """Problem.with_click_weights keeps what the weights do not change (the robust loss reweighs a vehicle up to five
    times): the reweighed problem reuses its parent's kernel arrays, and its arrays equal a fresh problem's."""
    rng = np.random.default_rng(11)
    d, R, t = scene(rng)
    model = build_parts_model(keypoint_parts(d, R, t))
    problem = Problem.build(model, CAMERA, exact_prior(d), 0.1, 10.0)
    assert with_weights(problem, None) is problem  # nothing weighed before or after: the same problem
    compiled._problem_arrays(problem)
    weights = soft_weights(problem, float(np.linalg.norm(t)), 1.0)
    reweighed = with_weights(problem, weights)
    fresh = with_weights(Problem.build(model, CAMERA, exact_prior(d), 0.1, 10.0), weights)

    def unmade(_):
        raise AssertionError("the kernel arrays were not kept under problem.KERNEL_ARRAYS")

    assert reweighed.kept(KERNEL_ARRAYS, unmade) is problem.kept(KERNEL_ARRAYS, unmade)
    for mine, theirs in zip(compiled._problem_arrays(reweighed), compiled._problem_arrays(fresh), strict=True):
        assert np.array_equal(mine, theirs)
    assert not np.array_equal(compiled._problem_arrays(reweighed)[12], compiled._problem_arrays(problem)[12])


def test_warm_up_says_when_it_compiles(monkeypatch):
    said = []
    monkeypatch.setattr(compiled, "_cached", lambda dispatcher: False)
    assert compiled.warm_up(said.append)
    assert said == [compiled.COMPILING]
    said.clear()
    monkeypatch.setattr(compiled, "_cached", lambda dispatcher: True)
    assert compiled.warm_up(said.append)
    assert said == []


def test_an_error_of_the_compiled_code_turns_it_off(monkeypatch):
    rng = np.random.default_rng(2)
    s, problem = _refine_problem(rng, False)
    refine = RefineProblem(problem, None)
    state = refine.start(s.R_cam_vehicle[None], s.t_cam_vehicle[None], s.p_true[None])

    def broken(*args):
        raise RuntimeError("a fault")

    monkeypatch.setattr(compiled, "_run", broken)
    monkeypatch.setattr(compiled, "_agrees", {"refine": True})
    assert compiled.levenberg_marquardt(refine, state, lm.LMOptions()) is None
    assert compiled._agrees["refine"] is False


def test_warm_up_that_fails_leaves_the_numpy_path(monkeypatch):
    available = compiled.available()

    class Broken:
        lm = residuals = solve_shapes = costs_3d = None

        @staticmethod
        def warm_up():
            raise RuntimeError("no compiler")

    monkeypatch.setattr(compiled, "_kernel", Broken)
    monkeypatch.setattr(compiled, "_cached", lambda dispatcher: True)
    assert available and not compiled.warm_up()
    assert not compiled.available()


@pytest.mark.parametrize("view", sorted(VIEW_YAW))
def test_the_descents_shape_step_and_3d_cost_are_the_same_to_the_last_bit(view, monkeypatch):
    # Every call compared (not only the first of the process), on the paper's parts and on 70 keypoints (140 pixel
    # rows: numpy's pairwise sum splits above 128 numbers).
    from toosicubix.solver.descent import costs_3d, solve_shapes

    compared = []

    def every_call(name, result, reference, same):
        expected = reference()
        compared.append(name)
        assert _bits(result) == _bits(expected), name
        return expected

    monkeypatch.setattr(compiled, "_first_checked", every_call)
    rng = np.random.default_rng(5)
    s = random_scene(rng, view)
    problems = [Problem.build(s.model, CAMERA, CAR, 0.1, 10.0, None, 0.0),
                Problem.build(s.model, CAMERA, CAR, 0.1, 10.0, GROUND, 20.0)]
    d, R, t = scene(rng)
    many = {f"k{i}": (*rng.uniform(-0.5, 0.5, 2), rng.uniform(0.0, 1.0)) for i in range(70)}
    problems.append(Problem.build(build_parts_model(keypoint_parts(d, R, t, many)), CAMERA, exact_prior(d), 0.1, 10.0))
    for problem in problems:
        for starts in (1, 3, 12):
            rotations = np.array([s.R_cam_vehicle @ _rotation(w) for w in rng.normal(0.0, 0.3, (starts, 3))])
            p, t_ = solve_shapes(problem, rotations)
            costs_3d(problem, rotations, t_, p)
    assert compared.count("shapes") == compared.count("costs") == 9


@pytest.mark.parametrize("starts", [1, 2, 5, 36])
@pytest.mark.parametrize("ground", [None, GROUND], ids=["no ground", "ground"])
def test_residuals_and_their_jacobian_are_the_same_to_the_last_bit(starts, ground, monkeypatch):
    # Every variant residuals_batch is called with (the refinement's: Jacobian, pivot, profiled scale; the fit's
    # checks: none of them; the joint ground's: pivot, no profile), weighted and not, arrows in and out of their zones
    # (starts off the answer), batches of one (numpy's gemv) to a sweep's 36.
    from toosicubix.solver.refine import _residuals_numpy

    monkeypatch.setattr(compiled, "_first_checked", lambda name, result, reference, same: result)  # every call: below
    rng = np.random.default_rng(starts)
    for view in sorted(VIEW_YAW):
        s = random_scene(rng, view)
        problem = Problem.build(s.model, CAMERA, CAR, 0.1, 10.0, ground, 20.0)
        for weighted in (False, True):
            if weighted:
                problem = with_weights(problem, rng.uniform(0.2, 1.0, s.model.n_clicks))
            R = np.array([s.R_cam_vehicle @ _rotation(w) for w in rng.normal(0.0, 0.3, (starts, 3))])
            t = s.t_cam_vehicle + rng.normal(0.0, 1.0, (starts, 3))
            p = s.p_true * rng.uniform(0.7, 1.3, (starts, len(s.p_true)))
            pivot = rng.normal(0.0, 1.0, (starts, 3))
            for with_jacobian, about, profile in [(True, True, True), (False, False, False), (True, False, False),
                                                  (True, True, False), (False, True, True)]:
                args = (problem, R, t, p, with_jacobian, pivot if about else None, profile)
                found = compiled.residuals(*args, numpy_residuals=lambda: None)
                assert found is not None
                expected = _residuals_numpy(*args)
                assert _bits(found[0]) == _bits(expected[0]), (view, weighted, with_jacobian, about, profile)
                assert (found[1] is None) == (expected[1] is None)
                if with_jacobian:
                    assert _bits(found[1]) == _bits(expected[1]), (view, weighted, with_jacobian, about, profile)


def test_a_residuals_variant_that_differs_falls_back_alone(monkeypatch):
    # The first call of each variant is compared; one off by a bit turns that variant off, not the others.
    from toosicubix.solver.refine import residuals_batch

    rng = np.random.default_rng(4)
    s, problem = _refine_problem(rng, False)
    R, t, p = s.R_cam_vehicle[None], s.t_cam_vehicle[None], s.p_true[None]
    real = compiled._kernel.residuals

    def off_by_one_bit(*args):
        r, J = real(*args)
        r = r.copy()
        r[0, 0] = np.nextafter(r[0, 0], np.inf)
        return r, J

    monkeypatch.setattr(compiled, "_agrees", {})
    monkeypatch.setattr(compiled._kernel, "residuals", off_by_one_bit)
    first = residuals_batch(problem, R, t, p, False, None, False)
    assert compiled._agrees == {"residuals": False}
    with compiled.numpy_path_only():
        assert _bits(first[0]) == _bits(residuals_batch(problem, R, t, p, False, None, False)[0])
    assert compiled.residuals(problem, R, t, p, False, None, False, lambda: None) is None
    monkeypatch.setattr(compiled._kernel, "residuals", real)
    assert compiled.residuals(problem, R, t, p, True, None, False, lambda: residuals_batch(
        problem, R, t, p, True, None, False)) is not None
    assert compiled._agrees == {"residuals": False, "residuals+J": True}


def test_warm_up_inside_the_numpy_path_loads_nothing(monkeypatch):
    loaded = []
    monkeypatch.setattr(compiled, "available", lambda: loaded.append(True) or True)
    with compiled.numpy_path_only():
        assert not compiled.warm_up(loaded.append)
    assert loaded == []  # neither asked whether numba is there nor told anything
