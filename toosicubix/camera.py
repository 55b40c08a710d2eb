"""The camera: intrinsics, optional lens distortion, and KITTI's per-camera offset.

A KITTI projection matrix is ``P = K [I | t]``: a point in the rectified camera-0 frame (``rect``)
projects through ``K (X_rect + t)``. Fitting uses ``K`` alone, so poses come out in the frame
``cam = rect + t`` (camera 2 for ``P2``); ``t_cam_rect`` turns them back.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import cv2
import numpy as np

from toosicubix.geometry import project_pinhole

_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)


@dataclass(frozen=True)
class Camera:
    """A calibrated camera.

    Attributes
    ----------
    K : (3, 3) intrinsics, last row (0, 0, 1)
    distortion : (k,) OpenCV coefficients, or None for an ideal pinhole
    t_cam_rect : (3,) ``X_cam = X_rect + t_cam_rect``; zero unless built from a KITTI ``P``
    image_size : (width, height) in pixels, or None
    """

    K: np.ndarray
    distortion: np.ndarray | None = None
    t_cam_rect: np.ndarray = field(default_factory=lambda: np.zeros(3))
    image_size: tuple[int, int] | None = None

    @classmethod
    def from_P(cls, P: np.ndarray, image_size: tuple[int, int] | None = None,
               distortion: np.ndarray | None = None) -> Camera:
        """Camera of a KITTI-style ``P = K [I | t]`` (3, 4)."""
        P = np.asarray(P, dtype=float)
        K = P[:, :3].copy()
        return cls(K=K, distortion=distortion, t_cam_rect=np.linalg.solve(K, P[:, 3]), image_size=image_size)

    @property
    def has_distortion(self) -> bool:
        return self.distortion is not None and bool(np.any(self.distortion != 0.0))

    def normalize(self, uv: np.ndarray) -> np.ndarray:
        """Normalized, undistorted image points ``u = K^-1 (x, y, 1)``.

        Parameters
        ----------
        uv : (N, 2) pixels

        Returns
        -------
        (N, 3) array, last column 1
        """
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        if self.has_distortion:
            xy = _undistort_points(uv, self.K, self.distortion)
        else:
            xy = (uv - self.K[:2, 2]) @ np.linalg.inv(self.K[:2, :2]).T
        return np.column_stack([xy, np.ones(len(xy))])

    def undistort_pixels(self, uv: np.ndarray) -> np.ndarray:
        """Where ``uv`` (N, 2) would be seen by the ideal pinhole ``K``: (N, 2) pixels."""
        if not self.has_distortion:
            return np.asarray(uv, dtype=float).reshape(-1, 2)
        return project_pinhole(self.K, self.normalize(uv))

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Pixels of camera-frame points, with lens distortion.

        Parameters
        ----------
        points_cam : (N, 3), z > 0

        Returns
        -------
        uv : (N, 2)
        """
        points_cam = np.asarray(points_cam, dtype=float).reshape(-1, 3)
        if not self.has_distortion:
            return project_pinhole(self.K, points_cam)
        uv, _ = cv2.projectPoints(points_cam, np.zeros(3), np.zeros(3), self.K, self.distortion)
        return uv.reshape(-1, 2)


#: Directions (about the optical axis) and radii (normalized, up to 4: 76 degrees off the axis) on which a lens's
#: distortion is checked for folding back.
_FOLD_DIRECTIONS, _FOLD_RADII = 16, np.linspace(0.0, 4.0, 2001)


def fold_radius(camera: Camera) -> float:
    """The normalized radius ``sqrt(x^2 + y^2)`` from which the camera's distortion folds back: past it, a point
    farther from the axis lands nearer the image's centre, so a drawn edge would cross the image on the wrong side.
    The smallest over :data:`_FOLD_DIRECTIONS` directions where the distorted radius stops growing; ``inf`` for a
    pinhole camera or a lens that does not fold within a radius of 4. Computed once per lens (K and distortion):
    a batch's images share a few."""
    if not camera.has_distortion:
        return float("inf")
    return _lens_fold_radius(tuple(camera.K.ravel().tolist()), tuple(np.ravel(camera.distortion).tolist()))


@functools.lru_cache(maxsize=64)
def _lens_fold_radius(K: tuple[float, ...], distortion: tuple[float, ...]) -> float:
    camera = Camera(K=np.array(K).reshape(3, 3), distortion=np.array(distortion))
    phi = np.linspace(0.0, 2.0 * np.pi, _FOLD_DIRECTIONS, endpoint=False)
    r = _FOLD_RADII
    points = np.stack([np.outer(np.cos(phi), r), np.outer(np.sin(phi), r), np.ones((len(phi), len(r)))], axis=-1)
    with np.errstate(all="ignore"):
        uv = camera.project(points.reshape(-1, 3)).reshape(len(phi), len(r), 2)
        # Distance from the axis's image, in the undistorted scale: K^-1 applied to the distorted pixels.
        xy = (uv - camera.K[:2, 2]) @ np.linalg.inv(camera.K[:2, :2]).T
        radius = np.linalg.norm(xy, axis=-1)  # (directions, radii)
        folds = ~(np.diff(radius, axis=1) > 0.0)  # NaN counts as a fold
    first = [r[int(np.argmax(row))] for row in folds if row.any()]
    return float(min(first)) if first else float("inf")


def trusted_radius(camera: Camera, size: tuple[int, int] | None) -> float:
    """How far from the optical axis (normalized ``sqrt(x^2 + y^2)``) the camera's distortion is trusted for drawing
    and export: 1.25 times the radius of the image's farthest corner, undistorted (1.5 when the image size is
    unknown), and never past where the lens model folds back (:func:`fold_radius`; KITTI's raw camera 2 folds at 1.21
    while its corners undistort past 1.3); ``inf`` for a pinhole camera."""
    if not camera.has_distortion:
        return float("inf")
    if size is None:
        corner = 1.5
    else:
        w, h = size
        corners_uv = np.array([[0.0, 0.0], [w - 1.0, 0.0], [0.0, h - 1.0], [w - 1.0, h - 1.0]])
        corner = 1.25 * float(np.max(np.linalg.norm(camera.normalize(corners_uv)[:, :2], axis=1)))
    return min(corner, 0.98 * fold_radius(camera))


def within_radius(points_cam: np.ndarray, radius: float) -> np.ndarray:
    """(N,) whether camera-frame points (N, 3), z > 0, lie within the normalized ``radius`` of the optical axis
    (:func:`trusted_radius`)."""
    return np.hypot(points_cam[:, 0], points_cam[:, 1]) <= radius * points_cam[:, 2]


def _undistort_points(uv: np.ndarray, K: np.ndarray, distortion: np.ndarray) -> np.ndarray:
    src = uv.reshape(-1, 1, 2)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x
        out = cv2.undistortPointsIter(src, K, distortion, None, None, _UNDISTORT_CRITERIA)
    else:  # OpenCV 5 takes the criteria in undistortPoints itself
        out = cv2.undistortPoints(src, K, distortion, criteria=_UNDISTORT_CRITERIA)
    return out.reshape(-1, 2)
