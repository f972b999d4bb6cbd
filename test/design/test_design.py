"""DMF design studies: a study on a local Dask cluster gives the numbers of direct
sweeps, resumes after an interruption to the same table, records failing designs and goes on,
and refuses bad study files (and an unreachable scheduler) with one line before any work."""
from __future__ import annotations

import json
import math
import os
import socket
from pathlib import Path

import numpy as np
import psutil
import pytest
import yaml
from support.nested_edit import DELETE, edited

from dmf_sim.cli import main as cli_main
from dmf_sim.cluster import connect, local_cluster
from dmf_sim.core.errors import ConfigError
from dmf_sim.design import read_study, run_study
from dmf_sim.design.evaluate import StudyContext, evaluate_design
from dmf_sim.design.metrics import first_max
from dmf_sim.design.runner import DEFAULT_BATCH_SIZE, batch_sizes
from dmf_sim.design.states import speed_grid
from dmf_sim.design.table import LOCK_FILE
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.orders import ORDER_3
from dmf_sim.solvers.hbm import SweepOptions, sweep

pytestmark = pytest.mark.slow     # studies on a local Dask cluster: its start and workers

REPO = Path(__file__).resolve().parents[2]

STUDY = {   # 12 designs x 2 load sets; knee reached or not, 1.5th-order states and coexistence
    'name': 'test_study', 'driveline': 'truck_dmf', 'engine': 'engine_d13',
    'sampling': {'method': 'grid'},
    'variables': {'alpha': {'values': [2.0, 3.0, 4.0]},
                  'theta': {'values': [0.2, 0.22, 0.24, 0.26]}},
    'conditions': {'load_sets': ['A', 'B'], 'loads': [1.0],
                   'speeds_rpm': {'from': 900, 'to': 1100, 'step': 10}},
    'objectives': ['worst_order_1_5', 'worst_torque_3', 'max_dmf_torque'],
}


def _listening(pid: int) -> set:
    return {c.laddr for c in psutil.Process(pid).net_connections('inet')
            if c.status == psutil.CONN_LISTEN}


@pytest.fixture(scope='module')
def client():
    from distributed import Client
    before = _listening(os.getpid())          # the scheduler runs in this process
    with local_cluster(2) as cluster, Client(cluster) as c:
        c.wait_for_workers(2)
        c.listening_before = before
        yield c


@pytest.fixture(scope='module')
def study():
    return read_study(STUDY)


@pytest.fixture(scope='module')
def full_run(client, study, tmp_path_factory):
    out = tmp_path_factory.mktemp('full')
    return run_study(study, client, out=out, batch_size=2), out


def _without_timing(table) -> list[dict]:
    return [{k: v for k, v in r.items() if k != 'seconds'} for r in table.to_pylist()]


REL_TOL = 1e-12
"""Rows computed in different processes (Dask workers, or a worker and this process) agree to
this relative tolerance, not bitwise: a worker's BLAS may use another thread count and so another
summation order, and the last bit of e.g. worst_order_1_5 differed on another machine
(0.003220760291894178 vs 0.00322076029189417). The absolute floor only spares values
that are zero on one path and ~1e-17 on the other."""
ABS_TOL = 1e-15


def _close(g, w) -> bool:
    """Floats within REL_TOL (NaN == NaN), sequences item by item, anything else equal."""
    if isinstance(w, float) or isinstance(g, float):
        if not isinstance(g, (int, float)) or not isinstance(w, (int, float)):
            return False
        return (math.isnan(g) and math.isnan(w)) or math.isclose(g, w, rel_tol=REL_TOL,
                                                                 abs_tol=ABS_TOL)
    if isinstance(w, (list, tuple)):
        return isinstance(g, (list, tuple)) and len(g) == len(w) and all(
            _close(a, b) for a, b in zip(g, w))
    return g == w


def _assert_rows_close(got: list[dict], want: list[dict]) -> None:
    """Same rows, same keys, equal strings/ints/flags, floats within REL_TOL (NaN == NaN)."""
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        assert g.keys() == w.keys()
        off = {k: (g[k], w[k]) for k in w if not _close(g[k], w[k])}
        assert not off, (w.get('design_id'), w.get('condition'), off)


# ------------------------------------------------------------------------------------------------
# the numbers
# ------------------------------------------------------------------------------------------------

def _direct(study, alpha, theta, cond) -> dict:
    """Worst values of one design and condition straight from hbm.sweep: every stable solution
    at every grid speed (SweepResult.solutions_at), the torque by the solver's own whole-chain
    recovery (CondensedHBM.torque_harmonics), and the time-integration envelope at every grid
    speed without a stable periodic state (what the driveline does there; no torque)."""
    lo, hi, step = study.speeds_rpm
    line = study.base.with_dmf(alpha=alpha, theta=theta)
    res = sweep(DrivelineExcitation(line.reduce(), study.engines[cond.load_set]), cond.load,
                (lo, hi), options=SweepOptions(step_rpm=step))
    el = line.index('INPUT SHAFT')
    out = {'worst_order_1_5': 0.0, 'worst_order_3': 0.0, 'worst_torque_3': 0.0,
           'max_dmf_torque': 0.0, 'n_stable': [], 'n_1_5': 0}
    for s in speed_grid(lo, hi, step):
        sols = [q for q in res.solutions_at(s) if q.stable]
        out['n_stable'].append(len(sols))
        out['n_1_5'] += any(q.order_1_5 > max(res.ratio_1_5 * q.forced_order_1_5, res.min_1_5)
                            for q in sols)
        for q in sols:
            sm = q.summary
            out['worst_order_1_5'] = max(out['worst_order_1_5'], q.order_1_5)
            out['worst_order_3'] = max(out['worst_order_3'], q.order_3)
            out['worst_torque_3'] = max(out['worst_torque_3'],
                                        abs(res.hbm.torque_harmonics(q)[ORDER_3, el]))
            ext = np.array([sm.mean + sm.max_deviation, sm.mean + sm.min_deviation])
            out['max_dmf_torque'] = max(out['max_dmf_torque'],
                                        float(np.abs(line.spring.torque(ext)).max()))
    for r in (r for band in res.non_periodic for r in band.results):
        assert res.stable_states_at(r.speed_rpm) == 0     # envelopes only where none is stable
        out['worst_order_1_5'] = max(out['worst_order_1_5'], r.order_1_5)
        out['worst_order_3'] = max(out['worst_order_3'], r.order_3)
        ext = np.array([r.mean + r.max_deviation, r.mean + r.min_deviation])
        out['max_dmf_torque'] = max(out['max_dmf_torque'],
                                    float(np.abs(line.spring.torque(ext)).max()))
    return out


@pytest.mark.parametrize('n, workers', [(100, 2), (300, 2), (100, 1), (7, 2), (1, 1)])
def test_default_batches_shrink_towards_the_end(n, workers):
    """Guided batch sizes: every design once, full batches while much is left, never growing,
    ending with single designs (so the workers finish together); a given size is kept."""
    sizes = batch_sizes(n, workers)
    assert sum(sizes) == n and max(sizes) <= DEFAULT_BATCH_SIZE
    assert all(a >= b for a, b in zip(sizes, sizes[1:])) and sizes[-1] == 1
    if n >= 100:
        assert sizes[0] == DEFAULT_BATCH_SIZE and len(sizes) < n / 3
    assert batch_sizes(n, workers, 4) == [4] * (n // 4) + ([n % 4] if n % 4 else [])


def test_study_on_a_local_cluster_equals_direct_sweeps(full_run, study):
    res, _ = full_run
    assert res.n_designs == 12 and not res.failed()
    rows = res.rows('condition')
    assert len(rows) == 24
    step = study.speeds_rpm[2]
    seen_1_5 = seen_two = False
    for r in rows:
        d = _direct(study, r['alpha'], r['theta'], next(c for c in study.conditions
                                                        if c.label == r['condition']))
        for key in ('worst_order_1_5', 'worst_order_3', 'worst_torque_3', 'max_dmf_torque'):
            assert r[key] == pytest.approx(d[key], rel=1e-6), (r['design_id'], r['condition'], key)
        assert r['max_stable_states'] == max(d['n_stable'])
        assert r['rpm_nonperiodic'] == step * sum(n == 0 for n in d['n_stable'])
        assert r['rpm_1_5'] == step * d['n_1_5']
        seen_1_5 |= r['rpm_1_5'] > 0
        seen_two |= r['max_stable_states'] >= 2
    assert seen_1_5 and seen_two          # the study covers designs with 1.5th-order states
    # a design's summary row holds the worst of its conditions
    for s in res.rows('design'):
        mine = [r for r in rows if r['design_id'] == s['design_id']]
        # the condition named is the first within TIE_REL of the worst (metrics.first_max): two
        # load sets can tie but for the last bits
        k = first_max(np.array([r['worst_order_1_5'] for r in mine]))
        # rel 1e-12: the summary row is reduced in another process than the condition rows
        # (summation order), so the last bits may differ (see the distributed-rows test)
        assert math.isclose(s['worst_order_1_5'], mine[k]['worst_order_1_5'], rel_tol=1e-12)
        assert s['worst_order_1_5_condition'] == mine[k]['condition']


def test_distributed_rows_equal_serial_evaluation(full_run, study):
    res, _ = full_run
    ctx = StudyContext.from_study(study)
    serial = []
    for i, row in enumerate(study.designs()):
        serial += evaluate_design(ctx, i, row)
    want = [{k: v for k, v in r.items() if k != 'seconds'} for r in serial]
    got = [{k: r[k] for k in w} for r, w in zip(res.rows(), want)]
    assert len(res.rows()) == len(want)
    _assert_rows_close(got, want)


def test_every_worker_loads_the_model_once(full_run):
    res, _ = full_run
    assert res.workers == 2 and res.batch_size == 2
    assert len(res.context_loads) == 2 and set(res.context_loads.values()) == {1}


def test_local_cluster_listens_on_loopback_only(client):
    ours = _listening(os.getpid()) - client.listening_before        # scheduler + its HTTP
    for pid in client.run(os.getpid).values():                      # workers and nannies
        ours |= _listening(pid)
    nanny_pids = {psutil.Process(pid).ppid() for pid in client.run(os.getpid).values()}
    for pid in nanny_pids - {os.getpid()}:
        ours |= _listening(pid)
    assert len(ours) >= 4 and {a.ip for a in ours} == {'127.0.0.1'}


def test_local_cluster_housekeeping_is_slowed_down(client):
    """The local cluster's workers run with the slower event-loop and monitor timers of
    cluster.QUIET_CLUSTER (Dask passes the config on to the worker processes)."""
    import dask

    from dmf_sim.cluster import QUIET_CLUSTER

    def config():
        return {k: dask.config.get(k) for k in QUIET_CLUSTER}

    assert list(client.run(config).values()) == [QUIET_CLUSTER, QUIET_CLUSTER]


def test_outputs_table_and_pareto_front(full_run, study):
    res, out = full_run
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq
    table = pq.read_table(out / 'results.parquet')
    assert _without_timing(table) == _without_timing(res.table)
    assert pacsv.read_csv(out / 'results.csv').num_rows == table.num_rows == 36
    summ = [r for r in res.rows('design') if r['status'] == 'ok']
    o1, o2 = study.objectives[:2]
    front = [r for r in summ if r['pareto']]
    assert front and res.best_id in {r['design_id'] for r in front}
    for r in summ:   # the front is exactly the set of designs nobody dominates
        dominated = any(q[o1] <= r[o1] and q[o2] <= r[o2] and (q[o1] < r[o1] or q[o2] < r[o2])
                        for q in summ)
        assert r['pareto'] == (not dominated)


# ------------------------------------------------------------------------------------------------
# resume, failures
# ------------------------------------------------------------------------------------------------

class _Stop(KeyboardInterrupt):
    pass


def test_interrupt_and_resume_gives_the_same_table(client, study, full_run, tmp_path):
    def stop_after_two(done, total):
        if done >= 4:
            raise _Stop
    with pytest.raises(_Stop):
        run_study(study, client, out=tmp_path, batch_size=2, on_batch=stop_after_two)
    assert not (tmp_path / 'results.parquet').exists()
    parts = list((tmp_path / 'parts').glob('part-*.parquet'))
    assert len(parts) == 2
    with pytest.raises(ConfigError, match='--resume'):
        run_study(study, client, out=tmp_path)           # stored results are never overwritten
    res = run_study(study, client, out=tmp_path, batch_size=2, resume=True)
    assert res.n_computed == 8 and res.n_designs == 12
    _assert_rows_close(_without_timing(res.table), _without_timing(full_run[0].table))
    again = run_study(study, client, out=tmp_path, resume=True)      # nothing left to do
    assert again.n_computed == 0 and _without_timing(again.table) == _without_timing(res.table)


def test_resume_refuses_a_different_study(client, study, full_run):
    other = dict(STUDY, conditions={**STUDY['conditions'], 'loads': [0.5]})
    with pytest.raises(ConfigError, match='different study'):
        run_study(other, client, out=full_run[1], resume=True)


def test_resume_with_fewer_designs_is_refused_and_drops_nothing(client, study, full_run):
    """A resume never drops stored designs: a study with fewer designs (here one alpha level
    less) is another study to the store, refused before anything is read or written."""
    out = full_run[1]
    parts = sorted(p.read_bytes() for p in (out / 'parts').glob('part-*.parquet'))
    fewer = dict(STUDY, variables={**STUDY['variables'], 'alpha': {'values': [2.0, 3.0]}})
    with pytest.raises(ConfigError, match='different study'):
        run_study(fewer, client, out=out, resume=True)
    assert sorted(p.read_bytes() for p in (out / 'parts').glob('part-*.parquet')) == parts
    assert run_study(study, client, out=out, resume=True).n_designs == study.n_designs


def test_a_failing_design_is_reported_and_the_rest_complete(client):
    data = dict(STUDY, variables={'theta': {'values': [0.2, 0.3, 0.22]}},
                fixed={'stages[1].angle_rad': 0.28, 'stages[1].stiffness_factor': 6.0},
                conditions={**STUDY['conditions'], 'load_sets': ['A']})
    res = run_study(data, client, batch_size=1)
    status = {r['design_id']: r for r in res.rows('design')}
    assert status[1]['status'] == 'failed' and 'stages[1].angle_rad' in status[1]['error']
    assert '\n' not in status[1]['error']
    assert status[0]['status'] == status[2]['status'] == 'ok'
    assert status[0]['worst_order_3'] > 0 and 1 not in res.pareto_ids
    assert [f['design_id'] for f in res.summary()['failed']] == [1]


def test_a_design_past_its_time_limit_is_recorded_as_failed_and_the_study_completes(client):
    """solver.time_limit_s bounds every design x condition sweep: one that reaches it is a
    failed row whose reason names the limit, the phase and the speed; the study finishes."""
    data = dict(STUDY, variables={'alpha': {'values': [2.0, 3.0]}},
                conditions={**STUDY['conditions'], 'load_sets': ['A']},
                solver={'time_limit_s': 0.001})
    res = run_study(data, client, batch_size=1)
    rows = res.rows('condition')
    assert len(rows) == 2 and all(r['status'] == 'failed' for r in rows)
    assert all(r['error'].startswith('TimeLimitError: sweep time limit 0.001 s reached during')
               and 'rpm' in r['error'] for r in rows)
    assert all(r['seconds'] < 5.0 for r in rows)
    assert sorted(f['design_id'] for f in res.summary()['failed']) == [0, 1]
    assert read_study(data).as_dict()['solver']['time_limit_s'] == 0.001


# ------------------------------------------------------------------------------------------------
# bad input: one line naming the field, before any work
# ------------------------------------------------------------------------------------------------

def _mutate(path: str, value):
    return edited(STUDY, path.split('/'), value)


@pytest.mark.parametrize('path, value, field', [
    ('variables', DELETE, "missing key 'variables'"),
    ('conditions/speeds_rpm', DELETE, "missing key 'conditions.speeds_rpm'"),
    ('objectives', DELETE, "missing key 'objectives'"),
    ('variables/alpha', {'min': 3.0, 'max': 3.0, 'n': 4}, "field 'variables.alpha' empty range"),
    ('variables/alpha', {'values': []}, 'variables.alpha.values'),
    ('variables/beta', {'min': 1, 'max': 2, 'n': 2}, "unknown design parameter 'beta'"),
    ('variables/stages[2].angle_rad', {'min': 0.3, 'max': 0.4, 'n': 2}, 'stages[2]'),
    ('variables/stages[1].angle_rad', {'min': 0.3, 'max': 0.4, 'n': 2}, 'stiffness_factor'),
    ('variables/theta', {'min': -0.1, 'max': 0.3, 'n': 2}, 'variables.theta.min'),
    ('conditions/load_sets', ['A', 'D'], 'conditions.load_sets[1]'),
    ('conditions/loads', [1.5], 'conditions.loads[0]'),
    ('conditions/speeds_rpm', {'from': 100, 'to': 2000, 'step': 10}, 'conditions.speeds_rpm'),
    ('objectives', ['worst_order_1_5', 'comfort'], 'objectives[1]'),
    ('sampling', {'method': 'lhs'}, "missing key 'sampling.n'"),
    ('sampling', {'method': 'sobol'}, 'sampling.method'),
    ('torque_element', 'GEARBOX', 'torque_element'),
    ('solver', {'time_limit_s': 0}, "field 'solver.time_limit_s' must be in [0.001, 86400] s"),
    ('solver', {'time_limit_s': 'soon'}, 'solver.time_limit_s'),
])
def test_bad_study_is_one_line_naming_the_field(path, value, field):
    with pytest.raises(ConfigError) as err:
        read_study(_mutate(path, value))
    msg = str(err.value)
    assert field in msg and '\n' not in msg


def test_cli_bad_study_exits_2_before_any_work(tmp_path, capsys):
    bad = tmp_path / 'bad.yaml'
    bad.write_text(yaml.safe_dump(_mutate('variables/alpha', {'min': 2, 'max': 1, 'n': 3})))
    out = tmp_path / 'out'
    assert cli_main(['design', str(bad), '--out', str(out), '--no-progress']) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'variables.alpha' in err
    assert not out.exists()


def test_cli_unreachable_scheduler_exits_2_before_any_work(tmp_path, capsys):
    study = tmp_path / 'study.yaml'
    study.write_text(yaml.safe_dump(STUDY))
    with socket.socket() as s:                 # a free loopback port nothing listens on
        s.bind(('127.0.0.1', 0))
        port = s.getsockname()[1]
    out = tmp_path / 'out'
    rc = cli_main(['design', str(study), '--out', str(out), '--no-progress',
                   '--scheduler', f'tcp://127.0.0.1:{port}', '--connect-timeout', '1'])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and '--scheduler' in err
    assert not out.exists()
    with pytest.raises(ConfigError, match='tcp://HOST:PORT'):
        connect('127.0.0.1')


def test_cli_on_an_existing_scheduler_json_and_files(client, tmp_path, capsys):
    data = dict(STUDY, variables={'alpha': {'values': [2.5, 3.0]}, 'theta': {'values': [0.24]}},
                conditions={**STUDY['conditions'], 'load_sets': ['A']})
    study = tmp_path / 'study.yaml'
    study.write_text(yaml.safe_dump(data))
    out = tmp_path / 'out'
    args = ['design', str(study), '--out', str(out), '--no-progress', '--json',
            '--scheduler', client.scheduler.address]
    assert cli_main(args) == 0
    s = json.loads(capsys.readouterr().out)
    assert s['n_designs'] == 2 and s['n_ok'] == 2 and s['n_computed'] == 2 and s['best']
    for name in ('results.parquet', 'results.csv', 'summary.json', 'objective_maps.png',
                 'pareto.png', 'fig13_best.png'):
        assert (out / name).stat().st_size > 0
    assert not (out / LOCK_FILE).exists()                         # the run's lock went with it
    assert cli_main(args) == 2                                    # would overwrite: refused
    assert '--resume' in capsys.readouterr().err
    assert cli_main(args + ['--resume', '--no-plots']) == 0       # nothing left to compute
    assert json.loads(capsys.readouterr().out)['n_resumed'] == 2


@pytest.mark.bench
def test_benchmark_quick():
    import subprocess
    import sys
    out = subprocess.run([sys.executable, str(REPO / 'benchmarks' / 'bench_design.py'), '--quick'],
                         capture_output=True, text=True, timeout=600, cwd=REPO)
    assert out.returncode == 0, out.stderr[-2000:]
    data = json.loads(out.stdout.strip().splitlines()[-1])
    assert data['quick'] is True
    for key in ('designs_per_s_1', 'designs_per_s_2', 'scaling_2', 'task_overhead_ms',
                'chosen_batch_size', 'serial_designs_per_s', 'mixed_designs_per_s_2'):
        assert data[key] > 0, key
    assert data['rss_failed'] == 0 and len(data['peak_rss_mb_per_worker']) == 2
    assert set(data['designs_per_s_2_by_batch']) == {'1', '2', '4', '8'}
