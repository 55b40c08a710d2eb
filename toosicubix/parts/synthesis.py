"""Clicks rendered from a known cuboid: the forward model of :mod:`toosicubix.parts`.

Given a pose, dimensions, the wheel positions and every annotation's auxiliary values (``Z`` of a
badge, ``(Y, Z)`` of a pair of lights, ...), this projects the parts' 3D points into the image. Tests,
the bundled sample and the simulated annotator use it; it adds no noise and judges no visibility.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from toosicubix.camera import Camera
from toosicubix.model import Part
from toosicubix.parts.linear import build_parts_model
from toosicubix.vocabulary import KINDS


@dataclass(frozen=True)
class PartSpec:
    """An annotation to render.

    Attributes
    ----------
    kind : 'point', 'symmetry', 'direction' or 'length'
    name : part name, symmetry face, direction axis or length feature (as in the annotation file)
    aux : its auxiliary unknowns by name, metres in the vehicle frame: 'Z' for a centre badge or an edge
        point, 'X' for top-center, 'Y' and 'Z' for a front or rear pair or a plate, 'X' and 'Y' for a roof
        pair, 'X', 'Y', 'Z' for a direction's tail, 'Zt' for a tyre's top
    known : ``(metres, sigma)`` a length annotation states
    """

    kind: str
    name: str
    aux: dict[str, float] = field(default_factory=dict)
    known: tuple[float, float] | None = None


def true_parameters(specs: list[PartSpec], dimensions: np.ndarray,
                    wheel_x: tuple[float, float]) -> tuple[list[Part], np.ndarray]:
    """The parts (with placeholder pixels) and the true parameter vector ``p`` of the parts model.

    Parameters
    ----------
    dimensions : (3,) ``(dx, dy, dz)``
    wheel_x : X of the front and rear axles in the vehicle frame, metres

    Returns
    -------
    parts : the annotations with zero pixels
    p : (P,) ordered as ``build_parts_model(parts).param_names``
    """
    parts = [Part(s.kind, s.name, np.zeros((len(KINDS[s.kind].clicks), 2)), f"spec[{k}]", s.known)
             for k, s in enumerate(specs)]
    model = build_parts_model(parts)
    values = {"dx": dimensions[0], "dy": dimensions[1], "dz": dimensions[2], "Xwf": wheel_x[0], "Xwr": wheel_x[1]}
    p = np.empty(model.n_params)
    for i, name in enumerate(model.param_names):
        if name in values:
            p[i] = values[name]
        else:  # "parts[k].Z"
            k, what = name[len("parts["):].split("].")
            try:
                p[i] = specs[int(k)].aux[what]
            except KeyError:
                raise ValueError(f"spec {k} ({specs[int(k)].kind} {specs[int(k)].name}) needs aux {what!r}") from None
    return parts, p


def render_parts(specs: list[PartSpec], R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray,
                 dimensions: np.ndarray, camera: Camera, wheel_x: tuple[float, float] = (0.0, 0.0)) -> list[Part]:
    """Project the annotations of a posed cuboid into the image (with the camera's distortion).

    Parameters
    ----------
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,); dimensions : (3,)
    wheel_x : X of the front and rear axles, metres

    Returns
    -------
    list of Part, pixels filled in, in ``specs`` order
    """
    parts, p = true_parameters(specs, np.asarray(dimensions, dtype=float), wheel_x)
    model = build_parts_model(parts)
    points_cam = model.points_vehicle(p) @ np.asarray(R_cam_vehicle).T + np.asarray(t_cam_vehicle)
    uv = camera.project(points_cam)
    out, start = [], 0
    for part in parts:
        k = len(part.uv)
        out.append(Part(part.kind, part.name, uv[start:start + k].copy(), part.json_path, part.known))
        start += k
    return out
