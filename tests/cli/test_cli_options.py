"""The shared CLI pieces: one ground-truth option set, one input-error handler, one-line registration."""

from __future__ import annotations

import click
import pytest
from click.testing import CliRunner

from toosicubix.cli import main
from toosicubix.cli.options import BadInput, CommandGroup, GroundTruth, ground_truth_options
from toosicubix.errors import FormatError, InputError


def _group() -> click.Group:
    @click.group(cls=CommandGroup)
    def group() -> None:
        """A test group."""

    @click.command("show")
    @ground_truth_options()
    def show(ground_truth: GroundTruth) -> None:
        click.echo(f"{ground_truth.kind} {ground_truth.root} {ground_truth.flag}")

    @click.command("broken")
    def broken() -> None:
        raise FormatError("labels/000001.txt", "expected 15 or 16 fields", 3)

    group.add_command(show)
    group.add_command(broken)
    return group


def test_exactly_one_ground_truth_reaches_the_command(tmp_path):
    group = _group()
    result = CliRunner().invoke(group, ["show", "--kitti-tracking", str(tmp_path)])
    assert result.exit_code == 0 and result.output == f"kitti-tracking {tmp_path} --kitti-tracking\n"
    for args in ([], ["--kitti", "a", "--cityscapes", "b"]):
        result = CliRunner().invoke(group, ["show", *args])
        assert result.exit_code == 2
        assert ("give exactly one ground truth: --kitti DIR, --kitti-tracking DIR or --cityscapes DIR"
                in result.output)


def test_an_input_error_a_command_lets_through_exits_2_naming_file_and_line():
    result = CliRunner().invoke(_group(), ["broken"])
    assert result.exit_code == 2
    assert result.output == "Error: labels/000001.txt:3: expected 15 or 16 fields\n"


def test_bad_input_is_an_input_error():
    error = BadInput("cannot write out.json: Permission denied")
    assert isinstance(error, InputError) and isinstance(error, click.ClickException)
    assert str(error) == "cannot write out.json: Permission denied" and error.exit_code == 2


def test_the_ground_truth_options_are_declared_once():
    helps = {}
    for name in ("eval", "priors", "tune", "simulate"):
        for param in main.commands[name].params:
            if param.name.startswith("ground_truth_"):
                helps.setdefault(param.name, set()).add(param.help)
    assert set(helps) == {"ground_truth_kitti", "ground_truth_kitti_tracking", "ground_truth_cityscapes",
                          "ground_truth_apollocar3d"}  # ApolloCar3D's keypoint file: eval, priors (and render) only
    assert all(len(texts) == 1 for texts in helps.values())
    assert not any(p.name == "ground_truth_apollocar3d" for name in ("tune", "simulate")
                   for p in main.commands[name].params)
    car_models = [p.help for name in ("eval", "priors") for p in main.commands[name].params
                  if p.name == "car_models_path"]
    assert len(car_models) == 2 and len(set(car_models)) == 1  # one shared option


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "1e308"])
def test_number_options_refuse_what_is_not_a_finite_setting(tmp_path, value):
    # click's own range passes nan (it fails no comparison); --frame-rate inf made every track's times 0.
    result = CliRunner().invoke(main, ["fit", "missing.json", "-o", str(tmp_path / "out"), "--frame-rate", value])
    assert result.exit_code == 2 and "--frame-rate" in result.output, result.output
    if value != "1e308":  # a finite click noise, however large, is the user's to give
        result = CliRunner().invoke(main, ["fit", "missing.json", "--click-sigma", value])
        assert result.exit_code == 2 and "--click-sigma" in result.output, result.output
