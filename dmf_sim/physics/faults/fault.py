"""The description of a fault (:class:`Fault`, the grammar's kinds and modes) and a set of
faults acting together (:class:`FaultSet`)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from dmf_sim.physics.faults.combustion import combustion_factors
from dmf_sim.physics.faults.dmf import apply_dmf_faults
from dmf_sim.physics.model import Driveline

__all__ = ['FAULT_KINDS', 'COMBUSTION_KINDS', 'DMF_KINDS', 'SENSOR_KINDS', 'MISFIRE_MODES',
           'EDGE_MODES', 'BUS_MODES', 'Fault', 'FaultSet']

FAULT_KINDS = ('misfire', 'weak_cylinder', 'dmf_stiffness', 'dmf_broken', 'dmf_damping',
               'sensor_edges', 'bus_signal')
COMBUSTION_KINDS = ('misfire', 'weak_cylinder')
DMF_KINDS = ('dmf_stiffness', 'dmf_broken', 'dmf_damping')
SENSOR_KINDS = ('sensor_edges', 'bus_signal')
MISFIRE_MODES = ('single', 'every_cycle', 'random')
EDGE_MODES = ('missing', 'extra')
BUS_MODES = ('stuck', 'noisy')


@dataclass(frozen=True)
class Fault:
    """One validated fault (the fields: :mod:`dmf_sim.physics.faults`). ``stage`` is '1', '2',
    .. or 'coast_1', ..; ``cylinders`` holds the one cylinder of a weak_cylinder fault. Times
    [s] of simulated time; None = not given."""

    kind: str
    cylinders: tuple[int, ...] = ()
    mode: str = ''
    factor: float | None = None
    stage: str = ''
    sensor: str = ''
    signal: str = ''
    probability: float | None = None
    rate_per_s: float | None = None
    tooth: int | None = None
    sigma_rpm: float | None = None
    seed: int | None = None
    start_s: float | None = None
    end_s: float | None = None
    duration_s: float | None = None

    # ---- what it is -------------------------------------------------------------------------
    @property
    def single(self) -> bool:
        """A single misfire: one combustion per listed cylinder, then it ends by itself."""
        return self.kind == 'misfire' and self.mode == 'single'

    @property
    def persistent(self) -> bool:
        """A fault with a periodic steady state of its own (every-cycle misfire, weak cylinder,
        DMF): what :class:`FaultSet` applies to a steady state. Single and random misfires are
        events; sensor faults do not change the motion."""
        if self.kind == 'misfire':
            return self.mode == 'every_cycle'
        return self.kind in COMBUSTION_KINDS + DMF_KINDS

    def mapping(self) -> dict[str, Any]:
        """The fields given, in the grammar's names and order (what :func:`parse_fault` reads
        back to an equal fault)."""
        out: dict[str, Any] = {'kind': self.kind}
        if self.kind == 'weak_cylinder':
            out['cylinder'] = self.cylinders[0]
        elif self.cylinders:
            out['cylinders'] = list(self.cylinders)
        if self.stage:
            out['stage'] = int(self.stage) if self.stage.isdigit() else self.stage
        for key in ('sensor', 'signal', 'mode'):
            if getattr(self, key):
                out[key] = getattr(self, key)
        for key in ('factor', 'probability', 'rate_per_s', 'tooth', 'sigma_rpm', 'seed'):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.single and self.start_s is not None:
            out['at_s'] = self.start_s
        elif self.start_s is not None:
            out['start_s'] = self.start_s
        for key in ('end_s', 'duration_s'):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        return out

    def text(self) -> str:
        """The fault in YAML flow style on one line (the live request form)."""
        return _flow(self.mapping())

    def targets(self) -> tuple[tuple[str, str], ...]:
        """(group, target) pairs: two faults of one group on one target must not overlap in
        time (``misfire``/``cylinder 3``, ``dmf_stage``/``stage 2``, ...)."""
        if self.kind in COMBUSTION_KINDS:
            return tuple((self.kind, f'cylinder {c}') for c in self.cylinders)
        if self.kind in ('dmf_stiffness', 'dmf_broken'):
            return (('dmf_stage', f'stage {self.stage}'),)
        if self.kind == 'dmf_damping':
            return (('dmf_damping', 'DMF damping'),)
        if self.kind == 'sensor_edges':
            return (('sensor_edges', f'sensor {self.sensor}'),)
        return (('bus_signal', f'signal {self.signal}'),)

    def target_text(self) -> str:
        """What it acts on, for people: 'cylinders 2, 5', 'stage coast_1', 'sensor crank'."""
        if self.kind == 'misfire':
            return ('cylinder ' if len(self.cylinders) == 1 else 'cylinders ') + ', '.join(
                str(c) for c in self.cylinders)
        if self.kind == 'weak_cylinder':
            return f'cylinder {self.cylinders[0]}'
        return self.targets()[0][1]

    def window(self, now_s: float = 0.0) -> tuple[float, float]:
        """[start, end) [s]: start ``start_s`` or ``now_s``; end ``end_s``, start +
        ``duration_s`` or inf. A single misfire's window is the point [at_s, at_s]."""
        start = self.start_s if self.start_s is not None else now_s
        if self.single:
            return start, start
        if self.end_s is not None:
            return start, self.end_s
        if self.duration_s is not None:
            return start, start + self.duration_s
        return start, math.inf

    def label(self, index: int | None = None, where: str = '') -> str:
        """``<where>: faults[i] (kind)`` — how messages name this fault."""
        name = f'faults[{index}] ({self.kind})' if index is not None else f'fault ({self.kind})'
        return f'{where}: {name}' if where else name


def _flow(d: Mapping[str, Any]) -> str:
    return yaml.safe_dump(dict(d), default_flow_style=True, sort_keys=False,
                          width=math.inf).strip()


@dataclass(frozen=True)
class FaultSet:
    """Faults acting together (those active at one time, or the persistent ones of a steady
    state)."""

    faults: tuple[Fault, ...] = ()

    def __iter__(self):
        return iter(self.faults)

    def __len__(self) -> int:
        return len(self.faults)

    def __bool__(self) -> bool:
        return bool(self.faults)

    def of_kinds(self, kinds: Sequence[str]) -> 'FaultSet':
        return FaultSet(tuple(f for f in self.faults if f.kind in kinds))

    @property
    def persistent(self) -> 'FaultSet':
        """The faults with a periodic steady state (:attr:`Fault.persistent`)."""
        return FaultSet(tuple(f for f in self.faults if f.persistent))

    def combustion_factors(self, n_cylinders: int) -> np.ndarray:
        """Per-cylinder combustion factors s_k (n_cylinders,) of the persistent combustion
        faults: an every-cycle misfire 0, a weak cylinder its factor, healthy 1 (several on one
        cylinder multiply). Single and random misfires are events, not part of it
        (:class:`FaultTimeline` decides them combustion by combustion)."""
        return combustion_factors(self.faults, n_cylinders)

    def apply_to_driveline(self, line: Driveline) -> Driveline:
        """The driveline with this set's DMF faults applied (others ignored), built through
        :meth:`Driveline.with_dmf` (the one spring object): :func:`~dmf_sim.physics.faults.dmf.
        apply_dmf_faults`. One-line ConfigError when the result is no valid spring (a stage
        factor beyond its limit)."""
        return apply_dmf_faults(self.of_kinds(DMF_KINDS).faults, line)

    def text(self) -> str:
        return '[' + ', '.join(f.text() for f in self.faults) + ']'
