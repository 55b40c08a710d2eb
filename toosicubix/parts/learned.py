"""Typical keypoint positions learned from labelled keypoints on vehicles with ground-truth poses.

A keypoint at fractions ``f`` (3,) of the dimensions sits at ``X_vehicle = diag(d) f`` on a vehicle of
dimensions ``d``. One click gives one ray; the vehicles of a fleet see the keypoint from many directions, so
``f`` is the least-squares point nearest to every ray, each moved into its vehicle's frame: with ``r_i`` the
unit ray of the click (camera frame) and ``Q_i = I - r_i r_i^T``,

    minimize  sum_i | Q_i (R_cam_vehicle_i diag(d_i) f + t_cam_vehicle_i) |^2     (metres^2)

The spread per axis is the RMS of each vehicle's offset from its ray, ``R_i^T Q_i (...)`` divided by ``d_i``
(fractions), times ``sqrt(3 / 2)``: an offset perpendicular to the ray misses the ray's own component, one of
three on average.

Where a keypoint is seen from is learned too: at each labelled vehicle's ground-truth pose, the faces of its
cuboid turned to the camera (the camera beyond the face's plane). A keypoint's ``seen_from`` is the fewest faces,
taken greedily (the face turned to the camera on most of the vehicles not yet covered first), such that on at least
:data:`SEEN_FROM_SHARE` of its vehicles one of them was turned to the camera; only faces on the keypoint's half of
the vehicle count (front or rear by the sign of its length fraction, left or right by its width's, the top for a
keypoint above half the height): a face on the other half cannot show it, so a ground truth turned around does not
add one. It is learned over all prototypes pooled (a prototype's few vehicles are too few for a 5 % tail). Its
position alone can mislead: a rear window's top corner sits on the roof, inside the box's end, yet people click
it on cars seen from behind. Its ``clicked_share`` is how often people clicked it where it could be seen: of the
vehicles (any that has a labelled keypoint) on which one of its ``seen_from`` faces was turned to the camera, the
share on which it was labelled. Some keypoints are rarely clicked even then: small, low, or hidden by the car's own
body or by other cars.

Ground-truth poses can contradict the clicks (a pose turned 180 degrees, a car model fitted at the wrong
depth). With ``max_offset`` the positions are learned twice: the second pass leaves out every vehicle whose
keypoints lie more than ``max_offset`` metres RMS from their rays at the first pass's positions.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, replace

import numpy as np

from toosicubix.parts.mirror import MIRROR, swapped_sides
from toosicubix.vocabulary import FACES, faces_seen_from

#: ``seen_from`` covers at least this share of the vehicles a keypoint was labelled on.
SEEN_FROM_SHARE = 0.95

#: A ground-truth pose *hides its clicks* when it turns at least this many of a vehicle's labelled keypoints, and at
#: least this share of them, away from the camera (:func:`hides_clicks`; benchmarks/decisions.md, rule 17).
HIDES_MIN, HIDES_SHARE = 3, 0.25

#: Metres: a vehicle whose labelled keypoints, at their learned positions on its ground-truth cuboid, lie farther
#: than this (RMS) from their rays has a ground truth that contradicts its clicks (:func:`contradicting`):
#: ``learn-parts``' second pass leaves it out by default and ``eval --apollocar3d`` scores it apart
#: (benchmarks/decisions.md, rule 6).
CONTRADICTION_M = 0.5

#: The smallest spread reported (fractions of a dimension): a keypoint is never known better than this.
MIN_SPREAD = 0.005

def mirrored_positions(learned: dict[str, LearnedPosition]) -> dict[str, LearnedPosition]:
    """``learned`` (name -> position) with each keypoint whose mirror partner is learned too (the name with its left and
    right swapped, :func:`toosicubix.parts.mirror.swapped_sides`) put at the mean of its own position and the
    partner's mirrored (a vehicle is mirror-symmetric about its midplane, on which its ground-truth cuboid is centred);
    spreads, faces and counts stay each keypoint's own. ``learn-parts --mirror-pairs``: benchmarks/decisions.md, rule
    32's run, says why it is an option and not the default."""
    out = {}
    for name, position in learned.items():
        other = swapped_sides(name)
        partner = learned.get(other) if other != name else None
        out[name] = position if partner is None else replace(position, at=0.5 * (position.at + partner.at * MIRROR))
    return out


@dataclass(frozen=True)
class KeypointSample:
    """One labelled keypoint on a vehicle with a known pose.

    Attributes
    ----------
    prototype, name : which vehicle class and which keypoint
    vehicle : which vehicle it was clicked on (any id unique in the sample set)
    ray_cam : (3,) the click's ray ``K^-1 (x, y, 1)`` (undistorted), camera frame
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,); dimensions : (3,) the vehicle's ground truth
    """

    prototype: str
    name: str
    vehicle: str
    ray_cam: np.ndarray
    R_cam_vehicle: np.ndarray
    t_cam_vehicle: np.ndarray
    dimensions: np.ndarray


@dataclass(frozen=True)
class LearnedPosition:
    """``at`` (3,) and ``spread`` (3,), fractions of ``(dx, dy, dz)``, from ``n`` samples; ``seen_from`` the faces
    it was seen from and ``clicked_share`` how often it was clicked where it could be seen (see the module's
    docstring)."""

    at: np.ndarray
    spread: np.ndarray
    n: int
    seen_from: tuple[str, ...] = ()
    clicked_share: float | None = None


def faces_toward(s: KeypointSample) -> frozenset[str]:
    """The faces of a sample's vehicle (its ground-truth cuboid) turned to the camera (:func:`facing_camera`)."""
    return facing_camera(s.R_cam_vehicle, s.t_cam_vehicle, s.dimensions)


def facing_camera(R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, dimensions: np.ndarray) -> frozenset[str]:
    """The faces of a cuboid (pose ``R_cam_vehicle`` (3, 3), ``t_cam_vehicle`` (3,), ``dimensions`` (3,)) turned to
    the camera: those whose plane the camera lies beyond (:func:`~toosicubix.vocabulary.faces_seen_from`)."""
    seen = faces_seen_from(-R_cam_vehicle.T @ t_cam_vehicle, dimensions)
    return frozenset(face for face, yes in seen.items() if yes)


def halves(at: np.ndarray) -> tuple[str, ...]:
    """The faces on the half of the vehicle where a keypoint at fractions ``at`` (3,) sits (see the module's
    docstring)."""
    x, y, z = at
    near = {"front": x > 0, "rear": x < 0, "left": y > 0, "right": y < 0, "top": z > 0.5}
    return tuple(face for face in FACES if near[face])


def seen_from(facing: list[frozenset[str]], allowed: tuple[str, ...] = FACES,
              share: float = SEEN_FROM_SHARE) -> tuple[str, ...]:
    """The fewest faces of ``allowed``, taken greedily, one of which is in at least ``share`` of the sets
    ``facing`` (the faces turned to the camera on each vehicle a keypoint was labelled on), or as near to that as
    ``allowed`` gets; in :data:`FACES`'s order."""
    chosen: list[str] = []
    left = list(facing)
    while left and len(left) > (1.0 - share) * len(facing) + 1e-9:
        counts = {face: sum(face in f for f in left) for face in allowed if face not in chosen}
        if not counts:
            break
        best = max(counts, key=lambda face: (counts[face], -FACES.index(face)))  # ties: FACES's order
        if counts[best] == 0:
            break
        chosen.append(best)
        left = [f for f in left if best not in f]
    return tuple(face for face in FACES if face in chosen)


def learn_positions(samples: list[KeypointSample], min_samples: int = 3,
                    max_offset: float | None = None) -> dict[str, dict[str, LearnedPosition]]:
    """Per prototype and keypoint name, the typical position and spread (see the module's docstring).

    Parameters
    ----------
    samples : labelled keypoints with their vehicles' ground truth
    min_samples : keypoints seen on fewer vehicles of a prototype are left out (the rays need directions
        that differ)
    max_offset : metres; when given, a second pass leaves out the vehicles whose keypoints lie farther than
        this (RMS) from their rays at the first pass's positions

    Returns
    -------
    ``{prototype: {name: LearnedPosition}}``; a keypoint whose rays leave its position undetermined (all
    parallel) is left out.
    """
    return _two_passes(samples, min_samples, max_offset)[0]


def _two_passes(samples: list[KeypointSample], min_samples: int, max_offset: float | None
                ) -> tuple[dict[str, dict[str, LearnedPosition]], set[str]]:
    """:func:`learn_positions`, and the vehicles its second pass left out."""
    learned = _learn(samples, min_samples)
    if max_offset is None:
        return learned, set()
    bad = contradicting(samples, learned, max_offset)
    return _learn([s for s in samples if s.vehicle not in bad], min_samples), bad


def contradicting(samples: list[KeypointSample], learned: dict[str, dict[str, LearnedPosition]],
                  max_offset: float) -> set[str]:
    """The vehicles whose ground truth contradicts their clicks: at their ground-truth pose their labelled
    keypoints, put at the ``learned`` positions, lie more than ``max_offset`` metres RMS from their rays."""
    return {v for v, rms in rms_offsets(samples, learned).items() if rms > max_offset}


def rms_offsets(samples: list[KeypointSample], learned: dict[str, dict[str, LearnedPosition]]) -> dict[str, float]:
    """Per vehicle, the RMS distance (metres) of its labelled keypoints from their rays, each at its ``learned``
    position on the vehicle's ground-truth cuboid; keypoints without a learned position are left out, and so are
    vehicles with none."""
    squares: dict[str, list[float]] = defaultdict(list)
    for s in samples:
        position = learned.get(s.prototype, {}).get(s.name)
        if position is not None:
            squares[s.vehicle].append(float(np.sum(offset_from_ray(s, position.at) ** 2)))
    return {v: float(np.sqrt(np.mean(sq))) for v, sq in squares.items()}


def hidden_by_ground_truth(samples: list[KeypointSample], learned: dict[str, dict[str, LearnedPosition]]
                           ) -> dict[str, tuple[int, int]]:
    """Per vehicle: how many of its labelled keypoints have learned ``seen_from`` faces, and how many of those have
    none of them turned to the camera at the vehicle's ground-truth pose. A keypoint labelled as seen there
    contradicts its ground truth (up to the 1 - :data:`SEEN_FROM_SHARE` of labels outside ``seen_from`` by
    construction, and views edge-on to a face). Reads the ground truth and ``learned`` only, never a fit."""
    counts: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    for s in samples:
        position = learned.get(s.prototype, {}).get(s.name)
        if position is None or not position.seen_from:
            continue
        count = counts[s.vehicle]
        count[0] += 1
        count[1] += turned_away(position.seen_from, faces_toward(s))
    return {v: (n, hidden) for v, (n, hidden) in counts.items()}


def turned_away(seen_from: tuple[str, ...], facing: frozenset[str]) -> bool:
    """A keypoint seen from the faces ``seen_from`` cannot be seen when none of them is among ``facing`` (the faces
    turned to the camera); False when ``seen_from`` is empty (nothing learned)."""
    return bool(seen_from) and not (facing & set(seen_from))


def hides_clicks(labelled: int, hidden: int) -> bool:
    """Whether a pose that turns ``hidden`` of a vehicle's ``labelled`` keypoints away from the camera hides its
    clicks: at least :data:`HIDES_MIN` of them and at least :data:`HIDES_SHARE` of them. The thresholds allow for
    the labels outside ``seen_from`` by construction and for views nearly edge-on to a face."""
    return hidden >= HIDES_MIN and hidden >= HIDES_SHARE * labelled


def offset_from_ray(s: KeypointSample, at: np.ndarray) -> np.ndarray:
    """The keypoint's offset from its ray (3,), camera frame, metres, were it at fractions ``at``."""
    r = s.ray_cam / np.linalg.norm(s.ray_cam)
    Y = s.R_cam_vehicle @ (s.dimensions * at) + s.t_cam_vehicle
    return Y - r * (r @ Y)


def clicked_share(facing_of: dict[str, frozenset[str]], group: list[KeypointSample],
                  seen: tuple[str, ...]) -> float | None:
    """Of the vehicles ``facing_of`` (vehicle -> the faces turned to its camera) on which one of the faces ``seen``
    was turned to the camera, the share on which the keypoint of ``group`` (its labelled samples) was labelled;
    None when there is no such vehicle."""
    could = [v for v, facing in facing_of.items() if facing & set(seen)]
    if not could:
        return None
    labelled = {s.vehicle for s in group}
    return sum(v in labelled for v in could) / len(could)


def _learn(samples: list[KeypointSample], min_samples: int) -> dict[str, dict[str, LearnedPosition]]:
    groups: dict[tuple[str, str], list[KeypointSample]] = defaultdict(list)
    facing_of: dict[str, dict[str, frozenset[str]]] = defaultdict(dict)  # prototype -> vehicle -> faces to the camera
    for s in samples:
        groups[(s.prototype, s.name)].append(s)
        if s.vehicle not in facing_of[s.prototype]:
            facing_of[s.prototype][s.vehicle] = faces_toward(s)
    out: dict[str, dict[str, LearnedPosition]] = defaultdict(dict)
    for (prototype, name), group in sorted(groups.items()):
        if len(group) < min_samples:
            continue
        rays = np.array([s.ray_cam / np.linalg.norm(s.ray_cam) for s in group])  # (n, 3)
        Q = np.eye(3) - rays[:, :, None] * rays[:, None, :]  # (n, 3, 3)
        R = np.array([s.R_cam_vehicle for s in group])
        d = np.array([s.dimensions for s in group])
        t = np.array([s.t_cam_vehicle for s in group])
        A = Q @ R * d[:, None, :]  # (n, 3, 3): Q R diag(d)
        b = -np.einsum("nij,nj->ni", Q, t)
        A_rows, b_rows = A.reshape(-1, 3), b.reshape(-1)
        if np.linalg.matrix_rank(A_rows, tol=1e-9 * np.abs(A_rows).max()) < 3:
            continue
        f, *_ = np.linalg.lstsq(A_rows, b_rows, rcond=None)
        offsets_cam = A @ f - b  # (n, 3) perpendicular to each ray
        offsets = np.einsum("nji,nj->ni", R, offsets_cam) / d  # vehicle frame, fractions
        spread = np.maximum(np.sqrt(1.5 * np.mean(offsets**2, axis=0)), MIN_SPREAD)
        seen = seen_from([facing_of[prototype][s.vehicle] for s in group], halves(f))
        out[prototype][name] = LearnedPosition(at=f, spread=spread, n=len(group), seen_from=seen,
                                               clicked_share=clicked_share(facing_of[prototype], group, seen))
    return dict(out)


@dataclass(frozen=True)
class LearningReport:
    """What learning a mapping left out and noticed, by vehicle (the samples' ``vehicle``), over all prototypes
    pooled, as the mapping's ``position`` and ``seen_from`` were learned.

    Attributes
    ----------
    vehicles : how many vehicles had a labelled keypoint
    left_out : the vehicles the second pass left out (keypoints off their rays at the ground-truth pose)
    hiding : the vehicles whose ground-truth pose hides their clicks (:func:`hides_clicks`, by the learned
        ``seen_from``), each with (its labelled keypoints that have learned faces, those turned away); their
        keypoints were learned from unless ``left_out`` has them
    """

    vehicles: int
    left_out: frozenset[str]
    hiding: dict[str, tuple[int, int]]


def learned_mapping(base: dict, samples: list, min_samples: int, how: str, max_offset: float | None = None,
                    mirror_pairs: bool = False) -> tuple[dict, LearningReport]:
    """The mapping document ``base`` with every keypoint part's position learned from ``samples``: pooled over
    prototypes in ``position``, per prototype (with at least ``min_samples`` vehicles) in ``by_prototype``; and
    what the pooled learning left out and noticed. Keypoint parts without any sample are dropped (their keypoints
    are then counted as unused on import). ``mirror_pairs``: each left/right pair's positions averaged, mirrored
    (:func:`mirrored_positions`)."""
    pooled_samples = [replace(s, prototype="*") for s in samples]
    pooled_all, left_out = _two_passes(pooled_samples, 3, max_offset)
    pooled = pooled_all.get("*", {})
    hiding = {v: c for v, c in hidden_by_ground_truth(pooled_samples, pooled_all).items() if hides_clicks(*c)}
    report = LearningReport(len({s.vehicle for s in samples}), frozenset(left_out), hiding)
    per = learn_positions(samples, min_samples=min_samples, max_offset=max_offset)
    if mirror_pairs:
        pooled = mirrored_positions(pooled)
        per = {prototype: mirrored_positions(d) for prototype, d in per.items()}

    def entry(p, pooled: bool = False) -> dict:
        return {"at": [round(float(v), 4) for v in p.at], "spread": [round(float(v), 4) for v in p.spread], "n": p.n,
                **({"seen_from": list(p.seen_from)} if pooled and p.seen_from else {}),
                **({"clicked_share": round(p.clicked_share, 3)} if pooled and p.clicked_share else {})}

    parts, unused = [], list(base.get("unused", []))
    for part in base["parts"]:
        if part["kind"] == "plate":  # the centre: the mean of its two ends, on the centreline
            ends = [part["a"], part["b"]]
            if all(e in pooled for e in ends):
                part = {**part, "position": _centre([pooled[e] for e in ends]),
                        "by_prototype": {proto: _centre([d[e] for e in ends]) for proto, d in sorted(per.items())
                                         if all(e in d for e in ends)}}
            parts.append(part)
            continue
        if part["kind"] != "keypoint":
            parts.append(part)
            continue
        name = part["keypoint"]
        if name not in pooled:
            unused.append(name)
            continue
        parts.append({**part, "position": entry(pooled[name], pooled=True),
                      "by_prototype": {proto: entry(d[name]) for proto, d in sorted(per.items()) if name in d}})
    described = base.get("description", "").split(" Positions: ")[0]
    return {**base, "description": f"{described} Positions: {how}.".strip(), "unused": unused,
            "parts": parts}, report


def _centre(ends: list) -> dict:
    at = np.mean([e.at for e in ends], axis=0)
    at[1] = 0.0
    spread = np.mean([e.spread for e in ends], axis=0)
    return {"at": [round(float(v), 4) for v in at], "spread": [round(float(v), 4) for v in spread],
            "n": min(e.n for e in ends)}
