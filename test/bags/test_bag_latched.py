"""Latched (transient-local) topics and offered QoS in recorded bags.

A recording started after the prediction was published held no ``dmf_predicted`` message, and
``metadata.yaml`` offered every topic as keep-last 10, volatile. Now every recording and every
split file starts with the latched messages (as rosbag2 does for transient-local topics), and
each topic's real offered QoS is in ``metadata.yaml`` and the MCAP channel metadata, in rosbag2
Jazzy's form. Checked on real recorded bags with the ``mcap`` reader and ``rosbags``.
"""
from __future__ import annotations

import struct
from pathlib import Path

import yaml
from mcap.reader import make_reader

from dmf_sim.bags.writer import BagRecorder, qos_profile
from dmf_sim.live.recording import RecordingControl
from dmf_sim.live.streams import STREAMS

PRED, WINDUP = '/driveline/dmf_predicted', '/driveline/dmf_windup'
TOPICS = {PRED: 'std_msgs/msg/Float64', WINDUP: 'std_msgs/msg/Float64'}
QOS = {PRED: STREAMS['dmf_predicted'].qos_profile(), WINDUP: STREAMS['dmf_windup'].qos_profile()}
T0 = 1_700_000_000_000_000_000
MS = 1_000_000


def f64(value: float) -> bytes:
    return b'\x00\x01\x00\x00' + struct.pack('<d', value)


def value_of(data: bytes) -> float:
    return struct.unpack_from('<d', data, 4)[0]


def files_of(bag: Path) -> list[list[tuple[str, int, int, float]]]:
    """Per MCAP file (in split order): (topic, log time, publish time, value) of each message,
    as the ``mcap`` reader reads them in log-time order."""
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    out = []
    for name in meta['relative_file_paths']:
        with open(bag / name, 'rb') as fh:
            reader = make_reader(fh)
            out.append([(ch.topic, m.log_time, m.publish_time, value_of(m.data))
                        for _, ch, m in reader.iter_messages(log_time_order=True)])
    return out


def test_each_split_starts_with_the_latched_message_and_qos_is_the_offered_one(tmp_path):
    bag = tmp_path / 'bag'
    rec = BagRecorder(bag, TOPICS, qos=QOS, max_duration_s=1.0)
    rec.hold_latched(PRED, T0 - 5000 * MS, f64(1.0))     # published before the recording
    for i in range(350):                                 # 3.5 s at 100 Hz: 4 files
        t = T0 + i * 10 * MS
        if i == 150:
            rec.write(PRED, t, f64(2.0))                 # a new prediction in file 1
        rec.write(WINDUP, t, f64(0.001 * i))
    rec.close()

    files = files_of(bag)
    assert len(files) == 4
    expected = [1.0, 1.0, 2.0, 2.0]     # the latched value at each file's start
    for k, msgs in enumerate(files):
        topic, log_ns, _, value = msgs[0]
        assert topic == PRED and value == expected[k], (k, msgs[:2])
        assert log_ns == msgs[1][1] == T0 + k * 1000 * MS        # the file's first log time
        assert sum(m[0] == PRED for m in msgs) == (2 if k == 1 else 1)
    # original publication kept as publish time
    assert files[0][0][2] == T0 - 5000 * MS and files[2][0][2] == T0 + 1500 * MS

    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    offered = {t['topic_metadata']['name']: t['topic_metadata']['offered_qos_profiles']
               for t in meta['topics_with_message_count']}
    assert offered[PRED] == [qos_profile(1, transient_local=True)]
    assert offered[PRED][0]['durability'] == 'transient_local'
    assert offered[WINDUP] == [qos_profile(100)]
    assert (offered[WINDUP][0]['depth'], offered[WINDUP][0]['reliability']) == (100, 'reliable')
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in meta['topics_with_message_count']}
    assert counts == {PRED: 5, WINDUP: 350}

    # the MCAP channel metadata of every file says the same (rosbag2's YAML text)
    for name in meta['relative_file_paths']:
        with open(bag / name, 'rb') as fh:
            summary = make_reader(fh).get_summary()
        for ch in summary.channels.values():
            assert yaml.safe_load(ch.metadata['offered_qos_profiles']) == offered[ch.topic]

    # rosbags reads the offered QoS as ROS would replay it: reliable, transient-local, depth 1
    from rosbags.rosbag2 import Reader
    with Reader(bag) as reader:
        qos = {c.topic: c.ext.offered_qos_profiles[0] for c in reader.connections}
        assert qos[PRED].durability.name.lower() == 'transient_local'
        assert qos[PRED].depth == 1 and qos[WINDUP].depth == 100
        assert qos[WINDUP].reliability.name.lower() == 'reliable'
        first = next(reader.messages())
        assert first[0].topic == PRED and value_of(first[2]) == 1.0


def test_a_recording_started_after_the_prediction_holds_it(tmp_path):
    """The node's recording lifecycle: the latched message published while not recording is
    the first message of the next recording (and of the one after it)."""
    logs = []
    log = type('Log', (), {'info': logs.append, 'warning': logs.append,
                           'error': logs.append})()
    control = RecordingControl(TOPICS, log, qos=QOS, max_duration_s=60.0)
    control.write(PRED, T0, f64(3.0))                    # not recording: remembered
    control.write(WINDUP, T0, f64(0.1))
    bags = []
    for n in range(2):
        recorder, reason = control.prepare(str(tmp_path / f'rec{n}'), _metadata())
        assert reason is None
        control.start(recorder)
        for i in range(1, 20):
            control.write(WINDUP, T0 + (100 * n + i) * MS, f64(0.2))
        control.stop()
        bags.append(recorder.path)
    for path in bags:
        msgs = files_of(path)[0]
        assert msgs[0][0] == PRED and msgs[0][3] == 3.0 and msgs[0][2] == T0
        assert [m[0] for m in msgs].count(PRED) == 1 and len(msgs) == 20


def _metadata():
    from dmf_sim.bags.metadata import RunMetadata
    return RunMetadata(driveline='truck_dmf', engine='engine_d13', load_set='A', alpha=2.5,
                       theta_rad=0.24, spring=None, load=0.5, speed_rpm=1000.0, dt_s=1e-4,
                       publish_rate_hz=1000.0, node='/driveline_node')
