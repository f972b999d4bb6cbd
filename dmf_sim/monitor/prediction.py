"""Harmonic-balance prediction of the DMF wind-up at the live operating point (no ROS).

* :func:`predict_states` — THE pluggable solver: every stable periodic steady state at one speed
  and load, ``predict_states(loads, speed_rpm, load, faults=None) -> list of HBMPoint-like
  results`` (``faults``: the persistent faults acting, passed only when there are some; each
  with ``.summary`` (:class:`dmf_sim.physics.orders.OrderSummary`) and ``.stable``; ``.kind``,
  ``.branch``, ``.max_multiplier`` are used when present). The default sweeps a short speed range
  around the point with :func:`dmf_sim.solvers.hbm.sweep` (pseudo-arc-length continuation, Floquet
  stability, 1.5th-order branch switching) and takes :meth:`SweepResult.solutions_at` the point,
  keeping the stable ones. Another finder replaces it by being passed as ``solver``.
* :class:`Prediction` — the result for one :class:`OperatingPoint` (speed and load rounded, load
  set, spring, the persistent faults acting): the stable states (with alike cylinders a state and
  its 120-deg shifted copy count once; with faults that make the cylinders differ they are two
  states), or none ("no stable periodic state predicted here"), or the error text when the
  solver failed.
* :func:`solve_prediction` — runs a solver for an operating point and wraps the result.
* :func:`compare` — live minus predicted per quantity for a completed cycle, against the
  predicted stable state nearest to the live one (the one a run settles on depends on its
  history), when the cycle ran at the prediction's operating point.

Running the solver off the real-time path and caching per operating point is
:class:`dmf_sim.monitor.worker.LiveMonitor`'s job.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from dmf_sim.core.errors import ConvergenceError
from dmf_sim.physics.faults import COMBUSTION_KINDS, FaultSet

__all__ = ['SWEEP_HALF_WIDTHS_RPM', 'QUANTITIES', 'OperatingPoint', 'PredictedState',
           'Prediction', 'Comparison', 'predict_states', 'solve_prediction', 'compare',
           'steady_part']

SWEEP_HALF_WIDTHS_RPM = (50.0, 30.0, 20.0)  # sweep s +- these [rpm], in turn until one converges
SWEEP_STEP_RPM = 10.0                        # continuation output grid [rpm]
QUANTITIES = ('order_3', 'order_1_5', 'max_deviation', 'min_deviation', 'mean',
              'mean_minus_theta')            # the Fig. 13 quantities compared live vs predicted
_SAME_STATE_ABS = 1e-6                       # [rad] states closer than this (+ relative) are one
_SAME_STATE_REL = 1e-4


def predict_states(loads, speed_rpm: float, load: float, faults=None) -> list:
    """Every stable periodic steady state of the wind-up at ``speed_rpm`` and ``load`` (with
    the persistent ``faults``, a :class:`~dmf_sim.physics.faults.FaultSet`; None: healthy).

    Sweeps ``speed_rpm +- 50 rpm`` (clipped to the engine data; then +-30, +-20 rpm if the
    continuation fails to start) with :func:`dmf_sim.solvers.hbm.sweep` and returns the stable
    ones of
    :meth:`~dmf_sim.solvers.hbm.SweepResult.solutions_at` the speed (HBMPoints). Raises
    :class:`ConvergenceError` when no sweep converges."""
    from dmf_sim.solvers.hbm import SearchOptions, SweepOptions, sweep

    s = float(speed_rpm)
    lo_data, hi_data = getattr(loads.engine, 'speed_range_rpm', (0.0, math.inf))
    errors = []
    for half in SWEEP_HALF_WIDTHS_RPM:
        lo, hi = max(s - half, float(lo_data)), min(s + half, float(hi_data))
        if hi <= lo:
            raise ConvergenceError(f'{s:g} rpm is outside the engine data [{lo_data:g}, '
                                   f'{hi_data:g}] rpm')
        try:
            res = sweep(loads, float(load), (lo, hi),   # stable states only: no envelopes
                        options=SweepOptions(step_rpm=SWEEP_STEP_RPM,
                                             search=SearchOptions(nonperiodic_speeds=())),
                        faults=faults)
        except (ConvergenceError, np.linalg.LinAlgError, FloatingPointError) as exc:
            errors.append(f'+-{half:g} rpm: {exc}')
            continue
        return [p for p in res.solutions_at(s) if p.stable]
    raise ConvergenceError(f'no HBM sweep around {s:g} rpm converged ({"; ".join(errors)})')


@dataclass(frozen=True)
class OperatingPoint:
    """Where a prediction applies: speed [rpm] and load fraction (rounded), load set, spring,
    and the persistent faults acting (a :class:`~dmf_sim.physics.faults.FaultSet` of every-cycle
    misfires, weak cylinders and DMF faults; None: healthy)."""

    speed_rpm: float
    load: float
    load_set: str
    spring: object
    faults: object = None

    @classmethod
    def rounded(cls, speed_rpm: float, load: float, load_set: str, spring, speed_step_rpm: float,
                load_step: float, faults=None) -> 'OperatingPoint':
        """The point with speed and load rounded to the given steps (the cache key; the faults
        are part of it: :func:`steady_part` of the set given)."""
        return cls(round(round(speed_rpm / speed_step_rpm) * speed_step_rpm, 9),
                   round(round(load / load_step) * load_step, 9), str(load_set), spring,
                   steady_part(faults))

    @property
    def combustion_faults(self) -> bool:
        """Do misfires or weak cylinders act here? Then states with equal Fig. 13 quantities
        are not merged (the solver, which knows the factors, has merged what is one state:
        twins only when all cylinders still fire alike)."""
        return bool(self.faults) and any(f.kind in COMBUSTION_KINDS for f in self.faults)


def steady_part(faults):
    """The faults of a set that have a periodic steady state (its persistent part, without
    time windows: the same faults, held), or None when there are none: what a prediction
    takes from the faults acting now."""
    if not faults:
        return None
    held = FaultSet(tuple(replace(f, start_s=None, end_s=None, duration_s=None)
                          for f in faults.persistent))
    return held or None


@dataclass(frozen=True)
class PredictedState:
    """One stable periodic steady state: the Fig. 13 quantities of the wind-up [rad], how the
    solver found it (kind: 'main', 'subharmonic', 'harmonic'; branch id) and its largest Floquet
    multiplier modulus (< 1: stable)."""

    order_3: float
    order_1_5: float
    max_deviation: float
    min_deviation: float
    mean: float
    mean_minus_theta: float
    static_windup: float
    theta_minus_static: float
    kind: str = ''
    branch: int = -1
    max_multiplier: float = math.nan

    @classmethod
    def from_point(cls, p) -> 'PredictedState':
        s = p.summary
        return cls(float(s.order_3), float(s.order_1_5), float(s.max_deviation),
                   float(s.min_deviation), float(s.mean), float(s.mean_minus_theta),
                   float(s.static_windup), float(s.theta_minus_static),
                   str(getattr(p, 'kind', '')), int(getattr(p, 'branch', -1)),
                   float(getattr(p, 'max_multiplier', math.nan)))

    @property
    def max_windup(self) -> float:
        return self.mean + self.max_deviation

    @property
    def min_windup(self) -> float:
        return self.mean + self.min_deviation

    def vector(self) -> np.ndarray:
        return np.array([getattr(self, q) for q in QUANTITIES])


@dataclass(frozen=True)
class Prediction:
    """The predicted stable states at one operating point.

    ``states`` empty and ``error`` empty: the solver found no stable periodic state there.
    ``error``: the solver failed (one line). ``seconds``: solver wall time."""

    point: OperatingPoint
    states: tuple[PredictedState, ...]
    seconds: float
    error: str = ''

    @property
    def no_stable_state(self) -> bool:
        return not self.error and not self.states


def _distinct(states: Sequence[PredictedState], merge_twins: bool = True
              ) -> tuple[PredictedState, ...]:
    """States with different Fig. 13 quantities (a state and its 120-deg shifted copy, which the
    solver returns as two solutions, have equal amplitudes and extremes: one physical state).
    ``merge_twins`` False (cylinders that do not fire alike): every state is kept, equal
    quantities or not (a shifted copy is another state)."""
    if not merge_twins:
        return tuple(states)
    out: list[PredictedState] = []
    for s in states:
        v = s.vector()
        if all(np.abs(v - o.vector()).max() > _SAME_STATE_ABS + _SAME_STATE_REL * np.abs(v).max()
               for o in out):
            out.append(s)
    return tuple(out)


def solve_prediction(solver: Callable, loads, point: OperatingPoint) -> Prediction:
    """Run ``solver(loads, speed, load)`` at ``point`` (with ``faults=point.faults`` when faults
    act there): the stable states found (distinct), or the solver's failure as ``error``."""
    t0 = time.perf_counter()
    kw = {'faults': point.faults} if point.faults else {}
    try:
        pts = solver(loads, point.speed_rpm, point.load, **kw)
    except (ConvergenceError, np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:
        text = ' '.join(str(exc).split()) or type(exc).__name__
        return Prediction(point, (), time.perf_counter() - t0, error=text)
    states = _distinct([PredictedState.from_point(p) for p in pts
                        if getattr(p, 'stable', True) is not False],
                       merge_twins=not point.combustion_faults)
    return Prediction(point, states, time.perf_counter() - t0)


@dataclass(frozen=True)
class Comparison:
    """Live minus predicted for one cycle.

    ``applies``: the cycle ran at the prediction's operating point (within the tolerances) and a
    stable state was predicted; then ``state`` is the predicted state nearest to the live cycle
    and ``difference`` maps each of :data:`QUANTITIES` to live minus predicted [rad] (NaN when
    not applicable). ``reason`` says why not, when it does not apply."""

    applies: bool
    state: PredictedState | None
    difference: dict[str, float]
    reason: str = ''


def compare(cycle, prediction: Prediction | None, speed_tolerance_rpm: float,
            load_tolerance: float) -> Comparison:
    """Live minus predicted for a completed cycle (:class:`dmf_sim.monitor.orders.CycleResult`)."""
    nan = {q: math.nan for q in QUANTITIES}
    if prediction is None:
        return Comparison(False, None, nan, 'no prediction yet')
    if prediction.error:
        return Comparison(False, None, nan, 'prediction failed')
    if not prediction.states:
        return Comparison(False, None, nan, 'no stable periodic state predicted here')
    pt = prediction.point
    if (abs(cycle.speed_rpm - pt.speed_rpm) > speed_tolerance_rpm
            or abs(cycle.load - pt.load) > load_tolerance):
        return Comparison(False, None, nan,
                          f'cycle at {cycle.speed_rpm:.0f} rpm / load {cycle.load:.2f}, '
                          'prediction '
                          f'at {pt.speed_rpm:g} rpm / {pt.load:g}')
    live = np.array([getattr(cycle.summary, q) for q in QUANTITIES])
    weights = np.array([1.0 if q in ('order_3', 'order_1_5', 'mean') else 0.0 for q in QUANTITIES])
    state = min(prediction.states, key=lambda s: float(np.sum(weights * (live - s.vector()) ** 2)))
    diff = {q: float(v) for q, v in zip(QUANTITIES, live - state.vector(), strict=True)}
    return Comparison(True, state, diff)
