"""JSON text as ``json.dumps(value, indent=1, allow_nan=False)`` writes it, byte for byte, in a fraction of its time
(:func:`dumps_indented`).

The standard library's C encoder does not indent, so with ``indent`` set ``json`` encodes in Python, one generator
per container and one call per number. A batch's results.json is mostly short lists of floats (matrices, vectors,
sigmas), and the main process of ``fit --jobs N`` encodes every vehicle's entry while the workers fit: that Python
encoder was the largest share of its time. This module writes the same text with the same primitives (``float``'s
and ``int``'s own ``repr``, the C string escaper ``json`` uses) and a fast path for lists of plain floats. Anything
that is not a plain ``dict``, ``list``, ``tuple``, ``str``, ``int``, ``float``, ``bool`` or ``None`` (subclasses,
dicts with keys that are not strings, objects ``json`` refuses) is handed to ``json`` itself, indented to its place,
so the text and the errors are ``json``'s own.
"""

from __future__ import annotations

import json
import math
from typing import Any

__all__ = ["dumps_indented"]

_escaped = json.encoder.encode_basestring_ascii  # the C escaper when CPython has it, as json.dumps uses
_float_repr = float.__repr__
_int_repr = int.__repr__


def dumps_indented(value: Any) -> str:
    """``json.dumps(value, indent=1, allow_nan=False)``, the same text.

    Raises
    ------
    ValueError
        A NaN or an infinity, with ``json``'s message.
    TypeError
        A value ``json`` cannot encode, with ``json``'s message.
    RecursionError
        A container that holds itself (``json`` says ``ValueError: Circular reference detected``).
    """
    parts: list[str] = []
    _write(value, parts, "\n")
    return "".join(parts)


def _number(x: float) -> str:
    """A plain float as json writes it; NaN and infinities refused with json's message."""
    if math.isfinite(x):
        return _float_repr(x)
    raise ValueError("Out of range float values are not JSON compliant: " + repr(x))


def _numbers(values: list[float] | tuple[float, ...]) -> Any:
    """Plain floats as json writes them; one sum tells that none is a NaN or an infinity (a sum that overflows
    checks them one by one)."""
    if math.isfinite(sum(values)):
        return map(_float_repr, values)
    return map(_number, values)


#: How json writes a scalar of each plain type.
_SCALARS = {str: _escaped, float: _number, int: _int_repr, bool: lambda b: "true" if b else "false",
            type(None): lambda _: "null"}


def _write(value: Any, parts: list[str], newline: str) -> None:
    """Append ``value``'s text to ``parts``; ``newline`` is a line break and the indent of the line ``value`` is on."""
    kind = type(value)
    scalar = _SCALARS.get(kind)
    if scalar is not None:
        parts.append(scalar(value))
    elif kind is list or kind is tuple:
        if not value:
            parts.append("[]")
            return
        inner = newline + " "
        kinds = set(map(type, value))
        if len(kinds) == 1:
            kind = kinds.pop()
            if kind is float:  # vectors: one join
                parts.append("[" + inner + ("," + inner).join(_numbers(value)) + newline + "]")
                return
            if kind is str:  # labels
                parts.append("[" + inner + ("," + inner).join(map(_escaped, value)) + newline + "]")
                return
            if kind is list:  # matrices, residuals: rows of floats
                rows = _float_rows(value, inner)
                if rows is not None:
                    parts.append("[" + inner + ("," + inner).join(rows) + newline + "]")
                    return
        separator = "[" + inner
        for item in value:
            parts.append(separator)
            _write(item, parts, inner)
            separator = "," + inner
        parts.append(newline + "]")
    elif kind is dict and all(type(key) is str for key in value):
        if not value:
            parts.append("{}")
            return
        inner = newline + " "
        separator = "{" + inner
        for key, item in value.items():
            parts.append(separator + _escaped(key) + ": ")
            scalar = _SCALARS.get(type(item))
            if scalar is not None:
                parts.append(scalar(item))
            else:
                _write(item, parts, inner)
            separator = "," + inner
        parts.append(newline + "}")
    else:  # subclasses, other keys, objects json refuses: json's own text and errors, at this indent
        parts.append(json.dumps(value, indent=1, allow_nan=False).replace("\n", newline))


def _float_rows(rows: list[list], newline: str) -> list[str] | None:
    """Each row's text when every row is a non-empty list of plain floats (``newline``: the rows' own line); None
    otherwise."""
    inner = newline + " "
    out = []
    for row in rows:
        if not row or any(type(x) is not float for x in row):
            return None
        out.append("[" + inner + ("," + inner).join(_numbers(row)) + newline + "]")
    return out
