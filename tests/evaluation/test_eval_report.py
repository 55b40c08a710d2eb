"""The evaluation pipeline and its report on synthetic ground truth in all three formats.

Predictions of known error (see ``eval_scenes.perturb``): vehicle k of each image is exact (k % 4 == 0),
moved forward by SHIFT (IoU (l - SHIFT) / (l + SHIFT), E_t = SHIFT / ||t_gt||), rotated by ANGLE
(E_R = 7 deg) or resized by SCALE (E_d = 0.1, IoU 1 / SCALE^3: the larger box contains the other).
Tolerance 1e-12 throughout (closed forms, float64); 1e-9 where a KITTI offset read from a 13-digit calib
file enters a relative error.
"""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest

from tests.eval_scenes import (
    ANGLE,
    CITYSCAPES_SCENE,
    CS_SIZE,
    K_CS,
    K_KITTI,
    KITTI_SCENE,
    KITTI_SIZE,
    P2,
    SCALE,
    SHIFT,
    T2,
    TRACKING_FRAMES,
    cam_pose,
    kitti_pose,
    perturb,
    write_cityscapes,
    write_kitti_object,
    write_kitti_tracking,
    write_results,
)
from toosicubix.camera import Camera
from toosicubix.errors import EvaluationInputError, FormatError
from toosicubix.evaluation import (
    EvalOptions,
    evaluate,
    evaluate_folder,
    format_report,
    load_predictions,
    result_to_csv,
    result_to_json,
    summarize,
    write_csv,
    write_json,
)
from toosicubix.evaluation.report import CSV_COLUMNS, depth_breakdown, occlusion_breakdown
from toosicubix.formats.ground_truth import open_ground_truth
from toosicubix.formats.kitti import format_label_line, object_from_pose

SUMMARY_KEYS = {"n_matched", "n_unmatched_pred", "n_unmatched_gt", "iou_mean", "iou_median", "siou_mean",
                "siou_median", "e_r_mean_deg", "e_r_median_deg", "e_t_mean", "e_t_median", "e_d_mean", "e_d_median",
                "e_comb_mean"}


def check_known_errors(result, poses_by_image, tol=1e-12):
    """Every matched object shows exactly the error its prediction was built with."""
    by_key = {(r.image_id, r.pred_id): r for r in result.matched}
    for image_id, poses in poses_by_image.items():
        for k, pose in enumerate(poses):
            m = by_key[(image_id, str(k))].metrics
            kind = k % 4
            t_gt_norm = np.linalg.norm(by_key[(image_id, str(k))].gt.t_cam_vehicle)
            if kind == 0:
                assert m.iou == pytest.approx(1.0, abs=tol) and m.siou == pytest.approx(1.0, abs=tol)
                assert m.e_r_deg < 1e-9 and m.e_t < tol and m.e_d < tol and m.e_comb < 1e-9
            elif kind == 1:
                l_ = pose.d[0]
                assert m.iou == pytest.approx((l_ - SHIFT) / (l_ + SHIFT), abs=tol)
                assert m.e_t == pytest.approx(SHIFT / t_gt_norm, abs=1e-9)
                assert m.e_r_deg < 1e-9 and m.e_d < tol
            elif kind == 2:
                assert m.e_r_deg == pytest.approx(np.rad2deg(ANGLE), abs=1e-9)
                assert m.e_t < tol and m.e_d < tol
            else:
                assert m.e_d == pytest.approx(SCALE - 1.0, abs=tol)
                assert m.iou == pytest.approx(1.0 / SCALE**3, abs=tol)


def kitti_predictions():
    """Exact and perturbed predictions of the first two KITTI images (the third has no prediction)."""
    return {image_id: [perturb(k, kitti_pose(b)) for k, b in enumerate(KITTI_SCENE[image_id])]
            for image_id in ("000001", "000002")}


# --- KITTI object ------------------------------------------------------------------------------------------------

def test_kitti_object_known_errors_and_counts(tmp_path):
    gt_root = write_kitti_object(tmp_path / "gt")
    poses = kitti_predictions()
    out = write_results(tmp_path / "out", poses, K_KITTI, T2, KITTI_SIZE,
                        failed={"000001": [np.array([1.0, 1.0, 5.0, 5.0])]})
    result = evaluate_folder(out, "kitti", gt_root)
    assert len(result.matched) == 7
    check_known_errors(result, poses)
    assert result.warnings == ()
    assert result.n_images == 2 and result.n_gt_images == 3 and result.n_gt_images_without_pred == 1
    assert result.gt_excluded == {"DontCare": 1, "Pedestrian": 1}
    assert [(f.image_id, f.id) for f in result.failed_pred] == [("000001", "f0")]
    assert "PnP found no solution" in result.failed_pred[0].reason
    assert result.unmatched_pred == () and result.unmatched_gt == ()
    # Depth is the ground truth's z in camera 2: location z + t2_z.
    record = next(r for r in result.matched if r.image_id == "000001" and r.pred_id == "0")
    assert record.depth == pytest.approx(KITTI_SCENE["000001"][0].location_rect[2] + T2[2], abs=1e-12)
    assert record.occlusion == 0 and record.cls == "Car" and record.iou_2d == pytest.approx(1.0)
    summary = summarize(result)
    assert SUMMARY_KEYS <= set(summary)
    assert summary["n_failed_pred"] == 1 and summary["n_gt_excluded"] == 2


def test_unmatched_predictions_and_ground_truth_are_listed(tmp_path):
    gt_root = write_kitti_object(tmp_path / "gt")
    poses = kitti_predictions()
    stray = kitti_pose(KITTI_SCENE["000001"][0])
    poses["000001"] = [*poses["000001"][:2],
                       type(stray)(stray.R, stray.t, stray.d, np.array([1100.0, 10.0, 1150.0, 60.0]), "Car")]
    out = write_results(tmp_path / "out", poses, K_KITTI, T2, KITTI_SIZE)
    result = evaluate_folder(out, "kitti", gt_root)
    assert [(u.image_id, u.id) for u in result.unmatched_pred] == [("000001", "2")]
    assert result.unmatched_pred[0].best_iou_2d == 0.0
    assert sorted((u.image_id, u.id, u.cls) for u in result.unmatched_gt) == [
        ("000001", "2", "Van"), ("000001", "3", "Truck")]
    doc = result_to_json(result)
    assert doc["summary"]["n_unmatched_pred"] == 1 and doc["summary"]["n_unmatched_gt"] == 2
    assert doc["unmatched_gt"][0]["source"].endswith("000001.txt:3")
    text = format_report(result)
    assert "unmatched predictions: 1; unmatched ground truth: 2" in text
    assert "image 000001 id 3 (Truck)" in text


def test_class_filter_and_threshold(tmp_path):
    gt_root = write_kitti_object(tmp_path / "gt")
    out = write_results(tmp_path / "out", kitti_predictions(), K_KITTI, T2, KITTI_SIZE)
    result = evaluate_folder(out, "kitti", gt_root, EvalOptions(classes=("car",)))
    assert {r.cls for r in result.matched} == {"Car"}
    assert result.gt_excluded == {"DontCare": 1, "Pedestrian": 1, "Truck": 1, "Van": 1}
    assert len(result.unmatched_pred) == 2  # the van's and the truck's predictions
    with pytest.raises(EvaluationInputError, match="min_iou"):
        evaluate_folder(out, "kitti", gt_root, EvalOptions(min_iou=1.5))


def test_full_rotation_prediction_against_upright_kitti_ground_truth(tmp_path):
    """A pitched prediction: E_R sees the pitch, KITTI's yaw-only IoU does not."""
    gt_root = write_kitti_object(tmp_path / "gt")
    box = KITTI_SCENE["000002"][0]
    pose = kitti_pose(box)
    pitched = type(pose)(pose.R @ np.array([[np.cos(0.1), 0, np.sin(0.1)], [0, 1, 0], [-np.sin(0.1), 0, np.cos(0.1)]]),
                         pose.t, pose.d, pose.box2d, "Car")
    out = write_results(tmp_path / "out", {"000002": [pitched]}, K_KITTI, T2, KITTI_SIZE)
    (record,) = evaluate_folder(out, "kitti", gt_root).matched
    assert record.metrics.e_r_deg == pytest.approx(np.rad2deg(0.1), abs=1e-9)
    assert record.metrics.iou_kitti == pytest.approx(1.0, abs=1e-12)
    assert record.metrics.iou < 0.95


# --- frames ---------------------------------------------------------------------------------------------------------

def test_without_calib_results_offset_is_used_and_said(tmp_path):
    gt_root = write_kitti_object(tmp_path / "gt", with_calib=False)
    poses = kitti_predictions()
    out = write_results(tmp_path / "out", poses, K_KITTI, T2, KITTI_SIZE)
    result = evaluate_folder(out, "kitti", gt_root)
    check_known_errors(result, poses)
    assert len(result.warnings) == 1 and "no calib file for 2 image(s)" in result.warnings[0]
    assert "t_cam_rect" in result.warnings[0]


def test_offset_mismatch_warns_and_keeps_predictions_in_their_frame(tmp_path):
    """results.json states a wrong t_cam_rect (5 cm off): a warning; the ground truth still moves by the calib's
    offset, so exact predictions keep zero error."""
    gt_root = write_kitti_object(tmp_path / "gt")
    poses = kitti_predictions()
    out = write_results(tmp_path / "out", poses, K_KITTI, T2 + np.array([0.05, 0.0, 0.0]), KITTI_SIZE)
    result = evaluate_folder(out, "kitti", gt_root)
    check_known_errors(result, poses)
    assert len(result.warnings) == 1 and "differs from the ground truth's camera offset" in result.warnings[0]
    assert "50.0 mm" in result.warnings[0]


def test_different_K_warns(tmp_path):
    gt_root = write_kitti_object(tmp_path / "gt")
    out = write_results(tmp_path / "out", kitti_predictions(), K_KITTI * [[1.01], [1.01], [1.0]], T2, KITTI_SIZE)
    (warning,) = evaluate_folder(out, "kitti", gt_root).warnings
    assert "K of results.json differs" in warning


def test_yaw_only_label_predictions(tmp_path):
    """A bare label_2 folder: yaw only, moved by the calib's t2 like the ground truth."""
    gt_root = write_kitti_object(tmp_path / "gt")
    camera = Camera.from_P(P2)
    out = tmp_path / "out"
    (out / "label_2").mkdir(parents=True)
    yaw = np.deg2rad(5.0)
    for image_id in ("000001", "000002"):
        lines = []
        for k, box in enumerate(KITTI_SCENE[image_id]):
            p = kitti_pose(box)
            R = p.R @ np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]) \
                if k == 1 else p.R  # vehicle 1 turned by 5 degrees about its up axis
            lines.append(format_label_line(object_from_pose(box.cls, R, p.t, p.d, camera, p.box2d)))
        (out / "label_2" / f"{image_id}.txt").write_text("\n".join(lines) + "\n")
    predictions = load_predictions(out)
    assert predictions.yaw_only and predictions.kind == "label_2"
    result = evaluate(predictions, open_ground_truth("kitti", gt_root))
    assert len(result.matched) == 7 and all(r.yaw_only for r in result.matched)
    for r in result.matched:
        # The label prints ry with 6 decimals and lengths with 4: errors of 5e-7 rad and 5e-5 m at most.
        expected = 5.0 if r.pred_id == "1" else 0.0
        assert r.metrics.e_r_deg == pytest.approx(expected, abs=1e-4)
        assert r.metrics.e_t < 1e-5
    assert result.settings["rotations"].startswith("yaw only")


def test_yaw_only_labels_without_calib_are_compared_in_camera_0(tmp_path):
    gt_root = write_kitti_object(tmp_path / "gt", with_calib=False)
    out = tmp_path / "out"
    (out / "label_2").mkdir(parents=True)
    (out / "label_2" / "000001.txt").write_text((gt_root / "label_2" / "000001.txt").read_text())
    result = evaluate_folder(out, "kitti", gt_root)
    # The pedestrian is scored with the cars: the predictions have one.
    assert len(result.matched) == 5 and all(r.metrics.e_t == 0.0 for r in result.matched)
    assert sorted(r.cls for r in result.matched).count("Pedestrian") == 1 and result.unmatched_pred == ()
    assert "compared in camera 0" in result.warnings[0]
    # Its DontCare line is a failed prediction, not a silent drop.
    assert [f.cls for f in result.failed_pred] == ["DontCare"]


# --- KITTI tracking and Cityscapes ---------------------------------------------------------------------------------

def test_kitti_tracking_known_errors(tmp_path):
    gt_root = write_kitti_tracking(tmp_path / "gt")
    poses = {f"0003_{frame:06d}": [perturb(k, kitti_pose(b)) for k, b in enumerate(boxes)]
             for frame, boxes in TRACKING_FRAMES.items()}
    out = write_results(tmp_path / "out", poses, K_KITTI, T2, KITTI_SIZE)
    result = evaluate_folder(out, "kitti-tracking", gt_root)
    assert len(result.matched) == 7
    check_known_errors(result, poses)
    assert {r.gt_track_id for r in result.matched if r.image_id == "0003_000010"} == {0, 1, 2, 3}
    assert result.gt_excluded == {"DontCare": 2}
    assert result.n_gt_images_without_pred == 10  # frames 0-9 of the sequence


def test_cityscapes_known_errors_with_full_rotations(tmp_path):
    gt_root = write_cityscapes(tmp_path / "gt")
    poses = {image_id: [perturb(k, cam_pose(b)) for k, b in enumerate(boxes) if b.label != "bicycle"]
             for image_id, boxes in CITYSCAPES_SCENE.items()}
    out = write_results(tmp_path / "out", poses, K_CS, np.zeros(3), CS_SIZE)
    result = evaluate_folder(out, "cityscapes", gt_root)
    assert len(result.matched) == 5
    check_known_errors(result, poses)
    assert result.warnings == ()
    assert result.gt_excluded == {"bicycle": 1, "ignore": 2}
    assert result.occlusion_kind == "fraction"
    rows = {row["bin"]: row["n"] for row in occlusion_breakdown(result.matched, "fraction")}
    assert rows == {"0-0.1": 2, "0.1-0.4": 1, "0.4-0.7": 1, "0.7-1": 1}
    assert "By Cityscapes occlusion fraction" in format_report(result)


def test_missing_ground_truth_partner_is_an_error_naming_both_sides(tmp_path):
    gt_root = write_kitti_object(tmp_path / "gt")
    poses = kitti_predictions()
    poses["000777"] = poses["000001"][:1]
    out = write_results(tmp_path / "out", poses, K_KITTI, T2, KITTI_SIZE)
    with pytest.raises(EvaluationInputError, match=r"1 predicted image\(s\) have no ground truth") as info:
        evaluate_folder(out, "kitti", gt_root)
    assert "label_2/000777.txt" in str(info.value) and "results.json" in str(info.value)


def test_prediction_folder_errors(tmp_path):
    with pytest.raises(EvaluationInputError, match="prediction folder not found"):
        load_predictions(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(EvaluationInputError, match=r"neither results\.json nor KITTI label files"):
        load_predictions(tmp_path / "empty")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "results.json").write_text("{")
    with pytest.raises(FormatError, match="not valid JSON"):
        load_predictions(tmp_path / "bad")


# --- report -------------------------------------------------------------------------------------------------------

def test_breakdowns_by_depth_and_occlusion(tmp_path):
    gt_root = write_kitti_object(tmp_path / "gt")
    out = write_results(tmp_path / "out", kitti_predictions(), K_KITTI, T2, KITTI_SIZE)
    result = evaluate_folder(out, "kitti", gt_root)
    depth = {row["bin"]: row["n"] for row in depth_breakdown(result.matched)}
    # Scene depths: 14.2, 24.6, 9.8, 43.5 and 7.4, 33.3, 62.0 (plus t2_z = 3 mm).
    assert depth == {"0-10 m": 2, "10-20 m": 1, "20-30 m": 1, "30-50 m": 2, "50+ m": 1}
    occlusion = {row["bin"]: row["n"] for row in occlusion_breakdown(result.matched, "level")}
    assert occlusion == {"0 fully visible": 4, "1 partly occluded": 2, "2 largely occluded": 1, "3 unknown": 0}
    row = next(r for r in depth_breakdown(result.matched) if r["bin"] == "50+ m")
    assert row["iou_mean"] == row["iou_median"]


def test_means_and_medians_are_the_paper_table(tmp_path):
    gt_root = write_kitti_object(tmp_path / "gt")
    out = write_results(tmp_path / "out", kitti_predictions(), K_KITTI, T2, KITTI_SIZE)
    result = evaluate_folder(out, "kitti", gt_root)
    s = summarize(result)
    ious = [r.metrics.iou for r in result.matched]
    assert s["iou_mean"] == pytest.approx(np.mean(ious), abs=1e-15)
    assert s["iou_median"] == pytest.approx(np.median(ious), abs=1e-15)
    e_r = [r.metrics.e_r_deg for r in result.matched]
    assert s["e_r_mean_deg"] == pytest.approx(np.mean(e_r), abs=1e-12)
    text = format_report(result)
    header = next(line for line in text.splitlines() if "IoU_KITTI" in line)
    assert header.split() == ["n", "IoU", "sIoU", "E_R", "deg", "E_t", "E_d", "E_comb", "IoU_KITTI", "E_yaw", "deg"]
    e_yaw = [r.metrics.e_yaw_deg for r in result.matched]
    assert s["e_yaw_mean_deg"] == pytest.approx(np.mean(e_yaw), abs=1e-12)
    assert all(y <= r.metrics.e_r_deg + 1e-9 for y, r in zip(e_yaw, result.matched, strict=True))
    assert any(line.startswith("mean ") for line in text.splitlines())
    assert any(line.startswith("median ") for line in text.splitlines())


def test_json_and_csv_outputs(tmp_path):
    gt_root = write_kitti_object(tmp_path / "gt")
    out = write_results(tmp_path / "out", kitti_predictions(), K_KITTI, T2, KITTI_SIZE)
    result = evaluate_folder(out, "kitti", gt_root)
    write_json(result, tmp_path / "reports" / "eval.json")
    write_csv(result, tmp_path / "reports" / "eval.csv")
    doc = json.loads((tmp_path / "reports" / "eval.json").read_text())
    assert SUMMARY_KEYS <= set(doc["summary"]) and len(doc["objects"]) == doc["summary"]["n_matched"] == 7
    obj = doc["objects"][0]
    for key in ("image_id", "pred_id", "gt_index", "class", "occlusion", "truncation", "depth", "iou", "siou",
                "e_r_deg", "e_t", "e_d", "e_comb", "iou_kitti", "e_yaw_deg", "iou_2d"):
        assert key in obj
    assert np.array(obj["gt"]["R_cam_vehicle"]).shape == (3, 3)
    assert {row["bin"] for row in doc["breakdowns"]["depth"]} >= {"0-10 m", "50+ m"}
    rows = list(csv.DictReader(io.StringIO((tmp_path / "reports" / "eval.csv").read_text())))
    assert len(rows) == 7 and tuple(rows[0]) == CSV_COLUMNS
    assert float(rows[0]["iou"]) == pytest.approx(result.matched[0].metrics.iou, abs=1e-15)
    assert result_to_csv(result).count("\n") == 8


def test_empty_evaluation_has_null_statistics(tmp_path):
    gt_root = write_kitti_object(tmp_path / "gt")
    out = write_results(tmp_path / "out", {}, K_KITTI, T2, KITTI_SIZE)
    result = evaluate_folder(out, "kitti", gt_root)
    doc = result_to_json(result)
    assert doc["summary"]["n_matched"] == 0 and doc["summary"]["iou_mean"] is None
    assert "nothing scored" in result.warnings[0]
    json.dumps(doc, allow_nan=False)
    assert "-" in format_report(result)


def test_prediction_without_a_box_is_paired_by_its_projection(tmp_path):
    """results.json without box2d: the cuboid projected with K (clipped to the image) stands in."""
    gt_root = write_kitti_object(tmp_path / "gt")
    poses = {"000002": [kitti_pose(b) for b in KITTI_SCENE["000002"]]}
    poses["000002"] = [type(p)(p.R, p.t, p.d, None, p.cls) for p in poses["000002"]]
    out = write_results(tmp_path / "out", poses, K_KITTI, T2, KITTI_SIZE)
    result = evaluate_folder(out, "kitti", gt_root)
    assert len(result.matched) == 3
    # The ground-truth box is the same projection rounded to 0.01 px.
    assert all(r.iou_2d > 0.999 and r.metrics.iou == pytest.approx(1.0, abs=1e-12) for r in result.matched)
