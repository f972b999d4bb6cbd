"""The DMF wind-up from the two tooth wheels around it, against the true wind-up (no ROS).

With a tooth wheel on the primary and one on the secondary flywheel (both turning with the
crank, ratio 1), the edge angles (T1) of :mod:`dmf_sim.analysis.tooth_signals` give each
flywheel's absolute angle at its own edge times. The wind-up is their difference,

    phi(t_k) = (theta_P(t_k) - offset_P) - (theta_S(t_k) - offset_S)                (W1)

at the primary wheel's edge times t_k, theta_S there from the cubic spline of the secondary's
edges (their angle is smooth between teeth: the secondary is the heavy side of the DMF). The
two wheels' revolution counts are made to agree by the whole revolutions that bring the median
of (W1) nearest to zero (a wind-up is far below half a revolution). (W1) has the sign of the
bag's ``driveline/dmf_windup`` (primary minus secondary), which is the truth it is scored
against: the peak-to-peak of both over the same time span, and the rms of their difference.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from dmf_sim.analysis.tooth_signals import (
    edge_angles,
    learn_pitch_errors,
    read_float64,
    read_wheel_edges,
)
from dmf_sim.bags.layout import BagFiles, resolve_bag
from dmf_sim.bags.metadata import RunMetadata

__all__ = ['PITCH_MODES', 'WINDUP_TOPIC', 'WindupEstimate', 'estimate_windup', 'windup_from_bag']

PITCH_MODES = ('given', 'learned', 'none')
WINDUP_TOPIC = 'driveline/dmf_windup'


@dataclass(frozen=True)
class WindupEstimate:
    """Wind-up from the sensors against the truth over the same span (times [s] from the
    primary wheel's first edge, angles [rad]); ``rel_err`` = |p2p_est - p2p_true| / p2p_true."""

    t_s: np.ndarray
    windup_rad: np.ndarray
    true_t_s: np.ndarray
    true_rad: np.ndarray
    p2p_est_rad: float
    p2p_true_rad: float
    rel_err: float
    rms_err_rad: float


def estimate_windup(t_p: np.ndarray, theta_p: np.ndarray, t_s: np.ndarray,
                    theta_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(times, wind-up (W1)) from the primary's and secondary's edge times [s] and angles
    [rad] with their offsets removed; only primary edges inside the secondary's span."""
    from scipy.interpolate import CubicSpline

    inside = (t_p >= t_s[0]) & (t_p <= t_s[-1])
    t = t_p[inside]
    phi = theta_p[inside] - CubicSpline(t_s, theta_s)(t)
    turns = np.round(np.median(phi) / (2.0 * math.pi))
    return t, phi - 2.0 * math.pi * turns


def _pitch(edges, mode: str, learn_s: tuple[float, float] | None, origin_ns: int):
    if mode == 'given':
        return edges.wheel.pitch_errors_rad()
    if mode == 'none':
        return None
    sel = np.ones(len(edges), bool)
    if learn_s is not None:
        t = (edges.t_ns - origin_ns) * 1e-9
        sel = (t >= learn_s[0]) & (t <= learn_s[1])
    from dmf_sim.analysis.tooth_signals import WheelEdges
    part = WheelEdges(edges.wheel, edges.t_ns[sel], edges.tooth[sel], edges.flags[sel])
    return learn_pitch_errors(part)


def windup_from_bag(path: str | os.PathLike | BagFiles, primary: str = 'crank',
                    secondary: str = 'flywheel_secondary', *, pitch: str = 'given',
                    skip_s: float | None = None, learn_s: tuple[float, float] | None = None
                    ) -> WindupEstimate:
    """The wind-up (W1) of a bag's two wheels scored against its ``driveline/dmf_windup``.

    pitch: 'given' (the wheels' pitch errors from the bag's metadata), 'learned'
    (:func:`~dmf_sim.analysis.tooth_signals.learn_pitch_errors` over ``learn_s``, a (from, to)
    span [s] from the first primary edge; default all) or 'none'. skip_s: seconds from the first
    edge left out of the score (default: the run's settling time from the metadata, else 0)."""
    if pitch not in PITCH_MODES:
        raise ValueError(f"pitch must be one of {', '.join(PITCH_MODES)}, got {pitch!r}")
    bag = path if isinstance(path, BagFiles) else resolve_bag(path)
    edges = read_wheel_edges(bag, [primary, secondary])
    ep, es = edges[primary], edges[secondary]
    origin = int(ep.t_ns[0])
    tp, thp = edge_angles(ep, _pitch(ep, pitch, learn_s, origin), origin)
    ts, ths = edge_angles(es, _pitch(es, pitch, learn_s, origin), origin)
    thp = thp - math.radians(ep.wheel.offset_deg)
    ths = ths - math.radians(es.wheel.offset_deg)
    t, phi = estimate_windup(tp, thp, ts, ths)
    tt_ns, true = read_float64(bag, WINDUP_TOPIC)
    tt = (tt_ns - origin) * 1e-9
    if skip_s is None:
        skip_s = RunMetadata.from_bag_metadata(bag.metadata).settle_s or 0.0
    lo, hi = max(t[0], tt[0], skip_s), min(t[-1], tt[-1])
    if not hi > lo:
        raise ValueError(f'no time span with both the wheels and the true wind-up after '
                         f'{skip_s:g} s')
    a = (t >= lo) & (t <= hi)
    b = (tt >= lo) & (tt <= hi)
    t, phi, tt, true = t[a], phi[a], tt[b], true[b]
    p2p_est = float(phi.max() - phi.min())
    p2p_true = float(true.max() - true.min())
    rms = float(np.sqrt(np.mean((np.interp(tt, t, phi) - true) ** 2)))
    return WindupEstimate(t, phi, tt, true, p2p_est, p2p_true,
                          abs(p2p_est - p2p_true) / p2p_true, rms)
