"""kill -9 trials of ``toosicubix fit`` in its write phase: is the output folder ever left mixed?

Each trial starts from an output folder holding a complete earlier output (run A, or none for a
first-run trial), starts ``toosicubix fit`` with a different annotation file (run B) and the write-phase
pause hook (``TOOSICUBIX_PAUSE_BETWEEN_WRITES``), waits until its staging folder appears, then kills it with
SIGKILL after a random delay inside the write phase. The folder must then hold exactly A's files (or, for
a first run, nothing, or exactly B's: a kill after the swap), never a mixture; then a normal run B into
the same folder must succeed, give exactly B's files and leave no staging folder behind.

    python benchmarks/fuzz_kill.py --trials 20 [--json benchmarks/results/fuzz-kill.json]

:func:`kill_trials` is what ``benchmarks/fuzz.py`` calls.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "samples" / "annotations.json"


def snapshot(folder: Path) -> dict[str, bytes] | None:
    """Every file under ``folder`` by relative path, with its bytes; None when the folder is missing."""
    if not folder.exists():
        return None
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _fit(annotations: Path, out: Path, pause: float | None = None) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    if pause is not None:
        env["TOOSICUBIX_PAUSE_BETWEEN_WRITES"] = str(pause)
    return subprocess.Popen([sys.executable, "-m", "toosicubix", "fit", str(annotations), "-o", str(out), "-q"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def annotation_files(folder: Path, images: int) -> tuple[Path, Path]:
    """Two different annotation files (A, B) of ``images`` images each, from the bundled sample."""
    doc = json.loads(SAMPLE.read_text())
    paths = []
    for tag in ("a", "b"):
        d = copy.deepcopy(doc)
        d["images"] = [{**copy.deepcopy(doc["images"][k % len(doc["images"])]), "id": f"{tag}{k:04d}"}
                       for k in range(images)]
        path = folder / f"{tag}.json"
        path.write_text(json.dumps(d))
        paths.append(path)
    return paths[0], paths[1]


def kill_trials(trials: int, images: int = 6, pause: float = 0.05, seed: int = 0,
                first_run_share: float = 0.3, timeout_s: float = 120.0) -> dict:
    """Run ``trials`` kill -9 trials; return the counts (``mixed`` is the figure that must be 0)."""
    rng = np.random.default_rng(seed)
    counts = {"trials": 0, "mixed": 0, "previous_kept": 0, "new_complete": 0, "absent": 0,
              "rerun_failed": 0, "staging_left_after_rerun": 0, "kill_missed": 0}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        ann_a, ann_b = annotation_files(folder, images)
        reference = {}
        for tag, ann in (("a", ann_a), ("b", ann_b)):
            ref = folder / f"ref-{tag}"
            if _fit(ann, ref).wait(timeout_s) not in (0, 1):
                raise RuntimeError(f"reference run {tag} failed")
            reference[tag] = snapshot(ref)
        write_phase = (images + 2) * pause
        for trial in range(trials):
            out = folder / f"out-{trial}"
            first_run = rng.random() < first_run_share
            if not first_run:
                shutil.copytree(folder / "ref-a", out)
            process = _fit(ann_b, out, pause)
            deadline = time.monotonic() + timeout_s
            while not list(folder.glob(f".{out.name}.toosicubix-new-*")) and process.poll() is None:
                if time.monotonic() > deadline:
                    process.kill()
                    raise RuntimeError("no staging folder appeared")
                time.sleep(0.002)
            time.sleep(float(rng.uniform(0.0, write_phase)))
            if process.poll() is not None:
                counts["kill_missed"] += 1
            else:
                os.kill(process.pid, signal.SIGKILL)
            process.wait()
            state = snapshot(out)
            counts["trials"] += 1
            if state is None:
                counts["absent" if first_run else "mixed"] += 1
            elif state == reference["b"]:
                counts["new_complete"] += 1
            elif not first_run and state == reference["a"]:
                counts["previous_kept"] += 1
            else:
                counts["mixed"] += 1
            if _fit(ann_b, out).wait(timeout_s) not in (0, 1) or snapshot(out) != reference["b"]:
                counts["rerun_failed"] += 1
            if list(folder.glob(f".{out.name}.toosicubix-*")):
                counts["staging_left_after_rerun"] += 1
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--images", type=int, default=6)
    parser.add_argument("--pause", type=float, default=0.05, help="seconds after each file written")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    start = time.perf_counter()
    counts = kill_trials(args.trials, args.images, args.pause, args.seed)
    counts["seconds"] = time.perf_counter() - start
    print(", ".join(f"{k} {v:.0f}" if isinstance(v, float) else f"{k} {v}" for k, v in counts.items()))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(counts, indent=1) + "\n")
    sys.exit(1 if counts["mixed"] or counts["rerun_failed"] or counts["staging_left_after_rerun"] else 0)


if __name__ == "__main__":
    main()
