"""The live node's ROS-free core: pacing, stamps, the tick loop, setpoints, health, recording,
parameters and the runtime that wires them — all without DDS (fake clocks, a list as sink)."""
from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml
from support.live_core import ListLog, ListSink, new_loop, new_sim

from dmf_sim.bags.metadata import RunMetadata
from dmf_sim.core.errors import ConfigError, DmfSimError
from dmf_sim.core.numbers import fmt_num
from dmf_sim.live.health import ERROR, OK, WARN, HealthMonitor, HealthReport
from dmf_sim.live.pacing import LagStats, Pacer, TimeBase, publish_stride
from dmf_sim.live.parameters import DMF_PARAMETERS, PARAMETERS, coerce
from dmf_sim.live.recording import RecordingControl, run_metadata
from dmf_sim.live.run_loop import SetpointInbox
from dmf_sim.live.runtime import LiveRuntime, read_line
from dmf_sim.live.simulation import check_setpoint, ramp_toward, split_steps

REPO = Path(__file__).resolve().parents[2]
TOPICS = {'/driveline/joint_states': 'sensor_msgs/msg/JointState',
          '/driveline/dmf_windup': 'std_msgs/msg/Float64'}


# ================================================================================================
# Small functions, pacing, stamps
# ================================================================================================

def test_check_setpoint_and_ramp():
    assert check_setpoint(1000.0, 500, 2200, 'speed', 'rpm') is None
    assert check_setpoint(500, 500, 2200, 'speed') is None
    for bad, word in ((float('nan'), 'NaN'), (float('inf'), 'inf'), (-float('inf'), 'inf'),
                      (-5.0, 'outside'), (1e9, 'outside'), (True, 'number'), ('1', 'number')):
        assert word in check_setpoint(bad, 500, 2200, 'speed', 'rpm')
    assert ramp_toward(0.0, 1.0, 2.0, 0.1) == pytest.approx(0.2)
    assert ramp_toward(0.95, 1.0, 2.0, 0.1) == 1.0
    assert ramp_toward(1.0, 0.0, 2.0, 0.1) == pytest.approx(0.8)


def test_refused_setpoint_shows_every_digit_that_refuses_it():
    """2200.001 rpm was logged as '2200 rpm outside [500, 2200] rpm'."""
    assert check_setpoint(2200.001, 500.0, 2200.0, 'speed setpoint', 'rpm') == \
        'speed setpoint 2200.001 rpm outside [500, 2200] rpm'
    assert '2200.0000000001' in check_setpoint(2200.0000000001, 500.0, 2200.0, 'speed', 'rpm')
    assert '499.99999' in check_setpoint(499.99999, 500.0, 2200.0, 'speed', 'rpm')
    assert (fmt_num(2200.0), fmt_num(0.1), fmt_num(1e-4)) == ('2200', '0.1', '0.0001')


def test_publish_stride_refuses_rates_the_step_cannot_divide():
    assert publish_stride(1000.0, 1e-4) == 10
    assert publish_stride(10000.0, 1e-4) == 1
    assert publish_stride(200.0, 1e-4) == 50
    assert publish_stride(0.1, 1e-4) == 100000
    assert publish_stride(1000.0, 5e-5) == 20
    # 3000 Hz was accepted and published at 3333.33 Hz
    with pytest.raises(ConfigError, match=r'3000 Hz is not a whole number.*3333\.33 Hz \(every 3 '
                                          r'steps\) or 2500 Hz \(every 4 steps\)'):
        publish_stride(3000.0, 1e-4)
    with pytest.raises(ConfigError, match=r'^publish_rate 20000 Hz is faster than the step rate '
                                          r'of dt = 0\.0001 s \(10000 Hz\): give publish_rate '
                                          r'10000 Hz or less, or dt 5e-05 s or less$'):
        publish_stride(20000.0, 1e-4)
    for bad in (0.0, -1.0, float('nan')):
        with pytest.raises(ConfigError):
            publish_stride(bad, 1e-4)


@pytest.mark.parametrize('where', [('q', 7), ('v', 11), ('q', 0), ('v', -1)])
def test_a_non_finite_state_anywhere_is_never_published_and_restarts_the_solver(where):
    """A NaN in any one DOF's angle or rate (here put there by hand; in practice bad data) is
    caught within the next chunk: nothing non-finite is published, the solver restarts from
    static equilibrium at the setpoints and counts it, time goes on."""
    sim = new_sim()
    sim.advance(2000)
    t0 = sim.t
    name, dof = where
    getattr(sim.integ, name)[dof] = np.nan
    s = sim.advance(50)
    assert sim.solver_resets == 1 and sim.finite
    assert all(np.all(np.isfinite(getattr(s, f))) for f in ('position', 'velocity', 'effort'))
    assert sim.t == pytest.approx(t0 + 50 * sim.dt)
    s = sim.advance(500)
    assert sim.solver_resets == 1 and len(s) > 0 and np.all(np.isfinite(s.position))


def test_split_steps_records_exactly_every_stride():
    """Chunks of any size record the same absolute steps as one long run would."""
    for stride in range(1, 6):
        rng = np.random.default_rng(stride)
        phase, done, recorded = 0, 0, []
        for n in rng.integers(0, 3 * stride + 2, size=60):
            calls, new_phase = split_steps(int(n), phase, stride)
            assert sum(c[0] for c in calls) == n
            step = done
            for k, s, rows in calls:      # what NewmarkIntegrator.advance records
                got = [step + j + 1 for j in range(k) if (j + 1) % s == 0]
                assert len(got) == rows
                recorded += got
                step += k
            done += int(n)
            phase = new_phase
        assert recorded == list(range(stride, done + 1, stride))


def test_pacer_locks_to_wall_clock_and_handles_overruns():
    p = Pacer(1e-3, 1.0, max_lag=0.05, policy='skip')
    p.anchor(100.0, 0)
    plan = p.plan(100.0105, 0)
    assert plan.nsteps == 10 and plan.lag == pytest.approx(0.0105) and not plan.overrun
    assert p.due_wall(10) == pytest.approx(100.01)
    p.set_rate(2.0, 100.0105, 10)                       # no jump on a rate change
    assert p.plan(100.0205, 10).nsteps == 20
    # skip: backlog dropped, re-anchored, counted once, reported
    plan = p.plan(101.0, 30)
    assert plan.overrun and plan.nsteps == 0 and plan.skipped == pytest.approx(0.9795)
    assert p.overruns == 1 and p.plan(101.001, 30).nsteps == 2
    # catch_up: bounded bursts, one overrun per episode
    c = Pacer(1e-3, 1.0, max_lag=0.05, policy='catch_up')
    c.anchor(0.0, 0)
    first = c.plan(1.0, 0)
    assert first.overrun and first.nsteps == 50
    second = c.plan(1.0, 50)
    assert not second.overrun and second.nsteps == 50 and c.overruns == 1
    assert c.plan(1.0, 990).nsteps == 10 and not c.behind
    # next tick at the next sample's due time, clamped
    p2 = Pacer(1e-4, 1.0)
    p2.anchor(0.0, 0)
    assert p2.next_tick(0.0003, 10) == pytest.approx(0.001)
    assert p2.next_tick(0.0003, 1000) == pytest.approx(0.0103)
    with pytest.raises(ConfigError):
        Pacer(1e-4, policy='wait')


def test_lag_stats():
    s = LagStats()
    s.add(0.001)
    s.add(np.array([0.002, 0.003]))
    s.add([])
    w = s.take_window()
    assert w['n'] == 3 and w['max'] == pytest.approx(0.003)
    assert s.take_window()['n'] == 0
    assert s.total_percentile(50) == pytest.approx(0.002, abs=2 * LagStats.BIN)


def test_time_base_reanchors_stamps_and_keeps_log_times_continuous():
    tb = TimeBase()
    tb.start(1000 * 10**9, 0.0)
    assert tb.stamp_ns(1.5) == 1001_500_000_000
    tb.skip(0.25)                                   # overrun skip: both jump ahead
    assert tb.stamp_ns(1.5) == 1001_750_000_000 and tb.log_offset_ns == 0
    # 30 s simulated by wall time 1004.25 s (fast pacing), then back to real time
    assert tb.reanchor(1004_250_000_000, 30.0) == pytest.approx(-26.0)
    assert tb.stamp_ns(30.0) == 1004_250_000_000
    assert tb.stamp_ns(30.0) + tb.log_offset_ns == 1030_250_000_000     # log time continuous
    assert tb.reanchors == 1 and tb.last_jump_s == pytest.approx(-26.0)
    assert tb.reanchor(1005_250_000_000, 30.5) == pytest.approx(0.5)     # forward: no offset
    assert tb.log_offset_ns == 26 * 10**9
    tb.new_recording()
    assert tb.log_offset_ns == 0
    np.testing.assert_array_equal(tb.stamps_ns(np.array([30.5, 30.501])),
                                  [1005_250_000_000, 1005_251_000_000])


# ================================================================================================
# The tick loop (fake clock, list sink)
# ================================================================================================

def test_run_loop_publishes_due_samples_with_wall_clock_stamps():
    loop, clock, sink, _ = new_loop()
    seen = []
    loop.observers.append(lambda s, stamps: seen.extend(s.step.tolist()))   # hook: every chunk
    for k in range(1, 51):
        clock.now = k * 0.002
        loop.tick(clock.now)
    assert len(sink.t) == 100 and seen == list(range(10, 1001, 10))
    wall0 = int(round(clock.wall0 * 1e9))
    np.testing.assert_allclose(np.array(sink.stamps) - wall0, np.array(sink.t) * 1e9, atol=1)
    assert sink.logs == sink.stamps and sink.clock == []      # /clock off at factor 1
    assert loop.lag.count == 100 and loop.lag.max < 0.0025
    assert abs(loop.wall_minus_stamp_s()) < 0.002


def test_overrun_lag_is_in_the_lag_statistics():
    """``lag_max_ms_total`` (45 ms) left out the 65 ms overrun the log reported."""
    loop, clock, sink, log = new_loop()
    health = HealthMonitor(loop, cpu_clock=lambda: 0.0)
    health.start(0.0)
    clock.now = 0.01
    loop.tick(clock.now)
    clock.now = 0.01 + 0.0652                    # the process stalled for 65 ms
    loop.tick(clock.now)
    assert loop.pacer.overruns == 1 and loop.lag.max == pytest.approx(0.0652, abs=1e-3)
    assert 'overrun: 65' in log.text('warning')
    clock.now += 0.002
    loop.tick(clock.now)                          # live again at once
    report = health.report(clock.now)
    assert float(report.values['lag_max_ms_total']) == pytest.approx(65.2, abs=1.0)
    assert float(report.values['lag_max_ms']) == pytest.approx(65.2, abs=1.0)
    assert report.level == WARN and '1 overrun(s)' in report.message
    assert float(report.values['skipped_s']) == pytest.approx(0.0652, abs=1e-3)


def test_fast_then_real_time_reanchors_stamps_log_times_stay_monotonic():
    """After fast pacing and back, stamps stayed 27 s ahead of the wall clock."""
    loop, clock, sink, log = new_loop()
    for k in range(1, 11):
        clock.now = k * 0.002
        loop.tick(clock.now)
    assert loop.set_rate(0.0) is None and loop.clock_on
    clock.auto = 1e-4                                # the fast loop reads the clock
    for _ in range(20):
        loop.tick(clock())
    clock.auto = 0.0
    ahead = -loop.wall_minus_stamp_s()
    assert ahead > 0.3 and len(sink.clock) > 0        # simulated time ran ahead of the wall
    n_fast = len(sink.stamps)
    msg = loop.set_rate(1.0)
    assert 're-anchored to the wall clock' in msg and 'jumped back' in msg
    assert msg in log.text('info')
    assert abs(loop.wall_minus_stamp_s()) < 1e-6 and loop.time.reanchors == 1
    t_switch = clock.now
    for k in range(1, 11):
        clock.now = t_switch + k * 0.002
        loop.tick(clock.now)
    stamps, logs = np.array(sink.stamps), np.array(sink.logs)
    assert stamps[n_fast] < stamps[n_fast - 1]                       # stamps jumped back ...
    assert stamps[-1] / 1e9 == pytest.approx(clock.wall0 + clock.now, abs=0.003)   # ... to wall
    assert np.all(np.diff(logs) > 0)                                  # bag log times monotonic
    np.testing.assert_allclose(np.diff(logs), np.diff(sink.t) * 1e9, atol=2)   # and continuous
    assert np.all(np.diff(sink.psi) > 0)


def test_setpoint_inbox_counts_every_arrival_and_keeps_the_last_valid():
    sim = new_sim()
    inbox = SetpointInbox({'speed': sim.check_speed_setpoint, 'load': sim.check_load_setpoint})
    values = [float('nan'), 1234.5, 3000.0, 1300.0] + [float('inf'), 1e9, -1.0] * 33 + [499.0]
    reasons = [inbox.offer('speed', v) for v in values]
    assert inbox.received['speed'] == len(values) == 104
    assert inbox.rejected['speed'] == sum(r is not None for r in reasons) == 102
    assert inbox.take() == {'speed': 1300.0} and inbox.take() == {}
    # a flood from another thread while the tick thread takes: the last valid one wins
    good = [900.0 + i for i in range(0, 1000, 10)]

    def flood():
        for i in range(10_000):
            inbox.offer('load', 0.25 if i == 9_899 else (2.0 if i % 3 else float('nan')))
            if i % 100 == 50:
                inbox.offer('speed', good[i // 100])

    th = threading.Thread(target=flood)
    taken = []
    th.start()
    while th.is_alive():
        taken.append(inbox.take())
    th.join()
    taken.append(inbox.take())
    last = {}
    for d in taken:
        last.update(d)
    assert last == {'speed': good[-1], 'load': 0.25}
    assert inbox.received['load'] == 10_000 and inbox.rejected['load'] == 9_999
    assert inbox.total('received') == 104 + 10_100


def test_run_loop_applies_setpoints_at_the_next_tick_and_notifies_listeners():
    loop, clock, sink, log = new_loop()
    changes = []
    loop.setpoint_listeners.append(lambda v, load: changes.append((v, load)))
    assert loop.inbox.offer('speed', 1500.0) is None
    assert 'outside' in loop.inbox.offer('speed', 2200.001)
    assert loop.inbox.offer('load', 0.9) is None
    assert loop.sim.speed_setpoint == 1000.0              # not before the tick
    clock.now = 0.002
    loop.tick(clock.now)
    assert (loop.sim.speed_setpoint, loop.sim.load_setpoint) == (1500.0, 0.9)
    assert changes == [(1500.0, 0.9)]
    # valid on arrival, but the limits changed before the tick: refused and counted
    assert loop.inbox.offer('speed', 2000.0) is None
    assert loop.sim.set_speed_limits(500.0, 1800.0) is None
    clock.now = 0.004
    loop.tick(clock.now)
    assert loop.sim.speed_setpoint == 1500.0 and loop.refused_on_apply == 1
    assert 'limits changed' in log.text('warning')


def test_health_report_levels_values_and_contributors():
    loop, clock, sink, _ = new_loop()
    health = HealthMonitor(loop, cpu_clock=lambda: 0.0)
    health.start(0.0)
    for k in range(1, 6):
        clock.now = k * 0.002
        loop.tick(clock.now)
    r = health.report(clock.now)
    assert r.level == OK and r.problems == [] and r.message.startswith('realtime x1.000')
    assert r.values['real_time_factor'] == '1.0000' and r.values['dmf_region'] == 'primary'
    assert r.values['alpha'] == '2.5' and r.values['setpoints_received'] == '0'
    loop.inbox.offer('speed', float('nan'))
    loop.inbox.count_lost('load', 3)
    health.contributors.append(lambda rep: (rep.values.update(alarm='1.5th order'),
                                            rep.problem('sub-harmonic state', ERROR)))
    clock.now += 0.002
    loop.tick(clock.now)
    r = health.report(clock.now)
    assert r.level == ERROR and r.values['alarm'] == '1.5th order'
    assert r.message == ('1 setpoint(s) rejected; 3 setpoint(s) lost before they reached the '
                         'node; sub-harmonic state')
    assert (r.values['rejected_setpoints'], r.values['setpoints_lost']) == ('1', '3')
    rep = HealthReport(summary='fine')
    assert rep.message == 'fine' and rep.level == OK


# ================================================================================================
# Recording lifecycle
# ================================================================================================

class SplittingRecorder:
    """Stands in for a bag writer that takes max_duration_s (to test that it is handed on)."""

    def __init__(self, path, topics, *, custom_data=None, max_duration_s=60.0):
        self.path, self.topics, self.custom_data = Path(path), topics, custom_data
        self.max_duration_s, self.message_count, self.closed = max_duration_s, 0, False
        self.path.mkdir(parents=True)

    def write(self, topic, log_ns, data):
        raise OSError(28, 'No space left on device')

    def close(self):
        self.closed = True


def test_recording_lifecycle(tmp_path, monkeypatch):
    log = ListLog()
    rc = RecordingControl(TOPICS, log, max_duration_s=30.0)
    sim = new_sim()
    meta = run_metadata(sim, driveline='truck_dmf', engine='engine_d13', node='/truck1/dn',
                        publish_rate_hz=1000.0)
    assert RunMetadata.from_custom_data(meta.to_custom_data()) == meta
    existing = tmp_path / 'existing'
    existing.mkdir()
    assert 'exists already' in rc.check(str(existing))
    rec, reason = rc.prepare(str(existing), meta)
    assert rec is None and 'exists already' in reason
    # missing parents are created (as rosbag2 does) and the created directory is logged
    rec, reason = rc.prepare(str(tmp_path / 'a' / 'b' / 'bag1'), meta)
    assert reason is None and (tmp_path / 'a' / 'b' / 'bag1' / 'metadata.yaml').is_file()
    assert f'created directory {tmp_path / "a"} for bag' in log.text('info')
    rc.start(rec)
    assert log.text('info').count('recording to') == 1 and rc.active
    assert "applies to the next recording; still recording to" in rc.note_bag_path('next')
    for i in range(5):
        rc.write('/driveline/dmf_windup', 10**9 + i, b'\x00\x01\x00\x00' + bytes(8))
    msg = rc.stop()
    assert msg == f'stopped recording: bag {tmp_path / "a" / "b" / "bag1"} closed, 5 messages'
    assert rc.stop() == 'not recording' and rc.note_bag_path('x') is None
    meta_yaml = yaml.safe_load((tmp_path / 'a/b/bag1/metadata.yaml').read_text())
    info = meta_yaml['rosbag2_bagfile_information']
    assert info['message_count'] == 5
    assert info['custom_data']['dmf_sim.node'] == '/truck1/dn'
    # the default name, never an existing one
    monkeypatch.chdir(tmp_path)
    first = rc.target('')
    first.mkdir()
    assert rc.target('') != first and rc.target('').name.startswith(first.name)
    # a writer that splits gets max_duration_s; a failing write stops the recording only
    split = RecordingControl(TOPICS, log, max_duration_s=30.0, recorder_class=SplittingRecorder)
    assert split.splits_supported
    rec, _ = split.prepare(str(tmp_path / 'split'), meta)
    assert rec.max_duration_s == 30.0 and rec.custom_data['dmf_sim.driveline'] == 'truck_dmf'
    split.start(rec)
    split.write('/driveline/dmf_windup', 1, b'')
    assert not split.active and 'No space left' in split.error and rec.closed
    assert 'stopped: ' in log.text('error')


# ================================================================================================
# Parameters and the runtime
# ================================================================================================

def test_params_file_matches_parameter_table():
    cfg = yaml.safe_load((REPO / 'config' / 'driveline_node.yaml').read_text())
    params = cfg['/**/driveline_node']['ros__parameters']
    assert set(params) == set(PARAMETERS)
    for name, value in params.items():
        spec = PARAMETERS[name]
        assert value == spec.default and type(value) is type(spec.default), name
        assert spec.description
        if spec.range is not None:
            assert spec.range[0] <= spec.default <= spec.range[1]
    assert set(DMF_PARAMETERS) == {'alpha', 'theta'}


def test_integers_are_accepted_for_float_parameters():
    """'ros2 param set /driveline_node speed_ramp_rpm_per_s 1000' was refused."""
    assert coerce('speed_ramp_rpm_per_s', 1000) == 1000.0
    assert type(coerce('speed_ramp_rpm_per_s', 1000)) is float
    assert type(coerce('alpha', 3)) is float
    assert coerce('record', True) is True and coerce('real_time_factor', True) is True
    assert coerce('load_set', 'B') == 'B' and coerce('bag_path', 5) == 5


def runtime_values(**over):
    values = {name: spec.default for name, spec in PARAMETERS.items()}
    values.update(alpha=2.5, theta=0.24)
    values.update(over)
    return values


def make_runtime(**over):
    log, sink = ListLog(), ListSink()
    values = runtime_values(**over)
    rt = LiveRuntime(values, read_line(values['driveline']), sink, log, topics=TOPICS,
                     node_name='/truck1/driveline_node')
    return rt, log


@pytest.mark.parametrize('over, words', [
    ({'driveline': 'no_such_driveline'}, "parameter 'driveline'"),
    ({'engine': 'no_such_engine'}, "parameter 'engine'"),
    ({'pacing': 'slow'}, 'pacing must be one of'),
    ({'overrun_policy': 'wait'}, 'overrun_policy must be one of'),
    ({'publish_rate': 3000.0}, 'not a whole number of steps'),
    ({'initial_speed_rpm': 3000.0}, 'initial_speed_rpm 3000 rpm outside'),
    ({'speed_max_rpm': 4000.0}, 'engine data range'),
    ({'theta': -0.1}, 'alpha/theta'),
])
def test_bad_start_up_configuration_is_one_config_error(over, words):
    with pytest.raises(ConfigError) as exc:
        if 'driveline' in over:
            read_line(over['driveline'])
        make_runtime(**over)
    assert words in str(exc.value) and '\n' not in str(exc.value)
    assert isinstance(exc.value, DmfSimError)


def test_runtime_validates_then_applies_parameter_changes(tmp_path):
    rt, log = make_runtime()
    refused = {'publish_rate': (3000.0, '3333.33 Hz'), 'pacing': ('slow', 'pacing'),
               'speed_max_rpm': (3000.0, 'engine data range'), 'theta': (0.0, 'theta'),
               'load_set': ('D', 'load_set'), 'overrun_policy': ('wait', 'overrun')}
    for name, (value, word) in refused.items():
        reason = rt.check({name: value})
        assert reason and word in reason, (name, reason)
    assert rt.check({'publish_rate': 2500.0}) is None
    assert rt.apply({'publish_rate': 2500.0}) == [] and rt.sim.stride == 4
    assert rt.loop.publish_rate_hz == pytest.approx(2500.0)
    assert rt.check({'alpha': 3.0}) is None
    assert rt.apply({'alpha': 3.0})[0].startswith('DMF rebuilt: alpha=3')
    assert rt.sim.model.spring.alpha == 3.0
    # recording: check creates the bag, apply starts it; a bag_path while recording is for later
    bag = tmp_path / 'rt_bag'
    assert rt.check({'bag_path': str(bag)}) is None
    rt.apply({'bag_path': str(bag)})
    assert rt.check({'record': True}) is None and bag.is_dir() and not rt.recording.active
    assert rt.apply({'record': True}) == [f'recording to {bag}']
    assert rt.recording.active and rt.loop.time.log_offset_ns == 0
    (msg,) = rt.apply({'bag_path': str(tmp_path / 'next_bag')})
    assert 'applies to the next recording' in msg and str(bag) in msg
    (msg,) = rt.apply({'record': False})
    assert msg == f'stopped recording: bag {bag} closed, 0 messages'
    assert 'exists already' in rt.check({'bag_path': str(bag), 'record': True})
    # pacing: fast, then back to real time re-anchors the stamps
    assert rt.apply({'pacing': 'fast'}) == [] and rt.loop.clock_on
    (msg,) = rt.apply({'pacing': 'realtime'})
    assert 're-anchored' in msg and not rt.loop.clock_on
    assert rt.apply({'publish_clock': True}) == [] and rt.loop.clock_on
    assert rt.reset().startswith('reset to static equilibrium at 1000 rpm')


@pytest.mark.slow
def test_node_module_imports_and_refuses_cleanly_without_ros():
    code = ("import sys; sys.modules['rclpy'] = None\n"
            "import dmf_sim.node as n\n"
            "assert n.ROS_IMPORT_ERROR is not None and 'record' in n.PARAMETERS\n"
            "sys.exit(n.main([]))")
    res = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 2, res.stderr
    assert 'ROS 2 Python packages missing' in res.stderr and 'Traceback' not in res.stderr


# ================================================================================================
# The launch file (the launch / launch_ros packages are not on the package index: their API is
# recorded by small stand-ins, which checks how the file wires its arguments into the node)
# ================================================================================================

def test_launch_file_declares_namespace_params_record_and_wires_them(monkeypatch):
    import runpy
    import types

    class Recorded:
        def __init__(self, *args, **kwargs):
            self.args, self.kwargs = args, kwargs

        def __eq__(self, other):
            return (type(self) is type(other) and self.args == other.args
                    and self.kwargs == other.kwargs)

    modules = {}
    for mod, names in {'launch': ['LaunchDescription'],
                       'launch.actions': ['DeclareLaunchArgument'],
                       'launch.substitutions': ['LaunchConfiguration', 'PathJoinSubstitution'],
                       'launch_ros': [], 'launch_ros.actions': ['Node'],
                       'launch_ros.parameter_descriptions': ['ParameterValue'],
                       'launch_ros.substitutions': ['FindPackageShare']}.items():
        m = modules[mod] = types.ModuleType(mod)
        for name in names:
            setattr(m, name, type(name, (Recorded,), {}))
        monkeypatch.setitem(sys.modules, mod, m)
    ns = runpy.run_path(str(REPO / 'launch' / 'driveline.launch.py'))
    desc = ns['generate_launch_description']()
    (entities,) = desc.args
    arguments = {a.args[0]: a.kwargs for a in entities[:-1]}
    assert set(arguments) == {'namespace', 'params_file', 'record', 'bag_path'}
    assert arguments['namespace']['default_value'] == ''
    assert arguments['record']['default_value'] == 'false'
    assert arguments['record']['choices'] == ['true', 'false']
    default_params = arguments['params_file']['default_value']
    (parts,) = default_params.args
    assert parts[0].args == ('dmf_sim',) and parts[1:] == ['config', 'driveline_node.yaml']
    node = entities[-1]
    config = modules['launch.substitutions'].LaunchConfiguration
    value = modules['launch_ros.parameter_descriptions'].ParameterValue
    assert node.kwargs['package'] == 'dmf_sim' and node.kwargs['executable'] == 'driveline_node'
    assert node.kwargs['namespace'] == config('namespace')
    params_file, overrides = node.kwargs['parameters']
    assert params_file == config('params_file')
    assert overrides == {'record': value(config('record'), value_type=bool),
                         'bag_path': value(config('bag_path'), value_type=str)}
    assert set(overrides) <= set(PARAMETERS)
    # the installed params file's key matches the node in any namespace
    cfg = yaml.safe_load((REPO / 'config' / 'driveline_node.yaml').read_text())
    assert list(cfg) == ['/**/driveline_node']


def test_start_lines_say_topics_rates_where_to_look_and_how_to_stop(tmp_path):
    """``make node`` printed one line, then nothing; the node now says what
    it publishes at which rate, where to look and how to stop (and which bag Ctrl-C closes)."""
    from dmf_sim.live.streams import STREAMS

    resolved = {k: '/truck1/' + s.topic if not s.topic.startswith('/') else s.topic
                for k, s in STREAMS.items()}
    rt, _ = make_runtime(publish_rate=500.0, diagnostics_rate=2.0, monitor=False,
                         record=True, bag_path=str(tmp_path / 'b'))
    try:
        lines = rt.ready_lines(resolved)
    finally:
        rt.close()
    text = '\n'.join(lines)
    assert lines[0].startswith('publishing /truck1/driveline/joint_states, ')
    assert '/truck1/engine/crank_angle at 500 Hz' in lines[0]
    assert '/diagnostics at 2 Hz' in lines[0]
    assert 'dmf_predicted' not in text                      # no monitor: not promised
    assert 'dmf-sim monitor --namespace /truck1' in text
    assert 'ros2 topic hz /truck1/engine/speed' in text
    assert lines[-1] == f'stop: Ctrl-C or SIGTERM (closes the bag {tmp_path / "b"})'
    # with sensors: the edge batches' period is the driveline's (10 ms on the shipped truck)
    from dmf_sim.live.streams import resolved_topics, streams_for
    values = runtime_values(monitor=False, sensors=True)
    line = read_line(values['driveline'])
    streams = streams_for(line.sensors)
    topics = resolved_topics('', streams)
    rt = LiveRuntime(values, line, ListSink(), ListLog(),
                     topics={topics[k]: st.msgtype for k, st in streams.items()},
                     node_name='/driveline_node', streams=streams)
    try:
        text = '\n'.join(rt.ready_lines(topics))
    finally:
        rt.close()
    assert 'sensors: edge batches /sensors/crank/edges' in text and 'every 10 ms; bus' in text
