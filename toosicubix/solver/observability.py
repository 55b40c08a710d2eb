"""Which unknowns the clicks determine: the spectrum of the data term's Jacobian.

The pixel data term never fixes the scale, so its Jacobian w.r.t. ``(delta, t, p)`` has at least one
null direction. When that is the only one, the clicks determine the cuboid up to scale (8 DoF); each
further null direction is left to the size prior.
"""

from __future__ import annotations

import numpy as np

from toosicubix.solver.problem import Problem
from toosicubix.solver.refine import residuals_and_jacobian


def data_jacobian_spectrum(problem: Problem, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray,
                           p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values and right singular vectors of the column-scaled data Jacobian.

    Columns are scaled to unit norm first, so the spectrum does not depend on units (radians, metres).

    Returns
    -------
    s : (6 + P,) relative singular values, descending, ``s[0] == 1``
    Vt : (6 + P, 6 + P) right singular vectors (rows) in scaled coordinates
    """
    _, J = residuals_and_jacobian(problem, R_cam_vehicle, t_cam_vehicle, p)
    J_data = J[: 2 * problem.parts.n_clicks]
    norms = np.linalg.norm(J_data, axis=0)
    norms[norms == 0.0] = 1.0
    _, s, Vt = np.linalg.svd(J_data / norms, full_matrices=True)
    s_full = np.zeros(J_data.shape[1])
    s_full[: len(s)] = s
    return s_full / s_full[0], Vt


def undetermined_directions(problem: Problem, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray,
                            p: np.ndarray, tolerance: float = 1e-7) -> int:
    """How many directions of the unknowns the clicks leave free (scale included, so at least 1).

    Parameters
    ----------
    tolerance : singular values below this fraction of the largest count as zero
    """
    s, _ = data_jacobian_spectrum(problem, R_cam_vehicle, t_cam_vehicle, p)
    return int(np.sum(s < tolerance))


def determines_8dof(problem: Problem, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray,
                    tolerance: float = 1e-7) -> bool:
    """True when the clicks fix everything but the scale."""
    return undetermined_directions(problem, R_cam_vehicle, t_cam_vehicle, p, tolerance) == 1
