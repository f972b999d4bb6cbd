"""Non-linear normal modes (NNMs) of the conservative DMF driveline (design.md §3, paper Fig. 14).

The conservative system is the driveline without damping and without excitation, held at the static
equilibrium of a mean torque (static wind-up ``w_s``). With ``x`` the DOF deviation from that
equilibrium and ``u = e.x`` the wind-up deviation:

    J x'' + K_lin x + e f(u) = 0,     K_lin = K + g'(w_s) e e^T,
    f(u) = g(w_s + u) - g(w_s) - g'(w_s) u                         (piecewise linear, f(0) = f'(0) = 0)

``g`` is the DMF's extra torque (dmf_sim.spring). For the drive-side knee alone: with the static point
in the primary region (``w_s < theta``), ``K_lin`` has the primary stiffness and ``f(u) = b max(u - d, 0)``
(stiffening, knee at ``d = theta - w_s`` above); in the secondary region ``K_lin`` has ``k(1+alpha)`` and
``f(u) = -b min(u + d, 0)`` (softening, knee at ``d = w_s - theta`` below). A coast knee, if
configured, is one more ramp term of the same kind.

Harmonic balance condensed on the wind-up. The NNMs followed here are the synchronous (symmetric)
periodic orbits: all velocities vanish at t = 0, so every DOF is a cosine series in ``tau = Omega t``,

    u(tau) = sum_{n=0}^{H} a_n cos(n tau),     x(tau) = sum_n x_n cos(n tau).

This fixes the phase (time-shift invariance; stronger than "sine part of the 1st harmonic = 0").
Balancing harmonic n of the linear chain with the DMF force as a load gives ``x_n = -H_n e f_n`` with
``H_n = (K_lin - (n Omega)^2 J)^-1`` and, on the wind-up row, ``a_n = -h_n f_n`` with the wind-up
receptance ``h_n = e.H_n e = sum_k (e.phi_k)^2 / (omega_k^2 - (n Omega)^2)`` (modal sum over the elastic
modes of (K_lin, J); at n = 0 this is the static flexibility with the rigid mode removed, as
harmonic.solve_static). The residual is written in a form that stays finite at the poles of h_n
(the linear resonances, where the branch starts: a_1 is free and f_1 = 0):

    r_n = c_n a_n + s_n f_n / b,     (c_n, s_n) = sign * (1, b h_n) / sqrt(1 + (b h_n)^2),

with ``b`` the knee's stiffness jump and the sign of det(K_lin - (n Omega)^2 J) making (c_n, s_n)
continuous through the poles. The force harmonics f_n are exact Galerkin integrals, not sampled:
the knee crossings of u(tau) on the half period are located (grid + Newton on the trigonometric
polynomial) and ``f_n = (2/pi) int_{active} c (u - beta) cos(n tau) dtau`` is integrated in closed form,
with the exact Jacobian ``df_n/da_m = (2/pi) c int_{active} cos(m tau) cos(n tau) dtau``. (hbm.py's AFT
is a sampled FFT on a complex, forced, 720-degree layout; this autonomous cosine problem has its own
small version.) Unknowns: a_0..a_H plus Omega; the one-parameter family is followed with
continuation.py's pseudo-arc-length continuation, started on the linear mode exactly at the knee
(xi = 1, tangent along a_1) and stopped once xi exceeds ``xi_stop``. Where the branch climbs a flat
branch (below) beyond ``xi_stop``, the backbone is restarted on the far side of that internal
resonance (Newton at fixed Omega), and the tongue's far side is traced back up to ``xi_stop``;
``NNMBranch.segment`` numbers the pieces. Tongues narrower than a continuation step are stepped over
(``NNMOptions.step_max`` decides how thin a tongue is still resolved).

Energy (relative to the static equilibrium, evaluated at t = 0 where all velocities vanish):

    E = 1/2 x(0)^T K_lin x(0) + F(u(0)),   F' = f,
    x_n = (H_n e / h_n) a_n = -H_n e f_n   (the first form at resonance, the second near h_n = 0;
                                           evaluated as a least-squares blend, finite everywhere),

and ``xi = E / E_nl`` with ``E_nl = 1/2 omega_m^2 (d / e.phi_m)^2`` the energy of the linear mode m
(mass-normalized phi_m, mode of (K_lin, J)) whose wind-up amplitude just reaches the knee.

Scaling (paper, after eq. 19): ``f`` is positively homogeneous in (u, d), so every orbit scales with d,
E and E_nl with d^2; frequency against xi does not depend on theta nor on the static point's distance
to the knee (exactly, without a coast knee). :func:`scaling_check` confirms it numerically.

Flat branches (paper: "close to a multiple of one of the linear resonances of the systems to the rear
and front of the non-linearity"): where n Omega meets a linear resonance with little DMF motion, the
branch runs into an internal-resonance tongue: the energy of harmonic n grows at almost constant
Omega. Such points are those where a harmonic n >= 2 carries more than ``tongue_share`` (25 %) of the
kinetic energy; they are labelled with n and with the subsystem resonance (front or rear of the DMF,
each free at the DMF, DMF spring removed) nearest to n Omega. On the truck these agree with n Omega
to ~1 % (with the driveline's own resonance at K_lin to ~0.1 %); the natural frequencies with the
wind-up clamped (flywheels rigidly joined, the zeros of h) lie 1-7 % away and are reported only for
reference.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
from scipy.integrate import solve_ivp
from scipy.sparse.csgraph import connected_components

from dmf_sim.errors import ConfigError
from dmf_sim.continuation import ContinuationOptions, CorrectorFailed, continue_branch, correct
from dmf_sim.harmonic import solve_static
from dmf_sim.modal import stiffness_matrix
from dmf_sim.model import ReducedModel

REGIONS = ('primary', 'secondary')
TWO_PI = 2.0 * np.pi


# ------------------------------------------------------------------------------------------------
# Options and results
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class NNMOptions:
    """Numerical settings.

    Attributes:
        n_harmonics: H, highest harmonic of the base frequency kept.
        n_grid: grid intervals on the half period used to bracket the knee crossings.
        tol: corrector tolerance on max|r| relative to the knee distance d.
        step, step_min, step_max: arc-length steps (unknowns scaled by d, Omega by the linear mode).
        max_steps: safety limit of continuation steps per branch.
        xi_stop: continuation stops once xi exceeds this (default: 1.5 * xi_max of the caller).
        tongue_share: a point is on a flat branch (tongue) when one harmonic n >= 2 carries more
            than this share of the time-averaged kinetic energy; it is on the backbone when the
            fundamental carries at least 1 - tongue_share.
    """

    n_harmonics: int = 20
    n_grid: int = 1024
    tol: float = 1e-11
    step: float = 0.02
    step_min: float = 1e-6
    step_max: float = 0.02
    max_steps: int = 4000
    xi_stop: float | None = None
    tongue_share: float = 0.25


@dataclass
class NNMBranch:
    """One NNM branch, points ordered along the continuation (arc length).

    Attributes:
        region: 'primary' or 'secondary': where the static wind-up lies.
        mode: index of the linear mode the branch starts from (modal.modes order, 0 = rigid).
        windup_static: static wind-up w_s [rad]; distance: |theta - w_s| [rad].
        linear_frequency_hz: the start mode's frequency at K_lin [Hz]; e_nl: E_nl [J].
        xi: (p,) E / E_nl; frequency_hz: (p,) base frequency Omega / 2 pi [Hz]; energy: (p,) E [J].
        coefficients: (p, H+1) wind-up deviation cosine coefficients a_n [rad].
        shares: (p, H+1) share of each harmonic in the time-averaged kinetic energy.
        residual: (p,) max|r| at convergence [rad].
        segment: (p,) continuation piece: 0, 1, ... along the backbone (a new piece starts past a
            tongue cut at xi_stop); -1 - k: the far side of the tongue that ended piece k, traced
            from the restart point back up to xi_stop (reversed, so it runs down into piece k + 1).
    """

    region: str
    mode: int
    windup_static: float
    distance: float
    linear_frequency_hz: float
    e_nl: float
    xi: np.ndarray
    frequency_hz: np.ndarray
    energy: np.ndarray
    coefficients: np.ndarray
    shares: np.ndarray
    residual: np.ndarray
    segment: np.ndarray
    tongue_share: float = 0.25

    @property
    def dominant_harmonic(self) -> np.ndarray:
        """(p,) harmonic carrying most kinetic energy (1 on the backbone)."""
        return self.shares.argmax(axis=1)

    @property
    def tongue_harmonic(self) -> np.ndarray:
        """(p,) harmonic n >= 2 with the largest kinetic-energy share, or 0 where no harmonic
        n >= 2 carries more than ``tongue_share`` (the point is not on a flat branch)."""
        if self.shares.shape[1] <= 2:
            return np.zeros(len(self.xi), int)
        n = self.shares[:, 2:].argmax(axis=1) + 2
        return np.where(self.shares[np.arange(len(n)), n] > self.tongue_share, n, 0)

    @property
    def backbone(self) -> np.ndarray:
        """Boolean mask of the backbone points: the fundamental carries most of the kinetic
        energy (near a flat branch a point can be both: the branch bends into the tongue)."""
        return self.shares[:, 1] >= 0.5

    def frequency_at(self, xi) -> np.ndarray:
        """Backbone frequency [Hz] at the given xi: linear interpolation at the first crossing of
        xi on the backbone (near a flat branch the backbone is two-valued: the crossing where the
        fundamental's kinetic-energy share is largest wins). NaN where xi is not reached."""
        xi = np.atleast_1d(np.asarray(xi, float))
        out = np.full(xi.shape, np.nan)
        ok = self.backbone & (self.segment >= 0)
        pair = ok[:-1] & ok[1:] & (self.segment[:-1] == self.segment[1:])
        x0, x1 = self.xi[:-1], self.xi[1:]
        f0, f1 = self.frequency_hz[:-1], self.frequency_hz[1:]
        for j, v in enumerate(xi):
            tol = 1e-9 * max(abs(v), 1.0)
            hit = np.flatnonzero(pair & (np.minimum(x0, x1) <= v + tol) & (np.maximum(x0, x1) >= v - tol))
            if len(hit):
                purity = np.minimum(self.shares[hit, 1], self.shares[hit + 1, 1])
                i = hit[int(np.argmax(purity))]
                w = 0.0 if x1[i] == x0[i] else min(max((v - x0[i]) / (x1[i] - x0[i]), 0.0), 1.0)
                out[j] = f0[i] + w * (f1[i] - f0[i])
        return out

@dataclass
class FlatBranch:
    """A flat branch (internal-resonance tongue) of an NNM branch."""

    region: str
    harmonic: int                 # n: n * base frequency ~ subsystem resonance (the figure's label)
    frequency_hz: float           # base frequency on the tongue (median) [Hz]
    xi_min: float
    xi_max: float
    subsystem: str                # 'front' or 'rear' of the DMF
    subsystem_frequency_hz: float
    resonance_hz: float           # nearest linear resonance of the whole driveline at K_lin
    clamped_frequency_hz: float   # nearest natural frequency with the DMF wind-up clamped

    def as_dict(self) -> dict:
        return {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in self.__dict__.items()}


@dataclass
class NNMResult:
    """Both branches of one NNM family (paper Fig. 14) and the reference frequencies."""

    driveline: str
    alpha: float
    theta: float
    mode: int
    branches: dict[str, NNMBranch]
    linear_frequencies_hz: dict[str, np.ndarray]
    subsystem_frequencies_hz: dict[str, np.ndarray]
    clamped_frequencies_hz: np.ndarray
    flat_branches: list[FlatBranch] = field(default_factory=list)
    n_harmonics: int = 0

    def as_dict(self, xi_max: float | None = None) -> dict:
        out = {
            'driveline': self.driveline, 'alpha': self.alpha, 'theta_rad': self.theta, 'mode': self.mode,
            'n_harmonics': self.n_harmonics,
            'linear_frequencies_hz': {r: [float(f) for f in v] for r, v in self.linear_frequencies_hz.items()},
            'subsystem_frequencies_hz': {r: [float(f) for f in v] for r, v in self.subsystem_frequencies_hz.items()},
            'clamped_frequencies_hz': [float(f) for f in self.clamped_frequencies_hz],
            'flat_branches': [fb.as_dict() for fb in self.flat_branches],
            'branches': {},
        }
        for name, br in self.branches.items():
            m = np.ones(len(br.xi), bool) if xi_max is None else br.xi <= xi_max
            out['branches'][name] = {
                'region': br.region, 'windup_static_rad': br.windup_static, 'distance_rad': br.distance,
                'linear_frequency_hz': br.linear_frequency_hz, 'e_nl_J': br.e_nl,
                'xi': [float(v) for v in br.xi[m]],
                'frequency_hz': [float(v) for v in br.frequency_hz[m]],
                'segment': [int(v) for v in br.segment[m]],
                'fundamental_share': [float(v) for v in br.shares[m, 1]],
                'tongue_harmonic': [int(v) for v in br.tongue_harmonic[m]],
            }
        return out


# ------------------------------------------------------------------------------------------------
# Reference frequencies: subsystems in front of / behind the DMF, clamped wind-up
# ------------------------------------------------------------------------------------------------

def _require_dmf(model: ReducedModel) -> None:
    if model.spring is None:
        raise ConfigError(f'driveline {model.line.name!r} has no dmf section: no non-linear normal modes')


def subsystem_frequencies(model: ReducedModel) -> dict[str, np.ndarray]:
    """Natural frequencies [Hz] of the parts in front of ('front') and behind ('rear') the DMF,
    each on its own with the DMF spring removed (free at the DMF); rigid-body modes dropped."""
    _require_dmf(model)
    K0 = model.K - model.spring.k * np.outer(model.e, model.e)
    _, labels = connected_components((np.abs(K0) > 0) | np.eye(model.n_dof, dtype=bool), directed=False)
    primary_dof = int(np.argmax(model.e))       # e = +1 on the primary side, -1 on the secondary side
    secondary_dof = int(np.argmin(model.e))
    out = {}
    for name, dof in (('front', primary_dof), ('rear', secondary_dof)):
        idx = np.flatnonzero(labels == labels[dof])
        w2 = scipy.linalg.eigh(K0[np.ix_(idx, idx)], model.J[np.ix_(idx, idx)], eigvals_only=True)
        w2 = w2[w2 > 1e-8 * max(w2.max(), 1.0)]
        out[name] = np.sqrt(w2) / TWO_PI
    return out


def clamped_frequencies(model: ReducedModel) -> np.ndarray:
    """Natural frequencies [Hz] with the DMF wind-up held at zero (flywheels rigidly joined);
    the rigid-body mode dropped. These are the zeros of the wind-up receptance h(Omega)."""
    _require_dmf(model)
    N = scipy.linalg.null_space(model.e[None, :])
    w2 = scipy.linalg.eigh(N.T @ model.K @ N, N.T @ model.J @ N, eigvals_only=True)
    w2 = w2[w2 > 1e-8 * w2.max()]
    return np.sqrt(w2) / TWO_PI


def static_windup(model: ReducedModel, region: str, distance: float | None = None) -> float:
    """Static wind-up [rad] at ``distance`` [rad] below ('primary') or above ('secondary') the knee
    theta (default distance theta / 2)."""
    _require_dmf(model)
    if region not in REGIONS:
        raise ConfigError(f'region={region!r}: allowed {", ".join(REGIONS)}')
    th = model.spring.theta
    d = 0.5 * th if distance is None else float(distance)
    if not (np.isfinite(d) and d > 0):
        raise ConfigError(f'distance={distance}: must be > 0 rad (static wind-up off the knee)')
    return th - d if region == 'primary' else th + d


# ------------------------------------------------------------------------------------------------
# Exact Galerkin harmonics of the piecewise-linear force (cosine series)
# ------------------------------------------------------------------------------------------------

class _RampForce:
    """f(u) = sum_j c_j (u - beta_j) on {side_j (u - beta_j) > 0}: piecewise linear, f(0) = f'(0) = 0.

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


# ------------------------------------------------------------------------------------------------
# The conservative condensed HBM about one static point
# ------------------------------------------------------------------------------------------------

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
        _require_dmf(model)
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
                raise ConfigError(f'static wind-up {ws} rad lies on a knee: the linearization is undefined')
            if wk > ws:
                c.append(jump), beta.append(wk - ws), side.append(1.0)
            else:
                c.append(-jump), beta.append(wk - ws), side.append(-1.0)
        if not c:
            raise ConfigError('alpha = 0: the DMF spring is linear, the normal modes are the linear ones')
        self.distance = float(min(abs(b) for b in beta))       # nearest knee
        self.b_ref = float(max(abs(x) for x in c))
        self.H = H = int(o.n_harmonics)
        if H < 1:
            raise ConfigError(f'n_harmonics={H}: must be >= 1')
        self.force = _RampForce(c, beta, side, H, int(o.n_grid))
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
            raise ConfigError(f'mode {mode} does not move the DMF: it has no non-linear normal mode')
        self.omega_lin = float(np.sqrt(self.w2[km]))
        self.e_nl = 0.5 * self.w2[km] * (self.distance / self.ephi[km]) ** 2
        self._nn2 = np.arange(H + 1) ** 2

    # ---- linear parts per harmonic --------------------------------------------------------------
    def _modal(self, Omega: float):
        """Per harmonic: dominant pole k, delta = w_k^2 - lam, A = c_k + delta R, dA/dlam terms, sign."""
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

    # ---- residual -----------------------------------------------------------------------------------
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

    # ---- recovery --------------------------------------------------------------------------------------
    def dof_harmonics(self, a: np.ndarray, Omega: float) -> np.ndarray:
        """(H+1, n_dof) cosine coefficients x_n of the DOF deviation [rad] (rigid part zero)."""
        lam, k, delta, A, ck, Rp, sig = self._modal(Omega)
        f = self.force.harmonics(a)
        b = self.b_ref
        # x_n = B_n X_n with B_n = phi_k e.phi_k + delta Y_rest and X_n = a_n / A_n = -f_n / delta_n,
        # combined in least squares so it is well-defined at poles (delta = 0) and zeros (A = 0) of h.
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

    # ---- the branch -----------------------------------------------------------------------------------
    def start(self) -> tuple[np.ndarray, float]:
        """The linear mode exactly at the knee: a_1 = d, Omega = omega_m (xi = 1)."""
        a = np.zeros(self.H + 1)
        a[1] = self.distance
        return a, self.omega_lin

    def _continue(self, a0, W0, tangent0, xi_stop):
        o = self.options
        d = self.distance
        copt = ContinuationOptions(s_scale=self.omega_lin, x_scale=d, step=o.step, step_min=o.step_min,
                                   step_max=o.step_max, grid=None, tol=o.tol * d, max_iter=15,
                                   easy_iter=4, max_turn=0.5, max_steps=o.max_steps)

        def stop(p, pts):
            return self.energy(p.x, p.s) / self.e_nl > xi_stop

        pts = continue_branch(self, a0, W0, (0.05 * self.omega_lin, 20.0 * self.omega_lin), options=copt,
                              tangent0=tangent0, stop=stop)
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
                parts.append(tuple(z[:0:-1] for z in (Ab, Wb, Eb, sb, rb)) + (np.full(len(Wb) - 1, -1 - seg),))
            t0 = np.zeros(self.H + 2)
            t0[-1] = sign
        A, W, E, shares, res, segs = (np.concatenate(z) for z in zip(*parts))
        return NNMBranch(region=self.region, mode=self.mode, windup_static=self.windup_static,
                         distance=self.distance, linear_frequency_hz=self.omega_lin / TWO_PI,
                         e_nl=float(self.e_nl), xi=E / self.e_nl, frequency_hz=W / TWO_PI, energy=E,
                         coefficients=A, shares=shares, residual=res, segment=segs,
                         tongue_share=self.options.tongue_share)

    # ---- time-domain verification ------------------------------------------------------------------
    def integrate(self, x0: np.ndarray, v0: np.ndarray, t_end: float, rtol: float = 1e-11
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Integrate J x'' + K_lin x + e f(e.x) = 0 from (x0, v0) over t_end [s] (see integrate_chain)."""
        return integrate_chain(self.model.J, self.K_lin, self.model.e, self.force.value, self.force.beta,
                               np.zeros(self.model.n_dof), x0, v0, t_end, rtol=rtol)

    def periodicity_error(self, a: np.ndarray, Omega: float, period_factor: float = 1.0, **kw) -> float:
        """Start from the HBM solution's x(0), v(0) = 0, integrate one period 2 pi / Omega (times
        ``period_factor``) in time and return the energy norm of the state change relative to the
        orbit's energy: sqrt((dx.K_lin.dx + dv.J.dv) / (2 E))."""
        x0, v0 = self.initial_state(a, Omega)
        x1, v1 = self.integrate(x0, v0, period_factor * TWO_PI / Omega, **kw)
        return _energy_norm(self.K_lin, self.model.J, x1 - x0, v1 - v0, self.energy(a, Omega))


def _energy_norm(K, J, dx, dv, E) -> float:
    return float(np.sqrt(max(dx @ K @ dx + dv @ J @ dv, 0.0) / (2.0 * E)))


def integrate_chain(J, K, e, force, levels, P, x0, v0, t_end: float, rtol: float = 1e-11):
    """Integrate J x'' + K x + e force(e.x) = P (constant P) from (x0, v0) over t_end [s].

    scipy DOP853 with tight tolerances; the integration is restarted at every crossing of a knee
    level of the wind-up e.x (``levels``), so the kink of the piecewise-linear force is never
    stepped over. Returns (x, v) at t_end."""
    n = len(x0)
    Jinv = np.linalg.inv(J)
    JK, Je, JP = Jinv @ K, Jinv @ e, Jinv @ P

    def rhs(t, y):
        x = y[:n]
        return np.concatenate([y[n:], JP - JK @ x - Je * float(force(e @ x))])

    events = []
    for lev in levels:
        def ev(t, y, lev=float(lev)):
            return e @ y[:n] - lev
        ev.terminal = True
        events.append(ev)
    y = np.concatenate([x0, v0]).astype(float)
    atol = 1e-13 * max(np.abs(y).max(), 1e-300)
    t = 0.0
    while t < t_end:
        sol = solve_ivp(rhs, (t, t_end), y, method='DOP853', rtol=rtol, atol=atol, events=events)
        if sol.status < 0:
            raise RuntimeError(f'time integration failed: {sol.message}')
        y, t = sol.y[:, -1], float(sol.t[-1])
        if sol.status == 0:
            break
        dt = min(1e-12, t_end - t)          # step off the knee (the event is located to round-off)
        y = y + dt * rhs(t, y)
        t += dt
    return y[:n], y[n:]


def static_state(model: ReducedModel, windup_static: float) -> tuple[np.ndarray, np.ndarray]:
    """Static DOF deflection q_s [rad] and the balanced mean load P0 [Nm] (engine torque on the
    cylinder elements, or element 1 without cylinders, minus the mean torque times the cumulative
    ratio on the rear-load element) that hold the DMF at ``windup_static`` [rad]."""
    _require_dmf(model)
    line = model.line
    p = np.zeros(model.n_elements)
    front = [line.index(c) for c in line.cylinders] or [0]
    for i in front:
        p[i] = 1.0 / len(front)
    rear = line.index(line.rear_load_element) if line.rear_load_element else model.n_elements - 1
    p[rear] -= sum(model.R[rear] / model.R[i] / len(front) for i in front)
    P1 = model.element_vector(p)
    q1 = solve_static(model, P1)
    torque_per_unit = model.spring.k * float(model.e @ q1)      # statics of a chain: determinate
    T_s = float(model.spring.torque(windup_static))
    P0 = P1 * (T_s / torque_per_unit)
    q_s = solve_static(model, P0 - model.e * float(model.spring.extra_torque(windup_static)))
    return q_s, P0


def integrate_physical(model: ReducedModel, P0: np.ndarray, q0: np.ndarray, v0: np.ndarray,
                       t_end: float, rtol: float = 1e-11) -> tuple[np.ndarray, np.ndarray]:
    """Integrate the undamped driveline J q'' + K q + e g(e.q) = P0 with the full DMF spring
    (no linearization about any static point) from (q0, v0) over t_end [s]."""
    sp = model.spring
    return integrate_chain(model.J, model.K, model.e, sp.extra_torque, list(sp.knees), P0, q0, v0, t_end,
                           rtol=rtol)


# ------------------------------------------------------------------------------------------------
# Both branches (paper Fig. 14)
# ------------------------------------------------------------------------------------------------

def _flat_branches(result: NNMResult, xi_max: float | None) -> list[FlatBranch]:
    subs = result.subsystem_frequencies_hz
    cl = result.clamped_frequencies_hz
    lin = result.linear_frequencies_hz
    out = []
    for name, br in result.branches.items():
        tn = br.tongue_harmonic
        idx = np.flatnonzero(tn > 0)
        if not len(idx):
            continue
        # runs of consecutive points on the same harmonic
        cut = np.flatnonzero((np.diff(idx) > 1) | (np.diff(tn[idx]) != 0)) + 1
        for g in np.split(idx, cut):
            n = int(tn[g[0]])
            if xi_max is not None and br.xi[g].min() > xi_max:
                continue
            f = float(np.median(br.frequency_hz[g]))
            best = None
            for sub, fr in subs.items():
                if len(fr):
                    j = int(np.argmin(np.abs(fr - n * f)))
                    if best is None or abs(fr[j] - n * f) < abs(best[1] - n * f):
                        best = (sub, float(fr[j]))
            jc = int(np.argmin(np.abs(cl - n * f)))
            fl = lin[br.region][lin[br.region] > 0]
            jl = int(np.argmin(np.abs(fl - n * f)))
            out.append(FlatBranch(region=br.region, harmonic=n, frequency_hz=f,
                                  xi_min=float(br.xi[g].min()), xi_max=float(br.xi[g].max()),
                                  subsystem=best[0], subsystem_frequency_hz=best[1],
                                  resonance_hz=float(fl[jl]), clamped_frequency_hz=float(cl[jc])))
    # merge tongues of the same harmonic at the same frequency visited twice (up and back down)
    merged: list[FlatBranch] = []
    for fb in sorted(out, key=lambda x: (x.region, x.harmonic, x.frequency_hz)):
        if merged and merged[-1].region == fb.region and merged[-1].harmonic == fb.harmonic and \
                abs(merged[-1].frequency_hz - fb.frequency_hz) < 0.01 * fb.frequency_hz:
            m = merged[-1]
            m.xi_min, m.xi_max = min(m.xi_min, fb.xi_min), max(m.xi_max, fb.xi_max)
            continue
        merged.append(fb)
    return merged


def nnm_branches(model: ReducedModel, *, mode: int = 2, distance: float | None = None,
                 xi_max: float = 10.0, options: NNMOptions | None = None,
                 regions=REGIONS) -> NNMResult:
    """Both NNM branches of linear mode ``mode``: static wind-up ``distance`` [rad] below the knee
    ('primary', frequency rises with xi) and above it ('secondary', frequency falls), each continued
    from xi = 1 to beyond ``xi_max`` (options.xi_stop, default 1.5 xi_max)."""
    _require_dmf(model)
    o = options or NNMOptions()
    xi_stop = o.xi_stop if o.xi_stop is not None else 1.5 * xi_max
    branches = {}
    for region in regions:
        solver = ConservativeNNM(model, static_windup(model, region, distance), mode=mode, options=o)
        branches[region] = solver.branch(xi_stop=xi_stop)
    lin = {}
    for region in REGIONS:
        K = stiffness_matrix(model, region)
        w2 = scipy.linalg.eigh(K, model.J, eigvals_only=True)
        lin[region] = np.sqrt(np.clip(w2, 0.0, None)) / TWO_PI
    res = NNMResult(driveline=model.line.name, alpha=float(model.spring.alpha), theta=float(model.spring.theta),
                    mode=int(mode), branches=branches, linear_frequencies_hz=lin,
                    subsystem_frequencies_hz=subsystem_frequencies(model),
                    clamped_frequencies_hz=clamped_frequencies(model), n_harmonics=o.n_harmonics)
    res.flat_branches = _flat_branches(res, xi_max)
    return res


def scaling_check(model: ReducedModel, xi_values=(2.0, 5.0), *,
                  cases=((0.24, 0.5), (0.12, 0.1), (0.5, 0.9), (0.05, 0.3)), mode: int = 2,
                  options: NNMOptions | None = None, regions=REGIONS, time_domain: bool = True) -> dict:
    """The paper's scaling claim: for fixed alpha and xi the frequency does not depend on theta nor
    on the static wind-up's distance d to the knee.

    ``cases`` are (theta [rad], d / theta). Per region and case:
      * frequency_hz: the HBM backbone frequency at ``xi_values`` for that (theta, d);
      * time_domain_error: the reference orbit (theta of ``model``, d = theta / 2) at the backbone
        point nearest each xi, scaled by d / d_ref and started from that case's own static
        equilibrium (engine torque and rear load, full two-step spring, no linearization), integrated
        over the reference period: energy-norm periodicity error (see periodicity_error);
      * control_error: the same with the period 0.1 % longer (what a 0.1 % frequency change costs).
    """
    o = options or NNMOptions()
    xi_values = np.asarray(xi_values, float)
    xi_stop = 1.2 * xi_values.max()
    out = {}
    for region in regions:
        ref = ConservativeNNM(model, static_windup(model, region), mode=mode, options=o)
        rb = ref.branch(xi_stop=xi_stop)
        bb = np.flatnonzero(rb.backbone)
        picks = [int(bb[np.argmin(np.abs(rb.xi[bb] - x))]) for x in xi_values]
        rows = []
        for th, frac in cases:
            m = model.line.with_dmf(theta=th).reduce()
            d = frac * th
            ws = static_windup(m, region, d)
            solver = ConservativeNNM(m, ws, mode=mode, options=o)
            br = solver.branch(xi_stop=xi_stop)
            row = {'theta_rad': float(th), 'distance_rad': float(d), 'windup_static_rad': float(ws),
                   'frequency_hz': [float(v) for v in br.frequency_at(xi_values)]}
            if time_domain:
                q_s, P0 = static_state(m, ws)
                errs, ctrl, xis = [], [], []
                for i in picks:
                    a, W = rb.coefficients[i], TWO_PI * rb.frequency_hz[i]
                    scale = d / ref.distance
                    x0, v0 = ref.initial_state(a, W)
                    x0 = x0 * scale
                    E = solver.energy(a * scale, W)
                    xis.append(E / solver.e_nl)
                    for fac, store in ((1.0, errs), (1.001, ctrl)):
                        q1, v1 = integrate_physical(m, P0, q_s + x0, v0, fac * TWO_PI / W)
                        store.append(_energy_norm(solver.K_lin, m.J, q1 - q_s - x0, v1 - v0, E))
                row.update({'reference_frequency_hz': [float(rb.frequency_hz[i]) for i in picks],
                            'xi_scaled_orbit': [float(v) for v in xis],
                            'time_domain_error': [float(v) for v in errs],
                            'control_error': [float(v) for v in ctrl]})
            rows.append(row)
        F = np.array([r['frequency_hz'] for r in rows])
        spread = float(np.nanmax((F.max(axis=0) - F.min(axis=0)) / F.mean(axis=0)))
        res = {'xi': [float(v) for v in xi_values], 'rows': rows, 'max_relative_spread': spread}
        if time_domain:
            res['max_time_domain_error'] = float(max(max(r['time_domain_error']) for r in rows))
            res['min_control_error'] = float(min(min(r['control_error']) for r in rows))
        out[region] = res
    return out
