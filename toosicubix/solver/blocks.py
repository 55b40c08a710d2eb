"""A symmetric matrix of a chain with a shared border: block tridiagonal over the chain's blocks, plus a few variables
every block sees (an arrowhead). The normal equations of a track (:mod:`.track`) have this shape: each frame's pose
and its own unknowns are a block, the motion terms tie neighbouring frames, and the vehicle's size ties them all.

``H = [[A, E], [E^T, C]]`` with ``A`` block tridiagonal (diagonal blocks ``D_k`` (n_k, n_k), upper blocks ``B_k``
(n_k, n_k+1)), the border ``E`` (rows ``E_k`` (n_k, s)) and the corner ``C`` (s, s).

Solving and the marginal covariances both run in time and memory linear in the number of blocks: the forward
Schur complements ``S_0 = D_0``, ``S_k = D_k - B_k-1^T S_k-1^-1 B_k-1`` (Cholesky factors), then

- a solve: ``A^-1`` on the right-hand side and on ``E`` by forward and back substitution, then the border's Schur
  complement ``P = C - E^T A^-1 E``;
- the diagonal blocks of ``H^-1``: those of ``A^-1`` by the backward recursion ``Sigma_K-1 = S_K-1^-1``,
  ``Sigma_k = S_k^-1 + S_k^-1 B_k Sigma_k+1 B_k^T S_k^-1`` (the Rauch-Tung-Striebel form), plus the border's share
  ``X_k P^-1 X_k^T`` with ``X = A^-1 E``; the border's own block is ``P^-1`` and its cross blocks ``-X_k P^-1``.
"""

from __future__ import annotations

import itertools

import numpy as np


class NotPositiveDefinite(np.linalg.LinAlgError):
    """The matrix (with its damping) is not positive definite: the step cannot be solved."""


class BlockArrow:
    """The matrix, filled by :meth:`add` (``J^T J`` of residual blocks), and the vector ``J^T r`` (:attr:`g`).

    Parameters
    ----------
    sizes : (K,) the chain's block sizes
    n_border : s, the border's size
    """

    def __init__(self, sizes: list[int], n_border: int):
        self.sizes = list(sizes)
        self.s = n_border
        self.D = [np.zeros((n, n)) for n in sizes]
        self.B = [np.zeros((a, b)) for a, b in itertools.pairwise(sizes)]
        self.E = [np.zeros((n, n_border)) for n in sizes]
        self.C = np.zeros((n_border, n_border))
        self.g = [np.zeros(n) for n in sizes]
        self.g_border = np.zeros(n_border)

    def add(self, r: np.ndarray, k: int, J_k: np.ndarray | None, J_next: np.ndarray | None,
            J_border: np.ndarray | None) -> None:
        """Add the residual block ``r`` (m,) whose Jacobian is ``J_k`` (m, n_k) on block ``k``, ``J_next``
        (m, n_k+1) on block ``k + 1`` and ``J_border`` (m, s) on the border (None: zero)."""
        if J_k is not None:
            self.D[k] += J_k.T @ J_k
            self.g[k] += J_k.T @ r
            if J_next is not None:
                self.B[k] += J_k.T @ J_next
            if J_border is not None:
                self.E[k] += J_k.T @ J_border
        if J_next is not None:
            self.D[k + 1] += J_next.T @ J_next
            self.g[k + 1] += J_next.T @ r
            if J_border is not None:
                self.E[k + 1] += J_next.T @ J_border
        if J_border is not None:
            self.C += J_border.T @ J_border
            self.g_border += J_border.T @ r

    def diagonal(self) -> tuple[list[np.ndarray], np.ndarray]:
        """The diagonal of ``H``, per block and for the border."""
        return [np.diag(D).copy() for D in self.D], np.diag(self.C).copy()

    def _factor(self, damping: float, floor: float) -> list:
        """Cholesky factors of the forward Schur complements of ``A + damping diag(A)``."""
        factors, previous = [], None
        for k, D in enumerate(self.D):
            S = D + np.diag(damping * np.maximum(np.diag(D), floor))
            if previous is not None:
                S = S - self.B[k - 1].T @ _cho_solve(previous, self.B[k - 1])
            try:
                previous = _cho_factor(S)
            except np.linalg.LinAlgError:
                raise NotPositiveDefinite(f"block {k} is not positive definite") from None
            factors.append(previous)
        return factors

    def _solve_chain(self, factors: list, rhs: list[np.ndarray]) -> list[np.ndarray]:
        """``A^-1`` on a right-hand side given per block (each (n_k,) or (n_k, c))."""
        w = [rhs[0]]
        for k in range(1, len(rhs)):
            w.append(rhs[k] - self.B[k - 1].T @ _cho_solve(factors[k - 1], w[k - 1]))
        x = [None] * len(rhs)
        x[-1] = _cho_solve(factors[-1], w[-1])
        for k in range(len(rhs) - 2, -1, -1):
            x[k] = _cho_solve(factors[k], w[k] - self.B[k] @ x[k + 1])
        return x  # type: ignore[return-value]

    def _border_schur(self, factors: list, damping: float, floor: float) -> tuple[list[np.ndarray], tuple]:
        """``X = A^-1 E`` and the Cholesky factor of ``P = C + damping diag(C) - E^T X``."""
        X = self._solve_chain(factors, self.E)
        P = self.C + np.diag(damping * np.maximum(np.diag(self.C), floor))
        for E_k, X_k in zip(self.E, X, strict=True):
            P = P - E_k.T @ X_k
        try:
            return X, _cho_factor(P)
        except np.linalg.LinAlgError:
            raise NotPositiveDefinite("the border's Schur complement is not positive definite") from None

    def solve(self, damping: float = 0.0, floor: float = 1e-12) -> tuple[list[np.ndarray], np.ndarray]:
        """The step ``x`` of ``(H + damping diag(H)) x = -g`` (the diagonal floored at ``floor``), per block and
        for the border.

        Raises
        ------
        NotPositiveDefinite
        """
        factors = self._factor(damping, floor)
        if self.s == 0:
            return [-x for x in self._solve_chain(factors, self.g)], np.zeros(0)
        X, P = self._border_schur(factors, damping, floor)
        y_chain = self._solve_chain(factors, self.g)
        rhs = self.g_border - sum((E_k.T @ y_k for E_k, y_k in zip(self.E, y_chain, strict=True)), np.zeros(self.s))
        border = _cho_solve(P, rhs)
        chain = [y_k - X_k @ border for y_k, X_k in zip(y_chain, X, strict=True)]
        return [-x for x in chain], -border

    def marginals(self, ridge: float = 1e-12) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
        """The diagonal blocks of ``H^-1``: per chain block (n_k, n_k), its cross block with the border
        (n_k, s), and the border's (s, s). ``ridge`` (a share of each diagonal entry, at least 1e-300) keeps
        directions the data leave free finite but huge.

        Raises
        ------
        NotPositiveDefinite
        """
        factors = self._factor(ridge, 1e-300)
        Sigma = [np.zeros(0)] * len(self.sizes)
        Sigma[-1] = _cho_solve(factors[-1], np.eye(self.sizes[-1]))
        for k in range(len(self.sizes) - 2, -1, -1):
            S_inv = _cho_solve(factors[k], np.eye(self.sizes[k]))
            G = S_inv @ self.B[k]
            Sigma[k] = S_inv + G @ Sigma[k + 1] @ G.T
        if self.s == 0:
            return Sigma, [np.zeros((n, 0)) for n in self.sizes], np.zeros((0, 0))
        X, P = self._border_schur(factors, ridge, 1e-300)
        P_inv = _cho_solve(P, np.eye(self.s))
        cross = [-(X_k @ P_inv) for X_k in X]
        chain = [S + X_k @ P_inv @ X_k.T for S, X_k in zip(Sigma, X, strict=True)]
        return chain, cross, P_inv


# scipy's Cholesky, imported on a track's first solve: a batch of single vehicles never loads scipy.
def _cho_factor(a: np.ndarray):
    from scipy.linalg import cho_factor

    return cho_factor(a)


def _cho_solve(factor, b: np.ndarray) -> np.ndarray:
    from scipy.linalg import cho_solve

    return cho_solve(factor, b)
