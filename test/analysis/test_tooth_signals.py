"""Crank speed from tooth-edge times (dmf_sim.analysis.tooth_signals): edges synthesized from a
known motion give back its speed per tooth and per cylinder segment, across the gap, a dropped
edge and a spurious one; pitch errors are learned from the edges alone."""
from __future__ import annotations

import math

import numpy as np
import pytest

from dmf_sim.analysis.tooth_signals import (
    WheelEdges,
    cycle_phase,
    edge_angles,
    learn_pitch_errors,
    segment_speeds,
    tooth_speeds,
)
from dmf_sim.physics.sensors import FLAG_FIRST_AFTER_GAP, ToothWheel

OMEGA = 2 * math.pi * 1200 / 60      # mean speed [rad/s]
AMP = 0.002                          # angle fluctuation [rad], 3rd order
NU = 3 * OMEGA                       # its frequency [rad/s]


def motion(t):
    return OMEGA * t + AMP * np.sin(NU * t), OMEGA + AMP * NU * np.cos(NU * t)


def wheel(errors_deg=()) -> ToothWheel:
    return ToothWheel('crank', 'PRIMARY FLYWHEEL', 60, 2, 0.0, tuple(errors_deg))


def synth(w: ToothWheel, revs: int, t0_ns: int = 10**18) -> WheelEdges:
    """Exact edge times of ``motion`` (Newton on each level), tooth 0 after the gap first."""
    a = w.tooth_angles_rad()
    levels = (2 * math.pi * np.arange(revs)[:, None] + a[None, :]).ravel()
    t = levels / OMEGA
    for _ in range(8):
        th, om = motion(t)
        t -= (th - levels) / om
    tooth = np.tile(np.arange(w.present_teeth), revs)
    flags = np.where(tooth == 0, FLAG_FIRST_AFTER_GAP, 0)
    return WheelEdges(w, t0_ns + np.round(t * 1e9).astype(np.int64), tooth, flags)


def test_tooth_speed_across_the_gap_matches_the_motion():
    e = synth(wheel(), 20)
    t, th = edge_angles(e)
    tm, om = tooth_speeds(t, th)
    # mean speed over each interval from the motion itself (the interval's angle / its time)
    _, exact_mid = motion(tm)
    # the mean speed over an interval h against the speed at its middle: omega'' h^2 / 24
    # (omega'' <= AMP NU^3, h up to three pitches at the gap), plus the ns stamps' rounding
    pitch = 2 * math.pi / 60
    h = 3 * pitch / OMEGA
    tol = AMP * NU ** 3 * h ** 2 / 24 + 1e-9 * OMEGA / (pitch / OMEGA)
    assert np.max(np.abs(om - exact_mid)) < tol
    gap = np.diff(th) > 2 * pitch
    assert gap.sum() == 19                      # one gap per revolution, seen as 3 pitches
    np.testing.assert_allclose(np.diff(th)[gap], 3 * pitch, rtol=1e-12)


def test_dropped_and_spurious_edges_keep_the_angles():
    e = synth(wheel(), 5)
    keep = np.ones(len(e), bool)
    keep[100] = False                                         # a dropped edge
    t_ns = np.insert(e.t_ns[keep], 50, e.t_ns[keep][49] + 1000)   # a spurious edge after 49
    tooth = np.insert(e.tooth[keep], 50, e.tooth[keep][49])
    flags = np.insert(e.flags[keep], 50, 2)
    bad = WheelEdges(e.wheel, t_ns, tooth, flags)
    t, th = edge_angles(bad)
    t0, th0 = edge_angles(e)
    assert len(th) == len(th0) - 1
    np.testing.assert_allclose(th, np.delete(th0, 100), atol=1e-12)
    np.testing.assert_allclose(t, np.delete(t0, 100), atol=1e-12)


def test_segment_speed_is_the_mean_speed_over_the_window():
    e = synth(wheel(), 30)
    t, th = edge_angles(e)
    beta = np.radians([0, 480, 240, 600, 120, 360])
    seg = segment_speeds(t, th, beta, 0.0)
    width = 4 * math.pi / 6
    # exact: the window's angle over the time the motion takes to turn it
    t0 = seg['tdc_rad'] / OMEGA
    t1 = (seg['tdc_rad'] + width) / OMEGA
    for _ in range(8):
        a0, w0 = motion(t0)
        a1, w1 = motion(t1)
        t0 -= (a0 - seg['tdc_rad']) / w0
        t1 -= (a1 - seg['tdc_rad'] - width) / w1
    np.testing.assert_allclose(seg['omega'], width / (t1 - t0), rtol=1e-6)
    # crank-angle order of the firing sequence 1-5-3-6-2-4, 120 deg apart
    assert list(seg['cylinder'][:6]) in ([1, 5, 3, 6, 2, 4][k:] + [1, 5, 3, 6, 2, 4][:k]
                                         for k in range(6))
    np.testing.assert_allclose(np.diff(seg['tdc_rad']), width)


def test_cycle_phase_moves_whole_revolutions_onto_the_crank_angle():
    e = synth(wheel(), 6)
    t, th = edge_angles(e)
    crank_t = np.linspace(0, t[-1], 500)
    psi = motion(crank_t)[0] + 3 * 2 * math.pi            # the cycle started 3 turns earlier
    moved = cycle_phase(t, th, crank_t, psi, e.wheel)
    np.testing.assert_allclose(moved - th, 6 * math.pi)


def test_pitch_errors_are_learned_from_the_edges():
    rng = np.random.default_rng(3)
    err = rng.normal(0, 0.02, 58)
    err -= err.mean()
    w = wheel(err)
    e = synth(w, 40)
    learned = learn_pitch_errors(e)
    truth = w.pitch_errors_rad()
    # the learned pattern explains most of the true one (a few pitches' smooth part of it is
    # not observable against the motion)
    assert np.corrcoef(learned, truth)[0, 1] > 0.9
    assert np.std(learned - truth) < 0.5 * np.std(truth)
    # with the learned pattern the per-tooth speed is closer to the motion's than without
    for pattern, bound in ((learned, 0.5), ):
        _, th = edge_angles(e, pattern)
        t, th0 = edge_angles(e)
        tm, om = tooth_speeds(t, th)
        _, om0 = tooth_speeds(t, th0)
        exact = motion(tm)[1]
        assert np.std(om - exact) < bound * np.std(om0 - exact)


def test_too_few_edges_to_learn_is_one_line():
    e = synth(wheel(), 1)
    with pytest.raises(ValueError, match='learning pitch errors needs at least'):
        learn_pitch_errors(WheelEdges(e.wheel, e.t_ns[:20], e.tooth[:20], e.flags[:20]))
