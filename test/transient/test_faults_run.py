"""Offline runs with a fault schedule (``dmf-sim run PROFILE --faults FILE``): the faults act
along the profile and their ground truth is in the bag as the node publishes it; a bad schedule
is one line and exit 2 before anything runs."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from dmf_sim.bags.read import read_messages
from dmf_sim.cli import main as cli_main
from dmf_sim.live.streams import STREAMS, resolved_topics
from dmf_sim.physics.faults import event_from_values
from dmf_sim.transient.profiles import read_profile
from dmf_sim.transient.run import RunOptions, run_profile

SCHEDULE = '''description: a misfire, a cylinder that stops firing for a while, worn DMF damping
faults:
  - {kind: misfire, cylinders: [3], at_s: 0.5}
  - {kind: misfire, cylinders: [1], mode: every_cycle, start_s: 1.0, end_s: 1.5}
  - {kind: dmf_damping, factor: 3, start_s: 1.2, end_s: 1.8}
'''


def _ground_truth(bag):
    topics = resolved_topics()
    gt, active = [], []
    for m in read_messages(bag, [topics['fault_ground_truth'], topics['fault_active']]):
        statuses = m.msg.status
        if m.topic == topics['fault_active']:
            active.append((m.timestamp_ns, [s.name for s in statuses]))
            continue
        assert len(statuses) == 1
        s = statuses[0]
        gt.append((m.timestamp_ns, event_from_values(s.message,
                                                     {kv.key: kv.value for kv in s.values})))
    return gt, active


@pytest.mark.slow
def test_run_with_a_schedule_writes_the_ground_truth(tmp_path):
    path = tmp_path / 'faults.yaml'
    path.write_text(SCHEDULE)
    prof = read_profile('ramp:1000:1400:200:1.0:0.5')
    bags = {}
    for threads in (1, 2):
        bags[threads] = tmp_path / f'bag{threads}'
        summary = run_profile(prof, bags[threads], RunOptions(faults=str(path), threads=threads))
        assert summary.misfires == 6 and summary.fault_events == 12
    gt, active = _ground_truth(bags[1])
    assert [(e['id'], e['what']) for _, e in gt if e['what'] != 'misfire'] == [
        (1, 'start'), (1, 'end'), (2, 'start'), (3, 'start'), (2, 'end'), (3, 'end')]
    misfires = [e for _, e in gt if e['what'] == 'misfire']
    assert misfires[0]['cylinder'] == 3 and {e['cylinder'] for e in misfires[1:]} == {1}
    # every combustion of cylinder 1 whose window opened in [1.0, 1.5) s misfired: one per
    # cycle, TDCs 720 deg apart
    tdc = np.array([e['tdc_crank_angle_rad'] for e in misfires[1:]])
    np.testing.assert_allclose(np.diff(tdc), 4 * np.pi)
    assert all(1.0 <= e['event_s'] < 1.5 for e in misfires[1:])
    # stamps: the bag's log time is the event's stamp
    assert all(t == e['event_ns'] for t, e in gt)
    # the active set: empty at the start (latched "none"), then as the faults come and go
    assert active[0][1] == [] and active[0][0] <= gt[0][0]
    assert ['fault 2', 'fault 3'] in [names for _, names in active] and active[-1][1] == []
    # both thread settings write the same ground truth
    other, _ = _ground_truth(bags[2])
    t0, u0 = gt[0][0], other[0][0]
    assert [(t - t0, e['what'], e['id']) for t, e in gt] == \
        [(t - u0, e['what'], e['id']) for t, e in other]
    # the fault topics are declared latched with their depths
    meta = yaml.safe_load((bags[1] / 'metadata.yaml').read_text())
    qos = {t['topic_metadata']['name']: t['topic_metadata']['offered_qos_profiles']
           for t in meta['rosbag2_bagfile_information']['topics_with_message_count']}
    for key in ('fault_ground_truth', 'fault_active'):
        [profile] = qos[resolved_topics()[key]]
        assert profile['durability'] == 'transient_local'
        assert profile['depth'] == STREAMS[key].depth


def test_run_without_faults_declares_the_topics_writes_nothing(tmp_path):
    prof = read_profile('ramp:1000:1050:500:0.5:0.1')
    summary = run_profile(prof, tmp_path / 'bag', RunOptions())
    gt, active = _ground_truth(tmp_path / 'bag')
    assert gt == [] and active == [] and summary.fault_events == 0


@pytest.mark.parametrize('faults,words', [
    ('[{kind: misfire, cylinders: [7], at_s: 0.1}]', ["faults[0] (misfire)", "'cylinders[0]'",
                                                       '1..6']),
    ('[{kind: misfire, cylinders: [1], at_s: 0.1}, {kind: dmf_broken, stage: 5}]',
     ['faults[1] (dmf_broken)', "'stage'", '5 does not exist']),
    ('[{kind: misfire, cylinders: [2], mode: every_cycle, start_s: 0.2, end_s: 0.1}]',
     ["faults[0] (misfire)", "'end_s'", 'inverted']),
    ('[{kind: weak_cylinder, cylinder: 2, factor: 0.5, start_s: 0.1, end_s: 0.3},'
     ' {kind: weak_cylinder, cylinder: 2, factor: 0.6, start_s: 0.2}]',
     ['faults[1] (weak_cylinder)', 'overlaps faults[0]', 'cylinder 2']),
    ('[{kind: weak_cylinder, cylinder: 2, factor: .nan}]', ["'factor'", 'nan']),
    ('[{kind: misfire, cylinders: [2], at_s: 9.0}]', ["'at_s'", 'not before the end']),
    ('[{kind: misfire, cylinders: [2], sometimes: true}]', ["unknown key 'sometimes'"]),
])
@pytest.mark.slow
def test_bad_schedule_one_line_exit_2(tmp_path, capsys, faults, words):
    path = tmp_path / 'faults.yaml'
    path.write_text(f'faults: {faults}\n')
    assert cli_main(['run', 'ramp:1000:1050:500:0.5:0.1', '--faults', str(path),
                     '--no-write']) == 2
    err = capsys.readouterr().err.strip()
    assert '\n' not in err and err.startswith('dmf-sim run: ') and str(path) in err
    for w in words:
        assert w in err, (w, err)


def test_schedule_errors_of_file_and_engine(tmp_path, capsys):
    assert cli_main(['run', 'ramp:1000:1050:500:0.5:0.1', '--faults',
                     str(tmp_path / 'none.yaml'), '--no-write']) == 2
    assert 'none.yaml' in capsys.readouterr().err
    path = tmp_path / 'faults.yaml'
    path.write_text('faults: [{kind: misfire, cylinders: [2], at_s: 0.05}]\n')
    assert cli_main(['run', 'ramp:1000:1050:500:0.5:0.1', '--faults', str(path), '--engine',
                     'engine_table_example.csv', '--no-write']) == 2
    err = capsys.readouterr().err
    assert 'faults[0] (misfire)' in err and 'pressure-model engine' in err
    # a DMF fault runs with any engine
    path.write_text('faults: [{kind: dmf_damping, factor: 2, start_s: 0.05}]\n')
    assert cli_main(['run', 'ramp:1000:1050:500:0.5:0.1', '--faults', str(path), '--engine',
                     'engine_table_example.csv', '--no-write']) == 0
    # its start; no end: it is active when the run ends (faults/active says so)
    assert 'ground-truth events: 1, misfires: 0' in capsys.readouterr().out


def test_a_dmf_rebuild_keeps_the_end_stop_and_friction_counts(tmp_path):
    """A DMF fault rebuilds the integrator keeping the state; a fault that changes nothing
    (damping factor 1) must leave every count of the run as it is: the stop contacts, the
    largest impact torque and the friction heat (to 1e-6 J: the rebuilt integrator's own
    round-off), the knee crossings and the wind-up. Before, the chunk the rebuild fell in lost
    its contacts and heat: 4 contacts and 106.6 J instead of 35 and 256.1 J."""
    from dmf_sim.core.paths import config_dir
    line = yaml.safe_load((config_dir() / 'truck_dmf_friction.yaml').read_text())
    line['dmf']['end_stops']['drive_angle_rad'] = 0.25        # a tip-in reaches the stop
    config = tmp_path / 'stop_close.yaml'
    config.write_text(yaml.safe_dump(line))
    faults = tmp_path / 'f.yaml'
    faults.write_text('faults: [{kind: dmf_damping, factor: 1.0, start_s: 2.5}]\n')
    profile = read_profile('step:1200:0:1:0.1')
    plain = run_profile(profile, None, RunOptions(driveline=str(config), write=False))
    faulted = run_profile(profile, None, RunOptions(driveline=str(config), write=False,
                                                    faults=str(faults)))
    assert faulted.fault_events == 1 and plain.stop_contacts > 20
    assert faulted.stop_contacts == plain.stop_contacts
    assert faulted.knee_crossings == plain.knee_crossings
    assert faulted.peak_stop_torque_nm == pytest.approx(plain.peak_stop_torque_nm, abs=1e-3)
    assert faulted.friction_heat_j == pytest.approx(plain.friction_heat_j, abs=1e-6)
    assert faulted.peak_windup_rad == pytest.approx(plain.peak_windup_rad, abs=1e-8)
