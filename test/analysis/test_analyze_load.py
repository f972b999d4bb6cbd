"""``analyze`` at the load the bag recorded.

A recording whose load setpoint goes 0.5 -> 1.0 mid-way at a fixed 1000 rpm, made offline with
the node's simulation core and its health statuses in /diagnostics (as the node records them).
Before: one 1000 rpm row mixing both loads, marked steady, compared with the HBM at the start
load (3rd order tens of % off). Now: rows per speed *and* load, each compared with the HBM at its
own load (3rd order within 1 %), the cycles of the change never steady.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from support.analysis_tolerances import TOL_MEAN, TOL_ORDER_1_5, TOL_ORDER_3
from support.synthetic_bags import record_load_change, write_synthetic

from dmf_sim.analysis.load_timeline import HEALTH_KEYS, load_timeline
from dmf_sim.analysis.pipeline import AnalysisOptions, analyze_bag, model_settings, overlay_all
from dmf_sim.bags.metadata import RunMetadata
from dmf_sim.cli import main as cli_main

CHANGE_S, DURATION_S = 5.0, 12.0


@pytest.fixture(scope='module')
def step(tmp_path_factory):
    root = tmp_path_factory.mktemp('load')
    return record_load_change(root / 'step', 1000.0, 0.5, 1.0, CHANGE_S, DURATION_S)


@pytest.mark.slow
def test_rows_per_load_each_compared_at_its_own_load(step, capsys):
    assert cli_main(['analyze', str(step), '--json', '--no-plots']) == 0
    data = json.loads(capsys.readouterr().out)
    rows = data['signals']['windup']['rows']
    assert {r['speed_rpm'] for r in rows} == {1000.0}
    steady = [r for r in rows if r['steady']]
    assert sorted(r['load'] for r in steady) == [0.5, 1.0]
    for r in steady:
        assert abs(r['order_3'] / r['hbm_order_3'] - 1) < TOL_ORDER_3, r
        assert abs(r['order_1_5'] / r['hbm_order_1_5'] - 1) < TOL_ORDER_1_5, r
        assert abs(r['mean_minus_theta'] - r['hbm_mean_minus_theta']) < TOL_MEAN, r
    # the loads differ enough that comparing at the wrong one could not pass
    a, b = sorted(steady, key=lambda r: r['load'])
    assert b['hbm_order_3'] / a['hbm_order_3'] > 1.5
    # the cycles of the change: their own row, never steady, no HBM value
    (mixed,) = [r for r in rows if r['load'] is None]
    assert not mixed['steady'] and mixed['hbm_order_3'] is None and mixed['n_cycles'] >= 1
    diff = data['signals']['windup']['hbm']['difference']['order_3']
    assert diff['n_rows'] == 2 and diff['rel_to_peak'] < TOL_ORDER_3
    assert data['model']['load'] == [0.5, 1.0]
    assert data['model_sources']['load'] == 'bag (per engine cycle)'
    timeline = data['load_timeline']
    assert timeline['levels'] == [0.5, 1.0]
    (gap,) = timeline['unknown_s']
    assert gap[0] <= CHANGE_S + 0.05 and CHANGE_S + 0.5 <= gap[1] <= CHANGE_S + 1.1
    assert any('load was changing or unknown' in w for w in data['warnings'])


def test_load_option_is_one_load_for_the_whole_recording(step):
    """--load L (a caller who knows better) is taken for every cycle: one row per speed."""
    res = analyze_bag(step, options=AnalysisOptions(load=0.5))
    assert res.load_timeline is None and res.signal('windup').table.load is None
    assert len(res.signal('windup').table) == 1


def test_per_cycle_rows_are_steady_only_at_a_known_load(step):
    res = analyze_bag(step, options=AnalysisOptions(bin_rpm=0))
    t = res.signal('windup').table
    assert len(t) == len(res.signal('windup').cycles)
    assert (t.steady == np.isfinite(t.load)).all() and (~t.steady).sum() >= 1
    assert set(np.round(t.load[t.steady], 3)) == {0.5, 1.0}


def test_load_setpoint_topic_marks_the_change():
    """The setpoint topic (ros2 bag record -a) says when a change started: the load is known
    up to it and unknown from it to the next health status that shows it reached."""
    s = 1_000_000_000
    health = (np.array([0, 1, 2, 3]) * s,
              np.array([[0.5, 0.5, 2.5, 0.24], [0.5, 0.5, 2.5, 0.24], [1.0, 1.0, 2.5, 0.24],
                        [1.0, 1.0, 2.5, 0.24]]))
    assert health[1].shape[1] == len(HEALTH_KEYS)
    setpoints = (np.array([int(1.4 * s)]), np.array([1.0]))
    tl = load_timeline(health, setpoints, 0.5, 0, int(3.5 * s))
    assert tl.load_between(0.1 * s, 1.3 * s) == 0.5          # before the setpoint: known
    assert math.isnan(tl.load_between(1.3 * s, 1.5 * s))     # across it: changing
    assert math.isnan(tl.load_between(1.5 * s, 1.9 * s))     # ramping, not confirmed yet
    assert tl.load_between(2.1 * s, 3.4 * s) == 1.0
    assert tl.levels == [0.5, 1.0] and len(tl.sources) == 3
    no_sp = load_timeline(health, None, 0.5, 0, int(3.5 * s))
    assert no_sp.load_between(0.1 * s, 0.9 * s) == 0.5 and math.isnan(no_sp.load_between(
        1.3 * s, 1.5 * s))
    # a health status still ramping towards its setpoint: unknown up to the next one
    ramping = (np.array([0, 1, 2]) * s, np.array([[0.5, 0.5, 2.5, 0.24], [0.7, 1.0, 2.5, 0.24],
                                                  [1.0, 1.0, 2.5, 0.24]]))
    tl = load_timeline(ramping, None, None, 0, 2 * s)
    assert math.isnan(tl.load_between(1.1 * s, 1.2 * s))
    assert load_timeline(None, None, 0.5, 0, s) is None     # the start value alone: no timeline


@pytest.mark.slow
def test_start_load_only_and_no_load_are_warned(tmp_path):
    """A bag that stores only the start load (no health statuses, no setpoints) is analysed
    at it, with a warning that it was assumed constant; with no load at all: 1.0, warned; and
    a model the bag does not record (driveline, engine, spring) is named as assumed."""
    short = {'duration': 2.0, 'v0': 950.0, 'v1': 1050.0}
    only_start = write_synthetic(tmp_path / 'start', ('windup', 'speed', 'crank'),
                                 custom_data=RunMetadata(load=0.7).to_custom_data(), **short)
    none = write_synthetic(tmp_path / 'none', ('windup', 'speed', 'crank'), **short)
    for bag, words in ((only_start, 'only at the start of the recording (0.7'),
                       (none, 'does not record the engine load')):
        res = analyze_bag(bag)
        overlay_all(res, model_settings(res.metadata), hbm=False)
        assert any(words in w for w in res.warnings), res.warnings
        (model,) = [w for w in res.warnings if 'does not record the model' in w]
        assert 'driveline truck_dmf' in model and 'engine engine_d13' in model
        assert 'DMF spring of the driveline YAML' in model
    res = analyze_bag(none)
    overlay_all(res, model_settings(res.metadata, config='truck_dmf', engine='engine_d13',
                                    load_set='A', load=1.0), hbm=False)
    assert not any('does not record' in w for w in res.warnings), res.warnings
