"""The monitor's live misfire detector (no ROS): the node's core runs with its sensors on, the
detector scores every firing interval once, on ``faults/detections``, and its alarms are the
ground truth's misfires, no more."""
from __future__ import annotations

import math

import numpy as np
from support.live_core import StatusSink

from dmf_sim.analysis.misfire_detector import WINDUP_POINTS
from dmf_sim.live.parameters import PARAMETERS
from dmf_sim.live.runtime import LiveRuntime, read_line
from dmf_sim.live.streams import resolved_topics, streams_for
from dmf_sim.monitor.messages import values_of
from dmf_sim.monitor.misfire import dmf_wheels

NODE = '/driveline_node'


class Sink(StatusSink):
    """The runtime's statuses; the detector's and the ground truth's misfires read back; the
    true wind-up of the samples (simulated time [s], rad)."""

    def __init__(self):
        super().__init__()
        self.t, self.windup, self.psi, self.position = [], [], [], []

    def publish_samples(self, s, stamps_ns, log_ns):
        super().publish_samples(s, stamps_ns, log_ns)
        self.t += s.t.tolist()
        self.windup += s.windup.tolist()
        self.psi += s.psi.tolist()
        self.position.append(s.position.copy())

    def detections(self) -> list[dict]:
        return [values_of(s) for _, st in self.statuses.get('misfire_detections', [])
                for s in st]

    def misfires(self) -> list[dict]:
        return [e for e in self.events() if e['what'] == 'misfire']


def make(**over):
    values = {name: spec.default for name, spec in PARAMETERS.items()}
    values.update(monitor=True, monitor_worker='thread', sensors=True, pacing='fast',
                  initial_speed_rpm=1200.0, initial_load=1.0)
    values.update(over)
    line = read_line(values['driveline'])
    values.setdefault('alpha', line.dmf.alpha)
    values.setdefault('theta', line.dmf.theta)
    streams = streams_for(line.sensors)
    topics = resolved_topics('', streams)
    sink = Sink()

    class Log:
        def info(self, m):
            pass

        warning = error = info

    rt = LiveRuntime(values, line, sink, Log(), topics={topics[k]: s.msgtype
                                                        for k, s in streams.items()},
                     node_name=NODE, streams=streams)
    rt.loop.start()
    return rt, sink


def run_for(rt, seconds: float) -> None:
    end = rt.sim.t + seconds
    while rt.sim.t < end:
        with rt.lock:
            rt.loop.tick(rt.loop.clock())


def drain(rt) -> None:
    """Every window handed in analysed, and a tick that publishes what finished."""
    rt.monitor.wait_idle(120.0)
    run_for(rt, 0.002)


def test_the_default_truck_has_the_wheels_around_its_dmf():
    line = read_line(PARAMETERS['driveline'].default)
    assert dmf_wheels(line) == ('crank', 'flywheel_secondary')
    assert 'misfire_detections' in streams_for(line.sensors)


def test_live_alarms_are_the_misfires_of_the_ground_truth():
    rt, sink = make()
    try:
        run_for(rt, 1.5)                      # settle, then healthy cycles
        for _ in range(3):                    # three single misfires of cylinder 3, 0.5 s apart
            assert rt.faults.offer('{kind: misfire, cylinders: [3]}') is None
            run_for(rt, 0.5)
        run_for(rt, 0.4)                      # the last one's right baseline
        drain(rt)
    finally:
        rt.close()
    det = sink.detections()
    truth = sink.misfires()
    assert len(truth) == 3
    # every interval once, in order, the six cylinders in turn
    tdc = np.array([float(d['tdc_crank_angle_rad']) for d in det])
    assert np.all(np.diff(tdc) > 0)
    assert np.allclose(np.diff(tdc), 4 * math.pi / 6, atol=1e-5)   # 9 digits of text
    speed = 1200.0 * 2 * math.pi / 60
    cycles = (float(det[-1]['tdc_time_s']) - float(det[0]['tdc_time_s'])) * speed / (4 * math.pi)
    assert cycles > 15                       # 2.9 s of 12.5 cycles/s, less the start-up
    alarms = [d for d in det if d['alarm'] == 'true']
    half = math.pi / 6                       # half a firing interval [rad]
    for ev in truth:
        hit = [a for a in alarms if abs(float(a['tdc_crank_angle_rad'])
                                        - ev['tdc_crank_angle_rad']) < half]
        assert len(hit) == 1 and int(hit[0]['cylinder']) == ev['cylinder'] == 3
    assert len(alarms) == len(truth)         # no false alarm
    # each message is about its last interval's TDC (its stamp) and recorded when it is sent,
    # a sample stamp later: a bag's log times stay in the order of sending
    stamps = [st for st, _ in sink.statuses['misfire_detections']]
    sent = sink.sent['misfire_detections']
    assert all(b > a for a, b in zip(stamps, sent)) and sent == sorted(sent)
    counters = rt.monitor.counters
    assert counters['misfire_alarms'] == 3 and counters['intervals_scored'] == len(det)


def test_no_alarm_through_a_speed_ramp_and_a_load_step_nor_after_a_reset():
    rt, sink = make(speed_ramp_rpm_per_s=400.0, load_ramp_per_s=10.0)
    try:
        run_for(rt, 1.0)
        rt.loop.inbox.offer('speed', 1600.0)          # a 1 s run-up
        run_for(rt, 1.5)
        rt.loop.inbox.offer('load', 0.3)              # a tip-out in 0.07 s
        run_for(rt, 1.0)
        rt.reset()                                    # the motion jumps: the detector restarts
        run_for(rt, 1.0)
        drain(rt)
    finally:
        rt.close()
    det = sink.detections()
    tdc = [float(d['tdc_crank_angle_rad']) for d in det]
    assert tdc == sorted(set(tdc))                             # each interval once
    speeds = [float(d['speed_rpm']) for d in det]
    assert min(speeds) < 1250 and max(speeds) > 1550          # the ramp was scored
    assert [d for d in det if d['alarm'] == 'true'] == []
    assert not sink.misfires()


def test_the_segment_speed_and_wind_up_from_the_sensors_are_the_true_ones():
    """Each scored interval carries its crank speed and mean DMF wind-up made from the tooth
    edges alone: against the true wind-up's mean over the same interval (the samples at 1 kHz)
    within 1 % of its swing, and the primary flywheel's true mean speed over the segment
    (TDC -+ 60 deg) within 0.5 rpm."""
    rt, sink = make()
    try:
        run_for(rt, 2.0)
        drain(rt)
    finally:
        rt.close()
    det = sink.detections()
    assert len(det) > 60
    t, w = np.array(sink.t), np.array(sink.windup)
    # the primary flywheel's true angle on the crank angle (the crank wheel's element)
    theta = np.array(sink.psi) + np.concatenate(sink.position)[:, rt.sim.names.index(
        'PRIMARY FLYWHEEL')]
    frac = (np.arange(WINDUP_POINTS) + 0.5) / WINDUP_POINTS   # the detector's quadrature
    width = 4 * math.pi / 6                      # a segment: TDC -+ 60 deg of crank angle
    err, rpm_err = [], []
    for d, nxt in zip(det, det[1:]):             # an interval: from its TDC to the next one
        t0, t1 = float(d['tdc_time_s']), float(nxt['tdc_time_s'])
        true = np.interp(t0 + (t1 - t0) * frac, t, w).mean()
        err.append(float(d['windup_sensors_rad']) - true)
        tdc = float(d['tdc_crank_angle_rad'])
        ta, tb = np.interp([tdc - width / 2, tdc + width / 2], theta, t)
        rpm_err.append(float(d['speed_rpm']) - width / (tb - ta) * 60 / (2 * math.pi))
    swing = w[t > 1.0].max() - w[t > 1.0].min()
    assert np.abs(err).max() < 0.01 * swing, (np.abs(err).max(), swing)
    assert np.abs(rpm_err).max() < 0.5, np.abs(rpm_err).max()      # [rpm]
