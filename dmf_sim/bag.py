"""rosbag2-compatible MCAP bags: crash-tolerant recording, reading (also truncated), recovery.

A bag is a directory holding ``metadata.yaml`` and one ``<name>_0.mcap`` file, laid out as
rosbag2 (Jazzy, metadata version 9) with its MCAP storage plugin writes it: ``ros2`` profile,
``cdr`` messages, ``ros2msg`` schemas with the full message definition embedded, channel
metadata ``offered_qos_profiles`` and ``topic_type_hash``, a ``rosbag2`` metadata record. So
``ros2 bag``, Foxglove, PlotJuggler, rosbags and the ``mcap`` readers open it.

Crash tolerance: :class:`BagRecorder` closes a chunk whenever it holds ``chunk_bytes`` of data or
spans ``chunk_seconds`` (of log time or of wall time), and hands it to the operating system at
once. After a crash (even SIGKILL) the file is a valid MCAP prefix: :func:`read_messages` reads it
up to the last complete chunk, :func:`recover_bag` rewrites it as a complete bag.

No ROS runtime is needed: the recorder takes CDR bytes (e.g. from
``rclpy.serialization.serialize_message``), the reader decodes with ``rosbags`` from the schemas
embedded in the file.
"""
from __future__ import annotations

import os
import shutil
import struct
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from dmf_sim import __version__
from dmf_sim.errors import BagError, BagFileError

__all__ = [
    'BagMessage', 'BagRecorder', 'RecoverReport', 'bag_topics', 'read_messages', 'recover_bag',
]

ROSBAG2_VERSION = 9
ROS_DISTRO = 'jazzy'
STORAGE_ID = 'mcap'
LIBRARY = f'dmf_sim-{__version__}'

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
_TRUNCATION_ERRORS = (McapError, struct.error, EOFError, UnicodeDecodeError)


# --------------------------------------------------------------------------- metadata helpers

def _qos_profile(preset: str) -> dict[str, Any]:
    base = _QOS_PRESETS[preset]
    return {**base, 'deadline': dict(_INFINITE), 'lifespan': dict(_INFINITE),
            'liveliness': 'automatic', 'liveliness_lease_duration': dict(_INFINITE),
            'avoid_ros_namespace_conventions': False}


def _parse_qos(text: str) -> list[dict[str, Any]]:
    """Offered QoS profiles as a list (rosbag2 v9 metadata form); [] when absent or unreadable."""
    if not text:
        return []
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return []
    return value if isinstance(value, list) else []


def _qos_text(value: str | None, topic: str) -> str:
    """Channel-metadata QoS text from a preset name or a YAML list of profiles."""
    if value is None:
        value = 'reliable'
    if value in _QOS_PRESETS:
        return yaml.safe_dump([_qos_profile(value)], sort_keys=False).strip()
    if not _parse_qos(value):
        msg = (f'QoS for {topic!r} must be one of {sorted(_QOS_PRESETS)} or a YAML list of '
               f'profiles, got {value!r}.')
        raise BagError(msg)
    return value.strip()


@dataclass
class _TopicInfo:
    name: str
    msgtype: str
    qos: str = ''
    type_hash: str = ''
    count: int = 0


@dataclass
class _FileInfo:
    path: str
    start: int = 0
    end: int = 0
    count: int = 0


def _metadata(topics: list[_TopicInfo], files: list[_FileInfo], *,
              custom_data: Mapping[str, str] | None = None,
              ros_distro: str = ROS_DISTRO) -> dict[str, Any]:
    """``metadata.yaml`` content as rosbag2 Jazzy (version 9) writes it."""
    counted = [f for f in files if f.count]
    start = min((f.start for f in counted), default=0)
    end = max((f.end for f in counted), default=0)
    return {'rosbag2_bagfile_information': {
        'version': ROSBAG2_VERSION,
        'storage_identifier': STORAGE_ID,
        'duration': {'nanoseconds': end - start},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(f.count for f in files),
        'topics_with_message_count': [
            {'topic_metadata': {'name': t.name, 'type': t.msgtype, 'serialization_format': 'cdr',
                                'offered_qos_profiles': _parse_qos(t.qos),
                                'type_description_hash': t.type_hash},
             'message_count': t.count}
            for t in topics],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [f.path for f in files],
        'files': [{'path': f.path, 'starting_time': {'nanoseconds_since_epoch': f.start},
                   'duration': {'nanoseconds': f.end - f.start}, 'message_count': f.count}
                  for f in files],
        'custom_data': dict(custom_data) if custom_data else None,
        'ros_distro': ros_distro,
    }}


def _dump_metadata(meta: dict[str, Any]) -> str:
    return yaml.safe_dump(meta, sort_keys=False, default_flow_style=False)


def _write_metadata(directory: Path, meta: dict[str, Any]) -> None:
    """Write ``metadata.yaml`` atomically (temporary file, then rename)."""
    tmp = directory / 'metadata.yaml.tmp'
    tmp.write_text(_dump_metadata(meta), encoding='utf-8')
    os.replace(tmp, directory / 'metadata.yaml')


def _refuse_existing(path: Path) -> None:
    if path.exists() or path.is_symlink():
        msg = f'{path} exists already, not overwriting.'
        raise FileExistsError(msg)


# --------------------------------------------------------------------------------- recording

class BagRecorder:
    """Write pre-serialized CDR messages to a new rosbag2 MCAP bag directory.

    Args:
        path: Bag directory to create; it must not exist.
        topics: Topic name -> ROS type name, e.g. ``'sensor_msgs/msg/JointState'``.
        chunk_seconds: Close a chunk once it spans this much log time or wall time [s].
        chunk_bytes: Close a chunk once it holds this many bytes.
        qos: Topic -> offered QoS: ``'reliable'`` (default), ``'best_effort'``,
            ``'transient_local'``, or a YAML list of QoS profiles as rosbag2 writes them.
        msgdefs: Type name -> ros2msg definition text (with dependencies, rosbag2 style) for
            types not in the rosbags ROS 2 Jazzy type store.
        custom_data: Key/value strings stored in ``metadata.yaml`` (``custom_data``).
        compression: Chunk compression: ``'none'`` (rosbag2's default), ``'lz4'`` or ``'zstd'``.

    Use as a context manager or call :meth:`close`; a bag that is never closed (crash) stays
    readable up to its last complete chunk. The wall-time bound is checked on :meth:`write`; call
    :meth:`flush` from a timer if messages can pause. Methods are thread-safe.
    """

    def __init__(self, path: str | os.PathLike[str], topics: Mapping[str, str], *,
                 chunk_seconds: float = 0.1, chunk_bytes: int = 64 * 1024,
                 qos: Mapping[str, str] | None = None, msgdefs: Mapping[str, str] | None = None,
                 custom_data: Mapping[str, str] | None = None,
                 compression: str = 'none') -> None:
        if not chunk_seconds > 0:
            msg = f'chunk_seconds must be positive, got {chunk_seconds!r}.'
            raise BagError(msg)
        if chunk_bytes < 1:
            msg = f'chunk_bytes must be positive, got {chunk_bytes!r}.'
            raise BagError(msg)
        if compression not in _COMPRESSION:
            msg = f'compression must be one of {sorted(_COMPRESSION)}, got {compression!r}.'
            raise BagError(msg)
        qos = dict(qos or {})
        if unknown := set(qos) - set(topics):
            msg = f'QoS given for undeclared topics {sorted(unknown)}.'
            raise BagError(msg)
        self.path = Path(path)
        self._infos: list[_TopicInfo] = []
        schemas = self._schemas(topics, msgdefs or {})
        for topic, msgtype in topics.items():
            if not topic.startswith('/'):
                msg = f'Topic names must be absolute (start with "/"), got {topic!r}.'
                raise BagError(msg)
            self._infos.append(_TopicInfo(topic, msgtype, _qos_text(qos.get(topic), topic),
                                          schemas[msgtype][1]))
        self._custom_data = dict(custom_data or {})
        self._chunk_ns = int(chunk_seconds * 1e9)
        self._chunk_seconds = float(chunk_seconds)
        self._chunk_bytes = int(chunk_bytes)

        _refuse_existing(self.path)
        try:
            self.path.mkdir(parents=True)
        except FileExistsError:
            _refuse_existing(self.path)
            raise
        self._file = _FileInfo(f'{self.path.name}_0.mcap')
        self._stream = (self.path / self._file.path).open('xb')
        self._writer = Writer(self._stream, chunk_size=2**62,
                              compression=_COMPRESSION[compression])
        self._writer.start(profile='ros2', library=LIBRARY)
        schema_ids = {name: self._writer.register_schema(name, 'ros2msg', text.encode())
                      for name, (text, _) in schemas.items()}
        self._channels: dict[str, tuple[int, _TopicInfo]] = {}
        for info in self._infos:
            cid = self._writer.register_channel(
                info.name, 'cdr', schema_ids[info.msgtype],
                {'offered_qos_profiles': info.qos, 'topic_type_hash': info.type_hash})
            self._channels[info.name] = (cid, info)
        self._stream.flush()
        _write_metadata(self.path, self._metadata())

        self.message_count = 0
        self._pending = 0
        self._pending_bytes = 0
        self._chunk_t0 = 0
        self._chunk_wall0 = 0.0
        self._closed = False
        self._lock = threading.Lock()

    @staticmethod
    def _schemas(topics: Mapping[str, str],
                 msgdefs: Mapping[str, str]) -> dict[str, tuple[str, str]]:
        """Type name -> (ros2msg definition, RIHS01 hash) for every declared type."""
        from rosbags.typesys import Stores, get_typestore
        from rosbags.typesys.msg import get_types_from_msg

        store = get_typestore(Stores.ROS2_JAZZY)
        result: dict[str, tuple[str, str]] = {}
        for msgtype in dict.fromkeys(topics.values()):
            if msgtype in msgdefs:
                store.register(get_types_from_msg(msgdefs[msgtype], msgtype))
                result[msgtype] = (msgdefs[msgtype], store.hash_rihs01(msgtype))
            elif msgtype in store.types:
                result[msgtype] = (store.generate_msgdef(msgtype, ros_version=2)[0],
                                   store.hash_rihs01(msgtype))
            else:
                msg = (f'Unknown message type {msgtype!r}; use the full name like '
                       f'"sensor_msgs/msg/JointState" or pass its definition in msgdefs.')
                raise BagError(msg)
        return result

    def _metadata(self) -> dict[str, Any]:
        return _metadata(self._infos, [self._file], custom_data=self._custom_data)

    def write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        """Append one CDR-serialized message with log (receive) time ``timestamp_ns``."""
        with self._lock:
            self._write(topic, timestamp_ns, data)

    def _write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        if self._closed:
            msg = f'Bag {self.path} is closed.'
            raise BagError(msg)
        try:
            cid, info = self._channels[topic]
        except KeyError:
            msg = f'Topic {topic!r} was not declared when the bag was opened.'
            raise BagError(msg) from None
        if timestamp_ns < 0:
            msg = f'Timestamp must be non-negative, got {timestamp_ns}.'
            raise BagError(msg)
        self._writer.add_message(cid, timestamp_ns, data, timestamp_ns, info.count & 0xFFFFFFFF)
        info.count += 1
        self.message_count += 1
        f = self._file
        if f.count == 0:
            f.start = f.end = timestamp_ns
        elif timestamp_ns < f.start:
            f.start = timestamp_ns
        elif timestamp_ns > f.end:
            f.end = timestamp_ns
        f.count += 1

        now = time.monotonic()
        if self._pending == 0:
            self._chunk_t0, self._chunk_wall0 = timestamp_ns, now
        self._pending += 1
        self._pending_bytes += len(data) + _MESSAGE_OVERHEAD
        if (self._pending_bytes >= self._chunk_bytes
                or timestamp_ns - self._chunk_t0 >= self._chunk_ns
                or now - self._chunk_wall0 >= self._chunk_seconds):
            self._flush()

    def flush(self) -> None:
        """Close the open chunk (if any) and hand everything written so far to the OS.

        Called automatically by :meth:`write`; call it from a timer when messages may pause.
        """
        with self._lock:
            self._flush()

    def _flush(self) -> None:
        if self._closed or self._pending == 0:
            return
        self._writer.flush()  # finalizes the chunk + message indexes, flushes the stream
        self._pending = 0
        self._pending_bytes = 0

    def close(self) -> None:
        """Write the last chunk, summary and index, and the final ``metadata.yaml``. Idempotent."""
        with self._lock:
            self._close()

    def _close(self) -> None:
        if self._closed:
            return
        self._flush()
        self._closed = True
        meta = self._metadata()
        self._writer.add_metadata('rosbag2', {
            'serialized_metadata': _dump_metadata(meta['rosbag2_bagfile_information']),
            'ROS_DISTRO': ROS_DISTRO})
        self._writer.finish()
        self._stream.close()
        _write_metadata(self.path, meta)

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` has run."""
        return self._closed

    def __enter__(self) -> BagRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f'BagRecorder({str(self.path)!r}, messages={self.message_count})'


# ----------------------------------------------------------------------------------- reading

@dataclass(frozen=True, slots=True)
class BagMessage:
    """One message: topic, log time [ns], ROS type name, decoded message (or CDR bytes if raw)."""

    topic: str
    timestamp_ns: int
    msgtype: str
    msg: Any


def _bag_files(path: str | os.PathLike[str]) -> tuple[Path, list[Path], dict[str, Any] | None]:
    """Resolve a bag path to (bag directory or file, its MCAP files, parsed metadata.yaml)."""
    path = Path(path)
    if path.is_file() and path.name == 'metadata.yaml':
        path = path.parent
    if not path.exists():
        msg = f'{path} does not exist.'
        raise BagFileError(msg)
    if path.is_file():
        if path.suffix != '.mcap':
            msg = f'{path} is neither a rosbag2 directory nor an .mcap file.'
            raise BagError(msg)
        return path, [path], None
    metapath = path / 'metadata.yaml'
    if not metapath.exists():
        files = sorted(path.glob('*.mcap'))
        if not files:
            msg = f'{path} holds neither metadata.yaml nor .mcap files.'
            raise BagFileError(msg)
        return path, files, None
    try:
        meta = yaml.safe_load(metapath.read_text(encoding='utf-8'))['rosbag2_bagfile_information']
        storage = meta.get('storage_identifier', '')
        names = [Path(p).name for p in meta['relative_file_paths']]
        compression = meta.get('compression_mode', '') or ''
    except (yaml.YAMLError, KeyError, TypeError, AttributeError) as exc:
        msg = f'Invalid bag metadata in {metapath}: {exc!r}.'
        raise BagError(msg) from None
    if storage != STORAGE_ID:
        msg = f'{path}: storage {storage!r} is not supported, only mcap.'
        raise BagError(msg)
    if compression.lower() not in {'', 'none'}:
        msg = f'{path}: rosbag2 compression mode {compression!r} is not supported.'
        raise BagError(msg)
    files = [path / n for n in names]
    if missing := [str(f) for f in files if not f.exists()]:
        msg = f'{path}: bag files missing: {missing}.'
        raise BagFileError(msg)
    return path, files, meta


@dataclass
class _Scan:
    """Outcome of a sequential pass over one MCAP file."""

    complete: bool = False   # footer and trailing magic seen
    valid_end: int = 0       # file offset after the last complete record
    size: int = 0
    error: str = ''


def _iter_records(file: Path, scan: _Scan) -> Iterator[Any]:
    """Yield the records of an MCAP file in file order (chunks expanded), stopping cleanly at a
    truncated or damaged tail; ``scan`` tells how far the file was valid."""
    scan.size = file.stat().st_size
    with file.open('rb') as stream:
        reader = StreamReader(stream, record_size_limit=max(scan.size, 1))
        records = reader.records
        while True:
            try:
                record = next(records)
            except StopIteration:
                scan.complete = True
                scan.valid_end = stream.tell()
                return
            except _TRUNCATION_ERRORS as exc:
                scan.error = f'{type(exc).__name__}: {exc}' if str(exc) else type(exc).__name__
                return
            scan.valid_end = stream.tell()  # chunk contents come after the whole chunk is read
            yield record


class _Decoder:
    """Decode CDR with rosbags types registered from the schemas embedded in a file."""

    def __init__(self) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.store = get_typestore(Stores.EMPTY)
        self._stores: dict[str, Any] = {}  # msgtype -> type store that decodes it

    def add(self, schema: Schema | None, msgtype: str) -> None:
        """Make ``msgtype`` decodable, from its embedded schema or else the standard types."""
        from rosbags.typesys import Stores, get_typestore
        from rosbags.typesys.idl import get_types_from_idl
        from rosbags.typesys.msg import get_types_from_msg

        if msgtype in self._stores:
            return
        if schema is None or not schema.data:
            store = get_typestore(Stores.ROS2_JAZZY)
            if msgtype not in store.types:
                msg = f'No schema embedded for type {msgtype!r} and it is not a standard type.'
                raise BagError(msg)
            self._stores[msgtype] = store
            return
        text = schema.data.decode()
        if schema.encoding == 'ros2msg':
            types = get_types_from_msg(text, msgtype)
        elif schema.encoding == 'ros2idl':
            sep = '=' * 80 + '\n'
            parts = ([p.split('\n', 1)[1] for p in text.split(sep)[1:]]
                     if text.startswith(sep + 'IDL: ') else [text])
            types = {}
            for part in parts:
                types.update(get_types_from_idl(part))
        else:
            msg = f'Schema encoding {schema.encoding!r} of {msgtype!r} is not supported.'
            raise BagError(msg)
        self.store.register(types)
        self._stores[msgtype] = self.store

    def decode(self, data: bytes, msgtype: str) -> Any:
        """Deserialize one CDR message of a type passed to :meth:`add` before."""
        return self._stores[msgtype].deserialize_cdr(data, msgtype)


def _normalize(msgtype: str) -> str:
    from rosbags.typesys.msg import normalize_msgtype

    return normalize_msgtype(msgtype)


def read_messages(path: str | os.PathLike[str], topics: str | list[str] | set[str] | None = None,
                  *, raw: bool = False) -> Iterator[BagMessage]:
    """Iterate over the messages of a bag in file order (log-time order for our own bags).

    Args:
        path: rosbag2 directory (with ``metadata.yaml``), directory of ``.mcap`` files, or a bare
            ``.mcap`` file. Bags written by other tools are fine: messages are decoded with the
            definitions embedded in the file.
        topics: Only these topics (default: all).
        raw: Yield the CDR bytes as ``msg`` instead of decoding.

    A truncated file (crashed recorder) is read up to its last complete chunk.
    """
    _, files, _ = _bag_files(path)
    wanted = {topics} if isinstance(topics, str) else (set(topics) if topics is not None else None)
    for file in files:
        decoder = _Decoder()
        schemas: dict[int, Schema] = {}
        channels: dict[int, tuple[str, str] | None] = {}  # id -> (topic, type); None: skipped
        for record in _iter_records(file, _Scan()):
            if isinstance(record, Message):
                info = channels.get(record.channel_id)
                if info is None:
                    continue
                topic, msgtype = info
                msg = record.data if raw else decoder.decode(record.data, msgtype)
                yield BagMessage(topic, record.log_time, msgtype, msg)
            elif isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel) and record.id not in channels:
                if wanted is not None and record.topic not in wanted:
                    channels[record.id] = None
                    continue
                if record.message_encoding != 'cdr':
                    msg = (f'{file}: topic {record.topic!r} has message encoding '
                           f'{record.message_encoding!r}; only cdr is supported.')
                    raise BagError(msg)
                schema = schemas.get(record.schema_id)
                if schema is None and record.schema_id != 0:
                    msg = f'{file}: channel {record.topic!r} refers to unknown schema.'
                    raise BagError(msg)
                msgtype = _normalize(schema.name) if schema else ''
                if not msgtype:
                    msg = f'{file}: topic {record.topic!r} has no schema; its type is unknown.'
                    raise BagError(msg)
                if not raw:
                    decoder.add(schema, msgtype)
                channels[record.id] = (record.topic, msgtype)


def bag_topics(path: str | os.PathLike[str]) -> dict[str, str]:
    """Topic name -> ROS type name of a bag (directory or ``.mcap``, also truncated)."""
    _, files, meta = _bag_files(path)
    if meta is not None and meta.get('topics_with_message_count'):
        return {t['topic_metadata']['name']: t['topic_metadata']['type']
                for t in meta['topics_with_message_count']}
    result: dict[str, str] = {}
    for file in files:
        schemas: dict[int, str] = {}
        with file.open('rb') as stream:
            try:  # complete file: the summary lists the channels
                summary = make_reader(stream).get_summary()
            except Exception:  # noqa: BLE001 - truncated or damaged: scan the records instead
                summary = None
        if summary is not None and summary.channels:
            for channel in summary.channels.values():
                schema = summary.schemas.get(channel.schema_id)
                result.setdefault(channel.topic, _normalize(schema.name) if schema else '')
            continue
        for record in _iter_records(file, _Scan()):
            if isinstance(record, Schema):
                schemas[record.id] = _normalize(record.name) if record.name else ''
            elif isinstance(record, Channel):
                result.setdefault(record.topic, schemas.get(record.schema_id, ''))
    return result


# ---------------------------------------------------------------------------------- recovery

@dataclass(frozen=True)
class RecoverReport:
    """What :func:`recover_bag` did."""

    input_path: Path
    output_path: Path
    message_count: int                          # messages kept
    topics: dict[str, int] = field(default_factory=dict)  # topic -> messages kept
    start_ns: int = 0
    end_ns: int = 0
    truncated: bool = False                     # some input file lacked its footer/summary
    dropped_bytes: int = 0                      # bytes after the last complete record
    errors: tuple[str, ...] = ()                # why reading stopped, per damaged file

    def __str__(self) -> str:
        state = (f'truncated input, {self.dropped_bytes} trailing bytes dropped'
                 if self.truncated else 'input was complete')
        span = (self.end_ns - self.start_ns) / 1e9
        return (f'{self.output_path}: kept {self.message_count} messages on '
                f'{len(self.topics)} topics over {span:.3f} s ({state})')


def _rewrite(src: Path, dst: Path, chunk_bytes: int,
             known: dict[str, _TopicInfo], scan: _Scan) -> _FileInfo:
    """Copy every complete record of ``src`` into a new, complete MCAP file ``dst``."""
    info = _FileInfo(dst.name)
    with dst.open('xb') as stream:
        writer = Writer(stream, chunk_size=chunk_bytes, compression=CompressionType.NONE)
        started = False
        schema_map: dict[int, int] = {}
        channel_map: dict[int, tuple[int, _TopicInfo]] = {}
        pending_schemas: dict[int, Schema] = {}

        def start(header: Header | None) -> None:
            nonlocal started
            if not started:
                lib = f'{LIBRARY} bag-recover' + (f' of {header.library}' if header else '')
                writer.start(profile=header.profile if header else 'ros2', library=lib)
                started = True

        for record in _iter_records(src, scan):
            if isinstance(record, Header):
                start(record)
            elif isinstance(record, Schema):
                pending_schemas[record.id] = record
            elif isinstance(record, Channel) and record.id not in channel_map:
                start(None)
                sid = 0
                if record.schema_id:
                    if record.schema_id not in pending_schemas:
                        msg = f'{src}: channel {record.topic!r} refers to unknown schema.'
                        raise BagError(msg)
                    if record.schema_id not in schema_map:
                        s = pending_schemas[record.schema_id]
                        schema_map[record.schema_id] = writer.register_schema(
                            s.name, s.encoding, s.data)
                    sid = schema_map[record.schema_id]
                s = pending_schemas.get(record.schema_id)
                msgtype = _normalize(s.name) if s and s.name else ''
                topic = known.setdefault(record.topic, _TopicInfo(
                    record.topic, msgtype, record.metadata.get('offered_qos_profiles', ''),
                    record.metadata.get('topic_type_hash', '')))
                cid = writer.register_channel(record.topic, record.message_encoding, sid,
                                              dict(record.metadata))
                channel_map[record.id] = (cid, topic)
            elif isinstance(record, Message):
                cid, topic = channel_map[record.channel_id]
                writer.add_message(cid, record.log_time, record.data, record.publish_time,
                                   record.sequence)
                topic.count += 1
                if info.count == 0:
                    info.start = info.end = record.log_time
                else:
                    info.start = min(info.start, record.log_time)
                    info.end = max(info.end, record.log_time)
                info.count += 1
            elif isinstance(record, Metadata) and record.name != 'rosbag2':
                start(None)
                writer.add_metadata(record.name, record.metadata)
            elif isinstance(record, Attachment):
                start(None)
                writer.add_attachment(record.create_time, record.log_time, record.name,
                                      record.media_type, record.data)
        start(None)
        writer.flush()
        meta = _metadata(list(known.values()), [info])['rosbag2_bagfile_information']
        writer.add_metadata('rosbag2', {'serialized_metadata': _dump_metadata(meta),
                                        'ROS_DISTRO': ROS_DISTRO})
        writer.finish()
    return info


def recover_bag(path: str | os.PathLike[str], out_path: str | os.PathLike[str] | None = None,
                *, in_place: bool = False, chunk_bytes: int = 1024 * 1024) -> RecoverReport:
    """Rewrite a (possibly truncated) bag as a complete one: summary, index, ``metadata.yaml``.

    Args:
        path: rosbag2 directory or bare ``.mcap`` file.
        out_path: Where to write; default ``<bag>_recovered`` (directory) or
            ``<name>_recovered.mcap`` (file). An ``.mcap`` suffix gives a bare MCAP file,
            anything else a rosbag2 directory. Never overwritten.
        in_place: Replace the input instead, after the rewrite succeeded.
        chunk_bytes: Chunk size of the rewritten file.
    """
    src, files, meta = _bag_files(path)
    if in_place and out_path is not None:
        msg = 'Give either an output path or in_place, not both.'
        raise BagError(msg)
    if in_place:
        out = src.with_name(f'.{src.name}.recover-tmp')
    elif out_path is not None:
        out = Path(out_path)
    else:
        out = (src.with_name(f'{src.stem}_recovered.mcap') if src.is_file()
               else src.with_name(f'{src.name}_recovered'))
    _refuse_existing(out)
    as_dir = src.is_dir() if in_place else out.suffix != '.mcap'
    if not as_dir and len(files) > 1:
        msg = f'{src} has {len(files)} files; recover it into a directory.'
        raise BagError(msg)

    known: dict[str, _TopicInfo] = {}
    infos: list[_FileInfo] = []
    scans: list[_Scan] = []
    try:
        if as_dir:
            out.mkdir(parents=True)
            for i, file in enumerate(files):
                name = file.name if (in_place or src.is_dir()) else f'{out.name}_{i}.mcap'
                scans.append(_Scan())
                infos.append(_rewrite(file, out / name, chunk_bytes, known, scans[-1]))
            old = meta or {}
            _write_metadata(out, _metadata(list(known.values()), infos,
                                           custom_data=old.get('custom_data'),
                                           ros_distro=old.get('ros_distro') or ROS_DISTRO))
        else:
            scans.append(_Scan())
            infos.append(_rewrite(files[0], out, chunk_bytes, known, scans[-1]))
    except BaseException:
        if out.is_dir():
            shutil.rmtree(out, ignore_errors=True)
        else:
            out.unlink(missing_ok=True)
        raise

    final = out
    if in_place:
        final = src
        if as_dir:
            for info in infos:
                os.replace(out / info.path, src / info.path)
            os.replace(out / 'metadata.yaml', src / 'metadata.yaml')
            shutil.rmtree(out)
        else:
            os.replace(out, src)

    counted = [i for i in infos if i.count]
    return RecoverReport(
        input_path=src, output_path=final, message_count=sum(i.count for i in infos),
        topics={t.name: t.count for t in known.values()},
        start_ns=min((i.start for i in counted), default=0),
        end_ns=max((i.end for i in counted), default=0),
        truncated=not all(s.complete for s in scans),
        dropped_bytes=sum(s.size - s.valid_end for s in scans if not s.complete),
        errors=tuple(s.error for s in scans if s.error))
