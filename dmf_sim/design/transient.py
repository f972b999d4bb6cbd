"""Load steps of a design study: tip-ins and tip-outs run per design in the time domain.

A study's ``conditions.load_steps`` (``dmf_sim.design.study``) lists load steps::

    load_steps:
      - {speed_rpm: 1200, from: 0, to: 1, rise_s: 0.1}                # tip-in and back
      - {speed_rpm: 1600, from: 0, to: -1, rise_s: 0.1, hold_s: 0.5}  # into the full brake
      # optional: hold_s (default 1 s), settle_s (default 2 s), load_set (default the first)

Each is the profile ``step:SPEED:FROM:TO:RISE:HOLD:SETTLE``
(:func:`dmf_sim.transient.profiles.step_profile`: SETTLE s at FROM from static equilibrium,
FROM -> TO in RISE s, HOLD s, back in RISE s, HOLD s) integrated per design by the live core as
``dmf-sim run`` integrates it, without a bag (:func:`dmf_sim.transient.run.follow_profile`,
Newmark step :data:`LOAD_STEP_DT_S`). What it measures are the peaks of
:mod:`dmf_sim.live.peaks`, the wind-up's after the step's SETTLE (the start from static
equilibrium is not the step: the run's summary leaves it out too; the stop contacts and the
friction heat are the whole profile's, as there); a design's summary row gets, over all its
load steps
(:func:`transient_summary`, the study columns the optimizer's transient objective reads):

* ``transient_windup``: the largest wind-up magnitude [rad] (either sign), and the step where;
* ``transient_dmf_torque``: the largest DMF spring torque magnitude [Nm] at those peaks, and where;
* ``transient_stop_contacts``: end-stop contacts in all steps together (0 for a spring without
  stops: nothing to hit); ``transient_travel_margin``: the smallest distance to a stop [rad]
  (None without stops: no stop, no margin; an empty field of the CSV table, null in Parquet);
* ``transient_seconds``: compute time of the steps.

A study's ``conditions.road_cycle`` runs one drive cycle per design the same way (the thermal
load a DMF carries in service)::

    road_cycle: {profile: truck_road_cycle, from_s: 10, to_s: 42}
      # optional: from_s (default 0), to_s (default the profile's end) [s], a window of the
      # profile; settle_s (default 2 s) at its first row before the window; load_set

The profile (a packaged name, a CSV/YAML path: :func:`dmf_sim.transient.profiles.read_profile`)
cut to the window [from_s, to_s] (linear between rows, as the run follows it), started from
static equilibrium at its first row and held there ``settle_s`` first (not counted), gives
(:func:`cycle_metrics`, :func:`cycle_summary`):

* ``cycle_friction_heat``: the arc-spring friction's work over the window [J] (the kernel's,
  eq. 8a of doc/theory.md, summed at every Newmark step; 0 for a spring without friction): the
  heat the grease and the arc springs take;
* ``cycle_dmf_torque``: the largest DMF spring torque magnitude in the window [Nm];
* ``cycle_seconds``: its compute time.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.validation import Where
from dmf_sim.design.metrics import first_max
from dmf_sim.physics.engine import load_error
from dmf_sim.transient.profiles import DEFAULT_HOLD_S, DEFAULT_SETTLE_S, Profile, step_profile
from dmf_sim.transient.run import RunOptions, follow_profile

__all__ = ['LOAD_STEP_DT_S', 'LOAD_STEP_KEYS', 'TRANSIENT', 'LoadStep', 'parse_load_steps',
           'step_metrics', 'transient_summary', 'ROAD_CYCLE_KEYS', 'CYCLE', 'RoadCycle',
           'parse_road_cycle', 'cycle_metrics', 'cycle_summary']

LOAD_STEP_DT_S = RunOptions.dt
"""Newmark step [s] of a load step: ``dmf-sim run``'s default (a rise shorter is refused)."""

LOAD_STEP_KEYS = (('speed_rpm', 'from', 'to', 'rise_s'), ('hold_s', 'settle_s', 'load_set'))
"""Required and optional keys of one load step."""

TRANSIENT = ('transient_windup', 'transient_dmf_torque', 'transient_stop_contacts',
             'transient_travel_margin')
"""The summary columns of the load steps (module docstring)."""

ROAD_CYCLE_KEYS = (('profile',), ('from_s', 'to_s', 'settle_s', 'load_set'))
"""Required and optional keys of the road cycle."""

CYCLE = ('cycle_friction_heat', 'cycle_dmf_torque')
"""The summary columns of the road cycle (module docstring)."""

MAX_CYCLE_SETTLE_S = 60.0
"""Longest settling time before the road cycle's window [s]."""


@dataclass(frozen=True)
class LoadStep:
    """One load step: speed [rpm], from and to load (-1..1), rise, hold and settle [s], the
    engine's load set."""

    speed_rpm: float
    from_load: float
    to_load: float
    rise_s: float
    hold_s: float = DEFAULT_HOLD_S
    settle_s: float = DEFAULT_SETTLE_S
    load_set: str = 'A'

    def profile(self) -> Profile:
        return step_profile(self.speed_rpm, self.from_load, self.to_load, self.rise_s,
                            self.hold_s, self.settle_s)

    @property
    def label(self) -> str:
        """How the step is named in the study's columns: its ``step:`` spec and load set."""
        return f'{self.profile().name} {self.load_set}'

    def as_dict(self) -> dict:
        return {'speed_rpm': self.speed_rpm, 'from': self.from_load, 'to': self.to_load,
                'rise_s': self.rise_s, 'hold_s': self.hold_s, 'settle_s': self.settle_s,
                'load_set': self.load_set}


def parse_load_steps(w: Where, raw, engines: dict) -> list[LoadStep]:
    """The study's ``conditions.load_steps`` (absent or empty: none), each checked as the run
    checks a profile: fields and ranges, the engine's speed data and load range (braking needs a
    brake curve), a rise of at least one Newmark step; one-line errors naming the step."""
    if raw is None:
        return []
    if not isinstance(raw, list):
        raise w.error('conditions.load_steps', 'must be a list of load steps {speed_rpm, from, '
                      'to, rise_s[, hold_s, settle_s, load_set]}', raw)
    steps = []
    for i, item in enumerate(raw):
        field = f'conditions.load_steps[{i}]'
        d = w.mapping(item, field, *LOAD_STEP_KEYS)
        load_set = d.get('load_set', next(iter(engines)))
        if load_set not in engines:
            raise w.error(f'{field}.load_set', f'must be one of the conditions.load_sets '
                          f'({", ".join(engines)})', load_set)
        engine = engines[load_set]
        where = f'{w.source}: {field}'
        prof = step_profile(d['speed_rpm'], d['from'], d['to'], d['rise_s'],
                            d.get('hold_s', DEFAULT_HOLD_S), d.get('settle_s', DEFAULT_SETTLE_S),
                            where=where)
        lo, hi = getattr(engine, 'speed_range_rpm', (0.0, math.inf))
        speed = float(prof.speed_rpm[0])
        if not lo <= speed <= hi:
            raise w.error(f'{field}.speed_rpm', f'outside the engine data ({lo:g}..{hi:g} rpm)',
                          speed)
        for key, value in (('from', float(d['from'])), ('to', float(d['to']))):
            if reason := load_error(engine, value, f'{field}.{key}'):
                raise ConfigError(f'{w.source}: {reason}')
        try:
            prof.check_load_steps(LOAD_STEP_DT_S, "the study's Newmark step")
        except ConfigError:
            raise w.error(f'{field}.rise_s', f'a load change faster than one Newmark step '
                          f'({LOAD_STEP_DT_S:g} s)', float(d['rise_s'])) from None
        steps.append(LoadStep(speed, float(d['from']), float(d['to']), float(d['rise_s']),
                              float(d.get('hold_s', DEFAULT_HOLD_S)),
                              float(d.get('settle_s', DEFAULT_SETTLE_S)), str(load_set)))
    if len(set(steps)) != len(steps):
        raise w.error('conditions.load_steps', 'repeated load steps')
    return steps


def step_metrics(line, engine, step: LoadStep, dt: float = LOAD_STEP_DT_S) -> dict:
    """The peaks of one load step of the driveline ``line`` (a design) under ``engine``
    (:meth:`dmf_sim.live.peaks.WindupPeaks.as_dict`; the wind-up's after the step's settle, as
    ``dmf-sim run`` reports them) and its compute time ``seconds``;
    ``dt``: the Newmark step [s] (a finer one checks the study's, ``dmf_sim.optimize.verify``)."""
    from dmf_sim.live.simulation import LiveSimulation
    t0 = time.perf_counter()
    prof = step.profile()
    lo, hi = getattr(engine, 'speed_range_rpm', (0.0, math.inf))
    sim = LiveSimulation(line, engine, dt=dt, speed_rpm=step.speed_rpm,
                         load=step.from_load, speed_limits_rpm=(lo, hi))
    out = follow_profile(sim, prof, peaks_after_s=prof.start_settle_s).as_dict()
    out['seconds'] = time.perf_counter() - t0
    return out


def transient_summary(steps: list[LoadStep], results: list[dict]) -> dict:
    """The design's transient columns over its load steps (module docstring)."""
    if not steps:
        return {}
    windup = [max(abs(r['peak_windup_rad'][0]), abs(r['peak_windup_rad'][1])) for r in results]
    torque = [max(abs(r['peak_dmf_torque_nm'][0]), abs(r['peak_dmf_torque_nm'][1]))
              for r in results]
    kw, kt = first_max(np.array(windup)), first_max(np.array(torque))
    stops = [r for r in results if 'stop_contacts' in r]
    return {'transient_windup': windup[kw], 'transient_windup_condition': steps[kw].label,
            'transient_dmf_torque': torque[kt],
            'transient_dmf_torque_condition': steps[kt].label,
            'transient_stop_contacts': sum(r['stop_contacts'] for r in stops),
            'transient_travel_margin': (min(r['travel_margin_rad'] for r in stops) if stops
                                        else None),
            'transient_seconds': sum(r['seconds'] for r in results)}


@dataclass(frozen=True)
class RoadCycle:
    """The study's road cycle: the profile's spec as given, the window [from_s, to_s] [s], the
    settling time before it [s] and the engine's load set; ``window``: the cut profile."""

    profile: str
    from_s: float
    to_s: float
    settle_s: float
    load_set: str
    window: Profile

    @property
    def label(self) -> str:
        return f'{self.window.name} {self.load_set}'

    def as_dict(self) -> dict:
        return {'profile': self.profile, 'from_s': self.from_s, 'to_s': self.to_s,
                'settle_s': self.settle_s, 'load_set': self.load_set}


def parse_road_cycle(w: Where, raw, engines: dict) -> RoadCycle | None:
    """The study's ``conditions.road_cycle`` (absent: None), checked as the run checks a profile:
    readable, the window inside it, its speeds in the engine data, its loads allowed by the
    engine; one-line errors naming the field."""
    from dmf_sim.transient.profiles import read_profile
    if raw is None:
        return None
    field = 'conditions.road_cycle'
    d = w.mapping(raw, field, *ROAD_CYCLE_KEYS)
    spec = d['profile']
    if not isinstance(spec, str) or not spec.strip():
        raise w.error(f'{field}.profile', 'must be a profile name or path', spec)
    try:
        profile = read_profile(spec)
    except ConfigError as exc:
        raise w.error(f'{field}.profile', str(exc)) from None
    end = profile.duration_s
    from_s = w.number(d.get('from_s', 0.0), f'{field}.from_s', 0.0, end, 's', hi_open=True)
    to_s = w.number(d.get('to_s', end), f'{field}.to_s', from_s, end, 's', lo_open=True)
    settle = w.number(d.get('settle_s', DEFAULT_SETTLE_S), f'{field}.settle_s', 0.0,
                      MAX_CYCLE_SETTLE_S, 's')
    load_set = d.get('load_set', next(iter(engines)))
    if load_set not in engines:
        raise w.error(f'{field}.load_set', f'must be one of the conditions.load_sets '
                      f'({", ".join(engines)})', load_set)
    engine = engines[load_set]
    window = profile.window(from_s, to_s)
    lo, hi = getattr(engine, 'speed_range_rpm', (0.0, math.inf))
    bad = (window.speed_rpm < lo) | (window.speed_rpm > hi)
    if bad.any():
        raise w.error(f'{field}.profile', f'speed outside the engine data ({lo:g}..{hi:g} rpm) '
                      f'at {from_s + window.t_s[bad][0]:g} s', float(window.speed_rpm[bad][0]))
    for x in (float(window.load.min()), float(window.load.max())):
        if reason := load_error(engine, x, f'{field}.profile load'):
            raise ConfigError(f'{w.source}: {reason}')
    return RoadCycle(str(spec), from_s, to_s, settle, str(load_set), window)


def cycle_metrics(line, engine, cycle: RoadCycle, dt: float = LOAD_STEP_DT_S) -> dict:
    """The road cycle of the driveline ``line`` (a design) under ``engine``: held ``settle_s``
    at the window's first row from static equilibrium, then the window, whose peaks
    (:meth:`dmf_sim.live.peaks.WindupPeaks.as_dict`, friction heat included) are returned with
    the compute time ``seconds``; ``dt``: the Newmark step [s]."""
    from dmf_sim.live.simulation import LiveSimulation
    from dmf_sim.transient.profiles import make_profile
    t0 = time.perf_counter()
    win = cycle.window
    speed, load = float(win.speed_rpm[0]), float(win.load[0])
    lo, hi = getattr(engine, 'speed_range_rpm', (0.0, math.inf))
    sim = LiveSimulation(line, engine, dt=dt, speed_rpm=speed, load=load,
                         speed_limits_rpm=(lo, hi))
    if cycle.settle_s > 0:
        follow_profile(sim, make_profile([(0.0, speed, load), (cycle.settle_s, speed, load)],
                                         name='settle'))
    out = follow_profile(sim, win).as_dict()          # the peaks start afresh here
    out['seconds'] = time.perf_counter() - t0
    return out


def cycle_summary(cycle: RoadCycle | None, result: dict | None) -> dict:
    """The design's road-cycle columns (module docstring); none without a road cycle."""
    if cycle is None or result is None:
        return {}
    torque = max(abs(result['peak_dmf_torque_nm'][0]), abs(result['peak_dmf_torque_nm'][1]))
    return {'cycle_friction_heat': float(result.get('friction_heat_j', 0.0)),
            'cycle_dmf_torque': torque, 'cycle_dmf_torque_condition': cycle.label,
            'cycle_seconds': result['seconds']}
