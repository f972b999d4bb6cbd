"""The engine excitation object: A_n = gas part (cached grid, Load A/B/C speed shift) + inertia
part (exact at the actual speed), and the free functions on the eq. 16-17 series."""
from __future__ import annotations

import bisect
import math
from pathlib import Path
from typing import Callable, Protocol, runtime_checkable

import numpy as np

from dmf_sim.core.deprecation import renamed_method
from dmf_sim.core.errors import ConfigError, OperatingRangeError
from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.core.validation import Table1D
from dmf_sim.physics.engine.config import EngineConfig

__all__ = ['LOAD_LIMITS', 'EngineExcitation', 'cylinder_torque_signal', 'engine_torque_orders',
           'GasGrid', 'Engine', 'load_range', 'load_error']

LOAD_LIMITS = (-1.0, 1.0)
"""The widest torque demand any engine accepts: -1 full brake (the engine's brake curve), 0 no
load, 1 full load. An engine accepts less (:func:`load_range`): one without a brake curve
[0, 1]. Where the engine is not known yet (a profile file, a command-line option, the setpoint
client) a value outside these is refused at once, the rest when the engine is."""


def load_range(engine) -> tuple[float, float]:
    """The torque demands [lo, hi] ``engine`` accepts: its ``load_range`` where it has one
    (:attr:`Engine.load_range`), else [0, 1] (an excitation without engine braking)."""
    rng = getattr(engine, 'load_range', None)
    return (float(rng[0]), float(rng[1])) if rng is not None else (0.0, 1.0)


def load_error(engine, load, what: str = 'load') -> str | None:
    """Why ``load`` is not a torque demand ``engine`` accepts, or None: one line naming
    ``what`` (a field, option or parameter) and the range; a negative load for an engine
    without a brake curve says so. The one rule every caller asks (engine, live setpoints,
    profiles, options, study conditions)."""
    lo, hi = load_range(engine)
    if isinstance(load, bool) or not isinstance(load, (int, float, np.floating, np.integer)):
        return f'{what} must be a number in [{lo:g}, {hi:g}], got {load!r}'
    x = float(load)
    if math.isfinite(x) and lo <= x <= hi:
        return None
    text = f'{what} {x:g} outside [{lo:g}, {hi:g}]'
    if math.isfinite(x) and LOAD_LIMITS[0] <= x < lo:
        name = getattr(engine, 'name', '') or type(engine).__name__
        text += (f' (engine {name!r} has no brake curve: a negative load, engine braking, '
                 'needs an engine YAML with brake_curve such as engine_d13)')
    else:
        text += ' (-1 full engine brake, 0 no load, 1 full load)'
    return text


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

    ``P_k(psi) = Re(sum_n A_n exp(i n/2 (psi - beta_k)))`` (eq. 16 for beta = 0, eq. 17 in
    general). Returns an array of the shape of ``psi``.
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


class GasGrid:
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
            self.values[i, j] = self._filler(self._speeds_list[i], self._loads_list[j])
            self.done[i, j] = True
            self.__dict__.pop('_load_rows', None)        # computed from fewer nodes
        return self.values[i, j]

    def load_rows(self, load: float) -> tuple[np.ndarray, np.ndarray]:
        """(rows, ready): the grid interpolated to ``load`` at every grid speed (S, n_orders) —
        the load step of :meth:`__call__`, the same operations — and (S,) whether that speed's
        nodes are computed (rows of the others are zero). What a compiled caller needs to do
        the speed step itself; nodes are not computed here (the grid stays lazy)."""
        j, tl = self._bracket(self._loads_list, load)
        cache = self.__dict__.setdefault('_load_rows', {})
        hit = cache.get((j, tl))
        if hit is None:
            ready = self.done[:, j] & self.done[:, j + 1]
            rows = np.zeros((self.speeds.size, self.values.shape[2]), dtype=complex)
            v = self.values
            for i in np.flatnonzero(ready).tolist():
                rows[i] = v[i, j] * (1.0 - tl) + v[i, j + 1] * tl
            hit = cache[(j, tl)] = (rows, ready)
        return hit

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

    def many(self, speeds_rpm: np.ndarray, load: float) -> np.ndarray:
        """(K, n_orders) :meth:`__call__` at K speeds and one load, vectorized: the same
        brackets and the same operations in the same order (bitwise the same values)."""
        x = np.asarray(speeds_rpm, dtype=float)
        n = len(self._speeds_list)
        i = np.minimum(np.maximum(np.searchsorted(self.speeds, x, side='right') - 1, 0), n - 2)
        ts = ((x - self.speeds[i]) / (self.speeds[i + 1] - self.speeds[i]))[:, None]
        j, tl = self._bracket(self._loads_list, load)
        for k in set(i.tolist()):
            for kk in (k, k + 1):
                self._node(kk, j)
                self._node(kk, j + 1)
        v = self.values
        a = v[i, j] * (1.0 - tl) + v[i, j + 1] * tl
        b = v[i + 1, j] * (1.0 - tl) + v[i + 1, j + 1] * tl
        return a * (1.0 - ts) + b * ts


class Engine:
    """Engine excitation (implements :class:`EngineExcitation`) for one load set.

    ``coefficients = gas(effective speed, load) + inertia(actual speed)``.
    """

    def __init__(self, cfg: EngineConfig, gas: GasGrid, inertia_unit: np.ndarray, *,
                 load_set: str = 'A', n_max: int | None = None,
                 full_load_curve: Table1D | None = None, model=None,
                 source: Path | None = None, motored_gas: GasGrid | None = None,
                 brake_curve: Table1D | None = None) -> None:
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
        self._motored_gas = motored_gas
        self._inertia_unit = np.asarray(inertia_unit, dtype=complex)[: self.n_max + 1]
        self._curve = full_load_curve
        self._brake_curve = brake_curve
        self.speed_range_rpm: tuple[float, float] = gas.speed_range
        self.load_range: tuple[float, float] = (float(gas.loads[0]), float(gas.loads[-1]))
        """The torque demands this engine's data cover: [-1, 1] with a brake curve (the gas
        grid's loads from -1), else [0, 1]."""

    @property
    def name(self) -> str:
        """The engine's name (YAML ``name``; for a table, the table's file name)."""
        return self.config.name if self.source == self.config.path else self.source.name

    def with_load_set(self, load_set: str) -> Engine:
        """The same engine (sharing the cached gas data) for another load set."""
        return Engine(self.config, self._gas, self._inertia_unit, load_set=load_set,
                      n_max=self.n_max, full_load_curve=self._curve, model=self.model,
                      source=self.source, motored_gas=self._motored_gas,
                      brake_curve=self._brake_curve)

    def warm_up(self) -> None:
        """Compute every grid node now (about 0.1 s for the default grid)."""
        self._gas.fill_all()

    warm = renamed_method('warm_up')

    # -- checks --------------------------------------------------------------------------------
    def _check(self, speed_rpm: float, load: float | None = None) -> None:
        lo, hi = self.speed_range_rpm
        if not (math.isfinite(speed_rpm) and lo <= speed_rpm <= hi):
            raise OperatingRangeError(f'speed_rpm: must be in [{lo:g}, {hi:g}] rpm '
                                      f'(got {speed_rpm!r})')
        if load is not None and (reason := load_error(self, load)):
            raise OperatingRangeError(reason)

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

    @property
    def has_motored(self) -> bool:
        """Whether the engine knows the torque of a cylinder that does not fire
        (:meth:`motored_coefficients`): the pressure model does, a user table does not."""
        return self._motored_gas is not None

    def motored_coefficients(self, speed_rpm: float, load: float) -> np.ndarray:
        """Complex A_0..A_{n_max} [Nm] of one cylinder that does not fire at ``speed_rpm`` [rpm]
        and ``load`` [-1..1]: compression and gas exchange at that operating point's manifold
        pressures without heat release
        (:meth:`~dmf_sim.physics.engine.pressure.PressureModel.motored_gas_coefficients`, cached
        on the gas grid's speeds and loads and interpolated as the fired gas part is) plus the
        inertia part. ConfigError when the engine has no such model (a user table)."""
        if self._motored_gas is None:
            raise ConfigError(f'engine {self.name!r} (a coefficient table) has no model of a '
                              'cylinder that does not fire (compression without combustion): '
                              'misfire and weak_cylinder faults need a pressure-model engine '
                              'YAML such as engine_d13')
        speed_rpm, load = float(speed_rpm), float(load)
        self._check(speed_rpm, load)
        s_eff = self.effective_speed(speed_rpm)
        self._check(s_eff)
        return self._motored_gas(s_eff, load) + self.inertia_coefficients(speed_rpm)

    def inertia_coefficients(self, speed_rpm: float) -> np.ndarray:
        """Oscillating-mass part of A_n [Nm] at the actual speed (load independent)."""
        speed_rpm = float(speed_rpm)
        self._check(speed_rpm)
        omega = speed_rpm * RPM_TO_RAD_S
        return omega * omega * self._inertia_unit

    # -- EngineExcitation ----------------------------------------------------------------------
    def coefficients(self, speed_rpm: float, load: float) -> np.ndarray:
        """Complex per-cylinder A_0..A_{n_max} [Nm] at ``speed_rpm`` [rpm] and ``load``
        (:attr:`load_range`)."""
        return self.gas_coefficients(speed_rpm, load) + self.inertia_coefficients(speed_rpm)

    def coefficients_many(self, speeds_rpm, load: float) -> np.ndarray:
        """(K, n_max+1) :meth:`coefficients` at K speeds [rpm] and one load in one vectorized
        pass (a sweep asks for hundreds of speeds): bitwise the same values; a speed outside the
        data raises the same error."""
        s = np.asarray(speeds_rpm, dtype=float).reshape(-1)
        load = float(load)
        lo, hi = self.speed_range_rpm
        s_eff = np.minimum(s + self.shift_rpm, np.maximum(s, self.limit_rpm))
        bad = ~(np.isfinite(s) & (s >= lo) & (s <= hi) & (s_eff >= lo) & (s_eff <= hi))
        if bad.any():
            k = int(np.argmax(bad))
            self._check(float(s[k]), load)
            self._check(float(s_eff[k]))
        self._check(lo, load)
        omega = s * RPM_TO_RAD_S
        return self._gas.many(s_eff, load) + (omega * omega)[:, None] * self._inertia_unit

    def speed_table(self, load: float) -> tuple:
        """What a compiled caller needs to evaluate :meth:`coefficients` at any speed at this
        ``load`` (same operations, same values): (grid speeds [rpm], gas rows at the load
        (S, n_max+1), ready (S,) bool, inertia part per (rad/s)^2 (n_max+1,), load-set shift
        [rpm], limit [rpm]); see :meth:`GasGrid.load_rows` (a speed whose nodes are not computed
        yet is not ready: ask :meth:`coefficients` there)."""
        load = float(load)
        self._check(self.speed_range_rpm[0], load)
        rows, ready = self._gas.load_rows(load)
        return (self._gas.speeds, rows, ready, self._inertia_unit, float(self.shift_rpm),
                float(self.limit_rpm))

    def mean_torque(self, speed_rpm: float, load: float) -> float:
        """Whole-engine mean torque n_cylinders * A_0 [Nm]."""
        return self.n_cylinders * float(self.coefficients(speed_rpm, load)[0].real)

    def full_load_torque(self, speed_rpm: float) -> float:
        """Whole-engine full-load torque [Nm] as this load set sees it (curve at the effective
        speed)."""
        speed_rpm = float(speed_rpm)
        self._check(speed_rpm)
        s_eff = self.effective_speed(speed_rpm)
        if self._curve is not None:
            return self._curve(s_eff)
        self._check(s_eff)
        return self.n_cylinders * float(self._gas(s_eff, 1.0)[0].real)

    @property
    def has_brake(self) -> bool:
        """Whether this engine brakes (negative loads): a brake curve in its YAML."""
        return self._brake_curve is not None

    def brake_torque(self, speed_rpm: float) -> float:
        """Whole-engine torque [Nm] at full brake (load -1; <= 0) as this load set sees it
        (the brake curve at the effective speed); 0 for an engine without a brake."""
        speed_rpm = float(speed_rpm)
        self._check(speed_rpm)
        if self._brake_curve is None:
            return 0.0
        return self._brake_curve(self.effective_speed(speed_rpm))

    def __repr__(self) -> str:
        return (f'Engine({self.config.name!r}, source={self.source.name!r}, '
                f'load_set={self.load_set!r}, n_max={self.n_max})')
