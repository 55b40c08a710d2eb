"""`toosicubix eval`: exit codes, messages, outputs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from tests.eval_scenes import (
    K_KITTI,
    KITTI_SCENE,
    KITTI_SIZE,
    T2,
    kitti_pose,
    perturb,
    write_kitti_object,
    write_results,
)
from toosicubix.cli import main


@pytest.fixture
def kitti_setup(tmp_path):
    gt = write_kitti_object(tmp_path / "kitti")
    poses = {i: [perturb(k, kitti_pose(b)) for k, b in enumerate(KITTI_SCENE[i])] for i in ("000001", "000002")}
    out = write_results(tmp_path / "toosicubix-out", poses, K_KITTI, T2, KITTI_SIZE)
    return tmp_path, gt, out


def run(*args: str):
    return CliRunner().invoke(main, ["eval", *[str(a) for a in args]])


def test_success_prints_the_table_and_writes_json_and_csv(kitti_setup):
    tmp, gt, out = kitti_setup
    result = run(out, "--kitti", gt, "--json", tmp / "r" / "e.json", "--csv", tmp / "e.csv")
    assert result.exit_code == 0, result.output
    assert "IoU_KITTI" in result.stdout and "median" in result.stdout
    assert "By ground-truth depth" in result.stdout and "By KITTI occlusion level" in result.stdout
    assert "matched: 7; unmatched predictions: 0; unmatched ground truth: 0" in result.stdout
    assert "wrote" in result.stderr and "wrote" not in result.stdout
    doc = json.loads((tmp / "r" / "e.json").read_text())
    assert doc["summary"]["n_matched"] == 7
    assert (tmp / "e.csv").read_text().count("\n") == 8


def test_out_defaults_to_toosicubix_out_in_the_working_directory(kitti_setup, monkeypatch):
    tmp, _, _ = kitti_setup
    monkeypatch.chdir(tmp)
    result = run("--kitti", "kitti")
    assert result.exit_code == 0, result.output
    assert "toosicubix-out" in result.stdout


def test_kitti_root_as_label_folder_and_options(kitti_setup):
    _, gt, out = kitti_setup
    result = run(out, "--kitti", gt / "label_2", "--classes", "Car", "--min-iou", "0.7")
    assert result.exit_code == 0, result.output
    assert "classes: Car" in result.stdout and "2D box IoU >= 0.7" in result.stdout
    assert "ground truth not scored (class filter): DontCare 1, Pedestrian 1, Truck 1, Van 1" in result.stdout


def test_exactly_one_ground_truth_is_required(kitti_setup):
    _, gt, out = kitti_setup
    result = run(out)
    assert result.exit_code == 2 and "give exactly one ground truth" in result.output
    result = run(out, "--kitti", gt, "--cityscapes", gt)
    assert result.exit_code == 2 and "give exactly one ground truth" in result.output


def test_missing_folders_exit_2_with_the_path(kitti_setup):
    tmp, gt, out = kitti_setup
    result = run(tmp / "nothing-here", "--kitti", gt)
    assert result.exit_code == 2
    assert "nothing-here: prediction folder not found" in result.stderr
    result = run(out, "--kitti-tracking", tmp / "no-gt")
    assert result.exit_code == 2
    assert "no-gt: ground-truth folder not found" in result.stderr


def test_malformed_label_line_exit_2_with_file_and_line(kitti_setup):
    _, gt, out = kitti_setup
    path = gt / "label_2" / "000002.txt"
    lines = path.read_text().splitlines()
    lines[2] = lines[2].replace("Car", "Car x", 1)
    path.write_text("\n".join(lines) + "\n")
    result = run(out, "--kitti", gt)
    assert result.exit_code == 2
    assert f"Error: {path}:3: expected numbers after the type" in result.stderr


def test_prediction_without_ground_truth_partner_exit_2(kitti_setup):
    _, gt, out = kitti_setup
    (gt / "label_2" / "000002.txt").unlink()
    result = run(out, "--kitti", gt)
    assert result.exit_code == 2
    assert "no ground truth for image '000002'" in result.stderr
    assert str(Path("label_2") / "000002.txt") in result.stderr and "results.json" in result.stderr


def test_bad_option_values_exit_2(kitti_setup):
    _, gt, out = kitti_setup
    assert run(out, "--kitti", gt, "--min-iou", "2").exit_code == 2
    result = run(out, "--kitti", gt, "--classes", " , ")
    assert result.exit_code == 2 and "at least one class" in result.output


def test_warnings_go_to_stderr_and_quiet_silences_them(tmp_path):
    gt = write_kitti_object(tmp_path / "kitti", with_calib=False)
    out = write_results(tmp_path / "out", {"000001": [kitti_pose(b) for b in KITTI_SCENE["000001"]]},
                        K_KITTI, T2, KITTI_SIZE)
    result = run(out, "--kitti", gt)
    assert result.exit_code == 0
    assert "warning: no calib file for 1 image(s)" in result.stderr
    assert "warning:" not in result.stdout
    result = run(out, "--kitti", gt, "-q")
    assert result.exit_code == 0 and result.stderr == ""


def test_help_has_an_example():
    result = CliRunner().invoke(main, ["eval", "--help"])
    assert result.exit_code == 0
    assert "Example:" in result.output and "--kitti-tracking" in result.output and "--cityscapes" in result.output


def test_a_folder_is_never_scored_against_itself(kitti_setup):
    # issue 13: fit -o on a KITTI root, then eval on that root, scored predictions against themselves
    _, gt, out = kitti_setup
    cases = [(gt, gt, "is"), (gt / "label_2", gt, "is inside"), (out, out / "label_2", "contains")]
    for pred, truth, relation in cases:
        result = run(pred, "--kitti", truth)
        assert result.exit_code == 2, result.output
        assert f"predictions folder {relation} the ground-truth folder" in result.output
        assert "against itself" in result.output
