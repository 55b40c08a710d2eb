"""The person's 2D box (toosicubix.simulate.boxes): inside the projected cuboid's box, smaller where the body is,
at the border where the border cuts, seeded, None out of sight."""

import numpy as np
import pytest

from toosicubix.camera import Camera
from toosicubix.geometry import R_cam_vehicle_from_ypr
from toosicubix.simulate import annotator
from toosicubix.simulate.boxes import (
    SHAPE_RANGES,
    TYRE_INSET_MAX,
    body_family,
    body_pieces,
    draw_body_shape,
    person_error,
    projection_box2d,
    side_offsets,
    silhouette_box2d,
    simulated_box2d,
)

P2 = np.array([[721.5, 0.0, 609.6, 44.9], [0.0, 721.5, 172.9, 0.2], [0.0, 0.0, 1.0, 0.003]])
CAMERA = Camera.from_P(P2, image_size=(1242, 375))
WIDTH, HEIGHT = CAMERA.image_size
DIMENSIONS = {"Car": (4.2, 1.75, 1.5), "Van": (5.1, 1.95, 2.2), "Truck": (8.5, 2.5, 3.3)}


def random_pose(rng: np.random.Generator, near: bool = False) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """A prototype, a pose on a road 1.65 m below the camera (any yaw, a little pitch and roll) and dimensions
    scaled by up to 20 %; ``near``: anywhere from 5 m behind the camera to 40 m ahead."""
    prototype = str(rng.choice(list(DIMENSIONS)))
    d = np.array(DIMENSIONS[prototype]) * rng.uniform(0.8, 1.2, 3)
    R = R_cam_vehicle_from_ypr(rng.uniform(-np.pi, np.pi), rng.normal(0.0, 0.03), rng.normal(0.0, 0.03))
    t = np.array([rng.uniform(-20.0, 20.0), 1.65 + rng.normal(0.0, 0.1), rng.uniform(-5.0, 40.0) if near
                  else rng.uniform(4.0, 70.0)])
    return prototype, R, t, d


def test_every_family_builds_a_solid_inside_its_cuboid(rng):
    for prototype in ("Car", "Van", "Truck", "Tram", "Sedan"):
        for _ in range(50):
            d = np.array(DIMENSIONS.get(prototype, (4.5, 1.8, 1.6))) * rng.uniform(0.5, 1.5, 3)
            points = np.concatenate([p.reshape(-1, 3) for p in body_pieces(draw_body_shape(prototype, rng), d)])
            # 1e-12: the rings are built from the dimensions by a few products and sums.
            assert np.all(np.abs(points[:, :2]) <= d[:2] / 2 + 1e-12)
            assert np.all((points[:, 2] >= -1e-12) & (points[:, 2] <= d[2] + 1e-12))
            assert points[:, 2].min() == pytest.approx(0.0, abs=1e-12)  # the tyres stand on the ground
            assert points[:, 2].max() == pytest.approx(d[2], abs=1e-12)  # the roof reaches the full height
    assert [body_family(p) for p in ("Car", "Sedan", "Van", "Box Wagon", "Truck", "Tram")] == \
        ["car", "car", "van", "van", "truck", "truck"]


def test_the_silhouette_box_lies_inside_the_projected_cuboids_box(rng):
    """1,000 poses, some crossing the image border or the camera's near plane: the box before the person's error
    never leaves the projected cuboid's box (both are the extents of convex sets, one inside the other)."""
    boxed = 0
    for _ in range(1000):
        prototype, R, t, d = random_pose(rng, near=rng.uniform() < 0.3)
        projection = projection_box2d(R, t, d, CAMERA)
        silhouette = silhouette_box2d(R, t, d, draw_body_shape(prototype, rng), CAMERA)
        if projection is None:
            assert silhouette is None
            continue
        if silhouette is None:
            continue
        boxed += 1
        inward, _ = side_offsets(silhouette[0][None], projection[None])
        # 1e-6 px: both extents come from the same projection of points, one set inside the other's hull.
        assert np.all(inward >= -1e-6), (prototype, R, t, d, silhouette[0], projection)
    assert boxed > 500


def test_cars_seen_from_above_get_a_strictly_smaller_box(rng):
    """The camera 1.65 m above the road sees 1.5 m cars from above: the crowned, narrower roof brings the top side
    down, and the rounded corners and the roof pull in at least one side by 0.1 px or more (a tenth of a pixel is
    4 mm at 40 m)."""
    for _ in range(200):
        R = R_cam_vehicle_from_ypr(rng.uniform(-np.pi, np.pi))
        t = np.array([rng.uniform(-6.0, 6.0), 1.65, rng.uniform(6.0, 40.0)])
        d = np.array(DIMENSIONS["Car"])
        projection = projection_box2d(R, t, d, CAMERA)
        silhouette = silhouette_box2d(R, t, d, draw_body_shape("Car", rng), CAMERA)
        assert projection is not None and silhouette is not None
        inward, _ = side_offsets(silhouette[0][None], projection[None])
        assert inward[0, 1] > 0.0 and inward.max() > 0.1


def test_sides_the_image_border_cuts_stay_at_the_border(rng):
    """A car half out of the image on the left, one on the right and one below: the person's side there is exactly
    the border, whatever the noise; the other sides get the person's error."""
    R = R_cam_vehicle_from_ypr(0.3)
    for t, side, border in (((-9.0, 1.65, 10.0), 0, 0.0), ((9.5, 1.65, 10.0), 2, WIDTH - 1.0),
                            ((0.0, 1.65, 3.5), 3, HEIGHT - 1.0)):
        for seed in range(20):
            box = simulated_box2d(R, np.array(t), np.array(DIMENSIONS["Car"]), "Car", CAMERA,
                                  np.random.default_rng(seed))
            assert box is not None and box[side] == border
            assert projection_box2d(R, np.array(t), np.array(DIMENSIONS["Car"]), CAMERA)[side] == border
            assert np.all(box >= 0.0) and box[2] <= WIDTH - 1 and box[3] <= HEIGHT - 1


def test_a_person_box_is_seeded_rounded_and_ordered(rng):
    prototype, R, t, d = "Car", R_cam_vehicle_from_ypr(-0.7), np.array([2.0, 1.65, 15.0]), np.array(DIMENSIONS["Car"])
    first = simulated_box2d(R, t, d, prototype, CAMERA, np.random.default_rng(7))
    again = simulated_box2d(R, t, d, prototype, CAMERA, np.random.default_rng(7))
    other = simulated_box2d(R, t, d, prototype, CAMERA, np.random.default_rng(8))
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, other)
    np.testing.assert_array_equal(first, np.round(first, 1))
    assert first[2] > first[0] and first[3] > first[1]
    # The same solid given explicitly draws the same box: the shape comes first from the stream, then the error.
    stream = np.random.default_rng(7)
    shape = draw_body_shape(prototype, stream)
    np.testing.assert_array_equal(simulated_box2d(R, t, d, prototype, CAMERA, stream, shape=shape), first)


def test_the_persons_error_has_the_stated_spread(rng):
    """Each free side moves by N(0, 1 px + 1 % of the box's size on its axis); 4,000 draws of a 300 x 100 px box:
    sample deviations within 5 % of 4 px and 2 px (the standard error of a deviation of n draws is 1/sqrt(2n),
    1.1 % here)."""
    box, cut = np.array([100.0, 100.0, 400.0, 200.0]), np.zeros(4, dtype=bool)
    steps = np.array([person_error(box, cut, (1242, 375), rng) - box for _ in range(4000)])
    np.testing.assert_allclose(steps.std(axis=0), [4.0, 2.0, 4.0, 2.0], rtol=0.05)
    assert np.all(np.abs(steps.mean(axis=0)) < 0.2)


def test_nothing_behind_the_camera_or_outside_the_image_is_boxed():
    R, d = R_cam_vehicle_from_ypr(0.5), np.array(DIMENSIONS["Car"])
    for t in ((0.0, 1.65, -10.0), (0.0, 1.65, -3.0), (200.0, 1.65, 10.0), (0.0, -80.0, 10.0)):
        for kind in ("person", "projection"):
            assert simulated_box2d(R, np.array(t), d, "Car", CAMERA, np.random.default_rng(0), kind=kind) is None


def test_a_cuboid_reaching_behind_the_camera_is_cut_at_the_near_plane():
    """A car beside the camera, its rear behind it: the boxes are finite, clipped to the image, the silhouette's
    inside the projection's."""
    R, t, d = R_cam_vehicle_from_ypr(-np.pi / 2), np.array([-2.5, 1.65, 0.5]), np.array(DIMENSIONS["Car"])
    projection = projection_box2d(R, t, d, CAMERA)
    silhouette = silhouette_box2d(R, t, d, draw_body_shape("Car", np.random.default_rng(0)), CAMERA)
    assert projection is not None and silhouette is not None
    assert np.all(side_offsets(silhouette[0][None], projection[None])[0] >= -1e-6)


def test_bad_calls_are_refused():
    R, t, d = np.eye(3), np.array([0.0, 1.0, 10.0]), np.ones(3)
    with pytest.raises(ValueError, match="expected a box kind among person, projection"):
        simulated_box2d(R, t, d, "Car", CAMERA, np.random.default_rng(0), kind="amodal")
    with pytest.raises(ValueError, match="expected a camera with image_size"):
        simulated_box2d(R, t, d, "Car", Camera(K=CAMERA.K), np.random.default_rng(0))


def test_the_tyres_sit_as_the_click_simulator_puts_them():
    assert TYRE_INSET_MAX == annotator.TYRE_INSET_MAX
    assert SHAPE_RANGES["car"]["front_overhang_l"] == (0.17, 0.24)  # as simulate_vehicle's axles
    assert SHAPE_RANGES["car"]["rear_overhang_l"] == (0.18, 0.26)


@pytest.mark.kitti_data
def test_kittis_tracking_boxes_are_the_projected_cuboids(shared_data):
    """KITTI tracking's 2D boxes are its cuboids' clipped projections: 0.4 px apart (median) on sequence 0000."""
    from toosicubix.formats.datasets import KittiTrackingFolder
    from toosicubix.formats.kitti import read_tracking_file

    folder = KittiTrackingFolder(shared_data / "kitti_tracking")
    camera = folder.camera("0000")
    offsets = []
    for objs in read_tracking_file(folder.label_file("0000")).values():
        for obj in objs:
            if obj.type in ("Car", "Van", "Truck") and obj.location_rect[2] > 3.0:
                box = projection_box2d(obj.R_cam_vehicle, obj.t_cam_vehicle(camera.t_cam_rect), obj.dimensions,
                                       camera)
                offsets.append(np.abs(box - obj.box2d))
    assert len(offsets) > 500 and np.median(offsets) < 0.5 and np.percentile(offsets, 90) < 1.5
