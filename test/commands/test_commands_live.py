"""``dmf-sim setpoint`` and ``dmf-sim monitor`` against a real driveline_node process over DDS
(localhost only, ROS_DOMAIN_ID from DMF_SIM_TEST_DOMAINS, see dds_peer), plus the monitor's
view without ROS."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

import pytest
from support.cli_output import frames as _frames
from support.dds_peer import START_TIMEOUT, new_domain
from support.processes import kill_started as _kill

from dmf_sim.commands._ros import select_node
from dmf_sim.commands.monitor import MonitorView, Status, render_plain
from dmf_sim.core.errors import ConfigError

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'   # this process's participants too


def _env(domain: int) -> dict:
    return dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                PYTHONUNBUFFERED='1')


def _dmf_sim(args, env, timeout=120):
    return subprocess.run([sys.executable, '-m', 'dmf_sim.cli', *args], env=env,
                          capture_output=True, text=True, timeout=timeout)


# ------------------------------------------------------------------------------------------------
# The view without ROS
# ------------------------------------------------------------------------------------------------

def test_monitor_view_shows_every_quantity():
    from support.monitor_cycles import cycle as _cycle

    from dmf_sim.monitor.alarms import AlarmSettings, evaluate
    from dmf_sim.monitor.messages import cycle_status, prediction_statuses
    from dmf_sim.monitor.prediction import OperatingPoint, PredictedState, Prediction, compare

    view = MonitorView()
    assert 'waiting' in render_plain(view, 0.0)
    sim = Status(0, 'driveline_node: driveline simulation', 'realtime x1.000', {
        'speed_rpm': '949.7', 'speed_setpoint_rpm': '950', 'load': '1.0000',
        'load_setpoint': '1', 'windup_rad': '0.201', 'dmf_region': 'secondary',
        'lag_ms': '0.61', 'lag_p99_ms': '2.1', 'overruns': '0', 'sim_time_s': '12.5',
        'real_time_factor': '1.0001', 'dmf_secondary_fraction': '0.3', 'knee_crossings': '8'})
    view.on_diagnostics([sim, Status(0, 'other_node: something', '', {})], now=1.0)
    pred = Prediction(OperatingPoint(950.0, 1.0, 'A', None),
                      (PredictedState(0.015, 0.0162, 0.03, -0.03, 0.2, 0.0, 0.19, 0.01, 'main'),),
                      0.2)
    cyc = _cycle()
    report = evaluate(AlarmSettings(0.005, 0.6), cyc, pred)
    st = cycle_status('n', cyc, compare(cyc, pred, 10, 0.02), pred, report)
    as_msg = lambda s: Status(s.level, s.name, s.message, dict(s.values))  # noqa: E731
    view.on_cycle([as_msg(st)], now=1.0)
    view.on_predicted([as_msg(s) for s in prediction_statuses('n', pred, 3.0, 0.2)], now=1.0)
    text = render_plain(view, 1.5)
    for part in ('949.7 rpm (setpoint 950 rpm)', '+0.20100 rad', 'DMF region secondary',
                 'lag 0.61 ms', '3rd 0.01499 rad', '1.5th 0.01630 rad', 'secondary 40%',
                 '1 stable state(s) at 950 rpm', 'live - predicted +0.00010',
                 '1.5th-order sub-harmonic present'):
        assert part in text, (part, text)
    assert 'no firing interval scored' in text
    from dmf_sim.monitor.messages import detection_statuses
    from dmf_sim.monitor.misfire import Detection
    dets = [Detection(10**9 + k, 1 + k % 6, 3, 30.0 + k, 950.0, -0.9 if k == 4 else 0.01, k == 4)
            for k in range(6)]
    view.on_detections([as_msg(s) for s in detection_statuses('n', dets)], now=1.2)
    assert ('6 firing intervals scored, 1 alarms; last: cylinder 5 at 1.000 s, crank angle '
            '34.00 rad, score -0.90') in render_plain(view, 1.5)
    assert 'diagnostics' not in text.splitlines()[0]        # fresh
    assert '(diagnostics 9 s old)' in render_plain(view, 10.0)


def _health(fqn: str, speed: str) -> Status:
    return Status(0, f'{fqn}: driveline simulation', 'ok', {'speed_rpm': speed}, fqn)


@pytest.mark.parametrize('namespace, node', [('/truck1', ''), ('', '/truck1/driveline_node'),
                                             ('/truck1', 'driveline_node'),
                                             ('/truck1', '/truck1/driveline_node')])
def test_monitor_view_keeps_to_its_node_by_full_name(namespace, node):
    """The filter compared only the last name segment (the same for every
    truck), and --namespace alone did not filter /diagnostics at all."""
    view = MonitorView(node=select_node(namespace, node))
    assert view.node.namespace == '/truck1'
    for fqn, speed in [('/truck1/driveline_node', '800'), ('/truck2/driveline_node', '1200'),
                       ('/driveline_node', '1000'), ('/truck1/sub/driveline_node', '900')]:
        view.on_diagnostics([_health(fqn, speed)], now=1.0)
    assert view.sim.values['speed_rpm'] == '800'
    assert render_plain(view, 1.0).splitlines()[0].split()[1] == '/truck1/driveline_node'


def test_node_selector_resolves_names_and_refuses_a_mismatch():
    assert select_node('', '').matches('/driveline_node')
    assert not select_node('', '').matches('/truck2/driveline_node')
    assert not select_node('', 'driveline_node').matches('/truck2/driveline_node')
    assert select_node('/truck2', 'my_node').fqn == '/truck2/my_node'
    assert select_node('', 'driveline_node').matches('driveline_node')      # no leading '/'
    with pytest.raises(ConfigError, match="--node '/truck1/driveline_node' is not in "
                                          "--namespace '/truck2'"):
        select_node('/truck2', '/truck1/driveline_node')
    # a relative namespace is taken from the root, as launch takes namespace:=truck1
    assert select_node('truck1', '') == select_node('/truck1', '')
    assert select_node('truck1', 'driveline_node').fqn == '/truck1/driveline_node'
    for bad, why in (('truck1/', "ends with '/'"), ('/a//b', "contains '//'"),
                     ('1truck', 'starts with a digit'), ('truck-1', "character '-'")):
        with pytest.raises(ConfigError, match=f"--namespace '{bad}': not a valid ROS 2 "
                                              f'namespace, .*{why}'):
            select_node(bad, '')


# ================================================================================================
# Over DDS with a real node
# ================================================================================================


class Node:
    """driveline_node (the console script) as a subprocess on its own domain."""

    def __init__(self, tmp_path: Path, domain: int, *args) -> None:
        exe = Path(sysconfig.get_path('scripts')) / 'driveline_node'
        cmd = [str(exe)] if exe.exists() else [sys.executable, '-m', 'dmf_sim.node']
        self.log = open(tmp_path / f'node_{domain}.log', 'w')
        self.proc = subprocess.Popen(cmd + ['--ros-args', *args], cwd=tmp_path, env=_env(domain),
                                     stdout=self.log, stderr=subprocess.STDOUT)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)
        self.log.close()


@pytest.mark.slow
@pytest.mark.ros
def test_setpoint_and_monitor_against_a_running_node(tmp_path):
    domain = new_domain()
    env = _env(domain)
    # the node's own monitor off: the per-cycle and prediction topics carry the messages this
    # test publishes (the wired monitor is tested in test_node_monitor.py)
    node = Node(tmp_path, domain, '-r', '__ns:=/truck1', '-p', 'diagnostics_rate:=4.0',
                '-p', 'monitor:=false')
    # no node in that namespace / of that name: one line, exit 2 (run while the node starts)
    cli = [sys.executable, '-m', 'dmf_sim.cli']
    nobody = [subprocess.Popen(cli + args, env=env, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True) for args in (
        ['setpoint', '--speed', '900', '--namespace', '/nobody', '--timeout', '2'],
        ['monitor', '--once', '--node', 'nobody', '--timeout', '2'])]
    try:
        # setpoints: delivered once the node's subscription matched; exit 0
        res = _dmf_sim(['setpoint', '--speed', '900', '--load', '0.8', '--namespace', '/truck1',
                        '--timeout', str(START_TIMEOUT)], env, timeout=START_TIMEOUT + 60)
        assert res.returncode == 0, res.stderr
        assert '/truck1/engine/speed_setpoint: 900 rpm delivered to 1 subscriber' in res.stdout
        assert '/truck1/engine/load_setpoint: load 0.8 delivered' in res.stdout

        # the namespace as launch takes it (relative); a speed outside the node's limits
        # (read from its parameters) is refused before anything is sent: one line, exit 2
        limits = "node /truck1/driveline_node's speed_min_rpm/speed_max_rpm [500, 2200] rpm"
        for args, line in (
                (['--profile', 'ramp:300:1400:50'],
                 f'profile ramp:300:1400:50: row 1 (t = 0 s) speed 300 rpm outside {limits}'),
                (['--speed', '2500'], f'--speed 2500 rpm is outside {limits}; nothing sent')):
            res = _dmf_sim(['setpoint', *args, '--namespace', 'truck1', '--timeout', '30'], env)
            assert res.returncode == 2 and res.stdout == '', (res.stdout, res.stderr)
            assert res.stderr.strip().splitlines() == [f'dmf-sim setpoint: error: {line}']

        out, err = nobody[0].communicate(timeout=60)
        assert nobody[0].returncode == 2 and out == ''
        assert err.strip().splitlines() == [
            'dmf-sim setpoint: error: no node subscribes to /nobody/engine/speed_setpoint within '
            '2 s (is driveline_node running with this ROS_DOMAIN_ID and namespace?)']
        out, err = nobody[1].communicate(timeout=60)
        assert nobody[1].returncode == 2 and 'no /diagnostics from /nobody within 2 s' in err

        # the monitor shows the node's state, refreshing with values that change, and the
        # per-cycle and prediction topics (published here as the node will publish them)
        frames = _frames(_monitor_with_monitor_topics(domain, _shows_monitor_topics))
        frames = [f for f in frames if 'speed' in f]
        assert len(frames) >= 3, frames
        last = frames[-1]
        assert 'setpoint 900 rpm' in last['speed'] and 'setpoint 0.8' in last['speed']
        assert re.match(r'/truck1/driveline_node  (OK|WARN)  ', last['node'])   # WARN: overruns
        assert re.search(r'lag [\d.]+ ms', last['time'])
        assert 'DMF region primary' in last['wind-up']
        times = [float(re.search(r'sim ([\d.]+) s', f['time']).group(1)) for f in frames]
        windups = {re.search(r'([+-][\d.]+) rad', f['wind-up']).group(1) for f in frames}
        assert times == sorted(times) and times[-1] > times[0] and len(windups) >= 2
        assert '3rd 0.01499 rad' in last['orders'] and '1.5th 0.01630 rad' in last['orders']
        assert last['predicted'] == '2 stable state(s) at 950 rpm, load 1, Load A'
        assert 'live - predicted +0.00010' in last['vs']
        assert last['alarms'].startswith('1.5th-order sub-harmonic present: 0.0163 rad')
    finally:
        _kill(nobody)
        node.stop()


MONITOR_FRAMES_MAX = 120      # at 2 Hz: the monitor's discovery of this process's topics may
#                               take seconds on a loaded machine; it is stopped once it shows them


def _shows_monitor_topics(frame: dict[str, str]) -> bool:
    return ('3rd ' in frame.get('orders', '') and 'stable state' in frame.get('predicted', '')
            and 'live - predicted' in frame.get('vs', ''))


def _read_lines(stream, lines: list[str]) -> None:
    for line in stream:
        lines.append(line)


def _monitor_with_monitor_topics(domain: int, ready) -> str:
    """Run ``dmf-sim monitor --plain`` while this process publishes a real per-cycle message
    and a latched prediction on /truck1 (the node's monitor is wired in separately), until three
    frames are complete and the last of them is ``ready`` (then it is killed; at most
    :data:`MONITOR_FRAMES_MAX` frames); returns the monitor's complete frames."""
    import threading

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.executors import SingleThreadedExecutor
    from support.monitor_cycles import cycle as _cycle

    from dmf_sim.commands._ros import reliable_qos
    from dmf_sim.monitor.alarms import AlarmSettings, evaluate
    from dmf_sim.monitor.messages import (
        TOPIC_CYCLE,
        TOPIC_PREDICTED,
        cycle_status,
        prediction_statuses,
    )
    from dmf_sim.monitor.prediction import OperatingPoint, PredictedState, Prediction, compare

    ctx = rclpy.context.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node('fake_monitor', namespace='/truck1', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    proc = None
    try:
        cyc_pub = node.create_publisher(DiagnosticArray, TOPIC_CYCLE, reliable_qos())
        pred_pub = node.create_publisher(DiagnosticArray, TOPIC_PREDICTED,
                                         reliable_qos(depth=1, latched=True))
        pred = Prediction(OperatingPoint(950.0, 1.0, 'A', None), (
            PredictedState(0.015, 0.0178, 0.03, -0.03, 0.2, 0.0, 0.19, 0.01, 'main'),
            PredictedState(0.015, 0.0162, 0.03, -0.03, 0.2, 0.0, 0.19, 0.01, 'subharmonic')),
            0.2)
        pred_pub.publish(DiagnosticArray(status=[
            s.to_msg(DiagnosticStatus, KeyValue) for s in prediction_statuses('n', pred, 3, 0.2)]))
        cyc = _cycle()
        report = evaluate(AlarmSettings(0.005, 0.6), cyc, pred)
        cyc_msg = DiagnosticArray(status=[cycle_status(
            'n', cyc, compare(cyc, pred, 10, 0.02), pred, report).to_msg(DiagnosticStatus,
                                                                          KeyValue)])
        proc = subprocess.Popen([sys.executable, '-m', 'dmf_sim.cli', 'monitor', '--namespace',
                                 '/truck1', '--plain', '--rate', '2', '--frames',
                                 str(MONITOR_FRAMES_MAX)],
                                env=_env(domain), stdout=subprocess.PIPE, text=True)
        lines: list[str] = []
        reader = threading.Thread(target=_read_lines, args=(proc.stdout, lines), daemon=True)
        reader.start()
        # publish until the monitor shows what is published (its frames start once it has the
        # node's diagnostics; the match with this process's publishers may come later)
        end = time.monotonic() + 120
        while proc.poll() is None and time.monotonic() < end:
            cyc_pub.publish(cyc_msg)
            ex.spin_once(timeout_sec=0.1)
            done = _frames(''.join(lines))[:-1]         # the last one may still be printing
            if len(done) >= 3 and ready(done[-1]):
                # ended by SIGKILL: a process started with SIGINT ignored (a CI job started in
                # the background) keeps ignoring it, as it should; its frames are read already
                proc.kill()
                break
        proc.wait(timeout=30)
        reader.join(timeout=30)
        out = ''.join(lines)
        out = out[:out.rfind('--- frame')]           # the complete frames
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        ex.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    return out

