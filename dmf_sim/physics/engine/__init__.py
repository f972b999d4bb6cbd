"""Engine excitation: cylinder torque coefficients A_n (pressure model or user table), Load A/B/C.

Convention (paper eq. 16-17, doc/theory.md §3)
-------------------------------------------------
The torque [Nm] one cylinder k applies to its crank throw is the half-order series::

    P_k(psi) = Re( sum_{n=0}^{n_max} A_n exp(i n/2 (psi - beta_k)) )          (eq. 16-17)

``psi`` is the crank angle [rad] (``psi = 0`` at cylinder 1 firing top dead centre), ``beta_k`` the
firing phase of cylinder k (0, 480, 240, 600, 120, 360 deg for firing order 1-5-3-6-2-4) and
``n`` the half-order index (n = 6 is the 3rd engine order). All cylinders share the same complex
``A_n`` (Nm); ``A_0`` is real and is the mean torque of one cylinder, so the whole engine delivers
``n_cylinders * A_0``. :meth:`Engine.coefficients` returns ``A_0..A_{n_max}`` for an engine speed
[rpm] and a load fraction in [0, 1], or [-1, 1] for an engine with a brake curve (engine
braking below 0, :func:`load_range`).

Every ``A_n`` is the sum of two parts:

* **inertia part** of the oscillating mass m (piston, pin, rings, share of the rod),
  ``T_i = -m omega^2 (d2x/dpsi2)(dx/dpsi)``, computed exactly from the slider-crank geometry at the
  *actual* speed; it does not depend on load and its mean is zero;
* **gas part** ``T_g = (p - p_crankcase) A_p dx/dpsi`` from the cylinder pressure p. The load
  fraction acts on this part only (``load = 0`` keeps the compression/expansion torque and burns
  just enough fuel to overcome the pumping loss, so its mean is 0). A cylinder that does not fire
  at all (a misfire) is :meth:`Engine.motored_coefficients`: no heat release, the manifold
  pressures of the operating point.

Modules: ``fields`` (YAML field validation), ``config`` (the engine YAML, ``base:`` files),
``pressure`` (the default pressure model), ``excitation`` (the :class:`Engine` object: gas grid +
inertia part, Load A/B/C), ``tables`` (user tables).

Default model (``config/engine_d13.yaml``)
------------------------------------------
13-litre inline six (Volvo D13 geometry, a 2800 Nm rating; sources in the YAML); the pressure
model is described in :mod:`dmf_sim.physics.engine.pressure`. ``config/engine_d13_2500nm.yaml`` is
the same engine with a 2500 Nm rating (``base: engine_d13``). ``A_n`` come from the half orders of
one sampled cycle. The gas part is cached on a speed/load grid (YAML ``grid``), computed lazily
cell by cell (or all at once with :meth:`Engine.warm_up`) and interpolated linearly (complex
bilinear) in between; the inertia part is exact at any speed.

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
      coefficients: ...           # [speed][load][order] -> [re, im]
                                  # ([speed][order] without loads)

Rules: orders 0..n_max all present (1 <= n_max <= 48), at least two speeds within [100, 5000] rpm,
finite values, ``im(A_0) = 0``. The table's own (whole-engine) mean ``n_cylinders * A_0`` defines
the full-load curve. Inside the table the gas part is ``table - inertia(geometry)`` and is
interpolated linearly in speed and load; the exact inertia part is added back at the actual speed.
A table **without a load axis is full-load data**: the gas part (table minus inertia) is scaled by
the load fraction, so at load 0 only the inertia torque is left (the table carries no information
on the motored gas torque). Queries outside the table's speed range raise
:class:`~dmf_sim.core.errors.OperatingRangeError`.

Every invalid file is refused with a one-line :class:`~dmf_sim.core.errors.ConfigError` naming the
file, the field and the allowed range (YAML syntax errors with line and column, a file that is not
a YAML mapping or a directory said so). :func:`write_coefficient_table` writes the CSV format
(``config/engine_table_example.csv`` was generated with it from the default model).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from dmf_sim.core.deprecation import renamed
from dmf_sim.core.paths import config_file, read_yaml_mapping
from dmf_sim.physics.engine.config import EngineConfig, Geometry, engine_config, read_engine_config
from dmf_sim.physics.engine.excitation import (
    LOAD_LIMITS,
    Engine,
    EngineExcitation,
    GasGrid,
    cylinder_torque_signal,
    engine_torque_orders,
    load_error,
    load_range,
)
from dmf_sim.physics.engine.pressure import CycleResult, PressureModel
from dmf_sim.physics.engine.tables import (
    DEFAULT_ENGINE,
    engine_from_table,
    read_table_csv,
    read_table_yaml,
    write_coefficient_table,
)

__all__ = [
    'LOAD_SETS', 'LOAD_LIMITS', 'load_range', 'load_error', 'DEFAULT_ENGINE', 'EngineExcitation',
    'Engine', 'EngineConfig', 'Geometry',
    'PressureModel', 'CycleResult', 'read_engine', 'engine_from_mapping', 'read_engine_config',
    'cylinder_torque_signal', 'engine_torque_orders', 'write_coefficient_table',
]

LOAD_SETS: tuple[str, ...] = ('A', 'B', 'C')
"""Load-set names of the paper; their shifts and limit speed live in the engine YAML."""


def read_engine(source: str | Path = DEFAULT_ENGINE, load_set: str = 'A') -> Engine:
    """Engine excitation from a config name (``engine_d13``), an engine YAML or a table
    CSV/YAML."""
    path = config_file(source)
    if path.suffix == '.csv':
        return engine_from_table(path, read_table_csv(path), load_set)
    path, doc = read_yaml_mapping(path, 'engine')
    if 'coefficients' in doc:
        return engine_from_table(path, read_table_yaml(path, doc), load_set)
    return engine_from_mapping(doc, path, load_set)


def engine_from_mapping(doc: Mapping[str, Any], path: str | Path, load_set: str = 'A') -> Engine:
    """The pressure-model engine of an engine YAML mapping (as read from ``path``, which names it
    in errors and anchors relative ``base:`` references); e.g. a study's variant of a packaged
    engine with another full-load curve."""
    cfg = engine_config(doc, path)
    model = PressureModel(cfg)
    # with a brake, the full brake (-1) is one more load of the grid: part braking is linear
    # between it and load 0 (PressureModel.cycle), so the interpolation is exact there
    loads = np.concatenate(([LOAD_LIMITS[0]], cfg.grid.loads)) if cfg.has_brake else cfg.grid.loads
    grid = GasGrid(cfg.grid.speeds_rpm, loads, cfg.n_max + 1, filler=model.gas_coefficients)
    motored = GasGrid(cfg.grid.speeds_rpm, loads, cfg.n_max + 1,
                      filler=model.motored_gas_coefficients)
    return Engine(cfg, grid, model.inertia_unit, load_set=load_set,
                  full_load_curve=cfg.full_load_curve, model=model, source=Path(path),
                  motored_gas=motored, brake_curve=cfg.brake_curve if cfg.has_brake else None)


__getattr__ = renamed(__name__, {'load_engine': 'read_engine'}, globals())
