"""The ``toosicubix`` command. Thin: parses options, calls the library, reports, sets the exit code.

Exit codes: 0 success; 1 a batch finished but some vehicles failed (validate: are not well determined);
2 bad input or usage.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import click
import numpy as np

from toosicubix import __version__
from toosicubix.formats.results import DEFAULT_OUTPUT_DIR
from toosicubix.pipeline.validation import Thresholds
from toosicubix.solver import SolverOptions

EXIT_OK, EXIT_SOME_FAILED, EXIT_BAD_INPUT = 0, 1, 2


class BadInput(click.ClickException):
    """A bad input file or option value: printed as is, exit code 2."""

    exit_code = EXIT_BAD_INPUT

    def show(self, file=None) -> None:
        click.echo(f"Error: {self.format_message()}", err=True)


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, "--version", prog_name="toosicubix")
def main() -> None:
    """ToosiCubix: 3D vehicle cuboids (rotation, position, size) from part clicks in one image.

    \b
    Typical use:
      toosicubix fit annotations.json          # writes toosicubix-out/label_2/*.txt, results.json
      toosicubix eval --kitti path/to/kitti    # scores toosicubix-out against KITTI ground truth
    """


@main.command("schema")
def schema_command() -> None:
    """Print the JSON Schema of the annotation file (format version 1).

    \b
    Example:
      toosicubix schema > annotations.schema.json
    """
    from toosicubix.annotations.schema import json_schema

    click.echo(json.dumps(json_schema(), indent=2))


_FITTING_OPTIONS = [
    click.option("--priors", "priors_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
                 help="Size priors file (JSON, see README); default: the bundled KITTI and Cityscapes 3D table."),
    click.option("--lambda", "lambda_3d", type=click.FloatRange(min=0.0, min_open=True),
                 default=SolverOptions.lambda_3d, show_default=True,
                 help="Weight of the size prior in the coordinate descent's 3D cost."),
    click.option("--lambda-p", "lambda_px", type=click.FloatRange(min=0.0, min_open=True),
                 default=SolverOptions.lambda_px, show_default=True,
                 help="Weight of the size prior in the pixel cost, in px^2 per squared Mahalanobis unit: the click "
                      "noise variance at which clicks and prior are weighed evenly. Smaller trusts the clicks more."),
    click.option("--config", "config_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
                 help="Settings file (as `toosicubix tune` writes it); options given on the command line win."),
    click.option("--click-sigma", type=click.FloatRange(min=0.0, min_open=True), default=SolverOptions.click_sigma,
                 show_default=True,
                 help="Click noise in pixels the reported uncertainty (sigma, confidence, next clicks) is for."),
    click.option("--part-sigma", type=click.FloatRange(min=0.0), default=SolverOptions.part_sigma, show_default=True,
                 help="How far real parts sit from where the cuboid model puts them (tyres inside the body, lights "
                      "set back, rounded corners), metres; the reported uncertainty includes it. 0: exactly on a box."),
    click.option("--kitti-ground", is_flag=True,
                 help="Give every image KITTI's ground: camera 1.65 +- 0.1 m above a road whose normal is -y +- 1 "
                      "deg, vehicles upright within 2 deg. The options below then change single fields."),
    click.option("--camera-height", type=click.FloatRange(min=0.0, min_open=True), default=None,
                 help="Camera height above the road, metres, for every image (enables the ground contact)."),
    click.option("--camera-height-sigma", type=click.FloatRange(min=0.0, min_open=True), default=None,
                 help="Its uncertainty, metres [default 0.05, KITTI 0.1]."),
    click.option("--road-normal", default=None, help="Road normal in camera coordinates, x,y,z [default 0,-1,0]."),
    click.option("--camera-pitch-deg", type=float, default=None, help="Instead of the normal: camera pitch, > 0 up."),
    click.option("--camera-roll-deg", type=float, default=None, help="Instead of the normal: camera roll."),
    click.option("--normal-sigma-deg", type=click.FloatRange(min=0.0, min_open=True), default=None,
                 help="Uncertainty of the normal, degrees [default 1]."),
    click.option("--upright-sigma-deg", type=click.FloatRange(min=0.0, min_open=True), default=None,
                 help="How far vehicles lean from the road normal, degrees [default 2]."),
    click.option("--joint-ground", is_flag=True,
                 help="Refine each image's vehicles together with its ground plane (images with a ground block or "
                      "the options above); the camera height may then be unknown: the vehicles' sizes fix it."),
    click.option("-j", "--jobs", type=click.IntRange(min=1), default=1, show_default=True,
                 help="Worker processes; the output is the same for any number."),
]


def _fitting_options(command):
    """The options ``fit`` and ``validate`` share: priors, weights, click noise, ground cues, jobs."""
    for option in reversed(_FITTING_OPTIONS):
        command = option(command)
    return command


@dataclass(frozen=True)
class _Fitting:
    """What the shared options amount to."""

    priors_path: Path | None
    options: SolverOptions
    ground: dict[str, object]
    joint_ground: bool
    jobs: int


def _fitting(ctx: click.Context, priors_path: Path | None, lambda_3d: float, lambda_px: float,
             config_path: Path | None, click_sigma: float, part_sigma: float, kitti_ground: bool,
             camera_height: float | None,
             camera_height_sigma: float | None, road_normal: str | None, camera_pitch_deg: float | None,
             camera_roll_deg: float | None, normal_sigma_deg: float | None, upright_sigma_deg: float | None,
             joint_ground: bool, jobs: int) -> _Fitting:
    options = replace(_solver_options(ctx, config_path, lambda_3d=lambda_3d, lambda_px=lambda_px),
                      click_sigma=click_sigma, part_sigma=part_sigma)
    ground = _ground_options(kitti_ground, camera_height, camera_height_sigma, road_normal, camera_pitch_deg,
                             camera_roll_deg, normal_sigma_deg, upright_sigma_deg)
    return _Fitting(priors_path, options, ground, joint_ground, jobs)


@main.command("fit")
@click.argument("annotations", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=DEFAULT_OUTPUT_DIR, show_default=True,
              help="Output folder: label_2/<image id>.txt (KITTI) and results.json.")
@_fitting_options
@click.option("--next-clicks", type=click.IntRange(min=0), default=0, show_default=True,
              help="Per vehicle, add to results.json this many parts to click next, best first (about 2 ms a "
                   "vehicle; `toosicubix validate` shows them).")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar or summary on stderr.")
@click.pass_context
def fit_command(ctx: click.Context, annotations: Path, out_dir: Path, next_clicks: int, quiet: bool,
                **fitting_options) -> None:
    """Fit a 3D cuboid to every annotated vehicle.

    Reads ANNOTATIONS (annotation file v1, see `toosicubix schema`) and writes OUT/label_2/<image id>.txt
    in KITTI format plus OUT/results.json with the full pose of every vehicle, its uncertainty (sigma),
    what its clicks leave to the prior, and any second answer nearly as good. KITTI files store yaw only:
    pitch and roll are dropped there and kept in results.json; their score is the fit's confidence.

    Scale comes from the size priors unless the file or the options give a ground plane (vehicles stand
    upright on the road; with the camera height, on it) or known sizes (plate widths, wheelbases, tyres,
    known dimensions); the summary says which cue set each vehicle's scale.

    Exit code 0 when every vehicle was fitted, 1 when some failed (their reasons are in results.json
    and on stderr; the others are written), 2 for a bad input file or option.

    \b
    Example:
      toosicubix fit samples/annotations.json -o toosicubix-out
      toosicubix fit big.json --jobs 2 --kitti-ground
      toosicubix fit big.json --road-normal 0,-1,0 --joint-ground   # camera height unknown
    """
    from toosicubix.annotations.schema import InputFileError
    from toosicubix.pipeline.batch import OutputFolderError, fit_file

    f = _fitting(ctx, **fitting_options)
    bar = _ProgressBar(quiet)
    try:
        summary = fit_file(annotations, out_dir, f.priors_path, f.options, progress=bar.update, on_start=bar.start,
                           jobs=f.jobs, ground=f.ground, joint_ground=f.joint_ground, next_clicks=next_clicks)
    except (InputFileError, OutputFolderError) as exc:
        raise BadInput(str(exc)) from None
    finally:
        bar.finish()
    if not quiet:
        click.echo(
            f"fitted {summary.ok} of {summary.vehicles} vehicles in {summary.images} images -> "
            f"{summary.out_dir / 'label_2'} (KITTI: yaw only, pitch and roll dropped) and "
            f"{summary.out_dir / 'results.json'} (full rotations)",
            err=True,
        )
        if summary.scale_from:
            counts = ", ".join(f"{cue} {n}" for cue, n in sorted(summary.scale_from.items(), key=lambda kv: -kv[1]))
            click.echo(f"scale set by: {counts} (vehicles; per vehicle in results.json: scale_from)", err=True)
        for image_id, vehicle_id, reason in summary.failed[:20]:
            click.echo(f"  failed: image {image_id} vehicle {vehicle_id}: {reason}", err=True)
        if len(summary.failed) > 20:
            click.echo(f"  ... and {len(summary.failed) - 20} more failed vehicles (see results.json)", err=True)
    sys.exit(EXIT_SOME_FAILED if summary.failed else EXIT_OK)


@main.command("validate")
@click.argument("annotations", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--max-yaw-sigma", "max_yaw_sigma_deg", type=click.FloatRange(min=0.0, min_open=True),
              default=Thresholds.max_yaw_sigma_deg, show_default=True,
              help="A vehicle is well determined when its yaw standard deviation is at most this, degrees ...")
@click.option("--max-depth-sigma", "max_depth_sigma_rel", type=click.FloatRange(min=0.0, min_open=True),
              default=Thresholds.max_depth_sigma_rel, show_default=True,
              help="... its depth standard deviation at most this share of its depth ...")
@click.option("--allow-ambiguous", is_flag=True,
              help="... and (unless this flag is given) no second answer fits the clicks about as well.")
@click.option("--next-clicks", type=click.IntRange(min=0), default=3, show_default=True,
              help="How many parts to suggest clicking next, per vehicle.")
@_fitting_options
@click.option("--all", "show_all", is_flag=True, help="Describe every vehicle, not only those that need work.")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON on stdout instead of text.")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar on stderr.")
@click.pass_context
def validate_command(ctx: click.Context, annotations: Path, max_yaw_sigma_deg: float, max_depth_sigma_rel: float,
                     allow_ambiguous: bool, next_clicks: int, show_all: bool, as_json: bool, quiet: bool,
                     **fitting_options) -> None:
    """Check an annotation file and say which vehicles need more clicks; writes nothing.

    Schema errors are listed with their JSON paths (exit code 2). Otherwise every vehicle is fitted as
    `toosicubix fit` would fit it with the same options, and for each vehicle that is not well determined
    the report gives its constraint count, the standard deviations of its pose and size for clicks off by
    --click-sigma pixels, what its clicks leave to the prior, any second answer (e.g. turned around) that
    fits nearly as well, and the parts to click next, with where they should appear in the image and how
    much each would shrink the yaw and depth uncertainty.

    Exit code 0 when every vehicle is well determined, 1 when some are not (or cannot be fitted), 2 for a
    bad input file or option.

    \b
    Example:
      toosicubix validate annotations.json
      toosicubix validate annotations.json --kitti-ground --max-yaw-sigma 3 --all
      toosicubix validate annotations.json --json > report.json
    """
    from toosicubix.annotations.schema import InputFileError
    from toosicubix.pipeline.validation import validate_file

    f = _fitting(ctx, **fitting_options)
    thresholds = Thresholds(max_yaw_sigma_deg, max_depth_sigma_rel, allow_ambiguous)
    bar = _ProgressBar(quiet)
    try:
        report = validate_file(annotations, f.priors_path, f.options, thresholds, f.ground, f.joint_ground,
                               next_clicks, f.jobs, progress=bar.update, on_start=bar.start)
    except InputFileError as exc:
        raise BadInput(str(exc)) from None
    finally:
        bar.finish()
    if as_json:
        from toosicubix.formats.results import dumps

        click.echo(dumps(report.to_json()), nl=False)
    else:
        click.echo(report.text(show_all), nl=False)
    sys.exit(EXIT_OK if report.ok else EXIT_SOME_FAILED)


def _ground_options(kitti_ground: bool, camera_height: float | None, camera_height_sigma: float | None,
                   road_normal: str | None, camera_pitch_deg: float | None, camera_roll_deg: float | None,
                   normal_sigma_deg: float | None, upright_sigma_deg: float | None) -> dict[str, object]:
    """The ground-block fields the options set for every image (schema field names)."""
    from toosicubix.model import KITTI_GROUND

    fields: dict[str, object] = dict(KITTI_GROUND) if kitti_ground else {}
    if road_normal is not None:
        try:
            normal = tuple(float(v) for v in road_normal.split(","))
        except ValueError:
            normal = ()
        if len(normal) != 3:
            raise click.BadParameter(f"expected three numbers x,y,z, got {road_normal!r}", param_hint="--road-normal")
        fields["normal"] = normal
    given = {"camera_height": camera_height, "camera_height_sigma": camera_height_sigma,
             "camera_pitch_deg": camera_pitch_deg, "camera_roll_deg": camera_roll_deg,
             "normal_sigma_deg": normal_sigma_deg, "upright_sigma_deg": upright_sigma_deg}
    fields.update({k: v for k, v in given.items() if v is not None})
    if ("camera_pitch_deg" in fields or "camera_roll_deg" in fields) and road_normal is not None:
        raise click.UsageError("give --road-normal or --camera-pitch-deg/--camera-roll-deg, not both")
    if "camera_pitch_deg" in fields or "camera_roll_deg" in fields:
        fields.pop("normal", None)
    return fields


def _parse_sequences(value: str | None) -> tuple[str, ...] | None:
    """'0010-0020' or '0001,0005,0007' -> sequence names."""
    if value is None:
        return None
    names: list[str] = []
    for item in value.split(","):
        item = item.strip()
        first, dash, last = item.partition("-")
        if not (first.isdigit() and (not dash or last.isdigit())):
            raise click.BadParameter(f"expected sequence numbers like 0010-0020 or 0001,0005, got {item!r}",
                                     param_hint="--sequences")
        width = len(first)
        names += [f"{n:0{width}d}" for n in range(int(first), int(last if dash else first) + 1)]
    return tuple(names)


@main.command("simulate")
@click.option("--kitti", "kitti_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="KITTI object ground truth: a folder with label_2/ and calib/.")
@click.option("--kitti-tracking", "tracking_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="KITTI tracking ground truth: a folder with label_02/ and calib/.")
@click.option("-o", "--out", "annotations", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Annotation file to write (format v1).")
@click.option("--gt-out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Where to write the simulated vehicles' ground truth as a KITTI object folder (label_2/, "
                   "calib/) for `toosicubix eval --kitti`. Default: <annotation file without .json>_gt/.")
@click.option("--noise", "noise_px", type=click.FloatRange(min=0.0), default=1.0, show_default=True,
              help="Gaussian click noise, pixels per coordinate.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (per vehicle streams).")
@click.option("--exact-placement", is_flag=True,
              help="Put every part exactly where the parts model says (default: varied as on real vehicles).")
@click.option("--max-clicks", type=click.IntRange(min=1), default=12, show_default=True,
              help="The most clicked points per vehicle.")
@click.option("--classes", default="Car,Van,Truck", show_default=True, help="KITTI types to simulate.")
@click.option("--max-truncation", type=float, default=0.0, show_default=True,
              help="Keep vehicles truncated at most this much (object labels: fraction; tracking: 0, 1, 2).")
@click.option("--max-occlusion", type=click.IntRange(0, 3), default=1, show_default=True,
              help="Keep vehicles occluded at most this much (0 visible, 1 partly, 2 largely).")
@click.option("--min-depth", type=float, default=3.0, show_default=True, help="Metres.")
@click.option("--max-depth", type=float, default=60.0, show_default=True, help="Metres.")
@click.option("--min-box-height", type=float, default=25.0, show_default=True, help="2D box height, pixels.")
@click.option("--frames-per-track", type=click.IntRange(min=1), default=3, show_default=True,
              help="Tracking labels: at most this many frames per track, evenly spread.")
@click.option("--sequences", default=None, help="Tracking labels: e.g. 0010-0020 or 0001,0005 (default: all).")
@click.option("--ground", "ground_kind", type=click.Choice(["none", "kitti"]), default="none", show_default=True,
              help="Give every image a ground block: kitti = KITTI's nominal road (camera 1.65 m above it).")
def simulate_command(kitti_dir: Path | None, tracking_dir: Path | None, annotations: Path, gt_out: Path | None,
                     noise_px: float, seed: int, exact_placement: bool, max_clicks: int, classes: str,
                     max_truncation: float, max_occlusion: int, min_depth: float, max_depth: float,
                     min_box_height: float, frames_per_track: int, sequences: str | None, ground_kind: str) -> None:
    """Simulate a person clicking parts on real ground-truth cuboids (no public human clicks exist).

    Selects vehicles from KITTI object or tracking labels, places the parts a person would click (tyre
    contacts, light pairs, badges, vertical edges, roof pairs, box corners, a ground arrow for straight
    views), keeps those a person could see, adds click noise, and writes an annotation file plus the
    selected vehicles' ground truth in KITTI format. Tracking images get ids <sequence>_<frame:06d>.
    The annotator model is described in `toosicubix.simulate`. Simulated clicks are not human clicks.

    \b
    Example:
      toosicubix simulate --kitti-tracking data/kitti_tracking --sequences 0010-0020 -o sim.json
      toosicubix fit sim.json && toosicubix eval --kitti sim_gt
    """
    from toosicubix.formats import FormatError
    from toosicubix.simulate.annotator import (
        AnnotatorOptions,
        SelectionOptions,
        select_kitti_object,
        select_kitti_tracking,
        simulate,
        write_simulation,
    )

    if (kitti_dir is None) == (tracking_dir is None):
        raise click.UsageError("give exactly one of --kitti DIR and --kitti-tracking DIR")
    selection = SelectionOptions(
        classes=tuple(c.strip() for c in classes.split(",") if c.strip()), max_truncation=max_truncation,
        max_occlusion=max_occlusion, min_depth=min_depth, max_depth=max_depth, min_box_height=min_box_height,
        frames_per_track=frames_per_track, sequences=_parse_sequences(sequences),
    )
    try:
        if kitti_dir is not None:
            vehicles = select_kitti_object(kitti_dir, selection)
        else:
            vehicles = select_kitti_tracking(tracking_dir, selection)
    except FormatError as exc:
        raise BadInput(str(exc)) from None
    simulated = simulate(vehicles, AnnotatorOptions(noise_px=noise_px, exact_placement=exact_placement,
                                                    max_clicks=max_clicks, seed=seed))
    gt_dir = gt_out or annotations.with_name(annotations.stem + "_gt")
    from toosicubix.model import KITTI_GROUND

    write_simulation(simulated, annotations, gt_dir, KITTI_GROUND if ground_kind == "kitti" else None)
    clicks = [sv.n_clicks for sv in simulated]
    images = len({sv.source.image_id for sv in simulated})
    few = sum(1 for c in clicks if c < 3)
    click.echo(f"simulated {len(simulated)} vehicles in {images} images -> {annotations} (clicks per vehicle: "
               f"median {int(np.median(clicks)) if clicks else 0}, {few} with fewer than 3); ground truth -> {gt_dir}",
               err=True)


def _solver_options(ctx: click.Context, config_path: Path | None, **given: float) -> SolverOptions:
    """Defaults, then the settings file, then the options given on the command line."""
    from toosicubix.annotations.schema import InputFileError, load_settings_file

    options = SolverOptions()
    if config_path is not None:
        try:
            settings = load_settings_file(config_path)
        except InputFileError as exc:
            raise BadInput(str(exc)) from None
        from_file = {k: getattr(settings, k) for k in ("lambda_3d", "lambda_px") if getattr(settings, k) is not None}
        options = replace(options, **from_file)
    explicit = {k: v for k, v in given.items()
                if ctx.get_parameter_source(k) is not click.core.ParameterSource.DEFAULT}
    return replace(options, **explicit)


def _float_list(value: str, name: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in value.split(",") if v.strip())
    except ValueError:
        raise click.BadParameter(f"expected comma-separated numbers, got {value!r}", param_hint=name) from None
    if not values or min(values) <= 0:
        raise click.BadParameter(f"expected positive numbers, got {value!r}", param_hint=name)
    return values


@main.command("tune")
@click.argument("annotations", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--kitti", "kitti_dir", type=click.Path(path_type=Path), default=None,
              help="KITTI object ground truth (label_2/ and calib/).")
@click.option("--kitti-tracking", "tracking_dir", type=click.Path(path_type=Path), default=None,
              help="KITTI tracking ground truth (label_02/ and calib/).")
@click.option("--cityscapes", "cityscapes_dir", type=click.Path(path_type=Path), default=None,
              help="Cityscapes 3D ground truth (gtBbox3d JSON files).")
@click.option("-o", "--out", "config_out", type=click.Path(dir_okay=False, path_type=Path),
              default="toosicubix-settings.json", show_default=True,
              help="Settings file to write, for `toosicubix fit --config`.")
@click.option("--lambdas", default=",".join(f"{v:g}" for v in (0.01, 0.1, 1, 10)), show_default=True,
              help="Values of lambda (descent prior weight) to try.")
@click.option("--lambda-ps", default=",".join(f"{v:g}" for v in (0.01, 0.1, 1, 10, 100)), show_default=True,
              help="Values of lambda_p (pixel-cost prior weight) to try.")
@click.option("--refine/--no-refine", default=True, show_default=True,
              help="Then try the half-steps around the best pair.")
@click.option("--priors", "priors_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Size priors file; default: the bundled one.")
@click.option("--min-iou", type=click.FloatRange(0.0, 1.0), default=0.5, show_default=True,
              help="2D box IoU needed to pair a fit with a ground-truth vehicle.")
@click.option("-j", "--jobs", type=click.IntRange(min=1), default=1, show_default=True, help="Worker processes.")
def tune_command(annotations: Path, kitti_dir: Path | None, tracking_dir: Path | None, cityscapes_dir: Path | None,
                 config_out: Path, lambdas: str, lambda_ps: str, refine: bool, priors_path: Path | None,
                 min_iou: float, jobs: int) -> None:
    """Choose lambda and lambda_p by maximising mean sIoU against ground truth, as the paper does.

    Fits every vehicle of ANNOTATIONS with each pair of weights on a log grid (then the half-steps around
    the best), scores the fits as `toosicubix eval` does, prints the landscape (mean sIoU; mean IoU and
    median E_R of the best beside it) and writes the best pair to a settings file for `fit --config`.
    Tune on vehicles you will not report accuracy on.

    \b
    Example:
      toosicubix simulate --kitti-tracking data/kitti_tracking --sequences 0000-0009 -o tuning.json
      toosicubix tune tuning.json --kitti tuning_gt -o settings.json --jobs 2
      toosicubix fit annotations.json --config settings.json
    """
    from toosicubix.annotations.convert import load_images
    from toosicubix.annotations.schema import InputFileError
    from toosicubix.evaluation import EvalOptions, EvaluationInputError, open_ground_truth
    from toosicubix.formats import FormatError
    from toosicubix.formats.atomic import atomic_write_text
    from toosicubix.pipeline.tuning import tune
    from toosicubix.priors.table import load_priors

    given = [(kind, path) for kind, path in (("kitti", kitti_dir), ("kitti-tracking", tracking_dir),
                                             ("cityscapes", cityscapes_dir)) if path is not None]
    if len(given) != 1:
        raise click.UsageError("give exactly one ground truth: --kitti DIR, --kitti-tracking DIR or --cityscapes DIR")
    grid_l, grid_p = _float_list(lambdas, "--lambdas"), _float_list(lambda_ps, "--lambda-ps")
    try:
        images = load_images(annotations)
        priors = load_priors(priors_path)
        from toosicubix.pipeline.batch import check_prototypes

        check_prototypes(images, priors, annotations)
        ground_truth = open_ground_truth(*given[0])
    except (InputFileError, EvaluationInputError, FormatError) as exc:
        raise BadInput(str(exc)) from None
    n = sum(len(im.vehicles) for im in images)
    click.echo(f"tuning on {n} vehicles in {len(images)} images", err=True)

    def report(point) -> None:
        click.echo(f"  lambda {point.lambda_3d:<8.3g} lambda_p {point.lambda_px:<8.3g} mean sIoU "
                   f"{point.siou_mean:.4f}  mean IoU {point.iou_mean:.4f}  median E_R {point.e_r_median_deg:.2f} deg"
                   f"  ({point.n_matched} matched, {point.n_failed} failed)", err=True)

    try:
        result = tune(images, priors, ground_truth, grid_l, grid_p, eval_options=EvalOptions(min_iou=min_iou),
                      refine=refine, jobs=jobs, progress=report)
    except (EvaluationInputError, FormatError) as exc:
        raise BadInput(str(exc)) from None
    best = result.best
    click.echo(result.landscape())
    click.echo(f"best: lambda {best.lambda_3d:g}, lambda_p {best.lambda_px:g}: mean sIoU {best.siou_mean:.4f}, "
               f"mean IoU {best.iou_mean:.4f}, median E_R {best.e_r_median_deg:.2f} deg ({best.n_matched} vehicles)")
    doc = {"toosicubix_settings": 1, "lambda_3d": best.lambda_3d, "lambda_px": best.lambda_px,
           "tuned": {"annotations": str(annotations), "ground_truth": f"--{given[0][0]} {given[0][1]}",
                     "priors": str(priors_path) if priors_path else "bundled", **result.to_json()}}
    atomic_write_text(config_out, json.dumps(doc, indent=1) + "\n")
    click.echo(f"wrote {config_out}", err=True)


class _ProgressBar:
    """A progress bar on stderr for batches of more than a few vehicles."""

    MIN_VEHICLES = 50

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.bar = None

    def start(self, total: int) -> None:
        if not self.quiet and total >= self.MIN_VEHICLES:
            self.bar = click.progressbar(length=total, label="fitting", file=sys.stderr, show_eta=True)
            self.bar.__enter__()

    def update(self, n: int) -> None:
        if self.bar is not None:
            self.bar.update(n)

    def finish(self) -> None:
        if self.bar is not None:
            self.bar.__exit__(None, None, None)
            self.bar = None


# --- priors: owned by toosicubix.prior_estimation; keep edits inside this section -------------------------
@main.command("priors")
@click.option("--kitti", "kitti_dir", type=click.Path(path_type=Path), default=None,
              help="KITTI object labels: a root with label_2/, or a folder of label .txt files; every object "
                   "counts once.")
@click.option("--kitti-tracking", "tracking_dir", type=click.Path(path_type=Path), default=None,
              help="KITTI tracking labels: a root with label_02/<seq>.txt; every track counts once.")
@click.option("--cityscapes", "cityscapes_dir", type=click.Path(path_type=Path), default=None,
              help="Cityscapes 3D: a folder searched recursively for *_gtBbox3d.json; the classes are the "
                   "boxes' prototype `type` names (e.g. 'Mid Size Car').")
@click.option("-o", "--out", "out_path", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Priors file to write (JSON); may be the --base file.")
@click.option("--classes", default=None,
              help="Comma-separated classes, case-insensitive [default: Car,Van,Truck for KITTI; every vehicle "
                   "prototype type found for Cityscapes].")
@click.option("--sequences", default=None, help="KITTI tracking only: e.g. 0000-0009 or 0001,0005 (default: all).")
@click.option("--min-samples", type=click.IntRange(min=1), default=20, show_default=True,
              help="Classes with fewer samples are written but named in a warning; fewer than 2 are skipped.")
@click.option("--base", "base_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Start from this priors file: replace or add only the estimated classes, keep every other entry.")
@click.option("--covariance", "method", type=click.Choice(["paper", "whitened"]), default="paper",
              show_default=True,
              help="paper: geometric median of the outer products divided by c (Gaussian-consistent for isotropic "
                   "spread); whitened: its fixed point in whitened coordinates (consistent for any Gaussian).")
@click.option("-q", "--quiet", is_flag=True, help="No summary or warnings on stderr.")
def priors_command(kitti_dir: Path | None, tracking_dir: Path | None, cityscapes_dir: Path | None, out_path: Path,
                   classes: str | None, sequences: str | None, min_samples: int, base_path: Path | None,
                   method: str, quiet: bool) -> None:
    """Estimate Gaussian size priors per class from ground-truth cuboids, as the paper does.

    Per class (KITTI type, or Cityscapes 3D prototype type): mean = geometric median of the dimension
    vectors (dx, dy, dz) = (length, width, height); covariance = geometric median of the outer products
    (d - mean)(d - mean)^T divided by the Gaussian consistency factor c = 0.586. KITTI tracking counts every
    track once. Writes a priors file for `toosicubix fit --priors`; every entry records its data, its sample
    count and the method. Per-class counts and means go to stderr, with a warning naming every class with
    fewer than --min-samples samples.

    Exit code 0 on success, 2 for a missing folder, a malformed label file (file and line) or no estimable class.

    \b
    Example:
      toosicubix priors --kitti-tracking data/kitti_tracking --sequences 0000-0009 -o priors.json
      toosicubix priors --cityscapes gtBbox3d/train --base priors.json -o priors.json
    """
    from toosicubix.annotations.schema import InputFileError, load_priors_file
    from toosicubix.evaluation import EvaluationInputError
    from toosicubix.formats import FormatError
    from toosicubix.priors.estimation import (
        PriorEstimationError,
        collect_dimensions,
        estimate_priors,
        format_sequences,
        priors_document,
        write_priors_file,
    )

    given = [(kind, flag, path) for kind, flag, path in (
        ("kitti", "--kitti", kitti_dir), ("kitti-tracking", "--kitti-tracking", tracking_dir),
        ("cityscapes", "--cityscapes", cityscapes_dir)) if path is not None]
    if len(given) != 1:
        raise click.UsageError("give exactly one ground truth: --kitti DIR, --kitti-tracking DIR or --cityscapes DIR")
    kind, flag, gt_dir = given[0]
    if sequences is not None and kind != "kitti-tracking":
        raise click.UsageError("--sequences applies to --kitti-tracking only")
    sequence_names = _parse_sequences(sequences)
    class_list = tuple(c.strip() for c in classes.split(",") if c.strip()) if classes is not None else None
    if class_list is not None and not class_list:
        raise click.BadParameter("expected at least one class name", param_hint="--classes")
    command = f"toosicubix priors {flag} {gt_dir}"
    if sequence_names is not None:
        command += f" --sequences {format_sequences(sequence_names)}"
    if class_list is not None:
        command += f" --classes {','.join(class_list)}"
    if method != "paper":
        command += f" --covariance {method}"
    try:
        base = load_priors_file(base_path) if base_path is not None else None
        samples = collect_dimensions(kind, gt_dir, class_list, sequence_names)
    except (EvaluationInputError, FormatError, InputFileError, PriorEstimationError) as exc:
        raise BadInput(str(exc)) from None
    estimates = estimate_priors(samples, min_samples=min_samples, method=method, command=command)  # type: ignore[arg-type]
    if not quiet:
        for warning in estimates.warnings:
            click.echo(f"warning: {warning}", err=True)
    if not estimates.classes:
        raise BadInput(f"no class gave a prior from {samples.describe()}: each needs at least 2 samples")
    document = priors_document(estimates, base)
    try:
        write_priors_file(document, out_path)
    except OSError as exc:
        raise BadInput(f"cannot write {out_path}: {exc.strerror or exc}") from None
    if not quiet:
        for name, prior in estimates.classes.items():
            g = prior.gaussian
            mean = ", ".join(f"{v:.3f}" for v in g.mean)
            std = ", ".join(f"{v:.3f}" for v in g.std)
            click.echo(f"{name}: n={g.n} {samples.unit}s, mean (dx, dy, dz) = ({mean}) m, sd = ({std}) m", err=True)
        kept = len(document.prototypes) - len(estimates.classes)
        base_note = f", kept {kept} other entries of {base_path}" if base_path is not None else ""
        click.echo(f"wrote {len(estimates.classes)} priors to {out_path}{base_note}", err=True)
# --- end of priors ---------------------------------------------------------------------------------------


# --- eval: owned by the evaluation module; keep edits inside this section ---------------------------------
@main.command("eval")
@click.argument("out", required=False, default=DEFAULT_OUTPUT_DIR, type=click.Path(file_okay=False, path_type=Path))
@click.option("--kitti", "kitti_dir", type=click.Path(path_type=Path), default=None,
              help="KITTI object ground truth: a root with label_2/ and calib/, or a folder of label .txt files "
                   "(calib then looked for beside it). Example: --kitti data/kitti")
@click.option("--kitti-tracking", "tracking_dir", type=click.Path(path_type=Path), default=None,
              help="KITTI tracking ground truth: a root with label_02/<seq>.txt and calib/<seq>.txt; image ids are "
                   "<seq>_<frame as 6 digits>. Example: --kitti-tracking data/kitti_tracking")
@click.option("--cityscapes", "cityscapes_dir", type=click.Path(path_type=Path), default=None,
              help="Cityscapes 3D ground truth: a folder searched recursively for *_gtBbox3d.json; image id = file "
                   "stem without _gtBbox3d. Example: --cityscapes gtBbox3d/val")
@click.option("--min-iou", type=click.FloatRange(0.0, 1.0), default=0.5, show_default=True,
              help="2D box IoU a prediction and a ground-truth object need to be paired. Example: --min-iou 0.3")
@click.option("--classes", default=None,
              help="Comma-separated ground-truth classes to score, case-insensitive [default: Car,Van,Truck for "
                   "KITTI; car,truck,bus,caravan,trailer,train for Cityscapes]. Example: --classes Car,Van")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write the summary, every matched object and the unmatched ones as JSON. "
                   "Example: --json eval.json")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write one CSV row per matched object. Example: --csv eval.csv")
@click.option("-q", "--quiet", is_flag=True, help="No warnings or notes on stderr; the table still goes to stdout.")
def eval_command(out: Path, kitti_dir: Path | None, tracking_dir: Path | None, cityscapes_dir: Path | None,
                 min_iou: float, classes: str | None, json_path: Path | None, csv_path: Path | None,
                 quiet: bool) -> None:
    """Score fitted cuboids against KITTI or Cityscapes 3D ground truth, as the paper's Evaluation does.

    Reads OUT (a `toosicubix fit` output folder, default toosicubix-out): results.json with full rotations,
    else label_2/*.txt read as yaw only. Pairs each predicted image with its ground truth by id (file stem),
    matches objects by 2D box IoU (Hungarian), and reports per metric the mean and median: exact 3D IoU with
    full rotations, sIoU, E_R (degrees), E_t, E_d, E_comb, plus KITTI's yaw-only IoU for comparison; then
    breakdowns by depth and occlusion, and the unmatched objects. Poses are compared in the camera frame of
    the prediction's K. The table goes to stdout, warnings to stderr.

    Exit code 0 on success, 2 for a missing folder, a malformed file or a predicted image without ground truth.

    \b
    Example:
      toosicubix eval --kitti data/kitti
      toosicubix eval runs/kitti-out --kitti data/kitti --json eval.json --csv eval.csv
    """
    from toosicubix.evaluation import (
        EvalOptions,
        EvaluationInputError,
        evaluate_folder,
        format_report,
        write_csv,
        write_json,
    )
    from toosicubix.formats import FormatError

    given = [(kind, path) for kind, path in (("kitti", kitti_dir), ("kitti-tracking", tracking_dir),
                                             ("cityscapes", cityscapes_dir)) if path is not None]
    if len(given) != 1:
        raise click.UsageError("give exactly one ground truth: --kitti DIR, --kitti-tracking DIR or --cityscapes DIR")
    gt_kind, gt_dir = given[0]
    class_list = tuple(c.strip() for c in classes.split(",") if c.strip()) if classes is not None else None
    if class_list is not None and not class_list:
        raise click.BadParameter("expected at least one class name", param_hint="--classes")
    try:
        result = evaluate_folder(out, gt_kind, gt_dir, EvalOptions(min_iou=min_iou, classes=class_list))
    except (EvaluationInputError, FormatError) as exc:
        raise BadInput(str(exc)) from None
    if not quiet:
        for warning in result.warnings:
            click.echo(f"warning: {warning}", err=True)
    click.echo(format_report(result), nl=False)
    try:
        if json_path is not None:
            write_json(result, json_path)
        if csv_path is not None:
            write_csv(result, csv_path)
    except OSError as exc:
        raise BadInput(f"cannot write {exc.filename}: {exc.strerror or exc}") from None
    if not quiet:
        written = [str(p) for p in (json_path, csv_path) if p is not None]
        if written:
            click.echo(f"wrote {' and '.join(written)}", err=True)
# --- end of eval -----------------------------------------------------------------------------------------

main.add_command(__import__("toosicubix.cli.annotate", fromlist=["annotate_command"]).annotate_command)

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
