"""Load steps: the ``step:`` profile grammar, the one-Newmark-step rule, the peaks a run reports
(overshoot of the driveline's lowest mode), end stops through the spring's hook, the node's
health peaks (ROS-free), and a design study's load steps. Over DDS: test_load_steps_dds.py."""
from __future__ import annotations

import copy
import csv
import json
import math

import numpy as np
import pytest
import yaml

import dmf_sim as dmf
from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.paths import config_dir
from dmf_sim.live.peaks import WindupPeaks
from dmf_sim.physics.spring import PiecewiseLinearSpring
from dmf_sim.transient.profiles import DEFAULT_HOLD_S, DEFAULT_SETTLE_S, read_profile, step_spec
from dmf_sim.transient.run import RunOptions, run_profile


def _run(spec: str, **kw):
    return run_profile(read_profile(spec), None, RunOptions(write=False, **kw))


@pytest.fixture(scope='module')
def loads():
    return dmf.DrivelineExcitation(dmf.read_model('truck_dmf'), dmf.read_engine('engine_d13'))


# ---- the grammar -------------------------------------------------------------------------------
def test_step_grammar_rows_and_defaults(tmp_path):
    p = read_profile('step:1200:0:1:0.1')
    s, h = DEFAULT_SETTLE_S, DEFAULT_HOLD_S
    assert p.t_s.tolist() == pytest.approx([0, s, s + 0.1, s + 0.1 + h, s + 0.2 + h,
                                            s + 0.2 + 2 * h])
    assert p.load.tolist() == [0, 0, 1, 1, 0, 0] and set(p.speed_rpm) == {1200.0}
    assert p.settle_s == s and p.name == 'step:1200:0:1:0.1'
    q = read_profile('step:1600:0.5:-1:0.2:0.5:0')                  # a tip-out into the brake
    assert q.t_s.tolist() == pytest.approx([0, 0.2, 0.7, 0.9, 1.4])
    assert q.load.tolist() == [0.5, -1, -1, 0.5, 0.5] and 'tip-out' in q.source
    assert step_spec(1200, 0, 1, 0.1, 0.5) == 'step:1200:0:1:0.1:0.5'
    yml = tmp_path / 'tip.yaml'
    yml.write_text('step: {speed_rpm: 1200, from: 0, to: 1, rise_s: 0.1}\n')
    r = read_profile(str(yml))
    assert r.t_s.tolist() == p.t_s.tolist() and r.load.tolist() == p.load.tolist()


@pytest.mark.parametrize('spec, needle', [
    ('step:1200:0:1', 'write step:SPEED:FROM:TO:RISE[:HOLD[:SETTLE]]'),
    ('step:1200:0:0:0.1', "field 'to' must differ from from (0)"),
    ('step:1200:0:1.5:0.1', "field 'to' must be in [-1, 1], got 1.5"),
    ('step:1200:0:1:0', "field 'rise_s' must be in (0, 3600] s, got 0.0"),
    ('step:1200:0:1:0.1:-1', "field 'hold_s' must be in (0, 3600] s"),
    ('step:0:0:1:0.1', "field 'speed_rpm' must be > 0 rpm"),
    # below the time's resolution at its start: named 'time_s' of a row the user never wrote
    ('step:1200:0:1:1e-17', "field 'rise_s' must be in (0, 3600] s and longer than the time "
                            'resolution at t = 2 s (4.44e-16 s), got 1e-17'),
    ('step:1200:0:1:1e-300:1:0', "field 'rise_s' must be in (0, 3600] s and longer than the "
                                 'time resolution at t = 1 s'),
    ('step:1200:0:1:0.1:1e-300', "field 'hold_s' must be in (0, 3600] s and longer than the "
                                 'time resolution at t = 2.1 s'),
])
def test_bad_step_specs_are_one_line(spec, needle, capsys, tmp_path):
    out = tmp_path / 'bag'
    assert cli_main(['run', spec, '--out', str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count('\n') == 0 and 'Traceback' not in err and needle in err, err
    assert not out.exists()


def test_a_load_step_faster_than_one_newmark_step_is_refused(tmp_path, capsys):
    """The profile does not know the step; the run (--dt) and the node (dt) do: one line naming
    the row, the change and the step, nothing written."""
    out = tmp_path / 'bag'
    assert cli_main(['run', 'step:1200:0:1:0.00005', '--out', str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count('\n') == 0 and 'Traceback' not in err
    assert ('profile step:1200:0:1:5e-05: row 3 (t = 2.00005 s) the load changes from 0 to 1 '
            'in 5e-05 s, faster than one Newmark step (--dt = 0.0001 s)') in err
    assert not out.exists()
    table = tmp_path / 'fast.csv'
    table.write_text('time_s,speed_rpm,load\n0,1200,0\n1,1200,0\n1.0005,1200,1\n2,1200,1\n')
    assert cli_main(['run', str(table), '--dt', '1e-3', '--out', str(out)]) == 2
    assert 'faster than one Newmark step (--dt = 0.001 s)' in capsys.readouterr().err
    assert not out.exists()
    # one step is allowed (the rise as given, down to dt)
    assert _run('step:1200:0:1:0.0001:0.3:0.1').samples > 0
    # braking with an engine that has no brake curve: one line naming the row
    assert cli_main(['run', 'step:1200:0:-1:0.1', '--engine', 'engine_table_example.csv',
                     '--out', str(out)]) == 2
    err = capsys.readouterr().err
    assert 'row 3 (t = 2.1 s) load -1 outside [0, 1]' in err and 'no brake curve' in err
    assert not out.exists()


# ---- what a run reports ------------------------------------------------------------------------
@pytest.mark.slow
def test_tip_in_overshoots_the_static_windup(loads):
    """The DMF mode (the driveline's lowest, ~7.8 Hz) overshoots a fast load step: an undamped
    single mode reaches 1 + |sin(pi f T)/(pi f T)| of the static change for a ramp of T s (2 for a
    step); damped it stays below that. Measured on 0 -> 0.5 at 1200 rpm (the spring stays in its
    primary stage): one Newmark step 1.78 (the first peak of a mode damped at ~8 %), 0.1 s 1.22
    (undamped 1.26); the tip-out undershoots below zero. A full tip-in in 0.1 s peaks above the
    static full-load wind-up (in the stiffer second stage: 0.273 vs 0.245 rad)."""
    f1 = dmf.modes(loads.model).frequencies_hz[1]
    assert 7.0 < f1 < 8.5
    w_half = loads.static_state(1200.0, 0.5).windup
    for rise, lo, hi in ((1e-4, 1.7, 2.0), (0.1, 1.1, None), (0.3, 1.03, None)):
        s = _run(f'step:1200:0:0.5:{rise:g}:1:0.5')
        x = math.pi * f1 * rise
        undamped = 1.0 + abs(math.sin(x) / x)
        ratio = s.peak_windup_rad[1] / w_half
        assert lo < ratio < (hi or undamped), (rise, ratio, undamped)
        assert s.peak_windup_rad[0] < 0.0                       # tip-out undershoot
    full = _run('step:1200:0:1:0.1')
    w_full = loads.static_state(1200.0, 1.0).windup
    assert full.peak_windup_rad[1] > w_full + 0.02
    spring = loads.model.spring
    assert full.peak_dmf_torque_nm == pytest.approx([float(spring.torque(w))
                                                     for w in full.peak_windup_rad])


def test_braking_step_and_the_summary_json(capsys):
    assert cli_main(['run', 'step:1600:0:-1:0.1:0.5:0.5', '--no-write', '--json']) == 0
    d = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    lo, hi = d['peak_windup_rad']
    assert lo < -0.11 < hi                                      # below the static -0.113
    assert d['peak_dmf_torque_nm'][0] < -1230.0                 # beyond the brake curve
    assert 'stop_contacts' not in d and 'travel_margin_rad' not in d   # no stop: not reported
    assert set(d['peak_rss_mib']) == {'0.1', '0.5', '1'}     # the memory marks stay apart
    assert cli_main(['run', 'step:1600:0:-1:0.1:0.5:0.5', '--no-write']) == 0
    out = capsys.readouterr().out
    assert 'step:1600:0:-1:0.1:0.5:0.5: peak wind-up -0.1' in out and 'DMF torque -1' in out


def test_a_driveline_without_a_dmf_reports_no_peaks(capsys):
    """Without a DMF there is no wind-up and no DMF torque: the summary printed "0.0000 ..
    0.0000 rad, DMF torque nan .. nan Nm" and its JSON held NaN (not JSON). The peak fields are
    left out now, the text says there is no DMF, and the node's health carries only the time
    the peaks start at."""
    from dmf_sim.live.health import peak_values

    def refuse(name):
        raise ValueError(f'not JSON: {name}')
    argv = ['run', 'step:1200:0:1:0.1', '--config', 'truck_conventional', '--no-write']
    assert cli_main([*argv, '--json']) == 0
    d = json.loads(capsys.readouterr().out.strip().splitlines()[-1], parse_constant=refuse)
    assert 'peak_windup_rad' not in d and 'peak_dmf_torque_nm' not in d and d['samples'] > 0
    assert cli_main(argv) == 0
    out = capsys.readouterr().out
    assert 'step:1200:0:1:0.1: no DMF: no wind-up, no DMF torque' in out and 'nan' not in out
    peaks = WindupPeaks(None)
    peaks.observe(np.zeros(3), np.arange(3.0))
    assert peaks.as_dict() == {'since_s': 0.0}
    assert peak_values(peaks) == {'peaks_since_s': '0.0000'}


def test_end_stops_through_the_spring_hook(monkeypatch):
    """With end stops on the spring (``stop_angles_rad``, set by the end-stop model) a run
    reports the travel margin and the stop contacts."""
    monkeypatch.setattr(PiecewiseLinearSpring, 'stop_angles_rad', (-0.05, 0.25))
    s = _run('step:1200:0:1:0.0001:1:0.5')
    d = s.as_dict()
    assert d['travel_margin_rad'] == pytest.approx(min(0.25 - s.peak_windup_rad[1],
                                                       s.peak_windup_rad[0] + 0.05))
    assert d['travel_margin_rad'] < 0 and d['stop_contacts'] >= 2    # tip-in and tip-out


def test_peaks_count_entries_across_chunks():
    spring = PiecewiseLinearSpring.two_step(10890.0, 0.24, 2.5)
    peaks = WindupPeaks(spring)
    peaks.observe(np.array([0.0, 0.1]), np.array([0.0, 1.0]))
    assert peaks.as_dict()['peak_windup_rad'] == [0.0, 0.1] and 'stop_contacts' not in \
        peaks.as_dict()
    spring.stop_angles_rad = (-0.2, 0.2)
    peaks.observe(np.array([0.15, 0.25, 0.3]), np.array([2.0, 3.0, 4.0]))   # one entry
    peaks.observe(np.array([0.21, 0.1, -0.3]), np.array([5.0, 6.0, 7.0]))   # still in, out, in
    d = peaks.as_dict()
    assert d['stop_contacts'] == 2 and d['travel_margin_rad'] == pytest.approx(-0.1)
    assert d['peak_windup_rad'] == [-0.3, 0.3] and d['peak_windup_t_s'] == [7.0, 4.0]
    assert d['peak_dmf_torque_nm'] == pytest.approx([float(spring.torque(-0.3)),
                                                     float(spring.torque(0.3))])
    peaks.reset(8.0)
    assert math.isnan(peaks.lo) and peaks.as_dict()['since_s'] == 8.0


# ---- the node's core (ROS-free) ----------------------------------------------------------------
def test_node_health_peaks_and_profile_checks():
    from dmf_sim.live.health import SimulationHealth
    from dmf_sim.live.simulation import LiveSimulation
    from dmf_sim.transient.live_profile import check_profile
    line = dmf.read_driveline('truck_dmf')
    sim = LiveSimulation(line, dmf.read_engine('engine_d13'), speed_rpm=1200.0, load=0.0,
                         load_ramp_per_s=10.0)
    sim.set_load_setpoint(1.0)                  # a tip-in in 0.1 s with the ramp parameter
    for _ in range(100):
        sim.advance(100)
    values = SimulationHealth(sim).report('x').values
    assert float(values['peak_windup_max_rad']) > 0.26
    assert float(values['peak_dmf_torque_max_nm']) > 3600.0
    assert float(values['peaks_since_s']) == 0.0 and 'stop_contacts' not in values
    sim.reset()                                 # ~/reset: the peaks start afresh
    values = SimulationHealth(sim).report('x').values
    assert values['peak_windup_max_rad'] == 'nan' and float(values['peaks_since_s']) > 0.99
    limits = sim.speed_limits_rpm
    prof, reason = check_profile('step:1200:0:1:0.00005', limits, engine=sim.engine, dt=sim.dt)
    assert prof is None and "faster than one Newmark step (the node's dt = 0.0001 s)" in reason
    prof, reason = check_profile('step:1200:0:-1:0.1', limits, engine=sim.engine, dt=sim.dt)
    assert reason is None and prof.load.min() == -1.0
    table = dmf.read_engine('engine_table_example.csv')
    assert 'no brake curve' in check_profile('step:1200:0:-1:0.1', (600.0, 2000.0),
                                             engine=table)[1]


# ---- a design study's load steps ---------------------------------------------------------------
def _study_doc() -> dict:
    d = yaml.safe_load((config_dir() / 'study_example.yaml').read_text())
    d['sampling'] = {'method': 'grid'}
    d['variables'] = {'alpha': {'values': [1.0, 4.0]}, 'theta': {'values': [0.3]}}
    d['conditions'].update(load_sets=['A'], speeds_rpm={'from': 1000, 'to': 1100, 'step': 50},
                           load_steps=[{'speed_rpm': 1200, 'from': 0, 'to': 1, 'rise_s': 0.1,
                                        'hold_s': 0.5, 'settle_s': 0.5},
                                       {'speed_rpm': 1600, 'from': 0, 'to': -1, 'rise_s': 0.1,
                                        'hold_s': 0.5, 'settle_s': 0.5}])
    d['objectives'] = ['transient_dmf_torque', 'worst_torque_3']
    return d


def test_design_study_load_step_columns(tmp_path):
    """Each design runs its load steps (the live core, as dmf-sim run does, no bag); its summary
    row holds the transient columns the optimizer's transient objective reads, stored in the
    study's table."""
    from dmf_sim.design.evaluate import StudyContext, evaluate_design
    from dmf_sim.design.study import study_from_dict
    from dmf_sim.design.table import to_table
    study = study_from_dict(_study_doc(), 'study.yaml')
    assert [st.label for st in study.load_steps] == ['step:1200:0:1:0.1:0.5:0.5 A',
                                                     'step:1600:0:-1:0.1:0.5:0.5 A']
    ctx = StudyContext.from_study(study)
    rows = []
    for i, row in enumerate(study.designs()):
        rows += evaluate_design(ctx, i, row)
    summ = [r for r in rows if r['kind'] == 'design']
    assert all(r['status'] == 'ok' for r in summ), summ
    soft, stiff = summ
    for r in summ:
        assert r['transient_windup'] > 0.27 and r['transient_stop_contacts'] == 0
        assert r['transient_travel_margin'] is None         # no stops: no margin
        assert r['transient_dmf_torque_condition'] == 'step:1200:0:1:0.1:0.5:0.5 A'
        assert 0 < r['transient_seconds'] < 5.0
    # the stiffer second stage stops the tip-in sooner, with a higher DMF torque
    assert stiff['transient_windup'] < soft['transient_windup']
    assert stiff['transient_dmf_torque'] > soft['transient_dmf_torque']
    table = to_table(rows, study.variable_names).to_pylist()
    assert [r['transient_dmf_torque'] for r in table if r['kind'] == 'design'] == \
        [r['transient_dmf_torque'] for r in summ]
    assert 'load_steps' in study.as_dict()['conditions']
    # the CSV table leaves it empty, as doc/commands/design-study.md says (it wrote 'nan')
    from dmf_sim.core.csv_out import write_csv
    with write_csv(tmp_path / 't.csv', list(table[0]), table).open() as f:
        csv_rows = [r for r in csv.DictReader(f) if r['kind'] == 'design']
    assert [r['transient_travel_margin'] for r in csv_rows] == ['', '']


@pytest.mark.parametrize('change, needle', [
    (lambda d: d['conditions'].pop('load_steps'),
     "field 'objectives[0]' 'transient_dmf_torque' is measured in load steps: give "
     'conditions.load_steps'),
    (lambda d: d['conditions']['load_steps'][0].update(rise_s=5e-5),
     "field 'conditions.load_steps[0].rise_s' a load change faster than one Newmark step "
     '(0.0001 s), got 5e-05'),
    (lambda d: d['conditions']['load_steps'][0].update(to=2),
     "conditions.load_steps[0]: field 'to' must be in [-1, 1], got 2"),
    (lambda d: d['conditions']['load_steps'][0].update(speed_rpm=2500),
     "field 'conditions.load_steps[0].speed_rpm' outside the engine data (400..2200 rpm)"),
    (lambda d: d.update(engine='engine_table_example.csv'),
     'conditions.load_steps[1].to -1 outside [0, 1]'),
    (lambda d: d['conditions']['load_steps'][0].update(gear=3),
     'gear'),
])
def test_bad_load_steps_are_one_line(change, needle):
    from dmf_sim.design.study import study_from_dict
    d = _study_doc()
    change(d)
    with pytest.raises(ConfigError) as exc:
        study_from_dict(copy.deepcopy(d), 'study.yaml')
    msg = str(exc.value)
    assert '\n' not in msg and needle in msg, msg


# ---- the output rate is no part of the physics -------------------------------------------------
def _windup_at_samples(spec: str, rate_hz: float) -> tuple[np.ndarray, np.ndarray, int]:
    """(times [s], wind-ups [rad]) of the samples of ``spec`` at ``rate_hz``, knee crossings."""
    from dmf_sim.transient.run import build_simulation, follow_profile
    profile = read_profile(spec)
    sim = build_simulation(profile, RunOptions(rate_hz=rate_hz, write=False, sensors=False))
    t, w = [], []
    follow_profile(sim, profile, on_samples=lambda s: (t.append(s.t.copy()),
                                                       w.append(s.windup.copy())))
    return np.concatenate(t), np.concatenate(w), sim.knee_crossings


def test_the_sample_rate_does_not_change_the_integration():
    """A 0 -> 1 tip-in in 0.1 s sampled at 1 kHz and at 20 Hz: the load follows the profile
    step by step whatever the rate, so the wind-up at the 20 Hz samples is the 1 kHz run's at
    those times (to 1e-9 rad: round-off) and the knee crossings are the same. Held per 50 ms
    sample (before), the load entered in two stairs: the wind-ups differed by up to ~0.03 rad
    and the crossings were 98 against 72."""
    spec = 'step:1200:0:1:0.1:0.5:0.2'
    t_fine, w_fine, knees_fine = _windup_at_samples(spec, 1000.0)
    t_coarse, w_coarse, knees_coarse = _windup_at_samples(spec, 20.0)
    at = np.searchsorted(t_fine, t_coarse - 1e-9)
    assert np.allclose(t_fine[at], t_coarse, rtol=0, atol=1e-9)
    assert np.max(np.abs(w_fine[at] - w_coarse)) < 1e-9
    assert knees_coarse == knees_fine > 0


def test_the_run_summary_peaks_leave_out_the_settling(tmp_path, capsys):
    """A run at constant full load from static equilibrium: the first swing (0.28 rad at 0.011
    s) is the start from static equilibrium, not running; the summary reported it as the peak,
    above a tip-in to the same load (0.273 rad). The peaks are now those of the samples after
    the profile's settling, the same as the bag's, and the text says so."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    prof = tmp_path / 'const.csv'
    prof.write_text('time_s,speed_rpm,load\n0,1200,1\n5,1200,1\n')
    bag = tmp_path / 'bag'
    summary = run_profile(read_profile(str(prof)), bag, RunOptions(sensors=False))
    assert summary.peaks_after_s == DEFAULT_SETTLE_S
    store = get_typestore(Stores.ROS2_JAZZY)
    t, w = [], []
    with AnyReader([bag], default_typestore=store) as reader:
        conns = [c for c in reader.connections if c.topic == '/driveline/dmf_windup']
        for conn, stamp, raw in reader.messages(connections=conns):
            t.append(stamp)
            w.append(store.deserialize_cdr(raw, conn.msgtype).data)
    t = (np.array(t) - t[0]) * 1e-9 + 1e-3
    w = np.array(w)
    after = w[t >= DEFAULT_SETTLE_S]
    lo, hi = summary.peak_windup_rad          # over every Newmark step: beyond the samples'
    swing = after.max() - after.min()
    assert lo <= after.min() and hi >= after.max()
    assert after.min() - lo < 0.02 * swing and hi - after.max() < 0.02 * swing
    assert w.max() > hi + 0.01                                # the start's swing, left out
    capsys.readouterr()
    assert cli_main(['run', str(prof), '--no-write', '--no-progress', '--no-sensors']) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert f'peak wind-up {lo:.4f} .. {hi:.4f} rad' in line
    assert line.endswith('(after the first 2 s: the settling from static equilibrium)')


def test_a_design_load_step_leaves_out_the_settling_as_the_run_does():
    """A tip-out from full load (1 -> 0.8 at 1200 rpm) started from static equilibrium at full
    load: the first swing (0.279 rad, 4.10 kNm at 0.012 s) is the start, not the step. A
    design's load step reported it as the step's peak (transient_windup, transient_dmf_torque),
    while ``dmf-sim run`` of the same profile leaves the settling out (0.252 rad, 3.07 kNm). The
    design's peaks are now the run's (the same samples: equal to round-off), and the friction
    heat, like the run's, is the whole profile's."""
    from dmf_sim.design.transient import LoadStep, step_metrics
    from dmf_sim.physics.model import read_driveline
    step = LoadStep(speed_rpm=1200.0, from_load=1.0, to_load=0.8, rise_s=1.0, hold_s=0.5)
    spec = 'step:1200:1:0.8:1:0.5'
    assert step.label == f'{spec} A'
    design = step_metrics(read_driveline('truck_dmf_friction'), dmf.read_engine('engine_d13'),
                          step)
    run = _run(spec, driveline='truck_dmf_friction', sensors=False)
    assert run.peaks_after_s == DEFAULT_SETTLE_S and run.peak_windup_rad[1] < 0.26
    for key in ('peak_windup_rad', 'peak_dmf_torque_nm', 'travel_margin_rad'):
        assert design[key] == pytest.approx(getattr(run, key), rel=1e-9, abs=1e-12), key
    assert design['friction_heat_j'] == pytest.approx(run.friction_heat_j, rel=1e-9)
    assert design['stop_contacts'] == run.stop_contacts


def test_the_run_summary_peaks_do_not_depend_on_the_output_rate(capsys):
    """The summary's peak wind-up, DMF torque and travel margin are the kernel's extremes over
    every Newmark step after the settling, not those of the published samples: at 2 Hz the
    samples saw -0.0002 rad of a 0.27 rad tip-in, and at 100 Hz the margin was positive while
    the stop was hit. Now 1 kHz and 2 Hz give the same figures (the integration is the same),
    and the margin is negative exactly when the stops were hit."""
    out = {}
    for rate in ('1000', '2'):
        assert cli_main(['run', 'step:1200:0:1:0.1:0.5:0.5', '--config', 'truck_dmf_friction',
                         '--rate', rate, '--no-write', '--json', '--no-progress',
                         '--no-sensors']) == 0
        out[rate] = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    a, b = out['1000'], out['2']
    assert a['peak_windup_rad'][1] > 0.25
    for key in ('peak_windup_rad', 'peak_dmf_torque_nm'):
        assert b[key] == pytest.approx(a[key], rel=1e-9, abs=1e-9), key
    assert b['travel_margin_rad'] == pytest.approx(a['travel_margin_rad'], abs=1e-9)
    assert (a['travel_margin_rad'] < 0) == (a['stop_contacts'] > 0)
