"""The one exception of the evaluation package: input that cannot be evaluated."""

from __future__ import annotations

from pathlib import Path

from toosicubix.errors import InputError, Where


class EvaluationInputError(InputError):
    """A missing folder or file, or a prediction without a ground-truth partner; the message names the path.

    Malformed files raise :class:`toosicubix.errors.FormatError` (file and line) instead.
    """

    def __init__(self, message: str, file: str | Path | None = None, where: Where = None):
        super().__init__(file, [(where, message)])
