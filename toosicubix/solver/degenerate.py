"""Why a vehicle's clicks cannot give a cuboid: too few constraints, clicks in one blob or on one line, arrows
without a length (all judged before solving), a direction of the unknowns the answer leaves undetermined, or an
answer at an absurd depth (judged after). Each returns the reason the failed result carries, or None."""

from __future__ import annotations

import numpy as np

from toosicubix.camera import Camera
from toosicubix.parts.linear import PartsModel
from toosicubix.solver.problem import Problem
from toosicubix.vocabulary import click

_BLOCKS = ("rotation", "rotation", "rotation", "position", "position", "position")


def degeneracy(problem: Problem, J: np.ndarray, tolerance: float) -> str | None:
    """A reason when the clicks and the prior leave a direction of the unknowns undetermined, else None.
    ``J`` : (M, 6 + P) the Jacobian at the answer (:func:`.refine.residuals_and_jacobian`)."""
    norms = np.linalg.norm(J, axis=0)
    if np.any(norms == 0.0):
        names = _unknown_names(problem)
        missing = [names[i] for i in np.flatnonzero(norms == 0.0)]
        return f"degenerate clicks: nothing constrains {', '.join(missing)}"
    _, s, Vt = np.linalg.svd(J / norms, full_matrices=False)
    if s[-1] >= tolerance * s[0]:
        return None
    names = _unknown_names(problem)
    null = np.abs(Vt[-1])
    involved = sorted({names[i] for i in np.flatnonzero(null > 0.3 * null.max())})
    return f"degenerate clicks: they do not determine {', '.join(involved)} (Jacobian rank deficient)"


def _unknown_names(problem: Problem) -> list[str]:
    return [*_BLOCKS, *problem.parts.param_names]


#: An arrow shorter than this (pixels) has no direction.
MIN_ARROW_PX = 1.0


def short_arrows(parts: PartsModel) -> str | None:
    """A description of the direction arrows whose tail and head are less than MIN_ARROW_PX apart."""
    found = []
    for i in parts.arrow_tails:
        length = float(np.linalg.norm(parts.uv[i + 1] - parts.uv[i]))
        if length < MIN_ARROW_PX:
            axis = click(parts.click_labels[i]).name
            found.append(f"the {axis} arrow of annotation parts[{parts.click_part[i]}] is {length:.2f} px long")
    return "; ".join(found) + f" (an arrow needs at least {MIN_ARROW_PX:g} px)" if found else None


#: Clicks whose spread (root mean square distance from their centroid along their main direction) is below
#: this many pixels are one blob: a vehicle that small in the image cannot be annotated part by part.
MIN_CLICK_SPREAD_PX = 4.0
#: Clicks whose root mean square distance from their best-fitting line is below this many pixels lie on one
#: line (clicks on a real vehicle's wheels, lights and edges span an area).
MIN_CLICK_THICKNESS_PX = 0.5
#: A fit this far away (metres) is absurd for a vehicle whose parts were clicked.
MAX_DEPTH_M = 1000.0


def degenerate_spread(uv: np.ndarray) -> str | None:
    """Why the clicks ``uv`` (N, 2), pixels, cannot determine a cuboid (clustered or collinear), else None."""
    if len(uv) < 3:
        return None
    spread = np.linalg.svd(uv - uv.mean(axis=0), compute_uv=False) / np.sqrt(len(uv))  # RMS along the axes
    if spread[0] < MIN_CLICK_SPREAD_PX:
        return (f"all {len(uv)} clicks lie in one cluster ({spread[0]:.2f} px RMS spread; at least "
                f"{MIN_CLICK_SPREAD_PX:g} px needed)")
    if spread[1] < MIN_CLICK_THICKNESS_PX:
        return (f"all {len(uv)} clicks lie on one line ({spread[1]:.2f} px RMS off it; at least "
                f"{MIN_CLICK_THICKNESS_PX:g} px needed)")
    return None


def absurd_depth(camera: Camera, t_cam_vehicle: np.ndarray, dimensions: np.ndarray) -> str | None:
    """Why a fit at ``t_cam_vehicle`` (3,), metres, with ``dimensions`` (3,) is too far to be believed, else None:
    beyond ``MAX_DEPTH_M``, or so far that the vehicle spans fewer than ``MIN_CLICK_SPREAD_PX`` pixels."""
    depth = float(t_cam_vehicle[2])
    focal = float(max(camera.K[0, 0], camera.K[1, 1]))
    extent_px = focal * float(np.max(dimensions)) / depth if depth > 0 else np.inf
    if not (np.isfinite(depth) and depth <= MAX_DEPTH_M and extent_px >= MIN_CLICK_SPREAD_PX):
        return (f"degenerate clicks: the fit is at an absurd depth ({depth:.4g} m, where the vehicle spans "
                f"{extent_px:.3g} px; at most {MAX_DEPTH_M:g} m and {MIN_CLICK_SPREAD_PX:g} px)")
    return None


def too_few(parts: PartsModel, needed: int) -> str:
    return (f"too few constraints: {parts.n_clicks} clicked points give {parts.constraints} "
            f"(2 per point minus {parts.n_aux} auxiliary unknowns); at least {needed} are needed to place "
            f"the cuboid with its size prior, 8 to fix its shape from the clicks alone")
