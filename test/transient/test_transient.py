"""Transient runs: profiles and their one-line errors, the profile followed exactly,
the node's messages encoded in bulk, block writing equal to per-message writing, a run bag read
by analyze, an interrupted run leaves a readable bag, a slow run-up follows the HBM branch."""
from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from dmf_sim.analysis.pipeline import AnalysisOptions, analyze_bag
from dmf_sim.bags.columns import joint_state_layout
from dmf_sim.bags.layout import resolve_bag
from dmf_sim.bags.metadata import RunMetadata
from dmf_sim.bags.sensor_messages import decode_edges
from dmf_sim.bags.writer import BagRecorder
from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import ConfigError, OperatingRangeError
from dmf_sim.live.streams import SAMPLE_STREAMS, STREAMS, resolved_topics, streams_for
from dmf_sim.physics.model import read_driveline
from dmf_sim.physics.sensors import parse_sensors
from dmf_sim.transient.encode import SampleEncoder
from dmf_sim.transient.profiles import profile_from_table, ramp_profile, read_profile
from dmf_sim.transient.run import RunOptions, run_profile

REPO = Path(__file__).resolve().parents[2]
STORE = get_typestore(Stores.ROS2_JAZZY)


@pytest.fixture(scope='module')
def run_bag(tmp_path_factory):
    """A short run-up through a knee crossing: 1000 -> 1300 rpm at 150 rpm/s after 0.3 s."""
    out = tmp_path_factory.mktemp('run') / 'runup'
    prof = read_profile('ramp:1000:1300:150:1.0:0.3')
    summary = run_profile(prof, out, RunOptions(split_s=1.0))
    return prof, out, summary


# ---------------------------------------------------------------------------------- profiles

def test_profiles_from_csv_yaml_ramp_and_packaged(tmp_path):
    csv = tmp_path / 'p.csv'
    csv.write_text('# a comment\ntime_s,speed_rpm,load\n0,800,0.2\n5,1200,1\n10,1200,0.5\n')
    p = read_profile(csv)
    assert p.duration_s == 10 and p.at(2.5)[0] == pytest.approx(1000.0)
    assert p.at(7.5)[1] == pytest.approx(0.75)
    y = tmp_path / 'p.yaml'
    y.write_text(yaml.safe_dump({'name': 'x', 'points': [[0, 800, 0.2], [5, 1200, 1.0]]}))
    assert read_profile(y).name == 'x'
    y.write_text(yaml.safe_dump({'ramp': {'from_rpm': 2000, 'to_rpm': 800,
                                          'rate_rpm_per_s': 100, 'settle_s': 1}}))
    down = read_profile(y)
    assert down.duration_s == pytest.approx(13.0) and down.speed_rpm[-1] == 800
    road = read_profile('truck_road_cycle')
    assert road.duration_s > 600 and 'WHTC' in road.source and road.load.max() <= 1


@pytest.mark.parametrize('text, words', [
    ('time_s,speed,load\n0,800,1\n1,900,1\n', ["'header' must be time_s,speed_rpm,load"]),
    ('time_s,speed_rpm,load\n0,800,1\n0,900,1\n', [':3:', "'time_s' must increase strictly"]),
    ('time_s,speed_rpm,load\n0,800,1\n1,900,1.5\n', [':3:', "'load' must be in [-1, 1], got 1.5"]),
    ('time_s,speed_rpm,load\n0,800,1\n1,nan,1\n', [':3:', "'speed_rpm' must be finite"]),
    ('time_s,speed_rpm,load\n0,800,1\n1,abc,1\n', [':3:', "'speed_rpm' must be a finite number"]),
    ('time_s,speed_rpm,load\n1,800,1\n2,900,1\n', ["'time_s' must start at 0"]),
    ('time_s,speed_rpm,load\n0,800,1\n', ['at least 2 rows']),
    ('time_s,speed_rpm,load\n0,800,1\n1,900\n', ["'row' must have 3 values"]),
])
def test_bad_profiles_refused_with_one_line(tmp_path, capsys, text, words):
    path = tmp_path / 'bad.csv'
    path.write_text(text)
    assert cli_main(['run', str(path), '--no-write']) == 2
    err = capsys.readouterr().err.strip()
    assert '\n' not in err and 'Traceback' not in err and str(path) in err
    for w in words:
        assert w in err


@pytest.mark.parametrize('spec, words', [
    ('ramp:800:2000', ['ramp:FROM:TO:RATE']),
    ('ramp:800:2000:0', ["'rate_rpm_per_s' must be in [0.001, 10000] rpm/s"]),
    ('ramp:800:800:10', ['nothing to ramp']),
    ('ramp:800:2000:10:2', ["'load' must be in [-1, 1]"]),
    ('no_such_profile', ['no such file, packaged profile (truck_road_cycle']),
    ('ramp:300:2000:100', ['row 1', '300 rpm outside the engine data', '[400, 2200]']),
])
def test_bad_specs_refused_with_one_line(capsys, spec, words):
    assert cli_main(['run', spec, '--no-write']) == 2
    err = capsys.readouterr().err.strip()
    assert '\n' not in err and 'Traceback' not in err
    for w in words:
        assert w in err


@pytest.mark.parametrize('table, words', [
    ({'t_s': [0, 1], 'speed_rpm': [1000, 1000]}, 'not a profile table'),
    ({'t_s': [0, 1], 'speed_rpm': [1000], 'load': [1, 1]}, 'not a profile table'),
    ({'t_s': [0, 1], 'speed_rpm': [1000, 'x'], 'load': [1, 1]}, 'speed_rpm'),
    ({'t_s': [1, 0], 'speed_rpm': [1000, 1000], 'load': [1, 1]}, 'time_s'),
    ({'t_s': [0, 1], 'speed_rpm': [1000, 1000], 'load': [1, 1], 'settle_s': -1}, 'settle_s'),
])
def test_a_bad_profile_table_is_refused_with_one_line(table, words):
    """A bag's stored profile read back is checked as a file's rows are."""
    with pytest.raises(ConfigError, match=words) as err:
        profile_from_table(table, 'bag: the profile in its metadata')
    assert '\n' not in str(err.value) and str(err.value).startswith('bag: the profile')


def test_out_of_range_is_an_operating_range_error():
    with pytest.raises(OperatingRangeError):
        run_profile(ramp_profile(1000, 2500, 500, settle_s=0), None)
    with pytest.raises(ConfigError, match='chunk_s'):
        run_profile(ramp_profile(1000, 1100, 500), None, RunOptions(chunk_s=5.0))


@pytest.mark.parametrize('dt', [0.0, -1e-4, math.nan, math.inf, 1e-9, 0.1])
def test_a_newmark_step_the_run_cannot_take_is_one_line(dt):
    """The Python route (``run_profile``, what ``follow_profile`` and a design share) checked
    the step only on the command line (``--dt``): dt = 0 ended in ZeroDivisionError, NaN in
    "cannot convert float NaN to integer". Refused like ``chunk_s``, before anything runs,
    naming the field and the node's range for its ``dt``."""
    with pytest.raises(ConfigError) as err:
        run_profile(read_profile('step:1200:0:1:0.1'), None, RunOptions(dt=dt, write=False))
    assert str(err.value) == f'dt must be within [1e-06, 0.01] s, got {dt!r}'


# --------------------------------------------------------------------------- the run's bag

def _read(bag, topics=None):
    out = []
    with AnyReader([Path(bag)], default_typestore=STORE) as reader:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        for conn, t, raw in reader.messages(connections=conns):
            out.append((conn.topic, t, bytes(raw), conn.msgtype))
    return out


def test_run_bag_has_the_nodes_topics_and_follows_the_profile(run_bag):
    prof, out, summary = run_bag
    assert not summary.interrupted and summary.samples == round(prof.duration_s * 1000)
    meta = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    topics = {t['topic_metadata']['name']: t['topic_metadata']['type']
              for t in meta['topics_with_message_count']}
    streams = streams_for(read_driveline('truck_dmf').sensors)     # the node's, sensors on
    names = resolved_topics('', streams)
    assert topics == {names[k]: s.msgtype for k, s in streams.items()}
    assert len(meta['files']) == 3                       # split every simulated second
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in meta['topics_with_message_count']}
    # the node's health status every simulated second (diagnostics_rate 1 Hz), the sample
    # streams one message per sample, the sensors as the node publishes them
    assert counts['/diagnostics'] == int(prof.duration_s)
    assert all(counts[names[k]] == summary.samples for k in SAMPLE_STREAMS)
    assert meta['message_count'] == sum(counts.values()) == summary.messages
    rm = RunMetadata.from_bag_metadata(meta)
    assert parse_sensors(rm.sensors) == read_driveline('truck_dmf').sensors
    assert rm.profile == prof.name and rm.node == 'dmf-sim run' and rm.publish_rate_hz == 1000
    kept = profile_from_table(rm.profile_table)        # the whole run, without its file
    for col in ('t_s', 'speed_rpm', 'load'):
        np.testing.assert_array_equal(getattr(kept, col), getattr(prof, col))
    assert (kept.name, kept.settle_s, kept.start_settle_s) == (prof.name, prof.settle_s,
                                                               prof.start_settle_s)
    # the reference speed is on the table at every sample (ramp exact in the kernel)
    msgs = _read(out, {'/engine/speed', '/engine/crank_angle'})
    speed = np.array([STORE.deserialize_cdr(r, mt).data for tp, _, r, mt in msgs
                      if tp == '/engine/speed'])
    t = (np.arange(len(speed)) + 1) * 1e-3
    assert np.abs(speed - prof.at(t)[0]).max() < 1e-6
    # crank angle = integral of the speed (trapezoid of the piecewise-linear profile)
    psi = np.array([STORE.deserialize_cdr(r, mt).data for tp, _, r, mt in msgs
                    if tp == '/engine/crank_angle'])
    tt = np.concatenate(([0.0], t))
    rpm = prof.at(tt)[0]
    expected = np.cumsum(0.5 * (rpm[1:] + rpm[:-1]) * 1e-3) * np.pi / 30
    assert np.abs(psi - expected).max() < 1e-6


def test_run_bag_read_by_analyze(run_bag):
    prof, out, _ = run_bag
    res = analyze_bag(out, options=AnalysisOptions(bin_rpm=50))
    sig = res.signal('windup')
    assert res.sample_rate_hz == pytest.approx(1000.0) and not res.truncated
    assert res.crank_source == 'crank angle topic'
    assert sig.cycles.speed_rpm.min() >= 1000 - 1 and sig.cycles.speed_rpm.max() <= 1300 + 1
    assert np.all(sig.table.order_3 > 1e-3)              # the 3rd order is there


def test_encoded_messages_equal_the_serializers(run_bag):
    names = ['CYL1', 'DMF PRIMARY', 'GEAR BOX']
    enc = SampleEncoder(names)
    rng = np.random.default_rng(3)
    stamps = np.array([1_700_000_000_123_456_789, 5, 2_000_000_000], np.int64)
    pos, vel, eff = (rng.normal(size=(3, 3)) for _ in range(3))
    got = enc.joint_states(stamps, pos, vel, eff)
    js = STORE.types['sensor_msgs/msg/JointState']
    hdr = STORE.types['std_msgs/msg/Header']
    tm = STORE.types['builtin_interfaces/msg/Time']
    for i in range(3):
        sec, ns = divmod(int(stamps[i]), 10 ** 9)
        msg = js(header=hdr(stamp=tm(sec=sec, nanosec=ns), frame_id=''), name=names,
                 position=pos[i], velocity=vel[i], effort=eff[i])
        assert got[i].tobytes() == bytes(STORE.serialize_cdr(msg, 'sensor_msgs/msg/JointState'))
    f64 = STORE.types['std_msgs/msg/Float64']
    for v, row in zip([1.5, -2e9], enc.floats(np.array([1.5, -2e9]))):
        assert row.tobytes() == bytes(STORE.serialize_cdr(f64(data=v), 'std_msgs/msg/Float64'))


@pytest.mark.ros
def test_encoded_messages_equal_rclpy(run_bag):
    """What the node publishes (rclpy's serializer) is what the run writes, byte for byte but
    for the alignment padding (rclpy leaves it unset)."""
    import rclpy.serialization as rclpy_ser
    from sensor_msgs.msg import JointState
    enc = SampleEncoder(['A', 'BB'])
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = 12, 345
    msg.name = ['A', 'BB']
    msg.position, msg.velocity, msg.effort = [1.0, 2.0], [3.0, 4.0], [5.0, -6.0]
    got = enc.joint_states(np.array([12 * 10 ** 9 + 345]), np.array([[1.0, 2.0]]),
                           np.array([[3.0, 4.0]]), np.array([[5.0, -6.0]]))
    theirs = np.frombuffer(rclpy_ser.serialize_message(msg), np.uint8)
    ours = got[0]
    _, _, arrays, total, key = joint_state_layout(ours.tobytes())
    assert len(theirs) == len(ours) == total
    used = np.concatenate([key, np.arange(4, 12)]
                          + [np.arange(off, off + 8 * n) for off, n in arrays.values()])
    assert np.array_equal(ours[used], theirs[used])


def test_block_writing_equals_per_message_writing(tmp_path):
    topics = {'/js': 'sensor_msgs/msg/JointState', '/f': 'std_msgs/msg/Float64'}
    enc = SampleEncoder(['a', 'b'])
    n = 2500
    t = 10 ** 9 + np.arange(n, dtype=np.int64) * 1_000_000       # 2.5 s at 1 kHz
    x = np.random.default_rng(0).normal(size=(n, 2))
    js, fl = enc.joint_states(t, x, x, x), enc.floats(x[:, 0])
    one = BagRecorder(tmp_path / 'one', topics, max_duration_s=1.0, chunk_bytes=10 ** 9,
                      chunk_seconds=10.0)
    with one:
        for i in range(n):
            one.write('/js', int(t[i]), js[i].tobytes())
            one.write('/f', int(t[i]), fl[i].tobytes())
    block = BagRecorder(tmp_path / 'block', topics, max_duration_s=1.0)
    with block:
        for a in range(0, n, 700):
            block.write_block(t[a:a + 700], [('/js', js[a:a + 700]), ('/f', fl[a:a + 700])])
    assert [(tp, tt, r) for tp, tt, r, _ in _read(tmp_path / 'one')] == \
        [(tp, tt, r) for tp, tt, r, _ in _read(tmp_path / 'block')]
    m1 = yaml.safe_load((tmp_path / 'one' / 'metadata.yaml').read_text())
    m2 = yaml.safe_load((tmp_path / 'block' / 'metadata.yaml').read_text())
    def files(m):
        return [{k: v for k, v in f.items() if k != 'path'}
                for f in m['rosbag2_bagfile_information']['files']]
    assert files(m1) == files(m2) and len(files(m1)) == 3
    # the mcap library's indexed reader (chunk and message indexes, statistics) agrees
    from mcap.reader import make_reader
    for f1, f2 in zip(resolve_bag(tmp_path / 'one').files, resolve_bag(tmp_path / 'block').files):
        with open(f1, 'rb') as a, open(f2, 'rb') as b:
            ra, rb = make_reader(a), make_reader(b)
            sa, sb = ra.get_summary().statistics, rb.get_summary().statistics
            assert (sa.message_count, dict(sa.channel_message_counts)) == \
                (sb.message_count, dict(sb.channel_message_counts))
            ma = [(m.channel_id, m.sequence, m.log_time, m.data)
                  for _, _, m in ra.iter_messages(log_time_order=True)]
            mb = [(m.channel_id, m.sequence, m.log_time, m.data)
                  for _, _, m in rb.iter_messages(log_time_order=True)]
            assert ma == mb and len(ma) > 0


def test_encoding_into_the_records_equals_copying_them(tmp_path):
    """EncodedBlock encoding into the recorder's own records (BagRecorder.block_payloads: no
    copy) writes the same files as encoding apart and copying, also where a block is split
    across files (1 s splits, 1024-row blocks)."""
    from dmf_sim.live.simulation import Samples
    from dmf_sim.transient.encode import EncodedBlock
    names = ['a', 'b', 'c']
    topics = resolved_topics('')
    types = {topics[k]: STREAMS[k].msgtype for k in ('joint_states', 'dmf_windup', 'speed',
                                                      'crank_angle')}
    n = 2600
    rng = np.random.default_rng(5)
    t = 10 ** 9 + np.arange(n, dtype=np.int64) * 1_000_000
    x = rng.normal(size=(n, 3, 3))
    s = Samples(np.arange(n), t * 1e-9, x[:, 0, 0], x[:, 0, 1], x[:, 0, 2], x[:, 0], x[:, 1],
                x[:, 2])
    for name, in_place in (('apart', False), ('inplace', True)):
        rec = BagRecorder(tmp_path / name / 'bag', types, max_duration_s=1.0)
        block = EncodedBlock(SampleEncoder(names), 1024, topics, rec if in_place else None)
        with rec:
            for a in range(0, n, 300):                  # chunks of 300 rows
                b = min(a + 300, n)
                start = a
                while start < b:
                    k = min(block.free, b - start)
                    block.add(s, t, start, start + k)
                    start += k
                    if block.free == 0:
                        rec.write_block(*block.take())
            rec.write_block(*block.take())
    one, two = (resolve_bag(tmp_path / name / 'bag').files for name in ('apart', 'inplace'))
    assert len(one) == len(two) == 3
    for f1, f2 in zip(one, two):
        assert f1.read_bytes() == f2.read_bytes()
    msgs = _read(tmp_path / 'inplace' / 'bag')
    assert len(msgs) == 4 * n


def test_block_written_files_pass_every_crc_check(run_bag):
    """The run's chunks go straight to the file (one CRC pass each, the data-section CRC
    combined from it): every chunk CRC and each file's data-section CRC check out, and the
    data-section CRC is really written (not 0 = "not computed")."""
    import zlib

    from mcap.reader import make_reader

    from dmf_sim.bags.read import read_messages
    from dmf_sim.bags.records import Scan
    from dmf_sim.bags.writer import _crc_combine

    rng = np.random.default_rng(5)
    for la, lb in ((0, 0), (0, 3), (7, 0), (1, 1), (100, 270_123), (3, 1 << 20)):
        a, b = rng.bytes(la), rng.bytes(lb)
        assert _crc_combine(zlib.crc32(a), zlib.crc32(b), lb) == zlib.crc32(a + b)
        assert _crc_combine(zlib.crc32(a, 7), zlib.crc32(b), lb) == zlib.crc32(b, zlib.crc32(a, 7))
    _, out, summary = run_bag
    scans: list[Scan] = []
    assert sum(1 for _ in read_messages(out, scans=scans)) == summary.messages
    assert len(scans) == 3 and all(s.complete and not s.corrupt and not s.data_crc_error
                                   for s in scans)
    from mcap.records import DataEnd
    from mcap.stream_reader import StreamReader
    for f in resolve_bag(out).files:
        with open(f, 'rb') as fh:
            ends = [r for r in StreamReader(fh).records if isinstance(r, DataEnd)]
            assert len(ends) == 1 and ends[0].data_section_crc != 0
        with open(f, 'rb') as fh:           # the library's reader checks the chunk CRCs too
            n = sum(1 for _ in make_reader(fh, validate_crcs=True).iter_messages())
            assert n > 0


@pytest.mark.parametrize('times, needle', [(3, '3 bags given'), (2, 'a second run-up bag')])
def test_runup_takes_one_run_up_and_one_run_down(run_bag, times, needle, tmp_path, capsys):
    """`runup up down up` analysed all three and kept the last run-up's comparison."""
    out = tmp_path / 'out'
    assert cli_main(['runup', *[str(run_bag[1])] * times, '--no-hbm', '--out', str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and needle in err and not out.exists()


@pytest.mark.slow
def test_threaded_run_writes_the_sequential_bag(tmp_path):
    """Integrating in a thread of its own while the last chunks are read out and written
    (threads=2, the default with two CPUs) gives the bag one thread gives (threads=1), byte for
    byte but for the wall-clock stamps: the same payloads in the same order, the same log times
    relative to the first, the same solver counters."""
    prof = read_profile('ramp:1000:1300:300:1.0:0.2')
    bags, summaries = {}, {}
    for threads in (1, 2):
        bags[threads] = tmp_path / f'threads{threads}'
        summaries[threads] = run_profile(prof, bags[threads], RunOptions(threads=threads))
    s1, s2 = summaries[1], summaries[2]
    assert (s1.threads, s2.threads) == (1, 2)
    assert (s1.samples, s1.messages, s1.knee_crossings, s1.solver_resets) == \
        (s2.samples, s2.messages, s2.knee_crossings, s2.solver_resets)
    assert s1.knee_crossings > 0 and s1.samples == round(prof.duration_s * 1000)

    def strip(bag):
        msgs = _read(bag)
        t0 = msgs[0][1]
        stamped = ('joint_states', 'diagnostics')      # header stamps: the wall clock
        return [(tp, t - t0, raw[:4] + raw[12:] if tp.endswith(stamped)
                 else (decode_edges(raw)[0] - t0).tobytes() + raw[:68] if tp.endswith('edges')
                 else raw) for tp, t, raw, _ in msgs]
    assert strip(bags[1]) == strip(bags[2])


@pytest.mark.parametrize('cpus, threads', [({0}, 1), ({0, 1}, 2), ({0, 1, 2, 3}, 2)])
def test_default_threads_follow_the_cpus_this_process_may_use(cpus, threads, monkeypatch):
    from dmf_sim.transient.defaults import default_threads
    monkeypatch.setattr('os.sched_getaffinity', lambda pid: cpus, raising=False)
    assert default_threads() == threads
    assert RunOptions().threads == threads


def test_run_shows_its_progress_when_stderr_is_not_a_terminal(capsys):
    """Like sweep, design and paper: progress on stderr unless --no-progress (it was shown only
    on a terminal, so a log of a long run said nothing until the end)."""
    assert cli_main(['run', 'ramp:1200:1300:100:1.0:0.5', '--no-write']) == 0
    captured = capsys.readouterr()
    assert 'run ramp' in captured.err and 'sim s' in captured.err, captured.err
    assert cli_main(['run', 'ramp:1200:1300:100:1.0:0.5', '--no-write', '--no-progress']) == 0
    assert capsys.readouterr().err == ''


@pytest.mark.slow
def test_interrupted_run_leaves_a_readable_bag(tmp_path):
    """SIGINT (Ctrl-C) during a long run: exit 130, the bag holds what was simulated and
    analyze reads it (with two threads: the integrating one is stopped and joined)."""
    out = tmp_path / 'cut'
    env = {**os.environ, 'PYTHONPATH': os.pathsep.join([str(REPO),
                                                         os.environ.get('PYTHONPATH', '')])}
    # Ctrl-C's handler set in the child: a process started in the background by a script
    # (CI launched with `... &`) inherits SIGINT ignored, and Python then keeps it ignored
    ctrl_c = ('import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); '
              'from dmf_sim.cli import main; sys.exit(main(sys.argv[1:]))')
    proc = subprocess.Popen([sys.executable, '-c', ctrl_c, 'run', 'ramp:800:2000:1',
                             '--out', str(out), '--no-progress', '--threads', '2'], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        first = out / 'cut_0.mcap'
        while not (first.exists() and first.stat().st_size > 600_000):   # ~1 s simulated
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130 and 'interrupted at' in err
    meta = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['message_count'] >= 4 * 500 and meta['files']
    # from the start (how far it got varies: the settle, 2 s, may be all there is)
    res = analyze_bag(out, options=AnalysisOptions(bin_rpm=20, start_s=0.0))
    assert not res.truncated and res.duration_s > 0.5


def test_slow_runup_follows_the_hbm_branch(tmp_path):
    """Quasi-static: at 10 rpm/s between 1500 and 1600 rpm (one stable state, no jump) the
    run-up's 3rd-order wind-up amplitude is the harmonic balance branch's within 3 %."""
    out = tmp_path / 'slow'
    run_profile(read_profile('ramp:1500:1600:10:1.0:3'), out)
    from dmf_sim.analysis.hbm_overlay import model_settings, overlay_all
    res = analyze_bag(out, options=AnalysisOptions(bin_rpm=20, start_s=3.0))
    overlay_all(res, model_settings(res.metadata))
    sig = res.signal('windup')
    meas, hbm = sig.table.order_3, sig.hbm.values['order_3']
    ok = np.isfinite(hbm)
    assert ok.sum() >= 4
    assert np.abs(meas[ok] / hbm[ok] - 1).max() < 0.03


# ------------------------------------------------------------------------- the node's profile

def test_node_profile_parameter_follows_and_refuses(tmp_path):
    """The node's ``profile`` parameter (ROS-free core): follows a ramp in simulated time,
    tells the monitor's setpoint listeners, refuses profiles outside the node's speed limits
    or broken files with a one-line reason, '' stops it."""
    import time as _time

    from dmf_sim.live.parameters import PARAMETERS
    from dmf_sim.live.runtime import LiveRuntime, read_line
    from dmf_sim.transient.live_profile import NodeProfile

    class Log:
        def __init__(self):
            self.lines = []
        info = warning = error = lambda self, m: self.lines.append(m)

    class Sink:
        def publish_samples(self, *a): pass
        def publish_clock(self, *a): pass
        def publish_sensors(self, *a): pass
        def publish_statuses(self, *a): pass

    values = {n: s.default for n, s in PARAMETERS.items()}
    values.update(alpha=2.5, theta=0.24, pacing='fast', monitor=False)
    log = Log()
    rt = LiveRuntime(values, read_line('truck_dmf'), Sink(), log, topics={})
    heard = []
    rt.loop.setpoint_listeners.append(lambda speed, load: heard.append((speed, load)))
    prof = NodeProfile(rt, log)
    low = prof.check('ramp:400:1000:100')      # one line, the profile named once
    assert low.startswith('profile ramp:400:1000:100: row 1') and 'speed_min_rpm' in low
    bad = tmp_path / 'bad.csv'
    bad.write_text('time_s,speed_rpm,load\n0,900,1\n0,950,1\n')
    reason = prof.check(str(bad))
    assert reason.startswith(f'profile {bad}:') and 'increase strictly' in reason
    assert 'profile: profile' not in reason and '\n' not in reason
    assert prof.start('ramp:1000:1200:1000:0.8:0.05') is None
    rt.loop.start()
    while rt.sim.t < 0.3:
        rt.loop.tick(_time.perf_counter())
    assert rt.sim.speed == pytest.approx(1200.0) and rt.sim.load == pytest.approx(0.8)
    assert prof.follower is None and any('done at' in m for m in log.lines)
    assert heard and heard[-1] == (1200.0, 0.8)
    assert rt.sim.speed_ramp_rpm_per_s == values['speed_ramp_rpm_per_s']   # restored
    prof.apply('ramp:1200:1100:100')
    assert prof.follower is not None
    assert 'stopped' in prof.apply('') and prof.follower is None


def test_profile_player_and_setpoint_profile_errors(tmp_path, capsys):
    """``dmf-sim setpoint --profile``: the setpoints due over wall-clock time, the last row
    exactly; bad profiles and mixed options refused in one line before any ROS is touched."""
    from dmf_sim.transient.live_profile import ProfilePlayer
    player = ProfilePlayer(read_profile('ramp:1000:1200:100:0.5:1'), t0=10.0, rate_hz=20.0)
    assert player.setpoints(10.5) == (1000.0, 0.5)
    assert player.setpoints(12.0) == pytest.approx((1100.0, 0.5))
    assert player.next_time(11.0) == pytest.approx(11.05)
    assert player.next_time(12.98) == pytest.approx(13.0)      # the last row exactly
    assert not player.done(12.99) and player.done(13.0)
    bad = tmp_path / 'bad.csv'
    bad.write_text('time_s,speed_rpm,load\n0,900,1\n1,950,2\n')
    for argv in (['setpoint', '--profile', str(bad)],
                 ['setpoint', '--profile', 'ramp:800:900:10', '--speed', '900']):
        assert cli_main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert '\n' not in err and 'Traceback' not in err
        assert "'load' must be in [-1, 1]" in err or 'not both' in err
