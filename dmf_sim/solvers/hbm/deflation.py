"""Deflated Newton on the condensed harmonic balance residual (Farrell, Birkisson & Funke, SIAM
J. Sci. Comput. 37 (2015) A2026): find solutions *other than* the known ones.

For the residual r(x) = 0 (eq. 15, dmf_sim.solvers.hbm.condensed) and known solutions x_i, Newton
is applied to the deflated residual

    r~(x) = M(x) r(x),     M(x) = prod_i ( ||(x - x_i) / s||^-p + sigma ),

which has the same roots except the x_i, where it does not vanish. With the plain Newton step
d = -J^-1 r the deflated step is ``d / (1 - grad(ln M) . d)`` (Sherman-Morrison), so a
deflated iteration costs no more than a plain one. Convergence is judged on the plain residual.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dmf_sim.solvers.continuation import solve_small
from dmf_sim.solvers.hbm import kernels
from dmf_sim.solvers.hbm.condensed import CondensedHBM
from dmf_sim.solvers.hbm.point import LinearParts

__all__ = ['DeflationOptions', 'DeflatedNewton']


@dataclass(frozen=True)
class DeflationOptions:
    """power p, shift sigma of the deflation operator; scale s [rad] of the distance; Newton
    iterations, smallest backtracking step, and ``stagnation``: give up when ``stagnation``
    iterations in a row have not halved the best residual (a seed that wanders)."""

    power: float = 2.0
    shift: float = 1.0
    scale: float = 1e-2
    max_iter: int = 30
    min_step: float = 1.0 / 8
    stagnation: int = 6


class DeflatedNewton:
    """Newton on M(x) r(x) for one speed of a condensed HBM problem."""

    def __init__(self, hbm: CondensedHBM, options: DeflationOptions | None = None):
        self.hbm = hbm
        self.options = o = options or DeflationOptions()
        # what the compiled kernels read of the options: [power, shift, scale, max_iter,
        # min_step, stagnation]
        self._defl = np.array([o.power, o.shift, o.scale, o.max_iter, o.min_step, o.stagnation],
                              dtype=float)

    @staticmethod
    def _rows(known: np.ndarray, n: int) -> np.ndarray:
        """The known solutions as C-contiguous rows of n unknowns (what the kernels read)."""
        return np.ascontiguousarray(np.asarray(known, dtype=float).reshape(-1, n))

    def _log_m(self, x: np.ndarray, known: np.ndarray) -> tuple[float, np.ndarray]:
        """ln M(x) and its gradient for the known solutions (rows of ``known``)."""
        o = self.options
        if len(known) == 0:
            return 0.0, np.zeros_like(x)
        d = (x[None, :] - known) / o.scale
        dist2 = np.maximum(np.einsum('ij,ij->i', d, d), 1e-300)
        m = dist2 ** (-0.5 * o.power) + o.shift
        # d/dx ln(||d||^-p + sigma) = -p ||d||^(-p-2) d / (scale m)
        coef = -o.power * dist2 ** (-0.5 * o.power - 1.0) / (m * o.scale)
        return float(np.log(m).sum()), coef @ d

    def solve(self, lp: LinearParts, x0: np.ndarray, known: np.ndarray
              ) -> tuple[np.ndarray, int, float] | None:
        """Solution (x, iterations, max|r|) reached from ``x0`` avoiding the rows of ``known``,
        or None if Newton does not converge (compiled: :func:`kernels.deflated_newton`)."""
        hb = self.hbm
        if not hb.compiled:
            return self.solve_reference(lp, x0, known)
        x0 = np.array(x0, dtype=float)
        x = np.empty_like(x0)
        found, it, nr = kernels.deflated_newton(x0, self._rows(known, len(x0)), lp.lin,
                                                hb._aft_mats, hb._spring_arrays,
                                                float(hb.options.tol), self._defl, x)
        return (x, it, nr) if found else None

    def solve_first(self, lp: LinearParts, seeds: np.ndarray, known: np.ndarray, start: int = 0
                    ) -> tuple[int, np.ndarray, int, float] | None:
        """:meth:`solve` from the rows of ``seeds``, from row ``start`` on, in turn until one
        converges: (its row, x, iterations, max|r|), or None if none does (compiled: one call,
        :func:`kernels.deflated_newton_first`; the same values as :meth:`solve` row by row)."""
        hb = self.hbm
        seeds = np.ascontiguousarray(seeds, dtype=float)
        if not hb.compiled:
            for i in range(start, len(seeds)):
                sol = self.solve_reference(lp, seeds[i], known)
                if sol is not None:
                    return (i, *sol)
            return None
        n = seeds.shape[1]
        x = np.empty(n)
        i, it, nr = kernels.deflated_newton_first(seeds, int(start), self._rows(known, n), lp.lin,
                                                  hb._aft_mats, hb._spring_arrays,
                                                  float(hb.options.tol), self._defl, x)
        return None if i < 0 else (int(i), x, int(it), float(nr))

    def solve_reference(self, lp: LinearParts, x0: np.ndarray, known: np.ndarray
                        ) -> tuple[np.ndarray, int, float] | None:
        """:meth:`solve` in readable numpy (the compiled kernel's reference)."""
        hb, o = self.hbm, self.options
        tol = hb.options.tol
        x = np.array(x0, dtype=float)
        known = np.asarray(known, dtype=float).reshape(-1, len(x))
        r, J = hb.residual_and_jacobian_reference(x, lp)
        nr = float(np.abs(r).max())
        lm, g = self._log_m(x, known)
        best, since = nr, 0
        for it in range(1, o.max_iter + 1):
            if nr <= tol:
                return x, it - 1, nr
            if nr < 0.5 * best:
                best, since = nr, 0
            else:
                since += 1
                if since >= o.stagnation:
                    return None
            try:
                d = solve_small(J, -r)
            except np.linalg.LinAlgError:
                return None
            denom = 1.0 - float(g @ d)
            if abs(denom) > 1e-12:
                d = d / denom
            merit = np.log(max(nr, 1e-300)) + lm
            lam = 1.0
            while True:                 # backtracking on the deflated residual ln(M max|r|)
                xn = x + lam * d
                rn, Jn = hb.residual_and_jacobian_reference(xn, lp)
                nn = float(np.abs(rn).max())
                lmn, gn = self._log_m(xn, known)
                if np.log(max(nn, 1e-300)) + lmn < merit or lam <= o.min_step:
                    break
                lam *= 0.5
            if not np.isfinite(nn):
                return None
            x, r, J, nr, lm, g = xn, rn, Jn, nn, lmn, gn
        return (x, o.max_iter, nr) if nr <= tol else None
