"""The Newmark benchmark runs on small sizes and prints real figures as its last JSON line."""
import math

import pytest
from support.benchmarks import bench_json

pytestmark = pytest.mark.bench


@pytest.mark.slow
def test_bench_newmark_quick_prints_json():
    data = bench_json('bench_newmark.py', '--quick', timeout=300)
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
