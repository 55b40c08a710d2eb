"""``toosicubix annotate``: serve the annotation page (thin: parses options, builds the session, serves)."""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import Any

import click

from toosicubix.cli.options import (
    BadInput,
    Finite,
    announced_estimates,
    click_sigma_option,
    keypoint_mapping_option,
    out_option,
    priors_option,
    road_normal_choice,
    road_normal_option,
)

#: The image files a folder given to annotate contributes (case-insensitive): what OpenCV reads and a browser shows.
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".webp")


@click.command("annotate")
@click.argument("images", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--cameras", "cameras_path", type=click.Path(path_type=Path), default=None,
              help="Each image's camera, needed for images the output file does not have yet: a KITTI calib file "
                   "(its P2, for every image), a folder of KITTI calib files (<image file stem>.txt, e.g. "
                   "calib/000123.txt for image_2/000123.png), an OpenCV or ROS camera YAML (for every image), the "
                   "importers' cameras file ({\"cameras\": [{\"match\": GLOB on the file name, \"K\": ...}]}, first "
                   "match wins), one camera block ({\"K\": ...} or {\"P\": ...}, as in the annotation file) for "
                   "every image, or {\"<image id or file name>\": block}.")
@out_option("Annotation file (v1): read and continued when it exists, written atomically after every change.",
            type=click.Path(dir_okay=False, path_type=Path), default=Path("annotations.json"), show_default=True)
@click.option("--prototype", default="Car", show_default=True, help="Prototype (size prior) of a new vehicle.")
@priors_option
@click.option("--kitti-ground", is_flag=True,
              help="Give images the file does not have yet KITTI's ground block (camera 1.65 +- 0.1 m above a road "
                   "whose normal is -y): vehicles stand on the road, which fixes their scale far better than the "
                   "size prior alone. It is written to the file, so `fit` uses it too.")
@road_normal_option
@click.option("--camera-height", type=Finite(min=0.0, min_open=True), default=None,
              help="With it, the camera's height above that road, metres (+- 0.05; with --kitti-ground 0.1): "
                   "vehicles stand on the road, which fixes their scale. Replaces --kitti-ground's height.")
@click_sigma_option
@keypoint_mapping_option("Also offer a keypoint mapping's keypoints (bundled: apollocar3d-66, ApolloCar3D's 66 car "
                         "keypoints: lamp, glass, door and handle corners, wheel centres, plates; or a mapping file, "
                         "e.g. from `toosicubix learn-parts`): a click named one takes its typical position for the "
                         "vehicle's prototype, unnamed clicks are named among them, and the parts to click next are "
                         "them.")
@click.option("--sequence", default=None, metavar="NAME",
              help="The IMAGES are the frames of sequence NAME, in frame order: each frame number is the last run of "
                   "digits in its file name when every name has one (000123.png -> 123), else its position. Images "
                   "the file has keep their own sequence and frame. A new vehicle gets a new track; a track with a "
                   "vehicle on another frame but not this one is shown predicted, to confirm (Enter), box (b), "
                   "click, or dismiss (x).")
@click.option("--frame-rate", type=Finite(min=0.0, max=1000.0, min_open=True), default=10.0, show_default=True,
              help="Frames per second of the sequences, as `fit --frame-rate` (the tracks' motion model's clock).")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Interface to listen on. Anything but 127.0.0.1 lets other machines edit your file.")
@click.option("--port", type=click.IntRange(0, 65535), default=8017, show_default=True, help="Port; 0: any free one.")
def annotate_command(images: tuple[Path, ...], cameras_path: Path | None, out: Path, prototype: str,
                     priors_path: Path | None, kitti_ground: bool, road_normal: str | None,
                     camera_height: float | None, click_sigma: float | None, mapping: Any, sequence: str | None,
                     frame_rate: float, host: str, port: int) -> None:
    """Serve a local page to click vehicle parts on IMAGES and watch each cuboid form.

    IMAGES are image files or folders: a folder gives its .png, .jpg, .jpeg, .bmp and .webp files (any letter case;
    not its subfolders), sorted by file name; the page shows the images in the order given. Each image's id is its
    file stem, and --cameras finds its camera by that stem or its file name (see --cameras).

    --kitti-ground, --road-normal x,y,z and --camera-height give the images the file does not have yet a ground
    block (its own blocks are kept); it is written to the file, so `fit` uses it too.

    After every click the vehicle is refitted as `fit` fits it; the page draws the cuboid, the residuals, the
    yaw and depth sigmas and the parts to click next. When the file already has vehicles, the click noise and
    each camera's road normal are first estimated from them, as `fit` estimates them (the road normal only for
    images without a ground block of their own, and never written to the file); they are estimated again, in
    the background, each time the file's vehicles double from 30 on, up to the 400 that `fit`'s pilot takes
    (each fit on the page says what it was made for). Click first or choose a name first:
    a click left unnamed is named from where it is (before a fit exists, by the prototype's prior cuboid placed by
    the box and the named clicks), or the page asks, offering the few names that fit there; s swaps a vehicle's
    left and right (the vehicle's own, as its driver sees them), and a banner says when the clicks fit no cuboid a
    person could have clicked, with the likely cause. The file is written after every
    change; two pages on one file never lose a click (a change made on a stale page is refused and re-applied
    after a reload). With --mapping, the page offers that mapping's keypoints too (a filter box above them),
    names unnamed clicks among them (the most probable visible one, given its spread and how often people click
    it) and suggests them as the next clicks. A road user with keypoints of its own (the Pedestrian prototype:
    COCO's 17; Cyclist, Traffic cone, ...) is clicked on those, which the page offers in place of a car's parts.

    With --sequence, the images are the frames of one video and vehicles are tracks across them (saved with their
    sequence, frame and track, so `fit` fits each track as one vehicle): `[` `]` step through the frames, and each
    frame shows every nearby track not on it yet as a dashed, predicted cuboid from the track's other frames, to
    confirm, box or click instead of clicking ten parts again.

    \b
    Example:
      toosicubix annotate image_2/*.png --cameras cameras.json -o annotations.json
      toosicubix annotate kitti/training/image_2 --cameras kitti/training/calib --kitti-ground
      toosicubix annotate frames/*.png --sequence 0003 --cameras cameras.json -o annotations.json
      toosicubix annotate frames/*.jpg --cameras cameras.json --road-normal 0.04,-0.99,0.15
      toosicubix annotate frames/*.jpg --cameras cameras.json --mapping apollocar3d-66
    """
    from toosicubix.annotations.convert import ground_with
    from toosicubix.annotations.priors_file import load_priors
    from toosicubix.errors import InputFileError
    from toosicubix.pipeline.settings import ground_overrides
    from toosicubix.solver.compiled import warm_up
    from toosicubix.solver.track import TrackOptions
    from toosicubix.web.request_fields import ApiError
    from toosicubix.web.server import serve
    from toosicubix.web.session import Session, load_cameras
    from toosicubix.web.worker import WorkerProcess

    road, normal = road_normal_choice(road_normal)
    ground = ground_overrides(kitti_ground, normal, camera_height=camera_height)
    estimate_road = road != "none" and ground is None  # a ground option gives every image its road, as in fit
    images = expand_images(images)
    if not out.parent.is_dir():
        raise BadInput(f"{out}: the folder {out.parent} does not exist")
    try:
        if ground is not None:
            ground_with(None, ground)  # a zero normal: refused here, not on the first click
        priors = load_priors(priors_path)
        ids = [p.stem for p in images]
        cameras = load_cameras(cameras_path, ids, [p.name for p in images]) if cameras_path is not None else {}
        options, road_grounds, estimate = _batch_settings(out, priors, click_sigma, estimate_road)
    except (InputFileError, ApiError) as exc:
        raise BadInput(str(exc)) from None
    warm_up(lambda text: click.echo(text, err=True))  # before the first refit, which would otherwise wait for it
    # The estimates again as the file grows: in a worker process, not competing with the page's requests.
    with WorkerProcess(estimate) as worker:
        try:
            session = Session(list(images), out, cameras, priors, prototype, options, ground=ground,
                              road_grounds=road_grounds, estimate=worker if estimate is not None else None,
                              mapping=mapping, sequence=sequence, track_options=TrackOptions(frame_rate=frame_rate))
        except (InputFileError, ApiError) as exc:
            raise BadInput(str(exc)) from None
        if sequence is not None:
            click.echo(_sequence_line(session, sequence), err=True)
        try:
            server = serve(session, host, port)
        except OSError as exc:
            raise BadInput(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
        if not server.loopback:
            click.echo(f"warning: listening on {host}: other machines can read the images and change {out}",
                       err=True)
        click.echo(f"annotating {len(images)} image(s) into {out}: open {server.url}  (Ctrl-C stops)")
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            click.echo("stopped", err=True)
        finally:
            server.server_close()


def expand_images(given: tuple[Path, ...]) -> tuple[Path, ...]:
    """The image files of the command line: each file as given, each folder's :data:`IMAGE_EXTENSIONS` files sorted by
    name. Exits 2 (:class:`BadInput`) naming what is missing, or a folder without images."""
    out: list[Path] = []
    for path in given:
        if path.is_dir():
            found = sorted((p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS),
                           key=lambda p: p.name)
            if not found:
                raise BadInput(f"{path}: a folder with no images in it (expected {', '.join(IMAGE_EXTENSIONS)} files; "
                               "its subfolders are not searched)")
            out.extend(found)
        elif path.is_file():
            out.append(path)
        else:
            raise BadInput(f"no such image or folder: {path}")
    return tuple(out)


def _sequence_line(session: Any, sequence: str) -> str:
    """What the terminal says at start of a sequence: its frames and how they were numbered."""
    new = [im for im in session.images if im.sequence == sequence and im.id in session.new_ids]
    kept = len(session.images) - len(new)
    how = ("by the last run of digits in each file name (e.g. "
           f"{new[-1].path.name} -> frame {new[-1].frame})" if session.frames_from_names else
           "by their position in the given order (not every file name has digits, or two give the same number)")
    line = f"sequence {sequence}: {len(new)} new frame(s), numbered {how}" if new else f"sequence {sequence}:"
    if kept:
        line += f"; {kept} image(s) already in {session.out.name} keep their own sequence and frame"
    return line


def _batch_settings(out: Path, priors, click_sigma: float | None, estimate_road: bool):
    """The solver settings and per-camera road grounds (when ``estimate_road``) that `fit` would estimate for the
    file ``out`` (none when it does not exist yet), saying on stderr what they are, and the function that estimates
    them again from the file as it grows (None when nothing is estimated)."""
    from dataclasses import replace

    from toosicubix.pipeline.road_normal import MIN_VEHICLES
    from toosicubix.solver.fit import SolverOptions

    options = SolverOptions() if click_sigma is None else replace(SolverOptions(), click_sigma=click_sigma)
    if click_sigma is not None and not estimate_road:
        announced_estimates(out, priors, options, False, False)  # nothing to estimate: it says so
        return options, None, None

    estimate = partial(_estimates, priors=priors, options=options, estimate_click_sigma=click_sigma is None,
                       estimate_road_normal=estimate_road, shown=out)  # picklable: run in a worker process too
    if not out.is_file():
        source = "given" if click_sigma is not None else "default: no file yet to estimate it from"
        noise = "the click noise (for cuboid parts with how far they sit from the cuboid model)"
        what = ("the road normal" if click_sigma is not None else
                f"{noise} and the road normal" if estimate_road else noise)
        road = "no road normal estimated yet; " if estimate_road else "the road as the ground options give it; "
        click.echo(f"click noise: {options.click_sigma:g} px ({source}); {road}the page estimates {what} as `fit` "
                   f"does once the file has {MIN_VEHICLES} vehicles, and again as they double", err=True)
        return options, None, estimate
    return (*estimate(out), estimate)


def _estimates(path: Path, priors: Any, options: Any, estimate_click_sigma: bool, estimate_road_normal: bool,
               shown: Path) -> tuple[Any, dict[tuple, dict[str, Any]]]:
    """What `fit` would estimate from the file ``path`` (a snapshot of ``shown``), said on stderr: the solver
    settings with its click noise, and per camera the ground block of its road normal."""
    from toosicubix.pipeline.pilot import estimated_grounds

    findings = announced_estimates(path, priors, options, estimate_click_sigma, estimate_road_normal, shown=shown)
    return findings.options, estimated_grounds(findings.road_normals)
