"""Order analysis of recorded driveline bags (doc/commands/analyze.md): no ROS runtime needed.

Pipeline (one module per step):

1. **Read** (:mod:`dmf_sim.analysis.series` on the bag layer :mod:`dmf_sim.bags.layout`,
   :mod:`dmf_sim.bags.columns`): the few topics needed from a rosbag2 MCAP bag -- a directory
   (split files, a truncated last file), one of its files, or a bare ``.mcap``; written by
   :class:`dmf_sim.bags.writer.BagRecorder` or ``ros2 bag record``; topics under the driveline's
   namespace found by themselves.
2. **Crank angle** psi(t): ``/engine/crank_angle`` (a wrapped angle is unwrapped), or the time
   integral of ``/engine/speed`` [rpm]; a bag with neither is refused with a one-line error.
3. **Angle-domain resampling** and 4. **half orders per engine cycle**
   (:mod:`dmf_sim.analysis.cycle_orders`, the same functions as the live node's per-cycle orders):
   every whole 720 deg cycle resampled on the crank angle, ``x(psi) = Re(sum c_n exp(i n psi/2))``
   and the paper's Fig. 13 quantities (:mod:`dmf_sim.physics.orders`).
5. **Speed bins** (:mod:`dmf_sim.analysis.order_bins`): means over the cycles of each bin; bins
with fewer
   than ``min_cycles`` cycles are ramp bins.
6. **Model** (:mod:`dmf_sim.analysis.hbm_overlay`): natural frequencies, the static wind-up of the
mean
   torque (the paper's green line, theta minus it) and the HBM prediction compared on the steady
   bins. Outputs: :mod:`dmf_sim.analysis.outputs`, :mod:`dmf_sim.analysis.plots`.
"""
from __future__ import annotations

import os
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dmf_sim.analysis.cycle_orders import CycleOrders, angle_cycle_orders, cycle_orders
from dmf_sim.analysis.hbm_overlay import (
    HBMOverlay,
    hbm_overlay,
    model_settings,
    natural_frequencies,
    overlay_all,
)
from dmf_sim.analysis.load_timeline import LoadTimeline, describe_unknown, load_timeline
from dmf_sim.analysis.order_bins import DEFAULT_BIN_RPM, DEFAULT_MIN_CYCLES, OrderTable, bin_cycles
from dmf_sim.analysis.outputs import (
    analysis_dict,
    table_rows,
    to_jsonable,
    write_csv,
    write_cycles_csv,
    write_outputs,
)
from dmf_sim.analysis.series import (
    DEFAULT_TOPICS,
    TOPIC_CRANK,
    TOPIC_JOINTS,
    TOPIC_SPEED,
    TOPIC_WINDUP,
    BagSeries,
    Series,
    SignalSpec,
    check_reader,
    crank_angle,
    read_bag_series,
)
from dmf_sim.bags.layout import BagFiles
from dmf_sim.bags.records import damage_lines, skipped_chunks
from dmf_sim.core.deprecation import options_from_keywords
from dmf_sim.core.errors import BagError

__all__ = [
    'TOPIC_WINDUP', 'TOPIC_JOINTS', 'TOPIC_SPEED', 'TOPIC_CRANK', 'DEFAULT_TOPICS',
    'DEFAULT_BIN_RPM', 'DEFAULT_MIN_CYCLES', 'SignalSpec', 'Series', 'BagSeries', 'CycleOrders',
    'OrderTable', 'SignalAnalysis', 'BagAnalysis', 'AnalysisOptions', 'HBMOverlay',
    'read_bag_series', 'crank_angle', 'angle_cycle_orders', 'cycle_orders', 'bin_cycles',
    'analyze_bag',
    'model_settings', 'hbm_overlay', 'overlay_all', 'natural_frequencies', 'analysis_dict',
    'table_rows', 'write_outputs', 'write_csv', 'write_cycles_csv', 'to_jsonable',
]


@dataclass
class SignalAnalysis:
    """One analysed signal: its cycles, its table over speed, the HBM beside it."""

    signal: SignalSpec
    cycles: CycleOrders
    table: OrderTable
    n_samples: int
    topic: str = ''
    hbm: HBMOverlay | None = None
    cycle_load: np.ndarray | None = None     # engine load of each cycle (NaN: unknown)


@dataclass
class BagAnalysis:
    """Result of :func:`analyze_bag`."""

    bag: Path
    crank_source: str
    signals: list[SignalAnalysis]
    bin_rpm: float
    min_cycles: int
    n_max: int
    points_per_cycle: int
    sample_rate_hz: float
    duration_s: float
    series: BagSeries
    analyze_seconds: float
    theta: float | None
    warnings: list[str] = field(default_factory=list)
    model: dict | None = None        # model settings, once :func:`overlay_all` ran
    corrupt: list[dict] = field(default_factory=list)   # corrupt chunks skipped (skipped_chunks)
    damage: list[str] = field(default_factory=list)     # what the reading left out, one line
                                                        # each (damage_lines; in warnings too)
    load_timeline: LoadTimeline | None = None   # the load over the recording, from the bag

    def signal(self, label: str = 'windup') -> SignalAnalysis:
        for s in self.signals:
            if s.signal.label == label:
                return s
        raise KeyError(label)

    # what was read (see BagSeries)
    topics = property(lambda self: self.series.topics)
    files = property(lambda self: self.series.files)
    metadata = property(lambda self: self.series.metadata)
    reader = property(lambda self: self.series.reader)
    read_seconds = property(lambda self: self.series.read_seconds)
    joint_names = property(lambda self: self.series.joint_names)
    namespace = property(lambda self: self.series.namespace)
    truncated = property(lambda self: bool(self.series.truncated))


def _signal_topic(spec: SignalSpec, names: Mapping[str, str]) -> str:
    return {'windup': names['windup'], 'topic': spec.element}.get(spec.kind, names['joints'])


@dataclass(frozen=True)
class AnalysisOptions:
    """How :func:`analyze_bag` reads and cuts a bag (which bag and signals are its arguments).

    Attributes:
        bin_rpm: speed bin width [rpm]; 0 gives one row per engine cycle.
        min_cycles: bins with fewer cycles are ramp bins (marked, not compared with the HBM).
        points_per_cycle: crank-angle grid per 720 deg cycle; n_max: highest half-order index.
        theta: DMF stiffness change angle [rad] for 'mean minus theta' and the green line of
            the wind-up (None: not reported).
        topics, namespace, stamp, reader: see :func:`read_bag_series` (reader 'fast' or
            'messages').
        start_s, end_s: keep only cycles within this time window [s from the first crank-angle
            sample] (e.g. to skip a start-up transient). ``start_s`` None: the cycles after the
            settle from static equilibrium the bag marks (``custom_data`` ``settle_s``, as
            ``dmf-sim run`` writes it), else all.
        load: the engine load fraction of the whole recording, if the caller knows it (the
            ``--load`` option). None: the load each cycle ran at, from what the bag holds
            (:mod:`dmf_sim.analysis.load_timeline`); rows are then per speed bin *and* load.
    """

    bin_rpm: float = DEFAULT_BIN_RPM
    min_cycles: int = DEFAULT_MIN_CYCLES
    points_per_cycle: int = 256
    n_max: int = 24
    theta: float | None = None
    topics: Mapping[str, str] | None = None
    namespace: str | None = None
    stamp: str = 'log'
    reader: str = 'fast'
    start_s: float | None = None
    end_s: float | None = None
    load: float | None = None


def analyze_bag(path: str | os.PathLike | BagFiles,
                signals: Iterable[str | SignalSpec] = ('windup',), *,
                options: AnalysisOptions | None = None, progress: bool = False,
                **keywords) -> BagAnalysis:
    """Order analysis of a bag (see the module docstring).

    Args:
        path: the bag (or its resolved files, :func:`dmf_sim.bags.layout.resolve_bag`).
        signals: 'windup', 'angle:NAME', 'velocity:NAME', 'torque:NAME', 'topic:/name'.
        options: :class:`AnalysisOptions` (bins, grid, time window, load, how to read).
        progress: a progress bar while reading (:func:`read_bag_series`).

    The fields of :class:`AnalysisOptions` given as keywords (``analyze_bag(bag,
    bin_rpm=20)``, the old signature) still work, with a deprecation warning.
    """
    o = options_from_keywords(AnalysisOptions, options, keywords, 'analyze_bag')
    bin_rpm, min_cycles, n_max, theta = o.bin_rpm, o.min_cycles, o.n_max, o.theta
    points_per_cycle, start_s, end_s, load = o.points_per_cycle, o.start_s, o.end_s, o.load
    t_start = time.perf_counter()
    specs = [s if isinstance(s, SignalSpec) else SignalSpec.parse(s) for s in signals]
    if not specs:
        raise BagError('no signal requested')
    labels = [s.label for s in specs]
    if len(set(labels)) != len(labels):
        raise BagError(f'signal requested twice: {labels}')
    bag = read_bag_series(path, signals=specs, topics=o.topics, namespace=o.namespace,
                          stamp=o.stamp, reader=check_reader(o.reader), progress=progress)
    crank, source = crank_angle(bag)
    warnings = list(bag.notes)
    damage = damage_lines(bag.scans, bag.truncated, int(crank.t_ns[0]))
    warnings += damage
    corrupt = skipped_chunks(bag.scans, int(crank.t_ns[0]))
    timeline = None
    if load is None:
        t0_ns = int(crank.t_ns[0])
        timeline = load_timeline(bag.health, bag.load_setpoints, bag.bag.run_metadata.load,
                                 t0_ns, int(crank.t_ns[-1]))
        if timeline is not None:
            warnings += timeline.notes
            for key, seen in timeline.settings.items():
                if len(seen) > 1:
                    warnings.append(f'{key} changed during the recording '
                                    f'({", ".join(f"{v:g}" for v in seen)}): the model uses one '
                                    f'value (see model_sources); analyse the parts apart with '
                                    '--start/--end')
    out, rates = [], []
    settle = bag.bag.run_metadata.settle_s if start_s is None else None
    if settle:
        start_s = settle
    window = start_s is not None or end_s is not None
    for spec in specs:
        topic = _signal_topic(spec, bag.topic_names)
        s = bag.series.get(spec.label)
        if s is None or len(s) == 0:
            raise BagError(f'signal {spec.label!r}: topic {bag.topic_state(topic)}; topics found: '
                           f'{bag.topics_found()}')
        cyc = cycle_orders(s.t_ns, s.values, crank.t_ns, crank.values,
                           points_per_cycle=points_per_cycle, n_max=n_max)
        if window:
            keep = np.ones(len(cyc), bool)
            if start_s is not None:
                keep &= cyc.t_start >= start_s
            if end_s is not None:
                keep &= cyc.t_end <= end_s
            if settle and not out:
                warnings.append(f'{int(np.count_nonzero(cyc.t_start < settle))} engine '
                                f'cycle(s) of the first {settle:g} s left out: the driveline '
                                'settling from static equilibrium, as the bag marks it '
                                '(custom_data settle_s; --start 0 keeps them)')
            cyc = cyc.select(keep)
        if len(cyc) == 0:
            raise BagError(f'signal {spec.label!r}: no whole engine cycle (720 deg of crank '
                           'angle) recorded with the signal'
                           + (f' after the settle from static equilibrium ({settle:g} s, '
                              'custom_data settle_s; --start 0 keeps it)' if settle
                              else ' in the time window' if window else ''))
        if len(s) > 1:
            rates.append(1e9 / float(np.median(np.diff(s.t_ns))))
        loads = (None if timeline is None else
                 timeline.cycle_loads(cyc.t_start, cyc.t_end, int(crank.t_ns[0])))
        table = bin_cycles(cyc, bin_rpm, theta if spec.kind == 'windup' else None, min_cycles,
                           loads)
        if loads is not None and not np.isfinite(loads).all() and not out:
            warnings.append(describe_unknown(timeline, loads, int(crank.t_ns[0])))
        out.append(SignalAnalysis(spec, cyc, table, len(s), topic, cycle_load=loads))
    dur = float(crank.t_ns[-1] - crank.t_ns[0]) * 1e-9
    return BagAnalysis(bag.bag.path, source, out, float(bin_rpm), int(min_cycles), int(n_max),
                       int(points_per_cycle), float(min(rates)) if rates else float('nan'), dur,
                       bag, time.perf_counter() - t_start, theta, warnings, corrupt=corrupt,
                       damage=damage, load_timeline=timeline)
