"""The live simulation behind ``driveline_node``, without ROS: setpoints, ramps, samples.

Importable and testable without DDS; pacing and stamps are in :mod:`dmf_sim.live.pacing`, the tick
loop in :mod:`dmf_sim.live.run_loop`.

* :func:`check_setpoint`, :func:`ramp_toward`, :func:`split_steps` — small pure functions
  (setpoint validation, rate limiting, phase-exact chunking of the Newmark stepper).
* :class:`LiveSimulation` — owns the model, the engine and the Newmark integrator:
  setpoints with ramps (the speed ramp runs inside the Newmark kernel, the load ramp too: the
  excitation goes linearly in time over a chunk to that of the load's ramp end,
  :meth:`~dmf_sim.solvers.newmark.NewmarkIntegrator.ramp_excitation`), rebuild on
  alpha/theta/load-set changes keeping the operating point, the vibratory state and every
  count (knee crossings, stop contacts, friction heat), reset to static equilibrium, solver
  health, and the per-element samples the node publishes (vibratory angle, velocity,
  transmitted torque).

Faults (:attr:`LiveSimulation.faults`, a :class:`~dmf_sim.physics.faults.FaultTimeline`): a
chunk is split at the step where a combustion window opens with another combustion factor or a
DMF fault starts or ends (exact to one step); the cylinder coefficients of the next part are
``DrivelineExcitation.excitation`` with the timeline's factors, and a DMF change rebuilds the
integrator keeping the state (:meth:`LiveSimulation._swap`). Without faults (or an idle
timeline) a chunk is what it always was.

Sensors (``sensors=True`` and a driveline with a ``sensors:`` section): the kernel also writes
the sensor elements' DOFs every step, and each chunk's signals (tooth edges, bus values) come
with its samples (:attr:`Samples.sensors`, :class:`dmf_sim.live.sensors.LiveSensors`). Off, the
kernel tracks nothing and nothing else runs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from dmf_sim.core.errors import ConfigError, OperatingRangeError
from dmf_sim.core.numbers import fmt_num
from dmf_sim.core.units import RAD_S_TO_RPM
from dmf_sim.live.peaks import NO_EXTREMES, WindupPeaks, merge_extremes
from dmf_sim.live.sensors import LiveSensors, fault_windows
from dmf_sim.live.torques import TorqueOperator
from dmf_sim.physics.engine import load_error
from dmf_sim.physics.faults import COMBUSTION_KINDS, FaultEvent, FaultTimeline
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.model import Driveline, read_driveline
from dmf_sim.physics.sensor_signals import SensorChunk
from dmf_sim.solvers.newmark import NewmarkIntegrator, StepRecord

__all__ = ['check_setpoint', 'ramp_toward', 'split_steps', 'Samples', 'Integrated',
           'LiveSimulation']


# ------------------------------------------------------------------------------------------------
# Small pure functions
# ------------------------------------------------------------------------------------------------

def check_setpoint(value, lo: float, hi: float, name: str, unit: str = '') -> str | None:
    """Why ``value`` is not an acceptable setpoint in [lo, hi], or None when it is."""
    u = f' {unit}' if unit else ''
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        return f'{name} must be a number, got {value!r}'
    v = float(value)
    if math.isnan(v):
        return f'{name} is NaN'
    if math.isinf(v):
        return f'{name} is {"+" if v > 0 else "-"}inf'
    if not lo <= v <= hi:
        return f'{name} {fmt_num(v)}{u} outside [{fmt_num(lo)}, {fmt_num(hi)}]{u}'
    return None


def ramp_toward(current: float, target: float, rate: float, dt: float) -> float:
    """Move ``current`` toward ``target`` by at most ``rate * dt`` (rate-limited ramp)."""
    step = rate * dt
    if target > current:
        return min(target, current + step)
    return max(target, current - step)


def split_steps(nsteps: int, phase: int, stride: int) -> tuple[list[tuple[int, int, int]], int]:
    """Split ``nsteps`` Newmark steps into ``advance(k, record, s)`` calls that record exactly
    every ``stride``-th step counted from the last recorded one.

    ``phase`` = steps done since the last recorded sample (0 <= phase < stride). Returns the calls
    as (k, s, rows) and the new phase. ``NewmarkIntegrator.advance`` records when
    ``(step + 1) % s == 0`` inside one call, so a call that must not record uses ``s = k + 1``.
    """
    if nsteps < 0 or not 0 <= phase < stride:
        raise ValueError(f'nsteps={nsteps}, phase={phase}, stride={stride}')
    if nsteps == 0:
        return [], phase
    to_next = stride - phase
    if nsteps < to_next:
        return [(nsteps, nsteps + 1, 0)], phase + nsteps
    if phase == 0:
        return [(nsteps, stride, nsteps // stride)], nsteps % stride
    calls = [(to_next, to_next, 1)]
    rest = nsteps - to_next
    if rest:
        calls.append((rest, stride, rest // stride))
    return calls, rest % stride


# ------------------------------------------------------------------------------------------------
# The simulation
# ------------------------------------------------------------------------------------------------

@dataclass
class Samples:
    """Published samples of one chunk (rows = samples). Views into reused buffers: consume them
    before the next :meth:`LiveSimulation.advance`.

    step: absolute step index; t [s]; psi crank angle [rad]; speed_rpm reference engine speed;
    windup [rad]; position/velocity: vibratory element angles [rad] / velocities [rad/s];
    effort: torque transmitted into each element [Nm] (rows x elements); sensors: the chunk's
    sensor signals (None without sensors), whether or not samples fell due in it.
    """

    step: np.ndarray
    t: np.ndarray
    psi: np.ndarray
    speed_rpm: np.ndarray
    windup: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    sensors: SensorChunk | None = None

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass
class Integrated:
    """One integrated chunk before its read-out (:meth:`LiveSimulation.integrate`).

    record: the kernel's recorded states (rows from 0); rows: how many; first: step index of the
    first row; omega_dot: reference acceleration at the chunk's end [rad/s^2]; loads: element
    loads of the rows (rows x elements) where the read-out needs them, else None; sensors: the
    chunk's sensor signals (None without sensors); windup_extremes: the wind-up's extremes over
    every step of the chunk (:func:`dmf_sim.live.peaks.merge_extremes`' layout), None where the
    chunk was dropped (not finite).
    """

    record: StepRecord
    rows: int
    first: int
    omega_dot: float
    loads: np.ndarray | None = None
    fault_events: list[FaultEvent] = field(default_factory=list)
    sensors: SensorChunk | None = None
    windup_extremes: tuple | None = None


@dataclass
class LiveSimulation:
    """Newmark integration of a driveline with ramped setpoints, stepped in chunks.

    Build with :meth:`from_config`. Setpoint setters return None on success or the reason for
    refusing (the previous setpoint stays); structural changes raise ConfigError and leave the
    simulation unchanged. :attr:`line` is the driveline as configured (alpha/theta apply to
    it); the integrated one (:attr:`model`) has the active DMF faults applied. ``sensors``:
    synthesize the driveline's sensor signals (:attr:`live_sensors`; nothing when the driveline
    has none); the timeline's sensor faults act on them.
    """

    line: Driveline
    engine: object
    dt: float = 1e-4
    speed_rpm: float = 1000.0
    load: float = 0.5
    speed_ramp_rpm_per_s: float = 500.0
    load_ramp_per_s: float = 1.0
    speed_limits_rpm: tuple[float, float] = (500.0, 2200.0)
    stride: int = 10
    sensors: bool = False
    solver_resets: int = field(default=0, init=False)

    @classmethod
    def from_config(cls, driveline: str = 'truck_dmf', engine: str = 'engine_d13',
                    load_set: str = 'A', alpha: float | None = None, theta: float | None = None,
                    **kw) -> 'LiveSimulation':
        """Load the driveline YAML and the engine (names in ``config/`` or paths)."""
        from dmf_sim.physics.engine import read_engine

        line = read_driveline(driveline, alpha=alpha, theta=theta)
        return cls(line, read_engine(engine, load_set=load_set), **kw)

    def __post_init__(self) -> None:
        rng = getattr(self.engine, 'speed_range_rpm', None)
        self.engine_speed_range_rpm = (tuple(float(x) for x in rng) if rng is not None
                                       else (0.0, math.inf))
        lo, hi = self.speed_limits_rpm
        if reason := self.check_speed_limits(lo, hi):
            raise OperatingRangeError(reason)
        self.speed_limits_rpm = (float(lo), float(hi))
        if reason := (check_setpoint(self.speed_rpm, *self.speed_limits_rpm, 'initial_speed_rpm',
                                     'rpm') or load_error(self.engine, self.load, 'initial_load')):
            raise ConfigError(reason)
        for name, value in (('speed_ramp_rpm_per_s', self.speed_ramp_rpm_per_s),
                            ('load_ramp_per_s', self.load_ramp_per_s), ('dt', self.dt)):
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f'{name} must be > 0, got {value!r}')
        self.speed_setpoint = float(self.speed_rpm)
        self.load_setpoint = float(self.load)
        self.load = float(self.load)
        self.steps = 0
        self.phase = 0
        self._knees = self._secondary = self._contacts = 0
        self._heat_j = self._stop_peak_nm = 0.0
        #: the wind-up's extremes over every step of the last chunk (:meth:`integrate`):
        #: (smallest [rad], its time [s], largest [rad], its time [s]), nan before a chunk
        self.chunk_windup_extremes: tuple = NO_EXTREMES
        #: simulated time [s] from which the chunks' wind-up extremes count the steps (-inf:
        #: all; a run sets its settling's end: :meth:`NewmarkIntegrator.extremes_from`)
        self.extremes_from_s = -math.inf
        self.faults: FaultTimeline | None = None
        self._dmf_version = 0
        self.fault_events: list[FaultEvent] = []    # of the chunks of advance(), not taken yet
        self.integ, self._torques = self._make_integrator(self.line, self.engine)
        # load the compiled kernel now (numba cache), not on the first real-time tick
        self.integ.reset(self.speed_setpoint, self.load)
        self.integ.advance(1)
        self.integ.reset(self.speed_setpoint, self.load)
        self.integ.set_target(self.speed_setpoint, self.speed_ramp_rpm_per_s)
        self.peaks = WindupPeaks(self.model.spring, self.t)
        """Peak wind-up and DMF torque (and end stops) of the recorded steps since the start
        or the last :meth:`reset`."""
        self.live_sensors = None
        if self.sensors and self.line.sensors:
            self.live_sensors = LiveSensors(self.line, self.integ.model)
            self.live_sensors.start(self.integ)
        self._rec = StepRecord.allocate(64, self.integ.model.n_dof)
        self._work = np.zeros((64, 3 * self.integ.model.n_elements))
        # ... and the compiled read-out
        self.read_out(Integrated(self._rec, 1, 0, 0.0,
                                 np.zeros((1, self.model.n_elements))
                                 if self._torques.needs_loads else None))

    # ---- building ---------------------------------------------------------------------------
    def _make_integrator(self, line: Driveline, engine):
        integ = NewmarkIntegrator(DrivelineExcitation(line.reduce(), engine), dt=self.dt)
        integ.extremes_from(self.extremes_from_s)
        return integ, TorqueOperator(integ)

    @property
    def model(self):
        return self.integ.model

    @property
    def names(self) -> list[str]:
        return list(self.model.names)

    def faulted_line(self, line: Driveline | None = None) -> Driveline:
        """``line`` (default :attr:`line`) with the active DMF faults applied (ConfigError when
        they leave no valid spring)."""
        line = self.line if line is None else line
        return self.faults.dmf.apply_to_driveline(line) if self.faults is not None else line

    def _swap(self, line: Driveline, engine) -> None:
        """Rebuild the integrator for another DMF / engine keeping the operating point (speed,
        target, load, crank angle, time, combustion factors) and the vibratory state (same DOF
        layout). ``line``: the configured driveline; the active DMF faults are applied to it."""
        new, torques = self._make_integrator(self.faulted_line(line), engine)
        old = self.integ
        if new.model.n_dof != old.model.n_dof:
            raise ConfigError('the new driveline has another DOF layout; restart the node instead')
        new.reset(old.speed_rpm, self.load, psi=old.psi, t=old.t)
        new.q[:] = old.q
        new.v[:] = old.v
        new.follow_excitation(old)       # the (faulted) excitation and ramp of the chunk in hand
        new.a[:] = new.acceleration(new.q, new.v)
        new.set_target(self.speed_setpoint, self.speed_ramp_rpm_per_s)
        if self.live_sensors is not None:
            self.live_sensors.attach(new)
        self._carry_counters(old)
        self.integ, self._torques, self.line, self.engine = new, torques, line, engine
        self.peaks.set_spring(new.model.spring)
        if self.faults is not None:
            self.faults.line = line
            self._dmf_version = self.faults.dmf_version

    def _carry_counters(self, old: NewmarkIntegrator) -> None:
        """Keep what ``old`` counted since its last reset (knee crossings, steps beyond a
        knee, end-stop contacts, friction heat [J], largest stop torque [Nm] of the chunk)
        before it is rebuilt or reset: the totals of this simulation go on from there."""
        self._knees += old.knee_crossings
        self._secondary += old.steps_secondary
        self._contacts += sum(old.stop_contacts)
        self._heat_j += old.friction_heat_j
        self._stop_peak_nm = max(self._stop_peak_nm, old.peak_stop_torque_nm)
        self.chunk_windup_extremes = merge_extremes(self.chunk_windup_extremes,
                                                    old.windup_extremes)

    def set_dmf(self, alpha: float | None = None, theta: float | None = None) -> None:
        """New DMF knee parameters (alpha, theta [rad]); ConfigError if invalid."""
        self._swap(self.line.with_dmf(alpha=alpha, theta=theta), self.engine)

    # ---- faults -----------------------------------------------------------------------------
    def attach_faults(self, faults=(), where: str = 'faults') -> FaultTimeline:
        """Follow a :class:`FaultTimeline` from now on (``faults``: the schedule's, ids from 1);
        returns it (:attr:`faults`). Combustion faults need an engine with a motored model:
        one-line ConfigError otherwise, naming ``<where>[i] (kind)``."""
        timeline = FaultTimeline(self.line)
        for i, f in enumerate(faults):
            if reason := self.check_fault(f, timeline):
                raise ConfigError(f'{where}[{i}] ({f.kind}): {reason}')
            timeline.add(f, self.t)
        self.faults = timeline
        self._dmf_version = timeline.dmf_version
        return timeline

    def check_fault(self, fault, timeline: FaultTimeline | None = None) -> str | None:
        """Why ``fault`` (a :class:`~dmf_sim.physics.faults.Fault`) cannot start now, or None:
        the timeline's checks (overlaps, windows, a valid spring) and a motored model for the
        combustion faults (the reason without the fault's name)."""
        if fault.kind in COMBUSTION_KINDS and not self.integ.loads.has_motored:
            try:
                self.integ.loads.motored_coefficients(self.speed, self.load)
            except ConfigError as exc:
                return str(exc)
        timeline = self.faults if timeline is None else timeline
        return timeline.check(fault, self.t) if timeline is not None else None

    def _apply_faults(self) -> None:
        """The timeline changed the combustion factors or the DMF: new excitation (the chunk's
        speed and load) or a rebuild keeping the state."""
        tl = self.faults
        if tl.dmf_version != self._dmf_version:
            self._swap(self.line, self.engine)
        self.integ.set_factors(tl.factors)

    def set_load_set(self, load_set: str) -> None:
        """Switch the engine's load set (A, B, C); ConfigError if unknown."""
        if getattr(self.engine, 'load_set', None) == load_set:
            return
        if not hasattr(self.engine, 'with_load_set'):
            raise ConfigError('this engine has no load sets')
        self._swap(self.line, self.engine.with_load_set(load_set))

    # ---- setpoints --------------------------------------------------------------------------
    def check_speed_limits(self, lo: float, hi: float) -> str | None:
        elo, ehi = self.engine_speed_range_rpm
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            return (f'speed limits need speed_min_rpm < speed_max_rpm, got '
                    f'[{fmt_num(lo)}, {fmt_num(hi)}]')
        if lo < elo or hi > ehi:
            return (f'speed limits [{fmt_num(lo)}, {fmt_num(hi)}] rpm must lie within the engine '
                    f'data range [{fmt_num(elo)}, {fmt_num(ehi)}] rpm')
        return None

    def set_speed_limits(self, lo: float, hi: float) -> str | None:
        if reason := self.check_speed_limits(lo, hi):
            return reason
        if not lo <= self.speed_setpoint <= hi:
            return (f'the current speed setpoint {fmt_num(self.speed_setpoint)} rpm is outside '
                    f'[{fmt_num(lo)}, {fmt_num(hi)}]')
        self.speed_limits_rpm = (float(lo), float(hi))
        return None

    def check_speed_setpoint(self, value) -> str | None:
        """Why ``value`` is not an acceptable speed setpoint now, or None."""
        return check_setpoint(value, *self.speed_limits_rpm, 'speed setpoint', 'rpm')

    def check_load_setpoint(self, value) -> str | None:
        """Why ``value`` is not an acceptable load setpoint (a torque demand the engine accepts:
        [-1, 1] with a brake curve, else [0, 1]), or None."""
        return load_error(self.engine, value, 'load setpoint')

    def set_speed_setpoint(self, value) -> str | None:
        """Engine speed setpoint [rpm]; ramped at ``speed_ramp_rpm_per_s``."""
        if reason := self.check_speed_setpoint(value):
            return reason
        self.speed_setpoint = float(value)
        self.integ.set_target(self.speed_setpoint, self.speed_ramp_rpm_per_s)
        return None

    def set_load_setpoint(self, value) -> str | None:
        """Load setpoint (torque demand: 1 full load, 0 none, -1 full engine brake);
        ramped at ``load_ramp_per_s``."""
        if reason := self.check_load_setpoint(value):
            return reason
        self.load_setpoint = float(value)
        return None

    def set_ramps(self, speed_ramp_rpm_per_s: float | None = None,
                  load_ramp_per_s: float | None = None) -> None:
        if speed_ramp_rpm_per_s is not None:
            self.speed_ramp_rpm_per_s = float(speed_ramp_rpm_per_s)
            self.integ.set_target(self.speed_setpoint, self.speed_ramp_rpm_per_s)
        if load_ramp_per_s is not None:
            self.load_ramp_per_s = float(load_ramp_per_s)

    def set_stride(self, stride: int) -> None:
        """New publish decimation; the next sample comes ``stride`` steps from now."""
        self.stride = int(stride)
        self.phase = 0

    def reset(self, peaks: bool = True) -> None:
        """Static equilibrium at the current setpoints (speed and load jump to them); time,
        crank angle and step count stay continuous. ``peaks``: start :attr:`peaks` afresh."""
        if peaks:
            self.peaks.reset(self.t)
        it = self.integ
        self._carry_counters(it)
        self.load = self.load_setpoint
        it.reset(self.speed_setpoint, self.load, psi=it.psi, t=it.t)
        it.set_target(self.speed_setpoint, self.speed_ramp_rpm_per_s)
        if self.live_sensors is not None:
            self.live_sensors.resync(it)

    def set_sensor_faults(self, faults) -> None:
        """The sensor faults acting from the next chunk on (objects with the fault grammar's
        fields and ``start_s`` / ``end_s``; see
        :meth:`dmf_sim.physics.sensor_signals.SensorSynthesizer.set_faults`); ignored without
        sensors."""
        if self.live_sensors is not None:
            self.live_sensors.set_faults(faults)

    # ---- state ------------------------------------------------------------------------------
    @property
    def t(self) -> float:
        return self.integ.t

    @property
    def psi(self) -> float:
        return self.integ.psi

    @property
    def speed(self) -> float:
        """Reference (ramped) engine speed [rpm]."""
        return self.integ.speed_rpm

    @property
    def windup(self) -> float:
        return self.integ.windup

    @property
    def region(self) -> str:
        sp = self.model.spring
        return sp.region(self.windup) if sp is not None else 'none'

    @property
    def knee_crossings(self) -> int:
        return self._knees + self.integ.knee_crossings

    @property
    def steps_secondary(self) -> int:
        return self._secondary + self.integ.steps_secondary

    @property
    def stop_contacts(self) -> int:
        """End-stop contacts the kernel counted (drive and coast) since the start, across
        rebuilds and resets."""
        return self._contacts + sum(self.integ.stop_contacts)

    @property
    def friction_heat_j(self) -> float:
        """The arc-spring friction's work [J] since the start, across rebuilds and resets."""
        return self._heat_j + self.integ.friction_heat_j

    @property
    def finite(self) -> bool:
        """Solver health: the state holds only finite numbers. The tridiagonal solve spreads a
        NaN/inf in any load, angle or rate to every DOF's angle within one step (and the rates
        follow from the angles), so the end DOFs' angle and rate tell, at the cost of four scalar
        reads instead of two array sums per chunk."""
        q, v = self.integ.q, self.integ.v
        return math.isfinite(q[0] + q[-1] + v[0] + v[-1])

    @property
    def next_sample_step(self) -> int:
        return self.steps + (self.stride - self.phase)

    # ---- stepping ---------------------------------------------------------------------------
    def advance(self, nsteps: int) -> Samples:
        """Integrate ``nsteps`` steps: the kernel, the load ramped step by step (and the
        excitation with it, :meth:`integrate`); returns the samples due in the chunk (every
        ``stride``-th step). The chunk's fault events are kept in :attr:`fault_events`."""
        chunk = self.integrate(nsteps)
        if chunk.fault_events:
            self.fault_events.extend(chunk.fault_events)
        return self.read_out(chunk)

    def take_fault_events(self) -> list[FaultEvent]:
        """The fault events of the chunks :meth:`advance` integrated since the last call."""
        out, self.fault_events = self.fault_events, []
        return out

    def integrate(self, nsteps: int, record: StepRecord | None = None) -> Integrated:
        """The first half of :meth:`advance`: setpoint ramps, excitation and the kernel, the
        recorded states in ``record`` (default: this simulation's own buffer; a caller's must
        hold the chunk's rows). :meth:`read_out` turns the result into samples; ``dmf-sim run``
        integrates the next chunk in another thread meanwhile (the kernel releases the GIL)."""
        if self.faults is not None and self.faults.dmf_version != self._dmf_version:
            # a DMF fault ended between chunks (its parameter cleared, ~/clear_faults): the
            # timeline's scans only see changes made inside a chunk
            self._swap(self.line, self.engine)
        it = self.integ
        if nsteps > 0:
            # the load ramps toward its setpoint at load_ramp_per_s step by step: the kernel's
            # excitation goes linearly in time to that of the load's ramp end (the setpoint, or
            # the chunk's end if it comes first) and the reference speed then
            seconds = nsteps * self.dt
            load = ramp_toward(self.load, self.load_setpoint, self.load_ramp_per_s, seconds)
            ramp_s = min(seconds, abs(load - self.load) / self.load_ramp_per_s) \
                if load != self.load else seconds
            it.ramp_excitation(it.speed_after_rpm(ramp_s), load, it.t + ramp_s)
            self.load = load
        calls, phase = split_steps(int(nsteps), self.phase, self.stride)
        rows = sum(c[2] for c in calls)
        if record is None:
            if rows > self._rec.t.shape[0]:
                self._rec = StepRecord.allocate(max(rows, 2 * self._rec.t.shape[0]),
                                                it.model.n_dof)
            record = self._rec
        elif rows > record.t.shape[0]:
            raise ValueError(f'record holds {record.t.shape[0]} rows, the chunk needs {rows}')
        first = self.steps + (self.stride - self.phase)
        row = 0
        law_start = (self.stop_contacts, self.friction_heat_j)
        it.restart_chunk_peaks()
        it.extremes_from(self.extremes_from_s)
        self._stop_peak_nm = 0.0
        self.chunk_windup_extremes = NO_EXTREMES
        events: list[FaultEvent] = []
        parts: list[np.ndarray] = []
        if self.live_sensors is not None and self.faults is not None:
            self.live_sensors.set_faults(fault_windows(self.faults))
        if self.faults is None or self.faults.idle:
            for k, s, _ in calls:
                row += self._advance(it, k, record if row == 0 else record.rows_from(row), s)
        else:
            row, parts = self._integrate_faulted(int(nsteps), record)
            events = self.faults.take_events()
            it = self.integ
        self.steps += int(nsteps)
        self.phase = phase
        finite = self.finite
        if finite:                     # the kernel's stop contacts and friction heat of the chunk
            self.peaks.observe_law(self.stop_contacts - law_start[0],
                                   self.friction_heat_j - law_start[1],
                                   max(self._stop_peak_nm, it.peak_stop_torque_nm))
            self.chunk_windup_extremes = merge_extremes(self.chunk_windup_extremes,
                                                        it.windup_extremes)
        if not finite:
            # Newmark (average acceleration) is unconditionally stable; a non-finite state means
            # bad input data. Never publish it: restart from static equilibrium.
            self.solver_resets += 1
            self.reset(peaks=False)      # the sensors resync: the chunk's steps are dropped
            row = 0
            parts = []
        self.peaks.observe(record.windup[:row], record.t[:row],
                           self.chunk_windup_extremes if finite else None)
        omega_dot = it.omega_dot
        # element loads with this chunk's excitation, now (the next chunk changes it)
        loads = None
        if self._torques.needs_loads:
            done = sum(len(p) for p in parts)
            loads = np.concatenate(parts + [it.element_loads(record.psi[done:row], omega_dot,
                                                             record.t[done:row])])
        it.end_ramp()
        # a caller's record is read out later (dmf-sim run's pipeline): the signals copied
        sensors = (self.live_sensors.finish(copy=record is not self._rec)
                   if self.live_sensors is not None else None)
        return Integrated(record, row, first, omega_dot, loads, events, sensors,
                          self.chunk_windup_extremes if finite else None)

    def _advance(self, it: NewmarkIntegrator, nsteps: int, record: StepRecord,
                 stride: int) -> int:
        """``it.advance``, the sensor DOFs of the steps tracked when the sensors are on."""
        return it.advance(nsteps, record, stride, None if self.live_sensors is None
                          else self.live_sensors.next_rows(nsteps))

    def _integrate_faulted(self, nsteps: int, record: StepRecord) -> tuple[int, list]:
        """The kernel over ``nsteps`` steps in parts that end where the fault timeline changes
        the excitation or the DMF (:meth:`FaultTimeline.scan`), recording every ``stride``-th
        step as one call would. Returns the rows written and, where the read-out needs them,
        the element loads of the rows of each part but the last (before its excitation
        changes)."""
        done = row = 0
        phase = self.phase
        parts: list[np.ndarray] = []
        while done < nsteps:
            it = self.integ
            t_ends, psi_ends = it.step_ends(nsteps - done)
            k, changed = self.faults.scan(t_ends, psi_ends)
            start = row
            calls, phase = split_steps(k, phase, self.stride)
            for n, s, _ in calls:
                row += self._advance(it, n, record if row == 0 else record.rows_from(row), s)
            done += k
            if changed:             # (a scan that changes nothing took the remaining steps)
                if self._torques.needs_loads:
                    parts.append(it.element_loads(record.psi[start:row], it.omega_dot,
                                                  record.t[start:row]))
                self._apply_faults()
        return row, parts

    def read_out(self, chunk: Integrated, work: np.ndarray | None = None) -> Samples:
        """The samples of an integrated chunk: element angles, velocities and transmitted
        torques (``work``: their rows x 3 n_elements storage, default this simulation's own;
        the samples are views into it)."""
        m = self.model.n_elements
        row, rec = chunk.rows, chunk.record
        if work is None:
            if row > self._work.shape[0]:
                self._work = np.zeros((max(row, 2 * self._work.shape[0]), 3 * m))
            work = self._work
        psi, w = rec.psi[:row], rec.windup[:row]
        # d'Alembert part with the reference acceleration at the end of the chunk (exact while
        # the speed is constant or ramping; a ramp that ends inside the chunk is off for <= 1 row)
        position, velocity, effort = self._torques.outputs_of(
            rec.q[:row], rec.v[:row], rec.a[:row], w, psi, chunk.omega_dot, chunk.loads, work,
            rec.omega[:row])
        return Samples(step=chunk.first + self.stride * np.arange(row, dtype=np.int64),
                       t=rec.t[:row], psi=psi, speed_rpm=rec.omega[:row] * RAD_S_TO_RPM,
                       windup=w, position=position, velocity=velocity, effort=effort,
                       sensors=chunk.sensors)
