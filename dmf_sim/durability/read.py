"""Durability of a recorded bag, read in batches (``dmf-sim durability BAG``).

The bag (the node's recording or a ``dmf-sim run`` bag; :func:`dmf_sim.bags.layout.resolve_bag`)
is read file by file with the fast column reader (:class:`dmf_sim.bags.columns.McapColumns`),
which hands over about 1 MiB of decompressed chunks at a time; each batch goes into the
:class:`DurabilityAccumulator` and is dropped. Memory stays at one batch plus the accumulated
histograms, whatever the record's length.

Signals: the joint states of the two elements around the DMF give the wind-up
w = phi_(s-1) / r_s - phi_s and its rate from the recorded velocities (exact, no numerical
differentiation); engine speed and crank angle are interpolated onto the joint-state stamps.
The model (the DMF spring, its damping) is the one the bag's ``custom_data`` names
(:func:`dmf_sim.analysis.hbm_overlay.model_settings`), as ``dmf-sim analyze`` rebuilds it, with
the DMF faults of the bag's ground truth (``faults/ground_truth``: a spring or damping changed
from a time on, :data:`dmf_sim.physics.faults.DMF_KINDS`) applied where they were active
(:func:`dmf_segments`): the samples of a faulted stretch are counted with the faulted spring
and damping, and the notes say which.
What the reading had to leave out (truncated files, corrupt chunks skipped) goes into the notes
in the words ``dmf-sim analyze`` uses (:func:`dmf_sim.bags.records.damage_lines`) and, chunk by
chunk, into ``corrupt_chunks`` (:func:`dmf_sim.bags.records.skipped_chunks`).
"""
from __future__ import annotations

import os
import resource
import time
from dataclasses import dataclass, field

import numpy as np

from dmf_sim.analysis.hbm_overlay import build_model, model_settings
from dmf_sim.analysis.series import bag_topic_names
from dmf_sim.bags.columns import JointStateColumns, McapColumns, ScalarColumn
from dmf_sim.bags.layout import BagFiles, resolve_bag
from dmf_sim.bags.read import TypeDecoder, bag_topics, message_counts, topics_text
from dmf_sim.bags.records import Scan, damage_lines, no_message_text, skipped_chunks
from dmf_sim.core.errors import BagError
from dmf_sim.durability.accumulate import DurabilityAccumulator, DurabilityResult
from dmf_sim.durability.settings import DurabilitySettings

__all__ = ['DurabilityRun', 'DmfSegment', 'dmf_segments', 'bag_durability']


@dataclass(frozen=True)
class DmfSegment:
    """From stamp ``from_ns`` on (until the next segment's): the DMF ``spring`` and its viscous
    ``damping_nms`` [Nms/rad], and the DMF faults active (``faults``, their text)."""

    from_ns: int | None          # None: from the start
    spring: object
    damping_nms: float
    faults: str = ''


def dmf_segments(bag: BagFiles, model) -> list[DmfSegment]:
    """The DMF of the recording stretch by stretch: the bag's model (``ReducedModel``) as it is,
    then its driveline with the DMF faults of the ground truth active over each stretch applied
    (``FaultSet.apply_to_driveline``, the node's own rebuild); the first segment alone where the
    bag has none."""
    from dmf_sim.analysis.misfire_detector import event_start_ns, ground_truth_events
    from dmf_sim.physics.faults import DMF_KINDS, FaultSet

    line, element = model.line, model.dmf_element
    starts = [ev for ev in ground_truth_events(bag)
              if ev['what'] == 'start' and ev['fault'].kind in DMF_KINDS
              and event_start_ns(ev) is not None]
    nominal = DmfSegment(None, model.spring, float(line.elements[element].damping))
    if not starts:
        return [nominal]
    spans = [(event_start_ns(ev), ev['end_ns'], ev) for ev in starts]
    cuts = sorted({a for a, _, _ in spans} | {b for _, b, _ in spans if b is not None})
    out = [nominal]
    for cut in cuts:
        active = [ev for a, b, ev in spans if a <= cut and (b is None or cut < b)]
        faulted = FaultSet(tuple(ev['fault'] for ev in active)).apply_to_driveline(line)
        out.append(DmfSegment(int(cut), faulted.reduce().spring,
                              float(faulted.elements[element].damping),
                              ', '.join(f'fault {ev["id"]} {ev["fault"].text()}'
                                        for ev in active)))
    return out


@dataclass
class DurabilityRun:
    """The result and how it was read."""

    result: DurabilityResult
    bag: str
    files: int
    truncated: list
    model: dict
    read_seconds: float
    peak_rss_mib: float
    batches: int
    corrupt: list[dict] = field(default_factory=list)   # corrupt chunks skipped


class _Aligner:
    """Joint-state rows with speed and crank angle interpolated onto their stamps, handed to
    the accumulator as soon as both scalars reach past them."""

    def __init__(self, acc: DurabilityAccumulator, topics: dict, ratio: float,
                 segments: list[DmfSegment]) -> None:
        self.acc, self.topics, self.ratio = acc, topics, ratio
        self.segments = segments
        self.used: set[int] = set()          # the segments that had samples
        self.joint: list = []
        self.scalar: dict[str, list] = {'speed': [], 'crank': []}
        self.batches = 0

    def __call__(self, topic: str, t: np.ndarray, values: np.ndarray) -> None:
        if topic == self.topics['joints']:
            self.joint.append((t, values))
        elif topic == self.topics['speed']:
            self.scalar['speed'].append((t, values[:, 0]))
        elif topic == self.topics['crank']:
            self.scalar['crank'].append((t, values[:, 0]))
        self.process()

    @staticmethod
    def _joined(parts: list) -> tuple[np.ndarray, np.ndarray]:
        if len(parts) == 1:
            return parts[0]
        return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]))

    def process(self, final: bool = False) -> None:
        if not self.joint or not all(self.scalar.values()):
            return
        jt, jv = self._joined(self.joint)
        sc = {k: self._joined(v) for k, v in self.scalar.items()}
        upto = min(sc['speed'][0][-1], sc['crank'][0][-1])
        n = len(jt) if final else int(np.searchsorted(jt, upto, side='right'))
        if n == 0:
            self.joint = [(jt, jv)]
            self.scalar = {k: [v] for k, v in sc.items()}
            return
        t = jt[:n]
        speed = np.interp(t, *sc['speed'])
        psi = np.interp(t, *sc['crank'])
        v = jv[:n]
        w = v[:, 0] / self.ratio - v[:, 1]
        wdot = v[:, 2] / self.ratio - v[:, 3]
        self._add(t, w, wdot, speed, psi)
        self.batches += 1
        self.joint = [(jt[n:], jv[n:])] if n < len(jt) else []
        # keep the scalars from the last one at or before the processed stamps on
        self.scalar = {}
        for k, (st, sv) in sc.items():
            i = max(int(np.searchsorted(st, t[-1], side='right')) - 1, 0)
            self.scalar[k] = [(st[i:], sv[i:])]


    def _add(self, t, w, wdot, speed, psi) -> None:
        """The samples to the accumulator, each stretch of a DMF segment with its spring and
        damping."""
        segs = self.segments
        cuts = np.searchsorted(t, [sg.from_ns for sg in segs[1:]], side='left').tolist()
        bounds = [0, *cuts, len(t)]
        for k, sg in enumerate(segs):
            a, b = bounds[k], bounds[k + 1]
            if b > a:
                if len(segs) > 1:
                    self.acc.set_dmf(sg.spring, sg.damping_nms)
                self.used.add(k)
                self.acc.add(t[a:b], w[a:b], wdot[a:b], speed[a:b], psi[a:b])


def bag_durability(path: str | os.PathLike | BagFiles, settings: DurabilitySettings, *,
                   namespace: str | None = None, progress: bool = False,
                   config: str | None = None) -> DurabilityRun:
    """Durability figures of a bag (see the module docstring); ``config``: the driveline YAML
    instead of the one the bag names (``--config`` of ``dmf-sim analyze``: the DMF spring
    stored in the bag still applies)."""
    t0 = time.perf_counter()
    bag = path if isinstance(path, BagFiles) else resolve_bag(path)
    listed = bag_topics(bag)
    tp, _ = bag_topic_names(listed, None, namespace)
    needs = ("durability needs the joint states, engine speed and crank angle of the node's "
             'recording')
    for key in ('joints', 'speed', 'crank'):
        if listed and tp[key] not in listed:     # (no topic at all: read, then say why)
            raise BagError(f'the bag has no {tp[key]} topic ({needs}); topics found: '
                           f'{topics_text(listed)}')
    st = model_settings(bag.metadata, config=config)
    model = build_model(st)
    if model.spring is None:
        raise BagError(f'driveline {st["driveline"]!r} of this bag has no DMF: nothing to assess')
    line = model.line
    s = model.dmf_element
    names = line.names
    el = line.elements[s]
    cols = [('position', names[s - 1]), ('position', names[s]), ('velocity', names[s - 1]),
            ('velocity', names[s])]
    segments = dmf_segments(bag, model)
    acc = DurabilityAccumulator(segments[0].spring, segments[0].damping_nms, settings)
    align = _Aligner(acc, tp, el.ratio, segments)
    requests = {tp['joints']: lambda dec, t: JointStateColumns(dec, t, cols),
                tp['speed']: ScalarColumn, tp['crank']: ScalarColumn}
    decoder = TypeDecoder()
    truncated = []
    scans: list[Scan] = []
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=sum(f.stat().st_size for f in bag.files), unit='B', unit_scale=True,
                   desc='durability', leave=False)
    try:
        for file in bag.files:
            reader = McapColumns(file, requests, decoder, 'log',
                                 bar.update if bar is not None else None, sink=align).read()
            scans.append(reader.scan)
            if reader.truncated:
                truncated.append(str(file))
    finally:
        if bar is not None:
            bar.close()
    if not any(s.messages for s in scans):
        raise BagError(f'{bag.path}: nothing to assess: {no_message_text(scans)}')
    align.process(final=True)
    if acc.samples == 0:
        raise BagError(f'{bag.path}: no joint states with engine speed and crank angle to '
                       f'assess ({needs}); topics found: '
                       f'{topics_text(listed or message_counts(scans), message_counts(scans))}')
    result = acc.finish()
    result.notes += [f'DMF faults of the ground truth from t = '
                     f'{(sg.from_ns - acc.t0_ns) * 1e-9:.3f} s: {sg.faults or "none"} (counted '
                     f'with the spring and damping they make: c = {sg.damping_nms:g} Nms/rad)'
                     for k, sg in enumerate(segments) if k > 0 and k in align.used]
    result.notes += damage_lines(scans, truncated, acc.t0_ns)
    keep = ('driveline', 'engine', 'load_set', 'alpha', 'theta_rad')
    return DurabilityRun(result, str(bag.path), len(bag.files), truncated,
                         {k: st.get(k) for k in keep}, time.perf_counter() - t0,
                         resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                         align.batches, skipped_chunks(scans, acc.t0_ns))
