"""The one base of every input error: a file (or folder, or option) that cannot be used, and where in it.

Every exception that reports bad input derives from :class:`InputError`: annotation, priors and settings
files (:class:`InputFileError`), KITTI, Cityscapes 3D and results files
(:class:`FormatError`), ground-truth and prediction folders
(:class:`EvaluationInputError`), unknown prototypes
(:class:`toosicubix.size_priors.UnknownPrototypeError`), priors estimation
(:class:`toosicubix.priors.estimation.PriorEstimationError`) and output folders
(:class:`toosicubix.pipeline.output_folder.OutputFolderError`). A caller that only reports the problem catches
``InputError``; the CLI turns it into exit code 2.

Every message is formatted here, one line per problem:

- ``file:line: message`` when the place is a line (an int, 1-based),
- ``file: $.json.path: message`` when it is a JSON path (a str),
- ``file: message`` when only the file is known, ``message`` when not even that.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

#: Where in a file: a 1-based line (int), a JSON path such as ``$.images[0].id`` (str), or None.
Where = int | str | None


def locate(file: str | Path | None, where: Where = None) -> str:
    """The prefix of a message about ``file`` at ``where``: ``'f:3'``, ``'f: $.a'``, ``'f'`` or ``''``."""
    if file is None:
        return "" if where is None else str(where)
    if where is None:
        return str(file)
    if isinstance(where, int):
        return f"{file}:{where}"
    return f"{file}: {where}"


class InputError(ValueError):
    """Input that cannot be used: names the file and, per problem, the JSON path or line.

    Parameters
    ----------
    file : the file or folder, as given; None when the problem is not in a file
    problems : (where, message) pairs; ``where`` is a line (int, 1-based), a JSON path (str) or None

    Attributes
    ----------
    file : str or None
    problems : list of (where, message)
    """

    def __init__(self, file: str | Path | None, problems: Sequence[tuple[Where, str]]):
        self.file = None if file is None else str(file)
        self.problems = list(problems)
        super().__init__(self.format())

    def format(self) -> str:
        """The message: one line per problem, each naming the file and the place (see the module)."""
        lines = []
        for where, message in self.problems:
            prefix = locate(self.file, where)
            lines.append(f"{prefix}: {message}" if prefix else message)
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.format()

    def __reduce__(self):
        # Pickled with its attributes, not through ``__init__`` (whose signature subclasses change): an error
        # raised in a worker process reaches the caller as itself.
        return _restored, (type(self), self.args, self.__dict__)


class FormatError(InputError):
    """A file that cannot be read, naming the file and, where there is one, the line (1-based)."""

    def __init__(self, file: str | Path, message: str, line: int | None = None):
        self.line = line
        self.message = message
        super().__init__(file, [(line, message)])


class InputFileError(InputError):
    """An input file (annotations, priors, settings, mappings) that cannot be used, with every problem found.

    Attributes
    ----------
    file : str
        The file, as given.
    problems : list of (json_path, message)
        ``json_path`` is like ``$.images[0].vehicles[2].parts[1].part``.
    """

    def __init__(self, file: str | Path, problems: list[tuple[str, str]]):
        super().__init__(file, problems)


class EvaluationInputError(InputError):
    """A missing folder or file, or a prediction without a ground-truth partner; the message names the path.

    Malformed files raise :class:`toosicubix.errors.FormatError` (file and line) instead.
    """

    def __init__(self, message: str, file: str | Path | None = None, where: Where = None):
        super().__init__(file, [(where, message)])


def _restored(cls: type[InputError], args: tuple, state: dict) -> InputError:
    error = cls.__new__(cls, *args)
    error.args = args
    error.__dict__.update(state)
    return error


__all__ = ["EvaluationInputError", "FormatError", "InputError", "InputFileError", "Where", "locate"]
