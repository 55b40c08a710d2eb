"""eval pairs and scores each class of road users (issue 35): pairing within one family, a breakdown by class with
each class's heading error, Cityscapes 3D's bicycles."""

from __future__ import annotations

import numpy as np
import pytest

from tests.eval_scenes import (
    CITYSCAPES_SCENE,
    K_CS,
    K_KITTI,
    KITTI_SIZE,
    T2,
    KittiBox,
    Pose,
    calib_text,
    cam_pose,
    kitti_line,
    kitti_pose,
    rotated,
    write_cityscapes,
    write_results,
)
from toosicubix.evaluation import evaluate_folder
from toosicubix.evaluation.evaluate import EvalOptions
from toosicubix.evaluation.metrics import heading_error_deg
from toosicubix.evaluation.report import class_breakdown, format_report, result_to_json

PERSON = KittiBox("Pedestrian", (1.84, 1.47, 8.41), (0.8, 0.66, 1.75), -0.2)
CYCLIST = KittiBox("Cyclist", (-3.2, 1.55, 12.3), (1.76, 0.6, 1.73), 1.1)
CAR = KittiBox("Car", (-6.5, 1.65, 14.2), (3.9, 1.62, 1.5), 0.3)


def _ground_truth(root, boxes):
    (root / "label_2").mkdir(parents=True)
    (root / "calib").mkdir()
    (root / "label_2" / "000001.txt").write_text("\n".join(kitti_line(b) for b in boxes) + "\n")
    (root / "calib" / "000001.txt").write_text(calib_text())
    return root


def test_a_prediction_is_paired_within_its_family_only(tmp_path):
    """A pedestrian fit whose 2D box is exactly a car's is no car: it stays unmatched, and so does the car."""
    gt = _ground_truth(tmp_path / "gt", [CAR, PERSON])
    impostor = Pose(PERSON.R_cam_vehicle, PERSON.t_cam(), np.array(PERSON.lwh), CAR.box2d(), "Pedestrian")
    out = write_results(tmp_path / "out", {"000001": [impostor]}, K_KITTI, T2, KITTI_SIZE)
    result = evaluate_folder(out, "kitti", gt, EvalOptions(classes=("Car", "Pedestrian")))
    assert result.matched == ()
    assert [u.cls for u in result.unmatched_pred] == ["Pedestrian"]
    assert sorted(u.cls for u in result.unmatched_gt) == ["Car", "Pedestrian"]


def test_each_class_is_scored_with_its_heading_error(tmp_path):
    """Exact car and cyclist, a pedestrian turned by 20 degrees about its up axis: the class rows say so."""
    gt = _ground_truth(tmp_path / "gt", [CAR, PERSON, CYCLIST])
    person = rotated(kitti_pose(PERSON), np.array([0.0, 0.0, np.deg2rad(20.0)]))
    out = write_results(tmp_path / "out", {"000001": [kitti_pose(CAR), person, kitti_pose(CYCLIST)]}, K_KITTI, T2,
                        KITTI_SIZE)
    result = evaluate_folder(out, "kitti", gt, EvalOptions(classes=("Car", "Pedestrian", "Cyclist")))
    rows = {r["bin"]: r for r in class_breakdown(result.matched)}
    assert set(rows) == {"Car", "Pedestrian", "Cyclist"} and all(r["n"] == 1 for r in rows.values())
    # 1e-6 degrees: the poses are written with full float precision; about Z the rotation is the yaw alone.
    assert rows["Pedestrian"]["e_heading_median_deg"] == pytest.approx(20.0, abs=1e-6)
    assert rows["Cyclist"]["e_heading_median_deg"] == pytest.approx(0.0, abs=1e-6)
    assert rows["Car"]["siou_mean"] == pytest.approx(1.0, abs=1e-6)
    text = format_report(result)
    assert "By ground-truth class (means):" in text and "Pedestrian 20.00 / 20.00" in text
    objects = result_to_json(result)["objects"]
    assert [o["e_heading_deg"] is not None for o in objects] == [True, True, True]


def test_heading_errors_follow_the_class():
    assert heading_error_deg(170.0, "directed") == 170.0
    assert heading_error_deg(170.0, "axial") == pytest.approx(10.0)  # a barrier's ends are alike
    assert heading_error_deg(170.0, "none") is None  # a cone has no yaw


def test_a_cone_is_scored_without_a_heading(tmp_path):
    """KITTI has no cone; a KITTI-format dataset that has them (type TrafficCone) is scored without a heading."""
    cone = KittiBox("TrafficCone", (2.0, 1.6, 10.0), (0.4, 0.4, 0.7), 0.8)
    gt = _ground_truth(tmp_path / "gt", [cone])
    pose = Pose(cone.R_cam_vehicle, cone.t_cam(), np.array(cone.lwh), cone.box2d(), "Traffic cone")
    out = write_results(tmp_path / "out", {"000001": [pose]}, K_KITTI, T2, KITTI_SIZE)
    result = evaluate_folder(out, "kitti", gt, EvalOptions(classes=("TrafficCone",)))
    (record,) = result.matched  # a prediction of prototype "Traffic cone" pairs with cone ground truth...
    assert record.e_heading_deg is None  # ... and has no heading error
    assert class_breakdown(result.matched)[0]["n_heading"] == 0


def test_cityscapes_bicycles_are_scored_as_their_class(tmp_path):
    gt = write_cityscapes(tmp_path / "cs")
    image = "bochum_000000_000313"
    car, bicycle = CITYSCAPES_SCENE[image]
    poses = [cam_pose(car), Pose(**{**cam_pose(bicycle).__dict__, "cls": "Bicycle"})]
    out = write_results(tmp_path / "out", {image: poses}, K_CS, np.zeros(3), (2048, 1024))
    result = evaluate_folder(out, "cityscapes", gt, EvalOptions(classes=("car", "bicycle")))
    rows = {r["bin"]: r for r in class_breakdown([r for r in result.matched if r.image_id == image])}
    assert rows["bicycle"]["n"] == 1 and rows["bicycle"]["e_heading_median_deg"] == pytest.approx(0.0, abs=1e-6)
    assert rows["car"]["n"] == 1
