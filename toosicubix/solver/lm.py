"""One Levenberg-Marquardt for every least-squares fit of the solver, batched over starts.

The shape is PoseLib's: a *problem* knows its unknowns, a *loss* knows how residuals are weighed, and the
loop below knows neither. A problem (:class:`LeastSquaresProblem`) works on a *state*: a tuple of arrays whose
first axis runs over ``B`` starts refined in lockstep (``B = 1`` for a single fit). It gives

- ``residuals(state, with_jacobian)``: residuals ``r`` (B, M) and their Jacobian ``J`` (B, M, n) with respect
  to the step ``delta`` (B, n) of ``update``;
- ``update(state, delta)``: the retraction. Rotations move on SO(3), ``R <- R exp([delta_R]x)``
  (:func:`toosicubix.geometry.so3_exp`); every other unknown is additive, ``x <- x + delta_x``;
- ``feasible(state)``: (B,) bool, whether a trial state may be evaluated at all (points in front of the
  camera, positive dimensions, ...); an infeasible step is rejected like one that raises the cost;
- ``settle(state)``: moves a feasible trial state to an equivalent one before it is evaluated (the identity
  for most problems; the single-vehicle refinement moves it to the scale its cues prefer);
- ``step_is_small(delta, tolerance, starts)``: (k,) bool, whether each accepted step of the starts ``starts``
  (k,) is below ``tolerance`` (the problem knows which unknowns are angles and which are lengths).

``update`` and ``settle`` return new arrays or arrays of the state they are given, never arrays the problem
keeps: the loop writes into its state, and a trial all of whose starts are accepted becomes the state.

A loss (:class:`Loss`) maps each squared residual ``s = r^2`` to ``rho(s)`` and gives the weight
``rho'(s)``. The cost is ``sum rho(r_j^2)``; each iteration solves the reweighted normal equations
(iteratively reweighted least squares): with ``W = diag(rho'(r^2))``, ``g = J^T W r`` and ``H = J^T W J``,

    ``(H + mu D) delta = -g``,  ``D`` the diagonal of ``H`` (floored at 1e-12 of its largest entry).

For :class:`TrivialLoss` (``rho(s) = s``, weight 1) this is plain Gauss-Newton with damping and the weights
are never formed. Damping follows Nielsen's rule: the gain ratio ``rho_gain = (cost - new cost) / predicted``,
``predicted = delta . (mu D delta - g)``, accepts a step when positive and then multiplies ``mu`` by
``max(1/3, 1 - (2 rho_gain - 1)^3)`` (floored at 1e-15); a rejected step multiplies ``mu`` by ``nu``, which
doubles with each rejection in a row, and the start stops ('damping') once ``mu`` exceeds 1e16.

Stopping, per start: 'gradient' (the residual nearly orthogonal to every Jacobian column, MINPACK's gtol),
'step' (an accepted step the problem calls small), 'cost' (an accepted step lowered the cost by less than a
fraction of it), 'damping', 'max-iterations', or 'abandoned' (a start still far above the batch's best after
a few iterations, see :class:`LMOptions`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from toosicubix.solver import openblas

State = tuple[np.ndarray, ...]

_RUNNING, _GRADIENT, _STEP, _COST, _MAX_ITERATIONS, _DAMPING, _ABANDONED = range(7)
STATUS_NAMES = ("running", "gradient", "step", "cost", "max-iterations", "damping", "abandoned")


class Loss:
    """How squared residuals ``s`` (any shape) are weighed: ``loss(s)`` is ``rho(s)``, ``weight(s)`` is
    ``rho'(s)``. A robust loss subclasses this and defines both; ``trivial`` is True only for the plain sum of
    squares, which lets the loop skip the weights (and keep its arithmetic unchanged)."""

    trivial = False

    def loss(self, s: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def weight(self, s: np.ndarray) -> np.ndarray:
        raise NotImplementedError


class TrivialLoss(Loss):
    """Least squares: ``rho(s) = s``, weight 1."""

    trivial = True

    def loss(self, s: np.ndarray) -> np.ndarray:
        return np.asarray(s, dtype=float)

    def weight(self, s: np.ndarray) -> np.ndarray:
        return np.ones_like(s, dtype=float)


class LeastSquaresProblem(Protocol):
    """What :func:`levenberg_marquardt` asks of a problem; see the module docstring."""

    def residuals(self, state: State, with_jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]: ...

    def update(self, state: State, delta: np.ndarray) -> State: ...

    def feasible(self, state: State) -> np.ndarray: ...

    def settle(self, state: State) -> State: ...

    def step_is_small(self, delta: np.ndarray, tolerance: float, starts: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class LMOptions:
    """Options of :func:`levenberg_marquardt`.

    Attributes
    ----------
    max_iterations : iteration cap per start (accepted and rejected steps)
    gradient_tolerance : stop when the largest ``|J_j^T r| / (|J_j| |r|)`` is at most this (0: never, unless
        the gradient vanishes)
    step_tolerance : passed to the problem's ``step_is_small`` for every accepted step (0: only a zero step)
    cost_tolerance : stop when an accepted step lowers the cost by at most this fraction of the new cost
    initial_damping : ``mu`` at the start
    abandon_factor, abandon_after, abandon_above : a start is stopped ('abandoned') when after
        ``abandon_after`` iterations its cost is still above ``abandon_factor`` times the lowest cost in the
        batch (plus 1e-6), or above ``abandon_above``; None: never
    """

    max_iterations: int = 100
    gradient_tolerance: float = 1e-6
    step_tolerance: float = 1e-10
    cost_tolerance: float = 1e-8
    initial_damping: float = 1e-3
    abandon_factor: float | None = None
    abandon_after: int = 10
    abandon_above: float | None = None


@dataclass(frozen=True)
class LMResult:
    """Where each of the B starts ended.

    Attributes
    ----------
    state : the final states (same layout as the start)
    cost, initial_cost : (B,) the final and starting cost ``sum rho(r^2)``
    iterations : (B,) int, accepted and rejected steps
    stopped : the reason per start, one of :data:`STATUS_NAMES` but 'running'
    seconds : wall time of the whole batch
    """

    state: State
    cost: np.ndarray
    initial_cost: np.ndarray
    iterations: np.ndarray
    stopped: tuple[str, ...]
    seconds: float


def _weigh(loss: Loss, r: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cost (B,) and the residuals and Jacobian the normal equations use: ``sqrt(w) r`` and ``sqrt(w) J``."""
    if loss.trivial:
        return np.einsum("km,km->k", r, r), r, J
    s = r * r
    root_w = np.sqrt(loss.weight(s))
    return loss.loss(s).sum(axis=1), root_w * r, root_w[:, :, None] * J


def _cost(loss: Loss, r: np.ndarray) -> np.ndarray:
    if loss.trivial:
        return np.einsum("km,km->k", r, r)
    return loss.loss(r * r).sum(axis=1)


def levenberg_marquardt(problem: LeastSquaresProblem, state: State, options: LMOptions = LMOptions(),
                        loss: Loss | None = None) -> LMResult:
    """Levenberg-Marquardt from B feasible starts at once (see the module docstring for the update, damping
    and stopping rules).

    Residuals, Jacobians and the damped normal equations of all starts are computed in one pass of batched
    array operations, each start keeping its own damping, acceptance and stopping. Starts that stopped ride
    along in every array (a few more rows cost less than the gathers to leave them out) but never move.
    Every batched operation sees the same rows whichever shortcut the loop takes (a trial of every start is
    used as it is, not gathered; an iterate all of whose starts moved is replaced, not overwritten): some of
    them (matrix products) round differently for a different number of rows.

    Parameters
    ----------
    problem : see :class:`LeastSquaresProblem`
    state : tuple of arrays, first axis B (the starts)
    options : :class:`LMOptions`
    loss : :class:`TrivialLoss` when None

    Returns
    -------
    LMResult
    """
    started = time.perf_counter()
    loss = TrivialLoss() if loss is None else loss
    trivial = loss.trivial
    state = tuple(np.array(a) for a in state)
    r, J = problem.residuals(state, True)
    cost, rw, Jw = _weigh(loss, r, J)
    initial_cost = cost.copy()
    B, n = J.shape[0], J.shape[2]
    mu = np.full(B, float(options.initial_damping))
    nu = np.full(B, 2.0)
    iterations = np.zeros(B, dtype=int)
    status = np.full(B, _RUNNING)
    abandon = options.abandon_factor is not None or options.abandon_above is not None
    gradient_tolerance_sq = options.gradient_tolerance**2
    moved = True  # whether any start moved since g, J^T J and D were formed
    diagonal = np.arange(0, n * n, n + 1)  # H's diagonal in its rows of n * n

    for iteration in range(options.max_iterations):
        running = status == _RUNNING
        # No start has taken abandon_after steps before that many iterations.
        if abandon and iteration >= options.abandon_after:
            running &= ~_abandoned(options, cost, iterations, running, status)
        if not np.count_nonzero(running):  # (count_nonzero: a fraction of any()'s overhead on a few starts)
            break
        if moved:
            # After an iteration that moved no start, the same residuals give the same g, J^T J and D (and the
            # gradient test, which every running start failed on them): they are kept, not formed again.
            g = np.einsum("kmi,km->ki", Jw, rw)
            column_sq = np.einsum("kmi,kmi->ki", Jw, Jw)  # squared column norms: the diagonal of H
            rr = cost if trivial else np.einsum("km,km->k", rw, rw)
            # max_j |g_j| / |J_j| <= gtol |r|, squared
            cosines_sq = (g * g / np.maximum(column_sq, 1e-300)).max(axis=1)
            done = running & ((rr == 0.0) | (cosines_sq <= gradient_tolerance_sq * rr))
            if np.count_nonzero(done):
                status[done] = _GRADIENT
                running &= ~done
                if not np.count_nonzero(running):
                    break
            JtJ = (Jw.transpose(0, 2, 1) @ Jw).reshape(B, n * n)
            Dg = np.maximum(column_sq, 1e-12 * column_sq.max(axis=1, keepdims=True) + 1e-300)
            minus_g = -g
            moved = False
        iterations += running
        H = JtJ.copy()
        H[:, diagonal] += mu[:, None] * Dg
        step = _solve_batch(H.reshape(B, n, n), minus_g, running)
        solved = np.isfinite(step).all(axis=1)  # only running starts are solved
        step[~solved] = 0.0
        trial = problem.update(state, step)
        feasible = solved & problem.feasible(trial)
        n_feasible = np.count_nonzero(feasible)
        # Evaluated with its Jacobian: most steps are accepted, and then it is the next iterate's.
        if n_feasible == B:  # the trial as it is
            trial = problem.settle(trial)
            r_try, J_try = problem.residuals(trial, True)
            new_cost = _cost(loss, r_try)
            rho = gain_ratio(step, mu[:, None] * Dg * step - g, cost, new_cost)
        else:
            rho = np.full(B, -1.0)
            if n_feasible:
                trial = problem.settle(tuple(a[feasible] for a in trial))
                r_try, J_try = problem.residuals(trial, True)
                new_cost = _cost(loss, r_try)
                rho[feasible] = gain_ratio(step[feasible], (mu[:, None] * Dg * step - g)[feasible],
                                            cost[feasible], new_cost)
        accept = rho > 0  # implies feasible, hence running
        rejected = running & ~accept
        if np.count_nonzero(rejected):
            np.multiply(mu, nu, out=mu, where=rejected)
            np.multiply(nu, 2.0, out=nu, where=rejected)
            status[rejected & (mu > 1e16)] = _DAMPING
        ka = accept.nonzero()[0]
        if not len(ka):
            continue
        moved = True
        small = problem.step_is_small(step[ka], options.step_tolerance, ka)
        if len(ka) == B:  # every start moved (hence every trial was evaluated): the trial is the iterate
            state, r, J = trial, r_try, J_try
            drop, cost = cost - new_cost, new_cost
            mu = damping_after_success(mu, rho)
            nu = np.full(B, 2.0)
            status = _status_after_success(small, drop, new_cost, options.cost_tolerance)
        else:
            taken = accept[feasible]  # the accepted among the evaluated trials
            for a, b in zip(state, trial, strict=True):
                a[ka] = b[taken]
            r[ka], J[ka] = r_try[taken], J_try[taken]
            new_cost = new_cost[taken]
            drop = cost[ka] - new_cost
            cost[ka] = new_cost
            mu[ka] = damping_after_success(mu[ka], rho[ka])
            nu[ka] = 2.0
            status[ka] = _status_after_success(small, drop, new_cost, options.cost_tolerance)
        if trivial:
            rw, Jw = r, J
        else:
            _, rw, Jw = _weigh(loss, r, J)
    status[status == _RUNNING] = _MAX_ITERATIONS
    return LMResult(state, cost, initial_cost, iterations, tuple(STATUS_NAMES[s] for s in status),
                    time.perf_counter() - started)


def gain_ratio(step: np.ndarray, damped_step_minus_g: np.ndarray, cost: np.ndarray,
                new_cost: np.ndarray) -> np.ndarray:
    """Nielsen's gain ratio of k steps (k, n): the drop of the cost (k,) over the drop the damped model
    predicts, ``step . (mu D step - g)``, or -1 where that prediction is not positive: (k,)."""
    predicted = np.einsum("ki,ki->k", step, damped_step_minus_g)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(predicted > 0, (cost - new_cost) / predicted, -1.0)


def damping_after_success(mu: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Nielsen's damping (k,) after accepted steps of gain ratios ``rho`` (k,)."""
    return np.maximum(mu * np.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 1e-15)


def _status_after_success(small: np.ndarray, drop: np.ndarray, new_cost: np.ndarray,
                          cost_tolerance: float) -> np.ndarray:
    """The status (k,) of starts after accepted steps: 'step' where the step was small, else 'cost' where the
    cost dropped by at most ``cost_tolerance`` of the new cost, else still running."""
    return np.where(small, _STEP, np.where(drop <= cost_tolerance * new_cost, _COST, _RUNNING))


def _abandoned(options: LMOptions, cost: np.ndarray, iterations: np.ndarray, running: np.ndarray,
               status: np.ndarray) -> np.ndarray:
    """Marks the running starts that are still far above the batch's best after ``abandon_after`` iterations
    (see :class:`LMOptions`) as abandoned in ``status`` (B,) and returns them, (B,) bool."""
    bar = np.inf if options.abandon_above is None else options.abandon_above
    if options.abandon_factor is not None:
        bar = min(bar, options.abandon_factor * float(cost.min()) + 1e-6)
    gone = running & (iterations >= options.abandon_after) & (cost > bar)
    status[gone] = _ABANDONED
    return gone


def _solve_batch(H: np.ndarray, b: np.ndarray, which: np.ndarray) -> np.ndarray:
    """Solve ``H x = b`` for the rows ``which`` (B,) bool of a batch (B, n, n), (B, n) of symmetric positive
    definite systems (LAPACK dposv, one call each: cheaper than a batched solve for a few starts); rows not
    asked for or not positive definite come back NaN."""
    out = np.full(b.shape, np.nan)
    for k in which.nonzero()[0]:
        x, info = openblas.dposv(H[k], b[k])
        if info == 0:
            out[k] = x
    return out
