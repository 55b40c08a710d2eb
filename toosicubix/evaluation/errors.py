"""The one exception of the evaluation package: input that cannot be evaluated."""

from __future__ import annotations


class EvaluationInputError(ValueError):
    """A missing folder or file, or a prediction without a ground-truth partner; the message names the path.

    Malformed files raise :class:`toosicubix.formats.FormatError` (file and line) instead.
    """
