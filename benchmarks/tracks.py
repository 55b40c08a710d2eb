"""Tracks on KITTI tracking with a simulated annotator (issue 32): clicks on every k-th frame and a 2D box on every
frame, fitted as tracks, against every frame clicked and fitted alone.

No human clicks exist publicly for KITTI: a simulated annotator (``toosicubix simulate --tracks``) clicks on real
ground-truth cuboids of KITTI tracking and draws a person's box around each frame's vehicle (a silhouette inside the
cuboid, a pixel or two off: ``toosicubix.simulate.boxes``; never KITTI's own boxes, which are the cuboids'
projections). Simulated clicks are not human clicks.

Rows (each through the product's own pipeline: simulate, fit, eval):

- ``alone``: clicks on every frame, every frame fitted alone (``fit --tracks off``): today's way, the baseline;
- ``k=1``, ``k=2``, ``k=5``, ``k=10``: clicks on every k-th frame of each track (its first and its last too) and a
  person's box on every frame, fitted as tracks (``fit``'s default).

Per row, over the frames of the selected tracks: how many were fitted, mean and median E_R (degrees), E_t, IoU and
sIoU against the ground truth; per track the error of its one size (the median over its frames, relative) and the
jitter of the bottom centre (the median over its frames of ``|second difference of the fit - that of the truth|``,
metres); clicked points per labelled cuboid; fit seconds per frame.

``--motion-model`` instead measures, on the tuning sequences only, what rules 19 and 19a of benchmarks/decisions.md fix
the track solver's motion model and box cue from (and prints them).

Run from the repository root (the comparison about ten minutes on 2 cores):

    python benchmarks/tracks.py --motion-model [--json benchmarks/results/tracks-motion-model.json]
    python benchmarks/tracks.py [--jobs 2] [--json benchmarks/results/tracks.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SPLITS, default_data_dir, machine

from toosicubix.formats.ground_truth import open_ground_truth
from toosicubix.formats.kitti import read_tracking_file
from toosicubix.geometry import so3_log

VEHICLES = ("Car", "Van", "Truck")
FRAME_RATE = 10.0


def _eligible(obj, t_cam_rect: np.ndarray) -> bool:
    depth = obj.location_rect[2] + t_cam_rect[2]
    return obj.type in VEHICLES and obj.truncated == 0 and obj.occluded <= 1 and 3.0 <= depth <= 60.0


def motion_statistics(data: Path, sequences: tuple[str, ...]) -> dict:
    """Rule 19, items 1 and 2: the robust sigma of the change of velocity and of rotation rate per axis over the
    root of the frame interval, and the 99th percentiles of speed and yaw rate, from the ground truth of
    ``sequences``."""
    source = open_ground_truth("kitti-tracking", data / "kitti_tracking")
    dv, dw, speeds, yaw_rates = [], [], [], []
    h = 1.0 / FRAME_RATE
    for sequence in sequences:
        camera = source.folder.camera(sequence)
        tracks: dict[int, dict[int, object]] = {}
        for frame, objects in read_tracking_file(source.folder.label_file(sequence)).items():
            for obj in objects:
                if _eligible(obj, camera.t_cam_rect):
                    tracks.setdefault(int(obj.track_id), {})[frame] = obj
        for frames in tracks.values():
            for f, obj in frames.items():
                prev = frames.get(f - 1)
                if prev is not None:
                    speeds.append(np.abs(obj.location_rect - prev.location_rect).max() / h)
                    yaw_rates.append(abs(so3_log(prev.R_cam_vehicle.T @ obj.R_cam_vehicle)[2]) / h)
                after = frames.get(f + 1)
                if prev is None or after is None:
                    continue
                t0, t1, t2 = prev.location_rect, obj.location_rect, after.location_rect
                dv.append(((t2 - t1) / h - (t1 - t0) / h) / np.sqrt(h))
                w1 = so3_log(prev.R_cam_vehicle.T @ obj.R_cam_vehicle) / h
                w2 = so3_log(obj.R_cam_vehicle.T @ after.R_cam_vehicle) / h
                dw.append((w2 - w1) / np.sqrt(h))
    dv, dw = np.array(dv), np.array(dw)

    def robust_sigma(x: np.ndarray) -> list[float]:
        return (1.4826 * np.median(np.abs(x - np.median(x, axis=0)), axis=0)).tolist()

    def rms(x: np.ndarray) -> list[float]:
        return np.sqrt(np.mean(x**2, axis=0)).tolist()

    yaw_sigma = rms(dw[:, 2:3])[0]
    return {
        "sequences": list(sequences), "triples": len(dv), "pairs": len(speeds),
        "accel_sigma": rms(dv),
        "angular_accel_sigma": [yaw_sigma, yaw_sigma, yaw_sigma],
        "rule_19_item_1_as_first_written": {"accel_sigma": robust_sigma(dv), "yaw": robust_sigma(dw[:, 2:3])[0],
                                            "note": "collapsed to the labels' rounding: rule 19a"},
        "speed_sigma": float(np.percentile(speeds, 99)), "angular_speed_sigma": float(np.percentile(yaw_rates, 99)),
        "accel_sigma_note": "m s^-3/2 per camera axis (x right, y down, z forward)",
        "angular_accel_sigma_note": "rad s^-3/2; KITTI has yaw only: pitch and roll take the yaw's (rule 19)",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=default_data_dir())
    parser.add_argument("--motion-model", action="store_true", help="measure rule 19's values on the tuning split")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    if args.motion_model:
        out = {"machine": machine(), "motion": motion_statistics(args.data, SPLITS["tuning"])}
        print(json.dumps(out["motion"], indent=1))
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
