"""The dataset folder walkers: KITTI object, KITTI tracking, Cityscapes 3D."""

from __future__ import annotations

import numpy as np
import pytest

from toosicubix.camera import Camera
from toosicubix.errors import FormatError, InputError
from toosicubix.formats.datasets import (
    DEFAULT_IMAGE_SIZE,
    KITTI_VEHICLE_CLASSES,
    CityscapesFolder,
    KittiObjectFolder,
    KittiTrackingFolder,
    kitti_image_size,
    parse_tracking_image_id,
    tracking_image_id,
)

P2 = "721.5377 0 609.5593 44.85728 0 721.5377 172.854 0.2163791 0 0 1 0.002745884"


def _calib(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(f"P{i}: {P2}\n" for i in range(4)))


def _label(path, text="Car 0 0 0 1 2 3 40 1.5 1.6 4 1 2 10 0.1\n"):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def test_tracking_image_ids_round_trip():
    assert tracking_image_id("0010", 7) == "0010_000007"
    assert parse_tracking_image_id(tracking_image_id("0003", 123)) == ("0003", 123)
    assert parse_tracking_image_id("000123") is None and parse_tracking_image_id("a_1") is None


@pytest.mark.parametrize("layout", ["label_2", "training/label_2"])
def test_kitti_object_root_finds_labels_and_calib(tmp_path, layout):
    label_dir = tmp_path / layout
    _label(label_dir / "000002.txt")
    _label(label_dir / "000001.txt")
    _calib(label_dir.parent / "calib" / "000001.txt")
    folder = KittiObjectFolder(tmp_path)
    assert folder.label_dir == label_dir and folder.calib_dir == label_dir.parent / "calib"
    assert folder.image_ids() == ["000001", "000002"]
    camera = folder.camera("000001")
    assert camera.image_size == (1242, 375)
    # t_cam_rect = K^-1 P2[:, 3]: x = (44.85728 - 609.5593 * 0.002745884) / 721.5377, about 6 cm.
    assert camera.t_cam_rect[0] == pytest.approx((44.85728 - 609.5593 * 0.002745884) / 721.5377, abs=1e-12)
    with pytest.raises(FormatError, match=r"000002\.txt: no calibration file .*calib/000002\.txt"):
        folder.camera("000002")


def test_bare_label_folder_and_missing_calib(tmp_path):
    _label(tmp_path / "labels" / "000001.txt")
    folder = KittiObjectFolder(tmp_path / "labels")
    assert folder.label_dir == tmp_path / "labels" and folder.calib_dir is None
    assert folder.calib_file("000001") is None
    with pytest.raises(FormatError, match="expected a KITTI object folder with label_2/ and calib/"):
        folder.require_calib("000001")


def test_missing_or_empty_folder_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="ground-truth folder not found \\(kitti-tracking\\)"):
        KittiTrackingFolder(tmp_path / "absent")
    with pytest.raises(FormatError, match="expected a KITTI object root with label_2/"):
        KittiObjectFolder(tmp_path)
    _label(tmp_path / "label_2" / "000001.txt")
    with pytest.raises(FormatError, match=r"calib: expected a KITTI object folder with label_2/ and calib/"):
        KittiObjectFolder(tmp_path, strict=True)


def test_the_other_kitti_layout_is_named_with_the_option_that_reads_it(tmp_path):
    # An object folder given where tracking ground truth is expected, and the reverse (simulate's ground truth is an
    # object folder even for tracking frames): the error says which layout the folder holds and what reads it.
    _label(tmp_path / "object" / "label_2" / "000001.txt")
    with pytest.raises(FormatError, match=r"found neither \(.*object holds label_2/, KITTI object ground truth: "
                                          r"--kitti reads it\)"):
        KittiTrackingFolder(tmp_path / "object")
    _label(tmp_path / "tracking" / "training" / "label_02" / "0001.txt")
    (tmp_path / "tracking" / "training" / "calib").mkdir()
    with pytest.raises(FormatError, match=r"\(.*tracking holds label_02/, KITTI tracking ground truth: "
                                          r"--kitti-tracking reads it\)"):
        KittiObjectFolder(tmp_path / "tracking")
    with pytest.raises(FormatError, match=r"tracking/label_2: expected a KITTI object folder with label_2/ and calib/ "
                                          r"\(.*tracking holds label_02/"):
        KittiObjectFolder(tmp_path / "tracking", strict=True)
    with pytest.raises(FormatError, match=r"found neither$"):  # nothing KITTI there: no hint
        KittiObjectFolder(_empty(tmp_path))


def _empty(tmp_path):
    folder = tmp_path / "empty"
    folder.mkdir()
    return folder


def test_tracking_frames_up_to_the_last_labelled_one(tmp_path):
    _label(tmp_path / "label_02" / "0001.txt", "0 1 Car 0 0 0 1 2 3 4 1.5 1.6 4 1 2 10\n"
                                               "2 1 Car 0 0 0 1 2 3 4 1.5 1.6 4 1 2 10\n")
    _label(tmp_path / "label_02" / "0000.txt", "")
    folder = KittiTrackingFolder(tmp_path)
    assert folder.sequences() == ["0000", "0001"]
    assert folder.last_frame("0000") == -1 and folder.last_frame("0001") == 2
    assert folder.image_ids() == ["0001_000000", "0001_000001", "0001_000002"]


def test_cityscapes_prefers_gtbbox3d_and_reports_clashes(tmp_path):
    for name in ("a/x_gtBbox3d.json", "b/x.json", "a/y.json", "a/z_gtBbox3d.json", "b/z_gtBbox3d.json"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("{}")
    folder = CityscapesFolder(tmp_path)
    assert folder.image_ids() == ["x", "y", "z"]
    assert folder.files["x"] == tmp_path / "a/x_gtBbox3d.json"
    assert folder.resolve_id("x_leftImg8bit") == "x" and folder.resolve_id("w_leftImg8bit") == "w_leftImg8bit"
    assert folder.clash("x") is None
    assert folder.clash("z") == (f"image 'z': several ground-truth files have that name: "
                                 f"{tmp_path / 'a/z_gtBbox3d.json'}, {tmp_path / 'b/z_gtBbox3d.json'}")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FormatError, match="no Cityscapes 3D"):
        CityscapesFolder(tmp_path / "empty")


def test_image_size_by_focal_length():
    K = np.array([[707.0493, 0, 604.0814], [0, 707.0493, 180.5066], [0, 0, 1]])
    assert kitti_image_size(Camera(K=K)) == (1224, 370)
    assert kitti_image_size(Camera(K=np.diag([500.0, 500.0, 1.0]))) == DEFAULT_IMAGE_SIZE


def test_one_definition_of_the_vehicle_classes_and_tracking_ids():
    from toosicubix.formats import ground_truth
    from toosicubix.priors import estimation
    from toosicubix.simulate import annotator

    assert ground_truth.KITTI_DEFAULT_CLASSES is KITTI_VEHICLE_CLASSES
    assert estimation.KITTI_DEFAULT_CLASSES is KITTI_VEHICLE_CLASSES
    assert annotator.VEHICLE_CLASSES is KITTI_VEHICLE_CLASSES
    assert annotator.tracking_image_id is tracking_image_id


def test_sequence_ranges():
    from toosicubix.formats.datasets import parse_sequences

    assert parse_sequences("0010-0012, 0015") == ("0010", "0011", "0012", "0015")
    assert parse_sequences("7-9") == ("7", "8", "9")
    assert parse_sequences(None) is None
    with pytest.raises(ValueError, match="expected sequence numbers like 0010-0020 or 0001,0005, got '00x0'"):
        parse_sequences("00x0")
