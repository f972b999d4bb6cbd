"""The transient-run benchmark runs on small sizes and prints its figures as the last JSON
line (the whole chain: run with and without a bag, run-up analysis, fold case up and down, a
profile's memory, durability in batches)."""
import math

import pytest
from support.benchmarks import bench_json


@pytest.mark.slow
def test_bench_run_small_prints_json():
    data = bench_json('bench_run.py', '--small', timeout=900)
    for key in ('realtime_factor', 'realtime_factor_cpu', 'realtime_factor_no_write',
                'realtime_factor_no_write_cpu', 'realtime_factor_threads1',
                'realtime_factor_threads2', 'realtime_factor_no_sensors',
                'realtime_factor_no_write_no_sensors'):
        assert math.isfinite(data[key]) and data[key] > 0
    assert data['threads_default'] in (1, 2)
    # four sample streams at 1 kHz, the node's health status once per simulated second, and
    # the default sensors' tooth-edge batches and bus frames beside them
    counts = data['messages_by_topic']
    samples = round(data['simulated_s'] * 1000)
    for topic in ('/driveline/joint_states', '/driveline/dmf_windup', '/engine/speed',
                  '/engine/crank_angle'):
        assert counts[topic] == samples, topic
    assert counts['/diagnostics'] == int(data['simulated_s'])
    sensors = {t: n for t, n in counts.items() if t.startswith(('/sensors/', '/vehicle_bus/'))}
    assert sensors and all(n > 0 for n in sensors.values()), sensors
    assert data['messages'] == sum(counts.values())
    folds = data['fold_events_rpm']
    assert len(folds) == 2 and 360 < min(folds) < max(folds) < 380
    assert set(data['run_peak_rss_mib']) == {'0.1', '0.5', '1'}
    assert data['run_rss_growth_mib'] < 50 and data['durability_batches'] >= 2
    assert data['damage_per_hour'] > 0 and data['dissipated_power_mean_w'] > 0
    for key in ('quasi_static_rel_diff', 'quasi_static_rel_diff_slow', 'jump_speed_error_rpm'):
        assert key in data
