"""The annotate page's requests, checked field by field: what the session refuses (:class:`ApiError`, with the
HTTP status to answer) and why, naming the field and what was expected.

Numbers go through the field rules every input reader applies (:mod:`toosicubix.fields`: a type checked before use,
finite, within the bounds the annotation file's schema takes from there: pixels, metres, sigmas), and a refusal says
what those rules say, after the request's field; so the page never keeps an edit the file's readers (``fit``,
``validate``, ``annotate`` itself on its next start) would refuse. What only a request has is checked here: a click
on the image or within :data:`OUTSIDE_MARGIN` of it, a box's corners in order, the vocabulary's kinds and names."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from toosicubix import fields, vocabulary
from toosicubix.fields import FieldError, shown

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


def checked_number(value: Any, what: str, rule: Callable[[Any, None, str], float] = fields.number) -> float:
    """``value`` through the readers' field ``rule`` (:func:`toosicubix.fields.pixel`,
    :func:`~toosicubix.fields.metres`, :func:`~toosicubix.fields.sigma_metres`; by default any finite number), as a
    float; the refusal names ``what``, the request's field, and says what the rule expected and found."""
    try:
        return rule(value, None, what)
    except FieldError as exc:
        raise ApiError(f"{what}: {exc.detail}") from None


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
                       f"{shown(value)}")
    return [checked_pixel(row, f"{what}[{k}]", size) for k, row in enumerate(value)]


def checked_pixel(value: Any, what: str, size: tuple[int, int] | None = None) -> list[float]:
    """``value`` as one pixel ``[x, y]`` (see :func:`checked_pixels`), the messages naming ``what``."""
    if not isinstance(value, list) or len(value) != 2:
        raise ApiError(f"{what}: expected [x, y], got {shown(value)}")
    xy = [checked_number(value[k], f"{what}[{k}]", fields.pixel) for k in (0, 1)]
    check_on_image((xy[0], xy[1]), size, what)
    return xy


def checked_box2d(value: Any, size: tuple[int, int] | None = None) -> list[float] | None:
    """A vehicle's ``box2d``: None, or ``[x1, y1, x2, y2]`` with x1 < x2 and y1 < y2, within the schema's bounds and,
    given the image's ``size``, on it or within :data:`OUTSIDE_MARGIN` of it."""
    if value is None:
        return None
    if not isinstance(value, list) or len(value) != 4:
        raise ApiError(f"box2d: expected [x1, y1, x2, y2] or null, got {shown(value)}")
    box = [checked_number(x, f"box2d[{k}]", fields.pixel) for k, x in enumerate(value)]
    if not (box[2] > box[0] and box[3] > box[1]):
        raise ApiError(f"box2d: expected x1 < x2 and y1 < y2, got {box}")
    check_on_image((box[0], box[1]), size, "box2d[0:2]")
    check_on_image((box[2], box[3]), size, "box2d[2:4]")
    return box


def checked_known(value: Any) -> tuple[float, float]:
    """A length annotation's ``known`` size: ``[metres, sigma]``, within the schema's bounds for them."""
    if not isinstance(value, list) or len(value) != 2:
        raise ApiError(f"known: expected [metres, sigma] for a length, got {shown(value)}")
    return (checked_number(value[0], "known[0]", fields.metres),
            checked_number(value[1], "known[1]", fields.sigma_metres))


def checked_kind_name(kind: Any, name: Any) -> tuple[str, str]:
    """A part kind of the vocabulary and one of its fixed names (a mapping's keypoints are the session's to
    check: :meth:`toosicubix.web.session.Session._keypoint_extra`)."""
    if not isinstance(kind, str) or kind not in vocabulary.KINDS:
        raise ApiError(f"kind: expected one of {', '.join(vocabulary.KINDS)}, got {shown(kind)}")
    if not isinstance(name, str) or name not in vocabulary.KINDS[kind].names:
        raise ApiError(f"name: expected a {kind} name ({', '.join(vocabulary.KINDS[kind].names)}), got {shown(name)}")
    return kind, name
