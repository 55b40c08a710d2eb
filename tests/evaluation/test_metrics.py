"""Per-object metrics of the paper: IoU, sIoU, E_R, E_t, E_d, E_comb.

Tolerance 1e-12: every expected value is closed-form and the computations are a handful of float64
operations (the IoU through Qhull is exact to rounding at metre scale).
"""

from __future__ import annotations

import numpy as np
import pytest

from toosicubix.evaluation.metrics import (
    METRIC_NAMES,
    ObjectMetrics,
    combined_error,
    dimension_error,
    object_metrics,
    rotation_error_deg,
    scale_factor,
    scaled_iou,
    translation_error,
    yaw_error_deg,
)
from toosicubix.geometry import Cuboid, R_cam_vehicle_from_ypr, so3_exp

GT = Cuboid(R_cam_vehicle_from_ypr(0.4, 0.02, -0.01), [3.0, 1.6, 20.0], [4.2, 1.8, 1.5])


def test_identical_prediction_has_zero_errors_and_iou_one():
    m = object_metrics(GT, GT)
    assert m.iou == pytest.approx(1.0, abs=1e-12)
    assert m.siou == pytest.approx(1.0, abs=1e-12)
    assert m.iou_kitti == pytest.approx(1.0, abs=1e-12)
    assert (m.e_r_deg, m.e_t, m.e_d, m.e_comb) == (0.0, 0.0, 0.0, 0.0)


def test_moved_by_a_known_vector():
    shift = 0.6
    v = shift * GT.R_cam_vehicle[:, 0]  # along the vehicle's length: I = V (1 - shift / l)
    m = object_metrics(GT.translated(v), GT)
    l_ = GT.dimensions[0]
    assert m.iou == pytest.approx((l_ - shift) / (l_ + shift), abs=1e-12)
    assert m.e_t == pytest.approx(shift / np.linalg.norm(GT.t_cam_vehicle), abs=1e-12)
    assert m.e_r_deg == 0.0 and m.e_d == 0.0
    assert m.e_comb == pytest.approx(m.e_t / 3.0, abs=1e-12)


@pytest.mark.parametrize("angle_deg", [0.5, 7.0, 90.0, 179.0])
def test_rotated_by_a_known_angle(angle_deg):
    axis = np.array([0.2, -0.6, 0.77]) / np.linalg.norm([0.2, -0.6, 0.77])
    pred = Cuboid(GT.R_cam_vehicle @ so3_exp(np.deg2rad(angle_deg) * axis), GT.t_cam_vehicle, GT.dimensions)
    m = object_metrics(pred, GT)
    # geodesic_angle is accurate to ~1e-15 rad everywhere, 1e-12 deg leaves ample room.
    assert m.e_r_deg == pytest.approx(angle_deg, abs=1e-12)
    assert m.e_comb == pytest.approx(angle_deg / 180.0 / 3.0, abs=1e-12)
    assert rotation_error_deg(GT.R_cam_vehicle, pred.R_cam_vehicle) == pytest.approx(angle_deg, abs=1e-12)


def test_backwards_vehicle_is_180_degrees():
    pred = Cuboid(GT.R_cam_vehicle @ so3_exp([0.0, 0.0, np.pi]), GT.t_cam_vehicle, GT.dimensions)
    assert rotation_error_deg(pred.R_cam_vehicle, GT.R_cam_vehicle) == pytest.approx(180.0, abs=1e-12)


def test_dimension_and_translation_errors():
    assert dimension_error([4.4, 1.8, 1.5], [4.0, 1.8, 1.5]) == pytest.approx(0.4 / np.linalg.norm([4, 1.8, 1.5]))
    assert dimension_error(1.1 * GT.dimensions, GT.dimensions) == pytest.approx(0.1, abs=1e-12)
    assert translation_error([0.0, 0.0, 22.0], [0.0, 0.0, 20.0]) == pytest.approx(0.1, abs=1e-12)
    assert combined_error(0.4, 0.6, 90.0) == pytest.approx(0.5, abs=1e-12)


def test_scaled_iou_removes_the_scale_ambiguity():
    """A prediction scaled about the camera centre projects identically: sIoU 1, IoU < 1."""
    pred = GT.scaled(0.8)
    assert scale_factor(pred.t_cam_vehicle, GT.t_cam_vehicle) == pytest.approx(1.25, abs=1e-12)
    assert scaled_iou(pred, GT) == pytest.approx(1.0, abs=1e-12)
    m = object_metrics(pred, GT)
    assert m.iou < 0.9
    assert m.e_t == pytest.approx(0.2, abs=1e-12) and m.e_d == pytest.approx(0.2, abs=1e-12)


def test_scale_factor_of_a_zero_translation_is_one():
    assert scale_factor(np.zeros(3), GT.t_cam_vehicle) == 1.0


def test_metric_names_match_the_record():
    assert set(METRIC_NAMES) == set(ObjectMetrics.__dataclass_fields__)


def test_yaw_error_is_the_kitti_yaw_difference_alone_wrapped():
    ry = np.deg2rad
    # Pitch and roll add to E_R but not to the yaw error.
    pred = R_cam_vehicle_from_ypr(ry(40.0), ry(5.0), ry(-3.0))
    truth = R_cam_vehicle_from_ypr(ry(10.0), 0.0, 0.0)
    assert yaw_error_deg(pred, truth) == pytest.approx(30.0, abs=1e-12)
    assert rotation_error_deg(pred, truth) > 30.0
    # Across the +-180 seam: 175 and -175 degrees are 10 apart; a vehicle turned around is 180 off.
    assert yaw_error_deg(R_cam_vehicle_from_ypr(ry(175.0), 0.0, 0.0),
                         R_cam_vehicle_from_ypr(ry(-175.0), 0.0, 0.0)) == pytest.approx(10.0, abs=1e-9)
    assert yaw_error_deg(R_cam_vehicle_from_ypr(ry(90.0), 0.0, 0.0),
                         R_cam_vehicle_from_ypr(ry(-90.0), 0.0, 0.0)) == pytest.approx(180.0, abs=1e-9)
    assert object_metrics(GT, GT).e_yaw_deg == 0.0
