"""The annotate page's requests, checked field by field: what the session refuses (:class:`ApiError`, with the
HTTP status to answer) and why, naming the field and what was expected.

Numbers are checked with the annotation file's own field types (:mod:`toosicubix.annotations.schema`: ``Coordinate``,
``Metres``, ``SigmaMetres``), so the page never keeps an edit the file's readers (``fit``, ``validate``, ``annotate``
itself on its next start) would refuse."""

from __future__ import annotations

import json
import math
from typing import Any

from pydantic import TypeAdapter, ValidationError

from toosicubix import vocabulary
from toosicubix.annotations.schema import Coordinate, Metres, SigmaMetres

#: The schema's field types a request's numbers must pass, as it checks a file's.
_PIXEL, _METRES, _SIGMA_METRES = TypeAdapter(Coordinate), TypeAdapter(Metres), TypeAdapter(SigmaMetres)


class ApiError(Exception):
    """A request the session refuses: ``status`` is the HTTP status, the message says why."""

    status = 400

    def __init__(self, message: str, status: int | None = None):
        super().__init__(message)
        if status is not None:
            self.status = status


class Conflict(ApiError):
    """A change made on a stale revision, or over a file changed on disk by someone else (HTTP 409)."""

    status = 409


def checked_number(value: Any, what: str, field_type: TypeAdapter | None = None) -> float:
    """``value`` as a finite float that passes the schema's ``field_type`` (its bounds) when given; ``what`` names the
    field in the refusal."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ApiError(f"{what}: expected a finite number, got {json.dumps(value)[:60]}")
    if field_type is not None:
        try:
            field_type.validate_python(value)
        except ValidationError as exc:
            raise ApiError(f"{what}: {exc.errors()[0]['msg'].removeprefix('Value error, ')}") from None
    return float(value)


def checked_pixels(value: Any, count: int, what: str) -> list[list[float]]:
    """``value`` as ``count`` pixels ``[[x, y], ...]`` of finite numbers."""
    if not isinstance(value, list) or len(value) != count:
        raise ApiError(f"{what}: expected {count} pixel{'s' if count > 1 else ''} [[x, y], ...], got "
                       f"{json.dumps(value)[:60]}")
    out = []
    for k, row in enumerate(value):
        if not isinstance(row, list) or len(row) != 2:
            raise ApiError(f"{what}[{k}]: expected [x, y], got {json.dumps(row)[:60]}")
        out.append([checked_number(row[k2], f"{what}[{k}][{k2}]", _PIXEL) for k2 in (0, 1)])
    return out


def checked_box2d(value: Any) -> list[float] | None:
    """A vehicle's ``box2d``: None, or ``[x1, y1, x2, y2]`` with x1 < x2 and y1 < y2."""
    if value is None:
        return None
    if not isinstance(value, list) or len(value) != 4:
        raise ApiError(f"box2d: expected [x1, y1, x2, y2] or null, got {json.dumps(value)[:60]}")
    box = [checked_number(x, f"box2d[{k}]", _PIXEL) for k, x in enumerate(value)]
    if not (box[2] > box[0] and box[3] > box[1]):
        raise ApiError(f"box2d: expected x1 < x2 and y1 < y2, got {box}")
    return box


def checked_known(value: Any) -> tuple[float, float]:
    """A length annotation's ``known`` size: ``[metres, sigma]``, within the schema's bounds for them."""
    if not isinstance(value, list) or len(value) != 2:
        raise ApiError(f"known: expected [metres, sigma] for a length, got {json.dumps(value)[:60]}")
    return checked_number(value[0], "known[0]", _METRES), checked_number(value[1], "known[1]", _SIGMA_METRES)


def checked_kind_name(kind: Any, name: Any) -> tuple[str, str]:
    """A part kind of the vocabulary and one of its fixed names (a mapping's keypoints are the session's to
    check: :meth:`toosicubix.web.session.Session._keypoint_extra`)."""
    if not isinstance(kind, str) or kind not in vocabulary.KINDS:
        raise ApiError(f"kind: expected one of {', '.join(vocabulary.KINDS)}, got {kind!r:.60}")
    if not isinstance(name, str) or name not in vocabulary.KINDS[kind].names:
        raise ApiError(f"name: expected a {kind} name ({', '.join(vocabulary.KINDS[kind].names)}), got {name!r}")
    return kind, name
