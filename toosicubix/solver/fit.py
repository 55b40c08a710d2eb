"""Fit one vehicle's cuboid from its clicks: the paper's three stages.

(a) starting yaws from image lines (:mod:`.init`); (b) coordinate descent on the 3D cost from every
start (:mod:`.descent`); (c) Levenberg-Marquardt on the pixel cost (:mod:`.refine`).

Choosing among starts: the 3D cost of stage (b) falls when the vehicle shrinks toward the camera, so
starts are never compared by it. Each descent result is moved to the scale its size prior prefers
(the pixel data term does not change with scale; a negative scale turns a mirrored, behind-the-camera
answer around), must then have positive dimensions and every point in front of the camera, and is
ranked by the pixel cost. The best few with distinct rotations are refined (the next few too when the
first few found nothing plausible, or only a misfit), and the lowest final pixel cost wins among the
plausible answers (:mod:`.plausibility`: roughly upright, every clicked part on a face turned to the
camera); an implausible answer is returned only when no plausible one was found, with a warning.
Clicks that cannot give a cuboid, and answers no one can believe, fail with a reason (:mod:`.degenerate`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from toosicubix import vocabulary
from toosicubix.camera import Camera
from toosicubix.geometry import geodesic_angle, rotation_between, wrap_angle, ypr_from_R_cam_vehicle
from toosicubix.model import GroundPlane
from toosicubix.parts.linear import PartsModel
from toosicubix.size_priors import SizePrior, axle_prior
from toosicubix.solver.degenerate import (
    Refusal,
    absurd_depth,
    degeneracy,
    degenerate_spread,
    no_start,
    short_arrows,
    starts_collapsed,
    too_far,
    too_few,
)
from toosicubix.solver.descent import descend_all, solve_shapes
from toosicubix.solver.fallback import typical_starts
from toosicubix.solver.init import rotations_from_yaws, yaw_candidates
from toosicubix.solver.misfit import ResidualTest, residual_test
from toosicubix.solver.plausibility import implausibility
from toosicubix.solver.problem import Problem
from toosicubix.solver.refine import (
    MIN_DEPTH,
    RefineResult,
    levenberg_marquardt_batch,
    residuals_and_jacobian,
    residuals_batch,
)
from toosicubix.solver.robust import DOWNWEIGHTED_BELOW, CauchyLoss, robust_factors, soft_weights, with_weights
from toosicubix.solver.uncertainty import (
    Observability,
    Uncertainty,
    analyse,
    residual_dof,
    row_sigmas,
)


@dataclass(frozen=True)
class SolverOptions:
    """Settings of the solver.

    Attributes
    ----------
    lambda_3d : weight of the size prior in the 3D cost of the coordinate descent (``lambda``)
    lambda_px : weight of the size prior in the pixel cost (``lambda_p``), px^2 per unit of squared
        Mahalanobis distance: the click-noise variance at which a MAP estimate weighs clicks and prior.
        The defaults (0.1, 10) are ``toosicubix tune``'s choice on simulated clicks (1 px noise, realistic
        part placement) on the KITTI tracking tuning sequences 0000-0009; see docs/method.md.
    min_constraints : fewer constraints than this fail the vehicle (6: pose, with the prior's 3 for size)
    sweep_starts : yaws spread over the circle tried besides the line-based ones (0: the paper's starts only)
    descent_starts : how many starts, the best by pixel cost after the first shape step, continue the descent
        with SQPnP rounds (None: all)
    descent_iterations, descent_tolerance : stopping rules of stage (b); the descent only has to reach the
        refinement's basin, which Levenberg-Marquardt then finishes
    refine_starts : how many of the best, mutually distinct descent results stage (c) refines together
        (and how many more when none of them ends plausible)
    distinct_deg : descent results whose rotations differ by less than this count as one
    refine_iterations : iteration cap of stage (c)
    abandon_factor, abandon_after : a refinement is dropped when after ``abandon_after`` iterations its
        cost is still above ``abandon_factor`` times the lowest in its batch
    rank_tolerance : a vehicle fails as degenerate when the column-scaled Jacobian at the optimum has a
        singular value below this fraction of its largest
    max_tilt_deg : answers whose up axis leans more than this from the camera's up direction are
        implausible (a camera on a vehicle sees vehicles upright); None turns the check off
    click_sigma : the click noise (pixels per coordinate) the reported uncertainty is computed for
    part_sigma : how far, in metres, real parts sit from where the cuboid model puts them (tyres inside the
        body's width, lights behind its end faces, rounded corners), as a random offset per part; the
        reported uncertainty includes it. The default 0.09 m makes the yaw sigmas calibrated on simulated
        clicks with realistic part placement (KITTI tracking tuning sequences 0000-0009, 1 px noise);
        0 for parts that sit exactly on a box
    soft_noise : what the sigmas take keypoints' and plates' residuals to be, ``(sigma, scale)``: click noise
        ``sigma`` pixels on top of ``scale`` times each one's learned spread; None: ``click_sigma`` on top of the
        spreads as learned, as the fit weighs them. ``fit`` sets it from the batch's residuals (rules 34 and 35 of
        benchmarks/decisions.md); only the sigmas take it, not the fit, its weights or its chi-square test
    ambiguity_sigmas : another minimum whose cost is within this many ``click_sigma^2`` of the best one
        makes the fit ambiguous
    robust_loss : 'cauchy' (reweight clicks far off the fit, :mod:`.robust`), 'none', or 'auto': Cauchy for
        vehicles with keypoint or plate clicks (real clicks: mislabelled ones happen), none otherwise. Default
        'auto': on ApolloCar3D's comparison half it lowered the mean E_comb and E_R and took yaw within two sigmas
        from 87.2 to 89.8 % (rule 18 of benchmarks/decisions.md); vehicles of cuboid parts are fitted as without it
    robust_rounds : how many reweighting rounds the robust loss takes at most
    upright_weight : how the upright term (a ground's) of a vehicle with keypoint or plate clicks is weighed: 'lambda'
        (by ``lambda_px``, as every cue) or 'clicks' (against the click noise its soft-weighted pixel rows have: the
        prior of the sigma the ground states, :meth:`.problem.Problem.upright_against_clicks`; rule 23 of
        benchmarks/decisions.md); vehicles of cuboid parts are fitted as with 'lambda' either way
    misfit_level : the level of the chi-square test of a fit's residuals (:mod:`.misfit`), e.g. 0.99; a fit that
        fails it is warned about and its sigmas widen by the root of its chi-square per degree of freedom. Default
        None (no test): on the simulated KITTI test split it took the yaw share within one sigma with a ground
        block to 76.2 %, past the 60-76 % that rule 8 of benchmarks/decisions.md asked for
    """

    lambda_3d: float = 0.1
    lambda_px: float = 10.0
    min_constraints: int = 6
    sweep_starts: int = 12
    descent_starts: int | None = 10
    descent_iterations: int = 1
    descent_tolerance: float = 1e-8
    refine_starts: int = 4
    distinct_deg: float = 2.0
    refine_iterations: int = 200
    abandon_factor: float = 2.0
    abandon_after: int = 10
    rank_tolerance: float = 1e-8
    max_tilt_deg: float | None = 45.0
    click_sigma: float = 1.5
    part_sigma: float = 0.09
    soft_noise: tuple[float, float] | None = None
    ambiguity_sigmas: float = 4.0
    robust_loss: str = "auto"
    robust_rounds: int = 5
    upright_weight: str = "lambda"
    misfit_level: float | None = None

    @property
    def max_tilt(self) -> float | None:
        """:attr:`max_tilt_deg` in radians (None: the check is off)."""
        return None if self.max_tilt_deg is None else float(np.deg2rad(self.max_tilt_deg))


@dataclass(frozen=True)
class FitResult:
    """The fit of one vehicle; the pose fields are None when ``status == 'failed'``.

    Attributes
    ----------
    R_cam_vehicle : (3, 3); t_cam_vehicle : (3,) bottom-face centre; p : (P,) all unknowns
    dimensions : (3,) ``(dx, dy, dz)`` metres
    cost : pixel cost at the optimum (px^2 + lambda_px Mahalanobis^2)
    residuals_px : (N, 2) projected minus clicked, undistorted pixels
    constraints : 2 per click minus the auxiliary unknowns
    timings : seconds per stage
    scale_shares : the cues' shares of the information on the scale ('size prior', 'ground contact',
        'length plate-rear', 'known dx', ...), summing to 1
    click_weights : (N,) the weight of each click in the pixel cost (soft term times robust factor), or None
    downweighted : the labels of the clicks the robust loss down-weighted (factor below 0.5)
    residual_dof : the pixel residuals' effective degrees of freedom (:func:`.uncertainty.residual_dof`): what
        the batch's click-noise estimate pools
    residual_test : the chi-square test of the residuals (:mod:`.misfit`), or None when not made; a misfit's
        ``uncertainty`` is already widened
    implausible : why the answer is one no person could have clicked (:mod:`.plausibility`: tilted, or clicked
        parts on faces turned away), when no plausible answer was found; None for a plausible answer
    reason, detail : for a failed fit, why in plain words (what is missing and what would fix it) and the
        technical account (the unknowns involved, the numbers); None for a fit (:mod:`.degenerate`)
    """

    status: str
    reason: str | None
    constraints: int
    n_clicks: int
    n_aux: int
    R_cam_vehicle: np.ndarray | None = None
    t_cam_vehicle: np.ndarray | None = None
    p: np.ndarray | None = None
    cost: float | None = None
    cost_prior: float | None = None
    residuals_px: np.ndarray | None = None
    starts: int = 0
    starts_from_lines: bool = False
    descent_iterations: int = 0
    refine_iterations: int = 0
    initial_cost: float | None = None
    timings: dict[str, float] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    scale_shares: dict[str, float] = field(default_factory=dict)
    uncertainty: Uncertainty | None = None
    observability: Observability | None = None
    alternatives: tuple[Alternative, ...] = ()
    click_weights: np.ndarray | None = None
    downweighted: tuple[str, ...] = ()
    residual_dof: float | None = None
    residual_test: ResidualTest | None = None
    implausible: str | None = None
    detail: str | None = None

    @classmethod
    def refused(cls, refusal: Refusal, **fields: Any) -> FitResult:
        """A failed result: the refusal's plain ``reason`` and its technical ``detail``."""
        return cls("failed", refusal.reason, detail=refusal.detail, **fields)

    @property
    def ambiguous(self) -> bool:
        """Another plausible minimum fits the clicks about as well (implausible ones were rejected)."""
        return any(a.close and a.implausible is None for a in self.alternatives)

    @property
    def scale_from(self) -> str | None:
        """The cue that carries most of the information on the vehicle's scale."""
        return max(self.scale_shares, key=self.scale_shares.get) if self.scale_shares else None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def dimensions(self) -> np.ndarray | None:
        return None if self.p is None else self.p[:3]

    @property
    def rms_px(self) -> float | None:
        if self.residuals_px is None or len(self.residuals_px) == 0:
            return None
        return float(np.sqrt(np.mean(np.sum(self.residuals_px ** 2, axis=1))))


@dataclass(frozen=True)
class Alternative:
    """Another local minimum the refinement found, distinct from the answer.

    Attributes
    ----------
    cost : its cost (the answer's is ``FitResult.cost``)
    rotation_deg : how far its rotation is from the answer's
    turned_around : its yaw differs by more than 135 degrees (the vehicle facing the other way)
    implausible : why it is implausible, or None
    close : its cost is within ``ambiguity_sigmas * click_sigma^2`` of the answer's
    R_cam_vehicle, t_cam_vehicle, dimensions : the pose
    """

    cost: float
    rotation_deg: float
    turned_around: bool
    implausible: str | None
    close: bool
    R_cam_vehicle: np.ndarray
    t_cam_vehicle: np.ndarray
    dimensions: np.ndarray

    def to_json(self) -> dict:
        return {"cost": self.cost, "rotation_deg": self.rotation_deg, "turned_around": self.turned_around,
                "implausible": self.implausible, "close": self.close,
                "R_cam_vehicle": self.R_cam_vehicle.tolist(), "t_cam_vehicle": self.t_cam_vehicle.tolist(),
                "dimensions": self.dimensions.tolist()}

    @classmethod
    def from_json(cls, d: dict) -> Alternative:
        """The inverse of :meth:`to_json` (results.json's ``alternatives``)."""
        return cls(cost=d["cost"], rotation_deg=d["rotation_deg"], turned_around=d["turned_around"],
                   implausible=d["implausible"], close=d["close"],
                   R_cam_vehicle=np.array(d["R_cam_vehicle"], dtype=float),
                   t_cam_vehicle=np.array(d["t_cam_vehicle"], dtype=float),
                   dimensions=np.array(d["dimensions"], dtype=float))


@dataclass(frozen=True)
class _Candidate:
    R: np.ndarray
    t: np.ndarray
    p: np.ndarray
    cost_px: float
    implausible: str | None


def fit_vehicle(parts: PartsModel, camera: Camera, prior: SizePrior,
                options: SolverOptions | None = None, ground: GroundPlane | None = None) -> FitResult:
    """Fit a cuboid to one vehicle's clicks.

    Parameters
    ----------
    parts : the vehicle's linear parts model (with its known sizes)
    camera : intrinsics (and distortion) of its image
    prior : size prior of its prototype
    options : solver settings; defaults when None
    ground : the image's road plane: vehicles stand upright on it, and, with the camera height, on it

    Returns
    -------
    FitResult
        ``status='failed'`` with a reason when the clicks are too few or degenerate; never raises for
        bad geometry.
    """
    options = options or SolverOptions()
    t_start = time.perf_counter()
    counts = {"constraints": parts.constraints, "n_clicks": parts.n_clicks, "n_aux": parts.n_aux}
    # A car's axles the axle prior holds are not the clicks' to fix (rule 31), as the dimensions are not.
    axles = axle_prior(prior.prototype)
    held = 0 if axles is None else sum(name in parts.param_names for name in axles.at)
    if parts.n_clicks < 3 or parts.constraints + held < options.min_constraints:
        return FitResult.refused(too_few(parts, options.min_constraints, held), **counts)
    short = short_arrows(parts) or degenerate_spread(parts.uv)
    if short:
        return FitResult.refused(short, **counts)

    problem = Problem.build(parts, camera, prior, options.lambda_3d, options.lambda_px, ground)
    max_tilt = options.max_tilt
    # Starts stand upright on the road: rotate the rays so that the road normal is the camera's -y.
    R_align = rotation_between(np.array([0.0, -1.0, 0.0]), problem.up)
    yaws, from_lines = yaw_candidates(parts, problem.u @ R_align, options.sweep_starts)
    t_init = time.perf_counter()

    R_starts = R_align @ rotations_from_yaws(yaws)
    R_d, t_d, p_d, descent_iterations = _descend(problem, R_starts, options)
    t_d, p_d = _at_signed_prior_scale(problem, t_d, p_d)
    candidates = _feasible(problem, R_d, t_d, p_d)
    collapsed = not candidates
    if collapsed:  # every start collapsed onto the camera: start from typical part positions instead
        t_f, p_f = typical_starts(problem, R_starts)
        candidates = _feasible(problem, R_starts, *_at_signed_prior_scale(problem, t_f, p_f))
    t_descent = time.perf_counter()
    base = {"starts": len(yaws), "starts_from_lines": from_lines, "descent_iterations": descent_iterations}
    if not candidates:
        return FitResult.refused(no_start(parts), **counts, **base)

    # Refine the best distinct starts in lockstep, plausible ones first; a start still far above the
    # best after a few iterations is abandoned. A second batch runs when the first found nothing plausible,
    # or only an answer whose residuals fail the chi-square test (a misfit may be the wrong minimum).
    click_faces = parts.click_faces
    ordered = _plausible_first(candidates, parts.click_labels, max_tilt, np.deg2rad(options.distinct_deg),
                               options.refine_starts, problem.up, click_faces)
    # The ground contact's sigma grows with the distance (the normal's uncertainty): set it from the best start.
    problem = problem.with_contact_distance(float(np.linalg.norm(ordered[0].t)))
    # Keypoints' and plates' soft term: their spread as per-click weights, seen from the best start's distance.
    soft = soft_weights(problem, float(np.linalg.norm(ordered[0].t)), options.click_sigma)
    problem = with_weights(problem, soft)
    if soft is not None and options.upright_weight == "clicks":  # the upright term as the prior it states
        problem = problem.upright_against_clicks(options.click_sigma)
    k = options.refine_starts
    converged, refine_iterations = _refine_batch(problem, ordered[:k], options, max_tilt, parts.click_labels,
                                                 click_faces)
    best, best_any = _cheapest(converged)
    further, checked = None, None
    if best is None:
        further = ordered[k:2 * k]
    elif (checked := _checked(problem, best, options)).misfit:
        more = _plausible_first(candidates, parts.click_labels, max_tilt, np.deg2rad(options.distinct_deg),
                                2 * k, problem.up, click_faces)
        further = [c for c in more if c.implausible is None][k:]
    if further:
        extra_converged, extra_iterations = _refine_batch(problem, further, options, max_tilt, parts.click_labels,
                                                          click_faces)
        if checked is not None:  # searching past a misfit: an answer at an absurd depth is no better answer
            extra_converged = [(r, why or absurd_depth(camera, r.t_cam_vehicle, r.p[:3]))
                               for r, why in extra_converged]
        converged += extra_converged
        refine_iterations += extra_iterations
        best, best_any = _cheapest(converged)
    warnings: tuple[str, ...] = ()
    implausible = None
    if best is None:
        best, implausible = best_any
        warnings = (f"no plausible answer found; returning one that is {implausible}",)
    chosen = ordered
    robust = options.robust_loss == "cauchy" or (options.robust_loss == "auto" and any(
        vocabulary.soft(label) for label in parts.click_labels))
    factors = None
    if robust:
        problem, best, factors, extra = _reweighted(problem, best, soft, options, max_tilt)
        refine_iterations += extra
    t_refine = time.perf_counter()
    timings = {"init": t_init - t_start, "descent": t_descent - t_init, "refine": t_refine - t_descent}

    if checked is not None and checked.answer is best:  # the same answer of the same problem: its Jacobian
        J_best, dof = checked.J, checked.dof
    else:
        _, J_best = residuals_and_jacobian(problem, best.R_cam_vehicle, best.t_cam_vehicle, best.p)
        dof = residual_dof(J_best, 2 * parts.n_clicks)
    degenerate = degeneracy(problem, J_best, options.rank_tolerance)
    if degenerate is not None and not degenerate.cuboid:  # only parts' own places are loose: fit it (rule 30)
        warnings, degenerate = (*warnings, degenerate.reason), None
    residuals = problem.pixel_residuals(best.R_cam_vehicle, best.t_cam_vehicle, best.p)
    prior_r = problem.prior_residual(best.p)
    common = dict(**counts, **base, refine_iterations=refine_iterations, initial_cost=chosen[0].cost_px,
                  timings={**timings, "total": time.perf_counter() - t_start}, warnings=warnings,
                  implausible=implausible)
    far = absurd_depth(camera, best.t_cam_vehicle, best.p[:3])
    degenerate = degenerate or (too_far(far) if far else None)
    if degenerate:
        return FitResult.refused(degenerate, **common)
    shares = scale_shares(problem, best.R_cam_vehicle, best.t_cam_vehicle, best.p)
    scale_source = max(shares, key=shares.get) if shares else None
    u, obs = analyse(problem, best.R_cam_vehicle, best.t_cam_vehicle, best.p, options.click_sigma, scale_source,
                     options.part_sigma, J_best, options.soft_noise)
    u, test = tested(problem, best.R_cam_vehicle, best.t_cam_vehicle, best.p, u, options, dof)
    if test is not None and test.misfit:
        common["warnings"] = (*warnings, test.sentence())
    if collapsed and not (u is not None and np.isfinite(u.depth_rel) and u.depth_rel <= COLLAPSED_MAX_DEPTH_REL):
        depth = "not determined" if u is None or not np.isfinite(u.depth_rel) else f"uncertain by {u.depth_rel:.0%}"
        return FitResult.refused(starts_collapsed(depth), **common)
    downweighted = () if factors is None else tuple(
        parts.click_labels[i] for i in np.flatnonzero(factors < DOWNWEIGHTED_BELOW))
    return FitResult(
        "ok", None, R_cam_vehicle=best.R_cam_vehicle, t_cam_vehicle=best.t_cam_vehicle, p=best.p,
        cost=best.cost, cost_prior=float(prior_r @ prior_r), residuals_px=residuals, scale_shares=shares,
        uncertainty=u, observability=obs, alternatives=_alternatives(best, converged, options),
        click_weights=problem.click_weights, downweighted=downweighted, residual_dof=dof, residual_test=test,
        **common,
    )


def tested(problem: Problem, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray, u: Uncertainty,
           options: SolverOptions, dof: float | None = None) -> tuple[Uncertainty, ResidualTest | None]:
    """A fit's uncertainty ``u`` after the chi-square test of its residuals (:mod:`.misfit`; ``dof`` their
    effective degrees of freedom, computed when None), widened when it fails, and the test (None when
    ``options.misfit_level`` is None or the clicks are not redundant enough)."""
    if options.misfit_level is None:
        return u, None
    if dof is None:
        _, J = residuals_and_jacobian(problem, R_cam_vehicle, t_cam_vehicle, p)
        dof = residual_dof(J, 2 * problem.parts.n_clicks)
    test = _residual_test(problem, R_cam_vehicle, t_cam_vehicle, p, options, dof, options.misfit_level)
    if test is not None and test.misfit:
        u = u.widened(test.ratio)
    return u, test


def _refine_batch(problem: Problem, batch: list[_Candidate], options: SolverOptions, max_tilt: float | None,
                  click_labels: tuple[str, ...], click_faces: tuple[tuple[str, ...] | None, ...] | None
                  ) -> tuple[list[tuple[RefineResult, str | None]], int]:
    """Stage (c) on ``batch`` in lockstep: the answers not abandoned, each with why it is implausible (None when
    plausible), and the iterations taken."""
    if not batch:
        return [], 0
    results = levenberg_marquardt_batch(
        problem, np.array([c.R for c in batch]), np.array([c.t for c in batch]), np.array([c.p for c in batch]),
        max_iterations=options.refine_iterations, abandon_factor=options.abandon_factor,
        abandon_after=options.abandon_after, max_tilt=max_tilt)
    converged = [(r, implausibility(click_labels, r.R_cam_vehicle, r.t_cam_vehicle, r.p[:3], max_tilt, problem.up,
                                    click_faces))
                 for r in results if r.stopped != "abandoned"]
    return converged, sum(r.iterations for r in results)


def _cheapest(converged: list[tuple[RefineResult, str | None]]
              ) -> tuple[RefineResult | None, tuple[RefineResult, str | None] | None]:
    """The cheapest plausible answer (None if none is) and the cheapest answer with its implausibility."""
    plausible = [r for r, why in converged if why is None]
    best = min(plausible, key=lambda r: r.cost) if plausible else None
    best_any = min(converged, key=lambda rw: rw[0].cost) if converged else None
    return best, best_any


@dataclass(frozen=True)
class _Checked:
    """A first batch's answer after the chi-square test of its residuals at :data:`SEARCH_LEVEL` (whatever
    ``options.misfit_level`` says), with the Jacobian (M, 6 + P) and residual degrees of freedom it took, which
    the analysis reuses when the answer stays."""

    answer: RefineResult
    misfit: bool
    J: np.ndarray
    dof: float


def _checked(problem: Problem, r: RefineResult, options: SolverOptions) -> _Checked:
    """Test answer ``r``: a misfit's clicks are worse explained than their noise allows, and the search goes on."""
    _, J = residuals_and_jacobian(problem, r.R_cam_vehicle, r.t_cam_vehicle, r.p)
    dof = residual_dof(J, 2 * problem.parts.n_clicks)
    test = _residual_test(problem, r.R_cam_vehicle, r.t_cam_vehicle, r.p, options, dof, SEARCH_LEVEL)
    return _Checked(r, test is not None and test.misfit, J, dof)


def _residual_test(problem: Problem, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray,
                   options: SolverOptions, dof: float, level: float) -> ResidualTest | None:
    """The chi-square test (:mod:`.misfit`) at ``level`` of the pixel residuals of the answer (R, t, p), weighed
    as the pixel cost weighs them, each over its row's noise."""
    r = problem.pixel_residuals(R_cam_vehicle, t_cam_vehicle, p)  # (N, 2)
    if problem.click_weights is not None:
        r = r * problem.click_weights[:, None]
    sigmas = row_sigmas(problem, R_cam_vehicle, t_cam_vehicle, p, options.click_sigma, options.part_sigma)
    return residual_test(r.reshape(-1), sigmas, dof, level)


def _reweighted(problem: Problem, best: RefineResult, soft: np.ndarray | None, options: SolverOptions,
                max_tilt: float | None) -> tuple[Problem, RefineResult, np.ndarray, int]:
    """Iteratively reweighted refinement under the Cauchy loss (:mod:`.robust`), from ``best``: returns the
    reweighted problem, its answer, the robust factors (N,) and the iterations taken."""
    loss = CauchyLoss()
    factors = np.ones(problem.parts.n_clicks)
    iterations = 0
    for _ in range(options.robust_rounds):
        residuals = problem.pixel_residuals(best.R_cam_vehicle, best.t_cam_vehicle, best.p)
        new = robust_factors(residuals, soft, options.click_sigma, loss)
        if np.max(np.abs(new - factors)) < 1e-3:
            break
        factors = new
        problem = with_weights(problem, factors if soft is None else soft * factors)
        best = levenberg_marquardt_batch(problem, best.R_cam_vehicle[None], best.t_cam_vehicle[None], best.p[None],
                                         max_iterations=options.refine_iterations, max_tilt=max_tilt)[0]
        iterations += best.iterations
    return problem, best, factors, iterations


def _feasible(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray) -> list[_Candidate]:
    """The starts (B, 3, 3), (B, 3), (B, P) with positive dimensions and every point in front of the camera,
    with their pixel cost."""
    depths = problem.points_vehicle_batch(p) @ R[:, 2, :, None]
    valid = (np.all(np.isfinite(p), axis=1) & np.all(p[:, :3] > 0, axis=1) & (t[:, 2] > MIN_DEPTH)
             & (depths[..., 0].min(axis=1) + t[:, 2] > MIN_DEPTH))
    if not valid.any():
        return []
    r, _ = residuals_batch(problem, R[valid], t[valid], p[valid], False, None, False)
    costs = np.einsum("km,km->k", r, r)
    return [_Candidate(R[i], t[i], p[i], float(c), None) for i, c in zip(np.flatnonzero(valid), costs, strict=True)]


def _alternatives(best: RefineResult, converged: list[tuple[RefineResult, str | None]],
                  options: SolverOptions, min_angle_deg: float = 15.0) -> tuple[Alternative, ...]:
    """The other minima the refinement reached, cheapest first, each at least ``min_angle_deg`` from the
    answer and from one another."""
    margin = options.ambiguity_sigmas * options.click_sigma**2
    kept: list[Alternative] = []
    for r, why in sorted(converged, key=lambda rw: rw[0].cost):
        angle = np.rad2deg(geodesic_angle(r.R_cam_vehicle, best.R_cam_vehicle))
        if angle < min_angle_deg or any(np.rad2deg(geodesic_angle(r.R_cam_vehicle, a.R_cam_vehicle)) < min_angle_deg
                                        for a in kept):
            continue
        yaw_diff = abs(np.rad2deg(wrap_angle(ypr_from_R_cam_vehicle(r.R_cam_vehicle)[0]
                                             - ypr_from_R_cam_vehicle(best.R_cam_vehicle)[0])))
        kept.append(Alternative(cost=r.cost, rotation_deg=float(angle), turned_around=bool(yaw_diff > 135.0),
                                implausible=why, close=bool(r.cost - best.cost <= margin),
                                R_cam_vehicle=r.R_cam_vehicle, t_cam_vehicle=r.t_cam_vehicle,
                                dimensions=r.p[:3].copy()))
    return tuple(kept)


def _descend(problem: Problem, R_starts: np.ndarray, options: SolverOptions
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Stage (b) from every start (S, 3, 3): where each ended, ``R`` (S, 3, 3), ``t`` (S, 3), ``p`` (S, P), and the
    rounds the descents took. Every start takes the first step (shape and translation for its rotation); the
    ``descent_starts`` best of them by the pixel cost at their prior scale go on with SQPnP rounds, the others stop
    there (a stopping rule: a start that fits the clicks far worse than others rarely wins, and each SQPnP call costs
    as much as the rest of a round)."""
    p0, t0 = solve_shapes(problem, R_starts)
    keep = np.arange(len(R_starts))
    if options.descent_starts is not None and len(R_starts) > options.descent_starts:
        t_s, p_s = _at_signed_prior_scale(problem, t0, p0)
        r, _ = residuals_batch(problem, R_starts, t_s, p_s, False, None, False)
        score = np.where(np.all(np.isfinite(r), axis=1), np.einsum("km,km->k", r, r), np.inf)
        keep = np.sort(np.argsort(score)[: options.descent_starts])
    R, t, p = np.array(R_starts, dtype=float), t0.copy(), p0.copy()
    iterations = 0
    for k, d in zip(keep, descend_all(problem, R_starts[keep], options.descent_iterations,
                                      options.descent_tolerance, (p0[keep], t0[keep])), strict=True):
        R[k], t[k], p[k] = d.R_cam_vehicle, d.t_cam_vehicle, d.p
        iterations += d.iterations
    return R, t, p, iterations


def _at_signed_prior_scale(problem: Problem, t: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Move each descent result (B, 3), (B, P) to the scale the cues prefer, which may be negative: that
    turns a mirrored, behind-the-camera answer around (the pixel data term is the same for both)."""
    a, b = problem.scale_terms(t, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (a @ b) / np.einsum("ki,ki->k", a, a)
    return s[:, None] * t, s[:, None] * p


def scale_shares(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray) -> dict[str, float]:
    """How the information on the vehicle's scale splits among the cues: for each cue, the squared change of
    its rows under a change of scale (the direction ``(0, t, p)``), as a share of all of them. The pixel rows
    do not change with scale, so they take no share."""
    a, _ = problem.scale_terms(t, p)
    sensitivity = a**2  # d/ds of the row s a - b is a
    shares: dict[str, float] = {}
    for cue, value in zip(problem.row_cues, sensitivity, strict=True):
        if cue != "axle prior":  # where the axles sit on the length states the shape, not the size
            shares[cue] = shares.get(cue, 0.0) + float(value)
    total = sum(shares.values())
    return {k: v / total for k, v in shares.items()} if total > 0 else {}


def _plausible_first(candidates: list[_Candidate], click_labels: tuple[str, ...], max_tilt: float | None,
                     min_angle: float, wanted: int, up: np.ndarray,
                     click_faces: tuple[tuple[str, ...] | None, ...] | None = None) -> list[_Candidate]:
    """Candidates by cost, leaving out any within ``min_angle`` of a cheaper one, the plausible ones first;
    stops looking once ``wanted`` plausible ones are found."""
    plausible: list[_Candidate] = []
    implausible: list[_Candidate] = []
    if not candidates:
        return []
    by_cost = sorted(candidates, key=lambda c: c.cost_px)
    min_trace = 1.0 + 2.0 * np.cos(min_angle)  # trace(R_a R_b^T) above this: closer than min_angle
    R = np.array([c.R for c in by_cost])  # (n, 3, 3)
    # close[l][k]: candidate l within min_angle of candidate k. One einsum for every pair; each trace is summed as
    # einsum("kij,ij->k") sums it against one rotation (the same nine-term loop), so the same pairs are close.
    close = (np.einsum("kij,lij->lk", R, R) > min_trace).tolist()
    kept: list[int] = []
    for l, c in enumerate(by_cost):
        row = close[l]
        if any(row[k] for k in kept):
            continue
        kept.append(l)
        why = implausibility(click_labels, c.R, c.t, c.p[:3], max_tilt, up, click_faces)
        if why is None:
            plausible.append(c)
            if len(plausible) == wanted:
                break
        else:
            implausible.append(replace(c, implausible=why))
    return plausible + implausible


#: A first batch's answer that fails the chi-square test of its residuals at this level (:mod:`.misfit`, the level
#: ``--misfit-level`` suggests) sends the next batch of starts to refinement too: car 907 of ApolloCar3D's
#: comparison half fitted 105 degrees off at 29 px RMS while its fifth start led to a lower cost.
SEARCH_LEVEL = 0.99
#: A fit reached only from typical part positions (every descent start collapsed onto the camera) is kept only
#: when its relative depth sigma is at most this: twice the spread the size prior alone gives the scale.
COLLAPSED_MAX_DEPTH_REL = 0.2
