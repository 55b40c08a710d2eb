"""Choose the prior weights lambda and lambda_p by maximising mean sIoU on annotated vehicles with ground truth
(paper, "Priors and Hyperparameters").

The search is a grid in log space, refined once around the best point: every vehicle is fitted with every
pair of weights and scored by the evaluation (pairing by 2D box IoU, sIoU with full rotations). The mean
sIoU is the objective; mean IoU and median E_R are reported beside it. Ties (within 1e-4) go to the larger
lambda_p, the more regularised fit.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from toosicubix.evaluation import EvalOptions, evaluate, predictions_from_results, summarize
from toosicubix.formats.ground_truth import GroundTruthSource
from toosicubix.model import Image
from toosicubix.pipeline import workers
from toosicubix.pipeline.fitting import fit_images, shared_workers
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.size_priors import Priors
from toosicubix.solver.fit import SolverOptions

#: Default grids (the refinement then tries the half-decades around the best).
LAMBDAS = (0.01, 0.1, 1.0, 10.0)
LAMBDA_PS = (0.01, 0.1, 1.0, 10.0, 100.0)


@dataclass(frozen=True)
class GridPoint:
    """The scores of one pair of weights.

    Attributes
    ----------
    siou_mean : the objective; iou_mean, e_r_median_deg : reported beside it
    n_matched : vehicles fitted and paired with ground truth
    n_failed : vehicles that failed (too few or degenerate clicks)
    """

    lambda_3d: float
    lambda_px: float
    siou_mean: float
    iou_mean: float
    e_r_median_deg: float
    n_matched: int
    n_failed: int


@dataclass(frozen=True)
class TuneResult:
    """Every grid point tried, in order, and the best."""

    points: tuple[GridPoint, ...]
    best: GridPoint

    def landscape(self) -> str:
        """The mean sIoU over the grid as a text table: lambda in rows, lambda_p in columns (the best starred)."""
        lambdas = sorted({p.lambda_3d for p in self.points})
        lambda_ps = sorted({p.lambda_px for p in self.points})
        cell = {(p.lambda_3d, p.lambda_px): p for p in self.points}
        header = "lambda \\ lambda_p " + "".join(f"{lp:>9.3g}" for lp in lambda_ps)
        lines = ["mean sIoU (blank: not tried; * best)", header]
        for lam in lambdas:
            row = f"{lam:>18.3g} "
            for lp in lambda_ps:
                point = cell.get((lam, lp))
                if point is None:
                    row += " " * 9
                else:
                    mark = "*" if point is self.best else " "
                    row += f"{point.siou_mean:>8.4f}{mark}"
            lines.append(row)
        return "\n".join(lines)

    def to_json(self) -> dict[str, Any]:
        fields = ("lambda_3d", "lambda_px", "siou_mean", "iou_mean", "e_r_median_deg", "n_matched", "n_failed")
        return {"objective": "mean sIoU", "best": {f: getattr(self.best, f) for f in fields},
                "grid": [{f: getattr(p, f) for f in fields} for p in self.points]}


def score(images: list[Image], priors: Priors, ground_truth: GroundTruthSource, options: SolverOptions,
          eval_options: EvalOptions | None = None, jobs: int = 1) -> GridPoint:
    """Fit every vehicle with ``options`` and score the fits against the ground truth."""
    results = fit_images(images, BatchSettings(priors, options, jobs=jobs))
    evaluation = evaluate(predictions_from_results(results), ground_truth, eval_options)
    summary = summarize(evaluation)
    n_failed = sum(1 for im in results for v in im.vehicles if not v.ok)
    return GridPoint(
        lambda_3d=options.lambda_3d, lambda_px=options.lambda_px,
        siou_mean=float(summary["siou_mean"] or 0.0), iou_mean=float(summary["iou_mean"] or 0.0),
        e_r_median_deg=float(summary["e_r_median_deg"] if summary["e_r_median_deg"] is not None else math.nan),
        n_matched=int(summary["n_matched"]), n_failed=n_failed,
    )


def _better(a: GridPoint, b: GridPoint | None) -> bool:
    if b is None:
        return True
    if abs(a.siou_mean - b.siou_mean) > 1e-4:
        return a.siou_mean > b.siou_mean
    return (a.lambda_px, a.lambda_3d) > (b.lambda_px, b.lambda_3d)


def grid_search(evaluate_point: Callable[[float, float], GridPoint], lambdas: Sequence[float],
                lambda_ps: Sequence[float], refine: bool = True,
                progress: Callable[[GridPoint], None] | None = None) -> TuneResult:
    """Maximise the mean sIoU over a log grid, then (``refine``) over the half-steps around the best.

    Parameters
    ----------
    evaluate_point : scores one ``(lambda_3d, lambda_px)``
    lambdas, lambda_ps : the grid
    progress : called with each point once scored
    """
    done: dict[tuple[float, float], GridPoint] = {}

    def visit(lam: float, lp: float) -> None:
        key = (float(f"{lam:.6g}"), float(f"{lp:.6g}"))
        if key not in done:
            done[key] = evaluate_point(*key)
            if progress is not None:
                progress(done[key])

    for lam in lambdas:
        for lp in lambda_ps:
            visit(lam, lp)
    if refine:
        best = _best(done.values())
        step_l = _half_step(lambdas)
        step_p = _half_step(lambda_ps)
        for f_l in (1.0 / step_l, 1.0, step_l):
            for f_p in (1.0 / step_p, 1.0, step_p):
                visit(best.lambda_3d * f_l, best.lambda_px * f_p)
    points = tuple(done.values())
    return TuneResult(points=points, best=_best(points))


def _best(points: Sequence[GridPoint] | Any) -> GridPoint:
    best: GridPoint | None = None
    for p in points:
        if _better(p, best):
            best = p
    assert best is not None
    return best


def _half_step(values: Sequence[float]) -> float:
    """The square root of the grid's typical ratio (a half step in log space); 2 for one value."""
    values = sorted(values)
    if len(values) < 2:
        return 2.0
    ratios = np.array(values[1:]) / np.array(values[:-1])
    return float(np.sqrt(np.median(ratios)))


def tune(images: list[Image], priors: Priors, ground_truth: GroundTruthSource,
         lambdas: Sequence[float] = LAMBDAS, lambda_ps: Sequence[float] = LAMBDA_PS,
         base: SolverOptions | None = None, eval_options: EvalOptions | None = None, refine: bool = True,
         jobs: int = 1, progress: Callable[[GridPoint], None] | None = None) -> TuneResult:
    """Search lambda and lambda_p for the highest mean sIoU on these vehicles.

    Parameters
    ----------
    images : annotated images whose ids the ground truth knows
    base : the other solver settings (defaults when None)
    jobs : worker processes for each grid point's fits, one pool for them all; 0 (``--jobs auto``): as many as
        the vehicles repay (:func:`toosicubix.pipeline.workers.workers_for`)
    """
    base = base or SolverOptions()
    jobs = workers.resolved(jobs, sum(len(im.vehicles) for im in images))

    def evaluate_point(lam: float, lp: float) -> GridPoint:
        return score(images, priors, ground_truth, replace(base, lambda_3d=lam, lambda_px=lp), eval_options, jobs)

    with shared_workers():  # every grid point's fits on the same workers
        return grid_search(evaluate_point, lambdas, lambda_ps, refine, progress)
