"""Parts of the design studies: parameters -> spring, sampling, the torque read-out at an element,
merging repeated states, speed ranges, the Pareto front."""
from __future__ import annotations

import numpy as np
import pytest

from dmf_sim.core.errors import ConfigError
from dmf_sim.design.metrics import design_summary, first_max, speed_ranges
from dmf_sim.design.parameters import check_parameter_set, design_driveline, parse_parameter
from dmf_sim.design.pareto import compromise, pareto_mask
from dmf_sim.design.sampling import VariableRange, grid, latin_hypercube, uniform_random
from dmf_sim.design.states import _distinct, order_torques
from dmf_sim.physics.engine import read_engine
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.model import read_driveline
from dmf_sim.physics.orders import ORDER_3
from dmf_sim.physics.spring import Stage
from dmf_sim.solvers.hbm import SweepOptions, sweep


def test_parameters_build_the_design_spring():
    base = read_driveline('truck_dmf')
    params = {parse_parameter(n, 'test'): v for n, v in {
        'theta': 0.2, 'alpha': 2.0, 'stages[1].angle_rad': 0.3, 'stages[1].stiffness_factor': 5.0,
        'coast_stages[0].angle_rad': 0.1, 'coast_stages[0].stiffness_factor': 1.5,
        'k': 9000.0, 'damping': 30.0}.items()}
    check_parameter_set(list(params), base, 'test')
    line = design_driveline(base, params)
    sp = line.spring
    assert sp.k == 9000.0 and line.dmf_element.damping == 30.0
    assert sp.drive == (Stage(0.2, 2.0), Stage(0.3, 5.0)) and sp.coast == (Stage(0.1, 1.5),)
    # torque law: beyond the second knee the stiffness is k (1 + 5)
    w = np.array([0.35, 0.36])
    assert np.diff(sp.torque(w))[0] == pytest.approx(9000.0 * 6.0 * 0.01)
    # untouched parameters keep the base values
    only = design_driveline(base, {parse_parameter('alpha', 't'): 4.0})
    assert only.spring.drive == (Stage(base.spring.theta, 4.0),)
    assert only.dmf_element == base.dmf_element


def test_parameter_names_checked():
    base = read_driveline('truck_dmf')
    with pytest.raises(ConfigError, match='same quantity'):
        check_parameter_set([parse_parameter('theta', 't'),
                             parse_parameter('stages[0].angle_rad', 't')], base, 't')
    with pytest.raises(ConfigError, match='unknown design parameter'):
        parse_parameter('stages[0].angle', 't')
    with pytest.raises(ConfigError, match=r"'damping' must be in \[0, 1e\+06\] Nms/rad, got -1"):
        parse_parameter('damping', 't').check_value(-1.0, 't')
    # stage angles out of order: that one design is invalid, with the spring's own message
    with pytest.raises(ConfigError, match=r'stages\[1\]\.angle_rad'):
        design_driveline(base, {parse_parameter('theta', 't'): 0.3,
                                parse_parameter('stages[1].angle_rad', 't'): 0.25,
                                parse_parameter('stages[1].stiffness_factor', 't'): 5.0})


def test_sampling():
    r = [VariableRange('a', 1.0, 2.0), VariableRange('b', 0.0, 10.0, (0.0, 5.0, 10.0))]
    g = grid(r, [3, 3])
    assert g.shape == (9, 2) and set(g[:, 1]) == {0.0, 5.0, 10.0}
    assert list(g[:3, 0]) == [1.0, 1.0, 1.0]           # last variable fastest
    n = 20
    lhs = latin_hypercube(r, n, seed=4)
    assert np.array_equal(lhs, latin_hypercube(r, n, seed=4))        # resumable: same designs
    for j, (lo, hi) in enumerate(((1.0, 2.0), (0.0, 10.0))):      # one sample per stratum
        strata = np.floor((lhs[:, j] - lo) / (hi - lo) * n).astype(int)
        assert sorted(strata) == list(range(n))
    u = uniform_random(r, 50, seed=1)
    assert (u[:, 0] >= 1.0).all() and (u[:, 0] <= 2.0).all() and len(np.unique(u[:, 1])) == 50


@pytest.fixture(scope='module')
def knee_sweep():
    eng = read_engine('engine_d13', load_set='A')
    line = read_driveline('truck_dmf').with_dmf(alpha=3.0, theta=0.2)
    return line, sweep(DrivelineExcitation(line.reduce(), eng), 1.0, (900.0, 1100.0),
                       options=SweepOptions(step_rpm=10.0))


@pytest.mark.parametrize('element', ['INPUT SHAFT', 'SECONDARY FLYWHEEL', 'HUB', 'CYL3', 'DIFF'])
def test_order_torques_equal_whole_chain_recovery(knee_sweep, element):
    """Batched 3rd-order torque into an element (flexible, the DMF itself, rigid links, a
    cylinder) = CondensedHBM.torque_harmonics, on both branches (the knee is crossed)."""
    line, res = knee_sweep
    pts = [p for b in res.branches for p in b.points][::4]
    assert len(res.branches) >= 2
    i = line.index(element)
    got = order_torques(res.hbm, pts, i)
    want = np.array([res.hbm.torque_harmonics(p)[ORDER_3, i] for p in pts])
    assert np.max(np.abs(got - want)) <= 1e-9 * np.abs(want).max()


def test_repeated_states_are_merged():
    gi = np.array([0, 0, 0, 1, 1])
    stable = np.array([True, True, True, True, False])
    v = np.array([[0.010, 0.002, 0.25, 0.012, -0.011],
                  [0.010, 0.002, 0.25, 0.0121, -0.011],      # the same state again
                  [0.010, 0.015, 0.25, 0.020, -0.020],      # a 1.5th-order state
                  [0.010, 0.002, 0.25, 0.012, -0.011],
                  [0.010, 0.002, 0.25, 0.012, -0.011]])     # unstable: kept apart
    assert list(_distinct(gi, stable, v)) == [0, 2, 3, 4]


def test_speed_ranges_and_pareto():
    speeds = np.array([900.0, 910, 920, 1000, 1020, 1030])
    assert speed_ranges(speeds, 10.0) == '900-920, 1000, 1020-1030'
    assert speed_ranges(np.array([]), 10.0) == ''
    f1 = np.array([1.0, 2.0, 4.0, 2.0, np.nan, 1.0])
    f2 = np.array([4.0, 2.0, 1.0, 3.0, 0.0, 4.0])      # NaN: never on the front
    mask = pareto_mask(f1, f2)
    assert list(mask) == [True, True, True, False, False, True]
    assert compromise((f1, f2), mask) == 1


@pytest.mark.slow
def test_non_periodic_speeds_count_in_the_worst_values(tmp_path):
    """Where no periodic state is stable (the pure-3rd-order table at 600-640 rpm, alpha 2.5: a
    torus instability) the study reports the speeds as non-periodic and takes the worst values
    from the time-integration envelope there, not from the unstable periodic solution."""
    from dmf_sim.design.evaluate import SolverSettings, solve_condition
    from dmf_sim.design.metrics import condition_metrics
    rows = ['speed_rpm,n,re,im']
    for s in range(600, 1201, 20):
        for n in range(25):
            re = 2650 / 6 if n == 0 else (2500 / 6 if n == 6 else 0.0)
            rows.append(f'{s},{n},{re!r},0.0')
    table = tmp_path / 'pure3.csv'
    table.write_text('\n'.join(rows) + '\n')
    line = read_driveline('truck_dmf', alpha=2.5)
    engine = read_engine(table)
    settings = SolverSettings((600.0, 640.0, 20.0), 24, True, line.index('INPUT SHAFT'))
    states = solve_condition(line, engine, 1.0, settings)
    m = condition_metrics(states, line.spring, 20.0)
    res = sweep(DrivelineExcitation(line.reduce(), engine), 1.0, (600.0, 640.0),
                options=SweepOptions(step_rpm=20.0))
    envelope = [r for band in res.non_periodic for r in band.results if r.speed_rpm == 620.0]
    assert envelope and m['rpm_nonperiodic'] >= 20.0 and m['speeds_nonperiodic']
    assert m['max_windup'] >= envelope[0].mean + envelope[0].max_deviation - 1e-12
    assert m['worst_order_1_5'] >= envelope[0].order_1_5


def test_worst_condition_and_speed_do_not_hang_on_the_last_bit():
    """Two load sets with the same worst value but for the last bits (as a Dask worker
    and this process computed them) named either condition; the first within TIE_REL is named."""
    hi, lo = 0.003220760291894178, 0.00322076029189417      # the field report's two values

    def row(cond, v):
        return {'condition': cond, **{n: v for n in ('worst_order_1_5', 'worst_order_3',
                                                     'worst_torque_3', 'max_dmf_torque')},
                **{f'{n}_rpm': 1000.0 for n in ('worst_order_1_5', 'worst_order_3',
                                                'worst_torque_3', 'max_dmf_torque',
                                                'max_stable_states')},
                'max_stable_states': 1, 'max_windup': 0.1, 'rpm_1_5': 0.0,
                'rpm_nonperiodic': 0.0, 'speeds_1_5': '', 'speeds_nonperiodic': '',
                'n_branches': 1}
    for a, b in ((lo, hi), (hi, lo)):
        s = design_summary([row('A 1', a), row('B 1', b)])
        assert s['worst_torque_3_condition'] == 'A 1' and s['worst_order_1_5'] in (a, b)
    assert design_summary([row('A 1', 1.0), row('B 1', 1.001)])['worst_torque_3_condition'] \
        == 'B 1'                                                  # a real difference still wins
    assert first_max(np.array([np.nan, 2.0, 2.0 * (1 + 1e-12), 1.0])) == 1
    assert first_max(np.array([np.nan, np.nan])) == 0


def test_study_plugin_limits_the_worker_thread_pools():
    """A design-study worker computes one design at a time: its plugin limits the BLAS / OpenMP
    pools to WORKER_THREADS (here from 2, as a worker started without Dask's nanny may have)."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from dmf_sim.cluster import WORKER_THREADS
    from dmf_sim.design import read_study
    from dmf_sim.design.evaluate import StudyContext, drop_context
    from dmf_sim.design.runner import StudyPlugin
    study = read_study({'name': 'threads', 'driveline': 'truck_dmf', 'engine': 'engine_d13',
                        'sampling': {'method': 'grid'},
                        'variables': {'alpha': {'values': [3.0]}},
                        'conditions': {'load_sets': ['A'], 'loads': [1.0],
                                       'speeds_rpm': {'from': 900, 'to': 1000, 'step': 10}},
                        'objectives': ['worst_order_1_5', 'worst_torque_3']})
    plugin = StudyPlugin('test-threads', StudyContext.from_study(study))
    with threadpool_limits(limits=2):
        pools = threadpool_info()
        plugin.setup(None)
        after = threadpool_info()
    drop_context('test-threads')
    assert pools and all(p['num_threads'] == WORKER_THREADS for p in after)


def test_the_lock_file_lives_only_while_a_run_holds_it(tmp_path, monkeypatch):
    """design / optimize left an empty .lock in --out, after success and after an error."""
    from dmf_sim.design import read_study, run_study
    from dmf_sim.design.table import LOCK_FILE, ResultStore
    study = read_study({'name': 'lock', 'driveline': 'truck_dmf', 'engine': 'engine_d13',
                        'sampling': {'method': 'grid'},
                        'variables': {'alpha': {'values': [2.0, 3.0]}},
                        'conditions': {'load_sets': ['A'], 'loads': [1.0],
                                       'speeds_rpm': {'from': 900, 'to': 1000, 'step': 50}},
                        'objectives': ['worst_order_1_5', 'worst_torque_3']})
    out = tmp_path / 'out'
    first, second = ResultStore(out, study), ResultStore(out, study)
    first.lock()
    assert (out / LOCK_FILE).exists()
    with pytest.raises(ConfigError, match='another study run is using'):
        second.lock()
    second.close()                          # a refused run leaves the holder's lock alone
    assert (out / LOCK_FILE).exists()
    first.close()
    assert not (out / LOCK_FILE).exists()
    second.lock()                           # free again
    second.close()

    def lost(client):
        raise RuntimeError('the cluster went away')
    monkeypatch.setattr('dmf_sim.design.runner.wait_for_workers', lost)
    with pytest.raises(RuntimeError, match='went away'):
        run_study(study, client=object(), out=tmp_path / 'failed')
    assert (tmp_path / 'failed').is_dir() and not (tmp_path / 'failed' / LOCK_FILE).exists()
