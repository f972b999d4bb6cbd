"""User tables of complex per-cylinder A_n over speed (and load): reading, validation, writing.

Formats (the package docstring, dmf_sim.physics.engine, has the full description):

* CSV: ``#`` comments (``# engine: <name|path>`` names the engine YAML for geometry, firing
  phases and load sets), header ``speed_rpm,n,re,im`` or ``speed_rpm,load,n,re,im``;
* YAML: ``speeds_rpm``, optional ``loads``, ``orders`` 0..n_max, ``coefficients``
  [speed][load][order] -> [re, im] (``[speed][order]`` without loads), optional ``engine``.

Inside the table the gas part is ``table - inertia(geometry)``, interpolated linearly in speed and
load; the exact inertia part is added back at the actual speed. A table without a load axis is
full-load data: its gas part scales with the load fraction.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from dmf_sim.core.bounds import BOUNDS
from dmf_sim.core.csv_out import write_csv
from dmf_sim.core.errors import ConfigFileError
from dmf_sim.core.paths import read_text
from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.core.validation import check_keys, field_error, number_list
from dmf_sim.physics.engine.config import N_MAX_RANGE, read_engine_config, resolve_ref
from dmf_sim.physics.engine.excitation import Engine, EngineExcitation, GasGrid

__all__ = ['DEFAULT_ENGINE', 'TABLE_SPEED_RANGE_RPM', 'PEAK_PRESSURE_MAX_PA',
           'INERTIA_SAMPLES_MIN', 'TableData', 'read_table_csv', 'read_table_yaml',
           'engine_from_table', 'write_coefficient_table']

DEFAULT_ENGINE = 'engine_d13'
"""Engine YAML a table refers to when it names none."""

TABLE_SPEED_RANGE_RPM = (100.0, 5000.0)
"""Speeds a table may hold [rpm]."""

PEAK_PRESSURE_MAX_PA = BOUNDS['cylinder_pressure'].hi
"""Highest cylinder pressure [Pa] a table's gas part may imply (350 bar: above the 250-300 bar
peak firing pressures of current heavy-duty diesels; the table of bounds,
:data:`dmf_sim.core.bounds.BOUNDS`). A table coefficient's gas part is bounded by
twice the largest gas torque one cylinder can produce at that pressure (|A_n| <= 2 max |P_k|, n >
0), :meth:`~dmf_sim.physics.engine.config.Geometry.max_gas_torque_nm`."""

INERTIA_SAMPLES_MIN = 2880
"""Samples per 720 deg cycle for a table's inertia part (0.25 deg, as the default model)."""

_CSV_HEADERS = (['speed_rpm', 'n', 're', 'im'], ['speed_rpm', 'load', 'n', 're', 'im'])


@dataclass(frozen=True)
class TableData:
    engine_ref: str
    speeds_rpm: np.ndarray
    loads: np.ndarray | None
    coefficients: np.ndarray        # complex (n_speeds, n_loads or 1, n_orders)


def _validate(where: str, speeds: np.ndarray, loads: np.ndarray | None, orders: np.ndarray,
              coeffs: np.ndarray, *, yaml_fields: bool = False) -> None:
    f_speed, f_load, f_n = (('speeds_rpm', 'loads', 'orders') if yaml_fields
                            else ('speed_rpm', 'load', 'n'))
    lo, hi = TABLE_SPEED_RANGE_RPM
    if speeds.size < 2:
        raise field_error(where, f_speed, f'need at least 2 speeds in [{lo:g}, {hi:g}] rpm')
    if not np.all(np.isfinite(speeds)) or speeds.min() < lo or speeds.max() > hi:
        raise field_error(where, f_speed, f'speeds must be in [{lo:g}, {hi:g}] rpm '
                          f'(got {speeds.min():g}..{speeds.max():g})')
    if np.any(np.diff(speeds) <= 0):
        raise field_error(where, f_speed,
                          f'speeds must be strictly increasing within [{lo:g}, {hi:g}] rpm')
    if loads is not None and (loads.size < 2 or not np.all(np.isfinite(loads))
                              or np.any(np.diff(loads) <= 0) or loads[0] != 0.0
                              or loads[-1] != 1.0):
        raise field_error(where, f_load,
                          'loads must be strictly increasing from 0 to 1 (at least 2)')
    n_lo, n_hi = N_MAX_RANGE
    n_max = int(orders.max()) if orders.size else -1
    if not n_lo <= n_max <= n_hi:
        raise field_error(where, f_n,
                          f'highest order n_max must be in [{n_lo}, {n_hi}] (got {n_max})')
    expected = np.arange(n_max + 1)
    if orders.size != expected.size or np.any(np.sort(orders) != expected):
        missing = sorted(set(expected.tolist()) - set(orders.tolist()))
        raise field_error(where, f_n, f'orders must be 0..{n_max}, each once (missing: {missing})')
    if not np.all(np.isfinite(coeffs.view(float))):
        raise field_error(where, 'coefficients' if yaml_fields else 're/im',
                          'coefficients must be finite (no NaN/inf)')
    scale = max(1.0, float(np.abs(coeffs.view(float)).max()))     # no overflow near 1e308
    if np.any(np.abs(coeffs[..., 0].imag) > 1e-9 * scale):
        raise field_error(where, 'coefficients' if yaml_fields else 'im',
                          'A_0 (n = 0) must be real: im must be 0')


def _csv_rows(path: Path) -> tuple[str, list[str], list[list[str]]]:
    """(engine reference, header, data rows) of a table CSV."""
    where = path.name
    engine_ref = DEFAULT_ENGINE
    rows: list[list[str]] = []
    header: list[str] | None = None
    for line_no, line in enumerate(read_text(path).splitlines(), start=1):
        text = line.strip()
        if not text:
            continue
        if text.startswith('#'):
            key, sep, val = text[1:].partition(':')
            if sep and key.strip() == 'engine':
                engine_ref = val.strip()
            continue
        fields = next(csv.reader([text]))
        if header is None:
            header = [f.strip() for f in fields]
            if header not in _CSV_HEADERS:
                raise field_error(where, 'header', 'must be "speed_rpm,n,re,im" or '
                                  f'"speed_rpm,load,n,re,im" (got {",".join(header)!r})')
            continue
        if len(fields) != len(header):
            raise field_error(where, f'line {line_no}',
                              f'must have {len(header)} fields ({",".join(header)})')
        rows.append(fields)
    if header is None or not rows:
        raise field_error(where, 'header', 'no header/data rows (need speed_rpm,[load,]n,re,im)')
    return engine_ref, header, rows


def read_table_csv(path: Path) -> TableData:
    """A table CSV (format in the module docstring), validated."""
    where = path.name
    engine_ref, header, rows = _csv_rows(path)
    has_load = 'load' in header
    try:
        data = np.array([[float(v) for v in r] for r in rows])
    except ValueError:
        raise field_error(where, 're/im', 'all fields must be numbers') from None
    if not np.all(np.isfinite(data)):
        col = header[int(np.argwhere(~np.isfinite(data))[0, 1])]
        raise field_error(where, col, 'values must be finite (no NaN/inf)')
    sp = data[:, 0]
    if np.any(np.diff(sp) < 0):
        raise field_error(where, 'speed_rpm', 'rows must be in non-decreasing speed order')
    n_col = data[:, 2 if has_load else 1]
    if np.any(n_col != np.round(n_col)):
        raise field_error(where, 'n', 'orders must be integers')
    speeds = np.unique(sp)
    loads = np.unique(data[:, 1]) if has_load else None
    orders = np.unique(n_col).astype(int)
    if np.any(orders < 0):
        raise field_error(where, 'n', f'orders must be in [0, {N_MAX_RANGE[1]}]')
    n_l = loads.size if loads is not None else 1
    expected_rows = speeds.size * n_l * orders.size
    coeffs = np.full((speeds.size, n_l, orders.size), np.nan + 0j)
    i_s = np.searchsorted(speeds, sp)
    i_l = np.searchsorted(loads, data[:, 1]) if loads is not None else np.zeros(len(sp), int)
    i_n = np.searchsorted(orders, n_col)
    if len(set(zip(i_s.tolist(), i_l.tolist(), i_n.tolist(), strict=True))) != len(rows):
        raise field_error(where, 'n', 'duplicate speed/load/order rows')
    if len(rows) != expected_rows:
        what = 'speed/load' if has_load else 'speed'
        raise field_error(where, 'n', f'incomplete table: every {what} needs orders '
                          f'0..{orders.max()} ({len(rows)} rows, expected {expected_rows})')
    coeffs[i_s, i_l, i_n] = data[:, -2] + 1j * data[:, -1]
    _validate(where, speeds, loads, orders, coeffs)
    return TableData(engine_ref, speeds, loads, coeffs)


def read_table_yaml(path: Path, doc: Mapping[str, Any]) -> TableData:
    """A table YAML mapping (read from ``path``), validated."""
    where = path.name
    d = check_keys(doc, where, '', ['speeds_rpm', 'orders', 'coefficients'],
                   ['engine', 'loads', 'description'])
    lo, hi = TABLE_SPEED_RANGE_RPM
    speeds = number_list(d['speeds_rpm'], where, 'speeds_rpm', lo, hi, min_len=2)
    loads = (number_list(d['loads'], where, 'loads', 0.0, 1.0, min_len=2)
             if d.get('loads') is not None else None)
    orders_raw = d['orders']
    n_range = list(N_MAX_RANGE)
    if not isinstance(orders_raw, list) or not all(isinstance(o, int) and not isinstance(o, bool)
                                                   for o in orders_raw):
        raise field_error(where, 'orders',
                          f'must be the list of integers 0..n_max (n_max in {n_range})')
    orders = np.array(orders_raw, dtype=int)
    if orders.size and np.any(orders != np.arange(orders.size)):
        raise field_error(where, 'orders',
                          f'must be 0, 1, ..., n_max in order (n_max in {n_range})')
    n_l = loads.size if loads is not None else None
    expected = (speeds.size,) + ((n_l,) if n_l else ()) + (orders.size, 2)
    try:
        arr = np.array(d['coefficients'], dtype=float)
    except (ValueError, TypeError):
        raise field_error(where, 'coefficients',
                          f'must be nested lists of [re, im] of shape {expected}') from None
    if arr.shape != expected:
        raise field_error(where, 'coefficients', f'must have shape {expected} '
                          '([speed][load][order][re, im], no load level without loads) '
                          f'(got {arr.shape})')
    if not np.all(np.isfinite(arr)):
        raise field_error(where, 'coefficients', 'values must be finite (no NaN/inf)')
    coeffs = (arr[..., 0] + 1j * arr[..., 1]).reshape(speeds.size, n_l or 1, orders.size)
    _validate(where, speeds, loads, orders, coeffs, yaml_fields=True)
    engine_ref = d.get('engine') or DEFAULT_ENGINE
    if not isinstance(engine_ref, str):
        raise field_error(where, 'engine', 'must be an engine YAML name or path')
    return TableData(engine_ref, speeds, loads, coeffs)


def _check_gas_bound(where: str, table: TableData, gas: np.ndarray, torque_max_nm: float) -> None:
    """Refuse gas parts no engine of this geometry produces (:data:`PEAK_PRESSURE_MAX_PA`)."""
    with np.errstate(over='ignore'):
        size = np.maximum(np.abs(gas.real), np.abs(gas.imag))          # no overflow warnings
        size = np.where(size <= 2.0 * torque_max_nm, np.abs(gas), size)
    bound = np.full(gas.shape[-1], 2.0 * torque_max_nm)
    bound[0] = torque_max_nm                                           # the mean: |A_0| <= max |P|
    bad = np.argwhere(~(size <= bound))
    if bad.size:
        i_s, i_l, n = bad[0]
        load = '' if table.loads is None else f', load {table.loads[i_l]:g}'
        raise field_error(where, 'coefficients',
                          f'A_{n} at {table.speeds_rpm[i_s]:g} rpm{load}: its gas part (inertia '
                          f'part excluded) must be <= {bound[n]:.4g} Nm in magnitude, what one '
                          f'cylinder of this geometry produces at {PEAK_PRESSURE_MAX_PA / 1e5:g} '
                          'bar', float(size[i_s, i_l, n]))


def engine_from_table(path: Path, table: TableData, load_set: str) -> Engine:
    """The Engine of a table: gas part = table - inertia part of the referenced geometry."""
    try:
        engine_yaml = resolve_ref(table.engine_ref, path)
    except ConfigFileError:
        raise field_error(path.name, 'engine', f'engine YAML {table.engine_ref!r} not found '
                          '(a config name like engine_d13 or a path)') from None
    cfg = read_engine_config(engine_yaml, need_model=False)
    n_max = table.coefficients.shape[-1] - 1
    c = cfg.geometry.inertia_coefficients(n_max, max(INERTIA_SAMPLES_MIN, 8 * (n_max + 1)))
    omega2 = (table.speeds_rpm * RPM_TO_RAD_S) ** 2
    gas = table.coefficients - omega2[:, None, None] * c[None, None, :]
    _check_gas_bound(path.name, table, gas, cfg.geometry.max_gas_torque_nm(PEAK_PRESSURE_MAX_PA))
    if table.loads is None:   # full-load data: gas part scales with the load fraction
        loads = np.array([0.0, 1.0])
        gas = np.concatenate((np.zeros_like(gas), gas), axis=1)
    else:
        loads = table.loads
    grid = GasGrid(table.speeds_rpm, loads, n_max + 1, values=gas)
    return Engine(cfg, grid, c, load_set=load_set, n_max=n_max, source=path)


def write_coefficient_table(engine: EngineExcitation, path: str | Path,
                            speeds_rpm: Sequence[float], loads: Sequence[float] | None = None, *,
                            engine_ref: str = DEFAULT_ENGINE, comment: str = '') -> Path:
    """Write per-cylinder A_n of ``engine`` as a table CSV (format in the module docstring).

    Without ``loads`` the table holds full-load data (header ``speed_rpm,n,re,im``).
    """
    rows = []
    for s in speeds_rpm:
        for ld in (loads if loads is not None else [1.0]):
            A = engine.coefficients(s, ld)
            A = np.where(np.abs(A) < 1e-9 * max(1.0, float(np.abs(A).max())), 0.0, A)  # round-off
            for n, a in enumerate(A):
                im = 0.0 if n == 0 else a.imag
                rows.append([s, ld, n, a.real, im] if loads is not None else [s, n, a.real, im])
    return write_csv(path, _CSV_HEADERS[1] if loads is not None else _CSV_HEADERS[0], rows,
                     comments=[*comment.splitlines(), f'engine: {engine_ref}'])
