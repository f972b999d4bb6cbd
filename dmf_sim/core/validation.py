"""Reading engine YAML fields: one-line :class:`~dmf_sim.core.errors.ConfigError` naming the file,
the
field and the allowed range (``engine_x.yaml: geometry.bore_m: must be in (0, 2] (got -1)``)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from dmf_sim.core.errors import ConfigError


def field_error(where: str, field: str, msg: str) -> ConfigError:
    """``where: field: msg`` on one line."""
    return ConfigError(' '.join(f'{where}: {field}: {msg}'.split()))


def check_keys(d: Any, where: str, field: str, required: Sequence[str],
               optional: Sequence[str] = ()) -> Mapping[str, Any]:
    """``d`` as a mapping holding every ``required`` key and nothing beyond ``optional``."""
    if not isinstance(d, Mapping):
        raise field_error(where, field or 'document', 'must be a mapping')
    prefix = field + '.' if field else ''
    for key in required:
        if key not in d:
            raise field_error(where, prefix + key, 'missing (required key)')
    allowed = set(required) | set(optional)
    for key in d:
        if key not in allowed:
            raise field_error(where, prefix + str(key),
                              f'unknown key (allowed: {", ".join(sorted(allowed))})')
    return d


def number(value: Any, where: str, field: str, lo: float, hi: float, *,
           lo_open: bool = False, hi_open: bool = False) -> float:
    """A finite number in [lo, hi] (or the open variants)."""
    lo_b, hi_b = '(' if lo_open else '[', ')' if hi_open else ']'
    rng = f'{lo_b}{lo:g}, {hi:g}{hi_b}'
    if isinstance(value, str):  # PyYAML (YAML 1.1) reads 1.0e5 without a sign as a string
        try:
            value = float(value)
        except ValueError:
            pass
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise field_error(where, field, f'must be a number in {rng} (got {value!r})')
    x = float(value)
    if not math.isfinite(x) or x < lo or x > hi or (lo_open and x == lo) or (hi_open and x == hi):
        raise field_error(where, field, f'must be in {rng} (got {value!r})')
    return x


def integer(value: Any, where: str, field: str, lo: int, hi: int) -> int:
    """An integer in [lo, hi]."""
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise field_error(where, field, f'must be an integer in [{lo}, {hi}] (got {value!r})')
    return int(value)


def number_list(value: Any, where: str, field: str, lo: float, hi: float, *,
                min_len: int = 1, increasing: bool = False) -> np.ndarray:
    """A list of at least ``min_len`` numbers in [lo, hi] (strictly increasing if asked)."""
    if not isinstance(value, (list, tuple)) or len(value) < min_len:
        raise field_error(where, field,
                          f'must be a list of at least {min_len} numbers in [{lo:g}, {hi:g}]')
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
