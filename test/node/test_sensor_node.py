"""The node's sensors over real DDS (localhost only, its own ROS_DOMAIN_ID): edge batches and bus
speeds as a stack receives them, checked against the layout and the physics (tooth period at
the setpoint speed, the gap, bus period and resolution), recorded in the node's bag the same
way; ``sensors:=false`` publishes none. The ROS-free parts: test_sensor_live.py."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from support.dds_peer import START_TIMEOUT, NodeProcess, Peer, new_domain

from dmf_sim.bags.metadata import RunMetadata
from dmf_sim.bags.read import read_messages
from dmf_sim.bags.sensor_messages import decode_edges, edges_of_message
from dmf_sim.physics.model import read_driveline
from dmf_sim.physics.sensors import FLAG_FIRST_AFTER_GAP, parse_sensors

pytestmark = [pytest.mark.ros, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
SPEED_RPM = 1000.0                 # the node's initial speed (config/driveline_node.yaml)


def _start(tmp_path, *extra):
    domain = new_domain()
    bag = tmp_path / 'bag'
    node = NodeProcess(['--ros-args', '--params-file', str(REPO / 'config' /
                                                          'driveline_node.yaml'),
                        '-p', 'monitor:=false', '-p', 'record:=true', '-p', f'bag_path:={bag}',
                        '-p', 'max_lag:=5.0', *extra], tmp_path, domain)
    return node, Peer(domain), bag


def test_edge_batches_and_bus_speeds_over_dds_and_in_the_bag(tmp_path):
    from std_msgs.msg import Float64, UInt64MultiArray

    sensors = read_driveline('truck_dmf').sensors
    node, peer, bag = _start(tmp_path)
    raw: dict[str, list] = {'crank': [], 'output_shaft': []}
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    deep = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)   # a loaded machine
    try:
        for wheel in raw:
            peer.node.create_subscription(
                UInt64MultiArray, f'/sensors/{wheel}/edges',
                lambda data, w=wheel: raw[w].append((time.time_ns(), data)), deep, raw=True)
        peer.subscribe('/sensors/flywheel_secondary/edges', UInt64MultiArray)
        peer.subscribe('/vehicle_bus/engine_speed', Float64, keep=True)
        peer.subscribe('/vehicle_bus/gearbox_input_speed', Float64, keep=True)
        assert peer.spin_until(lambda: len(raw['crank']) > 200, START_TIMEOUT), node.output()
        raw['crank'].clear()
        n_bus = len(peer.series['/vehicle_bus/engine_speed'])
        t0 = time.monotonic()
        assert peer.spin_until(lambda: len(raw['crank']) > 1500, 60.0), node.output()
        seconds = time.monotonic() - t0
        bus_rate = (len(peer.series['/vehicle_bus/engine_speed']) - n_bus) / seconds
        assert node.alive()
    finally:
        code = node.stop()
        peer.close()
    assert code == 0, node.output()

    # --- the crank wheel's batches: layout, tooth order, gap, tooth period at the speed -------
    batches = [decode_edges(data) for _, data in raw['crank']]
    t_ns = np.concatenate([b[0] for b in batches])
    tooth = np.concatenate([b[1] for b in batches])
    flags = np.concatenate([b[2] for b in batches])
    assert all(len(b[0]) for b in batches)                   # empty batches are not sent
    present = sensors.wheel('crank').present_teeth
    assert np.array_equal(np.diff(tooth) % present, np.ones(len(tooth) - 1))   # none missing
    assert np.array_equal(flags == FLAG_FIRST_AFTER_GAP, tooth == 0)
    dt = np.diff(t_ns) / 1e9
    pitch_s = 60.0 / SPEED_RPM / sensors.wheel('crank').teeth
    normal = dt[tooth[1:] != 0]
    assert np.median(normal) == pytest.approx(pitch_s, rel=0.01)
    assert np.median(dt[tooth[1:] == 0]) == pytest.approx(3 * pitch_s, rel=0.02)
    assert np.all(np.diff(t_ns) % 100 == 0)           # whole 1e-7-s ticks (from the epoch)
    # stamped on the wall clock at real-time factor 1, received shortly after
    recv = np.array([r for r, _ in raw['crank']])
    last = np.array([b[0][-1] for b in batches])
    assert np.all(recv > last) and np.median(recv - last) < 50e6
    # the output shaft's wheel: 20 teeth at the shaft's speed (cumulative ratio 0.802)
    out = np.concatenate([decode_edges(d)[0] for _, d in raw['output_shaft']])
    ratio = 0.881 * 0.9105
    assert np.median(np.diff(out)) / 1e9 == pytest.approx(60.0 / (SPEED_RPM / ratio) / 20,
                                                          rel=0.01)
    # a decoded message (rclpy's) reads the same way
    t2, _, _ = edges_of_message(peer.last['/sensors/flywheel_secondary/edges'])
    assert len(t2) > 0

    # --- bus: the mean speed, whole 0.125-rpm steps, every 20 ms -------------------------------
    eng = np.array([v for _, v in peer.series['/vehicle_bus/engine_speed']])
    assert np.all(eng % 0.125 == 0) and abs(np.median(eng) - SPEED_RPM) < 5.0
    assert bus_rate == pytest.approx(1 / sensors.signal('engine_speed').period_s, rel=0.15)
    gbx = np.array([v for _, v in peer.series['/vehicle_bus/gearbox_input_speed']])
    assert abs(np.median(gbx) - SPEED_RPM) < 5.0

    # --- the bag: the same topics and layout, its sensor set in the metadata -------------------
    counts: dict[str, int] = {}
    last_edge_ns = last_sample_ns = 0
    for m in read_messages(bag, raw=True):
        counts[m.topic] = counts.get(m.topic, 0) + 1
        if m.topic == '/sensors/crank/edges':
            bt, btooth, _ = decode_edges(m.msg)
            assert bt[-1] <= m.timestamp_ns and np.all(np.diff(btooth) % present == 1)
            last_edge_ns = max(last_edge_ns, int(bt[-1]))
        elif m.topic == '/driveline/joint_states':
            last_sample_ns = max(last_sample_ns, m.timestamp_ns)
    # the bag ends with every edge: they reach the last sample (within the gap, 3 pitches)
    assert last_edge_ns >= last_sample_ns - 3.5 * pitch_s * 1e9
    assert counts['/sensors/crank/edges'] > 500 and counts['/vehicle_bus/engine_speed'] > 50
    assert set(counts) >= {f'/sensors/{w.name}/edges' for w in sensors.tooth_wheels}
    import yaml
    meta = RunMetadata.from_bag_metadata(yaml.safe_load((bag / 'metadata.yaml').read_text())
                                         ['rosbag2_bagfile_information'])
    assert parse_sensors(meta.sensors) == sensors


def test_sensors_off_publishes_none(tmp_path):
    from std_msgs.msg import Float64
    node, peer, bag = _start(tmp_path, '-p', 'sensors:=false')
    try:
        peer.subscribe('/engine/speed', Float64)
        assert peer.spin_until(lambda: peer.counts['/engine/speed'] > 300, START_TIMEOUT), \
            node.output()
        topics = {name for name, _ in peer.node.get_topic_names_and_types()}
        assert not {t for t in topics if t.startswith(('/sensors/', '/vehicle_bus/'))}
    finally:
        code = node.stop()
        peer.close()
    assert code == 0
    assert not any(m.topic.startswith(('/sensors/', '/vehicle_bus/'))
                   for m in read_messages(bag, raw=True))


@pytest.mark.bench
def test_bench_node_sensor_pairs_quick():
    """``bench_node.py --sensors-pairs``: the sensors' cost figures in its JSON line (small
    sizes: the figures themselves are the benchmark's, not pass conditions)."""
    import json
    import subprocess
    import sys
    res = subprocess.run([sys.executable, str(REPO / 'benchmarks' / 'bench_node.py'),
                          '--sensors-pairs', '1', '--duration', '2', '--warmup', '0.5',
                          '--monitor', 'off', '--domain', str(new_domain())],
                         capture_output=True, text=True, timeout=400, cwd=REPO)
    assert res.returncode == 0, res.stdout + res.stderr
    data = json.loads(res.stdout.strip().splitlines()[-1])
    for key in ('node_cpu_ratio_sensors', 'node_lag_p99_ms_sensors', 'lag_p99_ms_sensors'):
        assert isinstance(data[key], float) and 0 < data[key] < 1e4, key
    assert data['sensor_messages_per_s'] > 100        # the probe received the sensor topics
    assert data['bag_complete'] and data['node_exit_code'] == 0
