"""The refinement's Levenberg-Marquardt (:mod:`.lm` on :class:`.refine.RefineProblem`), the residuals and their
Jacobian wherever the solver evaluates them (:func:`.refine.residuals_batch`), and coordinate descent's shape step and
3D cost (:func:`.descent.solve_shapes`, :func:`.descent.costs_3d`), compiled with numba, every number computed as the
numpy path computes it.

The numpy path spends its time in Python around some hundred small array operations an iteration; the arithmetic is
microseconds. This module runs the same loop as compiled code and reproduces each operation's rounding, so that a
fit is the same to the last bit whichever path ran it (issue 37 asks for results unchanged):

- elementwise arithmetic in the same order (IEEE operations round the same everywhere; no fused multiply-adds, which
  numba emits only under ``fastmath``);
- every matrix product through the very BLAS call numpy makes for it (numpy's own OpenBLAS, with the same
  transposes, and the same special cases: numpy turns a product with one row into ``gemv`` or ``dot``, ``A^T A`` into
  ``syrk``, and a product it cannot hand to BLAS into a plain loop);
- every ``einsum`` as numpy's loops sum: a reduction over two contiguous operands with a scalar output in numpy's
  two-lane SIMD loop (blocks of eight, the block's vectors last to first, then pairs, then the lanes added), any other
  in order;
- the damped solve through the same LAPACK ``dposv`` of numpy's OpenBLAS that the numpy path calls
  (:mod:`.openblas`); the cube in Nielsen's damping through numpy's own ``power`` (its SIMD ``pow`` rounds unlike the
  C library's);
- the SO(3) exponential as ``cv2.Rodrigues`` computes it, operation for operation;
- sums as ``np.add.reduce`` sums (numpy's pairwise summation), the descent's solve through the ``dgesv`` numpy's
  ``linalg.solve`` calls.

Whether a machine's libraries round as this module assumes is checked, not assumed: the first refinement in a process
runs both paths and keeps the compiled one only when every number agrees (:func:`levenberg_marquardt`; the
first call of each other function, and of each variant of the residuals, likewise); otherwise, or without numba, or
with a numpy not built on OpenBLAS, the numpy path runs and the results are the same. A refinement of more than
:data:`MAX_STARTS` starts takes the numpy loop (with the compiled residuals).
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from toosicubix.solver import lm
from toosicubix.solver.problem import KERNEL_ARRAYS

log = logging.getLogger(__name__)

#: Batches up to this many starts (``cv2.Rodrigues`` per start in :func:`toosicubix.geometry.so3_exp`).
MAX_STARTS = 8
#: Set to "0" to run the numpy path only (the results are the same; a benchmark's comparison, or a machine whose
#: numba misbehaves).
ENVIRONMENT_SWITCH = "TOOSICUBIX_COMPILED"

_kernel = None  # the kernel module once loaded, False when it cannot be
_off = 0  # nesting depth of numpy_path_only()
#: Per compiled function ('refine', 'shapes', 'costs'): whether its first call in this process agreed with the numpy
#: path to the last bit (absent: not called yet). False turns it off for the process, as an error of it does.
_agrees: dict[str, bool] = {}


def available() -> bool:
    """Whether the compiled path can run here (not switched off; numba, numpy's OpenBLAS and scipy's LAPACK found)."""
    global _kernel
    if _kernel is None:
        _kernel = False
        if os.environ.get(ENVIRONMENT_SWITCH, "1") != "0":
            from toosicubix.solver import refine_kernel

            if refine_kernel.LOADED:
                _kernel = refine_kernel
    return _kernel is not False


#: What :func:`warm_up` says before it compiles (the code is cached afterwards, so once per installation and version).
COMPILING = ("compiling the solver's refinement for this machine (numba, once per installation: about 20 s; "
             "the results are the same as without it)")


def warm_up(say: Callable[[str], None] | None = None) -> bool:
    """Load the compiled refinement now, compiling it when no cached copy exists (``say`` is told :data:`COMPILING`
    first), so that no fit waits for it later: the commands call this before their first fit. Returns whether the
    compiled path is available. Inside :func:`numpy_path_only` it loads nothing (numba is not even imported)."""
    if _off or not available():
        return False
    global _kernel
    if say is not None and not all(_cached(f) for f in (_kernel.lm, _kernel.residuals, _kernel.solve_shapes,
                                                          _kernel.costs_3d)):
        say(COMPILING)
    try:
        _kernel.warm_up()
    except Exception as exc:  # numba cannot compile it here: the numpy path refines, with the same results
        log.warning("the compiled refinement could not be loaded (%s: %s); the numpy path runs instead (the same "
                    "results, only slower)", type(exc).__name__, exc)
        _kernel = False
        return False
    return True


def _cached(dispatcher) -> bool:
    """Whether numba has this function compiled on disk (its cache index; True when that cannot be told)."""
    try:
        return bool(dispatcher._cache._cache_file._load_index())
    except Exception:  # numba's cache internals moved: say nothing rather than something wrong
        return True


@contextmanager
def numpy_path_only() -> Iterator[None]:
    """Within this block every refinement takes the numpy path (tests and benchmarks compare the two with it)."""
    global _off
    _off += 1
    try:
        yield
    finally:
        _off -= 1


def levenberg_marquardt(refine, state: tuple[np.ndarray, ...], options):
    """:func:`.lm.levenberg_marquardt` of a :class:`.refine.RefineProblem` from ``state`` (after its ``start``),
    compiled; None when this refinement takes the numpy path (see the module docstring).

    The first refinement in a process runs both paths and compares every number of their results; the compiled path
    is kept only when they agree bit for bit, and that first comparison's result is the numpy path's either way. An
    error of the compiled code turns it off for the process, and the numpy path refines."""
    if len(state[0]) > MAX_STARTS or not _on("refine"):
        return None
    result = _guarded("refine", lambda: _run(refine, state, options))
    if result is None:
        return None
    return _first_checked("refine", result, lambda: lm.levenberg_marquardt(refine, state, options), _same)


def _problem_arrays(problem) -> tuple:
    """What the kernel takes of a :class:`.problem.Problem`, in its order (``A`` to ``high`` of its functions): all
    but the click weights made once per problem (:meth:`.problem.Problem.kept`) and handed on when only the weights
    change (:data:`.problem.UNWEIGHTED_KEPT`)."""
    head, tail = problem.kept(KERNEL_ARRAYS, _make_problem_arrays)
    weights = problem.pixel_row_weights
    return (*head, np.ones(1) if weights is None else _c(weights), weights is not None, *tail)


def _make_problem_arrays(problem) -> tuple[tuple, tuple]:
    """The kernel's arrays of a problem before and after its click weights (which they must not depend on)."""
    n_up = 0 if problem.upright_sigma is None else 3
    K = problem.K
    P = problem.parts.n_params
    return ((_c(problem.A), _c(problem.A_rows), _c(problem.uv),
             np.array([K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]], dtype=float), float(np.sqrt(problem.lambda_px)),
             _c(problem.G), _c(problem.b), _c(problem.scale_rows_jacobian), bool(problem.scale_rows_see_t),
             _c(problem.up), n_up, float(problem.upright_weight) if n_up else 0.0),
            (_c(problem.arrow_mid).reshape(-1, 3, P), _c(problem.arrow_low), _c(problem.arrow_high)))


def _run(refine, state, options):
    started = time.perf_counter()
    problem = refine.problem
    R, t, p, pivot = (np.array(a, dtype=float) for a in state)
    A, A_rows, *rest = _problem_arrays(problem)
    out = _kernel.lm(
        R, t, p, pivot, A, A_rows, _c(problem.A_mean), *rest,
        float(refine.min_up), np.ascontiguousarray(refine.may_tilt, dtype=np.bool_), _c(refine.size),
        int(options.max_iterations), float(options.gradient_tolerance**2), float(options.step_tolerance),
        float(options.cost_tolerance), float(options.initial_damping),
        math.nan if options.abandon_factor is None else float(options.abandon_factor), int(options.abandon_after),
        math.inf if options.abandon_above is None else float(options.abandon_above),
        options.abandon_factor is not None or options.abandon_above is not None)
    R, t, p, cost, initial_cost, iterations, status = out
    return lm.LMResult((R, t, p, pivot), cost, initial_cost, iterations, tuple(lm.STATUS_NAMES[s] for s in status),
                       time.perf_counter() - started)


def _c(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=float)


def _identical(x: np.ndarray, y: np.ndarray) -> bool:
    """Whether two arrays hold the same bits (NaNs where the other has NaNs, zeros of the same sign)."""
    x, y = np.ascontiguousarray(x), np.ascontiguousarray(y)
    return x.shape == y.shape and x.dtype == y.dtype and np.array_equal(x.view(np.uint8), y.view(np.uint8))


def _same(a, b) -> bool:
    """Whether two :class:`.lm.LMResult` agree to the last bit."""
    pairs = [*zip(a.state[:3], b.state[:3], strict=True), (a.cost, b.cost), (a.initial_cost, b.initial_cost),
             (a.iterations, b.iterations)]
    return a.stopped == b.stopped and all(_identical(x, y) for x, y in pairs)


# --- the residuals and their Jacobian ---------------------------------------------------------------------------------

def residuals(problem, R: np.ndarray, t: np.ndarray, p: np.ndarray, with_jacobian: bool, pivot: np.ndarray | None,
              profile_scale: bool, numpy_residuals: Callable[[], tuple[np.ndarray, np.ndarray | None]]
              ) -> tuple[np.ndarray, np.ndarray | None] | None:
    """:func:`.refine.residuals_batch` (its arguments), compiled; None when numpy computes it (compiled path off, no
    pose, or this variant's first call in the process disagreeing with ``numpy_residuals()``: each combination of
    ``with_jacobian``, ``pivot`` and ``profile_scale`` is checked on its own first call)."""
    name = f"residuals{'+J' if with_jacobian else ''}{'+pivot' if pivot is not None else ''}" \
           f"{'+profile' if profile_scale else ''}"
    if not len(R) or not _on(name):
        return None
    B = len(R)
    out = _guarded(name, lambda: _kernel.residuals(
        _c(R), _c(t), _c(p), np.zeros((B, 3)) if pivot is None else _c(pivot), *_problem_arrays(problem),
        bool(profile_scale), pivot is not None, bool(with_jacobian)))
    if out is None:
        return None
    result = (out[0], out[1] if with_jacobian else None)
    return _first_checked(name, result, numpy_residuals, _same_residuals)


def _same_residuals(a, b) -> bool:
    return _identical(a[0], b[0]) and (a[1] is None) == (b[1] is None) and (a[1] is None or _identical(a[1], b[1]))


# --- coordinate descent's shape step and 3D cost ----------------------------------------------------------------------

def solve_shapes(A: np.ndarray, M: np.ndarray, R_cam_vehicle: np.ndarray, prior_normal: np.ndarray, rhs: np.ndarray,
                 numpy_shapes: Callable[[], np.ndarray]) -> np.ndarray | None:
    """:func:`.descent.solve_shapes`' solution ``x`` (S, P + 3), compiled; None when numpy computes it (compiled path
    off, a singular system, or this function's first call in the process disagreeing with ``numpy_shapes()``)."""
    if not _on("shapes"):
        return None
    x = _guarded("shapes", lambda: _kernel.solve_shapes(_c(R_cam_vehicle), _c(A), _c(M), _c(prior_normal), _c(rhs)))
    if x is None or not len(x):
        return None
    return _first_checked("shapes", x, numpy_shapes, _identical)


def costs_3d(problem, R_cam_vehicle: np.ndarray, t_cam_vehicle: np.ndarray, p: np.ndarray,
             numpy_costs: Callable[[], np.ndarray]) -> np.ndarray | None:
    """:func:`.descent.costs_3d`, compiled; None when numpy computes it (as :func:`solve_shapes`)."""
    if not _on("costs"):
        return None
    out = _guarded("costs", lambda: _kernel.costs_3d(_c(R_cam_vehicle), _c(t_cam_vehicle), _c(p), _c(problem.A_rows),
                                            _c(problem.u), _c(problem.G), _c(problem.b), float(problem.lambda_3d)))
    return None if out is None else _first_checked("costs", out, numpy_costs, _identical)


def _on(name: str) -> bool:
    """Whether the compiled ``name`` may run: the path available, not inside :func:`numpy_path_only`, not turned off."""
    return not _off and _agrees.get(name) is not False and available()


def _guarded(name: str, compute: Callable[[], Any]) -> Any:
    """``compute()``, or None after an error of the compiled ``name``, which turns it off for the process (a fault of
    the compiled code must cost speed, never a fit)."""
    try:
        return compute()
    except Exception as exc:
        _agrees[name] = False
        log.warning("the compiled %s failed (%s: %s); the numpy path runs instead (the same results, only slower)",
                    _what(name), type(exc).__name__, exc)
        return None


def _first_checked(name: str, result: Any, reference: Callable[[], Any], same: Callable[[Any, Any], bool]) -> Any:
    """``result``, after the first call of the compiled ``name`` in the process compared it with ``reference()`` (the
    reference is returned then, and ``name`` is turned off for the process if ``same`` says they differ)."""
    if name in _agrees:
        return result
    with numpy_path_only():  # the reference is numpy's alone, whatever else is compiled
        expected = reference()
    _agrees[name] = same(result, expected)
    if not _agrees[name]:
        log.warning("the compiled %s does not reproduce the numpy path's numbers on this machine; the numpy path runs "
                    "instead (the results are the same, only slower)", _what(name))
    return expected


def _what(name: str) -> str:
    """The compiled function ``name`` in words (its variant after a '+', as :func:`residuals` names them)."""
    base, _, variant = name.partition("+")
    words = {"refine": "refinement", "shapes": "descent's shape step", "costs": "descent's 3D cost",
             "residuals": "residuals"}[base]
    return f"{words} ({variant.replace('+', ', ')})" if variant else words
