"""``toosicubix fit``: thin over :func:`toosicubix.pipeline.batch.fit_file`."""

from __future__ import annotations

import functools
import sys
from pathlib import Path
from typing import Any

import click

from toosicubix.cli.import_tools import foreign_file
from toosicubix.cli.options import (
    EXIT_OK,
    EXIT_SOME_FAILED,
    ProgressBar,
    fitting_options,
    keypoint_mapping_option,
)
from toosicubix.errors import InputError
from toosicubix.formats.results import DEFAULT_OUTPUT_DIR


@click.command("fit")
@click.argument("annotations", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=DEFAULT_OUTPUT_DIR, show_default=True,
              help="Output folder: label_2/<image id>.txt (KITTI) and results.json.")
@fitting_options
@click.option("--next-clicks", type=click.IntRange(min=0), default=0, show_default=True,
              help="Per vehicle, add to results.json this many parts to click next, best first (about 2 ms a "
                   "vehicle; `toosicubix validate` shows them).")
@keypoint_mapping_option("With --next-clicks: suggest this keypoint mapping's keypoints (e.g. apollocar3d-66, or a "
                         "mapping file) instead of the cuboid vocabulary's parts, for clicks made in its vocabulary.")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar or summary on stderr.")
def fit_command(annotations: Path, out_dir: Path, settings: Any, next_clicks: int, mapping: Any,
                quiet: bool) -> None:
    """Fit a 3D cuboid to every annotated vehicle.

    Reads ANNOTATIONS (annotation file v1, see `toosicubix schema`) and writes OUT/label_2/<image id>.txt
    in KITTI format plus OUT/results.json with the full pose of every vehicle, its uncertainty (sigma),
    what its clicks leave to the prior, and any second answer nearly as good. KITTI files store yaw only:
    pitch and roll are dropped there and kept in results.json; their score is the fit's confidence.

    Scale comes from the size priors unless the file or the options give a ground plane (vehicles stand
    upright on the road; with the camera height, on it) or known sizes (plate widths, wheelbases, tyres,
    known dimensions); the summary says which cue set each vehicle's scale.

    The click noise the uncertainty is computed for is estimated from the batch's own residuals (a pilot
    fit of up to 400 vehicles spread over the file, before the real one) unless --click-sigma gives it; the
    summary and results.json ("click_noise") say which, and on how many degrees of freedom.

    Unless a ground is given (--road-normal, --kitti-ground, a camera height or pitch, --joint-ground, or the
    file's ground blocks), the same pilot fit estimates each camera's road normal from its vehicles' up axes,
    and vehicles are then fitted upright on it (within 2 deg; results.json "road_normal"). Far vehicles need
    it: their clicks fit a pose tilted toward the camera about as well as the true one. --road-normal none
    turns it off.

    Exit code 0 when every vehicle was fitted, 1 when some failed (their reasons are in results.json
    and on stderr; the others are written), 2 for a bad input file or option. A COCO, Label Studio, CVAT
    or KITTI file given as ANNOTATIONS is named with the `toosicubix import` that turns it into one.

    \b
    Example:
      toosicubix fit samples/annotations.json -o toosicubix-out
      toosicubix fit big.json --jobs 2 --kitti-ground
      toosicubix fit big.json --road-normal 0,-1,0 --joint-ground   # camera height unknown
    """
    from dataclasses import replace

    from toosicubix.pipeline.batch import fit_file

    bar = ProgressBar(quiet)
    try:
        summary = fit_file(annotations, out_dir, replace(settings, next_clicks=next_clicks, keypoints=mapping),
                           progress=bar.update, on_start=bar.start,
                           say=None if quiet else functools.partial(click.echo, err=True))  # before the bar
    except InputError:
        foreign_file(annotations)
        raise
    finally:
        bar.finish()
    if not quiet:
        click.echo(
            f"fitted {summary.ok} of {summary.vehicles} vehicles in {summary.images} images"
            f"{f' ({summary.jobs} processes)' if summary.jobs > 1 else ''} -> "
            f"{summary.out_dir / 'label_2'} (KITTI: yaw only, pitch and roll dropped) and "
            f"{summary.out_dir / 'results.json'} (full rotations)",
            err=True,
        )
        for line in summary.pilot.describe() if summary.pilot is not None else ():
            click.echo(line, err=True)
        if summary.implausible:
            swapped = sum(why == "left and right look swapped" for *_, why in summary.implausible)
            click.echo(f"IMPLAUSIBLE: {len(summary.implausible)} fitted vehicle(s) in a pose no person could have "
                       f"clicked ({swapped} with left and right that look swapped: the vehicle's own left, its "
                       "driver's, is on the image's right when it faces the camera); their KITTI score is at most "
                       "0.2 (results.json: implausible, warnings):", err=True)
            for image_id, vehicle_id, why in summary.implausible[:20]:
                click.echo(f"  image {image_id} vehicle {vehicle_id}: {why}", err=True)
        if summary.tracks:
            counts = ", ".join(f"{summary.pose_from.get(k, 0)} {what}" for k, what in (
                ("clicks", "from their clicks"), ("box", "from a box alone"), ("interpolated", "interpolated")))
            click.echo(f"tracks: {summary.tracks} fitted as tracks (one size each, a smooth motion), their frames "
                       f"{counts} (results.json: pose_from; KITTI tracking labels in "
                       f"{summary.out_dir / 'label_02'})", err=True)
        if summary.scale_from:
            counts = ", ".join(f"{cue} {n}" for cue, n in sorted(summary.scale_from.items(), key=lambda kv: -kv[1]))
            click.echo(f"scale set by: {counts} (vehicles; per vehicle in results.json: scale_from)", err=True)
        if summary.misfits is not None:
            click.echo(f"misfits: {summary.misfits} of {summary.ok} fitted vehicles failed the chi-square test of "
                       "their residuals; their sigmas are widened (results.json: residual_test and a 'misfit' "
                       "warning; `toosicubix render --only misfit` draws their images)", err=True)
        said = 0  # failed vehicles said, a track's frames with it: at most 20 lines, tracks first
        for track in summary.failed_tracks[:20]:
            click.echo(f"  failed: {track.describe()}", err=True)
            said += track.frames
        for image_id, vehicle_id, reason in summary.failed[:20 - min(20, len(summary.failed_tracks))]:
            click.echo(f"  failed: image {image_id} vehicle {vehicle_id}: {reason}", err=True)
            said += 1
        if summary.n_failed > said:
            click.echo(f"  ... and {summary.n_failed - said} more failed vehicles (see results.json)", err=True)
    sys.exit(EXIT_SOME_FAILED if summary.n_failed else EXIT_OK)
