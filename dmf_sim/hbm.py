"""Harmonic balance (HBM) of the DMF driveline, condensed onto the DMF wind-up (paper eq. 9-15).

Equation of motion in vibratory DOF coordinates q (model.py, eq. 7 merged):

    J q'' + C q' + K q + e g(e q) = P(psi),     P(psi) = Re( sum_n P_n exp(i n psi/2) )

with ``e`` the wind-up row (w = e q, positive when the engine drives) and ``g(w)`` the extra torque
of the DMF spring (dmf_sim.spring). The base frequency is omega/2: one 720 deg engine cycle, so
half-orders (the 1.5th order, n = 3) are representable. A periodic steady state is written

    w(psi) = Re( sum_{n=0}^{H} w_n exp(i n psi/2) ),   g(w(psi)) ~ Re( sum_{n=0}^{H} g_n exp(i n psi/2) )

(eq. 9: the non-linear torque tau of the paper is e g, truncated to the same H harmonics).

Condensation (the paper's split at the non-linear element, eq. 10-14). Balancing each harmonic of the
linear chain with the non-linear torque as an extra load (eq. 10-13) gives

    q_n = H_n (P_n - e g_n),        H_n = (K - Om_n^2 J + i Om_n C)^-1,   Om_n = n omega / 2

and the wind-up row of it (eq. 14) is one scalar equation per harmonic:

    r_n = w_n - wlin_n + h_n g_n(w_0..w_H) = 0,     wlin_n = e.H_n P_n,   h_n = e.H_n e    (eq. 15)

``wlin_n`` is the linear (alpha = 0) wind-up response and ``h_n`` the wind-up receptance of the
chain at the DMF. At n = 0 the free-free chain is singular: the static problem is solved with the
rigid mode removed (harmonic.solve_static), which is the paper's mean offset delta of eq. (14)
found from the mean torque. The Newton unknowns are only the 2H + 1 real numbers of the wind-up
harmonics, whatever the size of the driveline. h_n and wlin_n are computed once per speed — from
the chain's complex modes, computed once per model (exactly the direct n_dof x n_dof solves, see
``linear_parts_direct`` and the tests) — so a Newton iteration costs one alternating
frequency-time (AFT) pass: w(psi_j) on M samples of the cycle -> g(w(psi_j)) -> g_n, with the
analytic Jacobian dg_n/dw_m = (2/M) sum_j g'(w_j) exp(-i n phi_j) dw_j/dw_m.

All element responses are recovered afterwards: ``q_n = H_n (P_n - e g_n)``.

Speed sweeps (pseudo-arc-length continuation, turning points, coexisting solutions), Floquet
stability and the branch switching to the 1.5th-order (sub-harmonic) branches are in
:func:`sweep` below, built on ``continuation.py`` and ``stability.py``.

Real unknown layout used throughout: ``x = [w_0, Re w_1..Re w_H, Im w_1..Im w_H]`` [rad].
"""
from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from dmf_sim.errors import ConfigError, ConvergenceError
from dmf_sim.continuation import solve_small
from dmf_sim.harmonic import solve_harmonic, solve_static
from dmf_sim.loads import RPM_TO_RAD_S, DrivelineLoads
from dmf_sim.orders import OrderSummary, summarize_orders, synthesize
from dmf_sim.stability import FlexibleModes

SUB_HARMONICS = (3, 9, 15, 21)   # half-orders n = 3 mod 6: the 1.5th-order family (1.5, 4.5, 7.5, 10.5)


# ------------------------------------------------------------------------------------------------
# Real <-> complex harmonic vectors
# ------------------------------------------------------------------------------------------------

def to_complex(x: np.ndarray, H: int) -> np.ndarray:
    """(2H+1,) real unknowns -> (H+1,) complex w_n (w_0 real)."""
    c = np.empty(H + 1, dtype=complex)
    c[0] = x[0]
    c[1:] = x[1:H + 1] + 1j * x[H + 1:]
    return c


def to_real(c: np.ndarray, H: int) -> np.ndarray:
    """(H+1,) complex w_n -> (2H+1,) real unknowns (Im w_0 dropped)."""
    c = np.asarray(c)
    x = np.empty(2 * H + 1)
    x[0] = c[0].real
    x[1:H + 1] = c[1:H + 1].real
    x[H + 1:] = c[1:H + 1].imag
    return x


def _times_h(h: np.ndarray, v: np.ndarray, H: int) -> np.ndarray:
    """Complex product h_n * v_n written on the real layout; v is (2H+1,) or (2H+1, k)."""
    hr, hi = h.real[1:], h.imag[1:]
    if v.ndim == 2:
        hr, hi = hr[:, None], hi[:, None]
    out = np.empty_like(v)
    re, im = v[1:H + 1], v[H + 1:]
    out[0] = h[0].real * v[0]
    out[1:H + 1] = hr * re - hi * im
    out[H + 1:] = hr * im + hi * re
    return out


# ------------------------------------------------------------------------------------------------
# Options, linear parts, solution point
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class HBMOptions:
    """Numerical settings of the condensed harmonic balance.

    Attributes:
        n_harmonics: H, highest half-order index kept (24 = 12th engine order).
        n_time: M, AFT samples per 720 deg cycle (default: 8 (H+1) rounded up to a power of 2).
        tol: Newton tolerance on the residual's max norm [rad].
        max_iter: Newton iterations per solve.
        speed_fd_rpm: finite-difference step for the speed derivative of the engine load [rpm].
    """

    n_harmonics: int = 24
    n_time: int | None = None
    tol: float = 1e-10
    max_iter: int = 40
    speed_fd_rpm: float = 0.05

    def time_samples(self) -> int:
        if self.n_time is not None:
            return int(self.n_time)
        return 1 << int(math.ceil(math.log2(8 * (self.n_harmonics + 1))))


@dataclass
class LinearParts:
    """Everything the condensed equation needs at one speed (computed once per speed).

    Attributes:
        speed_rpm: engine speed.
        omega: crank speed [rad/s].
        P: (H+1, n_dof) complex generalized load harmonics [Nm].
        h: (H+1,) complex wind-up receptance e.H_n e [rad/Nm] (h_0 static, real).
        wlin: (H+1,) complex linear wind-up response e.H_n P_n [rad] (wlin_0: static mean).
        dh_ds, dwlin_ds: their derivatives with respect to speed [per rpm].
    """

    speed_rpm: float
    omega: float
    P: np.ndarray
    h: np.ndarray
    wlin: np.ndarray
    dh_ds: np.ndarray
    dwlin_ds: np.ndarray


@dataclass
class HBMPoint:
    """One periodic steady state of the wind-up (SI; speed in rpm).

    Attributes:
        speed_rpm: engine speed.
        x: (2H+1,) real unknowns [w_0, Re w_n, Im w_n] [rad].
        windup_orders: (H+1,) complex c_n of the wind-up, ``w = Re(sum c_n exp(i n psi/2))`` [rad]
            (same convention as newmark.SimulationResult.windup_orders).
        summary: OrderSummary (3rd and 1.5th order amplitude, max/min deviation, mean - theta).
        residual: max |r_n| at convergence [rad]; iterations: Newton iterations used.
        stable: Floquet stability (None until computed); multipliers: Floquet multipliers of the
            full linearized driveline over one 720 deg cycle (rigid-body pair excluded).
        branch: branch id in a sweep; kind: 'main', 'subharmonic' or 'harmonic'.
        tangent_speed: d(speed)/d(arc) of the continuation tangent (changes sign at a fold).
        forced_order_1_5: |wlin_3|, the linear (directly forced) 1.5th-order wind-up [rad].
    """

    speed_rpm: float
    x: np.ndarray
    windup_orders: np.ndarray
    summary: OrderSummary
    residual: float
    iterations: int
    stable: bool | None = None
    multipliers: np.ndarray | None = None
    max_multiplier: float = float('nan')
    branch: int = 0
    kind: str = 'main'
    tangent_speed: float = float('nan')
    forced_order_1_5: float = float('nan')

    @property
    def order_3(self) -> float:
        return self.summary.order_3

    @property
    def order_1_5(self) -> float:
        return self.summary.order_1_5

    def subharmonic_amplitude(self) -> float:
        """rms of the n = 3, 9, 15, 21 wind-up harmonics [rad] (zero on a 120-deg-periodic state)."""
        c = self.windup_orders
        return float(np.sqrt(np.sum(np.abs(c[[n for n in SUB_HARMONICS if n < len(c)]]) ** 2)))

    def as_dict(self) -> dict:
        d = {'speed_rpm': float(self.speed_rpm), 'branch': int(self.branch), 'kind': self.kind,
             'stable': None if self.stable is None else bool(self.stable)}
        d.update({k: v for k, v in self.summary.as_dict().items() if k != 'mean'})
        d['mean'] = float(self.summary.mean)
        d['max_multiplier'] = float(self.max_multiplier)
        d['forced_order_1_5'] = float(self.forced_order_1_5)
        return d


# ------------------------------------------------------------------------------------------------
# The condensed harmonic balance problem
# ------------------------------------------------------------------------------------------------

class CondensedHBM:
    """Harmonic balance of one driveline at one load fraction, condensed on the DMF wind-up.

    Args:
        loads: DrivelineLoads (merged model with a DMF + engine).
        load: engine load fraction 0..1.
        options: HBMOptions.
    """

    def __init__(self, loads: DrivelineLoads, load: float, options: HBMOptions | None = None):
        self.loads = loads
        self.load = float(load)
        self.options = options or HBMOptions()
        self.model = loads.model
        if self.model.spring is None:
            raise ConfigError(f'driveline {self.model.line.name!r} has no dmf section: nothing to condense on')
        self.spring = self.model.spring
        self.H = H = int(self.options.n_harmonics)
        if H < 1:
            raise ConfigError(f'n_harmonics={H}: must be >= 1')
        self.M = M = self.options.time_samples()
        if M < 2 * H + 2:
            raise ConfigError(f'n_time={M}: needs at least 2 (n_harmonics + 1) = {2 * H + 2} samples')
        # AFT matrices on the base angle phi_j = psi_j / 2 = 2 pi j / M (one 720 deg cycle):
        #   w_j = E x        (E = [1, cos n phi_j, -sin n phi_j])
        #   G   = F g_j      (F = W E^T: mean and 2/M-weighted Fourier sums)
        self.phi = 2.0 * np.pi * np.arange(M) / M
        n = np.arange(1, H + 1)
        self.E = np.hstack([np.ones((M, 1)), np.cos(np.outer(self.phi, n)), -np.sin(np.outer(self.phi, n))])
        weights = np.full(2 * H + 1, 2.0 / M)
        weights[0] = 1.0 / M
        self.F = weights[:, None] * self.E.T
        m = self.model
        # Static (n = 0) flexibility at the DMF, rigid mode removed: u_0 = K^+ e, h_0 = e.K^+ e.
        self._u0 = solve_static(m, m.e.astype(float))
        self._h0 = float(m.e @ self._u0)
        # Load assembly from one engine call per speed (same as DrivelineLoads.dof_harmonics).
        L = loads
        self._n_eng = min(int(L.n_max), H)
        self._phase = L.phase[:, :self._n_eng + 1]                            # (n_cyl, n+1), eq. (17)
        self._cyl_vec = L.cylinder_dof_vectors                                # (n_cyl, n_dof)
        self._rear_vec = L.rear_dof_vector
        R = m.R
        self._rear_factor = float(np.sum(R[L.rear_element] / R[L.cylinder_elements]))
        # Receptances of the flexible chain by its complex modes (computed once per model):
        # with the J-orthonormal flexible modes Phi, the first-order matrix A = [[0, I], [-Lam, -Cr]]
        # = V diag(d) V^-1, and for Om > 0
        #     e.H(Om) f = sum_k (e.Phi V_top)_k (V^-1_bottom Phi^T f)_k / (i Om - d_k).
        # The rigid-body part of H(Om) (-r r^T / (Om^2 r.J r)) does not reach the wind-up (e.r = 0).
        self.modes = FlexibleModes(m)
        d, V, Vinv = self.modes.eig(0.0)
        self._d = d
        self._ell = self.modes.er @ V[:self.modes.nf]                         # (2nf,)
        self._B = self.modes.Phi @ Vinv[:, self.modes.nf:].T                   # (n_dof, 2nf)
        self._a = self._ell * (self.modes.er @ Vinv[:, self.modes.nf:].T)      # residues of h
        self._cache: OrderedDict[float, LinearParts] = OrderedDict()
        self._eye = np.eye(2 * H + 1)

    # ---- loads and linear parts -------------------------------------------------------------
    def dof_loads(self, speed_rpm: float) -> np.ndarray:
        """(H+1, n_dof) complex generalized load harmonics P_n [Nm] (rows above the engine's n_max 0)."""
        A = np.asarray(self.loads.engine.coefficients(speed_rpm, self.load), dtype=complex)
        A = A[:self._n_eng + 1]
        P = np.zeros((self.H + 1, self.model.n_dof), dtype=complex)
        P[:self._n_eng + 1] = (A[None, :] * self._phase).T @ self._cyl_vec
        P[0] += -float(A[0].real) * self._rear_factor * self._rear_vec       # rear load, balanced
        return P

    def linear_parts(self, speed_rpm: float) -> LinearParts:
        """h_n, wlin_n and their speed derivatives at ``speed_rpm`` (a few most recent are cached)."""
        key = float(speed_rpm)
        lp = self._cache.get(key)
        if lp is not None:
            return lp
        H = self.H
        omega = key * RPM_TO_RAD_S
        P = self.dof_loads(key)
        # engine load derivative by a forward difference (backward at the top of the engine's range)
        ds = self.options.speed_fd_rpm
        if key + ds > self._speed_range()[1]:
            ds = -ds
        dP = (self.dof_loads(key + ds) - P) / ds
        Om = np.arange(1, H + 1) * (omega / 2.0)                 # Om_n = n omega / 2
        dOm = np.arange(1, H + 1) * (RPM_TO_RAD_S / 2.0)         # dOm_n / ds
        pole = 1.0 / (1j * Om[:, None] - self._d[None, :])       # (H, 2nf): 1 / (i Om_n - d_k)
        Q = P[1:] @ self._B                                      # modal load of each harmonic
        dQ = dP[1:] @ self._B
        h = np.empty(H + 1, dtype=complex)
        wlin = np.empty(H + 1, dtype=complex)
        dh = np.zeros(H + 1, dtype=complex)
        dw = np.empty(H + 1, dtype=complex)
        h[0] = self._h0                                          # static: e.K^+ e
        wlin[0] = self._u0 @ P[0].real                           # static: e.K^+ P_0 (rigid mode removed)
        dw[0] = self._u0 @ dP[0].real
        h[1:] = pole @ self._a
        wlin[1:] = (Q * pole) @ self._ell
        pole2 = -1j * pole ** 2                                   # d/dOm of the pole
        dh[1:] = (pole2 @ self._a) * dOm
        dw[1:] = (Q * pole2) @ self._ell * dOm + (dQ * pole) @ self._ell
        lp = LinearParts(key, omega, P, h, wlin, dh, dw)
        self._cache[key] = lp
        if len(self._cache) > 16:
            self._cache.popitem(last=False)
        return lp

    def linear_response(self, speeds_rpm) -> np.ndarray:
        """(K, H+1) complex linear wind-up harmonics wlin_n at K speeds at once (same modal
        receptances as :meth:`linear_parts`): the solution wherever the wind-up stays below the knee."""
        speeds = np.atleast_1d(np.asarray(speeds_rpm, dtype=float))
        P = np.stack([self.dof_loads(s) for s in speeds])                       # (K, H+1, n_dof)
        Om = np.outer(speeds * (RPM_TO_RAD_S / 2.0), np.arange(1, self.H + 1))  # (K, H)
        pole = 1.0 / (1j * Om[..., None] - self._d)                              # (K, H, 2nf)
        w = np.empty((len(speeds), self.H + 1), dtype=complex)
        w[:, 0] = P[:, 0].real @ self._u0
        w[:, 1:] = ((P[:, 1:] @ self._B) * pole) @ self._ell
        return w

    def time_series_batch(self, C: np.ndarray, n_samples: int = 1024) -> np.ndarray:
        """(K, n_samples) wind-up over one cycle for K complex harmonic vectors (K, H+1)."""
        return synthesize(C, n_samples)

    def static_windup(self, speed_rpm: float) -> float:
        """Wind-up [rad] the mean torque alone causes at ``speed_rpm`` (the non-linear static
        equilibrium; the paper's green line is theta minus it)."""
        lp = self.linear_parts(speed_rpm)
        return self.spring.solve_condensed(float(lp.wlin[0].real), float(lp.h[0].real))

    def linear_parts_direct(self, speed_rpm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(h, wlin, u, v) by direct complex solves Z_n [u_n, v_n] = [e, P_n] (harmonic.solve_harmonic);
        u_n = H_n e, v_n = H_n P_n are DOF vectors (H+1, n_dof). Used for recovery and as a check."""
        m = self.model
        P = self.dof_loads(speed_rpm)
        omega = float(speed_rpm) * RPM_TO_RAD_S
        u = np.empty((self.H + 1, m.n_dof), dtype=complex)
        v = np.empty((self.H + 1, m.n_dof), dtype=complex)
        u[0], v[0] = self._u0, solve_static(m, P[0].real)
        for n in range(1, self.H + 1):
            sol = solve_harmonic(m, n * omega / 2.0, np.stack([m.e.astype(complex), P[n]], axis=1))
            u[n], v[n] = sol[:, 0], sol[:, 1]
        return u @ m.e, v @ m.e, u, v

    def _speed_range(self) -> tuple[float, float]:
        rng = getattr(self.loads.engine, 'speed_range_rpm', None)
        return (float(rng[0]), float(rng[1])) if rng is not None else (-np.inf, np.inf)

    # ---- AFT: non-linear torque harmonics and their Jacobian ---------------------------------
    def windup_samples(self, x: np.ndarray) -> np.ndarray:
        """w(psi_j) on the M AFT samples of one cycle [rad]."""
        return self.E @ x

    def nonlinear_harmonics(self, x: np.ndarray, jacobian: bool = False):
        """G = harmonics of g(w(psi)) on the real layout [Nm] (and dG/dx [Nm/rad], None if zero).

        AFT: w_j = E x -> g(w_j) -> G = F g. Jacobian dG/dx = F diag(g'(w_j)) E, summed over the
        samples where g' != 0 only (the others contribute nothing).
        """
        w = self.E @ x
        sp = self.spring
        active = sp.region_index(w) != sp.primary_index
        if not active.any():
            G = np.zeros(2 * self.H + 1)
            return (G, None) if jacobian else G
        idx = np.flatnonzero(active)
        wa = w[idx]
        Fa = self.F[:, idx]
        G = Fa @ sp.extra_torque(wa)
        if not jacobian:
            return G
        return G, (Fa * sp.extra_stiffness(wa)) @ self.E[idx]

    # ---- residual (eq. 15) -------------------------------------------------------------------
    def residual(self, x: np.ndarray, lp: LinearParts) -> np.ndarray:
        """r = w - wlin + h g(w) on the real layout [rad]."""
        G = self.nonlinear_harmonics(x)
        return x - to_real(lp.wlin, self.H) + _times_h(lp.h, G, self.H)

    def residual_and_jacobian(self, x: np.ndarray, lp: LinearParts):
        """(r, dr/dx) with the analytic AFT Jacobian dr/dx = I + h dG/dx."""
        G, dG = self.nonlinear_harmonics(x, jacobian=True)
        if dG is None:                          # no sample beyond a knee: the linear problem
            return x - to_real(lp.wlin, self.H), self._eye.copy()
        r = x - to_real(lp.wlin, self.H) + _times_h(lp.h, G, self.H)
        Jx = _times_h(lp.h, dG, self.H)
        Jx[np.diag_indices_from(Jx)] += 1.0
        return r, Jx

    def residual_speed_derivative(self, x: np.ndarray, lp: LinearParts) -> np.ndarray:
        """dr/ds [rad/rpm] at fixed wind-up harmonics."""
        G = self.nonlinear_harmonics(x)
        return -to_real(lp.dwlin_ds, self.H) + _times_h(lp.dh_ds, G, self.H)

    # ---- solving at one speed ------------------------------------------------------------------
    def linear_solution(self, speed_rpm: float) -> np.ndarray:
        """x of the linear (primary stiffness, alpha = 0) response, the usual initial guess."""
        return to_real(self.linear_parts(speed_rpm).wlin, self.H)

    def solve(self, speed_rpm: float, x0: np.ndarray | None = None) -> HBMPoint:
        """Periodic steady state at ``speed_rpm`` by damped Newton from ``x0`` (default: the
        static mean plus the linear dynamic response)."""
        lp = self.linear_parts(speed_rpm)
        if x0 is None:
            x0 = self.linear_solution(speed_rpm)
            x0[0] = self.spring.solve_condensed(float(lp.wlin[0].real), float(lp.h[0].real))
        x, it, res = self.newton(x0, lp)
        return self.make_point(speed_rpm, x, res, it)

    def newton(self, x0: np.ndarray, lp: LinearParts) -> tuple[np.ndarray, int, float]:
        """Damped Newton on r(x) = 0 at fixed speed; returns (x, iterations, max|r|)."""
        x = np.array(x0, dtype=float)
        r, Jx = self.residual_and_jacobian(x, lp)
        nr = np.abs(r).max()
        for it in range(1, self.options.max_iter + 1):
            if nr <= self.options.tol:
                return x, it - 1, nr
            dx = solve_small(Jx, -r)
            lam = 1.0
            while True:   # backtracking on the max norm (the residual is only piecewise smooth)
                xn = x + lam * dx
                rn, Jn = self.residual_and_jacobian(xn, lp)
                nn = np.abs(rn).max()
                if nn < nr or lam < 1e-3:
                    break
                lam *= 0.5
            x, r, Jx, nr = xn, rn, Jn, nn
        if nr <= self.options.tol:
            return x, self.options.max_iter, nr
        raise ConvergenceError(f'HBM Newton: residual {nr:.2e} rad after {self.options.max_iter} iterations '
                               f'at {lp.speed_rpm:.1f} rpm')

    def make_point(self, speed_rpm: float, x: np.ndarray, residual: float = 0.0,
                   iterations: int = 0, samples: np.ndarray | None = None) -> HBMPoint:
        """Wrap a solution vector with its Fig. 13 summary (``samples``: w over the cycle, if at hand)."""
        c = to_complex(x, self.H)
        w = self.time_series(x, 1024) if samples is None else samples
        summ = summarize_orders(c, w, self.spring.theta, self.static_windup(speed_rpm))
        return HBMPoint(float(speed_rpm), np.array(x, dtype=float), c, summ, float(residual), int(iterations))

    # ---- recovery of the whole driveline ---------------------------------------------------------
    def time_series(self, x: np.ndarray, n_samples: int = 512) -> np.ndarray:
        """w(psi) on ``n_samples`` uniform points of one cycle (psi = 0 .. 4 pi) [rad]."""
        return synthesize(to_complex(x, self.H), n_samples)

    def dof_harmonics(self, point: HBMPoint) -> np.ndarray:
        """(H+1, n_dof) complex DOF harmonics q_n = H_n (P_n - e g_n) [rad] (eq. 10-13), by direct
        solves of the whole chain (rigid-body motion included for n >= 1, removed at n = 0)."""
        _, _, u, v = self.linear_parts_direct(point.speed_rpm)
        g = to_complex(self.nonlinear_harmonics(point.x), self.H)
        return v - u * g[:, None]

    def element_harmonics(self, point: HBMPoint) -> np.ndarray:
        """(H+1, m) complex element angle harmonics [rad] through the rigid constraints."""
        return self.dof_harmonics(point) @ self.model.T.T

    def torque_harmonics(self, point: HBMPoint) -> np.ndarray:
        """(H+1, m) complex harmonics of the torque transmitted into every element [Nm], positive
        when driving (ReducedModel.transmitted_torques in the frequency domain): flexible
        connections -(k + i Om c) dphi_n, plus g_n at the DMF; rigid connections from the element
        equation T_i = -Om^2 j_i phi_i - p_i + T_{i+1} / r_{i+1}."""
        m = self.model
        qn = self.dof_harmonics(point)
        Om = np.arange(self.H + 1) * (point.speed_rpm * RPM_TO_RAD_S / 2.0)
        out = np.zeros((self.H + 1, m.n_elements), dtype=complex)
        dphi = qn @ m.D.T
        out[:, m.spring_elements] = -(m.spring_k + 1j * Om[:, None] * m.spring_c) * dphi
        out[:, m.dmf_element] += to_complex(self.nonlinear_harmonics(point.x), self.H)
        p = np.zeros((self.H + 1, m.n_elements), dtype=complex)
        pe = self.loads.element_harmonics(point.speed_rpm, self.load)
        k = min(len(pe), self.H + 1)
        p[:k] = pe[:k]
        acc = -(Om ** 2)[:, None] * (qn @ m.T.T)
        els = m.line.elements
        for i in range(m.n_elements - 1, 0, -1):
            if els[i].rigid:
                nxt = out[:, i + 1] / els[i + 1].ratio if i + 1 < m.n_elements else 0.0
                out[:, i] = els[i].inertia * acc[:, i] - p[:, i] + nxt
        return out

    def dof_state(self, point: HBMPoint, psi: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """DOF angles q [rad] and velocities q' [rad/s] at crank angle psi (e.g. to start Newmark)."""
        qn = self.dof_harmonics(point)
        n = np.arange(self.H + 1)
        z = np.exp(1j * n * psi / 2.0)
        omega = point.speed_rpm * RPM_TO_RAD_S
        q = np.real(z @ qn)
        v = np.real((1j * n * omega / 2.0 * z) @ qn)
        return q, v

    # ---- interface for the continuation (continuation.ContinuationProblem) ------------------------
    def residual_and_jacobians(self, x: np.ndarray, speed_rpm: float):
        """(r, dr/dx, dr/ds) at wind-up harmonics x and speed [rpm]."""
        lp = self.linear_parts(speed_rpm)
        r, Jx = self.residual_and_jacobian(x, lp)
        return r, Jx, self.residual_speed_derivative(x, lp)

    # ---- cross-check by time integration -------------------------------------------------------
    def newmark_from(self, point: HBMPoint, *, perturb: np.ndarray | None = None, **kwargs):
        """Newmark steady state (newmark.simulate) started on this HBM solution's DOF state at
        psi = 0 (plus an optional DOF perturbation ``perturb`` [rad]); kwargs go to simulate
        (dt=1e-4 by default). On a stable solution it stays there; an unstable one is left."""
        from dmf_sim.newmark import simulate
        q, v = self.dof_state(point, 0.0)
        if perturb is not None:
            q = q + perturb
        kwargs.setdefault('dt', 1e-4)
        return simulate(self.loads, point.speed_rpm, self.load, initial=(q, v), **kwargs)


# ================================================================================================
# Speed sweep: continuation, stability, branch switching
# ================================================================================================

@dataclass
class Branch:
    """A solution branch over speed.

    Attributes:
        id: 0 for the branch traced from the lowest speed, then further ones in the order found.
        kind: 'main' (traced from a speed-range end: the forced response, which can itself carry a
            1.5th-order hump where the bifurcation is imperfect), 'subharmonic' (found by branch
            switching, with a 1.5th-order resonance) or 'harmonic' (found by branch switching,
            without one).
        points: HBMPoints in continuation order (speed may go back and forth at turning points).
        origin: how the branch was found.
    """

    id: int
    kind: str
    points: list[HBMPoint]
    origin: str = ''

    def column(self, name: str) -> np.ndarray:
        """One quantity of every point: a summary field, 'speed_rpm', 'stable' or 'max_multiplier'."""
        if name in ('speed_rpm', 'stable', 'max_multiplier'):
            return np.array([getattr(p, name) for p in self.points], dtype=float)
        return np.array([getattr(p.summary, name) for p in self.points], dtype=float)

    @property
    def speed_range(self) -> tuple[float, float]:
        s = self.column('speed_rpm')
        return float(s.min()), float(s.max())


@dataclass
class SweepEvent:
    """Something that happens along a branch: 'fold' (turning point: coexisting solutions beyond),
    'stability_loss' / 'stability_gain' (a Floquet multiplier crosses the unit circle; ``detail``
    says which kind), 'branch_switch' (a new branch seeded there)."""

    kind: str
    branch: int
    speed_rpm: float
    detail: str = ''

    def as_dict(self) -> dict:
        return {'kind': self.kind, 'branch': self.branch, 'speed_rpm': float(self.speed_rpm), 'detail': self.detail}


@dataclass
class SweepResult:
    """All branches of one sweep (one alpha, one load set, one load fraction)."""

    branches: list[Branch]
    events: list[SweepEvent]
    speed_range: tuple[float, float]
    load: float
    alpha: float
    theta: float
    label: str = ''
    seconds: float = 0.0
    n_harmonics: int = 24
    ratio_1_5: float = 3.0
    min_1_5: float = 2e-4
    hbm: 'CondensedHBM | None' = field(default=None, repr=False)
    floquet: object = field(default=None, repr=False)

    def rows(self) -> list[dict]:
        """One dict per computed point: speed_rpm, branch, kind, stable, order_3, order_1_5,
        max_deviation, min_deviation, mean_minus_theta (wind-up, rad), mean, max_multiplier."""
        out = []
        for b in self.branches:
            for p in b.points:
                d = p.as_dict()
                d['branch'], d['kind'] = b.id, b.kind
                out.append(d)
        return out

    @property
    def n_points(self) -> int:
        return sum(len(b.points) for b in self.branches)

    def main(self) -> Branch:
        return self.branches[0]

    def subharmonic_branches(self) -> list[Branch]:
        return [b for b in self.branches if b.kind == 'subharmonic']

    def solutions_at(self, speed_rpm: float) -> list[HBMPoint]:
        """Every solution on the branches at exactly ``speed_rpm`` (several where solutions
        coexist): for each stretch of a branch that brackets the speed, Newton at that speed from
        the interpolated branch, duplicates removed; with stability when the sweep had it."""
        s = float(speed_rpm)
        out: list[HBMPoint] = []
        for b in self.branches:
            for p, q in zip(b.points[:-1], b.points[1:]):
                a, c = p.speed_rpm, q.speed_rpm
                if not (min(a, c) <= s <= max(a, c)):
                    continue
                if abs(a - s) < 1e-9 or abs(c - s) < 1e-9:
                    sol = p if abs(a - s) < 1e-9 else q
                else:
                    f = (s - a) / (c - a)
                    try:
                        sol = self.hbm.solve(s, p.x + f * (q.x - p.x))
                    except ConvergenceError:
                        continue
                    sol.branch, sol.kind = b.id, b.kind
                    sol.forced_order_1_5 = float(abs(self.hbm.linear_parts(s).wlin[3]))
                    if self.floquet is not None:
                        fr = self.floquet.analyze(sol.windup_orders, s)
                        sol.stable, sol.multipliers, sol.max_multiplier = fr.stable, fr.multipliers, fr.max_abs
                if all(np.abs(sol.x - o.x).max() > 1e-6 + 1e-4 * np.abs(sol.x).max() for o in out):
                    out.append(sol)
        return out

    def subharmonic_summary(self) -> list[dict]:
        """Where the 1.5th order is a resonance, not just the directly forced response: per branch,
        each speed stretch where order_1_5 > ratio_1_5 x the linear forced level (and > min_1_5),
        with its peak amplitude and whether it is stable there."""
        out = []
        for b in self.branches:
            runs = _runs(b.points, lambda q: q.order_1_5 > max(self.ratio_1_5 * q.forced_order_1_5, self.min_1_5))
            for run in runs:
                s = np.array([q.speed_rpm for q in run])
                k = int(np.argmax([q.order_1_5 for q in run]))
                st = [q.speed_rpm for q in run if q.stable]
                out.append({'branch': b.id, 'branch_kind': b.kind,
                            'speed_min_rpm': float(s.min()), 'speed_max_rpm': float(s.max()),
                            'peak_order_1_5_rad': float(run[k].order_1_5), 'peak_speed_rpm': float(s[k]),
                            'order_3_at_peak_rad': float(run[k].order_3),
                            'peak_stable': None if run[k].stable is None else bool(run[k].stable),
                            'stable_speed_min_rpm': float(min(st)) if st else None,
                            'stable_speed_max_rpm': float(max(st)) if st else None,
                            'origin': b.origin})
        return out

    def as_dict(self) -> dict:
        return {'label': self.label, 'alpha': self.alpha, 'theta_rad': self.theta, 'load': self.load,
                'speed_range_rpm': list(self.speed_range), 'n_harmonics': self.n_harmonics,
                'seconds': self.seconds, 'n_points': self.n_points,
                'branches': [{'id': b.id, 'kind': b.kind, 'origin': b.origin, 'n_points': len(b.points),
                              'speed_range_rpm': list(b.speed_range)} for b in self.branches],
                'subharmonic': self.subharmonic_summary(),
                'events': [e.as_dict() for e in self.events], 'points': self.rows()}


@dataclass(frozen=True)
class SweepOptions:
    """What a sweep does besides following the main branch.

    Attributes:
        step_rpm: output grid (continuation lands on multiples of it where the branch runs along speed).
        stability: compute Floquet multipliers of every point.
        branch_switching: at a sub-harmonic loss of stability or a 1.5th-order hump, seed and
            follow the other 1.5th-order / 3rd-order branches (see SpeedSweep).
        isola_scan: if no bifurcation leads to one, also try n = 3 seeds where the main branch
            reaches within ``scan_margin`` x its peak-to-peak of the knee (a branch not connected to
            the main one), every ``scan_step_rpm``.
        newmark_seed: when Newton seeding fails, integrate in time from the perturbed unstable
            solution and start Newton from the attractor reached (slower).
        min_subharmonic: smallest 1.5th-order wind-up amplitude [rad] that counts as a
            1.5th-order response (besides exceeding ``ratio_1_5`` x the directly forced, linear
            1.5th-order wind-up at that speed).
        ratio_1_5: see min_subharmonic.
        max_branches: stop switching after this many extra branches.
    """

    step_rpm: float = 10.0
    stability: bool = True
    branch_switching: bool = True
    isola_scan: bool = True
    scan_step_rpm: float = 100.0
    scan_margin: float = 0.25
    newmark_seed: bool = False
    min_subharmonic: float = 2e-4
    ratio_1_5: float = 3.0
    max_branches: int = 6


class _Progress:
    """tqdm over covered speed (or nothing)."""

    def __init__(self, enabled, total: float, desc: str):
        self.bar = None
        if enabled:
            from tqdm import tqdm
            self.bar = tqdm(total=round(total), desc=desc, unit='rpm', leave=False)
        self.done = 0.0

    def advance(self, ds: float) -> None:
        if self.bar is not None:
            self.done += abs(ds)
            step = int(self.done) - self.bar.n
            if step > 0:
                self.bar.update(min(step, self.bar.total - self.bar.n))

    def note(self, text: str) -> None:
        if self.bar is not None:
            self.bar.set_postfix_str(text)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class SpeedSweep:
    """Continuation over engine speed with stability and branch switching (used by :func:`sweep`).

    Branch switching to the 1.5th-order (sub-harmonic) solutions. The excitation is almost
    120 deg periodic (orders 3, 6, 9 dominate the DMF), so the 3rd-order solution can lose
    stability by a period doubling of its 120 deg period: over the 720 deg base period a Floquet
    multiplier leaves the unit circle through +1 with an eigen-solution of half-orders n = 3 mod 6.
    The flexible crank lets the cylinders excite n = 3 directly a little, so the bifurcation is
    imperfect: either the branch traced from low speed itself turns into the 1.5th-order solution
    (a smooth hump of order_1_5, no loss of stability), or the 3rd-order branch loses stability
    and the 1.5th-order branch is separate. Seeds for Newton at one speed, each followed in both
    directions when it converges to a solution not yet on a branch:

    1. unstable stretch of a branch, sub-harmonic eigen-solution: the most unstable point plus
       +-a times the eigen-solution's n = 3, 9, 15, 21 wind-up harmonics;
    2. 1.5th-order hump on a branch: its peak with the n = 3 mod 6 harmonics reversed (the
       120 deg-shifted twin) or set back to the directly forced (linear) values (the 3rd-order
       solution beside it);
    3. if 1 and 2 find nothing: n = 3 seeds every ``scan_step_rpm`` where the main branch reaches
       near the knee (a branch not connected to it), and optionally Newmark from the perturbed
       unstable solution (``newmark_seed``).

    Args:
        hbm: CondensedHBM (driveline, engine, load fraction).
        options: SweepOptions; continuation: ContinuationOptions (grid set from step_rpm).
    """

    def __init__(self, hbm: CondensedHBM, options: SweepOptions | None = None, continuation=None):
        from dmf_sim.continuation import ContinuationOptions
        from dmf_sim.stability import FloquetAnalyzer
        self.hbm = hbm
        self.options = options or SweepOptions()
        base = continuation or ContinuationOptions()
        self.cont = ContinuationOptions(**{**base.__dict__, 'grid': self.options.step_rpm,
                                           's_scale': self.options.step_rpm, 'tol': hbm.options.tol})
        self.floquet = FloquetAnalyzer(hbm.model, modes=hbm.modes)
        self.events: list[SweepEvent] = []
        self.branches: list[Branch] = []
        self.range = (0.0, 0.0)

    # ---- one point -------------------------------------------------------------------------------
    def _point(self, x: np.ndarray, s: float, branch: int, kind: str, residual=0.0, iterations=0,
               tangent_speed=float('nan')) -> HBMPoint:
        w = self.hbm.time_series(x, self.floquet.n_fine)
        p = self.hbm.make_point(s, x, residual, iterations, samples=w)
        p.branch, p.kind, p.tangent_speed = branch, kind, float(tangent_speed)
        p.forced_order_1_5 = float(abs(self.hbm.linear_parts(s).wlin[3])) if self.hbm.H >= 3 else 0.0
        if self.options.stability:
            fr = self.floquet.analyze(p.windup_orders, p.speed_rpm, samples=w)
            p.stable, p.multipliers, p.max_multiplier = fr.stable, fr.multipliers, fr.max_abs
        return p

    def _trace(self, x0, s0, direction, branch, kind, bar, stop=None) -> list[HBMPoint]:
        from dmf_sim.continuation import continue_branch
        pts: list[HBMPoint] = []
        last = [s0]

        def on_point(cp):
            pre = getattr(cp, 'point', None)
            if pre is not None:
                pre.branch, pre.kind = branch, kind
                pts.append(pre)
            else:
                pts.append(self._point(cp.x, cp.s, branch, kind, cp.residual, cp.iterations, cp.tangent[-1]))
            bar.advance(cp.s - last[0])
            last[0] = cp.s

        continue_branch(self.hbm, x0, s0, self.range, direction, self.cont, stop=stop, on_point=on_point,
                        fast_forward=self._linear_stretch)
        return pts

    def _in_primary(self, w: np.ndarray) -> np.ndarray:
        """Rows of w (K, N) that stay strictly inside the primary region over the whole cycle."""
        lo, hi = self.hbm.spring.primary_bounds()
        return (w.max(axis=1) < hi) & (w.min(axis=1) > lo)

    def _linear_stretch(self, cp, sign: float) -> list:
        """Grid points ahead of ``cp`` where the wind-up never reaches a knee: there g = 0, the HBM
        solution is the linear response wlin (exact, no iteration) and the stability follows from
        the primary-stiffness eigenvalues. Checked in batches of growing size."""
        from dmf_sim.continuation import ContinuationPoint, _tangent
        hb, o = self.hbm, self.options
        here = hb.time_series(cp.x, self.floquet.n_fine)[None]
        if np.any(hb.nonlinear_harmonics(cp.x)) or not self._in_primary(here)[0]:
            return []
        lo, hi = self.range
        out: list = []
        s0, batch = cp.s, 4
        xs, ss = self.cont.x_scale, self.cont.s_scale
        while True:
            speeds = s0 + sign * o.step_rpm * np.arange(1, batch + 1)
            speeds = speeds[(speeds >= lo - 1e-9) & (speeds <= hi + 1e-9)]
            speeds = np.round(speeds / o.step_rpm) * o.step_rpm
            if len(speeds) == 0:
                break
            W = hb.linear_response(speeds)
            series = hb.time_series_batch(W, self.floquet.n_fine)
            ok = self._in_primary(series)
            k = len(ok) if ok.all() else int(np.argmin(ok))
            if k == 0:
                break
            mu = self.floquet.linear_multipliers(speeds[:k]) if o.stability else None
            for j in range(k):
                x = to_real(W[j], hb.H)
                p = hb.make_point(speeds[j], x, 0.0, 0, samples=series[j])
                p.forced_order_1_5 = float(abs(W[j, 3])) if hb.H >= 3 else 0.0
                if mu is not None:
                    m = mu[j][np.argsort(-np.abs(mu[j]))]
                    p.multipliers, p.max_multiplier = m, float(np.abs(m[0]))
                    p.stable = p.max_multiplier < 1.0 + self.floquet.tol
                q = ContinuationPoint(x, float(speeds[j]), np.zeros(len(x) + 1), 0, 0.0, True)
                q.point = p
                out.append(q)
            if k < len(ok) or len(speeds) < batch:
                break
            s0 = speeds[-1]
            batch = min(2 * batch, 32)
        # tangents: secant directions in scaled coordinates, the last one exact
        prev = np.concatenate([cp.x / xs, [cp.s / ss]])
        for q in out:
            y = np.concatenate([q.x / xs, [q.s / ss]])
            d = y - prev
            q.tangent = d / np.linalg.norm(d)
            q.point.tangent_speed = float(q.tangent[-1])
            prev = y
        if out:
            last = out[-1]
            r, Jx, rs = hb.residual_and_jacobians(last.x, last.s)
            last.tangent = _tangent(Jx, rs, last.tangent, xs, ss)
            last.point.tangent_speed = float(last.tangent[-1])
        return out

    # ---- the sweep -------------------------------------------------------------------------------
    def run(self, speed_range: tuple[float, float], progress=False, start_x: np.ndarray | None = None,
            desc: str = 'HBM sweep') -> SweepResult:
        import time
        t0 = time.perf_counter()
        lo, hi = float(speed_range[0]), float(speed_range[1])
        if not hi > lo:
            raise ConfigError(f'speed range [{lo}, {hi}] rpm: need TO > FROM')
        self.range = (lo, hi)
        bar = _Progress(progress, hi - lo, desc)
        try:
            first = self.hbm.solve(lo, start_x)
            pts = self._trace(first.x, lo, +1.0, 0, 'main', bar)
            self.branches = [Branch(0, 'main', pts, f'continuation from {lo:g} rpm')]
            self._events(self.branches[0])
            self._cover(bar)
            if self.options.stability and self.options.branch_switching:
                bar.note('branch switching')
                self._switch_branches(bar)
        finally:
            bar.close()
        sp = self.hbm.spring
        return SweepResult(self.branches, self.events, (lo, hi), self.hbm.load, sp.alpha, sp.theta,
                           seconds=time.perf_counter() - t0, n_harmonics=self.hbm.H,
                           ratio_1_5=self.options.ratio_1_5, min_1_5=self.options.min_subharmonic,
                           hbm=self.hbm, floquet=self.floquet if self.options.stability else None)

    def _uncovered(self) -> np.ndarray:
        """Grid speeds that no branch passes through (e.g. beyond a turning point where the branch
        from the lowest speed went back down)."""
        lo, hi = self.range
        step = self.options.step_rpm
        grid = np.arange(np.ceil(lo / step - 1e-9), np.floor(hi / step + 1e-9) + 1) * step
        grid = grid[(grid >= lo - 1e-9) & (grid <= hi + 1e-9)]
        covered = np.zeros(len(grid), dtype=bool)
        for b in self.branches:
            S = np.array([q.speed_rpm for q in b.points])
            for a, c in zip(S[:-1], S[1:]):
                covered |= (grid >= min(a, c) - 1e-6) & (grid <= max(a, c) + 1e-6)
            if len(S) == 1:
                covered |= np.abs(grid - S[0]) < 1e-6
        return grid[~covered]

    def _cover(self, bar) -> None:
        """Start further branches at speeds not reached yet (highest first), both directions."""
        for _ in range(3):
            todo = self._uncovered()
            if len(todo) == 0:
                return
            s0 = float(todo[-1])
            try:
                first = self.hbm.solve(s0)
            except ConvergenceError:
                return
            bid = len(self.branches)
            down = self._trace(first.x, s0, -1.0, bid, 'main', bar)
            up = self._trace(first.x, s0, +1.0, bid, 'main', bar) if s0 < self.range[1] - 1e-9 else down[:1]
            for q in down:
                q.tangent_speed = -q.tangent_speed
            b = Branch(bid, 'main', down[::-1] + up[1:],
                       f'continuation from {s0:g} rpm (speeds the branches before did not reach)')
            self.branches.append(b)
            self._events(b)

    # ---- events along a branch -------------------------------------------------------------------
    def _events(self, b: Branch) -> None:
        pts = b.points
        for a, c in zip(pts[:-1], pts[1:]):
            if a.tangent_speed * c.tangent_speed < 0:
                self.events.append(SweepEvent('fold', b.id, 0.5 * (a.speed_rpm + c.speed_rpm),
                                              'turning point: solutions coexist on one side'))
            if a.stable is not None and c.stable is not None and a.stable != c.stable:
                unstable = c if a.stable else a
                self.events.append(SweepEvent('stability_loss' if a.stable else 'stability_gain', b.id,
                                              0.5 * (a.speed_rpm + c.speed_rpm), self._instability_kind(unstable)))

    def _instability_kind(self, p: HBMPoint) -> str:
        mc = self.floquet.classify(p.windup_orders, p.speed_rpm)
        return (f'{mc.kind}: multiplier {mc.multiplier.real:+.3f}{mc.multiplier.imag:+.3f}j, '
                f'dominant half-order n={mc.dominant_n}, n=3 mod 6 share {mc.sub_harmonic_share:.2f}')

    # ---- is a solution already on a branch? --------------------------------------------------------
    def _amplitudes(self, x: np.ndarray) -> np.ndarray:
        """|w_n| (n = 0..H) of real-layout vectors x (..., 2H+1): the comparison ignores time
        shifts, so the 120 deg shifted twin of a 1.5th-order solution counts as the same branch
        (exactly so when the excitation is exactly 120 deg periodic)."""
        H = self.hbm.H
        amp = np.empty(x.shape[:-1] + (H + 1,))
        amp[..., 0] = np.abs(x[..., 0])
        amp[..., 1:] = np.hypot(x[..., 1:H + 1], x[..., H + 1:])
        return amp

    def _distance_to_branch(self, x: np.ndarray, s: float, b: Branch) -> float:
        """Smallest max | |w_n| - |w_n|_b(s) | [rad] over the stretches of branch b that bracket
        speed s (linear interpolation of the harmonic amplitudes between its points)."""
        S = np.array([q.speed_rpm for q in b.points])
        a0 = self._amplitudes(x)
        if len(S) == 1:
            return float(np.abs(a0 - self._amplitudes(b.points[0].x)).max()) if abs(S[0] - s) < 1e-9 else np.inf
        a, c = S[:-1], S[1:]
        idx = np.flatnonzero((np.minimum(a, c) - 1e-9 <= s) & (s <= np.maximum(a, c) + 1e-9))
        if len(idx) == 0:
            return np.inf
        X = self._amplitudes(np.array([b.points[i].x for i in idx]))
        Y = self._amplitudes(np.array([b.points[i + 1].x for i in idx]))
        den = c[idx] - a[idx]
        safe = np.where(np.abs(den) < 1e-12, 1.0, den)
        f = np.where(np.abs(den) < 1e-12, 0.0, (s - a[idx]) / safe)
        return float(np.abs(a0[None, :] - (X + f[:, None] * (Y - X))).max(axis=1).min())

    def _known(self, q: HBMPoint, tol: float) -> bool:
        return any(self._distance_to_branch(q.x, q.speed_rpm, b) < tol for b in self.branches)

    def _novelty_tol(self, q: HBMPoint) -> float:
        return max(0.1 * max(q.subharmonic_amplitude(), q.order_3), 5e-4)

    def _try(self, s: float, x0: np.ndarray) -> HBMPoint | None:
        try:
            q = self.hbm.solve(s, x0)
        except ConvergenceError:
            return None
        return None if self._known(q, self._novelty_tol(q)) else q

    # ---- seeds -------------------------------------------------------------------------------------
    def _sub_part(self, c: np.ndarray) -> np.ndarray:
        """Real-layout vector with only the n = 3, 9, 15, 21 harmonics of the complex ``c``."""
        out = np.zeros(self.hbm.H + 1, dtype=complex)
        for n in SUB_HARMONICS:
            if n <= self.hbm.H and n < len(c):
                out[n] = c[n]
        return to_real(out, self.hbm.H)

    def _eigen_seeds(self, p: HBMPoint) -> tuple[HBMPoint | None, str]:
        mc = self.floquet.classify(p.windup_orders, p.speed_rpm)
        if mc.kind != 'subharmonic':
            return None, ''
        d = self._sub_part(mc.coefficients)
        d /= max(np.abs(d).max(), 1e-300)
        scale = max(p.order_3, 1e-3)
        for a in (0.5, 1.0, 2.0, 4.0):
            for sign in (1.0, -1.0):
                q = self._try(p.speed_rpm, p.x + sign * a * scale * d)
                if q is not None:
                    return q, (f'branch switching at {p.speed_rpm:.1f} rpm: Newton from the unstable solution '
                               f'+ its sub-harmonic Floquet eigen-solution (multiplier {mc.multiplier.real:+.3f})')
        if self.options.newmark_seed:
            q = self._newmark_seed(p, d)
            if q is not None:
                return q, (f'branch switching at {p.speed_rpm:.1f} rpm: Newmark from the perturbed '
                           f'unstable solution, then Newton')
        return None, ''

    def _hump_seeds(self, p: HBMPoint) -> tuple[HBMPoint | None, str]:
        sub = self._sub_part(p.windup_orders)
        forced = self._sub_part(self.hbm.linear_parts(p.speed_rpm).wlin)
        for how, x0 in (('n = 3 mod 6 harmonics reversed (120 deg shifted twin)', p.x - 2.0 * sub),
                        ('n = 3 mod 6 harmonics set to the forced response', p.x - sub + forced)):
            q = self._try(p.speed_rpm, x0)
            if q is not None:
                return q, f'branch switching at {p.speed_rpm:.1f} rpm from the 1.5th-order hump: {how}'
        return None, ''

    def _newmark_seed(self, p: HBMPoint, direction: np.ndarray) -> HBMPoint | None:
        """Time integration from the perturbed (unstable) solution, then Newton from the attractor."""
        H = self.hbm.H
        _, _, u, _ = self.hbm.linear_parts_direct(p.speed_rpm)
        c = to_complex(direction, H)
        e = self.hbm.model.e
        # DOF perturbation: the chain's response shape to a DMF torque of each sub-harmonic
        dq = np.real(sum(c[n] / (e @ u[n]) * u[n] for n in SUB_HARMONICS if n <= H and c[n] != 0))
        dq *= 0.5 * max(p.order_3, 1e-3) / max(np.abs(e @ dq), 1e-12)
        res = self.hbm.newmark_from(p, perturb=dq, max_cycles=300)
        if res.windup_orders is None:
            return None
        return self._try(p.speed_rpm, to_real(res.windup_orders[:H + 1], H))

    # ---- following a new branch ----------------------------------------------------------------------
    def _follow(self, seed: HBMPoint, origin: str, bar) -> Branch:
        bid = len(self.branches)
        x_start, s_start = seed.x.copy(), seed.speed_rpm
        others = list(self.branches)

        def stop(cp, cps):
            if len(cps) < 3:
                return False
            tol = max(0.02 * np.abs(cp.x[1:]).max(), 1e-4)
            if any(self._distance_to_branch(cp.x, cp.s, b) < tol for b in others):
                return True       # arrived on a known branch (a turning or bifurcation point)
            if len(cps) > 8 and abs(cp.s - s_start) < 0.5 * self.options.step_rpm and \
                    np.abs(cp.x - x_start).max() < 0.05 * max(np.abs(x_start[1:]).max(), 1e-6):
                return True       # closed loop (an isolated branch): back at the start
            return False

        closed = [False]

        def stop_mark(cp, cps):
            res = stop(cp, cps)
            if res and len(cps) > 8 and abs(cp.s - s_start) < 0.5 * self.options.step_rpm and \
                    np.abs(cp.x - x_start).max() < 0.05 * max(np.abs(x_start[1:]).max(), 1e-6):
                closed[0] = True
            return res

        up = self._trace(seed.x, s_start, +1.0, bid, 'subharmonic', bar, stop_mark)
        if closed[0]:
            # an isolated closed branch: one direction went all the way round; start the list at
            # its lowest speed so stretches are contiguous
            loop = up[:-1]
            k = int(np.argmin([q.speed_rpm for q in loop]))
            pts = loop[k:] + loop[:k + 1]
            origin += ' (closed branch)'
        else:
            down = self._trace(seed.x, s_start, -1.0, bid, 'subharmonic', bar, stop)
            for q in down:                     # reversed list: the arc parameter runs the other way
                q.tangent_speed = -q.tangent_speed
            pts = down[::-1] + up[1:]
        kind = 'subharmonic' if self._humps(pts) else 'harmonic'
        for q in pts:
            q.kind = kind
        b = Branch(bid, kind, pts, origin)
        self.branches.append(b)
        self.events.append(SweepEvent('branch_switch', bid, s_start, origin))
        self._events(b)
        return b

    def _humps(self, pts: list[HBMPoint]) -> list[list[HBMPoint]]:
        """Stretches where the 1.5th order clearly exceeds its directly forced (linear) level."""
        o = self.options
        return _runs(pts, lambda q: q.order_1_5 > max(o.ratio_1_5 * q.forced_order_1_5,
                                                      o.min_subharmonic))

    def _switch_branches(self, bar) -> None:
        o = self.options
        queue = [self.branches[0]]
        while queue and len(self.branches) <= o.max_branches:
            b = queue.pop(0)
            seeds = []
            for run in _runs(b.points, lambda q: q.stable is False):
                seeds.append(('eigen', max(run, key=lambda q: q.max_multiplier)))
            for run in self._humps(b.points):
                peak = max(run, key=lambda q: q.order_1_5 / max(q.forced_order_1_5, 1e-12))
                seeds.append(('hump', peak))
                if len(run) >= 4:
                    seeds += [('hump', run[len(run) // 4]), ('hump', run[(3 * len(run)) // 4])]
            for kind, p in seeds:
                if len(self.branches) > o.max_branches:
                    break
                q, how = (self._eigen_seeds(p) if kind == 'eigen' else self._hump_seeds(p))
                if q is not None and not self._known(q, self._novelty_tol(q)):
                    queue.append(self._follow(q, how, bar))
        if o.isola_scan and len(self.branches) == 1 and not self._humps(self.branches[0].points):
            self._scan(bar)

    def _scan(self, bar) -> None:
        """Seed n = 3 perturbations where the main branch comes near the knee (isolated branches)."""
        o = self.options
        theta = self.hbm.spring.theta
        H = self.hbm.H
        last = -np.inf
        for p in list(self.branches[0].points):
            if len(self.branches) > o.max_branches:
                break
            sm = p.summary
            ptp = sm.max_deviation - sm.min_deviation
            if sm.mean + sm.max_deviation < theta - o.scan_margin * ptp:
                continue
            if p.speed_rpm - last < o.scan_step_rpm - 1e-6 or not _on_grid(p.speed_rpm, o.step_rpm):
                continue
            last = p.speed_rpm
            scale = max(p.order_3, 1e-3)
            found = None
            for phase in (0.0, 0.5 * np.pi, np.pi, 1.5 * np.pi):
                c = np.zeros(H + 1, dtype=complex)
                c[3] = 2.0 * scale * np.exp(1j * phase)
                q = self._try(p.speed_rpm, p.x + to_real(c, H))
                if q is not None and q.subharmonic_amplitude() > max(o.ratio_1_5 * p.subharmonic_amplitude(),
                                                                     o.min_subharmonic):
                    found = q
                    break
            if found is not None:
                self._follow(found, f'n = 3 seed at {p.speed_rpm:.0f} rpm (search for a branch not '
                                    'connected to the main one)', bar)


def _runs(items, pred) -> list[list]:
    """Maximal consecutive runs of items satisfying pred."""
    runs, cur = [], []
    for q in items:
        if pred(q):
            cur.append(q)
        elif cur:
            runs.append(cur)
            cur = []
    if cur:
        runs.append(cur)
    return runs


def _on_grid(s: float, grid: float) -> bool:
    k = round(s / grid)
    return abs(s - k * grid) < 1e-6


def sweep(loads: DrivelineLoads, load: float, speed_range: tuple[float, float] = (600.0, 2000.0), *,
          hbm_options: HBMOptions | None = None, options: SweepOptions | None = None,
          continuation=None, progress=False, label: str = '') -> SweepResult:
    """Steady-state wind-up over engine speed by condensed HBM + pseudo-arc-length continuation.

    Follows the branch from the lowest speed (turning points included), computes the Floquet
    stability of every point, and switches to 1.5th-order branches where the 3rd-order solution
    loses stability to a sub-harmonic (or, failing that, seeds n = 3 perturbations near the knee).

    Args:
        loads: DrivelineLoads (driveline with DMF + engine); load: load fraction 0..1.
        speed_range: (from, to) [rpm].
        hbm_options, options, continuation: HBMOptions, SweepOptions, ContinuationOptions.
        progress: show a tqdm bar.
        label: free text stored in the result (e.g. 'alpha=3 Load A').
    """
    hb = CondensedHBM(loads, load, hbm_options)
    res = SpeedSweep(hb, options, continuation).run(speed_range, progress=progress, desc=label or 'HBM sweep')
    res.label = label
    return res
