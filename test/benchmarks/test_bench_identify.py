"""The identification benchmark runs on its small case and prints its figures as the last JSON
line: the known parameters come back from a noisy wind-up within the target."""

import pytest
from support.benchmarks import bench_json


@pytest.mark.slow
def test_bench_identify_small_prints_json():
    data = bench_json('bench_identify.py', '--small', timeout=600)
    assert data['small'] and data['noise_rad'] > 0 and data['start_from'] == 'truck_dmf'
    assert set(data['cases']) == {'small'}
    case = data['cases']['small']
    assert set(case['rel_err']) == {'k', 'theta', 'alpha', 'damping', 'friction.torque_nm',
                                    'friction.speed_coefficient'}
    assert case['windup_max_rad'] > case['true']['theta']          # the knee was crossed
    assert data['identify_param_rel_err'] <= 0.05
    assert data['identify_seconds'] > 0 and case['simulations'] >= 5
