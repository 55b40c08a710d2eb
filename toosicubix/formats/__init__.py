"""Readers and writers of files other tools use: KITTI labels and calibration, Cityscapes 3D, results JSON."""

from __future__ import annotations

from pathlib import Path


class FormatError(ValueError):
    """A file that cannot be read, naming the file and, where there is one, the line (1-based)."""

    def __init__(self, file: str | Path, message: str, line: int | None = None):
        self.file = str(file)
        self.line = line
        self.message = message
        where = f"{self.file}:{line}" if line is not None else self.file
        super().__init__(f"{where}: {message}")
