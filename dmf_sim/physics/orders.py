"""Half orders of a signal over the engine cycle, and the paper's Fig. 13 quantities (one place).

A periodic signal over one engine cycle (720 deg = 4 pi rad of crank angle psi) is written

    x(psi) = Re( sum_{n=0}^{N} c_n exp(i n psi / 2) )                 (same form as eq. 16)

so |c_n| is the amplitude of engine order n/2 (n = 6: 3rd order, n = 3: 1.5th order) and c_0 is
the (real) mean. :func:`half_orders` computes c_n from uniform samples over whole cycles (FFT
divided by the number of samples, doubled for n >= 1, c_0 real), :func:`synthesize` is its
inverse on one cycle. Every solver and every analysis (Newmark, harmonic balance, bag analysis,
the live node's per-cycle orders) uses these two and :func:`summarize_orders`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.units import CYCLE_RAD

__all__ = ['CYCLE_RAD', 'ORDER_3', 'ORDER_1_5', 'resample_on_angle', 'half_orders',
           'half_order_coefficients', 'synthesize', 'OrderSummary', 'fig13_rows',
           'summarize_orders', 'summarize_rows', 'summarize']

ORDER_3 = 6      # half-order index of the 3rd engine order (the main firing order of a six)
ORDER_1_5 = 3    # half-order index of the 1.5th engine order (the DMF's sub-harmonic)


def resample_on_angle(psi: np.ndarray, x: np.ndarray, psi_start: float, n_cycles: int,
                      points_per_cycle: int = 256) -> np.ndarray:
    """Linear interpolation of x(psi) on a uniform crank-angle grid of whole cycles."""
    grid = psi_start + np.arange(n_cycles * points_per_cycle) * (CYCLE_RAD / points_per_cycle)
    if grid[-1] > psi[-1] + 1e-12 or grid[0] < psi[0] - 1e-12:
        raise ValueError('not enough crank angle recorded for the requested cycles')
    return np.interp(grid, psi, x)


def half_orders(samples: np.ndarray, n_max: int, n_cycles: int = 1) -> np.ndarray:
    """Complex c_n, n = 0..n_max, from ``samples`` uniform over ``n_cycles`` whole cycles
    (last axis; leading axes are independent signals, e.g. one row per cycle)."""
    samples = np.asarray(samples, dtype=float)
    M = samples.shape[-1]
    X = np.fft.rfft(samples, axis=-1) / M
    idx = np.arange(n_max + 1) * n_cycles
    if idx[-1] >= X.shape[-1]:
        raise ConfigError(f'n_max={n_max} too high for {M} samples over {n_cycles} cycles '
                          f'(need at most {(X.shape[-1] - 1) // n_cycles})')
    c = X[..., idx] * 2.0
    c[..., 0] = X[..., 0].real
    return c


def half_order_coefficients(samples: np.ndarray, n_cycles: int, n_max: int) -> np.ndarray:
    """:func:`half_orders` with the argument order of earlier releases."""
    return half_orders(samples, n_max, n_cycles)


def synthesize(c: np.ndarray, n_samples: int) -> np.ndarray:
    """x(psi) on ``n_samples`` uniform points of one cycle (psi = 0 .. 4 pi, end excluded) from
    half-order coefficients c (..., N+1): the inverse of :func:`half_orders`."""
    c = np.asarray(c, dtype=complex)
    spec = np.zeros(c.shape[:-1] + (n_samples // 2 + 1,), dtype=complex)
    k = min(c.shape[-1] - 1, n_samples // 2 - 1)
    spec[..., 0] = c[..., 0].real * n_samples
    spec[..., 1:k + 1] = c[..., 1:k + 1] * (n_samples / 2.0)
    return np.fft.irfft(spec, n_samples, axis=-1)


def fig13_rows(c: np.ndarray, samples: np.ndarray) -> dict[str, np.ndarray]:
    """The paper's Fig. 13 quantities of one cycle or of rows of cycles: ``c`` (..., N+1) half
    orders and ``samples`` (..., M) the signal over each row's cycle(s). Returns order_3,
    order_1_5, mean, max_deviation, min_deviation (the mean is c_0), arrays of shape (...)."""
    c = np.asarray(c)
    samples = np.asarray(samples, dtype=float)
    mean = c[..., 0].real.astype(float)
    n = c.shape[-1]
    return {'order_3': np.abs(c[..., ORDER_3]) if n > ORDER_3 else np.zeros(c.shape[:-1]),
            'order_1_5': np.abs(c[..., ORDER_1_5]) if n > ORDER_1_5 else np.zeros(c.shape[:-1]),
            'mean': mean,
            'max_deviation': samples.max(axis=-1) - mean,
            'min_deviation': samples.min(axis=-1) - mean}


@dataclass(frozen=True)
class OrderSummary:
    """The paper's Fig. 13 quantities of a wind-up signal [rad].

    ``mean_minus_theta`` is the dynamic mean minus the first knee theta; ``static_windup`` the
    wind-up the mean torque alone causes (NaN where unknown), so ``theta_minus_static`` is the
    paper's green line: above both max/min deviation lines the wind-up stays in the primary
    region, below both in the secondary one, between them it crosses the knee.
    """

    order_3: float          # amplitude of the 3rd engine order [rad]
    order_1_5: float        # amplitude of the 1.5th engine order [rad]
    max_deviation: float    # max(w) - mean(w) [rad]
    min_deviation: float    # min(w) - mean(w) [rad]
    mean: float             # mean(w) [rad]
    mean_minus_theta: float  # mean(w) - theta [rad]
    static_windup: float = math.nan   # static wind-up of the mean torque [rad]
    theta: float = math.nan           # the first knee [rad]

    @property
    def theta_minus_static(self) -> float:
        """theta - static wind-up [rad] (the paper's green line; NaN where unknown)."""
        return self.theta - self.static_windup

    def as_dict(self) -> dict:
        d = {k: float(v) for k, v in self.__dict__.items() if k != 'theta'}
        d['theta_minus_static'] = float(self.theta_minus_static)
        return d


def summarize_orders(c: np.ndarray, samples: np.ndarray, theta: float,
                     static_windup: float = math.nan) -> OrderSummary:
    """Fig. 13 summary of one signal from its half orders ``c`` and its ``samples`` over whole
    cycles; ``theta`` the first knee [rad], ``static_windup`` [rad] if known."""
    c = np.asarray(c)
    if c.ndim == 1:       # one signal (every sweep point): the same values, in scalar arithmetic
        n = c.shape[0]
        mean = float(c[0].real)
        samples = np.asarray(samples, dtype=float)
        return OrderSummary(order_3=float(np.abs(c[ORDER_3])) if n > ORDER_3 else 0.0,
                            order_1_5=float(np.abs(c[ORDER_1_5])) if n > ORDER_1_5 else 0.0,
                            max_deviation=float(samples.max()) - mean,
                            min_deviation=float(samples.min()) - mean, mean=mean,
                            mean_minus_theta=mean - theta, static_windup=float(static_windup),
                            theta=float(theta))
    return summarize_rows(np.reshape(c, (1, -1)), np.reshape(samples, (1, -1)), theta,
                          [static_windup])[0]


def summarize_rows(c: np.ndarray, samples: np.ndarray, theta: float,
                   static_windups) -> list[OrderSummary]:
    """:func:`summarize_orders` of K signals at once: half orders ``c`` (K, N+1), ``samples``
    (K, M) each over whole cycles, ``static_windups`` (K,) [rad]; the same values."""
    r = fig13_rows(c, samples)
    theta = float(theta)
    return [OrderSummary(order_3=o3, order_1_5=o15, max_deviation=mx, min_deviation=mn, mean=mean,
                         mean_minus_theta=mean - theta, static_windup=float(st), theta=theta)
            for o3, o15, mx, mn, mean, st in zip(
                r['order_3'].tolist(), r['order_1_5'].tolist(), r['max_deviation'].tolist(),
                r['min_deviation'].tolist(), r['mean'].tolist(), static_windups)]


def summarize(samples: np.ndarray, n_cycles: int, theta: float, n_max: int = 24,
              static_windup: float = math.nan) -> OrderSummary:
    """Fig. 13 summary of ``samples`` uniform over ``n_cycles`` whole cycles."""
    return summarize_orders(half_orders(samples, n_max, n_cycles), samples, theta, static_windup)
