"""Pairing predictions with ground-truth objects of one image by 2D box IoU (Hungarian assignment)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment


@dataclass(frozen=True)
class Matching:
    """The outcome of pairing one image's predictions with its ground truth.

    Attributes
    ----------
    pairs : (prediction index, ground-truth index, 2D IoU) for every accepted pair
    unmatched_pred : indices of predictions left without a partner
    unmatched_gt : indices of ground-truth objects left without a partner
    """

    pairs: tuple[tuple[int, int, float], ...]
    unmatched_pred: tuple[int, ...]
    unmatched_gt: tuple[int, ...]


def box_iou_matrix(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """IoU of every pair of axis-aligned boxes.

    Parameters
    ----------
    boxes_a : (N, 4) ``(x1, y1, x2, y2)`` pixels
    boxes_b : (M, 4) likewise

    Returns
    -------
    (N, M) array in [0, 1]; 0 where a box has no area
    """
    a = np.asarray(boxes_a, dtype=float).reshape(-1, 4)[:, None, :]
    b = np.asarray(boxes_b, dtype=float).reshape(-1, 4)[None, :, :]
    iw = np.clip(np.minimum(a[..., 2], b[..., 2]) - np.maximum(a[..., 0], b[..., 0]), 0.0, None)
    ih = np.clip(np.minimum(a[..., 3], b[..., 3]) - np.maximum(a[..., 1], b[..., 1]), 0.0, None)
    inter = iw * ih
    area_a = np.clip(a[..., 2] - a[..., 0], 0.0, None) * np.clip(a[..., 3] - a[..., 1], 0.0, None)
    area_b = np.clip(b[..., 2] - b[..., 0], 0.0, None) * np.clip(b[..., 3] - b[..., 1], 0.0, None)
    union = area_a + area_b - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0.0)


def match_boxes(pred_boxes: np.ndarray, gt_boxes: np.ndarray, min_iou: float = 0.5) -> Matching:
    """One-to-one pairing that maximises the summed 2D IoU over pairs with IoU >= ``min_iou``.

    Pairs below the threshold (and pairs that do not overlap at all, whatever the threshold) are
    never accepted; their entries are zeroed before the assignment, so they cannot displace a pair
    that passes.

    Parameters
    ----------
    pred_boxes : (N, 4) ``(x1, y1, x2, y2)`` pixels
    gt_boxes : (M, 4) likewise
    min_iou : threshold in [0, 1]

    Returns
    -------
    Matching, pairs sorted by prediction index
    """
    n, m = len(pred_boxes), len(gt_boxes)
    if n == 0 or m == 0:
        return Matching((), tuple(range(n)), tuple(range(m)))
    iou = box_iou_matrix(pred_boxes, gt_boxes)
    gain = np.where((iou >= min_iou) & (iou > 0.0), iou, 0.0)
    rows, cols = linear_sum_assignment(gain, maximize=True)
    pairs = tuple(sorted((int(i), int(j), float(iou[i, j])) for i, j in zip(rows, cols, strict=True)
                         if gain[i, j] > 0.0))
    paired_pred = {i for i, _, _ in pairs}
    paired_gt = {j for _, j, _ in pairs}
    return Matching(
        pairs=pairs,
        unmatched_pred=tuple(i for i in range(n) if i not in paired_pred),
        unmatched_gt=tuple(j for j in range(m) if j not in paired_gt),
    )
