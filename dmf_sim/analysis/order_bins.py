"""Order amplitudes over engine speed: cycles grouped into speed bins (step 5 of the bag analysis).

A bin ``bin_rpm`` wide is centred on a multiple of it; its amplitudes and Fig. 13 quantities are
the means over the cycles whose speed (120 / cycle duration) falls in it, and ``n_cycles`` says
how many. A bin with fewer than ``min_cycles`` cycles is a *ramp* bin: the speed swept through
it, so the vibration there is not the steady state of that speed. Plots mark such bins apart and
the comparison with the harmonic balance uses only the *steady* ones.

With the engine load of each cycle (:mod:`dmf_sim.analysis.load_timeline`), bins are per speed
*and* load: cycles at two loads never share a row, so a row is one operating point. Cycles whose
load is unknown (it changed within them, or the bag does not say) form rows of their own, with
load NaN, that are never steady.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from dmf_sim.analysis.cycle_orders import CycleOrders
from dmf_sim.physics.orders import ORDER_1_5, ORDER_3

__all__ = ['DEFAULT_BIN_RPM', 'DEFAULT_MIN_CYCLES', 'LOAD_TOLERANCE', 'OrderTable', 'bin_cycles']

DEFAULT_BIN_RPM = 20.0
# 5 cycles in a 20-rpm bin: the speed moved by at most ~33 rpm/s at 1000 rpm (a cycle lasts 0.12 s)
DEFAULT_MIN_CYCLES = 5
_UNKNOWN_LEVEL = np.iinfo(np.int64).max     # load level key of cycles of unknown load
# two loads within this fraction of full load are one operating point (the node's health status
# prints the load with 4 decimals)
LOAD_TOLERANCE = 1e-3


@dataclass
class OrderTable:
    """Order amplitudes and Fig. 13 quantities over engine speed (rows = speed bins or cycles).

    Attributes:
        speed_rpm: bin centre (or cycle speed); speed_mean_rpm: mean cycle speed in the bin.
        n_cycles: cycles in the row; min_cycles: rows with fewer are ramp rows (``steady``).
        amplitudes: (rows, n_max + 1) |c_n| (mean over the row's cycles), n = 0 is |mean|.
        max_deviation, min_deviation, mean: Fig. 13 quantities (means over the row's cycles).
        theta: the DMF's first knee [rad] for the wind-up (else None).
        static_windup: wind-up the mean engine torque alone causes at each row's speed [rad]
            (model; set by :func:`dmf_sim.analysis.hbm_overlay.overlay_all`, else None).
        load: engine load fraction of each row's cycles (NaN: unknown or changing; None: the
            cycles' loads were not given, one load for the whole table).
    """

    speed_rpm: np.ndarray
    speed_mean_rpm: np.ndarray
    n_cycles: np.ndarray
    amplitudes: np.ndarray
    max_deviation: np.ndarray
    min_deviation: np.ndarray
    mean: np.ndarray
    theta: float | None = None
    min_cycles: int = 1
    static_windup: np.ndarray | None = None
    load: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.speed_rpm)

    @property
    def orders(self) -> np.ndarray:
        return np.arange(self.amplitudes.shape[1]) / 2.0

    @property
    def order_3(self) -> np.ndarray:
        return self.amplitudes[:, ORDER_3]

    @property
    def order_1_5(self) -> np.ndarray:
        return self.amplitudes[:, ORDER_1_5]

    @property
    def steady(self) -> np.ndarray:
        """Rows with at least ``min_cycles`` cycles (the others are ramp rows) at one known
        load."""
        ok = self.n_cycles >= self.min_cycles
        return ok if self.load is None else ok & np.isfinite(self.load)

    def select(self, rows: np.ndarray) -> OrderTable:
        """The table of the rows ``rows`` (mask or indexes)."""
        kw = {}
        for f in fields(self):
            v = getattr(self, f.name)
            kw[f.name] = v[rows] if isinstance(v, np.ndarray) else v
        return OrderTable(**kw)

    @property
    def mean_minus_theta(self) -> np.ndarray | None:
        """Dynamic mean minus theta [rad] (wind-up only)."""
        return None if self.theta is None else self.mean - self.theta

    @property
    def theta_minus_static(self) -> np.ndarray | None:
        """The paper's green line: theta minus the static wind-up of the mean torque [rad]."""
        if self.theta is None or self.static_windup is None:
            return None
        return self.theta - self.static_windup


def bin_cycles(cycles: CycleOrders, bin_rpm: float = DEFAULT_BIN_RPM,
               theta: float | None = None, min_cycles: int = DEFAULT_MIN_CYCLES,
               loads: np.ndarray | None = None) -> OrderTable:
    """Group cycles into speed bins ``bin_rpm`` wide (centres at multiples of it); 0: one row
    per cycle (then every row of known load counts as steady). With ``loads`` (the engine load
    of each cycle, NaN = unknown) the rows are per speed bin and load, ascending in both."""
    amp = np.abs(cycles.coeffs)
    load = None if loads is None else np.asarray(loads, float)
    if bin_rpm <= 0 or len(cycles) == 0:
        return OrderTable(cycles.speed_rpm.copy(), cycles.speed_rpm.copy(),
                          np.ones(len(cycles), int), amp, cycles.max_deviation.copy(),
                          cycles.min_deviation.copy(), cycles.mean.copy(), theta, 1,
                          load=None if load is None else load.copy())
    idx = np.floor(cycles.speed_rpm / bin_rpm + 0.5).astype(np.int64)
    if load is None:
        uniq, inv, counts = np.unique(idx, return_inverse=True, return_counts=True)
        centres = uniq * float(bin_rpm)
    else:
        # load levels at LOAD_TOLERANCE; unknown loads (NaN) sort after every known level
        known = np.isfinite(load)
        level = np.full(len(load), _UNKNOWN_LEVEL, np.int64)
        level[known] = np.round(load[known] / LOAD_TOLERANCE).astype(np.int64)
        keys, inv, counts = np.unique(np.stack([idx, level], axis=1), axis=0,
                                      return_inverse=True, return_counts=True)
        inv = inv.ravel()
        centres = keys[:, 0] * float(bin_rpm)

    def mean_of(v: np.ndarray) -> np.ndarray:
        out = np.zeros((len(counts),) + v.shape[1:])
        np.add.at(out, inv, v)
        return out / counts.reshape((-1,) + (1,) * (v.ndim - 1))

    row_load = None
    if load is not None:
        row_load = mean_of(np.where(np.isfinite(load), load, 0.0))
        row_load[keys[:, 1] == _UNKNOWN_LEVEL] = np.nan
    return OrderTable(centres, mean_of(cycles.speed_rpm), counts, mean_of(amp),
                      mean_of(cycles.max_deviation), mean_of(cycles.min_deviation),
                      mean_of(cycles.mean), theta, int(min_cycles), load=row_load)
