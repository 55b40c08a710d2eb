"""``toosicubix template``: the label template a labelling tool needs to label for us."""

from __future__ import annotations

from pathlib import Path

import click

from toosicubix.cli.options import BadInput, priors_option


@click.command("template")
@click.argument("tool", type=click.Choice(["cvat", "label-studio", "coco"]))
@click.option("--prototypes", default="Car,Van,Truck", show_default=True,
              help="Comma-separated prototypes (size classes of the priors table) annotators choose from.")
@priors_option
@click.option("-o", "--out", "out_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the template to this file instead of stdout.")
def template_command(tool: str, prototypes: str, priors_path: Path | None, out_path: Path | None) -> None:
    """Print what to paste into a labelling tool to click parts for ToosiCubix.

    \b
    cvat          CVAT's Raw label JSON: a skeleton label 'vehicle' (one point per keypoint, a
                  'prototype' attribute) and the review labels of `toosicubix export cvat`. Paste it
                  into the label constructor's Raw tab, or: cvat-cli project create NAME --labels FILE
    label-studio  the labelling config XML: a box per vehicle labelled with its prototype, and the
                  keypoints (nest each under its box in the Regions panel)
    coco          COCO 'categories' (one per prototype) with the keypoint names and a skeleton

    Every template names one keypoint per click (see docs/tools.md for the keypoint vocabulary). Road users
    with a vocabulary of their own (Pedestrian: COCO's 17 keypoints; Cyclist, Motorcyclist, Bicycle,
    Motorcycle; Traffic cone; Barrier) get it instead: a CVAT skeleton per class, their keypoint labels in
    Label Studio, their keypoint lists in COCO (docs/road-users.md).

    \b
    Example:
      toosicubix template cvat --prototypes Car,Van -o labels.json
      toosicubix template label-studio > config.xml
      toosicubix template cvat --prototypes Car,Pedestrian,Cyclist -o labels.json
    """
    from toosicubix.annotations.priors_file import load_priors
    from toosicubix.errors import InputFileError
    from toosicubix.formats.atomic import atomic_write_text
    from toosicubix.formats.templates import template_text

    names = tuple(p.strip() for p in prototypes.split(",") if p.strip())
    if not names:
        raise click.BadParameter("expected at least one prototype", param_hint="--prototypes")
    try:
        priors = load_priors(priors_path)
    except InputFileError as exc:
        raise BadInput(str(exc)) from None
    unknown = [p for p in names if p not in priors]
    if unknown:
        raise BadInput(f"--prototypes: unknown prototype {unknown[0]!r}; known: {', '.join(sorted(priors))}")
    text = template_text(tool, names)
    if out_path is None:
        click.echo(text, nl=False)
        return
    try:
        atomic_write_text(out_path, text)
    except OSError as exc:
        raise BadInput(f"cannot write {out_path}: {exc.strerror or exc}") from None
    click.echo(f"wrote {out_path}", err=True)
