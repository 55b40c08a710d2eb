"""Hungarian pairing by 2D box IoU, with a threshold."""

from __future__ import annotations

import numpy as np
import pytest

from toosicubix.evaluation.matching import box_iou_matrix, match_boxes
from toosicubix.geometry import box2d_iou


def test_iou_matrix_agrees_with_box2d_iou(rng):
    a = np.sort(rng.uniform(0, 100, size=(5, 2, 2)), axis=1).reshape(5, 4)[:, [0, 2, 1, 3]]
    b = np.sort(rng.uniform(0, 100, size=(4, 2, 2)), axis=1).reshape(4, 4)[:, [0, 2, 1, 3]]
    expected = np.array([[box2d_iou(x, y) for y in b] for x in a])
    np.testing.assert_allclose(box_iou_matrix(a, b), expected, atol=1e-12)


def test_degenerate_boxes_have_iou_zero():
    assert box_iou_matrix([[0, 0, 0, 10]], [[0, 0, 0, 10]])[0, 0] == 0.0


def test_hungarian_beats_greedy():
    """Greedy takes p0-g0 (IoU 0.82) and leaves p1 alone; the optimum pairs p0-g1 and p1-g0."""
    gt = np.array([[0, 0, 10, 10], [2, 0, 12, 10]], dtype=float)
    pred = np.array([[1, 0, 11, 10], [-1.5, 0, 8.5, 10]], dtype=float)
    iou = box_iou_matrix(pred, gt)
    assert iou[0, 0] > iou[1, 0] and iou[1, 1] < 0.5  # greedy's trap
    m = match_boxes(pred, gt, 0.5)
    assert [(i, j) for i, j, _ in m.pairs] == [(0, 1), (1, 0)]
    assert m.unmatched_pred == () and m.unmatched_gt == ()


def test_threshold_and_unmatched_lists():
    gt = np.array([[0, 0, 10, 10], [100, 100, 110, 110], [200, 0, 210, 10]], dtype=float)
    pred = np.array([[0, 0, 10, 10], [104, 100, 114, 110], [500, 500, 510, 510]], dtype=float)
    m = match_boxes(pred, gt, 0.5)  # pred 1 vs gt 1: IoU 60 / 140 < 0.5
    assert [(i, j) for i, j, _ in m.pairs] == [(0, 0)]
    assert m.pairs[0][2] == pytest.approx(1.0)
    assert m.unmatched_pred == (1, 2) and m.unmatched_gt == (1, 2)
    m = match_boxes(pred, gt, 0.4)
    assert [(i, j) for i, j, _ in m.pairs] == [(0, 0), (1, 1)]


def test_zero_threshold_never_pairs_disjoint_boxes():
    m = match_boxes(np.array([[0, 0, 1, 1.0]]), np.array([[5, 5, 6, 6.0]]), 0.0)
    assert m.pairs == () and m.unmatched_pred == (0,) and m.unmatched_gt == (0,)


def test_empty_sides():
    m = match_boxes(np.zeros((0, 4)), np.array([[0, 0, 1, 1.0]]), 0.5)
    assert m.pairs == () and m.unmatched_gt == (0,)
    m = match_boxes(np.array([[0, 0, 1, 1.0]]), np.zeros((0, 4)), 0.5)
    assert m.unmatched_pred == (0,)
