"""Hostile input for ``toosicubix fit``, ``validate`` and ``eval``: mutated files, one command (issue 13, item 7).

Every trial mutates the bundled sample annotation file once (structural: keys dropped, added, renamed, nodes
replaced, duplicated or nested deep; numeric: a number replaced by an extreme, NaN, infinity or a huge
integer, clicks scaled, made collinear or clustered; text: bytes cut, inserted, replaced, a BOM, non-UTF-8
bytes), runs ``fit`` and ``validate`` on it, then ``eval`` of the fit's output against a copy of the sample's
ground truth whose label or calibration file got a text or numeric mutation of its own in every second trial.
The commands run in-process through click's ``CliRunner`` (about 0.1 s a command) with a per-command timeout.

It counts, per command:

- tracebacks: any exception other than the command's own exit (the targets of issue 13 are 0);
- exit codes other than 0, 1, 2, and exit code 2 without an ``Error:`` message;
- non-finite values written: a NaN or infinity in any JSON, label or CSV file written;
- files outside the output folder: anything new in the trial's folder but the input and the outputs;
- hangs: a command over the timeout (20 s).

Each finding's input is kept under ``--keep`` for reproduction. Run from the repository root:

    python benchmarks/fuzz.py [--files 10000] [--workers 1] [--seed 0] [--json benchmarks/results/fuzz.json]

Then ``--kill-trials N`` (default 20) kill -9 runs of ``fit`` in its write phase (:mod:`fuzz_kill`), counting folders
left mixed or refused by the next run (the second half of item 7).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import multiprocessing
import random
import shutil
import signal
import sys
import tempfile
import time
import traceback
from collections import Counter
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from click.testing import CliRunner  # noqa: E402

from toosicubix.cli import main  # noqa: E402

SAMPLE = REPO / "samples" / "annotations.json"
SAMPLE_GT = REPO / "samples" / "ground_truth"
#: The image whose ground truth eval scores (one vehicle: keeps a trial near 0.3 s).
SMALL_IMAGE = 2
CLICK_KEYS = ("xy", "left", "right", "tail", "head")
EXTREMES: tuple[Any, ...] = (
    0, -0.0, -1, 1e-308, 5e-324, 1e308, -1e308, 1e9, -1e9, 1e-9, float("nan"), float("inf"), float("-inf"),
    2**63, 10**400, 1e6, 1e6 + 1, -1e6 - 1, 100.0, 100.0001, 1e-4, 0.5, True, "1", None,
)
TEXT_NOISE = (b"\xff", b"\xfe\xff", b"\xef\xbb\xbf", b"\x00", b"\xc3", b"\"", b"\\", b"{", b"[", b"]", b"}", b",",
              b"NaN", b"Infinity", b"-", b"1e999", b"\n", "é".encode(), "\u2028".encode())


# --- mutations ------------------------------------------------------------------------------------------

def _nodes(doc: Any, path: tuple = ()) -> list[tuple[tuple, Any]]:
    """Every (path, node) of a JSON document, the root included."""
    out = [(path, doc)]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _nodes(v, (*path, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _nodes(v, (*path, i))
    return out


def _set(doc: Any, path: tuple, value: Any) -> Any:
    if not path:
        return value
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    parent[path[-1]] = value
    return doc


def _parent(doc: Any, path: tuple) -> Any:
    for key in path[:-1]:
        doc = doc[key]
    return doc


def mutate_structure(doc: Any, rng: random.Random) -> tuple[Any, str]:
    nodes = _nodes(doc)
    path, node = rng.choice(nodes)
    kind = rng.choice(["drop", "replace", "duplicate", "unknown_key", "rename", "nest", "swap", "empty_list"])
    if kind == "drop" and path:
        del _parent(doc, path)[path[-1]]
    elif kind == "replace":
        doc = _set(doc, path, copy.deepcopy(rng.choice([None, {}, [], "x", 0, True, [1, 2], {"a": 1}, "a" * 300])))
    elif kind == "duplicate" and isinstance(node, list) and node:
        node.extend(copy.deepcopy(rng.choice(node)) for _ in range(rng.choice([1, 2, 10, 50])))
    elif kind == "unknown_key" and isinstance(node, dict):
        node[rng.choice(["extra", "id", "K", "P", "parts", "", "\u0000"])] = rng.choice([1, "x", None, []])
    elif kind == "rename" and isinstance(node, dict) and node:
        key = rng.choice(list(node))
        node[key + rng.choice(["_", "X", " "])] = node.pop(key)
    elif kind == "nest":
        depth = rng.choice([2, 10, 31, 33, 200, 1000, 5000])
        value: Any = node
        for _ in range(depth):
            value = [value] if rng.random() < 0.5 else {"a": value}
        doc = _set(doc, path, value)
    elif kind == "swap":
        other_path, other = rng.choice(nodes)
        if path and other_path and path[: len(other_path)] != other_path and other_path[: len(path)] != path:
            doc = _set(doc, path, copy.deepcopy(other))
    elif kind == "empty_list" and isinstance(node, list):
        node.clear()
    return doc, f"structure:{kind}"


def mutate_numbers(doc: Any, rng: random.Random) -> tuple[Any, str]:
    numbers = [(p, v) for p, v in _nodes(doc) if isinstance(v, int | float) and not isinstance(v, bool)]
    vehicles = [v for im in doc.get("images", []) if isinstance(im, dict)
                for v in im.get("vehicles", []) if isinstance(v, dict)] if isinstance(doc, dict) else []
    kind = rng.choice(["extreme", "extreme", "perturb", "scale_clicks", "collinear", "clustered", "camera"])
    if kind in ("scale_clicks", "collinear", "clustered") and vehicles:
        vehicle = rng.choice(vehicles)
        factor = rng.choice([1e9, -1.0, 1e-9, 1e3, 0.0, -1e5])
        k = 0
        for part in vehicle.get("parts", []):
            for key in CLICK_KEYS:
                if isinstance(part, dict) and isinstance(part.get(key), list) and len(part[key]) == 2:
                    x, y = part[key]
                    if not all(isinstance(c, int | float) for c in (x, y)):
                        continue
                    part[key] = ([x * factor, y * factor] if kind == "scale_clicks"
                                 else [300.0 + 17.0 * k, 200.0] if kind == "collinear" else [500.0 + k % 2, 200.0])
                    k += 1
        if rng.random() < 0.5:
            vehicle.pop("box2d", None)
        return doc, f"numeric:{kind}"
    if kind == "camera":
        cameras = [n for p, n in _nodes(doc) if p and p[-1] in ("K", "P") and isinstance(n, list)]
        if cameras:
            camera = rng.choice(cameras)
            row = rng.randrange(len(camera))
            if isinstance(camera[row], list) and camera[row]:
                camera[row][rng.randrange(len(camera[row]))] = rng.choice(EXTREMES)
            return doc, "numeric:camera"
    if not numbers:
        return doc, "numeric:none"
    path, value = rng.choice(numbers)
    if kind == "perturb":
        new = value * rng.choice([-1, 10, 1e6, 1e-6, 0.5]) + rng.choice([0, 0.5, -1])
    else:
        new = rng.choice(EXTREMES)
    return _set(doc, path, new), f"numeric:{kind}"


def mutate_text(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    kind = rng.choice(["truncate", "delete", "insert", "replace", "duplicate", "bom", "latin1"])
    n = len(data)
    i = rng.randrange(n + 1)
    if kind == "truncate":
        return data[:i], "text:truncate"
    if kind == "delete":
        return data[:i] + data[i + rng.randint(1, 64):], "text:delete"
    if kind == "insert":
        return data[:i] + rng.choice(TEXT_NOISE) + data[i:], "text:insert"
    if kind == "replace":
        return data[:i] + bytes([rng.randrange(256)]) + data[i + 1:], "text:replace"
    if kind == "duplicate":
        j = min(n, i + rng.randint(1, 200))
        return data[:j] + data[i:j] + data[j:], "text:duplicate"
    if kind == "bom":
        return b"\xef\xbb\xbf" + data, "text:bom"
    return data.replace(b'"Car"', b'"C\xe4r"', 1), "text:latin1"


def mutated_annotations(index: int, seed: int) -> tuple[bytes, str]:
    """The ``index``-th mutated annotation file: (bytes, kind of mutation)."""
    rng = random.Random(f"{seed}/annotations/{index}")
    doc = json.loads(SAMPLE.read_text())
    if rng.random() < 0.8:
        doc["images"] = [doc["images"][SMALL_IMAGE]]
    family = index % 3
    if family == 0:
        doc, kind = mutate_structure(doc, rng)
    elif family == 1:
        doc, kind = mutate_numbers(doc, rng)
    else:
        data, kind = mutate_text(json.dumps(doc, indent=rng.choice([None, 1])).encode(), rng)
        return data, kind
    try:
        text = json.dumps(doc)
    except (ValueError, RecursionError):
        return b"[" * 5000, kind + ":unserialisable"
    return text.encode(), kind


def mutate_ground_truth(gt_dir: Path, index: int, seed: int) -> str:
    """Mutate the label or calibration file of the scored image in ``gt_dir``; the kind of mutation."""
    rng = random.Random(f"{seed}/ground_truth/{index}")
    name = f"{SMALL_IMAGE + 1:06d}.txt"
    path = gt_dir / rng.choice(["label_2", "calib"]) / name
    data = path.read_bytes()
    if rng.random() < 0.5:
        tokens = data.split(b" ")
        k = rng.randrange(len(tokens))
        tokens[k] = str(rng.choice(EXTREMES)).encode() + (b"\n" if tokens[k].endswith(b"\n") else b"")
        path.write_bytes(b" ".join(tokens))
        return f"gt-numeric:{path.parent.name}"
    new, kind = mutate_text(data, rng)
    path.write_bytes(new)
    return f"gt-{kind}:{path.parent.name}"


# --- checks ---------------------------------------------------------------------------------------------

class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang()


def run_command(args: list[str], timeout: float) -> dict[str, Any]:
    """Run one command in-process; its exit code, output, exception and seconds."""
    signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    start = time.perf_counter()
    try:
        result = CliRunner().invoke(main, args, catch_exceptions=True)
    except Hang:
        return {"hang": True, "seconds": time.perf_counter() - start}
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
    seconds = time.perf_counter() - start
    exc = result.exc_info[1] if result.exc_info else None
    if isinstance(exc, Hang):
        return {"hang": True, "seconds": seconds}
    out: dict[str, Any] = {"exit": result.exit_code, "output": result.output, "seconds": seconds, "hang": False}
    if exc is not None and not isinstance(exc, SystemExit):
        frame = traceback.extract_tb(exc.__traceback__)[-1]
        out["traceback"] = f"{type(exc).__name__} at {Path(frame.filename).name}:{frame.lineno}: {str(exc)[:200]}"
    return out


def _reject_constant(name: str) -> None:
    raise ValueError(f"non-finite literal {name}")


def non_finite_in(path: Path) -> str | None:
    """Where a written file holds a NaN or an infinity, else None."""
    data = path.read_bytes()
    if path.suffix == ".json":
        try:
            json.loads(data, parse_constant=_reject_constant)
        except ValueError as exc:
            return str(exc)[:100] if "non-finite" in str(exc) else None
        return None
    text = data.decode("utf-8", "replace")
    for number, line in enumerate(text.splitlines(), 1):
        for token in line.replace(",", " ").split():
            try:
                value = float(token)
            except ValueError:
                continue
            if not math.isfinite(value):
                return f"line {number}: {token}"
    return None


# --- trials ---------------------------------------------------------------------------------------------

def trial(index: int, seed: int, work: Path, timeout: float, baseline_out: Path) -> tuple[list[dict[str, Any]], Path]:
    """One mutated annotation file through fit and validate, and eval of its output; findings per command."""
    folder = work / f"t{index}"
    folder.mkdir()
    data, kind = mutated_annotations(index, seed)
    ann = folder / "annotations.json"
    ann.write_bytes(data)
    out = folder / "out"
    gt = folder / "gt"
    shutil.copytree(SAMPLE_GT, gt)
    gt_kind = mutate_ground_truth(gt, index, seed) if index % 2 == 1 else "gt-unchanged"
    before = {ann, gt, *gt.rglob("*")}
    records = []
    for command, args in (
        ("fit", ["fit", str(ann), "-o", str(out), "-q"]),
        ("validate", ["validate", str(ann), "-q", "--json"]),
        ("eval", ["eval", str(out if (out / "label_2").is_dir() else baseline_out), "--kitti", str(gt), "-q",
                  "--json", str(out / "eval.json"), "--csv", str(out / "eval.csv")]),
    ):
        r = run_command(args, timeout)
        r.update(command=command, index=index, kind=kind if command != "eval" else gt_kind)
        if command == "validate" and not r.get("hang") and r.get("exit") in (0, 1):
            try:
                json.loads(r["output"], parse_constant=_reject_constant)
            except ValueError as exc:  # not JSON at all is a traceback's doing, counted as such
                if "non-finite" in str(exc):
                    r["non_finite"] = f"stdout: {str(exc)[:100]}"
        records.append(r)
    written = [p for p in out.rglob("*") if p.is_file()] if out.is_dir() else []
    for p in written:
        bad = non_finite_in(p)
        if bad is not None:
            records[0 if p.parent.name == "label_2" or p.name == "results.json" else 2]["non_finite"] = \
                f"{p.relative_to(folder)}: {bad}"
    outside = sorted(str(p.relative_to(folder)) for p in folder.rglob("*")
                     if p not in before and out not in p.parents and p != out)
    if outside:
        records[0]["outside"] = outside[:5]
    for r in records:
        r["finding"] = bool(r.get("traceback") or r.get("hang") or r.get("non_finite") or r.get("outside")
                            or r.get("exit") not in (0, 1, 2)
                            or (r.get("exit") == 2 and "Error" not in r.get("output", "")))
    return records, folder


def run_chunk(job: tuple[list[int], int, float, str]) -> dict[str, Any]:
    indices, seed, timeout, keep = job
    keep_dir = Path(keep)
    summary: dict[str, Any] = {"trials": 0, "exits": Counter(), "kinds": Counter(), "tracebacks": Counter(),
                               "non_finite": [], "outside": [], "hangs": [], "unclear": [], "bad_exit": [],
                               "max_seconds": Counter(), "seconds": 0.0}
    with tempfile.TemporaryDirectory(prefix="toosicubix-fuzz-") as tmp:
        work = Path(tmp)
        baseline = work / "baseline"
        base_ann = work / "baseline.json"
        doc = json.loads(SAMPLE.read_text())
        doc["images"] = [doc["images"][SMALL_IMAGE]]
        base_ann.write_text(json.dumps(doc))
        run_command(["fit", str(base_ann), "-o", str(baseline), "-q"], timeout)
        for index in indices:
            start = time.perf_counter()
            records, folder = trial(index, seed, work, timeout, baseline)
            summary["seconds"] += time.perf_counter() - start
            summary["trials"] += 1
            for r in records:
                c = r["command"]
                summary["exits"][f"{c} {'hang' if r.get('hang') else r.get('exit')}"] += 1
                summary["max_seconds"][c] = max(summary["max_seconds"][c], r["seconds"])
                if r.get("traceback"):
                    summary["tracebacks"][f"{c}: {r['traceback']}"] += 1
                for key, target in (("non_finite", "non_finite"), ("outside", "outside"), ("hang", "hangs")):
                    if r.get(key):
                        summary[target].append(f"{c} trial {index} ({r['kind']}): {r[key]}")
                if r.get("exit") not in (0, 1, 2) and not r.get("hang"):
                    summary["bad_exit"].append(f"{c} trial {index}: exit {r.get('exit')}")
                if r.get("exit") == 2 and "Error" not in r.get("output", ""):
                    summary["unclear"].append(f"{c} trial {index}: {r.get('output', '')[:100]!r}")
                if r["finding"]:
                    dest = keep_dir / f"trial{index}-{c}"
                    if not dest.exists():
                        shutil.copytree(folder, dest, symlinks=True)
                        (dest / "finding.json").write_text(json.dumps(
                            {k: v for k, v in r.items() if k != "output"} | {"output": r.get("output", "")[-2000:]},
                            indent=1, default=str))
            summary["kinds"][records[0]["kind"].split(":")[0]] += 1
            shutil.rmtree(folder, ignore_errors=True)
            if summary["trials"] % 250 == 0:
                print(f"[worker {indices[0] % max(1, len(indices))}] {summary['trials']} of {len(indices)} trials, "
                      f"{sum(summary['tracebacks'].values())} tracebacks, {len(summary['non_finite'])} non-finite, "
                      f"{len(summary['hangs'])} hangs", file=sys.stderr, flush=True)
    return summary


def kill_trials(args: argparse.Namespace) -> dict[str, Any]:
    """kill -9 in the write phase of ``fit``, then check the folder is the previous complete output or one the
    next run takes as its own ("folders left mixed": ``mixed``, target 0); :mod:`fuzz_kill` runs them."""
    if args.kill_trials == 0:
        return {"trials": 0}
    from fuzz_kill import kill_trials as run_kill_trials

    return run_kill_trials(args.kill_trials, seed=args.seed)


def merge(parts: list[dict[str, Any]]) -> dict[str, Any]:
    total: dict[str, Any] = {}
    for part in parts:
        for key, value in part.items():
            if key == "max_seconds":
                total.setdefault(key, Counter())
                for k, v in value.items():
                    total[key][k] = max(total[key][k], v)
            elif isinstance(value, Counter):
                total.setdefault(key, Counter()).update(value)
            elif isinstance(value, list):
                total.setdefault(key, []).extend(value)
            else:
                total[key] = total.get(key, 0) + value
    return total


def main_(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--files", type=int, default=10_000, help="mutated annotation files (default 10000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--start", type=int, default=0, help="index of the first trial (to rerun a finding)")
    parser.add_argument("--workers", type=int, default=1, help="processes (each runs its share of the trials)")
    parser.add_argument("--timeout", type=float, default=20.0, help="seconds per command before it counts as a hang")
    parser.add_argument("--keep", type=Path, default=Path(tempfile.gettempdir()) / "toosicubix-fuzz-findings",
                        help="where the inputs of findings are kept")
    parser.add_argument("--kill-trials", type=int, default=20, help="kill -9 trials in fit's write phase (0: none)")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    args.keep.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    end = args.start + args.files
    chunks = [(list(range(args.start + w, end, args.workers)), args.seed, args.timeout, str(args.keep))
              for w in range(args.workers)]
    if args.workers > 1:
        with multiprocessing.get_context("fork").Pool(args.workers) as pool:
            parts = pool.map(run_chunk, chunks)
    else:
        parts = [run_chunk(chunks[0])]
    total = merge(parts)
    kills = kill_trials(args)
    wall = time.perf_counter() - start
    figures = {
        "files": total["trials"], "mutation_families": dict(total["kinds"]),
        "gt_files_mutated": args.files // 2, "seed": args.seed, "timeout_s": args.timeout,
        "exit_codes": dict(sorted(total["exits"].items())),
        "tracebacks": sum(total["tracebacks"].values()), "traceback_kinds": dict(total["tracebacks"].most_common(20)),
        "non_finite_written": len(total["non_finite"]), "files_outside_output": len(total["outside"]),
        "hangs_over_timeout": len(total["hangs"]), "bad_exit_codes": len(total["bad_exit"]),
        "exit_2_without_message": len(total["unclear"]),
        "max_seconds_per_command": {k: round(v, 2) for k, v in total["max_seconds"].items()},
        "examples": {k: total[k][:5] for k in ("non_finite", "outside", "hangs", "bad_exit", "unclear")},
        "kill_trials": kills, "wall_s": round(wall, 1), "findings_kept_in": str(args.keep),
    }
    print(json.dumps(figures, indent=1))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=1) + "\n")
    bad = (figures["tracebacks"] + figures["non_finite_written"] + figures["files_outside_output"]
           + figures["hangs_over_timeout"] + figures["bad_exit_codes"] + figures["exit_2_without_message"]
           + kills.get("mixed", 0) + kills.get("rerun_failed", 0))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main_())
