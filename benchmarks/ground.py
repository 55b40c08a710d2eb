"""Scale and ground cues on simulated clicks over real KITTI ground truth (issue 6).

Simulated clicks are not human clicks (see ``toosicubix.simulate``). Test sequences 0010-0020, 1 px click
noise, realistic part placement, default settings. Two vehicle sets:

- *benchmark set*: the accuracy benchmark's selection (untruncated, occlusion <= 1, 3-60 m, box >= 25 px,
  at most 3 frames per track): 647 vehicles, mostly one per image;
- *multi-vehicle set*: 150 images (seeded draw) with 3 or more such vehicles, every one of them annotated,
  for the joint image fit.

Ground settings compared, each row through the product's pipeline (annotation file -> fit -> eval):

- size prior only;
- KITTI's nominal ground block: camera 1.65 +- 0.1 m above a road with normal -y +- 1 degree;
- the same with the joint image fit;
- an *oracle* plane per image, fitted to that image's ground-truth bottom centres (held near a sensible
  road: slopes within about 2 degrees, height within 0.5 m of 1.65 m, which matters for images with few
  vehicles), with tight sigmas (3 cm, 0.1 degree): what the cues give when the road plane is known, e.g.
  from a calibrated rig or a road-plane estimate.

Then the camera-height recovery: the joint fit with the oracle normal but no height, on the multi-vehicle
set, with realistic and with exact part placement; error against the oracle height.

Run from the repository root (about three minutes on 2 cores):

    python benchmarks/ground.py [--json benchmarks/results/ground-test.json]
"""

from __future__ import annotations

import argparse
import collections
import copy
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SPLITS, default_data_dir, machine

from toosicubix.evaluation import evaluate_folder, summarize
from toosicubix.formats.results import dumps, read_results
from toosicubix.model import KITTI_GROUND, GroundOverride
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.simulate.annotator import (
    AnnotatorOptions,
    SelectionOptions,
    annotation_document,
    select_kitti_tracking,
    simulate,
    write_simulation,
)

ORACLE_SIGMAS = {"camera_height_sigma": 0.03, "normal_sigma_deg": 0.1, "upright_sigma_deg": 2.0}


def oracle_planes(simulated) -> dict[str, dict]:
    """Per image: the plane through its vehicles' true bottom centres (camera frame of K)."""
    bottoms = collections.defaultdict(list)
    for sv in simulated:
        bottoms[sv.source.image_id].append(sv.t_cam_vehicle)
    planes = {}
    for image_id, points in bottoms.items():
        P = np.array(points)
        # y = h + a x + b z through the bottoms (2 cm each), held near a sensible road: slopes a, b within
        # about 2 degrees, h within 0.5 m of 1.65 m. Three bottoms close together would otherwise tilt the
        # plane anywhere.
        rows = np.vstack([np.column_stack([np.ones(len(P)), P[:, 0], P[:, 2]]) / 0.02,
                          np.diag([1 / 0.5, 1 / 0.035, 1 / 0.035])])
        rhs = np.concatenate([P[:, 1] / 0.02, [1.65 / 0.5, 0.0, 0.0]])
        (h, a, b), *_ = np.linalg.lstsq(rows, rhs, rcond=None)
        norm = np.linalg.norm([a, -1.0, b])
        planes[image_id] = {"camera_height": h / norm, "normal": [a / norm, -1.0 / norm, b / norm]}
    return planes


def run(doc: dict, gt_dir: Path, folder: Path, joint: bool = False) -> tuple[dict, list]:
    folder.mkdir(parents=True)
    annotations = folder / "annotations.json"
    annotations.write_text(dumps(doc))
    start = time.perf_counter()
    fit_file(annotations, folder / "out", BatchSettings(jobs=2, joint_ground=joint))
    seconds = time.perf_counter() - start
    summary = summarize(evaluate_folder(folder / "out", "kitti", gt_dir))
    summary["fit_seconds"] = seconds
    results = read_results(folder / "out" / "results.json")
    scale_from = collections.Counter(v.scale_from for im in results for v in im.vehicles if v.ok)
    summary["scale_from"] = dict(scale_from)
    return summary, results


def with_ground(doc: dict, blocks: dict[str, dict] | GroundOverride | None) -> dict:
    doc = copy.deepcopy(doc)
    for im in doc["images"]:
        if blocks is None:
            im.pop("ground", None)
        elif isinstance(blocks, GroundOverride):  # one block for every image
            im["ground"] = blocks.to_json()
        else:
            im["ground"] = dict(blocks[im["id"]])
    return doc


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=default_data_dir())
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    report: dict = {"machine": machine(), "rows": [], "height_recovery": []}
    print(f"machine: {report['machine']}", flush=True)
    data = args.data / "kitti_tracking"
    benchmark_set = select_kitti_tracking(data, SelectionOptions(sequences=SPLITS["test"]))
    every_frame = select_kitti_tracking(data, SelectionOptions(sequences=SPLITS["test"], frames_per_track=None))
    by_image = collections.defaultdict(list)
    for g in every_frame:
        by_image[g.image_id].append(g)
    crowded = sorted(k for k, v in by_image.items() if len(v) >= 3)
    picked = set(np.random.default_rng(0).choice(crowded, size=min(150, len(crowded)), replace=False))
    multi_set = [g for g in every_frame if g.image_id in picked]

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for set_name, vehicles in (("benchmark set", benchmark_set), ("multi-vehicle set", multi_set)):
            simulated = simulate(vehicles, AnnotatorOptions(noise_px=1.0))
            gt_dir = tmp / set_name.replace(" ", "-") / "gt"
            write_simulation(simulated, tmp / f"{set_name}.json", gt_dir)
            base = annotation_document(simulated)
            oracle = {k: {**v, **ORACLE_SIGMAS} for k, v in oracle_planes(simulated).items()}
            rows = [("size prior only", None, False), ("KITTI ground block", KITTI_GROUND, False),
                    ("KITTI ground block, joint image fit", KITTI_GROUND, True),
                    ("oracle plane per image", oracle, False)]
            for label, blocks, joint in rows:
                folder = tmp / set_name.replace(" ", "-") / label.replace(" ", "-").replace(",", "")
                summary, _ = run(with_ground(base, blocks), gt_dir, folder, joint)
                row = {"set": set_name, "ground": label, "vehicles": len(simulated), **summary}
                report["rows"].append(row)
                print(f"{set_name} | {label}: n={summary['n_matched']} IoU {summary['iou_mean']:.3f} "
                      f"sIoU {summary['siou_mean']:.3f} E_R median {summary['e_r_median_deg']:.2f} "
                      f"E_t median {summary['e_t_median']:.3f} scale from {summary['scale_from']}", flush=True)

        # Camera height unknown, oracle normal known: the joint fit estimates the height.
        planes = None
        for placement, exact in (("realistic placement", False), ("exact placement", True)):
            simulated = simulate(multi_set, AnnotatorOptions(noise_px=1.0, exact_placement=exact))
            planes = planes or oracle_planes(simulated)
            gt_dir = tmp / f"height-{exact}" / "gt"
            write_simulation(simulated, tmp / f"height-{exact}.json", gt_dir)
            blocks = {k: {"normal": v["normal"], "normal_sigma_deg": 0.1, "camera_height_sigma": 0.05}
                      for k, v in planes.items()}
            summary, results = run(with_ground(annotation_document(simulated), blocks), gt_dir,
                                   tmp / f"height-{exact}" / "fit", joint=True)
            errors = []
            for im in results:
                fitted = sum(v.ok for v in im.vehicles)
                if im.ground is not None and im.ground.estimated and fitted >= 3:
                    errors.append(im.ground.camera_height - planes[im.id]["camera_height"])
            errors = np.array(errors)
            record = {"placement": placement, "images": len(errors),
                      "median_abs_error_m": float(np.median(np.abs(errors))), "bias_m": float(np.median(errors)),
                      "within_5cm": float(np.mean(np.abs(errors) <= 0.05)), "iou_mean": summary["iou_mean"],
                      "e_t_median": summary["e_t_median"]}
            report["height_recovery"].append(record)
            print(f"camera height, joint fit, normal known, {placement}: {len(errors)} images with >= 3 fitted "
                  f"vehicles: median error {record['median_abs_error_m'] * 100:.1f} cm "
                  f"(bias {record['bias_m'] * 100:+.1f} cm), within 5 cm: {100 * record['within_5cm']:.0f} %",
                  flush=True)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
