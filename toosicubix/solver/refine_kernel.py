"""The compiled kernels of :mod:`.compiled`: the refinement's Levenberg-Marquardt in numba, each operation as numpy
computes it (that module's docstring says how). Imported on the first refinement only, so that numba's import and the
compiled code's loading cost nothing to commands that fit no vehicle.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from toosicubix.solver import openblas

log = logging.getLogger(__name__)

#: Points closer than this (metres) to the camera plane count as behind it (:data:`.refine.MIN_DEPTH`).
MIN_DEPTH = 1e-3

_RUNNING, _GRADIENT, _STEP, _COST, _MAX_ITERATIONS, _DAMPING, _ABANDONED = range(7)
_ROW_MAJOR, _COL_MAJOR, _NO_TRANS, _TRANS, _UPPER = 101, 102, 111, 112, 121


def _load():
    """numba, with the BLAS and LAPACK functions of numpy's OpenBLAS (:mod:`.openblas`) registered under this
    module's symbol names (so that the compiled code refers to them by name and can be cached), or None (the reason
    logged)."""
    try:
        import llvmlite.binding as llvm
        import numba
    except ImportError:
        return None
    if openblas.library() is None:
        log.debug("compiled refinement off: numpy's OpenBLAS not found")
        return None
    try:
        for ours, theirs in _BLAS.items():
            llvm.add_symbol(ours, openblas.address(theirs))
    except (OSError, AttributeError, ValueError) as exc:
        log.debug("compiled refinement off: %s", exc)
        return None
    return numba


#: Our symbol names for the functions of numpy's OpenBLAS (ILP64: 64-bit integers, numpy's own symbol names).
_BLAS = {"toosicubix_dgemm": "scipy_cblas_dgemm64_", "toosicubix_dgemv": "scipy_cblas_dgemv64_",
         "toosicubix_dsyrk": "scipy_cblas_dsyrk64_", "toosicubix_ddot": "scipy_cblas_ddot64_",
         "toosicubix_dposv": "scipy_dposv_64_", "toosicubix_dgesv": "scipy_dgesv_64_"}


LOADED = _load() is not None


def _pow3(x: np.ndarray) -> np.ndarray:
    """``x ** 3`` as numpy computes it (the expression of :func:`.lm.damping_after_success`)."""
    return x ** 3


if LOADED:
    import numba
    from numba import types

    _i32, _i64, _f64, _ptr = types.int32, types.int64, types.float64, types.uintp  # pointers as integers
    _gemm = types.ExternalFunction("toosicubix_dgemm", types.void(_i32, _i32, _i32, _i64, _i64, _i64, _f64, _ptr,
                                                                   _i64, _ptr, _i64, _f64, _ptr, _i64))
    _gemv = types.ExternalFunction("toosicubix_dgemv", types.void(_i32, _i32, _i64, _i64, _f64, _ptr, _i64, _ptr,
                                                                   _i64, _f64, _ptr, _i64))
    _syrk = types.ExternalFunction("toosicubix_dsyrk", types.void(_i32, _i32, _i32, _i64, _i64, _f64, _ptr, _i64,
                                                                   _f64, _ptr, _i64))
    _dot = types.ExternalFunction("toosicubix_ddot", _f64(_i64, _ptr, _i64, _ptr, _i64))
    # Fortran's LAPACK: every argument by reference, and the character argument's length last (gfortran's hidden one).
    _posv = types.ExternalFunction("toosicubix_dposv", types.void(_ptr, _ptr, _ptr, _ptr, _ptr, _ptr, _ptr, _ptr,
                                                                   _i64))
    _gesv = types.ExternalFunction("toosicubix_dgesv", types.void(_ptr, _ptr, _ptr, _ptr, _ptr, _ptr, _ptr, _ptr))
    njit = numba.njit(cache=True)

    # --- numpy's reductions --------------------------------------------------------------------------------------

    @njit
    def _maximum(a, b):
        """``np.maximum`` of two numbers: NaN when either is."""
        if math.isnan(a) or math.isnan(b):
            return math.nan
        return a if a >= b else b

    @njit
    def _extreme(x, largest):
        """``x.max()`` (``largest``) or ``x.min()`` of a 1-d array: NaN when any is."""
        out = x[0]
        for i in range(1, len(x)):
            if math.isnan(out):
                return out
            if math.isnan(x[i]) or (x[i] > out if largest else x[i] < out):
                out = x[i]
        return out

    @njit
    def _einsum_pair(a, b, n):
        """``einsum('i,i->', a, b)`` over ``n`` contiguous numbers: numpy's two-lane loop (blocks of eight summed
        from their last pair to their first, then the pairs left, a zero pad last; the lanes added)."""
        acc0 = 0.0
        acc1 = 0.0
        m = 0
        while n - m >= 8:
            for u in range(3, -1, -1):
                acc0 = acc0 + a[m + 2 * u] * b[m + 2 * u]
                acc1 = acc1 + a[m + 2 * u + 1] * b[m + 2 * u + 1]
            m += 8
        while m < n:
            acc0 = acc0 + a[m] * b[m]
            if m + 1 < n:
                acc1 = acc1 + a[m + 1] * b[m + 1]
            else:
                acc1 = acc1 + 0.0 * 0.0
            m += 2
        return 0.0 + (acc0 + acc1)

    @njit
    def _pairwise(a, n):
        """``np.add.reduce`` of ``a[:n]`` (contiguous): numpy's pairwise sum (eight partial sums per block of 128,
        halves above that)."""
        if n < 8:
            res = 0.0
            for i in range(n):
                res += a[i]
            return res
        if n <= 128:
            r = a[:8].copy()
            i = 8
            while i < n - (n % 8):
                for j in range(8):
                    r[j] += a[i + j]
                i += 8
            res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
            while i < n:
                res += a[i]
                i += 1
            return res
        half = n // 2
        half -= half % 8
        return _pairwise(a, half) + _pairwise(a[half:], n - half)

    # --- numpy's matrix products ---------------------------------------------------------------------------------

    @njit
    def _rows_times_t(x, B, K, m_ptr, ldm, ncols, out):
        """``x @ M.T`` for ``x`` (B, K) C-contiguous and ``M`` (ncols, K) rows ``ldm`` apart at ``m_ptr``: numpy's
        ``gemv`` for one row, else ``gemm``. ``out`` (B, ncols) C-contiguous."""
        if B == 1:
            _gemv(_COL_MAJOR, _TRANS, K, ncols, 1.0, m_ptr, ldm, x.ctypes.data, 1, 0.0, out.ctypes.data, 1)
        else:
            _gemm(_ROW_MAJOR, _NO_TRANS, _TRANS, B, ncols, K, 1.0, x.ctypes.data, K, m_ptr, ldm, 0.0,
                  out.ctypes.data, ncols)

    @njit
    def _rows_dot(a, vec, out):
        """``a @ vec`` for ``a`` (B, m) C-contiguous and ``vec`` (m,): numpy's ``dot`` for one row, else ``gemv``."""
        B, m = a.shape
        if B == 1:
            out[0] = 0.0 + _dot(m, a.ctypes.data, 1, vec.ctypes.data, 1)
        else:
            _gemv(_COL_MAJOR, _TRANS, m, B, 1.0, a.ctypes.data, m, vec.ctypes.data, 1, 0.0, out.ctypes.data, 1)

    @njit
    def _mm(a_ptr, lda, b_ptr, ldb, out_ptr, ldc, M, N, K):
        """``A @ B`` of C-contiguous (M, K) and (K, N) blocks as numpy multiplies matrices of more than one row and
        column: ``gemm``."""
        _gemm(_ROW_MAJOR, _NO_TRANS, _NO_TRANS, M, N, K, 1.0, a_ptr, lda, b_ptr, ldb, 0.0, out_ptr, ldc)

    # --- the problem (:class:`.refine.RefineProblem` with :func:`.refine.residuals_batch`) -----------------------

    @njit
    def _scale_terms(t, p, G, a):
        """``a = t @ G[:, :3].T + p @ G[:, 3:].T`` (:meth:`.problem.Problem.scale_terms`) into ``a`` (B, m)."""
        B, P = p.shape
        m = G.shape[0]
        ld = G.shape[1]
        at = np.empty((B, m))
        ap = np.empty((B, m))
        _rows_times_t(t, B, 3, G.ctypes.data, ld, m, at)
        _rows_times_t(p, B, P, G.ctypes.data + 3 * 8, ld, m, ap)
        for k in range(B):
            for i in range(m):
                a[k, i] = at[k, i] + ap[k, i]

    @njit
    def _settle(t, p, G, b, A_mean):
        """:meth:`.refine.RefineProblem.settle`: ``(t, p)`` at the scale the cues prefer, and the pivots."""
        B, P = p.shape
        m = G.shape[0]
        a = np.empty((B, m))
        _scale_terms(t, p, G, a)
        ab = np.empty(B)
        _rows_dot(a, b, ab)
        t_out = np.empty((B, 3))
        p_out = np.empty((B, P))
        for k in range(B):
            s = ab[k] / _einsum_pair(a[k], a[k], m)
            if not s > 0:
                s = 1.0
            for i in range(3):
                t_out[k, i] = s * t[k, i]
            for i in range(P):
                p_out[k, i] = s * p[k, i]
        pivot = np.empty((B, 3))
        _rows_times_t(p_out, B, P, A_mean.ctypes.data, P, 3, pivot)
        return t_out, p_out, pivot

    @njit
    def residuals(R, t, p, pivot, A, A_rows, uv, Kp, w, G, b, Gjac, see_t, up, n_up, w_up, row_w, weighted,
                  mid, low, high, profile, about_pivot, with_jacobian):
        """:func:`.refine.residuals_batch`: ``r`` (B, M) and, ``with_jacobian``, ``J`` (B, M, 6 + P) (else an empty
        array), with the scale rows profiled when ``profile``; rotations about ``pivot`` (B, 3) when ``about_pivot``,
        else about the origin (``pivot`` then zeros, as the arrows' rows take it); the arrows' midpoints ``mid``
        (n, 3, P) and their zones' bounds ``low``, ``high`` (3 n, P) (:meth:`.problem.Problem.arrow_rows`)."""
        B, P = p.shape
        N = A.shape[0]
        m = G.shape[0]
        n = 6 + P
        n_arrows = mid.shape[0]
        M = 2 * N + m + n_up + 3 * n_arrows
        fx, skew, cx, fy, cy = Kp[0], Kp[1], Kp[2], Kp[3], Kp[4]
        X = np.empty((B, 3 * N))
        _rows_times_t(p, B, P, A_rows.ctypes.data, P, 3 * N, X)
        Y = np.empty((B, N, 3))
        for k in range(B):
            if N == 1:
                _gemv(_COL_MAJOR, _TRANS, 3, 3, 1.0, R[k].ctypes.data, 3, X[k].ctypes.data, 1, 0.0,
                      Y[k].ctypes.data, 1)
            else:
                _gemm(_ROW_MAJOR, _NO_TRANS, _TRANS, N, 3, 3, 1.0, X[k].ctypes.data, 3, R[k].ctypes.data, 3, 0.0,
                      Y[k].ctypes.data, 3)
        for k in range(B):
            for i in range(N):
                for j in range(3):
                    Y[k, i, j] = Y[k, i, j] + t[k, j]
        inv_z = np.empty((B, N))
        u_px = np.empty((B, N))
        v_px = np.empty((B, N))
        r = np.empty((B, M))
        for k in range(B):
            for i in range(N):
                iz = 1.0 / Y[k, i, 2]
                inv_z[k, i] = iz
                xn = Y[k, i, 0] * iz
                yn = Y[k, i, 1] * iz
                u = fx * xn + skew * yn
                v = fy * yn
                u_px[k, i] = u
                v_px[k, i] = v
                r[k, 2 * i] = u + cx - uv[i, 0]
                r[k, 2 * i + 1] = v + cy - uv[i, 1]
        a = np.empty((B, m))
        _scale_terms(t, p, G, a)
        aa = np.empty(B)
        s_best = np.empty(B)
        if profile:
            ab = np.empty(B)
            _rows_dot(a, b, ab)
        for k in range(B):
            if profile:
                aa[k] = _einsum_pair(a[k], a[k], m)
                s_best[k] = ab[k] / aa[k]
                for i in range(m):
                    r[k, 2 * N + i] = w * (s_best[k] * a[k, i] - b[i])
            else:
                for i in range(m):
                    r[k, 2 * N + i] = w * (a[k, i] - b[i])
            for i in range(n_up):
                r[k, 2 * N + m + i] = w_up * (R[k, i, 2] - up[i])
        if weighted:
            for k in range(B):
                for i in range(2 * N):
                    r[k, i] *= row_w[i]
        if not with_jacobian:
            if n_arrows:
                _arrow_rows(R, t, p, pivot, mid, low, high, w, r, np.empty((0, 0, 0)), 2 * N + m + n_up, False)
            return r, np.empty((0, 0, 0))
        J = np.zeros((B, M, n))
        DR = np.empty((B, N, 2, 3))
        for k in range(B):
            for i in range(N):
                iz = inv_z[k, i]
                J[k, 2 * i, 3] = fx * iz
                J[k, 2 * i, 4] = skew * iz
                miz = -iz
                J[k, 2 * i, 5] = u_px[k, i] * miz
                J[k, 2 * i + 1, 4] = fy * iz
                J[k, 2 * i + 1, 5] = v_px[k, i] * miz
                _mm(J.ctypes.data + ((k * M + 2 * i) * n + 3) * 8, n, R[k].ctypes.data, 3,
                    DR[k, i].ctypes.data, 3, 2, 3, 3)
        for k in range(B):
            for i in range(N):
                x0 = X[k, 3 * i] - pivot[k, 0]
                x1 = X[k, 3 * i + 1] - pivot[k, 1]
                x2 = X[k, 3 * i + 2] - pivot[k, 2]
                for row in range(2):
                    d0, d1, d2 = DR[k, i, row, 0], DR[k, i, row, 1], DR[k, i, row, 2]
                    J[k, 2 * i + row, 0] = x1 * d2 - x2 * d1
                    J[k, 2 * i + row, 1] = x2 * d0 - x0 * d2
                    J[k, 2 * i + row, 2] = x0 * d1 - x1 * d0
        DRA = np.empty((2, P))
        for k in range(B):
            for i in range(N):
                _mm(DR[k, i].ctypes.data, 3, A[i].ctypes.data, P, DRA.ctypes.data, P, 2, P, 3)
                for row in range(2):
                    for j in range(P):
                        J[k, 2 * i + row, 6 + j] = DRA[row, j]
        if weighted:
            for k in range(B):
                for i in range(2 * N):
                    for j in range(n):
                        J[k, i, j] *= row_w[i]
        Ga = np.empty((B, m, n))
        for k in range(B):
            Ga[k] = Gjac
        if see_t and about_pivot:
            W = np.zeros((3, 3))
            RW = np.empty((3, 3))
            GRW = np.empty((m, 3))
            for k in range(B):
                W[0, 1], W[0, 2] = -pivot[k, 2], pivot[k, 1]
                W[1, 0], W[1, 2] = pivot[k, 2], -pivot[k, 0]
                W[2, 0], W[2, 1] = -pivot[k, 1], pivot[k, 0]
                _mm(R[k].ctypes.data, 3, W.ctypes.data, 3, RW.ctypes.data, 3, 3, 3, 3)
                _mm(G.ctypes.data, G.shape[1], RW.ctypes.data, 3, GRW.ctypes.data, 3, m, 3, 3)
                for i in range(m):
                    for j in range(3):
                        Ga[k, i, j] = GRW[i, j]
        v = np.empty(m)
        for k in range(B):
            if profile:
                two_s = 2.0 * s_best[k]
                for i in range(m):
                    v[i] = b[i] - two_s * a[k, i]
                for j in range(n):
                    ds = 0.0
                    for i in range(m):
                        ds = ds + Ga[k, i, j] * v[i]
                    ds = ds / aa[k]
                    for i in range(m):
                        J[k, 2 * N + i, j] = w * (s_best[k] * Ga[k, i, j] + a[k, i] * ds)
            else:
                for j in range(n):
                    for i in range(m):
                        J[k, 2 * N + i, j] = w * Ga[k, i, j]
            for i in range(n_up):
                J[k, 2 * N + m + i, 0] = -w_up * R[k, i, 1]
                J[k, 2 * N + m + i, 1] = w_up * R[k, i, 0]
        if n_arrows:
            _arrow_rows(R, t, p, pivot, mid, low, high, w, r, J, 2 * N + m + n_up, True)
        return r, J

    @njit
    def _hat(x, out):
        out[0, 0], out[0, 1], out[0, 2] = 0.0, -x[2], x[1]
        out[1, 0], out[1, 1], out[1, 2] = x[2], 0.0, -x[0]
        out[2, 0], out[2, 1], out[2, 2] = -x[1], x[0], 0.0

    @njit
    def _d_point(Rk, x, q, H, out):
        """The rotation and translation columns of ``d(R x + t)`` (3, 6 + P) into ``out``: ``-R [x - q]x`` and ``I``
        (``d_point`` of :meth:`.problem.Problem.arrow_rows`; the ``p`` columns are the caller's)."""
        col = np.empty(3)
        for j in range(3):
            col[j] = x[j] - q[j]
        _hat(col, H)
        for i in range(3):
            for kk in range(3):
                s = 0.0
                for j in range(3):
                    s = s + Rk[i, j] * H[j, kk]
                out[i, kk] = -s
            for kk in range(3):
                out[i, 3 + kk] = 1.0 if kk == i else 0.0

    @njit
    def _arrow_rows(R, t, p, pivot, mid, low, high, w, r, J, row0, with_jacobian):
        """:meth:`.problem.Problem.arrow_rows` times ``w`` into ``r`` and ``J`` from row ``row0``: each arrow's
        midpoint, moved along its ray to the distance of the vehicle's centre, outside its zone (metres over
        :data:`.problem.ARROW_ZONE_SIGMA`)."""
        B, P = p.shape
        n = mid.shape[0]
        Q = 6 + P
        sigma = 0.5  # ARROW_ZONE_SIGMA
        lows = np.empty((B, 3 * n))
        highs = np.empty((B, 3 * n))
        _rows_times_t(p, B, P, low.ctypes.data, P, 3 * n, lows)
        _rows_times_t(p, B, P, high.ctypes.data, P, 3 * n, highs)
        c = np.empty((n, 3))
        a = np.empty((n, 3))
        wv = np.empty((n, 3))
        c_ray = np.empty((n, 3))
        na = np.empty(n)
        rho = np.empty(n)
        v = np.zeros(3)
        bv = np.empty(3)
        outside = np.empty((n, 3))
        side = np.zeros((n, 3), dtype=np.int64)  # 1 above, -1 below, 0 inside
        for k in range(B):
            v[2] = 0.5 * p[k, 2]
            for q in range(n):
                for i in range(3):
                    c[q, i] = _einsum_pair(mid[q, i], p[k], P)
            for q in range(n):
                for i in range(3):
                    a[q, i] = _einsum_pair(R[k, i], c[q], 3) + t[k, i]
            for i in range(3):
                bv[i] = _einsum_pair(R[k, i], v, 3) + t[k, i]
            nb = math.sqrt((bv[0] * bv[0] + bv[1] * bv[1]) + bv[2] * bv[2])
            any_out = False
            for q in range(n):
                na[q] = math.sqrt((a[q, 0] * a[q, 0] + a[q, 1] * a[q, 1]) + a[q, 2] * a[q, 2])
                rho[q] = nb / na[q]
                for i in range(3):
                    wv[q, i] = rho[q] * a[q, i] - t[k, i]
                for i in range(3):
                    s = 0.0
                    for j in range(3):
                        s = s + R[k, j, i] * wv[q, j]
                    c_ray[q, i] = s
                for i in range(3):
                    above = c_ray[q, i] - highs[k, 3 * q + i]
                    below = c_ray[q, i] - lows[k, 3 * q + i]
                    if above > 0.0:
                        outside[q, i], side[q, i] = above, 1
                    elif below < 0.0:
                        outside[q, i], side[q, i] = below, -1
                    else:
                        outside[q, i], side[q, i] = 0.0, 0
                        continue
                    any_out = True
                    r[k, row0 + 3 * q + i] = w * (outside[q, i] / sigma)
                for i in range(3):
                    if side[q, i] == 0:
                        r[k, row0 + 3 * q + i] = w * (0.0 / sigma)
            if not any_out or not with_jacobian:
                continue
            # The Jacobian of the rows outside (the others stay zero, as numpy's zone gradient leaves them).
            H = np.empty((3, 3))
            da = np.empty((n, 3, Q))
            for q in range(n):
                _d_point(R[k], c[q], pivot[k], H, da[q])
                for i in range(3):
                    for pp in range(P):
                        s = 0.0
                        for j in range(3):
                            s = s + R[k, i, j] * mid[q, j, pp]
                        da[q, i, 6 + pp] = s
            db = np.empty((3, Q))
            _d_point(R[k], v, pivot[k], H, db)
            for i in range(3):
                for pp in range(P):
                    s = 0.0
                    for j in range(3):
                        s = s + R[k, i, j] * (0.5 if (j == 2 and pp == 2) else 0.0)
                    db[i, 6 + pp] = s
            e1 = np.empty(Q)
            for pp in range(Q):
                s = 0.0
                for i in range(3):
                    s = s + bv[i] * db[i, pp]
                e1[pp] = s
            dt_total = np.zeros((3, Q))
            _hat(pivot[k], H)
            for i in range(3):
                for kk in range(3):
                    s = 0.0
                    for j in range(3):
                        s = s + R[k, i, j] * H[j, kk]
                    dt_total[i, kk] = s
                dt_total[i, 3 + i] = 1.0
            dw = np.empty((3, Q))
            Hc = np.empty((3, 3))
            for q in range(n):
                nb2 = nb * nb
                na2 = na[q] * na[q]
                for pp in range(Q):
                    s = 0.0
                    for i in range(3):
                        s = s + a[q, i] * da[q, i, pp]
                    d_rho = rho[q] * (e1[pp] / nb2 - s / na2)
                    for j in range(3):
                        dw[j, pp] = (a[q, j] * d_rho + rho[q] * da[q, j, pp]) - dt_total[j, pp]
                _hat(c_ray[q], Hc)
                for i in range(3):
                    if side[q, i] == 0:
                        continue
                    row = 3 * q + i
                    for pp in range(Q):
                        s = 0.0
                        for j in range(3):
                            s = s + R[k, j, i] * dw[j, pp]
                        if pp < 3:
                            s += Hc[i, pp]
                        elif pp >= 6:
                            s -= _bound(high, low, side[q, i], row, pp - 6)
                        J[k, row0 + row, pp] = w * (s / sigma)

    @njit
    def _bound(high, low, side, row, j):
        """The zone's bound a row outside it is measured from: its high bound above, its low bound below."""
        return high[row, j] if side == 1 else low[row, j]

    @njit
    def _rodrigues(wx, wy, wz, out):
        """``cv2.Rodrigues`` of the rotation vector ``(wx, wy, wz)`` into ``out`` (3, 3), operation for operation
        (the identity below machine epsilon, as it; :func:`toosicubix.geometry.so3_exp` gives the zero vector the
        identity without calling it)."""
        theta = math.sqrt(wx * wx + wy * wy + wz * wz)
        if theta < 2.220446049250313e-16:
            for i in range(3):
                for j in range(3):
                    out[i, j] = 1.0 if i == j else 0.0
            return
        c = math.cos(theta)
        s = math.sin(theta)
        c1 = 1.0 - c
        itheta = 1.0 / theta
        rx = wx * itheta
        ry = wy * itheta
        rz = wz * itheta
        rrt = (rx * rx, rx * ry, rx * rz, rx * ry, ry * ry, ry * rz, rx * rz, ry * rz, rz * rz)
        r_x = (0.0, -rz, ry, rz, 0.0, -rx, -ry, rx, 0.0)
        for i in range(3):
            for j in range(3):
                e = 1.0 if i == j else 0.0
                out[i, j] = (c * e + c1 * rrt[3 * i + j]) + s * r_x[3 * i + j]

    @njit
    def _update(R, t, p, pivot, step):
        """:meth:`.refine.RefineProblem.update`: ``R exp([delta]x)``, ``t`` moved with the turn about the pivot."""
        B, P = p.shape
        E = np.empty((3, 3))
        R_new = np.empty((B, 3, 3))
        t_new = np.empty((B, 3))
        p_new = np.empty((B, P))
        D = np.empty(3)
        for k in range(B):
            _rodrigues(step[k, 0], step[k, 1], step[k, 2], E)
            _mm(R[k].ctypes.data, 3, E.ctypes.data, 3, R_new[k].ctypes.data, 3, 3, 3, 3)
            piv = pivot[k].copy()
            for i in range(3):
                for j in range(3):
                    D[j] = R[k, i, j] - R_new[k, i, j]
                t_new[k, i] = (t[k, i] + step[k, 3 + i]) + _einsum_pair(D, piv, 3)
            for i in range(P):
                p_new[k, i] = p[k, i] + step[k, 6 + i]
        return R_new, t_new, p_new

    @njit
    def _feasible(R, t, p, A_rows, up, min_up, may_tilt):
        """:meth:`.refine.RefineProblem.feasible`: (B,) bool."""
        B, P = p.shape
        N = A_rows.shape[0] // 3
        X = np.empty((B, 3 * N))
        _rows_times_t(p, B, P, A_rows.ctypes.data, P, 3 * N, X)
        depths = np.empty(N)
        out = np.empty(B, dtype=np.bool_)
        for k in range(B):
            if N == 1:
                depths[0] = 0.0 + _dot(3, X[k].ctypes.data, 1, R[k].ctypes.data + 6 * 8, 1)
            else:
                _gemv(_COL_MAJOR, _TRANS, 3, N, 1.0, X[k].ctypes.data, 3, R[k].ctypes.data + 6 * 8, 1, 0.0,
                      depths.ctypes.data, 1)
            if B == 1:
                upness = 0.0 + _dot(3, R[k].ctypes.data + 2 * 8, 3, up.ctypes.data, 1)
            else:
                upness = 0.0
                for j in range(3):
                    upness += R[k, j, 2] * up[j]
            positive = p[k, 0] > 0.0 and p[k, 1] > 0.0 and p[k, 2] > 0.0
            out[k] = (positive and t[k, 2] > MIN_DEPTH and _extreme(depths, False) + t[k, 2] > MIN_DEPTH
                      and (may_tilt[k] or upness >= min_up))
        return out


    # --- coordinate descent's shape step and 3D cost (:func:`.descent.solve_shapes`, :func:`.descent.costs_3d`) ----

    @njit
    def solve_shapes(R, A, M, prior_normal, rhs):
        """The shape step's ``(p, t)`` (S, P + 3) of S rotations, or an empty array when a system is singular (numpy
        raises there): ``M_i R`` per click, ``[M_i R A_i, M_i]`` stacked, its normal matrix plus the prior's with
        numpy's ridge, solved by ``dgesv`` as ``np.linalg.solve`` does."""
        S = R.shape[0]
        N, _, P = A.shape
        n = P + 3
        design = np.zeros((N, 2, n))
        for i in range(N):
            for row in range(2):
                for j in range(3):
                    design[i, row, P + j] = M[i, row, j]
        MR = np.empty((N, 2, 3))
        normal = np.empty((n, n))
        diagonal = np.empty(n)
        x = np.empty((S, n))
        ipiv = np.empty(n, dtype=np.int64)
        info = np.zeros(1, dtype=np.int64)
        sizes = np.array([n, 1], dtype=np.int64)
        for s in range(S):
            for i in range(N):
                _mm(M[i].ctypes.data, 3, R[s].ctypes.data, 3, MR[i].ctypes.data, 3, 2, 3, 3)
            for i in range(N):
                _mm(MR[i].ctypes.data, 3, A[i].ctypes.data, P, design[i].ctypes.data, n, 2, P, 3)
            _syrk(_ROW_MAJOR, _UPPER, _TRANS, n, 2 * N, 1.0, design.ctypes.data, n, 0.0, normal.ctypes.data, n)
            for i in range(n):
                for j in range(i + 1, n):
                    normal[j, i] = normal[i, j]
            for i in range(n):
                for j in range(n):
                    normal[i, j] = normal[i, j] + prior_normal[i, j]
            for i in range(n):
                diagonal[i] = normal[i, i]
            ridge = 1e-12 * _pairwise(diagonal, n) / n
            for i in range(n):
                normal[i, i] += ridge
            x[s] = rhs
            _gesv(sizes.ctypes.data, sizes.ctypes.data + 8, normal.ctypes.data, sizes.ctypes.data, ipiv.ctypes.data,
                  x[s].ctypes.data, sizes.ctypes.data, info.ctypes.data)
            if info[0] != 0:
                return np.empty((0, n))
        return x

    @njit
    def costs_3d(R, t, p, A_rows, u, G, b, lambda_3d):
        """:func:`.descent.costs_3d`: (S,)."""
        S, P = p.shape
        N = A_rows.shape[0] // 3
        m = G.shape[0]
        X = np.empty((S, 3 * N))
        _rows_times_t(p, S, P, A_rows.ctypes.data, P, 3 * N, X)
        a = np.empty((S, m))
        _scale_terms(t, p, G, a)
        ee = np.empty(2 * N)
        d = np.empty(m)
        out = np.empty(S)
        for s in range(S):
            for i in range(N):
                y0 = _einsum_pair(R[s, 0], X[s, 3 * i:3 * i + 3], 3) + t[s, 0]
                y1 = _einsum_pair(R[s, 1], X[s, 3 * i:3 * i + 3], 3) + t[s, 1]
                y2 = _einsum_pair(R[s, 2], X[s, 3 * i:3 * i + 3], 3) + t[s, 2]
                e0 = y0 - u[i, 0] * y2
                e1 = y1 - u[i, 1] * y2
                ee[2 * i] = e0 * e0
                ee[2 * i + 1] = e1 * e1
            for i in range(m):
                diff = a[s, i] - b[i]
                d[i] = diff * diff
            out[s] = _pairwise(ee, 2 * N) + lambda_3d * _pairwise(d, m)
        return out

    # --- the loop (:func:`.lm.levenberg_marquardt`, trivial loss) ------------------------------------------------

    @njit
    def _gather(x, which):
        return x[which]

    @njit
    def lm(R, t, p, pivot, A, A_rows, A_mean, uv, Kp, w, G, b, Gjac, see_t, up, n_up, w_up, row_w, weighted,
           mid, low, high, min_up, may_tilt, size, max_iterations, gradient_tolerance_sq, step_tolerance,
           cost_tolerance, initial_damping, abandon_factor, abandon_after, abandon_above, abandon):
        B, P = p.shape
        n = 6 + P
        r, J = residuals(R, t, p, pivot, A, A_rows, uv, Kp, w, G, b, Gjac, see_t, up, n_up, w_up, row_w, weighted,
                         mid, low, high, True, True, True)
        M = r.shape[1]
        cost = np.empty(B)
        for k in range(B):
            cost[k] = _einsum_pair(r[k], r[k], M)
        initial_cost = cost.copy()
        mu = np.full(B, initial_damping)
        nu = np.full(B, 2.0)
        iterations = np.zeros(B, dtype=np.int64)
        status = np.full(B, _RUNNING)
        moved = True
        g = np.empty((B, n))
        column_sq = np.empty((B, n))
        JtJ = np.empty((B, n, n))
        Dg = np.empty((B, n))
        minus_g = np.empty((B, n))
        H = np.empty((n, n))
        step = np.empty((B, n))
        running = np.empty(B, dtype=np.bool_)
        n_arr = np.array([n], dtype=np.int64)
        one_arr = np.array([1], dtype=np.int64)
        info = np.zeros(1, dtype=np.int64)
        uplo = np.array([ord("U")], dtype=np.uint8)
        for iteration in range(max_iterations):
            for k in range(B):
                running[k] = status[k] == _RUNNING
            if abandon and iteration >= abandon_after:
                bar = abandon_above
                if not math.isnan(abandon_factor):
                    lowest = abandon_factor * _extreme(cost, False) + 1e-6
                    if lowest < bar:  # Python's min(bar, lowest)
                        bar = lowest
                for k in range(B):
                    if running[k] and iterations[k] >= abandon_after and cost[k] > bar:
                        status[k] = _ABANDONED
                        running[k] = False
            if not running.any():
                break
            if moved:
                for k in range(B):
                    for i in range(n):
                        gi = 0.0
                        ci = 0.0
                        for j in range(M):
                            gi = gi + J[k, j, i] * r[k, j]
                            ci = ci + J[k, j, i] * J[k, j, i]
                        g[k, i] = gi
                        column_sq[k, i] = ci
                any_done = False
                for k in range(B):
                    cosines = np.empty(n)
                    for i in range(n):
                        cosines[i] = g[k, i] * g[k, i] / _maximum(column_sq[k, i], 1e-300)
                    cosine = _extreme(cosines, True)
                    rr = cost[k]
                    if running[k] and (rr == 0.0 or cosine <= gradient_tolerance_sq * rr):
                        status[k] = _GRADIENT
                        running[k] = False
                        any_done = True
                if any_done and not running.any():
                    break
                for k in range(B):
                    _syrk(_ROW_MAJOR, _UPPER, _TRANS, n, M, 1.0, J[k].ctypes.data, n, 0.0, JtJ[k].ctypes.data, n)
                    for i in range(n):
                        for j in range(i + 1, n):
                            JtJ[k, j, i] = JtJ[k, i, j]
                    floor = 1e-12 * _extreme(column_sq[k], True) + 1e-300
                    for i in range(n):
                        Dg[k, i] = _maximum(column_sq[k, i], floor)
                        minus_g[k, i] = -g[k, i]
                moved = False
            for k in range(B):
                if running[k]:
                    iterations[k] += 1
            solved = np.zeros(B, dtype=np.bool_)
            for k in range(B):
                if running[k]:
                    for i in range(n):
                        for j in range(n):
                            H[i, j] = JtJ[k, i, j]
                        H[i, i] += mu[k] * Dg[k, i]
                    for i in range(n):
                        step[k, i] = minus_g[k, i]
                    _posv(uplo.ctypes.data, n_arr.ctypes.data, one_arr.ctypes.data, H.ctypes.data, n_arr.ctypes.data,
                          step[k].ctypes.data, n_arr.ctypes.data, info.ctypes.data, 1)
                    ok = info[0] == 0
                    if ok:
                        for i in range(n):
                            if not np.isfinite(step[k, i]):
                                ok = False
                    solved[k] = ok
                if not solved[k]:
                    for i in range(n):
                        step[k, i] = 0.0
            R_try, t_try, p_try = _update(R, t, p, pivot, step)
            feasible = solved & _feasible(R_try, t_try, p_try, A_rows, up, min_up, may_tilt)
            n_feasible = int(feasible.sum())
            rho = np.full(B, -1.0)
            which = np.flatnonzero(feasible)
            if 0 < n_feasible < B:  # the feasible trials only, as a batch of their own
                R_try, t_try, p_try = _gather(R_try, which), _gather(t_try, which), _gather(p_try, which)
            if n_feasible:
                t_try, p_try, pivot_try = _settle(t_try, p_try, G, b, A_mean)
                r_try, J_try = residuals(R_try, t_try, p_try, pivot_try, A, A_rows, uv, Kp, w, G, b, Gjac, see_t,
                                          up, n_up, w_up, row_w, weighted, mid, low, high, True, True, True)
                new_cost = np.empty(n_feasible)
                for q in range(n_feasible):
                    new_cost[q] = _einsum_pair(r_try[q], r_try[q], M)
                dsg = np.empty(n)
                for q in range(n_feasible):
                    k = which[q]
                    for i in range(n):
                        dsg[i] = mu[k] * Dg[k, i] * step[k, i] - g[k, i]
                    predicted = _einsum_pair(step[k], dsg, n)
                    if predicted > 0:
                        rho[k] = (cost[k] - new_cost[q]) / predicted
            accept = rho > 0
            for k in range(B):
                if running[k] and not accept[k]:
                    mu[k] = mu[k] * nu[k]
                    nu[k] = nu[k] * 2.0
                    if mu[k] > 1e16:
                        status[k] = _DAMPING
            ka = np.flatnonzero(accept)
            if not len(ka):
                continue
            moved = True
            # step_is_small (RefineProblem), then the damping and status of the accepted starts
            small = np.empty(len(ka), dtype=np.bool_)
            for q in range(len(ka)):
                k = ka[q]
                biggest = _extreme(np.abs(step[k, :3]), True)
                rest = step[k, 3:].copy()
                small[q] = (biggest <= step_tolerance
                            and math.sqrt(_einsum_pair(rest, rest, n - 3)) <= step_tolerance * size[k])
            base = np.empty(len(ka))
            for q in range(len(ka)):
                base[q] = 2.0 * rho[ka[q]] - 1.0
            with numba.objmode(cube="float64[:]"):
                cube = _pow3(base)
            position = np.full(B, -1)
            for q in range(n_feasible):
                position[which[q]] = q
            for q in range(len(ka)):
                k = ka[q]
                s = position[k]
                R[k] = R_try[s]
                t[k] = t_try[s]
                p[k] = p_try[s]
                pivot[k] = pivot_try[s]
                r[k] = r_try[s]
                J[k] = J_try[s]
                drop = cost[k] - new_cost[s]
                cost[k] = new_cost[s]
                mu[k] = _maximum(mu[k] * _maximum(1.0 / 3.0, 1.0 - cube[q]), 1e-15)
                nu[k] = 2.0
                if small[q]:
                    status[k] = _STEP
                elif drop <= cost_tolerance * new_cost[s]:
                    status[k] = _COST
                else:
                    status[k] = _RUNNING
        for k in range(B):
            if status[k] == _RUNNING:
                status[k] = _MAX_ITERATIONS
        return R, t, p, cost, initial_cost, iterations, status


def warm_up() -> None:
    """Compile (or load from numba's cache) :func:`lm`, :func:`residuals`, :func:`solve_shapes` and :func:`costs_3d` for
    the argument types the solver passes, on a cuboid's four corners seen from 10 m."""
    P = 3
    A = np.zeros((4, 3, P))
    for i, (fx, fy, fz) in enumerate(((0.5, 0.5, 0.0), (-0.5, 0.5, 0.0), (-0.5, -0.5, 1.0), (0.5, -0.5, 1.0))):
        A[i] = np.diag([fx, fy, fz])
    R = np.array([[[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]])
    t = np.array([[0.0, 1.5, 10.0]])
    p = np.array([[4.0, 1.8, 1.5]])
    X = (A @ p[0]) @ R[0].T + t[0]
    uv = np.ascontiguousarray(X[:, :2] / X[:, 2:] * 700.0 + 300.0)
    G = np.zeros((3, 3 + P))
    G[:, 3:] = np.eye(3)
    Gjac = np.zeros((3, 6 + P))
    Gjac[:, 6:] = np.eye(3)
    lm(R.copy(), t.copy(), p.copy(), np.zeros((1, 3)), A, np.ascontiguousarray(A.reshape(-1, P)), A.mean(axis=0), uv,
       np.array([700.0, 0.0, 300.0, 700.0, 300.0]), 1.0, G, np.array([4.0, 1.8, 1.5]), Gjac, False,
       np.array([0.0, -1.0, 0.0]), 0, 0.0, np.ones(1), False, np.zeros((0, 3, P)), np.zeros((0, P)), np.zeros((0, P)),
       -np.inf, np.ones(1, dtype=np.bool_), np.ones(1), 5, 1e-12, 1e-10, 1e-8, 1e-3, math.nan, 10, math.inf, False)
    for with_jacobian in (True, False):
        residuals(R.copy(), t.copy(), p.copy(), np.zeros((1, 3)), A, np.ascontiguousarray(A.reshape(-1, P)), uv,
                  np.array([700.0, 0.0, 300.0, 700.0, 300.0]), 1.0, G, np.array([4.0, 1.8, 1.5]), Gjac, False,
                  np.array([0.0, -1.0, 0.0]), 0, 0.0, np.ones(1), False, np.zeros((0, 3, P)), np.zeros((0, P)),
                  np.zeros((0, P)), False, False, with_jacobian)
    M = np.zeros((4, 2, 3))
    M[:, 0, 0] = M[:, 1, 1] = 1.0
    x = solve_shapes(R.copy(), A, M, np.eye(6), np.ones(6))
    costs_3d(R.copy(), t.copy(), np.ascontiguousarray(x[:, :P]), np.ascontiguousarray(A.reshape(-1, P)),
             np.zeros((4, 3)), G, np.array([4.0, 1.8, 1.5]), 0.1)
