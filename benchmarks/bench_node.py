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

The bag is closed by SIGTERM and checked (message counts in metadata.yaml vs the MCAP summary).
Last line: one JSON object.

    python benchmarks/bench_node.py [--duration 60] [--fast-duration 10] [--warmup 3]
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


def proc_cpu_seconds(pid: int) -> float:
    """utime + stime [s] of a process (all threads), from /proc/<pid>/stat."""
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


class Probe:
    """rclpy peer on the node's domain: JointState stamps (raw CDR) and diagnostics."""

    def __init__(self, domain: int, cap: int) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from diagnostic_msgs.msg import DiagnosticArray
        from rcl_interfaces.srv import SetParameters
        from sensor_msgs.msg import JointState

        self.rclpy = rclpy
        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node('bench_probe', context=self.ctx)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.recv = np.zeros(cap, dtype=np.int64)
        self.stamp = np.zeros(cap, dtype=np.int64)
        self.n = 0
        self.recording = False
        self.diags: list[tuple[float, dict]] = []
        self.js_sub = self.node.create_subscription(JointState, '/driveline/joint_states',
                                                    self._on_js, qos, raw=True)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, qos)
        self.param_client = self.node.create_client(SetParameters,
                                                    '/driveline_node/set_parameters')
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001 - shutdown races
            pass

    def _on_js(self, data: bytes) -> None:
        now = time.time_ns()
        if self.recording and self.n < self.recv.shape[0]:
            sec, nsec = struct.unpack_from('<iI', data, 4)   # CDR header, then header.stamp
            self.recv[self.n] = now
            self.stamp[self.n] = sec * 1_000_000_000 + nsec
            self.n += 1

    def _on_diag(self, msg) -> None:
        for st in msg.status:
            if st.name.endswith('driveline simulation'):
                self.diags.append((time.monotonic(), {kv.key: kv.value for kv in st.values}))

    def wait(self, cond, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if cond():
                return True
            time.sleep(0.02)
        return cond()

    def set_params(self, **values) -> list:
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        if not self.param_client.wait_for_service(timeout_sec=10.0):
            raise RuntimeError('parameter service of the node not found')
        req = SetParameters.Request()
        req.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
        fut = self.param_client.call_async(req)
        if not self.wait(fut.done, 10.0):
            raise RuntimeError('set_parameters timed out')
        return fut.result().results

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.ctx)


def _diag_values(diags, t0: float, t1: float, key: str) -> list[float]:
    out = []
    for t, d in diags:
        if t0 <= t <= t1 and key in d:
            try:
                out.append(float(d[key]))
            except ValueError:
                pass
    return out


def _rate_between(diags, t0: float, t1: float) -> float:
    """Simulated seconds per wall second between the first and last diagnostics in [t0, t1]."""
    pts = [(t, float(d['sim_time_s'])) for t, d in diags if t0 <= t <= t1]
    if len(pts) < 2:
        return float('nan')
    return (pts[-1][1] - pts[0][1]) / (pts[-1][0] - pts[0][0])


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--duration', type=float, default=60.0, help='real-time measurement [s]')
    ap.add_argument('--fast-duration', type=float, default=10.0,
                    help='as-fast-as-possible measurement [s] (each of: recording on, off)')
    ap.add_argument('--warmup', type=float, default=3.0, help='discarded start [s]')
    ap.add_argument('--publish-rate', type=float, default=1000.0)
    ap.add_argument('--domain', type=int, default=None, help='ROS_DOMAIN_ID (default: from pid)')
    ap.add_argument('--keep', action='store_true', help='keep the bag directory')
    args = ap.parse_args(argv)

    domain = args.domain or 1 + (os.getpid() * 7 + 3) % 100
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    tmp = Path(tempfile.mkdtemp(prefix='bench_node_'))
    bag = tmp / 'bench_bag'
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    cmd = [sys.executable, '-m', 'dmf_sim.node', '--ros-args', '-p', 'record:=true',
           '-p', f'bag_path:={bag}', '-p', f'publish_rate:={args.publish_rate!r}',
           '-p', 'dt:=0.0001', '-p', 'diagnostics_rate:=1.0']
    log = open(tmp / 'node.log', 'w')
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=tmp)
    probe = None
    result: dict = {}
    try:
        cap = int((args.duration + 5) * args.publish_rate * 1.2) + 1000
        probe = Probe(domain, cap)
        if not probe.wait(lambda: len(probe.diags) > 0, 90.0):
            raise RuntimeError(f'node did not publish diagnostics; log: {tmp / "node.log"}')
        time.sleep(args.warmup)

        # ---- real time ----------------------------------------------------------------
        ovr0 = int(probe.diags[-1][1]['overruns'])
        c0, w0 = proc_cpu_seconds(proc.pid), time.monotonic()
        probe.recording = True
        time.sleep(args.duration)
        probe.recording = False
        c1, w1 = proc_cpu_seconds(proc.pid), time.monotonic()
        time.sleep(1.2)                                   # the diagnostics of the last window
        n = probe.n
        lat = (probe.recv[:n] - probe.stamp[:n]) / 1e6    # ms
        rtf_w = _diag_values(probe.diags, w0 + 0.5, w1 + 0.5, 'real_time_factor')
        node_p99 = _diag_values(probe.diags, w0 + 0.5, w1 + 0.5, 'lag_p99_ms')
        last = probe.diags[-1][1]
        span_stamp = (probe.stamp[n - 1] - probe.stamp[0]) / 1e9 if n > 1 else float('nan')
        span_recv = (probe.recv[n - 1] - probe.recv[0]) / 1e9 if n > 1 else float('nan')
        result.update({
            'duration_s': args.duration, 'dt_s': 1e-4, 'publish_rate_hz': args.publish_rate,
            'recording': True,
            'rtf_mean': float(np.mean(rtf_w)) if rtf_w else float('nan'),
            'rtf_min': float(np.min(rtf_w)) if rtf_w else float('nan'),
            'rtf_max': float(np.max(rtf_w)) if rtf_w else float('nan'),
            'rtf_windows': len(rtf_w),
            'rtf_overall': span_stamp / span_recv,
            'lag_p50_ms': float(np.percentile(lat, 50)) if n else float('nan'),
            'lag_p99_ms': float(np.percentile(lat, 99)) if n else float('nan'),
            'lag_max_ms': float(lat.max()) if n else float('nan'),
            'joint_states_received': int(n),
            'joint_states_expected': int(round(args.duration * args.publish_rate)),
            'node_lag_p99_ms_worst_window': (float(np.nanmax(node_p99)) if node_p99
                                             else float('nan')),
            'node_lag_p99_ms_run': float(last['lag_p99_ms_total']),
            'overruns': int(last['overruns']) - ovr0,
            'cpu_pct': 100.0 * (c1 - c0) / (w1 - w0),
        })

        # ---- as fast as possible -----------------------------------------------------
        probe.node.destroy_subscription(probe.js_sub)
        fast = {}
        for label, record in (('max_rtf_fast', True), ('max_rtf_fast_no_record', False)):
            if not record:
                probe.set_params(record=False)
            res = probe.set_params(real_time_factor=0.0)
            if not res[0].successful:
                raise RuntimeError(f'switching to fast mode refused: {res[0].reason}')
            t0 = time.monotonic()
            cf0 = proc_cpu_seconds(proc.pid)
            time.sleep(args.fast_duration + 1.5)
            t1 = time.monotonic()
            fast[label] = _rate_between(probe.diags, t0 + 1.2, t1)
            fast[label + '_cpu_pct'] = 100.0 * (proc_cpu_seconds(proc.pid) - cf0) / (t1 - t0)
            probe.set_params(real_time_factor=1.0)
            time.sleep(0.5)
        result.update(fast)
    finally:
        if probe is not None:
            probe.close()
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        log.close()

    # ---- the bag: closed by SIGTERM, counts consistent --------------------------------
    import yaml
    from mcap.reader import make_reader

    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    with open(bag / meta['relative_file_paths'][0], 'rb') as f:
        summary = make_reader(f).get_summary()
    mcap_count = sum(summary.statistics.channel_message_counts.values()) if summary else -1
    result.update({
        'node_exit_code': proc.returncode,
        'bag_messages': int(meta['message_count']),
        'bag_complete': bool(summary is not None and mcap_count == meta['message_count']),
        'bag_mb': sum(p.stat().st_size for p in bag.iterdir()) / 1e6,
    })
    if not args.keep:
        shutil.rmtree(tmp, ignore_errors=True)
    else:
        result['bag_path'] = str(bag)

    r = result
    print(f'real time, {r["duration_s"]:g} s, dt 1e-4 s, {r["publish_rate_hz"]:g} Hz, recording:')
    print(f'  real-time factor  mean {r["rtf_mean"]:.4f}  min {r["rtf_min"]:.4f}  max '
          f'{r["rtf_max"]:.4f}  ({r["rtf_windows"]} windows of 1 s), overall '
          f'{r["rtf_overall"]:.5f}')
    print(f'  lag end-to-end    p50 {r["lag_p50_ms"]:.2f} ms  p99 {r["lag_p99_ms"]:.2f} ms  max '
          f'{r["lag_max_ms"]:.2f} ms  ({r["joint_states_received"]} of '
          f'{r["joint_states_expected"]} JointState received)')
    print(f'  node-side lag     p99 {r["node_lag_p99_ms_run"]:.2f} ms (run), worst 1-s window '
          f'{r["node_lag_p99_ms_worst_window"]:.2f} ms; overruns {r["overruns"]}')
    print(f'  node CPU          {r["cpu_pct"]:.1f} % of one core')
    print(f'as fast as possible: x{r.get("max_rtf_fast", float("nan")):.2f} recording '
          f'(CPU {r.get("max_rtf_fast_cpu_pct", float("nan")):.0f} %), '
          f'x{r.get("max_rtf_fast_no_record", float("nan")):.2f} not recording')
    print(f'bag: {r["bag_messages"]} messages, {r["bag_mb"]:.1f} MB, complete: {r["bag_complete"]}'
          f', node exit code {r["node_exit_code"]}')
    print(json.dumps({k: (round(v, 6) if isinstance(v, float) and math.isfinite(v) else v)
                      for k, v in r.items()}))
    return r


if __name__ == '__main__':
    main()
