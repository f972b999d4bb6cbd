"""Crank speed from tooth-edge times, as an engine controller computes it (no ROS).

A tooth wheel (:mod:`dmf_sim.physics.sensors`) gives the capture time of each edge and the
tooth's index j (0 = the first tooth after the gap). The edge of tooth j in revolution r lies at
the wheel angle

    theta_rj = 2 pi r + offset + j * pitch + e_j                                    (T1)

(pitch = 2 pi / teeth, e_j the tooth's pitch error), so the angle of every edge is known from
its index alone: the missing-tooth gap is simply a larger angle step between the last tooth and
tooth 0, and a dropped edge a larger step too. A repeated index (a spurious edge, which carries
the index of the tooth before it) is ignored: only the first edge of each (r, j) counts.
Speeds are finite differences of (T1) over time:

* per tooth: omega_k = (theta_{k+1} - theta_k) / (t_{k+1} - t_k) at the interval's mid time;
* per cylinder segment: the mean speed over a crank-angle window of 720 deg / n_cyl that starts
  ``start_rad`` after each cylinder's TDC (beta_k + 720 deg m); the window's end times are the
  monotone cubic interpolant (PCHIP) of t(theta) through the edges.

Pitch errors are given (the wheel's ``pitch_errors_deg`` in the bag's metadata) or learned from
a healthy stretch (:func:`learn_pitch_errors`). The engine cycle spans two revolutions; which
one is first is the cam sensor's job in a vehicle, here :func:`cycle_phase` takes it from the
bag's crank angle (the reference rotation psi, which differs from the flywheel angle by its
vibratory angle, far less than a revolution).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from dmf_sim.bags.layout import BagFiles, resolve_bag
from dmf_sim.bags.metadata import RunMetadata
from dmf_sim.bags.read import bag_topics, read_messages
from dmf_sim.bags.sensor_messages import decode_edges, wheel_of_topic
from dmf_sim.core.errors import BagError
from dmf_sim.physics.sensors import ToothWheel, parse_sensors

__all__ = ['LEARN_HALF_WINDOW', 'LEARN_RCOND', 'WheelEdges', 'read_wheel_edges',
           'bag_wheels', 'read_float64', 'edge_angles', 'tooth_speeds', 'learn_pitch_errors',
           'cycle_phase', 'segment_speeds']

NS = 1e-9
LEARN_HALF_WINDOW = 3      # edges each side of the local cubic that learns a pitch error
LEARN_RCOND = 1e-2         # singular values of the learning's equations below this are noise


@dataclass(frozen=True)
class WheelEdges:
    """The edges of one tooth wheel in a bag: capture time [ns] on the stamp clock, tooth
    index and flags (:mod:`dmf_sim.bags.sensor_messages`), in capture order."""

    wheel: ToothWheel
    t_ns: np.ndarray
    tooth: np.ndarray
    flags: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ns)


def bag_wheels(path: str | os.PathLike | BagFiles) -> dict[str, ToothWheel]:
    """The tooth wheels a bag recorded (from its metadata), by name."""
    bag = path if isinstance(path, BagFiles) else resolve_bag(path)
    meta = RunMetadata.from_bag_metadata(bag.metadata)
    return {w.name: w for w in parse_sensors(meta.sensors).tooth_wheels}


def read_wheel_edges(path: str | os.PathLike | BagFiles,
                     wheels: Sequence[str] | None = None) -> dict[str, WheelEdges]:
    """The edges of the tooth wheels ``wheels`` (default: all the bag recorded) of a bag."""
    bag = path if isinstance(path, BagFiles) else resolve_bag(path)
    known = bag_wheels(bag)
    wanted = list(known) if wheels is None else list(wheels)
    for name in wanted:
        if name not in known:
            raise BagError(f'{bag.path}: no tooth wheel {name!r} recorded; wheels are '
                           f'{", ".join(known) or "none"}')
    topics = {t: wheel_of_topic(t) for t in bag_topics(bag)}
    topics = {t: w for t, w in topics.items() if w in wanted}
    parts: dict[str, list] = {w: [] for w in wanted}
    for m in read_messages(bag, list(topics), raw=True):
        parts[topics[m.topic]].append(decode_edges(m.msg))
    out = {}
    for name in wanted:
        cols = [np.concatenate([p[i] for p in parts[name]]) if parts[name]
                else np.zeros(0, np.int64) for i in range(3)]
        out[name] = WheelEdges(known[name], *cols)
    return out


def read_float64(path: str | os.PathLike | BagFiles,
                 topic: str = 'engine/crank_angle') -> tuple[np.ndarray, np.ndarray]:
    """The log times [ns] and values of a Float64 topic of a bag (given relative to the node's
    namespace), e.g. the crank angle psi [rad] or the true DMF wind-up [rad]."""
    bag = path if isinstance(path, BagFiles) else resolve_bag(path)
    names = [t for t in bag_topics(bag) if t.lstrip('/') == topic or t.endswith('/' + topic)]
    if not names:
        raise BagError(f'{bag.path}: no topic {topic!r}')
    t, psi = [], []
    for m in read_messages(bag, names[:1]):
        t.append(m.timestamp_ns)
        psi.append(m.msg.data)
    return np.asarray(t, np.int64), np.asarray(psi, float)


def edge_angles(edges: WheelEdges, pitch_errors_rad: np.ndarray | None = None,
                origin_ns: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(capture times [s] from ``origin_ns``, unwrapped wheel angles [rad]) of the edges,
    eq. (T1); revolution 0 is the first one in the data. ``origin_ns`` default: the first edge
    (stamps since 1970 as float seconds would not resolve the timer). A repeated tooth index
    is dropped; ``pitch_errors_rad`` (one per tooth that exists) default: none."""
    w = edges.wheel
    tooth = edges.tooth
    if len(tooth) == 0:
        raise ValueError(f'tooth wheel {w.name!r}: no edges')
    keep = np.ones(len(tooth), bool)
    keep[1:] = tooth[1:] != tooth[:-1]
    t = edges.t_ns[keep]
    j = tooth[keep]
    rev = np.concatenate([[0], np.cumsum(j[1:] < j[:-1])])
    nominal = math.radians(w.offset_deg) + j * w.pitch_rad
    if pitch_errors_rad is not None:
        nominal = nominal + np.asarray(pitch_errors_rad)[j]
    origin = int(edges.t_ns[0]) if origin_ns is None else int(origin_ns)
    return (t - origin) * NS, 2.0 * math.pi * rev + nominal


def tooth_speeds(t_s: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-tooth speed: (mid times [s], omega [rad/s]) of each edge interval."""
    dt = np.diff(t_s)
    return 0.5 * (t_s[1:] + t_s[:-1]), np.diff(theta) / dt


def _prediction_operator(wheel: ToothWheel, h: int) -> np.ndarray:
    """(n, n) matrix P: (P e)_j is what the local cubic through the ``h`` teeth each side of
    tooth j (by angle, across the gap) predicts from their errors; the residual of a pattern
    e is (I - P) e."""
    n = wheel.present_teeth
    pos = np.arange(n, dtype=float)
    pos_ext = np.concatenate([pos - wheel.teeth, pos, pos + wheel.teeth])   # neighbours' revs
    p = np.zeros((n, n))
    for j in range(n):
        ks = np.concatenate([np.arange(-h, 0), np.arange(1, h + 1)])
        x = pos_ext[n + j + ks] - pos[j]
        v = np.stack([x ** q for q in range(4)], axis=1)
        weights = np.linalg.pinv(v)[0]                 # the fit's value at x = 0
        np.add.at(p[j], (j + ks) % n, weights)
    return p


def learn_pitch_errors(edges: WheelEdges, half_window: int = LEARN_HALF_WINDOW) -> np.ndarray:
    """The pitch errors e_j [rad] of a wheel learned from a healthy stretch of its edges.

    Each edge's angle (T1, without errors) is compared with a cubic in time fitted through the
    ``half_window`` edges each side of it (not itself): the motion between a few teeth is
    smooth, a pitch error is not. The residuals averaged per tooth over the revolutions are
    (P - I) e with P the same fit applied to the errors (:func:`_prediction_operator`); e is
    the least-squares solution of that ring of equations, its mean removed (patterns the cubic
    follows, a constant and slow ones, are not observable and not learned). Firing pulsations
    spanning many teeth pass the cubic and are not mistaken for pitch errors; the stretch must
    be one where the wheel's motion is smooth over a few teeth (the secondary flywheel, a crank
    wheel in overrun): on a fired crank behind a DMF the combustion's high orders defeat it."""
    w = edges.wheel
    n = w.present_teeth
    keep = np.ones(len(edges.tooth), bool)
    keep[1:] = edges.tooth[1:] != edges.tooth[:-1]
    tooth = edges.tooth[keep]
    h = half_window
    if len(tooth) < 2 * h + 1 + n:
        raise ValueError(f'learning pitch errors needs at least {2 * h + 1 + n} edges, '
                         f'got {len(tooth)}')
    offsets = np.concatenate([np.arange(-h, 0), np.arange(1, h + 1)])
    centre = np.arange(h, len(tooth) - h)
    idx = centre[:, None] + offsets[None, :]
    t, theta = edge_angles(edges)
    tt = t[idx] - t[centre][:, None]
    scale = np.maximum(np.abs(tt).max(axis=1, keepdims=True), 1e-12)
    vand = np.stack([(tt / scale) ** q for q in range(4)], axis=2)          # (m, 2h, 4)
    a = np.einsum('mki,mkj->mij', vand, vand)
    b = np.einsum('mki,mk->mi', vand, theta[idx])
    fit0 = np.linalg.solve(a, b[..., None])[:, 0, 0]                # each cubic at its edge
    resid = theta[centre] - fit0                                    # = ((P - I) e)_j + noise
    counts = np.bincount(tooth[centre], None, n)
    r = np.bincount(tooth[centre], resid, n) / np.maximum(counts, 1)
    m = _prediction_operator(w, h) - np.eye(n)
    e = np.linalg.lstsq(m, r, rcond=LEARN_RCOND)[0]
    return e - e.mean()


def cycle_phase(t_s: np.ndarray, theta: np.ndarray, crank_t_s: np.ndarray,
                crank_psi: np.ndarray, wheel: ToothWheel) -> np.ndarray:
    """The wheel angles of :func:`edge_angles` moved by whole revolutions onto the crank angle
    psi (the engine-cycle phase a cam sensor gives): theta - offset ~ psi at the edges."""
    psi = np.interp(t_s, crank_t_s, crank_psi)
    shift = np.median(psi - (theta - math.radians(wheel.offset_deg)))
    turns = np.round(shift / (2.0 * math.pi))
    return theta + 2.0 * math.pi * turns


def segment_speeds(t_s: np.ndarray, theta: np.ndarray, firing_phases_rad: Sequence[float],
                   start_rad: float = 0.0, *, offset_rad: float = 0.0) -> Mapping[str, np.ndarray]:
    """Mean crank speed over each cylinder's segment (see the module docstring).

    ``theta``: wheel angles on the crank angle (:func:`cycle_phase`), ``offset_rad``: the
    wheel's offset (theta - offset = crank angle). Segments are the crank-angle windows
    [beta_k + 4 pi m + start, + 4 pi / n_cyl) inside the data. Returns arrays per segment,
    in crank-angle order: ``cylinder`` (1-based), ``combustion`` m, ``tdc_rad``, ``t0_s``,
    ``t1_s`` (window start and end times), ``omega`` [rad/s] (window angle / duration)."""
    from scipy.interpolate import PchipInterpolator

    psi = theta - offset_rad
    beta = np.asarray(firing_phases_rad, float)
    n_cyl = len(beta)
    width = 4.0 * math.pi / n_cyl
    lo, hi = psi[0], psi[-1]
    tdc, cyl, comb = [], [], []
    for k, b in enumerate(beta):
        m = np.arange(math.ceil((lo - start_rad - b) / (4 * math.pi)),
                      math.floor((hi - start_rad - width - b) / (4 * math.pi)) + 1)
        tdc.append(b + 4.0 * math.pi * m)
        cyl.append(np.full(len(m), k + 1))
        comb.append(m)
    tdc_a = np.concatenate(tdc)
    order = np.argsort(tdc_a)
    tdc_a = tdc_a[order]
    t_of = PchipInterpolator(psi, t_s)
    t0 = t_of(tdc_a + start_rad)
    t1 = t_of(tdc_a + start_rad + width)
    return {'cylinder': np.concatenate(cyl)[order], 'combustion': np.concatenate(comb)[order],
            'tdc_rad': tdc_a, 't0_s': t0, 't1_s': t1, 'omega': width / (t1 - t0)}
