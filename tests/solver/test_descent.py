"""Coordinate descent's pose step and shape step give what they gave before they were made cheaper (issue 37)."""

import cv2
import numpy as np
import pytest

from tests.scenes import CAMERA, VIEW_YAW, random_scene
from toosicubix.annotations.priors_file import load_priors
from toosicubix.solver import descent
from toosicubix.solver.problem import Problem

CAR = load_priors()["Car"]


@pytest.mark.parametrize("view", sorted(VIEW_YAW))
def test_the_pose_step_is_sqpnps_first_solution_as_solvepnpgeneric_gives_it(view):
    # solve_pose calls cv2.solvePnP, which skips solvePnPGeneric's reprojection errors; the pose must be the same
    # bits as solvePnPGeneric's first solution (what the descent used before), shapes off the answer included.
    rng = np.random.default_rng(4)
    for _ in range(5):
        s = random_scene(rng, view)
        problem = Problem.build(s.model, CAMERA, CAR, 0.1, 10.0)
        for p in (s.p_true, s.p_true * rng.uniform(0.7, 1.3, len(s.p_true))):
            X = np.ascontiguousarray(problem.A @ p, dtype=np.float64).reshape(-1, 1, 3)
            x = np.ascontiguousarray(problem.u[:, :2], dtype=np.float64).reshape(-1, 1, 2)
            n, rvecs, tvecs, _ = cv2.solvePnPGeneric(X, x, np.eye(3), None, flags=cv2.SOLVEPNP_SQPNP)
            assert n >= 1
            R, t = descent.solve_pose(problem, p)
            assert R.tobytes() == cv2.Rodrigues(rvecs[0])[0].tobytes()
            assert t.tobytes() == np.asarray(tvecs[0], dtype=float).ravel().tobytes()


def test_the_shape_steps_shared_terms_are_made_once_and_change_nothing():
    rng = np.random.default_rng(9)
    s = random_scene(rng, "oblique-front-left")
    problem = Problem.build(s.model, CAMERA, CAR, 0.1, 10.0)
    R = np.array([s.R_cam_vehicle, s.R_cam_vehicle.T @ s.R_cam_vehicle])
    first = descent.solve_shapes(problem, R)
    terms = descent._shape_terms(problem)
    assert descent._shape_terms(problem) is terms  # kept on the problem
    again = descent.solve_shapes(problem, R)
    fresh = descent.solve_shapes(Problem.build(s.model, CAMERA, CAR, 0.1, 10.0), R)
    for a, b, c in zip(first, again, fresh, strict=True):
        assert a.tobytes() == b.tobytes() == c.tobytes()
