"""Hostile ground truth: every case of issue 13 is exit 2 with the file and line, never a traceback or a nan."""

import math
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from tests.conftest import REPO
from toosicubix.cli import main
from toosicubix.errors import FormatError
from toosicubix.evaluation.report import _cell, metric_stats
from toosicubix.formats.kitti import MAX_FRAME, KittiObject, format_label_line, read_calib, read_label_file

SAMPLE_GT = REPO / "samples" / "ground_truth"
P2 = "720 0 620 43.2 0 720 180 0 0 0 1 0"


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    out = tmp_path_factory.mktemp("fit") / "out"
    result = CliRunner().invoke(main, ["fit", str(REPO / "samples" / "annotations.json"), "-q", "-o", str(out)])
    assert result.exit_code == 0, result.output
    return out


def ground_truth(tmp_path):
    gt = tmp_path / "gt"
    shutil.copytree(SAMPLE_GT, gt)
    return gt, gt / "label_2" / "000001.txt", gt / "calib" / "000001.txt"


def replace_calib(path, key, values):
    lines = [f"{key}: {values}" if ln.startswith(f"{key}:") else ln for ln in path.read_text().splitlines()]
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize(("mutate", "where", "fragment"), [
    (lambda lab, cal: lab.write_bytes(lab.read_bytes() + b"Car \xff\n"), "label_2/000001.txt:4",
     "not UTF-8 text: invalid start byte"),
    (lambda lab, cal: cal.write_bytes(b"\xfe" + cal.read_bytes()), "calib/000001.txt:1", "not UTF-8 text"),
    (lambda lab, cal: replace_calib(cal, "P2", " ".join(["0"] * 12)), "calib/000001.txt:3", "P2 is not a camera"),
    (lambda lab, cal: replace_calib(cal, "P2", "720 0 620 43 0 720 180 0 0 0 0 0"), "calib/000001.txt:3",
     "last row of K to be [0, 0, 1]"),
    (lambda lab, cal: replace_calib(cal, "P2", P2.replace("720", "nan", 1)), "calib/000001.txt:3", "finite numbers"),
    (lambda lab, cal: replace_calib(cal, "P2", P2.replace("43.2", "inf")), "calib/000001.txt:3", "finite numbers"),
    (lambda lab, cal: lab.write_text(lab.read_text().replace("14.0000", "1e308", 1)), "label_2/000001.txt:1",
     "location within 10000 m"),
    (lambda lab, cal: lab.write_text(lab.read_text().replace("4.1000", "1e308", 1)), "label_2/000001.txt:1",
     "at most 100 m"),
])
def test_hostile_kitti_ground_truth_exits_2_naming_file_and_line(tmp_path, fitted, mutate, where, fragment):
    gt, label, calib = ground_truth(tmp_path)
    mutate(label, calib)
    json_out = tmp_path / "eval.json"
    result = CliRunner().invoke(main, ["eval", str(fitted), "--kitti", str(gt), "-q", "--json", str(json_out)])
    assert result.exit_code == 2, result.output
    assert f"{gt}/{where}: " in result.output and fragment in result.output, result.output
    assert result.exc_info is None or isinstance(result.exc_info[1], SystemExit)
    assert not json_out.exists()


def test_byte_order_mark_is_stripped(tmp_path, fitted):
    gt, label, _ = ground_truth(tmp_path)
    plain = CliRunner().invoke(main, ["eval", str(fitted), "--kitti", str(gt), "-q"])
    label.write_bytes(b"\xef\xbb\xbf" + label.read_bytes())
    assert read_label_file(label)[0].type == "Car"  # was '\ufeffCar', an unscored class
    with_bom = CliRunner().invoke(main, ["eval", str(fitted), "--kitti", str(gt), "-q"])
    assert with_bom.exit_code == plain.exit_code == 0
    assert with_bom.stdout.replace(str(gt), "") == plain.stdout.replace(str(gt), "")


def test_a_huge_tracking_frame_is_refused_before_allocation(tmp_path):
    root = tmp_path / "tracking"
    (root / "label_02").mkdir(parents=True)
    (root / "calib").mkdir()
    line = "30000000 1 Car 0 0 -1.5 100 100 200 200 1.5 1.6 4.0 1.0 1.6 20.0 -1.5\n"
    (root / "label_02" / "0000.txt").write_text(line)
    (root / "calib" / "0000.txt").write_text("\n".join(f"P{k}: {P2}" for k in range(4)) + "\n")
    out = tmp_path / "out"
    (out / "label_2").mkdir(parents=True)
    (out / "label_2" / "0000_000000.txt").write_text("")
    result = CliRunner().invoke(main, ["eval", str(out), "--kitti-tracking", str(root), "-q"])
    assert result.exit_code == 2, result.output
    assert f"label_02/0000.txt:1: expected a frame number from 0 to {MAX_FRAME}, got 30000000" in result.output


def test_read_calib_rejects_a_singular_P2(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text("\n".join(f"P{k}: {P2 if k != 2 else ' '.join(['0'] * 12)}" for k in range(4)) + "\n")
    with pytest.raises(FormatError, match=r"calib.txt:3: P2 is not a camera"):
        read_calib(path)


def test_no_nan_is_ever_a_mean_or_a_cell():
    class Metrics:
        def __init__(self, v):
            self.iou = self.siou = self.e_r_deg = self.e_t = self.e_d = self.e_comb = self.iou_kitti = v
            self.e_yaw_deg = v

    class Record:
        def __init__(self, v):
            self.metrics = Metrics(v)

    stats = metric_stats([Record(0.5), Record(float("nan"))])
    assert all(v is None for v in stats.values())
    assert _cell(float("nan"), "iou") == "-" and _cell(float("inf"), "e_r_deg") == "-"
    assert math.isclose(metric_stats([Record(0.5), Record(0.7)])["iou_mean"], 0.6)


def test_the_label_writer_refuses_nan():
    obj = KittiObject(type="Car", truncated=0.0, occluded=3, alpha=0.1, box2d=np.array([1.0, 2.0, 3.0, 4.0]),
                      dimensions=np.array([4.0, 1.7, np.nan]), location_rect=np.array([1.0, 1.5, 20.0]),
                      rotation_y=0.2, score=0.9)
    with pytest.raises(ValueError, match="refusing to write a KITTI label with a NaN or infinity"):
        format_label_line(obj)
