"""The signals of a recorded bag as time series: what to read, from which topics, and the crank
angle to resample on (step 1-2 of the bag analysis, :mod:`dmf_sim.analysis.pipeline`).

Topics: the node's defaults (``/driveline/dmf_windup``, ``/driveline/joint_states``,
``/engine/speed``, ``/engine/crank_angle``), or the same under the namespace of the one
driveline the bag holds (``/truck1/driveline/...``: detected from the bag's topics; a bag with
several asks for ``namespace``), or topics given explicitly.

Time stamps: kept in file order. A jump back by more than ``BACK_JUMP_STEPS`` sample intervals
is a clock re-anchored during the recording (the node returning from fast pacing to real
time): later stamps are shifted so time runs on, and the analysis says so. Smaller reversals
(out-of-order receive times) are sorted.
"""
from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dmf_sim.bags.columns import Column, JointStateColumns, McapColumns, ScalarColumn
from dmf_sim.bags.layout import BagFiles, resolve_bag
from dmf_sim.bags.read import TypeDecoder, bag_topics, message_counts, read_messages, topics_text
from dmf_sim.bags.records import Scan, no_message_text
from dmf_sim.core.deprecation import warn_renamed
from dmf_sim.core.errors import BagError
from dmf_sim.core.names import check_namespace
from dmf_sim.core.units import RPM_TO_RAD_S

__all__ = ['TOPIC_WINDUP', 'TOPIC_JOINTS', 'TOPIC_SPEED', 'TOPIC_CRANK', 'DEFAULT_TOPICS',
           'SIGNAL_KINDS', 'SignalSpec', 'Series', 'BagSeries', 'read_bag_series',
           'check_reader', 'driveline_namespaces', 'bag_topic_names', 'monotonic_times',
           'crank_angle']

TOPIC_WINDUP = '/driveline/dmf_windup'
TOPIC_JOINTS = '/driveline/joint_states'
TOPIC_SPEED = '/engine/speed'
TOPIC_CRANK = '/engine/crank_angle'
DEFAULT_TOPICS = {'windup': TOPIC_WINDUP, 'joints': TOPIC_JOINTS, 'speed': TOPIC_SPEED,
                  'crank': TOPIC_CRANK}
# where the bag holds the engine load (analysis.load_timeline): the node's health statuses and,
# when it was recorded, the load setpoint topic (under the driveline's namespace)
TOPIC_DIAGNOSTICS = '/diagnostics'
TOPIC_LOAD_SETPOINT = '/engine/load_setpoint'
BACK_JUMP_STEPS = 100     # a stamp this many sample intervals back is a re-anchored clock

# signal kind -> (JointState field or None, unit, description)
SIGNAL_KINDS: dict[str, tuple[str | None, str, str]] = {
    'windup': (None, 'rad', 'DMF wind-up'),
    'angle': ('position', 'rad', 'vibratory angle'),
    'velocity': ('velocity', 'rad/s', 'vibratory angular velocity'),
    'torque': ('effort', 'Nm', 'transmitted torque'),
    'topic': (None, '', 'Float64 topic'),
}


@dataclass(frozen=True)
class SignalSpec:
    """What to analyse: ``windup`` (the wind-up topic), ``angle:NAME``, ``velocity:NAME``,
    ``torque:NAME`` (a JointState element column: position, velocity, effort) or ``topic:/name``
    (the ``data`` field of any scalar topic such as std_msgs/Float64)."""

    kind: str
    element: str | None = None

    @classmethod
    def parse(cls, text: str) -> SignalSpec:
        text = text.strip()
        kind, sep, rest = text.partition(':')
        kind = kind.strip().lower()
        if kind not in SIGNAL_KINDS:
            raise BagError(f'signal {text!r}: kind must be one of {", ".join(SIGNAL_KINDS)} '
                           "(e.g. 'windup', 'angle:CYL1', 'torque:INPUT SHAFT', "
                           "'topic:/my/float')")
        if kind == 'windup':
            if sep and rest.strip():
                raise BagError(f"signal {text!r}: 'windup' takes no element name")
            return cls('windup')
        if not rest.strip():
            what, example = (('a topic name', "'topic:/driveline/dmf_windup'") if kind == 'topic'
                             else ('an element name', f"'{kind}:CYL1'"))
            raise BagError(f"signal {text!r}: '{kind}:' needs {what}, e.g. {example}")
        return cls(kind, rest.strip())

    @property
    def field(self) -> str | None:
        """The JointState field of an element signal (None for scalar topics)."""
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
        series: request key ('crank', 'speed', signal labels) -> Series (missing when the topic
            is absent or empty).
        topics: topic -> ROS type of every topic of the bag.
        bag: the resolved bag (files, metadata.yaml, the recording's custom_data).
        truncated: files that ended without footer (crash).
        reader: 'fast' or 'messages'; read_seconds: wall time of the reading.
        joint_names: element names of the joint states (when read).
        namespace: the driveline namespace the default topics were taken under ('' for none).
        notes: what the reader adapted to (skipped files, re-anchored clocks).
        topic_names: the topics read ('windup', 'joints', 'speed', 'crank' -> name).
        scans: per file read, how far it was valid and its corrupt chunks (skipped: the
            messages they held are missing from the series), see :mod:`dmf_sim.bags.records`.
        health: (times [ns], rows of :data:`dmf_sim.analysis.load_timeline.HEALTH_KEYS`) of
            the recording node's health statuses in ``/diagnostics`` (None: none recorded).
        load_setpoints: (times [ns], values) of the recorded load setpoint topic, or None.
    """

    series: dict[str, Series]
    topics: dict[str, str]
    bag: BagFiles
    truncated: list[Path]
    reader: str
    read_seconds: float
    joint_names: list[str] = field(default_factory=list)
    namespace: str = ''
    notes: list[str] = field(default_factory=list)
    topic_names: dict[str, str] = field(default_factory=lambda: dict(DEFAULT_TOPICS))
    scans: list[Scan] = field(default_factory=list)
    health: tuple[np.ndarray, np.ndarray] | None = None
    load_setpoints: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def message_counts(self) -> dict[str, int]:
        """Topic -> messages read (every topic of the files read, not only those analysed)."""
        return message_counts(self.scans)

    def topic_state(self, topic: str) -> str:
        """``topic`` and whether the bag declares it and how many messages it holds, for a
        message: '/t is not in the bag', '/t holds no messages', '/t holds 1 message'."""
        if topic not in self.topics:
            return f'{topic} is not in the bag'
        n = self.message_counts.get(topic, 0)
        return f'{topic} holds {n or "no"} message{"" if n == 1 else "s"}'

    def topics_found(self) -> str:
        """The bag's topics for a message (declared topics without messages marked)."""
        return topics_text(self.topics, self.message_counts)

    @property
    def corrupt(self) -> list:
        """The corrupt chunks skipped in every file (:class:`~dmf_sim.bags.records.CorruptChunk`).
        """
        return [c for s in self.scans for c in s.corrupt]

    @property
    def files(self) -> tuple[Path, ...]:
        return self.bag.files

    @property
    def metadata(self) -> dict | None:
        return self.bag.metadata


# -------------------------------------------------------------------------------- topics

def driveline_namespaces(topics: Sequence[str]) -> list[str]:
    """Namespaces under which the bag holds the node's default topics ('' = none)."""
    found = set()
    for topic in topics:
        for default in DEFAULT_TOPICS.values():
            if topic == default:
                found.add('')
            elif topic.endswith(default) and topic.startswith('/'):
                found.add(topic[:-len(default)])
    return sorted(found)


def bag_topic_names(listed: Mapping[str, str], topics: Mapping[str, str] | None = None,
                    namespace: str | None = None) -> tuple[dict[str, str], str]:
    """Topics to read ('windup', 'joints', 'speed', 'crank' -> name) and the namespace used.

    Explicit ``topics`` win; the others are the defaults under ``namespace``, or under the one
    namespace the bag holds them in (several: a one-line BagError listing them)."""
    if namespace is None:
        spaces = driveline_namespaces(list(listed))
        if len(spaces) > 1:
            names = ', '.join(s or '/' for s in spaces)
            raise BagError(f'the bag holds several drivelines ({names}); choose one with '
                           '--namespace')
        namespace = spaces[0] if spaces else ''
    ns = check_namespace(namespace, 'namespace')
    out = {key: ns + topic for key, topic in DEFAULT_TOPICS.items()}
    out.update(topics or {})
    return out, ns


# ---------------------------------------------------------------------------- time stamps

def monotonic_times(t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, int]:
    """Stamps in file order -> (stamps running forward, order to apply to the values or None if
    they are in order, number of re-anchored clock jumps unrolled). See the module docstring."""
    t = np.asarray(t_ns, np.int64)
    if len(t) < 2:
        return t, None, 0
    d = np.diff(t)
    if not (d < 0).any():
        return t, None, 0
    forward = d[d > 0]
    step = int(np.median(forward)) if len(forward) else 1
    jumps = np.flatnonzero(d < -BACK_JUMP_STEPS * step)
    shift = np.zeros(len(t), np.int64)
    for j in jumps:
        shift[j + 1:] += -d[j] + step
    t = t + shift
    order = np.argsort(t, kind='stable')
    return t[order], order, len(jumps)


# -------------------------------------------------------------------------------- reading

def _requests(keys: Mapping[str, str], signals: Sequence[SignalSpec], tp: Mapping[str, str]
              ) -> tuple[dict[str, str], list[tuple[str, str]], dict]:
    """Scalar request key -> topic, joint columns, and topic -> Column factory."""
    scalar = dict(keys)
    for s in signals:
        if s.kind == 'windup':
            scalar[s.label] = tp['windup']
        elif s.kind == 'topic':
            scalar[s.label] = s.element
    joint_cols = [(s.field, s.element) for s in signals if s.field is not None]
    factories = {topic: ScalarColumn for topic in scalar.values()}
    if joint_cols:
        factories[tp['joints']] = lambda dec, msgtype: JointStateColumns(dec, msgtype, joint_cols)
    return scalar, joint_cols, factories


def _read_fast(bag: BagFiles, factories, stamp: str, bar, scans: list[Scan]
               ) -> tuple[dict, list, list]:
    parts: dict[str, list] = {}
    truncated: list[Path] = []
    columns: list[Column] = []
    decoder = TypeDecoder()

    def factory_of(topic):
        def make(dec, msgtype):
            col = factories[topic](dec, msgtype)
            columns.append(col)
            return col
        return make

    requests = {topic: factory_of(topic) for topic in factories}
    for file in bag.files:
        reader = McapColumns(file, requests, decoder, stamp,
                             bar.update if bar is not None else None).read()
        for topic, got in reader.columns.items():
            parts.setdefault(topic, []).extend(got)
        if reader.truncated:
            truncated.append(file)
        scans.append(reader.scan)
    return parts, truncated, columns


def _read_messages(bag: BagFiles, factories, stamp: str, scans: list[Scan]
                    ) -> tuple[dict, list, list]:
    """The library path: mcap records, every wanted message decoded by rosbags."""
    columns: dict[str, Column] = {}
    rows: dict[str, list] = {}
    times: dict[str, list] = {}
    decoder = TypeDecoder()
    for m in read_messages(bag, list(factories), scans=scans):
        col = columns.get(m.topic)
        if col is None:
            col = columns[m.topic] = factories[m.topic](decoder, m.msgtype)
        rows.setdefault(m.topic, []).append(col.row(m.msg))
        times.setdefault(m.topic, []).append(m.timestamp_ns if stamp == 'log'
                                             else m.publish_time_ns)
    parts = {t: [(np.array(times[t], np.int64), np.array(rows[t], float))] for t in rows}
    truncated = [f for f, s in zip(bag.files, scans) if not s.complete]
    return parts, truncated, list(columns.values())


def check_reader(reader: str) -> str:
    """The reader asked for: 'fast' or 'messages' ('reference', its old name, with a deprecation
    warning at the line that called the function calling this one); else a BagError."""
    if reader == 'reference':
        warn_renamed("reader='reference'", "reader='messages'", stacklevel=4)
        reader = 'messages'
    if reader not in ('fast', 'messages'):
        raise BagError(f"reader={reader!r}: allowed 'fast', 'messages'")
    return reader


def read_bag_series(path: str | os.PathLike | BagFiles, *, signals: Sequence[SignalSpec] = (),
                    topics: Mapping[str, str] | None = None, namespace: str | None = None,
                    stamp: str = 'log', reader: str = 'fast', progress: bool = False
                    ) -> BagSeries:
    """Read the crank angle, speed and the requested signals of a bag.

    Args:
        path: a bag (see :func:`dmf_sim.bags.layout.resolve_bag`).
        signals: signals whose topics to read (the crank angle and speed are always read).
        topics: overrides of DEFAULT_TOPICS (keys 'windup', 'joints', 'speed', 'crank').
        namespace: driveline namespace of the default topics (None: detect it).
        stamp: 'log' (receive time, default) or 'publish' time of each message.
        reader: 'fast' (:mod:`dmf_sim.bags.columns`) or 'messages' (:mod:`dmf_sim.bags.read`,
            the libraries alone: every wanted message decoded by rosbags; 'reference', its old
            name, still works with a deprecation warning).
        progress: tqdm progress bar over the bytes read.
    """
    if stamp not in ('log', 'publish'):
        raise BagError(f"stamp={stamp!r}: allowed 'log', 'publish'")
    reader = check_reader(reader)
    t0 = time.perf_counter()
    bag = path if isinstance(path, BagFiles) else resolve_bag(path)
    listed = bag_topics(bag)
    tp, ns = bag_topic_names(listed, topics, namespace)
    scalar, joint_cols, factories = _requests({'crank': tp['crank'], 'speed': tp['speed']},
                                              signals, tp)
    load_sp = ns + TOPIC_LOAD_SETPOINT
    if load_sp in listed:
        scalar['load_setpoint'] = load_sp
        factories[load_sp] = ScalarColumn
    if TOPIC_DIAGNOSTICS in listed:
        factories[TOPIC_DIAGNOSTICS] = _health_factory(bag, ns)
    bar = None
    if progress and reader == 'fast':
        from tqdm import tqdm
        bar = tqdm(total=sum(f.stat().st_size for f in bag.files), unit='B', unit_scale=True,
                   desc='reading bag', leave=False)
    scans: list[Scan] = []
    try:
        if reader == 'fast':
            parts, truncated, columns = _read_fast(bag, factories, stamp, bar, scans)
        else:
            parts, truncated, columns = _read_messages(bag, factories, stamp, scans)
    finally:
        if bar is not None:
            bar.close()
    notes = list(bag.notes)
    series: dict[str, Series] = {}
    jumps: dict[str, int] = {}

    joined: dict[str, tuple[np.ndarray, np.ndarray] | None] = {}

    def assemble(topic: str) -> tuple[np.ndarray, np.ndarray] | None:
        if topic in joined:
            return joined[topic]
        got = parts.pop(topic, None)       # freed as it is joined: peak ~ one copy of a topic
        joined[topic] = None
        if got:
            t, order, n = monotonic_times(np.concatenate([p[0] for p in got]))
            if n:
                jumps[topic] = n
            values = np.concatenate([p[1] for p in got])
            joined[topic] = (t, values if order is None else values[order])
        return joined[topic]

    for key, topic in scalar.items():
        if (tv := assemble(topic)) is not None:
            series[key] = Series(tv[0], tv[1][:, 0])
    names: list[str] = []
    if joint_cols and (tv := assemble(tp['joints'])) is not None:
        signal_cols = [s for s in signals if s.field is not None]
        for k, s in enumerate(signal_cols):
            series[s.label] = Series(tv[0], tv[1][:, k])
        names = next((c.names for c in columns if getattr(c, 'names', None)), [])
    health = assemble(TOPIC_DIAGNOSTICS) if TOPIC_DIAGNOSTICS in factories else None
    if health is not None:
        keep = np.isfinite(health[1][:, 0])
        health = (health[0][keep], health[1][keep]) if keep.any() else None
    setpoints = series.pop('load_setpoint', None)
    if jumps:
        notes.append(f'time stamps jump back {max(jumps.values())} time(s) (a clock re-anchored '
                     'while recording): later stamps shifted so time runs on')
    return BagSeries(series, {**listed}, bag, truncated, reader, time.perf_counter() - t0, names,
                     ns.strip('/'), notes, dict(tp), scans, health,
                     None if setpoints is None else (setpoints.t_ns, setpoints.values))


def _health_factory(bag: BagFiles, ns: str):
    """Column factory of the recording node's health statuses: the node stored in the bag's
    metadata, else any node under the namespace ``ns``."""
    from dmf_sim.analysis.load_timeline import HealthColumn

    node = bag.run_metadata.node
    prefix = None if node else (ns + '/' if ns else None)
    return lambda dec, msgtype: HealthColumn(dec, msgtype, node=node, prefix=prefix)


# ---------------------------------------------------------------------------- crank angle

def _unwrap(psi: np.ndarray) -> tuple[np.ndarray, bool]:
    """Unwrap a crank angle wrapped at 2 pi or 4 pi (drops of more than pi rad)."""
    d = np.diff(psi)
    drops = d[d < -math.pi]
    if len(drops) == 0:
        return psi, False
    span = float(np.median(-drops))
    period = 4 * math.pi if span > 3 * math.pi else 2 * math.pi
    return np.unwrap(psi, period=period), True


def _strictly_increasing(s: Series) -> tuple[np.ndarray, np.ndarray]:
    keep = np.concatenate(([True], np.diff(s.t_ns) > 0))
    return s.t_ns[keep], s.values[keep]


def crank_angle(bag: BagSeries) -> tuple[Series, str]:
    """Crank angle [rad] over time from the crank-angle topic, else from integrating the speed.

    Returns (Series, description of the source). A bag with neither is a one-line BagError
    (a bag without any complete message: why, in bag-recover's words)."""
    crank = bag.series.get('crank')
    if crank is not None and len(crank) >= 2:
        t, psi = _strictly_increasing(crank)
        psi, wrapped = _unwrap(psi)
        return Series(t, psi), ('crank angle topic (unwrapped)' if wrapped
                                else 'crank angle topic')
    speed = bag.series.get('speed')
    if speed is not None and len(speed) >= 2:
        t, rpm = _strictly_increasing(speed)
        ts = (t - t[0]) * 1e-9
        omega = rpm * RPM_TO_RAD_S
        psi = np.concatenate(([0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) * np.diff(ts))))
        return Series(t, psi), 'integrated engine speed (no crank angle topic)'
    if not any(s.messages for s in bag.scans):            # a stub, or an empty recording
        raise BagError(f'{bag.bag.path}: nothing to analyze: {no_message_text(bag.scans)}'
                       + (f'; topics declared: {topics_text(bag.topics)}' if bag.topics else ''))
    tp = bag.topic_names
    raise BagError(f'the bag has neither a crank angle topic ({bag.topic_state(tp["crank"])}) '
                   f'nor an engine speed topic ({bag.topic_state(tp["speed"])}) to resample on; '
                   f'topics found: {bag.topics_found()} (use --crank-topic/--speed-topic for '
                   'other names)')
