"""Validation of user input, one place for the whole package: every field of a driveline, engine,
study or optimizer file (and every option the commands share) is checked here, and every refusal
reads the same way, on one line, as a :class:`~dmf_sim.core.errors.ConfigError`::

    <where>: field '<field>' <requirement>, got <value>
    element 4 (CYL2): field 'inertia' must be in (0, 1e+06] kg m^2, got 1e+308
    engine_x.yaml: field 'geometry.bore_m' must be in (0, 2] m, got -1.0
    study.yaml: missing key 'conditions.speeds_rpm'

``where`` names the file or the part of it (``element 4 (CYL2)``, ``dmf``); ``field`` is the
dotted path inside it. The bound of every physical quantity is in the one table
:data:`dmf_sim.core.bounds.BOUNDS` (with its reason), and :func:`bounded` checks a field against
it. :class:`Where` binds a ``where`` for a reader that checks many fields.
Numbers written the YAML 1.1 way without a dot (``1e300``), which PyYAML reads as strings, are
taken as the numbers the user meant.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Mapping, Sequence

import numpy as np

from dmf_sim.core.bounds import BOUNDS
from dmf_sim.core.errors import ConfigError

__all__ = ['SEED_MAX', 'field_error', 'check_keys', 'as_number', 'number', 'bounded', 'integer',
           'number_list', 'nonempty_list', 'Where', 'Table1D', 'table_1d']

SEED_MAX = 2 ** 32 - 1
"""Largest seed of a random generator (numpy's seeds are 0 .. 2**32 - 1; a negative one is an
error there): every seed a user gives is checked against 0 .. SEED_MAX."""

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
        raise field_error(where, field, f'must be {rng}', x)
    return x


def bounded(value: Any, where: str, field: str, quantity: str, *,
            positive: bool = False) -> float:
    """A finite number within the bound of the physical ``quantity``
    (:data:`dmf_sim.core.bounds.BOUNDS`: the one table, with the reasons), e.g.
    ``element 4 (CYL2): field 'inertia' must be in (0, 1e+06] kg m^2, got 1e+308``.
    ``positive``: 0 excluded too, where the use needs it (a spring that carries torque)."""
    b = BOUNDS[quantity]
    if positive and b.lo == 0.0 and not b.lo_open:
        b = replace(b, lo_open=True)
    if b.signed:
        x = number(value, where, field)
        if not b.contains(x):
            raise field_error(where, field, f'must be {b.text()}', x)
        return x
    return number(value, where, field, b.lo, b.hi, lo_open=b.lo_open, hi_open=b.hi_open,
                  unit=b.unit)


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

    def bounded(self, value: Any, field: str, quantity: str, **kw) -> float:
        return bounded(value, self.source, field, quantity, **kw)

    def integer(self, value: Any, field: str, lo: int, hi: int) -> int:
        return integer(value, self.source, field, lo, hi)

    def nonempty_list(self, value: Any, field: str) -> list:
        return nonempty_list(value, self.source, field)


def number_list(value: Any, where: str, field: str, lo: float = -math.inf,
                hi: float = math.inf, *, min_len: int = 1, increasing: bool = False,
                quantity: str | None = None) -> np.ndarray:
    """A list of at least ``min_len`` numbers in [lo, hi], or within the bound of the physical
    ``quantity`` (:func:`bounded`) when one is given (strictly increasing if asked)."""
    rng = BOUNDS[quantity].text() if quantity else f'in [{lo:g}, {hi:g}]'
    if not isinstance(value, (list, tuple)) or len(value) < min_len:
        raise field_error(where, field, f'must be a list of at least {min_len} numbers {rng}',
                          value)
    arr = np.array([bounded(v, where, f'{field}[{i}]', quantity) if quantity
                    else number(v, where, f'{field}[{i}]', lo, hi) for i, v in enumerate(value)])
    if increasing and np.any(np.diff(arr) <= 0):
        raise field_error(where, field, f'must be strictly increasing, each {rng}')
    return arr


@dataclass(frozen=True)
class Table1D:
    """Piecewise-linear table y(x), held constant outside its points."""

    x: np.ndarray
    y: np.ndarray

    def __call__(self, x: float) -> float:
        return float(np.interp(x, self.x, self.y))


def table_1d(d: Any, where: str, field: str, x_key: str, y_key: str,
             x_quantity: str, y_quantity: str) -> Table1D:
    """A ``{x_key: [...], y_key: [...]}`` table with strictly increasing x, x and y within the
    bounds of their physical quantities (:func:`bounded`)."""
    check_keys(d, where, field, [x_key, y_key])
    x = number_list(d[x_key], where, f'{field}.{x_key}', min_len=1, increasing=True,
                    quantity=x_quantity)
    y = number_list(d[y_key], where, f'{field}.{y_key}', min_len=1, quantity=y_quantity)
    if len(x) != len(y):
        raise field_error(where, f'{field}.{y_key}',
                          f'must have as many entries as {x_key} ({len(x)})')
    return Table1D(x, y)
