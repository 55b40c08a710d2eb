"""Naming on the annotate page from a vehicle's fit: which part an unnamed click is.

With a keypoint mapping (``annotate --mapping``), a click made without a name is named once the vehicle's named
clicks fit a cuboid: it takes the name of the keypoint most probably clicked there (:func:`nearest_parts`) among the
candidates :func:`naming_candidates` places on the fitted cuboid (its keypoints not clicked yet, each at its typical
place, on a face turned to the camera). The vocabulary's point parts are named by the prototype's prior cuboid
(:mod:`toosicubix.web.placement`), before a fit and after; this module's rule (the nearest part not clicked yet at
its typical place, :func:`toosicubix.solver.guidance.suggest_clicks`) names them only with
``NamingSettings(after_fit="fit")``, as the page did before issue 33, and for a track's vehicle placed by its other
frames alone.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from toosicubix.camera import Camera
from toosicubix.formats.results import VehicleResult
from toosicubix.parts.linear import TypicalKeypoint
from toosicubix.solver.plausibility import faces_turned_to_camera
from toosicubix.solver.refine import MIN_DEPTH

#: How far past edge-on (degrees) a face a keypoint sits near may be turned for an unnamed click to be named that
#: keypoint; negative: turned toward the camera by at least that. 0: any face turned toward the camera (a click
#: shows its part is seen), chosen by rule 12 of benchmarks/decisions.md over the targets' -5 (VISIBLE_MIN_DEG).
NAMING_GRAZING_DEG = 0.0


def naming_candidates(result: VehicleResult, camera: Camera,
                      keypoints: Mapping[str, TypicalKeypoint] | None = None,
                      points: set[str] | None = None,
                      grazing_deg: float = NAMING_GRAZING_DEG,
                      click_sigma: float | None = None) -> list[dict[str, Any]]:
    """What an unnamed click on a fitted vehicle may be, each as ``next_clicks`` has it (kind, name, uv (1, 2),
    visible): the vocabulary's point parts among the fit's ``next_clicks`` (at their typical positions; only
    those named in ``points`` when given), then each keypoint of ``keypoints`` projected from its typical place
    (``at``, fractions of the dimensions) on the fitted cuboid, visible when one of the faces it is seen from
    (:attr:`~toosicubix.parts.linear.TypicalKeypoint.faces`) is turned to the camera (``grazing_deg``: turned
    away by up to that, negative: toward it by at least that), or when it has none. A keypoint behind the camera
    is left out. With ``click_sigma`` (pixels), each keypoint also gets ``sigma_px``, how far a click of it may
    lie from its predicted pixel (the click noise and its spread projected at its depth), and ``prior``, its
    ``clicked_share``: :func:`nearest_parts` then ranks by probability (benchmarks/decisions.md, rule 15)."""
    out = [s for s in (result.next_clicks or []) if s["kind"] == "point" and (points is None or s["name"] in points)]
    if not keypoints or not result.ok:
        return out
    R, t, d = (np.asarray(x, dtype=float) for x in (result.R_cam_vehicle, result.t_cam_vehicle, result.dimensions))
    facing = faces_turned_to_camera(R, t, d, grazing_deg=grazing_deg)
    for name, k in keypoints.items():
        point_cam = R @ (d * np.asarray(k.at, dtype=float)) + t
        if point_cam[2] <= MIN_DEPTH:
            continue
        faces = k.faces
        candidate = {"kind": "keypoint", "name": name, "uv": camera.project(point_cam[None]).tolist(),
                     "visible": faces is None or any(facing[f] for f in faces)}
        if click_sigma is not None:
            candidate["sigma_px"] = _spread_px(camera, point_cam[2], np.asarray(k.spread, dtype=float) * d,
                                               click_sigma)
            candidate["prior"] = float(k.clicked_share)
        out.append(candidate)
    return out


def _spread_px(camera: Camera, depth: float, spread_m: np.ndarray, click_sigma: float) -> float:
    """How far, per image coordinate, a click of a keypoint at ``depth`` (metres) with ``spread_m`` (3,) (its
    spread, metres per vehicle axis) may lie from its predicted pixel: the click noise and the spread projected,
    two of its three axes lying in the image on average."""
    f = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    return float(math.sqrt(click_sigma**2 + (f / depth) ** 2 * float(spread_m @ spread_m) / 3.0))


def nearest_parts(uv: list[float], suggestions: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The point parts and keypoints among ``suggestions`` (:func:`naming_candidates`: kind, name, uv, visible)
    that are visible, each with its ``kind`` and ``distance_px`` to the pixel ``uv``: the most probable first
    when every one has a ``sigma_px`` and a ``prior`` (the negative log of prior times a 2D Gaussian of the
    distance, ``-ln prior + r^2 / (2 s^2) + 2 ln s``), else the nearest first."""
    out, costs = [], []
    for s in suggestions:
        if s["kind"] not in ("point", "keypoint") or not s["visible"]:
            continue
        distance = math.dist(uv, s["uv"][0])
        out.append({"kind": s["kind"], "name": s["name"], "distance_px": round(distance, 2), "uv": s["uv"][0]})
        if "sigma_px" in s and "prior" in s:
            sigma = s["sigma_px"]
            costs.append(-math.log(s["prior"]) + distance**2 / (2 * sigma**2) + 2 * math.log(sigma))
    if out and len(costs) == len(out):
        return [o for _, o in sorted(zip(costs, out, strict=True), key=lambda co: co[0])]
    return sorted(out, key=lambda s: s["distance_px"])
