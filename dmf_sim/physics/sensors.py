"""The driveline's sensors: the ``sensors:`` section of the driveline YAML (doc/configuration.md).

What a vehicle software stack sees of the driveline instead of element angles:

* **tooth wheels** (:class:`ToothWheel`) on any element: ``teeth`` equally spaced teeth of which
  the last ``gap`` are missing (60-2: ``teeth: 60, gap: 2``), each tooth's edge displaced by a
  pitch error, the edge times captured by a timer of ``timer_resolution_s`` with Gaussian
  ``timer_jitter_s``. Tooth index 0 is the first tooth after the gap; its edge lies at
  ``offset_deg`` of the element's absolute angle (tooth j at ``offset + j * 360/teeth`` deg plus
  its pitch error). Pitch errors are given per tooth (``pitch_errors_deg``, one per tooth that
  exists) or drawn as a seeded pattern (``pitch_error_sigma_deg``: Gaussian, its mean removed,
  from :mod:`dmf_sim.core.counter_random`, the same on every machine);
* **bus signals** (:class:`BusSignal`): a speed as a vehicle bus carries it, the mean speed of
  an element over the last ``period_s`` (from the element's angle), plus Gaussian ``noise_rpm``,
  quantized to ``resolution_rpm``, sent every ``period_s`` and delivered ``delay_s`` later. The
  source is an element (``element:``) or a tooth wheel's element (``wheel:``).

The signals themselves are synthesized by :mod:`dmf_sim.physics.sensor_signals`. Every field is
checked here with one line naming it (:mod:`dmf_sim.core.validation`). Example::

    sensors:
      tooth_wheels:
        - {name: crank, element: PRIMARY FLYWHEEL, teeth: 60, gap: 2,
           pitch_error_sigma_deg: 0.02, timer_resolution_s: 1.0e-7, timer_jitter_s: 2.0e-7,
           seed: 1}
      bus_signals:
        - {name: engine_speed, wheel: crank, period_s: 0.01, resolution_rpm: 0.125,
           delay_s: 0.005, noise_rpm: 0.25, seed: 11}
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.validation import check_keys, field_error, integer, number

__all__ = ['SECTION_KEYS', 'WHEEL_KEYS_REQUIRED', 'WHEEL_KEYS_OPTIONAL', 'BUS_KEYS_REQUIRED',
           'BUS_KEYS_OPTIONAL', 'BUS_SOURCE_KEYS', 'MAX_TEETH', 'TIMER_RESOLUTION_RANGE_S',
           'DEFAULT_TIMER_RESOLUTION_S', 'TIMER_JITTER_MAX_S', 'BUS_PERIOD_RANGE_S',
           'BUS_DELAY_MAX_S', 'BUS_RESOLUTION_MAX_RPM', 'BUS_NOISE_MAX_RPM',
           'PITCH_SIGMA_MAX_PITCHES', 'PITCH_ERROR_MAX_PITCHES', 'STREAM_PITCH_PATTERN',
           'MAX_SEED', 'NAME_PATTERN', 'FLAG_FIRST_AFTER_GAP', 'FLAG_SPURIOUS', 'ToothWheel',
           'BusSignal', 'SensorSet', 'parse_sensors', 'EDGE_BATCH_MAX_S']

SECTION_KEYS = ('tooth_wheels', 'bus_signals', 'edge_batch_s')
EDGE_BATCH_MAX_S = 1.0       # longest edge-batch period [s]
WHEEL_KEYS_REQUIRED = ('name', 'element', 'teeth')
WHEEL_KEYS_OPTIONAL = ('gap', 'offset_deg', 'pitch_errors_deg', 'pitch_error_sigma_deg',
                       'timer_resolution_s', 'timer_jitter_s', 'seed')
BUS_KEYS_REQUIRED = ('name', 'period_s', 'resolution_rpm')
BUS_SOURCE_KEYS = ('wheel', 'element')                # give one
BUS_KEYS_OPTIONAL = BUS_SOURCE_KEYS + ('delay_s', 'noise_rpm', 'seed')

MAX_TEETH = 3600                   # 0.1 deg per tooth: finer than any production tooth wheel
TIMER_RESOLUTION_RANGE_S = (1e-9, 1e-3)   # stamps are in ns; a 1 kHz timer is the coarsest
DEFAULT_TIMER_RESOLUTION_S = 1e-7  # a 10 MHz capture timer, as engine controllers have
TIMER_JITTER_MAX_S = 1e-3
BUS_PERIOD_RANGE_S = (1e-4, 60.0)  # from one Newmark step to a once-a-minute signal
BUS_DELAY_MAX_S = 10.0
BUS_RESOLUTION_MAX_RPM = 1000.0
BUS_NOISE_MAX_RPM = 1000.0
PITCH_SIGMA_MAX_PITCHES = 0.1      # a drawn pattern keeps its teeth in order (5 sigma < 1/2 pitch)
PITCH_ERROR_MAX_PITCHES = 0.5      # a given error: each edge stays between its neighbours
STREAM_PITCH_PATTERN = 6           # counter_random stream of the drawn pitch-error pattern
MAX_SEED = 2**63 - 1               # seeds are int64 >= 0, as dmf_sim.core.counter_random takes
NAME_PATTERN = re.compile(r'[A-Za-z][A-Za-z0-9_]*\Z')   # one token of a ROS topic name

# flags of a tooth edge (dmf_sim.physics.sensor_signals sets them; the edge-batch messages carry
# them, dmf_sim.bags.sensor_messages)
FLAG_FIRST_AFTER_GAP = 1    # bit 0: the first edge after the gap (tooth 0 of a wheel with a gap)
FLAG_SPURIOUS = 2           # bit 1: a spurious edge a sensor fault injected (ground truth)


@dataclass(frozen=True)
class ToothWheel:
    """A tooth wheel on an element (see the module docstring).

    name: topic token (``sensors/<name>/edges``); element: the driveline element it turns with;
    teeth: tooth positions N (pitch 360/N deg), ``gap`` of them missing at the end of the
    revolution; offset_deg: the element angle of tooth 0's edge; pitch_errors_deg: the angular
    error of each tooth that exists (N - gap values, tooth 0 first) [deg];
    pitch_error_sigma_deg: the sigma they were drawn with (0 when given or none);
    timer_resolution_s, timer_jitter_s [s]; seed: of the drawn pattern and the jitter.
    """

    name: str
    element: str
    teeth: int
    gap: int = 0
    offset_deg: float = 0.0
    pitch_errors_deg: tuple[float, ...] = ()
    pitch_error_sigma_deg: float = 0.0
    timer_resolution_s: float = DEFAULT_TIMER_RESOLUTION_S
    timer_jitter_s: float = 0.0
    seed: int = 0

    @property
    def present_teeth(self) -> int:
        """Teeth that exist (``teeth - gap``): edges per revolution."""
        return self.teeth - self.gap

    @property
    def pitch_rad(self) -> float:
        return 2.0 * math.pi / self.teeth

    def pitch_errors_rad(self) -> np.ndarray:
        """Pitch error of each tooth that exists [rad] (zeros without any)."""
        if not self.pitch_errors_deg:
            return np.zeros(self.present_teeth)
        return np.radians(np.asarray(self.pitch_errors_deg, dtype=float))

    def tooth_angles_rad(self) -> np.ndarray:
        """Element angle of each tooth's edge within a revolution [rad], tooth 0 first:
        ``offset + j * pitch + error_j`` (increasing; the last one below tooth 0's + 2 pi)."""
        j = np.arange(self.present_teeth)
        return math.radians(self.offset_deg) + j * self.pitch_rad + self.pitch_errors_rad()

    def as_dict(self) -> dict[str, Any]:
        """The YAML mapping that gives this wheel back (a drawn pattern as its sigma: the
        draws are the same everywhere)."""
        d = {'name': self.name, 'element': self.element, 'teeth': self.teeth, 'gap': self.gap,
             'offset_deg': self.offset_deg, 'timer_resolution_s': self.timer_resolution_s,
             'timer_jitter_s': self.timer_jitter_s, 'seed': self.seed}
        if self.pitch_error_sigma_deg:
            d['pitch_error_sigma_deg'] = self.pitch_error_sigma_deg
        elif self.pitch_errors_deg:
            d['pitch_errors_deg'] = list(self.pitch_errors_deg)
        return d


@dataclass(frozen=True)
class BusSignal:
    """A speed on the vehicle bus (see the module docstring).

    name: topic token (``vehicle_bus/<name>``); element: the element whose speed it carries;
    wheel: the tooth wheel named as its source (None when given by element); period_s,
    delay_s [s]; resolution_rpm, noise_rpm [rpm]; seed: of the noise.
    """

    name: str
    element: str
    period_s: float
    resolution_rpm: float
    wheel: str | None = None
    delay_s: float = 0.0
    noise_rpm: float = 0.0
    seed: int = 0

    def as_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {'name': self.name}
        d.update({'wheel': self.wheel} if self.wheel is not None else {'element': self.element})
        d.update(period_s=self.period_s, resolution_rpm=self.resolution_rpm,
                 delay_s=self.delay_s, noise_rpm=self.noise_rpm, seed=self.seed)
        return d


def _named(items, name: str, what: str):
    for item in items:
        if item.name == name:
            return item
    raise ConfigError(f'unknown {what} {name!r}; {what}s are '
                      f'{", ".join(i.name for i in items) or "none"}')


@dataclass(frozen=True)
class SensorSet:
    """The sensors of a driveline (empty without a ``sensors:`` section)."""

    tooth_wheels: tuple[ToothWheel, ...] = ()
    bus_signals: tuple[BusSignal, ...] = ()
    edge_batch_s: float = 0.0
    """Each wheel's edges go out in one message per this period of simulated time [s] (0: per
    publish period; rounded to a whole number of publish periods, at least one): the edges
    captured in (b - period, b] are sent at b (:meth:`edge_batch_ns`)."""

    def edge_batch_ns(self, sample_period_s: float) -> float:
        """The edge-batch period [ns] at publish period ``sample_period_s`` [s]: a whole
        number of publish periods, at least one (the node sends at its publish ticks)."""
        k = max(1, round(self.edge_batch_s / sample_period_s))
        return k * sample_period_s * 1e9

    @property
    def names(self) -> tuple[str, ...]:
        """Every sensor's name, tooth wheels first."""
        return tuple(s.name for s in self.tooth_wheels) + tuple(s.name for s in self.bus_signals)

    def __bool__(self) -> bool:
        return bool(self.tooth_wheels or self.bus_signals)

    def wheel(self, name: str) -> ToothWheel:
        """The tooth wheel called ``name`` (ConfigError naming the ones there are)."""
        return _named(self.tooth_wheels, name, 'tooth wheel')

    def signal(self, name: str) -> BusSignal:
        """The bus signal called ``name`` (ConfigError naming the ones there are)."""
        return _named(self.bus_signals, name, 'bus signal')

    def as_dict(self) -> dict[str, Any]:
        """The ``sensors:`` mapping that gives this set back (:func:`parse_sensors`)."""
        out: dict[str, Any] = {'tooth_wheels': [w.as_dict() for w in self.tooth_wheels],
                               'bus_signals': [s.as_dict() for s in self.bus_signals]}
        if self.edge_batch_s:
            out['edge_batch_s'] = self.edge_batch_s
        return out


# --------------------------------------------------------------------------------------------
# Parsing and validation
# --------------------------------------------------------------------------------------------

def _seed(raw: dict, where: str) -> int:
    return integer(raw.get('seed', 0), where, 'seed', 0, MAX_SEED)


def _name(raw: dict, where: str) -> str:
    name = raw['name']
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        raise field_error(where, 'name', 'must be a letter followed by letters, digits or '
                          "'_' (it names a topic)", name)
    return name


def _element(value, where: str, field_name: str, elements: Sequence[str] | None) -> str:
    if elements is not None and value not in elements:
        raise field_error(where, field_name, 'names no element of the driveline; elements are '
                          + ', '.join(elements), value)
    return str(value)


def _drawn_pattern(n: int, sigma_deg: float, seed: int) -> tuple[float, ...]:
    """The seeded pitch-error pattern [deg]: Gaussian of ``sigma_deg``, its mean removed (a
    common offset is the wheel's mounting angle, not a pitch error)."""
    from dmf_sim.core.counter_random import gaussians  # numba: not for `dmf-sim --help`

    if sigma_deg == 0.0:
        return ()
    z = np.empty(n)
    gaussians(seed, STREAM_PITCH_PATTERN, 0, z)
    e = sigma_deg * z
    return tuple(float(x) for x in e - e.mean())


def _parse_wheel(raw, pos: int, elements: Sequence[str] | None) -> ToothWheel:
    where = f'sensors.tooth_wheels[{pos}]'
    if isinstance(raw, dict) and isinstance(raw.get('name'), str):
        where += f' ({raw["name"]})'
    check_keys(raw, where, '', WHEEL_KEYS_REQUIRED, WHEEL_KEYS_OPTIONAL)
    name = _name(raw, where)
    element = _element(raw['element'], where, 'element', elements)
    teeth = integer(raw['teeth'], where, 'teeth', 1, MAX_TEETH)
    gap = integer(raw.get('gap', 0), where, 'gap', 0, teeth - 1)
    offset = number(raw.get('offset_deg', 0.0), where, 'offset_deg', -360.0, 360.0, unit='deg')
    res = number(raw.get('timer_resolution_s', DEFAULT_TIMER_RESOLUTION_S), where,
                 'timer_resolution_s', *TIMER_RESOLUTION_RANGE_S, unit='s')
    jitter = number(raw.get('timer_jitter_s', 0.0), where, 'timer_jitter_s', 0.0,
                    TIMER_JITTER_MAX_S, unit='s')
    seed = _seed(raw, where)
    pitch_deg = 360.0 / teeth
    present = teeth - gap
    if 'pitch_errors_deg' in raw and 'pitch_error_sigma_deg' in raw:
        raise ConfigError(f"{where}: give either 'pitch_errors_deg' (one per tooth) or "
                          "'pitch_error_sigma_deg' (a seeded pattern), not both")
    sigma = 0.0
    if 'pitch_errors_deg' in raw:
        values = raw['pitch_errors_deg']
        if not isinstance(values, list) or len(values) != present:
            raise field_error(where, 'pitch_errors_deg', f'must be a list of {present} numbers '
                              f'(one per tooth that exists: teeth {teeth} - gap {gap}) [deg]',
                              values)
        lim = PITCH_ERROR_MAX_PITCHES * pitch_deg
        errors = tuple(number(v, where, f'pitch_errors_deg[{j}]', -lim, lim, lo_open=True,
                              hi_open=True, unit='deg (half a pitch)')
                       for j, v in enumerate(values))
    else:
        sigma = number(raw.get('pitch_error_sigma_deg', 0.0), where, 'pitch_error_sigma_deg',
                       0.0, PITCH_SIGMA_MAX_PITCHES * pitch_deg,
                       unit=f'deg ({PITCH_SIGMA_MAX_PITCHES:g} pitch)')
        errors = _drawn_pattern(present, sigma, seed)
        if errors and max(abs(e) for e in errors) >= PITCH_ERROR_MAX_PITCHES * pitch_deg:
            raise field_error(where, 'pitch_error_sigma_deg', 'draws an error beyond half a '
                              'pitch with this seed; use a smaller sigma or another seed', sigma)
    return ToothWheel(name, element, teeth, gap, offset, errors, sigma, res, jitter, seed)


def _parse_bus(raw, pos: int, elements: Sequence[str] | None,
               wheels: dict[str, ToothWheel]) -> BusSignal:
    where = f'sensors.bus_signals[{pos}]'
    if isinstance(raw, dict) and isinstance(raw.get('name'), str):
        where += f' ({raw["name"]})'
    check_keys(raw, where, '', BUS_KEYS_REQUIRED, BUS_KEYS_OPTIONAL)
    name = _name(raw, where)
    given = [k for k in BUS_SOURCE_KEYS if k in raw]
    if len(given) != 1:
        raise ConfigError(f"{where}: give its source once, as 'wheel' (a tooth wheel's name) "
                          f"or 'element' (an element's name){'' if not given else ', not both'}")
    wheel = None
    if given[0] == 'wheel':
        wheel = raw['wheel']
        if wheel not in wheels:
            raise field_error(where, 'wheel', 'names no tooth wheel; tooth wheels are '
                              + (', '.join(wheels) or 'none'), wheel)
        element = wheels[wheel].element
    else:
        element = _element(raw['element'], where, 'element', elements)
    period = number(raw['period_s'], where, 'period_s', *BUS_PERIOD_RANGE_S, unit='s')
    res = number(raw['resolution_rpm'], where, 'resolution_rpm', 0.0, BUS_RESOLUTION_MAX_RPM,
                 lo_open=True, unit='rpm')
    delay = number(raw.get('delay_s', 0.0), where, 'delay_s', 0.0, BUS_DELAY_MAX_S, unit='s')
    noise = number(raw.get('noise_rpm', 0.0), where, 'noise_rpm', 0.0, BUS_NOISE_MAX_RPM,
                   unit='rpm')
    return BusSignal(name, element, period, res, wheel, delay, noise, _seed(raw, where))


def _list(raw, key: str) -> list:
    value = raw.get(key)
    if value is None:
        return []
    if not isinstance(value, list):
        raise field_error('sensors', key, 'must be a list of mappings', value)
    return value


def parse_sensors(raw, elements: Sequence[str] | None = None) -> SensorSet:
    """The ``sensors:`` mapping (None: no sensors) as a :class:`SensorSet`; ``elements``: the
    driveline's element names (None: not checked, e.g. a set read back from a bag). A bad field
    is a ConfigError of one line naming it; names must be unique over wheels and signals."""
    if raw is None:
        return SensorSet()
    check_keys(raw, 'sensors', '', (), SECTION_KEYS)
    wheels: dict[str, ToothWheel] = {}
    for i, item in enumerate(_list(raw, 'tooth_wheels')):
        w = _parse_wheel(item, i, elements)
        if w.name in wheels:
            raise ConfigError(f'sensors.tooth_wheels[{i}]: name {w.name!r} is used twice; '
                              'sensor names must be unique')
        wheels[w.name] = w
    signals: dict[str, BusSignal] = {}
    for i, item in enumerate(_list(raw, 'bus_signals')):
        s = _parse_bus(item, i, elements, wheels)
        if s.name in signals or s.name in wheels:
            raise ConfigError(f'sensors.bus_signals[{i}]: name {s.name!r} is used twice; '
                              'sensor names must be unique')
        signals[s.name] = s
    batch = number(raw.get('edge_batch_s', 0.0), 'sensors', 'edge_batch_s', 0.0,
                   EDGE_BATCH_MAX_S, unit='s')
    return SensorSet(tuple(wheels.values()), tuple(signals.values()), batch)
