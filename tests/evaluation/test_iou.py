"""Exact 3D IoU with full rotations, and KITTI's yaw-only variant.

Tolerances: 1e-12 for closed-form answers (a few dozen float64 operations plus Qhull's vertices,
which are exact to rounding at metre scale); Monte Carlo comparisons use 4 standard errors.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull, HalfspaceIntersection
from scipy.spatial.transform import Rotation

from toosicubix.evaluation.iou import (
    chebyshev_centre,
    convex_polygon_intersection_area,
    cuboid_halfspaces,
    intersection_volume_3d,
    iou_3d,
    iou_bev_height_yaw,
    polygon_area,
)
from toosicubix.geometry import Cuboid, R_cam_vehicle_from_ypr, so3_exp

I3 = np.eye(3)


def cube(centre, side: float = 1.0, R=I3) -> Cuboid:
    return Cuboid.from_centre(R, centre, [side, side, side])


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """Uniform on SO(3)."""
    return Rotation.random(random_state=rng).as_matrix()


# --- DESIGN section 5 reference values (from pytorch3d's tests) ----------------------------------------------

def test_unit_cube_with_itself_is_one():
    assert iou_3d(cube([0, 0, 0]), cube([0, 0, 0])) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("shift", [(0.1, 0.2, 0.3), (0.5, 0.0, 0.0), (0.0, 0.25, 0.75), (0.9, 0.01, 0.3)])
def test_shifted_unit_cube(shift):
    inter = (1 - shift[0]) * (1 - shift[1]) * (1 - shift[2])
    assert intersection_volume_3d(cube([0, 0, 0]), cube(shift)) == pytest.approx(inter, abs=1e-12)
    assert iou_3d(cube([0, 0, 0]), cube(shift)) == pytest.approx(inter / (2 - inter), abs=1e-12)


def test_unit_cube_shifted_by_half_its_side_is_one_third():
    assert iou_3d(cube([0, 0, 0]), cube([0.5, 0, 0])) == pytest.approx(1 / 3, abs=1e-12)


def test_side_two_cubes_at_origin_and_minus_one_one_zero():
    a, b = cube([0, 0, 0], 2.0), cube([-1, 1, 0], 2.0)
    assert intersection_volume_3d(a, b) == pytest.approx(2.0, abs=1e-12)
    assert iou_3d(a, b) == pytest.approx(2.0 / 14.0, abs=1e-12)


# --- special configurations -----------------------------------------------------------------------------------

def test_nested_box_iou_is_the_volume_ratio(rng):
    R = random_rotation(rng)
    outer = Cuboid(R, [1.0, 2.0, 10.0], [4.0, 2.0, 1.6])
    # Same axes, same bottom centre, smaller in every direction: wholly inside.
    inner = Cuboid(R, outer.t_cam_vehicle + 0.1 * R[:, 2], [2.0, 1.0, 1.0])
    assert iou_3d(outer, inner) == pytest.approx(inner.volume / outer.volume, abs=1e-12)


@pytest.mark.parametrize("offset", [(1, 0, 0), (0, -1, 0), (1, 1, 0), (1, 1, 1), (0, 0, 1)])
def test_touching_boxes_give_zero_without_exception(offset):
    """Face, edge and corner contact: the intersection has no volume."""
    assert iou_3d(cube([0, 0, 0]), cube(offset)) == 0.0


def test_touching_rotated_boxes_give_zero(rng):
    R = random_rotation(rng)
    d = np.array([4.0, 1.8, 1.5])
    a = Cuboid(R, [0.0, 0.0, 12.0], d)
    b = Cuboid(so3_exp(R[:, 0] * 0.3) @ R, a.t_cam_vehicle + d[0] * R[:, 0], d)  # front face to rear face
    assert iou_3d(a, b) == pytest.approx(0.0, abs=1e-12)


def test_disjoint_boxes_give_zero(rng):
    assert iou_3d(cube([0, 0, 0]), cube([5, 0, 0])) == 0.0
    # Inside each other's bounding spheres but separated by a plane: the linear programme decides.
    R = so3_exp(np.array([0.0, 0.0, np.pi / 4]))
    assert iou_3d(cube([0, 0, 0]), cube([1.3, 0.9, 0.0], R=R)) == 0.0


def test_degenerate_box_gives_zero():
    assert iou_3d(cube([0, 0, 0]), Cuboid(I3, [0, 0, 0], [1.0, 0.0, 1.0])) == 0.0


def test_slivers_are_exact(rng):
    """Overlaps down to 1e-8 of the side are still measured: I = eps for unit cubes."""
    for eps in (1e-8, 1e-6, 1e-3):
        assert intersection_volume_3d(cube([0, 0, 0]), cube([1 - eps, 0, 0])) == pytest.approx(eps, rel=1e-6)


def test_far_from_origin_loses_nothing():
    far = np.array([1e5, -2e4, 3e4])
    assert iou_3d(cube(far), cube(far + np.array([0.5, 0.0, 0.0]))) == pytest.approx(1 / 3, abs=1e-9)


def test_symmetric_and_invariant_under_a_common_rigid_motion(rng):
    for _ in range(5):
        a = Cuboid(random_rotation(rng), rng.normal(size=3), rng.uniform(0.5, 3.0, 3))
        b = Cuboid(random_rotation(rng), a.t_cam_vehicle + 0.5 * rng.normal(size=3), rng.uniform(0.5, 3.0, 3))
        Q, s = random_rotation(rng), rng.normal(size=3) * 10
        a2 = Cuboid(Q @ a.R_cam_vehicle, Q @ a.t_cam_vehicle + s, a.dimensions)
        b2 = Cuboid(Q @ b.R_cam_vehicle, Q @ b.t_cam_vehicle + s, b.dimensions)
        v = iou_3d(a, b)
        assert iou_3d(b, a) == pytest.approx(v, abs=1e-12)
        assert iou_3d(a2, b2) == pytest.approx(v, abs=1e-10)


def test_not_the_yaw_only_shortcut():
    """A pitched box: the exact IoU sees the pitch, KITTI's yaw-only IoU does not."""
    a = Cuboid(R_cam_vehicle_from_ypr(0.3), [0.0, 1.6, 10.0], [4.0, 1.7, 1.5])
    b = Cuboid(R_cam_vehicle_from_ypr(0.3, pitch=np.deg2rad(20.0)), a.t_cam_vehicle, a.dimensions)
    assert iou_bev_height_yaw(a, b) == pytest.approx(1.0, abs=1e-12)
    assert iou_3d(a, b) < 0.8


# --- Monte Carlo -------------------------------------------------------------------------------------------------

def test_random_rotated_boxes_against_monte_carlo(rng):
    """Sample N points uniformly in box a; the fraction f inside b estimates I / V_a with standard error
    sqrt(f (1 - f) / N). The exact intersection must lie within 4 standard errors (plus 1e-12)."""
    n = 60_000
    checked = 0
    for _ in range(12):
        a = Cuboid(random_rotation(rng), rng.normal(size=3), rng.uniform(0.5, 2.5, 3))
        b = Cuboid.from_centre(random_rotation(rng), a.centre + rng.uniform(-0.5, 0.5, 3) * a.dimensions.max(),
                               rng.uniform(0.5, 2.5, 3))
        local = rng.uniform(-0.5, 0.5, size=(n, 3)) * a.dimensions
        points = local @ a.R_cam_vehicle.T + a.centre
        in_b = np.all(np.abs((points - b.centre) @ b.R_cam_vehicle) <= b.dimensions / 2.0, axis=1)
        f = in_b.mean()
        se = np.sqrt(max(f * (1.0 - f), 1.0 / n) / n)
        exact = intersection_volume_3d(a, b)
        assert abs(exact - f * a.volume) <= 4.0 * se * a.volume + 1e-12
        checked += f > 0.05
    assert checked >= 4  # enough pairs with real overlap to make the comparison meaningful


def test_centre_shortcut_and_chebyshev_centre_give_the_same_volume(rng):
    """The interior point only seeds Qhull: a box centre (fast path) and the Chebyshev centre agree."""
    for _ in range(10):
        a = Cuboid(random_rotation(rng), rng.normal(size=3), rng.uniform(0.5, 2.5, 3))
        b = Cuboid.from_centre(random_rotation(rng), a.centre + 0.2 * rng.normal(size=3), rng.uniform(0.5, 2.5, 3))
        halfspaces = np.concatenate([cuboid_halfspaces(c.R_cam_vehicle, c.centre, c.dimensions / 2) for c in (a, b)])
        centre, radius = chebyshev_centre(halfspaces)
        assert radius > 0.0
        reference = ConvexHull(HalfspaceIntersection(halfspaces, centre).intersections).volume
        assert intersection_volume_3d(a, b) == pytest.approx(reference, rel=1e-12, abs=1e-12)


# --- KITTI yaw-only IoU -----------------------------------------------------------------------------------------

def test_yaw_only_iou_equals_exact_iou_for_upright_boxes(rng):
    """For zero pitch and roll both measure the same polytope: two independent implementations agree."""
    for _ in range(20):
        a = Cuboid(R_cam_vehicle_from_ypr(rng.uniform(-np.pi, np.pi)), [0.0, 1.6, 10.0], rng.uniform(1.0, 5.0, 3))
        b = Cuboid(R_cam_vehicle_from_ypr(rng.uniform(-np.pi, np.pi)),
                   a.t_cam_vehicle + rng.normal(size=3) * [1.0, 0.3, 1.0], rng.uniform(1.0, 5.0, 3))
        assert iou_bev_height_yaw(a, b) == pytest.approx(iou_3d(a, b), abs=1e-10)


def test_yaw_only_iou_known_values():
    a = Cuboid(R_cam_vehicle_from_ypr(0.0), [0.0, 1.6, 10.0], [4.0, 2.0, 1.5])
    assert iou_bev_height_yaw(a, a) == pytest.approx(1.0, abs=1e-12)
    # Shifted half its length along camera x (its forward axis at ry = 0): IoU 1/3.
    assert iou_bev_height_yaw(a, a.translated([2.0, 0.0, 0.0])) == pytest.approx(1 / 3, abs=1e-12)
    # Lifted by its full height: touching, 0.
    assert iou_bev_height_yaw(a, a.translated([0.0, -1.5, 0.0])) == 0.0
    # Turned by 90 degrees about the vertical: footprints 4x2 and 2x4 cross in 2x2.
    b = Cuboid(R_cam_vehicle_from_ypr(np.pi / 2), a.t_cam_vehicle, a.dimensions)
    assert iou_bev_height_yaw(a, b) == pytest.approx(4.0 / 12.0, abs=1e-12)


def test_convex_polygon_intersection():
    square = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], dtype=float)
    # |x - 1| + |y - 1| <= 1.5 cuts a right triangle with legs 0.5 (area 1/8) off each corner of the square.
    diamond = np.array([[1, -0.5], [2.5, 1], [1, 2.5], [-0.5, 1]], dtype=float)
    assert polygon_area(square) == 4.0
    assert polygon_area(square[::-1]) == -4.0
    assert convex_polygon_intersection_area(square, diamond) == pytest.approx(3.5, abs=1e-12)
    assert convex_polygon_intersection_area(square[::-1], diamond) == pytest.approx(3.5, abs=1e-12)
    assert convex_polygon_intersection_area(square, square + 5.0) == 0.0
