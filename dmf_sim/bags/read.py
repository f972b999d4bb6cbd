"""Reading bags message by message with the libraries: ``mcap`` framing, ``rosbags`` decoding.

This is the message reader (``reader='messages'`` of the analysis): every record of every file
through ``mcap``'s record parsing (its chunk decompression included), every wanted message
decoded by :class:`TypeDecoder` (``rosbags`` types from the schemas embedded in the
file). It reads complete files, files a crash truncated (up to the last complete record) and
files written by other tools. The records come from :mod:`dmf_sim.bags.records` (chunks checked
against their CRCs: a corrupt chunk is skipped and reported in the file's :class:`Scan`).
:mod:`dmf_sim.bags.columns` is the fast path for numeric columns; it is checked against this
one.
"""
from __future__ import annotations

import os
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.records import Channel, Message, Schema

from dmf_sim.bags.layout import BagFiles, resolve_bag
from dmf_sim.bags.records import Scan, file_topics, iter_records, normalize_type
from dmf_sim.core.errors import BagError

__all__ = ['BagMessage', 'Scan', 'TypeDecoder', 'bag_topics', 'iter_records', 'normalize_type',
           'read_messages', 'message_counts', 'topics_text']

_IDL_SEPARATOR = '=' * 80 + '\n'


class TypeDecoder:
    """CDR decoding with ``rosbags``: one policy for every reader of the package.

    A type is registered from the schema embedded in the file (``ros2msg``, or ``ros2idl`` as
    rosbag2 writes it), which is what the writer used; without an embedded schema, the ROS 2
    Jazzy standard types are used. Two files defining one type differently are refused.
    """

    def __init__(self) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.store = get_typestore(Stores.EMPTY)
        self._standard = None
        self._stores: dict[str, Any] = {}     # msgtype -> the type store that decodes it
        self._texts: dict[str, str] = {}      # msgtype -> embedded definition it came from

    def __contains__(self, msgtype: str) -> bool:
        return msgtype in self._stores

    def add(self, msgtype: str, encoding: str = '', text: str = '') -> None:
        """Make ``msgtype`` decodable from its embedded definition, else the standard types."""
        if msgtype in self._stores:
            if text and self._texts.get(msgtype, text) != text:
                self._check_same(msgtype, encoding, text)
            return
        if not text:
            self._stores[msgtype] = self._standard_store(msgtype)
            return
        try:
            self.store.register(self._parse(msgtype, encoding, text))
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001 - rosbags refuses a conflicting dependency
            raise BagError(f'type {msgtype!r}: {" ".join(str(exc).split())}') from None
        self._stores[msgtype] = self.store
        self._texts[msgtype] = text

    def add_schema(self, schema: Schema | None, msgtype: str) -> None:
        """:meth:`add` from an mcap Schema record (None: no schema)."""
        if schema is None or not schema.data:
            self.add(msgtype)
        else:
            self.add(msgtype, schema.encoding, schema.data.decode(errors='replace'))

    def decode(self, data: bytes | memoryview, msgtype: str) -> Any:
        """Deserialize one CDR message of a type passed to :meth:`add` before."""
        return self._stores[msgtype].deserialize_cdr(bytes(data), msgtype)

    def _standard_store(self, msgtype: str):
        from rosbags.typesys import Stores, get_typestore

        if self._standard is None:
            self._standard = get_typestore(Stores.ROS2_JAZZY)
        if msgtype not in self._standard.types:
            raise BagError(f'no schema embedded for type {msgtype!r} and it is not a standard '
                           'ROS 2 Jazzy type')
        return self._standard

    @staticmethod
    def _parse(msgtype: str, encoding: str, text: str) -> dict[str, Any]:
        from rosbags.typesys.idl import get_types_from_idl
        from rosbags.typesys.msg import get_types_from_msg

        try:
            if encoding == 'ros2msg':
                return get_types_from_msg(text, msgtype)
            if encoding == 'ros2idl':
                parts = ([p.split('\n', 1)[1] for p in text.split(_IDL_SEPARATOR)[1:]]
                         if text.startswith(_IDL_SEPARATOR + 'IDL: ') else [text])
                types: dict[str, Any] = {}
                for part in parts:
                    types.update(get_types_from_idl(part))
                return types
        except Exception as exc:  # noqa: BLE001 - rosbags' parser errors vary by version
            raise BagError(f'schema of {msgtype!r} cannot be parsed: '
                           f'{" ".join(str(exc).split())}') from None
        raise BagError(f'schema encoding {encoding!r} of {msgtype!r} is not supported '
                       '(ros2msg, ros2idl)')

    def _check_same(self, msgtype: str, encoding: str, text: str) -> None:
        from rosbags.typesys import Stores, get_typestore

        probe = get_typestore(Stores.EMPTY)
        try:
            probe.register(self._parse(msgtype, encoding, text))
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001
            raise BagError(f'type {msgtype!r}: {" ".join(str(exc).split())}') from None
        if probe.hash_rihs01(msgtype) != self.store.hash_rihs01(msgtype):
            raise BagError(f'type {msgtype!r} is defined differently in two files of the bag')


@dataclass(frozen=True, slots=True)
class BagMessage:
    """One message: topic, log time [ns], ROS type name, decoded message (or CDR bytes if raw),
    publish time [ns]."""

    topic: str
    timestamp_ns: int
    msgtype: str
    msg: Any
    publish_time_ns: int = 0


def _wanted(topics: str | Iterable[str] | None) -> set[str] | None:
    if topics is None:
        return None
    return {topics} if isinstance(topics, str) else set(topics)


def _channel_type(file: Path, channel: Channel, schemas: dict[int, Schema]) -> str:
    """The ROS type of a cdr channel from its schema record (checked)."""
    if channel.message_encoding != 'cdr':
        raise BagError(f'{file}: topic {channel.topic!r} has message encoding '
                       f'{channel.message_encoding!r}; only cdr is supported')
    schema = schemas.get(channel.schema_id)
    if schema is None and channel.schema_id != 0:
        raise BagError(f'{file}: channel {channel.topic!r} refers to an unknown schema')
    msgtype = normalize_type(schema.name) if schema else ''
    if not msgtype:
        raise BagError(f'{file}: topic {channel.topic!r} has no schema; its type is unknown')
    return msgtype


def read_messages(path: str | os.PathLike[str] | BagFiles,
                  topics: str | Iterable[str] | None = None, *, raw: bool = False,
                  scans: list[Scan] | None = None) -> Iterator[BagMessage]:
    """Iterate over the messages of a bag in file order (log-time order for our own bags).

    Args:
        path: a bag (see :func:`dmf_sim.bags.layout.resolve_bag`) or its resolved files. Bags
            written by other tools are fine: messages are decoded with the definitions embedded
            in the file.
        topics: only these topics (default: all).
        raw: yield the CDR bytes as ``msg`` instead of decoding.
        scans: if given, one :class:`Scan` per file is appended as the file is read: how far
            it was valid and which chunks were corrupt (skipped), with their topics.

    A truncated file (crashed recorder) is read up to its last complete chunk; a corrupt chunk
    (CRC mismatch) is skipped.
    """
    bag = path if isinstance(path, BagFiles) else resolve_bag(path)
    wanted = _wanted(topics)
    decoder = TypeDecoder()
    for file in bag.files:
        schemas: dict[int, Schema] = {}
        channels: dict[int, tuple[str, str] | None] = {}   # id -> (topic, type); None: skipped
        names: dict[int, str] = {}
        scan = Scan()
        if scans is not None:
            scans.append(scan)
        for record in iter_records(file, scan):
            if isinstance(record, Message):
                scan.count(record.channel_id)
                info = channels.get(record.channel_id)
                if info is None:
                    continue
                topic, msgtype = info
                msg = record.data if raw else decoder.decode(record.data, msgtype)
                yield BagMessage(topic, record.log_time, msgtype, msg, record.publish_time)
            elif isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel) and record.id not in channels:
                names[record.id] = record.topic
                if wanted is not None and record.topic not in wanted:
                    channels[record.id] = None
                    continue
                msgtype = _channel_type(file, record, schemas)
                if not raw:
                    decoder.add_schema(schemas.get(record.schema_id), msgtype)
                channels[record.id] = (record.topic, msgtype)
        scan.name(names)


def message_counts(scans: Iterable[Scan]) -> dict[str, int]:
    """Topic -> complete messages read, over the scanned files of a bag."""
    out: dict[str, int] = {}
    for s in scans:
        for topic, n in s.messages.items():
            out[topic] = out.get(topic, 0) + n
    return out


def topics_text(topics: Iterable[str], counts: Mapping[str, int] | None = None) -> str:
    """A bag's topics for a message, sorted (``none`` if there are none); with the messages
    read per topic (``counts``), a declared topic that holds none is marked ``(no messages)``."""
    return ', '.join(t + (' (no messages)' if counts is not None and not counts.get(t) else '')
                     for t in sorted(topics)) or 'none'


def bag_topics(path: str | os.PathLike[str] | BagFiles) -> dict[str, str]:
    """Topic name -> ROS type name of a bag: from ``metadata.yaml``, else the files' summaries,
    else (truncated file) a scan of its records."""
    bag = path if isinstance(path, BagFiles) else resolve_bag(path)
    if bag.metadata is not None and bag.topics and not bag.unlisted:
        return bag.topics
    result = dict(bag.topics)
    for file in bag.files:
        for topic, msgtype in file_topics(file).items():
            result.setdefault(topic, msgtype)
    return result
