"""The evaluation: pair each predicted image with its ground truth, match objects, compute the metrics.

Frames. Everything is compared in the camera frame where the prediction's ``K`` applies:

- results.json poses are already there. The ground truth is moved there by its own ``t_cam_rect``
  (KITTI: ``K^-1 P2[:, 3]`` from the calib file). Without a calib file, results.json's
  ``t_cam_rect`` is used and a warning says so. When both exist and differ by more than 1 mm, a
  warning says so and the calib's offset is used for the ground truth.
- KITTI label predictions (yaw only) are in camera 0, like KITTI ground truth: both are moved by the
  calib's ``t2``; without a calib file ``t2 = 0`` (compared in camera 0) with a warning.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from toosicubix.errors import EvaluationInputError
from toosicubix.evaluation.matching import box_iou_matrix, match_boxes
from toosicubix.evaluation.metrics import heading_error_deg, object_metrics, symmetric_twin, twin_rotation_error_deg
from toosicubix.evaluation.predictions import Predictions, PredImage, PredObject, load_predictions
from toosicubix.evaluation.records import EvaluationResult, MatchedObject, UnscoredObject
from toosicubix.formats.ground_truth import GroundTruthSource, GtImage, GtObject, open_ground_truth
from toosicubix.vocabulary import family_of, heading_of

#: results.json's and the calib's camera offsets may differ by this much (metres) without a warning.
T_CAM_RECT_TOLERANCE = 1e-3
#: results.json's and the ground truth's K may differ by this much (pixels) without a warning.
K_TOLERANCE_PX = 0.5
#: Missing ground-truth partners listed in the error message.
_MAX_LISTED = 5


@dataclass(frozen=True)
class EvalOptions:
    """Settings of an evaluation.

    Attributes
    ----------
    min_iou : 2D box IoU a pair needs to be matched, in [0, 1] (default 0.5)
    classes : ground-truth classes scored (case-insensitive); None for the source's defaults and every other class
        the predictions have a fitted object of (a batch's pedestrians are scored with its cars)
    """

    min_iou: float = 0.5
    classes: tuple[str, ...] | None = None


@dataclass
class _Notes:
    """Warnings gathered per kind, reported once each with a count and an example."""

    counts: dict[str, list[str]] = field(default_factory=dict)
    worst: dict[str, float] = field(default_factory=dict)

    def add(self, key: str, image_id: str, value: float = 0.0) -> None:
        self.counts.setdefault(key, []).append(image_id)
        self.worst[key] = max(self.worst.get(key, 0.0), value)

    def lines(self) -> list[str]:
        out = []
        for key, ids in self.counts.items():
            example = ", ".join(ids[:3]) + (", ..." if len(ids) > 3 else "")
            out.append(key.format(n=len(ids), ids=example, worst=self.worst[key]))
        return out


_MISC_LABELS = ("{n} label file(s) ({ids}) hold predictions typed Misc: fit writes cones, barriers and two-wheelers "
                "without a rider so, and without results.json their class is unknown, so they are paired as vehicles; "
                "evaluate the output folder with its results.json to score them as their class")
_NO_CALIB_RESULTS = ("no calib file for {n} image(s) ({ids}): ground truth moved into the camera of K by "
                     "results.json's t_cam_rect")
_NO_CALIB_LABELS = ("no calib file for {n} image(s) ({ids}): KITTI label predictions and ground truth compared in "
                    "camera 0 (t2 = 0)")
_T_MISMATCH = ("t_cam_rect of results.json differs from the ground truth's camera offset (KITTI: K^-1 P2[:, 3] of the "
               "calib file) by up to {worst:.1f} mm in {n} image(s) ({ids}): predictions kept in their own frame, "
               "ground truth moved by its own offset")
_K_MISMATCH = ("K of results.json differs from the ground truth's camera by up to {worst:.2f} px in {n} image(s) "
               "({ids}): were these images fitted with another calibration?")


def evaluate(predictions: Predictions, ground_truth: GroundTruthSource,
             options: EvalOptions | None = None) -> EvaluationResult:
    """Score predictions against ground truth, image by image.

    Parameters
    ----------
    predictions : from :func:`load_predictions`
    ground_truth : from :func:`open_ground_truth`
    options : threshold and class filter

    Returns
    -------
    EvaluationResult

    Raises
    ------
    EvaluationInputError
        A predicted image has no ground-truth partner (all such images are named), or a bad option.
    FormatError
        A malformed ground-truth file.
    """
    options = options or EvalOptions()
    if not 0.0 <= options.min_iou <= 1.0:
        raise EvaluationInputError(f"min_iou: expected a 2D IoU in [0, 1], got {options.min_iou}")
    classes = options.classes if options.classes is not None else default_classes(ground_truth, predictions)
    wanted = {c.lower() for c in classes}
    notes = _Notes()
    missing: list[str] = []
    matched: list[MatchedObject] = []
    unmatched_pred: list[UnscoredObject] = []
    unmatched_gt: list[UnscoredObject] = []
    failed_pred: list[UnscoredObject] = []
    excluded: dict[str, int] = {}
    scored_by: dict[str, PredImage] = {}  # ground-truth image -> the predicted image scored against it
    for pred_image in predictions.images:
        try:
            gt_id = ground_truth.resolve_id(pred_image.id, pred_image.sequence, pred_image.frame_number)
            gt_image = ground_truth.load(gt_id)
        except EvaluationInputError as exc:
            missing.append(f"{exc} (predictions: {pred_image.source})")
            continue
        other = scored_by.setdefault(gt_id, pred_image)
        if other is not pred_image:  # scoring both would count that frame's objects twice
            raise EvaluationInputError(f"predicted images {other.id!r} ({other.source}) and {pred_image.id!r} "
                                       f"({pred_image.source}) are both ground-truth image {gt_id!r}: give each "
                                       "frame once")
        if pred_image.frame == "rect" and any(p.cls == "Misc" for p in pred_image.objects):
            notes.add(_MISC_LABELS, pred_image.id)
        gt_offset, pred_offset = _frame_offsets(pred_image, gt_image, notes)
        scored_gt: list[GtObject] = []
        for obj in gt_image.objects:
            if obj.cuboid_rect is not None and obj.cls.lower() in wanted:
                scored_gt.append(obj)
            else:
                excluded[obj.cls] = excluded.get(obj.cls, 0) + 1
        failed_pred.extend(
            UnscoredObject(pred_image.id, p.id, p.cls, p.box2d, 0.0, _failure_reason(p), p.source)
            for p in pred_image.objects if not p.ok
        )
        # Pair within each family of road users (a pedestrian with a pedestrian, never with a car's box).
        families = dict.fromkeys([p.family for p in pred_image.objects if p.ok]
                                 + [family_of(g.cls) for g in scored_gt])
        for family in families:
            _pair(pred_image, [p for p in pred_image.objects if p.ok and p.family == family],
                  [g for g in scored_gt if family_of(g.cls) == family], gt_offset, pred_offset, options, matched,
                  unmatched_pred, unmatched_gt, wanted)
    if missing:
        more = f" (and {len(missing) - _MAX_LISTED} more)" if len(missing) > _MAX_LISTED else ""
        raise EvaluationInputError(
            f"{len(missing)} predicted image(s) have no ground truth{more}:\n  " + "\n  ".join(missing[:_MAX_LISTED]))
    gt_ids = set(ground_truth.image_ids())
    pred_ids = {ground_truth.resolve_id(im.id, im.sequence, im.frame_number) for im in predictions.images}
    warnings = notes.lines()
    if not predictions.images:
        warnings.append(f"{predictions.source}: no predicted images, nothing scored")
    return EvaluationResult(
        matched=tuple(matched), unmatched_pred=tuple(unmatched_pred), unmatched_gt=tuple(unmatched_gt),
        failed_pred=tuple(failed_pred), gt_excluded=dict(sorted(excluded.items())),
        n_images=len(predictions.images), n_gt_images=len(gt_ids), n_gt_images_without_pred=len(gt_ids - pred_ids),
        occlusion_kind=ground_truth.occlusion_kind, warnings=tuple(warnings),
        settings={
            "min_iou": options.min_iou, "classes": list(classes), "ground_truth": ground_truth.kind,
            "ground_truth_source": ground_truth.describe(), "predictions": predictions.kind,
            "predictions_source": str(predictions.source),
            "rotations": "yaw only (KITTI labels)" if predictions.yaw_only else "full (results.json)",
        },
    )


def _pair(pred_image: PredImage, preds: list[PredObject], scored_gt: list[GtObject], gt_offset: np.ndarray,
          pred_offset: np.ndarray, options: EvalOptions, matched: list[MatchedObject],
          unmatched_pred: list[UnscoredObject], unmatched_gt: list[UnscoredObject], wanted: set[str]) -> None:
    """Match one image's predictions ``preds`` and ground truth ``scored_gt`` (one family of road users) by 2D box
    IoU, appending the pairs with their metrics and the objects left without a partner (a prediction of a class
    not ``wanted`` had none to be paired with, and is said to be so)."""
    pred_boxes = np.array([p.box2d for p in preds]).reshape(-1, 4)
    gt_boxes = np.array([g.box2d for g in scored_gt]).reshape(-1, 4)
    matching = match_boxes(pred_boxes, gt_boxes, options.min_iou)
    ious = box_iou_matrix(pred_boxes, gt_boxes)
    for i, j, iou_2d in matching.pairs:
        p, g = preds[i], scored_gt[j]
        heading = heading_of(p.prototype or g.cls)
        gt_cuboid = g.cuboid_rect.translated(gt_offset)  # type: ignore[union-attr]
        pred_cuboid = symmetric_twin(p.cuboid.translated(pred_offset), gt_cuboid, heading)  # type: ignore[union-attr]
        metrics = object_metrics(pred_cuboid, gt_cuboid)
        matched.append(MatchedObject(
            image_id=pred_image.id, pred_id=p.id, gt_index=g.index, gt_track_id=g.track_id, cls=g.cls,
            pred_cls=p.cls, subtype=g.subtype, occlusion=g.occlusion, occlusion_fraction=g.occlusion_fraction,
            truncation=g.truncation, depth=float(gt_cuboid.t_cam_vehicle[2]), iou_2d=iou_2d,
            metrics=metrics, pred=pred_cuboid, gt=gt_cuboid,
            yaw_only=pred_image.frame == "rect", pred_source=p.source, gt_source=g.source,
            keypoints=g.keypoints, keypoints_hidden=g.keypoints_hidden,
            e_r_twin_deg=None if g.keypoints_hidden is None else twin_rotation_error_deg(pred_cuboid, gt_cuboid),
            keypoints_off_rays_m=g.keypoints_off_rays_m,
            e_heading_deg=heading_error_deg(metrics.e_yaw_deg, heading),
        ))
    reason = f"no ground-truth partner with 2D IoU >= {options.min_iou:g}"
    unmatched_pred.extend(
        UnscoredObject(pred_image.id, preds[i].id, preds[i].cls, preds[i].box2d,
                       float(ious[i].max()) if ious.shape[1] else 0.0,
                       reason if preds[i].cls.lower() in wanted else
                       f"its class, {preds[i].cls}, is not among the ground-truth classes scored", preds[i].source)
        for i in matching.unmatched_pred
    )
    reason = f"no prediction with 2D IoU >= {options.min_iou:g}"
    unmatched_gt.extend(
        UnscoredObject(pred_image.id, str(scored_gt[j].index), scored_gt[j].cls, scored_gt[j].box2d,
                       float(ious[:, j].max()) if ious.shape[0] else 0.0, reason, scored_gt[j].source)
        for j in matching.unmatched_gt
    )


def default_classes(ground_truth: GroundTruthSource, predictions: Predictions) -> tuple[str, ...]:
    """The classes scored when none are given: the ground-truth source's defaults (the paper's vehicles), then
    every other class the predictions have a fitted object of, in order of name."""
    defaults = tuple(ground_truth.default_classes)
    known = {c.lower() for c in defaults}
    fitted = sorted({p.cls for im in predictions.images for p in im.objects if p.ok and p.cls.lower() not in known})
    return defaults + tuple(fitted)


def _failure_reason(p: PredObject) -> str:
    if p.status != "ok":
        return f"{p.status}: {p.error or 'no reason given'}"
    return "no 2D box: the cuboid lies behind the camera"


def _frame_offsets(pred_image: PredImage, gt_image: GtImage, notes: _Notes) -> tuple[np.ndarray, np.ndarray]:
    """``(gt_offset, pred_offset)``: what to add to each side's translations to reach the camera of ``K``."""
    if pred_image.frame == "rect":  # KITTI labels: camera 0 like the ground truth
        if gt_image.t_cam_rect is None:
            notes.add(_NO_CALIB_LABELS, pred_image.id)
            return np.zeros(3), np.zeros(3)
        return gt_image.t_cam_rect, gt_image.t_cam_rect
    pred_t = pred_image.t_cam_rect if pred_image.t_cam_rect is not None else np.zeros(3)
    if gt_image.K is not None and pred_image.K is not None:
        dK = float(np.max(np.abs(gt_image.K - pred_image.K)))
        if dK > K_TOLERANCE_PX:
            notes.add(_K_MISMATCH, pred_image.id, dK)
    if gt_image.t_cam_rect is None:
        notes.add(_NO_CALIB_RESULTS, pred_image.id)
        return pred_t, np.zeros(3)
    dt = float(np.linalg.norm(gt_image.t_cam_rect - pred_t))
    if dt > T_CAM_RECT_TOLERANCE:
        notes.add(_T_MISMATCH, pred_image.id, 1e3 * dt)
    return gt_image.t_cam_rect, np.zeros(3)


def evaluate_folder(out_dir: str | Path, gt_kind: str, gt_dir: str | Path,
                    options: EvalOptions | None = None, **source_options: Any) -> EvaluationResult:
    """Read a fit output folder and a ground-truth folder, and score the one against the other.

    Parameters
    ----------
    out_dir : output folder of ``toosicubix fit`` (results.json, else label_2/)
    gt_kind : 'kitti', 'kitti-tracking', 'cityscapes' or 'apollocar3d'
    gt_dir : the ground-truth folder (ApolloCar3D: its keypoint file)
    options : threshold and class filter
    source_options : further arguments of the ground-truth source (``car_models``, ``cameras`` for
        'apollocar3d')

    Raises
    ------
    EvaluationInputError, FormatError
        See :func:`load_predictions`, :func:`open_ground_truth` and :func:`evaluate`; also when the
        predictions folder is the ground-truth folder, or one is inside the other (a folder scored against
        itself).
    """
    _ensure_not_self(Path(out_dir), Path(gt_dir))
    predictions = load_predictions(out_dir)
    return evaluate(predictions, open_ground_truth(gt_kind, gt_dir, **source_options), options)


def _ensure_not_self(out_dir: Path, gt_dir: Path) -> None:
    """Refuse to score a folder against itself: predictions and ground truth the same folder or nested."""
    pred, truth = out_dir.resolve(), gt_dir.resolve()
    if pred == truth or pred.is_relative_to(truth) or truth.is_relative_to(pred):
        relation = ("is" if pred == truth else "is inside" if pred.is_relative_to(truth) else "contains")
        raise EvaluationInputError(
            f"{out_dir}: the predictions folder {relation} the ground-truth folder {gt_dir}; it would be scored "
            f"against itself. Give the fit output folder and a separate ground-truth folder.")
