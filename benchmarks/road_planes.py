"""How far KITTI's roads are from the nominal ground plane (issue 6, benchmarks/decisions.md "Scale and ground cues").

The KITTI ground block says: camera 1.65 m above a road whose normal is the camera's -y. This measures how
well that holds where the vehicles stand: the camera-frame height ``y`` of every labelled vehicle's bottom
centre (Car, Van, Truck; untruncated, occlusion <= 1, depth 3-60 m; every frame) against 1.65 m, by
depth band, and against a plane ``y = h + z tan(pitch) + x tan(roll)`` fitted by least squares to each
split and to each sequence.

Run from the repository root (a few seconds):

    python benchmarks/road_planes.py [--json benchmarks/results/road-planes.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SPLITS, default_data_dir, machine

from toosicubix.formats.kitti import read_tracking_file
from toosicubix.model import KITTI_GROUND
from toosicubix.simulate.annotator import VEHICLE_CLASSES

DEPTH_BANDS = ((3.0, 10.0), (10.0, 20.0), (20.0, 30.0), (30.0, 60.0))


def bottom_centres(root: Path, sequences: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Per sequence, the selected vehicles' bottom centres in camera 0 (rectified) coordinates: (n, 3)."""
    out = {}
    for sequence in sequences:
        points = [obj.location_rect for objs in read_tracking_file(root / "label_02" / f"{sequence}.txt").values()
                  for obj in objs
                  if obj.type in VEHICLE_CLASSES and obj.truncated == 0 and obj.occluded <= 1
                  and 3.0 < obj.location_rect[2] < 60.0]
        out[sequence] = np.array(points).reshape(-1, 3)
    return out


def fit_plane(points: np.ndarray) -> dict[str, float]:
    """``y = h + z tan(pitch) + x tan(roll)`` by least squares: h in metres, the angles in degrees."""
    x, y, z = points.T
    (h, a, b), *_ = np.linalg.lstsq(np.column_stack([np.ones_like(z), z, x]), y, rcond=None)
    return {"n": len(points), "height_m": float(h), "pitch_deg": float(np.degrees(np.arctan(a))),
            "roll_deg": float(np.degrees(np.arctan(b)))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=default_data_dir())
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    root = args.data / "kitti_tracking"
    nominal = float(KITTI_GROUND.camera_height)
    report: dict = {"machine": machine(), "nominal_camera_height_m": nominal, "splits": {}}
    for split, sequences in SPLITS.items():
        per_sequence = bottom_centres(root, sequences)
        points = np.concatenate(list(per_sequence.values()))
        plane = fit_plane(points)
        off_nominal = np.abs(points[:, 1] - nominal)
        bands = {}
        for lo, hi in DEPTH_BANDS:
            inside = (points[:, 2] >= lo) & (points[:, 2] < hi)
            bands[f"{lo:g}-{hi:g} m"] = {"n": int(inside.sum()),
                                         "median_abs_off_nominal_m": float(np.median(off_nominal[inside]))}
        report["splits"][split] = {"plane": plane, "depth_bands": bands,
                                   "sequences": {s: fit_plane(p) for s, p in per_sequence.items() if len(p) >= 3}}
        print(f"{split}: {plane['n']} vehicles; one plane: camera {plane['height_m']:.2f} m, pitch "
              f"{plane['pitch_deg']:+.2f} deg, roll {plane['roll_deg']:+.2f} deg")
        for band, row in bands.items():
            print(f"  {band}: {row['n']} vehicles, median |y - {nominal:g} m| = "
                  f"{row['median_abs_off_nominal_m']:.3f} m")
        for sequence, p in report["splits"][split]["sequences"].items():
            print(f"  sequence {sequence}: {p['n']} vehicles, camera {p['height_m']:.2f} m, pitch "
                  f"{p['pitch_deg']:+.2f} deg, roll {p['roll_deg']:+.2f} deg")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
