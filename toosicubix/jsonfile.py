"""Reading JSON input files: the one reader every input file goes through, and field checks for documents read by hand.

:func:`read_json` checks the text before parsing it (readable, UTF-8, nested at most :data:`MAX_JSON_DEPTH` deep) and
reports a problem either at a line (:class:`~toosicubix.errors.FormatError`, for files whose readers name lines) or at
the document's root ``$`` (:class:`~toosicubix.errors.InputFileError`, for files whose readers name JSON paths).
:func:`json_field` and :func:`json_numbers` check one field of a document read by hand.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np

from toosicubix.errors import FormatError, InputFileError
from toosicubix.fields import shown

#: The deepest nesting of JSON arrays and objects a file may have (an annotation file needs 7, results 6);
#: far below the depth at which Python's JSON reader runs out of stack.
MAX_JSON_DEPTH = 32


#: +1 for an opening bracket or brace, -1 for a closing one, by byte.
_DEPTH_STEP = np.zeros(256, dtype=np.int8)
_DEPTH_STEP[[ord("["), ord("{")]] = 1
_DEPTH_STEP[[ord("]"), ord("}")]] = -1
#: Characters of the text scanned at once: the scan's own memory stays a few MB for any file size.
_NESTING_BLOCK = 1 << 18
_QUOTE, _BACKSLASH = ord('"'), ord("\\")
#: The characters the nesting check looks at: quotes, backslashes, brackets and braces.
_STRUCTURAL = np.zeros(256, dtype=bool)
_STRUCTURAL[[_QUOTE, _BACKSLASH, ord("["), ord("]"), ord("{"), ord("}")]] = True


def json_nesting(text: str) -> tuple[int, int]:
    """The deepest nesting of arrays and objects in JSON ``text`` (strings ignored) and the 1-based line
    where it is first reached; (0, 1) for a scalar. Linear in the text; no recursion; no copy of the text.

    Scanned in blocks of :data:`_NESTING_BLOCK` characters, carrying from one block to the next whether the
    scan is inside a string, how many backslashes end the block and the depth: a quote opens or closes a
    string unless an odd number of backslashes precedes it. Up to the first place where a JSON reader would
    fail, this sees the structure that reader sees, so a text it passes cannot nest deeper in the reader.
    Only a block's quotes, backslashes, brackets and braces are looked at (a few in ten of an annotation file's
    characters): the depth changes nowhere else.
    """
    deepest, where_line = None, 1
    depth_carry, in_string, backslashes, lines = 0, 0, 0, 0
    for start in range(0, len(text), _NESTING_BLOCK):
        data = text[start:start + _NESTING_BLOCK].encode("utf-8", "surrogatepass")
        codes = np.frombuffer(data, dtype=np.uint8)
        at = np.flatnonzero(_STRUCTURAL[codes])  # (m,) byte offsets of the characters that matter
        c = codes[at]
        m = at.size
        is_backslash = c == _BACKSLASH
        ending = backslashes if m and at[0] == 0 else 0  # the previous block's backslashes before this one's first
        if is_backslash.any() or ending:
            # Backslashes right before each character: a run continues while they follow one another.
            index = np.arange(m)
            link = np.zeros(m, dtype=bool)
            link[1:] = is_backslash[:-1] & (at[1:] == at[:-1] + 1)
            run_start = np.maximum.accumulate(np.where(link, 0, index))
            before = index - run_start + np.where(run_start == 0, ending, 0)
            quotes = np.cumsum((c == _QUOTE) & (before % 2 == 0), dtype=np.int64)
            backslashes = int(before[-1]) + 1 if is_backslash[-1] and at[-1] == codes.size - 1 else 0
        else:
            quotes = np.cumsum(c == _QUOTE, dtype=np.int64)
            backslashes = 0
        outside = (quotes + in_string) % 2 == 0  # (m,) after each of them: not inside a string
        depth = np.cumsum(np.where(outside, _DEPTH_STEP[c], np.int8(0)), dtype=np.int64) + depth_carry
        if deepest is None and (m == 0 or at[0] != 0):  # the text's first character leaves the depth at 0
            deepest, where_line = depth_carry, 1
        if m:
            k = int(np.argmax(depth))
            if deepest is None or depth[k] > deepest:  # the first place the maximum is reached
                deepest, where_line = int(depth[k]), lines + data.count(b"\n", 0, int(at[k])) + 1
            depth_carry, in_string = int(depth[-1]), int((quotes[-1] + in_string) % 2)
        lines += data.count(b"\n")
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


#: A run of digits longer than Python reads as an integer (``sys.get_int_max_str_digits()``, 4,300 by default).
_LONG_DIGITS = re.compile(r"[0-9]{4301,}")


def long_integer_error(text: str, path: str | Path, offset: int = 0) -> FormatError:
    """The error for JSON ``text`` that Python's reader refused for an integer of more than 4,300 digits (it raises a
    plain ``ValueError`` without a place): the line of the first such run of digits from ``offset``."""
    found = _LONG_DIGITS.search(text, offset)
    if found is None:  # pragma: no cover - the only ValueError json raises besides JSONDecodeError
        return FormatError(path, "not valid JSON: a number Python cannot read")
    line = text.count("\n", 0, found.start()) + 1
    return FormatError(path, f"not valid JSON: a number of {found.end() - found.start()} digits at line {line} "
                             f"(expected at most 4300)", line)


class _DuplicateKey(ValueError):
    def __init__(self, key: str):
        super().__init__(key)
        self.key = key


def _unique_pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """An object hook of ``json.loads`` that refuses a key given twice in one object."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _DuplicateKey(key)
        out[key] = value
    return out


def read_json(path: str | Path, at_root: bool = False, unique_keys: bool = False) -> Any:
    """The parsed contents of a JSON file: the one JSON reader of every input file (checked first by
    :func:`read_json_text`).

    Parameters
    ----------
    at_root : report a problem at the JSON path ``$`` (:class:`~toosicubix.errors.InputFileError`), as readers
        that name JSON paths do (annotation, priors, settings and mapping files), instead of at its line
    unique_keys : refuse a key given twice in one object (Python's reader keeps the last silently), for files whose
        keys are data (a dataset's model numbers); it slows reading, so large files leave it off

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
            return json.loads(text, object_pairs_hook=_unique_pairs) if unique_keys else json.loads(text)
        except _DuplicateKey as exc:
            raise FormatError(path, f"the key {exc.key[:60]!r} is given twice in one object (expected each key "
                                    "once: a JSON reader keeps only the last)") from None
        except json.JSONDecodeError as exc:
            message = f"not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}"
            raise FormatError(path, message, exc.lineno) from None
        except ValueError:  # Python reads no integer of more than 4,300 digits
            raise long_integer_error(text, path) from None
        except RecursionError:  # pragma: no cover - the depth check comes first
            raise FormatError(path, "not valid JSON: nested too deep") from None
    except FormatError as exc:
        if at_root:
            raise InputFileError(path, [("$", exc.message)]) from None
        raise


_WHITESPACE = re.compile(r"[ \t\n\r]*")


class _ObjectScanner:
    """Reads a JSON object's text one value at a time (see :func:`scan_object`)."""

    def __init__(self, text: str, path: Path, at_root: bool):
        self.text, self.path, self.at_root, self.pos = text, path, at_root, 0
        self.decoder = json.JSONDecoder()

    def fail(self, message: str, pos: int | None = None) -> FormatError | InputFileError:
        pos = self.pos if pos is None else pos
        line = self.text.count("\n", 0, pos) + 1
        column = pos - (self.text.rfind("\n", 0, pos) + 1) + 1
        error = FormatError(self.path, f"not valid JSON: {message} at line {line} column {column}", line)
        return InputFileError(self.path, [("$", error.message)]) if self.at_root else error

    def expect(self, char: str) -> bool:
        """Skip whitespace; consume ``char`` when it comes next."""
        self.pos = _WHITESPACE.match(self.text, self.pos).end()  # type: ignore[union-attr]
        if self.text.startswith(char, self.pos):
            self.pos += 1
            return True
        return False

    def value(self) -> tuple[Any, int]:
        """The next value and where it starts."""
        self.pos = _WHITESPACE.match(self.text, self.pos).end()  # type: ignore[union-attr]
        start = self.pos
        try:
            value, self.pos = self.decoder.raw_decode(self.text, self.pos)
        except json.JSONDecodeError as exc:
            raise self.fail(exc.msg, exc.pos) from None
        except ValueError:  # an integer of more than 4,300 digits
            error = long_integer_error(self.text, self.path, start)
            raise (InputFileError(self.path, [("$", error.message)]) if self.at_root else error) from None
        return value, start

    def spans(self) -> list[tuple[int, int]]:
        """The ``(start, end)`` of each element of the array the scanner is just inside of."""
        out: list[tuple[int, int]] = []
        if self.expect("]"):
            return out
        while True:
            _, start = self.value()  # decoded to find its end, then dropped
            out.append((start, self.pos))
            if self.expect("]"):
                return out
            if not self.expect(","):
                raise self.fail("Expecting ',' delimiter")


def scan_object(text: str, path: str | Path, spans_of: Collection[str] = (),
                at_root: bool = False) -> tuple[dict[str, Any], dict[str, list[tuple[int, int]]]] | None:
    """The members of a JSON object's text (as :func:`read_json_text` gives it), the arrays of ``spans_of`` not kept
    as values but as the span of each element in ``text``: a large array is then decoded one element at a time
    (``json.JSONDecoder().raw_decode(text, start)``) and never held whole. A key given twice keeps its last value,
    as ``json.loads`` does.

    Returns
    -------
    (members, spans) : the other members decoded, by key; per key of ``spans_of`` whose value is an array, its
        elements' ``(start, end)`` (a key whose value is no array is among ``members``). None when the text is not
        an object (valid JSON or not: the caller says what it expected).

    Raises
    ------
    FormatError
        The text is not valid JSON: the line and column named (``at_root``: :class:`InputFileError` at ``$``).
    """
    scanner = _ObjectScanner(text, Path(path), at_root)
    if not scanner.expect("{"):
        return None
    members: dict[str, Any] = {}
    spans: dict[str, list[tuple[int, int]]] = {}
    if not scanner.expect("}"):
        while True:
            key, start = scanner.value()
            if not isinstance(key, str):
                raise scanner.fail("Expecting property name enclosed in double quotes", start)
            if not scanner.expect(":"):
                raise scanner.fail("Expecting ':' delimiter")
            members.pop(key, None)
            spans.pop(key, None)
            if key in spans_of and scanner.expect("["):
                spans[key] = scanner.spans()
            else:
                members[key], _ = scanner.value()
            if scanner.expect("}"):
                break
            if not scanner.expect(","):
                raise scanner.fail("Expecting ',' delimiter")
    scanner.pos = _WHITESPACE.match(text, scanner.pos).end()  # type: ignore[union-attr]
    if scanner.pos != len(text):
        raise scanner.fail("Extra data")
    return members, spans


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
    except (TypeError, ValueError, OverflowError):  # OverflowError: an integer beyond a float's range
        arr = np.zeros(0)
    if arr.shape != shape or not all(math.isfinite(x) for x in arr.ravel()) or isinstance(value, bool):
        what = "a finite number" if shape == () else f"finite numbers of shape {shape}"
        raise FormatError(path, f"{where}: expected {what}, got {shown(value)}")
    return arr
