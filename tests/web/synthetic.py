"""A synthetic vehicle for the annotate tests and benchmark: a known cuboid seen obliquely from its front left,
its parts' exact pixels (:mod:`toosicubix.parts.synthesis`) and an image drawn from it (body faces, wheels,
lights), so that a person, or a browser test, can click the parts where they appear."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from toosicubix.camera import Camera
from toosicubix.geometry import R_cam_vehicle_from_ypr, cuboid_corners_cam
from toosicubix.parts.synthesis import PartSpec, render_parts

K = np.array([[720.0, 0.0, 620.0], [0.0, 720.0, 180.0], [0.0, 0.0, 1.0]])
SIZE = (1240, 375)
CAMERA = Camera(K=K, image_size=SIZE)
DIMENSIONS = np.array([4.0, 1.7, 1.5])
WHEEL_X = (1.2, -1.2)
R_CAM_VEHICLE = R_cam_vehicle_from_ypr(3 * np.pi / 4)  # KITTI ry: the front-left corner turned to the camera
T_CAM_VEHICLE = np.array([1.0, 1.65, 10.0])

#: Parts at their typical positions (lights at 38 % of the width and 55 % of the height, edges at mid height,
#: badges at 45 %), as a person would click them: the first ones named, the rest left to auto-naming.
NAMED = [
    PartSpec("point", "wheel-front-left"), PartSpec("point", "wheel-rear-left"),
    PartSpec("symmetry", "front", {"Y": 0.38 * DIMENSIONS[1], "Z": 0.55 * DIMENSIONS[2]}),
    PartSpec("point", "edge-front-left", {"Z": 0.5 * DIMENSIONS[2]}),
    PartSpec("point", "front-center", {"Z": 0.45 * DIMENSIONS[2]}),
]
UNNAMED = [
    PartSpec("point", "wheel-front-right"),
    PartSpec("point", "edge-rear-left", {"Z": 0.5 * DIMENSIONS[2]}),
    PartSpec("point", "edge-front-right", {"Z": 0.5 * DIMENSIONS[2]}),
]


@dataclass(frozen=True)
class Click:
    kind: str
    name: str
    uv: list[list[float]]


def clicks(specs: list[PartSpec], R: np.ndarray = R_CAM_VEHICLE, t: np.ndarray = T_CAM_VEHICLE) -> list[Click]:
    """The exact pixels of ``specs`` on the synthetic vehicle (at pose ``R``, ``t``: by default the scene's)."""
    parts = render_parts(specs, R, t, DIMENSIONS, CAMERA, WHEEL_X)
    return [Click(p.kind, p.name, p.uv.tolist()) for p in parts]


def draw(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The vehicle at pose (R, t) drawn on the road: BGR image (SIZE[1], SIZE[0], 3)."""
    image = np.full((SIZE[1], SIZE[0], 3), (200, 190, 170), np.uint8)
    image[int(K[1, 2]):] = (110, 110, 110)  # road below the horizon
    corners_uv = CAMERA.project(cuboid_corners_cam(R, t, DIMENSIONS))
    faces = {"front": (0, 3, 7, 4), "left": (0, 1, 5, 4), "top": (4, 5, 6, 7)}
    colours = {"front": (150, 120, 60), "left": (120, 95, 50), "top": (175, 150, 95)}  # BGR blues
    for face, idx in faces.items():
        cv2.fillConvexPoly(image, np.round(corners_uv[list(idx)]).astype(np.int32), colours[face], cv2.LINE_AA)
    for c in clicks([*NAMED, *UNNAMED], R, t):
        for u, v in c.uv:
            colour = (20, 20, 20) if c.name.startswith("wheel") else (0, 220, 255)
            cv2.circle(image, (round(u), round(v)), 5 if c.name.startswith("wheel") else 3, colour, -1, cv2.LINE_AA)
    return image


def write_scene(folder: Path) -> tuple[Path, Path]:
    """Draw the vehicle into ``folder/car.png`` and its camera into ``folder/cameras.json``."""
    image_path = folder / "car.png"
    cv2.imwrite(str(image_path), draw(R_CAM_VEHICLE, T_CAM_VEHICLE))
    cameras_path = folder / "cameras.json"
    cameras_path.write_text(json.dumps({"K": K.tolist()}))
    return image_path, cameras_path


#: The sequence's frames: the vehicle drives away to the right and turns, at a constant velocity and rate.
FRAMES = 11


def sequence_pose(frame: int) -> tuple[np.ndarray, np.ndarray]:
    """The vehicle's pose (R_cam_vehicle (3, 3), t_cam_vehicle (3,)) on frame ``frame`` of the sequence."""
    return (R_cam_vehicle_from_ypr(3 * np.pi / 4 + 0.01 * frame),
            T_CAM_VEHICLE + np.array([0.08, 0.0, 0.25]) * frame)


def write_sequence(folder: Path, frames: int = FRAMES) -> tuple[list[Path], Path]:
    """The vehicle on ``frames`` frames, ``folder/frames/000000.png`` on, and their camera in
    ``folder/cameras.json``: the image paths in frame order and the cameras file."""
    (folder / "frames").mkdir(exist_ok=True)
    paths = []
    for f in range(frames):
        paths.append(folder / "frames" / f"{f:06d}.png")
        cv2.imwrite(str(paths[-1]), draw(*sequence_pose(f)))
    cameras_path = folder / "cameras.json"
    cameras_path.write_text(json.dumps({"K": K.tolist()}))
    return paths, cameras_path
