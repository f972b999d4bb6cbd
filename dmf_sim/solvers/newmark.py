"""Newmark time integration of the non-linear driveline (doc/theory.md §5): integrator and
``simulate()``.

The step itself (the numba kernel, exact condensed DMF solve region by region of the spring, knee
crossings on step boundaries) and its readable numpy reference live in
:mod:`dmf_sim.solvers.newmark_kernel`; see its docstring for the equations. This module owns the
state and the model arrays the kernel works on (:class:`NewmarkIntegrator`: stepping API for the
live node), and the offline one-call API :func:`simulate` (like ``scipy.integrate.solve_ivp``: one
call, one :class:`SimulationResult`).
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from dmf_sim.core.deprecation import options_from_keywords
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.core.validation import field_error, number
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.orders import CYCLE_RAD, half_orders, resample_on_angle, summarize_orders
from dmf_sim.solvers import newmark_kernel as kernel

__all__ = ['StepRecord', 'NewmarkIntegrator', 'SimulationOptions', 'SimulationResult', 'simulate']

STOP_STEPS_PER_PERIOD = 20.0
"""Newmark steps an end-stop contact's period 2 pi sqrt(J_eff / k_s) must span at least: fewer,
and the impact torque depends on the step (the average-acceleration rule is stable there but
shortens nothing: it stretches the contact's period and misplaces its force)."""
STOP_DAMPING_STEP = 2.0
"""Largest contact damping rate c_s dt / J_eff per step: beyond it the average-acceleration rule
turns the contact's overdamped decay into an oscillation flipping sign every step, which the
contact's on/off switching (it pushes, never pulls) drives to divergence (a contact of 5e5
Nms/rad at dt = 1e-4 s on the truck's DMF reached a wind-up of 1e251 rad)."""

__all__ += ['STOP_STEPS_PER_PERIOD', 'STOP_DAMPING_STEP', 'stop_resolution_error']


def stop_resolution_error(model, dt: float) -> str | None:
    """Why the Newmark step ``dt`` [s] cannot resolve the end-stop contact of ``model``'s DMF
    (one line naming the field and the largest value it can take), or None (no stops, or
    resolved). J_eff = 1 / (e^T J^-1 e) is the inertia of the DMF's relative motion [kg m^2]
    with the rest of the driveline free: the fastest the contact can move."""
    sp = model.spring
    if sp is None or sp.stops is None:
        return None
    e = np.asarray(model.e, dtype=float)
    j_eff = 1.0 / float(np.sum(e * e / np.diag(model.J)))
    k_max = j_eff * (2.0 * math.pi / (STOP_STEPS_PER_PERIOD * dt)) ** 2
    c_max = STOP_DAMPING_STEP * j_eff / dt
    where = (f'the Newmark step dt = {dt:g} s, J_eff = {j_eff:.3g} kg m^2 the inertia of the '
             "DMF's relative motion")
    if sp.stops.stiffness > k_max:
        return (f'dmf.end_stops.stiffness {sp.stops.stiffness:g} Nm/rad: {where}, resolves a '
                f'contact stiffness up to {k_max:.3g} Nm/rad (a contact period of '
                f'{STOP_STEPS_PER_PERIOD:g} steps); lower it or the step')
    if sp.stops.damping > c_max:
        return (f'dmf.end_stops.damping {sp.stops.damping:g} Nms/rad: {where}, resolves a '
                f'contact damping up to {c_max:.3g} Nms/rad ({STOP_DAMPING_STEP:g} J_eff / dt); '
                f'lower it or the step')
    return None


# ------------------------------------------------------------------------------------------------
# Integrator object (stepping API for the node; simulate() for offline use)
# ------------------------------------------------------------------------------------------------

def _tridiag(M: np.ndarray, name: str):
    off = M - np.diag(np.diag(M)) - np.diag(np.diag(M, 1), 1) - np.diag(np.diag(M, -1), -1)
    if np.abs(off).max() > 1e-9 * max(np.abs(M).max(), 1.0):
        raise ConfigError(f'{name} is not tridiagonal: the Newmark kernel needs a series chain')
    return np.diag(M, -1).copy(), np.diag(M).copy(), np.diag(M, 1).copy()


_SUMS_START = (0.0, 0.0, math.inf, -math.inf, math.nan, math.nan, -math.inf)
"""The kernel's ``sums`` before a step: no heat, no contact, no wind-up extreme yet, every step
counted for them."""
_NO_EXTREMES = (math.nan,) * 4
"""``windup_extremes`` before a step (no wind-up extreme yet)."""


@dataclass
class StepRecord:
    """Preallocated buffers the stepper writes into (rows = recorded steps). SI units."""

    t: np.ndarray
    psi: np.ndarray
    omega: np.ndarray
    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    windup: np.ndarray
    count: int = 0

    def rows_from(self, start: int) -> 'StepRecord':
        """A view of these buffers from row ``start`` on (the stepper writes into it)."""
        return StepRecord(self.t[start:], self.psi[start:], self.omega[start:], self.q[start:],
                          self.v[start:], self.a[start:], self.windup[start:])

    @classmethod
    def allocate(cls, rows: int, n_dof: int) -> 'StepRecord':
        return cls(np.zeros(rows), np.zeros(rows), np.zeros(rows), np.zeros((rows, n_dof)),
                   np.zeros((rows, n_dof)), np.zeros((rows, n_dof)), np.zeros(rows))


@dataclass
class NewmarkIntegrator:
    """Fixed-step Newmark integrator on a merged model with the DMF's piecewise-linear spring.

    Args:
        loads: DrivelineExcitation (model + engine).
        dt: time step [s].
        beta, gamma: Newmark parameters (average acceleration: 1/4, 1/2).
        use_numba: compiled kernel (True) or the readable numpy reference path (False).
    """

    loads: DrivelineExcitation
    dt: float = 1e-4
    beta: float = 0.25
    gamma: float = 0.5
    use_numba: bool = True
    knee_crossings: int = field(default=0, init=False)
    steps_secondary: int = field(default=0, init=False)
    steps_coast: int = field(default=0, init=False)
    split_steps: int = field(default=0, init=False)
    #: end-stop contacts (drive, coast) since the last reset (doc/theory.md eq. 8b)
    stop_contacts: tuple[int, int] = field(default=(0, 0), init=False)
    #: work of the arc-spring friction since the last reset [J]: its heat (eq. 8a)
    friction_heat_j: float = field(default=0.0, init=False)
    #: largest end-stop contact torque |T_s| since the last reset [Nm] (eq. 8b)
    peak_stop_torque_nm: float = field(default=0.0, init=False)
    #: (smallest wind-up [rad], its time [s], largest wind-up [rad], its time [s]) over every
    #: step's end since the last reset or :meth:`restart_chunk_peaks` (nan before a step), of
    #: the steps that end at :meth:`extremes_from` or later
    windup_extremes: tuple = field(default=_NO_EXTREMES, init=False)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ConfigError(f'dt={self.dt}: must be > 0 s')
        if not (0 < self.beta <= 0.5 and 0.5 <= self.gamma <= 1.0
                and self.beta >= self.gamma / 4 - 1e-12):
            raise ConfigError(f'beta={self.beta}, gamma={self.gamma}: need 0.5 <= gamma <= 1 and '
                             'gamma/4 <= beta <= 0.5 (unconditionally stable Newmark)')
        m = self.loads.model
        if reason := stop_resolution_error(m, self.dt):
            raise ConfigError(reason)
        self.model = m
        n = m.n_dof
        Jd = np.diag(m.J).copy()
        if np.abs(m.J - np.diag(Jd)).max() > 0:
            raise ConfigError('J is not diagonal')
        Clo, Cd, Cup = _tridiag(m.C, 'C')
        Klo, Kd, Kup = _tridiag(m.K, 'K')
        self._Jd = Jd
        self._system = (Jd, Klo, Kd, Kup, Clo, Cd, Cup, np.ascontiguousarray(m.e, dtype=float),
                        np.array([self.beta, self.gamma]))
        # Newmark constants, Thomas factors of Khat = K + a0 J + a1 C and u = Khat^-1 e for dt
        self._factors = (np.zeros(9), np.zeros(max(n - 1, 1)), np.zeros(n),
                         np.zeros(max(n - 1, 1)), np.zeros(n))
        kernel.factor(self.dt, *self._system, *self._factors)
        sp = m.spring
        knees, slopes, offsets = (sp.arrays() if sp is not None
                                  else (np.zeros(0), np.zeros(1), np.zeros(1)))
        law = (sp.law_array() if sp is not None
               else np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0]))
        # friction heat [J], largest |end-stop torque| [Nm], smallest and largest wind-up [rad]
        # and their times [s] (the kernel's, every step)
        self._sums = np.array(_SUMS_START)
        self._spring = (knees, slopes, offsets, sp.primary_index if sp is not None else 0, law,
                        self._sums)
        L = self.loads
        cyl_dof = np.array([int(np.flatnonzero(row)[0]) for row in L.cylinder_dof_vectors],
                           dtype=np.int64)
        cyl_scale = np.array([row[d] for row, d in zip(L.cylinder_dof_vectors, cyl_dof)])
        self._rear_vec = L.rear_dof_vector.copy()
        self._B = np.zeros((len(cyl_dof), L.n_max + 1), dtype=complex)
        self._fixed = np.zeros(n)
        # the setpoints' ramp: rates of B and fixed [per s] over ramp = [t0, t1] [s] (kernel)
        self._dB = np.zeros_like(self._B)
        self._dfixed = np.zeros(n)
        self._ramp = np.zeros(2)
        self._d_rear = 0.0
        self._excitation = (self._B, cyl_dof, cyl_scale, L.dalembert_dof.copy(), self._fixed,
                            self._dB, self._dfixed, self._ramp)
        # state
        self.q = np.zeros(n)
        self.v = np.zeros(n)
        self.a = np.zeros(n)
        self._scal = np.zeros(6)  # t, psi, omega, omega_target, ramp, omega_dot
        self._state = (self.q, self.v, self.a, self._scal)
        # crossings, drive stage, coast stage, splits, drive stop contacts, coast stop contacts
        self._counters = np.zeros(6, dtype=np.int64)
        self.track_dofs = np.zeros(0, dtype=np.int64)
        self.load = 0.0
        self._rear_torque = 0.0
        #: (speed [rpm], load) of the excitation at the ramp's start and at its end (the same
        #: when no ramp is on: :meth:`ramp_excitation`)
        self.excitation_keys: tuple[tuple[float, float], tuple[float, float]] = ((0.0, 0.0),
                                                                                 (0.0, 0.0))
        #: per-cylinder combustion factors of the excitation (None: every cylinder fires)
        self.factors: np.ndarray | None = None

    # ---- state accessors ---------------------------------------------------------------
    @property
    def t(self) -> float:
        return float(self._scal[0])

    @property
    def psi(self) -> float:
        """Crank angle of the reference rotation [rad], continuous."""
        return float(self._scal[1])

    @property
    def omega(self) -> float:
        """Reference crank speed [rad/s]."""
        return float(self._scal[2])

    @property
    def speed_rpm(self) -> float:
        return self.omega / RPM_TO_RAD_S

    @property
    def omega_dot(self) -> float:
        return float(self._scal[5])

    @property
    def windup(self) -> float:
        return float(self.model.e @ self.q)

    # ---- set-up --------------------------------------------------------------------------
    def update_excitation(self, speed_rpm: float | None = None, load: float | None = None,
                          factors=None) -> None:
        """Recompute the cylinder coefficients and rear load for the current (or given) speed
        [rpm] and load fraction, and (given) per-cylinder combustion ``factors`` (kept for the
        next updates; all ones = every cylinder fires): :meth:`DrivelineExcitation.excitation`.
        Called by the stepper between chunks; coefficients are held constant inside a chunk."""
        if speed_rpm is None:
            speed_rpm = self.speed_rpm
        if load is not None:
            self.load = float(load)
        if factors is not None:
            f = np.array(factors, dtype=float)
            self.factors = None if np.all(f == 1.0) else f
        B, self._rear_torque = self.loads.excitation(speed_rpm, self.load, self.factors)
        self._B[:] = B
        self._fixed[:] = self._rear_vec * self._rear_torque
        self._dB[:] = 0.0
        self._dfixed[:] = 0.0
        self._d_rear = 0.0
        self._ramp[:] = self.t
        key = (float(speed_rpm), self.load)
        self.excitation_keys = (key, key)

    @property
    def ramping(self) -> bool:
        """An excitation ramp (:meth:`ramp_excitation`) not yet at its end."""
        return self._ramp[1] > self._ramp[0]

    def ramp_excitation(self, speed_rpm: float, load: float, t_end_s: float) -> None:
        """Let the excitation follow the setpoints step by step: from its (speed, load) now
        linearly in time to (``speed_rpm`` [rpm], ``load``) at simulated time ``t_end_s`` [s],
        then held there (each Newmark step uses the cylinder coefficients and rear load of its
        end time, :mod:`dmf_sim.solvers.newmark_kernel`). A ramp ending now or before is
        :meth:`update_excitation` at its end."""
        start = self.excitation_at(self.t)
        if self.ramping or self.excitation_keys[0] != start:
            self.update_excitation(*start)
        span = t_end_s - self.t
        end = (float(speed_rpm), float(load))
        if span <= 0.0 or end == start:
            if end != start:
                self.update_excitation(*end)
            return
        B1, rear1 = self.loads.excitation(end[0], end[1], self.factors)
        self._dB[:] = (B1 - self._B) / span
        self._d_rear = (rear1 - self._rear_torque) / span
        self._dfixed[:] = self._rear_vec * self._d_rear
        self._ramp[:] = (self.t, t_end_s)
        self.excitation_keys = (start, end)

    def excitation_at(self, t_s: float) -> tuple[float, float]:
        """(speed [rpm], load) the excitation is at, at simulated time ``t_s`` [s] (along the
        ramp of :meth:`ramp_excitation`, held at its ends)."""
        (s0, l0), (s1, l1) = self.excitation_keys
        t0, t1 = self._ramp
        if not t1 > t0:
            return s0, l0
        x = min(max((t_s - t0) / (t1 - t0), 0.0), 1.0)
        return s0 + x * (s1 - s0), l0 + x * (l1 - l0)

    def end_ramp(self) -> None:
        """The ramp is over (now at or past its end): the excitation at its end, held."""
        if self.ramping and self.t >= self._ramp[1] - 0.5 * self.dt:
            self.update_excitation(*self.excitation_keys[1])

    def set_factors(self, factors) -> None:
        """New per-cylinder combustion ``factors`` from now on, the ramp (if any) carried on
        with them to its end."""
        end, t_end = self.excitation_keys[1], float(self._ramp[1])
        ramping = self.ramping and self.t < t_end
        self.update_excitation(*self.excitation_at(self.t), factors=factors)
        if ramping:
            self.ramp_excitation(*end, t_end)

    def follow_excitation(self, other: 'NewmarkIntegrator') -> None:
        """The excitation of ``other`` from now on (its combustion factors, and its ramp to
        its end), on this integrator's loads: a rebuild that keeps the operating point."""
        (end, t_end), ramping = (other.excitation_keys[1], float(other._ramp[1])), other.ramping
        self.update_excitation(*other.excitation_at(self.t),
                               factors=other.factors if other.factors is not None
                               else np.ones(len(self._B)))
        if ramping and self.t < t_end:
            self.ramp_excitation(*end, t_end)

    def _tau(self, t_s) -> np.ndarray | float:
        """Seconds [s] into the ramp at time(s) ``t_s`` (0 without a ramp)."""
        if not self.ramping:
            return 0.0
        t0, t1 = self._ramp
        return np.clip(np.asarray(t_s, dtype=float) - t0, 0.0, t1 - t0)

    def step_ends(self, nsteps: int) -> tuple[np.ndarray, np.ndarray]:
        """(t [s], psi [rad]) at the end of each of the next ``nsteps`` steps: the kernel's
        speed ramp (toward the target at the ramp rate, clipped there) and psi = integral of
        omega dt (trapezoid), evaluated ahead (equal to the kernel's values to rounding)."""
        t0, psi0, omega0, target, ramp = (float(x) for x in self._scal[:5])
        h = self.dt
        j = np.arange(1, nsteps + 1, dtype=float)
        d = target - omega0
        omega = omega0 + math.copysign(1.0, d) * np.minimum(j * ramp * h, abs(d))
        prev = np.concatenate(([omega0], omega[:-1]))
        return t0 + j * h, psi0 + np.cumsum(0.5 * (prev + omega) * h)

    def speed_after_rpm(self, seconds: float) -> float:
        """Reference speed [rpm] ``seconds`` [s] ahead on the current ramp (the kernel's ramp
        toward the target at the ramp rate, clipped there)."""
        omega, target, ramp = self._scal[2], self._scal[3], self._scal[4]
        lim = ramp * max(seconds, 0.0)
        return float(omega + min(max(target - omega, -lim), lim)) / RPM_TO_RAD_S

    def set_target(self, speed_rpm: float, ramp_rpm_per_s: float) -> None:
        """Ramp the reference speed toward ``speed_rpm`` at ``ramp_rpm_per_s``."""
        self._scal[3] = speed_rpm * RPM_TO_RAD_S
        self._scal[4] = ramp_rpm_per_s * RPM_TO_RAD_S

    def reset(self, speed_rpm: float, load: float, psi: float = 0.0, t: float = 0.0) -> None:
        """Start at constant speed from the static equilibrium under the mean torque.

        The rigid-body velocity is set to the forced periodic rigid-body velocity at psi so the
        free chain's mean speed does not drift away from the reference (the rigid mode is
        decoupled: r^T K = r^T C = 0).
        """
        self._scal[:] = [t, psi, speed_rpm * RPM_TO_RAD_S, speed_rpm * RPM_TO_RAD_S, 0.0, 0.0]
        self.update_excitation(speed_rpm, load)
        st = self.loads.static_state(speed_rpm, load, self.factors)
        self.q[:] = st.q
        self.v[:] = 0.0
        r = self.model.rigid_mode
        if r is not None and speed_rpm > 0:
            P = self.loads.dof_harmonics(speed_rpm, load, self.factors)
            Jr = float(r @ self.model.J @ r)
            n = np.arange(1, P.shape[0])
            Om = n / 2 * speed_rpm * RPM_TO_RAD_S
            F = P[1:] @ r
            # eta'' = Re(F e^{i n psi/2})/Jr  ->  eta' = Re(F/(i Om Jr) e^{i n psi/2})
            eta_dot = np.real(np.sum(F / (1j * Om * Jr) * np.exp(1j * n * psi / 2)))
            self.v[:] = r * eta_dot
        self.a[:] = self.acceleration(self.q, self.v)
        self._counters[:] = 0
        self._sums[:6] = _SUMS_START[:6]
        self._read_counters()

    def acceleration(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """a = J^-1 (P - C v - K q - e (g + T_f + T_s)) at the current psi, omega and
        omega_dot (T_f, T_s: friction and end stops, eq. 8a-8b, where the spring has them)."""
        P = self.generalized_load(self.psi, self.omega_dot, self.t)
        m = self.model
        sp = m.spring
        g = float(sp.extra_torque(m.e @ q)) if sp is not None else 0.0
        if sp is not None and not sp.smooth_elastic:
            g += float(sp.law_torque(m.e @ q, m.e @ v, self.omega))
        return (P - m.C @ v - m.K @ q - m.e * g) / self._Jd

    def generalized_load(self, psi, omega_dot=0.0, t_s=None) -> np.ndarray:
        """Generalized load [Nm] with the current coefficients at crank angle(s) psi [rad]:
        ``T^T p`` of :meth:`element_loads` (virtual work)."""
        return self.model.element_vector(self.element_loads(psi, omega_dot, t_s))

    def element_loads(self, psi, omega_dot=0.0, t_s=None) -> np.ndarray:
        """Element torques [Nm] (cylinders, rear, d'Alembert) at crank angle(s) psi, with the
        coefficients at simulated time(s) ``t_s`` [s] along an excitation ramp
        (:meth:`ramp_excitation`; None: those at the ramp's start)."""
        psi = np.asarray(psi, dtype=float)
        L = self.loads
        n = np.arange(self._B.shape[1])
        z = np.exp(1j * np.multiply.outer(psi, n) / 2)
        cyl = np.real(z @ self._B.T)
        rear = self._rear_torque
        if t_s is not None and self.ramping:
            tau = np.multiply(self._tau(t_s), np.ones_like(psi))
            cyl = cyl + tau[..., None] * np.real(z @ self._dB.T)
            rear = rear + tau * self._d_rear
        p = np.multiply.outer(np.asarray(omega_dot, float) * np.ones_like(psi),
                              L.dalembert_elements)
        p[..., L.cylinder_elements] += cyl
        p[..., L.rear_element] += rear
        return p

    # ---- stepping ------------------------------------------------------------------------
    def set_tracked(self, dofs) -> None:
        """DOFs whose angle and velocity :meth:`advance` writes every step into its ``track``
        rows (the sensors' elements); empty: none."""
        self.track_dofs = np.ascontiguousarray(dofs, dtype=np.int64)

    def track_columns(self) -> int:
        """Columns of a ``track`` row: t [s], psi [rad], omega [rad/s], then the tracked DOFs'
        angles [rad] and velocities [rad/s]."""
        return 3 + 2 * len(self.track_dofs)

    def advance(self, nsteps: int, record: StepRecord | None = None, stride: int = 1,
                track: np.ndarray | None = None) -> int:
        """Advance ``nsteps`` steps; every ``stride`` steps write the state into ``record``
        (rows from 0; needs nsteps // stride rows); with ``track`` ((>= nsteps, track_columns())
        float64, C order), every step's tracked DOFs (:meth:`set_tracked`) into its rows from 0.
        Returns the number of rows of ``record`` written."""
        if record is None:
            record = self._scratch(max(nsteps // stride, 1))
            stride = max(nsteps, 1)
        out = (record.t, record.psi, record.omega, record.q, record.v, record.a, record.windup)
        tracked = None                  # the kernel as it is without sensors
        if track is not None and len(self.track_dofs):
            if track.shape[0] < nsteps or track.shape[1] != self.track_columns():
                raise ValueError(f'track rows {track.shape}: need ({nsteps}, '
                                 f'{self.track_columns()})')
            tracked = (self.track_dofs, track)
        if self.use_numba:
            rows = kernel.advance_compiled(int(nsteps), int(stride), self._state, self._system,
                                           self._factors, self._spring, self._excitation, out,
                                           self._counters, tracked)
        else:
            rows = kernel.advance_reference(int(nsteps), int(stride), self._state, self._system,
                                            self._factors, (self.model.spring, self._sums),
                                            self._excitation, out, self._counters, tracked)
        record.count = rows
        self._read_counters()
        return rows

    def restart_chunk_peaks(self) -> None:
        """Start :attr:`peak_stop_torque_nm` and :attr:`windup_extremes` afresh (the next
        chunk's own largest contact torque and wind-up extremes; the contacts and the friction
        heat keep counting)."""
        self._sums[1:6] = _SUMS_START[1:6]
        self._read_counters()

    def extremes_from(self, t_s: float) -> None:
        """Count only the steps ending at simulated time ``t_s`` [s] or later in
        :attr:`windup_extremes` (-inf: every step; kept across resets)."""
        self._sums[6] = float(t_s)

    def _read_counters(self) -> None:
        c = self._counters.tolist()
        self.knee_crossings, self.steps_secondary, self.steps_coast, self.split_steps = c[:4]
        self.stop_contacts = (c[4], c[5])
        self.friction_heat_j = float(self._sums[0])
        self.peak_stop_torque_nm = float(self._sums[1])
        lo, hi, t_lo, t_hi = self._sums[2:6].tolist()
        self.windup_extremes = (lo, t_lo, hi, t_hi) if lo <= hi else _NO_EXTREMES

    def _scratch(self, rows: int) -> StepRecord:
        buf = getattr(self, '_scratch_buf', None)
        if buf is None or buf.t.shape[0] < rows:
            buf = StepRecord.allocate(rows, self.model.n_dof)
            self._scratch_buf = buf
        return buf


# ------------------------------------------------------------------------------------------------
# Offline: one call, one result (like scipy.integrate.solve_ivp)
# ------------------------------------------------------------------------------------------------

@dataclass
class SimulationResult:
    """Result of :func:`simulate` (SI units; speed in rpm as named).

    Attributes:
        t, psi, speed_rpm, windup: recorded time [s], crank angle [rad], reference speed, DMF
            wind-up [rad] (every ``record_stride`` steps; for steady-state runs, the last cycles).
        q, v: recorded DOF angles [rad] and velocities [rad/s].
        steady: whether the cycle-to-cycle change fell below ``steady_tol``.
        cycles: engine cycles integrated; change: the last relative cycle-to-cycle change.
        windup_orders: complex half-order coefficients c_n of the wind-up over the last
            ``eval_cycles`` whole cycles (steady-state runs; None otherwise).
        summary: OrderSummary of the wind-up (3rd/1.5th order, max/min deviation, mean - theta).
        knee_crossings: DMF region changes counted by the kernel.
        message: human-readable status.
    """

    t: np.ndarray
    psi: np.ndarray
    speed_rpm: np.ndarray
    windup: np.ndarray
    q: np.ndarray
    v: np.ndarray
    steady: bool
    cycles: int
    change: float
    windup_orders: np.ndarray | None
    summary: object | None
    knee_crossings: int
    message: str
    integrator: NewmarkIntegrator | None = None

    @property
    def success(self) -> bool:
        return self.steady


@dataclass(frozen=True)
class SimulationOptions:
    """How :func:`simulate` integrates (what it integrates is its arguments).

    Attributes:
        dt: time step [s]; beta, gamma: Newmark's parameters (0.25, 0.5: the average
            acceleration rule, unconditionally stable, no numerical damping).
        steady_tol: a steady-state run stops once the wind-up's cycle-to-cycle change (max abs
            difference over one cycle on a crank-angle grid, relative to its peak-to-peak) is
            below this, after at least ``min_cycles`` and at most ``max_cycles`` engine cycles.
        eval_cycles: the last cycles whose wind-up orders a steady-state run returns.
        record_stride: a transient run (``t_end``) records every ``record_stride``-th step.
        chunk_s: a ramped transient run holds the excitation coefficients over chunks of this
            length [s], each chunk's those of its middle, as the live core does.
        use_numba: the compiled step (False: its numpy twin, the readable one).
    """

    dt: float = 1e-4
    beta: float = 0.25
    gamma: float = 0.5
    steady_tol: float = 1e-4
    min_cycles: int = 5
    max_cycles: int = 400
    eval_cycles: int = 4
    record_stride: int = 1
    chunk_s: float = 0.01
    use_numba: bool = True

    def __post_init__(self) -> None:
        """Refuse options no run can use, one line naming the field and its range: the cycle
        counts and the record stride whole numbers (``min_cycles`` >= 0, the others >= 1),
        ``steady_tol`` a finite number >= 0, ``chunk_s`` > 0 s. ``dt``, ``beta`` and ``gamma``
        are checked by :class:`NewmarkIntegrator`."""
        where = 'SimulationOptions'
        for name, lo in (('min_cycles', 0), ('max_cycles', 1), ('eval_cycles', 1),
                         ('record_stride', 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < lo:
                raise field_error(where, name, f'must be a whole number >= {lo}', value)
        number(self.steady_tol, where, 'steady_tol', 0.0)
        number(self.chunk_s, where, 'chunk_s', 0.0, lo_open=True, unit='s')


def simulate(loads: DrivelineExcitation, speed_rpm: float, load: float, *,
             t_end: float | None = None, target_speed_rpm: float | None = None,
             ramp_rpm_per_s: float = 0.0, initial: tuple[np.ndarray, np.ndarray] | None = None,
             factors=None, options: SimulationOptions | None = None, progress: bool = False,
             **keywords) -> SimulationResult:
    """Integrate the driveline at speed ``speed_rpm`` and load fraction ``load``.

    Without ``t_end``: run whole engine cycles at constant speed until the wind-up is steady
    (``options.steady_tol``), then return the wind-up orders of the last ``options.eval_cycles``
    cycles. With ``t_end`` [s]: a transient run, optionally ramping toward ``target_speed_rpm``
    at ``ramp_rpm_per_s``; the excitation coefficients follow the speed chunk by chunk
    (``options.chunk_s``), as in the live core (at constant speed, no target, the run is one
    kernel call). ``initial`` = (q, v) replaces the static equilibrium start. ``factors``:
    per-cylinder combustion factors held over the whole run (an every-cycle misfire 0, a weak
    cylinder its factor; :meth:`NewmarkIntegrator.update_excitation`), None: every cylinder
    fires. ``options``: :class:`SimulationOptions` (time step, Newmark parameters, when a run
    is steady, recording); ``progress``: a tqdm bar.

    The fields of :class:`SimulationOptions` given as keywords (``simulate(..., dt=5e-5)``, the
    old signature) still work, with a deprecation warning.
    """
    o = options_from_keywords(SimulationOptions, options, keywords, 'simulate')
    dt, record_stride, steady_tol = o.dt, o.record_stride, o.steady_tol
    min_cycles, max_cycles, eval_cycles = o.min_cycles, o.max_cycles, o.eval_cycles
    integ = NewmarkIntegrator(loads, dt=dt, beta=o.beta, gamma=o.gamma, use_numba=o.use_numba)
    if factors is not None:
        integ.update_excitation(speed_rpm, load, factors)
    integ.reset(speed_rpm, load)
    if initial is not None:
        integ.q[:] = initial[0]
        integ.v[:] = initial[1]
        integ.a[:] = integ.acceleration(integ.q, integ.v)
    theta = loads.model.spring.theta if loads.model.spring is not None else 0.0
    n_max = loads.n_max

    if t_end is not None:
        if target_speed_rpm is not None:
            integ.set_target(target_speed_rpm, ramp_rpm_per_s)
        n_total = int(round(t_end / dt))
        chunk = max(int(round(o.chunk_s / dt)) // record_stride, 1) * record_stride
        if target_speed_rpm is None and not progress:
            # constant speed: the excitation coefficients never change, so the whole run is one
            # kernel call (no per-chunk Python work; the solution finder's and the non-periodic
            # classification's long shots)
            chunk = max(n_total // record_stride, 1) * record_stride
        rows_total = n_total // record_stride
        rec = StepRecord.allocate(rows_total, loads.model.n_dof)
        done = row = 0
        bar = _bar(progress, n_total, 'simulate')
        while done < n_total:
            k = min(chunk, n_total - done)
            k -= k % record_stride if k >= record_stride else 0
            k = max(k, 1)
            if target_speed_rpm is not None:      # held over the chunk: its middle's speed
                integ.update_excitation(integ.speed_after_rpm(0.5 * k * dt))
            row += integ.advance(k, rec.rows_from(row), record_stride)
            done += k
            bar.update(k)
        bar.close()
        return SimulationResult(rec.t[:row], rec.psi[:row], rec.omega[:row] / RPM_TO_RAD_S,
                                rec.windup[:row], rec.q[:row], rec.v[:row], steady=False,
                                cycles=int(integ.psi // CYCLE_RAD), change=float('nan'),
                                windup_orders=None, summary=None,
                                knee_crossings=integ.knee_crossings,
                                message=f'transient run of {t_end} s', integrator=integ)

    # --- steady state at constant speed, cycle by cycle -----------------------------------
    omega = speed_rpm * RPM_TO_RAD_S
    steps_per_cycle = CYCLE_RAD / (omega * dt)
    keep = eval_cycles + 2
    cap = int(np.ceil(steps_per_cycle)) + 2
    ring = [StepRecord.allocate(cap, loads.model.n_dof) for _ in range(keep)]
    grid_pts = 256

    def stitched(first: int, last: int, attr: str) -> np.ndarray:
        recs = [ring[j % keep] for j in range(first, last + 1)]
        return np.concatenate([getattr(r, attr)[:r.count] for r in recs])

    prev = None
    change = np.inf
    steady = False
    cyc = 0
    bar = _bar(progress, max_cycles, f'steady state {speed_rpm:.0f} rpm')
    for cyc in range(1, max_cycles + 1):
        # record j covers crank angle [(j-1) 4pi + ~2 omega dt, j 4pi + ~2 omega dt)
        nsteps = int(np.ceil((cyc * CYCLE_RAD - integ.psi) / (omega * dt))) + 1
        integ.advance(nsteps, ring[cyc % keep], 1)
        if cyc >= 2:
            cur = resample_on_angle(stitched(cyc - 1, cyc, 'psi'),
                                    stitched(cyc - 1, cyc, 'windup'),
                                    (cyc - 1) * CYCLE_RAD, 1, grid_pts)
            if prev is not None:
                change = float(np.max(np.abs(cur - prev))) / max(float(np.ptp(cur)), 1e-9)
                if cyc >= min_cycles and change < steady_tol:
                    steady = True
                    bar.update(1)
                    break
            prev = cur
        bar.update(1)
    bar.close()
    n_eval = max(min(eval_cycles, cyc - 1), 1)
    first = cyc - n_eval
    psi, w = stitched(first, cyc, 'psi'), stitched(first, cyc, 'windup')
    start = (cyc - n_eval) * CYCLE_RAD
    samples = resample_on_angle(psi, w, start, n_eval, grid_pts)
    coeffs = half_orders(samples, n_max, n_eval)
    static = (loads.static_state(speed_rpm, load, integ.factors).windup
              if loads.model.spring is not None
              else np.nan)
    summ = summarize_orders(coeffs, samples, theta, static)
    cat = lambda attr: stitched(first, cyc, attr)  # noqa: E731
    msg = (f'steady after {cyc} cycles (change {change:.2e})' if steady
           else f'not steady after {cyc} cycles (change {change:.2e} > {steady_tol:g})')
    return SimulationResult(cat('t'), psi, np.full(len(psi), speed_rpm), w, cat('q'), cat('v'),
                            steady=steady, cycles=cyc, change=change, windup_orders=coeffs,
                            summary=summ, knee_crossings=integ.knee_crossings, message=msg,
                            integrator=integ)


def _bar(enabled: bool, total: int, desc: str):
    if enabled:
        from tqdm import tqdm
        return tqdm(total=total, desc=desc, unit='step' if total > 1000 else 'cycle', leave=False)

    class _Null:
        def update(self, n): pass
        def close(self): pass
    return _Null()
