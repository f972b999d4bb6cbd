"""The node's sample messages as CDR bytes, a block of samples at a time (numpy, no rclpy); the
sensor messages of ``dmf-sim run`` likewise (:class:`SensorBlock`).

The node serializes every sample into a ``sensor_msgs/JointState`` (stamp; one name per element;
position = vibratory angle, velocity, effort = transmitted torque) and three ``std_msgs/Float64``
(wind-up [rad], engine speed [rpm], crank angle [rad]) -- see
:data:`dmf_sim.live.streams.SAMPLE_STREAMS`. With fixed element names every message of a stream
has the same length and layout, so a block is a template row repeated with the stamp and the
numbers written in place. The template comes from ``rosbags``' serializer (the readers' decoder)
and the field offsets from :func:`dmf_sim.bags.columns.joint_state_layout`, the layout the fast
reader checks; a test compares the bytes with ``rosbags``' and rclpy's serialization.

:class:`StatusEncoder` writes status arrays (``diagnostic_msgs/DiagnosticArray`` of
:class:`dmf_sim.monitor.messages.StatusData`, e.g. the node's health status on ``/diagnostics``)
as the node publishes them (:meth:`StatusData.to_msg`), one message at a time.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dmf_sim.bags.columns import FLOAT64, JOINT_STATE, joint_state_layout
from dmf_sim.bags.sensor_messages import FLOAT64_BYTES, batch_log_ns, encode_sensor_messages
from dmf_sim.live.simulation import Samples
from dmf_sim.live.streams import SAMPLE_STREAMS, STREAMS
from dmf_sim.monitor.messages import StatusData

__all__ = ['SampleEncoder', 'EncodedBlock', 'StatusEncoder', 'SensorBlock']

# the Float64 sample streams (SAMPLE_STREAMS after the joint states): the Samples field each
# carries
_FLOAT_FIELDS = {'dmf_windup': 'windup', 'speed': 'speed_rpm', 'crank_angle': 'psi'}

_NS_PER_S = 1_000_000_000
_DIAGNOSTIC_ARRAY = 'diagnostic_msgs/msg/DiagnosticArray'


def _typestore():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)          # cached by rosbags


def _float_field(rows: np.ndarray, offset: int, n: int) -> np.ndarray:
    """The (rows, n) little-endian float64 field at byte ``offset`` of each row of a (rows,
    size) uint8 array, as a view (unaligned: CDR puts it where the message layout does), so
    values are written into the messages in one copy."""
    return rows[:, offset:offset + 8 * n].view('<f8')


class SampleEncoder:
    """CDR payloads of the four sample streams for element ``names`` (little-endian CDR, as
    rclpy writes on x86/ARM)."""

    def __init__(self, names: Sequence[str]) -> None:
        store = _typestore()
        js_t = store.types[JOINT_STATE]
        hdr_t = store.types['std_msgs/msg/Header']
        time_t = store.types['builtin_interfaces/msg/Time']
        n = len(names)
        msg = js_t(header=hdr_t(stamp=time_t(sec=0, nanosec=0), frame_id=''), name=list(names),
                   position=np.zeros(n), velocity=np.zeros(n), effort=np.zeros(n))
        self.template = np.frombuffer(bytes(store.serialize_cdr(msg, JOINT_STATE)), np.uint8)
        _, got_names, arrays, total, _ = joint_state_layout(self.template.tobytes())
        if got_names != list(names) or total != len(self.template):
            raise ValueError('unexpected JointState layout')        # a rosbags change: a bug
        self.offsets = {k: off for k, (off, _) in arrays.items()}
        self.n = n
        f64 = store.types[FLOAT64]
        self.float_template = np.frombuffer(bytes(store.serialize_cdr(f64(data=0.0), FLOAT64)),
                                            np.uint8)
        if len(self.float_template) != FLOAT64_BYTES:
            raise ValueError('unexpected Float64 layout')

    @property
    def sample_bytes(self) -> int:
        """Payload bytes of one sample: its JointState and its Float64 messages."""
        return len(self.template) + (len(SAMPLE_STREAMS) - 1) * FLOAT64_BYTES

    def joint_states(self, stamps_ns: np.ndarray, position: np.ndarray, velocity: np.ndarray,
                     effort: np.ndarray) -> np.ndarray:
        """(rows, size) uint8: one JointState per row."""
        out = np.empty((len(stamps_ns), len(self.template)), np.uint8)
        out[:] = self.template
        self.stamp(out, stamps_ns)
        arrays = self.arrays(out)
        for k, values in enumerate((position, velocity, effort)):
            arrays[k][:] = values
        return out

    def stamp(self, rows: np.ndarray, stamps_ns: np.ndarray) -> None:
        """Write the header stamps [ns] of JointState ``rows`` (rows, size)."""
        sec, nsec = np.divmod(np.asarray(stamps_ns, np.int64), _NS_PER_S)
        stamp = np.empty((len(sec), 2), '<u4')        # builtin_interfaces/Time: int32, uint32
        stamp[:, 0] = sec.astype('<i4').view('<u4')
        stamp[:, 1] = nsec
        rows[:, 4:12] = stamp.view(np.uint8)          # one strided copy of 8 bytes a row

    def arrays(self, rows: np.ndarray) -> list[np.ndarray]:
        """The position, velocity and effort arrays of JointState ``rows`` (rows, size) as
        (rows, elements) float64 views into them."""
        return [_float_field(rows, self.offsets[k], self.n)
                for k in ('position', 'velocity', 'effort')]

    def floats(self, values: np.ndarray) -> np.ndarray:
        """(rows, 12) uint8: one Float64 per row."""
        out = np.empty((len(values), FLOAT64_BYTES), np.uint8)
        out[:, :4] = self.float_template[:4]
        _float_field(out, 4, 1)[:, 0] = values
        return out


class StatusEncoder:
    """CDR payloads of status arrays (the node's ``diagnostic_msgs/DiagnosticArray`` streams,
    e.g. ``/diagnostics``): the header stamp and the statuses with their level, name, message,
    hardware id and key/values, as :meth:`StatusData.to_msg` fills the rclpy message."""

    def __init__(self) -> None:
        store = _typestore()
        self.store = store
        self.msgtype = STREAMS['diagnostics'].msgtype
        self._array = store.types[self.msgtype]
        self._status = store.types['diagnostic_msgs/msg/DiagnosticStatus']
        self._key_value = store.types['diagnostic_msgs/msg/KeyValue']
        self._header = store.types['std_msgs/msg/Header']
        self._time = store.types['builtin_interfaces/msg/Time']

    def array(self, stamp_ns: int, statuses: Sequence[StatusData]) -> bytes:
        """One DiagnosticArray of ``statuses`` stamped ``stamp_ns`` [ns]."""
        sec, nsec = divmod(int(stamp_ns), _NS_PER_S)
        msg = self._array(
            header=self._header(stamp=self._time(sec=sec, nanosec=nsec), frame_id=''),
            status=[self._status(level=s.level, name=s.name, message=s.message,
                                 hardware_id=s.hardware_id,
                                 values=[self._key_value(key=k, value=v) for k, v in s.values])
                    for s in statuses])
        return bytes(self.store.serialize_cdr(msg, self.msgtype))


class EncodedBlock:
    """The sample messages of up to ``rows`` samples, encoded as the chunks arrive (no gathered
    copy of the samples; the template bytes written once, the stamps once per block): :meth:`add`
    a chunk's rows, then :meth:`take` the stamps and the (topic, payloads) of the sample streams
    in the node's order (:data:`dmf_sim.live.streams.SAMPLE_STREAMS`) for
    :meth:`dmf_sim.bags.writer.BagRecorder.write_block`. The views into the messages are made
    once: ~7 array copies per chunk. With ``recorder``, the messages are the records it writes
    (:meth:`~dmf_sim.bags.writer.BagRecorder.block_payloads`: no copy of the ~1 MB block)."""

    def __init__(self, encoder: SampleEncoder, rows: int, topics: dict[str, str],
                 recorder=None) -> None:
        self.encoder = encoder
        self.stamps = np.empty(rows, np.int64)
        self.topics = [topics[k] for k in SAMPLE_STREAMS]
        sizes = [len(encoder.template)] + [FLOAT64_BYTES] * (len(SAMPLE_STREAMS) - 1)
        if recorder is not None:      # encode into the records the bag recorder writes
            self.js, *self.fl = recorder.block_payloads(self.topics, sizes, rows)
        else:
            self.js, *self.fl = (np.empty((rows, size), np.uint8) for size in sizes)
        self.js[:] = encoder.template
        for f in self.fl:
            f[:] = encoder.float_template
        self.js_arrays = encoder.arrays(self.js)
        self.fl_values = [(_FLOAT_FIELDS[k], _float_field(f, 4, 1)[:, 0])
                          for k, f in zip(SAMPLE_STREAMS[1:], self.fl)]
        self.n = 0

    @property
    def free(self) -> int:
        return len(self.stamps) - self.n

    def add(self, s: Samples, stamps_ns: np.ndarray, start: int, stop: int) -> None:
        """Encode rows start:stop of ``s`` (stamped ``stamps_ns``, one per row of ``s``)."""
        sl = slice(self.n, self.n + stop - start)
        rows = slice(start, stop)
        self.stamps[sl] = stamps_ns[rows]
        for dst, values in zip(self.js_arrays, (s.position, s.velocity, s.effort)):
            dst[sl] = values[rows]
        for field, dst in self.fl_values:
            dst[sl] = getattr(s, field)[rows]
        self.n = sl.stop

    def take(self) -> tuple[np.ndarray, list[tuple[str, np.ndarray]]]:
        """The stamps and payloads gathered (views; valid until the next :meth:`add`), and
        empty."""
        n, self.n = self.n, 0
        self.encoder.stamp(self.js[:n], self.stamps[:n])
        return self.stamps[:n], list(zip(self.topics, [self.js[:n]] + [f[:n] for f in self.fl]))


class SensorBlock:
    """The sensor messages of ``dmf-sim run``, gathered chunk by chunk and encoded and written
    at once (:func:`dmf_sim.bags.sensor_messages.encode_sensor_messages`,
    :meth:`dmf_sim.bags.writer.BagRecorder.write_messages`), as the node sends them: per wheel
    one edge batch per batch period with the edges captured in it (logged at the period's end,
    :func:`dmf_sim.bags.sensor_messages.batch_log_ns`; none when empty), and one ``Float64``
    per bus value at its delivery (layouts: :mod:`dmf_sim.bags.sensor_messages`).

    ``topics``: stream key -> topic (:func:`dmf_sim.live.streams.resolved_topics` of the run's
    streams); ``batch_period_ns``: the edge-batch period
    (:meth:`dmf_sim.physics.sensors.SensorSet.edge_batch_ns`); ``epoch_ns``: the stamp of
    simulated time 0 (:class:`dmf_sim.live.pacing.TimeBase`)."""

    def __init__(self, wheel_names: Sequence[str], signal_names: Sequence[str],
                 topics: dict[str, str], batch_period_ns: float, epoch_ns: int) -> None:
        from dmf_sim.live.streams import bus_key, edge_key
        self.wheel_names = tuple(wheel_names)
        self.signal_names = tuple(signal_names)
        self.topics = ([topics[edge_key(w)] for w in wheel_names]
                       + [topics[bus_key(b)] for b in signal_names])
        self.period_ns = float(batch_period_ns)
        self.epoch_ns = int(epoch_ns)
        self._edges: list[list[np.ndarray]] = [[] for _ in self.wheel_names]
        self._bus: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in self.signal_names]

    def add(self, chunk) -> None:
        """A :class:`~dmf_sim.physics.sensor_signals.SensorChunk`'s signals (its own arrays)."""
        for w, n in enumerate(chunk.edge_counts):
            if n:
                self._edges[w].append(chunk.edge_rows(w))
        for b, n in enumerate(chunk.bus_counts):
            if n:
                self._bus[b].append(chunk.bus_of(b))

    def take(self, upto_ns: int | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The messages gathered with log times up to ``upto_ns`` (None: all), encoded, in
        log-time order, as :meth:`~dmf_sim.bags.writer.BagRecorder.write_messages` takes them
        (log times, topic indexes into :attr:`topics`, payload, offsets); the later ones
        stay."""
        limit = np.inf if upto_ns is None else upto_ns - self.epoch_ns    # simulated ns
        rows, groups, logs, topic = [], [], [], []
        at = 0
        for w, parts in enumerate(self._edges):
            if not parts:
                continue
            r = np.concatenate(parts) if len(parts) > 1 else parts[0]
            log = batch_log_ns(r[:, 0], self.period_ns)
            n = int(np.searchsorted(log, limit, side='right'))
            self._edges[w] = [r[n:]] if n < len(r) else []
            if not n:
                continue
            starts = np.flatnonzero(np.diff(log[:n], prepend=-1))
            counts = np.diff(np.append(starts, n))
            rows.append(r[:n])
            groups.append(np.stack([starts + at, counts], axis=1))
            logs.append(log[starts])
            topic.append(np.full(len(starts), w))
            at += n
        values = []
        for b, parts in enumerate(self._bus):
            if not parts:
                continue
            ns = np.concatenate([p[0] for p in parts])
            rpm = np.concatenate([p[1] for p in parts])
            n = int(np.searchsorted(ns, limit, side='right'))
            self._bus[b] = [(ns[n:], rpm[n:])] if n < len(ns) else []
            values.append(rpm[:n])
            logs.append(ns[:n])
            topic.append(np.full(n, len(self.wheel_names) + b))
        if not logs:
            return (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.uint8),
                    np.zeros(1, np.int64))
        log = np.concatenate(logs)
        order = np.argsort(log, kind='stable')
        payload, offsets = encode_sensor_messages(
            np.concatenate(rows) if rows else np.zeros((0, 3), np.int64),
            np.concatenate(groups) if groups else np.zeros((0, 2), np.int64),
            np.concatenate(values) if values else np.zeros(0), order, self.epoch_ns)
        return self.epoch_ns + log[order], np.concatenate(topic)[order], payload, offsets
