"""Where no periodic steady state is stable: what time integration shows (doc/theory.md §9).

A long Newmark run from a given state (usually the unstable periodic solution, slightly
perturbed) is sampled once per engine cycle (a Poincaré section at psi = 0 mod 720 deg) and
resampled on the crank angle cycle by cycle. After the transient:

* the envelope: max and min deviation of the wind-up from its mean over all kept cycles;
* the averaged order amplitudes: |c_n| per cycle (dmf_sim.physics.orders.half_orders), averaged;
* a label from the section points (wind-up w, wind-up rate w') of the kept cycles, scaled by
  the peak-to-peak motion:

  - ``periodic``: the points repeat every k cycles to ``cluster_tol`` over the last third, and
    the difference does not grow with m k cycles (lightly damped gearbox modes keep a small
    residual motion that does not accumulate; a drift along an invariant circle does) (k = 1: a
    720 deg periodic state; k > 1: a state of period k x 720 deg, which the harmonic balance
    with base frequency omega/2 cannot represent);
  - ``long transient``: not yet, but converging (the k-cycle differences of the last third are
    below a tenth of those of the first third);
  - ``quasi-periodic``: the points lie on a closed curve (an invariant circle: a torus in the
    flow): ordered by angle about their centre, the radius is a smooth function of the angle
    (a low-order Fourier fit leaves a residual below ``curve_tol`` of the mean radius);
  - ``chaotic``: none of the above (a cloud).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dmf_sim.core.units import cycle_period_s
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.orders import CYCLE_RAD, ORDER_1_5, ORDER_3, half_orders
from dmf_sim.solvers.newmark import SimulationOptions, simulate

__all__ = ['LABELS', 'NonPeriodicOptions', 'NonPeriodicResult', 'classify_section', 'analyze']

LABELS = ('periodic', 'long transient', 'quasi-periodic', 'chaotic')


@dataclass(frozen=True)
class NonPeriodicOptions:
    """cycles: engine cycles integrated; transient: cycles discarded first; dt: Newmark step [s];
    stride: recording stride [steps]; points_per_cycle: crank-angle resampling; cluster_tol:
    section points that repeat to this share of the motion are periodic; curve_tol: see the
    module doc; max_period: largest k tested for period-k states."""

    cycles: int = 160
    transient: int = 60
    dt: float = 1e-4
    stride: int = 2
    points_per_cycle: int = 256
    cluster_tol: float = 1e-3
    curve_tol: float = 0.1
    max_period: int = 8


@dataclass
class NonPeriodicResult:
    """Time-integration summary at one operating point (wind-up quantities in rad).

    label: one of LABELS; period_cycles: k for a periodic label (cycles of 720 deg) else 0;
    mean, max_deviation, min_deviation: the envelope over the kept cycles; order_3, order_1_5:
    averaged amplitudes over the kept cycles; section: (cycles, 2) Poincaré points (w, w');
    cycles: kept cycles."""

    speed_rpm: float
    label: str
    period_cycles: int
    mean: float
    max_deviation: float
    min_deviation: float
    order_3: float
    order_1_5: float
    section: np.ndarray
    cycles: int

    def describe(self) -> str:
        """The label in words (a periodic label with its period)."""
        if self.label != 'periodic':
            return self.label
        if self.period_cycles == 1:
            return (f'720 deg periodic within {self.cycles} cycles (the unstable periodic state '
                    'drifts too slowly to show, or an attractor harmonic balance did not find)')
        return f'periodic of {self.period_cycles} x 720 deg'

    def as_dict(self) -> dict:
        return {'speed_rpm': float(self.speed_rpm), 'label': self.label,
                'period_cycles': int(self.period_cycles), 'mean': float(self.mean),
                'max_deviation': float(self.max_deviation),
                'min_deviation': float(self.min_deviation), 'order_3': float(self.order_3),
                'order_1_5': float(self.order_1_5), 'cycles': int(self.cycles)}


def _lag_differences(points: np.ndarray, k: int) -> np.ndarray:
    """max over the coordinates of |p[i + k] - p[i]| for every i."""
    return np.abs(points[k:] - points[:-k]).max(axis=1)


def _on_closed_curve(points: np.ndarray, tol: float, n_fourier: int = 6) -> bool:
    """Points on a closed curve around their centre: radius a smooth function of the angle."""
    z = points - points.mean(axis=0)
    z = z / np.maximum(z.std(axis=0), 1e-300)
    ang = np.arctan2(z[:, 1], z[:, 0])
    r = np.hypot(z[:, 0], z[:, 1])
    if len(r) < 4 * n_fourier or r.mean() <= 0:
        return False
    A = np.column_stack([np.ones_like(ang)] + [f(k * ang) for k in range(1, n_fourier + 1)
                                               for f in (np.cos, np.sin)])
    coef, *_ = np.linalg.lstsq(A, r, rcond=None)
    resid = r - A @ coef
    return float(np.sqrt(np.mean(resid ** 2))) < tol * float(r.mean())


def classify_section(points: np.ndarray, scale: np.ndarray,
                     options: NonPeriodicOptions | None = None) -> tuple[str, int]:
    """(label, period k) of Poincaré section points (cycles, 2) after the transient; ``scale``
    (2,): the size of the motion in each coordinate (the peak-to-peak wind-up and rate)."""
    o = options or NonPeriodicOptions()
    z = points / np.maximum(scale, 1e-300)
    third = max(len(z) // 3, 2)
    converging = 0
    for k in range(1, o.max_period + 1):
        if len(z) <= 3 * k + 3:
            break
        d = _lag_differences(z, k)
        if d[-third:].max() <= o.cluster_tol:
            # repeats after k cycles; periodic unless the difference accumulates with the lag (a
            # slow drift along an invariant circle near a k:1 resonance: quasi-periodic)
            m = min(10, (len(z) - third) // k)
            far = _lag_differences(z, m * k)[-third:].max() if m > 1 else 0.0
            if far <= max(2.0 * d[-third:].max(), o.cluster_tol * 1e-3):
                return 'periodic', k
        if not converging and d[-third:].mean() < 0.1 * d[:third].mean():
            converging = k
    if converging:
        return 'long transient', converging
    if _on_closed_curve(points, o.curve_tol):
        return 'quasi-periodic', 0
    return 'chaotic', 0


def analyze(loads: DrivelineExcitation, speed_rpm: float, load: float,
            initial: tuple[np.ndarray, np.ndarray] | None = None,
            options: NonPeriodicOptions | None = None, factors=None) -> NonPeriodicResult:
    """Long Newmark run at constant speed from ``initial`` = (q, v) at psi = 0 (default: the
    static equilibrium), summarized as in the module docstring; ``factors``: per-cylinder
    combustion factors (:func:`dmf_sim.solvers.newmark.simulate`)."""
    o = options or NonPeriodicOptions()
    if not 0 <= o.transient < o.cycles:
        raise ValueError(f'transient={o.transient} must be in [0, cycles={o.cycles})')
    T = float(cycle_period_s(speed_rpm))
    n_steps = int(np.ceil(o.cycles * T / o.dt)) + 2 * o.stride
    res = simulate(loads, speed_rpm, load, t_end=n_steps * o.dt, initial=initial, factors=factors,
                   options=SimulationOptions(dt=o.dt, record_stride=o.stride, chunk_s=1e9))
    e = loads.model.e
    psi, w, wd = res.psi, res.windup, res.v @ e
    first, last = o.transient, o.cycles
    grid = (np.arange(first * o.points_per_cycle, last * o.points_per_cycle)
            * (CYCLE_RAD / o.points_per_cycle))
    samples = np.interp(grid, psi, w).reshape(last - first, o.points_per_cycle)
    c = half_orders(samples, ORDER_3 * 4, 1)
    starts = np.arange(first, last) * CYCLE_RAD
    section = np.column_stack([np.interp(starts, psi, w), np.interp(starts, psi, wd)])
    kept = slice(np.searchsorted(psi, first * CYCLE_RAD), None)
    scale = np.array([np.ptp(w[kept]), np.ptp(wd[kept])])
    label, k = classify_section(section, scale, o)
    mean = float(samples.mean())
    return NonPeriodicResult(float(speed_rpm), label, k, mean, float(samples.max() - mean),
                             float(samples.min() - mean), float(np.abs(c[:, ORDER_3]).mean()),
                             float(np.abs(c[:, ORDER_1_5]).mean()), section, last - first)
