"""How far a batch's parts sit from the cuboid model, and its click noise, estimated from its own residuals (what
``toosicubix fit`` does for a batch of cuboid parts unless given ``--click-sigma`` or ``--part-sigma``;
benchmarks/decisions.md, rule 33).

A part on the cuboid model (a tyre's contact point, a light pair, an edge) sits, on a real vehicle, some way off where
the model puts it, and its click carries the click noise on top. Seen from depth ``z`` with focal length ``f``, an
offset of ``part_sigma`` metres is ``f part_sigma / z`` pixels, while the click noise ``sigma`` is the same at every
depth; so a batch with vehicles near and far tells the two apart. Each click ``i`` of a fitted vehicle ``v`` has a
residual ``r_i`` (2,) whose expected square is ``2 c_v (sigma^2 + b_i (f part_sigma / z_v)^2)``, with ``b_i`` 1 for a
part on the body (0 for an arrow drawn on the ground) and ``c_v`` the share of the vehicle's ``2 N_v`` pixel rows its
fit leaves as residual degrees of freedom (``dof_v / 2 N_v``, :func:`toosicubix.solver.uncertainty.residual_dof`). The
estimate maximizes the likelihood of the squared residuals under that model, a scaled chi-square with two degrees of
freedom each: it minimizes ``sum_i ln v_i + |r_i|^2 / (2 c_v v_i)``, ``v_i = sigma^2 + b_i (f part_sigma / z_v)^2``.

The residuals show less of a part's offset than the pose feels: an offset that is the same in every view of a part
is partly absorbed by the fit. The sigmas use ``KAPPA`` times the estimate, ``KAPPA`` chosen on the tuning sequences
(rule 33) so that the simulated person's realistic placement gets the calibration ``part_sigma`` was chosen for.

Only vehicles whose clicks are all cuboid parts or arrows enter (keypoints and plates tell the click noise on top of
their learned spread: :mod:`toosicubix.pipeline.click_noise`). Fewer than ``MIN_DOF`` degrees of freedom give no
estimate, and the batch keeps its settings.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from toosicubix import vocabulary
from toosicubix.camera import Camera
from toosicubix.formats.results import ImageResult
from toosicubix.pipeline.click_noise import MIN_DOF, MIN_VEHICLE_DOF, SIGMA_BOUNDS, two_scale_ml

#: The batch's sigmas use this many times the residuals' estimate of how far parts sit from the model (rule 33).
KAPPA = 1.0
#: The estimate of ``part_sigma`` is kept within these bounds (metres): 0.1 mm is a part exactly on the model, half a
#: metre no part of a vehicle.
PART_SIGMA_BOUNDS = (1e-4, 0.5)


@dataclass(frozen=True)
class PartPlacement:
    """What a batch's residuals say about its clicks (:func:`estimate_placement`).

    Attributes
    ----------
    sigma_px : the click noise, pixels per coordinate
    part_sigma_m : how far the batch's parts sit from the cuboid model as its sigmas take it (``KAPPA`` times the
        residuals' estimate), metres
    residual_part_sigma_m : the residuals' own estimate, metres
    dof : the residuals' degrees of freedom the estimate rests on; vehicles : how many vehicles gave them
    """

    sigma_px: float
    part_sigma_m: float
    residual_part_sigma_m: float
    dof: float
    vehicles: int

    def to_json(self) -> dict:
        return {"sigma_px": self.sigma_px, "part_sigma_m": self.part_sigma_m,
                "residual_part_sigma_m": self.residual_part_sigma_m, "kappa": KAPPA, "dof": self.dof,
                "vehicles": self.vehicles}

    def describe(self) -> str:
        """One line for the command's summary."""
        bounded = (" (the click noise at its lower bound: the parts' offsets explain every residual)"
                   if self.sigma_px <= SIGMA_BOUNDS[0] * (1 + 1e-9) else "")
        return (f"click noise and part placement: {self.sigma_px:.2f} px, parts {100 * self.part_sigma_m:.1f} cm off "
                f"the cuboid model{bounded} (estimated from the residuals of {self.vehicles} pilot vehicles' cuboid "
                f"parts, {self.dof:.0f} degrees of freedom; --click-sigma and --part-sigma set them)")


@dataclass(frozen=True)
class Evidence:
    """One fitted vehicle's clicks for :func:`estimate_placement`: ``squared`` (N,) ``|r_i|^2`` (px^2), ``offset_px``
    (N,) ``f / z_v`` for a part on the body and 0 for one on the ground (pixels per metre of offset), and ``share``
    ``c_v``, its residual degrees of freedom over its ``2 N`` pixel rows."""

    squared: np.ndarray
    offset_px: np.ndarray
    share: float


def evidence(cameras: Iterable[Camera], results: Iterable[ImageResult]) -> list[Evidence]:
    """Each fitted vehicle's residuals with what the model expects of them, from image results and their images'
    cameras (one each); vehicles with keypoints or plates, with too few redundant clicks, or not fitted are left
    out."""
    out = []
    for camera, result in zip(cameras, results, strict=True):
        focal = 0.5 * float(camera.K[0, 0] + camera.K[1, 1])
        for v in result.vehicles:
            if not v.ok or v.residuals_px is None or v.solver is None or v.solver.residual_dof is None:
                continue
            labels = v.click_labels or ()
            if not labels or any(vocabulary.soft(label) for label in labels):
                continue
            dof = float(v.solver.residual_dof)
            r = np.asarray(v.residuals_px, dtype=float)
            if dof < MIN_VEHICLE_DOF or len(r) != len(labels):
                continue
            depth = max(float(np.asarray(v.t_cam_vehicle, dtype=float)[2]), 0.5)
            on_body = np.array([vocabulary.on_body(label) for label in labels], dtype=float)
            out.append(Evidence(np.sum(r**2, axis=1), on_body * focal / depth, dof / (2 * len(r))))
    return out


def evidence_dof(items: list[Evidence]) -> float:
    """The residual degrees of freedom the vehicles ``items`` give an estimate."""
    return sum(2 * e.share * len(e.squared) for e in items)


def too_few(dof: float, part_sigma_m: float, sigma_px: float) -> str:
    """The summary line of a batch of cuboid parts whose residuals are too few to estimate the click noise and the
    parts' placement: the settings it keeps."""
    return (f"click noise and part placement: {sigma_px:g} px, parts {100 * part_sigma_m:g} cm off the cuboid model "
            f"(defaults: the pilot's cuboid parts give {dof:.0f} degrees of freedom, {MIN_DOF} needed to estimate "
            f"them); --click-sigma and --part-sigma set them")


def estimate_placement(items: list[Evidence]) -> PartPlacement | None:
    """The maximum-likelihood click noise and part offset of the module's docstring
    (:func:`~toosicubix.pipeline.click_noise.two_scale_ml`), or None with fewer than ``MIN_DOF`` degrees of
    freedom."""
    dof = evidence_dof(items)
    if dof < MIN_DOF:
        return None
    squared = np.concatenate([e.squared for e in items])
    offset2 = np.concatenate([e.offset_px for e in items]) ** 2
    twice_share = 2.0 * np.concatenate([np.full(len(e.squared), e.share) for e in items])
    sigma, part = two_scale_ml(squared, offset2, twice_share, PART_SIGMA_BOUNDS)
    return PartPlacement(sigma, KAPPA * part, part, dof, len(items))
