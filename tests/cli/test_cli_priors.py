"""`toosicubix priors`: exit codes, warnings, --base, and files that load as priors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from tests.eval_scenes import write_cityscapes
from tests.priors.test_prior_estimation import small_tracking, tracking_line, write_tracking
from toosicubix.annotations.priors_file import load_priors, load_priors_file
from toosicubix.cli import main
from toosicubix.priors.estimation import make_positive_definite
from toosicubix.size_priors import bundled_priors_path


def run(*args):
    return CliRunner().invoke(main, ["priors", *[str(a) for a in args]])


@pytest.fixture
def tracking(tmp_path):
    return small_tracking(tmp_path / "kitti_tracking")


def test_tracking_priors_are_written_validated_and_summarised(tmp_path, tracking):
    out = tmp_path / "priors.json"
    result = run("--kitti-tracking", tracking, "--min-samples", "2", "-o", out)
    assert result.exit_code == 0, result.output
    assert "Car: n=5 tracks, mean (dx, dy, dz) = (" in result.stderr
    assert f"wrote 1 priors to {out}" in result.stderr and result.stdout == ""
    # Van and Truck have one track each: no covariance, skipped with a warning.
    assert "warning: Van: only 1 sample; at least 2 are needed for a covariance, skipped" in result.stderr
    doc = load_priors_file(out)
    assert list(doc.prototypes) == ["Car"] and doc.prototypes["Car"].kitti_type == "Car"
    assert doc.prototypes["Car"].source.startswith(f"toosicubix priors --kitti-tracking {tracking}: ")
    assert load_priors(out)["Car"].n == 5


def test_small_classes_are_written_and_named_in_a_warning(tmp_path, tracking):
    out = tmp_path / "priors.json"
    result = run("--kitti-tracking", tracking, "-o", out)
    assert result.exit_code == 0, result.output
    assert "warning: Car: only 5 samples (fewer than 20); written, but its spread is poorly determined" in \
        result.stderr
    assert "only 5 samples (fewer than 20)" in load_priors_file(out).prototypes["Car"].source


def test_base_keeps_every_other_entry(tmp_path, tracking):
    base = tmp_path / "base.json"
    base.write_text(bundled_priors_path().read_text())
    result = run("--kitti-tracking", tracking, "--min-samples", "2", "--base", base, "-o", base)
    assert result.exit_code == 0, result.output
    before, after = load_priors_file(bundled_priors_path()), load_priors_file(base)
    assert f"kept {len(before.prototypes) - 1} other entries of {base}" in result.stderr
    assert list(after.prototypes) == list(before.prototypes)
    assert after.prototypes["Car"] != before.prototypes["Car"] and after.prototypes["Car"].n == 5
    assert all(after.prototypes[k] == v for k, v in before.prototypes.items() if k != "Car")


def test_sequences_classes_and_whitened_covariance(tmp_path, tracking):
    out = tmp_path / "priors.json"
    result = run("--kitti-tracking", tracking, "--sequences", "0000", "--classes", "car", "--min-samples", "2",
                 "--covariance", "whitened", "-o", out)
    assert result.exit_code == 0, result.output
    entry = load_priors_file(out).prototypes["Car"]
    assert entry.n == 4  # tracks 1-4 of sequence 0000
    assert "--sequences 0000 --classes car --covariance whitened:" in entry.source
    assert "sequences 0000, one sample per track" in entry.source and "whitened fixed point" in entry.source


def test_cityscapes_prototypes_map_to_kitti_types(tmp_path):
    out = tmp_path / "priors.json"
    result = run("--cityscapes", write_cityscapes(tmp_path / "cs"), "--min-samples", "3", "-o", out)
    assert result.exit_code == 0, result.output
    entry = load_priors_file(out).prototypes["Mid Size Car"]
    assert entry.kitti_type == "Car" and entry.n == 4
    assert "warning: Mini Truck: only 1 sample" in result.stderr


def test_apollocar3d_cars_give_priors_per_prototype_of_their_type(tmp_path):
    # Three saloons of model 0 and two of model 1, two hatchbacks of model 2; each labelled car counts once,
    # with its car model's extents.
    models = {"0": {"type": "3x", "length": 4.8, "width_body": 1.8, "height": 1.45},
              "1": {"type": "3x", "length": 4.6, "width_body": 1.75, "height": 1.5},
              "2": {"type": "2x", "length": 4.2, "width_body": 1.72, "height": 1.52}}
    cars = [0, 0, 0, 1, 1, 2, 2]
    coco = {"images": [{"id": 1, "file_name": "a_Camera_5.jpg"}], "categories": [],
            "annotations": [{"id": k, "image_id": 1, "category_id": m, "bbox": [10, 20, 30, 40],
                             "keypoints": [0, 0, 0] * 66, "pose": [3.14, 0.0, 0.0, 0.0, 1.0, 20.0 + 5 * k]}
                            for k, m in enumerate(cars)]}
    keypoints, car_models = tmp_path / "kp.json", tmp_path / "models.json"
    keypoints.write_text(json.dumps(coco))
    car_models.write_text(json.dumps(models))
    out = tmp_path / "priors.json"
    result = run("--apollocar3d", keypoints, "--car-models", car_models, "--min-samples", "2", "-o", out)
    assert result.exit_code == 0, result.output
    doc = load_priors_file(out)
    assert sorted(doc.prototypes) == ["Car", "Sedan"]
    sedan = doc.prototypes["Sedan"]
    assert sedan.n == 5 and sedan.kitti_type == "Car"
    # Exact CAD extents: the samples' own mean and covariance (n - 1), not medians, which would sit on model 0.
    sizes = np.array([[4.8, 1.8, 1.45]] * 3 + [[4.6, 1.75, 1.5]] * 2)
    assert sedan.mean == pytest.approx(sizes.mean(axis=0), abs=1e-4)  # the file keeps 0.1 mm
    # Two sizes span one direction: the others are raised to the positive-definite floor, as every method's are.
    expected, floored = make_positive_definite(np.cov(sizes, rowvar=False))
    assert floored == 2
    np.testing.assert_allclose(sedan.cov, expected, rtol=1e-8, atol=1e-15)  # 9 significant digits in the file
    assert doc.prototypes["Car"].n == 2
    assert sedan.source.startswith(f"toosicubix priors --apollocar3d {keypoints} --car-models {car_models}: ")
    assert "cov = sample covariance (n - 1)" in sedan.source
    assert "Sedan: n=5 cars" in result.stderr
    assert "repeated size" not in result.stderr

    # The paper's estimator, asked for, sits on the majority model (found as a data point by its optimality
    # test, exact) and is warned about: 60 % of the saloons are one size.
    result = run("--apollocar3d", keypoints, "--car-models", car_models, "--min-samples", "2",
                 "--covariance", "paper", "-o", out)
    assert result.exit_code == 0, result.output
    sedan = load_priors_file(out).prototypes["Sedan"]
    assert sedan.mean == pytest.approx([4.8, 1.8, 1.45], abs=1e-9)
    assert "--covariance paper" in sedan.source
    assert "warning: Sedan: 60 % of its samples are one repeated size" in result.stderr


def test_quiet_prints_nothing(tmp_path, tracking):
    result = run("--kitti-tracking", tracking, "-q", "-o", tmp_path / "p.json")
    assert result.exit_code == 0 and result.stderr == ""


@pytest.mark.parametrize(("args", "message"), [
    ([], "give exactly one ground truth"),
    (["--kitti", "a", "--kitti-tracking", "b"], "give exactly one ground truth"),
    (["--kitti", "{gt}", "--sequences", "0000"], "--sequences applies to --kitti-tracking only"),
    (["--kitti-tracking", "{gt}", "--sequences", "00x0"], "expected sequence numbers like 0010-0020"),
    (["--kitti-tracking", "{gt}", "--sequences", "0007"], "no label file for the requested sequences"),
    (["--kitti-tracking", "{gt}", "--classes", " , "], "expected at least one class name"),
    (["--kitti-tracking", "{gt}", "--classes", "Tram"], "no class gave a prior"),
    (["--kitti-tracking", "{tmp}/absent"], "ground-truth folder not found"),
    (["--kitti-tracking", "{gt}", "--car-models", "{tmp}/models.json"], "--car-models goes with --apollocar3d only"),
])
def test_bad_input_exits_2(tmp_path, tracking, args, message):
    args = [a.format(gt=tracking, tmp=tmp_path) for a in args]
    result = run(*args, "-o", tmp_path / "p.json")
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert not (tmp_path / "p.json").exists()


def test_malformed_label_exits_2_naming_file_and_line(tmp_path):
    gt = write_tracking(tmp_path / "gt", {"0000": [tracking_line(0, 1, "Car", (4.0, 1.6, 1.5)), "0 2 Car x"]})
    result = run("--kitti-tracking", gt, "-o", tmp_path / "p.json")
    assert result.exit_code == 2
    assert f"Error: {gt / 'label_02' / '0000.txt'}:2: expected 17 or 18 fields" in result.stderr


def test_bad_base_file_exits_2(tmp_path, tracking):
    base = tmp_path / "base.json"
    base.write_text(json.dumps({"toosicubix_priors": 1, "prototypes": {}}))
    result = run("--kitti-tracking", tracking, "--base", base, "-o", tmp_path / "p.json")
    assert result.exit_code == 2
    assert f"{base}: $.prototypes" in result.stderr


def test_unwritable_output_exits_2(tmp_path, tracking):
    result = run("--kitti-tracking", tracking, "--min-samples", "2", "-o", tmp_path / "no" / "p.json")
    assert result.exit_code == 2 and "cannot write" in result.stderr


def test_help_has_an_example():
    result = CliRunner().invoke(main, ["priors", "--help"])
    assert result.exit_code == 0 and "Example:" in result.output and "--kitti-tracking" in result.output
