"""The sensor messages (dmf_sim.bags.sensor_messages): the edge-batch CDR equals rosbags' and
rclpy's serialization, decodes back from raw bytes and from decoded messages; many batches at
once equal one at a time; BagRecorder.write_messages writes what write() per message writes."""
from __future__ import annotations

import numpy as np
import pytest
import yaml
from rosbags.typesys import Stores, get_typestore

from dmf_sim.bags.layout import resolve_bag
from dmf_sim.bags.read import read_messages
from dmf_sim.bags.sensor_messages import (
    EDGE_DIM_LABELS,
    EDGES_TYPE,
    decode_edges,
    edge_topic,
    edges_of_message,
    encode_edges,
    encode_float64,
    encode_sensor_messages,
    float64_bytes,
    signal_of_topic,
    wheel_of_topic,
)
from dmf_sim.bags.writer import BagRecorder

STORE = get_typestore(Stores.ROS2_JAZZY)
ROWS = np.array([[1_000_000, 5, 0], [2_500_000, 0, 1], [3_000_123, 1, 2], [9_999, 57, 3]],
                np.int64)
EPOCH = 1_796_000_000_123_456_789


def rosbags_edges(rows, epoch):
    t = STORE.types
    n = len(rows)
    data = rows.astype(np.uint64)
    data[:, 0] += np.uint64(epoch)
    msg = t[EDGES_TYPE](
        layout=t['std_msgs/msg/MultiArrayLayout'](
            dim=[t['std_msgs/msg/MultiArrayDimension'](label=EDGE_DIM_LABELS[0], size=n,
                                                        stride=3 * n),
                 t['std_msgs/msg/MultiArrayDimension'](label=EDGE_DIM_LABELS[1], size=3,
                                                        stride=3)],
            data_offset=0), data=data.ravel())
    return msg, bytes(STORE.serialize_cdr(msg, EDGES_TYPE))


@pytest.mark.parametrize('n', [0, 1, 4])
def test_edge_batches_equal_rosbags_serialization_and_decode_back(n):
    msg, theirs = rosbags_edges(ROWS[:n], EPOCH)
    ours = encode_edges(ROWS[:n], EPOCH)
    assert ours == theirs
    for got in (decode_edges(ours), edges_of_message(STORE.deserialize_cdr(ours, EDGES_TYPE))):
        assert np.array_equal(np.stack(got, axis=1), ROWS[:n] + [[EPOCH, 0, 0]])


def test_edge_batches_equal_rclpy_serialization():
    rclpy_ser = pytest.importorskip('rclpy.serialization')
    from std_msgs.msg import MultiArrayDimension, UInt64MultiArray
    msg = UInt64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=EDGE_DIM_LABELS[0], size=4, stride=12),
                      MultiArrayDimension(label=EDGE_DIM_LABELS[1], size=3, stride=3)]
    msg.data = (ROWS + [[EPOCH, 0, 0]]).astype(np.uint64).ravel().tolist()
    raw = rclpy_ser.serialize_message(msg)
    ours = encode_edges(ROWS, EPOCH)
    pad = slice(17, 20)                    # after 'edge\0': rclpy leaves its padding unset
    assert len(raw) == len(ours) and raw[:pad.start] + raw[pad.stop:] == \
        ours[:pad.start] + ours[pad.stop:]
    assert np.array_equal(np.stack(decode_edges(raw), axis=1), ROWS + [[EPOCH, 0, 0]])
    back = rclpy_ser.deserialize_message(raw, UInt64MultiArray)
    assert np.array_equal(np.stack(edges_of_message(back), axis=1), ROWS + [[EPOCH, 0, 0]])


def test_many_messages_at_once_equal_one_at_a_time():
    rows = np.arange(30, dtype=np.int64).reshape(10, 3)
    groups = np.array([[0, 2], [2, 3], [5, 1], [6, 4]])
    values = np.array([1200.125, -3.5])
    order = np.array([4, 0, 1, 5, 3, 2])              # groups 0..3, then the values 4, 5
    payload, offsets = encode_sensor_messages(rows, groups, values, order, EPOCH)
    expect = [float64_bytes(values[m - 4]) if m >= 4
              else encode_edges(rows[groups[m, 0]:groups[m].sum()], EPOCH) for m in order]
    assert [bytes(payload[offsets[i]:offsets[i + 1]]) for i in range(len(order))] == expect


def test_not_an_edge_batch_is_one_line():
    with pytest.raises(ValueError) as exc:
        decode_edges(b'\x00\x01\x00\x00' + bytes(80))
    assert '\n' not in str(exc.value) and 'edge batch' in str(exc.value)
    t = STORE.types
    other = t[EDGES_TYPE](layout=t['std_msgs/msg/MultiArrayLayout'](dim=[], data_offset=0),
                          data=np.zeros(3, np.uint64))
    with pytest.raises(ValueError, match='not an edge batch'):
        edges_of_message(other)


def test_topics_name_their_sensor():
    assert edge_topic('crank') == 'sensors/crank/edges'
    assert wheel_of_topic('/truck1/sensors/crank/edges') == 'crank'
    assert wheel_of_topic('/sensors/crank') is None and wheel_of_topic('/xsensors/a/edges') is None
    assert signal_of_topic('/truck1/vehicle_bus/engine_speed') == 'engine_speed'
    assert signal_of_topic('/vehicle_bus/') is None


def test_float64_payload_equals_rosbags():
    f = encode_float64(np.array([1200.125, -3.5]))
    for v, row in zip((1200.125, -3.5), f):
        msg = STORE.types['std_msgs/msg/Float64'](data=v)
        assert bytes(row) == bytes(STORE.serialize_cdr(msg, 'std_msgs/msg/Float64')) == \
            float64_bytes(v)


@pytest.mark.slow
def test_write_messages_equals_write_per_message(tmp_path):
    topics = {'/a': EDGES_TYPE, '/b': 'std_msgs/msg/Float64'}
    rng = np.random.default_rng(1)
    n = 3000
    log = 10 ** 9 + np.sort(rng.integers(0, 3 * 10 ** 9, n))          # 3 s, 1-s files
    which = rng.integers(0, 2, n)
    payloads = [encode_edges(ROWS[:rng.integers(0, 5)], int(t)) if w == 0
                else bytes(encode_float64(np.array([float(t)]))[0]) for t, w in zip(log, which)]
    one = BagRecorder(tmp_path / 'one', topics, max_duration_s=1.0, chunk_bytes=10 ** 9,
                      chunk_seconds=10.0)
    with one:
        for t, w, p in zip(log, which, payloads):
            one.write(['/a', '/b'][w], int(t), p)
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in payloads])])
    flat = np.frombuffer(b''.join(payloads), np.uint8)
    many = BagRecorder(tmp_path / 'many', topics, max_duration_s=1.0)
    with many:
        for a in range(0, n, 700):
            many.write_messages(log[a:a + 700], which[a:a + 700], ['/a', '/b'], flat,
                                offsets[a:a + 701])

    def content(bag):
        return [(m.topic, m.timestamp_ns, bytes(m.msg)) for m in read_messages(bag, raw=True)]
    assert content(tmp_path / 'one') == content(tmp_path / 'many')
    files = [yaml.safe_load((tmp_path / b / 'metadata.yaml').read_text())
             ['rosbag2_bagfile_information']['files'] for b in ('one', 'many')]
    assert [{k: v for k, v in f.items() if k != 'path'} for f in files[0]] == \
        [{k: v for k, v in f.items() if k != 'path'} for f in files[1]]
    assert len(files[0]) == 3
    from mcap.reader import make_reader
    for f1, f2 in zip(resolve_bag(tmp_path / 'one').files, resolve_bag(tmp_path / 'many').files):
        with open(f1, 'rb') as a, open(f2, 'rb') as b:
            ma = [(m.channel_id, m.sequence, m.log_time, m.data)
                  for _, _, m in make_reader(a).iter_messages(log_time_order=True)]
            mb = [(m.channel_id, m.sequence, m.log_time, m.data)
                  for _, _, m in make_reader(b, validate_crcs=True).iter_messages(
                      log_time_order=True)]
            assert ma == mb and ma
