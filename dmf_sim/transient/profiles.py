"""Speed/load profiles: tables of time [s], engine speed [rpm], load [0..1], linear between rows.

A profile is what ``dmf-sim run`` integrates, what the node follows (parameter ``profile``) and
what ``dmf-sim setpoint --profile`` publishes. Sources (:func:`load_profile`):

* a CSV file with the header ``time_s,speed_rpm,load`` (``#`` starts a comment line);
* a YAML mapping with ``points`` (rows ``[time_s, speed_rpm, load]``), or ``ramp`` (a built-in
  run-up / run-down, below), and optional ``name`` and ``source`` (where the table comes from);
* a packaged profile by name (``config/profiles/NAME.yaml``), e.g. ``truck_road_cycle``;
* ``ramp:FROM:TO:RATE[:LOAD[:SETTLE]]``: from FROM to TO rpm at RATE rpm/s (a run-up when
  TO > FROM, a run-down otherwise) at load LOAD (default 1), after SETTLE s at FROM (default
  :data:`DEFAULT_SETTLE_S`) so the start from static equilibrium has settled.

Rules (each broken one is a one-line :class:`ConfigError` naming the file, row and field): at
least two rows, times finite, starting at 0 and strictly increasing, speeds finite and > 0 (and
within the engine's data when a range is given: :meth:`Profile.check_speed_range`), loads in
[0, 1].
"""
from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dmf_sim.core.errors import ConfigError, ConfigFileError, OperatingRangeError
from dmf_sim.core.paths import config_dir, config_file, parse_yaml, read_text
from dmf_sim.core.validation import check_keys, field_error, number

__all__ = ['COLUMNS', 'DEFAULT_SETTLE_S', 'RAMP_RATE_RANGE', 'SETTLE_RANGE_S', 'LOAD_RANGE',
           'PROFILE_DIR', 'RAMP_PREFIX', 'Profile', 'make_profile', 'ramp_profile',
           'packaged_profiles', 'load_profile']

COLUMNS = ('time_s', 'speed_rpm', 'load')
DEFAULT_SETTLE_S = 2.0            # dwell at a ramp's start speed [s] before it ramps
RAMP_RATE_RANGE = (1e-3, 1e4)     # accepted ramp rates [rpm/s]
SETTLE_RANGE_S = (0.0, 3600.0)
LOAD_RANGE = (0.0, 1.0)
PROFILE_DIR = 'profiles'          # packaged profiles: config/profiles/NAME.yaml
RAMP_PREFIX = 'ramp:'


@dataclass(frozen=True)
class Profile:
    """A speed/load table, linear between rows.

    Attributes:
        t_s: times [s], from 0, strictly increasing; speed_rpm: engine speed [rpm]; load: 0..1.
        name: short name (file stem or the ramp spec); source: where the table comes from.
    """

    t_s: np.ndarray
    speed_rpm: np.ndarray
    load: np.ndarray
    name: str = 'profile'
    source: str = ''

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1])

    def __len__(self) -> int:
        return len(self.t_s)

    def at(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(speed [rpm], load) at time(s) ``t`` [s] (held at the ends)."""
        return (np.interp(t, self.t_s, self.speed_rpm), np.interp(t, self.t_s, self.load))

    def segment(self, t: float) -> int:
        """Index i of the row segment [t_i, t_i+1) holding ``t`` (the last one at and past the
        end)."""
        return int(min(max(np.searchsorted(self.t_s, t, side='right') - 1, 0), len(self) - 2))

    def next_row_s(self, t: float) -> float:
        """Time of the first row after ``t`` (inf past the end)."""
        i = int(np.searchsorted(self.t_s, t, side='right'))
        return float(self.t_s[i]) if i < len(self) else math.inf

    def check_speed_range(self, lo: float, hi: float, what: str = 'the engine data') -> None:
        """OperatingRangeError (one line) if a row's speed lies outside [lo, hi] rpm."""
        bad = np.flatnonzero((self.speed_rpm < lo - 1e-9) | (self.speed_rpm > hi + 1e-9))
        if len(bad):
            i = int(bad[0])
            raise OperatingRangeError(
                f'profile {self.name}: row {i + 1} (t = {self.t_s[i]:g} s) speed '
                f'{self.speed_rpm[i]:g} rpm outside {what} [{lo:g}, {hi:g}] rpm')

    def as_dict(self) -> dict:
        return {'name': self.name, 'source': self.source, 'rows': len(self),
                'duration_s': self.duration_s,
                'speed_rpm': [float(self.speed_rpm.min()), float(self.speed_rpm.max())],
                'load': [float(self.load.min()), float(self.load.max())]}


# ------------------------------------------------------------------------------- building

def make_profile(rows, *, name: str = 'profile', source: str = '', where: str = 'profile',
                 lines: list[int] | None = None) -> Profile:
    """A validated :class:`Profile` from rows (time_s, speed_rpm, load). ``where`` and
    ``lines`` (the file line of each row) go into the error messages."""
    rows = list(rows)

    def at(i: int) -> str:
        return f'{where}:{lines[i]}' if lines else f'{where} row {i + 1}'

    if len(rows) < 2:
        raise ConfigError(f'{where}: a profile needs at least 2 rows (time_s, speed_rpm, load), '
                          f'got {len(rows)}')
    out = np.empty((len(rows), 3))
    for i, row in enumerate(rows):
        if not isinstance(row, (list, tuple)) or len(row) != 3:
            raise field_error(at(i), 'row', 'must be [time_s, speed_rpm, load] (3 numbers)', row)
        for j, (col, value) in enumerate(zip(COLUMNS, row)):
            out[i, j] = number(value, at(i), col)
    t, speed, load = out.T
    if t[0] != 0.0:
        raise field_error(at(0), 'time_s', 'must start at 0 s', float(t[0]))
    for i in range(1, len(t)):
        if not t[i] > t[i - 1]:
            raise field_error(at(i), 'time_s', f'must increase strictly (after {t[i - 1]:g})',
                              float(t[i]))
    for i in range(len(t)):
        number(float(speed[i]), at(i), 'speed_rpm', 0.0, lo_open=True, unit='rpm')
        number(float(load[i]), at(i), 'load', *LOAD_RANGE)
    return Profile(t.copy(), speed.copy(), load.copy(), name=name, source=source)


def ramp_profile(from_rpm: float, to_rpm: float, rate_rpm_per_s: float, load: float = 1.0,
                 settle_s: float = DEFAULT_SETTLE_S, *, where: str = 'ramp') -> Profile:
    """Built-in run-up (to > from) or run-down: ``settle_s`` at ``from_rpm``, then a constant
    rate to ``to_rpm``."""
    from_rpm = number(from_rpm, where, 'from_rpm', 0.0, lo_open=True, unit='rpm')
    to_rpm = number(to_rpm, where, 'to_rpm', 0.0, lo_open=True, unit='rpm')
    rate_rpm_per_s = number(rate_rpm_per_s, where, 'rate_rpm_per_s', *RAMP_RATE_RANGE,
                            unit='rpm/s')
    load = number(load, where, 'load', *LOAD_RANGE)
    settle_s = number(settle_s, where, 'settle_s', *SETTLE_RANGE_S, unit='s')
    if from_rpm == to_rpm:
        raise field_error(where, 'to_rpm', f'must differ from from_rpm ({from_rpm:g} rpm): '
                          'nothing to ramp', to_rpm)
    ramp_s = abs(float(to_rpm) - float(from_rpm)) / float(rate_rpm_per_s)
    times = [0.0, float(settle_s), float(settle_s) + ramp_s] if settle_s > 0 else [0.0, ramp_s]
    speeds = ([from_rpm, from_rpm, to_rpm] if settle_s > 0 else [from_rpm, to_rpm])
    kind = 'run-up' if to_rpm > from_rpm else 'run-down'
    name = f'ramp:{float(from_rpm):g}:{float(to_rpm):g}:{float(rate_rpm_per_s):g}'
    return make_profile([(t, s, load) for t, s in zip(times, speeds)], name=name,
                        source=f'built-in {kind} {float(from_rpm):g} -> {float(to_rpm):g} rpm at '
                        f'{float(rate_rpm_per_s):g} rpm/s, load {float(load):g}, after '
                        f'{float(settle_s):g} s at the start speed', where=where)


def _parse_ramp_spec(spec: str) -> Profile:
    parts = spec[len(RAMP_PREFIX):].split(':')
    if not 3 <= len(parts) <= 5 or not all(p.strip() for p in parts):
        raise ConfigError(f'profile {spec!r}: write ramp:FROM:TO:RATE[:LOAD[:SETTLE]] (rpm, rpm, '
                          'rpm/s, 0..1, s), e.g. ramp:800:2000:10:1.0')
    names = ('from_rpm', 'to_rpm', 'rate_rpm_per_s', 'load', 'settle_s')
    return ramp_profile(**dict(zip(names, parts)), where=f'profile {spec!r}')


def _read_csv(path: Path) -> Profile:
    text = read_text(path)
    rows, lines = [], []
    header = None
    for lineno, raw in enumerate(io.StringIO(text), start=1):
        stripped = raw.strip()
        if not stripped or stripped.startswith('#'):
            continue
        cells = [c.strip() for c in next(csv.reader([stripped]))]
        if header is None:
            header = cells
            if header != list(COLUMNS):
                raise field_error(f'{path}:{lineno}', 'header', f'must be {",".join(COLUMNS)}',
                                  stripped)
            continue
        if len(cells) != len(COLUMNS):
            raise field_error(f'{path}:{lineno}', 'row', f'must have 3 values '
                              f'({",".join(COLUMNS)})', stripped)
        rows.append(cells)
        lines.append(lineno)
    if header is None:
        raise ConfigError(f'{path}: empty profile (expected the header {",".join(COLUMNS)})')
    return make_profile(rows, name=path.stem, source=str(path), where=str(path), lines=lines)


def _read_yaml(path: Path) -> Profile:
    data = parse_yaml(read_text(path), str(path))
    check_keys(data, str(path), '', (), ('name', 'source', 'points', 'ramp', 'columns'))
    name = str(data.get('name') or path.stem)
    source = str(data.get('source') or path)
    if ('points' in data) == ('ramp' in data):
        raise ConfigError(f'{path}: give exactly one of points: (rows [time_s, speed_rpm, load]) '
                          'or ramp: (from_rpm, to_rpm, rate_rpm_per_s, load, settle_s)')
    if 'columns' in data and list(data['columns']) != list(COLUMNS):
        raise field_error(str(path), 'columns', f'must be {list(COLUMNS)}', data['columns'])
    if 'ramp' in data:
        ramp = check_keys(data['ramp'], str(path), 'ramp', ('from_rpm', 'to_rpm',
                                                             'rate_rpm_per_s'),
                          ('load', 'settle_s'))
        p = ramp_profile(**ramp, where=f'{path}: ramp')
        return Profile(p.t_s, p.speed_rpm, p.load, name=name, source=data.get('source')
                       or p.source)
    points = data['points']
    if not isinstance(points, list):
        raise field_error(str(path), 'points', 'must be a list of [time_s, speed_rpm, load] rows',
                          points)
    return make_profile(points, name=name, source=source, where=f'{path}: points')


def packaged_profiles() -> list[str]:
    """Names of the profiles shipped in ``config/profiles``."""
    folder = config_dir() / PROFILE_DIR
    return sorted(p.stem for p in folder.glob('*.yaml')) if folder.is_dir() else []


def load_profile(spec: str | os.PathLike) -> Profile:
    """A profile from a CSV/YAML path, a packaged name or a ``ramp:`` spec (module docstring)."""
    text = os.fspath(spec)
    if text.startswith(RAMP_PREFIX):
        return _parse_ramp_spec(text)
    path = Path(text)
    try:
        bare_name = path.parent == Path('.') and path.suffix == '' and not path.exists()
    except OSError as exc:              # e.g. a name longer than the file system allows
        raise ConfigFileError(f'profile {text}: cannot be read ({exc.strerror or exc})') from None
    if bare_name:
        packaged = config_dir() / PROFILE_DIR / f'{text}.yaml'
        if packaged.is_file():
            return _read_yaml(packaged)
        names = ', '.join(packaged_profiles()) or 'none'
        raise ConfigError(f'profile {text!r}: no such file, packaged profile ({names}) or '
                          'ramp:FROM:TO:RATE spec')
    path = config_file(path)
    if path.suffix.lower() == '.csv':
        return _read_csv(path)
    if path.suffix.lower() in ('.yaml', '.yml'):
        return _read_yaml(path)
    raise ConfigError(f'{path}: a profile is a .csv or .yaml file, got {path.suffix or "none"}')
