"""The conservative condensed harmonic balance about one static point (doc/theory.md §10,
paper Fig. 14).

The conservative system is the driveline without damping and without excitation, held at the static
equilibrium of a mean torque (static wind-up ``w_s``). With ``x`` the DOF deviation from that
equilibrium and ``u = e.x`` the wind-up deviation:

    J x'' + K_lin x + e f(u) = 0,     K_lin = K + g'(w_s) e e^T,
    f(u) = g(w_s + u) - g(w_s) - g'(w_s) u                    (piecewise linear, f(0) = f'(0) = 0)

``g`` is the DMF's extra torque (dmf_sim.physics.spring). For the drive-side knee alone: with the
static point in the primary region (``w_s < theta``), ``K_lin`` has the primary stiffness and
``f(u) = b max(u - d, 0)`` (stiffening, knee at ``d = theta - w_s`` above); in the secondary
region ``K_lin`` has ``k(1+alpha)`` and ``f(u) = -b min(u + d, 0)`` (softening, knee at
``d = w_s - theta`` below). A coast knee, if configured, is one more ramp term of the same kind.

Harmonic balance condensed on the wind-up. The NNMs followed here are the synchronous (symmetric)
periodic orbits: all velocities vanish at t = 0, so every DOF is a cosine series in
``tau = Omega t``,

    u(tau) = sum_{n=0}^{H} a_n cos(n tau),     x(tau) = sum_n x_n cos(n tau).

This fixes the phase (time-shift invariance; stronger than "sine part of the 1st harmonic = 0").
Balancing harmonic n of the linear chain with the DMF force as a load gives ``x_n = -H_n e f_n``
with ``H_n = (K_lin - (n Omega)^2 J)^-1`` and, on the wind-up row, ``a_n = -h_n f_n`` with the
wind-up receptance ``h_n = e.H_n e = sum_k (e.phi_k)^2 / (omega_k^2 - (n Omega)^2)`` (modal sum
over the elastic modes of (K_lin, J); at n = 0 this is the static flexibility with the rigid mode
removed, as harmonic.solve_static). The residual is written in a form that stays finite at the
poles of h_n (the linear resonances, where the branch starts: a_1 is free and f_1 = 0):

    r_n = c_n a_n + s_n f_n / b,     (c_n, s_n) = sign * (1, b h_n) / sqrt(1 + (b h_n)^2),

with ``b`` the knee's stiffness jump and the sign of det(K_lin - (n Omega)^2 J) making (c_n, s_n)
continuous through the poles. The force harmonics f_n are exact Galerkin integrals, not sampled:
the knee crossings of u(tau) on the half period are located (grid + Newton on the trigonometric
polynomial) and ``f_n = (2/pi) int_{active} c (u - beta) cos(n tau) dtau`` is integrated in closed
form, with the exact Jacobian ``df_n/da_m = (2/pi) c int_{active} cos(m tau) cos(n tau) dtau``.
(hbm.py's AFT is a sampled FFT on a complex, forced, 720-degree layout; this autonomous cosine
problem has its own small version.) Unknowns: a_0..a_H plus Omega; the one-parameter family is
followed with continuation.py's pseudo-arc-length continuation, started on the linear mode exactly
at the knee (xi = 1, tangent along a_1) and stopped once xi exceeds ``xi_stop``. Where the branch
climbs a flat branch (below) beyond ``xi_stop``, the backbone is restarted on the far side of that
internal resonance (Newton at fixed Omega), and the tongue's far side is traced back up to
``xi_stop``; ``NNMBranch.segment`` numbers the pieces. Tongues narrower than a continuation step
are stepped over (``NNMOptions.step_max`` decides how thin a tongue is still resolved).

Energy (relative to the static equilibrium, evaluated at t = 0 where all velocities vanish):

    E = 1/2 x(0)^T K_lin x(0) + F(u(0)),   F' = f,
    x_n = (H_n e / h_n) a_n = -H_n e f_n   (the first form at resonance, the second near h_n = 0;
                                           evaluated as a least-squares blend, finite everywhere),

and ``xi = E / E_nl`` with ``E_nl = 1/2 omega_m^2 (d / e.phi_m)^2`` the energy of the linear mode m
(mass-normalized phi_m, mode of (K_lin, J)) whose wind-up amplitude just reaches the knee.

Scaling (paper, after eq. 19): ``f`` is positively homogeneous in (u, d), so every orbit scales
with d, E and E_nl with d^2; frequency against xi does not depend on theta nor on the static
point's distance to the knee (exactly, without a coast knee). :func:`scaling_check` confirms it
numerically.

Flat branches (paper: "close to a multiple of one of the linear resonances of the systems to the
rear and front of the non-linearity"): where n Omega meets a linear resonance with little DMF
motion, the branch runs into an internal-resonance tongue: the energy of harmonic n grows at almost
constant Omega. Such points are those where a harmonic n >= 2 carries more than ``tongue_share``
(25 %) of the kinetic energy; they are labelled with n and with the subsystem resonance (front or
rear of the DMF, each free at the DMF, DMF spring removed) nearest to n Omega. On the truck these
agree with n Omega to ~1 % (with the driveline's own resonance at K_lin to ~0.1 %); the natural
frequencies with the wind-up clamped (flywheels rigidly joined, the zeros of h) lie 1-7 % away and
are reported only for reference.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg

from dmf_sim.core.errors import ConfigError
from dmf_sim.physics.model import ReducedModel
from dmf_sim.solvers.continuation import (
    BranchHooks,
    BranchStart,
    ContinuationOptions,
    CorrectorFailed,
    continue_branch,
    correct,
)
from dmf_sim.solvers.nnm.ramp_force import RampForce
from dmf_sim.solvers.nnm.results import TWO_PI, NNMBranch, NNMOptions
from dmf_sim.solvers.nnm.subsystems import require_dmf
from dmf_sim.solvers.nnm.time_domain import energy_norm, integrate_chain

__all__ = ['ConservativeNNM']


class ConservativeNNM:
    """Condensed harmonic balance of the undamped, unforced driveline about a static wind-up.

    Args:
        model: merged driveline with a DMF.
        windup_static: static wind-up w_s [rad] (not on a knee).
        mode: linear mode (modal.modes index, 0 = rigid) the branch starts from (2: the DMF's
            second driveline mode, 18 Hz at primary stiffness).
        options: NNMOptions.
    """

    def __init__(self, model: ReducedModel, windup_static: float, mode: int = 2,
                 options: NNMOptions | None = None):
        require_dmf(model)
        self.model = model
        self.options = o = options or NNMOptions()
        sp = model.spring
        ws = float(windup_static)
        self.windup_static = ws
        self.region = sp.region(ws)
        # knees of the full spring: (position, slope jump right minus left)
        knees = zip(sp.knees, np.diff(sp.slopes))
        c, beta, side = [], [], []
        for wk, jump in knees:
            if jump == 0.0:
                continue
            if abs(wk - ws) < 1e-12 * max(1.0, abs(wk)):
                raise ConfigError(f'static wind-up {ws} rad lies on a knee: '
                                  'the linearization is undefined')
            if wk > ws:
                c.append(jump), beta.append(wk - ws), side.append(1.0)
            else:
                c.append(-jump), beta.append(wk - ws), side.append(-1.0)
        if not c:
            raise ConfigError('alpha = 0: the DMF spring is linear, '
                              'the normal modes are the linear ones')
        self.distance = float(min(abs(b) for b in beta))       # nearest knee
        self.b_ref = float(max(abs(x) for x in c))
        self.H = H = int(o.n_harmonics)
        if H < 1:
            raise ConfigError(f'n_harmonics={H}: must be >= 1')
        self.force = RampForce(c, beta, side, H, int(o.n_grid))
        # linearized stiffness and its modes
        self.K_lin = model.K + float(sp.extra_stiffness(ws)) * np.outer(model.e, model.e)
        w2, V = scipy.linalg.eigh(self.K_lin, model.J)
        scale = np.abs(w2).max()
        elastic = w2 > 1e-10 * scale
        if model.rigid_mode is not None and np.count_nonzero(~elastic) != 1:
            raise ConfigError('expected exactly one rigid-body mode')
        self.w2 = w2[elastic]
        self.phi = V[:, elastic]
        self.ephi = self.phi.T @ model.e
        self.cres = self.ephi ** 2
        if not 0 <= mode < len(w2):
            raise ConfigError(f'mode={mode}: allowed 0..{len(w2) - 1}')
        if not elastic[mode]:
            raise ConfigError(f'mode={mode} is the rigid-body mode')
        self.mode = int(mode)
        km = int(np.flatnonzero(elastic).tolist().index(mode))
        if abs(self.ephi[km]) < 1e-9 * np.abs(self.ephi).max():
            raise ConfigError(f'mode {mode} does not move the DMF: '
                              'it has no non-linear normal mode')
        self.omega_lin = float(np.sqrt(self.w2[km]))
        self.e_nl = 0.5 * self.w2[km] * (self.distance / self.ephi[km]) ** 2
        self._nn2 = np.arange(H + 1) ** 2

    # ---- linear parts per harmonic --------------------------------------------------------------
    def _modal(self, Omega: float):
        """Per harmonic: dominant pole k, delta = w_k^2 - lam, A = c_k + delta R, dA/dlam terms,
        sign."""
        lam = self._nn2 * Omega ** 2                                  # (H+1,)
        dw = self.w2[None, :] - lam[:, None]                          # (H+1, modes)
        with np.errstate(divide='ignore'):
            terms = np.where(dw == 0, np.inf, self.cres[None, :] / np.abs(dw))
        k = np.argmax(terms, axis=1)
        rows = np.arange(self.H + 1)
        delta = dw[rows, k]
        dw_o = dw.copy()
        dw_o[rows, k] = np.inf
        R = (self.cres[None, :] / dw_o).sum(axis=1)
        Rp = (self.cres[None, :] / dw_o ** 2).sum(axis=1)
        ck = self.cres[k]
        A = ck + delta * R
        below = (dw_o < 0).sum(axis=1)                                 # other poles below n Omega
        sig = np.where(below % 2 == 0, 1.0, -1.0)
        return lam, k, delta, A, ck, Rp, sig

    def _unit(self, Omega: float):
        """(c_n, s_n) and d psi_n / d Omega for all harmonics."""
        lam, k, delta, A, ck, Rp, sig = self._modal(Omega)
        b = self.b_ref
        norm = np.sqrt(delta ** 2 + (b * A) ** 2)
        c = sig * delta / norm
        s = sig * b * A / norm
        dpsi_dlam = b * (ck + delta ** 2 * Rp) / norm ** 2
        dpsi = dpsi_dlam * 2.0 * self._nn2 * Omega
        return c, s, dpsi

    # ---- residual -------------------------------------------------------------------------------
    def residual_and_jacobians(self, a: np.ndarray, Omega: float):
        """(r, dr/da, dr/dOmega) of the condensed balance; r in rad."""
        c, s, dpsi = self._unit(Omega)
        f, df = self.force.harmonics(a, jacobian=True)
        fb = f / self.b_ref
        r = c * a + s * fb
        Ja = np.diag(c) + (s / self.b_ref)[:, None] * df
        rO = dpsi * (-s * a + c * fb)
        return r, Ja, rO

    def residual(self, a: np.ndarray, Omega: float) -> np.ndarray:
        return self.residual_and_jacobians(a, Omega)[0]

    # ---- recovery -------------------------------------------------------------------------------
    def dof_harmonics(self, a: np.ndarray, Omega: float) -> np.ndarray:
        """(H+1, n_dof) cosine coefficients x_n of the DOF deviation [rad] (rigid part zero)."""
        lam, k, delta, A, ck, Rp, sig = self._modal(Omega)
        f = self.force.harmonics(a)
        b = self.b_ref
        # x_n = B_n X_n with B_n = phi_k e.phi_k + delta Y_rest and X_n = a_n / A_n =
        # -f_n / delta_n, combined in least squares so it is well-defined at poles (delta = 0) and
        # zeros (A = 0) of h.
        X = (A * a - (delta / b) * (f / b)) / (A ** 2 + (delta / b) ** 2)
        out = np.empty((self.H + 1, self.model.n_dof))
        for n in range(self.H + 1):
            dw = self.w2 - lam[n]
            dw_o = dw.copy()
            dw_o[k[n]] = np.inf
            Y_rest = self.phi @ (self.ephi / dw_o)
            B = self.phi[:, k[n]] * self.ephi[k[n]] + delta[n] * Y_rest
            out[n] = B * X[n]
        return out

    def initial_state(self, a: np.ndarray, Omega: float) -> tuple[np.ndarray, np.ndarray]:
        """DOF deviation x(0) [rad] and velocity (zero) [rad/s] from the static point at t = 0."""
        x0 = self.dof_harmonics(a, Omega).sum(axis=0)
        return x0, np.zeros_like(x0)

    def energy(self, a: np.ndarray, Omega: float) -> float:
        """Total energy [J] relative to the static equilibrium."""
        x0, _ = self.initial_state(a, Omega)
        return float(0.5 * x0 @ self.K_lin @ x0 + self.force.potential(np.sum(a)))

    def kinetic_shares(self, a: np.ndarray, Omega: float) -> np.ndarray:
        """Share of each harmonic in the time-averaged kinetic energy (sums to 1)."""
        xn = self.dof_harmonics(a, Omega)
        ke = (self._nn2 * Omega ** 2) * np.einsum('ni,ij,nj->n', xn, self.model.J, xn)
        tot = ke.sum()
        return ke / tot if tot > 0 else ke

    # ---- the branch -----------------------------------------------------------------------------
    def start(self) -> tuple[np.ndarray, float]:
        """The linear mode exactly at the knee: a_1 = d, Omega = omega_m (xi = 1)."""
        a = np.zeros(self.H + 1)
        a[1] = self.distance
        return a, self.omega_lin

    def _continue(self, a0, W0, tangent0, xi_stop):
        o = self.options
        d = self.distance
        copt = ContinuationOptions(s_scale=self.omega_lin, x_scale=d, step=o.step,
                                   step_min=o.step_min,
                                   step_max=o.step_max, grid=None, tol=o.tol * d, max_iter=15,
                                   easy_iter=4, max_turn=0.5, max_steps=o.max_steps)

        def stop(p, pts):
            return self.energy(p.x, p.s) / self.e_nl > xi_stop

        pts = continue_branch(self, BranchStart(a0, W0, (0.05 * self.omega_lin,
                                                         20.0 * self.omega_lin),
                                                tangent0=tangent0),
                              copt, BranchHooks(stop=stop))
        A = np.array([p.x for p in pts])
        W = np.array([p.s for p in pts])
        shares = np.array([self.kinetic_shares(x, w) for x, w in zip(A, W)])
        E = np.array([self.energy(x, w) for x, w in zip(A, W)])
        res = np.array([p.residual for p in pts])
        return A, W, E, shares, res

    def _jump(self, A, W, shares):
        """Past a tongue that rises above xi_stop: restart the backbone on the other side of the
        internal resonance by a Newton solve at fixed Omega (None if that fails)."""
        higher = shares[:, 2:].max(axis=1) if shares.shape[1] > 2 else np.zeros(len(W))
        back = np.flatnonzero(higher < 0.1)
        if not len(back):
            return None
        ib = back[-1]
        n = int(np.argmax(shares[-1, 2:])) + 2
        Wt, Wb = W[-1], W[ib]
        sign = 1.0 if Wt >= Wb else -1.0
        gap = max(abs(Wt - Wb), 1e-4 * Wt)
        d = self.distance
        ss, xs = self.omega_lin, d
        normal = np.zeros(self.H + 2)
        normal[-1] = 1.0
        for factor in (1.0, 2.0, 4.0, 8.0, 16.0):
            Wj = Wt + sign * factor * gap
            guess = A[ib].copy()
            guess[n] = -guess[n]
            y = np.concatenate([guess / xs, [Wj / ss]])
            try:
                y, _, _, _ = correct(self, y, normal, xs, ss, self.options.tol * d, 30)
            except CorrectorFailed:
                continue
            a = y[:-1] * xs
            sh = self.kinetic_shares(a, Wj)
            if sh[1] >= max(0.5, 1.0 - self.options.tongue_share):
                return a, Wj, sign
        return None

    def branch(self, xi_stop: float = 15.0, max_jumps: int = 50) -> NNMBranch:
        """Continue from the linear mode at the knee until xi > xi_stop (or the step limit).

        Where the branch runs into an internal-resonance tongue that rises above xi_stop, the
        tongue is kept up to xi_stop and the backbone is restarted beyond it (``segment`` counts
        the pieces)."""
        a0, W0 = self.start()
        t0 = np.zeros(self.H + 2)
        t0[1] = 1.0                                  # leave the linear segment: a_1 grows
        parts = []
        for seg in range(max_jumps + 1):
            A, W, E, shares, res = self._continue(a0, W0, t0, xi_stop)
            parts.append((A, W, E, shares, res, np.full(len(W), seg)))
            if E[-1] / self.e_nl <= xi_stop:
                break                                  # ended below xi_stop (step limit / failure)
            if shares.shape[1] <= 2 or shares[-1, 2:].max() <= self.options.tongue_share:
                break                                  # the backbone itself reached xi_stop
            nxt = self._jump(A, W, shares)
            if nxt is None:
                break
            a0, W0, sign = nxt
            # the tongue's far side: from the restart point back toward the resonance up to xi_stop
            tb = np.zeros(self.H + 2)
            tb[-1] = -sign
            Ab, Wb, Eb, sb, rb = self._continue(a0, W0, tb, xi_stop)
            if len(Wb) > 1:
                parts.append(tuple(z[:0:-1] for z in (Ab, Wb, Eb, sb, rb))
                             + (np.full(len(Wb) - 1, -1 - seg),))
            t0 = np.zeros(self.H + 2)
            t0[-1] = sign
        A, W, E, shares, res, segs = (np.concatenate(z) for z in zip(*parts))
        return NNMBranch(region=self.region, mode=self.mode, windup_static=self.windup_static,
                         distance=self.distance, linear_frequency_hz=self.omega_lin / TWO_PI,
                         e_nl=float(self.e_nl), xi=E / self.e_nl, frequency_hz=W / TWO_PI,
                         energy=E,
                         coefficients=A, shares=shares, residual=res, segment=segs,
                         tongue_share=self.options.tongue_share)

    # ---- time-domain verification ---------------------------------------------------------------
    def integrate(self, x0: np.ndarray, v0: np.ndarray, t_end: float, rtol: float = 1e-11
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Integrate J x'' + K_lin x + e f(e.x) = 0 from (x0, v0) over t_end [s] (see
        integrate_chain)."""
        return integrate_chain(self.model.J, self.K_lin, self.model.e, self.force.value,
                               self.force.beta,
                               np.zeros(self.model.n_dof), x0, v0, t_end, rtol=rtol)

    def periodicity_error(self, a: np.ndarray, Omega: float, period_factor: float = 1.0, **kw
                          ) -> float:
        """Start from the HBM solution's x(0), v(0) = 0, integrate one period 2 pi / Omega (times
        ``period_factor``) in time and return the energy norm of the state change relative to the
        orbit's energy: sqrt((dx.K_lin.dx + dv.J.dv) / (2 E))."""
        x0, v0 = self.initial_state(a, Omega)
        x1, v1 = self.integrate(x0, v0, period_factor * TWO_PI / Omega, **kw)
        return energy_norm(self.K_lin, self.model.J, x1 - x0, v1 - v0, self.energy(a, Omega))
