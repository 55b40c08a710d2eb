"""Rotations, projections and cuboids: the geometry every other module shares.

Frames (see docs/conventions.md):

- ``vehicle``: origin at the centre of the cuboid's bottom face; X forward, Y left, Z up.
- ``cam``: x right, y down, z forward (OpenCV). ``X_cam = R_cam_vehicle @ X_vehicle + t_cam_vehicle``.

Angles are radians; names ending in ``_deg`` are degrees. Rotations compose by their names:
``R_a_b @ R_b_c`` is ``R_a_c``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: Vehicle axes in KITTI's object frame: ``R_cam_vehicle = R_y(ry) @ R_KITTI_VEHICLE`` for an upright
#: vehicle. Vehicle X (forward) -> camera x, vehicle Y (left) -> camera z, vehicle Z (up) -> camera -y.
R_LEVEL_VEHICLE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

# Corner signs in the vehicle frame, as (sx, sy, top): x = sx*dx/2, y = sy*dy/2, z = top*dz.
# Order: bottom face counter-clockwise from front-left seen from above, then the top face likewise.
_CORNER_SIGNS = np.array(
    [
        [1, 1, 0], [-1, 1, 0], [-1, -1, 0], [1, -1, 0],
        [1, 1, 1], [-1, 1, 1], [-1, -1, 1], [1, -1, 1],
    ],
    dtype=float,
)

#: Batches up to this many rotation vectors go through ``cv2.Rodrigues`` one by one (see :func:`so3_exp`).
_RODRIGUES_LOOP_MAX = 8
_IDENTITY = np.eye(3)


def hat(omega: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrices of 3-vectors: ``hat(a) @ b == cross(a, b)``.

    Parameters
    ----------
    omega : (..., 3) array

    Returns
    -------
    (..., 3, 3) array
    """
    omega = np.asarray(omega, dtype=float)
    W = np.zeros((*omega.shape[:-1], 3, 3))
    W[..., 0, 1], W[..., 0, 2] = -omega[..., 2], omega[..., 1]
    W[..., 1, 0], W[..., 1, 2] = omega[..., 2], -omega[..., 0]
    W[..., 2, 0], W[..., 2, 1] = -omega[..., 1], omega[..., 0]
    return W


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of two 3-vectors (3,), the same numbers (each component one product less another, as numpy
    computes it) without its general machinery's cost."""
    a0, a1, a2 = a.tolist()
    b0, b1, b2 = b.tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def so3_exp(omega: np.ndarray) -> np.ndarray:
    """Exponential map of SO(3), Rodrigues' formula, for one rotation vector or a batch of them.

    ``exp([omega]x) = c I + (1 - c) u u^T + s [u]x`` with ``theta = |omega|``, ``u = omega / theta``,
    ``c = cos(theta)``, ``s = sin(theta)``; the identity below ``theta`` = machine epsilon. The arithmetic is
    OpenCV's ``cv2.Rodrigues`` operation for operation (the same bits), vectorised; its error near zero is that
    of ``1 - cos(theta)``, below 1e-16 absolute. Up to ``_RODRIGUES_LOOP_MAX`` rotations (the few starts of a
    refinement, the vehicles of an image) it calls ``cv2.Rodrigues`` itself in a loop, about 1 microsecond
    each against the array formula's fixed cost of some 20 numpy operations; the two agree bit for bit.

    Parameters
    ----------
    omega : (..., 3) array
        Axis times angle, radians.

    Returns
    -------
    (..., 3, 3) rotation matrices
    """
    omega = np.asarray(omega, dtype=float)
    if omega.size <= 3 * _RODRIGUES_LOOP_MAX:
        return _so3_exp_loop(omega.reshape(-1, 3)).reshape((*omega.shape, 3))
    x, y, z = omega[..., 0], omega[..., 1], omega[..., 2]
    theta = np.sqrt(x * x + y * y + z * z)
    tiny = theta < np.finfo(float).eps
    theta = np.where(tiny, 1.0, theta)
    c, s = np.cos(theta), np.sin(theta)
    u = omega * (1.0 / theta)[..., None]
    R = (1.0 - c)[..., None, None] * (u[..., :, None] * u[..., None, :])
    su = s[..., None] * u
    R[..., 0, 1] -= su[..., 2]
    R[..., 0, 2] += su[..., 1]
    R[..., 1, 0] += su[..., 2]
    R[..., 1, 2] -= su[..., 0]
    R[..., 2, 0] -= su[..., 1]
    R[..., 2, 1] += su[..., 0]
    diagonal = R.reshape((*omega.shape[:-1], 9))[..., ::4]
    diagonal += c[..., None]
    R[tiny] = np.eye(3)
    return R


def _so3_exp_loop(omega: np.ndarray) -> np.ndarray:
    """``cv2.Rodrigues`` of each rotation vector of ``omega`` (K, 3): (K, 3, 3). A zero vector (a start of a
    refinement that has stopped) gives the identity without the call, as ``cv2.Rodrigues`` would."""
    R = np.empty((len(omega), 3, 3))
    for k, w in enumerate(omega.tolist()):
        R[k] = cv2.Rodrigues(omega[k])[0] if any(w) else _IDENTITY
    return R


def so3_log(R: np.ndarray) -> np.ndarray:
    """Logarithm of SO(3): the rotation vector ``omega`` with ``so3_exp(omega) == R``.

    Accurate for angles near 0 and near pi.

    Parameters
    ----------
    R : (3, 3) rotation matrix

    Returns
    -------
    (3,) array, norm in [0, pi]
    """
    R = np.asarray(R, dtype=float)
    cos_theta = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    axis_sin = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2.0
    sin_theta = float(np.linalg.norm(axis_sin))
    theta = float(np.arctan2(sin_theta, cos_theta))
    if theta < 1e-6:
        # R ~ I + hat(omega) + O(theta^2).
        return axis_sin * (1.0 + theta * theta / 6.0)
    if np.pi - theta > 1e-3:
        return axis_sin * (theta / sin_theta)
    # Near pi the vector part vanishes; the symmetric part is cos(theta) I + (1 - cos(theta)) a a^T exactly.
    A = ((R + R.T) / 2.0 - cos_theta * np.eye(3)) / (1.0 - cos_theta)
    k = int(np.argmax(np.diag(A)))
    axis = A[:, k] / np.sqrt(max(A[k, k], 1e-300))
    axis /= np.linalg.norm(axis)
    if axis @ axis_sin < 0.0:
        axis = -axis
    return axis * theta


def geodesic_angle(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle of the rotation ``R_a @ R_b.T``, radians in [0, pi].

    Computed from the vector part and the trace together, so it stays accurate for tiny angles.
    """
    D = np.asarray(R_a, dtype=float) @ np.asarray(R_b, dtype=float).T
    s = np.linalg.norm([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]]) / 2.0
    c = (np.trace(D) - 1.0) / 2.0
    return float(np.arctan2(s, c))


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation closest to ``M`` in Frobenius norm (SVD projection, det +1)."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``a`` (3,) to unit vector ``b`` (3,): (3, 3)."""
    a = np.asarray(a, dtype=float) / np.linalg.norm(a)
    b = np.asarray(b, dtype=float) / np.linalg.norm(b)
    axis = cross3(a, b)
    s, c = np.linalg.norm(axis), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # Opposite: half a turn about any axis orthogonal to a.
        other = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        axis = cross3(a, other)
        return so3_exp(axis / np.linalg.norm(axis) * np.pi)
    return so3_exp(axis / s * np.arctan2(s, c))


def rot_x(angle: float) -> np.ndarray:
    """Rotation by ``angle`` about the x axis, (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> np.ndarray:
    """Rotation by ``angle`` about the y axis, (3, 3): ``[[c, 0, s], [0, 1, 0], [-s, 0, c]]``."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> np.ndarray:
    """Rotation by ``angle`` about the z axis, (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def wrap_angle(angle: float | np.ndarray) -> float | np.ndarray:
    """Wrap radians to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def R_cam_vehicle_from_ypr(ry: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """Rotation from KITTI yaw plus the vehicle's own pitch and roll.

    ``R_cam_vehicle = R_y(ry) @ R_LEVEL_VEHICLE @ R_Y(pitch) @ R_X(roll)``, where ``R_Y`` and
    ``R_X`` turn about the vehicle's own left (Y) and forward (X) axes. Positive pitch puts the nose
    down; positive roll lowers the right side. ``ry`` is KITTI's ``rotation_y``: the vehicle faces
    camera +x at 0 and turns about camera y.

    Returns
    -------
    (3, 3) rotation matrix ``R_cam_vehicle``
    """
    return rot_y(ry) @ R_LEVEL_VEHICLE @ rot_y(pitch) @ rot_x(roll)


def ypr_from_R_cam_vehicle(R_cam_vehicle: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`R_cam_vehicle_from_ypr`: ``(ry, pitch, roll)`` in radians.

    ``ry = atan2(-f_z, f_x)`` with ``f = R e_x`` the forward axis in camera coordinates, as KITTI
    defines it; pitch in [-pi/2, pi/2].
    """
    f_cam = R_cam_vehicle[:, 0]
    ry = float(np.arctan2(-f_cam[2], f_cam[0]))
    R_level_vehicle = R_LEVEL_VEHICLE.T @ rot_y(ry).T @ R_cam_vehicle
    pitch = float(np.arctan2(-R_level_vehicle[2, 0], np.hypot(R_level_vehicle[0, 0], R_level_vehicle[1, 0])))
    roll = float(np.arctan2(R_level_vehicle[2, 1], R_level_vehicle[2, 2]))
    return ry, pitch, roll


def cuboid_corners_vehicle(dimensions: np.ndarray) -> np.ndarray:
    """The 8 corners of a cuboid in its own vehicle frame (origin at the bottom-face centre).

    Parameters
    ----------
    dimensions : (3,) array
        ``(dx, dy, dz)`` = (length, width, height), metres.

    Returns
    -------
    corners_vehicle : (8, 3) array
        Bottom face first (front-left, rear-left, rear-right, front-right), then the top face.
    """
    dx, dy, dz = np.asarray(dimensions, dtype=float)
    scale = np.array([dx / 2.0, dy / 2.0, dz])
    return _CORNER_SIGNS * scale


def cuboid_corners_cam(R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, dimensions: np.ndarray) -> np.ndarray:
    """The 8 corners of a posed cuboid in camera coordinates, (8, 3), same order as
    :func:`cuboid_corners_vehicle`."""
    return cuboid_corners_vehicle(dimensions) @ np.asarray(R_cam_vehicle).T + np.asarray(t_cam_vehicle)


def depth_reversed_twin(R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, dimensions: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """A posed cuboid's depth-reversed twin: reflected across the plane through its centre perpendicular to the
    line of sight, then mirrored left for right in its own frame. Two reflections make a rotation.

    Each point ``(x, y, z)`` of the twin (vehicle frame) sits where the pose's point ``(x, -y, z)``, reflected across
    that plane, sits: seen from afar the two project nearly alike, with each part's left and right exchanged and
    the faces turned to the camera turned away. Clicks whose left and right were read the other way fit the twin
    about as well as the pose. The twin of the twin is the pose.

    Parameters
    ----------
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,) the bottom-face centre, camera frame; dimensions : (3,)

    Returns
    -------
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,) of the twin (same dimensions, same box centre); NaN when the box
    centre is at the camera (no line of sight)
    """
    R_cam_vehicle = np.asarray(R_cam_vehicle, dtype=float)
    half_height = float(np.asarray(dimensions, dtype=float)[2]) / 2.0
    centre_cam = np.asarray(t_cam_vehicle, dtype=float) + R_cam_vehicle[:, 2] * half_height
    distance = float(np.linalg.norm(centre_cam))
    if not distance > 0.0:
        return np.full((3, 3), np.nan), np.full(3, np.nan)
    sight = centre_cam / distance
    R_twin = (np.eye(3) - 2.0 * np.outer(sight, sight)) @ R_cam_vehicle @ np.diag([1.0, -1.0, 1.0])
    return R_twin, centre_cam - R_twin[:, 2] * half_height


def project_pinhole(K: np.ndarray, points_cam: np.ndarray) -> np.ndarray:
    """Project camera-frame points with an ideal pinhole ``K`` (no distortion).

    Parameters
    ----------
    K : (3, 3) intrinsics
    points_cam : (N, 3) array, z > 0 for a meaningful result

    Returns
    -------
    uv : (N, 2) pixels
    """
    homog = np.asarray(points_cam, dtype=float) @ np.asarray(K, dtype=float).T
    return homog[:, :2] / homog[:, 2:3]


def box2d_of_points(uv: np.ndarray, image_size: tuple[int, int] | None = None) -> np.ndarray:
    """Axis-aligned box ``(x1, y1, x2, y2)`` around pixels, clipped to ``(width, height)`` if given.

    Parameters
    ----------
    uv : (N, 2) pixels
    image_size : (width, height) or None

    Returns
    -------
    (4,) array
    """
    x1, y1 = uv.min(axis=0)
    x2, y2 = uv.max(axis=0)
    box = np.array([x1, y1, x2, y2], dtype=float)
    if image_size is not None:
        w, h = image_size
        box[[0, 2]] = np.clip(box[[0, 2]], 0.0, w - 1.0)
        box[[1, 3]] = np.clip(box[[1, 3]], 0.0, h - 1.0)
    return box


def box2d_iou(box_a: np.ndarray, box_b: np.ndarray) -> float:
    """IoU of two axis-aligned boxes ``(x1, y1, x2, y2)``; 0 when either has no area."""
    ix = max(0.0, min(box_a[2], box_b[2]) - max(box_a[0], box_b[0]))
    iy = max(0.0, min(box_a[3], box_b[3]) - max(box_a[1], box_b[1]))
    inter = ix * iy
    area_a = max(0.0, box_a[2] - box_a[0]) * max(0.0, box_a[3] - box_a[1])
    area_b = max(0.0, box_b[2] - box_b[0]) * max(0.0, box_b[3] - box_b[1])
    union = area_a + area_b - inter
    return float(inter / union) if union > 0.0 else 0.0


#: The 12 edges of a cuboid as pairs of corner indices (order of :func:`cuboid_corners_vehicle`).
CUBOID_EDGES = (
    (0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7),
)
#: The front face (vehicle +X) as corner indices: bottom front-left, bottom front-right, top front-right, top
#: front-left.
FRONT_FACE = (0, 3, 7, 4)


#: The near plane (metres in front of the camera) where clipping cuts what reaches behind the camera.
Z_NEAR = 0.1


def clip_segment_to_near_plane(a_cam: np.ndarray, b_cam: np.ndarray, z_near: float = Z_NEAR
                               ) -> tuple[np.ndarray, np.ndarray] | None:
    """The part of the segment from ``a_cam`` to ``b_cam`` (3,), camera frame, with ``z >= z_near``, or None when
    none is.

    Returns
    -------
    (a', b') : two (3,) arrays in the camera frame, or None
    """
    za, zb = float(a_cam[2]), float(b_cam[2])
    if za < z_near and zb < z_near:
        return None
    if za >= z_near and zb >= z_near:
        return a_cam, b_cam
    s = (z_near - za) / (zb - za)
    crossing = a_cam + s * (b_cam - a_cam)
    return (crossing, b_cam) if za < z_near else (a_cam, crossing)


def clip_polygon_to_near_plane(polygon_cam: np.ndarray, z_near: float) -> np.ndarray:
    """The part of a planar polygon (k, 3), camera frame, with ``z >= z_near`` (Sutherland-Hodgman): (m, 3), m may be
    0."""
    out = []
    n = len(polygon_cam)
    for i in range(n):
        a, b = polygon_cam[i], polygon_cam[(i + 1) % n]
        a_in, b_in = a[2] >= z_near, b[2] >= z_near
        if a_in:
            out.append(a)
        if a_in != b_in:
            s = (z_near - a[2]) / (b[2] - a[2])
            out.append(a + s * (b - a))
    return np.array(out).reshape(-1, 3)


def clip_cuboid_to_near_plane(corners_cam: np.ndarray, z_near: float = Z_NEAR) -> np.ndarray:
    """The corners in front of ``z = z_near`` plus where the cuboid's edges cross that plane.

    Projecting these gives the image extent of a cuboid that reaches behind the camera.

    Parameters
    ----------
    corners_cam : (8, 3)
    z_near : metres

    Returns
    -------
    (M, 3) array, M may be 0 when the cuboid lies wholly behind the plane
    """
    z = corners_cam[:, 2]
    points = [corners_cam[z >= z_near]]
    depths = z.tolist()  # the same numbers as plain floats: twelve edges' tests without numpy's per-scalar cost
    for i, j in CUBOID_EDGES:
        if (depths[i] - z_near) * (depths[j] - z_near) < 0.0:  # the edge crosses the plane: where (its clipped end)
            a, b = clip_segment_to_near_plane(corners_cam[i], corners_cam[j], z_near)  # type: ignore[misc]
            points.append((b if depths[i] >= z_near else a)[None, :])
    return np.concatenate(points, axis=0)


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
