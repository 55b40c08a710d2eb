"""Gaussian size priors per vehicle prototype: mean and covariance of ``(dx, dy, dz)``, as the solver uses them.

The bundled table (``toosicubix/data/priors.json``) covers KITTI's Car, Van and Truck and the
Cityscapes 3D prototype names; ``--priors FILE`` replaces it. Each entry records its provenance. The file is read by
:func:`toosicubix.annotations.priors_file.load_priors`.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from toosicubix.errors import InputError


@dataclass(frozen=True)
class SizePrior:
    """``d ~ N(mean, cov)`` for one prototype.

    Attributes
    ----------
    mean : (3,) ``(dx, dy, dz)`` metres
    cov : (3, 3) m^2, symmetric positive definite
    sqrt_information : (3, 3) upper triangular ``W`` with ``W.T @ W == inv(cov)``, so that
        ``(d - mean) @ inv(cov) @ (d - mean) == |W @ (d - mean)|^2``
    kitti_type : the type written to KITTI label files
    """

    prototype: str
    mean: np.ndarray
    cov: np.ndarray
    sqrt_information: np.ndarray
    kitti_type: str
    n: int | None
    approximate: bool
    source: str

    @classmethod
    def from_mean_cov(cls, prototype: str, mean: np.ndarray, cov: np.ndarray, kitti_type: str = "Car",
                      n: int | None = None, approximate: bool = False, source: str = "given") -> SizePrior:
        mean = np.asarray(mean, dtype=float)
        cov = np.asarray(cov, dtype=float)
        L = np.linalg.cholesky(np.linalg.inv(cov))  # inv(cov) = L L^T
        return cls(prototype, mean, cov, L.T.copy(), kitti_type, n, approximate, source)

    def mahalanobis2(self, dimensions: np.ndarray) -> float:
        """``(d - mean)^T inv(cov) (d - mean)`` for ``dimensions`` (3,)."""
        r = self.sqrt_information @ (np.asarray(dimensions, dtype=float) - self.mean)
        return float(r @ r)


class UnknownPrototypeError(InputError, KeyError):
    """A prototype that is not in the priors table; the message lists the known ones."""

    def __init__(self, prototype: str, known: list[str]):
        self.prototype = prototype
        self.known = known
        close = difflib.get_close_matches(prototype, known, n=3, cutoff=0.6)
        hint = f" Did you mean {', '.join(repr(c) for c in close)}?" if close else ""
        super().__init__(None, [(None, f"unknown prototype {prototype!r}.{hint} Known prototypes: {', '.join(known)}")])


class Priors(Mapping[str, SizePrior]):
    """A read-only table ``prototype -> SizePrior``; looking up an unknown name raises
    :class:`UnknownPrototypeError`."""

    def __init__(self, entries: dict[str, SizePrior], source: str, bundled: bool = False):
        self._entries = dict(entries)
        self.source = source
        self.bundled = bundled  # the table shipped with the package, not a file a user gave

    def __getitem__(self, prototype: str) -> SizePrior:
        try:
            return self._entries[prototype]
        except KeyError:
            raise UnknownPrototypeError(prototype, sorted(self._entries)) from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)


def bundled_priors_path() -> Path:
    """Path of the priors table shipped with the package."""
    return Path(str(resources.files("toosicubix") / "data" / "priors.json"))
