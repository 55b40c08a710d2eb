"""One cuboid per track (:mod:`toosicubix.solver.track`) and its normal equations (:mod:`toosicubix.solver.blocks`).

Tolerances: 1e-12 for algebra (the block solver against dense numpy); 1e-6 for noise-free fits (exact clicks, an
exact size prior: the answer is the truth up to the Levenberg-Marquardt's stopping rule); finite differences of the
box cue's Jacobian to 1e-5 relative (central differences with a 1e-6 step).
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import CAMERA, _specs
from toosicubix.geometry import R_cam_vehicle_from_ypr, cuboid_corners_cam, geodesic_angle, so3_exp
from toosicubix.parts.linear import build_parts_model
from toosicubix.parts.synthesis import render_parts
from toosicubix.size_priors import SizePrior
from toosicubix.solver.blocks import BlockArrow
from toosicubix.solver.fit import SolverOptions
from toosicubix.solver.track import TrackFrame, TrackOptions, box_residuals, fit_track, upright_on

D = np.array([4.3, 1.8, 1.5])
EXACT_PRIOR = SizePrior.from_mean_cov("Car", D, np.diag([1e-6, 1e-6, 1e-6]))
#: Exact clicks stand for a click-noise variance near zero (lambda_p is that variance in px^2).
EXACT = SolverOptions(lambda_px=1e-9)


def _truth(f: int) -> tuple[np.ndarray, np.ndarray]:
    """A vehicle turning at a constant rate and moving at a constant velocity relative to the camera."""
    t = np.array([-3.0, 1.6, 15.0]) + np.array([0.05, 0.0, 0.3]) * f
    return R_cam_vehicle_from_ypr(3 * np.pi / 4 + 0.02 * f), t


def _track(frames: int, clicked, boxed, seed: int = 0) -> list[TrackFrame]:
    rng = np.random.default_rng(seed)
    specs = _specs("oblique-front-left", D, rng)
    wheel_x = (0.32 * D[0], -0.3 * D[0])
    out = []
    for f in range(frames):
        R, t = _truth(f)
        parts = render_parts(specs, R, t, D, CAMERA, wheel_x) if f in clicked else []
        box = None
        if f in boxed:
            uv = CAMERA.project(cuboid_corners_cam(R, t, D))
            box = np.array([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()])
        out.append(TrackFrame(f, build_parts_model(parts), CAMERA, None, box))
    return out


def _errors(fit, frames: list[TrackFrame]) -> tuple[float, float]:
    pairs = list(zip(fit.frames, frames, strict=True))
    t_err = max(float(np.linalg.norm(r.t_cam_vehicle - _truth(f.frame)[1])) for r, f in pairs)
    R_err = max(float(geodesic_angle(r.R_cam_vehicle, _truth(f.frame)[0])) for r, f in pairs)
    return t_err, R_err


def test_a_track_is_recovered_exactly_from_noise_free_keyframe_clicks_and_boxes():
    frames = _track(21, clicked={0, 10, 20}, boxed=set(range(21)) - {0, 10, 20, 5, 15})
    fit = fit_track(frames, EXACT_PRIOR, EXACT)
    assert fit.ok, fit.reason
    t_err, R_err = _errors(fit, frames)
    assert t_err < 1e-6 and R_err < 1e-6
    np.testing.assert_allclose(fit.dimensions, D, atol=1e-6)
    assert [r.pose_from for r in fit.frames][:6] == ["clicks", "box", "box", "box", "box", "interpolated"]
    # One size for the whole track: every frame's parameters start with it.
    assert all(np.allclose(r.p[:3], fit.dimensions) for r in fit.frames)


def test_interpolation_between_two_clicked_frames_of_a_constant_velocity_vehicle_is_exact():
    frames = _track(11, clicked={0, 10}, boxed=set())
    fit = fit_track(frames, EXACT_PRIOR, EXACT)
    assert fit.ok, fit.reason
    t_err, R_err = _errors(fit, frames)
    assert t_err < 1e-6 and R_err < 1e-6
    assert [r.pose_from for r in fit.frames] == ["clicks"] + ["interpolated"] * 9 + ["clicks"]


def test_frames_given_in_any_order_keep_their_order():
    frames = _track(11, clicked={0, 10}, boxed={3})
    shuffled = [frames[i] for i in (7, 0, 10, 3, 1, 2, 4, 5, 6, 8, 9)]
    fit = fit_track(shuffled, EXACT_PRIOR, EXACT)
    assert [r.pose_from for r in fit.frames][:4] == ["interpolated", "clicks", "clicks", "box"]
    t_err, _ = _errors(fit, shuffled)
    assert t_err < 1e-6


def test_sigmas_grow_away_from_the_clicked_frames():
    frames = _track(21, clicked={0, 20}, boxed=set())
    fit = fit_track(frames, SizePrior.from_mean_cov("Car", D, np.diag([0.04, 0.01, 0.01])), SolverOptions())
    depth = np.array([r.uncertainty.depth_m for r in fit.frames])
    yaw = np.array([r.uncertainty.yaw_deg for r in fit.frames])
    assert depth[10] > 1.05 * max(depth[0], depth[20]) and yaw[10] > 1.05 * max(yaw[0], yaw[20])
    assert np.all(np.diff(yaw[2:11]) > 0)  # growing from beside a clicked frame to the middle


def test_a_track_without_a_frame_its_clicks_fix_fails_with_a_reason():
    frames = _track(5, clicked=set(), boxed=set(range(5)))
    fit = fit_track(frames, EXACT_PRIOR, EXACT)
    assert not fit.ok and "no frame has clicks" in fit.reason and "click one frame" in fit.reason


def test_the_box_cues_jacobian_matches_central_differences():
    """Away from ties (a level vehicle's top and bottom corners of one vertical edge project to the same column:
    the extreme's corner changes there, and a derivative is one-sided), pitched and rolled a little."""
    rng = np.random.default_rng(3)
    R, t = R_cam_vehicle_from_ypr(3 * np.pi / 4, 0.05, -0.03), _truth(4)[1]
    box = np.array([400.0, 150.0, 700.0, 260.0])
    r, J = box_residuals(CAMERA.K, box, R, t, D)
    _assert_central_differences(J, box, R, t, None)
    assert rng is not None and np.all(np.isfinite(r))


def _assert_central_differences(J: np.ndarray, box: np.ndarray, R: np.ndarray, t: np.ndarray,
                                up: np.ndarray | None) -> None:
    """``J`` (4, 9), :func:`box_residuals`' Jacobian at ``(R, t, D)``, against central differences of its residuals
    (steps of 1e-6: rounding at 1e-10 of pixels in the tens, well inside the 1e-5 tolerance)."""
    x = np.concatenate([np.zeros(3), t, D])
    step = 1e-6
    for k in range(9):
        e = np.zeros(9)
        e[k] = step

        def at(v):
            return box_residuals(CAMERA.K, box, R @ so3_exp(v[:3]), v[3:6], v[6:9], False, up)[0]

        numeric = (at(x + e) - at(x - e)) / (2 * step)
        np.testing.assert_allclose(J[:, k], numeric, rtol=1e-5, atol=1e-5 * (1 + np.abs(numeric).max()))


#: A road normal a degree off the camera's -y, camera frame.
ROAD_UP = np.array([0.01, -1.0, 0.013]) / np.linalg.norm([0.01, -1.0, 0.013])


def test_on_a_road_the_box_rows_do_not_see_the_lean_and_their_jacobian_holds():
    """Rule 28: on a road the box rows project the cuboid stood upright on it. Pitching or rolling the vehicle then
    leaves them as they are (to rounding), turning it about the road's normal does not, and the Jacobian (the
    heading's derivative taken through the projection onto the road) matches central differences."""
    R, t = R_cam_vehicle_from_ypr(3 * np.pi / 4, 0.05, -0.03), _truth(4)[1]
    box = np.array([400.0, 150.0, 700.0, 260.0])
    r, J = box_residuals(CAMERA.K, box, R, t, D, up=ROAD_UP)
    upright, _ = upright_on(R, ROAD_UP)
    np.testing.assert_allclose(box_residuals(CAMERA.K, box, upright, t, D, False)[0], r, atol=1e-9)
    for lean in ([0.03, 0.0, 0.0], [0.0, -0.04, 0.0]):  # a roll, a pitch (its own axes) of an upright vehicle
        leaned, _ = box_residuals(CAMERA.K, box, upright @ so3_exp(np.array(lean)), t, D, False, ROAD_UP)
        np.testing.assert_allclose(leaned, r, atol=1e-9)
    turned, _ = box_residuals(CAMERA.K, box, so3_exp(0.02 * ROAD_UP) @ R, t, D, False, ROAD_UP)
    assert np.abs(turned - r).max() > 0.5  # 0.02 rad of heading moves a side of a 15 m car by pixels
    assert J[:, 0].tolist() == [0.0] * 4
    _assert_central_differences(J, box, R, t, ROAD_UP)


def test_upright_on_keeps_the_heading_and_takes_the_roads_up_axis():
    R = R_cam_vehicle_from_ypr(0.7, 0.04, -0.02)
    R_up, _ = upright_on(R, ROAD_UP)
    np.testing.assert_allclose(R_up.T @ R_up, np.eye(3), atol=1e-12)
    assert np.linalg.det(R_up) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(R_up[:, 2], ROAD_UP, atol=1e-12)
    # The forward axis turns only toward the road: it stays in the plane of R's forward axis and the normal.
    assert abs(np.cross(R[:, 0], ROAD_UP) @ R_up[:, 0]) < 1e-12
    assert R_up[:, 0] @ R[:, 0] > np.cos(0.06)


def test_a_track_on_a_road_is_recovered_exactly_from_keyframe_clicks_and_boxes():
    """With a road whose normal is the vehicle's up axis (the truth is upright on it), the upright box rows are
    exact too: the noise-free track comes back to rounding."""
    from toosicubix.model import GroundPlane

    up = _truth(0)[0][:, 2]
    ground = GroundPlane(up, np.radians(3.0), None, 0.1, np.radians(2.0), from_batch=True)
    frames = [TrackFrame(f.frame, f.parts, f.camera, ground, f.box2d)
              for f in _track(11, clicked={0, 10}, boxed=set(range(1, 10)))]
    fit = fit_track(frames, EXACT_PRIOR, EXACT)
    assert fit.ok, fit.reason
    t_err, R_err = _errors(fit, frames)
    assert t_err < 1e-6 and R_err < 1e-6


def test_block_arrow_solves_and_inverts_as_dense_algebra():
    rng = np.random.default_rng(0)
    sizes, s = [3, 5, 2, 4, 6], 3
    n = sum(sizes) + s
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    H, g = np.zeros((n, n)), np.zeros(n)
    system = BlockArrow(sizes, s)
    for _ in range(40):
        k = int(rng.integers(0, len(sizes) - 1))
        m = int(rng.integers(1, 6))
        r = rng.normal(size=m)
        J_k = rng.normal(size=(m, sizes[k]))
        J_next = rng.normal(size=(m, sizes[k + 1])) if rng.random() < 0.6 else None
        J_border = rng.normal(size=(m, s)) if rng.random() < 0.5 else None
        system.add(r, k, J_k, J_next, J_border)
        J = np.zeros((m, n))
        J[:, offsets[k]:offsets[k + 1]] = J_k
        if J_next is not None:
            J[:, offsets[k + 1]:offsets[k + 2]] = J_next
        if J_border is not None:
            J[:, offsets[-1]:] = J_border
        H += J.T @ J
        g += J.T @ r
    damping = 0.3
    chain, border = system.solve(damping, floor=0.0)
    H_damped = H + damping * np.diag(np.diag(H))
    np.testing.assert_allclose(np.concatenate([*chain, border]), np.linalg.solve(H_damped, -g), atol=1e-12)
    blocks, cross, corner = system.marginals(ridge=0.0)
    inverse = np.linalg.inv(H)
    for k in range(len(sizes)):
        np.testing.assert_allclose(blocks[k], inverse[offsets[k]:offsets[k + 1], offsets[k]:offsets[k + 1]], atol=1e-12)
        np.testing.assert_allclose(cross[k], inverse[offsets[k]:offsets[k + 1], offsets[-1]:], atol=1e-12)
    np.testing.assert_allclose(corner, inverse[offsets[-1]:, offsets[-1]:], atol=1e-12)


@pytest.mark.parametrize("frames", [3, 40])
def test_the_frame_rate_is_the_motion_models_clock(frames):
    """The same track fitted at twice the frame rate with frame numbers twice as large gives the same poses."""
    track = _track(frames, clicked={0, frames - 1}, boxed={1})
    doubled = [TrackFrame(2 * f.frame, f.parts, f.camera, f.ground, f.box2d) for f in track]
    a = fit_track(track, EXACT_PRIOR, SolverOptions())
    b = fit_track(doubled, EXACT_PRIOR, SolverOptions(), TrackOptions(frame_rate=20.0))
    for x, y in zip(a.frames, b.frames, strict=True):
        np.testing.assert_allclose(x.t_cam_vehicle, y.t_cam_vehicle, atol=1e-6)
