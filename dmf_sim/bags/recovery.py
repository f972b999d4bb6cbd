"""Completing a bag a crash left behind (``dmf-sim bag-recover``).

After a crash (even SIGKILL) a bag written by :class:`dmf_sim.bags.writer.BagRecorder` holds its
closed splits, complete and listed in ``metadata.yaml``, and the split being written: a valid MCAP
prefix without summary or footer, not listed yet. :func:`recover_bag` checks every file with the
record scanner (:mod:`dmf_sim.bags.records`: chunk CRCs, the data section CRC), keeps every
complete and intact file as it is (copied, or left in place), rewrites each incomplete or
damaged one record by record with the ``mcap`` writer -- every complete, intact chunk kept,
corrupt chunks dropped (and reported: topic, time range, messages), summary, indexes and footer
added -- and writes a ``metadata.yaml`` listing every file with its message counts and the
original ``custom_data``. Bags written by other tools (``ros2 bag record``, a bare ``.mcap``)
are handled the same way. A bag from which no message can be recovered (a stub a crash left
before the first chunk was written) is refused: there is nothing to write.
"""
from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from dmf_sim.bags.layout import (
    LIBRARY,
    ROS_DISTRO,
    BagFiles,
    FileInfo,
    TopicInfo,
    bag_metadata,
    dump_metadata,
    refuse_existing,
    resolve_bag,
    write_metadata,
)
from dmf_sim.bags.records import (
    SUMMARY_ERRORS,
    Scan,
    damage_lines,
    iter_records,
    no_message_text,
    normalize_type,
)
from dmf_sim.core.errors import BagError
from dmf_sim.core.paths import PACKAGE

__all__ = ['CHUNK_BYTES_RANGE', 'RECOVERY_TAG', 'RecoverReport', 'recover_bag', 'recovery_output',
           'recovery_library', 'written_by_recovery']

CHUNK_BYTES_RANGE = (1024, 1 << 30)      # chunk size of rewritten files [bytes]
RECOVERY_TAG = 'bag-recover'             # the library field of a rewritten file names the command


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
    rewritten: tuple[str, ...] = ()             # files rewritten (the others were complete)
    corrupt: tuple[str, ...] = ()               # corrupt chunks dropped (one line each)
    dropped_messages: int = 0                   # messages in the dropped chunks (as indexed)

    def __str__(self) -> str:
        parts = []
        if self.truncated:
            parts.append(f'truncated input, {self.dropped_bytes} trailing bytes dropped')
        if self.corrupt:
            parts.append(f'{len(self.corrupt)} corrupt part(s) dropped, '
                         f'{self.dropped_messages} messages lost')
        state = '; '.join(parts) or 'input was complete and intact'
        span = (self.end_ns - self.start_ns) / 1e9
        return (f'{self.output_path}: kept {self.message_count} messages on '
                f'{len(self.topics)} topics over {span:.3f} s ({state})')


def _complete_info(file: Path, name: str, known: dict[str, TopicInfo]) -> FileInfo | None:
    """Counts of a complete file from its summary (None: incomplete, or no statistics)."""
    with file.open('rb') as stream:
        try:
            summary = make_reader(stream).get_summary()
        except SUMMARY_ERRORS:
            return None
    if summary is None or summary.statistics is None:
        return None
    stats = summary.statistics
    info = FileInfo(name, stats.message_start_time, stats.message_end_time,
                    stats.message_count)
    for cid, channel in summary.channels.items():
        schema = summary.schemas.get(channel.schema_id)
        topic = known.setdefault(channel.topic, TopicInfo(
            channel.topic, normalize_type(schema.name) if schema else '',
            channel.metadata.get('offered_qos_profiles', ''),
            channel.metadata.get('topic_type_hash', '')))
        count = int(stats.channel_message_counts.get(cid, 0))
        topic.count += count
        info.topic_counts[channel.topic] = info.topic_counts.get(channel.topic, 0) + count
    return info


class _Rewrite:
    """Copy every complete record of one MCAP file into a new, complete MCAP file."""

    def __init__(self, src: Path, dst: Path, chunk_bytes: int,
                 known: dict[str, TopicInfo]) -> None:
        self.src, self.dst, self.known = src, dst, known
        self.chunk_bytes = chunk_bytes
        self.info = FileInfo(dst.name)
        self.scan = Scan()
        self._started = False
        self._schema_ids: dict[int, int] = {}
        self._channels: dict[int, tuple[int, TopicInfo]] = {}
        self._schemas: dict[int, Schema] = {}

    def _start(self, header: Header | None) -> None:
        if not self._started:
            lib = recovery_library(header.library if header else None)
            self.writer.start(profile=header.profile if header else 'ros2', library=lib)
            self._started = True

    def _channel(self, record: Channel) -> None:
        self._start(None)
        sid = 0
        schema = self._schemas.get(record.schema_id)
        if record.schema_id:
            if schema is None:
                raise BagError(f'{self.src}: channel {record.topic!r} refers to an unknown schema')
            if record.schema_id not in self._schema_ids:
                self._schema_ids[record.schema_id] = self.writer.register_schema(
                    schema.name, schema.encoding, schema.data)
            sid = self._schema_ids[record.schema_id]
        msgtype = normalize_type(schema.name) if schema and schema.name else ''
        topic = self.known.setdefault(record.topic, TopicInfo(
            record.topic, msgtype, record.metadata.get('offered_qos_profiles', ''),
            record.metadata.get('topic_type_hash', '')))
        cid = self.writer.register_channel(record.topic, record.message_encoding, sid,
                                           dict(record.metadata))
        self._channels[record.id] = (cid, topic)

    def _record(self, record) -> None:
        if isinstance(record, Header):
            self._start(record)
        elif isinstance(record, Schema):
            self._schemas[record.id] = record
        elif isinstance(record, Channel) and record.id not in self._channels:
            self._channel(record)
        elif isinstance(record, Message):
            self.scan.count(record.channel_id)
            cid, topic = self._channels[record.channel_id]
            self.writer.add_message(cid, record.log_time, record.data, record.publish_time,
                                    record.sequence)
            topic.count += 1
            self.info.add(topic.name, record.log_time)
        elif isinstance(record, Metadata) and record.name != 'rosbag2':
            self._start(None)
            self.writer.add_metadata(record.name, record.metadata)
        elif isinstance(record, Attachment):
            self._start(None)
            self.writer.add_attachment(record.create_time, record.log_time, record.name,
                                       record.media_type, record.data)

    def run(self) -> FileInfo:
        with self.dst.open('xb') as stream:
            self.writer = Writer(stream, chunk_size=self.chunk_bytes,
                                 compression=CompressionType.NONE, enable_data_crcs=True)
            for record in iter_records(self.src, self.scan):
                self._record(record)
            self._start(None)
            self.scan.name({cid: topic.name for cid, (_, topic) in self._channels.items()})
            self.writer.flush()
            meta = bag_metadata(list(self.known.values()), [self.info])
            self.writer.add_metadata('rosbag2', {
                'serialized_metadata': dump_metadata(meta['rosbag2_bagfile_information']),
                'ROS_DISTRO': ROS_DISTRO})
            self.writer.finish()
        return self.info


def recovery_output(bag: BagFiles, out_path=None, in_place: bool = False) -> tuple[Path, bool]:
    """Where :func:`recover_bag` writes, and whether as a bag directory (else a bare MCAP file:
    an output path ending in ``.mcap``)."""
    src = bag.path
    if in_place and out_path is not None:
        raise BagError('give either an output path or in_place, not both')
    if in_place:
        out = src.with_name(f'.{src.name}.recover-tmp')
    elif out_path is not None:
        out = Path(out_path)
    else:
        out = (src.with_name(f'{src.stem}_recovered.mcap') if src.is_file()
               else src.with_name(f'{src.name}_recovered'))
    as_dir = src.is_dir() if in_place else out.suffix != '.mcap'
    if not as_dir and len(bag.files) > 1:
        raise BagError(f'{out}: a bare .mcap file holds one file, and {src} is split into '
                       f'{len(bag.files)}; give a directory name (e.g. {out.with_suffix("")}) '
                       'or recover one split file at a time')
    return out, as_dir


def recovery_library(original: str | None) -> str:
    """The MCAP header's library field of a file :func:`recover_bag` rewrote: this package's
    :data:`~dmf_sim.bags.layout.LIBRARY`, ``bag-recover`` and the original's library."""
    return f'{LIBRARY} {RECOVERY_TAG}' + (f' of {original}' if original else '')


def written_by_recovery(path: Path) -> bool:
    """Whether the MCAP file ``path`` was written by :func:`recover_bag` (any version of this
    package: its header's library field, :func:`recovery_library`)."""
    from mcap.stream_reader import StreamReader
    try:
        with open(path, 'rb') as fh:
            header = next(iter(StreamReader(fh).records), None)
    except Exception:  # noqa: BLE001 - a file that cannot be read is not one of ours
        return False
    if not isinstance(header, Header):
        return False
    words = header.library.split(' ')
    return len(words) > 1 and words[0].startswith(f'{PACKAGE}-') and words[1] == RECOVERY_TAG


def recover_bag(path: str | os.PathLike[str], out_path: str | os.PathLike[str] | None = None,
                *, in_place: bool = False, chunk_bytes: int = 1024 * 1024) -> RecoverReport:
    """Make a (possibly truncated) bag complete: summary, index, ``metadata.yaml``.

    Args:
        path: rosbag2 directory or bare ``.mcap`` file; anything else (random bytes, an empty
            file) is refused with a BagError.
        out_path: Where to write; default ``<bag>_recovered`` (directory) or
            ``<name>_recovered.mcap`` (file). An ``.mcap`` suffix gives a bare MCAP file,
            anything else a rosbag2 directory. Never overwritten.
        in_place: Replace the incomplete files of the input instead, after the rewrite
            succeeded (complete files stay untouched).
        chunk_bytes: Chunk size of rewritten files, within ``CHUNK_BYTES_RANGE``.
    """
    lo, hi = CHUNK_BYTES_RANGE
    if not (isinstance(chunk_bytes, int) and lo <= chunk_bytes <= hi):
        raise BagError(f'chunk_bytes must be an integer within [{lo}, {hi}], got {chunk_bytes!r}')
    bag = resolve_bag(path)
    src = bag.path
    out, as_dir = recovery_output(bag, out_path, in_place)
    refuse_existing(out)
    known: dict[str, TopicInfo] = {}
    infos: list[FileInfo] = []
    scans: list[Scan] = []
    rewritten: list[str] = []
    existed = out.is_dir()              # an empty directory (_output)
    try:
        if as_dir:
            out.mkdir(parents=True, exist_ok=existed)
        for i, file in enumerate(bag.files):
            name = file.name if (in_place or src.is_dir()) else f'{out.name}_{i}.mcap'
            target = out / name if as_dir else out
            info = _complete_info(file, name, known) if as_dir and _intact(file) else None
            if info is not None:
                if not in_place:
                    shutil.copy2(file, target)
            else:
                job = _Rewrite(file, target, chunk_bytes, known)
                info = job.run()
                scans.append(job.scan)
                rewritten.append(name)
            infos.append(info)
        if not any(i.count for i in infos) and scans:
            raise BagError(f'{src}: nothing to recover: {no_message_text(scans)}')
        if as_dir:
            old = bag.metadata or {}
            write_metadata(out, bag_metadata(list(known.values()), infos,
                                             custom_data=old.get('custom_data'),
                                             ros_distro=old.get('ros_distro') or ROS_DISTRO))
    except BaseException:
        if out.is_dir():
            shutil.rmtree(out, ignore_errors=True)
            if existed:
                out.mkdir(exist_ok=True)
        else:
            out.unlink(missing_ok=True)
        raise

    final = out
    if in_place:
        final = src
        if as_dir:
            for name in rewritten:
                os.replace(out / name, src / name)
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
        errors=tuple(s.error for s in scans if s.error), rewritten=tuple(rewritten),
        corrupt=tuple(damage_lines(scans, done='dropped')),
        dropped_messages=sum(c.messages or 0 for s in scans for c in s.corrupt))


def _intact(file: Path) -> bool:
    """Whether every chunk of ``file`` passes its CRC and the data section its CRC."""
    scan = Scan()
    for _ in iter_records(file, scan, emit_chunks=True):
        pass
    return not scan.corrupt and not scan.data_crc_error
