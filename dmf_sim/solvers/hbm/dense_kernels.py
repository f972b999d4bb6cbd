"""Small dense linear algebra for the compiled harmonic-balance kernels
(:mod:`dmf_sim.solvers.hbm.kernels`): an LU solve with partial pivoting of the 2H+1 (or 2H+2)
unknowns of a sweep point, its work arrays and a NaN-aware max norm. numba's own
``np.linalg.solve`` inside a kernel was measured slower at these sizes (53-59 us against 23-33 us
at n = 49, doc/guide/compiled-sweeps.md).
"""
from __future__ import annotations

import numpy as np

from dmf_sim.core.compiled import jit

__all__ = ['PIVOT_TINY', 'lu_solve', 'lu_work', 'max_abs']

PIVOT_TINY = 0.0          # an exactly zero pivot is singular (as LAPACK's dgesv reports)


def lu_solve(A, b, x, LU, piv):
    """Solve A x = b by LU with partial pivoting (what LAPACK dgesv does); A, b untouched.
    Returns False on an exactly singular matrix. The elimination reads the pivot row from a
    copy, so its inner loop vectorizes (the same operations in the same order as a plain
    row update: bitwise the same result, 1.5-2x faster at n = 49)."""
    n = b.shape[0]
    row = np.empty(n)
    for i in range(n):
        for j in range(n):
            LU[i, j] = A[i, j]
        x[i] = b[i]
    for k in range(n):
        p = k
        big = abs(LU[k, k])
        for i in range(k + 1, n):
            a = abs(LU[i, k])
            if a > big:
                big = a
                p = i
        if big <= PIVOT_TINY:
            return False
        piv[k] = p
        if p != k:
            for j in range(n):
                t = LU[k, j]
                LU[k, j] = LU[p, j]
                LU[p, j] = t
            t = x[k]
            x[k] = x[p]
            x[p] = t
        inv = 1.0 / LU[k, k]
        m = n - k - 1
        for j in range(m):              # pivot row's tail in its own buffer: the update below
            row[j] = LU[k, k + 1 + j]   # reads no row it writes, so it runs in SIMD
        for i in range(k + 1, n):
            f = LU[i, k] * inv
            if f != 0.0:
                LU[i, k] = f
                tail = LU[i, k + 1:]
                for j in range(m):
                    tail[j] -= f * row[j]
                x[i] -= f * x[k]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for j in range(i + 1, n):
            s -= LU[i, j] * x[j]
        x[i] = s / LU[i, i]
    return True


def max_abs(v):
    """max |v_i|, NaN if any entry is NaN (numpy's max does so)."""
    m = 0.0
    for i in range(v.shape[0]):
        a = abs(v[i])
        if a > m or a != a:
            m = a
            if a != a:
                return a
    return m


def lu_work(n):
    """Work arrays of an n x n Newton solve: (matrix, right-hand side, step, LU, pivots)."""
    return (np.empty((n, n)), np.empty(n), np.empty(n), np.empty((n, n)),
            np.empty(n, dtype=np.int64))


lu_solve = jit(lu_solve)
max_abs = jit(max_abs)
lu_work = jit(lu_work)
