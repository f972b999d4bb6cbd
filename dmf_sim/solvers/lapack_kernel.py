"""Eigenvalues of a real square matrix inside compiled kernels: LAPACK's balancing and
Hessenberg reduction, then the double-shift QR of :mod:`dmf_sim.solvers.francis_qr`.

numba compiles ``np.linalg.eigvals`` only where the result keeps the input's type (a real matrix
with complex eigenvalues raises), so a kernel that needs the Floquet multipliers of a monodromy
calls LAPACK itself: SciPy's LAPACK routines, found by name in ``scipy.linalg.cython_lapack``,
bound as numba external functions so the kernels that call them are cached on disk like the
others. The symbols are registered when this module is imported, before any kernel that uses
them is loaded or compiled.

:func:`eigenvalues_into` does what ``dgeev`` without eigenvectors does — ``dgebal`` (permute and
scale), ``dgehrd`` (Householder reduction to Hessenberg form), then the QR iteration — with the
QR stage compiled in the package instead of LAPACK's ``dlahqr`` (0.7 of ``dgeev``'s time on a
sweep's monodromies, the same accuracy: ``benchmarks/bench_eigen.py``). A matrix whose QR
iteration does not converge goes to ``dgeev`` itself (:func:`dgeev_into`).
"""
from __future__ import annotations

import numpy as np

from dmf_sim.core.compiled import HAVE_NUMBA, jit
from dmf_sim.solvers.francis_qr import MAX_ITER, hessenberg_eigenvalues

__all__ = ['HRD_WORK_PER_ROW', 'eigenvalues_into', 'dgeev_into']

HRD_WORK_PER_ROW = 64    # dgehrd's workspace per row (its largest block size; n would do here)

if HAVE_NUMBA:
    import llvmlite.binding as _llvm
    from numba import types as _types
    from numba.extending import get_cython_function_address as _cython_address

    def _bind(name: str, n_args: int):
        symbol = f'dmf_sim_{name}'
        _llvm.add_symbol(symbol, _cython_address('scipy.linalg.cython_lapack', name))
        return _types.ExternalFunction(symbol, _types.void(*([_types.voidptr] * n_args)))

    # every argument a pointer, in LAPACK's order:
    # dgeev(jobvl, jobvr, n, a, lda, wr, wi, vl, ldvl, vr, ldvr, work, lwork, info)
    _dgeev = _bind('dgeev', 14)
    # dgebal(job, n, a, lda, ilo, ihi, scale, info)
    _dgebal = _bind('dgebal', 8)
    # dgehrd(n, ilo, ihi, a, lda, tau, work, lwork, info)
    _dgehrd = _bind('dgehrd', 9)
else:  # pragma: no cover - numba is a hard dependency
    _dgeev = _dgebal = _dgehrd = None


def dgeev_into(X, wr, wi):
    """wr + i wi <- the eigenvalues of the real square matrix X (C order; not changed) by LAPACK
    ``dgeev`` without eigenvectors, given X in column-major order as SciPy's wrapper gives it
    (the same bits as ``scipy.linalg.lapack.dgeev(X)``). The caller checks that X is finite.
    Returns LAPACK's ``info`` (0: converged)."""
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


def eigenvalues_into(X, wr, wi, max_iter=MAX_ITER):
    """wr + i wi <- the eigenvalues of the real square matrix X (C order; not changed): LAPACK
    ``dgebal`` ('B') and ``dgehrd`` on X, then
    :func:`dmf_sim.solvers.francis_qr.hessenberg_eigenvalues` (``dgeev``'s steps with the QR
    stage compiled); complex pairs come as LAPACK gives them, the positive imaginary part first.
    Where the QR iteration does not converge in ``max_iter`` iterations per eigenvalue,
    ``dgeev`` (:func:`dgeev_into`). The caller checks that X is finite. Returns 0, or
    ``dgeev``'s ``info`` (0: converged)."""
    n = X.shape[0]
    if n == 0:
        return 0
    a = np.ascontiguousarray(X.T)        # column-major X, as LAPACK reads it
    job = np.array([66], dtype=np.uint8)  # 'B': permute and scale
    # n, lda, ilo, ihi, lwork, info
    dims = np.array([n, n, 1, n, HRD_WORK_PER_ROW * n, 0], dtype=np.int32)
    scale = np.empty(n)
    _dgebal(job.ctypes, dims[0:].ctypes, a.ctypes, dims[1:].ctypes, dims[2:].ctypes,
            dims[3:].ctypes, scale.ctypes, dims[5:].ctypes)
    if dims[5] != 0:
        return dgeev_into(X, wr, wi)
    tau = np.empty(max(n - 1, 1))
    work = np.empty(HRD_WORK_PER_ROW * n)
    _dgehrd(dims[0:].ctypes, dims[2:].ctypes, dims[3:].ctypes, a.ctypes, dims[1:].ctypes,
            tau.ctypes, work.ctypes, dims[4:].ctypes, dims[5:].ctypes)
    if dims[5] != 0:
        return dgeev_into(X, wr, wi)
    h = np.ascontiguousarray(a.T)        # the Hessenberg matrix in C order (reflectors below)
    if hessenberg_eigenvalues(h, wr, wi, max_iter) != 0:
        return dgeev_into(X, wr, wi)
    return 0


dgeev_into = jit(dgeev_into)
eigenvalues_into = jit(eigenvalues_into)
