"""Live order analysis of the DMF wind-up, one result per completed engine cycle (no ROS).

The node hands every chunk of published samples (:class:`dmf_sim.live.simulation.Samples`: stamps,
crank angle psi, wind-up) to a :class:`CycleOrderTracker`; whenever the crank angle has passed the
end of an engine cycle (720 deg = 4 pi rad, cycles starting at whole multiples of 4 pi as in
``dmf-sim analyze``) :meth:`CycleOrderTracker.collect` returns a :class:`CycleWindow` and
:func:`analyze_window` (in a worker, see :mod:`dmf_sim.monitor.worker`; or both at once with
:meth:`CycleOrderTracker.add`) gives that cycle's :class:`CycleResult`:

* the paper's Fig. 13 quantities of the wind-up (:class:`dmf_sim.physics.orders.OrderSummary`):
3rd and
  1.5th order amplitude, max/min deviation from the cycle mean, the mean, mean - theta, the
  static wind-up of the mean torque and theta - static wind-up (the paper's green line);
* the share of the cycle's samples in each spring region (``spring.stage``, named by
  ``spring.region_name``), i.e. the share of the cycle's time;
* the cycle's engine speed (120 / cycle duration, as the bag analysis) and its mean load.

Same numbers as the bag analysis: the orders come from
:func:`dmf_sim.analysis.cycle_orders.cycle_orders`,
the function ``dmf-sim analyze`` applies to a recording (cubic spline over the crank angle, 256
points per cycle, FFT scaled by :mod:`dmf_sim.physics.orders`' convention). The tracker passes it
the samples of the cycle plus :data:`MARGIN_SAMPLES` samples on either side; a cubic spline's
dependence on data ``m`` knots away decays like 0.27**m, so with 32 samples of margin the result
equals the analysis of the whole recording to rounding (tested). Give the tracker the stamps the
node publishes (``stamps_ns``) so a skip-ahead after an overrun (a gap in the stamps) drops the
cycle across the gap exactly as the bag analysis does.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.interpolate  # noqa: F401  (loaded now, not on the first cycle of a live run)

from dmf_sim.analysis.cycle_orders import EDGE_SAMPLES, cycle_orders
from dmf_sim.core.units import CYCLE_RAD
from dmf_sim.physics.orders import ORDER_1_5, ORDER_3, OrderSummary

__all__ = ['MARGIN_SAMPLES', 'CycleResult', 'CycleWindow', 'CycleOrderTracker', 'analyze_window',
           'region_key']

MARGIN_SAMPLES = EDGE_SAMPLES   # samples kept before and after a cycle for the spline (see above)
POINTS_PER_CYCLE = 256       # crank-angle grid per cycle: the bag analysis' default
N_MAX = 24                   # highest half-order index: the bag analysis' default
_INITIAL_CAPACITY = 4096     # samples; the buffer doubles when needed


def region_key(name: str) -> str:
    """Message key of a spring region's share: 'share_primary', 'share_drive_stage_2', ..."""
    return 'share_' + name.replace(' ', '_')


@dataclass(frozen=True)
class CycleResult:
    """Order analysis of one completed engine cycle of the DMF wind-up (SI, speed in rpm).

    Attributes:
        index: cycle number k (crank angle 4 pi k .. 4 pi (k + 1)).
        t_start_s, t_end_s: cycle start and end [s] on the stamps given to the tracker.
        speed_rpm: 120 / cycle duration; load: mean load fraction over the cycle's samples.
        summary: Fig. 13 quantities of the wind-up [rad] (:class:`OrderSummary`).
        region_share: spring region name -> share of the cycle's samples in it (sums to 1).
        coeffs: complex half-order coefficients c_0..c_N of the wind-up [rad].
    """

    index: int
    t_start_s: float
    t_end_s: float
    speed_rpm: float
    load: float
    summary: OrderSummary
    region_share: dict[str, float]
    coeffs: np.ndarray = field(repr=False)

    @property
    def max_windup(self) -> float:
        """Largest wind-up of the cycle [rad] (mean + max deviation, on the analysis grid)."""
        return self.summary.mean + self.summary.max_deviation

    @property
    def min_windup(self) -> float:
        """Smallest wind-up of the cycle [rad]."""
        return self.summary.mean + self.summary.min_deviation

    @property
    def stamp_ns(self) -> int:
        """End of the cycle as a stamp [ns] (the message header of this result)."""
        return int(round(self.t_end_s * 1e9))

    def values(self) -> dict[str, float]:
        """Quantity name (with unit suffix) -> value: what the per-cycle message carries."""
        s = self.summary
        out = {'cycle': float(self.index), 'cycle_duration_s': self.t_end_s - self.t_start_s,
               'speed_rpm': self.speed_rpm, 'load': self.load,
               'order_3_rad': s.order_3, 'order_1_5_rad': s.order_1_5,
               'max_deviation_rad': s.max_deviation, 'min_deviation_rad': s.min_deviation,
               'mean_rad': s.mean, 'mean_minus_theta_rad': s.mean_minus_theta,
               'static_windup_rad': s.static_windup,
               'theta_minus_static_rad': s.theta_minus_static,
               'max_windup_rad': self.max_windup, 'min_windup_rad': self.min_windup}
        out.update({region_key(name): share for name, share in self.region_share.items()})
        return out


@dataclass(frozen=True)
class CycleWindow:
    """Samples around completed cycles, ready for :func:`analyze_window` (picklable: the node
    may analyse it in a worker). Cycles ``first_cycle .. end_cycle - 1`` are reported.

    Attributes:
        t_ns: stamps [ns]; psi: crank angle [rad]; windup [rad]; load: load fraction per sample.
        first_cycle, end_cycle: cycle numbers to report; spring: the DMF spring of the run.
    """

    t_ns: np.ndarray
    psi: np.ndarray
    windup: np.ndarray
    load: np.ndarray
    first_cycle: int
    end_cycle: int
    spring: object


def analyze_window(window: CycleWindow, static_windup: Callable[[float, float], float] | None
                   = None, *, points_per_cycle: int = POINTS_PER_CYCLE,
                   n_max: int = N_MAX) -> list[CycleResult]:
    """Order analysis of the window's cycles (:func:`dmf_sim.analysis.cycle_orders.cycle_orders`,
    the bag
    analysis' function); cycles across a gap in the stamps are left out, as in the bag analysis.
    ``static_windup(speed_rpm, load)`` [rad] gives the static wind-up of the mean torque."""
    t, psi, w = window.t_ns, window.psi, window.windup
    cyc = cycle_orders(t, w, t, psi, points_per_cycle=points_per_cycle, n_max=n_max,
                       t0_ns=int(t[0]))
    spring = window.spring
    regions = [(st, spring.region_name(st)) for st in spring.stages()]
    theta = float(spring.theta)
    t0_ns = int(t[0])
    rel = (t - t0_ns) * 1e-9
    out = []
    for i in range(len(cyc)):
        k = int(round(cyc.psi_start[i] / CYCLE_RAD))
        if not window.first_cycle <= k < window.end_cycle:
            continue
        speed = float(cyc.speed_rpm[i])
        inside = (rel >= cyc.t_start[i]) & (rel < cyc.t_end[i])
        load = float(np.mean(window.load[inside]))
        stages = np.asarray(spring.stage(w[inside]))
        count = int(inside.sum())
        share = {name: float(np.count_nonzero(stages == st)) / count for st, name in regions}
        c = np.array(cyc.coeffs[i])
        mean = float(cyc.mean[i])
        static = float(static_windup(speed, load)) if static_windup is not None else math.nan
        summary = OrderSummary(order_3=float(abs(c[ORDER_3])), order_1_5=float(abs(c[ORDER_1_5])),
                               max_deviation=float(cyc.max_deviation[i]),
                               min_deviation=float(cyc.min_deviation[i]), mean=mean,
                               mean_minus_theta=mean - theta, static_windup=static, theta=theta)
        out.append(CycleResult(k, t0_ns * 1e-9 + float(cyc.t_start[i]),
                               t0_ns * 1e-9 + float(cyc.t_end[i]), speed, load, summary, share, c))
    return out


class CycleOrderTracker:
    """Collects published samples into windows of completed engine cycles.

    Args:
        spring: the DMF spring (:class:`dmf_sim.physics.spring.PiecewiseLinearSpring`): theta and
        the
            regions.
        static_windup: ``f(speed_rpm, load) -> static wind-up [rad]`` of the mean torque (e.g.
            ``lambda s, l: loads.static_state(s, l).windup``), used by :meth:`add`; None: NaN.

    :meth:`collect` is the cheap part (a few microseconds per chunk: copy into a buffer, compare
    the crank angle with the next cycle end) and returns a :class:`CycleWindow` when cycles
    completed; :func:`analyze_window` (about 1 ms per cycle) can then run anywhere.
    :meth:`add` does both. :meth:`set_spring` after a DMF change; :meth:`clear` drops the samples.
    """

    def __init__(self, spring, static_windup: Callable[[float, float], float] | None = None
                 ) -> None:
        self.spring = spring
        self.static_windup = static_windup
        self._t = np.zeros(_INITIAL_CAPACITY, dtype=np.int64)
        self._psi = np.zeros(_INITIAL_CAPACITY)
        self._w = np.zeros(_INITIAL_CAPACITY)
        self._load = np.zeros(_INITIAL_CAPACITY)
        self._n = 0
        self._next_cycle: int | None = None     # number of the next cycle to report

    def set_spring(self, spring, static_windup: Callable[[float, float], float] | None = None
                   ) -> None:
        """Use another spring (and static wind-up function) from the next window on."""
        self.spring = spring
        self.static_windup = static_windup

    def clear(self) -> None:
        """Forget the collected samples (the next cycle starts after the next sample)."""
        self._n = 0
        self._next_cycle = None

    # ---- collecting ----------------------------------------------------------------------------
    def _append(self, t_ns: np.ndarray, psi: np.ndarray, w: np.ndarray, load: float) -> None:
        m = len(t_ns)
        need = self._n + m
        if need > len(self._t):
            cap = max(need, 2 * len(self._t))
            for name in ('_t', '_psi', '_w', '_load'):
                old = getattr(self, name)
                new = np.zeros(cap, dtype=old.dtype)
                new[:self._n] = old[:self._n]
                setattr(self, name, new)
        sl = slice(self._n, need)
        self._t[sl] = t_ns
        self._psi[sl] = psi
        self._w[sl] = w
        self._load[sl] = load
        self._n = need

    def _samples_after(self, angle: float) -> int:
        return self._n - int(np.searchsorted(self._psi[:self._n], angle, side='right'))

    def collect(self, samples, load: float, stamps_ns=None) -> CycleWindow | None:
        """Add a chunk of samples (``samples.t`` [s], ``.psi`` [rad], ``.windup`` [rad]) taken
        at load fraction ``load``; ``stamps_ns``: their published stamps [ns] (default
        ``round(t * 1e9)``). Returns a window when cycles completed (with :data:`MARGIN_SAMPLES`
        samples after them), else None."""
        if len(samples.t) == 0:
            return None
        t_ns = (np.round(np.asarray(samples.t, dtype=float) * 1e9).astype(np.int64)
                if stamps_ns is None else np.asarray(stamps_ns, dtype=np.int64))
        self._append(t_ns, samples.psi, samples.windup, float(load))
        if self._next_cycle is None:
            self._next_cycle = math.ceil(self._psi[0] / CYCLE_RAD - 1e-12)
        first = end = self._next_cycle
        if self._psi[self._n - 1] < (end + 1) * CYCLE_RAD:
            return None
        while self._samples_after((end + 1) * CYCLE_RAD) >= MARGIN_SAMPLES:
            end += 1
        if end == first:
            return None
        n = self._n
        window = CycleWindow(self._t[:n].copy(), self._psi[:n].copy(), self._w[:n].copy(),
                             self._load[:n].copy(), first, end, self.spring)
        keep = max(int(np.searchsorted(self._psi[:n], end * CYCLE_RAD)) - MARGIN_SAMPLES, 0)
        for arr in (self._t, self._psi, self._w, self._load):
            arr[:n - keep] = arr[keep:n]
        self._n = n - keep
        self._next_cycle = end
        return window

    def add(self, samples, load: float, stamps_ns=None) -> list[CycleResult]:
        """:meth:`collect` and :func:`analyze_window` in one call: the cycles completed by this
        chunk (usually none or one)."""
        window = self.collect(samples, load, stamps_ns)
        return [] if window is None else analyze_window(window, self.static_windup)
