"""``toosicubix eval``: thin over :func:`toosicubix.evaluation.evaluate_folder`."""

from __future__ import annotations

from pathlib import Path

import click

from toosicubix.cli.options import (
    BadInput,
    Finite,
    GroundTruth,
    apollocar3d_cameras_option,
    car_models_option,
    ground_truth_options,
    parse_classes,
)
from toosicubix.formats.results import DEFAULT_OUTPUT_DIR


@click.command("eval")
@click.argument("out", required=False, default=DEFAULT_OUTPUT_DIR, type=click.Path(file_okay=False, path_type=Path))
@ground_truth_options("kitti", "kitti-tracking", "cityscapes", "apollocar3d")
@car_models_option
@apollocar3d_cameras_option
@click.option("--min-iou", type=Finite(0.0, 1.0), default=0.5, show_default=True,
              help="2D box IoU a prediction and a ground-truth object need to be paired. Example: --min-iou 0.3")
@click.option("--classes", default=None,
              help="Comma-separated ground-truth classes to score, case-insensitive [default: Car,Van,Truck for "
                   "KITTI; car,truck,bus,caravan,trailer,train for Cityscapes; and every other class the fit has, "
                   "e.g. Pedestrian]. Example: --classes Car,Van")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write the summary, every matched object and the unmatched ones as JSON. "
                   "Example: --json eval.json")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write one CSV row per matched object. Example: --csv eval.csv")
@click.option("--plots", "plots_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Also write PNG plots into this folder: errors against depth, each metric's distribution, and "
                   "the calibration of the predicted sigmas. Example: --plots eval-plots")
@click.option("-q", "--quiet", is_flag=True, help="No warnings or notes on stderr; the table still goes to stdout.")
def eval_command(out: Path, ground_truth: GroundTruth, car_models_path: Path | None, cameras_path: Path | None,
                 min_iou: float,
                 classes: str | None, json_path: Path | None, csv_path: Path | None, plots_dir: Path | None,
                 quiet: bool) -> None:
    """Score fitted cuboids against KITTI, Cityscapes 3D or ApolloCar3D ground truth, as the paper's Evaluation
    does.

    Reads OUT (a `toosicubix fit` output folder, default toosicubix-out): results.json with full rotations,
    else label_2/*.txt read as yaw only. Pairs each predicted image with its ground truth by id (file stem),
    matches objects by 2D box IoU (Hungarian), and reports per metric the mean and median: exact 3D IoU with
    full rotations, sIoU, E_R (degrees), E_t, E_d, E_comb, plus KITTI's yaw-only IoU for comparison; then
    breakdowns by depth, by occlusion (KITTI, Cityscapes) or by labelled keypoints (ApolloCar3D, with the cars
    whose ground-truth pose contradicts their clicks scored apart: it hides 3 or more, and a quarter, of their
    labelled keypoints from the camera, or, with the cameras file, puts them more than 0.5 m RMS from their rays),
    and the unmatched objects. Poses are compared in the camera frame of
    the prediction's K. The table goes to stdout, warnings to stderr.

    Exit code 0 on success, 2 for a missing folder, a malformed file or a predicted image without ground truth.

    \b
    Example:
      toosicubix eval --kitti data/kitti
      toosicubix eval runs/kitti-out --kitti data/kitti --json eval.json --csv eval.csv
      toosicubix eval apollo-out --apollocar3d apollo_val.json --car-models car_models.json
    """
    from toosicubix.evaluation import EvalOptions, evaluate_folder, format_report, write_csv, write_json

    options = EvalOptions(min_iou=min_iou, classes=parse_classes(classes))
    source_options = {key: path for key, path in (("car_models", car_models_path), ("cameras", cameras_path))
                      if path is not None}
    result = evaluate_folder(out, ground_truth.kind, ground_truth.root, options, **source_options)
    if not quiet:
        for warning in result.warnings:
            click.echo(f"warning: {warning}", err=True)
    click.echo(format_report(result), nl=False)
    try:
        if json_path is not None:
            write_json(result, json_path)
        if csv_path is not None:
            write_csv(result, csv_path)
        if plots_dir is not None:
            from toosicubix.render.plots import write_evaluation_plots

            write_evaluation_plots(result, plots_dir, out / "results.json")
    except OSError as exc:
        raise BadInput(f"cannot write {exc.filename}: {exc.strerror or exc}") from None
    if not quiet:
        written = [str(p) for p in (json_path, csv_path, plots_dir) if p is not None]
        if written:
            click.echo(f"wrote {' and '.join(written)}", err=True)
