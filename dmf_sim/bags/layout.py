"""rosbag2 bag layout: which MCAP files make a bag, and its ``metadata.yaml`` (one policy).

A bag is what ``ros2 bag record -s mcap`` writes: a directory holding ``metadata.yaml``
(rosbag2 Jazzy, version 9) and MCAP files ``<name>_0.mcap``, ``<name>_1.mcap``, ... (split by
duration or size). :func:`resolve_bag` turns anything a user may point at into the files to
read, always by the same rules:

* a bag directory with ``metadata.yaml``: the files it lists (a listed file that is missing is
  an error), then the ``.mcap`` files it does not list yet -- the split being recorded, or the
  one a crash left behind (``BagRecorder`` lists a split once it is closed). A last unlisted
  file without MCAP data (a crash right as a split started) is skipped with a note;
* a directory without ``metadata.yaml``: its ``.mcap`` files;
* ``metadata.yaml`` itself: its directory;
* an ``.mcap`` file: that file alone; when a ``metadata.yaml`` beside it belongs to the same
  bag, its metadata (the recording's ``custom_data``) comes with it.

Files are ordered by their split number (``x_10.mcap`` after ``x_9.mcap``). A file that does not
start with the MCAP magic (random bytes, an empty file) is "not an MCAP file".
"""
from __future__ import annotations

import functools
import os
import re
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.stream_reader import MAGIC_SIZE, read_magic

from dmf_sim import __version__
from dmf_sim.bags.metadata import RunMetadata
from dmf_sim.core.errors import BagError, BagExistsError, BagFileError, ConfigError, one_line
from dmf_sim.core.paths import parse_yaml, read_text

__all__ = ['LIBRARY', 'METADATA_FILE', 'ROSBAG2_VERSION', 'ROS_DISTRO', 'STORAGE_ID', 'BagFiles',
           'FileInfo', 'TopicInfo', 'bag_metadata', 'dump_metadata', 'is_mcap',
           'refuse_existing', 'resolve_bag',
           'split_number', 'write_metadata']

LIBRARY = f'dmf_sim-{__version__}'   # the MCAP header's library field
METADATA_FILE = 'metadata.yaml'
ROSBAG2_VERSION = 9
ROS_DISTRO = 'jazzy'
STORAGE_ID = 'mcap'
_SPLIT = re.compile(r'^(.*?)(?:_(\d+))?\.mcap$')
_DUMPER = getattr(yaml, 'CSafeDumper', yaml.SafeDumper)


# ------------------------------------------------------------------------- metadata.yaml

@dataclass
class TopicInfo:
    """One topic of a bag: name, ROS type, offered QoS (YAML text), RIHS01 type hash, count."""

    name: str
    msgtype: str
    qos: str = ''
    type_hash: str = ''
    count: int = 0

    @functools.cached_property
    def qos_profiles(self) -> list[dict[str, Any]]:
        """The offered QoS as a list of profiles (rosbag2 v9 metadata form)."""
        return _parse_qos(self.qos)


@dataclass
class FileInfo:
    """One MCAP file of a bag: name relative to the bag, log-time span [ns], message count."""

    path: str
    start: int = 0
    end: int = 0
    count: int = 0
    topic_counts: dict[str, int] = field(default_factory=dict)

    def add(self, topic: str, timestamp_ns: int) -> None:
        """Count one message of ``topic`` logged at ``timestamp_ns``."""
        if self.count == 0:
            self.start = self.end = timestamp_ns
        elif timestamp_ns < self.start:
            self.start = timestamp_ns
        elif timestamp_ns > self.end:
            self.end = timestamp_ns
        self.count += 1
        self.topic_counts[topic] = self.topic_counts.get(topic, 0) + 1


def _parse_qos(text: str) -> list[dict[str, Any]]:
    """Offered QoS profiles as a list (rosbag2 v9 metadata form); [] when absent or unreadable."""
    if not text:
        return []
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return []
    return value if isinstance(value, list) else []


def bag_metadata(topics: Sequence[TopicInfo], files: Sequence[FileInfo], *,
                 custom_data: Mapping[str, str] | None = None,
                 ros_distro: str = ROS_DISTRO) -> dict[str, Any]:
    """``metadata.yaml`` content as rosbag2 Jazzy (version 9) writes it, for ``files``; the
    topic message counts are those of ``files`` (so readers find what the counts promise)."""
    counted = [f for f in files if f.count]
    start = min((f.start for f in counted), default=0)
    end = max((f.end for f in counted), default=0)
    counts = {t.name: sum(f.topic_counts.get(t.name, 0) for f in files) for t in topics}
    return {'rosbag2_bagfile_information': {
        'version': ROSBAG2_VERSION,
        'storage_identifier': STORAGE_ID,
        'duration': {'nanoseconds': end - start},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(f.count for f in files),
        'topics_with_message_count': [
            {'topic_metadata': {'name': t.name, 'type': t.msgtype, 'serialization_format': 'cdr',
                                'offered_qos_profiles': t.qos_profiles,
                                'type_description_hash': t.type_hash},
             'message_count': counts[t.name]}
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


def dump_metadata(meta: Mapping[str, Any]) -> str:
    """YAML text of a metadata mapping, keys in rosbag2's order (libyaml's emitter if present:
    the recorder writes it at every split)."""
    return yaml.dump(dict(meta), Dumper=_DUMPER, sort_keys=False, default_flow_style=False)


def write_metadata(directory: Path, meta: Mapping[str, Any]) -> None:
    """Write ``metadata.yaml`` atomically (temporary file, then rename)."""
    tmp = directory / (METADATA_FILE + '.tmp')
    tmp.write_text(dump_metadata(meta), encoding='utf-8')
    os.replace(tmp, directory / METADATA_FILE)


def refuse_existing(path: Path) -> None:
    """Bags are never overwritten: refuse a path that exists, other than an empty directory
    (one-line BagExistsError)."""
    if path.is_dir() and not path.is_symlink() and not any(path.iterdir()):
        return
    if path.exists() or path.is_symlink():
        raise BagExistsError(f'{path} exists already, not overwriting')


def _read_metadata(directory: Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of ``directory/metadata.yaml`` (checked)."""
    path = directory / METADATA_FILE
    try:
        data = parse_yaml(read_text(path), str(path))
    except ConfigError as exc:
        raise BagError(f'invalid bag metadata: {one_line(exc)}') from None
    info = data.get('rosbag2_bagfile_information') if isinstance(data, dict) else None
    if not isinstance(info, dict):
        raise BagError(f'invalid bag metadata {path}: no rosbag2_bagfile_information mapping')
    storage = info.get('storage_identifier') or STORAGE_ID
    if storage != STORAGE_ID:
        raise BagError(f'{directory}: storage {storage!r} is not supported, only mcap')
    compression = str(info.get('compression_mode') or '')
    if compression.lower() not in ('', 'none'):
        raise BagError(f'{directory}: rosbag2 compression mode {compression!r} is not supported '
                       '(only per-chunk MCAP compression is)')
    paths = info.get('relative_file_paths') or []
    if not isinstance(paths, list) or not all(isinstance(p, str) for p in paths):
        raise BagError(f'invalid bag metadata {path}: relative_file_paths must be a list of names')
    return info


# ------------------------------------------------------------------------------ resolution

def split_number(path: Path) -> tuple[str, int]:
    """Sort key of a bag file: (stem without the split suffix, split number)."""
    m = _SPLIT.match(path.name)
    if m is None:
        return path.name, -1
    return m.group(1), int(m.group(2)) if m.group(2) is not None else -1


def is_mcap(path: Path) -> bool:
    """Whether ``path`` starts with the MCAP magic (read with the mcap library).

    A file shorter than the magic is not one: the library's ``struct.unpack`` of the short read
    raises ``struct.error`` then, which is no McapError."""
    try:
        with open(path, 'rb') as fh:
            read_magic(ReadDataStream(fh))
    except (McapError, OSError, ValueError, EOFError, struct.error):
        return False
    return True


def _not_mcap(path: Path) -> BagError:
    size = path.stat().st_size if path.exists() else 0
    if size == 0:
        what = 'an empty file'
    elif size < MAGIC_SIZE:
        what = f'{size} bytes, shorter than the {MAGIC_SIZE}-byte MCAP magic'
    else:
        what = f'{size} bytes without the MCAP magic'
    return BagError(f'{path} is not an MCAP file ({what})')


@dataclass(frozen=True)
class BagFiles:
    """What :func:`resolve_bag` found.

    Attributes:
        path: the bag as given (``metadata.yaml`` replaced by its directory).
        directory: the bag directory, or None for a bare ``.mcap`` outside a bag.
        files: the MCAP files to read, in recording order.
        metadata: the ``rosbag2_bagfile_information`` of ``metadata.yaml`` (None without one).
        unlisted: files read although ``metadata.yaml`` does not list them (being recorded, or
            left by a crash).
        notes: what was skipped and why.
    """

    path: Path
    directory: Path | None
    files: tuple[Path, ...]
    metadata: dict[str, Any] | None = None
    unlisted: tuple[Path, ...] = ()
    notes: tuple[str, ...] = ()

    @property
    def run_metadata(self) -> RunMetadata:
        """The recording node's settings from ``custom_data`` (all None if absent)."""
        return RunMetadata.from_bag_metadata(self.metadata)

    @property
    def topics(self) -> dict[str, str]:
        """Topic -> ROS type as ``metadata.yaml`` lists them ({} without metadata)."""
        out: dict[str, str] = {}
        for item in (self.metadata or {}).get('topics_with_message_count') or []:
            try:
                out.setdefault(str(item['topic_metadata']['name']),
                               str(item['topic_metadata']['type']))
            except (KeyError, TypeError):
                continue
        return out


def _directory(path: Path) -> BagFiles:
    meta = _read_metadata(path) if (path / METADATA_FILE).is_file() else None
    present = sorted(path.glob('*.mcap'), key=split_number)
    listed: list[Path] = []
    if meta is not None:
        listed = [path / Path(p).name for p in meta.get('relative_file_paths') or []]
        if missing := [p.name for p in listed if not p.is_file()]:
            raise BagFileError(f'{path}: bag files listed in metadata.yaml are missing: '
                               f'{", ".join(missing)}')
    unlisted = [p for p in present if p not in listed]
    if not listed and not unlisted:
        raise BagFileError(f'{path} holds no .mcap file (is it a rosbag2 MCAP bag?)')
    notes = []
    if unlisted and len(listed) + len(unlisted) > 1 and not is_mcap(unlisted[-1]):
        notes.append(f'{unlisted[-1].name} holds no MCAP data yet (recording stopped as the split '
                     'began): skipped')
        unlisted = unlisted[:-1]
    files = listed + unlisted
    for f in files:
        if not is_mcap(f):
            raise _not_mcap(f)
    return BagFiles(path, path, tuple(files), meta, tuple(unlisted), tuple(notes))


def _file(path: Path) -> BagFiles:
    if path.suffix != '.mcap':
        raise BagError(f'{path} is neither a rosbag2 bag directory nor an .mcap file')
    if not is_mcap(path):
        raise _not_mcap(path)
    parent = path.parent
    meta = None
    if (parent / METADATA_FILE).is_file():
        info = _read_metadata(parent)
        names = [Path(p).name for p in info.get('relative_file_paths') or []]
        stems = {split_number(Path(n))[0] for n in names} or {parent.name}
        if path.name in names or split_number(path)[0] in stems:
            meta = info
    return BagFiles(path, parent if meta is not None else None, (path,), meta)


def resolve_bag(path: str | os.PathLike[str]) -> BagFiles:
    """The MCAP files and metadata of a bag (see the module docstring for the rules).

    Raises BagFileError (one line) if nothing is there or the path cannot be used (e.g. a name
    longer than the file system allows), BagError if it is not a bag."""
    p = Path(path)
    try:
        if p.name == METADATA_FILE and p.is_file():
            p = p.parent
        if not p.exists():
            raise BagFileError(f'bag {p} does not exist')
        return _directory(p) if p.is_dir() else _file(p)
    except BagError:
        raise
    except OSError as exc:
        raise BagFileError(f'bag {p}: cannot be read ({exc.strerror or exc})') from None
