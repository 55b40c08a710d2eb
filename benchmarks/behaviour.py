"""Behaviour unchanged: run a fixed list of command lines and record what each one did, then compare two records.

A reshaping of the code (issues 12, 31) or a change made for speed (issue 37) must not change what a command
prints, writes or returns. This runs each command line of :data:`COMMANDS` in a fresh working folder (always the
same path, so that paths printed or written agree between runs) that holds a copy of the bundled sample and, when
the shared data is present, small extracts of it; it records the exit code, stdout, stderr and every file the
command left (its bytes' SHA-256, and the text of small text files), in one JSON file per run.

Record the code before and after a change, then compare:

    PYTHONPATH=/path/to/old python benchmarks/behaviour.py record /tmp/old.json
    python benchmarks/behaviour.py record /tmp/new.json
    python benchmarks/behaviour.py compare /tmp/old.json /tmp/new.json

``compare`` prints every command whose exit code, output or files differ (with the first differing lines) and
exits 1 when any does. Timing lines (seconds, items per second) are the only text it ignores.
"""

from __future__ import annotations

import argparse
import difflib
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import REPO, default_data_dir

#: The folder the commands run in, the same path for every record.
WORK = Path("/tmp/toosicubix-behaviour")
#: Text files up to this size are kept whole in the record (for a readable diff); larger ones by hash only.
KEEP_TEXT = 200_000

#: (name, argv after ``toosicubix``). ``$DATA`` is the shared data folder; commands that need it are left out when
#: it is absent (the record says which ran).
COMMANDS: list[tuple[str, list[str]]] = [
    ("help", ["--help"]),
    *[(f"help-{c}", [*c.split(), "--help"]) for c in (
        "fit", "validate", "eval", "render", "schema", "simulate", "priors", "tune", "template", "annotate",
        "import", "import coco", "import cvat", "import label-studio", "export", "export openlabel", "export cvat",
        "learn-parts")],
    ("schema", ["schema"]),
    ("fit", ["fit", "samples/annotations.json"]),
    ("fit-next", ["fit", "samples/annotations.json", "--next-clicks", "3", "-o", "out-next"]),
    ("fit-joint", ["fit", "samples/annotations.json", "--kitti-ground", "--joint-ground", "-o", "out-joint"]),
    ("fit-height", ["fit", "samples/annotations.json", "--camera-height", "1.65", "--upright-sigma-deg", "3",
                    "-o", "out-height"]),
    ("fit-options", ["fit", "samples/annotations.json", "--road-normal", "none", "--robust-loss", "cauchy",
                     "--misfit-level", "0.99", "--click-sigma", "1", "--part-sigma", "0.05", "--lambda-p", "5",
                     "-o", "out-options"]),
    ("fit-jobs", ["fit", "samples/annotations.json", "--jobs", "2", "-o", "out-jobs", "-q"]),
    ("validate-all", ["validate", "samples/annotations.json", "--all"]),
    ("validate-json", ["validate", "samples/annotations.json", "--json"]),
    ("validate-kitti-ground", ["validate", "samples/annotations.json", "--kitti-ground", "--all"]),
    ("eval", ["eval", "--kitti", "samples/ground_truth"]),
    ("eval-files", ["eval", "--kitti", "samples/ground_truth", "--json", "eval.json", "--csv", "eval.csv"]),
    ("eval-joint", ["eval", "out-joint", "--kitti", "samples/ground_truth"]),
    ("render", ["render", "--png-compression", "9"]),
    ("render-gt", ["render", "out-next", "--kitti", "samples/ground_truth", "-o", "render-gt"]),
    ("export-openlabel", ["export", "openlabel", "toosicubix-out", "-o", "labels.json"]),
    ("export-cvat", ["export", "cvat", "toosicubix-out", "-o", "review.xml"]),
    ("template-ls", ["template", "label-studio"]),
    ("template-cvat", ["template", "cvat"]),
    ("template-coco", ["template", "coco"]),
    # bad input and usage
    ("fit-missing", ["fit", "missing.json"]),
    ("fit-not-json", ["fit", "samples/ground_truth/calib/000001.txt"]),
    ("fit-bad-schema", ["fit", "bad.json", "-o", "out-bad"]),
    ("fit-unknown-prototype", ["fit", "unknown-prototype.json", "-o", "out-bad"]),
    ("fit-into-dataset", ["fit", "samples/annotations.json", "-o", "samples/ground_truth"]),
    ("fit-both-normals", ["fit", "samples/annotations.json", "--road-normal", "0,-1,0", "--camera-pitch-deg", "1"]),
    ("validate-bad", ["validate", "bad.json"]),
    ("eval-no-gt", ["eval"]),
    ("eval-missing", ["eval", "--kitti", "nowhere"]),
    ("export-missing", ["export", "openlabel", "nowhere", "-o", "x.json"]),
    ("render-missing", ["render", "nowhere"]),
    ("import-ls-bad", ["import", "label-studio", "bad.json", "-o", "imported.json"]),
    ("import-cvat-bad", ["import", "cvat", "bad.json", "-o", "imported.json"]),
    ("import-coco-bad", ["import", "coco", "bad.json", "--mapping", "toosicubix", "-o", "imported.json"]),
    # on the shared data
    ("simulate", ["simulate", "--kitti-tracking", "$DATA/kitti_tracking", "--sequences", "0010-0011", "--noise", "1",
                  "--frames-per-track", "2", "-o", "sim.json"]),
    ("fit-sim", ["fit", "sim.json", "-o", "out-sim", "--next-clicks", "2"]),
    ("eval-sim", ["eval", "out-sim", "--kitti", "sim_gt", "--json", "eval-sim.json"]),
    ("eval-tracking", ["eval", "out-sim", "--kitti-tracking", "$DATA/kitti_tracking"]),
    ("validate-sim", ["validate", "sim.json", "--json"]),
    ("tune", ["tune", "sim.json", "--kitti", "sim_gt", "--lambdas", "0.1", "--lambda-ps", "1,10", "--no-refine",
              "-o", "settings.json"]),
    ("fit-config", ["fit", "sim.json", "--config", "settings.json", "-o", "out-config", "-q"]),
    ("priors", ["priors", "--kitti-tracking", "$DATA/kitti_tracking", "--sequences", "0000-0002", "-o", "priors.json"]),
    ("priors-kitti", ["priors", "--kitti", "$DATA/kitti", "-o", "priors-kitti.json"]),
    ("fit-priors", ["fit", "samples/annotations.json", "--priors", "priors.json", "-o", "out-priors"]),
    ("import-coco", ["import", "coco", "ac.json", "--mapping", "apollocar3d-66", "--cameras",
                     "$DATA/apollocar3d/cameras.json", "-o", "ac-annotations.json"]),
    ("import-coco-paper", ["import", "coco", "ac.json", "--mapping", "apollocar3d-66-paper", "--option", "hubs",
                           "--cameras", "$DATA/apollocar3d/cameras.json", "-o", "ac-paper.json"]),
    ("fit-ac", ["fit", "ac-annotations.json", "-o", "out-ac", "--next-clicks", "2", "--mapping", "apollocar3d-66"]),
    ("fit-ac-paper", ["fit", "ac-paper.json", "-o", "out-ac-paper"]),
    ("validate-ac", ["validate", "ac-annotations.json", "--mapping", "apollocar3d-66"]),
    ("eval-ac", ["eval", "out-ac", "--apollocar3d", "ac.json", "--car-models", "$DATA/apollocar3d/car_models.json",
                 "--cameras", "$DATA/apollocar3d/cameras.json", "--json", "eval-ac.json", "--csv", "eval-ac.csv"]),
    ("render-ac", ["render", "out-ac", "--apollocar3d", "ac.json", "-o", "render-ac"]),
    ("export-openlabel-ac", ["export", "openlabel", "out-ac", "-o", "labels-ac.json"]),
    ("learn-parts", ["learn-parts", "ac.json", "--car-models", "$DATA/apollocar3d/car_models.json", "--cameras",
                     "$DATA/apollocar3d/cameras.json", "-o", "mapping.json"]),
    ("priors-ac", ["priors", "--apollocar3d", "ac.json", "--car-models", "$DATA/apollocar3d/car_models.json",
                   "-o", "priors-ac.json"]),
    ("eval-kitti-object", ["eval", "out-sim", "--kitti", "$DATA/kitti"]),
]

#: Lines that carry a duration or a rate: compared without their numbers.
_TIMING = re.compile(r"(\d+(\.\d+)?\s*(s|ms|seconds|vehicles/s|it/s)\b|\d\d:\d\d:\d\d|ETA|\[#*-*\])")


def _prepare(data: Path | None) -> None:
    if WORK.exists():
        shutil.rmtree(WORK)
    WORK.mkdir(parents=True)
    shutil.copytree(REPO / "samples", WORK / "samples")
    (WORK / "bad.json").write_text('{"toosicubix": 1, "images": [{"id": "a b", "camera": {"K": [[1, 0], [0, 1]]}, '
                                   '"vehicles": [{"id": "1", "prototype": "Car", "parts": [{"kind": "point", '
                                   '"part": "wheel-middle", "xy": [1, "x"]}]}]}], "extra": 1}\n')
    sample = json.loads((REPO / "samples" / "annotations.json").read_text())
    sample["images"][0]["vehicles"][0]["prototype"] = "Spaceship"
    (WORK / "unknown-prototype.json").write_text(json.dumps(sample))
    if data is not None:
        coco = json.loads((data / "apollocar3d" / "apollocar3d_val_dev.json").read_text())
        keep = {im["id"] for im in coco["images"][:6]}
        coco["images"] = [im for im in coco["images"] if im["id"] in keep]
        coco["annotations"] = [a for a in coco["annotations"] if a["image_id"] in keep]
        (WORK / "ac.json").write_text(json.dumps(coco))
        shutil.copy(data / "apollocar3d" / "car_models.json", WORK / "car_models.json")


def _files(root: Path) -> dict[str, dict[str, str]]:
    out = {}
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        blob = path.read_bytes()
        entry = {"sha256": hashlib.sha256(blob).hexdigest()}
        if len(blob) <= KEEP_TEXT and path.suffix in (".json", ".txt", ".csv", ".xml"):
            try:
                entry["text"] = blob.decode("utf-8")
            except UnicodeDecodeError:
                pass
        out[str(path.relative_to(root))] = entry
    return out


def record(out: Path, data: Path | None) -> None:
    """Run every command of :data:`COMMANDS` and write what each did to ``out`` (JSON)."""
    _prepare(data)
    env = {**os.environ, "COLUMNS": "100", "TOOSICUBIX_SHARED_DATA": str(data) if data else ""}
    runs = []
    for name, argv in COMMANDS:
        if any("$DATA" in a for a in argv) and data is None:
            continue
        argv = [a.replace("$DATA", str(data)) for a in argv]
        before = _files(WORK)
        proc = subprocess.run([sys.executable, "-m", "toosicubix", *argv], cwd=WORK, capture_output=True,
                              text=True, env=env, timeout=1800)
        after = _files(WORK)
        changed = {k: v for k, v in after.items() if before.get(k) != v}
        runs.append({"name": name, "argv": argv, "exit": proc.returncode, "stdout": proc.stdout,
                     "stderr": proc.stderr, "files": changed})
        print(f"{name}: exit {proc.returncode}, {len(changed)} files", file=sys.stderr)
    out.write_text(json.dumps({"commands": runs}, indent=1) + "\n")


def _lines(text: str) -> list[str]:
    return [_TIMING.sub("<t>", line) for line in text.splitlines()]


def compare(old_path: Path, new_path: Path) -> int:
    """Print every command whose exit code, output or files differ; 1 when any does."""
    old = {r["name"]: r for r in json.loads(old_path.read_text())["commands"]}
    new = {r["name"]: r for r in json.loads(new_path.read_text())["commands"]}
    differ = 0
    for name in sorted(set(old) | set(new)):
        a, b = old.get(name), new.get(name)
        if a is None or b is None:
            print(f"{name}: only in {'new' if a is None else 'old'}")
            differ += 1
            continue
        problems = []
        if a["exit"] != b["exit"]:
            problems.append(f"exit {a['exit']} -> {b['exit']}")
        for stream in ("stdout", "stderr"):
            la, lb = _lines(a[stream]), _lines(b[stream])
            if la != lb:
                diff = list(difflib.unified_diff(la, lb, lineterm="", n=0))[2:12]
                problems.append(f"{stream} differs:\n    " + "\n    ".join(diff))
        for file in sorted(set(a["files"]) | set(b["files"])):
            fa, fb = a["files"].get(file), b["files"].get(file)
            if fa is None or fb is None:
                problems.append(f"file {file} only {'new' if fa is None else 'old'}")
            elif fa["sha256"] != fb["sha256"]:
                detail = ""
                if "text" in fa and "text" in fb:
                    diff = list(difflib.unified_diff(fa["text"].splitlines(), fb["text"].splitlines(), lineterm="",
                                                     n=0))[2:8]
                    detail = ":\n    " + "\n    ".join(diff)
                problems.append(f"file {file} differs{detail}")
        if problems:
            differ += 1
            print(f"{name} ({' '.join(b['argv'])}):")
            for p in problems:
                print(f"  {p}")
    print(f"{len(set(old) & set(new))} commands compared, {differ} differ")
    return 1 if differ else 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    rec = sub.add_parser("record", help="run the commands, write their record")
    rec.add_argument("out", type=Path)
    rec.add_argument("--data", type=Path, default=None, help="shared data folder [default: ../shared/data]")
    cmp_ = sub.add_parser("compare", help="compare two records")
    cmp_.add_argument("old", type=Path)
    cmp_.add_argument("new", type=Path)
    args = parser.parse_args()
    if args.what == "record":
        data = args.data or default_data_dir()
        record(args.out, data if data.is_dir() else None)
    else:
        sys.exit(compare(args.old, args.new))


if __name__ == "__main__":
    main()
