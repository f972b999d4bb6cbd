"""The live node: pure logic (no DDS), then the node as its own process talking over real DDS.

Each DDS test runs the node on its own ROS_DOMAIN_ID (1..100, from the pid and a counter) with
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, in this process and in the node's. Every process a test
starts is stopped in ``finally`` (by its own pid).
"""
from __future__ import annotations

import itertools
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import sysconfig
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import yaml

from dmf_sim.live import (LagStats, LiveSimulation, Pacer, check_setpoint, publish_stride,
                          ramp_toward, split_steps)

REPO = Path(__file__).resolve().parents[1]
BENCH = REPO / 'benchmarks' / 'bench_node.py'
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
_seq = itertools.count(1)
START_TIMEOUT = 90.0      # first start compiles/loads the numba kernel


def new_domain() -> int:
    """A ROS_DOMAIN_ID in 1..100, different for every test of this run."""
    return 1 + (os.getpid() * 11 + 37 * next(_seq)) % 100


# ================================================================================================
# Pure logic (no ROS)
# ================================================================================================

def test_check_setpoint_and_ramp():
    assert check_setpoint(1000.0, 500, 2200, 'speed', 'rpm') is None
    assert check_setpoint(500, 500, 2200, 'speed') is None
    for bad, word in ((float('nan'), 'NaN'), (float('inf'), 'inf'), (-float('inf'), 'inf'),
                      (-5.0, 'outside'), (1e9, 'outside'), (True, 'number'), ('1', 'number')):
        assert word in check_setpoint(bad, 500, 2200, 'speed', 'rpm')
    assert ramp_toward(0.0, 1.0, 2.0, 0.1) == pytest.approx(0.2)
    assert ramp_toward(0.95, 1.0, 2.0, 0.1) == 1.0
    assert ramp_toward(1.0, 0.0, 2.0, 0.1) == pytest.approx(0.8)


def test_publish_stride():
    assert publish_stride(1000.0, 1e-4) == 10
    assert publish_stride(10000.0, 1e-4) == 1
    assert publish_stride(200.0, 1e-4) == 50
    assert publish_stride(3000.0, 1e-4) == 3          # 3.33 -> 3 (effective 3333 Hz)
    for bad in (20000.0, 0.0, -1.0, float('nan')):
        with pytest.raises(ValueError):
            publish_stride(bad, 1e-4)


def test_split_steps_records_exactly_every_stride():
    """Chunks of any size record the same absolute steps as one long run would."""
    for stride in range(1, 6):
        rng = np.random.default_rng(stride)
        phase, done, recorded = 0, 0, []
        for n in rng.integers(0, 3 * stride + 2, size=60):
            calls, new_phase = split_steps(int(n), phase, stride)
            assert sum(c[0] for c in calls) == n
            step = done
            for k, s, rows in calls:      # what NewmarkIntegrator.advance records
                got = [step + j + 1 for j in range(k) if (j + 1) % s == 0]
                assert len(got) == rows
                recorded += got
                step += k
            done += int(n)
            phase = new_phase
        assert recorded == list(range(stride, done + 1, stride))


def test_pacer_locks_to_wall_clock_and_handles_overruns():
    p = Pacer(1e-3, 1.0, max_lag=0.05, policy='skip')
    p.anchor(100.0, 0)
    plan = p.plan(100.0105, 0)
    assert plan.nsteps == 10 and plan.lag == pytest.approx(0.0105) and not plan.overrun
    assert p.due_wall(10) == pytest.approx(100.01)
    p.set_rate(2.0, 100.0105, 10)                       # no jump on a rate change
    assert p.plan(100.0205, 10).nsteps == 20
    # skip: backlog dropped, re-anchored, counted once, reported
    plan = p.plan(101.0, 30)
    assert plan.overrun and plan.nsteps == 0 and plan.skipped == pytest.approx(0.9795)
    assert p.overruns == 1 and p.plan(101.001, 30).nsteps == 2
    # catch_up: bounded bursts, one overrun per episode
    c = Pacer(1e-3, 1.0, max_lag=0.05, policy='catch_up')
    c.anchor(0.0, 0)
    first = c.plan(1.0, 0)
    assert first.overrun and first.nsteps == 50
    second = c.plan(1.0, 50)
    assert not second.overrun and second.nsteps == 50 and c.overruns == 1
    assert c.plan(1.0, 990).nsteps == 10 and not c.behind
    # next tick at the next sample's due time, clamped
    p2 = Pacer(1e-4, 1.0)
    p2.anchor(0.0, 0)
    assert p2.next_tick(0.0003, 10) == pytest.approx(0.001)
    assert p2.next_tick(0.0003, 1000) == pytest.approx(0.0103)
    with pytest.raises(ValueError):
        Pacer(1e-4, policy='wait')


def test_lag_stats():
    s = LagStats()
    s.add(0.001)
    s.add(np.array([0.002, 0.003]))
    s.add([])
    w = s.take_window()
    assert w['n'] == 3 and w['max'] == pytest.approx(0.003)
    assert s.take_window()['n'] == 0
    assert s.total_percentile(50) == pytest.approx(0.002, abs=2 * LagStats.BIN)


@pytest.fixture(scope='module')
def sim() -> LiveSimulation:
    return LiveSimulation.from_config('truck_dmf', 'engine_d13', 'A', alpha=3.0,
                                      speed_rpm=1200.0, load=1.0)


def test_live_simulation_samples_and_torques(sim):
    assert len(sim.names) == 22
    s = sim.advance(25)
    assert len(s) == 2 and list(s.step) == [sim.steps - 15, sim.steps - 5]
    assert s.t[0] == pytest.approx(s.step[0] * sim.dt)
    for _ in range(400):                     # 0.4 s at full load, 1200 rpm: knee crossings
        s = sim.advance(10)
    assert sim.knee_crossings > 0
    s = sim.advance(2000)
    assert (s.windup > sim.model.spring.theta).any()
    # fast torque operator == ReducedModel.transmitted_torques (also in the secondary region)
    it, rec, n = sim.integ, sim._rec, len(s)
    ref = sim.model.transmitted_torques(rec.q[:n], rec.v[:n], rec.a[:n],
                                        it.element_loads(s.psi, it.omega_dot))
    assert np.abs(s.effort - ref).max() < 1e-6 * np.abs(ref).max()
    np.testing.assert_allclose(s.position, sim.model.element_angles(rec.q[:n]))
    np.testing.assert_allclose(s.velocity, sim.model.element_angles(rec.v[:n]))
    assert np.all(np.diff(s.psi) > 0)


def test_live_simulation_setpoints_rebuild_reset(sim):
    assert 'NaN' in sim.set_speed_setpoint(float('nan'))
    assert sim.set_load_setpoint(1.5) is not None
    assert sim.speed_setpoint == 1200.0 and sim.load_setpoint == 1.0
    assert sim.set_speed_setpoint(1300.0) is None
    sim.set_ramps(speed_ramp_rpm_per_s=1000.0)
    sim.advance(1000)                         # 0.1 s at 1000 rpm/s
    assert sim.speed == pytest.approx(1300.0)
    t, psi, q = sim.t, sim.psi, sim.integ.q.copy()
    sim.set_dmf(alpha=1.0)                   # rebuild keeps the operating point and state
    assert (sim.t, sim.psi, sim.speed) == (t, psi, pytest.approx(1300.0))
    np.testing.assert_array_equal(sim.integ.q, q)
    assert sim.model.spring.alpha == 1.0
    with pytest.raises(ValueError):
        sim.set_dmf(theta=-1.0)
    assert sim.model.spring.alpha == 1.0
    sim.set_load_set('C')
    assert sim.engine.load_set == 'C' and sim.t == t
    sim.set_ramps(speed_ramp_rpm_per_s=1.0)
    sim.set_speed_setpoint(2000.0)
    sim.reset()                               # static equilibrium at the setpoints
    assert sim.speed == pytest.approx(2000.0) and sim.t == t
    sim.integ.q[3] = np.nan                  # solver health: never publish a broken state
    s = sim.advance(20)
    assert len(s) == 0 and sim.solver_resets == 1 and sim.finite
    assert len(sim.advance(20)) == 2


def test_node_module_imports_without_dds_and_params_file_matches():
    import dmf_sim.node as node
    cfg = yaml.safe_load((REPO / 'config' / 'driveline_node.yaml').read_text())
    params = cfg['driveline_node']['ros__parameters']
    assert set(params) == set(node.PARAMETERS)
    for name, value in params.items():
        default, text, rng, _ = node.PARAMETERS[name]
        assert value == default and type(value) is type(default), name
        assert text
        if rng is not None:
            assert rng[0] <= default <= rng[1]


# ================================================================================================
# The node over DDS
# ================================================================================================

rclpy = pytest.importorskip('rclpy')
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402


class NodeProcess:
    """The node as a subprocess (python -m dmf_sim.node or an executable)."""

    def __init__(self, args, cwd: Path, domain: int, exe=None, env=None) -> None:
        self.cmd = list(exe or [sys.executable, '-m', 'dmf_sim.node']) + list(args)
        self.env = dict(env or os.environ, ROS_DOMAIN_ID=str(domain),
                        ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
        self.log_path = cwd / f'node_{next(_seq)}.log'
        self._log = open(self.log_path, 'w')
        self.proc = subprocess.Popen(self.cmd, cwd=cwd, env=self.env, stdout=self._log,
                                     stderr=subprocess.STDOUT)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, sig=signal.SIGTERM, timeout: float = 30.0) -> int:
        if self.alive():
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout=timeout)
        finally:
            self.close()

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        self._log.close()

    def output(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()


class Peer:
    """An rclpy participant in this process, on the node's domain."""

    def __init__(self, domain: int) -> None:
        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node(f'test_peer_{os.getpid()}', context=self.ctx)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.last: dict = {}
        self.counts: dict = defaultdict(int)
        self.series: dict = defaultdict(list)
        self.qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)

    def subscribe(self, topic: str, msg_type, keep: bool = False):
        def cb(msg):
            self.last[topic] = msg
            self.counts[topic] += 1
            if keep:
                self.series[topic].append((time.monotonic(), msg.data))
        return self.node.create_subscription(msg_type, topic, cb, self.qos)

    def spin_until(self, cond, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if cond():
                return True
            self.executor.spin_once(timeout_sec=0.02)
        return bool(cond())

    def spin_for(self, seconds: float) -> None:
        self.spin_until(lambda: False, seconds)

    def call(self, srv_type, name: str, request, timeout: float = 15.0):
        client = self.node.create_client(srv_type, name)
        assert client.wait_for_service(timeout_sec=timeout), f'service {name} not found'
        fut = client.call_async(request)
        assert self.spin_until(fut.done, timeout), f'{name} timed out'
        self.node.destroy_client(client)
        return fut.result()

    def set_params(self, node_name: str, **values):
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        req = SetParameters.Request()
        req.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
        return self.call(SetParameters, f'/{node_name}/set_parameters', req).results

    def diagnostics(self) -> dict:
        msg = self.last.get('/diagnostics')
        if msg is None:
            return {}
        st = msg.status[0]
        return {'_name': st.name, '_level': st.level, **{kv.key: kv.value for kv in st.values}}

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


def _recent_mean(series, seconds: float) -> float:
    end = series[-1][0]
    return float(np.mean([v for t, v in series if t >= end - seconds]))


def _publish_when_matched(peer: Peer, pub, value: float, timeout: float = 20.0) -> None:
    """Publish a setpoint once matched, a few times (setpoints are idempotent; the first sample
    can arrive before the node's reader has discovered this writer)."""
    assert peer.spin_until(lambda: pub.get_subscription_count() > 0, timeout)
    from std_msgs.msg import Float64
    for _ in range(4):
        pub.publish(Float64(data=float(value)))
        peer.spin_for(0.1)


def _mcap_counts(path: Path) -> tuple[dict, object]:
    """Messages per topic decoded with the independent reader (mcap + mcap_ros2), and the
    file's summary (None if it has none)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    mcap_file = next(path.glob('*.mcap'))
    counts: dict = defaultdict(int)
    decoded: dict = {}
    with open(mcap_file, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for _schema, channel, _message, msg in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            decoded[channel.topic] = msg
    return dict(counts), summary, decoded


def test_setpoints_reach_outputs_and_sigterm_closes_bag(tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from dmf_sim.model import load_model

    domain = new_domain()
    bag = tmp_path / 'run_bag'
    # max_lag 5 s: a VM hiccup must not skip ahead here (gaps in the stamps are tested below)
    node = NodeProcess(['--ros-args', '--params-file', str(REPO / 'config' / 'driveline_node.yaml'),
                        '-p', 'record:=true', '-p', f'bag_path:={bag}', '-p', 'max_lag:=5.0'],
                       tmp_path, domain)
    peer = Peer(domain)
    try:
        peer.subscribe('/engine/speed', Float64, keep=True)
        peer.subscribe('/driveline/dmf_windup', Float64, keep=True)
        peer.subscribe('/driveline/joint_states', JointState)
        peer.subscribe('/diagnostics', DiagnosticArray)
        assert peer.spin_until(lambda: len(peer.series['/driveline/dmf_windup']) > 300,
                               START_TIMEOUT), node.output()
        peer.spin_for(0.5)
        w_before = _recent_mean(peer.series['/driveline/dmf_windup'], 0.4)
        assert peer.series['/engine/speed'][-1][1] == pytest.approx(1000.0)

        speed_pub = peer.node.create_publisher(Float64, '/engine/speed_setpoint', peer.qos)
        load_pub = peer.node.create_publisher(Float64, '/engine/load_setpoint', peer.qos)
        _publish_when_matched(peer, load_pub, 1.0)
        _publish_when_matched(peer, speed_pub, 1500.0)
        assert peer.spin_until(lambda: peer.series['/engine/speed'][-1][1] > 1499.99, 20.0)
        peer.spin_for(0.8)
        w_after = _recent_mean(peer.series['/driveline/dmf_windup'], 0.4)
        assert w_after - w_before > 0.05          # full load at 1500 rpm winds the DMF up
        speeds = [v for _, v in peer.series['/engine/speed']]
        assert np.all(np.diff(speeds) >= -1e-9)   # ramped, monotone

        js = peer.last['/driveline/joint_states']
        assert list(js.name) == load_model('truck_dmf').names
        assert len(js.position) == len(js.velocity) == len(js.effort) == 22
        assert np.all(np.isfinite(js.effort)) and np.abs(js.effort).max() > 100
        assert peer.spin_until(lambda: peer.diagnostics().get('speed_rpm', '') == '1500.000', 5)
        d = peer.diagnostics()
        assert d['recording'] == 'true' and d['state_finite'] == 'true'
        for key in ('real_time_factor', 'lag_p99_ms', 'overruns', 'dmf_region', 'knee_crossings'):
            assert key in d
    finally:
        peer.close()
        rc = node.stop(signal.SIGTERM)
    out = node.output()
    assert rc == 0, out
    assert 'Traceback' not in out and 'closed' in out

    # complete bag: metadata counts == MCAP summary == what an independent reader decodes
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    per_topic = {t['topic_metadata']['name']: t['message_count']
                 for t in meta['topics_with_message_count']}
    assert sum(per_topic.values()) == meta['message_count'] > 0
    custom = meta['custom_data']                 # what dmf-sim analyze uses for its HBM overlay
    assert custom['dmf_sim.driveline'] == 'truck_dmf' and custom['dmf_sim.load'] == '0.5'
    assert custom['dmf_sim.alpha'] == '2.5' and custom['dmf_sim.load_set'] == 'A'
    counts, summary, decoded = _mcap_counts(bag)
    assert summary is not None and summary.statistics.message_count == meta['message_count']
    assert counts == {k: v for k, v in per_topic.items() if v}
    streams = ['/driveline/joint_states', '/driveline/dmf_windup', '/engine/speed',
               '/engine/crank_angle']
    assert len({per_topic[t] for t in streams}) == 1       # every sample on every stream
    assert per_topic['/diagnostics'] >= 1
    assert list(decoded['/driveline/joint_states'].name)[9] == 'PRIMARY FLYWHEEL'

    # rosbags reads it too; stamps are contiguous simulated time (1 kHz, nothing lost)
    from rosbags.highlevel import AnyReader
    with AnyReader([bag]) as reader:
        conns = {c.topic: c for c in reader.connections}
        stamps, speed, crank = [], [], []
        for conn, t, raw in reader.messages(connections=[conns[t] for t in streams]):
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == '/driveline/joint_states':
                stamps.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
                assert t == stamps[-1]
            elif conn.topic == '/engine/speed':
                speed.append(msg.data)
            elif conn.topic == '/engine/crank_angle':
                crank.append(msg.data)
    assert len(stamps) == per_topic['/driveline/joint_states']
    assert np.abs(np.diff(stamps) - 1_000_000).max() <= 1_000
    assert min(speed) == pytest.approx(1000.0) and max(speed) == pytest.approx(1500.0)
    assert np.all(np.diff(crank) > 0)


def test_bad_input_parameters_reset_and_record_service(tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64
    from std_srvs.srv import SetBool, Trigger

    domain = new_domain()
    existing = tmp_path / 'existing_bag'
    existing.mkdir()
    node = NodeProcess(['--ros-args', '-p', 'publish_rate:=200.0', '-p', f'bag_path:={existing}'],
                       tmp_path, domain)
    peer = Peer(domain)
    try:
        peer.subscribe('/engine/speed', Float64, keep=True)
        peer.subscribe('/diagnostics', DiagnosticArray)
        assert peer.spin_until(lambda: peer.counts['/engine/speed'] > 10, START_TIMEOUT), \
            node.output()

        # ---- 10,000 garbage setpoints mixed with good ones; the last good value holds ------
        speed_pub = peer.node.create_publisher(Float64, '/engine/speed_setpoint', peer.qos)
        load_pub = peer.node.create_publisher(Float64, '/engine/load_setpoint', peer.qos)
        assert peer.spin_until(lambda: speed_pub.get_subscription_count() > 0
                               and load_pub.get_subscription_count() > 0, 20.0)
        bad_speed = [math.nan, math.inf, -math.inf, -5.0, 1e9, 0.0, 3000.0, 499.0]
        bad_load = [math.nan, math.inf, -math.inf, -5.0, 1e9, 1.5, -0.1]
        for i in range(10_000):
            good = i % 10 == 3
            speed_pub.publish(Float64(data=1400.0 if good else bad_speed[i % len(bad_speed)]))
            load_pub.publish(Float64(data=0.8 if good else bad_load[i % len(bad_load)]))
            if i % 500 == 0:
                peer.executor.spin_once(timeout_sec=0)
        assert node.alive(), node.output()
        assert peer.spin_until(lambda: abs(peer.series['/engine/speed'][-1][1] - 1400.0) < 1e-6,
                               20.0)
        peer.spin_for(0.5)
        assert abs(peer.series['/engine/speed'][-1][1] - 1400.0) < 1e-6
        assert peer.spin_until(lambda: peer.diagnostics().get('load', '') == '0.8000', 10.0)
        d = peer.diagnostics()
        assert d['speed_setpoint_rpm'] == '1400' and d['load_setpoint'] == '0.8'
        assert int(d['rejected_setpoints']) > 0 and d['state_finite'] == 'true'
        assert 'rejected' in node.output()

        # ---- runtime parameters: invalid ones refused with a reason ---------------------------
        refused = {
            'real_time_factor': (-1.0, ''), 'publish_rate': (20000.0, 'step rate'),
            'pacing': ('slow', 'pacing'), 'theta': (0.0, 'theta'), 'dt': (1e-3, ''),
            'speed_max_rpm': (3000.0, 'engine data range'), 'overrun_policy': ('wait', 'overrun'),
            'record': (True, 'exists'), 'load_set': ('D', 'load_set'),
        }
        for name, (value, word) in refused.items():
            (res,) = peer.set_params('driveline_node', **{name: value})
            assert not res.successful, name
            assert res.reason and word in res.reason, (name, res.reason)
        (res,) = peer.set_params('driveline_node', alpha=3.0)
        assert res.successful, res.reason
        assert peer.spin_until(lambda: peer.diagnostics().get('alpha') == '3', 5.0)
        n0 = peer.counts['/engine/speed']
        assert peer.spin_until(lambda: peer.counts['/engine/speed'] > n0 + 50, 5.0)

        # ---- reset: static equilibrium at the setpoints (speed jumps past the slow ramp) -----
        (res,) = peer.set_params('driveline_node', speed_ramp_rpm_per_s=10.0)
        assert res.successful
        _publish_when_matched(peer, speed_pub, 2000.0)
        peer.spin_for(0.3)
        assert peer.series['/engine/speed'][-1][1] < 1420.0
        resp = peer.call(Trigger, '/driveline_node/reset', Trigger.Request())
        assert resp.success and '2000' in resp.message
        assert peer.spin_until(
            lambda: abs(peer.series['/engine/speed'][-1][1] - 2000.0) < 1e-6, 5.0)

        # ---- record service: refuses an existing bag, records to a new one --------------------
        resp = peer.call(SetBool, '/driveline_node/record', SetBool.Request(data=True))
        assert not resp.success and 'exists' in resp.message
        new_bag = tmp_path / 'service_bag'
        (res,) = peer.set_params('driveline_node', bag_path=str(new_bag))
        assert res.successful
        resp = peer.call(SetBool, '/driveline_node/record', SetBool.Request(data=True))
        assert resp.success and 'service_bag' in resp.message
        peer.spin_for(1.0)
        resp = peer.call(SetBool, '/driveline_node/record', SetBool.Request(data=False))
        assert resp.success
        meta = yaml.safe_load((new_bag / 'metadata.yaml').read_text())
        assert meta['rosbag2_bagfile_information']['message_count'] > 100
        assert _mcap_counts(new_bag)[1] is not None
        assert list(existing.iterdir()) == []

        # ---- pacing: a stalled node reports its overrun (policy skip), never drifts silently ---
        peer.spin_for(1.1)
        d0 = peer.diagnostics()
        node.proc.send_signal(signal.SIGSTOP)
        time.sleep(0.3)
        node.proc.send_signal(signal.SIGCONT)
        assert peer.spin_until(
            lambda: int(peer.diagnostics()['overruns']) > int(d0['overruns']), 5.0)
        d = peer.diagnostics()
        assert d['_level'] == b'\x01' and 'overrun' in peer.last['/diagnostics'].status[0].message
        assert float(d['skipped_s']) - float(d0['skipped_s']) > 0.25
        assert abs(float(d['wall_minus_stamp_s'])) < 0.05     # published time skipped ahead
        assert peer.spin_until(                      # live again at once, at real time
            lambda: abs(float(peer.diagnostics()['real_time_factor']) - 1.0) < 0.02, 5.0)
        assert 'overrun' in node.output()

        # ---- another real-time factor: /clock carries the simulated time ----------------------
        from rosgraph_msgs.msg import Clock
        clocks = []
        peer.node.create_subscription(
            Clock, '/clock', lambda m: clocks.append((time.monotonic(),
                                                      m.clock.sec + 1e-9 * m.clock.nanosec)),
            peer.qos)
        (res,) = peer.set_params('driveline_node', real_time_factor=2.0)
        assert res.successful
        assert peer.spin_until(lambda: len(clocks) > 10, 10.0)
        peer.spin_for(1.0)
        (w0, c0), (w1, c1) = clocks[1], clocks[-1]
        assert (c1 - c0) / (w1 - w0) == pytest.approx(2.0, rel=0.15)
        (res,) = peer.set_params('driveline_node', real_time_factor=1.0)
        assert res.successful
    finally:
        peer.close()
        rc = node.stop(signal.SIGINT)
    assert rc == 0, node.output()
    assert 'Traceback' not in node.output()


def test_sigkill_leaves_readable_bag_that_recovers(tmp_path):
    from std_msgs.msg import Float64

    from dmf_sim.bag import read_messages, recover_bag

    domain = new_domain()
    bag = tmp_path / 'killed_bag'
    node = NodeProcess(['--ros-args', '-p', 'record:=true', '-p', f'bag_path:={bag}'],
                       tmp_path, domain)
    peer = Peer(domain)
    try:
        peer.subscribe('/engine/speed', Float64)
        assert peer.spin_until(lambda: peer.counts['/engine/speed'] > 10, START_TIMEOUT), \
            node.output()
        peer.spin_for(1.5)
    finally:
        peer.close()
        node.stop(signal.SIGKILL)
    msgs = list(read_messages(bag))
    by_topic: dict = defaultdict(int)
    for m in msgs:
        by_topic[m.topic] += 1
    assert by_topic['/driveline/joint_states'] > 500
    js = [m for m in msgs if m.topic == '/driveline/joint_states'][-1]
    assert len(js.msg.name) == 22 and js.msgtype == 'sensor_msgs/msg/JointState'

    report = recover_bag(bag, tmp_path / 'recovered')
    assert report.message_count == len(msgs)
    meta = yaml.safe_load((tmp_path / 'recovered' / 'metadata.yaml').read_text())
    counts, summary, _ = _mcap_counts(tmp_path / 'recovered')
    assert summary is not None
    assert sum(counts.values()) == meta['rosbag2_bagfile_information']['message_count'] == len(msgs)
    from rosbags.highlevel import AnyReader
    with AnyReader([tmp_path / 'recovered']) as reader:
        assert reader.message_count == len(msgs)


def _bad_configs(tmp: Path):
    bad_line = tmp / 'bad_line.yaml'
    bad_line.write_text('name: bad\nelements: []\n')
    bad_params = tmp / 'bad_params.yaml'
    bad_params.write_text('driveline_node:\n  ros__parameters:\n    pacing: slow\n')
    return [
        (['-p', 'driveline:=no_such_driveline'], 'driveline'),
        (['-p', f'driveline:={bad_line}'], 'elements'),
        (['--params-file', str(tmp / 'missing.yaml')], 'params file'),
        (['--params-file', str(bad_params)], 'pacing'),
        (['-p', 'dt:=-1.0'], 'dt'),
        (['-p', 'publish_rate:=200'], 'decimal point'),
    ]


def test_bad_configuration_stops_startup_with_one_line(tmp_path):
    env = dict(os.environ, ROS_DOMAIN_ID=str(new_domain()))
    for args, word in _bad_configs(tmp_path):
        res = subprocess.run([sys.executable, '-m', 'dmf_sim.node', '--ros-args', *args],
                             cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
        err = res.stderr + res.stdout
        assert res.returncode == 2, (args, err)
        assert 'Traceback' not in err, err
        lines = [ln for ln in err.splitlines() if word in ln]
        assert len(lines) == 1 and ('error' in lines[0].lower() or 'failed' in lines[0]), err


def test_installed_layout_runs_like_ros2_run(tmp_path):
    """colcon's install form, then launch the way ``ros2 run`` finds executables."""
    from std_msgs.msg import Float64

    src = tmp_path / 'src'
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(
        '.venv', '.git', 'build', 'install', 'log', '__pycache__', '*.egg-info', 'dmf_bag_*',
        '.pytest_cache', 'out'))
    prefix = tmp_path / 'prefix'
    subprocess.run([sys.executable, 'setup.py', '-q', 'install', '--prefix', str(prefix),
                    '--single-version-externally-managed', '--record', str(tmp_path / 'files.txt')],
                   cwd=src, check=True, capture_output=True, timeout=300)
    exe = prefix / 'lib' / 'dmf_sim' / 'driveline_node'
    assert exe.is_file() and os.access(exe, os.X_OK)
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'dmf_sim').is_file()
    assert (prefix / 'share' / 'dmf_sim' / 'config' / 'driveline_node.yaml').is_file()

    site = Path(sysconfig.get_path('purelib', vars={'base': str(prefix)}))
    env = dict(os.environ, AMENT_PREFIX_PATH=str(prefix),
               PYTHONPATH=os.pathsep.join([str(site), os.environ.get('PYTHONPATH', '')]))
    # ros2run: prefix = get_package_prefix(pkg); executable = <prefix>/lib/<pkg>/<name>
    probe = subprocess.run(
        [sys.executable, '-c', 'from ament_index_python.packages import get_package_prefix; '
         'import dmf_sim, dmf_sim.paths; print(get_package_prefix("dmf_sim")); '
         'print(dmf_sim.__file__); print(dmf_sim.paths.config_dir())'],
        env=env, capture_output=True, text=True, check=True, cwd=tmp_path)
    found_prefix, module_file, config_dir = probe.stdout.split('\n')[:3]
    assert Path(found_prefix) == prefix
    assert Path(module_file).is_relative_to(prefix)          # the installed copy runs
    assert Path(config_dir) == prefix / 'share' / 'dmf_sim' / 'config'

    domain = new_domain()
    node = NodeProcess(['--ros-args', '-r', '__node:=my_node', '-p', 'publish_rate:=200.0'],
                       tmp_path, domain, exe=[str(Path(found_prefix) / 'lib' / 'dmf_sim' /
                                                  'driveline_node')], env=env)
    peer = Peer(domain)
    try:
        peer.subscribe('/engine/speed', Float64, keep=True)
        assert peer.spin_until(lambda: ('my_node', '/') in
                               peer.node.get_node_names_and_namespaces(), START_TIMEOUT), \
            node.output()
        assert peer.spin_until(lambda: peer.counts['/engine/speed'] > 20, 30.0), node.output()
        n0, t0 = peer.counts['/engine/speed'], time.monotonic()
        peer.spin_for(2.0)
        rate = (peer.counts['/engine/speed'] - n0) / (time.monotonic() - t0)
        assert 120.0 < rate < 260.0, rate                     # 200 Hz
        names = {n for n, _ in peer.node.get_node_names_and_namespaces()}
        assert 'driveline_node' not in names
    finally:
        peer.close()
        rc = node.stop(signal.SIGTERM)
    assert rc == 0, node.output()


def test_bench_node_quick_prints_json():
    res = subprocess.run([sys.executable, str(BENCH), '--duration', '3', '--fast-duration', '1.5',
                          '--warmup', '1', '--domain', str(new_domain())],
                         capture_output=True, text=True, timeout=240, cwd=REPO)
    assert res.returncode == 0, res.stdout + res.stderr
    data = json.loads(res.stdout.strip().splitlines()[-1])
    for key in ('rtf_mean', 'lag_p99_ms', 'cpu_pct', 'max_rtf_fast'):
        assert isinstance(data[key], float) and math.isfinite(data[key]) and data[key] > 0, key
    assert 0.8 < data['rtf_mean'] < 1.2
    assert data['bag_complete'] and data['node_exit_code'] == 0
