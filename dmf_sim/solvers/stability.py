"""Floquet stability of a periodic steady state of the DMF driveline (doc/theory.md §8; the paper
leaves stability open).

Linearizing J q'' + C q' + K q + e g(e q) = P about a periodic solution q*(t) gives

    J dq'' + C dq' + (K + g'(w*(t)) e e^T) dq = 0,

a linear system with a *piecewise-constant* stiffness: g' is the extra stiffness of the spring
stage w* is in (0 in the primary region; dmf_sim.physics.spring). The force g is continuous, so no
jump (saltation) matrix is needed at a knee crossing. Over one period T = 4 pi / omega (720 deg of
crank angle) the state transition (monodromy) matrix is therefore the exact product of matrix
exponentials

    Phi(T) = exp(A_{r_k} tau_k) ... exp(A_{r_2} tau_2) exp(A_{r_1} tau_1),

one factor per stretch tau between knee crossings, with the crossing times found as roots of the
wind-up's Fourier series (not rounded to a time grid). Each A_r is constant, so it is diagonalized
once per model: exp(A_r tau) = V_r diag(exp(lambda_r tau)) V_r^-1 — a monodromy costs a few small
matrix products.

The rigid-body rotation of the free-free chain (K r = C r = 0, e.r = 0) is decoupled and carries a
double multiplier 1 (neutral drift of the mean angle); it is removed by working in the
J-orthonormal flexible modes of (K, J). The Floquet multipliers reported are those of the
2 (n_dof - 1) flexible states; the solution is asymptotically stable when all lie inside the unit
circle.

The base period is the 720 deg cycle, so a period-doubling of a 120-deg-periodic 3rd-order solution
(multiplier -1 over 120 deg) shows up as a multiplier crossing +1 over 720 deg (like a fold); the
eigenvector's harmonic content tells them apart (:meth:`FloquetAnalyzer.classify`): a 1.5th-order
(n = 3 mod 6) perturbation is the sub-harmonic instability.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.units import CYCLE_RAD, RPM_TO_RAD_S, cycle_period_s
from dmf_sim.physics.model import ReducedModel
from dmf_sim.physics.orders import synthesize
from dmf_sim.solvers.lapack_kernel import eigenvalues_into
from dmf_sim.solvers.stability_kernel import floquet, floquet_law_many, floquet_many

__all__ = ['CROSSING_NEWTON_STEPS', 'NEGLIGIBLE_STEPS', 'EXTREME_SPREAD', 'FloquetResult',
           'ModeClass', 'by_modulus', 'real_eigenbasis', 'extreme_quantity', 'FlexibleModes',
           'FloquetAnalyzer']

#: Newton steps refining each knee crossing on the wind-up's trigonometric polynomial
CROSSING_NEWTON_STEPS = 4
#: what the step-by-step monodromy with friction or end stops may leave out, in all: a step whose
#: linearized DMF part changes the state by at most this over the cycle's steps (|R_j - I| <=
#: NEGLIGIBLE_STEPS / N, in each region's real eigenbasis) is flowed without it. Those are the
#: far tails of the regularized friction, where tanh' is tiny but not zero. A hundredth of the
#: stability tolerance's default, and below the splitting's own error at N = 1024 steps
NEGLIGIBLE_STEPS = 1e-9
#: a connection's rate this many times the lowest natural frequency is named as the cause when a
#: modal decomposition fails (its small eigenvalues lose ~log10 of it of double's 16 digits)
EXTREME_SPREAD = 1e6


@dataclass
class FloquetResult:
    """Floquet multipliers of one periodic solution.

    Attributes:
        multipliers: (2 (n_dof-1),) complex multipliers over one 720 deg cycle, by |mu| descending.
        max_abs: largest |mu|; stable: max_abs < 1 + tol.
        n_crossings: knee crossings per cycle (0: the solution stays in one linear region).
    """

    multipliers: np.ndarray
    max_abs: float
    stable: bool
    n_crossings: int
    monodromy: np.ndarray | None = None
    segments: list | None = None


@dataclass
class ModeClass:
    """Harmonic content of a Floquet eigen-solution's wind-up perturbation."""

    multiplier: complex
    dominant_n: int                 # half-order index with the largest share
    share_by_class: np.ndarray      # (6,) share of |.|^2 in n = 0..5 mod 6
    sub_harmonic_share: float       # share in n = 3 mod 6 (1.5th-order family)
    spectrum: np.ndarray            # |P_n| of the periodic part
    coefficients: np.ndarray | None = None   # complex c_n of Re(p) from psi = 0 (for seeding)

    @property
    def kind(self) -> str:
        mu = self.multiplier
        if abs(mu.imag) > 1e-6 * abs(mu):
            base = 'complex'
        elif mu.real < 0:
            return 'flip'          # period doubling of the 720 deg solution (order n/4)
        else:
            base = 'real'
        if self.sub_harmonic_share > 0.5:
            return 'subharmonic'   # period doubling of the 120 deg solution: 1.5th-order family
        return 'fold' if base == 'real' else 'torus'


def real_eigenbasis(d: np.ndarray, V: np.ndarray, Vinv: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Real form of A = V diag(d) V^-1 (a real matrix): (Q, kind, sigma, freq) with
    A = Q blockdiag(B_i) Q^-1, Q's columns Re v, Im v of each complex pair (Im d > 0 first) and
    the real eigenvectors; B = [[sigma, freq], [-freq, sigma]] for a pair (kind 1, 2), sigma for a
    real eigenvalue (kind 0). What the compiled monodromy works in."""
    n = len(d)
    Q = np.empty((n, n))
    kind = np.zeros(n, dtype=np.int64)
    sigma = np.empty(n)
    freq = np.zeros(n)
    used = np.zeros(n, dtype=bool)
    col = 0
    scale = max(float(np.abs(d).max()), 1e-300)
    for i in range(n):
        if used[i]:
            continue
        used[i] = True
        if abs(d[i].imag) <= 1e-12 * scale:
            Q[:, col] = V[:, i].real
            sigma[col] = d[i].real
            col += 1
            continue
        j = next(k for k in range(n) if not used[k]
                 and abs(d[k] - np.conj(d[i])) <= 1e-9 * scale)
        used[j] = True
        i_pos = i if d[i].imag > 0 else j
        v = V[:, i_pos]
        Q[:, col], Q[:, col + 1] = v.real, v.imag
        kind[col], kind[col + 1] = 1, 2
        sigma[col] = sigma[col + 1] = d[i_pos].real
        freq[col] = freq[col + 1] = d[i_pos].imag
        col += 2
    return Q, kind, sigma, freq


_FIELD_UNITS = {'stiffness': ' Nm/rad', 'damping': ' Nms/rad', 'inertia': ' kg m^2', 'ratio': ''}


def _decades(value: float, typical: float) -> float:
    """How many decades ``value`` lies from ``typical`` (inf for a zero or non-finite one)."""
    if not (value > 0 and typical > 0 and np.isfinite(value) and np.isfinite(typical)):
        return np.inf
    return abs(float(np.log10(value / typical)))


def extreme_quantity(model: ReducedModel, lam: np.ndarray | None = None) -> str | None:
    """The element field whose size puts the model's modes out of double precision's reach, as
    the start of an error message, or None if none stands out (the solvers' error path: a
    decomposition of the modal state matrix that fails).

    Each flexible connection moves an inertia m = 1 / (d^T J^-1 d) (d its elongation row): its
    damping gives the rate c / m [1/s], its stiffness the natural frequency sqrt(k / m) [rad/s].
    The connection with the fastest of them is blamed when that is more than EXTREME_SPREAD times
    the lowest natural frequency of the model (``lam``: the flexible eigenvalues omega^2 of
    (K, J), when known), or not finite; of the fields that make it (its damping or stiffness,
    whichever gives the faster rate, the smaller inertia it moves, its gear ratio) the one that
    lies furthest, in decades, from the model's median of that field (a ratio: from 1) is
    named."""
    line = model.line
    D, k, c = model.D, model.spring_k, model.spring_c
    if not len(k):
        return None
    jd = np.diag(model.J).astype(float)
    with np.errstate(all='ignore'):
        share = D ** 2 / jd                            # 1/m of each row, DOF by DOF
        m = 1.0 / share.sum(axis=1)
        omega = np.sqrt(k / m)
        gamma = c / m
        fastest = np.nan_to_num(np.maximum(omega, gamma), nan=np.inf)
        flexible = np.asarray(lam if lam is not None else [], float)
        flexible = flexible[np.isfinite(flexible) & (flexible > 0)]
        low = (float(np.sqrt(flexible.min())) if len(flexible)
               else float(np.min(np.where(omega > 0, omega, np.inf))))
    r = int(np.argmax(fastest))
    rate = float(fastest[r])
    if np.isfinite(rate) and not rate > EXTREME_SPREAD * low:
        return None
    element = int(model.spring_elements[r])
    if not gamma[r] < omega[r]:
        own, values, what, unit = 'damping', c, 'a damping rate', '1/s'
    else:
        own, values, what, unit = 'stiffness', k, 'a natural frequency', 'rad/s'
    dof = int(np.argmax(share[r]))                     # the smaller inertia it moves
    group = np.flatnonzero(model.dof_of_element == dof)
    owner = int(group[np.argmax([line.elements[i].inertia * model.T[i, dof] ** 2
                                 for i in group])])
    typical = float(np.median(values[values > 0])) if (values > 0).any() else float(values[r])
    candidates = [(_decades(float(values[r]), typical), own, element),
                  (_decades(float(jd[dof]), float(np.median(jd))), 'inertia', owner),
                  (_decades(line.elements[element].ratio, 1.0), 'ratio', element)]
    _, field, element = max(candidates, key=lambda x: x[0] if np.isfinite(x[0]) else -1.0)
    el = line.elements[element]
    times = (f', {rate / low:.3g} times the lowest natural frequency ({low:.3g} rad/s)'
             if np.isfinite(rate) and 0 < low < np.inf else '')
    return (f"element {element + 1} ({el.name}): field '{field}' {getattr(el, field):g}"
            f'{_FIELD_UNITS[field]} gives {what} of {rate:.3g} {unit}{times}: beyond what the '
            'modal decomposition resolves in double precision')


def _modal_error(model: ReducedModel, lam: np.ndarray | None, failure: str,
                 otherwise: str = '') -> ConfigError:
    """A failed modal decomposition: the quantity responsible (:func:`extreme_quantity`) with
    the ``failure`` in brackets, else the failure and the ``otherwise`` hint."""
    cause = extreme_quantity(model, lam)
    if cause is not None:
        return ConfigError(f'{cause} ({failure})')
    return ConfigError(f'{failure}{"; " + otherwise if otherwise else ""}')


class FlexibleModes:
    """The flexible part of the free-free chain in J-orthonormal modal coordinates.

    ``q = r eta + Phi y``: the rigid rotation r is decoupled (K r = C r = 0, e.r = 0), the flexible
    coordinates obey y'' + Cr y' + (Lam + k_extra er er^T) y = Phi^T f with Cr = Phi^T C Phi and
    er = Phi^T e (the wind-up of each mode). ``eig(k_extra)`` diagonalizes the first-order matrix
    A = [[0, I], [-(Lam + k_extra er er^T), -Cr]] (cached per stiffness value).
    """

    def __init__(self, model: ReducedModel):
        self.model = model
        try:
            lam, V = scipy.linalg.eigh(model.K, model.J)
        except (ValueError, np.linalg.LinAlgError) as exc:
            raise _modal_error(model, None, f'natural modes: {exc}') from None
        if model.rigid_mode is not None:
            keep = np.sort(np.argsort(np.abs(lam))[1:])       # drop the rigid-body mode
        else:
            keep = np.arange(len(lam))
        self.Phi = V[:, keep]
        self.nf = len(keep)
        self.lam = lam[keep]
        self.er = self.Phi.T @ model.e
        self.Cr = self.Phi.T @ model.C @ self.Phi
        self._eig: dict[float, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def state_matrix(self, k_extra: float = 0.0) -> np.ndarray:
        """A = [[0, I], [-(Lam + k_extra er er^T), -Cr]] (2 nf x 2 nf)."""
        nf = self.nf
        A = np.zeros((2 * nf, 2 * nf))
        A[:nf, nf:] = np.eye(nf)
        A[nf:, :nf] = -(np.diag(self.lam) + k_extra * np.outer(self.er, self.er))
        A[nf:, nf:] = -self.Cr
        return A

    def eig(self, k_extra: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(d, V, V^-1) with A = V diag(d) V^-1 for the extra DMF stiffness ``k_extra``
        [Nm/rad]."""
        key = float(k_extra)
        if key not in self._eig:
            A = self.state_matrix(key)
            d, V = scipy.linalg.eig(A)
            Vinv = np.linalg.inv(V)
            err = np.abs((V * d) @ Vinv - A).max()
            if not err <= 1e-6 * np.abs(d).max():
                raise _modal_error(self.model, self.lam, f'state matrix not diagonalizable to '
                                   f'accuracy ({err:.1e})', 'check for repeated undamped modes')
            self._eig[key] = (d, V, Vinv)
        return self._eig[key]


#: relative step of the centred differences that give the law's tangents in numpy
SLOPE_STEP = 1e-7


def _slope(f, x: np.ndarray) -> np.ndarray:
    """Centred-difference tangent of f at x (step SLOPE_STEP relative, at least SLOPE_STEP)."""
    dx = SLOPE_STEP * np.maximum(np.abs(x), 1.0)
    return (f(x + dx) - f(x - dx)) / (2.0 * dx)


def by_modulus(mu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Multipliers sorted by decreasing modulus along the last axis (each row of a batch), and
    the largest modulus (a 0-d array for one point, one per row for a batch)."""
    size = np.abs(mu)
    order = np.argsort(-size, axis=-1)
    return (np.take_along_axis(mu, order, axis=-1),
            np.take_along_axis(size, order[..., :1], axis=-1)[..., 0])


# numpy's messages for a matrix eigvals refuses (eigenvalues, and analyze_many for a batch)
_NOT_FINITE = 'Array must not contain infs or NaNs'
_NO_CONVERGENCE = 'Eigenvalues did not converge'


def eigenvalues(X: np.ndarray) -> np.ndarray:
    """Eigenvalues of a real square matrix: ``np.linalg.eigvals`` (real when all are real, else
    complex) by the compiled call the Floquet kernels make
    (:func:`dmf_sim.solvers.lapack_kernel.eigenvalues_into`: LAPACK's balancing and Hessenberg
    reduction, then the double-shift QR of :mod:`dmf_sim.solvers.francis_qr`), so a point
    analyzed alone gets the same bits as in a sweep's batch; like numpy, it raises LinAlgError
    for a matrix with an inf or NaN."""
    X = np.ascontiguousarray(X, dtype=float)
    if not np.isfinite(X).all():
        raise np.linalg.LinAlgError(_NOT_FINITE)
    wr, wi = np.empty(len(X)), np.empty(len(X))
    if eigenvalues_into(X, wr, wi) != 0:
        raise np.linalg.LinAlgError(_NO_CONVERGENCE)
    return wr + 1j * wi if wi.any() else wr


class FloquetAnalyzer:
    """Monodromy and Floquet multipliers of periodic wind-up solutions of one model.

    Args:
        model: merged driveline with a DMF.
        n_fine: samples per cycle to locate knee crossings before refining them (default 1024).
        tol: stability tolerance on |mu| (default 1e-7: the lightly damped gearbox modes have
            |mu| within 1e-5 of 1 but below it).
        modes: FlexibleModes to share with the HBM solver (built if None).
        compiled: crossings, monodromy and multipliers of :meth:`analyze` through the compiled
            kernel (:func:`dmf_sim.solvers.stability_kernel.floquet`); False: the readable numpy
            reference below.
        negligible: with friction or end stops, the bound on the steps whose linearized DMF
            part the monodromy leaves out (default :data:`NEGLIGIBLE_STEPS`; 0 keeps every
            step).
    """

    def __init__(self, model: ReducedModel, n_fine: int = 1024, tol: float = 1e-7,
                 modes: FlexibleModes | None = None, compiled: bool = True,
                 negligible: float = NEGLIGIBLE_STEPS):
        if model.spring is None:
            raise ConfigError('model has no DMF: stability of the linear chain is trivial')
        self.model = model
        self.spring = model.spring
        self.n_fine = int(n_fine)
        self.tol = float(tol)
        self.negligible = float(negligible)
        self.modes = modes or FlexibleModes(model)
        self.nf = self.modes.nf
        self.er = self.modes.er
        self._region_stiffness = {st: self.spring.stage_stiffness(st)
                                  for st in self.spring.stages()}
        self._eig = {r: self.modes.eig(k) for r, k in self._region_stiffness.items()}
        # wind-up read-out of the first-order state y = [modal angles, modal velocities]
        self._ew = np.concatenate([self.er, np.zeros(self.nf)])
        self.compiled = bool(compiled)
        # what the compiled kernel reads: the spring's arrays and each region's real eigenbasis
        # (stacked by region index 0 .. n_knees, ascending in w)
        sp = self.spring
        knees, _, _ = sp.arrays()
        real_bases = [real_eigenbasis(*self._eig[st]) for st in sp.stages()]
        Q = [rb[0] for rb in real_bases]
        try:
            Qinv = [np.linalg.inv(q) for q in Q]
        except np.linalg.LinAlgError as exc:
            raise _modal_error(model, self.modes.lam, f'modal basis: {exc}') from None
        W = np.stack([np.stack([qa @ qb for qb in Q]) for qa in Qinv])   # W[a, b] = Q_a^-1 Q_b
        self._kernel_args = (knees, int(sp.primary_index), CROSSING_NEWTON_STEPS,
                             np.stack([rb[1] for rb in real_bases]),
                             np.stack([rb[2] for rb in real_bases]),
                             np.stack([rb[3] for rb in real_bases]), W)
        #: the spring has friction or end stops: the linearized DMF torque has a time-varying
        #: damping too, and the monodromy is integrated step by step (:meth:`analyze_law`)
        self.has_law = not sp.smooth_elastic
        if self.has_law:
            nf = self.nf
            zero = np.zeros(nf)
            b = np.concatenate([zero, -self.er])
            rows = (np.concatenate([self.er, zero]), np.concatenate([zero, self.er]))
            er2 = float(self.er @ self.er)
            # per region (by region index): the numpy reference works in the complex
            # eigen-coordinates (d, V, V^-1, beta, p, q), the compiled kernel in the real
            # eigenbasis Q (the same flows, in real arithmetic)
            self._law_complex = [(*self._eig[st], *(np.ascontiguousarray(a) for a in (
                self._eig[st][2] @ b, rows[0] @ self._eig[st][1], rows[1] @ self._eig[st][1])))
                for st in sp.stages()]
            self._law_real = (np.stack(Q), np.stack(Qinv))
            beta = np.stack([qi @ b for qi in Qinv])
            p, q = (np.stack([r @ qr for qr in Q]) for r in rows)
            nb = np.linalg.norm(beta, axis=1)
            #: per region, |beta| |p| and |beta| |q|: a step's |R_j - I| <= h (|k| bound[r, 0]
            #: + |c| bound[r, 1]) in the real eigenbasis (which steps ``negligible`` skips)
            self._law_bound = np.ascontiguousarray(
                np.stack([nb * np.linalg.norm(p, axis=1), nb * np.linalg.norm(q, axis=1)], axis=1))
            self._law_args = (*sp.arrays(), int(sp.primary_index), sp.law_array(),
                              *self._kernel_args[3:], beta, p, q, er2, self._law_bound,
                              self.negligible)

    # ---- regions and crossings -------------------------------------------------------------
    def linear_multipliers(self, speeds_rpm: np.ndarray, region: int = 0) -> np.ndarray:
        """(K, 2 nf) multipliers exp(d T) of solutions that stay in one region for the whole
        cycle."""
        T = cycle_period_s(np.asarray(speeds_rpm, dtype=float))
        return np.exp(np.outer(T, self._eig[region][0]))

    def segments_from(self, c: np.ndarray, omega: float, samples: np.ndarray | None = None
                      ) -> tuple[list[tuple[int, float]], float]:
        """(segments, t_start): [(stage, duration [s]), ...] covering one 720 deg cycle from the
        first knee crossing, and the time [s] after psi = 0 at which they start.

        ``c`` are the complex wind-up harmonics (w = Re sum c_n exp(i n psi/2)), omega [rad/s];
        ``samples``: w on a uniform grid of the cycle if already at hand (any length). Crossings
        are bracketed on the grid (every knee passed between two samples, in order) and refined
        by Newton's method on the trigonometric polynomial w(phi) - knee (all at once)."""
        c = np.asarray(c, dtype=complex)
        T = CYCLE_RAD / omega
        w = np.asarray(samples, dtype=float) if samples is not None else synthesize(c, self.n_fine)
        N = len(w)
        idx = self.spring.region_index(w)
        nxt_idx = np.roll(idx, -1)
        change = np.flatnonzero(idx != nxt_idx)                # between sample j and j+1
        if len(change) == 0:
            return [(int(idx[0]) - self.spring.primary_index, T)], 0.0
        # one entry per knee crossed: the knees between the two samples' regions, in order
        ia, ib = idx[change], nxt_idx[change]
        count = np.abs(ib - ia)
        j = np.repeat(change, count)
        step = np.repeat(np.sign(ib - ia), count)
        k = np.concatenate([np.arange(m) for m in count])      # 0, 1, .. within each interval
        start = np.repeat(ia, count)
        knee_index = np.where(step > 0, start + k, start - 1 - k)
        after = knee_index + (step > 0)                        # region index after the crossing
        level = self.spring.knees[knee_index]
        dphi = 2.0 * np.pi / N
        w0, w1 = w[j], w[(j + 1) % N]
        phis = (j + np.clip((level - w0) / (w1 - w0), 0.0, 1.0)) * dphi
        n = np.arange(len(c))
        for _ in range(CROSSING_NEWTON_STEPS):
            z = np.exp(1j * np.outer(phis, n)) * c
            f = z.real.sum(axis=1) - level
            df = (1j * n * z).real.sum(axis=1)
            upd = np.where(np.abs(df) > 0, f / np.where(df == 0, 1.0, df), 0.0)
            phis = np.clip(phis - upd, j * dphi, (j + 1) * dphi)
        phis = np.maximum.accumulate(phis)                     # crossings in time order
        times = phis * 2.0 / omega                             # psi = 2 phi, t = psi / omega
        stages = after - self.spring.primary_index
        segs = []
        for i in range(len(times)):
            t0 = times[i]
            t1 = times[i + 1] if i + 1 < len(times) else times[0] + T
            segs.append((int(stages[i]), float(t1 - t0)))
        return segs, float(times[0])

    # ---- monodromy -------------------------------------------------------------------------
    def transition(self, region: int, tau: float) -> np.ndarray:
        """exp(A_region tau) through the precomputed eigen-decomposition."""
        w, V, Vinv = self._eig[region]
        return ((V * np.exp(w * tau)) @ Vinv).real

    def monodromy(self, segments: list[tuple[int, float]]) -> np.ndarray:
        M = np.eye(2 * self.nf)
        for r, tau in segments:
            M = self.transition(r, tau) @ M
        return M

    def _one_region(self, stage: int, tau: float) -> np.ndarray:
        """Multipliers exp(lambda tau) of a solution that stays in region ``stage`` for the
        whole cycle of duration ``tau`` [s] (closed form: no knee crossed)."""
        return np.exp(self._eig[stage][0] * tau)

    def analyze(self, c: np.ndarray, speed_rpm: float, keep_monodromy: bool = False,
                samples: np.ndarray | None = None) -> FloquetResult:
        """Floquet multipliers of the periodic wind-up with harmonics ``c`` at ``speed_rpm``
        (``samples``: the wind-up on a uniform grid of the cycle, if already computed)."""
        if self.has_law:
            return self.analyze_law(c, speed_rpm, keep_monodromy, samples)
        if not self.compiled:
            return self.analyze_reference(c, speed_rpm, keep_monodromy, samples)
        omega = speed_rpm * RPM_TO_RAD_S
        c = np.ascontiguousarray(c, dtype=complex)
        w = synthesize(c, self.n_fine) if samples is None else samples
        X, count, stages, taus = floquet(c, np.ascontiguousarray(w, dtype=float), float(omega),
                                         *self._kernel_args)
        segs = list(zip(stages.tolist(), taus.tolist()))
        mu, mx = by_modulus(self._one_region(*segs[0]) if count == 1 else eigenvalues(X))
        mx = float(mx)
        return FloquetResult(mu, mx, mx < 1.0 + self.tol, 0 if count == 1 else count,
                             self.monodromy(segs) if keep_monodromy else None, segs)

    def analyze_many(self, C: np.ndarray, speeds_rpm, samples: np.ndarray
                     ) -> tuple[list[np.ndarray], list[float], list[bool]]:
        """:meth:`analyze` of K periodic wind-ups at once (a sweep's points, after their branch is
        traced): complex harmonics ``C`` (K, H+1) at ``speeds_rpm`` (K,), ``samples`` (K, N) each
        one's wind-up over the cycle. Returns the multipliers (sorted by decreasing modulus),
        max |mu| and stability of each, the same values as K calls of :meth:`analyze`; the
        crossings, monodromies and eigenvalues in one compiled call
        (:func:`dmf_sim.solvers.stability_kernel.floquet_many`; with friction or end stops
        :func:`~dmf_sim.solvers.stability_kernel.floquet_law_many`)."""
        speeds = np.asarray(speeds_rpm, dtype=float).reshape(-1)
        if self.compiled and self.has_law and len(speeds):
            res = [by_modulus(mu) for mu in self._law_many(C, speeds, samples)[0]]
            top = [float(mx) for _, mx in res]
            return [mu for mu, _ in res], top, [m < 1.0 + self.tol for m in top]
        if not self.compiled or self.has_law or len(speeds) == 0:
            res = [self.analyze(c, s, samples=w) for c, s, w in zip(C, speeds.tolist(), samples)]
            return ([r.multipliers for r in res], [r.max_abs for r in res],
                    [r.stable for r in res])
        K, ns = len(speeds), 2 * self.nf
        counts = np.empty(K, dtype=np.int64)
        stage0 = np.empty(K, dtype=np.int64)
        tau0 = np.empty(K)
        wr = np.zeros((K, ns))
        wi = np.zeros((K, ns))
        status = np.empty(K, dtype=np.int64)
        floquet_many(np.ascontiguousarray(C, dtype=complex),
                     np.ascontiguousarray(samples, dtype=float), speeds * RPM_TO_RAD_S,
                     *self._kernel_args, counts, stage0, tau0, wr, wi, status)
        if status.any():        # as eigenvalues() raises for one point
            raise np.linalg.LinAlgError(_NOT_FINITE if 1 in status else _NO_CONVERGENCE)
        mu = wr + 1j * wi
        one = counts == 1
        for k in np.flatnonzero(one).tolist():      # no knee crossed
            mu[k] = self._one_region(int(stage0[k]), float(tau0[k]))
        mu, top = by_modulus(mu)
        top = top.tolist()
        real = (~one & ~wi.any(axis=1)).tolist()    # eigenvalues() gives these a real dtype
        return ([mu[k].real.copy() if real[k] else mu[k] for k in range(K)], top,
                [m < 1.0 + self.tol for m in top])

    # ---- friction and end stops: the time-varying damping ------------------------------------
    def law_samples(self, c: np.ndarray, speed_rpm, samples: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(w, w_dot, period [s], sliding friction torque [Nm]) of the periodic wind-up with
        harmonics ``c`` at ``speed_rpm``, on the uniform grid of ``n_fine`` points of the cycle
        (or of ``samples``' length): what the step-by-step monodromy reads. ``c`` (K, H+1) at
        K speeds (``samples`` (K, N)) gives them for each row, the same values as row by row."""
        omega = np.asarray(speed_rpm, dtype=float) * RPM_TO_RAD_S
        c = np.asarray(c, dtype=complex)
        N = self.n_fine if samples is None else np.shape(samples)[-1]
        w = synthesize(c, N) if samples is None else np.asarray(samples, dtype=float)
        half = 0.5 * omega[..., None] if omega.ndim else 0.5 * float(omega)
        v = synthesize(1j * np.arange(c.shape[-1]) * half * c, N)
        amp = (self.spring.friction.amplitude(omega) if self.spring.friction
               else np.zeros_like(omega))
        return (np.ascontiguousarray(w), np.ascontiguousarray(v), CYCLE_RAD / omega, amp)

    def _law_many(self, C: np.ndarray, speeds: np.ndarray, samples: np.ndarray | None
                  ) -> tuple[list[np.ndarray], np.ndarray]:
        """(multipliers of each point, unsorted: real where all are, as :func:`eigenvalues`
        gives them; monodromies (K, 2 nf, 2 nf)) of K periodic wind-ups with friction or end
        stops in one compiled call (:func:`dmf_sim.solvers.stability_kernel.floquet_law_many`)."""
        w, v, periods, amps = self.law_samples(C, speeds, samples)
        K, ns = len(speeds), 2 * self.nf
        M = np.empty((K, ns, ns))
        wr = np.zeros((K, ns))
        wi = np.zeros((K, ns))
        status = np.empty(K, dtype=np.int64)
        floquet_law_many(w, v, np.ascontiguousarray(periods, dtype=float),
                         np.ascontiguousarray(amps, dtype=float), *self._law_args,
                         *self._law_real, M, wr, wi, status)
        if status.any():        # as eigenvalues() raises for one point
            raise np.linalg.LinAlgError(_NOT_FINITE if 1 in status else _NO_CONVERGENCE)
        mu = wr + 1j * wi
        return [mu[k] if wi[k].any() else wr[k] for k in range(K)], M

    def analyze_law(self, c: np.ndarray, speed_rpm: float, keep_monodromy: bool = False,
                    samples: np.ndarray | None = None) -> FloquetResult:
        """Floquet multipliers of a periodic wind-up of a spring with friction or end stops
        (doc/theory.md §8): the linearization has the time-varying stiffness dg/dw + dT_s/dw and
        damping dT_f/dw_dot + dT_s/dw_dot along the wind-up; the monodromy is formed over the
        ``n_fine`` steps of the cycle by the compiled splitting
        (:func:`dmf_sim.solvers.stability_kernel.monodromy_law`, the same call as a sweep's
        batch, :meth:`analyze_many`; ``compiled`` off: its numpy twin
        :meth:`monodromy_law_reference`)."""
        if self.compiled:
            c = np.asarray(c, dtype=complex)
            mus, Ms = self._law_many(c[None], np.array([float(speed_rpm)]),
                                     None if samples is None else np.asarray(samples)[None])
            mu, M = mus[0], Ms[0]
            w = synthesize(c, self.n_fine) if samples is None else np.asarray(samples)
        else:
            w, v, period, amp = self.law_samples(c, speed_rpm, samples)
            Z, first = self.monodromy_law_reference(w, v, float(period), float(amp))
            _, V, Vinv = self._law_complex[first][:3]
            M = ((V @ Z) @ Vinv).real
            mu = eigenvalues(M)
        mu, mx = by_modulus(mu)
        mx = float(mx)
        idx = self.spring.region_index(w)
        crossings = int(np.count_nonzero(idx != np.roll(idx, -1)))
        return FloquetResult(mu, mx, mx < 1.0 + self.tol, crossings,
                             M if keep_monodromy else None, None)

    def monodromy_law_reference(self, w: np.ndarray, v: np.ndarray, period: float, amp: float,
                                record: bool = False):
        """The compiled :func:`~dmf_sim.solvers.stability_kernel.monodromy_law` in numpy: the
        same splitting step by step, in the complex eigen-coordinates of each step's base
        region (where the step starts), with the law's numpy form (the spring's
        ``extra_torque``, its friction's and end stops' ``torque``; a tangent where a secant is
        undefined, and the end stop's, by a centred difference: exact on their linear pieces).
        Returns (Z in the coordinates of the first step's region, that region's index); with
        ``record`` also the wind-up read-out of the transition after each step (N, n)."""
        sp = self.spring
        _, slopes, _ = sp.arrays()
        er2 = float(self.er @ self.er)
        N = len(w)
        h = period / N
        w1, v1 = np.roll(w, -1), np.roll(v, -1)
        dw, dv = w1 - w, v1 - v
        base = sp.region_index(w)
        g0, g1 = sp.extra_torque(w), sp.extra_torque(w1)
        k = np.where(base == np.roll(base, -1), 0.0,
                     (g1 - g0) / np.where(dw != 0, dw, 1.0) - slopes[base])
        omega = CYCLE_RAD / period
        if sp.friction is not None:
            f0 = sp.friction.torque(v, omega)
            f1 = sp.friction.torque(v1, omega)
            c = np.where(dv != 0, (f1 - f0) / np.where(dv != 0, dv, 1.0),
                         _slope(lambda x: sp.friction.torque(x, omega), v))
        else:
            c = np.zeros(N)
        if sp.stops is not None:            # the contact's tangents at the step's middle
            wm, vm = 0.5 * (w + w1), 0.5 * (v + v1)
            k = k + _slope(lambda x: sp.stops.torque(x, vm), wm)
            c = c + _slope(lambda x: sp.stops.torque(wm, x), vm)
        bound = self._law_bound[base]           # the steps the kernel leaves out, likewise
        skip = h * (np.abs(k) * bound[:, 0] + np.abs(c) * bound[:, 1]) <= self.negligible / N
        k, c = np.where(skip, 0.0, k), np.where(skip, 0.0, c)
        first = cur = int(base[0])
        Z = np.eye(2 * self.nf, dtype=complex)
        steps = []
        for j in range(N):
            r = int(base[j])
            if r != cur:
                Z = (self._law_complex[r][2] @ self._law_complex[cur][1]) @ Z
                cur = r
            d, V, _, beta, p, q = self._law_complex[r]
            half = np.exp(0.5 * d * h)[:, None]
            Z = half * Z
            if k[j] != 0.0 or c[j] != 0.0:
                sigma = -c[j] * er2
                phi = h if abs(sigma * h) < 1e-12 else np.expm1(sigma * h) / sigma
                Z = Z + np.outer(beta * phi, (k[j] * p + c[j] * q) @ Z)
            Z = half * Z
            if record:
                steps.append((self._ew @ V) @ Z)
        Z = (self._law_complex[first][2] @ self._law_complex[cur][1]) @ Z
        return (Z, first, np.array(steps)) if record else (Z, first)

    def _law_eigen_solution(self, c: np.ndarray, speed_rpm: float, which: int, n_grid: int):
        """(multiplier, wind-up perturbation on ``n_grid`` points of the cycle, 0.0) of the
        ``which``-th largest Floquet multiplier with friction or end stops: the eigenvector of
        the step-by-step monodromy (:meth:`monodromy_law_reference`, recording each step),
        read out along the wind-up at every step and resampled."""
        w, v, period, amp = self.law_samples(c, speed_rpm, None)
        Z, first, steps = self.monodromy_law_reference(w, v, float(period), float(amp),
                                                       record=True)
        mu, vecs = np.linalg.eig(Z)
        order = np.argsort(-np.abs(mu))
        m = complex(mu[order[which]])
        z0 = vecs[:, order[which]]
        ev = self._ew @ self._law_complex[first][1]
        dw_steps = np.concatenate([[ev @ z0], steps @ z0])[:-1]   # at t_0 .. t_(N-1)
        grid = np.arange(n_grid) * len(w) / n_grid
        dw = (np.interp(grid, np.arange(len(w)), dw_steps.real)
              + 1j * np.interp(grid, np.arange(len(w)), dw_steps.imag))
        if abs(m.imag) < 1e-12 * abs(m):       # real multiplier: a real eigen-solution
            dw = dw * np.exp(-1j * np.angle(dw[np.argmax(np.abs(dw))]))
        return m, dw, 0.0

    def analyze_reference(self, c: np.ndarray, speed_rpm: float, keep_monodromy: bool = False,
                          samples: np.ndarray | None = None) -> FloquetResult:
        """:meth:`analyze` in readable numpy (the compiled kernel's reference)."""
        if self.has_law:
            compiled, self.compiled = self.compiled, False
            try:
                return self.analyze_law(c, speed_rpm, keep_monodromy, samples)
            finally:
                self.compiled = compiled
        omega = speed_rpm * RPM_TO_RAD_S
        segs, _ = self.segments_from(c, omega, samples)
        if len(segs) == 1:
            # one linear region for the whole cycle: multipliers exp(lambda T) in closed form
            mu = self._one_region(*segs[0])
            M = self.monodromy(segs) if keep_monodromy else None
        else:
            M = self.monodromy(segs)
            mu = np.linalg.eigvals(M)
        mu, mx = by_modulus(mu)
        mx = float(mx)
        n_cross = 0 if len(segs) == 1 else len(segs)
        return FloquetResult(mu, mx, mx < 1.0 + self.tol, n_cross,
                             M if keep_monodromy else None, segs)

    # ---- what kind of instability --------------------------------------------------------
    def classify(self, c: np.ndarray, speed_rpm: float, which: int = 0, n_grid: int = 512
                 ) -> ModeClass:
        """Harmonic content of the wind-up perturbation of the ``which``-th largest multiplier.

        The eigen-solution is dy(t) = exp(t log(mu)/T) p(t) with p periodic over 720 deg; the
        spectrum of p's wind-up part (half-order n relative to the base omega/2) tells a fold
        (n = 0 mod 6), a 1.5th-order sub-harmonic (n = 3 mod 6) or other orders apart.
        ``ModeClass.coefficients`` are p's wind-up harmonics c_n in the psi convention of the
        solution (w = Re sum c_n exp(i n psi/2)): the direction to perturb for branch switching.
        """
        omega = speed_rpm * RPM_TO_RAD_S
        T = CYCLE_RAD / omega
        t_grid = np.arange(n_grid) * T / n_grid
        if self.has_law:
            m, dw, t_start = self._law_eigen_solution(c, speed_rpm, which, n_grid)
        else:
            segs, t_start = self.segments_from(c, omega)
            M = self.monodromy(segs)
            mu, vecs = np.linalg.eig(M)
            order = np.argsort(-np.abs(mu))
            m = complex(mu[order[which]])
            y = vecs[:, order[which]].astype(complex)
            if abs(m.imag) < 1e-12 * abs(m):       # real multiplier: a real eigen-solution
                y = y * np.exp(-1j * np.angle(y[np.argmax(np.abs(y))]))
            dw = np.empty(n_grid, dtype=complex)
            t0 = 0.0
            for r, tau in segs:
                w, V, Vinv = self._eig[r]
                a = Vinv @ y
                ev = self._ew @ V
                sel = (t_grid >= t0) & (t_grid < t0 + tau)
                dw[sel] = (np.exp(np.outer(t_grid[sel] - t0, w)) * a) @ ev
                y = V @ (np.exp(w * tau) * a)
                t0 += tau
        p = dw * np.exp(-t_grid * np.log(m) / T)
        X = np.fft.fft(p) / n_grid
        n_idx = np.fft.fftfreq(n_grid, 1.0 / n_grid).astype(int)
        power = np.abs(X) ** 2
        by_class = np.array([power[np.mod(n_idx, 6) == k].sum() for k in range(6)])
        by_class = by_class / max(by_class.sum(), 1e-300)
        spec = np.zeros(n_grid // 2 + 1)
        for n, pw in zip(n_idx, power):
            spec[abs(n)] += pw
        dominant = int(np.argmax(spec))
        # real part of p as a half-order series from psi = 0:
        # c_n = 2 X_n exp(-i n omega t_start / 2)
        Xr = np.fft.rfft(p.real) / n_grid
        nn = np.arange(len(Xr))
        coeffs = 2.0 * Xr * np.exp(-1j * nn * omega * t_start / 2.0)
        coeffs[0] = Xr[0].real
        return ModeClass(m, dominant, by_class, float(by_class[3]), np.sqrt(spec), coeffs)
