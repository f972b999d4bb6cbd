"""Speed/load profiles: tables of time [s], engine speed [rpm], load [-1..1], linear between rows.

A profile is what ``dmf-sim run`` integrates, what the node follows (parameter ``profile``) and
what ``dmf-sim setpoint --profile`` publishes. Sources (:func:`read_profile`):

* a CSV file with the header ``time_s,speed_rpm,load`` (``#`` starts a comment line);
* a YAML mapping with ``points`` (rows ``[time_s, speed_rpm, load]``), ``ramp`` (a built-in
  run-up / run-down, below) or ``step`` (a built-in load step, below), and optional ``name`` and
  ``source`` (where the table comes from);
* a packaged profile by name (``config/profiles/NAME.yaml``), e.g. ``truck_road_cycle``;
* ``ramp:FROM:TO:RATE[:LOAD[:SETTLE]]``: from FROM to TO rpm at RATE rpm/s (a run-up when
  TO > FROM, a run-down otherwise) at load LOAD (default 1), after SETTLE s at FROM (default
  :data:`DEFAULT_SETTLE_S`) so the start from static equilibrium has settled;
* ``step:SPEED:FROM:TO:RISE[:HOLD[:SETTLE]]``: a load step at SPEED rpm: SETTLE s at load FROM
  (default :data:`DEFAULT_SETTLE_S`), FROM -> TO in RISE s (a tip-in when TO > FROM, a tip-out
  otherwise), HOLD s at TO (default :data:`DEFAULT_HOLD_S`), back to FROM in RISE s and HOLD s
  there; ``step:1200:0:1:0.1`` is 0 -> 1 -> 0 in 0.1 s at 1200 rpm.

The load is the torque demand: 1 full load, 0 no load, -1 the engine's full brake
(:data:`~dmf_sim.physics.engine.LOAD_LIMITS`); a profile below 0 needs an engine with a brake
curve, checked where the engine is known (:meth:`Profile.check_load_range`), and a load change
faster than one Newmark step is refused where the step is known (:meth:`Profile.check_load_steps`:
``dmf-sim run``, the node).

Rules (each broken one is a one-line :class:`ConfigError` naming the file, row and field): at
least two rows and at most :data:`~dmf_sim.core.limits.MAX_PROFILE_ROWS`, times finite, starting
at 0, strictly increasing and ending within :data:`~dmf_sim.core.limits.MAX_PROFILE_DURATION_S`,
speeds finite and > 0 (and within the engine's data when a range is given:
:meth:`Profile.check_speed_range`), changing by at most :data:`MAX_SPEED_RATE_RPM_PER_S` between
rows (the fastest ``ramp:``), loads in [-1, 1]. A CSV table is read by numpy (a million rows in
about a second); a file larger than the limits is refused before it is read.
"""
from __future__ import annotations

import csv
import io
import math
import os
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from dmf_sim.core.errors import ConfigError, ConfigFileError, OperatingRangeError, one_line
from dmf_sim.core.limits import (
    MAX_PROFILE_CSV_BYTES,
    MAX_PROFILE_DURATION_S,
    MAX_PROFILE_ROWS,
    MAX_PROFILE_YAML_BYTES,
)
from dmf_sim.core.paths import config_dir, config_file, parse_yaml, read_text
from dmf_sim.core.validation import check_keys, field_error, number
from dmf_sim.physics.engine import LOAD_LIMITS, load_error

__all__ = ['COLUMNS', 'DEFAULT_SETTLE_S', 'DEFAULT_LOAD', 'DEFAULT_HOLD_S',
           'MAX_SPEED_RATE_RPM_PER_S', 'RAMP_RATE_RANGE', 'SETTLE_RANGE_S', 'STEP_TIME_RANGE_S',
           'PROFILE_DIR', 'RAMP_PREFIX', 'STEP_PREFIX', 'Profile', 'make_profile',
           'profile_from_table', 'ramp_profile',
           'ramp_spec', 'step_profile', 'step_spec', 'packaged_profiles', 'read_profile']

COLUMNS = ('time_s', 'speed_rpm', 'load')
DEFAULT_SETTLE_S = 2.0            # dwell at a ramp's start speed [s] before it ramps
DEFAULT_LOAD = 1.0                # a ramp's load when none is given
MAX_SPEED_RATE_RPM_PER_S = 1e4    # fastest speed change of a profile, between rows or as a ramp
                                  # [rpm/s]: a clutch engagement; a faster step is a typo or a
                                  # table with a missing row
RAMP_RATE_RANGE = (1e-3, MAX_SPEED_RATE_RPM_PER_S)     # accepted ramp rates [rpm/s]
SETTLE_RANGE_S = (0.0, 3600.0)
DEFAULT_HOLD_S = 1.0              # a load step's hold at its target and after its return [s]:
                                  # several periods of the truck's lowest driveline mode
STEP_TIME_RANGE_S = (0.0, 3600.0)  # a load step's rise and hold [s], 0 excluded
PROFILE_DIR = 'profiles'          # packaged profiles: config/profiles/NAME.yaml
RAMP_PREFIX = 'ramp:'
STEP_PREFIX = 'step:'


@dataclass(frozen=True)
class Profile:
    """A speed/load table, linear between rows.

    Attributes:
        t_s: times [s], from 0, strictly increasing; speed_rpm: engine speed [rpm]; load: the
            torque demand, -1..1 (below 0: engine braking).
        name: short name (file stem or the ramp spec); source: where the table comes from.
        settle_s: a ramp's dwell at its start speed, a step's at its start load [s] (None: a
            table; see :attr:`start_settle_s`).
    """

    t_s: np.ndarray
    speed_rpm: np.ndarray
    load: np.ndarray
    name: str = 'profile'
    source: str = ''
    settle_s: float | None = None

    @property
    def start_settle_s(self) -> float:
        """Time [s] from the start in which a run started from static equilibrium at the first
        row settles (its cycles are not steady running): a ramp's settle, else
        :data:`DEFAULT_SETTLE_S`; at most the profile's duration."""
        settle = DEFAULT_SETTLE_S if self.settle_s is None else self.settle_s
        return min(float(settle), self.duration_s)

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

    def as_table(self) -> dict:
        """The whole profile as plain values (JSON): what a ``dmf-sim run`` bag keeps in its
        metadata so the run can be followed again without the file
        (:func:`profile_from_table` reads it back)."""
        return {'name': self.name, 'source': self.source, 'settle_s': self.settle_s,
                't_s': self.t_s.tolist(), 'speed_rpm': self.speed_rpm.tolist(),
                'load': self.load.tolist()}

    def window(self, from_s: float, to_s: float, name: str | None = None) -> 'Profile':
        """The profile between ``from_s`` and ``to_s`` [s] (rows inside kept, the ends
        interpolated as the run does), its time starting at 0; ``name`` (default
        ``NAME[FROM:TO s]``), its source kept."""
        inside = (self.t_s > from_s) & (self.t_s < to_s)
        t = np.r_[from_s, self.t_s[inside], to_s]
        speed, load = self.at(t)
        return make_profile(np.column_stack([t - from_s, speed, load]),
                            name=name or f'{self.name}[{from_s:g}:{to_s:g} s]',
                            source=self.source)

    def check_runnable(self, speed_limits_rpm: tuple[float, float], engine=None,
                       dt: float | None = None, *, speed_what: str = 'the engine data',
                       dt_what: str = 'dt') -> None:
        """The checks a run makes of its profile before it starts (one-line errors naming the
        row): speeds within ``speed_limits_rpm`` (:meth:`check_speed_range`), loads ``engine``
        accepts (:meth:`check_load_range`) and no load change faster than one Newmark step
        ``dt`` (:meth:`check_load_steps`); ``engine``, ``dt`` None: not checked."""
        self.check_speed_range(*speed_limits_rpm, speed_what)
        if engine is not None:
            self.check_load_range(engine)
        if dt is not None:
            self.check_load_steps(dt, dt_what)

    def check_speed_range(self, lo: float, hi: float, what: str = 'the engine data') -> None:
        """OperatingRangeError (one line) if a row's speed lies outside [lo, hi] rpm."""
        bad = np.flatnonzero((self.speed_rpm < lo - 1e-9) | (self.speed_rpm > hi + 1e-9))
        if len(bad):
            i = int(bad[0])
            raise OperatingRangeError(
                f'profile {self.name}: row {i + 1} (t = {self.t_s[i]:g} s) speed '
                f'{self.speed_rpm[i]:g} rpm outside {what} [{lo:g}, {hi:g}] rpm')

    def check_load_range(self, engine, what: str = '') -> None:
        """OperatingRangeError (one line naming the row) if a row's load is not a torque demand
        ``engine`` accepts (:func:`dmf_sim.physics.engine.load_error`: below 0 only with a brake
        curve)."""
        for i in dict.fromkeys((int(np.argmin(self.load)), int(np.argmax(self.load)))):
            if reason := load_error(engine, float(self.load[i]), 'load'):
                raise OperatingRangeError(
                    f'profile {self.name}: row {i + 1} (t = {self.t_s[i]:g} s) {reason}'
                    + (f' ({what})' if what else ''))

    def check_load_steps(self, dt: float, what: str = 'dt') -> None:
        """ConfigError (one line naming the row) if the load changes between two rows closer
        than one Newmark step ``dt`` [s]: the integrator could not follow it (``what`` names
        where the step comes from: an option or a parameter)."""
        dt_rows = np.diff(self.t_s)
        changes = np.diff(self.load) != 0.0
        bad = np.flatnonzero(changes & (dt_rows < dt * (1.0 - 1e-9)))
        if len(bad):
            i = int(bad[0])
            raise ConfigError(
                f'profile {self.name}: row {i + 2} (t = {self.t_s[i + 1]:g} s) the load changes '
                f'from {self.load[i]:g} to {self.load[i + 1]:g} in {dt_rows[i]:g} s, faster '
                f'than one Newmark step ({what} = {dt:g} s); give the change at least {dt:g} s')

    def as_dict(self) -> dict:
        return {'name': self.name, 'source': self.source, 'rows': len(self),
                'duration_s': self.duration_s,
                'speed_rpm': [float(self.speed_rpm.min()), float(self.speed_rpm.max())],
                'load': [float(self.load.min()), float(self.load.max())]}


# ------------------------------------------------------------------------------- building

def make_profile(rows, *, name: str = 'profile', source: str = '', where: str = 'profile',
                 lines: list[int] | Callable[[int], int] | None = None) -> Profile:
    """A validated :class:`Profile` from rows (time_s, speed_rpm, load): a sequence of rows or
    an (n, 3) float array. ``where`` and ``lines`` (the file line of each row, a list or a
    function of the row index) go into the error messages."""

    def at(i: int) -> str:
        if lines is None:
            return f'{where} row {i + 1}'
        return f'{where}:{lines(i) if callable(lines) else lines[i]}'

    if not isinstance(rows, np.ndarray):
        rows = list(rows)
    _check_rows(len(rows), where)
    if isinstance(rows, np.ndarray) and rows.ndim == 2 and rows.shape[1] == 3:
        out = np.asarray(rows, dtype=float)
    else:
        out = np.empty((len(rows), 3))
        for i, row in enumerate(rows):
            if not isinstance(row, (list, tuple)) or len(row) != 3:
                raise field_error(at(i), 'row', 'must be [time_s, speed_rpm, load] (3 numbers)',
                                  row)
            for j, (col, value) in enumerate(zip(COLUMNS, row)):
                out[i, j] = number(value, at(i), col)
    _check_table(out, at, where)
    t, speed, load = out.T
    return Profile(t.copy(), speed.copy(), load.copy(), name=name, source=source)


def profile_from_table(table: Mapping, where: str = 'profile table') -> Profile:
    """The :class:`Profile` of :meth:`Profile.as_table`, validated as a file's rows are (a
    one-line ConfigError naming ``where`` if the table is not one)."""
    try:
        cols = [table[c] for c in ('t_s', 'speed_rpm', 'load')]
        rows = list(zip(*cols, strict=True))
    except (KeyError, TypeError, ValueError):
        raise ConfigError(f'{where}: not a profile table (t_s, speed_rpm and load lists of one '
                          'length)') from None
    prof = make_profile(rows, name=str(table.get('name') or 'profile'),
                        source=str(table.get('source') or ''), where=where)
    settle = table.get('settle_s')
    if settle is None:
        return prof
    return replace(prof, settle_s=number(settle, where, 'settle_s', *SETTLE_RANGE_S, unit='s'))


def _check_rows(n: int, where: str) -> None:
    if n < 2:
        raise ConfigError(f'{where}: a profile needs at least 2 rows (time_s, speed_rpm, load), '
                          f'got {n}')
    if n > MAX_PROFILE_ROWS:
        raise ConfigError(f'{where}: {n} rows, a profile has at most {MAX_PROFILE_ROWS}')


def _first(bad: np.ndarray) -> int | None:
    idx = np.flatnonzero(bad)
    return int(idx[0]) if len(idx) else None


def _check_table(out: np.ndarray, at: Callable[[int], str], where: str) -> None:
    """The rules of the module docstring over the whole table at once; the first broken one is
    reported for its row (the same message as a row checked alone)."""
    t, speed, load = out.T
    if (i := _first(~np.isfinite(out).all(axis=1))) is not None:
        for col, value in zip(COLUMNS, out[i]):
            number(float(value), at(i), col)
    if t[0] != 0.0:
        raise field_error(at(0), 'time_s', 'must start at 0 s', float(t[0]))
    dt = np.diff(t)
    if (i := _first(~(dt > 0))) is not None:
        raise field_error(at(i + 1), 'time_s', f'must increase strictly (after {t[i]:g})',
                          float(t[i + 1]))
    if (i := _first(~(speed > 0))) is not None:
        number(float(speed[i]), at(i), 'speed_rpm', 0.0, lo_open=True, unit='rpm')
    if (i := _first(~((load >= LOAD_LIMITS[0]) & (load <= LOAD_LIMITS[1])))) is not None:
        number(float(load[i]), at(i), 'load', *LOAD_LIMITS)
    rate = np.abs(np.diff(speed)) / dt
    if (i := _first(rate > MAX_SPEED_RATE_RPM_PER_S * (1 + 1e-9))) is not None:
        raise field_error(at(i + 1), 'speed_rpm', f'changes by {rate[i]:.6g} rpm/s after the row '
                          f'before ({speed[i]:g} rpm at {t[i]:g} s); at most '
                          f'{MAX_SPEED_RATE_RPM_PER_S:g} rpm/s (as a ramp:)', float(speed[i + 1]))
    if t[-1] > MAX_PROFILE_DURATION_S:
        raise field_error(at(len(t) - 1), 'time_s', f'must end within {MAX_PROFILE_DURATION_S:g} '
                          's (a day; split a longer cycle)', float(t[-1]))


def ramp_spec(from_rpm: float, to_rpm: float, rate_rpm_per_s: float, load: float = DEFAULT_LOAD,
              settle_s: float = DEFAULT_SETTLE_S) -> str:
    """The shortest ``ramp:`` spec of a ramp: trailing fields at their defaults left out, so
    that ``ramp:800:1000:100:1:2`` is written ``ramp:800:1000:100`` and ``ramp:800:1000:100:0:0``
    stays whole."""
    fields = [f'{float(v):g}' for v in (from_rpm, to_rpm, rate_rpm_per_s, load, settle_s)]
    if float(settle_s) == DEFAULT_SETTLE_S:
        fields.pop()
        if float(load) == DEFAULT_LOAD:
            fields.pop()
    return RAMP_PREFIX + ':'.join(fields)


def ramp_profile(from_rpm: float, to_rpm: float, rate_rpm_per_s: float,
                 load: float = DEFAULT_LOAD, settle_s: float = DEFAULT_SETTLE_S, *,
                 where: str = 'ramp') -> Profile:
    """Built-in run-up (to > from) or run-down: ``settle_s`` at ``from_rpm``, then a constant
    rate to ``to_rpm``; named by its :func:`ramp_spec`."""
    from_rpm = number(from_rpm, where, 'from_rpm', 0.0, lo_open=True, unit='rpm')
    to_rpm = number(to_rpm, where, 'to_rpm', 0.0, lo_open=True, unit='rpm')
    rate_rpm_per_s = number(rate_rpm_per_s, where, 'rate_rpm_per_s', *RAMP_RATE_RANGE,
                            unit='rpm/s')
    load = number(load, where, 'load', *LOAD_LIMITS)
    settle_s = number(settle_s, where, 'settle_s', *SETTLE_RANGE_S, unit='s')
    if from_rpm == to_rpm:
        raise field_error(where, 'to_rpm', f'must differ from from_rpm ({from_rpm:g} rpm): '
                          'nothing to ramp', to_rpm)
    ramp_s = abs(float(to_rpm) - float(from_rpm)) / float(rate_rpm_per_s)
    times = [0.0, float(settle_s), float(settle_s) + ramp_s] if settle_s > 0 else [0.0, ramp_s]
    speeds = ([from_rpm, from_rpm, to_rpm] if settle_s > 0 else [from_rpm, to_rpm])
    kind = 'run-up' if to_rpm > from_rpm else 'run-down'
    name = ramp_spec(from_rpm, to_rpm, rate_rpm_per_s, load, settle_s)
    p = make_profile([(t, s, load) for t, s in zip(times, speeds)], name=name,
                        source=f'built-in {kind} {float(from_rpm):g} -> {float(to_rpm):g} rpm at '
                        f'{float(rate_rpm_per_s):g} rpm/s, load {float(load):g}, after '
                        f'{float(settle_s):g} s at the start speed', where=where)
    return replace(p, settle_s=float(settle_s))


def step_spec(speed_rpm: float, from_load: float, to_load: float, rise_s: float,
              hold_s: float = DEFAULT_HOLD_S, settle_s: float = DEFAULT_SETTLE_S) -> str:
    """The shortest ``step:`` spec of a load step (trailing fields at their defaults left
    out, as :func:`ramp_spec`)."""
    fields = [f'{float(v):g}' for v in (speed_rpm, from_load, to_load, rise_s, hold_s,
                                        settle_s)]
    if float(settle_s) == DEFAULT_SETTLE_S:
        fields.pop()
        if float(hold_s) == DEFAULT_HOLD_S:
            fields.pop()
    return STEP_PREFIX + ':'.join(fields)


def step_profile(speed_rpm: float, from_load: float, to_load: float, rise_s: float,
                 hold_s: float = DEFAULT_HOLD_S, settle_s: float = DEFAULT_SETTLE_S, *,
                 where: str = 'step') -> Profile:
    """Built-in load step at ``speed_rpm``: ``settle_s`` at ``from_load``, to ``to_load`` in
    ``rise_s``, ``hold_s`` there, back in ``rise_s`` and ``hold_s`` at ``from_load`` (a tip-in
    and the tip-out after it, or the other way round); named by its :func:`step_spec`."""
    speed_rpm = number(speed_rpm, where, 'speed_rpm', 0.0, lo_open=True, unit='rpm')
    from_load = number(from_load, where, 'from', *LOAD_LIMITS)
    to_load = number(to_load, where, 'to', *LOAD_LIMITS)
    rise_s = number(rise_s, where, 'rise_s', *STEP_TIME_RANGE_S, lo_open=True, unit='s')
    hold_s = number(hold_s, where, 'hold_s', *STEP_TIME_RANGE_S, lo_open=True, unit='s')
    settle_s = number(settle_s, where, 'settle_s', *SETTLE_RANGE_S, unit='s')
    if from_load == to_load:
        raise field_error(where, 'to', f'must differ from from ({from_load:g}): no step',
                          to_load)
    t1 = settle_s + rise_s
    rows = [(settle_s, from_load), (t1, to_load), (t1 + hold_s, to_load),
            (t1 + hold_s + rise_s, from_load), (t1 + 2 * hold_s + rise_s, from_load)]
    spans = (('rise_s', rise_s), ('hold_s', hold_s)) * 2       # what moves each row on
    for (t_a, _), (t_b, _), (field, span) in zip(rows, rows[1:], spans):
        if not t_b > t_a:        # below the resolution of the time it is added to
            lo, hi = STEP_TIME_RANGE_S
            raise field_error(where, field, f'must be in ({lo:g}, {hi:g}] s and longer than the '
                              f'time resolution at t = {t_a:g} s ({math.ulp(t_a):.3g} s)', span)
    if settle_s > 0:
        rows.insert(0, (0.0, from_load))
    kind = 'tip-in' if to_load > from_load else 'tip-out'
    p = make_profile([(t, speed_rpm, ld) for t, ld in rows],
                     name=step_spec(speed_rpm, from_load, to_load, rise_s, hold_s, settle_s),
                     source=f'built-in {kind} at {speed_rpm:g} rpm: load {from_load:g} -> '
                     f'{to_load:g} in {rise_s:g} s, {hold_s:g} s there, back in {rise_s:g} s, '
                     f'after {settle_s:g} s at load {from_load:g}', where=where)
    return replace(p, settle_s=settle_s)


def _parse_step_spec(spec: str) -> Profile:
    parts = spec[len(STEP_PREFIX):].split(':')
    if not 4 <= len(parts) <= 6 or not all(p.strip() for p in parts):
        raise ConfigError(f'profile {spec!r}: write step:SPEED:FROM:TO:RISE[:HOLD[:SETTLE]] (rpm, '
                          'load -1..1, load -1..1, s, s, s), e.g. step:1200:0:1:0.1')
    names = ('speed_rpm', 'from_load', 'to_load', 'rise_s', 'hold_s', 'settle_s')
    return step_profile(**dict(zip(names, parts)), where=f'profile {spec!r}')


def _parse_ramp_spec(spec: str) -> Profile:
    parts = spec[len(RAMP_PREFIX):].split(':')
    if not 3 <= len(parts) <= 5 or not all(p.strip() for p in parts):
        raise ConfigError(f'profile {spec!r}: write ramp:FROM:TO:RATE[:LOAD[:SETTLE]] (rpm, rpm, '
                          'rpm/s, -1..1, s), e.g. ramp:800:2000:10:1.0')
    names = ('from_rpm', 'to_rpm', 'rate_rpm_per_s', 'load', 'settle_s')
    return ramp_profile(**dict(zip(names, parts)), where=f'profile {spec!r}')


def _file_size(path: Path, limit: int, kind: str) -> None:
    """Refuse a profile file larger than ``limit`` bytes before reading it."""
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise ConfigFileError(f'{path}: cannot be read ({exc.strerror or exc})') from None
    if size > limit:
        raise ConfigError(f'{path}: {size / 2**20:.1f} MiB, a {kind} profile is at most '
                          f'{limit / 2**20:g} MiB (at most {MAX_PROFILE_ROWS} rows'
                          + ('; write a longer table as CSV)' if kind == 'YAML' else ')'))


def _read_csv(path: Path) -> Profile:
    """A CSV table: the header checked here, the rows read by numpy; a row numpy cannot read is
    found and reported by the row-by-row reader (:func:`_read_csv_rows`)."""
    _file_size(path, MAX_PROFILE_CSV_BYTES, 'CSV')
    text = read_text(path)
    where = f'profile {path}'
    offset = header_line = 0
    header: list[str] = []
    for header_line, raw in enumerate(io.StringIO(text), start=1):
        offset += len(raw)
        stripped = raw.strip()
        if stripped and not stripped.startswith('#'):
            header = [c.strip() for c in next(csv.reader([stripped]))]
            break
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')         # 'input contained no data': refused below
            data = np.loadtxt(io.StringIO(text[offset:]), delimiter=',', comments='#',
                              ndmin=2, quotechar='"', max_rows=MAX_PROFILE_ROWS + 1)
    except ValueError:
        data = None
    if data is None or data.shape[1] != len(COLUMNS) or header != list(COLUMNS):
        return _read_csv_rows(path, text)

    def line_of(i: int) -> int:         # only for an error message: the file line of row i
        body = enumerate(io.StringIO(text[offset:]), start=header_line + 1)
        rows = (n for n, raw in body if raw.strip() and not raw.strip().startswith('#'))
        return next(n for k, n in enumerate(rows) if k == i)

    return make_profile(data, name=path.stem, source=str(path), where=where, lines=line_of)


def _read_csv_rows(path: Path, text: str) -> Profile:
    """The table row by row (Python), for the message naming the line numpy could not read."""
    where = f'profile {path}'
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
                raise field_error(f'{where}:{lineno}', 'header', f'must be {",".join(COLUMNS)}',
                                  stripped)
            continue
        if len(cells) != len(COLUMNS):
            raise field_error(f'{where}:{lineno}', 'row', f'must have 3 values '
                              f'({",".join(COLUMNS)})', stripped)
        rows.append(cells)
        lines.append(lineno)
        if len(rows) > MAX_PROFILE_ROWS:
            break
    if header is None:
        raise ConfigError(f'{where}: empty (expected the header {",".join(COLUMNS)})')
    return make_profile(rows, name=path.stem, source=str(path), where=where, lines=lines)


def _read_yaml(path: Path) -> Profile:
    where = f'profile {path}'
    _file_size(path, MAX_PROFILE_YAML_BYTES, 'YAML')
    data = parse_yaml(read_text(path), where)
    check_keys(data, where, '', (), ('name', 'source', 'points', 'ramp', 'step', 'columns'))
    name = str(data.get('name') or path.stem)
    source = str(data.get('source') or path)
    if sum(k in data for k in ('points', 'ramp', 'step')) != 1:
        raise ConfigError(f'{where}: give exactly one of points: (rows [time_s, speed_rpm, '
                          'load]), ramp: (from_rpm, to_rpm, rate_rpm_per_s, load, settle_s) or '
                          'step: (speed_rpm, from, to, rise_s, hold_s, settle_s)')
    if 'columns' in data and list(data['columns']) != list(COLUMNS):
        raise field_error(where, 'columns', f'must be {list(COLUMNS)}', data['columns'])
    if 'ramp' in data:
        ramp = check_keys(data['ramp'], where, 'ramp', ('from_rpm', 'to_rpm',
                                                             'rate_rpm_per_s'),
                          ('load', 'settle_s'))
        p = ramp_profile(**ramp, where=f'{where}: ramp')
        return replace(p, name=name, source=data.get('source') or p.source)
    if 'step' in data:
        step = check_keys(data['step'], where, 'step', ('speed_rpm', 'from', 'to', 'rise_s'),
                          ('hold_s', 'settle_s'))
        p = step_profile(step['speed_rpm'], step['from'], step['to'], step['rise_s'],
                         step.get('hold_s', DEFAULT_HOLD_S),
                         step.get('settle_s', DEFAULT_SETTLE_S), where=f'{where}: step')
        return replace(p, name=name, source=data.get('source') or p.source)
    points = data['points']
    if not isinstance(points, list):
        raise field_error(where, 'points', 'must be a list of [time_s, speed_rpm, load] rows',
                          points)
    return make_profile(points, name=name, source=source, where=f'{where}: points')


def packaged_profiles() -> list[str]:
    """Names of the profiles shipped in ``config/profiles``."""
    folder = config_dir() / PROFILE_DIR
    return sorted(p.stem for p in folder.glob('*.yaml')) if folder.is_dir() else []


def read_profile(spec: str | os.PathLike) -> Profile:
    """A profile from a CSV/YAML path, a packaged name or a ``ramp:`` spec (module docstring).
    Every refusal is one line starting with ``profile <spec or path>``, so a caller (the node's
    ``profile`` parameter, ``dmf-sim run``, ``dmf-sim setpoint``) adds no prefix of its own."""
    text = os.fspath(spec)
    if text.startswith(RAMP_PREFIX):
        return _parse_ramp_spec(text)
    if text.startswith(STEP_PREFIX):
        return _parse_step_spec(text)
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
        raise ConfigError(f'profile {text!r}: no such file, packaged profile ({names}), '
                          'ramp:FROM:TO:RATE or step:SPEED:FROM:TO:RISE spec')
    try:
        path = config_file(path)
    except ConfigFileError as exc:
        raise ConfigFileError(f'profile {text!r}: {one_line(exc)}') from None
    if path.suffix.lower() == '.csv':
        return _read_csv(path)
    if path.suffix.lower() in ('.yaml', '.yml'):
        return _read_yaml(path)
    raise ConfigError(f'profile {path}: a profile is a .csv or .yaml file, got '
                      f'{path.suffix or "none"}')
