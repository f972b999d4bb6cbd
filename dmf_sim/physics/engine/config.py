"""The engine YAML (``config/engine_d13.yaml``): geometry, firing phases, load sets and the
pressure-model sections, validated field by field (dmf_sim.core.validation).

Engine braking (optional, with the pressure model): ``brake_curve`` (the whole engine's torque
[Nm] over speed at full brake, every value <= 0) and ``compression_release_brake`` (the valve
events of the brake, :class:`CompressionReleaseBrake`); the load fraction -1 is that curve.
``brake_curve: null`` in a file with a ``base:`` removes the base's brake.

An engine YAML may start from another one: ``base: engine_d13`` (a config name or a path,
relative paths relative to the file) takes every top-level section of the base file and lets this
file replace whole sections (e.g. only ``name``, ``description`` and ``full_load_curve`` for
another torque rating of the same engine).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from dmf_sim.core.errors import ConfigError, ConfigFileError
from dmf_sim.core.paths import config_file, read_yaml_mapping
from dmf_sim.core.units import CYCLE_RAD
from dmf_sim.core.validation import (
    Table1D,
    bounded,
    check_keys,
    field_error,
    integer,
    number,
    number_list,
    table_1d,
)
from dmf_sim.physics.orders import half_orders

__all__ = ['N_MAX_RANGE', 'MODEL_KEYS', 'BRAKE_KEYS', 'BASE_DEPTH_MAX', 'Geometry', 'GasExchange',
           'Combustion', 'CompressionReleaseBrake', 'Grid', 'EngineConfig', 'resolve_ref',
           'with_base', 'read_engine_config', 'engine_config', 'require_model']

N_MAX_RANGE = (1, 48)
"""Allowed highest half-order index n_max of an engine or a table."""

MODEL_KEYS = ('full_load_curve', 'gas_exchange', 'combustion', 'samples_per_cycle', 'grid')
"""Top-level sections of the pressure model (absent in a YAML that only backs a table)."""

BRAKE_KEYS = ('brake_curve', 'compression_release_brake')
"""Optional top-level sections of the pressure model: the engine brake (both or neither)."""

BASE_DEPTH_MAX = 8
"""Longest chain of ``base:`` references followed."""


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
        """Piston travel from TDC x [m], dx/dtheta [m/rad], d2x/dtheta2 [m/rad^2] at crank
        angle theta [rad]."""
        r, lam = self.crank_radius_m, self.crank_radius_m / self.conrod_m
        s, c = np.sin(theta), np.cos(theta)
        root = np.sqrt(1.0 - (lam * s) ** 2)
        x = r * (1.0 - c) + self.conrod_m * (1.0 - root)
        dx = r * s * (1.0 + lam * c / root)
        d2x = r * c + r * lam * (np.cos(2.0 * theta) + lam ** 2 * s ** 4) / root ** 3
        return x, dx, d2x

    def max_gas_torque_nm(self, pressure_pa: float) -> float:
        """Upper bound [Nm] of one cylinder's gas torque at cylinder pressure ``pressure_pa``
        (gauge to the crankcase): p A dx/dtheta with the lever |dx/dtheta| <= r (1 + r/l)."""
        r = self.crank_radius_m
        return pressure_pa * self.piston_area_m2 * r * (1.0 + r / self.conrod_m)

    def inertia_shape(self, theta: np.ndarray) -> np.ndarray:
        """Oscillating-mass torque per omega^2, -m (d2x/dtheta2)(dx/dtheta) [Nm s^2]."""
        _, dx, d2x = self.kinematics(theta)
        return -self.oscillating_mass_kg * d2x * dx

    def inertia_coefficients(self, n_max: int, n_samples: int) -> np.ndarray:
        """Half-order coefficients A_0..A_{n_max} [Nm s^2] of :meth:`inertia_shape` (times
        omega^2 [rad/s]^2 the inertia torque's A_n; its mean is exactly zero)."""
        theta = CYCLE_RAD * np.arange(n_samples) / n_samples
        c = half_orders(self.inertia_shape(theta), n_max)
        c[0] = 0.0
        return c


@dataclass(frozen=True)
class GasExchange:
    """Valve events, intake (boost) and exhaust pressures of the pressure model."""

    ambient_pa: float
    crankcase_pa: float
    ivc_deg: float
    evo_deg: float
    blowdown_deg: float
    overlap_deg: float
    boost_gauge_full_load: Table1D          # Pa over rpm
    exhaust_backpressure_zero_load_pa: float
    exhaust_backpressure_full_load_pa: float


@dataclass(frozen=True)
class Combustion:
    """Double Wiebe heat release (Ghojel 2010) and the polytropic exponent."""

    polytropic_exponent: float
    wiebe_a: float
    start_deg: Table1D                      # deg over rpm
    premixed_fraction_zero_load: float
    premixed_fraction_full_load: float
    premixed_duration_deg: float
    premixed_shape: float
    diffusion_duration_full_load_deg: Table1D  # deg over rpm
    diffusion_duration_zero_load_factor: float
    diffusion_shape: float


@dataclass(frozen=True)
class CompressionReleaseBrake:
    """Valve events of a compression-release engine brake (crank angles [deg] from the
    cylinder's compression TDC), :meth:`dmf_sim.physics.engine.pressure.PressureModel.brake_cycle`:

    ``charge_duration_deg``: the exhaust valve's charging lift opens this long before the intake
    valve closes (near intake BDC; not before the intake stroke begins): by intake valve closing
    the cylinder holds the exhaust manifold's pressure; ``release_deg``: the release lift opens
    the exhaust valve before compression TDC and the cylinder falls to the manifold's pressure
    within ``release_duration_deg``; ``close_deg``: the release lift ends (at the latest at the
    normal exhaust valve opening, where the valve stays open), the gas left re-expands until the
    normal exhaust valve opening."""

    charge_duration_deg: float
    release_deg: float
    release_duration_deg: float
    close_deg: float


@dataclass(frozen=True)
class Grid:
    """Speed x load grid on which the gas part is cached."""

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
    full_load_curve: Table1D | None = None
    gas_exchange: GasExchange | None = None
    combustion: Combustion | None = None
    samples_per_cycle: int | None = None
    grid: Grid | None = None
    brake_curve: Table1D | None = None              # Nm (<= 0) over rpm
    brake: CompressionReleaseBrake | None = None

    @property
    def has_model(self) -> bool:
        return self.full_load_curve is not None

    @property
    def has_brake(self) -> bool:
        """Whether the engine brakes: a pressure model with a brake curve."""
        return self.has_model and self.brake_curve is not None


# ----------------------------------------------------------------------------------------------
# Files and base references
# ----------------------------------------------------------------------------------------------
def resolve_ref(ref: str, relative_to: Path) -> Path:
    """A referenced engine YAML: a path relative to ``relative_to``'s directory if it exists
    there, else a config name or path (dmf_sim.core.paths.config_file)."""
    cand = Path(ref)
    if not cand.is_absolute() and cand.suffix in ('.yaml', '.yml'):
        local = relative_to.parent / cand
        if local.is_file():
            return local
    return config_file(ref)


def with_base(doc: Mapping[str, Any], path: Path) -> tuple[dict[str, Any], str]:
    """The mapping with its ``base:`` chain applied (the file's sections replace the base's) and
    the name to quote in error messages (``x.yaml`` or ``x.yaml (base engine_d13.yaml)``)."""
    merged = dict(doc)
    seen = [Path(path).resolve()]
    where = Path(path).name
    bases = []
    while 'base' in merged:
        ref = merged.pop('base')
        if not isinstance(ref, str) or not ref.strip():
            raise field_error(where, 'base', 'must be the name or path of another engine YAML')
        if len(seen) > BASE_DEPTH_MAX:
            raise field_error(where, 'base', f'more than {BASE_DEPTH_MAX} nested base files')
        try:
            base_path = resolve_ref(ref, seen[-1])
        except ConfigFileError as exc:
            raise field_error(where, 'base', f'{ref!r}: {exc}') from None
        if base_path.resolve() in seen:
            raise field_error(where, 'base',
                              f'{ref!r} refers back to a file already read (a cycle)')
        seen.append(base_path.resolve())
        bases.append(base_path.name)
        _, base_doc = read_yaml_mapping(base_path, 'engine')
        if 'coefficients' in base_doc:
            raise field_error(where, 'base', f'{ref!r} is a coefficient table, not an engine YAML')
        merged = {**base_doc, **merged}     # the base's own 'base' (if any) comes along
    if bases:
        where = f'{where} (base {", ".join(bases)})'
    return merged, where


def read_engine_config(path: str | Path, *, need_model: bool = True) -> EngineConfig:
    """Read and validate an engine YAML (see ``config/engine_d13.yaml``).

    With ``need_model=False`` the pressure-model sections may be absent (a YAML that only supplies
    geometry, firing phases and load sets for a user table).
    """
    path, doc = read_yaml_mapping(path, 'engine')
    return engine_config(doc, path, need_model=need_model)


def engine_config(doc: Mapping[str, Any], path: str | Path, *,
                  need_model: bool = True) -> EngineConfig:
    """Validate an engine mapping (as read from ``path``; its ``base:`` chain is applied)."""
    path = Path(path)
    d, where = with_base(doc, path)
    required = ['name', 'n_cylinders', 'firing_phases_deg', 'n_max', 'geometry', 'load_sets']
    check_keys(d, where, '', required + (list(MODEL_KEYS) if need_model else []),
               ['description', *BRAKE_KEYS] + ([] if need_model else list(MODEL_KEYS)))
    if not isinstance(d['name'], str) or not d['name']:
        raise field_error(where, 'name', 'must be a non-empty string')
    n_cyl = integer(d['n_cylinders'], where, 'n_cylinders', 1, 24)
    phases = number_list(d['firing_phases_deg'], where, 'firing_phases_deg',
                         quantity='firing_phase')
    if len(phases) != n_cyl:
        raise field_error(where, 'firing_phases_deg',
                          f'must have n_cylinders = {n_cyl} entries in [0, 720)')
    n_max = integer(d['n_max'], where, 'n_max', *N_MAX_RANGE)
    cfg: dict[str, Any] = dict(
        path=path, name=d['name'], n_cylinders=n_cyl, firing_phases_deg=phases, n_max=n_max,
        geometry=_geometry(d['geometry'], where), **_load_sets(d['load_sets'], where))
    if all(k in d for k in MODEL_KEYS):
        cfg.update(_model_sections(d, where, n_max))
        cfg.update(_brake_sections(d, where))
    elif any(k in d for k in MODEL_KEYS):
        missing = next(k for k in MODEL_KEYS if k not in d)
        raise field_error(where, missing,
                          'missing (required when any pressure-model section is given)')
    return EngineConfig(**cfg)


# ----------------------------------------------------------------------------------------------
# Sections
# ----------------------------------------------------------------------------------------------
def _geometry(g: Any, where: str) -> Geometry:
    g = check_keys(g, where, 'geometry',
                   ['bore_m', 'stroke_m', 'conrod_m', 'compression_ratio', 'oscillating_mass_kg'])
    f = 'geometry.'
    geometry = Geometry(
        bore_m=bounded(g['bore_m'], where, f + 'bore_m', 'bore'),
        stroke_m=bounded(g['stroke_m'], where, f + 'stroke_m', 'stroke'),
        conrod_m=bounded(g['conrod_m'], where, f + 'conrod_m', 'conrod'),
        compression_ratio=bounded(g['compression_ratio'], where, f + 'compression_ratio',
                                  'compression_ratio'),
        oscillating_mass_kg=bounded(g['oscillating_mass_kg'], where, f + 'oscillating_mass_kg',
                                    'oscillating_mass'),
    )
    if geometry.conrod_m <= geometry.crank_radius_m:
        raise field_error(where, f + 'conrod_m', 'must exceed the crank radius stroke_m/2 = '
                          f'{geometry.crank_radius_m:g} m')
    return geometry


def _load_sets(ls: Any, where: str) -> dict[str, Any]:
    ls = check_keys(ls, where, 'load_sets', ['limit_rpm', 'shift_rpm'])
    limit = bounded(ls['limit_rpm'], where, 'load_sets.limit_rpm', 'engine_speed', positive=True)
    shifts_raw = ls['shift_rpm']
    if not isinstance(shifts_raw, Mapping) or 'A' not in shifts_raw:
        raise field_error(where, 'load_sets.shift_rpm',
                          'must be a mapping of set names to shifts, including A: 0')
    shifts = {str(k): number(v, where, f'load_sets.shift_rpm.{k}', 0.0, limit, hi_open=True)
              for k, v in shifts_raw.items()}
    if shifts['A'] != 0.0:
        raise field_error(where, 'load_sets.shift_rpm.A',
                          'must be 0 (Load A is the reference data)')
    return dict(load_set_shifts_rpm=shifts, load_set_limit_rpm=limit)


def _model_sections(d: Mapping[str, Any], where: str, n_max: int) -> dict[str, Any]:
    curve = table_1d(d['full_load_curve'], where, 'full_load_curve', 'speeds_rpm', 'torque_nm',
                     'engine_speed', 'torque')
    samples = integer(d['samples_per_cycle'], where, 'samples_per_cycle', 720, 100000)
    if samples % 2 or samples <= 4 * (n_max + 1):
        raise field_error(where, 'samples_per_cycle',
                          f'must be even and > 4*(n_max+1) = {4 * (n_max + 1)}')
    return dict(full_load_curve=curve, gas_exchange=_gas_exchange(d['gas_exchange'], where),
                combustion=_combustion(d['combustion'], where), samples_per_cycle=samples,
                grid=_grid(d['grid'], where))


def _brake_sections(d: Mapping[str, Any], where: str) -> dict[str, Any]:
    """``brake_curve`` (torques <= 0, BOUNDS 'brake_torque') and ``compression_release_brake``;
    both absent (or ``brake_curve: null``): an engine that does not brake."""
    if d.get('brake_curve') is None:
        return {}
    curve = table_1d(d['brake_curve'], where, 'brake_curve', 'speeds_rpm', 'torque_nm',
                     'engine_speed', 'brake_torque')
    if d.get('compression_release_brake') is None:
        raise field_error(where, 'compression_release_brake',
                          'missing (required with brake_curve: the valve events of the brake)')
    b = check_keys(d['compression_release_brake'], where, 'compression_release_brake',
                   ['charge_duration_deg', 'release_deg', 'release_duration_deg', 'close_deg'])
    f = 'compression_release_brake.'
    return dict(brake_curve=curve, brake=CompressionReleaseBrake(
        charge_duration_deg=bounded(b['charge_duration_deg'], where, f + 'charge_duration_deg',
                                    'brake_charge_duration'),
        release_deg=bounded(b['release_deg'], where, f + 'release_deg', 'brake_release_angle'),
        release_duration_deg=bounded(b['release_duration_deg'], where,
                                     f + 'release_duration_deg', 'blowdown_duration'),
        close_deg=bounded(b['close_deg'], where, f + 'close_deg', 'brake_close_angle')))


def _gas_exchange(ge: Any, where: str) -> GasExchange:
    ge = check_keys(ge, where, 'gas_exchange',
                    ['ambient_pa', 'crankcase_pa', 'ivc_deg', 'evo_deg', 'blowdown_deg',
                     'overlap_deg', 'boost_gauge_full_load', 'exhaust_backpressure_zero_load_pa',
                     'exhaust_backpressure_full_load_pa'])
    f = 'gas_exchange.'

    def num(key: str, quantity: str) -> float:
        return bounded(ge[key], where, f + key, quantity)

    gas = GasExchange(
        ambient_pa=num('ambient_pa', 'ambient_pressure'),
        crankcase_pa=num('crankcase_pa', 'ambient_pressure'),
        ivc_deg=num('ivc_deg', 'ivc_angle'),
        evo_deg=num('evo_deg', 'evo_angle'),
        blowdown_deg=num('blowdown_deg', 'blowdown_duration'),
        overlap_deg=num('overlap_deg', 'valve_overlap'),
        boost_gauge_full_load=table_1d(ge['boost_gauge_full_load'], where,
                                       f + 'boost_gauge_full_load', 'speeds_rpm', 'pressure_pa',
                                       'engine_speed', 'boost_pressure'),
        exhaust_backpressure_zero_load_pa=num('exhaust_backpressure_zero_load_pa',
                                              'exhaust_backpressure'),
        exhaust_backpressure_full_load_pa=num('exhaust_backpressure_full_load_pa',
                                              'exhaust_backpressure'),
    )
    if gas.evo_deg + gas.blowdown_deg > 360.0 - 0.5 * gas.overlap_deg:
        raise field_error(where, f + 'blowdown_deg', 'evo_deg + blowdown_deg must not exceed '
                          '360 - overlap_deg/2 (blowdown ends before the overlap)')
    if gas.ivc_deg < -360.0 + 0.5 * gas.overlap_deg:
        raise field_error(where, f + 'ivc_deg', 'must be later than -360 + overlap_deg/2')
    return gas


def _combustion(cb: Any, where: str) -> Combustion:
    cb = check_keys(cb, where, 'combustion',
                    ['polytropic_exponent', 'wiebe_a', 'start_deg', 'premixed_fraction_zero_load',
                     'premixed_fraction_full_load', 'premixed_duration_deg', 'premixed_shape',
                     'diffusion_duration_full_load_deg', 'diffusion_duration_zero_load_factor',
                     'diffusion_shape'])
    f = 'combustion.'

    def num(key: str, quantity: str) -> float:
        return bounded(cb[key], where, f + key, quantity)

    return Combustion(
        polytropic_exponent=num('polytropic_exponent', 'polytropic_exponent'),
        wiebe_a=num('wiebe_a', 'wiebe_efficiency'),
        start_deg=table_1d(cb['start_deg'], where, f + 'start_deg', 'speeds_rpm', 'angle_deg',
                           'engine_speed', 'combustion_start'),
        premixed_fraction_zero_load=num('premixed_fraction_zero_load', 'fraction'),
        premixed_fraction_full_load=num('premixed_fraction_full_load', 'fraction'),
        premixed_duration_deg=num('premixed_duration_deg', 'premixed_duration'),
        premixed_shape=num('premixed_shape', 'wiebe_shape'),
        diffusion_duration_full_load_deg=table_1d(
            cb['diffusion_duration_full_load_deg'], where, f + 'diffusion_duration_full_load_deg',
            'speeds_rpm', 'duration_deg', 'engine_speed', 'diffusion_duration'),
        diffusion_duration_zero_load_factor=num('diffusion_duration_zero_load_factor',
                                                'duration_factor'),
        diffusion_shape=num('diffusion_shape', 'wiebe_shape'),
    )


def _grid(gr: Any, where: str) -> Grid:
    gr = check_keys(gr, where, 'grid',
                    ['speed_min_rpm', 'speed_max_rpm', 'speed_step_rpm', 'loads'])
    s0 = number(gr['speed_min_rpm'], where, 'grid.speed_min_rpm', 50.0, 10000.0)
    s1 = number(gr['speed_max_rpm'], where, 'grid.speed_max_rpm', 50.0, 10000.0)
    if not s0 < s1:                 # either may be the one changed: both named
        raise field_error(where, '', "fields 'grid.speed_min_rpm' and 'grid.speed_max_rpm' must "
                          f'satisfy speed_min_rpm < speed_max_rpm, got {s0:g} and {s1:g} rpm')
    ds = number(gr['speed_step_rpm'], where, 'grid.speed_step_rpm', 0.0, s1 - s0, lo_open=True)
    n_steps = round((s1 - s0) / ds)
    if abs(n_steps * ds - (s1 - s0)) > 1e-6 * ds:
        raise field_error(where, 'grid.speed_step_rpm',
                          f'must divide speed_max_rpm - speed_min_rpm = {s1 - s0:g}')
    loads = number_list(gr['loads'], where, 'grid.loads', 0.0, 1.0, min_len=2, increasing=True)
    if loads[0] != 0.0 or loads[-1] != 1.0:
        raise field_error(where, 'grid.loads',
                          'must start at 0 and end at 1 (strictly increasing)')
    return Grid(np.linspace(s0, s1, n_steps + 1), loads)


def require_model(cfg: EngineConfig) -> None:
    """Refuse a configuration without the pressure-model sections."""
    if not cfg.has_model:
        raise ConfigError(f'{cfg.path.name}: full_load_curve: missing (pressure model sections '
                          'required)')
