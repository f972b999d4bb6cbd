"""Angle-domain resampling and half orders per engine cycle (steps 3-4 of the bag analysis).

:func:`angle_cycle_orders` is the ROS-free core shared by ``dmf-sim analyze`` and the live
node's per-cycle orders: from samples of (crank angle psi, signal x) it takes every whole engine
cycle -- psi from k 4 pi to (k+1) 4 pi (720 deg), so phases refer to the engine's crank angle --
interpolates x(psi) with a cubic spline onto ``points_per_cycle`` uniform angles and computes
the half orders ``x(psi) = Re(sum_n c_n exp(i n psi/2))``
(:func:`dmf_sim.physics.orders.half_orders`)
and the paper's Fig. 13 quantities (:func:`dmf_sim.physics.orders.fig13_rows`). A speed ramp does
not smear the orders, whatever the ramp rate.

For a recording, :func:`cycle_orders` first gives each signal sample its crank angle (linear
interpolation of psi(t); samples published together with a crank-angle sample but stamped with
receive-time jitter take that sample's angle, see :func:`_psi_at`), splits the data at gaps
(lost messages, a truncated tail) and runs :func:`angle_cycle_orders` on each piece, block by
block of ``BLOCK_CYCLES`` cycles.

Same numbers live and offline: a cubic spline's dependence on data m knots away decays like
0.27**m, so blocks (here) and live windows (dmf_sim.monitor.orders) that carry ``EDGE_SAMPLES`` =
32 samples beyond a cycle's ends give the orders of a spline through the whole recording to
rounding (tested).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from dmf_sim.core.errors import ConfigError
from dmf_sim.physics.orders import CYCLE_RAD, ORDER_1_5, ORDER_3, fig13_rows, half_orders

__all__ = ['GAP_FACTOR', 'EDGE_SAMPLES', 'CycleOrders', 'angle_cycle_orders', 'cycle_orders']

GAP_FACTOR = 5.0          # a time step > GAP_FACTOR x the median step is a gap (segment break)
EDGE_SAMPLES = 32         # samples beyond a cycle's ends that make its spline edge-independent
BLOCK_CYCLES = 64         # cycles resampled per spline (bounds the memory of long recordings)
_PAIRING_JITTER = 0.3     # a signal stamp within this fraction of a step of a crank stamp pairs
_SECONDS_PER_CYCLE_RPM = 120.0   # one 720 deg cycle lasts 120 / speed[rpm] seconds


@dataclass
class CycleOrders:
    """Half-order analysis per engine cycle (rows = cycles).

    Attributes:
        t_start, t_end: cycle start/end [s] (from the first crank-angle sample of a bag; NaN
            without sample times).
        psi_start: crank angle at the cycle start [rad] (a multiple of 4 pi).
        speed_rpm: mean speed of the cycle, 120 / duration (NaN without sample times).
        coeffs: (n_cycles, n_max + 1) complex c_n (NaN at or above the recording's Nyquist
            frequency).
        mean, max_deviation, min_deviation: per cycle, in the signal's unit.
        samples: (n_cycles, points_per_cycle) the resampled signal, if asked for.
    """

    t_start: np.ndarray
    t_end: np.ndarray
    psi_start: np.ndarray
    speed_rpm: np.ndarray
    coeffs: np.ndarray
    mean: np.ndarray
    max_deviation: np.ndarray
    min_deviation: np.ndarray
    samples: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.psi_start)

    @property
    def order_3(self) -> np.ndarray:
        """Amplitude of the 3rd engine order per cycle."""
        return np.abs(self.coeffs[:, ORDER_3])

    @property
    def order_1_5(self) -> np.ndarray:
        """Amplitude of the 1.5th engine order per cycle."""
        return np.abs(self.coeffs[:, ORDER_1_5])

    @classmethod
    def empty(cls, n_max: int) -> CycleOrders:
        z = np.zeros(0)
        return cls(z, z, z, z, np.zeros((0, n_max + 1), complex), z, z, z)

    def select(self, keep: np.ndarray) -> CycleOrders:
        """The cycles where ``keep`` (bool mask or indices)."""
        return CycleOrders(*(None if getattr(self, f.name) is None else getattr(self, f.name)[keep]
                             for f in fields(self)))

    @classmethod
    def concatenate(cls, parts: list[CycleOrders], n_max: int) -> CycleOrders:
        if not parts:
            return cls.empty(n_max)
        return cls(*(None if any(getattr(p, f.name) is None for p in parts)
                     else np.concatenate([getattr(p, f.name) for p in parts])
                     for f in fields(cls)))


def _check_grid(points_per_cycle: int, n_max: int) -> None:
    if not (isinstance(n_max, (int, np.integer)) and n_max >= ORDER_3):
        raise ConfigError(f'n_max={n_max!r} must be an integer >= {ORDER_3} (the 3rd order)')
    if points_per_cycle < 2 * n_max + 2:
        raise ConfigError(f'points_per_cycle={points_per_cycle} must be >= 2 n_max + 2 = '
                          f'{2 * n_max + 2}')


def angle_cycle_orders(psi: np.ndarray, x: np.ndarray, *, t_s: np.ndarray | None = None,
                       points_per_cycle: int = 256, n_max: int = 24,
                       sample_rate_hz: float | None = None,
                       keep_samples: bool = False) -> CycleOrders:
    """Half orders and Fig. 13 quantities of every whole engine cycle in (psi, x) samples.

    Args:
        psi: crank angle [rad], continuous (not wrapped) and strictly increasing.
        x: the signal at those angles (any unit).
        t_s: sample times [s], optional: cycle start/end times and speed 120/duration [rpm].
        points_per_cycle: uniform crank-angle grid per 720 deg cycle (>= 2 n_max + 2).
        n_max: highest half-order index n (order n/2) computed.
        sample_rate_hz: the signal's sample rate; orders at or above its Nyquist frequency at a
            cycle's speed are NaN (default: from ``t_s``; None without times: no check).
        keep_samples: also return the resampled signal (e.g. for the share of each spring
            region over the cycle).

    Cycles are [k 4 pi, (k+1) 4 pi) lying wholly inside [psi[0], psi[-1]].
    """
    _check_grid(points_per_cycle, n_max)
    psi = np.asarray(psi, dtype=float)
    x = np.asarray(x, dtype=float)
    if psi.shape != x.shape or psi.ndim != 1:
        raise ConfigError(f'psi and x must be 1-d arrays of one length, got {psi.shape} and '
                          f'{x.shape}')
    if len(psi) < 4:
        return CycleOrders.empty(n_max)
    if not np.all(np.diff(psi) > 0):
        raise ConfigError('crank angle psi must be strictly increasing (unwrapped)')
    k0 = math.ceil(psi[0] / CYCLE_RAD - 1e-12)
    k1 = math.floor(psi[-1] / CYCLE_RAD + 1e-12)
    if k1 <= k0:
        return CycleOrders.empty(n_max)
    from scipy.interpolate import CubicSpline

    starts = np.arange(k0, k1) * CYCLE_RAD
    grid = np.arange(points_per_cycle) * (CYCLE_RAD / points_per_cycle)
    samples = CubicSpline(psi, x)((starts[:, None] + grid).ravel()).reshape(len(starts), -1)
    c = half_orders(samples, n_max)
    nan = np.full(len(starts), np.nan)
    t_start, t_end, speed = nan, nan.copy(), nan.copy()
    if t_s is not None:
        t_s = np.asarray(t_s, dtype=float)
        edges = np.interp(np.append(starts, k1 * CYCLE_RAD), psi, t_s)
        t_start, t_end = edges[:-1], edges[1:]
        speed = _SECONDS_PER_CYCLE_RPM / (t_end - t_start)
        if sample_rate_hz is None and len(t_s) > 1:
            sample_rate_hz = 1.0 / float(np.median(np.diff(t_s)))
    if sample_rate_hz is not None and sample_rate_hz > 0 and t_s is not None:
        # half-order n is resolved while n/2 * speed/60 < fs/2
        n = np.arange(n_max + 1)
        c[n[None, :] * speed[:, None] / _SECONDS_PER_CYCLE_RPM >= sample_rate_hz / 2.0] = np.nan
    q = fig13_rows(c, samples)
    return CycleOrders(t_start, t_end, starts, speed, c, q['mean'], q['max_deviation'],
                       q['min_deviation'], samples if keep_samples else None)


def _segments(breaks: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges [a, b) between break positions (break i sits between samples i and i+1)."""
    cuts = np.flatnonzero(breaks) + 1
    bounds = np.concatenate(([0], cuts, [len(breaks) + 1]))
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


def _psi_at(ts: np.ndarray, tc: np.ndarray, psi_c: np.ndarray) -> tuple[np.ndarray, int]:
    """Crank angle at the signal time stamps ``ts`` [s] from crank samples (tc, psi_c).

    Linear interpolation in time, except where the signal and the crank angle are sampled
    together (same rate, e.g. the node publishes both per simulation sample) but their stamps
    differ by receive-time jitter (``ros2 bag record`` log times): then a signal sample takes the
    crank angle of the crank sample nearest in time, when that one is within 30 % of the sample
    interval -- interpolating between jittered stamps would add phase noise. Returns (psi, number
    of paired samples)."""
    psi = np.interp(ts, tc, psi_c)
    if len(ts) < 3 or len(tc) < 3:
        return psi, 0
    dt_s, dt_c = float(np.median(np.diff(ts))), float(np.median(np.diff(tc)))
    if not (dt_c > 0 and abs(dt_s / dt_c - 1.0) < 0.01):
        return psi, 0
    j = np.clip(np.searchsorted(tc, ts), 1, len(tc) - 1)
    j -= (ts - tc[j - 1]) < (tc[j] - ts)
    dist = np.abs(ts - tc[j])
    if np.median(dist) > 0.1 * dt_c or not dist.any():
        return psi, 0          # identical stamps (interpolation is exact) or a real time offset
    near = dist < _PAIRING_JITTER * dt_c
    psi[near] = psi_c[j[near]]
    return psi, int(near.sum())


def cycle_orders(t_ns: np.ndarray, x: np.ndarray, crank_t_ns: np.ndarray,
                 crank_psi: np.ndarray, *, points_per_cycle: int = 256, n_max: int = 24,
                 t0_ns: int | None = None) -> CycleOrders:
    """Resample a recorded ``x(t)`` on the crank angle and analyse every whole cycle.

    ``t_ns``: signal time stamps [ns] (sorted); ``crank_t_ns``, ``crank_psi``: the crank angle
    series (psi increasing); ``t0_ns``: time origin of the cycle times (default: first crank
    sample).
    """
    _check_grid(points_per_cycle, n_max)
    t0 = int(crank_t_ns[0] if t0_ns is None else t0_ns)
    tc = (np.asarray(crank_t_ns) - t0) * 1e-9
    psi_c = np.asarray(crank_psi, dtype=float)
    ts = (np.asarray(t_ns) - t0) * 1e-9
    x = np.asarray(x, dtype=float)
    inside = np.isfinite(x) & (ts >= tc[0]) & (ts <= tc[-1])
    ts, x = ts[inside], x[inside]
    if len(ts) < 4:
        return CycleOrders.empty(n_max)
    # gaps: of the signal, or of the crank angle around a signal sample
    dts, dtc = np.diff(ts), np.diff(tc)
    thr_s = GAP_FACTOR * float(np.median(dts))
    thr_c = GAP_FACTOR * float(np.median(dtc)) if len(dtc) else 0.0
    j = np.clip(np.searchsorted(tc, ts, side='right') - 1, 0, max(len(tc) - 2, 0))
    crank_gap = dtc[j] > thr_c if len(dtc) else np.zeros(len(ts), bool)
    psi, _ = _psi_at(ts, tc, psi_c)
    breaks = (dts > thr_s) | (np.diff(psi) <= 0) | crank_gap[1:] | crank_gap[:-1]
    fs = 1.0 / float(np.median(dts)) if np.median(dts) > 0 else None
    parts = [angle_cycle_orders(psi[lo:hi], x[lo:hi], t_s=ts[lo:hi],
                                points_per_cycle=points_per_cycle, n_max=n_max,
                                sample_rate_hz=fs)
             for a, b in _segments(breaks) if b - a >= 4
             for lo, hi in _blocks(psi[a:b], a)]
    return CycleOrders.concatenate([p for p in parts if len(p)], n_max)


def _blocks(psi: np.ndarray, offset: int) -> list[tuple[int, int]]:
    """Sample ranges holding ``BLOCK_CYCLES`` whole cycles each (plus EDGE_SAMPLES on both
    sides, within the segment): one spline per block, so memory does not grow with the
    recording and every cycle gets the same numbers as from a spline over the whole segment."""
    k0 = math.ceil(psi[0] / CYCLE_RAD - 1e-12)
    k1 = math.floor(psi[-1] / CYCLE_RAD + 1e-12)
    out = []
    for k in range(k0, k1, BLOCK_CYCLES):
        lo = int(np.searchsorted(psi, k * CYCLE_RAD)) - EDGE_SAMPLES
        hi = int(np.searchsorted(psi, min(k + BLOCK_CYCLES, k1) * CYCLE_RAD)) + EDGE_SAMPLES
        out.append((offset + max(lo, 0), offset + min(hi, len(psi))))
    return out
