"""What a real DMF spring must meet, as constraint values (> 0: violated).

* ``capacity``: the spring reaches the torque capacity before its travel ends,
  ``T(max_travel_rad) >= capacity`` (T the spring's full torque, dmf_sim.physics.spring). The
  capacity is ``capacity_nm`` or ``capacity_factor`` (default :data:`DEFAULT_CAPACITY_FACTOR`)
  times the engine's largest mean torque (full load, every load set, the study's speed grid).
* ``dmf_torque`` (``max_dmf_torque: true``, the default): the largest DMF torque in operation
  (the design metric ``max_dmf_torque``: every stable state and non-periodic envelope, every
  condition) stays below the capacity.
* ``metrics``: optional bounds ``{name: {min: a, max: b}}`` on any metric of a design's summary
  row (``dmf_sim.design.metrics``).

Each value is relative (divided by the bound's size), so they add up to one violation measure.
A design is feasible when every value is <= 0; a failed design has no values and is infeasible.
Without the capacity constraint the problem is trivial: a knee beyond the operating wind-up (a
soft, in effect linear spring) dominates every progressive design.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.validation import bounded
from dmf_sim.design.metrics import OBJECTIVES
from dmf_sim.design.states import speed_grid

__all__ = ['DEFAULT_CAPACITY_FACTOR', 'FULL_LOAD', 'KEYS', 'BOUNDABLE', 'Constraints', 'violation',
           'engine_max_torque', 'parse_constraints', 'rank']

DEFAULT_CAPACITY_FACTOR = 1.2
"""Torque capacity / engine's largest mean torque (the issue's default margin)."""
FULL_LOAD = 1.0
KEYS = ('max_travel_rad', 'capacity_factor', 'capacity_nm', 'max_dmf_torque', 'metrics')
BOUNDABLE = tuple(OBJECTIVES) + ('max_windup',)


@dataclass
class Constraints:
    """Resolved constraints: travel [rad], capacity [Nm] (and how it was set), bounds."""

    max_travel_rad: float | None
    capacity_nm: float
    capacity_factor: float | None
    engine_max_torque_nm: float
    max_dmf_torque: bool = True
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        """Names of the constraint values, in the order of :meth:`values`."""
        out = ['capacity'] if self.max_travel_rad is not None else []
        out += ['dmf_torque'] if self.max_dmf_torque else []
        for m, (lo, hi) in self.bounds.items():
            out += [f'{m}>=min'] if math.isfinite(lo) else []
            out += [f'{m}<=max'] if math.isfinite(hi) else []
        return out

    def values(self, spring, summary: dict) -> list[float]:
        """Constraint values of one design (> 0 violated, relative to the bound)."""
        out = []
        cap = self.capacity_nm
        if self.max_travel_rad is not None:
            out.append((cap - float(spring.torque(self.max_travel_rad))) / cap)
        if self.max_dmf_torque:
            out.append((float(summary['max_dmf_torque']) - cap) / cap)
        for m, (lo, hi) in self.bounds.items():
            v = float(summary[m])
            if math.isfinite(lo):
                out.append((lo - v) / max(abs(lo), 1e-12))
            if math.isfinite(hi):
                out.append((v - hi) / max(abs(hi), 1e-12))
        return [math.inf if math.isnan(v) else v for v in out]

    def as_dict(self) -> dict:
        return {'max_travel_rad': self.max_travel_rad, 'capacity_nm': self.capacity_nm,
                'capacity_factor': self.capacity_factor,
                'engine_max_torque_nm': self.engine_max_torque_nm,
                'max_dmf_torque': self.max_dmf_torque,
                'metrics': {m: {'min': lo, 'max': hi} for m, (lo, hi) in self.bounds.items()}}


def violation(values) -> float:
    """Total violation: the sum of the positive constraint values (0: feasible)."""
    return float(sum(max(v, 0.0) for v in values))


def engine_max_torque(study) -> float:
    """The engine's largest mean torque [Nm]: full load, every load set, the study's speeds."""
    speeds = speed_grid(*study.speeds_rpm)
    return float(max(e.mean_torque(float(s), FULL_LOAD) for e in study.engines.values()
                     for s in speeds))


def parse_constraints(raw, where: str, study) -> Constraints:
    """Validate the ``optimizer.constraints`` mapping (one-line ConfigErrors naming the field)."""
    if not isinstance(raw, dict):
        raise ConfigError(f'{where}: must be a mapping, got {raw!r}')
    for key in raw:
        if key not in KEYS:
            raise ConfigError(f'{where}: unknown key {key!r} (allowed: {", ".join(KEYS)})')
    if 'capacity_nm' in raw and 'capacity_factor' in raw:
        raise ConfigError(f'{where}: give capacity_nm or capacity_factor, not both')
    travel = raw.get('max_travel_rad')
    if travel is not None:
        travel = bounded(travel, where, 'max_travel_rad', 'windup_angle')
    t_max = engine_max_torque(study)
    factor = None
    if 'capacity_nm' in raw:
        cap = bounded(raw['capacity_nm'], where, 'capacity_nm', 'torque', positive=True)
    else:
        factor = _positive(raw.get('capacity_factor', DEFAULT_CAPACITY_FACTOR),
                           f'{where}.capacity_factor', '')
        cap = factor * t_max
    flag = raw.get('max_dmf_torque', True)
    if not isinstance(flag, bool):
        raise ConfigError(f'{where}.max_dmf_torque: must be true or false, got {flag!r}')
    bounds = {}
    metrics = raw.get('metrics') or {}
    if not isinstance(metrics, dict):
        raise ConfigError(f'{where}.metrics: must be a mapping {{metric: {{min, max}}}}, '
                          f'got {metrics!r}')
    for m, spec in metrics.items():
        w = f'{where}.metrics.{m}'
        if m not in BOUNDABLE:
            raise ConfigError(f'{w}: unknown metric (allowed: {", ".join(BOUNDABLE)})')
        if not isinstance(spec, dict) or not spec or set(spec) - {'min', 'max'}:
            raise ConfigError(f'{w}: give {{min: ..}} and/or {{max: ..}}, got {spec!r}')
        lo = _finite(spec.get('min', -math.inf), f'{w}.min', allow_inf=('min' not in spec))
        hi = _finite(spec.get('max', math.inf), f'{w}.max', allow_inf=('max' not in spec))
        if not lo < hi:
            raise ConfigError(f'{w}: min {lo:g} must be < max {hi:g}')
        bounds[m] = (lo, hi)
    return Constraints(travel, cap, factor, t_max, flag, bounds)


def _positive(value, where: str, unit: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or value <= 0:
        raise ConfigError(f'{where}: must be a finite number > 0 {unit}'.rstrip()
                          + f', got {value!r}')
    return float(value)


def _finite(value, where: str, allow_inf: bool) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            not (allow_inf or math.isfinite(value)):
        raise ConfigError(f'{where}: must be a finite number, got {value!r}')
    return float(value)


def rank(feasible: np.ndarray, violations: np.ndarray, objectives: np.ndarray,
         failed: np.ndarray) -> np.ndarray:
    """Rank of every design (1 best): feasible designs by non-dominated layer of their
    ``objectives`` ((n_designs, n_objectives), all minimized), then infeasible ones by total
    violation, then failed ones. Never drops a design."""
    from dmf_sim.design.pareto import pareto_mask
    n = len(feasible)
    out = np.zeros(n, dtype=int)
    left = np.flatnonzero(feasible & ~failed)
    layer = 0
    while len(left):
        layer += 1
        m = pareto_mask(*np.asarray(objectives, dtype=float)[left].T)
        if not m.any():                       # undefined objectives: one last layer
            m[:] = True
        out[left[m]] = layer
        left = left[~m]
    nxt = layer + 1
    bad = np.flatnonzero(~feasible & ~failed)
    for k, i in enumerate(bad[np.argsort(violations[bad], kind='stable')]):
        out[i] = nxt + k
    nxt += len(bad)
    out[failed] = nxt
    return out
