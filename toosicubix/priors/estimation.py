"""Size priors estimated from ground truth: a robust Gaussian over ``(dx, dy, dz)`` per vehicle class.

The paper ("Resolving the Ambiguities") fits, per prototype class ``c``,

    mu_c    = geometric median of the dimension vectors d_i,
    Sigma_c = geometric median of the outer products (d_i - mu_c)(d_i - mu_c)^T,

the second in the Frobenius norm (the outer products flattened to R^9). The geometric median of the outer
products of ``v ~ N(0, I_3)`` is ``c I_3`` with ``c = 0.5863`` (:func:`outer_product_median_factor`), so the
raw figure underestimates a Gaussian's covariance; it is divided by ``c`` here. That makes the estimate
Gaussian-consistent for isotropic spread. For anisotropic spread (a car's length varies four times as much
as its width) the Frobenius median is not equivariant: the raw median over ``c`` then underestimates the
largest variance (by about a quarter for KITTI cars) and overestimates the smallest ones. ``method=
"whitened"`` removes that bias: it iterates ``S <- L median(L^-1 v v^T L^-T) L^T / c`` with ``S = L L^T``
until the median of the whitened outer products is ``c I``, a fixed point that every Gaussian's own
covariance satisfies. ``method="paper"`` (the default) keeps the paper's formula.

Medians suit labelled sizes, which carry a few gross errors; they fail on sizes that repeat exactly. ApolloCar3D's
cars take their extents from a few dozen CAD models, and one model can be 40 % of a type's cars: the geometric
median then sits on that model, two fifths of the outer products are zero, and their median collapses toward
zero (the shared folder's SUVs: a width sd of 2.0 cm against the 6.1 cm their sizes show). ``method="sample"`` takes the
arithmetic mean and the sample covariance (``n - 1``), right for exact sizes without outliers, and the default
for ApolloCar3D (:func:`default_method`); :func:`estimate_priors` warns when a median-based method meets a class
whose samples repeat one vector (:data:`REPEAT_SHARE`).

Samples: KITTI object labels count every object once, KITTI tracking labels every track once (its
dimensions are the same in every frame), Cityscapes 3D every box once, grouped by its prototype ``type``.

Layers: :func:`collect_dimensions` (ground truth -> samples per class), :func:`robust_gaussian`
(samples -> mean and covariance), :func:`estimate_priors` (per class, with warnings and provenance),
:func:`priors_document` and :func:`write_priors_file` (the priors file, ``priors_file.PriorsFile``).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Literal

import numpy as np
from scipy import integrate, linalg, optimize, stats

from toosicubix.annotations import priors_file
from toosicubix.errors import EvaluationInputError, InputError
from toosicubix.formats.atomic import atomic_write_text
from toosicubix.formats.ground_truth import (
    CITYSCAPES_VEHICLE_LABELS,
    KITTI_DEFAULT_CLASSES,
    GroundTruthSource,
    open_ground_truth,
)
from toosicubix.priors.geometric_median import GeometricMedianOptions, GeometricMedianResult, geometric_median

Method = Literal["paper", "whitened", "sample"]
METHODS: tuple[str, ...] = ("paper", "whitened", "sample")
#: A median-based estimate is warned about when this share of a class's samples are one repeated vector.
REPEAT_SHARE = 0.2

#: KITTI type written for a Cityscapes 3D prototype; any other name gets ``Misc``.
CITYSCAPES_KITTI_TYPES: dict[str, str] = {
    **{name: "Car" for name in ("Mid Size Car", "Small Size Car", "Sedan", "SUV", "Station Wagon", "Sports Car",
                                "Mini Car", "Pickup")},
    **{name: "Van" for name in ("Small Van", "Large Van", "Box Wagon")},
    **{name: "Truck" for name in ("Mini Truck", "Small Size Truck", "Mid Size Truck")},
}
#: Smallest variance (m^2) of a written covariance: eigenvalues are raised to at least this (1 mm squared) ...
MIN_VARIANCE = 1e-6
#: ... and to at least this fraction of the largest one, which keeps the condition number below 1e6.
MIN_EIGENVALUE_RATIO = 1e-6
#: Description of a new priors file (a ``base`` file keeps its own).
DEFAULT_DESCRIPTION = (
    "Gaussian priors of vehicle dimensions (dx, dy, dz) = (length, width, height) in metres, per prototype."
)


class PriorEstimationError(InputError):
    """Input that gives no prior: a missing sequence, no class with enough samples; the message says which."""

    def __init__(self, message: str, file: str | Path | None = None):
        super().__init__(file, [(None, message)])


@lru_cache(maxsize=8)
def outer_product_median_factor(dim: int = 3) -> float:
    """The ``c`` with geometric median of ``{v v^T : v ~ N(0, I_dim)}`` = ``c I_dim`` (Frobenius norm).

    With ``s = |v|^2 ~ chi^2(dim)``, ``|v v^T - c I|_F^2 = s^2 - 2 c s + dim c^2``; by rotational symmetry the
    median is a multiple of ``I`` and ``c`` solves ``d/dc E|v v^T - c I|_F = 0``, that is
    ``E[(s - dim c) / sqrt(s^2 - 2 c s + dim c^2)] = 0``, integrated here over the chi-square law.
    ``c = 0.58626`` for ``dim = 3``; ``dim = 1`` gives the median of chi^2(1), 0.45494.

    Raises
    ------
    ValueError
        ``dim < 1``.
    """
    if dim < 1:
        raise ValueError(f"expected a dimension >= 1, got {dim}")

    def gradient(c: float) -> float:
        def integrand(s: float) -> float:
            return (s - dim * c) / np.sqrt(s * s - 2.0 * c * s + dim * c * c) * stats.chi2.pdf(s, dim)

        # Split where the integrand has its kink (dim = 1) or bulk, so quad's error estimate holds.
        value, _ = integrate.quad(integrand, 0.0, dim * c, limit=200)
        tail, _ = integrate.quad(integrand, dim * c, np.inf, limit=200)
        return value + tail

    return float(optimize.brentq(gradient, 1e-3, float(dim), xtol=1e-13, rtol=1e-13))


@dataclass(frozen=True)
class RobustGaussian:
    """A robust mean and covariance of samples in R^k.

    Attributes
    ----------
    mean : (k,) geometric median of the samples (arithmetic mean for 'sample')
    cov : (k, k) symmetric positive definite covariance, consistent for Gaussian data (see the module)
    cov_median : (k, k) the paper's raw figure: geometric median of ``(x_i - mean)(x_i - mean)^T``,
        symmetrized; ``cov_median / c`` is ``cov`` for ``method="paper"`` (before any eigenvalue floor)
    n : number of samples
    consistency_factor : ``c``, see :func:`outer_product_median_factor`
    method : 'paper', 'whitened' or 'sample' (then ``cov_median`` is the sample covariance and ``c`` is 1)
    floored_eigenvalues : how many eigenvalues were raised to the floor to make ``cov`` positive definite
    mean_fit, cov_fit : diagnostics of the two geometric medians (for 'whitened', of the last whitened one;
        None for 'sample')
    whitening_iterations : fixed-point steps of 'whitened' (0 for 'paper')
    converged : every geometric median converged (and, for 'whitened', the fixed point)
    """

    mean: np.ndarray
    cov: np.ndarray
    cov_median: np.ndarray
    n: int
    consistency_factor: float
    method: str
    floored_eigenvalues: int
    mean_fit: GeometricMedianResult | None
    cov_fit: GeometricMedianResult | None
    whitening_iterations: int = 0
    converged: bool = True

    @property
    def std(self) -> np.ndarray:
        """(k,) square roots of the covariance's diagonal."""
        return np.sqrt(np.diag(self.cov))


def outer_products(deviations: np.ndarray) -> np.ndarray:
    """Flattened outer products ``v_i v_i^T`` of deviations (n, k), as (n, k*k) rows (row-major)."""
    V = np.asarray(deviations, dtype=np.float64)
    return np.einsum("ni,nj->nij", V, V).reshape(V.shape[0], -1)


def make_positive_definite(matrix: np.ndarray, min_value: float = MIN_VARIANCE,
                           min_ratio: float = MIN_EIGENVALUE_RATIO) -> tuple[np.ndarray, int]:
    """Symmetrize a (k, k) matrix and raise its eigenvalues to ``max(min_value, min_ratio * largest)``.

    Returns
    -------
    matrix : (k, k) symmetric positive definite
    floored : how many eigenvalues were raised
    """
    S = 0.5 * (np.asarray(matrix, dtype=np.float64) + np.asarray(matrix, dtype=np.float64).T)
    eigenvalues, vectors = np.linalg.eigh(S)
    floor = max(min_value, min_ratio * float(eigenvalues.max()))
    low = eigenvalues < floor
    if not np.any(low):
        return S, 0
    S = (vectors * np.maximum(eigenvalues, floor)) @ vectors.T
    return 0.5 * (S + S.T), int(low.sum())


def robust_gaussian(samples: np.ndarray, method: Method = "paper", options: GeometricMedianOptions | None = None,
                    max_whitening_iterations: int = 100, whitening_tol: float = 1e-8) -> RobustGaussian:
    """The paper's robust mean and covariance of samples, made positive definite and Gaussian-consistent.

    Parameters
    ----------
    samples : (n, k) with n >= 2, e.g. dimension vectors ``(dx, dy, dz)`` in metres
    method : 'paper' (raw median of the outer products divided by ``c``), 'whitened' (its equivariant
        fixed point, consistent for any Gaussian) or 'sample' (mean and sample covariance, not robust); see the
        module docstring
    options : stopping rule of the geometric medians
    max_whitening_iterations, whitening_tol : 'whitened' stops when ``|median / c - I|_F <= whitening_tol``

    Returns
    -------
    RobustGaussian

    Raises
    ------
    ValueError
        Fewer than 2 samples, non-finite values, or an unknown method.
    """
    X = np.asarray(samples, dtype=np.float64)
    if X.ndim != 2 or X.shape[0] < 2:
        raise ValueError(f"expected at least 2 samples of shape (n, k), got shape {X.shape}")
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    k = X.shape[1]
    if method == "sample":
        if not np.all(np.isfinite(X)):
            raise ValueError("samples must be finite")
        mean = X.mean(axis=0)
        cov_sample = np.atleast_2d(np.cov(X, rowvar=False, ddof=1))
        cov, floored = make_positive_definite(0.5 * (cov_sample + cov_sample.T))
        return RobustGaussian(mean=mean, cov=cov, cov_median=cov_sample, n=X.shape[0], consistency_factor=1.0,
                              method=method, floored_eigenvalues=floored, mean_fit=None, cov_fit=None)
    c = outer_product_median_factor(k)
    mean_fit = geometric_median(X, options=options)
    V = X - mean_fit.median
    cov_fit = geometric_median(outer_products(V), options=options)
    cov_median = cov_fit.median.reshape(k, k)
    cov_median = 0.5 * (cov_median + cov_median.T)
    cov, floored = make_positive_definite(cov_median / c)
    converged = mean_fit.converged and cov_fit.converged
    iterations = 0
    if method == "whitened":
        fixed_point = False
        while not fixed_point and iterations < max_whitening_iterations:
            iterations += 1
            L = np.linalg.cholesky(cov)
            Z = linalg.solve_triangular(L, V.T, lower=True).T
            cov_fit = geometric_median(outer_products(Z), options=options)
            M = cov_fit.median.reshape(k, k) / c
            M = 0.5 * (M + M.T)
            cov, floored = make_positive_definite(L @ M @ L.T)
            converged = converged and cov_fit.converged
            fixed_point = bool(np.linalg.norm(M - np.eye(k)) <= whitening_tol)
        converged = converged and fixed_point
    return RobustGaussian(mean=mean_fit.median, cov=cov, cov_median=cov_median, n=X.shape[0],
                          consistency_factor=c, method=method, floored_eigenvalues=floored, mean_fit=mean_fit,
                          cov_fit=cov_fit, whitening_iterations=iterations, converged=converged)


# --- samples from ground truth ---------------------------------------------------------------------------


@dataclass(frozen=True)
class DimensionSamples:
    """Dimension samples per class read from one ground-truth source.

    Attributes
    ----------
    dimensions : class name (as spelled in the data) -> (n, 3) ``(dx, dy, dz)`` metres, one row per
        object (KITTI object, Cityscapes) or per track (KITTI tracking)
    kind : 'kitti', 'kitti-tracking', 'cityscapes' or 'apollocar3d'
    root : the folder (ApolloCar3D: the keypoint file) read, as given
    unit : 'object', 'track' or 'car' (ApolloCar3D): what one row stands for
    sequences : the tracking sequences read, or None (all, or not tracking)
    missing : requested classes without any sample
    notes : remarks for the report (tracks whose rows disagree, boxes without a type)
    """

    dimensions: dict[str, np.ndarray]
    kind: str
    root: Path
    unit: str
    sequences: tuple[str, ...] | None = None
    missing: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    def describe(self) -> str:
        """What was read, for an entry's provenance: e.g. 'KITTI tracking labels in DIR, sequences
        0000-0009, one sample per track'."""
        what = {"kitti": "KITTI object labels", "kitti-tracking": "KITTI tracking labels",
                "cityscapes": "Cityscapes 3D gtBbox3d boxes grouped by their prototype type",
                "apollocar3d": "ApolloCar3D cars (their car models' extents) grouped by the prototype of their "
                               "car-model type"}[self.kind]
        text = f"{what} in {self.root}"
        if self.kind == "kitti-tracking":
            text += f", sequences {format_sequences(self.sequences) if self.sequences is not None else 'all'}"
        return f"{text}, one sample per {self.unit}"


def format_sequences(names: Sequence[str]) -> str:
    """Sequence names as compact ranges: ('0000', '0001', '0002', '0005') -> '0000-0002,0005'."""
    parts: list[str] = []
    ordered = sorted(names, key=lambda s: (int(s), s)) if all(s.isdigit() for s in names) else list(names)
    i = 0
    while i < len(ordered):
        j = i
        while (j + 1 < len(ordered) and ordered[j + 1].isdigit() and ordered[j].isdigit()
               and int(ordered[j + 1]) == int(ordered[j]) + 1):
            j += 1
        parts.append(ordered[i] if i == j else f"{ordered[i]}-{ordered[j]}")
        i = j + 1
    return ",".join(parts)


def priors_command_line(kind: str, root: str | Path, classes: Sequence[str] | None = None,
                        sequences: Sequence[str] | None = None, method: str = "paper",
                        car_models: str | Path | None = None) -> str:
    """The ``toosicubix priors`` command that estimates these priors, recorded in every entry's source."""
    command = f"toosicubix priors --{kind} {root}"
    if car_models is not None:
        command += f" --car-models {car_models}"
    if sequences is not None:
        command += f" --sequences {format_sequences(sequences)}"
    if classes is not None:
        command += f" --classes {','.join(classes)}"
    if method != default_method(kind):
        command += f" --covariance {method}"
    return command


def collect_dimensions(kind: str, root: str | Path, classes: Sequence[str] | None = None,
                       sequences: Sequence[str] | None = None, car_models: str | Path | None = None
                       ) -> DimensionSamples:
    """Read the dimensions of every object of the asked classes from a ground-truth folder.

    Parameters
    ----------
    kind : 'kitti' (object labels), 'kitti-tracking', 'cityscapes' or 'apollocar3d'
    root : the folder, laid out as :mod:`toosicubix.formats.datasets` describes; ApolloCar3D: its keypoint file
    classes : class names, matched case-insensitively (KITTI ``type``, Cityscapes ``3d.type``, ApolloCar3D the
        prototype of the car-model type, :data:`toosicubix.formats.apollocar3d.PROTOTYPE_OF_TYPE`); default
        Car, Van, Truck for KITTI and every class found for the others
    sequences : tracking only: sequence names such as '0003'; default all
    car_models : ApolloCar3D only: its ``car_models.json`` (default: beside the keypoint file); one sample per
        labelled car, the extents of its car model

    Returns
    -------
    DimensionSamples
        KITTI tracking: one row per track (sequence, track id, type), the dimensions of its first row, or
        the geometric median of its rows when they differ (a note says so).

    Raises
    ------
    toosicubix.errors.FormatError
        Missing folder, no label files, or a malformed label line or file (file and line, or JSON path).
    PriorEstimationError
        ``sequences`` for a source other than tracking, or a requested sequence without a label file.
    """
    root = Path(root)
    if sequences is not None and kind != "kitti-tracking":
        raise PriorEstimationError("sequences can only be chosen for KITTI tracking labels")
    if car_models is not None and kind != "apollocar3d":
        raise PriorEstimationError("car models go with ApolloCar3D only")
    options = {"car_models": car_models, "keypoint_checks": False} if kind == "apollocar3d" else {}
    source = open_ground_truth(kind, root, **options)
    rows, notes = _rows(source, sequences)
    unit = {"kitti-tracking": "track", "apollocar3d": "car"}.get(kind, "object")
    if classes is None:
        if kind in ("cityscapes", "apollocar3d"):
            classes = sorted({name for name, _ in rows})
        else:
            classes = KITTI_DEFAULT_CLASSES
    wanted = {c.lower(): c for c in classes}
    found: dict[str, list[np.ndarray]] = {}
    spelled: dict[str, str] = {}
    for name, dims in rows:
        key = name.lower()
        if key in wanted:
            spelled.setdefault(key, name)
            found.setdefault(key, []).append(dims)
    dimensions = {spelled[key]: np.array(found[key]) for key in wanted if key in found}
    missing = tuple(wanted[key] for key in wanted if key not in found)
    return DimensionSamples(dimensions=dimensions, kind=kind, root=root, unit=unit,
                            sequences=tuple(sequences) if sequences is not None else None, missing=missing,
                            notes=tuple(notes))


def _rows(source: GroundTruthSource, sequences: Sequence[str] | None
          ) -> tuple[list[tuple[str, np.ndarray]], list[str]]:
    """``(class, dimensions)`` of every object a size prior can be estimated from
    (:meth:`GroundTruthSource.size_class`), in the order the source reads them; a source of tracks (KITTI tracking)
    gives one row per track, the dimensions of its first row, or the geometric median of its rows when they differ
    (a note says so)."""
    if sequences is None:
        image_ids = source.image_ids()
    else:
        files = [source.folder.label_file(name) for name in sequences]  # type: ignore[attr-defined]
        absent = [str(path) for path in files if not path.is_file()]
        if absent:
            raise PriorEstimationError(f"no label file for the requested sequences: expected {', '.join(absent)}")
        image_ids = [image_id for name in sequences for image_id in source.sequence_ids(name)]  # type: ignore[attr-defined]
    per_object: list[tuple[str, np.ndarray]] = []
    tracks: dict[tuple[str, int, str], list[np.ndarray]] = {}
    for image_id in image_ids:
        try:
            gt = source.load(image_id)
        except EvaluationInputError as exc:  # e.g. Cityscapes files that claim one image
            raise PriorEstimationError(exc.problems[0][1], source.root) from None
        for obj in gt.objects:
            name = source.size_class(obj)
            if name is None:
                continue
            if source.per_track:
                sequence = image_id.rpartition("_")[0]
                key = (sequence, int(obj.track_id), name)  # type: ignore[arg-type]
                tracks.setdefault(key, []).append(obj.cuboid_rect.dimensions)  # type: ignore[union-attr]
            else:
                per_object.append((name, obj.cuboid_rect.dimensions))  # type: ignore[union-attr]
    if not source.per_track:
        return per_object, []
    rows: list[tuple[str, np.ndarray]] = []
    differing = 0
    for (_, _, type_), dims in tracks.items():
        D = np.array(dims)
        if np.all(D == D[0]):
            rows.append((type_, D[0]))
        else:
            differing += 1
            rows.append((type_, geometric_median(D).median))
    notes = [f"{differing} tracks have rows with differing dimensions; the geometric median of each was used"
             ] if differing else []
    return rows, notes


def apollocar3d_rows(images: Sequence, prototype_of_type: dict[str, str] | None = None
                     ) -> list[tuple[str, np.ndarray]]:
    """``(prototype, (3,) dimensions)`` of every car of ApolloCar3D ``images``
    (:class:`toosicubix.formats.apollocar3d.ApolloImage`): its car model's extents, under the prototype of its
    car-model type (``prototype_of_type``, default :data:`toosicubix.formats.apollocar3d.PROTOTYPE_OF_TYPE`)."""
    from toosicubix.formats.apollocar3d import prototype_of

    return [(prototype_of(car.model.type, prototype_of_type), car.model.dimensions)
            for image in images for car in image.cars]


# --- priors per class --------------------------------------------------------------------------------------


def kitti_type_for(name: str, kind: str) -> str:
    """The KITTI type written for a class: itself for KITTI data, 'Car' for ApolloCar3D (cars only), by
    :data:`CITYSCAPES_KITTI_TYPES` (else 'Misc') for Cityscapes prototype names."""
    if kind in ("kitti", "kitti-tracking"):
        return name
    if kind == "apollocar3d":
        return "Car"
    return CITYSCAPES_KITTI_TYPES.get(name, "Misc")


@dataclass(frozen=True)
class ClassPrior:
    """The estimated prior of one class.

    Attributes
    ----------
    name : class name as in the data
    gaussian : the robust fit; ``gaussian.n`` samples
    kitti_type : type written to KITTI files
    source : provenance for the priors file
    few_samples : fewer than ``min_samples``
    """

    name: str
    gaussian: RobustGaussian
    kitti_type: str
    source: str
    few_samples: bool

    def entry(self) -> priors_file.PriorEntry:
        """The priors-file entry: mean to 0.1 mm, covariance to 9 significant digits (keeps it positive
        definite for condition numbers up to the floor's 1e6)."""
        mean = tuple(round(float(v), 4) for v in self.gaussian.mean)
        cov = tuple(tuple(float(f"{float(v):.9g}") for v in row) for row in self.gaussian.cov)
        return priors_file.PriorEntry(mean=mean, cov=cov, kitti_type=self.kitti_type, n=self.gaussian.n,  # type: ignore[arg-type]
                                  approximate=False, source=self.source)


@dataclass(frozen=True)
class PriorEstimates:
    """Priors estimated from one :class:`DimensionSamples`.

    Attributes
    ----------
    classes : name -> :class:`ClassPrior`, in the order asked
    warnings : classes too small (named), missing or skipped, and notes from reading
    skipped : classes that gave no prior (fewer than 2 samples)
    """

    classes: dict[str, ClassPrior]
    warnings: list[str] = field(default_factory=list)
    skipped: tuple[str, ...] = ()


def estimate_priors(samples: DimensionSamples, min_samples: int = 20, method: Method = "paper",
                    command: str | None = None, options: GeometricMedianOptions | None = None) -> PriorEstimates:
    """A robust Gaussian prior per class of ``samples``.

    Parameters
    ----------
    samples : from :func:`collect_dimensions`
    min_samples : classes with fewer samples are still estimated but named in a warning and in their source;
        classes with fewer than 2 samples cannot give a covariance and are skipped with a warning
    method : see :func:`robust_gaussian`
    command : the command line that produced them, recorded in every source (e.g. ``toosicubix priors ...``)
    options : stopping rule of the geometric medians

    Returns
    -------
    PriorEstimates
    """
    c = outer_product_median_factor(3)
    warnings = [f"{name}: no samples found" for name in samples.missing]
    warnings += list(samples.notes)
    classes: dict[str, ClassPrior] = {}
    skipped: list[str] = []
    for name, dims in samples.dimensions.items():
        n = dims.shape[0]
        if n < 2:
            warnings.append(f"{name}: only {n} sample; at least 2 are needed for a covariance, skipped")
            skipped.append(name)
            continue
        gaussian = robust_gaussian(dims, method=method, options=options)
        few = n < min_samples
        if few:
            warnings.append(f"{name}: only {n} samples (fewer than {min_samples}); written, but its spread is "
                            f"poorly determined")
        if not gaussian.converged:
            warnings.append(f"{name}: a geometric median did not converge within the iteration cap")
        share = repeated_share(dims)
        if method != "sample" and share >= REPEAT_SHARE:
            warnings.append(f"{name}: {100 * share:.0f} % of its samples are one repeated size, on which the "
                            f"geometric medians collapse (its spread is underestimated); sizes that repeat exactly "
                            f"are better estimated with --covariance sample")
        classes[name] = ClassPrior(name=name, gaussian=gaussian, kitti_type=kitti_type_for(name, samples.kind),
                                   source=_source(samples, gaussian, c, few, min_samples, command), few_samples=few)
    return PriorEstimates(classes=classes, warnings=warnings, skipped=tuple(skipped))


def repeated_share(samples: np.ndarray) -> float:
    """The largest share of ``samples`` (n, k) equal to one another (to 0.1 mm): 1 / n when none repeats."""
    _, counts = np.unique(np.round(np.asarray(samples, dtype=float), 4), axis=0, return_counts=True)
    return float(counts.max() / len(samples))


def default_method(kind: str) -> Method:
    """The covariance method :func:`estimate_priors` is given by default for a ground-truth ``kind``: 'sample'
    for ApolloCar3D (exact CAD extents, a few models repeated), the paper's for labelled sizes."""
    return "sample" if kind == "apollocar3d" else "paper"


def _source(samples: DimensionSamples, g: RobustGaussian, c: float, few: bool, min_samples: int,
            command: str | None) -> str:
    text = f"{command}: " if command else ""
    text += f"{samples.describe()}; n={g.n}; "
    if g.method == "sample":
        text += "mean = arithmetic mean of the dimension vectors; cov = sample covariance (n - 1)"
    elif g.method == "paper":
        text += (f"mean = geometric median of the dimension vectors; cov = geometric median of the outer products "
                 f"(d_i - mean)(d_i - mean)^T divided by c={c:.6f} (Gaussian consistency; multiply by c for the "
                 f"paper's raw figure)")
    else:
        raw = np.array2string(g.cov_median, precision=6, separator=", ", suppress_small=True).replace("\n", "")
        text += (f"mean = geometric median of the dimension vectors; cov = whitened fixed point: the S whose "
                 f"whitened outer products L^-1 (d_i - mean)(d_i - mean)^T L^-T (S = L L^T) have geometric median "
                 f"c I, c={c:.6f} (Gaussian consistency for any covariance); the paper's raw figure (geometric median "
                 f"of the outer products) is {raw}")
    if g.floored_eigenvalues:
        text += f"; {g.floored_eigenvalues} eigenvalue(s) raised to the positive-definite floor"
    if few:
        text += f"; only {g.n} samples (fewer than {min_samples}): the spread is poorly determined"
    return text


# --- the priors file ---------------------------------------------------------------------------------------


def priors_document(estimates: PriorEstimates, base: priors_file.PriorsFile | None = None) -> priors_file.PriorsFile:
    """A validated priors file: ``base``'s entries (in order) with the estimated classes replaced or added.

    Raises
    ------
    pydantic.ValidationError
        An entry that does not validate (cannot happen for a positive definite estimate).
    """
    prototypes = dict(base.prototypes) if base is not None else {}
    for name, prior in estimates.classes.items():
        prototypes[name] = prior.entry()
    description = base.description if base is not None and base.description else DEFAULT_DESCRIPTION
    return priors_file.PriorsFile(toosicubix_priors=1, description=description, prototypes=prototypes)


def write_priors_file(document: priors_file.PriorsFile, path: str | Path) -> None:
    """Write a priors file atomically (JSON, one-space indent, as the bundled table).

    Raises
    ------
    OSError
        The folder does not exist or is not writable.
    """
    text = json.dumps(document.model_dump(mode="json"), indent=1, ensure_ascii=False) + "\n"
    atomic_write_text(path, text)


__all__ = [
    "CITYSCAPES_KITTI_TYPES", "CITYSCAPES_VEHICLE_LABELS", "DEFAULT_DESCRIPTION", "KITTI_DEFAULT_CLASSES", "METHODS",
    "MIN_EIGENVALUE_RATIO", "MIN_VARIANCE", "REPEAT_SHARE", "ClassPrior", "DimensionSamples", "PriorEstimates",
    "PriorEstimationError", "RobustGaussian", "apollocar3d_rows", "collect_dimensions", "default_method",
    "estimate_priors", "format_sequences", "kitti_type_for", "make_positive_definite", "outer_product_median_factor",
    "outer_products", "priors_command_line", "priors_document", "repeated_share", "robust_gaussian",
    "write_priors_file",
]
