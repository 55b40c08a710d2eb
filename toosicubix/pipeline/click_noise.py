"""The click noise of a batch, estimated from its own residuals (what ``toosicubix fit`` does unless it is given
``--click-sigma``).

Every reported uncertainty (sigma, confidence, ambiguity, the soft term of keypoints, the robust loss's scale)
is computed for a click noise ``sigma`` in pixels per coordinate. Real annotators differ; the batch says how
precise its own were. A pilot fit of up to :data:`PILOT_VEHICLES` vehicles spread evenly over the file gives
each fitted vehicle's residuals ``r_i`` (pixels). A keypoint's (or plate's) residual has the variance of the
click noise plus that of where the vehicle's keypoint sits around its learned position: ``sigma^2 + s_i^2`` per
coordinate, with ``s_i`` (pixels) its learned spread, which its soft weight ``w_i = sigma_0 / sqrt(sigma_0^2 +
s_i^2)`` at the pilot's ``sigma_0`` holds. The estimate solves the moment equation pooled over the vehicles
with redundant clicks

    sum_v sum_i |r_i|^2 / (sigma^2 + s_i^2)  =  sum_v dof_v

with ``dof_v`` the effective degrees of freedom of vehicle ``v``'s pixel residuals at its optimum
(:func:`toosicubix.solver.uncertainty.residual_dof`, ``n - 2 tr H + tr H^2`` of the hat matrix): ``2 N_v``
minus what the fit absorbs. Counting the unknowns instead (``2 N_v - (5 + P_v)``: pose and shape up to scale)
overstates the noise where the size prior holds shape directions the clicks barely see: on simulated KITTI
clicks of 1 px, parts exactly on the cuboid, 1.39 px against 1.10 px this way.

Only vehicles whose every click has a learned spread (keypoints, plates) enter. The residuals of parts on the
cuboid (tyres, light pairs, corners) are dominated by how far real parts sit from the box (``part_sigma``),
which they cannot tell from the click noise: on simulated KITTI clicks with realistic placement they imply
2.3, 2.4 and 2.9 px for a true noise of 0.5, 1 and 2 px. A batch without such vehicles, or with fewer than
:data:`MIN_DOF` degrees of freedom, keeps the given default.

The sigmas take more from the same residuals (benchmarks/decisions.md, rules 34 and 35). The moment equation holds
the learned spreads as they are; whether they describe this batch's keypoints, the residuals tell too, since a batch
has keypoints near and far and spreads small and large. Each click's expected squared residual is ``2 c_v (sigma'^2
+ t^2 s_i^2)``, ``c_v = dof_v / 2 N_v``, and :func:`two_scale_ml` finds the ``(sigma', t)`` of greatest likelihood
from the vehicles none of whose clicks the batch's robust loss would down-weight (:func:`clean`: a sigma describes a
fit whose gross outliers that loss took out, and the pilot fits without it). The fit keeps its weights (``sigma``
and the spreads as learned); the sigmas, a sandwich covariance that is right for any weights once given the rows'
noise, take ``(sigma', t)`` (:attr:`toosicubix.solver.fit.SolverOptions.soft_noise`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np

from toosicubix.formats.results import ImageResult, VehicleResult
from toosicubix.model import Image, Vehicle
from toosicubix.solver.robust import CAUCHY_SCALE, DOWNWEIGHTED_BELOW
from toosicubix.vocabulary import KINDS

#: Vehicles the pilot fit takes at most, every k-th of the batch.
PILOT_VEHICLES = 400
#: Fewer redundant degrees of freedom than this give no estimate (relative standard error 1 / sqrt(2 dof): 5 %).
MIN_DOF = 200
#: A vehicle whose residuals have fewer degrees of freedom than this is left out (its clicks are not redundant).
MIN_VEHICLE_DOF = 0.5
#: An estimate is kept within these bounds (pixels): below, sub-pixel clicks the model's own error hides;
#: above, clicks that are not on their parts at all.
SIGMA_BOUNDS = (0.1, 50.0)
#: The estimate of the scale on the keypoints' learned spreads is kept within these bounds: a hundredth of them (as
#: good as exact) to ten times (no keypoint at its learned position).
SPREAD_SCALE_BOUNDS = (0.01, 10.0)
#: A click whose squared standardized residual passes this, the batch's robust loss would down-weight (its factor
#: ``1 / sqrt(1 + e^2 / c^2)`` below ``DOWNWEIGHTED_BELOW``): its vehicle stays out of the sigmas' estimate (rule 35).
DOWNWEIGHTED_E2 = CAUCHY_SCALE**2 * (1.0 / DOWNWEIGHTED_BELOW**2 - 1.0)


@dataclass(frozen=True)
class ClickNoise:
    """The click noise a batch is fitted with, and where it came from.

    Attributes
    ----------
    sigma_px : pixels per coordinate, what every vehicle's uncertainty is computed for
    source : 'given' (``--click-sigma``), 'estimated' (from the pilot's residuals) or 'default' (too few
        redundant clicks to estimate it)
    estimate_px : the pilot's estimate (None when it had no redundant click), at a bound of SIGMA_BOUNDS when
        the residuals lie beyond what it allows
    dof : the residuals' degrees of freedom it rests on (effective: a sum of fractional ones)
    pilot_vehicles, redundant_vehicles : vehicles fitted by the pilot; those of them whose clicks are redundant
    clean_vehicles : how many of the redundant vehicles have no click the robust loss would down-weight
        (:func:`clean`), which ``sigmas_noise`` is estimated from
    sigmas_noise : when estimated, what the sigmas take (:attr:`toosicubix.solver.fit.SolverOptions.soft_noise`):
        the click noise (pixels) and the scale on the learned spreads of greatest likelihood (the module's
        docstring); None otherwise
    """

    sigma_px: float
    source: str
    estimate_px: float | None = None
    dof: float = 0.0
    pilot_vehicles: int = 0
    redundant_vehicles: int = 0
    sigmas_noise: tuple[float, float] | None = None
    clean_vehicles: int = 0

    def to_json(self) -> dict:
        out = {"sigma_px": self.sigma_px, "source": self.source, "estimate_px": self.estimate_px,
               "dof": self.dof, "pilot_vehicles": self.pilot_vehicles,
               "redundant_vehicles": self.redundant_vehicles}
        if self.sigmas_noise is not None:
            out["sigmas"] = {"sigma_px": self.sigmas_noise[0], "spread_scale": self.sigmas_noise[1],
                             "vehicles": self.clean_vehicles}
        return out

    def describe(self) -> str:
        """One line for the command's summary."""
        if self.source == "given":
            return f"click noise: {self.sigma_px:g} px (given)"
        if self.source == "estimated":
            bounded = ""
            if self.sigma_px <= SIGMA_BOUNDS[0]:
                bounded = (" (its lower bound: the keypoints' learned spread explains every residual; were the "
                           "positions learned on these very clicks?)")
            elif self.sigma_px >= SIGMA_BOUNDS[1]:
                bounded = " (its upper bound: are the clicks on their parts?)"
            sigmas = "" if self.sigmas_noise is None else (
                f"; the sigmas take {self.sigmas_noise[0]:.2f} px on top of {self.sigmas_noise[1]:.2f} x each "
                f"learned spread, the likeliest for the {self.clean_vehicles} of them without a click the robust "
                f"loss would down-weight")
            given = "--click-sigma sets it" if self.sigmas_noise is None else "--click-sigma sets both"
            return (f"click noise: {self.sigma_px:.2f} px on top of each keypoint's learned spread{bounded}, "
                    f"estimated from the residuals of {self.redundant_vehicles} vehicles with redundant clicks "
                    f"({self.dof:.0f} degrees of freedom; pilot fit of {self.pilot_vehicles}){sigmas}; {given}")
        if not self.redundant_vehicles:
            return (f"click noise: {self.sigma_px:g} px (default: no vehicle has redundant clicks that are all "
                    f"keypoints or plates, the clicks whose residuals tell the noise); --click-sigma sets it")
        return (f"click noise: {self.sigma_px:g} px (default: the batch's {self.dof:.0f} redundant degrees of freedom "
                f"are too few to estimate it, {MIN_DOF} needed); --click-sigma sets it")


def pilot_stride(n_vehicles: int) -> int:
    """Every how many vehicles the pilot takes one, for a batch of ``n_vehicles``."""
    return max(1, math.ceil(n_vehicles / PILOT_VEHICLES))


def telling(vehicle: Vehicle) -> bool:
    """Whether a vehicle's residuals can tell the click noise: every part has a learned spread (keypoints,
    plates; the module's docstring says why parts on the cuboid cannot)."""
    return bool(vehicle.parts) and all(KINDS[part.kind].soft for part in vehicle.parts)


def pilot_images(images: Iterable[Image], n_clicked: int,
                 keep: Callable[[Vehicle], bool] | None = telling,
                 clicked_before: Iterable[int] | None = None) -> Iterator[Image]:
    """The images of a batch with ``n_clicked`` vehicles that carry clicks, with only the pilot's vehicles: every k-th
    vehicle with clicks (counted in file order) that ``keep`` keeps (default: those whose residuals can tell the
    noise, :func:`telling`, so that a batch of parts on the cuboid has no pilot; None: every k-th, as the road
    normal's estimate wants); images left without one are skipped. Vehicles without clicks (a track's frames with
    only a box, or none) are not counted: the pilot cannot fit them alone, and counting them would leave it few
    vehicles, or none of one camera, when a track is clicked on one frame in k.

    ``clicked_before``: for each of ``images``, how many vehicles with clicks the file has before it, when
    ``images`` are only some of the file's (those :func:`pilot_positions` names); None: they are all of them."""
    k = pilot_stride(n_clicked)
    seen = 0
    before = iter(clicked_before) if clicked_before is not None else None
    for im in images:
        if before is not None:
            seen = next(before)
        clicked = [v for v in im.vehicles if v.parts]
        chosen = tuple(v for i, v in enumerate(clicked, start=seen) if i % k == 0 and (keep is None or keep(v)))
        seen += len(clicked)
        if chosen:
            yield replace(im, vehicles=chosen)


def pilot_positions(image_clicked: Sequence[int], n_clicked: int) -> list[tuple[int, int]]:
    """Which images hold a vehicle the pilot may take (:func:`pilot_images`), from how many vehicles with clicks each
    image has (``image_clicked``, in file order): each such image's place in the file and how many vehicles with
    clicks come before it. A batch reads only these images for its pilot."""
    k = pilot_stride(n_clicked)
    out, seen = [], 0
    for i, n in enumerate(image_clicked):
        if -seen % k < n:  # the first multiple of k from ``seen`` on falls among this image's vehicles
            out.append((i, seen))
        seen += n
    return out


@dataclass(frozen=True)
class Redundancy:
    """One fitted vehicle's evidence: ``squared`` (N,) ``|r_i|^2`` px^2, ``model_px2`` (N,) ``s_i^2`` px^2,
    and its residuals' degrees of freedom ``dof`` (effective, :func:`toosicubix.solver.uncertainty.residual_dof`)."""

    squared: np.ndarray
    model_px2: np.ndarray
    dof: float


def redundancy(result: VehicleResult, pilot_sigma: float) -> Redundancy | None:
    """A fitted vehicle's :class:`Redundancy`, or None when it failed, its clicks are not redundant, or any of
    them is a part on the cuboid (see the module's docstring).

    ``pilot_sigma``: the click noise its fit assumed, which its soft weights hold.
    """
    if not result.ok or result.residuals_px is None or result.click_weights is None:
        return None
    w = np.asarray(result.click_weights, dtype=float)
    if len(w) == 0 or np.any(w >= 1.0) or np.any(w <= 0.0):
        return None  # a part on the cuboid (weight 1), or a click the robust loss took out
    if result.solver is not None and result.solver.residual_dof is not None:
        dof = float(result.solver.residual_dof)
    else:  # results of earlier versions: the clicks alone fix the pose and the shape up to scale
        dof = float(2 * int(result.clicks or 0) - (5 + 3 + int(result.aux_unknowns or 0)))
    if dof < MIN_VEHICLE_DOF:
        return None
    r = np.asarray(result.residuals_px, dtype=float)  # (N, 2)
    return Redundancy(np.sum(r**2, axis=1), pilot_sigma**2 * (1.0 / w**2 - 1.0), dof)


def pooled_sigma(evidence: Iterable[Redundancy]) -> tuple[float | None, float, int]:
    """Solve the moment equation of the module's docstring: (sigma or None, degrees of freedom, vehicles).

    Each click's two coordinates share ``s_i``; the equation's left side falls as sigma grows, so its root
    is unique. None when nothing is redundant; the bound of :data:`SIGMA_BOUNDS` the root lies beyond when the
    residuals are smaller (or larger) than the model explains at that bound.
    """
    items = list(evidence)
    dof = sum(e.dof for e in items)
    if not dof:
        return None, 0, 0
    squared = np.concatenate([e.squared for e in items])
    model = np.concatenate([e.model_px2 for e in items])

    def excess(log_sigma: float) -> float:
        return float(np.sum(squared / (np.exp(2 * log_sigma) + model))) - dof

    lo, hi = np.log(SIGMA_BOUNDS[0]), np.log(SIGMA_BOUNDS[1])
    if excess(lo) <= 0:
        return SIGMA_BOUNDS[0], dof, len(items)
    if excess(hi) >= 0:
        return SIGMA_BOUNDS[1], dof, len(items)
    while hi - lo > 1e-10:  # bisection on log sigma (scipy.optimize would add 20 MB to every fit's process)
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if excess(mid) > 0 else (lo, mid)
    return float(np.exp(0.5 * (lo + hi))), dof, len(items)


def two_scale_ml(squared: np.ndarray, model2: np.ndarray, twice_share: np.ndarray,
                 theta_bounds: tuple[float, float]) -> tuple[float, float]:
    """The ``(sigma, theta)`` of greatest likelihood for squared residuals ``squared`` (N,) px^2 whose expectations
    are ``twice_share (sigma^2 + theta^2 model2)``, each a scaled chi-square with two degrees of freedom: the minimum
    of ``sum_i ln v_i + squared_i / (twice_share_i v_i)``, ``v_i = sigma^2 + theta^2 model2_i``. ``sigma`` is kept in
    :data:`SIGMA_BOUNDS`, ``theta`` in ``theta_bounds``. For each ``theta`` the likelihood equation in ``sigma^2``
    has one root (bisection); ``theta`` is found by a golden-section search of that profile over its logarithm.
    Rule 33 (``model2`` a part's pixels per metre of offset, squared) and rules 34 and 35 (a keypoint's learned spread,
    pixels, squared) use it."""

    def nll(log_s2: float, log_p2: float) -> float:
        v = math.exp(log_s2) + model2 * math.exp(log_p2)
        return float(np.sum(np.log(v) + squared / (twice_share * v)))

    def best_sigma(log_p2: float) -> float:
        """The log sigma^2 where the likelihood's derivative over sigma^2 vanishes, for this theta."""
        p2 = math.exp(log_p2)

        def slope(log_s2: float) -> float:
            v = math.exp(log_s2) + model2 * p2
            return float(np.sum((1.0 - squared / (twice_share * v)) / v))

        lo, hi = 2 * math.log(SIGMA_BOUNDS[0]), 2 * math.log(SIGMA_BOUNDS[1])
        if slope(lo) >= 0:
            return lo
        if slope(hi) <= 0:
            return hi
        while hi - lo > 1e-9:
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if slope(mid) < 0 else (lo, mid)
        return 0.5 * (lo + hi)

    def profile(log_p2: float) -> float:
        return nll(best_sigma(log_p2), log_p2)

    a, b = 2 * math.log(theta_bounds[0]), 2 * math.log(theta_bounds[1])
    golden = (math.sqrt(5.0) - 1.0) / 2.0
    c, d = b - golden * (b - a), a + golden * (b - a)
    fc, fd = profile(c), profile(d)
    while b - a > 1e-6:
        if fc <= fd:
            b, d, fd = d, c, fc
            c = b - golden * (b - a)
            fc = profile(c)
        else:
            a, c, fc = c, d, fd
            d = a + golden * (b - a)
            fd = profile(d)
    log_p2 = 0.5 * (a + b)
    return math.exp(0.5 * best_sigma(log_p2)), math.exp(0.5 * log_p2)


def clean(evidence: list[Redundancy], sigma: float) -> list[Redundancy]:
    """The vehicles none of whose clicks the batch's robust loss would down-weight at click noise ``sigma``: each
    click's standardized residual ``|r_i|^2 / (sigma^2 + s_i^2)`` at most :data:`DOWNWEIGHTED_E2`."""
    return [e for e in evidence if np.all(e.squared <= DOWNWEIGHTED_E2 * (sigma**2 + e.model_px2))]


def sigmas_noise(evidence: list[Redundancy]) -> tuple[float, float] | None:
    """The click noise and the scale on the learned spreads the sigmas take (the module's docstring, rules 34 and
    35), from vehicles ``evidence`` (:func:`clean`'s), or None when they have fewer than :data:`MIN_DOF` degrees of
    freedom."""
    if sum(e.dof for e in evidence) < MIN_DOF:
        return None
    squared = np.concatenate([e.squared for e in evidence])
    model2 = np.concatenate([e.model_px2 for e in evidence])
    twice_share = np.concatenate([np.full(len(e.squared), e.dof / len(e.squared)) for e in evidence])
    return two_scale_ml(squared, model2, twice_share, SPREAD_SCALE_BOUNDS)


def estimate_from_pilot(results: Iterable[ImageResult], pilot_sigma: float) -> ClickNoise:
    """The :class:`ClickNoise` of a pilot fit's image results, fitted with click noise ``pilot_sigma``."""
    evidence, pilot = [], 0
    for im in results:
        for v in im.vehicles:
            pilot += 1
            e = redundancy(v, pilot_sigma)
            if e is not None:
                evidence.append(e)
    estimate, dof, redundant = pooled_sigma(evidence)
    if estimate is None or dof < MIN_DOF:
        return ClickNoise(pilot_sigma, "default", estimate, dof, pilot, redundant)
    kept = clean(evidence, estimate)
    return ClickNoise(estimate, "estimated", estimate, dof, pilot, redundant,  # pooled_sigma keeps it in bounds
                      sigmas_noise(kept), len(kept))
