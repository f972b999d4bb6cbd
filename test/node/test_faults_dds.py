"""Faults in the live node over real DDS (localhost only, its own ROS_DOMAIN_ID, see dds_peer):
a misfire injected by ``dmf-sim fault`` (topic) and by parameter, the ground truth latched for a
late joiner, a bad request refused while the node keeps publishing, ``dmf-sim fault --clear``,
and the bag holding the ground truth."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest
from support.dds_peer import START_TIMEOUT, NodeProcess, Peer, new_domain

from dmf_sim.bags.read import read_messages
from dmf_sim.physics.faults import event_from_values

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NODE = '/driveline_node'


def _dmf_sim(args, domain: int, timeout: float = 120.0):
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    return subprocess.run([sys.executable, '-m', 'dmf_sim.cli', *args], env=env,
                          capture_output=True, text=True, timeout=timeout)


def _events(msgs) -> list[dict]:
    out = []
    for msg in msgs:
        assert len(msg.status) == 1                    # one message per event
        s = msg.status[0]
        out.append(event_from_values(s.message, {kv.key: kv.value for kv in s.values}))
    return out


def _latched(peer: Peer, topic: str, depth: int, into: list):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    return peer.node.create_subscription(DiagnosticArray, topic, into.append, qos)


def test_faults_live_over_dds(tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64, String

    domain = new_domain()
    bag = tmp_path / 'bag'
    node = NodeProcess(['--ros-args', '-p', 'record:=true', '-p', f'bag_path:={bag}',
                        '-p', 'monitor:=false', '-p', 'initial_speed_rpm:=1200.0',
                        '-p', 'initial_load:=1.0', '-p', 'max_lag:=5.0'], tmp_path, domain)
    peer = Peer(domain)
    try:
        peer.subscribe('/driveline/dmf_windup', Float64, keep=True)
        peer.subscribe('/diagnostics', DiagnosticArray)
        assert peer.spin_until(lambda: len(peer.series['/driveline/dmf_windup']) > 200,
                               START_TIMEOUT), node.output()

        # a misfire by topic, with the command line
        r = _dmf_sim(['fault', '{kind: misfire, cylinders: [3]}'], domain)
        assert r.returncode == 0, r.stdout + r.stderr + node.output()
        assert 'delivered to 1 subscriber' in r.stdout
        # a late joiner gets the ground truth so far (transient local) and the active set
        truth: list = []
        _latched(peer, '/faults/ground_truth', 100, truth)
        assert peer.spin_until(lambda: len(truth) >= 3, 30.0), node.output()
        events = _events(truth)
        assert [e['what'] for e in events[:3]] == ['start', 'misfire', 'end']
        assert events[1]['cylinder'] == 3 and events[0]['id'] == 1
        active: list = []
        _latched(peer, '/faults/active', 1, active)
        assert peer.spin_until(lambda: active, 10.0)
        assert list(active[-1].status) == []                # the single misfire is over

        # a bad request on the topic: refused with its reason, the node keeps publishing
        pub = peer.node.create_publisher(String, '/faults/inject', peer.qos)
        assert peer.spin_until(lambda: pub.get_subscription_count() > 0, 20.0)
        for _ in range(3):
            pub.publish(String(data='{kind: misfire, cylinders: [7]}'))
            peer.spin_for(0.1)
        n_before = len(peer.series['/driveline/dmf_windup'])
        assert peer.spin_until(
            lambda: peer.diagnostics().get('fault_requests_refused', '0') != '0', 15.0)
        diag = peer.diagnostics()
        assert "'cylinders[0]'" in diag['fault_last_refused'], diag
        assert node.alive()
        assert peer.spin_until(
            lambda: len(peer.series['/driveline/dmf_windup']) > n_before + 200, 10.0)

        # by parameter: every combustion of cylinder 2, then a bad value refused
        res = peer.set_params(NODE, fault_misfire='{cylinders: [2], mode: every_cycle}')
        assert res[0].successful, res[0].reason
        assert peer.spin_until(lambda: sum(e['what'] == 'misfire' and e['cylinder'] == 2
                                           for e in _events(truth)) >= 3, 20.0)
        assert peer.spin_until(lambda: len(active[-1].status) == 1, 10.0)
        res = peer.set_params(NODE, fault_misfire='{cylinders: [9], mode: every_cycle}')
        assert not res[0].successful and "'cylinders[0]'" in res[0].reason
        res = peer.set_params(NODE, fault_dmf='{kind: dmf_broken, stage: 5}')
        assert not res[0].successful and 'does not exist' in res[0].reason

        # the clear service ends it; the parameter shows '' again
        r = _dmf_sim(['fault', '--clear'], domain)
        assert r.returncode == 0 and 'cleared faults' in r.stdout, r.stdout + r.stderr
        assert peer.spin_until(lambda: list(active[-1].status) == [], 10.0)
        assert peer.spin_until(lambda: _events(truth)[-1]['what'] == 'end', 10.0)
        assert node.alive()
    finally:
        peer.close()
        code = node.stop()
    assert code == 0, node.output()

    # the bag holds the whole ground truth, the active set first
    got = [(m.topic, m.msg) for m in read_messages(bag, ['/faults/ground_truth',
                                                         '/faults/active'])]
    assert got[0][0] == '/faults/active' and list(got[0][1].status) == []
    events = _events([m for t, m in got if t == '/faults/ground_truth'])
    whats = [(e['id'], e['what']) for e in events if e['what'] != 'misfire']
    assert whats == [(1, 'start'), (1, 'end'), (2, 'start'), (2, 'end')]
    assert sum(e['what'] == 'misfire' for e in events) >= 4
