"""Bags: recording (rosbag2 MCAP, small chunks), reading (own, mcap, rosbags), crash recovery."""
from __future__ import annotations

import os
import shutil
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from support.cdr import Float64, String, joint_state as _joint_state, serialize_message
from support.crash import sigkill_when_ready

from dmf_sim.bags.writer import BagRecorder, bag_topics, read_messages, recover_bag
from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import BagError

REPO = Path(__file__).resolve().parents[2]
TOPICS = {'/joint_states': 'sensor_msgs/msg/JointState', '/dmf/windup': 'std_msgs/msg/Float64'}
NAMES = [f'element_{i:02d}' for i in range(22)]
T0 = 1_700_000_000_000_000_000
PERIOD = 500_000  # 2 kHz
N = 4000          # 2 s


def joint_state(i: int, stamp_ns: int):
    return _joint_state(stamp_ns, NAMES, [1e-3 * i + k for k in range(22)], [float(i)] * 22,
                        [-float(k) for k in range(22)], frame='driveline')


def write_bag(path: Path, n: int = N, **kwargs) -> Path:
    with BagRecorder(path, TOPICS, **kwargs) as rec:
        for i in range(n):
            t = T0 + i * PERIOD
            rec.write('/joint_states', t, serialize_message(joint_state(i, t)))
            rec.write('/dmf/windup', t, serialize_message(Float64(data=0.01 * i)))
    return path


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_bag(tmp_path_factory.mktemp('bags') / 'run')


def mcap_file(bag: Path) -> Path:
    (file,) = bag.glob('*.mcap')
    return file


def check_values(topic: str, t: int, msg: object) -> None:
    """Values of sample i, whatever decoder produced ``msg`` (attribute access)."""
    i = (t - T0) // PERIOD
    if topic == '/joint_states':
        assert list(msg.name) == NAMES
        assert msg.position[3] == pytest.approx(1e-3 * i + 3)
        assert msg.effort[21] == -21.0
        assert msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec == t
        assert msg.header.frame_id == 'driveline'
    else:
        assert msg.data == pytest.approx(0.01 * i)


# ------------------------------------------------------------------------------ round trip

@pytest.mark.slow
def test_own_reader_round_trip(bag: Path) -> None:
    msgs = list(read_messages(bag))
    assert len(msgs) == 2 * N
    assert [m.timestamp_ns for m in msgs[::2]] == [T0 + i * PERIOD for i in range(N)]
    for m in msgs[::97]:
        assert m.msgtype == TOPICS[m.topic]
        check_values(m.topic, m.timestamp_ns, m.msg)
    only = list(read_messages(bag, topics=['/dmf/windup']))
    assert len(only) == N and {m.topic for m in only} == {'/dmf/windup'}
    raw = next(read_messages(bag, topics='/dmf/windup', raw=True))
    assert raw.msg == serialize_message(Float64(data=0.0))
    assert bag_topics(bag) == TOPICS
    assert bag_topics(mcap_file(bag)) == TOPICS


@pytest.mark.slow
def test_mcap_reader_with_ros2_decoder(bag: Path) -> None:
    with mcap_file(bag).open('rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        assert summary.statistics.message_count == 2 * N
        assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
        for ch in summary.channels.values():
            assert ch.message_encoding == 'cdr'
            qos = yaml.safe_load(ch.metadata['offered_qos_profiles'])
            assert qos[0]['reliability'] == 'reliable'
            assert ch.metadata['topic_type_hash'].startswith('RIHS01_')
        # chunks are time bounded (0.1 s) and many
        spans = [c.message_end_time - c.message_start_time for c in summary.chunk_indexes]
        assert len(spans) >= 20 and max(spans) < 100_000_000
        count = 0
        for _, channel, message, decoded in reader.iter_decoded_messages():
            if count % 101 == 0:
                check_values(channel.topic, message.log_time, decoded)
            count += 1
        assert count == 2 * N
        assert [m.name for m in reader.iter_metadata()] == ['rosbag2']


def test_rosbags_anyreader(bag: Path) -> None:
    with AnyReader([bag]) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == TOPICS
        assert {c.topic: c.msgcount for c in reader.connections} == {t: N for t in TOPICS}
        assert reader.message_count == 2 * N
        count = 0
        for conn, t, raw in reader.messages():
            if count % 103 == 0:
                check_values(conn.topic, t, reader.deserialize(raw, conn.msgtype))
            count += 1
        assert count == 2 * N


def test_metadata_yaml(bag: Path) -> None:
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9
    assert info['storage_identifier'] == 'mcap'
    assert info['message_count'] == 2 * N
    assert info['starting_time']['nanoseconds_since_epoch'] == T0
    assert info['duration']['nanoseconds'] == (N - 1) * PERIOD
    assert info['relative_file_paths'] == [mcap_file(bag).name]
    assert info['files'][0]['message_count'] == 2 * N
    assert info['compression_mode'] == '' and info['ros_distro'] == 'jazzy'
    topics = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    assert {k: v['topic_metadata']['type'] for k, v in topics.items()} == TOPICS
    assert all(v['message_count'] == N for v in topics.values())
    js = topics['/joint_states']['topic_metadata']
    assert js['serialization_format'] == 'cdr'
    assert js['type_description_hash'] == (
        'RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e')
    assert js['offered_qos_profiles'][0]['durability'] == 'volatile'


def test_provisional_metadata_and_live_read(tmp_path: Path) -> None:
    rec = BagRecorder(tmp_path / 'live', TOPICS, qos={'/dmf/windup': 'best_effort'},
                      custom_data={'model': 'table1'})
    info = yaml.safe_load((tmp_path / 'live' / 'metadata.yaml').read_text())
    info = info['rosbag2_bagfile_information']
    assert info['message_count'] == 0 and len(info['topics_with_message_count']) == 2
    assert info['custom_data'] == {'model': 'table1'}
    for i in range(500):
        rec.write('/dmf/windup', T0 + i * PERIOD, serialize_message(Float64(data=float(i))))
    rec.flush()
    assert [m.msg.data for m in read_messages(tmp_path / 'live')] == [float(i) for i in range(500)]
    rec.close()
    rec.close()  # idempotent
    assert rec.message_count == 500
    with pytest.raises(ValueError, match='closed'):
        rec.write('/dmf/windup', T0, b'')
    with AnyReader([tmp_path / 'live']) as reader:
        (conn,) = [c for c in reader.connections if c.topic == '/dmf/windup']
        assert conn.ext.offered_qos_profiles[0].reliability.name == 'BEST_EFFORT'


def test_existing_path_refused(tmp_path: Path) -> None:
    existing = tmp_path / 'exists'
    existing.mkdir()
    (existing / 'keep.txt').write_text('data')
    with pytest.raises(FileExistsError, match='exists already, not overwriting'):
        BagRecorder(existing, TOPICS)
    assert os.listdir(existing) == ['keep.txt']
    with pytest.raises(FileExistsError):
        BagRecorder(existing / 'keep.txt', TOPICS)


def test_missing_parents_created_and_reported(tmp_path: Path) -> None:
    """Like rosbag2, missing parent directories are created; the recorder lists
    them so the node can log what it created."""
    with BagRecorder(tmp_path / 'a' / 'b' / 'run', TOPICS) as rec:
        assert rec.created_dirs == [tmp_path / 'a', tmp_path / 'a' / 'b']
    with BagRecorder(tmp_path / 'a' / 'run2', TOPICS) as rec:
        assert rec.created_dirs == []


def test_bad_arguments(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match='(?i)unknown message type'):
        BagRecorder(tmp_path / 'a', {'/x': 'sensor_msgs/JointStat'})
    with pytest.raises(ValueError, match='absolute'):
        BagRecorder(tmp_path / 'b', {'x': 'std_msgs/msg/Float64'})
    with pytest.raises(ValueError, match='QoS'):
        BagRecorder(tmp_path / 'c', {'/x': 'std_msgs/msg/Float64'}, qos={'/x': 'fast'})
    with pytest.raises(BagError, match='not a valid ros2msg definition'):
        BagRecorder(tmp_path / 'e', {'/x': 'my_msgs/msg/T'},
                    msgdefs={'my_msgs/msg/T': 'floatx y'})
    assert not any(tmp_path.iterdir())  # nothing created on bad arguments
    with BagRecorder(tmp_path / 'd', {'/x': 'std_msgs/msg/Float64'}) as rec:
        with pytest.raises(ValueError, match='not declared'):
            rec.write('/y', T0, b'')
    with pytest.raises(FileNotFoundError):
        list(read_messages(tmp_path / 'missing'))


# ----------------------------------------------------------------------- truncation, crash

def truncated_copy(bag: Path, dst: Path, fraction: float) -> Path:
    shutil.copytree(bag, dst)
    file = mcap_file(dst)
    size = file.stat().st_size
    with file.open('r+b') as f:
        f.truncate(int(size * fraction))
    return dst


@pytest.mark.slow
@pytest.mark.parametrize('fraction', [0.003, 0.37, 0.9999])
def test_truncated_read_and_recover(bag: Path, tmp_path: Path, fraction: float) -> None:
    cut = truncated_copy(bag, tmp_path / 'cut', fraction)
    with mcap_file(cut).open('rb') as f, pytest.raises(Exception):
        make_reader(f).get_summary()  # the seeking reader refuses the file
    msgs = list(read_messages(cut))
    stamps = [m.timestamp_ns for m in msgs]
    assert stamps == sorted(stamps)
    if fraction > 0.3:
        assert len(msgs) > 0.3 * 2 * N * fraction
        check_values(msgs[-1].topic, msgs[-1].timestamp_ns, msgs[-1].msg)

    out = tmp_path / 'cut_recovered'
    if not msgs:           # a stub with no complete message is refused, not emptied
        with pytest.raises(BagError, match='nothing to recover'):
            recover_bag(cut)
        assert not out.exists()
        return
    report = recover_bag(cut)
    assert report.output_path == out and report.truncated
    assert report.message_count == len(msgs)
    assert sum(report.topics.values()) == len(msgs)
    with AnyReader([out]) as reader:
        assert reader.message_count == len(msgs)
        assert sum(1 for _ in reader.messages()) == len(msgs)
    with mcap_file(out).open('rb') as f:
        assert sum(1 for _ in make_reader(f).iter_messages()) == len(msgs)
    with pytest.raises(FileExistsError):
        recover_bag(cut)


def test_empty_or_random_file_is_not_mcap(bag: Path, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """An empty file, one shorter than the magic and random bytes are all "not an MCAP file";
    bag-recover refuses them (exit 2, one line) and writes nothing."""
    cut = truncated_copy(bag, tmp_path / 'cut', 0.0)
    empty = tmp_path / 'x.mcap'
    empty.write_bytes(b'')
    short = tmp_path / 'short.mcap'
    short.write_bytes(b'hello\n')
    noise = tmp_path / 'noise.mcap'
    noise.write_bytes(np.random.default_rng(0).bytes(1 << 20))
    for path in (cut, empty, short, noise):
        with pytest.raises(BagError, match='is not an MCAP file'):
            list(read_messages(path))
        with pytest.raises(BagError, match='is not an MCAP file'):
            recover_bag(path)
        assert cli_main(['bag-recover', str(path)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and 'not an MCAP file' in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cut', 'noise.mcap', 'short.mcap',
                                                          'x.mcap']


CHILD = textwrap.dedent('''
    import sys, time
    from support.cdr import Float64, joint_state, serialize_message
    from dmf_sim.bags.writer import BagRecorder

    topics = {'/joint_states': 'sensor_msgs/msg/JointState', '/dmf/windup': 'std_msgs/msg/Float64'}
    rec = BagRecorder(sys.argv[1], topics)
    names = [f'element_{k:02d}' for k in range(22)]
    period = 500_000
    t_next = time.time_ns()
    i = 0
    while True:
        now = time.time_ns()
        if now < t_next:
            time.sleep(min((t_next - now) * 1e-9, 0.0005))
            continue
        js = joint_state(now, names, [1e-3 * i + k for k in range(22)], [float(i)] * 22)
        rec.write('/joint_states', now, serialize_message(js))
        rec.write('/dmf/windup', now, serialize_message(Float64(data=0.01 * i)))
        if i % 100 == 0:
            print(i, now, flush=True)            # written (not necessarily flushed) so far
        i += 1
        t_next += period
''')
WRITTEN_BEFORE_KILL = 2000      # JointState messages the child reports written before SIGKILL
CHUNK_SECONDS = 0.1             # BagRecorder's default: a chunk closes once it spans this


@pytest.mark.slow
def test_sigkill_loses_little_and_recovers(tmp_path: Path) -> None:
    """SIGKILL while recording ~2 kHz: everything in closed chunks survives. Load-independent:
    the kill waits for the child's report of WRITTEN_BEFORE_KILL messages (not a sleep), and
    "little" is what the recorder promises: every message logged CHUNK_SECONDS before the last
    reported one is in a closed chunk, without a gap."""
    script = tmp_path / 'child.py'
    script.write_text(CHILD)
    path = tmp_path / 'crash'
    reported = []

    def until_enough_written(proc) -> None:
        while not reported or reported[-1][0] < WRITTEN_BEFORE_KILL:
            line = proc.stdout.readline()
            assert line, 'the recording child ended before it was killed'
            i, t_ns = (int(x) for x in line.split())
            reported.append((i, t_ns))

    sigkill_when_ready(script, [str(path)], until_enough_written)
    first_t, (last_i, last_t) = reported[0][1], reported[-1]

    msgs = list(read_messages(path))
    js = [m for m in msgs if m.topic == '/joint_states']
    index = [round(m.msg.position[0] * 1e3) for m in js]
    assert index == list(range(len(js)))                      # from the first one, no gap
    assert js[0].timestamp_ns == first_t
    safe = max(i for i, t in reported if t <= last_t - CHUNK_SECONDS * 1e9)
    print(f'\nSIGKILL: {len(msgs)} messages kept, {last_i + 1} JointStates reported written, '
          f'the last {len(js) - safe} past the one certainly flushed')
    assert len(js) > safe >= WRITTEN_BEFORE_KILL - 1000
    assert list(js[-1].msg.name) == NAMES

    report = recover_bag(path)
    assert report.truncated and report.message_count == len(msgs)
    with AnyReader([report.output_path]) as reader:
        assert sum(1 for _ in reader.messages()) == len(msgs)
        assert {c.topic for c in reader.connections} == set(TOPICS)
    with mcap_file(report.output_path).open('rb') as f:
        reader = make_reader(f)
        assert reader.get_summary().statistics.message_count == len(msgs)
        assert sum(1 for _ in reader.iter_messages()) == len(msgs)


# ------------------------------------------------------------------- bags from other tools

@pytest.mark.slow
def test_bare_mcap_files(bag: Path, tmp_path: Path) -> None:
    from mcap_ros2.writer import Writer as Ros2Writer

    assert len(list(read_messages(mcap_file(bag)))) == 2 * N
    path = tmp_path / 'foreign.mcap'
    with path.open('wb') as f:
        writer = Ros2Writer(f)
        schema = writer.register_msgdef('std_msgs/msg/String', 'string data\n')
        for i in range(10):
            writer.write_message('/chatter', schema, {'data': f'hello {i}'}, log_time=T0 + i)
        writer.finish()
    msgs = list(read_messages(path))
    assert [m.msg.data for m in msgs] == [f'hello {i}' for i in range(10)]
    assert bag_topics(path) == {'/chatter': 'std_msgs/msg/String'}
    report = recover_bag(path)
    assert report.output_path == tmp_path / 'foreign_recovered.mcap' and not report.truncated
    assert [m.msg.data for m in read_messages(report.output_path)] == [m.msg.data for m in msgs]


def _msgdef_like_rosbag2(msgtype: str, deps: list[str]) -> str:
    """Message definition as rosbag2 embeds it: .msg files with comments, dependencies after."""
    share = Path(sys.prefix) / 'share'

    def text(t: str) -> str:
        pkg, _, name = t.split('/')
        return (share / pkg / 'msg' / f'{name}.msg').read_text()

    sep = '=' * 80 + '\n'
    return text(msgtype) + ''.join(f'\n{sep}MSG: {d}\n{text(d)}' for d in deps)


@pytest.mark.ros                   # the .msg files rosbag2 embeds come with the ROS packages
def test_rosbag2_style_bag_with_extra_topics(tmp_path: Path) -> None:
    """A bag laid out like `ros2 bag record -s mcap --storage-preset-profile zstd_fast`."""
    from mcap.writer import CompressionType, Writer

    if not (Path(sys.prefix) / 'share/sensor_msgs/msg/JointState.msg').exists():
        pytest.skip('no .msg files under this Python prefix (a colcon install keeps them in '
                    'the ROS prefix)')
    bag = tmp_path / 'rosbag2_2024_01_01-00_00_00'
    bag.mkdir()
    fname = f'{bag.name}_0.mcap'
    qos = '- history: 1\n  depth: 10\n  reliability: 1\n  durability: 2\n' \
          '  deadline:\n    sec: 2147483647\n    nsec: 4294967295\n' \
          '  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n  liveliness: 1\n' \
          '  liveliness_lease_duration:\n    sec: 2147483647\n    nsec: 4294967295\n' \
          '  avoid_ros_namespace_conventions: false'
    with (bag / fname).open('wb') as f:
        w = Writer(f, compression=CompressionType.ZSTD, chunk_size=4096)
        w.start('ros2', 'rosbag2')
        s_js = w.register_schema('sensor_msgs/msg/JointState', 'ros2msg', _msgdef_like_rosbag2(
            'sensor_msgs/msg/JointState', ['std_msgs/msg/Header', 'builtin_interfaces/msg/Time']
        ).encode())
        s_str = w.register_schema('std_msgs/msg/String', 'ros2msg',
                                  _msgdef_like_rosbag2('std_msgs/msg/String', []).encode())
        c_js = w.register_channel('/joint_states', 'cdr', s_js, {'offered_qos_profiles': qos})
        c_str = w.register_channel('/rosout_text', 'cdr', s_str, {'offered_qos_profiles': qos})
        for i in range(300):
            t = T0 + i * PERIOD
            w.add_message(c_js, t, serialize_message(joint_state(i, t)), t)
            if i % 100 == 0:
                w.add_message(c_str, t, serialize_message(String(data=f'note {i}')), t)
        w.finish()
    meta = {'rosbag2_bagfile_information': {
        'version': 8, 'storage_identifier': 'mcap', 'relative_file_paths': [fname],
        'duration': {'nanoseconds': 299 * PERIOD},
        'starting_time': {'nanoseconds_since_epoch': T0},
        'message_count': 303, 'compression_format': '', 'compression_mode': '',
        'topics_with_message_count': [
            {'topic_metadata': {'name': n, 'type': t, 'serialization_format': 'cdr',
                                'offered_qos_profiles': qos}, 'message_count': c}
            for n, t, c in [('/joint_states', 'sensor_msgs/msg/JointState', 300),
                            ('/rosout_text', 'std_msgs/msg/String', 3)]],
        'files': [{'path': fname, 'starting_time': {'nanoseconds_since_epoch': T0},
                   'duration': {'nanoseconds': 299 * PERIOD}, 'message_count': 303}],
        'custom_data': None, 'ros_distro': 'jazzy'}}
    (bag / 'metadata.yaml').write_text(yaml.safe_dump(meta, sort_keys=False))

    assert bag_topics(bag) == {'/joint_states': 'sensor_msgs/msg/JointState',
                               '/rosout_text': 'std_msgs/msg/String'}
    msgs = list(read_messages(bag))
    assert len(msgs) == 303
    assert [m.msg.data for m in msgs if m.topic == '/rosout_text'] == ['note 0', 'note 100',
                                                                      'note 200']
    for m in msgs[::50]:
        if m.topic == '/joint_states':
            check_values(m.topic, m.timestamp_ns, m.msg)
    assert len(list(read_messages(bag, topics=['/joint_states']))) == 300


def test_rosbags_written_bag(tmp_path: Path) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    path = tmp_path / 'by_rosbags'
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        c1 = writer.add_connection('/dmf/windup', 'std_msgs/msg/Float64', typestore=store)
        c2 = writer.add_connection('/status', 'std_msgs/msg/String', typestore=store)
        for i in range(50):
            writer.write(c1, T0 + i, serialize_message(Float64(data=0.01 * i)))
        writer.write(c2, T0 + 50, serialize_message(String(data='done')))
    msgs = list(read_messages(path))
    assert len(msgs) == 51 and msgs[-1].msg.data == 'done'
    check_values('/dmf/windup', T0 + 7 * PERIOD, msgs[7].msg)


# ------------------------------------------------------------------------------ CLI, speed

@pytest.mark.slow
def test_cli_bag_recover(bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cut = truncated_copy(bag, tmp_path / 'cut', 0.5)
    n = sum(1 for _ in read_messages(cut))
    out = tmp_path / 'fixed'
    assert cli_main(['bag-recover', str(cut), '--output', str(out)]) == 0
    assert f'kept {n} messages' in capsys.readouterr().out
    with AnyReader([out]) as reader:
        assert reader.message_count == n
    assert cli_main(['bag-recover', str(cut), '--output', str(out)]) == 2
    err = capsys.readouterr().err
    assert 'not empty' in err and 'pass --overwrite' in err
    with pytest.raises(SystemExit):
        cli_main(['bag-recover', str(cut), '--output', str(out), '--in-place'])
    assert cli_main(['bag-recover', str(cut), '--in-place']) == 0
    with AnyReader([cut]) as reader:
        assert reader.message_count == n
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cut', 'fixed']


@pytest.mark.slow
def test_write_throughput(tmp_path: Path) -> None:
    data = serialize_message(joint_state(1, T0))
    n = 20000
    start = time.process_time()       # this process's CPU time: the same on a busy machine
    with BagRecorder(tmp_path / 'speed', {'/joint_states': TOPICS['/joint_states']}) as rec:
        for i in range(n):
            rec.write('/joint_states', T0 + i * PERIOD, data)
    rate = n / (time.process_time() - start)
    print(f'\nBagRecorder: {rate:.0f} JointState messages/s of CPU ({len(data)} bytes each)')
    assert rate > 5000  # the live node needs 2 kHz per topic
