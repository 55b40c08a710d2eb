"""The solver settings file (``toosicubix_settings: 1``) that ``toosicubix tune`` writes and ``fit --config`` reads:
its Pydantic schema and its reader."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import ConfigDict, Field

from toosicubix.annotations.schema import _Model, _validate
from toosicubix.jsonfile import read_json


class SettingsFile(_Model):
    """Solver settings for ``toosicubix fit --config`` (written by ``toosicubix tune``)."""

    model_config = ConfigDict(title="ToosiCubix settings v1")

    toosicubix_settings: Literal[1]
    lambda_3d: float | None = Field(default=None, gt=0, description="Prior weight in the descent's 3D cost.")
    lambda_px: float | None = Field(default=None, gt=0, description="Prior weight in the pixel cost (px^2).")
    tuned: dict[str, Any] | None = Field(default=None, description="How the values were chosen (free form).")


def load_settings_file(path: str | Path) -> SettingsFile:
    """Read and validate a settings file.

    Raises
    ------
    InputFileError
    """
    return _validate(SettingsFile, read_json(path, at_root=True), path)
