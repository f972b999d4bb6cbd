"""The engine load over a recording, from what the bag holds (step 2b of the bag analysis).

A recording's load can change (a load setpoint mid-way), and the harmonic balance must be solved
at the load each engine cycle ran at. The bag holds it in three places:

* ``/diagnostics``: the recording node's health status (its ``hardware_id`` is the node's full
  name) carries ``load`` (the load being simulated, ramped towards the setpoint) and
  ``load_setpoint``, a few times per second of wall time;
* the load setpoint topic (``engine/load_setpoint``, std_msgs/Float64), when it was recorded
  (``ros2 bag record -a``): when a change was commanded;
* ``custom_data`` (:class:`dmf_sim.bags.metadata.RunMetadata`): the load when recording started.

:func:`load_timeline` joins them into intervals of *known constant* load and intervals where the
load was *changing or unknown*: between two health statuses the load is known to be constant
only if both report the same load and the first reports it at its setpoint (not ramping); a
setpoint change recorded in between starts an unknown interval there. :meth:`LoadTimeline.
cycle_loads` gives each engine cycle its load, or NaN when the cycle touches an unknown interval
(such cycles are never compared with the HBM). Only what the bag states is used; where a value
had to be assumed, :attr:`LoadTimeline.notes` says so.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dmf_sim.analysis.order_bins import LOAD_TOLERANCE
from dmf_sim.bags.columns import Column

__all__ = ['LOAD_TOLERANCE', 'HEALTH_KEYS', 'HealthColumn', 'LoadTimeline', 'load_timeline',
           'describe_unknown', 'load_text']

# health status values read: the load simulated, its setpoint, the DMF's first drive stage
HEALTH_KEYS = ('load', 'load_setpoint', 'alpha', 'theta_rad')


def _number(text: Any) -> float:
    try:
        v = float(text)
    except (TypeError, ValueError):
        return math.nan
    return v if math.isfinite(v) else math.nan


class HealthColumn(Column):
    """``HEALTH_KEYS`` of the recording node's health status in ``/diagnostics``
    (diagnostic_msgs/DiagnosticArray): the status that carries them, of the node ``node`` (its
    full name, e.g. ``/truck1/driveline_node``) or of a node whose name starts with ``prefix``
    (e.g. ``/truck1/``) when given; NaN where a message has none."""

    def __init__(self, decoder, msgtype: str, node: str | None = None,
                 prefix: str | None = None) -> None:
        super().__init__(decoder, msgtype)
        self.width = len(HEALTH_KEYS)
        self.node, self.prefix = node, prefix

    def row(self, msg: Any) -> list[float]:
        for status in getattr(msg, 'status', ()):
            if self.node and status.hardware_id != self.node:
                continue
            if self.prefix and not status.hardware_id.startswith(self.prefix):
                continue
            values = {kv.key: kv.value for kv in status.values}
            if 'load' in values and 'load_setpoint' in values:
                return [_number(values.get(k)) for k in HEALTH_KEYS]
        return [math.nan] * self.width


@dataclass
class LoadTimeline:
    """Load over the recording as intervals ``[t0, t1)`` [ns] of constant load (``value``) or of
    changing / unknown load (``value`` NaN); before the first and after the last interval the
    load is unknown. ``sources`` names what was used; ``notes``, what had to be assumed."""

    t0_ns: np.ndarray
    t1_ns: np.ndarray
    value: np.ndarray
    sources: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    settings: dict[str, list[float]] = field(default_factory=dict)   # alpha/theta seen

    @property
    def levels(self) -> list[float]:
        """The distinct known loads, ascending."""
        out: list[float] = []
        for v in sorted(float(x) for x in self.value[np.isfinite(self.value)]):
            if not out or v - out[-1] > LOAD_TOLERANCE:
                out.append(v)
        return out

    def load_between(self, a_ns: float, b_ns: float) -> float:
        """The constant load over ``[a_ns, b_ns]``, else NaN (changing, unknown or mixed)."""
        first = int(np.searchsorted(self.t1_ns, a_ns, side='right'))
        if first >= len(self.t0_ns) or self.t0_ns[first] > a_ns:
            return math.nan
        last = int(np.searchsorted(self.t0_ns, b_ns, side='right')) - 1
        if last < first or self.t1_ns[last] < b_ns:
            return math.nan
        vals = self.value[first:last + 1]
        if not np.all(np.isfinite(vals)) or np.ptp(vals) > LOAD_TOLERANCE:
            return math.nan
        if last > first and np.any(self.t0_ns[first + 1:last + 1] != self.t1_ns[first:last]):
            return math.nan
        return float(vals[0])

    def cycle_loads(self, t_start_s: np.ndarray, t_end_s: np.ndarray, origin_ns: int
                    ) -> np.ndarray:
        """Load of each engine cycle (times in s from ``origin_ns``); NaN where unknown."""
        return np.array([self.load_between(origin_ns + a * 1e9, origin_ns + b * 1e9)
                         for a, b in zip(t_start_s, t_end_s)], float)


def load_text(load: float | Sequence[float]) -> str:
    """A load, or the loads compared (a list), as text: ``0.5`` or ``0.5, 1``."""
    if isinstance(load, (list, tuple)):
        return ', '.join(f'{v:g}' for v in load)
    return f'{load:g}'


def _same(a: float, b: float) -> bool:
    return math.isfinite(a) and math.isfinite(b) and abs(a - b) <= LOAD_TOLERANCE


def _fmt_s(t_ns: float, origin_ns: int) -> str:
    return f'{(t_ns - origin_ns) * 1e-9:.2f} s'


def load_timeline(health: tuple[np.ndarray, np.ndarray] | None,
                  setpoints: tuple[np.ndarray, np.ndarray] | None,
                  start_load: float | None, start_ns: int, end_ns: int) -> LoadTimeline | None:
    """The load timeline of a recording (see the module docstring), None if the bag states no
    load at all.

    Args:
        health: (times [ns], rows of ``HEALTH_KEYS``) of the node's health statuses.
        setpoints: (times [ns], load setpoints) of the recorded setpoint topic.
        start_load: the load ``custom_data`` says the recording started at.
        start_ns, end_ns: the recording's first and last crank-angle sample [ns].
    """
    pts: list[tuple[float, float, float]] = []      # (time, load, setpoint)
    sources = []
    if start_load is not None and math.isfinite(start_load):
        pts.append((float(start_ns), float(start_load), float(start_load)))
        sources.append('metadata (start of the recording)')
    settings: dict[str, list[float]] = {}
    if health is not None and len(health[0]):
        t, rows = health
        ok = np.isfinite(rows[:, 0])
        if ok.any():
            sources.append(f'/diagnostics health status ({int(ok.sum())} messages)')
            pts += [(float(a), float(r[0]), float(r[1])) for a, r in zip(t[ok], rows[ok])]
            for k, key in enumerate(HEALTH_KEYS[2:], 2):
                seen = rows[ok, k][np.isfinite(rows[ok, k])]
                if len(seen):
                    settings[key] = sorted({float(v) for v in seen})
    if not pts:
        if setpoints is None or not len(setpoints[0]):
            return None
    pts.sort(key=lambda p: p[0])
    notes: list[str] = []
    t0, t1, val, before = [], [], [], []     # before: the load up to a change inside, or NaN
    for (ta, la, sa), (tb, lb, _) in zip(pts[:-1], pts[1:]):
        at_setpoint = not math.isfinite(sa) or _same(sa, la)
        t0.append(ta)
        t1.append(tb)
        val.append(la if at_setpoint and _same(la, lb) else math.nan)
        before.append(la if at_setpoint else math.nan)
    if pts:
        ta, la, sa = pts[-1]
        if (not math.isfinite(sa) or _same(sa, la)) and end_ns >= ta:
            t0.append(ta)
            t1.append(float(end_ns) + 1.0)
            val.append(la)
            before.append(la)
            period = float(np.median(np.diff([p[0] for p in pts]))) if len(pts) > 1 else 0.0
            if len(pts) > 1 and end_ns - ta > period:
                notes.append(f'load {la:g} assumed to hold from the last health status '
                             f'({_fmt_s(ta, start_ns)}) to the end of the recording')
    if setpoints is not None and len(setpoints[0]):
        sources.append(f'load setpoint topic ({len(setpoints[0])} messages)')
        t0, t1, val = _cut_at_setpoints(t0, t1, val, before, *setpoints)
    t0a, t1a, va = np.array(t0, float), np.array(t1, float), np.array(val, float)
    if len(pts) == 1 and pts[0][0] == float(start_ns) and health is None and setpoints is None:
        return None                           # only the start value: the caller's default rule
    return LoadTimeline(t0a, t1a, va, sources, notes, settings)


def _cut_at_setpoints(t0: list, t1: list, val: list, before: list, ts: np.ndarray,
                      sp: np.ndarray) -> tuple[list, list, list]:
    """A recorded setpoint change splits its interval: the load held before it (the
    interval's constant load, or its start load when the interval ends at another load) is
    known up to the setpoint; from there to the interval's end the load ramps (unknown)."""
    t0, t1, val, before = list(t0), list(t1), list(val), list(before)
    for t, v in sorted(zip(ts.tolist(), sp.tolist())):
        for i in range(len(t0)):
            if not t0[i] <= t < t1[i]:
                continue
            held = val[i] if math.isfinite(val[i]) else before[i]
            if math.isfinite(held) and not _same(held, v):
                t0.insert(i + 1, t)
                t1.insert(i + 1, t1[i])
                val.insert(i + 1, math.nan)
                before.insert(i + 1, math.nan)
                t1[i], val[i] = t, held
            break
    return t0, t1, val


def describe_unknown(timeline: LoadTimeline, loads: Sequence[float], origin_ns: int) -> str:
    """One line about the cycles whose load is unknown (changing within them)."""
    n = int(np.count_nonzero(~np.isfinite(np.asarray(loads, float))))
    spans = [f'{_fmt_s(a, origin_ns)}-{_fmt_s(b, origin_ns)}'
             for a, b, v in zip(timeline.t0_ns, timeline.t1_ns, timeline.value)
             if not math.isfinite(v)]
    return (f'{n} engine cycle(s) ran while the load was changing or unknown'
            + (f' ({", ".join(spans[:5])}{" ..." if len(spans) > 5 else ""})' if spans else '')
            + ': not binned with a load, never steady, not compared with the HBM')
