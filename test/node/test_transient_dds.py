"""Profiles for a running node over real DDS (localhost, ROS_DOMAIN_ID from
DMF_SIM_TEST_DOMAINS, see dds_peer): ``dmf-sim setpoint --profile FILE`` played in real time, and
the node's ``profile`` parameter at start-up and through the parameter service. The ROS-free
cores (ProfilePlayer, NodeProfile) are tested in test_transient.py.

Profiles are a few seconds long with slopes (100-150 rpm/s) well below the node's speed ramp
(500 rpm/s), so a speed that follows the profile is told from one that jumped to its end: the
time the speed takes between two levels is measured on the peer's clock (the node paces at
real time; ``max_lag`` 5 s so a loaded machine does not skip simulated time ahead).
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from support.dds_peer import START_TIMEOUT, NodeProcess, Peer, new_domain

pytestmark = pytest.mark.ros

NODE_RAMP_RPM_PER_S = 500.0    # the node's default speed_ramp_rpm_per_s (config/driveline_node)
RATE_TOL = 0.5                 # measured slope within this fraction of the profile's
NODE_ARGS = ['--ros-args', '-p', 'publish_rate:=100.0', '-p', 'monitor:=false',
             '-p', 'max_lag:=5.0', '-p', 'diagnostics_rate:=4.0']


def _csv(path: Path, rows) -> Path:
    path.write_text('time_s,speed_rpm,load\n' + ''.join(f'{t},{s},{x}\n' for t, s, x in rows))
    return path


def _crossing(series, level: float, rising: bool) -> float:
    """Peer time [s] of the first sample past ``level``."""
    for t, v in series:
        if (v >= level) if rising else (v <= level):
            return t
    raise AssertionError(f'speed never crossed {level} rpm: {series[-5:]}')


def _slope(series, lo: float, hi: float, rising: bool) -> float:
    """Speed change per second of the peer's clock between levels ``lo`` and ``hi`` [rpm/s]."""
    a, b = (lo, hi) if rising else (hi, lo)
    t0 = _crossing(series, a, rising)
    t1 = _crossing([p for p in series if p[0] >= t0], b, rising)
    return (hi - lo) / max(t1 - t0, 1e-9)


def _start(tmp_path: Path, *extra: str):
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64

    domain = new_domain()
    node = NodeProcess([*NODE_ARGS, *extra], tmp_path, domain)
    peer = Peer(domain)
    peer.subscribe('/engine/speed', Float64, keep=True)
    peer.subscribe('/diagnostics', DiagnosticArray)
    return domain, node, peer


@pytest.mark.slow
def test_setpoint_profile_plays_in_real_time_to_a_running_node(tmp_path):
    """``dmf-sim setpoint --profile``: the node's /engine/speed follows the profile's speeds
    at the profile's pace (not the node's faster ramp) and ends on its last row; the load
    setpoint follows too."""
    prof = _csv(tmp_path / 'up.csv', [(0, 1000, 0.5), (0.5, 1000, 0.5), (2.5, 1300, 0.8),
                                      (3.0, 1300, 0.8)])
    domain, node, peer = _start(tmp_path)
    proc = None
    try:
        # the peer hears the node before the player starts, so it sees the whole profile
        assert peer.spin_until(lambda: peer.counts['/engine/speed'] > 20, START_TIMEOUT), \
            node.output()
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED='1')
        proc = subprocess.Popen([sys.executable, '-m', 'dmf_sim.cli', 'setpoint', '--profile',
                                 str(prof), '--timeout', '30'], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        # spin while the player runs: the speeds arrive in real time
        assert peer.spin_until(lambda: proc.poll() is not None, 60.0), 'setpoint did not end'
        out, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
        assert 'playing profile up: 3 s, 1000-1300 rpm' in out
        assert '/engine/speed_setpoint: 1300 rpm delivered to 1 subscriber' in out
        assert '/engine/load_setpoint: load 0.8 delivered' in out
        assert peer.spin_until(lambda: peer.series['/engine/speed'][-1][1] > 1299.99, 10.0)
        speeds = peer.series['/engine/speed']
        assert speeds[0][1] == pytest.approx(1000.0)
        assert all(b[1] >= a[1] - 1e-9 for a, b in zip(speeds, speeds[1:]))   # a run-up
        slope = _slope(speeds, 1050.0, 1250.0, rising=True)
        assert slope == pytest.approx(150.0, rel=RATE_TOL), slope      # 300 rpm in 2 s
        assert slope < 0.6 * NODE_RAMP_RPM_PER_S
        assert peer.spin_until(lambda: peer.diagnostics().get('load_setpoint') == '0.8', 5.0)
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        peer.close()
        node.stop()
    assert 'Traceback' not in node.output()


@pytest.mark.slow
def test_node_profile_parameter_at_start_and_at_run_time(tmp_path):
    """The node's ``profile`` parameter: a profile given at start-up is followed from t = 0;
    one set through the parameter service (what ``ros2 param set`` calls) is followed from
    then on at the profile's pace; a broken file or one outside the node's speed limits is
    refused with a one-line reason and the simulation keeps running where it was."""
    start = _csv(tmp_path / 'start.csv', [(0, 1000, 0.5), (1.0, 1100, 0.6)])
    down = _csv(tmp_path / 'down.csv', [(0, 1100, 0.6), (0.5, 1100, 0.6), (2.5, 900, 0.9)])
    broken = _csv(tmp_path / 'broken.csv', [(0, 900, 0.9), (1.0, 950, 0.9), (1.0, 1000, 0.9)])
    too_fast = _csv(tmp_path / 'too_fast.csv', [(0, 900, 0.9), (1.0, 2500, 0.9)])
    _, node, peer = _start(tmp_path, '-p', f'profile:={start}')
    try:
        # start-up: followed from the first step, ends on its last row
        assert peer.spin_until(lambda: peer.series['/engine/speed']
                               and peer.series['/engine/speed'][-1][1] > 1099.99,
                               START_TIMEOUT), node.output()
        assert peer.spin_until(lambda: peer.diagnostics().get('load_setpoint') == '0.6', 5.0)
        assert 'following profile start: 2 rows, 1 s' in node.output()

        # at run time through the parameter service: a run-down at 100 rpm/s
        n_before = len(peer.series['/engine/speed'])
        (res,) = peer.set_params('driveline_node', profile=str(down))
        assert res.successful, res.reason
        assert peer.spin_until(lambda: peer.series['/engine/speed'][-1][1] < 900.01, 20.0)
        speeds = peer.series['/engine/speed'][n_before:]
        assert all(b[1] <= a[1] + 1e-9 for a, b in zip(speeds, speeds[1:]))   # a run-down
        slope = _slope(speeds, 925.0, 1075.0, rising=False)
        assert slope == pytest.approx(100.0, rel=RATE_TOL), slope
        assert peer.spin_until(lambda: peer.diagnostics().get('load_setpoint') == '0.9', 5.0)
        assert peer.spin_until(lambda: 'profile down done at' in node.output(), 5.0)

        # refused: one line naming the problem; the simulation runs on at 900 rpm
        for bad, words in ((broken, ('broken.csv', 'time_s', 'increase strictly')),
                           (too_fast, ('too_fast', '2500 rpm', 'speed_max_rpm')),
                           (tmp_path / 'missing.csv', ('missing.csv',))):
            (res,) = peer.set_params('driveline_node', profile=str(bad))
            assert not res.successful
            assert res.reason.startswith('profile ') and '\n' not in res.reason, res.reason
            assert 'profile: profile' not in res.reason, res.reason
            assert all(w in res.reason for w in words), (words, res.reason)
        n0 = peer.counts['/engine/speed']
        assert peer.spin_until(lambda: peer.counts['/engine/speed'] > n0 + 50, 10.0)
        assert peer.series['/engine/speed'][-1][1] == pytest.approx(900.0)
        assert node.alive()
    finally:
        peer.close()
        rc = node.stop()
    assert rc == 0, node.output()
    assert 'Traceback' not in node.output()
