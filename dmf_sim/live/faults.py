"""Faults in the live node without ROS: requests in, ground truth out.

Requests come three ways, all in the fault grammar of :mod:`dmf_sim.physics.faults`:

* the topic ``faults/inject`` (``std_msgs/String``, one fault or a list in YAML flow style):
  :meth:`LiveFaults.offer` (any thread) parses and validates it on arrival and queues it; the
  tick thread adds it to the timeline at the start of the next tick (:meth:`LiveFaults.apply`),
  where the checks that need the timeline run (overlaps, a valid spring, a motored engine
  model). A refusal is counted, logged with its reason and shown in ``/diagnostics``; the node
  never stops for it. A request may carry ``request_id: <text>`` (beside ``kind``): the node
  applies a request id once, so a sender may repeat a request until it is acknowledged
  (``dmf-sim fault`` does) without injecting it twice;
* one string parameter per fault kind (:data:`FAULT_PARAMETERS`): its value is the fault(s) of
  that kind the parameter holds, '' none. The on-set callback validates
  (:meth:`LiveFaults.check_parameter`, the parameter keeps its value when refused), the
  post-set callback applies (:meth:`LiveFaults.apply_parameter`): the faults the parameter held
  end, the new ones start. Setting a single misfire again fires it again;
* the service ``~/clear_faults``: every fault ends now (:meth:`LiveFaults.clear`).

Times in a request (``start_s``, ``end_s``, ``at_s``) are the node's simulated time
(``engine/crank_angle``'s stamps minus the start); absent, a fault starts now and lasts until
cleared.

Ground truth: every event of the timeline (a fault's start or end, each misfired combustion)
becomes one ``DiagnosticStatus`` on ``faults/ground_truth`` (:func:`ground_truth_statuses`,
one message each, latched keep-last 100) and the set of active faults one
``DiagnosticArray`` on ``faults/active`` (:func:`active_statuses`, latched depth 1, an empty
array when none) whenever it changes. ``dmf-sim run`` writes the same into its bags.
"""
from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from typing import Any

from dmf_sim.core.errors import ConfigError, one_line
from dmf_sim.core.paths import parse_yaml
from dmf_sim.monitor.messages import StatusData
from dmf_sim.physics.faults import (
    DMF_KINDS,
    SENSOR_KINDS,
    FaultEvent,
    FaultTimeline,
    parse_request,
)

__all__ = ['REQUEST_ID', 'REQUEST_IDS_KEPT', 'FAULT_PARAMETERS', 'GROUND_TRUTH_STREAM',
           'ACTIVE_STREAM', 'OK', 'WARN', 'ground_truth_statuses', 'active_statuses',
           'ActiveFaults', 'LiveFaults']

OK, WARN = 0, 1                    # diagnostic_msgs/DiagnosticStatus levels
REQUEST_ID = 'request_id'          # the key of a request's id on faults/inject
REQUEST_IDS_KEPT = 10_000          # request ids remembered (a repeat of an older one is new)
GROUND_TRUTH_STREAM = 'fault_ground_truth'      # keys of dmf_sim.live.streams.STREAMS
ACTIVE_STREAM = 'fault_active'

FAULT_PARAMETERS: dict[str, tuple[tuple[str, ...], str]] = {
    'fault_misfire': (('misfire',), "Misfire(s) held by this parameter, e.g. '{cylinders: [3], "
                      "mode: every_cycle}' (YAML flow; kind may be left out); '' = none. "
                      'Setting it ends what it held and starts this'),
    'fault_weak_cylinder': (('weak_cylinder',), "Weak cylinder(s), e.g. '{cylinder: 5, factor: "
                            "0.7}'; '' = none"),
    'fault_dmf': (DMF_KINDS, "DMF fault(s), e.g. '{kind: dmf_stiffness, stage: 2, factor: "
                  "0.5}' or '{kind: dmf_broken, stage: 2}' or '{kind: dmf_damping, factor: 3}'; "
                  "'' = none"),
    'fault_sensor': (SENSOR_KINDS, "Sensor fault(s), e.g. '{kind: bus_signal, signal: "
                     "engine_speed, mode: stuck}'; '' = none"),
}


def _values(event_or_entry: dict[str, str]) -> tuple[tuple[str, str], ...]:
    return tuple(event_or_entry.items())


def ground_truth_statuses(events: Sequence[FaultEvent], stamp_ns: Callable[[float], int],
                          node: str) -> list[tuple[int, StatusData]]:
    """(stamp [ns], status) of each event: name ``fault <id>``, message ``start: ...``,
    ``end: ...`` or ``misfire: ...``, values :meth:`FaultEvent.values` (``stamp_ns``:
    simulated time [s] -> the node's stamp clock [ns]). Level WARN for a start or a misfire,
    OK for an end."""
    return [(int(stamp_ns(e.t_s)),
             StatusData(OK if e.what == 'end' else WARN, e.name, e.message(),
                        _values(e.values(stamp_ns)), node)) for e in events]


def active_statuses(active, stamp_ns: Callable[[float], int], node: str) -> list[StatusData]:
    """One status per active fault (``faults/active``) of ``active``, (id, fault, start [s])
    each (:meth:`FaultTimeline.active_statuses`, :class:`ActiveFaults`): name ``fault <id>``,
    message ``active: <the fault>``, values id, kind, targets, fault, start_s, start_ns."""
    out = []
    for fault_id, fault, start_s in active:
        values = {'id': str(fault_id), 'kind': fault.kind, 'targets': fault.target_text(),
                  'fault': fault.text(), 'start_s': f'{start_s:.12g}',
                  'start_ns': str(int(stamp_ns(start_s)))}
        out.append(StatusData(WARN, f'fault {fault_id}', f'active: {fault.text()}',
                              _values(values), node))
    return out


def _split_request_id(text, where: str) -> tuple[Any, str | None]:
    """(the request without its ``request_id`` keys, the id or None)."""
    spec = parse_yaml(text, where) if isinstance(text, str) else text
    request_id = None
    for item in (spec if isinstance(spec, list) else [spec]):
        if isinstance(item, dict) and REQUEST_ID in item:
            value = item.pop(REQUEST_ID)
            request_id = str(value) if request_id is None else request_id
    return ('' if spec is None else spec), request_id


class ActiveFaults:
    """The active set followed from the events alone (``dmf-sim run`` writes chunks the
    integrating thread has left behind): :meth:`update` with a chunk's events returns whether
    the set changed; iterate for (id, fault, start [s])."""

    def __init__(self) -> None:
        self._active: dict[int, tuple] = {}

    def update(self, events: Sequence[FaultEvent]) -> bool:
        changed = False
        for e in events:
            if e.what == 'start':
                self._active[e.fault_id] = (e.fault_id, e.fault, e.t_s)
                changed = True
            elif e.what == 'end':
                changed |= self._active.pop(e.fault_id, None) is not None
        return changed

    def __iter__(self):
        return iter(list(self._active.values()))


class LiveFaults:
    """The faults of one live simulation: requests from the topic, the parameters and the
    clear service; the ground truth to publish.

    Args:
        sim: the :class:`~dmf_sim.live.simulation.LiveSimulation` (its timeline is created).
        log: info/warning/error logger.
        node: the node's full name (the statuses' hardware_id).
        wheels, signals: the tooth wheels' and bus signals' names (None: not checked), as
            :func:`~dmf_sim.physics.faults.parse_fault` takes them.
    """

    def __init__(self, sim, log, node: str, *, wheels=None, signals=None) -> None:
        self.sim, self.log, self.node = sim, log, node
        self.timeline = sim.faults if sim.faults is not None else sim.attach_faults()
        self.wheels, self.signals = wheels, signals
        self._lock = threading.Lock()
        self._pending: list[tuple[str, Any]] = []
        self.received = 0
        self.refused = 0
        self.last_refused = ''
        self.params: dict[str, list[int]] = {name: [] for name in FAULT_PARAMETERS}
        self._active_dirty = True       # faults/active to publish (at the first tick: empty)
        self._refused_reported = 0
        self._seen: dict[str, None] = {}    # request ids applied (insertion order)
        self.repeated = 0

    # ---- parsing ----------------------------------------------------------------------------
    def parse(self, text: str, where: str, kinds: Sequence[str] | None = None):
        kw = {'line': self.sim.line, 'wheels': self.wheels, 'signals': self.signals}
        if kinds is not None:
            kw['kinds'] = tuple(kinds)
        return parse_request(text, where, **kw)

    def _refuse(self, reason: str) -> str:
        with self._lock:
            self.refused += 1
            self.last_refused = reason
        self.log.warning(f'fault request refused: {reason} ({self.refused} refused so far)')
        return reason

    # ---- the topic (any thread) -------------------------------------------------------------
    def offer(self, text) -> str | None:
        """A request from ``faults/inject``: parsed now, queued for the next tick; returns the
        reason it was refused, or None (also for a repeat of a request id already seen)."""
        try:
            spec, request_id = _split_request_id(text, 'faults/inject')
        except ConfigError as exc:
            with self._lock:
                self.received += 1
            return self._refuse(one_line(exc))
        with self._lock:
            if request_id is not None:
                if request_id in self._seen:
                    self.repeated += 1
                    return None
                self._seen[request_id] = None
                if len(self._seen) > REQUEST_IDS_KEPT:
                    self._seen.pop(next(iter(self._seen)))
            self.received += 1
        try:
            faults = self.parse(spec, 'faults/inject')
        except ConfigError as exc:
            return self._refuse(one_line(exc))
        if not faults:
            return self._refuse("faults/inject: empty request (send a fault mapping, e.g. "
                                "'{kind: misfire, cylinders: [3]}')")
        with self._lock:
            self._pending.append(('faults/inject', faults))
        return None

    # ---- the tick thread --------------------------------------------------------------------
    def _add(self, faults, where: str) -> tuple[list[int], str | None]:
        """Add all of ``faults`` or none (the reason)."""
        tl, ids = self.timeline, []
        for i, f in enumerate(faults):
            if reason := self.sim.check_fault(f):
                for fault_id in ids:
                    tl.end(fault_id, self.sim.t, self.sim.psi)
                    tl.entries = [e for e in tl.entries if e.id != fault_id]
                name = f'{where}[{i}] ({f.kind})' if len(faults) > 1 else f'{where} ({f.kind})'
                return [], f'{name}: {reason}'
            ids.append(tl.add(f, self.sim.t))
        return ids, None

    def apply(self) -> None:
        """Add the queued topic requests to the timeline (start of a tick, under the tick
        lock); a request the timeline refuses is counted and logged."""
        if not self._pending:
            return
        with self._lock:
            pending, self._pending = self._pending, []
        for where, faults in pending:
            ids, reason = self._add(faults, where)
            if reason:
                self._refuse(reason)
            else:
                self.log.info(f'{where}: fault {", ".join(map(str, ids))} added: '
                              + '; '.join(f.text() for f in faults))

    # ---- parameters (on-set: validate, post-set: apply; under the tick lock) ---------------
    def check_parameter(self, name: str, value) -> str | None:
        """Why parameter ``name`` may not take ``value``, or None."""
        kinds, _ = FAULT_PARAMETERS[name]
        try:
            faults = self.parse(value, name, kinds)
        except ConfigError as exc:
            return one_line(exc)
        # the parameter's own faults end when it is set: check against the others
        tl = self.timeline
        mine = set(self.params[name])
        saved = [(e, e.state) for e in tl.entries if e.id in mine and e.state != 'ended']
        for e, _ in saved:
            e.state = 'ended'
        try:
            for i, f in enumerate(faults):
                if reason := self.sim.check_fault(f):
                    return f'{name} ({f.kind}): {reason}'
            if len(faults) > 1:
                probe = FaultTimeline(self.sim.line)
                for i, f in enumerate(faults):
                    if reason := probe.check(f, self.sim.t):
                        return f'{name}[{i}] ({f.kind}): {reason}'
                    probe.add(f, self.sim.t)
        finally:
            for e, state in saved:
                e.state = state
        return None

    def apply_parameter(self, name: str, value) -> str:
        """End the faults parameter ``name`` held, start ``value``'s; returns what it did."""
        kinds, _ = FAULT_PARAMETERS[name]
        sim, tl = self.sim, self.timeline
        for i in self.params[name]:
            tl.end(i, sim.t, sim.psi)
        self.params[name] = []
        faults = self.parse(value, name, kinds)      # checked by check_parameter
        ids, reason = self._add(faults, name)
        if reason:                                   # changed between check and apply
            return self._refuse(reason)
        self.params[name] = ids
        self._active_dirty = True
        msg = (f'{name}: fault {", ".join(map(str, ids))} started: {value}' if ids
               else f'{name}: cleared')
        self.log.info(msg)
        return msg

    def clear(self) -> str:
        """End every fault now (``~/clear_faults``); returns what it did."""
        ids = self.timeline.clear(self.sim.t, self.sim.psi)
        for name in self.params:
            self.params[name] = []
        with self._lock:
            self._pending = []
        self._active_dirty = True
        msg = (f'cleared faults {", ".join(map(str, ids))}' if ids else 'no fault to clear')
        self.log.info(msg)
        return msg

    # ---- ground truth out -------------------------------------------------------------------
    def publish(self, sink, stamp_ns: Callable[[float], int],
                events: Sequence[FaultEvent] = ()) -> None:
        """Publish ``events`` and what the timeline holds besides (cleared/ended faults) on
        ``faults/ground_truth``, one message each, and ``faults/active`` when it changed
        (tick thread)."""
        events = list(events) + self.timeline.take_events()
        for stamp, status in ground_truth_statuses(events, stamp_ns, self.node):
            sink.publish_statuses(GROUND_TRUTH_STREAM, [status], stamp)
        if self._active_dirty or any(e.what != 'misfire' for e in events):
            self._active_dirty = False
            sink.publish_statuses(ACTIVE_STREAM, active_statuses(
                self.timeline.active_statuses(), stamp_ns, self.node), int(stamp_ns(self.sim.t)))

    def health(self, report) -> None:
        """A health contributor: the request counters (WARN for requests refused in the
        window), the active faults and the last refusal."""
        active = self.timeline.active_statuses()
        new = self.refused - self._refused_reported
        self._refused_reported = self.refused
        if new:
            report.problem(f'{new} fault request(s) refused: {self.last_refused}')
        report.values.update({'fault_requests': str(self.received),
                              'fault_requests_repeated': str(self.repeated),
                              'fault_requests_refused': str(self.refused),
                              'faults_active': str(len(active)),
                              'fault_last_refused': self.last_refused})

