"""Load steps and engine braking in a running node over real DDS (localhost, its own
ROS_DOMAIN_ID, see dds_peer): a tip-in in 0.1 s through the setpoint topic with
``load_ramp_per_s`` 10, a negative (braking) load setpoint, the health's peak wind-up and DMF
torque, and ``~/reset`` starting them afresh. The ROS-free core is tested in test_load_steps.py.
"""
from __future__ import annotations

import pytest
from support.dds_peer import START_TIMEOUT, NodeProcess, Peer, new_domain

pytestmark = pytest.mark.ros

STATIC_FULL_RAD = 0.2449     # static wind-up at 1200 rpm, load 1 (test_load_steps.py)
STATIC_BRAKE_RAD = -0.0826   # ... at load -1 (the full engine brake)
NODE_ARGS = ['--ros-args', '-p', 'publish_rate:=100.0', '-p', 'monitor:=false',
             '-p', 'max_lag:=5.0', '-p', 'diagnostics_rate:=4.0',
             '-p', 'initial_speed_rpm:=1200.0', '-p', 'initial_load:=0.0',
             '-p', 'load_ramp_per_s:=10.0']


def _value(peer, key: str) -> float:
    v = peer.diagnostics().get(key)
    return float(v) if v not in (None, 'nan') else float('nan')


@pytest.mark.slow
def test_fast_tip_in_and_braking_setpoints(tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64
    from std_srvs.srv import Trigger

    domain = new_domain()
    node = NodeProcess(NODE_ARGS, tmp_path, domain)
    peer = Peer(domain)
    peer.subscribe('/diagnostics', DiagnosticArray)
    load_pub = peer.node.create_publisher(Float64, '/engine/load_setpoint', peer.qos)
    try:
        assert peer.spin_until(lambda: 'peak_windup_max_rad' in peer.diagnostics(),
                               START_TIMEOUT), node.output()
        assert peer.spin_until(lambda: load_pub.get_subscription_count() > 0, 10.0)
        # a tip-in 0 -> 1 in 0.1 s: the wind-up overshoots its static full-load value
        load_pub.publish(Float64(data=1.0))
        assert peer.spin_until(lambda: _value(peer, 'peak_windup_max_rad')
                               > STATIC_FULL_RAD + 0.01, 20.0), peer.diagnostics()
        assert _value(peer, 'peak_dmf_torque_max_nm') > 3000.0
        # engine braking: a negative setpoint is taken, the wind-up swings past its static value
        load_pub.publish(Float64(data=-1.0))
        assert peer.spin_until(lambda: peer.diagnostics().get('load_setpoint') == '-1'
                               and _value(peer, 'load') < -0.999, 20.0), peer.diagnostics()
        assert peer.spin_until(lambda: _value(peer, 'peak_windup_min_rad')
                               < STATIC_BRAKE_RAD - 0.01, 10.0), peer.diagnostics()
        assert _value(peer, 'peak_dmf_torque_min_nm') < -900.0
        assert peer.diagnostics().get('rejected_setpoints', '0') == '0'
        # ~/reset: static equilibrium at the setpoints, the peaks start afresh
        since = _value(peer, 'peaks_since_s')
        res = peer.call(Trigger, '/driveline_node/reset', Trigger.Request())
        assert res.success and 'peak wind-up and DMF torque start afresh' in res.message
        assert peer.spin_until(lambda: _value(peer, 'peaks_since_s') > since
                               and _value(peer, 'peak_windup_max_rad') < 0.0, 10.0), \
            peer.diagnostics()
        # a load outside [-1, 1] is refused and counted; the node keeps running
        load_pub.publish(Float64(data=-1.5))
        assert peer.spin_until(lambda: peer.diagnostics().get('rejected_setpoints', '0') != '0',
                               10.0), peer.diagnostics()
        assert peer.diagnostics().get('load_setpoint') == '-1'
    finally:
        peer.close()
        node.stop()
    out = node.output()
    assert 'Traceback' not in out and 'load setpoint -1.5 outside [-1, 1]' in out
