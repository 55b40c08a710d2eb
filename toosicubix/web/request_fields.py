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
#: How far outside the image a click or box may lie, as a fraction of the image's width (for x) and height (for
#: y): a wheel or corner of a vehicle cut off by the image's edge is clicked where the person guesses it, a little
#: outside; anything farther is a slip (the page itself sends only clicks on the image).
OUTSIDE_MARGIN = 0.1


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
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ApiError(f"{what}: expected a finite number, got {_shown(value)}")
    try:
        number = float(value)
    except OverflowError:  # an integer of hundreds of digits
        raise ApiError(f"{what}: expected a finite number, got an integer of {len(str(abs(value)))} digits") from None
    if not math.isfinite(number):
        raise ApiError(f"{what}: expected a finite number, got {_shown(value)}")
    if field_type is not None:
        try:
            field_type.validate_python(number)
        except ValidationError as exc:
            raise ApiError(f"{what}: {exc.errors()[0]['msg'].removeprefix('Value error, ')}") from None
    return number


def _shown(value: Any) -> str:
    """A request's value as the refusal quotes it: JSON, cut to 60 characters."""
    try:
        text = json.dumps(value, allow_nan=True)
    except (TypeError, ValueError, RecursionError):
        text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def check_on_image(xy: tuple[float, float], size: tuple[int, int] | None, what: str) -> None:
    """A pixel ``(x, y)`` on an image of ``size = (width, height)``, or within :data:`OUTSIDE_MARGIN` of its size
    around it (ApiError 400 naming ``what`` otherwise); anything goes without a size."""
    if size is None:
        return
    width, height = size
    x_range = (-OUTSIDE_MARGIN * width, (1 + OUTSIDE_MARGIN) * width)
    y_range = (-OUTSIDE_MARGIN * height, (1 + OUTSIDE_MARGIN) * height)
    if not (x_range[0] <= xy[0] <= x_range[1] and y_range[0] <= xy[1] <= y_range[1]):
        raise ApiError(f"{what}: ({xy[0]:g}, {xy[1]:g}) lies outside the {width} x {height} image by more than "
                       f"{100 * OUTSIDE_MARGIN:g} % of its size (expected x within [{x_range[0]:g}, {x_range[1]:g}] "
                       f"and y within [{y_range[0]:g}, {y_range[1]:g}])")


def checked_pixels(value: Any, count: int, what: str, size: tuple[int, int] | None = None) -> list[list[float]]:
    """``value`` as ``count`` pixels ``[[x, y], ...]`` of finite numbers within the schema's bounds, and, given the
    image's ``size`` (width, height), on it or within :data:`OUTSIDE_MARGIN` of it."""
    if not isinstance(value, list) or len(value) != count:
        raise ApiError(f"{what}: expected {count} pixel{'s' if count > 1 else ''} [[x, y], ...], got "
                       f"{_shown(value)}")
    out = []
    for k, row in enumerate(value):
        if not isinstance(row, list) or len(row) != 2:
            raise ApiError(f"{what}[{k}]: expected [x, y], got {_shown(row)}")
        out.append([checked_number(row[k2], f"{what}[{k}][{k2}]", _PIXEL) for k2 in (0, 1)])
        check_on_image((out[-1][0], out[-1][1]), size, f"{what}[{k}]")
    return out


def checked_box2d(value: Any, size: tuple[int, int] | None = None) -> list[float] | None:
    """A vehicle's ``box2d``: None, or ``[x1, y1, x2, y2]`` with x1 < x2 and y1 < y2, within the schema's bounds and,
    given the image's ``size``, on it or within :data:`OUTSIDE_MARGIN` of it."""
    if value is None:
        return None
    if not isinstance(value, list) or len(value) != 4:
        raise ApiError(f"box2d: expected [x1, y1, x2, y2] or null, got {_shown(value)}")
    box = [checked_number(x, f"box2d[{k}]", _PIXEL) for k, x in enumerate(value)]
    if not (box[2] > box[0] and box[3] > box[1]):
        raise ApiError(f"box2d: expected x1 < x2 and y1 < y2, got {box}")
    check_on_image((box[0], box[1]), size, "box2d[0:2]")
    check_on_image((box[2], box[3]), size, "box2d[2:4]")
    return box


def checked_known(value: Any) -> tuple[float, float]:
    """A length annotation's ``known`` size: ``[metres, sigma]``, within the schema's bounds for them."""
    if not isinstance(value, list) or len(value) != 2:
        raise ApiError(f"known: expected [metres, sigma] for a length, got {_shown(value)}")
    return checked_number(value[0], "known[0]", _METRES), checked_number(value[1], "known[1]", _SIGMA_METRES)


def checked_kind_name(kind: Any, name: Any) -> tuple[str, str]:
    """A part kind of the vocabulary and one of its fixed names (a mapping's keypoints are the session's to
    check: :meth:`toosicubix.web.session.Session._keypoint_extra`)."""
    if not isinstance(kind, str) or kind not in vocabulary.KINDS:
        raise ApiError(f"kind: expected one of {', '.join(vocabulary.KINDS)}, got {_shown(kind)}")
    if not isinstance(name, str) or name not in vocabulary.KINDS[kind].names:
        raise ApiError(f"name: expected a {kind} name ({', '.join(vocabulary.KINDS[kind].names)}), got {_shown(name)}")
    return kind, name
