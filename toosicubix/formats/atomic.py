"""Atomic file output: a reader sees the old file or the new one, never half of one."""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any


def atomic_write(path: str | Path, write: Callable[[IO[str]], None]) -> None:
    """Let ``write`` fill a temporary file (UTF-8, ``\\n`` line ends) in the folder of ``path``, then rename
    it to ``path``.

    The folder must exist. On any error the temporary file is removed and ``path`` is untouched.
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


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
