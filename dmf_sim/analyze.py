"""Order analysis of recorded driveline bags (design.md §4-5): no ROS runtime needed.

Pipeline
--------
1. **Read** the few topics needed from a rosbag2 MCAP bag (directory with ``metadata.yaml``, a
   directory of ``.mcap`` files, or a bare ``.mcap``; complete, truncated by a crash, written by
   :class:`dmf_sim.bag.BagRecorder` or by ``ros2 bag record``). The reader walks the MCAP records
   itself and uses each chunk's message indexes to pick out only the wanted channels, so the
   1 kHz ``JointState`` stream is skipped entirely unless an element signal is requested.
   ``std_msgs/Float64`` values are gathered straight from the CDR bytes (fixed layout, both byte
   orders); ``sensor_msgs/JointState`` columns are gathered through a byte layout learnt from the
   first message and checked against ``rosbags``' decoder, and every message whose bytes do not
   match that layout is decoded with ``rosbags`` (so odd messages are still read correctly).
   Any file the fast reader cannot handle is read through :func:`dmf_sim.bag.read_messages`.
2. **Crank angle** psi(t): ``/engine/crank_angle`` (continuous; a wrapped angle is unwrapped), or,
   when that topic is missing, the time integral (trapezoid) of ``/engine/speed`` [rpm]. A bag
   with neither is refused with a one-line error.
3. **Angle-domain resampling**: each signal sample gets the crank angle at its time stamp (linear
   interpolation of psi(t), exact to O(domega/dt dt^2); when signal and crank angle are sampled
   together but their stamps carry receive-time jitter, each sample takes the crank angle of its
   own crank sample instead, see :func:`_psi_at`); the signal is interpolated as a function
   of psi with a cubic spline onto ``points_per_cycle`` points per engine cycle (720 deg = 4 pi rad
   of crank angle). Cycles start at whole multiples of 4 pi, so phases refer to the engine's
   crank angle. A speed ramp therefore does not smear the orders, whatever the ramp rate.
   Segments are split at gaps in the data (lost messages, a truncated tail).
4. **Half orders per cycle**: ``x(psi) = Re(sum_n c_n exp(i n psi/2))`` (dmf_sim.orders), |c_n|
   the amplitude of engine order n/2 (n = 6: 3rd order, n = 3: 1.5th order), plus the paper's
   Fig. 13 quantities per cycle: max and min deviation from the cycle mean, the mean, and for the
   DMF wind-up the mean minus theta. Orders above the Nyquist frequency of the recording at the
   cycle's speed are NaN.
5. **Speed bins** (``bin_rpm`` wide, centred on multiples of it; 0 keeps one row per cycle): the
   cycle's speed is 120 / (cycle duration [s]) rpm; a bin's amplitudes and Fig. 13 quantities are
   the means over its cycles (``n_cycles`` per bin is reported).

The HBM overlay (:func:`hbm_overlay`) solves the harmonic balance of the same model, alpha, load
and load set over the measured speed range and reports the difference per order.
"""
from __future__ import annotations

import math
import mmap
import os
import struct
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from dmf_sim.errors import BagError, BagFileError
from dmf_sim.orders import CYCLE_RAD
from dmf_sim.run_metadata import RunMetadata

__all__ = [
    'TOPIC_WINDUP', 'TOPIC_JOINTS', 'TOPIC_SPEED', 'TOPIC_CRANK', 'DEFAULT_TOPICS',
    'SignalSpec', 'Series', 'BagSeries', 'CycleOrders', 'OrderTable', 'SignalAnalysis',
    'BagAnalysis', 'HBMOverlay', 'read_bag_series', 'crank_angle', 'cycle_orders', 'bin_cycles',
    'analyze_bag', 'model_settings', 'hbm_overlay', 'overlay_all', 'natural_frequencies',
    'analysis_dict', 'write_outputs', 'write_csv', 'write_cycles_csv', 'plot_campbell',
    'plot_fig13', 'to_jsonable',
]

TOPIC_WINDUP = '/driveline/dmf_windup'
TOPIC_JOINTS = '/driveline/joint_states'
TOPIC_SPEED = '/engine/speed'
TOPIC_CRANK = '/engine/crank_angle'
DEFAULT_TOPICS = {'windup': TOPIC_WINDUP, 'joints': TOPIC_JOINTS, 'speed': TOPIC_SPEED,
                  'crank': TOPIC_CRANK}

RAD_S_TO_RPM = 30.0 / math.pi
GAP_FACTOR = 5.0          # a time step > GAP_FACTOR x the median step is a gap (segment break)

FLOAT64 = 'std_msgs/msg/Float64'
JOINT_STATE = 'sensor_msgs/msg/JointState'

# signal kind -> (JointState field or None, unit, description)
SIGNAL_KINDS: dict[str, tuple[str | None, str, str]] = {
    'windup': (None, 'rad', 'DMF wind-up'),
    'angle': ('position', 'rad', 'vibratory angle'),
    'velocity': ('velocity', 'rad/s', 'vibratory angular velocity'),
    'torque': ('effort', 'Nm', 'transmitted torque'),
    'topic': (None, '', 'Float64 topic'),
}


# ================================================================================================
# Signals
# ================================================================================================

@dataclass(frozen=True)
class SignalSpec:
    """What to analyse: ``windup`` (the wind-up topic), ``angle:NAME``, ``velocity:NAME``,
    ``torque:NAME`` (a JointState element column: position, velocity, effort) or ``topic:/name``
    (the ``data`` field of any scalar topic such as std_msgs/Float64)."""

    kind: str
    element: str | None = None

    @classmethod
    def parse(cls, text: str) -> 'SignalSpec':
        text = text.strip()
        kind, sep, rest = text.partition(':')
        kind = kind.strip().lower()
        if kind not in SIGNAL_KINDS:
            raise BagError(f'signal {text!r}: kind must be one of {", ".join(SIGNAL_KINDS)} '
                             "(e.g. 'windup', 'angle:CYL1', 'torque:INPUT SHAFT', 'topic:/my/float')")
        if kind == 'windup':
            if sep and rest.strip():
                raise BagError(f"signal {text!r}: 'windup' takes no element name")
            return cls('windup')
        if not rest.strip():
            what = 'a topic name' if kind == 'topic' else 'an element name'
            raise BagError(f"signal {text!r}: '{kind}:' needs {what}, e.g. "
                             + ("'topic:/driveline/dmf_windup'" if kind == 'topic' else f"'{kind}:CYL1'"))
        return cls(kind, rest.strip())

    @property
    def field(self) -> str | None:
        return SIGNAL_KINDS[self.kind][0]

    @property
    def unit(self) -> str:
        return SIGNAL_KINDS[self.kind][1]

    @property
    def label(self) -> str:
        return 'windup' if self.kind == 'windup' else f'{self.kind}:{self.element}'

    @property
    def slug(self) -> str:
        """File-name friendly label: ``windup``, ``angle_CYL1``, ``torque_INPUT_SHAFT``."""
        raw = self.label.replace(':', '_').replace('/', '_')
        return ''.join(ch if ch.isalnum() or ch in '._-' else '_' for ch in raw).strip('_')

    @property
    def description(self) -> str:
        if self.kind == 'windup':
            return 'DMF wind-up'
        return f'{SIGNAL_KINDS[self.kind][2]} {self.element}'


def _match_name(wanted: str, names: Sequence[str]) -> int:
    """Index of element ``wanted`` in ``names``: exact, else case-insensitive with '_' == ' '."""
    if wanted in names:
        return list(names).index(wanted)
    key = wanted.replace('_', ' ').strip().lower()
    hits = [i for i, n in enumerate(names) if n.replace('_', ' ').strip().lower() == key]
    if len(hits) == 1:
        return hits[0]
    raise BagError(f'element {wanted!r} is not in the joint states; names are: {", ".join(names)}')


# ================================================================================================
# Fast MCAP reading
# ================================================================================================

_MAGIC = b'\x89MCAP0\r\n'
_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_MSG_INDEX = 1, 2, 3, 4, 5, 6, 7
_OP_DATA_END = 0x0F
_MSG_DATA = 31            # message record: opcode 1 + length 8 + channel 2 + seq 4 + log 8 + pub 8
_ARANGE8 = np.arange(8)


class _Unsupported(Exception):
    """The fast reader cannot read this file; the generic reader is used instead."""


@dataclass
class Series:
    """Samples of one quantity: time stamps [ns] (int64) and values (float64)."""

    t_ns: np.ndarray
    values: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ns)


@dataclass
class BagSeries:
    """What :func:`read_bag_series` read.

    Attributes:
        series: request key -> Series (keys missing when the topic is absent or empty).
        topics: topic -> ROS type of every channel seen.
        files: MCAP files read; truncated: files that ended without footer (crash).
        metadata: the ``rosbag2_bagfile_information`` of metadata.yaml (None for a bare .mcap).
        reader: 'fast' or 'reference'; read_seconds: wall time of the reading.
        joint_names: element names of the joint states (when read).
    """

    series: dict[str, Series]
    topics: dict[str, str]
    files: list[Path]
    truncated: list[Path]
    metadata: dict | None
    reader: str
    read_seconds: float
    joint_names: list[str] = field(default_factory=list)


def _bag_files(path: str | os.PathLike) -> tuple[list[Path], dict | None]:
    """MCAP files of a bag (directory, metadata.yaml, or bare .mcap) and its parsed metadata."""
    import yaml

    p = Path(path)
    if p.is_file() and p.name == 'metadata.yaml':
        p = p.parent
    if not p.exists():
        raise BagFileError(f'bag {p} does not exist')
    if p.is_file():
        if p.suffix != '.mcap':
            raise BagError(f'{p} is neither a rosbag2 directory nor an .mcap file')
        return [p], None
    meta = None
    files: list[Path] = []
    metapath = p / 'metadata.yaml'
    if metapath.is_file():
        try:
            meta = yaml.safe_load(metapath.read_text(encoding='utf-8'))['rosbag2_bagfile_information']
            storage = meta.get('storage_identifier', 'mcap')
            if storage and storage != 'mcap':
                raise BagError(f'{p}: storage {storage!r} is not supported, only mcap')
            files = [p / Path(f).name for f in meta.get('relative_file_paths') or []]
        except (yaml.YAMLError, KeyError, TypeError, AttributeError):
            meta = None
            files = []
    files = [f for f in files if f.is_file()] or sorted(p.glob('*.mcap'))
    if not files:
        raise BagFileError(f'{p} holds no .mcap file (is it a rosbag2 MCAP bag?)')
    return files, meta


def _u64(arr: np.ndarray, pos: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(arr[pos[:, None] + _ARANGE8]).view('<u8').ravel()


class _Decoder:
    """rosbags CDR decoding for the slow path (types from the standard store or the schema)."""

    def __init__(self) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.std = get_typestore(Stores.ROS2_JAZZY)
        self.custom = get_typestore(Stores.EMPTY)
        self.stores: dict[str, Any] = {}

    def add(self, msgtype: str, encoding: str, text: str) -> None:
        if msgtype in self.stores:
            return
        if msgtype in self.std.types:
            self.stores[msgtype] = self.std
            return
        from rosbags.typesys.msg import get_types_from_msg

        if encoding != 'ros2msg' or not text:
            raise _Unsupported(f'type {msgtype!r} with schema encoding {encoding!r}')
        self.custom.register(get_types_from_msg(text, msgtype))
        self.stores[msgtype] = self.custom

    def decode(self, data: bytes, msgtype: str) -> Any:
        return self.stores[msgtype].deserialize_cdr(data, msgtype)


class _Extractor:
    """Turns the messages of one channel into rows of float values."""

    n_values = 1

    def __init__(self, decoder: _Decoder, msgtype: str) -> None:
        self.decoder = decoder
        self.msgtype = msgtype

    def extract(self, arr: np.ndarray, view: memoryview, start: np.ndarray,
                length: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def slow(self, msg: Any) -> list[float]:  # pragma: no cover - interface
        raise NotImplementedError

    def _slow_rows(self, view: memoryview, start: np.ndarray, length: np.ndarray,
                   out: np.ndarray, rows: np.ndarray) -> None:
        for r in rows:
            s, n = int(start[r]), int(length[r])
            out[r] = self.slow(self.decoder.decode(bytes(view[s:s + n]), self.msgtype))


class _ScalarExtractor(_Extractor):
    """The ``data`` field; std_msgs/Float64 gathered straight from the CDR bytes."""

    def slow(self, msg: Any) -> list[float]:
        try:
            return [float(msg.data)]
        except (AttributeError, TypeError):
            raise BagError(f'messages of type {self.msgtype} have no numeric field "data"') from None

    def extract(self, arr, view, start, length):
        out = np.full((len(start), 1), np.nan)
        if self.msgtype == FLOAT64 and len(start):
            # CDR: 2-byte representation id (0x0000 CDR_BE, 0x0001 CDR_LE), 2 option bytes, float64
            ok = (length >= 12) & (arr[start] == 0) & (arr[start + 1] <= 1)
            le = ok & (arr[start + 1] == 1)
            be = ok & ~le
            raw = np.ascontiguousarray(arr[(start + 4)[:, None] + _ARANGE8])
            if le.any():
                out[le, 0] = raw[le].view('<f8').ravel()
            if be.any():
                out[be, 0] = raw[be].view('>f8').ravel()
            bad = np.flatnonzero(~ok)
        else:
            bad = np.arange(len(start))
        self._slow_rows(view, start, length, out, bad)
        return out


def _joint_layout(data: bytes) -> tuple[str, list[str], dict[str, tuple[int, int]], int, np.ndarray]:
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
    p += 4 + n
    p = align(p, 4)
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


class _JointExtractor(_Extractor):
    """Columns (field, element name) of sensor_msgs/JointState.

    The byte layout of the first message (checked against rosbags' decoding of it) is used for
    every message of the same length whose bytes up to the first array (frame id, names, array
    lengths) are identical; any other message is decoded with rosbags."""

    def __init__(self, decoder, msgtype, columns: Sequence[tuple[str, str]]) -> None:
        super().__init__(decoder, msgtype)
        self.columns = list(columns)
        self.n_values = len(self.columns)
        self.names: list[str] | None = None
        self.layout = None   # (dtype, key bytes, key byte positions, value offsets, size)

    def _index(self, names: Sequence[str]) -> list[int]:
        return [_match_name(el, names) for _, el in self.columns]

    def slow(self, msg):
        names = list(msg.name)
        if self.names is None:
            self.names = names
        idx = self._index(names)
        row = []
        for (fld, el), i in zip(self.columns, idx):
            arr = getattr(msg, fld)
            if len(arr) <= i:
                raise BagError(f'joint states carry no {fld!r} for element {el!r} '
                                 f'({len(arr)} values for {len(names)} names)')
            row.append(float(arr[i]))
        return row

    def _learn(self, data: bytes) -> None:
        msg = self.decoder.decode(data, self.msgtype)
        self.slow(msg)                                    # names, and errors for bad requests
        try:
            end, names, arrays, total, cols = _joint_layout(data)
        except (_Unsupported, struct.error, UnicodeDecodeError):
            self.layout = False
            return
        if names != list(msg.name) or total > len(data):
            self.layout = False
            return
        for fld, (off, n) in arrays.items():
            got = np.frombuffer(data, end + 'f8', count=n, offset=off) if n else np.zeros(0)
            if not np.array_equal(got, np.asarray(getattr(msg, fld), dtype=float), equal_nan=True):
                self.layout = False
                return
        idx = self._index(names)
        offsets = [arrays[fld][0] + 8 * i for (fld, _), i in zip(self.columns, idx)]
        if cols.max() >= len(data):
            self.layout = False
            return
        tmpl = np.frombuffer(bytes(data), np.uint8)
        self.layout = (np.dtype(end + 'f8'), tmpl[cols].copy(), cols, np.array(offsets), len(data))

    def extract(self, arr, view, start, length):
        n = len(start)
        out = np.full((n, self.n_values), np.nan)
        if n == 0:
            return out
        if self.layout is None:
            s, k = int(start[0]), int(length[0])
            self._learn(bytes(view[s:s + k]))
        if not self.layout:
            self._slow_rows(view, start, length, out, np.arange(n))
            return out
        dtype, key, cols, offsets, size = self.layout
        ok = length == size
        ok[ok] = np.all(arr[start[ok, None] + cols] == key, axis=1)
        good = np.flatnonzero(ok)
        if len(good):
            raw = np.ascontiguousarray(arr[(start[good, None] + offsets)[:, :, None] + _ARANGE8])
            out[good] = raw.view(dtype).reshape(len(good), self.n_values)
        self._slow_rows(view, start, length, out, np.flatnonzero(~ok))
        return out


def _str(view, pos: int) -> tuple[str, int]:
    n = struct.unpack_from('<I', view, pos)[0]
    return bytes(view[pos + 4:pos + 4 + n]).decode(), pos + 4 + n


class _McapFile:
    """One MCAP file read for a set of topics (see module docstring)."""

    def __init__(self, file: Path, requests: Mapping[str, Callable[[str], _Extractor | None]],
                 decoder: _Decoder, stamp: str, bar=None) -> None:
        self.file = file
        self.requests = requests      # topic -> factory(msgtype) of its extractor
        self.decoder = decoder
        self.stamp_offset = 15 if stamp == 'log' else 23
        self.schemas: dict[int, tuple[str, str, str]] = {}   # id -> (name, encoding, text)
        self.channels: dict[int, tuple[str, str]] = {}        # id -> (topic, msgtype)
        self.extractors: dict[int, _Extractor | None] = {}    # channel id -> extractor / None
        self.out: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        self.truncated = False
        self.error = ''
        self.bar = bar

    # ---- records -----------------------------------------------------------------------------
    def _schema(self, view, body: int) -> None:
        sid = struct.unpack_from('<H', view, body)[0]
        name, p = _str(view, body + 2)
        enc, p = _str(view, p)
        n = struct.unpack_from('<I', view, p)[0]
        text = bytes(view[p + 4:p + 4 + n]).decode(errors='replace')
        self.schemas[sid] = (name, enc, text)

    def _channel(self, view, body: int) -> None:
        cid, sid = struct.unpack_from('<HH', view, body)
        if cid in self.channels:
            return
        topic, p = _str(view, body + 4)
        enc, _ = _str(view, p)
        name, senc, text = self.schemas.get(sid, ('', '', ''))
        from rosbags.typesys.msg import normalize_msgtype

        msgtype = normalize_msgtype(name) if name else ''
        self.channels[cid] = (topic, msgtype)
        factory = self.requests.get(topic)
        if factory is None:
            self.extractors[cid] = None
            return
        if enc != 'cdr':
            raise _Unsupported(f'topic {topic!r} has message encoding {enc!r}')
        if not msgtype:
            raise BagError(f'{self.file}: topic {topic!r} has no schema; its type is unknown')
        self.decoder.add(msgtype, senc, text)
        self.extractors[cid] = factory(msgtype)

    # ---- chunks ------------------------------------------------------------------------------
    def _walk(self, view, size: int, messages: bool = True) -> dict[int, list[int]]:
        """Walk the records of a chunk: learn its schema and channel records and (``messages``)
        return channel id -> offsets of the message records of channels with an extractor."""
        found: dict[int, list[int]] = {}
        p = 0
        unpack = struct.unpack_from
        while p + 9 <= size:
            op = view[p]
            n = unpack('<Q', view, p + 1)[0]
            if p + 9 + n > size:
                break
            if op == _OP_MESSAGE:
                if messages:
                    cid = unpack('<H', view, p + 9)[0]
                    if cid not in self.channels:
                        raise BagError(f'{self.file}: message on undeclared channel {cid}')
                    if self.extractors.get(cid) is not None:
                        found.setdefault(cid, []).append(p)
            elif op == _OP_SCHEMA:
                self._schema(view, p + 9)
            elif op == _OP_CHANNEL:
                self._channel(view, p + 9)
            p += 9 + n
        return found

    def _gather(self, arr: np.ndarray, view, cid: int, offsets: np.ndarray) -> None:
        ext = self.extractors[cid]
        offsets = np.sort(offsets.astype(np.int64))
        rec_len = _u64(arr, offsets + 1).astype(np.int64)
        t = _u64(arr, offsets + self.stamp_offset).astype(np.int64)
        start = offsets + _MSG_DATA
        length = rec_len - (_MSG_DATA - 9)
        vals = ext.extract(arr, view, start, length)
        self.out.setdefault(self.channels[cid][0], []).append((t, vals))

    def _chunk(self, arr: np.ndarray, view, indexes: dict[int, np.ndarray] | None) -> None:
        size = len(arr)
        if indexes and set(indexes) - self.channels.keys():
            # channel records inside the chunk (the usual case for the first chunk): learn them
            self._walk(view, size, messages=False)
            if set(indexes) - self.channels.keys():
                indexes = None
        if not indexes:
            found = {cid: np.array(v) for cid, v in self._walk(view, size).items()}
        else:
            found = {cid: offs for cid, offs in indexes.items()
                     if self.extractors.get(cid) is not None and len(offs)}
        for cid, offs in found.items():
            self._gather(arr, view, cid, offs)

    def _summary(self, mm, size: int) -> None:
        """Schemas and channels from the summary section of a complete file (if any)."""
        unpack = struct.unpack_from
        foot = size - 8 - 29          # footer record: opcode, length 20, 2 x u64, u32 crc
        if foot < 8 or mm[size - 8:size] != _MAGIC or mm[foot] != _OP_FOOTER:
            return
        start = unpack('<Q', mm, foot + 9)[0]
        if not 8 <= start < foot:
            return
        pos = start
        while pos + 9 <= foot:
            op = mm[pos]
            n = unpack('<Q', mm, pos + 1)[0]
            if pos + 9 + n > foot:
                return
            if op == _OP_SCHEMA:
                self._schema(mm, pos + 9)
            elif op == _OP_CHANNEL:
                self._channel(mm, pos + 9)
            pos += 9 + n

    def _decompress(self, mm, body: int) -> tuple[np.ndarray, memoryview]:
        _, _, usize, _ = struct.unpack_from('<QQQI', mm, body)
        comp, p = _str(mm, body + 28)
        rlen = struct.unpack_from('<Q', mm, p)[0]
        p += 8
        if comp == '':
            view = memoryview(mm)[p:p + rlen]
            return np.frombuffer(view, np.uint8), view
        raw = mm[p:p + rlen]
        if comp == 'zstd':
            import zstandard
            data = zstandard.ZstdDecompressor().decompress(raw, max_output_size=usize)
        elif comp == 'lz4':
            import lz4.frame
            data = lz4.frame.decompress(raw)
        else:
            raise _Unsupported(f'chunk compression {comp!r}')
        return np.frombuffer(data, np.uint8), memoryview(data)

    def _process(self, mm, body: int, indexes) -> bool:
        """Decompress and read one chunk; False (file treated as truncated there) if damaged."""
        try:
            arr, view = self._decompress(mm, body)
        except _Unsupported:
            raise
        except Exception as exc:  # noqa: BLE001 - zstd/lz4 errors of a damaged chunk
            self.truncated = True
            self.error = f'damaged chunk: {type(exc).__name__}: {exc}'
            return False
        self._chunk(arr, view, indexes)
        del arr, view
        return True

    def read(self) -> None:
        with open(self.file, 'rb') as fh:
            size = os.fstat(fh.fileno()).st_size
            if size < len(_MAGIC):
                self.truncated = True
                return
            mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
            try:
                self._read(mm, size)
            finally:
                try:
                    mm.close()
                except BufferError:   # a numpy view is still alive; the GC closes it
                    pass

    def _read(self, mm, size: int) -> None:
        if mm[:8] != _MAGIC:
            raise BagError(f'{self.file} is not an MCAP file')
        try:
            self._summary(mm, size)
        except (struct.error, UnicodeDecodeError):
            pass
        unpack = struct.unpack_from
        pos = 8
        pending = None       # (body offset) of a chunk waiting for its message indexes
        indexes: dict[int, np.ndarray] = {}
        loose: dict[int, list[int]] = {}
        last_bar = 0
        complete_after_pending = False
        while True:
            if pos + 9 > size:
                self.truncated = True
                break
            op = mm[pos]
            n = unpack('<Q', mm, pos + 1)[0]
            body, end = pos + 9, pos + 9 + n
            if end > size:
                self.truncated = True
                break
            if op == _OP_MSG_INDEX and pending is not None:
                cid = unpack('<H', mm, body)[0]
                cnt = unpack('<I', mm, body + 2)[0] // 16
                entries = np.frombuffer(mm, '<u8', count=2 * cnt, offset=body + 6).reshape(cnt, 2)
                indexes[cid] = entries[:, 1].astype(np.int64)
                pos = end
                continue
            if pending is not None:
                if not self._process(mm, pending, indexes):
                    pending = None
                    break
                pending = None
            if op == _OP_CHUNK:
                pending, indexes = body, {}
            elif op == _OP_SCHEMA:
                self._schema(mm, body)
            elif op == _OP_CHANNEL:
                self._channel(mm, body)
            elif op == _OP_MESSAGE:
                cid = unpack('<H', mm, body)[0]
                if cid not in self.channels:
                    raise BagError(f'{self.file}: message on undeclared channel {cid}')
                if self.extractors.get(cid) is not None:
                    loose.setdefault(cid, []).append(pos)
            elif op in (_OP_DATA_END, _OP_FOOTER):
                complete_after_pending = True
                break
            if self.bar is not None and end - last_bar > (1 << 22):
                self.bar.update(end - last_bar)
                last_bar = end
            pos = end
        if pending is not None:   # the file ends right after a chunk's indexes: trust only a walk
            self._process(mm, pending, indexes if complete_after_pending else None)
        if loose:
            arr = np.frombuffer(mm, np.uint8)
            view = memoryview(mm)
            for cid, offs in loose.items():
                self._gather(arr, view, cid, np.array(offs))
            del arr, view
        if self.bar is not None:
            self.bar.update(size - last_bar)


def _concat(parts: list[tuple[np.ndarray, np.ndarray]], width: int) -> tuple[np.ndarray, np.ndarray]:
    if not parts:
        return np.zeros(0, np.int64), np.zeros((0, width))
    t = np.concatenate([p[0] for p in parts])
    v = np.concatenate([p[1] for p in parts])
    order = np.argsort(t, kind='stable')
    return t[order], v[order]


def read_bag_series(path: str | os.PathLike, *, signals: Sequence[SignalSpec] = (),
                    topics: Mapping[str, str] | None = None, stamp: str = 'log',
                    reader: str = 'fast', progress: bool = False) -> BagSeries:
    """Read the wind-up, crank angle, speed and the requested joint-state columns of a bag.

    Args:
        path: rosbag2 directory, directory of .mcap files, or bare .mcap file.
        signals: signals whose topics to read (the crank angle and speed are always read).
        topics: overrides of DEFAULT_TOPICS (keys 'windup', 'joints', 'speed', 'crank').
        stamp: 'log' (receive time, default) or 'publish' time of each message.
        reader: 'fast' (own MCAP walker, falls back to the reference reader when it cannot read
            a file) or 'reference' (dmf_sim.bag.read_messages, decoding every message).
        progress: tqdm progress bar over the bytes read.

    Returns a BagSeries whose ``series`` keys are 'crank', 'speed' and the signal labels.
    """
    if stamp not in ('log', 'publish'):
        raise BagError(f"stamp={stamp!r}: allowed 'log', 'publish'")
    tp = {**DEFAULT_TOPICS, **(topics or {})}
    files, meta = _bag_files(path)
    joint_cols = [(s.field, s.element) for s in signals if s.field is not None]
    scalar_topics = {'crank': tp['crank'], 'speed': tp['speed']}
    for s in signals:
        if s.kind == 'windup':
            scalar_topics[s.label] = tp['windup']
        elif s.kind == 'topic':
            scalar_topics[s.label] = s.element
    t0 = time.perf_counter()
    decoder = _Decoder()
    joint_ext: list[_JointExtractor] = []

    def scalar_factory(msgtype: str) -> _Extractor:
        return _ScalarExtractor(decoder, msgtype)

    def joint_factory(msgtype: str) -> _Extractor:
        ext = _JointExtractor(decoder, msgtype, joint_cols)
        joint_ext.append(ext)
        return ext

    requests: dict[str, Callable] = {t: scalar_factory for t in scalar_topics.values()}
    if joint_cols:
        requests[tp['joints']] = joint_factory
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=sum(f.stat().st_size for f in files), unit='B', unit_scale=True,
                   desc='reading bag', leave=False)
    per_topic: dict[str, list] = {}
    seen: dict[str, str] = {}
    truncated: list[Path] = []
    used = 'fast'
    try:
        if reader not in ('fast', 'reference'):
            raise BagError(f"reader={reader!r}: allowed 'fast', 'reference'")
        try:
            if reader != 'fast':
                raise _Unsupported('reference reader requested')
            for f in files:
                mf = _McapFile(f, requests, decoder, stamp, bar)
                mf.read()
                for topic, parts in mf.out.items():
                    per_topic.setdefault(topic, []).extend(parts)
                for topic, msgtype in mf.channels.values():
                    seen.setdefault(topic, msgtype)
                if mf.truncated:
                    truncated.append(f)
        except _Unsupported:
            used = 'reference'
            joint_ext.clear()
            per_topic, seen, truncated = _read_reference(path, files, requests, stamp)
    finally:
        if bar is not None:
            bar.close()
    series: dict[str, Series] = {}
    for key, topic in scalar_topics.items():
        if per_topic.get(topic):
            t, v = _concat(per_topic[topic], 1)
            series[key] = Series(t, v[:, 0])
    names: list[str] = []
    if joint_cols and per_topic.get(tp['joints']):
        t, v = _concat(per_topic[tp['joints']], len(joint_cols))
        k = 0
        for s in signals:
            if s.field is not None:
                series[s.label] = Series(t, v[:, k])
                k += 1
        names = next((e.names for e in joint_ext if e.names), [])
    if meta is not None:
        for item in meta.get('topics_with_message_count') or []:
            try:
                seen.setdefault(item['topic_metadata']['name'], item['topic_metadata']['type'])
            except (KeyError, TypeError):
                pass
    return BagSeries(series, seen, files, truncated, meta, used, time.perf_counter() - t0, names)


def _read_reference(path, files, requests, stamp):
    """Generic path: dmf_sim.bag.read_messages (decodes every wanted message with rosbags)."""
    from dmf_sim.bag import bag_topics, read_messages

    if stamp == 'publish':
        raise BagError("stamp='publish' needs the fast reader, which cannot read this bag")
    extractors: dict[str, _Extractor] = {}
    rows: dict[str, list] = {}
    times: dict[str, list] = {}
    for m in read_messages(path, list(requests)):
        ext = extractors.get(m.topic)
        if ext is None:
            ext = extractors[m.topic] = requests[m.topic](m.msgtype)
        rows.setdefault(m.topic, []).append(ext.slow(m.msg))
        times.setdefault(m.topic, []).append(m.timestamp_ns)
    per_topic = {t: [(np.array(times[t], np.int64), np.array(rows[t], float))] for t in rows}
    try:
        seen = bag_topics(path)
    except Exception:  # noqa: BLE001 - the topic listing is informative only
        seen = {}
    return per_topic, seen, []


# ================================================================================================
# Crank angle, cycles, bins
# ================================================================================================

def _unwrap(psi: np.ndarray) -> tuple[np.ndarray, bool]:
    """Unwrap a crank angle wrapped at 2 pi or 4 pi (drops of more than pi rad)."""
    d = np.diff(psi)
    drops = d[d < -math.pi]
    if len(drops) == 0:
        return psi, False
    span = float(np.median(-drops))
    period = 4 * math.pi if span > 3 * math.pi else 2 * math.pi
    return np.unwrap(psi, period=period), True


def crank_angle(bag: BagSeries, topics: Mapping[str, str] | None = None) -> tuple[Series, str]:
    """Crank angle [rad] over time from the crank-angle topic, else from integrating the speed.

    Returns (Series, description of the source). Raises ValueError (one line) with neither."""
    crank = bag.series.get('crank')
    if crank is not None and len(crank) >= 2:
        t = crank.t_ns
        keep = np.concatenate(([True], np.diff(t) > 0))
        psi, wrapped = _unwrap(crank.values[keep])
        return Series(t[keep], psi), ('crank angle topic (unwrapped)' if wrapped else 'crank angle topic')
    speed = bag.series.get('speed')
    if speed is not None and len(speed) >= 2:
        t = speed.t_ns
        keep = np.concatenate(([True], np.diff(t) > 0))
        t, rpm = t[keep], speed.values[keep]
        ts = (t - t[0]) * 1e-9
        omega = rpm / RAD_S_TO_RPM
        psi = np.concatenate(([0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) * np.diff(ts))))
        return Series(t, psi), 'integrated engine speed (no crank angle topic)'
    tp = {**DEFAULT_TOPICS, **(topics or {})}
    found = ', '.join(sorted(bag.topics)) or 'none'
    raise BagError(f'the bag has neither a crank angle topic ({tp["crank"]}) nor an engine speed '
                     f'topic ({tp["speed"]}) to resample on; topics found: {found} (use '
                     '--crank-topic/--speed-topic for other names)')


@dataclass
class CycleOrders:
    """Half-order analysis per engine cycle (rows = cycles).

    Attributes:
        t_start, t_end: cycle start/end [s] from the bag's first crank-angle sample.
        psi_start: crank angle at the cycle start [rad] (a multiple of 4 pi).
        speed_rpm: mean speed of the cycle, 120 / duration.
        coeffs: (n_cycles, n_max + 1) complex c_n (NaN above the recording's Nyquist frequency).
        mean, max_deviation, min_deviation: per cycle, in the signal's unit.
    """

    t_start: np.ndarray
    t_end: np.ndarray
    psi_start: np.ndarray
    speed_rpm: np.ndarray
    coeffs: np.ndarray
    mean: np.ndarray
    max_deviation: np.ndarray
    min_deviation: np.ndarray

    def __len__(self) -> int:
        return len(self.speed_rpm)


def _segments(mask_breaks: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges [a, b) between break positions (break i sits between samples i and i+1)."""
    cuts = np.flatnonzero(mask_breaks) + 1
    bounds = np.concatenate(([0], cuts, [len(mask_breaks) + 1]))
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


def _psi_at(ts: np.ndarray, tc: np.ndarray, psi_c: np.ndarray) -> tuple[np.ndarray, int]:
    """Crank angle at the signal time stamps ``ts`` [s] from crank samples (tc, psi_c).

    Linear interpolation in time, except where the signal and the crank angle are sampled
    together (same rate, e.g. the node publishes both per simulation sample) but their stamps
    differ by receive-time jitter (``ros2 bag record`` log times): then a signal sample takes the
    crank angle of the crank sample nearest in time, when that one is within 30 % of the sample
    interval -- interpolating between jittered stamps would add phase noise. Returns (psi, number
    of paired samples)."""
    psi = np.interp(ts, tc, psi_c)
    if len(ts) < 3 or len(tc) < 3:
        return psi, 0
    dt_s, dt_c = float(np.median(np.diff(ts))), float(np.median(np.diff(tc)))
    if not (dt_c > 0 and abs(dt_s / dt_c - 1.0) < 0.01):
        return psi, 0
    j = np.clip(np.searchsorted(tc, ts), 1, len(tc) - 1)
    j -= (ts - tc[j - 1]) < (tc[j] - ts)
    dist = np.abs(ts - tc[j])
    if np.median(dist) > 0.1 * dt_c or not dist.any():
        return psi, 0          # identical stamps (interpolation is exact) or a real time offset
    near = dist < 0.3 * dt_c
    psi[near] = psi_c[j[near]]
    return psi, int(near.sum())


def cycle_orders(t_ns: np.ndarray, x: np.ndarray, crank: Series, *, points_per_cycle: int = 256,
                 n_max: int = 24, t0_ns: int | None = None) -> CycleOrders:
    """Resample ``x(t)`` on the crank angle and compute the half orders of every whole cycle.

    ``t_ns``: signal time stamps [ns] (sorted); ``crank``: crank angle series (psi increasing).
    """
    from scipy.interpolate import CubicSpline

    if points_per_cycle < 2 * n_max + 2:
        raise BagError(f'points_per_cycle={points_per_cycle} must be >= 2 n_max + 2 = {2 * n_max + 2}')
    t0 = int(crank.t_ns[0] if t0_ns is None else t0_ns)
    tc = (crank.t_ns - t0) * 1e-9
    psi_c = crank.values
    ts = (np.asarray(t_ns) - t0) * 1e-9
    x = np.asarray(x, dtype=float)
    finite = np.isfinite(x)
    inside = finite & (ts >= tc[0]) & (ts <= tc[-1])
    ts, x = ts[inside], x[inside]
    empty = CycleOrders(*(np.zeros(0) for _ in range(4)), np.zeros((0, n_max + 1), complex),
                        np.zeros(0), np.zeros(0), np.zeros(0))
    if len(ts) < 4:
        return empty
    # gaps: of the signal, or of the crank angle around a signal sample
    dts = np.diff(ts)
    dtc = np.diff(tc)
    thr_s = GAP_FACTOR * float(np.median(dts)) if len(dts) else 0.0
    thr_c = GAP_FACTOR * float(np.median(dtc)) if len(dtc) else 0.0
    j = np.clip(np.searchsorted(tc, ts, side='right') - 1, 0, len(tc) - 2)
    crank_gap = dtc[j] > thr_c
    psi, _ = _psi_at(ts, tc, psi_c)
    breaks = (dts > thr_s) | (np.diff(psi) <= 0) | crank_gap[1:] | crank_gap[:-1]
    fs = 1.0 / float(np.median(dts)) if len(dts) else 0.0
    P = int(points_per_cycle)
    grid = np.arange(P) * (CYCLE_RAD / P)
    rows = []
    for a, b in _segments(breaks):
        if b - a < 4:
            continue
        ps, xs, tseg = psi[a:b], x[a:b], ts[a:b]
        k0 = math.ceil(ps[0] / CYCLE_RAD - 1e-12)
        k1 = math.floor(ps[-1] / CYCLE_RAD + 1e-12)
        if k1 <= k0:
            continue
        starts = np.arange(k0, k1) * CYCLE_RAD
        pts = (starts[:, None] + grid).ravel()
        spline = CubicSpline(ps, xs)
        samples = spline(pts).reshape(len(starts), P)
        edges = np.concatenate((starts, [k1 * CYCLE_RAD]))
        t_edges = np.interp(edges, ps, tseg)
        rows.append((starts, t_edges[:-1], t_edges[1:], samples))
    if not rows:
        return empty
    starts = np.concatenate([r[0] for r in rows])
    t_start = np.concatenate([r[1] for r in rows])
    t_end = np.concatenate([r[2] for r in rows])
    samples = np.concatenate([r[3] for r in rows])
    speed = 120.0 / (t_end - t_start)
    X = np.fft.rfft(samples, axis=1) / P
    c = 2.0 * X[:, :n_max + 1]
    c[:, 0] = X[:, 0].real
    # Nyquist of the recording: half-order n is fine while n/2 * speed/60 < fs/2
    if fs > 0:
        n = np.arange(n_max + 1)
        c[n[None, :] * speed[:, None] / 120.0 >= fs / 2.0] = np.nan
    mean = samples.mean(axis=1)
    return CycleOrders(t_start, t_end, starts, speed, c, mean, samples.max(axis=1) - mean,
                       samples.min(axis=1) - mean)


@dataclass
class OrderTable:
    """Order amplitudes and Fig. 13 quantities over engine speed (rows = speed bins or cycles).

    Attributes:
        speed_rpm: bin centre (or cycle speed); speed_mean_rpm: mean cycle speed in the bin.
        n_cycles: cycles in the row.
        amplitudes: (rows, n_max + 1) |c_n| (mean over the row's cycles), n = 0 is |mean|.
        order_3, order_1_5: amplitude of the 3rd and 1.5th engine order.
        max_deviation, min_deviation, mean: Fig. 13 quantities (means over the row's cycles).
        mean_minus_theta: mean - theta (DMF wind-up only, else None).
    """

    speed_rpm: np.ndarray
    speed_mean_rpm: np.ndarray
    n_cycles: np.ndarray
    amplitudes: np.ndarray
    max_deviation: np.ndarray
    min_deviation: np.ndarray
    mean: np.ndarray
    theta: float | None = None

    @property
    def order_3(self) -> np.ndarray:
        return self.amplitudes[:, 6]

    @property
    def order_1_5(self) -> np.ndarray:
        return self.amplitudes[:, 3]

    @property
    def mean_minus_theta(self) -> np.ndarray | None:
        return None if self.theta is None else self.mean - self.theta

    def __len__(self) -> int:
        return len(self.speed_rpm)

    @property
    def orders(self) -> np.ndarray:
        return np.arange(self.amplitudes.shape[1]) / 2.0


def bin_cycles(cycles: CycleOrders, bin_rpm: float, theta: float | None = None) -> OrderTable:
    """Group cycles into speed bins ``bin_rpm`` wide (centres at multiples of it); 0: per cycle."""
    amp = np.abs(cycles.coeffs)
    if bin_rpm <= 0 or len(cycles) == 0:
        return OrderTable(cycles.speed_rpm.copy(), cycles.speed_rpm.copy(),
                          np.ones(len(cycles), int), amp, cycles.max_deviation.copy(),
                          cycles.min_deviation.copy(), cycles.mean.copy(), theta)
    idx = np.floor(cycles.speed_rpm / bin_rpm + 0.5).astype(np.int64)
    uniq, inv, counts = np.unique(idx, return_inverse=True, return_counts=True)

    def mean_of(v: np.ndarray) -> np.ndarray:
        out = np.zeros((len(uniq),) + v.shape[1:])
        np.add.at(out, inv, v)
        return out / counts.reshape((-1,) + (1,) * (v.ndim - 1))

    return OrderTable(uniq * float(bin_rpm), mean_of(cycles.speed_rpm), counts, mean_of(amp),
                      mean_of(cycles.max_deviation), mean_of(cycles.min_deviation),
                      mean_of(cycles.mean), theta)


# ================================================================================================
# Whole analysis
# ================================================================================================

@dataclass
class HBMOverlay:
    """HBM prediction on the measured speeds and its difference from the measurement.

    Attributes:
        speed_rpm: speeds the HBM was solved at (the table's rows).
        order_3, order_1_5, max_deviation, min_deviation, mean_minus_theta: HBM values there.
        stable: Floquet stability of each point (None if not computed).
        curve: optional finer HBM curve for plotting (dict of arrays, may hold several branches).
        difference: per order / quantity: max_abs, rms_abs [rad], max_rel (max |meas-hbm| over the
            HBM peak of that quantity), at_speed_rpm (speed of max_abs).
        settings: model, alpha, load, load_set used; seconds: wall time.
    """

    speed_rpm: np.ndarray
    values: dict[str, np.ndarray]
    stable: np.ndarray | None
    curve: dict[str, Any] | None
    difference: dict[str, dict[str, float]]
    settings: dict[str, Any]
    seconds: float
    method: str = ''
    branch: np.ndarray | None = None
    events: list = field(default_factory=list)


@dataclass
class SignalAnalysis:
    """One analysed signal."""

    signal: SignalSpec
    cycles: CycleOrders
    table: OrderTable
    n_samples: int
    hbm: HBMOverlay | None = None


@dataclass
class BagAnalysis:
    """Result of :func:`analyze_bag`."""

    bag: Path
    crank_source: str
    signals: list[SignalAnalysis]
    bin_rpm: float
    n_max: int
    points_per_cycle: int
    sample_rate_hz: float
    duration_s: float
    topics: dict[str, str]
    truncated: bool
    reader: str
    read_seconds: float
    analyze_seconds: float
    theta: float | None
    joint_names: list[str]
    metadata: dict | None
    warnings: list[str] = field(default_factory=list)

    def signal(self, label: str = 'windup') -> SignalAnalysis:
        for s in self.signals:
            if s.signal.label == label:
                return s
        raise KeyError(label)


def analyze_bag(path: str | os.PathLike, signals: Iterable[str | SignalSpec] = ('windup',), *,
                bin_rpm: float = 20.0, points_per_cycle: int = 256, n_max: int = 24,
                theta: float | None = None, topics: Mapping[str, str] | None = None,
                stamp: str = 'log', reader: str = 'fast', progress: bool = False,
                start_s: float | None = None, end_s: float | None = None) -> BagAnalysis:
    """Order analysis of a bag (see module docstring).

    Args:
        path: the bag.
        signals: 'windup', 'angle:NAME', 'velocity:NAME', 'torque:NAME', 'topic:/name'.
        bin_rpm: speed bin width [rpm]; 0 gives one row per engine cycle.
        points_per_cycle: crank-angle grid per 720 deg cycle; n_max: highest half-order index.
        theta: DMF stiffness change angle [rad] for 'mean minus theta' of the wind-up (None: not
            reported).
        topics, stamp, reader, progress: see :func:`read_bag_series`.
        start_s, end_s: keep only cycles within this time window [s from the first crank-angle
            sample] (e.g. to skip a start-up transient).
    """
    t_start = time.perf_counter()
    specs = [s if isinstance(s, SignalSpec) else SignalSpec.parse(s) for s in signals]
    if not specs:
        raise BagError('no signal requested')
    labels = [s.label for s in specs]
    if len(set(labels)) != len(labels):
        raise BagError(f'signal requested twice: {labels}')
    bag = read_bag_series(path, signals=specs, topics=topics, stamp=stamp, reader=reader,
                          progress=progress)
    crank, source = crank_angle(bag, topics)
    warnings = []
    if bag.truncated:
        warnings.append(f'truncated bag (recorder crashed?): read up to the last complete chunk of '
                        f'{", ".join(f.name for f in bag.truncated)}')
    tp = {**DEFAULT_TOPICS, **(topics or {})}
    out = []
    rates = []
    for spec in specs:
        s = bag.series.get(spec.label)
        if s is None or len(s) == 0:
            topic = {'windup': tp['windup'], 'topic': spec.element}.get(spec.kind, tp['joints'])
            raise BagError(f'signal {spec.label!r}: topic {topic} is not in the bag (or empty); '
                             f'topics found: {", ".join(sorted(bag.topics)) or "none"}')
        cyc = cycle_orders(s.t_ns, s.values, crank, points_per_cycle=points_per_cycle, n_max=n_max,
                           t0_ns=int(crank.t_ns[0]))
        if start_s is not None or end_s is not None:
            keep = np.ones(len(cyc), bool)
            if start_s is not None:
                keep &= cyc.t_start >= start_s
            if end_s is not None:
                keep &= cyc.t_end <= end_s
            cyc = CycleOrders(*(getattr(cyc, f.name)[keep] for f in fields(CycleOrders)))
        if len(cyc) == 0:
            raise BagError(f'signal {spec.label!r}: no whole engine cycle (720 deg of crank '
                             'angle) recorded with the signal'
                             + (' in the time window' if start_s is not None or end_s is not None else ''))
        if len(s) > 1:
            rates.append(1e9 / float(np.median(np.diff(s.t_ns))))
        table = bin_cycles(cyc, bin_rpm, theta if spec.kind == 'windup' else None)
        out.append(SignalAnalysis(spec, cyc, table, len(s)))
    dur = float(crank.t_ns[-1] - crank.t_ns[0]) * 1e-9
    return BagAnalysis(Path(path), source, out, float(bin_rpm), int(n_max), int(points_per_cycle),
                       float(min(rates)) if rates else float('nan'), dur, bag.topics,
                       bool(bag.truncated), bag.reader, bag.read_seconds,
                       time.perf_counter() - t_start, theta, bag.joint_names, bag.metadata, warnings)


# ================================================================================================
# Model-side quantities: natural frequencies, HBM overlay
# ================================================================================================

def natural_frequencies(model) -> dict[str, list[float]]:
    """Linear natural frequencies [Hz] (rigid-body mode excluded) at primary and secondary DMF
    stiffness (modal.modes)."""
    from dmf_sim.modal import REGIONS, modes

    regions = REGIONS if model.spring is not None else ('primary',)
    out = {}
    for r in regions:
        f = modes(model, r).frequencies_hz
        out[r] = [float(v) for v in f if v > 1e-6]
    return out


COMPARED = ('order_3', 'order_1_5', 'max_deviation', 'min_deviation', 'mean_minus_theta')


def model_settings(metadata: Mapping[str, Any] | None = None, *, config: str | None = None,
                   engine: str | None = None, alpha: float | None = None,
                   theta: float | None = None, load: float | None = None,
                   load_set: str | None = None) -> dict[str, Any]:
    """Model settings for the modes and the HBM: explicit options first, then what the recording
    node stored in the bag's ``custom_data`` (``dmf_sim.driveline``, ``dmf_sim.engine``,
    ``dmf_sim.alpha``, ``dmf_sim.theta_rad``, ``dmf_sim.load_set``, ``dmf_sim.load``), then the
    defaults (truck_dmf, engine_d13, the YAML's alpha and theta, load 1.0, load set A).
    ``sources`` tells where each value came from."""
    from dmf_sim.model import load_driveline

    stored = RunMetadata.from_bag_metadata(metadata)
    out: dict[str, Any] = {}
    src: dict[str, str] = {}

    def pick(key: str, given, default):
        if given is not None:
            out[key], src[key] = given, 'option'
        elif getattr(stored, key) is not None:
            out[key], src[key] = getattr(stored, key), 'bag'
        else:
            out[key], src[key] = default, 'default'

    pick('driveline', config, 'truck_dmf')
    pick('engine', engine, 'engine_d13')
    pick('load_set', load_set, 'A')
    pick('load', load, 1.0)
    pick('alpha', alpha, None)
    pick('theta_rad', theta, None)
    try:
        line = load_driveline(out['driveline'])
    except (OSError, ValueError) as exc:
        where = 'stored in the bag' if src['driveline'] == 'bag' else 'given'
        raise BagError(f'driveline {out["driveline"]!r} ({where}) cannot be loaded: {exc}; '
                         'pass --config') from None
    if line.dmf is not None:
        if out['alpha'] is None:
            out['alpha'], src['alpha'] = line.dmf.alpha, 'driveline YAML'
        if out['theta_rad'] is None:
            out['theta_rad'], src['theta_rad'] = line.dmf.theta, 'driveline YAML'
    out['sources'] = src
    return out


def _build_model(settings: Mapping[str, Any]):
    from dmf_sim.model import load_model

    has_dmf = settings.get('theta_rad') is not None
    return load_model(settings['driveline'], alpha=settings['alpha'] if has_dmf else None,
                      theta=settings['theta_rad'] if has_dmf else None)


def _ramp_direction(cycles: CycleOrders) -> int:
    """+1 if the speed mostly rises over the recording, -1 if it falls."""
    if len(cycles) < 2 or np.ptp(cycles.t_start) == 0:
        return 1
    slope = np.polyfit(cycles.t_start, cycles.speed_rpm, 1)[0]
    return 1 if slope >= 0 else -1


def _differences(meas: Mapping[str, np.ndarray], pred: Mapping[str, np.ndarray],
                 speed: np.ndarray) -> dict[str, dict[str, float]]:
    out = {}
    for k in COMPARED:
        if k not in meas or meas[k] is None or k not in pred:
            continue
        m, p = np.asarray(meas[k], float), np.asarray(pred[k], float)
        ok = np.isfinite(m) & np.isfinite(p)
        if not ok.any():
            continue
        d = m[ok] - p[ok]
        i = int(np.argmax(np.abs(d)))
        peak = float(np.max(np.abs(p[ok])))
        out[k] = {'max_abs': float(abs(d[i])), 'at_speed_rpm': float(speed[ok][i]),
                  'rms_abs': float(np.sqrt(np.mean(d ** 2))), 'mean_diff': float(np.mean(d)),
                  'hbm_peak': peak, 'rel_to_peak': float(abs(d[i]) / peak) if peak > 0 else float('nan'),
                  'n_rows': int(ok.sum())}
    return out


_HBM_KEYS = ('order_3', 'order_1_5', 'max_deviation', 'min_deviation', 'mean_minus_theta', 'mean')


def _branch_candidates(branches, speed: float) -> list[dict[str, Any]]:
    """Every solution of the swept branches at ``speed`` (linear interpolation between the two
    continuation points around it; a branch folding back gives several)."""
    out = []
    for b in branches:
        pts = b.points
        for p, q in zip(pts[:-1], pts[1:]):
            s0, s1 = p.speed_rpm, q.speed_rpm
            if not (min(s0, s1) <= speed <= max(s0, s1)) or s0 == s1:
                continue
            f = (speed - s0) / (s1 - s0)
            d0, d1 = p.summary.as_dict(), q.summary.as_dict()
            cand = {k: (1 - f) * d0[k] + f * d1[k] for k in _HBM_KEYS}
            near = p if f < 0.5 else q
            cand['stable'] = near.stable
            cand['branch'] = b.id
            out.append(cand)
        if len(pts) == 1 and abs(pts[0].speed_rpm - speed) < 1e-6:
            d = pts[0].summary.as_dict()
            out.append({**{k: d[k] for k in _HBM_KEYS}, 'stable': pts[0].stable, 'branch': b.id})
    return out


def _pick(cands: list[dict[str, Any]], meas: Mapping[str, float]) -> dict[str, Any]:
    """The stable candidate (any candidate if none is stable) nearest to the measurement in the
    3rd and 1.5th order amplitudes and the mean wind-up."""
    stable = [c for c in cands if c['stable'] is not False]
    pool = stable or cands

    def dist(c):
        tot = 0.0
        for k in ('order_3', 'order_1_5', 'mean'):
            m = meas.get(k)
            if m is not None and math.isfinite(m):
                tot += (c[k] - m) ** 2
        return tot

    return min(pool, key=dist)


def hbm_overlay(table: OrderTable, loads, load: float, *, direction: int = 1,
                settings: Mapping[str, Any] | None = None, step_rpm: float = 10.0,
                use_sweep: bool = True) -> HBMOverlay:
    """Harmonic-balance prediction of the DMF wind-up for the same model, engine, load set and
    load over the measured speed range, and its difference from the measurement per Fig. 13
    quantity.

    The HBM is swept over the measured range with :func:`dmf_sim.hbm.sweep` (pseudo-arc-length
    continuation, Floquet stability, 1.5th-order branches). At each measured speed the stable
    solutions there are candidates; where several coexist, the one nearest to the measurement (3rd
    and 1.5th order amplitude, mean) is compared -- which one a run-up lands on depends on its
    history, not on the speed alone. Speeds no swept branch covers are solved by natural
    continuation along the recording's ramp direction (``direction`` +1 rising, -1 falling), each
    from the previous solution. Rows outside the engine data's speed range are NaN.
    """
    from dmf_sim import hbm as hbm_mod

    t0 = time.perf_counter()
    rows = np.asarray(table.speed_mean_rpm, float)
    lo, hi = float(np.nanmin(rows)), float(np.nanmax(rows))
    rng = getattr(loads.engine, 'speed_range_rpm', None)
    if rng is not None:
        lo, hi = max(lo, float(rng[0])), min(hi, float(rng[1]))
    values = {k: np.full(len(rows), np.nan) for k in _HBM_KEYS}
    stable = np.full(len(rows), None, dtype=object)
    branch = np.full(len(rows), -1)
    curve: dict[str, list] = {k: [] for k in ('speed_rpm', 'branch', 'stable') + _HBM_KEYS}
    method = []
    events = []
    meas = {'order_3': table.order_3, 'order_1_5': table.order_1_5, 'mean': table.mean}
    if hi <= lo:
        hi = lo + 1e-9
    swept = None
    if use_sweep and hasattr(hbm_mod, 'sweep'):
        try:
            opts = hbm_mod.SweepOptions(step_rpm=step_rpm)
            swept = hbm_mod.sweep(loads, load, (math.floor(lo), math.ceil(hi)), options=opts)
            method.append('condensed HBM sweep (pseudo-arc-length continuation, Floquet stability, '
                          '1.5th-order branch switching)')
            events = [e.as_dict() for e in swept.events]
            for b in swept.branches:
                for p in b.points:
                    curve['speed_rpm'].append(float(p.speed_rpm))
                    curve['branch'].append(int(b.id))
                    curve['stable'].append(None if p.stable is None else bool(p.stable))
                    d = p.summary.as_dict()
                    for k in _HBM_KEYS:
                        curve[k].append(float(d[k]))
        except (hbm_mod.ConvergenceError, np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:
            method.append(f'sweep failed ({type(exc).__name__}: {exc})')
            swept = None
    if swept is not None:
        for i, s in enumerate(rows):
            if not lo - 1e-9 <= s <= hi + 1e-9:
                continue
            cands = _branch_candidates(swept.branches, float(s))
            if not cands:
                continue
            c = _pick(cands, {k: float(v[i]) for k, v in meas.items()})
            for k in _HBM_KEYS:
                values[k][i] = c[k]
            stable[i] = c['stable']
            branch[i] = c['branch']
    missing = [i for i in range(len(rows)) if lo - 1e-9 <= rows[i] <= hi + 1e-9
               and not math.isfinite(values['order_3'][i])]
    if missing:
        solver = hbm_mod.CondensedHBM(loads, load)
        order = sorted(missing, key=lambda i: rows[i] * (1 if direction >= 0 else -1))
        x = None
        for i in order:
            try:
                pt = solver.solve(float(rows[i]), x)
            except (hbm_mod.ConvergenceError, np.linalg.LinAlgError, FloatingPointError):
                try:
                    pt = solver.solve(float(rows[i]))
                except (hbm_mod.ConvergenceError, np.linalg.LinAlgError, FloatingPointError):
                    x = None
                    continue
            x = pt.x
            d = pt.summary.as_dict()
            for k in _HBM_KEYS:
                values[k][i] = d[k]
        method.append(f'natural continuation along the ramp for {len(missing)} speeds')
        if swept is None:
            ok = np.isfinite(values['order_3'])
            curve = {'speed_rpm': rows[ok].tolist(), 'branch': [0] * int(ok.sum()),
                     'stable': [None] * int(ok.sum()),
                     **{k: values[k][ok].tolist() for k in _HBM_KEYS}}
    diff = _differences({**meas, 'max_deviation': table.max_deviation,
                         'min_deviation': table.min_deviation,
                         'mean_minus_theta': table.mean_minus_theta}, values, rows)
    st = dict(settings or {})
    st.update(load=float(load), speed_range_rpm=[lo, hi])
    ov = HBMOverlay(rows, values, stable, curve, diff, st, time.perf_counter() - t0,
                    method='; '.join(method))
    ov.branch = branch
    ov.events = events
    return ov


def overlay_all(res: BagAnalysis, settings: Mapping[str, Any], *, hbm: bool = True) -> dict[str, list[float]]:
    """Natural frequencies of the model (returned) and, with ``hbm``, the HBM overlay on every
    wind-up signal of ``res`` (set in place; other signals get a warning)."""
    model = _build_model(settings)
    natural = natural_frequencies(model)
    if not hbm:
        return natural
    if model.spring is None:
        res.warnings.append(f'driveline {settings["driveline"]!r} has no DMF: no HBM overlay')
        return natural
    loads = None
    for sig in res.signals:
        if sig.signal.kind != 'windup':
            res.warnings.append(f'HBM overlay is computed for the DMF wind-up only, not for '
                                f'{sig.signal.label}')
            continue
        if loads is None:
            from dmf_sim.engine import load_engine
            from dmf_sim.loads import DrivelineLoads
            loads = DrivelineLoads(model, load_engine(settings['engine'], load_set=settings['load_set']))
        keep = ('driveline', 'engine', 'alpha', 'theta_rad', 'load_set')
        sig.hbm = hbm_overlay(sig.table, loads, settings['load'],
                              direction=_ramp_direction(sig.cycles),
                              settings={k: settings[k] for k in keep})
    if settings.get('sources', {}).get('load') == 'default' and any(s.hbm for s in res.signals):
        res.warnings.append('the bag does not record the engine load: HBM at load 1.0 (set --load)')
    return natural


# ================================================================================================
# Output: JSON, CSV, plots
# ================================================================================================

def _f(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def to_jsonable(obj: Any) -> Any:
    """Recursively convert numpy values to JSON types (NaN/inf -> None)."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [to_jsonable(v) for v in obj.tolist()]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return _f(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj


def table_rows(sig: SignalAnalysis) -> list[dict[str, Any]]:
    """Rows (dicts) of a signal's table, as written to CSV/JSON."""
    t = sig.table
    rows = []
    mmt = t.mean_minus_theta
    for i in range(len(t)):
        row = {'speed_rpm': float(t.speed_rpm[i]), 'speed_mean_rpm': float(t.speed_mean_rpm[i]),
               'n_cycles': int(t.n_cycles[i]),
               'order_3': _f(t.order_3[i]), 'order_1_5': _f(t.order_1_5[i]),
               'max_deviation': _f(t.max_deviation[i]), 'min_deviation': _f(t.min_deviation[i]),
               'mean': _f(t.mean[i]),
               'mean_minus_theta': None if mmt is None else _f(mmt[i]),
               'amplitudes': [_f(a) for a in t.amplitudes[i]]}
        if sig.hbm is not None:
            for k, v in sig.hbm.values.items():
                row[f'hbm_{k}'] = _f(v[i])
            if sig.hbm.stable is not None:
                row['hbm_stable'] = None if sig.hbm.stable[i] is None else bool(sig.hbm.stable[i])
            if sig.hbm.branch is not None:
                row['hbm_branch'] = int(sig.hbm.branch[i])
        rows.append(row)
    return rows


def analysis_dict(res: BagAnalysis, extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The whole analysis as one JSON-ready dict (what ``dmf-sim analyze --json`` prints)."""
    signals = {}
    for sig in res.signals:
        d = {'signal': sig.signal.label, 'description': sig.signal.description,
             'unit': sig.signal.unit, 'samples': sig.n_samples, 'cycles': len(sig.cycles),
             'rows': table_rows(sig)}
        if sig.hbm is not None:
            h = sig.hbm
            d['hbm'] = {'method': h.method, 'settings': dict(h.settings), 'seconds': h.seconds,
                        'difference': h.difference, 'events': h.events, 'curve': h.curve}
        signals[sig.signal.label] = d
    out = {
        'bag': str(res.bag), 'reader': res.reader, 'truncated': res.truncated,
        'crank_angle_source': res.crank_source, 'duration_s': res.duration_s,
        'sample_rate_hz': res.sample_rate_hz,
        'mode': 'bins' if res.bin_rpm > 0 else 'cycles', 'bin_rpm': res.bin_rpm,
        'points_per_cycle': res.points_per_cycle, 'n_max': res.n_max,
        'orders': [n / 2 for n in range(res.n_max + 1)], 'theta_rad': res.theta,
        'read_seconds': res.read_seconds, 'analyze_seconds': res.analyze_seconds,
        'warnings': list(res.warnings), 'signals': signals,
    }
    if extra:
        out.update(extra)
    return to_jsonable(out)


def write_csv(sig: SignalAnalysis, path: Path) -> Path:
    """One row per speed bin (or cycle): speed, Fig. 13 quantities, HBM columns, all half orders."""
    import csv

    rows = table_rows(sig)
    orders = [f'o{n / 2:g}' for n in range(sig.table.amplitudes.shape[1])]
    fixed = [k for k in rows[0] if k != 'amplitudes'] if rows else []
    with open(path, 'w', newline='') as fh:
        w = csv.writer(fh)
        w.writerow(fixed + orders)
        for r in rows:
            w.writerow([('' if r[k] is None else r[k]) for k in fixed]
                       + [('' if a is None else a) for a in r['amplitudes']])
    return path


def write_cycles_csv(sig: SignalAnalysis, path: Path) -> Path:
    """Every engine cycle: start/end time, crank angle, speed, Fig. 13 quantities, |c_n|."""
    import csv

    c = sig.cycles
    amp = np.abs(c.coeffs)
    with open(path, 'w', newline='') as fh:
        w = csv.writer(fh)
        w.writerow(['t_start_s', 't_end_s', 'psi_start_rad', 'speed_rpm', 'mean', 'max_deviation',
                    'min_deviation'] + [f'o{n / 2:g}' for n in range(amp.shape[1])])
        for i in range(len(c)):
            w.writerow([f'{c.t_start[i]:.6f}', f'{c.t_end[i]:.6f}', f'{c.psi_start[i]:.6f}',
                        f'{c.speed_rpm[i]:.4f}', f'{c.mean[i]:.8g}', f'{c.max_deviation[i]:.8g}',
                        f'{c.min_deviation[i]:.8g}']
                       + [('' if not math.isfinite(a) else f'{a:.8g}') for a in amp[i]])
    return path


def plot_campbell(res: BagAnalysis, sig: SignalAnalysis, path: Path,
                  natural: Mapping[str, Sequence[float]] | None = None,
                  engine_orders: Sequence[float] = (1.5, 3.0, 4.5, 6.0, 9.0)) -> Path:
    """Campbell diagram (frequency over speed, half orders as dots sized by amplitude, engine
    orders and linear natural frequencies as lines) beside an order waterfall (colour map)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    t = sig.table
    amp = t.amplitudes[:, 1:]
    orders = t.orders[1:]
    speeds = t.speed_rpm
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(14, 6), gridspec_kw={'width_ratios': [1.25, 1]})
    finite = amp[np.isfinite(amp)]
    top = float(finite.max()) if finite.size else 1.0
    fmax_plot = min(res.sample_rate_hz / 2 if math.isfinite(res.sample_rate_hz) else np.inf,
                    orders[-1] * speeds.max() / 60.0 * 1.05)
    S, O = np.meshgrid(speeds, orders, indexing='ij')
    F = O * S / 60.0
    ok = np.isfinite(amp) & (amp > 1e-4 * top)
    sc = ax.scatter(S[ok], F[ok], s=4 + 120 * (amp[ok] / top), c=amp[ok], cmap='viridis',
                    norm=LogNorm(vmin=max(1e-3 * top, 1e-300), vmax=top), alpha=0.8, lw=0)
    fig.colorbar(sc, ax=ax, label=f'half-order amplitude [{sig.signal.unit}]')
    rpm = np.array([speeds.min(), speeds.max()])
    for o in engine_orders:
        ax.plot(rpm, o * rpm / 60.0, 'k--', lw=0.7)
        ax.annotate(f'{o:g}', (rpm[-1], o * rpm[-1] / 60.0), fontsize=8, xytext=(2, 0),
                    textcoords='offset points', va='center')
    styles = {'primary': ('tab:blue', '-'), 'secondary': ('tab:red', ':')}
    for region, freqs in (natural or {}).items():
        color, ls = styles.get(region, ('gray', '-.'))
        first = True
        for f in freqs:
            if f <= fmax_plot:
                ax.axhline(f, color=color, ls=ls, lw=1,
                           label=f'natural frequency, DMF {region} stiffness' if first else None)
                first = False
    ax.set_xlim(speeds.min() - 10, speeds.max() + 10)
    ax.set_ylim(0, fmax_plot)
    ax.set_xlabel('engine speed [rpm]')
    ax.set_ylabel('frequency [Hz]')
    ax.set_title(f'Campbell diagram: {sig.signal.description}')
    if natural:
        ax.legend(loc='upper left', fontsize=8)
    ax.grid(alpha=0.3)
    # waterfall: order x speed colour map
    a2 = np.where(np.isfinite(amp) & (amp > 0), amp, np.nan)
    if len(speeds) > 1:
        edges_s = np.concatenate(([speeds[0] - (speeds[1] - speeds[0]) / 2],
                                  (speeds[1:] + speeds[:-1]) / 2,
                                  [speeds[-1] + (speeds[-1] - speeds[-2]) / 2]))
    else:
        edges_s = np.array([speeds[0] - 1, speeds[0] + 1])
    edges_o = np.concatenate(([orders[0] - 0.25], orders + 0.25))
    m = ax2.pcolormesh(edges_o, edges_s, a2, cmap='magma',
                       norm=LogNorm(vmin=max(1e-3 * top, 1e-300), vmax=top), shading='flat')
    fig.colorbar(m, ax=ax2, label=f'amplitude [{sig.signal.unit}]')
    ax2.set_xlabel('engine order')
    ax2.set_ylabel('engine speed [rpm]')
    ax2.set_title('order waterfall')
    fig.suptitle(f'{res.bag.name}: {sig.signal.description} ({res.crank_source})', fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_fig13(res: BagAnalysis, sig: SignalAnalysis, path: Path) -> Path:
    """The paper's Fig. 13 quantities over speed: 3rd and 1.5th order, max/min deviation, mean
    minus theta (or mean), measured (markers) with the HBM prediction (lines) if present."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    t = sig.table
    unit = sig.signal.unit
    fig, axes = plt.subplots(2, 2, figsize=(12, 8), sharex=True)
    mmt = t.mean_minus_theta
    panels = [('order_3', '3rd order', t.order_3), ('order_1_5', '1.5th order', t.order_1_5),
              ('deviation', 'max / min deviation', None),
              ('mean_minus_theta' if mmt is not None else 'mean',
               'mean - theta' if mmt is not None else 'mean', mmt if mmt is not None else t.mean)]
    h = sig.hbm
    curve = h.curve if h is not None else None
    for ax, (key, title, y) in zip(axes.ravel(), panels):
        if key == 'deviation':
            ax.plot(t.speed_rpm, t.max_deviation, 'o', ms=3, color='tab:blue', label='measured max')
            ax.plot(t.speed_rpm, t.min_deviation, 'o', ms=3, color='tab:orange', label='measured min')
        else:
            ax.plot(t.speed_rpm, y, 'o', ms=3, color='tab:blue', label='measured (bag)')
        if h is not None:
            keys = ['max_deviation', 'min_deviation'] if key == 'deviation' else [key]
            for k in keys:
                if curve is not None and k in curve and len(curve[k]):
                    sp = np.asarray(curve['speed_rpm'], float)
                    yy = np.asarray(curve[k], float)
                    st = list(curve.get('stable') or [None] * len(sp))
                    br = np.asarray(curve.get('branch') or [0] * len(sp))
                    known = any(v is not None for v in st)
                    unstable = np.array([v is False for v in st])
                    for j, b in enumerate(np.unique(br)):
                        sel = br == b
                        yb = np.where(~unstable[sel], yy[sel], np.nan)
                        yu = np.where(unstable[sel], yy[sel], np.nan)
                        first = j == 0 and k == keys[0]
                        ax.plot(sp[sel], yb, '-', color='k', lw=1.2,
                                label=('HBM (stable)' if known else 'HBM') if first else None)
                        if np.isfinite(yu).any():
                            ax.plot(sp[sel], yu, ':', color='tab:red', lw=1,
                                    label='HBM (unstable)' if first else None)
                elif k in h.values:
                    ax.plot(h.speed_rpm, h.values[k], '-', color='k', lw=1.2,
                            label='HBM' if k == keys[0] else None)
        ax.set_title(title)
        ax.set_ylabel(f'[{unit}]')
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel('engine speed [rpm]')
    sub = f'{res.bag.name}: {sig.signal.description}'
    if h is not None:
        s = h.settings
        sub += f" vs HBM (alpha={s.get('alpha')}, load={s.get('load')}, load set {s.get('load_set')})"
    fig.suptitle(sub + ' (paper Fig. 13 quantities)', fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_outputs(res: BagAnalysis, out: Path, *, natural: Mapping[str, Sequence[float]] | None = None,
                  plots: bool = True, extra: Mapping[str, Any] | None = None) -> list[Path]:
    """Write ``analysis.json`` and per signal ``<slug>_orders.csv``, ``<slug>_cycles.csv``,
    ``<slug>_campbell.png``, ``<slug>_fig13.png`` into ``out``."""
    import json

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    data = analysis_dict(res, extra)
    p = out / 'analysis.json'
    p.write_text(json.dumps(data, indent=1))
    written.append(p)
    for sig in res.signals:
        written.append(write_csv(sig, out / f'{sig.signal.slug}_orders.csv'))
        written.append(write_cycles_csv(sig, out / f'{sig.signal.slug}_cycles.csv'))
        if plots:
            written.append(plot_campbell(res, sig, out / f'{sig.signal.slug}_campbell.png', natural))
            written.append(plot_fig13(res, sig, out / f'{sig.signal.slug}_fig13.png'))
    return written
