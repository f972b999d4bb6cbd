"""dmf-sim optimize: the optimizer improves on its own first generation, resumes
without recomputing finished designs, ranks infeasible designs after feasible ones and records
failing designs as rows; stage angles are ascending by construction; the constraints are the
spring's physics; HBM worst values agree with the time domain; bad study files are one line."""
from __future__ import annotations

import copy
import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from dmf_sim.cli import main as cli_main
from dmf_sim.cluster import local_cluster
from dmf_sim.core.errors import ConfigError
from dmf_sim.design.parameters import design_driveline
from dmf_sim.design.pareto import pareto_mask
from dmf_sim.design.table import LOCK_FILE
from dmf_sim.optimize import read_problem, run_optimization
from dmf_sim.optimize.constraints import rank
from dmf_sim.optimize.hypervolume import hypervolume, hypervolume_history
from dmf_sim.optimize.runner import finish

pytestmark = pytest.mark.slow     # optimizations on a local Dask cluster: its start and workers

REPO = Path(__file__).resolve().parents[2]


def _quick_study() -> dict:
    """The benchmark's cheap problem (5 variables with the friction torque, one condition, 9
    speeds, 8 half orders, one load step, 4 s of the road cycle, three objectives)."""
    spec = importlib.util.spec_from_file_location('bench_optimize',
                                                  REPO / 'benchmarks' / 'bench_optimize.py')
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.QUICK_STUDY


PROBLEM = copy.deepcopy(_quick_study())
PROBLEM['name'] = 'test_optimize'
PROBLEM['optimizer'].update(budget=12, seed=3)        # three generations of four


def _problem(**opt):
    d = copy.deepcopy(PROBLEM)
    d['optimizer'].update(opt)
    return d


@pytest.fixture(scope='module')
def client():
    from distributed import Client
    with local_cluster(2) as cluster, Client(cluster) as c:
        c.wait_for_workers(2)
        yield c


@pytest.fixture(scope='module')
def problem():
    return read_problem(PROBLEM)


@pytest.fixture(scope='module')
def run(client, problem, tmp_path_factory):
    out = tmp_path_factory.mktemp('opt')
    return run_optimization(problem, client, out=out), out


# ------------------------------------------------------------------------------------------------

def test_stage_angles_ascend_by_construction(problem):
    rng = np.random.default_rng(0)
    lo = np.array([v.low for v in problem.variables])
    hi = np.array([v.high for v in problem.variables])
    names = problem.study.variable_names
    for x in lo + rng.random((200, len(lo))) * (hi - lo):
        values = problem.absolute(x)
        line = design_driveline(problem.study.base,
                                dict(zip(problem.study.params, values)))     # never raises
        a = [s.angle_rad for s in line.spring.drive]
        assert a[1] - a[0] == pytest.approx(x[names.index('stages[1].angle_rad')], abs=1e-12)
        assert a[0] < a[1]


def test_capacity_is_the_springs_torque_at_the_travel(problem):
    """The paper's two-step spring carries 1.5 x 2800 Nm before 0.29 rad; the soft spring with
    its knee beyond the operating range (alpha 0.5, theta 0.28) does not."""
    c = problem.constraints
    assert c.engine_max_torque_nm == pytest.approx(max(
        problem.study.engines['A'].mean_torque(s, 1.0) for s in range(1400, 1801, 50)))
    paper = problem.study.base.with_dmf(alpha=3.0, theta=0.24).spring
    soft = problem.study.base.with_dmf(alpha=0.5, theta=0.28).spring
    row = {'max_dmf_torque': 0.5 * c.capacity_nm}
    k = 10890.0
    assert c.values(paper, row)[0] == pytest.approx(
        (c.capacity_nm - (k * 0.29 + 3 * k * (0.29 - 0.24))) / c.capacity_nm, rel=1e-9)
    assert c.values(paper, row)[0] < 0 < c.values(soft, row)[0]
    assert c.values(paper, {'max_dmf_torque': 1.1 * c.capacity_nm})[1] == pytest.approx(0.1)


def test_rank_puts_infeasible_after_feasible_and_failed_last():
    feas = np.array([False, True, True, False, False, True])
    failed = np.array([False, False, False, False, True, False])
    viol = np.array([0.3, 0.0, 0.0, 0.1, np.inf, 0.0])
    f1 = np.array([0.1, 1.0, 2.0, 0.0, np.nan, 3.0])
    f2 = np.array([0.1, 2.0, 1.0, 0.0, np.nan, 3.0])
    r = rank(feas, viol, np.column_stack([f1, f2]), failed)
    # feasible: 1 and 2 non-dominated (layer 1), 5 dominated (layer 2); then infeasible by
    # violation (3 before 0, although both dominate every feasible design); failed last
    assert r.tolist() == [4, 1, 1, 3, 5, 2]


def test_hypervolume_of_a_staircase():
    assert hypervolume([[1, 2], [2, 1]], (3, 3)) == pytest.approx(2 * 1 + 1 * 1)
    assert hypervolume([[1, 2], [5, 0]], (3, 3)) == pytest.approx(2.0)     # 5 > 3 adds nothing
    h = hypervolume_history([[2, 2], [1, 2], [1.5, 1]], [True, False, True], (3, 3))
    assert h.tolist() == pytest.approx([1.0, 1.0, 1.5 * 2])     # (1.5, 1) dominates (2, 2)


def test_hypervolume_of_three_objectives_is_the_union_of_boxes():
    # two boxes below (4, 4, 4): 3 x 2 x 1 and 1 x 3 x 3 (volumes 6 and 9), overlapping in
    # 1 x 2 x 1 = 2 -> 13 by inclusion-exclusion; a dominated point and one outside add nothing
    pts = [[1, 2, 3], [3, 1, 1], [3, 2, 3], [5, 0, 0]]
    assert hypervolume(pts, (4, 4, 4)) == pytest.approx(6 + 9 - 2)
    # the same against a Monte Carlo count of the dominated share of the box (independent of the
    # slicing): 20 000 uniform points, 3 standard errors
    rng = np.random.default_rng(3)
    p = rng.uniform(0, 1, (12, 3))
    u = rng.uniform(0, 1, (20_000, 3))
    hit = np.any(np.all(p[None, :, :] <= u[:, None, :], axis=2), axis=1)
    share = hit.mean()
    assert hypervolume(p, (1, 1, 1)) == pytest.approx(share, abs=3 * np.sqrt(share / 20_000))
    # with 4 objectives, a point adds its box: one point's volume is the product
    assert hypervolume([[0.5, 0.5, 0.5, 0.5]], (1, 1, 1, 1)) == pytest.approx(0.0625)
    h = hypervolume_history(p, np.ones(len(p), bool), (1, 1, 1))
    assert h[-1] == pytest.approx(hypervolume(p, (1, 1, 1)))
    assert np.all(np.diff(h) >= 0)


def test_pareto_mask_of_three_objectives():
    f = np.array([[1, 2, 3], [3, 1, 1], [3, 2, 3], [1, 2, 3], [np.nan, 0, 0], [0, 9, 9]])
    # 2 is dominated by 0; 0 and 3 are identical (both kept); NaN never on the front
    assert pareto_mask(*f.T).tolist() == [True, True, False, True, False, True]


def test_the_optimizer_improves_on_its_first_generation(run, problem):
    res, out = run
    rows = res.rows('design')
    assert [r['design_id'] for r in rows] == list(range(problem.budget))
    assert {r['generation'] for r in rows} == {0, 1, 2}
    first = res.hypervolume[problem.batch_size - 1]
    assert res.hypervolume[-1] > first > 0
    # the front is feasible, on rank 1, and every design's rank follows the rules
    front = [r for r in rows if r['pareto']]
    assert front and all(r['feasible'] and r['rank'] == 1 for r in front)
    worst_feasible = max(r['rank'] for r in rows if r['feasible'])
    assert all(r['rank'] > worst_feasible for r in rows if not r['feasible'])
    assert (out / 'results.parquet').exists() and (out / 'optuna.journal').exists()


def test_tpe_is_reproducible_and_improves_on_its_random_start(client):
    """The model-based method (the example study's): a seed gives the same designs run after
    run (a generation is told in trial order, whatever worker finished first), and its model
    finds better designs than its random start (the first generation)."""
    problem = read_problem(_problem(method='tpe'))
    a, b = (run_optimization(problem, client) for _ in range(2))
    assert [r['design_id'] for r in a.rows('design')] == list(range(problem.budget))
    names = problem.study.variable_names
    assert ([[r[v] for v in names] for r in a.rows('design')]
            == [[r[v] for v in names] for r in b.rows('design')])
    assert a.hypervolume[-1] > a.hypervolume[problem.batch_size - 1] > 0


def test_resume_after_an_interruption_skips_finished_designs(client, problem, run, tmp_path):
    done = []

    def stop(n, total):
        done.append(n)
        if n == 6:                      # in the middle of the second generation
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_optimization(problem, client, out=tmp_path, on_batch=stop, budget=8)
    res = run_optimization(problem, client, out=tmp_path, resume=True, budget=8)
    rows = res.rows('design')
    assert sorted(r['design_id'] for r in rows) == list(range(8))
    assert res.n_computed == 8 - 6
    # the same designs as the uninterrupted run (seeded sampler, generation by generation)
    full = {r['design_id']: r for r in run[0].rows('design')}
    for r in rows:
        for v in problem.study.variable_names:
            assert r[v] == pytest.approx(full[r['design_id']][v], rel=1e-12)
    # extending the budget computes only the new designs
    more = run_optimization(problem, client, out=tmp_path, resume=True, budget=10)
    assert more.n_computed == 2 and more.n_designs == 10
    with pytest.raises(ConfigError, match='different study|another optimization'):
        run_optimization(read_problem(_problem(seed=4)), client, out=tmp_path, resume=True)


def test_a_fresh_run_with_resume_enqueues_its_designs(problem, tmp_path):
    """--resume into an empty directory starts a new run: the Latin hypercube's designs (and a
    method's initial designs) are enqueued, not left to the fallback sampler (a defect: the
    journal file was created before asking whether it existed)."""
    from optuna.trial import TrialState

    from dmf_sim.optimize.runner import _open_study, baseline_problem
    for sub in ('lhs', 'opt'):
        (tmp_path / sub).mkdir()
    lhs = _open_study(baseline_problem(problem), tmp_path / 'lhs', resume=True)
    waiting = lhs.get_trials(deepcopy=False, states=(TrialState.WAITING,))
    assert len(waiting) == problem.budget
    d = _problem(initial=[{'theta': 0.2, 'alpha': 3.0, 'stages[1].angle_step_rad': 0.03,
                           'stages[1].stiffness_factor': 3.0,
                           'friction.torque_nm': 40.0}])
    opt = _open_study(read_problem(d), tmp_path / 'opt', resume=True)
    from optuna.distributions import FloatDistribution
    first = opt.ask({v.name: FloatDistribution(v.low, v.high) for v in problem.variables})
    assert first.params == d['optimizer']['initial'][0]


def test_a_failing_design_is_a_row_and_ranked_last(client, tmp_path):
    d = _problem(budget=4, batch_size=2)
    d['solver']['time_limit_s'] = 0.001
    res = run_optimization(read_problem(d), client, out=tmp_path)
    rows = res.rows('design')
    assert len(rows) == 4
    assert all(r['status'] == 'failed' and 'TimeLimitError' in r['error'] for r in rows), \
        [(r['status'], r['error']) for r in rows]
    assert all(not r['feasible'] and r['constraints'] == 'failed' for r in rows)
    assert res.pareto_ids == [] and res.best_id is None
    # one failed design among good ones ranks after every other
    good = run_optimization(read_problem(_problem(budget=2, batch_size=2)), client).rows()
    mixed = finish(read_problem(_problem()), good + [dict(r, design_id=99) for r in
                                                     res.rows() if r['design_id'] == 0])
    by_id = {r['design_id']: r['rank'] for r in mixed.rows('design')}
    assert by_id[99] == max(by_id.values()) and by_id[99] > by_id[0]


def test_time_domain_agrees_with_the_hbm_worst_values(run, problem):
    from dmf_sim.optimize.verify import VerifySettings, verify_design, verify_transient
    res, _ = run
    best = res.design(res.best_id)
    quick = VerifySettings(dt=1e-4, offsets=(0.0, 1.0), window_rpm=10.0, max_cycles=150,
                           steady_tol=1e-3)
    checks = verify_design(problem, best, quick)
    assert [c.objective for c in checks] == ['worst_torque_3']
    for c in checks:
        assert c.settled == 2
        assert c.rel_diff < 0.05, c
        assert math.isfinite(c.run_up)
    # the time-domain objectives: the design's load step and road cycle again at half the
    # study's Newmark step converge (the study's values within 1 %), and the values are the
    # study's own
    tr = verify_transient(problem, best, VerifySettings(dt=5e-5))
    assert [c.objective for c in tr] == ['transient_dmf_torque', 'cycle_friction_heat']
    for c in tr:
        assert c.study_value == best[c.objective] and c.dt_s == 1e-4
        assert 0 < c.rel_diff < 0.01, c


def test_the_summary_says_what_the_time_domain_is_compared_with():
    """The summary said 'largest relative difference 0.06 %' while the report's run-up column
    showed 1763 vs 1634 Nm (+8 %): it compared only the shots. Both comparisons are now named,
    each with its largest difference and where."""
    from dmf_sim.optimize.report import Block, _markdown
    from dmf_sim.optimize.verify import Check, verification_extremes, verification_lines
    checks = [Check(155, 'worst_torque_3', 'A_1', 1380.0, 1634.0, 1633.0, 1763.0).as_dict(),
              Check(155, 'worst_order_1_5', 'C_1', 920.0, 1.366e-3, 1.3665e-3, 1.376e-3).as_dict()]
    summary = {'verification': checks, **verification_extremes(checks)}
    assert summary['verified_max_rel_diff'] == pytest.approx(1 / 1634)
    assert summary['verified_run_up_rel_diff'] == pytest.approx(129 / 1634)
    text = '\n'.join(verification_lines(summary))
    assert 'steady shots at the worst grid speed: largest difference 0.06 %' in text
    assert 'run-ups through that speed' in text and '+7.9 %' in text
    assert '1763 vs HBM 1634' in text and '1633 vs HBM 1634' in text
    assert 'worst_torque_3 at 1380 rpm' in text
    assert _markdown([Block('p', text)]).count('HBM') >= 3


@pytest.mark.parametrize('change, field', [
    ({'method': 'simplex'}, 'optimizer.method'),
    ({'method': ['tpe']}, 'optimizer.method'),                    # not a name: no traceback
    ({'budget': 0}, 'optimizer.budget'),
    ({'batch_size': 1.5}, 'optimizer.batch_size'),
    ({'popsize': 3}, "unknown key 'popsize'"),
    ({'constraints': {'max_travel_rad': -0.1}}, 'max_travel_rad'),
    ({'constraints': {'capacity_nm': 3000, 'capacity_factor': 1.2}}, 'not both'),
    ({'constraints': {'metrics': {'loudness': {'max': 1}}}}, 'metrics.loudness'),
    ({'initial': [{'theta': 0.2}]}, 'optimizer.initial[0]'),
])
def test_bad_optimizer_section_is_one_line(change, field):
    with pytest.raises(ConfigError) as e:
        read_problem(_problem(**change))
    assert field in str(e.value) and '\n' not in str(e.value)


def test_an_increment_over_the_base_springs_knee(tmp_path):
    """A knee increment whose stage before is neither a variable nor fixed takes that stage's
    angle from the base spring (a defect: the lookup imported a name that does not exist, a
    traceback instead of the problem)."""
    d = _problem()
    del d['variables']['theta']
    p = read_problem(d)
    step = next(v for v in p.variables if v.name == 'stages[1].angle_step_rad')
    assert step.step_of.name == 'stages[0].angle_rad'
    reach = p.study.ranges[p.study.variable_names.index('stages[1].angle_rad')]
    assert (reach.low, reach.high) == pytest.approx((0.24 + 0.005, 0.24 + 0.06))


def test_absolute_later_stage_angle_asks_for_an_increment():
    d = _problem()
    d['variables']['stages[1].angle_rad'] = d['variables'].pop('stages[1].angle_step_rad')
    with pytest.raises(ConfigError, match=r'stages\[1\].angle_step_rad'):
        read_problem(d)


def test_cli_report_yaml_designs_and_json(client, tmp_path, capsys):
    import yaml

    from dmf_sim.physics.model import read_driveline
    study = tmp_path / 'study.yaml'
    study.write_text(yaml.safe_dump(_problem(budget=4, batch_size=4)))
    out = tmp_path / 'out'
    rc = cli_main(['optimize', str(study), '--out', str(out), '--scheduler',
                   client.scheduler.address, '--verify', '0', '--json', '--no-progress'])
    assert rc == 0
    s = json.loads(capsys.readouterr().out)
    assert s['n_designs'] == 4 and s['baseline']['n_designs'] == 4
    assert set(s['hypervolume']) == {'reference_point', 'optimizer_final', 'lhs_final', 'ratio',
                                     'front'}
    front = s['hypervolume']['front']
    assert set(front) == {'reference_point', 'optimizer_final', 'lhs_final', 'ratio',
                          'wide_bound'}
    assert s['hypervolume']['ratio'] <= front['wide_bound'] * (1 + 1e-12)
    assert "fronts' own reference point" in (out / 'report.md').read_text()
    assert 'dominates_paper' in s['best_vs_paper']
    for name in ('report.md', 'report.html', 'pareto_vs_lhs.png', 'hypervolume.png',
                 'springs.png', 'fig13_best.png'):
        assert (out / name).stat().st_size > 0
    assert not (out / LOCK_FILE).exists() and not (out / 'baseline' / LOCK_FILE).exists()
    for design_id, path in s['files']['designs'].items():
        line = read_driveline(path)
        row = next(r for r in s['pareto'] if str(r['design_id']) == design_id)
        assert line.spring.theta == pytest.approx(row['theta'])
        assert line.spring.drive[1].angle_rad == pytest.approx(row['stages[1].angle_rad'])
    assert '| design |' in (out / 'report.md').read_text()


def test_a_smaller_budget_on_resume_never_drops_stored_designs(client, tmp_path, capsys):
    """The field report's case: `--resume --budget 8` after a 16-design run rewrote
    results.parquet and summary.json with designs 0-7 only (the best design gone), leaving
    designs/*.yaml and report.md of the full run. Now it is refused in one line and nothing
    stored changes; the full budget resumes with every design."""
    import yaml
    study = tmp_path / 'study.yaml'
    study.write_text(yaml.safe_dump(_problem(budget=8, batch_size=4)))
    out = tmp_path / 'out'
    args = ['optimize', str(study), '--out', str(out), '--scheduler', client.scheduler.address,
            '--verify', '0', '--no-report', '--no-baseline', '--no-progress', '--json']
    assert cli_main(args) == 0
    first = json.loads(capsys.readouterr().out)
    assert first['n_designs'] == 8
    stored = {f: (out / f).read_bytes() for f in ('results.parquet', 'summary.json')}
    assert cli_main(args + ['--resume', '--budget', '4']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'budget 4' in err and 'holds 8 designs' in err, err
    assert 'pass --budget 8 or more' in err
    assert {f: (out / f).read_bytes() for f in stored} == stored
    with pytest.raises(ConfigError, match='holds 8 designs'):      # the library route too
        run_optimization(read_problem(_problem(budget=8, batch_size=4)), client, out=out,
                         resume=True, budget=5)
    assert cli_main(args + ['--resume']) == 0                       # the same budget: all kept
    again = json.loads(capsys.readouterr().out)
    assert again['n_designs'] == 8 and again['n_resumed'] == 8
    assert again['pareto'] == first['pareto']


def test_design_files_of_a_former_front_are_removed(run, problem, tmp_path):
    from dmf_sim.optimize.export import write_designs
    res, _ = run
    front = [r for r in res.rows('design') if r['pareto']]
    stale = tmp_path / 'designs' / 'design_999.yaml'
    stale.parent.mkdir()
    stale.write_text('name: an earlier front\n')
    files = write_designs(problem, front[:1], tmp_path)
    assert sorted(p.name for p in stale.parent.iterdir()) == [f'design_{front[0]["design_id"]}'
                                                               '.yaml']
    assert list(files) == [str(front[0]['design_id'])]


def test_cli_bad_study_exits_2_with_one_line(tmp_path, capsys):
    import yaml
    study = tmp_path / 'bad.yaml'
    study.write_text(yaml.safe_dump(_problem(method='simplex')))
    assert cli_main(['optimize', str(study), '--out', str(tmp_path / 'o')]) == 2
    err = capsys.readouterr().err.strip()
    assert 'optimizer.method' in err and len(err.splitlines()) == 1


def test_benchmark_quick():
    import subprocess
    import sys
    out = subprocess.run([sys.executable, str(REPO / 'benchmarks' / 'bench_optimize.py'),
                          '--quick'], capture_output=True, text=True, timeout=900, cwd=REPO)
    assert out.returncode == 0, out.stderr[-2000:]
    data = json.loads(out.stdout.strip().splitlines()[-1])
    assert data['quick'] is True and len(data['hypervolume_ratio_per_seed']) == 2
    # 8 designs per run: a run may have none inside the paper's box (ratio 0 or inf)
    assert data['hypervolume_ratio'] >= 0 and data['designs_per_s_1'] > 0
    assert data['designs_per_s_2'] > 0
    assert 0 <= data['verified_max_rel_diff'] < 0.05
    # the time-domain objectives are checked too: the load step and the road cycle again at
    # the verification's Newmark step
    assert data['verified_transient'] and 0 <= data['verified_max_rel_diff_transient'] < 0.05
    assert {c['objective'] for c in data['verified_transient']} == {'transient_dmf_torque',
                                                                    'cycle_friction_heat'}
    assert data['objectives'] == ['worst_torque_3', 'transient_dmf_torque',
                                  'cycle_friction_heat']
    assert 'dominates_paper' in data['best_vs_paper']
    # one reference point, fixed before the runs: the paper design's objectives x 1.1
    paper = data['paper']
    assert data['reference_point'] == pytest.approx(
        [1.1 * paper[o] for o in data['objectives']], rel=1e-12)
    assert data['hypervolume_ratio_min'] <= data['hypervolume_ratio']
    assert data['front_size'] == data['front_size_per_seed'][0] >= 1
    assert len(data['hypervolume_ratio_wide_per_seed']) == 2
    for ratio, bound in zip(data['hypervolume_ratio_wide_per_seed'],
                            data['hypervolume_ratio_wide_bound_per_seed']):
        assert ratio <= bound * (1 + 1e-12)          # no front beats the ideal point
    for seed in data['ideal_point_search']:
        for run in ('optimizer', 'lhs'):
            assert seed[run]['front_size'] >= 1 and seed[run]['n_near_ideal'] >= 0


def test_ideal_point_search_counts_evaluations_to_the_ideal_point():
    """The ideal point is the best feasible value of each objective over both runs; a run finds
    it at the first evaluation within 1 % of it in both objectives; infeasible rows never count."""
    from types import SimpleNamespace

    from dmf_sim.optimize.report import ideal_point_search

    def run(points, pareto):
        rows = [{'design_id': i, 'feasible': feas, 'status': 'ok', 'pareto': i in pareto,
                 'a': a, 'b': b} for i, (a, b, feas) in enumerate(points)]
        return SimpleNamespace(problem=SimpleNamespace(objectives=['a', 'b']),
                               rows=lambda kind: rows)

    opt = run([(3.0, 3.0, True), (1.0, 1.0, False), (1.005, 1.0, True), (1.0, 1.009, True)],
              {2, 3})
    lhs = run([(2.0, 1.5, True), (1.5, 2.0, True), (1.0, 5.0, True)], {0, 1, 2})
    out = ideal_point_search(opt, lhs, rel=0.01)
    assert out['ideal'] == {'a': 1.0, 'b': 1.0}         # the infeasible (1, 1) does not count
    assert out['optimizer'] == {'front_size': 2, 'n_near_ideal': 2, 'evaluations_to_ideal': 3}
    assert out['lhs'] == {'front_size': 3, 'n_near_ideal': 0, 'evaluations_to_ideal': None}


def test_common_hypervolumes_with_a_given_reference_point():
    """With the paper's design as the reference point only the area that improves on it counts:
    a run whose designs are all worse than it in one objective has none."""
    from types import SimpleNamespace

    from dmf_sim.optimize.report import common_hypervolumes

    def run(points):
        rows = [{'design_id': i, 'feasible': True, 'status': 'ok', 'a': a, 'b': b}
                for i, (a, b) in enumerate(points)]
        return SimpleNamespace(problem=SimpleNamespace(objectives=['a', 'b']),
                               rows=lambda kind: rows)

    opt, lhs = run([(1.0, 1.0), (4.0, 0.5)]), run([(2.0, 3.0), (0.5, 6.0)])
    default = common_hypervolumes(opt, lhs)
    assert default['reference_point'] == pytest.approx([4.4, 6.6])
    paper = common_hypervolumes(opt, lhs, (2.0, 2.0))
    assert paper['optimizer_final'] == pytest.approx(1.0)      # (2-1) x (2-1)
    assert paper['lhs_final'] == 0.0 and paper['ratio'] == math.inf


def test_front_reference_point_and_the_bound_of_the_wide_one():
    """The fronts' reference point is their nadir plus 10 % of their range, so both fronts count
    whole; with the wide reference point (1.1 x the worst feasible design) a design far worse
    than either front dominates the comparison and the ratio is bounded by the ideal point's."""
    from types import SimpleNamespace

    from dmf_sim.optimize.report import common_hypervolumes, front_hypervolumes

    def run(points, front):
        rows = [{'design_id': i, 'feasible': True, 'status': 'ok', 'a': a, 'b': b,
                 'pareto': i in front} for i, (a, b) in enumerate(points)]
        return SimpleNamespace(problem=SimpleNamespace(objectives=['a', 'b']),
                               rows=lambda kind: rows)

    # both fronts near (1, 1); one far design (20, 20) sets the wide reference point
    opt = run([(1.0, 1.0), (20.0, 20.0)], {0})
    lhs = run([(1.2, 1.5), (1.5, 1.2)], {0, 1})
    front = front_hypervolumes(opt, lhs)
    # nadir (1.5, 1.5), ideal (1, 1), range 0.5 -> reference (1.55, 1.55)
    assert front['reference_point'] == pytest.approx([1.55, 1.55])
    assert front['optimizer_final'] == pytest.approx(0.55 ** 2)
    assert front['lhs_final'] == pytest.approx(2 * 0.35 * 0.05 - 0.05 ** 2)  # overlap once
    assert front['ratio'] == pytest.approx(0.55 ** 2 / 0.0325)
    wide = common_hypervolumes(opt, lhs)
    assert wide['reference_point'] == pytest.approx([22.0, 22.0])
    # the optimizer's front is the ideal point itself: the wide ratio is the bound, near 1
    assert wide['ratio'] == pytest.approx(front['wide_bound'])
    assert 1.0 < front['wide_bound'] < 1.05


def test_hypervolumes_without_a_feasible_design_are_empty_not_an_error():
    """A run with no feasible design (a tight constraint, a small budget): both comparisons give
    zero hypervolumes and an undefined ratio, with the same keys as a normal run."""
    from types import SimpleNamespace

    from dmf_sim.optimize.report import common_hypervolumes, front_hypervolumes

    rows = [{'design_id': 0, 'feasible': False, 'status': 'ok', 'a': 1.0, 'b': 1.0,
             'pareto': False}]
    run = SimpleNamespace(problem=SimpleNamespace(objectives=['a', 'b']), rows=lambda kind: rows)
    for hv in (common_hypervolumes(run, run), front_hypervolumes(run, run)):
        assert hv['reference_point'] is None and math.isnan(hv['ratio'])
        assert hv['optimizer_final'] == hv['lhs_final'] == 0.0


def test_the_printed_front_names_every_objective(capsys):
    """The front is of all the objectives (finish: ranks over every one); the summary named the
    first two of config/optimize_example.yaml's three."""
    from dmf_sim.commands.optimize import _print
    objectives = ['worst_torque_3', 'transient_dmf_torque', 'cycle_friction_heat']
    _print({'designs_per_s': 1.0, 'study': 's', 'method': 'nsga2', 'n_designs': 2,
            'n_feasible': 2, 'n_failed': 0, 'n_resumed': 0, 'seconds': 1.0, 'workers': 1,
            'objectives': objectives, 'pareto': [], 'files': {}})
    out = capsys.readouterr().out
    assert ('feasible Pareto front of worst_torque_3, transient_dmf_torque, cycle_friction_heat: '
            '0 designs') in out


def test_a_run_without_a_feasible_design_names_the_nearest(capsys):
    """capacity_nm 20000 Nm for the example's spring bounds (budget 8): no design feasible, and
    the summary said only 'feasible Pareto front ...: 0 designs', not which constraint no
    design met. It names the design nearest to feasible and its constraint values."""
    from dmf_sim.commands.optimize import _print
    from dmf_sim.optimize.runner import nearest_infeasible
    rows = [{'design_id': 0, 'feasible': False, 'violation': 0.9,
             'constraints': 'capacity +0.9, dmf_torque -0.8'},
            {'design_id': 1, 'feasible': False, 'violation': 0.5,
             'constraints': 'capacity +0.5, dmf_torque -0.7'},
            {'design_id': 2, 'feasible': False, 'violation': math.inf, 'constraints': 'failed'}]
    near = nearest_infeasible(rows)
    assert near == {'design_id': 1, 'violation': 0.5,
                    'constraints': 'capacity +0.5, dmf_torque -0.7'}
    feasible = {'design_id': 3, 'feasible': True, 'violation': 0.0, 'constraints': ''}
    assert nearest_infeasible([*rows, feasible]) is None
    assert nearest_infeasible(rows[2:]) is None                  # only failed designs
    _print({'designs_per_s': 1.0, 'study': 's', 'method': 'tpe', 'n_designs': 3,
            'n_feasible': 0, 'n_failed': 1, 'n_resumed': 0, 'seconds': 1.0, 'workers': 1,
            'objectives': ['a', 'b'], 'pareto': [], 'nearest_infeasible': near, 'files': {}})
    out = capsys.readouterr().out
    assert ('no design meets the constraints; the nearest, design 1: capacity +0.5, '
            'dmf_torque -0.7') in out
