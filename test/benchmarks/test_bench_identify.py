"""The identification benchmark runs on its small case and prints its figures as the last JSON
line: the known parameters come back from a noisy wind-up within the target."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / 'benchmarks' / 'bench_identify.py'


@pytest.mark.slow
def test_bench_identify_small_prints_json():
    out = subprocess.run([sys.executable, str(BENCH), '--small'], capture_output=True, text=True,
                         check=True, timeout=600).stdout.strip().splitlines()
    data = json.loads(out[-1])
    assert data['small'] and data['noise_rad'] > 0 and data['start_from'] == 'truck_dmf'
    assert set(data['cases']) == {'small'}
    case = data['cases']['small']
    assert set(case['rel_err']) == {'k', 'theta', 'alpha', 'damping', 'friction.torque_nm',
                                    'friction.speed_coefficient'}
    assert case['windup_max_rad'] > case['true']['theta']          # the knee was crossed
    assert data['identify_param_rel_err'] <= 0.05
    assert data['identify_seconds'] > 0 and case['simulations'] >= 5
