"""The ``toosicubix`` command. Thin: parses options, calls the library, reports, sets the exit code.

Exit codes: 0 success; 1 a batch finished but some vehicles failed; 2 bad input or usage.
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import click
import numpy as np

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
@click.option("-j", "--jobs", type=click.IntRange(min=1), default=1, show_default=True,
              help="Worker processes; the output is the same for any number.")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar or summary on stderr.")
def fit_command(annotations: Path, out_dir: Path, priors_path: Path | None, lambda_3d: float, lambda_px: float,
                jobs: int, quiet: bool) -> None:
    """Fit a 3D cuboid to every annotated vehicle.

    Reads ANNOTATIONS (annotation file v1, see `toosicubix schema`) and writes OUT/label_2/<image id>.txt
    in KITTI format plus OUT/results.json with the full pose of every vehicle. KITTI files store yaw only:
    pitch and roll are dropped there and kept in results.json.

    Exit code 0 when every vehicle was fitted, 1 when some failed (their reasons are in results.json
    and on stderr; the others are written), 2 for a bad input file or option.

    \b
    Example:
      toosicubix fit samples/annotations.json -o toosicubix-out
      toosicubix fit big.json --jobs 2
    """
    from .batch import OutputFolderError, fit_file
    from .schemas import InputFileError

    options = replace(SolverOptions(), lambda_3d=lambda_3d, lambda_px=lambda_px)
    bar = _ProgressBar(quiet)
    try:
        summary = fit_file(annotations, out_dir, priors_path, options, progress=bar.update, on_start=bar.start,
                           jobs=jobs)
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


def _parse_sequences(value: str | None) -> tuple[str, ...] | None:
    """'0010-0020' or '0001,0005,0007' -> sequence names."""
    if value is None:
        return None
    names: list[str] = []
    for item in value.split(","):
        item = item.strip()
        first, dash, last = item.partition("-")
        if not (first.isdigit() and (not dash or last.isdigit())):
            raise click.BadParameter(f"expected sequence numbers like 0010-0020 or 0001,0005, got {item!r}",
                                     param_hint="--sequences")
        width = len(first)
        names += [f"{n:0{width}d}" for n in range(int(first), int(last if dash else first) + 1)]
    return tuple(names)


@main.command("simulate")
@click.option("--kitti", "kitti_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="KITTI object ground truth: a folder with label_2/ and calib/.")
@click.option("--kitti-tracking", "tracking_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="KITTI tracking ground truth: a folder with label_02/ and calib/.")
@click.option("-o", "--out", "annotations", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Annotation file to write (format v1).")
@click.option("--gt-out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Where to write the simulated vehicles' ground truth as a KITTI object folder (label_2/, "
                   "calib/) for `toosicubix eval --kitti`. Default: <annotation file without .json>_gt/.")
@click.option("--noise", "noise_px", type=click.FloatRange(min=0.0), default=1.0, show_default=True,
              help="Gaussian click noise, pixels per coordinate.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (per vehicle streams).")
@click.option("--exact-placement", is_flag=True,
              help="Put every part exactly where the parts model says (default: varied as on real vehicles).")
@click.option("--max-clicks", type=click.IntRange(min=1), default=12, show_default=True,
              help="The most clicked points per vehicle.")
@click.option("--classes", default="Car,Van,Truck", show_default=True, help="KITTI types to simulate.")
@click.option("--max-truncation", type=float, default=0.0, show_default=True,
              help="Keep vehicles truncated at most this much (object labels: fraction; tracking: 0, 1, 2).")
@click.option("--max-occlusion", type=click.IntRange(0, 3), default=1, show_default=True,
              help="Keep vehicles occluded at most this much (0 visible, 1 partly, 2 largely).")
@click.option("--min-depth", type=float, default=3.0, show_default=True, help="Metres.")
@click.option("--max-depth", type=float, default=60.0, show_default=True, help="Metres.")
@click.option("--min-box-height", type=float, default=25.0, show_default=True, help="2D box height, pixels.")
@click.option("--frames-per-track", type=click.IntRange(min=1), default=3, show_default=True,
              help="Tracking labels: at most this many frames per track, evenly spread.")
@click.option("--sequences", default=None, help="Tracking labels: e.g. 0010-0020 or 0001,0005 (default: all).")
def simulate_command(kitti_dir: Path | None, tracking_dir: Path | None, annotations: Path, gt_out: Path | None,
                     noise_px: float, seed: int, exact_placement: bool, max_clicks: int, classes: str,
                     max_truncation: float, max_occlusion: int, min_depth: float, max_depth: float,
                     min_box_height: float, frames_per_track: int, sequences: str | None) -> None:
    """Simulate a person clicking parts on real ground-truth cuboids (no public human clicks exist).

    Selects vehicles from KITTI object or tracking labels, places the parts a person would click (tyre
    contacts, light pairs, badges, vertical edges, roof pairs, box corners, a ground arrow for straight
    views), keeps those a person could see, adds click noise, and writes an annotation file plus the
    selected vehicles' ground truth in KITTI format. Tracking images get ids <sequence>_<frame:06d>.
    The annotator model is described in `toosicubix.simulate`. Simulated clicks are not human clicks.

    \b
    Example:
      toosicubix simulate --kitti-tracking data/kitti_tracking --sequences 0010-0020 -o sim.json
      toosicubix fit sim.json && toosicubix eval --kitti sim_gt
    """
    from .formats import FormatError
    from .simulate import (
        AnnotatorOptions,
        SelectionOptions,
        select_kitti_object,
        select_kitti_tracking,
        simulate,
        write_simulation,
    )

    if (kitti_dir is None) == (tracking_dir is None):
        raise click.UsageError("give exactly one of --kitti DIR and --kitti-tracking DIR")
    selection = SelectionOptions(
        classes=tuple(c.strip() for c in classes.split(",") if c.strip()), max_truncation=max_truncation,
        max_occlusion=max_occlusion, min_depth=min_depth, max_depth=max_depth, min_box_height=min_box_height,
        frames_per_track=frames_per_track, sequences=_parse_sequences(sequences),
    )
    try:
        if kitti_dir is not None:
            vehicles = select_kitti_object(kitti_dir, selection)
        else:
            vehicles = select_kitti_tracking(tracking_dir, selection)
    except FormatError as exc:
        raise BadInput(str(exc)) from None
    simulated = simulate(vehicles, AnnotatorOptions(noise_px=noise_px, exact_placement=exact_placement,
                                                    max_clicks=max_clicks, seed=seed))
    gt_dir = gt_out or annotations.with_name(annotations.stem + "_gt")
    write_simulation(simulated, annotations, gt_dir)
    clicks = [sv.n_clicks for sv in simulated]
    images = len({sv.source.image_id for sv in simulated})
    few = sum(1 for c in clicks if c < 3)
    click.echo(f"simulated {len(simulated)} vehicles in {images} images -> {annotations} (clicks per vehicle: "
               f"median {int(np.median(clicks)) if clicks else 0}, {few} with fewer than 3); ground truth -> {gt_dir}",
               err=True)


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
