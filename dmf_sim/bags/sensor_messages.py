"""The sensor messages: topics, the edge-batch layout, its encoding and decoding (no ROS).

The one place the layout is written: the live node and ``dmf-sim run`` encode with it, the
analysis of bags decodes with it.

**Edge batches**, topic ``sensors/<wheel>/edges`` (relative to the node's namespace), type
``std_msgs/msg/UInt64MultiArray``, one message per wheel per batch period (the driveline's
``sensors.edge_batch_s``, at least one publish period) with that period's edges, logged at its
end (:func:`batch_log_ns`; an empty batch is not sent)::

    layout.dim = [{label: 'edge', size: n, stride: 3 n},
                  {label: 'time_ns,tooth,flags', size: 3, stride: 3}]
    layout.data_offset = 0
    data = [time_ns_0, tooth_0, flags_0, time_ns_1, tooth_1, flags_1, ...]   (row-major, n x 3)

* ``time_ns``: when the timer captured the edge [ns], on the node's stamp clock (the same clock
  as every header stamp it publishes: wall clock at real-time factor 1); exact integers (a
  float64 of seconds since 1970 would not resolve 0.1 us);
* ``tooth``: the tooth index, 0 .. teeth - gap - 1, 0 = the first tooth after the gap;
* ``flags``: bit 0 (:data:`FLAG_FIRST_AFTER_GAP`) the first edge after the gap (tooth 0 of a
  wheel with a gap); bit 1 (:data:`FLAG_SPURIOUS`) a spurious edge injected by a sensor fault:
  ground truth, which a stack under test must not use.

**Bus signals**, topic ``vehicle_bus/<signal>``, ``std_msgs/msg/Float64``: the value [rpm], one
message when each value is delivered (its send time + delay).

The CDR bytes are built here with numpy (little-endian CDR, as rclpy writes on x86 and ARM);
``test/bags/test_sensor_messages.py`` compares them with rosbags' and rclpy's serializers.
"""
from __future__ import annotations

import struct
from typing import Any

import numpy as np

from dmf_sim.core.compiled import jit
from dmf_sim.physics.sensors import FLAG_FIRST_AFTER_GAP, FLAG_SPURIOUS

__all__ = ['EDGES_TYPE', 'BUS_TYPE', 'EDGE_DIM_LABELS', 'EDGE_FIELDS', 'FLAG_FIRST_AFTER_GAP',
           'FLAG_SPURIOUS', 'edge_topic', 'bus_topic', 'wheel_of_topic', 'signal_of_topic',
           'batch_log_ns', 'encode_edges', 'encode_sensor_messages', 'fill_messages',
           'decode_edges',
           'edges_of_message',
           'encode_float64', 'float64_bytes', 'FLOAT64_BYTES', 'EDGE_HEADER_BYTES',
           'EDGE_ROW_BYTES']

EDGES_TYPE = 'std_msgs/msg/UInt64MultiArray'
BUS_TYPE = 'std_msgs/msg/Float64'
EDGE_FIELDS = ('time_ns', 'tooth', 'flags')
EDGE_DIM_LABELS = ('edge', ','.join(EDGE_FIELDS))
_EDGES_PREFIX = 'sensors/'
_EDGES_SUFFIX = '/edges'
_BUS_PREFIX = 'vehicle_bus/'


def edge_topic(wheel: str) -> str:
    """The edge batches' topic of tooth wheel ``wheel`` (relative to the node's namespace)."""
    return f'{_EDGES_PREFIX}{wheel}{_EDGES_SUFFIX}'


def bus_topic(signal: str) -> str:
    """The topic of bus signal ``signal`` (relative to the node's namespace)."""
    return f'{_BUS_PREFIX}{signal}'


def wheel_of_topic(topic: str) -> str | None:
    """The wheel whose edges an (absolute or relative) topic carries, or None."""
    head, sep, tail = topic.rpartition(_EDGES_PREFIX)
    if not sep or not tail.endswith(_EDGES_SUFFIX) or (head and not head.endswith('/')):
        return None
    wheel = tail[:-len(_EDGES_SUFFIX)]
    return wheel if wheel and '/' not in wheel else None


def signal_of_topic(topic: str) -> str | None:
    """The bus signal an (absolute or relative) topic carries, or None."""
    head, sep, tail = topic.rpartition(_BUS_PREFIX)
    if not sep or not tail or '/' in tail or (head and not head.endswith('/')):
        return None
    return tail


# ---- CDR of std_msgs/msg/UInt64MultiArray with the edge layout ------------------------------
# encapsulation (CDR little-endian), dim count 2, dim 0: label 'edge', size, stride; dim 1: label
# 'time_ns,tooth,flags', size 3, stride 3; data_offset 0; data: count, then the uint64s (at an
# 8-byte aligned offset of the body: 64, so no padding)


def _cdr_string(text: str) -> bytes:
    raw = text.encode() + b'\0'
    pad = (-len(raw)) % 4
    return struct.pack('<I', len(raw)) + raw + b'\0' * pad


_HEAD_A = b'\x00\x01\x00\x00' + struct.pack('<I', 2) + _cdr_string(EDGE_DIM_LABELS[0])
_HEAD_B = _cdr_string(EDGE_DIM_LABELS[1]) + struct.pack('<III', 3, 3, 0)
EDGE_HEADER_BYTES = len(_HEAD_A) + 8 + len(_HEAD_B) + 4     # before the data: 68
EDGE_ROW_BYTES = 24                                           # three uint64 per edge
_SIZE_AT = len(_HEAD_A)                                       # dim 0 size, stride
_HEAD_B_DIMS = _HEAD_B[:-4]               # label 1, its size and stride (then data_offset)
_PAD_AT = _SIZE_AT - (-(len(EDGE_DIM_LABELS[0]) + 1)) % 4   # the label's padding: rclpy
                                                              # leaves it unset, so not read
_COUNT_AT = EDGE_HEADER_BYTES - 4                             # data count
FLOAT64_BYTES = 12                                            # encapsulation + float64
_FLOAT64_HEAD = b'\x00\x01\x00\x00'
_FLOAT64 = struct.Struct('<4sd')


def batch_log_ns(t_ns: np.ndarray, period_ns: float) -> np.ndarray:
    """The send (log) time [ns of simulated time] of edges captured at ``t_ns``: the end of
    their batch period, ``ceil(t / period) * period`` (edges in (b - period, b] go at b;
    :meth:`dmf_sim.physics.sensors.SensorSet.edge_batch_ns`). One rule for the node and
    ``dmf-sim run``."""
    return np.rint(np.ceil(np.asarray(t_ns) / period_ns) * period_ns).astype(np.int64)


def encode_edges(rows: np.ndarray, epoch_ns: int = 0) -> bytes:
    """One edge batch: (n, 3) int64 rows (time_ns of simulated time, tooth, flags), stamped
    ``epoch_ns`` + time_ns; the CDR bytes of its UInt64MultiArray."""
    n = rows.shape[0]
    flat = rows.ravel().tolist()          # the node's batches hold an edge or two: struct
    flat[0::3] = [t + epoch_ns for t in flat[0::3]]       # beats numpy's per-call overhead
    return b''.join((_HEAD_A, struct.pack('<II', n, 3 * n), _HEAD_B_DIMS,
                     struct.pack(f'<II{3 * n}Q', 0, 3 * n, *flat)))


def _put(out, at, value, nbytes):
    """``nbytes`` little-endian bytes of the integer ``value`` into out[at:]."""
    for k in range(nbytes):
        out[at + k] = (value >> (8 * k)) & 0xFF


def fill_messages(rows, groups, values_bits, order, epoch, head, out, offsets):
    """The messages of :func:`encode_sensor_messages` into ``out`` at ``offsets`` (compiled)."""
    n_groups = groups.shape[0]
    for i in range(order.shape[0]):
        m = order[i]
        p = offsets[i]
        if m < n_groups:
            start = groups[m, 0]
            n = groups[m, 1]
            for k in range(head.shape[0]):
                out[p + k] = head[k]
            _put(out, p + _SIZE_AT, n, 4)
            _put(out, p + _SIZE_AT + 4, 3 * n, 4)
            _put(out, p + _COUNT_AT, 3 * n, 4)
            q = p + head.shape[0]
            for r in range(start, start + n):
                _put(out, q, rows[r, 0] + epoch, 8)
                _put(out, q + 8, rows[r, 1], 8)
                _put(out, q + 16, rows[r, 2], 8)
                q += EDGE_ROW_BYTES
        else:
            out[p] = 0
            out[p + 1] = 1
            out[p + 2] = 0
            out[p + 3] = 0
            _put(out, p + 4, values_bits[m - n_groups], 8)


def encode_sensor_messages(rows: np.ndarray, groups: np.ndarray, values: np.ndarray,
                           order: np.ndarray, epoch_ns: int = 0
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Many sensor messages at once (``dmf-sim run``): edge batch g holds rows
    ``groups[g, 0]`` .. + ``groups[g, 1]`` of ``rows`` ((n, 3) int64: time_ns of simulated
    time, tooth, flags; stamped ``epoch_ns`` + time_ns), bus message k the Float64
    ``values[k]``; ``order`` lists the messages to write, g < len(groups) an edge batch,
    len(groups) + k a bus value. Returns the payloads concatenated (uint8) and their offsets
    (messages + 1): each what :func:`encode_edges` / :func:`float64_bytes` gives."""
    groups = np.asarray(groups, dtype=np.int64).reshape(-1, 2)
    order = np.asarray(order, dtype=np.int64)
    edge = order < len(groups)
    sizes = np.full(len(order), FLOAT64_BYTES, np.int64)
    sizes[edge] = EDGE_HEADER_BYTES + EDGE_ROW_BYTES * groups[order[edge], 1]
    offsets = np.zeros(len(order) + 1, np.int64)
    np.cumsum(sizes, out=offsets[1:])
    out = np.empty(int(offsets[-1]), np.uint8)
    fill_messages(np.ascontiguousarray(rows, dtype=np.int64), groups,
          np.ascontiguousarray(values, dtype=np.float64).view(np.int64), order, int(epoch_ns),
          _EDGE_HEAD, out, offsets)
    return out, offsets


_put = jit(_put)
fill_messages = jit(fill_messages)
_EDGE_HEAD = np.frombuffer(encode_edges(np.zeros((0, 3), np.int64)), np.uint8)[:EDGE_HEADER_BYTES]


def decode_edges(data: bytes | memoryview) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The edges of one edge-batch message's CDR bytes: (time_ns, tooth, flags) int64 arrays
    (time on the publisher's stamp clock). ValueError (one line) when the bytes are not an
    edge batch of this layout."""
    buf = bytes(data[:EDGE_HEADER_BYTES])
    if len(buf) < EDGE_HEADER_BYTES or buf[:_PAD_AT] != _HEAD_A[:_PAD_AT] \
            or buf[_SIZE_AT + 8:_COUNT_AT - 4] != _HEAD_B_DIMS:
        raise ValueError('not an edge batch (UInt64MultiArray with dims edge, '
                         f'{EDGE_DIM_LABELS[1]})')
    n, stride = struct.unpack_from('<II', buf, _SIZE_AT)
    (count,) = struct.unpack_from('<I', buf, _COUNT_AT)
    if stride != 3 * n or count != 3 * n or len(data) < EDGE_HEADER_BYTES + 24 * n:
        raise ValueError(f'edge batch of {n} edges holds {count} numbers (expected {3 * n})')
    rows = np.frombuffer(data, '<u8', 3 * n, EDGE_HEADER_BYTES).reshape(n, 3).astype(np.int64)
    return rows[:, 0], rows[:, 1], rows[:, 2]


def edges_of_message(msg: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The edges of a decoded UInt64MultiArray (rclpy's or rosbags' message object), as
    :func:`decode_edges` gives them; ValueError when its layout is not the edge layout."""
    dims = list(msg.layout.dim)
    labels = tuple(d.label for d in dims)
    if labels != EDGE_DIM_LABELS or dims[1].size != 3 or msg.layout.data_offset != 0:
        raise ValueError(f'not an edge batch: layout labels {labels}, expected '
                         f'{EDGE_DIM_LABELS}')
    n = dims[0].size
    data = np.asarray(msg.data, dtype=np.uint64)
    if data.shape[0] != 3 * n:
        raise ValueError(f'edge batch of {n} edges holds {data.shape[0]} numbers')
    rows = data.reshape(n, 3).astype(np.int64)
    return rows[:, 0], rows[:, 1], rows[:, 2]


def float64_bytes(value: float) -> bytes:
    """One std_msgs/msg/Float64 (the node's bus messages, one at a time)."""
    return _FLOAT64.pack(_FLOAT64_HEAD, value)


def encode_float64(values: np.ndarray) -> np.ndarray:
    """(n, 12) uint8: one std_msgs/msg/Float64 per value."""
    out = np.empty((len(values), FLOAT64_BYTES), np.uint8)
    out[:, :4] = np.frombuffer(_FLOAT64_HEAD, np.uint8)
    out[:, 4:].view('<f8')[:, 0] = values
    return out
