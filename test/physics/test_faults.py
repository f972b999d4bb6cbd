"""Faults: the grammar and its validation (every bad input one line naming the fault and the
field), schedules, what a fault set does to the combustion and the DMF, the ground-truth
timeline (which combustions misfire, reproducibly), and the faulted excitation."""
from __future__ import annotations

import math

import numpy as np
import pytest

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.physics.faults import (
    CYCLE_RAD,
    WINDOW_OPEN_RAD,
    Fault,
    FaultSet,
    FaultTimeline,
    event_from_values,
    parse_fault,
    parse_faults,
    parse_request,
    read_schedule,
)
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.model import read_driveline


@pytest.fixture(scope='module')
def line():
    return read_driveline('truck_dmf')


def _one_line(exc: pytest.ExceptionInfo) -> str:
    text = str(exc.value)
    assert '\n' not in text
    return text


# ---- the grammar ---------------------------------------------------------------------------

GOOD = [
    '{kind: misfire, cylinders: [3], mode: single}',
    '{kind: misfire, cylinders: [3], mode: single, at_s: 2.5}',
    '{kind: misfire, cylinders: [1, 4], mode: every_cycle, start_s: 1, end_s: 3}',
    '{kind: misfire, cylinders: [2], mode: random, probability: 0.1, seed: 7}',
    '{kind: misfire, cylinders: [2], mode: random, rate_per_s: 2.0, duration_s: 5}',
    '{kind: weak_cylinder, cylinder: 5, factor: 0.7}',
    '{kind: dmf_stiffness, stage: 1, factor: 0.8}',
    '{kind: dmf_stiffness, stage: 2, factor: 0.5}',
    '{kind: dmf_broken, stage: 2}',
    '{kind: dmf_damping, factor: 3}',
    '{kind: sensor_edges, sensor: crank, mode: missing, probability: 0.01}',
    '{kind: sensor_edges, sensor: crank, mode: missing, tooth: 17}',
    '{kind: sensor_edges, sensor: crank, mode: extra, rate_per_s: 5}',
    '{kind: bus_signal, signal: engine_speed, mode: stuck, start_s: 1}',
    '{kind: bus_signal, signal: engine_speed, mode: noisy, sigma_rpm: 20}',
]


@pytest.mark.parametrize('text', GOOD)
def test_good_faults_read_back_equal(text, line):
    f = parse_fault(text, line=line, wheels={'crank': 58}, signals={'engine_speed'})
    assert isinstance(f, Fault)
    # the canonical text is the same grammar: parsing it again gives the same fault
    assert parse_fault(f.text(), line=line) == f
    assert parse_fault(f.mapping()) == f


BAD = [   # (request, the words the one line must hold)
    ('{kind: misfire, cylinders: [7]}', ["'cylinders[0]'", '1..6', '7']),
    ('{kind: misfire, cylinders: [0]}', ["'cylinders[0]'", '1..6']),
    ('{kind: misfire, cylinders: []}', ["'cylinders'"]),
    ('{kind: misfire, cylinders: [2, 2]}', ["'cylinders'", 'twice']),
    ('{kind: weak_cylinder, cylinder: 7, factor: 0.5}', ["'cylinder'", '1..6']),
    ('{kind: weak_cylinder, cylinder: 2, factor: .nan}', ["'factor'", 'nan']),
    ('{kind: weak_cylinder, cylinder: 2, factor: 1.0}', ["'factor'", '[0, 1)']),
    ('{kind: misfire, cylinders: [1], mode: every_cycle, start_s: .nan}', ["'start_s'", 'nan']),
    ('{kind: misfire, cylinders: [1], mode: random, probability: .nan}', ["'probability'"]),
    ('{kind: misfire, cylinders: [1], mode: random}', ["'probability'", 'rate_per_s']),
    ('{kind: misfire, cylinders: [1], mode: sometimes}', ["'mode'", 'every_cycle']),
    ('{kind: misfire, cylinders: [1], colour: red}', ["unknown key 'colour'"]),
    ('{kind: misfire, cylinders: [1], end_s: 3}', ["'end_s'", 'single']),
    ('{kind: misfire, cylinders: [1], mode: every_cycle, start_s: 3, end_s: 2}',
     ["'end_s'", 'inverted']),
    ('{kind: misfire, cylinders: [1], mode: every_cycle, end_s: 2, duration_s: 1}',
     ["'duration_s'"]),
    ('{kind: dmf_stiffness, stage: 3, factor: 0.5}', ["'stage'", '3 does not exist', '1, 2']),
    ('{kind: dmf_stiffness, stage: coast_1, factor: 0.5}', ["'stage'", 'coast_1 does not']),
    ('{kind: dmf_stiffness, stage: 2, factor: 0}', ["'factor'", '(0, 1]']),
    ('{kind: dmf_stiffness, stage: 1, factor: 0.01}', ["'factor'", 'no valid spring']),
    ('{kind: dmf_broken, stage: 1}', ["'stage'", 'primary']),
    ('{kind: dmf_damping, factor: -1}', ["'factor'", '[0, 100]']),
    ('{kind: dmf_damping, factor: .inf}', ["'factor'"]),
    ('{kind: sensor_edges, sensor: cam, mode: missing, probability: 0.1}',
     ["'sensor'", 'crank']),
    ('{kind: sensor_edges, sensor: crank, mode: missing, tooth: 58}', ["'tooth'", '0..57']),
    ('{kind: sensor_edges, sensor: crank, mode: extra}', ["'rate_per_s'"]),
    ('{kind: bus_signal, signal: oil_temp, mode: stuck}', ["'signal'", 'engine_speed']),
    ('{kind: bus_signal, signal: engine_speed, mode: noisy}', ["'sigma_rpm'"]),
    ('{kind: gremlin}', ["'kind'", 'misfire']),
    ('{cylinders: [1]}', ["missing key 'kind'"]),
    ('[1, 2', ['invalid YAML']),
    ('42', ['must be a mapping']),
]


@pytest.mark.parametrize('text,words', BAD)
def test_bad_faults_one_line_naming_the_field(text, words, line):
    with pytest.raises(ConfigError) as exc:
        parse_fault(text, 'request', line=line, wheels={'crank': 58}, signals={'engine_speed'})
    msg = _one_line(exc)
    assert msg.startswith('request')
    for w in words:
        assert w in msg, (w, msg)


def test_sensor_names_checked_against_the_driveline_s_sensors(line):
    """The shipped truck has sensors (its YAML's sensors section): an unknown wheel is refused
    in one line naming the known ones, a known one's tooth within the teeth present; without a
    driveline, names are not checked."""
    text = '{kind: sensor_edges, sensor: anything, mode: missing, probability: 0.1}'
    with pytest.raises(ConfigError, match='known: crank, flywheel_secondary'):
        parse_fault(text, line=line)
    parse_fault(text)
    parse_fault('{kind: sensor_edges, sensor: crank, mode: missing, tooth: 57}', line=line)
    with pytest.raises(ConfigError, match=r"'tooth' must be in 0\.\.57"):
        parse_fault('{kind: sensor_edges, sensor: crank, mode: missing, tooth: 58}', line=line)


def test_no_dmf_refused_for_dmf_faults():
    conv = read_driveline('truck_conventional')
    for text in ('{kind: dmf_damping, factor: 2}', '{kind: dmf_stiffness, stage: 1, factor: 1}'):
        with pytest.raises(ConfigError, match='has none'):
            parse_fault(text, line=conv)


def test_parameter_kind_implied_and_restricted(line):
    f = parse_fault('{cylinders: [2], mode: every_cycle}', kinds=('misfire',), line=line)
    assert f.kind == 'misfire'
    with pytest.raises(ConfigError, match="'kind'"):
        parse_fault('{kind: weak_cylinder, cylinder: 1, factor: 0.5}',
                    kinds=('dmf_stiffness', 'dmf_broken', 'dmf_damping'))


def test_overlapping_windows_refused_naming_both(line):
    with pytest.raises(ConfigError) as exc:
        parse_faults('[{kind: misfire, cylinders: [1], mode: every_cycle, start_s: 1, end_s: 3},'
                     ' {kind: misfire, cylinders: [2, 1], mode: random, probability: 0.5, '
                     'start_s: 2}]', line=line)
    msg = _one_line(exc)
    assert 'faults[1] (misfire)' in msg and 'faults[0]' in msg and 'cylinder 1' in msg
    # a single misfire inside an every-cycle window of its cylinder overlaps too
    with pytest.raises(ConfigError, match='cylinder 1'):
        parse_faults('[{kind: misfire, cylinders: [1], mode: every_cycle, start_s: 1, end_s: 3},'
                     ' {kind: misfire, cylinders: [1], at_s: 2}]')
    with pytest.raises(ConfigError, match='stage 2'):
        parse_faults('[{kind: dmf_stiffness, stage: 2, factor: 0.5}, '
                     '{kind: dmf_broken, stage: 2, start_s: 10}]', line=line)
    # touching windows, other targets, two singles: fine
    faults = parse_faults(
        '[{kind: misfire, cylinders: [1], mode: every_cycle, start_s: 1, end_s: 3},'
        ' {kind: misfire, cylinders: [1], mode: every_cycle, start_s: 3},'
        ' {kind: misfire, cylinders: [2], at_s: 2}, {kind: misfire, cylinders: [2], at_s: 2},'
        ' {kind: weak_cylinder, cylinder: 1, factor: 0.5}]', line=line)
    assert len(faults) == 5


def test_request_one_or_several(line):
    assert len(parse_request('{kind: misfire, cylinders: [3]}', line=line)) == 1
    assert len(parse_request('[{kind: misfire, cylinders: [3]}, {kind: dmf_damping, '
                             'factor: 2}]', line=line)) == 2
    assert parse_request('', line=line) == ()
    with pytest.raises(ConfigError, match=r'request\[1\] \(misfire\)'):
        parse_request('[{kind: misfire, cylinders: [3]}, {kind: misfire, cylinders: [9]}]',
                      'request', line=line)


def test_schedule_file(tmp_path, line):
    path = tmp_path / 'faults.yaml'
    path.write_text('description: a test\nfaults:\n'
                    '  - {kind: misfire, cylinders: [3], at_s: 1.0}\n'
                    '  - {kind: weak_cylinder, cylinder: 2, factor: 0.5, start_s: 2}\n')
    sched = read_schedule(path, line=line)
    assert [f.kind for f in sched.faults] == ['misfire', 'weak_cylinder']
    path.write_text('faults:\n  - {kind: misfire, cylinders: [3], at_s: 1.0}\n'
                    '  - {kind: misfire, cylinders: [7], mode: every_cycle}\n')
    with pytest.raises(ConfigError) as exc:
        read_schedule(path, line=line)
    assert str(path) in _one_line(exc) and 'faults[1] (misfire)' in str(exc.value)
    path.write_text('faults:\n  - {kind: misfire, cylinders: [1], mode: every_cycle, '
                    'start_s: 5, end_s: 4}\n')
    with pytest.raises(ConfigError, match=r"faults\[0\] \(misfire\): field 'end_s'"):
        read_schedule(path, line=line)
    path.write_text('fault: []\n')
    with pytest.raises(ConfigError, match="missing key 'faults'"):
        read_schedule(path, line=line)


# ---- what a fault set does -------------------------------------------------------------------

def test_combustion_factors_persistent_only(line):
    fs = FaultSet(parse_faults(
        '[{kind: misfire, cylinders: [4], mode: every_cycle}, {kind: misfire, cylinders: [1]},'
        ' {kind: misfire, cylinders: [6], mode: random, probability: 0.5},'
        ' {kind: weak_cylinder, cylinder: 2, factor: 0.6}, {kind: dmf_damping, factor: 2}]',
        line=line))
    np.testing.assert_array_equal(fs.combustion_factors(6), [1, 0.6, 1, 0, 1, 1])
    assert [f.kind for f in fs.persistent] == ['misfire', 'weak_cylinder', 'dmf_damping']


def test_dmf_faults_through_the_spring(line):
    spring, k = line.spring, line.spring.k
    # the stage's increment [Nm/rad] halved: stage stiffness k + 0.5 alpha k
    worn = FaultSet(parse_faults('{kind: dmf_stiffness, stage: 2, factor: 0.5}')).\
        apply_to_driveline(line)
    assert worn.spring.k == k and worn.spring.alpha == pytest.approx(0.5 * spring.alpha)
    # the primary spring worn: k halved, the stage's increment (alpha k) kept
    prim = FaultSet(parse_faults('{kind: dmf_stiffness, stage: 1, factor: 0.5}')).\
        apply_to_driveline(line)
    assert prim.spring.k == 0.5 * k
    assert prim.spring.stiffness(0.3) == pytest.approx(0.5 * k + spring.alpha * k)
    assert prim.elements[prim.index('SECONDARY FLYWHEEL')].stiffness == 0.5 * k
    broken = FaultSet(parse_faults('{kind: dmf_broken, stage: 2}')).apply_to_driveline(line)
    assert broken.spring.is_linear and broken.spring.k == k
    damped = FaultSet(parse_faults('{kind: dmf_damping, factor: 4}')).apply_to_driveline(line)
    assert damped.dmf_element.damping == 4 * line.dmf_element.damping
    assert damped.spring == spring
    assert FaultSet().apply_to_driveline(line) is line
    # knees stay where they were
    assert worn.spring.theta == spring.theta


def test_multistage_coast_stage(tmp_path):
    from dmf_sim.physics.spring import Stage
    line = read_driveline('truck_dmf').with_dmf(stages=[Stage(0.2, 1.0), Stage(0.4, 3.0)],
                                                 coast_stages=[Stage(0.1, 2.0)])
    f = parse_fault('{kind: dmf_broken, stage: 2}', line=line)   # drive stage 1: +1 k
    out = FaultSet((f,)).apply_to_driveline(line).spring
    assert [s.stiffness_factor for s in out.drive] == [0.0, 2.0]   # stage 3 keeps its +2 k
    coast = parse_fault('{kind: dmf_stiffness, stage: coast_1, factor: 0.5}', line=line)
    assert FaultSet((coast,)).apply_to_driveline(line).spring.coast[0].stiffness_factor == 1.0
    with pytest.raises(ConfigError, match='coast_2 does not exist'):
        parse_fault('{kind: dmf_broken, stage: coast_2}', line=line)


# ---- the timeline ---------------------------------------------------------------------------

def _scan_run(tl, speed_rpm, t_end, dt=1e-4, chunk=37):
    """As the simulation does it: steps run with the factors in effect before the scan's
    change; returns per-step factors, events."""
    om = speed_rpm * RPM_TO_RAD_S
    n_total = int(round(t_end / dt))
    factors = np.empty((n_total, tl.n_cylinders))
    cur = tl.factors.copy()
    done = 0
    while done < n_total:
        n = min(chunk, n_total - done)
        j = np.arange(done + 1, done + n + 1)
        k, _ = tl.scan(j * dt, j * dt * om)
        factors[done:done + k] = cur
        done += k
        cur = tl.factors.copy()
    return factors, tl.take_events()


def test_single_misfire_takes_one_whole_combustion(line):
    tl = FaultTimeline(line, parse_faults('{kind: misfire, cylinders: [3], at_s: 0.05}'))
    dt, rpm = 1e-4, 1200.0
    factors, events = _scan_run(tl, rpm, 0.4, dt)
    off = np.flatnonzero(factors[:, 2] == 0.0)
    om = rpm * RPM_TO_RAD_S
    # one window of 720 deg, opening 180 deg before cylinder 3's TDC (beta 240 deg), the first
    # after t = 0.05 s: psi = 780 deg
    psi_first = (off[0] + 1) * dt * om          # the crank angle the first faulted step ends at
    open_rad = np.radians(240.0) + WINDOW_OPEN_RAD + CYCLE_RAD
    assert open_rad <= psi_first - om * dt + 1e-9 < open_rad + om * dt
    assert len(off) == pytest.approx(CYCLE_RAD / (om * dt), abs=1)
    assert np.all(np.diff(off) == 1) and np.all(factors[:, [0, 1, 3, 4, 5]] == 1.0)
    kinds = [e.what for e in events]
    assert kinds == ['start', 'misfire', 'end']
    mis = events[1]
    assert (mis.cylinder, mis.combustion) == (3, 1)
    assert mis.tdc_rad == pytest.approx(np.radians(240.0) + CYCLE_RAD)
    assert events[2].t_s - events[0].t_s == pytest.approx(CYCLE_RAD / om, abs=2 * dt)


def test_single_misfires_queue_on_one_cylinder(line):
    tl = FaultTimeline(line, parse_faults('[{kind: misfire, cylinders: [1], at_s: 0.01}, '
                                          '{kind: misfire, cylinders: [1], at_s: 0.01}]'))
    _, events = _scan_run(tl, 1200.0, 0.4)
    mis = [e for e in events if e.what == 'misfire']
    assert [(e.fault_id, e.combustion) for e in mis] == [(1, 1), (2, 2)]


def test_every_cycle_window_and_weak(line):
    tl = FaultTimeline(line, parse_faults(
        '[{kind: misfire, cylinders: [1], mode: every_cycle, start_s: 0.1, end_s: 0.3},'
        ' {kind: weak_cylinder, cylinder: 2, factor: 0.6, start_s: 0.05}]'))
    factors, events = _scan_run(tl, 1200.0, 0.5)
    mis = [e for e in events if e.what == 'misfire']
    # cylinder 1's windows open at -180 + 720 m deg: 0.1 m - 0.025 s; those opening in
    # [0.1, 0.3) misfire: m = 2, 3
    assert [e.combustion for e in mis] == [2, 3]
    assert all(e.cylinder == 1 for e in mis)
    assert set(np.unique(factors[:, 1])) == {0.6, 1.0}
    assert factors[-1, 1] == 0.6 and factors[-1, 0] == 1.0
    assert [e.what for e in events if e.fault_id == 1] == ['start', 'misfire', 'misfire', 'end']


def test_random_misfires_reproducible_whatever_the_chunks(line):
    spec = ('[{kind: misfire, cylinders: [2, 5], mode: random, probability: 0.3, seed: 11},'
            ' {kind: misfire, cylinders: [4], mode: random, rate_per_s: 4, seed: 2}]')
    runs = []
    for chunk in (10, 37, 1000):
        tl = FaultTimeline(line, parse_faults(spec))
        _, events = _scan_run(tl, 1500.0, 3.0, chunk=chunk)
        runs.append([(e.fault_id, e.cylinder, e.combustion) for e in events
                     if e.what == 'misfire'])
    assert runs[0] == runs[1] == runs[2]
    by_prob = [r for r in runs[0] if r[0] == 1]
    by_rate = [r for r in runs[0] if r[0] == 2]
    combustions = 3.0 * 1500 / 120 * 2          # of cylinders 2 and 5 in 3 s
    assert 0.15 * combustions < len(by_prob) < 0.45 * combustions
    assert 4 <= len(by_rate) <= 22                # Poisson, mean 12 in 3 s
    other = FaultTimeline(line, parse_faults(spec.replace('seed: 11', 'seed: 12')))
    _, events = _scan_run(other, 1500.0, 3.0)
    assert [(e.fault_id, e.cylinder, e.combustion) for e in events
            if e.what == 'misfire'] != runs[0]


def test_dmf_switch_and_clear(line):
    tl = FaultTimeline(line, parse_faults('{kind: dmf_damping, factor: 2, start_s: 0.01}'))
    om = 1000 * RPM_TO_RAD_S
    j = np.arange(1, 1001)
    k, changed = tl.scan(j * 1e-4, j * 1e-4 * om)
    assert changed and k == 100 and tl.dmf_version == 1 and len(tl.dmf) == 1
    tl.add(parse_fault('{kind: misfire, cylinders: [2], mode: every_cycle}'), 0.01)
    assert tl.check(parse_fault('{kind: dmf_damping, factor: 3}'), 0.02) is not None
    assert 'overlaps' in tl.check(parse_fault('{kind: misfire, cylinders: [2]}'), 0.02)
    ids = tl.clear(0.02, 1.0)
    assert ids == [1, 2] and tl.dmf_version == 2 and not tl.dmf
    # the misfire was cleared before a step started it: no start, no end
    assert [(e.what, e.fault_id) for e in tl.take_events()] == [('start', 1), ('end', 1)]
    assert tl.idle


def test_event_values_read_back(line):
    tl = FaultTimeline(line, parse_faults('{kind: misfire, cylinders: [3], at_s: 0.05}'))
    _, events = _scan_run(tl, 1200.0, 0.4)
    mis = events[1]
    vals = mis.values(lambda t: int(round(t * 1e9)) + 10)
    back = event_from_values(mis.message(), vals)
    assert back['what'] == 'misfire' and back['id'] == 1 and back['cylinder'] == 3
    assert back['fault'] == mis.fault
    assert back['tdc_crank_angle_rad'] == pytest.approx(mis.tdc_rad)
    assert back['event_ns'] == int(round(mis.t_s * 1e9)) + 10
    assert back['end_ns'] is None
    end = event_from_values(events[2].message(), events[2].values(lambda t: 0))
    assert end['what'] == 'end' and end['end_s'] == pytest.approx(events[2].t_s)


# ---- the faulted excitation ------------------------------------------------------------------

@pytest.fixture(scope='module')
def loads(truck_dmf, engine_d13):
    return DrivelineExcitation(truck_dmf, engine_d13)


def test_motored_cylinder_burns_nothing(engine_d13):
    model = engine_d13.model
    fired0 = model.cycle(1200, 0.0)
    motored = model.cycle(1200, 1.0, fired=False)
    assert fired0.heat_release_j > 1.0              # load 0 still burns a little fuel ...
    assert motored.heat_release_j == 0.0            # ... a misfire burns none
    # compression without combustion: expansion gives back what compression took, minus the
    # pumping loop: a small negative mean; boosted (load 1) more pressure than at load 0
    Am = engine_d13.motored_coefficients(1200, 1.0)
    assert -0.1 * engine_d13.coefficients(1200, 1.0)[0].real < Am[0].real < 0.0
    assert motored.peak_pressure_pa > model.cycle(1200, 0.0, fired=False).peak_pressure_pa
    assert motored.peak_pressure_pa < 0.8 * model.cycle(1200, 1.0).peak_pressure_pa
    # the grid interpolates it like the fired gas part (exact on the grid)
    np.testing.assert_allclose(Am - engine_d13.inertia_coefficients(1200),
                               model.motored_gas_coefficients(1200, 1.0), atol=1e-9)
    assert engine_d13.with_load_set('B').has_motored


def test_faulted_coefficients_formula(loads, engine_d13):
    Af = engine_d13.coefficients(1200, 0.8)
    Am = engine_d13.motored_coefficients(1200, 0.8)
    s = np.array([1.0, 0.0, 1.0, 0.5, 1.0, 1.0])
    B = loads.faulted_cylinder_coefficients(Af, Am, s)
    np.testing.assert_allclose(B[0], loads.cylinder_coefficients_for(Af)[0])
    np.testing.assert_allclose(B[1], Am * loads.phase[1])
    np.testing.assert_allclose(B[3], 0.5 * (Af + Am) * loads.phase[3])
    # K sets at once
    BK = loads.faulted_cylinder_coefficients(np.stack([Af, Am]), np.stack([Am, Am]), s)
    assert BK.shape == (2, 6, Af.size)
    np.testing.assert_allclose(BK[0], B)
    # healthy factors: the healthy path
    np.testing.assert_allclose(loads.faulted_rear_load(Af, Am, np.ones(6)),
                               loads.rear_load_for(Af))
    # the rear load balances the faulted mean: no net torque on a rigid rotation
    P = loads.element_harmonics(1200, 0.8, s)
    assert abs(np.real(P[0]) @ (1 / loads.model.R)) < 1e-9 * abs(Af[0].real)
    # the mean drops by the combustion mean of 1.5 cylinders (one misfiring, one at half)
    drop = loads.mean_engine_torque(1200, 0.8) - np.real(P[0, loads.cylinder_elements]).sum()
    assert drop == pytest.approx(1.5 * (Af[0].real - Am[0].real), rel=1e-9)
    # the static state follows the faulted mean
    assert loads.static_state(1200, 0.8, s).dmf_torque == pytest.approx(
        np.real(P[0, loads.cylinder_elements]).sum(), rel=1e-9)


def test_table_engine_refuses_misfires(truck_dmf):
    from dmf_sim.physics.engine import read_engine
    table = read_engine('engine_table_example.csv')
    L = DrivelineExcitation(truck_dmf, table)
    assert not L.has_motored
    with pytest.raises(ConfigError, match='misfire and weak_cylinder faults need'):
        L.excitation(1200, 1.0, [1, 0, 1, 1, 1, 1])
    B, rear = L.excitation(1200, 1.0, np.ones(6))       # healthy: fine
    assert math.isfinite(rear)


def test_packaged_example_schedule_has_every_kind(line):
    from dmf_sim.physics.faults import FAULT_KINDS
    sched = read_schedule('faults_example', line=line, wheels={'crank': 58},
                          signals={'engine_speed'})
    assert {f.kind for f in sched.faults} == set(FAULT_KINDS)
    assert {f.mode for f in sched.faults if f.kind == 'misfire'} == {'single', 'every_cycle',
                                                                      'random'}


def test_sensor_names_come_from_the_driveline():
    """A driveline that describes its sensors (Driveline.sensors: tooth_wheels, bus_signals)
    checks the names and the tooth index; one that does not leaves them unchecked."""
    from types import SimpleNamespace

    from dmf_sim.physics.faults import known_sensors
    line = read_driveline('truck_dmf')
    sensors = SimpleNamespace(
        tooth_wheels=(SimpleNamespace(name='crank', teeth=60, present_teeth=58),),
        bus_signals=(SimpleNamespace(name='engine_speed'),))
    fake = SimpleNamespace(**{k: getattr(line, k) for k in ('cylinders', 'dmf', 'name')},
                           sensors=sensors)
    assert known_sensors(fake) == ({'crank': 58}, {'engine_speed'})
    with pytest.raises(ConfigError, match="'tooth'.*0..57"):
        parse_fault('{kind: sensor_edges, sensor: crank, mode: missing, tooth: 58}', line=fake)
    with pytest.raises(ConfigError, match="'signal'"):
        parse_fault('{kind: bus_signal, signal: oil, mode: stuck}', line=fake)
    parse_fault('{kind: bus_signal, signal: engine_speed, mode: stuck}', line=fake)
    if getattr(line, 'sensors', None) is None:
        assert known_sensors(line) == (None, None)
