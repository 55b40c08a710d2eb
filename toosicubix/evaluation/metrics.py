"""Per-object error metrics of the paper's section "Evaluation Metrics", as pure functions.

All take the prediction first and the ground truth second, both posed in the same camera frame.
Translations are bottom-face centres ``t_cam_vehicle``; dimensions are ``(dx, dy, dz)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from toosicubix.evaluation.iou import iou_3d, iou_bev_height_yaw
from toosicubix.geometry import Cuboid, depth_reversed_twin, geodesic_angle, wrap_angle, ypr_from_R_cam_vehicle


def rotation_error_deg(R_pred: np.ndarray, R_gt: np.ndarray) -> float:
    """E_R: the angle of ``R_pred @ R_gt.T`` (geodesic distance on SO(3)).

    Parameters
    ----------
    R_pred, R_gt : (3, 3) rotations ``R_cam_vehicle``

    Returns
    -------
    float, degrees in [0, 180]
    """
    return float(np.degrees(geodesic_angle(R_pred, R_gt)))


def twin_rotation_error_deg(pred: Cuboid, gt: Cuboid) -> float:
    """E_R (degrees) against the ground truth's depth-reversed twin
    (:func:`toosicubix.geometry.depth_reversed_twin`): small when the prediction is the pose the clicks show and
    the ground truth its mirror image in depth."""
    R_twin, _ = depth_reversed_twin(gt.R_cam_vehicle, gt.t_cam_vehicle, gt.dimensions)
    return rotation_error_deg(pred.R_cam_vehicle, R_twin)


def yaw_error_deg(R_pred: np.ndarray, R_gt: np.ndarray) -> float:
    """The size of the KITTI yaw (``rotation_y``, about the camera's y axis) difference, wrapped, in degrees
    (0 to 180) of the two (3, 3) ``R_cam_vehicle``: the part of E_R that KITTI's labels, which have no pitch or
    roll, can score.
    """
    difference = ypr_from_R_cam_vehicle(R_pred)[0] - ypr_from_R_cam_vehicle(R_gt)[0]
    return float(abs(np.degrees(wrap_angle(difference))))


def symmetric_twin(pred: Cuboid, gt: Cuboid, heading: str) -> Cuboid:
    """The prediction as the ground truth's class lets it be: turned about its own up axis (through its bottom
    centre, which leaves the box where it is) by the angle that brings it nearest the ground truth's rotation, for a
    class whose ends are alike (``axial``: 0 or 180 degrees, a barrier) or that has no yaw (``none``: any angle, a
    traffic cone); unchanged for a class with a front. E_R and the yaw's error then count only what the class has."""
    if heading == "directed":
        return pred
    M = pred.R_cam_vehicle.T @ gt.R_cam_vehicle  # (3, 3): the gt's rotation in the prediction's vehicle frame
    if heading == "axial":
        theta = 0.0 if M[0, 0] + M[1, 1] >= 0.0 else np.pi
    else:  # the turn about z maximizing trace(Rz(theta)^T M)
        theta = float(np.arctan2(M[1, 0] - M[0, 1], M[0, 0] + M[1, 1]))
    c, s_ = np.cos(theta), np.sin(theta)
    Rz = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    return Cuboid(pred.R_cam_vehicle @ Rz, pred.t_cam_vehicle, pred.dimensions)


def heading_error_deg(e_yaw_deg: float, heading: str) -> float | None:
    """The heading error (degrees) of a class whose yaw is determined as ``heading`` says
    (:data:`toosicubix.vocabulary.HEADINGS`), from the KITTI yaw's error ``e_yaw_deg`` (0 to 180): that error for a
    class with a front ('directed'), its distance from 0 or 180 for one whose ends are alike ('axial', 0 to 90), None
    for one without a yaw ('none', a traffic cone)."""
    if heading == "none":
        return None
    if heading == "axial":
        return float(min(e_yaw_deg, 180.0 - e_yaw_deg))
    return float(e_yaw_deg)


def translation_error(t_pred: np.ndarray, t_gt: np.ndarray) -> float:
    """E_t = ||t_gt - t_pred|| / ||t_gt||: relative translation error, unitless, >= 0.

    Parameters
    ----------
    t_pred, t_gt : (3,) bottom centres in the camera frame, metres (``t_gt`` not zero)
    """
    t_gt = np.asarray(t_gt, dtype=float)
    return float(np.linalg.norm(t_gt - np.asarray(t_pred, dtype=float)) / np.linalg.norm(t_gt))


def dimension_error(d_pred: np.ndarray, d_gt: np.ndarray) -> float:
    """E_d = ||d_gt - d_pred|| / ||d_gt||: relative dimension error, unitless, >= 0.

    Parameters
    ----------
    d_pred, d_gt : (3,) ``(dx, dy, dz)`` metres
    """
    d_gt = np.asarray(d_gt, dtype=float)
    return float(np.linalg.norm(d_gt - np.asarray(d_pred, dtype=float)) / np.linalg.norm(d_gt))


def combined_error(e_t: float, e_d: float, e_r_deg: float) -> float:
    """E_comb = (E_t + E_d + E_R / 180) / 3, unitless, >= 0 (E_R in degrees)."""
    return (e_t + e_d + e_r_deg / 180.0) / 3.0


def scale_factor(t_pred: np.ndarray, t_gt: np.ndarray) -> float:
    """s* = ||t_gt|| / ||t_pred||, the scale that puts the prediction at the ground truth's distance.

    Returns 1.0 when ``t_pred`` is zero (no scale can be inferred).
    """
    norm_pred = float(np.linalg.norm(t_pred))
    return float(np.linalg.norm(t_gt)) / norm_pred if norm_pred > 0.0 else 1.0


def scaled_iou(pred: Cuboid, gt: Cuboid) -> float:
    """sIoU: exact 3D IoU of ``(R, s* t, s* d)`` against the ground truth, in [0, 1].

    Scaling ``t`` and ``d`` together scales the whole cuboid about the camera centre, which leaves its
    image unchanged: sIoU scores the 8 degrees of freedom a single image can determine.
    """
    return iou_3d(pred.scaled(scale_factor(pred.t_cam_vehicle, gt.t_cam_vehicle)), gt)


@dataclass(frozen=True)
class ObjectMetrics:
    """Every metric of one prediction against its ground truth.

    Attributes
    ----------
    iou : exact 3D IoU, full rotations, [0, 1]
    siou : scaled IoU, [0, 1]
    e_r_deg : rotation error, degrees in [0, 180]
    e_t : relative translation error, unitless
    e_d : relative dimension error, unitless
    e_comb : combined error, unitless
    iou_kitti : KITTI-style yaw-only bird's-eye x height IoU, [0, 1] (for comparison with KITTI tools)
    e_yaw_deg : the KITTI yaw's error alone (:func:`yaw_error_deg`), degrees in [0, 180]
    """

    iou: float
    siou: float
    e_r_deg: float
    e_t: float
    e_d: float
    e_comb: float
    iou_kitti: float
    e_yaw_deg: float


#: Metric names in report order, as in the paper's table (plus KITTI's yaw-only IoU and the yaw's error alone).
METRIC_NAMES = ("iou", "siou", "e_r_deg", "e_t", "e_d", "e_comb", "iou_kitti", "e_yaw_deg")


def object_metrics(pred: Cuboid, gt: Cuboid) -> ObjectMetrics:
    """All metrics of ``pred`` against ``gt``, both in the same camera frame."""
    e_r_deg = rotation_error_deg(pred.R_cam_vehicle, gt.R_cam_vehicle)
    e_t = translation_error(pred.t_cam_vehicle, gt.t_cam_vehicle)
    e_d = dimension_error(pred.dimensions, gt.dimensions)
    return ObjectMetrics(
        iou=iou_3d(pred, gt), siou=scaled_iou(pred, gt), e_r_deg=e_r_deg, e_t=e_t, e_d=e_d,
        e_comb=combined_error(e_t, e_d, e_r_deg), iou_kitti=iou_bev_height_yaw(pred, gt),
        e_yaw_deg=yaw_error_deg(pred.R_cam_vehicle, gt.R_cam_vehicle),
    )
