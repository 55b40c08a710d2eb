"""``toosicubix render``: one PNG per image of a fit, over its photo or a blank canvas. Thin over
:mod:`toosicubix.render`."""

from __future__ import annotations

from pathlib import Path

import click

from toosicubix.cli.options import BadInput, Finite, GroundTruth, ProgressBar, ground_truth_options
from toosicubix.formats.results import DEFAULT_OUTPUT_DIR


@click.command("render")
@click.argument("out", required=False, default=DEFAULT_OUTPUT_DIR, type=click.Path(file_okay=False, path_type=Path))
@click.option("-o", "--out", "render_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Folder for the PNG files, one per image: <image id>.png [default: OUT-render beside OUT, "
                   "never inside OUT, which fit replaces as a whole].")
@click.option("--annotations", "annotations", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="The annotation file [default: the one OUT/results.json names].")
@click.option("--images", "images_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Folder of the images: DIR/<file>, DIR/<file name>, DIR/<image id>.png|.jpg or, for a frame "
                   "of a sequence (or a KITTI tracking id), DIR/<seq>/<frame as 6 digits>.png, or DIR/<frame as 6 "
                   "digits>.png when DIR is named as the sequence (KITTI's image_02/0001) [default: each image's "
                   "`file`, relative to the annotation file]. Without an image the overlay is drawn on a blank "
                   "canvas of the image's size.")
@click.option("--only", type=click.Choice(["failed", "ambiguous", "uncertain", "misfit"]), default=None,
              help="Render only images with a failed vehicle, an ambiguous one, one whose yaw or depth sigma is "
                   "beyond `toosicubix validate`'s thresholds, or a misfit (results of `fit --misfit-level`).")
@ground_truth_options("kitti", "kitti-tracking", "cityscapes", "apollocar3d", required=False)
@click.option("--next-clicks", is_flag=True,
              help="Draw the parts suggested to click next (results.json of `fit --next-clicks N`) as targets.")
@click.option("--no-birds-eye", is_flag=True, help="Leave out the bird's-eye view beside each overlay.")
@click.option("--png-compression", type=click.IntRange(0, 9), default=1, show_default=True,
              help="zlib level of the PNG files: 1 is fast, 9 gives the smallest files (about half as large).")
@click.option("--video", is_flag=True,
              help="Also write each sequence's rendered frames as one video, <sequence>.mp4 beside the PNGs (MPEG-4, "
                   "in frame order at --frame-rate; a frame missing between two shows the one before, for up to "
                   "5 s).")
@click.option("--frame-rate", type=Finite(min=0.0, max=1000.0, min_open=True), default=10.0, show_default=True,
              help="Frames per second of the videos, as `fit --frame-rate` (KITTI's 10).")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar, warnings or summary on stderr.")
def render_command(out: Path, render_dir: Path | None, annotations: Path | None, images_dir: Path | None,
                   only: str | None, ground_truth: GroundTruth | None, next_clicks: bool, no_birds_eye: bool,
                   png_compression: int, video: bool, frame_rate: float, quiet: bool) -> None:
    """Draw every fit of OUT (a `toosicubix fit` folder) over its image: one PNG per image.

    Each fitted cuboid's 12 edges are projected with the camera's lens distortion and cut where they pass
    behind the camera; its front face is filled, it has a colour and a label (id, prototype, dimensions,
    depth, yaw sigma, confidence). Every click is a dot with a yellow line to where the fit puts it; clicks
    the robust loss down-weighted (results.json `downweighted`) are crossed in red; failed vehicles are boxed
    in red with their reason. Ground truth, when given, is drawn dashed in white (an ApolloCar3D car whose pose
    contradicts its clicks, as `eval` flags it, with a note of why, by its id). Beside each overlay a
    bird's-eye view shows the footprints in metres with heading, depth and yaw sigmas.

    Frames of a sequence (a fit with tracks): a tracked vehicle keeps its track's colour in every frame, its
    label ends with its track and how this frame's pose was determined (clicks, box or interp.), and the
    bird's-eye view draws each of the frame's tracks over all the sequence's frames: its positions relative to
    the camera, a dot per frame, clicked frames ringed, this frame's a larger dot. With --video, each sequence's
    frames also become one video to play.

    Images come from each image's `file` relative to the annotation file, or from --images; a missing image, or
    one that cannot be decoded, gets a warning naming it and a blank canvas. Sizes are bounded: an image file whose
    header declares more than 16,384 px a side or 50 Mpx is not decoded, and a canvas beyond them is drawn scaled
    down with a warning (left out when a side would be under a pixel). Files are written atomically; rendering
    twice gives identical files.

    Exit code 0 on success, 2 for a missing or malformed input.

    \b
    Example:
      toosicubix fit samples/annotations.json && toosicubix render
      toosicubix render runs/kitti-out --images data/kitti/image_2 --kitti data/kitti --only uncertain
      toosicubix render tracks-out --images data/kitti_tracking/image_02 --video
    """
    from toosicubix.render.folder import RenderOptions, render_folder
    from toosicubix.render.overlay import OverlayOptions

    options = RenderOptions(overlay=OverlayOptions(birds_eye=not no_birds_eye, next_clicks=next_clicks), only=only,
                            png_compression=png_compression, video=video, frame_rate=frame_rate)
    gt = (ground_truth.kind, ground_truth.root) if ground_truth else None
    bar = ProgressBar(quiet, label="rendering")
    try:
        summary = render_folder(out, render_dir, annotations, images_dir, gt, options,
                                progress=bar.update, on_start=bar.start)
    except OSError as exc:
        raise BadInput(f"cannot write {exc.filename}: {exc.strerror or exc}") from None
    finally:
        bar.finish()
    if not quiet:
        for warning in summary.warnings[:20]:
            click.echo(f"warning: {warning}", err=True)
        if len(summary.warnings) > 20:
            click.echo(f"  ... and {len(summary.warnings) - 20} more warnings", err=True)
        blank = f", {len(summary.blank)} on a blank canvas" if summary.blank else ""
        blank += f", {len(summary.refused)} left out (too large to draw even scaled)" if summary.refused else ""
        skipped = f" ({summary.skipped} left out by --only {only})" if only else ""
        click.echo(f"rendered {len(summary.written)} images{blank} -> {summary.out_dir}{skipped}", err=True)
        if summary.videos:
            click.echo(f"videos: {', '.join(p.name for p in summary.videos)} in {summary.out_dir}", err=True)
