"""Exact Galerkin harmonics of a sum of ramp forces (the DMF spring about a static point) over a
cosine series: the non-linear force of the conservative NNM problem."""
from __future__ import annotations

import numpy as np

__all__ = ['RampForce']


class RampForce:
    """f(u) = sum_j c_j (u - beta_j) on {side_j (u - beta_j) > 0}: piecewise linear,
    f(0) = f'(0) = 0.

    Fourier coefficients of f(u(tau)) for u = sum a_n cos(n tau), exact over the half period."""

    def __init__(self, c, beta, side, H: int, n_grid: int):
        self.c = np.asarray(c, float)
        self.beta = np.asarray(beta, float)
        self.side = np.asarray(side, float)
        self.H = H
        self.tau = np.linspace(0.0, np.pi, n_grid + 1)
        n = np.arange(H + 1)
        self.n = n
        self.cos_grid = np.cos(np.outer(self.tau, n))           # (G, H+1)
        self.p = np.arange(-H, 2 * H + 1)                       # n - m and n + m
        self.i_minus = (n[:, None] - n[None, :]) + H
        self.i_plus = (n[:, None] + n[None, :]) + H
        self.weight = np.full(H + 1, 2.0 / np.pi)
        self.weight[0] = 1.0 / np.pi

    def value(self, u):
        u = np.asarray(u, float)
        out = np.zeros_like(u)
        for c, b, s in zip(self.c, self.beta, self.side):
            out = out + c * (u - b) * (s * (u - b) > 0)
        return out

    def potential(self, u):
        u = np.asarray(u, float)
        out = np.zeros_like(u)
        for c, b, s in zip(self.c, self.beta, self.side):
            out = out + 0.5 * c * (u - b) ** 2 * (s * (u - b) > 0)
        return out

    def _u(self, a, t):
        return np.cos(np.outer(t, self.n)) @ a, -(np.sin(np.outer(t, self.n)) * self.n) @ a

    def _roots(self, a, beta, lo, hi):
        """Roots of u(tau) = beta in the brackets [lo, hi] (vectorized safeguarded Newton)."""
        flo = self._u(a, lo)[0] - beta
        fhi = self._u(a, hi)[0] - beta
        # regula falsi start, then Newton with bisection fallback
        x = lo - flo * (hi - lo) / (fhi - flo)
        for _ in range(30):
            fx, dfx = self._u(a, x)
            fx = fx - beta
            left = np.sign(fx) == np.sign(flo)
            lo = np.where(left, x, lo)
            flo = np.where(left, fx, flo)
            hi = np.where(left, hi, x)
            with np.errstate(divide='ignore', invalid='ignore'):
                xn = x - fx / dfx
            bad = ~np.isfinite(xn) | (xn <= lo) | (xn >= hi)
            xn = np.where(bad, 0.5 * (lo + hi), xn)
            done = np.abs(xn - x) < 1e-15 * np.pi
            x = xn
            if np.all(done):
                break
        return x

    def harmonics(self, a, jacobian: bool = False):
        """f_n (H+1,) [Nm] (and df_n/da_m (H+1, H+1)) of f(u(tau))."""
        ug = self.cos_grid @ a
        D_lin = np.zeros(len(self.p))      # sum over active intervals of c [F_p]_a^b
        D_off = np.zeros(len(self.p))      # same, times beta
        for c, beta, s in zip(self.c, self.beta, self.side):
            v = s * (ug - beta)
            pos = v > 0
            if not pos.any():
                continue
            k = np.flatnonzero(pos[1:] != pos[:-1])
            roots = self._roots(a, beta, self.tau[k], self.tau[k + 1]) if len(k) else np.empty(0)
            # interval bounds: starts where pos switches on, ends where it switches off
            starts = list(roots[~pos[k]]) if len(k) else []
            ends = list(roots[pos[k]]) if len(k) else []
            if pos[0]:
                starts = [0.0] + starts
            if pos[-1]:
                ends = ends + [np.pi]
            ta, tb = np.array(starts), np.array(ends)
            P = self.p[None, :]
            with np.errstate(divide='ignore', invalid='ignore'):
                Fb = np.where(P == 0, tb[:, None], np.sin(P * tb[:, None]) / P)
                Fa = np.where(P == 0, ta[:, None], np.sin(P * ta[:, None]) / P)
            dF = (Fb - Fa).sum(axis=0)
            D_lin += c * dF
            D_off += c * beta * dF
        S = 0.5 * (D_lin[self.i_minus] + D_lin[self.i_plus])       # sum c int cos m cos n
        S0 = 0.5 * (D_off[self.i_minus[:, 0]] + D_off[self.i_plus[:, 0]])
        f = self.weight * (S @ a - S0)
        if not jacobian:
            return f
        return f, self.weight[:, None] * S
