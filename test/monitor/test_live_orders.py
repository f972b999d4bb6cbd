"""Live per-cycle order analysis (dmf_sim.monitor.orders): known orders recovered, and the same
numbers as ``dmf-sim analyze`` on a bag of the same samples. No ROS needed."""
from __future__ import annotations

import math
import struct
from types import SimpleNamespace

import numpy as np
import pytest

from dmf_sim.analysis.pipeline import AnalysisOptions, analyze_bag
from dmf_sim.bags.writer import BagRecorder
from dmf_sim.core.units import CYCLE_RAD, RPM_TO_RAD_S
from dmf_sim.monitor.orders import CycleOrderTracker, region_key
from dmf_sim.physics.spring import PiecewiseLinearSpring

THETA = 0.24
SPRING = PiecewiseLinearSpring.two_step(10890.0, THETA, 2.5, theta_coast=0.05, alpha_coast=1.0)


def _cdr_float64(value: float) -> bytes:
    """std_msgs/Float64 as CDR (little-endian encapsulation header + the double)."""
    return b'\x00\x01\x00\x00' + struct.pack('<d', value)


def _chunks(n: int, rng) -> list[slice]:
    out, i = [], 0
    while i < n:
        k = int(rng.integers(1, 60))
        out.append(slice(i, min(n, i + k)))
        i += k
    return out


def _synthetic(speed0=900.0, ramp=40.0, seconds=1.6, rate=1000.0, psi0=0.3):
    """Crank angle of a speed ramp and a wind-up with known half orders over the crank angle:
    w = mean + a3 cos(3 psi + p3) + a15 cos(1.5 psi + p15) + a6 cos(6 psi)."""
    t = np.arange(int(seconds * rate)) / rate
    omega0, alpha = speed0 * RPM_TO_RAD_S, ramp * RPM_TO_RAD_S
    psi = psi0 + omega0 * t + 0.5 * alpha * t ** 2
    mean, a3, a15, a6 = 0.23, 0.012, 0.004, 0.002
    w = mean + a3 * np.cos(3 * psi + 0.4) + a15 * np.cos(1.5 * psi - 1.1) + a6 * np.cos(6 * psi)
    return t, psi, w, dict(mean=mean, a3=a3, a15=a15, a6=a6)


def _feed(tracker, t, psi, w, load, stamps=None, seed=1):
    out = []
    for sl in _chunks(len(t), np.random.default_rng(seed)):
        s = SimpleNamespace(t=t[sl], psi=psi[sl], windup=w[sl])
        out += tracker.add(s, load(t[sl][0]) if callable(load) else load,
                           None if stamps is None else stamps[sl])
    return out


def test_known_orders_regions_and_static_windup_recovered():
    t, psi, w, true = _synthetic()
    static = lambda speed, load: 0.2 + 1e-5 * speed * load  # noqa: E731 - known function
    tracker = CycleOrderTracker(SPRING, static)
    cycles = _feed(tracker, t, psi, w, lambda tt: 0.5 + 0.1 * tt)
    # every whole cycle of the run, except the last one (no samples after it yet)
    k0, k1 = math.ceil(psi[0] / CYCLE_RAD), math.floor(psi[-1] / CYCLE_RAD)
    assert [c.index for c in cycles] == list(range(k0, k1))[:len(cycles)]
    assert len(cycles) >= k1 - k0 - 1 >= 10
    for c in cycles:
        s = c.summary
        assert s.order_3 == pytest.approx(true['a3'], rel=2e-4)
        assert s.order_1_5 == pytest.approx(true['a15'], rel=2e-4)
        assert s.mean == pytest.approx(true['mean'], abs=1e-7)
        assert s.mean_minus_theta == pytest.approx(true['mean'] - THETA, abs=1e-7)
        # deviations: the extremes of the known signal on a fine grid of the cycle
        grid = np.linspace(c.index * CYCLE_RAD, (c.index + 1) * CYCLE_RAD, 20001)
        wf = (true['mean'] + true['a3'] * np.cos(3 * grid + 0.4)
              + true['a15'] * np.cos(1.5 * grid - 1.1) + true['a6'] * np.cos(6 * grid))
        assert s.max_deviation == pytest.approx(wf.max() - true['mean'], abs=2e-5)
        assert s.min_deviation == pytest.approx(wf.min() - true['mean'], abs=2e-5)
        # speed: 120 / duration of the cycle on the ramp, at the cycle's mid time
        tm = 0.5 * (c.t_start_s + c.t_end_s)
        assert c.speed_rpm == pytest.approx(900.0 + 40.0 * tm, rel=1e-4)
        assert c.load == pytest.approx(0.5 + 0.1 * tm, abs=0.01)
        assert s.static_windup == pytest.approx(static(c.speed_rpm, c.load))
        assert s.theta_minus_static == pytest.approx(THETA - s.static_windup)
        # region shares: samples of the cycle in each region
        inside = (t >= c.t_start_s) & (t < c.t_end_s)
        wi = w[inside]
        assert c.region_share['secondary'] == pytest.approx(np.mean(wi > THETA))
        assert c.region_share['primary'] == pytest.approx(np.mean(wi <= THETA))
        assert c.region_share['coast'] == 0.0
        assert 0.1 < c.region_share["secondary"] < 0.9
        assert sum(c.region_share.values()) == pytest.approx(1.0)
        v = c.values()
        assert v['order_3_rad'] == s.order_3 and v[region_key('secondary')] == \
            c.region_share['secondary']
        assert v['max_windup_rad'] == pytest.approx(s.mean + s.max_deviation)


def test_gap_in_stamps_drops_the_cycle_across_it_and_continues():
    t, psi, w, true = _synthetic(ramp=0.0, seconds=2.0)
    stamps = np.round(t * 1e9).astype(np.int64)
    stamps[900:] += 300_000_000          # skip ahead 0.3 s after sample 900 (an overrun)
    cycles = _feed(CycleOrderTracker(SPRING), t, psi, w, 0.5, stamps)
    gap_psi = psi[899:901]
    assert all(not ((c.index * CYCLE_RAD) < gap_psi[1] and (c.index + 1) * CYCLE_RAD
                    > gap_psi[0]) for c in cycles)
    assert any(c.index * CYCLE_RAD > gap_psi[1] for c in cycles)
    for c in cycles:
        assert c.summary.order_3 == pytest.approx(true['a3'], rel=2e-4)
        assert c.speed_rpm == pytest.approx(900.0, rel=1e-6)


def test_live_cycles_equal_dmf_sim_analyze_of_a_bag_of_the_same_run(tmp_path):
    """The simulated run (LiveSimulation, as the node steps it, chunks of any size) analysed live
    and recorded to a bag analysed by ``analyze_bag`` (what ``dmf-sim analyze`` runs): the same
    numbers per cycle."""
    from dmf_sim.live.simulation import LiveSimulation

    sim = LiveSimulation.from_config(alpha=3.0, theta=0.2, speed_rpm=950.0, load=1.0,
                                     speed_limits_rpm=(500.0, 2200.0), stride=10)
    sim.set_speed_setpoint(1000.0)
    spring = sim.model.spring
    loads = sim.integ.loads
    tracker = CycleOrderTracker(spring, lambda speed, ld: loads.static_state(speed, ld).windup)
    epoch = 1_700_000_000_000_000_000
    live = []
    bag = tmp_path / 'run'
    topics = {'/driveline/dmf_windup': 'std_msgs/msg/Float64',
              '/engine/crank_angle': 'std_msgs/msg/Float64'}
    rng = np.random.default_rng(5)
    with BagRecorder(bag, topics) as rec:
        while sim.t < 1.5:
            s = sim.advance(int(rng.integers(1, 400)))
            stamps = epoch + np.round(s.t * 1e9).astype(np.int64)
            for i in range(len(s)):
                rec.write('/driveline/dmf_windup', int(stamps[i]), _cdr_float64(s.windup[i]))
                rec.write('/engine/crank_angle', int(stamps[i]), _cdr_float64(s.psi[i]))
            live += tracker.add(s, sim.load, stamps)
    res = analyze_bag(bag, options=AnalysisOptions(bin_rpm=0, theta=spring.theta)).signal('windup')
    table, cyc = res.table, res.cycles
    k_bag = np.round(cyc.psi_start / CYCLE_RAD).astype(int)
    by_k = {int(k): i for i, k in enumerate(k_bag)}
    assert len(live) >= 8 and len(live) >= len(k_bag) - 2
    for c in live:
        i = by_k[c.index]
        s = c.summary
        assert s.order_3 == pytest.approx(table.order_3[i], rel=1e-9, abs=1e-15)
        assert s.order_1_5 == pytest.approx(table.order_1_5[i], rel=1e-9, abs=1e-15)
        assert s.max_deviation == pytest.approx(table.max_deviation[i], rel=1e-9)
        assert s.min_deviation == pytest.approx(table.min_deviation[i], rel=1e-9)
        assert s.mean == pytest.approx(table.mean[i], rel=1e-12)
        assert s.mean_minus_theta == pytest.approx(table.mean_minus_theta[i], rel=1e-9)
        assert c.speed_rpm == pytest.approx(table.speed_rpm[i], rel=1e-9)
        np.testing.assert_allclose(c.coeffs, cyc.coeffs[i], rtol=1e-9, atol=1e-11)
        assert s.static_windup == pytest.approx(loads.static_state(c.speed_rpm, c.load).windup)
    # the run crosses the knee (theta = 0.2 at full load), so the region shares are informative
    assert any(0.0 < c.region_share['secondary'] < 1.0 for c in live)
