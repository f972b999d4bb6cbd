"""What ``dmf-sim analyze`` accepts: namespaced bags, a file inside a bag,
split and truncated bags, re-anchored clocks, bounded options, files that are not MCAP; and the
per-cycle orders the live node shares with it.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from support.cli_output import one_line_error
from support.synthetic_bags import WINDUP, check_table, ramp, synth, write_synthetic

from dmf_sim.analysis.cycle_orders import EDGE_SAMPLES, angle_cycle_orders, cycle_orders
from dmf_sim.analysis.pipeline import SignalSpec, analyze_bag, read_bag_series
from dmf_sim.bags.metadata import RunMetadata
from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import BagError
from dmf_sim.physics.orders import CYCLE_RAD

SHORT = {'duration': 3.0, 'v0': 900.0, 'v1': 1100.0}      # 3 s ramp, ~25 cycles


@pytest.fixture(scope='module')
def root(tmp_path_factory):
    return tmp_path_factory.mktemp('inputs')


@pytest.mark.slow
def test_namespaced_bag_detects_its_driveline(root, capsys):
    """Topics under /truck1/... are found without options; a bag with two drivelines
    asks which one (one line listing them); --namespace picks it."""
    one = write_synthetic(root / 'truck1', ('windup', 'speed', 'crank'), namespaces=('/truck1',),
                          **SHORT)
    res = analyze_bag(one)
    assert res.namespace == 'truck1'
    assert res.signal('windup').topic == '/truck1/driveline/dmf_windup'
    check_table(res.signal('windup').table, WINDUP)
    two = write_synthetic(root / 'two', ('windup', 'crank'), namespaces=('/truck1', '/truck2'),
                          **SHORT)
    assert cli_main(['analyze', str(two), '--json', '--no-hbm']) == 2
    err = one_line_error(capsys)
    assert 'several drivelines' in err and '/truck1' in err and '/truck2' in err
    assert '--namespace' in err
    assert cli_main(['analyze', str(two), '--json', '--no-hbm', '--namespace', 'truck2']) == 0
    data = json.loads(capsys.readouterr().out)
    assert data['namespace'] == 'truck2'
    assert data['signals']['windup']['topic'] == '/truck2/driveline/dmf_windup'


@pytest.mark.slow
def test_file_inside_a_bag_uses_its_metadata(root, capsys):
    """`dmf-sim analyze run1/run1_0.mcap` reads the bag's metadata.yaml beside it and
    uses the stored load, alpha, theta and load set instead of silently using load 1.0."""
    stored = RunMetadata(driveline='truck_dmf', engine='engine_d13', load_set='B', alpha=2.0,
                         theta_rad=0.22, load=0.6)
    bag = write_synthetic(root / 'run1', ('windup', 'speed', 'crank'),
                          custom_data=stored.to_custom_data(), **SHORT)
    for target in (bag / 'run1_0.mcap', bag / 'metadata.yaml', bag):
        assert cli_main(['analyze', str(target), '--json', '--no-hbm']) == 0
        data = json.loads(capsys.readouterr().out)
        model, src = data['model'], data['model_sources']
        assert (model['load'], model['alpha'], model['theta_rad'], model['load_set']) == \
            (0.6, 2.0, 0.22, 'B'), target
        assert src['load'] == src['alpha'] == src['load_set'] == 'bag'
        assert data['theta_rad'] == 0.22
        assert not any('load 1.0' in w for w in data['warnings'])
    # a bare file elsewhere has no metadata: defaults, and the analysis says so
    bare = root / 'elsewhere.mcap'
    shutil.copy(bag / 'run1_0.mcap', bare)
    assert cli_main(['analyze', str(bare), '--json', '--no-hbm']) == 0
    data = json.loads(capsys.readouterr().out)
    assert data['model_sources']['load'] == 'default'
    assert any('load 1.0' in w for w in data['warnings'])


def test_help_says_where_the_load_comes_from(capsys):
    """--help and the docs agree: the load is the stored one, else 1.0."""
    with pytest.raises(SystemExit):
        cli_main(['analyze', '--help'])
    text = ' '.join(capsys.readouterr().out.split())
    assert 'the load stored in the bag' in text and 'not stored in bags' not in text
    page = Path(__file__).resolve().parents[2] / 'doc' / 'commands' / 'analyze.md'
    assert 'load stored in the bag' in ' '.join(page.read_text().split())


@pytest.mark.parametrize('argv, field', [
    (['--bin-rpm', '1e9'], '--bin-rpm'), (['--bin-rpm', '-5'], '--bin-rpm'),
    (['--n-max', '100000'], '--n-max'), (['--n-max', '2'], '--n-max'),
    (['--points-per-cycle', '10'], '--points-per-cycle'),
    (['--points-per-cycle', '100000000'], '--points-per-cycle'),
    (['--min-cycles', '0'], '--min-cycles'), (['--start', '-1'], '--start'),
    (['--start', '5', '--end', '2'], '--end'), (['--load', '1.5'], '--load'),
])
def test_size_like_options_are_bounded(tmp_path, capsys, argv, field):
    """Every size-like option is refused with one line naming it and its range,
    before any bag is read."""
    assert cli_main(['analyze', str(tmp_path / 'no_such_bag'), *argv]) == 2
    err = one_line_error(capsys)
    assert err.startswith('dmf-sim analyze: error: ' + field), err


def test_empty_or_random_mcap_is_not_an_mcap_file(tmp_path, capsys):
    """An empty x.mcap gets "not an MCAP file", like random bytes."""
    empty = tmp_path / 'x.mcap'
    empty.write_bytes(b'')
    noise = tmp_path / 'y.mcap'
    noise.write_bytes(np.random.default_rng(1).bytes(4096))
    for path in (empty, noise):
        assert cli_main(['analyze', str(path), '--json']) == 2
        assert 'is not an MCAP file' in one_line_error(capsys)


@pytest.mark.slow
def test_split_bag_with_truncated_last_file(root):
    """A bag split into files (the recorder's default) whose last file a crash truncated and
    metadata.yaml does not list yet: every file is read, fast reader == library reader."""
    bag = write_synthetic(root / 'split', ('joints', 'windup', 'speed', 'crank'),
                          max_duration_s=1.0, **SHORT)
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())
    names = info['rosbag2_bagfile_information']['relative_file_paths']
    assert len(names) == 3
    last = bag / names[-1]
    last.write_bytes(last.read_bytes()[:int(last.stat().st_size * 0.6)])
    info['rosbag2_bagfile_information']['relative_file_paths'] = names[:-1]
    (bag / 'metadata.yaml').write_text(yaml.safe_dump(info))
    specs = [SignalSpec.parse('windup'), SignalSpec.parse('torque:INPUT_SHAFT')]
    fast = read_bag_series(bag, signals=specs)
    ref = read_bag_series(bag, signals=specs, reader='messages')
    assert fast.truncated == ref.truncated == [last]
    assert fast.bag.unlisted == (last,)
    for key in ('crank', 'windup', 'torque:INPUT_SHAFT'):
        np.testing.assert_array_equal(fast.series[key].t_ns, ref.series[key].t_ns)
        np.testing.assert_array_equal(fast.series[key].values, ref.series[key].values)
    crank = fast.series['crank']
    assert 2.3 < (crank.t_ns[-1] - crank.t_ns[0]) * 1e-9 < 2.8   # ~60 % of the last second
    check_table(analyze_bag(bag).signal('windup').table, WINDUP)


def test_clock_re_anchored_while_recording(root):
    """Stamps jump back 27 s half-way (fast pacing, then real time again): the
    analysis unrolls the jump, says so, and loses at most the cycle across it."""
    plain = analyze_bag(write_synthetic(root / 'plain', ('windup', 'crank'), **SHORT))
    bag = write_synthetic(root / 'jump', ('windup', 'crank'), jump_back_s=27.0, **SHORT)
    res = analyze_bag(bag)
    assert any('jump back' in w for w in res.warnings)
    w = res.signal('windup')
    check_table(w.table, WINDUP)
    assert len(w.cycles) >= len(plain.signal('windup').cycles) - 1
    np.testing.assert_allclose(w.cycles.speed_rpm[-5:],
                               plain.signal('windup').cycles.speed_rpm[-5:], rtol=1e-6)


def test_live_per_cycle_orders_equal_the_bag_analysis():
    """The ROS-free per-cycle function on a window of one cycle plus EDGE_SAMPLES on each side
    (what the live node holds) gives the whole recording's numbers to 1e-6."""
    t, rpm, psi = ramp(duration=3.0, v0=800.0, v1=1400.0)
    x = synth(WINDUP, psi)
    t_ns = (t * 1e9).astype(np.int64)
    whole = cycle_orders(t_ns, x, t_ns, psi)
    assert len(whole) >= 20
    for k in (1, len(whole) // 2, len(whole) - 2):
        start = whole.psi_start[k]
        a = np.searchsorted(psi, start) - EDGE_SAMPLES
        b = np.searchsorted(psi, start + CYCLE_RAD) + EDGE_SAMPLES
        live = angle_cycle_orders(psi[a:b], x[a:b], t_s=t[a:b])
        assert len(live) == 1 and live.psi_start[0] == start
        assert np.max(np.abs(live.coeffs[0] - whole.coeffs[k])) < 1e-6 * WINDUP[6][0]
        for name in ('mean', 'max_deviation', 'min_deviation', 'speed_rpm'):
            assert getattr(live, name)[0] == pytest.approx(getattr(whole, name)[k], rel=1e-6)
    with pytest.raises(ValueError, match='strictly increasing'):
        angle_cycle_orders(psi[::-1], x)
    with pytest.raises(BagError):
        SignalSpec.parse('pressure:CYL1')
