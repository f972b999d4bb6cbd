"""Benchmark: the live driveline node in real time, and as fast as possible.

Starts ``python -m dmf_sim.node`` as its own process (dt = 1e-4 s, JointState and the three
Float64 streams at 1 kHz, recording to an MCAP bag) on a private DDS domain (localhost only)
and measures from a second process, over real DDS:

* real-time factor: per diagnostics window (1 s of wall time, from the node's simulated time),
  mean/min/max over the measurement, and overall from the JointState stamps vs receive times;
* lag, wall minus simulated time: end to end for every JointState received (receive wall
  clock minus the header stamp, which is start wall time + simulated time), p50/p99/max — the
  headline ``lag_p99_ms``; and the node's own per-sample lag (publish time minus due time) from
  its diagnostics (largest window p99, and p99 over the whole run);
* the node's CPU use [% of one core] from /proc/<pid>/stat (utime + stime, all its threads);
* the fastest real-time factor in as-fast-as-possible mode (parameter real_time_factor := 0),
  with recording still on (and once more with recording off), publishing at the same rate.
  The JointState subscription is dropped first, so the figure is the node's own speed.

With ``--nodes N`` (several trucks on one machine) N nodes run at once in namespaces /truck1 ..
/truckN, each recording its own bag; every figure is measured per node (``per_node``), the
top-level ones are the mean (rtf_mean, cpu_pct), the worst (rtf_min, lag_*) or the sum
(cpu_pct_total, overruns), and ``realtime_ok`` says whether every node kept real time (every
1-s window within 2 % of factor 1, no overrun, end-to-end lag p99 below max_lag 50 ms). The
fast-mode part runs only with one node.

Each bag is closed by SIGTERM and checked (message counts in metadata.yaml vs the MCAP summary).
Last line: one JSON object.

Sensors (the driveline's tooth wheels and bus signals, parameter ``sensors``): ``--sensors on``
(the node's default) or ``off`` for the runs above; with them on a process of its own (a stack
under test) subscribes to every sensor topic and counts what it receives. ``--sensors-pairs N``
measures their cost instead: N pairs of real-time runs, each a fresh node, sensors off then on
(alternating, so a machine whose speed drifts affects both alike), and reports
``node_cpu_ratio_sensors`` (median of the per-pair CPU ratios on/off, with min and max) and
``node_lag_p99_ms_sensors`` (the
node-side lag p99 of the worst 1-s window of the measurement with sensors on: median and max
over the runs; the node's lag since its start would count its start-up), ``lag_p99_ms_sensors``
(the end-to-end JointState lag p99, the same over the runs) and the real-time factor.

    python benchmarks/bench_node.py [--duration 60] [--fast-duration 10] [--warmup 3] [--nodes N]
                                    [--config truck_dmf_friction]
    python benchmarks/bench_node.py --sensors-pairs 3 --duration 30
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from dmf_sim.live.health import status_name

# speed setpoints of --setpoint-period: through the default DMF's 1.5th-order resonance
SETPOINT_SPEEDS_RPM = (960.0, 1010.0, 905.0, 1100.0, 940.0, 1050.0, 980.0, 920.0, 1200.0, 870.0)
MAX_LAG_MS = 50.0            # the node's default max_lag: above it a lag is an overrun
REALTIME_TOLERANCE = 0.02    # every 1-s window within 2 % of factor 1 counts as real time
SET_PARAMS_TIMEOUT_S = 10.0  # wait for one set_parameters answer ...
SET_PARAMS_ATTEMPTS = 3      # ... and ask this many times in all


def proc_cpu_seconds(pid: int) -> float:
    """utime + stime [s] of a process (all threads), from /proc/<pid>/stat."""
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def proc_rss_mib(pid: int) -> float:
    """Resident set size [MiB] of a process, from /proc/<pid>/status."""
    with open(f'/proc/{pid}/status') as f:
        for line in f:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024.0
    return float('nan')


def default_domain() -> int:
    """A ROS_DOMAIN_ID from DMF_SIM_TEST_DOMAINS ('LO-HI', default 1-100) and the pid."""
    lo, hi = (int(x) for x in os.environ.get('DMF_SIM_TEST_DOMAINS', '1-100').split('-'))
    return lo + (os.getpid() * 7 + 3) % (hi - lo + 1)


class NodeRun:
    """One driveline_node process (namespace ``ns``, '' = none) recording to ``bag``."""

    def __init__(self, ns: str, bag: Path, workdir: Path, extra: list[str]) -> None:
        self.ns, self.bag = ns, bag
        self.fqn = f'{ns}/driveline_node'
        cmd = [sys.executable, '-m', 'dmf_sim.node', '--ros-args', '-p', 'record:=true',
               '-p', f'bag_path:={bag}', *extra]
        if ns:
            cmd += ['-r', f'__ns:={ns}']
        self.log = open(workdir / f'node{ns.replace("/", "_")}.log', 'w')
        self.proc = subprocess.Popen(cmd, env=dict(os.environ, PYTHONUNBUFFERED='1'),
                                     stdout=self.log, stderr=subprocess.STDOUT, cwd=workdir)

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log.close()
        return self.proc.returncode

    def bag_check(self) -> dict:
        """Message counts of the closed bag: metadata.yaml vs the MCAP summaries."""
        import yaml
        from mcap.reader import make_reader

        meta = yaml.safe_load((self.bag / 'metadata.yaml').read_text())
        meta = meta['rosbag2_bagfile_information']
        mcap_count, complete = 0, True
        for rel in meta['relative_file_paths']:
            with open(self.bag / rel, 'rb') as f:
                summary = make_reader(f).get_summary()
            if summary is None:
                complete = False
            else:
                mcap_count += sum(summary.statistics.channel_message_counts.values())
        return {'bag_messages': int(meta['message_count']),
                'bag_complete': complete and mcap_count == meta['message_count'],
                'bag_files': len(meta['relative_file_paths']),
                'bag_mb': sum(p.stat().st_size for p in self.bag.iterdir()) / 1e6}


class Probe:
    """rclpy peer on the nodes' domain: JointState stamps (raw CDR) and diagnostics per node."""

    def __init__(self, domain: int, cap: int, fqns: list[str]) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rcl_interfaces.srv import SetParameters
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState

        self.rclpy = rclpy
        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node('bench_probe', context=self.ctx)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.fqns = fqns
        self.recv = {f: np.zeros(cap, dtype=np.int64) for f in fqns}
        self.stamp = {f: np.zeros(cap, dtype=np.int64) for f in fqns}
        self.n = dict.fromkeys(fqns, 0)
        self.recording = False
        self.diags: dict[str, list[tuple[float, dict]]] = {f: [] for f in fqns}
        self.js_subs = [self.node.create_subscription(
            JointState, f'{f.rsplit("/", 1)[0]}/driveline/joint_states',
            lambda data, f=f: self._on_js(f, data), qos, raw=True) for f in fqns]
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, qos)
        self.param_clients = {f: self.node.create_client(SetParameters, f'{f}/set_parameters')
                              for f in fqns}
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001 - shutdown races
            pass

    def _on_js(self, fqn: str, data: bytes) -> None:
        now = time.time_ns()
        n = self.n[fqn]
        if self.recording and n < self.recv[fqn].shape[0]:
            sec, nsec = struct.unpack_from('<iI', data, 4)   # CDR header, then header.stamp
            self.recv[fqn][n] = now
            self.stamp[fqn][n] = sec * 1_000_000_000 + nsec
            self.n[fqn] = n + 1

    def _on_diag(self, msg) -> None:
        for st in msg.status:     # the node's health status (its monitor shares hardware_id)
            if st.hardware_id in self.diags and st.name == status_name(st.hardware_id):
                self.diags[st.hardware_id].append(
                    (time.monotonic(), {kv.key: kv.value for kv in st.values}))

    def wait(self, cond, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if cond():
                return True
            time.sleep(0.02)
        return cond()

    def set_params(self, fqn: str, **values) -> list:
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        client = self.param_clients[fqn]
        if not client.wait_for_service(timeout_sec=10.0):
            raise RuntimeError(f'parameter service of {fqn} not found')
        req = SetParameters.Request()
        req.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
        # a response can be lost when the service answers before its response writer has
        # matched this client's reader (DDS discovery, slow on a loaded machine): setting the
        # same values again is harmless, so ask again instead of failing the run
        for _ in range(SET_PARAMS_ATTEMPTS):
            fut = client.call_async(req)
            if self.wait(fut.done, SET_PARAMS_TIMEOUT_S):
                return fut.result().results
            client.remove_pending_request(fut)
        raise RuntimeError(f'set_parameters of {fqn}: no answer in {SET_PARAMS_ATTEMPTS} x '
                           f'{SET_PARAMS_TIMEOUT_S:g} s')

    def setpoint_publishers(self, namespace: str = '') -> dict:
        """Reliable keep-all publishers of the speed and load setpoints of the node in
        ``namespace``, once the node subscribes (setpoints are commands: none may be lost)."""
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Float64

        keep_all = QoSProfile(history=HistoryPolicy.KEEP_ALL,
                              reliability=ReliabilityPolicy.RELIABLE)
        pubs = {k: self.node.create_publisher(Float64, f'{namespace}/engine/{k}_setpoint',
                                              keep_all) for k in ('speed', 'load')}
        if not self.wait(lambda: all(p.get_subscription_count() for p in pubs.values()), 20.0):
            raise RuntimeError('the node does not subscribe to the setpoints')
        return pubs

    def drop_joint_states(self) -> None:
        for sub in self.js_subs:
            self.node.destroy_subscription(sub)

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.ctx)


def diag_values(diags, t0: float, t1: float, key: str) -> list[float]:
    out = []
    for t, d in diags:
        if t0 <= t <= t1 and key in d:
            try:
                out.append(float(d[key]))
            except ValueError:
                pass
    return out


def rate_between(diags, t0: float, t1: float) -> float:
    """Simulated seconds per wall second between the first and last diagnostics in [t0, t1]."""
    pts = [(t, float(d['sim_time_s'])) for t, d in diags if t0 <= t <= t1]
    if len(pts) < 2:
        return float('nan')
    return (pts[-1][1] - pts[0][1]) / (pts[-1][0] - pts[0][0])


def _stat(fn, values) -> float:
    return float(fn(values)) if len(values) else float('nan')


def measure_realtime(probe: Probe, runs: list[NodeRun], duration: float,
                     setpoint_period: float = 0.0) -> list[dict]:
    """Per node: real-time factor, end-to-end and node-side lag, overruns, CPU. With
    ``setpoint_period`` > 0 [s] every node gets the next speed of :data:`SETPOINT_SPEEDS_RPM` at
    that period (each one a new operating point for the monitor's prediction)."""
    from std_msgs.msg import Float64

    pubs = ([probe.setpoint_publishers(r.ns)['speed'] for r in runs]
            if setpoint_period > 0 else [])
    ovr0 = {r.fqn: int(probe.diags[r.fqn][-1][1]['overruns']) for r in runs}
    c0 = {r.fqn: proc_cpu_seconds(r.proc.pid) for r in runs}
    w0 = time.monotonic()
    probe.recording = True
    k = 0
    while (now := time.monotonic()) < w0 + duration:
        if pubs and now >= w0 + k * setpoint_period:
            for pub in pubs:
                pub.publish(Float64(data=SETPOINT_SPEEDS_RPM[k % len(SETPOINT_SPEEDS_RPM)]))
            k += 1
        wake = w0 + (k * setpoint_period if pubs else duration)
        time.sleep(max(0.0, min(wake, w0 + duration) - time.monotonic()))
    probe.recording = False
    c1 = {r.fqn: proc_cpu_seconds(r.proc.pid) for r in runs}
    w1 = time.monotonic()
    time.sleep(1.2)                                   # the diagnostics of the last window
    out = []
    for r in runs:
        f, n = r.fqn, probe.n[r.fqn]
        lat = (probe.recv[f][:n] - probe.stamp[f][:n]) / 1e6    # ms
        diags = probe.diags[f]
        rtf_w = diag_values(diags, w0 + 0.5, w1 + 0.5, 'real_time_factor')
        node_p99 = diag_values(diags, w0 + 0.5, w1 + 0.5, 'lag_p99_ms')
        last = diags[-1][1]
        span_stamp = (probe.stamp[f][n - 1] - probe.stamp[f][0]) / 1e9 if n > 1 else math.nan
        span_recv = (probe.recv[f][n - 1] - probe.recv[f][0]) / 1e9 if n > 1 else math.nan
        out.append({
            'node': f,
            'rtf_mean': _stat(np.mean, rtf_w), 'rtf_min': _stat(np.min, rtf_w),
            'rtf_max': _stat(np.max, rtf_w), 'rtf_windows': len(rtf_w),
            'rtf_overall': span_stamp / span_recv,
            'lag_p50_ms': _stat(lambda x: np.percentile(x, 50), lat),
            'lag_p99_ms': _stat(lambda x: np.percentile(x, 99), lat),
            'lag_max_ms': _stat(np.max, lat),
            'joint_states_received': int(n),
            'node_lag_p99_ms_worst_window': _stat(np.nanmax, node_p99),
            'node_lag_p99_ms_run': float(last['lag_p99_ms_total']),
            'node_lag_max_ms_run': float(last['lag_max_ms_total']),
            'overruns': int(last['overruns']) - ovr0[f],
            'cpu_pct': 100.0 * (c1[f] - c0[f]) / (w1 - w0),
        })
    return out


def realtime_ok(node: dict) -> bool:
    return (node['rtf_windows'] > 0 and abs(node['rtf_min'] - 1.0) <= REALTIME_TOLERANCE
            and abs(node['rtf_max'] - 1.0) <= REALTIME_TOLERANCE and node['overruns'] == 0
            and node['lag_p99_ms'] < MAX_LAG_MS)


def measure_fast(probe: Probe, run: NodeRun, fast_duration: float) -> dict:
    """Fastest real-time factor (and CPU) with recording on, then off."""
    probe.drop_joint_states()
    fast = {}
    for label, record in (('max_rtf_fast', True), ('max_rtf_fast_no_record', False)):
        if not record:
            probe.set_params(run.fqn, record=False)
        res = probe.set_params(run.fqn, real_time_factor=0.0)
        if not res[0].successful:
            raise RuntimeError(f'switching to fast mode refused: {res[0].reason}')
        t0 = time.monotonic()
        cf0 = proc_cpu_seconds(run.proc.pid)
        time.sleep(fast_duration + 1.5)
        t1 = time.monotonic()
        fast[label] = rate_between(probe.diags[run.fqn], t0 + 1.2, t1)
        fast[label + '_cpu_pct'] = 100.0 * (proc_cpu_seconds(run.proc.pid) - cf0) / (t1 - t0)
        probe.set_params(run.fqn, real_time_factor=1.0)
        time.sleep(0.5)
    return fast


def summarize(per_node: list[dict], args) -> dict:
    """Top-level figures: one node's as they are; several: mean / worst / sum."""
    def worst(key, fn=max):
        return float(fn(n[key] for n in per_node))

    return {
        'nodes': len(per_node), 'duration_s': args.duration, 'dt_s': 1e-4,
        'publish_rate_hz': args.publish_rate, 'recording': True,
        'monitor': args.monitor == 'on', 'setpoint_period_s': args.setpoint_period,
        'rtf_mean': float(np.mean([n['rtf_mean'] for n in per_node])),
        'rtf_min': worst('rtf_min', min), 'rtf_max': worst('rtf_max'),
        'rtf_windows': min(n['rtf_windows'] for n in per_node),
        'rtf_overall': worst('rtf_overall', min),
        'lag_p50_ms': worst('lag_p50_ms'), 'lag_p99_ms': worst('lag_p99_ms'),
        'lag_max_ms': worst('lag_max_ms'),
        'joint_states_received': min(n['joint_states_received'] for n in per_node),
        'joint_states_expected': int(round(args.duration * args.publish_rate)),
        'node_lag_p99_ms_worst_window': worst('node_lag_p99_ms_worst_window'),
        'node_lag_p99_ms_run': worst('node_lag_p99_ms_run'),
        'node_lag_max_ms_run': worst('node_lag_max_ms_run'),
        'overruns': sum(n['overruns'] for n in per_node),
        'cpu_pct': float(np.mean([n['cpu_pct'] for n in per_node])),
        'cpu_pct_total': float(sum(n['cpu_pct'] for n in per_node)),
        'realtime_ok': all(realtime_ok(n) for n in per_node),
    }


# A stack's subscriber of the sensor topics, a process of its own (as the stack under test
# would be): raw, counted between its start signal (a line on stdin) and its stop (another)
STACK = r"""
import sys, threading, time, rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64, UInt64MultiArray
rclpy.init()
node = rclpy.create_node('bench_stack')
qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
state = {'on': False, 'n': 0}
def count(_data):
    if state['on']:
        state['n'] += 1
for topic in sys.argv[1:]:
    msgtype = UInt64MultiArray if topic.endswith('/edges') else Float64
    node.create_subscription(msgtype, topic, count, qos, raw=True)
ex = SingleThreadedExecutor()
ex.add_node(node)
spinner = threading.Thread(target=ex.spin, daemon=True)
spinner.start()
print('ready', flush=True)
sys.stdin.readline()
state['on'] = True
t0 = time.monotonic()
sys.stdin.readline()
state['on'] = False
print(state['n'] / (time.monotonic() - t0), flush=True)
ex.shutdown(timeout_sec=2.0)
spinner.join(timeout=5.0)
node.destroy_node()
rclpy.try_shutdown()
"""


def sensor_topics(namespaces: list[str]) -> list[str]:
    """Every sensor topic of the default driveline in each namespace."""
    from dmf_sim.live.streams import resolved_topics, sensor_streams
    from dmf_sim.physics.model import read_driveline

    streams = sensor_streams(read_driveline('truck_dmf').sensors)
    return [resolved_topics(ns, streams)[k] for ns in namespaces for k in streams]


def run_nodes(args, domain: int, tmp: Path, sensors: bool, fast: bool,
              tag: str = '') -> dict:
    """Start the nodes, measure real time (and fast mode when ``fast``), stop them, check the
    bags; returns the figures."""
    extra = ['-p', f'publish_rate:={args.publish_rate!r}', '-p', 'dt:=0.0001',
             '-p', 'diagnostics_rate:=1.0', '-p', f'monitor:={args.monitor == "on"}'.lower(),
             '-p', f'sensors:={str(sensors).lower()}', '-p', f'driveline:={args.config}']
    namespaces = [''] if args.nodes == 1 else [f'/truck{i + 1}' for i in range(args.nodes)]
    runs = [NodeRun(ns, tmp / f'bench_bag{tag}{ns.replace("/", "_")}', tmp, extra)
            for ns in namespaces]
    probe = stack = None
    result: dict = {'sensors': sensors, 'config': args.config}
    try:
        cap = int((args.duration + 5) * args.publish_rate * 1.2) + 1000
        probe = Probe(domain, cap, [r.fqn for r in runs])
        if sensors:
            stack = subprocess.Popen([sys.executable, '-c', STACK, *sensor_topics(namespaces)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
            stack.stdout.readline()
        if not probe.wait(lambda: all(probe.diags[r.fqn] for r in runs), 90.0 + 30 * len(runs)):
            raise RuntimeError(f'a node did not publish diagnostics; logs in {tmp}')
        time.sleep(args.warmup)
        if stack is not None:
            stack.stdin.write('start\n')
            stack.stdin.flush()
        per_node = measure_realtime(probe, runs, args.duration, args.setpoint_period)
        result.update(summarize(per_node, args))
        if stack is not None:
            stack.stdin.write('stop\n')
            stack.stdin.flush()
            result['sensor_messages_per_s'] = float(stack.stdout.readline())
        else:
            result['sensor_messages_per_s'] = 0.0
        if len(runs) == 1 and fast:
            result.update(measure_fast(probe, runs[0], args.fast_duration))
        elif len(runs) > 1:
            result['per_node'] = per_node
    finally:
        if probe is not None:
            probe.close()
        if stack is not None:
            stack.stdin.close()            # (after its count: it ends by itself)
            try:
                stack.wait(timeout=20)
            except subprocess.TimeoutExpired:
                stack.kill()
                stack.wait()
        codes = [r.stop() for r in runs]

    checks = [r.bag_check() for r in runs]
    result.update({
        'node_exit_code': max(codes, key=abs),
        'bag_messages': sum(c['bag_messages'] for c in checks),
        'bag_complete': all(c['bag_complete'] for c in checks),
        'bag_files': sum(c['bag_files'] for c in checks),
        'bag_mb': sum(c['bag_mb'] for c in checks),
    })
    return result


def sensor_pairs(args, domain: int, tmp: Path) -> dict:
    """``--sensors-pairs``: alternating off/on runs; the cost of the sensors."""
    runs: dict[str, list[dict]] = {'off': [], 'on': []}
    for i in range(args.sensors_pairs):
        for mode in ('off', 'on'):
            r = run_nodes(args, domain, tmp, mode == 'on', fast=False, tag=f'_{mode}{i}')
            runs[mode].append(r)
            print(f'pair {i + 1} sensors {mode}: CPU {r["cpu_pct"]:.1f} %, node lag p99 (worst '
                  f'1-s window) {r["node_lag_p99_ms_worst_window"]:.2f} ms, end-to-end p99 '
                  f'{r["lag_p99_ms"]:.2f} ms, '
                  f'factor {r["rtf_mean"]:.4f} ({r["rtf_min"]:.4f}..{r["rtf_max"]:.4f}), '
                  f'{r["sensor_messages_per_s"]:.0f} sensor messages/s received', flush=True)
    ratios = [on['cpu_pct'] / off['cpu_pct'] for off, on in zip(runs['off'], runs['on'])]
    lag_on = [r['node_lag_p99_ms_worst_window'] for r in runs['on']]

    def stat(values):
        return {'min': float(np.min(values)), 'median': float(np.median(values)),
                'max': float(np.max(values))}
    return {
        'sensors_pairs': args.sensors_pairs, 'duration_s': args.duration,
        'publish_rate_hz': args.publish_rate, 'monitor': args.monitor == 'on',
        'node_cpu_ratio_sensors': float(np.median(ratios)),
        'node_cpu_ratio_sensors_all': stat(ratios),
        'node_lag_p99_ms_sensors': float(np.median(lag_on)),
        'node_lag_p99_ms_sensors_all': stat(lag_on),
        'node_lag_p99_ms_no_sensors_all': stat([r['node_lag_p99_ms_worst_window']
                                                for r in runs['off']]),
        'lag_p99_ms_sensors': float(np.median([r['lag_p99_ms'] for r in runs['on']])),
        'lag_p99_ms_sensors_all': stat([r['lag_p99_ms'] for r in runs['on']]),
        'lag_p99_ms_no_sensors_all': stat([r['lag_p99_ms'] for r in runs['off']]),
        'cpu_pct_sensors_all': stat([r['cpu_pct'] for r in runs['on']]),
        'cpu_pct_no_sensors_all': stat([r['cpu_pct'] for r in runs['off']]),
        'rtf_min_sensors': min(r['rtf_min'] for r in runs['on']),
        'rtf_max_sensors': max(r['rtf_max'] for r in runs['on']),
        'overruns_sensors': sum(r['overruns'] for r in runs['on']),
        'sensor_messages_per_s': float(np.median([r['sensor_messages_per_s']
                                                  for r in runs['on']])),
        'realtime_ok_sensors': all(r['realtime_ok'] for r in runs['on']),
        'bag_complete': all(r['bag_complete'] for m in runs.values() for r in m),
        'node_exit_code': max((r['node_exit_code'] for m in runs.values() for r in m), key=abs),
    }


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--duration', type=float, default=60.0, help='real-time measurement [s]')
    ap.add_argument('--fast-duration', type=float, default=10.0,
                    help='as-fast-as-possible measurement [s] (each of: recording on, off)')
    ap.add_argument('--warmup', type=float, default=3.0, help='discarded start [s]')
    ap.add_argument('--publish-rate', type=float, default=1000.0)
    ap.add_argument('--nodes', type=int, default=1, help='trucks at once (namespaces /truckI)')
    ap.add_argument('--domain', type=int, default=None,
                    help='ROS_DOMAIN_ID (default: from DMF_SIM_TEST_DOMAINS and the pid)')
    ap.add_argument('--keep', action='store_true', help='keep the bag directories')
    ap.add_argument('--monitor', choices=('on', 'off'), default='on',
                    help="the node's DMF monitor (per-cycle orders, prediction, alarms; "
                         'default on, as the node)')
    ap.add_argument('--setpoint-period', type=float, default=0.0,
                    help='send a new speed setpoint every this many seconds during the '
                         'real-time measurement (0 = none)')
    ap.add_argument('--config', default='truck_dmf',
                    help="the node's driveline (parameter driveline; e.g. truck_dmf_friction: "
                         'the DMF with arc-spring friction and end stops)')
    ap.add_argument('--sensors', choices=('on', 'off'), default='on',
                    help="the node's sensors (edge batches, bus speeds; default on, as the "
                         'node); on: the probe subscribes to them too')
    ap.add_argument('--sensors-pairs', type=int, default=0, metavar='N',
                    help='measure the sensors\' cost: N pairs of real-time runs, sensors off '
                         'then on (no fast-mode part)')
    args = ap.parse_args(argv)
    if args.nodes < 1:
        ap.error('--nodes must be >= 1')
    if args.setpoint_period < 0:
        ap.error('--setpoint-period must be >= 0')
    if args.sensors_pairs < 0:
        ap.error('--sensors-pairs must be >= 0')

    domain = args.domain or default_domain()
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    tmp = Path(tempfile.mkdtemp(prefix='bench_node_'))
    if args.sensors_pairs:
        result = sensor_pairs(args, domain, tmp)
    else:
        result = run_nodes(args, domain, tmp, args.sensors == 'on', fast=True)
    if not args.keep:
        shutil.rmtree(tmp, ignore_errors=True)
    else:
        result['bag_dir'] = str(tmp)
    report(result)
    return result


def report(r: dict) -> None:
    if 'sensors_pairs' in r:
        ratio, lag = r['node_cpu_ratio_sensors_all'], r['node_lag_p99_ms_sensors_all']
        print(f'sensors on vs off, {r["sensors_pairs"]} alternating pairs of '
              f'{r["duration_s"]:g} s at {r["publish_rate_hz"]:g} Hz: node CPU '
              f'x{r["node_cpu_ratio_sensors"]:.3f} '
              f'(min {ratio["min"]:.3f}, max {ratio["max"]:.3f}); with sensors node lag p99 '
              f'{r["node_lag_p99_ms_sensors"]:.2f} ms (worst 1-s window; max {lag["max"]:.2f}), '
              f'end-to-end {r["lag_p99_ms_sensors"]:.2f} ms; real-time factor '
              f'{r["rtf_min_sensors"]:.4f}..{r["rtf_max_sensors"]:.4f}, overruns '
              f'{r["overruns_sensors"]}; {r["sensor_messages_per_s"]:.0f} sensor messages/s')
        print(json.dumps(clean_json(r)))
        return
    setpoints = (f'a speed setpoint every {r["setpoint_period_s"]:g} s'
                 if r['setpoint_period_s'] else 'fixed setpoints')
    print(f'real time, {r["duration_s"]:g} s, dt 1e-4 s, {r["publish_rate_hz"]:g} Hz, recording, '
          f'monitor {"on" if r["monitor"] else "off"}, sensors {"on" if r["sensors"] else "off"}, '
          f'{setpoints}, {r["nodes"]} node(s) at once:')
    for n in r.get('per_node', [r]):
        label = f'  {n["node"]}:' if 'node' in n else ' '
        print(f'{label} real-time factor  mean {n["rtf_mean"]:.4f}  min {n["rtf_min"]:.4f}  max '
              f'{n["rtf_max"]:.4f}  ({n["rtf_windows"]} windows of 1 s), overall '
              f'{n["rtf_overall"]:.5f}')
        print(f'{label} lag end-to-end    p50 {n["lag_p50_ms"]:.2f} ms  p99 '
              f'{n["lag_p99_ms"]:.2f} ms  max {n["lag_max_ms"]:.2f} ms  '
              f'({n["joint_states_received"]} of {r["joint_states_expected"]} '
              f'JointState received)')
        print(f'{label} node-side lag     p99 {n["node_lag_p99_ms_run"]:.2f} ms (run), max '
              f'{n["node_lag_max_ms_run"]:.2f} ms, worst 1-s window p99 '
              f'{n["node_lag_p99_ms_worst_window"]:.2f} ms; overruns {n["overruns"]}')
        print(f'{label} node CPU          {n["cpu_pct"]:.1f} % of one core')
    print(f'every node kept real time: {r["realtime_ok"]}')
    if 'max_rtf_fast' in r:
        print(f'as fast as possible: x{r["max_rtf_fast"]:.2f} recording '
              f'(CPU {r["max_rtf_fast_cpu_pct"]:.0f} %), '
              f'x{r["max_rtf_fast_no_record"]:.2f} not recording')
    print(f'bags: {r["bag_messages"]} messages in {r["bag_files"]} file(s), {r["bag_mb"]:.1f} MB, '
          f'complete: {r["bag_complete"]}, node exit code {r["node_exit_code"]}')
    print(json.dumps(clean_json(r)))


def clean_json(r: dict) -> dict:
    """Floats rounded; non-finite ones as null (strict JSON)."""
    def clean(v):
        if isinstance(v, float):
            return round(v, 6) if math.isfinite(v) else None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, list):
            return [clean(x) for x in v]
        return v
    return clean(r)


if __name__ == '__main__':
    main()
