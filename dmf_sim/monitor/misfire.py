"""Live misfire detection in the node's monitor: the reference detector on the tooth edges of
the last engine cycles, off the real-time path (no ROS).

A stack's misfire detector runs on what the node publishes: the edge times of the two tooth
wheels around the DMF (``sensors/<wheel>/edges``) and the engine-cycle phase a cam sensor would
give (here the crank angle). The monitor runs the package's reference detector
(:func:`dmf_sim.analysis.misfire_detector.detect_edges`, the same function ``dmf-sim detect``
runs on a bag) on them live, so a team sees what a DMF-aware detector makes of its run while it
runs, next to the faults' ground truth:

* the tick thread hands each chunk's edges of the two wheels and the crank angle at the chunk's
  end to :class:`MisfireTracker` (:meth:`~MisfireTracker.add`: a copy of a few edges); once per
  engine cycle it returns a :class:`MisfireWindow`, the edges of the last
  :data:`HISTORY_CYCLES` engine cycles;
* the monitor's cycle worker analyses the window (:func:`analyze_window`): every firing
  interval with a full baseline on both sides is scored (eq. M1-M2 of the detector, the spring's
  work from the wind-up of the two wheels and the DMF characteristic of the node's model);
* the monitor reports each interval once, the first time it is scored (:class:`Detection`),
  on ``faults/detections`` (:func:`dmf_sim.monitor.messages.detection_statuses`).

An interval is scored once ``window`` intervals follow it (the right baseline), so a misfire
is reported about ``window`` firing intervals plus up to one engine cycle after its TDC (about
0.25 s at 1200 rpm with the defaults). The gain of the spring's work is fitted as on a bag,
to every interval so far (:class:`~dmf_sim.analysis.misfire_detector.GainSums`, learned
window by window; a window's own few cycles would let a load step's swing move it), and the
outliers are trimmed per window, so scores differ slightly from ``dmf-sim detect``'s on the
same edges. Like a controller's detector it knows the nominal DMF, not a worn one.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from dmf_sim.analysis.misfire_detector import (
    DEFAULT_THRESHOLD,
    DEFAULT_WINDOW,
    GainSums,
    detect_edges,
)
from dmf_sim.analysis.tooth_signals import WheelEdges

__all__ = ['HISTORY_CYCLES', 'MIN_CYCLES', 'dmf_wheels', 'MisfireWindow', 'Detection',
           'MisfireTracker', 'analyze_window']

HISTORY_CYCLES = 8        # engine cycles of edges per analysis (the gain's fit, both baselines)
MIN_CYCLES = 4.0          # engine cycles of edges before the first analysis
ENGINE_CYCLE_RAD = 4.0 * math.pi


def dmf_wheels(line) -> tuple[str, str] | None:
    """The names of the tooth wheels on the DMF's primary and secondary elements (the element
    before the DMF element and the DMF element itself), or None when the driveline has no DMF or
    lacks either wheel: the live detector needs both."""
    if line.dmf is None or not line.sensors:
        return None
    i = line.index(line.dmf.element)
    if i == 0:
        return None
    by_element = {}
    for w in line.sensors.tooth_wheels:
        by_element.setdefault(w.element, w.name)
    primary = by_element.get(line.elements[i - 1].name)
    secondary = by_element.get(line.elements[i].name)
    return (primary, secondary) if primary and secondary else None


@dataclass(frozen=True)
class MisfireWindow:
    """The edges of the last engine cycles and the crank angle over them (simulated ns), the
    detector's settings, the engine cycle it was cut at (``cycle``) and the gain's fit learned
    from the windows before (``learned``, a copy)."""

    crank: WheelEdges
    secondary: WheelEdges
    crank_t_ns: np.ndarray
    crank_psi: np.ndarray
    firing_phases_rad: tuple[float, ...]
    threshold: float
    window: int
    cycle: int
    learned: GainSums | None = None


@dataclass(frozen=True)
class Detection:
    """One scored firing interval: the time of its TDC [ns of simulated time], its cylinder
    (1-based) and combustion number, the TDC's crank angle [rad] (as the ground truth gives a
    misfire's), the segment speed [rpm], the score (M2), whether it raised an alarm, and the
    mean DMF wind-up over the interval from the two wheels [rad] (eq. W1 of
    :mod:`dmf_sim.analysis.windup_estimate`)."""

    t_ns: int
    cylinder: int
    combustion: int
    tdc_crank_angle_rad: float
    speed_rpm: float
    score: float
    alarm: bool
    windup_rad: float = float('nan')


class MisfireTracker:
    """Collects the edges of the two wheels around the DMF in the tick thread and cuts a
    :class:`MisfireWindow` once per engine cycle (see the module docstring).

    Args:
        wheels: the primary and secondary wheels (:class:`~dmf_sim.physics.sensors.ToothWheel`).
        firing_phases_rad: the cylinders' firing phases [rad] (the driveline's).
        threshold, window: the detector's alarm threshold and baseline (intervals each side).
    """

    def __init__(self, wheels: Sequence, firing_phases_rad: Sequence[float], *,
                 threshold: float = DEFAULT_THRESHOLD, window: int = DEFAULT_WINDOW) -> None:
        self.wheels = tuple(wheels)
        self.names = tuple(w.name for w in self.wheels)
        self.firing_phases_rad = tuple(float(b) for b in firing_phases_rad)
        self.threshold, self.window = float(threshold), int(window)
        self.learned = GainSums()
        self.clear()

    def clear(self) -> None:
        """Forget the edges (a reset: the motion jumped)."""
        self._edges: list[list[np.ndarray]] = [[] for _ in self.wheels]
        self._psi: list[tuple[int, float]] = []
        self._next_cycle: int | None = None

    def add(self, chunk, t_s: float, psi_rad: float) -> MisfireWindow | None:
        """A chunk's sensor signals (:class:`~dmf_sim.physics.sensor_signals.SensorChunk`) and
        the crank angle ``psi_rad`` at its end ``t_s`` [s]; a window when an engine cycle ended."""
        t_ns = int(round(t_s * 1e9))
        if self._psi and (t_ns < self._psi[-1][0] or psi_rad < self._psi[-1][1]):
            self.clear()                  # time or the crank went back: a reset
        for w, name in enumerate(self.names):
            rows = chunk.edges(name)
            if len(rows):
                self._edges[w].append(np.column_stack([rows.time_ns, rows.tooth, rows.flags]))
        self._psi.append((t_ns, float(psi_rad)))
        cycle = math.floor(psi_rad / ENGINE_CYCLE_RAD)
        if self._next_cycle is None:
            self._next_cycle = cycle + 1
        if cycle < self._next_cycle:
            return None
        self._next_cycle = cycle + 1
        return self._cut(cycle)

    def _cut(self, cycle: int) -> MisfireWindow | None:
        t_psi = np.array(self._psi)
        psi_now = t_psi[-1, 1]
        keep_psi = t_psi[:, 1] >= psi_now - HISTORY_CYCLES * ENGINE_CYCLE_RAD
        first = max(int(np.argmax(keep_psi)) - 1, 0)        # one point before the span
        t_psi = t_psi[first:]
        self._psi = [(int(t), p) for t, p in t_psi]
        start_ns = int(t_psi[0, 0])
        edges = []
        for w in range(len(self.wheels)):
            rows = np.concatenate(self._edges[w]) if self._edges[w] else np.zeros((0, 3), np.int64)
            rows = rows[rows[:, 0] >= start_ns]
            self._edges[w] = [rows]
            edges.append(rows)
        if psi_now - t_psi[0, 1] < MIN_CYCLES * ENGINE_CYCLE_RAD or min(len(e) for e in edges) < 4:
            return None
        crank, secondary = (WheelEdges(wh, e[:, 0].copy(), e[:, 1].copy(), e[:, 2].copy())
                            for wh, e in zip(self.wheels, edges))
        return MisfireWindow(crank, secondary, t_psi[:, 0].astype(np.int64), t_psi[:, 1].copy(),
                             self.firing_phases_rad, self.threshold, self.window, cycle,
                             replace(self.learned))


def analyze_window(window: MisfireWindow,
                   spring_torque: Callable[[np.ndarray], np.ndarray] | None = None
                   ) -> tuple[list[Detection], dict[str, np.ndarray]]:
    """Score every firing interval of the window that has a full baseline both sides
    (:func:`~dmf_sim.analysis.misfire_detector.detect_edges`); ``spring_torque``: the DMF
    characteristic T(phi) [Nm] of the node's model. Returns the detections and the window's
    terms of the gain's fit (for :meth:`GainSums.add` of the tracker's ``learned``). Runs in
    the monitor's worker."""
    try:
        sc = detect_edges(window.crank, window.secondary, window.crank_t_ns, window.crank_psi,
                          window.firing_phases_rad, spring_torque=spring_torque,
                          threshold=window.threshold, window=window.window,
                          learned=window.learned)
    except (ValueError, np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError):
        return [], {}                 # too few edges for a fit (the sensors dropped them)
    rpm = 60.0 / (2.0 * math.pi)
    return [Detection(int(o + round(t * 1e9)), int(c), int(m), float(tdc), float(om * rpm),
                      float(s), bool(a), float(wu))
            for o, t, c, m, tdc, om, s, a, wu in zip(
                sc['origin_ns'], sc['t_s'], sc['cylinder'], sc['combustion'], sc['tdc_rad'],
                sc['omega'], sc['score'], sc['alarm'], sc['windup_rad'])], \
        {k: v for k, v in sc.items() if k.startswith('diff_')}
