"""The live node's health report without ROS: level, problems and key/values per window.

:class:`HealthMonitor` turns what happened since its last report (counters of the run loop, the
simulation, the setpoint inbox and the recording) into a :class:`HealthReport`;
:meth:`HealthReport.status` makes it the node's one ``diagnostic_msgs/DiagnosticStatus``
(levels are the message's numbers) on ``/diagnostics``.

:class:`SimulationHealth` is the part about the simulation itself: the operating point (engine
speed and load with their setpoints: what a bag analysis reads the load each engine cycle ran at
from, :mod:`dmf_sim.analysis.load_timeline`), the DMF and the solver. ``dmf-sim run`` has no
pacing, setpoint inbox or recording control, and writes this part alone, as the same status.

Levels: OK; WARN for overruns, lag above ``max_lag``, refused or lost setpoints, a failed
recording; ERROR for a solver restart (non-finite state). ``contributors`` is the hook for
further checks (alarms): callables ``contribute(report)`` that add values and problems.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

from dmf_sim.core.numbers import fmt_num
from dmf_sim.monitor.messages import StatusData

__all__ = ['LEVEL_NAMES', 'STATUS_SUFFIX', 'status_name', 'HealthReport', 'SimulationHealth',
           'peak_values', 'HealthMonitor']

OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES = {OK: 'OK', WARN: 'WARN', ERROR: 'ERROR', STALE: 'STALE'}
STATUS_SUFFIX = 'driveline simulation'      # the health status is '<node FQN>: ' + this


def status_name(node_fqn: str) -> str:
    """Name of the node's health status on /diagnostics (hardware_id is the FQN itself)."""
    return f'{node_fqn}: {STATUS_SUFFIX}'


@dataclass
class HealthReport:
    """One diagnostics status: ``level`` (OK/WARN/ERROR), ``problems`` (the message when there
    are any), ``summary`` (the message otherwise) and ``values`` (key -> text)."""

    level: int = OK
    summary: str = ''
    problems: list[str] = field(default_factory=list)
    values: dict[str, str] = field(default_factory=dict)

    def problem(self, text: str, level: int = WARN) -> None:
        self.problems.append(text)
        self.level = max(self.level, level)

    @property
    def message(self) -> str:
        return '; '.join(self.problems) if self.problems else self.summary

    def status(self, node_fqn: str) -> StatusData:
        """The node's health status on /diagnostics: named :func:`status_name` of
        ``node_fqn``, whose ``hardware_id`` is ``node_fqn`` itself."""
        return StatusData(self.level, status_name(node_fqn), self.message,
                          tuple(self.values.items()), node_fqn)


def _ms(x: float) -> str:
    return 'nan' if not math.isfinite(x) else f'{x * 1e3:.3f}'


class SimulationHealth:
    """The simulation's part of the health report, per window of steps (the last
    :meth:`report`): ERROR for a solver restart (non-finite state); the operating point, DMF and
    solver values.

    Args:
        sim: the :class:`dmf_sim.live.simulation.LiveSimulation`.
    """

    def __init__(self, sim) -> None:
        self.sim = sim
        self._win = self._snapshot()

    def _snapshot(self) -> tuple[int, int, int]:
        sim = self.sim
        return sim.steps_secondary, sim.steps, sim.solver_resets

    def start(self) -> None:
        """Open a window at the current step."""
        self._win = self._snapshot()

    def report(self, lead: str) -> HealthReport:
        """The report of the window that ends now (and open the next one); its summary starts
        with ``lead`` (the node: pacing and real-time factor)."""
        sim = self.sim
        sec0, steps0, res0 = self._win
        self._win = snap = self._snapshot()
        nsteps = snap[1] - steps0
        finite = sim.finite
        r = HealthReport(summary=f'{lead}, {sim.speed:.0f} rpm, load {sim.load:.2f}, DMF '
                                 f'{sim.region}')
        if not finite or snap[2] - res0:
            r.problem(f'solver restarted {snap[2] - res0}x (non-finite state)', ERROR)
        spring = sim.model.spring
        r.values = {
            'sim_time_s': f'{sim.t:.4f}',
            'steps': str(sim.steps), 'dt_s': f'{sim.dt:g}',
            'publish_rate_hz': f'{1.0 / (sim.stride * sim.dt):g}',
            'speed_rpm': f'{sim.speed:.3f}', 'speed_setpoint_rpm': fmt_num(sim.speed_setpoint),
            'load': f'{sim.load:.4f}', 'load_setpoint': fmt_num(sim.load_setpoint),
            'windup_rad': f'{sim.windup:.6f}', 'dmf_region': sim.region,
            'dmf_secondary_fraction': f'{(snap[0] - sec0) / nsteps if nsteps else 0.0:.4f}',
            'knee_crossings': str(sim.knee_crossings),
            'state_finite': str(finite).lower(), 'solver_resets': str(sim.solver_resets),
            'alpha': fmt_num(spring.alpha) if spring is not None else 'none',
            'theta_rad': fmt_num(spring.theta) if spring is not None else 'none',
            'load_set': str(getattr(sim.engine, 'load_set', '')),
        }
        r.values.update(peak_values(sim.peaks))
        return r


def peak_values(peaks) -> dict[str, str]:
    """The health values of a :class:`dmf_sim.live.peaks.WindupPeaks`: the peak wind-up and
    the DMF spring torque there, both signs, since ``peaks_since_s`` (the start or the last
    reset), and the end stops' travel margin and contacts for a spring with stops; without a
    DMF only ``peaks_since_s``."""
    d = peaks.as_dict()
    out = {'peaks_since_s': f'{d["since_s"]:.4f}'}
    if 'peak_windup_rad' in d:
        (w_lo, w_hi), (t_lo, t_hi) = d['peak_windup_rad'], d['peak_dmf_torque_nm']
        out.update(peak_windup_min_rad=f'{w_lo:.6f}', peak_windup_max_rad=f'{w_hi:.6f}',
                   peak_dmf_torque_min_nm=f'{t_lo:.1f}', peak_dmf_torque_max_nm=f'{t_hi:.1f}')
    if 'stop_contacts' in d:
        out.update(travel_margin_rad=f'{d["travel_margin_rad"]:.6f}',
                   stop_contacts=str(d['stop_contacts']))
    if 'peak_stop_torque_nm' in d:
        out['peak_stop_torque_nm'] = f'{d["peak_stop_torque_nm"]:.1f}'
    if 'friction_heat_j' in d:
        out['friction_heat_j'] = f'{d["friction_heat_j"]:.3f}'
    return out


class HealthMonitor:
    """Reports of a :class:`dmf_sim.live.run_loop.RunLoop` (and a recording, if any) per window:
    the simulation's part (:class:`SimulationHealth`), then pacing, lag, setpoints, recording.

    Args:
        loop: the run loop (simulation, pacer, lag statistics, inbox, stamps).
        recording: a :class:`dmf_sim.live.recording.RecordingControl`, or None.
        cpu_clock: process CPU time [s] (``time.process_time``).
    """

    def __init__(self, loop, recording=None, *,
                 cpu_clock: Callable[[], float] = time.process_time) -> None:
        self.loop, self.recording, self.cpu_clock = loop, recording, cpu_clock
        self.simulation = SimulationHealth(loop.sim)
        self.contributors: list[Callable[[HealthReport], None]] = []
        self._win: tuple | None = None

    def _snapshot(self, now: float) -> tuple:
        loop = self.loop
        return (now, loop.sim.t, self.cpu_clock(), loop.pacer.overruns,
                loop.inbox.total('rejected') + loop.refused_on_apply, loop.inbox.total('lost'))

    def start(self, now: float) -> None:
        """Open the first window at wall time ``now``."""
        self._win = self._snapshot(now)
        self.simulation.start()

    def report(self, now: float) -> HealthReport:
        """The report of the window that ends at ``now`` (and open the next one)."""
        if self._win is None:
            self.start(now)
        loop, sim, pacer = self.loop, self.loop.sim, self.loop.pacer
        w0, t0, c0, ovr0, rej0, lost0 = self._win
        self._win = snap = self._snapshot(now)
        wall = max(now - w0, 1e-9)
        rtf = (sim.t - t0) / wall
        new_overruns, new_rejected, new_lost = snap[3] - ovr0, snap[4] - rej0, snap[5] - lost0
        lw = loop.lag.take_window()
        late_max, busy_max = loop.take_tick_maxima()
        inbox, tb = loop.inbox, loop.time
        fast = pacer.fast

        r = self.simulation.report(f'{loop.mode} x{rtf:.3f}')
        if new_overruns:
            r.problem(f'{new_overruns} overrun(s)')
        if not fast and lw['n'] and lw['max'] > pacer.max_lag:
            r.problem(f'lag up to {lw["max"] * 1e3:.1f} ms')
        if new_rejected:
            r.problem(f'{new_rejected} setpoint(s) rejected')
        if new_lost:
            r.problem(f'{new_lost} setpoint(s) lost before they reached the node')
        r.values = {
            'pacing': loop.mode,
            'real_time_factor_target': 'max' if fast else f'{pacer.rtf:g}',
            'real_time_factor': f'{rtf:.4f}',
            'lag_ms': 'nan' if fast else _ms(loop.last_lag),
            'lag_p50_ms': _ms(lw['p50']), 'lag_p99_ms': _ms(lw['p99']),
            'lag_max_ms': _ms(lw['max']), 'lag_samples': str(lw['n']),
            'lag_p99_ms_total': _ms(loop.lag.total_percentile(99.0)),
            'lag_max_ms_total': _ms(loop.lag.max if loop.lag.count else math.nan),
            'max_lag_ms': f'{pacer.max_lag * 1e3:g}',
            'overruns': str(pacer.overruns), 'overrun_policy': pacer.policy,
            'skipped_s': f'{pacer.skipped:.4f}',
            'wall_minus_stamp_s': f'{loop.wall_minus_stamp_s():.4f}',
            'stamp_reanchors': str(tb.reanchors),
            'stamp_last_jump_s': f'{tb.last_jump_s:.4f}',
            'cpu_pct': f'{100.0 * (snap[2] - c0) / wall:.1f}',
            'tick_wake_late_max_ms': _ms(late_max),
            'tick_busy_max_ms': _ms(busy_max),
            'clock_published': str(loop.clock_on).lower(),
            **r.values,
            'setpoints_received': str(inbox.total('received')),
            'rejected_setpoints': str(snap[4]),
            'setpoints_lost': str(snap[5]),
        }
        rec = self.recording
        if rec is not None:
            if rec.error:
                r.problem(f'recording failed: {rec.error}')
            r.values.update({'recording': str(rec.active).lower(),
                             'bag_path': str(rec.path or ''),
                             'bag_messages': str(rec.message_count)})
        for contribute in self.contributors:
            contribute(r)
        return r
