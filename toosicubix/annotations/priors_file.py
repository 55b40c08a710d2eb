"""The size priors file (``toosicubix_priors: 1``): its Pydantic schema and its reader, which gives the solver's table
(:class:`toosicubix.size_priors.Priors`)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import ConfigDict, Field, field_validator

from toosicubix.annotations.schema import Row3, _Model, _validate
from toosicubix.jsonfile import read_json
from toosicubix.size_priors import Priors, SizePrior, bundled_priors_path


class PriorEntry(_Model):
    """The Gaussian size prior of one prototype, dimensions ordered (dx, dy, dz) = (length, width, height)."""

    mean: Row3 = Field(description="Mean (dx, dy, dz) in metres.")
    cov: tuple[Row3, Row3, Row3] = Field(description="Covariance of (dx, dy, dz), m^2; symmetric positive definite.")
    kitti_type: str = Field(pattern=r"^\S+$", description="Type written to KITTI label files, e.g. 'Car'.")
    n: int | None = Field(default=None, ge=0, description="Number of vehicles it was estimated from.")
    approximate: bool = Field(default=False, description="True when not estimated from measured data.")
    source: str = Field(min_length=1, description="Where the figures come from.")

    @field_validator("mean")
    @classmethod
    def _ensure_positive_mean(cls, mean: Row3) -> Row3:
        if min(mean) <= 0:
            raise ValueError(f"expected positive dimensions, got {list(mean)}")
        return mean

    @field_validator("cov")
    @classmethod
    def _ensure_spd(cls, cov: tuple[Row3, Row3, Row3]) -> tuple[Row3, Row3, Row3]:
        C = np.array(cov)
        if not np.allclose(C, C.T, rtol=1e-9, atol=1e-12):
            raise ValueError("expected a symmetric covariance")
        if np.linalg.eigvalsh(C).min() <= 0:
            raise ValueError(f"expected a positive definite covariance, eigenvalues {np.linalg.eigvalsh(C).tolist()}")
        return cov


class PriorsFile(_Model):
    """A table of size priors per prototype."""

    model_config = ConfigDict(title="ToosiCubix size priors v1")

    toosicubix_priors: Literal[1]
    description: str = ""
    prototypes: dict[str, PriorEntry] = Field(min_length=1)


def load_priors_file(path: str | Path) -> PriorsFile:
    """Read and validate a priors file.

    Raises
    ------
    InputFileError
    """
    return _validate(PriorsFile, read_json(path, at_root=True), path)


def load_priors(path: str | Path | None = None) -> Priors:
    """Load a priors file, or the bundled one when ``path`` is None.

    Raises
    ------
    toosicubix.errors.InputFileError
        The file is unreadable or not a valid priors file (the message names the JSON path).
    """
    bundled = path is None
    path = Path(path) if path is not None else bundled_priors_path()
    doc = load_priors_file(path)
    entries = {
        name: SizePrior.from_mean_cov(name, np.array(e.mean), np.array(e.cov), e.kitti_type, e.n,
                                      e.approximate, e.source)
        for name, e in doc.prototypes.items()
    }
    return Priors(entries, str(path), bundled)
