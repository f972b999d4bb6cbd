"""The live node's tick loop without ROS: setpoints in, paced Newmark chunks out.

:class:`RunLoop` is what ``driveline_node`` runs in its main thread; the node only supplies a
*sink* (serialize, publish, record) and a lock shared with its ROS callbacks. Everything here is
testable with a fake clock and a list as the sink.

* Setpoints arrive in :class:`SetpointInbox` from the subscription callbacks (another thread):
  each arrival is counted and validated at once; a valid one becomes the pending value (the last
  valid one wins), an invalid one is counted and refused with its reason and never replaces it.
  The callbacks take only the inbox's own small lock, never the tick lock, so they keep up with a
  flood; the tick thread applies the pending values at the start of every tick (<= 10 ms later).
* Real-time ticks (:class:`dmf_sim.live.pacing.Pacer`): integrate up to the wall clock, publish the
  samples that fell due, record each sample's lag; an overrun skips ahead or catches up. A
  skip-ahead tick publishes nothing, so its lag enters the statistics as one entry of its own.
* Fast mode (real-time factor 0): chunks of about 1 ms of simulated time for
  :data:`FAST_BUDGET_S` of wall time per tick, then a short pause for the ROS callbacks.
* Stamps (:class:`dmf_sim.live.pacing.TimeBase`): when pacing returns to real time at factor 1 the
  stamps are re-anchored to the wall clock and the loop says so (log and diagnostics).
* Sensors (a simulation with sensors on): each chunk's signals go to the sink right after the
  chunk's samples and their lag are taken (``publish_sensors``), also from a chunk in which no
  sample fell due.

Hook points (for per-cycle order analysis, predictions, alarms): ``observers`` are called in the
tick thread with every chunk of published :class:`dmf_sim.live.simulation.Samples` and their stamps
[ns] (views: copy what you keep, return within ~0.1 ms, hand heavy work to a worker: the node's DMF
monitor, :class:`dmf_sim.monitor.worker.LiveMonitor`, is one); ``sensor_observers`` likewise with
each chunk's sensor signals that has any (:class:`dmf_sim.physics.sensor_signals.SensorChunk`,
after they are published); ``setpoint_listeners`` are called
with ``(speed_setpoint_rpm, load_setpoint)`` whenever an applied setpoint changes;
``before_tick`` callables run in the tick thread after the setpoints are applied (requests
queued by other threads, e.g. faults, applied between ticks) and ``after_tick`` ones after the
tick's chunks (their ground truth published). Health contributors live in
:class:`dmf_sim.live.health.HealthMonitor`.
"""
from __future__ import annotations

import gc
import math
import sys
import threading
import time
from typing import Any, Callable, Protocol

import numpy as np

from dmf_sim.core.numbers import fmt_num
from dmf_sim.live.pacing import LagStats, Pacer, TimeBase
from dmf_sim.live.simulation import LiveSimulation, Samples

__all__ = ['PACING_MODES', 'FAST_BUDGET_S', 'FAST_PAUSE_S', 'FAST_CHUNK_S', 'WARN_THROTTLE_S',
           'SWITCH_INTERVAL_S', 'SETPOINT_KINDS', 'Log', 'Throttle', 'SampleSink', 'SetpointInbox',
           'RunLoop']

PACING_MODES = ('realtime', 'fast')
FAST_BUDGET_S = 0.01        # wall time per tick in fast mode ...
FAST_PAUSE_S = 1e-4         # ... then a short pause so the ROS callbacks get the lock
FAST_CHUNK_S = 1e-3         # simulated time per fast-mode chunk (rounded to whole samples)
WARN_THROTTLE_S = 1.0       # repeated warnings of one kind: at most one per second
SWITCH_INTERVAL_S = 1e-3    # the tick thread waits at most ~1 ms for the GIL
SETPOINT_KINDS = ('speed', 'load')


class Log(Protocol):
    """What the core logs through (rclpy's logger and :class:`logging.Logger` both fit)."""

    def info(self, msg: str) -> Any: ...
    def warning(self, msg: str) -> Any: ...
    def error(self, msg: str) -> Any: ...


class Throttle:
    """At most one message of a kind per ``period_s`` (wall clock)."""

    def __init__(self, period_s: float = WARN_THROTTLE_S, clock=time.monotonic) -> None:
        self.period_s = period_s
        self.clock = clock
        self._last: dict[str, float] = {}

    def ready(self, key: str) -> bool:
        now = self.clock()
        if now - self._last.get(key, -math.inf) >= self.period_s:
            self._last[key] = now
            return True
        return False


class SampleSink(Protocol):
    """Where the loop's output goes (the node: serialize once, publish and record)."""

    def publish_samples(self, samples: Samples, stamps_ns: np.ndarray,
                        log_ns: np.ndarray) -> None: ...

    def publish_clock(self, stamp_ns: int) -> None: ...

    def publish_sensors(self, chunk, epoch_ns: int, log_offset_ns: int) -> None:
        """A chunk's sensor signals (:class:`dmf_sim.physics.sensor_signals.SensorChunk`):
        stamps are ``epoch_ns`` + simulated ns, log times the stamps + ``log_offset_ns``."""

    def publish_statuses(self, key: str, statuses: list, stamp_ns: int,
                         sent_ns: int | None = None) -> None:
        """A DiagnosticArray of ``statuses`` (dmf_sim.monitor.messages.StatusData) on stream
        ``key`` ('dmf_orders', 'dmf_predicted', 'misfire_detections'), stamped ``stamp_ns``
        and sent (recorded) at stamp ``sent_ns`` (default ``stamp_ns``): a status about the
        past, stamped with the time it is about, is recorded when it is sent, so a bag's
        log times stay in the order things were sent."""


# ------------------------------------------------------------------------------------------------
# Setpoints
# ------------------------------------------------------------------------------------------------

class SetpointInbox:
    """Setpoints from any thread to the tick thread: counted, validated on arrival, last valid
    one pending. ``checks`` maps 'speed'/'load' to a function returning why a value is refused
    (or None)."""

    def __init__(self, checks: dict[str, Callable[[Any], str | None]]) -> None:
        self._checks = checks
        self._lock = threading.Lock()
        self._pending: dict[str, float] = {}
        self.received = dict.fromkeys(SETPOINT_KINDS, 0)
        self.rejected = dict.fromkeys(SETPOINT_KINDS, 0)
        self.lost = dict.fromkeys(SETPOINT_KINDS, 0)     # reported lost by the middleware
        self.last_valid: dict[str, float] = {}

    def offer(self, kind: str, value) -> str | None:
        """One arrival; returns the reason it was refused, or None."""
        reason = self._checks[kind](value)
        with self._lock:
            self.received[kind] += 1
            if reason:
                self.rejected[kind] += 1
            else:
                self._pending[kind] = self.last_valid[kind] = float(value)
        return reason

    def count_lost(self, kind: str, n: int) -> None:
        with self._lock:
            self.lost[kind] += int(n)

    def take(self) -> dict[str, float]:
        """The pending valid setpoints (and forget them)."""
        if not self._pending:          # the usual case, without the lock
            return {}
        with self._lock:
            pending, self._pending = self._pending, {}
        return pending

    def total(self, what: str) -> int:
        """'received', 'rejected' or 'lost', summed over speed and load."""
        return sum(getattr(self, what).values())


# ------------------------------------------------------------------------------------------------
# The loop
# ------------------------------------------------------------------------------------------------

class RunLoop:
    """Paced stepping of a :class:`LiveSimulation` into a :class:`SampleSink`.

    Args:
        sim: the simulation.
        pacer: real-time pacing (its factor 0 = fast mode).
        sink: publishes samples and /clock.
        log: info/warning/error logger.
        publish_clock: publish /clock also at real-time factor 1.
        clock: monotonic wall clock [s] (``time.perf_counter``); wall_clock_ns: the wall clock
            for stamps [ns] (``time.time_ns``) — both injectable for tests.
    """

    def __init__(self, sim: LiveSimulation, pacer: Pacer, sink: SampleSink, log: Log, *,
                 publish_clock: bool = False, diagnostics_period_s: float = 1.0,
                 clock: Callable[[], float] = time.perf_counter,
                 wall_clock_ns: Callable[[], int] = time.time_ns) -> None:
        self.sim, self.pacer, self.sink, self.log = sim, pacer, sink, log
        self.clock, self.wall_clock_ns = clock, wall_clock_ns
        self.time = TimeBase()
        self.lag = LagStats()
        self.inbox = SetpointInbox({'speed': sim.check_speed_setpoint,
                                    'load': sim.check_load_setpoint})
        self.throttle = Throttle()
        self.publish_clock_param = bool(publish_clock)
        self.diagnostics_period_s = float(diagnostics_period_s)
        self.observers: list[Callable[[Samples, np.ndarray], None]] = []
        self.sensor_observers: list[Callable[[object], None]] = []
        self.setpoint_listeners: list[Callable[[float, float], None]] = []
        self.before_tick: list[Callable[[], None]] = []
        self.after_tick: list[Callable[[], None]] = []
        self.last_lag = 0.0
        self.next_tick = self.next_diag = 0.0
        self.wake_late_max = self.tick_busy_max = 0.0     # [s], per diagnostics window
        self.refused_on_apply = 0     # valid on arrival, refused by limits changed since

    # ---- state ------------------------------------------------------------------------------
    @property
    def mode(self) -> str:
        return 'fast' if self.pacer.fast else 'realtime'

    @property
    def clock_on(self) -> bool:
        """/clock is published: fast pacing, another factor than 1, or ``publish_clock``."""
        return self.publish_clock_param or self.pacer.fast or self.pacer.rtf != 1.0

    @property
    def publish_rate_hz(self) -> float:
        return 1.0 / (self.sim.stride * self.sim.dt)

    def wall_minus_stamp_s(self) -> float:
        return (self.wall_clock_ns() - self.time.stamp_ns(self.sim.t)) / 1e9

    # ---- control ----------------------------------------------------------------------------
    def start(self) -> None:
        """Anchor pacing and stamps at the current state (call before the first tick)."""
        now = self.clock()
        self.time.start(self.wall_clock_ns(), self.sim.t)
        self.pacer.anchor(now, self.sim.steps)
        self.next_tick = now
        self.next_diag = now + self.diagnostics_period_s

    def set_rate(self, real_time_factor: float) -> str | None:
        """New real-time factor (0 = fast), without a jump in the physics. Returning to real time
        at factor 1 re-anchors the stamps to the wall clock; the message says so (else None)."""
        was = self.pacer.rtf
        now = self.clock()
        self.pacer.set_rate(real_time_factor, now, self.sim.steps)
        self.next_tick = now
        if self.pacer.rtf != 1.0 or was == 1.0:
            return None
        jump = self.time.reanchor(self.wall_clock_ns(), self.sim.t)
        before = 'fast pacing' if was <= 0.0 else f'real_time_factor {fmt_num(was)}'
        msg = (f'real time again after {before}: stamps re-anchored to the wall clock (jumped '
               f'{"back" if jump < 0 else "ahead"} {abs(jump):.3f} s)')
        if jump < 0:
            msg += '; bag log times stay continuous'
        self.log.info(msg)
        return msg

    def apply_setpoints(self) -> None:
        """Apply the pending valid setpoints (tick thread)."""
        pending = self.inbox.take()
        if not pending:
            return
        sim = self.sim
        for kind, value in pending.items():
            setter = sim.set_speed_setpoint if kind == 'speed' else sim.set_load_setpoint
            if reason := setter(value):       # limits changed between arrival and now
                self.refused_on_apply += 1
                self.log.warning(f'rejected {reason} (limits changed since it arrived)')
        for listener in self.setpoint_listeners:
            listener(sim.speed_setpoint, sim.load_setpoint)

    # ---- ticks ------------------------------------------------------------------------------
    def tick(self, now: float) -> None:
        """One tick at wall time ``now`` (call with the lock held)."""
        self.apply_setpoints()
        for hook in self.before_tick:
            hook()
        self._tick(now)
        for hook in self.after_tick:
            hook()

    def _tick(self, now: float) -> None:
        sim, pacer = self.sim, self.pacer
        if pacer.fast:
            chunk = sim.stride * max(1, math.ceil(FAST_CHUNK_S / (sim.dt * sim.stride)))
            end = now + FAST_BUDGET_S
            while True:
                samples = sim.advance(chunk)
                self._emit(samples)
                self._emit_sensors(samples)
                self.sink.publish_clock(self.time.stamp_ns(sim.t))
                if self.clock() >= end:
                    break
            self.next_tick = self.clock()
            return
        plan = pacer.plan(now, sim.steps)
        self.last_lag = plan.lag
        if plan.skipped:
            # skip ahead: published time jumps to the wall clock; the physics (state, crank
            # angle) continues from where it was, as if paused for the skipped interval
            self.time.skip(plan.skipped * pacer.rtf)
            self.lag.add(float(plan.lag))
        if plan.overrun and self.throttle.ready('overrun'):
            self.log.warning(
                f'overrun: {plan.lag * 1e3:.1f} ms behind the wall clock (max_lag '
                f'{pacer.max_lag * 1e3:g} ms); policy {pacer.policy}: '
                + (f'skipped ahead {plan.skipped * 1e3:.1f} ms' if pacer.policy == 'skip'
                   else 'catching up') + f'; {pacer.overruns} overruns so far')
        samples = sim.advance(plan.nsteps)
        rows = len(samples)
        if rows:
            self._emit(samples)
            if rows == 1:
                self.lag.add(self.clock() - pacer.due_wall_scalar(int(samples.step[0])))
            else:
                self.lag.add(self.clock() - pacer.due_wall(samples.step))
        self._emit_sensors(samples)        # after the samples (and their lag): they go first
        if self.clock_on:
            self.sink.publish_clock(self.time.stamp_ns(sim.t))
        self.next_tick = pacer.next_tick(self.clock(), sim.next_sample_step)

    def _emit_sensors(self, samples: Samples) -> None:
        if samples.sensors is not None and not samples.sensors.empty:
            self.sink.publish_sensors(samples.sensors, self.time.epoch_ns,
                                      self.time.log_offset_ns)
            for observe in self.sensor_observers:
                observe(samples.sensors)

    def _emit(self, samples: Samples) -> None:
        if not len(samples):
            return
        stamps = self.time.stamps_ns(samples.t)
        self.sink.publish_samples(samples, stamps, stamps + self.time.log_offset_ns)
        for observe in self.observers:
            observe(samples, stamps)

    # ---- the thread -------------------------------------------------------------------------
    def run(self, should_stop: Callable[[], bool], lock: threading.RLock,
            on_diagnostics: Callable[[float], None]) -> None:
        """Tick until ``should_stop()``; ``on_diagnostics(now)`` every diagnostics period. The
        lock is held during each tick and diagnostics call (ROS callbacks take it too)."""
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        # Everything allocated so far (numba, rclpy, the model) lives until exit: move it out of
        # the collector's reach so full collections do not stall the ticks.
        gc.collect()
        gc.freeze()
        with lock:
            self.start()
        while not should_stop():
            now = self.clock()
            if now >= self.next_tick:
                late = now - self.next_tick
                with lock:
                    self.tick(now)
                busy = self.clock() - now
                self.wake_late_max = max(self.wake_late_max, late)
                self.tick_busy_max = max(self.tick_busy_max, busy)
            if now >= self.next_diag:
                with lock:
                    on_diagnostics(now)
                self.next_diag = max(self.next_diag + self.diagnostics_period_s, now)
            wait = min(self.next_tick, self.next_diag) - self.clock()
            if self.pacer.fast:
                wait = FAST_PAUSE_S
            if wait > 0:
                time.sleep(wait)

    def take_tick_maxima(self) -> tuple[float, float]:
        """(wake-up lateness, busy time) maxima [s] since the last call."""
        out = (self.wake_late_max, self.tick_busy_max)
        self.wake_late_max = self.tick_busy_max = 0.0
        return out
