"""The faults benchmark runs small and prints its figures as the last JSON line: every injected
misfire of its grid found, no false alarm, the wind-up from the sensors within 3 %."""

import pytest
from support.benchmarks import bench_json


@pytest.mark.slow
def test_bench_faults_small_prints_json():
    data = bench_json('bench_faults.py', '--small', timeout=600)
    assert data['small'] and data['misfires'] == 12 and data['engine_cycles'] > 50
    assert data['misfire_detection_rate'] >= 0.99
    assert data['false_alarm_rate'] <= 1e-3
    assert data['windup_from_sensors_rel_err'] <= 0.03
    runs = [row['run'] for row in data['table']]
    assert len(runs) == 5 and runs[-1].startswith('ramp:')
    assert all(row['false_alarms'] == 0 for row in data['table'])
    assert set(data['campaign_runs_per_s']) == {'1', '2'}
    assert all(r > 0 for r in data['campaign_runs_per_s'].values())
