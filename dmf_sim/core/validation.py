"""Validation of user input, one place for the whole package: every field of a driveline, engine,
study or optimizer file (and every option the commands share) is checked here, and every refusal
reads the same way, on one line, as a :class:`~dmf_sim.core.errors.ConfigError`::

    <where>: field '<field>' <requirement>, got <value>
    element 4 (CYL2): field 'inertia' must be > 0 kg m^2, got 0.0
    engine_x.yaml: field 'geometry.bore_m' must be in (0, 2] m, got -1
    study.yaml: missing key 'conditions.speeds_rpm'

``where`` names the file or the part of it (``element 4 (CYL2)``, ``dmf``); ``field`` is the
dotted path inside it. :class:`Where` binds a ``where`` for a reader that checks many fields.
Numbers written the YAML 1.1 way without a dot (``1e300``), which PyYAML reads as strings, are
taken as the numbers the user meant.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from dmf_sim.core.errors import ConfigError

__all__ = ['field_error', 'check_keys', 'as_number', 'number', 'integer', 'number_list',
           'nonempty_list', 'Where', 'Table1D', 'table_1d', 'ros_namespace',
           'NAMESPACE_MAX_LENGTH']

_NO_VALUE = object()


def field_error(where: str, field: str, msg: str, value: Any = _NO_VALUE) -> ConfigError:
    """``<where>: field '<field>' <msg>[, got <value>]`` on one line (``<where>: <msg>`` without
    a field)."""
    text = f"{where}: field '{field}' {msg}" if field else f'{where}: {msg}'
    if value is not _NO_VALUE:
        text += f', got {value!r}'
    return ConfigError(' '.join(text.split()))


def check_keys(d: Any, where: str, field: str, required: Sequence[str] = (),
               optional: Sequence[str] | None = ()) -> Mapping[str, Any]:
    """``d`` as a mapping holding every ``required`` key and, unless ``optional`` is None (any
    key), nothing beyond ``optional``."""
    if not isinstance(d, Mapping):
        got = 'nothing' if d is None else f'a {type(d).__name__}'
        raise field_error(where, field, f'must be a mapping, got {got}')
    prefix = field + '.' if field else ''
    for key in required:
        if key not in d:
            raise ConfigError(f"{where}: missing key '{prefix}{key}'")
    if optional is not None:
        allowed = set(required) | set(optional)
        for key in d:
            if key not in allowed:
                raise ConfigError(f"{where}: unknown key '{prefix}{key}' "
                                  f'(allowed: {", ".join(sorted(allowed))})')
    return d


def as_number(value: Any) -> Any:
    """``value`` as a float where it is a string that spells a number (PyYAML follows YAML 1.1,
    which needs a dot: ``1e300`` and ``1.0e5`` without a sign arrive as strings); else as is."""
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


def _range_text(lo: float, hi: float, lo_open: bool, hi_open: bool, unit: str) -> str:
    if lo == -math.inf and hi == math.inf:
        return 'finite'
    if hi == math.inf:
        text = f'{">" if lo_open else ">="} {lo:g}'
    elif lo == -math.inf:
        text = f'{"<" if hi_open else "<="} {hi:g}'
    else:
        text = f'in {"(" if lo_open else "["}{lo:g}, {hi:g}{")" if hi_open else "]"}'
    return f'{text} {unit}'.rstrip()


def number(value: Any, where: str, field: str, lo: float = -math.inf, hi: float = math.inf, *,
           lo_open: bool = False, hi_open: bool = False, unit: str = '') -> float:
    """A finite number in [lo, hi] (or the open variants), ``unit`` named in the message."""
    rng = _range_text(lo, hi, lo_open, hi_open, unit)
    x = as_number(value)
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise field_error(where, field, f'must be a number {rng}'.replace('number finite',
                                                                          'finite number'), value)
    x = float(x)
    if not math.isfinite(x) or x < lo or x > hi or (lo_open and x == lo) or (hi_open and x == hi):
        raise field_error(where, field, f'must be {rng}', value)
    return x


def integer(value: Any, where: str, field: str, lo: int, hi: int) -> int:
    """An integer in [lo, hi]."""
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise field_error(where, field, f'must be an integer in [{lo}, {hi}]', value)
    return int(value)


def nonempty_list(value: Any, where: str, field: str) -> list:
    """A non-empty list."""
    if not isinstance(value, list) or not value:
        raise field_error(where, field, 'must be a non-empty list', value)
    return value


class Where:
    """The checks above bound to one ``where`` (a file or a part of it)."""

    def __init__(self, source: str):
        self.source = source

    def error(self, field: str, msg: str, value: Any = _NO_VALUE) -> ConfigError:
        return field_error(self.source, field, msg, value)

    def mapping(self, data: Any, field: str, required: Sequence[str] = (),
                optional: Sequence[str] | None = None) -> dict:
        return check_keys(data, self.source, field, required, optional)

    def number(self, value: Any, field: str, lo: float = -math.inf, hi: float = math.inf,
               unit: str = '', **kw) -> float:
        return number(value, self.source, field, lo, hi, unit=unit, **kw)

    def integer(self, value: Any, field: str, lo: int, hi: int) -> int:
        return integer(value, self.source, field, lo, hi)

    def nonempty_list(self, value: Any, field: str) -> list:
        return nonempty_list(value, self.source, field)


def number_list(value: Any, where: str, field: str, lo: float, hi: float, *,
                min_len: int = 1, increasing: bool = False) -> np.ndarray:
    """A list of at least ``min_len`` numbers in [lo, hi] (strictly increasing if asked)."""
    if not isinstance(value, (list, tuple)) or len(value) < min_len:
        raise field_error(where, field,
                          f'must be a list of at least {min_len} numbers in [{lo:g}, {hi:g}]',
                          value)
    arr = np.array([number(v, where, f'{field}[{i}]', lo, hi) for i, v in enumerate(value)])
    if increasing and np.any(np.diff(arr) <= 0):
        raise field_error(where, field, f'must be strictly increasing within [{lo:g}, {hi:g}]')
    return arr


@dataclass(frozen=True)
class Table1D:
    """Piecewise-linear table y(x), held constant outside its points."""

    x: np.ndarray
    y: np.ndarray

    def __call__(self, x: float) -> float:
        return float(np.interp(x, self.x, self.y))


def table_1d(d: Any, where: str, field: str, x_key: str, y_key: str,
             x_range: tuple[float, float], y_range: tuple[float, float]) -> Table1D:
    """A ``{x_key: [...], y_key: [...]}`` table with strictly increasing x."""
    check_keys(d, where, field, [x_key, y_key])
    x = number_list(d[x_key], where, f'{field}.{x_key}', *x_range, min_len=1, increasing=True)
    y = number_list(d[y_key], where, f'{field}.{y_key}', *y_range, min_len=1)
    if len(x) != len(y):
        raise field_error(where, f'{field}.{y_key}',
                          f'must have as many entries as {x_key} ({len(x)})')
    return Table1D(x, y)


_NAMESPACE_TOKEN = re.compile(r'[A-Za-z_][A-Za-z0-9_]*')
NAMESPACE_MAX_LENGTH = 245   # characters, '/' included: rmw's RMW_NAMESPACE_MAX_LENGTH (Jazzy)


def ros_namespace(value: str | None, what: str = '--namespace') -> str:
    """A ROS namespace taken as ``ros2 launch ... namespace:=`` and rclpy take it, written one
    way: ``''`` for the root (``''`` or ``'/'``), else absolute, ``'/truck1'``, ``'/fleet/t1'``.
    A relative namespace is taken from the root (``truck1`` -> ``/truck1``), as launch_ros and
    rcl do. ROS's rules (``rmw_validate_namespace``): tokens of ASCII letters, digits and
    underscores, none starting with a digit, separated by single ``/``, no ``/`` at the end,
    at most :data:`NAMESPACE_MAX_LENGTH` characters. A one-line :class:`ConfigError` naming
    ``what`` otherwise."""
    text = '' if value is None else str(value)
    if text in ('', '/'):
        return ''
    absolute = text if text.startswith('/') else '/' + text
    problem = None
    if len(absolute) > NAMESPACE_MAX_LENGTH:
        problem = f'it is longer than {NAMESPACE_MAX_LENGTH} characters'
    elif absolute.endswith('/'):
        problem = "it ends with '/'"
    elif '//' in absolute:
        problem = "it has an empty token ('//')"
    else:
        for token in absolute[1:].split('/'):
            if not _NAMESPACE_TOKEN.fullmatch(token):
                problem = (f'token {token!r} starts with a digit' if token[:1].isdigit()
                           else f'token {token!r} has characters other than letters, digits '
                           'and underscores')
                break
    if problem:
        raise ConfigError(f'{what} {text!r} is not a ROS namespace: {problem} (tokens of '
                          "letters, digits and '_', not starting with a digit, joined by '/', "
                          'e.g. truck1 or /fleet/truck1)')
    return absolute
