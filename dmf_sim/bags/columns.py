"""Fast reading of numeric columns from MCAP files, chunk by chunk (the bag analysis' reader).

The message reader (:mod:`dmf_sim.bags.read`, ``reader='messages'``) builds a Python object per
record and decodes every wanted message with ``rosbags`` -- fine for a few thousand messages,
slow for a bag of millions (``benchmarks/bench_analyze.py`` measures both). This reader keeps
the library's framing and decompression and replaces only the per-message work with array
operations:

1. **Framing**: the top-level records come from the record scanner
   (:mod:`dmf_sim.bags.records`: chunks whole and checked against their CRCs, message indexes
   skipped), so truncated files stop cleanly at their last complete record, as there, and a
   corrupt chunk is skipped and reported (:attr:`McapColumns.scan`).
2. **Chunks**, decompressed and checked by the scanner, are walked by a small jitted loop that
   lists the record offsets (no message index needed, so a chunk a crash cut off from its
   indexes reads the same); message fields (channel, log/publish time, data span) are gathered
   with numpy.
3. **Values**: ``std_msgs/Float64`` comes straight from the CDR bytes (both byte orders).
   ``sensor_msgs/JointState`` columns use the byte layout of the first message, checked against
   ``rosbags``' decoding of it; each message whose fixed bytes (frame id, names, array lengths)
   differ from that layout is decoded with ``rosbags``. Any other type: ``rosbags`` per message.

Memory: a batch of decompressed chunks (about 1 MiB) at a time plus the kept columns; the file
is read, not mapped.
"""
from __future__ import annotations

import io
import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.records import Channel, DataEnd, Footer, Message, Schema

from dmf_sim.bags.read import TypeDecoder
from dmf_sim.bags.records import (
    RECORD_HEAD,
    CheckedChunk,
    Scan,
    iter_records,
    normalize_type,
    record_offsets,
)
from dmf_sim.core.errors import BagError

__all__ = ['FLOAT64', 'JOINT_STATE', 'joint_state_layout', 'Column', 'ScalarColumn',
           'JointStateColumns', 'McapColumns',
           'ColumnFactory']

FLOAT64 = 'std_msgs/msg/Float64'
JOINT_STATE = 'sensor_msgs/msg/JointState'
_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE = 3, 4, 5
_RECORD_HEAD = RECORD_HEAD
_record_offsets = record_offsets   # (the benchmark times it by this name)
_LOG_TIME, _PUBLISH_TIME = 15, 23   # message record offsets: head 9, channel 2, sequence 4
_MSG_DATA = 31            # message data after log and publish time
_LOOSE_BATCH = 4096       # unchunked messages gathered per batch
_CHUNK_BATCH_BYTES = 1 << 20   # decompressed chunks gathered per batch (the recorder's chunks
                               # are small for crash tolerance: numpy's per-call cost would
                               # dominate chunk by chunk)
_ARANGE8 = np.arange(8)


def _u64(buf: np.ndarray, pos: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(buf[pos[:, None] + _ARANGE8]).view('<u8').ravel()


# --------------------------------------------------------------------------------- columns

class Column:
    """Turns the messages of one channel into rows of ``width`` float values."""

    width = 1

    def __init__(self, decoder: TypeDecoder, msgtype: str) -> None:
        self.decoder = decoder
        self.msgtype = msgtype

    def row(self, msg: Any) -> list[float]:  # pragma: no cover - interface
        """The values of one decoded message."""
        raise NotImplementedError

    def rows(self, buf: np.ndarray, start: np.ndarray, length: np.ndarray) -> np.ndarray:
        """Values of the messages whose CDR bytes are ``buf[start:start + length]``."""
        out = np.full((len(start), self.width), np.nan)
        self._decode_rows(buf, start, length, out, np.arange(len(start)))
        return out

    def _decode_rows(self, buf: np.ndarray, start: np.ndarray, length: np.ndarray,
                     out: np.ndarray, which: np.ndarray) -> None:
        for r in which:
            s, n = int(start[r]), int(length[r])
            out[r] = self.row(self.decoder.decode(buf[s:s + n].tobytes(), self.msgtype))


class ScalarColumn(Column):
    """The ``data`` field of a scalar message; std_msgs/Float64 straight from the CDR bytes
    (once the first message read so agrees with ``rosbags``' decoding of it)."""

    checked: bool | None = None     # None: not yet compared with rosbags; False: disagreed

    def row(self, msg: Any) -> list[float]:
        try:
            return [float(msg.data)]
        except (AttributeError, TypeError, ValueError):
            raise BagError(f'messages of type {self.msgtype} have no numeric field "data"'
                           ) from None

    def rows(self, buf, start, length):
        out = np.full((len(start), 1), np.nan)
        if self.msgtype != FLOAT64 or not len(start) or self.checked is False:
            self._decode_rows(buf, start, length, out, np.arange(len(start)))
            return out
        # CDR: representation id 0x0000 (big endian) or 0x0001 (little), 2 option bytes, float64
        ok = (length >= 12) & (buf[start] == 0) & (buf[start + 1] <= 1)
        le = ok & (buf[start + 1] == 1)
        be = ok & ~le
        raw = np.ascontiguousarray(buf[(start + 4)[:, None] + _ARANGE8])
        if le.any():
            out[le, 0] = raw[le].view('<f8').ravel()
        if be.any():
            out[be, 0] = raw[be].view('>f8').ravel()
        self._decode_rows(buf, start, length, out, np.flatnonzero(~ok))
        if self.checked is None:
            s, n = int(start[0]), int(length[0])
            ref = self.row(self.decoder.decode(buf[s:s + n].tobytes(), self.msgtype))[0]
            self.checked = bool(np.array_equal(out[0, 0], ref, equal_nan=True))
            if not self.checked:
                return self.rows(buf, start, length)
        return out


class _Unsupported(Exception):
    """A JointState message whose bytes the layout reader does not handle."""


def joint_state_layout(data: bytes) -> tuple[str, list[str], dict[str, tuple[int, int]], int,
                                         np.ndarray]:
    """Byte layout of one sensor_msgs/JointState CDR message (XCDR1, plain): byte order, names,
    field -> (offset of its first float64, count), total length, and the byte positions that
    carry the representation id, frame id, names and array lengths (alignment padding excluded:
    serializers need not zero it)."""
    if len(data) < 4 or data[0] != 0 or data[1] > 1:
        raise _Unsupported('not plain CDR')
    end = '<' if data[1] == 1 else '>'
    key: list[range] = [range(0, 2)]

    def align(p: int, a: int) -> int:
        return 4 + (p - 4 + a - 1) // a * a

    def u32(p: int) -> int:
        return struct.unpack_from(end + 'I', data, p)[0]

    p = 4 + 8                                    # header.stamp: int32 sec, uint32 nanosec
    n = u32(p)
    key.append(range(p, p + 4 + n))              # header.frame_id
    p = align(p + 4 + n, 4)
    names = []
    count = u32(p)
    key.append(range(p, p + 4))
    p += 4
    for _ in range(count):
        p = align(p, 4)
        n = u32(p)
        key.append(range(p, p + 4 + n))
        names.append(bytes(data[p + 4:p + 4 + n]).rstrip(b'\0').decode())
        p += 4 + n
    arrays = {}
    for fld in ('position', 'velocity', 'effort'):
        p = align(p, 4)
        n = u32(p)
        key.append(range(p, p + 4))
        p += 4
        if n:
            p = align(p, 8)
        arrays[fld] = (p, n)
        p += 8 * n
    cols = np.unique(np.concatenate([np.arange(r.start, r.stop) for r in key]))
    return end, names, arrays, p, cols


def match_element(wanted: str, names: Sequence[str]) -> int:
    """Index of element ``wanted`` in ``names``: exact, else case-insensitive with '_' == ' '."""
    if wanted in names:
        return list(names).index(wanted)
    key = wanted.replace('_', ' ').strip().lower()
    hits = [i for i, n in enumerate(names) if n.replace('_', ' ').strip().lower() == key]
    if len(hits) == 1:
        return hits[0]
    raise BagError(f'element {wanted!r} is not in the joint states; names are: '
                   f'{", ".join(names)}')


class JointStateColumns(Column):
    """Columns (field, element name) of sensor_msgs/JointState (see the module docstring)."""

    def __init__(self, decoder: TypeDecoder, msgtype: str,
                 columns: Sequence[tuple[str, str]]) -> None:
        super().__init__(decoder, msgtype)
        self.columns = list(columns)
        self.width = len(self.columns)
        self.names: list[str] | None = None
        self.layout: tuple | bool | None = None   # None: not learnt yet; False: none usable

    def row(self, msg: Any) -> list[float]:
        names = list(msg.name)
        if self.names is None:
            self.names = names
        out = []
        for fld, el in self.columns:
            i = match_element(el, names)
            arr = getattr(msg, fld)
            if len(arr) <= i:
                raise BagError(f'joint states carry no {fld!r} for element {el!r} '
                               f'({len(arr)} values for {len(names)} names)')
            out.append(float(arr[i]))
        return out

    def _learn(self, data: bytes) -> None:
        msg = self.decoder.decode(data, self.msgtype)
        self.row(msg)                                  # names, and errors for bad requests
        self.layout = False
        try:
            end, names, arrays, total, cols = joint_state_layout(data)
        except (_Unsupported, struct.error, UnicodeDecodeError):
            return
        if names != list(msg.name) or total > len(data) or cols.max() >= len(data):
            return
        for fld, (off, n) in arrays.items():
            got = np.frombuffer(data, end + 'f8', count=n, offset=off) if n else np.zeros(0)
            if not np.array_equal(got, np.asarray(getattr(msg, fld), dtype=float),
                                  equal_nan=True):
                return
        idx = [match_element(el, names) for _, el in self.columns]
        if any(i >= arrays[fld][1] for (fld, _), i in zip(self.columns, idx)):
            return
        offsets = np.array([arrays[fld][0] + 8 * i for (fld, _), i in zip(self.columns, idx)])
        key = np.frombuffer(data, np.uint8)[cols].copy()
        self.layout = (np.dtype(end + 'f8'), key, cols, offsets, len(data))

    def rows(self, buf, start, length):
        n = len(start)
        out = np.full((n, self.width), np.nan)
        if n == 0:
            return out
        if self.layout is None:
            s, k = int(start[0]), int(length[0])
            self._learn(buf[s:s + k].tobytes())
        if not self.layout:
            self._decode_rows(buf, start, length, out, np.arange(n))
            return out
        dtype, key, cols, offsets, size = self.layout
        ok = length == size
        ok[ok] = np.all(buf[start[ok, None] + cols] == key, axis=1)
        good = np.flatnonzero(ok)
        if len(good):
            raw = np.ascontiguousarray(buf[(start[good, None] + offsets)[:, :, None] + _ARANGE8])
            out[good] = raw.view(dtype).reshape(len(good), self.width)
        self._decode_rows(buf, start, length, out, np.flatnonzero(~ok))
        return out


ColumnFactory = Callable[[TypeDecoder, str], Column]


# ---------------------------------------------------------------------------------- reading

@dataclass
class McapColumns:
    """Columns of chosen topics of one MCAP file.

    Args:
        file: the MCAP file.
        requests: topic -> factory(decoder, ROS type) of its Column.
        decoder: shared type decoder (several files of one bag).
        stamp: 'log' (receive time) or 'publish' time of each message.
        progress: callable(bytes read) for a progress bar.
        sink: callable(topic, times, values) that takes each batch as it is gathered (a reader
            that must not hold the whole file, e.g. ``dmf-sim durability``); ``columns`` then
            stays empty.

    After :meth:`read`: ``columns`` topic -> list of (times [ns] int64, values (k, width)) in
    file order, ``topics`` topic -> type of every channel, ``truncated`` / ``error``, ``scan``
    (how far the file was valid; its corrupt chunks, skipped, with the topics they held) and
    ``undeclared`` (messages on channels declared only in a corrupt chunk: unreadable).
    """

    file: Path
    requests: Mapping[str, ColumnFactory] = field(default_factory=dict)
    decoder: TypeDecoder = field(default_factory=TypeDecoder)
    stamp: str = 'log'
    progress: Callable[[int], Any] | None = None
    sink: Callable[[str, np.ndarray, np.ndarray], Any] | None = None
    columns: dict[str, list[tuple[np.ndarray, np.ndarray]]] = field(default_factory=dict)
    topics: dict[str, str] = field(default_factory=dict)
    truncated: bool = False
    error: str = ''
    scan: Scan = field(default_factory=Scan)
    undeclared: int = 0

    def __post_init__(self) -> None:
        if self.stamp not in ('log', 'publish'):
            raise BagError(f"stamp={self.stamp!r}: allowed 'log', 'publish'")
        self._stamp_at = _LOG_TIME if self.stamp == 'log' else _PUBLISH_TIME
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, tuple[str, Column | None]] = {}
        self._loose: list[Message] = []
        self._pending: list[bytes] = []        # decompressed chunks not gathered yet
        self._pending_bytes = 0

    # ---- records -----------------------------------------------------------------------------
    def _channel(self, channel: Channel) -> None:
        if channel.id in self._channels:
            return
        schema = self._schemas.get(channel.schema_id)
        msgtype = normalize_type(schema.name) if schema is not None else ''
        self.topics.setdefault(channel.topic, msgtype)
        factory = self.requests.get(channel.topic)
        column = None
        if factory is not None:
            if channel.message_encoding != 'cdr':
                raise BagError(f'{self.file}: topic {channel.topic!r} has message encoding '
                               f'{channel.message_encoding!r}; only cdr is supported')
            if not msgtype:
                raise BagError(f'{self.file}: topic {channel.topic!r} has no schema; its type '
                               'is unknown')
            self.decoder.add_schema(schema, msgtype)
            column = factory(self.decoder, msgtype)
        self._channels[channel.id] = (channel.topic, column)

    def _record(self, record: Any) -> None:
        if isinstance(record, Schema):
            self._schemas[record.id] = record
        elif isinstance(record, Channel):
            self._channel(record)

    def _column(self, cid: int) -> Column | None:
        try:
            return self._channels[cid][1]
        except KeyError:
            if self.scan.corrupt:          # declared in a chunk that was skipped
                return None
            raise BagError(f'{self.file}: message on undeclared channel {cid}') from None

    def _gather(self, buf: np.ndarray, cids: np.ndarray, times: np.ndarray, start: np.ndarray,
                length: np.ndarray) -> None:
        for cid in np.unique(cids):
            column = self._column(int(cid))
            if column is None:
                if int(cid) not in self._channels:
                    self.undeclared += int(np.count_nonzero(cids == cid))
                continue
            sel = np.flatnonzero(cids == cid)
            values = column.rows(buf, start[sel], length[sel])
            topic = self._channels[int(cid)][0]
            if self.sink is not None:
                self.sink(topic, times[sel].astype(np.int64), values)
            else:
                self.columns.setdefault(topic, []).append((times[sel].astype(np.int64), values))

    # ---- chunks ------------------------------------------------------------------------------
    def _chunk(self, chunk: CheckedChunk) -> None:
        """Add one checked chunk's records to the pending batch (see :meth:`_flush_chunks`)."""
        self._pending.append(chunk.data)
        self._pending_bytes += len(chunk.data)
        if self._pending_bytes >= _CHUNK_BATCH_BYTES:
            self._flush_chunks()

    def _flush_chunks(self) -> None:
        """Gather the pending chunks at once: a chunk's records are a complete record sequence,
        so chunks read back to back are one."""
        if not self._pending:
            return
        buf = np.frombuffer(b''.join(self._pending), np.uint8)
        self._pending, self._pending_bytes = [], 0
        offs = _record_offsets(buf)
        ops = buf[offs]
        lengths = _u64(buf, offs + 1).astype(np.int64)
        for i in np.flatnonzero((ops == _OP_SCHEMA) | (ops == _OP_CHANNEL)):
            body = ReadDataStream(io.BytesIO(buf[offs[i] + _RECORD_HEAD:
                                                 offs[i] + _RECORD_HEAD + lengths[i]].tobytes()))
            self._record(Schema.read(body) if ops[i] == _OP_SCHEMA else Channel.read(body))
        msg = ops == _OP_MESSAGE
        m_offs, m_len = offs[msg], lengths[msg]
        if not len(m_offs):
            return
        cids = buf[m_offs + _RECORD_HEAD].astype(np.int64) \
            | (buf[m_offs + _RECORD_HEAD + 1].astype(np.int64) << 8)
        for cid, n in zip(*np.unique(cids, return_counts=True)):
            self.scan.count(int(cid), int(n))
        times = _u64(buf, m_offs + self._stamp_at)
        self._gather(buf, cids, times, m_offs + _MSG_DATA, m_len - (_MSG_DATA - _RECORD_HEAD))

    def _flush_loose(self) -> None:
        """Messages outside chunks (unchunked files), gathered like a chunk's."""
        if not self._loose:
            return
        msgs, self._loose = self._loose, []
        length = np.array([len(m.data) for m in msgs], np.int64)
        start = np.concatenate(([0], np.cumsum(length)[:-1])).astype(np.int64)
        buf = np.frombuffer(b''.join(m.data for m in msgs), np.uint8)
        cids = np.array([m.channel_id for m in msgs], np.int64)
        stamp = 'log_time' if self.stamp == 'log' else 'publish_time'
        times = np.array([getattr(m, stamp) for m in msgs], np.uint64)
        self._gather(buf, cids, times, start, length)

    def read(self) -> McapColumns:
        """Read the file (once); returns self."""
        scan = self.scan
        done = 0
        ended = False
        # the chunk CRCs protect every record read; the data-section CRC would only add the
        # message indexes this reader skips, at the cost of a second pass over the file
        for record in iter_records(self.file, scan, emit_chunks=True, data_crc=False):
            if isinstance(record, CheckedChunk):
                self._flush_loose()
                self._chunk(record)
            elif isinstance(record, Message):
                self._flush_chunks()           # file order: the chunks before this message
                scan.count(record.channel_id)
                if self._column(record.channel_id) is not None:
                    self._loose.append(record)
                    if len(self._loose) >= _LOOSE_BATCH:
                        self._flush_loose()
            elif isinstance(record, (DataEnd, Footer)):
                ended = True           # the summary section follows: nothing more to read
                break
            else:
                self._flush_chunks()           # e.g. a channel declared after these chunks
                self._record(record)
            if self.progress is not None:
                self.progress(scan.valid_end - done)
                done = scan.valid_end
        self._flush_chunks()
        self._flush_loose()
        if not ended and not scan.complete:
            self.truncated = True
            self.error = scan.error
        scan.name({cid: topic for cid, (topic, _) in self._channels.items()})
        if self.progress is not None:
            self.progress(scan.size - done)
        return self
