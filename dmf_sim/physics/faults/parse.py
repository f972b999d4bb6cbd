"""The fault grammar (:mod:`dmf_sim.physics.faults`): one fault, several, a live request or a
schedule file parsed and validated, with one-line errors naming the fault and the field; the
windows of faults on one target must not overlap."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Collection, Mapping, Sequence

from dmf_sim.core.errors import ConfigError, one_line
from dmf_sim.core.paths import parse_yaml, read_yaml_mapping
from dmf_sim.core.validation import SEED_MAX, check_keys, field_error, number
from dmf_sim.physics.faults.dmf import DMF_DAMPING_FACTOR_MAX, check_stage
from dmf_sim.physics.faults.fault import (
    BUS_MODES,
    EDGE_MODES,
    FAULT_KINDS,
    MISFIRE_MODES,
    Fault,
    FaultSet,
)
from dmf_sim.physics.model import Driveline

__all__ = ['SEED_MAX', 'FaultSchedule', 'known_sensors', 'parse_fault', 'parse_faults',
           'parse_request', 'read_schedule', 'check_overlaps', 'overlap_reason']

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
        f['stage'] = check_stage(d['stage'], where, line, kind)
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
