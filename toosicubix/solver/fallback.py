"""Starts at typical part positions, for click sets whose 3D cost has a trivial minimum.

The coordinate descent's 3D cost ``sum |M_i (R A_i p + t)|^2`` is zero when every clicked point sits at the
camera centre. Parts whose auxiliary unknowns can move all clicked points onto one point allow exactly that:
symmetry pairs (``Y -> 0``, ``Z -> dz``) with roof pairs (``X -> dx / 2``), as real clicks on lights, glass
corners and plates give. The size prior is then met exactly, every start collapses onto the camera, and none
is in front of it. Such starts are replaced by shapes fixed at typical positions (lights at 38 % of the
width and 55 % of the height, as :mod:`.guidance` places them; roof pairs at 35 % of the width; wheels at a
third of the length from the centre), with only ``t`` solved for each start's rotation: linear, and it cannot
collapse, since the points are fixed and distinct. The refinement then frees every unknown.
"""

from __future__ import annotations

import numpy as np

from toosicubix import vocabulary
from toosicubix.solver.problem import Problem

#: Typical values of the auxiliary unknowns as fractions of (dx, dy, dz), by (kind, the part's name or its
#: vocabulary shape, or '*' for every name of the kind, the unknown).
_TYPICAL = {
    ("symmetry", "front", "Y"): (1, 0.38), ("symmetry", "front", "Z"): (2, 0.55),
    ("symmetry", "rear", "Y"): (1, 0.38), ("symmetry", "rear", "Z"): (2, 0.55),
    ("symmetry", "roof", "X"): (0, -0.1), ("symmetry", "roof", "Y"): (1, 0.35),
    ("point", "front-center", "Z"): (2, 0.45), ("point", "rear-center", "Z"): (2, 0.45),
    ("point", "top-center", "X"): (0, 0.0), ("point", "edge", "Z"): (2, 0.5),
    ("length", "plate-front", "Y"): (1, 0.12), ("length", "plate-front", "Z"): (2, 0.35),
    ("length", "plate-rear", "Y"): (1, 0.12), ("length", "plate-rear", "Z"): (2, 0.45),
    ("length", "tyre", "Zt"): (2, 0.42), ("plate", "*", "W"): (1, 0.24),
}
_WHEELS = {"Xwf": (0, 0.33), "Xwr": (0, -0.33), "Zh": (2, 0.22)}


def typical_p(problem: Problem) -> np.ndarray:
    """``p`` (P,) with the prior's mean dimensions and every auxiliary unknown at its typical value (0 for an
    arrow's position and for unknowns without one), metres."""
    parts = problem.parts
    d = problem.prior.mean
    p = np.zeros(parts.n_params)
    p[:3] = d
    part_of = {int(k): vocabulary.click(label) for k, label in zip(parts.click_part, parts.click_labels, strict=True)}
    for j, name in enumerate(parts.param_names[3:], start=3):
        if name in _WHEELS:
            axis, fraction = _WHEELS[name]
        else:
            k, unknown = int(name[name.index("[") + 1:name.index("]")]), name.split(".")[-1]
            c = part_of.get(k)
            if c is None:
                continue
            shape = vocabulary.entry(c.kind, c.name).get("shape")
            for key in ((c.kind, c.name, unknown), (c.kind, shape, unknown), (c.kind, "*", unknown)):
                if key in _TYPICAL:
                    axis, fraction = _TYPICAL[key]
                    break
            else:
                continue
        p[j] = fraction * d[axis]
    return p


def typical_starts(problem: Problem, R_starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each start rotation (B, 3, 3): the translation (B, 3) that best fits the clicks with the shape fixed
    at :func:`typical_p`, by linear least squares on the 3D cost; and that ``p`` (B, P)."""
    p = typical_p(problem)
    X = problem.A @ p  # (N, 3) vehicle frame
    u = problem.u[:, :2]
    # M_i (R X_i + t) with M_i = [[1, 0, -x_i], [0, 1, -y_i]]: rows (2N, 3) for t, constant (B, 2N).
    M = np.zeros((len(u), 2, 3))
    M[:, 0, 0] = M[:, 1, 1] = 1.0
    M[:, :, 2] = -u
    M_rows = M.reshape(-1, 3)
    Y = np.einsum("bij,nj->bni", R_starts, X)  # (B, N, 3)
    constant = np.einsum("nij,bnj->bni", M, Y).reshape(len(R_starts), -1)
    t, *_ = np.linalg.lstsq(M_rows, -constant.T, rcond=None)
    return t.T, np.tile(p, (len(R_starts), 1))
