"""``toosicubix import coco|cvat|label-studio``: keypoint files and labelling-tool exports -> annotation file v1.

The commands are plain click commands; :data:`COMMANDS` lists them for the ``import`` group.
"""

from __future__ import annotations

from pathlib import Path

import click

from toosicubix.cli.options import BadInput
from toosicubix.errors import InputError


def _lengths(values: tuple[str, ...]) -> dict[str, tuple[float, float]]:
    from toosicubix.vocabulary import LENGTH_FEATURES

    out = {}
    for value in values:
        feature, _, size = value.partition("=")
        metres, _, sigma = size.partition(":")
        try:
            known = (float(metres), float(sigma) if sigma else 0.01)
        except ValueError:
            known = (-1.0, -1.0)
        if feature not in LENGTH_FEATURES or min(known) <= 0:
            raise click.BadParameter(f"expected FEATURE=METRES[:SIGMA] with a feature of {', '.join(LENGTH_FEATURES)}"
                                     f" and positive sizes, got {value!r}", param_hint="--length")
        out[feature] = known
    return out


_COMMON = [
    click.option("--cameras", "cameras_path", type=click.Path(path_type=Path), default=None,
                 help='Cameras: a JSON file {"cameras": [{"match": GLOB on the image name, "K": 3x3 or 9 numbers, '
                      '"distortion": [...]}]} (first match wins), a KITTI calib file (its P2 for every image) or a '
                      "folder of them (<image stem>.txt), or an OpenCV or ROS camera YAML (one camera for every "
                      "image). Every image needs a camera."),
    click.option("-o", "--out", "out_path", type=click.Path(dir_okay=False, path_type=Path), required=True,
                 help="The annotation file to write (v1)."),
    click.option("--default-prototype", default="Car", show_default=True,
                 help="Prototype of vehicles the export gives none (a warning names each)."),
    click.option("--length", "lengths", multiple=True, metavar="FEATURE=METRES[:SIGMA]",
                 help="Known size of a length feature, e.g. plate-rear=0.44:0.01 (plates default to EU 0.52 m)."),
    click.option("--strict", is_flag=True, help="Treat every warning as an error: exit 2 and write nothing."),
    click.option("-q", "--quiet", is_flag=True, help="No warnings or summary on stderr."),
]


def _common(command):
    for option in reversed(_COMMON):
        command = option(command)
    return command


def _run(read, source: Path, cameras_path: Path | None, out_path: Path, strict: bool, quiet: bool) -> None:
    from toosicubix.annotations.schema import parse_annotations
    from toosicubix.errors import FormatError, InputFileError
    from toosicubix.formats.cameras import load_cameras

    try:
        cameras = load_cameras(cameras_path) if cameras_path is not None else None
        doc, summary = read(source, cameras)
        parse_annotations(doc, out_path)  # what we write must be a valid annotation file
    except (FormatError, InputFileError) as exc:
        raise BadInput(str(exc)) from None
    if strict and summary.warnings:
        raise BadInput("\n".join(summary.warnings) + f"\n--strict: {len(summary.warnings)} warnings, nothing written")
    if not quiet:
        for warning in summary.warnings:
            click.echo(f"warning: {warning}", err=True)
    _write(doc, summary, out_path, quiet)


def _write(doc: dict, summary, out_path: Path, quiet: bool) -> None:
    """Write an imported annotation file atomically, then the import's summary on stderr."""
    from toosicubix.formats.atomic import atomic_write_json

    try:
        atomic_write_json(out_path, doc)
    except OSError as exc:
        raise BadInput(f"cannot write {out_path}: {exc.strerror or exc}") from None
    if not quiet:
        for line in summary.lines():
            click.echo(line, err=True)
        click.echo(f"wrote {out_path}", err=True)


def foreign_file(path: Path) -> None:
    """For ``fit`` and ``validate`` when ``path`` is no annotation file: if it is a labelling tool's file (COCO,
    Label Studio, CVAT, KITTI labels), raise :class:`BadInput` with the one line saying which ``toosicubix
    import`` turns it into one, instead of the schema's errors."""
    from toosicubix.formats.tool_import import import_hint

    hint = import_hint(path)
    if hint is not None:
        raise BadInput(hint) from None


def _sequence_name(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    from toosicubix.formats.tool_import import check_sequence_name

    try:
        return None if value is None else check_sequence_name(value)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None


@click.command("cvat")
@click.argument("annotations_xml", type=click.Path(dir_okay=False, path_type=Path))
@_common
@click.option("--sequence", "sequence", default=None, metavar="NAME", callback=_sequence_name,
              help="CVAT for video: the sequence name of the frames [default: the task name, else task_<id> or "
                   "job_<id>].")
def cvat_command(annotations_xml: Path, cameras_path: Path | None, out_path: Path, default_prototype: str,
                 lengths: tuple[str, ...], strict: bool, quiet: bool, sequence: str | None) -> None:
    """Import a CVAT for images 1.1 or CVAT for video 1.1 export as an annotation file: its annotations.xml, or
    the .zip CVAT downloads (read as it is; it needs exactly one annotations.xml).

    Skeletons (from `toosicubix template cvat`) are vehicles, their points the keypoints; points marked
    outside are not clicked. Loose points are grouped into vehicles by group_id (a box in the group gives
    the prototype and box). Task, job and project exports are read (a video's: task or job). Keypoints that
    cannot be grouped, unknown names and points outside the image are warnings that name the image and the
    element.

    A video export (tracks) becomes one sequence: frame N is the image <sequence>_<N:06d> (file
    images/frame_<N:06d>.PNG), tracks with the same group_id are one vehicle whose "track" is
    <sequence>-<smallest track id>. Clicks come from keyframes only; boxes from every frame the box track is
    not outside; outside means not in the frame.

    \b
    Example:
      toosicubix import cvat annotations.xml --cameras cameras.json -o annotations.json
      toosicubix import cvat task_7-cvat_for_images.zip --cameras cameras.json -o annotations.json
      toosicubix import cvat video/annotations.xml --sequence drive3 --cameras cameras.json -o drive3.json
    """
    from toosicubix.formats.cvat import read_cvat

    known = _lengths(lengths)
    _run(lambda path, cameras: read_cvat(path, cameras, default_prototype, known, sequence),
         annotations_xml, cameras_path, out_path, strict, quiet)


@click.command("label-studio")
@click.argument("export_json", type=click.Path(dir_okay=False, path_type=Path))
@_common
@click.option("--image-key", default=None, help="The task data key of the image [default: image].")
def label_studio_command(export_json: Path, cameras_path: Path | None, out_path: Path, default_prototype: str,
                         lengths: tuple[str, ...], strict: bool, quiet: bool, image_key: str | None) -> None:
    """Import a Label Studio JSON export as an annotation file.

    Boxes are vehicles (their label is the prototype); keypoints (percent of original_width and
    original_height) belong to the box named by their parentID, else to the box a relation ties them to,
    else to the one box that contains them. Old exports with 'completions' are read too.

    Image ids are the stems of the file names as the person gave them: an upload's
    /data/upload/<project>/<8 hex>-<name> gives <name>, a local-files ?d=<path> its path (refused if it holds
    '..'), an s3://, gs:// or azure-blob:// object its key's base name (docs/tools.md).

    \b
    Example:
      toosicubix import label-studio export.json --cameras cameras.json -o annotations.json
    """
    from toosicubix.formats.labelstudio import read_label_studio

    known = _lengths(lengths)
    _run(lambda path, cameras: read_label_studio(path, cameras, default_prototype, known, image_key),
         export_json, cameras_path, out_path, strict, quiet)


@click.command("coco")
@click.argument("keypoints", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--mapping", "mapping_name", required=True,
              help="A bundled mapping (apollocar3d-66, apollocar3d-66-paper, toosicubix, coco-person, two-wheeler) "
                   "or a mapping file (JSON, schema in schemas/mapping.schema.json): which keypoints make which "
                   "parts.")
@click.option("--cameras", "cameras_path", type=click.Path(path_type=Path), default=None,
              help='Cameras: a JSON file {"cameras": [{"match": GLOB on file_name, "K": 3x3 or 9 numbers, '
                   '"distortion": [...]}]} (first match wins), a KITTI calib file or a folder of them (<image '
                   "stem>.txt), or an OpenCV or ROS camera YAML; else every image needs its own K (images[].K).")
@click.option("--option", "options", multiple=True,
              help="Use the mapping's optional parts with this option, e.g. --option plates (licence-plate "
                   "corners as a known-width feature). Repeatable.")
@click.option("-o", "--out", "out_path", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="The annotation file to write.")
@click.option("-q", "--quiet", is_flag=True, help="No summary on stderr.")
def coco_command(keypoints: Path, mapping_name: str, cameras_path: Path | None, options: tuple[str, ...],
                        out_path: Path, quiet: bool) -> None:
    """Turn a COCO keypoint file into an annotation file v1.

    Image id = the file name's stem, vehicle id = the COCO annotation id, box2d from bbox. Keypoints with
    v = 0 are skipped, v = 1 (labelled, not visible) kept; crowd annotations (iscrowd 1) are skipped. The
    summary on stderr counts every labelled keypoint the mapping left unused, per name, and the crowds.

    Road users: --mapping coco-person makes every person of a COCO person-keypoint file a Pedestrian (its 17
    keypoints by their COCO names; a person without a labelled ankle is fitted all the same, its feet placed by
    the height prior, and the summary counts them); --mapping two-wheeler makes cyclists, motorcyclists,
    bicycles and motorcycles (see docs/road-users.md).

    Videos (TAO, BDD100K): an image with video_id (named by videos[]), video_name or video, and frame_index
    or frame_id is a frame of a sequence (image id <sequence>_<frame:06d>); an annotation's track_id or
    instance_id makes its track <sequence>-<id> (without keypoints: a box-only frame).

    Exit code 0 on success, 2 for a malformed file (named with its JSON path), an image without a camera or a
    keypoint the mapping does not know.

    Then, in the same vocabulary: `toosicubix validate ann.json --mapping apollocar3d-66` says which keypoints to
    click next, and `toosicubix annotate IMAGES --mapping apollocar3d-66 -o ann.json` clicks them on a page.

    \b
    Example:
      toosicubix import coco apollo_val.json --mapping apollocar3d-66 --cameras cameras.json -o ann.json
      toosicubix import coco person_keypoints.json --mapping coco-person --cameras cameras.json -o ann.json
    """
    from toosicubix.annotations.mapping import load_mapping
    from toosicubix.formats.cameras import load_cameras
    from toosicubix.formats.coco import CocoImport

    try:
        mapping, _ = load_mapping(mapping_name)
        unknown = set(options) - {p.option for p in mapping.parts if p.option is not None}
        if unknown:
            raise click.BadParameter(f"the mapping {mapping.name!r} has no parts with option "
                                     f"{', '.join(sorted(unknown))}", param_hint="--option")
        cameras = load_cameras(cameras_path) if cameras_path is not None else None
        imported = CocoImport(keypoints, mapping, cameras, options)
        imported.write(out_path)  # image by image, atomically: a problem found on the way leaves nothing written
    except InputError as exc:
        raise BadInput(str(exc)) from None
    except OSError as exc:
        raise BadInput(f"cannot write {out_path}: {exc.strerror or exc}") from None
    if not quiet:
        for line in imported.summary.lines():
            click.echo(line, err=True)
        click.echo(f"wrote {out_path}", err=True)


#: The commands of the ``import`` group this module contributes.
COMMANDS = (coco_command, cvat_command, label_studio_command)


@click.group("import")
def import_group() -> None:
    """Import labelling-tool exports as annotation files (v1).

    \b
    Example:
      toosicubix import coco keypoints.json --mapping apollocar3d-66 --cameras cameras.json -o annotations.json
      toosicubix import cvat annotations.xml --cameras cameras.json -o annotations.json
      toosicubix import label-studio export.json --cameras cameras.json -o annotations.json
    """


for _command in COMMANDS:
    import_group.add_command(_command)
