"""Scoring fitted cuboids against KITTI and Cityscapes 3D ground truth (paper section "Evaluation Metrics").

Layers, each a small module: :mod:`.iou` (exact 3D IoU with full
rotations; KITTI's yaw-only variant), :mod:`.metrics` (IoU, sIoU, E_R, E_t, E_d, E_comb as pure
functions), :mod:`.predictions` (results read into one per-image form, beside the ground truth's,
:mod:`toosicubix.formats.ground_truth`),
:mod:`.matching` (Hungarian pairing on 2D IoU), :mod:`.evaluate` (the pipeline) and :mod:`.report`
(aggregates, table, JSON, CSV). Nothing here imports the solver or the CLI.

Example
-------
>>> from toosicubix.evaluation import EvalOptions, evaluate_folder, format_report
>>> result = evaluate_folder("toosicubix-out", "kitti", "data/kitti", EvalOptions(min_iou=0.5))  # doctest: +SKIP
>>> print(format_report(result))  # doctest: +SKIP
"""

from __future__ import annotations

from toosicubix.evaluation.evaluate import EvalOptions, evaluate, evaluate_folder
from toosicubix.evaluation.iou import intersection_volume_3d, iou_3d, iou_bev_height_yaw
from toosicubix.evaluation.matching import Matching, box_iou_matrix, match_boxes
from toosicubix.evaluation.metrics import (
    ObjectMetrics,
    combined_error,
    dimension_error,
    object_metrics,
    rotation_error_deg,
    scale_factor,
    scaled_iou,
    translation_error,
)
from toosicubix.evaluation.predictions import (
    Predictions,
    PredImage,
    PredObject,
    load_predictions,
    predictions_from_results,
)
from toosicubix.evaluation.records import EvaluationResult, MatchedObject, UnscoredObject
from toosicubix.evaluation.report import format_report, result_to_csv, result_to_json, summarize, write_csv, write_json

__all__ = [
    "EvalOptions", "EvaluationResult", "GroundTruthSource",
    "MatchedObject", "Matching",
    "ObjectMetrics", "PredImage", "PredObject", "Predictions", "UnscoredObject", "box_iou_matrix", "combined_error",
    "dimension_error", "evaluate", "evaluate_folder", "format_report", "intersection_volume_3d", "iou_3d",
    "iou_bev_height_yaw", "load_predictions", "match_boxes", "object_metrics", "open_ground_truth",
    "predictions_from_results",
    "result_to_csv", "result_to_json", "rotation_error_deg", "scale_factor", "scaled_iou", "summarize",
    "translation_error", "write_csv", "write_json",
]
