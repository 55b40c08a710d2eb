"""Atomic file output: a reader sees the old file or the new one, never half of one.

A file is written to a temporary file ``.<name>.<pid>.<random>.tmp`` in the same folder, then renamed
over ``path``. A run killed before the rename leaves that temporary file; the next atomic write into the
same folder deletes such files whose process is gone. Files get the user's umask (``0o666 & ~umask``),
as ``open`` would give them, not the ``0o600`` of :func:`tempfile.mkstemp`.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import IO, Any

_TEMPORARY = re.compile(r"^\..+\.(\d+)\.[^.]+\.tmp$")


def current_umask() -> int:
    """The process's umask, read without changing it where Linux allows (``/proc/self/status``)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def remove_stale_temporaries(folder: str | Path) -> list[Path]:
    """Delete the temporary files of :func:`atomic_write` in ``folder`` whose writing process is gone;
    return them."""
    removed = []
    with contextlib.suppress(OSError):
        for entry in Path(folder).iterdir():
            match = _TEMPORARY.match(entry.name)
            if match is None or not entry.is_file() or _alive(int(match.group(1))):
                continue
            with contextlib.suppress(OSError):
                entry.unlink()
                removed.append(entry)
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def atomic_write(path: str | Path, write: Callable[[IO[Any]], None], binary: bool = False,
                 clean: bool = True) -> None:
    """Let ``write`` fill a temporary file in the folder of ``path`` (text: UTF-8, ``\\n`` line ends; or
    ``binary``), then rename it to ``path``.

    The folder must exist. On any error the temporary file is removed and ``path`` is untouched. ``clean``
    first removes the folder's stale temporaries (:func:`remove_stale_temporaries`); a caller writing many files
    into one folder does that once and passes False.
    """
    path = Path(path)
    tmp = _staged(path, write, binary, clean)
    try:
        os.replace(tmp, path)
    except BaseException:
        _discard(tmp)
        raise


def atomic_write_texts(files: list[tuple[Path, str | None]]) -> None:
    """Write several files as one change: every text to its temporary file first (written and synced), then each
    renamed over its path (None: the path removed). An error while writing any of them leaves every path
    untouched; only a failing rename, after all were written, can leave some renamed and others not.
    """
    staged: list[tuple[str, Path]] = []
    try:
        for path, text in files:
            if text is not None:
                staged.append((_staged(path, lambda handle, text=text: handle.write(text)), path))
    except BaseException:
        for tmp, _ in staged:
            _discard(tmp)
        raise
    for tmp, path in staged:
        os.replace(tmp, path)
    for path, text in files:
        if text is None:
            path.unlink(missing_ok=True)


def _staged(path: Path, write: Callable[[IO[Any]], None], binary: bool = False, clean: bool = True) -> str:
    """A temporary file beside ``path``, with the user's umask, filled by ``write`` and synced: its path. On any
    error it is removed (``clean``: the folder's stale temporaries first, :func:`remove_stale_temporaries`)."""
    if clean:
        remove_stale_temporaries(path.parent)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~current_umask())
        handle_of = (lambda: os.fdopen(fd, "wb")) if binary else (
            lambda: os.fdopen(fd, "w", encoding="utf-8", newline="\n"))
        with handle_of() as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
    except BaseException:
        _discard(tmp)
        raise
    return tmp


def _discard(tmp: str) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(tmp)


def atomic_write_bytes(path: str | Path, data: bytes, clean: bool = True) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_write`)."""
    atomic_write(path, lambda handle: handle.write(data), binary=True, clean=clean)


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_write`)."""
    atomic_write(path, lambda handle: handle.write(text))


def atomic_write_json(path: str | Path, doc: Any) -> None:
    """Write ``doc`` as ``json.dumps(doc, indent=1, allow_nan=False) + "\\n"`` would, streamed piece by piece
    (a large results file is never held in memory as one string), atomically.

    Raises
    ------
    ValueError
        A NaN or an infinity in ``doc`` (not JSON); ``path`` is then untouched.
    """
    def write(handle: IO[str]) -> None:
        for chunk in json.JSONEncoder(indent=1, allow_nan=False).iterencode(doc):
            handle.write(chunk)
        handle.write("\n")

    atomic_write(path, write)


def atomic_write_json_items(path: str | Path, head: dict[str, Any], key: str, items: Iterable[Any]) -> int:
    """Write ``{**head, key: [*items]}`` byte for byte as :func:`atomic_write_json` would, taking ``items`` one at a
    time from an iterator (a large imported annotation file is never held whole); return how many were written.

    ``head`` comes first, ``key`` last. An exception from ``items`` (a problem found while they are made) leaves
    ``path`` untouched, as any error does.

    Raises
    ------
    ValueError
        A NaN or an infinity (not JSON); ``path`` is then untouched.
    """
    count = 0

    def write(handle: IO[str]) -> None:
        nonlocal count
        opening = json.dumps({**head, key: []}, indent=1, allow_nan=False)  # '{\n ...,\n "key": []\n}'
        handle.write(opening[: -len("[]\n}")])
        for item in items:
            text = json.dumps(item, indent=1, allow_nan=False)  # JSON strings hold no raw newline
            handle.write(("[\n  " if count == 0 else ",\n  ") + text.replace("\n", "\n  "))
            count += 1
        handle.write("\n ]\n}\n" if count else "[]\n}\n")

    atomic_write(path, write)
    return count
