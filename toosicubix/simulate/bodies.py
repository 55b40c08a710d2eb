"""Simulated people and two-wheelers in real ground-truth boxes: where their keypoints really are, and which of them a
person labelling COCO-style keypoints sees.

The solver knows a class's keypoints only as typical fractions of the box within a spread (the vocabulary's
``classes``). The simulated annotator must click where the keypoints really are on a body, so this module poses a
body inside each ground-truth box. The models are articulated (segments and joint angles), drawn per object, and
independent of the vocabulary's fractions: nothing here reads them, and nothing was set by looking at fits. Every
length is in metres, every point in the box frame (origin at the bottom-face centre, X forward = the way the person
faces or the machine points, Y left, Z up).

**A person** (:func:`pose_person`) of stature ``H`` = the box's height:

- segments from Drillis & Contini's (1966) fractions of stature (shoulder 0.818, hip joint 0.530, ankle 0.039 above
  the floor; thigh 0.245, shank 0.246, upper arm 0.186, forearm 0.146; shoulder breadth 0.259), each scaled by its
  own factor (normal, 3 % sd: the spread of body proportions);
- hip keypoints 0.12 H apart (the lateral pelvis where people click a hip), head from NASA-STD-3000 / ANSUR-like
  head dimensions (tragus to nose tip 0.105 m, eyes 0.08 m ahead of the tragus and 0.064 m apart, ears 0.145 m
  apart; 4 % sd), the tragus 0.108 H above the shoulders' midpoint;
- standing (35 %: legs straight, feet 0.07-0.15 m either side, arms hanging) or walking (65 %): a gait phase drawn
  uniformly, hip flexion 5 degrees + A sin(phase) with A 15-25 degrees, the knee flexing up to 60 degrees in swing,
  the arms swinging against the legs by 8-25 degrees, feet near the line of progress; the trunk leaning forward
  0-6 degrees and counter-rotating +-4 degrees with the pelvis; one person in five holds a forearm up (a phone, a
  bag: elbow 60-90 degrees);
- the head turned from the chest (normal, 15 degrees sd, at most 50) and tilted (8 degrees sd): KITTI's heading is
  the body's, the face may look elsewhere;
- the pelvis 0-3 cm (sd) off the box's centre, the lower foot on the floor.

**A two-wheeler with its rider** (:func:`pose_two_wheeler`): wheels 0.62-0.70 m, wheelbase 0.98-1.10 m (bicycle;
motorcycle 0.60-0.66 m and 1.35-1.50 m), the machine centred on the box; grips 0.05-0.18 m behind the front axle,
0.90-1.10 m high, 0.21-0.35 m from the centre line, turned with the steering (4 degrees sd); saddle 0.22-0.32 m ahead
of the rear axle, 0.82-1.00 m high; the rider's head centre 0.10-0.13 m below the box's top, 0.15-0.45 m ahead of the
saddle, shoulders 0.20-0.27 m below it, 0.17-0.21 m from the centre line; the whole leaning by 2 degrees (sd).

**What is labelled** (:func:`labelled`): COCO's visibility flags as a person sets them. A keypoint on the body's
far side from the camera (seen more than 35 degrees from straight ahead or behind) is hidden; the face (nose, eyes)
is hidden from behind (camera more than 100 degrees off the face's direction); the far wheel's contact and hub are
hidden seen within 25 degrees of straight ahead or behind, the saddle under the rider unless seen from the side (45
degrees or more). A hidden keypoint is labelled v = 1 with probability 0.8 (a face from behind: 0.2), else not at
all (v = 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from toosicubix.geometry import rot_x, rot_y, rot_z

#: Drillis & Contini's (1966) heights and lengths as fractions of stature.
SHOULDER_HEIGHT, HIP_HEIGHT, ANKLE_HEIGHT = 0.818, 0.530, 0.039
THIGH, SHANK, UPPER_ARM, FOREARM, SHOULDER_BREADTH = 0.245, 0.246, 0.186, 0.146, 0.259
#: Where people click a hip, as a fraction of stature between the two; the tragus above the shoulders' midpoint.
HIP_SPAN, TRAGUS_ABOVE_SHOULDERS = 0.12, 0.108
#: Head points in metres, head frame (origin midway between the tragi, X the face's direction, Y its left, Z up).
HEAD_POINTS = {"nose": (0.105, 0.0, -0.035), "left_eye": (0.08, 0.032, 0.005), "right_eye": (0.08, -0.032, 0.005),
               "left_ear": (0.0, 0.0725, 0.0), "right_ear": (0.0, -0.0725, 0.0)}
#: Share of standing people; of people holding a forearm up.
STANDING, FOREARM_UP = 0.35, 0.2
#: Far-side keypoints count as hidden seen more than this from straight ahead or behind (degrees).
FAR_SIDE_DEG = 35.0
#: The face is hidden seen more than this from its direction (degrees).
FACE_HIDDEN_DEG = 100.0
#: Probability that a hidden keypoint is labelled (v = 1) rather than left out (v = 0); for a face from behind.
HIDDEN_LABELLED, FACE_FROM_BEHIND_LABELLED = 0.8, 0.2


@dataclass(frozen=True)
class PosedBody:
    """A posed body in its box.

    Attributes
    ----------
    points : keypoint name -> (3,) position, metres, box frame
    facing : the direction the hidden-side tests measure views from, radians about Z from the box's X (the chest's
        direction for a person, the machine's for a two-wheeler)
    face_yaw : where the face looks (a person's head), radians about Z from the box's X; None for a two-wheeler
    kind : 'person' or 'two-wheeler'
    """

    points: dict[str, np.ndarray]
    facing: float
    face_yaw: float | None
    kind: str


def _segment(rng: np.random.Generator, fraction: float, H: float) -> float:
    return fraction * H * (1.0 + 0.03 * rng.standard_normal())


def _leg(hip: np.ndarray, flexion: float, knee_flexion: float, thigh: float, shank: float,
         ankle_y: float) -> tuple[np.ndarray, np.ndarray]:
    """Knee and ankle (3,) of a leg hanging from ``hip`` (3,), flexed forward by ``flexion`` at the hip and back by
    ``knee_flexion`` at the knee (radians), its ankle at lateral place ``ankle_y``."""
    knee = hip + thigh * np.array([math.sin(flexion), 0.0, -math.cos(flexion)])
    shank_angle = flexion - knee_flexion
    ankle = knee + shank * np.array([math.sin(shank_angle), 0.0, -math.cos(shank_angle)])
    knee[1] = hip[1] + 0.5 * (ankle_y - hip[1])
    ankle[1] = ankle_y
    return knee, ankle


def _arm(shoulder: np.ndarray, swing: float, elbow_flexion: float, abduction: float, upper: float, fore: float,
         side: float) -> tuple[np.ndarray, np.ndarray]:
    """Elbow and wrist (3,) of an arm from ``shoulder`` (3,), swung forward by ``swing`` (radians), the elbow flexed
    forward by ``elbow_flexion``, abducted outward (``side`` +1 left, -1 right) by ``abduction``."""
    out = side * math.sin(abduction)
    elbow = shoulder + upper * np.array([math.sin(swing), out, -math.cos(swing)])
    fore_angle = swing + elbow_flexion
    wrist = elbow + fore * np.array([math.sin(fore_angle), 0.5 * out, -math.cos(fore_angle)])
    return elbow, wrist


def pose_person(dimensions: np.ndarray, rng: np.random.Generator) -> PosedBody:
    """A standing or walking person in a box of ``dimensions`` (3,) ``(dx, dy, dz)``: COCO's 17 keypoints."""
    H = float(dimensions[2])
    deg = math.radians
    thigh, shank = _segment(rng, THIGH, H), _segment(rng, SHANK, H)
    upper, fore = _segment(rng, UPPER_ARM, H), _segment(rng, FOREARM, H)
    trunk = _segment(rng, SHOULDER_HEIGHT - HIP_HEIGHT, H)
    half_shoulders, half_hips = 0.5 * _segment(rng, SHOULDER_BREADTH, H), 0.5 * _segment(rng, HIP_SPAN, H)
    walking = rng.uniform() >= STANDING
    phase = rng.uniform(0.0, 2.0 * math.pi)
    if walking:
        amplitude, arm_amplitude = deg(rng.uniform(15.0, 25.0)), deg(rng.uniform(8.0, 25.0))
        legs = {}
        for side, phi in (("left", phase), ("right", phase + math.pi)):
            swing = max(0.0, math.sin(phi - math.pi / 3))
            legs[side] = (deg(5.0) + amplitude * math.sin(phi), deg(5.0) + deg(55.0) * swing ** 2)
        arms = {"left": -arm_amplitude * math.sin(phase), "right": arm_amplitude * math.sin(phase)}
        foot_y = {s: sign * (half_hips - rng.uniform(0.02, 0.05)) for s, sign in (("left", 1.0), ("right", -1.0))}
        twist = deg(4.0) * math.sin(phase)
    else:
        legs = {s: (deg(rng.normal(0.0, 3.0)), abs(deg(rng.normal(3.0, 2.0)))) for s in ("left", "right")}
        arms = {s: deg(rng.normal(0.0, 5.0)) for s in ("left", "right")}
        foot_y = {s: sign * rng.uniform(0.07, 0.15) for s, sign in (("left", 1.0), ("right", -1.0))}
        twist = 0.0
    elbows = {s: deg(rng.uniform(10.0, 30.0)) for s in ("left", "right")}
    if rng.uniform() < FOREARM_UP:
        elbows[str(rng.choice(["left", "right"]))] = deg(rng.uniform(60.0, 90.0))
    lean = deg(rng.uniform(0.0, 6.0))

    points: dict[str, np.ndarray] = {}  # the pelvis at the origin; moved onto the floor below
    for side, sign in (("left", 1.0), ("right", -1.0)):
        hip = rot_z(twist) @ np.array([0.0, sign * half_hips, 0.0])
        knee, ankle = _leg(hip, *legs[side], thigh, shank, foot_y[side])
        points[f"{side}_hip"], points[f"{side}_knee"], points[f"{side}_ankle"] = hip, knee, ankle
    R_trunk = rot_z(-twist) @ rot_y(lean)  # the chest counter-rotates the pelvis, leans forward
    neck = R_trunk @ np.array([0.0, 0.0, trunk])
    for side, sign in (("left", 1.0), ("right", -1.0)):
        shoulder = neck + R_trunk @ np.array([0.0, sign * half_shoulders, 0.0])
        elbow, wrist = _arm(shoulder, arms[side], elbows[side], deg(rng.uniform(5.0, 12.0)), upper, fore, sign)
        points[f"{side}_shoulder"], points[f"{side}_elbow"], points[f"{side}_wrist"] = shoulder, elbow, wrist
    head_scale = H / 1.75 * (1.0 + 0.04 * rng.standard_normal())
    head_yaw = float(np.clip(rng.normal(0.0, 15.0), -50.0, 50.0))
    R_head = rot_z(-twist + deg(head_yaw)) @ rot_y(deg(rng.normal(0.0, 8.0)))
    tragus = neck + R_trunk @ np.array([0.02, 0.0, _segment(rng, TRAGUS_ABOVE_SHOULDERS, H)])
    for name, p in HEAD_POINTS.items():
        points[name] = tragus + head_scale * (R_head @ np.array(p))
    floor = min(points["left_ankle"][2], points["right_ankle"][2]) - ANKLE_HEIGHT * H
    offset = np.array([rng.normal(0.0, 0.03), rng.normal(0.0, 0.03), -floor])
    facing = float(-twist)
    return PosedBody({k: v + offset for k, v in points.items()}, facing, facing + deg(head_yaw), "person")


#: (wheel diameter, wheelbase) ranges, metres, of a bicycle and a motorcycle; their grips and saddle (seat) heights.
BICYCLE = {"wheel": (0.62, 0.70), "wheelbase": (0.98, 1.10), "grip_z": (0.90, 1.10), "seat_z": (0.82, 1.00),
           "grip_y": (0.21, 0.35)}
MOTORCYCLE = {"wheel": (0.60, 0.66), "wheelbase": (1.35, 1.50), "grip_z": (0.95, 1.15), "seat_z": (0.76, 0.86),
              "grip_y": (0.34, 0.42)}


def pose_two_wheeler(dimensions: np.ndarray, rng: np.random.Generator, motor: bool = False,
                     rider: bool = True) -> PosedBody:
    """A bicycle (``motor``: a motorcycle) with or without its rider in a box of ``dimensions`` (3,): the two-wheeler
    vocabulary's keypoints (the rider's head and shoulders only with ``rider``)."""
    g = MOTORCYCLE if motor else BICYCLE
    u = rng.uniform
    wheel, wheelbase = u(*g["wheel"]), u(*g["wheelbase"])
    shift = rng.normal(0.0, 0.03)
    front, rear = wheelbase / 2 + shift, -wheelbase / 2 + shift
    steer = math.radians(rng.normal(0.0, 4.0))
    pivot = np.array([front - 0.1, 0.0, 0.0])
    grip_back, grip_z, grip_y = u(0.05, 0.18), u(*g["grip_z"]), u(*g["grip_y"])
    points = {
        "front_wheel_contact": np.array([front, 0.0, 0.0]), "rear_wheel_contact": np.array([rear, 0.0, 0.0]),
        "front_wheel_hub": np.array([front, 0.0, wheel / 2]), "rear_wheel_hub": np.array([rear, 0.0, wheel / 2]),
    }
    for side, sign in (("left", 1.0), ("right", -1.0)):
        grip = np.array([front - grip_back, sign * grip_y, 0.0])
        turned = pivot + rot_z(steer) @ (grip - pivot)
        points[f"{side}_handlebar_end"] = np.array([turned[0], turned[1], grip_z])
    seat_x = rear + u(0.22, 0.32)
    points["saddle"] = np.array([seat_x, 0.0, u(*g["seat_z"])])
    if rider:
        head = np.array([seat_x + u(0.15, 0.45), 0.0, float(dimensions[2]) - u(0.10, 0.13)])
        shoulder_x, shoulder_z, half = head[0] - u(0.0, 0.1), head[2] - u(0.20, 0.27), u(0.17, 0.21)
        points["head"] = head
        points["left_shoulder"] = np.array([shoulder_x, half, shoulder_z])
        points["right_shoulder"] = np.array([shoulder_x, -half, shoulder_z])
    R_lean = rot_x(math.radians(rng.normal(0.0, 2.0)))
    return PosedBody({k: R_lean @ v for k, v in points.items()}, 0.0, None, "two-wheeler")


def _side(name: str) -> float:
    """+1 for a keypoint on the body's left, -1 on its right, 0 on its centre line."""
    return 1.0 if name.startswith("left") else -1.0 if name.startswith("right") else 0.0


def hidden(body: PosedBody, name: str, camera_box: np.ndarray) -> str | None:
    """Why keypoint ``name`` of ``body`` is hidden (self-occluded) from a camera at ``camera_box`` (3,), box frame:
    'far side', 'face from behind', 'behind the near wheel', 'under the rider'; None when it is seen (see the
    module's description)."""
    view = camera_box[:2] - body.points[name][:2]
    azimuth = math.degrees(math.atan2(view[1], view[0]) - body.facing)
    azimuth = (azimuth + 180.0) % 360.0 - 180.0  # 0: seen from straight ahead; +90: from the left
    side = _side(name)
    off_axis = min(abs(azimuth), 180.0 - abs(azimuth))  # from straight ahead or behind
    if side != 0.0 and side * azimuth < 0 and off_axis > FAR_SIDE_DEG:
        return "far side"
    if body.kind == "person" and name in ("nose", "left_eye", "right_eye") and body.face_yaw is not None:
        face = math.degrees(math.atan2(view[1], view[0]) - body.face_yaw)
        return "face from behind" if abs((face + 180.0) % 360.0 - 180.0) > FACE_HIDDEN_DEG else None
    if body.kind == "two-wheeler":
        if name.endswith(("wheel_contact", "wheel_hub")) and off_axis < 25.0:
            far = "rear" if abs(azimuth) < 90.0 else "front"
            return "behind the near wheel" if name.startswith(far) else None
        if name == "saddle" and "head" in body.points and off_axis < 45.0:
            return "under the rider"
    return None


def labelled(body: PosedBody, camera_box: np.ndarray, rng: np.random.Generator) -> dict[str, bool]:
    """The keypoints a person labels on ``body`` seen from ``camera_box`` (3,), box frame: name -> visible (v = 2)
    or hidden but labelled (v = 1); the ones left out (v = 0) are absent."""
    out = {}
    for name in body.points:
        why = hidden(body, name, camera_box)
        if why is None:
            out[name] = True
        elif rng.uniform() < (FACE_FROM_BEHIND_LABELLED if why == "face from behind" else HIDDEN_LABELLED):
            out[name] = False
    return out
