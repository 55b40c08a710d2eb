"""Evaluation plots with matplotlib (Agg canvas only: no display, no pyplot state) for ``eval --plots DIR``.

Three PNG files, each with titles, units and the number of vehicles:

- ``errors-by-depth.png``: E_R, E_t, IoU and sIoU against the ground truth's depth; every vehicle as a dot,
  the median per depth bin as a line and its 25-75 % spread as a band.
- ``distributions.png``: a histogram of each metric (E_R, E_t, E_d, IoU, sIoU, E_comb) with its median.
- ``calibration.png``: for yaw and depth, the share of vehicles whose error is within ``k`` predicted
  standard deviations (``sigma`` in results.json) against ``k``, beside a Gaussian's share ``erf(k / sqrt 2)``.

Files are written atomically, with a fixed size and dpi and no ``Software`` metadata, so the same
evaluation gives byte-identical files.
"""

from __future__ import annotations

import io
import itertools
import math
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from toosicubix.evaluation.records import EvaluationResult, MatchedObject
from toosicubix.formats.atomic import atomic_write_bytes

DPI = 100
#: Depth bins of ``errors-by-depth.png``, metres (the last is open).
DEPTH_EDGES = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, np.inf)
PLOT_FILES = ("errors-by-depth.png", "distributions.png", "calibration.png")
_METRICS = (  # attribute, axis label
    ("e_r_deg", "E_R (degrees)"), ("e_t", "E_t (relative)"), ("e_d", "E_d (relative)"),
    ("iou", "IoU (3D, full rotation)"), ("siou", "sIoU (scale-corrected IoU)"), ("e_comb", "E_comb"),
)


def _save(fig: Figure, path: Path) -> None:
    FigureCanvasAgg(fig)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI, metadata={"Software": None})
    atomic_write_bytes(path, buffer.getvalue())


def _values(matched: tuple[MatchedObject, ...], name: str) -> np.ndarray:
    return np.array([getattr(m.metrics, name) for m in matched], dtype=float)


def _source_note(result: EvaluationResult) -> str:
    s = result.settings
    return f"{s.get('predictions_source', '?')} vs {s.get('ground_truth', '?')} ground truth"


def plot_errors_by_depth(result: EvaluationResult, path: Path) -> None:
    """E_R, E_t, IoU, sIoU against depth: dots, the median per depth bin and its 25-75 % band."""
    matched = result.matched
    depth = np.array([m.depth for m in matched], dtype=float)
    fig = Figure(figsize=(10, 7))
    fig.suptitle(f"Errors against depth ({len(matched)} matched vehicles; {_source_note(result)})", fontsize=11)
    for k, (name, label) in enumerate((_METRICS[0], _METRICS[1], _METRICS[3], _METRICS[4])):
        ax = fig.add_subplot(2, 2, k + 1)
        values = _values(matched, name)
        ax.scatter(depth, values, s=6, alpha=0.35, color="tab:blue", label="vehicles")
        centres, med, lo, hi, counts = [], [], [], [], []
        for a, b in itertools.pairwise(DEPTH_EDGES):
            sel = (depth >= a) & (depth < b) & np.isfinite(values)
            if sel.any():
                q25, q50, q75 = np.percentile(values[sel], [25, 50, 75])
                centres.append(float(np.median(depth[sel])))
                med.append(q50)
                lo.append(q25)
                hi.append(q75)
                counts.append(int(sel.sum()))
        if centres:
            ax.fill_between(centres, lo, hi, color="tab:orange", alpha=0.25, label="25-75 % per bin")
            ax.plot(centres, med, "o-", color="tab:orange", label="median per 10 m bin")
            for x, y, n in zip(centres, med, counts, strict=True):
                ax.annotate(f"n={n}", (x, y), textcoords="offset points", xytext=(0, 6), fontsize=7, ha="center")
        ax.set_xlabel("depth of the ground truth (m)")
        ax.set_ylabel(label)
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
        if k == 0:
            ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    _save(fig, path)


def plot_distributions(result: EvaluationResult, path: Path) -> None:
    """A histogram per metric with its median."""
    matched = result.matched
    fig = Figure(figsize=(11, 6.5))
    fig.suptitle(f"Distribution of each metric ({len(matched)} matched vehicles; {_source_note(result)})",
                 fontsize=11)
    for k, (name, label) in enumerate(_METRICS):
        ax = fig.add_subplot(2, 3, k + 1)
        values = _values(matched, name)
        values = values[np.isfinite(values)]
        if len(values):
            ax.hist(values, bins=min(40, max(5, len(values) // 3)), color="tab:blue", alpha=0.8)
            median = float(np.median(values))
            ax.axvline(median, color="tab:orange", label=f"median {median:.3g}")
            ax.legend(fontsize=7)
        else:
            ax.text(0.5, 0.5, "no values", ha="center", va="center", transform=ax.transAxes)
        ax.set_xlabel(label)
        ax.set_ylabel("vehicles")
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    _save(fig, path)


def sigmas_from_results(results_json: Path | None) -> dict[tuple[str, str], dict[str, Any]]:
    """``(image id, vehicle id) -> sigma`` from a results.json; empty when there is none."""
    if results_json is None or not Path(results_json).is_file():
        return {}
    from toosicubix.formats.results import read_results

    return {(im.id, v.id): v.sigma.to_json() for im in read_results(results_json) for v in im.vehicles
            if v.ok and v.sigma is not None}


def normalized_errors(result: EvaluationResult, sigmas: dict[tuple[str, str], dict[str, Any]]
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Yaw and depth errors of the matched vehicles in units of their predicted standard deviations.

    Yaw: the KITTI yaw difference wrapped to [-180, 180) degrees over ``sigma.yaw_deg``; depth: the
    difference of the bottom centres' camera z over ``sigma.depth_m``. Vehicles without a finite positive
    sigma are left out.

    Returns
    -------
    (yaw (n,), depth (m,))
    """
    yaw, depth = [], []
    for m in result.matched:
        s = sigmas.get((m.image_id, m.pred_id))
        if not s:
            continue
        sy, sd = s.get("yaw_deg"), s.get("depth_m")
        if isinstance(sy, (int, float)) and math.isfinite(sy) and sy > 0:
            d_yaw = (math.degrees(m.pred.yaw - m.gt.yaw) + 180.0) % 360.0 - 180.0
            yaw.append(d_yaw / sy)
        if isinstance(sd, (int, float)) and math.isfinite(sd) and sd > 0:
            depth.append((m.pred.t_cam_vehicle[2] - m.gt.t_cam_vehicle[2]) / sd)
    return np.array(yaw), np.array(depth)


def plot_calibration(result: EvaluationResult, path: Path, sigmas: dict[tuple[str, str], dict[str, Any]]) -> None:
    """Share of errors within ``k`` predicted sigmas against ``k``, for yaw and depth, beside the Gaussian's."""
    yaw, depth = normalized_errors(result, sigmas)
    k = np.linspace(0.0, 3.0, 61)
    gauss = np.array([math.erf(v / math.sqrt(2.0)) for v in k])
    fig = Figure(figsize=(10, 4.5))
    fig.suptitle(f"Calibration of the predicted uncertainty ({len(result.matched)} matched vehicles; "
                 f"{_source_note(result)})", fontsize=11)
    for j, (values, name) in enumerate(((yaw, "yaw"), (depth, "depth"))):
        ax = fig.add_subplot(1, 2, j + 1)
        ax.plot(k, gauss, "--", color="gray", label="Gaussian: erf(k / sqrt 2)")
        if len(values):
            share = np.array([np.mean(np.abs(values) <= v) for v in k])
            ax.plot(k, share, color="tab:blue", label=f"measured ({len(values)} vehicles)")
            for kk in (1.0, 2.0):
                s = float(np.mean(np.abs(values) <= kk))
                ax.annotate(f"{100 * s:.0f} % within {kk:g} sigma", (kk, s), textcoords="offset points",
                            xytext=(4, -12), fontsize=8)
        else:
            ax.text(0.5, 0.5, "no predicted sigmas\n(results.json without sigma)", ha="center", va="center",
                    transform=ax.transAxes)
        ax.set_xlim(0.0, 3.0)
        ax.set_ylim(0.0, 1.02)
        ax.set_xlabel(f"k: |{name} error| / predicted {name} sigma")
        ax.set_ylabel("share of vehicles within k sigma")
        ax.set_title(f"{name} ({'degrees' if name == 'yaw' else 'metres'} over sigma)", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    _save(fig, path)


def write_evaluation_plots(result: EvaluationResult, plots_dir: str | Path,
                           results_json: str | Path | None = None) -> list[Path]:
    """Write the evaluation's plots (see the module's docstring) into ``plots_dir`` (created if needed).

    Parameters
    ----------
    result : from :func:`toosicubix.evaluation.evaluate_folder`
    plots_dir : folder to write into
    results_json : the fit's results.json, for the predicted sigmas of ``calibration.png`` (None: none)

    Returns
    -------
    the written files, in the order of :data:`PLOT_FILES`
    """
    plots_dir = Path(plots_dir)
    plots_dir.mkdir(parents=True, exist_ok=True)
    paths = [plots_dir / name for name in PLOT_FILES]
    plot_errors_by_depth(result, paths[0])
    plot_distributions(result, paths[1])
    plot_calibration(result, paths[2], sigmas_from_results(None if results_json is None else Path(results_json)))
    return paths
