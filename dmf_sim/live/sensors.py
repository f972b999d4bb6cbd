"""The live core's sensors, without ROS: per chunk of Newmark steps, the sensor signals of that
chunk, and the messages that carry them.

:class:`LiveSensors` is what :class:`dmf_sim.live.simulation.LiveSimulation` holds when its
sensors are on (the node's ``sensors`` parameter, ``dmf-sim run`` without ``--no-sensors``):
it has the integrator write the sensor elements' DOFs every step into its rows
(:meth:`next_rows`, one slice per kernel call of a chunk), and turns a chunk's rows into
signals (:meth:`finish`: :class:`dmf_sim.physics.sensor_signals.SensorSynthesizer`). With the
sensors off there is no :class:`LiveSensors`: the kernel tracks nothing and nothing else runs.

:class:`SensorMessages` turns a chunk's signals into the node's messages (stream key, log time,
CDR bytes; layouts in :mod:`dmf_sim.bags.sensor_messages`): an edge batch per wheel with edges,
logged at the chunk's end, and a Float64 per bus value delivered, logged at its delivery.
"""
from __future__ import annotations

import math
from dataclasses import replace
from typing import Sequence

import numpy as np

from dmf_sim.bags.sensor_messages import batch_log_ns, encode_edges, float64_bytes
from dmf_sim.live.streams import bus_key, edge_key
from dmf_sim.physics.faults import SENSOR_KINDS
from dmf_sim.physics.sensor_signals import SensorChunk, SensorSynthesizer

__all__ = ['LiveSensors', 'SensorMessages', 'fault_windows']

_INITIAL_ROWS = 256           # steps per chunk the row buffer holds before it grows


def fault_windows(timeline) -> list:
    """The sensor faults of a :class:`~dmf_sim.physics.faults.FaultTimeline` not ended yet,
    each with the window it acts in (``start_s``/``end_s``: started or scheduled start, ended or
    scheduled end; None = open), as the synthesis applies them per edge and per bus value. Taken
    before a chunk runs: nothing starts or ends inside it but by these windows (live requests
    come between chunks)."""
    out = []
    for e in timeline.entries:
        if e.fault.kind not in SENSOR_KINDS or e.state == 'ended':
            continue
        start = e.started_s if e.started_s is not None else e.start_s
        out.append(replace(e.fault, start_s=start, duration_s=None,
                           end_s=None if math.isinf(e.end_s) else e.end_s))
    return out


class LiveSensors:
    """The sensor signals of a live simulation's chunks (see the module docstring).

    Args:
        line: the driveline (its ``sensors``).
        model: its reduced model (which DOF carries each sensor's element).
    """

    def __init__(self, line, model) -> None:
        self.synth = SensorSynthesizer(line.sensors, model)
        self._rows = np.zeros((_INITIAL_ROWS, self.synth.track_columns))
        self._used = 0
        self.faults: Sequence = ()

    @property
    def wheel_names(self) -> tuple[str, ...]:
        return self.synth.wheel_names

    @property
    def signal_names(self) -> tuple[str, ...]:
        return self.synth.signal_names

    def attach(self, integ) -> None:
        """Have ``integ`` (a :class:`~dmf_sim.solvers.newmark.NewmarkIntegrator`) track the
        sensors' DOFs (a rebuilt integrator too)."""
        integ.set_tracked(self.synth.dofs)

    def state_row(self, integ) -> np.ndarray:
        """``integ``'s state as a track row: t, psi, omega, q[dofs], v[dofs]."""
        d = self.synth.dofs
        return np.concatenate([[integ.t, integ.psi, integ.omega], integ.q[d], integ.v[d]])

    def start(self, integ) -> None:
        """The signals begin at ``integ``'s state (nothing emitted before)."""
        self.attach(integ)
        self.synth.start(self.state_row(integ))
        self.synth.warm_up()
        self._used = 0

    def resync(self, integ) -> None:
        """``integ``'s state jumped (a reset): continue from it, no edges for the jump."""
        self.synth.resync(self.state_row(integ))
        self._used = 0

    def set_faults(self, faults: Sequence) -> None:
        """The sensor faults acting from the next chunk on (see
        :meth:`SensorSynthesizer.set_faults`)."""
        self.faults = tuple(faults)

    def next_rows(self, nsteps: int) -> np.ndarray:
        """Rows for the next ``nsteps`` steps of this chunk (the kernel's ``track``)."""
        end = self._used + nsteps
        if end > self._rows.shape[0]:
            grown = np.zeros((max(end, 2 * self._rows.shape[0]), self._rows.shape[1]))
            grown[:self._used] = self._rows[:self._used]
            self._rows = grown
        rows = self._rows[self._used:end]
        self._used = end
        return rows

    def finish(self, copy: bool = True) -> SensorChunk:
        """The signals of the chunk's rows so far; the next rows start a new chunk. ``copy``
        False: views valid until the next :meth:`finish` (a caller that consumes them at
        once)."""
        chunk = self.synth.process(self._rows[:self._used], self.faults, copy=copy)
        self._used = 0
        return chunk


class SensorMessages:
    """The node's sensor messages of a chunk: (stream key, log time [ns], CDR bytes), keys as
    :func:`dmf_sim.live.streams.streams_for` names them. Each wheel's edges are held until
    their batch period ends (``batch_period_ns``,
    :meth:`dmf_sim.physics.sensors.SensorSet.edge_batch_ns`: one publish period or more) and
    sent in one message logged at its end (:func:`dmf_sim.bags.sensor_messages.batch_log_ns`,
    the rule ``dmf-sim run`` writes by)."""

    def __init__(self, wheel_names: Sequence[str], signal_names: Sequence[str],
                 batch_period_ns: float) -> None:
        self.edge_keys = [edge_key(w) for w in wheel_names]
        self.bus_keys = [bus_key(b) for b in signal_names]
        self.batch_period_ns = batch_period_ns
        self._held: list[list[np.ndarray]] = [[] for _ in wheel_names]

    def of(self, chunk: SensorChunk, epoch_ns: int, log_offset_ns: int = 0
           ) -> list[tuple[str, int, bytes]]:
        """Stamps = ``epoch_ns`` + simulated ns (:class:`dmf_sim.live.pacing.TimeBase`); log
        times = stamps + ``log_offset_ns``."""
        out = self._batches(chunk, epoch_ns, log_offset_ns)
        if any(chunk.bus_counts):
            for b, n in enumerate(chunk.bus_counts):
                if n:
                    ns, rpm = chunk.bus_of(b)
                    key = self.bus_keys[b]
                    for t, v in zip(ns.tolist(), rpm.tolist()):
                        out.append((key, epoch_ns + t + log_offset_ns, float64_bytes(v)))
        return out

    def held(self, epoch_ns: int, log_offset_ns: int = 0) -> list[tuple[str, int, bytes]]:
        """The edges still held, each batch logged at the end of its period as :meth:`of` would
        log it (``dmf-sim run`` writes its last batches so too): what the node sends and records
        when it stops, so a bag ends with every edge of the simulated time."""
        return self._batches(None, epoch_ns, log_offset_ns)

    def _batches(self, chunk: SensorChunk | None, epoch_ns: int, log_offset_ns: int) -> list:
        """The edge batches whose period ended by the chunk's end (no chunk: all); later edges
        are held."""
        end_ns = math.inf if chunk is None else int(round(chunk.t_end_s * 1e9))
        out = []
        for w in range(len(self._held)):
            if chunk is not None and chunk.edge_counts[w]:
                self._held[w].append(chunk.edge_rows(w).copy())
            if not self._held[w]:
                continue
            rows = (np.concatenate(self._held[w]) if len(self._held[w]) > 1
                    else self._held[w][0])
            log = batch_log_ns(rows[:, 0], self.batch_period_ns)
            due = int(np.searchsorted(log, end_ns, side='right'))
            self._held[w] = [rows[due:]] if due < len(rows) else []
            if not due:
                continue
            starts = np.flatnonzero(np.diff(log[:due], prepend=-1))
            for a, b in zip(starts, [*starts[1:], due]):
                out.append((self.edge_keys[w], epoch_ns + int(log[a]) + log_offset_ns,
                            encode_edges(rows[a:b], epoch_ns)))
        return out
