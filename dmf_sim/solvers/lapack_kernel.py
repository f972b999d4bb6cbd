"""LAPACK's ``dgeev`` (eigenvalues of a real square matrix) callable from compiled kernels.

numba compiles ``np.linalg.eigvals`` only where the result keeps the input's type (a real matrix
with complex eigenvalues raises), so a kernel that needs the Floquet multipliers of a monodromy
calls the routine itself: the same ``dgeev`` that ``scipy.linalg.lapack.dgeev`` and
:func:`dmf_sim.solvers.stability.eigenvalues` call (SciPy's LAPACK, found by name in
``scipy.linalg.cython_lapack``), bound as a numba external function so the kernels that call it
are cached on disk like the others. The symbol is registered when this module is imported,
before any kernel that uses it is loaded or compiled.
"""
from __future__ import annotations

import numpy as np

from dmf_sim.solvers.compiled import HAVE_NUMBA, jit

__all__ = ['eigenvalues_into']

if HAVE_NUMBA:
    import llvmlite.binding as _llvm
    from numba import types as _types
    from numba.extending import get_cython_function_address as _cython_address

    _llvm.add_symbol('dmf_sim_dgeev', _cython_address('scipy.linalg.cython_lapack', 'dgeev'))
    # dgeev(jobvl, jobvr, n, a, lda, wr, wi, vl, ldvl, vr, ldvr, work, lwork, info): all pointers
    _dgeev = _types.ExternalFunction('dmf_sim_dgeev', _types.void(*([_types.voidptr] * 14)))
else:  # pragma: no cover - numba is a hard dependency
    _dgeev = None


def eigenvalues_into(X, wr, wi):
    """wr + i wi <- the eigenvalues of the real square matrix X (C order; not changed) by LAPACK
    ``dgeev`` without eigenvectors, given X in column-major order as SciPy's wrapper gives it,
    so the values are the same bits as :func:`dmf_sim.solvers.stability.eigenvalues` (X). The
    caller checks that X is finite. Returns LAPACK's ``info`` (0: converged)."""
    n = X.shape[0]
    a = np.ascontiguousarray(X.T)        # column-major X
    job = np.array([78], dtype=np.uint8)  # 'N': no eigenvectors
    # n, lda, ldvl, ldvr, lwork (SciPy's default 4n), info
    dims = np.array([n, n, 1, 1, max(4 * n, 1), 0], dtype=np.int32)
    dummy = np.empty(1)
    work = np.empty(max(4 * n, 1))
    _dgeev(job.ctypes, job.ctypes, dims[0:].ctypes, a.ctypes, dims[1:].ctypes, wr.ctypes,
           wi.ctypes, dummy.ctypes, dims[2:].ctypes, dummy.ctypes, dims[3:].ctypes,
           work.ctypes, dims[4:].ctypes, dims[5:].ctypes)
    return dims[5]


eigenvalues_into = jit(eigenvalues_into)
