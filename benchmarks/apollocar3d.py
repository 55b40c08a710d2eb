"""Accuracy of ToosiCubix on real human clicks: ApolloCar3D (half of its validation images).

One command: import the keypoints (``import coco``), fit (``fit``), score (``eval --apollocar3d``), with the
paper's six metrics (mean and median) by number of labelled keypoints and by depth, beside the paper's KITTI
row. The rules that fixed every choice before any result was seen are in ``benchmarks/decisions.md``:

- images sorted by file name; positions learned on the even ones (learning half), scored on the odd ones
  (comparison half): the out-of-sample figures;
- the bundled ``apollocar3d-66`` positions, learned from all 100 images, scored on all of them: in-sample for
  the positions, and said so; on any other folder laid out the same way (such as the held-out half of the split)
  the same rows score the bundled positions out of sample, and the benchmark says which it is
  (:data:`BUNDLED_LEARNED_ON`);
- scored cars: at least 10 labelled keypoints; a car that fails to fit counts as not fitted. Beside the figures,
  the cars whose ground truth contradicts their clicks (rule 6: keypoints off their rays at it) or hides them
  (rule 17: labelled keypoints on faces it turns away from the camera) are counted, and scored apart.

Rows: the keypoints with ``fit``'s default settings (the targets' row: the size prior, the click noise and the
camera's road normal estimated from the batch, rule 7); the same with the chi-square test of each fit's residuals
widening the misfits' sigmas (``--misfit-level 0.99``, rule 8); with each car type its own prototype, its size
prior measured on the learning images' cars (rule 16: not a default, see benchmarks/decisions.md); without the road
normal
(``--road-normal none``, the default before rule 7); with the licence plates' width (``--option plates``); with
the camera's road normal taken
from the ground truth (the median up axis of the learning half's cars, or of all for the in-sample half) instead
of the batch: a ground block without camera height, vehicles upright on a road of that normal within 2 degrees,
the normal known within 3; and the paper's part vocabulary (``apollocar3d-66-paper``: mirror pairs as symmetry
pairs), alone and with the wheel centres as hubs, the configuration that failed in issue 14. Issue 36's rows: the
upright term weighed against the click noise (``--upright-weight clicks``, rule 23); without it (a diagnostic: the
batch's normal still places the starts and judges plausibility, vehicles "upright within 180 degrees"); and every
car of the half fitted, those with fewer than 10 keypoints too, which are reported apart (a diagnostic).

Issue 36's diagnostics, per row and half: where the rotation error comes from (``rotation_breakdown``: E_R, the yaw
and up-axis errors and the yaw calibration by keypoints, depth, view and whether the clicks fix pitch and roll);
what the upright term does to the cars whose clicks fix their own tilt (``upright_cost``, across the rows); the cars
with fewer than 10 keypoints (``few_keypoints``); and what one keypoint on the far end does for an end-on car
clicked on its near end only (``far_end``: the default row's cars refitted from their near-end keypoints, then with
one more).

Run from the repository root (about eight minutes on 2 cores):

    python benchmarks/apollocar3d.py [--jobs 2] [--json benchmarks/results/apollocar3d.json]
    python benchmarks/apollocar3d.py --keypoints OTHER/apollocar3d_val_test.json   # another folder, same layout
    python benchmarks/apollocar3d.py --design   # rule 16's design run: learning half only, in quarters
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import default_data_dir, machine

import toosicubix.pipeline.road_normal as road_normal_module
from toosicubix.annotations.mapping import MappingFile, load_mapping
from toosicubix.annotations.priors_file import load_priors, load_priors_file
from toosicubix.annotations.schema import SCHEMA_VERSION
from toosicubix.errors import InputError
from toosicubix.evaluation import EvalOptions, evaluate, load_predictions
from toosicubix.formats.apollocar3d import PROTOTYPE_OF_TYPE, keypoint_samples, read_apollocar3d, read_car_models
from toosicubix.formats.cameras import load_cameras
from toosicubix.formats.coco import coco_to_annotations
from toosicubix.formats.ground_truth import ApolloCar3DGroundTruth
from toosicubix.geometry import depth_reversed_twin
from toosicubix.model import GroundOverride
from toosicubix.parts.learned import (  # CONTRADICTION_M: rule 6's 0.5 m
    CONTRADICTION_M,
    contradicting,
    hidden_by_ground_truth,
    hides_clicks,
    learn_positions,
    learned_mapping,
    offset_from_ray,
)
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.priors.estimation import (
    DimensionSamples,
    apollocar3d_rows,
    default_method,
    estimate_priors,
    priors_document,
    write_priors_file,
)
from toosicubix.size_priors import bundled_priors_path
from toosicubix.solver.fit import SolverOptions

PAPER_KITTI = {"iou": 0.29, "siou": 0.77, "e_r_deg": 3.16, "e_t": 0.10, "e_d": 0.14, "e_comb": 0.10}
METRICS = ("iou", "siou", "e_r_deg", "e_t", "e_d", "e_comb")
MIN_KEYPOINTS = 10
#: SHA-256 of the sorted image file names, one per line, of the folder the bundled ``apollocar3d-66`` positions
#: were learned from (``../shared/data/apollocar3d``, 100 images). The "all" rows of any other folder score those
#: positions out of sample.
BUNDLED_LEARNED_ON = "de6252f8c68cb029f01f438d7487fec6c0515c6a08f5727645a365e06c0ac3f7"
#: A contradicting car's clicks are explained by another pose when they lie this close (RMS, metres) to their rays
#: at it: half of rule 6's threshold (a diagnostic written after looking at those cars; it changes no figure).
EXPLAINED_M = 0.25
KEYPOINT_BINS = ((10, 15), (15, 20), (20, 30), (30, 67))
DEPTH_BINS = ((0, 20), (20, 40), (40, 60), (60, np.inf))
#: The view: the angle between a car's ground-truth heading and the line of sight, both in the road plane, folded to
#: 0-90 degrees (0: seen end-on, front or rear; 90: seen side-on).
VIEW_BINS = ((0, 30), (30, 60), (60, 90.01))
#: A car's labelled keypoints are all on one end when every one of them sits this far (a fraction of the length)
#: from the middle on the same side (a rear view's lamps, plate, boot and rear glass; a door or a wheel is not).
END_FRACTION = 0.15


@dataclass(frozen=True)
class Row:
    label: str
    mapping: str  # a bundled mapping, or 'learned' (the learning half's positions)
    options: tuple[str, ...] = ()
    ground: bool = False  # the camera's road normal (learned, see road_normal) as every image's ground block
    batch_normal: bool = False  # the road normal estimated from the batch's own fits (rule 7)
    misfit_level: float | None = None  # the chi-square test of each fit's residuals (rule 8)
    own_priors: bool = False  # each car type its own prototype, size priors measured on the learning images (rule 16)
    upright_weight: str = "lambda"  # SolverOptions.upright_weight (rule 23)
    upright_sigma_deg: float | None = None  # the batch normal's upright sigma instead of road_normal's (a diagnostic)
    every_car: bool = False  # fit every car of the half, also those with fewer than 10 keypoints (a diagnostic)
    mirror_pairs: bool = False  # positions learned with `learn-parts --mirror-pairs` (a diagnostic, rule 32's run)


ROWS = (
    Row("keypoints, default settings", "apollocar3d-66", batch_normal=True),
    Row("keypoints, --upright-weight clicks", "apollocar3d-66", batch_normal=True, upright_weight="clicks"),
    Row("keypoints, no upright term", "apollocar3d-66", batch_normal=True, upright_sigma_deg=180.0),
    Row("keypoints, every car fitted", "apollocar3d-66", batch_normal=True, every_car=True),
    Row("keypoints, mirror pairs' positions averaged", "apollocar3d-66", batch_normal=True, mirror_pairs=True),
    Row("keypoints, car types' own priors", "apollocar3d-66", batch_normal=True, own_priors=True),
    Row("keypoints, --misfit-level 0.99", "apollocar3d-66", batch_normal=True, misfit_level=0.99),
    Row("keypoints, --road-normal none", "apollocar3d-66"),
    Row("keypoints + plate width", "apollocar3d-66", ("plates",), batch_normal=True),
    Row("keypoints + ground-truth road normal", "apollocar3d-66", (), True),
    Row("paper vocabulary (symmetry pairs)", "apollocar3d-66-paper", batch_normal=True),
    Row("paper vocabulary + wheel hubs", "apollocar3d-66-paper", ("hubs",), batch_normal=True),
)

#: Rule 16's prototypes: each car-model type its own, its size prior measured on the learning images' cars.
OWN_PROTOTYPES = {"2x": "ApolloCar3D hatchback", "3x": "ApolloCar3D saloon", "SUV": "ApolloCar3D SUV"}


@dataclass(frozen=True)
class Half:
    """Which images a set of rows learns positions (and rule 16's priors) on, and which it scores."""

    name: str  # 'odd' (comparison half), 'all' (the bundled positions, in sample) or 'design' (rule 16)
    learn: list
    score: list
    bundled: bool  # the default rows take the bundled positions (learned on all 100 images) as they are


#: The road normal's uncertainty in the ground block of the row with it (degrees), fixed before that row was
#: first run from the spread of the learning half's up vectors about their median (median 2.0, 90 %: 5.2 deg).
NORMAL_SIGMA_DEG = 3.0


def road_normal(images: list) -> tuple[float, float, float]:
    """The camera's road normal (camera frame): the median of the ground-truth up axes of ``images``' cars,
    normalised. One camera rig: a user of such data gives it once (``--road-normal``)."""
    ups = np.array([car.R_cam_vehicle[:, 2] for im in images for car in im.cars])
    n = np.median(ups, axis=0)
    return tuple(float(v) for v in n / np.linalg.norm(n))


def up_axis_scatter(images: list, normal: tuple[float, float, float], scored: set[str]) -> dict[str, float]:
    """Degrees between each scored car's ground-truth up axis and the camera's road ``normal`` (:func:`road_normal`),
    mean, median and 90th percentile: what a fit that stood every car upright on that road would leave of E_R's
    up-axis part. Beside it, the mean angle to the mean ground-truth up axis of the other cars of the car's image
    (``image_others_mean_deg``; the camera's normal for a car alone in its image), what a road normal per image known
    perfectly from its other cars would leave, and to the mean of all the image's cars, itself included
    (``image_all_mean_deg``: that normal is partly the car's own answer). A diagnostic of the data that looks at no
    fit."""
    n = np.asarray(normal, dtype=float)
    angles, others, everyone = [], [], []
    for im in images:
        ups = np.array([c.R_cam_vehicle[:, 2] for c in im.cars])
        for i, car in enumerate(im.cars):
            if str(car.id) not in scored:
                continue
            rest = np.delete(ups, i, axis=0)
            angles.append(_angle_deg(ups[i], n))
            others.append(_angle_deg(ups[i], rest.mean(axis=0)) if len(rest) else angles[-1])
            everyone.append(_angle_deg(ups[i], ups.mean(axis=0)))
    return {"cars": len(angles), "mean_deg": float(np.mean(angles)), "median_deg": float(np.median(angles)),
            "p90_deg": float(np.percentile(angles, 90)), "image_others_mean_deg": float(np.mean(others)),
            "image_all_mean_deg": float(np.mean(everyone))}


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Degrees between two directions (3,), neither necessarily of unit length."""
    return float(np.degrees(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0))))


def labelled_counts(coco: dict) -> dict[str, int]:
    return {str(a["id"]): sum(1 for v in a["keypoints"][2::3] if v > 0) for a in coco["annotations"]}


def subset(document: dict, image_ids: set[str], keep: set[str]) -> dict:
    images = []
    for im in document["images"]:
        if im["id"] in image_ids:
            images.append({**im, "vehicles": [v for v in im["vehicles"] if v["id"] in keep]})
    return {"toosicubix": SCHEMA_VERSION, "images": images}


def stats(objects: list[dict]) -> dict:
    out: dict = {"n": len(objects)}
    for m in METRICS:
        values = np.array([o[m] for o in objects], dtype=float)
        out[m] = {"mean": float(values.mean()) if len(values) else None,
                  "median": float(np.median(values)) if len(values) else None}
    return out


@contextmanager
def batch_upright_sigma(degrees: float | None) -> Iterator[None]:
    """Within it, a road normal estimated from the batch stands vehicles upright within ``degrees`` instead of
    :data:`toosicubix.pipeline.road_normal.UPRIGHT_SIGMA_DEG` (a diagnostic row's setting; None: as it is)."""
    if degrees is None:
        yield
        return
    kept = road_normal_module.UPRIGHT_SIGMA_DEG
    road_normal_module.UPRIGHT_SIGMA_DEG = degrees
    try:
        yield
    finally:
        road_normal_module.UPRIGHT_SIGMA_DEG = kept


def run_row(row: Row, half: str, keypoints_path: Path, folder: Path, mapping: MappingFile, cameras,
            image_ids: set[str], scored: set[str], counts: dict[str, int], jobs: int, options: SolverOptions,
            estimate_sigma: bool, contradicting: dict[str, str], normal: tuple[float, float, float],
            priors: Path | None = None, hiding: frozenset[str] = frozenset(),
            half_cars: set[str] | None = None) -> dict:
    """One row on one half: fit the half's scored cars (every car of the half, ``half_cars``, for an ``every_car``
    row), score those with at least :data:`MIN_KEYPOINTS` keypoints, and, for an ``every_car`` row, report the others
    apart (``few_keypoints``). The returned dict's ``_objects`` (the scored cars, one dict each) and ``_work`` (the
    row's folder) are for the cross-row diagnostics and are not written."""
    work = folder / f"{half}-{row.label.replace(' ', '_')}"
    work.mkdir(parents=True)
    document, summary = coco_to_annotations(keypoints_path, mapping, cameras, row.options)
    fitted_cars = (half_cars or scored) if row.every_car else scored
    annotations = work / "annotations.json"
    annotations.write_text(json.dumps(subset(document, image_ids, fitted_cars)))
    start = time.perf_counter()
    ground = (GroundOverride(normal=normal, normal_sigma_deg=NORMAL_SIGMA_DEG, upright_sigma_deg=2.0) if row.ground
              else None)
    if row.misfit_level is not None:
        options = replace(options, misfit_level=row.misfit_level)
    options = replace(options, upright_weight=row.upright_weight)
    with batch_upright_sigma(row.upright_sigma_deg):
        fit_file(annotations, work / "out", BatchSettings(priors=load_priors(priors), options=options, jobs=jobs,
                                                          estimate_click_sigma=estimate_sigma, ground=ground,
                                                          estimate_part_sigma=estimate_sigma,  # as `fit` (rule 33)
                                                          estimate_road_normal=row.batch_normal))
    seconds = time.perf_counter() - start
    n_up = np.asarray(normal, dtype=float)
    ends = clicked_ends(document, image_ids, fitted_cars)
    result = evaluate(load_predictions(work / "out"), ApolloCar3DGroundTruth(keypoints_path),
                      EvalOptions(classes=("Car",)))
    results = json.loads((work / "out" / "results.json").read_text())
    noise = results.get("click_noise") or (
        {**results["part_placement"], "source": "estimated with the parts' placement (rule 33)"}
        if "part_placement" in results else {"sigma_px": options.click_sigma, "source": "given"})
    fits = {(im["id"], v["id"]): v for im in results["images"] for v in im["vehicles"]}
    objects, few = [], []
    for m in result.matched:
        if m.pred_id not in fitted_cars:
            continue
        o = {"id": m.pred_id, "depth": m.depth, "keypoints": counts[m.pred_id], "type": m.subtype, **{
            "iou": m.metrics.iou, "siou": m.metrics.siou, "e_r_deg": m.metrics.e_r_deg, "e_t": m.metrics.e_t,
            "e_d": m.metrics.e_d, "e_comb": m.metrics.e_comb}}
        fit = fits[(m.image_id, m.pred_id)]
        sigma = (fit.get("sigma") or {}).get("yaw_deg")
        o["yaw_error_deg"], o["yaw_sigma_deg"] = m.metrics.e_yaw_deg, sigma  # the yaw's error alone, >= 0
        z_pred, z_gt = float(m.pred.t_cam_vehicle[2]), float(m.gt.t_cam_vehicle[2])
        o["depth_error_rel"] = (z_pred - z_gt) / z_gt  # signed: < 0 fitted nearer than the ground truth
        o["depth_error_m"], o["depth_sigma_m"] = abs(z_pred - z_gt), (fit.get("sigma") or {}).get("depth_m")
        up_pred, up_gt = m.pred.R_cam_vehicle[:, 2], m.gt.R_cam_vehicle[:, 2]
        o["tilt_error_deg"] = float(np.degrees(np.arccos(np.clip(up_pred @ up_gt, -1.0, 1.0))))
        if m.pred_id in hiding:
            o["fit_from_twin_deg"] = m.e_r_twin_deg  # evaluate's E_R against the ground truth's twin
        o["downweighted"] = len(fit.get("downweighted", []))
        o["misfit"] = bool((fit.get("residual_test") or {}).get("misfit"))
        o["view_deg"], o["facing"] = view_of(m.gt.R_cam_vehicle, m.gt.t_cam_vehicle, n_up)
        determined = (fit.get("observability") or {}).get("determined_by") or {}
        o["tilt_by_clicks"] = determined.get("pitch") == "clicks" and determined.get("roll") == "clicks"
        o["end"] = ends.get(m.pred_id)
        o["consistent"] = m.pred_id not in contradicting and m.pred_id not in hiding
        (objects if m.pred_id in scored else few).append(o)
    n_cars = len(scored)
    by_kp = {f"{lo}-{hi - 1}": stats([o for o in objects if lo <= o["keypoints"] < hi]) for lo, hi in KEYPOINT_BINS}
    by_depth = {(f"{lo:g}+ m" if np.isinf(hi) else f"{lo:g}-{hi:g} m"): stats(
        [o for o in objects if lo <= o["depth"] < hi]) for lo, hi in DEPTH_BINS}
    within = calibration(objects)
    depth_within = calibration(objects, "depth")
    agreeing = [o for o in objects if o["id"] not in contradicting]
    consistent = [o for o in agreeing if o["id"] not in hiding]
    hidden = [o for o in objects if o["id"] in hiding]
    return {
        "row": row.label, "half": half, "mapping": mapping.name, "priors": None if priors is None else {
            name: entry for name, entry in json.loads(priors.read_text())["prototypes"].items()
            if name in OWN_PROTOTYPES.values()}, "options": list(row.options),
        "ground": None if ground is None else ground.to_json(),
        "cars": n_cars, "fitted": len(objects), "fitted_share": len(objects) / n_cars if n_cars else None,
        "seconds": seconds, "import": summary.lines(), **stats(objects),
        "by_keypoints": by_kp, "by_depth": by_depth,
        "yaw_within_1_sigma": within[0], "yaw_within_2_sigma": within[1],
        "depth_within_1_sigma": depth_within[0], "depth_within_2_sigma": depth_within[1],
        "depth_error_rel_median_by_type": depth_bias(objects),
        "rotation_parts": rotation_parts(objects),
        "ground_truth_agrees": {"cars": len(agreeing), "contradicting": len(objects) - len(agreeing),
                                **stats(agreeing), "yaw_within_1_sigma": calibration(agreeing)[0],
                                "yaw_within_2_sigma": calibration(agreeing)[1],
                                "rotation_parts": rotation_parts(agreeing)},
        "ground_truth_hides": {"cars": len(hidden), "e_r_deg": stats(hidden)["e_r_deg"],
                               "fit_within_10_deg_of_twin": sum(o["fit_from_twin_deg"] <= 10 for o in hidden),
                               "fit_from_twin_deg": sorted(round(o["fit_from_twin_deg"], 1) for o in hidden)},
        "ground_truth_consistent": {"cars": len(consistent), "hiding": sum(o["id"] in hiding for o in objects),
                                    "hiding_not_contradicting": len(agreeing) - len(consistent), **stats(consistent),
                                    "yaw_within_1_sigma": calibration(consistent)[0],
                                    "yaw_within_2_sigma": calibration(consistent)[1],
                                    "rotation_parts": rotation_parts(consistent),
                                    "e_r_over_30_deg": int(sum(o["e_r_deg"] > 30 for o in consistent))},
        "e_r_over_30_deg": int(sum(o["e_r_deg"] > 30 for o in objects)),
        "e_r_over_30_deg_by_ground_truth": dict(Counter(contradicting.get(o["id"], "agrees with the clicks")
                                                        for o in objects if o["e_r_deg"] > 30)),
        "contradicting_by_kind": dict(Counter(contradicting[o["id"]] for o in objects if o["id"] in contradicting)),
        "click_noise": noise,
        "cars_with_downweighted_clicks": int(sum(o["downweighted"] > 0 for o in objects)),
        "misfits": int(sum(o["misfit"] for o in objects)),
        "rotation_breakdown": {"neither rule 6 nor 17 flags": rotation_breakdown(consistent),
                               "all cars": rotation_breakdown(objects)},
        "few_keypoints": few_keypoints(few) if row.every_car else None,
        "_objects": objects, "_work": work,
    }


def rotation_parts(objects: list[dict]) -> dict:
    """E_R's two parts, degrees, mean and median: the yaw error's size (what KITTI's labels can score) and the
    angle between the fitted and the ground-truth up axes (pitch and roll together)."""
    out = {}
    for key, values in (("abs_yaw_error_deg", [o["yaw_error_deg"] for o in objects]),
                        ("tilt_error_deg", [o["tilt_error_deg"] for o in objects])):
        out[key] = {"mean": float(np.mean(values)) if values else None,
                    "median": float(np.median(values)) if values else None}
    return out


def view_of(R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, normal: np.ndarray) -> tuple[float, float]:
    """A car's view (:data:`VIEW_BINS`), degrees, and ``heading . ray`` (> 0: it shows its rear), from its ground-truth
    pose (3, 3), (3,) and the camera's road ``normal`` (3,)."""
    ray = t_cam_vehicle / np.linalg.norm(t_cam_vehicle)
    heading = R_cam_vehicle[:, 0]
    h, r = heading - (heading @ normal) * normal, ray - (ray @ normal) * normal
    cos = abs(float(h @ r)) / (np.linalg.norm(h) * np.linalg.norm(r))
    return float(np.degrees(np.arccos(min(cos, 1.0)))), float(heading @ ray)


def clicked_ends(document: dict, image_ids: set[str], cars: set[str]) -> dict[str, str | None]:
    """Per car, 'front' or 'rear' when all its keypoint clicks sit on that end (their typical positions' length
    fractions beyond :data:`END_FRACTION` on one side), else None (plates count as keypoints at their centres)."""
    out = {}
    for im in document["images"]:
        if im["id"] not in image_ids:
            continue
        for v in im["vehicles"]:
            if v["id"] not in cars:
                continue
            x = [p["at"][0] for p in v["parts"] if p.get("at") is not None]
            out[v["id"]] = ("front" if x and min(x) > END_FRACTION else "rear" if x and max(x) < -END_FRACTION
                            else None)
    return out


def _group(objects: list[dict]) -> dict:
    """E_R (mean, median), its parts' means and the yaw calibration of a group of cars."""
    within = calibration(objects)
    return {"n": len(objects),
            "e_r_deg": {"mean": float(np.mean([o["e_r_deg"] for o in objects])) if objects else None,
                        "median": float(np.median([o["e_r_deg"] for o in objects])) if objects else None},
            "abs_yaw_error_deg": float(np.mean([o["yaw_error_deg"] for o in objects])) if objects else None,
            "tilt_error_deg": float(np.mean([o["tilt_error_deg"] for o in objects])) if objects else None,
            "yaw_within_1_sigma": within[0], "yaw_within_2_sigma": within[1]}


def rotation_breakdown(objects: list[dict]) -> dict[str, dict]:
    """Where the rotation error of ``objects`` comes from (issue 36, item 1): E_R, its yaw and up-axis parts and the
    yaw calibration, by labelled keypoints, by ground-truth depth, by view (:data:`VIEW_BINS`), and by whether the
    fit's clicks fix its pitch and roll themselves (both 'clicks' in its observability) or leave them to the road."""
    out = {"all": _group(objects)}
    for lo, hi in KEYPOINT_BINS:
        out[f"keypoints {lo}-{hi - 1}"] = _group([o for o in objects if lo <= o["keypoints"] < hi])
    for lo, hi in DEPTH_BINS:
        out["depth " + (f"{lo:g}+ m" if np.isinf(hi) else f"{lo:g}-{hi:g} m")] = _group(
            [o for o in objects if lo <= o["depth"] < hi])
    for lo, hi in VIEW_BINS:
        out[f"view {lo:g}-{min(hi, 90):g} deg"] = _group([o for o in objects if lo <= o["view_deg"] < hi])
    out["pitch and roll fixed by the clicks"] = _group([o for o in objects if o["tilt_by_clicks"]])
    out["pitch or roll left to the road"] = _group([o for o in objects if not o["tilt_by_clicks"]])
    return out


def few_keypoints(objects: list[dict]) -> dict:
    """The cars with fewer than :data:`MIN_KEYPOINTS` keypoints of an ``every_car`` row (issue 36, item 3): the six
    metrics, E_R's parts and the yaw calibration, for all and for those neither rule 6 nor rule 17 flags; by keypoint
    count; and for those whose keypoints all lie on one end (:func:`clicked_ends`) against the others."""
    consistent = [o for o in objects if o["consistent"]]
    return {"cars": len(objects), "flagged": len(objects) - len(consistent),
            "all": {**stats(objects), **_group(objects),
                    "e_r_over_30_deg": int(sum(o["e_r_deg"] > 30 for o in objects))},
            "neither rule 6 nor 17 flags": {**stats(consistent), **_group(consistent)},
            "by_keypoints": {str(k): _group([o for o in objects if o["keypoints"] == k])
                             for k in sorted({o["keypoints"] for o in objects})},
            "keypoints on one end": _group([o for o in consistent if o["end"] is not None]),
            "keypoints along the length": _group([o for o in consistent if o["end"] is None]),
            "by_view": {f"{lo:g}-{min(hi, 90):g} deg": _group([o for o in consistent if lo <= o["view_deg"] < hi])
                        for lo, hi in VIEW_BINS}}


def upright_cost(rows: list[dict]) -> dict:
    """What the upright term does to the cars whose clicks fix their own pitch and roll (issue 36, item 1): the cars
    neither rule 6 nor rule 17 flags whose fit in the default row has both 'clicks' in its observability, and the
    others, each scored in the default row, the ``--upright-weight clicks`` row and the row without the term."""
    by_label = {r["row"]: r for r in rows}
    default = by_label[ROWS[0].label]["_objects"]
    fixed = {o["id"] for o in default if o["consistent"] and o["tilt_by_clicks"]}
    rest = {o["id"] for o in default if o["consistent"]} - fixed
    out = {}
    for label in (ROWS[0].label, ROWS[1].label, ROWS[2].label):
        objects = by_label[label]["_objects"]
        out[label] = {"pitch and roll fixed by the clicks": _group([o for o in objects if o["id"] in fixed]),
                      "pitch or roll left to the road": _group([o for o in objects if o["id"] in rest])}
    return out


def far_end(row: dict, keypoints_path: Path, jobs: int) -> dict:
    """What one keypoint on the far end does for a car clicked on one end only (issue 36, item 3): the default row's
    cars neither rule 6 nor rule 17 flags, seen within 45 degrees of end-on, with at least 4 labelled keypoints on the
    end they show (length fraction beyond :data:`END_FRACTION` that way) and one on the other half (beyond 5 % of the
    length past the middle). Each is fitted from the first 8 of its near-end keypoints (file order), then from those
    and its labelled keypoint farthest toward the far end; with the default row's click noise and road normal (as a
    ground block: normal within 3 degrees, upright within 2), positions as the row's."""
    work = row["_work"]
    objects = {o["id"]: o for o in row["_objects"] if o["consistent"] and o["view_deg"] <= 45.0}
    document = json.loads((work / "annotations.json").read_text())
    results = json.loads((work / "out" / "results.json").read_text())
    (estimated,) = [n for n in results["road_normal"] if n["normal"] is not None]
    ground = GroundOverride(normal=tuple(estimated["normal"]), normal_sigma_deg=road_normal_module.NORMAL_SIGMA_DEG,
                            upright_sigma_deg=road_normal_module.UPRIGHT_SIGMA_DEG)
    options = SolverOptions(click_sigma=results["click_noise"]["sigma_px"])
    near_doc, far_doc, added = [], [], {}
    for im in document["images"]:
        near_cars, far_cars = [], []
        for v in im["vehicles"]:
            o = objects.get(v["id"])
            if o is None:
                continue
            sign = -1.0 if o["facing"] > 0 else 1.0  # the end it shows: the rear (x < 0) when it faces away
            keypoints = [p for p in v["parts"] if p["kind"] == "keypoint"]
            near = [p for p in keypoints if sign * p["at"][0] > END_FRACTION][:8]
            far = [p for p in keypoints if sign * p["at"][0] < -0.05]
            if len(near) < 4 or not far:
                continue
            extra = min(far, key=lambda p: sign * p["at"][0])
            near_cars.append({**v, "parts": near})
            far_cars.append({**v, "parts": [*near, extra]})
            added[v["id"]] = extra["name"]
        if near_cars:
            near_doc.append({**im, "vehicles": near_cars})
            far_doc.append({**im, "vehicles": far_cars})
    out: dict = {"cars": len(added), "keypoint_added": dict(Counter(added.values()).most_common(8))}
    for label, images in (("near end only", near_doc), ("near end + one on the far end", far_doc)):
        folder = work.parent / f"{work.name}-far-end-{len(out)}"
        folder.mkdir()
        (folder / "annotations.json").write_text(json.dumps({"toosicubix": SCHEMA_VERSION, "images": images}))
        fit_file(folder / "annotations.json", folder / "out", BatchSettings(options=options, jobs=jobs, ground=ground))
        result = evaluate(load_predictions(folder / "out"), ApolloCar3DGroundTruth(keypoints_path),
                          EvalOptions(classes=("Car",)))
        fits = {(im["id"], v["id"]): v for im in json.loads((folder / "out" / "results.json").read_text())["images"]
                for v in im["vehicles"]}
        scored = []
        for m in result.matched:
            if m.pred_id in added:
                fit = fits[(m.image_id, m.pred_id)]
                up = float(np.degrees(np.arccos(np.clip(m.pred.R_cam_vehicle[:, 2] @ m.gt.R_cam_vehicle[:, 2], -1, 1))))
                scored.append({"e_r_deg": m.metrics.e_r_deg, "yaw_error_deg": m.metrics.e_yaw_deg, "tilt_error_deg": up,
                               "yaw_sigma_deg": (fit.get("sigma") or {}).get("yaw_deg")})
        out[label] = {**_group(scored), "fitted": len(scored),
                      "e_r_over_10_deg": int(sum(o["e_r_deg"] > 10 for o in scored))}
    out["all their keypoints (the default row)"] = _group([objects[c] for c in added])
    return out


def listed_cars(images: list, found: dict[str, str], scored: set[str]) -> dict[str, dict]:
    """The cars whose ground truth contradicts their clicks (``found``: id -> kind), each with its image, its
    ground-truth depth and whether it is scored, for a reader to look at them one by one."""
    where = {str(c.id): (im.file_name, float(c.t_cam_vehicle[2])) for im in images for c in im.cars}
    return {cid: {"kind": kind, "image": where[cid][0], "depth_m": round(where[cid][1], 1), "scored": cid in scored}
            for cid, kind in sorted(found.items(), key=lambda item: _car_order(item[0]))}


def _car_order(car_id: str) -> int:
    """Cars listed by their numeric id (ApolloCar3D's annotation ids); others first."""
    return int(car_id) if car_id.isdigit() else 0


def depth_bias(objects: list[dict]) -> dict[str, float]:
    """Per car-model type (``2x``, ``3x``, ``SUV``), the median signed relative depth error: < 0 when the fits put
    its cars nearer than the ground truth (the prototype's sizes smaller than the type's CAD models)."""
    types = sorted({o["type"] for o in objects})
    return {t: float(np.median([o["depth_error_rel"] for o in objects if o["type"] == t])) for t in types}


def calibration(objects: list[dict], of: str = "yaw") -> tuple[float | None, float | None]:
    """The shares of cars whose yaw (or depth: ``of="depth"``) error is within one and two predicted sigmas."""
    error, sigma = ("yaw_error_deg", "yaw_sigma_deg") if of == "yaw" else ("depth_error_m", "depth_sigma_m")
    ratio = np.array([o[error] / o[sigma] for o in objects if o[sigma]])
    if not len(ratio):
        return None, None
    return float(np.mean(ratio <= 1)), float(np.mean(ratio <= 2))


def contradicting_cars(images: list, learned: dict, samples: list) -> dict[str, str]:
    """The cars of ``images`` whose ground truth contradicts their clicks by rule 6 (benchmarks/decisions.md): at the
    ground-truth pose their keypoints (``samples``) lie more than 0.5 m RMS from their rays, keypoints at the
    ``learned`` positions (:func:`learned_and_samples`). For a report beside the figures; no car is left out of
    them.

    Each maps to what its clicks do fit, a diagnostic of the data that looks at no fit: 'left and right
    swapped' when they lie within :data:`EXPLAINED_M` RMS of their rays at the car's own ground-truth pose with
    every keypoint's lateral position negated (its left for its right); 'another car's pose' when at the pose
    of another car of the same image (with or without the swap); else 'neither'."""
    bad = contradicting(samples, learned, CONTRADICTION_M)
    of_car: dict[str, list] = {}
    for sample in samples:
        if sample.vehicle in bad:
            of_car.setdefault(sample.vehicle, []).append(sample)
    cars = {im.id: im.cars for im in images}
    kinds = {}
    for key, car_samples in of_car.items():
        image_id, car_id = key.split("/", 1)
        fits = {(str(c.id), swapped): _off_rays(_at_pose(car_samples, c), learned, swapped)
                for c in cars[image_id] for swapped in (False, True)}
        if fits.get((car_id, True), np.inf) <= EXPLAINED_M:
            kinds[car_id] = "left and right swapped"
        elif min([v for (other, _), v in fits.items() if other != car_id], default=np.inf) <= EXPLAINED_M:
            kinds[car_id] = "another car's pose"
        else:
            kinds[car_id] = "neither"
    return kinds


def hiding_cars(learned: dict, samples: list) -> dict[str, dict]:
    """The cars whose ground truth hides their clicks (``samples``) by rule 17 (benchmarks/decisions.md), each with how
    many of its labelled keypoints have learned ``seen_from`` faces (``labelled_with_faces``) and how many of those its
    ground-truth pose turns away from the camera (``hidden``); and, at the ground truth's depth-reversed twin
    (:func:`toosicubix.geometry.depth_reversed_twin`), the keypoints' RMS distance from their rays
    (``twin_off_rays_m``; ``off_rays_m`` at the ground truth) and how many it turns away (``twin_hidden``).
    Positions and faces ``learned`` (:func:`learned_and_samples`). Every keypoint of ApolloCar3D is labelled as
    seen (v = 2). A diagnostic of the data that looks at no fit; no car is left out of any figure."""
    counts = hidden_by_ground_truth(samples, learned)
    of_car: dict[str, list] = {}
    for sample in samples:
        of_car.setdefault(sample.vehicle, []).append(sample)
    out = {}
    for key, (n, hidden) in counts.items():
        if not hides_clicks(n, hidden):
            continue
        car_samples = of_car[key]
        R, t, d = car_samples[0].R_cam_vehicle, car_samples[0].t_cam_vehicle, car_samples[0].dimensions
        R_twin, t_twin = depth_reversed_twin(R, t, d)
        twin = [replace(s, R_cam_vehicle=R_twin, t_cam_vehicle=t_twin) for s in car_samples]
        out[key.split("/", 1)[1]] = {
            "labelled_with_faces": n, "hidden": hidden,
            "off_rays_m": round(_off_rays(car_samples, learned), 3),
            "twin_off_rays_m": round(_off_rays(twin, learned), 3),
            "twin_hidden": hidden_by_ground_truth(twin, learned).get(key, (0, 0))[1]}
    return out


def _off_rays(samples: list, learned: dict, swapped: bool = False) -> float:
    """RMS distance (m) of the keypoints ``samples`` (one car, at the pose and size they carry) from their rays, at
    the ``learned`` positions of their prototype, lateral positions negated when ``swapped``; inf when none of
    them is learned."""
    flip = np.array([1.0, -1.0, 1.0]) if swapped else np.ones(3)
    squares = [float(np.sum(offset_from_ray(s, learned[s.prototype][s.name].at * flip) ** 2))
               for s in samples if s.name in learned.get(s.prototype, {})]
    return float(np.sqrt(np.mean(squares))) if squares else np.inf


def _at_pose(samples: list, car) -> list:
    """The keypoint samples of one car as if it stood at ``car``'s ground-truth pose and size (``car``: another car
    of the image, or its own), with the prototype of ``car``'s type."""
    return [replace(s, prototype=PROTOTYPE_OF_TYPE.get(car.model.type, "Car"), R_cam_vehicle=car.R_cam_vehicle,
                    t_cam_vehicle=car.t_cam_vehicle, dimensions=car.model.dimensions) for s in samples]


def learned_and_samples(images: list, learn_on: list, cameras, names: list[str]) -> tuple[dict, list]:
    """Keypoint positions learned (second pass, rule 6) on ``learn_on``, and the labelled keypoints of ``images``."""
    K_of = {im.id: np.array(cameras.camera_for(im.file_name)["K"], dtype=float) for im in [*images, *learn_on]}
    learned = learn_positions(keypoint_samples(learn_on, names, K_of), 5, CONTRADICTION_M)
    return learned, keypoint_samples(images, names, K_of)


def ends_named(images: list, coco: dict, names: list[str], kinds: dict[str, str]) -> dict[str, dict[str, int]]:
    """Per kind of car (rule 6's contradiction kinds, 'agrees' for the rest), among the scored cars seen end-on
    (the ground truth's heading within 60 degrees of the line of sight, either way): how many have more labelled
    keypoints named for the end their ground-truth pose shows than for the other end, and how many the reverse.
    Lamps, glass, plates, bumpers and the like count; doors and wheels do not. A diagnostic of the data that
    looks at no fit: a person clicks the end they see."""
    keypoints = {str(a["id"]): a["keypoints"] for a in coco["annotations"]}
    out: dict[str, dict[str, int]] = {}
    for im in images:
        for car in im.cars:
            key = str(car.id)
            v = keypoints[key]
            labelled = [names[i] for i in range(len(names)) if v[3 * i + 2] > 0]
            if len(labelled) < MIN_KEYPOINTS:
                continue
            ends = [n for n in labelled if "door" not in n and "wheel" not in n]
            front, rear = sum("front" in n for n in ends), sum("rear" in n for n in ends)
            ray = car.t_cam_vehicle / np.linalg.norm(car.t_cam_vehicle)
            facing = float(car.R_cam_vehicle[:, 0] @ ray)  # < 0: the front is toward the camera
            if abs(facing) < 0.5 or front == rear:
                continue
            shown = (front > rear) == (facing < 0)
            counts = out.setdefault(kinds.get(key, "agrees"), {"shown end": 0, "hidden end": 0})
            counts["shown end" if shown else "hidden end"] += 1
    return out


def contradicting_by_depth(images: list, scored: set[str], kinds: dict[str, str]) -> dict[str, dict[str, int]]:
    """Per depth bin (the ground truth's depth z, as the figures' bins), how many scored cars there are and how
    many of them contradict their clicks (rule 6). A diagnostic of the data that looks at no fit: ApolloScape's
    own issue tracker reports inaccurate and turned poses, "mostly the distant cars" (ApolloScapeAuto/dataset-api
    issues 16 and 28)."""
    out = {}
    for lo, hi in DEPTH_BINS:
        cars = [str(c.id) for im in images for c in im.cars
                if str(c.id) in scored and lo <= float(c.t_cam_vehicle[2]) < hi]
        out[f"{lo:g}+ m" if np.isinf(hi) else f"{lo:g}-{hi:g} m"] = {
            "cars": len(cars), "contradicting": sum(c in kinds for c in cars)}
    return out


def _line(name: str, g: dict) -> str:
    if not g["n"]:
        return f"{name}: none"
    return (f"{name}: {g['n']} cars, E_R {g['e_r_deg']['mean']:.2f} / {g['e_r_deg']['median']:.2f} deg, |yaw| "
            f"{g['abs_yaw_error_deg']:.2f}, up axis {g['tilt_error_deg']:.2f}"
            + ("" if g["yaw_within_1_sigma"] is None else f", yaw within 1 / 2 sigmas "
               f"{100 * g['yaw_within_1_sigma']:.1f} / {100 * g['yaw_within_2_sigma']:.1f} %"))


def print_breakdown(r: dict) -> None:
    """The rotation breakdown of a row (its cars that neither rule 6 nor rule 17 flags), and the few-keypoint cars
    of an ``every_car`` row."""
    if r["half"] == "design":
        return
    for name, g in r["rotation_breakdown"]["neither rule 6 nor 17 flags"].items():
        if name != "all":
            print(f"{'':<6}   neither flags, {_line(name, g)}", flush=True)
    few = r["few_keypoints"]
    if few:
        print(f"{'':<6} fewer than {MIN_KEYPOINTS} keypoints: {few['cars']} cars ({few['flagged']} flagged by rule 6 "
              f"or 17): {_line('all', few['all'])}; means IoU {few['all']['iou']['mean']:.3f}, E_t "
              f"{few['all']['e_t']['mean']:.4f}", flush=True)
        for name in ("neither rule 6 nor 17 flags", "keypoints on one end", "keypoints along the length"):
            print(f"{'':<6}   {_line(name, few[name])}", flush=True)


def print_upright_cost(half: str, cost: dict) -> None:
    for label, groups in cost.items():
        for name, g in groups.items():
            print(f"{half:<6} upright term, {label}: {_line(name, g)}", flush=True)


def print_far_end(half: str, found: dict) -> None:
    print(f"{half:<6} one keypoint on the far end: {found['cars']} cars seen end-on, clicked on their near end",
          flush=True)
    for name in ("near end only", "near end + one on the far end", "all their keypoints (the default row)"):
        print(f"{'':<6}   {_line(name, found[name])}", flush=True)


def format_row(r: dict) -> str:
    def cell(m: str, k: str) -> str:
        v = r[m][k]
        return "-" if v is None else (f"{v:.2f}" if m == "e_r_deg" else f"{v:.3f}")
    means = " ".join(f"{cell(m, 'mean'):>7}" for m in METRICS)
    medians = " ".join(f"{cell(m, 'median'):>7}" for m in METRICS)
    return (f"{r['half']:<6} {r['row']:<36} {r['fitted']:>4}/{r['cars']:<4} {100 * (r['fitted_share'] or 0):5.1f}%"
            f" | {means} | {medians}")


def sorted_images(folder: Path, keypoints: Path | None = None) -> list:
    """The folder's images (of its ``apollocar3d_val_dev.json``, or of ``keypoints``) sorted by file name (the
    split's order: even learning, odd comparison)."""
    keypoints = keypoints or folder / "apollocar3d_val_dev.json"
    return sorted(read_apollocar3d(keypoints, read_car_models(folder / "car_models.json")), key=lambda im: im.file_name)


def bundled_positions_are(images: list, data: Path) -> str:
    """Whether the "all" rows score the bundled positions in or out of sample: 'in sample' when ``images``
    (:func:`sorted_images`) are the ones they were learned from, 'out of sample' when none of them is, else how
    many are. The images they were learned from are those of ``data`` (the shared folder), when its image names
    are the ones :data:`BUNDLED_LEARNED_ON` records."""
    names = [im.file_name for im in images]
    if _names_digest(names) == BUNDLED_LEARNED_ON:
        return "in sample"
    source = data / "apollocar3d" / "apollocar3d_val_dev.json"
    if not source.is_file():
        return "out of sample unless its images are some of those they were learned from (not found to compare)"
    learned_from = {im["file_name"] for im in json.loads(source.read_text())["images"]}
    if _names_digest(sorted(learned_from)) != BUNDLED_LEARNED_ON:
        return f"of unknown sample ({source} is not the folder they were learned from)"
    shared = len(set(names) & learned_from)
    if shared == len(names):
        return "in sample (its images are among those they were learned from)"
    return "out of sample" if not shared else f"in sample for {shared} of its {len(names)} images"


def _names_digest(names: list[str]) -> str:
    return hashlib.sha256("\n".join(names).encode()).hexdigest()


def learned_on(images: list, cameras, how: str, car_models: dict | None = None,
               mirror_pairs: bool = False) -> MappingFile:
    """``apollocar3d-66`` with its keypoint positions learned on ``images`` only (:func:`sorted_images`'s); with
    ``car_models`` each car model's type gets its own prototype (:data:`OWN_PROTOTYPES`, rule 16); with
    ``mirror_pairs`` as ``learn-parts --mirror-pairs`` learns them."""
    bundled, _ = load_mapping("apollocar3d-66")
    base = bundled.model_dump(mode="json", exclude_none=True)
    of_type = None
    if car_models is not None:
        of_type = OWN_PROTOTYPES
        base["prototypes"] = {str(k): OWN_PROTOTYPES.get(m.type, "Car") for k, m in sorted(car_models.items())}
    K_of = {im.id: np.array(cameras.camera_for(im.file_name)["K"], dtype=float) for im in images}
    learned, _ = learned_mapping(base, keypoint_samples(images, bundled.keypoints, K_of, of_type), 5, how, 0.5,
                                 mirror_pairs)
    return MappingFile.model_validate(learned)


def own_priors(images: list, keypoints_path: Path, out: Path) -> Path:
    """Rule 16's priors file: the bundled table with each car type's own prototype (:data:`OWN_PROTOTYPES`),
    its size prior estimated as ``toosicubix priors --apollocar3d`` does, from the cars of ``images``."""
    rows: dict[str, list[np.ndarray]] = {}
    for name, dimensions in apollocar3d_rows(images, OWN_PROTOTYPES):
        if name in OWN_PROTOTYPES.values():  # never re-estimate a bundled prototype from a type without its own
            rows.setdefault(name, []).append(dimensions)
    samples = DimensionSamples(dimensions={name: np.array(d) for name, d in sorted(rows.items())},
                               kind="apollocar3d", root=keypoints_path, unit="car")
    estimates = estimate_priors(samples, method=default_method("apollocar3d"),
                                command=f"benchmarks/apollocar3d.py, {len(images)} images of")
    write_priors_file(priors_document(estimates, load_priors_file(bundled_priors_path())), out)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=None, help="the shared data folder (default ../shared/data)")
    parser.add_argument("--keypoints", type=Path, default=None,
                        help="another ApolloCar3D keypoint file, e.g. the held-out half's, with its cameras.json and "
                             "car_models.json beside it (default DATA/apollocar3d/apollocar3d_val_dev.json)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--design", action="store_true",
                        help="rule 16's design run: learn on images 0, 4, 8, ..., score images 2, 6, 10, ...")
    parser.add_argument("--json", type=Path, default=None, help="write the figures here")
    parser.add_argument("--robust-loss", default=SolverOptions.robust_loss, choices=("auto", "cauchy", "none"))
    parser.add_argument("--click-sigma", type=float, default=None,
                        help="fit with this click noise (px); default: estimated from each batch, as `fit` does")
    args = parser.parse_args()
    keypoints_path = args.keypoints or (args.data or default_data_dir()) / "apollocar3d" / "apollocar3d_val_dev.json"
    folder = keypoints_path.parent
    if not keypoints_path.is_file():
        print(f"no ApolloCar3D keypoint file at {keypoints_path}", file=sys.stderr)
        return 2
    missing = [name for name in ("cameras.json", "car_models.json") if not (folder / name).is_file()]
    if missing:
        print(f"{folder}: expected {' and '.join(missing)} beside {keypoints_path.name} (the images' intrinsics as "
              f"`toosicubix import coco --cameras` reads them; ApolloCar3D's car models)", file=sys.stderr)
        return 2
    options = SolverOptions(robust_loss=args.robust_loss)
    if args.click_sigma is not None:
        options = replace(options, click_sigma=args.click_sigma)
    images = sorted_images(folder, keypoints_path)  # reads and checks the keypoint file (InputError naming it)
    coco = json.loads(keypoints_path.read_text())
    counts = labelled_counts(coco)
    scored = {k for k, n in counts.items() if n >= MIN_KEYPOINTS}
    cameras = load_cameras(folder / "cameras.json")
    car_models = read_car_models(folder / "car_models.json")
    uncovered = [im.file_name for im in images if cameras.camera_for(im.file_name) is None]
    if uncovered:
        print(f"{folder / 'cameras.json'}: no camera matches {len(uncovered)} image(s) of {keypoints_path.name}, e.g. "
              f"{uncovered[0]}", file=sys.stderr)
        return 2
    names = load_mapping("apollocar3d-66")[0].keypoints
    if args.design:
        halves = [Half("design", images[0::4], images[2::4], bundled=False)]
        rows_of = [row for row in ROWS if row.label in (ROWS[0].label, ROWS[1].label)]
        print("design rows: positions and priors learned on images 0, 4, 8, ..., cars of images 2, 6, 10, ... "
              "scored (rule 16's design run; decides nothing)", flush=True)
    else:
        halves = [Half("odd", images[0::2], images[1::2], bundled=False), Half("all", images, images, bundled=True)]
        rows_of = list(ROWS)
        bundled = bundled_positions_are(images, args.data or default_data_dir())
        print(f"all    rows: the bundled positions on {len(images)} images, {bundled} (odd rows: positions learned "
              f"on this folder's even images, out of sample)", flush=True)
    normal_of = {h.name: road_normal(h.learn) for h in halves}
    data_of = {h.name: learned_and_samples(h.score, h.learn, cameras, names) for h in halves}
    contradicting_of = {h.name: contradicting_cars(h.score, *data_of[h.name]) for h in halves}
    ends_of = {h.name: ends_named(h.score, coco, names, contradicting_of[h.name]) for h in halves}
    for half, ends in ends_of.items():
        told = "; ".join(f"{k} {v['shown end']} / {v['hidden end']}" for k, v in sorted(ends.items()))
        print(f"{half:<6} cars seen end-on whose labels name the end their ground truth shows / hides (a diagnostic "
              f"of the data): {told}", flush=True)
    scatter_of = {h.name: up_axis_scatter(h.score, normal_of[h.name], scored) for h in halves}
    for half, scatter in scatter_of.items():
        print(f"{half:<6} scored cars' ground-truth up axes from the camera's road normal (a diagnostic of the data): "
              f"mean {scatter['mean_deg']:.2f} deg, median {scatter['median_deg']:.2f}, 90 % {scatter['p90_deg']:.2f}; "
              f"from the mean up axis of their image's other cars {scatter['image_others_mean_deg']:.2f} (of all its "
              f"cars, their own included, {scatter['image_all_mean_deg']:.2f})", flush=True)
    hiding_of = {h.name: hiding_cars(*data_of[h.name]) for h in halves}
    for half, found in hiding_of.items():
        flagged = set(found) & scored
        twins = {car for car in flagged if found[car]["twin_hidden"] == 0
                 and found[car]["twin_off_rays_m"] <= EXPLAINED_M}
        print(f"{half:<6} scored cars whose ground truth hides their clicks (rule 17, a diagnostic of the data): "
              f"{len(flagged)}, of which rule 6 names {len(flagged & set(contradicting_of[half]))}; the clicks fit "
              f"the ground truth's depth-reversed twin (within {EXPLAINED_M:g} m of their rays, none hidden) for "
              f"{len(twins)}", flush=True)
    depth_of = {h.name: contradicting_by_depth(h.score, scored, contradicting_of[h.name]) for h in halves}
    for half, bins in depth_of.items():
        told = "; ".join(f"{b} {v['contradicting']} of {v['cars']}" for b, v in bins.items())
        print(f"{half:<6} cars whose ground truth contradicts their clicks, by ground-truth depth: {told}", flush=True)
    rows: list[dict] = []
    upright_of: dict[str, dict] = {}
    far_end_of: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for half in halves:
            learned = None if half.bundled else learned_on(half.learn, cameras, f"{half.name} learning images")
            # Learned only for the rows that take them (the design run has neither).
            own, own_priors_path, mirrored = None, None, None
            if any(row.own_priors for row in rows_of):
                own = learned_on(half.learn, cameras, f"{half.name} learning images", car_models)
                own_priors_path = own_priors(half.learn, keypoints_path, Path(tmp) / f"{half.name}-priors.json")
            if any(row.mirror_pairs for row in rows_of):
                mirrored = learned_on(half.learn, cameras, f"{half.name} learning images, mirror pairs",
                                      mirror_pairs=True)
            for row in rows_of:
                if row.own_priors:
                    mapping = own
                elif row.mirror_pairs:
                    mapping = mirrored
                elif row.mapping == "apollocar3d-66" and learned is not None:
                    mapping = learned
                else:
                    mapping = load_mapping(row.mapping)[0]
                ids = {im.id for im in half.score}
                every = {str(c.id) for im in half.score for c in im.cars}
                result = run_row(row, half.name, keypoints_path, Path(tmp), mapping, cameras, ids, every & scored,
                                 counts, args.jobs, options, args.click_sigma is None, contradicting_of[half.name],
                                 normal_of[half.name], own_priors_path if row.own_priors else None,
                                 frozenset(hiding_of[half.name]), every)
                rows.append(result)
                print(format_row(result), flush=True)
                print_breakdown(result)
                if result["yaw_within_1_sigma"] is not None:
                    print(f"{'':<6} yaw within 1 / 2 predicted sigmas: {100 * result['yaw_within_1_sigma']:.1f} % / "
                          f"{100 * result['yaw_within_2_sigma']:.1f} %; E_R > 30 deg: {result['e_r_over_30_deg']}; "
                          f"click noise {result['click_noise']['sigma_px']:.2f} px ({result['click_noise']['source']})"
                          + (f"; misfits {result['misfits']}" if row.misfit_level is not None else ""),
                          flush=True)
                    bias = ", ".join(f"{t} {100 * v:+.1f} %"
                                     for t, v in result["depth_error_rel_median_by_type"].items())
                    print(f"{'':<6} depth within 1 / 2 predicted sigmas: {100 * result['depth_within_1_sigma']:.1f} "
                          f"% / {100 * result['depth_within_2_sigma']:.1f} %; median depth error by car type: {bias}",
                          flush=True)
                agree = result["ground_truth_agrees"]
                if agree["yaw_within_1_sigma"] is None:
                    continue
                print(f"{'':<6} cars whose ground truth agrees with their clicks (rule 6): {agree['cars']} of "
                      f"{result['fitted']}: mean E_R {agree['e_r_deg']['mean']:.2f} deg (median "
                      f"{agree['e_r_deg']['median']:.2f}), mean E_comb {agree['e_comb']['mean']:.3f}, yaw within 1 / 2 "
                      f"sigmas {100 * agree['yaw_within_1_sigma']:.1f} % / {100 * agree['yaw_within_2_sigma']:.1f} %",
                      flush=True)
                hides = result["ground_truth_hides"]
                if hides["cars"]:
                    print(f"{'':<6} cars whose ground truth hides their clicks (rule 17): {hides['cars']}, mean E_R "
                          f"{hides['e_r_deg']['mean']:.1f} deg; fitted within 10 deg of the ground truth's "
                          f"depth-reversed twin: {hides['fit_within_10_deg_of_twin']}", flush=True)
                both = result["ground_truth_consistent"]
                if both["cars"] and both["yaw_within_1_sigma"] is not None:
                    print(f"{'':<6} cars that neither rule 6 nor rule 17 flags: {both['cars']} of {result['fitted']}"
                          f": mean E_R {both['e_r_deg']['mean']:.2f} deg (median {both['e_r_deg']['median']:.2f}), "
                          f"mean E_comb {both['e_comb']['mean']:.3f}, yaw within 1 / 2 sigmas "
                          f"{100 * both['yaw_within_1_sigma']:.1f} % / {100 * both['yaw_within_2_sigma']:.1f} %; "
                          f"E_R > 30 deg: {both['e_r_over_30_deg']}", flush=True)
                parts = {k: agree["rotation_parts"][k]["mean"] for k in ("abs_yaw_error_deg", "tilt_error_deg")}
                every = {k: result["rotation_parts"][k]["mean"] for k in parts}
                print(f"{'':<6} E_R's parts, means: |yaw error| {every['abs_yaw_error_deg']:.2f} deg, up-axis error "
                      f"{every['tilt_error_deg']:.2f} (agreeing cars: {parts['abs_yaw_error_deg']:.2f}, "
                      f"{parts['tilt_error_deg']:.2f})", flush=True)
                kinds = "; ".join(f"{k} {n}" for k, n in sorted(result["contradicting_by_kind"].items()))
                misses = "; ".join(f"{k} {n}" for k, n in sorted(result["e_r_over_30_deg_by_ground_truth"].items()))
                print(f"{'':<6} the other {agree['contradicting']} fit: {kinds}. E_R > 30 deg by ground truth: "
                      f"{misses}", flush=True)
            if not args.design:  # issue 36's diagnostics, from this half's rows
                of_half = [r for r in rows if r["half"] == half.name]
                upright_of[half.name] = upright_cost(of_half)
                far_end_of[half.name] = far_end(of_half[0], keypoints_path, args.jobs)
                print_upright_cost(half.name, upright_of[half.name])
                print_far_end(half.name, far_end_of[half.name])
        for r in rows:
            del r["_objects"], r["_work"]
    print(f"{'paper':<6} {'KITTI, human clicks (paper)':<36} {'':>16} | "
          + " ".join(f"{PAPER_KITTI[m]:>7}" for m in METRICS))
    doc = {"generator": "benchmarks/apollocar3d.py", "machine": machine(), "min_keypoints": MIN_KEYPOINTS,
           "robust_loss": args.robust_loss, "click_sigma": args.click_sigma, "paper_kitti": PAPER_KITTI,
           "bundled_positions": None if args.design else bundled, "design": args.design,
           "ends_named": ends_of, "contradicting_by_depth": depth_of, "up_axis_scatter": scatter_of,
           "contradicting_cars": {half: listed_cars(images, found, scored) for half, found in contradicting_of.items()},
           "hiding_cars": {half: {car: {**counts, "scored": car in scored, "rule_6": contradicting_of[half].get(car)}
                                  for car, counts in sorted(found.items(), key=lambda item: _car_order(item[0]))}
                           for half, found in hiding_of.items()},
           "upright_cost": upright_of, "far_end": far_end_of, "rows": rows}
    if args.json is not None:
        args.json.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except InputError as exc:  # a malformed keypoint, cameras or car-models file: named, with its JSON path
        print(exc.format(), file=sys.stderr)
        sys.exit(2)
