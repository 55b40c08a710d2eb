"""The camera's road normal, estimated from a batch's own fits (what ``toosicubix fit`` does unless it is given
a ground: ``--road-normal``, ``--kitti-ground``, a camera height or pitch, ``--joint-ground``).

A camera on a vehicle sees the others standing upright on a road whose normal, in its own frame, depends on
how it is mounted (ApolloCar3D's camera 5 looks about 9 degrees up: the road's horizon lies 360 px below the
image centre). Without that normal a fit only knows that
a vehicle stands within 45 degrees of the camera's up, and far vehicles, whose clicks barely tell perspective,
keep the depth-reversed pose of their clicks (a vehicle reflected through a plane across the line of sight
projects almost as it does, tilted by twice the viewing angle): the clicks fit both. The batch knows the normal:
the pilot fit (:mod:`toosicubix.pipeline.click_noise`) gives up to 400 vehicles' up axes, and their median is the
road's normal in the camera's frame, per camera (images with the same intrinsics).

For each camera with at least :data:`MIN_VEHICLES` fitted pilot vehicles on images without a ground block of
their own, the estimate is the normalised component-wise median of their up axes ``R_cam_vehicle[:, 2]``. It is
refused when their median angle from it exceeds :data:`MAX_SPREAD_DEG` (they do not share a road). Those images
are then fitted with the ground block :func:`ground_block`: the normal known within :data:`NORMAL_SIGMA_DEG`,
vehicles upright on it within :data:`UPRIGHT_SIGMA_DEG`, no camera height (the scale still comes from the sizes).

These values were fixed before the comparison run by rule 7 of benchmarks/decisions.md: the sigmas from the
spread of ApolloCar3D's learning-half ground-truth up axes (median 2.0, 90 %: 5.2 degrees), the thresholds
before any result.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from toosicubix.camera import Camera
from toosicubix.formats.results import ImageResult
from toosicubix.model import GroundOverride, Image

#: Fewer fitted pilot vehicles of a camera than this give it no estimate.
MIN_VEHICLES = 30
#: The pilot's up axes must lie within this median angle (degrees) of their estimate.
MAX_SPREAD_DEG = 10.0
#: The ground block an estimate becomes: the normal's uncertainty and how far vehicles lean from it (degrees).
NORMAL_SIGMA_DEG = 3.0
UPRIGHT_SIGMA_DEG = 2.0

CameraKey = tuple[float, ...]


def camera_key(camera: Camera) -> CameraKey:
    """Which camera an image was taken with: ``(fx, fy, cx, cy, skew, *distortion)``, the intrinsics to 0.01 px
    and the distortion to 1e-6."""
    k = tuple(round(float(v), 2) for v in np.asarray(camera.K, dtype=float).ravel()[[0, 4, 2, 5, 1]])
    d = () if camera.distortion is None else tuple(round(float(v), 6) for v in np.ravel(camera.distortion))
    return k + d


@dataclass(frozen=True)
class RoadNormal:
    """One camera's road normal as the batch estimated it, or why it did not.

    Attributes
    ----------
    camera : ``(fx, fy, cx, cy)`` of the camera, pixels
    images : images of the batch taken with it (without a ground block of their own)
    normal : (3,) unit normal in the camera frame, or None when not estimated
    vehicles : fitted pilot vehicles it rests on
    spread_deg : their up axes' median angle from it
    reason : why there is no estimate, or None
    """

    camera: tuple[float, float, float, float]
    images: int
    normal: tuple[float, float, float] | None
    vehicles: int
    spread_deg: float | None
    reason: str | None = None

    def to_json(self) -> dict:
        return {"camera": dict(zip(("fx", "fy", "cx", "cy"), self.camera, strict=True)),
                "images": self.images, "normal": None if self.normal is None else list(self.normal),
                "normal_sigma_deg": NORMAL_SIGMA_DEG if self.normal is not None else None,
                "upright_sigma_deg": UPRIGHT_SIGMA_DEG if self.normal is not None else None,
                "vehicles": self.vehicles, "spread_deg": self.spread_deg, "reason": self.reason}

    def describe(self) -> str:
        """One line for the command's summary."""
        where = f"camera fx {self.camera[0]:.0f} px ({self.images} image{'' if self.images == 1 else 's'})"
        if self.normal is None:
            return f"road normal of {where}: not estimated, {self.reason}; vehicles only kept within 45 deg of upright"
        n = self.normal
        up = float(np.degrees(np.arctan2(n[2], -n[1])))  # the camera's pitch above the road
        return (f"road normal of {where}: ({n[0]:.3f}, {n[1]:.3f}, {n[2]:.3f}), the camera looking "
                f"{abs(up):.1f} deg {'up' if up >= 0 else 'down'}, estimated from {self.vehicles} vehicles' up axes "
                f"(median {self.spread_deg:.1f} deg from it); vehicles upright on it within {UPRIGHT_SIGMA_DEG:g} deg "
                f"(--road-normal sets it, --road-normal none turns it off)")


def estimate_road_normals(pilot: Iterable[Image], results: Iterable[ImageResult],
                          cameras: dict[CameraKey, int]) -> dict[CameraKey, RoadNormal]:
    """Each camera's :class:`RoadNormal` from the pilot's images and their fits (same order).

    Parameters
    ----------
    pilot, results : the pilot's images and their image results, pairwise
    cameras : per camera (:func:`camera_key`), how many images of the batch have no ground block of their own:
        the cameras to estimate for; pilot images with a ground block do not count

    Returns
    -------
    The cameras the pilot has a vehicle of (at most as many as its vehicles, whatever the batch's number of
    cameras); the others have no estimate (:func:`without_pilot` counts them).
    """
    ups: dict[CameraKey, list[np.ndarray]] = {}
    for im, res in zip(pilot, results, strict=True):
        key = camera_key(im.camera)
        if im.ground is None and key in cameras and im.vehicles:
            ups.setdefault(key, []).extend(np.asarray(v.R_cam_vehicle, dtype=float)[:, 2]
                                           for v in res.vehicles if v.ok)
    return {key: _estimate(key[:4], cameras[key], np.array(u).reshape(-1, 3)) for key, u in ups.items()}


def without_pilot(cameras: dict[CameraKey, int], normals: dict[CameraKey, RoadNormal]) -> dict[str, int]:
    """How many cameras, and images of theirs, the pilot had no vehicle of (so no estimate): ``{"cameras": n,
    "images": m}`` (e.g. a batch whose every image has its own intrinsics)."""
    missing = [n for key, n in cameras.items() if key not in normals]
    return {"cameras": len(missing), "images": sum(missing)}


def describe_without_pilot(counts: dict[str, int]) -> str:
    """One line for the command's summary (empty when every camera had pilot vehicles)."""
    if not counts["cameras"]:
        return ""
    return (f"road normal: none for {counts['cameras']} more camera(s) ({counts['images']} images): the pilot had "
            f"none of their vehicles; vehicles only kept within 45 deg of upright (--road-normal sets it)")


def _estimate(camera: tuple, images: int, ups: np.ndarray) -> RoadNormal:
    """``ups``: (n, 3) unit up axes of one camera's fitted pilot vehicles, camera frame."""
    if len(ups) < MIN_VEHICLES:
        return RoadNormal(camera, images, None, len(ups), None,
                          f"the pilot fitted {len(ups)} of its vehicles, {MIN_VEHICLES} needed")
    n = np.median(ups, axis=0)
    n /= np.linalg.norm(n)
    spread = float(np.degrees(np.median(np.arccos(np.clip(ups @ n, -1.0, 1.0)))))
    if spread > MAX_SPREAD_DEG:
        return RoadNormal(camera, images, None, len(ups), spread,
                          f"its {len(ups)} vehicles' up axes lie a median {spread:.1f} deg from their median, more "
                          f"than {MAX_SPREAD_DEG:g}: they do not share one road")
    return RoadNormal(camera, images, tuple(float(v) for v in n), len(ups), spread)


def ground_block(normal: RoadNormal) -> GroundOverride:
    """The ground-block fields an estimated normal gives its camera's images."""
    assert normal.normal is not None
    return GroundOverride(normal=normal.normal, normal_sigma_deg=NORMAL_SIGMA_DEG, upright_sigma_deg=UPRIGHT_SIGMA_DEG)
