"""The 2D box a person draws around a vehicle whose true cuboid is known, and KITTI's own box for comparison.

KITTI's 2D boxes are its 3D boxes' projections (clipped to the image), which no person or detector draws: a person's
box hugs the vehicle's silhouette, which lies inside the projected cuboid (rounded corners, a narrower roof, tyres
set in from the sides), and is a pixel or two off. A box cue tuned on KITTI's boxes is tuned on the answer; this
module simulates the person's box instead (:func:`simulated_box2d`, ``kind="person"``) and gives KITTI's kind of
box too (``kind="projection"``).

**The silhouette.** The vehicle is a solid inside its cuboid (vehicle frame: X forward, Y left, Z up, origin at the
bottom centre; ``L, W, H = dx, dy, dz``), made of convex pieces, each a loft of horizontal rings (:class:`BodyShape`
holds one vehicle's draw, :func:`body_pieces` builds it):

- a car (any prototype but the box-shaped ones below, so KITTI's ``Car``): a lower body over the full length and
  width from the ground clearance to the belt line, its vertical corners rounded in plan (radius a share of the
  width), its bottom front and rear edges chamfered (a bumper undercut), its sides tucked under at the sill and
  drawn in to the shoulder at the belt line, its nose and tail set back at the belt line; a greenhouse from the
  belt line (shorter and narrower than the body) tapering to a roof edge (narrower still: tumblehome) and a crowned
  roof top at the full height; four wheels (16-gon cylinders) on the ground inside the body's width;
- a van (``Van``, ``Small Van``, ``Large Van``, ``Box Wagon``, ``Caravan``): a boxy lower body up to a short hood,
  then one upper body with a raked windscreen and a nearly full-width, nearly full-length roof (little tumblehome),
  small corner radii;
- a truck (the other box-shaped prototypes, ``Truck`` and the buses among them, and ``Tram``): a box with small
  rounded corners, its front top edge chamfered, a full-length roof at nearly the full width.

Each shape parameter is drawn per vehicle, uniformly from its range in :data:`SHAPE_RANGES` (shares of ``L``, ``W``
or ``H``). Sources of the car ranges:

- belt line at 0.58-0.70 H: the car-design rule of thumb of a greenhouse about a third and a body two thirds of the
  height (carbrandexperts.com, "Proportion of a city car": "a balanced 1/3 to 2/3 ratio"; carstylecritic.blogspot.com,
  "Want to look sporty? Chop the greenhouse", 2022: the greenhouse "fairly tall, comprising more than a third of
  total body height", sporty ones lower), and the people's clicks on ApolloCar3D's front doors' top front and middle
  corners, 0.60-0.68 H (the project's learned part positions, ``toosicubix/parts/mappings/apollocar3d-66.json``,
  built by ``toosicubix learn-parts`` from human clicks with CAD-fitted metric poses);
- roof edge 0.58-0.74 W wide at 0.86-0.94 H: greenhouses taper inward from bottom to top ("tumblehome", Wikipedia
  "Greenhouse (car)"; core77.com, "Car design terms that sound like cocktail names: tumblehome": the sportier, the
  more) by how much no published source found here says in numbers, so the range is the clicks' on ApolloCar3D:
  windscreen and rear-window top corners at +-0.30-0.33 W (a roof 0.60-0.66 W wide), the front doors' top rear
  corners at +-0.32-0.36 W (0.64-0.72 W), all at 0.87-0.93 H; the greenhouse's base is 0.82-0.90 W wide (front-door
  top front corners at +-0.43-0.45 W);
- greenhouse base from 0.16-0.28 L ahead of the centre (A-pillar base; clicks 0.18-0.20 L) to 0.28-0.46 L behind it
  (C-pillar base of a saloon to the tailgate of a hatchback); roof edge set in from these by the windscreen's run
  0.08-0.18 L and the rear window's 0.03-0.10 L (clicks: windscreen top 0.07-0.11 L, rear-window top -0.24 L on
  saloons, -0.38 to -0.39 L on hatchbacks and SUVs);
- vertical body corners rounded with a radius of 0.15-0.30 W in plan: designers round the corners in plan view to
  hide the overhangs (automotivedesign.biz, "Basic car design", 2015: "large front and rear overhangs ... are hidden
  by rounding the corners of the car in plan view"); clicked rear-bumper corners sit at +-0.33 W, 0.03-0.04 L ahead
  of the rear, the lights' outer corners 0.07 W in from the sides at 0.09-0.12 L from the ends;
- bottom edges chamfered up to 0.15-0.25 H, the lowest 0.02-0.06 L set back (clicked plate bottoms at the very
  front at 0.17-0.27 H, rear bumper corners at 0.14-0.22 H); ground clearance 0.08-0.13 H; sill tuck-under
  0.01-0.04 W ("tuck under", techzle.com, car designer Niels van Roij); shoulder at the belt line 0.90-0.96 W
  (clicked door handles at +-0.47-0.49 W); nose and tail 0.03-0.09 L behind the ends at the belt line (clicked
  headlight tops 0.05 L behind the front at 0.46-0.52 H, tail-light tops 0.09 L ahead of the rear at 0.63-0.65 H);
- wheels of radius 0.16-0.22 H (height about three wheel diameters for saloons, formtrends.com, "Getting the
  wheels in the right place"; about 2.5 for hatchbacks, car designer Berk Kaplan in autoevolution.com, "Perfect car
  proportions explained with German hatchbacks"; clicked wheel centres at 0.18-0.19 H on saloons and SUVs,
  0.11-0.14 H on hatchbacks), axles placed by the overhangs the click simulator uses (front 0.17-0.24 L, rear
  0.18-0.26 L; clicked wheel centres at +-0.27-0.32 L),
  tyres 0.11-0.14 W wide with their outer faces 0-5 cm inside the body's sides (the click simulator's
  ``TYRE_INSET_MAX``).

Vans and trucks have little or no tumblehome ("on cargo vans, tumblehome is minimal or non-existent", uxdesign.cc,
"Five more weird car design terms, explained"); their ranges (:data:`SHAPE_RANGES`) are this module's own choice,
not measured. All figures of the ApolloCar3D clicks above are read from that mapping file's ``at`` positions (per
keypoint, the point nearest in least squares to every click's ray, in each car's frame; the ranges span its
prototypes: Car = ApolloCar3D's hatchbacks, Sedan, SUV).

**The box.** The solid's vertices (7 per rounded corner, 16 per wheel rim) and the points where its ring, loft and
diagonal edges cross the camera's near plane (:data:`toosicubix.geometry.Z_NEAR`) are projected; their extent,
clipped to the image (``[0, width - 1] x [0, height - 1]``, KITTI's convention), is the silhouette's box, None when it
misses the image or is under ``MIN_BOX_SIDE_PX`` wide or high. KITTI's box (``kind="projection"``) is the same with
the cuboid's 8 corners.

**The person's own error.** Each side is moved by an independent Gaussian with standard deviation 1 px plus 1 % of
the box's size along that side's axis (width for the left and right sides, height for top and bottom), then the box
is clipped to the image again and rounded to 0.1 px. The 1 px is where a careful click lands on a sharp edge at 1:1
zoom; the 1 % is the edge's own ambiguity, which grows with the vehicle's size in the image (soft shadows under the
body, antialiased and blurred edges, mirrors, aerials). Both are this module's choice, not measured: a person
clicking a box's imaginary corners needs several adjustments to make it tight (Papadopoulos et al., "Extreme
clicking for efficient object annotation", ICCV 2017), which these figures assume was done. A side the image border
cuts stays at the border, as a person's would; a pair of sides that noise would bring within ``MIN_BOX_SIDE_PX`` of
each other keeps its noise-free place.

**Measured on KITTI tracking's tuning split** (sequences 0000-0009, the vehicles that ``toosicubix simulate
--tracks`` selects with its default filters):

``python -m toosicubix.simulate.boxes ../shared/data/kitti_tracking --sequences 0000-0009`` (seed 0; 8,350 frames of
346 tracks: 7,090 Car, 592 Van, 668 Truck boxes; KITTI's boxes 85 x 53 px, median). How far each side of a box lies
inside KITTI's box (negative: outside), median [10th, 90th percentile]:

=========================  ===================  ===================  ===================  ===================
box                        left                 top                  right                bottom
=========================  ===================  ===================  ===================  ===================
person, px                 2.51 [-0.30, 8.67]   0.68 [-1.47, 3.29]   1.97 [-0.83, 7.85]   1.55 [-0.70, 8.98]
person, % of width/height  3.0 [-0.6, 6.8]      1.2 [-3.0, 5.2]      2.4 [-1.3, 5.9]      3.3 [-1.8, 8.4]
silhouette (no error), px  2.43 [0.59, 7.94]    0.54 [0.06, 1.96]    1.88 [0.16, 7.13]    1.19 [0.29, 8.82]
silhouette, %              2.7 [1.2, 5.5]       1.0 [0.1, 2.5]       2.2 [0.3, 4.5]       2.5 [0.8, 7.3]
projection, px             0.44 [0.16, 1.03]    0.05 [-0.63, 1.21]   0.00 [-0.03, 0.02]   -0.43 [-1.29, 0.00]
=========================  ===================  ===================  ===================  ===================

The last row is this module's ``kind="projection"`` against KITTI's labels: KITTI's boxes are the clipped
projections to within a pixel. The person's box is a median 2-2.5 px narrower on each side and 0.7 px lower at the
top (KITTI's camera, 1.65 m up, sees 1.5 m cars nearly edge-on, so the roof's shape moves the top side little);
the sides move most on near vehicles, the bottom most of all (its lowest points are tyres and a chamfered bumper,
set in from the cuboid's bottom corners): the silhouette's bottom side lies a median 12.6 px inside under 10 m depth
(742 boxes), 4.5 px at 10-20 m, 0.9 px at 20-40 m, 0.4 px beyond (same run, binned by the bottom centre's depth).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from toosicubix import vocabulary
from toosicubix.camera import Camera
from toosicubix.geometry import Z_NEAR, clip_cuboid_to_near_plane, cuboid_corners_cam

#: The kinds of box :func:`simulated_box2d` draws.
BOX_KINDS = ("person", "projection")
#: A person's box: standard deviation of each side's error, pixels plus a share of the box's size on that axis.
SIDE_NOISE_PX = 1.0
SIDE_NOISE_SHARE = 0.01
#: A person's box is drawn to this many decimals of a pixel.
BOX_DECIMALS = 1
#: A silhouette narrower or lower than this (pixels, after clipping to the image) is not boxed.
MIN_BOX_SIDE_PX = 1.0
#: How far, at most, the outer faces of the tyres sit inside the body's sides (metres; as the click simulator's
#: ``toosicubix.simulate.annotator.TYRE_INSET_MAX``, which a test keeps equal).
TYRE_INSET_MAX = 0.05
#: Points per rounded corner of a ring (the chords stay within 1 % of the radius of the arc) and per wheel rim
#: (within 2 %).
ARC_POINTS = 7
WHEEL_POINTS = 16

#: Prototypes built as vans.
VAN_PROTOTYPES = frozenset({"Van", "Small Van", "Large Van", "Box Wagon", "Caravan"})
#: Prototypes built as trucks besides the vocabulary's other box-shaped ones; any other prototype is a car.
TRUCK_PROTOTYPES_EXTRA = frozenset({"Tram"})

#: Each shape parameter's range (uniform, one draw per vehicle), by family; shares of L (``*_l``), W (``*_w``) or
#: H (``*_h``), or of another parameter where named. Sources: the module's description.
SHAPE_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "car": {
        "clearance_h": (0.08, 0.13),       # body bottom above the ground
        "undercut_l": (0.02, 0.06),        # bottom front and rear edges set back ...
        "chamfer_h": (0.15, 0.25),         # ... up to this height, where the body reaches the full length
        "tuck_w": (0.01, 0.04),            # sill drawn in, per side
        "belt_h": (0.58, 0.70),            # belt line
        "shoulder_w": (0.90, 0.96),        # body width at the belt line
        "nose_l": (0.03, 0.09),            # front end set back at the belt line
        "tail_l": (0.03, 0.09),            # rear end likewise
        "corner_w": (0.15, 0.30),          # plan-view radius of the vertical corners
        "base_w": (0.82, 0.90),            # greenhouse width at the belt line
        "base_front_l": (0.16, 0.28),      # greenhouse front (A-pillar base), ahead of the centre
        "base_rear_l": (0.28, 0.46),       # greenhouse rear, behind the centre
        "screen_run_l": (0.08, 0.18),      # windscreen's run: roof front = base front - this
        "backlight_run_l": (0.03, 0.10),   # rear window's run: roof rear = base rear - this
        "roof_w": (0.58, 0.74),            # roof edge width
        "roof_h": (0.86, 0.94),            # roof edge height
        "crown_w": (0.40, 0.80),           # roof top (at H) width, share of the roof edge's
        "crown_l": (0.60, 0.90),           # roof top length, share of the roof edge's
        "wheel_h": (0.16, 0.22),           # wheel radius
        "front_overhang_l": (0.17, 0.24),
        "rear_overhang_l": (0.18, 0.26),
        "tyre_w": (0.11, 0.14),            # tyre width
    },
    "van": {
        "clearance_h": (0.06, 0.10),
        "undercut_l": (0.01, 0.03),
        "chamfer_h": (0.10, 0.18),
        "tuck_w": (0.00, 0.02),
        "hood_h": (0.40, 0.55),            # hood (bonnet) height: the lower body's top
        "hood_l": (0.05, 0.20),            # hood length: the upper body starts this far behind the front
        "tail_l": (0.00, 0.03),
        "corner_w": (0.05, 0.14),
        "screen_run_l": (0.06, 0.15),
        "roof_w": (0.84, 0.96),
        "roof_h": (0.92, 0.98),
        "crown_w": (0.60, 0.90),
        "crown_l": (0.85, 0.98),
        "wheel_h": (0.13, 0.18),
        "front_overhang_l": (0.17, 0.24),
        "rear_overhang_l": (0.20, 0.35),
        "tyre_w": (0.10, 0.13),
    },
    "truck": {
        "clearance_h": (0.08, 0.14),
        "undercut_l": (0.00, 0.02),
        "chamfer_h": (0.10, 0.18),
        "tuck_w": (0.00, 0.02),
        "front_top_l": (0.01, 0.06),       # cab's front top edge chamfered (45 degrees) back by this
        "tail_l": (0.00, 0.02),
        "corner_w": (0.02, 0.08),
        "roof_w": (0.90, 0.99),
        "roof_h": (0.94, 0.99),
        "crown_w": (0.70, 0.95),
        "crown_l": (0.90, 0.99),
        "wheel_h": (0.10, 0.16),
        "front_overhang_l": (0.10, 0.15),
        "rear_overhang_l": (0.20, 0.35),
        "tyre_w": (0.10, 0.13),
    },
}


@dataclass(frozen=True)
class BodyShape:
    """One vehicle's solid: its family ('car', 'van' or 'truck') and its drawn parameters (:data:`SHAPE_RANGES`'
    names, shares of the cuboid's dimensions), and the tyres' inset from the body's sides in metres."""

    family: str
    params: dict[str, float]
    tyre_inset: float


def body_family(prototype: str) -> str:
    """'van', 'truck' or 'car': how a prototype's silhouette is built (see the module's description)."""
    if prototype in VAN_PROTOTYPES:
        return "van"
    if prototype in vocabulary.PROTOTYPE_GROUPS["box-shaped"] or prototype in TRUCK_PROTOTYPES_EXTRA:
        return "truck"
    return "car"


def draw_body_shape(prototype: str, rng: np.random.Generator) -> BodyShape:
    """One vehicle's shape parameters, each uniform in its range (in :data:`SHAPE_RANGES`' order), then the tyre
    inset, uniform in ``[0, TYRE_INSET_MAX]``."""
    family = body_family(prototype)
    params = {name: float(rng.uniform(lo, hi)) for name, (lo, hi) in SHAPE_RANGES[family].items()}
    return BodyShape(family, params, float(rng.uniform(0.0, TYRE_INSET_MAX)))


def _ring(x_rear: float, x_front: float, half_width: float, radius: float, z: float) -> np.ndarray:
    """A horizontal rounded rectangle at height ``z`` (vehicle frame): (4 * ARC_POINTS, 3), counter-clockwise
    from above, starting at the front-left corner's arc. The radius shrinks to fit."""
    radius = max(0.0, min(radius, (x_front - x_rear) / 2.0, half_width))
    angles = np.linspace(0.0, np.pi / 2.0, ARC_POINTS)
    centres = ((x_front - radius, half_width - radius), (x_rear + radius, half_width - radius),
               (x_rear + radius, -half_width + radius), (x_front - radius, -half_width + radius))
    points = []
    for k, (cx, cy) in enumerate(centres):
        a = angles + k * np.pi / 2.0
        points.append(np.column_stack([cx + radius * np.cos(a), cy + radius * np.sin(a), np.full(ARC_POINTS, z)]))
    return np.concatenate(points)


def _wheels(shape: BodyShape, d: np.ndarray) -> list[np.ndarray]:
    """Four cylinders standing on the ground, each (2, WHEEL_POINTS, 3): outer and inner rim."""
    L, W, H = d
    p = shape.params
    x_front = L * (0.5 - p["front_overhang_l"])
    x_rear = -L * (0.5 - p["rear_overhang_l"])
    radius = min(p["wheel_h"] * H, L * p["front_overhang_l"], L * p["rear_overhang_l"], H / 2.0)
    y_out = max(W / 2.0 - shape.tyre_inset, 0.0)
    y_in = max(y_out - p["tyre_w"] * W, 0.0)
    a = np.linspace(0.0, 2.0 * np.pi, WHEEL_POINTS, endpoint=False)
    out = []
    for x in (x_front, x_rear):
        for sign in (1.0, -1.0):
            rims = [np.column_stack([x + radius * np.cos(a), np.full(WHEEL_POINTS, sign * y),
                                     radius + radius * np.sin(a)]) for y in (y_out, y_in)]
            out.append(np.stack(rims))
    return out


def body_pieces(shape: BodyShape, dimensions: np.ndarray) -> list[np.ndarray]:
    """The solid of a vehicle of ``dimensions`` (3,) ``(dx, dy, dz)``: its convex pieces in the vehicle frame, each
    (rings, points, 3), rings bottom to top, ring ``i`` point ``k`` lofted to ring ``i + 1`` point ``k``. Every point
    lies inside the cuboid."""
    L, W, H = (float(v) for v in dimensions)
    p = shape.params
    radius = p["corner_w"] * W
    half = W / 2.0
    tuck = p["tuck_w"] * W
    bottom = _ring(-L / 2 + p["undercut_l"] * L, L / 2 - p["undercut_l"] * L, half - tuck, radius,
                   p["clearance_h"] * H)
    chamfer = _ring(-L / 2, L / 2, half, radius, max(p["chamfer_h"], p["clearance_h"]) * H)
    if shape.family == "car":
        belt = p["belt_h"] * H
        middle = _ring(-L / 2, L / 2, half, radius, (p["chamfer_h"] + p["belt_h"]) / 2.0 * H)
        shoulder = p["shoulder_w"] * half
        top = _ring(-L / 2 + p["tail_l"] * L, L / 2 - p["nose_l"] * L, shoulder, radius * p["shoulder_w"], belt)
        lower = np.stack([bottom, chamfer, middle, top])
        base_front, base_rear = p["base_front_l"] * L, -p["base_rear_l"] * L
        roof_front = base_front - p["screen_run_l"] * L
        roof_rear = base_rear + p["backlight_run_l"] * L
        roof_half = p["roof_w"] * half
        crown_mid, crown_half_len = (roof_front + roof_rear) / 2.0, p["crown_l"] * (roof_front - roof_rear) / 2.0
        base = _ring(base_rear, base_front, p["base_w"] * half, radius * p["base_w"], belt)
        roof = _ring(roof_rear, roof_front, roof_half, radius * p["roof_w"], p["roof_h"] * H)
        crown = _ring(crown_mid - crown_half_len, crown_mid + crown_half_len, p["crown_w"] * roof_half,
                      radius * p["roof_w"] * p["crown_w"], H)
        return [lower, np.stack([base, roof, crown]), *_wheels(shape, np.array([L, W, H]))]
    if shape.family == "van":
        hood = _ring(-L / 2 + p["tail_l"] * L, L / 2, half, radius, p["hood_h"] * H)
        lower = np.stack([bottom, chamfer, hood])
        upper_front = L / 2 - p["hood_l"] * L
        roof_front = upper_front - p["screen_run_l"] * L
        base = _ring(-L / 2 + p["tail_l"] * L, upper_front, half, radius, p["hood_h"] * H)
        upper = [base]
    else:  # a box whose front top edge is chamfered at 45 degrees by front_top_l
        lower = np.stack([bottom, chamfer])
        roof_front = L / 2 - p["front_top_l"] * L
        low = max(p["chamfer_h"], p["clearance_h"]) * H
        upper = [_ring(-L / 2 + p["tail_l"] * L, L / 2, half, radius, z)
                 for z in (low, max(low, p["roof_h"] * H - p["front_top_l"] * L))]
    roof_rear = -L / 2 + p["tail_l"] * L
    roof_half = p["roof_w"] * half
    roof = _ring(roof_rear, roof_front, roof_half, radius * p["roof_w"], p["roof_h"] * H)
    crown_mid, crown_half_len = (roof_front + roof_rear) / 2.0, p["crown_l"] * (roof_front - roof_rear) / 2.0
    crown = _ring(crown_mid - crown_half_len, crown_mid + crown_half_len, p["crown_w"] * roof_half,
                  radius * p["roof_w"] * p["crown_w"], H)
    return [lower, np.stack([*upper, roof, crown]), *_wheels(shape, np.array([L, W, H]))]


def _clipped_points(piece_cam: np.ndarray, z_near: float) -> np.ndarray:
    """A lofted piece (rings, points, 3) in the camera frame cut at ``z = z_near``: its vertices in front of the plane
    and where its ring edges, loft edges and loft diagonals cross it, (M, 3)."""
    nxt = np.roll(piece_cam, -1, axis=1)
    segments = [(piece_cam, nxt)]
    if len(piece_cam) > 1:
        segments += [(piece_cam[:-1], piece_cam[1:]), (piece_cam[:-1], nxt[1:])]
    a = np.concatenate([s[0].reshape(-1, 3) for s in segments])
    b = np.concatenate([s[1].reshape(-1, 3) for s in segments])
    vertices = piece_cam.reshape(-1, 3)
    out = [vertices[vertices[:, 2] >= z_near]]
    crossing = (a[:, 2] - z_near) * (b[:, 2] - z_near) < 0.0
    if np.any(crossing):
        a, b = a[crossing], b[crossing]
        s = (z_near - a[:, 2]) / (b[:, 2] - a[:, 2])
        out.append(a + s[:, None] * (b - a))
    return np.concatenate(out)


def _extent(points_cam: np.ndarray, camera: Camera) -> np.ndarray | None:
    """``(x1, y1, x2, y2)`` of the projected points (N, 3), camera frame, all with z >= Z_NEAR; None for none."""
    if len(points_cam) == 0:
        return None
    uv = camera.project(points_cam)
    return np.concatenate([uv.min(axis=0), uv.max(axis=0)])


def _image_box(extent: np.ndarray | None, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
    """The extent clipped to the image and which of its sides the border cut, (4,) each; None when too little
    of it is in the image."""
    if extent is None:
        return None
    box = np.clip(extent, 0.0, np.array([size[0] - 1.0, size[1] - 1.0] * 2))
    if box[2] - box[0] < MIN_BOX_SIDE_PX or box[3] - box[1] < MIN_BOX_SIDE_PX:
        return None
    return box, box != extent


def silhouette_box2d(R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, dimensions: np.ndarray,
                     shape: BodyShape, camera: Camera) -> tuple[np.ndarray, np.ndarray] | None:
    """The box around the projected solid of ``shape``, before the person's error.

    Parameters
    ----------
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,) bottom-face centre, camera frame; dimensions : (3,) ``(dx, dy, dz)``
    camera : its ``image_size`` clips the box

    Returns
    -------
    (box (4,) ``(x1, y1, x2, y2)`` pixels, cut (4,) bool: the sides the image border cut), or None when the solid
    lies behind the camera's near plane or (nearly) outside the image
    """
    R, t = np.asarray(R_cam_vehicle, dtype=float), np.asarray(t_cam_vehicle, dtype=float)
    points = [_clipped_points(piece @ R.T + t, Z_NEAR) for piece in body_pieces(shape, dimensions)]
    return _image_box(_extent(np.concatenate(points), camera), _size(camera))


def projection_box2d(R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, dimensions: np.ndarray,
                     camera: Camera) -> np.ndarray | None:
    """KITTI's kind of box: the projected cuboid (cut at the near plane) clipped to the image, (4,) ``(x1, y1, x2,
    y2)`` pixels; None when it lies behind the camera or (nearly) outside the image."""
    corners = clip_cuboid_to_near_plane(cuboid_corners_cam(R_cam_vehicle, t_cam_vehicle, dimensions), Z_NEAR)
    clipped = _image_box(_extent(corners, camera), _size(camera))
    return None if clipped is None else clipped[0]


def person_error(box: np.ndarray, cut: np.ndarray, size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """The person's drawing of a silhouette box (4,): each side not ``cut`` by the border moved by a Gaussian of
    ``SIDE_NOISE_PX + SIDE_NOISE_SHARE * (the box's size on that axis)`` pixels, clipped to the image, rounded to
    ``BOX_DECIMALS``; a pair of sides closer than ``MIN_BOX_SIDE_PX`` keeps its noise-free place. Draws 4 normals."""
    extent = np.array([box[2] - box[0], box[3] - box[1]])
    sigma = SIDE_NOISE_PX + SIDE_NOISE_SHARE * np.concatenate([extent, extent])
    step = rng.normal(0.0, 1.0, 4) * sigma
    drawn = np.where(cut, box, box + step)
    drawn = np.clip(drawn, 0.0, np.array([size[0] - 1.0, size[1] - 1.0] * 2))
    drawn = np.round(drawn, BOX_DECIMALS)
    for lo, hi in ((0, 2), (1, 3)):
        if drawn[hi] - drawn[lo] < MIN_BOX_SIDE_PX:
            drawn[[lo, hi]] = np.round(box[[lo, hi]], BOX_DECIMALS)
    return drawn


def simulated_box2d(R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, dimensions: np.ndarray, prototype: str,
                    camera: Camera, rng: np.random.Generator, kind: str = "person",
                    shape: BodyShape | None = None) -> np.ndarray | None:
    """The 2D box of a vehicle whose cuboid is known: a person's (see the module's description) or KITTI's.

    Parameters
    ----------
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,) bottom-face centre, camera frame; dimensions : (3,) ``(dx, dy, dz)``
    prototype : its prototype or KITTI type ('Car', 'Van', 'Truck', ...): which family of solid
    camera : with ``image_size``
    rng : draws the solid's shape (unless ``shape`` is given) then the person's error; unused for 'projection'
    kind : 'person' (the silhouette's box with the person's error) or 'projection' (the projected cuboid's box,
        as KITTI's labels have it; no error, not rounded)
    shape : the vehicle's solid, e.g. one drawn once per track (:func:`draw_body_shape`); default: drawn from ``rng``

    Returns
    -------
    (4,) ``(x1, y1, x2, y2)`` pixels, or None when the vehicle is not in the image

    Raises
    ------
    ValueError
        An unknown ``kind``, or a camera without ``image_size``.
    """
    if kind not in BOX_KINDS:
        raise ValueError(f"expected a box kind among {', '.join(BOX_KINDS)}, got {kind!r}")
    if kind == "projection":
        return projection_box2d(R_cam_vehicle, t_cam_vehicle, dimensions, camera)
    shape = shape or draw_body_shape(prototype, rng)
    silhouette = silhouette_box2d(R_cam_vehicle, t_cam_vehicle, dimensions, shape, camera)
    if silhouette is None:
        return None
    return person_error(*silhouette, _size(camera), rng)


def _size(camera: Camera) -> tuple[int, int]:
    if camera.image_size is None:
        raise ValueError("expected a camera with image_size (width, height): the box is clipped to the image")
    return camera.image_size


def side_offsets(boxes: np.ndarray, references: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How far each side of ``boxes`` (N, 4) lies inside the same side of ``references`` (N, 4), both ``(x1, y1, x2,
    y2)``: (N, 4) pixels (left, top, right, bottom; negative: outside) and (N, 4) the same as shares of the
    reference's width (left, right) or height (top, bottom)."""
    boxes, references = np.asarray(boxes, dtype=float), np.asarray(references, dtype=float)
    inward = (boxes - references) * np.array([1.0, 1.0, -1.0, -1.0])
    size = np.column_stack([references[:, 2] - references[:, 0], references[:, 3] - references[:, 1]])
    return inward, inward / size[:, [0, 1, 0, 1]]


def _report(argv: list[str] | None = None) -> None:
    """``python -m toosicubix.simulate.boxes KITTI_TRACKING_DIR --sequences 0000-0009``: the person's boxes of the
    tracks that ``toosicubix simulate --tracks`` selects (default filters, seed 0), side by side with KITTI's:
    how far inside KITTI's box each side lies (negative: outside), median and 10th and 90th percentiles."""
    import argparse

    from toosicubix.formats.datasets import parse_sequences
    from toosicubix.simulate.annotator import (
        AnnotatorOptions,
        SelectionOptions,
        TrackOptions,
        select_kitti_tracks,
        simulate_tracks,
        track_body_shape,
    )

    parser = argparse.ArgumentParser(prog="python -m toosicubix.simulate.boxes", description=_report.__doc__)
    parser.add_argument("root", help="KITTI tracking folder (label_02/, calib/)")
    parser.add_argument("--sequences", default="0000-0009", help="the tuning split by default")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    vehicles = select_kitti_tracks(args.root, SelectionOptions(frames_per_track=None,
                                                               sequences=parse_sequences(args.sequences)))
    simulated = simulate_tracks(vehicles, AnnotatorOptions(seed=args.seed), TrackOptions(boxes="person"))
    drawn = {
        "person": [sv.box2d for sv in simulated],
        "silhouette": [None if (b := silhouette_box2d(
            sv.R_cam_vehicle, sv.t_cam_vehicle, sv.dimensions,
            track_body_shape(args.seed, sv.source.track, sv.source.label.type),  # type: ignore[arg-type]
            sv.source.camera)) is None else b[0] for sv in simulated],
        "projection": [projection_box2d(sv.R_cam_vehicle, sv.t_cam_vehicle, sv.dimensions, sv.source.camera)
                       for sv in simulated],
    }
    kitti = np.array([gt.label.box2d for gt in vehicles])
    print(f"{len(vehicles)} boxes of {len({g.track for g in vehicles})} tracks, sequences {args.sequences}, seed "
          f"{args.seed}; how far inside KITTI's box each side lies: median [10 %, 90 %], left, top, right, bottom")
    depth = np.array([sv.t_cam_vehicle[2] for sv in simulated])
    for kind, boxes in drawn.items():
        keep = np.array([b is not None for b in boxes])
        px, share = side_offsets(np.array([b for b in boxes if b is not None]), kitti[keep])
        for values, unit in ((px, "px"), (100 * share, "%")):
            cells = [f"{np.median(v):6.2f} [{np.percentile(v, 10):6.2f}, {np.percentile(v, 90):6.2f}]"
                     for v in values.T]
            print(f"{kind:10s} ({keep.sum()}) {unit:2s}: " + ", ".join(cells))
        if kind == "silhouette":
            for low, high in ((0.0, 10.0), (10.0, 20.0), (20.0, 40.0), (40.0, np.inf)):
                near = (depth[keep] >= low) & (depth[keep] < high)
                if near.any():
                    print(f"  depth {low:g}-{high:g} m ({near.sum()}) px medians: "
                          + ", ".join(f"{np.median(v):.2f}" for v in px[near].T))


if __name__ == "__main__":
    _report()
