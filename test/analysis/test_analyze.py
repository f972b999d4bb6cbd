"""Order analysis of bags (dmf_sim.analysis.pipeline, ``dmf-sim analyze``).

Bags with known content come from ``synthetic_bags`` (BagRecorder + rosbags CDR, or mcap_ros2's
writer for the ``ros2 bag record``-style bag); the "node recording" is the node's simulation
core stepped offline and recorded as the node does.
"""
from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from support.analysis_tolerances import RUNUP_TOL
from support.synthetic_bags import (
    CYL1,
    NAMES,
    RATE,
    T0,
    TOL,
    TOPICS,
    TORQUE,
    WINDUP,
    check_table,
    ramp,
    record_node_run_up,
    synth,
    write_synthetic,
)

from dmf_sim.analysis.pipeline import AnalysisOptions, SignalSpec, analyze_bag, read_bag_series
from dmf_sim.cli import main as cli_main

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    root = tmp_path_factory.mktemp('analyze')
    return {'full': write_synthetic(root / 'full'),
            'no_crank': write_synthetic(root / 'no_crank', topics=('windup', 'speed'),
                                   max_duration_s=3.0),         # 6 split files
            'neither': write_synthetic(root / 'neither', topics=('windup',)),
            'root': root}


# ---------------------------------------------------------------------------------- recovery

@pytest.mark.slow
def test_synthetic_orders_recovered_on_speed_ramp(bags):
    res = analyze_bag(bags['full'], ['windup', 'angle:CYL1', 'torque:INPUT SHAFT'],
                      options=AnalysisOptions(bin_rpm=20, theta=0.24))
    assert res.crank_source == 'crank angle topic'
    assert res.sample_rate_hz == pytest.approx(RATE, rel=1e-6)
    w = res.signal('windup')
    check_table(w.table, WINDUP)
    speeds = w.table.speed_rpm
    assert speeds.min() <= 720 and speeds.max() >= 1480          # whole ramp covered
    assert np.allclose(w.table.mean_minus_theta, WINDUP['mean'] - 0.24, atol=1e-6)
    check_table(res.signal('angle:CYL1').table, CYL1)
    check_table(res.signal('torque:INPUT SHAFT').table, TORQUE)
    # per cycle: the complex coefficients (phase referred to the crank angle) within 0.5 %
    c = w.cycles.coeffs
    for n in (3, 6, 9, 12):
        a, ph = WINDUP[n]
        assert np.max(np.abs(c[:, n] - a * np.exp(1j * ph))) / a < TOL
    # cycle speed = 120 / cycle duration follows the ramp
    t_mid = 0.5 * (w.cycles.t_start + w.cycles.t_end)
    assert np.allclose(w.cycles.speed_rpm, 700 + 50 * t_mid, atol=0.5)
    # Fig. 13 max/min deviation of the synthetic wave (dense reference)
    psi = np.linspace(0, 4 * np.pi, 20001)
    x = synth(WINDUP, psi)
    assert np.allclose(w.table.max_deviation, x.max() - x.mean(), rtol=TOL)
    assert np.allclose(w.table.min_deviation, x.min() - x.mean(), rtol=TOL)


@pytest.mark.slow
def test_fast_reader_matches_reference_reader(bags):
    specs = [SignalSpec.parse(s) for s in ('windup', 'angle:cyl1', 'torque:INPUT_SHAFT')]
    fast = read_bag_series(bags['full'], signals=specs)
    ref = read_bag_series(bags['full'], signals=specs, reader='messages')
    assert fast.reader == 'fast' and ref.reader == 'messages'
    assert set(fast.series) == set(ref.series) == {'crank', 'speed', 'windup', 'angle:cyl1',
                                                   'torque:INPUT_SHAFT'}
    for k in fast.series:
        np.testing.assert_array_equal(fast.series[k].t_ns, ref.series[k].t_ns)
        np.testing.assert_array_equal(fast.series[k].values, ref.series[k].values)
    assert fast.joint_names == NAMES


def test_per_cycle_mode_and_time_window(bags):
    res = analyze_bag(bags['full'], options=AnalysisOptions(bin_rpm=0, start_s=4.0, end_s=8.0))
    cyc = res.signal('windup').cycles
    assert len(res.signal('windup').table) == len(cyc) > 20
    assert cyc.t_start.min() >= 4.0 and cyc.t_end.max() <= 8.0
    k = cyc.psi_start / (4 * np.pi)                       # cycles start at whole 720 deg
    np.testing.assert_allclose(k, np.round(k), atol=1e-12)


# --------------------------------------------------------------------- bags it did not write

def test_missing_crank_angle_integrates_speed(bags):
    res = analyze_bag(bags['no_crank'], options=AnalysisOptions(theta=0.24))
    assert 'integrated engine speed' in res.crank_source
    check_table(res.signal('windup').table, WINDUP)


@pytest.mark.slow
def test_neither_crank_angle_nor_speed_is_a_clear_error(bags, capsys):
    assert cli_main(['analyze', str(bags['neither']), '--json']) == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines()
           if 'compiling the numerical kernels once' not in line]    # a cold cache says so first
    assert len(err) == 1
    assert 'neither a crank angle topic' in err[0] and '/engine/speed' in err[0]
    assert '/driveline/dmf_windup' in err[0]        # lists what the bag holds


@pytest.mark.slow
def test_truncated_bag(bags):
    bag = bags['root'] / 'truncated'
    shutil.copytree(bags['full'], bag)
    (mcap,) = bag.glob('*.mcap')
    data = mcap.read_bytes()
    mcap.write_bytes(data[:int(len(data) * 0.55)])          # crash in the middle of a chunk
    res = analyze_bag(bag, ['windup', 'torque:INPUT SHAFT', 'topic:/late'])
    assert res.truncated and any('truncated' in w for w in res.warnings)
    # a topic whose first message comes chunks after its channel record (no summary to help)
    late = res.signal('topic:/late').table
    assert late.speed_rpm.min() >= 940
    check_table(late, WINDUP)
    w = res.signal('windup').table
    assert 900 < w.speed_rpm.max() < 1300                     # about half the ramp survived
    check_table(w, WINDUP)
    check_table(res.signal('torque:INPUT SHAFT').table, TORQUE)
    specs = [SignalSpec.parse('windup'), SignalSpec.parse('torque:INPUT SHAFT')]
    fast = read_bag_series(bag, signals=specs)
    ref = read_bag_series(bag, signals=specs, reader='messages')
    for k in fast.series:
        np.testing.assert_array_equal(fast.series[k].values, ref.series[k].values)


def _msgdef(msgtype: str) -> str:
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY).generate_msgdef(msgtype, ros_version=2)[0]


def write_ros2_record_style(path: Path, jitter_ns: int = 100_000, wrap: bool = True) -> Path:
    """What ``ros2 bag record`` of the node's topics (plus others) looks like: rosbag2's MCAP
    conventions (profile ros2, ros2msg schemas, zstd chunks, channel QoS metadata, a 'rosbag2'
    metadata record, metadata.yaml), receive-time log stamps with jitter, publish_time exact,
    a crank angle wrapped to [0, 4 pi), extra topics, and JointState messages of other layouts."""
    import yaml
    from mcap.writer import CompressionType
    from mcap_ros2.writer import Writer

    path.mkdir()
    t, rpm, psi = ramp(duration=12.0, v0=800.0, v1=1400.0)
    w, tq = synth(WINDUP, psi), synth(TORQUE, psi)
    i_in = NAMES.index('INPUT SHAFT')
    rng = np.random.default_rng(1)
    qos = ('- history: keep_last\n  depth: 10\n  reliability: reliable\n  durability: volatile\n'
           '  deadline:\n    sec: 9223372036\n    nsec: 854775807\n')
    counts = {}
    with open(path / 'rec_0.mcap', 'wb') as fh:
        wr = Writer(fh, chunk_size=786432, compression=CompressionType.ZSTD)
        schemas = {}
        extra = {'/tf_like': 'std_msgs/msg/String',
                 '/parameter_events_like': 'std_msgs/msg/String'}
        for topic, msgtype in {**TOPICS, **extra}.items():
            if msgtype not in schemas:
                schemas[msgtype] = wr.register_msgdef(msgtype, _msgdef(msgtype))
            cid = wr._writer.register_channel(topic, 'cdr', schemas[msgtype].id,
                                              {'offered_qos_profiles': qos, 'topic_type_hash': ''})
            wr._channel_ids[topic] = cid

        def put(topic, msg, pub):
            log = pub + int(rng.integers(0, jitter_ns + 1))
            wr.write_message(topic, schemas[TOPICS.get(topic, 'std_msgs/msg/String')], msg,
                             log_time=log, publish_time=pub, sequence=counts.get(topic, 0))
            counts[topic] = counts.get(topic, 0) + 1

        for i in range(len(t)):
            pub = T0 + int(round(t[i] * 1e9))
            names, eff, frame = list(NAMES), np.zeros(len(NAMES)), 'driveline'
            eff[i_in] = tq[i]
            if i % 97 == 0:                       # another publisher: other frame, names reversed
                names, eff, frame = names[::-1], eff[::-1], 'base'
            put('/driveline/joint_states', {
                'header': {'stamp': {'sec': pub // 10**9, 'nanosec': pub % 10**9},
                           'frame_id': frame},
                'name': names, 'position': [0.0] * len(names), 'velocity': [],
                'effort': list(eff)},
                pub)
            put('/driveline/dmf_windup', {'data': float(w[i])}, pub)
            put('/engine/speed', {'data': float(rpm[i])}, pub)
            crank = psi[i] % (4 * np.pi) if wrap else psi[i]
            put('/engine/crank_angle', {'data': float(crank)}, pub)
            if i % 200 == 0:
                put('/tf_like', {'data': 'x'}, pub)
        wr.add_metadata('rosbag2', {'serialized_metadata': '', 'ROS_DISTRO': 'jazzy'})
        wr.finish()
    meta = {'rosbag2_bagfile_information': {
        'version': 9, 'storage_identifier': 'mcap', 'relative_file_paths': ['rec_0.mcap'],
        'duration': {'nanoseconds': int(t[-1] * 1e9)},
        'starting_time': {'nanoseconds_since_epoch': T0},
        'message_count': sum(counts.values()),
        'topics_with_message_count': [
            {'topic_metadata': {'name': k, 'type': TOPICS.get(k, 'std_msgs/msg/String'),
                                'serialization_format': 'cdr', 'offered_qos_profiles': [],
                                'type_description_hash': ''}, 'message_count': v}
            for k, v in counts.items()],
        'compression_format': '', 'compression_mode': '', 'files': [], 'custom_data': None,
        'ros_distro': 'jazzy'}}
    (path / 'metadata.yaml').write_text(yaml.safe_dump(meta, sort_keys=False))
    return path


@pytest.mark.slow
def test_bag_recorded_by_ros2_bag_record(tmp_path):
    bag = write_ros2_record_style(tmp_path / 'rec')
    for stamp in ('publish', 'log'):
        res = analyze_bag(bag, ['windup', 'torque:INPUT SHAFT'],
                          options=AnalysisOptions(stamp=stamp))
        assert res.crank_source == 'crank angle topic (unwrapped)'
        assert '/tf_like' in res.topics
        # publish times are exact; log (receive) times carry up to 0.1 ms jitter per topic, which
        # the pairing of each sample with its own crank angle removes
        check_table(res.signal('windup').table, WINDUP)
        check_table(res.signal('torque:INPUT SHAFT').table, TORQUE)
    # the odd JointState messages (names in another order) were decoded, not skipped
    specs = [SignalSpec.parse('torque:INPUT SHAFT')]
    fast = read_bag_series(bag, signals=specs, stamp='publish')
    ref = read_bag_series(bag, signals=specs, reader='messages')
    assert len(fast.series['torque:INPUT SHAFT']) == 12000
    np.testing.assert_array_equal(fast.series['torque:INPUT SHAFT'].values,
                                  ref.series['torque:INPUT SHAFT'].values)
    # a bare .mcap works as well
    res = analyze_bag(next(bag.glob('*.mcap')), options=AnalysisOptions(stamp='publish'))
    check_table(res.signal('windup').table, WINDUP)


def test_signal_errors(bags):
    with pytest.raises(ValueError, match='kind must be one of'):
        SignalSpec.parse('pressure:CYL1')
    with pytest.raises(ValueError, match="needs an element name"):
        SignalSpec.parse('angle:')
    with pytest.raises(ValueError, match="element 'CYL9' is not in the joint states"):
        analyze_bag(bags['full'], ['angle:CYL9'])
    with pytest.raises(ValueError, match='/driveline/joint_states is not in the bag'):
        analyze_bag(bags['no_crank'], ['torque:INPUT SHAFT'])


# ---------------------------------------------------------------------------------- CLI output

@pytest.mark.slow
def test_cli_json_and_files(bags, tmp_path, capsys):
    out = tmp_path / 'out'
    assert cli_main(['analyze', str(bags['full']), '--signal', 'windup', '--signal',
                     'torque:INPUT_SHAFT', '--out', str(out), '--load', '1', '--json']) == 0
    data = json.loads(capsys.readouterr().out)
    assert data['mode'] == 'bins' and data['bin_rpm'] == 20
    assert data['orders'][6] == 3.0 and data['orders'][3] == 1.5
    rows = data['signals']['windup']['rows']
    assert len(rows) >= 35
    for r in rows:
        assert abs(r['order_3'] - WINDUP[6][0]) / WINDUP[6][0] < TOL
        assert r['amplitudes'][6] == r['order_3']
        assert r['hbm_order_3'] is not None                 # HBM overlay on by default
    assert 'difference' in data['signals']['windup']['hbm']
    assert set(data['natural_frequencies_hz']) == {'primary', 'secondary'}
    for name in ('analysis.json', 'windup_orders.csv', 'windup_cycles.csv', 'windup_campbell.png',
                 'windup_fig13.png', 'torque_INPUT_SHAFT_orders.csv',
                 'torque_INPUT_SHAFT_fig13.png'):
        assert (out / name).stat().st_size > 0, name
    header = (out / 'windup_orders.csv').read_text().splitlines()[0].split(',')
    assert {'speed_rpm', 'order_3', 'order_1_5', 'max_deviation', 'min_deviation',
            'mean_minus_theta', 'hbm_order_3', 'o1.5', 'o3', 'o12'} <= set(header)


def test_cli_text_report(bags, tmp_path, capsys, monkeypatch):
    """The analysis goes beside the bag by default, not into the current directory."""
    monkeypatch.chdir(tmp_path)
    assert cli_main(['analyze', str(bags['no_crank']), '--no-hbm', '--no-plots', '--bin-rpm',
                     '50']) == 0
    out = capsys.readouterr().out
    assert 'integrated engine speed' in out and '3rd' in out
    assert (bags['root'] / 'no_crank_analysis' / 'windup_orders.csv').exists()
    assert not list(tmp_path.iterdir())



# ------------------------------------------------------------- node run-up against the HBM

@pytest.mark.slow
def test_node_run_up_agrees_with_hbm(tmp_path, capsys):
    """850 -> 1150 rpm at 20 rpm/s, full load: the DMF crosses its knee near 1000 rpm."""
    bag = record_node_run_up(tmp_path / 'runup', 850.0, 1150.0, 20.0, hold_s=3.0)
    # alpha, theta, load set come from the bag's custom_data; the load is not recorded
    assert cli_main(['analyze', str(bag), '--json', '--load', '1.0', '--start', '3.2',
                     '--no-plots']) == 0
    data = json.loads(capsys.readouterr().out)
    assert data['model']['alpha'] == 2.5 and data['model_sources']['alpha'] == 'bag'
    sig = data['signals']['windup']
    rows = [r for r in sig['rows'] if r['n_cycles'] >= 3]
    assert rows[0]['speed_rpm'] <= 880 and rows[-1]['speed_rpm'] >= 1120
    for key, (kind, tol) in RUNUP_TOL.items():
        meas = np.array([r[key] for r in rows])
        pred = np.array([r['hbm_' + key] for r in rows])
        err = np.abs(meas - pred)
        if kind == 'rel':
            err = err / np.abs(pred)
        elif kind == 'peak':
            err = err / np.abs(pred).max()
        assert err.max() < tol, (key, err.max(), tol)
    # the knee: mean wind-up below theta at 860 rpm, within 15 mrad of it above 1000 rpm
    assert rows[0]['mean_minus_theta'] < -0.025    # default engine (2800 Nm): -0.033 rad
    assert all(r['mean_minus_theta'] > -0.015 for r in rows if r['speed_rpm'] >= 1020)


@pytest.mark.slow
@pytest.mark.ros
def test_node_end_to_end_killed_recording(tmp_path, capsys):
    """The real driveline_node (separate process, fast pacing, full load at 1100 rpm, where the
    DMF crosses its knee every cycle) records a bag; it is killed with SIGKILL while recording
    (a crash); the truncated bag is analysed and agrees with the steady-state HBM."""
    import os
    import time

    from support.dds_peer import new_domain

    import dmf_sim.node  # noqa: F401
    bag = tmp_path / 'nodebag'
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
           'ROS_DOMAIN_ID': str(new_domain())}
    proc = subprocess.Popen(
        [sys.executable, '-m', 'dmf_sim.node', '--ros-args', '-p', 'pacing:=fast', '-p',
         'record:=true', '-p', f'bag_path:={bag}', '-p', 'initial_speed_rpm:=1100.0', '-p',
         'initial_load:=1.0'], env=env, cwd=tmp_path, stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 90
        span = 0.0
        while time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.5)
            if (bag / 'metadata.yaml').exists():
                crank = read_bag_series(bag).series.get('crank')   # the bag is being written
                span = 0.0 if crank is None else (crank.t_ns[-1] - crank.t_ns[0]) * 1e-9
                if span >= 6.0:
                    break
        assert proc.poll() is None, f'node exited: {proc.communicate()[1][-2000:]}'
        assert span >= 6.0, 'node recorded too slowly'
    finally:
        proc.kill()                        # SIGKILL: no clean close of the bag
        proc.communicate(timeout=30)
    assert cli_main(['analyze', str(bag), '--json', '--load', '1.0', '--start', '2.0',
                     '--no-plots']) == 0
    data = json.loads(capsys.readouterr().out)
    assert data['truncated'] and data['model_sources']['alpha'] == 'bag'
    (row,) = data['signals']['windup']['rows']
    assert row['speed_rpm'] == 1100 and row['n_cycles'] >= 30
    assert abs(row['order_3'] / row['hbm_order_3'] - 1) < 0.01
    assert abs(row['order_1_5'] / row['hbm_order_1_5'] - 1) < 0.05
    assert abs(row['mean_minus_theta'] - row['hbm_mean_minus_theta']) < 1e-3
    assert row['max_deviation'] > 0.005
    assert row['mean_minus_theta'] + row['max_deviation'] > 0          # crosses the knee


# ------------------------------------------------------------------------------------ benchmark

MEASURE_ANALYSIS = """
import sys
from pathlib import Path
from dmf_sim.analysis.pipeline import analyze_bag

def kib(field):
    for line in Path('/proc/self/status').read_text().splitlines():
        if line.startswith(field + ':'):
            return int(line.split()[1])

analyze_bag(sys.argv[1])                       # imports, caches
base = kib('VmRSS')
Path('/proc/self/clear_refs').write_text('5')  # peak RSS from here
analyze_bag(sys.argv[1])
print((kib('VmHWM') - base) / 1024)
"""


@pytest.mark.slow
@pytest.mark.bench
def test_bench_analyze_quick(tmp_path):
    """The benchmark on a small bag: figures sane, the fast reader agrees with the libraries
    alone and is faster; and the analysis' memory does not grow with the bag: a
    32 MiB bag costs a few MiB (at cbb69f1 the memory-mapped file grew RSS by its whole size)."""
    out = subprocess.run([sys.executable, str(REPO / 'benchmarks' / 'bench_analyze.py'),
                          '--minutes', '0.5', '--no-plots', '--keep', str(tmp_path)],
                         capture_output=True, text=True, check=True,
                         timeout=300).stdout.strip().splitlines()
    data = json.loads(out[-1])
    assert data['messages'] == 4 * 30000 and data['bag_mib'] > 25
    for key in ('analyze_seconds', 'read_seconds', 'library_read_seconds',
                'joint_analyze_seconds', 'write_seconds'):
        assert math.isfinite(data[key]) and data[key] > 0
    # CPU time of this process: the same when both cores are busy (wall time is not)
    assert data['analyze_cpu_seconds'] < 20
    assert data['reader'] == 'fast' and data['readers_agree']
    assert data['fast_reader_cpu_speedup'] > 1
    assert data['analyze_rss_growth_mib'] < 0.4 * data['bag_mib']
    assert data['joint_rss_growth_mib'] < 0.4 * data['bag_mib']
    for key in ('order_3_max_rel_error', 'order_1_5_max_rel_error', 'cyl1_order_3_max_rel_error',
                'input_torque_order_3_max_rel_error'):
        assert data[key] < TOL
    growth = float(subprocess.run([sys.executable, '-c', MEASURE_ANALYSIS,
                                   str(tmp_path / 'bench_bag')], capture_output=True, text=True,
                                  check=True, timeout=300).stdout.split()[-1])
    print(f'\nanalysis of a {data["bag_mib"]:.0f} MiB bag: RSS +{growth:.1f} MiB')
    assert growth < 0.4 * data['bag_mib']
