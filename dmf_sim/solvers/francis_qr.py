"""Eigenvalues of a real upper Hessenberg matrix by Francis' implicit double-shift QR iteration,
compiled (numba: nopython, cached).

Why the package has its own: a sweep's Floquet multipliers are the eigenvalues of one 32 x 32
monodromy per point beyond a knee, and LAPACK's ``dgeev`` spends most of its time on those in
the QR stage (``dhseqr``, which below 75 rows is ``dlahqr``). This iteration, on LAPACK's own
balancing and Hessenberg reduction (:func:`dmf_sim.solvers.lapack_kernel.eigenvalues_into`),
takes 0.7 of ``dgeev``'s time on the monodromies of the paper case with the same accuracy
(``benchmarks/bench_eigen.py`` measures both and their largest difference; the tests compare it
with ``numpy.linalg.eigvals``). Where it does not converge, the caller falls back on ``dgeev``.

The algorithm (Golub & Van Loan, *Matrix Computations*, 4th ed., alg. 7.5.1 and 7.5.2; the
control flow of EISPACK's ``hqr``): on the active block ``[lo, nn]`` of the Hessenberg matrix,

1. deflate where a subdiagonal entry is negligible, ``|h(k, k-1)| + s == s`` with
   ``s = |h(k-1, k-1)| + |h(k, k)|`` (the classical test);
2. a 1 x 1 block gives a real eigenvalue, a 2 x 2 block a real pair or a complex-conjugate pair
   (the one with the positive imaginary part first, as LAPACK orders them);
3. otherwise one implicit double-shift QR step with the eigenvalues of the trailing 2 x 2 block
   as shifts (exceptional shifts after 10 and 20 iterations without deflation), chasing the
   bulge down the active block with 3 x 3 Householder reflectors. Eigenvalues alone are wanted,
   so each reflector is applied inside the active block only.

At most ``max_iter`` iterations per eigenvalue (30, as EISPACK).
"""
from __future__ import annotations

import math

from dmf_sim.core.compiled import jit

__all__ = ['hessenberg_eigenvalues', 'MAX_ITER']

MAX_ITER = 30          # QR iterations per eigenvalue before giving up (EISPACK's limit)


def hessenberg_eigenvalues(a, wr, wi, max_iter):
    """wr + i wi <- the eigenvalues of the upper Hessenberg matrix ``a`` (n x n, C order; entries
    below the first subdiagonal are read as zero; ``a`` is overwritten). Returns 0, or the
    1-based index of the eigenvalue that did not converge in ``max_iter`` iterations."""
    n = a.shape[0]
    for i in range(2, n):
        for j in range(i - 1):
            a[i, j] = 0.0
    anorm = 0.0
    for i in range(n):
        for j in range(max(i - 1, 0), n):
            anorm += abs(a[i, j])
    nn = n - 1
    shift = 0.0                  # exceptional shifts applied so far (added back to each value)
    x = y = w = 0.0
    while nn >= 0:
        its = 0
        while True:
            # 1. look for a negligible subdiagonal entry: the active block is [lo, nn]
            lo = nn
            while lo >= 1:
                s = abs(a[lo - 1, lo - 1]) + abs(a[lo, lo])
                if s == 0.0:
                    s = anorm
                if abs(a[lo, lo - 1]) + s == s:
                    a[lo, lo - 1] = 0.0
                    break
                lo -= 1
            x = a[nn, nn]
            if lo == nn:                                   # 2. one real eigenvalue
                wr[nn] = x + shift
                wi[nn] = 0.0
                nn -= 1
                break
            y = a[nn - 1, nn - 1]
            w = a[nn, nn - 1] * a[nn - 1, nn]
            if lo == nn - 1:                               # 2. a 2 x 2 block: two eigenvalues
                p = 0.5 * (y - x)
                q = p * p + w
                z = math.sqrt(abs(q))
                x += shift
                if q >= 0.0:                              # a real pair
                    z = p + (z if p >= 0.0 else -z)
                    wr[nn - 1] = x + z
                    wr[nn] = x + z
                    if z != 0.0:
                        wr[nn] = x - w / z
                    wi[nn - 1] = 0.0
                    wi[nn] = 0.0
                else:                                     # a complex-conjugate pair
                    wr[nn - 1] = x + p
                    wr[nn] = x + p
                    wi[nn - 1] = z
                    wi[nn] = -z
                nn -= 2
                break
            if its == max_iter:
                return nn + 1
            if its == 10 or its == 20:                    # exceptional shift
                shift += x
                for i in range(nn + 1):
                    a[i, i] -= x
                s = abs(a[nn, nn - 1]) + abs(a[nn - 1, nn - 2])
                x = 0.75 * s
                y = x
                w = -0.4375 * s * s
            its += 1
            # 3. where the double-shift step can start: two consecutive small subdiagonals
            m = nn - 2
            p = q = r = 0.0
            while m >= lo:
                z = a[m, m]
                r = x - z
                s = y - z
                p = (r * s - w) / a[m + 1, m] + a[m, m + 1]
                q = a[m + 1, m + 1] - z - r - s
                r = a[m + 2, m + 1]
                s = abs(p) + abs(q) + abs(r)
                p /= s
                q /= s
                r /= s
                if m == lo:
                    break
                u = abs(a[m, m - 1]) * (abs(q) + abs(r))
                v = abs(p) * (abs(a[m - 1, m - 1]) + abs(z) + abs(a[m + 1, m + 1]))
                if u + v == v:
                    break
                m -= 1
            for i in range(m + 2, nn + 1):
                a[i, i - 2] = 0.0
                if i != m + 2:
                    a[i, i - 3] = 0.0
            # the bulge chase: a 3 x 3 reflector per column (2 x 2 at the last)
            for k in range(m, nn):
                if k != m:
                    p = a[k, k - 1]
                    q = a[k + 1, k - 1]
                    r = a[k + 2, k - 1] if k != nn - 1 else 0.0
                    x = abs(p) + abs(q) + abs(r)
                    if x != 0.0:
                        p /= x
                        q /= x
                        r /= x
                s = math.sqrt(p * p + q * q + r * r)
                if p < 0.0:
                    s = -s
                if s == 0.0:
                    continue
                if k == m:
                    if lo != m:
                        a[k, k - 1] = -a[k, k - 1]
                else:
                    a[k, k - 1] = -s * x
                p += s
                x = p / s
                y = q / s
                z = r / s
                q /= p
                r /= p
                last = k == nn - 1
                for j in range(k, nn + 1):                # rows k .. k+2 of the active block
                    if last:
                        p = a[k, j] + q * a[k + 1, j]
                    else:
                        p = a[k, j] + q * a[k + 1, j] + r * a[k + 2, j]
                        a[k + 2, j] -= p * z
                    a[k + 1, j] -= p * y
                    a[k, j] -= p * x
                top = nn if nn < k + 3 else k + 3
                for i in range(lo, top + 1):               # columns k .. k+2 of the block
                    if last:
                        p = x * a[i, k] + y * a[i, k + 1]
                    else:
                        p = x * a[i, k] + y * a[i, k + 1] + z * a[i, k + 2]
                        a[i, k + 2] -= p * r
                    a[i, k + 1] -= p * q
                    a[i, k] -= p
    return 0


hessenberg_eigenvalues = jit(hessenberg_eigenvalues)
