"""Ground-truth sources: KITTI object, KITTI tracking, Cityscapes 3D, and the real KITTI files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.eval_scenes import (
    CITYSCAPES_SCENE,
    KITTI_SCENE,
    T2,
    TRACKING_FRAMES,
    write_cityscapes,
    write_kitti_object,
    write_kitti_tracking,
)
from toosicubix.errors import EvaluationInputError, FormatError
from toosicubix.formats.ground_truth import (
    CityscapesGroundTruth,
    KittiObjectGroundTruth,
    KittiTrackingGroundTruth,
    open_ground_truth,
)
from toosicubix.formats.kitti import read_calib
from toosicubix.geometry import geodesic_angle, wrap_angle, ypr_from_R_cam_vehicle

# --- KITTI object ------------------------------------------------------------------------------------------------

def test_kitti_object_root_reads_labels_and_calib_offset(tmp_path):
    gt = KittiObjectGroundTruth(write_kitti_object(tmp_path))
    assert gt.image_ids() == ["000001", "000002", "000003"]
    image = gt.load("000001")
    # t2 = K^-1 P2[:, 3] from the calib file, written with 13 significant digits.
    np.testing.assert_allclose(image.t_cam_rect, T2, atol=1e-12)
    assert [o.cls for o in image.objects] == ["Car", "Car", "Van", "Truck", "Pedestrian", "DontCare"]
    assert image.objects[-1].cuboid_rect is None
    for obj, box in zip(image.objects, KITTI_SCENE["000001"], strict=False):
        # Values on the 0.01 grid read back exactly.
        np.testing.assert_array_equal(obj.cuboid_rect.t_cam_vehicle, box.location_rect)
        np.testing.assert_array_equal(obj.cuboid_rect.dimensions, box.lwh)
        assert geodesic_angle(obj.cuboid_rect.R_cam_vehicle, box.R_cam_vehicle) == 0.0
        assert obj.occlusion == box.occluded
        np.testing.assert_array_equal(obj.box2d, box.box2d())
    assert image.objects[1].source.endswith("000001.txt:2")


def test_bare_label_folder_finds_calib_beside_it(tmp_path):
    write_kitti_object(tmp_path)
    gt = open_ground_truth("kitti", tmp_path / "label_2")
    assert gt.calib_dir == tmp_path / "calib"
    np.testing.assert_allclose(gt.load("000002").t_cam_rect, T2, atol=1e-12)


def test_kitti_without_calib_leaves_the_offset_unknown(tmp_path):
    gt = KittiObjectGroundTruth(write_kitti_object(tmp_path, with_calib=False))
    assert gt.calib_dir is None
    image = gt.load("000001")
    assert image.t_cam_rect is None and image.K is None
    assert "none found" in gt.describe()


def test_missing_folder_and_missing_partner_name_the_path(tmp_path):
    with pytest.raises(EvaluationInputError, match="ground-truth folder not found"):
        KittiObjectGroundTruth(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(EvaluationInputError, match="label_2/"):
        KittiObjectGroundTruth(tmp_path / "empty")
    gt = KittiObjectGroundTruth(write_kitti_object(tmp_path / "k"))
    with pytest.raises(EvaluationInputError, match=r"image '000999': expected .*label_2/000999\.txt"):
        gt.load("000999")


def test_malformed_label_line_names_file_and_line(tmp_path):
    root = write_kitti_object(tmp_path)
    path = root / "label_2" / "000002.txt"
    lines = path.read_text().splitlines()
    lines[1] = lines[1].rsplit(" ", 1)[0]  # 14 fields
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(FormatError, match=r"000002\.txt:2: expected 15 or 16 fields"):
        KittiObjectGroundTruth(root).load("000002")


# --- KITTI tracking -----------------------------------------------------------------------------------------------

def test_tracking_ids_frames_and_track_ids(tmp_path):
    gt = KittiTrackingGroundTruth(write_kitti_tracking(tmp_path))
    assert gt.image_ids() == [f"0003_{f:06d}" for f in range(12)]  # frames 0 to the last labelled one
    image = gt.load("0003_000011")
    np.testing.assert_allclose(image.t_cam_rect, T2, atol=1e-12)
    vehicles = [o for o in image.objects if o.cuboid_rect is not None]
    assert [o.track_id for o in vehicles] == list(range(len(TRACKING_FRAMES[11])))
    for obj, box in zip(vehicles, TRACKING_FRAMES[11], strict=True):
        np.testing.assert_array_equal(obj.cuboid_rect.t_cam_vehicle, box.location_rect)
    assert image.objects[-1].cls == "DontCare"
    # A frame without rows holds no objects; it is not an error.
    assert gt.load("0003_000012").objects == ()


def test_tracking_bad_ids_and_missing_sequences(tmp_path):
    gt = KittiTrackingGroundTruth(write_kitti_tracking(tmp_path))
    with pytest.raises(EvaluationInputError, match="not a KITTI tracking id"):
        gt.load("000010")
    with pytest.raises(EvaluationInputError, match=r"expected .*label_02/0007\.txt \(sequence 0007\)"):
        gt.load("0007_000001")


# --- Cityscapes ------------------------------------------------------------------------------------------------------

def test_cityscapes_source_searches_recursively_and_converts(tmp_path):
    gt = CityscapesGroundTruth(write_cityscapes(tmp_path))
    assert gt.image_ids() == sorted(CITYSCAPES_SCENE)
    image = gt.load("aachen_000000_000019_leftImg8bit")  # an image file's stem pairs too
    assert image.id == "aachen_000000_000019"
    np.testing.assert_array_equal(image.t_cam_rect, np.zeros(3))
    boxes = [o for o in image.objects if o.cuboid_rect is not None]
    for obj, truth in zip(boxes, CITYSCAPES_SCENE["aachen_000000_000019"], strict=True):
        np.testing.assert_allclose(obj.cuboid_rect.t_cam_vehicle, truth.t_cam, atol=1e-12)
        assert geodesic_angle(obj.cuboid_rect.R_cam_vehicle, truth.R_cam_vehicle) < 1e-12
        assert obj.occlusion_fraction == truth.occlusion and obj.track_id == truth.instance_id
    assert image.objects[-1].cls == "ignore" and image.objects[-1].cuboid_rect is None


def test_cityscapes_prefers_gtbbox3d_and_reports_clashes(tmp_path):
    root = write_cityscapes(tmp_path)
    (root / "aachen" / "aachen_000000_000019.json").write_text("{}")  # plain json: the gtBbox3d file wins
    (root / "other").mkdir()
    (root / "other" / "bochum_000000_000313_gtBbox3d.json").write_text("{}")  # same id twice
    gt = CityscapesGroundTruth(root)
    assert gt.load("aachen_000000_000019").objects
    with pytest.raises(EvaluationInputError, match="several ground-truth files"):
        gt.load("bochum_000000_000313")


def test_cityscapes_empty_folder_and_missing_partner(tmp_path):
    with pytest.raises(EvaluationInputError, match="no Cityscapes 3D"):
        CityscapesGroundTruth(tmp_path)
    gt = CityscapesGroundTruth(write_cityscapes(tmp_path))
    with pytest.raises(EvaluationInputError, match=r"expected a file koeln_1_gtBbox3d\.json"):
        gt.load("koeln_1")


def test_unknown_kind():
    with pytest.raises(EvaluationInputError, match="unknown ground-truth kind"):
        open_ground_truth("nuscenes", ".")


# --- real KITTI files ------------------------------------------------------------------------------------------------

def _rows(path):
    return [ln.split() for ln in path.read_text().splitlines() if ln.strip()]


def _check_round_trip(obj, tokens, t2):
    """Every field of a label line survives: class, occlusion, truncation, box, h w l, location, ry."""
    values = [float(v) for v in tokens[1:]]
    assert obj.cls == tokens[0]
    assert obj.truncation == values[0] and obj.occlusion == int(values[1])
    np.testing.assert_array_equal(obj.box2d, values[3:7])
    if obj.cls == "DontCare":
        assert obj.cuboid_rect is None
        return
    h, w, l_ = values[7:10]
    np.testing.assert_array_equal(obj.cuboid_rect.dimensions, [l_, w, h])
    np.testing.assert_array_equal(obj.cuboid_rect.t_cam_vehicle, values[10:13])
    ry, pitch, roll = ypr_from_R_cam_vehicle(obj.cuboid_rect.R_cam_vehicle)
    # ry through a rotation matrix and atan2: exact to a few ulps of pi.
    assert abs(wrap_angle(ry - values[13])) < 1e-12 and abs(pitch) < 1e-12 and abs(roll) < 1e-12


@pytest.mark.kitti_data
def test_real_kitti_object_labels_read_without_loss(shared_data):
    root = shared_data / "kitti"
    gt = KittiObjectGroundTruth(root)
    ids = gt.image_ids()
    assert len(ids) == 24
    n_vehicles = 0
    for image_id in ids:
        image = gt.load(image_id)
        rows = _rows(root / "label_2" / f"{image_id}.txt")
        assert len(image.objects) == len(rows)  # every non-empty line became an object
        t2 = read_calib(root / "calib" / f"{image_id}.txt").camera(2).t_cam_rect
        np.testing.assert_array_equal(image.t_cam_rect, t2)
        assert 0.04 < np.linalg.norm(t2) < 0.08  # about 6 cm (SOURCES.md)
        for obj, tokens in zip(image.objects, rows, strict=True):
            _check_round_trip(obj, tokens, t2)
        n_vehicles += sum(o.cls in ("Car", "Van", "Truck") for o in image.objects)
    assert n_vehicles == 67  # SOURCES.md: Car 60, Van 4, Truck 3


@pytest.mark.kitti_data
def test_real_kitti_tracking_labels_read_without_loss(shared_data):
    root = shared_data / "kitti_tracking"
    if not (root / "label_02").is_dir():
        pytest.skip("kitti_tracking not present")
    gt = KittiTrackingGroundTruth(root)
    ids = gt.image_ids()
    # SOURCES.md: 8,008 frames, i.e. 0 to the last labelled frame of each sequence (7,924 of them have rows).
    assert len(ids) == 8008
    # Sequence 0001, read in full: every row becomes an object of its frame, values intact.
    path = root / "label_02" / "0001.txt"
    rows = _rows(path)
    frames = sorted({int(r[0]) for r in rows})
    seen = 0
    for frame in frames:
        image = gt.load(f"0001_{frame:06d}")
        frame_rows = [r for r in rows if int(r[0]) == frame]
        assert len(image.objects) == len(frame_rows)
        for obj, tokens in zip(image.objects, frame_rows, strict=True):
            assert obj.track_id == int(tokens[1])
            _check_round_trip(obj, tokens[2:], image.t_cam_rect)
        seen += len(image.objects)
    assert seen == len(rows)
    # P2 differs per recording date: fx 707.0493 for sequences 0014-0017 (SOURCES.md).
    assert gt.load(ids[-1]).K is not None
    assert gt.load("0015_000000").K[0, 0] == pytest.approx(707.0493)


def test_json_files_other_than_gtbbox3d_are_read(tmp_path):
    root = write_cityscapes(tmp_path)
    path = root / "aachen" / "aachen_000000_000019_gtBbox3d.json"
    path.rename(root / "aachen" / "aachen_000000_000019.json")
    doc = json.loads((root / "aachen" / "aachen_000000_000019.json").read_text())
    assert CityscapesGroundTruth(root).load("aachen_000000_000019").objects
    assert len(doc["objects"]) == 4


def test_one_tracking_frame_is_scored_once(tmp_path):
    """'0003_11' and '0003_000011' are one frame: a folder predicting it under both ids is refused, naming both
    (before, its objects were counted twice)."""
    from tests.eval_scenes import K_KITTI, KITTI_SIZE, kitti_pose, write_results
    from toosicubix.evaluation import evaluate_folder

    gt = write_kitti_tracking(tmp_path / "gt")
    poses = [kitti_pose(b) for b in TRACKING_FRAMES[11]]
    out = write_results(tmp_path / "out", {"0003_11": poses, "0003_000011": poses}, K_KITTI, T2, KITTI_SIZE)
    with pytest.raises(EvaluationInputError, match=r"'0003_11' .* and '0003_000011' .* are both ground-truth "
                                                   r"image '0003_000011'"):
        evaluate_folder(out, "kitti-tracking", gt)
    assert KittiTrackingGroundTruth(gt).resolve_id("0003_11") == "0003_000011"
