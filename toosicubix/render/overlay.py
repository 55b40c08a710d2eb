"""Overlays with OpenCV: fitted cuboids, clicks and residuals over an image, and a bird's-eye view beside it.

Everything is drawn with integer pixel operations and Hershey fonts, so the same input gives the same
pixels on every run and machine with the same OpenCV.

Frames: ``cam`` (x right, y down, z forward), ``vehicle`` (X forward, Y left, Z up, origin at the bottom
centre). Cuboid edges are cut at the plane ``z = z_near`` in front of the camera before projection, so an
edge that reaches behind the camera is drawn up to where it leaves the view, never wrapped through infinity.
With lens distortion every edge is projected as a polyline of samples (edges bend), and only where the
distortion polynomial is valid: samples farther from the axis than the image's own corners (plus a margin)
are dropped, because there the polynomial folds back and would paint far-away points inside the image.

Colours are BGR (OpenCV's order). A vehicle is drawn in its own colour (:attr:`DrawnVehicle.colour`, which a
tracked vehicle takes from its track) or else in the palette's colour of its place in the image.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from toosicubix.camera import Camera, trusted_radius, within_radius
from toosicubix.geometry import (
    CUBOID_EDGES,
    FRONT_FACE,
    Z_NEAR,
    clip_polygon_to_near_plane,
    clip_segment_to_near_plane,
    cuboid_corners_cam,
    cuboid_corners_vehicle,
)

#: One colour per vehicle, in image order (BGR; Okabe-Ito-like, distinguishable on grey and on photos).
PALETTE_BGR = (
    (0, 159, 230), (233, 180, 86), (115, 158, 0), (66, 228, 240), (178, 114, 0),
    (0, 94, 213), (167, 121, 204), (255, 255, 120), (120, 255, 120), (200, 200, 255),
)
GROUND_TRUTH_BGR = (255, 255, 255)
FAILED_BGR = (40, 40, 230)
DOWNWEIGHTED_BGR = (60, 60, 255)
RESIDUAL_BGR = (0, 255, 255)
BLANK_GREY = 48  # grey canvases are filled by one memset (np.full with a scalar), 300 times faster than a BGR fill
BLANK_BGR = (BLANK_GREY,) * 3
PANEL_GREY = 28
TEXT_BGR = (235, 235, 235)

#: Sub-pixel bits for OpenCV's drawing (coordinates are multiplied by 2**SHIFT).
SHIFT = 2
_FONT = cv2.FONT_HERSHEY_SIMPLEX


@dataclass(frozen=True)
class OverlayOptions:
    """What an overlay shows.

    Attributes
    ----------
    z_near : metres; edges are cut at ``z = z_near`` in the camera frame
    samples_per_edge : polyline samples per edge when the camera has lens distortion (1 without)
    front_alpha : opacity of the filled front face
    birds_eye : draw the bird's-eye view beside the overlay
    next_clicks : draw the suggested next clicks (``next_clicks`` in results.json) as targets
    """

    z_near: float = Z_NEAR
    samples_per_edge: int = 16
    front_alpha: float = 0.3
    birds_eye: bool = True
    next_clicks: bool = False


@dataclass(frozen=True)
class DrawnVehicle:
    """One vehicle as the overlay needs it.

    Attributes
    ----------
    id : vehicle id
    ok : fitted (else failed, with ``error``)
    R_cam_vehicle : (3, 3) or None
    t_cam_vehicle : (3,) bottom centre in the camera frame, metres, or None
    dimensions : (3,) ``(dx, dy, dz)`` metres, or None
    clicks_uv : (N, 2) clicked pixels (lens distortion as in the image), possibly empty
    fitted_uv : (N, 2) where the fit puts each click, image pixels, or None when unknown
    downweighted : indices into ``clicks_uv`` of the clicks the robust loss down-weighted
    box2d : (4,) annotated or fitted box ``(x1, y1, x2, y2)``, or None
    label : the short text drawn beside the cuboid
    error : why the fit failed, or None
    sigma_yaw : radians or None; sigma_depth : metres or None (bird's-eye view)
    next_clicks : ``[(label, uv (k, 2)), ...]`` the parts suggested next, best first
    colour : BGR, or None for the palette's colour of its place in the image (:func:`colour_of`)
    """

    id: str
    ok: bool
    R_cam_vehicle: np.ndarray | None = None
    t_cam_vehicle: np.ndarray | None = None
    dimensions: np.ndarray | None = None
    clicks_uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    fitted_uv: np.ndarray | None = None
    downweighted: tuple[int, ...] = ()
    box2d: np.ndarray | None = None
    label: str = ""
    error: str | None = None
    sigma_yaw: float | None = None
    sigma_depth: float | None = None
    next_clicks: tuple[tuple[str, np.ndarray], ...] = ()
    colour: tuple[int, int, int] | None = None


@dataclass(frozen=True)
class DrawnTrack:
    """One track's positions over the frames of its sequence, as the bird's-eye view draws them.

    Attributes
    ----------
    name : the track
    colour : BGR, its vehicle's colour
    xz : (n, 2) bottom centre (``t_cam_vehicle``'s x and z) in each frame's own camera frame, metres, in frame
        order: the motion relative to the camera (which may move itself)
    clicked : (n,) bool, the frames whose pose came from clicks (drawn ringed)
    current : index into ``xz`` of the frame drawn, or None when the track has no pose in it
    """

    name: str
    colour: tuple[int, int, int]
    xz: np.ndarray
    clicked: np.ndarray
    current: int | None = None


@dataclass(frozen=True)
class DrawnCuboid:
    """A ground-truth cuboid in the camera frame of the overlay's ``K`` (``R_cam_vehicle`` (3, 3),
    ``t_cam_vehicle`` (3,) bottom centre, ``dimensions`` (3,)), drawn dashed in white; ``note``, when not empty, is
    written in white above it (e.g. that its pose contradicts the clicks)."""

    R_cam_vehicle: np.ndarray
    t_cam_vehicle: np.ndarray
    dimensions: np.ndarray
    note: str = ""


def colour_of(index: int) -> tuple[int, int, int]:
    """The BGR colour of the ``index``-th vehicle of an image."""
    return PALETTE_BGR[index % len(PALETTE_BGR)]


def _colours(vehicles: Sequence[DrawnVehicle]) -> list[tuple[int, int, int]]:
    """Each vehicle's colour: its own, else :func:`colour_of` its place in the image."""
    return [v.colour if v.colour is not None else colour_of(i) for i, v in enumerate(vehicles)]


def blank_canvas(size: tuple[int, int]) -> np.ndarray:
    """A dark grey (height, width, 3) uint8 canvas for ``size = (width, height)``."""
    width, height = size
    return np.full((height, width, 3), BLANK_GREY, dtype=np.uint8)


def project_polylines(camera: Camera, segments_cam: Sequence[tuple[np.ndarray, np.ndarray]],
                      samples: int, max_radius: float) -> list[np.ndarray]:
    """Project 3D segments already in front of the near plane as image polylines.

    Parameters
    ----------
    segments_cam : pairs of (3,) endpoints in the camera frame, z > 0
    samples : pieces per segment when the camera has lens distortion
    max_radius : normalized radius beyond which distorted samples are dropped
        (:func:`toosicubix.camera.trusted_radius`)

    Returns
    -------
    polylines : list of (k, 2) pixel arrays, k >= 2; a segment that leaves the trusted zone is split, each piece
    running to where the segment crosses the zone's edge (not only to its last sample inside)
    """
    if not segments_cam:
        return []
    n = samples if camera.has_distortion else 1
    s = np.linspace(0.0, 1.0, n + 1)
    runs: list[np.ndarray] = []  # each (k, 3), camera frame
    for a, b in segments_cam:
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        inside = within_radius(a + s[:, None] * (b - a), max_radius)  # (n + 1,)
        edges = np.flatnonzero(np.diff(np.concatenate([[False], inside, [False]])))  # run starts and stops
        for first, stop in zip(edges[0::2], edges[1::2], strict=True):  # samples first .. stop - 1 inside
            ts = list(s[first:stop])
            if first > 0:  # the segment enters the zone between samples first - 1 and first
                ts.insert(0, _zone_edge(a, b, s[first - 1], s[first], max_radius))
            if stop <= n:  # and leaves it between stop - 1 and stop
                ts.append(_zone_edge(a, b, s[stop], s[stop - 1], max_radius))
            if len(ts) >= 2:
                runs.append(a + np.asarray(ts)[:, None] * (b - a))
    if not runs:
        return []
    uv = camera.project(np.concatenate(runs))  # one projection for every run
    return np.split(uv, np.cumsum([len(run) for run in runs])[:-1])


def _zone_edge(a: np.ndarray, b: np.ndarray, s_out: float, s_in: float, max_radius: float) -> float:
    """The parameter between ``s_out`` (outside the zone) and ``s_in`` (inside) where ``a + s (b - a)`` crosses its
    edge, by bisection (30 halvings: a thousandth of a pixel on any image), on the inside."""
    for _ in range(30):
        mid = 0.5 * (s_out + s_in)
        if within_radius((a + mid * (b - a))[None], max_radius)[0]:
            s_in = mid
        else:
            s_out = mid
    return s_in


_FIXED_LIMIT = float(2 ** 28)


def _fixed(uv: np.ndarray) -> np.ndarray:
    """Pixels as OpenCV's fixed-point int32 (``SHIFT`` fractional bits), clamped far outside any image."""
    scaled = np.rint(np.asarray(uv, dtype=float) * (1 << SHIFT))
    if np.abs(scaled).max(initial=0.0) > _FIXED_LIMIT:
        scaled = np.clip(scaled, -_FIXED_LIMIT, _FIXED_LIMIT)
    return scaled.astype(np.int32)


def _dashed(polyline: np.ndarray, dash_px: float = 8.0) -> list[np.ndarray]:
    """Split a (k, 2) polyline into dashes of ``dash_px`` pixels with gaps as long: a list of (2, 2) arrays
    (straight dashes; a dash is short next to any bend of a distorted edge)."""
    steps = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    total = float(steps.sum())
    if total <= dash_px:
        return [polyline]
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    total = min(total, 20000.0)  # a segment running far off the image: its first 20,000 px are plenty
    starts = np.arange(0.0, total, 2.0 * dash_px)
    ts = np.column_stack([starts, np.minimum(starts + dash_px, total)]).ravel()
    ends = np.column_stack([np.interp(ts, arc, polyline[:, 0]), np.interp(ts, arc, polyline[:, 1])])
    return list(ends.reshape(-1, 2, 2))


def _dashed_all(lines: Sequence[np.ndarray], dash_px: float = 8.0) -> list[np.ndarray]:
    """:func:`_dashed` for many polylines; the straight ones (2 points, every edge of a pinhole camera) at once."""
    straight = [p for p in lines if len(p) == 2]
    out = [dash for p in lines if len(p) != 2 for dash in _dashed(p, dash_px)]
    if not straight:
        return out
    ab = np.asarray(straight, dtype=float)  # (n, 2, 2)
    direction = ab[:, 1] - ab[:, 0]
    length = np.linalg.norm(direction, axis=1)
    usable = np.minimum(length, 20000.0)  # as in _dashed
    counts = np.maximum(1, np.ceil(usable / (2.0 * dash_px)).astype(int))
    which = np.repeat(np.arange(len(ab)), counts)
    k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    start = k * 2.0 * dash_px
    end = np.minimum(start + dash_px, usable[which])
    unit = direction[which] / np.maximum(length[which], 1e-12)[:, None]
    origin = ab[which, 0]
    dashes = np.stack([origin + start[:, None] * unit, origin + end[:, None] * unit], axis=1)  # (m, 2, 2)
    return out + list(dashes)


def cuboid_polylines(camera: Camera, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, dimensions: np.ndarray,
                     options: OverlayOptions, max_radius: float) -> tuple[list[np.ndarray], list[np.ndarray],
                                                                         list[np.ndarray]]:
    """The image polylines of a posed cuboid: its 12 edges, its front face's outline, its heading line.

    Parameters
    ----------
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,) bottom centre, metres; dimensions : (3,) ``(dx, dy, dz)``

    Returns
    -------
    edges : polylines (k, 2) of the edges' visible parts
    front : one closed (k, 2) outline of the front face cut at the near plane, or empty
    heading : the polyline from the bottom centre to the front face's bottom centre, or empty
    """
    corners_cam = cuboid_corners_cam(R_cam_vehicle, t_cam_vehicle, dimensions)  # (8, 3)
    segments = [clip_segment_to_near_plane(corners_cam[i], corners_cam[j], options.z_near) for i, j in CUBOID_EDGES]
    edges = project_polylines(camera, [s for s in segments if s is not None], options.samples_per_edge, max_radius)
    face_cam = clip_polygon_to_near_plane(corners_cam[list(FRONT_FACE)], options.z_near)
    front: list[np.ndarray] = []
    if len(face_cam) >= 3:
        ring = [(face_cam[i], face_cam[(i + 1) % len(face_cam)]) for i in range(len(face_cam))]
        pieces = project_polylines(camera, ring, options.samples_per_edge, max_radius)
        if len(pieces) == len(ring):  # the whole outline is drawable
            front = [np.concatenate(pieces)]
    dx = float(np.asarray(dimensions)[0])
    heading_vehicle = np.array([[0.0, 0.0, 0.0], [dx / 2.0, 0.0, 0.0]])
    heading_cam = heading_vehicle @ np.asarray(R_cam_vehicle).T + np.asarray(t_cam_vehicle)
    segment = clip_segment_to_near_plane(heading_cam[0], heading_cam[1], options.z_near)
    heading = project_polylines(camera, [segment], options.samples_per_edge, max_radius) if segment else []
    return edges, front, heading


class _LabelPlacer:
    """Puts text on dark boxes without covering earlier labels: a label that would overlap one is moved a
    line up (then down), up to a few lines, before it is drawn where it was asked."""

    def __init__(self, canvas: np.ndarray):
        self.canvas = canvas
        self.placed: list[tuple[int, int, int, int]] = []

    def put(self, text: str, anchor_uv: tuple[float, float], colour: tuple[int, int, int], scale: float) -> None:
        """``text`` with its bottom-left near ``anchor_uv``, inside the canvas."""
        if not text:
            return
        h, w = self.canvas.shape[:2]
        (tw, th), base = cv2.getTextSize(text, _FONT, scale, 1)
        line = th + base + 3
        x = int(np.clip(anchor_uv[0], 0, max(0, w - tw - 2)))
        y0 = float(anchor_uv[1])
        best: tuple[int, int, tuple[int, int, int, int]] | None = None
        for shift in (0, -1, 1, -2, 2, -3, 3, -4, 4, -5, 5, -6, 6, -8, 8, -10, 10):
            y = int(np.clip(y0 + shift * line, th + 2, max(th + 2, h - base - 1)))
            rect = (x - 1, y - th - 2, x + tw + 1, y + base)
            overlap = sum(max(0, min(rect[2], r[2]) - max(rect[0], r[0]))
                          * max(0, min(rect[3], r[3]) - max(rect[1], r[1])) for r in self.placed)
            if best is None or overlap < best[0]:
                best = (overlap, y, rect)
            if overlap == 0:
                break
        _, y, rect = best
        self.placed.append(rect)
        cv2.rectangle(self.canvas, rect[:2], rect[2:], (0, 0, 0), -1)
        cv2.putText(self.canvas, text, (x, y), _FONT, scale, colour, 1, cv2.LINE_AA)


def _polylines(canvas: np.ndarray, lines: list[np.ndarray], colour: tuple[int, int, int], thickness: int,
               closed: bool = False) -> None:
    if not lines:
        return
    lengths = [len(p) for p in lines]
    fixed = _fixed(np.concatenate(lines))  # one conversion for all: dashed lines come in thousands of pieces
    if min(lengths) == max(lengths):
        pieces = list(fixed.reshape(len(lines), lengths[0], 2))
    else:
        pieces = np.split(fixed, np.cumsum(lengths)[:-1])
    cv2.polylines(canvas, pieces, closed, colour, thickness, cv2.LINE_AA, SHIFT)


def text_scale(height: int) -> float:
    """Font scale for an image ``height`` pixels high: 0.4 for KITTI's 375 px, growing with larger images."""
    return float(np.clip(height / 1000.0, 0.4, 1.2))


def line_thickness(height: int) -> int:
    """Base line thickness in pixels: 1 for KITTI's 375 px, 2 for 720 px, up to 5 for large images."""
    return int(np.clip(round(height / 450.0), 1, 5))


def draw_overlay(canvas: np.ndarray, camera: Camera, vehicles: Sequence[DrawnVehicle],
                 ground_truth: Sequence[DrawnCuboid] = (), options: OverlayOptions | None = None) -> np.ndarray:
    """Draw fitted cuboids, clicks, residuals, failures and ground truth over ``canvas``.

    Parameters
    ----------
    canvas : (H, W, 3) uint8 BGR, drawn on in place and returned
    camera : the camera the poses and clicks refer to (lens distortion is applied)
    vehicles : the vehicles in image order; the ``i``-th gets its ``colour``, else :func:`colour_of` ``(i)``
    ground_truth : cuboids in the same camera frame, drawn dashed in white, each with its note

    Returns
    -------
    canvas
    """
    options = options or OverlayOptions()
    colours = _colours(vehicles)
    size = (canvas.shape[1], canvas.shape[0])
    max_radius = trusted_radius(camera, size)
    scale = text_scale(size[1])
    thick = line_thickness(size[1])
    fills = canvas.copy()
    any_fill = False
    drawn = []
    for i, v in enumerate(vehicles):
        if not (v.ok and v.R_cam_vehicle is not None):
            continue
        edges, front, heading = cuboid_polylines(camera, v.R_cam_vehicle, v.t_cam_vehicle, v.dimensions, options,
                                                 max_radius)
        if front:
            cv2.fillPoly(fills, [_fixed(front[0])], colours[i], cv2.LINE_AA, SHIFT)
            any_fill = True
        drawn.append((i, v, edges, heading))
    if any_fill:
        cv2.addWeighted(fills, options.front_alpha, canvas, 1.0 - options.front_alpha, 0.0, dst=canvas)
    for g in ground_truth:
        edges, _, heading = cuboid_polylines(camera, g.R_cam_vehicle, g.t_cam_vehicle, g.dimensions, options,
                                             max_radius)
        _polylines(canvas, _dashed_all(edges + heading), GROUND_TRUTH_BGR, 1)
    for i, _v, edges, heading in drawn:
        colour = colours[i]
        _polylines(canvas, edges, colour, thick + 1)
        _polylines(canvas, heading, colour, thick + 1)
    labels = _LabelPlacer(canvas)
    for i, v in enumerate(vehicles):
        _draw_clicks(canvas, v, colours[i], thick)
        if options.next_clicks:
            _draw_next_clicks(canvas, v, colours[i], scale, labels)
    for i, v in enumerate(vehicles):
        if v.ok and v.R_cam_vehicle is not None:
            anchor = _label_anchor(camera, v, max_radius, options.z_near)
            if anchor is not None:
                labels.put(v.label, anchor, colours[i], scale)
        else:
            _draw_failed(canvas, v, scale, thick, labels)
    for g in ground_truth:  # after the fits' labels, which keep their places
        anchor = _label_anchor(camera, g, max_radius, options.z_near) if g.note else None
        if anchor is not None:
            labels.put(g.note, anchor, GROUND_TRUTH_BGR, scale)
    return canvas


def _label_anchor(camera: Camera, v: DrawnVehicle | DrawnCuboid, max_radius: float,
                  z_near: float) -> tuple[float, float] | None:
    """Above the projected cuboid's top-left, or None when no corner is in view."""
    corners_cam = cuboid_corners_vehicle(v.dimensions) @ v.R_cam_vehicle.T + v.t_cam_vehicle
    seen = corners_cam[(corners_cam[:, 2] >= z_near)
                       & (np.hypot(corners_cam[:, 0], corners_cam[:, 1]) <= max_radius * corners_cam[:, 2])]
    if len(seen) == 0:
        return None
    uv = camera.project(seen)
    return float(uv[:, 0].min()), float(uv[:, 1].min()) - 4.0


def _draw_clicks(canvas: np.ndarray, v: DrawnVehicle, colour: tuple[int, int, int], thick: int) -> None:
    radius = 3 + thick
    for k, uv in enumerate(v.clicks_uv):
        if v.fitted_uv is not None and np.all(np.isfinite(v.fitted_uv[k])):
            cv2.line(canvas, tuple(_fixed(uv)), tuple(_fixed(v.fitted_uv[k])), RESIDUAL_BGR, thick, cv2.LINE_AA, SHIFT)
        centre = tuple(_fixed(uv))
        cv2.circle(canvas, centre, radius << SHIFT, (0, 0, 0), -1, cv2.LINE_AA, SHIFT)
        cv2.circle(canvas, centre, (radius - 1) << SHIFT, colour, -1, cv2.LINE_AA, SHIFT)
        if k in v.downweighted:  # a red cross and ring: the robust loss gave this click less weight
            r = radius + 3
            x, y = uv
            for a, b in (((x - r, y - r), (x + r, y + r)), ((x - r, y + r), (x + r, y - r))):
                cv2.line(canvas, tuple(_fixed(a)), tuple(_fixed(b)), DOWNWEIGHTED_BGR, thick + 1, cv2.LINE_AA, SHIFT)
            cv2.circle(canvas, centre, r << SHIFT, DOWNWEIGHTED_BGR, thick, cv2.LINE_AA, SHIFT)


def _draw_next_clicks(canvas: np.ndarray, v: DrawnVehicle, colour: tuple[int, int, int], scale: float,
                      labels: _LabelPlacer) -> None:
    for rank, (label, uv) in enumerate(v.next_clicks, start=1):
        points = np.asarray(uv, dtype=float).reshape(-1, 2)
        for p in points:
            c = tuple(_fixed(p))
            cv2.circle(canvas, c, 9 << SHIFT, colour, 1, cv2.LINE_AA, SHIFT)
            cv2.circle(canvas, c, 4 << SHIFT, colour, 1, cv2.LINE_AA, SHIFT)
        if len(points) == 2:
            cv2.arrowedLine(canvas, tuple(_fixed(points[0])), tuple(_fixed(points[1])), colour, 1, cv2.LINE_AA,
                            SHIFT, 0.2)
        x, y = points[0]
        labels.put(f"{rank}. {label}", (x + 11, y - 6), colour, scale * 0.85)


def _draw_failed(canvas: np.ndarray, v: DrawnVehicle, scale: float, thick: int, labels: _LabelPlacer) -> None:
    """A red box round the vehicle's 2D box (else its clicks), with the reason."""
    if v.box2d is not None:
        box = np.asarray(v.box2d, dtype=float)
    elif len(v.clicks_uv):
        box = np.concatenate([v.clicks_uv.min(axis=0) - 8.0, v.clicks_uv.max(axis=0) + 8.0])
    else:
        return
    cv2.rectangle(canvas, tuple(_fixed(box[:2])), tuple(_fixed(box[2:])), FAILED_BGR, thick + 1, cv2.LINE_AA, SHIFT)
    reason = (v.error or "no reason given").splitlines()[0]
    if len(reason) > 70:
        reason = reason[:67] + "..."
    labels.put(f"{v.id} failed: {reason}", (box[0], box[1] - 4.0), FAILED_BGR, scale)


# --- bird's-eye view ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _BevFrame:
    """Camera x (right) and z (forward), metres, to panel pixels: ``u = u0 + s x``, ``v = v0 - s z``."""

    s: float
    u0: float
    v0: float

    def uv(self, xz: np.ndarray) -> np.ndarray:
        xz = np.asarray(xz, dtype=float).reshape(-1, 2)
        return np.column_stack([self.u0 + self.s * xz[:, 0], self.v0 - self.s * xz[:, 1]])


def _nice_step(span: float) -> float:
    for step in (5.0, 10.0, 20.0, 50.0, 100.0):
        if span / step <= 8:
            return step
    return 200.0


@dataclass(frozen=True)
class BirdsEyeLayout:
    """Where things go in a bird's-eye panel (:func:`birds_eye_layout`).

    Attributes
    ----------
    width, height : the panel's size, pixels
    frame : camera x and z, metres, to panel pixels
    z_max, x_half : metres shown ahead and to each side
    scale : font scale; m : how much larger than on KITTI's 375 px panel everything is drawn; lw : line width
    margin_left, margin_bottom, margin_top : pixels round the plot (tick labels, axis names, title)
    """

    width: int
    height: int
    frame: _BevFrame
    z_max: float
    x_half: float
    scale: float
    m: float
    lw: int
    margin_left: int
    margin_bottom: int
    margin_top: int


def _footprints_xz(vehicles: Sequence[DrawnVehicle]) -> list[tuple[int, np.ndarray, DrawnVehicle]]:
    """``(index, (4, 2) footprint corners' camera x and z, vehicle)`` of each fitted vehicle."""
    out = []
    for i, v in enumerate(vehicles):
        if v.ok and v.R_cam_vehicle is not None:
            out.append((i, cuboid_corners_cam(v.R_cam_vehicle, v.t_cam_vehicle, v.dimensions)[:4][:, [0, 2]], v))
    return out


def birds_eye_layout(side: int, vehicles: Sequence[DrawnVehicle], ground_truth: Sequence[DrawnCuboid] = (),
                     height: int | None = None, tracks: Sequence[DrawnTrack] = ()) -> BirdsEyeLayout:
    """The scale and placement of the panel :func:`draw_birds_eye` draws for the same arguments: the view holds
    the camera, every footprint, and every track's positions that are not behind the camera (z > -2 m).

    Parameters
    ----------
    side : the panel's width (and height unless ``height`` is given), pixels
    height : a taller panel's height, pixels
    """
    width = side
    height = side if height is None else max(int(height), side)
    gt_prints = [cuboid_corners_cam(g.R_cam_vehicle, g.t_cam_vehicle, g.dimensions)[:4][:, [0, 2]]
                 for g in ground_truth]
    track_xz = [t.xz[t.xz[:, 1] > -2.0] for t in tracks]
    all_xz = np.concatenate([f[1] for f in _footprints_xz(vehicles)] + gt_prints + track_xz + [np.zeros((1, 2))])
    z_max = max(20.0, float(np.max(all_xz[:, 1])) * 1.1)
    x_half = max(z_max / 2.0, float(np.max(np.abs(all_xz[:, 0]))) * 1.1)
    scale = float(np.clip(width / 1000.0, 0.38, 1.2))
    m = scale / 0.38  # everything grows with the text
    lw = max(1, round(m))
    margin_left, margin_bottom, margin_top = int(34 * m), int(34 * m), int(22 * m)
    usable = width - margin_left - 8
    s = min(usable / (2.0 * x_half), (height - margin_bottom - margin_top) / (z_max + 2.0))
    z_max = max(z_max, (height - margin_bottom - margin_top) / s - 2.0)  # a tall panel shows farther ahead
    frame = _BevFrame(s, margin_left + usable / 2.0, height - margin_bottom - 2.0 * s)
    return BirdsEyeLayout(width, height, frame, z_max, x_half, scale, m, lw, margin_left, margin_bottom, margin_top)


#: The caption of a bird's-eye panel with tracks, line by line.
TRACKS_CAPTION = ("tracks: positions relative", "to the camera, every frame", "ring: clicked frame",
                  "big dot: this frame")


def draw_birds_eye(side: int, camera: Camera, vehicles: Sequence[DrawnVehicle],
                   ground_truth: Sequence[DrawnCuboid] = (), image_width: int | None = None,
                   height: int | None = None, tracks: Sequence[DrawnTrack] = ()) -> np.ndarray:
    """A top view of the camera's x-z plane: each cuboid's footprint with its heading, depth and yaw sigmas, and
    each track's positions over its sequence.

    The footprint is the bottom face's corners with their camera y dropped (exact for a level camera).
    Depth sigma: a bar along the ray through the footprint's centre, from ``z - sigma`` to ``z + sigma``.
    Yaw sigma: two thin lines from the centre at the heading plus and minus sigma.
    A track: a thin polyline through its bottom centres in frame order, a dot per frame, a ring round the frames
    whose pose came from clicks, a larger dot at this frame's position; drawn under the footprints and cut at the
    plot's edges, with a caption saying that the positions are relative to the (perhaps moving) camera.

    Parameters
    ----------
    side : the panel's width (and height unless ``height`` is given), pixels
    image_width : to draw the camera's field of view, or None
    height : a taller panel's height, pixels (beside a tall image): the view then reaches farther forward at
        the scale its width allows, instead of leaving the space below empty
    tracks : the tracks of the image's vehicles (positions in each frame's camera frame, metres)

    Returns
    -------
    (height, side, 3) uint8 BGR panel

    See Also
    --------
    birds_eye_layout : the panel's scale and placement
    """
    layout = birds_eye_layout(side, vehicles, ground_truth, height, tracks)
    width, height, frame = layout.width, layout.height, layout.frame
    z_max, x_half, scale, m, lw = layout.z_max, layout.x_half, layout.scale, layout.m, layout.lw
    margin_left, margin_bottom, margin_top = layout.margin_left, layout.margin_bottom, layout.margin_top
    panel = np.full((height, width, 3), PANEL_GREY, dtype=np.uint8)
    colours = _colours(vehicles)
    footprints = _footprints_xz(vehicles)
    gt_prints = [cuboid_corners_cam(g.R_cam_vehicle, g.t_cam_vehicle, g.dimensions)[:4][:, [0, 2]]
                 for g in ground_truth]
    step = _nice_step(max(z_max, 2.0 * x_half))
    grid = (70, 70, 70)
    for z in np.arange(0.0, z_max + 1e-9, step):
        a, b = frame.uv([[-x_half * 2, z], [x_half * 2, z]])
        cv2.line(panel, tuple(_fixed(a)), tuple(_fixed(b)), grid, 1, cv2.LINE_AA, SHIFT)
        y = frame.uv([[0.0, z]])[0, 1]
        if margin_top <= y <= height - margin_bottom + 4:
            cv2.putText(panel, f"{z:g}", (2, int(y + 4 * m)), _FONT, scale, TEXT_BGR, lw, cv2.LINE_AA)
    for x in np.arange(-np.floor(x_half / step) * step, x_half + 1e-9, step):
        a, b = frame.uv([[x, -2.0], [x, z_max * 2]])
        cv2.line(panel, tuple(_fixed(a)), tuple(_fixed(b)), grid, 1, cv2.LINE_AA, SHIFT)
        u = frame.uv([[x, 0.0]])[0, 0]
        if margin_left <= u <= width - 10:
            label = f"{x + 0.0:g}"  # + 0.0: the tick at -0.0 reads "0"
            cv2.putText(panel, label, (int(u - 8 * m), int(height - margin_bottom + 16 * m)), _FONT, scale, TEXT_BGR,
                        lw, cv2.LINE_AA)
    cv2.putText(panel, "x (m, right)", (int(width / 2 - 40 * m), int(height - 4 * m)), _FONT, scale, TEXT_BGR, lw,
                cv2.LINE_AA)
    cv2.putText(panel, "z (m) forward, top view", (margin_left, int(15 * m)), _FONT, scale, TEXT_BGR, lw,
                cv2.LINE_AA)
    if image_width is not None:
        K = camera.K
        for u_px in (0.0, image_width - 1.0):
            x_per_z = (u_px - K[0, 2]) / K[0, 0]
            a, b = frame.uv([[0.0, 0.0], [x_per_z * z_max * 3, z_max * 3]])
            cv2.line(panel, tuple(_fixed(a)), tuple(_fixed(b)), (110, 110, 110), 1, cv2.LINE_AA, SHIFT)
    cam = frame.uv([[0.0, 0.0]])[0]
    cv2.circle(panel, tuple(_fixed(cam)), int(3 * m) << SHIFT, TEXT_BGR, -1, cv2.LINE_AA, SHIFT)
    for corners in gt_prints:
        _polylines(panel, _dashed(np.vstack([frame.uv(corners), frame.uv(corners[:1])]), 5.0), GROUND_TRUTH_BGR, 1)
    if tracks:
        _draw_tracks(panel, layout, tracks)
    labels = _LabelPlacer(panel)
    for i, corners, v in footprints:
        colour = colours[i]
        _polylines(panel, [frame.uv(corners)], colour, lw + 1, closed=True)
        centre = corners.mean(axis=0)
        front = corners[[0, 3]].mean(axis=0)
        _polylines(panel, [frame.uv(np.array([centre, front]))], colour, lw + 1)
        if v.sigma_yaw is not None and np.isfinite(v.sigma_yaw):
            heading = np.arctan2(front[1] - centre[1], front[0] - centre[0])
            reach = max(float(np.linalg.norm(front - centre)) * 1.6, 1.5)
            for sign in (-1.0, 1.0):
                a = heading + sign * min(v.sigma_yaw, np.pi)
                tip = centre + reach * np.array([np.cos(a), np.sin(a)])
                _polylines(panel, [frame.uv(np.array([centre, tip]))], colour, lw)
        if v.sigma_depth is not None and np.isfinite(v.sigma_depth) and centre[1] > 0:
            ray = centre / np.linalg.norm(centre)
            depth = float(np.linalg.norm(centre))
            sd = float(v.sigma_depth) * depth / max(centre[1], 1e-6)  # sigma of z -> along the ray
            near, far = centre - sd * ray, centre + sd * ray
            _polylines(panel, [frame.uv(np.array([near, far]))], colour, lw)
            normal = np.array([-ray[1], ray[0]]) * (3.0 * m / frame.s)
            for end in (near, far):
                _polylines(panel, [frame.uv(np.array([end - normal, end + normal]))], colour, lw)
        label_uv = frame.uv(corners).max(axis=0)  # beside the footprint, moved off earlier labels, in the panel
        labels.put(v.id, (label_uv[0] + 2 * m, label_uv[1]), colour, scale)
    for track in tracks:  # this frame's position over its footprint's outline, ringed in black
        if track.current is not None:
            centre = tuple(_fixed(frame.uv(track.xz[track.current])[0]))
            r = 3.5 * m
            cv2.circle(panel, centre, round((r + 1.5) * (1 << SHIFT)), (0, 0, 0), -1, cv2.LINE_AA, SHIFT)
            cv2.circle(panel, centre, round(r * (1 << SHIFT)), track.colour, -1, cv2.LINE_AA, SHIFT)
            if track.clicked[track.current]:  # its ring, which the dot covers, round the dot
                cv2.circle(panel, centre, round((r + 3.5) * (1 << SHIFT)), track.colour, lw, cv2.LINE_AA, SHIFT)
    return panel


def _draw_tracks(panel: np.ndarray, layout: BirdsEyeLayout, tracks: Sequence[DrawnTrack]) -> None:
    """Each track's polyline, dots and rings, cut at the plot's edges (never over the axes' labels), and the
    caption in the plot's bottom-left corner (outside the camera's view, where nothing visible stands)."""
    m, frame = layout.m, layout.frame
    left, bottom = layout.margin_left, layout.height - layout.margin_bottom  # the plot: z >= -2 m, right of ticks
    plot = panel[:bottom, left:]  # a view: drawing on it draws on the panel
    offset = np.array([left, 0.0])
    dot, ring = 1.6 * m, 4.0 * m
    for track in tracks:
        uv = frame.uv(track.xz) - offset
        if len(uv) >= 2:
            _polylines(plot, [uv], track.colour, 1)
        for k, p in enumerate(uv):
            centre = tuple(_fixed(p))
            cv2.circle(plot, centre, round(dot * (1 << SHIFT)), track.colour, -1, cv2.LINE_AA, SHIFT)
            if track.clicked[k]:
                cv2.circle(plot, centre, round(ring * (1 << SHIFT)), track.colour, max(1, round(m)), cv2.LINE_AA,
                           SHIFT)
    # The caption: bottom left, left of the camera, shrunk to fit there.
    room = frame.u0 - 6.0 * m - (left + 2)
    caption_scale = layout.scale * 0.8
    widest = max(cv2.getTextSize(line, _FONT, caption_scale, 1)[0][0] for line in TRACKS_CAPTION)
    caption_scale *= min(1.0, room / widest)
    (_, th), base = cv2.getTextSize(TRACKS_CAPTION[0], _FONT, caption_scale, 1)
    y = bottom - base - 2
    for line in reversed(TRACKS_CAPTION):
        cv2.putText(panel, line, (left + 2, int(y)), _FONT, caption_scale, TEXT_BGR, 1, cv2.LINE_AA)
        y -= th + base + 2


def compose(overlay: np.ndarray, panel: np.ndarray | None) -> np.ndarray:
    """The overlay with the bird's-eye panel to its right, the shorter of the two padded below in black."""
    if panel is None:
        return overlay
    height = max(overlay.shape[0], panel.shape[0])
    out = np.zeros((height, overlay.shape[1] + panel.shape[1], 3), dtype=np.uint8)
    out[:overlay.shape[0], :overlay.shape[1]] = overlay
    out[:panel.shape[0], overlay.shape[1]:] = panel
    return out


def birds_eye_side(image_height: int) -> int:
    """The bird's-eye panel's width for an image: its height, kept within 360-1400 px (the panel is as tall as
    the image, and at least this)."""
    return int(np.clip(image_height, 360, 1400))
