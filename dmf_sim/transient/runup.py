"""Run-up analysis: order tracks over speed from run-up / run-down bags beside the HBM sweep,
jump speeds found in the records and the sweep's fold / stability events that explain them
(``dmf-sim runup``).

Each bag goes through the bag analysis (:func:`dmf_sim.analysis.pipeline.analyze_bag`: angle-
domain resampling, half orders per engine cycle, speed bins) and its HBM overlay
(:func:`dmf_sim.analysis.hbm_overlay.overlay_all`: the same model, from the bag's
``custom_data``, swept by pseudo-arc-length continuation with Floquet stability and branch
switching). The settle from static equilibrium a bag marks (``dmf-sim run``'s, ``custom_data``
``settle_s``) is left out by the bag analysis itself, as ``dmf-sim analyze`` leaves it out; of the
rest, the cycles before the speed leaves the run's start speed (a node recording's dwell, a
``ramp:`` settle longer than the mark) are left out here (:func:`ramp_cycles`): the ramp is what
is tracked.

A slow ramp follows a stable branch quasi-statically; where that branch ends (a fold) or loses
stability, the state jumps onto another one -- at different speeds going up and down when
several states coexist (hysteresis). :func:`find_jumps` finds candidate jumps as the largest
steps of an order amplitude between the ``JUMP_WINDOW_CYCLES`` cycles before and after a cycle,
larger than ``JUMP_MIN_FRACTION`` of the amplitude's peak over the record; with the HBM sweep
at hand a candidate is a jump only if the states before and after it lie nearest to different
stable stretches of the swept branches (a steep stretch of one branch, or the beating after a
jump, is not one). Each jump is matched with the nearest sweep event (``fold``,
``stability_loss``).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from dmf_sim.analysis.cycle_orders import CycleOrders
from dmf_sim.analysis.hbm_overlay import model_settings, overlay_all
from dmf_sim.analysis.order_bins import bin_cycles
from dmf_sim.analysis.pipeline import AnalysisOptions, BagAnalysis, analyze_bag
from dmf_sim.core.errors import BagError
from dmf_sim.transient.defaults import DEFAULT_BIN_RPM, JUMP_WINDOW_CYCLES

__all__ = ['ORDERS', 'JUMP_MIN_FRACTION', 'JUMP_FLOOR_FRACTION', 'STEP_RATIO_MAX', 'EVENT_KINDS',
           'SEGMENT_SPEED_SCALE_RPM', 'SETTLE_TOLERANCE_RPM', 'AWAY_FROM_JUMPS_RPM',
           'MIN_SHARE_OF_PEAK', 'Jump', 'RunupResult', 'ramp_cycles', 'find_jumps',
           'stable_stretches', 'on_other_stretch', 'match_events', 'quasi_static_difference',
           'runup_analysis']

ORDERS = ('order_3', 'order_1_5')
JUMP_MIN_FRACTION = 0.25    # a jump changes the amplitude by this fraction of its peak at least
JUMP_FLOOR_FRACTION = 0.05  # ... and by this fraction of the largest order's peak (noise floor)
STEP_RATIO_MAX = 1.5        # a step seen over the whole window at most this many times the one
                            # over half of it (a jump: ~1; a steep but smooth slope: ~2)
EVENT_KINDS = ('fold', 'stability_loss')
SEGMENT_SPEED_SCALE_RPM = 10.0   # speed distance that counts like the amplitude's peak when
                                 # a state is placed on the nearest stable HBM stretch
SETTLE_TOLERANCE_RPM = 0.5  # cycles within this of the start speed are before the ramp
AWAY_FROM_JUMPS_RPM = 30.0  # quasi-static comparison: rows this far from jumps and events
MIN_SHARE_OF_PEAK = 0.05    # ... and where the HBM amplitude is at least this share of its peak


@dataclass
class Jump:
    """A jump of an order amplitude in a record: at ``speed_rpm`` [rpm] (the ramp's
    ``direction`` +1 up, -1 down), from ``before`` to ``after`` [rad]; ``event`` the nearest
    sweep event (dict) and ``error_rpm`` its distance."""

    direction: int
    order: str
    speed_rpm: float
    before: float
    after: float
    t_s: float
    event: dict | None = None
    error_rpm: float | None = None

    def as_dict(self) -> dict:
        return {'direction': 'up' if self.direction > 0 else 'down', 'order': self.order,
                'speed_rpm': self.speed_rpm, 'before_rad': self.before, 'after_rad': self.after,
                't_s': self.t_s, 'event': self.event, 'error_rpm': self.error_rpm}


@dataclass
class RunupResult:
    """Run-up (and run-down) analyses, their jumps and the sweep's events."""

    runs: list[BagAnalysis]
    directions: list[int]
    jumps: list[Jump]
    events: list[dict]
    quasi_static: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        """The result for JSON; per bag (in the order of ``bags``) its analysis' warnings
        (damaged parts skipped included, as ``dmf-sim analyze`` words them), the corrupt
        chunks skipped and whether it was truncated."""
        return {'bags': [str(r.bag) for r in self.runs],
                'directions': ['up' if d > 0 else 'down' for d in self.directions],
                'jumps': [j.as_dict() for j in self.jumps], 'events': self.events,
                'quasi_static': self.quasi_static,
                'warnings': [list(r.warnings) for r in self.runs],
                'corrupt_chunks': [list(r.corrupt) for r in self.runs],
                'truncated': [r.truncated for r in self.runs]}


def ramp_cycles(cyc: CycleOrders, start_rpm: float | None = None) -> slice:
    """The cycles after the speed left ``start_rpm`` (the run's start speed; None: the first
    cycle's), as a slice of ``cyc``."""
    if len(cyc) == 0:
        return slice(0, 0)
    start = float(cyc.speed_rpm[0]) if start_rpm is None else float(start_rpm)
    moved = np.flatnonzero(np.abs(cyc.speed_rpm - start) > SETTLE_TOLERANCE_RPM)
    return slice(int(moved[0]), None) if len(moved) else slice(0, 0)


def _steps(c: np.ndarray, idx: np.ndarray, w: int) -> np.ndarray:
    """Mean of the w values from idx on minus the mean of the w before (c: cumulative sum)."""
    return (c[idx + w] - c[idx]) / w - (c[idx] - c[idx - w]) / w


def find_jumps(cyc: CycleOrders, order: str = 'order_3', direction: int = 1, *,
               window: int = JUMP_WINDOW_CYCLES, min_fraction: float = JUMP_MIN_FRACTION
               ) -> list[Jump]:
    """Jumps of one order amplitude over the cycles of a ramp: steps between the ``window``
    cycles before and after a cycle larger than ``min_fraction`` of the amplitude's peak (and
    than JUMP_FLOOR_FRACTION of the largest order's), that are steps and not slopes (the step
    over half the window is at least 1/STEP_RATIO_MAX of it)."""
    a = np.asarray(getattr(cyc, order), float)
    n = len(a)
    if n < 2 * window + 1 or not np.isfinite(a).any():
        return []
    c = np.concatenate(([0.0], np.cumsum(np.nan_to_num(a))))
    idx = np.arange(window, n - window + 1)
    step = _steps(c, idx, window)
    half = _steps(c, idx, max(window // 2, 1))
    largest = max(float(np.nanmax(getattr(cyc, o))) for o in ORDERS)
    thr = max(min_fraction * float(np.nanmax(a)), JUMP_FLOOR_FRACTION * largest)
    big = (np.abs(step) > thr) & (np.abs(step) <= STEP_RATIO_MAX * np.abs(half))
    out = []
    k = 0
    while k < len(idx):
        if not big[k]:
            k += 1
            continue
        end = k
        while end + 1 < len(idx) and big[end + 1] and np.sign(step[end + 1]) == np.sign(step[k]):
            end += 1
        best = k + int(np.argmax(np.abs(step[k:end + 1])))
        i = int(idx[best])
        speed = 0.5 * (cyc.speed_rpm[i - 1] + cyc.speed_rpm[i])
        out.append(Jump(direction, order, float(speed), float(np.mean(a[i - window:i])),
                        float(np.mean(a[i:i + window])), float(cyc.t_start[i])))
        k = end + 1
    return out


def stable_stretches(curve: dict, order: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(speed, value, stretch id) of the stable points of the swept branches; a stretch is a
    run of stable points of one branch."""
    sp = np.asarray(curve['speed_rpm'], float)
    br = np.asarray(curve['branch'])
    val = np.asarray(curve[order], float)
    st = np.array([x is not False for x in curve['stable']])
    new = np.concatenate(([True], (br[1:] != br[:-1]) | ~st[:-1]))
    ids = np.cumsum(new)
    return sp[st], val[st], ids[st]


def on_other_stretch(jump: Jump, cyc: CycleOrders, stretches, window: int) -> bool:
    """Whether the states before and after ``jump`` lie nearest to different stable
    stretches of the sweep."""
    sp, val, ids = stretches
    if len(sp) == 0:
        return True
    a = np.asarray(getattr(cyc, jump.order), float)
    i = int(np.searchsorted(cyc.t_start, jump.t_s))
    peak = max(float(np.nanmax(val)), float(np.nanmax(a)), 1e-12)

    def nearest(lo: int, hi: int) -> int:
        s_m, v_m = float(np.mean(cyc.speed_rpm[lo:hi])), float(np.mean(a[lo:hi]))
        d = ((sp - s_m) / SEGMENT_SPEED_SCALE_RPM) ** 2 + ((val - v_m) / peak) ** 2
        return int(ids[int(np.argmin(d))])

    return nearest(max(i - window, 0), i) != nearest(i, min(i + window, len(a)))


def match_events(jumps: list[Jump], events: list[dict]) -> None:
    """Set each jump's nearest sweep event of the kinds in EVENT_KINDS (in place)."""
    cands = [e for e in events if e.get('kind') in EVENT_KINDS]
    for j in jumps:
        if cands:
            e = min(cands, key=lambda e: abs(e['speed_rpm'] - j.speed_rpm))
            j.event, j.error_rpm = dict(e), abs(e['speed_rpm'] - j.speed_rpm)


def quasi_static_difference(res: BagAnalysis, jumps: list[Jump], events: list[dict],
                            away_rpm: float = AWAY_FROM_JUMPS_RPM) -> dict:
    """Largest |measured / HBM - 1| per order over the speed bins away from jumps and events
    (``away_rpm``) where the HBM amplitude is at least MIN_SHARE_OF_PEAK of its peak."""
    sig = res.signal('windup')
    if sig.hbm is None:
        return {}
    speed = np.asarray(sig.table.speed_mean_rpm)
    marks = [j.speed_rpm for j in jumps] + [e['speed_rpm'] for e in events
                                            if e.get('kind') in EVENT_KINDS]
    away = np.ones(len(speed), bool)
    for m in marks:
        away &= np.abs(speed - m) > away_rpm
    out = {}
    for order in ORDERS:
        meas = np.asarray(getattr(sig.table, order), float)
        hbm = np.asarray(sig.hbm.values[order], float)
        ok = away & np.isfinite(hbm) & np.isfinite(meas) & sig.table.steady
        if ok.any():
            ok &= hbm >= MIN_SHARE_OF_PEAK * np.nanmax(hbm[ok])
        if not ok.any():
            out[order] = {'max_rel_diff': None, 'rows': 0}
            continue
        ok &= hbm > 0
        if not ok.any():
            out[order] = {'max_rel_diff': None, 'rows': 0}
            continue
        rel = np.abs(meas[ok] / hbm[ok] - 1)
        k = int(np.argmax(rel))
        out[order] = {'max_rel_diff': float(rel[k]), 'at_speed_rpm': float(speed[ok][k]),
                      'rows': int(ok.sum()),
                      'speed_range_rpm': [float(speed[ok].min()), float(speed[ok].max())]}
    return out


def runup_analysis(bags: list[str | os.PathLike], *, bin_rpm: float = DEFAULT_BIN_RPM,
                   hbm: bool = True, window: int = JUMP_WINDOW_CYCLES,
                   min_fraction: float = JUMP_MIN_FRACTION,
                   config: str | None = None) -> RunupResult:
    """Analyse run-up / run-down bags (module docstring); ``config``: the driveline YAML of
    the HBM overlay instead of the one each bag names (``--config`` of ``dmf-sim analyze``)."""
    if not bags:
        raise BagError('give at least one run-up or run-down bag')
    runs, dirs, jumps, events = [], [], [], []
    for bag in bags:
        res = analyze_bag(bag, options=AnalysisOptions(bin_rpm=bin_rpm))
        sig = res.signal('windup')
        ramp = ramp_cycles(sig.cycles, res.series.bag.run_metadata.speed_rpm)
        cyc = sig.cycles.select(ramp)
        if len(cyc) < 2:
            raise BagError(f'{bag}: the speed does not ramp (a run-up or run-down bag is needed)')
        direction = 1 if cyc.speed_rpm[-1] >= cyc.speed_rpm[0] else -1
        if direction in dirs:
            way = 'up' if direction > 0 else 'down'
            raise BagError(f'{bag}: a second run-{way} bag; give a run-up bag, a run-down bag or '
                           'one of each')
        sig.cycles = cyc
        if sig.cycle_load is not None:
            sig.cycle_load = sig.cycle_load[ramp]
        sig.table = bin_cycles(cyc, bin_rpm, res.theta, res.min_cycles, sig.cycle_load)
        if hbm:
            overlay_all(res, model_settings(res.metadata, config=config))
            sig = res.signal('windup')
            if sig.hbm is not None:
                for e in sig.hbm.events:
                    if not any(e['kind'] == x['kind'] and math.isclose(
                            e['speed_rpm'], x['speed_rpm'], abs_tol=0.5) for x in events):
                        events.append(dict(e))
        sig = res.signal('windup')
        curve = sig.hbm.curve if sig.hbm is not None else None
        for order in ORDERS:
            found = find_jumps(sig.cycles, order, direction, window=window,
                               min_fraction=min_fraction)
            if curve:
                stretches = stable_stretches(curve, order)
                found = [j for j in found if on_other_stretch(j, sig.cycles, stretches, window)]
            jumps += found
        runs.append(res)
        dirs.append(direction)
    events.sort(key=lambda e: e['speed_rpm'])
    match_events(jumps, events)
    qs = {}
    for res, d in zip(runs, dirs):
        own = [j for j in jumps if j.direction == d]
        qs['up' if d > 0 else 'down'] = quasi_static_difference(res, own, events)
    return RunupResult(runs, dirs, jumps, events, qs)
