"""Reading JSON input files: the one reader every input file goes through, and field checks for documents read by hand.

:func:`read_json` checks the text before parsing it (readable, UTF-8, nested at most :data:`MAX_JSON_DEPTH` deep) and
reports a problem either at a line (:class:`~toosicubix.errors.FormatError`, for files whose readers name lines) or at
the document's root ``$`` (:class:`~toosicubix.errors.InputFileError`, for files whose readers name JSON paths).
:func:`json_field` and :func:`json_numbers` check one field of a document read by hand.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from toosicubix.errors import FormatError, InputFileError

#: The deepest nesting of JSON arrays and objects a file may have (an annotation file needs 7, results 6);
#: far below the depth at which Python's JSON reader runs out of stack.
MAX_JSON_DEPTH = 32


#: +1 for an opening bracket or brace, -1 for a closing one, by byte.
_DEPTH_STEP = np.zeros(256, dtype=np.int8)
_DEPTH_STEP[[ord("["), ord("{")]] = 1
_DEPTH_STEP[[ord("]"), ord("}")]] = -1
#: Characters of the text scanned at once: the scan's own memory stays a few MB for any file size.
_NESTING_BLOCK = 1 << 18
_QUOTE, _BACKSLASH, _NEWLINE = ord('"'), ord("\\"), ord("\n")


def json_nesting(text: str) -> tuple[int, int]:
    """The deepest nesting of arrays and objects in JSON ``text`` (strings ignored) and the 1-based line
    where it is first reached; (0, 1) for a scalar. Linear in the text; no recursion; no copy of the text.

    Scanned in blocks of :data:`_NESTING_BLOCK` characters, carrying from one block to the next whether the
    scan is inside a string, how many backslashes end the block and the depth: a quote opens or closes a
    string unless an odd number of backslashes precedes it. Up to the first place where a JSON reader would
    fail, this sees the structure that reader sees, so a text it passes cannot nest deeper in the reader.
    """
    deepest, where_line = None, 1
    depth_carry, in_string, backslashes, lines = 0, 0, 0, 0
    for start in range(0, len(text), _NESTING_BLOCK):
        codes = np.frombuffer(text[start:start + _NESTING_BLOCK].encode("utf-8", "surrogatepass"), dtype=np.uint8)
        n = codes.size
        is_backslash = codes == _BACKSLASH
        index = np.arange(n, dtype=np.int32)
        last_other = np.maximum.accumulate(np.where(is_backslash, np.int32(-1), index))  # (n,) -1: none yet
        # Backslashes right before each character: those since the last other one (or the block's start,
        # counting the ones that ended the previous block).
        before = np.empty(n, dtype=np.int64)
        before[0] = backslashes
        before[1:] = np.where(last_other[:-1] >= 0, index[:-1] - last_other[:-1], index[1:] + backslashes)
        quotes = np.cumsum((codes == _QUOTE) & (before % 2 == 0), dtype=np.int64)
        outside = (quotes + in_string) % 2 == 0  # (n,) after each character: not inside a string
        depth = np.cumsum(np.where(outside, _DEPTH_STEP[codes], np.int8(0)), dtype=np.int64) + depth_carry
        k = int(np.argmax(depth))
        if deepest is None or depth[k] > deepest:  # the first place the maximum is reached
            deepest, where_line = int(depth[k]), lines + int(np.count_nonzero(codes[:k] == _NEWLINE)) + 1
        depth_carry, in_string = int(depth[-1]), int((quotes[-1] + in_string) % 2)
        backslashes = n - 1 - int(last_other[-1]) if last_other[-1] >= 0 else backslashes + n
        lines += int(np.count_nonzero(codes == _NEWLINE))
    if deepest is None:
        return 0, 1
    return deepest, where_line


def read_json_text(path: str | Path) -> str:
    """The text of a JSON file, checked before any parsing: readable, UTF-8 (a byte order mark is skipped),
    nested at most ``MAX_JSON_DEPTH`` deep.

    Raises
    ------
    FormatError
        The file cannot be read, is not UTF-8 (the byte named), or is nested too deep (the line named).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise FormatError(path, f"cannot read the file: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise FormatError(path, f"expected UTF-8 JSON text: {exc.reason} at byte {exc.start}") from None
    depth, line = json_nesting(text)
    if depth > MAX_JSON_DEPTH:
        raise FormatError(path, f"arrays and objects nested {depth} deep (first at line {line}); at most "
                                f"{MAX_JSON_DEPTH} allowed", line)
    return text


def read_json(path: str | Path, at_root: bool = False) -> Any:
    """The parsed contents of a JSON file: the one JSON reader of every input file (checked first by
    :func:`read_json_text`).

    Parameters
    ----------
    at_root : report a problem at the JSON path ``$`` (:class:`~toosicubix.errors.InputFileError`), as readers
        that name JSON paths do (annotation, priors, settings and mapping files), instead of at its line

    Raises
    ------
    FormatError
        As :func:`read_json_text`, or the text is not valid JSON (``line`` set, the message says the line and
        column too).
    InputFileError
        The same problems, with ``at_root``.
    """
    try:
        text = read_json_text(path)
        try:
            return json.loads(text)
        except json.JSONDecodeError as exc:
            message = f"not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}"
            raise FormatError(path, message, exc.lineno) from None
        except RecursionError:  # pragma: no cover - the depth check comes first
            raise FormatError(path, "not valid JSON: nested too deep") from None
    except FormatError as exc:
        if at_root:
            raise InputFileError(path, [("$", exc.message)]) from None
        raise


def json_field(obj: Any, key: str, kind: type | tuple[type, ...], path: Path, where: str) -> Any:
    """``obj[key]`` of a JSON document, checked to be a ``kind`` (booleans never count as numbers).

    Raises
    ------
    FormatError
        Naming the file and the JSON path ``where.key``: missing, or of another type.
    """
    if not isinstance(obj, dict) or key not in obj:
        raise FormatError(path, f"{where}.{key}: missing")
    value = obj[key]
    if not isinstance(value, kind) or isinstance(value, bool):
        names = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
        raise FormatError(path, f"{where}.{key}: expected {names}, got {type(value).__name__}")
    return value


def json_numbers(value: Any, shape: tuple[int, ...], path: Path, where: str) -> np.ndarray:
    """A JSON value as a float array of ``shape`` (``()`` for one number), every entry finite.

    Raises
    ------
    FormatError
        Naming the file and the JSON path ``where``, with what was expected and what was found.
    """
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        arr = np.zeros(0)
    if arr.shape != shape or not all(math.isfinite(x) for x in arr.ravel()) or isinstance(value, bool):
        what = "a finite number" if shape == () else f"finite numbers of shape {shape}"
        raise FormatError(path, f"{where}: expected {what}, got {value!r:.60}")
    return arr
