"""Check an annotation file without writing anything: the job behind ``toosicubix validate``.

Every vehicle is fitted exactly as ``toosicubix fit`` would fit it (same options, same cues), and judged:
it is *well determined* when the fit succeeded, its yaw and relative depth standard deviations (for the
stated click noise, :mod:`toosicubix.solver.uncertainty`) are within the thresholds, and no second answer
fits the clicks about as well (:attr:`toosicubix.solver.fit.FitResult.ambiguous`). The report gives, per
vehicle, the constraint count, the uncertainty, what the clicks leave to the prior, the ambiguity, and the
parts to click next (:mod:`toosicubix.guidance`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from toosicubix import vocabulary
from toosicubix.annotations.stream import index_annotations
from toosicubix.formats.results import Alternative, VehicleResult
from toosicubix.pipeline.batch import pilot_and_fits
from toosicubix.pipeline.fitting import batch_run
from toosicubix.pipeline.pilot import PilotFindings
from toosicubix.pipeline.settings import BatchSettings

VALIDATION_VERSION = 1


@dataclass(frozen=True)
class Thresholds:
    """When a vehicle counts as well determined.

    The defaults refer to the bands of the confidence (the KITTI score: yaw within 10 degrees, depth within
    10 %): two yaw standard deviations inside the first, one depth standard deviation inside the second.
    The depth's is loose because no click fixes the scale: with the size prior alone, a car's depth is
    uncertain by about 7 %; a ground block (the camera height) brings it to 2 to 4 %.

    Where no click can get there (a far vehicle, a scale only the size prior sets), a limit is raised to
    ``reach_factor`` times what clicking every visible part would give at that distance (the vehicle's
    ``reachable_sigma``, :class:`toosicubix.solver.guidance.Guidance`; benchmarks/decisions.md, rule 20), and the
    report says so: "well determined" stays reachable, and honest about what limits it.

    Attributes
    ----------
    max_yaw_sigma_deg : largest yaw standard deviation, degrees
    max_depth_sigma_rel : largest depth standard deviation, relative to the depth
    allow_ambiguous : a second answer about as good as the best does not count against the vehicle
    reach_factor : each limit is at least this times the vehicle's reachable sigma, when known (0: fixed limits)
    """

    max_yaw_sigma_deg: float = 5.0
    max_depth_sigma_rel: float = 0.10
    allow_ambiguous: bool = False
    reach_factor: float = 1.25

    def to_json(self) -> dict[str, Any]:
        return {"max_yaw_sigma_deg": self.max_yaw_sigma_deg, "max_depth_sigma_rel": self.max_depth_sigma_rel,
                "allow_ambiguous": self.allow_ambiguous, "reach_factor": self.reach_factor}

    def limits(self, result: VehicleResult) -> tuple[float, float]:
        """The yaw (degrees) and relative depth limits for this vehicle: the fixed ones, raised to
        ``reach_factor`` times its reachable sigmas when those are larger."""
        reach = result.reachable_sigma
        if reach is None or self.reach_factor <= 0:
            return self.max_yaw_sigma_deg, self.max_depth_sigma_rel
        return (max(self.max_yaw_sigma_deg, self.reach_factor * _value(reach.yaw_deg)),
                max(self.max_depth_sigma_rel, self.reach_factor * _value(reach.depth_rel)))


@dataclass(frozen=True)
class VehicleCheck:
    """One vehicle's verdict.

    Attributes
    ----------
    image_id : its image; json_path : where it stands in the annotation file
    result : its fit, as results.json would have it (with ``next_clicks``)
    problems : why it is not well determined; empty when it is
    limited : what no click can fix at its distance (:func:`limited_by_distance`)
    """

    image_id: str
    json_path: str
    result: VehicleResult
    problems: tuple[str, ...]
    limited: tuple[str, ...] = ()

    @property
    def well_determined(self) -> bool:
        return not self.problems

    def to_json(self) -> dict[str, Any]:
        r = self.result
        return {
            "image": self.image_id, "id": r.id, "json_path": self.json_path, "prototype": r.prototype,
            "status": r.status, "error": r.error, "well_determined": self.well_determined,
            "problems": list(self.problems), "limited": list(self.limited), "constraints": r.constraints,
            "clicks": r.clicks,
            "aux_unknowns": r.aux_unknowns, "sigma": None if r.sigma is None else r.sigma.to_json(),
            "confidence": r.confidence,
            "reachable_sigma": None if r.reachable_sigma is None else r.reachable_sigma.to_json(),
            "observability": None if r.observability is None else r.observability.to_json(),
            "ambiguous": r.ambiguous if r.ok else None,
            "alternatives": [_brief(a) for a in r.alternatives], "warnings": list(r.warnings),
            "next_clicks": list(r.next_clicks or []),
        }


def _brief(alternative: Alternative) -> dict[str, Any]:
    a = alternative
    return {"cost": a.cost, "rotation_deg": a.rotation_deg, "turned_around": a.turned_around,
            "implausible": a.implausible, "close": a.close}


def _value(sigma: float | None) -> float:
    """A standard deviation from results.json: null stands for infinity (not determined at all)."""
    return math.inf if sigma is None else float(sigma)


def _show(value: float | None, digits: int = 1) -> str:
    value = _value(value)
    return "infinite" if math.isinf(value) else f"{value:.{digits}f}"


def judge(result: VehicleResult, thresholds: Thresholds) -> tuple[str, ...]:
    """Why a fitted vehicle is not well determined (empty: it is)."""
    if not result.ok:
        return (f"failed: {result.error}",)
    # A fit no person could have clicked (mirrored, turned away, wheels on the wrong axles) is never well determined,
    # however small its sigmas: they are the sigmas of the wrong answer.
    out = [f"implausible: {result.implausible}"] if result.implausible else []
    sigma = result.sigma
    if sigma is None:
        return (*out, "no uncertainty could be computed")
    yaw, depth = _value(sigma.yaw_deg), _value(sigma.depth_rel)
    max_yaw, max_depth = thresholds.limits(result)
    if not yaw <= max_yaw:
        out.append(f"yaw sigma {_show(yaw)} deg > {max_yaw:.3g}"
                   f"{_raised(max_yaw, thresholds.max_yaw_sigma_deg, f'{thresholds.max_yaw_sigma_deg:g}')}")
    if not depth <= max_depth:
        out.append(f"depth sigma {_show(100 * depth)} % > {100 * max_depth:.3g}"
                   f"{_raised(max_depth, thresholds.max_depth_sigma_rel, f'{100 * thresholds.max_depth_sigma_rel:g}')}")
    if result.ambiguous and not thresholds.allow_ambiguous:
        out.append("ambiguous: another answer fits the clicks about as well")
    return tuple(out)


def _raised(limit: float, fixed: float, shown: str) -> str:
    """Words saying a limit was raised from the ``fixed`` one (``shown`` as the report writes it), or nothing."""
    return f" (raised from {shown} to what clicks can reach here)" if limit > fixed else ""


def limited_by_distance(result: VehicleResult, thresholds: Thresholds) -> tuple[str, ...]:
    """Plain sentences, one per sigma that no click can bring within its fixed limit at this vehicle's distance
    (its reachable sigma is beyond the limit): what limits it, and that no click fixes it."""
    reach = result.reachable_sigma
    if not result.ok or reach is None or thresholds.reach_factor <= 0:
        return ()
    out = []
    if _value(reach.yaw_deg) > thresholds.max_yaw_sigma_deg:
        out.append(f"yaw: even with every visible part clicked its sigma would be {_show(reach.yaw_deg)} deg "
                   f"(> {thresholds.max_yaw_sigma_deg:g}) at this distance; no click can fix that, so it is judged "
                   f"against {thresholds.limits(result)[0]:.3g} deg")
    if _value(reach.depth_rel) > thresholds.max_depth_sigma_rel:
        scale = ("the size prior sets the scale" if result.scale_from == "size prior" else
                 f"the scale comes from {result.scale_from}" if result.scale_from else "the scale is loose")
        out.append(f"depth: even with every visible part clicked its sigma would be {_show(100 * reach.depth_rel)} % "
                   f"(> {100 * thresholds.max_depth_sigma_rel:g} %) at this distance, since {scale}; no click can "
                   f"fix that, so it is judged against {100 * thresholds.limits(result)[1]:.3g} %")
    return tuple(out)


@dataclass(frozen=True)
class ValidationReport:
    """The verdict on a whole file."""

    source: Path
    click_sigma: float
    part_sigma: float
    thresholds: Thresholds
    vehicles: list[VehicleCheck]
    pilot: PilotFindings | None = None  # what the batch's pilot estimated (click noise, road normals), if run

    @property
    def soft_noise(self) -> tuple[float, float] | None:
        """What keypoints' and plates' sigmas took (rule 35), when the pilot estimated it."""
        return None if self.pilot is None else self.pilot.options.soft_noise

    @property
    def ok(self) -> bool:
        """Every vehicle well determined."""
        return all(v.well_determined for v in self.vehicles)

    def summary(self) -> dict[str, int]:
        failed = sum(not v.result.ok for v in self.vehicles)
        good = sum(v.well_determined for v in self.vehicles)
        return {"vehicles": len(self.vehicles), "well_determined": good,
                "not_well_determined": len(self.vehicles) - good - failed, "failed": failed,
                "ambiguous": sum(bool(v.result.ambiguous) for v in self.vehicles)}

    def to_json(self) -> dict[str, Any]:
        estimated = self.pilot.header() if self.pilot is not None else {}
        return {"toosicubix_validation": VALIDATION_VERSION, "annotations": str(self.source),
                "click_sigma": self.click_sigma, "part_sigma": self.part_sigma, **estimated,
                "thresholds": self.thresholds.to_json(), "ok": self.ok, "summary": self.summary(),
                "vehicles": [v.to_json() for v in self.vehicles]}

    def text(self, show_all: bool = False) -> str:
        """A report for people: one paragraph per vehicle that is not well determined (every vehicle with
        ``show_all``; the frames of a track that failed for one reason, one paragraph), then a summary line."""
        shown = [v for v in self.vehicles if show_all or not v.well_determined]
        failed_tracks: dict[tuple[str, str | None], list[VehicleCheck]] = {}
        order: list[VehicleCheck | tuple[str, str | None]] = []
        for v in shown:
            if not v.result.ok and v.result.track is not None:
                key = (v.result.track, v.result.error)
                if key not in failed_tracks:
                    order.append(key)
                failed_tracks.setdefault(key, []).append(v)
            else:
                order.append(v)
        blocks = [describe(item) if isinstance(item, VehicleCheck) else describe_failed_track(failed_tracks[item])
                  for item in order]
        s = self.summary()
        t = self.thresholds
        tail = (f"{self.source}: {s['vehicles']} vehicles: {s['well_determined']} well determined, "
                f"{s['not_well_determined']} not, {s['failed']} failed (well determined: yaw sigma <= "
                f"{t.max_yaw_sigma_deg:g} deg, depth sigma <= {100 * t.max_depth_sigma_rel:g} %"
                f"{self._reach_phrase()}{'' if t.allow_ambiguous else ', not ambiguous'}; {self._noise_phrase()})")
        return "\n\n".join([*blocks, tail]) + "\n"

    def _reach_phrase(self) -> str:
        """How the limits were raised where no click reaches them, when they were for any vehicle."""
        t = self.thresholds
        if not any(v.limited for v in self.vehicles):
            return ""
        n = sum(bool(v.limited) for v in self.vehicles)
        return (f", or {t.reach_factor:g} x what every visible part clicked would give where that is more "
                f"({n} vehicle{'s' if n != 1 else ''})")

    def _noise_phrase(self) -> str:
        """What the sigmas were computed for: the click noise, on cuboid parts ``part_sigma`` off the model, and on
        keypoints and plates on top of their learned spread, or what the batch's residuals said of those (rule 35)
        (whichever of the two kinds the file's vehicles have)."""
        labels = {label for v in self.vehicles for label in v.result.click_labels}
        cuboid = any(vocabulary.on_body(label) and not vocabulary.soft(label) for label in labels)
        soft = any(vocabulary.soft(label) for label in labels)
        if soft and self.soft_noise is not None:
            sigma, scale = self.soft_noise
            keypoints = (f"keypoints and plates {sigma:.3g} px off on top of {scale:.2g} x their learned spread (the "
                         f"batch's residuals)")
            if not cuboid:
                return f"for {keypoints}"
            return (f"for clicks off by {self.click_sigma:.3g} px on parts {100 * self.part_sigma:.2g} cm off the "
                    f"cuboid model, {keypoints}")
        where = []
        if cuboid:
            where.append(f"on parts {100 * self.part_sigma:.2g} cm off the cuboid model")
        if soft:
            where.append("on top of each keypoint's learned spread")
        return " ".join([f"for clicks off by {self.click_sigma:.3g} px", " and ".join(where)]).strip()


def describe_failed_track(checks: list[VehicleCheck]) -> str:
    """The paragraph of a track's frames that failed for one reason (its first and last frame named with their JSON
    paths); one frame's is :func:`describe`'s."""
    if len(checks) == 1:
        return describe(checks[0])
    first, last, r = checks[0], checks[-1], checks[0].result
    return (f"track {r.track} ({r.prototype}): {len(checks)} frames failed, image {first.image_id} vehicle {r.id} "
            f"({first.json_path}) to image {last.image_id} vehicle {last.result.id} ({last.json_path}): {r.error}")


def describe(check: VehicleCheck) -> str:
    """One vehicle's paragraph of the text report."""
    r = check.result
    verdict = "well determined" if check.well_determined else "NOT well determined: " + "; ".join(check.problems)
    lines = [f"image {check.image_id} vehicle {r.id} ({r.prototype}, {check.json_path}): {verdict}"]
    if r.pose_from in ("box", "interpolated"):  # a track's frame without clicks: its clicks are the track's
        here = "its 2D box here" if r.pose_from == "box" else "nothing here: interpolated"
        lines.append(f"  its pose from its track ({here}) and the track's other frames; its sigmas are the track's")
    elif r.constraints is not None:
        lines.append(f"  constraints {r.constraints} from {r.clicks} clicked points "
                     f"({r.aux_unknowns} auxiliary unknowns); 8 fix the cuboid up to scale")
    if not r.ok:
        return "\n".join(lines)
    sigma = r.sigma
    if sigma is not None:
        dims = " x ".join(_show(v, 2) for v in sigma.dimensions)
        lines.append(f"  sigma: yaw {_show(sigma.yaw_deg)} deg, pitch {_show(sigma.pitch_deg)}, roll "
                     f"{_show(sigma.roll_deg)}; depth {_show(sigma.depth_m, 2)} m "
                     f"({_show(100 * _value(sigma.depth_rel))} %); size {dims} m; scale "
                     f"{_show(100 * _value(sigma.scale_rel))} %; confidence {r.confidence or 0.0:.2f}")
    for sentence in r.observability.sentences if r.observability is not None else ():
        lines.append(f"  {sentence}")
    for sentence in check.limited:
        lines.append(f"  {sentence}")
    for a in r.alternatives:
        if a.close:
            what = "turned around" if a.turned_around else f"rotated by {a.rotation_deg:.0f} deg"
            if a.implausible:
                lines.append(f"  rejected: an answer {what} costs {a.cost:.2f} against {r.cost:.2f}, but is "
                             f"implausible ({a.implausible})")
            else:
                lines.append(f"  ambiguous: an answer {what} costs {a.cost:.2f} against {r.cost:.2f}")
    for warning in r.warnings:
        lines.append(f"  warning: {warning}")
    suggestions = r.next_clicks or []
    if suggestions:
        lines.append("  click next:" if not any("clicked_share" in s for s in suggestions) else
                     "  click next (ranked by each one's shrink of the sigmas times how often people click it):")
    for k, s in enumerate(suggestions, 1):
        where = ", ".join(f"({u:.0f}, {v:.0f})" for u, v in s["uv"])
        caveat = (" [toward the far end: fixes yaw and length]" if s.get("far_end") else "") + (
            "" if s["visible"] and s["inside_image"] else
            " [on a face turned away]" if not s["visible"] else " [outside the image]")
        yaw_now = None if sigma is None else sigma.yaw_deg
        depth_now = None if sigma is None else sigma.depth_rel
        share = s.get("clicked_share")
        often = "" if share is None else f"; people click it on {100 * share:.0f} % of the cars that show it"
        lines.append(f"    {k}. {s['label']} near {where}: yaw sigma {_show(yaw_now)} -> "
                     f"{_show(s['yaw_sigma_deg'])} deg, depth {_show(100 * _value(depth_now))} -> "
                     f"{_show(100 * _value(s['depth_sigma_rel']))} %{often}{caveat}")
    return "\n".join(lines)


def validate_file(annotations: str | Path, settings: BatchSettings | None = None, thresholds: Thresholds | None = None,
                  progress: Callable[[int], None] | None = None,
                  on_start: Callable[[int], None] | None = None,
                  say: Callable[[str], None] | None = None) -> ValidationReport:
    """Fit every vehicle of a file as ``fit`` would, write nothing, judge each (see the module docstring).

    Parameters
    ----------
    annotations, progress, on_start, say : as :func:`toosicubix.pipeline.batch.fit_file` takes them
    settings : as :func:`~toosicubix.pipeline.batch.fit_file` takes them (``toosicubix validate``, like ``fit``,
        estimates the click noise and the road normals unless given them); default: its defaults with 3 next clicks
        per vehicle (the parts to suggest)
    thresholds : when a vehicle is well determined

    Raises
    ------
    InputFileError
        Bad annotation file, unknown prototype (the message has the file and the JSON paths).
    """
    annotations = Path(annotations)
    settings = settings or BatchSettings(next_clicks=3)
    thresholds = thresholds or Thresholds()
    index = index_annotations(annotations, known_prototypes=list(settings.priors))
    with batch_run(index.vehicles, settings, say) as settings:
        # Read image by image, as fit does: the fitter and the checks read the same stream.
        pilot, for_checks, results = pilot_and_fits(index, settings, progress, on_start)
        checks = [VehicleCheck(im.id, vehicle.json_path, r, judge(r, thresholds), limited_by_distance(r, thresholds))
                  for im, res in zip(for_checks, results, strict=True)
                  for vehicle, r in zip(im.vehicles, res.vehicles, strict=True)]
    options = pilot.options
    return ValidationReport(annotations, options.click_sigma, options.part_sigma, thresholds, checks, pilot)
