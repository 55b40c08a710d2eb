import numpy as np
import pytest

from toosicubix.geometry import (
    R_LEVEL_VEHICLE,
    R_cam_vehicle_from_ypr,
    box2d_iou,
    box2d_of_points,
    clip_cuboid_to_near_plane,
    cross3,
    cuboid_corners_cam,
    cuboid_corners_vehicle,
    depth_reversed_twin,
    geodesic_angle,
    hat,
    nearest_rotation,
    project_pinhole,
    rot_y,
    so3_exp,
    so3_log,
    wrap_angle,
    ypr_from_R_cam_vehicle,
)

# Tolerance tiers: 1e-12 for closed-form algebra on O(1) numbers; 1e-9 where a trig function of an angle
# near pi or a sqrt of a small difference loses digits.


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    return so3_exp(rng.normal(size=3))


def test_hat_is_cross_product(rng):
    a, b = rng.normal(size=3), rng.normal(size=3)
    np.testing.assert_allclose(hat(a) @ b, np.cross(a, b), atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 0.5, 2.0, np.pi - 1e-6, np.pi - 1e-2])
def test_so3_exp_log_round_trip(rng, angle):
    for _ in range(5):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        omega = axis * angle
        R = so3_exp(omega)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(so3_log(R), omega, atol=1e-9)


def test_so3_exp_matches_rodrigues_about_y():
    np.testing.assert_allclose(so3_exp(np.array([0.0, 0.3, 0.0])), rot_y(0.3), atol=1e-12)


def test_geodesic_angle_small_and_large(rng):
    R = random_rotation(rng)
    for angle in (1e-8, 1e-3, 1.0, 3.0):
        axis = rng.normal(size=3)
        D = so3_exp(axis / np.linalg.norm(axis) * angle)
        # Accurate even for tiny angles, where arccos of the trace would lose half the digits.
        assert geodesic_angle(D @ R, R) == pytest.approx(angle, rel=1e-9, abs=1e-15)


def test_nearest_rotation_fixes_drift(rng):
    R = random_rotation(rng)
    noisy = R + 1e-6 * rng.normal(size=(3, 3))
    Q = nearest_rotation(noisy)
    np.testing.assert_allclose(Q @ Q.T, np.eye(3), atol=1e-12)
    assert geodesic_angle(Q, R) < 1e-5


def test_kitti_yaw_convention_matches_design():
    # DESIGN: R_cam_vehicle = R_y(ry) @ [[1,0,0],[0,0,-1],[0,1,0]]; ry = atan2(-f_z, f_x) with f = R e_x.
    ry = 0.7
    R = R_cam_vehicle_from_ypr(ry)
    np.testing.assert_allclose(R, rot_y(ry) @ R_LEVEL_VEHICLE, atol=1e-12)
    f = R[:, 0]
    assert np.arctan2(-f[2], f[0]) == pytest.approx(ry, abs=1e-12)
    # Vehicle up (Z) is camera -y; at ry = 0 the vehicle faces camera +x.
    np.testing.assert_allclose(R[:, 2], [0.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(R_cam_vehicle_from_ypr(0.0)[:, 0], [1.0, 0.0, 0.0], atol=1e-12)


def test_ypr_round_trip(rng):
    for _ in range(50):
        ry, pitch, roll = rng.uniform(-np.pi, np.pi), rng.uniform(-1.4, 1.4), rng.uniform(-np.pi, np.pi)
        got = ypr_from_R_cam_vehicle(R_cam_vehicle_from_ypr(ry, pitch, roll))
        np.testing.assert_allclose(got, [ry, pitch, roll], atol=1e-9)


def test_positive_pitch_lowers_the_nose():
    R = R_cam_vehicle_from_ypr(0.0, pitch=0.2)
    # Forward axis in camera coordinates gains +y (downward in the image).
    assert R[1, 0] > 0.0


def test_wrap_angle():
    np.testing.assert_allclose(wrap_angle(np.array([np.pi, -np.pi, 3 * np.pi / 2, 0.1])),
                               [-np.pi, -np.pi, -np.pi / 2, 0.1], atol=1e-12)


def test_cuboid_corners_vehicle_frame():
    corners = cuboid_corners_vehicle(np.array([4.0, 2.0, 1.5]))
    assert corners.shape == (8, 3)
    np.testing.assert_allclose(corners.min(axis=0), [-2.0, -1.0, 0.0])
    np.testing.assert_allclose(corners.max(axis=0), [2.0, 1.0, 1.5])
    # Bottom face first, front-left first (paper: top-right-front corner is (dx/2, -dy/2, dz)).
    np.testing.assert_allclose(corners[0], [2.0, 1.0, 0.0])
    np.testing.assert_allclose(corners[7], [2.0, -1.0, 1.5])


def test_cuboid_corners_cam_applies_pose(rng):
    R, t, d = random_rotation(rng), rng.normal(size=3), np.array([4.0, 2.0, 1.5])
    np.testing.assert_allclose(cuboid_corners_cam(R, t, d), cuboid_corners_vehicle(d) @ R.T + t, atol=1e-12)


def test_clip_to_near_plane_adds_edge_crossings():
    # Vehicle X along camera z, so the cuboid spans z in [-0.5, 1.5].
    R = R_cam_vehicle_from_ypr(-np.pi / 2)
    corners = cuboid_corners_cam(R, np.array([0.0, 0.0, 0.5]), np.array([2.0, 1.0, 1.0]))
    assert corners[:, 2].min() == pytest.approx(-0.5) and corners[:, 2].max() == pytest.approx(1.5)
    clipped = clip_cuboid_to_near_plane(corners, z_near=0.1)
    assert np.all(clipped[:, 2] >= 0.1 - 1e-12)
    assert len(clipped) == 4 + 4  # the 4 front corners and 4 crossings of the length-wise edges
    assert np.sum(np.isclose(clipped[:, 2], 0.1)) == 4


def test_project_pinhole():
    K = np.array([[500.0, 0.0, 320.0], [0.0, 400.0, 240.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(project_pinhole(K, np.array([[1.0, -2.0, 4.0]])), [[445.0, 40.0]], atol=1e-12)


def test_box2d_of_points_and_clipping():
    uv = np.array([[-10.0, 5.0], [50.0, 500.0], [20.0, 30.0]])
    np.testing.assert_allclose(box2d_of_points(uv), [-10.0, 5.0, 50.0, 500.0])
    np.testing.assert_allclose(box2d_of_points(uv, (40, 100)), [0.0, 5.0, 39.0, 99.0])


def test_box2d_iou_known_values():
    a = np.array([0.0, 0.0, 2.0, 2.0])
    assert box2d_iou(a, a) == pytest.approx(1.0)
    assert box2d_iou(a, np.array([1.0, 0.0, 3.0, 2.0])) == pytest.approx(2.0 / 6.0)
    assert box2d_iou(a, np.array([2.0, 0.0, 4.0, 2.0])) == 0.0  # touching
    assert box2d_iou(a, np.array([1.0, 1.0, 1.0, 3.0])) == 0.0  # degenerate partner


def test_depth_reversed_twin():
    """A rotation; each mirrored point of the twin is the pose's point reflected across the plane through the box
    centre perpendicular to the line of sight (exact); the twin of the twin is the pose; and seen from 60 m a
    keypoint and its mirror partner on the twin project within a few pixels."""
    R = R_cam_vehicle_from_ypr(0.7, 0.05, -0.03)
    t, d = np.array([3.0, 1.5, 60.0]), np.array([4.6, 1.8, 1.5])
    R_twin, t_twin = depth_reversed_twin(R, t, d)
    np.testing.assert_allclose(R_twin.T @ R_twin, np.eye(3), atol=1e-12)
    assert np.linalg.det(R_twin) == pytest.approx(1.0)
    centre = t + R[:, 2] * d[2] / 2
    sight = centre / np.linalg.norm(centre)
    points = d * np.array([[-0.46, 0.33, 0.51], [0.5, -0.3, 0.4], [0.1, 0.45, 0.95]])
    on_pose = points @ R.T + t
    reflected = on_pose - 2.0 * np.outer((on_pose - centre) @ sight, sight)
    np.testing.assert_allclose((points * [1.0, -1.0, 1.0]) @ R_twin.T + t_twin, reflected, atol=1e-12)
    R_back, t_back = depth_reversed_twin(R_twin, t_twin, d)
    np.testing.assert_allclose(R_back, R, atol=1e-12)
    np.testing.assert_allclose(t_back, t, atol=1e-12)
    K = np.array([[2300.0, 0.0, 1700.0], [0.0, 2300.0, 1350.0], [0.0, 0.0, 1.0]])
    apart = project_pinhole(K, on_pose) - project_pinhole(K, reflected)
    assert np.max(np.linalg.norm(apart, axis=1)) < 5.0  # the depth offsets are a few % of 60 m: a few px
    R_none, t_none = depth_reversed_twin(np.eye(3), np.array([0.0, 0.0, -0.75]), d)  # the box centre at the camera
    assert np.isnan(R_none).all() and np.isnan(t_none).all()


def test_cross3_is_numpy_cross_to_the_bit():
    """cross3 stands in for np.cross on the solver's hot path: every component must be the same double, across
    magnitudes, signs, zeros and non-finite values."""
    rng = np.random.default_rng(7)
    a = rng.normal(size=(4000, 3)) * 10.0 ** rng.integers(-12, 12, size=(4000, 3))
    b = rng.normal(size=(4000, 3)) * 10.0 ** rng.integers(-12, 12, size=(4000, 3))
    a[::97] = 0.0
    b[::89, 1] = np.inf
    a[::83, 2] = np.nan
    with np.errstate(invalid="ignore"):
        for x, y in zip(a, b, strict=True):
            assert np.cross(x, y).tobytes() == cross3(x, y).tobytes()
