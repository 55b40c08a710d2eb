"""The README's set-up commands, CI and the CLI help stay in step."""

import subprocess

from click.testing import CliRunner

from tests.conftest import REPO
from toosicubix.cli import main


def readme_commands() -> list[str]:
    lines = (REPO / "README.md").read_text().splitlines()
    start = lines.index("```sh")
    return lines[start + 1: lines.index("```", start)]


def test_readme_opens_with_the_two_setup_commands():
    lines = (REPO / "README.md").read_text().splitlines()
    assert lines[0] == "# ToosiCubix" and lines[2] == "```sh"
    install_and_fit, install_and_test = readme_commands()
    assert install_and_fit == "python -m pip install . && toosicubix fit samples/annotations.json"
    assert install_and_test.startswith("python -m pip install '.[test]' && ")
    assert install_and_test.endswith("python -m pytest -q")


def test_ci_runs_exactly_the_readme_test_command():
    script = REPO / ".ci" / "run"
    extracted = subprocess.run(
        ["bash", "-c", "sed -n '/^```sh$/,/^```$/p' README.md | sed -n '3p'"],
        cwd=REPO, capture_output=True, text=True, check=True,
    ).stdout.strip()
    assert extracted == readme_commands()[1]
    assert "sed -n '/^```sh$/,/^```$/p' README.md | sed -n '3p'" in script.read_text()


def test_readme_says_kitti_files_drop_pitch_and_roll():
    text = (REPO / "README.md").read_text()
    assert "KITTI files store yaw only: the fitted pitch and roll are dropped there" in text


def test_every_command_has_help_with_an_example():
    runner = CliRunner()
    for name, command in main.commands.items():
        assert command.help, name
        result = runner.invoke(main, [name, "--help"])
        assert result.exit_code == 0
        assert "Example:" in result.output, name
