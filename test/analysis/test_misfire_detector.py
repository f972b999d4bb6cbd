"""The reference misfire detector (dmf_sim.analysis.misfire_detector) on simulated bags: the
injected misfires found at their cylinder and combustion, no alarm on a healthy run with a load
step; the scoring counts per cylinder."""
from __future__ import annotations

import json

import numpy as np

from dmf_sim.analysis.misfire_detector import detect_bag, ground_truth_misfires, score_detections
from dmf_sim.transient.profiles import make_profile, read_profile
from dmf_sim.transient.run import RunOptions, run_profile

SCHEDULE = '''faults:
  - {kind: misfire, cylinders: [3], at_s: 2.3}
  - {kind: misfire, cylinders: [5], at_s: 2.8}
'''


def test_misfires_found_at_their_cylinder_and_combustion(tmp_path):
    (tmp_path / 'f.yaml').write_text(SCHEDULE)
    prof = make_profile([(0.0, 1300.0, 0.6), (3.3, 1300.0, 0.6)])
    run_profile(prof, tmp_path / 'bag', RunOptions(faults=str(tmp_path / 'f.yaml')))
    scores, result = detect_bag(tmp_path / 'bag')
    truth = ground_truth_misfires(tmp_path / 'bag')
    assert len(truth) == 2
    assert result.misfires == 2 and result.detected == 2 and result.false_alarms == 0
    alarms = np.flatnonzero(scores['alarm'])
    assert list(scores['cylinder'][alarms]) == [3, 5]
    np.testing.assert_allclose(scores['tdc_rad'][alarms], truth, atol=1e-9)
    assert 2.3 < scores['t_s'][alarms[0]] < 2.3 + 0.1      # its next combustion, in time
    # a misfire removes about a whole combustion's share of the work (M2), far past the
    # threshold; healthy intervals stay near 0
    assert np.all(scores['score'][alarms] < -0.4)
    healthy = np.delete(scores['score'], alarms)
    assert np.max(np.abs(healthy)) < 0.25
    assert result.per_cylinder[3]['detected'] == 1 and result.per_cylinder[1]['misfires'] == 0
    assert abs(result.mean_speed_rpm - 1300) < 5


def test_no_alarm_on_a_healthy_load_step(tmp_path):
    run_profile(read_profile('step:1200:1:0.3:0.1:0.6:2'), tmp_path / 'bag', RunOptions())
    scores, result = detect_bag(tmp_path / 'bag')
    assert result.misfires == 0 and result.false_alarms == 0
    assert result.cycles > 10 and not scores['alarm'].any()


def test_scoring_counts_per_cylinder():
    order = np.tile([1, 5, 3, 6, 2, 4], 2)                   # firing order, two cycles
    scores = {'tdc_rad': np.arange(12) * (4 * np.pi / 6), 'cylinder': order,
              'score': np.zeros(12), 'omega': np.full(12, 2 * np.pi * 20)}
    scores['score'][[2, 10]] = -1.0         # alarms: cylinder 3 (a misfire), cylinder 2
    misfired = scores['tdc_rad'][[2, 3]] + 0.1               # cylinders 3 and 6
    result = score_detections(scores, misfired, 6)
    assert (result.misfires, result.detected, result.false_alarms) == (2, 1, 1)
    assert result.per_cylinder[6] == {'misfires': 1, 'detected': 0, 'missed': 1,
                                      'false_alarms': 0, 'intervals': 2}
    assert result.per_cylinder[2]['false_alarms'] == 1
    assert result.per_cylinder[3]['detected'] == 1
    assert result.cycles == 2 and result.false_alarm_rate == 0.5
    assert abs(result.mean_speed_rpm - 1200) < 1e-9


def test_detect_command_prints_the_score(tmp_path, capsys):
    from dmf_sim.cli import main as cli_main

    (tmp_path / 'f.yaml').write_text(SCHEDULE)
    prof = make_profile([(0.0, 1500.0, 1.0), (3.3, 1500.0, 1.0)])
    run_profile(prof, tmp_path / 'bag', RunOptions(faults=str(tmp_path / 'f.yaml')))
    assert cli_main(['detect', str(tmp_path / 'bag'), '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out['misfires'], out['detected'], out['false_alarms']) == (2, 2, 0)
    assert [a['cylinder'] for a in out['alarms']] == [3, 5]
    assert out['per_cylinder']['3']['detected'] == 1
    assert out['windup']['rel_err'] < 0.03
    assert cli_main(['detect', str(tmp_path / 'bag'), '--crank', 'cam']) == 2
    err = capsys.readouterr().err
    assert "no tooth wheel 'cam' recorded; wheels are crank" in err


def test_dropped_and_spurious_edges_do_not_raise_alarms(tmp_path):
    # sensor faults: 1 % of the crank's edges dropped, spurious edges on the secondary wheel
    (tmp_path / 'f.yaml').write_text('''faults:
  - {kind: misfire, cylinders: [2], at_s: 2.3}
  - {kind: sensor_edges, sensor: crank, mode: missing, probability: 0.01, seed: 5}
  - {kind: sensor_edges, sensor: flywheel_secondary, mode: extra, rate_per_s: 20, seed: 6}
''')
    prof = make_profile([(0.0, 1400.0, 0.6), (3.3, 1400.0, 0.6)])
    run_profile(prof, tmp_path / 'bag', RunOptions(faults=str(tmp_path / 'f.yaml')))
    scores, result = detect_bag(tmp_path / 'bag')
    assert (result.misfires, result.detected, result.false_alarms) == (1, 1, 0)
    assert list(scores['cylinder'][scores['alarm']]) == [2]
