"""A reference misfire detector on tooth-edge times that takes the DMF into account (no ROS).

An example of what an engine controller builds, short on purpose; its score against the bag's
ground truth shows that the sensor signals carry what a real detector uses.

**Why the DMF matters.** Behind a DMF the crank sees the light primary flywheel on a soft
spring: one missing combustion swings the crank speed at the DMF's low resonance for many
cycles after it, and the swing (of the size of the misfire's own speed drop) makes the classic
segment-time test raise alarms on healthy cylinders or miss the misfire. Following Kiencke et
al. (2007, "Misfire detection for vehicles with dual mass flywheel based on reconstructed engine
torque"), the detector reconstructs the engine's work per firing interval and takes the DMF's
spring torque out of it, here measured through the wind-up (W1) of the two tooth wheels around
the DMF (:mod:`dmf_sim.analysis.windup_estimate`).

**The test.** Segment speeds omega_i (:func:`~dmf_sim.analysis.tooth_signals.segment_speeds`)
over crank windows of 720 deg / n_cyl centred on each TDC. Between the centres of segments i and
i + 1 (cylinder i's power stroke) the primary side's energy balance per unit inertia J_P is

    E_i = (omega_{i+1}^2 - omega_i^2) / 2 = (W_gas,i - W_dmf,i - W_loss,i) / J_P      (M1)

with W_dmf,i = g * Tbar_i the spring's work: Tbar_i the mean DMF torque T(phi) over the interval
(phi the wind-up (W1), T the DMF's characteristic from the bag's model) and g (= interval angle
/ J_P) one factor per run, fitted by least squares of the first differences of E_i against
those of Tbar_i (slow changes of speed and load cancel in them; differences beyond ``TRIM``
median errors, a misfire's, are left out of a second fit). The engine's work per unit inertia
is then w_i = E_i - g Tbar_i, flat while healthy: the DMF's swing after a misfire is in Tbar,
not in w. Its local baselines are the medians of the ``window`` intervals before and after i
(a median ignores a neighbouring misfire; a load step or a run-up's start moves only one side);
the score is the deficit against the nearer of them, relative to the mean engine work
|g * median(Tbar)| (the spring passes on the mean engine torque),

    s_i = max(w_i - median(w_left), w_i - median(w_right)) / |g * median(Tbar)|       (M2)

about -1 for a misfire (its combustion's share of the work missing) and near 0 when healthy;
an alarm is s_i < -``threshold``.

**Scoring** (:func:`score_detections`): a misfire of the ground truth (``faults/ground_truth``,
its TDC crank angle) is detected when the interval of its TDC raised an alarm on its cylinder;
every other alarm is a false alarm. Counts per cylinder; engine cycles = intervals / n_cyl.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from dmf_sim.analysis.tooth_signals import (
    WheelEdges,
    cycle_phase,
    edge_angles,
    read_float64,
    read_wheel_edges,
    segment_speeds,
)
from dmf_sim.analysis.windup_estimate import estimate_windup
from dmf_sim.bags.layout import BagFiles, resolve_bag
from dmf_sim.bags.metadata import RunMetadata
from dmf_sim.bags.read import read_messages

__all__ = ['DEFAULT_WINDOW', 'DEFAULT_THRESHOLD', 'WINDUP_POINTS', 'CRANK_ANGLE_TOPIC',
           'GROUND_TRUTH_TOPIC', 'GainSums', 'misfire_scores', 'MisfireScore', 'score_detections',
           'ground_truth_events', 'event_start_ns', 'ground_truth_misfires', 'detect_edges',
           'detect_bag']

DEFAULT_WINDOW = 9          # intervals each side of the local baseline (1.5 engine cycles)
DEFAULT_THRESHOLD = 0.3     # alarm below -0.3 of the mean engine work per firing interval (M2)
TRIM = 5.0                  # the gain's fit leaves out differences beyond 5 median errors
WINDUP_POINTS = 8           # points of the mean wind-up over an interval
CRANK_ANGLE_TOPIC = 'engine/crank_angle'
GROUND_TRUTH_TOPIC = 'faults/ground_truth'


@dataclass
class GainSums:
    """The least-squares fit of the gain g (M2) accumulated over a run: the sums of
    dE*dTbar and dTbar^2 of the inlier first differences up to the TDC angle ``after_rad``
    [rad] (a live detector, :mod:`dmf_sim.monitor.misfire`, learns it window by window;
    a bag is fitted at once)."""

    num: float = 0.0
    den: float = 0.0
    after_rad: float = -math.inf

    def add(self, scores: Mapping[str, np.ndarray]) -> None:
        """The differences of a window (:func:`misfire_scores` with ``learned``) beyond
        ``after_rad``, each once."""
        label = scores.get('diff_rad')
        if label is None or not len(label):
            return
        new = scores['diff_use'] & (label > self.after_rad)
        self.num += float(scores['diff_num'][new].sum())
        self.den += float(scores['diff_den'][new].sum())
        self.after_rad = max(self.after_rad, float(label[-1]))


def misfire_scores(t_p: np.ndarray, theta_p: np.ndarray, t_w: np.ndarray, phi: np.ndarray,
                   firing_phases_rad: Sequence[float], *, offset_rad: float = 0.0,
                   window: int = DEFAULT_WINDOW,
                   spring_torque: Callable[[np.ndarray], np.ndarray] | None = None,
                   learned: GainSums | None = None) -> dict[str, np.ndarray]:
    """Scores (M2) of every firing interval with a full fit window.

    t_p, theta_p: the crank wheel's edge times [s] and angles on the crank angle
    (:func:`~dmf_sim.analysis.tooth_signals.cycle_phase`); t_w, phi: the wind-up (W1) [rad]
    at times [s]; spring_torque: the DMF characteristic T(phi) [Nm] (default: linear, Tbar
    then the mean wind-up itself). Returns the segments of ``segment_speeds`` (``cylinder``,
    ``combustion``, ``tdc_rad``, ...) of the scored intervals (each the segment whose TDC
    starts it) plus ``t_s`` (the TDC's time), ``score`` and ``windup_rad`` (the mean of the
    wind-up (W1) over the interval, from the sensors). ``learned``: the gain's fit
    accumulated over the data before (a live detector's earlier windows): the gain is
    fitted to those and this window's later differences together, as on the whole run, and
    the window's differences are returned too (``diff_rad``, ``diff_num``, ``diff_den``,
    ``diff_use``: the second TDC of each, its terms of the fit, inlier or not) for
    :meth:`GainSums.add`."""
    n_cyl = len(firing_phases_rad)
    seg = segment_speeds(t_p, theta_p, firing_phases_rad, -2.0 * math.pi / n_cyl,
                         offset_rad=offset_rad)
    w = seg['omega']
    tm = 0.5 * (seg['t0_s'] + seg['t1_s'])                 # the TDC (segment centre) times
    energy = 0.5 * np.diff(w ** 2)                           # (M1), interval i: tm_i .. tm_i+1
    frac = (np.arange(WINDUP_POINTS) + 0.5) / WINDUP_POINTS
    tt = tm[:-1, None] + np.diff(tm)[:, None] * frac[None, :]
    wind_t = np.interp(tt, t_w, phi)
    wbar = wind_t.mean(axis=1)
    tbar = wbar if spring_torque is None else spring_torque(wind_t).mean(axis=1)
    n = len(energy)
    # the spring's work per unit inertia, one factor for the run: first differences of (M1)
    # against those of Tbar (slow levels cancel; refitted without the outliers)
    de, dtq = np.diff(energy), np.diff(tbar)
    use = np.ones(len(de), bool)
    for _ in range(2):
        gain = float(np.dot(de[use], dtq[use]) / np.dot(dtq[use], dtq[use]))
        err = np.abs(de - gain * dtq)
        use = err <= TRIM * np.median(err)
    if learned is not None:
        label = seg['tdc_rad'][1:n]           # difference k: intervals k and k+1
        new = use & (label > learned.after_rad)
        num = learned.num + float(np.dot(de[new], dtq[new]))
        den = learned.den + float(np.dot(dtq[new], dtq[new]))
        gain = num / den if den > 0.0 else gain
    work = energy - gain * tbar                      # engine work per unit inertia (M2)
    score = np.full(n, np.nan)
    for i in range(window, n - window):
        left = np.median(work[i - window:i])
        right = np.median(work[i + 1:i + window + 1])
        scale = abs(gain * np.median(tbar[i - window:i + window + 1]))
        score[i] = max(work[i] - left, work[i] - right) / max(scale, 1e-300)
    ok = np.isfinite(score)
    out = {k: v[:-1][ok] for k, v in seg.items()}
    out['t_s'] = tm[:-1][ok]
    out['score'] = score[ok]
    out['windup_rad'] = wbar[ok]
    if learned is not None:
        out.update(diff_rad=label, diff_num=de * dtq, diff_den=dtq * dtq, diff_use=use)
    return out


@dataclass
class MisfireScore:
    """A detector's record against the ground truth (counts; ``per_cylinder``: cylinder ->
    {'misfires', 'detected', 'missed', 'false_alarms', 'intervals'})."""

    misfires: int
    detected: int
    false_alarms: int
    cycles: float
    per_cylinder: dict[int, dict[str, int]] = field(default_factory=dict)
    mean_speed_rpm: float = float('nan')

    @property
    def missed(self) -> int:
        return self.misfires - self.detected

    @property
    def detection_rate(self) -> float:
        return self.detected / self.misfires if self.misfires else float('nan')

    @property
    def false_alarm_rate(self) -> float:
        """False alarms per engine cycle."""
        return self.false_alarms / self.cycles if self.cycles else float('nan')

    def as_dict(self) -> dict:
        return {'misfires': self.misfires, 'detected': self.detected, 'missed': self.missed,
                'false_alarms': self.false_alarms, 'cycles': self.cycles,
                'detection_rate': self.detection_rate,
                'false_alarm_rate': self.false_alarm_rate,
                'mean_speed_rpm': self.mean_speed_rpm,
                'per_cylinder': {str(k): v for k, v in self.per_cylinder.items()}}


def score_detections(scores: dict[str, np.ndarray], misfire_tdc_rad: Sequence[float],
                     n_cyl: int, threshold: float = DEFAULT_THRESHOLD) -> MisfireScore:
    """Alarms (score < -threshold) against the ground truth's misfired TDCs [rad]; misfires
    outside the scored intervals (the settling, the ends' fit windows) are not counted."""
    tdc = scores['tdc_rad']
    alarm = scores['score'] < -threshold
    half = math.pi / n_cyl                   # TDCs are 4 pi / n_cyl apart
    truth = np.zeros(len(tdc), bool)
    for x in misfire_tdc_rad:
        if tdc.size and tdc[0] - half <= x <= tdc[-1] + half:
            k = int(np.argmin(np.abs(tdc - x)))
            if abs(tdc[k] - x) < half:
                truth[k] = True
    per = {}
    for c in range(1, n_cyl + 1):
        m = scores['cylinder'] == c
        per[c] = {'misfires': int((truth & m).sum()), 'detected': int((truth & alarm & m).sum()),
                  'missed': int((truth & ~alarm & m).sum()),
                  'false_alarms': int((~truth & alarm & m).sum()), 'intervals': int(m.sum())}
    speed = float(np.mean(scores['omega']) * 60.0 / (2.0 * math.pi)) if tdc.size else math.nan
    return MisfireScore(int(truth.sum()), int((truth & alarm).sum()),
                        int((~truth & alarm).sum()), len(tdc) / n_cyl, per, speed)


def ground_truth_events(path: str | os.PathLike | BagFiles) -> list[dict]:
    """The fault events of a bag's ground truth (``faults/ground_truth``, in any namespace), in
    the bag's order, as :func:`dmf_sim.physics.faults.event_from_values` reads them back."""
    from dmf_sim.bags.read import bag_topics
    from dmf_sim.physics.faults import event_from_values

    bag = path if isinstance(path, BagFiles) else resolve_bag(path)
    topics = [t for t in bag_topics(bag) if t.lstrip('/') == GROUND_TRUTH_TOPIC
              or t.endswith('/' + GROUND_TRUTH_TOPIC)]
    return [event_from_values(s.message, {kv.key: kv.value for kv in s.values})
            for m in read_messages(bag, topics) for s in m.msg.status]


def event_start_ns(event: dict) -> int | None:
    """The stamp [ns] a ground-truth event of :func:`ground_truth_events` starts at: its fault's
    start stamp, else the event's own (None where the status gave neither)."""
    return event['start_ns'] if event['start_ns'] is not None else event['event_ns']


def ground_truth_misfires(path: str | os.PathLike | BagFiles) -> np.ndarray:
    """The TDC crank angles [rad] of the misfired combustions in a bag's ground truth."""
    return np.asarray([ev['tdc_crank_angle_rad'] for ev in ground_truth_events(path)
                       if ev['what'] == 'misfire'], float)


def detect_edges(crank: WheelEdges, secondary: WheelEdges, crank_t_ns: np.ndarray,
                 crank_psi: np.ndarray, firing_phases_rad: Sequence[float], *,
                 spring_torque: Callable[[np.ndarray], np.ndarray] | None = None,
                 threshold: float = DEFAULT_THRESHOLD, window: int = DEFAULT_WINDOW,
                 learned: GainSums | None = None) -> dict[str, np.ndarray]:
    """The detector on the edges of the two tooth wheels around the DMF (pitch errors from the
    wheels), the engine-cycle phase from the crank angle ``crank_psi`` [rad] at
    ``crank_t_ns`` (the clock of the edges): the scores of :func:`misfire_scores` plus
    ``alarm``, times ``t_s`` from the crank wheel's first edge (``origin_ns``, also returned);
    ``learned`` as :func:`misfire_scores` takes it.
    One function for a bag (:func:`detect_bag`) and the node's monitor
    (:mod:`dmf_sim.monitor.misfire`)."""
    origin = int(crank.t_ns[0])
    tp, thp = edge_angles(crank, crank.wheel.pitch_errors_rad(), origin)
    ts, ths = edge_angles(secondary, secondary.wheel.pitch_errors_rad(), origin)
    off_p = math.radians(crank.wheel.offset_deg)
    off_s = math.radians(secondary.wheel.offset_deg)
    tw, phi = estimate_windup(tp, thp - off_p, ts, ths - off_s)
    thp = cycle_phase(tp, thp, (np.asarray(crank_t_ns) - origin) * 1e-9, crank_psi,
                      crank.wheel)
    sc = misfire_scores(tp, thp, tw, phi, firing_phases_rad, offset_rad=off_p, window=window,
                        spring_torque=spring_torque, learned=learned)
    sc['alarm'] = sc['score'] < -threshold
    sc['origin_ns'] = np.full(len(sc['score']), origin, np.int64)
    return sc


def detect_bag(path: str | os.PathLike | BagFiles, *, crank: str = 'crank',
               secondary: str = 'flywheel_secondary', threshold: float = DEFAULT_THRESHOLD,
               window: int = DEFAULT_WINDOW, skip_s: float | None = None,
               config: str | None = None) -> tuple[dict[str, np.ndarray], MisfireScore]:
    """Run the detector on a bag's tooth wheels (pitch errors from its metadata) and score it
    against its ground truth. skip_s: seconds from the first crank edge not scored (default:
    the run's settling time from the metadata); config: the driveline YAML instead of the one
    the bag names (``--config`` of ``dmf-sim analyze``). Returns the scores
    (:func:`detect_edges`) and the :class:`MisfireScore`."""
    from dmf_sim.analysis.hbm_overlay import build_model, model_settings

    bag = path if isinstance(path, BagFiles) else resolve_bag(path)
    meta = RunMetadata.from_bag_metadata(bag.metadata)
    model = build_model(model_settings(bag.metadata, config=config))
    beta = np.radians(np.asarray(model.line.firing_phases_deg, float))
    edges = read_wheel_edges(bag, [crank, secondary])
    ct_ns, psi = read_float64(bag, CRANK_ANGLE_TOPIC)
    spring = model.spring
    sc = detect_edges(edges[crank], edges[secondary], ct_ns, psi, beta,
                      spring_torque=None if spring is None else spring.torque,
                      threshold=threshold, window=window)
    skip = (meta.settle_s or 0.0) if skip_s is None else skip_s
    keep = sc['t_s'] >= skip
    sc = {k: v[keep] for k, v in sc.items()}
    return sc, score_detections(sc, ground_truth_misfires(bag), len(beta), threshold)
