"""``toosicubix learn-parts``: where ApolloCar3D's keypoints sit on a vehicle, learned from its poses
(thin over :mod:`toosicubix.parts.learned`)."""

from __future__ import annotations

from pathlib import Path

import click

from toosicubix.cli.options import BadInput, Finite
from toosicubix.errors import InputError
from toosicubix.fields import shown
from toosicubix.parts.learned import CONTRADICTION_M


@click.command("learn-parts")
@click.argument("keypoints", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--car-models", "car_models_path", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="ApolloCar3D car_models.json: each car model's extents and type.")
@click.option("--cameras", "cameras_path", type=click.Path(path_type=Path), required=True,
              help="The cameras of the images, in any form `toosicubix import` takes: a cameras JSON file, a KITTI "
                   "calib file or a folder of them, or an OpenCV or ROS camera YAML.")
@click.option("--mapping", "mapping_name", default="apollocar3d-66", show_default=True,
              help="The mapping whose keypoint parts get the learned positions (names by index, other parts kept).")
@click.option("--images", "which", type=click.Choice(["all", "even", "odd"]), default="all", show_default=True,
              help="Learn from all images, or those at even or odd positions when sorted by file name.")
@click.option("--min-samples", type=click.IntRange(min=3), default=5, show_default=True,
              help="Keypoints seen on fewer vehicles of a prototype keep only the pooled position.")
@click.option("--max-offset", type=Finite(min=0.0, min_open=True), default=CONTRADICTION_M,
              show_default=True,
              help="Metres: a second pass leaves out cars whose keypoints lie farther than this (RMS) from the "
                   "first pass's positions at their ground-truth pose (poses that contradict the clicks).")
@click.option("--mirror-pairs", is_flag=True,
              help="Put each left/right keypoint pair (names with the words left and right swapped) at the mean of "
                   "its two learned positions, mirrored: cars are mirror-symmetric. Each keeps its own spread. Off by "
                   "default: on ApolloCar3D it lowered the rotation error but not every other error (benchmarks/"
                   "decisions.md, rule 32).")
@click.option("-o", "--out", "out_path", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="The mapping file to write.")
def learn_parts_command(keypoints: Path, car_models_path: Path, cameras_path: Path, mapping_name: str, which: str,
                        min_samples: int, max_offset: float, mirror_pairs: bool, out_path: Path) -> None:
    """Learn where each keypoint sits on a vehicle, as fractions of its dimensions, with its spread.

    Reads an ApolloCar3D keypoint file (COCO with a 6-DoF `pose` per car), moves every labelled keypoint's ray
    into its car's frame and finds, per prototype (from the car model's type) and keypoint, the point nearest
    to all the rays; and, pooled over prototypes, the faces each keypoint is seen from (at least one of them was
    turned to the camera on 95 % of the cars it was labelled on), which the page and the suggested next clicks
    use to say whether it can be seen, and how often each was labelled where it could be seen (the suggestions
    weigh their gain by it). Writes a mapping file: the given mapping with these positions.

    \b
    Example:
      toosicubix learn-parts apollo_val.json --car-models car_models.json --cameras cameras.json -o mine.json
    """
    from toosicubix.annotations.mapping import load_mapping
    from toosicubix.formats.apollocar3d import keypoint_samples, read_apollocar3d, read_car_models
    from toosicubix.formats.atomic import atomic_write_json
    from toosicubix.formats.cameras import intrinsics, load_cameras
    from toosicubix.parts.learned import learned_mapping

    try:
        mapping, source = load_mapping(mapping_name)
        if mapping.keypoints is None:
            raise BadInput(f"{source}: the mapping does not name its keypoints by index ($.keypoints)")
        cameras = load_cameras(cameras_path)
        images = sorted(read_apollocar3d(keypoints, read_car_models(car_models_path)), key=lambda im: im.file_name)
    except InputError as exc:
        raise BadInput(str(exc)) from None
    images = {"all": images, "even": images[0::2], "odd": images[1::2]}[which]
    K_of = {}
    for im in images:
        camera = cameras.camera_for(im.file_name)
        if camera is None:
            raise BadInput(f"{cameras_path}: no camera for image {shown(im.file_name)} "
                           f"({cameras.why_none(im.file_name)})")
        K_of[im.id] = intrinsics(camera)  # a K, or a KITTI calib's P[:, :3]
    try:
        samples = keypoint_samples(images, mapping.keypoints, K_of)
    except InputError as exc:
        raise BadInput(str(exc)) from None
    how = f"toosicubix learn-parts {keypoints.name} --images {which} --max-offset {max_offset:g}" + (
        " --mirror-pairs" if mirror_pairs else "")
    document, report = learned_mapping(mapping.model_dump(mode="json", exclude_none=True), samples, min_samples, how,
                                       max_offset, mirror_pairs)
    try:
        atomic_write_json(out_path, document)
    except OSError as exc:
        raise BadInput(f"cannot write {out_path}: {exc.strerror or exc}") from None
    n = sum(1 for p in document["parts"] if p["kind"] == "keypoint")
    click.echo(f"learned {n} keypoint positions from {len(samples)} labelled keypoints on "
               f"{sum(len(im.cars) for im in images)} cars in {len(images)} images; wrote {out_path}", err=True)
    click.echo(f"left out {len(report.left_out)} of {report.vehicles} cars whose keypoints lie more than "
               f"{max_offset:g} m (RMS) from their rays at their ground-truth pose{_listed(report.left_out)}", err=True)
    click.echo(f"{len(report.hiding)} cars have a ground-truth pose that hides their own clicks (3 or more, and a "
               f"quarter, of their labelled keypoints on faces turned away from the camera; `eval --apollocar3d` "
               f"scores them apart){_listed(report.hiding)}", err=True)


def _listed(vehicles, most: int = 10) -> str:
    """': image/car, ...' for up to ``most`` vehicles (sorted), then how many more; '' for none."""
    names = sorted(vehicles)
    if not names:
        return ""
    more = f" and {len(names) - most} more" if len(names) > most else ""
    return ": " + ", ".join(names[:most]) + more
