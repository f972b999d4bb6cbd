"""The DMF wind-up from the two tooth wheels around it (dmf_sim.analysis.windup_estimate):
exact on a synthetic motion, within 3 % peak-to-peak of the true wind-up of a simulated run."""
from __future__ import annotations

import math

import numpy as np
import pytest

from dmf_sim.analysis.windup_estimate import estimate_windup, windup_from_bag
from dmf_sim.transient.profiles import make_profile
from dmf_sim.transient.run import RunOptions, run_profile

OMEGA = 2 * math.pi * 1200 / 60


def _edges(theta_fn, dtheta_fn, pitch, revs):
    levels = np.arange(int(revs * 2 * math.pi / pitch)) * pitch
    t = levels / OMEGA
    for _ in range(8):
        t -= (theta_fn(t) - levels) / dtheta_fn(t)
    return t, levels


def test_windup_of_a_synthetic_motion():
    nu, a_p, a_s, mean = 3 * OMEGA, 0.004, 0.0005, 0.2
    tp, thp = _edges(lambda t: OMEGA * t + a_p * np.sin(nu * t) + mean,
                     lambda t: OMEGA + a_p * nu * np.cos(nu * t), 2 * math.pi / 60, 10)
    ts, ths = _edges(lambda t: OMEGA * t + a_s * np.sin(nu * t),
                     lambda t: OMEGA + a_s * nu * np.cos(nu * t), 2 * math.pi / 60, 10)
    thp = thp - 2 * math.pi * 3                 # the wheels' revolution counts differ
    t, phi = estimate_windup(tp, thp, ts, ths)
    exact = mean + (a_p - a_s) * np.sin(nu * t)
    # the cubic spline of the secondary between teeth: O(h^4) of its motion
    h = 2 * math.pi / 60 / OMEGA
    assert np.max(np.abs(phi - exact)) < a_s * nu ** 4 * h ** 4 / 100 + 1e-12
    assert abs(np.ptp(phi) / np.ptp(exact) - 1) < 1e-3


def test_windup_from_the_sensors_of_a_simulated_run(tmp_path):
    prof = make_profile([(0.0, 1200.0, 1.0), (2.5, 1200.0, 1.0)])
    run_profile(prof, tmp_path / 'bag', RunOptions())
    given = windup_from_bag(tmp_path / 'bag')                 # scored after the 2 s settle
    assert given.rel_err <= 0.03
    assert given.p2p_true_rad > 0.01                         # a real swing, full load
    # the mean wind-up (the load torque through the spring) comes out too
    assert abs(given.windup_rad.mean() - given.true_rad.mean()) < 0.02 * given.true_rad.mean()
    assert given.rms_err_rad < 0.05 * given.p2p_true_rad
    # without the pitch errors the estimate is worse
    none = windup_from_bag(tmp_path / 'bag', pitch='none')
    assert none.rms_err_rad > 2 * given.rms_err_rad


def test_unknown_pitch_mode_is_one_line(tmp_path):
    with pytest.raises(ValueError, match='pitch must be one of given, learned, none'):
        windup_from_bag(tmp_path, pitch='guessed')
