"""Half-order analysis of a signal over the crank angle (shared by Newmark, bag analysis, HBM).

A periodic steady state over one engine cycle (720 deg = 4 pi rad of crank angle psi) is written

    x(psi) = Re( sum_{n=0}^{N} c_n exp(i n psi / 2) )                 (same form as eq. 16)

so |c_n| is the amplitude of engine order n/2 (n = 6: 3rd order, n = 3: 1.5th order).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CYCLE_RAD = 4.0 * np.pi   # one four-stroke engine cycle of crank angle


def resample_on_angle(psi: np.ndarray, x: np.ndarray, psi_start: float, n_cycles: int,
                      points_per_cycle: int = 256) -> np.ndarray:
    """Linear interpolation of x(psi) on a uniform crank-angle grid of whole cycles."""
    grid = psi_start + np.arange(n_cycles * points_per_cycle) * (CYCLE_RAD / points_per_cycle)
    if grid[-1] > psi[-1] + 1e-12 or grid[0] < psi[0] - 1e-12:
        raise ValueError('not enough crank angle recorded for the requested cycles')
    return np.interp(grid, psi, x)


def half_order_coefficients(samples: np.ndarray, n_cycles: int, n_max: int) -> np.ndarray:
    """Complex c_n, n = 0..n_max, from ``samples`` uniform over ``n_cycles`` whole cycles."""
    M = samples.shape[-1]
    X = np.fft.rfft(samples, axis=-1) / M
    idx = np.arange(n_max + 1) * n_cycles
    if idx[-1] >= X.shape[-1]:
        raise ValueError(f'n_max={n_max} too high for {M} samples over {n_cycles} cycles')
    c = X[..., idx] * 2.0
    c[..., 0] = X[..., 0].real
    return c


@dataclass(frozen=True)
class OrderSummary:
    """The paper's Fig. 13 quantities for a wind-up signal [rad]."""

    order_3: float          # amplitude of the 3rd engine order [rad]
    order_1_5: float        # amplitude of the 1.5th engine order [rad]
    max_deviation: float    # max(w) - mean(w) [rad]
    min_deviation: float    # min(w) - mean(w) [rad]
    mean: float             # mean(w) [rad]
    mean_minus_theta: float  # mean(w) - theta [rad]

    def as_dict(self) -> dict:
        return {k: float(v) for k, v in self.__dict__.items()}


def summarize(samples: np.ndarray, n_cycles: int, theta: float, n_max: int = 24) -> OrderSummary:
    c = half_order_coefficients(samples, n_cycles, n_max)
    mean = float(np.mean(samples))
    return OrderSummary(order_3=float(abs(c[6])), order_1_5=float(abs(c[3])),
                        max_deviation=float(samples.max() - mean),
                        min_deviation=float(samples.min() - mean), mean=mean,
                        mean_minus_theta=mean - theta)
