"""Stage (a): starting rotations from image lines of known vehicle direction (paper, "Initialization").

With zero pitch and roll, ``R_cam_vehicle = R_y(ry) @ R_LEVEL_VEHICLE``. An image line ``l`` through two
clicks whose 3D points differ along the vehicle axis ``D`` holds that axis' vanishing point:
``l^T R D = 0`` in normalized coordinates. For ``D = e_x`` this reads ``l0 cos ry - l2 sin ry = 0``, for
``D = e_y`` ``l2 cos ry + l0 sin ry = 0``. The stacked rows give ``(cos ry, sin ry)`` as the last right
singular vector; both ``ry`` and ``ry + pi`` are tried, each also 10 and 20 degrees either side. Without
any line, 36 yaws 10 degrees apart are tried.

The line-based yaw assumes zero pitch and roll relative to the camera. A few degrees of either, in a view
nearly straight from the front or rear, can move it by tens of degrees (a line through a far vanishing
point barely constrains the yaw). So a coarse sweep of yaws is added to the line-based starts; the
refinement's basin (about 40 degrees) then always holds one of them.
"""

from __future__ import annotations

import numpy as np

from toosicubix.geometry import R_LEVEL_VEHICLE, cross3
from toosicubix.parts.linear import PartsModel

#: Offsets tried around each line-based yaw, radians.
YAW_OFFSETS = np.deg2rad([0.0, -10.0, 10.0, -20.0, 20.0])
#: Yaws tried when no line exists.
YAW_SWEEP = np.deg2rad(np.arange(0.0, 360.0, 10.0))


def line_rows(parts: PartsModel, u: np.ndarray) -> np.ndarray:
    """One row ``(a, b)`` per line, with ``a cos ry + b sin ry = 0``.

    Parameters
    ----------
    parts : its ``lines`` name pairs of clicks along X or Y
    u : (N, 3) normalized clicks

    Returns
    -------
    (m, 2) array; lines through two coincident clicks are left out
    """
    rows = []
    for line in parts.lines:
        l = cross3(u[line.i], u[line.j])
        norm = np.linalg.norm(l)
        if norm < 1e-12:
            continue
        l = l / norm
        rows.append((l[0], -l[2]) if line.axis == 0 else (l[2], l[0]))
    return np.array(rows, dtype=float).reshape(-1, 2)


def yaw_from_lines(rows: np.ndarray) -> float | None:
    """Least-squares ``ry`` (radians) from line rows (m, 2), or None without rows.

    The answer is defined up to pi; the caller tries both.
    """
    if len(rows) == 0:
        return None
    _, _, Vt = np.linalg.svd(rows)
    c, s = Vt[-1]
    return float(np.arctan2(s, c))


def yaw_candidates(parts: PartsModel, u: np.ndarray, sweep: int = 12,
                   min_separation: float = np.deg2rad(5.0)) -> tuple[np.ndarray, bool]:
    """The starting yaws of the coordinate descent.

    Parameters
    ----------
    sweep : with lines, also try this many yaws evenly spread over the circle (0: lines only, as the paper)
    min_separation : a sweep yaw closer than this to a line-based one is left out

    Returns
    -------
    yaws : (k,) radians, ``ry`` in KITTI's sense; the line-based ones first
    from_lines : whether there were lines (else the 36-angle sweep)
    """
    ry = yaw_from_lines(line_rows(parts, u))
    if ry is None:
        return YAW_SWEEP.copy(), False
    bases = np.array([ry, ry + np.pi])
    line_yaws = (bases[:, None] + YAW_OFFSETS[None, :]).ravel()
    if sweep <= 0:
        return line_yaws, True
    extra = np.linspace(0.0, 2.0 * np.pi, sweep, endpoint=False)
    gaps = np.abs(np.angle(np.exp(1j * (extra[:, None] - line_yaws[None, :])))).min(axis=1)
    return np.concatenate([line_yaws, extra[gaps >= min_separation]]), True


def rotations_from_yaws(yaws: np.ndarray) -> np.ndarray:
    """``R_y(ry) @ R_LEVEL_VEHICLE`` for each yaw (k,): (k, 3, 3), upright vehicles."""
    c, s = np.cos(yaws), np.sin(yaws)
    R_y = np.zeros((len(yaws), 3, 3))
    R_y[:, 0, 0], R_y[:, 0, 2], R_y[:, 1, 1], R_y[:, 2, 0], R_y[:, 2, 2] = c, s, 1.0, -s, c
    return R_y @ R_LEVEL_VEHICLE
