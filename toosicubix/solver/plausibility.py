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

from functools import lru_cache

import numpy as np

from toosicubix.size_priors import axle_prior
from toosicubix.vocabulary import faces_of_click, faces_seen_from

#: A face this close to edge-on (degrees) still counts as turned to the camera.
GRAZING_DEG = 15.0
#: The camera's up direction (-y), the default ``up``.
_CAMERA_UP = np.array([0.0, -1.0, 0.0])



def tilt(R_cam_vehicle: np.ndarray, up: np.ndarray | None = None) -> float:
    """Angle (radians) between the vehicle's up axis and ``up`` (3,), by default the camera's up (-y)."""
    cosine = float(R_cam_vehicle[:, 2] @ (_CAMERA_UP if up is None else up))
    return float(np.arccos(min(max(cosine, -1.0), 1.0)))  # np.clip's answer (a NaN stays one) without its cost


def faces_turned_to_camera(R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, dimensions: np.ndarray,
                           grazing_deg: float = GRAZING_DEG) -> dict[str, bool]:
    """For each face but the bottom: is it turned to the camera? A face seen edge-on counts, and one
    turned away by up to ``grazing_deg`` (negative: it must be turned toward the camera by that much)."""
    camera_vehicle = -np.asarray(t_cam_vehicle, dtype=float) @ R_cam_vehicle  # R^T (-t): (3,)
    return faces_seen_from(camera_vehicle, dimensions, grazing_deg)


def unseen_clicks(click_labels: tuple[str, ...], R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray,
                  dimensions: np.ndarray, click_faces: tuple[tuple[str, ...] | None, ...] | None = None) -> list[str]:
    """The clicked parts that would lie on faces turned away from the camera, in click order. ``click_faces``: the
    faces of each click (:attr:`PartsModel.click_faces`, which places keypoints by their position); default the
    vocabulary's."""
    visible = faces_turned_to_camera(R_cam_vehicle, t_cam_vehicle, dimensions)
    if click_faces is None:
        click_faces = tuple(faces_of_click(label) for label in click_labels)
    unseen: list[int] = []
    for faces, clicks in _by_faces(click_faces):
        for face in faces:
            if visible[face]:
                break
        else:
            unseen += clicks
    return [click_labels[i] for i in sorted(unseen)]


@lru_cache(maxsize=1024)
def _by_faces(click_faces: tuple[tuple[str, ...] | None, ...]) -> tuple[tuple[tuple[str, ...], tuple[int, ...]], ...]:
    """The clicks grouped by their faces (a vehicle's clicks share a few sets, each judged once): each set with its
    clicks' indices; clicks without faces (arrows) left out. Kept per set of faces: the refinement judges a vehicle's
    clicks at every answer it reaches."""
    groups: dict[tuple[str, ...], list[int]] = {}
    for i, faces in enumerate(click_faces):
        if faces is not None:
            groups.setdefault(faces, []).append(i)
    return tuple((faces, tuple(clicks)) for faces, clicks in groups.items())


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


#: What every axle check's reason (:func:`axle_implausibility`) says: the page's likely cause 'axles' reads it.
AXLES_MARK = "axle comes out"
#: How many of the axle prior's standard deviations an axle may sit from where cars have theirs before the fit is
#: implausible (rule 30): 4, a chance of about 1 in 16,000 for a real car of the prior's spread (twice the spread
#: measured on 79 real cars), where a wheel named on the wrong axle sits 14 of them away.
AXLE_IMPLAUSIBLE_SIGMAS = 4.0


def axle_implausibility(param_names: tuple[str, ...], p: np.ndarray, prototype: str, mean_length: float) -> str | None:
    """Why a car's fitted axles are where no car has them, or None: the front axle behind the rear one, or an axle
    more than :data:`AXLE_IMPLAUSIBLE_SIGMAS` of the prototype's axle prior (:func:`toosicubix.size_priors.axle_prior`)
    from where it puts it. ``p`` (P,) the fit's unknowns named by ``param_names``; ``mean_length`` the prior's mean
    ``dx``, metres. None for prototypes without an axle prior and for vehicles whose clicks use no axle."""
    prior = axle_prior(prototype)
    if prior is None:
        return None
    dx = float(p[0])
    axles = {name: float(p[param_names.index(name)]) for name in prior.at if name in param_names}
    if len(axles) == 2 and axles["Xwf"] <= axles["Xwr"]:
        return "the front axle comes out behind the rear one: front and rear wheels look swapped"
    sigma = prior.sigma(mean_length)
    for (name, fraction), axle in zip(prior.at.items(), ("front", "rear"), strict=True):
        if name in axles and abs(axles[name] - fraction * dx) > AXLE_IMPLAUSIBLE_SIGMAS * sigma:
            where = "ahead of" if axles[name] >= 0 else "behind"
            return (f"the {axle} axle comes out {abs(axles[name]):.1f} m {where} the middle of a {dx:.1f} m car, where "
                    f"cars have it about {abs(fraction) * dx:.1f} m {'ahead of' if fraction > 0 else 'behind'} it: a "
                    f"wheel named on the wrong axle, or clicked away from its tyre")
    return None
