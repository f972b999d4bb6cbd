"""The sensors in the live core and in ``dmf-sim run`` (ROS-free): the same physics with sensors
on or off, each chunk's signals handed to the sink (also without a sample), the messages and
their stream keys, a reset without an edge burst, sensor faults through the simulation, and an
offline bag that holds the node's sensor topics with the same layout. Over DDS:
test_sensor_node.py."""
from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from dmf_sim.bags.metadata import RunMetadata
from dmf_sim.bags.read import read_messages
from dmf_sim.bags.sensor_messages import EDGES_TYPE, decode_edges
from dmf_sim.cli import main as cli_main
from dmf_sim.live.sensors import SensorMessages
from dmf_sim.live.simulation import LiveSimulation
from dmf_sim.live.streams import SAMPLE_STREAMS, resolved_topics, streams_for
from dmf_sim.physics.model import read_driveline
from dmf_sim.physics.sensors import FLAG_SPURIOUS, parse_sensors
from dmf_sim.transient.profiles import read_profile
from dmf_sim.transient.run import RunOptions, run_profile

SENSORS = read_driveline('truck_dmf').sensors
RAMP = 'ramp:1000:1200:200:1.0:0.2'


def sim(**kw) -> LiveSimulation:
    kw.setdefault('speed_rpm', 1200.0)
    kw.setdefault('load', 0.8)
    return LiveSimulation.from_config(**kw)


def test_sensors_change_no_sample_and_cost_nothing_off():
    on, off = sim(sensors=True), sim(sensors=False)
    assert off.live_sensors is None and not len(off.integ.track_dofs)
    for n in (7, 10, 33, 100):
        a, b = on.advance(n), off.advance(n)
        assert b.sensors is None and a.sensors is not None
        for f in ('t', 'psi', 'windup', 'position', 'velocity', 'effort'):
            assert np.array_equal(getattr(a, f), getattr(b, f)), f


def test_chunks_carry_the_edges_of_their_steps():
    s = sim(sensors=True)
    per_wheel = {w: [] for w in s.live_sensors.wheel_names}
    for n in [3] * 50 + [10] * 100 + [1] * 30:            # chunks without a sample too
        chunk = s.advance(n).sensors
        assert chunk.t_end_s == pytest.approx(s.t)
        for w, name in enumerate(chunk.wheel_names):
            per_wheel[name].append(chunk.edge_rows(w).copy())
    crank = np.concatenate(per_wheel['crank'])
    assert np.array_equal(np.diff(crank[:, 1]) % 58, np.ones(len(crank) - 1))
    assert crank[-1, 0] <= s.t * 1e9
    # the mean tooth period is the pitch at 1200 rpm (vibration averages out over revolutions)
    revs = (len(crank) - 1) / 58
    assert (crank[-1, 0] - crank[0, 0]) / 1e9 / revs == pytest.approx(60 / 1200, rel=0.02)


def test_reset_gives_no_burst_of_edges():
    s = sim(sensors=True)
    s.advance(200)
    s.set_load_setpoint(0.2)
    s.reset()                                  # the state jumps to another equilibrium
    chunk = s.advance(10).sensors
    assert all(n <= 2 for n in chunk.edge_counts)


def test_sensor_faults_through_the_simulation():
    s = sim(sensors=True)
    f = SimpleNamespace(kind='sensor_edges', sensor='crank', mode='extra', rate_per_s=200.0,
                        probability=None, tooth=None, seed=1, start_s=None, end_s=None)
    s.set_sensor_faults([f])
    # (the chunks are views valid until the next advance, as the samples: copied)
    rows = np.concatenate([s.advance(10).sensors.edges('crank').flags.copy()
                           for _ in range(100)])
    assert 8 < np.sum(rows & FLAG_SPURIOUS) / FLAG_SPURIOUS < 35      # 0.1 s x 200/s: 20
    s.set_sensor_faults([])
    rows = np.concatenate([s.advance(10).sensors.edges('crank').flags.copy()
                           for _ in range(100)])
    assert not np.any(rows & FLAG_SPURIOUS)


def test_messages_of_a_chunk_and_their_keys():
    s = sim(sensors=True)
    streams = streams_for(s.line.sensors)
    # one batch per publish period (sensors.edge_batch_s 0): the batch of a 1-ms chunk
    per_tick = replace(s.line.sensors, edge_batch_s=0.0).edge_batch_ns(s.stride * s.dt)
    msgs = SensorMessages(s.live_sensors.wheel_names, s.live_sensors.signal_names, per_tick)
    epoch, offset = 1_700_000_000_000_000_000, 5
    seen = {}
    for _ in range(300):
        chunk = s.advance(10).sensors
        for key, log, data in msgs.of(chunk, epoch, offset):
            assert key in streams
            seen.setdefault(key, []).append((log, data))
            if streams[key].msgtype == EDGES_TYPE:
                t = decode_edges(data)[0]
                assert log == epoch + round(chunk.t_end_s * 1e9) + offset and t[-1] <= log
            else:
                assert len(data) == 12
    # every sensor stream (the detector's statuses come from the monitor, not the chunk)
    assert set(seen) == set(streams) - set(streams_for(None)) - {'misfire_detections'}


def test_edge_batches_of_the_node_hold_each_period_s_edges_once():
    """The node holds each wheel's edges until its batch period ends (10 ms on the shipped
    truck, 10 chunks of 1 ms): every edge goes out once, in order, in the message logged at the
    end of its period, (log - period, log], as dmf-sim run writes them."""
    s = sim(sensors=True)
    period = s.line.sensors.edge_batch_ns(s.stride * s.dt)
    assert period == 1e7
    msgs = SensorMessages(s.live_sensors.wheel_names, s.live_sensors.signal_names, period)
    epoch = 1_700_000_000_000_000_000
    sent, captured = {}, {}
    for _ in range(505):                 # 0.505 s in chunks of 1 ms: the last period unfinished
        chunk = s.advance(10).sensors
        for w, name in enumerate(chunk.wheel_names):
            captured.setdefault(name, []).append(chunk.edge_rows(w)[:, 0].copy())
        for key, log, data in msgs.of(chunk, epoch, 0):
            if key.startswith('edges/'):
                t = decode_edges(data)[0]
                assert (log - epoch) % period == 0 and log - period < t[0] and t[-1] <= log
                sent.setdefault(key[len('edges/'):], []).append(t - epoch)
    for name, parts in sent.items():
        got, want = np.concatenate(parts), np.concatenate(captured[name])
        assert len(parts) <= 50                      # one message per 10 ms at most
        assert np.array_equal(got, want[want <= round(s.t * 1e9)][:len(got)])
        assert len(want) - len(got) <= len(want) // 40   # at most the last period held
    assert len(sent['crank']) >= 45
    # stopping: the held edges go out, logged at their period's end as the others
    end = round(s.t * 1e9)
    held = msgs.held(epoch, 0)
    assert held and not msgs.held(epoch, 0)
    for key, log, data in held:
        t = decode_edges(data)[0]
        assert (log - epoch) % period == 0 and log - period < t[0]
        assert t[-1] - epoch <= end < log - epoch
        sent[key[len('edges/'):]].append(t - epoch)
    for name, parts in sent.items():                 # every edge once, in order
        assert np.array_equal(np.concatenate(parts), np.concatenate(captured[name]))


def test_run_loop_hands_every_chunk_s_signals_to_the_sink():
    from support.live_core import ListLog, ListSink

    from dmf_sim.live.pacing import Pacer
    from dmf_sim.live.run_loop import RunLoop

    class Sink(ListSink):
        def publish_sensors(self, chunk, epoch_ns, log_offset_ns):
            assert not chunk.empty and epoch_ns == loop.time.epoch_ns
            self.sensors.append(chunk.edges('crank').time_ns.copy())

    s = sim(sensors=True)
    sink = Sink()
    reads = iter(np.arange(0.0, 1.0, 1e-3))         # a clock 1 ms later at every read
    loop = RunLoop(s, Pacer(s.dt, 0.0, 0.05, 'skip'), sink, ListLog(),
                   clock=lambda: float(next(reads)))
    loop.start()
    loop.tick(0.0)                                  # fast mode: chunks of 1 ms for 10 ms
    edges = np.concatenate(sink.sensors)
    assert len(sink.sensors) >= 5 and np.all(np.diff(edges) > 0)
    assert len(edges) >= int(s.t * 1200 / 60 * 58) - 2


# ---- dmf-sim run ------------------------------------------------------------------------------

@pytest.fixture(scope='module')
def sensor_bag(tmp_path_factory):
    out = tmp_path_factory.mktemp('run') / 'bag'
    prof = read_profile(RAMP)
    return prof, out, run_profile(prof, out, RunOptions(split_s=1.0))


def test_run_bag_holds_the_sensor_topics_with_the_node_s_layout(sensor_bag):
    prof, out, summary = sensor_bag
    streams = streams_for(SENSORS)
    names = resolved_topics('', streams)
    meta = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    topics = {t['topic_metadata']['name']: t['topic_metadata']['type']
              for t in meta['topics_with_message_count']}
    assert topics == {names[k]: s.msgtype for k, s in streams.items()}
    assert parse_sensors(RunMetadata.from_bag_metadata(meta).sensors) == SENSORS
    for f in meta['files']:                       # every split file holds its own second
        assert f['duration']['nanoseconds'] <= 1e9
    period_ns = SENSORS.edge_batch_ns(1e-3)       # 1 kHz samples, batches of edge_batch_s
    assert period_ns == 1e7
    edges, bus = {}, {}
    for m in read_messages(out, raw=True):
        if m.topic.endswith('/edges'):
            t, tooth, flags = decode_edges(m.msg)
            assert len(t) and t[-1] <= m.timestamp_ns and t[0] > m.timestamp_ns - period_ns
            edges.setdefault(m.topic, []).append((t, tooth))
        elif m.topic.startswith('/vehicle_bus/'):
            bus.setdefault(m.topic, []).append(m.timestamp_ns)
    for w in SENSORS.tooth_wheels:
        t = np.concatenate([a for a, _ in edges[names[f'edges/{w.name}']]])
        tooth = np.concatenate([b for _, b in edges[names[f'edges/{w.name}']]])
        assert np.all(np.diff(t) >= 0)
        assert np.array_equal(np.diff(tooth) % w.present_teeth, np.ones(len(tooth) - 1))
    eng = np.diff(bus['/vehicle_bus/engine_speed'])
    assert np.all(np.abs(eng - 0.02e9) <= 1)      # every 20 ms, exactly
    assert summary.messages == meta['message_count']


def test_no_sensors_run_has_none_and_the_same_samples(sensor_bag, tmp_path, capsys):
    prof, out, _ = sensor_bag
    plain = tmp_path / 'plain'
    assert cli_main(['run', RAMP, '--out', str(plain), '--no-sensors', '--no-progress']) == 0
    msgs = list(read_messages(plain, raw=True))
    assert not any(m.topic.startswith(('/sensors/', '/vehicle_bus/')) for m in msgs)
    assert RunMetadata.from_bag_metadata(yaml.safe_load(
        (plain / 'metadata.yaml').read_text())['rosbag2_bagfile_information']).sensors is None
    topic = resolved_topics()[SAMPLE_STREAMS[1]]         # the wind-up: physics unchanged
    a = [m.msg for m in read_messages(out, topic, raw=True)]
    b = [m.msg for m in msgs if m.topic == topic]
    assert a == b and len(a) == round(prof.duration_s * 1000)


def test_the_fault_timeline_s_sensor_faults_act_in_their_windows():
    """Sensor faults of a schedule (the FaultTimeline of dmf_sim.physics.faults) act from their
    start to their end inside chunks (fault_windows gives the synthesis each one's window):
    spurious crank edges only within [0.05, 0.15) s, the engine speed stuck within
    [0.1, 0.2) s."""
    from dmf_sim.physics.faults import parse_faults
    s = sim(sensors=True)
    faults = parse_faults('[{kind: sensor_edges, sensor: crank, mode: extra, rate_per_s: 400, '
                          'start_s: 0.05, end_s: 0.15, seed: 3}, {kind: bus_signal, '
                          'signal: engine_speed, mode: stuck, start_s: 0.1, end_s: 0.2}]',
                          line=s.line)
    s.attach_faults(faults)
    edges, bus = [], []
    for _ in range(30):                                  # 0.3 s in chunks of 10 ms
        chunk = s.advance(100).sensors
        edges.append(chunk.edge_rows(chunk.wheel_names.index('crank')).copy())
        bus.append(np.stack(chunk.bus('engine_speed'), axis=1).copy())
    e, b = np.concatenate(edges), np.concatenate(bus)
    spur = e[(e[:, 2] & FLAG_SPURIOUS) > 0, 0] / 1e9
    assert 20 < len(spur) < 65 and spur.min() >= 0.05 and spur.max() < 0.15     # ~40
    sent = b[:, 0] / 1e9 - s.line.sensors.signal('engine_speed').delay_s
    stuck = (sent >= 0.1) & (sent < 0.2)
    held = b[np.flatnonzero(stuck)[0] - 1, 1]
    assert np.all(b[stuck, 1] == held) and len(set(b[~stuck, 1])) > 3
