"""Where a batch's traffic heads: a prior on a vehicle's heading on the road, from the batch's own well-determined
fits (issue 36; ``fit --heading-prior estimate``).

A camera on a car looks down a road, and most vehicles it sees drive along that road, one way or the other. A
vehicle whose clicks leave its heading loose (a car seen end-on, clicked on its rear only: a yaw sigma of 10 to 15
degrees) is otherwise placed anywhere along the valley its clicks leave; the batch's other vehicles say where such a
vehicle most likely heads.

Heading ``theta`` (radians): the angle, in the road plane (normal ``n``, pointing up), from the camera's forward axis
projected on that plane (``f0``) to the vehicle's forward axis ``R e_x``, positive toward ``l0 = n x f0``. The prior
is axial (a heading and its reverse alike: which end is the front, the clicks say) and robust: a wrapped normal of
spread ``sigma`` about the traffic's direction ``mu`` for a share ``1 - others`` of the vehicles, any heading for the
rest (crossing traffic, parked cars). Its cost on a vehicle, with ``d = theta - mu`` taken to the nearest of ``mu``
and ``mu + pi``:

    c(d) = -2 ln((1 - others) exp(-d^2 / (2 sigma^2)) + others)

zero on the traffic's axis, ``(1 - others) d^2 / sigma^2`` near it, and ``-2 ln(others)`` at most: a vehicle that
heads elsewhere pays a bounded cost, which its clicks overrule once they fix its heading. The fit's row is
``sign(d) sqrt(c(d))`` (smooth through ``d = 0``) times the pixel noise it is weighed against, the batch's click noise
(:attr:`toosicubix.model.HeadingPrior.noise_px`): the prior it states, against clicks weighed to that noise.

The batch estimates ``(mu, sigma, others)`` by expectation-maximization from the headings of the pilot's vehicles
whose yaw sigma is at most :data:`WELL_DETERMINED_YAW_DEG` (:func:`estimate`).
"""

from __future__ import annotations

import math

import numpy as np

from toosicubix.model import HeadingPrior

#: Pilot vehicles whose yaw sigma is at most this many degrees tell the traffic's heading.
WELL_DETERMINED_YAW_DEG = 3.0
#: Fewer well-determined pilot vehicles of a camera than this: no heading prior for it (as for its road normal).
MIN_VEHICLES = 30
#: The spread's floor, radians (a batch of identical headings would otherwise give a spike).
MIN_SIGMA = math.radians(0.5)
#: Bounds of the share of vehicles heading elsewhere.
OTHERS_BOUNDS = (1e-3, 0.99)
#: Expectation-maximization rounds of :func:`estimate`.
EM_ROUNDS = 200


def road_axes(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``f0`` (3,), the camera's forward axis projected on the road plane of normal ``up`` (3,), and ``l0 = up x f0``
    (3,): unit vectors, camera frame."""
    n = np.asarray(up, dtype=float) / np.linalg.norm(up)
    f0 = np.array([0.0, 0.0, 1.0]) - n[2] * n
    f0 /= np.linalg.norm(f0)
    return f0, np.cross(n, f0)


def headings(R_cam_vehicle: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Headings (radians) of rotations ``R_cam_vehicle`` (..., 3, 3) on the road of normal ``up`` (3,): (...)."""
    f0, l0 = road_axes(up)
    forward = R_cam_vehicle[..., :, 0]
    return np.arctan2(forward @ l0, forward @ f0)


def axial(d: np.ndarray) -> np.ndarray:
    """Angles (radians) taken to (-pi/2, pi/2]: a heading and its reverse alike."""
    return d - np.pi * np.round(d / np.pi)


def gradient(R_cam_vehicle: np.ndarray, up: np.ndarray) -> np.ndarray:
    """d(heading)/d(delta) (B, 3) of rotations ``R_cam_vehicle`` (B, 3, 3) on the road of normal ``up``, for the
    increment ``R exp([delta]x)``: ``R e_x`` moves by ``delta_z R e_y - delta_y R e_z``."""
    f0, l0 = road_axes(up)
    forward = R_cam_vehicle[:, :, 0]
    a, b = forward @ l0, forward @ f0
    out = np.zeros((len(R_cam_vehicle), 3))
    for k, direction in ((1, -R_cam_vehicle[:, :, 2]), (2, R_cam_vehicle[:, :, 1])):
        out[:, k] = (b * (direction @ l0) - a * (direction @ f0)) / (a * a + b * b)
    return out


def _terms(prior: HeadingPrior, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``exp(-d^2 / (2 sigma^2))``, ``q = (1 - others) e + others`` and ``c = -2 ln q`` of axial deviations ``d``."""
    e = np.exp(-0.5 * (d / prior.sigma) ** 2)
    q = (1.0 - prior.others) * e + prior.others
    return e, q, np.maximum(-2.0 * np.log(q), 0.0)


def rows(prior: HeadingPrior, R_cam_vehicle: np.ndarray, up: np.ndarray, with_jacobian: bool
         ) -> tuple[np.ndarray, np.ndarray | None]:
    """The heading prior's standardized row of B poses, ``sign(d) sqrt(c(d))`` (B,), and its Jacobian (B, 3) on the
    rotation increment ``delta`` of ``R exp([delta]x)`` (None without ``with_jacobian``); ``R_cam_vehicle``
    (B, 3, 3)."""
    d = axial(headings(R_cam_vehicle, up) - prior.direction)
    e, q, c = _terms(prior, d)
    r = np.sign(d) * np.sqrt(c)
    if not with_jacobian:
        return r, None
    # dr/dd = c'(d) / (2 sqrt(c)) on both sides of the axis, which tends to sqrt(1 - others) / sigma as d -> 0.
    keep = 1.0 - prior.others
    small = np.abs(d) < 1e-8
    dr_dd = np.where(small, math.sqrt(keep) / prior.sigma,
                     keep * e * np.abs(d) / (prior.sigma**2 * q * np.sqrt(np.where(small, 1.0, c))))
    return r, dr_dd[:, None] * gradient(R_cam_vehicle, up)


def mixture_variance(prior: HeadingPrior, deviation: float, variance_with: float, variance_without: float
                     ) -> tuple[float, float, float]:
    """How sure a fit's heading is under the prior's mixture rather than at its peak alone (the Laplace
    approximation at the fit, ``variance_with``, is the peak's, and a vehicle that heads elsewhere is then reported
    far too sure). ``deviation`` (radians): the fit's heading from the traffic's axis; ``variance_without``: the
    heading's variance from the clicks and the other cues alone.

    The clicks alone put the heading at ``d0``, where the fit's stationarity puts it: ``d0 = d + v0 c'(d) / 2``.
    Given the clicks, the vehicle heads along the traffic with the probability ``rho`` of the peak against the
    uniform share, ``(1 - others) N(d0; 0, sigma^2 + v0)`` against ``others / pi``; the peak's posterior sits at
    ``d0 sigma^2 / (sigma^2 + v0)``, the uniform's at ``d0``. Returns ``(rho, shift, variance)``: the shift between the
    two posteriors' headings (radians) and the mixture's variance, ``rho variance_with + (1 - rho) v0 + rho (1 - rho)
    shift^2``."""
    v0 = max(float(variance_without), 0.0)
    if not math.isfinite(v0):
        return 1.0, 0.0, float(variance_with)
    d = float(deviation)
    e, q, _ = _terms(prior, np.array([d]))
    d0 = d + v0 * (1.0 - prior.others) * float(e[0]) * d / (prior.sigma**2 * float(q[0]))
    spread = prior.sigma**2 + v0
    peak = (1.0 - prior.others) * math.exp(-0.5 * d0 * d0 / spread) / math.sqrt(2.0 * math.pi * spread)
    rho = peak / (peak + prior.others / math.pi)
    shift = d0 * v0 / spread
    return rho, shift, rho * float(variance_with) + (1.0 - rho) * v0 + rho * (1.0 - rho) * shift * shift


def cost(prior: HeadingPrior, R_cam_vehicle: np.ndarray, up: np.ndarray) -> float:
    """``c(d)`` of one rotation (3, 3): the row's square."""
    r, _ = rows(prior, R_cam_vehicle[None], up, False)
    return float(r[0] ** 2)


def estimate(theta: np.ndarray, noise_px: float) -> HeadingPrior:
    """``(mu, sigma, others)`` of the headings ``theta`` (radians, (n,)) by expectation-maximization of the axial
    mixture (a wrapped normal about ``mu`` on (-pi/2, pi/2], plus a uniform share), from the axial mean, 5 degrees
    and a fifth; its row weighed against ``noise_px``."""
    theta = np.asarray(theta, dtype=float)
    mu = 0.5 * math.atan2(float(np.mean(np.sin(2.0 * theta))), float(np.mean(np.cos(2.0 * theta))))
    sigma, others = math.radians(5.0), 0.2
    for _ in range(EM_ROUNDS):
        d = axial(theta - mu)
        peak = (1.0 - others) * np.exp(-0.5 * (d / sigma) ** 2) / (math.sqrt(2.0 * math.pi) * sigma)
        responsibility = peak / (peak + others / math.pi)
        weight = float(np.sum(responsibility))
        if weight <= 0.0:
            break
        mu = float(axial(np.array(mu + float(np.sum(responsibility * d)) / weight)))
        d = axial(theta - mu)
        sigma = max(MIN_SIGMA, math.sqrt(float(np.sum(responsibility * d * d)) / weight))
        others = min(OTHERS_BOUNDS[1], max(OTHERS_BOUNDS[0], 1.0 - weight / len(theta)))
    return HeadingPrior(mu, sigma, others, noise_px, len(theta))
