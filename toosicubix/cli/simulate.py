"""``toosicubix simulate``: thin over :mod:`toosicubix.simulate.annotator`."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from toosicubix.cli.options import BadInput, Finite, GroundTruth, ground_truth_options, parse_sequences


@click.command("simulate")
@ground_truth_options("kitti", "kitti-tracking")
@click.option("-o", "--out", "annotations", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Annotation file to write (format v1).")
@click.option("--gt-out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Where to write the simulated vehicles' ground truth as a KITTI object folder (label_2/, "
                   "calib/) for `toosicubix eval --kitti`. Default: <annotation file without .json>_gt/.")
@click.option("--noise", "noise_px", type=Finite(min=0.0), default=1.0, show_default=True,
              help="Gaussian click noise, pixels per coordinate.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (per vehicle streams).")
@click.option("--exact-placement", is_flag=True,
              help="Put every part exactly where the parts model says (default: varied as on real vehicles).")
@click.option("--max-clicks", type=click.IntRange(min=1), default=12, show_default=True,
              help="The most clicked points per vehicle.")
@click.option("--order", type=click.Choice(["preference", "random"]), default="preference", show_default=True,
              help="The order the person takes the parts it can see in: a person's preference (tyres, lights, "
                   "edges, ...) or random (an annotator whose choice owes nothing to the solver).")
@click.option("--classes", default="Car,Van,Truck", show_default=True, help="KITTI types to simulate.")
@click.option("--max-truncation", type=Finite(), default=0.0, show_default=True,
              help="Keep vehicles truncated at most this much (object labels: fraction; tracking: 0, 1, 2).")
@click.option("--max-occlusion", type=click.IntRange(0, 3), default=1, show_default=True,
              help="Keep vehicles occluded at most this much (0 visible, 1 partly, 2 largely).")
@click.option("--min-depth", type=Finite(), default=3.0, show_default=True, help="Metres.")
@click.option("--max-depth", type=Finite(), default=60.0, show_default=True, help="Metres.")
@click.option("--min-box-height", type=Finite(), default=25.0, show_default=True, help="2D box height, pixels.")
@click.option("--frames-per-track", type=click.IntRange(min=1), default=None,
              help="Tracking labels: at most this many frames per track, evenly spread (default 3); with --tracks, "
                   "the first this many frames of each track's run (default: the whole run).")
@click.option("--sequences", default=None, help="Tracking labels: e.g. 0010-0020 or 0001,0005 (default: all).")
@click.option("--ground", "ground_kind", type=click.Choice(["none", "kitti"]), default="none", show_default=True,
              help="Give every image a ground block: kitti = KITTI's nominal road (camera 1.65 m above it).")
@click.option("--tracks", is_flag=True,
              help="Tracking labels: one vehicle per track over every frame of its longest run of consecutive "
                   "frames that pass the filters (images carry sequence and frame, vehicles their track).")
@click.option("--keyframes", type=click.IntRange(min=1), default=None,
              help="With --tracks: clicks on a track's first frame, every K-th frame after it and its last frame "
                   "only (default 1: every frame).")
@click.option("--boxes", "box_kind", type=click.Choice(["person", "projection", "none"]), default=None,
              help="With --tracks: the 2D box on every frame: person = a person's box around the vehicle's "
                   "silhouette, projection = KITTI's own box (the projected cuboid), none (default: person).")
def simulate_command(ground_truth: GroundTruth, annotations: Path, gt_out: Path | None, noise_px: float, seed: int,
                     exact_placement: bool, max_clicks: int, order: str, classes: str, max_truncation: float,
                     max_occlusion: int, min_depth: float, max_depth: float, min_box_height: float,
                     frames_per_track: int | None, sequences: str | None, ground_kind: str, tracks: bool,
                     keyframes: int | None, box_kind: str | None) -> None:
    """Simulate a person clicking parts on real ground-truth cuboids (no public human clicks exist).

    Selects vehicles from KITTI object or tracking labels, places the parts a person would click (tyre
    contacts, light pairs, badges, vertical edges, roof pairs, box corners, a ground arrow for straight
    views), keeps those a person could see, adds click noise, and writes an annotation file plus the
    selected vehicles' ground truth in KITTI format. Tracking images get ids <sequence>_<frame:06d>.
    With --tracks, every frame of each selected track is kept, clicked only on keyframes, and boxed on every
    frame. The annotator model is described in `toosicubix.simulate`. Simulated clicks are not human clicks.

    \b
    Example:
      toosicubix simulate --kitti-tracking data/kitti_tracking --sequences 0010-0020 -o sim.json
      toosicubix fit sim.json && toosicubix eval --kitti sim_gt
      toosicubix simulate --kitti-tracking data/kitti_tracking --sequences 0000-0009 --tracks --keyframes 5 -o t.json
    """
    from toosicubix.model import KITTI_GROUND
    from toosicubix.simulate.annotator import (
        NOT_A_KEYFRAME,
        AnnotatorOptions,
        SelectionOptions,
        TrackOptions,
        select_kitti_tracks,
        select_vehicles,
        simulate,
        simulate_tracks,
        write_simulation,
    )

    if not tracks and (keyframes is not None or box_kind is not None):
        raise BadInput(f"{'--keyframes' if keyframes is not None else '--boxes'} needs --tracks")
    if tracks and ground_truth.kind != "kitti-tracking":
        raise BadInput(f"--tracks needs tracking labels (--kitti-tracking), got {ground_truth.flag}")
    if not tracks and frames_per_track is None:
        frames_per_track = 3
    try:  # the options check themselves (simulate.annotator): say what is wrong before any file is read
        selection = SelectionOptions(
            classes=tuple(c.strip() for c in classes.split(",") if c.strip()), max_truncation=max_truncation,
            max_occlusion=max_occlusion, min_depth=min_depth, max_depth=max_depth, min_box_height=min_box_height,
            frames_per_track=frames_per_track, sequences=parse_sequences(sequences),
        )
        options = AnnotatorOptions(noise_px=noise_px, exact_placement=exact_placement, max_clicks=max_clicks,
                                   seed=seed, order=order)
        track_options = TrackOptions(keyframes=keyframes or 1, boxes=box_kind or "person") if tracks else None
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    if track_options is not None:
        simulated = simulate_tracks(select_kitti_tracks(ground_truth.root, selection), options, track_options)
    else:
        simulated = simulate(select_vehicles(ground_truth.kind, ground_truth.root, selection), options)
    gt_dir = gt_out or annotations.with_name(annotations.stem + "_gt")
    write_simulation(simulated, annotations, gt_dir, KITTI_GROUND if ground_kind == "kitti" else None)
    clicks = [sv.n_clicks for sv in simulated if NOT_A_KEYFRAME not in sv.notes]
    images = len({sv.source.image_id for sv in simulated})
    few = sum(1 for c in clicks if c < 3)
    tracked = ""
    if track_options is not None:
        boxed = sum(sv.box2d is not None for sv in simulated)
        tracked = (f" of {len({sv.source.track for sv in simulated})} tracks, {len(clicks)} with clicks (keyframes "
                   f"every {track_options.keyframes}), {boxed} with a {track_options.boxes} box")
    click.echo(f"simulated {len(simulated)} vehicles{tracked} in {images} images -> {annotations} (clicks per "
               f"{'clicked ' if tracked else ''}vehicle: median {int(np.median(clicks)) if clicks else 0}, {few} with "
               f"fewer than 3); ground truth -> {gt_dir}", err=True)
