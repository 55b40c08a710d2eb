"""Synthetic ground truth in the three formats `toosicubix eval` reads, and predictions of known error.

KITTI boxes are given by decimals that the label format prints exactly (2 decimals), so ground truth
read back equals the scene to the last bit and a prediction built from the scene has zero error.
Cityscapes boxes are built from a camera-frame pose by the rules of
``shared/data/cityscapes3d/CONVENTIONS.md``, written out here independently of the reader
(quaternions by scipy, not by toosicubix).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from toosicubix.formats.results import ImageResult, VehicleResult, dumps, results_to_json
from toosicubix.geometry import R_cam_vehicle_from_ypr, box2d_of_points, cuboid_corners_cam, project_pinhole, so3_exp

# A KITTI-like camera 2: P2 = K [I | T2], T2 = K^-1 P2[:, 3] about 6 cm, as in the real calib files.
K_KITTI = np.array([[721.5377, 0.0, 609.5593], [0.0, 721.5377, 172.854], [0.0, 0.0, 1.0]])
T2 = np.array([0.0597, -0.00035, 0.00275])
P2 = K_KITTI @ np.column_stack([np.eye(3), T2])
KITTI_SIZE = (1242, 375)


@dataclass(frozen=True)
class KittiBox:
    """A KITTI ground-truth object: location in camera 0, dimensions ``(l, w, h)``, yaw; all on a 0.01 grid."""

    cls: str
    location_rect: tuple[float, float, float]
    lwh: tuple[float, float, float]
    ry: float
    occluded: int = 0
    truncated: float = 0.0

    @property
    def R_cam_vehicle(self) -> np.ndarray:
        return R_cam_vehicle_from_ypr(self.ry)

    def t_cam(self, t2: np.ndarray = T2) -> np.ndarray:
        return np.asarray(self.location_rect) + t2

    def box2d(self) -> np.ndarray:
        """The projected cuboid's box in image 2, clipped, rounded to 2 decimals as the label prints it."""
        corners = cuboid_corners_cam(self.R_cam_vehicle, self.t_cam(), np.array(self.lwh))
        return np.round(box2d_of_points(project_pinhole(K_KITTI, corners), KITTI_SIZE), 2)


#: Two images of the object benchmark; a third with ground truth only.
KITTI_SCENE: dict[str, list[KittiBox]] = {
    "000001": [
        KittiBox("Car", (-6.5, 1.65, 14.2), (3.9, 1.62, 1.5), 0.3, occluded=0),
        KittiBox("Car", (-1.2, 1.7, 24.6), (4.2, 1.7, 1.45), -1.4, occluded=1),
        KittiBox("Van", (4.3, 1.6, 9.8), (4.95, 1.9, 2.18), 1.57, occluded=2),
        KittiBox("Truck", (9.1, 1.75, 43.5), (9.5, 2.5, 3.3), -0.2, occluded=0),
    ],
    "000002": [
        KittiBox("Car", (2.1, 1.66, 7.4), (3.7, 1.58, 1.49), 2.8, occluded=0),
        KittiBox("Car", (-4.0, 1.61, 33.3), (4.1, 1.66, 1.52), 0.05, occluded=1),
        KittiBox("Car", (6.6, 1.7, 62.0), (4.0, 1.6, 1.5), -3.0, occluded=0),
    ],
    "000003": [KittiBox("Car", (0.5, 1.6, 20.0), (4.0, 1.6, 1.5), 0.0)],
}
#: Lines that are never scored by default: they go into image 000001 after its vehicles.
KITTI_EXTRA_LINES = (
    "Pedestrian 0.00 0 -0.20 712.40 143.00 810.73 307.92 1.89 0.48 1.20 1.84 1.47 8.41 0.01",
    "DontCare -1 -1 -10 503.89 169.71 590.61 190.13 -1 -1 -1 -1000 -1000 -1000 -10",
)


def kitti_line(box: KittiBox, prefix: str = "") -> str:
    """A label line with every value on the 0.01 grid (15 fields, plus ``prefix``)."""
    x1, y1, x2, y2 = box.box2d()
    loc = box.location_rect
    alpha = box.ry - np.arctan2(loc[0], loc[2])
    l_, w, h = box.lwh
    return (f"{prefix}{box.cls} {box.truncated:.2f} {box.occluded} {alpha:.2f} {x1:.2f} {y1:.2f} {x2:.2f} {y2:.2f} "
            f"{h:.2f} {w:.2f} {l_:.2f} {loc[0]:.2f} {loc[1]:.2f} {loc[2]:.2f} {box.ry:.2f}")


def calib_text(P2_matrix: np.ndarray = P2) -> str:
    """An object-style calib file (P0 ... P3, R0_rect, Tr_velo_to_cam, Tr_imu_to_velo)."""
    P0 = K_KITTI @ np.column_stack([np.eye(3), np.zeros(3)])
    rows = {"P0": P0, "P1": P0, "P2": P2_matrix, "P3": P2_matrix, "R0_rect": np.eye(3),
            "Tr_velo_to_cam": np.eye(3, 4), "Tr_imu_to_velo": np.eye(3, 4)}
    return "".join(f"{k}: " + " ".join(f"{v:.12e}" for v in np.ravel(m)) + "\n" for k, m in rows.items())


def write_kitti_object(root: Path, with_calib: bool = True, label_dir: str = "label_2") -> Path:
    """``root/label_2/<id>.txt`` (+ ``root/calib/<id>.txt``) for :data:`KITTI_SCENE`; returns root."""
    (root / label_dir).mkdir(parents=True, exist_ok=True)
    for image_id, boxes in KITTI_SCENE.items():
        lines = [kitti_line(b) for b in boxes]
        if image_id == "000001":
            lines += KITTI_EXTRA_LINES
        (root / label_dir / f"{image_id}.txt").write_text("\n".join(lines) + "\n")
        if with_calib:
            (root / "calib").mkdir(exist_ok=True)
            (root / "calib" / f"{image_id}.txt").write_text(calib_text())
    return root


#: Tracking: sequence 0003, frames 10 and 11 hold the two object images' boxes; track ids by position.
TRACKING_SEQUENCE = "0003"
TRACKING_FRAMES = {10: KITTI_SCENE["000001"], 11: KITTI_SCENE["000002"]}


def write_kitti_tracking(root: Path, with_calib: bool = True) -> Path:
    """``root/label_02/0003.txt`` (+ ``root/calib/0003.txt``); frame 12 has no rows; returns root."""
    (root / "label_02").mkdir(parents=True, exist_ok=True)
    lines = []
    for frame, boxes in TRACKING_FRAMES.items():
        lines += [kitti_line(b, prefix=f"{frame} {k} ") for k, b in enumerate(boxes)]
        lines.append(f"{frame} -1 DontCare -1 -1 -10 1.0 2.0 30.0 40.0 -1000 -1000 -1000 -10 -10 -10 -1")
    (root / "label_02" / f"{TRACKING_SEQUENCE}.txt").write_text("\n".join(lines) + "\n")
    if with_calib:
        (root / "calib").mkdir(exist_ok=True)
        (root / "calib" / f"{TRACKING_SEQUENCE}.txt").write_text(calib_text())
    return root


# --- Cityscapes 3D --------------------------------------------------------------------------------------

#: ``p_S = M p_C``: camera axes (x fwd, y left, z up) to image-style axes (x right, y down, z fwd).
M = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
#: A sensor with extrinsic pitch and yaw (not the identity), translation as in the public samples.
R_SENSOR_EGO = Rotation.from_euler("zyx", [0.8, 2.2, 0.3], degrees=True).as_matrix()
T_SENSOR_EGO = np.array([-1.650, -0.133, -1.284])
CS_INTRINSICS = {"fx": 2262.52, "fy": 2265.30, "u0": 1096.98, "v0": 513.137}
K_CS = np.array([[2262.52, 0.0, 1096.98], [0.0, 2265.30, 513.137], [0.0, 0.0, 1.0]])
CS_SIZE = (2048, 1024)


@dataclass(frozen=True)
class CamBox:
    """A cuboid posed in the camera frame of K (x right, y down, z forward), full rotation."""

    label: str
    R_cam_vehicle: np.ndarray
    t_cam: np.ndarray
    lwh: np.ndarray
    occlusion: float = 0.0
    instance_id: int = 26001
    type: str = "Mid Size Car"


def _upright(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    return R_cam_vehicle_from_ypr(yaw, pitch, roll)


CITYSCAPES_SCENE: dict[str, list[CamBox]] = {
    "aachen_000000_000019": [
        CamBox("car", _upright(0.4, 0.03, -0.02), np.array([-5.0, 1.3, 15.0]), np.array([4.2, 1.75, 1.45]), 0.05),
        CamBox("car", _upright(-1.5, -0.02, 0.01), np.array([1.5, 1.25, 26.0]), np.array([4.1, 1.7, 1.5]), 0.3, 26002),
        CamBox("truck", _upright(1.7, 0.01, 0.0), np.array([4.5, 1.4, 16.0]), np.array([6.5, 2.3, 2.9]), 0.55, 27001,
               "Mini Truck"),
        CamBox("car", _upright(3.0), np.array([-2.0, 1.35, 55.0]), np.array([4.3, 1.8, 1.55]), 0.9, 26003),
    ],
    "bochum_000000_000313": [
        CamBox("car", _upright(0.1, 0.0, 0.04), np.array([3.0, 1.3, 9.0]), np.array([4.0, 1.7, 1.4]), 0.0, 26004),
        CamBox("bicycle", _upright(0.2), np.array([-3.0, 1.3, 8.0]), np.array([1.8, 0.6, 1.7]), 0.0, 33001, "Bicycle"),
    ],
}


def cs_box_json(box: CamBox) -> dict:
    """A gtBbox3d ``objects`` entry for a camera-frame pose, by the CONVENTIONS rules run backwards."""
    R_q = R_SENSOR_EGO.T @ M.T @ box.R_cam_vehicle
    centre_S = box.t_cam + 0.5 * box.lwh[2] * box.R_cam_vehicle[:, 2]
    centre_V = R_SENSOR_EGO.T @ (M.T @ centre_S - T_SENSOR_EGO)
    x, y, z, w = Rotation.from_matrix(R_q).as_quat()
    # Amodal box: the 8 vertices in V (centre +- half size along the box axes) projected with K M [R | t].
    signs = np.array([[sx, sy, sz] for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)])
    vertices_V = (signs * box.lwh / 2.0) @ R_q.T + centre_V
    uv = project_pinhole(K_CS, (vertices_V @ R_SENSOR_EGO.T + T_SENSOR_EGO) @ M.T)
    x1, y1, x2, y2 = box2d_of_points(uv, CS_SIZE)
    return {
        "2d": {"modal": [x1, y1, x2 - x1, y2 - y1], "amodal": [x1, y1, x2 - x1, y2 - y1]},
        "3d": {"center": centre_V.tolist(), "dimensions": box.lwh.tolist(), "rotation": [w, x, y, z],
               "type": box.type, "format": "CRS_ISO8855"},
        "occlusion": box.occlusion, "truncation": 0.0, "instanceId": box.instance_id, "label": box.label,
        "score": 1.0,
    }


def cs_document(boxes: list[CamBox], ignore: bool = True) -> dict:
    doc = {
        "imgWidth": CS_SIZE[0], "imgHeight": CS_SIZE[1],
        "sensor": {"sensor_T_ISO_8855": np.column_stack([R_SENSOR_EGO, T_SENSOR_EGO]).tolist(),
                   **CS_INTRINSICS, "baseline": 0.209313},
        "objects": [cs_box_json(b) for b in boxes],
    }
    if ignore:
        doc["ignore"] = [{"2d": [10, 400, 60, 40], "label": "car", "instanceId": 0}]
    return doc


def write_cityscapes(root: Path) -> Path:
    """``root/<city>/<id>_gtBbox3d.json`` for :data:`CITYSCAPES_SCENE`; returns root."""
    for image_id, boxes in CITYSCAPES_SCENE.items():
        folder = root / image_id.split("_")[0]
        folder.mkdir(parents=True, exist_ok=True)
        (folder / f"{image_id}_gtBbox3d.json").write_text(json.dumps(cs_document(boxes), indent=1))
    return root


# --- predictions of known error -------------------------------------------------------------------------

@dataclass(frozen=True)
class Pose:
    """A prediction: ``R_cam_vehicle`` (3, 3), ``t_cam_vehicle`` (3,), ``(dx, dy, dz)``, 2D box, class."""

    R: np.ndarray
    t: np.ndarray
    d: np.ndarray
    box2d: np.ndarray
    cls: str


def moved(p: Pose, offset: np.ndarray) -> Pose:
    return replace(p, t=p.t + offset)


def rotated(p: Pose, axis_angle_vehicle: np.ndarray) -> Pose:
    """Rotated about the vehicle's own axes: ``R exp([w]x)``; the angle of the error is ``|w|``."""
    return replace(p, R=p.R @ so3_exp(axis_angle_vehicle))


def resized(p: Pose, factor: float) -> Pose:
    return replace(p, d=p.d * factor)


def kitti_pose(box: KittiBox) -> Pose:
    """The exact prediction of a KITTI box, in camera 2."""
    return Pose(box.R_cam_vehicle, box.t_cam(), np.array(box.lwh), box.box2d(), box.cls)


def cam_pose(box: CamBox) -> Pose:
    """The exact prediction of a Cityscapes box, in the camera of K."""
    d = cs_box_json(box)["2d"]["amodal"]
    return Pose(box.R_cam_vehicle, box.t_cam, box.lwh, np.array([d[0], d[1], d[0] + d[2], d[1] + d[3]]), box.label)


def write_results(out_dir: Path, images: dict[str, list[Pose]], K: np.ndarray, t_cam_rect: np.ndarray,
                  image_size: tuple[int, int], failed: dict[str, list[np.ndarray]] | None = None) -> Path:
    """``out_dir/results.json`` with one vehicle per pose (ids "0", "1", ...), plus failed ones (no pose)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    results = []
    for image_id, poses in images.items():
        vehicles = [VehicleResult(id=str(k), status="ok", error=None, prototype=p.cls, R_cam_vehicle=p.R,
                                  t_cam_vehicle=p.t, dimensions=p.d, box2d=p.box2d, kitti_type=p.cls)
                    for k, p in enumerate(poses)]
        for k, box in enumerate((failed or {}).get(image_id, [])):
            vehicles.append(VehicleResult(id=f"f{k}", status="failed", error="PnP found no solution",
                                          prototype="Car", box2d=box, kitti_type="Car"))
        results.append(ImageResult(id=image_id, K=K, t_cam_rect=t_cam_rect, image_size=image_size, vehicles=vehicles))
    (out_dir / "results.json").write_text(dumps(results_to_json(results, {"generator": "tests"})))
    return out_dir


#: The known errors applied to the i-th vehicle of every image, in this order (cycled).
SHIFT = 0.4  # metres along the vehicle's forward axis: IoU = (l - SHIFT) / (l + SHIFT)
ANGLE = np.deg2rad(7.0)  # about the axis (0.3, 0.5, 0.8) of the vehicle: E_R = 7 degrees
SCALE = 1.1  # all dimensions: E_d = 0.1


def perturb(k: int, p: Pose) -> Pose:
    """Vehicle k's prediction: 0 exact, 1 moved forward by SHIFT, 2 rotated by ANGLE, 3 resized by SCALE."""
    kind = k % 4
    if kind == 1:
        return moved(p, SHIFT * p.R[:, 0])
    if kind == 2:
        axis = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
        return rotated(p, ANGLE * axis)
    if kind == 3:
        return resized(p, SCALE)
    return p

