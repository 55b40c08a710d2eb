"""The output folder: ours only by its marker, replaced as a whole, never a mixture after kill -9."""

import json
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from tests.conftest import REPO
from toosicubix.cli import main
from toosicubix.formats.atomic import atomic_write_text, remove_stale_temporaries
from toosicubix.pipeline import output_folder
from toosicubix.pipeline.output_folder import MARKER_NAME, OutputFolderError, check_output_dir, recover

SAMPLE = REPO / "samples" / "annotations.json"
GT_LINE = "Car 0 0 0 1 2 3 4 1.5 1.6 4 1 2 10 0.1\n"


def run(*args: str):
    return CliRunner().invoke(main, list(args))


def files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def small_doc(tmp_path: Path, prefix: str, images: int = 3) -> Path:
    doc = json.loads(SAMPLE.read_text())
    doc["images"] = [{**doc["images"][0], "id": f"{prefix}{k}", "vehicles": doc["images"][0]["vehicles"][:1]}
                     for k in range(images)]
    path = tmp_path / f"{prefix}.json"
    path.write_text(json.dumps(doc))
    return path


def test_fit_writes_a_marker_and_a_rerun_replaces_the_whole_folder(tmp_path):
    out = tmp_path / "out"
    assert run("fit", str(small_doc(tmp_path, "a")), "-o", str(out)).exit_code == 0
    assert json.loads((out / MARKER_NAME).read_text())["toosicubix_output"] == 1
    assert run("fit", str(small_doc(tmp_path, "b", 2)), "-o", str(out)).exit_code == 0
    assert sorted(files(out)) == [MARKER_NAME, "label_2/b0.txt", "label_2/b1.txt", "results.json"]
    assert [p.name for p in tmp_path.iterdir() if "toosicubix-" in p.name] == []  # no staging folder left


@pytest.mark.parametrize("results_text", ["", "{}", '{"toosicubix_results": 1, "images": []}'])
def test_a_results_json_beside_ground_truth_does_not_make_it_ours(tmp_path, results_text):
    # issue 13: an empty results.json (or {}) beside label_2 was taken as ours and 17 of 24 labels overwritten
    root = tmp_path / "kitti"
    (root / "label_2").mkdir(parents=True)
    (root / "label_2" / "a0.txt").write_text(GT_LINE)
    (root / "results.json").write_text(results_text)
    result = run("fit", str(small_doc(tmp_path, "a")), "-o", str(root))
    assert result.exit_code == 2
    assert "toosicubix did not write" in result.output and MARKER_NAME in result.output
    assert (root / "label_2" / "a0.txt").read_text() == GT_LINE


@pytest.mark.parametrize("entries", [("label_2", "calib", "image_2"), ("training", "testing"), ("gtBbox3d",)])
def test_fit_refuses_a_dataset_root(tmp_path, entries):
    root = tmp_path / "dataset"
    for name in entries:
        (root / name).mkdir(parents=True)
        (root / name / "000000.txt").write_text(GT_LINE)
    before = files(root)
    result = run("fit", str(small_doc(tmp_path, "a")), "-o", str(root))
    assert result.exit_code == 2
    assert "looks like a dataset" in result.output
    assert files(root) == before


def test_fit_refuses_a_folder_with_a_file_it_did_not_write(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    result = run("fit", str(small_doc(tmp_path, "a")), "-o", str(out))
    assert result.exit_code == 2 and "notes.txt" in result.output
    # Our own output with a foreign file added is refused too: the whole folder would be replaced.
    ours = tmp_path / "ours"
    assert run("fit", str(small_doc(tmp_path, "a")), "-o", str(ours)).exit_code == 0
    (ours / "eval.json").write_text("{}")
    result = run("fit", str(small_doc(tmp_path, "a")), "-o", str(ours))
    assert result.exit_code == 2 and "eval.json" in result.output
    assert (ours / "eval.json").read_text() == "{}"


def test_an_empty_existing_folder_is_accepted(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    check_output_dir(out)
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputFolderError, match="not a folder"):
        check_output_dir(tmp_path / "file")


def test_files_get_the_users_umask(tmp_path):
    old = os.umask(0o027)
    try:
        out = tmp_path / "out"
        assert run("fit", str(small_doc(tmp_path, "a")), "-o", str(out)).exit_code == 0
        atomic_write_text(tmp_path / "single.txt", "x")
    finally:
        os.umask(old)
    for path in [out / "results.json", out / "label_2" / "a0.txt", tmp_path / "single.txt"]:
        assert stat.S_IMODE(path.stat().st_mode) == 0o640, path  # 0o666 & ~0o027, not mkstemp's 0o600
    assert stat.S_IMODE(out.stat().st_mode) == 0o750


def _dead_pid() -> int:
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def test_stale_temporaries_of_a_dead_process_are_removed(tmp_path):
    pid = _dead_pid()
    stale = tmp_path / f".x.txt.{pid}.abc123.tmp"
    stale.write_text("half")
    live = tmp_path / f".x.txt.{os.getpid()}.abc123.tmp"  # a writer still running: kept
    live.write_text("half")
    atomic_write_text(tmp_path / "x.txt", "whole")
    assert not stale.exists() and live.exists()
    assert remove_stale_temporaries(tmp_path) == []


def test_recover_puts_back_an_output_moved_aside_and_deletes_staging(tmp_path):
    # The fallback swap (no renameat2) killed between its two renames: OUT missing, the previous output
    # under its -old- name, the new one complete under -new-.
    pid = _dead_pid()
    out = tmp_path / "out"
    old = tmp_path / f".out.toosicubix-old-{pid}"
    new = tmp_path / f".out.toosicubix-new-{pid}-xyz"
    for folder in (old, new):
        (folder / "label_2").mkdir(parents=True)
        (folder / MARKER_NAME).write_text('{"toosicubix_output": 1}')
    (old / "results.json").write_text("previous")
    recover(out)
    assert (out / "results.json").read_text() == "previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_fallback_swap_without_exchange(tmp_path, monkeypatch):
    monkeypatch.setattr(output_folder, "_exchange", lambda a, b: False)
    out = tmp_path / "out"
    assert run("fit", str(small_doc(tmp_path, "a")), "-o", str(out)).exit_code == 0
    assert run("fit", str(small_doc(tmp_path, "b", 1)), "-o", str(out)).exit_code == 0
    assert sorted(files(out)) == [MARKER_NAME, "label_2/b0.txt", "results.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.json", "out"]


def _fit_process(annotations: Path, out: Path, pause: float) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO), output_folder.PAUSE_ENV: str(pause)}
    return subprocess.Popen([sys.executable, "-m", "toosicubix", "fit", str(annotations), "-o", str(out), "-q"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


@pytest.mark.parametrize("first_run", [False, True])
def test_kill_9_in_the_write_phase_leaves_the_previous_output(tmp_path, first_run):
    out = tmp_path / "out"
    ann_a, ann_b = small_doc(tmp_path, "a"), small_doc(tmp_path, "b")
    if not first_run:
        assert run("fit", str(ann_a), "-o", str(out)).exit_code == 0
    before = files(out) if out.exists() else None
    # The hook sleeps 0.5 s after each file: killed 0.3 s after the staging folder appears, the run is
    # between writing the marker and its first label file, well inside the write phase.
    process = _fit_process(ann_b, out, 0.5)
    deadline = time.monotonic() + 60
    while not list(tmp_path.glob(".out.toosicubix-new-*")):
        assert process.poll() is None and time.monotonic() < deadline, "the run never reached its write phase"
        time.sleep(0.005)
    time.sleep(0.3)
    assert process.poll() is None
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    if first_run:
        assert not out.exists()
    else:
        assert files(out) == before  # the previous complete output, nothing of run B
    assert list(tmp_path.glob(".out.toosicubix-new-*"))  # the killed run's staging folder is left ...
    assert run("fit", str(ann_b), "-o", str(out)).exit_code == 0
    assert sorted(files(out)) == [MARKER_NAME, "label_2/b0.txt", "label_2/b1.txt", "label_2/b2.txt", "results.json"]
    assert not list(tmp_path.glob(".out.toosicubix-*"))  # ... and cleaned by the next run


def test_a_file_the_file_system_refuses_leaves_the_folder_unchanged(tmp_path):
    # issue 13: an image id of 238+ characters (OSError "File name too long") left two label files and no
    # results.json, and the folder was refused forever after.
    out = tmp_path / "out"
    assert run("fit", str(small_doc(tmp_path, "a")), "-o", str(out)).exit_code == 0
    before = files(out)
    doc = json.loads(small_doc(tmp_path, "b").read_text())
    doc["images"][1]["id"] = "x" * 300
    bad = tmp_path / "long.json"
    bad.write_text(json.dumps(doc))
    result = run("fit", str(bad), "-o", str(out))
    assert result.exit_code == 2, result.output
    assert "Error:" in result.output and "Traceback" not in result.output
    assert files(out) == before
    assert not list(tmp_path.glob(".out.toosicubix-*"))


def test_the_staging_folder_is_synced_once_before_the_swap(tmp_path, monkeypatch):
    """One sync of the whole staging folder (not an fsync per file), and before the folder is swapped in."""
    calls = []
    real_sync, real_swap = output_folder.sync_folder, output_folder._swap_in
    monkeypatch.setattr(output_folder, "sync_folder", lambda folder: calls.append(("sync", folder.name))
                        or real_sync(folder))
    monkeypatch.setattr(output_folder, "_swap_in", lambda staging, out: calls.append(("swap", staging.name))
                        or real_swap(staging, out))
    fsyncs = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: fsyncs.append(fd) or real_fsync(fd))
    assert run("fit", str(SAMPLE), "-o", str(tmp_path / "out"), "-q").exit_code == 0
    assert [kind for kind, _ in calls] == ["sync", "swap"] and calls[0][1] == calls[1][1]
    assert len(fsyncs) <= 2  # the parent folder after the swap (and nothing per file where syncfs exists)


def test_sync_folder_without_syncfs_fsyncs_every_file_and_folder(tmp_path, monkeypatch):
    (tmp_path / "label_2").mkdir()
    for name in ("a.txt", "b.txt"):
        (tmp_path / "label_2" / name).write_text("x\n")
    (tmp_path / "results.json").write_text("{}\n")
    monkeypatch.setattr(output_folder, "_syncfs", lambda fd: False)
    fsyncs = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: fsyncs.append(fd) or real_fsync(fd))
    output_folder.sync_folder(tmp_path)
    assert len(fsyncs) == 3 + 2  # three files, two folders
