"""The friction benchmark runs small and prints its figures as the last JSON line: both sweep
ratios measured, with the share of the friction sweep's Floquet stage; HBM and Newmark within
2 % on the 1.5th and 3rd orders where the DMF slips."""

import pytest
from support.benchmarks import bench_json


@pytest.mark.slow
def test_bench_friction_hbm_small_prints_json():
    data = bench_json('bench_friction_hbm.py', '--small', timeout=900)
    assert data['small'] and data['repeat'] == 2
    for mode in ('fast', 'full'):
        assert data[f'friction_sweep_time_ratio_{mode}'] > 0
        assert data[f'friction_sweep_time_ratio_{mode}_min'] <= \
            data[f'friction_sweep_time_ratio_{mode}']
        # a part of the friction sweep, timed apart: above zero, below the whole
        share = data[f'floquet_over_baseline_{mode}']
        assert 0 < share < data[f'friction_sweep_time_ratio_{mode}']
    assert data['friction_sweep_time_ratio'] == data['friction_sweep_time_ratio_fast']
    assert len(data['check']) == 2
    assert data['max_rel_diff'] <= 0.02 and data['max_small_order_diff'] <= 0.01
