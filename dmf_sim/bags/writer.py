"""rosbag2-compatible MCAP bags: crash-tolerant recording split into files of bounded duration.

A bag is a directory holding ``metadata.yaml`` and MCAP files ``<name>_0.mcap``,
``<name>_1.mcap``, ..., laid out as rosbag2 (Jazzy, metadata version 9) with its MCAP storage
plugin writes it: ``ros2`` profile, ``cdr`` messages, ``ros2msg`` schemas with the full message
definition embedded, channel metadata ``offered_qos_profiles`` and ``topic_type_hash``, a
``rosbag2`` metadata record. So ``ros2 bag``, Foxglove, PlotJuggler, rosbags and the ``mcap``
readers open it.

Splits: like ``ros2 bag record --max-bag-duration``, :class:`BagRecorder` starts a new file once
the current one spans ``max_duration_s`` of log time. Each finished file is closed with its
complete MCAP summary and footer, and ``metadata.yaml`` is rewritten listing the closed files
(message counts, durations, ``custom_data``) -- by a helper thread, so the writing thread does not
wait for it. So after a crash (even SIGKILL) every split but
the last is a complete file that rosbags, ``mcap`` and ``ros2 bag`` read; the last one, not yet
listed, is a valid MCAP prefix that :func:`read_messages` and ``dmf-sim analyze`` read up to its
last complete chunk and :func:`recover_bag` (``dmf-sim bag-recover``) completes.

QoS and latched topics: each topic's offered QoS (``qos``; rosbag2 Jazzy's profile form, see
:func:`qos_profile`) is written into ``metadata.yaml`` and the MCAP channel metadata, so
``ros2 bag play`` offers it again. Like rosbag2, the last messages of each transient-local
topic are written again at the start of every split file (logged at the file's first log time,
their original time kept as publish time), so every file holds the latched state;
:meth:`BagRecorder.hold_latched` gives a recording the ones published before it started.

Memory: the ``mcap`` writer keeps one chunk index per chunk (about 0.7 KB) until it writes the
file's summary; at ~10 chunks per second that grew ~25-50 MB per hour of one file. Splitting
bounds it to one file's worth (60 s: < 1 MB) and frees it at every split.

Chunks: a chunk closes when it holds ``chunk_bytes`` of data or spans ``chunk_seconds`` of log
time or of wall time, and is handed to the operating system at once, so a crash loses at most
the open chunk.

No ROS runtime is needed: the recorder takes CDR bytes (e.g. from
``rclpy.serialization.serialize_message``); the readers decode with ``rosbags`` from the schemas
embedded in the files. Reading: :mod:`dmf_sim.bags.read` (re-exported here), recovery:
:mod:`dmf_sim.bags.recovery`, which files make a bag: :mod:`dmf_sim.bags.layout`.
"""
from __future__ import annotations

import io
import math
import os
import struct
import threading
import time
from collections import deque
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.records import ChunkIndex, MessageIndex
from mcap.writer import CompressionType, IndexType, Writer
from zlib_ng import zlib_ng as zlib  # zlib's CRC-32, ~4.7x faster (SIMD; the same values)

from dmf_sim.bags.layout import (
    LIBRARY,
    ROS_DISTRO,
    FileInfo,
    TopicInfo,
    bag_metadata,
    dump_metadata,
    refuse_existing,
    write_metadata,
)
from dmf_sim.bags.mcap_internals import WriterState, set_data_section_crc, writer_state
from dmf_sim.bags.read import BagMessage, bag_topics, read_messages
from dmf_sim.bags.recovery import RecoverReport, recover_bag
from dmf_sim.core.compiled import jit
from dmf_sim.core.errors import BagError, BagExistsError

__all__ = [
    'BagMessage', 'BagRecorder', 'RecoverReport', 'bag_topics', 'latched_depth', 'pack_records',
    'qos_profile',
    'read_messages', 'recover_bag', 'MAX_DURATION_RANGE_S',
]

DEFAULT_MAX_DURATION_S = 60.0
MAX_DURATION_RANGE_S = (1.0, 3600.0)   # split duration bounds [s]; the upper one bounds memory

_INFINITE = {'sec': 9223372036, 'nsec': 854775807}  # RMW_DURATION_INFINITE as rosbag2 writes it
_QOS_PRESETS: dict[str, dict[str, Any]] = {
    'reliable': {'history': 'keep_last', 'depth': 10, 'reliability': 'reliable',
                 'durability': 'volatile'},
    'best_effort': {'history': 'keep_last', 'depth': 5, 'reliability': 'best_effort',
                    'durability': 'volatile'},
    'transient_local': {'history': 'keep_last', 'depth': 1, 'reliability': 'reliable',
                        'durability': 'transient_local'},
}
_COMPRESSION = {'none': CompressionType.NONE, 'lz4': CompressionType.LZ4,
                'zstd': CompressionType.ZSTD}
_MESSAGE_OVERHEAD = 31 + 16  # message record header + its message index entry, bytes
_OP_MESSAGE, _OP_CHUNK, _OP_MESSAGE_INDEX = 5, 6, 7       # MCAP opcodes
_MESSAGE_HEAD = 22                          # channel 2 + sequence 4 + log 8 + publish 8 bytes
_MESSAGE_RECORD_HEAD = 9 + _MESSAGE_HEAD    # + opcode 1 + record length 8: before the data
_RECORD_HEAD = np.dtype([('op', 'u1'), ('len', '<u8'), ('cid', '<u2'), ('seq', '<u4'),
                         ('log', '<u8'), ('pub', '<u8')])       # packed: 31 bytes


class _ArrayMessageIndex(MessageIndex):
    """A chunk's message index for one channel from arrays (written in one piece: the
    library's per-entry loop would cost more than building the whole chunk)."""

    def __init__(self, channel_id: int, entries: np.ndarray) -> None:
        super().__init__(channel_id, [])
        self.entries = np.ascontiguousarray(entries, dtype='<u8')    # (n, 2): log time, offset

    def write(self, stream) -> None:
        body = self.entries.tobytes()
        stream.write(bytes([_OP_MESSAGE_INDEX]) + (6 + len(body)).to_bytes(8, 'little')
                     + int(self.channel_id).to_bytes(2, 'little')
                     + len(body).to_bytes(4, 'little') + body)


_CHUNK_HEAD = struct.Struct('<BQQQQIIQ')   # opcode, length, start, end, size, CRC, '', size
_CRC_BITS = 32


_BYTE_BITS = (np.arange(256)[:, None] >> np.arange(8)) & 1 == 1     # bit i of each byte value


def _byte_tables(op: tuple[int, ...]) -> tuple[tuple[int, ...], ...]:
    """A linear map of 32-bit vectors over GF(2), given by the images of the unit vectors, as
    four 256-entry tables, one per byte of the vector (apply: 4 lookups): entry v of table b
    is the XOR of the images of the bits set in v (numpy; a loop over the entries cost ~20 ms
    in the first chunk of every bag)."""
    ops = np.asarray(op, dtype=np.uint32).reshape(4, 1, 8)
    tables = np.bitwise_xor.reduce(np.where(_BYTE_BITS, ops, np.uint32(0)), axis=2)
    return tuple(tuple(t) for t in tables.tolist())


_ZERO_OPS: list[tuple[int, ...]] = []          # see _crc_zero_op
_ZERO_TABLES: list[tuple[tuple[int, ...], ...]] = []


def _crc_zero_op(k: int) -> tuple[tuple[int, ...], ...]:
    """The linear map c -> crc32(Z, c) ^ crc32(Z, 0) of 2**k zero bytes Z (zlib's CRC is affine
    in its start value; the linear part depends only on the length), as byte tables. One zero
    byte from zlib itself, each next by squaring; computed once, as far as needed."""
    while len(_ZERO_TABLES) <= k:
        if not _ZERO_OPS:
            base = zlib.crc32(b'\0')
            op = tuple(zlib.crc32(b'\0', 1 << i) ^ base for i in range(_CRC_BITS))
        else:
            t0, t1, t2, t3 = _ZERO_TABLES[-1]          # squared: the last map applied to itself
            op = tuple(t0[c & 255] ^ t1[c >> 8 & 255] ^ t2[c >> 16 & 255] ^ t3[c >> 24]
                       for c in _ZERO_OPS[-1])
        _ZERO_OPS.append(op)
        _ZERO_TABLES.append(_byte_tables(op))
    return _ZERO_TABLES[k]


def _crc_combine(crc_a: int, crc_b: int, length_b: int) -> int:
    """crc32(A + B) from crc32(A), crc32(B) and len(B), as zlib's crc32_combine (which Python's
    zlib does not offer): one pass over a chunk gives both its own CRC and the data section's
    (a few us against ~130 us for a second pass over a 270 KB chunk)."""
    k = 0
    while length_b:
        if length_b & 1:
            t0, t1, t2, t3 = _crc_zero_op(k)
            crc_a = (t0[crc_a & 255] ^ t1[crc_a >> 8 & 255] ^ t2[crc_a >> 16 & 255]
                     ^ t3[crc_a >> 24])
        length_b >>= 1
        k += 1
    return crc_a ^ crc_b


def _write_chunk(writer: Writer, state: WriterState, records: np.ndarray, t0: int, t1: int,
                 indexes: dict[int, MessageIndex]) -> bool:
    """Write an uncompressed chunk of ``records`` and its message indexes straight to the
    writer's stream, as ``Writer.flush`` would write it, keeping the writer's chunk index,
    statistics and data-section CRC (its private ``state``, :mod:`dmf_sim.bags.mcap_internals`);
    one CRC pass and no copy of the records in between (the library's chunk builder copies a
    chunk four times and checksums it twice). False (nothing written) while the writer holds
    records of its own not yet written."""
    if state.record_builder.count:
        return False
    stream = state.stream
    data = memoryview(records).cast('B')
    size = len(data)
    crc = zlib.crc32(data) if state.enable_crcs else 0
    head = _CHUNK_HEAD.pack(_OP_CHUNK, 40 + size, t0, t1, size, crc, 0, size)
    start = stream.tell()
    index_bytes = io.BytesIO()
    offsets = {}
    if state.index_types & IndexType.MESSAGE:
        for cid, index in indexes.items():
            offsets[cid] = start + len(head) + size + index_bytes.tell()
            index.write(index_bytes)
    tail = index_bytes.getvalue()
    if state.enable_data_crcs:
        dsc = zlib.crc32(head, state.data_section_crc)
        dsc = (_crc_combine(dsc, crc, size) if state.enable_crcs
               else zlib.crc32(data, dsc))
        set_data_section_crc(writer, zlib.crc32(tail, dsc))
    stream.write(head)
    stream.write(data)
    stream.write(tail)
    state.chunk_indices.append(ChunkIndex(
        message_start_time=t0, message_end_time=t1, chunk_start_offset=start,
        chunk_length=len(head) + size, message_index_offsets=offsets,
        message_index_length=len(tail), compression='', compressed_size=size,
        uncompressed_size=size))
    state.statistics.chunk_count += 1
    return True


def pack_records(raw, rec_at, heads, payload, offsets):
    """Message records into ``raw``: record i at ``rec_at[i]``, its head ``heads[i]`` then its
    data ``payload[offsets[i]:offsets[i + 1]]`` (compiled: thousands of small records)."""
    width = heads.shape[1]
    for i in range(rec_at.shape[0]):
        p = rec_at[i]
        raw[p:p + width] = heads[i]
        raw[p + width:p + width + offsets[i + 1] - offsets[i]] = payload[offsets[i]:offsets[i + 1]]


pack_records = jit(pack_records)


def _same_view(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether ``b`` is ``a`` (the same memory, shape and strides): nothing to copy."""
    return (a.shape == b.shape and a.strides == b.strides
            and a.__array_interface__['data'][0] == b.__array_interface__['data'][0])


def _block_layout(sizes: list[int]) -> np.dtype:
    """Packed record layout of one row of a block: per topic a message record (opcode,
    length, channel, sequence, log time, publish time, data)."""
    fields = []
    for j, size in enumerate(sizes):
        fields += [(f'op{j}', 'u1'), (f'len{j}', '<u8'), (f'cid{j}', '<u2'), (f'seq{j}', '<u4'),
                   (f'log{j}', '<u8'), (f'pub{j}', '<u8'), (f'data{j}', 'u1', (size,))]
    return np.dtype(fields)


def qos_profile(depth: int, *, reliable: bool = True, transient_local: bool = False,
                keep_all: bool = False) -> dict[str, Any]:
    """One offered QoS profile as rosbag2 Jazzy writes it (``offered_qos_profiles``, metadata
    version 9: policies as strings, durations as sec/nsec, unset ones infinite)."""
    return {'history': 'keep_all' if keep_all else 'keep_last', 'depth': int(depth),
            'reliability': 'reliable' if reliable else 'best_effort',
            'durability': 'transient_local' if transient_local else 'volatile',
            'deadline': dict(_INFINITE), 'lifespan': dict(_INFINITE),
            'liveliness': 'automatic', 'liveliness_lease_duration': dict(_INFINITE),
            'avoid_ros_namespace_conventions': False}


def _qos_profile(preset: str) -> dict[str, Any]:
    base = _QOS_PRESETS[preset]
    return {**qos_profile(base['depth']), **base}


def _qos_text(value: str | Mapping[str, Any] | None, topic: str) -> str:
    """Channel-metadata QoS text from a preset name, a profile mapping (missing policies as
    :func:`qos_profile` fills them) or a YAML list of profiles."""
    if value is None:
        value = 'reliable'
    if isinstance(value, Mapping):
        return yaml.safe_dump([{**qos_profile(10), **value}], sort_keys=False).strip()
    if value in _QOS_PRESETS:
        return yaml.safe_dump([_qos_profile(value)], sort_keys=False).strip()
    try:
        parsed = yaml.safe_load(value)
    except yaml.YAMLError:
        parsed = None
    if not isinstance(parsed, list) or not parsed:
        raise BagError(f'QoS for {topic!r} must be one of {sorted(_QOS_PRESETS)} or a YAML list '
                       f'of profiles, got {value!r}')
    return value.strip()


def latched_depth(profiles: list[dict[str, Any]]) -> int:
    """How many messages of a topic offered with ``profiles`` a late subscriber gets (0 when
    not transient-local; keep-all counts as 1 here, the latest)."""
    depths = [max(1, int(p.get('depth') or 1)) if p.get('history') != 'keep_all' else 1
              for p in profiles if p.get('durability') == 'transient_local']
    return max(depths, default=0)


def _schemas(topics: Mapping[str, str], msgdefs: Mapping[str, str]) -> dict[str, tuple[str, str]]:
    """Type name -> (ros2msg definition, RIHS01 hash) for every declared type."""
    from rosbags.typesys import Stores, get_typestore
    from rosbags.typesys.msg import get_types_from_msg

    store = get_typestore(Stores.ROS2_JAZZY)
    result: dict[str, tuple[str, str]] = {}
    for msgtype in dict.fromkeys(topics.values()):
        if msgtype in msgdefs:
            try:
                store.register(get_types_from_msg(msgdefs[msgtype], msgtype))
                result[msgtype] = (msgdefs[msgtype], store.hash_rihs01(msgtype))
            except Exception as exc:  # noqa: BLE001 - rosbags' parser errors vary by version
                raise BagError(f'msgdefs[{msgtype!r}] is not a valid ros2msg definition '
                               f'(with its dependencies): {type(exc).__name__} '
                               f'{" ".join(str(exc).split())}') from None
        elif msgtype in store.types:
            result[msgtype] = (store.generate_msgdef(msgtype, ros_version=2)[0],
                               store.hash_rihs01(msgtype))
        else:
            raise BagError(f'unknown message type {msgtype!r}; use the full name like '
                           '"sensor_msgs/msg/JointState" or pass its definition in msgdefs')
    return result


class BagRecorder:
    """Write pre-serialized CDR messages to a new rosbag2 MCAP bag directory.

    Args:
        path: Bag directory to create; it must not exist (or be an empty directory). Missing
            parents are created, as rosbag2 does, and listed in ``created_dirs`` (for the caller
            to log).
        topics: Topic name -> ROS type name, e.g. ``'sensor_msgs/msg/JointState'``.
        max_duration_s: Start a new file once the current one spans this much log time [s]
            (``ros2 bag record --max-bag-duration``), within ``MAX_DURATION_RANGE_S``.
        chunk_seconds: Close a chunk once it spans this much log time or wall time [s].
        chunk_bytes: Close a chunk once it holds this many bytes.
        qos: Topic -> offered QoS: ``'reliable'`` (default), ``'best_effort'``,
            ``'transient_local'``, a profile mapping (:func:`qos_profile`), or a YAML list of
            QoS profiles as rosbag2 writes them. Transient-local (latched) topics: the last
            ``depth`` messages are written again at the start of every split file (as rosbag2
            does), so each file holds the latched state; see :meth:`hold_latched`.
        msgdefs: Type name -> ros2msg definition text (with dependencies, rosbag2 style) for
            types not in the rosbags ROS 2 Jazzy type store.
        custom_data: Key/value strings stored in ``metadata.yaml`` (``custom_data``).
        compression: Chunk compression: ``'none'`` (rosbag2's default), ``'lz4'`` or ``'zstd'``.

    Use as a context manager or call :meth:`close`; see the module docstring for what a crash
    leaves. The wall-time chunk bound is checked on :meth:`write`; call :meth:`flush` from a
    timer if messages can pause. Methods are thread-safe.
    """

    def __init__(self, path: str | os.PathLike[str], topics: Mapping[str, str], *,
                 max_duration_s: float = DEFAULT_MAX_DURATION_S, chunk_seconds: float = 0.1,
                 chunk_bytes: int = 64 * 1024, qos: Mapping[str, Any] | None = None,
                 msgdefs: Mapping[str, str] | None = None,
                 custom_data: Mapping[str, str] | None = None,
                 compression: str = 'none') -> None:
        lo, hi = MAX_DURATION_RANGE_S
        if not (isinstance(max_duration_s, (int, float)) and math.isfinite(max_duration_s)
                and lo <= max_duration_s <= hi):
            raise BagError(f'max_duration_s must be within [{lo:g}, {hi:g}] s, '
                           f'got {max_duration_s!r}')
        if not (math.isfinite(chunk_seconds) and chunk_seconds > 0):
            raise BagError(f'chunk_seconds must be positive, got {chunk_seconds!r}')
        if chunk_bytes < 1:
            raise BagError(f'chunk_bytes must be positive, got {chunk_bytes!r}')
        if compression not in _COMPRESSION:
            raise BagError(f'compression must be one of {sorted(_COMPRESSION)}, '
                           f'got {compression!r}')
        qos = dict(qos or {})
        if unknown := set(qos) - set(topics):
            raise BagError(f'QoS given for undeclared topics {sorted(unknown)}')
        self.path = Path(path)
        schemas = _schemas(topics, msgdefs or {})
        self._infos: list[TopicInfo] = []
        for topic, msgtype in topics.items():
            if not topic.startswith('/'):
                raise BagError(f'topic names must be absolute (start with "/"), got {topic!r}')
            self._infos.append(TopicInfo(topic, msgtype, _qos_text(qos.get(topic), topic),
                                         schemas[msgtype][1]))
        self._schema_texts = {name: text for name, (text, _) in schemas.items()}
        #: latched topic -> its last messages (log time, bytes), repeated in every new file
        self._latched: dict[str, deque] = {
            info.name: deque(maxlen=n) for info in self._infos
            if (n := latched_depth(info.qos_profiles))}
        self._repeat_due = False
        self._custom_data = dict(custom_data or {})
        self._compression = _COMPRESSION[compression]
        self._max_duration_ns = int(max_duration_s * 1e9)
        self._chunk_ns = int(chunk_seconds * 1e9)
        self._chunk_seconds = float(chunk_seconds)
        self._chunk_bytes = int(chunk_bytes)

        refuse_existing(self.path)          # an empty directory is taken
        #: parent directories that did not exist and were created (rosbag2 does the same)
        self.created_dirs = [p for p in reversed(self.path.parents) if not p.exists()]
        try:
            self.path.mkdir(parents=True, exist_ok=self.path.is_dir())
        except FileExistsError:
            raise BagExistsError(f'{self.path} exists already, not overwriting') from None
        self.message_count = 0
        self.closed_files: list[FileInfo] = []   # finished splits, in order
        self._next_index = 0
        self._finisher: threading.Thread | None = None
        self._finisher_error: BaseException | None = None
        self._closed = False
        self._lock = threading.Lock()
        self._write_metadata()          # provisional: topics and custom_data, no file yet
        self._open_file()

    # ---- files -------------------------------------------------------------------------------
    def _open_file(self) -> None:
        self._file = FileInfo(f'{self.path.name}_{self._next_index}.mcap')
        self._next_index += 1
        self._stream = (self.path / self._file.path).open('xb')
        self._writer = Writer(self._stream, chunk_size=2**62, compression=self._compression,
                              enable_data_crcs=True)   # chunk CRCs are on by default
        self._writer.start(profile='ros2', library=LIBRARY)
        ids = {name: self._writer.register_schema(name, 'ros2msg', text.encode())
               for name, text in self._schema_texts.items()}
        self._channels: dict[str, tuple[int, TopicInfo]] = {}
        for info in self._infos:
            cid = self._writer.register_channel(
                info.name, 'cdr', ids[info.msgtype],
                {'offered_qos_profiles': info.qos, 'topic_type_hash': info.type_hash})
            self._channels[info.name] = (cid, info)
        self._stream.flush()
        self._pending = 0
        self._pending_bytes = 0
        self._chunk_t0 = 0
        self._chunk_wall0 = 0.0
        self._repeat_due = any(self._latched.values())

    def _finish(self, writer: Writer, stream, file: FileInfo) -> None:
        """Write a file's summary and footer, close it, list it in ``metadata.yaml``."""
        info = self._metadata([*self.closed_files, file])['rosbag2_bagfile_information']
        writer.add_metadata('rosbag2', {'serialized_metadata': dump_metadata(info),
                                        'ROS_DISTRO': ROS_DISTRO})
        writer.finish()
        stream.close()
        self.closed_files.append(file)
        self._write_metadata()

    def _finish_in_background(self, writer: Writer, stream, file: FileInfo) -> None:
        def run() -> None:
            try:
                self._finish(writer, stream, file)
            except BaseException as exc:  # noqa: BLE001 - reported by the next write/close
                self._finisher_error = exc

        self._finisher = threading.Thread(target=run, name=f'bag split {file.path}', daemon=True)
        self._finisher.start()

    def _join_finisher(self) -> None:
        """Wait for the previous split to be finished; re-raise what it failed with."""
        if self._finisher is not None:
            self._finisher.join()
            self._finisher = None
        if self._finisher_error is not None:
            exc, self._finisher_error = self._finisher_error, None
            raise exc

    def _split(self) -> None:
        """Start the next file; the full one is finished by a helper thread, so the writing
        thread (the node's tick) does not wait for its summary and metadata. The previous one
        is finished first (long since, at any real-time rate), so at most two files are ever
        unlisted: the one being finished and the one being written."""
        self._join_finisher()
        self._flush()
        old = (self._writer, self._stream, self._file)
        self._open_file()
        self._finish_in_background(*old)

    def _metadata(self, files: list[FileInfo]) -> dict[str, Any]:
        return bag_metadata(self._infos, files, custom_data=self._custom_data)

    def _write_metadata(self) -> None:
        write_metadata(self.path, self._metadata(self.closed_files))

    # ---- writing -----------------------------------------------------------------------------
    def write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        """Append one CDR-serialized message with log (receive) time ``timestamp_ns``."""
        with self._lock:
            self._write(topic, timestamp_ns, data)

    def _write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        if self._closed:
            raise BagError(f'bag {self.path} is closed')
        try:
            cid, info = self._channels[topic]
        except KeyError:
            raise BagError(f'topic {topic!r} was not declared when the bag was opened') from None
        if timestamp_ns < 0:
            raise BagError(f'timestamp must be non-negative, got {timestamp_ns}')
        if self._finisher_error is not None:
            self._join_finisher()
        f = self._file
        if f.count and timestamp_ns - f.start >= self._max_duration_ns:
            self._split()
        if self._repeat_due:
            self._repeat_latched(timestamp_ns, skip=topic)
        self._add(cid, info, timestamp_ns, timestamp_ns, data)
        if (held := self._latched.get(topic)) is not None:
            held.append((timestamp_ns, bytes(data)))

    def _add(self, cid: int, info: TopicInfo, log_ns: int, publish_ns: int, data: bytes) -> None:
        f = self._file
        self._writer.add_message(cid, log_ns, data, publish_ns, info.count & 0xFFFFFFFF)
        info.count += 1
        self.message_count += 1
        f.add(info.name, log_ns)

        now = time.monotonic()
        if self._pending == 0:
            self._chunk_t0, self._chunk_wall0 = log_ns, now
        self._pending += 1
        self._pending_bytes += len(data) + _MESSAGE_OVERHEAD
        if (self._pending_bytes >= self._chunk_bytes
                or abs(log_ns - self._chunk_t0) >= self._chunk_ns
                or now - self._chunk_wall0 >= self._chunk_seconds):
            self._flush()

    def file_end_ns(self, first_ns: int) -> int:
        """The log time from which messages go to the next file: the current file's start +
        ``max_duration_s`` (its start is ``first_ns`` when nothing is in it yet). A writer of
        several calls per time span (``dmf-sim run``: the samples, then the sensors) writes each
        call's messages before it first, so every file holds its own span."""
        with self._lock:
            f = self._file
            return (f.start if f.count else int(first_ns)) + self._max_duration_ns

    def write_block(self, log_ns: np.ndarray, payloads: list[tuple[str, np.ndarray]]) -> None:
        """Append rows of fixed-size messages at once: row i holds one message per
        (topic, payload) pair, in that order, all logged (and published) at ``log_ns[i]``;
        ``payload`` is a (rows, size) uint8 array of CDR messages. The file gets exactly what
        :meth:`write` called per message in that order would give it (same records, sequence
        numbers, indexes, splits, metadata), as one chunk per call and file, built with numpy
        (``dmf-sim run`` writes ~4000 messages per simulated second)."""
        log_ns = np.asarray(log_ns, dtype=np.int64)
        rows = len(log_ns)
        for topic, data in payloads:
            if data.ndim != 2 or data.shape[0] != rows or data.dtype != np.uint8:
                raise BagError(f'write_block: payload of {topic!r} must be a ({rows}, size) '
                               f'uint8 array, got {data.dtype} {data.shape}')
        if rows and (log_ns[0] < 0 or (np.diff(log_ns) < 0).any()):
            raise BagError('write_block: log times must be non-negative and non-decreasing')
        with self._lock:
            start = 0
            while start < rows:
                start += self._write_rows(log_ns[start:], [(t, d[start:]) for t, d in payloads])

    def _write_rows(self, log_ns: np.ndarray, payloads: list[tuple[str, np.ndarray]]) -> int:
        """Write the rows that belong to the current file (a split starts the next one as
        :meth:`_write` does); returns how many were written."""
        f, rows = self._file_for(log_ns)
        t = log_ns[:rows]
        chans = []
        for topic, data in payloads:
            if topic not in self._channels:
                raise BagError(f'topic {topic!r} was not declared when the bag was opened')
            cid, info = self._channels[topic]
            chans.append((cid, info, data[:rows]))
        writer = self._writer
        state = writer_state(writer)
        if state is None:                         # another mcap version: message by message
            for i in range(rows):
                for cid, info, data in chans:
                    self._write(info.name, int(t[i]), data[i].tobytes())
            return rows
        self._flush_chunk()                       # what write() left open goes first
        stats = state.statistics
        block = self._block_buffer(tuple((cid, d.shape[1]) for cid, _, d in chans), rows)
        layout = block.dtype
        raw = block.view(np.uint8).reshape(rows, layout.itemsize)
        row_offsets = np.arange(rows, dtype=np.int64) * layout.itemsize
        index = np.empty((len(chans), rows, 2), dtype='<u8')
        for j, (cid, info, data) in enumerate(chans):
            block[f'seq{j}'] = (info.count + np.arange(rows, dtype=np.int64)) & 0xFFFFFFFF
            block[f'log{j}'] = t
            block[f'pub{j}'] = t
            field = block[f'data{j}']
            if not _same_view(field, data):       # not encoded in place (block_payloads)
                field[...] = data
            index[j, :, 0] = t
            index[j, :, 1] = row_offsets + layout.fields[f'op{j}'][1]
            info.count += rows
            stats.channel_message_counts[cid] += rows
            f.topic_counts[info.name] = f.topic_counts.get(info.name, 0) + rows
        indexes = {cid: _ArrayMessageIndex(cid, index[j]) for j, (cid, _, _) in enumerate(chans)}
        self._commit_chunk(f, raw, t, rows * len(chans), indexes)
        return rows

    def _file_for(self, log_ns: np.ndarray) -> tuple[FileInfo, int]:
        """The file the messages from ``log_ns[0]`` on go to (split first, or the latched
        messages first in a new file, as :meth:`_write` does) and how many belong in it."""
        if self._closed:
            raise BagError(f'bag {self.path} is closed')
        if self._finisher_error is not None:
            self._join_finisher()
        if self._file.count and int(log_ns[0]) - self._file.start >= self._max_duration_ns:
            self._split()
        if self._repeat_due:                      # a new file starts with the latched messages
            self._repeat_latched(int(log_ns[0]), skip='')
        f = self._file
        first = f.start if f.count else int(log_ns[0])
        return f, max(int(np.searchsorted(log_ns, first + self._max_duration_ns, side='left')), 1)

    def _commit_chunk(self, f: FileInfo, raw: np.ndarray, t: np.ndarray, n: int,
                      indexes: dict[int, MessageIndex]) -> None:
        """Write the records ``raw`` of ``n`` messages logged at ``t`` as one chunk with its
        message ``indexes``: the writer's statistics, the file's span and counts, to the OS."""
        writer = self._writer
        state = writer_state(writer)                # after the flush: its data-section CRC
        builder, stats = state.chunk_builder, state.statistics
        t0, t1 = int(t[0]), int(t[-1])
        stats.message_start_time = (t0 if stats.message_count == 0
                                    else min(t0, stats.message_start_time))
        stats.message_end_time = max(t1, stats.message_end_time)
        stats.message_count += n
        if not (builder.count == 0 and self._compression == CompressionType.NONE
                and _write_chunk(writer, state, raw, t0, t1, indexes)):
            builder.record_writer.write(raw.data)   # after the file's schemas and channels
            builder.num_messages = n
            builder.message_start_time, builder.message_end_time = t0, t1
            builder.message_indices = indexes
        if f.count == 0:
            f.start = f.end = t0
        f.start, f.end = min(f.start, t0), max(f.end, t1)
        f.count += n
        self.message_count += n
        writer.flush()                            # the chunk, its indexes, to the OS

    def write_messages(self, log_ns: np.ndarray, topic_index: np.ndarray, topics: list[str],
                       payload: np.ndarray, offsets: np.ndarray) -> None:
        """Append messages of any sizes at once: message i on ``topics[topic_index[i]]``,
        logged (and published) at ``log_ns[i]`` (non-decreasing), its CDR bytes
        ``payload[offsets[i]:offsets[i + 1]]`` (uint8). The file gets exactly what :meth:`write`
        called per message in that order would give it (records, sequence numbers, indexes,
        splits, metadata), as one chunk per call and file, built with numpy (``dmf-sim run``
        writes thousands of sensor messages per simulated second)."""
        log_ns = np.asarray(log_ns, dtype=np.int64)
        topic_index = np.asarray(topic_index, dtype=np.int64)
        offsets = np.asarray(offsets, dtype=np.int64)
        n = len(log_ns)
        if topic_index.shape != (n,) or offsets.shape != (n + 1,) or payload.dtype != np.uint8:
            raise BagError(f'write_messages: {n} log times need {n} topic indexes and {n + 1} '
                           'offsets into a uint8 payload')
        if n and (log_ns[0] < 0 or (np.diff(log_ns) < 0).any()):
            raise BagError('write_messages: log times must be non-negative and non-decreasing')
        if n and (topic_index.min() < 0 or topic_index.max() >= len(topics)):
            raise BagError('write_messages: a topic index outside the topics given')
        with self._lock:
            start = 0
            while start < n:
                start += self._write_sized(log_ns[start:], topic_index[start:], topics,
                                           payload, offsets[start:])

    def _write_sized(self, log_ns: np.ndarray, topic_index: np.ndarray, topics: list[str],
                     payload: np.ndarray, offsets: np.ndarray) -> int:
        """:meth:`write_messages` of the messages that belong to the current file (as
        :meth:`_write_rows` does for fixed sizes); returns how many were written."""
        f, n = self._file_for(log_ns)
        t, idx = log_ns[:n], topic_index[:n]
        chans = []
        for topic in topics:
            if topic not in self._channels:
                raise BagError(f'topic {topic!r} was not declared when the bag was opened')
            chans.append(self._channels[topic])
        state = writer_state(self._writer)
        if state is None:                         # another mcap version: message by message
            for i in range(n):
                self._write(chans[idx[i]][1].name, int(t[i]),
                            payload[offsets[i]:offsets[i + 1]].tobytes())
            return n
        self._flush_chunk()                       # what write() left open goes first
        stats = state.statistics
        sizes = offsets[1:n + 1] - offsets[:n]
        rec_len = _MESSAGE_RECORD_HEAD + sizes
        rec_at = np.zeros(n, np.int64)
        np.cumsum(rec_len[:-1], out=rec_at[1:])
        raw = np.empty(int(rec_at[-1] + rec_len[-1]), np.uint8)
        head = np.zeros(n, _RECORD_HEAD)
        head['op'] = _OP_MESSAGE
        head['len'] = _MESSAGE_HEAD + sizes
        head['log'] = t
        head['pub'] = t
        indexes = {}
        for j, (cid, info) in enumerate(chans):
            mine = np.flatnonzero(idx == j)
            if not len(mine):
                continue
            head['cid'][mine] = cid
            head['seq'][mine] = (info.count + np.arange(len(mine), dtype=np.int64)) & 0xFFFFFFFF
            entries = np.empty((len(mine), 2), dtype='<u8')
            entries[:, 0] = t[mine]
            entries[:, 1] = rec_at[mine]
            indexes[cid] = _ArrayMessageIndex(cid, entries)
            info.count += len(mine)
            stats.channel_message_counts[cid] += len(mine)
            f.topic_counts[info.name] = f.topic_counts.get(info.name, 0) + len(mine)
        pack_records(raw, rec_at, head.view(np.uint8).reshape(n, _MESSAGE_RECORD_HEAD),
                      payload, offsets[:n + 1])
        self._commit_chunk(f, raw, t, n, indexes)
        return n

    def block_payloads(self, topics: list[str], sizes: list[int], rows: int
                       ) -> list[np.ndarray]:
        """Where :meth:`write_block` puts the payloads of ``rows`` rows of messages of
        ``topics`` (in that order) with these sizes: (rows, size) uint8 views into the records
        it writes. Payloads encoded into them (the first rows of each, in the same order) are
        written without a copy; the views stay valid while the layout and the row count do
        (a caller encoding into them keeps their bytes between calls only if it rewrites them)."""
        with self._lock:
            channels = tuple((self._channels[t][0], int(n)) for t, n in zip(topics, sizes))
            block = self._block_buffer(channels, rows)
            return [block[f'data{j}'] for j in range(len(channels))]

    def _block_buffer(self, channels: tuple[tuple[int, int], ...], rows: int) -> np.ndarray:
        """``rows`` records of (channel id, payload size) with their constant bytes (opcodes,
        lengths, channel ids) in place: a buffer kept per layout and reused (the caller fills
        every other field of every row, and the bytes are written or copied before the next
        call), so a block costs no allocation and no template copy."""
        cache = self.__dict__.setdefault('_blocks', {})
        buf = cache.get(channels)
        if buf is None or len(buf) < rows:
            layout = _block_layout([size for _, size in channels])
            buf = np.zeros(max(rows, len(buf) if buf is not None else 0), layout)
            for j, (cid, size) in enumerate(channels):
                buf[f'op{j}'] = _OP_MESSAGE
                buf[f'len{j}'] = _MESSAGE_HEAD + size
                buf[f'cid{j}'] = cid
            cache[channels] = buf
        return buf[:rows]

    def _repeat_latched(self, log_ns: int, skip: str) -> None:
        """Write the held latched messages at the start of a file, logged at ``log_ns`` (the
        file's first log time; their original log time is kept as publish time). ``skip``:
        the topic whose newer message is being written now (it supersedes the held ones)."""
        self._repeat_due = False
        for topic, held in self._latched.items():
            if topic == skip:
                continue
            cid, info = self._channels[topic]
            for original_ns, data in held:
                self._add(cid, info, log_ns, original_ns, data)

    def hold_latched(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        """Remember a latched message published before this recording started (the recording
        starts with it, as a late transient-local subscriber would receive it)."""
        with self._lock:
            if (held := self._latched.get(topic)) is None:
                raise BagError(f'topic {topic!r} is not a declared transient-local topic')
            held.append((int(timestamp_ns), bytes(data)))
            if not self._closed and self._file.count == 0:
                self._repeat_due = True         # before the first message of the recording

    def flush(self) -> None:
        """Close the open chunk (if any) and hand everything written so far to the OS.

        Called automatically by :meth:`write`; call it from a timer when messages may pause.
        """
        with self._lock:
            self._flush()

    def _flush(self) -> None:
        if not self._closed:
            self._flush_chunk()

    def _flush_chunk(self) -> None:
        if self._pending == 0:
            return
        self._writer.flush()  # finalizes the chunk + message indexes, flushes the stream
        self._pending = 0
        self._pending_bytes = 0

    def close(self) -> None:
        """Finish the last file (summary, index) and write the final ``metadata.yaml``.
        Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._flush_chunk()
            try:
                self._join_finisher()
            finally:
                self._finish(self._writer, self._stream, self._file)

    # ---- state -------------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        """Whether :meth:`close` has run."""
        return self._closed

    @property
    def files(self) -> list[Path]:
        """The bag's MCAP files so far (finished splits, then the open one)."""
        return [self.path / f'{self.path.name}_{i}.mcap' for i in range(self._next_index)]

    def __enter__(self) -> BagRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f'BagRecorder({str(self.path)!r}, messages={self.message_count}, '
                f'files={len(self.files)})')
