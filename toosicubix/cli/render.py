"""``toosicubix render``: one PNG per image of a fit, over its photo or a blank canvas. Thin over
:mod:`toosicubix.render`."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from toosicubix.formats.results import DEFAULT_OUTPUT_DIR

#: Exit code of bad input or usage (as everywhere in the CLI).
EXIT_BAD_INPUT = 2


class _BadInput(click.ClickException):
    """A bad input file or option value: printed as is, exit code 2."""

    exit_code = EXIT_BAD_INPUT

    def show(self, file=None) -> None:
        click.echo(f"Error: {self.format_message()}", err=True)


class _ImageBar:
    """A progress bar on stderr while rendering many images (as ``fit`` has for many vehicles)."""

    MIN_IMAGES = 50

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.bar = None

    def start(self, total: int) -> None:
        if not self.quiet and total >= self.MIN_IMAGES:
            self.bar = click.progressbar(length=total, label="rendering", file=sys.stderr, show_eta=True)
            self.bar.__enter__()

    def update(self, n: int) -> None:
        if self.bar is not None:
            self.bar.update(n)

    def finish(self) -> None:
        if self.bar is not None:
            self.bar.__exit__(None, None, None)
            self.bar = None


@click.command("render")
@click.argument("out", required=False, default=DEFAULT_OUTPUT_DIR, type=click.Path(file_okay=False, path_type=Path))
@click.option("-o", "--out", "render_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Folder for the PNG files, one per image: <image id>.png [default: OUT/render].")
@click.option("--annotations", "annotations", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="The annotation file [default: the one OUT/results.json names].")
@click.option("--images", "images_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Folder of the images: DIR/<file>, DIR/<file name>, DIR/<image id>.png|.jpg or, for KITTI "
                   "tracking ids, DIR/<seq>/<frame>.png [default: each image's `file`, relative to the annotation "
                   "file]. Without an image the overlay is drawn on a blank canvas of the image's size.")
@click.option("--only", type=click.Choice(["failed", "ambiguous", "uncertain"]), default=None,
              help="Render only images with a failed vehicle, an ambiguous one, or one whose yaw or depth sigma is "
                   "beyond `toosicubix validate`'s thresholds.")
@click.option("--kitti", "kitti_dir", type=click.Path(path_type=Path), default=None,
              help="Draw KITTI object ground truth (dashed white), as for `toosicubix eval --kitti`.")
@click.option("--kitti-tracking", "tracking_dir", type=click.Path(path_type=Path), default=None,
              help="Draw KITTI tracking ground truth, as for `toosicubix eval --kitti-tracking`.")
@click.option("--cityscapes", "cityscapes_dir", type=click.Path(path_type=Path), default=None,
              help="Draw Cityscapes 3D ground truth, as for `toosicubix eval --cityscapes`.")
@click.option("--apollocar3d", "apollo_dir", type=click.Path(path_type=Path), default=None,
              help="Draw ApolloCar3D ground truth (once `toosicubix eval` reads it; not yet).")
@click.option("--next-clicks", is_flag=True,
              help="Draw the parts suggested to click next (results.json of `fit --next-clicks N`) as targets.")
@click.option("--no-birds-eye", is_flag=True, help="Leave out the bird's-eye view beside each overlay.")
@click.option("--png-compression", type=click.IntRange(0, 9), default=1, show_default=True,
              help="zlib level of the PNG files: 1 is fast, 9 gives the smallest files (about half as large).")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar, warnings or summary on stderr.")
def render_command(out: Path, render_dir: Path | None, annotations: Path | None, images_dir: Path | None,
                   only: str | None, kitti_dir: Path | None, tracking_dir: Path | None, cityscapes_dir: Path | None,
                   apollo_dir: Path | None, next_clicks: bool, no_birds_eye: bool, png_compression: int,
                   quiet: bool) -> None:
    """Draw every fit of OUT (a `toosicubix fit` folder) over its image: one PNG per image.

    Each fitted cuboid's 12 edges are projected with the camera's lens distortion and cut where they pass
    behind the camera; its front face is filled, it has a colour and a label (id, prototype, dimensions,
    depth, yaw sigma, confidence). Every click is a dot with a yellow line to where the fit puts it; clicks
    the robust loss down-weighted (results.json `downweighted`) are crossed in red; failed vehicles are boxed
    in red with their reason. Ground truth, when given, is drawn dashed in white. Beside each overlay a
    bird's-eye view shows the footprints in metres with heading, depth and yaw sigmas.

    Images come from each image's `file` relative to the annotation file, or from --images; a missing image
    gets a warning and a blank canvas. Files are written atomically; rendering twice gives identical files.

    Exit code 0 on success, 2 for a missing or malformed input.

    \b
    Example:
      toosicubix fit samples/annotations.json && toosicubix render
      toosicubix render runs/kitti-out --images data/kitti/image_2 --kitti data/kitti --only uncertain
    """
    from toosicubix.annotations.schema import InputFileError
    from toosicubix.evaluation import EvaluationInputError
    from toosicubix.formats import FormatError
    from toosicubix.render.folder import RenderInputError, RenderOptions, render_folder
    from toosicubix.render.overlay import OverlayOptions

    given = [(kind, path) for kind, path in (("kitti", kitti_dir), ("kitti-tracking", tracking_dir),
                                             ("cityscapes", cityscapes_dir), ("apollocar3d", apollo_dir))
             if path is not None]
    if len(given) > 1:
        raise click.UsageError("give at most one ground truth: --kitti, --kitti-tracking, --cityscapes or "
                               "--apollocar3d")
    if given and given[0][0] == "apollocar3d":
        from toosicubix.evaluation.ground_truth import SOURCES

        if "apollocar3d" not in SOURCES:  # the hook: drawn as soon as `eval` can read it
            raise _BadInput("--apollocar3d: ApolloCar3D ground truth cannot be read yet (toosicubix eval does not "
                            "know it); render without ground truth")
    options = RenderOptions(overlay=OverlayOptions(birds_eye=not no_birds_eye, next_clicks=next_clicks), only=only,
                            png_compression=png_compression)
    bar = _ImageBar(quiet)
    try:
        summary = render_folder(out, render_dir, annotations, images_dir, given[0] if given else None, options,
                                progress=bar.update, on_start=bar.start)
    except (RenderInputError, InputFileError, FormatError, EvaluationInputError) as exc:
        raise _BadInput(str(exc)) from None
    except OSError as exc:
        raise _BadInput(f"cannot write {exc.filename}: {exc.strerror or exc}") from None
    finally:
        bar.finish()
    if not quiet:
        for warning in summary.warnings[:20]:
            click.echo(f"warning: {warning}", err=True)
        if len(summary.warnings) > 20:
            click.echo(f"  ... and {len(summary.warnings) - 20} more warnings", err=True)
        blank = f", {len(summary.blank)} on a blank canvas" if summary.blank else ""
        skipped = f" ({summary.skipped} left out by --only {only})" if only else ""
        click.echo(f"rendered {len(summary.written)} images{blank} -> {summary.out_dir}{skipped}", err=True)
