"""Does a fit explain its clicks? The chi-square test of its pixel residuals.

With clicks off by independent Gaussian noise of the stated size, the weighted pixel residuals of a fit at its
optimum, each divided by its row's noise (:func:`toosicubix.solver.uncertainty.row_sigmas`), have a squared sum
distributed about as chi-square with the residuals' effective degrees of freedom
(:func:`toosicubix.solver.uncertainty.residual_dof`). A fit whose sum lies above the distribution's ``level``
quantile is a *misfit*: its clicks disagree with the cuboid more than the noise explains (a mislabelled click,
a part the model places badly, a vehicle unlike its prototype). Its covariance is then multiplied by
``chi2 / dof`` (the Birge ratio), so its sigmas and confidence widen to what its residuals show; a fit that
passes keeps the covariance of the stated noise. The test comes first so that a batch whose noise model holds
keeps its calibration: scaling every fit with a ratio above one would widen about half of them by chance.

Under a robust loss (:mod:`.robust`; by default for keypoint and plate clicks) the residuals are weighed as the
loss weighs them: a down-weighted click counts for little, and the sum runs below the distribution's (on twelve
simulated keypoints of known noise, 0.77 of its degrees of freedom on average). The test then flags what the loss
left: disagreement spread over many clicks, not one mislabelled click.

Real human clicks (ApolloCar3D) have heavier tails than one noise level per batch. The test is off unless asked
for (``SolverOptions.misfit_level``, ``--misfit-level``): the rules that decided it and what it did on real and
simulated clicks are in benchmarks/decisions.md (rules 8 and 9).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

#: How a misfit's warning starts (a joint refinement replaces its vehicles' own).
MISFIT_WARNING = "misfit:"
#: Fewer effective degrees of freedom than this: the clicks are not redundant enough to test.
MIN_DOF = 1.0


def chi2_quantile(level: float, dof: float) -> float:
    """The ``level`` quantile of a chi-square distribution with ``dof`` degrees of freedom (any real >= 1), by
    the Wilson-Hilferty cube-root approximation, with no scipy import in every fitting process. Against scipy's
    exact quantile (the tests compare them): within 0.8 % at the 0.99 level from 1 degree of freedom up; within
    3.1 % for levels 0.9 to 0.999, 1 % from 2 degrees of freedom at 0.9-0.99."""
    z = NormalDist().inv_cdf(level)
    a = 2.0 / (9.0 * dof)
    return dof * (1.0 - a + z * math.sqrt(a)) ** 3


@dataclass(frozen=True)
class ResidualTest:
    """A fit's chi-square test.

    Attributes
    ----------
    chi2 : the squared sum of its weighted pixel residuals, each over its row's noise
    dof : their effective degrees of freedom
    level : the test's level (0.99: one fit in a hundred fails it by chance)
    """

    chi2: float
    dof: float
    level: float

    @property
    def ratio(self) -> float:
        """``chi2 / dof``: about 1 when the stated noise explains the residuals (the Birge ratio)."""
        return self.chi2 / self.dof

    @property
    def misfit(self) -> bool:
        return self.chi2 > chi2_quantile(self.level, self.dof)

    def sentence(self) -> str:
        return (f"{MISFIT_WARNING} the clicks disagree with the cuboid more than the click noise explains (chi-square "
                f"{self.ratio:.1f} times its {self.dof:.1f} degrees of freedom, above its {self.level:.0%} quantile); "
                f"its sigmas are widened by {math.sqrt(self.ratio):.1f}x. Look for a mislabelled click among the "
                f"largest residuals")

    def to_json(self) -> dict[str, float | bool]:
        return {"chi2": self.chi2, "dof": self.dof, "chi2_per_dof": self.ratio, "level": self.level,
                "misfit": self.misfit}

    @classmethod
    def from_json(cls, d: dict) -> ResidualTest:
        """The inverse of :meth:`to_json` (results.json's ``residual_test``)."""
        return cls(chi2=float(d["chi2"]), dof=float(d["dof"]), level=float(d["level"]))


def residual_test(weighted_residuals: np.ndarray, row_sigmas: np.ndarray, dof: float | None,
                  level: float) -> ResidualTest | None:
    """The test of a fit's pixel residuals: ``weighted_residuals`` (2N,) as the pixel cost weighs them,
    ``row_sigmas`` (2N,) the rows' noise; None when ``dof`` is below :data:`MIN_DOF` or not finite (nothing to
    test)."""
    if dof is None or not math.isfinite(dof) or dof < MIN_DOF:
        return None
    chi2 = float(np.sum((np.asarray(weighted_residuals) / np.asarray(row_sigmas)) ** 2))
    if not math.isfinite(chi2):
        return None
    return ResidualTest(chi2, float(dof), level)
