"""Two trucks in two namespaces under one launch parent, over real DDS (a domain from
DMF_SIM_TEST_DOMAINS); one pair of node starts serves two checks:

* item 2: ``dmf-sim monitor --namespace /truck1`` (and ``--node /truck1/driveline_node``)
  showed the other truck's health; every frame must show its own truck's node and speed;
* item 7: ``ros2 launch ... &`` from a script ignores SIGINT; SIGTERM then ended launch and left
  the node running and recording. The parent is SIGKILLed: both nodes must stop the way Ctrl-C
  stops them, closing complete bags.
"""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time

import pytest
import yaml
from mcap.reader import make_reader
from support.cli_output import frames as _frames
from support.dds_peer import START_TIMEOUT, Peer, new_domain
from support.processes import gone as _gone, kill_started as _kill

pytestmark = pytest.mark.ros     # two nodes over DDS

PARENT = '''
import json, subprocess, sys, time
procs = [subprocess.Popen(cmd, stdout=open(log, 'w'), stderr=subprocess.STDOUT)
         for cmd, log in json.loads(sys.argv[1])]
print(' '.join(str(p.pid) for p in procs), flush=True)
time.sleep(3600)
'''
EXIT_TIMEOUT = 60.0


def _monitors_show_their_own_truck(env: dict, speeds: dict) -> None:
    """Item 2: three monitors at once; every frame shows the selected truck's node and speed.
    ``--frames 3`` counts frames from the node's first diagnostics: discovery of the three new
    participants takes seconds on a loaded machine (``--duration 3`` once left 2 such frames)."""
    cases = [(['--namespace', '/truck1'], 1), (['--node', '/truck1/driveline_node'], 1),
             (['--namespace', '/truck2', '--node', 'driveline_node'], 2)]
    monitors = [subprocess.Popen([sys.executable, '-m', 'dmf_sim.cli', 'monitor', *args,
                                  '--plain', '--rate', '4', '--frames', '3'],
                                 env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                 text=True) for args, _ in cases]
    try:
        for proc, (args, truck) in zip(monitors, cases):
            out, err = proc.communicate(timeout=120)
            assert proc.returncode == 0, err
            frames = _frames(out)
            assert len(frames) == 3 and all('speed' in f for f in frames), (args, out)
            for f in frames:
                assert f['node'].startswith(f'/truck{truck}/driveline_node  '), (args, f)
                assert re.match(rf'{speeds[truck]}\.0 rpm', f['speed']), (args, f)
    finally:
        _kill(monitors)


@pytest.mark.slow
def test_two_trucks_monitor_apart_and_end_with_their_launch_parent(tmp_path):
    from std_msgs.msg import Float64

    domain = new_domain()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    bags = {i: tmp_path / f'truck{i}_bag' for i in (1, 2)}
    logs = {i: tmp_path / f'truck{i}.log' for i in (1, 2)}
    speeds = {1: 800, 2: 1200}
    cmds = [([sys.executable, '-m', 'dmf_sim.node', '--ros-args', '-r', f'__ns:=/truck{i}',
              '-p', 'record:=true', '-p', f'bag_path:={bags[i]}', '-p', 'monitor:=false',
              '-p', 'publish_rate:=200.0', '-p', f'initial_speed_rpm:={float(speeds[i])}',
              '-p', 'diagnostics_rate:=4.0'], str(logs[i])) for i in (1, 2)]
    parent = subprocess.Popen([sys.executable, '-c', PARENT, json.dumps(cmds)], env=env,
                              cwd=tmp_path, stdout=subprocess.PIPE, text=True)
    pids = [int(p) for p in parent.stdout.readline().split()]
    peer = Peer(domain)
    try:
        for i in (1, 2):
            peer.subscribe(f'/truck{i}/engine/speed', Float64)
        assert peer.spin_until(lambda: all(peer.counts[f'/truck{i}/engine/speed'] > 20
                                           for i in (1, 2)), 2 * START_TIMEOUT), \
            [log.read_text() for log in logs.values()]
        _monitors_show_their_own_truck(env, speeds)
        peer.spin_for(0.5)
        seen = {i: peer.counts[f'/truck{i}/engine/speed'] for i in (1, 2)}
        parent.send_signal(signal.SIGKILL)        # launch killed: nobody forwards a signal
        parent.wait(timeout=10)
        deadline = time.monotonic() + EXIT_TIMEOUT
        while not all(_gone(pid) for pid in pids) and time.monotonic() < deadline:
            peer.spin_for(0.05)
        assert all(_gone(pid) for pid in pids), [log.read_text() for log in logs.values()]
    finally:
        peer.close()
        if parent.poll() is None:
            parent.kill()
            parent.wait(timeout=10)
        for pid in pids:
            if not _gone(pid):
                os.kill(pid, signal.SIGKILL)

    for i in (1, 2):
        out = logs[i].read_text()
        assert f'stopping (SIGTERM: parent process {parent.pid} ended)' in out, out
        assert f'stopped recording: bag {bags[i]} closed' in out, out
        assert 'Traceback' not in out, out
        meta = yaml.safe_load((bags[i] / 'metadata.yaml').read_text())
        info = meta['rosbag2_bagfile_information']
        assert [p.name for p in sorted(bags[i].glob('*.mcap'))] == info['relative_file_paths']
        total = 0
        for name in info['relative_file_paths']:          # closed: summary and footer written
            with open(bags[i] / name, 'rb') as fh:
                summary = make_reader(fh).get_summary()
            assert summary is not None and summary.statistics is not None
            total += summary.statistics.message_count
        assert total == info['message_count']
        counts = {t['topic_metadata']['name']: t['message_count']
                  for t in info['topics_with_message_count']}
        # every sample a subscriber saw before the kill is in the bag (recorded as published)
        assert counts[f'/truck{i}/engine/speed'] >= seen[i] > 20
        assert meta['rosbag2_bagfile_information']['custom_data']['dmf_sim.node'] == \
            f'/truck{i}/driveline_node'
