"""``toosicubix validate``: thin over :func:`toosicubix.pipeline.validation.validate_file`."""

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
    Finite,
    ProgressBar,
    fitting_options,
    keypoint_mapping_option,
)
from toosicubix.errors import InputError
from toosicubix.pipeline.validation import Thresholds


@click.command("validate")
@click.argument("annotations", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--max-yaw-sigma", "max_yaw_sigma_deg", type=Finite(min=0.0, min_open=True),
              default=Thresholds.max_yaw_sigma_deg, show_default=True,
              help="A vehicle is well determined when its yaw standard deviation is at most this, degrees ...")
@click.option("--max-depth-sigma", "max_depth_sigma_rel", type=Finite(min=0.0, min_open=True),
              default=Thresholds.max_depth_sigma_rel, show_default=True,
              help="... its depth standard deviation at most this share of its depth ...")
@click.option("--allow-ambiguous", is_flag=True,
              help="... and (unless this flag is given) no second answer fits the clicks about as well.")
@click.option("--reach-factor", type=Finite(min=0.0), default=Thresholds.reach_factor, show_default=True,
              help="Where no click can reach those limits (a far vehicle, a scale only the size prior sets), each is "
                   "raised to this times what clicking every visible part would give, and the report says so; 0 "
                   "keeps the limits fixed. Needs --next-clicks above 0.")
@click.option("--next-clicks", type=click.IntRange(min=0), default=3, show_default=True,
              help="How many parts to suggest clicking next, per vehicle.")
@keypoint_mapping_option("Suggest this keypoint mapping's keypoints (e.g. apollocar3d-66, or a mapping file) as the "
                         "next clicks instead of the cuboid vocabulary's parts, for clicks made in its vocabulary.")
@fitting_options
@click.option("--all", "show_all", is_flag=True, help="Describe every vehicle, not only those that need work.")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON on stdout instead of text.")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar on stderr.")
def validate_command(annotations: Path, max_yaw_sigma_deg: float, max_depth_sigma_rel: float, allow_ambiguous: bool,
                     reach_factor: float, next_clicks: int, mapping: Any, settings: Any, show_all: bool, as_json: bool,
                     quiet: bool) -> None:
    """Check an annotation file and say which vehicles need more clicks; writes nothing.

    Schema errors are listed with their JSON paths (exit code 2). Otherwise every vehicle is fitted as
    `toosicubix fit` would fit it with the same options (the click noise and the road normal estimated from
    the batch unless given, said on stderr), and for each vehicle that is not well determined
    the report gives its constraint count, the standard deviations of its pose and size for clicks off by
    --click-sigma pixels, what its clicks leave to the prior, any second answer (e.g. turned around) that
    fits nearly as well, and the parts to click next, with where they should appear in the image and how
    much each would shrink the yaw and depth uncertainty.

    Exit code 0 when every vehicle is well determined, 1 when some are not (or cannot be fitted), 2 for a
    bad input file or option. A COCO, Label Studio, CVAT or KITTI file given as ANNOTATIONS is named with the
    `toosicubix import` that turns it into one.

    \b
    Example:
      toosicubix validate annotations.json
      toosicubix validate annotations.json --kitti-ground --max-yaw-sigma 3 --all
      toosicubix validate annotations.json --json > report.json
      toosicubix validate apollo.json --mapping apollocar3d-66   # keypoints to click next
    """
    from dataclasses import replace

    from toosicubix.pipeline.validation import validate_file

    thresholds = Thresholds(max_yaw_sigma_deg, max_depth_sigma_rel, allow_ambiguous, reach_factor)
    bar = ProgressBar(quiet)
    try:
        report = validate_file(annotations, replace(settings, next_clicks=next_clicks, keypoints=mapping), thresholds,
                               progress=bar.update, on_start=bar.start,
                               say=None if quiet else functools.partial(click.echo, err=True))  # before the bar
    except InputError:
        foreign_file(annotations)
        raise
    finally:
        bar.finish()
    if not quiet and not as_json and report.pilot is not None:  # the JSON report holds them
        for line in report.pilot.describe():
            click.echo(line, err=True)
    if as_json:
        from toosicubix.formats.results import dumps

        click.echo(dumps(report.to_json()), nl=False)
    else:
        click.echo(report.text(show_all), nl=False)
    sys.exit(EXIT_OK if report.ok else EXIT_SOME_FAILED)
