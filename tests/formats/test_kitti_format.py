import math

import numpy as np
import pytest

from toosicubix.camera import Camera
from toosicubix.errors import FormatError
from toosicubix.formats.kitti import format_label_line, object_from_pose, parse_label_line, read_calib, read_label_file
from toosicubix.geometry import R_cam_vehicle_from_ypr, wrap_angle

# An invented KITTI-like P2: K [I | t2] with t2 about 6 cm along x (not zero, as in KITTI).
P2 = np.array([[720.0, 0.0, 620.0, 44.0], [0.0, 720.0, 180.0, 0.2], [0.0, 0.0, 1.0, 0.003]])


def test_camera_offset_from_P():
    camera = Camera.from_P(P2)
    np.testing.assert_allclose(camera.K @ camera.t_cam_rect, P2[:, 3], atol=1e-12)
    assert 0.05 < np.linalg.norm(camera.t_cam_rect) < 0.07


def test_pose_round_trips_through_P2_fourth_column_within_1mm(rng):
    camera = Camera.from_P(P2)
    for _ in range(50):
        ry = rng.uniform(-np.pi, np.pi)
        t_cam = np.array([rng.uniform(-20, 20), rng.uniform(1, 2), rng.uniform(3, 70)])
        d = rng.uniform([3.0, 1.4, 1.3], [12.0, 2.6, 3.5])
        obj = object_from_pose("Car", R_cam_vehicle_from_ypr(ry), t_cam, d, camera, np.array([1, 2, 30, 40.0]))
        back = parse_label_line(format_label_line(obj))
        # Written with 4 decimals (0.05 mm); the 6 cm offset t2 must not be lost either way.
        assert np.abs(back.t_cam_vehicle(camera.t_cam_rect) - t_cam).max() < 1e-3
        np.testing.assert_allclose(back.location_rect, t_cam - camera.t_cam_rect, atol=1e-4)
        np.testing.assert_allclose(back.dimensions, d, atol=1e-4)
        assert abs(wrap_angle(back.rotation_y - ry)) < 1e-6


def test_label_line_has_16_fields_score_last_single_spaces():
    obj = object_from_pose("Car", R_cam_vehicle_from_ypr(0.3), np.array([1.0, 1.6, 20.0]),
                           np.array([4.0, 1.7, 1.5]), Camera.from_P(P2), np.array([100.0, 150.0, 200.0, 220.0]),
                           truncated=0.25, score=0.875)
    line = format_label_line(obj)
    fields = line.split(" ")
    assert len(fields) == 16 and "" not in fields and "\t" not in line
    assert fields[0] == "Car" and fields[1] == "0.25" and fields[2] == "3"  # occlusion 3: unknown
    assert fields[-1] == "0.8750"
    assert [float(v) for v in fields[8:11]] == [1.5, 1.7, 4.0]  # h, w, l = dz, dy, dx


def test_alpha_is_yaw_minus_viewing_angle_of_the_written_location():
    camera = Camera.from_P(P2)
    obj = object_from_pose("Car", R_cam_vehicle_from_ypr(0.3), np.array([5.0, 1.6, 10.0]),
                           np.array([4.0, 1.7, 1.5]), camera, np.zeros(4))
    x, _, z = obj.location_rect
    assert obj.alpha == pytest.approx(wrap_angle(0.3 - math.atan2(x, z)), abs=1e-12)


def test_pitch_and_roll_are_dropped_in_kitti():
    R = R_cam_vehicle_from_ypr(0.4, pitch=0.05, roll=-0.03)
    obj = object_from_pose("Car", R, np.array([0.0, 1.6, 10.0]), np.ones(3), Camera.from_P(P2), np.zeros(4))
    assert obj.rotation_y == pytest.approx(0.4, abs=1e-12)
    np.testing.assert_allclose(obj.R_cam_vehicle, R_cam_vehicle_from_ypr(0.4), atol=1e-12)


def test_reader_rejects_malformed_lines(tmp_path):
    path = tmp_path / "000001.txt"
    path.write_text("Car 0 0 0 1 2 3 4 1.5 1.6 4 1 2 10 0.1\nCar 0 0 0 1 2 3 4 1.5 1.6\n")
    with pytest.raises(FormatError, match=r"000001.txt:2: expected 15 or 16 fields in a KITTI object label, got 10"):
        read_label_file(path)
    path.write_text("Car 0 0 0 1 2 3 4 1.5 abc 4 1 2 10 0.1\n")
    with pytest.raises(FormatError, match=r"000001.txt:1: expected numbers"):
        read_label_file(path)
    path.write_text("Car 0 0 0 1 2 3 4 1.5 0 4 1 2 10 0.1\n")
    with pytest.raises(FormatError, match="expected positive h, w, l"):
        read_label_file(path)


def test_calib_reader_object_and_tracking_styles(tmp_path):
    numbers = " ".join(str(v) for v in P2.ravel())
    obj_style = tmp_path / "a.txt"
    obj_style.write_text(f"P0: {numbers}\nP1: {numbers}\nP2: {numbers}\nP3: {numbers}\nR0_rect: 1 0 0 0 1 0 0 0 1\n")
    tracking_style = tmp_path / "b.txt"
    tracking_style.write_text(f"P0: {numbers}\nP1: {numbers}\nP2: {numbers}\nP3: {numbers}\nR_rect 1 0 0 0 1 0 0 0 1\n"
                              "Tr_velo_cam 1 0 0 0 0 1 0 0 0 0 1 0\n")
    for path in (obj_style, tracking_style):
        calib = read_calib(path)
        np.testing.assert_allclose(calib.P[2], P2)
        np.testing.assert_allclose(calib.R0_rect, np.eye(3))
    assert "Tr_velo_to_cam" in read_calib(tracking_style).extra
    missing = tmp_path / "c.txt"
    missing.write_text(f"P0: {numbers}\n")
    with pytest.raises(FormatError, match="expected a line 'P1:'"):
        read_calib(missing)


@pytest.mark.kitti_data
def test_real_kitti_labels_rewrite_identically(shared_data):
    """Every real label parses, and writing it back reproduces each value to the file's 2 decimals."""
    count = 0
    for path in sorted((shared_data / "kitti" / "label_2").glob("*.txt")):
        calib = read_calib(shared_data / "kitti" / "calib" / path.name)
        assert 0.05 < np.linalg.norm(calib.camera(2).t_cam_rect) < 0.07  # P2's 4th column is not zero
        for line, obj in zip(path.read_text().splitlines(), read_label_file(path), strict=True):
            values = [float(v) for v in line.split()[1:]]
            again = [float(v) for v in format_label_line(obj).split()[1:]]
            np.testing.assert_allclose(again, values, atol=5e-3)
            count += 1
    assert count == 193
