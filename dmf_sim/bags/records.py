"""The MCAP record scanner every bag reader shares: records in file order, checked.

:func:`iter_records` walks an MCAP file's top-level records with ``mcap``'s record parsing and
stops cleanly at a truncated or damaged tail (a crashed recorder); :class:`Scan` says how far the
file was valid. Integrity, as the format provides it:

* **chunks** carry the CRC-32 of their uncompressed records (``uncompressed_crc``; 0 = not
  computed). A chunk whose CRC does not match, that cannot be decompressed, or (without a CRC)
  whose records do not exactly fill it is *corrupt*: it is skipped -- none of its messages is
  trusted -- and listed in :attr:`Scan.corrupt` with what it held (per channel: messages and log
  times, from the message index records that follow it; else the chunk's own time range).
  Reading goes on with the next chunk.
* the **data section** CRC (``DataEnd.data_section_crc``, 0 = not computed) covers every byte
  from the magic up to the DataEnd record; a mismatch that the corrupt chunks do not explain
  is reported in :attr:`Scan.data_crc_error` (a damaged record outside the chunks: an index, a
  message of an unchunked file).

Channels and schemas declared only inside a corrupt chunk are taken from the file's summary
section when it has one (yielded right after the corrupt chunk is found). Every reader of the
package (:mod:`dmf_sim.bags.read`, :mod:`dmf_sim.bags.columns`, :mod:`dmf_sim.bags.recovery`)
reads through this scanner, so they skip the same chunks; every command reports what was skipped
in the same words (:func:`damage_lines`, :func:`skipped_chunks`), and a bag of which not one
complete message could be read is diagnosed once (:func:`no_message_text`).
"""
from __future__ import annotations

import io
import struct
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError, RecordLengthLimitExceeded
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, DataEnd, Footer, MessageIndex, Schema
from mcap.stream_reader import StreamReader, breakup_chunk, get_chunk_data_stream, read_magic
from zlib_ng import zlib_ng as zlib  # zlib's CRC-32, ~4.7x faster (SIMD; the same values)

from dmf_sim.core.compiled import jit

__all__ = ['TRUNCATION_ERRORS', 'SUMMARY_ERRORS', 'RECORD_HEAD', 'CheckedChunk', 'CorruptChunk',
           'Scan', 'iter_records', 'record_offsets', 'normalize_type', 'file_topics',
           'damage_lines', 'skipped_chunks', 'no_message_text']

# what a truncated or damaged tail raises inside the mcap reader
TRUNCATION_ERRORS = (McapError, struct.error, EOFError, UnicodeDecodeError, ValueError)
# what reading the summary of a damaged or tiny file raises (a seek before the start: OSError)
SUMMARY_ERRORS = (*TRUNCATION_ERRORS, OSError)
RECORD_HEAD = 9           # opcode (1) + record length (8)
_MAGIC_BYTES = 8          # the magic before the first record
_NS = 1e-9


def record_offsets(buf: np.ndarray) -> np.ndarray:
    """Offsets of the complete records of a chunk's records area (uint8 array)."""
    n = buf.shape[0]
    out = np.empty(n // RECORD_HEAD + 1, np.int64)
    pos = 0
    count = 0
    while pos + RECORD_HEAD <= n:
        length = np.uint64(0)
        for k in range(8):
            length |= np.uint64(buf[pos + 1 + k]) << np.uint64(8 * k)
        if length > np.uint64(n - pos - RECORD_HEAD):
            break
        out[count] = pos
        count += 1
        pos += RECORD_HEAD + np.int64(length)
    return out[:count]


def _records_end(buf: np.ndarray, offs: np.ndarray) -> int:
    """Where the last complete record of ``buf`` (offsets ``offs``) ends."""
    if not len(offs):
        return 0
    last = int(offs[-1])
    return last + RECORD_HEAD + int(buf[last + 1:last + RECORD_HEAD].view('<u8')[0])


def normalize_type(name: str) -> str:
    """ROS type name in its full form (``std_msgs/Float64`` -> ``std_msgs/msg/Float64``)."""
    from rosbags.typesys.msg import normalize_msgtype

    return normalize_msgtype(name) if name else ''


@dataclass
class CorruptChunk:
    """A chunk skipped because its contents cannot be trusted.

    Attributes:
        file: the MCAP file; offset: file offset of the chunk record [bytes].
        start_ns, end_ns: log-time range of its messages [ns] (from its message index, else
            from the chunk record's own header).
        reason: why it is corrupt (CRC mismatch, decompression error, records overrun).
        lost: channel id -> messages it held (from its message index; empty: unknown).
        topics: topic -> messages lost, once the channel names are known (:meth:`Scan.name`).
    """

    file: Path
    offset: int
    start_ns: int
    end_ns: int
    reason: str
    lost: dict[int, int] = field(default_factory=dict)
    topics: dict[str, int] = field(default_factory=dict)
    _indexed: bool = False

    def add_index(self, index: MessageIndex) -> None:
        """Count the messages a message index record lists for this chunk."""
        if not index.records:
            return
        times = [t for t, _ in index.records]
        if not self._indexed:
            self.start_ns, self.end_ns, self._indexed = min(times), max(times), True
        else:
            self.start_ns, self.end_ns = min(self.start_ns, *times), max(self.end_ns, *times)
        self.lost[index.channel_id] = self.lost.get(index.channel_id, 0) + len(index.records)

    @property
    def messages(self) -> int | None:
        """Messages lost (None: unknown, the chunk had no message index)."""
        return sum(self.lost.values()) if self.lost else None

    def describe(self, t0_ns: int | None = None) -> str:
        """One line: where, why, the time range (s from ``t0_ns`` if given), what was lost."""
        if t0_ns is None:
            span = f'log time {self.start_ns * _NS:.3f}-{self.end_ns * _NS:.3f} s'
        else:
            span = f'{(self.start_ns - t0_ns) * _NS:.3f}-{(self.end_ns - t0_ns) * _NS:.3f} s'
        what = (', '.join(f'{t} {n}' for t, n in sorted(self.topics.items())) if self.topics
                else 'messages unknown (no message index)')
        total = self.messages
        lost = f'{total} messages lost ({what})' if total is not None else what
        return f'{self.file.name} chunk at byte {self.offset} ({self.reason}): {span}, {lost}'


@dataclass
class Scan:
    """Outcome of a sequential pass over one MCAP file."""

    complete: bool = False   # footer and trailing magic seen
    valid_end: int = 0       # file offset after the last complete record
    size: int = 0
    error: str = ''          # why reading stopped early
    corrupt: list[CorruptChunk] = field(default_factory=list)
    data_crc_error: str = ''

    counted: dict[int, int] = field(default_factory=dict)    # channel id -> messages read
    messages: dict[str, int] = field(default_factory=dict)   # topic -> messages read

    def count(self, channel_id: int, n: int = 1) -> None:
        """``n`` complete messages of channel ``channel_id`` read (the reader counts them)."""
        self.counted[channel_id] = self.counted.get(channel_id, 0) + n

    def name(self, channels: Mapping[int, str]) -> None:
        """Give the lost messages of the corrupt chunks, and the messages read, their topics
        (channel id -> topic)."""
        for c in self.corrupt:
            c.topics = {}
            for cid, n in c.lost.items():
                topic = channels.get(cid, f'channel {cid}')
                c.topics[topic] = c.topics.get(topic, 0) + n
        self.messages = {}
        for cid, n in self.counted.items():
            topic = channels.get(cid, f'channel {cid}')
            self.messages[topic] = self.messages.get(topic, 0) + n


@dataclass(frozen=True, slots=True)
class CheckedChunk:
    """A chunk whose records passed the checks: the record and its uncompressed records."""

    chunk: Chunk
    data: bytes


class _Reader(StreamReader):
    """mcap's StreamReader, driven record by record: chunks whole, the data section's CRC
    computed as it is read, message indexes parsed only when asked for (after a corrupt chunk;
    a reader that walks every chunk itself would only pay for their per-entry parsing)."""

    def __init__(self, stream, size: int, data_crc: bool) -> None:
        super().__init__(stream, emit_chunks=True, record_size_limit=max(size, 1))
        self._stream = ReadDataStream(stream, calculate_crc=data_crc)
        self.data_crc = data_crc
        self.want_index = False

    def _read_record(self, opcode: int, length: int):
        if opcode == Opcode.MESSAGE_INDEX and not self.want_index:
            self._stream.read(length)
            return None
        return super()._read_record(opcode, length)

    def scan(self) -> Iterator[tuple[Any, int]]:
        """(record or None, CRC of the bytes before it or None) in file order, up to the
        footer."""
        read_magic(self._stream)
        while True:
            before = self._stream.checksum() if self.data_crc else None
            opcode = self._stream.read1()
            length = self._stream.read8()
            if length > self._record_size_limit:
                raise RecordLengthLimitExceeded(opcode, length, self._record_size_limit)
            count = self._stream.count
            record = self._read_record(opcode, length)
            padding = length - (self._stream.count - count)
            if padding > 0:
                self._stream.read(padding)
            yield record, before
            if isinstance(record, Footer):
                read_magic(self._stream)
                return


def _framing_error(data: bytes) -> str:
    """Why the records of a chunk without CRC do not exactly fill it ('' if they do)."""
    buf = np.frombuffer(data, np.uint8)
    if _records_end(buf, record_offsets(buf)) == len(buf):
        return ''
    return 'its records do not fill it (no CRC to check)'


def _check(chunk: Chunk) -> tuple[bytes, str]:
    """The uncompressed records of ``chunk`` and '' -- or why it is corrupt."""
    try:
        stream, size = get_chunk_data_stream(chunk)
        data = stream.read(size)
    except Exception as exc:  # noqa: BLE001 - zstd/lz4 errors of a damaged chunk vary
        return b'', f'cannot be decompressed: {type(exc).__name__}'
    if len(data) != chunk.uncompressed_size:
        return b'', f'{len(data)} bytes uncompressed, {chunk.uncompressed_size} declared'
    if chunk.uncompressed_crc:
        crc = zlib.crc32(data)
        if crc != chunk.uncompressed_crc:
            return b'', f'CRC mismatch: {crc:08x}, stored {chunk.uncompressed_crc:08x}'
        return data, ''
    return data, _framing_error(data)


def _summary(file: Path):
    """The summary section of a complete file (None if it has none or cannot be read)."""
    with file.open('rb') as stream:
        try:
            return make_reader(stream).get_summary()
        except SUMMARY_ERRORS:
            return None


def iter_records(file: Path, scan: Scan | None = None, *, emit_chunks: bool = False,
                 data_crc: bool = True) -> Iterator[Any]:
    """Yield the records of an MCAP file in file order (see the module docstring).

    Chunks are checked and expanded into their records, or (``emit_chunks``) yielded as
    :class:`CheckedChunk`; corrupt chunks are skipped and listed in ``scan.corrupt``; message
    index records are not yielded. Reading stops cleanly at a truncated or damaged tail;
    ``scan`` tells how far the file was valid and what was corrupt. ``data_crc=False`` skips the
    data-section CRC (a second pass over every byte): for a reader that uses only what the
    chunk CRCs protect (the fast column reader skips the indexes it would cover).
    """
    scan = scan if scan is not None else Scan()
    scan.size = file.stat().st_size
    declared: set[tuple[type, int]] = set()
    from_summary = False
    with file.open('rb') as stream:
        reader = _Reader(stream, scan.size, data_crc)
        records = reader.scan()
        bad: CorruptChunk | None = None
        while True:
            start = max(scan.valid_end, _MAGIC_BYTES)     # offset of the next record
            try:
                record, before = next(records)
            except StopIteration:
                scan.complete = True
                scan.valid_end = stream.tell()
                return
            except TRUNCATION_ERRORS as exc:
                scan.error = f'{type(exc).__name__}: {exc}' if str(exc) else type(exc).__name__
                return
            scan.valid_end = stream.tell()  # chunk contents come after the whole chunk is read
            if isinstance(record, MessageIndex):
                if bad is not None:
                    bad.add_index(record)
                continue
            if record is None:
                continue
            bad, reader.want_index = None, False
            if isinstance(record, Chunk):
                data, problem = _check(record)
                if not problem and not emit_chunks:
                    try:
                        inner = breakup_chunk(record)
                    except TRUNCATION_ERRORS as exc:
                        problem = f'records cannot be parsed: {type(exc).__name__}'
                if problem:
                    bad = CorruptChunk(file, start, record.message_start_time,
                                       record.message_end_time, problem)
                    scan.corrupt.append(bad)
                    reader.want_index = True
                    if not from_summary:        # declarations the chunk may have held
                        from_summary = True
                        yield from _declarations(file, declared)
                    continue
                if emit_chunks:
                    yield CheckedChunk(record, data)
                else:
                    for r in inner:
                        if isinstance(r, (Schema, Channel)):
                            declared.add((type(r), r.id))
                        yield r
                continue
            if isinstance(record, DataEnd) and before is not None and record.data_section_crc \
                    and record.data_section_crc != before and not scan.corrupt:
                scan.data_crc_error = (f'{file.name}: data section CRC mismatch ({before:08x}, '
                                       f'stored {record.data_section_crc:08x}): a record outside '
                                       'the chunks is damaged')
            if isinstance(record, (Schema, Channel)):
                declared.add((type(record), record.id))
            yield record


def _declarations(file: Path, declared: set) -> Iterator[Any]:
    """Schemas, then channels, of the file's summary not declared so far."""
    summary = _summary(file)
    if summary is None:
        return
    for kind, table in ((Schema, summary.schemas), (Channel, summary.channels)):
        for rid, rec in sorted(table.items()):
            if (kind, rid) not in declared:
                declared.add((kind, rid))
                yield rec


def file_topics(file: Path) -> dict[str, str]:
    """Topic -> ROS type of one MCAP file: from its summary, else (truncated file) from the
    channel and schema records a scan finds."""
    summary = _summary(file)
    schemas: Mapping[int, Schema]
    channels: list[Channel]
    if summary is not None and summary.channels:
        schemas, channels = summary.schemas, list(summary.channels.values())
    else:
        found: dict[int, Schema] = {}
        channels = []
        for record in iter_records(file, emit_chunks=True):
            for r in chunk_declarations(record) if isinstance(record, CheckedChunk) else [record]:
                if isinstance(r, Schema):
                    found[r.id] = r
                elif isinstance(r, Channel):
                    channels.append(r)
        schemas = found
    out: dict[str, str] = {}
    for channel in channels:
        schema = schemas.get(channel.schema_id)
        out.setdefault(channel.topic, normalize_type(schema.name) if schema else '')
    return out


def damage_lines(scans: Sequence[Scan], truncated: Sequence[Path | str] = (),
                 t0_ns: int | None = None, done: str = 'skipped') -> list[str]:
    """What a bag's reading had to leave out, one line each, in the words of every command:
    the truncated files (read up to their last complete chunk), each corrupt chunk (where, why,
    its time range -- s from ``t0_ns`` when given -- and the messages lost per topic) and a data
    section CRC mismatch. ``done``: what was done with the corrupt chunks ('skipped' by a
    reader, 'dropped' by bag-recover)."""
    out = []
    if truncated:
        out.append('truncated bag (recorder crashed?): read up to the last complete chunk of '
                   + ', '.join(Path(f).name for f in truncated))
    for s in scans:
        out += [f'corrupt chunk {done}: {c.describe(t0_ns)}' for c in s.corrupt]
        if s.data_crc_error:
            out.append(s.data_crc_error)
    return out


def skipped_chunks(scans: Sequence[Scan], t0_ns: int) -> list[dict]:
    """The corrupt chunks a reader skipped, for a JSON report: file, byte offset, reason, time
    range [s from ``t0_ns``], messages lost (None: unknown) in total and per topic, and the
    chunk's line of :func:`damage_lines`."""
    return [{'file': c.file.name, 'offset': c.offset, 'reason': c.reason,
             't_start_s': (c.start_ns - t0_ns) * _NS, 't_end_s': (c.end_ns - t0_ns) * _NS,
             'messages_lost': c.messages, 'topics': dict(c.topics), 'text': c.describe(t0_ns)}
            for s in scans for c in s.corrupt]


def no_message_text(scans: Sequence[Scan]) -> str:
    """Why nothing can be read from the scanned files of a bag in which no complete message was
    found (a stub a crash left before its first chunk was written): their size and where
    reading stopped."""
    stopped = '; '.join(s.error for s in scans if s.error)
    return (f'no complete message in {sum(s.size for s in scans)} bytes'
            + (f' (reading stopped at: {stopped})' if stopped else ''))



def chunk_declarations(chunk: CheckedChunk) -> list[Schema | Channel]:
    """The schema and channel records inside a checked chunk (its messages left unparsed)."""
    buf = np.frombuffer(chunk.data, np.uint8)
    offs = record_offsets(buf)
    out: list[Schema | Channel] = []
    for i in np.flatnonzero((buf[offs] == Opcode.SCHEMA) | (buf[offs] == Opcode.CHANNEL)):
        o = int(offs[i])
        length = int(buf[o + 1:o + RECORD_HEAD].view('<u8')[0])
        body = ReadDataStream(io.BytesIO(chunk.data[o + RECORD_HEAD:o + RECORD_HEAD + length]))
        out.append(Schema.read(body) if buf[o] == Opcode.SCHEMA else Channel.read(body))
    return out


record_offsets = jit(record_offsets)
