"""The DMF spring's laws compiled once for every kernel (numba: nopython, cached): the region
lookup of the piecewise-linear spring and the friction and end-stop law (doc/theory.md §2, eq.
8a-8b), on the arrays of :class:`dmf_sim.physics.spring.PiecewiseLinearSpring`
(``arrays()``, ``primary_index``, ``law_array()``). The Newmark step
(:mod:`dmf_sim.solvers.newmark_kernel`), the harmonic balance's AFT
(:mod:`dmf_sim.solvers.hbm.kernels`) and the Floquet monodromy
(:mod:`dmf_sim.solvers.stability_kernel`) call these and write no law of their own; the spring
object's numpy methods (``region_index``, ``law_torque``) are their readable twins.
"""
from __future__ import annotations

import math

from dmf_sim.core.compiled import jit

__all__ = ['TANH_ONE', 'region_of', 'primary_range', 'friction_parts', 'stop_parts',
           'travel_range', 'law_parts', 'law_active']

TANH_ONE = 20.0
"""Beyond this argument tanh is 1 in double precision (from 19.1 on: 1 - tanh(x) = 2 exp(-2x) is
below half an ulp of 1), so the regularized friction law skips the call there: the same bits,
and most samples of a slipping cycle cost a comparison."""


def region_of(w, knees, primary):
    """Region index of wind-up w (count of knees below w; ties go to the primary side)."""
    r = 0
    nk = knees.shape[0]
    while r < nk and (w > knees[r] or (w == knees[r] and r < primary)):
        r += 1
    return r


def primary_range(knees, primary):
    """(lowest, highest) wind-up [rad] of the primary stage, region ``primary``: the knees on
    either side of it, -inf / inf where it has none. Inside it the spring adds no torque to
    the linear driveline's."""
    nk = knees.shape[0]
    lo = knees[primary - 1] if primary > 0 else -math.inf
    hi = knees[primary] if primary < nk else math.inf
    return lo, hi


def friction_parts(wd, amp, law):
    """(friction torque T_f [Nm], d(T_f)/d(w_dot) [Nms/rad], tanh(w_dot / omega_reg) = T_f /
    ``amp``) at wind-up rate wd [rad/s] and sliding friction torque ``amp`` = T0 + c_Omega
    Omega^2 [Nm] (eq. 8a; ``law`` = PiecewiseLinearSpring.law_array()). The third value is the
    law's shape, which d(T_f)/d(Omega) = d(amp)/d(Omega) tanh(...) reads."""
    z = wd / law[2]
    if z > TANH_ONE:
        return amp, 0.0, 1.0
    if z < -TANH_ONE:
        return -amp, 0.0, -1.0
    th = math.tanh(z)
    return amp * th, amp * (1.0 - th * th) / law[2], th


def stop_parts(w, wd, law):
    """(end-stop torque T_s [Nm], d(T_s)/dw [Nm/rad], d(T_s)/d(w_dot) [Nms/rad]) at wind-up w
    [rad] and rate wd [rad/s] (eq. 8b; all zero without stops, ``law[5]`` = 0)."""
    ts = 0.0
    dts_w = 0.0
    dts_v = 0.0
    if law[5] > 0.0:
        if w > law[4]:
            f = law[5] * (w - law[4]) + law[6] * wd
            if f > 0.0:
                ts = f
                dts_w = law[5]
                dts_v = law[6]
        elif w < law[3]:
            f = law[5] * (law[3] - w) - law[6] * wd
            if f > 0.0:
                ts = -f
                dts_w = law[5]
                dts_v = law[6]
    return ts, dts_w, dts_v


def travel_range(law):
    """(lowest, highest) wind-up [rad] within the end stops' travel, -inf / inf without stops
    (``law[5]`` = 0): inside it :func:`stop_parts` is zero, so a loop over samples calls it only
    outside (as :func:`primary_range` spares the region lookup)."""
    if law[5] > 0.0:
        return law[3], law[4]
    return -math.inf, math.inf


def law_parts(w, wd, amp, law):
    """(friction torque T_f, end-stop torque T_s, d(T_f)/d(w_dot), d(T_s)/dw, d(T_s)/d(w_dot))
    at wind-up w [rad], rate wd [rad/s] and sliding friction torque ``amp`` = T0 + c_Omega
    Omega^2 [Nm] (eq. 8a, 8b; ``law`` = PiecewiseLinearSpring.law_array()):
    :func:`friction_parts` and :func:`stop_parts` together."""
    tf, dtf, _ = friction_parts(wd, amp, law)
    ts, dts_w, dts_v = stop_parts(w, wd, law)
    return tf, ts, dtf, dts_w, dts_v


def law_active(law):
    """Whether ``law`` (``PiecewiseLinearSpring.law_array()``) gives any torque: friction (T0 or
    c_Omega > 0) or end stops (k_s > 0)."""
    return law[0] > 0.0 or law[1] > 0.0 or law[5] > 0.0


region_of = jit(region_of)
primary_range = jit(primary_range)
friction_parts = jit(friction_parts)
stop_parts = jit(stop_parts)
travel_range = jit(travel_range)
law_parts = jit(law_parts)
law_active = jit(law_active)
