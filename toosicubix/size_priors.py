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


@dataclass(frozen=True)
class AxlePrior:
    """Where a prototype's axles sit: ``Xwf ~ N(front * dx, sigma^2)`` and ``Xwr ~ N(-rear * dx, sigma^2)``.

    Attributes
    ----------
    front, rear : fractions of the length ``dx`` from the middle to each axle (both positive)
    spread : the standard deviation, as a fraction of the prototype's mean length (``sigma = spread * mu_dx``, metres)
    """

    front: float
    rear: float
    spread: float

    @property
    def at(self) -> dict[str, float]:
        """Each axle's unknown (``Xwf``, ``Xwr``) and where the prior puts it, a signed fraction of ``dx``."""
        return {"Xwf": self.front, "Xwr": -self.rear}

    def sigma(self, mean_length: float) -> float:
        """The standard deviation of an axle's place, metres, for a prototype of mean length ``mean_length``."""
        return self.spread * mean_length


#: Rules 29 and 30 (benchmarks/decisions.md): real cars' axles, from ApolloCar3D's human wheel-centre keypoints on
#: 79 car models as the bundled ``apollocar3d-66`` mapping learned them (n-weighted means of the two centres per axle;
#: twice the largest of their four spreads).
CAR_AXLES = AxlePrior(front=0.299, rear=0.282, spread=0.043)
#: The prototypes whose axles :data:`CAR_AXLES` states (rule 30): the bundled cars, by name.
CAR_PROTOTYPES = frozenset({"Car", "Sedan", "SUV", "Station Wagon", "Sports Car", "Mini Car", "Small Size Car",
                            "Mid Size Car", "Pickup"})


def axle_prior(prototype: str) -> AxlePrior | None:
    """The axle prior of ``prototype``: :data:`CAR_AXLES` for a car (:data:`CAR_PROTOTYPES`), None (free axles) for
    vans, trucks, buses, other road users and prototypes a user adds."""
    return CAR_AXLES if prototype in CAR_PROTOTYPES else None
