"""The model beside a recording: its settings, natural frequencies, static wind-up and the
harmonic-balance prediction compared with the measured orders (bag analysis, last step).

Settings come from the options, else from what the recording node stored in the bag
(:class:`dmf_sim.bags.metadata.RunMetadata`: driveline, engine, load set, the whole DMF spring,
the load at the start of the recording), else from the defaults. The static wind-up of the mean
torque at each speed (``DrivelineExcitation.static_state``) gives the paper's green line,
theta minus static wind-up. The HBM is swept over the measured speed range; each *steady* speed
bin (enough cycles, :mod:`dmf_sim.analysis.order_bins`) is compared with the stable solution
nearest to it.
"""
from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dmf_sim.analysis.order_bins import LOAD_TOLERANCE, OrderTable
from dmf_sim.bags.metadata import RunMetadata
from dmf_sim.core.errors import BagError, ConfigError, ConvergenceError, one_line

__all__ = ['COMPARED', 'HBMOverlay', 'model_settings', 'with_stored_spring', 'build_model',
           'natural_frequencies', 'static_windups', 'hbm_overlay', 'overlay_all']

COMPARED = ('order_3', 'order_1_5', 'max_deviation', 'min_deviation', 'mean_minus_theta')
_HBM_KEYS = ('order_3', 'order_1_5', 'max_deviation', 'min_deviation', 'mean_minus_theta', 'mean',
             'theta_minus_static')
_BRANCHES_PER_LOAD = 1000   # curve branch ids of load level j start at j * this (plots apart)
_SOLVER_ERRORS = (ConvergenceError, np.linalg.LinAlgError, FloatingPointError)


# ------------------------------------------------------------------------------- settings

def with_stored_spring(line, spring: Mapping[str, Any] | None = None,
                       alpha: float | None = None, theta_rad: float | None = None):
    """``line`` with the DMF spring a recording stored in its metadata: the whole ``spring``
    (k [Nm/rad], stages, coast_stages, friction and end stops: ``Driveline.with_spring``), else
    its first drive stage's ``alpha`` / ``theta_rad`` [rad]; ``line`` itself where it stored none
    or the line has no DMF. An invalid spring raises as :meth:`Driveline.with_dmf` does
    (ConfigError, KeyError, TypeError, ValueError)."""
    if line.dmf is None:
        return line
    if spring is not None:
        return line.with_spring(spring)
    if alpha is not None or theta_rad is not None:
        return line.with_dmf(alpha=alpha, theta=theta_rad)
    return line


def model_settings(metadata: Mapping[str, Any] | None = None, *, config: str | None = None,
                   engine: str | None = None, alpha: float | None = None,
                   theta: float | None = None, load: float | None = None,
                   load_set: str | None = None) -> dict[str, Any]:
    """Model settings for the modes, the static wind-up and the HBM.

    Each value: the option if given, else what the recording stored in ``metadata``'s
    ``custom_data`` (RunMetadata: driveline, engine, load set, load, and the whole spring,
    rebuilt exactly with ``Driveline.with_spring``: stages, friction and end stops), else the
    default (truck_dmf, engine_d13, load
    set A, load 1.0, the YAML's spring). ``alpha``/``theta`` options change the first drive
    stage of that spring. ``sources`` says where each value came from; ``spring`` is the
    resulting spring (``PiecewiseLinearSpring.as_dict()``, None without a DMF)."""
    from dmf_sim.physics.model import read_driveline

    stored = RunMetadata.from_bag_metadata(metadata)
    out: dict[str, Any] = {}
    src: dict[str, str] = {}

    def pick(key: str, given, default):
        if given is not None:
            out[key], src[key] = given, 'option'
        elif getattr(stored, key, None) is not None:
            out[key], src[key] = getattr(stored, key), 'bag'
        else:
            out[key], src[key] = default, 'default'

    pick('driveline', config, 'truck_dmf')
    pick('engine', engine, 'engine_d13')
    pick('load_set', load_set, 'A')
    pick('load', load, 1.0)
    try:
        line = read_driveline(out['driveline'])
    except (OSError, ValueError) as exc:
        if src['driveline'] == 'option':
            raise BagError(f'--config {out["driveline"]!r} cannot be loaded: '
                           f'{one_line(exc)}') from None
        where = 'stored in the bag' if src['driveline'] == 'bag' else 'the default'
        raise BagError(f'driveline {out["driveline"]!r} ({where}) cannot be loaded: '
                       f'{one_line(exc)}; pass --config') from None
    spring_src = 'driveline YAML'
    if line.dmf is not None:
        try:
            if (stored.spring is not None or stored.alpha is not None
                    or stored.theta_rad is not None):
                line = with_stored_spring(line, stored.spring, stored.alpha, stored.theta_rad)
                spring_src = 'bag'
        except (ConfigError, KeyError, TypeError, ValueError) as exc:
            raise BagError('the DMF spring stored in the bag is invalid: '
                           f'{one_line(exc)}') from None
        line = line.with_dmf(alpha=alpha, theta=theta)
    spring = line.spring
    out['alpha'] = spring.alpha if spring is not None else None
    out['theta_rad'] = spring.theta if spring is not None else None
    out['spring'] = spring.as_dict() if spring is not None else None
    src['alpha'] = 'option' if alpha is not None else spring_src
    src['theta_rad'] = 'option' if theta is not None else spring_src
    src['spring'] = spring_src
    out['sources'] = src
    return out


def build_model(settings: Mapping[str, Any]):
    """The ReducedModel of ``settings`` (its exact spring)."""
    from dmf_sim.physics.model import read_driveline

    line = read_driveline(settings['driveline'])
    sp = settings.get('spring')
    if sp is not None and line.dmf is not None:
        line = line.with_spring(sp)
    return line.reduce()


def natural_frequencies(model) -> dict[str, list[float]]:
    """Linear natural frequencies [Hz] (rigid-body mode excluded) at primary and secondary DMF
    stiffness (modal.modes)."""
    from dmf_sim.physics.modal import REGIONS, modes

    regions = REGIONS if model.spring is not None else ('primary',)
    return {r: [float(v) for v in modes(model, r).frequencies_hz if v > 1e-6] for r in regions}


def static_windups(loads, speeds_rpm: Sequence[float], load: float) -> np.ndarray:
    """Wind-up [rad] the mean engine torque alone causes at each speed (NaN outside the engine
    data)."""
    out = np.full(len(speeds_rpm), np.nan)
    for i, s in enumerate(speeds_rpm):
        try:
            out[i] = loads.static_state(float(s), load).windup
        except (ConfigError, *_SOLVER_ERRORS):
            continue
    return out


# --------------------------------------------------------------------------- HBM overlay

@dataclass
class HBMOverlay:
    """HBM prediction on the measured speeds and its difference from the measurement.

    Attributes:
        speed_rpm: speeds the HBM was solved at (the table's rows).
        values: quantity -> HBM value per row (order_3, order_1_5, max/min deviation, mean,
            mean_minus_theta, theta_minus_static).
        stable: Floquet stability of each row's solution (None if not computed).
        curve: HBM curve for plotting (dict of lists, may hold several branches).
        difference: per compared quantity, over the steady rows: max_abs, rms_abs, mean_diff,
            hbm_peak, rel_to_peak (max |meas - hbm| over the HBM peak), at_speed_rpm, n_rows.
        settings: model, alpha, load, load set used; seconds: wall time; method: how solved.
    """

    speed_rpm: np.ndarray
    values: dict[str, np.ndarray]
    stable: np.ndarray | None
    curve: dict[str, Any] | None
    difference: dict[str, dict[str, float]]
    settings: dict[str, Any]
    seconds: float
    method: str = ''
    branch: np.ndarray | None = None
    events: list = field(default_factory=list)


def _differences(meas: Mapping[str, np.ndarray | None], pred: Mapping[str, np.ndarray],
                 speed: np.ndarray, rows: np.ndarray) -> dict[str, dict[str, float]]:
    """Measured minus HBM per quantity over the rows selected by the mask ``rows``."""
    out = {}
    for k in COMPARED:
        if meas.get(k) is None or k not in pred:
            continue
        m, p = np.asarray(meas[k], float), np.asarray(pred[k], float)
        ok = np.isfinite(m) & np.isfinite(p) & rows
        if not ok.any():
            continue
        d = m[ok] - p[ok]
        i = int(np.argmax(np.abs(d)))
        peak = float(np.max(np.abs(p[ok])))
        out[k] = {'max_abs': float(abs(d[i])), 'at_speed_rpm': float(speed[ok][i]),
                  'rms_abs': float(np.sqrt(np.mean(d ** 2))), 'mean_diff': float(np.mean(d)),
                  'hbm_peak': peak,
                  'rel_to_peak': float(abs(d[i]) / peak) if peak > 0 else math.nan,
                  'n_rows': int(ok.sum())}
    return out


def _branch_candidates(branches, speed: float) -> list[dict[str, Any]]:
    """Every solution of the swept branches at ``speed`` (linear interpolation between the two
    continuation points around it; a branch folding back gives several)."""
    out = []
    for b in branches:
        pts = b.points
        for p, q in zip(pts[:-1], pts[1:]):
            s0, s1 = p.speed_rpm, q.speed_rpm
            if not (min(s0, s1) <= speed <= max(s0, s1)) or s0 == s1:
                continue
            f = (speed - s0) / (s1 - s0)
            d0, d1 = p.summary.as_dict(), q.summary.as_dict()
            cand = {k: (1 - f) * d0[k] + f * d1[k] for k in _HBM_KEYS}
            cand['stable'] = (p if f < 0.5 else q).stable
            cand['branch'] = b.id
            out.append(cand)
        if len(pts) == 1 and abs(pts[0].speed_rpm - speed) < 1e-6:
            d = pts[0].summary.as_dict()
            out.append({**{k: d[k] for k in _HBM_KEYS}, 'stable': pts[0].stable, 'branch': b.id})
    return out


def _pick(cands: list[dict[str, Any]], meas: Mapping[str, float]) -> dict[str, Any]:
    """The stable candidate (any candidate if none is stable) nearest to the measurement in the
    3rd and 1.5th order amplitudes and the mean wind-up."""
    pool = [c for c in cands if c['stable'] is not False] or cands

    def dist(c):
        return sum((c[k] - m) ** 2 for k in ('order_3', 'order_1_5', 'mean')
                   if (m := meas.get(k)) is not None and math.isfinite(m))

    return min(pool, key=dist)


def _sweep(hbm_mod, loads, load: float, lo: float, hi: float, step_rpm: float):
    """(swept result or None, curve dict, events, method text)."""
    curve: dict[str, list] = {k: [] for k in ('speed_rpm', 'branch', 'stable') + _HBM_KEYS}
    try:
        swept = hbm_mod.sweep(loads, load, (math.floor(lo), math.ceil(hi)),   # no envelopes used
                              options=hbm_mod.SweepOptions(step_rpm=step_rpm,
                                                           search=hbm_mod.SearchOptions(
                                                               nonperiodic_speeds=())))
    except (*_SOLVER_ERRORS, ConfigError) as exc:
        return None, curve, [], f'sweep failed ({type(exc).__name__}: {one_line(exc)})'
    for b in swept.branches:
        for p in b.points:
            curve['speed_rpm'].append(float(p.speed_rpm))
            curve['branch'].append(int(b.id))
            curve['stable'].append(None if p.stable is None else bool(p.stable))
            d = p.summary.as_dict()
            for k in _HBM_KEYS:
                curve[k].append(float(d[k]))
    return (swept, curve, [e.as_dict() for e in swept.events],
            'condensed HBM sweep (pseudo-arc-length continuation, Floquet stability, '
            '1.5th-order branch switching)')


def _solve_along(hbm_mod, loads, load: float, rows: np.ndarray, which: list[int],
                 direction: int, values: dict[str, np.ndarray]) -> None:
    """Natural continuation over the rows ``which`` along the ramp direction."""
    solver = hbm_mod.CondensedHBM(loads, load)
    x = None
    for i in sorted(which, key=lambda i: rows[i] * (1 if direction >= 0 else -1)):
        try:
            pt = solver.solve(float(rows[i]), x)
        except _SOLVER_ERRORS:
            try:
                pt = solver.solve(float(rows[i]))
            except _SOLVER_ERRORS:
                x = None
                continue
        x = pt.x
        d = pt.summary.as_dict()
        for k in _HBM_KEYS:
            values[k][i] = d[k]


def hbm_overlay(table: OrderTable, loads, load: float, *, direction: int = 1,
                settings: Mapping[str, Any] | None = None, step_rpm: float = 10.0,
                use_sweep: bool = True) -> HBMOverlay:
    """Harmonic-balance prediction of the DMF wind-up for the same model, engine, load set and
    load over the measured speed range, and its difference from the measurement per Fig. 13
    quantity over the table's steady rows.

    The HBM is swept over the measured range with :func:`dmf_sim.solvers.hbm.sweep`. At each
    measured speed the stable solutions there are candidates; where several coexist, the one
    nearest to the measurement (3rd and 1.5th order amplitude, mean) is compared -- which one a
    run-up lands on depends on its history, not on the speed alone. Speeds no swept branch covers
    are solved by natural continuation along the recording's ramp direction (``direction`` +1
    rising, -1 falling). Rows outside the engine data's speed range are NaN.
    """
    from dmf_sim.solvers import hbm as hbm_mod

    t0 = time.perf_counter()
    rows = np.asarray(table.speed_mean_rpm, float)
    lo, hi = float(np.nanmin(rows)), float(np.nanmax(rows))
    rng = getattr(loads.engine, 'speed_range_rpm', None)
    if rng is not None:
        lo, hi = max(lo, float(rng[0])), min(hi, float(rng[1]))
    hi = max(hi, lo + 1e-9)
    values = {k: np.full(len(rows), np.nan) for k in _HBM_KEYS}
    stable = np.full(len(rows), None, dtype=object)
    branch = np.full(len(rows), -1)
    inside = (rows >= lo - 1e-9) & (rows <= hi + 1e-9)
    meas = {'order_3': table.order_3, 'order_1_5': table.order_1_5, 'mean': table.mean}
    swept, curve, events, method = (_sweep(hbm_mod, loads, load, lo, hi, step_rpm) if use_sweep
                                    else (None, None, [], ''))
    methods = [method] if method else []
    if swept is not None:
        for i in np.flatnonzero(inside):
            if cands := _branch_candidates(swept.branches, float(rows[i])):
                c = _pick(cands, {k: float(v[i]) for k, v in meas.items()})
                for k in _HBM_KEYS:
                    values[k][i] = c[k]
                stable[i], branch[i] = c['stable'], c['branch']
    missing = [i for i in np.flatnonzero(inside) if not math.isfinite(values['order_3'][i])]
    if missing:
        _solve_along(hbm_mod, loads, load, rows, missing, direction, values)
        methods.append(f'natural continuation along the ramp for {len(missing)} speeds')
        if swept is None:
            ok = np.isfinite(values['order_3'])
            curve = {'speed_rpm': rows[ok].tolist(), 'branch': [0] * int(ok.sum()),
                     'stable': [None] * int(ok.sum()),
                     **{k: values[k][ok].tolist() for k in _HBM_KEYS}}
    meas_all = {**meas, 'max_deviation': table.max_deviation,
                'min_deviation': table.min_deviation, 'mean_minus_theta': table.mean_minus_theta}
    diff = _differences(meas_all, values, rows, table.steady)
    st = dict(settings or {})
    st.update(load=float(load), speed_range_rpm=[lo, hi])
    return HBMOverlay(rows, values, stable, curve, diff, st, time.perf_counter() - t0,
                      method='; '.join(methods), branch=branch, events=events)


def _ramp_direction(speed_rpm: np.ndarray, t_start: np.ndarray) -> int:
    """+1 if the speed mostly rises over the recording, -1 if it falls."""
    if len(speed_rpm) < 2 or np.ptp(t_start) == 0:
        return 1
    return 1 if np.polyfit(t_start, speed_rpm, 1)[0] >= 0 else -1


def overlay_all(res, settings: Mapping[str, Any], *, hbm: bool = True) -> dict[str, list[float]]:
    """Model quantities beside a :class:`dmf_sim.analysis.pipeline.BagAnalysis` (set in place):
    the static wind-up of the mean torque on every wind-up table (the green line) and, with
    ``hbm``, the HBM overlay on every wind-up signal (other signals get a warning). Each row is
    compared at its own load when the table has one per row (the load the bag recorded), else
    at ``settings['load']``. Returns the natural frequencies of the model."""
    model = build_model(settings)
    natural = natural_frequencies(model)
    res.model = {k: settings[k] for k in ('driveline', 'engine', 'alpha', 'theta_rad', 'load_set',
                                          'load')}
    windups = [s for s in res.signals if s.signal.kind == 'windup']
    per_row = any(s.table.load is not None for s in windups)
    if per_row:
        res.model['load'] = _levels(windups)
    if hbm:
        for s in res.signals:
            if s.signal.kind != 'windup':
                res.warnings.append('HBM overlay is computed for the DMF wind-up only, not for '
                                    f'{s.signal.label}')
    sources = settings.get('sources', {})
    guessed = [f'{key} {settings[key]}' for key in ('driveline', 'engine', 'load_set')
               if sources.get(key) == 'default']
    if settings.get('alpha') is not None and sources.get('spring') == 'driveline YAML' \
            and 'option' not in (sources.get('driveline'), sources.get('alpha'),
                                 sources.get('theta_rad')):
        guessed.append(f'the DMF spring of the driveline YAML (alpha {settings["alpha"]:g}, '
                       f'theta {settings["theta_rad"]:g} rad)')
    if guessed:
        res.warnings.append(f'the bag does not record the model: assumed {", ".join(guessed)} '
                            '(set --config/--engine/--load-set/--alpha/--theta)')
    if model.spring is None:
        if windups:
            res.warnings.append(f'driveline {settings["driveline"]!r} has no DMF: no static '
                                'wind-up and no HBM overlay')
        return natural
    if not windups:
        return natural
    from dmf_sim.physics.engine import load_error, read_engine
    from dmf_sim.physics.loads import DrivelineExcitation

    loads = DrivelineExcitation(model, read_engine(settings['engine'],
                                                   load_set=settings['load_set']))
    what = '--load' if sources.get('load') == 'option' else 'the load the bag records'
    for level in res.model['load'] if per_row else [settings['load']]:
        if reason := load_error(loads.engine, level, what):     # braking, but no brake curve
            raise ConfigError(f'engine {settings["engine"]}: {reason}')
    keep = {k: settings[k] for k in ('driveline', 'engine', 'alpha', 'theta_rad', 'load_set')}
    for sig in windups:
        if sig.table.load is None:
            sig.table.static_windup = static_windups(loads, sig.table.speed_mean_rpm,
                                                     settings['load'])
            if hbm:
                sig.hbm = hbm_overlay(sig.table, loads, settings['load'],
                                      direction=_ramp_direction(sig.cycles.speed_rpm,
                                                                sig.cycles.t_start),
                                      settings=keep)
        else:
            _overlay_per_load(sig, loads, keep, hbm)
    source = sources.get('load')
    if not per_row and source == 'default':
        res.warnings.append('the bag does not record the engine load: static wind-up and HBM '
                            'at load 1.0 (set --load)')
    elif not per_row and source == 'bag':
        res.warnings.append(f'the bag records the engine load only at the start of the recording '
                            f'({settings["load"]:g}, metadata.yaml), no health statuses or load '
                            'setpoints: assumed constant (set --load if it changed)')
    return natural


def _levels(windups) -> list[float]:
    """The distinct known loads of the wind-up tables' rows, ascending."""
    vals = np.concatenate([s.table.load for s in windups if s.table.load is not None])
    return sorted({float(v) for v in vals[np.isfinite(vals)]})


def _overlay_per_load(sig, loads, settings: Mapping[str, Any], hbm: bool) -> None:
    """Static wind-up and HBM of each row at its own load (rows of unknown load get neither):
    one overlay per load level, merged into one :class:`HBMOverlay` (curve branches numbered
    apart per level, ``curve['load']`` says which)."""
    table = sig.table
    n = len(table)
    table.static_windup = np.full(n, np.nan)
    key = np.where(np.isfinite(table.load), np.round(table.load / LOAD_TOLERANCE), np.nan)
    groups = [np.flatnonzero(key == k) for k in np.unique(key[np.isfinite(key)])]
    levels = [float(table.load[g[0]]) for g in groups]
    if not hbm:
        for rows, level in zip(groups, levels):
            table.static_windup[rows] = static_windups(loads, table.speed_mean_rpm[rows], level)
        return
    values = {k: np.full(n, np.nan) for k in _HBM_KEYS}
    stable = np.full(n, None, dtype=object)
    branch = np.full(n, -1)
    curve: dict[str, list] = {}
    events, methods, seconds = [], [], 0.0
    for j, (rows, level) in enumerate(zip(groups, levels)):
        table.static_windup[rows] = static_windups(loads, table.speed_mean_rpm[rows], level)
        at = np.isfinite(sig.cycle_load) & (np.abs(sig.cycle_load - level) <= LOAD_TOLERANCE)
        ov = hbm_overlay(table.select(rows), loads, level,
                         direction=_ramp_direction(sig.cycles.speed_rpm[at],
                                                   sig.cycles.t_start[at]),
                         settings=settings)
        for k in _HBM_KEYS:
            values[k][rows] = ov.values[k]
        stable[rows] = ov.stable
        branch[rows] = np.where(ov.branch >= 0, ov.branch + j * _BRANCHES_PER_LOAD, -1)
        for k, v in (ov.curve or {}).items():
            curve.setdefault(k, []).extend(
                [b + j * _BRANCHES_PER_LOAD for b in v] if k == 'branch' else v)
        curve.setdefault('load', []).extend([level] * len(ov.curve['speed_rpm'])
                                            if ov.curve else [])
        events += [{**e, 'load': level} for e in ov.events]
        methods.append((level, ov.method))
        seconds += ov.seconds
    meas = {'order_3': table.order_3, 'order_1_5': table.order_1_5,
            'max_deviation': table.max_deviation, 'min_deviation': table.min_deviation,
            'mean_minus_theta': table.mean_minus_theta}
    diff = _differences(meas, values, table.speed_mean_rpm, table.steady)
    speeds = table.speed_mean_rpm[np.isfinite(table.load)]
    st = {**settings, 'load': levels if len(levels) != 1 else levels[0],
          'speed_range_rpm': [float(np.min(speeds)), float(np.max(speeds))] if len(speeds)
          else []}
    by_method: dict[str, list[float]] = {}
    for level, method in methods:
        by_method.setdefault(method, []).append(level)
    text = '; '.join(f'load {", ".join(f"{v:g}" for v in lv)}: {m}' for m, lv in by_method.items())
    sig.hbm = HBMOverlay(table.speed_mean_rpm, values, stable, curve or None, diff, st, seconds,
                         method=text, branch=branch, events=events)
