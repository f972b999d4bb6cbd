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
:mod:`dmf_sim.live.peaks`; a design's summary row gets, over all its load steps
(:func:`transient_summary`, the study columns the optimizer's transient objective reads):

* ``transient_windup``: the largest wind-up magnitude [rad] (either sign), and the step where;
* ``transient_dmf_torque``: the largest DMF spring torque magnitude [Nm] at those peaks, and where;
* ``transient_stop_contacts``: end-stop contacts in all steps together (0 for a spring without
  stops: nothing to hit); ``transient_travel_margin``: the smallest distance to a stop [rad]
  (NaN without stops);
* ``transient_seconds``: compute time of the steps.
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
           'step_metrics', 'transient_summary']

LOAD_STEP_DT_S = RunOptions.dt
"""Newmark step [s] of a load step: ``dmf-sim run``'s default (a rise shorter is refused)."""

LOAD_STEP_KEYS = (('speed_rpm', 'from', 'to', 'rise_s'), ('hold_s', 'settle_s', 'load_set'))
"""Required and optional keys of one load step."""

TRANSIENT = ('transient_windup', 'transient_dmf_torque', 'transient_stop_contacts',
             'transient_travel_margin')
"""The summary columns of the load steps (module docstring)."""


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
    (:meth:`dmf_sim.live.peaks.WindupPeaks.as_dict`) and its compute time ``seconds``;
    ``dt``: the Newmark step [s] (a finer one checks the study's, ``dmf_sim.optimize.verify``)."""
    from dmf_sim.live.simulation import LiveSimulation
    t0 = time.perf_counter()
    prof = step.profile()
    lo, hi = getattr(engine, 'speed_range_rpm', (0.0, math.inf))
    sim = LiveSimulation(line, engine, dt=dt, speed_rpm=step.speed_rpm,
                         load=step.from_load, speed_limits_rpm=(lo, hi))
    out = follow_profile(sim, prof).as_dict()
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
                                        else math.nan),
            'transient_seconds': sum(r['seconds'] for r in results)}
