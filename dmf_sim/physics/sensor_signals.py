"""Sensor signals from the simulated motion: tooth-edge times, bus speeds, sensor faults.

The sensors (:mod:`dmf_sim.physics.sensors`) see the **absolute angle** of their element i,

    theta_i(t) = psi(t) / R_i + T[i, d] q_d(t),    theta_i'(t) = omega(t) / R_i + T[i, d] v_d(t)

(the reference rotation psi through the cumulative ratio R_i, plus the vibratory angle of the
element's DOF d through the rigid constraints; doc/theory.md §1). The Newmark kernel writes
t, psi, omega and the sensor DOFs' q and v at the end of every step (its ``track`` rows,
:meth:`dmf_sim.solvers.newmark.NewmarkIntegrator.advance`); this module turns them into signals,
chunk by chunk, with the state carried between chunks, so chunks of any length give the same
signals as one long run, bit for bit.

**Tooth edges.** Inside a step [t0, t0 + h] the angle is the cubic Hermite interpolant of the
angle and velocity at both ends,

    theta(t0 + tau h) = c0 + c1 tau + c2 tau^2 + c3 tau^3,   c0 = theta_0, c1 = h theta'_0,
    c2 = 3 (theta_1 - theta_0) - h (2 theta'_0 + theta'_1),
    c3 = 2 (theta_0 - theta_1) + h (theta'_0 + theta'_1),                       (S1)

and an edge is the crossing of a tooth's angle level: levels 2 pi r + a_j for revolution r and
tooth j (a_j = offset + j pitch + pitch error_j, :meth:`ToothWheel.tooth_angles_rad`), tooth 0
the first after the gap. Every level between the step's end angles is crossed once (in either
direction: a non-directional sensor gives an edge whichever way the tooth passes), at the root
of (S1) minus the level found by Newton's method kept inside the bracket [0, 1] (bisection when
a Newton step leaves it) to |delta tau| < 1e-15. (S1) interpolates a smooth motion with error
O(h^4) theta'''' / 384, so an edge time is off by O(h^4) (``test/physics/test_sensor_signals.py``
checks the order on a known motion). A motion reversing inside one step gives one edge per
level between the end angles. The capture timer: the edge at t is read as
``floor((t + jitter) / timer_resolution_s)`` ticks, jitter Gaussian of ``timer_jitter_s``
(counter-based, :mod:`dmf_sim.core.counter_random`, the k-th edge of a wheel its k-th draw),
never below the previous capture.

**Bus speeds.** Sent at t_k = k period (simulated time): the mean speed of the element over the
last period, (theta(t_k) - theta(t_{k-1})) / period, theta(t_k) from (S1); the first value one
period after the start. Gaussian ``noise_rpm`` added (the k-th draw), rounded to the nearest
whole ``resolution_rpm``, delivered at t_k + delay.

**Sensor faults** (the fault grammar of the spec: ``kind`` ``sensor_edges`` with ``mode``
``missing`` (each edge dropped with ``probability``, or ``tooth`` every revolution) or
``extra`` (spurious edges at ``rate_per_s``, a Poisson process from the fault's start, flagged
:data:`FLAG_SPURIOUS`, carrying the index of the tooth before them), ``kind`` ``bus_signal``
with ``mode`` ``stuck`` (the value sent before the fault started is sent again) or ``noisy``
(extra Gaussian ``sigma_rpm``)), each active from ``start_s`` to ``end_s`` of simulated time.
Their random numbers are counter-based too, so faults are as reproducible as the signals.

Times are integers: nanoseconds of simulated time from t = 0 (``time_ns``); the node adds its
stamp epoch (:class:`dmf_sim.live.pacing.TimeBase`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from dmf_sim.core.compiled import jit
from dmf_sim.core.counter_random import gaussian, uniform
from dmf_sim.core.units import RAD_S_TO_RPM
from dmf_sim.physics.sensors import FLAG_FIRST_AFTER_GAP, FLAG_SPURIOUS, SensorSet

__all__ = ['FLAG_FIRST_AFTER_GAP', 'FLAG_SPURIOUS', 'STREAM_JITTER', 'STREAM_MISSING',
           'STREAM_EXTRA', 'STREAM_BUS_NOISE', 'STREAM_BUS_FAULT', 'STREAMS_PER_SENSOR',
           'NEWTON_TOL', 'FAULT_SLOTS', 'EdgeArrays', 'SensorChunk', 'fault_window',
           'hermite_crossing', 'level_angle', 'spurious_step', 'synthesize', 'SensorSynthesizer']

# counter_random streams; sensor s uses stream + STREAMS_PER_SENSOR * s (its own numbers)
STREAM_JITTER = 1
STREAM_MISSING = 2
STREAM_EXTRA = 3
STREAM_BUS_NOISE = 4
STREAM_BUS_FAULT = 5
STREAMS_PER_SENSOR = 16

NEWTON_TOL = 1e-15          # crossing parameter tau: below round-off of a step's time
NEWTON_MAX_ITER = 60        # Newton steps (bisection when one leaves the bracket): 50 halve
                            # [0, 1] to 1e-15, so the loop always ends converged
FAULT_SLOTS = 4             # sensor faults acting on one sensor within one chunk (the fault
                            # grammar refuses overlapping windows of a kind on a target: one,
                            # two at a switch; more is a caller's bug)
_NS = 1e9
_MIN_TICK = np.iinfo(np.int64).min

# fault modes in the kernel's slots
FAULT_NONE = 0
FAULT_MISSING_RANDOM = 1
FAULT_MISSING_TOOTH = 2
FAULT_EXTRA = 3
FAULT_STUCK = 4
FAULT_NOISY = 5

# The kernel's packed per-sensor rows (few arrays: each argument costs dispatch time per call).
# Wheels, int64 row: parameters, state, then FAULT_SLOTS slots of [mode, tooth, seed, draws]
WI_COL, WI_TEETH, WI_GAP, WI_SEED, WI_NEXT, WI_COUNT, WI_TICK, WI_TOOTH, WI_N = range(9)
WI_SLOTS, WI_SLOT = 10, 4
# wheels, float64 row: parameters, cached levels around the angle, slots [start, end, value, next]
WF_SCALE, WF_INV_R, WF_RES, WF_JITTER, WF_LEV_HI, WF_LEV_LO, WF_SPACING = range(7)
WF_SLOTS, WF_SLOT = 8, 4
# bus, int64 row: parameters, state (next k, started, pending head/count, outputs), slots
# [mode, seed]
BI_COL, BI_SEED, BI_NEXT, BI_STARTED, BI_HEAD, BI_PENDING, BI_N = range(7)
BI_SLOTS, BI_SLOT = 8, 2
# bus, float64 row: parameters, state (angle at the last send, last value sent), slots
# [start, end, sigma]
BF_SCALE, BF_INV_R, BF_PERIOD, BF_RES, BF_NOISE, BF_DELAY, BF_THETA, BF_HELD = range(8)
BF_SLOTS, BF_SLOT = 8, 3


# ------------------------------------------------------------------------------------------------
# Compiled kernels
# ------------------------------------------------------------------------------------------------

def hermite_crossing(d1, hv0, hv1, level):
    """tau in [0, 1] where the cubic Hermite angle (S1), relative to its start (0 at tau = 0,
    ``d1`` at tau = 1, slopes ``hv0``, ``hv1`` = h times the end velocities), equals
    ``level`` (between 0 and d1): Newton's method inside the bracket, bisection when a step
    leaves it."""
    c1 = hv0
    c2 = 3.0 * d1 - 2.0 * hv0 - hv1
    c3 = -2.0 * d1 + hv0 + hv1
    a = 0.0
    b = 1.0
    fa = -level
    tau = level / d1 if d1 != 0.0 else 0.5
    if not 0.0 <= tau <= 1.0:
        tau = 0.5
    for _ in range(NEWTON_MAX_ITER):
        f = ((c3 * tau + c2) * tau + c1) * tau - level
        if f == 0.0:
            return tau
        if (f < 0.0) == (fa < 0.0):
            a = tau
            fa = f
        else:
            b = tau
        df = (3.0 * c3 * tau + 2.0 * c2) * tau + c1
        nxt = tau - f / df if df != 0.0 else -1.0
        if not a < nxt < b:
            nxt = 0.5 * (a + b)
        if abs(nxt - tau) <= NEWTON_TOL:
            return nxt
        tau = nxt
    return tau


def level_angle(g, m, angles, w):
    """Angle [rad] of level g of wheel w: revolution g // m (floor), tooth g % m."""
    r = g // m
    return 2.0 * math.pi * r + angles[w, g - r * m]


def _set_level(w, g, wi, wf, angles):
    """Wheel w's next level is g: cache the angles of g and g - 1."""
    m = wi[w, WI_TEETH]
    wi[w, WI_NEXT] = g
    wf[w, WF_LEV_HI] = level_angle(g, m, angles, w)
    wf[w, WF_LEV_LO] = level_angle(g - 1, m, angles, w)


def _dropped(w, t, tooth, count, wi, wf):
    """Whether a missing-edges fault of wheel w drops its real edge number ``count`` (tooth
    ``tooth``, at t [s])."""
    for s in range(FAULT_SLOTS):
        i = WI_SLOTS + WI_SLOT * s
        j = WF_SLOTS + WF_SLOT * s
        mode = wi[w, i]
        if (mode == FAULT_MISSING_RANDOM or mode == FAULT_MISSING_TOOTH) \
                and wf[w, j] <= t < wf[w, j + 1]:
            if mode == FAULT_MISSING_TOOTH:
                if tooth == wi[w, i + 1]:
                    return True
            elif uniform(wi[w, i + 2], STREAM_MISSING + STREAMS_PER_SENSOR * w,
                         count) < wf[w, j + 2]:
                return True
    return False


def _next_spurious(w, wi, wf):
    """The slot of wheel w's earliest pending spurious edge (-1: none)."""
    best = -1
    for s in range(FAULT_SLOTS):
        if wi[w, WI_SLOTS + WI_SLOT * s] == FAULT_EXTRA and (
                best < 0 or wf[w, WF_SLOTS + WF_SLOT * s + 3]
                < wf[w, WF_SLOTS + WF_SLOT * best + 3]):
            best = s
    return best


def spurious_step(w, s, wi, wf):
    """Advance slot s of wheel w to its next arrival: a Poisson process of rate [1/s] the slot's
    value (counter-based exponential draws), none from the window's end on."""
    i = WI_SLOTS + WI_SLOT * s
    j = WF_SLOTS + WF_SLOT * s
    u = uniform(wi[w, i + 2], STREAM_EXTRA + STREAMS_PER_SENSOR * w, wi[w, i + 3])
    wi[w, i + 3] += 1
    wf[w, j + 3] -= math.log1p(-u) / wf[w, j + 2]
    if wf[w, j + 3] >= wf[w, j + 1]:
        wf[w, j + 3] = math.inf


def _emit(w, t, jitter_k, tooth, flags, wi, wf, out_w):
    """Append wheel w's edge at t [s] as the timer reads it: whole ticks of ns of simulated time
    with the jitter draw ``jitter_k`` (-1: none), never below the previous capture."""
    if jitter_k >= 0 and wf[w, WF_JITTER] > 0.0:
        t += wf[w, WF_JITTER] * gaussian(wi[w, WI_SEED], STREAM_JITTER + STREAMS_PER_SENSOR * w,
                                         jitter_k)
    tick = np.int64(math.floor(t / wf[w, WF_RES]))
    if tick < wi[w, WI_TICK]:
        tick = wi[w, WI_TICK]
    wi[w, WI_TICK] = tick
    j = wi[w, WI_N]
    out_w[w, j, 0] = np.int64(math.floor(tick * wf[w, WF_RES] * _NS + 0.5))
    out_w[w, j, 1] = tooth
    out_w[w, j, 2] = flags
    wi[w, WI_N] = j + 1


def _room(t1, track_row, wi, wf, angles, bi, bf, out_w, out_b_ns, pend_ns):
    """Whether every output has room for what the step ending at t1 adds (counted without
    changing any state)."""
    cap_w = out_w.shape[1]
    for w in range(wi.shape[0]):
        th1 = track_row[1] * wf[w, WF_INV_R] + wf[w, WF_SCALE] * track_row[3 + wi[w, WI_COL]]
        cnt = 0
        if not wf[w, WF_LEV_LO] < th1 < wf[w, WF_LEV_HI]:
            m = wi[w, WI_TEETH]
            g = wi[w, WI_NEXT]
            while level_angle(g, m, angles, w) <= th1:
                g += 1
                cnt += 1
            while level_angle(g - 1, m, angles, w) > th1:
                g -= 1
                cnt += 1
        for s in range(FAULT_SLOTS):
            i = WI_SLOTS + WI_SLOT * s
            if wi[w, i] == FAULT_EXTRA:
                j = WF_SLOTS + WF_SLOT * s
                tn = wf[w, j + 3]
                k = wi[w, i + 3]
                while tn <= t1:
                    cnt += 1
                    tn -= math.log1p(-uniform(wi[w, i + 2], STREAM_EXTRA
                                              + STREAMS_PER_SENSOR * w, k)) / wf[w, j + 2]
                    k += 1
        if wi[w, WI_N] + cnt > cap_w:
            return False
    for b in range(bi.shape[0]):
        sends = 0
        kk = bi[b, BI_NEXT]
        while kk * bf[b, BF_PERIOD] <= t1:
            kk += 1
            sends += 1
        if (bi[b, BI_N] + bi[b, BI_PENDING] + sends > out_b_ns.shape[1]
                or bi[b, BI_PENDING] + sends > pend_ns.shape[1]):
            return False
    return True


def _surely_room(row, p, th1s, wi, wf, bi, bf, out_w, out_b_ns, pend_ns):
    """A quick bound of :func:`_room`: True when no output can overflow in this step (the
    levels crossed are at most the angle travelled over the closest spacing of two levels,
    plus one; a wheel with a spurious-edge fault is left to the exact count)."""
    for w in range(wi.shape[0]):
        th0 = p[1] * wf[w, WF_INV_R] + wf[w, WF_SCALE] * p[3 + wi[w, WI_COL]]
        need = abs(th1s[w] - th0) / wf[w, WF_SPACING] + 2.0
        if wi[w, WI_N] + need > out_w.shape[1]:
            return False
        for s in range(FAULT_SLOTS):
            if wi[w, WI_SLOTS + WI_SLOT * s] == FAULT_EXTRA:
                return False
    h = row[0] - p[0]
    for b in range(bi.shape[0]):
        sends = h / bf[b, BF_PERIOD] + 2.0
        if (bi[b, BI_N] + bi[b, BI_PENDING] + sends > out_b_ns.shape[1]
                or bi[b, BI_PENDING] + sends > pend_ns.shape[1]):
            return False
    return True


def _spurious_due(w, wi, wf):
    """The earliest pending spurious edge of wheel w [s] (inf: none)."""
    s = _next_spurious(w, wi, wf)
    return wf[w, WF_SLOTS + WF_SLOT * s + 3] if s >= 0 else math.inf


def synthesize(track, prev, angles, wi, wf, bi, bf, pend_ns, pend_val, out_w, out_b_ns,
               out_b_val):
    """Tooth edges and bus deliveries of the steps in ``track`` (rows t, psi, omega, q[k],
    v[k]), starting from the state row ``prev`` (updated to the last row processed); the packed
    per-sensor rows ``wi``, ``wf`` (wheels), ``bi``, ``bf`` (bus signals; layouts: the WI_*,
    WF_*, BI_*, BF_* indices), tooth angles (W, M), pending bus deliveries (B, P) (a ring).
    Appends to out_w (W, cap, 3) int64 rows (time ns, tooth, flags), out_b_ns, out_b_val
    (B, cap_b), their counts in wi[:, WI_N] / bi[:, BI_N]. Returns the steps processed: fewer
    than the rows when an output would overflow (the caller grows it and calls again with the
    rest).

    Most steps cross no tooth and send nothing: each wheel's angle is compared with the two
    levels around it (cached) and each bus timer with the step's end, and the step is done."""
    n_rows = track.shape[0]
    k = (track.shape[1] - 3) // 2
    cap_p = pend_ns.shape[1]
    n_w = wi.shape[0]
    n_b = bi.shape[0]
    th1s = np.empty(n_w)
    spur_t = np.empty(n_w)
    for w in range(n_w):
        spur_t[w] = _spurious_due(w, wi, wf)
    p = prev
    for step in range(n_rows):
        row = track[step]
        if step > 0:
            p = track[step - 1]
        t1 = row[0]
        busy = False
        for w in range(n_w):
            th1 = row[1] * wf[w, WF_INV_R] + wf[w, WF_SCALE] * row[3 + wi[w, WI_COL]]
            th1s[w] = th1
            if not (wf[w, WF_LEV_LO] < th1 < wf[w, WF_LEV_HI]) or spur_t[w] <= t1:
                busy = True
        t1_ns = np.int64(math.floor(t1 * _NS + 0.5))
        for b in range(n_b):
            if bi[b, BI_NEXT] * bf[b, BF_PERIOD] <= t1 or (
                    bi[b, BI_PENDING] > 0 and pend_ns[b, bi[b, BI_HEAD]] <= t1_ns):
                busy = True
        if not busy:
            continue
        if not (_surely_room(row, p, th1s, wi, wf, bi, bf, out_w, out_b_ns, pend_ns)
                or _room(t1, row, wi, wf, angles, bi, bf, out_w, out_b_ns, pend_ns)):
            if step > 0:
                for i in range(prev.shape[0]):
                    prev[i] = track[step - 1, i]
            return step
        t0 = p[0]
        h = t1 - t0
        # --- tooth edges, spurious ones merged in time order ----------------------------------
        for w in range(n_w):
            th1 = th1s[w]
            if spur_t[w] > t1 and wf[w, WF_LEV_LO] < th1 < wf[w, WF_LEV_HI]:
                continue
            c = wi[w, WI_COL]
            m = wi[w, WI_TEETH]
            th0 = p[1] * wf[w, WF_INV_R] + wf[w, WF_SCALE] * p[3 + c]
            hv0 = h * (p[2] * wf[w, WF_INV_R] + wf[w, WF_SCALE] * p[3 + k + c])
            hv1 = h * (row[2] * wf[w, WF_INV_R] + wf[w, WF_SCALE] * row[3 + k + c])
            d1 = th1 - th0
            spur = _next_spurious(w, wi, wf)
            while spur >= 0 and wf[w, WF_SLOTS + WF_SLOT * spur + 3] <= t0:
                spurious_step(w, spur, wi, wf)   # arrivals from before the fault reached us
                spur = _next_spurious(w, wi, wf)
            while True:
                g = wi[w, WI_NEXT]
                if wf[w, WF_LEV_HI] <= th1:      # forward past level g
                    lev = wf[w, WF_LEV_HI]
                    _set_level(w, g + 1, wi, wf, angles)
                elif wf[w, WF_LEV_LO] > th1:     # backward past level g - 1
                    g -= 1
                    lev = wf[w, WF_LEV_LO]
                    _set_level(w, g, wi, wf, angles)
                else:
                    break
                t = t0 + hermite_crossing(d1, hv0, hv1, lev - th0) * h
                while spur >= 0 and wf[w, WF_SLOTS + WF_SLOT * spur + 3] < t:
                    _emit(w, wf[w, WF_SLOTS + WF_SLOT * spur + 3], -1, wi[w, WI_TOOTH],
                          FLAG_SPURIOUS, wi, wf, out_w)
                    spurious_step(w, spur, wi, wf)
                    spur = _next_spurious(w, wi, wf)
                r = g // m
                tooth = g - r * m
                count = wi[w, WI_COUNT]
                wi[w, WI_COUNT] = count + 1
                wi[w, WI_TOOTH] = tooth
                if _dropped(w, t, tooth, count, wi, wf):
                    continue
                flags = FLAG_FIRST_AFTER_GAP if (wi[w, WI_GAP] > 0 and tooth == 0) else 0
                _emit(w, t, count, tooth, flags, wi, wf, out_w)
            while spur >= 0 and wf[w, WF_SLOTS + WF_SLOT * spur + 3] <= t1:
                _emit(w, wf[w, WF_SLOTS + WF_SLOT * spur + 3], -1, wi[w, WI_TOOTH],
                      FLAG_SPURIOUS, wi, wf, out_w)
                spurious_step(w, spur, wi, wf)
                spur = _next_spurious(w, wi, wf)
            spur_t[w] = _spurious_due(w, wi, wf)
        # --- bus: sends at t_k = k period, deliveries at t_k + delay ---------------------------
        for b in range(n_b):
            c = bi[b, BI_COL]
            period = bf[b, BF_PERIOD]
            while bi[b, BI_NEXT] * period <= t1:
                kk = bi[b, BI_NEXT]
                tk = kk * period
                th0 = p[1] * bf[b, BF_INV_R] + bf[b, BF_SCALE] * p[3 + c]
                th1 = row[1] * bf[b, BF_INV_R] + bf[b, BF_SCALE] * row[3 + c]
                hv0 = h * (p[2] * bf[b, BF_INV_R] + bf[b, BF_SCALE] * p[3 + k + c])
                hv1 = h * (row[2] * bf[b, BF_INV_R] + bf[b, BF_SCALE] * row[3 + k + c])
                tau = (tk - t0) / h if h > 0.0 else 1.0
                d1 = th1 - th0
                c2 = 3.0 * d1 - 2.0 * hv0 - hv1
                c3 = -2.0 * d1 + hv0 + hv1
                theta = th0 + ((c3 * tau + c2) * tau + hv0) * tau          # (S1) at t_k
                if bi[b, BI_STARTED]:
                    rpm = (theta - bf[b, BF_THETA]) / period * RAD_S_TO_RPM
                    if bf[b, BF_NOISE] > 0.0:
                        rpm += bf[b, BF_NOISE] * gaussian(bi[b, BI_SEED], STREAM_BUS_NOISE
                                                          + STREAMS_PER_SENSOR * b, kk)
                    stuck = False
                    for s in range(FAULT_SLOTS):
                        i = BI_SLOTS + BI_SLOT * s
                        j = BF_SLOTS + BF_SLOT * s
                        if bi[b, i] != FAULT_NONE and bf[b, j] <= tk < bf[b, j + 1]:
                            if bi[b, i] == FAULT_STUCK:
                                stuck = True
                            elif bi[b, i] == FAULT_NOISY:
                                rpm += bf[b, j + 2] * gaussian(bi[b, i + 1], STREAM_BUS_FAULT
                                                               + STREAMS_PER_SENSOR * b, kk)
                    value = math.floor(rpm / bf[b, BF_RES] + 0.5) * bf[b, BF_RES]
                    if stuck and not math.isnan(bf[b, BF_HELD]):
                        value = bf[b, BF_HELD]
                    else:
                        bf[b, BF_HELD] = value
                    slot = (bi[b, BI_HEAD] + bi[b, BI_PENDING]) % cap_p
                    pend_ns[b, slot] = np.int64(math.floor((tk + bf[b, BF_DELAY]) * _NS + 0.5))
                    pend_val[b, slot] = value
                    bi[b, BI_PENDING] += 1
                bi[b, BI_STARTED] = 1
                bf[b, BF_THETA] = theta
                bi[b, BI_NEXT] = kk + 1
            while bi[b, BI_PENDING] > 0 and pend_ns[b, bi[b, BI_HEAD]] <= t1_ns:
                j = bi[b, BI_N]
                out_b_ns[b, j] = pend_ns[b, bi[b, BI_HEAD]]
                out_b_val[b, j] = pend_val[b, bi[b, BI_HEAD]]
                bi[b, BI_N] = j + 1
                bi[b, BI_HEAD] = (bi[b, BI_HEAD] + 1) % cap_p
                bi[b, BI_PENDING] -= 1
    if n_rows > 0:
        for i in range(prev.shape[0]):
            prev[i] = track[n_rows - 1, i]
    return n_rows


hermite_crossing = jit(hermite_crossing)
level_angle = jit(level_angle)
_set_level = jit(_set_level)
_dropped = jit(_dropped)
_next_spurious = jit(_next_spurious)
spurious_step = jit(spurious_step)
_emit = jit(_emit)
_room = jit(_room)
_surely_room = jit(_surely_room)
_spurious_due = jit(_spurious_due)
synthesize = jit(synthesize)


# ------------------------------------------------------------------------------------------------
# Results of a chunk
# ------------------------------------------------------------------------------------------------

@dataclass
class EdgeArrays:
    """A wheel's edges: capture time [ns of simulated time], tooth index (0 = the first tooth
    after the gap), flags (:data:`FLAG_FIRST_AFTER_GAP`, :data:`FLAG_SPURIOUS`); int64 arrays in
    time order."""

    time_ns: np.ndarray
    tooth: np.ndarray
    flags: np.ndarray

    def __len__(self) -> int:
        return int(self.time_ns.shape[0])

    @classmethod
    def of_rows(cls, rows: np.ndarray) -> 'EdgeArrays':
        """From (n, 3) rows (time_ns, tooth, flags)."""
        return cls(rows[:, 0], rows[:, 1], rows[:, 2])

    @classmethod
    def concatenate(cls, parts: Sequence['EdgeArrays']) -> 'EdgeArrays':
        if not parts:
            return cls(*(np.zeros(0, np.int64) for _ in range(3)))
        return cls(*(np.concatenate([getattr(p, f) for p in parts])
                     for f in ('time_ns', 'tooth', 'flags')))


@dataclass
class SensorChunk:
    """The sensor signals of one chunk of steps (simulated time up to ``t_end_s``), in the
    order of ``wheel_names`` / ``signal_names``.

    :meth:`edge_rows` (w): wheel w's edges as (n, 3) int64 rows (time_ns, tooth, flags), the
    data of its edge-batch message before the stamp epoch is added; :meth:`bus_of` (b): bus
    signal b's deliveries (delivery time [ns of simulated time], value [rpm]). ``edge_counts``
    / ``bus_counts``: how many of each."""

    t_end_s: float
    wheel_names: Sequence[str]
    signal_names: Sequence[str]
    edges_packed: np.ndarray          # (W, >= max count, 3) int64
    edge_counts: list[int]
    bus_ns_packed: np.ndarray         # (B, >= max count) int64
    bus_rpm_packed: np.ndarray        # (B, >= max count)
    bus_counts: list[int]

    def edge_rows(self, w: int) -> np.ndarray:
        return self.edges_packed[w, :self.edge_counts[w]]

    def bus_of(self, b: int) -> tuple[np.ndarray, np.ndarray]:
        n = self.bus_counts[b]
        return self.bus_ns_packed[b, :n], self.bus_rpm_packed[b, :n]

    def edges(self, name: str) -> EdgeArrays:
        return EdgeArrays.of_rows(self.edge_rows(list(self.wheel_names).index(name)))

    def bus(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        return self.bus_of(list(self.signal_names).index(name))

    @property
    def empty(self) -> bool:
        return not (any(self.edge_counts) or any(self.bus_counts))


# ------------------------------------------------------------------------------------------------
# The streaming synthesizer
# ------------------------------------------------------------------------------------------------

_INITIAL_CAPACITY = 64        # edges / bus samples per sensor and call; grows on demand
_EDGE_MODES = {'missing': FAULT_MISSING_RANDOM, 'extra': FAULT_EXTRA}
_BUS_MODES = {'stuck': FAULT_STUCK, 'noisy': FAULT_NOISY}


def fault_window(fault) -> tuple[float, float]:
    """[start, end) [s of simulated time] of a fault (``start_s`` / ``end_s``, None = open)."""
    start = getattr(fault, 'start_s', None)
    end = getattr(fault, 'end_s', None)
    return (-math.inf if start is None else float(start)), (math.inf if end is None
                                                           else float(end))


def _fault_key(fault):
    try:
        return (hash(fault), fault_window(fault))
    except TypeError:                     # an unhashable parameter object: its identity
        return (id(fault), fault_window(fault))


class SensorSynthesizer:
    """The signals of ``sensors`` on a reduced model, chunk by chunk (see the module docstring).

    :attr:`dofs`: the DOFs to track (give them to the integrator's ``set_tracked``); a track row
    is t, psi, omega, q[dofs], v[dofs]. Call :meth:`start` with the state row where the signals
    begin, then :meth:`process` with each chunk's track rows; :meth:`set_faults` when the
    sensor faults change; :meth:`resync` after the state jumps (a reset to equilibrium): no
    edges for the jump.
    """

    def __init__(self, sensors: SensorSet, model) -> None:
        self.sensors = sensors
        line = model.line
        wheels, signals = sensors.tooth_wheels, sensors.bus_signals
        elements = [line.index(w.element) for w in wheels] + \
                   [line.index(s.element) for s in signals]
        dofs = sorted({int(model.dof_of_element[i]) for i in elements})
        self.dofs = np.array(dofs, dtype=np.int64)
        col = {d: c for c, d in enumerate(dofs)}

        def geometry(i: int) -> tuple[int, float, float]:
            d = int(model.dof_of_element[i])
            return col[d], float(model.T[i, d]), 1.0 / float(model.R[i])

        n_w, n_b = len(wheels), len(signals)
        self.wheel_names = tuple(w.name for w in wheels)
        self.signal_names = tuple(s.name for s in signals)
        m_max = max((w.present_teeth for w in wheels), default=1)
        self._angles = np.zeros((n_w, m_max))
        self._wi = np.zeros((n_w, WI_SLOTS + WI_SLOT * FAULT_SLOTS), np.int64)
        self._wf = np.zeros((n_w, WF_SLOTS + WF_SLOT * FAULT_SLOTS))
        for j, (w, i) in enumerate(zip(wheels, elements)):
            c, scale, inv_r = geometry(i)
            self._angles[j, :w.present_teeth] = w.tooth_angles_rad()
            self._wi[j, [WI_COL, WI_TEETH, WI_GAP, WI_SEED]] = (c, w.present_teeth, w.gap,
                                                                 w.seed)
            a = self._angles[j, :w.present_teeth]
            spacing = np.min(np.diff(np.append(a, a[0] + 2.0 * math.pi)))    # of two levels
            self._wf[j, [WF_SCALE, WF_INV_R, WF_RES, WF_JITTER, WF_SPACING]] = (
                scale, inv_r, w.timer_resolution_s, w.timer_jitter_s, spacing)
        self._bi = np.zeros((n_b, BI_SLOTS + BI_SLOT * FAULT_SLOTS), np.int64)
        self._bf = np.zeros((n_b, BF_SLOTS + BF_SLOT * FAULT_SLOTS))
        for j, (s, i) in enumerate(zip(signals, elements[n_w:])):
            c, scale, inv_r = geometry(i)
            self._bi[j, [BI_COL, BI_SEED]] = (c, s.seed)
            self._bf[j, [BF_SCALE, BF_INV_R, BF_PERIOD, BF_RES, BF_NOISE, BF_DELAY]] = (
                scale, inv_r, s.period_s, s.resolution_rpm, s.noise_rpm, s.delay_s)
        pending = max((int(math.ceil(s.delay_s / s.period_s)) + 2 for s in signals), default=1)
        self._pend_ns = np.zeros((n_b, pending), np.int64)
        self._pend_val = np.zeros((n_b, pending))
        self._slots: dict[tuple[str, int], list] = {}   # (kind, sensor) -> fault key per slot
        self._faults_seen: tuple = ()
        self._out_w = np.zeros((n_w, _INITIAL_CAPACITY, 3), np.int64)
        self._out_b_ns = np.zeros((n_b, _INITIAL_CAPACITY), np.int64)
        self._out_b_val = np.zeros((n_b, _INITIAL_CAPACITY))
        self.prev = np.zeros(3 + 2 * len(dofs))
        self.started = False

    @property
    def track_columns(self) -> int:
        return 3 + 2 * len(self.dofs)

    # ---- state ------------------------------------------------------------------------------
    def _place_wheels(self, row: np.ndarray) -> None:
        """Each wheel's next level: the first one above its angle in ``row``."""
        for w in range(len(self.wheel_names)):
            m = int(self._wi[w, WI_TEETH])
            theta = (row[1] * self._wf[w, WF_INV_R]
                     + self._wf[w, WF_SCALE] * row[3 + self._wi[w, WI_COL]])
            g = int(math.floor((theta - self._angles[w, 0]) / (2.0 * math.pi))) * m
            while level_angle(g, m, self._angles, w) <= theta:
                g += 1
            while level_angle(g - 1, m, self._angles, w) > theta:
                g -= 1
            _set_level(w, g, self._wi, self._wf, self._angles)

    def start(self, row: np.ndarray) -> None:
        """Begin at the state ``row`` (t, psi, omega, q[dofs], v[dofs]): nothing emitted yet,
        each wheel's next tooth the first above its angle, each bus signal's first value one
        period after its next send time; no faults."""
        self.prev[:] = row
        self._wi[:, WI_NEXT:WI_SLOTS] = 0
        self._wi[:, WI_TICK] = _MIN_TICK
        self._place_wheels(row)
        self._bi[:, BI_NEXT:BI_SLOTS] = 0
        self._bi[:, BI_NEXT] = np.floor(row[0] / self._bf[:, BF_PERIOD]).astype(np.int64) + 1
        self._bf[:, BF_THETA] = 0.0
        self._bf[:, BF_HELD] = math.nan
        self._wi[:, WI_SLOTS:] = 0
        self._wf[:, WF_SLOTS:] = 0.0
        self._bi[:, BI_SLOTS:] = 0
        self._bf[:, BF_SLOTS:] = 0.0
        self._slots.clear()
        self._faults_seen = ()
        self.started = True

    def warm_up(self) -> None:
        """Load (or, the first time, compile) the kernel now rather than in the first chunk:
        one call on the current state row alone, which crosses nothing and sends nothing."""
        synthesize(self.prev[None].copy(), self.prev, self._angles, self._wi, self._wf,
                   self._bi, self._bf, self._pend_ns, self._pend_val, self._out_w,
                   self._out_b_ns, self._out_b_val)

    def resync(self, row: np.ndarray) -> None:
        """The state jumped to ``row`` (continuous time and crank angle): continue from it
        without edges for the jump (counters, timers and bus timers kept)."""
        self.prev[:] = row
        self._place_wheels(row)

    # ---- faults -------------------------------------------------------------------------------
    def set_faults(self, faults: Sequence) -> None:
        """The sensor faults acting from now on: objects with the fault grammar's fields — kind
        ``sensor_edges`` (sensor, mode missing/extra, probability, tooth, rate_per_s, seed) or
        ``bus_signal`` (signal, mode stuck/noisy, sigma_rpm, seed) — and ``start_s`` /
        ``end_s`` [s of simulated time], None = open; other kinds are ignored. A fault kept
        from the last call keeps its state (its spurious edges' process)."""
        faults = tuple(faults)
        if faults == self._faults_seen:
            return
        wanted: dict[tuple[str, int], list] = {}
        for f in faults:
            kind = getattr(f, 'kind', None)
            if kind == 'sensor_edges' and getattr(f, 'sensor', None) in self.wheel_names:
                wanted.setdefault(('w', self.wheel_names.index(f.sensor)), []).append(f)
            elif kind == 'bus_signal' and getattr(f, 'signal', None) in self.signal_names:
                wanted.setdefault(('b', self.signal_names.index(f.signal)), []).append(f)
        for key in list(self._slots):
            if key not in wanted:
                for s in range(FAULT_SLOTS):
                    self._clear_slot(key, s)
                del self._slots[key]
        for key, fs in wanted.items():
            if len(fs) > FAULT_SLOTS:
                raise ValueError(f'{len(fs)} faults on one sensor at once (at most '
                                 f'{FAULT_SLOTS})')
            slots = self._slots.setdefault(key, [None] * FAULT_SLOTS)
            keys = [_fault_key(f) for f in fs]
            for s, k in enumerate(slots):
                if k is not None and k not in keys:
                    self._clear_slot(key, s)
                    slots[s] = None
            for f, k in zip(fs, keys):
                if k not in slots:
                    s = slots.index(None)
                    slots[s] = k
                    self._install(key, s, f)
        self._faults_seen = faults

    def _clear_slot(self, key, s: int) -> None:
        kind, i = key
        if kind == 'w':
            self._wi[i, WI_SLOTS + WI_SLOT * s:WI_SLOTS + WI_SLOT * (s + 1)] = 0
            self._wf[i, WF_SLOTS + WF_SLOT * s:WF_SLOTS + WF_SLOT * (s + 1)] = 0.0
        else:
            self._bi[i, BI_SLOTS + BI_SLOT * s:BI_SLOTS + BI_SLOT * (s + 1)] = 0
            self._bf[i, BF_SLOTS + BF_SLOT * s:BF_SLOTS + BF_SLOT * (s + 1)] = 0.0

    def _install(self, key, s: int, f) -> None:
        kind, i = key
        lo, hi = fault_window(f)
        seed = int(getattr(f, 'seed', 0) or 0)
        if kind == 'b':
            a, b = BI_SLOTS + BI_SLOT * s, BF_SLOTS + BF_SLOT * s
            self._bi[i, a:a + BI_SLOT] = (_BUS_MODES[f.mode], seed)
            self._bf[i, b:b + BF_SLOT] = (lo, hi, float(getattr(f, 'sigma_rpm', 0.0) or 0.0))
            return
        mode = _EDGE_MODES[f.mode]
        tooth = getattr(f, 'tooth', None)
        if mode == FAULT_MISSING_RANDOM and tooth is not None:
            mode = FAULT_MISSING_TOOTH
        value = float(f.rate_per_s if mode == FAULT_EXTRA
                      else (getattr(f, 'probability', 0.0) or 0.0))
        a, b = WI_SLOTS + WI_SLOT * s, WF_SLOTS + WF_SLOT * s
        self._wi[i, a:a + WI_SLOT] = (mode, -1 if tooth is None else int(tooth), seed, 0)
        self._wf[i, b:b + WF_SLOT] = (lo, hi, value, math.inf)
        if mode == FAULT_EXTRA:                 # the first arrival: start + exponential draw
            self._wf[i, b + 3] = lo if math.isfinite(lo) else float(self.prev[0])
            spurious_step(i, s, self._wi, self._wf)

    # ---- a chunk ----------------------------------------------------------------------------
    def process(self, track: np.ndarray, faults: Sequence | None = None, *,
                copy: bool = True) -> SensorChunk:
        """The signals of the steps in ``track`` ((n, track_columns) rows, after the state of
        the previous call); ``faults``: :meth:`set_faults` first (None: those set before).
        ``copy`` False: the chunk's arrays are views into this synthesizer's buffers, valid
        until the next call (a caller that consumes them at once saves the copies)."""
        if not self.started:
            raise RuntimeError('SensorSynthesizer.process before start')
        if faults is not None:
            self.set_faults(faults)
        self._wi[:, WI_N] = 0
        self._bi[:, BI_N] = 0
        done, rows = 0, track.shape[0]
        while done < rows:
            done += synthesize(track[done:], self.prev, self._angles, self._wi, self._wf,
                               self._bi, self._bf, self._pend_ns, self._pend_val, self._out_w,
                               self._out_b_ns, self._out_b_val)
            if done < rows:                            # an output is full: grow, go on
                self._grow()
        n_w, n_b = self._wi[:, WI_N].tolist(), self._bi[:, BI_N].tolist()
        rows_w, bus_ns, bus_val = self._out_w, self._out_b_ns, self._out_b_val
        if copy:
            m_w, m_b = max(n_w, default=0), max(n_b, default=0)
            rows_w, bus_ns, bus_val = (rows_w[:, :m_w].copy(), bus_ns[:, :m_b].copy(),
                                       bus_val[:, :m_b].copy())
        return SensorChunk(float(self.prev[0]), self.wheel_names, self.signal_names, rows_w,
                           n_w, bus_ns, bus_val, n_b)

    def _grow(self) -> None:
        """Twice the room in every output and in the pending bus ring (its entries moved to
        the ring's start, in order)."""
        def bigger(a):
            new = np.zeros((a.shape[0], 2 * a.shape[1]) + a.shape[2:], a.dtype)
            new[:, :a.shape[1]] = a
            return new
        self._out_w = bigger(self._out_w)
        self._out_b_ns = bigger(self._out_b_ns)
        self._out_b_val = bigger(self._out_b_val)
        cap = self._pend_ns.shape[1]
        order = (self._bi[:, BI_HEAD, None] + np.arange(cap)) % cap
        rows = np.arange(len(order))[:, None]
        self._pend_ns = bigger(self._pend_ns[rows, order])
        self._pend_val = bigger(self._pend_val[rows, order])
        self._bi[:, BI_HEAD] = 0
