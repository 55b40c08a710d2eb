"""Road users beyond vehicles on simulated keypoints over real KITTI ground truth (issue 35; rule 21 of
benchmarks/decisions.md).

No human keypoints exist publicly for KITTI's pedestrians and cyclists, so a simulated person labels them: COCO's 17
person keypoints on a pedestrian, the two-wheeler vocabulary (wheel contacts and hubs, handlebar ends, saddle, the
rider's head and shoulders) on a cyclist, each on a body posed inside the real ground-truth box
(``toosicubix/simulate/bodies.py``: an articulated person, standing or walking, and a bicycle with its rider, from
published proportions and design figures, independent of the vocabulary's fractions), with COCO's visibility
flags and Gaussian click noise. Simulated clicks are not human clicks; the body model is ours, not the person's.

Objects: KITTI tracking Car, Van, Truck, Pedestrian and Cyclist, untruncated, occlusion <= 1, depth 3-60 m, 2D box
height >= 25 px, at most 3 frames per track (the accuracy benchmark's selection, with the two classes added).
Sequences 0000-0009 are the tuning split, 0010-0020 the test split (the default).

Rows (each ``simulate`` -> ``fit`` with its defaults -> ``eval`` per class):

- ``with vehicles``: every selected object of the split in one annotation file, as a dataset labelled for every
  road user (the batch's road normal comes from its own fits): 2 px (the targets' row), 1 px, and 0 px with every
  keypoint exactly at the vocabulary's place on the true box and labelled as seen (the solver alone);
- ``alone``: the pedestrians and cyclists without the vehicles, 2 px.

Per class: how many were fitted, the paper's metrics (mean and median), the heading error (the KITTI yaw's error),
then the same by depth and by the number of keypoints labelled; the issue's targets for pedestrians (>= 95 %
fitted, mean E_t <= 0.10, median heading error <= 15 degrees, mean sIoU >= 0.60 at 2 px) and cyclists (>= 95 %,
mean E_t <= 0.10, median heading error <= 5 degrees) are checked on the first row.

Run from the repository root (about 4 minutes on 2 cores):

    python benchmarks/road_users.py [--split test] [--jobs 2] [--json benchmarks/results/road_users-test.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SPLITS, default_data_dir, machine

from toosicubix.evaluation import evaluate_folder
from toosicubix.evaluation.evaluate import EvalOptions
from toosicubix.evaluation.records import MatchedObject
from toosicubix.formats.results import read_results
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.simulate.annotator import (
    AnnotatorOptions,
    SelectionOptions,
    SimulatedVehicle,
    select_kitti_tracking,
    simulate,
    write_simulation,
)

VEHICLES = ("Car", "Van", "Truck")
ROAD_USERS = ("Pedestrian", "Cyclist")
#: Depth bins (metres, [lo, hi)) and keypoint-count bins per class ([lo, hi]).
DEPTH_BINS = ((0.0, 10.0), (10.0, 20.0), (20.0, 30.0), (30.0, 60.0))
KEYPOINT_BINS = {"Pedestrian": ((0, 9), (10, 13), (14, 17)), "Cyclist": ((0, 5), (6, 8), (9, 10))}
#: The issue's targets on the first row: (fitted share, mean E_t, median heading error deg, mean sIoU or None).
TARGETS = {"Pedestrian": (0.95, 0.10, 15.0, 0.60), "Cyclist": (0.95, 0.10, 5.0, None)}


@dataclass(frozen=True)
class Row:
    label: str
    noise_px: float
    exact: bool
    with_vehicles: bool


ROWS = (
    Row("2 px, with vehicles", 2.0, False, True),
    Row("1 px, with vehicles", 1.0, False, True),
    Row("0 px, exact placement, with vehicles", 0.0, True, True),
    Row("2 px, alone", 2.0, False, False),
)


def _stats(records: list[MatchedObject]) -> dict:
    """Mean and median of the paper's metrics and the heading error over ``records`` (None when empty)."""
    out: dict = {"n": len(records)}
    for key, get in (("siou", lambda r: r.metrics.siou), ("iou", lambda r: r.metrics.iou),
                     ("e_r_deg", lambda r: r.metrics.e_r_deg), ("e_t", lambda r: r.metrics.e_t),
                     ("e_d", lambda r: r.metrics.e_d), ("e_comb", lambda r: r.metrics.e_comb),
                     ("heading_deg", lambda r: r.e_heading_deg)):
        values = np.array([get(r) for r in records if get(r) is not None], dtype=float)
        out[f"{key}_mean"] = float(values.mean()) if len(values) else None
        out[f"{key}_median"] = float(np.median(values)) if len(values) else None
    return out


def run_row(row: Row, data: Path, split: str, jobs: int, seed: int, work: Path) -> dict:
    classes = (*VEHICLES, *ROAD_USERS) if row.with_vehicles else ROAD_USERS
    vehicles = select_kitti_tracking(data / "kitti_tracking", SelectionOptions(classes=classes,
                                                                                sequences=SPLITS[split]))
    simulated = simulate(vehicles, AnnotatorOptions(noise_px=row.noise_px, exact_placement=row.exact, seed=seed))
    folder = work / row.label.replace(" ", "_").replace(",", "")
    annotations, gt_dir, out = folder / "annotations.json", folder / "gt", folder / "out"
    folder.mkdir(parents=True)
    write_simulation(simulated, annotations, gt_dir)
    start = time.perf_counter()
    fit_file(annotations, out, BatchSettings(jobs=jobs, estimate_road_normal=True))
    fit_seconds = time.perf_counter() - start
    header = json.loads((out / "results.json").read_text())
    fitted = {(im.id, v.id): v for im in read_results(out / "results.json") for v in im.vehicles}
    evaluation = evaluate_folder(out, "kitti", gt_dir, EvalOptions(classes=classes))
    by_class: dict[str, dict] = {}
    for cls in classes:
        records = {(r.image_id, r.pred_id): r for r in evaluation.matched if r.cls == cls}
        members = [sv for sv in simulated if sv.source.label.type == cls]
        by_class[cls] = _class_figures(cls, members, fitted, records)
    return {"row": row.label, "noise_px": row.noise_px, "exact_placement": row.exact,
            "with_vehicles": row.with_vehicles, "fit_seconds": fit_seconds,
            "road_normal": header.get("road_normal"), "classes": by_class}


def _class_figures(cls: str, members: list[SimulatedVehicle], fitted: dict, records: dict) -> dict:
    n_fitted, failures, keypoints = 0, {}, []
    scored: list[tuple[SimulatedVehicle, MatchedObject]] = []
    for sv in members:
        key = (sv.source.image_id, sv.source.vehicle_id)
        v = fitted[key]
        keypoints.append(sv.n_clicks)
        if not v.ok:
            reason = (v.error or "").split(":")[0][:80]
            failures[reason] = failures.get(reason, 0) + 1
            continue
        n_fitted += 1
        if key in records:
            scored.append((sv, records[key]))
    out = {"objects": len(members), "fitted": n_fitted, "fitted_share": n_fitted / max(len(members), 1),
           "failures": failures, "scored": len(scored),
           "keypoints_mean": float(np.mean(keypoints)) if keypoints else None,
           **_stats([r for _, r in scored])}
    out["by_depth"] = [{"bin": f"{lo:g}-{hi:g} m", **_stats([r for _, r in scored if lo <= r.depth < hi])}
                       for lo, hi in DEPTH_BINS]
    if cls in KEYPOINT_BINS:
        out["by_keypoints"] = [{"bin": f"{lo}-{hi}", **_stats([r for sv, r in scored if lo <= sv.n_clicks <= hi])}
                               for lo, hi in KEYPOINT_BINS[cls]]
    return out


def _fmt(x: float | None, digits: int = 3) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def print_tables(rows: list[dict]) -> None:
    print("\n| row | class | objects | fitted | keypoints (mean) | sIoU mean / median | E_t mean / median "
          "| heading error deg median / mean | E_R deg mean / median | E_d mean |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        for cls, c in r["classes"].items():
            print(f"| {r['row']} | {cls} | {c['objects']} | {c['fitted']} ({100 * c['fitted_share']:.1f} %) "
                  f"| {_fmt(c['keypoints_mean'], 1)} | {_fmt(c['siou_mean'])} / {_fmt(c['siou_median'])} "
                  f"| {_fmt(c['e_t_mean'])} / {_fmt(c['e_t_median'])} "
                  f"| {_fmt(c['heading_deg_median'], 2)} / {_fmt(c['heading_deg_mean'], 2)} "
                  f"| {_fmt(c['e_r_deg_mean'], 2)} / {_fmt(c['e_r_deg_median'], 2)} | {_fmt(c['e_d_mean'])} |")
    first = rows[0]
    for breakdown, title in (("by_depth", "depth"), ("by_keypoints", "keypoints labelled")):
        print(f"\nBy {title} ({first['row']}): n, sIoU mean, E_t mean, heading error median deg")
        print("| class | " + " | ".join(b["bin"] for b in first["classes"]["Pedestrian"].get(breakdown, [])) + " |")
        for cls in ROAD_USERS:
            bins = first["classes"][cls].get(breakdown)
            if bins:
                print(f"| {cls} | " + " | ".join(f"{b['n']}: {_fmt(b['siou_mean'])}, {_fmt(b['e_t_mean'])}, "
                                                  f"{_fmt(b['heading_deg_median'], 1)}" for b in bins) + " |")
    print("\nTargets (first row):")
    for cls, (share, e_t, heading, siou) in TARGETS.items():
        c = first["classes"][cls]
        checks = [("fitted", c["fitted_share"] >= share, f"{100 * c['fitted_share']:.1f} % >= {100 * share:.0f} %"),
                  ("mean E_t", c["e_t_mean"] is not None and c["e_t_mean"] <= e_t, f"{_fmt(c['e_t_mean'])} <= {e_t}"),
                  ("median heading", c["heading_deg_median"] is not None and c["heading_deg_median"] <= heading,
                   f"{_fmt(c['heading_deg_median'], 2)} <= {heading} deg")]
        if siou is not None:
            checks.append(("mean sIoU", c["siou_mean"] is not None and c["siou_mean"] >= siou,
                           f"{_fmt(c['siou_mean'])} >= {siou}"))
        print(f"  {cls}: " + "; ".join(f"{name} {text} {'met' if ok else 'MISSED'}" for name, ok, text in checks))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=default_data_dir())
    parser.add_argument("--split", choices=sorted(SPLITS), default="test")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rows", type=int, default=len(ROWS), help="run only the first N rows")
    parser.add_argument("--json", type=Path, default=None, help="write every figure to this file")
    args = parser.parse_args(argv)
    if not (args.data / "kitti_tracking").is_dir():
        sys.exit(f"{args.data / 'kitti_tracking'}: not found (give --data)")
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="toosicubix-road-users-") as tmp:
        rows = []
        for row in ROWS[: args.rows]:
            print(f"{row.label} ...", file=sys.stderr)
            rows.append(run_row(row, args.data, args.split, args.jobs, args.seed, Path(tmp)))
    print_tables(rows)
    seconds = time.perf_counter() - started
    print(f"\n{args.split} split, {seconds:.0f} s; machine: {machine()}")
    if args.json:
        document = {"benchmark": "road_users", "split": args.split, "sequences": list(SPLITS[args.split]),
                    "seed": args.seed, "seconds": seconds, "machine": machine(),
                    "command": " ".join(["python", "benchmarks/road_users.py", *(argv or sys.argv[1:])]),
                    "rows": rows}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(document, indent=1) + "\n")


if __name__ == "__main__":
    main()
