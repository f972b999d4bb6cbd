"""Engine excitation: cylinder torque coefficients A_n (pressure model or user table), Load A/B/C.

Convention (paper eq. 16-17, docs/ARCHITECTURE.md)
-------------------------------------------------
The torque [Nm] one cylinder k applies to its crank throw is the half-order series::

    P_k(psi) = Re( sum_{n=0}^{n_max} A_n exp(i n/2 (psi - beta_k)) )          (eq. 16-17)

``psi`` is the crank angle [rad] (``psi = 0`` at cylinder 1 firing top dead centre), ``beta_k`` the
firing phase of cylinder k (0, 480, 240, 600, 120, 360 deg for firing order 1-5-3-6-2-4) and
``n`` the half-order index (n = 6 is the 3rd engine order). All cylinders share the same complex
``A_n`` (Nm); ``A_0`` is real and is the mean torque of one cylinder, so the whole engine delivers
``n_cylinders * A_0``. :meth:`Engine.coefficients` returns ``A_0..A_{n_max}`` for an engine speed
[rpm] and a load fraction in [0, 1].

Every ``A_n`` is the sum of two parts:

* **inertia part** of the oscillating mass m (piston, pin, rings, share of the rod),
  ``T_i = -m omega^2 (d2x/dpsi2)(dx/dpsi)``, computed exactly from the slider-crank geometry at the
  *actual* speed; it does not depend on load and its mean is zero;
* **gas part** ``T_g = (p - p_crankcase) A_p dx/dpsi`` from the cylinder pressure p. The load
  fraction acts on this part only (``load = 0`` keeps the motored compression/expansion torque).

Default model (``config/engine_d13.yaml``)
------------------------------------------
13-litre inline six (Volvo D13 data, sources in the YAML). One 720 deg cycle is sampled finely
(``samples_per_cycle``, 0.25 deg by default) in the cylinder's own angle ``theta`` (0 = firing TDC):

* closed cycle IVC..EVO with a constant polytropic exponent gamma and a double Wiebe burn fraction
  ``x_b`` (premixed + diffusion, Ghojel 2010). With constant gamma,
  ``d(p V^gamma)/dtheta = (gamma - 1) V^(gamma - 1) dQ/dtheta`` integrates to::

      p = V^-gamma [ p_ivc V_ivc^gamma + (gamma - 1) Q_tot * int_{ivc}^{theta} V^(gamma-1) dx_b ]

  so the pressure, the torque and every ``A_n`` are affine in the total heat release ``Q_tot``;
* blowdown from the EVO pressure to the exhaust back pressure (cosine ramp), exhaust stroke at
  the exhaust pressure, intake stroke at the boost pressure (cosine blend over the valve overlap);
* intake pressure ``p_amb + load * boost_gauge(speed)``; exhaust pressure above it by a
  load-dependent back pressure; Wiebe start/durations depend on speed and load (YAML tables);
* ``Q_tot`` is solved exactly so that the mean torque equals ``load * full_load_curve(speed) /
  n_cylinders`` per cylinder. **Friction is not modelled**: the mean indicated torque equals the
  configured (brake) full-load curve times the load fraction.

``A_n`` come from ``numpy.fft.rfft`` of the sampled cycle. The gas part is cached on a speed/load
grid (YAML ``grid``), computed lazily cell by cell (or all at once with :meth:`Engine.warm`) and
interpolated linearly (complex bilinear) in between; the inertia part is exact at any speed.

Load sets A, B, C (paper, "Load A, B and C")
--------------------------------------------
B and C shift Load A's cylinder-pressure data for speeds at and below ``limit_rpm`` (1000 rpm)
down by ``shift_rpm`` (50 and 100 rpm): the gas part at speed s uses Load A's gas part at the
effective speed ``min(s + shift, max(s, limit))``; the inertia part always uses s. The set
definitions live in the engine YAML (``load_sets``). :meth:`Engine.full_load_torque` reports the
curve as the load set sees it, i.e. at the effective speed.

User tables (replace the default model, no code change)
-------------------------------------------------------
A table of complex per-cylinder ``A_n`` [Nm] over speed [rpm] and optionally load fraction:

* **CSV**: lines starting with ``#`` are comments; an optional comment ``# engine: <name|path>``
  names the engine YAML that supplies geometry (inertia part), firing phases and load sets
  (default ``engine_d13``; relative paths are relative to the table). Header
  ``speed_rpm,n,re,im`` or ``speed_rpm,load,n,re,im``, then one row per speed/(load)/order, rows in
  non-decreasing speed order, every combination exactly once.
* **YAML**::

      engine: engine_d13          # optional, as for CSV
      speeds_rpm: [600, 800, ...] # strictly increasing
      loads: [0, 0.5, 1]          # optional; strictly increasing from 0 to 1
      orders: [0, 1, ..., 24]     # must be 0..n_max, consecutive
      coefficients: ...           # [speed][load][order] -> [re, im]  ([speed][order] without loads)

Rules: orders 0..n_max all present (1 <= n_max <= 48), at least two speeds within [100, 5000] rpm,
finite values, ``im(A_0) = 0``. The table's own (whole-engine) mean ``n_cylinders * A_0`` defines
the full-load curve. Inside the table the gas part is ``table - inertia(geometry)`` and is
interpolated linearly in speed and load; the exact inertia part is added back at the actual speed.
A table **without a load axis is full-load data**: the gas part (table minus inertia) is scaled by
the load fraction, so at load 0 only the inertia torque is left (the table carries no information
on the motored gas torque). Queries outside the table's speed range raise ``ValueError``.

Every invalid YAML/table is refused with a one-line ``ValueError`` naming the field and the
allowed range. :func:`write_coefficient_table` writes the CSV format
(``config/engine_table_example.csv`` was generated with it from the default model).
"""
from __future__ import annotations

import bisect
import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np
import yaml

from dmf_sim.errors import ConfigError, OperatingRangeError
from dmf_sim.paths import config_file

__all__ = [
    'LOAD_SETS', 'DEFAULT_ENGINE', 'EngineExcitation', 'Engine', 'EngineConfig', 'Geometry',
    'PressureModel', 'CycleResult', 'load_engine', 'read_engine_config', 'cylinder_torque_signal',
    'engine_torque_orders', 'write_coefficient_table',
]

LOAD_SETS: tuple[str, ...] = ('A', 'B', 'C')
"""Load-set names of the paper; their shifts and limit speed live in the engine YAML."""

DEFAULT_ENGINE = 'engine_d13'

# Sanity limits for validation (allowed ranges quoted in error messages).
_TABLE_SPEED_RANGE_RPM = (100.0, 5000.0)
_N_MAX_RANGE = (1, 48)


# ----------------------------------------------------------------------------------------------
# Public protocol and free functions
# ----------------------------------------------------------------------------------------------
@runtime_checkable
class EngineExcitation(Protocol):
    """What the load assembly needs from an engine (default model or user table)."""

    n_cylinders: int
    n_max: int                       # highest half-order index (24)
    firing_phases_deg: np.ndarray    # beta_k [deg]

    def coefficients(self, speed_rpm: float, load: float) -> np.ndarray:
        """Complex A_0..A_{n_max} of one cylinder [Nm] (eq. 16-17)."""
        ...

    def mean_torque(self, speed_rpm: float, load: float) -> float:
        """Whole-engine mean torque [Nm]."""
        ...

    def full_load_torque(self, speed_rpm: float) -> float:
        """Whole-engine full-load mean torque [Nm] as the load set sees it."""
        ...


def cylinder_torque_signal(A: np.ndarray, psi: np.ndarray, beta_rad: float) -> np.ndarray:
    """Time signal of one cylinder torque [Nm] at crank angles ``psi`` [rad].

    ``P_k(psi) = Re(sum_n A_n exp(i n/2 (psi - beta_k)))`` (eq. 16 for beta = 0, eq. 17 in general).
    Returns an array of the shape of ``psi``.
    """
    A = np.asarray(A, dtype=complex)
    psi = np.asarray(psi, dtype=float)
    half_orders = 0.5 * np.arange(A.size)
    phase = np.exp(1j * np.multiply.outer(psi - beta_rad, half_orders))  # eq. 17
    return (phase @ A).real


def engine_torque_orders(engine: EngineExcitation, speed_rpm: float, load: float) -> np.ndarray:
    """Complex half-order coefficients [Nm] of the sum over all cylinders on a rigid crank.

    ``sum_k P_k = Re(sum_n B_n exp(i n/2 psi))`` with ``B_n = A_n sum_k exp(-i n/2 beta_k)``
    (eq. 17 summed over k). Returns ``B_0..B_{n_max}``.
    """
    A = engine.coefficients(speed_rpm, load)
    n = np.arange(A.size)
    beta = np.radians(np.asarray(engine.firing_phases_deg, dtype=float))
    return A * np.exp(-0.5j * np.outer(n, beta)).sum(axis=1)


# ----------------------------------------------------------------------------------------------
# Validation helpers (one-line ValueError naming the field and the allowed range)
# ----------------------------------------------------------------------------------------------
def _err(where: str, field: str, msg: str) -> ConfigError:
    return ConfigError(f'{where}: {field}: {msg}'.replace('\n', ' '))


def _check_keys(d: Any, where: str, field: str, required: Sequence[str],
                optional: Sequence[str] = ()) -> Mapping[str, Any]:
    if not isinstance(d, Mapping):
        raise _err(where, field or 'document', 'must be a mapping')
    prefix = field + '.' if field else ''
    for key in required:
        if key not in d:
            raise _err(where, prefix + key, 'missing (required key)')
    allowed = set(required) | set(optional)
    for key in d:
        if key not in allowed:
            raise _err(where, prefix + str(key),
                       f'unknown key (allowed: {", ".join(sorted(allowed))})')
    return d


def _number(value: Any, where: str, field: str, lo: float, hi: float, *,
            lo_open: bool = False, hi_open: bool = False) -> float:
    lo_b, hi_b = '(' if lo_open else '[', ')' if hi_open else ']'
    rng = f'{lo_b}{lo:g}, {hi:g}{hi_b}'
    if isinstance(value, str):  # PyYAML (YAML 1.1) reads 1.0e5 without a sign as a string
        try:
            value = float(value)
        except ValueError:
            pass
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _err(where, field, f'must be a number in {rng} (got {value!r})')
    x = float(value)
    if not math.isfinite(x) or x < lo or x > hi or (lo_open and x == lo) or (hi_open and x == hi):
        raise _err(where, field, f'must be in {rng} (got {value!r})')
    return x


def _integer(value: Any, where: str, field: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise _err(where, field, f'must be an integer in [{lo}, {hi}] (got {value!r})')
    return int(value)


def _number_list(value: Any, where: str, field: str, lo: float, hi: float, *,
                 min_len: int = 1, increasing: bool = False) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or len(value) < min_len:
        raise _err(where, field, f'must be a list of at least {min_len} numbers in [{lo:g}, {hi:g}]')
    arr = np.array([_number(v, where, f'{field}[{i}]', lo, hi) for i, v in enumerate(value)])
    if increasing and np.any(np.diff(arr) <= 0):
        raise _err(where, field, f'must be strictly increasing within [{lo:g}, {hi:g}]')
    return arr


@dataclass(frozen=True)
class _Table1D:
    """Piecewise-linear table y(x), held constant outside its points."""

    x: np.ndarray
    y: np.ndarray

    def __call__(self, x: float) -> float:
        return float(np.interp(x, self.x, self.y))


def _table_1d(d: Any, where: str, field: str, x_key: str, y_key: str,
              x_range: tuple[float, float], y_range: tuple[float, float]) -> _Table1D:
    _check_keys(d, where, field, [x_key, y_key])
    x = _number_list(d[x_key], where, f'{field}.{x_key}', *x_range, min_len=1, increasing=True)
    y = _number_list(d[y_key], where, f'{field}.{y_key}', *y_range, min_len=1)
    if len(x) != len(y):
        raise _err(where, f'{field}.{y_key}', f'must have as many entries as {x_key} ({len(x)})')
    return _Table1D(x, y)


# ----------------------------------------------------------------------------------------------
# Engine YAML
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Geometry:
    """Slider-crank geometry and oscillating mass of one cylinder (SI units)."""

    bore_m: float
    stroke_m: float
    conrod_m: float
    compression_ratio: float
    oscillating_mass_kg: float

    @property
    def crank_radius_m(self) -> float:
        return 0.5 * self.stroke_m

    @property
    def piston_area_m2(self) -> float:
        return 0.25 * math.pi * self.bore_m ** 2

    @property
    def displacement_m3(self) -> float:
        """Swept volume of one cylinder [m^3]."""
        return self.piston_area_m2 * self.stroke_m

    @property
    def clearance_volume_m3(self) -> float:
        return self.displacement_m3 / (self.compression_ratio - 1.0)

    def kinematics(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Piston travel from TDC x [m], dx/dtheta [m/rad], d2x/dtheta2 [m/rad^2] at crank angle theta [rad]."""
        r, lam = self.crank_radius_m, self.crank_radius_m / self.conrod_m
        s, c = np.sin(theta), np.cos(theta)
        root = np.sqrt(1.0 - (lam * s) ** 2)
        x = r * (1.0 - c) + self.conrod_m * (1.0 - root)
        dx = r * s * (1.0 + lam * c / root)
        d2x = r * c + r * lam * (np.cos(2.0 * theta) + lam ** 2 * s ** 4) / root ** 3
        return x, dx, d2x


@dataclass(frozen=True)
class _GasExchange:
    ambient_pa: float
    crankcase_pa: float
    ivc_deg: float
    evo_deg: float
    blowdown_deg: float
    overlap_deg: float
    boost_gauge_full_load: _Table1D          # Pa over rpm
    exhaust_backpressure_zero_load_pa: float
    exhaust_backpressure_full_load_pa: float


@dataclass(frozen=True)
class _Combustion:
    polytropic_exponent: float
    wiebe_a: float
    start_deg: _Table1D                      # deg over rpm
    premixed_fraction_zero_load: float
    premixed_fraction_full_load: float
    premixed_duration_deg: float
    premixed_shape: float
    diffusion_duration_full_load_deg: _Table1D  # deg over rpm
    diffusion_duration_zero_load_factor: float
    diffusion_shape: float


@dataclass(frozen=True)
class _Grid:
    speeds_rpm: np.ndarray
    loads: np.ndarray


@dataclass(frozen=True)
class EngineConfig:
    """Validated engine YAML. Model sections are None when the YAML only backs a table."""

    path: Path
    name: str
    n_cylinders: int
    firing_phases_deg: np.ndarray
    n_max: int
    geometry: Geometry
    load_set_shifts_rpm: dict[str, float]
    load_set_limit_rpm: float
    full_load_curve: _Table1D | None = None
    gas_exchange: _GasExchange | None = None
    combustion: _Combustion | None = None
    samples_per_cycle: int | None = None
    grid: _Grid | None = None

    @property
    def has_model(self) -> bool:
        return self.full_load_curve is not None


_MODEL_KEYS = ('full_load_curve', 'gas_exchange', 'combustion', 'samples_per_cycle', 'grid')


def read_engine_config(path: str | Path, *, need_model: bool = True) -> EngineConfig:
    """Read and validate an engine YAML (see ``config/engine_d13.yaml``).

    With ``need_model=False`` the pressure-model sections may be absent (a YAML that only supplies
    geometry, firing phases and load sets for a user table).
    """
    path = Path(path)
    where = path.name
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f'{where}: not valid YAML ({str(exc).splitlines()[0]})') from None
    required = ['name', 'n_cylinders', 'firing_phases_deg', 'n_max', 'geometry', 'load_sets']
    d = _check_keys(doc, where, '', required + (list(_MODEL_KEYS) if need_model else []),
                    ['description'] + ([] if need_model else list(_MODEL_KEYS)))
    if not isinstance(d['name'], str) or not d['name']:
        raise _err(where, 'name', 'must be a non-empty string')
    n_cyl = _integer(d['n_cylinders'], where, 'n_cylinders', 1, 24)
    phases = _number_list(d['firing_phases_deg'], where, 'firing_phases_deg', 0.0, 720.0)
    if len(phases) != n_cyl:
        raise _err(where, 'firing_phases_deg', f'must have n_cylinders = {n_cyl} entries in [0, 720)')
    if np.any(phases >= 720.0):
        raise _err(where, 'firing_phases_deg', 'entries must be in [0, 720)')
    n_max = _integer(d['n_max'], where, 'n_max', *_N_MAX_RANGE)

    g = _check_keys(d['geometry'], where, 'geometry',
                    ['bore_m', 'stroke_m', 'conrod_m', 'compression_ratio', 'oscillating_mass_kg'])
    geometry = Geometry(
        bore_m=_number(g['bore_m'], where, 'geometry.bore_m', 0.0, 2.0, lo_open=True),
        stroke_m=_number(g['stroke_m'], where, 'geometry.stroke_m', 0.0, 3.0, lo_open=True),
        conrod_m=_number(g['conrod_m'], where, 'geometry.conrod_m', 0.0, 10.0, lo_open=True),
        compression_ratio=_number(g['compression_ratio'], where, 'geometry.compression_ratio',
                                  1.0, 40.0, lo_open=True),
        oscillating_mass_kg=_number(g['oscillating_mass_kg'], where,
                                    'geometry.oscillating_mass_kg', 0.0, 5000.0),
    )
    if geometry.conrod_m <= geometry.crank_radius_m:
        raise _err(where, 'geometry.conrod_m',
                   f'must exceed the crank radius stroke_m/2 = {geometry.crank_radius_m:g} m')

    ls = _check_keys(d['load_sets'], where, 'load_sets', ['limit_rpm', 'shift_rpm'])
    limit = _number(ls['limit_rpm'], where, 'load_sets.limit_rpm', 0.0, 10000.0, lo_open=True)
    shifts_raw = ls['shift_rpm']
    if not isinstance(shifts_raw, Mapping) or 'A' not in shifts_raw:
        raise _err(where, 'load_sets.shift_rpm', 'must be a mapping of set names to shifts, including A: 0')
    shifts = {str(k): _number(v, where, f'load_sets.shift_rpm.{k}', 0.0, limit, hi_open=True)
              for k, v in shifts_raw.items()}
    if shifts['A'] != 0.0:
        raise _err(where, 'load_sets.shift_rpm.A', 'must be 0 (Load A is the reference data)')

    cfg: dict[str, Any] = dict(
        path=path, name=d['name'], n_cylinders=n_cyl, firing_phases_deg=phases, n_max=n_max,
        geometry=geometry, load_set_shifts_rpm=shifts, load_set_limit_rpm=limit)
    if all(k in d for k in _MODEL_KEYS):
        cfg.update(_read_model_sections(d, where, n_max))
    elif any(k in d for k in _MODEL_KEYS):
        missing = next(k for k in _MODEL_KEYS if k not in d)
        raise _err(where, missing, 'missing (required when any pressure-model section is given)')
    return EngineConfig(**cfg)


def _read_model_sections(d: Mapping[str, Any], where: str, n_max: int) -> dict[str, Any]:
    speed_range = (0.0, 10000.0)
    curve = _table_1d(d['full_load_curve'], where, 'full_load_curve', 'speeds_rpm', 'torque_nm',
                      speed_range, (0.0, 1.0e6))

    ge = _check_keys(d['gas_exchange'], where, 'gas_exchange',
                     ['ambient_pa', 'crankcase_pa', 'ivc_deg', 'evo_deg', 'blowdown_deg',
                      'overlap_deg', 'boost_gauge_full_load', 'exhaust_backpressure_zero_load_pa',
                      'exhaust_backpressure_full_load_pa'])
    f = 'gas_exchange.'
    gas = _GasExchange(
        ambient_pa=_number(ge['ambient_pa'], where, f + 'ambient_pa', 1.0e4, 2.0e5),
        crankcase_pa=_number(ge['crankcase_pa'], where, f + 'crankcase_pa', 1.0e4, 2.0e5),
        ivc_deg=_number(ge['ivc_deg'], where, f + 'ivc_deg', -240.0, -90.0),
        evo_deg=_number(ge['evo_deg'], where, f + 'evo_deg', 90.0, 200.0),
        blowdown_deg=_number(ge['blowdown_deg'], where, f + 'blowdown_deg', 1.0, 120.0),
        overlap_deg=_number(ge['overlap_deg'], where, f + 'overlap_deg', 1.0, 120.0),
        boost_gauge_full_load=_table_1d(ge['boost_gauge_full_load'], where,
                                        f + 'boost_gauge_full_load', 'speeds_rpm', 'pressure_pa',
                                        speed_range, (0.0, 1.0e6)),
        exhaust_backpressure_zero_load_pa=_number(ge['exhaust_backpressure_zero_load_pa'], where,
                                                  f + 'exhaust_backpressure_zero_load_pa', 0.0, 5.0e5),
        exhaust_backpressure_full_load_pa=_number(ge['exhaust_backpressure_full_load_pa'], where,
                                                  f + 'exhaust_backpressure_full_load_pa', 0.0, 5.0e5),
    )
    if gas.evo_deg + gas.blowdown_deg > 360.0 - 0.5 * gas.overlap_deg:
        raise _err(where, f + 'blowdown_deg',
                   'evo_deg + blowdown_deg must not exceed 360 - overlap_deg/2 (blowdown ends before the overlap)')
    if gas.ivc_deg < -360.0 + 0.5 * gas.overlap_deg:
        raise _err(where, f + 'ivc_deg', 'must be later than -360 + overlap_deg/2')

    cb = _check_keys(d['combustion'], where, 'combustion',
                     ['polytropic_exponent', 'wiebe_a', 'start_deg', 'premixed_fraction_zero_load',
                      'premixed_fraction_full_load', 'premixed_duration_deg', 'premixed_shape',
                      'diffusion_duration_full_load_deg', 'diffusion_duration_zero_load_factor',
                      'diffusion_shape'])
    f = 'combustion.'
    comb = _Combustion(
        polytropic_exponent=_number(cb['polytropic_exponent'], where, f + 'polytropic_exponent',
                                    1.0, 1.67, lo_open=True),
        wiebe_a=_number(cb['wiebe_a'], where, f + 'wiebe_a', 0.0, 20.0, lo_open=True),
        start_deg=_table_1d(cb['start_deg'], where, f + 'start_deg', 'speeds_rpm', 'angle_deg',
                            speed_range, (-60.0, 30.0)),
        premixed_fraction_zero_load=_number(cb['premixed_fraction_zero_load'], where,
                                            f + 'premixed_fraction_zero_load', 0.0, 1.0),
        premixed_fraction_full_load=_number(cb['premixed_fraction_full_load'], where,
                                            f + 'premixed_fraction_full_load', 0.0, 1.0),
        premixed_duration_deg=_number(cb['premixed_duration_deg'], where,
                                      f + 'premixed_duration_deg', 0.0, 90.0, lo_open=True),
        premixed_shape=_number(cb['premixed_shape'], where, f + 'premixed_shape', 0.0, 10.0),
        diffusion_duration_full_load_deg=_table_1d(
            cb['diffusion_duration_full_load_deg'], where, f + 'diffusion_duration_full_load_deg',
            'speeds_rpm', 'duration_deg', speed_range, (1.0, 180.0)),
        diffusion_duration_zero_load_factor=_number(
            cb['diffusion_duration_zero_load_factor'], where,
            f + 'diffusion_duration_zero_load_factor', 0.0, 1.0, lo_open=True),
        diffusion_shape=_number(cb['diffusion_shape'], where, f + 'diffusion_shape', 0.0, 10.0),
    )

    samples = _integer(d['samples_per_cycle'], where, 'samples_per_cycle', 720, 100000)
    if samples % 2 or samples <= 4 * (n_max + 1):
        raise _err(where, 'samples_per_cycle', f'must be even and > 4*(n_max+1) = {4 * (n_max + 1)}')

    gr = _check_keys(d['grid'], where, 'grid', ['speed_min_rpm', 'speed_max_rpm', 'speed_step_rpm', 'loads'])
    s0 = _number(gr['speed_min_rpm'], where, 'grid.speed_min_rpm', 50.0, 10000.0)
    s1 = _number(gr['speed_max_rpm'], where, 'grid.speed_max_rpm', s0, 10000.0, lo_open=True)
    ds = _number(gr['speed_step_rpm'], where, 'grid.speed_step_rpm', 0.0, s1 - s0, lo_open=True)
    n_steps = round((s1 - s0) / ds)
    if abs(n_steps * ds - (s1 - s0)) > 1e-6 * ds:
        raise _err(where, 'grid.speed_step_rpm', f'must divide speed_max_rpm - speed_min_rpm = {s1 - s0:g}')
    loads = _number_list(gr['loads'], where, 'grid.loads', 0.0, 1.0, min_len=2, increasing=True)
    if loads[0] != 0.0 or loads[-1] != 1.0:
        raise _err(where, 'grid.loads', 'must start at 0 and end at 1 (strictly increasing)')
    grid = _Grid(np.linspace(s0, s1, n_steps + 1), loads)
    return dict(full_load_curve=curve, gas_exchange=gas, combustion=comb,
                samples_per_cycle=samples, grid=grid)


# ----------------------------------------------------------------------------------------------
# Pressure model of one cylinder
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CycleResult:
    """One 720 deg cycle of one cylinder, sampled at ``psi_deg`` (0 = its firing TDC)."""

    psi_deg: np.ndarray
    pressure_pa: np.ndarray
    gas_torque_nm: np.ndarray
    inertia_torque_nm: np.ndarray
    heat_release_j: float            # total Q of the Wiebe law (the part after EVO is not used)
    intake_pa: float
    exhaust_pa: float

    @property
    def torque_nm(self) -> np.ndarray:
        return self.gas_torque_nm + self.inertia_torque_nm

    @property
    def peak_pressure_pa(self) -> float:
        return float(self.pressure_pa.max())


class PressureModel:
    """Cylinder pressure and crank-throw torque of one cylinder (default engine model)."""

    def __init__(self, cfg: EngineConfig) -> None:
        if not cfg.has_model:
            raise _err(cfg.path.name, 'full_load_curve', 'missing (pressure model sections required)')
        self.cfg = cfg
        n = cfg.samples_per_cycle
        assert n is not None
        # Cylinder angle theta in [-360, 360) deg: one contiguous closed cycle around firing TDC.
        self.theta_deg = -360.0 + 720.0 * np.arange(n) / n
        theta = np.radians(self.theta_deg)
        x, self._dx, self._d2x = cfg.geometry.kinematics(theta)
        self._volume = cfg.geometry.clearance_volume_m3 + cfg.geometry.piston_area_m2 * x
        self._roll = -n // 2   # theta = 0 (psi = 0) is sample n/2
        # Inertia torque per omega^2: -m (d2x/dpsi2)(dx/dpsi)  [Nm s^2]
        self._inertia_shape = -cfg.geometry.oscillating_mass_kg * self._d2x * self._dx
        self.inertia_unit = self._fft(self._inertia_shape)
        gas = cfg.gas_exchange
        assert gas is not None
        th = self.theta_deg
        self._i_ivc = int(np.searchsorted(th, gas.ivc_deg))
        self._i_evo = int(np.searchsorted(th, gas.evo_deg, side='right')) - 1
        self._closed = (np.arange(n) >= self._i_ivc) & (np.arange(n) <= self._i_evo)
        t_evo = th[self._i_evo]
        frac = np.clip((th - t_evo) / gas.blowdown_deg, 0.0, 1.0)
        self._blowdown_w = np.where(th > t_evo, 0.5 * (1.0 + np.cos(np.pi * frac)), 0.0)
        # Exhaust -> intake blend around the gas-exchange TDC (theta = +-360 deg).
        d_ge = np.where(th > 0.0, th - 360.0, th + 360.0)
        w = np.clip(0.5 + d_ge / gas.overlap_deg, 0.0, 1.0)
        self._intake_w = 0.5 - 0.5 * np.cos(np.pi * w)
        self._blowdown_w[self._closed] = 0.0

    # -- helpers -------------------------------------------------------------------------------
    def _fft(self, signal_theta: np.ndarray) -> np.ndarray:
        """Half-order coefficients A_0..A_{n_max} of a cycle sampled on ``theta_deg``."""
        c = np.fft.rfft(np.roll(signal_theta, self._roll))[: self.cfg.n_max + 1] / signal_theta.size
        c[1:] *= 2.0
        c[0] = c[0].real
        return c

    def burn_fraction(self, speed_rpm: float, load: float) -> np.ndarray:
        """Double Wiebe burn fraction x_b(theta) (Ghojel 2010), premixed + diffusion."""
        cb = self.cfg.combustion
        assert cb is not None
        z = np.clip(self.theta_deg - cb.start_deg(speed_rpm), 0.0, None)
        beta = cb.premixed_fraction_zero_load + load * (cb.premixed_fraction_full_load
                                                        - cb.premixed_fraction_zero_load)
        dur_d = cb.diffusion_duration_full_load_deg(speed_rpm) * (
            cb.diffusion_duration_zero_load_factor
            + (1.0 - cb.diffusion_duration_zero_load_factor) * load)
        pre = 1.0 - np.exp(-cb.wiebe_a * (z / cb.premixed_duration_deg) ** (cb.premixed_shape + 1.0))
        dif = 1.0 - np.exp(-cb.wiebe_a * (z / dur_d) ** (cb.diffusion_shape + 1.0))
        return beta * pre + (1.0 - beta) * dif

    def _pressure_parts(self, speed_rpm: float, load: float
                        ) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Pressure as ``p_base + Q_tot * p_unit`` over the cycle, plus intake/exhaust pressure."""
        gas, cb = self.cfg.gas_exchange, self.cfg.combustion
        assert gas is not None and cb is not None
        g = cb.polytropic_exponent
        V = self._volume
        p_int = gas.ambient_pa + load * gas.boost_gauge_full_load(speed_rpm)
        p_exh = p_int + gas.exhaust_backpressure_zero_load_pa + load * (
            gas.exhaust_backpressure_full_load_pa - gas.exhaust_backpressure_zero_load_pa)
        # closed cycle: p V^g = p_ivc V_ivc^g + (g-1) Q int V^(g-1) dx_b
        xb = self.burn_fraction(speed_rpm, load)
        Vg = V ** (g - 1.0)
        dI = 0.5 * (Vg[1:] + Vg[:-1]) * np.diff(xb)
        integral = np.concatenate(([0.0], np.cumsum(dI)))
        integral -= integral[self._i_ivc]
        Vmg = V ** -g
        closed_base = p_int * V[self._i_ivc] ** g * Vmg
        closed_unit = (g - 1.0) * integral * Vmg
        # open cycle: exhaust/intake strokes plus the blowdown ramp from the EVO pressure
        exchange = p_exh + (p_int - p_exh) * self._intake_w
        i_evo = self._i_evo
        wb = self._blowdown_w
        p_base = np.where(self._closed, closed_base,
                          exchange + (closed_base[i_evo] - exchange[i_evo]) * wb)
        p_unit = np.where(self._closed, closed_unit, closed_unit[i_evo] * wb)
        return p_base, p_unit, p_int, p_exh

    # -- public --------------------------------------------------------------------------------
    def target_cylinder_mean(self, speed_rpm: float, load: float) -> float:
        """Mean torque of one cylinder [Nm]: load x full-load curve / n_cylinders (no friction)."""
        assert self.cfg.full_load_curve is not None
        return load * self.cfg.full_load_curve(speed_rpm) / self.cfg.n_cylinders

    def cycle(self, speed_rpm: float, load: float) -> CycleResult:
        """Pressure and torques of one cycle with Q_tot solved for the target mean torque."""
        gas = self.cfg.gas_exchange
        assert gas is not None
        area = self.cfg.geometry.piston_area_m2
        p_base, p_unit, p_int, p_exh = self._pressure_parts(speed_rpm, load)
        t_base = (p_base - gas.crankcase_pa) * area * self._dx     # gas torque, Q_tot = 0
        t_unit = p_unit * area * self._dx                          # per joule of Q_tot
        q = (self.target_cylinder_mean(speed_rpm, load) - t_base.mean()) / t_unit.mean()
        omega = speed_rpm * math.pi / 30.0
        roll = self._roll
        return CycleResult(
            psi_deg=np.roll(self.theta_deg, roll) % 720.0,
            pressure_pa=np.roll(p_base + q * p_unit, roll),
            gas_torque_nm=np.roll(t_base + q * t_unit, roll),
            inertia_torque_nm=np.roll(omega ** 2 * self._inertia_shape, roll),
            heat_release_j=float(q), intake_pa=p_int, exhaust_pa=p_exh)

    def gas_coefficients(self, speed_rpm: float, load: float) -> np.ndarray:
        """Gas-torque A_n of one cylinder [Nm] by FFT of one cycle (exact, no cache)."""
        res = self.cycle(speed_rpm, load)
        c = np.fft.rfft(res.gas_torque_nm)[: self.cfg.n_max + 1] / res.gas_torque_nm.size
        c[1:] *= 2.0
        c[0] = c[0].real
        return c

    def inertia_coefficients(self, speed_rpm: float) -> np.ndarray:
        """Inertia-torque A_n of one cylinder [Nm]: omega^2 times the unit-speed shape."""
        omega = speed_rpm * math.pi / 30.0
        return omega ** 2 * self.inertia_unit

    def truncation_error(self, speed_rpm: float, load: float) -> float:
        """Relative rms error of one cylinder's torque when the series stops at n_max.

        ``rms(P - P_trunc) / rms(P)`` over the finely sampled cycle (P = gas + inertia torque).
        """
        res = self.cycle(speed_rpm, load)
        c = np.fft.rfft(res.torque_nm)
        c[self.cfg.n_max + 1:] = 0.0
        residual = res.torque_nm - np.fft.irfft(c, res.torque_nm.size)
        return float(np.sqrt(np.mean(residual ** 2) / np.mean(res.torque_nm ** 2)))


# ----------------------------------------------------------------------------------------------
# Gas-part grid (lazy cache for the model, filled for tables) and the engine object
# ----------------------------------------------------------------------------------------------
class _GasGrid:
    """Gas-part A_n on a speed x load grid, bilinear complex interpolation, lazy filling."""

    def __init__(self, speeds_rpm: np.ndarray, loads: np.ndarray, n_orders: int,
                 filler: Callable[[float, float], np.ndarray] | None = None,
                 values: np.ndarray | None = None) -> None:
        self.speeds = np.asarray(speeds_rpm, dtype=float)
        self.loads = np.asarray(loads, dtype=float)
        self._speeds_list = self.speeds.tolist()
        self._loads_list = self.loads.tolist()
        shape = (self.speeds.size, self.loads.size, n_orders)
        if values is None:
            self.values = np.zeros(shape, dtype=complex)
            self.done = np.zeros(shape[:2], dtype=bool)
        else:
            self.values = np.asarray(values, dtype=complex).reshape(shape)
            self.done = np.ones(shape[:2], dtype=bool)
        self._filler = filler

    @property
    def speed_range(self) -> tuple[float, float]:
        return float(self.speeds[0]), float(self.speeds[-1])

    def _node(self, i: int, j: int) -> np.ndarray:
        if not self.done[i, j]:
            assert self._filler is not None
            self.values[i, j] = self._filler(self._speeds_list[i], self._loads_list[j])
            self.done[i, j] = True
        return self.values[i, j]

    def fill_all(self) -> None:
        for i in range(self.speeds.size):
            for j in range(self.loads.size):
                self._node(i, j)

    @staticmethod
    def _bracket(grid: list[float], x: float) -> tuple[int, float]:
        i = min(max(bisect.bisect_right(grid, x) - 1, 0), len(grid) - 2)
        return i, (x - grid[i]) / (grid[i + 1] - grid[i])

    def __call__(self, speed_rpm: float, load: float) -> np.ndarray:
        i, ts = self._bracket(self._speeds_list, speed_rpm)
        j, tl = self._bracket(self._loads_list, load)
        a = self._node(i, j) * (1.0 - tl) + self._node(i, j + 1) * tl
        b = self._node(i + 1, j) * (1.0 - tl) + self._node(i + 1, j + 1) * tl
        return a * (1.0 - ts) + b * ts


class Engine:
    """Engine excitation (implements :class:`EngineExcitation`) for one load set.

    ``coefficients = gas(effective speed, load) + inertia(actual speed)``.
    """

    def __init__(self, cfg: EngineConfig, gas: _GasGrid, inertia_unit: np.ndarray, *,
                 load_set: str = 'A', n_max: int | None = None,
                 full_load_curve: _Table1D | None = None, model: PressureModel | None = None,
                 source: Path | None = None) -> None:
        if load_set not in cfg.load_set_shifts_rpm:
            raise ConfigError(f'{cfg.path.name}: load_set: unknown {load_set!r} '
                             f'(allowed: {", ".join(cfg.load_set_shifts_rpm)})')
        self.config = cfg
        self.source = source or cfg.path
        self.model = model
        self.n_cylinders: int = cfg.n_cylinders
        self.n_max: int = cfg.n_max if n_max is None else n_max
        self.firing_phases_deg: np.ndarray = np.array(cfg.firing_phases_deg, dtype=float)
        self.load_set = load_set
        self.shift_rpm = cfg.load_set_shifts_rpm[load_set]
        self.limit_rpm = cfg.load_set_limit_rpm
        self._gas = gas
        self._inertia_unit = np.asarray(inertia_unit, dtype=complex)[: self.n_max + 1]
        self._curve = full_load_curve
        self.speed_range_rpm: tuple[float, float] = gas.speed_range

    def with_load_set(self, load_set: str) -> Engine:
        """The same engine (sharing the cached gas data) for another load set."""
        return Engine(self.config, self._gas, self._inertia_unit, load_set=load_set,
                      n_max=self.n_max, full_load_curve=self._curve, model=self.model,
                      source=self.source)

    def warm(self) -> None:
        """Compute every grid node now (about 0.1 s for the default grid)."""
        self._gas.fill_all()

    # -- checks --------------------------------------------------------------------------------
    def _check(self, speed_rpm: float, load: float | None = None) -> None:
        lo, hi = self.speed_range_rpm
        if not (math.isfinite(speed_rpm) and lo <= speed_rpm <= hi):
            raise OperatingRangeError(f'speed_rpm: must be in [{lo:g}, {hi:g}] rpm (got {speed_rpm!r})')
        if load is not None and not (math.isfinite(load) and 0.0 <= load <= 1.0):
            raise OperatingRangeError(f'load: must be in [0, 1] (got {load!r})')

    def effective_speed(self, speed_rpm: float) -> float:
        """Speed [rpm] at which Load A's gas data is used: min(s + shift, max(s, limit))."""
        return min(speed_rpm + self.shift_rpm, max(speed_rpm, self.limit_rpm))

    # -- parts ---------------------------------------------------------------------------------
    def gas_coefficients(self, speed_rpm: float, load: float) -> np.ndarray:
        """Gas-pressure part of A_n [Nm] (Load A data at the effective speed)."""
        speed_rpm, load = float(speed_rpm), float(load)
        self._check(speed_rpm, load)
        s_eff = self.effective_speed(speed_rpm)
        self._check(s_eff)
        return self._gas(s_eff, load)

    def inertia_coefficients(self, speed_rpm: float) -> np.ndarray:
        """Oscillating-mass part of A_n [Nm] at the actual speed (load independent)."""
        speed_rpm = float(speed_rpm)
        self._check(speed_rpm)
        omega = speed_rpm * (math.pi / 30.0)
        return omega * omega * self._inertia_unit

    # -- EngineExcitation ----------------------------------------------------------------------
    def coefficients(self, speed_rpm: float, load: float) -> np.ndarray:
        """Complex per-cylinder A_0..A_{n_max} [Nm] at ``speed_rpm`` [rpm] and ``load`` [0..1]."""
        return self.gas_coefficients(speed_rpm, load) + self.inertia_coefficients(speed_rpm)

    def mean_torque(self, speed_rpm: float, load: float) -> float:
        """Whole-engine mean torque n_cylinders * A_0 [Nm]."""
        return self.n_cylinders * float(self.coefficients(speed_rpm, load)[0].real)

    def full_load_torque(self, speed_rpm: float) -> float:
        """Whole-engine full-load torque [Nm] as this load set sees it (curve at the effective speed)."""
        speed_rpm = float(speed_rpm)
        self._check(speed_rpm)
        s_eff = self.effective_speed(speed_rpm)
        if self._curve is not None:
            return self._curve(s_eff)
        self._check(s_eff)
        return self.n_cylinders * float(self._gas(s_eff, 1.0)[0].real)

    def __repr__(self) -> str:
        return (f'Engine({self.config.name!r}, source={self.source.name!r}, '
                f'load_set={self.load_set!r}, n_max={self.n_max})')


# ----------------------------------------------------------------------------------------------
# Tables
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _TableData:
    engine_ref: str
    speeds_rpm: np.ndarray
    loads: np.ndarray | None
    coefficients: np.ndarray        # complex (n_speeds, n_loads or 1, n_orders)


def _validate_table(where: str, speeds: np.ndarray, loads: np.ndarray | None, orders: np.ndarray,
                    coeffs: np.ndarray, *, yaml_fields: bool = False) -> None:
    f_speed, f_load, f_n = (('speeds_rpm', 'loads', 'orders') if yaml_fields else ('speed_rpm', 'load', 'n'))
    f_im = 'coefficients' if yaml_fields else 'im'
    lo, hi = _TABLE_SPEED_RANGE_RPM
    if speeds.size < 2:
        raise _err(where, f_speed, f'need at least 2 speeds in [{lo:g}, {hi:g}] rpm')
    if not np.all(np.isfinite(speeds)) or speeds.min() < lo or speeds.max() > hi:
        raise _err(where, f_speed, f'speeds must be in [{lo:g}, {hi:g}] rpm '
                   f'(got {speeds.min():g}..{speeds.max():g})')
    if np.any(np.diff(speeds) <= 0):
        raise _err(where, f_speed, f'speeds must be strictly increasing within [{lo:g}, {hi:g}] rpm')
    if loads is not None:
        if (loads.size < 2 or not np.all(np.isfinite(loads)) or np.any(np.diff(loads) <= 0)
                or loads[0] != 0.0 or loads[-1] != 1.0):
            raise _err(where, f_load, 'loads must be strictly increasing from 0 to 1 (at least 2)')
    n_lo, n_hi = _N_MAX_RANGE
    n_max = int(orders.max()) if orders.size else -1
    if not n_lo <= n_max <= n_hi:
        raise _err(where, f_n, f'highest order n_max must be in [{n_lo}, {n_hi}] (got {n_max})')
    expected = np.arange(n_max + 1)
    if orders.size != expected.size or np.any(np.sort(orders) != expected):
        missing = sorted(set(expected.tolist()) - set(orders.tolist()))
        raise _err(where, f_n, f'orders must be 0..{n_max}, each once (missing: {missing})')
    if not np.all(np.isfinite(coeffs.view(float))):
        raise _err(where, 'coefficients' if yaml_fields else 're/im', 'coefficients must be finite (no NaN/inf)')
    scale = max(1.0, float(np.abs(coeffs).max()))
    if np.any(np.abs(coeffs[..., 0].imag) > 1e-9 * scale):
        raise _err(where, f_im, 'A_0 (n = 0) must be real: im must be 0')


def _read_table_csv(path: Path) -> _TableData:
    where = path.name
    engine_ref = DEFAULT_ENGINE
    rows: list[list[str]] = []
    header: list[str] | None = None
    with path.open(newline='') as fh:
        for line_no, line in enumerate(fh, start=1):
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
                if header not in (['speed_rpm', 'n', 're', 'im'], ['speed_rpm', 'load', 'n', 're', 'im']):
                    raise _err(where, 'header', 'must be "speed_rpm,n,re,im" or '
                               f'"speed_rpm,load,n,re,im" (got {",".join(header)!r})')
                continue
            if len(fields) != len(header):
                raise _err(where, f'line {line_no}', f'must have {len(header)} fields ({",".join(header)})')
            rows.append(fields)
    if header is None or not rows:
        raise _err(where, 'header', 'no header/data rows (need speed_rpm,[load,]n,re,im)')
    has_load = 'load' in header
    try:
        data = np.array([[float(v) for v in r] for r in rows])
    except ValueError:
        raise _err(where, 're/im', 'all fields must be numbers') from None
    if not np.all(np.isfinite(data)):
        col = header[int(np.argwhere(~np.isfinite(data))[0, 1])]
        raise _err(where, col, 'values must be finite (no NaN/inf)')
    sp = data[:, 0]
    if np.any(np.diff(sp) < 0):
        raise _err(where, 'speed_rpm', 'rows must be in non-decreasing speed order')
    n_col = data[:, 2 if has_load else 1]
    if np.any(n_col != np.round(n_col)):
        raise _err(where, 'n', 'orders must be integers')
    speeds = np.unique(sp)
    loads = np.unique(data[:, 1]) if has_load else None
    orders = np.unique(n_col).astype(int)
    if np.any(orders < 0):
        raise _err(where, 'n', f'orders must be in [0, {_N_MAX_RANGE[1]}]')
    n_l = loads.size if loads is not None else 1
    expected_rows = speeds.size * n_l * orders.size
    coeffs = np.full((speeds.size, n_l, orders.size), np.nan + 0j)
    i_s = np.searchsorted(speeds, sp)
    i_l = np.searchsorted(loads, data[:, 1]) if loads is not None else np.zeros(len(sp), int)
    i_n = np.searchsorted(orders, n_col)
    if len(set(zip(i_s.tolist(), i_l.tolist(), i_n.tolist()))) != len(rows):
        raise _err(where, 'n', 'duplicate speed/load/order rows')
    if len(rows) != expected_rows:
        raise _err(where, 'n', f'incomplete table: every speed{"/load" if has_load else ""} needs orders '
                   f'0..{orders.max()} ({len(rows)} rows, expected {expected_rows})')
    coeffs[i_s, i_l, i_n] = data[:, -2] + 1j * data[:, -1]
    _validate_table(where, speeds, loads, orders, coeffs)
    return _TableData(engine_ref, speeds, loads, coeffs)


def _read_table_yaml(path: Path, doc: Mapping[str, Any]) -> _TableData:
    where = path.name
    d = _check_keys(doc, where, '', ['speeds_rpm', 'orders', 'coefficients'], ['engine', 'loads', 'description'])
    lo, hi = _TABLE_SPEED_RANGE_RPM
    speeds = _number_list(d['speeds_rpm'], where, 'speeds_rpm', lo, hi, min_len=2)
    loads = (_number_list(d['loads'], where, 'loads', 0.0, 1.0, min_len=2)
             if d.get('loads') is not None else None)
    orders_raw = d['orders']
    if not isinstance(orders_raw, list) or not all(isinstance(o, int) and not isinstance(o, bool)
                                                   for o in orders_raw):
        raise _err(where, 'orders', f'must be the list of integers 0..n_max (n_max in {list(_N_MAX_RANGE)})')
    orders = np.array(orders_raw, dtype=int)
    if orders.size and np.any(orders != np.arange(orders.size)):
        raise _err(where, 'orders', f'must be 0, 1, ..., n_max in order (n_max in {list(_N_MAX_RANGE)})')
    n_l = loads.size if loads is not None else None
    expected = (speeds.size,) + ((n_l,) if n_l else ()) + (orders.size, 2)
    try:
        arr = np.array(d['coefficients'], dtype=float)
    except (ValueError, TypeError):
        raise _err(where, 'coefficients', f'must be nested lists of [re, im] of shape {expected}') from None
    if arr.shape != expected:
        raise _err(where, 'coefficients', f'must have shape {expected} '
                   '([speed][load][order][re, im], no load level without loads) '
                   f'(got {arr.shape})')
    if not np.all(np.isfinite(arr)):
        raise _err(where, 'coefficients', 'values must be finite (no NaN/inf)')
    coeffs = (arr[..., 0] + 1j * arr[..., 1]).reshape(speeds.size, n_l or 1, orders.size)
    _validate_table(where, speeds, loads, orders, coeffs, yaml_fields=True)
    engine_ref = d.get('engine') or DEFAULT_ENGINE
    if not isinstance(engine_ref, str):
        raise _err(where, 'engine', 'must be an engine YAML name or path')
    return _TableData(engine_ref, speeds, loads, coeffs)


def _resolve_ref(ref: str, relative_to: Path) -> Path:
    cand = Path(ref)
    if not cand.is_absolute() and cand.suffix in ('.yaml', '.yml'):
        local = relative_to.parent / cand
        if local.is_file():
            return local
    return config_file(ref)


def _engine_from_table(path: Path, table: _TableData, load_set: str) -> Engine:
    try:
        engine_yaml = _resolve_ref(table.engine_ref, path)
    except FileNotFoundError:
        raise _err(path.name, 'engine', f'engine YAML {table.engine_ref!r} not found '
                   '(a config name like engine_d13 or a path)') from None
    cfg = read_engine_config(engine_yaml, need_model=False)
    n_max = table.coefficients.shape[-1] - 1
    # Inertia part from the referenced geometry, same FFT route as the model.
    n_samples = max(2880, 8 * (n_max + 1))
    theta = 4.0 * np.pi * np.arange(n_samples) / n_samples
    _, dx, d2x = cfg.geometry.kinematics(theta)
    c = np.fft.rfft(-cfg.geometry.oscillating_mass_kg * d2x * dx)[: n_max + 1] / n_samples
    c[1:] *= 2.0
    c[0] = 0.0
    omega2 = (table.speeds_rpm * math.pi / 30.0) ** 2
    gas = table.coefficients - omega2[:, None, None] * c[None, None, :]
    if table.loads is None:   # full-load data: gas part scales with the load fraction
        loads = np.array([0.0, 1.0])
        gas = np.concatenate((np.zeros_like(gas), gas), axis=1)
    else:
        loads = table.loads
    grid = _GasGrid(table.speeds_rpm, loads, n_max + 1, values=gas)
    return Engine(cfg, grid, c, load_set=load_set, n_max=n_max, source=path)


# ----------------------------------------------------------------------------------------------
# Entry point
# ----------------------------------------------------------------------------------------------
def load_engine(source: str | Path = DEFAULT_ENGINE, load_set: str = 'A') -> Engine:
    """Engine excitation from a config name (``engine_d13``), an engine YAML or a table CSV/YAML."""
    path = config_file(source)
    if path.suffix == '.csv':
        return _engine_from_table(path, _read_table_csv(path), load_set)
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f'{path.name}: not valid YAML ({str(exc).splitlines()[0]})') from None
    if isinstance(doc, Mapping) and 'coefficients' in doc:
        return _engine_from_table(path, _read_table_yaml(path, doc), load_set)
    cfg = read_engine_config(path)
    model = PressureModel(cfg)
    assert cfg.grid is not None
    grid = _GasGrid(cfg.grid.speeds_rpm, cfg.grid.loads, cfg.n_max + 1, filler=model.gas_coefficients)
    return Engine(cfg, grid, model.inertia_unit, load_set=load_set,
                  full_load_curve=cfg.full_load_curve, model=model, source=path)


def write_coefficient_table(engine: EngineExcitation, path: str | Path, speeds_rpm: Sequence[float],
                            loads: Sequence[float] | None = None, *, engine_ref: str = DEFAULT_ENGINE,
                            comment: str = '') -> Path:
    """Write per-cylinder A_n of ``engine`` as a table CSV (format in the module docstring).

    Without ``loads`` the table holds full-load data (header ``speed_rpm,n,re,im``).
    """
    path = Path(path)
    lines = [f'# {ln}' for ln in comment.splitlines()]
    lines.append(f'# engine: {engine_ref}')
    lines.append('speed_rpm,load,n,re,im' if loads is not None else 'speed_rpm,n,re,im')
    for s in speeds_rpm:
        for ld in (loads if loads is not None else [1.0]):
            A = engine.coefficients(s, ld)
            A = np.where(np.abs(A) < 1e-9 * max(1.0, float(np.abs(A).max())), 0.0, A)  # round-off
            for n, a in enumerate(A):
                im = 0.0 if n == 0 else a.imag
                prefix = f'{s:g},{ld:g}' if loads is not None else f'{s:g}'
                lines.append(f'{prefix},{n},{a.real:.9g},{im:.9g}')
    path.write_text('\n'.join(lines) + '\n')
    return path
