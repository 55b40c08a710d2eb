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


def test_the_classes_the_fit_has_are_scored_unless_others_are_named(tmp_path):
    """Without classes, the source's vehicles and every class fitted (a batch's pedestrians with its cars); with
    classes that leave the pedestrian out, its prediction is unmatched for that reason, not for want of a box."""
    gt = _ground_truth(tmp_path / "gt", [CAR, PERSON, CYCLIST])
    out = write_results(tmp_path / "out", {"000001": [kitti_pose(CAR), kitti_pose(PERSON)]}, K_KITTI, T2, KITTI_SIZE)
    result = evaluate_folder(out, "kitti", gt)
    assert result.settings["classes"] == ["Car", "Van", "Truck", "Pedestrian"]
    assert sorted(m.cls for m in result.matched) == ["Car", "Pedestrian"] and result.gt_excluded == {"Cyclist": 1}
    only_cars = evaluate_folder(out, "kitti", gt, EvalOptions(classes=("Car",)))
    (person,) = only_cars.unmatched_pred
    assert person.cls == "Pedestrian" and person.reason == ("its class, Pedestrian, is not among the ground-truth "
                                                            "classes scored")


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


BARRIER = KittiBox("Barrier", (2.0, 1.6, 10.0), (2.49, 0.49, 0.98), 0.3)
CONE = KittiBox("TrafficCone", (2.0, 1.6, 10.0), (0.4, 0.4, 0.7), 0.8)


def test_a_barrier_turned_end_for_end_is_exact(tmp_path):
    """Its ends are alike: E_R, the yaw's error and E_comb count what a barrier has (before: E_R 180, E_comb 0.33),
    and a single class's report still gives its heading error."""
    gt = _ground_truth(tmp_path / "gt", [BARRIER])
    turned = rotated(kitti_pose(BARRIER), np.array([0.0, 0.0, np.pi]))
    out = write_results(tmp_path / "out", {"000001": [turned]}, K_KITTI, T2, KITTI_SIZE)
    result = evaluate_folder(out, "kitti", gt, EvalOptions(classes=("Barrier",)))
    (m,) = result.matched
    assert m.metrics.e_r_deg < 1e-6 and m.metrics.e_yaw_deg < 1e-6 and m.metrics.e_comb < 1e-9 and m.e_heading_deg == 0
    assert "heading error (degrees, median / mean): Barrier 0.00 / 0.00" in format_report(result)


@pytest.mark.parametrize("typed", ["TrafficCone", "traffic_cone"])
def test_a_cone_has_no_yaw_to_miss_whatever_its_type_is_called(tmp_path, typed):
    """A cone's yaw is undetermined: a label typed as a cone (nuScenes' names in KITTI format) gets no heading error,
    and E_R is its up axis's error alone (here 0: the cone is exact but for a 115 degree turn)."""
    gt = _ground_truth(tmp_path / "gt", [CONE])
    labels = tmp_path / "out" / "label_2"
    labels.mkdir(parents=True)
    wrong = KittiBox(typed, CONE.location_rect, CONE.lwh, CONE.ry + 2.0)
    (labels / "000001.txt").write_text(kitti_line(wrong) + "\n")
    (m,) = evaluate_folder(labels.parent, "kitti", gt, EvalOptions(classes=("TrafficCone",))).matched
    assert m.e_heading_deg is None and m.metrics.e_r_deg < 1e-6


def test_label_files_with_misc_predictions_say_their_class_is_unknown(tmp_path):
    gt = _ground_truth(tmp_path / "gt", [CONE])
    labels = tmp_path / "out" / "label_2"
    labels.mkdir(parents=True)
    (labels / "000001.txt").write_text(kitti_line(KittiBox("Misc", CONE.location_rect, CONE.lwh, CONE.ry)) + "\n")
    result = evaluate_folder(labels.parent, "kitti", gt, EvalOptions(classes=("TrafficCone",)))
    assert any("typed Misc" in w and "results.json" in w for w in result.warnings), result.warnings
