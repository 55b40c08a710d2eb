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
@main.command("eval")
@click.argument("out", required=False, default=DEFAULT_OUTPUT_DIR, type=click.Path(file_okay=False, path_type=Path))
@click.option("--kitti", "kitti_dir", type=click.Path(path_type=Path), default=None,
              help="KITTI object ground truth: a root with label_2/ and calib/, or a folder of label .txt files "
                   "(calib then looked for beside it). Example: --kitti data/kitti")
@click.option("--kitti-tracking", "tracking_dir", type=click.Path(path_type=Path), default=None,
              help="KITTI tracking ground truth: a root with label_02/<seq>.txt and calib/<seq>.txt; image ids are "
                   "<seq>_<frame as 6 digits>. Example: --kitti-tracking data/kitti_tracking")
@click.option("--cityscapes", "cityscapes_dir", type=click.Path(path_type=Path), default=None,
              help="Cityscapes 3D ground truth: a folder searched recursively for *_gtBbox3d.json; image id = file "
                   "stem without _gtBbox3d. Example: --cityscapes gtBbox3d/val")
@click.option("--min-iou", type=click.FloatRange(0.0, 1.0), default=0.5, show_default=True,
              help="2D box IoU a prediction and a ground-truth object need to be paired. Example: --min-iou 0.3")
@click.option("--classes", default=None,
              help="Comma-separated ground-truth classes to score, case-insensitive [default: Car,Van,Truck for "
                   "KITTI; car,truck,bus,caravan,trailer,train for Cityscapes]. Example: --classes Car,Van")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write the summary, every matched object and the unmatched ones as JSON. "
                   "Example: --json eval.json")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write one CSV row per matched object. Example: --csv eval.csv")
@click.option("-q", "--quiet", is_flag=True, help="No warnings or notes on stderr; the table still goes to stdout.")
def eval_command(out: Path, kitti_dir: Path | None, tracking_dir: Path | None, cityscapes_dir: Path | None,
                 min_iou: float, classes: str | None, json_path: Path | None, csv_path: Path | None,
                 quiet: bool) -> None:
    """Score fitted cuboids against KITTI or Cityscapes 3D ground truth, as the paper's Evaluation does.

    Reads OUT (a `toosicubix fit` output folder, default toosicubix-out): results.json with full rotations,
    else label_2/*.txt read as yaw only. Pairs each predicted image with its ground truth by id (file stem),
    matches objects by 2D box IoU (Hungarian), and reports per metric the mean and median: exact 3D IoU with
    full rotations, sIoU, E_R (degrees), E_t, E_d, E_comb, plus KITTI's yaw-only IoU for comparison; then
    breakdowns by depth and occlusion, and the unmatched objects. Poses are compared in the camera frame of
    the prediction's K. The table goes to stdout, warnings to stderr.

    Exit code 0 on success, 2 for a missing folder, a malformed file or a predicted image without ground truth.

    \b
    Example:
      toosicubix eval --kitti data/kitti
      toosicubix eval runs/kitti-out --kitti data/kitti --json eval.json --csv eval.csv
    """
    from .evaluation import EvalOptions, EvaluationInputError, evaluate_folder, format_report, write_csv, write_json
    from .formats import FormatError

    given = [(kind, path) for kind, path in (("kitti", kitti_dir), ("kitti-tracking", tracking_dir),
                                             ("cityscapes", cityscapes_dir)) if path is not None]
    if len(given) != 1:
        raise click.UsageError("give exactly one ground truth: --kitti DIR, --kitti-tracking DIR or --cityscapes DIR")
    gt_kind, gt_dir = given[0]
    class_list = tuple(c.strip() for c in classes.split(",") if c.strip()) if classes is not None else None
    if class_list is not None and not class_list:
        raise click.BadParameter("expected at least one class name", param_hint="--classes")
    try:
        result = evaluate_folder(out, gt_kind, gt_dir, EvalOptions(min_iou=min_iou, classes=class_list))
    except (EvaluationInputError, FormatError) as exc:
        raise BadInput(str(exc)) from None
    if not quiet:
        for warning in result.warnings:
            click.echo(f"warning: {warning}", err=True)
    click.echo(format_report(result), nl=False)
    try:
        if json_path is not None:
            write_json(result, json_path)
        if csv_path is not None:
            write_csv(result, csv_path)
    except OSError as exc:
        raise BadInput(f"cannot write {exc.filename}: {exc.strerror or exc}") from None
    if not quiet:
        written = [str(p) for p in (json_path, csv_path) if p is not None]
        if written:
            click.echo(f"wrote {' and '.join(written)}", err=True)
# --- end of eval -----------------------------------------------------------------------------------------


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
