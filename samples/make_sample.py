"""Generate the bundled sample: ``annotations.json`` and its ground truth ``ground_truth/``.

The vehicles are synthetic: known upright cuboids seen by invented cameras (a KITTI-like ``P`` and a
wide camera with lens distortion), their parts projected with :mod:`toosicubix.synthesis` and rounded
to 0.1 px as an annotation tool would store them. The ground truth is written as KITTI labels with
calibration files, so that ``toosicubix eval --kitti samples/ground_truth`` scores a fit of the sample.

Run from the repository root:  python samples/make_sample.py
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from toosicubix.annotations.convert import vehicle_json
from toosicubix.camera import Camera
from toosicubix.formats.kitti import format_label_line, object_from_pose
from toosicubix.geometry import R_cam_vehicle_from_ypr, box2d_of_points, clip_cuboid_to_near_plane, cuboid_corners_cam
from toosicubix.model import Vehicle
from toosicubix.parts.synthesis import PartSpec, render_parts
from toosicubix.solver.plausibility import unseen_clicks

HERE = Path(__file__).resolve().parent

# Invented cameras: a KITTI-like rectified camera 2 (6 cm right of camera 0) and a distorted 720p camera.
P_KITTI_LIKE = np.array([[720.0, 0.0, 620.0, 43.2], [0.0, 720.0, 180.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
K_WIDE = np.array([[1000.0, 0.0, 640.0], [0.0, 1000.0, 360.0], [0.0, 0.0, 1.0]])
DIST_WIDE = [-0.12, 0.05, 0.0005, -0.0003, 0.0]


def car(*specs: PartSpec) -> list[PartSpec]:
    return list(specs)


def wheels(*names: str) -> list[PartSpec]:
    return [PartSpec("point", f"wheel-{n}") for n in names]


# (id, prototype, KITTI yaw ry (deg), bottom centre in camera coords (m), dimensions (dx, dy, dz), parts)
SCENES = {
    "000001": {
        "camera": "kitti",
        "vehicles": [
            ("1", "Car", -70.0, (3.2, 1.62, 14.0), (4.1, 1.72, 1.46), [
                *wheels("rear-right", "front-right", "rear-left"),
                PartSpec("symmetry", "rear", {"Y": 0.62, "Z": 0.88}),
                PartSpec("point", "rear-center", {"Z": 0.55}),
                PartSpec("point", "edge-rear-right", {"Z": 1.1}),
            ]),
            ("2", "Van", 95.0, (-4.5, 1.70, 24.0), (5.0, 1.9, 2.1), [
                *wheels("front-left", "front-right"),
                PartSpec("symmetry", "front", {"Y": 0.7, "Z": 0.75}),
                PartSpec("point", "front-center", {"Z": 0.6}),
                PartSpec("symmetry", "roof", {"X": 1.8, "Y": 0.8}),
                PartSpec("direction", "forward", {"X": -1.0, "Y": 1.4, "Z": 0.0}),
            ]),
            ("3", "Car", 5.0, (-1.0, 1.60, 10.5), (3.9, 1.65, 1.50), [
                *wheels("front-right", "rear-right"),
                PartSpec("point", "edge-front-right", {"Z": 0.7}),
                PartSpec("point", "edge-rear-right", {"Z": 0.9}),
                PartSpec("point", "corner-top-front-right"),
                PartSpec("direction", "leftward", {"X": 0.5, "Y": -0.825, "Z": 0.4}),
            ]),
        ],
    },
    "000002": {
        "camera": "wide",
        "vehicles": [
            ("1", "Mid Size Car", 130.0, (2.5, 1.50, 9.0), (4.3, 1.74, 1.50), [
                *wheels("front-right", "front-left", "rear-left"),
                PartSpec("symmetry", "front", {"Y": 0.65, "Z": 0.7}),
                PartSpec("point", "edge-front-right", {"Z": 1.0}),
                PartSpec("point", "top-center", {"X": -0.2}),
                PartSpec("direction", "upward", {"X": 2.15, "Y": -0.87, "Z": 0.0}),
            ]),
            ("2", "Truck", -92.0, (-0.8, 1.50, 20.0), (8.5, 2.5, 3.3), [
                *wheels("rear-left", "rear-right"),
                PartSpec("symmetry", "rear", {"Y": 1.1, "Z": 0.9}),
                PartSpec("point", "corner-top-rear-left"),
                PartSpec("point", "corner-top-rear-right"),
                PartSpec("direction", "forward", {"X": -3.0, "Y": 1.8, "Z": 0.0}),
            ]),
        ],
    },
    "000003": {
        "camera": "wide",
        "vehicles": [
            ("7", "Car", 40.0, (-3.0, 1.55, 16.0), (4.4, 1.80, 1.45), [
                *wheels("front-left", "front-right", "rear-right"),
                PartSpec("symmetry", "front", {"Y": 0.7, "Z": 0.6}),
                PartSpec("point", "corner-bottom-front-right"),
                PartSpec("point", "edge-rear-right", {"Z": 0.8}),
                PartSpec("direction", "backward", {"X": 2.0, "Y": 0.9, "Z": 0.6}),
                PartSpec("direction", "rightward", {"X": -2.2, "Y": 0.45, "Z": 1.0}),
                PartSpec("direction", "downward", {"X": -2.2, "Y": 0.9, "Z": 1.3}),
            ]),
        ],
    },
}


def camera_for(kind: str) -> tuple[Camera, dict, tuple[int, int]]:
    if kind == "kitti":
        size = (1242, 375)
        return Camera.from_P(P_KITTI_LIKE, image_size=size), {"P": P_KITTI_LIKE.tolist()}, size
    size = (1280, 720)
    cam = Camera(K=K_WIDE, distortion=np.array(DIST_WIDE), image_size=size)
    return cam, {"K": K_WIDE.tolist(), "distortion": DIST_WIDE}, size


def calib_text(camera: Camera) -> str:
    P2 = np.hstack([camera.K, (camera.K @ camera.t_cam_rect)[:, None]])
    P0 = np.hstack([camera.K, np.zeros((3, 1))])
    lines = [f"P{i}: " + " ".join(f"{v:.12e}" for v in P.ravel()) for i, P in enumerate((P0, P0, P2, P2))]
    lines.append("R0_rect: " + " ".join(f"{v:.12e}" for v in np.eye(3).ravel()))
    identity34 = np.hstack([np.eye(3), np.zeros((3, 1))])
    lines.append("Tr_velo_to_cam: " + " ".join(f"{v:.12e}" for v in identity34.ravel()))
    lines.append("Tr_imu_to_velo: " + " ".join(f"{v:.12e}" for v in identity34.ravel()))
    return "\n".join(lines) + "\n"


def main() -> None:
    images = []
    gt_dir = HERE / "ground_truth"
    (gt_dir / "label_2").mkdir(parents=True, exist_ok=True)
    (gt_dir / "calib").mkdir(parents=True, exist_ok=True)
    for image_id, scene in SCENES.items():
        camera, camera_json, size = camera_for(scene["camera"])
        vehicles, gt_lines = [], []
        for vid, prototype, ry_deg, t, dims, specs in scene["vehicles"]:
            R = R_cam_vehicle_from_ypr(np.deg2rad(ry_deg))
            t, dims = np.array(t), np.array(dims)
            parts = render_parts(specs, R, t, dims, camera, wheel_x=(0.32 * dims[0], -0.30 * dims[0]))
            labels = tuple(label for part in parts for label in part.click_labels)
            unseen = unseen_clicks(labels, R, t, dims)
            assert not unseen, f"image {image_id} vehicle {vid}: {unseen} are on faces the camera cannot see"
            corners_uv = camera.project(clip_cuboid_to_near_plane(cuboid_corners_cam(R, t, dims)))
            box = box2d_of_points(corners_uv, size)
            box_json = np.array([round(float(v), 1) for v in box])
            vehicles.append(vehicle_json(Vehicle(vid, prototype, box_json, tuple(parts), ""), decimals=1))
            kitti_type = {"Mid Size Car": "Car"}.get(prototype, prototype)
            obj = object_from_pose(kitti_type, R, t, dims, camera, box, occluded=0, score=None)
            gt_lines.append(format_label_line(obj))
        images.append({"id": image_id, "size": list(size), "camera": camera_json, "vehicles": vehicles})
        (gt_dir / "label_2" / f"{image_id}.txt").write_text("".join(f"{ln}\n" for ln in gt_lines))
        calib_camera = camera if scene["camera"] == "kitti" else Camera(K=camera.K)
        (gt_dir / "calib" / f"{image_id}.txt").write_text(calib_text(calib_camera))
    doc = {"toosicubix": 1, "images": images}
    (HERE / "annotations.json").write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {HERE / 'annotations.json'} and {gt_dir}")


if __name__ == "__main__":
    main()
