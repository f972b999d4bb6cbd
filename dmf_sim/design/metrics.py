"""What a study reports per design and condition, from the steady states on the speed grid.

All "worst" values are over the *stable* steady states (the states a truck can sit in; an unstable
solution is never the answer, doc/theory.md §9), at every grid speed and on every branch, and over
the time-integration envelopes where no periodic state is stable (averaged orders and max/min
over many cycles: what the driveline does there):

* ``worst_order_1_5`` / ``worst_order_3``: largest 1.5th / 3rd-order wind-up amplitude [rad];
* ``worst_torque_3``: largest 3rd-order torque amplitude [Nm] transmitted into the study's torque
  element (default the gearbox input shaft, the paper's reason for the DMF);
* ``max_dmf_torque``: largest magnitude of the DMF spring torque T(w) [Nm] at the extreme wind-up
  of a stable state (mean + max or min deviation): the end-stop load; ``max_windup`` [rad];
* ``rpm_1_5``: width [rpm] of the grid speeds where a stable 1.5th-order state exists (the
  sweep's own criterion: 1.5th order above ratio x its directly forced level and above a floor),
  ``speeds_1_5`` those speeds as ranges; ``rpm_nonperiodic`` / ``speeds_nonperiodic``: grid
  speeds with no stable periodic state (there the response is not periodic: quasi-periodic or
  chaotic); ``max_stable_states``: most stable states coexisting at one speed.

The load steps of a study (``conditions.load_steps``, :mod:`dmf_sim.design.transient`) add
``transient_windup`` [rad], ``transient_dmf_torque`` [Nm], ``transient_stop_contacts`` and
``transient_travel_margin`` [rad] to a design's summary row: the peaks of its tip-ins and
tip-outs in the time domain. Its road cycle (``conditions.road_cycle``) adds
``cycle_friction_heat`` [J], the arc-spring friction's heat over the cycle, and
``cycle_dmf_torque`` [Nm].

Every worst value comes with the speed where it occurs (``<name>_rpm``) and, in a design's summary
row, the condition (``<name>_condition``). Objectives are any of :data:`OBJECTIVES`, all minimized.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ['OBJECTIVES', 'WORST', 'TIE_REL', 'condition_metrics', 'design_summary', 'first_max',
           'speed_ranges']

OBJECTIVES = {
    'worst_order_1_5': 'largest 1.5th-order wind-up amplitude of a stable state [rad]',
    'worst_order_3': 'largest 3rd-order wind-up amplitude of a stable state [rad]',
    'worst_torque_3': 'largest 3rd-order torque amplitude at the torque element [Nm]',
    'max_dmf_torque': 'largest DMF spring torque at the extreme wind-up of a stable state [Nm]',
    'rpm_1_5': 'width of the speeds with a stable 1.5th-order state [rpm]',
    'rpm_nonperiodic': 'width of the speeds without a stable periodic state [rpm]',
    'max_stable_states': 'most stable states coexisting at one speed',
    'transient_windup': 'largest wind-up magnitude in the load steps [rad]',
    'transient_dmf_torque': 'largest DMF spring torque magnitude in the load steps [Nm]',
    'transient_stop_contacts': 'end-stop contacts in the load steps',
    'cycle_friction_heat': "arc-spring friction's heat over the road cycle [J]",
    'cycle_dmf_torque': 'largest DMF spring torque magnitude in the road cycle [Nm]',
}
WORST = ('worst_order_1_5', 'worst_order_3', 'worst_torque_3', 'max_dmf_torque')
"""Metrics that are a maximum over states, reported with the speed and condition where."""
TIE_REL = 1e-9
"""Values within this relative distance of the largest are a tie when a metric names where its
worst value is (speed, condition): the first in grid or condition order is named. Load sets that
differ only at low speed give the same worst value above, equal but for the last bits, and a Dask
worker and this process may round those bits differently: a plain argmax then named either
condition."""


def condition_metrics(states, spring, step_rpm: float) -> dict:
    """Metrics of one design at one condition from its grid states (states.GridStates)."""
    st = states.stable | ~states.periodic          # what the driveline settles in or does
    s = states.speed_rpm[st]
    hi = states.mean[st] + states.max_dev[st]
    lo = states.mean[st] + states.min_dev[st]
    dmf = np.maximum(np.abs(spring.torque(hi)), np.abs(spring.torque(lo))) if st.any() else hi
    out: dict = {}
    for name, values in (('worst_order_1_5', states.order_1_5[st]),
                         ('worst_order_3', states.order_3[st]),
                         ('worst_torque_3', states.torque_3[st]), ('max_dmf_torque', dmf)):
        out[name], out[f'{name}_rpm'] = _worst(values, s)
    out['max_windup'] = float(hi.max()) if len(hi) else math.nan
    grid = states.grid
    n_stable = np.bincount(states.grid_index[states.stable], minlength=len(grid))
    sub = np.zeros(len(grid), dtype=bool)
    sub[states.grid_index[st & states.is_1_5]] = True
    out['rpm_1_5'] = float(sub.sum() * step_rpm)
    out['speeds_1_5'] = speed_ranges(grid[sub], step_rpm)
    none = n_stable == 0
    out['rpm_nonperiodic'] = float(none.sum() * step_rpm)
    out['speeds_nonperiodic'] = speed_ranges(grid[none], step_rpm)
    k = int(np.argmax(n_stable))
    out['max_stable_states'] = int(n_stable[k])
    out['max_stable_states_rpm'] = float(grid[k])
    out['n_branches'] = int(states.n_branches)
    return out


def design_summary(rows: list[dict]) -> dict:
    """A design's summary over its condition rows (every metric at its worst condition)."""
    out: dict = {}
    for name in WORST + ('max_stable_states',):
        vals = np.array([r[name] for r in rows], dtype=float)
        k = first_max(vals)
        out[name] = float(vals[k]) if name in WORST else int(vals[k])
        out[f'{name}_rpm'] = rows[k][f'{name}_rpm']
        out[f'{name}_condition'] = rows[k]['condition']
    out['max_windup'] = float(np.nanmax([r['max_windup'] for r in rows]))
    for name in ('rpm_1_5', 'rpm_nonperiodic'):
        out[name] = float(max(r[name] for r in rows))
    for name in ('speeds_1_5', 'speeds_nonperiodic'):
        out[name] = '; '.join(f'{r["condition"]}: {r[name]}' for r in rows if r[name])
    out['n_branches'] = int(max(r['n_branches'] for r in rows))
    return out


def first_max(values: np.ndarray) -> int:
    """Index of the first value within TIE_REL of the largest (NaN never counts; all NaN: 0)."""
    v = np.where(np.isnan(values), -np.inf, np.asarray(values, dtype=float))
    top = v.max()
    if not np.isfinite(top):
        return int(np.argmax(v))
    return int(np.flatnonzero(v >= top - TIE_REL * abs(top))[0])


def _worst(values: np.ndarray, speeds: np.ndarray) -> tuple[float, float]:
    if len(values) == 0 or np.all(np.isnan(values)):
        return math.nan, math.nan
    k = first_max(values)
    return float(values[k]), float(speeds[k])


def speed_ranges(speeds: np.ndarray, step_rpm: float) -> str:
    """Grid speeds as contiguous ranges, e.g. ``'720-800, 1010'`` [rpm]."""
    if len(speeds) == 0:
        return ''
    speeds = np.unique(speeds)
    breaks = np.flatnonzero(np.diff(speeds) > 1.5 * step_rpm)
    parts = []
    for a, b in zip(np.r_[0, breaks + 1], np.r_[breaks, len(speeds) - 1]):
        lo, hi = speeds[a], speeds[b]
        parts.append(f'{lo:g}' if lo == hi else f'{lo:g}-{hi:g}')
    return ', '.join(parts)
