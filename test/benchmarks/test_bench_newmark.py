"""The Newmark benchmark runs on small sizes and prints real figures as its last JSON line."""
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.bench
BENCH = Path(__file__).resolve().parents[2] / 'benchmarks' / 'bench_newmark.py'


@pytest.mark.slow
def test_bench_newmark_quick_prints_json():
    out = subprocess.run([sys.executable, str(BENCH), '--quick'], capture_output=True, text=True,
                         check=True, timeout=300).stdout.strip().splitlines()
    data = json.loads(out[-1])
    for key in ('steps_per_s', 'realtime_factor', 'speedup_vs_solve_ivp'):
        assert math.isfinite(data[key]) and data[key] > 0
    # same accuracy: solve_ivp's error is no larger than Newmark's (or the tightest rtol tried)
    assert (data['solve_ivp_rel_error'] <= data['newmark_rel_error']
            or data['solve_ivp_rtol'] == 1e-8)
    assert data['realtime_factor'] == data['steps_per_s'] * data['dt_s'] or \
        abs(data['realtime_factor'] - data['steps_per_s'] * data['dt_s']) < 0.1
    # what friction and end stops cost: the kernel and dmf-sim run with them over without
    for key in ('kernel_friction_slowdown', 'run_friction_slowdown',
                'realtime_factor_run_friction', 'kernel_steps_per_s_friction'):
        assert math.isfinite(data[key]) and data[key] > 0, key
    assert data['realtime_factor_run_friction'] > 1.0     # the node at 1 kHz keeps real time
    assert data['friction_config'] == 'truck_dmf_friction'
