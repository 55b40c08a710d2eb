"""What an evaluation produces: one record per matched object, the unmatched ones, and the counts."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from toosicubix.evaluation.metrics import ObjectMetrics
from toosicubix.geometry import Cuboid


@dataclass(frozen=True)
class MatchedObject:
    """A prediction paired with a ground-truth object, and its metrics.

    Attributes
    ----------
    image_id, pred_id : the prediction's image and vehicle id
    gt_index : the object's position in its ground-truth image (0-based, all classes counted)
    gt_track_id : KITTI tracking track id or Cityscapes instanceId, else None
    cls : ground-truth class; pred_cls : the prediction's class (KITTI type or prototype)
    subtype : Cityscapes ``3d.type``, else ''
    occlusion : KITTI level 0-3 or None; occlusion_fraction : Cityscapes fraction or None
    truncation : as the ground truth states it, or None
    depth : z of the ground truth's bottom centre in the camera frame, metres
    iou_2d : 2D box IoU of the pairing
    metrics : IoU, sIoU, E_R, E_t, E_d, E_comb, KITTI's yaw-only IoU
    pred, gt : the two cuboids in the camera frame where the prediction's ``K`` applies
    yaw_only : the prediction came from a KITTI label file (no pitch or roll)
    pred_source, gt_source : where each was read
    keypoints : how many keypoints people labelled on the ground-truth object (ApolloCar3D), else None
    keypoints_hidden : how many of those the ground-truth pose turns away from the camera (ApolloCar3D), else None
    e_r_twin_deg : the geodesic angle (degrees) between the prediction and the ground truth's depth-reversed twin
        (:func:`toosicubix.geometry.depth_reversed_twin`) where ``keypoints_hidden`` is given, else None
    keypoints_off_rays_m : how far (metres, RMS) the labelled keypoints lie from their rays at the ground-truth pose
        (ApolloCar3D with its cameras), else None
    e_heading_deg : the heading error of its class (:func:`toosicubix.evaluation.metrics.heading_error_deg`: the yaw's
        error, modulo 180 degrees for a barrier), None for a class without a yaw (a traffic cone)
    """

    image_id: str
    pred_id: str
    gt_index: int
    gt_track_id: int | None
    cls: str
    pred_cls: str
    subtype: str
    occlusion: int | None
    occlusion_fraction: float | None
    truncation: float | None
    depth: float
    iou_2d: float
    metrics: ObjectMetrics
    pred: Cuboid
    gt: Cuboid
    yaw_only: bool
    pred_source: str
    gt_source: str
    keypoints: int | None = None
    keypoints_hidden: int | None = None
    e_r_twin_deg: float | None = None
    keypoints_off_rays_m: float | None = None
    e_heading_deg: float | None = None

    def row(self) -> dict[str, Any]:
        """The flat record (one CSV row): identifiers, conditions, then the metrics."""
        m = self.metrics
        return {
            "image_id": self.image_id, "pred_id": self.pred_id, "gt_index": self.gt_index,
            "gt_track_id": self.gt_track_id, "class": self.cls, "pred_class": self.pred_cls, "subtype": self.subtype,
            "occlusion": self.occlusion, "occlusion_fraction": self.occlusion_fraction,
            "truncation": self.truncation, "depth": self.depth, "iou_2d": self.iou_2d,
            "iou": m.iou, "siou": m.siou, "e_r_deg": m.e_r_deg, "e_t": m.e_t, "e_d": m.e_d, "e_comb": m.e_comb,
            "iou_kitti": m.iou_kitti, "e_yaw_deg": m.e_yaw_deg, "yaw_only": self.yaw_only,
            "pred_source": self.pred_source, "gt_source": self.gt_source, "keypoints": self.keypoints,
            "keypoints_hidden": self.keypoints_hidden, "e_r_twin_deg": self.e_r_twin_deg,
            "keypoints_off_rays_m": self.keypoints_off_rays_m, "e_heading_deg": self.e_heading_deg,
        }


@dataclass(frozen=True)
class UnscoredObject:
    """A prediction or ground-truth object that got no partner, or a prediction that failed.

    Attributes
    ----------
    image_id : the image
    id : prediction id, or the ground-truth index as text
    cls : its class
    box2d : (4,) ``(x1, y1, x2, y2)`` pixels, or None
    best_iou_2d : best 2D IoU against any candidate of the other side (0 when there is none)
    reason : why it is not scored
    source : where it was read
    """

    image_id: str
    id: str
    cls: str
    box2d: np.ndarray | None
    best_iou_2d: float
    reason: str
    source: str

    def row(self) -> dict[str, Any]:
        return {
            "image_id": self.image_id, "id": self.id, "class": self.cls,
            "box2d": None if self.box2d is None else [float(v) for v in self.box2d],
            "best_iou_2d": self.best_iou_2d, "reason": self.reason, "source": self.source,
        }


@dataclass(frozen=True)
class EvaluationResult:
    """Everything an evaluation found.

    Attributes
    ----------
    matched : one record per matched pair, in image then prediction order
    unmatched_pred : predictions (status ok) without a ground-truth partner
    unmatched_gt : ground-truth objects of the scored classes without a partner
    failed_pred : predictions with status 'failed' (never matched)
    gt_excluded : ground-truth objects not scored, by class (class filter, DontCare, ignore regions)
    n_images : predicted images scored
    n_gt_images : images the ground truth holds
    n_gt_images_without_pred : ground-truth images with no predictions (normal; not scored)
    occlusion_kind : 'level' (KITTI), 'fraction' (Cityscapes) or None (the ground truth has no occlusion)
    warnings : things the user should know (frames, calibration), one line each
    settings : what was compared with what, and how
    """

    matched: tuple[MatchedObject, ...]
    unmatched_pred: tuple[UnscoredObject, ...]
    unmatched_gt: tuple[UnscoredObject, ...]
    failed_pred: tuple[UnscoredObject, ...]
    gt_excluded: dict[str, int]
    n_images: int
    n_gt_images: int
    n_gt_images_without_pred: int
    occlusion_kind: str | None
    warnings: tuple[str, ...] = ()
    settings: dict[str, Any] = field(default_factory=dict)
