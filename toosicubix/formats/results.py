"""``results.json``: what ``toosicubix fit`` found for every vehicle, with full rotations.

Layout (keys may be added; these keep their names and meanings)::

    {"toosicubix_results": 1, "generator": "toosicubix 0.1.0", "annotations": "...", "settings": {...},
     "images": [{"id": "000123", "camera": {"K": [[...]], "t_cam_rect": [...], "image_size": [w, h]},
                 "vehicles": [{"id": "3", "status": "ok", "error": null, "prototype": "Car",
                               "R_cam_vehicle": [[...]], "t_cam_vehicle": [...], "dimensions": [...], ...}]}],
     "summary": {...}}

``t_cam_vehicle`` is in the frame where the image's ``K`` applies; ``X_rect = X_cam - t_cam_rect``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import IO, Any

import numpy as np

from toosicubix import fields as field_rules
from toosicubix.annotations.schema import MAX_CAMERA_OFFSET, check_intrinsics
from toosicubix.errors import FormatError
from toosicubix.fields import shown
from toosicubix.formats.json_text import dumps_indented
from toosicubix.jsonfile import json_field, json_numbers, read_json
from toosicubix.solver.fit import Alternative
from toosicubix.solver.misfit import ResidualTest  # the solver's type: results.json's ``residual_test``
from toosicubix.solver.uncertainty import (  # the solver's types: results.json's ``sigma`` and ``observability``
    Observability,
    Uncertainty,
)

RESULTS_VERSION = 1
RESULTS_FILENAME = "results.json"
#: Where ``fit`` writes and ``eval`` reads when no folder is given (relative to the working directory).
DEFAULT_OUTPUT_DIR = "toosicubix-out"


@dataclass(frozen=True)
class Cues:
    """What besides the clicks shaped a fit (results.json's ``cues``).

    Attributes
    ----------
    size_prior : always; upright : the road's normal was known; ground_contact : the camera height was known
    known_sizes : the measurements' labels ('length plate-rear', 'known dx', ...)
    joint_ground : refined together with the image's other vehicles and its ground plane (None: not)
    """

    size_prior: bool
    upright: bool
    ground_contact: bool
    known_sizes: tuple[str, ...]
    joint_ground: bool | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"size_prior": self.size_prior, "upright": self.upright,
                               "ground_contact": self.ground_contact, "known_sizes": list(self.known_sizes)}
        if self.joint_ground is not None:
            out["joint_ground"] = self.joint_ground
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Cues:
        return cls(d["size_prior"], d["upright"], d["ground_contact"], tuple(d["known_sizes"]), d.get("joint_ground"))


@dataclass(frozen=True)
class SolverStats:
    """How the solver got there (results.json's ``solver``)."""

    starts: int
    starts_from_lines: bool
    descent_iterations: int
    refine_iterations: int
    initial_cost: float | None
    joint_iterations: int | None = None
    residual_dof: float | None = None  # the pixel residuals' effective degrees of freedom (click-noise estimate)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"starts": self.starts, "starts_from_lines": self.starts_from_lines,
                               "descent_iterations": self.descent_iterations,
                               "refine_iterations": self.refine_iterations, "initial_cost": self.initial_cost}
        if self.joint_iterations is not None:
            out["joint_iterations"] = self.joint_iterations
        if self.residual_dof is not None:
            out["residual_dof"] = self.residual_dof
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> SolverStats:
        return cls(d["starts"], d["starts_from_lines"], d["descent_iterations"], d["refine_iterations"],
                   d["initial_cost"], d.get("joint_iterations"), d.get("residual_dof"))


@dataclass(frozen=True)
class VehicleResult:
    """One vehicle's fit, as results.json has it. Pose fields are None when ``status == "failed"``; the fields
    from ``box2d_source`` to ``warnings`` are set only for a vehicle that was fitted.

    Attributes
    ----------
    R_cam_vehicle : (3, 3) or None
    t_cam_vehicle : (3,) or None, bottom-face centre in the camera frame of ``K``
    dimensions : (3,) or None, ``(dx, dy, dz)`` metres
    box2d : (4,) or None, ``(x1, y1, x2, y2)`` pixels
    kitti_type : the type its KITTI label gets
    constraints, clicks, aux_unknowns : 2 per click minus the auxiliary unknowns; clicked points; those unknowns
    cues : what besides the clicks shaped it
    box2d_source : 'annotated' or 'projected'; truncated : share of the projected box outside the image
    yaw_pitch_roll_deg : (3,) KITTI yaw, pitch, roll
    rms_px, residuals_px : (N, 2) projected minus clicked, undistorted pixels; click_labels : (N,)
    click_weights : (N,) each click's weight in the pixel cost (keypoints' soft term times the robust loss's
        factor), or None when every click weighs 1 (written only when set)
    downweighted : the labels of the clicks the robust loss down-weighted (written only when any)
    cost : final pixel cost; prior_mahalanobis2 : the size prior's squared Mahalanobis distance
    parameters : the wheel positions and other auxiliary unknowns by name, metres
    scale_from, scale_shares : the cue that sets the scale, and every cue's share of it
    sigma, confidence, observability, ambiguous, alternatives : how sure the fit is (docs/uncertainty.md)
    residual_test : the chi-square test of its residuals (:mod:`toosicubix.solver.misfit`; a misfit's sigmas are
        widened), or None when its clicks were not redundant enough (written only when set)
    warnings : what the solver warned about; solver : its statistics
    next_clicks : the best parts to click next (as :meth:`toosicubix.solver.guidance.Suggestion.to_json`
        gives them), or None when not asked for; next_clicks_error : why there are none
    reachable_sigma : the sigmas with every visible part inside the image clicked too
        (:attr:`toosicubix.solver.guidance.Guidance.reachable`): what clicks can reach at this distance; set with
        ``next_clicks`` (written only when set)
    error, error_detail : for a failed vehicle, why in plain words (what to click or add) and the technical
        account for experts (the unknowns involved, the numbers; written only when set)
    extra : keys of the JSON object this type does not know (kept, written last)
    track : the track it is a frame of (annotation file's ``track``), or None
    implausible : why its pose is one no person could have clicked (tilted, clicked parts on faces turned away:
        :mod:`toosicubix.solver.plausibility`), when no plausible pose fits its clicks; its confidence is then at most
        0.2 and a warning names the likely cause; None (not written) for a plausible fit
    pose_from : for a tracked vehicle, what determined its pose in this frame: 'clicks' (clicked here), 'box' (only
        its 2D box here, and the track's other frames), 'interpolated' (nothing here: the track's motion between
        its other frames); None for a vehicle fitted alone
    heading : how its yaw is determined when not by a front (:data:`toosicubix.vocabulary.HEADINGS`): 'none' (a
        traffic cone: rotationally symmetric, the yaw in its pose is a convention and its KITTI angles are written as
        -10) or 'axial' (a barrier: known modulo 180 degrees); None (not written) for everything with a front
    """

    id: str
    status: str
    error: str | None
    prototype: str
    R_cam_vehicle: np.ndarray | None = None
    t_cam_vehicle: np.ndarray | None = None
    dimensions: np.ndarray | None = None
    box2d: np.ndarray | None = None
    kitti_type: str | None = None
    constraints: int | None = None
    clicks: int | None = None
    aux_unknowns: int | None = None
    cues: Cues | None = None
    box2d_source: str | None = None
    truncated: float | None = None
    yaw_pitch_roll_deg: tuple[float, float, float] | None = None
    rms_px: float | None = None
    residuals_px: np.ndarray | None = None
    click_labels: tuple[str, ...] = ()
    click_weights: np.ndarray | None = None
    downweighted: tuple[str, ...] = ()
    cost: float | None = None
    prior_mahalanobis2: float | None = None
    parameters: dict[str, float] = field(default_factory=dict)
    scale_from: str | None = None
    scale_shares: dict[str, float] = field(default_factory=dict)
    sigma: Uncertainty | None = None
    confidence: float | None = None
    observability: Observability | None = None
    ambiguous: bool = False
    alternatives: tuple[Alternative, ...] = ()
    residual_test: ResidualTest | None = None
    warnings: tuple[str, ...] = ()
    solver: SolverStats | None = None
    next_clicks: list[dict[str, Any]] | None = None
    next_clicks_error: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    track: str | None = None
    pose_from: str | None = None
    implausible: str | None = None
    error_detail: str | None = None
    reachable_sigma: Uncertainty | None = None
    heading: str | None = None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def summary(self) -> VehicleResult:
        """The vehicle as a batch's writer reads it once its results.json entry and KITTI label lines are written
        (:class:`RenderedImage`): its status and reason, prototype and KITTI type, confidence, track and pose source,
        implausibility, warnings, scale source and residual test; no pose, residuals, sigmas or diagnostics."""
        return VehicleResult(id=self.id, status=self.status, error=self.error, prototype=self.prototype,
                             kitti_type=self.kitti_type, confidence=self.confidence, track=self.track,
                             pose_from=self.pose_from, implausible=self.implausible, warnings=self.warnings,
                             scale_from=self.scale_from, residual_test=self.residual_test)

    def to_json(self) -> dict[str, Any]:
        """The JSON object of one vehicle, keys in results.json's order."""
        out: dict[str, Any] = {
            "id": self.id, "status": self.status, "error": self.error,
            **({"error_detail": self.error_detail} if self.error_detail is not None else {}),
            "prototype": self.prototype,
            **({"track": self.track} if self.track is not None else {}),
            **({"pose_from": self.pose_from} if self.pose_from is not None else {}),
            "R_cam_vehicle": _array(self.R_cam_vehicle), "t_cam_vehicle": _array(self.t_cam_vehicle),
            "dimensions": _array(self.dimensions), "box2d": _array(self.box2d),
        }
        for key in ("kitti_type", "constraints", "clicks", "aux_unknowns"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.cues is not None:
            out["cues"] = self.cues.to_json()
        if self.ok:
            out.update({
                "box2d_source": self.box2d_source, "truncated": self.truncated,
                "yaw_pitch_roll_deg": None if self.yaw_pitch_roll_deg is None else list(self.yaw_pitch_roll_deg),
                **({"heading": self.heading} if self.heading is not None else {}),
                "rms_px": self.rms_px, "residuals_px": _array(self.residuals_px),
                "click_labels": list(self.click_labels), "cost": self.cost,
                "prior_mahalanobis2": self.prior_mahalanobis2, "parameters": dict(self.parameters),
                "scale_from": self.scale_from, "scale_shares": dict(self.scale_shares),
                "sigma": None if self.sigma is None else self.sigma.to_json(), "confidence": self.confidence,
                "observability": None if self.observability is None else self.observability.to_json(),
                "ambiguous": self.ambiguous, "alternatives": [a.to_json() for a in self.alternatives],
                "warnings": list(self.warnings),
            })
            if self.implausible is not None:
                out["implausible"] = self.implausible
            if self.click_weights is not None:
                out["click_weights"] = _array(self.click_weights)
            if self.downweighted:
                out["downweighted"] = list(self.downweighted)
            if self.residual_test is not None:
                out["residual_test"] = self.residual_test.to_json()
        if self.solver is not None:
            out["solver"] = self.solver.to_json()
        if self.next_clicks is not None:
            out["next_clicks"] = list(self.next_clicks)
        if self.next_clicks_error is not None:
            out["next_clicks_error"] = self.next_clicks_error
        if self.reachable_sigma is not None:
            out["reachable_sigma"] = self.reachable_sigma.to_json()
        out.update(self.extra)
        return out

    @classmethod
    def from_json(cls, v: dict[str, Any], path: str | Path = "<results>", where: str = "$") -> VehicleResult:
        """Read one vehicle's JSON object (``where`` its JSON path, for the messages).

        Raises
        ------
        FormatError
            A required key missing or malformed (the message gives its JSON path).
        """
        status = json_field(v, "status", str, path, where)
        posed = status == "ok"
        _check_fields(v, path, where)

        def get(key: str, convert: Any = None) -> Any:
            value = v.get(key)
            return value if value is None or convert is None else convert(value)

        try:
            return cls(
                id=str(json_field(v, "id", str, path, where)), status=status, error=v.get("error"),
                error_detail=v["error_detail"] if isinstance(v.get("error_detail"), str) else None,
                prototype=str(v.get("prototype", "")),
                track=v["track"] if isinstance(v.get("track"), str) else None,
                pose_from=v["pose_from"] if isinstance(v.get("pose_from"), str) else None,
                implausible=v["implausible"] if isinstance(v.get("implausible"), str) else None,
                heading=v["heading"] if isinstance(v.get("heading"), str) else None,
                R_cam_vehicle=json_numbers(v.get("R_cam_vehicle"), (3, 3), path, f"{where}.R_cam_vehicle")
                if posed else None,
                t_cam_vehicle=json_numbers(v.get("t_cam_vehicle"), (3,), path, f"{where}.t_cam_vehicle")
                if posed else None,
                dimensions=json_numbers(v.get("dimensions"), (3,), path, f"{where}.dimensions") if posed else None,
                box2d=json_numbers(v["box2d"], (4,), path, f"{where}.box2d") if v.get("box2d") is not None else None,
                kitti_type=v.get("kitti_type"), constraints=v.get("constraints"), clicks=v.get("clicks"),
                aux_unknowns=v.get("aux_unknowns"), cues=get("cues", Cues.from_json),
                box2d_source=v.get("box2d_source"), truncated=v.get("truncated"),
                yaw_pitch_roll_deg=get("yaw_pitch_roll_deg", tuple), rms_px=v.get("rms_px"),
                residuals_px=get("residuals_px", lambda r: np.array(r, dtype=float).reshape(-1, 2)),
                click_labels=tuple(v.get("click_labels") or ()),
                click_weights=get("click_weights", lambda w: np.array(w, dtype=float).reshape(-1)),
                downweighted=tuple(str(label) for label in v.get("downweighted") or ()), cost=v.get("cost"),
                prior_mahalanobis2=v.get("prior_mahalanobis2"), parameters=dict(v.get("parameters") or {}),
                scale_from=v.get("scale_from"), scale_shares=dict(v.get("scale_shares") or {}),
                sigma=get("sigma", Uncertainty.from_json), confidence=v.get("confidence"),
                reachable_sigma=get("reachable_sigma", Uncertainty.from_json),
                observability=get("observability", Observability.from_json), ambiguous=bool(v.get("ambiguous")),
                alternatives=tuple(Alternative.from_json(a) for a in v.get("alternatives") or ()),
                residual_test=get("residual_test", ResidualTest.from_json),
                warnings=tuple(v.get("warnings") or ()), solver=get("solver", SolverStats.from_json),
                next_clicks=get("next_clicks", list), next_clicks_error=v.get("next_clicks_error"),
                extra={k: val for k, val in v.items() if k not in _KNOWN_KEYS},
            )
        except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as exc:
            if isinstance(exc, FormatError):
                raise
            raise FormatError(path, f"{where}: malformed vehicle result ({type(exc).__name__}: "
                                    f"{shown(str(exc), 120)})") from None


_KNOWN_KEYS = {f.name for f in fields(VehicleResult)} - {"extra"}

#: The largest distance of a fitted vehicle from the camera, metres: 1,000 km, far beyond any fit of clicks (a
#: vehicle 30 px long at a focal length of 10^6 px is 100 km away), short of what turns a projection infinite.
MAX_RESULT_DISTANCE_M = 1e6
#: The largest fitted dimension, metres (the size priors' vehicles are under 30 m).
MAX_RESULT_SIZE_M = 1e3
#: How far a fitted rotation may be from orthonormal (``|R^T R - I|``, largest entry): fit writes them to 1e-12.
ROTATION_TOLERANCE = 1e-6

#: The optional keys of a vehicle result read by type (what readers of results.json use): strings, numbers (finite),
#: integers, lists of strings, and sigma blocks (results.json's ``sigma``: numbers >= 0, null for infinite).
_TEXT_KEYS = ("error", "error_detail", "prototype", "kitti_type", "box2d_source", "scale_from", "next_clicks_error",
              "track", "pose_from", "implausible")
_NUMBER_KEYS = ("confidence", "rms_px", "truncated", "cost", "prior_mahalanobis2")
_INTEGER_KEYS = ("constraints", "clicks", "aux_unknowns")
_TEXT_LIST_KEYS = ("click_labels", "downweighted", "warnings")
_SIGMA_KEYS = ("sigma", "reachable_sigma")


def _check_fields(v: dict[str, Any], path: str | Path, where: str) -> None:
    """The types and ranges of a vehicle result's keys, before any is used (:mod:`toosicubix.fields`): a results file
    that fit did not write (or that was edited) is refused naming the JSON path, not met by a traceback or written on
    as a NaN.

    Raises
    ------
    FormatError
        Naming the JSON path and what was expected.
    """
    for key in ("id", "status"):  # written into files and XML: the id rule (no control characters, no surrogates)
        field_rules.identifier(v.get(key), path, f"{where}.{key}", what=f"a vehicle {key}")
        if not isinstance(v[key], str):
            raise FormatError(path, f"{where}.{key}: expected a string, got {shown(v[key])}")
    for key in _TEXT_KEYS:
        if v.get(key) is not None and not (isinstance(v[key], str) and _encodable(v[key])):
            raise FormatError(path, f"{where}.{key}: expected a string (of text UTF-8 can write) or null, got "
                                    f"{shown(v[key])}")
    for key in _NUMBER_KEYS:
        if v.get(key) is not None:
            field_rules.number(v[key], path, f"{where}.{key}", what="a finite number or null")
    for key in _INTEGER_KEYS:
        if v.get(key) is not None:
            field_rules.integer(v[key], path, f"{where}.{key}", low=0, high=10**9, integral_floats=False,
                                what="a count or null")
    for key in _TEXT_LIST_KEYS:
        items = v.get(key)
        if items is not None and not (isinstance(items, list) and all(isinstance(item, str) for item in items)):
            raise FormatError(path, f"{where}.{key}: expected a list of strings, got {shown(items)}")
    for key in _SIGMA_KEYS:
        if v.get(key) is not None:
            _check_sigma(v[key], path, f"{where}.{key}")
    for key, shape in (("residuals_px", (-1, 2)), ("click_weights", (-1,)), ("yaw_pitch_roll_deg", (3,))):
        if v.get(key) is not None:
            _check_numbers(v[key], shape, path, f"{where}.{key}")
    for key in ("parameters", "scale_shares"):
        value = v.get(key)
        if value is not None and not (isinstance(value, dict)
                                      and all(field_rules.passes(field_rules.number, x) for x in value.values())):
            raise FormatError(path, f"{where}.{key}: expected an object of finite numbers, got {shown(value)}")
    if v.get("status") == "ok":
        _check_pose(v, path, where)


def _encodable(text: str) -> bool:
    """Whether UTF-8 can write ``text`` (JSON's escapes let a file hold unpaired surrogates, which it cannot)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _check_numbers(value: Any, shape: tuple[int, ...], path: str | Path, where: str) -> np.ndarray:
    """``value`` as finite numbers of ``shape`` (-1: any length)."""
    flat = value if isinstance(value, list) else None
    if flat is not None and len(shape) == 2:
        flat = [x for row in value for x in row] if all(isinstance(row, list) and len(row) == shape[1]
                                                       for row in value) else None
    if flat is None or not all(field_rules.passes(field_rules.number, x) for x in flat) \
            or (shape[0] >= 0 and len(value) != shape[0]):
        what = "finite numbers" + (f" of shape {shape}" if shape[0] >= 0 else f", {shape[-1]} per row"
                                   if len(shape) == 2 else "")
        raise FormatError(path, f"{where}: expected {what}, got {shown(value)}")
    return np.array(flat, dtype=float)


def _check_sigma(value: Any, path: str | Path, where: str) -> None:
    """A sigma block: its scalars and vectors numbers >= 0 or null (infinite)."""
    if not isinstance(value, dict):
        raise FormatError(path, f"{where}: expected an object of sigmas, got {shown(value)}")
    for key, item in value.items():
        for k, x in enumerate(item if isinstance(item, list) else [item]):
            if x is None:
                continue
            place = f"{where}.{key}" + (f"[{k}]" if isinstance(item, list) else "")
            field_rules.number(x, path, place, low=0.0, what="a sigma (or null for infinite): a number")


def _check_pose(v: dict[str, Any], path: str | Path, where: str) -> None:
    """A fitted pose: ``R_cam_vehicle`` a rotation (orthonormal, determinant +1), ``t_cam_vehicle`` within
    :data:`MAX_RESULT_DISTANCE_M`, ``dimensions`` positive and within :data:`MAX_RESULT_SIZE_M`."""
    R = json_numbers(v.get("R_cam_vehicle"), (3, 3), path, f"{where}.R_cam_vehicle")
    R_bounded = np.clip(R, -2.0, 2.0)  # a rotation's entries are within +-1: larger ones fail, without overflow
    error = float(np.abs(R_bounded.T @ R_bounded - np.eye(3)).max())
    if not (error <= ROTATION_TOLERANCE and np.abs(R).max() <= 1.0 + ROTATION_TOLERANCE and np.linalg.det(R) > 0):
        raise FormatError(path, f"{where}.R_cam_vehicle: expected a rotation matrix (orthonormal to "
                                f"{ROTATION_TOLERANCE:g}, determinant +1), got determinant "
                                f"{np.linalg.det(R_bounded):.3g} and |R^T R - I| = {error:.3g}")
    t = json_numbers(v.get("t_cam_vehicle"), (3,), path, f"{where}.t_cam_vehicle")
    if np.abs(t).max() > MAX_RESULT_DISTANCE_M:
        raise FormatError(path, f"{where}.t_cam_vehicle: expected a position within {MAX_RESULT_DISTANCE_M:g} m of the "
                                f"camera, got {t.tolist()}")
    d = json_numbers(v.get("dimensions"), (3,), path, f"{where}.dimensions")
    if not (d.min() > 0 and d.max() <= MAX_RESULT_SIZE_M):
        raise FormatError(path, f"{where}.dimensions: expected three sizes greater than 0 and at most "
                                f"{MAX_RESULT_SIZE_M:g} m, got {d.tolist()}")


@dataclass(frozen=True)
class RoadPlane:
    """The road plane an image's fits stood on (results.json's per-image ``ground``).

    Attributes
    ----------
    normal : (3,) unit normal in the camera frame, pointing up
    camera_height : metres above the road, or None when unknown
    estimated : refined with the vehicles (``--joint-ground``) or the batch's road normal, not given
    joint_iterations, vehicles : of the joint refinement (``--joint-ground``), else None
    joint_error : why the joint refinement failed (the vehicles keep their own fits), else None
    """

    normal: tuple[float, float, float]
    camera_height: float | None
    estimated: bool
    joint_iterations: int | None = None
    vehicles: int | None = None
    joint_error: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "normal", tuple(float(v) for v in self.normal))

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"normal": list(self.normal), "camera_height": self.camera_height,
                               "estimated": self.estimated}
        if self.joint_iterations is not None:
            out.update(joint_iterations=self.joint_iterations, vehicles=self.vehicles)
        if self.joint_error is not None:
            out["joint_error"] = self.joint_error
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> RoadPlane:
        return cls(normal=tuple(d["normal"]), camera_height=d.get("camera_height"), estimated=bool(d.get("estimated")),
                   joint_iterations=d.get("joint_iterations"), vehicles=d.get("vehicles"),
                   joint_error=d.get("joint_error"))


@dataclass(frozen=True)
class ImageResult:
    """One image's fits and the camera they are expressed in.

    Attributes
    ----------
    K : (3, 3)
    t_cam_rect : (3,) zero unless the camera came from a KITTI ``P``
    image_size : (width, height) or None
    ground : the road plane used or estimated, or None
    sequence, frame : the video the image is a frame of and its frame number, or None
    """

    id: str
    K: np.ndarray
    t_cam_rect: np.ndarray
    image_size: tuple[int, int] | None
    vehicles: list[VehicleResult]
    ground: RoadPlane | None = None
    sequence: str | None = None
    frame: int | None = None


@dataclass(frozen=True)
class RenderedImage(ImageResult):
    """An image's results written by the worker process that fitted it: its results.json entry (``text``, as
    :func:`image_text` writes it) and its KITTI label lines (``label_lines``, those of its successful fits in order:
    :func:`toosicubix.pipeline.labels.kitti_lines`), its vehicles only as their summaries
    (:meth:`VehicleResult.summary`). The main process of ``fit --jobs N`` then copies the text and lines instead of
    taking back every vehicle's numbers and encoding them itself, and so keeps up with more workers. A changed copy
    would keep the old text, so nothing changes a rendered image: the workers' results go straight to the writer
    (:func:`toosicubix.pipeline.fitting.iter_fit_file`)."""

    text: str = ""
    label_lines: tuple[str, ...] | None = None

    @classmethod
    def of(cls, im: ImageResult, label_lines: list[str] | tuple[str, ...]) -> RenderedImage:
        """``im`` with its entry written, its label lines ``label_lines``, and its vehicles summarized."""
        kept = {f.name: getattr(im, f.name) for f in fields(ImageResult) if f.name != "vehicles"}
        return cls(**kept, vehicles=[v.summary() for v in im.vehicles], text=image_text(im),
                   label_lines=tuple(label_lines))


def image_text(im: ImageResult) -> str:
    """The results.json entry of an image, ``json.dumps(image_to_json(im), indent=1, allow_nan=False)`` (before it
    is indented to its place): a rendered image's own text, else encoded now.

    Raises
    ------
    ValueError
        A NaN or an infinity (not JSON).
    """
    return im.text if isinstance(im, RenderedImage) else dumps_indented(image_to_json(im))


def _array(value: np.ndarray | None) -> Any:
    return None if value is None else np.asarray(value, dtype=float).tolist()


def vehicle_to_json(v: VehicleResult) -> dict[str, Any]:
    """The JSON object of one vehicle, fixed keys first (:meth:`VehicleResult.to_json`)."""
    return v.to_json()


def image_to_json(im: ImageResult) -> dict[str, Any]:
    """The JSON object of one image."""
    return {
        "id": im.id,
        **({"sequence": im.sequence, "frame": im.frame} if im.sequence is not None else {}),
        "camera": {"K": _array(im.K), "t_cam_rect": _array(im.t_cam_rect),
                   "image_size": list(im.image_size) if im.image_size else None},
        **({"ground": im.ground.to_json()} if im.ground is not None else {}),
        "vehicles": [vehicle_to_json(v) for v in im.vehicles],
    }


def results_to_json(images: list[ImageResult], header: dict[str, Any] | None = None) -> dict[str, Any]:
    """The whole document: ``header`` keys, then ``images`` and a ``summary`` of counts."""
    n_ok = sum(v.ok for im in images for v in im.vehicles)
    n_all = sum(len(im.vehicles) for im in images)
    doc: dict[str, Any] = {"toosicubix_results": RESULTS_VERSION, **(header or {})}
    doc["images"] = [image_to_json(im) for im in images]
    doc["summary"] = {"images": len(images), "vehicles": n_all, "ok": n_ok, "failed": n_all - n_ok}
    return doc


def write_results_stream(handle: IO[str], images: Iterable[ImageResult], header: dict[str, Any] | None = None,
                         on_image: Callable[[ImageResult], None] | None = None,
                         trailer: Callable[[], dict[str, Any]] | None = None) -> dict[str, int]:
    """Write the document of :func:`results_to_json` to ``handle`` one image at a time, byte for byte as
    :func:`dumps` would (so a batch never holds every image's results); return its summary.
    ``on_image`` is called with each image after it is written; ``trailer`` then gives keys written after the
    images, before the summary (what is known only once every image is: the track ids).

    Raises
    ------
    ValueError
        A NaN or an infinity (not JSON); what was written is then incomplete.
    """
    head = json.dumps({"toosicubix_results": RESULTS_VERSION, **(header or {})}, indent=1, allow_nan=False)
    handle.write(head[:-2] + ',\n "images": [')
    summary = {"images": 0, "vehicles": 0, "ok": 0, "failed": 0}
    for im in images:
        text = image_text(im)  # json.dumps(..., indent=1, allow_nan=False); no raw newline
        handle.write(("\n  " if summary["images"] == 0 else ",\n  ") + text.replace("\n", "\n  "))
        summary["images"] += 1
        summary["vehicles"] += len(im.vehicles)
        summary["ok"] += sum(v.ok for v in im.vehicles)
        if on_image is not None:
            on_image(im)
    summary["failed"] = summary["vehicles"] - summary["ok"]
    handle.write("\n ]" if summary["images"] else "]")
    for key, value in (trailer() if trailer is not None else {}).items():
        handle.write(f',\n {json.dumps(key)}: ' + json.dumps(value, indent=1, allow_nan=False).replace("\n", "\n "))
    handle.write(',\n "summary": ' + json.dumps(summary, indent=1).replace("\n", "\n ") + "\n}\n")
    return summary


def dumps(doc: dict[str, Any]) -> str:
    """JSON text with NaN and infinities refused (they are not JSON).

    Raises
    ------
    ValueError
        Naming the JSON path of the first NaN or infinity.
    """
    bad = non_finite_path(doc)
    if bad is not None:
        raise ValueError(f"refusing to write a NaN or infinity (not JSON) at {bad}")
    return dumps_indented(doc) + "\n"


def non_finite_path(value: Any, path: str = "$") -> str | None:
    """The JSON path of the first NaN or infinity in nested dicts, lists and arrays, else None."""
    if isinstance(value, float | np.floating):
        return None if np.isfinite(value) else path
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "fc" or np.all(np.isfinite(value)):
            return None
        return f"{path}{[int(i) for i in np.argwhere(~np.isfinite(value))[0]]}"
    if isinstance(value, dict):
        items: Any = ((f"{path}.{k}", v) for k, v in value.items())
    elif isinstance(value, list | tuple):
        items = ((f"{path}[{i}]", v) for i, v in enumerate(value))
    else:
        return None
    for sub_path, sub in items:
        found = non_finite_path(sub, sub_path)
        if found is not None:
            return found
    return None


def all_finite(value: Any) -> bool:
    """Whether no number in ``value`` is a NaN or an infinity, read without building a JSON form: floats, numpy
    scalars and arrays, inside dicts (their values), lists, tuples and dataclasses (every field, written or not).

    The types of this module and :class:`toosicubix.solver.fit.Alternative` write nothing but their fields
    (``to_json``), so True means that :func:`non_finite_path` of their JSON form is None. False also when it
    cannot tell: a value of any other type, or a numpy array neither numeric nor boolean.
    """
    kind = type(value)
    if kind is float:
        return math.isfinite(value)
    if value is None or kind is str or kind is int or kind is bool:
        return True
    if kind is tuple or kind is list:
        return _all_finite_items(value)
    if kind is dict:
        return _all_finite_items(value.values())
    if kind is np.ndarray or isinstance(value, np.generic):
        code = value.dtype.kind
        return code in "biu" or (code in "fc" and bool(np.isfinite(value).all()))
    names = _dataclass_fields.get(kind)
    if names is None and hasattr(kind, "__dataclass_fields__"):
        names = _dataclass_fields.setdefault(kind, tuple(f.name for f in fields(value)))
    if names is not None:
        return _all_finite_items([getattr(value, name) for name in names])
    if isinstance(value, float):  # subclasses of the types above
        return math.isfinite(value)
    if isinstance(value, str | int):
        return True
    if isinstance(value, list | tuple):
        return _all_finite_items(value)
    if isinstance(value, dict):
        return _all_finite_items(value.values())
    return False


def _all_finite_items(items: Iterable[Any]) -> bool:
    for item in items:
        if not all_finite(item):
            return False
    return True


#: The field names of each dataclass :func:`all_finite` has met; an Observability's numbers are its ratios (its
#: sentences are text, made only when read: reading them here would make every fit pay for them).
_dataclass_fields: dict[type, tuple[str, ...]] = {Observability: ("ratios", "status")}


def read_results(path: str | Path) -> list[ImageResult]:
    """Read a ``results.json`` written by ``toosicubix fit``.

    Raises
    ------
    FormatError
        Not JSON, or a required key missing or malformed (the message gives its JSON path).
    """
    path = Path(path)
    doc = read_json(path)
    if not isinstance(doc, dict) or doc.get("toosicubix_results") != RESULTS_VERSION:
        raise FormatError(path, f"$.toosicubix_results: expected {RESULTS_VERSION} (a toosicubix results file)")
    images = []
    for i, im in enumerate(json_field(doc, "images", list, path, "$")):
        where = f"$.images[{i}]"
        camera = json_field(im, "camera", dict, path, where)
        K = json_numbers(camera.get("K"), (3, 3), path, f"{where}.camera.K")
        try:
            check_intrinsics(K)
        except ValueError as exc:
            raise FormatError(path, f"{where}.camera.K: {exc}") from None
        t_cam_rect = json_numbers(camera.get("t_cam_rect", [0.0, 0.0, 0.0]), (3,), path, f"{where}.camera.t_cam_rect")
        if np.abs(t_cam_rect).max() > MAX_CAMERA_OFFSET:
            raise FormatError(path, f"{where}.camera.t_cam_rect: expected an offset within {MAX_CAMERA_OFFSET:g} m, "
                                    f"got {t_cam_rect.tolist()}")
        size = camera.get("image_size")
        if size is not None:
            if not (isinstance(size, list) and len(size) == 2):
                raise FormatError(path, f"{where}.camera.image_size: expected [width, height] or null, got "
                                        f"{shown(size)}")
            size = [field_rules.image_side(side, path, f"{where}.camera.image_size[{k}]")
                    for k, side in enumerate(size)]
        vehicles = [VehicleResult.from_json(v, path, f"{where}.vehicles[{j}]")
                    for j, v in enumerate(json_field(im, "vehicles", list, path, where))]
        image_id = field_rules.file_name(json_field(im, "id", str, path, where), path, f"{where}.id",
                                         what="an image id")
        sequence = im.get("sequence")
        images.append(ImageResult(
            id=image_id, K=K, t_cam_rect=t_cam_rect,
            image_size=tuple(size) if size else None, vehicles=vehicles,  # type: ignore[arg-type]
            ground=_road_plane(im.get("ground")),
            sequence=None if sequence is None else field_rules.file_name(sequence, path, f"{where}.sequence",
                                                                         what="a sequence name"),
            frame=im["frame"] if isinstance(im.get("frame"), int) and not isinstance(im.get("frame"), bool) else None,
        ))
    return images


def _road_plane(value: Any) -> RoadPlane | None:
    """An image's ``ground`` as read; None when absent or not one (it is informational: nothing reads it back but a
    report, so a file another version or program wrote is not refused for it)."""
    try:
        plane = RoadPlane.from_json(value)
    except (KeyError, TypeError, ValueError, AttributeError):
        return None
    return plane if all(math.isfinite(v) for v in plane.normal) and len(plane.normal) == 3 else None
