"""numpy's own OpenBLAS, called directly: the library the numpy wheels bundle (``scipy_openblas64``: 64-bit integers,
numpy's symbol names), found beside numpy, for the LAPACK solve numpy does not expose (:func:`dposv`) and for the
compiled kernels' BLAS and LAPACK calls (:mod:`.refine_kernel`).

Calling it saves every fitting process scipy's import (some 0.17 s, more than a small batch's fits) and gives the
numpy path and the compiled one the very same library. Where numpy is not built on a bundled OpenBLAS (a conda numpy
on MKL, say), :func:`library` is None, :func:`dposv` takes scipy's, and the compiled path is off.
"""

from __future__ import annotations

import ctypes
import glob
import logging
import os
from functools import cache

import numpy as np

log = logging.getLogger(__name__)

_INT = ctypes.c_int64


@cache
def library() -> ctypes.CDLL | None:
    """numpy's bundled OpenBLAS, or None where numpy has none (the reason logged at debug level)."""
    folder = os.path.join(os.path.dirname(np.__file__), os.pardir, "numpy.libs")
    found = sorted(glob.glob(os.path.join(folder, "libscipy_openblas64_*")))
    if not found:
        log.debug("numpy's OpenBLAS (scipy_openblas64) not found in %s", folder)
        return None
    try:
        blas = ctypes.CDLL(found[0])
        blas.scipy_dposv_64_  # noqa: B018 (the symbols this module and the kernels call)
        blas.scipy_dgesv_64_  # noqa: B018
    except (OSError, AttributeError) as exc:
        log.debug("numpy's OpenBLAS not usable: %s", exc)
        return None
    return blas


def address(symbol: str) -> int:
    """The address of a function of :func:`library` (which must not be None)."""
    return ctypes.cast(getattr(library(), symbol), ctypes.c_void_p).value


def dposv(H: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, int]:
    """LAPACK ``dposv`` on the upper triangle of a symmetric positive definite ``H`` (n, n): ``(x, info)`` with
    ``x`` (n,) solving ``H x = b`` (n,) when ``info`` is 0, as ``scipy.linalg.lapack.dposv(H, b)`` returns them (the
    same arithmetic: both run OpenBLAS's Cholesky factorisation and triangular solves)."""
    blas = library()
    if blas is None:
        from scipy.linalg import lapack

        _, x, info = lapack.dposv(H, b)
        return x, int(info)
    n = H.shape[0]
    a = np.array(H, dtype=float, order="F")  # overwritten by the factor
    x = np.array(b, dtype=float)  # overwritten by the solution
    info, size, one = _INT(0), _INT(n), _INT(1)
    pointer = ctypes.c_void_p
    blas.scipy_dposv_64_(ctypes.c_char_p(b"U"), ctypes.byref(size), ctypes.byref(one), a.ctypes.data_as(pointer),
                         ctypes.byref(size), x.ctypes.data_as(pointer), ctypes.byref(size), ctypes.byref(info),
                         ctypes.c_size_t(1))  # the length of the character argument (gfortran's hidden one)
    return x, int(info.value)
