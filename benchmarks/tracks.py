"""Tracks on KITTI tracking with a simulated annotator (issue 32): clicks on every k-th frame and a 2D box on every
frame, fitted as tracks, against every frame clicked and fitted alone.

No human clicks exist publicly for KITTI: a simulated annotator (``toosicubix simulate --tracks``) clicks on real
ground-truth cuboids of KITTI tracking and draws a person's box around each frame's vehicle (a silhouette inside the
cuboid, a pixel or two off: ``toosicubix.simulate.boxes``; never KITTI's own boxes, which are the cuboids'
projections). Simulated clicks are not human clicks.

Rows (each through the product's own pipeline: simulate, fit, eval):

- ``alone``: clicks on every frame, every frame fitted alone (``fit --tracks off``): today's way, the baseline;
- ``alone+box``: the same, each frame's person's box as a cue too (``fit --tracks off --box-cue``: issue 32's
  item 3, the box cue for single images, rule 19c);
- ``k=1``, ``k=2``, ``k=5``, ``k=10``: clicks on every k-th frame of each track (its first and its last too) and a
  person's box on every frame, fitted as tracks (``fit``'s default).

Per row, over the frames of the selected tracks: how many were fitted, mean and median E_R (degrees), E_t, IoU and
sIoU against the ground truth; per track the error of its one size (the median over its frames, relative) and the
jitter of the bottom centre (the median over its frames of ``|second difference of the fit - that of the truth|``,
metres); clicked points per labelled cuboid; fit seconds per frame; and the median E_R over the frames the
``alone`` row fitted too (``alone`` fits fewer frames: those its clicks cannot fit alone, the hardest, are not in
its median).

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


def box_statistics(data: Path, sequences: tuple[str, ...], seed: int = 0) -> dict:
    """Rule 19, item 3: the simulated person's box (one solid per track) against the projected ground-truth cuboid's
    extremes (what the track solver's box rows compare), the sides not on the image border; the least-squares fit
    ``offset^2 = a^2 + b^2 size^2`` over all of them."""
    from toosicubix.simulate.boxes import draw_body_shape, simulated_box2d
    from toosicubix.solver.track import box_residuals, box_sides_used

    source = open_ground_truth("kitti-tracking", data / "kitti_tracking")
    rng = np.random.default_rng(seed)
    offsets, sizes = [], []
    for sequence in sequences:
        camera = source.folder.camera(sequence)
        shapes: dict[int, object] = {}
        for _frame, objects in sorted(read_tracking_file(source.folder.label_file(sequence)).items()):
            for obj in objects:
                if not _eligible(obj, camera.t_cam_rect):
                    continue
                shape = shapes.setdefault(int(obj.track_id), draw_body_shape(obj.type, rng))
                t = obj.location_rect + camera.t_cam_rect
                box = simulated_box2d(obj.R_cam_vehicle, t, obj.dimensions, obj.type, camera, rng, shape=shape)
                if box is None:
                    continue
                r, _ = box_residuals(camera.K, box, obj.R_cam_vehicle, t, obj.dimensions, False)
                used = box_sides_used(camera, box)
                size = np.array([box[2] - box[0], box[3] - box[1]] * 2)
                offsets.extend(r[used])
                sizes.extend(size[used])
    offsets, sizes = np.array(offsets), np.array(sizes)
    A = np.column_stack([np.ones_like(sizes), sizes**2])
    (a2, b2), *_ = np.linalg.lstsq(A, offsets**2, rcond=None)
    a2, b2 = max(float(a2), 0.0), max(float(b2), 0.0)
    z = offsets / np.hypot(np.sqrt(a2), np.sqrt(b2) * sizes)
    return {"sides": len(offsets), "box_sigma_px": float(np.sqrt(a2)), "box_sigma_rel": float(np.sqrt(b2)),
            "offset_median_px": float(np.median(offsets)), "offset_rms_px": float(np.sqrt(np.mean(offsets**2))),
            "normalised_rms": float(np.sqrt(np.mean(z**2))),
            "within_1_sigma": float(np.mean(np.abs(z) <= 1)), "within_2_sigma": float(np.mean(np.abs(z) <= 2)),
            "note": "offset: the projected cuboid's extreme minus the person's box side (the solver's box residual), "
                    "pixels; size: the box's width (left, right) or height (top, bottom)"}


#: The rows: (label, clicks on every k-th frame, fitted as tracks).
#: (label, clicks on every k-th frame, fitted as tracks, the box as a cue for frames fitted alone)
ROWS = (("alone", 1, False, False), ("alone+box", 1, False, True), ("k=1", 1, True, False), ("k=2", 2, True, False),
        ("k=5", 5, True, False), ("k=10", 10, True, False))
#: Frames per track: the issue's 30 (KITTI tracking cars with a run of 30 eligible frames, cut to its first 30).
FRAMES_PER_TRACK = 30
NOISE_PX = 1.5


def select_tracks(data: Path, sequences: tuple[str, ...]) -> list:
    """The test split's car tracks with a run of at least :data:`FRAMES_PER_TRACK` eligible frames, each cut to its
    first :data:`FRAMES_PER_TRACK` (the simulator's selection: untruncated, occlusion at most 1, 3-60 m, boxes at
    least 25 px tall)."""
    from toosicubix.simulate.annotator import SelectionOptions, select_kitti_tracks

    vehicles = select_kitti_tracks(data / "kitti_tracking", SelectionOptions(
        classes=("Car",), sequences=sequences, frames_per_track=FRAMES_PER_TRACK))
    counts: dict[str, int] = {}
    for gt in vehicles:
        counts[gt.track] = counts.get(gt.track, 0) + 1
    return [gt for gt in vehicles if counts[gt.track] == FRAMES_PER_TRACK]


def run_row(label: str, keyframes: int, as_tracks: bool, vehicles: list, folder: Path, jobs: int,
            box_cue: bool = False) -> dict:
    """Simulate, fit and score one row (see the module docstring)."""
    import time

    from toosicubix.evaluation import evaluate_folder
    from toosicubix.formats.results import read_results
    from toosicubix.pipeline.batch import fit_file
    from toosicubix.pipeline.settings import BatchSettings
    from toosicubix.simulate.annotator import AnnotatorOptions, TrackOptions, simulate_tracks, write_simulation

    work = folder / label
    work.mkdir(parents=True)
    options = AnnotatorOptions(noise_px=NOISE_PX, seed=0)
    simulated = simulate_tracks(vehicles, options, TrackOptions(keyframes, "person"))
    write_simulation(simulated, work / "annotations.json", work / "gt")
    settings = BatchSettings(jobs=jobs, estimate_click_sigma=True, estimate_part_sigma=True, estimate_road_normal=True,
                             tracks=as_tracks, box_cue=box_cue)  # as `fit` fits a file (rule 33: the part placement)
    start = time.perf_counter()
    summary = fit_file(work / "annotations.json", work / "out", settings)
    seconds = time.perf_counter() - start
    result = evaluate_folder(work / "out", "kitti", work / "gt")
    track_of = {(sv.source.image_id, sv.source.vehicle_id): sv.source.track for sv in simulated}
    truth = {(sv.source.image_id, sv.source.vehicle_id): sv for sv in simulated}
    frame_of = {(sv.source.image_id, sv.source.vehicle_id): sv.source.frame for sv in simulated}
    per_frame = [m for m in result.matched]
    e_r = np.array([m.metrics.e_r_deg for m in per_frame])
    e_r_by_frame = {f"{m.image_id}/{m.pred_id}": float(m.metrics.e_r_deg) for m in per_frame}
    e_yaw = np.array([m.metrics.e_yaw_deg for m in per_frame])  # KITTI's yaw alone: E_R without the tilt
    e_t = np.array([m.metrics.e_t for m in per_frame])
    iou = np.array([m.metrics.iou for m in per_frame])
    siou = np.array([m.metrics.siou for m in per_frame])
    fits = {(im.id, v.id): v for im in read_results(work / "out" / "results.json") for v in im.vehicles}
    # The up axis's error (degrees): the rotation's part that KITTI's yaw leaves out, over every frame fitted and by
    # what the frame's pose came from (its clicks, its box alone, interpolated).
    tilt: dict[str, list[float]] = {}
    for key, v in fits.items():
        if v.ok:
            up = float(np.clip(v.R_cam_vehicle[:, 2] @ truth[key].R_cam_vehicle[:, 2], -1.0, 1.0))
            for group in ("all", v.pose_from or "alone"):
                tilt.setdefault(group, []).append(float(np.degrees(np.arccos(up))))
    by_track: dict[str, list] = {}
    for key, v in fits.items():
        if v.ok:
            by_track.setdefault(track_of[key], []).append((frame_of[key], v, truth[key]))
    size_error, sizes, jitter = [], [], []
    for frames in by_track.values():
        frames.sort(key=lambda row: row[0])
        d_fit = np.array([v.dimensions for _, v, _ in frames])
        d_true = frames[0][2].dimensions
        size_error.append(float(np.median(np.linalg.norm(d_fit - d_true, axis=1)) / np.linalg.norm(d_true)))
        sizes.append(len({tuple(np.round(d, 6)) for d in d_fit}))
        centre_fit = {f: v.t_cam_vehicle + 0.5 * v.dimensions[2] * v.R_cam_vehicle[:, 2] for f, v, _ in frames}
        centre_true = {f: sv.t_cam_vehicle + 0.5 * sv.dimensions[2] * sv.R_cam_vehicle[:, 2] for f, _, sv in frames}
        second = [np.linalg.norm((centre_fit[f + 1] - 2 * centre_fit[f] + centre_fit[f - 1])
                                 - (centre_true[f + 1] - 2 * centre_true[f] + centre_true[f - 1]))
                  for f in centre_fit if f - 1 in centre_fit and f + 1 in centre_fit]
        if second:
            jitter.append(float(np.median(second)))
    clicks = sum(sv.n_clicks for sv in simulated)
    return {
        "row": label, "keyframes": keyframes, "tracks": as_tracks, "frames": len(simulated),
        "tracks_count": len({sv.source.track for sv in simulated}),
        "fitted": summary.ok, "fitted_share": summary.ok / len(simulated), "matched": len(per_frame),
        "e_r_mean_deg": float(e_r.mean()), "e_r_median_deg": float(np.median(e_r)),
        "e_yaw_mean_deg": float(e_yaw.mean()), "e_yaw_median_deg": float(np.median(e_yaw)),
        "tilt_median_deg": {group: float(np.median(values)) for group, values in sorted(tilt.items())},
        "e_t_mean": float(e_t.mean()), "e_t_median": float(np.median(e_t)),
        "iou_mean": float(iou.mean()), "siou_mean": float(siou.mean()),
        "size_error_median": float(np.median(size_error)), "sizes_per_track_max": int(max(sizes)),
        "jitter_median_m": float(np.median(jitter)), "clicks_per_cuboid": clicks / max(summary.ok, 1),
        "seconds_per_frame": seconds / len(simulated), "pose_from": dict(summary.pose_from),
        "_e_r_by_frame": e_r_by_frame,
    }


def common_rows(rows: list[dict]) -> None:
    """Each row's median E_R over the frames the ``alone`` row fitted too (``e_r_median_common_deg``), beside its
    median over every frame it fitted: ``alone`` leaves out the frames its clicks cannot fit alone, the hardest, which
    a track fits; on the frames both fit, the comparison is of the same frames. Removes the rows' per-frame maps."""
    by_frame = {row["row"]: row.pop("_e_r_by_frame") for row in rows}
    alone = by_frame.get("alone")
    if alone is None:
        return
    for row in rows:
        common = [e for key, e in by_frame[row["row"]].items() if key in alone]
        row["e_r_median_common_deg"] = float(np.median(common)) if common else None
        row["common_frames"] = len(common)
        print(f"{row['row']:6s} median E_R on the {len(common)} frames alone fitted too: "
              f"{row['e_r_median_common_deg']:.2f}", flush=True)


def long_tracks(lengths: tuple[int, ...] = (75, 150, 300, 600, 1200)) -> list[dict]:
    """Time and peak memory of :func:`toosicubix.solver.track.fit_track` on a synthetic track of each length: a car
    seen obliquely, moving and turning steadily, exact clicks on every 10th frame, a box on the others. Linear in the
    frames is the target (issue 32: a 600-frame track well under a second per frame)."""
    import time
    import tracemalloc

    from toosicubix.camera import Camera
    from toosicubix.geometry import R_cam_vehicle_from_ypr, cuboid_corners_cam
    from toosicubix.parts.linear import build_parts_model
    from toosicubix.parts.synthesis import PartSpec, render_parts
    from toosicubix.size_priors import SizePrior
    from toosicubix.solver.track import TrackFrame, fit_track

    camera = Camera(K=np.array([[720.0, 0.0, 620.0], [0.0, 720.0, 180.0], [0.0, 0.0, 1.0]]), image_size=(1240, 375))
    d = np.array([4.3, 1.8, 1.5])
    prior = SizePrior.from_mean_cov("Car", np.array([4.2, 1.75, 1.5]), np.diag([0.09, 0.01, 0.01]))
    specs = [PartSpec("point", "wheel-front-left"), PartSpec("point", "wheel-rear-left"),
             PartSpec("point", "wheel-front-right"), PartSpec("point", "edge-front-left", {"Z": 0.8}),
             PartSpec("point", "edge-rear-left", {"Z": 0.8}), PartSpec("point", "corner-top-front-left"),
             PartSpec("point", "corner-top-rear-left"), PartSpec("symmetry", "front", {"Y": 0.7, "Z": 0.8})]
    out = []
    for n in lengths:
        frames = []
        for f in range(n):
            angle = 2 * np.pi * f / 600.0  # a slow circle around a point 25 m ahead: stays in view
            R = R_cam_vehicle_from_ypr(3 * np.pi / 4 + angle)
            t = np.array([6.0 * np.sin(angle) - 2.0, 1.6, 25.0 + 6.0 * np.cos(angle)])
            parts = render_parts(specs, R, t, d, camera, (1.4, -1.3)) if f % 10 == 0 else []
            uv = camera.project(cuboid_corners_cam(R, t, d))
            box = None if f % 10 == 0 else np.array([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()])
            frames.append(TrackFrame(f, build_parts_model(parts), camera, None, box))
        start = time.perf_counter()
        fit = fit_track(frames, prior)
        seconds = time.perf_counter() - start
        tracemalloc.start()  # memory in a second run: tracing slows the fit about ten times
        fit_track(frames, prior)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        out.append({"frames": n, "ok": fit.ok, "seconds": seconds, "ms_per_frame": 1000 * seconds / n,
                    "iterations": fit.iterations, "seconds_per_iteration_frame": seconds / max(fit.iterations, 1) / n,
                    "peak_mb": peak / 2**20, "timings": fit.timings})
        print(f"{n:5d} frames: {seconds:6.2f} s, {1000 * seconds / n:5.1f} ms/frame, {fit.iterations} iterations "
              f"({1e6 * seconds / max(fit.iterations, 1) / n:.0f} us per frame and iteration), peak "
              f"{peak / 2**20:.1f} MB (traced, a second run)", flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=default_data_dir())
    parser.add_argument("--motion-model", action="store_true", help="measure rule 19's values on the tuning split")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--split", choices=sorted(SPLITS), default="test")
    parser.add_argument("--long", action="store_true", help="time synthetic tracks of 75 to 1,200 frames instead")
    parser.add_argument("--rows", nargs="*", default=None, help="only these rows (default: all)")
    args = parser.parse_args()
    if args.long:
        out = {"machine": machine(), "long_tracks": long_tracks()}
    elif args.motion_model:
        out = {"machine": machine(), "motion": motion_statistics(args.data, SPLITS["tuning"]),
               "box": box_statistics(args.data, SPLITS["tuning"])}
        print(json.dumps({"motion": out["motion"], "box": out["box"]}, indent=1))
    else:
        import tempfile

        vehicles = select_tracks(args.data, SPLITS[args.split])
        rows = []
        with tempfile.TemporaryDirectory() as tmp:
            for label, keyframes, as_tracks, box_cue in ROWS:
                if args.rows and label not in args.rows:
                    continue
                row = run_row(label, keyframes, as_tracks, vehicles, Path(tmp), args.jobs, box_cue)
                rows.append(row)
                print(f"{label:6s} fitted {row['fitted']}/{row['frames']}  E_R mean {row['e_r_mean_deg']:.2f} median "
                      f"{row['e_r_median_deg']:.2f}  yaw median {row['e_yaw_median_deg']:.2f}  tilt median "
                      f"{', '.join(f'{k} {v:.2f}' for k, v in row['tilt_median_deg'].items())}  "
                      f"E_t mean {row['e_t_mean']:.3f} median {row['e_t_median']:.3f}  "
                      f"IoU {row['iou_mean']:.3f} sIoU {row['siou_mean']:.3f}  size err {row['size_error_median']:.3f}"
                      f" (sizes/track <= {row['sizes_per_track_max']})  jitter {row['jitter_median_m']:.3f} m  "
                      f"clicks/cuboid {row['clicks_per_cuboid']:.1f}  {1000 * row['seconds_per_frame']:.0f} ms/frame",
                      flush=True)
        common_rows(rows)
        out = {"machine": machine(), "split": args.split, "noise_px": NOISE_PX, "frames_per_track": FRAMES_PER_TRACK,
               "rows": rows}
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
