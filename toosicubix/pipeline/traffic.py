"""Where each camera's traffic heads, estimated from a batch's pilot fits (``fit --heading-prior estimate``, issue 36).

On each camera's estimated road (:mod:`toosicubix.pipeline.road_normal`), the headings of the pilot's vehicles whose
yaw sigma is at most :data:`toosicubix.solver.heading.WELL_DETERMINED_YAW_DEG` give the traffic's axis, its spread and
the share of vehicles heading elsewhere (:func:`toosicubix.solver.heading.estimate`); with at least
:data:`toosicubix.solver.heading.MIN_VEHICLES` of them, that camera's images on its estimated road carry the prior
(:attr:`toosicubix.model.GroundPlane.heading`), weighed against the batch's click noise. A camera whose road normal
was not estimated, or whose images have ground blocks of their own, gets none.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from toosicubix.formats.results import ImageResult
from toosicubix.model import HeadingPrior, Image
from toosicubix.pipeline.road_normal import CameraKey, RoadNormal, camera_key
from toosicubix.solver import heading as traffic


@dataclass(frozen=True)
class TrafficHeading:
    """One camera's traffic heading as the batch estimated it, or why it did not.

    Attributes
    ----------
    camera : ``(fx, fy, cx, cy)`` of the camera, pixels
    prior : the estimate, or None
    vehicles : the well-determined pilot vehicles of the camera
    reason : why there is no estimate, or None
    """

    camera: tuple[float, float, float, float]
    prior: HeadingPrior | None
    vehicles: int
    reason: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {"camera": dict(zip(("fx", "fy", "cx", "cy"), self.camera, strict=True)),
                **(self.prior.to_json() if self.prior is not None else {"vehicles": self.vehicles}),
                "reason": self.reason}

    def describe(self) -> str:
        """One line for the command's summary."""
        where = f"camera fx {self.camera[0]:.0f} px"
        if self.prior is None:
            return f"heading prior of {where}: none, {self.reason}"
        return f"heading prior of {where}: {self.prior.describe()} (--heading-prior none turns it off)"


def estimate_traffic(pilot: Iterable[Image], results: Iterable[ImageResult], normals: dict[CameraKey, RoadNormal],
                     noise_px: float) -> dict[CameraKey, TrafficHeading]:
    """Each camera of ``normals``: its :class:`TrafficHeading` from the pilot's images without a ground block of their
    own and their fits (same order), the prior weighed against ``noise_px``; none where the normal was not
    estimated."""
    found: dict[CameraKey, list[float]] = {key: [] for key, n in normals.items() if n.normal is not None}
    for im, res in zip(pilot, results, strict=True):
        key = camera_key(im.camera)
        if im.ground is not None or key not in found:
            continue
        up = np.asarray(normals[key].normal, dtype=float)
        for v in res.vehicles:
            sigma = None if v.sigma is None else v.sigma.yaw_deg
            if v.ok and sigma is not None and math.isfinite(sigma) and sigma <= traffic.WELL_DETERMINED_YAW_DEG:
                found[key].append(float(traffic.headings(np.asarray(v.R_cam_vehicle, dtype=float), up)))
    out = {key: TrafficHeading(n.camera, None, 0, "its road normal was not estimated")
           for key, n in normals.items() if n.normal is None}
    for key, theta in found.items():
        camera = normals[key].camera
        if len(theta) < traffic.MIN_VEHICLES:
            out[key] = TrafficHeading(camera, None, len(theta),
                                      f"the pilot fitted {len(theta)} of its vehicles within "
                                      f"{traffic.WELL_DETERMINED_YAW_DEG:g} deg of yaw, {traffic.MIN_VEHICLES} needed")
        else:
            out[key] = TrafficHeading(camera, traffic.estimate(np.array(theta), noise_px), len(theta))
    return out


def priors_of(headings: dict[CameraKey, TrafficHeading] | None) -> dict[CameraKey, HeadingPrior]:
    """Per camera, the prior its images on the estimated road carry; cameras without one left out."""
    return {key: h.prior for key, h in (headings or {}).items() if h.prior is not None}
