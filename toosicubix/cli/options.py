"""What the commands share: exit codes, the input-error handling, option decorators declared once, a progress bar.

- :func:`ground_truth_options`: exactly one of ``--kitti``, ``--kitti-tracking``, ``--cityscapes``; the
  command receives ``ground_truth`` (a :class:`GroundTruth`).
- :func:`fitting_options`: priors, weights, settings file, click and part noise, ground cues, jobs; the
  command receives ``settings`` (a :class:`toosicubix.pipeline.settings.BatchSettings`).
- the options several commands share, declared once: :data:`priors_option`, :data:`click_sigma_option`,
  :data:`road_normal_option`, :data:`jobs_option`, :func:`out_option`.
- :class:`CommandGroup`: any :class:`toosicubix.errors.InputError` a command lets through is printed as
  ``Error: <message>`` and exits 2, so commands do not catch input errors themselves.
"""

from __future__ import annotations

import functools
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import click

from toosicubix.errors import InputError
from toosicubix.solver.fit import SolverOptions

EXIT_OK, EXIT_SOME_FAILED, EXIT_BAD_INPUT = 0, 1, 2


class Finite(click.FloatRange):
    """A number option within a range, and finite: click's own range passes ``nan`` (it fails no comparison) and,
    without a bound, ``inf``, which no setting means."""

    name = "float"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> float:
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number

    def _describe_range(self) -> str:
        """Without bounds there is no range to show (click's would print ``[x<=None]`` in ``--help``)."""
        return "" if self.min is None and self.max is None else super()._describe_range()


class BadInput(InputError, click.ClickException):
    """A bad input file or option value found by the CLI itself: printed as is, exit code 2."""

    exit_code = EXIT_BAD_INPUT

    def __init__(self, message: str):
        InputError.__init__(self, None, [(None, message)])
        click.ClickException.__init__(self, message)

    def show(self, file=None) -> None:
        click.echo(f"Error: {self.format_message()}", err=True)


class CommandGroup(click.Group):
    """A group whose commands' input errors exit 2 with their message (file and JSON path or line)."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except click.ClickException:
            raise
        except InputError as exc:
            raise BadInput(str(exc)) from None


def parse_classes(value: str | None) -> tuple[str, ...] | None:
    """``'Car, Van'`` -> ``('Car', 'Van')``; None stays None (the command's default classes)."""
    if value is None:
        return None
    classes = tuple(c.strip() for c in value.split(",") if c.strip())
    if not classes:
        raise click.BadParameter("expected at least one class name", param_hint="--classes")
    return classes


def parse_sequences(value: str | None) -> tuple[str, ...] | None:
    """'0010-0020' or '0001,0005,0007' -> sequence names; None stays None (all sequences)."""
    from toosicubix.formats.datasets import parse_sequences as parse

    try:
        return parse(value)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--sequences") from None


def float_list(value: str, name: str) -> tuple[float, ...]:
    """``'0.1,1,10'`` -> positive numbers, for the option ``name``."""
    try:
        values = tuple(float(v) for v in value.split(",") if v.strip())
    except ValueError:
        raise click.BadParameter(f"expected comma-separated numbers, got {value!r}", param_hint=name) from None
    if not values or min(values) <= 0:
        raise click.BadParameter(f"expected positive numbers, got {value!r}", param_hint=name)
    return values


# --- ground truth ------------------------------------------------------------------------------------------

#: Help of each ground-truth option (one layout per dataset, see toosicubix.formats.datasets).
GROUND_TRUTH_HELP = {
    "kitti": "KITTI object ground truth: a root with label_2/ and calib/ (eval and priors also take a folder of "
             "label .txt files, calib then looked for beside it). Example: --kitti data/kitti",
    "kitti-tracking": "KITTI tracking ground truth: a root with label_02/<seq>.txt and calib/<seq>.txt; image ids "
                      "are <seq>_<frame as 6 digits>. Example: --kitti-tracking data/kitti_tracking",
    "cityscapes": "Cityscapes 3D ground truth: a folder searched recursively for *_gtBbox3d.json; image id = file "
                  "stem without _gtBbox3d. Example: --cityscapes gtBbox3d/val",
    "apollocar3d": "ApolloCar3D ground truth: a keypoint file (COCO with a 6-DoF pose per car), its car models in "
                   "car_models.json beside it (eval: or --car-models); image id = file name stem. "
                   "Example: --apollocar3d apollo_val.json",
}
#: The ground truths that are folders (the commands that walk a dataset take only these by default).
FOLDER_GROUND_TRUTHS = ("kitti", "kitti-tracking", "cityscapes")


@dataclass(frozen=True)
class GroundTruth:
    """The one ground truth given: ``kind`` ('kitti', 'kitti-tracking', 'cityscapes', 'apollocar3d') and ``root``
    (a folder; ApolloCar3D's keypoint file)."""

    kind: str
    root: Path

    @property
    def flag(self) -> str:
        """The option that gave it, e.g. ``--kitti-tracking``."""
        return f"--{self.kind}"


def _parameter(kind: str) -> str:
    return f"ground_truth_{kind.replace('-', '_')}"


def ground_truth_options(*kinds: str, required: bool = True) -> Callable:
    """Add ``--kitti``, ``--kitti-tracking`` and ``--cityscapes`` (or only ``kinds``, e.g. ``apollocar3d`` too);
    exactly one must be given (at most one when not ``required``).

    The command receives ``ground_truth: GroundTruth`` (or None when none is given and none is required) instead
    of the options.
    """
    kinds = kinds or FOLDER_GROUND_TRUTHS
    flags = [f"--{kind} {'FILE' if kind == 'apollocar3d' else 'DIR'}" for kind in kinds]
    quantity = "exactly one" if required else "at most one"
    if len(flags) == 2:
        usage = f"give {quantity} of {flags[0]} and {flags[1]}"
    else:
        usage = f"give {quantity} ground truth: {', '.join(flags[:-1])} or {flags[-1]}"

    def decorate(command: Callable) -> Callable:
        @functools.wraps(command)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            given = [(kind, kwargs.pop(_parameter(kind))) for kind in kinds]
            given = [(kind, root) for kind, root in given if root is not None]
            if len(given) > 1 or (required and not given):
                raise click.UsageError(usage)
            return command(*args, ground_truth=GroundTruth(*given[0]) if given else None, **kwargs)

        for kind in reversed(kinds):
            wrapper = click.option(f"--{kind}", _parameter(kind), type=click.Path(path_type=Path), default=None,
                                   help=GROUND_TRUTH_HELP[kind])(wrapper)
        return wrapper

    return decorate


def car_models_option(command: Callable) -> Callable:
    """Add ``--car-models`` (ApolloCar3D's ``car_models.json``) to a command with ``--apollocar3d``; put it right
    below :func:`ground_truth_options`. The command receives ``car_models_path``, refused with another ground
    truth."""
    return _apollocar3d_file_option(
        command, "--car-models", "car_models_path",
        "With --apollocar3d: ApolloCar3D's car_models.json [default: beside the keypoint file].")


def apollocar3d_cameras_option(command: Callable) -> Callable:
    """Add ``--cameras`` (the cameras file of ApolloCar3D's images) to a command with ``--apollocar3d``, below
    :func:`ground_truth_options`. The command receives ``cameras_path``, refused with another ground truth."""
    return _apollocar3d_file_option(
        command, "--cameras", "cameras_path",
        "With --apollocar3d: the cameras of its images, in any form `toosicubix import` takes (our JSON, a KITTI calib "
        "file or folder, an OpenCV or ROS YAML), for how far each car's labelled keypoints lie from their rays at its "
        "ground-truth pose [default: cameras.json beside the keypoint file, if there is one].", dir_okay=True)


def _apollocar3d_file_option(command: Callable, flag: str, parameter: str, help_text: str,
                             dir_okay: bool = False) -> Callable:
    @functools.wraps(command)
    def wrapper(*args: Any, ground_truth: GroundTruth | None, **kwargs: Any) -> Any:
        if kwargs[parameter] is not None and (ground_truth is None or ground_truth.kind != "apollocar3d"):
            raise click.UsageError(f"{flag} goes with --apollocar3d only")
        return command(*args, ground_truth=ground_truth, **kwargs)

    return click.option(flag, parameter, type=click.Path(dir_okay=dir_okay, path_type=Path), default=None,
                        help=help_text)(wrapper)


def keypoint_mapping_option(help_text: str) -> Callable:
    """Add ``--mapping NAME|FILE`` (a bundled keypoint mapping or a mapping file, with keypoint parts) to a
    command; it receives ``mapping``, the loaded :class:`toosicubix.annotations.mapping.MappingFile` or None. A mapping
    that does not load, or has no keypoint parts, is bad input naming it (exit 2)."""

    def decorate(command: Callable) -> Callable:
        @functools.wraps(command)
        def wrapper(*args: Any, mapping_name: str | None, **kwargs: Any) -> Any:
            return command(*args, mapping=_keypoint_mapping(mapping_name), **kwargs)

        return click.option("--mapping", "mapping_name", default=None, metavar="NAME|FILE", help=help_text)(wrapper)

    return decorate


def _keypoint_mapping(name: str | None) -> Any:
    if name is None:
        return None
    from toosicubix.annotations.mapping import load_mapping
    from toosicubix.errors import InputFileError

    try:
        mapping, _ = load_mapping(name)
    except InputFileError as exc:
        raise BadInput(str(exc)) from None
    if not mapping.keypoint_positions(mapping.prototype):
        raise BadInput(f"--mapping {name}: the mapping {mapping.name} has no keypoint parts (its parts are the "
                       "vocabulary's own, which are suggested anyway)")
    return mapping


# --- options several commands share, declared once -----------------------------------------------------------

#: ``--priors FILE`` (fit, validate, tune, annotate, template): the command receives ``priors_path``.
priors_option = click.option(
    "--priors", "priors_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
    help="Size priors file (JSON, see docs/size-priors.md); default: the bundled KITTI and Cityscapes 3D table.")
#: ``--click-sigma PX`` (fit, validate, tune, annotate): the command receives ``click_sigma`` (None: estimate it).
click_sigma_option = click.option(
    "--click-sigma", type=Finite(min=0.0, min_open=True), default=None,
    help="Click noise in pixels the reported uncertainty (sigma, confidence, next clicks) and the keypoints' soft "
         "term are for. Estimated from the file's own residuals when not given, as `fit` does (a pilot fit of up to "
         f"400 vehicles; {SolverOptions.click_sigma:g} when their clicks are too few to tell).")
#: ``--road-normal x,y,z|estimate|none`` (fit, validate, tune, annotate): the command receives ``road_normal`` (the
#: text; :func:`road_normal_choice` reads it).
road_normal_option = click.option(
    "--road-normal", default=None, metavar="X,Y,Z|estimate|none",
    help="Road normal in camera coordinates, x,y,z (vehicles upright on it, e.g. the `road_normal` that `fit` "
         "estimated for this camera in results.json); 'estimate': per camera from a pilot fit of the file's vehicles "
         "(the default when no ground is given); 'none': no road, vehicles only within 45 deg of the camera's up. "
         "With other ground options and no normal: 0,-1,0.")
class Jobs(click.ParamType):
    """``--jobs``: a number of processes (at least 1) or ``auto`` (received as
    :data:`toosicubix.pipeline.workers.AUTO`)."""

    name = "N|auto"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> int:
        if isinstance(value, int):
            return value
        text = str(value).strip().lower()
        if text == "auto":
            from toosicubix.pipeline.workers import AUTO

            return AUTO
        try:
            jobs = int(text)
        except ValueError:
            jobs = 0
        if jobs < 1:
            self.fail(f"expected a number of processes (1 or more) or 'auto', got {value!r}", param, ctx)
        return jobs


#: ``-j/--jobs N|auto`` (fit, validate, tune): the command receives ``jobs`` (0 for auto).
jobs_option = click.option(
    "-j", "--jobs", type=Jobs(), default="auto", show_default=True,
    help="Worker processes; the output is the same for any number. auto: one per usable core, but at most one per "
         "100 vehicles where workers are forked (Linux up to Python 3.13) and per 1,000 where each starts afresh "
         "(macOS, Windows, Python 3.14), and at most 16; a small batch runs in one process.")


def out_option(help_text: str, parameter: str = "out", **kwargs: Any) -> Callable:
    """``-o/--out`` (every command that writes a file or a folder), received as ``parameter``."""
    return click.option("-o", "--out", parameter, help=help_text, **kwargs)


def road_normal_choice(value: str | None) -> tuple[str, tuple[float, float, float] | None]:
    """What ``--road-normal`` says: ``('estimate', None)`` (also when not given), ``('none', None)`` or
    ``('given', (x, y, z))``.

    Raises
    ------
    click.BadParameter
        Neither three numbers nor 'estimate' or 'none' (exit 2).
    """
    if value is None or value == "estimate":
        return "estimate", None
    if value == "none":
        return "none", None
    return "given", parse_normal(value, "three numbers x,y,z, 'estimate' or 'none'")


# --- fitting -----------------------------------------------------------------------------------------------

_FITTING_OPTIONS = [
    priors_option,
    click.option("--lambda", "lambda_3d", type=Finite(min=0.0, min_open=True),
                 default=SolverOptions.lambda_3d, show_default=True,
                 help="Weight of the size prior in the coordinate descent's 3D cost."),
    click.option("--lambda-p", "lambda_px", type=Finite(min=0.0, min_open=True),
                 default=SolverOptions.lambda_px, show_default=True,
                 help="Weight of the size prior in the pixel cost, in px^2 per squared Mahalanobis unit: the click "
                      "noise variance at which clicks and prior are weighed evenly. Smaller trusts the clicks more."),
    click.option("--config", "config_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
                 help="Settings file (as `toosicubix tune` writes it); options given on the command line win."),
    click_sigma_option,
    click.option("--part-sigma", type=Finite(min=0.0), default=SolverOptions.part_sigma, show_default=True,
                 help="How far real parts sit from where the cuboid model puts them (tyres inside the body, lights "
                      "set back, rounded corners), metres; the reported uncertainty includes it. 0: exactly on a box. "
                      "Keypoints and plates carry their learned spread instead. Not given (and no --click-sigma): a "
                      "batch of cuboid parts estimates it and the click noise from its own residuals."),
    click.option("--robust-loss", type=click.Choice(["auto", "cauchy", "none"]), default=SolverOptions.robust_loss,
                 show_default=True,
                 help="Cauchy loss on the clicks (down-weights mislabelled ones, listed per vehicle as `downweighted`);"
                      " auto: for vehicles with keypoint or plate clicks only (real clicks), the others as with none."),
    click.option("--upright-weight", type=click.Choice(["lambda", "clicks"]), default=SolverOptions.upright_weight,
                 show_default=True,
                 help="How a vehicle with keypoint or plate clicks weighs being upright on the road: lambda, like the "
                      "size prior (--lambda-p); clicks, as a prior of the stated lean against the click noise (the "
                      "upright sigma about an estimated road normal). Vehicles of cuboid parts: lambda either way "
                      "(benchmarks/decisions.md, rule 23)."),
    click.option("--misfit-level", type=Finite(min=0.5, max=1.0, min_open=True, max_open=True), default=None,
                 help="Test each fit's residuals against the click noise (chi-square at this level, e.g. 0.99): a "
                      "fit that fails is warned about ('misfit: ...', `residual_test` in results.json) and its sigmas "
                      "widen to what its residuals show. Off by default (benchmarks/decisions.md, rule 8)."),
    click.option("--kitti-ground", is_flag=True,
                 help="Give every image KITTI's ground: camera 1.65 +- 0.1 m above a road whose normal is -y +- 1 "
                      "deg, vehicles upright within 2 deg. The options below then change single fields."),
    click.option("--camera-height", type=Finite(min=0.0, min_open=True), default=None,
                 help="Camera height above the road, metres, for every image (enables the ground contact)."),
    click.option("--camera-height-sigma", type=Finite(min=0.0, min_open=True), default=None,
                 help="Its uncertainty, metres [default 0.05, KITTI 0.1]."),
    road_normal_option,
    click.option("--camera-pitch-deg", type=Finite(), default=None,
                 help="Instead of the normal: camera pitch, > 0 up."),
    click.option("--camera-roll-deg", type=Finite(), default=None, help="Instead of the normal: camera roll."),
    click.option("--normal-sigma-deg", type=Finite(min=0.0, min_open=True), default=None,
                 help="Uncertainty of the normal, degrees [default 1]."),
    click.option("--upright-sigma-deg", type=Finite(min=0.0, min_open=True), default=None,
                 help="How far vehicles lean from the road normal, degrees [default 2]."),
    click.option("--joint-ground", is_flag=True,
                 help="Refine each image's vehicles together with its ground plane (images with a ground block or "
                      "the options above); the camera height may then be unknown: the vehicles' sizes fix it."),
    click.option("--tracks", type=click.Choice(["on", "off"]), default="on", show_default=True,
                 help="on: vehicles that carry a 'track' are fitted with their track's other frames (one size per "
                      "track, a smooth motion; frames with a box only or nothing get a pose too, said in results.json "
                      "as pose_from box / interpolated); off: every frame alone (box-only and empty frames fail)."),
    click.option("--frame-rate", type=Finite(min=0.0, max=1000.0, min_open=True), default=10.0, show_default=True,
                 help="Frames per second of the sequences (frame numbers over it are the times the tracks' motion "
                      "model runs on; KITTI's 10)."),
    click.option("--box-cue", is_flag=True,
                 help="A vehicle fitted alone with a box2d takes the box as a cue too: the projected cuboid's extremes "
                      "touch its sides (sides on the image border left out). Tracked frames always do."),
    jobs_option,
]
_FITTING_NAMES = ("priors_path", "lambda_3d", "lambda_px", "config_path", "click_sigma", "part_sigma", "robust_loss",
                  "upright_weight", "misfit_level", "kitti_ground",
                  "camera_height", "camera_height_sigma", "road_normal", "camera_pitch_deg", "camera_roll_deg",
                  "normal_sigma_deg", "upright_sigma_deg", "joint_ground", "tracks", "frame_rate", "box_cue", "jobs")


def parse_normal(value: str, expected: str = "three numbers x,y,z") -> tuple[float, float, float]:
    """A road normal given as ``x,y,z`` (camera frame; its length is the ground block's to check: the schema
    refuses a zero one and normalises the rest).

    Raises
    ------
    click.BadParameter
        Not three numbers (exit 2 with ``expected`` in the message).
    """
    try:
        normal = tuple(float(v) for v in value.split(","))
    except ValueError:
        normal = ()
    if len(normal) != 3:
        raise click.BadParameter(f"expected {expected}, got {value!r}", param_hint="--road-normal")
    return normal  # type: ignore[return-value]


def announced_estimates(path: Path, priors: Any, options: SolverOptions, estimate_click_sigma: bool,
                        estimate_road_normal: bool, shown: Path | None = None, ground: Any = None,
                        estimate_part_sigma: bool | None = None) -> Any:
    """What `fit` would estimate from the vehicles of the annotation file ``path`` before fitting it (the pilot,
    :func:`toosicubix.pipeline.pilot.file_estimates`), saying on stderr what is estimated (from the file named
    ``shown``, default ``path``: annotate estimates from a snapshot of its file) and what was found; None, with a
    line saying so, when nothing is asked. For the commands that fit single vehicles as `fit` fits them (annotate,
    tune). ``estimate_part_sigma``: a batch of cuboid parts estimates how far its parts sit from the model with the
    click noise (rule 33); None: whenever the click noise is estimated (the commands without ``--part-sigma``)."""
    from toosicubix.pipeline.pilot import file_estimates

    wanted = [what for what, asked in (("the click noise", estimate_click_sigma),
                                       ("road normals", estimate_road_normal)) if asked]
    if not wanted:
        click.echo(f"click noise: {options.click_sigma:g} px (given); no road normal estimated", err=True)
        return None
    click.echo(f"estimating {' and '.join(wanted)} from the vehicles of {shown or path}, as `fit` does ...", err=True)
    findings = file_estimates(path, priors, options, estimate_click_sigma, estimate_road_normal, ground=ground,
                              estimate_part_sigma=estimate_click_sigma if estimate_part_sigma is None
                              else estimate_part_sigma)
    for line in findings.describe():
        click.echo(line, err=True)
    return findings


def _settings(values: dict[str, Any]) -> Any:
    """The :class:`~toosicubix.pipeline.settings.BatchSettings` the fitting options amount to (without next clicks
    and keypoints, which each command sets)."""
    from toosicubix.annotations.priors_file import load_priors
    from toosicubix.pipeline.settings import BatchSettings, ground_overrides, solver_options

    ctx = click.get_current_context()
    explicit = {k: values[k] for k in ("lambda_3d", "lambda_px")
                if ctx.get_parameter_source(k) is not click.core.ParameterSource.DEFAULT}
    given_sigma = values["click_sigma"]
    options = replace(solver_options(values["config_path"], **explicit),
                      click_sigma=SolverOptions.click_sigma if given_sigma is None else given_sigma,
                      part_sigma=values["part_sigma"], robust_loss=values["robust_loss"],
                      upright_weight=values["upright_weight"], misfit_level=values["misfit_level"])
    road, normal = road_normal_choice(values["road_normal"])
    given = {k: values[k] for k in ("camera_height", "camera_height_sigma", "camera_pitch_deg", "camera_roll_deg",
                                    "normal_sigma_deg", "upright_sigma_deg")}
    if (given["camera_pitch_deg"] is not None or given["camera_roll_deg"] is not None) and normal is not None:
        raise click.UsageError("give --road-normal or --camera-pitch-deg/--camera-roll-deg, not both")
    ground = ground_overrides(values["kitti_ground"], normal, **given)
    if values["road_normal"] == "estimate" and (ground or values["joint_ground"]):
        raise click.UsageError("--road-normal estimate goes without other ground options and --joint-ground "
                               "(they say what the road is); give the normal as x,y,z instead")
    if ground is not None:
        from toosicubix.annotations.convert import ground_with

        ground_with(None, ground)  # a zero normal or an impossible block: refused here, naming the options
    estimate = road == "estimate" and not ground and not values["joint_ground"]
    from toosicubix.solver.track import TrackOptions

    return BatchSettings(priors=load_priors(values["priors_path"]), options=options, ground=ground,
                         joint_ground=values["joint_ground"], jobs=values["jobs"],
                         estimate_click_sigma=given_sigma is None, estimate_road_normal=estimate,
                         estimate_part_sigma=given_sigma is None and ctx.get_parameter_source(
                             "part_sigma") is click.core.ParameterSource.DEFAULT,
                         tracks=values["tracks"] == "on", track_options=TrackOptions(frame_rate=values["frame_rate"]),
                         box_cue=values["box_cue"])


def fitting_options(command: Callable) -> Callable:
    """Add the options ``fit`` and ``validate`` share; the command receives ``settings`` (a
    :class:`~toosicubix.pipeline.settings.BatchSettings`, without next clicks and keypoints) instead."""

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        values = {name: kwargs.pop(name) for name in _FITTING_NAMES}
        return command(*args, settings=_settings(values), **kwargs)

    for option in reversed(_FITTING_OPTIONS):
        wrapper = option(wrapper)
    return wrapper


class ProgressBar:
    """A progress bar on stderr for batches of more than a few items (vehicles fitted, images rendered)."""

    MIN_ITEMS = 50

    def __init__(self, quiet: bool, label: str = "fitting"):
        self.quiet = quiet
        self.label = label
        self.bar = None

    def start(self, total: int) -> None:
        if not self.quiet and total >= self.MIN_ITEMS:
            self.bar = click.progressbar(length=total, label=self.label, file=sys.stderr, show_eta=True)
            self.bar.__enter__()

    def update(self, n: int) -> None:
        if self.bar is not None:
            self.bar.update(n)

    def finish(self) -> None:
        if self.bar is not None:
            self.bar.__exit__(None, None, None)
            self.bar = None


__all__ = [
    "EXIT_BAD_INPUT", "EXIT_OK", "EXIT_SOME_FAILED", "GROUND_TRUTH_HELP", "BadInput", "CommandGroup", "GroundTruth",
    "ProgressBar", "click_sigma_option", "fitting_options", "float_list", "ground_truth_options", "jobs_option",
    "out_option", "parse_classes", "parse_sequences", "priors_option", "road_normal_choice", "road_normal_option",
]
