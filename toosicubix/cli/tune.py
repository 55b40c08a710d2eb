"""``toosicubix tune``: thin over :func:`toosicubix.pipeline.tuning.tune`."""

from __future__ import annotations

from pathlib import Path

import click

from toosicubix.cli.options import (
    Finite,
    GroundTruth,
    announced_estimates,
    click_sigma_option,
    float_list,
    ground_truth_options,
    jobs_option,
    out_option,
    priors_option,
    road_normal_choice,
    road_normal_option,
)


@click.command("tune")
@click.argument("annotations", type=click.Path(dir_okay=False, path_type=Path))
@ground_truth_options()
@out_option("Settings file to write, for `toosicubix fit --config`.", "config_out",
            type=click.Path(dir_okay=False, path_type=Path), default="toosicubix-settings.json", show_default=True)
@click.option("--lambdas", default=",".join(f"{v:g}" for v in (0.01, 0.1, 1, 10)), show_default=True,
              help="Values of lambda (descent prior weight) to try.")
@click.option("--lambda-ps", default=",".join(f"{v:g}" for v in (0.01, 0.1, 1, 10, 100)), show_default=True,
              help="Values of lambda_p (pixel-cost prior weight) to try.")
@click.option("--refine/--no-refine", default=True, show_default=True,
              help="Then try the half-steps around the best pair.")
@priors_option
@click.option("--min-iou", type=Finite(0.0, 1.0), default=0.5, show_default=True,
              help="2D box IoU needed to pair a fit with a ground-truth vehicle.")
@jobs_option
@click_sigma_option
@road_normal_option
def tune_command(annotations: Path, ground_truth: GroundTruth, config_out: Path, lambdas: str, lambda_ps: str,
                 refine: bool, priors_path: Path | None, min_iou: float, jobs: int, click_sigma: float | None,
                 road_normal: str | None) -> None:
    """Choose lambda and lambda_p by maximising mean sIoU against ground truth, as the paper does.

    Fits every vehicle of ANNOTATIONS with each pair of weights on a log grid (then the half-steps around
    the best), scores the fits as `toosicubix eval` does, prints the landscape (mean sIoU; mean IoU and
    median E_R of the best beside it) and writes the best pair to a settings file for `fit --config`.
    Tune on vehicles you will not report accuracy on.

    The fits are made as `fit` makes them by default: the click noise and each camera's road normal are first
    estimated from the file's vehicles (once, with the default weights), unless --click-sigma or --road-normal
    (none, or a normal x,y,z every image stands upright on) say otherwise.

    \b
    Example:
      toosicubix simulate --kitti-tracking data/kitti_tracking --sequences 0000-0009 -o tuning.json
      toosicubix tune tuning.json --kitti tuning_gt -o settings.json --jobs 2
      toosicubix fit annotations.json --config settings.json
    """
    from dataclasses import replace

    from toosicubix.annotations.convert import load_images, with_ground
    from toosicubix.annotations.priors_file import load_priors
    from toosicubix.evaluation import EvalOptions
    from toosicubix.formats.ground_truth import open_ground_truth
    from toosicubix.pipeline.fitting import check_prototypes
    from toosicubix.pipeline.pilot import on_estimated_roads
    from toosicubix.pipeline.settings import ground_overrides, settings_document, write_settings_file
    from toosicubix.pipeline.tuning import tune
    from toosicubix.solver.compiled import warm_up
    from toosicubix.solver.fit import SolverOptions

    grid_l, grid_p = float_list(lambdas, "--lambdas"), float_list(lambda_ps, "--lambda-ps")
    road, normal = road_normal_choice(road_normal)
    images = load_images(annotations)
    priors = load_priors(priors_path)
    check_prototypes(images, priors, annotations)
    source = open_ground_truth(ground_truth.kind, ground_truth.root)
    n = sum(len(im.vehicles) for im in images)
    base = SolverOptions() if click_sigma is None else replace(SolverOptions(), click_sigma=click_sigma)
    warm_up(lambda text: click.echo(text, err=True))
    ground = ground_overrides(normal=normal)
    images = with_ground(images, ground)  # every image upright on a given road, as `fit --road-normal x,y,z` fits
    findings = announced_estimates(annotations, priors, base, click_sigma is None, road == "estimate", ground=ground)
    if findings is not None:  # fitted as `fit` fits them: the estimated click noise, on each camera's road
        images, base = list(on_estimated_roads(images, findings.road_normals)), findings.options
    click.echo(f"tuning on {n} vehicles in {len(images)} images", err=True)

    def report(point) -> None:
        click.echo(f"  lambda {point.lambda_3d:<8.3g} lambda_p {point.lambda_px:<8.3g} mean sIoU "
                   f"{point.siou_mean:.4f}  mean IoU {point.iou_mean:.4f}  median E_R {point.e_r_median_deg:.2f} deg"
                   f"  ({point.n_matched} matched, {point.n_failed} failed)", err=True)

    result = tune(images, priors, source, grid_l, grid_p, base=base, eval_options=EvalOptions(min_iou=min_iou),
                  refine=refine, jobs=jobs, progress=report)
    best = result.best
    click.echo(result.landscape())
    click.echo(f"best: lambda {best.lambda_3d:g}, lambda_p {best.lambda_px:g}: mean sIoU {best.siou_mean:.4f}, "
               f"mean IoU {best.iou_mean:.4f}, median E_R {best.e_r_median_deg:.2f} deg ({best.n_matched} vehicles)")
    tuned = {"annotations": str(annotations), "ground_truth": f"{ground_truth.flag} {ground_truth.root}",
             "priors": str(priors_path) if priors_path else "bundled", "click_sigma": base.click_sigma,
             **(findings.header() if findings is not None else {}), **result.to_json()}
    write_settings_file(config_out, settings_document(best.lambda_3d, best.lambda_px, tuned))
    click.echo(f"wrote {config_out}", err=True)
