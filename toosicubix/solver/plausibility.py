"""Is a fitted pose one a person could have clicked? Two checks that the pixel cost cannot make.

With few clicks, a mirrored solution (the vehicle upside down, or turned end for end and tilted) can fit
the clicks as well as the true one. Two facts rule most of them out:

- **Upright**: a camera on a vehicle or a pole sees other vehicles roughly upright. The angle between the
  vehicle's up axis (Z) and the road normal (when known, else the camera's up direction -y) stays far below
  ``max_tilt``.
- **Seen faces**: every clicked part lies on a face of the cuboid that is turned to the camera (a tyre
  also from its end of the vehicle, under the bumper; an edge or a corner from any adjacent face). A
  face seen within ``GRAZING_DEG`` of edge-on still counts, for noise. Which faces a part can be seen on is
  the part vocabulary's (:func:`toosicubix.vocabulary.faces_of_click`).
"""

from __future__ import annotations

import numpy as np

from toosicubix.vocabulary import faces_of_click, faces_seen_from

#: A face this close to edge-on (degrees) still counts as turned to the camera.
GRAZING_DEG = 15.0



def tilt(R_cam_vehicle: np.ndarray, up: np.ndarray | None = None) -> float:
    """Angle (radians) between the vehicle's up axis and ``up`` (3,), by default the camera's up (-y)."""
    up = np.array([0.0, -1.0, 0.0]) if up is None else up
    return float(np.arccos(np.clip(R_cam_vehicle[:, 2] @ up, -1.0, 1.0)))


def faces_turned_to_camera(R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, dimensions: np.ndarray,
                           grazing_deg: float = GRAZING_DEG) -> dict[str, bool]:
    """For each face but the bottom: is it turned to the camera? A face seen edge-on counts, and one
    turned away by up to ``grazing_deg`` (negative: it must be turned toward the camera by that much)."""
    camera_vehicle = -np.asarray(t_cam_vehicle, dtype=float) @ R_cam_vehicle  # R^T (-t): (3,)
    return faces_seen_from(camera_vehicle, dimensions, grazing_deg)


def unseen_clicks(click_labels: tuple[str, ...], R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray,
                  dimensions: np.ndarray, click_faces: tuple[tuple[str, ...] | None, ...] | None = None) -> list[str]:
    """The clicked parts that would lie on faces turned away from the camera. ``click_faces``: the faces of each
    click (:attr:`PartsModel.click_faces`, which places keypoints by their position); default the vocabulary's."""
    visible = faces_turned_to_camera(R_cam_vehicle, t_cam_vehicle, dimensions)
    if click_faces is None:
        click_faces = tuple(faces_of_click(label) for label in click_labels)
    out = []
    for label, faces in zip(click_labels, click_faces, strict=True):
        if faces is not None and not any(visible[f] for f in faces):
            out.append(label)
    return out


def implausibility(click_labels: tuple[str, ...], R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray,
                   dimensions: np.ndarray, max_tilt: float | None, up: np.ndarray | None = None,
                   click_faces: tuple[tuple[str, ...] | None, ...] | None = None) -> str | None:
    """Why a pose is implausible, or None when it passes both checks. ``up``: the road normal when known;
    ``click_faces`` as :func:`unseen_clicks` takes them."""
    if max_tilt is not None and tilt(R_cam_vehicle, up) > max_tilt:
        return f"tilted {np.rad2deg(tilt(R_cam_vehicle, up)):.0f} degrees from upright"
    unseen = unseen_clicks(click_labels, R_cam_vehicle, t_cam_vehicle, dimensions, click_faces)
    if unseen:
        return f"clicked parts on faces turned away from the camera: {', '.join(sorted(set(unseen)))}"
    return None
