"""The ``toosicubix`` command. Thin: parses options, calls the library, reports, sets the exit code.

Exit codes: 0 success; 1 a batch finished but some vehicles failed; 2 bad input or usage.
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import click

from . import __version__
from .formats.results import DEFAULT_OUTPUT_DIR
from .solver import SolverOptions

EXIT_OK, EXIT_SOME_FAILED, EXIT_BAD_INPUT = 0, 1, 2


class BadInput(click.ClickException):
    """A bad input file or option value: printed as is, exit code 2."""

    exit_code = EXIT_BAD_INPUT

    def show(self, file=None) -> None:
        click.echo(f"Error: {self.format_message()}", err=True)


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, "--version", prog_name="toosicubix")
def main() -> None:
    """ToosiCubix: 3D vehicle cuboids (rotation, position, size) from part clicks in one image.

    \b
    Typical use:
      toosicubix fit annotations.json          # writes toosicubix-out/label_2/*.txt, results.json
      toosicubix eval --kitti path/to/kitti    # scores toosicubix-out against KITTI ground truth
    """


@main.command("schema")
def schema_command() -> None:
    """Print the JSON Schema of the annotation file (format version 1).

    \b
    Example:
      toosicubix schema > annotations.schema.json
    """
    from .schemas import json_schema

    click.echo(json.dumps(json_schema(), indent=2))


@main.command("fit")
@click.argument("annotations", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=DEFAULT_OUTPUT_DIR, show_default=True,
              help="Output folder: label_2/<image id>.txt (KITTI) and results.json.")
@click.option("--priors", "priors_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Size priors file (JSON, see README); default: the bundled KITTI and Cityscapes 3D table.")
@click.option("--lambda", "lambda_3d", type=click.FloatRange(min=0.0, min_open=True),
              default=SolverOptions.lambda_3d, show_default=True,
              help="Weight of the size prior in the coordinate descent's 3D cost.")
@click.option("--lambda-p", "lambda_px", type=click.FloatRange(min=0.0, min_open=True),
              default=SolverOptions.lambda_px, show_default=True,
              help="Weight of the size prior in the pixel cost, in px^2 per squared Mahalanobis unit: the click "
                   "noise variance at which clicks and prior are weighed evenly. Smaller trusts the clicks more.")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar or summary on stderr.")
def fit_command(annotations: Path, out_dir: Path, priors_path: Path | None, lambda_3d: float, lambda_px: float,
                quiet: bool) -> None:
    """Fit a 3D cuboid to every annotated vehicle.

    Reads ANNOTATIONS (annotation file v1, see `toosicubix schema`) and writes OUT/label_2/<image id>.txt
    in KITTI format plus OUT/results.json with the full pose of every vehicle. KITTI files store yaw only:
    pitch and roll are dropped there and kept in results.json.

    Exit code 0 when every vehicle was fitted, 1 when some failed (their reasons are in results.json
    and on stderr; the others are written), 2 for a bad input file or option.

    \b
    Example:
      toosicubix fit samples/annotations.json -o toosicubix-out
    """
    from .batch import OutputFolderError, fit_file
    from .schemas import InputFileError

    options = replace(SolverOptions(), lambda_3d=lambda_3d, lambda_px=lambda_px)
    bar = _ProgressBar(quiet)
    try:
        summary = fit_file(annotations, out_dir, priors_path, options, progress=bar.update, on_start=bar.start)
    except (InputFileError, OutputFolderError) as exc:
        raise BadInput(str(exc)) from None
    finally:
        bar.finish()
    if not quiet:
        click.echo(
            f"fitted {summary.ok} of {summary.vehicles} vehicles in {summary.images} images -> "
            f"{summary.out_dir / 'label_2'} (KITTI: yaw only, pitch and roll dropped) and "
            f"{summary.out_dir / 'results.json'} (full rotations)",
            err=True,
        )
        for image_id, vehicle_id, reason in summary.failed[:20]:
            click.echo(f"  failed: image {image_id} vehicle {vehicle_id}: {reason}", err=True)
        if len(summary.failed) > 20:
            click.echo(f"  ... and {len(summary.failed) - 20} more failed vehicles (see results.json)", err=True)
    sys.exit(EXIT_SOME_FAILED if summary.failed else EXIT_OK)


class _ProgressBar:
    """A progress bar on stderr for batches of more than a few vehicles."""

    MIN_VEHICLES = 50

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.bar = None

    def start(self, total: int) -> None:
        if not self.quiet and total >= self.MIN_VEHICLES:
            self.bar = click.progressbar(length=total, label="fitting", file=sys.stderr, show_eta=True)
            self.bar.__enter__()

    def update(self, n: int) -> None:
        if self.bar is not None:
            self.bar.update(n)

    def finish(self) -> None:
        if self.bar is not None:
            self.bar.__exit__(None, None, None)
            self.bar = None


# --- eval: owned by the evaluation module; keep edits inside this section ---------------------------------
# --- end of eval -----------------------------------------------------------------------------------------


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
