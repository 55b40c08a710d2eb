"""3D intersection over union of two cuboids: exact with full rotations, and KITTI's yaw-only variant.

:func:`iou_3d` is the metric of the paper: the intersection of two oriented cuboids is a convex polytope,
the intersection of their 12 face half-spaces. Its volume is found exactly (to rounding) by
``scipy.spatial.HalfspaceIntersection`` from a strictly interior point and ``ConvexHull``. The
interior point is a box centre when one lies well inside both boxes (the usual case for matched
objects), else the Chebyshev centre (the centre of the largest ball inside both boxes, one small
linear programme); a radius of about zero means the boxes touch or are disjoint: IoU 0.

:func:`iou_bev_height_yaw` is what KITTI tooling computes: each box reduced to its yaw ``ry``, the
bird's-eye rectangles intersected in the camera x-z plane, times the overlap of the vertical
extents. It ignores pitch and roll and is given only for comparison with such tools.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError

from toosicubix.geometry import Cuboid

#: Below this Chebyshev radius, relative to the smaller box's largest half-dimension, the boxes only
#: touch: the intersection is at most a slab of relative thickness 2e-9 and its IoU below ~1e-8.
RELATIVE_RADIUS_TOUCHING = 1e-9
#: A box centre at least this deep inside both boxes, relative to the smallest half-dimension, serves as
#: Qhull's interior point without solving for the Chebyshev centre.
FAST_DEPTH = 0.05


def cuboid_halfspaces(R_cam_vehicle: np.ndarray, centre: np.ndarray, half_dimensions: np.ndarray) -> np.ndarray:
    """The 6 face half-spaces of a cuboid in scipy's form ``A x + b <= 0``.

    Parameters
    ----------
    R_cam_vehicle : (3, 3) rotation, columns are the box axes
    centre : (3,) geometric centre
    half_dimensions : (3,) half the extent along each box axis

    Returns
    -------
    (6, 4) array ``[A | b]``, rows of ``A`` unit normals pointing out of the box
    """
    normals = np.concatenate([R_cam_vehicle.T, -R_cam_vehicle.T])
    offsets = normals @ centre + np.concatenate([half_dimensions, half_dimensions])
    return np.column_stack([normals, -offsets])


def chebyshev_centre(halfspaces: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius of the largest ball inside ``{x : A x + b <= 0}``.

    Parameters
    ----------
    halfspaces : (m, 4) ``[A | b]`` with unit-norm rows of ``A``

    Returns
    -------
    centre : (3,) array
    radius : float, 0.0 when the set is empty (the linear programme is infeasible)
    """
    A, b = halfspaces[:, :3], halfspaces[:, 3]
    norms = np.linalg.norm(A, axis=1)
    # Maximise r subject to A x + r |A_i| <= -b, r >= 0.
    res = linprog(c=[0.0, 0.0, 0.0, -1.0], A_ub=np.column_stack([A, norms]), b_ub=-b,
                  bounds=[(None, None)] * 3 + [(0.0, None)], method="highs")
    if res.status != 0:
        return np.zeros(3), 0.0
    return np.asarray(res.x[:3]), float(res.x[3])


def deepest_candidate(halfspaces: np.ndarray, candidates: list[np.ndarray]) -> tuple[np.ndarray, float]:
    """The candidate point deepest inside ``{x : A x + b <= 0}`` and its depth.

    Parameters
    ----------
    halfspaces : (m, 4) ``[A | b]`` with unit-norm rows of ``A``
    candidates : points (3,)

    Returns
    -------
    point : (3,) array
    depth : float, distance to the nearest bounding plane; negative outside
    """
    points = np.asarray(candidates, dtype=float)
    depths = -(points @ halfspaces[:, :3].T + halfspaces[:, 3]).max(axis=1)
    k = int(np.argmax(depths))
    return points[k], float(depths[k])


def intersection_volume_3d(a: Cuboid, b: Cuboid) -> float:
    """Volume of the intersection of two oriented cuboids, cubic metres, exact to rounding.

    Parameters
    ----------
    a, b : cuboids in the same frame, any rotations

    Returns
    -------
    float >= 0; 0.0 for disjoint or touching boxes (no exception)
    """
    if a.volume <= 0.0 or b.volume <= 0.0:
        return 0.0
    centre_a, centre_b = a.centre, b.centre
    half_a, half_b = 0.5 * a.dimensions, 0.5 * b.dimensions
    # Bounding spheres: cheap rejection of clearly disjoint boxes.
    if np.linalg.norm(centre_a - centre_b) >= np.linalg.norm(half_a) + np.linalg.norm(half_b):
        return 0.0
    # Work near the origin in float64: subtract the common midpoint so far-away boxes lose no digits.
    origin = 0.5 * (centre_a + centre_b)
    halfspaces = np.concatenate([
        cuboid_halfspaces(a.R_cam_vehicle, centre_a - origin, half_a),
        cuboid_halfspaces(b.R_cam_vehicle, centre_b - origin, half_b),
    ])
    halfspaces = _unique_rows(halfspaces, scale=float(max(half_a.max(), half_b.max())))
    scale = float(min(half_a.max(), half_b.max()))
    # Any point well inside both boxes will do for Qhull; a centre usually is one and costs no linear
    # programme. Otherwise (slivers, touching or disjoint boxes) the Chebyshev centre decides.
    interior, radius = deepest_candidate(halfspaces, [centre_a - origin, centre_b - origin, np.zeros(3)])
    if radius < FAST_DEPTH * float(min(half_a.min(), half_b.min())):
        interior, radius = chebyshev_centre(halfspaces)
    if radius <= RELATIVE_RADIUS_TOUCHING * scale:
        return 0.0
    try:
        vertices = HalfspaceIntersection(halfspaces, interior).intersections
        return float(ConvexHull(vertices).volume)
    except QhullError:
        # Only a sliver thin enough to defeat Qhull's precision gets here; its volume is below rounding
        # of the boxes' volumes at this radius.
        if radius <= 1e-6 * scale:
            return 0.0
        raise


def iou_3d(a: Cuboid, b: Cuboid) -> float:
    """Exact 3D IoU of two oriented cuboids with full rotations (DESIGN section 5).

    Parameters
    ----------
    a, b : cuboids in the same frame

    Returns
    -------
    float in [0, 1]; 1 for identical boxes, 0 for touching or disjoint ones
    """
    inter = intersection_volume_3d(a, b)
    union = a.volume + b.volume - inter
    return float(np.clip(inter / union, 0.0, 1.0)) if union > 0.0 else 0.0


def iou_bev_height_yaw(a: Cuboid, b: Cuboid) -> float:
    """KITTI-style 3D IoU: yaw-only bird's-eye overlap times vertical overlap, over the union volume.

    Each box is taken as KITTI stores it: its yaw ``ry`` (pitch and roll dropped), bottom centre
    ``t`` and dimensions. The bird's-eye rectangle lies in the camera x-z plane, centred at
    ``(t_x, t_z)``, length ``dx`` along ``(cos ry, -sin ry)``; the vertical extent is
    ``[t_y - dz, t_y]`` (camera y points down).

    Parameters
    ----------
    a, b : cuboids in the same camera frame (y down)

    Returns
    -------
    float in [0, 1]
    """
    if a.volume <= 0.0 or b.volume <= 0.0:
        return 0.0
    origin = 0.5 * (a.t_cam_vehicle + b.t_cam_vehicle)
    area = convex_polygon_intersection_area(_bev_rectangle(a, origin), _bev_rectangle(b, origin))
    y_top = max(a.t_cam_vehicle[1] - a.dimensions[2], b.t_cam_vehicle[1] - b.dimensions[2])
    y_bottom = min(a.t_cam_vehicle[1], b.t_cam_vehicle[1])
    inter = area * max(0.0, y_bottom - y_top)
    union = a.volume + b.volume - inter
    return float(np.clip(inter / union, 0.0, 1.0)) if union > 0.0 else 0.0


def _bev_rectangle(c: Cuboid, origin: np.ndarray) -> np.ndarray:
    """Counter-clockwise corners (in (x, z) coordinates) of a cuboid's yaw-only footprint, (4, 2)."""
    ry = c.yaw
    forward = np.array([np.cos(ry), -np.sin(ry)])
    side = np.array([-forward[1], forward[0]])
    centre = (c.t_cam_vehicle - origin)[[0, 2]]
    hl, hw = 0.5 * c.dimensions[0], 0.5 * c.dimensions[1]
    return np.array([centre + sx * hl * forward + sy * hw * side for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))])


def polygon_area(polygon: np.ndarray) -> float:
    """Signed area of a simple polygon (N, 2) by the shoelace formula: positive when counter-clockwise."""
    if len(polygon) < 3:
        return 0.0
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def convex_polygon_intersection_area(p: np.ndarray, q: np.ndarray) -> float:
    """Area of the intersection of two convex polygons, (N, 2) and (M, 2), either orientation.

    Sutherland–Hodgman: clip ``p`` by each edge of ``q`` in turn.
    """
    if polygon_area(p) < 0.0:
        p = p[::-1]
    if polygon_area(q) < 0.0:
        q = q[::-1]
    out = [tuple(v) for v in p]
    for k in range(len(q)):
        if not out:
            return 0.0
        e0, e1 = q[k], q[(k + 1) % len(q)]
        edge = e1 - e0
        inp, out = out, []

        def side(v: tuple[float, float], e0=e0, edge=edge) -> float:
            # Positive on the left of the edge, i.e. inside a counter-clockwise polygon.
            return edge[0] * (v[1] - e0[1]) - edge[1] * (v[0] - e0[0])

        for i, cur in enumerate(inp):
            prev = inp[i - 1]
            s_cur, s_prev = side(cur), side(prev)
            if s_cur >= 0.0:
                if s_prev < 0.0:
                    out.append(_crossing(prev, cur, s_prev, s_cur))
                out.append(cur)
            elif s_prev >= 0.0:
                out.append(_crossing(prev, cur, s_prev, s_cur))
    return max(0.0, polygon_area(np.array(out))) if len(out) >= 3 else 0.0


def _crossing(p0: tuple[float, float], p1: tuple[float, float], s0: float, s1: float) -> tuple[float, float]:
    w = s0 / (s0 - s1)
    return (p0[0] + w * (p1[0] - p0[0]), p0[1] + w * (p1[1] - p0[1]))


def _unique_rows(halfspaces: np.ndarray, scale: float) -> np.ndarray:
    """Drop half-spaces that repeat an earlier one (identical faces of the two boxes), which Qhull dislikes."""
    close = np.all(np.abs(halfspaces[:, None, :] - halfspaces[None, :, :]) <= 1e-12 * max(scale, 1.0), axis=2)
    repeated = np.triu(close, k=1).any(axis=0)
    return halfspaces[~repeated]
