"""The output folder of ``toosicubix fit``: ours only by its marker, replaced as a whole.

A folder is toosicubix's output only when it holds the marker file :data:`MARKER_NAME` that ``fit``
writes (never because a ``results.json`` is there), and nothing but what ``fit`` writes: the marker,
``results.json``, ``label_2/*.txt`` and, for sequences, ``label_02/*.txt``. ``fit -o`` refuses any other non-empty
folder: a dataset root (``calib``, ``image_2``, ``training``, ``testing``, ``gtBbox3d``...), ground truth (label
files without the marker), or a folder with one file it did not write.

Writing (:func:`staged_output`), for an output folder ``OUT`` in ``PARENT``:

1. every file is written into a sibling staging folder ``PARENT/.OUT.toosicubix-new-<pid>``, the marker
   first (so a leftover staging folder is recognisably ours), ``results.json`` last; then the whole folder is
   made durable at once (:func:`sync_folder`: one ``syncfs`` on Linux, not one ``fsync`` per file);
2. the staging folder and ``OUT`` are swapped in one step (Linux ``renameat2(RENAME_EXCHANGE)``); where
   that is not available, ``OUT`` is renamed to ``PARENT/.OUT.toosicubix-old-<pid>`` and the staging
   folder to ``OUT``;
3. the previous output, now under a staging name, is deleted.

What a reader of ``OUT`` sees at every point: before step 2, the previous complete output (or no folder
on a first run); after it, the new complete output. Never a mixture, whatever moment the run is killed
at (``kill -9`` included). Only on the fallback path is there a moment between its two renames when
``OUT`` is missing; the previous output is then complete under its ``-old-`` name and the next run puts
it back before anything else. Staging folders left by a killed run (their process gone) are deleted by
the next run into the same folder. Files and folders get the user's umask.

Test hook: with the environment variable :data:`PAUSE_ENV` set to a number of seconds, the writer
sleeps that long after each file and between the steps, so that a test can kill it in the write phase.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import errno
import json
import os
import shutil
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from toosicubix.errors import InputError
from toosicubix.formats.atomic import current_umask

#: The file that makes a folder toosicubix's output.
MARKER_NAME = ".toosicubix-output.json"
MARKER_VERSION = 1
LABEL_DIR = "label_2"
#: KITTI tracking labels of the frames of sequences: ``label_02/<sequence>.txt``.
TRACKING_LABEL_DIR = "label_02"
RESULTS_NAME = "results.json"
#: Seconds to sleep after each file and between the swap's steps (tests kill the run there).
PAUSE_ENV = "TOOSICUBIX_PAUSE_BETWEEN_WRITES"

#: Entries of a folder that mark a dataset (KITTI object or tracking, Cityscapes 3D).
DATASET_ENTRIES = ("calib", "image_2", "image_02", "velodyne", "training", "testing", "gtBbox3d",
                   "gtBbox2d", "leftImg8bit", "camera")


class OutputFolderError(InputError):
    """The output folder cannot be used: it is a dataset, holds files toosicubix did not write, or is not a
    folder. The message names the folder."""

    def __init__(self, message: str, folder: str | Path | None = None):
        super().__init__(folder, [(None, message)])


def _staging_prefix(out_dir: Path) -> str:
    return f".{out_dir.name}.toosicubix-"


def _pause() -> None:
    seconds = os.environ.get(PAUSE_ENV)
    if seconds:
        time.sleep(float(seconds))


def is_ours(folder: Path) -> bool:
    """Whether ``folder`` holds a marker written by ``toosicubix fit``."""
    marker = folder / MARKER_NAME
    if not marker.is_file():
        return False
    try:
        doc = json.loads(marker.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return False
    return isinstance(doc, dict) and doc.get("toosicubix_output") == MARKER_VERSION


def foreign_entries(folder: Path) -> list[str]:
    """What in ``folder`` toosicubix does not write (sorted, relative names): empty for our output."""
    foreign = []
    for entry in sorted(folder.iterdir()):
        if entry.name in (MARKER_NAME, RESULTS_NAME) and entry.is_file() and not entry.is_symlink():
            continue
        if entry.name in (LABEL_DIR, TRACKING_LABEL_DIR) and entry.is_dir() and not entry.is_symlink():
            foreign += [f"{entry.name}/{f.name}" for f in sorted(entry.iterdir())
                        if f.suffix != ".txt" or not f.is_file() or f.is_symlink()]
            continue
        foreign.append(entry.name + ("/" if entry.is_dir() else ""))
    return foreign


def check_output_dir(out_dir: str | Path) -> None:
    """Refuse an output folder that is not ours to replace; write nothing.

    A missing folder, an empty one or our own earlier output is fine.

    Raises
    ------
    OutputFolderError
        ``out_dir`` is a file, a dataset root, or a folder holding files toosicubix did not write (a folder
        with label files but no marker is taken as ground truth).
    """
    out_dir = Path(out_dir)
    if not out_dir.exists() and not out_dir.is_symlink():
        return
    if not out_dir.is_dir():
        raise OutputFolderError(f"{out_dir}: exists and is not a folder; choose another output folder")
    try:
        entries = {e.name for e in out_dir.iterdir()}
    except OSError as exc:
        raise OutputFolderError(f"{out_dir}: cannot read the folder: {exc.strerror or exc}") from None
    if not entries:
        return
    dataset = sorted(entries & set(DATASET_ENTRIES))
    if dataset:
        raise OutputFolderError(
            f"{out_dir}: looks like a dataset ({', '.join(e + '/' for e in dataset)}); toosicubix never writes "
            f"into one. Choose another output folder.")
    if not is_ours(out_dir):
        labels = [d for d in (LABEL_DIR, TRACKING_LABEL_DIR) if d in entries]
        what = f"label files in {labels[0]}/ (ground truth?)" if labels else "files"
        raise OutputFolderError(
            f"{out_dir}: holds {what} that toosicubix did not write (no {MARKER_NAME} marker): "
            f"{', '.join(sorted(entries)[:5])}{' ...' if len(entries) > 5 else ''}. Choose another output folder.")
    foreign = foreign_entries(out_dir)
    if foreign:
        raise OutputFolderError(
            f"{out_dir}: a toosicubix output folder, but it also holds files toosicubix did not write: "
            f"{', '.join(foreign[:5])}{' ...' if len(foreign) > 5 else ''}; move them away or choose another "
            f"output folder (the whole folder is replaced)")


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _stale_staging(out_dir: Path) -> list[tuple[str, Path]]:
    """Staging folders of ``out_dir`` whose process is gone: ``(kind, path)``, kind 'new' or 'old'."""
    prefix = _staging_prefix(out_dir)
    stale = []
    if not out_dir.parent.is_dir():
        return stale
    for entry in out_dir.parent.iterdir():
        if not entry.name.startswith(prefix) or entry.is_symlink() or not entry.is_dir():
            continue
        kind, _, rest = entry.name[len(prefix):].partition("-")
        pid = rest.split("-")[0]
        if kind in ("new", "old") and pid.isdigit() and not _process_alive(int(pid)):
            stale.append((kind, entry))
    return sorted(stale, key=lambda kv: kv[1].name)


def recover(out_dir: str | Path) -> None:
    """Clean up after a killed run into ``out_dir``: put back a previous output that the fallback swap had
    moved aside (``OUT`` missing), delete every other staging folder whose process is gone."""
    out_dir = Path(out_dir)
    for kind, path in _stale_staging(out_dir):
        if kind == "old" and not out_dir.exists() and is_ours(path):
            os.rename(path, out_dir)
        else:
            shutil.rmtree(path, ignore_errors=True)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2`` with ``RENAME_EXCHANGE``); False when unsupported."""
    libc_name = ctypes.util.find_library("c")
    if libc_name is None:
        return False
    libc = ctypes.CDLL(libc_name, use_errno=True)
    renameat2 = getattr(libc, "renameat2", None)
    if renameat2 is None:
        return False
    at_fdcwd, rename_exchange = -100, 2
    result = renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange)
    if result == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _syncfs(fd: int) -> bool:
    """Write back every file and folder of the file system holding ``fd`` and wait (Linux ``syncfs``, one
    call); False where it is not available."""
    libc_name = ctypes.util.find_library("c")
    syncfs = getattr(ctypes.CDLL(libc_name, use_errno=True), "syncfs", None) if libc_name else None
    if syncfs is None:
        return False
    if syncfs(fd) != 0:
        err = ctypes.get_errno()
        raise OSError(err, os.strerror(err))
    return True


def sync_folder(folder: Path) -> None:
    """Make every file and folder under ``folder`` durable before the folder is swapped in: one ``syncfs`` of
    its file system where Linux has it (a file written without its own ``fsync`` is then on disk), else an
    ``fsync`` of each file and folder under it, deepest first.

    Raises
    ------
    OSError
        The write-back failed (a full or failing disk): the folder must not be swapped in.
    """
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # a folder cannot be opened everywhere (Windows): the files one by one
        fd = None
    if fd is not None:
        try:
            if _syncfs(fd):
                return
        finally:
            os.close(fd)
    for root, _, files in os.walk(folder, topdown=False):
        for name in files:
            _fsync_file(os.path.join(root, name))
        _fsync_dir(Path(root))


def _fsync_file(path: str) -> None:
    """``fsync`` one file (opened for writing where that is allowed: Windows flushes only such a handle)."""
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError:
        fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _swap_in(staging: Path, out_dir: Path) -> None:
    """Make ``staging`` the folder ``out_dir`` (steps 2 and 3 of the module docstring)."""
    if not out_dir.exists():
        os.rename(staging, out_dir)
        _fsync_dir(out_dir.parent)
        return
    if _exchange(staging, out_dir):
        _fsync_dir(out_dir.parent)
        _pause()
        shutil.rmtree(staging, ignore_errors=True)  # now the previous output
        return
    old = out_dir.parent / f"{_staging_prefix(out_dir)}old-{os.getpid()}"
    os.rename(out_dir, old)
    _pause()
    os.rename(staging, out_dir)
    _fsync_dir(out_dir.parent)
    _pause()
    shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def staged_output(out_dir: str | Path, marker: dict[str, Any] | None = None) -> Iterator[Path]:
    """Yield an empty staging folder to write the output into; on leaving the block without an error, it
    replaces ``out_dir`` as a whole (see the module docstring). On an error the staging folder is deleted
    and ``out_dir`` is untouched.

    Raises
    ------
    OutputFolderError
        As :func:`check_output_dir`, or the parent folder cannot be written.
    """
    out_dir = Path(out_dir).resolve()
    check_output_dir(out_dir)
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        recover(out_dir)
        check_output_dir(out_dir)  # recovery may have put an earlier output back
        staging = Path(tempfile.mkdtemp(prefix=f"{_staging_prefix(out_dir)}new-{os.getpid()}-",
                                        dir=out_dir.parent))
        os.chmod(staging, 0o777 & ~current_umask())
    except OSError as exc:
        raise OutputFolderError(f"{out_dir}: cannot create the output folder: {exc.strerror or exc}") from None
    try:
        doc = {"toosicubix_output": MARKER_VERSION, **(marker or {}),
               "note": "written by toosicubix fit; the folder is replaced as a whole by the next run"}
        (staging / MARKER_NAME).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        _pause()
        yield staging
        # Once for the whole folder, not per file: what the swap brings in is on disk first (a power cut after
        # it leaves the new output whole), and a kill before it leaves the previous output.
        sync_folder(staging)
        _swap_in(staging, out_dir)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def pause_after_file() -> None:
    """The test hook's pause after one output file (see :data:`PAUSE_ENV`)."""
    _pause()
