"""numpy's own OpenBLAS called directly (:mod:`toosicubix.solver.openblas`): its ``dposv`` is the one scipy's
``lapack.dposv`` wraps to the last bit, and a fit of a small batch loads no scipy at all."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import REPO
from toosicubix.solver import openblas


def _systems(n_systems: int, seed: int = 0):
    """Symmetric positive definite systems like the refinement's damped normal equations: 3-15 unknowns whose
    columns differ in scale by up to e^12."""
    rng = np.random.default_rng(seed)
    for _ in range(n_systems):
        n = int(rng.integers(3, 16))
        J = rng.standard_normal((int(rng.integers(n, 4 * n)), n)) * np.exp(rng.uniform(-6.0, 6.0, n))
        yield J.T @ J + np.diag(rng.uniform(0.0, 1e-3, n)), rng.standard_normal(n)


@pytest.mark.skipif(openblas.library() is None, reason="numpy is not built on a bundled OpenBLAS here")
def test_dposv_is_scipys_to_the_last_bit():
    lapack = pytest.importorskip("scipy.linalg").lapack
    for H, b in _systems(2000):
        x, info = openblas.dposv(H, b)
        _, expected, expected_info = lapack.dposv(H, b)
        assert info == expected_info == 0
        assert x.tobytes() == np.ascontiguousarray(expected).tobytes()


def test_dposv_reports_a_matrix_that_is_not_positive_definite():
    H = np.diag([4.0, -1.0, 2.0])
    _, info = openblas.dposv(H, np.ones(3))
    assert info == 2  # the leading minor of order 2 is not positive definite (LAPACK's convention)


def test_dposv_leaves_its_arguments_alone():
    H, b = next(_systems(1, seed=3))
    H0, b0 = H.copy(), b.copy()
    x, info = openblas.dposv(H, b)
    assert info == 0 and np.array_equal(H, H0) and np.array_equal(b, b0)
    np.testing.assert_allclose(H @ x, b, rtol=0, atol=1e-9 * np.abs(H).max() * np.abs(x).max())


def test_dposv_takes_scipys_where_numpy_has_no_openblas(monkeypatch):
    pytest.importorskip("scipy.linalg")
    H, b = next(_systems(1, seed=5))
    expected = openblas.dposv(H, b)
    monkeypatch.setattr(openblas, "library", lambda: None)
    x, info = openblas.dposv(H, b)
    assert info == expected[1] == 0
    np.testing.assert_allclose(x, expected[0], rtol=1e-12, atol=0)


def test_a_small_batch_fits_without_importing_scipy(tmp_path):
    """`toosicubix fit` on a batch the numpy path fits (the bundled sample: fewer vehicles than the compiled path
    pays for) never imports scipy: its import costs some 0.17 s, more than such a batch's fits."""
    code = (
        "import sys\n"
        "from toosicubix.cli import main\n"
        "try:\n"
        f"    main(['fit', {str(REPO / 'samples' / 'annotations.json')!r}, '-o', {str(tmp_path / 'out')!r}, '-q'])\n"
        "except SystemExit as exc:\n"
        "    assert exc.code == 0, exc.code\n"
        "print(sorted(m for m in sys.modules if m == 'scipy' or m.startswith('scipy.')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout + out.stderr
    assert (tmp_path / "out" / "results.json").is_file()
