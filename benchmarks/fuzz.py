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

The surfaces after issue 13 (issue 34, item 2) are targets (:mod:`fuzz_targets`): ``import coco``, ``import cvat``,
``import label-studio``, ``learn-parts`` and mapping files, ``eval --apollocar3d``, ``export openlabel`` and ``export
cvat``, ``render``; and sequences (``tracks``: a file of frames with tracks through ``fit``, ``validate`` and
``render --video``, or its fit's results through ``export openlabel``, ``export cvat`` and ``render --video``).
``--targets`` picks them (``all``: every one; ``fit``: the trials above) and ``--cases N`` shares
N cases among the chosen ones. Each case's command runs in a forked child (:func:`run_isolated`), which gives its peak
memory (the child's maximum resident set, the worker's pages it touches included) and a hang bound that needs no
signal in the command's own process; the child may not map more than ``--address-limit`` GB (a runaway allocation
ends as a MemoryError, counted as a traceback, not as the machine's OOM killer). It counts, per target: tracebacks,
exit codes other than 0, 1, 2, exit 2 without an ``Error:`` message, anything written after an exit 2, a NaN or an
infinity in a file written, hangs, children killed by a signal, and cases whose peak memory passed 1 GB.

    python benchmarks/fuzz.py --targets all --cases 10000 --workers 2 --kill-trials 0 --json FILE
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import multiprocessing
import os
import random
import re
import resource
import select
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
sys.path.insert(0, str(REPO / "benchmarks"))

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

def nodes(doc: Any, path: tuple = ()) -> list[tuple[tuple, Any]]:
    """Every (path, node) of a JSON document, the root included."""
    out = [(path, doc)]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += nodes(v, (*path, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += nodes(v, (*path, i))
    return out


def set_at(doc: Any, path: tuple, value: Any) -> Any:
    """``doc`` with the node at ``path`` replaced by ``value`` (the new root when ``path`` is empty)."""
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
    every = nodes(doc)
    path, node = rng.choice(every)
    kind = rng.choice(["drop", "replace", "duplicate", "unknown_key", "rename", "nest", "swap", "empty_list"])
    if kind == "drop" and path:
        del _parent(doc, path)[path[-1]]
    elif kind == "replace":
        doc = set_at(doc, path, copy.deepcopy(rng.choice([None, {}, [], "x", 0, True, [1, 2], {"a": 1}, "a" * 300])))
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
        doc = set_at(doc, path, value)
    elif kind == "swap":
        other_path, other = rng.choice(every)
        if path and other_path and path[: len(other_path)] != other_path and other_path[: len(path)] != path:
            doc = set_at(doc, path, copy.deepcopy(other))
    elif kind == "empty_list" and isinstance(node, list):
        node.clear()
    return doc, f"structure:{kind}"


def mutate_numbers(doc: Any, rng: random.Random) -> tuple[Any, str]:
    numbers = [(p, v) for p, v in nodes(doc) if isinstance(v, int | float) and not isinstance(v, bool)]
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
        cameras = [n for p, n in nodes(doc) if p and p[-1] in ("K", "P") and isinstance(n, list)]
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
    return set_at(doc, path, new), f"numeric:{kind}"


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
    if path.suffix == ".xml":  # points="x,y;x,y" and numbers in attributes: any nan or inf spelled out
        found = re.search(r'[",; ](-?(?:nan|inf|infinity))[",; ]', text, flags=re.IGNORECASE)
        return None if found is None else f"line {text.count(chr(10), 0, found.start()) + 1}: {found.group(1)}"
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


# --- targets beyond fit (issue 34): each case's commands in a forked child -------------------------------------------

#: Peak memory a case may reach (the child's maximum resident set), bytes.
MEMORY_TARGET = 1 << 30


def _written_files(writes: Path | None) -> list[Path]:
    if writes is None or not writes.exists():
        return []
    return [writes] if writes.is_file() else sorted(p for p in writes.rglob("*") if p.is_file())


def _child(command, address_limit: float, out) -> None:
    """In the forked child: run the command in-process, check what it wrote, send the record, exit."""
    try:
        limit = int(address_limit * (1 << 30))
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
        start = time.perf_counter()
        result = CliRunner().invoke(main, command.args, catch_exceptions=True)
        text = result.output
        record: dict[str, Any] = {"exit": result.exit_code,
                                  "output": text if len(text) <= 2000 else f"{text[:1000]} [...] {text[-1000:]}",
                                  "seconds": time.perf_counter() - start}
        exc = result.exc_info[1] if result.exc_info else None
        if exc is not None and not isinstance(exc, SystemExit):
            frame = traceback.extract_tb(exc.__traceback__)[-1]
            record["traceback"] = (f"{type(exc).__name__} at {Path(frame.filename).name}:{frame.lineno}: "
                                   f"{str(exc)[:200]}")
        written = _written_files(command.writes)
        if result.exit_code == 2 and written and command.label != "render":
            record["written_on_error"] = [str(p) for p in written[:3]]
        for path in written:
            if path.suffix in (".json", ".xml", ".csv", ".txt"):
                bad = non_finite_in(path)
                if bad is not None:
                    record["non_finite"] = f"{path.name}: {bad}"
                    break
        os.write(out, json.dumps(record, default=str).encode())
    except BaseException as exc:
        os.write(out, json.dumps({"harness_error": f"{type(exc).__name__}: {exc}"[:300]}).encode())
    finally:
        os._exit(0)


def run_isolated(command, timeout: float, folder: Path, address_limit: float = 4.0) -> dict[str, Any]:
    """Run one command (:class:`fuzz_targets.Command`) in a forked child: its record (exit code, output, traceback,
    what it wrote), its peak memory (``max_rss_mb``, the child's maximum resident set) and whether it hung (killed
    after ``timeout`` seconds) or died of a signal."""
    read, write = os.pipe()
    start = time.perf_counter()
    pid = os.fork()
    if pid == 0:
        os.close(read)
        _child(command, address_limit, write)
    os.close(write)
    chunks, hang = [], False
    deadline = start + timeout
    while True:
        left = deadline - time.perf_counter()
        if left <= 0:
            hang = True
            os.kill(pid, signal.SIGKILL)
            break
        ready, _, _ = select.select([read], [], [], left)
        if ready:
            chunk = os.read(read, 1 << 16)
            if not chunk:
                break
            chunks.append(chunk)
    os.close(read)
    _, status, usage = os.wait4(pid, 0)
    record: dict[str, Any] = {"command": command.label, "hang": hang, "max_rss_mb": usage.ru_maxrss / 1024,
                              "seconds": time.perf_counter() - start}
    if not hang:
        if os.WIFSIGNALED(status):
            record["signal"] = os.WTERMSIG(status)
        else:
            try:
                record.update(json.loads(b"".join(chunks) or b"{}"))
            except ValueError:
                record["harness_error"] = "the child's record was not JSON"
    return record


def run_target_chunk(job: tuple[str, list[int], int, float, str, float]) -> dict[str, Any]:
    """A worker's share of one target's cases; the figures to merge (see :func:`merge`)."""
    from fuzz_targets import TARGETS

    name, indices, seed, timeout, keep, address_limit = job
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    # What the commands import, imported once here: each forked case then starts with it (and its memory counts).
    import toosicubix.evaluation.evaluate
    import toosicubix.formats.coco
    import toosicubix.formats.cvat
    import toosicubix.formats.labelstudio
    import toosicubix.formats.openlabel
    import toosicubix.pipeline.batch
    import toosicubix.render.folder  # noqa: F401
    summary: dict[str, Any] = {"cases": Counter(), "exits": Counter(), "kinds": Counter(), "tracebacks": Counter(),
                               "non_finite": [], "written_on_error": [], "hangs": [], "signals": [], "unclear": [],
                               "bad_exit": [], "harness": [], "over_memory": [], "unreadable": [],
                               "max_seconds": Counter(),
                               "max_rss_mb": Counter(), "seconds": 0.0}
    with tempfile.TemporaryDirectory(prefix=f"toosicubix-fuzz-{name}-") as tmp:
        work = Path(tmp)
        target = TARGETS[name]()
        (work / "base").mkdir()
        target.prepare(work / "base")
        # A target with checks after its last case (the page: the server still answers, the file still reads) runs
        # them as one more step, its records counted as a case's.
        steps = [*indices, None] if hasattr(target, "finish") else indices
        for n, index in enumerate(steps):
            folder = work / f"c{index}"
            folder.mkdir()
            start = time.perf_counter()
            try:
                records = target.finish() if index is None else target.run_case(
                    index, seed, folder, timeout, lambda c, t, f: run_isolated(c, t, f, address_limit))
            except Exception as exc:  # the case could not be made: the harness's fault, counted, the run goes on
                records = [{"command": "(making the case)", "kind": "harness", "hang": False, "max_rss_mb": 0.0,
                            "seconds": 0.0, "harness_error": f"{type(exc).__name__}: {str(exc)[:200]}"}]
            summary["seconds"] += time.perf_counter() - start
            summary["cases"][name] += index is not None
            for r in records:
                c = f"{name}: {r['command']}"
                summary["exits"][f"{c} {'hang' if r.get('hang') else r.get('exit', r.get('status', 'signal'))}"] += 1
                summary["kinds"][f"{name}: {r['kind'].split(':')[0]}"] += 1
                summary["max_seconds"][c] = max(summary["max_seconds"][c], r["seconds"])
                summary["max_rss_mb"][c] = max(summary["max_rss_mb"][c], r["max_rss_mb"])
                where = f"{c} case {index} ({r['kind']})"
                finding = False
                if r.get("traceback"):
                    summary["tracebacks"][f"{c}: {r['traceback']}"] += 1
                    finding = True
                for key, target_key in (("non_finite", "non_finite"), ("written_on_error", "written_on_error"),
                                        ("hang", "hangs"), ("signal", "signals"), ("harness_error", "harness"),
                                        ("unreadable", "unreadable")):
                    if r.get(key):
                        summary[target_key].append(f"{where}: {r[key]}")
                        finding = True
                if r["max_rss_mb"] * (1 << 20) > MEMORY_TARGET:
                    summary["over_memory"].append(f"{where}: {r['max_rss_mb']:.0f} MB")
                    finding = True
                if not r.get("hang") and "exit" in r:
                    if r["exit"] not in (0, 1, 2):
                        summary["bad_exit"].append(f"{where}: exit {r['exit']}")
                        finding = True
                    elif r["exit"] == 2 and "Error" not in r.get("output", ""):
                        summary["unclear"].append(f"{where}: {r.get('output', '')[:100]!r}")
                        finding = True
                if finding:
                    dest = Path(keep) / f"{name}-case{index}"
                    if not dest.exists():
                        shutil.copytree(folder, dest, symlinks=True)
                        (dest / "finding.json").write_text(json.dumps(r, indent=1, default=str))
            shutil.rmtree(folder, ignore_errors=True)
            if (n + 1) % 250 == 0 and index is not None:
                print(f"[{name}] {n + 1} of {len(indices)} cases, {sum(summary['tracebacks'].values())} tracebacks, "
                      f"max {max(summary['max_rss_mb'].values(), default=0):.0f} MB", file=sys.stderr, flush=True)
        summary["details"] = {name: getattr(target, "summary", None)} if hasattr(target, "finish") else {}
    return summary


def target_figures(total: dict[str, Any], names: list[str]) -> dict[str, Any]:
    """Per target: cases, exit codes, tracebacks, non-finite values written, hangs, peak memory."""
    out = {}
    for name in names:
        mine = [k for k in total["exits"] if k.startswith(f"{name}: ")]
        out[name] = {
            "cases": total["cases"][name],
            "exit_codes": {k[len(name) + 2:]: total["exits"][k] for k in sorted(mine)},
            "mutations": {k[len(name) + 2:]: v for k, v in sorted(total["kinds"].items()) if k.startswith(f"{name}: ")},
            "tracebacks": sum(v for k, v in total["tracebacks"].items() if k.startswith(f"{name}: ")),
            **{key: sum(1 for x in total[key] if x.startswith(f"{name}: "))
               for key in ("non_finite", "written_on_error", "hangs", "signals", "bad_exit", "unclear", "harness",
                           "over_memory", "unreadable")},
            "peak_memory_mb": {k[len(name) + 2:]: round(v) for k, v in total["max_rss_mb"].items()
                               if k.startswith(f"{name}: ")},
            "max_seconds": {k[len(name) + 2:]: round(v, 2) for k, v in total["max_seconds"].items()
                            if k.startswith(f"{name}: ")},
            **({"servers": total["details"][name]} if name in total.get("details", {}) else {}),
        }
    return out


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
            if key in ("max_seconds", "max_rss_mb"):
                total.setdefault(key, Counter())
                for k, v in value.items():
                    total[key][k] = max(total[key][k], v)
            elif key == "details":  # per target, each worker's (the page: its server's requests and memory)
                for name, detail in value.items():
                    total.setdefault(key, {}).setdefault(name, []).append(detail)
            elif isinstance(value, Counter):
                total.setdefault(key, Counter()).update(value)
            elif isinstance(value, list):
                total.setdefault(key, []).extend(value)
            else:
                total[key] = total.get(key, 0) + value
    return total


def main_(argv: list[str] | None = None) -> int:
    from fuzz_targets import TARGETS

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--targets", default="fit",
                        help=f"comma-separated: fit (issue 13's trials), {', '.join(TARGETS)}, or all [default: fit]")
    parser.add_argument("--files", type=int, default=10_000, help="fit: mutated annotation files (default 10000)")
    parser.add_argument("--cases", type=int, default=10_000,
                        help="the other targets: cases in all, shared evenly among them (default 10000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--start", type=int, default=0, help="index of the first trial or case (to rerun a finding)")
    parser.add_argument("--workers", type=int, default=1, help="processes (each runs its share of the trials)")
    parser.add_argument("--timeout", type=float, default=20.0, help="seconds per command before it counts as a hang")
    parser.add_argument("--address-limit", type=float, default=4.0,
                        help="GB of address space a case's process may map (a runaway allocation fails there)")
    parser.add_argument("--keep", type=Path, default=Path(tempfile.gettempdir()) / "toosicubix-fuzz-findings",
                        help="where the inputs of findings are kept")
    parser.add_argument("--kill-trials", type=int, default=20, help="kill -9 trials in fit's write phase (0: none)")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    names = [*TARGETS, "fit"] if args.targets == "all" else [t.strip() for t in args.targets.split(",")]
    unknown = set(names) - set(TARGETS) - {"fit"}
    if unknown:
        parser.error(f"unknown targets {', '.join(sorted(unknown))}; expected fit, {', '.join(TARGETS)} or all")
    args.keep.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    figures: dict[str, Any] = {"command": "python benchmarks/fuzz.py " + " ".join(argv if argv is not None
                                                                               else sys.argv[1:]),
                               "seed": args.seed, "timeout_s": args.timeout}
    bad = 0
    if "fit" in names:
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
        figures.update({
            "files": total["trials"], "mutation_families": dict(total["kinds"]),
            "gt_files_mutated": args.files // 2,
            "exit_codes": dict(sorted(total["exits"].items())),
            "tracebacks": sum(total["tracebacks"].values()),
            "traceback_kinds": dict(total["tracebacks"].most_common(20)),
            "non_finite_written": len(total["non_finite"]), "files_outside_output": len(total["outside"]),
            "hangs_over_timeout": len(total["hangs"]), "bad_exit_codes": len(total["bad_exit"]),
            "exit_2_without_message": len(total["unclear"]),
            "max_seconds_per_command": {k: round(v, 2) for k, v in total["max_seconds"].items()},
            "examples": {k: total[k][:5] for k in ("non_finite", "outside", "hangs", "bad_exit", "unclear")},
            "kill_trials": kills,
        })
        bad += (figures["tracebacks"] + figures["non_finite_written"] + figures["files_outside_output"]
                + figures["hangs_over_timeout"] + figures["bad_exit_codes"] + figures["exit_2_without_message"]
                + kills.get("mixed", 0) + kills.get("rerun_failed", 0))
    others = [n for n in names if n != "fit"]
    if others:
        share = [args.cases // len(others) + (k < args.cases % len(others)) for k in range(len(others))]
        jobs = [(name, list(range(args.start + w, args.start + n, args.workers)), args.seed, args.timeout,
                 str(args.keep), args.address_limit)
                for name, n in zip(others, share, strict=True) for w in range(args.workers)]
        if args.workers > 1:
            with multiprocessing.get_context("fork").Pool(args.workers) as pool:
                parts = pool.map(run_target_chunk, jobs, chunksize=1)
        else:
            parts = [run_target_chunk(job) for job in jobs]
        total = merge(parts)
        per_target = target_figures(total, others)
        findings = ("tracebacks", "non_finite", "written_on_error", "hangs", "signals", "bad_exit", "unclear",
                    "harness", "over_memory", "unreadable")
        figures["targets"] = {
            "cases": sum(total["cases"].values()), "address_limit_gb": args.address_limit,
            "memory_target_mb": MEMORY_TARGET >> 20,
            **{f"{key}_total": sum(t[key] for t in per_target.values()) for key in findings},
            "peak_memory_mb": round(max(total["max_rss_mb"].values(), default=0)),
            "traceback_kinds": dict(total["tracebacks"].most_common(20)),
            "examples": {k: total[k][:5] for k in findings[1:]},
            "per_target": per_target,
        }
        bad += sum(figures["targets"][f"{key}_total"] for key in findings)
    figures.update(wall_s=round(time.perf_counter() - start, 1), findings_kept_in=str(args.keep))
    try:
        from common import machine

        figures["machine"] = machine()
    except Exception as exc:
        figures["machine"] = f"unknown ({exc})"
    print(json.dumps(figures, indent=1))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=1) + "\n")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main_())
