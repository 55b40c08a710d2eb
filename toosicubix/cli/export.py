"""``toosicubix export openlabel|cvat``: fitted cuboids in standard files."""

from __future__ import annotations

import json
from pathlib import Path

import click

from toosicubix.cli.options import BadInput, out_option
from toosicubix.formats.results import DEFAULT_OUTPUT_DIR


@click.group("export")
def export_group() -> None:
    """Write the fitted cuboids of a `toosicubix fit` output folder in standard files.

    \b
    Example:
      toosicubix export openlabel toosicubix-out -o labels.json
      toosicubix export cvat toosicubix-out -o review.xml
    """


_COMMON = [
    click.argument("out", type=click.Path(file_okay=False, path_type=Path), default=DEFAULT_OUTPUT_DIR),
    click.option("--annotations", "annotations_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
                 help="The annotation file that was fitted [default: the one results.json names]."),
    click.option("-q", "--quiet", is_flag=True, help="No warnings or summary on stderr."),
]


def _common(command):
    for option in reversed(_COMMON):
        command = option(command)
    return command


def _load(out: Path, annotations_path: Path | None):
    from toosicubix.errors import FormatError
    from toosicubix.formats.fitted import load_fitted

    try:
        return load_fitted(out, annotations_path)
    except FormatError as exc:
        raise BadInput(str(exc)) from None


def _write(path: Path, text: str, warnings: list[str], quiet: bool) -> None:
    from toosicubix.formats.atomic import atomic_write_text

    if not quiet:
        for warning in warnings:
            click.echo(f"warning: {warning}", err=True)
    try:
        atomic_write_text(path, text)
    except OSError as exc:
        raise BadInput(f"cannot write {path}: {exc.strerror or exc}") from None
    if not quiet:
        click.echo(f"wrote {path}", err=True)


@export_group.command("openlabel")
@_common
@out_option("The OpenLABEL JSON file to write.", "output", type=click.Path(dir_okay=False, path_type=Path),
            required=True)
def openlabel_command(out: Path, annotations_path: Path | None, quiet: bool, output: Path) -> None:
    """Write ASAM OpenLABEL 1.0.0: a frame per image (in file order; a sequence's frame with its sequence and
    frame number), a camera stream with intrinsics_pinhole, each fitted vehicle an object with a cuboid [x, y, z,
    qx, qy, qz, qw, dx, dy, dz] (box centre in the camera frame, scalar-last quaternion of R_cam_vehicle,
    dimensions along X forward, Y left, Z up), its clicks as point2d, its uncertainty, status and prototype as
    attributes. A track of a sequence is one object over the frames that hold it, a pose in each.

    \b
    Example:
      toosicubix export openlabel toosicubix-out -o labels.json
    """
    from toosicubix.formats.openlabel import openlabel_document
    from toosicubix.formats.results import RESULTS_FILENAME, non_finite_path

    images, annotations = _load(out, annotations_path)
    doc, warnings = openlabel_document(images, name=annotations.name)
    bad = non_finite_path(doc)
    if bad is not None:  # results.json's numbers are checked when read: this is the last guard, not the first
        raise BadInput(f"{out / RESULTS_FILENAME}: its fits give a NaN or an infinity at {bad} of the OpenLABEL "
                       "document: refusing to write it")
    _write(output, json.dumps(doc, indent=1, allow_nan=False) + "\n", warnings, quiet)


@export_group.command("cvat")
@_common
@out_option("The CVAT 1.1 XML file to write.", "output", type=click.Path(dir_okay=False, path_type=Path),
            required=True)
def cvat_command(out: Path, annotations_path: Path | None, quiet: bool, output: Path) -> None:
    """Write the fitted cuboids projected into each image as CVAT 1.1 shapes (a polyline over the 12 edges, a
    polygon on the front face), for CVAT to import into the task that holds the clicks (upload annotations,
    format CVAT 1.1). The task needs the review labels of `toosicubix template cvat`. In a file of a CVAT video
    task's frames (`import cvat`) each track is one CVAT track over its frames.

    \b
    Example:
      toosicubix export cvat toosicubix-out -o review.xml
    """
    from toosicubix.formats.cvat_export import review_xml

    images, _ = _load(out, annotations_path)
    text, warnings = review_xml(images)
    _write(output, text, warnings, quiet)
