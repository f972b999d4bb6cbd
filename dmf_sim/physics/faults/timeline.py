"""The ground truth of a run: which faults act when, combustion by combustion
(:class:`FaultTimeline`), and each start, end and misfire as a :class:`FaultEvent` (the key/value
layout of the ``faults/ground_truth`` statuses, read back with :func:`event_from_values`)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

import numpy as np

from dmf_sim.core.errors import ConfigError, one_line
from dmf_sim.physics.faults.combustion import CYCLE_RAD, WINDOW_OPEN_RAD, combustion_windows
from dmf_sim.physics.faults.fault import (
    COMBUSTION_KINDS,
    DMF_KINDS,
    SENSOR_KINDS,
    Fault,
    FaultSet,
)
from dmf_sim.physics.faults.parse import overlap_reason, parse_fault
from dmf_sim.physics.model import Driveline

__all__ = ['FaultEvent', 'FaultTimeline', 'event_from_values']


@dataclass(frozen=True)
class FaultEvent:
    """One ground-truth event: a fault's ``start`` or ``end``, or one ``misfire`` (a combustion
    that did not fire). ``t_s``/``psi_rad``: simulated time and crank angle where it happened
    (the end of the Newmark step the switch fell in). A misfire carries its cylinder, the
    combustion's index m (TDC at beta_k + 720 deg m) and its TDC crank angle."""

    what: str
    fault_id: int
    fault: Fault
    t_s: float
    psi_rad: float
    start_s: float
    end_s: float | None = None
    cylinder: int | None = None
    combustion: int | None = None
    tdc_rad: float | None = None

    @property
    def name(self) -> str:
        return f'fault {self.fault_id}'

    def values(self, stamp_ns=None) -> dict[str, str]:
        """The status's key -> value text (``faults/ground_truth``). ``stamp_ns``: simulated
        time [s] -> stamp [ns] (the node's stamp clock); without it the stamps are left
        empty."""
        def ns(t):
            return '' if t is None or stamp_ns is None else str(int(stamp_ns(t)))
        out = {'id': str(self.fault_id), 'kind': self.fault.kind,
               'targets': self.fault.target_text(), 'fault': self.fault.text(),
               'start_s': _num(self.start_s), 'end_s': _num(self.end_s),
               'start_ns': ns(self.start_s), 'end_ns': ns(self.end_s),
               'event_s': _num(self.t_s), 'event_ns': ns(self.t_s),
               'crank_angle_rad': _num(self.psi_rad)}
        if self.cylinder is not None:
            out.update({'cylinder': str(self.cylinder), 'combustion': str(self.combustion),
                        'tdc_crank_angle_rad': _num(self.tdc_rad),
                        'window_start_rad': _num(self.tdc_rad + WINDOW_OPEN_RAD),
                        'window_end_rad': _num(self.tdc_rad + WINDOW_OPEN_RAD + CYCLE_RAD)})
        return out

    def message(self) -> str:
        """One line for people (the status message starts with :attr:`what`)."""
        if self.what == 'misfire':
            return (f'misfire: cylinder {self.cylinder}, combustion {self.combustion} (TDC at '
                    f'{self.tdc_rad:.4f} rad)')
        return f'{self.what}: {self.fault.text()}'


def _num(v) -> str:
    return '' if v is None else f'{float(v):.12g}'


def event_from_values(message: str, values: Mapping[str, str]) -> dict[str, Any]:
    """A ground-truth status read back (a bag's ``faults/ground_truth``): what ('start', 'end',
    'misfire', 'active'), id, the fault (:class:`Fault`), times [s] and stamps [ns] (None where
    empty), and for a misfire its cylinder, combustion and TDC crank angle."""
    def f(key):
        v = values.get(key, '')
        return float(v) if v != '' else None

    def i(key):
        v = values.get(key, '')
        return int(v) if v != '' else None
    out = {'what': message.split(':', 1)[0].strip(), 'id': i('id'),
           'fault': parse_fault(values.get('fault', ''), f'fault {values.get("id", "")}'),
           'start_s': f('start_s'), 'end_s': f('end_s'), 'event_s': f('event_s'),
           'start_ns': i('start_ns'), 'end_ns': i('end_ns'), 'event_ns': i('event_ns'),
           'crank_angle_rad': f('crank_angle_rad')}
    if 'cylinder' in values:
        out.update({'cylinder': i('cylinder'), 'combustion': i('combustion'),
                    'tdc_crank_angle_rad': f('tdc_crank_angle_rad')})
    return out


@dataclass
class _Entry:
    """A fault on the timeline: pending (not started), armed (a single misfire waiting for its
    combustion), active, or ended."""

    id: int
    fault: Fault
    start_s: float
    end_s: float
    state: str = 'pending'
    started_s: float | None = None
    ended_s: float | None = None
    remaining: set = field(default_factory=set)     # single: cylinders not yet misfired
    open: int = 0                                  # single: its misfire windows not yet closed
    rng: Any = None                                # random at a rate: arrivals
    next_arrival_s: float = math.inf


class FaultTimeline:
    """Which faults act when, combustion by combustion: the ground truth of a run.

    Faults come from a schedule (:meth:`add` at time 0, in file order) or live (:meth:`add`
    with the current time); ids count from 1 in that order. The simulation asks :meth:`scan`
    with the time and crank angle at the end of each of the next steps: it returns how many
    steps run before the excitation or the DMF changes, having decided every combustion and
    time switch up to there. The state after a scan: :attr:`factors` (per-cylinder combustion
    factors in effect), :attr:`dmf` (active DMF faults, :attr:`dmf_version` counts their
    changes), :attr:`sensor_faults`, and the new :attr:`events` (taken with
    :meth:`take_events`).

    Time switches (a fault's start/end, a single misfire's time) apply at the end of the step
    whose end time reaches them; a combustion's factor is decided at the step whose end crank
    angle reaches its window opening (exact to one step). Random misfires: with
    ``probability``, combustion m of cylinder k misfires when a uniform number drawn from
    ``numpy.random.default_rng([seed, k, m])`` is below it (the same combustions whatever the
    chunks); with ``rate_per_s``, arrivals of a Poisson process of that rate seeded with
    ``seed`` from the fault's start each misfire the next combustion of a listed cylinder.
    """

    def __init__(self, line: Driveline, faults: Iterable[Fault] = ()) -> None:
        self.line = line
        self.n_cylinders = len(line.cylinders)
        self.beta = np.radians(np.asarray(line.firing_phases_deg, dtype=float))
        self.entries: list[_Entry] = []
        self.factors = np.ones(self.n_cylinders)
        self._all_fire = True
        self.dmf = FaultSet()
        self.dmf_version = 0
        self.events: list[FaultEvent] = []
        self._next_id = 1
        self._next_open: np.ndarray | None = None      # per cylinder: next window opening [rad]
        self._misfired: list[_Entry | None] = [None] * self.n_cylinders   # current combustion's
        for f in faults:
            self.add(f, 0.0)

    # ---- adding and ending ------------------------------------------------------------------
    def _live(self) -> list[_Entry]:
        return [e for e in self.entries if e.state != 'ended']

    def check(self, fault: Fault, now_s: float) -> str | None:
        """Why ``fault`` cannot be added now, or None: a window in the past or inverted, an
        overlap with a fault not ended, a DMF set that is no valid spring (the reason without
        the fault's name: the caller knows how to name it)."""
        start, end = fault.window(now_s)
        if fault.start_s is not None and start < now_s and not fault.single:
            start = now_s      # a window that started before now runs from now
        if end <= start and not fault.single:
            return (f'its window ends at {end:g} s, not after its start '
                    f'{start:g} s (simulated time now {now_s:.3f} s)')
        for e in self._live():
            w = (e.start_s, e.end_s)
            reason = overlap_reason(fault, (start, end), e.fault, w, f'fault {e.id} '
                                    f'({e.fault.kind})')
            if reason:
                return f'window {reason}'
        if fault.kind in DMF_KINDS:
            together = FaultSet(tuple(e.fault for e in self._live()
                                      if e.fault.kind in DMF_KINDS) + (fault,))
            try:
                together.apply_to_driveline(self.line)
            except ConfigError as exc:
                return f'with the DMF faults already set: {one_line(exc)}'
        return None

    def add(self, fault: Fault, now_s: float = 0.0) -> int:
        """Put ``fault`` on the timeline (``now_s``: the current simulated time, the start of
        a fault without ``start_s``); returns its id. ConfigError with :meth:`check`'s reason."""
        if reason := self.check(fault, now_s):
            raise ConfigError(f'{fault.label()}: {reason}')
        start, end = fault.window(now_s)
        start = max(start, now_s) if not fault.single else start
        entry = _Entry(self._next_id, fault, start, end if not fault.single else math.inf)
        if fault.single:
            entry.remaining = set(fault.cylinders)
        self._next_id += 1
        self.entries.append(entry)
        return entry.id

    def end(self, fault_id: int, t_s: float, psi_rad: float) -> bool:
        """End fault ``fault_id`` now (a parameter cleared); a single misfire not yet fired is
        dropped. Returns whether it was live."""
        for e in self.entries:
            if e.id == fault_id and e.state != 'ended':
                self._finish(e, t_s, psi_rad)
                return True
        return False

    def clear(self, t_s: float, psi_rad: float) -> list[int]:
        """End every fault now (``~/clear_faults``); returns their ids. A combustion in its
        window keeps its factor until its window closes."""
        ids = [e.id for e in self._live()]
        for e in self._live():
            self._finish(e, t_s, psi_rad)
        return ids

    def _finish(self, e: _Entry, t_s: float, psi_rad: float) -> None:
        was = e.state
        e.state = 'ended'
        e.ended_s = t_s
        if was == 'active':          # (a single misfire not fired yet just goes)
            self.events.append(FaultEvent('end', e.id, e.fault, t_s, psi_rad, e.started_s, t_s))
        if e.fault.kind in DMF_KINDS and was == 'active':
            self._update_dmf()

    def _update_dmf(self) -> None:
        dmf = FaultSet(tuple(e.fault for e in self.entries
                             if e.state == 'active' and e.fault.kind in DMF_KINDS))
        if dmf != self.dmf:
            self.dmf = dmf
            self.dmf_version += 1

    # ---- state ------------------------------------------------------------------------------
    def active(self) -> list[_Entry]:
        """The faults acting now (a single misfire while its combustion's window is open)."""
        return [e for e in self.entries if e.state == 'active']

    def active_set(self) -> FaultSet:
        return FaultSet(tuple(e.fault for e in self.active()))

    @property
    def sensor_faults(self) -> FaultSet:
        """The sensor faults acting now (applied by the sensor signal synthesis)."""
        return self.active_set().of_kinds(SENSOR_KINDS)

    @property
    def idle(self) -> bool:
        """Nothing will ever change: no fault pending or active, every cylinder healthy."""
        return self._all_fire and all(e.state == 'ended' for e in self.entries)

    def take_events(self) -> list[FaultEvent]:
        out, self.events = self.events, []
        return out

    def active_statuses(self) -> list[tuple[int, Fault, float]]:
        """(id, fault, start [s]) of each active fault (``faults/active``)."""
        return [(e.id, e.fault, e.started_s) for e in self.active()]

    # ---- stepping ---------------------------------------------------------------------------
    def _next_time(self) -> float:
        t = math.inf
        for e in self.entries:
            if e.state == 'pending':
                t = min(t, e.start_s)
            elif e.state == 'active' and not e.fault.single:
                t = min(t, e.end_s)
        return t

    def _combustion_relevant(self) -> bool:
        if not self._all_fire:
            return True
        return any(e.fault.kind in COMBUSTION_KINDS and e.state in ('active', 'armed')
                   for e in self.entries)

    def _init_openings(self, psi: float) -> None:
        self._next_open = np.array([combustion_windows(b, psi, psi + CYCLE_RAD)[0]
                                    for b in self.beta])

    def scan(self, t_ends: np.ndarray, psi_ends: np.ndarray) -> tuple[int, bool]:
        """Decide what happens over the next steps, whose end times [s] and crank angles [rad]
        are ``t_ends``/``psi_ends`` (increasing). Returns (steps to run, changed): changed True
        when :attr:`factors` or :attr:`dmf` change at the end of the last of those steps (run
        them with the old excitation, then apply the new one); else all steps are decided and
        nothing changes."""
        n = len(t_ends)
        if n == 0 or self.idle:
            return n, False
        self.entries = [e for e in self.entries
                        if e.state != 'ended' or any(e is m for m in self._misfired)]
        pos = 0
        while pos < n:
            t_next = self._next_time()
            jt = int(np.searchsorted(t_ends, t_next, side='left')) if math.isfinite(
                t_next) else n
            jt = max(jt, pos)
            jo = n
            if self._combustion_relevant():
                if self._next_open is None:
                    self._init_openings(float(psi_ends[max(pos - 1, 0)]))
                jo = max(int(np.searchsorted(psi_ends, self._next_open.min(), side='left')),
                         pos)
            else:
                self._next_open = None
            j = min(jt, jo)
            if j >= n:
                return n, False
            before = (self.factors.copy(), self.dmf_version)
            t, psi = float(t_ends[j]), float(psi_ends[j])
            while self._next_time() <= t:
                self._time_switch(t, psi)
            if self._combustion_relevant():
                if self._next_open is None:
                    self._init_openings(psi)
                while self._next_open.min() <= psi:
                    k = int(np.argmin(self._next_open))
                    self._opening(k, float(self._next_open[k]), t, psi)
                    self._next_open[k] += CYCLE_RAD
            changed = (before[1] != self.dmf_version
                       or not np.array_equal(before[0], self.factors))
            if changed:
                return j + 1, True
            pos = j + 1
        return n, False

    def _time_switch(self, t: float, psi: float) -> None:
        """Every start/end due at time t (in time order)."""
        due = []
        for e in self.entries:
            if e.state == 'pending' and e.start_s <= t:
                due.append((e.start_s, 0, e))
            elif e.state == 'active' and not e.fault.single and e.end_s <= t:
                due.append((e.end_s, 1, e))
        for _, what, e in sorted(due, key=lambda x: (x[0], x[1], x[2].id)):
            if what == 1:
                self._finish(e, t, psi)
                continue
            if e.fault.single:
                e.state = 'armed'
                continue
            e.state = 'active'
            e.started_s = t
            if e.fault.mode == 'random' and e.fault.rate_per_s is not None:
                e.rng = np.random.default_rng(e.fault.seed)
                e.next_arrival_s = e.start_s + e.rng.exponential(1.0 / e.fault.rate_per_s)
            self.events.append(FaultEvent('start', e.id, e.fault, t, psi, t))
            if e.fault.kind in DMF_KINDS:
                self._update_dmf()

    def _opening(self, k: int, psi_open: float, t: float, psi: float) -> None:
        """Cylinder k's window opens at ``psi_open``: close its last combustion, decide the
        next one's factor."""
        cyl = k + 1
        m = int(round((psi_open - self.beta[k] - WINDOW_OPEN_RAD) / CYCLE_RAD))
        last = self._misfired[k]
        self._misfired[k] = None
        if last is not None and last.fault.single:
            last.open -= 1
            if last.open == 0 and not last.remaining and last.state == 'active':
                last.state = 'ended'
                last.ended_s = t
                self.events.append(FaultEvent('end', last.id, last.fault, t, psi,
                                              last.started_s, t))
        by = None
        for e in self.entries:
            f = e.fault
            if f.kind != 'misfire' or cyl not in f.cylinders:
                continue
            if f.single and e.state in ('armed', 'active') and cyl in e.remaining:
                by = e
                e.remaining.discard(cyl)
                e.open += 1
                if e.state == 'armed':
                    e.state = 'active'
                    e.started_s = t
                    self.events.append(FaultEvent('start', e.id, f, t, psi, t))
                break
            if e.state != 'active':
                continue
            if f.mode == 'every_cycle':
                by = e
                break
            if f.mode == 'random':
                if f.probability is not None:
                    hit = np.random.default_rng([f.seed, cyl, m]).random() < f.probability
                else:
                    hit = e.next_arrival_s <= t
                    while e.next_arrival_s <= t:
                        e.next_arrival_s += e.rng.exponential(1.0 / f.rate_per_s)
                if hit:
                    by = e
                    break
        if by is not None:
            self._misfired[k] = by
            self.factors[k] = 0.0
            self._all_fire = False
            tdc = psi_open - WINDOW_OPEN_RAD
            self.events.append(FaultEvent('misfire', by.id, by.fault, t, psi, by.started_s,
                                          cylinder=cyl, combustion=m, tdc_rad=tdc))
            return
        factor = 1.0
        for e in self.entries:
            if e.state == 'active' and e.fault.kind == 'weak_cylinder' \
                    and e.fault.cylinders[0] == cyl:
                factor *= float(e.fault.factor)
        self.factors[k] = factor
        self._all_fire = bool(np.all(self.factors == 1.0))

