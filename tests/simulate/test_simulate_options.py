"""simulate's options are checked in the library, and its CLI exits 2 for every hostile case of issue 13."""

import shutil

import pytest
from click.testing import CliRunner

from tests.conftest import REPO
from toosicubix.cli import main
from toosicubix.simulate.annotator import AnnotatorOptions, SelectionOptions

SAMPLE_GT = REPO / "samples" / "ground_truth"


@pytest.mark.parametrize(("make", "fragment"), [
    (lambda: AnnotatorOptions(noise_px=float("inf")), "noise_px"),
    (lambda: AnnotatorOptions(noise_px=float("nan")), "noise_px"),  # was: noise-free clicks, silently
    (lambda: AnnotatorOptions(noise_px=-1.0), "noise_px"),
    (lambda: AnnotatorOptions(max_clicks=0), "max_clicks"),
    (lambda: SelectionOptions(max_depth=float("nan")), "max_depth"),  # was: 0 vehicles, exit 0
    (lambda: SelectionOptions(min_depth=50.0, max_depth=10.0), "max_depth"),
    (lambda: SelectionOptions(min_depth=float("-inf")), "min_depth"),
    (lambda: SelectionOptions(min_box_height=float("nan")), "min_box_height"),
    (lambda: SelectionOptions(max_truncation=float("nan")), "max_truncation"),
    (lambda: SelectionOptions(frames_per_track=0), "frames_per_track"),
])
def test_bad_options_are_refused_by_the_library(make, fragment):
    with pytest.raises(ValueError, match=f"option {fragment}: expected a number from"):
        make()


def test_defaults_pass():
    AnnotatorOptions()
    SelectionOptions()
    SelectionOptions(frames_per_track=None, min_depth=0.0, max_depth=0.0)


def run_simulate(tmp_path, *args, out=None, mutate=None):
    gt = tmp_path / "gt"
    shutil.copytree(SAMPLE_GT, gt)
    if mutate is not None:
        mutate(gt)
    out = out or str(tmp_path / "sim.json")
    result = CliRunner().invoke(main, ["simulate", "--kitti", str(gt), "-o", out, *args])
    assert result.exc_info is None or isinstance(result.exc_info[1], SystemExit), result.exc_info
    return result


@pytest.mark.parametrize(("args", "fragment"), [
    (["--noise", "inf"], "'--noise': 'inf' is not a finite number"),  # refused by the option itself
    (["--noise", "nan"], "'--noise': 'nan' is not a finite number"),
    (["--max-depth", "nan"], "'--max-depth': 'nan' is not a finite number"),
    (["--min-depth", "50", "--max-depth", "10"], "option max_depth"),
])
def test_cli_bad_options_exit_2_and_write_nothing(tmp_path, args, fragment):
    result = run_simulate(tmp_path, *args)
    assert result.exit_code == 2 and fragment in result.output, result.output
    assert not (tmp_path / "sim.json").exists() and not (tmp_path / "sim_gt").exists()


def test_cli_hostile_files_exit_2(tmp_path):
    calib = "calib/000001.txt"
    result = run_simulate(tmp_path, mutate=lambda gt: (gt / calib).write_text(
        (gt / calib).read_text().replace("P2: 7.2", "P2: 0.0", 1)))
    assert result.exit_code == 2 and f"{calib}:3: P2 is not a camera" in result.output, result.output
    shutil.rmtree(tmp_path / "gt")
    label = "label_2/000002.txt"
    result = run_simulate(tmp_path, mutate=lambda gt: (gt / label).write_bytes(b"\xff" + (gt / label).read_bytes()))
    assert result.exit_code == 2 and f"{label}:1: not UTF-8 text" in result.output, result.output
    assert not (tmp_path / "sim.json").exists()


def test_cli_output_names(tmp_path):
    same = str(tmp_path / "same.json")
    result = run_simulate(tmp_path, "--gt-out", same, out=same)
    assert result.exit_code == 2 and "must be apart" in result.output, result.output
    assert not (tmp_path / "same.json").exists()
    shutil.rmtree(tmp_path / "gt")
    long_name = str(tmp_path / ("s" * 300 + ".json"))
    result = run_simulate(tmp_path, out=long_name)
    assert result.exit_code == 2 and "a file name of 305 bytes; at most 240" in result.output, result.output
    assert list(tmp_path.iterdir()) == [tmp_path / "gt"]
