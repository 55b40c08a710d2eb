"""Speed and memory of ``toosicubix fit`` on simulated clicks over real KITTI tracking ground truth.

1. Per-vehicle fit time in one process: ``toosicubix.pipeline.vehicle.fit_one`` (parts model, solver, result) on
   every vehicle of the accuracy benchmark's test split at 1 px click noise; median, p95 and mean, over
   all vehicles and over those fitted (vehicles with too few clicks return at once).
2. Throughput of the command line with ``--jobs 1`` and ``--jobs 2`` on the same annotation file of
   ``--throughput-vehicles`` vehicles (wall time, process start included), and whether the outputs are
   byte-identical.
3. Peak memory (maximum resident set size) of ``toosicubix fit --jobs 1`` on 1,000 and 10,000 vehicles,
   each run in a fresh process.
4. Peak memory of ``toosicubix fit --jobs 2`` against the batch size (``--memory-vehicles``, default
   1,000, 10,000 and 100,000): the main process and the largest worker, each run in a fresh process, on
   annotation files made by replicating 1,000 simulated vehicles (images copied under new ids). Flat in
   the number of vehicles is the target (issue 13: under 500 MB at 100,000).

Run from the repository root (about four minutes on 2 cores for parts 1-3; part 4 fits every vehicle,
about 40 minutes at 100,000):

    python benchmarks/speed.py [--json benchmarks/results/speed.json] [--only memory]
"""

from __future__ import annotations

import argparse
import filecmp
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SPLITS, default_data_dir, machine

from toosicubix.annotations.priors_file import load_priors
from toosicubix.model import Vehicle
from toosicubix.pipeline.vehicle import fit_one
from toosicubix.simulate.annotator import (
    AnnotatorOptions,
    SelectionOptions,
    select_kitti_tracking,
    simulate,
    write_simulation,
)
from toosicubix.solver.fit import SolverOptions

_PEAK_MEMORY_CHILD = """
import resource, sys
from toosicubix.cli import main
try:
    main(sys.argv[1:], standalone_mode=False)
except SystemExit:
    pass
# The main process's own peak: VmHWM starts afresh with this program (ru_maxrss keeps the peak of the process
# that started it, e.g. this benchmark's, across the exec); the workers' from ru_maxrss of the children.
try:
    own = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM:"))
except (OSError, StopIteration):
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(own, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
"""


def per_vehicle_times(data: Path) -> dict:
    vehicles = select_kitti_tracking(data / "kitti_tracking", SelectionOptions(sequences=SPLITS["test"]))
    simulated = simulate(vehicles, AnnotatorOptions(noise_px=1.0))
    priors = load_priors()
    options = SolverOptions()
    tasks = [(Vehicle(sv.source.vehicle_id, sv.source.label.type, sv.source.label.box2d, tuple(sv.parts), "$"),
              sv.source.camera, priors[sv.source.label.type]) for sv in simulated]
    for task in tasks[:20]:  # warm-up: imports, caches
        fit_one(*task, options)
    times, fitted = [], []
    for task in tasks:
        start = time.perf_counter()
        result = fit_one(*task, options)
        elapsed = time.perf_counter() - start
        times.append(elapsed)
        if result.ok:
            fitted.append(elapsed)

    def stats(values: list[float]) -> dict:
        ms = np.array(values) * 1e3
        return {"n": len(ms), "median_ms": float(np.median(ms)), "p95_ms": float(np.percentile(ms, 95)),
                "mean_ms": float(ms.mean())}

    return {"all": stats(times), "fitted": stats(fitted)}


def annotation_file(data: Path, n: int, folder: Path) -> Path:
    """An annotation file of the first ``n`` vehicles of all tracking sequences, every frame, 1 px noise."""
    vehicles = select_kitti_tracking(data / "kitti_tracking", SelectionOptions(frames_per_track=None))[:n]
    if len(vehicles) < n:
        sys.exit(f"only {len(vehicles)} vehicles available, {n} asked")
    path = folder / f"annotations-{n}.json"
    write_simulation(simulate(vehicles, AnnotatorOptions(noise_px=1.0)), path, folder / f"gt-{n}")
    return path


def fit_cli(annotations: Path, out: Path, jobs: int) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "toosicubix", "fit", str(annotations), "-o", str(out), "-q",
                    "--jobs", str(jobs)], check=False)
    return time.perf_counter() - start


def peak_memory_mb(annotations: Path, out: Path, jobs: int = 1) -> tuple[float, float]:
    """Peak resident set of ``toosicubix fit`` (main process, largest worker), MB."""
    output = subprocess.run([sys.executable, "-c", _PEAK_MEMORY_CHILD, "fit", str(annotations), "-o", str(out),
                             "-q", "--jobs", str(jobs)], capture_output=True, text=True, check=True).stdout
    main_kib, worker_kib = output.strip().splitlines()[-1].split()
    return int(main_kib) / 1024.0, int(worker_kib) / 1024.0  # both in KiB on Linux


def replicated_annotation_file(data: Path, n: int, folder: Path, base: int = 1000, parts: int | None = None) -> Path:
    """An annotation file of ``n`` vehicles: the images of ``base`` simulated vehicles (first tracking
    vehicles, 1 px noise), copied under new image ids until there are ``n`` vehicles. With ``parts``, each
    vehicle keeps only its first ``parts`` parts (``parts=1``: every vehicle fails at once with too few
    constraints, which measures what the batch keeps per vehicle without the solver's time)."""
    base_path = folder / f"annotations-base-{base}.json"
    if not base_path.is_file():
        vehicles = select_kitti_tracking(data / "kitti_tracking", SelectionOptions(frames_per_track=None))[:base]
        write_simulation(simulate(vehicles, AnnotatorOptions(noise_px=1.0)), base_path, folder / f"gt-base-{base}")
    doc = json.loads(base_path.read_text())
    source = doc["images"]
    path = folder / f"annotations-replicated-{n}-{parts}.json"
    count, copy = 0, 0
    with open(path, "w") as handle:  # written image by image: the benchmark itself stays small
        handle.write('{"toosicubix": 1, "images": [')
        while count < n:
            for im in source:
                if count >= n:
                    break
                vehicles = [v if parts is None else {**v, "parts": v["parts"][:parts]}
                            for v in im["vehicles"][: n - count]]
                handle.write(("," if count else "") + json.dumps({**im, "id": f"{im['id']}_r{copy}",
                                                                  "vehicles": vehicles}))
                count += len(vehicles)
            copy += 1
        handle.write("]}\n")
    return path


def speed_and_memory(args: argparse.Namespace, report: dict) -> None:
    """Parts 1-3 of the module docstring."""
    report["per_vehicle"] = per_vehicle_times(args.data)
    for which, s in report["per_vehicle"].items():
        print(f"fit time per vehicle ({which}, n={s['n']}): median {s['median_ms']:.2f} ms, p95 {s['p95_ms']:.1f} ms, "
              f"mean {s['mean_ms']:.2f} ms", flush=True)

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        n = args.throughput_vehicles
        ann = annotation_file(args.data, n, folder)
        seconds = {jobs: fit_cli(ann, folder / f"out-j{jobs}", jobs) for jobs in (1, 2)}
        identical = filecmp.cmp(folder / "out-j1" / "results.json", folder / "out-j2" / "results.json", shallow=False)
        report["throughput"] = {
            "vehicles": n, "seconds": seconds, "vehicles_per_second": {j: n / s for j, s in seconds.items()},
            "speedup_jobs2": seconds[1] / seconds[2], "identical_output": identical,
        }
        print(f"throughput, {n} vehicles: --jobs 1 {n / seconds[1]:.0f}/s ({seconds[1]:.1f} s), --jobs 2 "
              f"{n / seconds[2]:.0f}/s ({seconds[2]:.1f} s): {seconds[1] / seconds[2]:.2f}x; outputs identical: "
              f"{identical}", flush=True)

        report["peak_memory_mb"] = {}
        for size in (1000, 10000):
            ann = annotation_file(args.data, size, folder)
            peak, _ = peak_memory_mb(ann, folder / f"mem-{size}")
            report["peak_memory_mb"][size] = peak
            print(f"peak memory, {size} vehicles, --jobs 1: {peak:.0f} MB", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=default_data_dir())
    parser.add_argument("--throughput-vehicles", type=int, default=3000)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--memory-vehicles", default="1000,10000,100000",
                        help="batch sizes for the --jobs 2 peak-memory part, comma-separated")
    parser.add_argument("--only", choices=["all", "memory"], default="all",
                        help="memory: only the --jobs 2 peak-memory part")
    parser.add_argument("--memory-parts", type=int, default=None,
                        help="keep only this many parts per vehicle in the peak-memory part (1: every vehicle "
                             "fails at once; the batch's own memory without the solver's time)")
    args = parser.parse_args()
    if not (args.data / "kitti_tracking").is_dir():
        sys.exit(f"no KITTI tracking data at {args.data / 'kitti_tracking'} (set --data)")
    report: dict = {"machine": machine()}
    print(f"machine: {report['machine']}", flush=True)

    if args.only == "all":
        speed_and_memory(args, report)
    report["peak_memory_jobs2_mb"] = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for size in (int(v) for v in args.memory_vehicles.split(",")):
            ann = replicated_annotation_file(args.data, size, folder, parts=args.memory_parts)
            start = time.perf_counter()
            main_mb, worker_mb = peak_memory_mb(ann, folder / f"mem2-{size}", jobs=2)
            seconds = time.perf_counter() - start
            report["peak_memory_jobs2_mb"][size] = {"main": main_mb, "largest_worker": worker_mb,
                                                    "seconds": seconds, "parts_per_vehicle": args.memory_parts,
                                                    "annotation_file_mb": ann.stat().st_size / 2**20}
            print(f"peak memory, {size} vehicles, --jobs 2: main process {main_mb:.0f} MB, largest worker "
                  f"{worker_mb:.0f} MB ({seconds:.0f} s; annotation file {ann.stat().st_size / 2**20:.0f} MB)",
                  flush=True)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
