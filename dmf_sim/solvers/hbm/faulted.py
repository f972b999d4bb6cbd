"""The harmonic balance with faults (dmf_sim.physics.faults): a steady state whose cylinders no
longer fire alike, or whose DMF has a fault.

**Which faults have a steady state.** Only the persistent ones (:attr:`Fault.persistent`): a
misfire of every cycle, a weak cylinder, a DMF stiffness, broken stage or damping fault, each
without a time window. A single or random misfire is an event, a window a time, a sensor fault
does not change the motion: :func:`steady_faults` refuses them with one line.

**What they do.** DMF faults change the driveline (the one spring object,
:meth:`FaultSet.apply_to_driveline`): they enter through the model (:func:`apply_faults` builds
the loads on it). Combustion faults give per-cylinder combustion factors s_k; cylinder k carries
``A^m + s_k (A^f - A^m)`` phased by eq. (17)
(:meth:`DrivelineExcitation.faulted_cylinder_coefficients`), so the generalized load is

    P_n = A^m_n p_n + (A^f_n - A^m_n) p^s_n,
    p_n = sum_k phase_kn T_k,   p^s_n = sum_k s_k phase_kn T_k

plus, at n = 0, the rear load balancing the faulted mean (:meth:`DrivelineExcitation.
faulted_rear_load`). The condensed problem (eq. 15) sees the excitation only through its linear
parts ``wlin_n = e.H_n P_n`` and their speed derivatives, which are linear in P: the two
components add, each the healthy formula with its own coefficients (A^m, A^f - A^m), its own
modal load (p_n, p^s_n) and its own static wind-up per unit mean torque
(:class:`FaultedParts`). h_n, the AFT, Newton, the continuation and Floquet do not depend on the
excitation and are the healthy ones. The compiled paths that query the engine inside a kernel
(the arc-length corrector, grid runs) read one engine table; a faulted problem takes the Python
path there (its linear parts by two calls of the compiled modal sums): measured on the
performance page.

**Symmetry.** Alike cylinders make the excitation nearly 120 deg periodic: a 1.5th-order state
and its 120 deg shifted copy are one physical state (twins), recognised by shift-invariant
fingerprints (the harmonic amplitudes |w_n|), deflated together, counted as a multiplicity.
When the cylinders differ none of this holds: a shifted state is no solution, and two states of
equal amplitudes but other phases are two states. :func:`is_symmetric` says which case a problem
is (all factors equal, e.g. all 1 or all 0.5, is symmetric); :func:`fingerprints` is the one
fingerprint every comparison of states uses.
"""
from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.physics.faults import Fault, FaultSet
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.solvers.hbm import linear_kernels
from dmf_sim.solvers.hbm.point import LinearParts
from dmf_sim.solvers.hbm.unknowns import amplitudes, fit_harmonics, to_real

__all__ = ['steady_faults', 'apply_faults', 'combustion_factors', 'is_symmetric',
           'fingerprints', 'FaultedParts']

_WINDOW_FIELDS = ('start_s', 'end_s', 'duration_s')


def steady_faults(faults, where: str = 'faults') -> FaultSet | None:
    """The faults of a steady state (a :class:`FaultSet`, a sequence of :class:`Fault`, or None)
    as a FaultSet, None when there are none. One-line ConfigError for a fault that has no
    periodic steady state: a single or random misfire (an event), a time window (a steady state
    has no time), a sensor fault (it does not change the motion)."""
    if faults is None:
        return None
    items = tuple(faults.faults if isinstance(faults, FaultSet) else faults)
    for i, f in enumerate(items):
        if not isinstance(f, Fault):
            raise ConfigError(f'{where}[{i}]: must be a fault (dmf_sim.physics.faults.Fault), '
                              f'got {type(f).__name__}')
        name = f.label(i, where)
        given = [k for k in _WINDOW_FIELDS if getattr(f, k) is not None]
        if given:
            field = 'at_s' if f.single else given[0]
            raise ConfigError(f'{name}: field {field!r}: a steady state has no time; give the '
                              'fault without a window (time windows are for dmf-sim run '
                              '--faults)')
        if not f.persistent:
            what = (f'mode {f.mode!r} is an event, not a periodic steady state (only '
                    'every_cycle misfires have one)' if f.kind == 'misfire' else
                    'a sensor fault does not change the motion')
            raise ConfigError(f'{name}: {what}; a steady state takes every_cycle misfires, '
                              'weak cylinders and DMF faults')
    return FaultSet(items) if items else None


def combustion_factors(factors, n_cylinders: int) -> np.ndarray | None:
    """Per-cylinder combustion factors s_k as a float array (n_cylinders,), or None when every
    cylinder fires (None, or all exactly 1: the healthy problem, bitwise). ConfigError for a
    wrong length or a factor outside [0, 1]."""
    if factors is None:
        return None
    s = np.array(factors, dtype=float).reshape(-1)
    if s.shape != (n_cylinders,) or not np.all(np.isfinite(s)) or np.any((s < 0) | (s > 1)):
        raise ConfigError(f'combustion factors: need {n_cylinders} values in [0, 1], got '
                          f'{np.asarray(factors).tolist()!r}')
    return None if np.all(s == 1.0) else s


def is_symmetric(factors) -> bool:
    """Do all cylinders fire alike (no factors, or all factors equal)? Then the shift
    symmetries of the 120 deg firing interval hold (twins, shift-invariant fingerprints)."""
    if factors is None:
        return True
    s = np.asarray(factors, dtype=float)
    return bool(np.all(s == s[0]))


def fingerprints(x: np.ndarray, H: int, symmetric: bool) -> np.ndarray:
    """What tells two states apart, for real-layout vectors x (..., 2H+1): with a symmetric
    excitation the harmonic amplitudes |w_n| (a state and its 120 deg shifted twin have the
    same: one physical state), otherwise x itself (a shifted copy is another state, or none)."""
    return amplitudes(x, H) if symmetric else np.asarray(x, dtype=float)


def apply_faults(loads: DrivelineExcitation, faults
                 ) -> tuple[DrivelineExcitation, np.ndarray | None]:
    """(loads, combustion factors) of a steady state with ``faults`` (see :func:`steady_faults`):
    the loads on the driveline with the DMF faults applied (the same object without them), and
    the per-cylinder factors (None when every cylinder fires). A combustion fault on an engine
    without a model of a cylinder that does not fire (a user table) is refused in one line."""
    fs = steady_faults(faults)
    if fs is None:
        return loads, None
    line = loads.model.line
    faulted = fs.apply_to_driveline(line)
    if faulted is not line:
        loads = DrivelineExcitation(faulted.reduce(), loads.engine)
    factors = combustion_factors(fs.combustion_factors(len(line.cylinders)),
                                 len(line.cylinders))
    if factors is not None and not loads.has_motored:
        loads.motored_coefficients(0.0, 0.0)         # raises the one-line reason
    return loads, factors


class FaultedParts:
    """The linear parts of a condensed problem with per-cylinder combustion factors: a mixin of
    :class:`dmf_sim.solvers.hbm.condensed.CondensedHBM` (it reads the problem's ``loads``,
    ``load``, ``H``, ``options``, ``compiled``, ``factors``, ``_B``, ``_ell``, ``_u0``, ``_d``,
    ``_a``, ``_h0``, ``_dOm``, ``_modal_load``, ``_static_cyl``, ``_static_rear``,
    ``engine_harmonics_many``, ``_linear_numpy`` and ``_speed_range``)."""

    def _set_up_faults(self) -> None:
        """The second component's modal load p^s_n (times the wind-up read-out) and static
        wind-up per unit mean torque: the healthy ones with cylinder k weighted by s_k."""
        L, H, s = self.loads, self.H, self.factors
        k = min(L.n_max, H) + 1
        phase = np.zeros((H + 1, L.phase.shape[0]), dtype=complex)
        phase[:k] = L.phase[:, :k].T
        self._modal_load_s = ((phase * s) @ (L.cylinder_dof_vectors @ self._B)) * self._ell
        self._static_cyl_s = float((s @ L.cylinder_dof_vectors) @ self._u0)

    def motored_harmonics(self, speed_rpm: float) -> np.ndarray:
        """(H+1,) A^m_n [Nm] of a cylinder that does not fire at ``speed_rpm`` and the problem's
        load (:meth:`DrivelineExcitation.motored_coefficients`), truncated or zero-padded to H."""
        return fit_harmonics(np.asarray(self.loads.motored_coefficients(speed_rpm, self.load),
                                        dtype=complex), self.H)

    def motored_harmonics_many(self, speeds: np.ndarray) -> np.ndarray:
        """(K, H+1) :meth:`motored_harmonics` at K speeds."""
        return np.stack([self.motored_harmonics(s) for s in np.asarray(speeds).tolist()])

    def faulted_modal_loads(self, speeds: np.ndarray) -> np.ndarray:
        """(K, H+1, 2nf) the modal loads of the faulted excitation at K speeds times the
        wind-up read-out: A^m_n ml_nk + (A^f_n - A^m_n) ml^s_nk (what A_n ml_nk is for the
        healthy engine)."""
        A = self.engine_harmonics_many(np.asarray(speeds, dtype=float))
        Am = self.motored_harmonics_many(speeds)
        return Am[..., None] * self._modal_load + (A - Am)[..., None] * self._modal_load_s

    def _linear_parts_faulted(self, speeds: Iterable[float]) -> list[LinearParts]:
        """:meth:`CondensedHBM._linear_parts_many` of the faulted excitation: the two components
        (A^m on every cylinder, A^f - A^m weighted by s_k) each through the healthy formula, added
        (the speed derivative of both by the same finite difference)."""
        speeds = [float(s) for s in speeds]
        H, K = self.H, len(speeds)
        S = np.asarray(speeds, dtype=float)
        omega = S * RPM_TO_RAD_S
        fd = self.options.speed_fd_rpm
        ds = np.where(S + fd > self._speed_range()[1], -fd, fd)
        both = np.concatenate([S, S + ds])
        A_all = self.engine_harmonics_many(both)
        Am_all = self.motored_harmonics_many(both)
        A, A2, Am, Am2 = A_all[:K], A_all[K:], Am_all[:K], Am_all[K:]
        D, D2 = A - Am, A2 - Am2
        dAm = (Am2 - Am) / ds[:, None]
        dD = (D2 - D) / ds[:, None]
        L, s = self.loads, self.factors
        rear = np.atleast_1d(L.faulted_rear_load(A, Am, s))
        rear2 = np.atleast_1d(L.faulted_rear_load(A2, Am2, s))
        wlin0 = (Am[:, 0].real * self._static_cyl + D[:, 0].real * self._static_cyl_s
                 + rear * self._static_rear)
        dwlin0 = (dAm[:, 0].real * self._static_cyl + dD[:, 0].real * self._static_cyl_s
                  + (rear2 - rear) / ds * self._static_rear)
        comps = ((Am, dAm, self._modal_load[1:], wlin0, dwlin0),
                 (D, dD, self._modal_load_s[1:], np.zeros(K), np.zeros(K)))
        h = dh = None
        wlin = np.zeros((K, H + 1), dtype=complex)
        dw = np.zeros((K, H + 1), dtype=complex)
        for Ac, dAc, ml, w0, dw0 in comps:
            if self.compiled:
                hc, dhc, wc, dwc = (np.empty((K, H + 1), dtype=complex) for _ in range(4))
                wr = np.empty((K, 2 * H + 1))
                dwr = np.empty((K, 2 * H + 1))
                linear_kernels.linear_parts(omega, self._dOm, self._d, np.ascontiguousarray(ml),
                                            self._a, Ac, dAc, w0, dw0, self._h0, hc, dhc, wc,
                                            dwc, wr, dwr)
            else:
                hc, dhc, wc, dwc = (np.empty((K, H + 1), dtype=complex) for _ in range(4))
                self._linear_numpy(omega, Ac, dAc, ml, w0, dw0, hc, dhc, wc, dwc)
            h, dh = hc, dhc
            wlin += wc
            dw += dwc
        wr, dwr = to_real(wlin, H), to_real(dw, H)
        return [LinearParts(speeds[k], float(omega[k]), h[k], wlin[k], dh[k], dw[k],
                            (wr[k], h[k], float(omega[k])), (dwr[k], dh[k])) for k in range(K)]
