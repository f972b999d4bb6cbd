"""Faults of the virtual truck: their description, validation, schedule and ground truth.

One grammar for every way a fault comes in: a schedule file (``faults: [...]``, beside a
profile in ``dmf-sim run --faults FILE``), the node's string parameters and its
``faults/inject`` topic. A fault is a mapping; the live forms are the same mapping in YAML flow
style, e.g. ``{kind: misfire, cylinders: [3], mode: single}`` or ``{kind: weak_cylinder,
cylinder: 5, factor: 0.7}``.

========================  ======================================================================
kind                      fields (besides the window ``start_s``, ``end_s`` or ``duration_s``)
========================  ======================================================================
``misfire``               ``cylinders`` (1-based list), ``mode`` single (default) | every_cycle |
                          random; random: ``probability`` (per combustion) or ``rate_per_s``,
                          ``seed``; single: ``at_s`` (or ``start_s``), no end
``weak_cylinder``         ``cylinder``, ``factor`` in [0, 1): the combustion torque scaled
``dmf_stiffness``         ``stage`` (1 = the primary stiffness k, 2.. = the drive stages beyond
                          the knees, ``coast_1``.. the coast stages), ``factor`` in (0, 1]
``dmf_broken``            ``stage`` (>= 2 or ``coast_j``): the stage's stiffness increment gone
``dmf_damping``           ``factor`` in [0, 100]: the DMF damping scaled
``sensor_edges``          ``sensor`` (a tooth wheel), ``mode`` missing | extra; missing:
                          ``probability`` (per edge) or ``tooth`` (that tooth every revolution);
                          extra: ``rate_per_s``; ``seed``
``bus_signal``            ``signal`` (a bus signal), ``mode`` stuck | noisy; noisy: ``sigma_rpm``;
                          ``seed``
========================  ======================================================================

Times are simulated seconds. ``start_s`` absent: from the start of a run (schedule) or from now
(live); ``end_s``/``duration_s`` absent: to the end of the run or until cleared. Every refusal
is one line naming the fault (``faults[2] (misfire)``) and the field: unknown keys, NaN, a
cylinder outside 1..n_cyl, a stage the DMF does not have, an unknown sensor or bus signal (when
the caller names the known ones), an inverted window, and windows of the same kind on the same
target that overlap (``misfire`` on one cylinder, ``dmf_stiffness``/``dmf_broken`` on one stage,
...). Two single misfires never overlap: each takes the next combustion not taken yet.

What a fault does:

* combustion (doc/theory.md, "Faults"): cylinder k fires with a combustion factor s_k (1
  healthy, 0 misfire, ``factor`` of a weak cylinder); s_k changes only where fired and motored
  torques agree, at the cylinder's bottom dead centre before its compression stroke: combustion
  m of cylinder k owns the crank-angle window [TDC_km - 180 deg, TDC_km + 540 deg) with TDC_km =
  beta_k + 720 deg m. Its factor is decided when its window opens; a single misfire therefore
  removes exactly one combustion. :meth:`FaultSet.combustion_factors` gives the persistent part
  (every-cycle misfires and weak cylinders), what a periodic steady state sees;
* the DMF: :meth:`FaultSet.apply_to_driveline` returns the driveline with the spring's stages
  changed (the one spring object, :class:`~dmf_sim.physics.spring.PiecewiseLinearSpring`) and the
  DMF damping scaled;
* sensors: parsed and validated here, applied by the sensor signal synthesis
  (:attr:`FaultTimeline.sensor_faults`).

:class:`FaultTimeline` is the ground truth: which faults are active at which time, which
combustion events misfired (random ones reproducible from the seed), every start and end as a
:class:`FaultEvent` (the key/value layout of the ``faults/ground_truth`` statuses is
:meth:`FaultEvent.values`, read back with :func:`event_from_values`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Collection, Iterable, Mapping, Sequence

import numpy as np
import yaml

from dmf_sim.core.errors import ConfigError, one_line
from dmf_sim.core.paths import parse_yaml, read_yaml_mapping
from dmf_sim.core.validation import SEED_MAX, check_keys, field_error, number
from dmf_sim.physics.model import Driveline

__all__ = ['FAULT_KINDS', 'COMBUSTION_KINDS', 'DMF_KINDS', 'SENSOR_KINDS', 'MISFIRE_MODES',
           'EDGE_MODES', 'BUS_MODES', 'DMF_DAMPING_FACTOR_MAX', 'SEED_MAX', 'WINDOW_OPEN_RAD',
           'CYCLE_RAD', 'Fault', 'FaultSet', 'FaultSchedule', 'FaultEvent', 'FaultTimeline',
           'known_sensors', 'parse_fault', 'parse_faults', 'parse_request', 'read_schedule',
           'check_overlaps',
           'event_from_values', 'combustion_windows']

FAULT_KINDS = ('misfire', 'weak_cylinder', 'dmf_stiffness', 'dmf_broken', 'dmf_damping',
               'sensor_edges', 'bus_signal')
COMBUSTION_KINDS = ('misfire', 'weak_cylinder')
DMF_KINDS = ('dmf_stiffness', 'dmf_broken', 'dmf_damping')
SENSOR_KINDS = ('sensor_edges', 'bus_signal')
MISFIRE_MODES = ('single', 'every_cycle', 'random')
EDGE_MODES = ('missing', 'extra')
BUS_MODES = ('stuck', 'noisy')
DMF_DAMPING_FACTOR_MAX = 100.0
"""Largest DMF damping factor [-]: 100 times the design damping is far beyond any worn or
seized DMF; above it the damping term, not the spring, would set the wind-up."""
CYCLE_RAD = 4.0 * math.pi               # one engine cycle, 720 deg
WINDOW_OPEN_RAD = -math.pi              # a combustion's window opens 180 deg before its TDC

_WINDOW_KEYS = ('start_s', 'end_s', 'duration_s')
_KEYS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {     # kind: (required, optional)
    'misfire': (('cylinders',), ('mode', 'probability', 'rate_per_s', 'seed', 'at_s')),
    'weak_cylinder': (('cylinder', 'factor'), ()),
    'dmf_stiffness': (('stage', 'factor'), ()),
    'dmf_broken': (('stage',), ()),
    'dmf_damping': (('factor',), ()),
    'sensor_edges': (('sensor', 'mode'), ('probability', 'tooth', 'rate_per_s', 'seed')),
    'bus_signal': (('signal', 'mode'), ('sigma_rpm', 'seed')),
}
_FIELD_ORDER = ('kind', 'cylinders', 'cylinder', 'stage', 'sensor', 'signal', 'mode', 'factor',
                'probability', 'rate_per_s', 'tooth', 'sigma_rpm', 'seed', 'at_s', 'start_s',
                'end_s', 'duration_s')


# ------------------------------------------------------------------------------------------------
# The description
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Fault:
    """One validated fault (see the module docstring for the fields). ``stage`` is '1', '2', ..
    or 'coast_1', ..; ``cylinders`` holds the one cylinder of a weak_cylinder fault. Times [s] of
    simulated time; None = not given."""

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


# ------------------------------------------------------------------------------------------------
# Parsing and validation
# ------------------------------------------------------------------------------------------------

def _integer(value: Any, where: str, name: str, lo: int, hi: int | None = None) -> int:
    rng = f'>= {lo}' if hi is None else f'in {lo}..{hi}'
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (
            isinstance(value, float) and not value.is_integer()):
        raise field_error(where, name, f'must be an integer {rng}', value)
    v = int(value)
    if v < lo or (hi is not None and v > hi):
        raise field_error(where, name, f'must be {rng}', value)
    return v


def _choice(value: Any, where: str, name: str, allowed: Sequence[str]) -> str:
    if value not in allowed:
        raise field_error(where, name, f'must be one of {", ".join(allowed)}', value)
    return str(value)


def _stage(value: Any, where: str, line: Driveline | None, kind: str) -> str:
    """'1', '2', .. or 'coast_j', checked against the driveline's DMF when given."""
    if isinstance(value, str) and value.strip().isdigit():
        value = int(value.strip())
    if isinstance(value, str) and value.startswith('coast_') and value[6:].isdigit():
        side, idx = 'coast', int(value[6:])
    elif isinstance(value, int) and not isinstance(value, bool):
        side, idx = 'drive', int(value)
    else:
        raise field_error(where, 'stage', "must be a stage number >= 1 (1 = the primary "
                          "stiffness) or 'coast_1', 'coast_2', ...", value)
    if idx < 1:
        raise field_error(where, 'stage', 'must be >= 1 (1 = the primary stiffness)', value)
    text = str(idx) if side == 'drive' else f'coast_{idx}'
    if kind == 'dmf_broken' and text == '1':
        raise field_error(where, 'stage', "1 (the primary stiffness) cannot break: no spring "
                          "would be left below the first knee; give dmf_stiffness with a small "
                          "factor instead", value)
    if line is not None:
        if line.dmf is None:
            raise field_error(where, 'stage', f'refers to the DMF, but driveline {line.name!r} '
                              'has none')
        n_drive, n_coast = len(line.dmf.stages), len(line.dmf.coast_stages)
        have = [str(i) for i in range(1, n_drive + 2)] + [f'coast_{j}'
                                                          for j in range(1, n_coast + 1)]
        if text not in have:
            raise field_error(where, 'stage', f'{text} does not exist: the DMF of '
                              f'{line.name!r} has stages {", ".join(have)}')
    return text


def _name(value: Any, where: str, name: str, known: Collection[str] | None, what: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise field_error(where, name, f'must be the name of a {what}', value)
    if known is not None and value not in known:
        have = ', '.join(sorted(known)) or 'none'
        raise field_error(where, name, f'names no {what} of this driveline (known: {have})',
                          value)
    return value


def known_sensors(line: Driveline | None) -> tuple[dict[str, int] | None, set[str] | None]:
    """(tooth wheel name -> teeth present, bus signal names) of ``line``'s sensors
    (``Driveline.sensors``: its ``tooth_wheels`` and ``bus_signals``), or (None, None) when the
    driveline does not describe sensors (then sensor names are not checked)."""
    sensors = getattr(line, 'sensors', None) if line is not None else None
    if sensors is None or not hasattr(sensors, 'tooth_wheels'):
        return None, None
    return ({w.name: int(getattr(w, 'present_teeth', w.teeth)) for w in sensors.tooth_wheels},
            {b.name for b in sensors.bus_signals})


def parse_fault(spec: Any, where: str = 'fault', *, line: Driveline | None = None,
                wheels: Collection[str] | Mapping[str, int] | None = None,
                signals: Collection[str] | None = None,
                kinds: Sequence[str] = FAULT_KINDS) -> Fault:
    """One fault from its mapping (or its YAML flow text), validated; one-line ConfigError
    naming ``where`` and the field otherwise.

    ``line``: the driveline (cylinders 1..n_cyl, DMF stages); ``wheels``: the tooth wheels'
    names (a mapping name -> number of teeth present also checks ``tooth``, numbered from 0 =
    the first tooth after the gap), ``signals``: the bus signals' names; None = those of
    ``line``'s sensors (:func:`known_sensors`), not checked when it describes none. ``kinds``:
    the kinds allowed here (a parameter of one kind); when only one, ``kind`` may be left out.
    """
    if wheels is None and signals is None:
        wheels, signals = known_sensors(line)
    if isinstance(spec, str):
        spec = parse_yaml(spec, where)
    if isinstance(spec, Mapping) and 'kind' not in spec and len(kinds) == 1:
        spec = {'kind': kinds[0], **spec}
    check_keys(spec, where, '', ('kind',), None)
    kind = spec['kind']
    if kind not in kinds:
        raise field_error(where, 'kind', f'must be one of {", ".join(kinds)}', kind)
    where = f'{where} ({kind})' if not where.endswith(f'({kind})') else where
    required, optional = _KEYS[kind]
    check_keys(spec, where, '', ('kind',) + required, optional + _WINDOW_KEYS)
    d = dict(spec)

    def num(key, lo=-math.inf, hi=math.inf, **kw):
        return number(d[key], where, key, lo, hi, **kw) if key in d else None

    f: dict[str, Any] = {'kind': kind}
    n_cyl = len(line.cylinders) if line is not None else None
    if kind == 'misfire':
        raw = d['cylinders']
        if isinstance(raw, (int, float)) and not isinstance(raw, bool):
            raw = [raw]
        if not isinstance(raw, list) or not raw:
            raise field_error(where, 'cylinders', 'must be a non-empty list of cylinder '
                              'numbers (1-based)', raw)
        cyls = tuple(_integer(c, where, f'cylinders[{i}]', 1, n_cyl) for i, c in enumerate(raw))
        if len(set(cyls)) != len(cyls):
            raise field_error(where, 'cylinders', 'lists a cylinder twice', raw)
        f['cylinders'] = cyls
        mode = f['mode'] = _choice(d.get('mode', 'single'), where, 'mode', MISFIRE_MODES)
        if mode != 'random':
            for key in ('probability', 'rate_per_s', 'seed'):
                if key in d:
                    raise field_error(where, key, 'applies to mode random only')
        if mode == 'single':
            for key in ('end_s', 'duration_s'):
                if key in d:
                    raise field_error(where, key, 'does not apply to a single misfire (it ends '
                                      'with its combustion); give at_s')
            if 'at_s' in d and 'start_s' in d:
                raise field_error(where, 'at_s', 'give at_s or start_s, not both')
            if 'at_s' in d:
                d['start_s'] = d.pop('at_s')
        elif 'at_s' in d:
            raise field_error(where, 'at_s', 'applies to a single misfire only; give start_s')
        if mode == 'random':
            if ('probability' in d) == ('rate_per_s' in d):
                raise field_error(where, 'probability', 'mode random needs probability (per '
                                  'combustion) or rate_per_s, one of them')
            f['probability'] = num('probability', 0.0, 1.0, lo_open=True)
            f['rate_per_s'] = num('rate_per_s', 0.0, lo_open=True, unit='1/s')
            f['seed'] = _integer(d.get('seed', 0), where, 'seed', 0, SEED_MAX)
    elif kind == 'weak_cylinder':
        f['cylinders'] = (_integer(d['cylinder'], where, 'cylinder', 1, n_cyl),)
        f['factor'] = num('factor', 0.0, 1.0, hi_open=True)
    elif kind in ('dmf_stiffness', 'dmf_broken'):
        f['stage'] = _stage(d['stage'], where, line, kind)
        if kind == 'dmf_stiffness':
            f['factor'] = num('factor', 0.0, 1.0, lo_open=True)
    elif kind == 'dmf_damping':
        if line is not None and line.dmf is None:
            raise field_error(where, 'kind', f'refers to the DMF, but driveline {line.name!r} '
                              'has none')
        f['factor'] = num('factor', 0.0, DMF_DAMPING_FACTOR_MAX)
    elif kind == 'sensor_edges':
        f['sensor'] = _name(d['sensor'], where, 'sensor', wheels, 'tooth wheel')
        mode = f['mode'] = _choice(d['mode'], where, 'mode', EDGE_MODES)
        if mode == 'missing':
            if 'rate_per_s' in d:
                raise field_error(where, 'rate_per_s', 'applies to mode extra; mode missing '
                                  'takes probability or tooth')
            if ('probability' in d) == ('tooth' in d):
                raise field_error(where, 'probability', 'mode missing needs probability (per '
                                  'edge) or tooth (that tooth every revolution), one of them')
            f['probability'] = num('probability', 0.0, 1.0, lo_open=True)
            if 'tooth' in d:
                teeth = wheels.get(f['sensor']) if isinstance(wheels, Mapping) else None
                f['tooth'] = _integer(d['tooth'], where, 'tooth', 0,
                                      None if teeth is None else int(teeth) - 1)
        else:
            for key in ('probability', 'tooth'):
                if key in d:
                    raise field_error(where, key, 'applies to mode missing; mode extra takes '
                                      'rate_per_s')
            if 'rate_per_s' not in d:
                raise field_error(where, 'rate_per_s', 'mode extra needs rate_per_s (spurious '
                                  'edges per second)')
            f['rate_per_s'] = num('rate_per_s', 0.0, lo_open=True, unit='1/s')
        f['seed'] = _integer(d.get('seed', 0), where, 'seed', 0, SEED_MAX)
    else:                                               # bus_signal
        f['signal'] = _name(d['signal'], where, 'signal', signals, 'bus signal')
        mode = f['mode'] = _choice(d['mode'], where, 'mode', BUS_MODES)
        if mode == 'noisy':
            if 'sigma_rpm' not in d:
                raise field_error(where, 'sigma_rpm', 'mode noisy needs sigma_rpm (the extra '
                                  'noise, rpm)')
            f['sigma_rpm'] = num('sigma_rpm', 0.0, lo_open=True, unit='rpm')
            f['seed'] = _integer(d.get('seed', 0), where, 'seed', 0, SEED_MAX)
        else:
            for key in ('sigma_rpm', 'seed'):
                if key in d:
                    raise field_error(where, key, 'applies to mode noisy only')
    # the window
    f['start_s'] = num('start_s', 0.0, unit='s')
    f['end_s'] = num('end_s', 0.0, unit='s')
    f['duration_s'] = num('duration_s', 0.0, lo_open=True, unit='s')
    if f['end_s'] is not None and f['duration_s'] is not None:
        raise field_error(where, 'duration_s', 'give end_s or duration_s, not both')
    if f['start_s'] is not None and f['end_s'] is not None and f['end_s'] <= f['start_s']:
        raise field_error(where, 'end_s', f'must be > start_s = {f["start_s"]:g} s (an inverted '
                          'or empty window)', f['end_s'])
    fault = Fault(**{k: v for k, v in f.items() if v is not None})
    if line is not None and kind in ('dmf_stiffness', 'dmf_broken'):
        try:
            FaultSet((fault,)).apply_to_driveline(line)
        except ConfigError as exc:
            raise field_error(where, 'factor' if kind == 'dmf_stiffness' else 'stage',
                              f'leaves no valid spring: {one_line(exc)}') from None
    return fault


def _as_list(spec: Any, where: str) -> list:
    if isinstance(spec, str):
        spec = parse_yaml(spec, where)
    if spec is None or spec == '':
        return []
    return list(spec) if isinstance(spec, list) else [spec]


def parse_faults(spec: Any, where: str = 'faults', **kw) -> tuple[Fault, ...]:
    """Several faults: a list of mappings (or one mapping, or their YAML flow text; empty or
    '' = none), each :func:`parse_fault`-ed and named ``<where>[i]``; overlapping windows
    refused (:func:`check_overlaps`). ``kw``: as :func:`parse_fault`."""
    items = _as_list(spec, where)
    faults = tuple(parse_fault(item, f'{where}[{i}]', **kw) for i, item in enumerate(items))
    check_overlaps(faults, where)
    return faults


def parse_request(text: Any, where: str = 'fault request', **kw) -> tuple[Fault, ...]:
    """A live request (``faults/inject``, a fault parameter): one fault or a list in YAML flow
    style (or that text already read: a mapping or a list); ``kw`` as :func:`parse_fault`.
    '' = none."""
    if not isinstance(text, (str, Mapping, list)):
        raise ConfigError(f'{where}: must be text (a fault mapping in YAML flow style), got '
                          f'{type(text).__name__}')
    items = _as_list(text, where)
    if len(items) == 1:
        faults = (parse_fault(items[0], where, **kw),)
    else:
        faults = tuple(parse_fault(it, f'{where}[{i}]', **kw) for i, it in enumerate(items))
    check_overlaps(faults, where)
    return faults


def _overlap(a: tuple[float, float], b: tuple[float, float], a_single: bool,
             b_single: bool) -> bool:
    if a_single and b_single:
        return False
    if a_single:
        return b[0] <= a[0] < b[1]
    if b_single:
        return a[0] <= b[0] < a[1]
    return a[0] < b[1] and b[0] < a[1]


def _window_text(w: tuple[float, float], single: bool) -> str:
    if single:
        return f'at {w[0]:g} s'
    return f'[{w[0]:g}, {"end" if math.isinf(w[1]) else f"{w[1]:g}"}) s'


def overlap_reason(new: Fault, new_window: tuple[float, float], other: Fault,
                   other_window: tuple[float, float], other_name: str) -> str | None:
    """Why ``new`` (in ``new_window``) may not run beside ``other``, or None."""
    common = set(new.targets()) & set(other.targets())
    if common and _overlap(new_window, other_window, new.single, other.single):
        group, target = sorted(common)[0]
        return (f'{_window_text(new_window, new.single)} overlaps {other_name} '
                f'{_window_text(other_window, other.single)} on {target}')
    return None


def check_overlaps(faults: Sequence[Fault], where: str = 'faults') -> None:
    """Refuse windows of the same kind on the same target that overlap (one line naming both
    faults)."""
    windows = [f.window(0.0) for f in faults]
    for i, f in enumerate(faults):
        for j in range(i):
            reason = overlap_reason(f, windows[i], faults[j], windows[j],
                                    f'faults[{j}] ({faults[j].kind})')
            if reason:
                raise ConfigError(f'{where}[{i}] ({f.kind}): window {reason}')


@dataclass(frozen=True)
class FaultSchedule:
    """The faults of a schedule file, in file order (their ids are 1, 2, ...)."""

    faults: tuple[Fault, ...]
    source: str = ''

    @property
    def name(self) -> str:
        return Path(self.source).name if self.source else ''


SCHEDULE_KEYS = ('faults',)
SCHEDULE_OPTIONAL = ('description',)


def read_schedule(source: str | Path, *, line: Driveline | None = None, **kw) -> FaultSchedule:
    """A schedule file (YAML ``faults: [...]``), validated against ``line`` (and the sensor
    names of ``kw``, as :func:`parse_fault`); one-line errors naming the file, the fault's
    index and the field."""
    path, doc = read_yaml_mapping(source, 'fault schedule')
    check_keys(doc, str(path), '', SCHEDULE_KEYS, SCHEDULE_OPTIONAL)
    items = doc['faults']
    if items is None:
        items = []
    if not isinstance(items, list):
        raise field_error(str(path), 'faults', 'must be a list of fault mappings', items)
    faults = tuple(parse_fault(it, f'{path}: faults[{i}]', line=line, **kw)
                   for i, it in enumerate(items))
    check_overlaps(faults, f'{path}: faults')
    return FaultSchedule(faults, str(path))


# ------------------------------------------------------------------------------------------------
# What a set of faults does
# ------------------------------------------------------------------------------------------------

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
        s = np.ones(int(n_cylinders))
        for f in self.faults:
            if f.kind == 'misfire' and f.mode == 'every_cycle':
                factor = 0.0
            elif f.kind == 'weak_cylinder':
                factor = float(f.factor)
            else:
                continue
            for c in f.cylinders:
                if not 1 <= c <= len(s):
                    raise ConfigError(f'{f.label()}: cylinder {c} outside 1..{len(s)}')
                s[c - 1] *= factor
        return s

    def apply_to_driveline(self, line: Driveline) -> Driveline:
        """The driveline with this set's DMF faults applied (others ignored), built through
        :meth:`Driveline.with_dmf` (the one spring object).

        The spring is read as springs in parallel (:meth:`PiecewiseLinearSpring.ramps`): the
        primary stiffness k acts everywhere, each stage's increment beyond its knee. Stage 1
        ``dmf_stiffness`` scales k (the stages' increments [Nm/rad] stay), stage i >= 2 (drive
        stage i-1) or ``coast_j`` scales that stage's increment, ``dmf_broken`` removes it;
        ``dmf_damping`` scales the DMF element's damping. One-line ConfigError when the result
        is no valid spring (a stage factor beyond its limit)."""
        dmf = self.of_kinds(DMF_KINDS)
        if not dmf:
            return line
        if line.dmf is None:
            raise ConfigError(f'{dmf.faults[0].label()}: driveline {line.name!r} has no DMF')
        spring = line.spring
        k = spring.k
        inc = {'drive': _increments(spring.drive, k), 'coast': _increments(spring.coast, k)}
        k_new = k
        damping = None
        for f in dmf:
            if f.kind == 'dmf_damping':
                damping = (line.dmf_element.damping if damping is None else damping) * f.factor
                continue
            side, idx = (('coast', int(f.stage[6:])) if f.stage.startswith('coast_')
                         else ('drive', int(f.stage) - 1))
            scale = 0.0 if f.kind == 'dmf_broken' else float(f.factor)
            if side == 'drive' and idx == 0:
                k_new *= scale
                continue
            stages = inc[side]
            if not 1 <= idx <= len(stages):
                raise ConfigError(f'{f.label()}: stage {f.stage} does not exist')
            stages[idx - 1] *= scale
        drive = _cumulative(spring.drive, inc['drive'], k_new)
        coast = _cumulative(spring.coast, inc['coast'], k_new)
        return line.with_dmf(k=k_new, stages=drive, coast_stages=coast, damping=damping)

    def text(self) -> str:
        return '[' + ', '.join(f.text() for f in self.faults) + ']'


def _increments(stages, k: float) -> list[float]:
    """Stiffness increment [Nm/rad] of each stage over the one before (ramp slopes)."""
    out, prev = [], 0.0
    for st in stages:
        out.append(k * (st.stiffness_factor - prev))
        prev = st.stiffness_factor
    return out


def _cumulative(stages, increments: Sequence[float], k: float) -> list[tuple[float, float]]:
    """(angle, stiffness factor) per stage from increments [Nm/rad] over primary stiffness k."""
    total, out = 0.0, []
    for st, c in zip(stages, increments):
        total += c
        out.append((st.angle_rad, total / k))
    return out


# ------------------------------------------------------------------------------------------------
# Ground truth
# ------------------------------------------------------------------------------------------------

def combustion_windows(beta_rad: float, psi_from: float, psi_to: float) -> np.ndarray:
    """Crank angles [rad] in (psi_from, psi_to] where the windows of a cylinder of firing phase
    ``beta_rad`` open (``beta + 720 deg m - 180 deg``)."""
    first = math.floor((psi_from - beta_rad - WINDOW_OPEN_RAD) / CYCLE_RAD) + 1
    last = math.floor((psi_to - beta_rad - WINDOW_OPEN_RAD) / CYCLE_RAD)
    return beta_rad + WINDOW_OPEN_RAD + CYCLE_RAD * np.arange(first, last + 1)


@dataclass(frozen=True)
class FaultEvent:
    """One ground-truth event: a fault's ``start`` or ``end``, or one ``misfire`` (a combustion
    that did not fire). ``t_s``/``psi_rad``: simulated time and crank angle where it happened
    (the end of the Newmark step the switch fell in). A misfire carries its cylinder, the
    combustion's index m (TDC at beta_k + 720 deg m) and its TDC crank angle."""

    what: str
    fault_id: int
    fault: Fault
    t_s: float
    psi_rad: float
    start_s: float
    end_s: float | None = None
    cylinder: int | None = None
    combustion: int | None = None
    tdc_rad: float | None = None

    @property
    def name(self) -> str:
        return f'fault {self.fault_id}'

    def values(self, stamp_ns=None) -> dict[str, str]:
        """The status's key -> value text (``faults/ground_truth``). ``stamp_ns``: simulated
        time [s] -> stamp [ns] (the node's stamp clock); without it the stamps are left
        empty."""
        def ns(t):
            return '' if t is None or stamp_ns is None else str(int(stamp_ns(t)))
        out = {'id': str(self.fault_id), 'kind': self.fault.kind,
               'targets': self.fault.target_text(), 'fault': self.fault.text(),
               'start_s': _num(self.start_s), 'end_s': _num(self.end_s),
               'start_ns': ns(self.start_s), 'end_ns': ns(self.end_s),
               'event_s': _num(self.t_s), 'event_ns': ns(self.t_s),
               'crank_angle_rad': _num(self.psi_rad)}
        if self.cylinder is not None:
            out.update({'cylinder': str(self.cylinder), 'combustion': str(self.combustion),
                        'tdc_crank_angle_rad': _num(self.tdc_rad),
                        'window_start_rad': _num(self.tdc_rad + WINDOW_OPEN_RAD),
                        'window_end_rad': _num(self.tdc_rad + WINDOW_OPEN_RAD + CYCLE_RAD)})
        return out

    def message(self) -> str:
        """One line for people (the status message starts with :attr:`what`)."""
        if self.what == 'misfire':
            return (f'misfire: cylinder {self.cylinder}, combustion {self.combustion} (TDC at '
                    f'{self.tdc_rad:.4f} rad)')
        return f'{self.what}: {self.fault.text()}'


def _num(v) -> str:
    return '' if v is None else f'{float(v):.12g}'


def event_from_values(message: str, values: Mapping[str, str]) -> dict[str, Any]:
    """A ground-truth status read back (a bag's ``faults/ground_truth``): what ('start', 'end',
    'misfire', 'active'), id, the fault (:class:`Fault`), times [s] and stamps [ns] (None where
    empty), and for a misfire its cylinder, combustion and TDC crank angle."""
    def f(key):
        v = values.get(key, '')
        return float(v) if v != '' else None

    def i(key):
        v = values.get(key, '')
        return int(v) if v != '' else None
    out = {'what': message.split(':', 1)[0].strip(), 'id': i('id'),
           'fault': parse_fault(values.get('fault', ''), f'fault {values.get("id", "")}'),
           'start_s': f('start_s'), 'end_s': f('end_s'), 'event_s': f('event_s'),
           'start_ns': i('start_ns'), 'end_ns': i('end_ns'), 'event_ns': i('event_ns'),
           'crank_angle_rad': f('crank_angle_rad')}
    if 'cylinder' in values:
        out.update({'cylinder': i('cylinder'), 'combustion': i('combustion'),
                    'tdc_crank_angle_rad': f('tdc_crank_angle_rad')})
    return out


@dataclass
class _Entry:
    """A fault on the timeline: pending (not started), armed (a single misfire waiting for its
    combustion), active, or ended."""

    id: int
    fault: Fault
    start_s: float
    end_s: float
    state: str = 'pending'
    started_s: float | None = None
    ended_s: float | None = None
    remaining: set = field(default_factory=set)     # single: cylinders not yet misfired
    open: int = 0                                  # single: its misfire windows not yet closed
    rng: Any = None                                # random at a rate: arrivals
    next_arrival_s: float = math.inf


class FaultTimeline:
    """Which faults act when, combustion by combustion: the ground truth of a run.

    Faults come from a schedule (:meth:`add` at time 0, in file order) or live (:meth:`add`
    with the current time); ids count from 1 in that order. The simulation asks :meth:`scan`
    with the time and crank angle at the end of each of the next steps: it returns how many
    steps run before the excitation or the DMF changes, having decided every combustion and
    time switch up to there. The state after a scan: :attr:`factors` (per-cylinder combustion
    factors in effect), :attr:`dmf` (active DMF faults, :attr:`dmf_version` counts their
    changes), :attr:`sensor_faults`, and the new :attr:`events` (taken with
    :meth:`take_events`).

    Time switches (a fault's start/end, a single misfire's time) apply at the end of the step
    whose end time reaches them; a combustion's factor is decided at the step whose end crank
    angle reaches its window opening (exact to one step). Random misfires: with
    ``probability``, combustion m of cylinder k misfires when a uniform number drawn from
    ``numpy.random.default_rng([seed, k, m])`` is below it (the same combustions whatever the
    chunks); with ``rate_per_s``, arrivals of a Poisson process of that rate seeded with
    ``seed`` from the fault's start each misfire the next combustion of a listed cylinder.
    """

    def __init__(self, line: Driveline, faults: Iterable[Fault] = ()) -> None:
        self.line = line
        self.n_cylinders = len(line.cylinders)
        self.beta = np.radians(np.asarray(line.firing_phases_deg, dtype=float))
        self.entries: list[_Entry] = []
        self.factors = np.ones(self.n_cylinders)
        self._all_fire = True
        self.dmf = FaultSet()
        self.dmf_version = 0
        self.events: list[FaultEvent] = []
        self._next_id = 1
        self._next_open: np.ndarray | None = None      # per cylinder: next window opening [rad]
        self._misfired: list[_Entry | None] = [None] * self.n_cylinders   # current combustion's
        for f in faults:
            self.add(f, 0.0)

    # ---- adding and ending ------------------------------------------------------------------
    def _live(self) -> list[_Entry]:
        return [e for e in self.entries if e.state != 'ended']

    def check(self, fault: Fault, now_s: float) -> str | None:
        """Why ``fault`` cannot be added now, or None: a window in the past or inverted, an
        overlap with a fault not ended, a DMF set that is no valid spring (the reason without
        the fault's name: the caller knows how to name it)."""
        start, end = fault.window(now_s)
        if fault.start_s is not None and start < now_s and not fault.single:
            start = now_s      # a window that started before now runs from now
        if end <= start and not fault.single:
            return (f'its window ends at {end:g} s, not after its start '
                    f'{start:g} s (simulated time now {now_s:.3f} s)')
        for e in self._live():
            w = (e.start_s, e.end_s)
            reason = overlap_reason(fault, (start, end), e.fault, w, f'fault {e.id} '
                                    f'({e.fault.kind})')
            if reason:
                return f'window {reason}'
        if fault.kind in DMF_KINDS:
            together = FaultSet(tuple(e.fault for e in self._live()
                                      if e.fault.kind in DMF_KINDS) + (fault,))
            try:
                together.apply_to_driveline(self.line)
            except ConfigError as exc:
                return f'with the DMF faults already set: {one_line(exc)}'
        return None

    def add(self, fault: Fault, now_s: float = 0.0) -> int:
        """Put ``fault`` on the timeline (``now_s``: the current simulated time, the start of
        a fault without ``start_s``); returns its id. ConfigError with :meth:`check`'s reason."""
        if reason := self.check(fault, now_s):
            raise ConfigError(f'{fault.label()}: {reason}')
        start, end = fault.window(now_s)
        start = max(start, now_s) if not fault.single else start
        entry = _Entry(self._next_id, fault, start, end if not fault.single else math.inf)
        if fault.single:
            entry.remaining = set(fault.cylinders)
        self._next_id += 1
        self.entries.append(entry)
        return entry.id

    def end(self, fault_id: int, t_s: float, psi_rad: float) -> bool:
        """End fault ``fault_id`` now (a parameter cleared); a single misfire not yet fired is
        dropped. Returns whether it was live."""
        for e in self.entries:
            if e.id == fault_id and e.state != 'ended':
                self._finish(e, t_s, psi_rad)
                return True
        return False

    def clear(self, t_s: float, psi_rad: float) -> list[int]:
        """End every fault now (``~/clear_faults``); returns their ids. A combustion in its
        window keeps its factor until its window closes."""
        ids = [e.id for e in self._live()]
        for e in self._live():
            self._finish(e, t_s, psi_rad)
        return ids

    def _finish(self, e: _Entry, t_s: float, psi_rad: float) -> None:
        was = e.state
        e.state = 'ended'
        e.ended_s = t_s
        if was == 'active':          # (a single misfire not fired yet just goes)
            self.events.append(FaultEvent('end', e.id, e.fault, t_s, psi_rad, e.started_s, t_s))
        if e.fault.kind in DMF_KINDS and was == 'active':
            self._update_dmf()

    def _update_dmf(self) -> None:
        dmf = FaultSet(tuple(e.fault for e in self.entries
                             if e.state == 'active' and e.fault.kind in DMF_KINDS))
        if dmf != self.dmf:
            self.dmf = dmf
            self.dmf_version += 1

    # ---- state ------------------------------------------------------------------------------
    def active(self) -> list[_Entry]:
        """The faults acting now (a single misfire while its combustion's window is open)."""
        return [e for e in self.entries if e.state == 'active']

    def active_set(self) -> FaultSet:
        return FaultSet(tuple(e.fault for e in self.active()))

    @property
    def sensor_faults(self) -> FaultSet:
        """The sensor faults acting now (applied by the sensor signal synthesis)."""
        return self.active_set().of_kinds(SENSOR_KINDS)

    @property
    def idle(self) -> bool:
        """Nothing will ever change: no fault pending or active, every cylinder healthy."""
        return self._all_fire and all(e.state == 'ended' for e in self.entries)

    def take_events(self) -> list[FaultEvent]:
        out, self.events = self.events, []
        return out

    def active_statuses(self) -> list[tuple[int, Fault, float]]:
        """(id, fault, start [s]) of each active fault (``faults/active``)."""
        return [(e.id, e.fault, e.started_s) for e in self.active()]

    # ---- stepping ---------------------------------------------------------------------------
    def _next_time(self) -> float:
        t = math.inf
        for e in self.entries:
            if e.state == 'pending':
                t = min(t, e.start_s)
            elif e.state == 'active' and not e.fault.single:
                t = min(t, e.end_s)
        return t

    def _combustion_relevant(self) -> bool:
        if not self._all_fire:
            return True
        return any(e.fault.kind in COMBUSTION_KINDS and e.state in ('active', 'armed')
                   for e in self.entries)

    def _init_openings(self, psi: float) -> None:
        self._next_open = np.array([combustion_windows(b, psi, psi + CYCLE_RAD)[0]
                                    for b in self.beta])

    def scan(self, t_ends: np.ndarray, psi_ends: np.ndarray) -> tuple[int, bool]:
        """Decide what happens over the next steps, whose end times [s] and crank angles [rad]
        are ``t_ends``/``psi_ends`` (increasing). Returns (steps to run, changed): changed True
        when :attr:`factors` or :attr:`dmf` change at the end of the last of those steps (run
        them with the old excitation, then apply the new one); else all steps are decided and
        nothing changes."""
        n = len(t_ends)
        if n == 0 or self.idle:
            return n, False
        self.entries = [e for e in self.entries
                        if e.state != 'ended' or any(e is m for m in self._misfired)]
        pos = 0
        while pos < n:
            t_next = self._next_time()
            jt = int(np.searchsorted(t_ends, t_next, side='left')) if math.isfinite(
                t_next) else n
            jt = max(jt, pos)
            jo = n
            if self._combustion_relevant():
                if self._next_open is None:
                    self._init_openings(float(psi_ends[max(pos - 1, 0)]))
                jo = max(int(np.searchsorted(psi_ends, self._next_open.min(), side='left')),
                         pos)
            else:
                self._next_open = None
            j = min(jt, jo)
            if j >= n:
                return n, False
            before = (self.factors.copy(), self.dmf_version)
            t, psi = float(t_ends[j]), float(psi_ends[j])
            while self._next_time() <= t:
                self._time_switch(t, psi)
            if self._combustion_relevant():
                if self._next_open is None:
                    self._init_openings(psi)
                while self._next_open.min() <= psi:
                    k = int(np.argmin(self._next_open))
                    self._opening(k, float(self._next_open[k]), t, psi)
                    self._next_open[k] += CYCLE_RAD
            changed = (before[1] != self.dmf_version
                       or not np.array_equal(before[0], self.factors))
            if changed:
                return j + 1, True
            pos = j + 1
        return n, False

    def _time_switch(self, t: float, psi: float) -> None:
        """Every start/end due at time t (in time order)."""
        due = []
        for e in self.entries:
            if e.state == 'pending' and e.start_s <= t:
                due.append((e.start_s, 0, e))
            elif e.state == 'active' and not e.fault.single and e.end_s <= t:
                due.append((e.end_s, 1, e))
        for _, what, e in sorted(due, key=lambda x: (x[0], x[1], x[2].id)):
            if what == 1:
                self._finish(e, t, psi)
                continue
            if e.fault.single:
                e.state = 'armed'
                continue
            e.state = 'active'
            e.started_s = t
            if e.fault.mode == 'random' and e.fault.rate_per_s is not None:
                e.rng = np.random.default_rng(e.fault.seed)
                e.next_arrival_s = e.start_s + e.rng.exponential(1.0 / e.fault.rate_per_s)
            self.events.append(FaultEvent('start', e.id, e.fault, t, psi, t))
            if e.fault.kind in DMF_KINDS:
                self._update_dmf()

    def _opening(self, k: int, psi_open: float, t: float, psi: float) -> None:
        """Cylinder k's window opens at ``psi_open``: close its last combustion, decide the
        next one's factor."""
        cyl = k + 1
        m = int(round((psi_open - self.beta[k] - WINDOW_OPEN_RAD) / CYCLE_RAD))
        last = self._misfired[k]
        self._misfired[k] = None
        if last is not None and last.fault.single:
            last.open -= 1
            if last.open == 0 and not last.remaining and last.state == 'active':
                last.state = 'ended'
                last.ended_s = t
                self.events.append(FaultEvent('end', last.id, last.fault, t, psi,
                                              last.started_s, t))
        by = None
        for e in self.entries:
            f = e.fault
            if f.kind != 'misfire' or cyl not in f.cylinders:
                continue
            if f.single and e.state in ('armed', 'active') and cyl in e.remaining:
                by = e
                e.remaining.discard(cyl)
                e.open += 1
                if e.state == 'armed':
                    e.state = 'active'
                    e.started_s = t
                    self.events.append(FaultEvent('start', e.id, f, t, psi, t))
                break
            if e.state != 'active':
                continue
            if f.mode == 'every_cycle':
                by = e
                break
            if f.mode == 'random':
                if f.probability is not None:
                    hit = np.random.default_rng([f.seed, cyl, m]).random() < f.probability
                else:
                    hit = e.next_arrival_s <= t
                    while e.next_arrival_s <= t:
                        e.next_arrival_s += e.rng.exponential(1.0 / f.rate_per_s)
                if hit:
                    by = e
                    break
        if by is not None:
            self._misfired[k] = by
            self.factors[k] = 0.0
            self._all_fire = False
            tdc = psi_open - WINDOW_OPEN_RAD
            self.events.append(FaultEvent('misfire', by.id, by.fault, t, psi, by.started_s,
                                          cylinder=cyl, combustion=m, tdc_rad=tdc))
            return
        factor = 1.0
        for e in self.entries:
            if e.state == 'active' and e.fault.kind == 'weak_cylinder' \
                    and e.fault.cylinders[0] == cyl:
                factor *= float(e.fault.factor)
        self.factors[k] = factor
        self._all_fire = bool(np.all(self.factors == 1.0))

