"""Speed and memory of ``toosicubix fit``, interleaved with another checkout so that a ratio holds on a noisy machine.

Parts (``--parts``, comma-separated; the first three by default):

1. ``per-vehicle``: fit time per vehicle in one process, ``toosicubix.pipeline.vehicle.fit_one`` (parts model,
   solver, result) on every vehicle of the accuracy benchmark's test split at 1 px click noise: median, p90, p95
   and mean, over all vehicles and over those fitted (vehicles with too few clicks return at once).
2. ``apollocar3d``: vehicles per second on ApolloCar3D's cars (``apollocar3d_val_dev.json``, 1,034 cars) with
   ``--jobs 2``: the keypoints imported (``import coco --mapping apollocar3d-66``), then
   ``toosicubix.pipeline.batch.fit_file`` with ``fit``'s defaults (the pilot estimates the click noise and the road
   normals) and two processes, output written; timed from the import's start to the written folder. Also the CPU
   time ``fit_file`` costs a car in the main process and in the workers (pilot and batch): the main process's share
   is what caps how many workers help on a machine with more cores.
3. ``refit``: the annotation page's refit (``toosicubix.web.session.Session._fit``: ``fit_one`` with every
   suggestion of what to click next, ``next_clicks=NEXT_CLICKS``) on the first ``--refit-vehicles`` vehicles of
   part 1: median and p90.
4. ``whole``: whole ``toosicubix`` processes, as a user times them (Python's start, the imports, loading the
   compiled solver where the batch is large enough, the pilot, the fits, the output): ``toosicubix --help``,
   ``toosicubix fit`` on the bundled sample (6 vehicles) and on the first ``--whole-vehicles`` (306) vehicles of part
   1's test split at 1 px, at ``fit``'s defaults (``--jobs auto``); median seconds over ``--rounds`` rounds, each
   checkout in turn with ``--against``. Python's bytecode is cached as an install leaves it (an untimed first run of
   each case fills the cache), whatever ``PYTHONDONTWRITEBYTECODE`` says.
5. ``throughput``: the command line with ``--jobs 1`` and ``--jobs 2`` on ``--throughput-vehicles`` vehicles
   (wall time, process start included), whether the outputs are byte-identical, and the peak memory of
   ``--jobs 1`` on 1,000 and 10,000 vehicles.
6. ``memory``: peak memory of ``toosicubix fit --jobs 2`` against the batch size (``--memory-vehicles``, default
   1,000, 10,000 and 100,000; about 40 minutes at 100,000): the main process and the largest worker, each run in
   a fresh process, on annotation files made by replicating 1,000 simulated vehicles (images copied under new ids).
7. ``paired``: parts 1 and 3 for a machine whose speed drifts within seconds (a shared one), with ``--against``: one
   warm process per checkout, plus a second one of this checkout, fit the same chunks of ``--paired-chunk`` vehicles
   in turn (the order alternating chunk by chunk), ``--rounds`` passes over the vehicles, so that a drift hits both
   alike. Reports the ratio of the summed times (other / this) and the median of the chunk ratios, and the same for
   this checkout against its second process: the harness's own noise, which a ratio must pass to mean anything.

Parts 1-3 run in fresh worker processes (``--worker``, this file's code over either checkout's package), part 4 in
fresh ``toosicubix`` processes, ``--rounds`` rounds each; with ``--against PATH`` (another checkout, e.g. ``git
worktree add /tmp/base f35ec77``) every round runs this checkout and the other one in turn, alternating which goes
first: both see the same load, and the report gives each one's figures over all rounds and the ratio (other / this).

Run from the repository root (parts 1-3, 3 rounds, against another checkout: about 12 minutes on 2 cores):

    python benchmarks/speed.py [--against ../base] [--rounds 3] [--json benchmarks/results/speed.json]
    python benchmarks/speed.py --parts memory --memory-vehicles 1000,100000
    python benchmarks/speed.py --against ../base --rounds 3 --parts paired     # 2 min: parts 1 and 3, paired
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import REPO, SPLITS, default_data_dir, machine

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


def kitti_tasks(data: Path) -> list[tuple]:
    """``fit_one``'s arguments for the test split's vehicles at 1 px click noise."""
    from toosicubix.annotations.priors_file import load_priors
    from toosicubix.model import Vehicle
    from toosicubix.simulate.annotator import AnnotatorOptions, SelectionOptions, select_kitti_tracking, simulate

    vehicles = select_kitti_tracking(data / "kitti_tracking", SelectionOptions(sequences=SPLITS["test"]))
    simulated = simulate(vehicles, AnnotatorOptions(noise_px=1.0))
    priors = load_priors()
    return [(Vehicle(sv.source.vehicle_id, sv.source.label.type, sv.source.label.box2d, tuple(sv.parts), "$"),
             sv.source.camera, priors[sv.source.label.type]) for sv in simulated]


def per_vehicle_times(data: Path) -> dict:
    """Part 1 in this process: seconds per vehicle of ``fit_one``, and whether each was fitted."""
    from toosicubix.pipeline.vehicle import fit_one
    from toosicubix.solver.fit import SolverOptions

    tasks = kitti_tasks(data)
    options = SolverOptions()
    for task in tasks[:20]:  # warm-up: imports, caches
        fit_one(*task, options)
    times, ok = [], []
    for task in tasks:
        start = time.perf_counter()
        result = fit_one(*task, options)
        times.append(time.perf_counter() - start)
        ok.append(result.ok)
    return {"seconds": times, "ok": ok}


def refit_times(data: Path, n: int) -> dict:
    """Part 3 in this process: seconds per refit as the page asks it (``fit_one`` with ``NEXT_CLICKS``
    suggestions), on the first ``n`` vehicles of part 1."""
    from toosicubix.pipeline.vehicle import fit_one
    from toosicubix.solver.fit import SolverOptions
    from toosicubix.web.session import NEXT_CLICKS

    tasks = kitti_tasks(data)[:n]
    options = SolverOptions()
    for task in tasks[:5]:  # warm-up
        fit_one(*task, options, next_clicks=NEXT_CLICKS)
    times = []
    for task in tasks:
        start = time.perf_counter()
        fit_one(*task, options, next_clicks=NEXT_CLICKS)
        times.append(time.perf_counter() - start)
    return {"seconds": times}


def apollocar3d_rate(data: Path, jobs: int) -> dict:
    """Part 2 in this process: ApolloCar3D's keypoints imported and fitted with ``jobs`` processes, output
    written; seconds from the import's start to the written folder."""
    from toosicubix.annotations.mapping import load_mapping
    from toosicubix.formats.cameras import load_cameras
    from toosicubix.formats.coco import coco_to_annotations
    from toosicubix.pipeline.batch import fit_file
    from toosicubix.pipeline.settings import BatchSettings

    folder = data / "apollocar3d"
    settings = BatchSettings(jobs=jobs, estimate_click_sigma=True, estimate_road_normal=True)
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        document, _ = coco_to_annotations(folder / "apollocar3d_val_dev.json", load_mapping("apollocar3d-66")[0],
                                          load_cameras(folder / "cameras.json"))
        annotations = Path(tmp) / "annotations.json"
        annotations.write_text(json.dumps(document))
        imported = time.perf_counter()
        main_before, workers_before = _cpu_seconds()
        summary = fit_file(annotations, Path(tmp) / "out", settings)
        done = time.perf_counter()
        main_after, workers_after = _cpu_seconds()
    return {"vehicles": summary.vehicles, "ok": summary.ok, "seconds": done - start, "import_seconds": imported - start,
            "main_cpu_seconds": main_after - main_before, "workers_cpu_seconds": workers_after - workers_before}


def _cpu_seconds() -> tuple[float, float]:
    """CPU seconds (user and system) of this process and of its finished child processes (a batch's workers, once
    their pools are shut down)."""
    import resource  # Unix only, as this part's fork is

    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, children.ru_utime + children.ru_stime


def _stats(seconds: list[float]) -> dict:
    ms = np.array(seconds) * 1e3
    return {"n": len(ms), "median_ms": float(np.median(ms)), "p90_ms": float(np.percentile(ms, 90)),
            "p95_ms": float(np.percentile(ms, 95)), "mean_ms": float(ms.mean())}


def _run_worker(tree: Path, part: str, args: argparse.Namespace) -> dict:
    """One part in a fresh process over ``tree``'s package (this file's code)."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    command = [sys.executable, str(Path(__file__).resolve()), "--worker", part, "--data", str(args.data),
               "--refit-vehicles", str(args.refit_vehicles), "--jobs", str(args.jobs)]
    output = subprocess.run(command, env=env, capture_output=True, text=True, check=True).stdout
    return json.loads(output.strip().splitlines()[-1])


def _worker(part: str, args: argparse.Namespace) -> None:
    import toosicubix

    if part == "per-vehicle":
        result = per_vehicle_times(args.data)
    elif part == "refit":
        result = refit_times(args.data, args.refit_vehicles)
    else:
        result = apollocar3d_rate(args.data, args.jobs)
    result["package"] = str(Path(toosicubix.__file__).resolve().parents[1])
    print(json.dumps(result))


def _paired_server(args: argparse.Namespace) -> None:
    """Part 7's process over one checkout: warm, then fit the chunks it is told (``part first last`` a line) and say
    how long each took."""
    from toosicubix.pipeline.vehicle import fit_one
    from toosicubix.solver.fit import SolverOptions
    from toosicubix.web.session import NEXT_CLICKS

    tasks = kitti_tasks(args.data)
    options = SolverOptions()
    extra = {"per-vehicle": {}, "refit": {"next_clicks": NEXT_CLICKS}}
    for kwargs in extra.values():  # warm-up: imports, caches, the compiled solver
        for task in tasks[:10]:
            fit_one(*task, options, **kwargs)
    print(json.dumps({"ready": len(tasks), "refit": min(args.refit_vehicles, len(tasks))}), flush=True)
    for line in sys.stdin:
        part, first, last = line.split()
        start = time.perf_counter()
        for task in tasks[int(first):int(last)]:
            fit_one(*task, options, **extra[part])
        print(f"{time.perf_counter() - start:.9f}", flush=True)


def paired(args: argparse.Namespace, report: dict) -> None:
    """Part 7 of the module docstring."""
    trees = {"this": REPO, "against": args.against.resolve(), "this again": REPO}
    servers = {}
    for name, tree in trees.items():
        command = [sys.executable, str(Path(__file__).resolve()), "--worker", "paired", "--data", str(args.data),
                   "--refit-vehicles", str(args.refit_vehicles)]
        servers[name] = subprocess.Popen(command, env={**os.environ, "PYTHONPATH": str(tree)}, stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, text=True)
    try:
        sizes = [json.loads(server.stdout.readline()) for server in servers.values()]

        def run(name: str, part: str, first: int, last: int) -> float:
            servers[name].stdin.write(f"{part} {first} {last}\n")
            servers[name].stdin.flush()
            return float(servers[name].stdout.readline())

        out: dict = {"chunk": args.paired_chunk, "passes": args.rounds}
        for part, n in (("per-vehicle", sizes[0]["ready"]), ("refit", sizes[0]["refit"])):
            totals = {name: 0.0 for name in trees}
            ratios: dict[str, list[float]] = {"against": [], "this again": []}
            chunks = [(i, min(n, i + args.paired_chunk)) for i in range(0, n, args.paired_chunk)]
            for k in range(args.rounds):
                for c, (first, last) in enumerate(chunks):
                    for other in ("against", "this again"):
                        order = ("this", other) if (c + k) % 2 == 0 else (other, "this")
                        t = {name: run(name, part, first, last) for name in order}
                        totals["this"] += t["this"]
                        totals[other] += t[other]
                        ratios[other].append(t[other] / t["this"])
            entry = {"vehicles": n, "seconds": totals}
            for other in ratios:
                entry[other] = {"ratio_of_sums": 2.0 * totals[other] / totals["this"],  # "this" ran twice per chunk
                                "median_chunk_ratio": float(np.median(ratios[other]))}
            out[part] = entry
            against, again = entry["against"], entry["this again"]
            print(f"paired, {part} ({n} vehicles, chunks of {args.paired_chunk}, {args.rounds} passes): against / this "
                  f"{against['ratio_of_sums']:.3f} (chunk median {against['median_chunk_ratio']:.3f});"
                  f" this again / this {again['ratio_of_sums']:.3f} (chunk median "
                  f"{again['median_chunk_ratio']:.3f}, the harness's noise); > 1: this checkout is "
                  f"faster", flush=True)
    finally:
        for server in servers.values():
            server.stdin.close()
            server.wait()
    report["paired"] = out


def _trees(args: argparse.Namespace) -> dict[str, Path]:
    """The checkouts a run compares: this one, and ``--against``'s when given."""
    return {"this": REPO} | ({"against": args.against.resolve()} if args.against else {})


def interleaved(args: argparse.Namespace, report: dict) -> None:
    """Parts 1-3, ``args.rounds`` rounds, this checkout and ``args.against`` in turn."""
    trees = _trees(args)
    report["trees"] = {name: str(tree) for name, tree in trees.items()}
    for part in [p for p in ("per-vehicle", "apollocar3d", "refit") if p in args.parts]:
        runs: dict[str, list[dict]] = {name: [] for name in trees}
        for k in range(args.rounds):
            order = list(trees) if k % 2 == 0 else list(trees)[::-1]
            for name in order:
                runs[name].append(_run_worker(trees[name], part, args))
                if runs[name][-1]["package"] != str(trees[name]):
                    sys.exit(f"the worker for {trees[name]} imported toosicubix from {runs[name][-1]['package']}")
        out: dict = {}
        for name, rs in runs.items():
            if part == "apollocar3d":
                rates = [r["vehicles"] / r["seconds"] for r in rs]
                out[name] = {"vehicles": rs[0]["vehicles"], "ok": rs[0]["ok"], "jobs": args.jobs,
                             "vehicles_per_second": float(np.median(rates)), "per_round": rates,
                             "import_seconds": [r["import_seconds"] for r in rs]}
                if "main_cpu_seconds" in rs[0]:  # fit_file's CPU per car: the main process's share caps the workers
                    out[name]["main_cpu_ms_per_vehicle"] = float(np.median(
                        [1e3 * r["main_cpu_seconds"] / r["vehicles"] for r in rs]))
                    out[name]["workers_cpu_ms_per_vehicle"] = float(np.median(
                        [1e3 * r["workers_cpu_seconds"] / r["vehicles"] for r in rs]))
            elif part == "per-vehicle":
                pooled = [t for r in rs for t in r["seconds"]]
                fitted = [t for r in rs for t, ok in zip(r["seconds"], r["ok"], strict=True) if ok]
                out[name] = {"all": _stats(pooled), "fitted": _stats(fitted),
                             "per_round_median_ms": [_stats(r["seconds"])["median_ms"] for r in rs]}
            else:
                out[name] = {**_stats([t for r in rs for t in r["seconds"]]),
                             "per_round_median_ms": [_stats(r["seconds"])["median_ms"] for r in rs]}
        if "against" in out:
            if part == "apollocar3d":
                out["ratio"] = out["this"]["vehicles_per_second"] / out["against"]["vehicles_per_second"]
                out["ratio_per_round"] = [a / b for a, b in zip(out["this"]["per_round"], out["against"]["per_round"],
                                                                 strict=True)]
            else:
                key = out["this"]["all"] if part == "per-vehicle" else out["this"]
                other = out["against"]["all"] if part == "per-vehicle" else out["against"]
                out["ratio"] = {"median": other["median_ms"] / key["median_ms"], "p90": other["p90_ms"] / key["p90_ms"]}
                out["ratio_per_round"] = [a / b for a, b in zip(out["against"]["per_round_median_ms"],
                                                                 out["this"]["per_round_median_ms"], strict=True)]
        report[part] = out
        for name in trees:
            o = out[name]
            if part == "apollocar3d":
                line = (f"{o['vehicles_per_second']:.0f} vehicles/s with --jobs {o['jobs']} ({o['vehicles']} cars, "
                        f"{o['ok']} fitted; rounds {', '.join(f'{v:.0f}' for v in o['per_round'])})")
                if "main_cpu_ms_per_vehicle" in o:
                    line += (f"; fit_file's CPU a car: main process {o['main_cpu_ms_per_vehicle']:.2f} ms, workers "
                             f"{o['workers_cpu_ms_per_vehicle']:.2f} ms")
            else:
                o = o["all"] if part == "per-vehicle" else o
                rounds = ", ".join(f"{v:.2f}" for v in out[name]["per_round_median_ms"])
                line = (f"median {o['median_ms']:.2f} ms, p90 {o['p90_ms']:.2f} ms, mean {o['mean_ms']:.2f} ms "
                        f"(n={o['n']}; round medians {rounds})")
            print(f"{part}, {name} ({trees[name]}): {line}", flush=True)
        if "ratio" in out:
            print(f"{part}: ratio {json.dumps(out['ratio'])} (per round "
                  f"{', '.join(f'{v:.2f}' for v in out['ratio_per_round'])}); > 1: this checkout is faster", flush=True)


def test_split_file(data: Path, n: int, folder: Path) -> Path:
    """An annotation file of the first ``n`` vehicles of part 1's test split, 1 px click noise."""
    from toosicubix.simulate.annotator import (
        AnnotatorOptions,
        SelectionOptions,
        select_kitti_tracking,
        simulate,
        write_simulation,
    )

    vehicles = select_kitti_tracking(data / "kitti_tracking", SelectionOptions(sequences=SPLITS["test"]))[:n]
    path = folder / f"test-{n}.json"
    write_simulation(simulate(vehicles, AnnotatorOptions(noise_px=1.0)), path, folder / f"test-gt-{n}")
    return path


def whole(args: argparse.Namespace, report: dict) -> None:
    """Part 4 of the module docstring: each case's command in a fresh process over each checkout's package, the
    checkouts in turn (which goes first alternates by round); run from an empty folder, so that neither checkout's
    root is on the path."""
    trees = _trees(args)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        cases = {
            "--help": ["--help"],
            "fit, the bundled sample (6 vehicles)": ["fit", str(REPO / "samples" / "annotations.json"), "-q"],
            f"fit, {args.whole_vehicles} simulated KITTI vehicles": [
                "fit", str(test_split_file(args.data, args.whole_vehicles, folder)), "-q"],
        }
        runs = {case: {name: [] for name in trees} for case in cases}
        for k in range(args.rounds):
            for case, command in cases.items():
                for name in (list(trees) if k % 2 == 0 else list(trees)[::-1]):
                    extra = ["-o", str(folder / f"out-{name}")] if command[0] == "fit" else []
                    if k == 0:  # untimed: fills the bytecode cache, as an install or a first run does
                        _toosicubix(command + extra, folder, _user_env(trees[name], folder / f"pyc-{name}"))
                    start = time.perf_counter()
                    _toosicubix(command + extra, folder, _user_env(trees[name], folder / f"pyc-{name}"))
                    runs[case][name].append(time.perf_counter() - start)
        same = all(filecmp.cmp(a, folder / "out-against" / a.relative_to(folder / "out-this"), shallow=False)
                   for a in (folder / "out-this").rglob("*") if a.is_file()) if "against" in trees else None
    out: dict = {"trees": {name: str(tree) for name, tree in trees.items()}, "cases": {},
                 "last_outputs_identical": same}
    for case, by_tree in runs.items():
        entry = {name: {"median_s": float(np.median(v)), "seconds": v} for name, v in by_tree.items()}
        if "against" in entry:
            entry["ratio"] = entry["against"]["median_s"] / entry["this"]["median_s"]
        out["cases"][case] = entry
        print(f"whole, {case}: " + "; ".join(f"{name} {e['median_s']:.3f} s" for name, e in entry.items()
                                               if name != "ratio")
              + (f"; ratio {entry['ratio']:.3f} (> 1: this checkout is faster)" if "ratio" in entry else ""),
              flush=True)
    if same is not None:
        print(f"whole: the last fit's folders identical: {same}", flush=True)
    report["whole"] = out


def _user_env(tree: Path, pycache: Path) -> dict[str, str]:
    """A child's environment as a user's install gives it: ``tree``'s package, and Python's bytecode cached (``pip
    install`` compiles it; an editable install writes it at the first import). Some machines set
    ``PYTHONDONTWRITEBYTECODE``, which would make every process compile the package's source again (0.1-0.3 s)."""
    env = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
    return {**env, "PYTHONPATH": str(tree), "PYTHONPYCACHEPREFIX": str(pycache)}


def _toosicubix(arguments: list[str], folder: Path, env: dict[str, str]) -> None:
    subprocess.run([sys.executable, "-m", "toosicubix", *arguments], cwd=folder, env=env, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL, check=False)


def annotation_file(data: Path, n: int, folder: Path) -> Path:
    """An annotation file of the first ``n`` vehicles of all tracking sequences, every frame, 1 px noise."""
    from toosicubix.simulate.annotator import (
        AnnotatorOptions,
        SelectionOptions,
        select_kitti_tracking,
        simulate,
        write_simulation,
    )

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
    from toosicubix.simulate.annotator import (
        AnnotatorOptions,
        SelectionOptions,
        select_kitti_tracking,
        simulate,
        write_simulation,
    )

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


def throughput(args: argparse.Namespace, report: dict) -> None:
    """Part 4 of the module docstring (this checkout only)."""
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


def memory(args: argparse.Namespace, report: dict) -> None:
    """Part 5 of the module docstring (this checkout only)."""
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


PARTS = ("per-vehicle", "apollocar3d", "refit", "whole", "throughput", "memory", "paired")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=default_data_dir())
    parser.add_argument("--parts", default="per-vehicle,apollocar3d,refit",
                        help=f"comma-separated, of {', '.join(PARTS)}")
    parser.add_argument("--against", type=Path, default=None,
                        help="another checkout (its repository root) to run parts 1-4 against, round by round")
    parser.add_argument("--rounds", type=int, default=3, help="rounds of parts 1-4 (each checkout once a round)")
    parser.add_argument("--jobs", type=int, default=2, help="processes of the apollocar3d part")
    parser.add_argument("--refit-vehicles", type=int, default=100, help="vehicles of the refit part")
    parser.add_argument("--whole-vehicles", type=int, default=306, help="vehicles of the whole part's batch")
    parser.add_argument("--throughput-vehicles", type=int, default=3000)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--memory-vehicles", default="1000,10000,100000",
                        help="batch sizes for the --jobs 2 peak-memory part, comma-separated")
    parser.add_argument("--memory-parts", type=int, default=None,
                        help="keep only this many parts per vehicle in the peak-memory part (1: every vehicle "
                             "fails at once; the batch's own memory without the solver's time)")
    parser.add_argument("--only", choices=["memory"], default=None,
                        help="memory: the same as --parts memory (the earlier spelling)")
    parser.add_argument("--paired-chunk", type=int, default=10, help="vehicles a chunk of the paired part")
    parser.add_argument("--worker", choices=(*PARTS[:3], "paired"), default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker == "paired":
        _paired_server(args)
        return
    if args.worker is not None:
        _worker(args.worker, args)
        return
    if args.only == "memory":
        args.parts = "memory"
    args.parts = [p.strip() for p in args.parts.split(",")]
    if unknown := [p for p in args.parts if p not in PARTS]:
        sys.exit(f"unknown part(s) {', '.join(unknown)}; known: {', '.join(PARTS)}")
    if not (args.data / "kitti_tracking").is_dir():
        sys.exit(f"no KITTI tracking data at {args.data / 'kitti_tracking'} (set --data)")
    if args.against is not None and not (args.against / "toosicubix" / "__init__.py").is_file():
        sys.exit(f"--against {args.against}: no toosicubix package there (give a checkout's root)")
    report: dict = {"machine": machine(), "command": " ".join(sys.argv),
                    "load_average": list(os.getloadavg())}
    print(f"machine: {report['machine']}; load average {report['load_average']}", flush=True)
    interleaved(args, report)
    if "whole" in args.parts:
        whole(args, report)
    if "paired" in args.parts:
        if args.against is None:
            sys.exit("the paired part compares two checkouts: give --against")
        paired(args, report)
    if "throughput" in args.parts:
        throughput(args, report)
    if "memory" in args.parts:
        memory(args, report)
    report["load_average_after"] = list(os.getloadavg())
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
