"""Where a fit's time goes: cProfile over the per-vehicle fit and over a whole ApolloCar3D batch.

1. KITTI simulated: ``toosicubix.pipeline.vehicle.fit_one`` on every vehicle of the accuracy benchmark's test
   split at 1 px click noise (the per-vehicle part of ``benchmarks/speed.py``, same tasks, same warm-up).
2. ApolloCar3D: its keypoints imported as ``toosicubix import coco --mapping apollocar3d-66`` does, then
   ``toosicubix.pipeline.batch.fit_file`` with one process and ``fit``'s defaults (the click noise and road
   normals estimated by the pilot): import, pilot, fits and output writing.

For each, the functions with the largest cumulative time (calls, own time, cumulative time and its share of the
profiled total), as a Markdown table. cProfile slows Python calls more than array arithmetic, so the shares lean
towards call-heavy code; the wall time without the profiler is printed beside.

Run from the repository root (about two minutes on 2 cores):

    python benchmarks/profile_fit.py [--top 25] [--only kitti|apollocar3d] [--json PATH]
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import default_data_dir, machine
from speed import kitti_tasks

from toosicubix.annotations.mapping import load_mapping
from toosicubix.formats.cameras import load_cameras
from toosicubix.formats.coco import coco_to_annotations
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.pipeline.vehicle import fit_one
from toosicubix.solver.fit import SolverOptions


def apollocar3d_annotations(data: Path, out: Path) -> Path:
    """ApolloCar3D's keypoints as an annotation file (``import coco --mapping apollocar3d-66``)."""
    folder = data / "apollocar3d"
    document, _ = coco_to_annotations(folder / "apollocar3d_val_dev.json", load_mapping("apollocar3d-66")[0],
                                      load_cameras(folder / "cameras.json"))
    out.write_text(json.dumps(document))
    return out


def table(profile: cProfile.Profile, top: int) -> tuple[float, list[dict]]:
    """The profiled total (s) and the ``top`` functions by cumulative time."""
    stats = pstats.Stats(profile)
    total = stats.total_tt
    rows = []
    for (filename, line, name), (_, calls, own, cumulative, _) in stats.stats.items():
        where = filename.split("site-packages/")[-1].split("toosicubix/")[-1] if "/" in filename else filename
        rows.append({"function": f"{where}:{line}({name})" if line else name, "calls": calls, "own_s": own,
                     "cumulative_s": cumulative, "share": cumulative / total})
    rows.sort(key=lambda r: -r["cumulative_s"])
    return total, rows[:top]


def markdown(total: float, rows: list[dict]) -> str:
    lines = [f"profiled total {total:.2f} s", "", "| function | calls | own s | cumulative s | share |",
             "|---|---:|---:|---:|---:|"]
    lines += [f"| `{r['function']}` | {r['calls']} | {r['own_s']:.2f} | {r['cumulative_s']:.2f} | {r['share']:.0%} |"
              for r in rows]
    return "\n".join(lines)


def profile_kitti(data: Path, top: int) -> dict:
    tasks = kitti_tasks(data)
    options = SolverOptions()
    for task in tasks[:20]:  # warm-up: imports, caches
        fit_one(*task, options)
    start = time.perf_counter()
    for task in tasks:
        fit_one(*task, options)
    wall = time.perf_counter() - start
    profile = cProfile.Profile()
    profile.enable()
    for task in tasks:
        fit_one(*task, options)
    profile.disable()
    total, rows = table(profile, top)
    return {"vehicles": len(tasks), "wall_s_unprofiled": wall, "ms_per_vehicle_unprofiled": 1e3 * wall / len(tasks),
            "profiled_s": total, "ms_per_vehicle_profiled": 1e3 * total / len(tasks), "top": rows}


def profile_apollocar3d(data: Path, top: int) -> dict:
    settings = BatchSettings(estimate_click_sigma=True, estimate_road_normal=True)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        start = time.perf_counter()
        annotations = apollocar3d_annotations(data, folder / "annotations.json")
        import_s = time.perf_counter() - start
        n = sum(len(im["vehicles"]) for im in json.loads(annotations.read_text())["images"])
        start = time.perf_counter()
        fit_file(annotations, folder / "out-plain", settings)
        wall = time.perf_counter() - start
        profile = cProfile.Profile()
        profile.enable()
        apollocar3d_annotations(data, folder / "annotations-profiled.json")
        fit_file(annotations, folder / "out", settings)
        profile.disable()
    total, rows = table(profile, top)
    return {"vehicles": n, "import_s_unprofiled": import_s, "fit_file_s_unprofiled": wall,
            "ms_per_vehicle_unprofiled": 1e3 * (import_s + wall) / n, "profiled_s": total,
            "ms_per_vehicle_profiled": 1e3 * total / n, "top": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=default_data_dir())
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("--only", choices=["all", "kitti", "apollocar3d"], default="all")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).resolve().parent).stdout.strip()
    report: dict = {"machine": machine(), "commit": commit}
    print(f"machine: {report['machine']}; commit {commit}", flush=True)
    if args.only in ("all", "kitti"):
        report["kitti"] = k = profile_kitti(args.data, args.top)
        print(f"\nKITTI simulated test split, {k['vehicles']} vehicles: {k['ms_per_vehicle_unprofiled']:.2f} ms per "
              f"vehicle unprofiled, {k['ms_per_vehicle_profiled']:.2f} ms under cProfile", flush=True)
        print(markdown(k["profiled_s"], k["top"]), flush=True)
    if args.only in ("all", "apollocar3d"):
        report["apollocar3d"] = a = profile_apollocar3d(args.data, args.top)
        print(f"\nApolloCar3D, {a['vehicles']} cars: import {a['import_s_unprofiled']:.2f} s, fit_file "
              f"{a['fit_file_s_unprofiled']:.2f} s unprofiled ({a['ms_per_vehicle_unprofiled']:.2f} ms per car); "
              f"{a['ms_per_vehicle_profiled']:.2f} ms per car under cProfile", flush=True)
        print(markdown(a["profiled_s"], a["top"]), flush=True)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
