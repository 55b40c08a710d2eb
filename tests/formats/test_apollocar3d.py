"""ApolloCar3D poses into the vehicle frame, the ground-truth source, and learn-parts on a hand-made file."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.conftest import shared_data_dir
from tests.eval_scenes import K_KITTI, Pose, write_results
from toosicubix.annotations.mapping import load_mapping
from toosicubix.cli import main
from toosicubix.errors import InputFileError
from toosicubix.evaluation import evaluate_folder, format_report, result_to_csv, result_to_json
from toosicubix.evaluation.report import hidden_breakdown, keypoint_breakdown, off_rays_breakdown
from toosicubix.formats.apollocar3d import keypoints_off_rays, pose_to_vehicle, read_apollocar3d, read_car_models
from toosicubix.formats.ground_truth import ApolloCar3DGroundTruth
from toosicubix.geometry import depth_reversed_twin

MODELS = {"0": {"name": "a", "type": "3x", "length": 4.8, "width_body": 1.8, "width_with_mirrors": 2.0,
                "height": 1.5}}


def test_pose_to_vehicle_follows_the_readme_frames():
    # roll = pi: model +y (up) turns to camera -y (up), model +z (front) to camera -z: the car faces the camera.
    d = np.array([4.8, 1.8, 1.5])
    R, t = pose_to_vehicle(np.array([np.pi, 0.0, 0.0, 1.0, 2.0, 20.0]), d)
    # Columns: forward = R e_z = -z (toward the camera), left = R e_x = +x (a car facing the camera has its left
    # on the camera's right), up = R e_y = -y.
    np.testing.assert_allclose(R, [[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(t, [1.0, 2.0 + 0.75, 20.0], atol=1e-12)  # the box centre 0.75 m above the bottom


def write_dataset(tmp_path, pose=(np.pi, 0.0, 0.0, 1.0, 2.0, 20.0)):
    coco = {"images": [{"id": 1, "file_name": "x_Camera_5.jpg"}], "categories": [],
            "annotations": [{"id": 9, "image_id": 1, "category_id": 0, "bbox": [10, 20, 30, 40],
                             "keypoints": [0, 0, 0] * 66, "pose": list(pose)}]}
    (tmp_path / "kp.json").write_text(json.dumps(coco))
    (tmp_path / "car_models.json").write_text(json.dumps(MODELS))
    return tmp_path / "kp.json"


def test_ground_truth_source(tmp_path):
    source = ApolloCar3DGroundTruth(write_dataset(tmp_path))
    assert source.image_ids() == ["x_Camera_5"]
    gt = source.load("x_Camera_5")
    (obj,) = gt.objects
    assert obj.cls == "Car" and obj.subtype == "3x"
    np.testing.assert_allclose(obj.box2d, [10, 20, 40, 60])
    np.testing.assert_allclose(obj.cuboid_rect.dimensions, [4.8, 1.8, 1.5])


def test_eval_breaks_down_by_labelled_keypoints_and_states_no_occlusion(tmp_path):
    # Two cars with 12 and 31 labelled keypoints (v > 0), predicted exactly: the report bins them by that count
    # and has no occlusion section (ApolloCar3D states none); JSON and CSV carry the count.
    coco = {"images": [{"id": 1, "file_name": "x_Camera_5.jpg"}], "categories": [], "annotations": []}
    for k, (labelled, x) in enumerate(((12, -4.0), (31, 4.0))):
        kp = np.zeros((66, 3))
        kp[:labelled] = (100.0, 100.0, 2)
        coco["annotations"].append({"id": 9 + k, "image_id": 1, "category_id": 0, "bbox": [100 + 800 * k, 20, 300, 200],
                                    "keypoints": kp.ravel().tolist(), "pose": [np.pi, 0.0, 0.0, x, 2.0, 20.0]})
    (tmp_path / "kp.json").write_text(json.dumps(coco))
    (tmp_path / "car_models.json").write_text(json.dumps(MODELS))
    source = ApolloCar3DGroundTruth(tmp_path / "kp.json")
    gts = source.load("x_Camera_5").objects
    assert [g.keypoints for g in gts] == [12, 31] and source.occlusion_kind is None
    poses = {"x_Camera_5": [Pose(g.cuboid_rect.R_cam_vehicle, g.cuboid_rect.t_cam_vehicle, g.cuboid_rect.dimensions,
                                 g.box2d, "Car") for g in gts]}
    out = write_results(tmp_path / "out", poses, K_KITTI, np.zeros(3), (3384, 2710))
    result = evaluate_folder(out, "apollocar3d", tmp_path / "kp.json")
    assert [r.keypoints for r in result.matched] == [12, 31]
    rows = {row["bin"]: row["n"] for row in keypoint_breakdown(result.matched)}
    assert rows == {"0-9": 0, "10-14": 1, "15-19": 0, "20-29": 0, "30+": 1}
    text = format_report(result)
    assert "By keypoints labelled on the ground-truth object" in text and "occlusion" not in text
    doc = result_to_json(result)
    assert set(doc["breakdowns"]) == {"depth", "class", "keypoints", "ground_truth_shows_keypoints",
                                      "ground_truth_twin"}
    assert [o["keypoints"] for o in doc["objects"]] == [12, 31]
    assert [r["keypoints"] for r in csv.DictReader(io.StringIO(result_to_csv(result)))] == ["12", "31"]


def test_eval_scores_apart_a_ground_truth_that_hides_its_labelled_keypoints(tmp_path):
    # Two cars facing the camera, 2 m to its right: it sees their fronts and right sides. One has its front lamps
    # labelled (seen from the front, or the front and the right); the other its left rear lamps and left rear wheel
    # (seen from the rear, or the rear and the left): its pose hides all 5, so it contradicts its labels. The first
    # is predicted at its ground truth, the second at its ground truth's depth-reversed twin.
    names = load_mapping("apollocar3d-66")[0].keypoints
    faces = load_mapping("apollocar3d-66")[0].keypoint_candidates("Sedan")
    shown, hidden = (0, 1, 54, 55, 56, 57), (20, 22, 23, 25, 26)
    assert all(set(faces[names[j]].seen_from) <= {"front", "right"} for j in shown)
    assert all(set(faces[names[j]].seen_from) <= {"rear", "left"} for j in hidden)
    coco = {"images": [{"id": 1, "file_name": "x_Camera_5.jpg"}], "categories": [], "annotations": []}
    for k, (labelled, z) in enumerate(((shown, 15.0), (hidden, 30.0))):
        kp = np.zeros((66, 3))
        kp[list(labelled)] = (100.0, 100.0, 2)
        coco["annotations"].append({"id": 9 + k, "image_id": 1, "category_id": 0, "bbox": [100 + 800 * k, 20, 300, 200],
                                    "keypoints": kp.ravel().tolist(), "pose": [np.pi, 0.0, 0.0, 2.0, 2.0, z]})
    (tmp_path / "kp.json").write_text(json.dumps(coco))
    (tmp_path / "car_models.json").write_text(json.dumps(MODELS))
    gts = ApolloCar3DGroundTruth(tmp_path / "kp.json").load("x_Camera_5").objects
    assert [(g.keypoints, g.keypoints_hidden) for g in gts] == [(6, 0), (5, 5)]
    shown_gt, hidden_gt = (g.cuboid_rect for g in gts)
    twin = depth_reversed_twin(hidden_gt.R_cam_vehicle, hidden_gt.t_cam_vehicle, hidden_gt.dimensions)
    poses = {"x_Camera_5": [Pose(shown_gt.R_cam_vehicle, shown_gt.t_cam_vehicle, shown_gt.dimensions, gts[0].box2d,
                                 "Car"), Pose(*twin, hidden_gt.dimensions, gts[1].box2d, "Car")]}
    result = evaluate_folder(write_results(tmp_path / "out", poses, K_KITTI, np.zeros(3), (3384, 2710)),
                             "apollocar3d", tmp_path / "kp.json")
    assert [row["n"] for row in hidden_breakdown(result.matched)] == [1, 1]
    assert result.matched[1].e_r_twin_deg == pytest.approx(0.0, abs=1e-5)  # as written to results.json and read
    assert result.matched[1].metrics.e_r_deg > 30  # the twin of a car seen from 30 m, 2 m aside, is turned far
    assert "1 fits lie within 10 deg of the ground truth's depth-reversed twin" in format_report(result)
    doc = result_to_json(result)
    assert [row["n"] for row in doc["breakdowns"]["ground_truth_shows_keypoints"]] == [1, 1]
    assert doc["breakdowns"]["ground_truth_twin"] == {"hides": 1, "fit_within_10_deg_of_twin": 1}
    assert [o["keypoints_hidden"] for o in doc["objects"]] == [0, 5]
    assert [r["keypoints_hidden"] for r in csv.DictReader(io.StringIO(result_to_csv(result)))] == ["0", "5"]


#: ApolloCar3D's Camera_5 intrinsics (its README), for the off-the-rays tests.
K_APOLLO = np.array([[2304.54786556982, 0.0, 1686.23787612802], [0.0, 2305.875668062, 1354.98486439791],
                     [0.0, 0.0, 1.0]])


def _labelled_at(pose, labelled, shift_cam=(0.0, 0.0, 0.0)):
    """Keypoints (66, 3) of a car of MODELS at ``pose`` whose ``labelled`` indices are the bundled Sedan positions
    projected by K_APOLLO from the car moved by ``shift_cam`` (metres, camera frame); and the labelled points' camera
    coordinates at the unmoved pose (the ground truth's), (n, 3)."""
    mapping = load_mapping("apollocar3d-66")[0]
    typical = mapping.keypoint_candidates("Sedan")
    d = np.array([4.8, 1.8, 1.5])
    R, t = pose_to_vehicle(np.asarray(pose, dtype=float), d)
    Y = np.array([R @ (d * typical[mapping.keypoints[j]].at) + t for j in labelled])  # (n, 3) camera frame
    uvw = (Y + np.asarray(shift_cam)) @ K_APOLLO.T
    kp = np.zeros((66, 3))
    kp[list(labelled), :2] = uvw[:, :2] / uvw[:, 2:]
    kp[list(labelled), 2] = 2
    return kp, Y


def test_keypoints_off_rays_is_zero_on_the_rays_and_the_perpendicular_shift_off_them(tmp_path):
    # A car facing the camera 2 m to its right, its front lamps and right-side keypoints labelled. Projected from
    # its ground-truth pose they lie on their rays (0 m); projected from the car moved 0.6 m sideways, each ground-
    # truth point lies off its ray by the shift's part perpendicular to that ray, computed here on its own.
    labelled = (0, 1, 54, 55, 56, 57)
    pose = (np.pi, 0.0, 0.0, 2.0, 2.0, 15.0)
    path = write_dataset(tmp_path, pose)
    (car,) = read_apollocar3d(path, read_car_models(tmp_path / "car_models.json"))[0].cars
    at = [None] * 66
    mapping = load_mapping("apollocar3d-66")[0]
    for j in labelled:
        at[j] = mapping.keypoint_candidates("Sedan")[mapping.keypoints[j]].at
    on, _ = _labelled_at(pose, labelled)
    assert keypoints_off_rays(car.__class__(**{**car.__dict__, "keypoints": on}), K_APOLLO, at) == \
        pytest.approx(0.0, abs=1e-9)
    shift = np.array([0.6, 0.0, 0.0])
    off, Y = _labelled_at(pose, labelled, shift)
    rays = (Y + shift) / np.linalg.norm(Y + shift, axis=1, keepdims=True)
    perpendicular = shift - rays * (rays @ shift)[:, None]
    expected = np.sqrt(np.mean(np.sum(perpendicular**2, axis=1)))
    got = keypoints_off_rays(car.__class__(**{**car.__dict__, "keypoints": off}), K_APOLLO, at)
    assert got == pytest.approx(expected, rel=1e-6) and 0.55 < got < 0.6
    assert keypoints_off_rays(car, K_APOLLO, at[:10]) is None  # another keypoint count than the places given
    assert keypoints_off_rays(car, K_APOLLO, at) is None  # no keypoint labelled


def test_eval_with_cameras_scores_apart_a_ground_truth_off_its_keypoints_rays(tmp_path):
    # Two cars facing the camera, their front and right keypoints labelled (none hidden): the first's projected from
    # its ground truth, the second's from its ground truth moved 1.5 m sideways (its pose contradicts them). Both are
    # predicted at their ground truth; the cameras file beside the keypoint file gives the rays.
    labelled = (0, 1, 54, 55, 56, 57)
    coco = {"images": [{"id": 1, "file_name": "x_Camera_5.jpg"}], "categories": [], "annotations": []}
    for k, (x, shift) in enumerate(((2.0, 0.0), (-4.0, 1.5))):
        pose = (np.pi, 0.0, 0.0, x, 2.0, 15.0)
        kp, _ = _labelled_at(pose, labelled, (shift, 0.0, 0.0))
        coco["annotations"].append({"id": 9 + k, "image_id": 1, "category_id": 0, "bbox": [100 + 800 * k, 20, 300, 200],
                                    "keypoints": kp.ravel().tolist(), "pose": list(pose)})
    (tmp_path / "kp.json").write_text(json.dumps(coco))
    (tmp_path / "car_models.json").write_text(json.dumps(MODELS))
    (tmp_path / "cameras.json").write_text(json.dumps({"cameras": [{"match": "*_Camera_5.jpg",
                                                                    "K": K_APOLLO.tolist()}]}))
    gts = ApolloCar3DGroundTruth(tmp_path / "kp.json").load("x_Camera_5").objects
    assert [g.keypoints_hidden for g in gts] == [0, 0]
    assert gts[0].keypoints_off_rays_m == pytest.approx(0.0, abs=1e-9) and gts[1].keypoints_off_rays_m > 1.0
    poses = {"x_Camera_5": [Pose(g.cuboid_rect.R_cam_vehicle, g.cuboid_rect.t_cam_vehicle, g.cuboid_rect.dimensions,
                                 g.box2d, "Car") for g in gts]}
    out = write_results(tmp_path / "out", poses, K_APOLLO, np.zeros(3), (3384, 2710))
    result = evaluate_folder(out, "apollocar3d", tmp_path / "kp.json")
    assert not result.warnings  # the same K on both sides: no mismatch to warn of
    rows = off_rays_breakdown(result.matched)
    assert [(row["bin"], row["n"]) for row in rows] == [
        ("on them <= 0.5 m", 1), ("off them > 0.5 m", 1), ("neither off nor hiding", 1)]
    assert "By how far the labelled keypoints lie from their rays at the ground-truth pose" in format_report(result)
    doc = result_to_json(result)
    assert [row["n"] for row in doc["breakdowns"]["ground_truth_on_keypoint_rays"]] == [1, 1, 1]
    column = [r["keypoints_off_rays_m"] for r in csv.DictReader(io.StringIO(result_to_csv(result)))]
    assert float(column[0]) == pytest.approx(0.0, abs=1e-9) and float(column[1]) > 1.0
    # Without a cameras file nothing is measured, and the breakdown is left out; --cameras names one elsewhere.
    moved = tmp_path / "elsewhere.json"
    (tmp_path / "cameras.json").rename(moved)
    bare = evaluate_folder(out, "apollocar3d", tmp_path / "kp.json")
    assert all(r.keypoints_off_rays_m is None for r in bare.matched)
    assert "ground_truth_on_keypoint_rays" not in result_to_json(bare)["breakdowns"]
    runner = CliRunner()
    given = runner.invoke(main, ["eval", str(out), "--apollocar3d", str(tmp_path / "kp.json"), "--cameras", str(moved)])
    assert given.exit_code == 0, given.output
    assert "off them > 0.5 m" in given.output
    missing = runner.invoke(main, ["eval", str(out), "--apollocar3d", str(tmp_path / "kp.json"), "--cameras",
                                   str(tmp_path / "nope.json")])
    assert missing.exit_code == 2 and "nope.json: cameras file not found" in missing.output
    wrong = runner.invoke(main, ["eval", str(out), "--kitti", str(tmp_path), "--cameras", str(moved)])
    assert wrong.exit_code == 2 and "--cameras goes with --apollocar3d only" in wrong.output
    # A broken cameras.json beside the keypoint file is named, with why it was read.
    (tmp_path / "cameras.json").write_text('{"cameras": [{"K": 3}]}')
    broken = runner.invoke(main, ["eval", str(out), "--apollocar3d", str(tmp_path / "kp.json")])
    assert broken.exit_code == 2
    assert "cameras.json: $.cameras[0].match: missing (read as the cameras of kp.json's images because it lies " \
           "beside it; --cameras names another)" in broken.output


@pytest.mark.parametrize("n_keypoints", [10, 70])
def test_a_file_with_other_keypoints_than_apollocar3d_66_counts_none_hidden(tmp_path, n_keypoints):
    # The bundled mapping names 66 keypoints; for a file with another count nothing is known of their faces.
    coco = {"images": [{"id": 1, "file_name": "x_Camera_5.jpg"}], "categories": [],
            "annotations": [{"id": 9, "image_id": 1, "category_id": 0, "bbox": [10, 20, 30, 40],
                             "keypoints": [100, 100, 2] * n_keypoints, "pose": [np.pi, 0.0, 0.0, 1.0, 2.0, 20.0]}]}
    (tmp_path / "kp.json").write_text(json.dumps(coco))
    (tmp_path / "car_models.json").write_text(json.dumps(MODELS))
    (obj,) = ApolloCar3DGroundTruth(tmp_path / "kp.json").load("x_Camera_5").objects
    assert obj.keypoints == n_keypoints and obj.keypoints_hidden is None


def test_learn_parts_names_a_car_with_other_keypoints_than_its_mapping(tmp_path):
    coco = {"images": [{"id": 1, "file_name": "x_Camera_5.jpg"}], "categories": [],
            "annotations": [{"id": 9, "image_id": 1, "category_id": 0, "bbox": [10, 20, 30, 40],
                             "keypoints": [100, 100, 2] * 70, "pose": [np.pi, 0.0, 0.0, 1.0, 2.0, 20.0]}]}
    (tmp_path / "kp.json").write_text(json.dumps(coco))
    (tmp_path / "car_models.json").write_text(json.dumps(MODELS))
    (tmp_path / "cameras.json").write_text(json.dumps({"cameras": [{"match": "*", "K": K_KITTI.tolist()}]}))
    out = tmp_path / "mapping.json"
    result = CliRunner().invoke(main, ["learn-parts", str(tmp_path / "kp.json"), "--car-models",
                                       str(tmp_path / "car_models.json"), "--cameras", str(tmp_path / "cameras.json"),
                                       "-o", str(out)])
    assert result.exit_code == 2 and not out.exists()
    assert "kp.json: $.annotations[0].keypoints: expected 198 numbers (x, y, v for 66 keypoints), got 210" \
        in result.output


def test_bad_pose_names_the_json_path(tmp_path):
    path = write_dataset(tmp_path, pose=(0.0, 0.0, 0.0))
    with pytest.raises(InputFileError, match=r"kp.json: \$.annotations\[0\].pose: expected 6 numbers"):
        read_apollocar3d(path, read_car_models(tmp_path / "car_models.json"))


def test_eval_and_learn_parts_on_the_real_folder(tmp_path):
    folder = shared_data_dir() / "apollocar3d"
    if not (folder / "apollocar3d_val_dev.json").is_file():
        pytest.skip(f"ApolloCar3D data not found at {folder}")
    kp, models, cams = (str(folder / n) for n in ("apollocar3d_val_dev.json", "car_models.json", "cameras.json"))
    runner = CliRunner()
    learned = tmp_path / "learned.json"
    result = runner.invoke(main, ["learn-parts", kp, "--car-models", models, "--cameras", cams, "--images", "even",
                                  "-o", str(learned)])
    assert result.exit_code == 0, result.output
    doc = json.loads(learned.read_text())
    lamp = next(p for p in doc["parts"] if p.get("keypoint") == "top_left_c_left_rear_car_light")
    # The left rear lamp: at the rear (x < -0.3), on the car's left (y > 0.2), at about 60 % of the height.
    at = lamp["position"]["at"]
    assert at[0] < -0.3 and at[1] > 0.2 and 0.5 < at[2] < 0.8
    ann = tmp_path / "ann.json"
    result = runner.invoke(main, ["import", "coco", kp, "--mapping", str(learned), "--cameras", cams, "-o", str(ann)])
    assert result.exit_code == 0, result.output
    data = json.loads(ann.read_text())
    data["images"] = data["images"][:2]
    ann.write_text(json.dumps(data))
    out = tmp_path / "out"
    result = runner.invoke(main, ["fit", str(ann), "-o", str(out), "-q"])
    assert result.exit_code in (0, 1), result.output
    result = runner.invoke(main, ["eval", str(out), "--apollocar3d", kp, "--car-models", models])
    assert result.exit_code == 0, result.output
    assert "mean" in result.output and "ApolloCar3D" in result.output
    assert "By how far the labelled keypoints lie from their rays" in result.output  # cameras.json beside it
    result = runner.invoke(main, ["eval", str(out), "--kitti", str(tmp_path), "--car-models", models])
    assert result.exit_code == 2 and "--car-models goes with --apollocar3d only" in result.output
    # The robust loss names the clicks it down-weighted; render reads them, with ApolloCar3D's poses drawn.
    robust = tmp_path / "robust"
    result = runner.invoke(main, ["fit", str(ann), "-o", str(robust), "-q", "--robust-loss", "cauchy"])
    assert result.exit_code in (0, 1), result.output
    fitted = [v for im in json.loads((robust / "results.json").read_text())["images"] for v in im["vehicles"]
              if v["status"] == "ok"]
    assert fitted and all(len(v["click_weights"]) == v["clicks"] for v in fitted)
    assert all(set(v.get("downweighted", [])) <= set(v["click_labels"]) for v in fitted)
    result = runner.invoke(main, ["render", str(robust), "--annotations", str(ann), "--apollocar3d", kp, "-o",
                                  str(tmp_path / "render")])
    assert result.exit_code == 0, result.output
    assert list((tmp_path / "render").glob("*.png"))


# --- keys that collide, hostile values, cameras in every form (issue 34) -----------------------------------------

def _models_text(tmp_path, text: str):
    path = tmp_path / "car_models.json"
    path.write_text(text)
    return path


MODEL = '{"type": "3x", "length": 4.8, "width_body": 1.8, "height": 1.5}'


@pytest.mark.parametrize(("text", "message"), [
    (f'{{"35": {MODEL}, "035": {MODEL}}}', "$.035: car model keys '35' (at $.35) and '035' both mean car model 35"),
    (f'{{"35": {MODEL}, "\u0663\u0665": {MODEL}}}', "$.\u0663\u0665: car model keys '35' (at $.35) and "
                                                    "'\u0663\u0665' both mean car model 35"),
    (f'{{"35": {MODEL}, "35": {MODEL}}}', "$: the key '35' is given twice in one object"),
    (f'{{"\u00b2": {MODEL}}}', "$.\u00b2: expected a car model id: an integer from 0, or 1 to 18 decimal digits, "
                               "got '\u00b2'"),
    (f'{{"{"9" * 5000}": {MODEL}}}', "$['99999999"),
    ('{"35": {"length": 1e-300, "width_body": 1.8, "height": 1.5}}',
     "$.35.length: expected a size in metres greater than 0.1 and at most 100, got 1e-300"),
    ('{"35": {"length": ' + "9" * 400 + ', "width_body": 1.8, "height": 1.5}}',
     "$.35.length: expected a size in metres greater than 0.1 and at most 100, got an integer of 400 digits"),
    ('{"35": {"length": 4.8, "width_body": 1.8, "height": 1.5, "name": ' + "9" * 400 + '}}',
     "$.35.name: expected a string of at most 128 characters (no control characters), got an integer of 400 "
     "digits"),
    ('{"35": {"length": 4.8, "width_body": 1.8, "height": 1.5, "type": "\\ud800"}}',  # not text: eval's CSV failed
     "$.35.type: expected a string of at most 128 characters (no control characters), got '\\ud800'"),
])
def test_car_model_keys_and_extents_are_checked(tmp_path, text, message):
    path = _models_text(tmp_path, text)
    with pytest.raises(InputFileError) as info:
        read_car_models(path)
    assert str(info.value).startswith(f"{path}: {message}")


def test_a_category_id_written_as_text_means_its_model(tmp_path):
    path = write_dataset(tmp_path)
    doc = json.loads(path.read_text())
    doc["annotations"][0]["category_id"] = "000"
    path.write_text(json.dumps(doc))
    (image,) = read_apollocar3d(path, read_car_models(tmp_path / "car_models.json"))
    assert image.cars[0].model.id == 0


@pytest.mark.parametrize(("change", "message"), [
    (lambda d: d["annotations"][0].__setitem__("image_id", [1]), "$.annotations[0].image_id: expected an image id"),
    (lambda d: d["annotations"][0].__setitem__("category_id", {"a": 0}), "$.annotations[0].category_id: expected a "
                                                                         "car model id"),
    (lambda d: d["annotations"][0].__setitem__("category_id", "\u00b2"), "$.annotations[0].category_id: expected"),
    (lambda d: d["annotations"][0]["pose"].__setitem__(3, 10**400), "$.annotations[0].pose: expected 6 numbers, got "
                                                                    "[3.14159"),
    (lambda d: d["annotations"][0]["pose"].__setitem__(5, 1e300), "$.annotations[0].pose: expected roll, pitch, yaw "
                                                                  "within +-100 rad and x, y, z within +-10000 m"),
    (lambda d: d["annotations"][0].__setitem__("id", 10**400), "$.annotations[0].id: expected an annotation id"),
    (lambda d: d["images"].append({"id": 1, "file_name": "y.jpg"}), "$.images[1].id: image id 1 given twice"),
    (lambda d: d["images"].append({"id": 2, "file_name": "b/x_Camera_5.jpg"}),
     "$.images[1].file_name: this image and the one at $.images[0] both get the image id 'x_Camera_5'"),
    (lambda d: d["annotations"][0]["keypoints"].__setitem__(2, 7), "$.annotations[0]: expected bbox [x, y, w, h]"),
])
def test_keypoint_file_values_are_checked(tmp_path, change, message):
    path = write_dataset(tmp_path)
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))
    with pytest.raises(InputFileError) as info:
        read_apollocar3d(path, read_car_models(tmp_path / "car_models.json"))
    assert str(info.value).startswith(f"{path}: {message}")
    fit = write_results(tmp_path / "fit", {"x_Camera_5": []}, K_APOLLO, np.zeros(3), (3384, 2710))
    result = CliRunner().invoke(main, ["eval", str(fit), "--apollocar3d", str(path)])
    assert result.exit_code == 2 and message in result.output, result.output


def test_learn_parts_and_eval_take_the_cameras_in_every_form(tmp_path):
    """A KITTI calib file, a folder of them and an OpenCV YAML instead of our JSON (learn-parts took camera['K'] only
    and crashed with KeyError: 'P')."""
    labelled = (0, 1, 2, 3, 54, 55, 56, 57)
    pose = (np.pi, 0.0, 0.0, 2.0, 2.0, 15.0)
    path = write_dataset(tmp_path, pose)
    doc = json.loads(path.read_text())
    doc["annotations"][0]["keypoints"] = _labelled_at(pose, labelled)[0].ravel().tolist()
    path.write_text(json.dumps(doc))
    K = K_APOLLO
    P2 = " ".join(f"{v:.6f}" for v in np.hstack([K, np.zeros((3, 1))]).ravel())
    (tmp_path / "calib.txt").write_text(f"P0: {P2}\nP2: {P2}\n")
    (tmp_path / "calib").mkdir()
    (tmp_path / "calib" / "x_Camera_5.txt").write_text(f"P2: {P2}\n")
    (tmp_path / "camera.yaml").write_text("%YAML:1.0\ncamera_matrix: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n"
                                          f"  data: [{', '.join(str(v) for v in K.ravel())}]\n")
    learned = {}
    for cameras in ("calib.txt", "calib", "camera.yaml"):
        out = tmp_path / f"mapping-{cameras}.json"
        result = CliRunner().invoke(main, ["learn-parts", str(path), "--car-models", str(tmp_path / "car_models.json"),
                                           "--cameras", str(tmp_path / cameras), "--min-samples", "3", "-o", str(out)])
        assert result.exit_code == 0, result.output
        learned[cameras] = json.loads(out.read_text())["parts"]
        source = ApolloCar3DGroundTruth(path, cameras=tmp_path / cameras)
        (obj,) = source.load("x_Camera_5").objects
        assert obj.keypoints_off_rays_m == pytest.approx(0.0, abs=1e-3)
    assert learned["calib.txt"] == learned["calib"] == learned["camera.yaml"]


MODEL_VALUES = st.one_of(st.none(), st.booleans(), st.floats(), st.integers(min_value=-(10**500), max_value=10**500),
                         st.text(max_size=8), st.lists(st.integers(), max_size=2))


@settings(max_examples=100, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(key=st.one_of(st.text(min_size=1, max_size=6), st.integers(min_value=0, max_value=10**30).map(str)),
       field=st.sampled_from(["length", "width_body", "height", "name", "type", "category_id", "image_id", "bbox",
                              "pose", "keypoints", "id"]),
       value=MODEL_VALUES)
def test_any_key_or_value_reads_or_is_named(tmp_path, key, field, value):
    """A car model key and one value of the car models or keypoint file replaced: read, or an InputFileError naming
    the file and a JSON path; never another exception (and never a car model with an extent under 0.1 m)."""
    path = write_dataset(tmp_path)
    models = {**MODELS, key: dict(MODELS["0"])}
    doc = json.loads(path.read_text())
    if field in ("length", "width_body", "height", "name", "type"):
        models[key][field] = value
    else:
        doc["annotations"][0][field] = value
    (tmp_path / "car_models.json").write_text(json.dumps(models))
    path.write_text(json.dumps(doc))
    try:
        read = read_car_models(tmp_path / "car_models.json")
        images = read_apollocar3d(path, read)
    except InputFileError as exc:
        assert str(exc).startswith(str(tmp_path)) and ": $" in str(exc)
        return
    assert all(min(m.length, m.width_body, m.height) > 0.1 for m in read.values())
    assert all(np.isfinite(car.t_cam_vehicle).all() for im in images for car in im.cars)
