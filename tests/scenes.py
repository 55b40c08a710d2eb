"""Synthetic vehicles for tests: random poses (with pitch and roll) seen from the front, rear, side or at
an angle, and the parts a person would click in that view. Every part kind and direction axis appears
in some view.

The oblique views see both end faces, both sides, the top and the ground, so their clicks determine the
cuboid up to scale (8 DoF). Straight front and rear views leave the length to the prior, the side view
the width: points on one end face only fix that face, not the centre (a direction arrow's length is free).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from toosicubix.camera import Camera
from toosicubix.geometry import R_cam_vehicle_from_ypr
from toosicubix.model import Part
from toosicubix.parts.linear import PartsModel, build_parts_model
from toosicubix.parts.synthesis import PartSpec, render_parts, true_parameters

K_TEST = np.array([[720.0, 0.0, 620.0], [0.0, 720.0, 180.0], [0.0, 0.0, 1.0]])
CAMERA = Camera(K=K_TEST, image_size=(1240, 375))

# KITTI yaw (ry) that shows each view: ry = pi/2 faces the camera, -pi/2 drives away, 0 shows the right side.
VIEW_YAW = {"front": np.pi / 2, "rear": -np.pi / 2, "side": 0.0, "oblique-front-left": 3 * np.pi / 4,
            "oblique-rear-right": -np.pi / 4}


@dataclass(frozen=True)
class Scene:
    view: str
    R_cam_vehicle: np.ndarray
    t_cam_vehicle: np.ndarray
    dimensions: np.ndarray
    specs: list[PartSpec]
    parts: list[Part]
    model: PartsModel
    p_true: np.ndarray


def _specs(view: str, d: np.ndarray, rng: np.random.Generator) -> list[PartSpec]:
    dx, dy, dz = d
    u = rng.uniform

    def light() -> dict[str, float]:
        return {"Y": u(0.3, 0.45) * dy, "Z": u(0.4, 0.65) * dz}

    if view == "front":
        return [
            PartSpec("point", "wheel-front-left"), PartSpec("point", "wheel-front-right"),
            PartSpec("symmetry", "front", light()),
            PartSpec("point", "front-center", {"Z": u(0.25, 0.45) * dz}),
            PartSpec("symmetry", "roof", {"X": u(-0.3, 0.1) * dx, "Y": u(0.3, 0.45) * dy}),
            PartSpec("point", "edge-front-left", {"Z": u(0.3, 0.8) * dz}),
            PartSpec("point", "corner-top-front-right"),
            PartSpec("direction", "forward", {"X": u(-0.6, -0.2) * dx, "Y": u(0.6, 0.9) * dy, "Z": 0.0}),
        ]
    if view == "rear":
        return [
            PartSpec("point", "wheel-rear-left"), PartSpec("point", "wheel-rear-right"),
            PartSpec("symmetry", "rear", light()),
            PartSpec("point", "rear-center", {"Z": u(0.3, 0.5) * dz}),
            PartSpec("point", "top-center", {"X": u(-0.3, 0.1) * dx}),
            PartSpec("point", "edge-rear-right", {"Z": u(0.3, 0.8) * dz}),
            PartSpec("point", "corner-bottom-rear-right"),
            PartSpec("direction", "backward", {"X": u(0.0, 0.5) * dx, "Y": -u(0.6, 0.9) * dy, "Z": 0.0}),
        ]
    if view == "side":  # the right side (-Y) faces the camera
        return [
            PartSpec("point", "wheel-front-right"), PartSpec("point", "wheel-rear-right"),
            PartSpec("point", "edge-front-right", {"Z": u(0.3, 0.7) * dz}),
            PartSpec("point", "edge-rear-right", {"Z": u(0.3, 0.7) * dz}),
            PartSpec("point", "corner-top-front-right"), PartSpec("point", "corner-top-rear-right"),
            PartSpec("direction", "rightward", {"X": u(-0.3, 0.3) * dx, "Y": -0.5 * dy, "Z": u(0.2, 0.6) * dz}),
            PartSpec("direction", "downward", {"X": u(-0.4, 0.4) * dx, "Y": -0.5 * dy, "Z": dz}),
        ]
    if view == "oblique-front-left":
        return [
            PartSpec("point", "wheel-front-left"), PartSpec("point", "wheel-rear-left"),
            PartSpec("point", "wheel-front-right"),
            PartSpec("symmetry", "front", light()),
            PartSpec("point", "edge-front-left", {"Z": u(0.3, 0.8) * dz}),
            PartSpec("point", "top-center", {"X": u(-0.3, 0.1) * dx}),
            PartSpec("point", "corner-top-front-left"),
            PartSpec("point", "edge-rear-left", {"Z": u(0.3, 0.8) * dz}),
            PartSpec("direction", "leftward", {"X": u(-0.3, 0.3) * dx, "Y": 0.5 * dy, "Z": u(0.2, 0.6) * dz}),
        ]
    if view == "oblique-rear-right":
        return [
            PartSpec("point", "wheel-rear-right"), PartSpec("point", "wheel-front-right"),
            PartSpec("point", "wheel-rear-left"),
            PartSpec("symmetry", "rear", light()),
            PartSpec("point", "edge-rear-right", {"Z": u(0.3, 0.8) * dz}),
            PartSpec("symmetry", "roof", {"X": u(-0.3, 0.1) * dx, "Y": u(0.3, 0.45) * dy}),
            PartSpec("point", "corner-bottom-rear-left"),
            PartSpec("point", "edge-front-right", {"Z": u(0.3, 0.8) * dz}),
            PartSpec("direction", "upward", {"X": -0.5 * dx, "Y": -0.5 * dy, "Z": u(0.0, 0.2) * dz}),
        ]
    raise ValueError(view)


def random_scene(rng: np.random.Generator, view: str, camera: Camera = CAMERA,
                 max_tilt_deg: float = 4.0) -> Scene:
    """A vehicle 8-35 m away in ``view``, yaw within 20 degrees of the view's, pitch and roll up to
    ``max_tilt_deg``."""
    d = np.array([4.2, 1.75, 1.5]) * rng.uniform(0.85, 1.15, 3)
    ry = VIEW_YAW[view] + np.deg2rad(rng.uniform(-20.0, 20.0))
    tilt = np.deg2rad(max_tilt_deg)
    R = R_cam_vehicle_from_ypr(ry, rng.uniform(-tilt, tilt), rng.uniform(-tilt, tilt))
    z = rng.uniform(8.0, 35.0)
    t = np.array([rng.uniform(-0.25, 0.25) * z, rng.uniform(1.3, 1.8), z])
    wheel_x = (rng.uniform(0.28, 0.36) * d[0], -rng.uniform(0.28, 0.36) * d[0])
    specs = _specs(view, d, rng)
    parts = render_parts(specs, R, t, d, camera, wheel_x)
    _, p_true = true_parameters(specs, d, wheel_x)
    return Scene(view, R, t, d, specs, parts, build_parts_model(parts), p_true)
