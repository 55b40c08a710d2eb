"""A posed cuboid as the evaluation sees it: rotation, bottom-centre position, dimensions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from toosicubix.geometry import cuboid_corners_cam


@dataclass(frozen=True)
class Cuboid:
    """A cuboid posed in some camera frame (named by whoever holds it).

    Attributes
    ----------
    R_cam_vehicle : (3, 3) rotation; its columns are the vehicle's forward, left and up axes in the frame
    t_cam_vehicle : (3,) centre of the bottom face in the frame, metres
    dimensions : (3,) ``(dx, dy, dz)`` = (length, width, height), metres
    """

    R_cam_vehicle: np.ndarray
    t_cam_vehicle: np.ndarray
    dimensions: np.ndarray

    def __post_init__(self) -> None:
        for name, shape in (("R_cam_vehicle", (3, 3)), ("t_cam_vehicle", (3,)), ("dimensions", (3,))):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.shape != shape:
                raise ValueError(f"Cuboid.{name}: expected shape {shape}, got {value.shape}")
            object.__setattr__(self, name, value)

    @classmethod
    def from_centre(cls, R_cam_vehicle: np.ndarray, centre_cam: np.ndarray, dimensions: np.ndarray) -> Cuboid:
        """The cuboid whose geometric centre is ``centre_cam`` (3,): the bottom centre lies ``dz / 2`` below
        it along the vehicle's up axis ``R_cam_vehicle[:, 2]``."""
        R = np.asarray(R_cam_vehicle, dtype=np.float64)
        d = np.asarray(dimensions, dtype=np.float64)
        return cls(R, np.asarray(centre_cam, dtype=np.float64) - 0.5 * d[2] * R[:, 2], d)

    @property
    def centre(self) -> np.ndarray:
        """Geometric centre in the frame, (3,)."""
        return self.t_cam_vehicle + 0.5 * self.dimensions[2] * self.R_cam_vehicle[:, 2]

    @property
    def volume(self) -> float:
        """Volume in cubic metres; 0 when a dimension is not positive."""
        return float(np.prod(np.clip(self.dimensions, 0.0, None)))

    @property
    def yaw(self) -> float:
        """KITTI's ``rotation_y`` of the forward axis ``f``: ``atan2(-f_z, f_x)``, radians."""
        f = self.R_cam_vehicle[:, 0]
        return float(np.arctan2(-f[2], f[0]))

    def corners(self) -> np.ndarray:
        """The 8 corners in the frame, (8, 3), in the order of :func:`toosicubix.geometry.cuboid_corners_vehicle`."""
        return cuboid_corners_cam(self.R_cam_vehicle, self.t_cam_vehicle, self.dimensions)

    def translated(self, offset: np.ndarray) -> Cuboid:
        """The same cuboid seen from a frame whose origin is at ``-offset``: ``t + offset``."""
        return Cuboid(self.R_cam_vehicle, self.t_cam_vehicle + np.asarray(offset, dtype=np.float64), self.dimensions)

    def scaled(self, s: float) -> Cuboid:
        """The cuboid scaled by ``s`` about the frame's origin (the camera centre): ``(R, s t, s d)``."""
        return Cuboid(self.R_cam_vehicle, s * self.t_cam_vehicle, s * self.dimensions)
