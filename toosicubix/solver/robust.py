"""Per-click weights of the pixel cost: the soft term of keypoints and a robust (Cauchy) loss.

Both enter as a weight ``w_i`` on click ``i``'s two pixel rows (``Problem.click_weights``); the refinement
(:mod:`.refine`) stays a least-squares solver, and the robust loss is iteratively reweighted least squares.

- **Soft term.** A keypoint sits at typical fractions ``at`` of the dimensions, a real vehicle puts it within
  ``spread`` of there. Seen from depth ``z`` with focal length ``f``, that spread is ``f s / z`` pixels on
  top of the click noise ``sigma_c``, so ``w_i = sigma_c / sqrt(sigma_c^2 + (f s_i / z)^2)`` with ``s_i`` the
  spread in metres (RMS over the three axes of ``spread * d``, ``d`` the prior's mean dimensions).
- **Robust loss.** Cauchy on each click's standardized residual ``e_i = w_i |r_i| / sigma_c`` (2D, pixels):
  ``rho(s) = c^2 log(1 + s / c^2)`` of ``s = e^2``, so the reweighting factor is
  ``sqrt(rho'(s)) = 1 / sqrt(1 + e^2 / c^2)``. A click mislabelled left for right, tens of pixels off, weighs
  little; one within the noise keeps nearly its full weight.
"""

from __future__ import annotations

import numpy as np

from toosicubix.solver.lm import Loss
from toosicubix.solver.problem import Problem

#: Cauchy scale in click-noise units: a click this many sigmas off keeps 1/sqrt(2) of its weight.
CAUCHY_SCALE = 3.0
#: A click whose robust factor falls below this is reported as down-weighted.
DOWNWEIGHTED_BELOW = 0.5


class CauchyLoss(Loss):
    """``rho(s) = c^2 log(1 + s / c^2)`` on squared standardized residuals ``s``, and ``rho'(s)``.

    A :class:`.lm.Loss`, but applied per click (the 2D residual's norm) in outer reweighting rounds
    (:func:`robust_factors`), not per residual row inside the loop: a click's two rows share one weight.
    """

    def __init__(self, scale: float = CAUCHY_SCALE):
        self.scale = scale

    def loss(self, s: np.ndarray) -> np.ndarray:
        c2 = self.scale**2
        return c2 * np.log1p(np.asarray(s, dtype=float) / c2)

    def weight(self, s: np.ndarray) -> np.ndarray:
        return 1.0 / (1.0 + np.asarray(s, dtype=float) / self.scale**2)


def spread_px(problem: Problem, depth: float) -> np.ndarray | None:
    """Each click's learned spread (N,) in pixels seen from ``depth`` metres (0 for cuboid parts), or None when no
    click has one."""
    spread = problem.parts.click_spread
    if spread is None:
        return None
    metres = np.sqrt(np.mean((spread * problem.prior.mean) ** 2, axis=1))  # (N,), 0 for cuboid parts
    focal = float(np.sqrt(abs(problem.K[0, 0] * problem.K[1, 1])))
    return focal * metres / max(depth, 1e-3)


def soft_weights(problem: Problem, depth: float, click_sigma: float) -> np.ndarray | None:
    """The soft-term weights (N,) of a problem's clicks for a vehicle ``depth`` metres away, or None when no
    click has a spread (only cuboid parts: their weights stay 1)."""
    pixels = spread_px(problem, depth)
    if pixels is None:
        return None
    return click_sigma / np.sqrt(click_sigma**2 + pixels**2)


def robust_factors(residuals_px: np.ndarray, weights: np.ndarray | None, click_sigma: float,
                   loss: CauchyLoss) -> np.ndarray:
    """IRLS factors (N,) ``sqrt(rho'(e_i^2))`` for residuals (N, 2) pixels, under soft ``weights`` (N,) or None."""
    e = np.linalg.norm(residuals_px, axis=1) / click_sigma
    if weights is not None:
        e = e * weights
    return np.sqrt(loss.weight(e**2))


def with_weights(problem: Problem, weights: np.ndarray | None) -> Problem:
    """The problem with its pixel rows weighted by ``weights`` (N,) (None: unweighted):
    :meth:`.problem.Problem.with_click_weights`."""
    return problem.with_click_weights(weights)
