"""Aggregates of an evaluation and its outputs: the terminal table, JSON and CSV.

Every metric is reported as mean (as the paper does) and median, over all matched objects and per
bin of ground-truth depth (z in the camera frame), of occlusion where the ground truth states it (KITTI level;
Cityscapes occlusion fraction binned, see :data:`OCCLUSION_FRACTION_BINS`), and of the number of keypoints people
labelled where it counts them (ApolloCar3D, :data:`KEYPOINT_BINS`), and of whether the ground-truth pose hides
them (ApolloCar3D: turns at least 3 of them, and a quarter, away from the camera,
:func:`toosicubix.parts.learned.hides_clicks`): such a pose contradicts the clicks, and scores the fit against
something the clicks do not show.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from toosicubix import __version__
from toosicubix.evaluation.records import EvaluationResult, MatchedObject
from toosicubix.formats.atomic import atomic_write_text
from toosicubix.formats.ground_truth import GtObject
from toosicubix.parts.learned import CONTRADICTION_M, HIDES_MIN, hides_clicks
from toosicubix.vocabulary import class_of, heading_of

#: Depth bins over the ground truth's z, metres: [lo, hi).
DEPTH_BINS: tuple[tuple[float, float], ...] = ((0.0, 10.0), (10.0, 20.0), (20.0, 30.0), (30.0, 50.0), (50.0, math.inf))
#: KITTI occlusion levels.
OCCLUSION_LEVELS = {0: "0 fully visible", 1: "1 partly occluded", 2: "2 largely occluded", 3: "3 unknown"}
#: Cityscapes occlusion-fraction bins: [lo, hi), the last one closed.
OCCLUSION_FRACTION_BINS: tuple[tuple[float, float], ...] = ((0.0, 0.1), (0.1, 0.4), (0.4, 0.7), (0.7, 1.0))
#: Bins of labelled keypoints per ground-truth object: [lo, hi).
KEYPOINT_BINS: tuple[tuple[float, float], ...] = ((0, 10), (10, 15), (15, 20), (20, 30), (30, math.inf))
_OCCLUSION_TITLES = {"level": "KITTI occlusion level", "fraction": "Cityscapes occlusion fraction"}

#: (summary key of the mean, summary key of the median, attribute of ObjectMetrics), in the paper's order.
_STAT_KEYS = (
    ("iou_mean", "iou_median", "iou"),
    ("siou_mean", "siou_median", "siou"),
    ("e_r_mean_deg", "e_r_median_deg", "e_r_deg"),
    ("e_t_mean", "e_t_median", "e_t"),
    ("e_d_mean", "e_d_median", "e_d"),
    ("e_comb_mean", "e_comb_median", "e_comb"),
    ("iou_kitti_mean", "iou_kitti_median", "iou_kitti"),
    ("e_yaw_mean_deg", "e_yaw_median_deg", "e_yaw_deg"),
)


def metric_stats(records: Sequence[MatchedObject]) -> dict[str, float | None]:
    """Mean and median of every metric over ``records``; None when there are none.

    Keys: ``iou_mean``, ``iou_median``, ``siou_mean``, ..., ``e_r_mean_deg``, ``e_r_median_deg``, ...,
    ``iou_kitti_mean``, ``iou_kitti_median``, ``e_yaw_mean_deg``, ``e_yaw_median_deg``.
    """
    out: dict[str, float | None] = {}
    for mean_key, median_key, attr in _STAT_KEYS:
        values = np.array([getattr(r.metrics, attr) for r in records], dtype=float)
        usable = len(values) > 0 and bool(np.all(np.isfinite(values)))  # a NaN or infinity is never a mean
        out[mean_key] = float(values.mean()) if usable else None
        out[median_key] = float(np.median(values)) if usable else None
    return out


def summarize(result: EvaluationResult) -> dict[str, Any]:
    """The summary block: counts, then mean and median of every metric over the matched objects."""
    return {
        "n_matched": len(result.matched),
        "n_unmatched_pred": len(result.unmatched_pred),
        "n_unmatched_gt": len(result.unmatched_gt),
        "n_failed_pred": len(result.failed_pred),
        "n_gt_excluded": sum(result.gt_excluded.values()),
        "n_images": result.n_images,
        "n_gt_images_without_pred": result.n_gt_images_without_pred,
        **metric_stats(result.matched),
    }


def _bin_label(lo: float, hi: float, unit: str = "") -> str:
    return f"{lo:g}+{unit}" if math.isinf(hi) else f"{lo:g}-{hi:g}{unit}"


def _breakdown(records: Sequence[MatchedObject], bins: Sequence[tuple[str, Callable[[MatchedObject], bool]]]
               ) -> list[dict[str, Any]]:
    rows = []
    for label, belongs in bins:
        members = [r for r in records if belongs(r)]
        rows.append({"bin": label, "n": len(members), **metric_stats(members)})
    return rows


def depth_breakdown(records: Sequence[MatchedObject]) -> list[dict[str, Any]]:
    """Statistics per ground-truth depth bin (:data:`DEPTH_BINS`; a depth below 0 counts in the first)."""
    bins = []
    for k, (lo, hi) in enumerate(DEPTH_BINS):
        low = -math.inf if k == 0 else lo
        bins.append((_bin_label(lo, hi, " m"), lambda r, low=low, hi=hi: low <= r.depth < hi))
    return _breakdown(records, bins)


def occlusion_breakdown(records: Sequence[MatchedObject], kind: str) -> list[dict[str, Any]]:
    """Statistics per KITTI occlusion level (``kind='level'``) or Cityscapes occlusion-fraction bin
    (``kind='fraction'``, :data:`OCCLUSION_FRACTION_BINS`); objects without the field go to 'unknown'."""
    if kind == "level":
        bins = [(label, lambda r, level=level: r.occlusion == level) for level, label in OCCLUSION_LEVELS.items()]
        bins.append(("unknown", lambda r: r.occlusion not in OCCLUSION_LEVELS))
    else:
        bins = []
        for k, (lo, hi) in enumerate(OCCLUSION_FRACTION_BINS):
            last = k == len(OCCLUSION_FRACTION_BINS) - 1
            bins.append((f"{lo:g}-{hi:g}", lambda r, lo=lo, hi=hi, last=last: r.occlusion_fraction is not None
                         and lo <= r.occlusion_fraction and (r.occlusion_fraction < hi or last)))
        bins.append(("unknown", lambda r: r.occlusion_fraction is None))
    return [row for row in _breakdown(records, bins) if row["n"] > 0 or row["bin"] != "unknown"]


def keypoint_breakdown(records: Sequence[MatchedObject]) -> list[dict[str, Any]]:
    """Statistics per bin of labelled keypoints (:data:`KEYPOINT_BINS`), over the records that count them."""
    bins = [(_bin_label(lo, hi) if math.isinf(hi) else f"{lo:g}-{hi - 1:g}",
             lambda r, lo=lo, hi=hi: r.keypoints is not None and lo <= r.keypoints < hi) for lo, hi in KEYPOINT_BINS]
    return _breakdown(records, bins)


def heading_stats(records: Sequence[MatchedObject]) -> dict[str, float | int | None]:
    """Mean and median heading error (degrees, :attr:`MatchedObject.e_heading_deg`) over the records whose class has
    a heading, and how many those are (``n_heading``); None when none has."""
    values = np.array([r.e_heading_deg for r in records if r.e_heading_deg is not None], dtype=float)
    usable = len(values) > 0 and bool(np.all(np.isfinite(values)))
    return {"n_heading": len(values), "e_heading_mean_deg": float(values.mean()) if usable else None,
            "e_heading_median_deg": float(np.median(values)) if usable else None}


def class_breakdown(records: Sequence[MatchedObject]) -> list[dict[str, Any]]:
    """Statistics per ground-truth class (in the order the classes first appear), with the heading error of the
    classes that have a heading (a traffic cone has none; a barrier's counts modulo 180 degrees)."""
    classes = list(dict.fromkeys(r.cls for r in records))
    rows = []
    for cls in classes:
        members = [r for r in records if r.cls == cls]
        rows.append({"bin": cls, "n": len(members), **metric_stats(members), **heading_stats(members)})
    return rows


def _counts_keypoints(result: EvaluationResult) -> bool:
    return any(r.keypoints is not None for r in result.matched)


#: The two bins of :func:`hidden_breakdown`.
AGREES, HIDES = "shows them", f"hides >= {HIDES_MIN} and 1/4"


def hides_keypoints(r: MatchedObject | GtObject) -> bool | None:
    """Whether the object's ground-truth pose hides its labelled keypoints
    (:func:`toosicubix.parts.learned.hides_clicks`); None where the ground truth does not count them."""
    return None if r.keypoints_hidden is None else hides_clicks(r.keypoints or 0, r.keypoints_hidden)


def hidden_breakdown(records: Sequence[MatchedObject]) -> list[dict[str, Any]]:
    """Statistics of the objects whose ground-truth pose shows its labelled keypoints, and of those whose pose hides
    them (:func:`hides_keypoints`), over the records that count them."""
    return _breakdown(records, [(AGREES, lambda r: hides_keypoints(r) is False),
                                (HIDES, lambda r: hides_keypoints(r) is True)])


#: A fit this close (degrees, E_R) to the ground truth's depth-reversed twin counts as that twin.
TWIN_DEG = 10.0


def twin_summary(records: Sequence[MatchedObject]) -> dict[str, int]:
    """Of the objects whose ground-truth pose hides their labelled keypoints, how many there are and how many fits
    lie within :data:`TWIN_DEG` of the ground truth's depth-reversed twin."""
    hiding = [r for r in records if hides_keypoints(r)]
    return {"hides": len(hiding), "fit_within_10_deg_of_twin": sum(
        r.e_r_twin_deg is not None and r.e_r_twin_deg <= TWIN_DEG for r in hiding)}


def _counts_hidden(result: EvaluationResult) -> bool:
    return any(r.keypoints_hidden is not None for r in result.matched)


#: The two bins of :func:`off_rays_breakdown`, and the objects neither it nor :func:`hidden_breakdown` flags.
ON_RAYS, OFF_RAYS = f"on them <= {CONTRADICTION_M:g} m", f"off them > {CONTRADICTION_M:g} m"
CONSISTENT = "neither off nor hiding"


def off_keypoint_rays(r: MatchedObject | GtObject) -> bool | None:
    """Whether the object's labelled keypoints lie more than :data:`~toosicubix.parts.learned.CONTRADICTION_M` (RMS)
    from their rays at its ground-truth pose; None where the ground truth does not measure it."""
    return None if r.keypoints_off_rays_m is None else r.keypoints_off_rays_m > CONTRADICTION_M


def off_rays_breakdown(records: Sequence[MatchedObject]) -> list[dict[str, Any]]:
    """Statistics of the objects whose labelled keypoints lie on their rays at the ground-truth pose, of those off
    them (:func:`off_keypoint_rays`), and of those whose ground truth neither lies off its keypoints' rays nor hides
    them (:func:`hides_keypoints`): the ground truth that agrees with the clicks."""
    return _breakdown(records, [(ON_RAYS, lambda r: off_keypoint_rays(r) is False),
                                (OFF_RAYS, lambda r: off_keypoint_rays(r) is True),
                                (CONSISTENT, lambda r: off_keypoint_rays(r) is False and hides_keypoints(r) is False)])


def _counts_off_rays(result: EvaluationResult) -> bool:
    return any(r.keypoints_off_rays_m is not None for r in result.matched)


def breakdowns(result: EvaluationResult) -> dict[str, Any]:
    """``{"depth": [...], "class": [...], "occlusion": [...], "occlusion_kind": ...}``, each row ``{"bin", "n",
    <stats>}`` (a class's row also its heading error, :func:`heading_stats`);
    ``occlusion`` and ``occlusion_kind`` only where the ground truth states occlusion, ``keypoints`` (rows per
    bin of labelled keypoints) only where it counts them, ``ground_truth_shows_keypoints`` and
    ``ground_truth_twin`` where it counts those its pose hides, ``ground_truth_on_keypoint_rays`` where it measures
    how far they lie from their rays (:func:`off_rays_breakdown`)."""
    out: dict[str, Any] = {"depth": depth_breakdown(result.matched), "class": class_breakdown(result.matched)}
    if result.occlusion_kind is not None:
        out["occlusion"] = occlusion_breakdown(result.matched, result.occlusion_kind)
        out["occlusion_kind"] = _OCCLUSION_TITLES[result.occlusion_kind]
    if _counts_keypoints(result):
        out["keypoints"] = keypoint_breakdown(result.matched)
    if _counts_hidden(result):
        out["ground_truth_shows_keypoints"] = hidden_breakdown(result.matched)
        out["ground_truth_twin"] = twin_summary(result.matched)
    if _counts_off_rays(result):
        out["ground_truth_on_keypoint_rays"] = off_rays_breakdown(result.matched)
    return out


# --- terminal table ---------------------------------------------------------------------------------------

_COLUMNS = (("IoU", "iou"), ("sIoU", "siou"), ("E_R deg", "e_r_deg"), ("E_t", "e_t"), ("E_d", "e_d"),
            ("E_comb", "e_comb"), ("IoU_KITTI", "iou_kitti"), ("E_yaw deg", "e_yaw_deg"))


def _cell(value: float | None, attr: str) -> str:
    if value is None or not math.isfinite(value):
        return "-"
    return f"{value:.2f}" if attr in ("e_r_deg", "e_yaw_deg") else f"{value:.3f}"


def _table(rows: list[tuple[str, int, dict[str, Any], str]], label_width: int) -> list[str]:
    """Rows ``(label, n, stats, 'mean' or 'median')`` under a header of the metric names."""
    header = f"{'':<{label_width}} {'n':>5}" + "".join(f" {name:>9}" for name, _ in _COLUMNS)
    lines = [header]
    for label, n, stats, which in rows:
        cells = "".join(f" {_cell(stats[_stat_key(attr, which)], attr):>9}" for _, attr in _COLUMNS)
        lines.append(f"{label:<{label_width}} {n:>5}{cells}")
    return lines


def _stat_key(attr: str, which: str) -> str:
    mean_key, median_key, _ = next(k for k in _STAT_KEYS if k[2] == attr)
    return mean_key if which == "mean" else median_key


def format_report(result: EvaluationResult, max_listed: int = 10) -> str:
    """The terminal report: the paper's table (mean and median of every metric), breakdowns (means) by depth, by
    occlusion where the ground truth states it and by labelled keypoints where it counts them, then the counts and
    the first unmatched, failed and excluded objects."""
    s = result.settings
    stats = metric_stats(result.matched)
    n = len(result.matched)
    lines = [
        f"predictions: {s.get('predictions_source', '?')} (rotations: {s.get('rotations', '?')})",
        f"ground truth: {s.get('ground_truth_source', '?')}",
        f"paired by 2D box IoU >= {s.get('min_iou', '?')}; classes: {', '.join(s.get('classes', []))}",
        "",
        *_table([("mean", n, stats, "mean"), ("median", n, stats, "median")], 20),
        "",
        "By ground-truth depth (means):",
        *_table([(r["bin"], r["n"], r, "mean") for r in depth_breakdown(result.matched)], 20),
        "",
    ]
    by_class = class_breakdown(result.matched)
    # The table with more than one class; the heading errors whenever a class's yaw is not plain (a road user's).
    if len(by_class) > 1 or any(heading_of(r["bin"]) != "directed" or class_of(r["bin"]) is not None
                                for r in by_class):
        lines += ["By ground-truth class (means):",
                  *_table([(r["bin"], r["n"], r, "mean") for r in by_class], 20),
                  "heading error (degrees, median / mean): " + "; ".join(
                      f"{r['bin']} " + ("none (no yaw)" if r["e_heading_median_deg"] is None else
                                        f"{r['e_heading_median_deg']:.2f} / {r['e_heading_mean_deg']:.2f}")
                      for r in by_class), ""]
    if result.occlusion_kind is not None:
        lines += [f"By {_OCCLUSION_TITLES[result.occlusion_kind]} (means):",
                  *_table([(r["bin"], r["n"], r, "mean")
                           for r in occlusion_breakdown(result.matched, result.occlusion_kind)], 20), ""]
    if _counts_keypoints(result):
        lines += ["By keypoints labelled on the ground-truth object (means):",
                  *_table([(r["bin"], r["n"], r, "mean") for r in keypoint_breakdown(result.matched)], 20), ""]
    if _counts_hidden(result):
        lines += ["By whether the ground-truth pose hides the labelled keypoints from the camera (means):",
                  *_table([(r["bin"], r["n"], r, "mean") for r in hidden_breakdown(result.matched)], 20)]
        twins = twin_summary(result.matched)
        if twins["hides"]:
            near = twins["fit_within_10_deg_of_twin"]
            lines.append(f"of the {twins['hides']} whose pose hides them, {near} fits lie "
                         f"within {TWIN_DEG:g} deg of the ground truth's depth-reversed twin (the car reflected in "
                         "depth and mirrored left for right: the pose the clicks show when the ground truth is its "
                         "mirror image)")
        lines.append("")
    if _counts_off_rays(result):
        lines += ["By how far the labelled keypoints lie from their rays at the ground-truth pose (RMS; means):",
                  *_table([(r["bin"], r["n"], r, "mean") for r in off_rays_breakdown(result.matched)], 22), ""]
    lines += [
        f"images scored: {result.n_images}; ground-truth images without predictions (not scored): "
        f"{result.n_gt_images_without_pred} of {result.n_gt_images}",
        f"matched: {n}; unmatched predictions: {len(result.unmatched_pred)}; unmatched ground truth: "
        f"{len(result.unmatched_gt)}; failed predictions: {len(result.failed_pred)}",
    ]
    if result.gt_excluded:
        listed = ", ".join(f"{cls} {count}" for cls, count in result.gt_excluded.items())
        lines.append(f"ground truth not scored (class filter): {listed}")
    for title, items in (("unmatched predictions", result.unmatched_pred),
                         ("unmatched ground truth", result.unmatched_gt),
                         ("failed predictions", result.failed_pred)):
        if not items:
            continue
        lines.append(f"{title}:")
        for u in items[:max_listed]:
            box = "" if u.box2d is None else " box " + " ".join(f"{v:.1f}" for v in u.box2d)
            lines.append(f"  image {u.image_id} id {u.id} ({u.cls}){box}, best 2D IoU {u.best_iou_2d:.2f}: "
                         f"{u.reason}")
        if len(items) > max_listed:
            lines.append(f"  ... and {len(items) - max_listed} more (see --json)")
    return "\n".join(lines) + "\n"


# --- JSON and CSV -----------------------------------------------------------------------------------------

def _finite(value: Any) -> Any:
    """JSON has no NaN or infinity: such floats become None, recursively."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def _pose(c: Any) -> dict[str, Any]:
    return {"R_cam_vehicle": c.R_cam_vehicle.tolist(), "t_cam_vehicle": c.t_cam_vehicle.tolist(),
            "dimensions": c.dimensions.tolist()}


def result_to_json(result: EvaluationResult) -> dict[str, Any]:
    """The JSON document: ``summary`` (counts, mean and median of every metric), ``objects`` (one per match,
    with both poses in the camera frame of K), the unmatched, failed and excluded objects, breakdowns,
    warnings and settings."""
    return _finite({
        "generator": f"toosicubix {__version__}",
        "summary": summarize(result),
        "objects": [{**r.row(), "pred": _pose(r.pred), "gt": _pose(r.gt)} for r in result.matched],
        "unmatched_pred": [u.row() for u in result.unmatched_pred],
        "unmatched_gt": [u.row() for u in result.unmatched_gt],
        "failed_pred": [u.row() for u in result.failed_pred],
        "gt_excluded": result.gt_excluded,
        "breakdowns": breakdowns(result),
        "warnings": list(result.warnings),
        "settings": result.settings,
    })


#: CSV columns, one row per matched object.
CSV_COLUMNS = (
    "image_id", "pred_id", "gt_index", "gt_track_id", "class", "pred_class", "subtype", "occlusion",
    "occlusion_fraction", "truncation", "depth", "iou_2d", "iou", "siou", "e_r_deg", "e_t", "e_d", "e_comb",
    "iou_kitti", "e_yaw_deg", "yaw_only", "pred_source", "gt_source", "keypoints", "keypoints_hidden",
    "e_r_twin_deg", "keypoints_off_rays_m", "e_heading_deg",
)


def result_to_csv(result: EvaluationResult) -> str:
    """CSV text: a header of :data:`CSV_COLUMNS`, then one row per matched object (empty cell for None)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=CSV_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for r in result.matched:
        writer.writerow({k: "" if v is None or (isinstance(v, float) and not math.isfinite(v)) else v
                         for k, v in r.row().items()})
    return buffer.getvalue()


def write_json(result: EvaluationResult, path: str | Path) -> None:
    """Write :func:`result_to_json` atomically (the parent folder is created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(result_to_json(result), indent=1, allow_nan=False) + "\n")


def write_csv(result: EvaluationResult, path: str | Path) -> None:
    """Write :func:`result_to_csv` atomically (the parent folder is created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, result_to_csv(result))
