"""One vehicle's fitting problem and its two costs (paper, "Solving the equations" and "Pixel-domain
fine-tuning").

With ``X_i = A_i p`` and ``Y_i = R_cam_vehicle X_i + t_cam_vehicle``:

- 3D cost (coordinate descent): ``sum |M_i Y_i|^2 + lambda_3d |W (d - mu)|^2`` with
  ``M_i = [[1, 0, -x_i], [0, 1, -y_i]]`` in normalized coordinates: the SQPnP cost, a depth-weighted
  error that shrinks with the vehicle's scale.
- Pixel cost (refinement, and the comparison of starts): ``sum |K_:2 pi(Y_i) - x_i|^2 +
  lambda_px |W (d - mu)|^2``. Its data term does not change with scale, so the prior sets the scale.

``W`` is the upper Cholesky factor of the prior's inverse covariance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from ..parts import PartsModel
from ..priors import SizePrior


@dataclass(frozen=True)
class Problem:
    """Everything the solver stages need, as arrays.

    Attributes
    ----------
    parts : the linear model ``X_i = A_i p``; ``A`` (N, 3, P)
    u : (N, 3) normalized, undistorted clicks ``K^-1 (x, y, 1)``
    uv : (N, 2) the clicks as an ideal pinhole ``K`` sees them (undistorted pixels)
    K : (3, 3)
    prior : size prior of the vehicle's prototype
    lambda_3d, lambda_px : prior weights of the 3D and the pixel cost
    """

    parts: PartsModel
    u: np.ndarray
    uv: np.ndarray
    K: np.ndarray
    prior: SizePrior
    lambda_3d: float
    lambda_px: float
    A_rows: np.ndarray  # (3N, P): A stacked, so that the points of a batch of p are one matrix product
    A_mean: np.ndarray  # (3, P): the centroid of the clicked points is A_mean @ p

    @classmethod
    def build(cls, parts: PartsModel, camera: Camera, prior: SizePrior, lambda_3d: float,
              lambda_px: float) -> Problem:
        u = camera.normalize(parts.uv)
        uv = u[:, :2] @ camera.K[:2, :2].T + camera.K[:2, 2]
        A = parts.A
        return cls(parts, u, uv, camera.K, prior, lambda_3d, lambda_px, A.reshape(-1, A.shape[2]), A.mean(axis=0))

    @property
    def A(self) -> np.ndarray:
        return self.parts.A

    def points_vehicle_batch(self, p: np.ndarray) -> np.ndarray:
        """The clicked points for each ``p`` of a batch (B, P): (B, N, 3), vehicle frame."""
        return (p @ self.A_rows.T).reshape(len(p), -1, 3)

    def points_cam(self, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray) -> np.ndarray:
        """``Y_i = R X_i + t`` for every click: (N, 3)."""
        return (self.A @ p) @ R_cam_vehicle.T + t_cam_vehicle

    def prior_residual(self, p: np.ndarray) -> np.ndarray:
        """``W (d - mu)``: (3,), unweighted by lambda."""
        return self.prior.sqrt_information @ (p[:3] - self.prior.mean)

    def cost_3d(self, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray) -> float:
        """The coordinate-descent (SQPnP) cost with the prior, metres^2 plus lambda_3d times Mahalanobis^2."""
        Y = self.points_cam(R_cam_vehicle, t_cam_vehicle, p)
        e = Y[:, :2] - self.u[:, :2] * Y[:, 2:3]
        r = self.prior_residual(p)
        return float(np.sum(e * e) + self.lambda_3d * (r @ r))

    def pixel_residuals(self, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Projected minus clicked (undistorted) pixels: (N, 2)."""
        Y = self.points_cam(R_cam_vehicle, t_cam_vehicle, p)
        return Y[:, :2] / Y[:, 2:3] @ self.K[:2, :2].T + self.K[:2, 2] - self.uv

    def cost_px(self, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray) -> float:
        """The pixel-domain cost: px^2 plus lambda_px times Mahalanobis^2."""
        e = self.pixel_residuals(R_cam_vehicle, t_cam_vehicle, p)
        r = self.prior_residual(p)
        return float(np.sum(e * e) + self.lambda_px * (r @ r))

    def min_depth(self, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray) -> float:
        """Smallest depth (camera z) of the clicked points and the cuboid's bottom centre, metres."""
        Y = self.points_cam(R_cam_vehicle, t_cam_vehicle, p)
        return float(min(Y[:, 2].min(), t_cam_vehicle[2]))

    def prior_scale(self, p: np.ndarray) -> float:
        """The scale ``s`` that minimizes ``|W (s d - mu)|^2``: where the prior puts a cuboid of shape ``d``.

        May be negative: ``(s p, s t)`` then turns a mirrored, behind-the-camera answer around (the
        pixel data term is the same for both). 0 when ``d`` is zero.
        """
        Wd = self.prior.sqrt_information @ p[:3]
        denom = float(Wd @ Wd)
        if denom <= 0.0:
            return 0.0
        return float(Wd @ (self.prior.sqrt_information @ self.prior.mean)) / denom
