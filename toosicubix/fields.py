"""The field rules every input reader applies: what a number, a size, an image side or an id may be, said once.

A reader that takes a value from a file (a JSON value, or the text of an XML attribute) passes it through one of
these rules with the file and the place (a JSON path such as ``$.annotations[3].bbox[2]``, or a line), and gets the
value in its checked form, or a :class:`FieldError` naming the file, the place, what was expected and what was
found. The rules check the type before anything else touches the value, so no reader meets the exceptions Python
raises on hostile values: ``OverflowError`` (an integer of 400 digits turned into a float), ``ValueError`` (an
integer of 5,000 digits turned into text, ``int('²')``), ``TypeError`` (a list used as a dictionary key).

The bounds are the annotation file's (:mod:`toosicubix.annotations.schema` takes them from here): what a file may
hold is what a reader may pass on.

- Numbers: ``int`` or ``float`` (never ``bool``), finite, within the rule's bounds. As text (XML attributes,
  :func:`text_number`): only the decimal notation ``[+-]digits[.digits][e[+-]digits]`` in ASCII, at most
  :data:`MAX_NUMBER_TEXT` characters; Python's ``float()`` would also read ``4_01.2`` as 401.2, ``' 1 '``, ``nan``,
  ``infinity`` and digits of other scripts.
- Ids (:func:`identifier`): a string of 1 to :data:`MAX_ID_LENGTH` characters without control characters or
  unpaired surrogates, or an integer of at most :data:`MAX_ID_DIGITS` digits.
- Numeric keys (:func:`numeric_key`: a dataset's model numbers, ``"35"`` in ApolloCar3D's ``car_models.json``):
  an integer, or a string of 1 to :data:`MAX_ID_DIGITS` decimal digits, read as the number they write; ``"35"``,
  ``"035"`` and ``"٣٥"`` (Arabic-Indic digits) all mean 35, and :class:`DistinctKeys` refuses a second key that
  means a number an earlier key meant, naming both. ``'²'`` is a digit to Python's ``str.isdigit`` but no decimal
  digit: refused.
"""

from __future__ import annotations

import math
import re
import unicodedata
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import Any

from toosicubix.errors import FormatError, InputError, InputFileError, Where

#: The largest pixel coordinate (and image side) a file may hold. The largest camera images are some 10^5
#: pixels across; a click a million pixels off is a typo, and the solver's squared pixel costs of larger
#: numbers lose every digit a click carries (and overflow float64 near 1e154).
MAX_PIXEL = 1e6
#: The largest size in metres a ``length`` feature, known dimension or camera height may have: no road
#: vehicle or camera mount is 100 m.
MAX_METRES = 100.0
#: The smallest sigma in metres: no vehicle's size is known to a tenth of a millimetre, and a smaller sigma
#: makes the prior's weight (1 / sigma^2) swamp every click.
MIN_SIGMA_METRES = 1e-4
#: Image ids name files (``label_2/<id>.txt``, and a temporary file beside it with 14 more characters):
#: most file systems allow 255 bytes per name; this leaves room for both. Vehicle ids and prototypes have
#: the same bound so that messages and results stay readable.
MAX_ID_LENGTH = 128
#: What names a file: image ids and sequence names (``label_2/<image id>.txt``, ``label_02/<sequence>.txt``, and what
#: ``render`` writes, ``<image id>.png``, ``<sequence>.mp4``): no character that could climb out of a folder.
FILE_NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.\-]*$"
#: The largest frame number of a sequence (KITTI's longest sequence has 1,106 frames; 10^6 is a day at 10 Hz).
MAX_FRAME = 1_000_000
#: The most digits an integer id may have: 18 digits fit a signed 64-bit integer (COCO files written by C, Java
#: or numpy hold no more), and any id a dataset numbers its things with.
MAX_ID_DIGITS = 18
#: The longest number written as text (an XML attribute) that is read: 17 significant digits, a sign, a point and
#: an exponent need 25; this leaves room for zeros written out.
MAX_NUMBER_TEXT = 64

_DECIMAL_TEXT = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_INTEGER_TEXT = re.compile(r"[+-]?[0-9]+")
_ID_LIMIT = 10 ** MAX_ID_DIGITS
#: Unicode categories an id may not hold: control characters (``Cc``: ASCII's 0-31 and 127, and 128-159) and
#: unpaired surrogates (``Cs``: not text; they cannot be written as UTF-8).
_BAD_ID_CATEGORIES = ("Cc", "Cs")


class FieldError(FormatError, InputFileError):
    """A value that breaks a field rule: the file, the place and what was expected and found.

    Readers of both kinds raise it where they raised their own before: it is a
    :class:`~toosicubix.errors.FormatError` (whose ``message`` holds the JSON path, and ``line`` the line) and an
    :class:`~toosicubix.errors.InputFileError` (whose ``problems`` hold the place apart).

    Attributes
    ----------
    where : the JSON path (str), the line (int, 1-based) or None
    detail : what was expected and found, without the file and the place
    """

    def __init__(self, file: str | Path | None, where: Where, detail: str):
        self.where = where
        self.detail = detail
        self.line = where if isinstance(where, int) else None
        self.message = f"{where}: {detail}" if isinstance(where, str) else detail
        InputError.__init__(self, file, [(where, detail)])


def shown(value: Any, limit: int = 60) -> str:
    """``value`` as a message shows it: its ``repr``, cut to ``limit`` characters; never fails, never spells out
    a huge integer (Python refuses to write more than 4,300 digits) or a huge container in full."""
    if isinstance(value, bool) or value is None:
        return repr(value)
    if isinstance(value, int):
        if value.bit_length() > 200:  # 61 digits and more
            return f"an integer of {_digits(value)} digits"
        text = repr(value)
    elif isinstance(value, float | str):
        text = repr(value[: limit + 1] if isinstance(value, str) else value)
    elif isinstance(value, list | tuple):
        text = _shown_items(value, "[]" if isinstance(value, list) else "()", limit)
    elif isinstance(value, dict):
        text = "{" + ", ".join(f"{shown(k, limit)}: {shown(v, limit)}" for k, v in list(value.items())[:8])
        text += ", ...}" if len(value) > 8 else "}"
    else:
        text = f"a {type(value).__name__}"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _shown_items(items: list | tuple, brackets: str, limit: int) -> str:
    shown_items, length = [], 0
    for item in items:
        text = shown(item, limit)
        shown_items.append(text)
        length += len(text) + 2
        if length > limit:
            break
    more = ", ..." if len(shown_items) < len(items) else ""
    return brackets[0] + ", ".join(shown_items) + more + brackets[1]


def _digits(value: int) -> int:
    """How many decimal digits ``abs(value)`` has, without writing it out."""
    value = abs(value)
    if value == 0:
        return 1
    estimate = int(value.bit_length() * math.log10(2))  # the true count, or one less
    return estimate + (value >= 10 ** estimate)


def _fail(file: str | Path | None, where: Where, label: str | None, expected: str, found: str) -> FieldError:
    prefix = f"{label}: " if label else ""
    return FieldError(file, where, f"{prefix}expected {expected}, got {found}")


def _plain(value: float) -> str:
    """A bound as a message writes it: ``1000000``, ``-1000000``, ``0.1``, ``1e-300``."""
    return str(int(value)) if float(value).is_integer() and abs(value) < 1e16 else f"{value:g}"


def _bounds(low: float, high: float) -> str:
    if isinstance(high, int) and high >= 10**9 and str(high + 1).rstrip("0") == "1" and low in (0, -high):
        return f" of at most {len(str(high))} digits"  # 10^k - 1: said as the count of digits
    if math.isinf(low) and math.isinf(high):
        return ""
    if math.isinf(low):
        return f" at most {_plain(high)}"
    if math.isinf(high):
        return f" at least {_plain(low)}"
    return f" from {_plain(low)} to {_plain(high)}"


def number(value: Any, file: str | Path | None, where: Where, *, low: float = -math.inf, high: float = math.inf,
           what: str = "a finite number", label: str | None = None) -> float:
    """A JSON number, finite and within ``[low, high]``, as a float.

    Parameters
    ----------
    value : as read (an ``int`` of any size, a ``float``, or anything else)
    file, where : for the message: the file and the JSON path (or line)
    low, high : the bounds (inclusive)
    what : what is expected, for the message (the bounds are added to it)
    label : a prefix of the message (e.g. the element of an XML file)

    Raises
    ------
    FieldError
        Not a number (booleans are none), not finite, too large for a float, or out of bounds.
    """
    # The message is built only for a refusal: a file of a million clicks asks this of every coordinate.
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _fail(file, where, label, what + _bounds(low, high), shown(value))
    try:
        result = float(value)
    except OverflowError:
        raise _fail(file, where, label, what + _bounds(low, high), shown(value)) from None
    if not (math.isfinite(result) and low <= result <= high):
        raise _fail(file, where, label, what + _bounds(low, high), shown(value))
    return result


def integer(value: Any, file: str | Path | None, where: Where, *, low: int, high: int,
            what: str = "an integer", label: str | None = None, integral_floats: bool = True) -> int:
    """A JSON integer within ``[low, high]``; with ``integral_floats`` also a float without a fraction
    (``1242.0``: COCO writers in other languages write sizes so).

    Raises
    ------
    FieldError
        Not an integer (booleans are none), a float with a fraction, or out of bounds.
    """
    found = value
    if isinstance(value, float) and integral_floats and math.isfinite(value) and value == int(value):
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise _fail(file, where, label, what + _bounds(low, high), shown(found))
    return value


def pixel(value: Any, file: str | Path | None, where: Where, label: str | None = None) -> float:
    """A pixel coordinate: a finite number within +-:data:`MAX_PIXEL` (the annotation file's bound)."""
    if _plain_pixel(value):
        return float(value)
    return number(value, file, where, low=-MAX_PIXEL, high=MAX_PIXEL, what="a pixel coordinate", label=label)


def is_pixel(value: Any) -> bool:
    """Whether :func:`pixel` takes ``value`` (for a reader that tells a value's form by it)."""
    return _plain_pixel(value) or passes(pixel, value)


def _plain_pixel(value: Any) -> bool:
    """A plain number within the bound, told at once: an importer asks this of every coordinate of a file (some
    hundred thousand in a COCO keypoint file). NaN, infinities and huge integers fail the comparison and are left to
    :func:`number`, which says why."""
    kind = type(value)
    return (kind is float or kind is int) and -MAX_PIXEL <= value <= MAX_PIXEL


def image_side(value: Any, file: str | Path | None, where: Where, label: str | None = None) -> int:
    """An image's width or height: an integer from 1 to :data:`MAX_PIXEL` (a float without a fraction too)."""
    return integer(value, file, where, low=1, high=int(MAX_PIXEL), what="an image side in pixels", label=label)


def metres(value: Any, file: str | Path | None, where: Where, *, low: float = 0.0, label: str | None = None,
           what: str = "a size in metres") -> float:
    """A size in metres: a finite number above ``low`` (exclusive) and at most :data:`MAX_METRES`."""
    expected = f"{what} greater than {_plain(low)} and at most {_plain(MAX_METRES)}"
    try:
        result = number(value, file, where, high=MAX_METRES)
    except FieldError:
        raise _fail(file, where, label, expected, shown(value)) from None
    if not result > low:
        raise _fail(file, where, label, expected, shown(value))
    return result


def sigma_metres(value: Any, file: str | Path | None, where: Where, label: str | None = None) -> float:
    """A sigma in metres (a known length's): a finite number from :data:`MIN_SIGMA_METRES` to :data:`MAX_METRES`."""
    return number(value, file, where, low=MIN_SIGMA_METRES, high=MAX_METRES, what="a sigma in metres", label=label)


def passes(rule: Callable[..., Any], value: Any) -> bool:
    """Whether ``value`` passes the field ``rule`` (:func:`number`, :func:`pixel`, :func:`identifier`, ...), for a
    reader that tells a value's form by it rather than refusing it."""
    try:
        rule(value, None, None)
    except FieldError:
        return False
    return True


def identifier(value: Any, file: str | Path | None, where: Where, *, what: str = "an id",
               label: str | None = None) -> str | int:
    """An id as a dataset writes it: a string of 1 to :data:`MAX_ID_LENGTH` characters without control characters
    or unpaired surrogates, or an integer of at most :data:`MAX_ID_DIGITS` digits; returned as it is (a string and
    an integer stay distinct: COCO compares them so).

    Raises
    ------
    FieldError
        Of another type (a list, an object, a float, a boolean), too long, or holding such characters.
    """
    expected = (f"{what}: a string of 1 to {MAX_ID_LENGTH} characters (no control characters) or an integer of at "
                f"most {MAX_ID_DIGITS} digits")
    if isinstance(value, int) and not isinstance(value, bool):
        if -_ID_LIMIT < value < _ID_LIMIT:
            return value
        raise _fail(file, where, label, expected, shown(value))
    if isinstance(value, str) and 0 < len(value) <= MAX_ID_LENGTH \
            and not any(unicodedata.category(c) in _BAD_ID_CATEGORIES for c in value):
        return value
    raise _fail(file, where, label, expected, shown(value))


def file_name(value: Any, file: str | Path | None, where: Where, *, what: str = "a name",
              label: str | None = None) -> str:
    """An image id or a sequence name as the annotation file has them (:data:`FILE_NAME_PATTERN`, at most
    :data:`MAX_ID_LENGTH` characters), for a reader of a file another program may have written (results.json).

    Raises
    ------
    FieldError
        Not a string, too long, or holding another character (``../../etc/passwd``).
    """
    if isinstance(value, str) and len(value) <= MAX_ID_LENGTH and re.fullmatch(FILE_NAME_PATTERN, value):
        return value
    raise _fail(file, where, label, f"{what} as the annotation file has it (it names a file): letters, digits, '_', "
                f"'.', '-', first a letter or digit, at most {MAX_ID_LENGTH} characters", shown(value))


def numeric_key(value: Any, file: str | Path | None, where: Where, *, what: str = "an id",
                label: str | None = None) -> int:
    """An id that names a number (a dataset's model number): an integer from 0, or a string of 1 to
    :data:`MAX_ID_DIGITS` decimal digits of any script, as the number it writes (``"035"`` and ``"٣٥"`` are 35).

    Raises
    ------
    FieldError
        A negative or longer number, another character (``'²'``, a sign, a space, ``_``), another type.
    """
    expected = f"{what}: an integer from 0, or 1 to {MAX_ID_DIGITS} decimal digits"
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < _ID_LIMIT:
        return value
    if isinstance(value, str) and 0 < len(value) <= MAX_ID_DIGITS and value.isdecimal():
        return int(value)
    raise _fail(file, where, label, expected, shown(value))


def text_number(text: str | None, file: str | Path | None, where: Where, *, low: float = -math.inf,
                high: float = math.inf, what: str = "a number", label: str | None = None) -> float:
    """A number written as text (an XML attribute): decimal notation in ASCII digits only (see the module),
    finite and within ``[low, high]``.

    Raises
    ------
    FieldError
        Missing, another notation (``4_01.2``, ``nan``, ``1e999``, other scripts' digits, spaces), or out of bounds.
    """
    expected = f"{what} written in decimals (e.g. 401.25){_bounds(low, high)}"
    if text is None or len(text) > MAX_NUMBER_TEXT or not _DECIMAL_TEXT.fullmatch(text):
        raise _fail(file, where, label, expected, "nothing" if text is None else shown(text))
    result = float(text)
    if not (math.isfinite(result) and low <= result <= high):
        raise _fail(file, where, label, expected, shown(text))
    return result


def text_integer(text: str | None, file: str | Path | None, where: Where, *, low: int, high: int,
                 what: str = "an integer", label: str | None = None) -> int:
    """An integer written as text: ASCII digits with an optional sign, within ``[low, high]``.

    Raises
    ------
    FieldError
        Missing, other characters (``4_01``, ``'²'``, spaces), more than :data:`MAX_ID_DIGITS` digits, out of bounds.
    """
    bounds = _bounds(low, high)
    expected = f"{what} written in{bounds[3:]}" if bounds.startswith(" of at most") else \
        f"{what} written in digits{bounds}"
    if text is None or len(text) > MAX_ID_DIGITS + 1 or not _INTEGER_TEXT.fullmatch(text) \
            or not low <= int(text) <= high:
        raise _fail(file, where, label, expected, "nothing" if text is None else shown(text))
    return int(text)


class DistinctKeys:
    """Keys checked to stay distinct once normalised (``"35"``, ``"035"`` and ``"٣٥"`` all mean car model 35): the
    second key that means what an earlier one meant is an error naming both, instead of one silently winning.

    Parameters
    ----------
    file : for the message
    what : what the keys name, e.g. ``"car model"``
    """

    def __init__(self, file: str | Path | None, what: str):
        self.file = file
        self.what = what
        self._first: dict[Hashable, tuple[Any, Where]] = {}

    def add(self, normal: Hashable, raw: Any, where: Where) -> None:
        """Record ``raw`` (at ``where``), which means ``normal``.

        Raises
        ------
        FieldError
            An earlier key meant ``normal`` too.
        """
        first = self._first.setdefault(normal, (raw, where))
        if first[1] != where:
            raise FieldError(self.file, where, f"{self.what} keys {shown(first[0])} (at {first[1]}) and {shown(raw)} "
                                               f"both mean {self.what} {shown(normal)}: expected each once; keep one")

    def __contains__(self, normal: Hashable) -> bool:
        return normal in self._first


__all__ = [
    "MAX_FRAME", "MAX_ID_DIGITS", "MAX_ID_LENGTH", "MAX_METRES", "MAX_NUMBER_TEXT", "MAX_PIXEL", "MIN_SIGMA_METRES",
    "DistinctKeys", "FieldError", "identifier", "image_side", "integer", "metres", "number", "numeric_key",
    "passes", "pixel", "shown", "sigma_metres", "text_integer", "text_number",
]
